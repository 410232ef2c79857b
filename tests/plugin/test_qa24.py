"""QA pass 24 through the algorithms: rasters QGIS's loader of text values does not take. Each test failed
before its fix."""
import zipfile

import numpy as np
import pytest

pytestmark = pytest.mark.qgis
GT = (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0)


def _dsm(path, base=100.0):
    from bare_earth.core.grid import write_array
    z = np.add.outer(np.arange(48.0), np.arange(48.0)) * 0.05 + base
    z[10:20, 10:20] += 6.0
    return str(write_array(path, z.astype(np.float32), GT, 32632))


def _geopackage(tmp_path):
    """A GeoPackage of two Float32 raster tables, 'low' and 'high' (400 m above)."""
    from osgeo import gdal
    gpkg = str(tmp_path / "rasters.gpkg")
    gdal.Translate(gpkg, _dsm(tmp_path / "low.tif"), format="GPKG",
                   creationOptions=["RASTER_TABLE=low", "TILE_FORMAT=TIFF"])
    gdal.Translate(gpkg, _dsm(tmp_path / "high.tif", 500.0), format="GPKG",
                   creationOptions=["RASTER_TABLE=high", "TILE_FORMAT=TIFF", "APPEND_SUBDATASET=YES"])
    return gpkg


def _read(path):
    from osgeo import gdal
    ds = gdal.Open(path)
    return ds.GetRasterBand(1).ReadAsArray()


def test_gdal_rasters_that_are_no_file_run_when_given_as_text(processing_run, tmp_path):
    """A DSM in a zip (/vsizip/) and a GeoPackage's raster table (GPKG:file:table) given as text (qgis_process,
    a script) were refused with QGIS's "Could not load source layer for INPUT: ... not found", though the same
    layers loaded in QGIS ran: QGIS's loader of text values opens files only. They now run as the layers do."""
    plain = _dsm(tmp_path / "dsm.tif")
    with zipfile.ZipFile(tmp_path / "dsm.zip", "w") as z:
        z.write(plain, "inner/dsm.tif")
    gpkg = _geopackage(tmp_path)
    want = processing_run("bareearth:morphological", {"INPUT": plain, "OUTPUT_DTM": str(tmp_path / "d0.tif"),
                                                      "OUTPUT_MASK": str(tmp_path / "m0.tif")})
    for i, (given, rise) in enumerate(((f"/vsizip/{tmp_path}/dsm.zip/inner/dsm.tif", 0.0),
                                       (f"GPKG:{gpkg}:high", 400.0))):
        got = processing_run("bareearth:morphological", {"INPUT": given, "OUTPUT_DTM": str(tmp_path / f"d{i + 1}.tif"),
                                                         "OUTPUT_MASK": str(tmp_path / f"m{i + 1}.tif")})
        np.testing.assert_array_equal(_read(got["OUTPUT_MASK"]), _read(want["OUTPUT_MASK"]))
        np.testing.assert_allclose(_read(got["OUTPUT_DTM"]), _read(want["OUTPUT_DTM"]) + rise, atol=1e-3)


def test_a_file_of_several_rasters_or_a_vector_layer_uri_refused_naming_what_to_give(qgis_app, tmp_path):
    """A GeoPackage of two raster tables given as its path, and a table named the vector way ('|layername='),
    were refused with "Could not load source layer for INPUT: ... not found" (the file exists). The message now
    names the rasters as they may be given."""
    from qgis.core import QgsApplication, QgsProcessingContext
    gpkg = _geopackage(tmp_path)
    alg = QgsApplication.processingRegistry().algorithmById("bareearth:dtm")
    out = {"OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif")}
    ok, msg = alg.checkParameterValues(dict(out, INPUT=gpkg), QgsProcessingContext())
    assert not ok
    assert msg == (f"'Input DSM' (INPUT): the file '{gpkg}' holds 2 rasters (a GeoPackage's raster tables, a netCDF's "
                   f"variables), so it names none: give one of them (GPKG:{gpkg}:low, GPKG:{gpkg}:high).")
    ok, msg = alg.checkParameterValues(dict(out, INPUT=f"{gpkg}|layername=high"), QgsProcessingContext())
    assert not ok and msg.endswith(f"names a vector layer ('|layername='); a GeoPackage's raster table is given as "
                                   f"GPKG:{gpkg}:high."), msg
    ok, msg = alg.checkParameterValues(dict(out, INPUT=str(tmp_path / "missing.tif")), QgsProcessingContext())
    assert not ok and "not found" in msg        # a missing file: QGIS's own message


