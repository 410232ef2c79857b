"""bareearth:tiles through processing.run: layers or a folder in, seamless mosaics out, cancel,
and the refusal (naming what to install) when Dask is missing."""
import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed", reason="Dask distributed is not installed (scripts/setup.sh installs it)")

from bare_earth.core import grid, pipeline  # noqa: E402
from bare_earth.core.methods import available_methods  # noqa: E402
from bare_earth.core.synthetic import make_scene  # noqa: E402

TILE = 96


@pytest.fixture(scope="module")
def tiles(tmp_path_factory):
    d = tmp_path_factory.mktemp("tiles")
    sc = make_scene("city", shape=(2 * TILE, 3 * TILE), seed=5, nodata_holes=True)
    gt = sc.geotransform
    paths = []
    for i in range(0, sc.dsm.shape[0], TILE):
        for j in range(0, sc.dsm.shape[1], TILE):
            a = sc.dsm[i:i + TILE, j:j + TILE]
            p = d / f"tile_{i // TILE}_{j // TILE}.tif"
            grid.write_array(p, np.where(np.isfinite(a), a, -9999.0),
                             (gt[0] + j * gt[1], gt[1], 0.0, gt[3] + i * gt[5], 0.0, gt[5]), sc.epsg, nodata=-9999.0)
            paths.append(str(p))
    return {"scene": sc, "paths": paths, "dir": str(d)}


def method_index(name):
    return sorted(available_methods()).index(name)


def test_tiles_from_layers_equal_the_one_pass_mask(processing_run, tiles, tmp_path):
    out = str(tmp_path / "out")
    res = processing_run("bareearth:tiles", {
        "INPUT_LAYERS": tiles["paths"], "METHOD": method_index("morphological"),
        "PARAMETERS": "max_object_size_m=16", "WORKERS": 2, "OUTPUT_FOLDER": out})
    assert res["OUTPUT_MASK"] == os.path.join(out, "mask.vrt") and os.path.exists(res["OUTPUT_DTM"])
    rec = json.loads(Path(res["OUTPUT_RECORD"]).read_text())
    assert {v["status"] for v in rec["tiles"].values()} == {"done"} and len(rec["tiles"]) == 6
    assert rec["params"]["max_object_size_m"] == 16.0
    sc = tiles["scene"]
    ref = pipeline.run_array("morphological", sc.dsm, sc.cell_size, {"max_object_size_m": 16.0})
    info = grid.open_dsm(res["OUTPUT_MASK"])
    assert np.array_equal(info.dataset().GetRasterBand(1).ReadAsArray(), ref.mask)
    import gc
    gc.collect()                     # the layers Processing loaded are closed (side files were written then)
    assert not [f for f in os.listdir(tiles["dir"]) if f.endswith(".aux.xml")]     # the tiles' folder untouched


def test_tiles_from_a_folder_report_progress_per_tile_and_cancel(processing_run, tiles, tmp_path):
    from qgis.core import QgsProcessingFeedback
    seen = []

    class StopAfterTwo(QgsProcessingFeedback):
        def setProgress(self, p):  # noqa: N802
            seen.append(p)
            super().setProgress(p)
            if p >= 10 + 90 * 2 / 6 - 1e-6:      # the derivation takes the first tenth (QA15), each tile 90 / 6
                self.cancel()

    out = str(tmp_path / "out")
    params = {"INPUT_FOLDER": tiles["dir"], "METHOD": method_index("slopeprofile"),
              "PARAMETERS": "max_object_size_m=20", "WORKERS": 1, "OUTPUT_FOLDER": out}
    processing_run("bareearth:tiles", params, feedback=StopAfterTwo())
    rec = json.loads(Path(out, "run.json").read_text())
    done_first = [k for k, v in rec["tiles"].items() if v["status"] == "done"]
    assert 2 <= len(done_first) < 6 and rec["runs"][-1].get("cancelled")
    deriving = [p for p in seen if p <= 10.0]
    assert deriving                                                     # the bar moves while parameters are derived
    assert [p for p in seen if p > 10.0][:2] == pytest.approx([25.0, 40.0])   # then one step per finished tile
    res = processing_run("bareearth:tiles", params)                   # the rest only
    rec2 = json.loads(Path(res["OUTPUT_RECORD"]).read_text())
    assert rec2["runs"][-1]["tiles_done"] == 6 - len(done_first)
    assert {v["status"] for v in rec2["tiles"].values()} == {"done"}


