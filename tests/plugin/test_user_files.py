"""Files a QGIS user brings, through processing.run: rasters whose nodata is an alpha or mask
band, compound CRSs with a vertical unit, creation options, outputs that cannot be replaced."""
import numpy as np
import pytest

pytestmark = pytest.mark.qgis
gdal = pytest.importorskip("osgeo.gdal")


def _read(path):
    ds = gdal.Open(str(path))
    b = ds.GetRasterBand(1)
    return b.ReadAsArray(), b.GetNoDataValue()


def _scene():
    from bare_earth.core.synthetic import make_scene
    return make_scene("city", shape=(60, 70), seed=3)


def test_dsm_warped_with_an_alpha_band_keeps_its_outside_as_nodata(processing_run, tmp_path):
    """``gdalwarp -dstalpha`` writes heights 0 and a (Float32) alpha 0 outside the data: those
    cells are nodata in every output, and the heights band is taken without BAND. They were
    ground at height 0 in the DTM (and the two bands refused without BAND)."""
    from bare_earth.core.grid import write_array
    sc = _scene()
    src = write_array(tmp_path / "src.tif", sc.dsm, sc.geotransform, sc.epsg)
    warped = str(tmp_path / "warped.tif")
    gdal.Warp(warped, src, dstSRS="EPSG:32633", dstAlpha=True)
    ds = gdal.Open(warped)
    outside = ds.GetRasterBand(2).ReadAsArray() == 0
    assert ds.RasterCount == 2 and outside.any() and (~outside).any()
    ds = None
    r = processing_run("bareearth:morphological", {"INPUT": warped, "OUTPUT_DTM": str(tmp_path / "dtm.tif"),
                                                   "OUTPUT_MASK": str(tmp_path / "mask.tif")})
    dtm, _ = _read(r["OUTPUT_DTM"])
    mask, _ = _read(r["OUTPUT_MASK"])
    assert np.isnan(dtm[outside]).all() and np.isfinite(dtm[~outside]).all()
    assert (mask[outside] == 255).all() and (mask[~outside] != 255).all()
    assert np.nanmin(dtm) > 200          # no DTM cell pulled down to the 0 outside


@pytest.mark.parametrize("compound,cell_unit,z_unit", [("EPSG:26917+6360", 1.0, 1200 / 3937),
                                                       ("EPSG:2264+5703", 1200 / 3937, 1.0)])
def test_compound_crs_with_its_own_height_unit_equals_the_metric_run(processing_run, tmp_path, compound,
                                                                      cell_unit, z_unit):
    """One scene in metres and in a compound CRS whose horizontal and vertical units differ: the
    same mask, and the DTM in the vertical unit. The heights were taken in the horizontal unit
    (mask agreement 98-99 %, DTM off by up to 8 m)."""
    from osgeo import osr

    from bare_earth.core.grid import write_array
    sc = _scene()
    runs = {}
    for name, crs, cell, zu in (("m", "EPSG:26917", 1.0, 1.0), ("c", compound, cell_unit, z_unit)):
        s = osr.SpatialReference()
        s.SetFromUserInput(crs)
        gt = (500000.0 / cell, 1.0 / cell, 0.0, 4000000.0 / cell, 0.0, -1.0 / cell)
        p = write_array(tmp_path / f"{name}.tif", sc.dsm / np.float32(zu), gt, s.ExportToWkt())
        r = processing_run("bareearth:morphological", {"INPUT": p, "OUTPUT_DTM": str(tmp_path / f"{name}_dtm.tif"),
                                                       "OUTPUT_MASK": str(tmp_path / f"{name}_mask.tif")})
        runs[name] = (_read(r["OUTPUT_MASK"])[0], _read(r["OUTPUT_DTM"])[0] * np.float32(zu))
    np.testing.assert_array_equal(runs["c"][0], runs["m"][0])
    np.testing.assert_allclose(runs["c"][1], runs["m"][1], atol=1e-3)