def test_a_layer_with_gdal_open_options_or_a_file_gone_refused_saying_what_to_do(processing_run, tmp_path):
    """A DSM layer opened with GDAL open options (its source '...|option:KEY=VALUE', set in the Data Source
    Manager) and a layer whose file was deleted after loading were both refused as "No such file or directory ...
    The file may be truncated or corrupt": the first file exists, the second is not corrupt. The messages now
    name the options (with the gdal_translate that applies them) and the missing file."""
    import os
    import shutil

    from qgis.core import QgsProcessingException, QgsRasterLayer
    plain = _dsm(tmp_path / "dsm.tif")
    out = {"OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif")}
    layer = QgsRasterLayer(plain + "|option:GEOREF_SOURCES=INTERNAL", "opened", "gdal")
    assert layer.isValid()
    with pytest.raises(QgsProcessingException, match=r"The layer 'opened' is opened with GDAL open options "
                                                     r"\(GEOREF_SOURCES=INTERNAL\), which the filters cannot pass on "
                                                     r"to the file: write the raster as QGIS reads it \(gdal_translate "
                                                     r"-oo GEOREF_SOURCES=INTERNAL '.*dsm.tif' dsm.tif"):
        processing_run("bareearth:dtm", dict(out, INPUT=layer))
    shutil.copy(plain, tmp_path / "gone.tif")
    gone = QgsRasterLayer(str(tmp_path / "gone.tif"), "gone", "gdal")
    os.remove(tmp_path / "gone.tif")
    with pytest.raises(QgsProcessingException, match=rf"The layer 'gone' reads the file '{tmp_path / 'gone.tif'}', "
                                                     r"which no longer exists \(moved, renamed or deleted"):
        processing_run("bareearth:morphological", dict(out, INPUT=gone))
    assert not os.path.exists(out["OUTPUT_MASK"])
    processing_run("bareearth:morphological", dict(out, INPUT=QgsRasterLayer(plain, "plain", "gdal")))
    assert os.path.exists(out["OUTPUT_MASK"])


def test_paths_with_a_blank_at_either_end_refused_naming_the_path_without(qgis_app, tmp_path):
    """A path copied with the space after it, or read from a list with its line break: an output was refused as
    "cannot write ... as '.tif ': GDAL cannot write it here" (or its folder '/work/ /data' as missing), an input as
    "Could not load source layer for INPUT: ... not found". Both now say what is wrong and give the path
    without it."""
    from qgis.core import QgsApplication, QgsProcessingContext
    plain = _dsm(tmp_path / "dsm.tif")
    alg = QgsApplication.processingRegistry().algorithmById("bareearth:slopeprofile")
    mask = str(tmp_path / "m.tif")
    for given, where in ((str(tmp_path / "d.tif "), "ends"), (" " + str(tmp_path / "d.tif"), "begins"),
                         (str(tmp_path / "d.tif") + "\n", "ends")):
        ok, msg = alg.checkParameterValues({"INPUT": plain, "OUTPUT_DTM": given, "OUTPUT_MASK": mask},
                                           QgsProcessingContext())
        assert not ok and msg == (f"'DTM' (OUTPUT_DTM): the output {given!r} {where} with a blank (a space, a tab or "
                                  "a line break, e.g. copied with the name or read from a list): give it without, "
                                  f"'{tmp_path / 'd.tif'}'."), msg
    ok, msg = alg.checkParameterValues({"INPUT": plain + " ", "OUTPUT_DTM": str(tmp_path / "d.tif"),
                                        "OUTPUT_MASK": mask}, QgsProcessingContext())
    assert not ok and msg == (f"'Input DSM' (INPUT): '{plain} ' ends with a blank (a space, a tab or a line break), "
                              f"which is kept in the file name: give it without, '{plain}'."), msg
    points = tmp_path / "points.txt"
    points.write_text("500010 5399990 100.0 0\n")
    ok, msg = QgsApplication.processingRegistry().algorithmById("bareearth:evaluate").checkParameterValues(
        {"DTM": plain, "POINTS": f"{points}\n", "OUTPUT_JSON": str(tmp_path / "e.json")}, QgsProcessingContext())
    assert not ok and msg.startswith("'Reference points (ISPRS text or LAS/LAZ)' (POINTS): ") and msg.endswith(
        f"ends with a blank (a space, a tab or a line break), which is kept in the file name: give it without, "
        f"'{points}'."), msg
    from bare_earth.core import grid
    with pytest.raises(ValueError, match=r"^the output '.*out ' ends with a blank"):
        grid.check_output_dir(str(tmp_path / "out "))
    with pytest.raises(ValueError, match=r"^the output '.*e.json ' ends with a blank"):
        grid.check_output_file(str(tmp_path / "e.json "))


def test_orthorefine_dem_of_several_bands_names_no_band_parameter_it_lacks(qgis_app, tmp_path):
    """orthorefine's DEM of three bands was refused with the DSM's message, "Choose the height band with the BAND
    parameter (1..3)": orthorefine has no BAND parameter. Refused now as the other inputs without a band choice
    are, saying to extract the band."""
    from osgeo import gdal
    from qgis.core import QgsApplication, QgsProcessingContext
    plain = _dsm(tmp_path / "dsm.tif")
    gdal.Translate(str(tmp_path / "three.tif"), gdal.BuildVRT("", [plain] * 3, separate=True))
    alg = QgsApplication.processingRegistry().algorithmById("bareearth:orthorefine")
    assert alg.parameterDefinition("BAND") is None
    ok, msg = alg.checkParameterValues({"DEM": str(tmp_path / "three.tif"), "IMAGES": [plain, plain],
                                        "OUTPUT_DEM": str(tmp_path / "o.tif")}, QgsProcessingContext())
    assert not ok and "BAND" not in msg
    assert msg.startswith(f"DEM: the raster '{tmp_path / 'three.tif'}' has 3 bands but this input is read from a "
                          "single band (it has no band choice): extract the band"), msg
