"""QA pass 23 through the algorithms' checks. Each test failed before its fix."""
import re

import numpy as np
import pytest

pytestmark = pytest.mark.qgis
GT = (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0)


def _dsm(tmp_path):
    from bare_earth.core.grid import write_array
    z = np.add.outer(np.arange(48.0), np.arange(48.0)) * 0.05 + 100.0
    z[10:20, 10:20] += 6.0
    return str(write_array(tmp_path / "dsm.tif", z.astype(np.float32), GT, 32632))


@pytest.mark.parametrize("alg, given, message", [
    ("curvature", {"WINDOW_CELLS": "4"}, r"'Trend window \(cells, odd\)' \(WINDOW_CELLS\) must be an odd integer >= 3"),
    ("curvature", {"WINDOW_CELLS": 6}, r"got 6\. Use e\.g\. 5 or 7"),
    ("rascor", {"HEIGHT_MIN_M": 50, "HEIGHT_MAX_M": 10},
     r"'Lowest valid height \(m\)' \(HEIGHT_MIN_M\) \(50\.0\) must be below 'Highest valid height \(m\)' "
     r"\(HEIGHT_MAX_M\) \(10\.0\).*swap them"),
])
def test_values_no_data_makes_valid_refused_in_the_check(processing_run, tmp_path, alg, given, message):
    """An even curvature window and RASCOR's height limits in the wrong order passed the dialog's check (in
    range each) and failed only once the run had read the DSM. The method's own check (Method.check, the one
    its resolve runs) now refuses them before any work; the values beside them still run."""
    from qgis.core import QgsApplication, QgsProcessingContext
    params = {"INPUT": _dsm(tmp_path), "OUTPUT_DTM": str(tmp_path / "dtm.tif"),
              "OUTPUT_MASK": str(tmp_path / "mask.tif"), **given}
    ok, msg = QgsApplication.processingRegistry().algorithmById(f"bareearth:{alg}").checkParameterValues(
        params, QgsProcessingContext())
    assert not ok
    assert re.search(message, msg), msg
    fixed = {"WINDOW_CELLS": 5} if alg == "curvature" else {"HEIGHT_MIN_M": 10, "HEIGHT_MAX_M": 50}
    processing_run(f"bareearth:{alg}", dict(params, **fixed))
    assert (tmp_path / "mask.tif").exists()


def test_survey_parameters_no_data_makes_valid_refused_in_the_check(qgis_app, tmp_path):
    """PARAMETERS 'window_cells=4' for curvature passed the survey's check (in range) and would fail in the
    first task, after the sample had been read and the cluster started."""
    from qgis.core import QgsApplication, QgsProcessingContext

    from bare_earth.core.methods import available_methods
    ok, msg = QgsApplication.processingRegistry().algorithmById("bareearth:tiles").checkParameterValues(
        {"INPUT_LAYERS": [_dsm(tmp_path)], "METHOD": sorted(available_methods()).index("curvature"),
         "PARAMETERS": "window_cells=4", "OUTPUT_FOLDER": str(tmp_path / "out")}, QgsProcessingContext())
    assert not ok and "window_cells must be an odd integer >= 3" in msg, msg
    assert not (tmp_path / "out").exists()


def test_method_check_given_is_the_resolves_check():
    """Method.check_given refuses what resolve refuses whatever the data, and lets the rest pass."""
    from bare_earth.core.methods import get_method
    curvature, rascor = get_method("curvature"), get_method("rascor")
    with pytest.raises(ValueError, match="odd integer"):
        curvature.check_given({"window_cells": 4})
    with pytest.raises(ValueError, match="odd integer"):
        curvature.resolve(np.ones((16, 16), np.float32), 1.0, window_cells=4)
    with pytest.raises(ValueError, match="must be below height_max_m"):
        rascor.check_given({"height_min_m": 5.0, "height_max_m": 5.0})
    with pytest.raises(ValueError, match="out of range"):
        rascor.check_given({"sigma_m": -1.0})
    curvature.check_given({"window_cells": None})
    rascor.check_given({"height_min_m": None, "height_max_m": 5.0})


def _compound_pair(tmp_path):
    """A DSM in NAD83 / UTM 18N + NAVD88 height (US feet), and a mask of its cells declared in the horizontal
    CRS alone (EPSG:26918), as another tool or a reference writes it."""
    from osgeo import gdal, osr

    from bare_earth.core.grid import write_array
    gt = (320000.0, 2.0, 0.0, 4300000.0, 0.0, -2.0)
    z = (np.add.outer(np.arange(40.0), np.arange(40.0)) * 0.1 + 300.0).astype(np.float32)
    z[10:20, 10:20] += 20.0
    dsm = str(write_array(tmp_path / "dsm_ft.tif", z, gt, 26918))
    srs = osr.SpatialReference()
    srs.SetFromUserInput("EPSG:26918+6360")
    ds = gdal.Open(dsm, gdal.GA_Update)
    ds.SetProjection(srs.ExportToWkt())
    ds = None
    m = np.zeros(z.shape, np.uint8)
    m[10:20, 10:20] = 1
    return dsm, str(write_array(tmp_path / "mask.tif", m, gt, 26918, nodata=255))


def test_a_mask_in_the_horizontal_crs_of_a_compound_crs_dsm_is_on_its_grid(processing_run, tmp_path):
    """A mask declared in EPSG:26918 beside a DSM (or a filter's mask) in EPSG:26918+6360 was refused as 'in
    another CRS: the same cell numbers are another place', though it lies on the same cells: codes have no
    height, so only the horizontal CRS counts (filldtm's MASK, evaluate's MASK / REFERENCE_MASK)."""
    dsm, mask = _compound_pair(tmp_path)
    out = processing_run("bareearth:filldtm", {"INPUT": dsm, "MASK": mask, "FILL_NODATA": False,
                                               "OUTPUT": str(tmp_path / "filled.tif")})
    assert (tmp_path / "filled.tif").exists() and out["OUTPUT"]
    run = processing_run("bareearth:slopeprofile", {"INPUT": dsm, "OUTPUT_DTM": str(tmp_path / "dtm.tif"),
                                                    "OUTPUT_MASK": str(tmp_path / "m_ft.tif")})
    r = processing_run("bareearth:evaluate", {"MASK": run["OUTPUT_MASK"], "REFERENCE_MASK": mask})
    assert r["TOTAL"] is not None and 0.0 <= r["TOTAL"] <= 100.0


def test_dtms_on_one_place_with_heights_of_two_vertical_crs_refused_saying_so(qgis_app, tmp_path):
    """Two DTMs on the same horizontal grid, one with NAVD88 heights in feet declared, were refused as 'another
    place' and told to reproject: the heights' vertical CRS is what differs, and the message says so."""
    from qgis.core import QgsApplication, QgsProcessingContext
    dsm, _ = _compound_pair(tmp_path)
    from bare_earth.core.grid import write_array
    ref = str(write_array(tmp_path / "ref.tif", np.full((40, 40), 90.0, np.float32),
                          (320000.0, 2.0, 0.0, 4300000.0, 0.0, -2.0), 26918))
    ok, msg = QgsApplication.processingRegistry().algorithmById("bareearth:evaluate").checkParameterValues(
        {"DTM": ref, "REFERENCE_DTM": dsm}, QgsProcessingContext())
    assert not ok and "has its heights in another vertical CRS" in msg and "another place" not in msg, msg
