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
