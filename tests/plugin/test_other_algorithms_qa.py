"""The provider's other algorithms (evaluate, filldtm, points, orthophotos, survey) with edge
inputs (the second adversarial QA round): each test failed before the fix it names."""
import json
import os

import numpy as np
import pytest

pytestmark = pytest.mark.qgis
GT = (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0)


def _write(path, arr, gt=GT, epsg=32632, nodata=None, **kw):
    from bare_earth.core.grid import write_array
    return write_array(path, arr, gt, epsg, nodata=nodata, **kw)


def _mask(shape=(40, 40)):
    m = np.zeros(shape, np.uint8)
    m[10:20, 10:20] = 1
    return m


def _ramp(shape=(40, 40)):
    return np.zeros(shape, np.float32) + np.linspace(0.0, 3.0, shape[1], dtype=np.float32)[None, :]


def test_rasters_in_another_crs_are_not_on_the_grid(processing_run, tmp_path):
    """The same cell numbers in two CRS are two places: a reference mask, reference DTM or a mask
    to fill by in another CRS was compared cell by cell without a word (kappa 100 %)."""
    from qgis.core import QgsProcessingException
    m = _write(tmp_path / "m.tif", _mask(), nodata=255)
    m_bng = _write(tmp_path / "m_bng.tif", _mask(), epsg=27700, nodata=255)
    z = _write(tmp_path / "z.tif", _ramp(), nodata=-9999.0)
    z_bng = _write(tmp_path / "z_bng.tif", _ramp() + 1.0, epsg=27700, nodata=-9999.0)
    for params, what in (
            (dict(MASK=m, REFERENCE_MASK=m_bng), "The reference mask"),
            (dict(DTM=z, REFERENCE_DTM=z_bng), "The reference DTM")):
        with pytest.raises(QgsProcessingException, match=what + r" is in another CRS \(OSGB36.*\) than the"):
            processing_run("bareearth:evaluate", dict(params, OUTPUT_JSON=str(tmp_path / "e.json"),
                                                      OUTPUT_HTML=str(tmp_path / "e.html")))
    out = tmp_path / "filled.tif"
    with pytest.raises(QgsProcessingException, match=r"The mask is in another CRS \(OSGB36"):
        processing_run("bareearth:filldtm", {"INPUT": z, "MASK": m_bng, "OUTPUT": str(out)})
    assert not out.exists() and not (tmp_path / "e.json").exists()


def test_evaluate_reference_mask_of_a_dtm_comparison_on_its_grid(processing_run, tmp_path):
    """REFERENCE_MASK picks the ground cells of the DTM errors: on a shifted grid it picked other
    cells (ground RMSE of the wrong cells), on another shape it was dropped, both without a word;
    a MASK without REFERENCE_MASK was not used, without a word."""
    from qgis.core import QgsProcessingException
    z = _write(tmp_path / "z.tif", _ramp(), nodata=-9999.0)
    z_ref = _write(tmp_path / "z_ref.tif", _ramp(), nodata=-9999.0)   # one file is refused as compared with itself
    shifted = _write(tmp_path / "shifted.tif", _mask(), gt=(500010.0,) + GT[1:], nodata=255)
    small = _write(tmp_path / "small.tif", _mask((30, 30)), nodata=255)
    mask = _write(tmp_path / "m.tif", _mask(), nodata=255)
    outs = dict(OUTPUT_JSON=str(tmp_path / "e.json"), OUTPUT_HTML=str(tmp_path / "e.html"))
    for ref in (shifted, small):
        with pytest.raises(QgsProcessingException, match=r"The reference mask \(REFERENCE_MASK\), whose ground "
                                                         r"cells .* is not on the DTM's grid"):
            processing_run("bareearth:evaluate", dict(DTM=z, REFERENCE_DTM=z_ref, REFERENCE_MASK=ref, **outs))
    with pytest.raises(QgsProcessingException, match=r"MASK is compared .* or leave MASK out"):
        processing_run("bareearth:evaluate", dict(DTM=z, REFERENCE_DTM=z_ref, MASK=mask, **outs))
    res = processing_run("bareearth:evaluate", dict(DTM=z, REFERENCE_DTM=z_ref, REFERENCE_MASK=mask, **outs))
    with open(res["OUTPUT_JSON"]) as fh:
        figures = json.load(fh)["results"]["DTM vs reference DTM"]
    assert figures["ground_n"] == 1500 and figures["n"] == 1600


