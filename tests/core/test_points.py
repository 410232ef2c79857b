"""Tests of core/points.py: reading, rasterizing, sampling, classifying, writing points."""
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from bare_earth.core import pointfiles
from bare_earth.core.points import (
    PointCloud,
    classify_points,
    nice_cell_size,
    rasterize_points,
    read_points,
    sample_bilinear,
    write_points,
)

DTYPES = [np.float32, np.float64, np.int16]


@pytest.fixture(params=["loadtxt", "fromstring"])
def parser(request, monkeypatch):
    """Run a text test through both parsers (numpy >= 1.23 C loadtxt, and the fallback)."""
    if request.param == "fromstring":
        monkeypatch.setattr(pointfiles, "_FAST_LOADTXT", False)
    elif not pointfiles._FAST_LOADTXT:
        pytest.skip("numpy < 1.23 has no C loadtxt")
    return request.param


# --------------------------------------------------------------------------- text reading
def _write(tmp_path, text, name="pts.txt"):
    p = tmp_path / name
    p.write_bytes(text.encode("utf-8"))
    return p


@pytest.mark.parametrize("text", [
    "1\t2\t3\t0\n4\t5\t6\t1\n",
    "1,2,3,0\n4,5,6,1\n",
    "x y z class\n1 2 3 0\n\n   \n4   5 6 1",          # header, blank lines, no final newline
    "X, Y, Z, Classification\r\n1, 2, 3, 0\r\n4, 5, 6, 1\r\n",
    "\ufeffx\ty\tz\tc\n1\t2\t3\t0\n4\t5\t6\t1\n",        # byte-order mark
    '"X","Y","Z","Classification"\n1,2,3,0\n4,5,6,1\n',  # PDAL writers.text: a quoted header
    '"x","y","z","class"\n"1","2","3","0"\n"4","5","6","1"\n',   # every field quoted (refused before)
])
def test_read_text_variants(tmp_path, text, parser):
    c = read_points(_write(tmp_path, text))
    assert c.source_format == "text"
    np.testing.assert_array_equal(c.x, [1, 4])
    np.testing.assert_array_equal(c.y, [2, 5])
    np.testing.assert_array_equal(c.z, [3, 6])
    np.testing.assert_array_equal(c.classification, [0, 1])
    assert c.x.dtype == np.float64 and c.crs is None and c.units_to_metre == 1.0
    np.testing.assert_array_equal(c.ground_truth(), [True, False])


def test_read_text_xyz_only_and_header_column_order(tmp_path, parser):
    c = read_points(_write(tmp_path, "10.5 20.25 -3e2\n11 21 7\n"))
    assert c.classification is None and len(c) == 2
    np.testing.assert_array_equal(c.z, [-300.0, 7.0])
    c = read_points(_write(tmp_path, "intensity,z,classification,y,x\n9,3,2,2,1\n", "b.csv"))
    assert (c.x[0], c.y[0], c.z[0], c.classification[0]) == (1, 2, 3, 2)


@pytest.mark.parametrize("text, line", [
    ("x y z\n1 2 3\n\n4 5 abc\n7 8 9\n", 4),
    ("1 2 3\n4 5 6\n7,8,9x\n", 3),
    ("1 2 3\n4 5 6.1.2\n", 2),
    ("1 2 3 0\n4 5 6\n", 2),          # wrong column count
    ("1 2 3 0\n4 5 6 0.5\n", 2),      # class not a whole number
    ("1 2 3\nnan 5 6\n", 2),          # non-finite x
    ("1 2 3\n4 5 6\n7 8 9-", 3),       # bad last value, no final newline
    ("1 2 3\n\n4 5 1_0\n", 3),
    ("1 2 3\n#4 5 6\n", 2),
])
def test_read_text_bad_line_number(tmp_path, text, line, parser):
    with pytest.raises(ValueError, match=rf"line {line}\b"):
        read_points(_write(tmp_path, text))


def test_read_text_empty_and_missing(tmp_path, parser):
    with pytest.raises(ValueError, match="empty"):
        read_points(_write(tmp_path, "\n  \n"))
    with pytest.raises(ValueError, match="empty"):
        read_points(_write(tmp_path, ",,\t;\r\n"))
    with pytest.raises(ValueError, match="no points"):
        read_points(_write(tmp_path, "x y z\n"))
    with pytest.raises(ValueError, match="does not exist"):
        read_points(tmp_path / "nope.txt")
    with pytest.raises(ValueError, match="expected 3"):
        read_points(_write(tmp_path, "1 2 3 4 5\n"))


