"""The write side of core.grid: formats by extension, work files, stale leftovers, long names,
creation options and the cloud-optimised GeoTIFF."""
import os
import re
import stat
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from bare_earth.core import grid
from bare_earth.core.codes import NODATA

gdal = pytest.importorskip("osgeo.gdal")
GT = (500000.0, 0.5, 0.0, 5400000.0, 0.0, -0.5)


def _info(tmp_path):
    src = grid.write_array(tmp_path / "dsm.tif", np.zeros((6, 7), np.float32), GT, 32632)
    return grid.open_dsm(src)


def _scene():
    d = (np.arange(42, dtype=np.float32).reshape(6, 7) * 0.25 + 100).astype(np.float32)
    d[0, 0] = np.nan
    m = np.array([[0, 1, 2, 255, 0, 1, 2]] * 6, np.uint8)
    return d, m


def _read(path):
    ds = gdal.Open(str(path))
    a = ds.GetRasterBand(1).ReadAsArray()
    ds = None
    return a


def _partials(folder):
    return sorted(p for p in os.listdir(folder) if ".partial" in p)


def _write(info, outputs, **kw):
    d, m = _scene()
    with grid.OutputSet(info) as out:
        for key, path in outputs.items():
            if key == "mask":
                out.add(key, path, "Byte", nodata=NODATA, mask_style=True)
                out.write(key, m)
            else:
                out.add(key, path, "Float32", nodata=float("nan"), **kw)
                out.write(key, d)
        out.commit()
    return d, m


@pytest.mark.parametrize("ext,driver", [(".tif", "GTiff"), (".img", "HFA"), (".sdat", "SAGA"),
                                        (".asc", "AAIGrid"), (".nc", "netCDF"), (".gpkg", "GPKG")])
def test_each_offered_format_is_written_in_that_format(tmp_path, ext, driver):
    if gdal.GetDriverByName(driver) is None:
        pytest.skip(f"GDAL has no {driver} driver")
    info = _info(tmp_path)
    d, m = _write(info, {"dtm": tmp_path / f"dtm{ext}", "mask": tmp_path / f"mask{ext}"})
    for name, want in (("dtm", d), ("mask", m)):
        ds = gdal.Open(str(tmp_path / f"{name}{ext}"))
        assert ds.GetDriver().ShortName == driver
        got = ds.GetRasterBand(1).ReadAsArray()
        np.testing.assert_allclose(got[np.isfinite(want)], want[np.isfinite(want)], atol=1e-4)
        assert np.allclose(ds.GetGeoTransform(), GT)
        ds = None
    assert _partials(tmp_path) == []
    assert (tmp_path / "mask.qml").exists()


KM_CRS = ('PROJCS["UTM 32N in km",GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563]],'
          'PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433]],PROJECTION["Transverse_Mercator"],'
          'PARAMETER["latitude_of_origin",0],PARAMETER["central_meridian",9],PARAMETER["scale_factor",0.9996],'
          'PARAMETER["false_easting",500],PARAMETER["false_northing",0],UNIT["kilometre",1000]]')


def _run_into(tmp_path, crs, gt, out, seen):
    """pipeline.run_file of a small ramp in ``crs`` into the output ``out``, its progress put in ``seen``."""
    from bare_earth.core import pipeline
    z = (np.add.outer(np.arange(40.0), np.arange(40.0)) * 1e-4 + 0.3).astype(np.float32)
    src = grid.write_array(tmp_path / "dsm.tif", z, gt, crs)
    try:
        pipeline.run_file("morphological", src, {"dtm": str(tmp_path / out)}, progress=seen.append)
    finally:
        assert _partials(tmp_path) == []


def test_a_geopackage_that_would_write_the_crs_in_other_units_refused_before_work(tmp_path):
    """A DSM in a transverse Mercator in kilometres on a UTM zone's parameters: GDAL's GeoPackage copy
    wrote it as EPSG:32632, in metres, so the output lay 1000 x too close to the origin (the .tif kept
    its CRS). Refused before any work, naming both CRSs; a GeoTIFF output runs."""
    gt = (500.0, 0.001, 0.0, 5400.0, 0.0, -0.001)
    with pytest.raises(ValueError, match=r"dtm\.gpkg' is a GeoPackage, but GDAL writes its CRS \(UTM 32N in km, "
                                         r"in kilomet.*as WGS 84 / UTM zone 32N \(in metre\).*GeoTIFF"):
        _run_into(tmp_path, KM_CRS, gt, "dtm.gpkg", [])
    assert not (tmp_path / "dtm.gpkg").exists()
    _run_into(tmp_path, KM_CRS, gt, "dtm.tif", [])
    ds = gdal.Open(str(tmp_path / "dtm.tif"))
    assert "kilomet" in ds.GetProjection()
    ds = None


def test_a_format_gdal_cannot_write_the_crs_in_refused_before_work(tmp_path):
    """Swiss LV95 (EPSG:2056, an oblique Mercator) as netCDF: GDAL's copy failed after the whole run
    with an empty message ('cannot write the output ... as netCDF: '). Refused before the filter
    starts, with GDAL's reason; the other formats keep the CRS."""
    if gdal.GetDriverByName("netCDF") is None:
        pytest.skip("GDAL has no netCDF driver")
    gt = (2600000.0, 1.0, 0.0, 1200000.0, 0.0, -1.0)
    seen = []
    with pytest.raises(ValueError, match=r"dtm\.nc' is a netCDF, but GDAL cannot write its CRS in that format "
                                         r"\(.+\)\. Write it as a GeoTIFF"):
        _run_into(tmp_path, 2056, gt, "dtm.nc", seen)
    assert seen == [] and not (tmp_path / "dtm.nc").exists()
    for ext in (".gpkg", ".img", ".asc"):
        grid.check_output_crs(tmp_path / f"dtm{ext}", grid.open_dsm(tmp_path / "dsm.tif").crs_wkt, gt)