def test_creation_options_that_break_the_mask_refused_and_float_predictor_runs(processing_run, tmp_path):
    """CREATE_OPTIONS=NBITS=1 wrote a mask of 0s and 1s (nodata 255 read as 1) without a word;
    PREDICTOR=3 (the floating-point predictor a DTM is compressed with) failed on the UInt8 mask
    after the whole run. Now the first is refused before any work and the second runs, its mask
    equal to the default run's."""
    from qgis.core import QgsProcessingException

    from bare_earth.core.grid import write_array
    sc = _scene()
    dsm = write_array(tmp_path / "dsm.tif", sc.dsm, sc.geotransform, sc.epsg)

    def params(name, options):
        return {"INPUT": dsm, "OUTPUT_DTM": str(tmp_path / f"{name}_dtm.tif"),
                "OUTPUT_MASK": str(tmp_path / f"{name}_mask.tif"), "CREATE_OPTIONS": options}
    before = sorted(p.name for p in tmp_path.iterdir())
    with pytest.raises(QgsProcessingException, match=r"CREATE_OPTIONS.*change the values of a UInt8 output"):
        processing_run("bareearth:morphological", params("nbits", "NBITS=1"))
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    ref = processing_run("bareearth:morphological", params("ref", ""))
    r = processing_run("bareearth:morphological", params("p3", "COMPRESS=ZSTD|PREDICTOR=3"))
    np.testing.assert_array_equal(_read(r["OUTPUT_MASK"])[0], _read(ref["OUTPUT_MASK"])[0])
    np.testing.assert_array_equal(_read(r["OUTPUT_DTM"])[0], _read(ref["OUTPUT_DTM"])[0])


def test_an_existing_read_only_output_refused_before_any_work(processing_run, tmp_path, read_only):
    """Re-running into outputs of which one is read-only: refused naming it, before any work, the
    old outputs as they were (the run failed at its end with a PermissionError traceback)."""
    from qgis.core import QgsProcessingException

    from bare_earth.core.grid import write_array
    sc = _scene()
    dsm = write_array(tmp_path / "dsm.tif", sc.dsm, sc.geotransform, sc.epsg)
    params = {"INPUT": dsm, "OUTPUT_DTM": str(tmp_path / "dtm.tif"), "OUTPUT_MASK": str(tmp_path / "mask.tif")}
    processing_run("bareearth:morphological", params)
    old = {k: (tmp_path / k).read_bytes() for k in ("dtm.tif", "mask.tif")}
    with read_only(tmp_path / "mask.tif"):
        with pytest.raises(QgsProcessingException, match=r"'Object mask' \(OUTPUT_MASK\).*exists and is read-only"):
            processing_run("bareearth:slopeprofile", params)
        assert {k: (tmp_path / k).read_bytes() for k in old} == old


def _dtm_warnings(processing_run, warning_log, tmp_path, z, sc, nodata, phrase):
    """Run bareearth:dtm on ``z`` written with ``nodata`` declared (None: none); the log's
    warnings holding ``phrase``, and all its warnings."""
    from bare_earth.core.grid import write_array
    tag = "none" if nodata is None else f"{nodata:g}"
    src = write_array(tmp_path / f"dsm{tag}.tif", z, sc.geotransform, sc.epsg, nodata=nodata)
    log = warning_log()
    processing_run("bareearth:dtm", {"INPUT": src, "OUTPUT_DTM": str(tmp_path / f"d{tag}.tif"),
                                     "OUTPUT_MASK": str(tmp_path / f"m{tag}.tif")}, feedback=log)
    return [w for w in log.warnings if phrase in w], log.warnings


def test_undeclared_minus_9999_border_warned_in_the_log(processing_run, tmp_path, warning_log):
    """A DSM exported with a -9999 border but no declared nodata: the log says so and how to
    declare it (the run went on silently, its DTM pulled down by kilometres beside the border);
    declared, no warning."""
    sc = _scene()
    z = sc.dsm.copy()
    z[:, :12] = -9999.0
    for nodata, expect in ((None, True), (-9999.0, False)):
        said, warnings = _dtm_warnings(processing_run, warning_log, tmp_path, z, sc, nodata, "a common nodata value")
        assert bool(said) == expect, warnings
        if expect:
            assert "720 cell(s) hold -9999" in said[0] and "gdal_edit.py -a_nodata -9999" in said[0]


