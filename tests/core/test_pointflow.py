"""Tests of core/pointflow.py: units, one cloud, tiled blocks (seams), classified-point evaluation."""
import math

import numpy as np
import pytest

from bare_earth.core import pointflow as pf
from bare_earth.core.points import PointCloud, classify_points, read_points, write_points
from bare_earth.core.synthetic import make_scene

FEET = 0.3048


def scene_cloud(shape=(150, 180), seed=4, density=1.5, kind="city", x0=500000.0, y0=5400000.0):
    """Points sampled from a synthetic scene: z of the cell, truth 0 ground / 1 object (ISPRS)."""
    sc = make_scene(kind, shape, seed=seed)
    rng = np.random.default_rng(seed)
    h, w = sc.dsm.shape
    n = int(h * w * density)
    x, y = rng.uniform(0, w, n), rng.uniform(0, h, n)
    r = np.clip((h - y).astype(int), 0, h - 1)
    c = np.clip(x.astype(int), 0, w - 1)
    z = sc.dsm[r, c].astype(np.float64)
    ok = np.isfinite(z)
    truth = (sc.mask[r, c] != 0).astype(np.int32)
    return PointCloud(x[ok] + x0, y[ok] + y0, z[ok], classification=truth[ok])


@pytest.fixture(scope="module")
def cloud():
    return scene_cloud()


# --------------------------------------------------------------------------- stray points
def _tile(n=40000, side=200.0, seed=1):
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0, side, n) + 500000.0, rng.uniform(0, side, n) + 5400000.0
    return x, y, 100.0 + 0.05 * (x - 500000.0)


def test_stray_points_far_from_the_others_refused_naming_the_farthest():
    """One point 2 km from a 200 m tile of 40000 points made the default cell 2.5 m instead of 1 m
    and a grid of 800 x 800 cells, 99 % of them copies of their nearest point, without a word;
    a point off along x only (a bad easting) counts too."""
    x, y, z = _tile()
    clean = PointCloud(x, y, z)
    pf.check_stray_points(clean)                             # a tile: nothing said
    assert pf.default_cell_size_m(clean) == 1.0
    for sx, sy in ((502000.0, 5402000.0), (0.0, 5400100.0)):
        stray = PointCloud(np.append(x, sx), np.append(y, sy), np.append(z, 100.0))
        with pytest.raises(ValueError, match=r"INPUT: 1 of the 40001 points lie far from the others: 99 % of them "
                                             r"span 19\d(\.\d+)? x 19\d(\.\d+)? units, but the whole extent is .*"
                                             rf"the farthest stray point is at x {sx:.10g}, y {sy:.10g}\)"):
            pf.check_stray_points(stray)


def test_a_neighbouring_tile_with_a_stray_point_refused_naming_it():
    """The cell and lattice of a block of tiles follow every tile's extent: one stray point in a neighbouring
    tile (OTHER_TILES; only the input tile was checked) coarsened the block's cell without a word."""
    x, y, z = _tile(n=10000, side=100.0)
    a = PointCloud(x, y, z)
    b = PointCloud(np.append(x + 100.0, 502000.0), np.append(y, 5402000.0), np.append(z, 100.0))
    with pytest.raises(ValueError, match=r"^tile 2: 1 of the 10001 points lie far from the others.*the farthest "
                                         r"stray point is at x 502000, y 5402000\)"):
        pf.filter_tiles([a, b], method="morphological")


def test_stray_points_not_said_of_spread_or_lined_up_points():
    """Two dense blocks far apart, 1 % of the points beyond the bulk but near it, a few points
    (the quantiles of 5 points reach their extremes) and points along a line are no stray points."""
    x, y, z = _tile()
    half = x.size // 2
    pf.check_stray_points(PointCloud(np.r_[x[:half], x[half:] + 5000.0], y, z))
    k = x.size // 100                                        # 1 %, within half the bulk's span
    pf.check_stray_points(PointCloud(np.r_[x[k:], x[:k] + 250.0], y, z))
    pf.check_stray_points(PointCloud(np.array([0.0, 1, 2, 3, 1000]), np.array([0.0, 1, 2, 3, 1000]), np.zeros(5)))
    pf.check_stray_points(PointCloud(np.full(x.size, 500000.0), y, z))


