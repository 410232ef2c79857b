"""bareearth:orthoparallax and bareearth:orthorefine through processing.run and qgis_process.

Synthetic frames rendered by ray casting (core.orthophoto.render) with known truth, written to
GeoTIFFs in a temporary folder, on a UTM-like grid (coordinates offset to 500 km / 5400 km).
"""
import csv
import math
import os
import re

import numpy as np
import pytest
from scipy import ndimage

pytestmark = pytest.mark.qgis

OFF = np.array([500000.0, 5400000.0, 0.0])
EPSG = 32632


def _read(path, band=1):
    from osgeo import gdal
    ds = gdal.Open(str(path))
    b = ds.GetRasterBand(band)
    return b.ReadAsArray(), b.GetNoDataValue(), ds.GetGeoTransform(), ds.GetProjection()


def _shifted(transform):
    t = list(transform)
    t[0] += OFF[0]
    t[3] += OFF[1]
    return tuple(t)


def _write(path, arr, gt, nodata=None, epsg=EPSG):
    from bare_earth.core.grid import write_array
    return write_array(path, arr, gt, epsg, nodata=nodata)


def _write_rgba(path, grey, gt):
    """A Byte RGBA GeoTIFF of a grey image (alpha 0 where NaN)."""
    from osgeo import gdal, osr
    ok = np.isfinite(grey)
    g = np.clip(np.nan_to_num(grey, nan=0.0), 0, 255).round().astype(np.uint8)
    ds = gdal.GetDriverByName("GTiff").Create(str(path), g.shape[1], g.shape[0], 4, gdal.GDT_Byte,
                                              options=["PHOTOMETRIC=RGB", "ALPHA=YES"])
    ds.SetGeoTransform(gt)
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(EPSG)
    ds.SetProjection(srs.ExportToWkt())
    for k in range(3):
        ds.GetRasterBand(k + 1).WriteArray(g)
    ds.GetRasterBand(4).WriteArray(np.where(ok, 255, 0).astype(np.uint8))
    ds.GetRasterBand(4).SetColorInterpretation(gdal.GCI_AlphaBand)
    ds = None
    return str(path)


def _write_frame(path, img):
    """A frame image without georeference (float32, NaN nodata)."""
    from osgeo import gdal
    ds = gdal.GetDriverByName("GTiff").Create(str(path), img.shape[1], img.shape[0], 1, gdal.GDT_Float32)
    ds.GetRasterBand(1).SetNoDataValue(float("nan"))
    ds.GetRasterBand(1).WriteArray(img)
    ds = None
    return str(path)


def _xyz(c):
    return ",".join(repr(float(v)) for v in np.asarray(c.centre) + OFF)


def _write_exterior(path, cams, names=None, override=None):
    rows = ["filename,x,y,z,omega,phi,kappa"]
    for k, c in enumerate(cams):
        name = (names or [c.name for c in cams])[k]
        x, y, z = np.asarray(c.centre) + OFF
        o, p, kap = c.opk_deg
        vals = [name, repr(x), repr(y), repr(z), repr(o), repr(p), repr(kap)]
        if override and name in override:
            vals = [name] + override[name]
        rows.append(",".join(vals))
    path.write_text("\n".join(rows) + "\n")
    return str(path)