def _points(n=400, seed=0):
    rng = np.random.default_rng(seed)
    x = GT[0] + rng.uniform(0.5, 39.5, n)
    y = GT[3] - rng.uniform(0.5, 39.5, n)
    obj = rng.uniform(size=n) < 0.2
    z = (x - GT[0]) * 3.0 / 40.0 + 5.0 * obj
    return x, y, z, obj


def _text(path, *cols):
    np.savetxt(path, np.column_stack(cols), fmt="%.3f")
    return str(path)


def test_evaluate_truth_without_a_ground_class_refused(processing_run, tmp_path):
    """A truth in the other convention (ASPRS codes 2/6 in a text file, ISPRS 0/1 in a LAS file)
    or not classified (LAS all class 1) has no ground point: every point was an object, Type I
    'not defined' and a total error of the object share, without a word."""
    laspy = pytest.importorskip("laspy")
    from qgis.core import QgsProcessingException
    x, y, z, obj = _points()
    dtm = _write(tmp_path / "dtm.tif", _ramp(), nodata=-9999.0)
    outs = dict(OUTPUT_JSON=str(tmp_path / "e.json"), OUTPUT_HTML=str(tmp_path / "e.html"))
    asprs = _text(tmp_path / "asprs.txt", x, y, z, np.where(obj, 6, 2))
    with pytest.raises(QgsProcessingException, match=r"hold no ground point: ground is class 0 in a text file.*"
                                                     r"classes are 2, 6; class 2 looks like ASPRS LAS codes"):
        processing_run("bareearth:evaluate", dict(POINTS=asprs, DTM=dtm, **outs))

    def las(name, cls):
        h = laspy.LasHeader(point_format=3, version="1.2")
        h.scales, h.offsets = [0.001] * 3, [GT[0], GT[3], 0.0]
        data = laspy.LasData(h)
        data.x, data.y, data.z, data.classification = x, y, z, cls.astype(np.uint8)
        data.write(str(tmp_path / name))
        return str(tmp_path / name)
    for name, cls, classes in (("unclassified.las", np.ones(x.size), "1"), ("isprs.las", obj, "0, 1")):
        with pytest.raises(QgsProcessingException, match=r"hold no ground point: ground is class 2 in a LAS/LAZ "
                                                         rf"file .*classes are {classes}; it is not classified"):
            processing_run("bareearth:evaluate", dict(POINTS=las(name, cls), DTM=dtm, **outs))
    pred = _text(tmp_path / "pred.txt", x, y, z, obj.astype(int))
    with pytest.raises(QgsProcessingException, match=r"truth points hold no ground point.*classes are 2, 6"):
        processing_run("bareearth:evaluate", dict(POINTS=pred, TRUTH_POINTS=asprs, **outs))
    assert not (tmp_path / "e.json").exists() and not (tmp_path / "e.html").exists()
    truth = _text(tmp_path / "truth.txt", x, y, z, obj.astype(int))
    res = processing_run("bareearth:evaluate", dict(POINTS=pred, TRUTH_POINTS=truth, **outs))
    assert res["TOTAL"] == 0.0 and res["KAPPA"] == 100.0


def test_evaluate_points_in_another_crs_than_the_dtm_warn(processing_run, tmp_path):
    """LAS points whose header declares another CRS than the DTM's were classified by it without a
    word (classifypoints warns): the figures are of other places if the numbers differ."""
    laspy = pytest.importorskip("laspy")
    pyproj = pytest.importorskip("pyproj")
    from qgis.core import QgsProcessingFeedback
    x, y, z, obj = _points()
    h = laspy.LasHeader(point_format=3, version="1.2")
    h.scales, h.offsets = [0.001] * 3, [GT[0], GT[3], 0.0]
    try:
        h.add_crs(pyproj.CRS.from_wkt(_bng_wkt()))
    except Exception as exc:  # pragma: no cover - a pyproj without its data
        pytest.skip(f"pyproj cannot write a CRS here: {exc}")
    data = laspy.LasData(h)
    data.x, data.y, data.z, data.classification = x, y, z, np.where(obj, 6, 2).astype(np.uint8)
    data.write(str(tmp_path / "bng.las"))
    dtm = _write(tmp_path / "dtm.tif", _ramp(), nodata=-9999.0)
    warnings = []
    fb = QgsProcessingFeedback()
    fb.pushWarning = lambda s: warnings.append(s)
    res = processing_run("bareearth:evaluate", dict(POINTS=str(tmp_path / "bng.las"), DTM=dtm,
                                                    OUTPUT_JSON=str(tmp_path / "e.json"),
                                                    OUTPUT_HTML=str(tmp_path / "e.html")), feedback=fb)
    assert res["TOTAL"] == 0.0
    assert any("differs from the DTM's" in w and "British National Grid" in w for w in warnings), warnings


