"""Parallax -> height, orthoparallax and orthorefine on rendered synthetic frames."""
import numpy as np
import pytest
from scipy import ndimage

from bare_earth.core.codes import NODATA, OBJECT
from bare_earth.core.orthophoto import (
    fill_holes,
    orthoparallax,
    orthorefine,
    parallax_to_dh,
    parallax_to_dh_vertical,
    view_vectors,
)
from bare_earth.core.orthophoto.orthorectify import orthorectify
from bare_earth.core.orthophoto.refine import pair_geometry
from bare_earth.core.orthophoto.render import make_ortho_scene, render_frames, vertical_cameras


def test_general_parallax_reduces_to_eq18_for_vertical_frames():
    H, B = 1500.0, 600.0
    ca, cb = (1000.0, 2000.0, H), (1000.0 + B, 2000.0, H)
    X = np.array([[900.0, 1300.0, 2100.0]])
    Y = np.array([[1500.0, 2000.0, 2600.0]])
    va, vb = view_vectors(ca, X, Y, 0.0), view_vectors(cb, X, Y, 0.0)
    dx = np.array([[-3.0, 0.5, 12.0]])            # feature in b against the base: dh > 0
    dh = parallax_to_dh(-dx, 0 * dx, va, vb)       # parallax vector p = -dx along +X
    np.testing.assert_allclose(dh, parallax_to_dh_vertical(dx, B, H), rtol=1e-12)
    np.testing.assert_allclose(parallax_to_dh_vertical(6.0, 600.0, 1500.0), 15.0)


def test_parallax_to_dh_general_geometry():
    # a point 8 m above a DEM at 0: its images on the DEM plane move by dh * v
    ca, cb = np.array([0.0, 0.0, 120.0]), np.array([40.0, -25.0, 130.0])
    P = np.array([30.0, 20.0, 8.0])
    shift = lambda c: 8.0 * (P[:2] - c[:2]) / (c[2] - P[2])  # noqa: E731
    p = shift(cb) - shift(ca)
    va, vb = view_vectors(ca, P[0], P[1], P[2]), view_vectors(cb, P[0], P[1], P[2])
    assert float(parallax_to_dh(p[0], p[1], va, vb)) == pytest.approx(8.0, rel=1e-12)


def test_bad_geometry_errors():
    with pytest.raises(ValueError, match="B must be > 0"):
        parallax_to_dh_vertical(1.0, 0.0, 100.0)
    with pytest.raises(ValueError, match="H must be > 0"):
        parallax_to_dh_vertical(1.0, 10.0, -5.0)
    with pytest.raises(ValueError, match="B = 0"):
        parallax_to_dh(1.0, 0.0, (0.1, 0.2), (0.1, 0.2))


def test_fill_holes():
    z = np.arange(100, dtype=float).reshape(10, 10)
    z[3:5, 3:6] = np.nan
    f = fill_holes(z)
    assert np.isfinite(f).all()
    assert np.nanmax(np.abs(f - np.arange(100).reshape(10, 10))) < 6


@pytest.fixture(scope="module")
def scene2():
    sc = make_ortho_scene(seed=1)
    cams = vertical_cameras(sc, 2, base_over_height=0.45)
    imgs = render_frames(sc, cams)
    orthos = [orthorectify(im, c, sc.terrain, sc.transform)[0] for im, c in zip(imgs, cams)]
    return sc, cams, imgs, orthos


def test_orthoparallax_recovers_buildings(scene2):
    sc, cams, _, (oa, ob) = scene2
    r = orthoparallax(oa, ob, sc.terrain, sc.transform, centres=(cams[0].centre, cams[1].centre))
    both = r.mask != NODATA
    true_dh = sc.surface - sc.terrain
    for k in sc.heights:
        m = sc.labels == k
        est, tru = float(np.nanmedian(r.dh[m])), float(np.median(true_dh[m]))
        assert abs(est - tru) <= max(0.1 * tru, 0.5), (k, est, tru)
    obj = sc.labels > 0
    recall = float((r.mask[obj & both] == OBJECT).mean())
    false_alarm = float((r.mask[~obj & both] == OBJECT).mean())
    assert recall >= 0.9 and false_alarm < 0.05, (recall, false_alarm)
    ground = ~ndimage.binary_dilation(obj, iterations=4) & both
    assert np.nanmedian(np.abs(r.dh[ground])) < 0.3
    # the corrected DEM is the DSM on the roofs
    assert np.nanmedian(np.abs((r.dem - sc.surface)[obj & both])) < 0.6
    assert r.info["matched_share"] > 0.8 and np.nanmean(r.quality) > 0.8


