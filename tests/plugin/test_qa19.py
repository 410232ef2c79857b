"""QA pass 19 through processing.run and the algorithms' checks. Each test failed before its fix."""
import numpy as np
import pytest

pytestmark = pytest.mark.qgis


def _check(alg, params):
    from qgis.core import QgsApplication, QgsProcessingContext
    return QgsApplication.processingRegistry().algorithmById(alg).checkParameterValues(params,
                                                                                      QgsProcessingContext())


@pytest.mark.parametrize("alg", ["bareearth:dtm", "bareearth:morphological", "bareearth:slopeprofile",
                                 "bareearth:geodesic", "bareearth:rascor", "bareearth:curvature"])
def test_heights_far_steeper_than_terrain_refused_in_the_check(qgis_app, tmp_path, alg):
    """Pass 18 left the relief check (pipeline.check_relief: heights spanning more than 20 times the raster's
    diagonal, a cell size in mm read as m) in the core only: the dialog accepted a city at 1 mm cells and the
    run failed after Run. Refused by the check now, naming the cell size and the fix; at 1 cm (a warning in
    the run's log) and 1 m the check passes."""
    from bare_earth.core.grid import write_array
    from bare_earth.core.synthetic import make_scene
    z = make_scene("city", (120, 120), seed=1).dsm
    outs = {"OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif")}
    for cell, refused in ((0.001, True), (0.01, False), (1.0, False)):
        path = write_array(tmp_path / f"dsm_{cell:g}.tif", z, (500000.0, cell, 0.0, 5400000.0, 0.0, -cell), 32632)
        ok, msg = _check(alg, {"INPUT": str(path), **outs})
        if refused:
            assert not ok and "times the diagonal of the 120 x 120 cells of 0.001 x 0.001 m" in msg \
                and "gdal_edit.py -tr" in msg, msg
        else:
            assert ok, msg


@pytest.mark.parametrize("alg", ["bareearth:morphological", "bareearth:geodesic"])
def test_points_far_steeper_than_terrain_refused_in_the_check(qgis_app, tmp_path, alg):
    """The same through INPUT_POINTS: a city's points with x and y in mm in a CRS in metres were rasterized
    and refused only then (run_array's check). Refused by the check, naming INPUT_POINTS and the fix; the
    same points in metres pass."""
    from bare_earth.core.synthetic import make_scene
    z = make_scene("city", (60, 60), seed=1).dsm
    r, c = np.mgrid[0:60, 0:60]
    for scale, refused in ((0.001, True), (1.0, False)):
        path = tmp_path / f"pts_{scale:g}.txt"
        np.savetxt(path, np.column_stack([500000.0 + (c.ravel() + 0.5) * scale,
                                          5400000.0 - (r.ravel() + 0.5) * scale, z.ravel()]), fmt="%.4f")
        ok, msg = _check(alg, {"INPUT_POINTS": str(path), "POINTS_CRS": "EPSG:32632",
                               "OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif"),
                               "OUTPUT_POINTS": str(tmp_path / "p.txt")})
        if refused:
            assert not ok and "(INPUT_POINTS): the heights span" in msg and "cell size is probably wrong" in msg, msg
        else:
            assert ok, msg


