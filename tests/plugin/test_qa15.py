"""QA pass 15 through processing.run: one file under two names (a hard link; another case on a file
system that ignores case), a neighbouring point tile given twice. Each test failed before its fix."""
import os

import numpy as np
import pytest

pytestmark = pytest.mark.qgis
GT = (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0)


def _dsm(path, shape=(40, 40)):
    from bare_earth.core.grid import write_array
    z = np.zeros(shape, np.float32) + np.linspace(0.0, 2.0, shape[1], dtype=np.float32)[None, :]
    z[10:20, 10:20] += 6.0
    return write_array(path, z, GT, 32632)


def _check(alg, params):
    from qgis.core import QgsApplication, QgsProcessingContext
    return QgsApplication.processingRegistry().algorithmById(alg).checkParameterValues(params,
                                                                                      QgsProcessingContext())


@pytest.mark.parametrize("key", ["OUTPUT_DTM", "OUTPUT_MASK"])
def test_output_that_is_the_input_under_another_name_refused(qgis_app, tmp_path, key):
    """An output given as a hard link of the input (two names of one file, as 'DSM.TIF' is of 'dsm.tif' on a
    file system that ignores case) passed the check, which compared resolved paths: the run replaced the
    name, and on such a file system the input itself, by its DTM."""
    dsm = _dsm(tmp_path / "dsm.tif")
    os.link(dsm, tmp_path / "same.tif")
    params = {"INPUT": str(dsm), "OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif"),
              key: str(tmp_path / "same.tif")}
    ok, msg = _check("bareearth:slopeprofile", params)
    assert not ok and f"({key}) is the input" in msg and "same.tif" in msg, msg


def test_outputs_differing_only_in_case_where_case_is_ignored(qgis_app, tmp_path, monkeypatch):
    """Two outputs 'A.tif' and 'a.tif' are one file where the folder ignores case (Windows, macOS, a
    FAT or SMB share): the second replaced the first. Refused there, naming both; kept apart where
    case counts."""
    from bare_earth.core.grid import outputs
    dsm = _dsm(tmp_path / "dsm.tif")
    params = {"INPUT": str(dsm), "OUTPUT_DTM": str(tmp_path / "Out.tif"), "OUTPUT_MASK": str(tmp_path / "out.tif")}
    assert outputs.folder_ignores_case(tmp_path) is False     # Linux's file systems count case
    ok, msg = _check("bareearth:slopeprofile", params)
    assert ok, msg
    monkeypatch.setattr(outputs, "folder_ignores_case", lambda folder: True)
    ok, msg = _check("bareearth:slopeprofile", params)
    assert not ok and "(OUTPUT_DTM) and" in msg and "(OUTPUT_MASK) are one file" in msg and "two names of it" in msg


@pytest.mark.parametrize("alg,key,value", [
    ("bareearth:morphological", "BAND", 1.5), ("bareearth:morphological", "BAND", "2.7"),
    ("bareearth:morphological", "THREADS", 1.5), ("bareearth:morphological", "BLOCK_SIZE", "100.5"),
    ("bareearth:curvature", "WINDOW_CELLS", 7.5), ("bareearth:curvature", "WINDOW_CELLS", "7.5"),
])
def test_a_fraction_given_to_a_whole_number_refused(qgis_app, tmp_path, alg, key, value):
    """QA15: a fraction given to a whole-number parameter (qgis_process's BAND=2.7, a script's THREADS=1.5)
    was cut or rounded by QGIS without a word: BAND 2.7 read band 3, 1.5 band 1, WINDOW_CELLS 7.5 ran with
    7. Refused before work, naming the parameter; a whole number written 2.0 is still taken."""
    from osgeo import gdal
    path = str(tmp_path / "two.tif")
    ds = gdal.GetDriverByName("GTiff").Create(path, 40, 40, 2, gdal.GDT_Float32)
    ds.SetGeoTransform(GT)
    ds.GetRasterBand(1).WriteArray(np.linspace(0, 3, 1600, dtype=np.float32).reshape(40, 40))
    ds.GetRasterBand(2).Fill(5.0)
    ds = None
    params = {"INPUT": path, "BAND": 1, "OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif")}
    ok, msg = _check(alg, {**params, key: value})
    assert not ok and msg.endswith(f"({key}) = {value} is not a whole number: give a whole number."), msg
    ok, msg = _check(alg, {**params, key: {"BAND": "2.0", "THREADS": 1.0, "BLOCK_SIZE": "128",
                                           "WINDOW_CELLS": 7.0}[key]})
    assert ok, msg


