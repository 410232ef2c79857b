"""A raised level cut by the raster's edge: the run of its walls mirrored there (edge_walls), and the
curvature filter's region stage and RASCOR's level changes deciding it by that run at every cell size."""
import numpy as np
import pytest

from bare_earth.core.codes import GROUND, OBJECT
from bare_earth.core.common import walls_runs
from bare_earth.core.methods import get_method


def test_walls_runs_exact():
    """Several regions at once (common.walls_runs, the one copy): the box of a region's wall cells
    mirrored at every side of the raster both they and the ground at their foot meet: a wall cutting
    off a corner runs twice what is seen along each axis, one across the raster three times, a wall
    inside the raster what is seen; a wall ending in a corner whose foot does not reach the third side
    is not cut there."""
    shape = (10, 12)
    # 1: a diagonal from the top side (column 4) to the left side (row 4), its foot beyond it (above-left)
    # 2: a straight wall down column 6 from the top side to the bottom side, its foot in column 5
    # 3: a wall inside the raster, rows 5-7 of column 9, foot in column 10
    # 4: a diagonal from the top side to the bottom-left corner, its foot reaching row 8 only: top and left
    #    (rows 0-9 x 2 = 20; with the bottom side too, 3 x 10 = 30)
    # 5: no ground seen beyond: not mirrored (rows 0-1: 2)
    cells = [(1, r, 4 - r) for r in range(5)] + [(2, r, 6) for r in range(10)] + [(3, r, 9) for r in (5, 6, 7)]
    cells += [(4, r, (9 - r) // 2) for r in range(10)] + [(5, 0, 0), (5, 1, 1)]
    foot = [(1, r, 3 - r) for r in range(4)] + [(2, r, 5) for r in range(10)] + [(3, r, 10) for r in (5, 6, 7)]
    foot += [(4, r, (9 - r) // 2 - 1) for r in range(8)]
    ids, rows, cols = (np.array(a) for a in zip(*cells))
    f_ids, f_rows, f_cols = (np.array(a) for a in zip(*foot))
    got = walls_runs(rows, cols, ids, 6, shape, f_rows, f_cols, f_ids)
    assert got.tolist() == [0, 10, 30, 3, 20, 2, 0]
    full = [(4, 9, 0)]
    f4 = np.array(foot + full)
    assert walls_runs(rows, cols, ids, 6, shape, f4[:, 1], f4[:, 2], f4[:, 0])[4] == 30
    assert walls_runs([], [], [], 2, shape).tolist() == [0, 0, 0]


def _tile(cell, kind, side_m=80.0, seed=0):
    """An ``side_m`` square tile whose top-left 84 % x 84 % (70 % of it) is a raised level: a flat roof
    8 m above the ground on vertical walls (``"roof"``), or a terrace 3 m above it joined to the lower
    ground by a 15 degree bank (``"terrace"``); the ground around it slopes gently; noise 0.03 m.
    Returns the heights and the truth (True: the level, for the roof)."""
    n = int(round(side_m / cell))
    y, x = (np.mgrid[0:n, 0:n] + 0.5) * cell
    edge = 0.84 * side_m
    ground = 100.0 + 0.01 * x + 0.005 * y
    # the distance outside the level (0 on it): along x beyond its right side, along y below it
    out = np.maximum(np.maximum(x - edge, 0.0), np.maximum(y - edge, 0.0))
    if kind == "roof":
        level = out == 0
        z = ground + 8.0 * level
    else:
        level = out == 0
        z = ground + np.clip(3.0 - out * np.tan(np.radians(15.0)), 0.0, 3.0)
    rng = np.random.default_rng(seed)
    return (z + rng.normal(0.0, 0.03, z.shape)).astype(np.float32), level


@pytest.mark.parametrize("method", ["curvature", "rascor"])
@pytest.mark.parametrize("cell", [0.5, 1.0, 2.0, 4.0])
def test_roof_over_most_of_the_tile_cut_by_two_edges_is_an_object(method, cell):
    """A flat roof over 70 % of an 80 m tile, cut by its top and left edges (lidar ``sample_c``: a roof
    over 75 % of its tile): its walls, mirrored at the two sides they meet, run 134 m, within twice the
    largest object (curvature, 100 m) and the longest building (RASCOR, 120 m), and what is seen of it
    (67 m) within them: an object at every cell size (before: ground, 70 % of the tile wrong)."""
    m = get_method(method)
    z, roof = _tile(cell, "roof")
    res = m.run(z, cell, **m.resolve(z, cell))
    assert (res.mask[roof] == OBJECT).mean() > 0.97
    assert (res.mask[~roof] == GROUND).mean() > 0.9


@pytest.mark.parametrize("method", ["curvature", "rascor"])
@pytest.mark.parametrize("cell", [0.5, 1.0, 2.0, 4.0])
def test_terrace_over_most_of_the_tile_joined_by_a_bank_stays_ground(method, cell):
    """The same level 3 m high joined to the lower ground by a 15 degree bank: no wall, no jump, it
    stays ground at every cell size (RASCOR's steps 3 and 5 take a few cells of the bank at 4 m
    cells, 5 % of it, as before)."""
    m = get_method(method)
    z, level = _tile(cell, "terrace")
    res = m.run(z, cell, **m.resolve(z, cell))
    assert (res.mask[level] == OBJECT).mean() < 0.02
    assert (res.mask == OBJECT).mean() < 0.03


@pytest.mark.parametrize("method", ["curvature", "rascor"])
def test_terrace_wall_across_the_tile_stays_ground(method):
    """A 4 m retaining wall across a 90 m tile (from its top side to its bottom side), the upper level
    over 70 % of it: the wall, mirrored at both sides, runs 270 m, beyond twice the largest object and
    the longest building: the terrain's, ground."""
    m = get_method(method)
    cell = 1.0
    n = 90
    y, x = (np.mgrid[0:n, 0:n] + 0.5) * cell
    z = 100.0 + 0.01 * x + 4.0 * (x < 63)
    z = (z + np.random.default_rng(1).normal(0.0, 0.03, z.shape)).astype(np.float32)
    res = m.run(z, cell, **m.resolve(z, cell))
    # at most the cells on top of the wall (RASCOR's step 3 takes them, as before)
    assert not (res.mask == OBJECT)[:, np.abs(np.arange(n) - 62) > 2].any()


@pytest.mark.parametrize("method,reach", [("curvature", "max_object_size_m"), ("rascor", "max_building_m")])
def test_roof_cut_by_the_edge_blocks_match_one_pass(method, reach):
    """A roof 35 x 32 m cut by the bottom and right edges, the reach 40 m (seen within it, its walls
    mirrored 70 m within twice it): an object, and blocks whose windows cut other levels give the mask
    of one pass (a level cut by a block's window spans more than the reach from it: in the halo)."""
    from bare_earth.core import pipeline
    n = 150
    y, x = np.mgrid[0:n, 0:n].astype(np.float64)
    z = 100.0 + 0.01 * x + 0.02 * y + np.random.default_rng(2).normal(0.0, 0.03, (n, n))
    z[115:, 118:] += 8.0                              # the roof cut by two edges
    z[60:85, 55:90] += 9.0                            # one across the seams
    z = z.astype(np.float32)
    params = {reach: 40.0}
    one = pipeline.run_array(method, z, 1.0, params=params).mask
    assert (one[115:, 118:] == OBJECT).mean() > 0.97
    for block in (48, 51):
        res = pipeline.run_array(method, z, 1.0, params=params, block=block, workers=1)
        assert res.info["blocks"] > 1
        np.testing.assert_array_equal(res.mask, one)


def test_curvature_edge_regions_where_every_cell_is_a_break():
    """No unmarked cell at all (every cell a break): the region stage with the runs cut by the edge
    finds no region and says so (it failed to unpack before)."""
    from bare_earth.core.curvature import profiles
    marked = np.ones((12, 12), bool)
    cells = np.zeros((12, 12), bool)
    got = profiles.find_enclosed_objects(np.zeros((12, 12), bool), marked, None, (1.0, 1.0), 100.0,
                                         edge_runs=(cells, cells.copy()), z=np.zeros((12, 12), np.float32))
    assert not got.any()


@pytest.mark.parametrize("shape", ["straight", "round"])
def test_rascor_keeps_quarry_benches_cutting_off_a_corner(shape):
    """A quarry in a corner of a 100 m tile at 0.5 m cells: benches 15 m wide, 6 m apart. The level
    around the pit meets all four sides and its wall cuts off the corner, as ``sample_c``'s roof, but
    the ground beyond its wall steps down again by as much: one of a sequence of levels, ground
    (without that test RASCOR took 80 % / 73 % of the cells for a building)."""
    m = get_method("rascor")
    y, x = np.mgrid[0:200, 0:200].astype(np.float64)
    r = (x + y) / np.sqrt(2) if shape == "straight" else np.hypot(x, y)
    top = 120 if shape == "straight" else 150
    z = 100 - 6.0 * np.clip(np.floor((top - r) / 30), 0, None)
    z = (z + np.random.default_rng(0).normal(0.0, 0.05, z.shape)).astype(np.float32)
    res = m.run(z, 0.5, **m.resolve(z, 0.5))
    assert (res.mask == OBJECT).mean() < 0.05