def _write_interior(path, io):
    s = max(io.width, io.height)
    path.write_text(f"synthetic:\n  type: pinhole\n  im_size: [{io.width}, {io.height}]\n"
                    f"  focal_len: {io.fx / s!r}\n  cx: {(io.c0 - (io.width - 1) / 2) / s!r}\n"
                    f"  cy: {(io.r0 - (io.height - 1) / 2) / s!r}\n")
    return str(path)


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """Two vertical frames (B/H 0.45) orthorectified on the bare terrain: A single band, B RGBA."""
    from bare_earth.core.orthophoto import make_ortho_scene, orthorectify, render_frames, vertical_cameras
    d = tmp_path_factory.mktemp("pair")
    sc = make_ortho_scene(seed=1)
    cams = vertical_cameras(sc, 2, base_over_height=0.45)
    imgs = render_frames(sc, cams)
    oa, ob = (orthorectify(im, c, sc.terrain, sc.transform)[0] for im, c in zip(imgs, cams))
    gt = _shifted(sc.transform)
    files = dict(dem=_write(d / "terrain.tif", sc.terrain, gt),
                 a=_write(d / "ortho_a.tif", oa, gt, nodata=float("nan")),
                 b=_write_rgba(d / "ortho_b.tif", ob, gt))
    B = float(cams[1].centre[0] - cams[0].centre[0])
    H = float(cams[0].centre[2] - np.mean(sc.terrain))
    return dict(scene=sc, cams=cams, orthos=(oa, ob), gt=gt, dir=d, B=B, H=H, **files)


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    """Three vertical frames (B/H 0.3) and a start DEM = true surface + a smooth 3 m error."""
    from bare_earth.core.orthophoto import make_ortho_scene, render_frames, vertical_cameras
    d = tmp_path_factory.mktemp("frames")
    sc = make_ortho_scene(seed=2)
    cams = vertical_cameras(sc, 3, base_over_height=0.3)
    imgs = render_frames(sc, cams)
    rng = np.random.default_rng(5)
    err = ndimage.gaussian_filter(rng.normal(size=sc.surface.shape), 25)
    start = (sc.surface + err / err.std() * 3.0).astype(np.float32)
    gt = _shifted(sc.transform)
    img_dir = d / "images"
    img_dir.mkdir()
    paths = [_write_frame(img_dir / f"{c.name}.tif", im) for c, im in zip(cams, imgs)]
    return dict(scene=sc, cams=cams, start=start, gt=gt, dir=d, images=paths, image_dir=str(img_dir),
                dem=_write(d / "start.tif", start, gt, nodata=-9999.0),
                exterior=_write_exterior(d / "exterior.csv", cams),
                interior=_write_interior(d / "interior.yaml", cams[0].interior))


# --------------------------------------------------------------------------- registration
def test_registered(qgis_app):
    from qgis.core import QgsApplication
    reg = QgsApplication.processingRegistry()
    for alg_id in ("bareearth:orthoparallax", "bareearth:orthorefine"):
        alg = reg.algorithmById(alg_id)
        assert alg is not None, alg_id
        assert alg.group() == "Orthophoto refinement" and alg.shortHelpString()
        for p in alg.parameterDefinitions():
            assert p.help(), f"{alg_id}:{p.name()} has no help"
    assert "omega" in reg.algorithmById("bareearth:orthorefine").shortHelpString()


# --------------------------------------------------------------------------- orthoparallax
def _check_grid(paths, ref):
    _, _, gt, crs = _read(ref)
    for p in paths:
        _, _, g, c = _read(p)
        assert g == gt and c == crs, p


def test_orthoparallax_recovers_buildings(processing_run, pair):
    from bare_earth.core.codes import OBJECT
    d, sc, cams = pair["dir"], pair["scene"], pair["cams"]
    res = processing_run("bareearth:orthoparallax", {
        "ORTHO_A": pair["a"], "ORTHO_B": pair["b"], "DEM": pair["dem"],
        "CAMERA_A": _xyz(cams[0]), "CAMERA_B": _xyz(cams[1]),
        "OUTPUT_DEM": str(d / "dem.tif"), "OUTPUT_DH": str(d / "dh.tif"),
        "OUTPUT_QUALITY": str(d / "q.tif"), "OUTPUT_MASK": str(d / "mask.tif")})
    _check_grid([res[k] for k in ("OUTPUT_DEM", "OUTPUT_DH", "OUTPUT_QUALITY", "OUTPUT_MASK")], pair["dem"])
    mask, mnd, _, _ = _read(res["OUTPUT_MASK"])
    dh = _read(res["OUTPUT_DH"])[0]
    dem = _read(res["OUTPUT_DEM"])[0]
    q = _read(res["OUTPUT_QUALITY"])[0]
    assert mask.dtype == np.uint8 and mnd == 255 and set(np.unique(mask)) <= {0, 1, 2, 255}
    assert (d / "mask.qml").exists()
    true_dh = sc.surface - sc.terrain
    for k in sc.heights:
        m = sc.labels == k
        assert np.nanmedian(dh[m]) > 0.8 * np.median(true_dh[m]), k
    obj = sc.labels > 0
    seen = mask != 255
    assert (mask[obj & seen] == OBJECT).mean() > 0.85
    assert (mask[~obj & seen] == OBJECT).mean() < 0.05
    assert np.nanmedian(np.abs((dem - sc.surface)[obj & seen])) < 1.0
    assert np.nanmean(q) > 0.7