def test_saga_grid_readable_and_nothing_left_behind(tmp_path):
    info = _info(tmp_path)
    _write(info, {"dtm": tmp_path / "dtm.sdat"})
    ds = gdal.Open(str(tmp_path / "dtm.sdat"))
    assert ds.GetDriver().ShortName == "SAGA" and (tmp_path / "dtm.sgrd").exists()
    assert {"dtm.sdat", "dtm.sgrd"} <= {os.path.basename(f) for f in ds.GetFileList()}
    assert not [p for p in os.listdir(tmp_path) if "partial" in p]


@pytest.mark.parametrize("ext", [".vrt", ".xyz", ".png", ".jpg"])
def test_formats_not_offered_are_refused_naming_the_offered_ones(tmp_path, ext):
    with pytest.raises(ValueError, match=r"Formats offered: GeoTIFF \(\.tif, \.tiff\)"):
        grid.check_output_path(tmp_path / f"dtm{ext}")
    with pytest.raises(ValueError, match="Formats offered"):
        _write(_info(tmp_path), {"dtm": tmp_path / f"dtm{ext}"})
    assert not (tmp_path / f"dtm{ext}").exists() and _partials(tmp_path) == []


def test_single_band_formats_refuse_two_bands(tmp_path):
    with pytest.raises(ValueError, match="2 bands.*holds 1"):
        grid.check_output_path(tmp_path / "curv.asc", bands=2)
    grid.check_output_path(tmp_path / "curv.tif", bands=2)


def test_a_folder_where_a_side_file_goes_refused(tmp_path):
    """QA14: a folder named as a file an output writes beside it (the .aux.xml, a SAGA grid's .sgrd, a mask's
    .qml style) was found only once the work was done; the .qml only for a styled output (a mask)."""
    for side, out, styled in (("dtm.tif.aux.xml", "dtm.tif", False), ("dtm.sgrd", "dtm.sdat", False),
                              ("mask.qml", "mask.tif", True)):
        (tmp_path / side).mkdir()
        with pytest.raises(ValueError, match=rf"writes '{side}' beside it, but '{tmp_path / side}' is a folder"):
            grid.check_output_path(tmp_path / out, styled=styled)
    grid.check_output_path(tmp_path / "mask.tif")      # a DTM named mask.tif writes no style


def test_missing_or_unwritable_folder_refused_naming_it(tmp_path):
    missing = tmp_path / "no" / "such"
    with pytest.raises(ValueError, match=f"output folder '{missing}' does not exist"):
        grid.check_output_path(missing / "dtm.tif")
    with pytest.raises(ValueError, match="output folder '/proc' is not writable"):
        grid.check_output_path("/proc/dtm.tif")


def test_long_valid_name_is_written(tmp_path):
    limit = os.pathconf(tmp_path, "PC_NAME_MAX")
    long_dtm = tmp_path / ("d" * (limit - 4) + ".tif")         # the longest valid name
    long_mask = tmp_path / ("m" * (limit - 5) + ".tiff")
    grid.check_output_path(long_dtm)
    d, m = _write(_info(tmp_path), {"dtm": long_dtm, "mask": long_mask})
    assert _read(long_dtm)[1, 1] == d[1, 1]
    assert (_read(long_mask) == m).all()
    assert _partials(tmp_path) == []
    with pytest.raises(ValueError, match="file name is"):
        grid.check_output_path(tmp_path / ("x" * limit + ".tif"))


def test_work_files_are_hidden_and_not_named_as_rasters(tmp_path):
    info = _info(tmp_path)
    out = grid.OutputSet(info)
    out.add("dtm", tmp_path / "dtm.tif", "Float32")
    (work,) = _partials(tmp_path)
    assert work.startswith(".dtm.") and work.endswith(".partial")
    out.discard()
    assert _partials(tmp_path) == []


KILLED_RUN = textwrap.dedent("""
    import os, sys
    sys.path.insert(0, {plugins!r})
    import numpy as np
    from bare_earth.core import grid
    info = grid.open_dsm({dsm!r})
    out = grid.OutputSet(info)
    out.add("dtm", {dtm!r}, "Float32")
    out.write("dtm", np.ones(info.shape, np.float32))
    out.flush()
    os._exit(9)                                    # killed: no discard, no commit
""")


def test_killed_run_leftovers_removed_by_the_next_run_of_that_output(tmp_path):
    info = _info(tmp_path)
    # grid.__file__ is .build/plugins/bare_earth/core/grid/__init__.py
    plugins = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(grid.__file__))))
    code = KILLED_RUN.format(plugins=plugins, dsm=info.path, dtm=str(tmp_path / "dtm.tif"))
    assert subprocess.run([sys.executable, "-c", code]).returncode == 9
    (left,) = _partials(tmp_path)
    assert gdal.Open(str(tmp_path / left)) is not None           # GDAL would open it: it must go
    (tmp_path / "dtm.partial-0123abcd.tif").write_bytes(b"old")  # an older version's leftover
    other = tmp_path / f".other.{os.getppid():010d}-0123abcd.partial"   # another output's, alive
    other.write_bytes(b"x")
    _write(info, {"dtm": tmp_path / "dtm.tif"})
    assert _partials(tmp_path) == [other.name]
    assert _read(tmp_path / "dtm.tif")[1, 1] == 100.25 + 0.25 * 7