def test_read_text_crs_argument_and_prj(tmp_path):
    p = _write(tmp_path, "1 2 3\n")
    c = read_points(p, crs="EPSG:2263")            # NY Long Island, US feet
    assert "2263" in c.crs and c.units_to_metre == pytest.approx(0.3048006096)
    (tmp_path / "pts.prj").write_text(read_points(p, crs="EPSG:25832").crs)
    c = read_points(p)
    assert "25832" in c.crs and c.units_to_metre == 1.0
    with pytest.raises(ValueError, match="CRS"):
        read_points(p, crs="not a crs at all")


# --------------------------------------------------------------------------- rasterize
XS = np.array([0.2, 0.7, 1.5, 0.5])
YS = np.array([0.3, 0.9, 0.5, 1.5])
ZS = np.array([5.0, 3.0, 7.0, 2.0])


@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("reducer, expected", [
    ("min", [[2, np.nan], [3, 7]]),
    ("max", [[2, np.nan], [5, 7]]),
    ("mean", [[2, np.nan], [4, 7]]),
])
def test_rasterize_exact(dtype, reducer, expected):
    info = {}
    grid, gt = rasterize_points(XS, YS, ZS.astype(dtype), 1.0, reducer=reducer,
                                fill_empty=None, info=info)
    assert grid.dtype == np.float32
    np.testing.assert_array_equal(grid, np.array(expected, dtype=np.float32))
    assert gt == (0.0, 1.0, 0.0, 2.0, 0.0, -1.0)
    assert info["n_empty"] == 1 and info["shape"] == (2, 2) and info["n_points"] == 4


def test_rasterize_fill_nearest_and_edges():
    grid, gt = rasterize_points([0.5, 3.5], [0.5, 0.5], [1.0, 4.0], 1.0)
    np.testing.assert_array_equal(grid, [[1, 1, 4, 4]])
    assert gt == (0.0, 1.0, 0.0, 1.0, 0.0, -1.0)
    # a point on the east/south edge of the bounding box goes into the last cell
    grid, gt = rasterize_points([10.0, 12.0], [20.0, 22.0], [1.0, 2.0], 1.0, fill_empty=None)
    assert grid.shape == (2, 2) and gt[0] == 10.0 and gt[3] == 22.0
    assert grid[0, 1] == 2.0 and grid[1, 0] == 1.0


def test_rasterize_rectangular_cells_extent_and_origin_snap():
    grid, gt = rasterize_points([1.3, 4.9], [7.1, 2.2], [1, 2], (2.0, 0.5), fill_empty=None)
    assert gt == (0.0, 2.0, 0.0, 7.5, 0.0, -0.5)   # floor(1.3/2)*2, ceil(7.1/0.5)*0.5
    assert grid.shape == (11, 3)
    assert grid[0, 0] == 1 and grid[10, 2] == 2 and np.isnan(grid).sum() == 31
    # explicit extent: used exactly, points outside dropped
    grid, gt = rasterize_points([0.5, 1.5, 5.0], [0.5, 0.5, 0.5], [1, 2, 3], 1.0,
                                extent=(0, 0, 2, 1), fill_empty=None)
    assert gt == (0.0, 1.0, 0.0, 1.0, 0.0, -1.0)
    np.testing.assert_array_equal(grid, [[1, 2]])
    with pytest.raises(ValueError, match="inside the extent"):
        rasterize_points([5.0], [5.0], [1.0], 1.0, extent=(0, 0, 2, 1))


def test_rasterize_default_cell_size():
    g = np.arange(10) + 0.5
    x, y = np.meshgrid(g, g)
    info = {}
    grid, gt = rasterize_points(x.ravel(), y.ravel(), np.ones(100), info=info)
    assert gt[1] == 1.0 and gt[5] == -1.0 and info["cell_size"] == (1.0, 1.0)
    # 0.17 points per m2 (ISPRS rural) -> sqrt(1 / 0.17) = 2.4 -> 2.5 m
    rng = np.random.default_rng(1)
    n = 1700
    _, gt = rasterize_points(rng.uniform(0, 100, n), rng.uniform(0, 100, n), np.zeros(n))
    assert gt[1] == 2.5
    sizes = (2.43, 1.1, 0.7, 0.34, 6.5, 7.2, 40)
    assert [nice_cell_size(v) for v in sizes] == [2.5, 1, 0.5, 0.25, 5, 10, 50]
    assert [nice_cell_size(v, at_least=True) for v in sizes] == [2.5, 2, 1, 0.5, 10, 10, 50]
    assert nice_cell_size(2.0, at_least=True) == 2.0 and nice_cell_size(0.59, at_least=True) == 1.0