def test_orthoparallax_base_and_height_temporary_outputs(processing_run, pair):
    sc = pair["scene"]
    res = processing_run("bareearth:orthoparallax", {
        "ORTHO_A": pair["a"], "ORTHO_B": pair["b"], "DEM": pair["dem"], "BASE_M": pair["B"],
        "HEIGHT_M": pair["H"], "BASE_DIRECTION_DEG": 0.0, "WINDOW_CELLS": 7, "MIN_CORRELATION": 0.6,
        "HEIGHT_THRESHOLD_M": 2.0, "OUTPUT_DEM": "TEMPORARY_OUTPUT", "OUTPUT_DH": "TEMPORARY_OUTPUT",
        "OUTPUT_MASK": "TEMPORARY_OUTPUT"})
    dh = _read(res["OUTPUT_DH"])[0]
    assert np.nanmedian(dh[sc.labels > 0]) > 5
    assert "OUTPUT_QUALITY" not in res or not res["OUTPUT_QUALITY"]


def test_orthoparallax_cancel_writes_nothing(processing_run, pair, tmp_path):
    from qgis.core import QgsProcessingFeedback
    fb = QgsProcessingFeedback()
    fb.cancel()
    out = tmp_path / "dem.tif"
    res = processing_run("bareearth:orthoparallax", {
        "ORTHO_A": pair["a"], "ORTHO_B": pair["b"], "DEM": pair["dem"], "BASE_M": pair["B"],
        "HEIGHT_M": pair["H"], "OUTPUT_DEM": str(out), "OUTPUT_MASK": str(tmp_path / "m.tif")}, feedback=fb)
    assert not out.exists() and not res.get("OUTPUT_DEM")


def _parallax_bad(pair, tmp):
    from osgeo import gdal
    cams = pair["cams"]
    oa, ob = pair["orthos"]
    gt = pair["gt"]
    crop = str(tmp / "crop.tif")
    gdal.Translate(crop, pair["dem"], srcWin=[0, 0, 150, 120])
    left, right = np.full_like(oa, np.nan), np.full_like(ob, np.nan)
    left[:, :60], right[:, -60:] = oa[:, :60], ob[:, -60:]
    apart = dict(ORTHO_A=_write(tmp / "left.tif", left, gt, nodata=float("nan")),
                 ORTHO_B=_write(tmp / "right.tif", right, gt, nodata=float("nan")))
    bh = dict(BASE_M=pair["B"], HEIGHT_M=pair["H"])
    geo = _write(tmp / "geo.tif", pair["scene"].terrain, (7.0, 1e-5, 0.0, 45.0, 0.0, -1e-5), epsg=4326)
    return [
        ("geographic", dict(DEM=geo, **bh), "geographic CRS"),
        ("grid", dict(DEM=crop, **bh), r"ORTHO_A .* is not on the DEM's grid: ORTHO_A has 200 x 160 cells.*"
                                       r"the DEM .*crop.tif\) has 150 x 120 cells"),
        ("b0", dict(BASE_M=0.0, HEIGHT_M=pair["H"]), "base B must be > 0"),
        ("h0", dict(BASE_M=pair["B"], HEIGHT_M=-10.0), "flying height H must be > 0"),
        ("same_place", dict(CAMERA_A=_xyz(cams[0]), CAMERA_B=_xyz(cams[0])), "same place"),
        ("bad_xyz", dict(CAMERA_A="1,2", CAMERA_B=_xyz(cams[1])), "CAMERA_A must be the camera centre"),
        ("no_geometry", {}, "give the geometry of the pair"),
        ("no_overlap", dict(**apart, **bh), "do not overlap"),
    ]


def test_orthoparallax_bad_inputs(processing_run, pair, tmp_path):
    from qgis.core import QgsProcessingException
    for name, extra, message in _parallax_bad(pair, tmp_path):
        out = tmp_path / f"{name}_dem.tif"
        params = {"ORTHO_A": pair["a"], "ORTHO_B": pair["b"], "DEM": pair["dem"], "OUTPUT_DEM": str(out),
                  "OUTPUT_MASK": str(tmp_path / f"{name}_mask.tif"), **extra}
        with pytest.raises(QgsProcessingException, match=message):
            processing_run("bareearth:orthoparallax", params)
        assert not out.exists(), name


