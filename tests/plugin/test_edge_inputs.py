"""Edge inputs and outputs through processing.run and qgis_process (the adversarial QA round):
each test failed before the fix it names."""
import re

import numpy as np
import pytest

pytestmark = pytest.mark.qgis
GT = (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0)


def _write(path, arr, gt=GT, nodata=None, **kw):
    from bare_earth.core.grid import write_array
    return write_array(path, arr, gt, 32632, nodata=nodata, **kw)


def _ramp_with_box(shape=(40, 40)):
    """A gentle ramp (0-3 m) with a 6 m box on it."""
    z = np.zeros(shape, np.float32) + np.linspace(0.0, 3.0, shape[1], dtype=np.float32)[None, :]
    z[10:20, 10:20] += 6.0
    return z


def _read(path):
    from osgeo import gdal
    ds = gdal.Open(str(path))
    b = ds.GetRasterBand(1)
    return b.ReadAsArray(), b.GetNoDataValue()


def test_ndsm_of_a_dsm_with_nodata_zero_keeps_its_ground_cells(processing_run, tmp_path):
    """nodata = 0 is a value every ground cell of an nDSM holds (DSM - DTM = 0): the nDSM then
    declares NaN, so its ground cells stay valid (they all read as nodata before)."""
    z = _ramp_with_box()
    z[:, :3] = 0.0
    src = _write(tmp_path / "dsm.tif", z, nodata=0.0)
    res = processing_run("bareearth:slopeprofile", {
        "INPUT": src, "OUTPUT_DTM": str(tmp_path / "dtm.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif"),
        "OUTPUT_NDSM": str(tmp_path / "ndsm.tif")})
    ndsm, nd = _read(res["OUTPUT_NDSM"])
    mask, _ = _read(res["OUTPUT_MASK"])
    dtm, dnd = _read(res["OUTPUT_DTM"])
    assert dnd == 0.0 and (dtm[:, :3] == 0).all()            # the DTM keeps the input's nodata
    ground = mask == 0
    assert ground.sum() > 1000
    assert np.isnan(nd) and (ndsm[ground] == 0).all()         # valid zeros, not nodata
    assert np.isnan(ndsm[:, :3]).all() and (mask[:, :3] == 255).all()
    assert (ndsm[mask == 1] > 5).all()


def test_heights_in_millimetres_refused_naming_the_unit(processing_run, tmp_path):
    """An Int32 DSM in millimetres without a scale: every height is beyond +-1e5 m. The refusal
    says so and how to give the band its scale (it said "every cell is nodata" before)."""
    from qgis.core import QgsProcessingException
    z = (np.round(_ramp_with_box() * 1000.0) + 250_000).astype(np.int32)
    src = _write(tmp_path / "mm.tif", z, nodata=-99999, dtype="Int32")
    out = tmp_path / "dtm.tif"
    with pytest.raises(QgsProcessingException, match=r"beyond \+-100000 m.*gdal_edit.py -scale 0.001"):
        processing_run("bareearth:dtm", {"INPUT": src, "OUTPUT_DTM": str(out), "OUTPUT_MASK": str(tmp_path / "m.tif")})
    assert not out.exists()
    from osgeo import gdal
    ds = gdal.Open(src, gdal.GA_Update)
    ds.GetRasterBand(1).SetScale(0.001)
    ds = None
    res = processing_run("bareearth:slopeprofile", {"INPUT": src, "OUTPUT_DTM": str(out),
                                                    "OUTPUT_MASK": str(tmp_path / "m.tif")})
    mask, _ = _read(res["OUTPUT_MASK"])
    assert (mask[12:18, 12:18] == 1).all() and (mask[30:, 30:] == 0).all()


def _cancel_at(percent):
    """A feedback that asks to cancel once the bar reaches ``percent`` (as a user's click handled
    while the bar is drawn)."""
    from qgis.core import QgsProcessingFeedback

    class CancelAt(QgsProcessingFeedback):
        def setProgress(self, p):  # noqa: N802
            super().setProgress(p)
            if p >= percent:
                self.cancel()
    return CancelAt()


@pytest.mark.parametrize("percent", [50, 100])
def test_cancel_from_the_bar_leaves_no_output(processing_run, tmp_path, percent):
    """A cancel asked while the bar shows 100 % (the outputs about to move into place) stops the
    run with nothing written; before, the outputs were moved into place and the run then said
    "Cancelled: no output was written" and returned no result."""
    src = _write(tmp_path / "dsm.tif", _ramp_with_box((120, 130)))
    outs = {"OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif"),
            "OUTPUT_NDSM": str(tmp_path / "n.tif")}
    res = processing_run("bareearth:slopeprofile", {"INPUT": src, **outs}, feedback=_cancel_at(percent))
    assert not res or not any(res.values())
    assert sorted(p.name for p in tmp_path.iterdir() if not p.name.endswith(".aux.xml")) == ["dsm.tif"]


def test_a_cancel_after_the_outputs_are_in_place_comes_too_late(tmp_path):
    """Once the outputs are moved into place a cancel no longer raises: the run returns its
    result (before, the final progress call raised Cancelled over complete outputs)."""
    from bare_earth.core import pipeline
    from bare_earth.core.common import Cancelled
    src = _write(tmp_path / "dsm.tif", _ramp_with_box())
    seen = []

    def progress(f):
        if f >= 1.0 and seen.count(1.0) >= 1:     # the call after the outputs were moved
            raise Cancelled()
        seen.append(f)
    res = pipeline.run_file("slopeprofile", src, {"dtm": str(tmp_path / "d.tif"), "mask": str(tmp_path / "m.tif")},
                            progress=progress)
    assert res["method"] == "slopeprofile" and (tmp_path / "m.tif").exists()