def test_killed_runs_leftovers_of_other_outputs_removed_when_their_process_is_gone(tmp_path):
    """A run killed (SIGTERM, a crash) while writing ``b.tif`` leaves ``.b.<pid>-<hex>.partial`` and its
    sidecar; the next run writing anything into that folder removes them once that pid is gone. Work
    files of running processes, this process's own and any name off the writer's exact pattern stay."""
    info = _info(tmp_path)
    plugins = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(grid.__file__))))
    code = KILLED_RUN.format(plugins=plugins, dsm=info.path, dtm=str(tmp_path / "b.tif"))
    assert subprocess.run([sys.executable, "-c", code]).returncode == 9
    (left,) = _partials(tmp_path)
    (tmp_path / (left + ".aux.xml")).write_text("<PAMDataset/>")        # its sidecar
    alive = f".c.{os.getppid():010d}-0123abcd.partial"                  # another run's, still running
    mine = f".d.{os.getpid():010d}-0123abcd.partial"                    # this process's, another output
    kept = [alive, mine, ".e.12345-0123abcd.partial", ".e.0000012345-0123abcd.partials",
            "e.0000012345-0123abcd.partial", ".e.0000012345-0123ABCD.partial", "f.partial", "g.partial.tif"]
    for name in kept:
        (tmp_path / name).write_bytes(b"x")
    _write(info, {"dtm": tmp_path / "a.tif"})
    assert _partials(tmp_path) == sorted(kept)
    assert _read(tmp_path / "a.tif")[1, 1] == 100.25 + 0.25 * 7


def test_a_running_output_is_not_taken_for_a_leftover(tmp_path):
    info = _info(tmp_path)
    with grid.OutputSet(info) as first:
        first.add("dtm", tmp_path / "dtm.tif", "Float32")
        assert grid.remove_stale_partials(tmp_path / "dtm.tif") == []
        assert len(_partials(tmp_path)) == 1


def test_output_equal_to_input_or_shared_path_refused(tmp_path):
    info = _info(tmp_path)
    with grid.OutputSet(info) as out, pytest.raises(ValueError, match="is the input raster"):
        out.add("dtm", info.path, "Float32")
    with grid.OutputSet(info) as out, pytest.raises(ValueError, match="have one path"):
        out.add("dtm", tmp_path / "a.tif", "Float32")
        out.add("mask", tmp_path / "a.tif", "Byte")
    assert _partials(tmp_path) == []


def test_creation_options_and_cloud_optimised_geotiff(tmp_path):
    info = _info(tmp_path)
    opts = grid.parse_creation_options("COMPRESS=LZW|PREDICTOR=2")
    with grid.write_options(opts):
        _write(info, {"dtm": tmp_path / "lzw.tif"})
    ds = gdal.Open(str(tmp_path / "lzw.tif"))
    assert ds.GetMetadata("IMAGE_STRUCTURE")["COMPRESSION"] == "LZW"
    with grid.write_options(cog=True):
        _write(info, {"dtm": tmp_path / "cog.tif", "mask": tmp_path / "cogmask.tif"})
    ds = gdal.Open(str(tmp_path / "cog.tif"))
    assert ds.GetMetadata("IMAGE_STRUCTURE").get("LAYOUT") == "COG"
    ds = gdal.Open(str(tmp_path / "cogmask.tif"))
    assert ds.GetRasterBand(1).GetColorTable() is not None
    assert _partials(tmp_path) == []
    with pytest.raises(ValueError, match="allowed values"):
        grid.parse_creation_options("COMPRESS=NOPE")
    with pytest.raises(ValueError, match="no creation option 'FOO'"):
        grid.parse_creation_options("FOO=1")
    with pytest.raises(ValueError, match="KEY=VALUE"):
        grid.parse_creation_options("COMPRESS")


@pytest.mark.parametrize("text", ["COMPRESS=ZSTD;PREDICTOR=3", " COMPRESS = ZSTD | PREDICTOR = 3 ",
                                  "COMPRESS=ZSTD PREDICTOR=3", "COMPRESS=ZSTD|PREDICTOR=3|"])
def test_creation_options_separated_as_users_type_them(text):
    """';' (as the tiles' PARAMETERS take) and spaces around '=' read as the options they are;
    they were refused as 'COMPRESS=ZSTD;PREDICTOR=3: allowed values are NONE, LZW, ...' and
    "'COMPRESS' is not KEY=VALUE"."""
    assert grid.parse_creation_options(text) == ["COMPRESS=ZSTD", "PREDICTOR=3"]


def test_mask_palette_names_only_the_mask_codes(tmp_path):
    from bare_earth.core.codes import MASK_CODES, MASK_COLOURS
    _write(_info(tmp_path), {"mask": tmp_path / "mask.tif"})
    ds = gdal.Open(str(tmp_path / "mask.tif"))
    b = ds.GetRasterBand(1)
    ct = b.GetColorTable()
    names = b.GetCategoryNames()
    for code in range(ct.GetCount()):    # a TIFF palette holds 256 RGB entries: only 4 are named
        if code in MASK_CODES:
            assert ct.GetColorEntry(code)[:3] == MASK_COLOURS[code][:3] and names[code] == MASK_CODES[code]
        else:
            assert not names[code]


@pytest.mark.parametrize("ext,driver,gt", [(".asc", "AAIGrid", (500.0, 2.0, 0.0, 900.0, 0.0, -1.0)),
                                           (".sdat", "SAGA", (500.0, 2.0, 0.0, 900.0, 0.0, -2.0)),
                                           (".img", "HFA", (500.0, 2.0, 0.0, 900.0, 0.0, -2.0))])