# --------------------------------------------------------------------------- units
def test_axis_scales_and_cell_sizes():
    c = PointCloud(np.array([0.0, 3280.84, 0, 3280.84]), np.array([0.0, 3280.84, 3280.84, 0]),
                   np.array([0.0, 1.0, 2.0, 3.0]), units_to_metre=FEET)
    assert pf.axis_scales(c) == (FEET, FEET, FEET)
    # 1000 m x 1000 m, 4 points 500 m apart: the finest cell keeping a point per 16 cells,
    # 125 m rounded up (:func:`pf.cell_size_for_spacing`)
    assert pf.default_cell_size_m(c) == 200.0
    geo = PointCloud(np.array([10.0, 10.01]), np.array([60.0, 60.01]), np.array([0.0, 1.0]), crs="EPSG:4326")
    sx, sy, sz = pf.axis_scales(geo)
    assert sx == pytest.approx(55800, rel=0.01) and sy == pytest.approx(111420, rel=0.01) and sz == 1.0
    bad = PointCloud(np.array([0.0]), np.array([500000.0]), np.array([0.0]), crs="EPSG:4326")
    with pytest.raises(ValueError, match="not a latitude"):
        pf.axis_scales(bad)


def test_default_cell_is_the_finest_lowest_point_surface_up_to_smrf_cell():
    """About one point per cell where that is at most SMRF's 1 m; sparser points on 1 m cells
    (ISPRS samples 5-7, 0.16-0.18 points/m2: 1 m, no longer 2.5 m), or, where 1 m would leave
    fewer than one point per 16 cells, on a quarter of the spacing rounded up."""
    spacings = (0.3, 0.39, 0.75, 1.03, 1.5, 2.37, 2.53, 3.9, 4.1, 11.8, 19.2, 100.0)
    cells = [pf.cell_size_for_spacing(s) for s in spacings]
    assert cells == [0.25, 0.5, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 2.0, 5.0, 5.0, 25.0]
    assert all(c >= s / 4 - 1e-12 for s, c in zip(spacings, cells) if s > 1.5)
    # a 200 m square at 0.16 points/m2 (ISPRS rural): 1 m
    rng = np.random.default_rng(3)
    n = int(200 * 200 * 0.16)
    c = PointCloud(rng.uniform(0, 200, n) + 500000, rng.uniform(0, 200, n) + 5e6, np.zeros(n))
    assert pf.default_cell_size_m(c) == 1.0
    assert pf.rasterize_cloud(c).cell_size_m == (1.0, 1.0)
    # a block of tiles takes the same default over the tiles' areas
    half = c.x < 500100
    tiles = [PointCloud(c.x[k], c.y[k], c.z[k]) for k in (half, ~half)]
    r = pf.filter_tiles(tiles, method="morphological")
    assert r.cell_size_units == (1.0, 1.0)


def _slope_cloud(density, degrees=20.0, side=160.0, seed=0):
    """All-ground points on a plane of ``degrees``, gradient at 0.5 rad from x, noise 5 cm."""
    rng = np.random.default_rng(seed)
    n = int(side * side * density)
    x, y = rng.uniform(0, side, n), rng.uniform(0, side, n)
    s = math.tan(math.radians(degrees))
    z = 100 + s * (math.cos(0.5) * x + math.sin(0.5) * y) + rng.normal(0, 0.05, n)
    return PointCloud(x + 500000.0, y + 5000000.0, z)


def test_cell_slope_factor_grows_beyond_smrf_cell():
    assert pf.cell_slope_factor(1.25, 1.0) == 1.25
    assert pf.cell_slope_factor(1.25, (0.5, 0.5)) == 1.25
    assert pf.cell_slope_factor(1.25, (4.0, 2.0)) == pytest.approx(1.25 + 3 / math.sqrt(12), abs=1e-12)
    assert pf.cell_slope_factor(0.0, 13.0) == pytest.approx(12 / math.sqrt(12), abs=1e-12)


def test_ground_on_a_slope_kept_on_coarse_cells():
    """20 degrees, 0.3 points/m2, every point ground, 5 m cells: each cell's lowest point lies
    anywhere inside it, so SMRF's 1 m factor rejects a tenth of the ground against the
    lowest-point surface itself; the factor grown with the cell keeps it. Through the filter,
    the same DTM classified with SMRF's factor alone loses the same ground."""
    c = _slope_cloud(0.3)
    assert pf.default_cell_size_m(c) == 1.0             # the default: 1 m, not 2 m
    g = pf.rasterize_cloud(c, 5.0)
    smrf = pf.classify_cloud(c, g.z_metres(), g.geotransform)
    grown = pf.classify_cloud(c, g.z_metres(), g.geotransform, lowest_cell_m=g.cell_size_m)
    assert np.mean(smrf == 0) < 0.92 and np.mean(grown == 0) > 0.99
    r = pf.filter_cloud(c, "morphological", cell_size_m=5.0)
    before = pf.classify_cloud(c, r.result.dtm, r.grid.geotransform)
    assert np.mean(before == 0) < 0.92 and np.mean(r.classes == 0) > 0.975
    # on SMRF's own 1 m cells the rule is SMRF's
    g1 = pf.rasterize_cloud(c, 1.0)
    np.testing.assert_array_equal(pf.classify_cloud(c, g1.z_metres(), g1.geotransform),
                                  pf.classify_cloud(c, g1.z_metres(), g1.geotransform, lowest_cell_m=(1.0, 1.0)))