@pytest.mark.parametrize("block", [1, 8, 63])
def test_tiny_block_size_refused_before_work(processing_run, tmp_path, block):
    """BLOCK_SIZE below 64 cells is refused naming the parameter (before, BLOCK_SIZE = 1 ran one
    filter per cell over a halo of tens of cells: a 120 x 130 raster had not finished in 10 min)."""
    from qgis.core import QgsProcessingException
    src = _write(tmp_path / "dsm.tif", _ramp_with_box())
    out = tmp_path / "d.tif"
    with pytest.raises(QgsProcessingException, match=rf"'Block size.*\(BLOCK_SIZE\) = {block} cells is too small"):
        processing_run("bareearth:geodesic", {"INPUT": src, "OUTPUT_DTM": str(out),
                                              "OUTPUT_MASK": str(tmp_path / "m.tif"), "BLOCK_SIZE": block})
    assert not out.exists()


@pytest.mark.parametrize("side", ["m.qml", "m.tif.aux.xml", "d.tif.aux.xml"])
def test_a_folder_where_an_output_writes_beside_it_refused_before_work(processing_run, tmp_path, side):
    """QA14: a folder named as the mask's style (m.qml) or an output's .aux.xml: the whole run was done, then
    the style's write raised a bare IsADirectoryError traceback (the mask in place, not its style), the
    .aux.xml's move 'cannot put the output in place'."""
    from qgis.core import QgsProcessingException
    src = _write(tmp_path / "dsm.tif", _ramp_with_box())
    (tmp_path / side).mkdir()
    name = re.escape(side)
    with pytest.raises(QgsProcessingException, match=rf"^Unable to execute algorithm\n'(Object mask|DTM)' \(OUTPUT_"
                                                     rf"(MASK|DTM)\): the output '.*' writes '{name}' beside it, "
                                                     rf"but '.*{name}' is a folder: move or rename"):
        processing_run("bareearth:slopeprofile", {"INPUT": src, "OUTPUT_DTM": str(tmp_path / "d.tif"),
                                                  "OUTPUT_MASK": str(tmp_path / "m.tif")})
    assert not (tmp_path / "d.tif").exists() and not (tmp_path / "m.tif").exists()


@pytest.mark.parametrize("key", ["BLOCK_SIZE", "THREADS", "PROCESSES", "DH_M", "MAX_OBJECT_SIZE_M"])
def test_a_nan_given_as_a_number_refused_before_work(qgis_app, processing_run, tmp_path, key):
    """A NaN given as a number (a PyQGIS script's computed value, a model's expression) passed QGIS's
    range check and was read as -2147483648: BLOCK_SIZE = NaN ran for ever (10 min on 60 x 70 cells),
    MAX_OBJECT_SIZE_M = NaN silently took the derived value. 'nan' given as text was already refused."""
    from qgis.core import QgsApplication, QgsProcessingContext, QgsProcessingException
    src = _write(tmp_path / "dsm.tif", _ramp_with_box())
    params = {"INPUT": src, "OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif"),
              key: float("nan")}
    ok, msg = QgsApplication.processingRegistry().algorithmById("bareearth:morphological").checkParameterValues(
        params, QgsProcessingContext())
    assert not ok and re.search(rf"\({key}\) = nan is not a number: give a number", msg)
    with pytest.raises(QgsProcessingException, match=rf"\({key}\) = nan is not a number"):
        processing_run("bareearth:morphological", params)
    assert not (tmp_path / "d.tif").exists()


def test_smallest_block_size_equals_one_pass(processing_run, tmp_path):
    """BLOCK_SIZE = 64 on a raster of 2 x 3 blocks gives the one-pass mask."""
    from bare_earth.core.synthetic import make_scene
    sc = make_scene("city", shape=(120, 150), seed=3)
    src = _write(tmp_path / "dsm.tif", sc.dsm)
    masks = []
    for b in (0, 64):
        res = processing_run("bareearth:morphological", {
            "INPUT": src, "OUTPUT_DTM": str(tmp_path / f"d{b}.tif"), "OUTPUT_MASK": str(tmp_path / f"m{b}.tif"),
            "BLOCK_SIZE": b, "THREADS": 1})
        masks.append(_read(res["OUTPUT_MASK"])[0])
    assert (masks[0] == masks[1]).all() and (masks[0] == 1).any()


def _mask(shape=(40, 40)):
    m = np.zeros(shape, np.uint8)
    m[10:20, 10:20] = 1
    return m