def test_text_header_formats_declare_a_finite_nodata_for_nan(tmp_path, ext, driver, gt):
    # ESRI's ASCII grid and SAGA carry the nodata as text other software reads: "nan" there is
    # not a number to them. The NaN cells become -9999, declared as the nodata; the heights
    # are copied exactly (no CRS; non-square cells where the format holds them). QA24: an ERDAS
    # Imagine file declaring NaN made GDAL warn "NaN converted to INT_MAX" at every open.
    if gdal.GetDriverByName(driver) is None:
        pytest.skip(f"GDAL has no {driver} driver")
    z = np.random.default_rng(3).normal(100.0, 30.0, (23, 17)).astype(np.float32)
    z[3, 4] = z[0, 0] = z[22, 16] = np.nan
    info = grid.open_dsm(grid.write_array(tmp_path / "dsm.tif", np.zeros(z.shape, np.float32), gt))
    with grid.OutputSet(info) as out:
        out.add("dtm", tmp_path / f"dtm{ext}", "Float32", nodata=float("nan"))
        out.write("dtm", z)
        out.commit()
    said = []
    gdal.PushErrorHandler(lambda cls, no, msg: said.append(msg))
    try:
        ds = gdal.Open(str(tmp_path / f"dtm{ext}"))
        nodata = ds.GetRasterBand(1).GetNoDataValue()
        ds = None
        ds = gdal.Open(str(tmp_path / f"dtm{ext}"))
    finally:
        gdal.PopErrorHandler()
    assert said == []
    assert ds.GetDriver().ShortName == driver
    assert nodata == grid.TEXT_NODATA
    got = ds.GetRasterBand(1).ReadAsArray()
    np.testing.assert_array_equal(got == grid.TEXT_NODATA, np.isnan(z))
    np.testing.assert_allclose(got[~np.isnan(z)], z[~np.isnan(z)], rtol=1e-6)
    assert np.allclose(ds.GetGeoTransform(), gt)
    if driver == "AAIGrid":
        assert "nan" not in (tmp_path / "dtm.asc").read_text().lower()
    assert _partials(tmp_path) == [] and not gdal.ReadDir("/vsimem/")


def test_text_nodata_steps_below_heights_that_reach_it(tmp_path):
    ds = gdal.GetDriverByName("MEM").Create("", 3, 1, 1, gdal.GDT_Float32)
    ds.GetRasterBand(1).SetNoDataValue(float("nan"))
    ds.GetRasterBand(1).WriteArray(np.array([[-12000.0, np.nan, 5.0]], np.float32))
    assert grid.finite_text_nodata(ds) == -99999.0
    ds.GetRasterBand(1).WriteArray(np.full((1, 3), np.nan, np.float32))
    assert grid.finite_text_nodata(ds) == grid.TEXT_NODATA


def test_saga_output_of_non_square_cells_is_refused_before_any_work(tmp_path):
    from bare_earth.core.pipeline import run_file
    z = np.random.default_rng(1).normal(50.0, 1.0, (40, 30)).astype(np.float32)
    src = grid.write_array(tmp_path / "dsm.tif", z, (0.0, 2.0, 0.0, 80.0, 0.0, -1.0), 32632)
    with pytest.raises(ValueError, match=r"square cells only, but the input's cells are 2 x 1.*GeoTIFF"):
        run_file("morphological", src, {"dtm": str(tmp_path / "dtm.sdat"), "mask": str(tmp_path / "m.tif")})
    assert sorted(os.listdir(tmp_path)) == ["dsm.tif"]
    grid.check_output_cells(tmp_path / "dtm.sdat", (0.0, 2.0, 0.0, 80.0, 0.0, -2.0))   # square: accepted
    grid.check_output_cells(tmp_path / "dtm.asc", (0.0, 2.0, 0.0, 80.0, 0.0, -1.0))    # ASCII holds dx, dy


@pytest.mark.parametrize("text,cog,message", [
    ("NBITS=1", False, r"change the values of a UInt8 output"),                 # the mask's 255 read back as 1
    ("PIXELTYPE=SIGNEDBYTE", False, r"change the values of a UInt8 output"),    # 255 read as -1
    ("DISCARD_LSB=1", False, r"change the values of a UInt8 output"),
    ("COMPRESS=LERC|MAX_Z_ERROR=1", False, r"change the values of a UInt8 output"),
    ("COMPRESS=LERC|MAX_Z_ERROR=1", True, r"change the values of a UInt8 output"),
    ("BLOCKXSIZE=100", False, r"cannot write a Float32 output .*'BLOCKXSIZE=100'.*TileWidth"),
    ("BLOCKSIZE=100", True, r"cannot write a Float32 output .*'BLOCKSIZE=100'"),
    ("COMPRESS=JPEG", False, r"cannot write a Float32 output .*'COMPRESS=JPEG'.*JPEG"),
])
def test_creation_options_refused_when_gdal_fails_or_changes_the_codes(text, cog, message):
    """Options GDAL accepts by name but refuses when it creates the file (the run failed after its
    work), or that silently change a UInt8 output's codes (the mask written with NBITS=1 held 0
    and 1 only), are refused when parsed, before any work."""
    with pytest.raises(ValueError, match=message):
        grid.parse_creation_options(text, cog=cog)
    assert gdal.ReadDir("/vsimem/") in (None, []) or not any("probe" in f for f in gdal.ReadDir("/vsimem/"))


@pytest.mark.parametrize("text,cog", [("COMPRESS=ZSTD|PREDICTOR=3|ZLEVEL=9", False),
                                      ("COMPRESS=LERC|MAX_Z_ERROR=0.01", False),
                                      ("COMPRESS=DEFLATE|PREDICTOR=FLOATING_POINT", True)])
def test_float_predictor_and_lossless_options_write_the_mask_exactly(tmp_path, text, cog):
    """The floating-point predictor asked for the DTM is horizontal differencing on the UInt8
    mask (GDAL refuses PREDICTOR=3 there: the run failed after its work); the codes are exact."""
    info = _info(tmp_path)
    with grid.write_options(grid.parse_creation_options(text, cog=cog), cog):
        d, m = _write(info, {"dtm": tmp_path / "d.tif", "mask": tmp_path / "m.tif"})
    got_m, got_d = _read(tmp_path / "m.tif"), _read(tmp_path / "d.tif")
    np.testing.assert_array_equal(got_m, m)
    np.testing.assert_allclose(got_d, d, atol=0.011)