def test_web_mercator_points_are_measured_in_ground_metres():
    """Points in EPSG:3857 (USGS 3DEP's point tiles) at latitude 52: a unit is 0.62 m on the
    ground; it was taken as 1 m, so a 1 m cell covered 0.62 m and the filters' slopes read 1.6 x
    too gentle. UTM points keep their unit."""
    lat = 52.0
    y = 6378137.0 * math.log(math.tan(math.pi / 4 + math.radians(lat) / 2))
    merc = PointCloud(np.array([1e6, 1e6 + 100.0]), np.array([y, y + 100.0]), np.array([0.0, 1.0]),
                      crs="EPSG:3857")
    sx, sy, sz = pf.axis_scales(merc)
    assert sx == sy == pytest.approx(math.cos(math.radians(lat)), rel=5e-3) and sz == 1.0
    g = pf.rasterize_cloud(merc, 1.0)
    assert g.geotransform[1] == pytest.approx(1.0 / math.cos(math.radians(lat)), rel=5e-3)
    utm = PointCloud(np.array([500000.0, 500100.0]), np.array([5.4e6, 5.4e6 + 100]), np.array([0.0, 1.0]),
                     crs="EPSG:32632")
    assert pf.axis_scales(utm) == (1.0, 1.0, 1.0)


def test_rasterize_cloud_in_feet_uses_metres(cloud):
    ft = PointCloud(cloud.x / FEET, cloud.y / FEET, cloud.z / FEET, units_to_metre=FEET)
    g = pf.rasterize_cloud(ft, 1.0)
    assert g.geotransform[1] == pytest.approx(1 / FEET)
    assert g.cell_size_m == pytest.approx((1.0, 1.0))
    assert g.z_to_m == FEET
    gm = pf.rasterize_cloud(cloud, 1.0)
    # same points, same lattice in metres up to the origin snap: the metric heights agree
    assert abs(g.shape[0] - gm.shape[0]) <= 1 and abs(g.shape[1] - gm.shape[1]) <= 1
    assert np.nanmedian(g.z_metres()) == pytest.approx(np.nanmedian(gm.z), abs=0.05)
    with pytest.raises(ValueError, match="3 x 3"):
        pf.rasterize_cloud(cloud, 1000.0)
    with pytest.raises(ValueError, match="positive"):
        pf.rasterize_cloud(cloud, -1.0)
    with pytest.raises(ValueError, match="reducer"):
        pf.rasterize_cloud(cloud, 1.0, reducer="median")


@pytest.mark.parametrize("units", ["feet", "geographic"])
def test_classify_cloud_units_equal_metres(units):
    # a 20 % slope plane, points 0.3 m above it (ground with the 0.5 m tolerance) and 0.8 m
    # above (ground only thanks to the slope term 1.25 * 0.2 = 0.25 m -> 0.75 m: above)
    rng = np.random.default_rng(0)
    n = 2000
    xm, ym = rng.uniform(1, 99, n), rng.uniform(1, 99, n)
    dz = np.where(np.arange(n) % 2 == 0, 0.3, 0.8)
    zm = 0.2 * xm + dz
    gtm = (0.0, 1.0, 0.0, 100.0, 0.0, -1.0)
    cols = np.arange(100) + 0.5
    dtm = np.tile(0.2 * cols, (100, 1)).astype(np.float32)
    ref = classify_points(xm, ym, zm, dtm, gtm)
    np.testing.assert_array_equal(ref, np.where(dz < 0.5, 0, 1))
    if units == "feet":
        c = PointCloud(xm / FEET, ym / FEET, zm / FEET, units_to_metre=FEET)
        gt = (0.0, 1 / FEET, 0.0, 100 / FEET, 0.0, -1 / FEET)
    else:
        c = PointCloud(xm, ym, zm, crs="EPSG:4326")
        lat = 45.0
        c.y = lat + (ym - 50) / 111132.0
        sx, sy, _ = pf.axis_scales(c)
        c.x = 7.0 + xm / sx
        c.y = lat + (ym - 50) / sy
        gt = (7.0, 1 / sx, 0.0, lat + 50 / sy, 0.0, -1 / sy)
    got = pf.classify_cloud(c, dtm, gt)
    np.testing.assert_array_equal(got, ref)