def _bng_wkt():
    from osgeo import osr
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(27700)
    return srs.ExportToWkt()


def test_evaluate_report_to_a_folder_refused_and_leaves_no_json(processing_run, tmp_path):
    """OUTPUT_HTML naming a folder ended in a Python traceback (IsADirectoryError), after the JSON
    had been written: a figures file of a failed run, looking valid."""
    from qgis.core import QgsProcessingException
    m = _write(tmp_path / "m.tif", _mask(), nodata=255)
    folder = tmp_path / "reports"
    folder.mkdir()
    with pytest.raises(QgsProcessingException, match=r"OUTPUT_HTML\): the output '.*reports' is a folder: give "
                                                     r"a file name in it \(e.g. '.*reports/output.html'\)") as err:
        processing_run("bareearth:evaluate", dict(MASK=m, REFERENCE_MASK=m, OUTPUT_JSON=str(tmp_path / "e.json"),
                                                  OUTPUT_HTML=str(folder)))
    assert "Traceback" not in str(err.value)
    assert sorted(os.listdir(tmp_path)) == ["m.tif", "reports"] and os.listdir(folder) == []


@pytest.mark.parametrize("shift, side", [(0.0, None), (-47.0, "below"), (47.0, "above")])
def test_classifypoints_heights_that_do_not_fit_the_dtm_warn(processing_run, tmp_path, shift, side):
    """Points in ellipsoidal heights against a DTM in geoid heights (47 m apart in Europe) were
    all 'below' (or all 'above') the DTM, reported as counts without a word."""
    from qgis.core import QgsProcessingFeedback
    x, y, z, obj = _points()
    pts = _text(tmp_path / "pts.txt", x, y, z + shift)
    dtm = _write(tmp_path / "dtm.tif", _ramp(), nodata=-9999.0)
    warnings = []
    fb = QgsProcessingFeedback()
    fb.pushWarning = lambda s: warnings.append(s)
    res = processing_run("bareearth:classifypoints", {"INPUT": pts, "DTM": dtm, "OUTPUT": str(tmp_path / "c.txt")},
                         feedback=fb)
    found = [w for w in warnings if "do not fit" in w]
    if side is None:
        assert not found and res["GROUND"] == int((~obj).sum()) and res["ABOVE"] == int(obj.sum())
    else:
        assert res[side.upper()] == x.size
        assert len(found) == 1 and f"400 of the 400 points on the DTM (100 %) are {side} it" in found[0]
        assert "ellipsoidal against geoid heights" in found[0]


def test_laz_output_without_a_laz_backend_refused_before_work(processing_run, tmp_path, monkeypatch):
    """Without lazrs/laszip, laspy fails only when it writes the .laz, after the work: the run
    failed then, leaving an empty .laz (classifypoints) or the filter's DTM and mask in place."""
    laspy = pytest.importorskip("laspy")
    from qgis.core import QgsProcessingException
    monkeypatch.setattr(laspy.LazBackend, "detect_available", staticmethod(lambda: ()))
    x, y, z, _ = _points(2000)
    pts = _text(tmp_path / "pts.txt", x, y, z)
    dtm = _write(tmp_path / "dtm.tif", _ramp(), nodata=-9999.0)
    message = r"'.*\.laz' is a compressed LAZ file, but no LAZ backend is installed: write a .las file, or install"
    with pytest.raises(QgsProcessingException, match=message):
        processing_run("bareearth:classifypoints", {"INPUT": pts, "DTM": dtm, "OUTPUT": str(tmp_path / "c.laz")})
    with pytest.raises(QgsProcessingException, match=message):
        processing_run("bareearth:morphological", {"INPUT_POINTS": pts, "OUTPUT_DTM": str(tmp_path / "d.tif"),
                                                   "OUTPUT_MASK": str(tmp_path / "m.tif"),
                                                   "OUTPUT_POINTS": str(tmp_path / "c2.laz")})
    assert sorted(os.listdir(tmp_path)) == ["dtm.tif", "pts.txt"]
    res = processing_run("bareearth:classifypoints", {"INPUT": pts, "DTM": dtm, "OUTPUT": str(tmp_path / "c.las")})
    assert res["GROUND"] + res["ABOVE"] == 2000 and laspy.read(res["OUTPUT"]).header.point_count == 2000