@pytest.mark.parametrize("alg", ["filldtm", "evaluate"])
def test_a_dsm_given_as_mask_refused_before_work(processing_run, tmp_path, alg):
    """A float raster of heights given as MASK is refused naming the parameter and a value
    (before, filldtm filled nothing and evaluate counted every non-zero height as an object)."""
    from qgis.core import QgsProcessingException
    dsm = _write(tmp_path / "dsm.tif", _ramp_with_box())
    good = _write(tmp_path / "m.tif", _mask(), nodata=255)
    out = tmp_path / "out.tif"
    params = ({"INPUT": dsm, "MASK": dsm, "OUTPUT": str(out)} if alg == "filldtm" else
              {"MASK": dsm, "REFERENCE_MASK": good, "OUTPUT_JSON": str(tmp_path / "e.json"),
               "OUTPUT_HTML": str(tmp_path / "e.html")})
    with pytest.raises(QgsProcessingException, match=r"The mask \(MASK\) '.*dsm.tif' holds \d+ cell\(s\) that are "
                                                     r"no mask code \(e.g. 0.07"):
        processing_run(f"bareearth:{alg}", params)
    assert not out.exists() and not (tmp_path / "e.json").exists()


def test_mask_codes_read_with_their_nodata(processing_run, tmp_path):
    """An Int16 reference mask with nodata -9999: those cells are not evaluated, the others are
    read as codes (a whole-number Float32 mask too)."""
    m = _mask().astype(np.int16)
    ref = m.copy()
    ref[:5] = -9999
    ref_path = _write(tmp_path / "ref.tif", ref, nodata=-9999, dtype="Int16")
    mine = m.astype(np.float32)
    mine[:5] = 0.0                            # ground where the reference has no data: not evaluated
    res = processing_run("bareearth:evaluate", {"MASK": _write(tmp_path / "mine.tif", mine),
                                                "REFERENCE_MASK": ref_path, "OUTPUT_JSON": str(tmp_path / "e.json"),
                                                "OUTPUT_HTML": str(tmp_path / "e.html")})
    assert res["TOTAL"] == 0.0 and res["KAPPA"] == 100.0


def _ortho_pair(tmp, shape=(100, 100)):
    """A flat DEM and two textured orthophotos of it on its grid (zero parallax)."""
    from scipy import ndimage
    rng = np.random.default_rng(7)
    tex = (255.0 * ndimage.gaussian_filter(rng.random(shape), 1.5)).astype(np.float32)
    return {"DEM": _write(tmp / "dem.tif", np.full(shape, 100.0, np.float32)),
            "ORTHO_A": _write(tmp / "a.tif", tex), "ORTHO_B": _write(tmp / "b.tif", tex[:, ::-1].copy()),
            "OUTPUT_DEM": str(tmp / "o.tif"), "OUTPUT_MASK": str(tmp / "m.tif")}


@pytest.mark.parametrize("extra,message", [
    ({"BASE_M": 300.0, "HEIGHT_M": 1000.0, "MAX_DH_M": 1e6}, r"parallax searched.*wider than the DEM \(100 m.*"
                                                             r"MAX_DH_M below 333.3 m"),
    ({"BASE_M": 1e9, "HEIGHT_M": 1000.0}, r"B / H = 1e\+06"),
    # centres within sight of the DEM (1000 m either side at 1000 m above it; x = 0 is refused as far from it)
    ({"CAMERA_A": "499000,5399950,1100", "CAMERA_B": "501100,5399950,1100"}, r"parallax searched.*wider than the DEM"),
    ({"BASE_M": 300.0, "HEIGHT_M": 1000.0, "ORTHO_B": "A"}, r"ORTHO_A and ORTHO_B are one file"),
], ids=["max_dh", "base", "centres", "same_file"])
def test_orthoparallax_absurd_geometry_refused_before_work(processing_run, tmp_path, extra, message):
    """A parallax search wider than the DEM is refused naming the values and the bound (before, MAX_DH_M
    = 1e6 m ran 12 min on 200 x 160 cells and BASE_M = 1e9 did not finish); so is one file as both
    orthophotos (it ran, and measured no parallax)."""
    from qgis.core import QgsProcessingException
    params = _ortho_pair(tmp_path)
    params.update(extra)
    if params.get("ORTHO_B") == "A":
        params["ORTHO_B"] = params["ORTHO_A"]
    with pytest.raises(QgsProcessingException, match=message):
        processing_run("bareearth:orthoparallax", params)
    assert not (tmp_path / "o.tif").exists()


def test_orthorefine_tie_points_absurd_base_refused(processing_run, tmp_path):
    """The same bound in orthorefine's tie-point mode (B and H given)."""
    from qgis.core import QgsProcessingException
    p = _ortho_pair(tmp_path)
    ties = tmp_path / "ties.csv"
    ties.write_text("image,x,y,col,row\na,500010,5399990,10,10\nb,500010,5399990,12,10\n")
    with pytest.raises(QgsProcessingException, match=r"B / H = 1e\+06"):
        processing_run("bareearth:orthorefine", {"DEM": p["DEM"], "IMAGES": [p["ORTHO_A"], p["ORTHO_B"]],
                                                 "TIE_POINTS": str(ties), "BASE_M": 1e9, "HEIGHT_M": 1000.0,
                                                 "OUTPUT_DEM": p["OUTPUT_DEM"]})
    assert not (tmp_path / "o.tif").exists()


