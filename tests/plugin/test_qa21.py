"""QA pass 21 through processing.run and the algorithms' checks. Each test failed before its fix."""
import numpy as np
import pytest

pytestmark = pytest.mark.qgis
GT = (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0)


def _write(path, arr, gt=GT, epsg=32632, nodata=None):
    from bare_earth.core.grid import write_array
    return str(write_array(path, arr, gt, epsg, nodata=nodata))


def _check(alg, params):
    from qgis.core import QgsApplication, QgsProcessingContext
    return QgsApplication.processingRegistry().algorithmById(alg).checkParameterValues(params,
                                                                                      QgsProcessingContext())


@pytest.mark.parametrize("binary_is", ["REFERENCE_MASK", "MASK"])
def test_a_binary_0_255_mask_is_refused_not_scored_on_its_ground(processing_run, tmp_path, binary_is):
    """A reference mask of another tool, 0 ground and 255 object (footprints burnt with 255), was compared with
    every object cell left out as nodata: TOTAL 0 %, TYPE1 0 %, TYPE2 and KAPPA not defined, no warning at all.
    Refused in the check, naming the cells and the reclassification; the same mask as 0/1 is scored."""
    from qgis.core import QgsProcessingException
    m = np.zeros((40, 40), np.uint8)
    m[10:20, 10:20] = 1
    m[25:30, 5:35] = 1
    m[0, :] = 255                                          # the data's own edge: nodata in both
    binary = np.where(m == 1, 255, m).astype(np.uint8)
    mask, bin_path = _write(tmp_path / "mask.tif", m), _write(tmp_path / "binary.tif", binary)
    params = {"MASK": mask, "REFERENCE_MASK": bin_path} if binary_is == "REFERENCE_MASK" else \
        {"MASK": bin_path, "REFERENCE_MASK": mask}
    ok, msg = _check("bareearth:evaluate", params)
    assert not ok and f"({binary_is}) '{bin_path}' holds no object code (1 or 2), only 0 and 255, and its 250 " \
                      "cell(s) of 255 where" in msg and "(100 % of them, against 0 %" in msg and \
        "reclassify it to 0 ground and 1 object" in msg, msg
    with pytest.raises(QgsProcessingException, match="only 0 and 255"):
        processing_run("bareearth:evaluate", dict(params, OUTPUT_JSON=str(tmp_path / "e.json")))
    assert not (tmp_path / "e.json").exists()
    fixed = np.where(binary == 255, 1, binary).astype(np.uint8)
    fixed[0, :] = 255
    r = processing_run("bareearth:evaluate", dict(params, **{binary_is: _write(tmp_path / "fixed.tif", fixed)}))
    assert r["TOTAL"] == 0.0 and r["KAPPA"] == 100.0


def test_a_reference_of_bare_ground_beside_nodata_is_still_scored(processing_run, tmp_path):
    """A reference mask of ground only, its 255 where no truth was taken (the data's edge, not the objects):
    the check stays silent and the ground is scored (Type I)."""
    m = np.zeros((40, 40), np.uint8)
    m[5:9, 5:9] = 1                                          # an object inside the reference's area
    m[30:34, 30:34] = 1                                      # and one beyond it
    ref = np.zeros((40, 40), np.uint8)
    ref[:, 20:] = 255                                        # no truth on the right half
    ref[5:9, 5:9] = 0                                        # the filter's object there is ground: Type I
    r = processing_run("bareearth:evaluate", {"MASK": _write(tmp_path / "m.tif", m),
                                              "REFERENCE_MASK": _write(tmp_path / "r.tif", ref)})
    assert r["TYPE1"] == pytest.approx(100.0 * 16 / 800)


def test_points_with_a_northing_first_header_are_placed_where_they_are(processing_run, tmp_path):
    """A surveyor's 'N,E,H' file through rasterizepoints: the DSM was built with the northings as eastings (placed at
    x 5400000 in UTM zone 32, its rows and columns swapped) without a word. The columns are picked by name now."""
    from osgeo import gdal
    rng = np.random.default_rng(1)
    e, n = 500000 + rng.uniform(0, 40, 3000), 5400000 + rng.uniform(0, 20, 3000)
    pts = tmp_path / "neh.csv"
    pts.write_text("N,E,H\n" + "\n".join(f"{b:.3f},{a:.3f},{100 + 0.1 * (a - 500000):.3f}" for a, b in zip(e, n)))
    r = processing_run("bareearth:rasterizepoints", {"INPUT": str(pts), "CRS": "EPSG:32632", "CELL_SIZE_M": 1.0,
                                                     "OUTPUT": str(tmp_path / "dsm.tif")})
    ds = gdal.Open(r["OUTPUT"])
    gt = ds.GetGeoTransform()
    assert (ds.RasterXSize, ds.RasterYSize) == (40, 20) and 499999 <= gt[0] <= 500000 and 5400020 <= gt[3] <= 5400021
    z = ds.ReadAsArray()
    assert z[:, 0].mean() < z[:, -1].mean() - 3            # rises eastwards, by 0.1 m per metre