def test_bad_survey_refused_before_any_work(processing_run, tiles, tmp_path):
    from qgis.core import QgsProcessingException
    other = tmp_path / "other.tif"
    grid.write_array(other, np.zeros((40, 40), np.float32), (0.0, 2.0, 0.0, 80.0, 0.0, -2.0), 32632)
    with pytest.raises(QgsProcessingException, match="different cell sizes: other.tif"):
        processing_run("bareearth:tiles", {"INPUT_LAYERS": tiles["paths"] + [str(other)],
                                           "METHOD": method_index("slopeprofile"),
                                           "OUTPUT_FOLDER": str(tmp_path / "out")})


def test_without_dask_the_algorithm_says_what_to_install(qgis_app, processing_run, tiles, tmp_path, monkeypatch):
    from qgis.core import QgsApplication, QgsProcessingContext
    monkeypatch.setitem(sys.modules, "distributed", None)          # import distributed -> ImportError
    alg = QgsApplication.processingRegistry().algorithmById("bareearth:tiles")
    ok, msg = alg.checkParameterValues({"INPUT_LAYERS": tiles["paths"], "METHOD": 0,
                                        "OUTPUT_FOLDER": str(tmp_path / "o")}, QgsProcessingContext())
    assert not ok and "python3-distributed" in msg and "dask[distributed]" in msg
    # every other algorithm still runs
    res = processing_run("bareearth:slopeprofile", {"INPUT": tiles["paths"][0], "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                                    "OUTPUT_MASK": str(tmp_path / "m.tif")})
    assert os.path.exists(res["OUTPUT_MASK"])


def test_output_folder_holding_the_tiles_or_a_file_refused_before_any_work(processing_run, tiles, tmp_path):
    """The folder of the tile layers as OUTPUT_FOLDER (before: accepted, the outputs written among the
    tiles, so the folder given again would take them for tiles) and an existing file as OUTPUT_FOLDER
    (before: a FileExistsError traceback after the tile index) are refused naming the problem."""
    from qgis.core import QgsProcessingException
    before = sorted(os.listdir(tiles["dir"]))
    with pytest.raises(QgsProcessingException, match=r"output folder .* holds the tiles \(tile_0_0.tif and 5 more\)"
                                                     r".*Choose another output folder"):
        processing_run("bareearth:tiles", {"INPUT_LAYERS": tiles["paths"], "METHOD": method_index("slopeprofile"),
                                           "WORKERS": 1, "OUTPUT_FOLDER": tiles["dir"]})
    assert sorted(os.listdir(tiles["dir"])) == before
    a_file = tmp_path / "notes.txt"
    a_file.write_text("keep me")
    with pytest.raises(QgsProcessingException, match=r"output folder .*notes.txt' is an existing file, not a folder"):
        processing_run("bareearth:tiles", {"INPUT_FOLDER": tiles["dir"], "METHOD": method_index("slopeprofile"),
                                           "WORKERS": 1, "OUTPUT_FOLDER": str(a_file)})
    assert a_file.read_text() == "keep me"


def test_read_only_output_folder_refused_before_any_work(processing_run, tiles, tmp_path, read_only):
    """QA24: a read-only OUTPUT_FOLDER passed the checks (the folder above it was probed) and the run ended in a
    FileNotFoundError traceback renaming survey.vrt's work file; now refused naming the folder."""
    from qgis.core import QgsProcessingException
    out = tmp_path / "out"
    out.mkdir()
    with read_only(out):
        for given in (out, out / "new"):
            with pytest.raises(QgsProcessingException, match=rf"the output folder '{out}' .*is not writable \(.+\): "
                                                             "choose a folder you can write to"):
                processing_run("bareearth:tiles", {"INPUT_LAYERS": tiles["paths"], "WORKERS": 1,
                                                   "METHOD": method_index("slopeprofile"), "OUTPUT_FOLDER": str(given)})
    assert os.listdir(out) == []


def test_survey_of_nodata_tiles_refused_naming_it_and_leaving_no_folder(processing_run, tmp_path):
    """Tiles holding only nodata: refused saying the survey holds no data (before: "z has no valid
    cell", naming no tile, with the output folder and its survey.vrt left behind)."""
    from qgis.core import QgsProcessingException
    src = tmp_path / "sea"
    src.mkdir()
    for j in range(2):
        grid.write_array(src / f"t{j}.tif", np.full((40, 40), -9999.0, np.float32),
                         (500000.0 + 40 * j, 1.0, 0.0, 5400040.0, 0.0, -1.0), 32632, nodata=-9999.0)
    out = tmp_path / "out"
    with pytest.raises(QgsProcessingException, match=r"the survey holds no data in the whole survey \(80 x 40 cells\)"
                                                     r".*Check the tiles' nodata value"):
        processing_run("bareearth:tiles", {"INPUT_FOLDER": str(src), "METHOD": method_index("slopeprofile"),
                                           "WORKERS": 1, "OUTPUT_FOLDER": str(out)})
    assert not out.exists()


def test_rerun_after_a_tile_changed_is_refused_naming_it(processing_run, tmp_path):
    """A rerun into a finished survey's folder after one tile was edited (same path, new heights) is
    refused naming the tile (before: every tile was "already done", the old outputs kept silently)."""
    from qgis.core import QgsProcessingException
    src = tmp_path / "tiles"
    src.mkdir()
    sc = make_scene("city", shape=(64, 128), seed=2)
    gt = sc.geotransform
    for j in range(2):
        a = sc.dsm[:, 64 * j:64 * (j + 1)]
        grid.write_array(src / f"t{j}.tif", np.where(np.isfinite(a), a, -9999.0),
                         (gt[0] + 64 * j * gt[1], gt[1], 0.0, gt[3], 0.0, gt[5]), sc.epsg, nodata=-9999.0)
    params = {"INPUT_FOLDER": str(src), "METHOD": method_index("slopeprofile"), "WORKERS": 1,
              "OUTPUT_FOLDER": str(tmp_path / "out")}
    processing_run("bareearth:tiles", params)
    res = processing_run("bareearth:tiles", params)                 # unchanged: nothing redone
    assert json.loads(Path(res["OUTPUT_RECORD"]).read_text())["runs"][-1]["tiles_to_do"] == 0
    a = sc.dsm[:, 64:] + 5.0
    grid.write_array(src / "t1.tif", np.where(np.isfinite(a), a, -9999.0),
                     (gt[0] + 64 * gt[1], gt[1], 0.0, gt[3], 0.0, gt[5]), sc.epsg, nodata=-9999.0)
    with pytest.raises(QgsProcessingException, match=r"1 tile\(s\) changed since the run recorded in .*run.json "
                                                     r"\(size or modification time\): t1.tif"):
        processing_run("bareearth:tiles", params)


@pytest.mark.parametrize("address", ["not an address", "tcp://host", "tcp://host:port"])
def test_malformed_scheduler_address_refused_before_any_work(processing_run, tiles, tmp_path, address):
    """A SCHEDULER that is no Dask address is refused saying the expected form (before: "missing port
    number in address ..." after the parameters were derived, with the output folder made)."""
    from qgis.core import QgsProcessingException
    out = tmp_path / "out"
    with pytest.raises(QgsProcessingException, match=r"is not a Dask address .*give it as tcp://host:8786"):
        processing_run("bareearth:tiles", {"INPUT_FOLDER": tiles["dir"], "METHOD": method_index("slopeprofile"),
                                           "SCHEDULER": address, "OUTPUT_FOLDER": str(out)})
    assert not out.exists()


def test_an_output_folder_given_as_the_tiles_is_refused_naming_it(processing_run, tiles, tmp_path):
    """A survey's output folder given back as INPUT_FOLDER (its *_dtm.tif and *_mask.tif are no tiles)
    is refused saying so (before: "tiles overlap: tile_0_0_dtm.tif and tile_0_0_mask.tif")."""
    from qgis.core import QgsProcessingException
    out = tmp_path / "out"
    params = {"INPUT_FOLDER": tiles["dir"], "METHOD": method_index("slopeprofile"), "WORKERS": 1,
              "PARAMETERS": "max_object_size_m=20", "OUTPUT_FOLDER": str(out)}
    processing_run("bareearth:tiles", params)
    with pytest.raises(QgsProcessingException, match=r"holds the outputs of a survey run \(run.json\), not tiles"):
        processing_run("bareearth:tiles", dict(params, INPUT_FOLDER=str(out), OUTPUT_FOLDER=str(tmp_path / "again")))
    assert not (tmp_path / "again").exists()


def test_a_vrt_input_named_like_an_output_is_not_overwritten(processing_run, tiles, tmp_path):
    """One VRT over the tiles, named dtm.vrt, with its own folder as OUTPUT_FOLDER: refused (before:
    the survey ran and replaced the input VRT with its DTM mosaic)."""
    from osgeo import gdal
    from qgis.core import QgsProcessingException
    vrt = tmp_path / "dtm.vrt"
    gdal.BuildVRT(str(vrt), tiles["paths"])
    with pytest.raises(QgsProcessingException, match=r"an output in .* would replace the input .*dtm.vrt"):
        processing_run("bareearth:tiles", {"INPUT_LAYERS": [str(vrt)], "METHOD": method_index("slopeprofile"),
                                           "WORKERS": 1, "OUTPUT_FOLDER": str(tmp_path)})
    # still the VRT over the tiles (QGIS, loading the layer, may add band statistics to it: not ours)
    from bare_earth.core.survey import io
    assert sorted(io.vrt_sources(str(vrt))) == sorted(os.path.abspath(p) for p in tiles["paths"])
    assert not (tmp_path / "run.json").exists() and not (tmp_path / "survey.vrt").exists()


def test_a_failed_tile_fails_the_algorithm_and_leaves_no_mosaic(processing_run, tiles, tmp_path):
    """A tile that fails (its output name taken by a folder): the algorithm fails naming the tile and the
    rerun, with no dtm.vrt / mask.vrt; before: it succeeded and loaded mosaics with a hole."""
    from qgis.core import QgsProcessingException
    out = tmp_path / "out"
    out.mkdir()
    (out / "tile_1_2_mask.tif").mkdir()
    params = {"INPUT_LAYERS": tiles["paths"], "METHOD": method_index("morphological"),
              "PARAMETERS": "max_object_size_m=16", "WORKERS": 1, "OUTPUT_FOLDER": str(out)}
    with pytest.raises(QgsProcessingException, match=r"incomplete: 1 tile\(s\) not done \(1 failed: tile_1_2\).*"
                                                     r"Run the algorithm again"):
        processing_run("bareearth:tiles", params)
    assert not (out / "dtm.vrt").exists() and not (out / "mask.vrt").exists()
    assert not (out / "tile_1_2_dtm.tif").exists()          # the half of the pair written is removed
    (out / "tile_1_2_mask.tif").rmdir()
    res = processing_run("bareearth:tiles", params)
    assert os.path.exists(res["OUTPUT_DTM"]) and os.path.exists(res["OUTPUT_MASK"])


def test_more_workers_than_cores_refused_before_any_work(processing_run, tiles, tmp_path):
    from qgis.core import QgsProcessingException
    out = tmp_path / "out"
    with pytest.raises(QgsProcessingException, match=r"WORKERS = 256 local worker processes, but this computer has "):
        processing_run("bareearth:tiles", {"INPUT_FOLDER": tiles["dir"], "METHOD": method_index("slopeprofile"),
                                           "WORKERS": 256, "OUTPUT_FOLDER": str(out)})
    assert not out.exists()


def test_tile_layers_with_settings_their_files_lack_are_refused(processing_run, tiles, tmp_path):
    """A tile layer given additional no-data values or a CRS in QGIS: the survey's workers read the
    files, which do not hold them, so a -9999 border was filtered as heights and a CRS-less tile in
    feet as metres, without a word. Refused, naming the layer and the gdal_edit that fixes the file."""
    from qgis.core import (
        QgsCoordinateReferenceSystem,
        QgsProcessingException,
        QgsProject,
        QgsRasterLayer,
        QgsRasterRange,
    )
    nodata_layer = QgsRasterLayer(tiles["paths"][0], "tile_nodata", "gdal")
    nodata_layer.dataProvider().setUserNoDataValue(1, [QgsRasterRange(-5.0, -5.0)])
    bare = tmp_path / "bare.tif"
    a = np.full((TILE, TILE), 10.0, np.float32)
    grid.write_array(bare, a, (0.0, 1.0, 0.0, float(TILE), 0.0, -1.0), None)
    crs_layer = QgsRasterLayer(str(bare), "tile_crs", "gdal")
    crs_layer.setCrs(QgsCoordinateReferenceSystem("EPSG:2263"))
    for lyr in (nodata_layer, crs_layer):
        QgsProject.instance().addMapLayer(lyr)
    try:
        for lyr, what in ((nodata_layer, r"tile_nodata' has additional no-data values.*gdal_edit -a_nodata"),
                          (crs_layer, r"tile_crs' was given a CRS in QGIS \(EPSG:2263\).*gdal_edit -a_srs EPSG:2263")):
            out = tmp_path / f"out_{lyr.name()}"
            with pytest.raises(QgsProcessingException, match=what):
                processing_run("bareearth:tiles", {"INPUT_LAYERS": [lyr.id()], "METHOD": method_index("slopeprofile"),
                                                   "OUTPUT_FOLDER": str(out)})
            assert not out.exists()
    finally:
        for lyr in (nodata_layer, crs_layer):
            QgsProject.instance().removeMapLayer(lyr.id())


def test_the_surveys_warnings_are_warnings(processing_run, tiles, tmp_path, monkeypatch):
    """The survey's log went to QGIS's information lines whole, its warnings ("Warning: tiles declare
    no nodata value", a worker's memory) among them with the prefix: QGIS never showed them as
    warnings. The core's warnings now go to the warnings, its other lines to the information."""
    from qgis.core import QgsProcessingFeedback

    from bare_earth.core import Cancelled, survey
    lines = []
    fb = QgsProcessingFeedback()
    fb.pushInfo = lambda s: lines.append(("info", s))
    fb.pushWarning = lambda s: lines.append(("warning", s))
    fb.reportError = lambda s, fatal=False: lines.append(("error", s))

    def fake(method, inputs, out_dir, params, workers=0, scheduler=None, progress=None, log=None):
        log("Survey: 6 tiles")
        log("Warning: 6 tile(s) declare no nodata value")
        raise Cancelled()
    monkeypatch.setattr(survey, "run_survey", fake)
    processing_run("bareearth:tiles", {"INPUT_LAYERS": tiles["paths"], "METHOD": method_index("morphological"),
                                       "OUTPUT_FOLDER": str(tmp_path / "out")}, feedback=fb)
    assert ("info", "Survey: 6 tiles") in lines and ("warning", "6 tile(s) declare no nodata value") in lines, lines