def test_saga_header_extension_names_the_sdat(processing_run, tmp_path):
    """An output named .sgrd (SAGA's header) is refused saying to name the .sdat (it said "GDAL
    cannot write it here"); the .sdat is written with its .sgrd beside it."""
    from qgis.core import QgsProcessingException
    src = _write(tmp_path / "dsm.tif", _ramp_with_box())
    with pytest.raises(QgsProcessingException, match=r"header of a SAGA grid: name its .sdat"):
        processing_run("bareearth:slopeprofile", {"INPUT": src, "OUTPUT_DTM": str(tmp_path / "d.sgrd"),
                                                  "OUTPUT_MASK": str(tmp_path / "m.tif")})
    processing_run("bareearth:slopeprofile", {"INPUT": src, "OUTPUT_DTM": str(tmp_path / "d.sdat"),
                                              "OUTPUT_MASK": str(tmp_path / "m.tif")})
    assert (tmp_path / "d.sgrd").exists() and _read(tmp_path / "d.sdat")[0].shape == (40, 40)


def test_filldtm_with_every_cell_masked_refused_before_work(processing_run, tmp_path):
    """A mask covering every valid cell leaves nothing to fill from: refused naming INPUT, MASK and
    FILL_CODES (before, the core's "fill_gaps: ... outside `fill`" came after the work started)."""
    from qgis.core import QgsProcessingException
    src = _write(tmp_path / "dsm.tif", _ramp_with_box())
    m = _write(tmp_path / "m.tif", np.full((40, 40), 2, np.uint8), nodata=255)
    with pytest.raises(QgsProcessingException, match=r"Nothing to fill from: every cell of the surface "
                                                     r"\(INPUT\).*\(MASK\).*\(FILL_CODES\): 1, 2\)"):
        processing_run("bareearth:filldtm", {"INPUT": src, "MASK": m, "OUTPUT": str(tmp_path / "o.tif")})
    assert not (tmp_path / "o.tif").exists()


def test_evaluate_all_nodata_reference_dtm_refused(processing_run, tmp_path):
    """A reference DTM without a valid cell is refused naming it (before: RMSE NaN, no word)."""
    from qgis.core import QgsProcessingException
    dtm = _write(tmp_path / "dtm.tif", _ramp_with_box())
    ref = _write(tmp_path / "ref.tif", np.full((40, 40), -9999.0, np.float32), nodata=-9999.0)
    with pytest.raises(QgsProcessingException, match=r"\(REFERENCE_DTM\): the raster '.*ref.tif' has no valid cell"):
        processing_run("bareearth:evaluate", {"DTM": dtm, "REFERENCE_DTM": ref, "OUTPUT_JSON": str(tmp_path / "e.json"),
                                              "OUTPUT_HTML": str(tmp_path / "e.html")})
    assert not (tmp_path / "e.json").exists()



def test_log_gives_nodata_cells_as_a_count(processing_run, tmp_path):
    """The classes' line gives the nodata cells as a number of cells (it said "nodata cells 120 %"
    for 120 cells), the classes in percent."""
    from qgis.core import QgsProcessingFeedback
    lines = []

    class Log(QgsProcessingFeedback):
        def pushInfo(self, info):  # noqa: N802
            lines.append(info)

    z = _ramp_with_box()
    z[:, :3] = -9999.0
    processing_run("bareearth:slopeprofile", {"INPUT": _write(tmp_path / "dsm.tif", z, nodata=-9999.0),
                                              "OUTPUT_DTM": str(tmp_path / "d.tif"),
                                              "OUTPUT_MASK": str(tmp_path / "m.tif")}, feedback=Log())
    line = next(s for s in lines if "classes_percent" in s)
    assert re.search(r"ground \d+(\.\d+)? %", line) and line.rstrip().endswith("nodata cells 120"), line


def test_qgis_process_tiny_block_and_ndsm_of_nodata_zero(run_qgis_process, tmp_path):
    """Through qgis_process: the block-size refusal (exit code 1, the message, no file) and the nDSM
    of a DSM with nodata 0 (NaN declared, the reason in the log)."""
    z = _ramp_with_box()
    z[:, :3] = 0.0
    src = _write(tmp_path / "dsm.tif", z, nodata=0.0)
    outs = {"OUTPUT_DTM": tmp_path / "d.tif", "OUTPUT_MASK": tmp_path / "m.tif", "OUTPUT_NDSM": tmp_path / "n.tif"}
    rc, out, _ = run_qgis_process("bareearth:slopeprofile", {"INPUT": src, "BLOCK_SIZE": 5, **outs})
    assert rc != 0 and "(BLOCK_SIZE) = 5 cells is too small" in out and not (tmp_path / "d.tif").exists()
    rc, out, _ = run_qgis_process("bareearth:slopeprofile", {"INPUT": src, **outs})
    assert rc == 0, out
    assert "the nDSM declares NaN as nodata" in out and np.isnan(_read(tmp_path / "n.tif")[1])


@pytest.mark.parametrize("extra,message", [
    ({"MAX_DH_M": 0.0}, r"MAX_DH_M must be > 0 m; got 0.*Leave it empty for the default"),
    ({"MIN_CORRELATION": 1.0}, r"MIN_CORRELATION must be in 0 \.\. 1 \(1 excluded\); got 1.*below 1"),
], ids=["max_dh_0", "min_corr_1"])
def test_orthoparallax_meaningless_matching_values_refused_before_work(processing_run, tmp_path, extra, message):
    """MAX_DH_M = 0 (no height searched) and MIN_CORRELATION = 1 (no real match is kept) are refused
    naming the parameter and the valid range (before, 0 silently meant the default 0.2 H search and
    1 ran to a DEM with nothing measured)."""
    from qgis.core import QgsProcessingException
    params = _ortho_pair(tmp_path)
    params.update({"BASE_M": 300.0, "HEIGHT_M": 1000.0}, **extra)
    with pytest.raises(QgsProcessingException, match=message):
        processing_run("bareearth:orthoparallax", params)
    assert not (tmp_path / "o.tif").exists()