def test_orthoparallax_with_base_and_height(scene2):
    sc, cams, _, (oa, ob) = scene2
    B = float(cams[1].centre[0] - cams[0].centre[0])
    H = float(cams[0].centre[2] - np.mean(sc.terrain))
    r = orthoparallax(oa, ob, sc.terrain, sc.transform, base_m=B, height_m=H)
    m = sc.labels > 0
    assert np.nanmedian(r.dh[m]) > 5
    with pytest.raises(ValueError, match="B must be > 0"):
        orthoparallax(oa, ob, sc.terrain, sc.transform, base_m=0.0, height_m=H)
    with pytest.raises(ValueError, match="same grid"):
        orthoparallax(oa[:, :-1], ob, sc.terrain, sc.transform, base_m=B, height_m=H)
    with pytest.raises(ValueError, match="coincide"):
        orthoparallax(oa, ob, sc.terrain, sc.transform, centres=(cams[0].centre, cams[0].centre))
    empty = np.full_like(ob, np.nan)
    empty[:, :20] = ob[:, :20]
    a2 = np.full_like(oa, np.nan)
    a2[:, -20:] = oa[:, -20:]
    with pytest.raises(ValueError, match="do not overlap"):
        orthoparallax(a2, empty, sc.terrain, sc.transform, base_m=B, height_m=H)


def _three_frames_smooth_error():
    """Scene 2 seen by three vertical frames (B/H 0.3), and a start DEM with a smooth 3 m
    RMS error."""
    sc = make_ortho_scene(seed=2)
    cams = vertical_cameras(sc, 3, base_over_height=0.3)
    imgs = render_frames(sc, cams)
    rng = np.random.default_rng(5)
    err = ndimage.gaussian_filter(rng.normal(size=sc.surface.shape), 25)
    start = sc.surface + err / err.std() * 3.0
    return sc, cams, imgs, start


def test_orthorefine_reduces_smooth_errors(scene2):
    sc, cams, imgs, start = _three_frames_smooth_error()
    calls = []
    r = orthorefine(start, sc.transform, imgs, cams, max_iterations=4, progress=calls.append)
    seen2 = r.mask != NODATA
    e0 = np.sqrt(np.mean((start - sc.surface)[seen2] ** 2))
    e1 = np.sqrt(np.mean((r.dem - sc.surface)[seen2] ** 2))
    assert e0 > 2.5 and e1 < 0.2 * e0, (e0, e1)
    assert r.table[0]["rms_correction_m"] > 2 and r.table[-1]["rms_correction_m"] < 0.5
    assert all(0.8 < row["matched_share"] <= 1 for row in r.table)
    assert len(r.orthos) == 3 and r.orthos[0].shape == sc.surface.shape
    assert calls and all(0 <= c <= 1 for c in calls) and np.all(np.diff(calls) >= -1e-12)
    assert calls[-1] == 1.0
    # where the pairs agree: the residual parallax per cell on the start DEM and on the result,
    # the same quantities as the table's first and last RMS parallax
    both = np.isfinite(r.parallax_start) & np.isfinite(r.parallax)
    assert both.mean() > 0.5
    for grid, row in ((r.parallax_start, r.table[0]), (r.parallax, r.table[-1])):
        v = grid[np.isfinite(grid)].astype(np.float64)
        assert np.sqrt(np.mean(v ** 2)) == pytest.approx(row["rms_parallax_m"], rel=1e-5)
    assert np.sqrt(np.mean(r.parallax[both] ** 2)) < 0.3 * np.sqrt(np.mean(r.parallax_start[both] ** 2))