def test_rasterize_bad_input():
    with pytest.raises(ValueError, match="reducer"):
        rasterize_points(XS, YS, ZS, 1.0, reducer="median")
    with pytest.raises(ValueError, match="same length"):
        rasterize_points(XS, YS, ZS[:2], 1.0)
    with pytest.raises(ValueError, match="no point"):
        rasterize_points([np.nan], [1.0], [1.0], 1.0)
    with pytest.raises(ValueError, match="cell_size"):
        rasterize_points(XS, YS, ZS, -1.0)


def test_rasterize_matches_loop_on_random_points():
    rng = np.random.default_rng(3)
    x, y, z = rng.uniform(0, 20, 2000), rng.uniform(0, 10, 2000), rng.normal(size=2000)
    lo, gt = rasterize_points(x, y, z, 2.0, fill_empty=None)
    hi, _ = rasterize_points(x, y, z, 2.0, reducer="max", fill_empty=None)
    col = np.floor((x - gt[0]) / 2).astype(int)
    row = np.floor((gt[3] - y) / 2).astype(int)
    for r, c in [(0, 0), (2, 5), (4, 9)]:
        sel = (row == r) & (col == c)
        assert lo[r, c] == np.float32(z[sel].min()) and hi[r, c] == np.float32(z[sel].max())


# --------------------------------------------------------------------------- sampling
GT = (100.0, 2.0, 0.0, 50.0, 0.0, -2.0)


def _plane_grid(rows=6, cols=8):
    cx = GT[0] + (np.arange(cols) + 0.5) * GT[1]
    cy = GT[3] + (np.arange(rows) + 0.5) * GT[5]
    xx, yy = np.meshgrid(cx, cy)
    return 2.0 * xx + 3.0 * yy + 1.0


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_bilinear_exact_on_plane(dtype):
    grid = _plane_grid().astype(dtype)
    rng = np.random.default_rng(0)
    x = rng.uniform(101.0, 115.0, 50)   # between the outer cell centres
    y = rng.uniform(39.0, 49.0, 50)
    v = sample_bilinear(grid, GT, x, y)
    tol = 1e-9 if dtype == np.float64 else 1e-3
    np.testing.assert_allclose(v, 2 * x + 3 * y + 1, rtol=0, atol=tol * 500)
    # at a cell centre: the cell value
    assert sample_bilinear(grid, GT, 101.0, 49.0) == pytest.approx(float(grid[0, 0]))


def test_bilinear_outside_and_nan():
    grid = _plane_grid()
    out = sample_bilinear(grid, GT, [99.9, 116.1, 105.0, 100.5, 116.0], [45, 45, 50.1, 49.5, 38.0])
    assert np.isnan(out[:3]).all()
    # inside, within half a cell of the edge: the edge values (clamped)
    assert out[3] == pytest.approx(grid[0, 0]) and out[4] == pytest.approx(grid[-1, -1])
    grid[2, 3] = np.nan
    centre_x, centre_y = GT[0] + 3.5 * 2, GT[3] - 2.5 * 2     # centre of the NaN cell
    assert np.isnan(sample_bilinear(grid, GT, centre_x + 0.5, centre_y))
    # the centre of the next cell does not need the NaN cell
    assert np.isfinite(sample_bilinear(grid, GT, centre_x + 2.0, centre_y))
    with pytest.raises(ValueError, match="rotated"):
        sample_bilinear(grid, (0, 1, 0.1, 0, 0, -1), [0], [0])


# --------------------------------------------------------------------------- classify
def test_classify_with_slope_term():
    gt = (0.0, 1.0, 0.0, 10.0, 0.0, -1.0)
    cx = np.arange(10) + 0.5
    dtm = np.tile(0.5 * cx, (10, 1)).astype(np.float32)     # slope 0.5 rise/run
    x = np.array([5.0, 5.0, 5.0, 5.0, 5.0, 50.0])
    y = np.full(6, 5.0)
    ground = 2.5
    z = ground + np.array([0.0, 1.0, 1.2, -1.0, -1.2, 0.0])
    # tolerance 0.5 + 1.25 * 0.5 = 1.125
    cls = classify_points(x, y, z, dtm, gt)
    np.testing.assert_array_equal(cls, [0, 0, 1, 0, 2, 255])
    assert cls.dtype == np.uint8
    cls = classify_points(x, y, z, dtm, gt, slope_factor=0.0)
    np.testing.assert_array_equal(cls, [0, 1, 1, 2, 2, 255])
    dtm[5, 5] = np.nan
    assert classify_points(x[:1], y[:1], z[:1], dtm, gt)[0] == 255