# --------------------------------------------------------------------------- one cloud
def test_filter_cloud_on_a_synthetic_city(cloud):
    r = pf.filter_cloud(cloud)
    truth_ground = cloud.classification == 0
    acc = ((r.classes == 0) == truth_ground).mean()
    assert acc > 0.98
    assert r.classes.dtype == np.uint8 and r.classes.size == len(cloud)
    assert r.info["cell_size_m"] == (1.0, 1.0)          # 1.5 points/m2 -> 1 m
    assert sum(r.info["classes"].values()) == len(cloud)
    assert r.result.mask.shape == r.grid.shape == r.result.dtm.shape
    # select: only some points classified, same classes
    sub = pf.filter_cloud(cloud, params=r.info["params"] and {k: r.info["params"][k] for k in
                          ("mode", "max_object_size_m", "dh_m", "slope")}, select=slice(0, 100))
    np.testing.assert_array_equal(sub.classes, r.classes[:100])


def test_write_rasters(tmp_path, cloud):
    from bare_earth.core import grid
    r = pf.filter_cloud(cloud)
    outs = {k: str(tmp_path / f"{k}.tif") for k in ("dtm", "mask", "ndsm", "dsm")}
    pf.write_rasters(r.grid, r.result, outs)
    d = grid.open_dsm(outs["dtm"])
    assert d.shape == r.grid.shape and d.geotransform == pytest.approx(r.grid.geotransform)
    np.testing.assert_allclose(d.read(), r.result.dtm, atol=1e-5)
    mi = grid.open_dsm(outs["mask"])
    np.testing.assert_array_equal(mi.dataset().GetRasterBand(1).ReadAsArray(), r.result.mask)
    assert (tmp_path / "mask.qml").exists()
    with pytest.raises(ValueError, match="unknown raster output"):
        pf.write_rasters(r.grid, r.result, {"nonsense": str(tmp_path / "x.tif")})


def test_write_rasters_feet_back_in_feet(tmp_path, cloud):
    from osgeo import osr

    from bare_earth.core import grid
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(2264)                       # NAD83 / North Carolina (ftUS)
    f = srs.GetLinearUnits()
    ft = PointCloud(cloud.x / f - 1e6, cloud.y / f - 1.7e7, cloud.z / f, crs=srs.ExportToWkt(),
                    units_to_metre=f)
    r = pf.filter_cloud(ft, cell_size_m=1.0)
    pf.write_rasters(r.grid, r.result, {"dtm": str(tmp_path / "dtm.tif"), "dsm": str(tmp_path / "dsm.tif")})
    d = grid.open_dsm(tmp_path / "dtm.tif")
    assert d.z_to_m == pytest.approx(f)
    np.testing.assert_allclose(d.read(), r.result.dtm, atol=1e-3)     # read back in metres
    np.testing.assert_allclose(grid.open_dsm(tmp_path / "dsm.tif").read(), r.grid.z_metres(), atol=1e-3)


def test_point_output_path():
    assert pf.point_output_path("/t/out.txt", "/in/a.las", temporary=True) == "/t/out.las"
    assert pf.point_output_path("/t/out.txt", "/in/a.las") == "/t/out.txt"
    assert pf.point_output_path("/t/out.laz", "/in/a.txt") == "/t/out.laz"
    assert pf.point_output_path("/t/out", "/in/a.csv") == "/t/out.csv"
    with pytest.raises(ValueError, match="LAS/LAZ file or a text file"):
        pf.point_output_path("/t/out.shp", "/in/a.txt")


# --------------------------------------------------------------------------- tiles
def _cut(cloud, nx, ny):
    xs = np.quantile(cloud.x, np.linspace(0, 1, nx + 1))
    ys = np.quantile(cloud.y, np.linspace(0, 1, ny + 1))
    ix = np.clip(np.searchsorted(xs, cloud.x, side="right") - 1, 0, nx - 1)
    iy = np.clip(np.searchsorted(ys, cloud.y, side="right") - 1, 0, ny - 1)
    return [np.flatnonzero((ix == i) & (iy == j)) for j in range(ny) for i in range(nx)]


