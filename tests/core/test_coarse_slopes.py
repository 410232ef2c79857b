"""Issue 12: filters on a steep hillside gridded at 4 m from lidar-like points (lowest point per
cell), trees on it; known truth per cell.

A 4 m cell of lowest points on ground rising 0.5 per metre holds a height taken anywhere in the
cell: neighbours scatter by ``s c / sqrt(12)`` (0.6 m here) about the slope, and a rocky terrace's
riser rises several metres within one cell. The hexbin-crop lidar tile at 4 m (a 21 degree
hillside with rock steps) lost its risers to every filter but slopeprofile; these tests keep a
synthetic hillside of that kind ground while its trees stay objects.
"""
import numpy as np
import pytest

from bare_earth.core.pipeline import run_array
from bare_earth.core.points import rasterize_points


def terraced_hillside(cell=4.0, seed=0, extent=200.0, step_m=16.0, rise_m=6.0, riser_m=1.0):
    """Lowest point per ``cell`` of lidar-like points (0.6 per m2, 0.1 m noise) on a hillside of
    terraces ``step_m`` deep rising ``rise_m`` each over a riser of logistic width ``riser_m``
    (steepest 56 degrees), running obliquely, on a 0.1 slope; 25 trees 8-15 m tall, 3-6 m in
    radius, whose cells hold canopy returns only. Returns the DSM and the cells of the trees."""
    rng = np.random.default_rng(seed)
    n = int(0.6 * extent * extent)
    x, y = rng.uniform(0, extent, n), rng.uniform(0, extent, n)

    def ground(x, y):
        u = y + 0.3 * x
        k = np.floor(u / step_m)
        return rise_m * (k + 1.0 / (1.0 + np.exp(-(u - k * step_m - step_m / 2) / riser_m))) + 0.1 * x

    z = ground(x, y) + 0.1 * rng.standard_normal(n)
    tx, ty = rng.uniform(20, extent - 20, 25), rng.uniform(20, extent - 20, 25)
    tr, th = rng.uniform(3.0, 6.0, 25), rng.uniform(8.0, 15.0, 25)
    tree = np.zeros(n, bool)
    for cx, cy, r, h in zip(tx, ty, tr, th):
        d = np.hypot(x - cx, y - cy)
        inside = d < r
        z[inside] = ground(cx, cy) + h * (1.0 - 0.5 * (d[inside] / r) ** 2)
        tree |= inside
    box = (0.0, 0.0, extent, extent)
    dsm, _ = rasterize_points(x, y, z, cell, reducer="min", extent=box)
    canopy, _ = rasterize_points(x, y, tree.astype(np.float64), cell, reducer="min", extent=box)
    return dsm, canopy > 0.5


@pytest.fixture(scope="module")
def hillside():
    return terraced_hillside()


#: Share of the hillside's ground each filter keeps at least (before this issue's changes:
#: curvature 93.0 %, rascor 76.6 %; its terrace edges are taken for walls' tops).
KEPT = {"curvature": 0.99, "rascor": 0.82}


@pytest.mark.parametrize("method", sorted(KEPT))
def test_terraced_hillside_at_4m_stays_ground_and_its_trees_objects(hillside, method):
    z, trees = hillside
    assert 20 < trees.sum() < 0.1 * trees.size
    res = run_array(method, z, (4.0, 4.0), {})
    removed = res.mask != 0
    assert np.mean(~removed[~trees]) >= KEPT[method], method
    assert np.mean(removed[trees]) >= 0.9, method
