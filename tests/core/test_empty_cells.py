"""Empty cells of a DSM (cells without a point in a lowest-point grid, issues 12 and 13): filled from
the nearest data before a filter runs when enclosed by data, nodata in every output."""
import numpy as np
import pytest

from bare_earth.core import fill, methods, pipeline
from bare_earth.core.codes import GROUND, NODATA
from bare_earth.core.fill import empty_run_cells, enclosed_empty, fill_empty, fill_empty_reach
from bare_earth.core.synthetic import make_scene

N = np.nan


def test_enclosed_empty_runs_along_rows_and_columns_exact():
    z = np.array([[1, N, N, 1, 1, 1, 1],
                  [1, 1, 1, 1, N, 1, 1],
                  [N, N, 1, 1, N, 1, 1],
                  [1, 1, 1, 1, 1, 1, N],
                  [1, N, N, N, N, 1, 1]], np.float32)
    want = np.zeros(z.shape, bool)
    want[0, 1:3] = True                          # a run of two along the row
    want[1:3, 4] = True                          # a run of two down the column
    want[2, 0:2] = True                          # the row runs to the edge, the columns are bounded
    want[3, 6] = True                            # the row runs to the edge, the column is bounded
    # the last row: a run of four, wider than 3, its columns run to the edge
    np.testing.assert_array_equal(enclosed_empty(np.isfinite(z), 3), want)
    want[4, 1:5] = True                          # a run of four when four are allowed
    np.testing.assert_array_equal(enclosed_empty(np.isfinite(z), 4), want)


def test_fill_empty_takes_the_nearest_data_and_keeps_border_and_wide_holes():
    z = np.arange(49, dtype=np.float32).reshape(7, 7)
    z[2:5, 2:5] = N                              # a 3 x 3 hole
    z[0, :2] = N                                 # outer border
    z[6, 6] = N                                  # a corner
    out, n = fill_empty(z, 3)
    assert n == 9 and np.isnan(z[3, 3])          # the input untouched
    want = z.copy()
    want[2, 2:5] = [9, 10, 11]                   # from the row above (first of the sides: north)
    want[3, 2], want[3, 4] = 22, 26              # from the west / east sides
    want[3, 3] = 10                              # the centre: two rounds, from its northern neighbour
    want[4, 2:5] = [37, 38, 39]                  # from the row below
    np.testing.assert_array_equal(out, want)
    assert np.isnan(out[0, :2]).all() and np.isnan(out[6, 6])
    same, n = fill_empty(z, 2)                   # runs of 3 are wider than 2: nothing filled
    assert n == 0 and same is z


def test_fill_empty_without_holes_returns_the_input():
    z = np.ones((5, 6), np.float32)
    out, n = fill_empty(z, 10)
    assert out is z and n == 0


@pytest.mark.parametrize("seed", [0, 1])
def test_fill_empty_of_a_window_equals_the_whole_raster_within_its_reach(seed):
    rng = np.random.default_rng(seed)
    z = rng.normal(0, 1, (140, 150)).astype(np.float32)
    z[rng.random(z.shape) < 0.5] = N             # scattered empty cells
    z[59:76, 49:62] = 1.0                        # a hole of 15 x 11 cells inside a frame of data
    z[60:75, 50:61] = N
    z[:, :3] = N                                 # a border strip
    width = 12
    reach = fill_empty_reach(width)
    whole, n = fill_empty(z, width)
    assert n > 0.4 * z.size and np.isnan(whole[:, :3]).all()
    assert np.isfinite(whole[60:75, 50:61]).all()      # 11 wide along its rows
    r0, r1, c0, c1 = 55, 95, 40, 100
    win = z[r0 - reach:r1 + reach, c0 - reach:c1 + reach]
    part, _ = fill_empty(win, width)
    np.testing.assert_array_equal(part[reach:-reach, reach:-reach], whole[r0:r1, c0:c1])


def test_empty_run_cells_from_metres():
    assert empty_run_cells((1.0, 1.0)) == int(fill.EMPTY_RUN_M)
    assert empty_run_cells(2.0) == int(fill.EMPTY_RUN_M / 2)
    assert empty_run_cells(1000.0) == 1
    assert empty_run_cells((0.5, 0.5)) == fill.EMPTY_RUN_MAX_CELLS == 128
    assert empty_run_cells((0.0257, 0.0278)) == 128            # a drone DSM: the reach stays 193 cells
    assert fill_empty_reach(128) == 193


def _holey(dsm, seed=0, share=0.7):
    """``dsm`` with ``share`` of its cells empty (at random: the lowest-point grid of a cloud sparser than
    the cells, as the ISPRS samples at 1 m, 32-85 % empty), a lake of 90 x 80 m (wider than
    EMPTY_RUN_M both ways) and a nodata border strip."""
    rng = np.random.default_rng(seed)
    z = dsm.copy()
    z[rng.random(z.shape) < share] = N
    z[20:110, 120:200] = N
    z[:, -4:] = N
    return z


SCENE = make_scene("city", (192, 224), seed=5)
HOLEY = _holey(SCENE.dsm)


