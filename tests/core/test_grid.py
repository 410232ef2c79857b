"""Raster I/O: open_dsm's checks and messages, units, nodata, and all-or-nothing outputs."""
import math
import os

import numpy as np
import pytest

gdal = pytest.importorskip("osgeo.gdal")
from osgeo import osr  # noqa: E402

from bare_earth.core import grid  # noqa: E402
from bare_earth.core.codes import MASK_COLOURS, NODATA  # noqa: E402

GT = (500000.0, 2.0, 0.0, 4500000.0, 0.0, -2.0)
FT_US = 1200.0 / 3937.0          # metres per US survey foot


def wkt(epsg):
    s = osr.SpatialReference()
    s.ImportFromEPSG(epsg)
    return s.ExportToWkt()


def tif(tmp_path, a, name="dsm.tif", gt=GT, crs=32633, nodata=None, dtype=None):
    return grid.write_array(tmp_path / name, a, gt, crs, nodata=nodata, dtype=dtype)


def leftovers(folder):
    return [p for p in os.listdir(folder) if ".partial" in p]


# ---- open_dsm: errors -----------------------------------------------------------------

def test_nonexistent_path(tmp_path):
    with pytest.raises(ValueError, match="cannot open"):
        grid.open_dsm(tmp_path / "nope.tif")


def test_multiband_needs_band(tmp_path):
    p = tif(tmp_path, np.zeros((2, 5, 5), np.float32))
    with pytest.raises(ValueError, match=r"2 bands.*BAND parameter \(1\.\.2\)"):
        grid.open_dsm(p)
    info = grid.open_dsm(p, band=2)
    assert info.band_index == 2


def test_several_bands_named_when_they_have_descriptions(tmp_path):
    """PDAL's writers.gdal writes six bands (min, max, mean, idw, count, stdev): the refusal names
    them, so the lowest-point band is found without opening the file elsewhere."""
    names = ["min", "max", "mean", "idw", "count", "stdev"]
    p = tif(tmp_path, np.zeros((6, 5, 5), np.float32))
    ds = gdal.Open(str(p), gdal.GA_Update)
    for k, n in enumerate(names, 1):
        ds.GetRasterBand(k).SetDescription(n)
    ds = None
    with pytest.raises(ValueError, match=r"6 bands.*BAND parameter \(1\.\.6\) or extract it first\. Its bands: "
                                         r"1 min, 2 max, 3 mean, 4 idw, 5 count, 6 stdev\.$"):
        grid.open_dsm(p)


@pytest.mark.parametrize("dtype", ["CFloat32", "CInt16"])
def test_complex_raster_refused(tmp_path, dtype):
    """A complex-valued raster is no DSM: before, its real parts were read as heights and the
    imaginary parts dropped with a numpy ComplexWarning on stderr only."""
    tif(tmp_path, np.full((5, 5), 7.0, np.float32), dtype=dtype)
    with pytest.raises(ValueError, match=rf"holds complex numbers \({dtype}\).*gdal_translate -ot Float32"):
        grid.open_dsm(tmp_path / "dsm.tif")


@pytest.mark.parametrize("band", [3, -1])
def test_band_out_of_range(tmp_path, band):
    p = tif(tmp_path, np.zeros((2, 5, 5), np.float32))
    with pytest.raises(ValueError, match=f"band {band} does not exist.*2 band"):
        grid.open_dsm(p, band=band)


@pytest.mark.parametrize("shape", [(2, 5), (5, 2), (1, 1)])
def test_too_small(tmp_path, shape):
    p = tif(tmp_path, np.zeros(shape, np.float32))
    with pytest.raises(ValueError, match="too small.*3 x 3"):
        grid.open_dsm(p)


def test_three_by_three_accepted(tmp_path):
    assert grid.open_dsm(tif(tmp_path, np.zeros((3, 3), np.float32))).shape == (3, 3)


def test_rotated(tmp_path):
    p = tif(tmp_path, np.zeros((5, 5), np.float32), gt=(0.0, 1.0, 0.2, 10.0, 0.1, -1.0))
    with pytest.raises(ValueError, match="rotated.*gdalwarp"):
        grid.open_dsm(p)


@pytest.mark.parametrize("dtype,nodata", [(np.float32, -9999.0), (np.int16, -9999), (np.float32, None)])
def test_all_nodata(tmp_path, dtype, nodata):
    a = np.full((4, 4), -9999 if nodata is not None else np.nan, dtype)
    info = grid.open_dsm(tif(tmp_path, a, nodata=nodata))
    with pytest.raises(ValueError, match="no valid cell"):
        grid.check_has_data(info)


KM_CRS = ('PROJCS["UTM 32N in km",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],'
          'PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],'
          'PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",9],PARAMETER["scale_factor",0.9996],'
          'PARAMETER["false_easting",500],PARAMETER["false_northing",0],UNIT["kilometre",1000]]')


def test_heights_beyond_the_range_in_the_crs_unit_refused_naming_it(tmp_path):
    """A DSM in a CRS in kilometres storing its heights in metres (300): read in the CRS's unit they
    are 300 km, beyond any terrain. Refused before work naming the unit (before: the check read the
    stored values as metres and passed, then the filter found no cell: 'z has no valid cell (all
    nodata/NaN)')."""
    a = np.full((5, 5), 300.0, np.float32)
    info = grid.open_dsm(tif(tmp_path, a, gt=(500.0, 0.001, 0.0, 5400.0, 0.0, -0.001), crs=KM_CRS))
    with pytest.raises(ValueError, match=r"no valid cell.*read in its CRS's unit \(1000 m\).*compound CRS"):
        grid.check_has_data(info)
    info = grid.open_dsm(tif(tmp_path, a / 1000.0, name="km.tif", gt=(500.0, 0.001, 0.0, 5400.0, 0.0, -0.001),
                             crs=KM_CRS))
    assert grid.check_has_data(info) == 1.0                # 0.3 km: 300 m


@pytest.mark.parametrize("max_cells", [4, 9, 30])
def test_check_has_data_decimated(tmp_path, max_cells):
    # large rasters are sampled (max_cells small makes a 10 x 10 raster 'large')
    a = np.full((10, 10), -9999, np.float32)
    info = grid.open_dsm(tif(tmp_path, a, nodata=-9999))
    with pytest.raises(ValueError, match="no valid cell"):
        grid.check_has_data(info, max_cells=max_cells)
    a[:] = 1.0
    info = grid.open_dsm(tif(tmp_path, a, name="full.tif", nodata=-9999))
    assert grid.check_has_data(info, max_cells=max_cells) == 1.0


@pytest.mark.parametrize("rc", [(1, 1), (0, 9), (9, 0), (8, 3)])
def test_check_has_data_sparse_cell_not_missed_by_sampling(tmp_path, rc):
    a = np.full((10, 10), -9999, np.float32)
    a[rc] = 5.0                                  # one valid cell, between the samples
    info = grid.open_dsm(tif(tmp_path, a, nodata=-9999))
    assert 0 < grid.check_has_data(info, max_cells=4) <= 1