def test_tiles_parameter_out_of_range_refused_before_any_work(processing_run, tmp_path):
    """PARAMETERS 'max_object_size_m=-5' passed the check, started the run (and created the
    output folder) and failed there."""
    pytest.importorskip("distributed")
    from qgis.core import QgsProcessingException

    from bare_earth.core.methods import available_methods
    tile = _write(tmp_path / "t.tif", _ramp((64, 64)), nodata=-9999.0)
    out = tmp_path / "out"
    with pytest.raises(QgsProcessingException, match=r"max_object_size_m = -5.0 is out of range"):
        processing_run("bareearth:tiles", {"INPUT_LAYERS": [tile], "WORKERS": 1, "OUTPUT_FOLDER": str(out),
                                           "METHOD": sorted(available_methods()).index("morphological"),
                                           "PARAMETERS": "max_object_size_m=-5"})
    assert not out.exists()


def test_evaluate_truth_column_that_is_the_prediction_refused(processing_run, tmp_path):
    """TRUTH_COLUMN naming the column the classes of POINTS are read from (a classified LAS's
    'classification', which classifypoints overwrote; a text file's 'class'), or TRUTH_POINTS
    the POINTS file itself, compared the classes with themselves: kappa 100 %, no error,
    without a word."""
    from qgis.core import QgsProcessingException
    x, y, z, obj = _points()
    np.savetxt(tmp_path / "cls.txt", np.column_stack([x, y, z, obj, ~obj]), fmt="%.3f", header="x y z class truth",
               comments="")
    outs = dict(OUTPUT_JSON=str(tmp_path / "e.json"), OUTPUT_HTML=str(tmp_path / "e.html"))
    with pytest.raises(QgsProcessingException, match=r"\(TRUTH_COLUMN\) 'Class' is the column the classes of "
                                                     r"POINTS are read from: they would be compared with themselves"):
        processing_run("bareearth:evaluate", dict(POINTS=str(tmp_path / "cls.txt"), TRUTH_COLUMN="Class", **outs))
    with pytest.raises(QgsProcessingException, match=r"\(TRUTH_POINTS\) and POINTS are one file .*cls.txt\): the "
                                                     r"classes would be compared with themselves"):
        processing_run("bareearth:evaluate", dict(POINTS=str(tmp_path / "cls.txt"),
                                                  TRUTH_POINTS=str(tmp_path / "cls.txt"), **outs))
    res = processing_run("bareearth:evaluate", dict(POINTS=str(tmp_path / "cls.txt"), TRUTH_COLUMN="truth", **outs))
    assert res["TOTAL"] == 100.0                   # 'truth' holds the opposite classes: every point wrong
    laspy = pytest.importorskip("laspy")
    h = laspy.LasHeader(point_format=3, version="1.2")
    h.scales, h.offsets = [0.001] * 3, [GT[0], GT[3], 0.0]
    data = laspy.LasData(h)
    data.x, data.y, data.z, data.classification = x, y, z, np.where(obj, 1, 2).astype(np.uint8)
    data.write(str(tmp_path / "cls.las"))
    with pytest.raises(QgsProcessingException, match=r"\(TRUTH_COLUMN\) 'classification' is the column"):
        processing_run("bareearth:evaluate", dict(POINTS=str(tmp_path / "cls.las"), TRUTH_COLUMN="classification",
                                                  **outs))