def _listing(folder):
    """{name: bytes} of every file in ``folder``."""
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_inputs_given_as_paths_get_no_side_file(processing_run, tmp_path):
    """An input folder is left byte for byte as it was: no ``.aux.xml`` beside the inputs. Before: QGIS
    computed the statistics of each raster it loaded from a path (its default renderer) and GDAL saved
    them as dsm.tif.aux.xml, mask.tif.aux.xml, ... when the layers closed."""
    import gc
    src, out = tmp_path / "in", tmp_path / "out"
    src.mkdir()
    out.mkdir()
    z = _ramp_with_box()
    dsm = _write(src / "dsm.tif", z, nodata=-9999.0)
    mask = _write(src / "mask.tif", np.where(z > 4, 1, 0).astype(np.uint8), nodata=255, dtype="Byte")
    before = _listing(src)
    processing_run("bareearth:dtm", {"INPUT": dsm, "OUTPUT_DTM": str(out / "d.tif"), "OUTPUT_MASK": str(out / "m.tif")})
    processing_run("bareearth:filldtm", {"INPUT": dsm, "MASK": mask, "OUTPUT": str(out / "f.tif")})
    processing_run("bareearth:evaluate", {"MASK": str(out / "m.tif"), "REFERENCE_MASK": mask, "DTM": str(out / "d.tif"),
                                          "REFERENCE_DTM": dsm, "OUTPUT_JSON": str(out / "e.json"),
                                          "OUTPUT_HTML": str(out / "e.html")})
    gc.collect()                     # the layers Processing loaded are closed (their side files written then)
    assert _listing(src) == before


def test_qgis_process_leaves_the_input_folder_unchanged(run_qgis_process, tmp_path):
    src = tmp_path / "in"
    src.mkdir()
    dsm = _write(src / "dsm.tif", _ramp_with_box(), nodata=-9999.0)
    before = _listing(src)
    rc, out, _ = run_qgis_process("bareearth:dtm", {"INPUT": dsm, "OUTPUT_DTM": tmp_path / "d.tif",
                                                    "OUTPUT_MASK": tmp_path / "m.tif"})
    assert rc == 0, out
    assert _listing(src) == before


@pytest.mark.parametrize("nodata,dtype", [(np.inf, "Float32"), (-np.inf, "Float32"), (-1e300, "Float64")],
                         ids=["plus_inf", "minus_inf", "beyond_float32"])
def test_infinite_nodata_outputs_declare_nan(processing_run, tmp_path, nodata, dtype):
    """An input nodata of +-inf (or beyond float32) is nodata; the DTM and nDSM declare NaN with NaN
    cells exactly there, none infinite, and the log says why (before: NaN without a word in one file,
    and the survey's tile DTMs carried +-inf cells)."""
    from qgis.core import QgsProcessingFeedback
    z = _ramp_with_box().astype(np.float64)
    z[30:35, 30:35] = nodata
    src = _write(tmp_path / "dsm.tif", z, nodata=nodata, dtype=dtype)
    lines = []

    class Log(QgsProcessingFeedback):
        def pushInfo(self, text):  # noqa: N802
            lines.append(text)

        def pushWarning(self, text):  # noqa: N802
            lines.append(text)
    res = processing_run("bareearth:dtm", {"INPUT": src, "OUTPUT_DTM": str(tmp_path / "d.tif"),
                                           "OUTPUT_MASK": str(tmp_path / "m.tif"),
                                           "OUTPUT_NDSM": str(tmp_path / "n.tif")}, feedback=Log())
    hole = np.zeros(z.shape, bool)
    hole[30:35, 30:35] = True
    for key in ("OUTPUT_DTM", "OUTPUT_NDSM"):
        a, nd = _read(res[key])
        assert np.isnan(nd) and not np.isinf(a).any()
        assert np.array_equal(np.isnan(a), hole)
    assert np.array_equal(_read(res["OUTPUT_MASK"])[0] == 255, hole)
    assert any("declare NaN as nodata instead" in t for t in lines)


def test_survey_tiles_with_infinite_nodata_write_nan(tmp_path):
    pytest.importorskip("distributed")
    from bare_earth.core.survey import run_survey
    paths = []
    for k in range(2):
        z = _ramp_with_box((64, 64))
        z[:4, :4] = np.inf
        gt = (GT[0] + 64 * k, 1.0, 0.0, GT[3], 0.0, -1.0)
        paths.append(_write(tmp_path / f"t{k}.tif", z, gt=gt, nodata=np.inf))
    lines = []
    run_survey("morphological", paths, tmp_path / "out", {"max_object_size_m": 16.0}, workers=1, log=lines.append)
    for k in range(2):
        a, nd = _read(tmp_path / "out" / f"t{k}_dtm.tif")
        assert np.isnan(nd) and not np.isinf(a).any() and np.isnan(a[:4, :4]).all()
    assert any("declare NaN as nodata instead" in t for t in lines)