def test_classify_most_points_outside():
    dtm = np.zeros((10, 10), np.float32)
    gt = (0.0, 1.0, 0.0, 10.0, 0.0, -1.0)
    with pytest.raises(ValueError, match=r"outside the DTM.*x 5\.000\.\.1001\.000.*"
                                         r"DTM spans x 0\.000\.\.10\.000"):
        classify_points([1000, 1001, 5], [5, 5, 5], [0, 0, 0], dtm, gt)
    with pytest.raises(ValueError, match="threshold_m"):
        classify_points([5], [5], [0], dtm, gt, threshold_m=-1)


def test_rasterize_and_classify_a_larger_cloud():
    # a sloping plane with noise, 20 % of the points lifted by 5 m (objects)
    rng = np.random.default_rng(0)
    n = 100_000
    x, y = rng.uniform(0, 300, n), rng.uniform(0, 400, n)
    z = 0.05 * x + rng.normal(0, 0.05, n)
    lifted = rng.random(n) < 0.2
    z[lifted] += 5.0
    dtm, gt = rasterize_points(x, y, z, 4.0)          # ~ 13 points per 4 m cell
    cls = classify_points(x, y, z, dtm, gt)
    assert (cls[lifted] == 1).mean() > 0.99
    assert (cls[~lifted] == 0).mean() > 0.98


# --------------------------------------------------------------------------- writing
def test_text_round_trip(tmp_path):
    src = _write(tmp_path, "x,y,z,class\n1.25,2.5,3.125,1\n4,5,6,0\n", "in.csv")
    c = read_points(src)
    out = tmp_path / "out.csv"
    write_points(out, c, np.array([0, 2], np.uint8))
    assert out.read_text().splitlines() == ["x,y,z,class", "1.250,2.500,3.125,0",
                                            "4.000,5.000,6.000,2"]
    back = read_points(out)
    np.testing.assert_array_equal(back.classification, [0, 2])
    with pytest.raises(ValueError, match="one class per point"):
        write_points(out, c, [0])


def _make_las(path, n=500, point_format=3, crs_wkt=None):
    laspy = pytest.importorskip("laspy")
    header = laspy.LasHeader(point_format=point_format, version="1.2")
    header.scales = np.array([0.01, 0.01, 0.01])
    header.offsets = np.array([500000.0, 5400000.0, 0.0])
    if crs_wkt:
        header.vlrs.append(laspy.vlrs.known.WktCoordinateSystemVlr(crs_wkt))
    las = laspy.LasData(header)
    rng = np.random.default_rng(5)
    las.x = 500000 + rng.uniform(0, 50, n)
    las.y = 5400000 + rng.uniform(0, 50, n)
    las.z = 100 + rng.uniform(0, 1, n)
    las.intensity = rng.integers(0, 65535, n).astype(np.uint16)
    las.gps_time = rng.uniform(0, 1e5, n)
    las.return_number = np.ones(n, np.uint8)
    las.number_of_returns = np.ones(n, np.uint8)
    las.point_source_id = np.full(n, 7, np.uint16)
    las.classification = np.full(n, 5, np.uint8)
    las.red = rng.integers(0, 65535, n).astype(np.uint16)
    las.write(str(path))
    return laspy.read(str(path))


@pytest.mark.parametrize("ext", [".las", ".laz"])
def test_las_round_trip_keeps_attributes(tmp_path, ext):
    laspy = pytest.importorskip("laspy")
    if ext == ".laz":
        pytest.importorskip("lazrs")
    from osgeo import osr
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(32632)
    src = tmp_path / f"in{ext}"
    orig = _make_las(src, crs_wkt=srs.ExportToWkt())
    c = read_points(src)
    assert c.source_format == "las" and len(c) == 500
    assert "UTM zone 32N" in c.crs and c.units_to_metre == 1.0
    np.testing.assert_allclose(c.x, np.asarray(orig.x))
    np.testing.assert_array_equal(c.classification, 5)
    classes = np.zeros(500, np.uint8)
    classes[:100], classes[100:150], classes[150:160] = 1, 2, 255
    out = tmp_path / f"out{ext}"
    write_points(out, c, classes)
    back = laspy.read(str(out))
    np.testing.assert_array_equal(np.asarray(back.classification)[:100], 1)
    np.testing.assert_array_equal(np.asarray(back.classification)[100:150], 7)
    np.testing.assert_array_equal(np.asarray(back.classification)[150:160], 5)   # kept
    np.testing.assert_array_equal(np.asarray(back.classification)[160:], 2)
    for dim in ("X", "Y", "Z", "intensity", "gps_time", "point_source_id", "red",
                "return_number", "number_of_returns"):
        np.testing.assert_array_equal(np.asarray(back[dim]), np.asarray(orig[dim]), err_msg=dim)
    assert back.header.point_format.id == 3
    assert "UTM zone 32N" in read_points(out).crs
    # the input cloud was not modified
    np.testing.assert_array_equal(np.asarray(c.attrs.classification), 5)