def test_filldtm_codes_the_mask_does_not_hold_warn(processing_run, tmp_path):
    """FILL_CODES naming no code of the mask (7 for a 0/1 mask) filled nothing, the output a copy of
    the input, with only 'Filling 0 of ... cells' in the log."""
    from qgis.core import QgsProcessingFeedback
    z = _write(tmp_path / "z.tif", _ramp(), nodata=-9999.0)
    m = _write(tmp_path / "m.tif", _mask(), nodata=255)
    found = {}
    for codes in ("7", "1"):
        warnings = []
        fb = QgsProcessingFeedback()
        fb.pushWarning = lambda s, seen=warnings: seen.append(s)
        processing_run("bareearth:filldtm", {"INPUT": z, "MASK": m, "FILL_CODES": codes, "FILL_NODATA": False,
                                             "OUTPUT": str(tmp_path / f"f{codes}.tif")}, feedback=fb)
        found[codes] = [w for w in warnings if "holds none of FILL_CODES" in w]
    assert not found["1"]
    assert len(found["7"]) == 1 and "FILL_CODES (7); its codes are 0, 1: it fills no cell" in found["7"][0]


@pytest.mark.parametrize("ground,obj,codes,hint", [(2, 6, "2, 6", "ASPRS"), (1, 2, "1, 2", "another code")])
def test_evaluate_reference_mask_without_ground_refused_naming_its_codes(processing_run, tmp_path, ground, obj,
                                                                         codes, hint):
    """A reference mask in another convention (ASPRS 2 ground / 6 building, or 1 ground / 2
    object) has no cell of code 0: every cell was an object, Type I 'not defined' and a total
    error of 94.6 % without a word. Refused before any work, naming the codes and the fix; a
    reference with ground cells still runs."""
    from qgis.core import QgsProcessingException
    m = _write(tmp_path / "m.tif", _mask(), nodata=255)
    ref = _write(tmp_path / "ref.tif", np.where(_mask() == 1, obj, ground).astype(np.uint8), nodata=255)
    outs = dict(OUTPUT_JSON=str(tmp_path / "e.json"), OUTPUT_HTML=str(tmp_path / "e.html"))
    with pytest.raises(QgsProcessingException, match=rf"reference mask \(REFERENCE_MASK\) .*ref.tif' holds no ground "
                                                     rf"cell \(code 0\): its codes are {codes}\..*{hint}"):
        processing_run("bareearth:evaluate", dict(MASK=m, REFERENCE_MASK=ref, **outs))
    assert not os.path.exists(outs["OUTPUT_JSON"])
    same = _write(tmp_path / "same.tif", _mask(), nodata=255)      # one file is refused as compared with itself
    r = processing_run("bareearth:evaluate", dict(MASK=m, REFERENCE_MASK=same, **outs))
    assert r["TOTAL"] == 0.0


@pytest.mark.parametrize("percent", [1, 40])
def test_evaluate_cancelled_writes_no_report(processing_run, tmp_path, percent):
    """evaluate had no progress and ignored a cancel: it compared and wrote both reports."""
    from qgis.core import QgsProcessingFeedback

    class CancelAt(QgsProcessingFeedback):
        def setProgress(self, p):  # noqa: N802
            super().setProgress(p)
            if p >= percent:
                self.cancel()
    m = _write(tmp_path / "m.tif", _mask(), nodata=255)
    z = _write(tmp_path / "z.tif", _ramp(), nodata=-9999.0)
    m_ref = _write(tmp_path / "m_ref.tif", _mask(), nodata=255)    # one file is refused as compared with itself
    z_ref = _write(tmp_path / "z_ref.tif", _ramp(), nodata=-9999.0)
    outs = dict(OUTPUT_JSON=str(tmp_path / "e.json"), OUTPUT_HTML=str(tmp_path / "e.html"))
    res = processing_run("bareearth:evaluate", dict(MASK=m, REFERENCE_MASK=m_ref, DTM=z, REFERENCE_DTM=z_ref, **outs),
                         feedback=CancelAt())
    assert not res or not res.get("OUTPUT_JSON")
    assert not os.path.exists(outs["OUTPUT_JSON"]) and not os.path.exists(outs["OUTPUT_HTML"])


# ------------------------------------------------ the tenth QA pass: several bands where one is read, ...


def _rgb(mask):
    """A mask as QGIS exports its rendering (Save as > Rendered image): red, green, blue."""
    return np.stack([np.where(mask == 1, 255, 0), np.where(mask == 1, 0, 160), np.zeros_like(mask)]).astype(np.uint8)