def _memory_layer(kind, wkts, crs="EPSG:32632"):
    from qgis.core import QgsFeature, QgsGeometry, QgsVectorLayer
    lay = QgsVectorLayer(f"{kind}?crs={crs}", "l", "memory")
    feats = []
    for w in wkts:
        f = QgsFeature()
        f.setGeometry(QgsGeometry.fromWkt(w))
        feats.append(f)
    lay.dataProvider().addFeatures(feats)
    return lay


SQUARE = "POLYGON((500010 5399990, 500020 5399990, 500020 5399980, 500010 5399980, 500010 5399990))"
BOWTIE = "POLYGON((500010 5399990, 500020 5399980, 500020 5399990, 500010 5399980, 500010 5399990))"


@pytest.mark.parametrize("key,kind,wkt,message", [
    ("OBJECT_AREAS", "Point", "POINT(500015 5399985)",
     r"\(OBJECT_AREAS\) holds points \(feature 1\) but takes polygons"),
    ("OBJECT_AREAS", "LineString", "LINESTRING(500010 5399990, 500030 5399970)",
     r"\(OBJECT_AREAS\) holds lines \(feature 1\) but takes polygons"),
    ("BREAKLINES", "Polygon", SQUARE, r"\(BREAKLINES\) holds polygons \(feature 1\) but takes lines"),
    ("OBJECT_AREAS", "Polygon", BOWTIE, r"\(OBJECT_AREAS\): feature 1 has an invalid geometry \(.*intersect.*\): "
                                        r"repair the layer"),
    # a collection of mixed kinds (a DXF's or a GeoJSON's): named as such (before: "holds geometries")
    ("OBJECT_AREAS", "GeometryCollection", f"GEOMETRYCOLLECTION({SQUARE}, LINESTRING(500010 5399990, 500030 5399970))",
     r"\(OBJECT_AREAS\) holds GeometryCollection geometries \(feature 1\) but takes polygons"),
], ids=["points_as_objects", "lines_as_objects", "polygons_as_breaklines", "invalid_polygon", "collection_as_objects"])
def test_dtm_layers_of_the_wrong_kind_or_invalid_refused_before_work(processing_run, tmp_path, key, kind, wkt,
                                                                     message):
    """Points or lines as OBJECT_AREAS, polygons as BREAKLINES: refused naming the layer (before: burnt as
    objects or break lines over whole polygons). An invalid polygon: refused by our check, naming the
    feature and the fix; before: QGIS's check raised inside the feature iterator and the next run of the
    session crashed the interpreter ('XXX lineno: 367, opcode: 151'), so a valid run follows here."""
    from qgis.core import QgsProcessingException
    src = _write(tmp_path / "dsm.tif", _ramp_with_box((60, 60)), nodata=-9999.0)
    outs = {"OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif")}
    with pytest.raises(QgsProcessingException, match=message):
        processing_run("bareearth:dtm", {"INPUT": src, key: _memory_layer(kind, [wkt]), **outs})
    assert not (tmp_path / "d.tif").exists()
    res = processing_run("bareearth:dtm", {"INPUT": src, "OBJECT_AREAS": _memory_layer("Point", []), **outs})
    assert (tmp_path / "d.tif").exists() and res["OUTPUT_MASK"]


def test_dtm_layer_outside_the_dsm_warns_and_other_crs_is_reprojected(processing_run, tmp_path):
    from qgis.core import QgsProcessingFeedback
    src = _write(tmp_path / "dsm.tif", _ramp_with_box((60, 60)), nodata=-9999.0)
    warnings = []

    class Log(QgsProcessingFeedback):
        def pushWarning(self, text):  # noqa: N802
            warnings.append(text)
    far = _memory_layer("Polygon", ["POLYGON((600000 5000000, 600010 5000000, 600010 4999990, 600000 5000000))"])
    processing_run("bareearth:dtm", {"INPUT": src, "OBJECT_AREAS": far, "OUTPUT_DTM": str(tmp_path / "d.tif"),
                                     "OUTPUT_MASK": str(tmp_path / "m.tif")}, feedback=Log())
    assert any("none of its 1 feature(s) touches the DSM" in w and "EPSG:32632" in w for w in warnings)
    # the square 30..40 m east, 30..40 m south of the corner, given in degrees: objects there after reprojection
    from qgis.core import QgsCoordinateReferenceSystem, QgsCoordinateTransform, QgsGeometry, QgsProject
    g = QgsGeometry.fromWkt("POLYGON((500031 5399969, 500039 5399969, 500039 5399961, 500031 5399961, "
                            "500031 5399969))")
    g.transform(QgsCoordinateTransform(QgsCoordinateReferenceSystem("EPSG:32632"),
                                       QgsCoordinateReferenceSystem("EPSG:4326"), QgsProject.instance()))
    degrees = _memory_layer("Polygon", [g.asWkt()], "EPSG:4326")
    outs = {"OUTPUT_DTM": str(tmp_path / "d2.tif"), "OUTPUT_MASK": str(tmp_path / "m2.tif")}
    res = processing_run("bareearth:dtm", {"INPUT": src, "OBJECT_AREAS": degrees, **outs})
    assert (_read(res["OUTPUT_MASK"])[0][32:38, 32:38] == 1).all()