def test_tiles_agree_with_the_untiled_run_at_their_seams(tmp_path):
    """A cloud cut into 3 x 2 tile files, filtered as one block, equals the untiled run."""
    c = scene_cloud((160, 210), seed=9)
    parts = _cut(c, 3, 2)
    paths, outs = [], []
    for k, idx in enumerate(parts):
        t = PointCloud(c.x[idx], c.y[idx], c.z[idx], classification=c.classification[idx],
                       attrs={"header": None, "delimiter": " "})
        paths.append(tmp_path / f"tile{k}.txt")
        outs.append(tmp_path / f"tile{k}_cls.txt")
        write_points(paths[-1], t, t.classification)
    logs = []
    res = pf.filter_tiles(paths, outs, log=logs.append)
    assert len(logs) >= 7 and "neighbours" in logs[-1]
    fixed = {k: res.params[k] for k in ("mode", "max_object_size_m", "dh_m", "slope", "slope_scale_m",
                                         "window_growth", "low_outlier_slope")}
    order = np.concatenate(parts)
    # the untiled run of the same points (read back from the tiles: 3 decimals) with the same parameters
    back = [read_points(p) for p in paths]
    whole = PointCloud(np.concatenate([b.x for b in back]), np.concatenate([b.y for b in back]),
                       np.concatenate([b.z for b in back]))
    ref = pf.filter_cloud(whole, params=fixed, cell_size_units=res.cell_size_units)
    tiled = np.concatenate(res.classes)
    # points near the seams (within 25 m of an inner tile edge) and everywhere: identical classes
    xs = sorted({round(u[0], 6) for u in (b.extent for b in back)})[1:]
    near = np.zeros(len(whole), bool)
    for b_ext in (b.extent for b in back):
        for v in (b_ext[0], b_ext[2]):
            if whole.x.min() + 1 < v < whole.x.max() - 1:
                near |= np.abs(whole.x - v) < 25
        for v in (b_ext[1], b_ext[3]):
            if whole.y.min() + 1 < v < whole.y.max() - 1:
                near |= np.abs(whole.y - v) < 25
    assert near.sum() > len(whole) / 3 and xs
    np.testing.assert_array_equal(tiled[near], ref.classes[near])
    np.testing.assert_array_equal(tiled, ref.classes)
    # written tiles hold the same classes, in tile order
    for k, o in enumerate(outs):
        np.testing.assert_array_equal(read_points(o).classification, res.classes[k])
    # and the classes are good ones
    truth = c.classification[order] == 0
    assert ((tiled == 0) == truth).mean() > 0.98
    # one tile alone with the others as neighbours gives the same classes
    one = pf.filter_tiles(paths, only=[4], keep_results=True)
    assert one.classes[0] is None and one.results[4] is not None
    np.testing.assert_array_equal(one.classes[4], res.classes[4])


def test_tiles_bad_input(tmp_path, cloud):
    a = PointCloud(cloud.x[:5000], cloud.y[:5000], cloud.z[:5000])
    b = PointCloud(cloud.x[5000:], cloud.y[5000:], cloud.z[5000:], units_to_metre=FEET)
    with pytest.raises(ValueError, match="not in the CRS / units"):
        pf.filter_tiles([a, b])
    with pytest.raises(ValueError, match="no tile"):
        pf.filter_tiles([])
    with pytest.raises(ValueError, match="one per tile"):
        pf.filter_tiles([a], outputs=[None, None])
    b = PointCloud(cloud.x[5000:], cloud.y[5000:], cloud.z[5000:])
    with pytest.raises(ValueError, match="less than the filter's reach"):
        pf.filter_tiles([a, b], overlap_m=2.0)


# --------------------------------------------------------------------------- evaluation
def test_compare_classified_exact_and_matching():
    x = np.arange(6, dtype=float)
    truth = PointCloud(x, x, x, classification=np.array([0, 0, 0, 1, 1, 1]))
    pred = PointCloud(x, x, x, classification=np.array([0, 1, 255, 0, 1, 2]))
    r = pf.compare_classified(pred, truth)
    # valid: 5 points; a=1 (0->0), b=1 (ground->object), c=1 (object->ground), d=2
    assert (r["a"], r["b"], r["c"], r["d"]) == (1, 1, 1, 2)
    assert r["points_not_classified"] == 1 and r["points_unmatched"] == 0
    # the truth in another order: matched by position
    perm = np.array([5, 3, 1, 0, 2, 4])
    shuffled = PointCloud(x[perm], x[perm], x[perm], classification=truth.classification[perm])
    r2 = pf.compare_classified(pred, shuffled)
    assert (r2["a"], r2["b"], r2["c"], r2["d"]) == (1, 1, 1, 2)
    # truth column; LAS-style predictions (2 = ground)
    r3 = pf.compare_classified(pred, truth_column=np.array([0, 0, 0, 1, 1, 1]))
    assert r3["n"] == 5
    las_pred = PointCloud(x, x, x, classification=np.array([2, 1, 2, 2, 1, 7]), source_format="las")
    r4 = pf.compare_classified(las_pred, truth_column=np.array([2, 2, 1, 1, 1, 2]))
    assert (r4["a"], r4["b"], r4["c"], r4["d"]) == (1, 2, 2, 1)
    with pytest.raises(ValueError, match="not the same points"):
        pf.compare_classified(pred, PointCloud(x + 100, x, x, classification=truth.classification))
    with pytest.raises(ValueError, match="one of them"):
        pf.compare_classified(pred)
    with pytest.raises(ValueError, match="no class column"):
        pf.compare_classified(PointCloud(x, x, x), truth)