def test_a_layers_additional_no_data_value_is_nodata(processing_run, tmp_path):
    """A DSM with an undeclared -9999 border, loaded in QGIS and given -9999 as an additional no-data
    value (Properties > Transparency, which draws those cells transparent): the filters take them
    as nodata, whether the layer or its path is given. They were filtered as heights (the DTM
    pulled down by kilometres)."""
    from qgis.core import QgsProject, QgsRasterLayer, QgsRasterRange

    from bare_earth.core.grid import write_array
    sc = _scene()
    z = sc.dsm.copy()
    z[:, :12] = -9999.0
    src = write_array(tmp_path / "dsm.tif", z, sc.geotransform, sc.epsg)
    layer = QgsRasterLayer(src, "dsm", "gdal")
    layer.dataProvider().setUserNoDataValue(1, [QgsRasterRange(-9999.0, -9999.0)])
    QgsProject.instance().addMapLayer(layer)
    try:
        for name, given in (("layer", layer), ("path", src)):
            r = processing_run("bareearth:morphological", {
                "INPUT": given, "OUTPUT_DTM": str(tmp_path / f"{name}_d.tif"),
                "OUTPUT_MASK": str(tmp_path / f"{name}_m.tif")})
            mask, dtm = _read(r["OUTPUT_MASK"])[0], _read(r["OUTPUT_DTM"])[0]
            assert (mask[:, :12] == 255).all() and (mask[:, 12:] != 255).all(), name
            assert np.isnan(dtm[:, :12]).all() and np.nanmin(dtm) > 200, name
    finally:
        QgsProject.instance().removeMapLayer(layer.id())


def test_outputs_of_an_ungeoreferenced_dsm_lie_on_it_in_qgis(processing_run, tmp_path):
    """A DSM without georeference (a scan, a photogrammetry export): QGIS draws its outputs over it
    (they lay at 0..+rows, the input at 0..-rows)."""
    from qgis.core import QgsRasterLayer
    sc = _scene()
    src = str(tmp_path / "nogeo.tif")
    ds = gdal.GetDriverByName("GTiff").Create(src, sc.dsm.shape[1], sc.dsm.shape[0], 1, gdal.GDT_Float32)
    ds.GetRasterBand(1).WriteArray(sc.dsm)
    ds = None
    r = processing_run("bareearth:morphological", {"INPUT": src, "OUTPUT_DTM": str(tmp_path / "d.tif"),
                                                   "OUTPUT_MASK": str(tmp_path / "m.tif")})
    extent = QgsRasterLayer(src, "in", "gdal").extent()
    for key in ("OUTPUT_DTM", "OUTPUT_MASK"):
        assert QgsRasterLayer(r[key], key, "gdal").extent() == extent, key


def test_a_file_without_crs_takes_the_crs_its_layer_was_given(processing_run, tmp_path):
    """An .asc or .tif without a CRS, loaded in QGIS and given one (Set Layer CRS): the filters
    work in it (feet converted) and the outputs carry it, as a run on the file with that CRS
    does. Heights in feet were taken as metres and the outputs had no CRS."""
    from osgeo import osr
    from qgis.core import QgsCoordinateReferenceSystem, QgsProject, QgsRasterLayer

    from bare_earth.core.grid import write_array
    sc = _scene()
    ft = 1200 / 3937
    gt = (500000.0 / ft, 1 / ft, 0.0, 4000000.0 / ft, 0.0, -1 / ft)
    bare = write_array(tmp_path / "bare.tif", sc.dsm / np.float32(ft), gt, "")
    own = write_array(tmp_path / "own.tif", sc.dsm / np.float32(ft), gt, 2264)
    layer = QgsRasterLayer(bare, "bare", "gdal")
    layer.setCrs(QgsCoordinateReferenceSystem("EPSG:2264"))
    QgsProject.instance().addMapLayer(layer)
    try:
        outs = {}
        for name, given in (("layer", layer), ("own", own)):
            outs[name] = processing_run("bareearth:dtm", {"INPUT": given, "OUTPUT_DTM": str(tmp_path / f"{name}_d.tif"),
                                                          "OUTPUT_MASK": str(tmp_path / f"{name}_m.tif")})
    finally:
        QgsProject.instance().removeMapLayer(layer.id())
    np.testing.assert_array_equal(_read(outs["layer"]["OUTPUT_MASK"])[0], _read(outs["own"]["OUTPUT_MASK"])[0])
    np.testing.assert_array_equal(_read(outs["layer"]["OUTPUT_DTM"])[0], _read(outs["own"]["OUTPUT_DTM"])[0])
    ds = gdal.Open(outs["layer"]["OUTPUT_DTM"])
    assert osr.SpatialReference(ds.GetProjection()).GetAuthorityCode(None) == "2264"