def test_text_cloud_written_as_las(tmp_path):
    laspy = pytest.importorskip("laspy")
    c = read_points(_write(tmp_path, "1.5 2.25 3.125 0\n4 5 6 1\n"), crs="EPSG:25832")
    write_points(tmp_path / "o.las", c, [0, 1])
    back = read_points(tmp_path / "o.las")
    np.testing.assert_allclose(back.x, [1.5, 4]) and np.testing.assert_allclose(back.z, [3.125, 6])
    np.testing.assert_array_equal(back.classification, [2, 1])
    assert "25832" in back.crs
    assert laspy.read(str(tmp_path / "o.las")).header.point_format.id == 6


def test_corrupt_las(tmp_path):
    pytest.importorskip("laspy")
    for name, data in (("a.las", b"LASF" + b"\0" * 300), ("b.laz", b"hello")):
        (tmp_path / name).write_bytes(data)
        with pytest.raises(ValueError, match="not a readable LAS/LAZ file"):
            read_points(tmp_path / name)


def test_laspy_missing_message(tmp_path, monkeypatch):
    p = tmp_path / "a.las"
    p.write_bytes(b"LASF" + b"\0" * 300)
    monkeypatch.setitem(sys.modules, "laspy", None)
    with pytest.raises(ImportError, match="pip install laspy lazrs"):
        read_points(p)
    with pytest.raises(ImportError, match="pip install laspy lazrs"):
        write_points(tmp_path / "b.las", PointCloud(np.zeros(1), np.zeros(1), np.zeros(1)), [0])


# --------------------------------------------------------------------------- real data
def test_real_isprs_sample(shared_data):
    path = shared_data / "isprs" / "samp11.txt"
    if not path.exists():
        pytest.skip(f"{path} is absent")
    c = read_points(path)
    assert len(c) == 38010
    np.testing.assert_array_equal(np.bincount(c.classification), [21786, 16224])
    assert c.ground_truth().sum() == 21786
    assert 512000 < c.x.min() < c.x.max() < 513000 and 5403000 < c.y.min()
    grid, gt = rasterize_points(c.x, c.y, c.z, 1.0)
    cls = classify_points(c.x, c.y, c.z, grid, gt)
    assert (cls != 255).all()


def test_real_las_feet_units(shared_data):
    pytest.importorskip("laspy")
    path = shared_data / "lidar" / "mvk-thin.las"
    if not path.exists():
        pytest.skip(f"{path} is absent")
    c = read_points(path)
    # the file's EPSG code (26995) is in metres but its unit keys say US survey feet
    assert c.units_to_metre == pytest.approx(1200 / 3937)
    assert c.z_units_to_metre == pytest.approx(1200 / 3937)
    assert len(c) == 6280 and "Mississippi" in c.crs


def test_bilinear_one_row_and_one_column_grids():
    gt = (0.0, 1.0, 0.0, 1.0, 0.0, -1.0)
    row = np.array([[0.0, 10.0, 20.0]])
    np.testing.assert_allclose(sample_bilinear(row, gt, [0.5, 1.0, 2.9], [0.5, 0.1, 0.9]),
                               [0.0, 5.0, 20.0])
    col = row.T
    gt_col = (0.0, 1.0, 0.0, 3.0, 0.0, -1.0)
    np.testing.assert_allclose(sample_bilinear(col, gt_col, [0.5, 0.2, 0.9], [2.5, 2.0, 0.1]),
                               [0.0, 5.0, 20.0])
    assert sample_bilinear([[7.0]], gt, 0.3, 0.8) == 7.0