def test_read_column(tmp_path):
    p = tmp_path / "p.csv"
    p.write_text("x,y,z,class,truth\n1,2,3,0,1\n4,5,6,1,1\n7,8,9,0,0\n")
    np.testing.assert_array_equal(pf.read_column(p, "truth"), [1, 1, 0])
    np.testing.assert_array_equal(pf.read_column(p, "CLASS"), [0, 1, 0])
    with pytest.raises(ValueError, match="no column 'label'"):
        pf.read_column(p, "label")
    q = tmp_path / "q.txt"
    q.write_text("1 2 3 0\n")
    with pytest.raises(ValueError, match="no header line"):
        pf.read_column(q, "truth")


def test_real_isprs_sample_through_the_flow(shared_data):
    path = shared_data / "isprs" / "samp11.txt"
    if not path.exists():
        pytest.skip(f"{path} is absent")
    c = read_points(path)
    r = pf.filter_cloud(c)
    e = pf.compare_classified(PointCloud(c.x, c.y, c.z, classification=r.classes.astype(np.int32)), c)
    assert e["n"] == len(c) and e["total"] < 20.0


def test_chunked_classify_equals_classify_points(monkeypatch):
    """classify_cloud works in chunks of points (speed): the same codes as classify_points,
    DTM holes and the slope term included."""
    monkeypatch.setattr(pf, "CLASSIFY_CHUNK", 1000)
    rng = np.random.default_rng(3)
    n = 20_000
    x, y = rng.uniform(0, 200, n), rng.uniform(0, 150, n)
    z = 0.3 * x + 3 * np.sin(y / 10) + rng.normal(0, 0.4, n)
    z[rng.random(n) < 0.2] += 4
    c = PointCloud(x, y, z)
    g = pf.rasterize_cloud(c, 2.0)
    dtm = g.z.copy()
    dtm[10:20, 30:45] = np.nan
    got = pf.classify_cloud(c, dtm, g.geotransform, threshold_m=0.3, slope_factor=2.0)
    ref = classify_points(x, y, z, dtm, g.geotransform, threshold_m=0.3, slope_factor=2.0)
    np.testing.assert_array_equal(got, ref)
    assert set(np.unique(got)) == {0, 1, 2, 255}
    far = PointCloud(x + 1e4, y, z)
    with pytest.raises(ValueError, match="outside the DTM"):
        pf.classify_cloud(far, dtm, g.geotransform)


def test_tile_lattice_windows_pure():
    """The tiles' window planning: whole cells of the block's lattice, clipped to its bounds."""
    lat = pf.TileLattice.around((0.3, 0.2, 9.7, 5.9), 1.0, 1.0)          # snapped to (0, 0, 10, 6)
    assert (lat.x0, lat.y0, lat.x1, lat.y1, lat.rows, lat.cols) == (0.0, 0.0, 10.0, 6.0, 6, 10)
    assert lat.cells_of((2.5, 1.0, 4.0, 3.2)) == (2, 5, 2, 4)            # rows from the north edge
    assert lat.cells_of((2.5, 1.0, 4.0, 3.2), 2, 3) == (0, 6, 0, 7)      # grown, clipped
    assert lat.extent_of((2, 5, 2, 4)) == (2.0, 1.0, 4.0, 4.0)
    lat.margin = 1
    assert lat.trusted((0, 4, 2, 10)) == (0, 3, 3, 10)                    # block edges stay trusted
    assert lat.grow((1, 4, 2, 8), (2, 0, 0, 5)) == (0, 4, 2, 10)


def test_write_rasters_compound_crs_heights_in_its_vertical_unit(tmp_path, cloud):
    """Points in UTM metres with NAVD88 heights in US survey feet (EPSG:26917+6360): the DSM and
    DTM written carry that CRS and heights in feet, so they read back (open_dsm takes the
    vertical unit of a compound CRS) as the metres the filter saw. They were written in metres."""
    from osgeo import osr

    from bare_earth.core import grid
    srs = osr.SpatialReference()
    srs.SetFromUserInput("EPSG:26917+6360")
    ft = 1200.0 / 3937.0
    c = PointCloud(cloud.x - 5e4, cloud.y - 1.4e6, cloud.z / ft, crs=srs.ExportToWkt(), units_to_metre=1.0,
                   z_units_to_metre=ft)
    r = pf.filter_cloud(c, cell_size_m=1.0)
    pf.write_rasters(r.grid, r.result, {"dtm": str(tmp_path / "dtm.tif"), "dsm": str(tmp_path / "dsm.tif")})
    d = grid.open_dsm(tmp_path / "dtm.tif")
    assert d.z_to_m == pytest.approx(ft) and d.cell_size_m == pytest.approx((1.0, 1.0))
    np.testing.assert_allclose(d.read(), r.result.dtm, atol=1e-3)
    np.testing.assert_allclose(grid.open_dsm(tmp_path / "dsm.tif").read(), r.grid.z_metres(), atol=1e-3)
    np.testing.assert_allclose(np.nanmax(gdal_read(tmp_path / "dsm.tif")), np.nanmax(c.z), rtol=1e-5)