def test_evaluate_and_filldtm_refuse_several_bands_where_they_read_one(processing_run, tmp_path):
    """MASK, REFERENCE_MASK, DTM and REFERENCE_DTM of evaluate and filldtm's MASK have no band
    choice: a raster of several bands was read by its band 1 without a word (a mask exported as
    a rendered RGB image compared by its red: kappa 100 % against itself in colours, or a
    three-band stack compared by its first band)."""
    from qgis.core import QgsProcessingException
    m = _mask()
    rgb = _write(tmp_path / "mask_rgb.tif", _rgb(m))
    codes = _write(tmp_path / "mask.tif", m, nodata=255)
    z = np.zeros((40, 40), np.float32) + np.linspace(0.0, 3.0, 40, dtype=np.float32)
    stack = _write(tmp_path / "stack.tif", np.stack([z + 7.0, z]))
    dtm = _write(tmp_path / "dtm.tif", z)
    out = {"OUTPUT_JSON": str(tmp_path / "e.json"), "OUTPUT_HTML": str(tmp_path / "e.html")}
    for params, key in ((dict(MASK=rgb, REFERENCE_MASK=codes), "MASK"),
                        (dict(MASK=codes, REFERENCE_MASK=rgb), "REFERENCE_MASK"),
                        (dict(DTM=stack, REFERENCE_DTM=dtm), "DTM"),
                        (dict(DTM=dtm, REFERENCE_DTM=stack), "REFERENCE_DTM")):
        with pytest.raises(QgsProcessingException, match=rf"\b{key}\)?: the raster .* has [23] bands but this "
                                                         "input is read from a single band"):
            processing_run("bareearth:evaluate", dict(params, **out))
    assert not (tmp_path / "e.json").exists()
    filled = tmp_path / "filled.tif"
    with pytest.raises(QgsProcessingException, match="MASK: the raster .* has 3 bands.*rendered image"):
        processing_run("bareearth:filldtm", {"INPUT": dtm, "MASK": rgb, "OUTPUT": str(filled)})
    assert not filled.exists()


def test_evaluate_reads_the_height_band_beside_an_alpha_band(processing_run, tmp_path):
    """A DTM with an alpha band (gdalwarp -dstalpha) is one band of heights and its mask: still
    compared, its transparent cells left out."""
    from osgeo import gdal
    z = np.zeros((40, 40), np.float32) + np.linspace(0.0, 3.0, 40, dtype=np.float32)
    alpha = np.full((40, 40), 255, np.float32)
    alpha[:, :10] = 0
    path = _write(tmp_path / "dtm_alpha.tif", np.stack([z + 0.5, alpha]))
    ds = gdal.Open(path, gdal.GA_Update)
    ds.GetRasterBand(2).SetColorInterpretation(gdal.GCI_AlphaBand)
    ds = None
    ref = _write(tmp_path / "ref.tif", z)
    res = processing_run("bareearth:evaluate", {"DTM": path, "REFERENCE_DTM": ref,
                                                "OUTPUT_JSON": str(tmp_path / "e.json"),
                                                "OUTPUT_HTML": str(tmp_path / "e.html")})
    assert res["RMSE"] == pytest.approx(0.5, abs=1e-6)
    report = json.loads((tmp_path / "e.json").read_text())
    assert "1200" in json.dumps(report)                 # 30 x 40 cells compared


def test_orthophoto_tools_refuse_a_bottom_up_dem_before_work_saying_how(processing_run, tmp_path):
    """A DEM stored bottom-up (gt[5] > 0, as some exports write it; the filters take it) failed in
    orthoparallax with "geotransform must be north-up with positive cell size (dx > 0, dy < 0)",
    naming neither the input nor the fix; now refused before work naming the DEM and gdalwarp."""
    from qgis.core import QgsProcessingException
    rng = np.random.default_rng(0)
    up = (500000.0, 1.0, 0.0, 5399960.0, 0.0, 1.0)
    dem = _write(tmp_path / "dem_up.tif", np.full((40, 40), 100.0, np.float32), up)
    a = _write(tmp_path / "a.tif", rng.uniform(0, 255, (40, 40)).astype(np.float32), up)
    b = _write(tmp_path / "b.tif", rng.uniform(0, 255, (40, 40)).astype(np.float32), up)
    out = tmp_path / "out_dem.tif"
    for alg, params in (("orthoparallax", {"ORTHO_A": a, "ORTHO_B": b, "BASE_M": 100.0, "HEIGHT_M": 400.0}),
                        ("orthorefine", {"IMAGES": [a, b], "BASE_M": 100.0, "HEIGHT_M": 400.0})):
        with pytest.raises(QgsProcessingException, match=r"DEM: the raster .*dem_up.tif' is stored bottom-up .*"
                                                         r"gdalwarp"):
            processing_run(f"bareearth:{alg}", dict(params, DEM=dem, OUTPUT_DEM=str(out)))
        assert not out.exists()