def test_orthorefine_bad_inputs(scene2):
    sc, cams, imgs, _ = scene2
    with pytest.raises(ValueError, match="two or more"):
        orthorefine(sc.terrain, sc.transform, imgs[:1], cams[:1])
    with pytest.raises(ValueError, match="one camera per image"):
        orthorefine(sc.terrain, sc.transform, imgs, cams[:1])
    far = [type(cams[1])(cams[1].interior, cams[1].centre + np.array([5000.0, 0, 0]), cams[1].R)]
    with pytest.raises(ValueError, match="overlap"):
        orthorefine(sc.terrain, sc.transform, imgs, [cams[0]] + far)


def test_progress_can_cancel(scene2):
    from bare_earth.core.common import Cancelled
    sc, cams, imgs, _ = scene2

    def stop(f):
        if f > 0.3:
            raise Cancelled()
    with pytest.raises(Cancelled):
        orthorefine(sc.terrain, sc.transform, imgs, cams, max_iterations=3, progress=stop)


def test_drone_orthophotos_line_up_on_their_dsm(shared_data):
    """Real chain (OPK, Brown, collinearity): orthophotos made with the DSM agree."""
    from osgeo import gdal

    from bare_earth.core.orthophoto.camera import cameras_from_opk, read_opensfm_reconstruction, read_opk_csv
    d = shared_data / "stereo" / "orthority"
    ds = gdal.Open(str(d / "odm" / "odm_dem" / "dsm.tif"))
    dsm = ds.ReadAsArray().astype(np.float32)
    gt = ds.GetGeoTransform()
    ios, _, _ = read_opensfm_reconstruction(d / "odm" / "opensfm" / "reconstruction.json")
    names = ["100_0005_0136", "100_0005_0142"]
    cams = cameras_from_opk(read_opk_csv(d / "io" / "odm_xyz_opk.csv"), ios, names)
    imgs = [gdal.Open(str(d / "odm" / "images" / f"{n}.tif")).ReadAsArray().astype(np.float32)
            for n in names]
    oa, ob = (orthorectify(ndimage.gaussian_filter(im.mean(0), 2.0), c, dsm, gt)[0]
              for im, c in zip(imgs, cams))
    r = orthoparallax(oa, ob, dsm, gt, centres=(cams[0].centre, cams[1].centre), max_dh_m=8)
    assert r.info["matched_share"] > 0.5
    assert abs(np.nanmedian(r.dh)) < 0.3 and np.nanmedian(np.abs(r.dh)) < 0.8


def test_pair_geometry_along_equals_dv_projection():
    # along(dh) is exactly (v_b - v_a) . u of dv(dh), in both geometry modes
    rng = np.random.default_rng(5)
    dem = (100 + rng.normal(0, 3, (40, 50))).astype(np.float32)
    dem[3, 4] = np.nan
    t = (1000.0, 0.5, 0.0, 2000.0, 0.0, -0.5)
    dh = rng.normal(0, 4, dem.shape)
    dh[7, 9] = np.nan
    for kw in (dict(centres=((1005.0, 1990.0, 900.0), (1012.0, 1985.0, 905.0)), base_m=None, height_m=None),
               dict(centres=None, base_m=240.0, height_m=800.0)):
        g = pair_geometry(dem, t, kw["centres"], kw["base_m"], kw["height_m"], (0.6, 0.8))
        ux, uy = g["u"]
        for h in (np.zeros(dem.shape), dh):
            (dvx, dvy), _ = g["dv"](h)
            np.testing.assert_array_equal(g["along"](h), dvx * ux + dvy * uy)


def test_orthorefine_stops_one_update_after_parallax_within_noise():
    # once the pairs' RMS residual parallax is below precision_cells of a cell, the update
    # measured then is applied, checked by one more measurement, and the iteration ends
    sc, cams, imgs, start = _three_frames_smooth_error()
    r = orthorefine(start, sc.transform, imgs, cams, max_iterations=6, precision_cells=0.2, tolerance_m=1e-6)
    noise = 0.2 * sc.transform[1]
    below = [k for k, row in enumerate(r.table) if k >= 1 and row["rms_parallax_m"] < noise]
    assert below, [row["rms_parallax_m"] for row in r.table]
    k = below[0]
    assert len(r.table) == k + 2, r.table
    assert r.table[k]["status"] == "applied" and r.table[-1]["status"] == "measured"
    assert "expected matching precision" in r.info["stop"], r.info["stop"]