@pytest.mark.parametrize("overviews", [False, True])
def test_check_has_data_reads_a_sample_of_blocks_not_every_block(tmp_path, monkeypatch, overviews):
    """QA 20: the dialog's check of a sparse 33000 x 33000 GeoTIFF took 16 s: its decimated read of a raster
    without overviews made GDAL decompress every block. It now reads whole blocks spread over the raster (with
    overviews: the decimated read, which GDAL serves from them) and, when they miss the data, scans the strips
    GDAL does not report empty. Counted: the cells of the windows asked of GDAL (the blocks it must decode),
    never timings. The data are found either way."""
    from osgeo import gdal
    path = str(tmp_path / "sparse.tif")
    ds = gdal.GetDriverByName("GTiff").Create(path, 2048, 2048, 1, gdal.GDT_Float32,
                                              ["TILED=YES", "SPARSE_OK=TRUE", "COMPRESS=DEFLATE"])
    ds.SetGeoTransform(GT)
    ds.GetRasterBand(1).SetNoDataValue(-9999.0)
    ds.GetRasterBand(1).WriteArray(np.full((200, 200), 50.0, np.float32), 1000, 1100)   # off the sampled blocks
    if overviews:
        ds.BuildOverviews("NEAREST", [4, 16])
    ds = None
    info = grid.open_dsm(path)
    asked = []
    read = type(info).read_stored

    def counting(self, window=None, step=1):
        r0, r1, c0, c1 = window or (0, self.shape[0], 0, self.shape[1])
        asked.append((r1 - r0) * (c1 - c0) if step == 1 or not overviews else (r1 - r0) * (c1 - c0) // step ** 2)
        return read(self, window, step)
    monkeypatch.setattr(type(info), "read_stored", counting)
    assert 0 < grid.check_has_data(info, max_cells=65536) < 1
    assert sum(asked) <= 8 * 65536, asked          # a decimated read without overviews: the 4.2 Mcells
    if overviews:
        return
    ds = gdal.Open(path, gdal.GA_Update)
    ds.GetRasterBand(1).WriteArray(np.full((200, 200), -9999.0, np.float32), 1000, 1100)
    ds = None
    with pytest.raises(ValueError, match="no valid cell"):
        grid.check_has_data(grid.open_dsm(path), max_cells=65536)


@pytest.mark.parametrize("scale,offset", [(float("nan"), 0.0), (1.0, float("inf"))])
def test_a_band_scale_or_offset_that_is_no_number_refused_naming_it(tmp_path, scale, offset):
    """QA 20: a band whose scale (or offset) is NaN made every height NaN, and the check said "every cell is nodata.
    Check the nodata value", pointing at the wrong setting. Refused on opening, naming the scale and the fix."""
    from osgeo import gdal
    path = str(tif(tmp_path, np.full((5, 5), 300.0, np.float32)))
    ds = gdal.Open(path, gdal.GA_Update)
    ds.GetRasterBand(1).SetScale(scale)
    ds.GetRasterBand(1).SetOffset(offset)
    ds = None
    with pytest.raises(ValueError, match=r"declares a scale of .* and an offset of .*: no height can be read\. Give "
                                         r"the band a finite scale and offset \(gdal_edit\.py -scale 1 -offset 0"):
        grid.open_dsm(path)


def test_check_has_data_sample_windows_stay_within_the_budget_on_huge_blocks(tmp_path, monkeypatch):
    """The block sample of a raster stored as one strip (or tiles larger than the budget) read windows of whole
    blocks: the whole raster at once. Each window now holds at most ``max_cells`` cells."""
    from osgeo import gdal
    path = str(tmp_path / "strip.tif")
    ds = gdal.GetDriverByName("GTiff").Create(path, 1024, 1024, 1, gdal.GDT_Float32,
                                              ["BLOCKYSIZE=1024", "COMPRESS=DEFLATE"])     # one strip
    ds.SetGeoTransform(GT)
    ds.GetRasterBand(1).WriteArray(np.full((1024, 1024), 50.0, np.float32))
    ds = None
    info = grid.open_dsm(path)
    assert info.dataset().GetRasterBand(1).GetBlockSize() == [1024, 1024]
    asked = []
    read = type(info).read_stored

    def counting(self, window=None, step=1):
        r0, r1, c0, c1 = window or (0, self.shape[0], 0, self.shape[1])
        asked.append((r1 - r0) * (c1 - c0) // step ** 2)
        return read(self, window, step)
    monkeypatch.setattr(type(info), "read_stored", counting)
    assert grid.check_has_data(info, max_cells=16384) == 1.0
    assert max(asked) <= 16384, asked


def test_the_alpha_band_chosen_as_heights_refused_naming_the_height_band(tmp_path):
    """QA 20: BAND = 2 on a DSM with an alpha band (gdalwarp -dstalpha) read the transparency, 0 / 255, as heights:
    a flat DTM of 255 m, every cell ground, without a word. Refused naming the height band; band 1 reads the
    heights with the alpha band as their mask."""
    from osgeo import gdal
    path = str(tmp_path / "alpha.tif")
    ds = gdal.GetDriverByName("GTiff").Create(path, 6, 6, 2, gdal.GDT_Float32, ["ALPHA=YES"])
    ds.SetGeoTransform(GT)
    ds.GetRasterBand(1).WriteArray(np.full((6, 6), 300.0, np.float32))
    ds.GetRasterBand(2).WriteArray(np.full((6, 6), 255.0, np.float32))
    ds = None
    with pytest.raises(ValueError, match=r"band 2 of the raster .* is its alpha band \(transparency: 0 where a cell "
                                         r"is not drawn\), not heights: choose the height band \(1\)\."):
        grid.open_dsm(path, 2)
    assert grid.open_dsm(path, 1).masked == 2 and grid.open_dsm(path).band_index == 1


def test_check_has_data_decimated_nan_undeclared(tmp_path):
    a = np.zeros((10, 10), np.float32)
    a[:, :5] = np.nan
    info = grid.open_dsm(tif(tmp_path, a))
    assert grid.check_has_data(info, max_cells=4) == pytest.approx(0.5, abs=0.25)
    assert info.nan_undeclared


# ---- open_dsm: nodata and units -----------------------------------------------------------

def test_nan_without_declared_nodata(tmp_path):
    a = np.arange(16, dtype=np.float32).reshape(4, 4)
    a[1, 2] = np.nan
    info = grid.open_dsm(tif(tmp_path, a))
    assert info.nodata is None and not info.nan_undeclared
    share = grid.check_has_data(info)
    assert share == pytest.approx(15 / 16)
    assert info.nan_undeclared
    assert any("NaN" in w and "no nodata" in w for w in info.warnings)


def test_declared_nodata_no_nan_warning(tmp_path):
    a = np.arange(16, dtype=np.float32).reshape(4, 4)
    a[0, 0] = -9999
    info = grid.open_dsm(tif(tmp_path, a, nodata=-9999))
    assert grid.check_has_data(info) == pytest.approx(15 / 16)
    assert not info.nan_undeclared and info.warnings == []
    assert info.cell_size_m == (2.0, 2.0) and info.z_to_m == 1.0


def test_geographic_cell_size_at_centre_latitude(tmp_path):
    # 10 x 10 cells of 0.1 deg centred on latitude 45 (the top edge, 45.5, would be 0.9 % off)
    gt = (10.0, 0.1, 0.0, 45.5, 0.0, -0.1)
    info = grid.open_dsm(tif(tmp_path, np.zeros((10, 10), np.float32), gt=gt, crs=4326))
    dx, dy = info.cell_size_m
    assert dx == pytest.approx(7884.7, rel=1e-3)      # 1 deg lon at 45 deg ~ 78.85 km
    assert dy == pytest.approx(11113.2, rel=1e-3)     # 1 deg lat at 45 deg ~ 111.13 km
    assert info.z_to_m == 1.0
    assert any("geographic" in w and "45.0000" in w for w in info.warnings)


@pytest.mark.parametrize("gt,crs,message", [
    ((10.0, 1e-5, 0.0, 50.0, 0.0, -1e-5), None, r"1e-05 x 1e-05 m \(1e-05 x 1e-05 in metres, having no CRS\).*"
                                              r"probably in degrees.*gdal_edit\.py -a_srs EPSG:4326"),
    ((500000.0, 1e-5, 0.0, 5e6, 0.0, -1e-5), 32633, r"\(1e-05 x 1e-05 in its CRS\).*probably in degrees"),
    ((10.0, 1e-5, 0.0, 89.9999, 0.0, -1e-5), 4326, r"\de-0\d x 1\.1\d m on the ground.*EPSG:3413"),
], ids=["no_crs", "utm", "near_pole"])
def test_cells_under_a_millimetre_refused(tmp_path, gt, crs, message):
    """Cells under 1 mm are a cell size in degrees read as metres, or longitudes near a pole: before,
    a 10 x 10 raster of them made the filters' windows (metres) millions of cells wide (dtm, rascor
    and slopeprofile ran for hours; morphological and geodesic asked for 149 GB)."""
    p = tmp_path / "dsm.tif"
    grid.write_array(p, np.zeros((10, 10), np.float32), gt, wkt(crs) if crs else "")
    with pytest.raises(ValueError, match=message):
        grid.open_dsm(p)
    grid.write_array(p, np.zeros((10, 10), np.float32), (500000.0, 0.01, 0.0, 5e6, 0.0, -0.01), wkt(32633))
    assert grid.open_dsm(p).cell_size_m == pytest.approx((0.01, 0.01))     # a centimetre: a drone DSM


def test_geographic_cell_size_at_equator(tmp_path):
    gt = (0.0, 0.001, 0.0, 0.005, 0.0, -0.001)
    info = grid.open_dsm(tif(tmp_path, np.zeros((10, 10), np.float32), gt=gt, crs=4326))
    assert info.cell_size_m[0] == pytest.approx(111.319, rel=1e-3)
    assert info.cell_size_m[1] == pytest.approx(110.574, rel=1e-3)


@pytest.mark.parametrize("lat", [0.0, 52.0, 70.0])
def test_web_mercator_cell_size_is_the_ground_size(tmp_path, lat):
    """EPSG:3857 cells of 1 unit at latitude 52 are 0.62 m on the ground (1 / cos(lat) units per
    metre): they were taken as 1 m, so slopes read 1.6 x too gentle and windows 1.6 x too wide.
    The cell size is the ground's (Web Mercator's sphere on the WGS84 ellipsoid: within 0.5 %),
    with a warning; at the equator (scale 1) nothing changes."""
    import math
    y = 6378137.0 * math.log(math.tan(math.pi / 4 + math.radians(lat) / 2))
    info = grid.open_dsm(tif(tmp_path, np.zeros((10, 10), np.float32), gt=(1e6, 2.0, 0.0, y + 10.0, 0.0, -2.0),
                             crs=3857))
    want = 2.0 * math.cos(math.radians(lat))
    assert info.cell_size_m[0] == info.cell_size_m[1]
    assert info.cell_size_m[0] == pytest.approx(want, rel=5e-3)
    said = [w for w in info.warnings if "does not keep distances" in w]
    assert bool(said) == (lat > 0), info.warnings


def test_utm_cell_size_is_left_as_it_is(tmp_path):
    """A CRS made for measuring (UTM: scale 0.9996 at its central meridian) keeps its cell size."""
    gt = (500000.0, 0.5, 0.0, 5400000.0, 0.0, -0.5)
    info = grid.open_dsm(tif(tmp_path, np.zeros((10, 10), np.float32), gt=gt, crs=32632))
    assert info.cell_size_m == (0.5, 0.5) and info.warnings == []


def test_us_survey_feet(tmp_path):
    gt = (300000.0, 3.0, 0.0, 60000.0, 0.0, -3.0)
    info = grid.open_dsm(tif(tmp_path, np.zeros((4, 4), np.float32), gt=gt, crs=2263))
    assert info.z_to_m == pytest.approx(0.3048006, rel=1e-6)
    assert info.cell_size_m == pytest.approx((3 * FT_US, 3 * FT_US), rel=1e-9)
    assert any("linear unit" in w for w in info.warnings)


@pytest.mark.parametrize("gt,crs,want", [
    # 1 m cells given in US survey feet: 3.2808333333333337 ft x 0.30480060960121924 m/ft = 1.0000000000000002
    ((6000000.0, 1 / (1200 / 3937), 0.0, 2000000.0, 0.0, -1 / (1200 / 3937)), 2227, (1.0, 1.0)),
    # a cell size computed from an extent (OpenDroneMap's dsm.tif in the shared data)
    ((500000.0, 0.8000000000000287, 0.0, 5400000.0, 0.0, -0.8000000000001306), 32632, (0.8, 0.8)),
])
def test_cell_size_without_the_float_noise_of_its_computation(tmp_path, gt, crs, want):
    """A cell size's last digits of float noise are not kept: windows given in metres become
    cells by rounding sizes / cell, and 30 m / 1.0000000000000002 m is 29.99... cells."""
    info = grid.open_dsm(tif(tmp_path, np.zeros((4, 4), np.float32), gt=gt, crs=crs))
    assert info.cell_size_m == want


def test_no_crs_warns(tmp_path):
    info = grid.open_dsm(tif(tmp_path, np.zeros((4, 4), np.float32), crs=""))
    assert info.crs_wkt == ""
    assert info.cell_size_m == (2.0, 2.0) and info.z_to_m == 1.0
    assert any("no CRS" in w for w in info.warnings)


def test_non_square_cells_warn(tmp_path):
    gt = (0.0, 1.0, 0.0, 10.0, 0.0, -2.0)
    info = grid.open_dsm(tif(tmp_path, np.zeros((4, 4), np.float32), gt=gt))
    assert info.cell_size_m == (1.0, 2.0)
    assert any("not square" in w for w in info.warnings)
    info = grid.open_dsm(tif(tmp_path, np.zeros((4, 4), np.float32), name="sq.tif"))
    assert not any("not square" in w for w in info.warnings)


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int16])
def test_read_converts_nodata_to_nan(tmp_path, dtype):
    a = np.array([[1, 2, 3, 4], [5, -9999, 7, 8], [9, 10, 11, 12]], dtype)
    info = grid.open_dsm(tif(tmp_path, a, nodata=-9999))
    z = info.read()
    assert z.dtype == np.float32
    expect = a.astype(np.float32)
    expect[1, 1] = np.nan
    np.testing.assert_array_equal(z, expect)
    np.testing.assert_array_equal(info.read((1, 3, 1, 3)), expect[1:3, 1:3])