@pytest.mark.parametrize("outputs,written", [
    ({"OUTPUT_DTM": "x.sdat", "OUTPUT_MASK": "m.tif"}, "x.prj"),       # SAGA's .prj over the grid's own
    ({"OUTPUT_DTM": "d.tif", "OUTPUT_MASK": "x.img"}, "x.qml"),        # the mask's style: the input's style
])
def test_outputs_never_write_the_inputs_sidecars(processing_run, tmp_path, outputs, written):
    """An ASCII grid input x.asc with its x.prj: an output x.sdat rewrote x.prj (the input's CRS),
    and a mask x.img wrote x.qml, which QGIS then loads as x.asc's style. Refused before any work,
    naming the file; the input's files as they were."""
    import hashlib

    from qgis.core import QgsProcessingException

    from bare_earth.core.grid import write_array
    sc = _scene()
    src = write_array(tmp_path / "src.tif", sc.dsm, sc.geotransform, 2264)
    gdal.Translate(str(tmp_path / "x.asc"), src, format="AAIGrid")
    before = {p.name: hashlib.sha1(p.read_bytes()).hexdigest() for p in tmp_path.iterdir()}
    with pytest.raises(QgsProcessingException, match=rf"would write .*{written}, a file of the input"):
        processing_run("bareearth:morphological", {"INPUT": str(tmp_path / "x.asc"),
                                                   **{k: str(tmp_path / v) for k, v in outputs.items()}})
    assert {p.name: hashlib.sha1(p.read_bytes()).hexdigest() for p in tmp_path.iterdir()} == before


def test_a_mask_and_another_output_of_one_name_refused(processing_run, tmp_path):
    """OUTPUT_DTM x.tif and OUTPUT_MASK x.img: the mask's x.qml made QGIS draw the DTM with the
    mask's four classes. Refused before any work; other extensions of one name (x.asc and x.sdat,
    no mask) still run."""
    from qgis.core import QgsProcessingException

    from bare_earth.core.grid import write_array
    sc = _scene()
    src = write_array(tmp_path / "dsm.tif", sc.dsm, sc.geotransform, sc.epsg)
    with pytest.raises(QgsProcessingException, match=r"'DTM' \(OUTPUT_DTM\) and 'Object mask' \(OUTPUT_MASK\) "
                                                     r"share the name x"):
        processing_run("bareearth:morphological", {"INPUT": src, "OUTPUT_DTM": str(tmp_path / "x.tif"),
                                                   "OUTPUT_MASK": str(tmp_path / "x.img")})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dsm.tif"]
    processing_run("bareearth:morphological", {"INPUT": src, "OUTPUT_DTM": str(tmp_path / "y.asc"),
                                               "OUTPUT_NDSM": str(tmp_path / "y.sdat"),
                                               "OUTPUT_MASK": str(tmp_path / "m.tif")})