def test_read_crs_from_the_header_or_prj_without_the_points(tmp_path):
    """read_crs gives what read_points would: the LAS header's CRS, a text file's .prj, an override;
    a binary "text" file and a missing file are refused."""
    from osgeo import osr
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(2263)                                         # US feet
    las_path = tmp_path / "a.las"
    _make_las(las_path, n=20, crs_wkt=srs.ExportToWkt())
    wkt, h, v = pointfiles.read_crs(las_path)
    c = read_points(las_path)
    assert (wkt, h, v) == (c.crs, c.units_to_metre, c.z_units_to_metre) and h == pytest.approx(0.3048006096)
    p = _write(tmp_path, "1 2 3\n")
    assert pointfiles.read_crs(p) == (None, 1.0, 1.0)
    (tmp_path / "pts.prj").write_text("EPSG:25832")
    wkt, h, _ = pointfiles.read_crs(p)
    assert "25832" in wkt and h == 1.0
    assert "2263" in pointfiles.read_crs(p, crs="EPSG:2263")[0]
    (tmp_path / "r.txt").write_bytes(b"II*\x00" + bytes(100))
    with pytest.raises(ValueError, match="holds binary data"):
        pointfiles.read_crs(tmp_path / "r.txt")
    with pytest.raises(ValueError, match="does not exist"):
        pointfiles.read_crs(tmp_path / "nope.las")


def test_fourth_column_not_a_class_names_the_header_fix(tmp_path):
    """x y z intensity without a header: the refusal says the 4th column is read as the class and
    how to name the columns (before: only "the class column must hold whole numbers")."""
    p = _write(tmp_path, "1 2 3 12.5\n4 5 6 13.25\n")
    with pytest.raises(ValueError, match=r"line 1: the class column must hold whole numbers; got 12.5.*"
                                         r"4th column is read as the class.*header line naming the columns"):
        read_points(p)
    c = read_points(_write(tmp_path, "x y z intensity\n1 2 3 12.5\n4 5 6 13.25\n", name="named.txt"))
    assert c.classification is None and c.z.tolist() == [3.0, 6.0]


@pytest.mark.parametrize("ext", [".shp", ".gpkg"])
def test_a_vector_layer_given_as_points_says_how_to_export_it(tmp_path, ext):
    """A point shapefile or GeoPackage (how QGIS users keep survey points) was refused as "binary:
    a raster DSM goes to INPUT"; the message now says to export the points as x y z text."""
    p = tmp_path / f"pts{ext}"
    p.write_bytes(b"\x00\x00\x27\x0a" + bytes(100))
    with pytest.raises(ValueError, match=r"is a vector layer.*GEOMETRY=AS_XYZ"):
        read_points(p)
    with pytest.raises(ValueError, match=r"is a vector layer"):
        pointfiles.read_crs(p)


def test_write_points_failing_leaves_no_file(tmp_path, monkeypatch):
    """A write that fails half way (disk full, a LAZ without backend) left the part written under
    the output's name: a file that looks valid. It goes to a hidden file moved into place."""
    cloud = read_points(_points_file(tmp_path))
    out = tmp_path / "cls.txt"
    real = pointfiles._write_text

    def half(path, *args):
        with open(path, "w") as fh:
            fh.write("1 2 3 0\n")
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(pointfiles, "_write_text", half)
    with pytest.raises(ValueError, match=r"cannot write the output .*cls\.txt.*No space left on device.*may be full"):
        write_points(out, cloud, np.zeros(len(cloud), np.uint8))   # a message QGIS shows, not a traceback
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.txt"]
    monkeypatch.setattr(pointfiles, "_write_text", real)
    write_points(out, cloud, np.zeros(len(cloud), np.uint8))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cls.txt", "p.txt"]
    assert len(out.read_text().splitlines()) == len(cloud)


def _points_file(tmp_path):
    p = tmp_path / "p.txt"
    p.write_text("0 0 1\n1 0 2\n0 1 3\n1 1 4\n")
    return p


@pytest.mark.parametrize("sep", [" ", ",", "\t", ";"])
def test_classified_text_keeps_the_input_separator(tmp_path, sep):
    """Classified points go out with the input's separator (';' input came out space-separated,
    which the spreadsheet the ';' file came from reads as one column)."""
    src = tmp_path / "p.txt"
    src.write_text("x{0}y{0}z\n0{0}0{0}1\n1{0}0{0}2\n0{0}1{0}3\n".format(sep))
    cloud = read_points(src)
    write_points(tmp_path / "c.txt", cloud, np.zeros(len(cloud), np.uint8))
    lines = (tmp_path / "c.txt").read_text().splitlines()
    assert lines[0] == sep.join(["x", "y", "z", "class"]) and lines[1] == sep.join(["0.000", "0.000", "1.000", "0"])


def test_decimal_commas_under_a_header_are_named(tmp_path, parser):
    """'x;y;z' then '1,5;2,5;3,5': the refusal said "the header line names 3 columns but the
    points have 6"; it names the decimal commas now."""
    with pytest.raises(ValueError, match=r"names 3 columns but the points have 6.*decimal commas and separated "
                                         r"by ';'"):
        read_points(_write(tmp_path, "x;y;z\n1,5;2,5;3,5\n4,5;5,5;6,5\n", "c.csv"))