def test_filldtm_codes_separated_by_spaces_and_empty_entries(processing_run, tmp_path):
    """QA15: FILL_CODES '1 2' (codes separated by a space, as bareearth:tiles' PARAMETERS takes them) was
    refused as 'must be integers', and '1,,2' (a code left out) was read as '1,2' without a word. Spaces
    separate codes as commas do; an empty entry between two commas is refused before any work."""
    from osgeo import gdal
    from qgis.core import QgsApplication, QgsProcessingContext
    z = _write(tmp_path / "z.tif", _ramp(), nodata=-9999.0)
    m = _write(tmp_path / "m.tif", np.where(_mask() == 1, 2, 0).astype(np.uint8) + np.eye(40, dtype=np.uint8),
               nodata=255)
    alg = QgsApplication.processingRegistry().algorithmById("bareearth:filldtm")
    out = {}
    for codes in ("1,2", "1 2", " 1 ; 2 ", "1, 2"):
        params = {"INPUT": z, "MASK": m, "FILL_CODES": codes, "FILL_NODATA": False,
                  "OUTPUT": str(tmp_path / f"f{len(out)}.tif")}
        ok, msg = alg.checkParameterValues(params, QgsProcessingContext())
        assert ok, (codes, msg)
        out[codes] = gdal.Open(processing_run("bareearth:filldtm", params)["OUTPUT"]).ReadAsArray()
    for codes in ("1 2", " 1 ; 2 ", "1, 2"):
        np.testing.assert_array_equal(out[codes], out["1,2"])
    for codes in ("1,,2", "1;;2", "1, ,2"):
        ok, msg = alg.checkParameterValues({"INPUT": z, "MASK": m, "FILL_CODES": codes,
                                            "OUTPUT": str(tmp_path / "g.tif")}, QgsProcessingContext())
        assert not ok and "(FILL_CODES) has an empty entry between two commas or semicolons" in msg, (codes, msg)


def test_filldtm_cells_filled_to_the_declared_nodata_stay_heights(processing_run, tmp_path):
    """A DTM declaring 300 as nodata over ground alternating 299 / 301 m: the cells filled under a masked
    object came to exactly 300 and were written as 300, read back as nodata (the gap 'filled' with holes).
    They are written just above, and the log says how many."""
    from osgeo import gdal
    from qgis.core import QgsProcessingFeedback
    c = np.arange(80, dtype=np.float64)
    z = np.tile(299.0 + 2.0 * (c % 2), (60, 1)).astype(np.float32)
    mask = np.zeros(z.shape, np.uint8)
    mask[20:40, 30:50] = 1
    src = _write(tmp_path / "z.tif", z, nodata=300.0)
    m = _write(tmp_path / "m.tif", mask, nodata=255)
    warnings = []
    fb = QgsProcessingFeedback()
    fb.pushWarning = lambda s: warnings.append(s)
    out = tmp_path / "f.tif"
    processing_run("bareearth:filldtm", {"INPUT": src, "MASK": m, "OUTPUT": str(out)}, feedback=fb)
    ds = gdal.Open(str(out))
    band = ds.GetRasterBand(1)
    f = band.ReadAsArray()
    assert band.GetNoDataValue() == 300.0 and not (f == np.float32(300.0)).any()
    assert (band.GetMaskBand().ReadAsArray() == 255).all()                 # GDAL reads every cell as valid
    n = int((f == np.float32(300.00030517578125)).sum())
    assert n > 50 and any(w.startswith(f"{n} cell(s) of the filled surface hold the declared nodata value 300")
                          for w in warnings), warnings