# --------------------------------------------------------------------------- orthorefine
def test_orthorefine_reduces_rmse(processing_run, frames):
    d, sc = frames["dir"], frames["scene"]
    res = processing_run("bareearth:orthorefine", {
        "DEM": frames["dem"], "IMAGES": frames["images"], "EXTERIOR": frames["exterior"],
        "INTERIOR": frames["interior"], "MAX_ITERATIONS": 4,
        "OUTPUT_DEM": str(d / "refined.tif"), "OUTPUT_DH": str(d / "dh.tif"),
        "OUTPUT_QUALITY": str(d / "q.tif"), "OUTPUT_MASK": str(d / "mask.tif"),
        "OUTPUT_ORTHO_FOLDER": str(d / "orthos"), "OUTPUT_TABLE": str(d / "table.csv")})
    _check_grid([res[k] for k in ("OUTPUT_DEM", "OUTPUT_DH", "OUTPUT_QUALITY", "OUTPUT_MASK")], frames["dem"])
    mask, mnd, _, _ = _read(res["OUTPUT_MASK"])
    dem, dnd, _, _ = _read(res["OUTPUT_DEM"])
    assert mask.dtype == np.uint8 and mnd == 255 and set(np.unique(mask)) <= {0, 1, 2, 255}
    assert dnd == -9999.0 and (d / "mask.qml").exists()
    seen2 = mask != 255
    assert seen2.mean() > 0.5
    e0 = math.sqrt(np.mean((frames["start"] - sc.surface)[seen2] ** 2))
    e1 = math.sqrt(np.mean((dem - sc.surface)[seen2] ** 2))
    assert e0 > 2.5 and e1 < 0.3 * e0, (e0, e1)
    dh = _read(res["OUTPUT_DH"])[0]
    np.testing.assert_allclose(dh[seen2], (dem - frames["start"])[seen2], atol=1e-3)
    with open(res["OUTPUT_TABLE"], newline="") as f:
        rows = list(csv.DictReader(f))
    # one row per measurement; ITERATIONS counts the updates kept in the DEM
    assert 2 <= len(rows) <= 5 and res["ITERATIONS"] == sum(r["status"] == "applied" for r in rows) >= 1
    assert {"iteration", "rms_correction_m", "matched_share", "pairs", "rms_parallax_m", "agreement", "status",
            "mean_corr"} <= set(rows[0])
    assert float(rows[0]["rms_correction_m"]) > float(rows[-1]["rms_correction_m"])
    assert float(rows[1]["agreement"]) < 1                           # the first update made the pairs agree
    for c in frames["cams"]:
        p = d / "orthos" / f"{c.name}_ortho.tif"
        assert p.exists()
        _check_grid([p], frames["dem"])


def test_orthorefine_qgis_process_folder(run_qgis_process, frames, tmp_path):
    """A folder with a DEM beside the frames (as the NGI data): the file the CSV does not name is
    skipped and named in the log; OUTPUT_MASK is optional."""
    import shutil
    folder = tmp_path / "frames"
    folder.mkdir()
    for p in frames["images"]:
        shutil.copy(p, folder / os.path.basename(p))
    shutil.copy(frames["dem"], folder / "dem.tif")
    rc, out, data = run_qgis_process("bareearth:orthorefine", {
        "DEM": frames["dem"], "IMAGE_FOLDER": str(folder), "EXTERIOR": frames["exterior"],
        "INTERIOR": frames["interior"], "MAX_ITERATIONS": 1, "CROSS_CHECK": True,
        "OUTPUT_DEM": str(tmp_path / "r.tif"),
        "OUTPUT_DH": str(tmp_path / "dh.tif"), "OUTPUT_QUALITY": str(tmp_path / "q.tif"),
        "OUTPUT_TABLE": str(tmp_path / "t.csv")})
    assert rc == 0, out
    assert data is not None and data["results"]["ITERATIONS"] == 1
    assert "skipped 1 file(s) that EXTERIOR does not name: dem.tif" in out
    assert "rms_correction_m" in out                                   # the table in the log
    # CROSS_CHECK reaches the core: three frames along one base give one family, nothing to cross-check
    assert "not possible: all pairs have one base direction" in out
    _check_grid([tmp_path / "r.tif", tmp_path / "dh.tif"], frames["dem"])
    assert not data["results"].get("OUTPUT_MASK") and not list(tmp_path.glob("*mask*"))
    assert (tmp_path / "t.csv").read_text().startswith("iteration,")