@pytest.mark.parametrize("text", ["//X,Y,Z,R,G,B\n1,2,3,10,20,30\n4,5,6,10,20,30\n",   # CloudCompare ASCII
                                  "# X Y Z intensity\n1 2 3 7\n4 5 6 8\n",            # a commented header
                                  "#x,y,z\n1,2,3\n4,5,6\n"])
def test_a_header_written_as_a_comment_names_the_columns(tmp_path, text, parser):
    """CloudCompare's '//X,Y,Z,R,G,B' was refused (6 values per line) and '# X Y Z intensity'
    read as five names for four columns."""
    c = read_points(_write(tmp_path, text))
    np.testing.assert_array_equal(c.x, [1, 4])
    np.testing.assert_array_equal(c.z, [3, 6])
    assert c.classification is None


@pytest.mark.parametrize("header", ["N,E,H", "Northing,Easting,Elevation", "lat,lon,alt", "y,x,z",
                                    "North East Height", "Latitude;Longitude;Altitude"])
def test_a_header_naming_the_axes_in_another_order_picks_them_by_name(tmp_path, header, parser):
    """Surveyors' 'N,E,H' and a GPS's 'lat,lon,alt' were read x y z by position: the northings as eastings (the
    points mirrored about the diagonal, placed 4.9 km away in UTM, without a word); only x, y, z were names."""
    sep = ";" if ";" in header else ("," if "," in header else " ")
    c = read_points(_write(tmp_path, header + "\n" + "\n".join(sep.join(r) for r in (("5400001", "500002", "103"),
                                                                                     ("5400004", "500005", "106"))),
                           "p.csv"))
    np.testing.assert_array_equal(c.x, [500002, 500005])
    np.testing.assert_array_equal(c.y, [5400001, 5400004])
    np.testing.assert_array_equal(c.z, [103, 106])


def test_a_header_naming_the_axes_partly_or_twice_is_refused(tmp_path, parser):
    """x y z by position read 'n,e,quality' as x = northing; a header naming the axis of a column refuses a
    position-read contradicting it, and an axis named twice; 'e,n,quality' (the order x y z) and 'a,b,c' read
    as before."""
    with pytest.raises(ValueError, match=r"names column 1 \('n'\) as y and column 2 \('e'\) as x, but not "
                                         r"all three axes.*those columns are another axis.*easting northing height"):
        read_points(_write(tmp_path, "n,e,quality\n1,2,3\n4,5,6\n"))
    with pytest.raises(ValueError, match=r"names the z axis 2 times \('h', 'elevation'\)"):
        read_points(_write(tmp_path, "e,n,h,elevation\n1,2,3,4\n4,5,6,7\n"))
    for head in ("e,n,quality", "a,b,c", "x,y,z,z"):
        c = read_points(_write(tmp_path, head + "\n1,2,3" + (",3" if head.count(",") == 3 else "") + "\n"))
        assert (c.x[0], c.y[0], c.z[0]) == (1, 2, 3)


def test_utf16_text_points_read_as_text(tmp_path):
    """Points saved as UTF-16 text (Excel's "Unicode Text", Windows PowerShell 5's ``>`` and
    Out-File): their NUL bytes were taken for binary data and the file refused as "a raster DSM
    goes to INPUT". Now read like the UTF-8 file, header, columns and CRS check included."""
    text = "x\ty\tz\tclass\n1.5\t2.5\t3.5\t2\n2.5\t3.5\t4.5\t6\n"
    for enc in ("utf-16", "utf-16-be"):
        p = tmp_path / f"pts_{enc}.txt"
        data = text.encode(enc)
        p.write_bytes(data if enc == "utf-16" else b"\xfe\xff" + data)
        cloud = pointfiles.read_points(str(p))
        np.testing.assert_array_equal(cloud.x, [1.5, 2.5])
        np.testing.assert_array_equal(cloud.z, [3.5, 4.5])
        assert pointfiles.read_crs(str(p))[0] is None
        np.testing.assert_array_equal(pointfiles.read_column(str(p), "class"), [2, 6])
    bad = tmp_path / "bad.txt"
    bad.write_bytes(b"\xff\xfe" + "x y z\n1 2 3\n".encode("utf-16-le") + b"\x00\xd8")   # a cut surrogate
    with pytest.raises(ValueError, match=r"bad.txt' is not UTF-8 text .*save it as UTF-8"):
        pointfiles.read_points(str(bad))


