"""Pipeline: params checked, DTM = z on the ground and filled elsewhere, blocks, files, cancel."""
import math
import os
import re

import numpy as np
import pytest

from bare_earth.core import pipeline
from bare_earth.core.codes import GROUND, LOW, NODATA, OBJECT
from bare_earth.core.common import Cancelled, FilterResult, finish_mask, report
from bare_earth.core.methods import Method, Param

gdal = pytest.importorskip("osgeo.gdal")
from osgeo import osr  # noqa: E402

from bare_earth.core import grid  # noqa: E402

GT = (1000.0, 1.0, 0.0, 2000.0, 0.0, -1.0)


# ---- a tiny local method: object where z > threshold, low where z < low ---------------------

def _run(z, cell_size, progress=None, threshold_m=5.0, low_m=-5.0, marks=None):
    mask = np.zeros(z.shape, np.uint8)
    mask[z > threshold_m] = OBJECT
    mask[z < low_m] = LOW
    if marks is not None:                       # an aux input: forced objects
        mask[np.asarray(marks, bool)] = OBJECT
    report(progress, 0.5)
    flag = np.where(mask == OBJECT, 7, 0).astype(np.uint8)
    flag[~np.isfinite(z)] = 255
    two = np.stack([np.nan_to_num(z, nan=-1.0), np.full(z.shape, 3.0)]).astype(np.float32)
    return FilterResult(finish_mask(mask, z), extras={"flag": flag, "two": two},
                        info={"threshold_m": threshold_m, "object_cells": int((mask == OBJECT).sum())})


def _resolve(z, cell_size, threshold_m=None, low_m=-5.0):
    if threshold_m is None:
        threshold_m = 5.0
    return {"threshold_m": float(threshold_m), "low_m": float(low_m)}


ABOVE = Method(name="above", run=_run, resolve=_resolve, halo=lambda p, c: 1,
               extras={"flag": (np.uint8, 1, 255), "two": (np.float32, 2, -1.0)},
               params=(Param("threshold_m", "float", None, "object threshold", minimum=0.0, maximum=100.0),
                       Param("low_m", "float", -5.0, "low threshold", minimum=-100.0, maximum=0.0)))


def scene(dtype=np.float32, nodata=True):
    """12 x 11 tilted plane (0-2.1 m; int: 0-4 m terraces) with single-cell objects and a low cell."""
    r, c = np.mgrid[0:12, 0:11]
    z = (0.1 * r + 0.1 * c).astype(np.float64)
    if np.dtype(dtype).kind == "i":
        z = (r + c) // 5                         # integral terraces 0-4 m, all below 5 m
    objs = [(2, 3), (5, 7), (6, 6), (9, 2)]      # (5,7) and (6,6) touch diagonally
    for rc in objs:
        z[rc] = 60.0
    z[8, 8] = -40.0
    if nodata and np.dtype(dtype).kind == "f":
        z[0, 10] = np.nan
        z[11, 0] = np.nan
    return z.astype(dtype), objs


def neighbours(z, r, c):
    w = z[max(0, r - 1):r + 2, max(0, c - 1):c + 2].astype(np.float64)
    return w[np.isfinite(w) & (np.abs(w) < 30)]


# ---- run_array ----------------------------------------------------------------------------

@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int16])
def test_run_array_dtm_mask_ndsm(dtype):
    z, objs = scene(dtype)
    z0 = z.copy()
    res = pipeline.run_array(ABOVE, z, 1.0)
    np.testing.assert_array_equal(z, z0)                        # input untouched
    zf = z.astype(np.float32)
    nod = ~np.isfinite(zf)
    expect = np.zeros(z.shape, np.uint8)
    for rc in objs:
        expect[rc] = OBJECT
    expect[8, 8] = LOW
    expect[nod] = NODATA
    np.testing.assert_array_equal(res.mask, expect)
    assert res.mask.dtype == np.uint8 and res.dtm.dtype == np.float32 and res.ndsm.dtype == np.float32
    ground = expect == GROUND
    np.testing.assert_array_equal(res.dtm[ground], zf[ground])  # exact on the ground
    assert np.isnan(res.dtm[nod]).all() and np.isnan(res.ndsm[nod]).all()
    for r, c in objs + [(8, 8)]:
        nb = neighbours(zf, r, c)
        assert np.isfinite(res.dtm[r, c])
        assert nb.min() - 1e-4 <= res.dtm[r, c] <= nb.max() + 1e-4
    np.testing.assert_array_equal(res.ndsm[~nod], (zf - res.dtm)[~nod])
    assert (res.ndsm[ground] == 0).all()
    assert res.ndsm[2, 3] > 50 and res.ndsm[8, 8] < -30
    valid = (~nod).sum()
    cp = res.info["classes_percent"]
    assert cp["ground"] == pytest.approx(100.0 * ground.sum() / valid)
    assert cp["object"] == pytest.approx(100.0 * 4 / valid)
    assert cp["low outlier"] == pytest.approx(100.0 / valid)
    assert cp["nodata cells"] == nod.sum()
    assert res.info["params"] == {"threshold_m": 5.0, "low_m": -5.0}
    assert res.info["halo_cells"] == 1 and res.info["object_cells"] == 4
    np.testing.assert_array_equal(res.extras["flag"], np.where(expect == OBJECT, 7, np.where(nod, 255, 0)))
    assert res.extras["two"].shape == (2,) + z.shape


def test_run_array_user_param_used():
    z, _ = scene()
    res = pipeline.run_array(ABOVE, z, (1.0, 2.0), {"threshold_m": 1.5})
    assert res.info["params"]["threshold_m"] == 1.5
    zf = z.astype(np.float32)
    np.testing.assert_array_equal(res.mask == OBJECT, np.isfinite(zf) & (zf > 1.5))


def test_unknown_parameter_named():
    z, _ = scene()
    with pytest.raises(ValueError, match="thresold_m"):
        pipeline.run_array(ABOVE, z, 1.0, {"thresold_m": 3.0})
    with pytest.raises(ValueError, match="bogus"):
        pipeline.run_array("slopeprofile", z, 1.0, {"bogus": 1})


@pytest.mark.parametrize("value", [101.0, -0.5, float("nan")])
def test_out_of_range_custom_method(value):
    z, _ = scene()
    with pytest.raises(ValueError, match="threshold_m.*out of range"):
        pipeline.run_array(ABOVE, z, 1.0, {"threshold_m": value})


def test_aux_wrong_shape():
    z, _ = scene()
    with pytest.raises(ValueError, match="marks.*shape"):
        pipeline.run_array(ABOVE, z, 1.0, aux={"marks": np.zeros((3, 3), bool)})


@pytest.mark.parametrize("workers", [1, 2])
def test_blocked_equals_one_pass(workers):
    z, _ = scene()
    marks = np.zeros(z.shape, bool)
    marks[3, 9] = marks[10, 5] = True            # aux cut into blocks with the surface
    one = pipeline.run_array(ABOVE, z, 1.0, aux={"marks": marks})
    assert one.mask[3, 9] == OBJECT and one.mask[10, 5] == OBJECT
    fr = []
    blk = pipeline.run_array(ABOVE, z, 1.0, aux={"marks": marks}, block=7, workers=workers,
                             progress=fr.append)
    assert blk.info["blocks"] == 4 and one.info["blocks"] == 1
    np.testing.assert_array_equal(blk.mask, one.mask)
    np.testing.assert_allclose(blk.dtm, one.dtm, rtol=0, atol=1e-5, equal_nan=True)
    np.testing.assert_allclose(blk.ndsm, one.ndsm, rtol=0, atol=1e-5, equal_nan=True)
    for k in one.extras:
        np.testing.assert_array_equal(blk.extras[k], one.extras[k])
    assert blk.info["classes_percent"] == one.info["classes_percent"]
    assert fr[-1] == 1.0 and fr == sorted(fr)


@pytest.mark.parametrize("block,workers", [(None, 1), (5, 1), (5, 2)])
def test_cancel_propagates(block, workers):
    z, _ = scene()
    seen = []

    def progress(f):
        seen.append(f)
        if f > 0.3:
            raise Cancelled()

    with pytest.raises(Cancelled):
        pipeline.run_array(ABOVE, z, 1.0, block=block, workers=workers, progress=progress)
    assert max(seen) < 1.0


# ---- run_file ------------------------------------------------------------------------------

def write(tmp_path, z, name="dsm.tif", crs=32633, nodata=None, gt=GT, dtype=None):
    return grid.write_array(tmp_path / name, z, gt, crs, nodata=nodata, dtype=dtype)


def outputs(folder, *keys, prefix=""):
    return {k: str(folder / f"{prefix}{k}.tif") for k in keys}


def read(path):
    ds = gdal.Open(str(path))
    b = ds.GetRasterBand(1)
    return ds.ReadAsArray(), b.GetNoDataValue(), ds.GetGeoTransform(), ds.GetProjection()


def partials(folder):
    return [p for p in os.listdir(folder) if ".partial" in p]


@pytest.mark.parametrize("dtype", [np.float32, np.int16])
def test_run_file_declared_nodata_kept(tmp_path, dtype):
    z, objs = scene(dtype, nodata=False)
    z[0, 10] = z[11, 0] = -9999
    src = write(tmp_path, z, nodata=-9999)
    outs = outputs(tmp_path, "dtm", "ndsm", "mask")
    info = pipeline.run_file(ABOVE, src, outs)
    _, _, gt0, prj0 = read(src)
    nod = z == -9999
    zf = z.astype(np.float32)
    dtm, nd, gt, prj = read(outs["dtm"])
    assert nd == -9999 and gt == pytest.approx(GT) and prj == prj0 and prj
    assert (dtm[nod] == -9999).all()
    mask, mnd, mgt, mprj = read(outs["mask"])
    assert mnd == 255 and mgt == pytest.approx(GT) and mprj == prj0
    assert set(np.unique(mask).tolist()) <= {0, 1, 2, 255}
    np.testing.assert_array_equal(mask == NODATA, nod)
    ground = mask == GROUND
    np.testing.assert_array_equal(dtm[ground], zf[ground])
    ndsm, nnd, _, _ = read(outs["ndsm"])
    assert nnd == -9999 and (ndsm[nod] == -9999).all()
    np.testing.assert_allclose(ndsm[~nod], zf[~nod] - dtm[~nod], atol=1e-5)
    for rc in objs:
        assert mask[rc] == OBJECT and 0 <= dtm[rc] <= 30
    assert (tmp_path / "mask.qml").exists() and partials(tmp_path) == []
    ref = pipeline.run_array(ABOVE, np.where(nod, np.nan, zf), 1.0)
    np.testing.assert_array_equal(mask, ref.mask)
    assert info["classes_percent"] == pytest.approx(ref.info["classes_percent"])
    assert info["cell_size_m"] == (1.0, 1.0)