def test_orthorefine_progress_and_cancel(processing_run, frames, tmp_path):
    from qgis.core import QgsProcessingFeedback

    class Stop(QgsProcessingFeedback):
        seen = []

        def setProgress(self, p):  # noqa: N802
            self.seen.append(p)
            super().setProgress(p)
            if p > 40:
                self.cancel()

    fb = Stop()
    out = tmp_path / "dem.tif"
    res = processing_run("bareearth:orthorefine", {
        "DEM": frames["dem"], "IMAGES": frames["images"], "EXTERIOR": frames["exterior"],
        "INTERIOR": frames["interior"], "MAX_ITERATIONS": 4, "OUTPUT_DEM": str(out),
        "OUTPUT_MASK": str(tmp_path / "m.tif")}, feedback=fb)
    assert fb.seen and all(0 <= p <= 100 for p in fb.seen) and np.all(np.diff(fb.seen) >= -1e-9)
    assert max(fb.seen) < 100 and not out.exists() and not res.get("OUTPUT_DEM")


def _refine_bad(frames, tmp):
    from bare_earth.core.orthophoto import Camera, Interior
    cams = frames["cams"]
    ext = lambda name, **kw: _write_exterior(tmp / f"{name}.csv", cams, **kw)  # noqa: E731
    # two small frames over the two ends of the DEM: each sees the DEM, they share nothing
    io = Interior(40, 40, cams[0].interior.fx, cams[0].interior.fy, 19.5, 19.5, name="small")
    small_dir = tmp / "small"
    small_dir.mkdir()
    X0, Y0 = frames["gt"][0] - OFF[0], frames["gt"][3] - OFF[1]
    apart = [Camera.vertical(io, X0 + 30, Y0 - 80, cams[0].centre[2], name="w"),
             Camera.vertical(io, X0 + 170, Y0 - 80, cams[0].centre[2], name="e")]
    small = [_write_frame(small_dir / f"{c.name}.tif", np.zeros((40, 40), np.float32)) for c in apart]
    far = [type(c)(c.interior, c.centre + np.array([10000.0, 0, 0]), c.R, c.name, c.opk_deg) for c in cams]
    # folders holding a partly copied frame (it opens, its pixels cannot be read) or a file that is
    # no raster at all: each was a Python traceback (RuntimeError) before
    cut, junk = tmp / "cut", tmp / "junk"
    for folder in (cut, junk):
        folder.mkdir()
        for p in frames["images"]:
            with open(p, "rb") as fh:
                (folder / os.path.basename(p)).write_bytes(fh.read())
    (cut / "frame1.tif").write_bytes((cut / "frame1.tif").read_bytes()[:400])
    (junk / "frame2.tif").write_text("not an image")
    return [
        ("cut_frame", dict(IMAGES=None, IMAGE_FOLDER=str(cut)),
         r"the image '.*cut/frame1.tif' is not a raster that can be read .*: replace it"),
        ("junk_frame", dict(IMAGES=None, IMAGE_FOLDER=str(junk)),
         r"the image '.*junk/frame2.tif' is not a raster that can be read .*: replace it"),
        ("missing", dict(EXTERIOR=ext("missing", names=["frame0", "frame1", "other"])),
         r"no exterior orientation for image\(s\) \['frame2'\]"),
        ("angle_text", dict(EXTERIOR=ext("angle_text", override={"frame1": ["500040", "5400080", "250",
                                                                             "zero", "0", "0"]})),
         "omega='zero' is not a number"),
        ("angle_range", dict(EXTERIOR=ext("angle_range", override={"frame2": ["500040", "5400080", "250",
                                                                              "0", "0", "400"]})),
         r"outside \[-360, 360\]"),
        ("angle_tilt", dict(EXTERIOR=ext("angle_tilt", override={"frame0": ["500040", "5400080", "250",
                                                                            "95", "0", "0"]})),
         "90 deg or more from the nadir"),
        ("off_dem", dict(EXTERIOR=_write_exterior(tmp / "far.csv", far)), r"do not overlap the DEM"),
        ("apart", dict(IMAGES=small, EXTERIOR=_write_exterior(tmp / "apart.csv", apart),
                       INTERIOR=_write_interior(tmp / "small.yaml", io)), "no two images overlap"),
        ("one_image", dict(IMAGES=frames["images"][:1]), "two or more"),
        ("no_orientation", dict(EXTERIOR=None, INTERIOR=None), "give the orientation"),
    ]