def test_a_read_only_output_is_refused_and_no_output_replaced(tmp_path, read_only):
    """An existing output that cannot be replaced: refused by the output checks (before any work)
    and, should it become so during the run, at commit before any output moves (a DTM from
    this run beside a mask from the last was left, with a PermissionError traceback)."""
    info = _info(tmp_path)
    for name in ("d.tif", "m.tif"):
        (tmp_path / name).write_bytes(b"old")
    with read_only(tmp_path / "m.tif"):
        with pytest.raises(ValueError, match=r"'.*m\.tif' exists and is read-only"):
            grid.check_output_path(tmp_path / "m.tif")
        grid.check_output_path(tmp_path / "d.tif")
        with pytest.raises(ValueError, match=r"'.*m\.tif' exists and is read-only"):
            _write(info, {"dtm": tmp_path / "d.tif", "mask": tmp_path / "m.tif"})
        assert (tmp_path / "d.tif").read_bytes() == b"old"
        assert (tmp_path / "m.tif").read_bytes() == b"old"
        assert _partials(tmp_path) == []


def test_output_files_name_every_file_an_output_writes(tmp_path):
    """What writing an output creates: its sidecars by format and a mask's style (the checks
    compare them with the inputs' files)."""
    p = str(tmp_path / "x")
    assert grid.output_files(p + ".asc") == [p + ".asc", p + ".asc.aux.xml", p + ".prj"]
    assert grid.output_files(p + ".sdat", styled=True) == [p + ".sdat", p + ".sdat.aux.xml", p + ".sgrd", p + ".prj",
                                                           p + ".qml"]
    assert grid.output_files(p + ".tif") == [p + ".tif", p + ".tif.aux.xml"]
    # every file a real write makes is listed
    info = _info(tmp_path)
    for ext in (".asc", ".sdat", ".img", ".tif"):
        sub = tmp_path / ext[1:]
        sub.mkdir()
        _write(info, {"mask": sub / f"m{ext}"})
        assert {str(f) for f in sub.iterdir()} <= set(grid.output_files(sub / f"m{ext}", styled=True)), ext


@pytest.mark.parametrize("profile,compression", [("COMPRESS=DEFLATE|PREDICTOR=2|ZLEVEL=9", "DEFLATE"),
                                                 ("COMPRESS=LZW|PREDICTOR=2", "LZW"),
                                                 ("COMPRESS=ZSTD|ZSTD_LEVEL=9|PREDICTOR=3|TILED=YES", "ZSTD")])
def test_qgis_compression_profiles_with_cloud_optimised_geotiffs(tmp_path, profile, compression):
    """QGIS's compression profiles (the dialog offers them) are GeoTIFF options: with COG they were
    refused ("PREDICTOR=2: allowed values are YES, NO, STANDARD, FLOATING_POINT"); they are now
    given in the COG driver's words and written."""
    opts = grid.parse_creation_options(profile, cog=True)
    assert not any(o.startswith(("ZLEVEL", "ZSTD_LEVEL", "TILED", "PREDICTOR=2", "PREDICTOR=3")) for o in opts)
    info = _info(tmp_path)
    with grid.write_options(opts, cog=True):
        d, m = _write(info, {"dtm": tmp_path / "d.tif", "mask": tmp_path / "m.tif"})
    for name in ("d.tif", "m.tif"):
        ds = gdal.Open(str(tmp_path / name))
        meta = ds.GetMetadata("IMAGE_STRUCTURE")
        assert meta.get("LAYOUT") == "COG" and meta.get("COMPRESSION") == compression, (name, meta)
        ds = None
    np.testing.assert_array_equal(_read(tmp_path / "m.tif"), m)
    np.testing.assert_array_equal(_read(tmp_path / "d.tif"), d)


def test_check_output_file_refuses_a_folder_and_takes_a_file(tmp_path):
    """A report, table or point output naming a folder was accepted up front and failed after the
    work (IsADirectoryError); a file in a writable folder passes."""
    (tmp_path / "reports").mkdir()
    with pytest.raises(ValueError, match=r"reports' is a folder: give a file name in it \(e.g. '.*/output.csv'\)"):
        grid.check_output_file(tmp_path / "reports", "output.csv")
    grid.check_output_file(tmp_path / "table.csv")
    with pytest.raises(ValueError, match="does not exist"):
        grid.check_output_file(tmp_path / "missing" / "table.csv")
    (tmp_path / "notes").write_text("x")          # a file where the folder should be: it was "does not exist"
    with pytest.raises(ValueError, match=r"folder '.*notes' is a file, not a folder"):
        grid.check_output_file(tmp_path / "notes" / "table.csv")



@pytest.mark.parametrize("check", ["check_output_path", "check_output_file"])
def test_an_output_path_ending_in_a_separator_names_a_folder(tmp_path, check):
    """'out/' (typed as the folder to write in) was written as a file named 'out' while the run returned
    'out/', a path nothing can open; it is refused as a folder, whether or not the folder exists."""
    for folder in (tmp_path / "new", tmp_path):
        with pytest.raises(ValueError, match=r"is a folder: give a file name in it"):
            getattr(grid, check)(str(folder) + os.sep)
    assert sorted(os.listdir(tmp_path)) == []

FULL_DISK_RUN = textwrap.dedent("""
    import os, resource, signal, sys
    sys.path.insert(0, {plugins!r})
    import numpy as np
    from bare_earth.core import grid
    from bare_earth.core.pipeline import run_file
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)     # the write fails (EFBIG), as on a full disk
    resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, resource.RLIM_INFINITY))
    try:
        run_file("morphological", {dsm!r}, {{"dtm": {dtm!r}, "mask": {mask!r}}}, workers={workers})
        print("WROTE")
    except ValueError as exc:
        print("VALUEERROR", exc)
""")


