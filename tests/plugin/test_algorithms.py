"""The plugin through processing.run and qgis_process: outputs, conventions, bad inputs."""
import hashlib
import math

import numpy as np
import pytest

pytestmark = pytest.mark.qgis


def _read(path, band=1):
    from osgeo import gdal
    ds = gdal.Open(str(path))
    b = ds.GetRasterBand(band)
    return b.ReadAsArray(), b.GetNoDataValue(), ds.GetGeoTransform(), ds.GetProjection(), ds.RasterCount


def _sha(path):
    return hashlib.sha1(open(path, "rb").read()).hexdigest()


def filter_algorithms():
    """Ids of every registered filter algorithm (the table the conventions apply to)."""
    from bare_earth.algorithms import all_algorithms
    from bare_earth.algorithms.filter_base import FilterAlgorithm
    return [a.name() for a in all_algorithms() if isinstance(a, FilterAlgorithm)]


def test_provider_registered(qgis_app):
    from qgis.core import QgsApplication
    prov = QgsApplication.processingRegistry().providerById("bareearth")
    assert prov is not None and prov.name() == "Bare Earth"
    assert prov.longName().startswith("Bare Earth ")
    ids = {a.id() for a in prov.algorithms()}
    assert {"bareearth:slopeprofile", "bareearth:filldtm", "bareearth:evaluate"} <= ids
    for a in prov.algorithms():
        assert a.shortHelpString() and a.helpUrl()
        for p in a.parameterDefinitions():
            assert p.help(), f"{a.id()}:{p.name()} has no help"


@pytest.mark.parametrize("alg", filter_algorithms())
def test_filter_outputs_follow_conventions(processing_run, scene_files, alg):
    d = scene_files["dir"]
    before = _sha(scene_files["dsm"])
    res = processing_run(f"bareearth:{alg}", {"INPUT": scene_files["dsm"], "OUTPUT_DTM": str(d / f"{alg}_dtm.tif"),
                                              "OUTPUT_MASK": str(d / f"{alg}_mask.tif"),
                                              "OUTPUT_NDSM": str(d / f"{alg}_ndsm.tif")})
    assert _sha(scene_files["dsm"]) == before                      # input untouched
    z, znd, gt, crs, _ = _read(scene_files["dsm"])
    dtm, dnd, dgt, dcrs, _ = _read(res["OUTPUT_DTM"])
    mask, mnd, mgt, _, _ = _read(res["OUTPUT_MASK"])
    ndsm, _, _, _, _ = _read(res["OUTPUT_NDSM"])
    assert dgt == gt and mgt == gt and dcrs == crs                # same grid and CRS
    assert dnd == znd == -9999.0 and mnd == 255                   # nodata kept
    assert dtm.dtype == np.float32 and mask.dtype == np.uint8
    nod = z == -9999.0
    assert (mask[nod] == 255).all() and (dtm[nod] == -9999.0).all()
    assert set(np.unique(mask)) <= {0, 1, 2, 255}
    ground = mask == 0
    np.testing.assert_allclose(dtm[ground], z[ground])           # ground cells exact
    assert np.isfinite(dtm[~nod]).all()
    np.testing.assert_allclose(ndsm[~nod], (z - dtm)[~nod], atol=1e-4)
    truth = scene_files["scene"].mask
    obj = (truth == 1) & ~nod
    assert (mask[obj] != 0).mean() > 0.8                          # most objects removed
    assert (d / f"{alg}_mask.qml").exists()