def test_run_file_nan_undeclared_outputs_declare_nan(tmp_path):
    z, _ = scene()
    src = write(tmp_path, z)
    outs = outputs(tmp_path, "dtm", "ndsm", "mask")
    logs = []
    info = pipeline.run_file(ABOVE, src, outs, log=logs.append)
    for k in ("dtm", "ndsm"):
        a, nd, _, _ = read(outs[k])
        assert nd is not None and math.isnan(nd)
        np.testing.assert_array_equal(np.isnan(a), np.isnan(z))
    assert any("NaN" in s and s.startswith("Warning:") for s in logs)
    assert any("NaN" in w for w in info["warnings"])


def test_run_file_feet_dtm_back_in_feet(tmp_path):
    z, objs = scene()                            # heights and cells in US survey feet
    src = write(tmp_path, z, crs=2263, gt=(300000.0, 3.0, 0.0, 60000.0, 0.0, -3.0))
    outs = outputs(tmp_path, "dtm", "ndsm", "mask")
    logs = []
    info = pipeline.run_file(ABOVE, src, outs, log=logs.append)
    assert info["cell_size_m"] == pytest.approx((0.9144018, 0.9144018))
    assert any("linear unit" in s for s in logs)
    dtm, _, _, prj = read(outs["dtm"])
    mask = read(outs["mask"])[0]
    ground = mask == GROUND
    np.testing.assert_array_equal(dtm[ground], z[ground])      # feet, not metres, bit for bit
    # the threshold (5 m = 16.4 ft) is applied in metres: 60 ft objects found, 2.2 ft ground kept
    for rc in objs:
        assert mask[rc] == OBJECT
    ndsm = read(outs["ndsm"])[0]
    assert ndsm[2, 3] == pytest.approx(60.0 - dtm[2, 3], rel=1e-5)
    assert osr.SpatialReference(wkt=prj).GetLinearUnits() == pytest.approx(0.3048006096)


@pytest.mark.parametrize("dtype", [np.float32, np.int16])
def test_run_file_feet_ground_exact_many_values(tmp_path, dtype):
    rng = np.random.default_rng(0)
    z = (rng.random((20, 20)) * 15 + 0.5).astype(np.float32)   # all below 16.4 ft = 5 m
    if dtype == np.int16:
        z = np.round(z).astype(np.int16)
    src = write(tmp_path, z, crs=2263, nodata=-9999)
    outs = outputs(tmp_path, "dtm", "ndsm", "mask")
    pipeline.run_file(ABOVE, src, outs)
    assert (read(outs["mask"])[0] == GROUND).all()
    np.testing.assert_array_equal(read(outs["dtm"])[0], z.astype(np.float32))
    np.testing.assert_array_equal(read(outs["ndsm"])[0], 0.0)


@pytest.mark.parametrize("workers", [1, 2])
def test_run_file_blocked_equals_one_pass(tmp_path, workers):
    rng = np.random.default_rng(1)
    r, c = np.mgrid[0:40, 0:37]
    z = (0.05 * r + 0.03 * c + rng.normal(0, 0.05, r.shape)).astype(np.float32)
    z[rng.random(z.shape) < 0.04] = 20.0         # scattered single-cell objects (halo 1 enough)
    z[:3, :5] = -9999                            # a corner of nodata
    z[17:19, 17:19] = -9999                      # nodata at a block corner
    src = write(tmp_path, z, nodata=-9999)
    keys = ("dtm", "ndsm", "mask", "flag", "two")
    one = outputs(tmp_path, *keys, prefix="one_")
    blk = outputs(tmp_path, *keys, prefix="blk_")
    pipeline.run_file(ABOVE, src, one)
    info = pipeline.run_file(ABOVE, src, blk, block=16, workers=workers)
    assert info["blocks"] == 9
    for k in keys:
        a, b = gdal.Open(one[k]).ReadAsArray(), gdal.Open(blk[k]).ReadAsArray()
        if k in ("mask", "flag"):
            np.testing.assert_array_equal(a, b)
        else:
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-5)


def test_run_file_block_all_nodata(tmp_path, monkeypatch):
    from bare_earth.core import fill
    monkeypatch.setattr(fill, "EMPTY_RUN_M", 2.0)      # the fill of empty cells reaches 4 cells
    assert pipeline.window_halo(ABOVE, {}, (1.0, 1.0)) == 1 + 4
    z = np.full((160, 160), -9999, np.float32)
    z[:8, :8] = 1.0
    z[2, 2] = 30.0
    src = write(tmp_path, z, nodata=-9999)
    outs = outputs(tmp_path, "dtm", "mask", "flag", "two")
    pipeline.run_file(ABOVE, src, outs, block=8)
    mask = read(outs["mask"])[0]
    assert mask[2, 2] == OBJECT and (mask[8:, :] == NODATA).all() and (mask[:, 8:] == NODATA).all()
    dtm = read(outs["dtm"])[0]
    assert (dtm[8:, :] == -9999).all() and dtm[2, 2] == pytest.approx(1.0)
    assert (read(outs["flag"])[0][8:, :] == 255).all()
    two = gdal.Open(outs["two"]).ReadAsArray()
    # blocks whose window holds no data never run (a window's corner lies on a multiple of
    # blocks.alignment, 64: the blocks from row or column 136 on read from 128, all nodata)
    assert (two[:, 136:, :] == -1.0).all() and (two[:, :, 136:] == -1.0).all()
    assert (two[1, :8, :8] == 3.0).all()


@pytest.mark.parametrize("block,workers", [(None, 1), (8, 1), (8, 2)])
def test_run_file_cancel_leaves_nothing(tmp_path, block, workers):
    z, _ = scene()
    src = write(tmp_path, z)
    before = set(os.listdir(tmp_path))
    outs = outputs(tmp_path, "dtm", "ndsm", "mask", "flag")

    def progress(f):
        if f > 0.5:
            raise Cancelled()

    with pytest.raises(Cancelled):
        pipeline.run_file(ABOVE, src, outs, block=block, workers=workers, progress=progress)
    assert set(os.listdir(tmp_path)) == before


@pytest.mark.parametrize("kw", [dict(block=-2147483648), dict(block=0), dict(block=(64, -1)), dict(block=64.5),
                                dict(processes=0), dict(workers=float("nan")), dict(block="64")])
def test_run_file_blocks_and_counts_that_are_no_whole_numbers_refused_before_work(tmp_path, kw):
    """A block of -2147483648 cells (QGIS's whole number of a NaN) ran for ever (a 60 x 70 raster had not
    finished in 10 min); zero or negative blocks and processes, fractions and NaN are refused before work."""
    import subprocess
    import sys
    z, _ = scene()
    src = write(tmp_path, z)
    before = set(os.listdir(tmp_path))
    with pytest.raises(ValueError, match=r"(block size|workers|processes) must be a whole number"):
        pipeline.check_run_counts(**kw)
    if kw.get("block") == -2147483648:   # in a child process: without the check it never ends
        code = ("import sys; sys.path.insert(0, sys.argv[1]); from bare_earth.core import pipeline\n"
                "try:\n    pipeline.run_file('morphological', sys.argv[2], {'mask': sys.argv[3]}, block=-2147483648)\n"
                "except ValueError as exc:\n    print(exc)")
        plugins = os.path.dirname(os.path.dirname(os.path.dirname(pipeline.__file__)))
        res = subprocess.run([sys.executable, "-c", code, plugins, src, str(tmp_path / "m.tif")],
                             capture_output=True, text=True, timeout=120)
        assert "the block size must be a whole number of cells" in res.stdout
    assert set(os.listdir(tmp_path)) == before
    for ok in (dict(), dict(block=64), dict(block=(64, 128)), dict(workers=0, processes=2), dict(block=64.0)):
        pipeline.check_run_counts(**ok)


def test_run_file_cancel_keeps_previous_outputs(tmp_path):
    z, _ = scene()
    src = write(tmp_path, z)
    outs = outputs(tmp_path, "dtm", "mask")
    pipeline.run_file(ABOVE, src, outs)
    first = {k: gdal.Open(p).ReadAsArray() for k, p in outs.items()}

    def progress(f):
        if f > 0.5:
            raise Cancelled()

    with pytest.raises(Cancelled):
        pipeline.run_file(ABOVE, src, outs, params={"threshold_m": 1.0}, progress=progress)
    for k, p in outs.items():
        np.testing.assert_array_equal(gdal.Open(p).ReadAsArray(), first[k])
    assert partials(tmp_path) == []


def test_run_file_progress_reaches_one(tmp_path):
    z, _ = scene()
    src = write(tmp_path, z)
    fr = []
    pipeline.run_file(ABOVE, src, outputs(tmp_path, "mask"), block=5, progress=fr.append)
    assert fr[-1] == 1.0 and fr == sorted(fr)


def test_run_file_logs_grid_warnings(tmp_path):
    z, _ = scene()
    src = write(tmp_path, z, crs="", gt=(0.0, 1.0, 0.0, 12.0, 0.0, -2.0))
    logs = []
    info = pipeline.run_file(ABOVE, src, outputs(tmp_path, "mask"), log=logs.append)
    assert any("no CRS" in s for s in logs)
    assert any("not square" in s for s in logs)
    assert any("NaN" in s for s in logs)
    assert len(logs) >= len(info["warnings"]) == 3
    assert read(tmp_path / "mask.tif")[3] == ""