@pytest.mark.parametrize("method", sorted(methods.available_methods()))
def test_each_filter_with_empty_cells_close_to_without(method):
    """A city (1 m) with 70 % of its cells emptied, a lake and a nodata border: each filter's mask on the
    remaining cells agrees with its mask of the full DSM and stays as right against the truth; the outputs'
    nodata cells are exactly the input's (the lake too: no ground class there)."""
    full = pipeline.run_array(method, SCENE.dsm, SCENE.cell_size)
    res = pipeline.run_array(method, HOLEY, SCENE.cell_size)
    data = np.isfinite(HOLEY)
    assert res.info["empty_cells_filled"] > 0.5 * HOLEY.size
    np.testing.assert_array_equal(res.mask == NODATA, ~data)
    np.testing.assert_array_equal(np.isnan(res.dtm), ~data)
    for name, (_, _, nod) in methods.get_method(method).extras.items():   # side products: nodata there too
        if nod is not None and name in res.extras:
            at = res.extras[name][..., ~data]
            assert (np.isnan(at) if np.isnan(nod) else at == nod).all(), name
    truth = SCENE.mask[data] == GROUND
    err_full = np.mean((full.mask[data] == GROUND) != truth)
    err_holes = np.mean((res.mask[data] == GROUND) != truth)
    agree = np.mean(full.mask[data] == res.mask[data])
    assert agree > 0.99 and err_holes < err_full + 0.006, (agree, err_full, err_holes)
    ground = data & (res.mask == GROUND)
    # measured: agreement 0.995-1.0, DTM RMSE 0.05-0.08 m; the empty cells left NaN: curvature,
    # geodesic and morphological agree on 0.91-0.94, dtm's RMSE 0.47 m
    assert np.sqrt(np.mean((res.dtm[data] - SCENE.dtm[data]) ** 2)) < 0.15
    assert np.array_equal(res.dtm[ground], HOLEY[ground])


def _opening_objects(z, cell_size, progress=None, **p):
    """Objects: cells 1 m above the grey opening of 9 x 9 cells (reach 8 cells); empty cells read as far
    below (so a cell the pipeline left empty changes its neighbours' opening)."""
    from scipy import ndimage

    from bare_earth.core.common import FilterResult, finish_mask, report
    filled = np.where(np.isfinite(z), z, np.float32(-1e4)).astype(np.float32)
    mask = (filled - ndimage.grey_opening(filled, size=(9, 9)) > 1.0).astype(np.uint8)
    report(progress, 1.0)
    return FilterResult(finish_mask(mask, z), info={})


@pytest.mark.parametrize("block,workers", [(32, 1), (40, 2)])
def test_run_file_blocked_with_empty_cells_equals_one_pass(tmp_path, monkeypatch, block, workers):
    """Each block fills its window's empty cells itself: the halo holds the fill's reach besides the
    method's, so every block fills as the whole raster does and the outputs equal one pass; the log
    gives the cells filled; the outputs' nodata cells are the input's."""
    gdal = pytest.importorskip("osgeo.gdal")
    from bare_earth.core import grid
    from bare_earth.core.methods import Method
    monkeypatch.setattr(fill, "EMPTY_RUN_M", 12.0)     # runs of 12 cells: a reach of 19
    rng = np.random.default_rng(4)
    z = make_scene("city", (150, 140), seed=2).dsm
    z[rng.random(z.shape) < 0.3] = N
    for r in range(12, 150, 25):                        # gaps 10 rows high across the raster (between
        z[r:r + 10, 3:] = N                             # flight strips), cut by the blocks' windows
    z[:, :3] = N
    meth = Method(name="opening", run=_opening_objects, resolve=lambda z, c, **p: {}, halo=lambda p, c: 8)
    src = grid.write_array(tmp_path / "dsm.tif", np.nan_to_num(z, nan=-9999.0),
                           (1000.0, 1.0, 0.0, 2000.0, 0.0, -1.0), 32633, nodata=-9999.0)
    runs = {}
    for name, kw in (("one", {}), ("blk", {"block": block, "workers": workers})):
        out = {k: str(tmp_path / f"{name}_{k}.tif") for k in ("mask", "dtm")}
        logs = []
        info = pipeline.run_file(meth, src, out, log=logs.append, **kw)
        runs[name] = (gdal.Open(out["mask"]).ReadAsArray(), grid.open_dsm(out["dtm"]).read(), (info, logs))
    (m1, d1, (i1, l1)), (m2, d2, (i2, l2)) = runs["one"], runs["blk"]
    assert i1["blocks"] == 1 and i2["blocks"] > 4
    n = fill_empty(z, empty_run_cells(1.0))[1]
    assert i1["empty_cells_filled"] == i2["empty_cells_filled"] == n > 0.5 * z.size
    for logs in (l1, l2):
        assert any(s.startswith(f"{n} empty cell(s) enclosed by data") for s in logs), logs
    np.testing.assert_array_equal(m1, m2)
    np.testing.assert_array_equal(m1 == NODATA, ~np.isfinite(z))
    np.testing.assert_array_equal(np.isnan(d1), ~np.isfinite(z))
    np.testing.assert_array_equal(d1[m1 == GROUND], d2[m1 == GROUND])