@pytest.mark.parametrize("key,kind,wkt", [
    ("OBJECT_AREAS", "Polygon", SQUARE),
    ("BREAKLINES", "LineString", "LINESTRING(500010 5399990, 500030 5399970)"),
    ("GROUND_AREAS", "Point", "POINT(500015 5399985)"),
], ids=["objects", "breaklines", "ground_points"])
def test_dtm_layer_whose_coordinates_are_not_in_its_crs_refused_saying_so(processing_run, tmp_path, key, kind, wkt):
    """UTM metres in a layer said to be in degrees (EPSG:4326), the commonest wrong layer CRS: the
    reprojection gave infinite coordinates and the refusal blamed an invalid geometry ('ring 0 not
    closed: repair the layer (Fix Geometries)'), or the points were dropped without a word. It now
    names the layer's CRS, the feature's coordinates and how to assign the right CRS."""
    from qgis.core import QgsProcessingException
    src = _write(tmp_path / "dsm.tif", _ramp_with_box((60, 60)), nodata=-9999.0)
    outs = {"OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif")}
    with pytest.raises(QgsProcessingException, match=r"the coordinates of feature 1 \(5000[0-9]+, 5399[0-9]+\) are "
                                                     r"not coordinates of the layer's CRS \(EPSG:4326\).*EPSG:32632.*"
                                                     r"Assign Projection"):
        processing_run("bareearth:dtm", {"INPUT": src, key: _memory_layer(kind, [wkt], "EPSG:4326"), **outs})
    assert not (tmp_path / "d.tif").exists()


@pytest.mark.parametrize("extra,message", [
    ({"THREADS": "abc"}, r"\(THREADS\) = 'abc' is not a number"),
    ({"BAND": "abc"}, r"\(BAND\) = 'abc' is not a number"),
    ({"SLOPE_THRESHOLD_DEG": "nan"}, r"\(SLOPE_THRESHOLD_DEG\) = 'nan' is not a number: give a number, or leave it"),
    ({"COG": "maybe"}, r"\(COG\) = 'maybe' is not a yes/no value"),
    # a decimal comma (German, French... keyboards): the same value with a point is named
    ({"SLOPE_THRESHOLD_DEG": "30,5"}, r"\(SLOPE_THRESHOLD_DEG\) = '30,5' is not a number: give a number, or "
                                      r"leave it out \(with a decimal point: 30\.5\)"),
    ({"SLOPE_TRESHOLD_DEG": "30"}, r"SLOPE_TRESHOLD_DEG is no parameter of bareearth:slopeprofile"),
    ({"PROCESSES": "64"}, r"\(PROCESSES\) = 64, but this computer has [0-9]+ core\(s\)"),
], ids=["threads_text", "band_text", "nan_text", "bool_text", "decimal_comma", "misspelt", "processes_beyond_cores"])
def test_qgis_process_bad_values_refused(run_qgis_process, tmp_path, extra, message):
    """Values qgis_process passes as text that QGIS read as 0, false or "not given" (a run with other
    values than asked), a misspelt parameter name (silently left out) and more worker processes than
    cores: refused before any work (before: each ran, exit code 0)."""
    src = _write(tmp_path / "dsm.tif", _ramp_with_box(), nodata=-9999.0)
    if "PROCESSES" in extra:
        from bare_earth.core.blocks import available_cores
        extra = {"PROCESSES": str(available_cores() + 1)}
        message = message.replace("64", str(available_cores() + 1))
    rc, out, _ = run_qgis_process("bareearth:slopeprofile", {"INPUT": src, "OUTPUT_DTM": tmp_path / "d.tif",
                                                             "OUTPUT_MASK": tmp_path / "m.tif", **extra})
    assert rc != 0 and re.search(message, out), out
    assert not (tmp_path / "d.tif").exists()


@pytest.mark.parametrize("key,values", [("TOLERANCE_M", [0.3, 0.3]), ("BLOCK_SIZE", ["64", "128"]),
                                        ("REFINE", ["true", "false"]),
                                        ("CREATE_OPTIONS", ["COMPRESS=LZW", "TILED=YES"])])
def test_a_parameter_given_twice_refused_before_work(processing_run, tmp_path, key, values):
    """QA14: qgis_process makes a list of a key given twice (TOLERANCE_M=0.3 TOLERANCE_M=0.3); QGIS reads an
    optional number's list as 0 and passes it: slopeprofile ran with a height tolerance of 0 m, BLOCK_SIZE as 0
    (automatic), a yes/no or the creation options as neither value given, exit code 0. QGIS's own algorithms
    refuse it for a required number ('Incorrect parameter value for DISTANCE')."""
    from qgis.core import QgsProcessingException
    src = _write(tmp_path / "dsm.tif", _ramp_with_box())
    listed = ", ".join(str(v) for v in values)
    with pytest.raises(QgsProcessingException, match=rf"\({key}\) is given 2 times \({re.escape(listed)}\): give "
                                                     r"it once\.$"):
        processing_run("bareearth:slopeprofile", {"INPUT": src, "OUTPUT_DTM": str(tmp_path / "d.tif"),
                                                  "OUTPUT_MASK": str(tmp_path / "m.tif"), key: values})
    assert not (tmp_path / "d.tif").exists()
    first = re.escape(str(values[0]))
    with pytest.raises(QgsProcessingException, match=rf"\({key}\) is given as a list \(\[{first}\]\): give the "
                                                     r"value alone\.$"):     # a script's one-element list
        processing_run("bareearth:slopeprofile", {"INPUT": src, "OUTPUT_DTM": str(tmp_path / "d.tif"),
                                                  "OUTPUT_MASK": str(tmp_path / "m.tif"), key: values[:1]})