def test_read_converts_feet_to_metres(tmp_path):
    a = np.array([[10, 20, 30], [40, -9999, 60], [70, 80, 90]], np.float32)
    info = grid.open_dsm(tif(tmp_path, a, crs=2263, nodata=-9999))
    z = info.read()
    expect = a * np.float32(FT_US)
    expect[1, 1] = np.nan
    np.testing.assert_allclose(z, expect, rtol=1e-6)
    assert np.isnan(z[1, 1])


# ---- OutputSet ----------------------------------------------------------------------------

def _info(tmp_path, nodata=-9999.0):
    a = np.arange(20, dtype=np.float32).reshape(4, 5)
    return grid.open_dsm(tif(tmp_path, a, nodata=nodata))


def test_outputset_commit_keeps_georeference(tmp_path):
    info = _info(tmp_path)
    out_dtm, out_mask = tmp_path / "dtm.tif", tmp_path / "mask.tif"
    d = np.arange(20, dtype=np.float32).reshape(4, 5) / 2
    m = np.array([[0, 1, 2, 255, 0]] * 4, np.uint8)
    with grid.OutputSet(info) as out:
        out.add("dtm", out_dtm, "Float32", nodata=-9999.0)
        out.add("mask", out_mask, "Byte", nodata=NODATA, mask_style=True)
        out.write("dtm", d[:2], (0, 2, 0, 5))
        out.write("dtm", d[2:], (2, 4, 0, 5))
        out.write("mask", m)
        assert not out_dtm.exists() and len(leftovers(tmp_path)) == 2
        out.commit()
    assert leftovers(tmp_path) == []
    ds = gdal.Open(str(out_dtm))
    assert ds.GetGeoTransform() == pytest.approx(GT)
    srs = osr.SpatialReference(wkt=ds.GetProjection())
    assert srs.IsSame(osr.SpatialReference(wkt=info.crs_wkt))
    assert ds.GetRasterBand(1).GetNoDataValue() == -9999.0
    np.testing.assert_array_equal(ds.GetRasterBand(1).ReadAsArray(), d)
    ds = gdal.Open(str(out_mask))
    b = ds.GetRasterBand(1)
    assert b.DataType == gdal.GDT_Byte and b.GetNoDataValue() == 255
    np.testing.assert_array_equal(b.ReadAsArray(), m)
    ct = b.GetRasterColorTable()
    assert ct is not None
    for code, rgba in MASK_COLOURS.items():
        assert ct.GetColorEntry(code) == rgba
    qml = tmp_path / "mask.qml"
    assert qml.exists() and "paletteEntry" in qml.read_text()
    assert not (tmp_path / "dtm.qml").exists()