def test_orthorefine_bad_inputs(processing_run, frames, tmp_path):
    from qgis.core import QgsProcessingException
    for name, extra, message in _refine_bad(frames, tmp_path):
        out = tmp_path / f"{name}_dem.tif"
        params = {"DEM": frames["dem"], "IMAGES": frames["images"], "EXTERIOR": frames["exterior"],
                  "INTERIOR": frames["interior"], "OUTPUT_DEM": str(out),
                  "OUTPUT_MASK": str(tmp_path / f"{name}_mask.tif"), **extra}
        params = {k: v for k, v in params.items() if v is not None}
        with pytest.raises(QgsProcessingException, match=message):
            processing_run("bareearth:orthorefine", params)
        assert not out.exists(), name


def test_orthorefine_tie_points(processing_run, pair, tmp_path):
    """Eq. 17 mode: the two orthophotos in their own pixel grids, tie points, B and H."""
    from bare_earth.core.orthophoto import grid_xy
    sc = pair["scene"]
    X, Y = grid_xy(sc.terrain.shape, pair["gt"])
    rows = ["image,x,y,col,row"]
    paths = []
    for k, o in enumerate(pair["orthos"]):
        # own grid: the DEM grid shifted by (12 + 5k, 9) pixels
        off = (12 + 5 * k, 9)
        own = np.full((sc.terrain.shape[0] + 20, sc.terrain.shape[1] + 30), np.nan, np.float32)
        own[off[1]:off[1] + o.shape[0], off[0]:off[0] + o.shape[1]] = o
        paths.append(_write_frame(tmp_path / f"own{k}.tif", own))
        for c, r in ((10, 10), (180, 15), (20, 150), (190, 140), (100, 80)):
            rows.append(f"own{k},{X[0, c]!r},{Y[r, 0]!r},{c + off[0]},{r + off[1]}")
    ties = tmp_path / "ties.csv"
    ties.write_text("\n".join(rows) + "\n")
    res = processing_run("bareearth:orthorefine", {
        "DEM": pair["dem"], "IMAGES": paths, "TIE_POINTS": str(ties), "BASE_M": pair["B"],
        "HEIGHT_M": pair["H"], "OUTPUT_DEM": "TEMPORARY_OUTPUT", "OUTPUT_DH": "TEMPORARY_OUTPUT",
        "OUTPUT_MASK": "TEMPORARY_OUTPUT"})
    dh = _read(res["OUTPUT_DH"])[0]
    assert np.nanmedian(dh[sc.labels > 0]) > 5
    assert res["ITERATIONS"] == 1
    from qgis.core import QgsProcessingException
    with pytest.raises(QgsProcessingException, match="needs BASE_M"):
        processing_run("bareearth:orthorefine", {"DEM": pair["dem"], "IMAGES": paths, "TIE_POINTS": str(ties),
                                                 "OUTPUT_DEM": "TEMPORARY_OUTPUT", "OUTPUT_MASK": "TEMPORARY_OUTPUT"})