@pytest.mark.parametrize("limit, workers", [(60_000, 1), (60_000, 2), (200_000, 1)])
def test_a_full_disk_is_a_message_naming_the_output_and_leaves_nothing(tmp_path, limit, workers):
    """A write that fails part way (the disk full: here a file-size limit) is a ValueError naming the output
    and the disk (not GDAL's traceback from a writer thread, nor an output closed half-written and moved in
    place); nothing is left in the folder."""
    rng = np.random.default_rng(0)
    dsm = grid.write_array(tmp_path / "dsm.tif", (100 + rng.normal(0, 1, (512, 512))).astype(np.float32), GT, 32632)
    out = tmp_path / "out"
    out.mkdir()
    plugins = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(grid.__file__))))
    code = FULL_DISK_RUN.format(plugins=plugins, dsm=dsm, dtm=str(out / "dtm.tif"), mask=str(out / "mask.tif"),
                                limit=limit, workers=workers)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert res.stdout.startswith("VALUEERROR cannot write the output"), res.stdout + res.stderr[-2000:]
    assert "dtm.tif" in res.stdout and "disk" in res.stdout
    assert os.listdir(out) == []


def test_geopackage_outputs_are_exact_and_named_after_their_file(tmp_path):
    """A GeoPackage raster output (refused before, saying GDAL could not copy Float32 or a palette into
    one, which it can): the DTM's heights (its NaN nodata as -9999) and the mask's codes, 255 nodata and
    palette read back exactly, in a raster table named after the file (not after the hidden work file)."""
    info = _info(tmp_path)
    d, m = _write(info, {"dtm": tmp_path / "my dtm.gpkg", "mask": tmp_path / "mask.gpkg"})
    for name, want in (("my dtm", d), ("mask", m)):
        ds = gdal.Open(str(tmp_path / f"{name}.gpkg"))
        assert ds.GetDriver().ShortName == "GPKG" and ds.RasterCount == 1
        assert ds.GetMetadataItem("IDENTIFIER") == name
        b = ds.GetRasterBand(1)
        nd = b.GetNoDataValue()    # a GeoPackage records no NaN nodata: the DTM's is -9999, as in text grids
        assert nd == (NODATA if name == "mask" else -9999.0) and b.DataType == (gdal.GDT_Byte if name == "mask"
                                                                                 else gdal.GDT_Float32)
        np.testing.assert_array_equal(b.ReadAsArray(), np.where(np.isnan(want), nd, want))
        assert np.allclose(ds.GetGeoTransform(), GT)
        ds = None
    ds = gdal.Open(str(tmp_path / "mask.gpkg"))
    ct = ds.GetRasterBand(1).GetColorTable()
    assert ct is not None and ct.GetCount() >= 4
    ct = ds = None
    assert sorted(os.listdir(tmp_path)) == ["dsm.tif", "mask.gpkg", "mask.qml", "my dtm.gpkg"]


def test_a_geopackage_holding_other_layers_is_refused_and_kept(tmp_path):
    """Writing an output replaces its file: an existing GeoPackage holding anything else (a vector layer,
    another raster table) would lose it, so it is refused before any work and left as it was; a
    GeoPackage from an earlier run of the same output is replaced."""
    ogr = pytest.importorskip("osgeo.ogr")
    store = tmp_path / "project.gpkg"
    ds = ogr.GetDriverByName("GPKG").CreateDataSource(str(store))
    ds.CreateLayer("roads")
    ds = None
    before = store.read_bytes()
    with pytest.raises(ValueError, match=r"project\.gpkg.*holds other layers \(roads\).*another file"):
        grid.check_output_path(store)
    with pytest.raises(ValueError, match="holds other layers"):
        _write(_info(tmp_path), {"dtm": store})
    assert store.read_bytes() == before and _partials(tmp_path) == []
    (tmp_path / "notes.gpkg").write_text("not a GeoPackage")
    with pytest.raises(ValueError, match=r"notes\.gpkg' exists and is no GeoPackage GDAL can read"):
        grid.check_output_path(tmp_path / "notes.gpkg")
    assert (tmp_path / "notes.gpkg").read_text() == "not a GeoPackage"
    _write(_info(tmp_path), {"dtm": tmp_path / "dtm.gpkg"})
    grid.check_output_path(tmp_path / "dtm.gpkg")          # its own earlier output: replaced
    _write(_info(tmp_path), {"dtm": tmp_path / "dtm.gpkg"})
    assert gdal.Open(str(tmp_path / "dtm.gpkg")).GetMetadataItem("IDENTIFIER") == "dtm"


def test_an_output_set_refuses_a_path_ending_in_a_separator(tmp_path):
    with pytest.raises(ValueError, match=r"is a folder: give a file name in it \(e\.g\. '.*/new/dtm\.tif'\)"):
        _write(_info(tmp_path), {"dtm": str(tmp_path / "new") + os.sep})
    assert sorted(os.listdir(tmp_path)) == ["dsm.tif"]


@pytest.mark.parametrize("check", ["check_output_path", "check_output_file"])
def test_an_output_that_is_a_device_or_pipe_is_refused_and_kept(tmp_path, check):
    """An existing output that is no regular file (``/dev/null`` given to discard an output, a named pipe)
    was deleted and replaced by a regular file: as root, OUTPUT_NDSM=/dev/null destroyed the system's
    /dev/null. It is refused before any work, by the output set too, and left as it was."""
    pipe = tmp_path / "out.tif"
    os.mkfifo(pipe)
    with pytest.raises(ValueError, match=r"out\.tif' exists and is not a regular file"):
        getattr(grid, check)(pipe)
    with pytest.raises(ValueError, match="is not a regular file"):
        _write(_info(tmp_path), {"dtm": pipe})
    assert stat.S_ISFIFO(os.lstat(pipe).st_mode) and _partials(tmp_path) == []


