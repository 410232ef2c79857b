"""QA pass 25 through the algorithms: a graphical model's steps, layers given as files of another kind, a survey
folder without tiles. Each test failed before its fix."""
import os
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.qgis
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
MODEL = os.path.join(ROOT, "examples", "rasterize_filter_classify.model3")
GT = (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0)


def _points(path):
    """A text point file of 4000 points (x y z) on a tilted plane, 48 x 48 m."""
    rng = np.random.default_rng(0)
    x, y = 500000 + rng.uniform(0, 48, 4000), 5400000 - rng.uniform(0, 48, 4000)
    np.savetxt(path, np.c_[x, y, 100 + 0.05 * (x - 500000) + 0.05 * (5400000 - y)], fmt="%.3f")
    return str(path)


def _dsm(path):
    from bare_earth.core.grid import write_array
    z = np.add.outer(np.arange(48.0), np.arange(48.0)) * 0.05 + 100.0
    z[10:20, 10:20] += 6.0
    return str(write_array(path, z.astype(np.float32), GT, 32632))


def _model(path=MODEL):
    from qgis.core import QgsProcessingModelAlgorithm
    model = QgsProcessingModelAlgorithm()
    assert model.fromFile(path)
    return model


def _filter_model(tmp_path):
    """A model of one step: bareearth:morphological on the model's raster input 'dsm', its DTM and mask the
    model's outputs."""
    from qgis.core import (
        QgsProcessingModelAlgorithm,
        QgsProcessingModelChildAlgorithm,
        QgsProcessingModelChildParameterSource,
        QgsProcessingModelOutput,
        QgsProcessingModelParameter,
        QgsProcessingParameterRasterLayer,
    )
    model = QgsProcessingModelAlgorithm("one filter", "qa25")
    model.addModelParameter(QgsProcessingParameterRasterLayer("dsm", "DSM"), QgsProcessingModelParameter("dsm"))
    child = QgsProcessingModelChildAlgorithm("bareearth:morphological")
    child.setChildId("filter")
    child.addParameterSources("INPUT", [QgsProcessingModelChildParameterSource.fromModelParameter("dsm")])
    outputs = {}
    for key, name in (("OUTPUT_DTM", "dtm"), ("OUTPUT_MASK", "mask")):
        out = QgsProcessingModelOutput(name)
        out.setChildId("filter")
        out.setChildOutputName(key)
        outputs[name] = out
    child.setModelOutputs(outputs)
    model.addChildAlgorithm(child)
    path = str(tmp_path / "one_filter.model3")
    assert model.toFile(path)
    return _model(path)


def test_a_models_step_does_not_overwrite_its_input(processing_run, tmp_path):
    """QGIS does not run a model step's checkParameterValues: the example model (rasterize -> filter ->
    classify) given the points file as its classified output overwrote the points with their classes ('Model
    processed OK'), and a filter step given its input DSM as its DTM overwrote the DSM. The steps now check
    their outputs before any work and refuse, the input untouched."""
    from qgis.core import QgsProcessingException
    points = _points(tmp_path / "points.txt")
    before = Path(points).read_bytes()
    with pytest.raises(QgsProcessingException):
        processing_run(_model(), {"points": points, "classify:classified": points,
                                  "filter:dtm": str(tmp_path / "dtm.tif"), "filter:mask": str(tmp_path / "mask.tif")})
    assert Path(points).read_bytes() == before
    dsm = _dsm(tmp_path / "dsm.tif")
    before = Path(dsm).read_bytes()
    with pytest.raises(QgsProcessingException):
        processing_run(_filter_model(tmp_path), {"dsm": dsm, "filter:dtm": dsm, "filter:mask": str(tmp_path / "m.tif")})
    assert Path(dsm).read_bytes() == before
    assert not os.path.exists(tmp_path / "m.tif")


def _errors():
    """A processing feedback that keeps the errors reported to it (``.errors``)."""
    from qgis.core import QgsProcessingFeedback

    class Errors(QgsProcessingFeedback):
        def __init__(self):
            super().__init__()
            self.errors = []

        def reportError(self, text, fatal_error=False):  # noqa: N802
            self.errors.append(text)
    return Errors()


def test_a_models_step_names_a_missing_output_folder_before_work(processing_run, tmp_path):
    """A model step whose output lies in a missing folder failed after its work with GDAL's "Attempt to create
    new tiff file '.../.dtm.0000012-abc.partial' failed: No such file or directory", naming a work file; it
    now fails before the work, naming the folder."""
    from qgis.core import QgsProcessingException
    feedback = _errors()
    dsm = _dsm(tmp_path / "dsm.tif")
    with pytest.raises(QgsProcessingException):
        processing_run(_filter_model(tmp_path), {"dsm": dsm, "filter:dtm": str(tmp_path / "no" / "dtm.tif"),
                                                 "filter:mask": str(tmp_path / "m.tif")}, feedback=feedback)
    said = " ".join(feedback.errors)
    assert not os.path.exists(tmp_path / "m.tif")
    assert "'{}' does not exist".format(tmp_path / "no") in said and "partial" not in said