def test_outputset_exception_leaves_nothing(tmp_path):
    info = _info(tmp_path)
    before = set(os.listdir(tmp_path))
    with pytest.raises(RuntimeError, match="stop"):
        with grid.OutputSet(info) as out:
            out.add("dtm", tmp_path / "dtm.tif", "Float32", nodata=-9999.0)
            out.add("mask", tmp_path / "mask.tif", "Byte", nodata=NODATA, mask_style=True)
            out.write("dtm", np.zeros((4, 5), np.float32))
            out.write("mask", np.zeros((4, 5), np.uint8))
            raise RuntimeError("stop")
    assert set(os.listdir(tmp_path)) == before


def test_outputset_discard_leaves_nothing(tmp_path):
    info = _info(tmp_path)
    before = set(os.listdir(tmp_path))
    out = grid.OutputSet(info)
    out.add("mask", tmp_path / "mask.tif", "Byte", nodata=NODATA, mask_style=True)
    out.write("mask", np.ones((4, 5), np.uint8))
    out.discard()
    assert set(os.listdir(tmp_path)) == before


def test_outputset_replaces_existing(tmp_path):
    info = _info(tmp_path)
    path = tmp_path / "dtm.tif"
    for value in (1.0, 2.0):
        with grid.OutputSet(info) as out:
            out.add("dtm", path, "Float32", nodata=-9999.0)
            out.write("dtm", np.full((4, 5), value, np.float32))
            out.commit()
        np.testing.assert_array_equal(gdal.Open(str(path)).ReadAsArray(), value)
    assert leftovers(tmp_path) == []


def test_outputset_failed_rerun_keeps_previous_output(tmp_path):
    info = _info(tmp_path)
    path = tmp_path / "dtm.tif"
    with grid.OutputSet(info) as out:
        out.add("dtm", path, "Float32")
        out.write("dtm", np.full((4, 5), 1.0, np.float32))
        out.commit()
    with pytest.raises(KeyError):
        with grid.OutputSet(info) as out:
            out.add("dtm", path, "Float32")
            out.write("dtm", np.full((4, 5), 2.0, np.float32))
            raise KeyError("x")
    np.testing.assert_array_equal(gdal.Open(str(path)).ReadAsArray(), 1.0)
    assert leftovers(tmp_path) == []


def test_outputset_multiband_and_nan_nodata(tmp_path):
    info = _info(tmp_path, nodata=None)
    path = tmp_path / "curv.tif"
    a = np.stack([np.zeros((4, 5)), np.ones((4, 5))]).astype(np.float32)
    with grid.OutputSet(info) as out:
        out.add("curv", path, "Float32", bands=2, nodata=float("nan"), descriptions=["a", "b"])
        out.write("curv", a)
        out.commit()
    ds = gdal.Open(str(path))
    assert ds.RasterCount == 2 and np.isnan(ds.GetRasterBand(1).GetNoDataValue())
    assert ds.GetRasterBand(2).GetDescription() == "b"
    np.testing.assert_array_equal(ds.ReadAsArray(), a)


def test_no_georeference_warns(tmp_path):
    p = str(tmp_path / "raw.tif")
    ds = gdal.GetDriverByName("GTiff").Create(p, 4, 5, 1, gdal.GDT_Float32)
    ds.GetRasterBand(1).WriteArray(np.ones((5, 4), np.float32))
    ds = None
    info = grid.open_dsm(p)
    assert info.cell_size_m == (1.0, 1.0) and info.shape == (5, 4)
    assert any("no georeference" in w for w in info.warnings)