def gdal_read(path):
    from osgeo import gdal
    ds = gdal.Open(str(path))      # kept while its band is read
    return ds.GetRasterBand(1).ReadAsArray()


@pytest.mark.parametrize("crs, x0, y0, said", [
    (None, 0.0, 0.0, "The points have no CRS"),
    ("EPSG:4326", 7.0, 52.0, "geographic (degrees): distances were converted to metres at latitude 52.0"),
    ("EPSG:3857", 0.0, 6800000.0, "one of its units is 0.6"),
    ("EPSG:32632", 500000.0, 5400000.0, None),
])
def test_crs_warnings_name_how_the_points_were_measured(crs, x0, y0, said):
    """The log's warnings on a cloud's CRS, as a raster's reading gives them: none, degrees, a
    CRS that does not keep distances (Web Mercator at 52 deg N: a unit is cos(52 deg) m); UTM: none."""
    x = x0 + np.array([0.0, 0.001, 0.002]) * (1 if crs == "EPSG:4326" else 1000)
    cloud = PointCloud(x=x, y=y0 + x * 0, z=np.zeros(3), crs=crs)
    w = pf.crs_warnings(cloud)
    assert (w == []) if said is None else (len(w) == 1 and said in w[0]), w


def test_cells_under_a_millimetre_refused_naming_the_crs():
    """Points in degrees without a CRS (read as metres) gave cells of 1e-05 m: the filters' windows
    (metres) spanned millions of cells (morphological asked for 149 GB, others ran for hours)."""
    rng = np.random.default_rng(1)
    x, y, z = 10.0 + rng.uniform(0, 0.0009, 4000), 50.0 + rng.uniform(0, 0.0008, 4000), rng.uniform(0, 0.2, 4000)
    with pytest.raises(ValueError, match=r"cells of 1e-05 m.*under 1 mm.*probably in degrees.*CRS"):
        pf.filter_cloud(PointCloud(x, y, z), "morphological")
    geo = PointCloud(x, y, z, crs="EPSG:4326")               # the same points with their CRS: ~1 m cells
    assert pf.rasterize_cloud(geo).cell_size_m[0] > 0.5
    with pytest.raises(ValueError, match=r"cells of 0\.0005 m.*under 1 mm.*larger cell size"):
        pf.rasterize_cloud(geo, 0.0005)


def test_a_grid_mostly_copies_or_beyond_the_memory_is_refused_before_work():
    """3 points over 1 km at 0.05 m made 20000 x 20000 = 400 M cells, 6 GB of nearest-cell copies,
    without a word. A grid beyond a window of the filters (25 M cells) with fewer than one point per
    16 cells, or needing more memory than is available, is refused naming the cells, the memory and
    the cells to use; small sparse grids and dense ones pass."""
    with pytest.raises(ValueError, match=r"CELL_SIZE_M = 0.05 m gives 20000 x 20000 = 4e\+08 cells over the "
                                         r"points' 1000 x 1000 m for 3 point\(s\), one per 1.33e\+08 cells: .*"
                                         r"about 6.33 GB \(8 GB available\)\. Instead use cells of at least 200 m"):
        pf.check_grid_cells(3, 1000.0, 1000.0, 0.05, available=8 << 30)
    with pytest.raises(ValueError, match=r"copy of its nearest point's\. Instead use cells of at least 200 m"):
        pf.check_grid_cells(3, 1000.0, 1000.0, 0.05, whole=False)             # a filter's tiles: no memory
    pf.check_grid_cells(3, 100.0, 100.0, 0.05, available=8 << 30)              # 4 M cells: small
    pf.check_grid_cells(10 ** 7, 1000.0, 1000.0, 0.25, available=8 << 30)      # 16 M cells, dense
    with pytest.raises(ValueError, match=r"about 0.396 GB \(0.25 GB available\)\. Instead use cells of at least "
                                         r"0.5 m, or split the points into tiles"):
        pf.check_grid_cells(10 ** 8, 1000.0, 1000.0, 0.2, available=1 << 28)   # 25 M cells, 17 B each