@pytest.mark.parametrize("value", ["abc", "inf"])
def test_a_memory_bound_that_is_no_number_is_refused_in_the_dialog(qgis_app, tmp_path, monkeypatch, value):
    """BARE_EARTH_MEMORY_MB=abc passed the dialog's check and was refused after the parameters' derivation on a
    raster over 25 Mcells ('inf': a bare OverflowError there); the check names it now."""
    src = _write(tmp_path / "dsm.tif", np.zeros((40, 40), np.float32) + np.arange(40, dtype=np.float32))
    params = {"INPUT": src, "OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif")}
    assert _check("bareearth:slopeprofile", params)[0]
    monkeypatch.setenv("BARE_EARTH_MEMORY_MB", value)
    ok, msg = _check("bareearth:slopeprofile", params)
    assert not ok and f"BARE_EARTH_MEMORY_MB='{value}'" in msg and "megabytes" in msg, msg


def test_a_layer_given_another_crs_than_its_file_is_refused_naming_both(processing_run, tmp_path):
    """A DSM whose file declares UTM zone 33 for data of zone 32, assigned EPSG:32632 in QGIS (Properties >
    Source): GDAL read the file's CRS, so the DTM and mask were written in zone 33, 500 km from where the layer
    is drawn, without a word. The filters, filldtm and evaluate now refuse it in the check, naming both CRSs and
    the fix; a file without a CRS still takes its layer's."""
    from qgis.core import QgsCoordinateReferenceSystem, QgsProcessingException, QgsRasterLayer
    z = np.zeros((40, 40), np.float32) + np.arange(40, dtype=np.float32)
    path = _write(tmp_path / "dsm.tif", z, epsg=32633)
    layer = QgsRasterLayer(path, "dsm")
    outs = {"OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif")}
    assert _check("bareearth:morphological", {"INPUT": layer, **outs})[0]
    layer.setCrs(QgsCoordinateReferenceSystem("EPSG:32632"))
    ok, msg = _check("bareearth:morphological", {"INPUT": layer, **outs})
    assert not ok and "The layer 'dsm' is in EPSG:32632 as QGIS draws it" in msg and "its file declares EPSG:32633" \
        in msg and f"gdal_edit.py -a_srs EPSG:32632 '{path}'" in msg, msg
    with pytest.raises(QgsProcessingException, match="its file declares EPSG:32633"):
        processing_run("bareearth:morphological", {"INPUT": layer, **outs})
    assert not (tmp_path / "d.tif").exists()
    mask = QgsRasterLayer(_write(tmp_path / "mask.tif", np.zeros((40, 40), np.uint8), epsg=32633), "mask")
    mask.setCrs(QgsCoordinateReferenceSystem("EPSG:32632"))
    ok, msg = _check("bareearth:filldtm", {"INPUT": _write(tmp_path / "s.tif", z, epsg=32633), "MASK": mask,
                                           "OUTPUT": str(tmp_path / "f.tif")})
    assert not ok and "The layer 'mask' is in EPSG:32632" in msg, msg
    ok, msg = _check("bareearth:evaluate", {"MASK": mask, "REFERENCE_MASK": _write(tmp_path / "r.tif", np.zeros(
        (40, 40), np.uint8), epsg=32633)})
    assert not ok and "The layer 'mask' is in EPSG:32632" in msg, msg
    from osgeo import gdal
    bare = str(tmp_path / "nocrs.tif")
    ds = gdal.GetDriverByName("GTiff").Create(bare, 40, 40, 1, gdal.GDT_Float32)
    ds.SetGeoTransform(GT)
    ds.GetRasterBand(1).WriteArray(z)
    ds = None
    free = QgsRasterLayer(bare, "free")
    free.setCrs(QgsCoordinateReferenceSystem("EPSG:32632"))
    assert _check("bareearth:morphological", {"INPUT": free, **outs})[0]


def test_a_layer_given_the_same_crs_spelt_otherwise_is_accepted(processing_run, tmp_path):
    """The CRS check compares systems, not their spelling (QGIS's own equality identifies the WKT): a file
    whose WKT names UTM 32N under its own name, without an EPSG code (another tool's WKT), assigned
    EPSG:32632 in QGIS is the same system and runs; the same file assigned zone 33 is refused."""
    from osgeo import gdal, osr
    from qgis.core import QgsCoordinateReferenceSystem, QgsRasterLayer
    z = np.zeros((40, 40), np.float32) + np.arange(40, dtype=np.float32)
    path = str(tmp_path / "esri.tif")
    ds = gdal.GetDriverByName("GTiff").Create(path, 40, 40, 1, gdal.GDT_Float32)
    ds.SetGeoTransform(GT)
    srs = osr.SpatialReference()
    srs.SetProjCS("My UTM 32 north")
    srs.SetWellKnownGeogCS("WGS84")
    srs.SetUTM(32, True)
    ds.SetProjection(srs.ExportToWkt())
    ds.GetRasterBand(1).WriteArray(z)
    ds = None
    layer = QgsRasterLayer(path, "esri")
    outs = {"OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif")}
    layer.setCrs(QgsCoordinateReferenceSystem("EPSG:32632"))
    ok, msg = _check("bareearth:morphological", {"INPUT": layer, **outs})
    assert ok, msg
    layer.setCrs(QgsCoordinateReferenceSystem("EPSG:32633"))
    ok, msg = _check("bareearth:morphological", {"INPUT": layer, **outs})
    assert not ok and "The layer 'esri' is in EPSG:32633" in msg, msg