def test_run_file_extras_written(tmp_path):
    z, objs = scene()
    src = write(tmp_path, z)
    outs = outputs(tmp_path, "flag", "two")
    pipeline.run_file(ABOVE, src, outs)
    assert not (tmp_path / "dtm.tif").exists() and not (tmp_path / "mask.tif").exists()
    flag, fnd, fgt, _ = read(outs["flag"])
    assert fnd == 255 and fgt == pytest.approx(GT)
    fds = gdal.Open(outs["flag"])                # kept alive while its band is used
    assert fds.GetRasterBand(1).DataType == gdal.GDT_Byte
    expect = np.zeros(z.shape, np.uint8)
    for rc in objs:
        expect[rc] = 7
    expect[np.isnan(z)] = 255
    np.testing.assert_array_equal(flag, expect)
    ds = gdal.Open(outs["two"])
    assert ds.RasterCount == 2 and ds.GetRasterBand(2).GetNoDataValue() == -1.0
    two = ds.ReadAsArray()
    np.testing.assert_array_equal(two[1], 3.0)
    np.testing.assert_array_equal(two[0], np.nan_to_num(z, nan=-1.0))


def test_run_file_registered_method(tmp_path):
    from bare_earth.core.synthetic import make_scene
    s = make_scene("city", shape=(40, 40), seed=3, low_blunders=False)
    src = write(tmp_path, s.dsm.astype(np.float32), nodata=-9999)
    outs = outputs(tmp_path, "dtm", "mask")
    info = pipeline.run_file("slopeprofile", src, outs, params={"max_object_size_m": 20.0})
    mask = read(outs["mask"])[0]
    assert set(np.unique(mask).tolist()) <= {0, 1, 2, 255}
    assert info["method"] == "slopeprofile" and info["params"]["max_object_size_m"] == 20.0
    assert np.isfinite(read(outs["dtm"])[0]).all()


def _own_dtm_method(dtm_value):
    def run(z, cell_size, progress=None, threshold_m=5.0):
        mask = np.where(z > threshold_m, OBJECT, GROUND).astype(np.uint8)
        dtm = np.where(mask == OBJECT, dtm_value, z).astype(np.float32)
        return FilterResult(finish_mask(mask, z), dtm=dtm)
    return Method(name="owndtm", run=run, resolve=lambda z, c, **p: {"threshold_m": 5.0},
                  halo=lambda p, c: 1)


def test_method_dtm_used_instead_of_filling():
    z, objs = scene()
    res = pipeline.run_array(_own_dtm_method(1.25), z, 1.0)
    for rc in objs:
        assert res.dtm[rc] == np.float32(1.25)
    assert np.isnan(res.dtm[0, 10]) and np.isnan(res.ndsm[0, 10])   # nodata stays NaN
    ground = res.mask == GROUND
    np.testing.assert_array_equal(res.dtm[ground], z[ground])


def test_unusable_method_dtm_is_filled():
    z, objs = scene()
    res = pipeline.run_array(_own_dtm_method(np.nan), z, 1.0)    # NaN at valid cells: refill
    fill = pipeline.run_array(ABOVE, z, 1.0, {"low_m": -100.0})
    for rc in objs:
        assert np.isfinite(res.dtm[rc]) and res.dtm[rc] == fill.dtm[rc]


def test_run_file_aux_blocked(tmp_path):
    z, _ = scene(nodata=False)
    marks = np.zeros(z.shape, bool)
    marks[3, 9] = marks[7, 7] = True
    src = write(tmp_path, z)
    with pytest.raises(ValueError, match="marks.*shape"):
        pipeline.run_file(ABOVE, src, outputs(tmp_path, "mask"), aux={"marks": marks[:-1]})
    assert partials(tmp_path) == [] and not (tmp_path / "mask.tif").exists()
    for b in (None, 4):
        out = outputs(tmp_path, "mask", prefix=f"b{b}_")
        pipeline.run_file(ABOVE, src, out, aux={"marks": marks}, block=b)
        mask = read(out["mask"])[0]
        assert mask[3, 9] == OBJECT and mask[7, 7] == OBJECT and mask[3, 8] == GROUND


def test_run_file_resolves_on_central_window(tmp_path, monkeypatch):
    seen = []

    def resolve(z, cell_size, **p):
        seen.append(z.shape)
        return _resolve(z, cell_size, **p)

    meth = Method(name="above2", run=_run, resolve=resolve, halo=lambda p, c: 1, params=ABOVE.params)
    monkeypatch.setattr(pipeline, "RESOLVE_SIDE", 6)
    z, _ = scene()
    logs = []
    pipeline.run_file(meth, write(tmp_path, z), outputs(tmp_path, "mask"), log=logs.append)
    assert seen == [(6, 6)] and any("central 6 x 6" in s for s in logs)


# ---- #15: scale/offset, corrupt files, far heights, window planning ------------------------------

def test_run_file_applies_scale_and_offset_and_says_so(tmp_path):
    """Int16 counts with scale 0.1 and offset 100: filtered as heights 100 + 0.1 * count
    (the raw counts, about -1000, would all be low outliers)."""
    z, objs = scene()
    counts = np.round((np.nan_to_num(z, nan=-3176.8) - 100.0) * 10).astype(np.int16)    # heights = z
    p = grid.write_array(tmp_path / "scaled.tif", counts, GT, 32633, nodata=-32768, dtype="Int16")
    ds = gdal.Open(p, gdal.GA_Update)
    ds.GetRasterBand(1).SetScale(0.1)
    ds.GetRasterBand(1).SetOffset(100.0)
    ds = None
    lines = []
    info = pipeline.run_file(ABOVE, p, {"mask": tmp_path / "m.tif", "dtm": tmp_path / "d.tif"},
                             log=lines.append)
    assert any("scale" in s and "0.1" in s and "100" in s for s in lines)
    assert info["notes"] and "scale" in info["notes"][0]
    mask = gdal.Open(str(tmp_path / "m.tif")).ReadAsArray()
    dtm = gdal.Open(str(tmp_path / "d.tif")).ReadAsArray()
    assert all(mask[rc] == OBJECT for rc in objs) and mask[8, 8] == LOW
    ground = mask == GROUND
    want = (counts * 0.1 + 100.0).astype(np.float32)
    np.testing.assert_array_equal(dtm[ground], want[ground])  # the heights, not the counts
    valid = dtm != -32768                                      # the DSM's nodata, kept
    assert valid.sum() == dtm.size - 2 and -1 < dtm[valid].min() and dtm[valid].max() < 3


def test_run_file_scaled_band_whose_nodata_is_also_a_height(tmp_path):
    """UInt16 counts with nodata 0, scale 0.01 and offset -100 (heights from -100 m): the DTM and
    nDSM, written as heights, declared the stored 0 as their nodata, so every ground cell at 0 m
    (sea level, the count 10000) read as nodata; they now declare -100, the height of the nodata
    cells, and the log says so."""
    z, objs = scene()
    counts = np.round((np.nan_to_num(z, nan=-100.0) + 100.0) * 100).astype(np.uint16)  # heights = z
    counts[:, 0] = 10000                                                                # ground at 0 m
    p = grid.write_array(tmp_path / "scaled.tif", counts, GT, 32633, nodata=0, dtype="UInt16")
    ds = gdal.Open(p, gdal.GA_Update)
    ds.GetRasterBand(1).SetScale(0.01)
    ds.GetRasterBand(1).SetOffset(-100.0)
    ds = None
    lines = []
    pipeline.run_file(ABOVE, p, {"mask": tmp_path / "m.tif", "dtm": tmp_path / "d.tif", "ndsm": tmp_path / "n.tif"},
                      log=lines.append)
    assert any("declare the height of the nodata cells, -100" in s for s in lines), lines
    for name in ("d.tif", "n.tif"):
        ds = gdal.Open(str(tmp_path / name))
        band = ds.GetRasterBand(1)
        a = band.ReadAsArray()
        assert band.GetNoDataValue() == -100.0
        assert np.count_nonzero(a == -100.0) == np.count_nonzero(counts == 0) > 0, name
    dtm = gdal.Open(str(tmp_path / "d.tif")).ReadAsArray()
    assert (dtm[:, 0] == 0.0).all()