def _vector(path, layers):
    """A GeoPackage of polygon layers {name: (col0, row0, col1, row1)} on the DSM's grid (EPSG:32632)."""
    from osgeo import ogr, osr
    ds = ogr.GetDriverByName("GPKG").CreateDataSource(str(path))
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(32632)
    for name, (c0, r0, c1, r1) in layers.items():
        lay = ds.CreateLayer(name, srs, ogr.wkbPolygon)
        f = ogr.Feature(lay.GetLayerDefn())
        x0, y0 = GT[0], GT[3]
        f.SetGeometry(ogr.CreateGeometryFromWkt(
            f"POLYGON(({x0 + c0} {y0 - r0},{x0 + c1} {y0 - r0},{x0 + c1} {y0 - r1},{x0 + c0} {y0 - r1},"
            f"{x0 + c0} {y0 - r0}))"))
        lay.CreateFeature(f)
    ds = None
    return str(path)


def _check(alg_id, params):
    from qgis.core import QgsApplication, QgsProcessingContext
    alg = QgsApplication.processingRegistry().createAlgorithmById(alg_id)
    return alg.checkParameterValues(params, QgsProcessingContext())


def test_a_file_of_another_kind_is_named_as_such(qgis_app, tmp_path):
    """A point file given as a DSM, a vector layer given as a raster and a raster given as object areas were
    refused with QGIS's "Could not load source layer for INPUT: points.txt not found", the file there. The
    message now says what the file is and what to give."""
    dsm, points = _dsm(tmp_path / "dsm.tif"), _points(tmp_path / "points.txt")
    vec = _vector(tmp_path / "areas.gpkg", {"houses": (30, 30, 35, 35)})
    out = {"OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif")}
    cases = [("bareearth:dtm", {"INPUT": points}, "is a point cloud or a text file, not a raster",
              "bareearth:rasterizepoints"),
             ("bareearth:morphological", {"INPUT": points}, "not a raster", "(INPUT_POINTS) instead"),
             ("bareearth:dtm", {"INPUT": vec}, "is a vector layer, not a raster", "give a raster"),
             ("bareearth:dtm", {"INPUT": dsm, "OBJECT_AREAS": dsm}, "is a raster, not a vector layer",
              "Polygonize"),
             ("bareearth:rascor", {"INPUT": dsm, "BREAKLINES": points}, "'Break lines' (BREAKLINES)",
              "not a vector layer")]
    for alg_id, given, what, fix in cases:
        ok, msg = _check(alg_id, dict(given, **out))
        assert not ok and what in msg and fix in msg and "not found" not in msg, (alg_id, given, msg)


def test_a_file_of_several_vector_layers_given_as_its_path_refused_naming_them(processing_run, tmp_path):
    """A GeoPackage of two polygon layers given as its path ran with its first layer ('roads' here, not the
    'houses' meant) without a word; it is refused naming the layers and the '|layername=' to give, and the
    layer so given runs."""
    from osgeo import gdal
    dsm = _dsm(tmp_path / "dsm.tif")
    vec = _vector(tmp_path / "areas.gpkg", {"roads": (2, 40, 6, 44), "houses": (30, 30, 35, 35)})
    out = {"OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif")}
    ok, msg = _check("bareearth:dtm", dict(INPUT=dsm, OBJECT_AREAS=vec, **out))
    assert not ok and "holds 2 vector layers (roads, houses)" in msg and f"'{vec}|layername=houses'" in msg, msg
    got = processing_run("bareearth:dtm", dict(INPUT=dsm, OBJECT_AREAS=vec + "|layername=houses", **out))
    mask = gdal.Open(got["OUTPUT_MASK"]).ReadAsArray()
    assert (mask[30:35, 30:35] == 1).all() and not (mask[40:44, 2:6] == 1).any()


def test_points_outside_a_dtm_of_another_crs_named_with_both_crs(qgis_app, tmp_path):
    """Points in UTM against a DTM in degrees were refused as outside "the DTM spans x 9.000..9.000, y
    48.700..48.700" (three decimals of degrees), without a word of the CRS. The extent is now given to its
    significant digits and both CRS named."""
    from bare_earth.core.grid import write_array
    points = _points(tmp_path / "points.txt")
    z = np.full((48, 48), 100.0, np.float32)
    dtm = str(write_array(tmp_path / "dtm.tif", z, (9.0, 1e-5, 0.0, 48.7, 0.0, -1e-5), 4326))
    ok, msg = _check("bareearth:classifypoints", {"INPUT": points, "CRS": "EPSG:32632", "DTM": dtm,
                                                  "OUTPUT": str(tmp_path / "c.txt")})
    assert not ok and "x 9..9.00048" in msg and "differs from the DTM's (WGS 84)" in msg, msg


def test_a_required_text_given_empty_refused_naming_it_and_its_default(qgis_app, tmp_path):
    """filldtm's FILL_CODES given empty (qgis_process 'FILL_CODES=') was refused with QGIS's bare "Incorrect
    parameter value for 'Mask codes to fill' (FILL_CODES)"; the message now says it is empty and names the
    default taken when it is left out."""
    dsm = _dsm(tmp_path / "dsm.tif")
    ok, msg = _check("bareearth:filldtm", {"INPUT": dsm, "FILL_CODES": " ", "OUTPUT": str(tmp_path / "f.tif")})
    assert not ok and "(FILL_CODES) is empty" in msg and "default '1,2'" in msg, msg
    ok, msg = _check("bareearth:filldtm", {"INPUT": dsm, "OUTPUT": str(tmp_path / "f.tif")})
    assert ok, msg