def test_tiles_parameters_derived_with_progress_and_cancel(cloud, monkeypatch):
    """The block's parameters, derived on its central tile before any tile is filtered (seconds to
    minutes on a dense tile), fed no progress and ignored a cancel: the bar stood still and a cancel
    waited for the first tile. The bar now moves during the derivation, and a cancel raised there
    stops the run before any tile is filtered."""
    from bare_earth.core.common import Cancelled
    half = cloud.x < np.median(cloud.x)
    tiles = [PointCloud(cloud.x[k], cloud.y[k], cloud.z[k]) for k in (half, ~half)]
    filtered = []
    real = pf.filter_cloud
    monkeypatch.setattr(pf, "filter_cloud", lambda *a, **k: filtered.append(1) or real(*a, **k))
    seen = []
    pf.filter_tiles(tiles, method="morphological", progress=seen.append)
    before = [f for f in seen[:seen.index(pf.PARAMS_SHARE)]]
    assert len(set(before)) >= 3 and 0 < max(before) <= pf.PARAMS_SHARE     # moved while deriving
    assert seen == sorted(seen) and seen[-1] == 1.0
    assert len(filtered) == 2
    filtered.clear()

    def cancel_at(f):
        if 0 < f < pf.PARAMS_SHARE:
            raise Cancelled()
    with pytest.raises(Cancelled):
        pf.filter_tiles(tiles, method="morphological", progress=cancel_at)
    assert filtered == []


def test_height_warnings_count_points_without_a_finite_height():
    c = PointCloud(np.arange(5.0), np.arange(5.0), np.array([1.0, np.nan, np.inf, -np.inf, 2.0]))
    assert pf.height_warnings(c).startswith("3 of the 5 points have no finite height (z NaN or infinite): they are "
                                            "left out of the grid and classed 255")
    assert pf.height_warnings(c, classified=False).endswith("left out of the grid. Check the z column of those points.")
    assert pf.height_warnings(PointCloud(np.arange(3.0), np.arange(3.0), np.ones(3))) is None


_KILLED_DURING_RASTERS = r"""
import sys, time
sys.path.insert(0, sys.argv[1])
import numpy as np
from bare_earth.core import grid, pointflow as pf
from bare_earth.core.points import PointCloud
rng = np.random.default_rng(0)
x, y = rng.uniform(0, 60, 6000) + 500000.0, rng.uniform(0, 60, 6000) + 5400000.0
cloud = PointCloud(x, y, 100.0 + 0.01 * (x - 500000.0), crs="EPSG:32632")
r = pf.filter_cloud(cloud, "morphological")
def slow(self, *args, **kwargs):
    print("writing", flush=True)
    time.sleep(600)
grid.OutputSet.commit = slow
pf.write_cloud_outputs(sys.argv[2], cloud, r.classes, r.grid, r.result,
                       {"dtm": sys.argv[3], "mask": sys.argv[4]})
"""


def test_point_run_killed_while_its_rasters_are_written_leaves_no_points_file(tmp_path):
    """kill -9 while a point run's rasters were written left a complete-looking points file (it was
    put in place first); now only hidden work files are left, and the next write removes them."""
    import os
    import signal
    import subprocess
    import sys
    plugins = os.path.dirname(os.path.dirname(os.path.dirname(pf.__file__)))
    out, dtm, mask = tmp_path / "cls.txt", tmp_path / "dtm.tif", tmp_path / "mask.tif"
    p = subprocess.Popen([sys.executable, "-c", _KILLED_DURING_RASTERS, plugins, str(out), str(dtm), str(mask)],
                         stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "writing"
    finally:
        os.kill(p.pid, signal.SIGKILL)
        p.wait()
    left = sorted(q.name for q in tmp_path.iterdir())
    assert not [n for n in left if not n.startswith(".")]          # nothing that looks like a result
    assert any(n.startswith(".cls.txt.") and n.endswith(".part.txt") for n in left)
    c = scene_cloud(shape=(40, 40))
    r = pf.filter_cloud(c, "morphological")
    pf.write_cloud_outputs(out, c, r.classes, r.grid, r.result, {"dtm": str(dtm), "mask": str(mask)})
    names = {q.name for q in tmp_path.iterdir()}
    assert {"cls.txt", "dtm.tif", "mask.qml", "mask.tif"} <= names
    assert not [n for n in names if n.startswith(".")]              # the killed run's work files removed
    assert len(read_points(out)) == len(c)


def test_points_whose_coordinates_are_millimetres_read_as_metres_refused():
    """QA 17: cells that make no sense for the heights (pipeline.check_relief) reach the points path too: a
    city's points with their x and y in millimetres of metres (0.15 m across, buildings up to 56 m) are
    refused naming the points' CRS, before any point is classified."""
    c = scene_cloud(shape=(100, 100), density=1.0)
    x0, y0 = c.x.min(), c.y.min()
    mm = PointCloud(x0 + (c.x - x0) / 1000.0, y0 + (c.y - y0) / 1000.0, c.z)
    with pytest.raises(ValueError, match=r"heights span [\d.]+ times the diagonal.*POINTS_CRS"):
        pf.filter_cloud(mm, "morphological")