def test_run_file_corrupt_input_is_a_value_error(tmp_path):
    z = np.random.default_rng(1).random((600, 600), dtype=np.float32)
    p = grid.write_array(tmp_path / "ok.tif", z, GT, 32633)
    data = open(p, "rb").read()
    bad = tmp_path / "broken.tif"
    bad.write_bytes(data[: len(data) // 3])
    with pytest.raises(ValueError, match=r"broken\.tif"):
        pipeline.run_file(ABOVE, bad, {"mask": tmp_path / "m.tif"}, block=128)
    assert not (tmp_path / "m.tif").exists() and partials(tmp_path) == []


@pytest.mark.parametrize("far", [1e30, -1e30, -3.4e38])
def test_far_heights_are_nodata_with_a_log_line(tmp_path, far):
    import warnings
    z, objs = scene()
    z[3, 3] = far
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = pipeline.run_array(ABOVE, z, 1.0)
        assert res.mask[3, 3] == NODATA and np.isnan(res.dtm[3, 3])
        assert any("1 cell" in w and "nodata" in w for w in res.info["warnings"])
        p = grid.write_array(tmp_path / "far.tif", z, GT, 32633)
        lines = []
        for block in (None, 5):
            lines.clear()
            info = pipeline.run_file(ABOVE, p, {"mask": tmp_path / "m.tif"}, block=block, log=lines.append)
            assert any("1 cell" in w for w in info["warnings"]), block
            # the log (QGIS's warnings) says it too, whether the raster was read whole or in blocks
            assert any("1 cell" in w and "nodata" in w for w in lines), (block, lines)
            assert gdal.Open(str(tmp_path / "m.tif")).ReadAsArray()[3, 3] == NODATA


def test_without_far_heights_reads_a_clean_raster_without_a_copy():
    """A raster without far heights (the usual one, which each of dtm's member derivations checks again) is returned
    as it is, read without a raster-sized temporary; one far or infinite height is still found (a copy, NaN)."""
    import tracemalloc

    from bare_earth.core.common import without_far_heights
    z = np.random.default_rng(2).normal(100.0, 10.0, (500, 500)).astype(np.float32)
    z[::7, ::3] = np.nan
    tracemalloc.start()
    try:
        out, n = without_far_heights(z)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert out is z and n == 0 and peak < z.size       # not even a bool raster (one byte a cell)
    for far in (1e30, -np.inf):
        y = z.copy()
        y[4, 5] = far
        out, n = without_far_heights(y)
        assert n == 1 and np.isnan(out[4, 5]) and y[4, 5] == np.float32(far)
        want = z.copy()
        want[4, 5] = np.nan
        np.testing.assert_array_equal(out, want)


def test_far_heights_beside_a_declared_nodata_written_with_fewer_digits_say_so(tmp_path):
    """Missing cells holding Float32's lowest value while the raster declares -3.40282e+38 (the
    same value with fewer digits, as some exports write it): they are nodata (far beyond any
    height), and the log says the declared value is not the one they hold, instead of asking to
    declare a nodata value the raster already declares."""
    z, _ = scene()
    z[3, 3] = np.finfo(np.float32).min
    p = grid.write_array(tmp_path / "far.tif", z, GT, 32633, nodata=-3.40282e38)
    lines = []
    info = pipeline.run_file(ABOVE, p, {"mask": tmp_path / "m.tif"}, log=lines.append)
    said = [w for w in lines if "1 cell(s) with heights beyond" in w]
    assert said and "declares -3.40282e+38 as its nodata, which they do not hold exactly" in said[0]
    assert "Declare the raster's nodata value" not in said[0] and said[0][9:] in info["warnings"]
    ds = gdal.Open(str(tmp_path / "m.tif"))
    assert ds.ReadAsArray()[3, 3] == NODATA
    ds = None
    p = grid.write_array(tmp_path / "undeclared.tif", z, GT, 32633)
    lines.clear()
    pipeline.run_file(ABOVE, p, {"mask": tmp_path / "m2.tif"}, log=lines.append)
    assert any("Declare the raster's nodata value to silence this" in w for w in lines)


@pytest.mark.parametrize("block", [None, 5])
def test_a_mask_without_ground_says_the_dtm_is_empty(tmp_path, block):
    """A filter calling every valid cell an object (curvature on a 4 x 4 raster of a 5 m step at
    0.5 m cells did): the DTM and nDSM are nodata everywhere, which the log now says (they were
    written so without a word)."""
    z, _ = scene()
    z = z + 1.0                                  # every height above 0 m, the threshold given below
    p = grid.write_array(tmp_path / "dsm.tif", np.where(np.isfinite(z), z, -9999.0), GT, 32633, nodata=-9999.0)
    outs = {"dtm": tmp_path / "d.tif", "mask": tmp_path / "m.tif", "ndsm": tmp_path / "n.tif"}
    lines = []
    info = pipeline.run_file(ABOVE, p, outs, params={"threshold_m": 0.0}, block=block, log=lines.append)
    valid = int(np.count_nonzero(np.isfinite(z)))
    said = [w for w in lines if "called none of the" in w]
    assert said == [f"Warning: The filter called none of the {valid} valid cell(s) ground (objects 99 %, low "
                    "outliers 1 %): with no ground to interpolate from, the DTM and nDSM are nodata everywhere. "
                    "Give a raster that reaches the ground around its objects, or try another method."]
    assert said[0][9:] in info["warnings"]
    ds = gdal.Open(str(tmp_path / "d.tif"))
    assert (ds.ReadAsArray() == -9999.0).all()
    ds = None
    lines.clear()
    info = pipeline.run_file(ABOVE, p, outs, block=block, log=lines.append)
    assert not any("called none of the" in w for w in lines + info["warnings"])
    assert pipeline.no_ground_message({OBJECT: 5}, {"mask": "m.tif"}) is None      # no DTM written


def test_plan_block_pure():
    plan = pipeline.plan_block
    assert plan((500, 400), 3, block=77) == 77                        # given: as is
    assert plan((500, 400), 3) == 500                                  # one block in memory
    # large: the blocks the budget allows (a window of 2048 + 2 x 3 cells, its corner aligned out by up to 63)
    budget = (2048 + 6 + 63) ** 2 * pipeline.DEFAULT_BYTES_PER_CELL
    assert plan((6000, 6000), 3, budget=budget) == (2048, 2048)
    # two threads, small halo: 4 strips of whole rows, multiples of 64
    assert plan((500, 400), 3, workers=2) == (128, 400)
    # long strips align to the output tile
    assert plan((4096, 300), 3, workers=2) == (1024, 300)
    # a halo that would add more than a quarter: one strip per worker, at least 2 * halo rows
    assert plan((500, 400), 40, processes=2) == (256, 400)
    # large raster with workers: the budget shared by the windows held at once, each a fifth more a cell
    assert plan((6000, 6000), 3, workers=2, budget=2 * 1.2 * budget) == (2048, 2048)
    assert plan((6000, 6000), 3, workers=2, budget=2 * budget) == (1792, 1792)
    # a method using threads inside a window: one window in memory (no halo recomputed), blocks above
    assert plan((500, 400), 40, workers=2, threads=True) == 500
    assert plan((500, 400), 40, processes=2, threads=True) == (256, 400)
    # ... and above IN_MEMORY_CELLS, its windows one at a time with the threads: the whole budget for one
    assert plan((6000, 6000), 3, workers=2, threads=True, budget=budget) == (2048, 2048)


def test_run_file_threads_method_one_window_with_its_threads(tmp_path):
    """A method using threads inside a window (Method.threads) is run in one window with the
    run's threads (no strips recomputing a halo); the others get none."""
    seen = []

    def run(z, cell_size, progress=None, workers=1, **p):
        seen.append((z.shape, workers))
        return _run(z, cell_size, progress=progress, **p)

    threaded = Method(name="threaded", run=run, resolve=_resolve, halo=lambda p, c: 1, threads=True)
    z = np.arange(200 * 30, dtype=np.float32).reshape(200, 30) % 11
    src = write(tmp_path, z, nodata=-9999)
    one, par = outputs(tmp_path, "mask", prefix="one_"), outputs(tmp_path, "mask", prefix="par_")
    pipeline.run_file(threaded, src, one)
    info = pipeline.run_file(threaded, src, par, workers=2)
    assert info["blocks"] == 1 and seen == [((200, 30), 1), ((200, 30), 2)]
    np.testing.assert_array_equal(gdal.Open(one["mask"]).ReadAsArray(), gdal.Open(par["mask"]).ReadAsArray())
    seen.clear()
    info = pipeline.run_file(threaded, src, par, block=64, workers=2)   # blocks side by side: one thread each
    assert info["blocks"] > 1 and {w for _, w in seen} == {1}
    res = pipeline.run_array(threaded, z, 1.0, workers=2)
    assert res.info["blocks"] == 1 and seen[-1] == ((200, 30), 2)


def test_plan_block_large_rasters_read_little_within_the_memory_budget():
    """Above IN_MEMORY_CELLS the blocks come from the halo and the memory budget, not a fixed 2048:
    dtm's 40000 x 40000 cells at 1 m with a halo of 2176 cells read 9.2 x the raster in blocks of 2048
    (each window 41 Mcells for 4.2 of output); within 11 GB at 92 bytes a cell (dtm's) they read 2.56 x, and
    every window held at once fits the budget."""
    plan, amp, largest = pipeline.plan_block, pipeline.read_amplification, pipeline.largest_window
    big, gb = (40000, 40000), 1 << 30
    assert amp(big, 2048, 2176) > 9
    b = plan(big, 2176, workers=2, threads=True, budget=11 * gb, bytes_per_cell=92)
    assert amp(big, b, 2176) < 2.6 and largest(big, b, 2176) * 92 <= 11 * gb
    # the same budget shared by two windows side by side (a method without threads inside a window)
    b2 = plan(big, 2176, workers=2, budget=11 * gb, bytes_per_cell=92)
    assert 2 * largest(big, b2, 2176) * 92 * 1.2 <= 11 * gb and amp(big, b, 2176) < amp(big, b2, 2176) < 9
    assert plan(big, 2176, processes=3, threads=True, budget=11 * gb, bytes_per_cell=92) == \
        plan(big, 2176, workers=3, budget=11 * gb, bytes_per_cell=92)          # processes: a window each
    rng = np.random.default_rng(0)
    for _ in range(40):
        shape = tuple(int(v) for v in rng.integers(5001, 60000, 2))
        halo, budget = int(rng.integers(0, 3000)), float(rng.uniform(0.5, 16)) * gb
        n = int(rng.integers(1, 4))
        b = plan(shape, halo, workers=n, budget=budget, bytes_per_cell=60)
        cells = budget / n / pipeline.window_bytes_per_cell(60, n)
        if b == max(shape):                          # one pass: it fits, or every block reads it all
            assert shape[0] * shape[1] <= cells or largest(shape, pipeline.MIN_BLOCK, halo) == shape[0] * shape[1]
            continue
        assert all(v % 256 == 0 or v == w for v, w in zip(b, shape))        # whole output tiles
        if largest(shape, pipeline.MIN_BLOCK, halo) <= cells:                # the budget holds
            assert largest(shape, b, halo) <= cells
        else:                                        # a budget below the smallest block's window
            assert min(b) == pipeline.MIN_BLOCK
        # no worse than square blocks of the largest side fitting the budget (its corner aligned out by a - 1)
        a = pipeline.blocks.alignment(halo)
        unit = max(256, a)
        side = max(pipeline.MIN_BLOCK, (math.isqrt(int(cells)) - 2 * halo - a + 1) // unit * unit)
        assert amp(shape, b, halo) <= amp(shape, side, halo) + 1e-9
    # strips of whole rows when a window spans the raster's width: (4352 + 2 x 3 + 63) x 6000 cells <= 2 GB / 80
    assert plan((6000, 6000), 3, budget=2 * gb, bytes_per_cell=80) == (4352, 6000)
    assert plan((6000, 6000), 3, budget=6000 ** 2 * 80, bytes_per_cell=80) == 6000   # fits: one pass


def test_plan_block_windows_side_by_side_take_more_than_one_at_a_time():
    """Windows side by side (threads or processes) each hold their finished core while another is
    written and compressed: a method's bytes_per_cell, measured one window at a time, understated two
    windows by about 15 % (QA 17: slopeprofile on 36 Mcells with a 700 MB bound peaked 705 MB above its
    baseline). Two windows get 20 % more a cell; one window at a time (dtm's threads) does not."""
    plan, largest = pipeline.plan_block, pipeline.largest_window
    assert pipeline.window_bytes_per_cell(48, 1) == 48.0
    assert pipeline.window_bytes_per_cell(48, 2) == pytest.approx(48 * 1.2)
    shape, halo, budget, bpc = (6000, 6000), 40, 700 << 20, 48          # slopeprofile's 36 Mcells
    for kw in ({"workers": 2}, {"processes": 2}):
        b = plan(shape, halo, budget=budget, bytes_per_cell=bpc, **kw)
        assert 2 * largest(shape, b, halo) * bpc * 1.15 <= budget, (kw, b)
    one = plan(shape, halo, workers=2, threads=True, budget=budget, bytes_per_cell=bpc)
    assert largest(shape, one, halo) * bpc > budget / 1.2 * 0.9     # the whole budget for one window


def _opening_run(z, cell_size, progress=None, workers=1, seen=None, **p):
    """Objects: cells 1 m above the grey opening of 9 x 9 cells (reach 8 cells), for blocks above
    IN_MEMORY_CELLS; ``seen`` records the windows and threads."""
    from scipy import ndimage
    if seen is not None:
        seen.append((z.shape, workers))
    filled = np.where(np.isfinite(z), z, np.float32(-1e4)).astype(np.float32)
    mask = (filled - ndimage.grey_opening(filled, size=(9, 9)) > 1.0).astype(np.uint8)
    report(progress, 1.0)
    return FilterResult(finish_mask(mask, z), info={})


def test_run_file_above_in_memory_cells_blocked_equals_one_pass(tmp_path, monkeypatch):
    """A raster just above IN_MEMORY_CELLS (a synthetic city drawn 8 times larger as a VRT, 5008 x 5000
    cells) is cut into the blocks the memory budget allows, logged with their read amplification; a
    method using threads inside a window runs them one at a time with the run's threads; the mask
    equals one pass and the DTM's ground cells too (its filled cells nearly: 290 of 25 M differ by more
    than 5 cm, the fill of a hole crossing a block's edge seeing the halo only)."""
    from bare_earth.core import fill
    from bare_earth.core.synthetic import make_scene
    monkeypatch.setattr(fill, "EMPTY_RUN_M", 2.0)      # the fill of empty cells reaches 4 cells (none here)
    seen = []
    meth = Method(name="opening", run=lambda z, c, **k: _opening_run(z, c, seen=seen, **k), resolve=_resolve,
                  halo=lambda p, c: 8, threads=True)
    small = make_scene("city", (626, 625), seed=3).dsm
    src = grid.write_array(tmp_path / "small.tif", small, (500000.0, 8.0, 0.0, 5405008.0, 0.0, -8.0), 32633)
    vrt = str(tmp_path / "big.vrt")
    gdal.Translate(vrt, src, format="VRT", width=5000, height=5008, resampleAlg="nearest")
    assert 5008 * 5000 > pipeline.IN_MEMORY_CELLS
    monkeypatch.setenv("BARE_EARTH_MEMORY_MB", "300")       # 300 MB at 92 bytes a cell: windows of 3.4 Mcells
    logs = []
    info = pipeline.run_file(meth, vrt, outputs(tmp_path, "mask", "dtm"), workers=2, log=logs.append)
    assert info["blocks"] > 4 and {w for _, w in seen} == {2}
    assert max(a * b for (a, b), _ in seen) * pipeline.DEFAULT_BYTES_PER_CELL <= 300 * 2 ** 20
    assert any(s.startswith("Blocks of ") and "reading 1.0" in s for s in logs), logs
    seen.clear()
    one = pipeline.run_file(meth, vrt, outputs(tmp_path, "mask", "dtm", prefix="one_"), block=5008)
    assert one["blocks"] == 1 and seen == [((5008, 5000), 1)]
    m, m1 = read(tmp_path / "mask.tif")[0], read(tmp_path / "one_mask.tif")[0]
    np.testing.assert_array_equal(m, m1)
    assert (m1 == OBJECT).sum() > 100_000 and (m1 == GROUND).mean() > 0.9
    d, d1 = read(tmp_path / "dtm.tif")[0], read(tmp_path / "one_dtm.tif")[0]
    np.testing.assert_array_equal(d[m1 == GROUND], d1[m1 == GROUND])
    # filled cells: the interpolation sees the block and its halo (the method's reach, not the fill's)
    assert np.count_nonzero(np.abs(d - d1) > 0.05) < 1e-4 * d.size


@pytest.mark.parametrize("block", [None, 64])
def test_run_file_nodata_ranges_are_nodata_in_every_block_and_worker(tmp_path, block):
    """The additional no-data values of a QGIS layer (``nodata_ranges``) are nodata as a declared
    nodata is: the same mask, in one pass, in blocks, and in a block job sent to a worker
    process (pickled: it reopens the file with the ranges)."""
    import pickle
    rng = np.random.default_rng(1)
    z = rng.uniform(0.0, 2.0, (150, 140)).astype(np.float32)
    z[:, :9] = -9999.0
    z[70:80, 60:66] = 60.0                       # an object
    z[100:104, 100:130] = -32768.0               # a second value, in an exclusive-bounds range
    src = write(tmp_path, z)
    ranges = [(-9999.0, -9999.0, True, True), (-40000.0, -30000.0, False, False)]
    logs = []
    outs = outputs(tmp_path, "dtm", "mask")
    pipeline.run_file(ABOVE, src, outs, block=block, nodata_ranges=ranges, log=logs.append)
    nod = (z == -9999.0) | (z == -32768.0)
    mask, _, _, _ = read(outs["mask"])
    dtm, nd, _, _ = read(outs["dtm"])
    np.testing.assert_array_equal(mask == NODATA, nod)
    assert math.isnan(nd) and np.isnan(dtm[nod]).all() and np.isfinite(dtm[~nod]).all()
    assert any("additional no-data values (-9999, -40000 to -30000)" in s for s in logs)
    ref = pipeline.run_array(ABOVE, np.where(nod, np.nan, z), 1.0)
    np.testing.assert_array_equal(mask, ref.mask)
    job = pipeline._BlockJob(None, src, 1, (1.0, 1.0), {"threshold_m": 5.0, "low_m": -5.0}, True,
                             nodata_ranges=ranges)
    zb, _ = pickle.loads(pickle.dumps(job)).read((0, 150, 0, 20), (0, 150, 0, 20))
    np.testing.assert_array_equal(np.isnan(zb), nod[:, :20])


def test_block_job_sent_to_a_worker_reads_in_the_crs_given(tmp_path):
    """A file without a CRS run in the CRS its layer was given: a block job pickled for a worker
    process reopens it in that CRS (heights in US survey feet read as metres)."""
    import pickle
    z = np.full((20, 20), 100.0, np.float32)
    src = write(tmp_path, z, crs="")
    s = osr.SpatialReference()
    s.ImportFromEPSG(2264)
    job = pipeline._BlockJob(None, src, 1, (1.0, 1.0), {}, True, crs_wkt=s.ExportToWkt())
    zb, _ = pickle.loads(pickle.dumps(job)).read((0, 20, 0, 20), (0, 20, 0, 20))
    np.testing.assert_allclose(zb, 100.0 * 1200 / 3937, rtol=1e-6)


def test_run_file_parameters_from_the_data_when_the_centre_is_empty(tmp_path, monkeypatch):
    """A raster larger than the parameter window whose centre holds no data (an L-shaped survey):
    the parameters come from a window of that size on the data, not from the whole raster read
    at once (gigabytes for a large survey)."""
    monkeypatch.setattr(pipeline, "RESOLVE_SIDE", 64)
    z = np.full((200, 300), np.nan, np.float32)
    z[120:190, 10:90] = np.linspace(0.0, 2.0, 80, dtype=np.float32)[None, :]
    z[150, 50] = 60.0
    src = write(tmp_path, z)
    reads = []
    original = grid.DSMInfo.read

    def spy(self, window=None, step=1, far_in=None):
        reads.append(window)
        return original(self, window, step, far_in)
    monkeypatch.setattr(grid.DSMInfo, "read", spy)
    logs = []
    pipeline.run_file(ABOVE, src, outputs(tmp_path, "mask"), block=64, log=logs.append)
    assert None not in reads and (0, 200, 0, 300) not in reads        # never the whole raster
    said = [s for s in logs if s.startswith("Parameters derived from")]
    assert said == ["Parameters derived from the data's 64 x 64 cells (rows 88-152, columns 57-121)."]
    assert read(outputs(tmp_path, "mask")["mask"])[0][150, 50] == OBJECT


@pytest.mark.parametrize("method", ["dtm", "rascor", "geodesic"])
def test_heights_in_whole_metres_stay_ground(method):
    """An Int16 DSM in whole metres (SRTM / Copernicus style) of bare rolling terrain: its
    1 m steps are rounding, not walls (RASCOR took 14 %, geodesic 11 % and dtm 7 % of the
    cells for objects when the noise read 0 on the rounded heights)."""
    from bare_earth.core.synthetic import make_scene
    s = make_scene("rolling", (200, 200), seed=2)
    z = np.round(s.dsm).astype(np.int16)
    r = pipeline.run_array(method, z, 1.0)
    assert np.count_nonzero(r.mask == 0) / r.mask.size > 0.98


def test_blocked_run_logs_the_decisions_of_every_block():
    """Before: a blocked run's info came from the first block for everything but numbers, so a
    decision (dtm's raised regions) taken in a later block never reached the log. Lists that
    differ between blocks are joined, each entry once; lists all blocks share stay as they are."""
    def run(z, cell_size, progress=None, threshold_m=5.0, low_m=-5.0):
        res = _run(z, cell_size, threshold_m=threshold_m, low_m=low_m)
        found = [f"object of {v:g} m" for v in np.unique(z[z > threshold_m])]
        res.info.update(decisions=found, scales=[2, 2, 4])
        return res

    meth = Method(name="decides", run=run, resolve=_resolve, halo=lambda p, c: 1, params=ABOVE.params)
    z = np.zeros((128, 128))
    z[10, 10], z[100, 100], z[100, 20] = 20.0, 30.0, 20.0
    one = pipeline.run_array(meth, z, 1.0)
    blocked = pipeline.run_array(meth, z, 1.0, block=64)
    assert one.info["decisions"] == ["object of 20 m", "object of 30 m"]
    assert sorted(blocked.info["decisions"]) == ["object of 20 m", "object of 30 m"]
    assert blocked.info["scales"] == [2, 2, 4]
    np.testing.assert_array_equal(blocked.mask, one.mask)


@pytest.mark.parametrize("kind", ["tif", "vrt", "asc"])
def test_run_file_leaves_the_input_folder_byte_for_byte(tmp_path, kind):
    """The plugin's own reads write nothing into an input: no statistics into a ``.vrt`` (GDAL
    rewrites a VRT whose statistics were computed when it closes) and no ``.aux.xml`` beside it
    or its sources. (QGIS's layer loading still writes its statistics into a ``.vrt``: README.)"""
    src_dir, out = tmp_path / "in", tmp_path / "out"
    src_dir.mkdir()
    out.mkdir()
    z, _ = scene(np.float32, nodata=False)
    src = write(src_dir, z, nodata=-9999)
    if kind == "vrt":
        gdal.BuildVRT(str(src_dir / "dsm.vrt"), [src]).FlushCache()
        src = str(src_dir / "dsm.vrt")
    elif kind == "asc":
        gdal.Translate(str(src_dir / "dsm.asc"), src, format="AAIGrid")
        src = str(src_dir / "dsm.asc")
    for p in src_dir.glob("*.aux.xml"):
        p.unlink()
    before = {p.name: p.read_bytes() for p in src_dir.iterdir()}
    pipeline.run_file(ABOVE, src, outputs(out, "dtm", "ndsm", "mask"))
    grid.open_dsm(src).read()
    assert {p.name: p.read_bytes() for p in src_dir.iterdir()} == before


@pytest.mark.parametrize("method,extra,names", [
    ("curvature", "curvature", ["Gaussian curvature K (1/m^2)", "mean curvature H (1/m)"]),
    ("rascor", "step", ["RASCOR step that removed the cell (0 kept)"]),
    ("geodesic", "step", ["dilation step or stage that removed the cell (0 kept)"]),
    ("dtm", "confidence", ["confidence (%)"]),
])
def test_side_products_name_their_bands(tmp_path, method, extra, names):
    """A side product's bands say what they hold, as the DTM's and the mask's do: before, the
    curvature output's two bands read 'Band 1' and 'Band 2' in QGIS, K and H unnamed."""
    from bare_earth.core.synthetic import make_scene
    sc = make_scene("city", shape=(64, 72), seed=2)
    p = grid.write_array(tmp_path / "dsm.tif", sc.dsm, GT, 32633)
    out = tmp_path / f"{extra}.tif"
    pipeline.run_file(method, p, {"mask": tmp_path / "m.tif", extra: out})
    ds = gdal.Open(str(out))
    assert [ds.GetRasterBand(k + 1).GetDescription() for k in range(ds.RasterCount)] == names


def test_rascor_height_limits_hold_the_whole_raster_beyond_its_window(tmp_path, monkeypatch):
    """RASCOR's step 2 limits are heights, derived on the central window of a large raster: the
    flat plain there, the ground beyond rising 60 m (a valley side, a corridor climbing along
    its length) was removed whole as far outside the heights (45 % of a 3 x 100000 corridor
    rising 1000 m). The limits now hold the whole raster's heights, read every step-th cell;
    limits the user gives stay as given."""
    monkeypatch.setattr(pipeline, "RESOLVE_SIDE", 256)
    rng = np.random.default_rng(7)
    cols = 1200
    ground = np.full(cols, 100.0)
    ground[900:] += np.linspace(0.0, 60.0, 300)                # 60 m up over the last 300 m
    z = (ground[None, :] + rng.normal(0.0, 0.05, (64, cols))).astype(np.float32)
    objects = np.zeros(z.shape, bool)
    for c in (150, 600, 1000, 1150):
        objects[20:40, c:c + 20] = True
    z[objects] += 8.0
    src = write(tmp_path, z)
    logs = []
    res = pipeline.run_file("rascor", src, outputs(tmp_path, "mask"), block=256, log=logs.append)
    mask = read(outputs(tmp_path, "mask")["mask"])[0]
    assert res["params"]["terrain_class"] == "flat" and res["params"]["height_max_m"] > 168.0
    assert any("widened" in s for s in logs)
    assert res["removed_share_by_step"]["2 height distribution"] == 0.0
    slope = np.zeros(z.shape, bool)
    slope[:, 900:1100] = True         # the rest of the slope, steeper than the window's plain, is not step 2's
    assert np.mean(mask[slope & ~objects] == GROUND) > 0.99              # the rising ground stays ground
    assert np.mean(mask[objects] == OBJECT) > 0.9
    given = pipeline.run_file("rascor", src, outputs(tmp_path, "mask", prefix="given_"), block=256,
                              params={"height_max_m": 130.0})
    assert given["params"]["height_max_m"] == 130.0


def test_widen_rascor_params_takes_the_widest_limits():
    """The window's limits and the overview's (same rule on each), the widest of each kept; a
    terrain other than flat (step 2 skipped) and limits the user gave are left alone."""
    from bare_earth.core.rascor.parameters import widen_rascor_params
    over = np.full((30, 30), 100.0, np.float32)
    over[:, 25:] = 300.0                                   # ground up to 300 m beyond the window
    p = {"terrain_class": "flat", "sigma_m": 0.1, "height_min_m": 80.0, "height_max_m": 120.0}
    w = widen_rascor_params(p, {}, over, (10.0, 10.0))
    assert w["height_min_m"] == 80.0 and w["height_max_m"] >= 320.0
    assert widen_rascor_params(p, {"height_max_m": 120.0}, over, (10.0, 10.0))["height_max_m"] == 120.0
    assert widen_rascor_params(dict(p, terrain_class="rolling"), {}, over, (10.0, 10.0)) == dict(
        p, terrain_class="rolling")
    from bare_earth.core.dtm import widen_dtm_params
    d = widen_dtm_params(                                  # the vote widens its RASCOR member's
        {"members": {"rascor": p, "geodesic": {"max_object_size_m": 64.0}}, "tolerance_m": 0.5},
        {}, over, (10.0, 10.0))
    assert d["members"]["rascor"] == w and d["members"]["geodesic"] == {"max_object_size_m": 64.0}
    assert d["tolerance_m"] == 0.5


def test_a_halo_across_the_raster_runs_one_pass_not_blocks_reading_all_of_it(tmp_path, monkeypatch):
    """A raster above IN_MEMORY_CELLS whose method reaches across it from any block (dtm's 2 km
    reach at 2 cm cells: 100000 cells) was cut into blocks that each read and filtered the whole
    raster (40000 x 40000 at 2 cm: 6 GB after 90 s in the first of 400 blocks). It now runs in
    one pass, said in the log; a halo shorter than that keeps the blocks."""
    plan, least = pipeline.plan_block, pipeline.MIN_BLOCK
    budget = 4000 ** 2 * 80                   # windows of at most 4000 x 4000 cells: less than the raster
    assert plan((6000, 6000), 6000 - least, budget=budget) == 6000
    assert plan((6000, 3000), 6000 - least, budget=budget) == 6000
    b = plan((6000, 6000), 6000 - least - 1, budget=budget)     # the corner blocks read less than all
    assert b != 6000 and max(b) == least
    b = plan((6000, 6000), 1000, budget=budget)
    assert b != 6000 and pipeline.largest_window((6000, 6000), b, 1000) <= 4000 ** 2
    monkeypatch.setattr(pipeline, "IN_MEMORY_CELLS", 50 * 50)
    monkeypatch.setattr(pipeline, "MIN_BLOCK", 64)
    monkeypatch.setenv("BARE_EARTH_MEMORY_MB", "1")       # 1 MB: windows of 13107 cells at 80 bytes
    z = (np.arange(200 * 150, dtype=np.float32).reshape(200, 150) % 13).astype(np.float32)
    src = write(tmp_path, z)
    reach = Method(name="reach", run=_run, resolve=_resolve, halo=lambda p, c: 150, params=ABOVE.params)
    logs = []
    res = pipeline.run_file(reach, src, outputs(tmp_path, "mask"), log=logs.append)
    assert res["blocks"] == 1 and any("spans the raster from any block" in s for s in logs)
    one = pipeline.run_array(reach, z, (1.0, 1.0)).mask
    np.testing.assert_array_equal(read(outputs(tmp_path, "mask")["mask"])[0], one)
    short = Method(name="short", run=_run, resolve=_resolve, halo=lambda p, c: 20, params=ABOVE.params)
    # a given bound that makes the windows mostly halo is refused (check_plan): the default budget, 1 MB
    from bare_earth.core import memory
    monkeypatch.delenv("BARE_EARTH_MEMORY_MB")
    monkeypatch.setattr(memory, "available_memory", lambda: 2 << 20)
    logs = []
    assert pipeline.run_file(short, src, outputs(tmp_path, "mask", prefix="s_"), log=logs.append)["blocks"] > 1
    assert not any("spans the raster" in s for s in logs)


def test_cells_wider_than_any_filter_window_refused_before_work(tmp_path):
    """QA15: a DSM of 0.5 degree cells (55 km; or 50 km cells) failed in the opening's derived parameters,
    'WIDE_RADIUS_M = 25000 m is out of range', a parameter nobody gave, for morphological and dtm. Cells
    wider than the widest window any filter's parameters allow (pipeline.widest_window_m, 10 km) are
    refused before any work, naming the cell size; cells of 5 km still run."""
    from bare_earth.core import grid, pipeline
    from bare_earth.core.methods import available_methods, get_method
    widest = pipeline.widest_window_m()
    assert widest == max(p.maximum for m in available_methods() for p in get_method(m).params
                         if p.name.endswith("_m") and p.maximum is not None) == 10000.0
    z = np.zeros((40, 40), np.float32) + np.linspace(0.0, 30.0, 40, dtype=np.float32)[None, :]
    z[10:20, 10:20] += 8.0
    for method in ("morphological", "dtm"):
        with pytest.raises(ValueError, match=r"cells of 50000 x 50000 m are wider than the widest window any filter "
                                             r"takes \(10000 m\)"):
            pipeline.run_array(method, z, 50000.0)
    pipeline.check_cell_size((widest, widest))
    with pytest.raises(ValueError, match="wider than the widest window"):
        pipeline.check_cell_size((1.0, widest * 1.001))
    assert pipeline.run_array("morphological", z, 5000.0).mask.shape == z.shape
    path = grid.write_array(tmp_path / "deg.tif", z, (-180.0, 4.5, 0.0, 90.0, 0.0, -2.25), 4326)
    with pytest.raises(ValueError, match=r"cells of 354811 x 250046 m are wider"):
        pipeline.run_file("morphological", path, {"dtm": str(tmp_path / "d.tif"), "mask": str(tmp_path / "m.tif")})
    assert sorted(os.listdir(tmp_path)) == ["deg.tif"]


def test_dtm_cells_interpolated_to_the_declared_nodata_stay_heights(tmp_path):
    """A DSM declaring 300 as nodata over ground alternating 299 / 301 m (heights rounded to whole
    metres): the DTM under a building, interpolated from that ground, held exactly 300 in 186 cells,
    which every reader then took as nodata (holes in the DTM where the mask says object). Such cells
    are written just above, beyond GDAL's tolerance for a float nodata (300.0003), and the log says how
    many and why."""
    from osgeo import gdal
    c = np.arange(80, dtype=np.float64)
    z = np.tile(299.0 + 2.0 * (c % 2), (60, 1))
    z[20:40, 30:50] += 12.0
    src = str(tmp_path / "dsm.tif")
    grid.write_array(src, z.astype(np.float32), (500000, 1, 0, 5400000, 0, -1), 32632, nodata=300.0)
    logs = []
    outs = {"dtm": str(tmp_path / "dtm.tif"), "mask": str(tmp_path / "mask.tif"), "ndsm": str(tmp_path / "ndsm.tif")}
    pipeline.run_file("morphological", src, outs, log=logs.append)
    ds = gdal.Open(outs["dtm"])
    assert ds.GetRasterBand(1).GetNoDataValue() == 300.0                  # the input's nodata, kept
    d = ds.ReadAsArray()
    m = gdal.Open(outs["mask"]).ReadAsArray()
    assert (m == 1).sum() == 400 and not (m == 255).any()
    assert not (d == np.float32(300.0)).any()                             # no height reads as nodata
    up = np.float32(300.00030517578125)
    n = int((d == up).sum())
    assert n > 50 and (m[d == up] == 1).all()                            # only interpolated cells moved
    assert any(f"{n} cell(s) of the DTM hold the declared nodata value 300 as a height: they are written as "
               "300.000305" in s for s in logs), logs
    mask_band = ds.GetRasterBand(1).GetMaskBand().ReadAsArray()          # GDAL's own reading: all valid
    assert (mask_band == 255).all()
    nd = gdal.Open(outs["ndsm"])
    assert not (nd.ReadAsArray() == nd.GetRasterBand(1).GetNoDataValue()).any()


def test_with_output_nodata_exact():
    """Values GDAL takes for a float nodata (within a few float32 steps: 300.00003, 299.99997) move
    beyond its tolerance too; 299.999 stays."""
    a = np.array([[1.0, np.nan, 300.0, 300.00003], [np.inf, 299.99997, -np.inf, 299.999]], np.float32)
    assert grid.with_output_nodata(a, 300.0) == 3
    up = np.float32(300.00030517578125)
    assert grid.above_nodata(300.0) == up
    np.testing.assert_array_equal(a, np.array([[1.0, 300.0, up, up], [300.0, up, 300.0, 299.999]], np.float32))
    b = np.array([np.nan, 300.0], np.float32)
    assert grid.with_output_nodata(b, float("nan")) == 0 and np.isnan(b[0]) and b[1] == 300.0
    assert grid.moved_off_nodata_message(0, 300.0) is None


def test_with_output_nodata_at_the_largest_float32_is_quiet():
    """A DSM declaring ESRI's nodata -3.4028235e+38 (the lowest float32) printed numpy's "RuntimeWarning: overflow
    encountered in nextafter" into every run's log (the step beyond the largest float32, looking for the band
    below it): that step is now infinity without a word, and the cells are written as before."""
    import warnings
    top = float(np.finfo(np.float32).max)
    for nodata in (-top, top):
        a = np.array([np.nan, 300.0, -300.0], np.float32)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert grid.with_output_nodata(a, nodata) == 0
            assert np.isinf(grid.above_nodata(top))
        np.testing.assert_array_equal(a, np.array([nodata, 300.0, -300.0], np.float32))


@pytest.mark.parametrize("value", ["abc", "inf", "800MB"])
def test_a_memory_bound_that_is_no_number_is_refused_before_any_work(tmp_path, monkeypatch, value):
    """BARE_EARTH_MEMORY_MB was read only when a raster over IN_MEMORY_CELLS was planned, after the parameters'
    derivation (a minute on such a raster): 'abc' was refused there, 'inf' failed with a bare OverflowError; a
    smaller raster ran ignoring it. run_file refuses it first: no parameter derived, nothing written."""
    monkeypatch.setenv("BARE_EARTH_MEMORY_MB", value)
    derived = []
    meth = Method(name="short", run=_run, resolve=lambda z, c, **kw: derived.append(1) or _resolve(z, c, **kw),
                  halo=lambda p, c: 1, params=ABOVE.params)
    src = write(tmp_path, np.zeros((20, 20), np.float32))
    with pytest.raises(ValueError, match=rf"BARE_EARTH_MEMORY_MB='{value}'.*megabytes"):
        pipeline.run_file(meth, src, outputs(tmp_path, "mask"))
    assert not derived and sorted(p.name for p in tmp_path.iterdir()) == ["dsm.tif"]


def test_blocks_budget_leaves_out_what_the_run_holds_beside_its_windows(tmp_path, monkeypatch):
    """BARE_EARTH_MEMORY_MB bounded the windows alone; what the run held beside them when the blocks
    were planned (the input's window the parameters came from, rasterised layers, GDAL's block cache)
    came on top. The windows now get the bound less that (held_outside_windows), logged."""
    from bare_earth.core import fill, memory
    mb = 1 << 20
    monkeypatch.setattr(fill, "EMPTY_RUN_M", 2.0)      # the fill's reach 4 cells: windows not mostly halo
    monkeypatch.setattr(pipeline, "IN_MEMORY_CELLS", 50 * 50)
    monkeypatch.setattr(pipeline, "MIN_BLOCK", 64)
    z = (np.arange(400 * 400, dtype=np.float32).reshape(400, 400) % 13).astype(np.float32)
    src = write(tmp_path, z)
    meth = Method(name="short", run=_run, resolve=_resolve, halo=lambda p, c: 4, params=ABOVE.params)
    monkeypatch.setenv("BARE_EARTH_MEMORY_MB", str(80 + 64 + 10))    # 10 MB for the windows once 80 + 64 held
    monkeypatch.setattr(memory, "held_by_run", lambda: 80 * mb)
    assert pipeline.held_outside_windows() == 80 * mb + grid.BLOCK_MODE_CACHE
    logs = []
    res = pipeline.run_file(meth, src, outputs(tmp_path, "mask"), log=logs.append)
    plan = [s for s in logs if "Blocks of " in s]
    assert res["blocks"] > 1 and plan and "memory budget of 10 MB" in plan[0], logs
    np.testing.assert_array_equal(read(outputs(tmp_path, "mask")["mask"])[0],
                                  pipeline.run_array(meth, z, (1.0, 1.0)).mask)
    monkeypatch.setattr(memory, "held_by_run", lambda: 0)              # nothing held: the windows' 154 MB
    logs = []
    assert pipeline.run_file(meth, src, outputs(tmp_path, "mask", prefix="o_"), log=logs.append)["blocks"] == 1


@pytest.mark.parametrize("dtype", [np.complex64, np.complex128])
def test_complex_arrays_refused_before_work(dtype):
    """A complex array was cast to its real part with only numpy's ComplexWarning (a raster of complex
    numbers is refused); from Python it is refused too, naming the dtype and the fix."""
    z = np.full((20, 20), 100.0).astype(dtype)
    for call in (lambda: pipeline.run_array("morphological", z, 1.0), lambda: pipeline.resolve_params("dtm", z, 1.0)):
        with pytest.raises(ValueError, match=r"complex numbers \(complex(64|128)\).*real part"):
            call()


def test_a_given_bound_that_makes_the_windows_mostly_halo_is_refused_naming_the_bound_that_works(
        tmp_path, monkeypatch):
    """QA 17: dtm on 36 Mcells under BARE_EARTH_MEMORY_MB=700 planned 144 windows of 512 cells with a
    1185-cell halo, reading each cell 25.7 times, with a warning only. A bound the user gave that makes the
    windows read the raster more than MAX_READ_AMPLIFICATION times is refused before the blocks (no
    output written), naming the smallest bound that works; that bound then runs, reading at most 4 x.
    Under the default budget (half the memory available) the log warns, naming it too."""
    from bare_earth.core import memory
    mb = 1 << 20
    assert pipeline.smallest_efficient_budget((6000, 6000), 1185, workers=2, threads=True,
                                              bytes_per_cell=104) == 1905 * mb
    with pytest.raises(ValueError, match=r"25\.7 times.*at least 2005"):
        pipeline.check_plan((6000, 6000), (512, 512), 1185, 600 * mb, held=100 * mb, workers=2, threads=True,
                            bytes_per_cell=104, method="dtm")
    assert pipeline.check_plan((6000, 6000), (768, 6000), 1185, 1905 * mb, workers=2, threads=True,
                               bytes_per_cell=104) is None
    monkeypatch.setattr(pipeline, "IN_MEMORY_CELLS", 50 * 50)
    monkeypatch.setattr(pipeline, "MIN_BLOCK", 64)
    monkeypatch.setattr(memory, "held_by_run", lambda: 0)
    z = (np.arange(600 * 500, dtype=np.float32).reshape(600, 500) % 13).astype(np.float32)
    src = write(tmp_path, z)
    reach = Method(name="reach", run=_run, resolve=_resolve, halo=lambda p, c: 60, params=ABOVE.params)
    cache = grid.BLOCK_MODE_CACHE // mb
    monkeypatch.setenv("BARE_EARTH_MEMORY_MB", str(cache + 1))      # 1 MB for the windows: 13107 cells
    outs = outputs(tmp_path, "mask")
    with pytest.raises(ValueError, match=r"BARE_EARTH_MEMORY_MB leaves 1 MB for reach's windows.*"
                                         r"read the raster's cells \d+\.\d times.*at least (\d+)") as e:
        pipeline.run_file(reach, src, outs)
    assert not os.path.exists(outs["mask"])
    need = int(re.search(r"at least (\d+)", str(e.value)).group(1))
    assert need > cache + 1
    monkeypatch.setenv("BARE_EARTH_MEMORY_MB", str(need))
    logs = []
    res = pipeline.run_file(reach, src, outs, log=logs.append)
    plan = [s for s in logs if s.startswith("Blocks of ") or "one pass" in s]
    amp = float(re.search(r"reading (\d+\.\d+) x", plan[0]).group(1)) if res["blocks"] > 1 else 1.0
    assert amp <= pipeline.MAX_READ_AMPLIFICATION, logs
    np.testing.assert_array_equal(read(outs["mask"])[0], pipeline.run_array(reach, z, (1.0, 1.0)).mask)
    monkeypatch.delenv("BARE_EARTH_MEMORY_MB")                       # the default budget: a warning
    monkeypatch.setattr(memory, "available_memory", lambda: 2 * mb)
    logs = []
    assert pipeline.run_file(reach, src, outputs(tmp_path, "mask", prefix="d_"), log=logs.append)["blocks"] > 1
    warn = [s for s in logs if s.startswith("Warning: Blocks of ")]
    assert warn and re.search(r"at most 4 x the raster's cells with \d+ MB", warn[0]), logs


def test_cells_too_fine_for_the_heights_refused_or_warned_before_work(tmp_path):
    """QA 17: a city scene (buildings 4-56 m high) at 1 mm cells, 0.3 m wide: morphological kept every
    cell ground and dtm called 99.99 % objects, without a word; at 1 cm both called 99.7-99.99 % objects.
    Heights spanning more than MAX_RELIEF_RATIO (20) times the raster's diagonal are refused before any
    work naming the cell size and the fix; more than STEEP_RELIEF_RATIO (2) times: a warning (run_array's
    info, run_file's log); the scene at 1 m and 10 cm runs without one."""
    from bare_earth.core.synthetic import make_scene
    z = make_scene("city", (120, 120), seed=1).dsm
    assert pipeline.relief_ratio(z, 1.0) == pytest.approx(pipeline.relief_ratio(z, 0.001) / 1000, rel=1e-6)
    flat = np.zeros((10, 10), np.float32)
    assert pipeline.relief_ratio(flat, 1.0) == 0.0 and pipeline.check_relief(flat, 1e-3) is None
    assert pipeline.relief_ratio(np.full((3, 3), np.nan), 1.0) == 0.0
    step = np.zeros((10, 10), np.float32)
    step[:, 5:] = 30.0                             # 30 m over a diagonal of 14.1 m: 2.1
    assert pipeline.relief_ratio(step, 1.0) == pytest.approx(30 / math.hypot(10, 10))
    assert "steeper than any terrain" in pipeline.check_relief(step, 1.0)
    assert pipeline.check_relief(step, 1.5) is None
    calls = []
    meth = Method(name="count", run=lambda z, c, **k: calls.append(1) or _run(z, c, **k), resolve=_resolve,
                  halo=lambda p, c: 1, params=ABOVE.params)
    src = write(tmp_path, z, gt=(500000.0, 0.001, 0.0, 5400000.0, 0.0, -0.001))
    outs = outputs(tmp_path, "mask")
    for call in (lambda: pipeline.run_array(meth, z, 0.001), lambda: pipeline.run_file(meth, src, outs)):
        with pytest.raises(ValueError, match=r"heights span [\d.]+ times the diagonal .* cells of 0\.001 x 0\.001 m"
                                             r".*cell size is probably wrong.*gdal_edit\.py -tr"):
            call()
    assert not calls and not os.path.exists(outs["mask"])
    res = pipeline.run_array(meth, z, 0.01)
    assert any("steeper than any terrain" in w for w in res.info["warnings"])
    src = write(tmp_path, z, name="cm.tif", gt=(500000.0, 0.01, 0.0, 5400000.0, 0.0, -0.01))
    logs = []
    pipeline.run_file(meth, src, outs, log=logs.append)
    assert any(s.startswith("Warning: the heights span") for s in logs), logs
    for cell in (1.0, 0.1):
        assert not pipeline.run_array(meth, z, cell).info["warnings"]


def test_relief_ratio_leaves_out_blunders():
    """High blunders (birds, multipath) on up to 2 % of a small raster's cells do not make its heights'
    span: 1 % of the cells of a 100 x 100 m raster at 5 km are not refused."""
    z = np.random.default_rng(0).normal(0.0, 0.1, (100, 100)).astype(np.float32)
    z.flat[::100] = np.linspace(4000.0, 6000.0, 100)      # 1 % of the cells
    assert pipeline.relief_ratio(z, 1.0) < 0.01 and pipeline.check_relief(z, 1.0) is None
    z.flat[::25] = np.linspace(4000.0, 6000.0, 400)       # 4 %: the span
    with pytest.raises(ValueError, match="cell size is probably wrong"):
        pipeline.check_relief(z, 1.0)
    # an undeclared nodata: -9999 on a tenth of the cells is no height (grid.undeclared_nodata_warning says it)
    z = np.random.default_rng(0).normal(0.0, 0.1, (64, 64)).astype(np.float32)
    z[:, :6] = -9999.0
    assert pipeline.relief_ratio(z, 1.0) < 0.01


def test_relief_of_a_file_checked_as_the_run_checks_it(tmp_path, monkeypatch):
    """QA 19: check_relief ran only inside run_file, after the dialog had accepted the raster.
    check_relief_file reads the window run_file derives its parameters from, decimated, and refuses what the
    run refuses (a city at 1 mm cells), warns at 1 cm, passes at 1 m; a decimated read (at most 200 cells
    here) gives the whole read's ratio within a few per cent; a central window without data: None (the run
    takes the data's window)."""
    from bare_earth.core.synthetic import make_scene
    z = make_scene("city", (120, 120), seed=1).dsm
    mm = write(tmp_path, z, name="mm.tif", gt=(500000.0, 0.001, 0.0, 5400000.0, 0.0, -0.001))
    with pytest.raises(ValueError, match=r"heights span [\d.]+ times the diagonal of the 120 x 120 cells of "
                                         r"0\.001 x 0\.001 m .*cell size is probably wrong"):
        pipeline.check_relief_file(grid.open_dsm(mm))
    cm = write(tmp_path, z, name="cm.tif", gt=(500000.0, 0.01, 0.0, 5400000.0, 0.0, -0.01))
    assert "steeper than any terrain" in pipeline.check_relief_file(grid.open_dsm(cm))
    assert pipeline.check_relief_file(grid.open_dsm(write(tmp_path, z, name="m.tif"))) is None
    info = grid.open_dsm(cm)
    whole = pipeline.relief_ratio(z, 0.01)
    rw = pipeline._resolve_window(info.shape)
    step = 9                                            # ceil(sqrt(14400 / 200))
    sampled = pipeline.relief_ratio(info.read(rw, step), 0.01, shape=info.shape)
    assert sampled == pytest.approx(whole, rel=0.05)
    msg = pipeline.check_relief_file(info, sample=200)
    assert f"the heights span {sampled:.3g} times the diagonal of the 120 x 120 cells" in msg, msg
    # the window is the central RESOLVE_SIDE cells, as run_file's: data only outside it -> None
    monkeypatch.setattr(pipeline, "RESOLVE_SIDE", 40)
    hollow = z.copy()
    hollow[40:80, 40:80] = -9999.0
    info = grid.open_dsm(write(tmp_path, hollow, name="hollow.tif", nodata=-9999.0,
                               gt=(500000.0, 0.001, 0.0, 5400000.0, 0.0, -0.001)))
    assert pipeline.check_relief_file(info) is None


def test_raster_in_gdal_memory_refused_with_worker_processes(tmp_path):
    """QA 19: a raster in GDAL's memory of the process (/vsimem/, a layer a script or plugin made there) run with
    PROCESSES=2 failed in the workers once the parameters were derived ("No such file or directory ... may be
    truncated or corrupt"). Refused before any work naming /vsimem/ and the fix; one process runs it."""
    from bare_earth.core.synthetic import make_scene
    z = make_scene("city", (300, 300), seed=1).dsm
    src = "/vsimem/qa19-dsm.tif"
    gdal.Translate(src, write(tmp_path, z))
    try:
        outs = outputs(tmp_path, "mask", "dtm")
        calls = []
        with pytest.raises(ValueError, match=r"'/vsimem/qa19-dsm\.tif' lives in this process's memory.*"
                                             r"PROCESSES = 1"):
            pipeline.run_file("morphological", src, outs, processes=2, block=128,
                              progress=lambda f: calls.append(f))
        assert not calls and not os.path.exists(outs["mask"])
        pipeline.run_file("morphological", src, outs, processes=1, block=128)
        assert os.path.exists(outs["mask"])
    finally:
        gdal.Unlink(src)
