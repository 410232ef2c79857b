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