def test_geographic_bad_latitude(tmp_path):
    gt = (10.0, 0.1, 0.0, 250.0, 0.0, -0.1)
    with pytest.raises(ValueError, match="not a latitude"):
        grid.open_dsm(tif(tmp_path, np.zeros((4, 4), np.float32), gt=gt, crs=4326))


# ---- geodesy: one formula ---------------------------------------------------------------

def test_metres_per_degree_known_values():
    lon0, lat0 = grid.metres_per_degree(0.0)
    assert lon0 == pytest.approx(111319.49, abs=0.01)        # equator: pi/180 * a
    assert lat0 == pytest.approx(110574.28, abs=0.01)        # pi/180 * a (1 - e2)
    lon60, lat60 = grid.metres_per_degree(60.0)
    assert lon60 == pytest.approx(55799.98, abs=0.05) and lat60 == pytest.approx(111412.24, abs=0.05)
    assert grid.metres_per_degree(-60.0) == grid.metres_per_degree(60.0)


# ---- corrupt and unsafe inputs (#15 defects 2, 6) -------------------------------------------

def _tiled(tmp_path, name="src.tif", shape=(300, 300)):
    a = np.random.default_rng(0).random(shape, dtype=np.float32) * 10
    return tif(tmp_path, a, name=name), a


def test_truncated_geotiff_gives_value_error_naming_the_file(tmp_path):
    p, _ = _tiled(tmp_path)
    data = open(p, "rb").read()
    bad = tmp_path / "truncated.tif"
    bad.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"truncated\.tif.*(truncated or corrupt|TIFF)") as ei:
        info = grid.open_dsm(bad)
        info.read()
    assert str(ei.value) and ".." not in str(ei.value)      # GDAL's "TIFFReadEncodedTile() failed." ended in ".."


def test_vrt_with_missing_source_gives_value_error(tmp_path):
    p, _ = _tiled(tmp_path)
    vrt = str(tmp_path / "dsm.vrt")
    gdal.Translate(vrt, p, format="VRT")
    os.rename(p, tmp_path / "moved.tif")
    with pytest.raises(ValueError, match=r"dsm\.vrt.*src\.tif"):
        grid.open_dsm(vrt)


def test_read_error_in_a_later_block_is_a_value_error(tmp_path):
    """The first cells read fine, a later tile is cut off: the read names the file."""
    p, _ = _tiled(tmp_path, shape=(1024, 1024))
    data = open(p, "rb").read()
    bad = tmp_path / "cut.tif"
    bad.write_bytes(data[: int(len(data) * 0.9)])
    info = None
    try:
        info = grid.open_dsm(bad)
    except ValueError as exc:                 # the probe cell may already be cut off
        assert "cut.tif" in str(exc)
    if info is not None:
        with pytest.raises(ValueError, match=r"cut\.tif"):
            info.read()


RAW_VRT = """<VRTDataset rasterXSize="8" rasterYSize="8">
  <VRTRasterBand dataType="Byte" band="1" subClass="VRTRawRasterBand">
    <SourceFilename relativetoVRT="0">{src}</SourceFilename>
    <ImageOffset>0</ImageOffset><PixelOffset>1</PixelOffset><LineOffset>8</LineOffset>
  </VRTRasterBand>
</VRTDataset>"""


def test_raw_band_vrt_refused(tmp_path):
    secret = tmp_path / "secret.txt"
    secret.write_bytes(b"root:x:0:0:root:/root:/bin/bash\n" * 4)
    vrt = tmp_path / "raw.vrt"
    vrt.write_text(RAW_VRT.format(src=secret))
    with pytest.raises(ValueError, match=r"raw\.vrt.*refused.*VRTRawRasterBand"):
        grid.open_dsm(vrt)
    # hidden one level down: a VRT whose source is the raw VRT
    outer = tmp_path / "outer.vrt"
    gdal.Translate(str(outer), str(vrt), format="VRT")
    with pytest.raises(ValueError, match=r"outer\.vrt.*refused"):
        grid.open_dsm(outer)


def test_plain_vrt_accepted(tmp_path):
    p, a = _tiled(tmp_path)
    vrt = str(tmp_path / "ok.vrt")
    gdal.Translate(vrt, p, format="VRT")
    np.testing.assert_array_equal(grid.open_dsm(vrt).read(), a)


# ---- scale and offset (#15 defect 3), heights beyond any terrain (defect 11) ------------------

def _scaled(tmp_path, counts, scale=0.1, offset=100.0, nodata=-32768):
    p = tif(tmp_path, counts, name="scaled.tif", nodata=nodata, dtype="Int16")
    ds = gdal.Open(p, gdal.GA_Update)
    ds.GetRasterBand(1).SetScale(scale)
    ds.GetRasterBand(1).SetOffset(offset)
    ds = None
    return p


def test_scale_and_offset_applied_on_read(tmp_path):
    counts = np.array([[1880, 1900, 2081], [1950, -32768, 2000], [1883, 1884, 1885]], np.int16)
    info = grid.open_dsm(_scaled(tmp_path, counts))
    assert (info.scale, info.offset) == (0.1, 100.0)
    assert any("scale" in n and "0.1" in n and "100" in n for n in info.notes)
    z = info.read()
    want = (counts * 0.1 + 100.0).astype(np.float32)
    want[1, 1] = np.nan
    np.testing.assert_array_equal(z, want)
    np.testing.assert_array_equal(info.read_heights((0, 1, 0, 3)), want[:1])
    assert grid.check_has_data(info) == pytest.approx(8 / 9)


@pytest.mark.parametrize("far", [1e30, -1e30, -3.4e38, np.inf])
def test_far_heights_read_as_nodata(tmp_path, far):
    a = np.full((5, 6), 12.5, np.float32)
    a[2, 3] = far
    a[0, 0] = np.nan
    info = grid.open_dsm(tif(tmp_path, a))
    z = info.read()
    assert np.isnan(z[2, 3]) and np.isnan(z[0, 0]) and np.isfinite(z).sum() == 28
    assert info.far_cells == (1 if np.isfinite(far) else 0)   # inf: nodata as every non-finite cell
    assert info.nan_undeclared       # the NaN cell, not the far one, makes this warning


# ---- cells masked by an alpha band or a mask band are nodata ------------------------------

def _with_alpha(tmp_path, z, alpha, alpha_type=gdal.GDT_Float32, name="alpha.tif"):
    """A DSM band and an alpha band (as ``gdalwarp -dstalpha`` writes them: of the data's type)."""
    path = str(tmp_path / name)
    ds = gdal.GetDriverByName("GTiff").Create(path, z.shape[1], z.shape[0], 2, gdal.GDT_Float32)
    ds.SetGeoTransform(GT)
    ds.SetProjection(wkt(32633))
    ds.GetRasterBand(1).WriteArray(z)
    ds.GetRasterBand(2).SetColorInterpretation(gdal.GCI_AlphaBand)
    ds.GetRasterBand(2).WriteArray(alpha)
    ds = None
    if alpha_type != gdal.GDT_Float32:
        out = str(tmp_path / ("t_" + name))
        gdal.Translate(out, path, outputType=alpha_type)
        return out
    return path