@pytest.mark.parametrize("first,second", [("MASK", "REFERENCE_MASK"), ("DTM", "REFERENCE_DTM")])
@pytest.mark.parametrize("name", ["same", "link"])
def test_evaluate_a_raster_compared_with_itself_refused(qgis_app, tmp_path, first, second, name):
    """QA15: MASK and REFERENCE_MASK (or DTM and REFERENCE_DTM) given one file (the same layer chosen twice,
    or a model's one output wired to both) ran and reported kappa 100 %, no error at all; refused before
    work as TRUTH_POINTS and POINTS are, under any name of the file (a link)."""
    from bare_earth.core.grid import write_array
    arr = np.zeros((40, 40), np.uint8 if "MASK" in first else np.float32)
    arr[10:20, 10:20] = 1
    path = write_array(tmp_path / "r.tif", arr, GT, 32632, nodata=255 if "MASK" in first else None)
    other = path
    if name == "link":
        other = str(tmp_path / "r_link.tif")
        os.link(path, other)
    params = {first: str(path), second: str(other), "OUTPUT_JSON": str(tmp_path / "e.json"),
              "OUTPUT_HTML": str(tmp_path / "e.html")}
    ok, msg = _check("bareearth:evaluate", params)
    assert not ok and f"({second}) are one file" in msg and "compared with itself" in msg, msg


@pytest.mark.parametrize("alg", ["bareearth:morphological", "bareearth:dtm", "bareearth:slopeprofile"])
def test_cells_wider_than_any_filter_window_refused_in_the_check(qgis_app, tmp_path, alg):
    """QA15: a DSM of 4.5 x 2.25 degree cells ran the checks, read the data and failed deriving the opening's
    parameters ('WIDE_RADIUS_M = 250468 m is out of range', a parameter nobody gave). Refused by the check,
    naming the cells; the survey's tiles too."""
    from bare_earth.core.grid import write_array
    from bare_earth.core.survey import index_tiles
    z = np.zeros((40, 40), np.float32) + np.linspace(0.0, 30.0, 40, dtype=np.float32)[None, :]
    path = write_array(tmp_path / "deg.tif", z, (-180.0, 4.5, 0.0, 90.0, 0.0, -2.25), 4326)
    ok, msg = _check(alg, {"INPUT": str(path), "OUTPUT_DTM": str(tmp_path / "d.tif"),
                           "OUTPUT_MASK": str(tmp_path / "m.tif")})
    assert not ok and "cells of 354811 x 250046 m are wider than the widest window any filter takes" in msg, msg
    with pytest.raises(ValueError, match="are wider than the widest window"):
        index_tiles([str(path)])


def test_orthoparallax_one_orthophoto_under_two_names_refused(qgis_app, tmp_path):
    """QA15: ORTHO_B given as a hard link of ORTHO_A (one file, two names) passed the check, which compared
    resolved paths, and matched the orthophoto with itself (no parallax at all)."""
    from bare_earth.core.grid import write_array
    rng = np.random.default_rng(7)
    a = write_array(tmp_path / "a.tif", (255.0 * rng.random((100, 100))).astype(np.float32), GT, 32632)
    os.link(a, tmp_path / "b.tif")
    params = {"DEM": str(write_array(tmp_path / "dem.tif", np.full((100, 100), 100.0, np.float32), GT, 32632)),
              "ORTHO_A": str(a), "ORTHO_B": str(tmp_path / "b.tif"), "BASE_M": 300.0, "HEIGHT_M": 1000.0,
              "OUTPUT_DEM": str(tmp_path / "o.tif"), "OUTPUT_DH": str(tmp_path / "dh.tif"),
              "OUTPUT_QUALITY": str(tmp_path / "q.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif")}
    ok, msg = _check("bareearth:orthoparallax", params)
    assert not ok and "ORTHO_A and ORTHO_B are one file" in msg, msg