def test_slopeprofile_log_states_values_used(processing_run, scene_files):
    from qgis.core import QgsProcessingFeedback

    class Log(QgsProcessingFeedback):
        text = []

        def pushInfo(self, info):  # noqa: N802
            self.text.append(info)

    fb = Log()
    processing_run("bareearth:slopeprofile", {"INPUT": scene_files["dsm"], "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                              "OUTPUT_MASK": "TEMPORARY_OUTPUT"}, feedback=fb)
    log = "\n".join(fb.text)
    for key in ("(SLOPE_THRESHOLD_DEG) = ", "(TERRAIN_SLOPE_DEG) = ", "(TOLERANCE_M) = ", "rejected_by_x_percent",
                "classes_percent"):
        assert key in log


def test_slopeprofile_user_value_used(processing_run, scene_files):
    from qgis.core import QgsProcessingFeedback
    lines = []
    fb = QgsProcessingFeedback()
    fb.pushInfo = lambda s: lines.append(s)
    processing_run("bareearth:slopeprofile", {"INPUT": scene_files["dsm"], "SLOPE_THRESHOLD_DEG": 33.0,
                                              "OUTPUT_DTM": "TEMPORARY_OUTPUT", "OUTPUT_MASK": "TEMPORARY_OUTPUT"},
                   feedback=fb)
    assert any("'Terrain slope threshold (degrees)' (SLOPE_THRESHOLD_DEG) = 33" in s for s in lines)


def _write(path, arr, gt=(500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0), epsg=32632, nodata=None):
    from bare_earth.core.grid import write_array
    return write_array(path, arr, gt, epsg, nodata=nodata)


BAD = [
    ("multiband", lambda p: _write(p, np.zeros((2, 20, 20), np.float32)), {}, "bands"),
    ("allnodata", lambda p: _write(p, np.full((20, 20), -9999.0, np.float32), nodata=-9999.0), {}, "no valid cell"),
    ("tiny", lambda p: _write(p, np.zeros((2, 2), np.float32)), {}, "too small"),
    ("window", lambda p: _write(p, np.zeros((30, 30), np.float32)), {"MAX_OBJECT_SIZE_M": 5000.0},
     "larger than the raster"),
]


@pytest.mark.parametrize("name,make,extra,message", BAD, ids=[b[0] for b in BAD])
def test_bad_inputs_refused_before_work(processing_run, tmp_path, name, make, extra, message):
    from qgis.core import QgsProcessingException
    src = make(tmp_path / f"{name}.tif")
    out = tmp_path / "dtm.tif"
    with pytest.raises(QgsProcessingException, match=message):
        processing_run("bareearth:slopeprofile", {"INPUT": src, "OUTPUT_DTM": str(out),
                                                  "OUTPUT_MASK": str(tmp_path / "m.tif"), **extra})
    assert not out.exists()


def test_multiband_with_band_parameter_runs(processing_run, tmp_path):
    z = np.zeros((2, 30, 30), np.float32)
    z[1, 10:20, 10:20] = 6.0
    src = _write(tmp_path / "two.tif", z)
    res = processing_run("bareearth:slopeprofile", {"INPUT": src, "BAND": 2, "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                                    "OUTPUT_MASK": str(tmp_path / "m.tif")})
    mask = _read(res["OUTPUT_MASK"])[0]
    assert (mask[10:20, 10:20] == 1).all() and mask[0, 0] == 0


def test_geographic_crs_converted_with_warning(processing_run, tmp_path):
    from qgis.core import QgsProcessingFeedback
    z = np.zeros((60, 60), np.float32)
    z[20:35, 20:35] = 7.0
    dlat = 1.0 / 111_000                                    # about 1 m cells at 45 deg
    src = _write(tmp_path / "geo.tif", z, gt=(7.0, dlat * 1.41, 0.0, 45.0, 0.0, -dlat), epsg=4326)
    warnings = []
    fb = QgsProcessingFeedback()
    fb.pushWarning = lambda s: warnings.append(s)
    fb.reportError = lambda s, fatal=False: warnings.append(s)
    res = processing_run("bareearth:slopeprofile", {"INPUT": src, "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                                    "OUTPUT_MASK": str(tmp_path / "m.tif")}, feedback=fb)
    assert any("geographic" in w for w in warnings)
    mask = _read(res["OUTPUT_MASK"])[0]
    assert (mask[20:35, 20:35] == 1).all() and (mask[:15] == 0).all()
    assert "4326" in _read(res["OUTPUT_DTM"])[3] or "WGS 84" in _read(res["OUTPUT_DTM"])[3]


def test_nan_without_nodata_handled(processing_run, tmp_path):
    z = np.zeros((40, 40), np.float32)
    z[5:15, 5:15] = np.nan
    z[20:30, 20:30] = 6.0
    src = _write(tmp_path / "nan.tif", z)                 # NaN holes, no nodata declared
    res = processing_run("bareearth:slopeprofile", {"INPUT": src, "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                                    "OUTPUT_MASK": str(tmp_path / "m.tif")})
    dtm, dnd, *_ = _read(res["OUTPUT_DTM"])
    mask = _read(res["OUTPUT_MASK"])[0]
    assert dnd is not None and math.isnan(dnd)
    assert np.isnan(dtm[5:15, 5:15]).all() and (mask[5:15, 5:15] == 255).all()
    assert (mask[20:30, 20:30] == 1).all()
    np.testing.assert_allclose(dtm[20:30, 20:30], 0.0, atol=1e-3)


def test_cancel_leaves_no_output(qgis_app, tmp_path, scene_files):
    from qgis.core import QgsProcessingContext, QgsProcessingFeedback

    from bare_earth.algorithms.filters import SlopeProfileAlgorithm
    alg = SlopeProfileAlgorithm()
    alg.initAlgorithm()
    fb = QgsProcessingFeedback()
    fb.cancel()
    ctx = QgsProcessingContext()
    out = tmp_path / "c_dtm.tif"
    res = alg.processAlgorithm({"INPUT": scene_files["dsm"], "OUTPUT_DTM": str(out),
                                "OUTPUT_MASK": str(tmp_path / "c_mask.tif")}, ctx, fb)
    assert res == {}
    assert not out.exists() and not (tmp_path / "c_mask.tif").exists()
    assert not list(tmp_path.glob("*.partial*"))


def test_filldtm_with_mask_and_grid_check(processing_run, scene_files, tmp_path):
    from qgis.core import QgsProcessingException
    sc = scene_files["scene"]
    res = processing_run("bareearth:filldtm", {"INPUT": scene_files["dsm"], "MASK": scene_files["mask"],
                                               "OUTPUT": str(tmp_path / "filled.tif")})
    f, nd, gt, *_ = _read(res["OUTPUT"])
    z = _read(scene_files["dsm"])[0]
    ground = sc.mask == 0
    np.testing.assert_allclose(f[ground], z[ground])
    assert np.isfinite(f).all() and (f != -9999.0).all()              # nodata filled too (default)
    obj = sc.mask == 1
    assert np.median(np.abs(f[obj] - sc.dtm[obj])) < 0.5              # buildings filled near the truth
    other = _write(tmp_path / "other.tif", np.zeros((50, 50), np.uint8))
    with pytest.raises(QgsProcessingException, match="not on the DSM's grid"):
        processing_run("bareearth:filldtm", {"INPUT": scene_files["dsm"], "MASK": other,
                                             "OUTPUT": str(tmp_path / "x.tif")})


def test_evaluate_masks_dtm_and_reports(processing_run, scene_files, tmp_path):
    import json
    r = processing_run("bareearth:slopeprofile", {"INPUT": scene_files["dsm"],
                                                  "OUTPUT_DTM": str(tmp_path / "dtm.tif"),
                                                  "OUTPUT_MASK": str(tmp_path / "mask.tif")})
    ev = processing_run("bareearth:evaluate", {"MASK": r["OUTPUT_MASK"], "REFERENCE_MASK": scene_files["mask"],
                                               "DTM": r["OUTPUT_DTM"], "REFERENCE_DTM": scene_files["dtm"],
                                               "OUTPUT_JSON": str(tmp_path / "e.json"),
                                               "OUTPUT_HTML": str(tmp_path / "e.html")})
    assert 0 <= ev["TYPE2"] < 10 and 0 <= ev["TYPE1"] < 10 and ev["KAPPA"] > 80
    assert ev["RMSE"] < 2.0
    data = json.loads(open(ev["OUTPUT_JSON"]).read())
    assert "type1" in json.dumps(data)
    html = open(ev["OUTPUT_HTML"]).read()
    assert "Type I" in html and "data:image/png;base64," in html


@pytest.mark.parametrize("keep", ["OUTPUT_JSON", "OUTPUT_HTML", None])
def test_evaluate_writes_either_report_alone(processing_run, scene_files, tmp_path, keep):
    """Either report alone will do (before, each required the other); with neither, the figures
    are the log's table and the algorithm's numbers (a model's next step reads them)."""
    outs = {"OUTPUT_JSON": tmp_path / "e.json", "OUTPUT_HTML": tmp_path / "e.html"}
    sc = scene_files["scene"]
    mine = _write(tmp_path / "mine.tif", np.zeros(sc.mask.shape, np.uint8), sc.geotransform, sc.epsg)
    params = {"MASK": mine, "REFERENCE_MASK": scene_files["mask"]}
    if keep:
        params[keep] = str(outs[keep])
    ev = processing_run("bareearth:evaluate", params)
    assert ev["TYPE2"] == pytest.approx(100.0) and ev["TYPE1"] == 0.0   # all ground: every object accepted
    for key, path in outs.items():
        assert path.exists() == (key == keep)
    if keep:
        assert ev[keep] == str(outs[keep])


def test_evaluate_requires_something_to_compare(processing_run, tmp_path):
    from qgis.core import QgsProcessingException
    with pytest.raises(QgsProcessingException, match="Nothing to compare"):
        processing_run("bareearth:evaluate", {"OUTPUT_JSON": str(tmp_path / "e.json"),
                                              "OUTPUT_HTML": str(tmp_path / "e.html")})


def test_evaluate_points_against_isprs_truth(processing_run, tmp_path, shared_data):
    sample = shared_data / "isprs" / "samp21.txt"
    if not sample.exists():
        pytest.skip("samp21 absent")
    from bare_earth.core.grid import write_array
    from bare_earth.core.points import rasterize_points, read_points
    cloud = read_points(sample)
    g, gt = rasterize_points(cloud.x, cloud.y, cloud.z, 1.0)
    src = write_array(tmp_path / "samp21.tif", g, gt, 31467)
    r = processing_run("bareearth:slopeprofile", {"INPUT": src, "OUTPUT_DTM": str(tmp_path / "dtm.tif"),
                                                  "OUTPUT_MASK": "TEMPORARY_OUTPUT"})
    ev = processing_run("bareearth:evaluate", {"DTM": r["OUTPUT_DTM"], "POINTS": str(sample),
                                               "OUTPUT_JSON": str(tmp_path / "e.json"),
                                               "OUTPUT_HTML": str(tmp_path / "e.html")})
    baseline = 100.0 * (cloud.classification != 0).mean()
    assert ev["TOTAL"] < baseline / 2                              # far better than all-ground


def test_qgis_process_runs_filter_fill_and_evaluate(run_qgis_process, scene_files, tmp_path):
    rc, out, data = run_qgis_process("bareearth:slopeprofile", {
        "INPUT": scene_files["dsm"], "OUTPUT_DTM": tmp_path / "q_dtm.tif", "OUTPUT_MASK": tmp_path / "q_mask.tif"})
    assert rc == 0, out
    assert (tmp_path / "q_dtm.tif").exists() and (tmp_path / "q_mask.tif").exists()
    assert data["results"]["OUTPUT_MASK"].endswith("q_mask.tif")
    rc, out, _ = run_qgis_process("bareearth:filldtm", {"INPUT": scene_files["dsm"],
                                                        "MASK": tmp_path / "q_mask.tif",
                                                        "OUTPUT": tmp_path / "q_fill.tif"})
    assert rc == 0, out
    rc, out, data = run_qgis_process("bareearth:evaluate", {
        "MASK": tmp_path / "q_mask.tif", "REFERENCE_MASK": scene_files["mask"],
        "OUTPUT_JSON": tmp_path / "q.json", "OUTPUT_HTML": tmp_path / "q.html"})
    assert rc == 0, out
    assert data["results"]["KAPPA"] > 80


def test_qgis_process_bad_input_message(run_qgis_process, tmp_path):
    src = _write(tmp_path / "allnd.tif", np.full((20, 20), -9999.0, np.float32), nodata=-9999.0)
    rc, out, _ = run_qgis_process("bareearth:slopeprofile", {"INPUT": src, "OUTPUT_DTM": tmp_path / "d.tif",
                                                             "OUTPUT_MASK": tmp_path / "m.tif"}, as_json=False)
    assert rc != 0
    assert "no valid cell" in out
    assert not (tmp_path / "d.tif").exists()


def test_threads_give_the_same_mask(processing_run, scene_files, tmp_path):
    one = processing_run("bareearth:slopeprofile", {"INPUT": scene_files["dsm"], "THREADS": 1,
                                                    "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                                    "OUTPUT_MASK": str(tmp_path / "one.tif")})
    thr = processing_run("bareearth:slopeprofile", {"INPUT": scene_files["dsm"], "THREADS": 2,
                                                    "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                                    "OUTPUT_MASK": str(tmp_path / "thr.tif")})
    np.testing.assert_array_equal(_read(one["OUTPUT_MASK"])[0], _read(thr["OUTPUT_MASK"])[0])


def test_worker_processes_and_blocks_give_the_same_mask(processing_run, scene_files, tmp_path):
    one = processing_run("bareearth:slopeprofile", {"INPUT": scene_files["dsm"], "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                                    "OUTPUT_MASK": str(tmp_path / "one.tif")})
    par = processing_run("bareearth:slopeprofile", {"INPUT": scene_files["dsm"], "PROCESSES": 2, "BLOCK_SIZE": 64,
                                                    "OUTPUT_DTM": str(tmp_path / "par_dtm.tif"),
                                                    "OUTPUT_MASK": str(tmp_path / "par.tif")})
    np.testing.assert_array_equal(_read(one["OUTPUT_MASK"])[0], _read(par["OUTPUT_MASK"])[0])
    a, b = _read(one["OUTPUT_DTM"])[0], _read(par["OUTPUT_DTM"])[0]
    ok = a != -9999.0
    assert np.median(np.abs(a[ok] - b[ok])) < 1e-3 and np.abs(a[ok] - b[ok]).max() < 1.0


@pytest.mark.parametrize("alg", filter_algorithms())
def test_qgis_process_runs_each_filter(run_qgis_process, scene_files, tmp_path, alg):
    rc, out, data = run_qgis_process(f"bareearth:{alg}", {
        "INPUT": scene_files["dsm"], "OUTPUT_DTM": tmp_path / "dtm.tif", "OUTPUT_MASK": tmp_path / "mask.tif",
        "OUTPUT_NDSM": tmp_path / "ndsm.tif"})
    assert rc == 0, out
    mask = _read(tmp_path / "mask.tif")[0]
    truth = scene_files["scene"].mask
    assert (mask[truth == 1] != 0).mean() > 0.8
    assert (tmp_path / "ndsm.tif").exists()


def test_threads_default_is_one_per_core(qgis_app):
    from qgis.core import QgsApplication

    from bare_earth.algorithms.filter_base import auto_threads
    from bare_earth.core.blocks import default_workers
    alg = QgsApplication.processingRegistry().algorithmById("bareearth:slopeprofile")
    p = alg.parameterDefinition("THREADS")
    assert p.defaultValue() == 0 and p.minimum() == 0
    assert "one per core" in p.description()
    old = QgsApplication.maxThreads()
    try:
        QgsApplication.setMaxThreads(1)          # QGIS's "Max cores to use" caps it
        assert auto_threads() == 1
        QgsApplication.setMaxThreads(-1)         # unset: one per core
        assert auto_threads() == default_workers()
    finally:
        QgsApplication.setMaxThreads(old)


def _model_saved_before(alg, new, former):
    """A model holding ``alg`` with the static values its dialog stored before the parameters ``new``
    were added: every other input parameter at its default, ``former`` (former defaults) given."""
    from qgis.core import (
        QgsApplication,
        QgsProcessingDestinationParameter,
        QgsProcessingModelAlgorithm,
        QgsProcessingModelChildAlgorithm,
        QgsProcessingModelChildParameterSource,
        QgsProcessingModelOutput,
        QgsProcessingModelParameter,
        QgsProcessingParameterRasterLayer,
    )
    model = QgsProcessingModelAlgorithm("old", "tests")
    model.addModelParameter(QgsProcessingParameterRasterLayer("dsm", "DSM"), QgsProcessingModelParameter("dsm"))
    child = QgsProcessingModelChildAlgorithm(alg)
    child.setChildId("filter")
    child.addParameterSources("INPUT", [QgsProcessingModelChildParameterSource.fromModelParameter("dsm")])
    for d in QgsApplication.processingRegistry().algorithmById(alg).parameterDefinitions():
        name = d.name()
        if name in ("INPUT", *new) or isinstance(d, QgsProcessingDestinationParameter) or d.defaultValue() is None:
            continue
        value = former.get(name, d.defaultValue())
        child.addParameterSources(name, [QgsProcessingModelChildParameterSource.fromStaticValue(value)])
    outputs = {}
    for key in ("OUTPUT_DTM", "OUTPUT_MASK"):
        out = QgsProcessingModelOutput(key.lower())
        out.setChildOutputName(key)
        outputs[key.lower()] = out
    child.setModelOutputs(outputs)
    model.addChildAlgorithm(child)
    return model


@pytest.mark.parametrize("alg,new,former", [
    ("bareearth:geodesic", ("RAISED_REGIONS",), {"MAX_OBJECT_SIZE_M": 64.0}),
    ("bareearth:rascor", ("SPARE_CONTINUING_GROUND",), {}),
], ids=["geodesic", "rascor"])
def test_model_saved_before_new_parameters_runs_on_a_small_raster(processing_run, tmp_path, alg, new, former):
    """A model saved before RASCOR's spare_continuing_ground or geodesic's raised_regions existed (and,
    for geodesic, storing its former default largest object, 64 m) validates and runs on a raster 50 m
    across: the new parameters take their defaults."""
    from qgis.core import QgsProcessingModelAlgorithm
    z = np.full((50, 50), 100.0, np.float32)
    z[10:20, 10:20] += 8.0
    src = _write(tmp_path / "small.tif", z)
    path = tmp_path / "old.model3"
    assert _model_saved_before(alg, new, former).toFile(str(path))
    model = QgsProcessingModelAlgorithm()
    assert model.fromFile(str(path))
    ok, errors = model.validate()
    assert ok, errors
    r = processing_run(model, {"dsm": src, "filter:output_dtm": str(tmp_path / "dtm.tif"),
                               "filter:output_mask": str(tmp_path / "mask.tif")})
    mask = _read(r["filter:output_mask"])[0]
    assert (mask[10:20, 10:20] == 1).all() and (mask == 1).sum() == 100


def test_former_default_window_runs_on_a_small_raster(processing_run, tmp_path):
    """MAX_OBJECT_SIZE_M = 64 (geodesic's default before it was derived, stored by older scripts) on a
    raster 50 m across runs with the window clamped; a larger chosen window is still refused."""
    from qgis.core import QgsProcessingException
    z = np.full((50, 50), 100.0, np.float32)
    z[10:20, 10:20] += 8.0
    src = _write(tmp_path / "small.tif", z)
    params = {"INPUT": src, "OUTPUT_DTM": "TEMPORARY_OUTPUT", "OUTPUT_MASK": str(tmp_path / "m.tif")}
    r = processing_run("bareearth:geodesic", {**params, "MAX_OBJECT_SIZE_M": 64.0})
    assert (_read(r["OUTPUT_MASK"])[0] == 1).sum() == 100
    with pytest.raises(QgsProcessingException, match="larger than the raster"):
        processing_run("bareearth:geodesic", {**params, "MAX_OBJECT_SIZE_M": 65.0})