@pytest.mark.parametrize("alpha_type", [gdal.GDT_Float32, gdal.GDT_Byte])
def test_alpha_band_zero_is_nodata_and_the_heights_band_chosen(tmp_path, alpha_type):
    """A DSM warped with an alpha band (0 outside the data, the heights band 0 there too) is a
    DSM with nodata: the heights band is the DSM (no BAND needed) and alpha 0 cells are NaN.
    They were read as heights of 0 (GDAL's own mask ignores a Float32 alpha band)."""
    z = np.arange(30, dtype=np.float32).reshape(5, 6) + 100
    alpha = np.full(z.shape, 255, np.float32)
    alpha[:2, :3] = 0
    z[:2, :3] = 0
    p = _with_alpha(tmp_path, z, alpha, alpha_type)
    info = grid.open_dsm(p)
    assert info.band_index == 1
    expect = z.copy()
    expect[:2, :3] = np.nan
    np.testing.assert_array_equal(info.read(), expect)
    np.testing.assert_array_equal(info.read((1, 4, 2, 5)), expect[1:4, 2:5])
    assert any("alpha band (band 2)" in n for n in info.notes)
    assert grid.check_has_data(info) == pytest.approx(1 - 6 / 30)


def test_alpha_band_all_transparent_has_no_data(tmp_path):
    z = np.full((4, 5), 7.0, np.float32)
    info = grid.open_dsm(_with_alpha(tmp_path, z, np.zeros(z.shape, np.float32)))
    with pytest.raises(ValueError, match="no valid cell"):
        grid.check_has_data(info)
    with pytest.raises(ValueError, match="no valid cell"):   # decimated, then strip by strip
        grid.check_has_data(info, max_cells=4)


def test_internal_mask_band_is_nodata(tmp_path):
    """A GeoTIFF whose validity is an internal mask (no nodata value): masked cells are NaN."""
    z = np.arange(30, dtype=np.float32).reshape(5, 6) + 100
    src = _with_alpha(tmp_path, z, np.where(np.arange(30).reshape(5, 6) % 7 == 0, 0, 255).astype(np.float32),
                      gdal.GDT_Byte)
    out = str(tmp_path / "masked.tif")
    gdal.SetConfigOption("GDAL_TIFF_INTERNAL_MASK", "YES")
    try:
        gdal.Translate(out, src, bandList=[1], maskBand=2)
    finally:
        gdal.SetConfigOption("GDAL_TIFF_INTERNAL_MASK", None)
    info = grid.open_dsm(out)
    assert gdal.Open(out).RasterCount == 1 and info.nodata is None
    expect = z.copy()
    expect[np.arange(30).reshape(5, 6) % 7 == 0] = np.nan
    np.testing.assert_array_equal(info.read(), expect)
    assert any("mask band" in n for n in info.notes)


# ---- compound CRSs: heights in the unit of the vertical part -------------------------------

@pytest.mark.parametrize("crs,cell_to_m,z_to_m", [
    ("EPSG:26917+6360", 1.0, FT_US),          # UTM metres, NAVD88 heights in US survey feet
    ("EPSG:2264+5703", FT_US, 1.0),           # North Carolina ftUS, NAVD88 heights in metres
    ("EPSG:4326+6360", None, FT_US),          # degrees, heights in US survey feet
])
def test_compound_crs_heights_in_the_vertical_unit(tmp_path, crs, cell_to_m, z_to_m):
    """The heights of a raster in a compound CRS are in its vertical part's unit, whatever the
    horizontal unit: they were taken in the horizontal unit (metres for degrees)."""
    s = osr.SpatialReference()
    s.SetFromUserInput(crs)
    gt = (10.0, 0.0001, 0.0, 50.0, 0.0, -0.0001) if cell_to_m is None else GT
    if crs.startswith("EPSG:2264"):   # in North Carolina (GT lies 1400 km north of it, where the grid's
        gt = (2100000.0, 2.0, 0.0, 740000.0, 0.0, -2.0)   # scale is 1.018: no longer metres on the ground)
    a = np.array([[10, 20, 30], [40, 50, 60], [70, 80, 90]], np.float32)
    info = grid.open_dsm(tif(tmp_path, a, gt=gt, crs=s.ExportToWkt()))
    assert info.z_to_m == pytest.approx(z_to_m, rel=1e-9)
    if cell_to_m is not None:
        assert info.cell_size_m == pytest.approx((2.0 * cell_to_m, 2.0 * cell_to_m), rel=1e-9)
    np.testing.assert_allclose(info.read(), a * np.float32(z_to_m), rtol=1e-6)
    if z_to_m != 1.0:
        assert any("US survey foot" in w for w in info.warnings)


def test_vertical_unit_factor():
    s = osr.SpatialReference()
    s.SetFromUserInput("EPSG:26917+6360")
    assert grid.vertical_unit_factor(s) == (pytest.approx(FT_US), "US survey foot")
    assert grid.vertical_unit_factor(osr.SpatialReference(wkt(2264))) is None
    assert grid.vertical_unit_factor(None) is None


# ---- an undeclared common nodata value far below the heights: a warning --------------------

@pytest.mark.parametrize("value,dtype,declared,warned", [
    (-9999.0, np.float32, None, True),
    (-32768.0, np.int16, None, True),
    (-999.0, np.float32, None, True),            # QA21: -999 (many exports' nodata) was filtered without a word
    (-999.0, np.int16, None, True),
    (-9999.0, np.float32, -9999.0, False),       # declared: nodata, nothing to say
    (-9999.0, np.float32, -32768.0, True),       # another value declared
    (65535.0, np.uint16, None, True),            # above the heights: UInt16's largest
    (32767.0, np.int16, None, True),
    (0.0, np.uint16, None, True),                # an unsigned DSM's background 0, 300 m below its hill
    (0.0, np.float32, None, True),
    (0.0, np.uint16, 0.0, False),
])
def test_undeclared_common_nodata_far_below_warned(tmp_path, value, dtype, declared, warned):
    a = np.full((6, 8), 300.0)
    a[2, 3] = 310.0
    a[:, :2] = value
    info = grid.open_dsm(tif(tmp_path, a.astype(dtype), nodata=declared))
    text = grid.undeclared_nodata_warning(info, info.read())
    if warned:
        assert f"12 cell(s) hold {value:g}, a common nodata value" in text and f"-a_nodata {value:g}" in text
    else:
        assert text is None


@pytest.mark.parametrize("name,cells", [
    ("within the terrain's relief", {(0, 0): -9999.0, (1, 1): -9000.0}),   # -9999 less far below than the span
    ("no such value", {(0, 0): -500.0}),
    ("sea level beside a shore rising from 0.5 m", {(0, 0): 0.0, (0, 1): 0.0, (1, 1): 0.5}),   # 0 is also a height
    ("every cell", None),
])
def test_common_nodata_value_within_the_heights_not_warned(tmp_path, name, cells):
    a = np.full((6, 8), 300.0, np.float32)
    if cells is None:
        a[:] = -9999.0
    else:
        for rc, v in cells.items():
            a[rc] = v
    info = grid.open_dsm(tif(tmp_path, a))
    assert grid.undeclared_nodata_warning(info, info.read()) is None