def test_file_identity_names_of_one_file(tmp_path, monkeypatch):
    """QA15: two names of one file (a hard or symbolic link, './x', and where case is ignored 'X.TIF'
    for 'x.tif') have one identity; resolved paths told a hard link apart, and another case too."""
    from bare_earth.core.grid import outputs
    a = tmp_path / "a.tif"
    a.write_bytes(b"x")
    os.link(a, tmp_path / "hard.tif")
    os.symlink(a, tmp_path / "soft.tif")
    (tmp_path / "b.tif").write_bytes(b"x")
    key = outputs.file_identity(a)
    assert outputs.file_identity(tmp_path / "hard.tif") == key == outputs.file_identity(tmp_path / "soft.tif")
    assert outputs.file_identity(os.path.join(str(tmp_path), ".", "a.tif")) == key
    assert outputs.file_identity(tmp_path / "b.tif") != key
    # files not written yet: one name, one file; 'N.tif' and 'n.tif' are one only where case is ignored
    assert outputs.file_identity(tmp_path / "n.tif") == outputs.file_identity(str(tmp_path / "n.tif"))
    assert outputs.folder_ignores_case(tmp_path / "no" / "such") is False
    assert outputs.file_identity(tmp_path / "N.tif") != outputs.file_identity(tmp_path / "n.tif")
    monkeypatch.setattr(outputs, "folder_ignores_case", lambda folder: True)
    assert outputs.file_identity(tmp_path / "N.tif") == outputs.file_identity(tmp_path / "n.tif")
    assert outputs.file_identity(tmp_path / "no" / "n.tif") != outputs.file_identity(tmp_path / "n.tif")
    assert not [f for f in os.listdir(tmp_path) if f.startswith(".bare-earth")]   # the probe is removed


def test_output_that_is_the_input_under_another_name_refused(tmp_path):
    """QA15: an output given as a link to the input (two names of one file, as 'DSM.TIF' is of 'dsm.tif' where
    the file system ignores case) passed OutputSet's check, which compared paths, and the run's commit replaced
    the input's name (on such a file system the input) by its DTM; a run_file from Python too."""
    from bare_earth.core import pipeline
    info = _info(tmp_path)
    os.link(info.path, tmp_path / "hard.tif")
    (tmp_path / "soft.tif").symlink_to(info.path)
    for name in ("hard.tif", "soft.tif"):
        with grid.OutputSet(info) as out, pytest.raises(ValueError, match="is the input raster"):
            out.add("dtm", tmp_path / name, "Float32")
    with pytest.raises(ValueError, match="is the input raster"):
        pipeline.run_file("morphological", info.path, {"dtm": str(tmp_path / "hard.tif"),
                                                       "mask": str(tmp_path / "m.tif")})
    assert _partials(tmp_path) == [] and not (tmp_path / "m.tif").exists()


def test_classic_tiff_over_4_gb_refused_before_work(tmp_path):
    """QA 19: CREATE_OPTIONS BIGTIFF=NO on an output of more than 4 GB: uncompressed, GDAL refused the file when the
    output set created it (after the parameters were derived); compressed (or IF_NEEDED, under which GDAL never
    chooses BigTIFF for a compressed file), it failed when the data passed 4 GB, after the work. Refused before
    any work, naming the size and the fix; BIGTIFF=YES, IF_SAFER (the default), IF_NEEDED uncompressed (GDAL
    chooses), a smaller output or another format pass."""
    big, small = (33000, 33000), (32000, 32000)                # 4.36 and 4.10 GB of Float32
    out = str(tmp_path / "dtm.tif")
    for opts in (["BIGTIFF=NO"], ["BIGTIFF=no", "COMPRESS=NONE"], ["COMPRESS=ZSTD", "BIGTIFF=IF_NEEDED"]):
        with pytest.raises(ValueError, match=r"holds 4\.36 GB uncompressed \(33000 x 33000 cells of Float32\).*"
                                             r"BIGTIFF=(NO|IF_NEEDED).*give BIGTIFF=YES"):
            grid.check_tiff_size(out, big, 1, "Float32", opts)
    for opts in ([], ["BIGTIFF=YES"], ["BIGTIFF=IF_SAFER"], ["BIGTIFF=IF_NEEDED", "COMPRESS=NONE"]):
        assert grid.check_tiff_size(out, big, 1, "Float32", opts) is None
    assert grid.check_tiff_size(out, small, 1, "Float32", ["BIGTIFF=NO"]) is None
    assert grid.check_tiff_size(out, big, 1, "Byte", ["BIGTIFF=NO"]) is None          # a mask: 1.09 GB
    with pytest.raises(ValueError, match=r"4\.36 GB .* of Byte x 4 bands"):
        grid.check_tiff_size(out, big, 4, "Byte", ["BIGTIFF=NO"])
    assert grid.check_tiff_size(str(tmp_path / "dtm.img"), big, 1, "Float32", ["BIGTIFF=NO"]) is None
    # the output set refuses it before creating any file (run_file adds its outputs before the blocks)
    src = _sparse_dsm(tmp_path / "in" / "big.tif", big)
    with grid.write_options(["BIGTIFF=NO"]), pytest.raises(ValueError, match="BIGTIFF=NO"):
        with grid.OutputSet(grid.open_dsm(src)) as o:
            o.add("mask", str(tmp_path / "mask.tif"), "Byte")
            o.add("dtm", out, "Float32")
    assert sorted(os.listdir(tmp_path)) == ["in"]