# --------------------------------------------------------------------------- real data
@pytest.mark.parametrize("not_rougher", [False, True])
def test_orthorefine_drone_frames(processing_run, shared_data, tmp_path, not_rougher):
    """Four oblique DJI frames (OpenSfM Brown cameras, OPK CSV): start from the DSM smoothed by a
    10 m Gaussian; the refined DEM is closer to the DSM on the cells seen by two frames, and the
    pairs' residual parallax falls, with NOT_ROUGHER (the default: the smoothness step acts, its
    multiplier in the table; the relief comes from the detail two pairs confirm) and without."""
    from osgeo import gdal
    root = shared_data / "stereo" / "orthority"
    if not (root / "odm").is_dir():
        pytest.skip("orthority drone data absent")
    ds = gdal.Open(str(root / "odm" / "odm_dem" / "dsm.tif"))
    b = ds.GetRasterBand(1)
    dsm = b.ReadAsArray().astype(np.float32)
    nd = b.GetNoDataValue()
    ok = np.isfinite(dsm) & ((dsm != nd) if nd is not None else True)
    gt = ds.GetGeoTransform()
    s = 10.0 / gt[1]
    with np.errstate(invalid="ignore", divide="ignore"):
        start = (ndimage.gaussian_filter(np.where(ok, dsm, 0), s)
                 / ndimage.gaussian_filter(ok.astype(np.float64), s))
    start = np.where(ok, start, np.nan).astype(np.float32)
    dem = _write(tmp_path / "start.tif", start, gt, nodata=float("nan"), epsg=ds.GetProjection())
    res = processing_run("bareearth:orthorefine", {
        "DEM": dem, "IMAGE_FOLDER": str(root / "odm" / "images"),
        "EXTERIOR": str(root / "io" / "odm_xyz_opk.csv"),
        "INTERIOR": str(root / "odm" / "opensfm" / "reconstruction.json"), "MAX_ITERATIONS": 2,
        "NOT_ROUGHER": not_rougher,
        "OUTPUT_DEM": str(tmp_path / "refined.tif"), "OUTPUT_MASK": str(tmp_path / "mask.tif"),
        "OUTPUT_DH": "TEMPORARY_OUTPUT", "OUTPUT_TABLE": str(tmp_path / "t.csv")})
    refined = _read(res["OUTPUT_DEM"])[0]
    mask = _read(res["OUTPUT_MASK"])[0]
    ev = (mask != 255) & ok
    assert ev.sum() > 20000
    e0 = math.sqrt(np.mean((start - dsm)[ev] ** 2))
    e1 = math.sqrt(np.mean((refined - dsm)[ev] ** 2))
    with open(tmp_path / "t.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert e1 < 0.97 * e0, (e0, e1)                     # measured 2.67 -> 2.51 m, either way
    assert (float(rows[0]["smoothness_mu"]) > 0) == not_rougher      # the step acted (0: as measured)
    assert float(rows[-1]["rms_parallax_m"]) < 0.5 * float(rows[0]["rms_parallax_m"])


def test_orthoparallax_drone_orthophotos_line_up(processing_run, shared_data, tmp_path):
    """Two RGB orthophotos of oblique drone frames made with their own DSM: dh is about 0."""
    from osgeo import gdal

    from bare_earth.core.orthophoto import orthorectify, read_cameras
    root = shared_data / "stereo" / "orthority"
    if not (root / "odm").is_dir():
        pytest.skip("orthority drone data absent")
    dsm_path = str(root / "odm" / "odm_dem" / "dsm.tif")
    ds = gdal.Open(dsm_path)
    dsm = ds.ReadAsArray().astype(np.float32)
    gt = ds.GetGeoTransform()
    names = ["100_0005_0136", "100_0005_0142"]
    cams = read_cameras(root / "io" / "odm_xyz_opk.csv", root / "odm" / "opensfm" / "reconstruction.json", names)
    paths = []
    for n, c in zip(names, cams):
        im = gdal.Open(str(root / "odm" / "images" / f"{n}.tif")).ReadAsArray().astype(np.float32)
        o = orthorectify(ndimage.gaussian_filter(im, (0, 2.0, 2.0)), c, dsm, gt)[0]
        paths.append(_write(tmp_path / f"{n}_ortho.tif", o, gt, nodata=float("nan"), epsg=ds.GetProjection()))
    from qgis.core import QgsProcessingFeedback
    warnings = []
    fb = QgsProcessingFeedback()
    fb.pushWarning = warnings.append
    res = processing_run("bareearth:orthoparallax", {
        "ORTHO_A": paths[0], "ORTHO_B": paths[1], "DEM": dsm_path,
        "CAMERA_A": ",".join(repr(float(v)) for v in cams[0].centre),
        "CAMERA_B": ",".join(repr(float(v)) for v in cams[1].centre), "MAX_DH_M": 8.0,
        "OUTPUT_DEM": "TEMPORARY_OUTPUT", "OUTPUT_DH": "TEMPORARY_OUTPUT", "OUTPUT_MASK": "TEMPORARY_OUTPUT"},
        feedback=fb)
    dh = _read(res["OUTPUT_DH"])[0]
    mask = _read(res["OUTPUT_MASK"])[0]
    assert np.isfinite(dh).sum() > 0.5 * (mask != 255).sum()
    assert abs(np.nanmedian(dh)) < 0.3 and np.nanmedian(np.abs(dh)) < 0.8
    assert not [w for w in warnings if "wrong order" in w]      # orthophotos on their DSM: no false alarm


def test_orthorefine_with_orientation_absurd_max_dh_refused(processing_run, frames, tmp_path):
    """A parallax search wider than the DEM is refused with exterior orientation too (B: the closest
    pair of camera centres, H: above the DEM's median); MAX_DH_M = 1e6 m had not finished after
    8 min on these three 200 x 160 frames."""
    from qgis.core import QgsProcessingException
    out = tmp_path / "o.tif"
    with pytest.raises(QgsProcessingException, match=r"parallax searched.*wider than the DEM.*MAX_DH_M below"):
        processing_run("bareearth:orthorefine", {
            "DEM": frames["dem"], "IMAGES": frames["images"], "EXTERIOR": frames["exterior"],
            "INTERIOR": frames["interior"], "MAX_DH_M": 1e6, "OUTPUT_DEM": str(out)})
    assert not out.exists()


def test_orthoparallax_pair_given_in_the_wrong_order_warns(processing_run, pair, tmp_path):
    """CAMERA_A and CAMERA_B swapped: every building came out as low cells below the DEM (object
    recall 0.97 -> 0.00) and the run said nothing. It warns now, naming the check; the right order
    does not warn."""
    from qgis.core import QgsProcessingFeedback
    cams = pair["cams"]
    for k, (ca, cb) in enumerate(((cams[0], cams[1]), (cams[1], cams[0]))):
        warnings = []
        fb = QgsProcessingFeedback()
        fb.pushWarning = warnings.append
        processing_run("bareearth:orthoparallax", {
            "ORTHO_A": pair["a"], "ORTHO_B": pair["b"], "DEM": pair["dem"], "CAMERA_A": _xyz(ca),
            "CAMERA_B": _xyz(cb), "OUTPUT_DEM": str(tmp_path / f"dem{k}.tif"),
            "OUTPUT_MASK": str(tmp_path / f"mask{k}.tif")}, feedback=fb)
        said = [w for w in warnings if "wrong order" in w]
        assert bool(said) == (k == 1), warnings
    assert re.search(r"\d+ cells lie below the DEM \(low\) and only \d+ above it", said[0])
    assert "CAMERA_A is the centre of ORTHO_A's frame" in said[0]


def test_orthorefine_orthophotos_that_would_replace_an_input_refused_before_work(processing_run, frames, tmp_path):
    """OUTPUT_ORTHO_FOLDER holding the DEM as frame0_ortho.tif (or OUTPUT_DEM so named): the run did
    all its work, then stopped on a Python traceback while writing the orthophotos. Refused before
    any work, naming the file and the input."""
    import shutil

    from qgis.core import QgsProcessingException
    dem = tmp_path / "frame0_ortho.tif"
    shutil.copy(frames["dem"], dem)
    base = {"IMAGES": frames["images"], "EXTERIOR": frames["exterior"], "INTERIOR": frames["interior"],
            "MAX_ITERATIONS": 1, "OUTPUT_ORTHO_FOLDER": str(tmp_path)}
    for extra, what in (({"DEM": str(dem), "OUTPUT_DEM": str(tmp_path / "refined.tif")}, r"'Starting DEM' \(DEM\)"),
                        ({"DEM": frames["dem"], "OUTPUT_DEM": str(tmp_path / "frame1_ortho.tif")},
                         r"'Refined DEM' \(OUTPUT_DEM\)")):
        with pytest.raises(QgsProcessingException, match=r"\(OUTPUT_ORTHO_FOLDER\): the orthophoto of frame\d would "
                                                         r"be written as .*frame\d_ortho.tif, a file of " + what):
            processing_run("bareearth:orthorefine", {**base, **extra, "OUTPUT_MASK": str(tmp_path / "m.tif")})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frame0_ortho.tif"]


def test_orthoparallax_output_that_cannot_be_written_is_a_message(processing_run, pair, tmp_path, monkeypatch):
    """A write that fails (a full disk: grid raises a ValueError naming the output) ended the run
    on a Python traceback; it is the message."""
    from qgis.core import QgsProcessingException

    from bare_earth.core import grid

    def full(self, *a, **k):
        raise ValueError("cannot write the output 'dem.tif': No space left on device (the disk may be full)")
    monkeypatch.setattr(grid.OutputSet, "write", full)
    cams = pair["cams"]
    with pytest.raises(QgsProcessingException) as err:
        processing_run("bareearth:orthoparallax", {
            "ORTHO_A": pair["a"], "ORTHO_B": pair["b"], "DEM": pair["dem"], "CAMERA_A": _xyz(cams[0]),
            "CAMERA_B": _xyz(cams[1]), "OUTPUT_DEM": str(tmp_path / "dem.tif")})
    assert "No space left on device" in str(err.value) and "Traceback" not in str(err.value)
