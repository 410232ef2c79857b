"""QA pass 20 through processing.run, qgis_process and the algorithms' checks. Each test failed before its fix."""
import pytest

pytestmark = pytest.mark.qgis


def _check(alg, params):
    from qgis.core import QgsApplication, QgsProcessingContext
    return QgsApplication.processingRegistry().algorithmById(alg).checkParameterValues(params,
                                                                                      QgsProcessingContext())


def test_tiles_in_gdal_memory_refused_saying_where_they_live(qgis_app, tmp_path):
    """bareearth:tiles given a layer of a raster in GDAL's memory (/vsimem/, made by a script or another plugin)
    said "1 tile(s) are missing ... check the path": it exists, but in this process alone, which the survey's
    workers cannot read. The check says so and what to do."""
    pytest.importorskip("distributed")
    from osgeo import gdal
    from qgis.core import QgsRasterLayer

    from bare_earth.core.grid import write_array
    from bare_earth.core.synthetic import make_scene
    z = make_scene("flat", (64, 64), seed=1).dsm
    disk = write_array(tmp_path / "t.tif", z, (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0), 32632)
    mem = "/vsimem/qa20_tile.tif"
    gdal.Translate(mem, str(disk))
    try:
        layer = QgsRasterLayer(mem, "in memory")
        assert layer.isValid()
        ok, msg = _check("bareearth:tiles", {"INPUT_LAYERS": [layer], "METHOD": 0,
                                             "OUTPUT_FOLDER": str(tmp_path / "out")})
        assert not ok and "lives in this process's memory (GDAL's /vsimem/)" in msg and "missing" not in msg, msg
    finally:
        gdal.Unlink(mem)
    ok, msg = _check("bareearth:tiles", {"INPUT_LAYERS": [str(disk)], "METHOD": 0,
                                         "OUTPUT_FOLDER": str(tmp_path / "out")})
    assert ok, msg


@pytest.mark.parametrize("options,lossy", [("DISCARD_LSB=20", True), ("NBITS=16", True),
                                           ("COMPRESS=LERC|MAX_Z_ERROR=0.05", True),
                                           ("COMPRESS=ZSTD|PREDICTOR=3", False)])
def test_creation_options_that_change_the_heights_are_warned(processing_run, warning_log, tmp_path, options, lossy):
    """CREATE_OPTIONS DISCARD_LSB=20 wrote a DTM of one height (288 m for heights of 297-303 m) and NBITS=16 one of
    half floats (0.2 m off), without a word: the probe of the options guarded the mask's codes only. The run's log
    now warns, saying by how much heights of 312-464 m come back off; lossless options pass silently."""
    from bare_earth.core.grid import write_array
    from bare_earth.core.synthetic import make_scene
    z = make_scene("city", (64, 64), seed=1).dsm
    path = write_array(tmp_path / "dsm.tif", z, (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0), 32632)
    fb = warning_log()
    processing_run("bareearth:morphological", {"INPUT": str(path), "OUTPUT_DTM": str(tmp_path / "d.tif"),
                                               "OUTPUT_MASK": str(tmp_path / "m.tif"), "CREATE_OPTIONS": options},
                   feedback=fb)
    said = [w for w in fb.warnings if "lossily" in w]
    assert bool(said) == lossy, fb.warnings
    if lossy:
        assert f"The creation options '{options}' store the heights of the Float32 outputs (DTM, nDSM) lossily: " \
               "heights of 312-464 m written with them come back up to" in said[0]


def test_a_shared_parameter_name_gets_each_methods_own_label(qgis_app):
    """curvature's TERRAIN_SLOPE (the terrain's steep slope a wall must out-rise) was labelled with RASCOR's "Neighbour
    test: terrain slope for a height's place in its cell": the shared LABELS entry of the name, which RASCOR's step 3
    uses in another sense. A label naming one method's stage (RASCOR's tests and steps) is that method's alone; every
    other method using the name has its own wording."""
    from qgis.core import QgsApplication

    from bare_earth.algorithms import labels
    from bare_earth.core import methods
    reg = QgsApplication.processingRegistry()
    label = reg.algorithmById("bareearth:curvature").parameterDefinition("TERRAIN_SLOPE").description()
    assert label.startswith("Wall test: the terrain's steep slope (rise/run)"), label
    rascor_words = ("Neighbour test", "Neighbour and level tests", "Step ", "Outlier test")
    for name in methods.available_methods():
        if name == "rascor":
            continue
        for p in methods.get_method(name).params:
            shared = labels.LABELS.get(p.name, "")
            if shared.startswith(rascor_words):
                assert (name, p.name) in labels.METHOD_LABELS, (name, p.name, shared)


def test_an_output_in_gdal_memory_refused_saying_why(qgis_app, tmp_path):
    """An output given as a GDAL virtual file (/vsimem/d.tif, a script's habit) was refused with "the output folder
    '/vsimem' does not exist: create it": no folder can be created there. Outputs are written as work files on disk
    and moved into place; the message says so, for a filter's output and for a survey's output folder."""
    from bare_earth.core.grid import write_array
    from bare_earth.core.synthetic import make_scene
    dsm = str(write_array(tmp_path / "dsm.tif", make_scene("flat", (48, 48), seed=1).dsm,
                          (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0), 32632))
    ok, msg = _check("bareearth:morphological", {"INPUT": dsm, "OUTPUT_DTM": "/vsimem/qa20_d.tif",
                                                 "OUTPUT_MASK": str(tmp_path / "m.tif")})
    assert not ok and "the output '/vsimem/qa20_d.tif' is a GDAL virtual file (vsimem): outputs are written as " \
                      "work files on disk" in msg and "does not exist" not in msg, msg
    pytest.importorskip("distributed")
    ok, msg = _check("bareearth:tiles", {"INPUT_LAYERS": [dsm], "METHOD": 0, "OUTPUT_FOLDER": "/vsimem/qa20_out"})
    assert not ok and "is a GDAL virtual file (vsimem)" in msg, msg