_KILLED_WRITER = r"""
import sys, time
sys.path.insert(0, sys.argv[1])
import numpy as np
from bare_earth.core import pointfiles
def slow(path, *args):
    with open(path, "w") as fh:
        fh.write("0 0 1 0\n")
        fh.flush()
        print("writing", flush=True)
        time.sleep(600)
pointfiles._write_text = slow
pointfiles.write_points(sys.argv[3], pointfiles.read_points(sys.argv[2]), np.zeros(4, np.uint8))
"""


def _killed_mid_write(tmp_path, script, *args):
    """Run ``script`` (it prints a line once its work file is open), then kill -9 it."""
    import signal
    import subprocess
    plugins = os.path.dirname(os.path.dirname(os.path.dirname(pointfiles.__file__)))
    p = subprocess.Popen([sys.executable, "-c", script, plugins, *map(str, args)], stdout=subprocess.PIPE, text=True)
    try:
        assert p.stdout.readline().strip() == "writing"
    finally:
        os.kill(p.pid, signal.SIGKILL)
        p.wait()
    return p.pid


def test_points_write_killed_leaves_a_hidden_part_a_rerun_removes(tmp_path):
    """A point write killed with kill -9 left its hidden ``.part`` file for ever (the writer's cleanup
    never ran, and nothing else knew the name). The work file names its process; a rerun of the same
    output removes the work files of processes that are gone (and those of older versions, which named
    none), and keeps one whose process still runs (a write in progress)."""
    src = _points_file(tmp_path)
    out = tmp_path / "cls.txt"
    pid = _killed_mid_write(tmp_path, _KILLED_WRITER, src, out)
    left = sorted(p.name for p in tmp_path.iterdir() if p.name != "p.txt")
    assert left == [f".cls.txt.{pid:010d}-" + left[0].split("-")[1]] and left[0].endswith(".part.txt")
    assert not out.exists()                                   # nothing that looks valid
    old = tmp_path / ".cls.0123abcd.part.txt"                 # a version before named no process
    old.write_text("0 0 1 0\n")
    live = tmp_path / f".cls.txt.{os.getppid():010d}-0123abcd.part.txt"
    live.write_text("0 0 1 0\n")
    other = tmp_path / f".other.txt.{pid:010d}-0123abcd.part.txt"  # another output's: not ours to judge
    other.write_text("0 0 1 0\n")
    write_points(out, read_points(src), np.zeros(4, np.uint8))
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["cls.txt", "p.txt", live.name, other.name])
    assert len(out.read_text().splitlines()) == 4


def test_part_path_of_a_long_name_stays_within_the_name_limit(tmp_path):
    """The work file of an output whose name is near the 255-byte limit was longer than the limit:
    the write failed with 'File name too long' after the work. Its name is cut, and found again."""
    out = tmp_path / ("é" * 120 + ".las")
    part = pointfiles.part_path(out, ".las")
    assert len(os.path.basename(part).encode()) <= 255 and part.endswith(".part.las")
    gone = 4194305                                   # above Linux's largest pid: no such process
    Path(part.replace(f".{os.getpid():010d}-", f".{gone:010d}-")).write_bytes(b"x")
    assert len(pointfiles.remove_stale_parts(out)) == 1 and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("text, sep", [("1,5 2,5 3,5\n4,5 5,5 6,5\n", "spaces"),
                                       ("1,5\t2,5\t3,5\n4,5\t5,5\t6,5\n", "tabs"),
                                       ("1,5 2,5 3,5 2\n4,5 5,5 6,5 2\n", "spaces"),
                                       ("1,5;2,5;3,5\n4,5;5,5;6,5\n", "';'")])
def test_decimal_commas_between_spaces_or_tabs_are_named(tmp_path, text, sep):
    """A locale's export with decimal commas and tabs or spaces between the values ('1,5<TAB>2,5<TAB>3,5')
    was refused as "6 values per line" without a word of the commas (only ';' was recognised), so the
    README's "decimal commas ... refused with the fix" did not hold; a comma CSV of 6 values is not named."""
    with pytest.raises(ValueError, match=rf"[67] values per line.*decimal commas and separated by {sep}: write them "
                                         r"with decimal points\."):
        read_points(_write(tmp_path, text, "p.txt"))
    with pytest.raises(ValueError, match=r"6 values per line; expected 3 \(x y z\) or 4 \(x y z class\), or a header "
                                         r"line naming the x, y, z columns\.$"):
        read_points(_write(tmp_path, "1,2,3,4,5,6\n4,5,6,7,8,9\n", "six.csv"))
