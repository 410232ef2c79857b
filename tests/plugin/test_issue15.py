"""Issue #15 through processing.run: the bad-input table (one row per defect of the issue),
output formats by extension, creation options, and the styles of the layers Processing loads."""
import hashlib
import os
import re
import subprocess
import sys

import numpy as np
import pytest
from scipy import ndimage

pytestmark = pytest.mark.qgis
GT = (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0)

#: rows whose fix is in the core (helper coreB's #15 work): they pass once that branch is merged


def _sha(path):
    with open(path, "rb") as f:
        return hashlib.sha1(f.read()).hexdigest()


def _files(folder):
    """Files in a folder, less the .aux.xml QGIS writes beside an input it opens."""
    return {p for p in os.listdir(folder) if not p.endswith(".aux.xml")}


def _write(path, arr, gt=GT, nodata=None, **kw):
    from bare_earth.core.grid import write_array
    return write_array(path, arr, gt, 32632, nodata=nodata, **kw)


def _dsm(tmp, name="dsm.tif", shape=(40, 40)):
    z = np.zeros(shape, np.float32)
    z[10:20, 10:20] = 6.0
    return _write(tmp / name, z)


def _points(tmp):
    rng = np.random.default_rng(3)
    x, y = rng.uniform(500002, 500038, 500), rng.uniform(5399962, 5399998, 500)
    path = tmp / "pts.txt"
    np.savetxt(path, np.column_stack([x, y, np.zeros(500), np.zeros(500)]), fmt=["%.3f"] * 3 + ["%d"])
    return str(path)


def _read(path, band=1):
    from osgeo import gdal
    ds = gdal.Open(str(path))
    a = ds.GetRasterBand(band).ReadAsArray()
    driver = ds.GetDriver().ShortName
    ds = None
    return a, driver


def _filters():
    from bare_earth.algorithms import all_algorithms
    from bare_earth.algorithms.filter_base import FilterAlgorithm
    return [a.name() for a in all_algorithms() if isinstance(a, FilterAlgorithm)]