def _with_unit(path, unit):
    ds = gdal.Open(str(path), gdal.GA_Update)
    ds.GetRasterBand(1).SetUnitType(unit)
    ds = None
    return path


@pytest.mark.parametrize("crs,unit,z_to_m,warned", [
    (32633, "ft", 0.3048, True),              # a UTM grid whose band says its heights are in feet
    (32633, "US survey foot", 1200.0 / 3937.0, True),
    (2263, "m", 1.0, True),                   # a state plane grid in US feet with heights in metres
    (2263, "", 1200.0 / 3937.0, False),       # no unit stated: the CRS's
    (32633, "metre", 1.0, False),
    (32633, "furlong", 1.0, False),           # not a unit heights come in: the CRS's
])
def test_the_bands_stated_height_unit_wins_over_the_crs(tmp_path, crs, unit, z_to_m, warned):
    """GDAL's unit type of the band (gdal_edit.py -units ft) says what its values are in: a UTM DSM
    whose heights are in feet was read as metres (objects 6 ft high read as 6 m), a grid in US feet
    with heights in metres as feet."""
    a = np.full((6, 8), 1000.0, np.float32)
    info = grid.open_dsm(_with_unit(tif(tmp_path, a, crs=crs), unit))
    assert info.z_to_m == pytest.approx(z_to_m, rel=1e-12)
    np.testing.assert_allclose(info.read(), 1000.0 * z_to_m, rtol=1e-6)
    said = [w for w in info.warnings if "The band states its heights are in" in w]
    assert bool(said) == warned and (not warned or f"'{unit}'" in said[0])


def test_outputs_of_a_dsm_in_stated_feet_are_in_feet(tmp_path):
    """The mask of a DSM whose band says feet is the mask of the same DSM in metres, its DTM is
    written back in feet."""
    from bare_earth.core import pipeline
    from bare_earth.core.synthetic import make_scene
    sc = make_scene("city", shape=(90, 100), seed=3)
    metres = tif(tmp_path, sc.dsm.astype(np.float32), gt=sc.geotransform, crs=sc.epsg, name="m.tif")
    feet = _with_unit(tif(tmp_path, (sc.dsm / 0.3048).astype(np.float32), gt=sc.geotransform, crs=sc.epsg,
                          name="ft.tif"), "ft")
    for src, name in ((metres, "m"), (feet, "ft")):
        pipeline.run_file("slopeprofile", src, {"mask": tmp_path / f"mask_{name}.tif",
                                                "dtm": tmp_path / f"dtm_{name}.tif"})
    read = {}
    for name in ("mask_m", "mask_ft", "dtm_m", "dtm_ft"):
        ds = gdal.Open(str(tmp_path / f"{name}.tif"))
        read[name] = ds.ReadAsArray()
        ds = None
    np.testing.assert_array_equal(read["mask_ft"], read["mask_m"])
    np.testing.assert_allclose(read["dtm_ft"] * 0.3048, read["dtm_m"], atol=2e-3)
    ds = gdal.Open(str(tmp_path / "dtm_ft.tif"))
    assert ds.GetRasterBand(1).GetUnitType() == "ft"            # the DTM states it is in feet too
    ds = None


def test_undeclared_nodata_in_feet_and_scaled(tmp_path):
    """The stored -9999 is found whatever the unit and the scale the heights are read with."""
    a = np.full((6, 8), 1000.0, np.float32)
    a[0, :] = -9999.0
    info = grid.open_dsm(tif(tmp_path, a, crs=2263))
    assert "8 cell(s) hold -9999" in grid.undeclared_nodata_warning(info, info.read())
    ds = gdal.Open(tif(tmp_path, np.where(a < 0, -9999.0, a * 10).astype(np.float32), name="s.tif"), gdal.GA_Update)
    ds.GetRasterBand(1).SetScale(0.1)
    ds = None
    info = grid.open_dsm(tmp_path / "s.tif")
    assert "8 cell(s) hold -9999" in grid.undeclared_nodata_warning(info, info.read())


# ---- a raster without geotransform: outputs without one (and with its control points) --------

@pytest.mark.parametrize("with_gcps", [False, True])
def test_outputs_of_a_raster_without_geotransform_have_none(tmp_path, with_gcps):
    """Outputs of a raster without a geotransform were given 1 m cells from (0, rows), which GIS
    draws elsewhere than the input (QGIS: input 0..-rows, outputs 0..+rows); they now carry no
    geotransform, as the input, and its ground control points when it has some."""
    path = str(tmp_path / "nogeo.tif")
    ds = gdal.GetDriverByName("GTiff").Create(path, 6, 5, 1, gdal.GDT_Float32)
    ds.GetRasterBand(1).WriteArray(np.arange(30, dtype=np.float32).reshape(5, 6))
    if with_gcps:
        gcps = [gdal.GCP(500000.0 + 2 * p, 4000000.0 - 2 * q, 0.0, p, q) for p, q in ((0, 0), (6, 0), (0, 5))]
        ds.SetGCPs(gcps, wkt(32633))
    ds = None
    info = grid.open_dsm(path)
    assert not info.georeferenced and any("no georeference" in w for w in info.warnings)
    with grid.OutputSet(info) as out:
        out.add("dtm", tmp_path / "d.tif", "Float32")
        out.write("dtm", np.zeros((5, 6), np.float32))
        out.commit()
    src, res = gdal.Open(path), gdal.Open(str(tmp_path / "d.tif"))
    assert res.GetGeoTransform(can_return_null=True) is None
    assert [(g.GCPX, g.GCPY, g.GCPPixel, g.GCPLine) for g in res.GetGCPs()] == \
        [(g.GCPX, g.GCPY, g.GCPPixel, g.GCPLine) for g in src.GetGCPs()]
    assert len(res.GetGCPs()) == (3 if with_gcps else 0)


def test_alpha_band_read_through_a_vrt_mosaic(tmp_path):
    """A VRT over tiles with a Float32 alpha band (a survey's mosaic) reads their transparent
    cells as NaN in its alpha band: nodata too (they were valid heights of 0)."""
    z = np.arange(30, dtype=np.float32).reshape(5, 6) + 100
    alpha = np.full(z.shape, 255, np.float32)
    alpha[:, :2] = 0
    z[:, :2] = 0
    p = _with_alpha(tmp_path, z, alpha)
    vrt = str(tmp_path / "mosaic.vrt")
    gdal.BuildVRT(vrt, [p], VRTNodata="nan")
    ds = gdal.Open(vrt)
    assert np.isnan(ds.GetRasterBand(2).ReadAsArray()[:, :2]).all()
    ds = None
    expect = z.copy()
    expect[:, :2] = np.nan
    np.testing.assert_array_equal(grid.open_dsm(vrt).read(), expect)