def _sparse_dsm(path, shape):
    """A tiled GeoTIFF of ``shape`` cells with data in one 256 x 256 tile at its centre only (a few kB)."""
    from osgeo import gdal
    os.makedirs(os.path.dirname(str(path)), exist_ok=True)
    ds = gdal.GetDriverByName("GTiff").Create(str(path), shape[1], shape[0], 1, gdal.GDT_Float32,
                                              ["TILED=YES", "SPARSE_OK=TRUE", "COMPRESS=DEFLATE", "BIGTIFF=YES"])
    ds.SetGeoTransform((500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0))
    ds.GetRasterBand(1).SetNoDataValue(-9999.0)
    r, c = shape[0] // 2 // 256 * 256, shape[1] // 2 // 256 * 256
    ds.GetRasterBand(1).WriteArray(np.linspace(100.0, 110.0, 256 * 256, dtype=np.float32).reshape(256, 256), c, r)
    ds = None
    return str(path)


def test_an_output_folder_is_checked_itself_not_its_parent(tmp_path, read_only):
    """QA24: the check of an output folder (bareearth:tiles' OUTPUT_FOLDER, orthorefine's folder of orthophotos)
    probed the folder above it, so a read-only folder passed and the run failed at its first file (the survey: a
    FileNotFoundError traceback). The folder itself is probed, or, for a new one, the folder it is created in."""
    out = tmp_path / "out"
    out.mkdir()
    grid.check_output_dir(out)
    grid.check_output_dir(out / "new" / "deeper")          # created with the folders above it
    with read_only(out):
        with pytest.raises(ValueError, match=rf"^the output folder '{out}' is not writable \(.+\): choose a folder"):
            grid.check_output_dir(out)
        with pytest.raises(ValueError, match=rf"^the output folder '{out}' \(the output folder '{out / 'a'}' would "
                                             r"be created in it\) is not writable"):
            grid.check_output_dir(out / "a")
    (tmp_path / "f").write_text("")
    with pytest.raises(ValueError, match=r"'.*f' is an existing file, not a folder"):
        grid.check_output_dir(tmp_path / "f")
    with pytest.raises(ValueError, match=r"cannot be created: '.*f' is a file, not a folder"):
        grid.check_output_dir(tmp_path / "f" / "x")
    with pytest.raises(ValueError, match=r"name 'yyy.*' is 300 bytes long"):
        grid.check_output_dir(tmp_path / ("y" * 300) / "x")
    with pytest.raises(ValueError, match=r"is a GDAL virtual file \(vsimem\)"):
        grid.check_output_dir("/vsimem/out")
    assert sorted(os.listdir(out)) == [] and sorted(os.listdir(tmp_path)) == ["f", "out"]


def test_a_mask_name_leaving_no_room_for_its_class_names_refused_before_any_work(tmp_path):
    """QA24: a mask named with 247-255 bytes was written without its .aux.xml (GDAL leaves a side file longer than
    the file system allows out without a word), so its class names were lost; a DTM of that name keeps all it
    holds (its statistics are QGIS's, rebuilt on demand) and is still written."""
    limit = os.pathconf(tmp_path, "PC_NAME_MAX")
    base = "m" * (limit - 4 - 7) + ".tif"            # its .aux.xml one byte too long
    with pytest.raises(ValueError, match=rf"the mask's class names go to '{base}.aux.xml' beside it, {limit + 1} "
                                         rf"bytes, and the file system of '{tmp_path}' allows {limit}: choose a name "
                                         rf"of at most {limit - 8} bytes"):
        grid.check_output_path(tmp_path / base, styled=True)
    grid.check_output_path(tmp_path / base)                       # the DTM
    grid.check_output_path(tmp_path / base[1:], styled=True)       # one byte shorter: its .aux.xml fits
    assert os.listdir(tmp_path) == []


def test_an_output_that_is_a_link_leading_nowhere_is_written_not_called_read_only(tmp_path):
    """QA24: an output named by a symbolic link whose file was deleted (a 'latest_dtm.tif' link) was refused as
    "exists and is read-only": the link is replaced by the output as a missing file would be."""
    link = tmp_path / "latest_dtm.tif"
    link.symlink_to(tmp_path / "gone" / "dtm.tif")
    grid.check_output_path(link)
    info = grid.open_dsm(grid.write_array(tmp_path / "dsm.tif", np.ones((5, 6), np.float32), GT))
    with grid.OutputSet(info) as out:
        out.add("dtm", link, "Float32", nodata=float("nan"))
        out.write("dtm", np.full((5, 6), 2.0, np.float32))
        out.commit()
    assert not link.is_symlink() and (gdal.Open(str(link)).ReadAsArray() == 2.0).all()


@pytest.mark.parametrize("side", ["m.qml", "m.tif.aux.xml"])
def test_a_read_only_file_the_output_writes_beside_it_refused_before_any_work(tmp_path, read_only, side):
    """QA24: a read-only style (m.qml) or .aux.xml beside a mask passed the checks; the run ended, once the work
    was done and the mask already moved into place, in a PermissionError traceback writing it."""
    from bare_earth.core.pipeline import run_file
    dsm = grid.write_array(tmp_path / "dsm.tif", np.add.outer(np.arange(40.0), np.arange(40.0)).astype(np.float32), GT)
    (tmp_path / side).write_text("<keep/>")
    with read_only(tmp_path / side):
        with pytest.raises(ValueError, match=rf"^the output '.*m.tif' writes '{re.escape(side)}' beside it, but "
                                             r"'.*' exists and is read-only \(or no regular file\): make it writable"):
            grid.check_output_path(tmp_path / "m.tif", styled=True)
        with pytest.raises(ValueError, match=rf"writes '{re.escape(side)}' beside it, but .* is read-only"):
            run_file("morphological", str(dsm), {"dtm": str(tmp_path / "d.tif"), "mask": str(tmp_path / "m.tif")})
    assert sorted(os.listdir(tmp_path)) == ["dsm.tif", side]
    assert (tmp_path / side).read_text() == "<keep/>"