@pytest.mark.parametrize("alg", ["bareearth:slopeprofile", "bareearth:dtm", "bareearth:filldtm"])
def test_classic_tiff_over_4_gb_refused_in_the_check(qgis_app, tmp_path, alg):
    """CREATE_OPTIONS BIGTIFF=NO for a DTM of 33000 x 33000 cells (4.36 GB of Float32) passed the dialog's check
    and failed once written (compressed: when its data passed 4 GB, after the work). Refused by the check,
    naming the output and the fix; without BIGTIFF=NO it passes."""
    from osgeo import gdal
    path = str(tmp_path / "big.tif")
    ds = gdal.GetDriverByName("GTiff").Create(path, 33000, 33000, 1, gdal.GDT_Float32,
                                              ["TILED=YES", "SPARSE_OK=TRUE", "COMPRESS=DEFLATE", "BIGTIFF=YES"])
    ds.SetGeoTransform((500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0))
    ds.GetRasterBand(1).SetNoDataValue(-9999.0)
    ds.GetRasterBand(1).WriteArray(np.linspace(100.0, 110.0, 1024 * 1024, dtype=np.float32).reshape(1024, 1024),
                                   16000, 16000)
    ds = None
    params = {"INPUT": path, "OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif")}
    key = "OUTPUT_DTM"
    if alg == "bareearth:filldtm":
        params, key = {"INPUT": path, "FILL_NODATA": True, "OUTPUT": str(tmp_path / "d.tif")}, "OUTPUT"
    ok, msg = _check(alg, {**params, "CREATE_OPTIONS": "BIGTIFF=NO"})
    assert not ok and f"({key}): the output" in msg and "holds 4.36 GB uncompressed" in msg \
        and "give BIGTIFF=YES" in msg, msg
    ok, msg = _check(alg, {**params, "CREATE_OPTIONS": "BIGTIFF=YES|COMPRESS=ZSTD"})
    assert ok, msg


def test_layer_in_gdal_memory_with_worker_processes_refused_in_the_check(qgis_app, tmp_path):
    """A layer whose source is in GDAL's memory (/vsimem/) ran with PROCESSES=2 and failed in the workers once
    the parameters were derived, calling the raster "truncated or corrupt". Refused by the check; PROCESSES=1
    passes."""
    from osgeo import gdal
    from qgis.core import QgsRasterLayer

    from bare_earth.core.grid import write_array
    from bare_earth.core.synthetic import make_scene
    src = "/vsimem/qa19-layer.tif"
    gdal.Translate(src, write_array(tmp_path / "dsm.tif", make_scene("city", (120, 120), seed=1).dsm,
                                    (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0), 32632))
    try:
        layer = QgsRasterLayer(src, "in memory")
        assert layer.isValid()
        params = {"INPUT": layer, "OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif")}
        ok, msg = _check("bareearth:slopeprofile", {**params, "PROCESSES": 2})
        assert not ok and "lives in this process's memory (GDAL's /vsimem/)" in msg and "PROCESSES = 1" in msg, msg
        ok, msg = _check("bareearth:slopeprofile", {**params, "PROCESSES": 1})
        assert ok, msg
    finally:
        gdal.Unlink(src)


def test_survey_far_steeper_than_terrain_refused_in_the_check(qgis_app, tmp_path):
    """bareearth:tiles: four tiles of a city at 1 mm cells passed the dialog's check and were refused by
    run_survey after Run. Refused by the check now; at 1 m they pass."""
    pytest.importorskip("distributed")
    from bare_earth.core.grid import write_array
    from bare_earth.core.synthetic import make_scene
    z = make_scene("city", (120, 120), seed=1).dsm
    for cell, refused in ((0.001, True), (1.0, False)):
        paths = []
        for k, (r, c) in enumerate(((0, 0), (0, 60), (60, 0), (60, 60))):
            paths.append(str(write_array(tmp_path / f"t{cell:g}_{k}.tif", z[r:r + 60, c:c + 60],
                                         (500000.0 + c * cell, cell, 0.0, 5400000.0 - r * cell, 0.0, -cell), 32632)))
        ok, msg = _check("bareearth:tiles", {"INPUT_LAYERS": paths, "METHOD": 0,
                                             "OUTPUT_FOLDER": str(tmp_path / f"out{cell:g}")})
        if refused:
            assert not ok and "times the diagonal of the 120 x 120 cells of 0.001 x 0.001 m" in msg \
                and "(in the whole survey (120 x 120 cells))" in msg, msg
        else:
            assert ok, msg
        assert not (tmp_path / f"out{cell:g}").exists()