def test_crs_given_for_a_file_without_one(tmp_path):
    """``crs_wkt`` (the CRS a QGIS layer was given) is used for a file without a CRS of its own,
    its feet converted; a file's own CRS wins."""
    a = np.full((4, 4), 10.0, np.float32)
    gt = (300000.0, 3.0, 0.0, 60000.0, 0.0, -3.0)
    info = grid.open_dsm(tif(tmp_path, a, gt=gt, crs=""), crs_wkt=wkt(2263))
    assert info.z_to_m == pytest.approx(FT_US) and info.cell_size_m == pytest.approx((3 * FT_US, 3 * FT_US))
    assert info.crs_wkt == wkt(2263) and any("CRS its layer was given" in w for w in info.warnings)
    info = grid.open_dsm(tif(tmp_path, a, name="own.tif", gt=gt, crs=32633), crs_wkt=wkt(2263))
    assert info.z_to_m == 1.0 and "2263" not in info.crs_wkt


def test_gdal_mode_kept_across_threads():
    """Two runs in threads overlapping (QGIS's background tasks): GDAL's one process-wide mode stays on
    until the last run ends, then goes back to the session's (the first run leaving must not turn it
    off under the other, and the other must not restore the mode the first had set)."""
    import threading

    from osgeo import gdal
    old = gdal.GetUseExceptions()
    gdal.DontUseExceptions()
    a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()
    seen = {}

    def run_a():
        with grid.gdal_mode_kept():
            a_in.set()
            b_in.wait(5)
        a_out.set()

    def run_b():
        a_in.wait(5)
        with grid.gdal_mode_kept():
            b_in.set()
            a_out.wait(5)
            seen["b after a left"] = gdal.GetUseExceptions()

    try:
        threads = [threading.Thread(target=f) for f in (run_a, run_b)]
        [t.start() for t in threads]
        [t.join(10) for t in threads]
        seen["after both"] = gdal.GetUseExceptions()
    finally:
        (gdal.UseExceptions if old else gdal.DontUseExceptions)()
    assert seen == {"b after a left": 1, "after both": 0}


def test_bounded_cache_across_threads():
    """Two block-mode runs overlapping in threads: GDAL's one cache size stays capped until the last ends,
    then is the session's again (the second run must not put back the cap it found)."""
    import threading

    from osgeo import gdal
    old = gdal.GetCacheMax()
    gdal.SetCacheMax(512 * 2 ** 20)
    a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()
    seen = {}

    def run_a():
        with grid.bounded_cache(size=64 * 2 ** 20):
            a_in.set()
            b_in.wait(5)
        a_out.set()

    def run_b():
        a_in.wait(5)
        with grid.bounded_cache(size=64 * 2 ** 20):
            b_in.set()
            a_out.wait(5)
            seen["b after a left"] = gdal.GetCacheMax() // 2 ** 20

    try:
        threads = [threading.Thread(target=f) for f in (run_a, run_b)]
        [t.start() for t in threads]
        [t.join(10) for t in threads]
        seen["after both"] = gdal.GetCacheMax() // 2 ** 20
    finally:
        gdal.SetCacheMax(old)
    assert seen == {"b after a left": 64, "after both": 512}


# ---- a declared nodata value that is also a height ------------------------------------------

@pytest.mark.parametrize("nodata, scale, offset, named", [
    (300.0, None, None, True),       # whole-metre heights 296-305 m: 300 is one of them
    (-9999.0, None, None, False),    # below every height, as software writes it
    (290.0, None, None, False),      # below the 1st percentile
    (306.0, None, None, False),      # above the 99th
    (float("nan"), None, None, False),
    (0.0, 0.5, 300.0, True),         # stored 0 read as 300 m through the band's scale and offset
])
def test_declared_nodata_among_the_heights_named(tmp_path, nodata, scale, offset, named):
    """A declared nodata value lying among the heights (between their 1st and 99th percentiles)
    is named with the count of cells read as nodata and what to do; one below or above them,
    or NaN, is not."""
    rng = np.random.default_rng(3)
    heights = np.round(rng.uniform(296.0, 305.0, (40, 50))).astype(np.float32)
    stored = heights if scale is None else (heights - offset) / scale
    src = tif(tmp_path, stored, nodata=nodata)
    if scale is not None:
        from osgeo import gdal
        ds = gdal.Open(src, gdal.GA_Update)
        ds.GetRasterBand(1).SetScale(scale)
        ds.GetRasterBand(1).SetOffset(offset)
        ds = None
    info = grid.open_dsm(src)
    z = info.read()
    said = grid.nodata_among_heights_warning(info, z)
    assert (said is not None) == named, said
    if named:
        n = int(np.count_nonzero(heights == 300.0))
        assert n > 0 and f"({n} cell(s) read as nodata)" in said
        assert "lies among its heights" in said and "(e.g. -9999)" in said
        assert ("a height of 300 m" in said) == (scale is not None)


@pytest.mark.parametrize("nodata, scale, offset, dtype, out", [
    (0.0, 0.01, -100.0, "UInt16", -100.0),      # stored 0 is also a height (the stored 10000 is 0 m)
    (-32768.0, 0.1, 100.0, "Int16", -32768.0),  # no height of the band: kept
    (0.0, 1.0, 0.0, "UInt16", 0.0),             # no scale: kept
    (0.0, 0.5, 10.0, "Float32", 10.0),          # a float band holds any height
    (float("nan"), 0.5, 10.0, "Float32", float("nan")),
])
def test_float_outputs_of_a_scaled_band_declare_a_nodata_no_height_has(nodata, scale, offset, dtype, out):
    """The DTM and nDSM hold heights (stored x scale + offset): a band's stored nodata that is
    also one of its heights gives way to the height of the nodata cells, and the log says so."""
    got = grid.float_output_nodata(nodata, scale, offset, dtype)
    assert (math.isnan(got) and math.isnan(out)) or got == out
    note = grid.nodata_not_kept(nodata, scale, offset, dtype)
    changed = not math.isnan(out) and out != nodata
    assert (note is not None and f"declare the height of the nodata cells, {out:g}" in note) if changed else \
        note is None


def test_rounding_rotation_terms_read_as_north_up_a_real_rotation_refused(tmp_path):
    """QA 13: rotation terms of 1e-13 (a reprojection's rounding) were refused as "rotated: warp
    it", which resamples the DSM for nothing; terms moving a cell by a thousandth across the grid
    are no rotation (common.is_rotated), and a real one is still refused before work."""
    a = np.arange(20, dtype=np.float32).reshape(5, 4)
    info = grid.open_dsm(tif(tmp_path, a, gt=(500000.0, 2.0, 1e-13, 5000000.0, -1e-13, -2.0)))
    assert info.cell_size_m == (2.0, 2.0)
    np.testing.assert_array_equal(info.read(), a)
    with pytest.raises(ValueError, match="rotated"):
        grid.open_dsm(tif(tmp_path, a, name="rot.tif", gt=(500000.0, 2.0, 0.01, 5000000.0, 0.0, -2.0)))