def test_layers_that_are_not_gdal_files_are_refused_naming_the_layer(processing_run, tmp_path):
    """A GeoPackage raster table added as 'file.gpkg|layername=table' (the vector form) is an invalid
    layer: it was read as a file of that name ('No such file or directory. The file may be truncated
    or corrupt'); it is refused as an invalid layer, with the raster form. A web service's layer (XYZ
    tiles, WMS) is refused naming its provider. The same table as GPKG:file.gpkg:table runs."""
    from osgeo import gdal
    from qgis.core import QgsProcessingException, QgsProject, QgsRasterLayer
    dsm = _write(tmp_path / "dsm.tif", _ramp_with_box())
    gpkg = str(tmp_path / "dsm.gpkg")
    gdal.Translate(gpkg, str(dsm), format="GPKG", creationOptions=["RASTER_TABLE=heights"])
    outs = {"OUTPUT_DTM": "TEMPORARY_OUTPUT", "OUTPUT_MASK": "TEMPORARY_OUTPUT"}
    bad = QgsRasterLayer(gpkg + "|layername=heights", "heights")
    xyz = QgsRasterLayer("type=xyz&url=http://127.0.0.1:9/{z}/{x}/{y}.png&zmax=19&zmin=0", "tiles", "wms")
    good = QgsRasterLayer(f"GPKG:{gpkg}:heights", "table")
    QgsProject.instance().addMapLayers([bad, xyz, good])
    try:
        with pytest.raises(QgsProcessingException, match=r"The layer 'heights' is not valid: QGIS could not open "
                                                         r"its source .*GPKG:file.gpkg:table"):
            processing_run("bareearth:slopeprofile", dict(outs, INPUT=bad))
        with pytest.raises(QgsProcessingException, match=r"The layer 'tiles' is served by the 'wms' provider; save "
                                                         r"it as a GeoTIFF first"):
            processing_run("bareearth:slopeprofile", dict(outs, INPUT=xyz))
        assert processing_run("bareearth:slopeprofile", dict(outs, INPUT=good))["OUTPUT_MASK"]
    finally:
        QgsProject.instance().removeMapLayers([bad.id(), xyz.id(), good.id()])


def test_dtm_object_areas_covering_the_whole_dsm_refused_before_work(processing_run, tmp_path):
    """QA 22: an OBJECT_AREAS layer covering every cell (a study-area or parcel polygon given as footprints)
    forces every cell an object: the run wrote a DTM of nodata only and blamed the filter ("The filter called
    none of the 3600 valid cell(s) ground ... Give a raster that reaches the ground"). Now refused before any
    output, naming the layer; with a ground area inside (ground areas win) it runs."""
    from qgis.core import QgsProcessingException
    src = _write(tmp_path / "dsm.tif", _ramp_with_box((60, 60)), nodata=-9999.0)
    whole = _memory_layer("Polygon", ["POLYGON((499990 5400010, 500070 5400010, 500070 5399930, 499990 5399930, "
                                      "499990 5400010))"])
    outs = {"OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif")}
    with pytest.raises(QgsProcessingException, match=r"Object areas .*\(OBJECT_AREAS\) covers? every cell of the DSM"):
        processing_run("bareearth:dtm", {"INPUT": src, "OBJECT_AREAS": whole, **outs})
    assert not (tmp_path / "d.tif").exists() and not (tmp_path / "m.tif").exists()
    res = processing_run("bareearth:dtm", {"INPUT": src, "OBJECT_AREAS": whole, **outs,
                                           "GROUND_AREAS": _memory_layer("Point", ["POINT(500030.5 5399959.5)"])})
    mask, _ = _read(res["OUTPUT_MASK"])
    assert (mask == 0).sum() == 1 and (mask == 1).sum() == mask.size - 1


@pytest.mark.parametrize("centres", [("9.0,48.7,1100", "9.001,48.7,1100"), ("9.0,48.7,1100", "9.5,48.7,1100"),
                                     ("600050,5399950,1100", "600080,5399950,1100")],
                         ids=["degrees_close", "degrees_apart", "another_zone"])
def test_orthoparallax_camera_centres_far_from_the_dem_refused_naming_them(processing_run, tmp_path, centres):
    """QA 22: camera centres given in another CRS (degrees, another zone) than the DEM's: the DEM lies far
    beyond any vertical frame's view from them. Before: 'CAMERA_A and CAMERA_B are at the same place (9.0,
    48.7, 1100.0) (base B = 0)' for centres 0.001 apart, or a run measuring nothing; now refused before any
    output, naming the centre, its distance from the DEM and the DEM's CRS. Centres over the DEM run."""
    from qgis.core import QgsProcessingException
    params = _ortho_pair(tmp_path)
    params.update(CAMERA_A=centres[0], CAMERA_B=centres[1])
    a = re.escape(str(tuple(float(v) for v in centres[0].split(","))))
    with pytest.raises(QgsProcessingException, match=rf"CAMERA_A {a} lies .* m from the DEM.*EPSG:32632"):
        processing_run("bareearth:orthoparallax", params)
    assert not (tmp_path / "o.tif").exists()
    params.update(CAMERA_A="500040,5399950,1100", CAMERA_B="500060,5399950,1100")     # over the DEM
    assert processing_run("bareearth:orthoparallax", params)["OUTPUT_DEM"]