def test_the_session_keeps_gdals_exception_mode(processing_run, tmp_path):
    """A run (and the help, the provider's formats) left GDAL's Python exceptions on for the
    whole QGIS session, so another plugin's ``if gdal.Open(p) is None`` raised. The mode is as
    the session had it after every entry point, whichever it was."""
    from qgis.core import QgsApplication

    from bare_earth.core.grid import write_array
    sc = _scene()
    src = write_array(tmp_path / "dsm.tif", sc.dsm, sc.geotransform, sc.epsg)
    provider = QgsApplication.processingRegistry().providerById("bareearth")
    alg = QgsApplication.processingRegistry().algorithmById("bareearth:morphological")
    for a in provider.algorithms():          # every entry point, a mixin's too (the points input)
        for name in ("checkParameterValues", "processAlgorithm", "postProcessAlgorithm", "shortHelpString"):
            assert getattr(getattr(type(a), name), "gdal_mode_kept", False), (a.id(), name)
    for mode in (False, True):
        (gdal.UseExceptions if mode else gdal.DontUseExceptions)()
        try:
            processing_run("bareearth:morphological", {"INPUT": src, "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                                       "OUTPUT_MASK": "TEMPORARY_OUTPUT"})
            assert bool(gdal.GetUseExceptions()) == mode
            alg.shortHelpString()
            provider.supportedOutputRasterLayerExtensions()
            assert bool(gdal.GetUseExceptions()) == mode
        finally:
            gdal.UseExceptions()


def test_a_mask_named_as_a_vector_input_keeps_the_layers_style(processing_run, tmp_path):
    """OBJECT_AREAS buildings.shp with its style buildings.qml, OUTPUT_MASK buildings.tif: the
    mask's palette replaced the footprints' style. Refused before any work, the style as it was;
    a memory layer (no file) still runs."""
    from osgeo import ogr, osr
    from qgis.core import QgsFeature, QgsGeometry, QgsProcessingException, QgsVectorLayer

    from bare_earth.core.grid import write_array
    sc = _scene()
    dsm = write_array(tmp_path / "dsm.tif", sc.dsm, sc.geotransform, sc.epsg)
    x0, y0 = sc.geotransform[0], sc.geotransform[3]          # 1 m cells: rows 5-14, columns 10-19
    wkt = "POLYGON(({a} {c}, {b} {c}, {b} {d}, {a} {d}, {a} {c}))".format(a=x0 + 10, b=x0 + 20, c=y0 - 15, d=y0 - 5)
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(sc.epsg)
    ds = ogr.GetDriverByName("ESRI Shapefile").CreateDataSource(str(tmp_path / "buildings.shp"))
    lyr = ds.CreateLayer("buildings", srs, ogr.wkbPolygon)
    f = ogr.Feature(lyr.GetLayerDefn())
    f.SetGeometry(ogr.CreateGeometryFromWkt(wkt))
    lyr.CreateFeature(f)
    ds = lyr = f = None
    (tmp_path / "buildings.qml").write_text("<qgis>the footprints' style</qgis>")
    with pytest.raises(QgsProcessingException, match=r"would write .*buildings\.qml, a file of the input 'Object"):
        processing_run("bareearth:dtm", {"INPUT": dsm, "OBJECT_AREAS": str(tmp_path / "buildings.shp"),
                                         "OUTPUT_DTM": str(tmp_path / "d.tif"),
                                         "OUTPUT_MASK": str(tmp_path / "buildings.tif")})
    assert (tmp_path / "buildings.qml").read_text() == "<qgis>the footprints' style</qgis>"
    memory = QgsVectorLayer(f"Polygon?crs=EPSG:{sc.epsg}", "m", "memory")
    feat = QgsFeature()
    feat.setGeometry(QgsGeometry.fromWkt(wkt))
    memory.dataProvider().addFeatures([feat])
    r = processing_run("bareearth:dtm", {"INPUT": dsm, "OBJECT_AREAS": memory, "OUTPUT_DTM": str(tmp_path / "d.tif"),
                                         "OUTPUT_MASK": str(tmp_path / "m.tif")})
    assert (_read(r["OUTPUT_MASK"])[0][5:15, 10:20] == 1).all()


def test_evaluate_reads_a_dtm_layer_as_it_stands_in_qgis(processing_run, tmp_path):
    """A DTM file without a CRS (heights in US survey feet) given EPSG:2264 in QGIS, against a
    reference DTM with that CRS, one foot lower: an RMSE of one foot in metres (0.3048). The DTM
    was read as metres and the reference as feet converted: an RMSE of hundreds of metres."""
    from qgis.core import QgsCoordinateReferenceSystem, QgsProject, QgsRasterLayer

    from bare_earth.core.grid import write_array
    ft = 1200 / 3937
    gt = (500000.0 / ft, 1 / ft, 0.0, 4000000.0 / ft, 0.0, -1 / ft)
    z = np.full((30, 40), 1000.0, np.float32)
    dtm = write_array(tmp_path / "dtm.tif", z + 1.0, gt, "")
    ref = write_array(tmp_path / "ref.tif", z, gt, 2264)
    layer = QgsRasterLayer(dtm, "dtm", "gdal")
    layer.setCrs(QgsCoordinateReferenceSystem("EPSG:2264"))
    QgsProject.instance().addMapLayer(layer)
    try:
        r = processing_run("bareearth:evaluate", {"DTM": layer, "REFERENCE_DTM": ref,
                                                  "OUTPUT_JSON": str(tmp_path / "e.json"),
                                                  "OUTPUT_HTML": str(tmp_path / "e.html")})
    finally:
        QgsProject.instance().removeMapLayer(layer.id())
    assert r["RMSE"] == pytest.approx(ft, rel=1e-4)


@pytest.mark.parametrize("crs", ["EPSG:2264", "EPSG:2264+5703", "EPSG:32617 ft"])
def test_orthophoto_dem_in_feet_refused_whatever_its_height_unit(processing_run, tmp_path, crs):
    """The orthophoto tools work in metres: a DEM on a grid in feet is refused, also in a compound
    CRS whose heights are in metres (its height unit no longer stood for its grid's), and a DEM
    whose band states feet on a grid in metres, told how to write its heights in metres."""
    from osgeo import gdal, osr
    from qgis.core import QgsProcessingException
    from scipy import ndimage

    from bare_earth.core.grid import write_array
    crs, _, unit = crs.partition(" ")
    s = osr.SpatialReference()
    s.SetFromUserInput(crs)
    gt = (1000000.0, 3.0, 0.0, 500000.0, 0.0, -3.0)
    tex = (255.0 * ndimage.gaussian_filter(np.random.default_rng(7).random((80, 80)), 1.5)).astype(np.float32)
    dem = write_array(tmp_path / "dem.tif", np.full((80, 80), 100.0, np.float32), gt, s.ExportToWkt())
    if unit:
        ds = gdal.Open(dem, gdal.GA_Update)
        ds.GetRasterBand(1).SetUnitType(unit)
        ds = None
    a = write_array(tmp_path / "a.tif", tex, gt, s.ExportToWkt())
    b = write_array(tmp_path / "b.tif", tex, gt, s.ExportToWkt())
    message = r"states its heights are in 'ft' \(0\.3048 m\).*gdal_calc" if unit else "unit is not the metre"
    with pytest.raises(QgsProcessingException, match=message):
        processing_run("bareearth:orthoparallax", {"DEM": dem, "ORTHO_A": a, "ORTHO_B": b, "BASE_M": 300.0,
                                                   "HEIGHT_M": 1000.0, "OUTPUT_DEM": str(tmp_path / "o.tif"),
                                                   "OUTPUT_MASK": str(tmp_path / "m.tif")})


@pytest.mark.parametrize("key", ["OUTPUT_DTM", "OUTPUT_MASK"])
def test_an_output_onto_a_file_a_vrt_input_reads_refused(processing_run, tmp_path, key):
    """A VRT input over tiles: an output named as one of its tiles replaced the user's tile with
    the DTM (or the mask), so the VRT read the result from then on. Refused before any work,
    naming the tile and the VRT; every file as it was."""
    import hashlib

    from qgis.core import QgsProcessingException

    from bare_earth.core.grid import write_array
    sc = _scene()
    tile = write_array(tmp_path / "tile.tif", sc.dsm, sc.geotransform, sc.epsg)
    vrt = str(tmp_path / "mosaic.vrt")
    gdal.BuildVRT(vrt, [tile])
    before = hashlib.sha1((tmp_path / "tile.tif").read_bytes()).hexdigest()
    outputs = {"OUTPUT_DTM": str(tmp_path / "dtm.tif"), "OUTPUT_MASK": str(tmp_path / "mask.tif"), key: tile}
    with pytest.raises(QgsProcessingException, match=r"would write .*tile\.tif, a file the input 'Input DSM' "
                                                     r"\(INPUT\) \(.*mosaic\.vrt\) reads"):
        processing_run("bareearth:morphological", {"INPUT": vrt, **outputs})
    # (QGIS's layer of the VRT saves its statistics into mosaic.vrt itself, as loading it in QGIS does)
    assert hashlib.sha1((tmp_path / "tile.tif").read_bytes()).hexdigest() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mosaic.vrt", "tile.tif"]


def test_a_declared_nodata_value_that_is_also_a_height_warned(processing_run, tmp_path, warning_log):
    """A DSM of heights rounded to whole metres declaring one of those heights (the median) as its
    nodata: every cell holding it was read as missing without a word (a seventh of the cells, holes
    along a contour in the DTM); the log now says so and how to export it. Nodata -9999: no warning."""
    sc = _scene()
    z = np.round(sc.dsm).astype(np.float32)
    median = float(np.median(z))

    for nodata, expect in ((median, True), (-9999.0, False)):
        said, warnings = _dtm_warnings(processing_run, warning_log, tmp_path, z, sc, nodata, "lies among its heights")
        assert bool(said) == expect, warnings
        if expect:
            n = int(np.count_nonzero(z == median))
            assert f"declares {median:g} as its nodata value" in said[0] and f"({n} cell(s) read as nodata)" in said[0]


def test_a_scaled_band_whose_nodata_is_also_a_height_keeps_its_sea_level(processing_run, tmp_path):
    """UInt16 heights with nodata 0, scale 0.01 and offset -100 (a coast from -100 m): the DTM and
    the filled surface, written as heights, declared the stored 0 as their nodata, so the ground at
    0 m read as nodata in QGIS; they declare -100, the height of the nodata cells."""
    from osgeo import gdal

    from bare_earth.core.grid import write_array
    sc = _scene()
    counts = np.round((sc.dsm - np.median(sc.dsm) + 100.0) * 100).astype(np.uint16)   # the median at 0 m
    counts[0, 1:4] = 0       # nodata
    src = write_array(tmp_path / "coast.tif", counts, sc.geotransform, sc.epsg, nodata=0, dtype="UInt16")
    ds = gdal.Open(src, gdal.GA_Update)
    ds.GetRasterBand(1).SetScale(0.01)
    ds.GetRasterBand(1).SetOffset(-100.0)
    ds = None
    res = processing_run("bareearth:dtm", {"INPUT": src, "OUTPUT_DTM": str(tmp_path / "dtm.tif"),
                                           "OUTPUT_MASK": str(tmp_path / "mask.tif")})
    filled = processing_run("bareearth:filldtm", {"INPUT": src, "MASK": res["OUTPUT_MASK"], "FILL_NODATA": False,
                                                  "OUTPUT": str(tmp_path / "filled.tif")})
    for path in (res["OUTPUT_DTM"], filled["OUTPUT"]):
        ds = gdal.Open(path)
        band = ds.GetRasterBand(1)
        a = band.ReadAsArray()
        assert band.GetNoDataValue() == -100.0, path
        assert np.count_nonzero(a == -100.0) == 3, path
        assert np.count_nonzero(a == 0.0) >= np.count_nonzero(counts == 10000) // 2 > 0, path   # sea level kept


def test_creation_options_for_an_output_of_another_format_warned(processing_run, tmp_path, warning_log):
    """Creation options or COG with an output in another format than GeoTIFF (.asc, .img): they
    are GeoTIFF's and were left out without a word; the log names each such output. GeoTIFF
    outputs, and no options: no warning."""
    from bare_earth.core.grid import write_array
    sc = _scene()
    src = write_array(tmp_path / "dsm.tif", sc.dsm, sc.geotransform, sc.epsg)

    cases = [({"CREATE_OPTIONS": "COMPRESS=LZW"}, ".asc", ".tif", ["'DTM' (OUTPUT_DTM) is written as Arc/Info ASCII "
                                                                  "grid (.asc): the creation options apply"]),
             ({"COG": True}, ".img", ".img", ["'DTM' (OUTPUT_DTM) is written as ERDAS Imagine (.img): COG (a cloud-"
                                              "optimised GeoTIFF) applies to GeoTIFF outputs (.tif) only and is not "
                                              "used for it.",   # QA14: 'the COG apply ... and are not used'
                                              "'Object mask' (OUTPUT_MASK) is written as ERDAS Imagine (.img)"]),
             ({"COG": True, "CREATE_OPTIONS": "COMPRESS=LZW"}, ".asc", ".tif",
              ["'DTM' (OUTPUT_DTM) is written as Arc/Info ASCII grid (.asc): the creation options and COG apply to "
               "GeoTIFF outputs (.tif) only and are not used for it."]),
             ({"CREATE_OPTIONS": "COMPRESS=LZW"}, ".tif", ".tif", []),
             ({}, ".asc", ".asc", [])]
    for k, (extra, dtm_ext, mask_ext, said) in enumerate(cases):
        log = warning_log()
        processing_run("bareearth:slopeprofile", {"INPUT": src, "OUTPUT_DTM": str(tmp_path / f"d{k}{dtm_ext}"),
                                                  "OUTPUT_MASK": str(tmp_path / f"m{k}{mask_ext}"), **extra},
                       feedback=log)
        hits = [w for w in log.warnings if "to GeoTIFF outputs (.tif) only" in w]
        assert len(hits) == len(said) and all(s in h for s, h in zip(said, hits)), log.warnings