# ---- the bad-input table: (id, algorithm, parameters from tmp, message) ---------------------------
def _truncated(tmp):
    src = _dsm(tmp, "whole.tif", (300, 300))
    with open(src, "rb") as f:
        data = f.read()
    (tmp / "cut.tif").write_bytes(data[: len(data) // 3])
    return {"INPUT": str(tmp / "cut.tif"), "OUTPUT_DTM": str(tmp / "o.tif"), "OUTPUT_MASK": str(tmp / "m.tif")}


def _vrt_missing(tmp):
    (tmp / "v.vrt").write_text(
        '<VRTDataset rasterXSize="20" rasterYSize="20"><GeoTransform>0,1,0,20,0,-1</GeoTransform>'
        '<VRTRasterBand dataType="Float32" band="1"><SimpleSource><SourceFilename relativeToVRT="1">gone.tif'
        '</SourceFilename><SourceBand>1</SourceBand></SimpleSource></VRTRasterBand></VRTDataset>')
    return {"INPUT": str(tmp / "v.vrt"), "OUTPUT_DTM": str(tmp / "o.tif"), "OUTPUT_MASK": str(tmp / "m.tif")}


def _vrt_raw(tmp):
    (tmp / "raw.vrt").write_text(
        '<VRTDataset rasterXSize="16" rasterYSize="16"><GeoTransform>0,1,0,16,0,-1</GeoTransform>'
        '<VRTRasterBand dataType="Byte" band="1" subClass="VRTRawRasterBand"><SourceFilename relativeToVRT="0">'
        '/etc/passwd</SourceFilename><ImageOffset>0</ImageOffset><PixelOffset>1</PixelOffset>'
        '<LineOffset>16</LineOffset></VRTRasterBand></VRTDataset>')
    return {"INPUT": str(tmp / "raw.vrt"), "OUTPUT_DTM": str(tmp / "o.tif"), "OUTPUT_MASK": str(tmp / "m.tif")}


def _ortho_pair(tmp, shape=(100, 100)):
    """A flat DEM and two textured orthophotos of it on its grid (zero parallax), with B and H."""
    rng = np.random.default_rng(7)
    tex = 255.0 * ndimage.gaussian_filter(rng.random(shape), 1.5)
    return {"DEM": _write(tmp / "dem.tif", np.full(shape, 100.0, np.float32)),
            "ORTHO_A": _write(tmp / "a.tif", tex.astype(np.float32)),
            "ORTHO_B": _write(tmp / "b.tif", tex.astype(np.float32)),
            "BASE_M": 300.0, "HEIGHT_M": 1000.0, "OUTPUT_DEM": str(tmp / "o.tif"), "OUTPUT_DH": str(tmp / "dh.tif"),
            "OUTPUT_QUALITY": str(tmp / "q.tif"), "OUTPUT_MASK": str(tmp / "m.tif")}


def _ortho_refine(tmp, shape):
    p = _ortho_pair(tmp, shape)
    return {"DEM": p["DEM"], "IMAGES": [p["ORTHO_A"], p["ORTHO_B"]], "BASE_M": 300.0, "HEIGHT_M": 1000.0,
            "OUTPUT_DEM": p["OUTPUT_DEM"]}


BAD = [
    # defect 1: an output on the input, for every filter, filldtm and the point tools
    *[pytest.param(f"1-{a}-dtm-is-input", a, lambda t: {"INPUT": _dsm(t), "OUTPUT_DTM": str(t / "dsm.tif"),
                                                         "OUTPUT_MASK": str(t / "m.tif")},
                   r"'DTM' \(OUTPUT_DTM\) is the input", id=f"1-{a}-dtm-is-input") for a in _filters()],
    pytest.param("1-mask-is-input", "slopeprofile", lambda t: {"INPUT": _dsm(t), "OUTPUT_DTM": str(t / "o.tif"),
                                                              "OUTPUT_MASK": str(t / "dsm.tif")},
                 r"\(OUTPUT_MASK\) is the input", id="1-mask-is-input"),
    pytest.param("1-filldtm", "filldtm", lambda t: {"INPUT": _dsm(t), "OUTPUT": str(t / "dsm.tif")},
                 r"\(OUTPUT\) is the input 'Surface to fill' \(INPUT\)", id="1-filldtm"),
    pytest.param("1-classifypoints", "classifypoints", lambda t: {"INPUT": _points(t), "DTM": _dsm(t),
                                                                  "OUTPUT": str(t / "pts.txt")},
                 r"\(OUTPUT\) is the input", id="1-classifypoints"),
    pytest.param("1-rasterizepoints", "rasterizepoints", lambda t: {"INPUT": _points(t),
                                                                    "OUTPUT": str(t / "pts.txt")},
                 r"\(OUTPUT\) is the input", id="1-rasterizepoints"),
    pytest.param("1-two-outputs-one-file", "slopeprofile", lambda t: {"INPUT": _dsm(t), "OUTPUT_DTM": str(t / "o.tif"),
                                                                     "OUTPUT_MASK": str(t / "o.tif")},
                 r"\(OUTPUT_DTM\) and .*\(OUTPUT_MASK\) are one file", id="1-two-outputs-one-file"),
    # defect 2: corrupt inputs refused naming the file (core: coreB)
    pytest.param("2-truncated-tif", "slopeprofile", _truncated, "cut.tif", id="2-truncated-tif"),
    pytest.param("2-vrt-missing-source", "slopeprofile", _vrt_missing, "v.vrt", id="2-vrt-missing-source"),
    pytest.param("2-evaluate-truncated-mask", "evaluate", lambda t: {
        "MASK": _truncated(t)["INPUT"], "REFERENCE_MASK": _dsm(t, shape=(300, 300)),
        "OUTPUT_JSON": str(t / "e.json"), "OUTPUT_HTML": str(t / "e.html")},
        r"cannot read the raster '.*cut\.tif'.*truncated or corrupt", id="2-evaluate-truncated-mask"),
    pytest.param("2-orthoparallax-truncated-dem", "orthoparallax", lambda t: {
        **_ortho_pair(t, (300, 300)), "DEM": _truncated(t)["INPUT"]},
        r"DEM: cannot read the raster '.*cut\.tif'.*truncated or corrupt", id="2-orthoparallax-truncated-dem"),
    # defect 6: a raw-band VRT must not read any local file (core: coreB)
    pytest.param("6-vrt-raw-band", "slopeprofile", _vrt_raw, "raw", id="6-vrt-raw-band"),
    # defect 8: missing or unwritable output folder, named, before any work
    pytest.param("8-missing-folder", "slopeprofile", lambda t: {"INPUT": _dsm(t), "OUTPUT_DTM": str(t / "no/o.tif"),
                                                               "OUTPUT_MASK": str(t / "m.tif")},
                 r"output folder '.*/no' does not exist", id="8-missing-folder"),
    pytest.param("8-unwritable-folder", "filldtm", lambda t: {"INPUT": _dsm(t), "OUTPUT": "/proc/o.tif"},
                 r"output folder '/proc' is not writable", id="8-unwritable-folder"),
    # defect 9: a chosen window larger than the raster
    pytest.param("9-window-cells", "curvature", lambda t: {"INPUT": _dsm(t, shape=(3, 40)), "WINDOW_CELLS": 7,
                                                          "OUTPUT_DTM": str(t / "o.tif"),
                                                          "OUTPUT_MASK": str(t / "m.tif")},
                 r"\(WINDOW_CELLS\) = 7 cells is larger than the raster", id="9-window-cells"),
    # the orthophoto tools check their windows against the DEM as the filters do
    pytest.param("9-orthoparallax-window", "orthoparallax", lambda t: {**_ortho_pair(t, (5, 40)), "WINDOW_CELLS": 9},
                 r"\(WINDOW_CELLS\) = 9 cells is larger than the raster itself \(40 x 5 cells\)",
                 id="9-orthoparallax-window"),
    pytest.param("9-orthorefine-window", "orthorefine", lambda t: {**_ortho_refine(t, (5, 40)), "WINDOW_CELLS": 9},
                 r"\(WINDOW_CELLS\) = 9 cells is larger than the raster itself", id="9-orthorefine-window"),
    pytest.param("9-orthoparallax-object-size", "orthoparallax", lambda t: {**_ortho_pair(t, (8, 40)),
                                                                           "OBJECT_SIZE_M": 100.0},
                 r"\(OBJECT_SIZE_M\) = 100.0 m is larger than the raster itself \(40.0 m across\)",
                 id="9-orthoparallax-object-size"),
    # formats: an extension naming a format the outputs do not write, or too few bands
    *[pytest.param(f"format-{ext}", "slopeprofile", lambda t, ext=ext: {
        "INPUT": _dsm(t), "OUTPUT_DTM": str(t / f"o{ext}"), "OUTPUT_MASK": str(t / "m.tif")},
        r"\(OUTPUT_DTM\).*Formats offered: GeoTIFF \(\.tif, \.tiff\)", id=f"format-{ext}")
      for ext in (".vrt", ".xyz", ".png")],
    pytest.param("format-2-bands-in-ascii", "curvature", lambda t: {
        "INPUT": _dsm(t), "OUTPUT_DTM": str(t / "o.tif"), "OUTPUT_MASK": str(t / "m.tif"),
        "OUTPUT_CURVATURE": str(t / "k.asc")}, r"'Curvature \(K, H\)' \(OUTPUT_CURVATURE\).*2 bands",
        id="format-2-bands-in-ascii"),
    pytest.param("creation-options", "slopeprofile", lambda t: {
        "INPUT": _dsm(t), "OUTPUT_DTM": str(t / "o.tif"), "OUTPUT_MASK": str(t / "m.tif"),
        "CREATE_OPTIONS": "COMPRESS=NOPE"}, r"\(CREATE_OPTIONS\).*allowed values", id="creation-options"),
    *[pytest.param(f"creation-options-{alg}", alg, lambda t, make=make: {**make(t), "CREATE_OPTIONS": "COMPRESS=NOPE"},
                   r"\(CREATE_OPTIONS\).*allowed values", id=f"creation-options-{alg}")
      for alg, make in (("orthoparallax", _ortho_pair), ("orthorefine", lambda t: _ortho_refine(t, (100, 100))))],
]


@pytest.mark.parametrize("name,alg,make,message", BAD)
def test_bad_input_refused_before_any_work(processing_run, tmp_path, name, alg, make, message):
    from qgis.core import QgsProcessingException
    params = make(tmp_path)
    inputs = {k: _sha(v) for k, v in params.items() if k in ("INPUT", "DTM", "DEM", "ORTHO_A", "ORTHO_B")
              and os.path.isfile(v)}
    before = _files(tmp_path)
    with pytest.raises(QgsProcessingException, match=message):
        processing_run(f"bareearth:{alg}", params)
    if name != "6-vrt-raw-band":
        # GDAL 3.6 itself rewrites a raw-band VRT when QGIS opens it as a layer (the XML
        # pretty-printed, a <ByteOrder> added) before our refusal; every other input stays as it was.
        assert {k: _sha(params[k]) for k in inputs} == inputs      # inputs untouched
    assert _files(tmp_path) == before                              # nothing written


def test_defect2_corrupt_input_refused_by_qgis_process(run_qgis_process, tmp_path):
    """qgis_process refuses a truncated GeoTIFF with a message naming it (it died with rc 134, an
    uncaught GDAL RuntimeError); no traceback, nothing written."""
    params = _truncated(tmp_path)
    before = _files(tmp_path)
    rc, out, _ = run_qgis_process("bareearth:slopeprofile", params, as_json=False)
    assert rc == 1, out
    assert re.search(r"cannot read the raster '.*cut\.tif'.*truncated or corrupt", out), out
    assert "Traceback" not in out and "RuntimeError" not in out
    assert _files(tmp_path) == before


def test_defect3_scale_and_offset_applied(processing_run, tmp_path):
    from osgeo import gdal
    z = np.full((40, 40), 300.0)
    z[10:20, 10:20] = 308.0
    raw = np.round((z - 100.0) / 0.1).astype(np.int16)
    src = _write(tmp_path / "scaled.tif", raw)
    ds = gdal.Open(src, gdal.GA_Update)
    ds.GetRasterBand(1).SetScale(0.1)
    ds.GetRasterBand(1).SetOffset(100.0)
    ds = None
    from qgis.core import QgsProcessingFeedback
    lines = []
    fb = QgsProcessingFeedback()
    fb.pushInfo = lines.append
    res = processing_run("bareearth:slopeprofile", {"INPUT": src, "OUTPUT_DTM": str(tmp_path / "o.tif"),
                                                    "OUTPUT_MASK": str(tmp_path / "m.tif")}, feedback=fb)
    dtm = _read(res["OUTPUT_DTM"])[0]
    assert 299 < np.nanmin(dtm) and np.nanmax(dtm) < 301
    assert any(re.search(r"stored values x 0\.1 \+ 100 \(its scale and offset\)", line) for line in lines), lines


def test_defect5_workers_start_with_qgis_python_not_path(tmp_path):
    """Inside QGIS sys.executable is not a Python: the workers must still not come from PATH."""
    import shutil
    exe = shutil.which("qgis_process.bin") or "/usr/bin/qgis_process.bin"
    if not os.path.exists(exe):
        pytest.skip("qgis_process.bin is not installed")
    bindir = tmp_path / "bin"
    bindir.mkdir()
    marker = tmp_path / "planted-ran"
    (bindir / "python3").write_text(f"#!/bin/sh\ntouch {marker}\nexit 1\n")
    (bindir / "python3").chmod(0o755)
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    env = dict(os.environ, PATH=f"{bindir}{os.pathsep}{os.environ['PATH']}", QT_QPA_PLATFORM="offscreen",
               QGIS_PLUGINPATH=os.path.join(root, ".build", "plugins"))
    src = _dsm(tmp_path, shape=(300, 300))
    res = subprocess.run([exe, "run", "bareearth:slopeprofile", "--", f"INPUT={src}",
                          f"OUTPUT_DTM={tmp_path / 'o.tif'}", f"OUTPUT_MASK={tmp_path / 'm.tif'}", "PROCESSES=2",
                          "BLOCK_SIZE=128"], env=env, capture_output=True, text=True, timeout=600)
    assert not marker.exists(), "a python3 planted on PATH was started"
    assert res.returncode == 0, res.stdout + res.stderr


def test_defect11_no_numpy_overflow_noise(processing_run, tmp_path):
    import warnings
    z = np.zeros((40, 40), np.float32)
    z[5, 5], z[30, 30] = 1e30, -1e30
    src = _write(tmp_path / "huge.tif", z)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        processing_run("bareearth:curvature", {"INPUT": src, "OUTPUT_DTM": str(tmp_path / "o.tif"),
                                               "OUTPUT_MASK": str(tmp_path / "m.tif")})


def test_defect7_long_but_valid_output_names(processing_run, tmp_path):
    limit = os.pathconf(tmp_path, "PC_NAME_MAX")
    # the mask's name leaves room for its .aux.xml (its class names; QA 24: a longer one is refused)
    dtm, mask = tmp_path / ("d" * (limit - 7) + ".tif"), tmp_path / ("m" * (limit - 8 - 4) + ".tif")
    res = processing_run("bareearth:slopeprofile", {"INPUT": _dsm(tmp_path), "OUTPUT_DTM": str(dtm),
                                                    "OUTPUT_MASK": str(mask)})
    m = _read(res["OUTPUT_MASK"])[0]
    assert (m[10:20, 10:20] == 1).all() and m[0, 0] == 0
    assert os.path.exists(str(mask) + ".aux.xml")
    assert not [p for p in os.listdir(tmp_path) if "partial" in p]


def test_defect10_leftovers_of_killed_runs_removed(processing_run, tmp_path):
    from osgeo import gdal
    src = _dsm(tmp_path)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    stale = tmp_path / f".o.{int(dead):010d}-0123abcd.partial"
    gdal.Translate(str(stale), src, format="GTiff")                 # a GeoTIFF GDAL opens
    old = tmp_path / "o.partial-89abcdef.tif"                        # an older version's leftover
    gdal.Translate(str(old), src, format="GTiff")
    processing_run("bareearth:slopeprofile", {"INPUT": src, "OUTPUT_DTM": str(tmp_path / "o.tif"),
                                              "OUTPUT_MASK": str(tmp_path / "m.tif")})
    assert not stale.exists() and not old.exists()
    assert _files(tmp_path) == {"dsm.tif", "m.qml", "m.tif", "o.tif"}


# ---- formats ---------------------------------------------------------------------------------
@pytest.mark.parametrize("ext,driver", [(".sdat", "SAGA"), (".asc", "AAIGrid"), (".img", "HFA"), (".tif", "GTiff")])
def test_output_written_in_the_format_its_extension_names(processing_run, tmp_path, ext, driver):
    res = processing_run("bareearth:slopeprofile", {"INPUT": _dsm(tmp_path), "OUTPUT_DTM": str(tmp_path / f"o{ext}"),
                                                    "OUTPUT_MASK": str(tmp_path / f"m{ext}")})
    dtm, d_drv = _read(res["OUTPUT_DTM"])
    mask, m_drv = _read(res["OUTPUT_MASK"])
    assert d_drv == m_drv == driver
    assert (mask[10:20, 10:20] == 1).all() and np.allclose(dtm, 0.0, atol=1e-3)
    assert not [p for p in os.listdir(tmp_path) if "partial" in p]


def test_cloud_optimised_geotiff_and_creation_options(processing_run, tmp_path):
    from osgeo import gdal
    res = processing_run("bareearth:filldtm", {"INPUT": _dsm(tmp_path), "OUTPUT": str(tmp_path / "cog.tif"),
                                               "COG": True})
    ds = gdal.Open(res["OUTPUT"])
    assert ds.GetMetadata("IMAGE_STRUCTURE").get("LAYOUT") == "COG"
    res = processing_run("bareearth:slopeprofile", {"INPUT": _dsm(tmp_path), "OUTPUT_DTM": str(tmp_path / "z.tif"),
                                                    "OUTPUT_MASK": str(tmp_path / "m.tif"),
                                                    "CREATE_OPTIONS": "COMPRESS=LZW|PREDICTOR=2"})
    ds = gdal.Open(res["OUTPUT_DTM"])
    assert ds.GetMetadata("IMAGE_STRUCTURE")["COMPRESSION"] == "LZW"


def test_orthophoto_outputs_take_creation_options_and_cog(processing_run, tmp_path):
    """orthoparallax and orthorefine offer CREATE_OPTIONS and COG as the filters do."""
    from osgeo import gdal
    params = _ortho_pair(tmp_path)
    res = processing_run("bareearth:orthoparallax", {**params, "CREATE_OPTIONS": "COMPRESS=LZW|PREDICTOR=2"})
    for key in ("OUTPUT_DEM", "OUTPUT_DH", "OUTPUT_QUALITY", "OUTPUT_MASK"):
        assert gdal.Open(res[key]).GetMetadata("IMAGE_STRUCTURE")["COMPRESSION"] == "LZW", key
    res = processing_run("bareearth:orthoparallax", {**params, "COG": True})
    for key in ("OUTPUT_DEM", "OUTPUT_MASK"):
        assert gdal.Open(res[key]).GetMetadata("IMAGE_STRUCTURE").get("LAYOUT") == "COG", key
    from qgis.core import QgsApplication
    alg = QgsApplication.processingRegistry().algorithmById("bareearth:orthorefine")
    assert alg.parameterDefinition("CREATE_OPTIONS") is not None and alg.parameterDefinition("COG") is not None


def test_orthorefine_writes_with_creation_options(processing_run, tmp_path):
    from osgeo import gdal
    p = _ortho_pair(tmp_path)
    ties = tmp_path / "ties.csv"
    gt = GT
    rows = ["image,x,y,col,row"]
    for name in ("a", "b"):
        for r, c in ((5, 5), (5, 94), (94, 5), (94, 94), (50, 50)):
            rows.append(f"{name},{gt[0] + (c + 0.5) * gt[1]!r},{gt[3] + (r + 0.5) * gt[5]!r},{c},{r}")
    ties.write_text("\n".join(rows) + "\n")
    res = processing_run("bareearth:orthorefine", {
        "DEM": p["DEM"], "IMAGES": [p["ORTHO_A"], p["ORTHO_B"]], "TIE_POINTS": str(ties), "BASE_M": 300.0,
        "HEIGHT_M": 1000.0, "MAX_ITERATIONS": 1, "OUTPUT_DEM": str(tmp_path / "r.tif"),
        "OUTPUT_ORTHO_FOLDER": str(tmp_path / "orthos"), "OUTPUT_TABLE": str(tmp_path / "t.csv"),
        "CREATE_OPTIONS": "COMPRESS=LZW"})
    assert gdal.Open(res["OUTPUT_DEM"]).GetMetadata("IMAGE_STRUCTURE")["COMPRESSION"] == "LZW"
    orthos = sorted(os.listdir(tmp_path / "orthos"))
    assert orthos and all(gdal.Open(str(tmp_path / "orthos" / f)).GetMetadata("IMAGE_STRUCTURE")["COMPRESSION"]
                          == "LZW" for f in orthos if f.endswith(".tif"))


def test_provider_offers_the_formats_written(qgis_app):
    from qgis.core import QgsApplication
    exts = QgsApplication.processingRegistry().providerById("bareearth").supportedOutputRasterLayerExtensions()
    assert {"tif", "sdat", "asc", "img", "gpkg"} <= set(exts) and not {"vrt", "xyz"} & set(exts)


# ---- styles of the layers Processing loads -----------------------------------------------------
def _run_and_load(alg, params):
    import processing
    from qgis.core import QgsProject
    QgsProject.instance().removeAllMapLayers()
    processing.runAndLoadResults(alg, params)
    return {lay.name(): lay for lay in QgsProject.instance().mapLayers().values()}


def test_loaded_mask_has_the_four_classes(qgis_app, tmp_path):
    from qgis.core import QgsPalettedRasterRenderer

    from bare_earth.core.codes import MASK_CODES
    layers = _run_and_load("bareearth:slopeprofile", {"INPUT": _dsm(tmp_path), "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                                      "OUTPUT_MASK": str(tmp_path / "m.tif")})
    mask = layers["Object mask"]
    r = mask.renderer()
    assert isinstance(r, QgsPalettedRasterRenderer)
    assert {(c.value, c.label) for c in r.classes()} == set(MASK_CODES.items())


def test_side_products_get_short_names_and_renderers(qgis_app, tmp_path):
    from qgis.core import QgsPalettedRasterRenderer, QgsSingleBandPseudoColorRenderer
    layers = _run_and_load("bareearth:curvature", {"INPUT": _dsm(tmp_path), "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                                   "OUTPUT_MASK": "TEMPORARY_OUTPUT",
                                                   "OUTPUT_CURVATURE": str(tmp_path / "k.tif")})
    k = layers["Curvature (K, H)"].renderer()
    assert isinstance(k, QgsSingleBandPseudoColorRenderer) and k.band() == 1
    assert k.classificationMin() == -k.classificationMax() < 0
    layers = _run_and_load("bareearth:geodesic", {"INPUT": _dsm(tmp_path), "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                                  "OUTPUT_MASK": "TEMPORARY_OUTPUT",
                                                  "OUTPUT_STEP": str(tmp_path / "s.tif")})
    s = layers["Removal step"].renderer()
    assert isinstance(s, QgsPalettedRasterRenderer)
    labels = {c.value: c.label for c in s.classes()}
    assert labels[0] == "kept" and len(labels) >= 2
    assert all(v == 0 or lab.startswith("removed by step") for v, lab in labels.items())


def test_confidence_outputs_ramp_red_to_green(qgis_app, tmp_path):
    from qgis.core import QgsRasterLayer, QgsSingleBandPseudoColorRenderer

    from bare_earth.algorithms.styles import OUTPUT_RENDERERS, RENDERERS
    conf = np.tile(np.linspace(0, 100, 20, dtype=np.float32), (10, 1))
    layer = QgsRasterLayer(_write(tmp_path / "conf.tif", conf), "c")
    r = RENDERERS[OUTPUT_RENDERERS["OUTPUT_CONFIDENCE"]](layer)
    assert isinstance(r, QgsSingleBandPseudoColorRenderer)
    assert (r.classificationMin(), r.classificationMax()) == (0.0, 100.0)
    items = r.shader().rasterShaderFunction().colorRampItemList()
    low, high = items[0].color, items[-1].color
    assert low.red() > 200 > low.green() and high.green() > 100 > high.red()


def test_memory_raster_outputs_are_temporary_files(qgis_app, tmp_path, monkeypatch):
    """'memory:' (QGIS's memory layer, which rasters do not have) as a raster output wrote a file named
    'memory:' in the working folder, and two such outputs were refused as one file: each is a temporary
    output, as TEMPORARY_OUTPUT."""
    import processing
    from osgeo import gdal
    work = tmp_path / "cwd"
    work.mkdir()
    monkeypatch.chdir(work)
    res = processing.run("bareearth:slopeprofile", {"INPUT": _dsm(tmp_path), "OUTPUT_DTM": "memory:",
                                                    "OUTPUT_MASK": "memory:mask"})
    assert os.listdir(work) == []
    assert res["OUTPUT_DTM"] != res["OUTPUT_MASK"]
    assert gdal.Open(res["OUTPUT_DTM"]).GetRasterBand(1).DataType == gdal.GDT_Float32
    assert gdal.Open(res["OUTPUT_MASK"]).GetRasterBand(1).DataType == gdal.GDT_Byte
