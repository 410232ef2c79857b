"""bareearth:geodesic on points (INPUT_POINTS): rasterize, filter, classify, evaluate."""
import json

import pytest

pytestmark = pytest.mark.qgis


def test_geodesic_on_isprs_points(processing_run, shared_data, tmp_path):
    sample = shared_data / "isprs" / "samp21.txt"
    if not sample.exists():
        pytest.skip(f"{sample} is absent")
    r = processing_run("bareearth:geodesic", {"INPUT_POINTS": str(sample), "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                              "OUTPUT_MASK": "TEMPORARY_OUTPUT",
                                              "OUTPUT_POINTS": str(tmp_path / "cls.txt")})
    ev = processing_run("bareearth:evaluate", {"POINTS": r["OUTPUT_POINTS"], "TRUTH_POINTS": str(sample),
                                               "OUTPUT_JSON": str(tmp_path / "e.json"),
                                               "OUTPUT_HTML": str(tmp_path / "e.html")})
    figs = json.loads((tmp_path / "e.json").read_text())["results"]["classified points vs truth"]
    assert figs["n"] == 12960
    assert ev["TOTAL"] < 5.0 and ev["KAPPA"] > 80                 # samp21 every-point-ground: 22.2 %


def test_geodesic_needs_exactly_one_input(processing_run, tmp_path):
    from qgis.core import QgsProcessingException
    with pytest.raises(QgsProcessingException, match="INPUT"):
        processing_run("bareearth:geodesic", {"OUTPUT_DTM": str(tmp_path / "d.tif"),
                                              "OUTPUT_MASK": str(tmp_path / "m.tif")})
