"""Point clouds through the plugin: rasterizepoints, classifypoints, morphological with INPUT_POINTS,
evaluate on classified points, the example model, processing.run and qgis_process, bad inputs."""
import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.qgis

ROOT = Path(__file__).resolve().parents[2]
MODEL = ROOT / "examples" / "rasterize_filter_classify.model3"


def _scene_points(shape=(110, 130), seed=5, density=1.5):
    """x y z and ISPRS truth (0 ground, 1 object) sampled from a synthetic city."""
    from bare_earth.core.synthetic import make_scene
    sc = make_scene("city", shape, seed=seed)
    rng = np.random.default_rng(seed)
    h, w = sc.dsm.shape
    n = int(h * w * density)
    x, y = rng.uniform(0, w, n), rng.uniform(0, h, n)
    r, c = np.clip((h - y).astype(int), 0, h - 1), np.clip(x.astype(int), 0, w - 1)
    z = sc.dsm[r, c].astype(np.float64)
    ok = np.isfinite(z)
    return x[ok] + 500000.0, y[ok] + 5400000.0, z[ok], (sc.mask[r, c] != 0).astype(int)[ok]


def _write_text(path, x, y, z, cls=None, delim="\t", header=""):
    """x y z [class columns...] text, 3 decimals (the ISPRS layout with tabs)."""
    extra = [] if cls is None else [np.asarray(cls).reshape(len(x), -1)]
    table = np.column_stack([x, y, z] + extra)
    fmt = ["%.3f"] * 3 + ["%d"] * (table.shape[1] - 3)
    np.savetxt(path, table, fmt=fmt, delimiter=delim, header=header, comments="")
    return str(path)


@pytest.fixture(scope="module")
def cloud_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("points")
    x, y, z, t = _scene_points()
    txt = _write_text(d / "city.txt", x, y, z, t)
    (d / "city.prj").write_text("EPSG:32632")
    from bare_earth.core.points import read_points
    c = read_points(txt)                       # the coordinates as written (3 decimals)
    return {"dir": d, "txt": txt, "x": c.x, "y": c.y, "z": c.z, "truth": t}


def _las(path, x, y, z, cls, epsg=32632):
    laspy = pytest.importorskip("laspy")
    from osgeo import osr
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(epsg)
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([np.floor(x.min()), np.floor(y.min()), 0.0])
    header.vlrs.append(laspy.vlrs.known.WktCoordinateSystemVlr(srs.ExportToWkt()))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, z
    rng = np.random.default_rng(2)
    las.intensity = rng.integers(0, 65535, x.size).astype(np.uint16)
    las.gps_time = rng.uniform(0, 1e5, x.size)
    las.point_source_id = np.full(x.size, 9, np.uint16)
    las.classification = np.where(cls == 0, 2, 6).astype(np.uint8)   # ASPRS truth: 2 ground, 6 building
    las.write(str(path))
    return str(path)


def _read_raster(path):
    from osgeo import gdal
    ds = gdal.Open(str(path))
    b = ds.GetRasterBand(1)
    return b.ReadAsArray(), b.GetNoDataValue(), ds.GetGeoTransform(), ds.GetProjection()


# --------------------------------------------------------------------------- registration
def test_point_algorithms_registered(qgis_app):
    from qgis.core import QgsApplication

    from bare_earth.algorithms.compat import is_optional
    reg = QgsApplication.processingRegistry()
    for alg_id in ("bareearth:rasterizepoints", "bareearth:classifypoints", "bareearth:morphological"):
        assert reg.algorithmById(alg_id) is not None, alg_id
    m = reg.algorithmById("bareearth:morphological")
    assert is_optional(m.parameterDefinition("INPUT"))
    for key in ("INPUT_POINTS", "CELL_SIZE_M", "OUTPUT_POINTS", "OTHER_TILES"):
        assert m.parameterDefinition(key) is not None, key
    # INPUT stays mandatory for the other filters
    s = reg.algorithmById("bareearth:slopeprofile")
    assert not is_optional(s.parameterDefinition("INPUT"))
    assert s.parameterDefinition("INPUT_POINTS") is None


# --------------------------------------------------------------------------- rasterize
def test_rasterize_points(processing_run, cloud_files, tmp_path):
    from bare_earth.core.points import rasterize_points
    out = tmp_path / "dsm.tif"
    r = processing_run("bareearth:rasterizepoints", {"INPUT": cloud_files["txt"], "OUTPUT": str(out)})
    g, nd, gt, crs = _read_raster(out)
    assert r["CELL_SIZE"] == 1.0 and r["POINTS"] == cloud_files["x"].size
    assert "32632" in crs or "UTM zone 32N" in crs                   # from the .prj beside the text
    ref, rgt = rasterize_points(cloud_files["x"], cloud_files["y"], cloud_files["z"], 1.0)
    assert gt == pytest.approx(rgt) and np.isnan(nd)
    np.testing.assert_allclose(g, ref, atol=1e-3)                    # lowest, filled from the nearest
    # highest per cell, 2 m cells, empty cells left nodata, CRS given
    out2 = tmp_path / "dsm_max.tif"
    r2 = processing_run("bareearth:rasterizepoints", {"INPUT": cloud_files["txt"], "OUTPUT": str(out2),
                                                       "CELL_SIZE_M": 2.0, "REDUCER": 1, "FILL_EMPTY": False,
                                                       "CRS": "EPSG:25832"})
    g2, _, gt2, crs2 = _read_raster(out2)
    ref2, _ = rasterize_points(cloud_files["x"], cloud_files["y"], cloud_files["z"], 2.0, reducer="max",
                               fill_empty=None)
    assert gt2[1] == 2.0 and "25832" in crs2 or "ETRS89" in crs2
    np.testing.assert_allclose(g2, ref2, atol=1e-3)
    assert r2["EMPTY_CELLS"] == int(np.isnan(ref2).sum())


# --------------------------------------------------------------------------- morphological on points
def test_morphological_on_points_then_evaluate(processing_run, cloud_files, tmp_path):
    from bare_earth.core import pointflow as pf
    from bare_earth.core.points import read_points
    d = tmp_path
    r = processing_run("bareearth:morphological", {
        "INPUT_POINTS": cloud_files["txt"], "OUTPUT_DTM": str(d / "dtm.tif"), "OUTPUT_MASK": str(d / "mask.tif"),
        "OUTPUT_NDSM": str(d / "ndsm.tif"), "OUTPUT_POINTS": str(d / "cls.txt")})
    assert Path(r["OUTPUT_POINTS"]).exists() and Path(r["OUTPUT_NDSM"]).exists()
    out = read_points(r["OUTPUT_POINTS"])
    assert len(out) == cloud_files["x"].size
    assert set(np.unique(out.classification)) <= {0, 1, 2, 255}
    # the same classes as the core flow
    ref = pf.filter_cloud(read_points(cloud_files["txt"]))
    np.testing.assert_array_equal(out.classification, ref.classes)
    dtm, nd, gt, crs = _read_raster(r["OUTPUT_DTM"])
    assert dtm.shape == ref.grid.shape and gt == pytest.approx(ref.grid.geotransform) and "32632" in crs \
        or "UTM zone 32N" in crs
    mask, mnd, _, _ = _read_raster(r["OUTPUT_MASK"])
    assert mnd == 255 and set(np.unique(mask)) <= {0, 1, 2}
    # evaluate the classified points against the truth file
    ev = processing_run("bareearth:evaluate", {"POINTS": r["OUTPUT_POINTS"], "TRUTH_POINTS": cloud_files["txt"],
                                               "OUTPUT_JSON": str(d / "e.json"), "OUTPUT_HTML": str(d / "e.html")})
    figs = json.loads((d / "e.json").read_text())["results"]["classified points vs truth"]
    assert figs["n"] == len(out) and figs["points_unmatched"] == 0
    assert ev["TOTAL"] == pytest.approx(figs["total"]) and ev["TOTAL"] < 3.0
    assert ev["TYPE1"] >= 0 and ev["TYPE2"] >= 0 and ev["KAPPA"] > 90
    assert "point errors" in (d / "e.html").read_text()


def test_point_run_places_its_points_file_after_the_rasters(processing_run, cloud_files, tmp_path, monkeypatch):
    """A point run wrote (and put in place) its points file, then the rasters: a kill -9 during the
    rasters' writing left a complete-looking points file without its rasters. The points are now
    written to a hidden work file and moved into place after the rasters, so while the rasters are
    written no new points file is there; a failed raster write leaves the points file of the last
    run as it was."""
    from qgis.core import QgsProcessingException

    from bare_earth.core import grid
    seen = []
    commit = grid.OutputSet.commit

    def spy(self, *args, **kwargs):
        seen.append(sorted(p.name for p in tmp_path.iterdir()))
        return commit(self, *args, **kwargs)
    monkeypatch.setattr(grid.OutputSet, "commit", spy)
    params = {"INPUT_POINTS": cloud_files["txt"], "OUTPUT_DTM": str(tmp_path / "dtm.tif"),
              "OUTPUT_MASK": str(tmp_path / "mask.tif"), "OUTPUT_POINTS": str(tmp_path / "cls.txt")}
    processing_run("bareearth:morphological", params)
    assert len(seen) == 1 and "cls.txt" not in seen[0]      # not in place while the rasters were written
    assert any(n.startswith(".cls.txt.") and n.endswith(".part.txt") for n in seen[0])   # its work file was
    assert {"cls.txt", "dtm.tif", "mask.tif"} <= {p.name for p in tmp_path.iterdir()}
    before = (tmp_path / "cls.txt").read_bytes()
    (tmp_path / "cls.txt").write_text("old run\n")

    def fail(self, *args, **kwargs):
        raise ValueError("cannot put the output in place: disk full")
    monkeypatch.setattr(grid.OutputSet, "commit", fail)
    with pytest.raises(QgsProcessingException, match="disk full"):
        processing_run("bareearth:morphological", params)
    assert (tmp_path / "cls.txt").read_text() == "old run\n"   # the last run's file, untouched
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]   # no work file left
    assert before


def test_classified_points_truth_column(processing_run, cloud_files, tmp_path):
    from bare_earth.core.points import read_points
    r = processing_run("bareearth:morphological", {"INPUT_POINTS": cloud_files["txt"],
                                                   "OUTPUT_DTM": "TEMPORARY_OUTPUT", "OUTPUT_MASK": "TEMPORARY_OUTPUT",
                                                   "OUTPUT_POINTS": "TEMPORARY_OUTPUT"})
    assert r["OUTPUT_POINTS"].endswith(".txt")                       # a temporary output takes the input's format
    c = read_points(r["OUTPUT_POINTS"])
    both = _write_text(tmp_path / "both.csv", c.x, c.y, c.z, np.column_stack([c.classification,
                                                                               cloud_files["truth"]]),
                       delim=",", header="x,y,z,class,truth")
    ev = processing_run("bareearth:evaluate", {"POINTS": both, "TRUTH_COLUMN": "truth",
                                               "OUTPUT_JSON": str(tmp_path / "e.json"),
                                               "OUTPUT_HTML": str(tmp_path / "e.html")})
    ev2 = processing_run("bareearth:evaluate", {"POINTS": r["OUTPUT_POINTS"], "TRUTH_POINTS": cloud_files["txt"],
                                                "OUTPUT_JSON": str(tmp_path / "e2.json"),
                                                "OUTPUT_HTML": str(tmp_path / "e2.html")})
    assert ev["TOTAL"] == pytest.approx(ev2["TOTAL"]) and ev["KAPPA"] == pytest.approx(ev2["KAPPA"])


def test_morphological_on_las_keeps_attributes(processing_run, cloud_files, tmp_path):
    laspy = pytest.importorskip("laspy")
    src = _las(tmp_path / "city.las", cloud_files["x"], cloud_files["y"], cloud_files["z"], cloud_files["truth"])
    r = processing_run("bareearth:morphological", {"INPUT_POINTS": src, "OUTPUT_DTM": str(tmp_path / "dtm.tif"),
                                                   "OUTPUT_MASK": str(tmp_path / "mask.tif"),
                                                   "OUTPUT_POINTS": "TEMPORARY_OUTPUT"})
    assert r["OUTPUT_POINTS"].endswith(".las")
    a, b = laspy.read(src), laspy.read(r["OUTPUT_POINTS"])
    for dim in ("X", "Y", "Z", "intensity", "gps_time", "point_source_id"):
        np.testing.assert_array_equal(np.asarray(a[dim]), np.asarray(b[dim]), err_msg=dim)
    assert set(np.unique(np.asarray(b.classification))) <= {1, 2, 7}
    ev = processing_run("bareearth:evaluate", {"POINTS": r["OUTPUT_POINTS"], "TRUTH_POINTS": src,
                                               "OUTPUT_JSON": str(tmp_path / "e.json"),
                                               "OUTPUT_HTML": str(tmp_path / "e.html")})
    assert ev["TOTAL"] < 3.0 and ev["KAPPA"] > 90


def test_classifypoints_by_a_dtm(processing_run, cloud_files, tmp_path):
    from bare_earth.core.points import read_points
    f = processing_run("bareearth:morphological", {"INPUT_POINTS": cloud_files["txt"],
                                                   "OUTPUT_DTM": str(tmp_path / "dtm.tif"),
                                                   "OUTPUT_MASK": "TEMPORARY_OUTPUT",
                                                   "OUTPUT_POINTS": str(tmp_path / "m.txt")})
    r = processing_run("bareearth:classifypoints", {"INPUT": cloud_files["txt"], "DTM": f["OUTPUT_DTM"],
                                                    "OUTPUT": str(tmp_path / "c.csv")})
    n = cloud_files["x"].size
    assert r["GROUND"] + r["ABOVE"] + r["BELOW"] + r["OUTSIDE"] == n and r["OUTSIDE"] == 0
    c = read_points(r["OUTPUT"])
    np.testing.assert_array_equal(c.classification, read_points(tmp_path / "m.txt").classification)
    assert r["GROUND"] == int((c.classification == 0).sum())
    # a larger tolerance: more ground
    r2 = processing_run("bareearth:classifypoints", {"INPUT": cloud_files["txt"], "DTM": f["OUTPUT_DTM"],
                                                     "THRESHOLD_M": 3.0, "OUTPUT": str(tmp_path / "c2.txt")})
    assert r2["GROUND"] > r["GROUND"]


def test_morphological_tiles_with_neighbours(processing_run, cloud_files, tmp_path):
    from bare_earth.core import pointflow as pf
    from bare_earth.core.points import read_points
    x, y, z, t = cloud_files["x"], cloud_files["y"], cloud_files["z"], cloud_files["truth"]
    west = x < np.median(x)
    a = _write_text(tmp_path / "a.txt", x[west], y[west], z[west], t[west])
    b = _write_text(tmp_path / "b.txt", x[~west], y[~west], z[~west], t[~west])
    r = processing_run("bareearth:morphological", {"INPUT_POINTS": b, "OTHER_TILES": [a, b],
                                                   "OUTPUT_DTM": "TEMPORARY_OUTPUT", "OUTPUT_MASK": "TEMPORARY_OUTPUT",
                                                   "OUTPUT_POINTS": str(tmp_path / "b_cls.txt")})
    ref = pf.filter_tiles([a, b])
    np.testing.assert_array_equal(read_points(r["OUTPUT_POINTS"]).classification, ref.classes[1])


def test_other_tiles_given_twice_refused_and_the_input_under_another_name_left_out(processing_run, cloud_files,
                                                                                   tmp_path):
    """QA15: a neighbouring tile given twice in OTHER_TILES (a, a; or a and ./a or a link to it) was read twice
    without a word (its points counted twice in the block's cell size); refused before any work, naming it.
    The input among its neighbours is left out under any name of it (a link was read as a second tile)."""
    from qgis.core import QgsApplication, QgsProcessingContext

    from bare_earth.core.points import read_points
    x, y, z, t = cloud_files["x"], cloud_files["y"], cloud_files["z"], cloud_files["truth"]
    west = x < np.median(x)
    a = _write_text(tmp_path / "a.txt", x[west], y[west], z[west], t[west])
    b = _write_text(tmp_path / "b.txt", x[~west], y[~west], z[~west], t[~west])
    (tmp_path / "a_link.txt").symlink_to(a)
    (tmp_path / "b_link.txt").symlink_to(b)
    alg = QgsApplication.processingRegistry().algorithmById("bareearth:morphological")
    outs = {"OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif"),
            "OUTPUT_POINTS": str(tmp_path / "o.txt")}
    for tiles, named in (([a, a], r"'.*a\.txt' is given twice: give"),
                         ([a, str(tmp_path / "a_link.txt")], r"'.*a_link\.txt' is given twice \(also as '.*a\.txt', "
                                                             r"the same file\): give each neighbouring tile once")):
        ok, msg = alg.checkParameterValues({"INPUT_POINTS": b, "OTHER_TILES": tiles, **outs}, QgsProcessingContext())
        assert not ok and re.search(r"\(OTHER_TILES\): the point file " + named, msg), msg
    r = processing_run("bareearth:morphological", {"INPUT_POINTS": b, "OTHER_TILES": [a, str(tmp_path / "b_link.txt")],
                                                   **outs})
    ref = processing_run("bareearth:morphological", {"INPUT_POINTS": b, "OTHER_TILES": [a],
                                                     **outs, "OUTPUT_POINTS": str(tmp_path / "ref.txt")})
    np.testing.assert_array_equal(read_points(r["OUTPUT_POINTS"]).classification,
                                  read_points(ref["OUTPUT_POINTS"]).classification)


def test_raster_input_still_works(processing_run, scene_files):
    d = scene_files["dir"]
    r = processing_run("bareearth:morphological", {"INPUT": scene_files["dsm"], "OUTPUT_DTM": str(d / "m_dtm.tif"),
                                                   "OUTPUT_MASK": str(d / "m_mask.tif")})
    assert Path(r["OUTPUT_DTM"]).exists() and "OUTPUT_POINTS" not in r


def test_raster_input_with_point_parameters_says_they_are_not_used(processing_run, scene_files, cloud_files,
                                                                     warning_log):
    """QA14: a DSM raster INPUT with OUTPUT_POINTS, OTHER_TILES or CELL_SIZE_M given (a point file asked for)
    ran without a word, and no point file was written; the dialog's own values (a temporary point output,
    the rule's defaults) say nothing."""
    d = scene_files["dir"]
    log = warning_log()
    r = processing_run("bareearth:geodesic", {
        "INPUT": scene_files["dsm"], "OUTPUT_DTM": str(d / "g_dtm.tif"), "OUTPUT_MASK": str(d / "g_mask.tif"),
        "OUTPUT_POINTS": str(d / "g_points.txt"), "CELL_SIZE_M": 0.5, "THRESHOLD_M": "0.5"}, feedback=log)
    assert "OUTPUT_POINTS" not in r and not (d / "g_points.txt").exists()
    said = [w for w in log.warnings if w.startswith("INPUT is a DSM raster")]
    assert said == ["INPUT is a DSM raster, so what was given for INPUT_POINTS is not used: 'Cell size (m)' "
                    "(CELL_SIZE_M), 'Classified points' (OUTPUT_POINTS). No point file is written."], log.warnings
    log = warning_log()
    processing_run("bareearth:morphological", {
        "INPUT": scene_files["dsm"], "OUTPUT_DTM": str(d / "m2_dtm.tif"), "OUTPUT_MASK": str(d / "m2_mask.tif"),
        "OUTPUT_POINTS": "TEMPORARY_OUTPUT", "THRESHOLD_M": 0.5, "SLOPE_FACTOR": 0.2,
        "OTHER_TILES": [cloud_files["txt"]]}, feedback=log)
    said = [w for w in log.warnings if w.startswith("INPUT is a DSM raster")]
    assert len(said) == 1 and said[0].endswith("not used: 'Neighbouring tiles of the points' (OTHER_TILES), "
                                               "'Slope factor (m per unit slope)' (SLOPE_FACTOR)."), log.warnings


# --------------------------------------------------------------------------- bad inputs
def _bad_files(d):
    (d / "empty.txt").write_text("")
    (d / "blank.txt").write_text("\n  \n")
    (d / "garbage.txt").write_text("1 2 3 0\n4 5 6 1\n7 8 x 0\n")
    (d / "ragged.txt").write_text("1 2 3\n4 5 6\n7 8\n")
    (d / "fake.las").write_bytes(b"LASF" + b"\0" * 300)
    return d


BAD_POINTS = [
    ("empty.txt", "is empty"),
    ("blank.txt", "is empty"),
    ("garbage.txt", "line 3"),
    ("ragged.txt", "line 3"),
    ("missing.txt", "does not exist"),
]


@pytest.mark.parametrize("alg", ["rasterizepoints", "classifypoints", "morphological"])
@pytest.mark.parametrize("name,message", BAD_POINTS, ids=[b[0] for b in BAD_POINTS])
def test_bad_point_files_refused_before_work(processing_run, tmp_path, scene_files, alg, name, message):
    from qgis.core import QgsProcessingException
    src = str(_bad_files(tmp_path) / name)
    out = tmp_path / "out.tif"
    params = {"rasterizepoints": {"INPUT": src, "OUTPUT": str(out)},
              "classifypoints": {"INPUT": src, "DTM": scene_files["dtm"], "OUTPUT": str(tmp_path / "o.txt")},
              "morphological": {"INPUT_POINTS": src, "OUTPUT_DTM": str(out), "OUTPUT_MASK": str(tmp_path / "m.tif"),
                                "OUTPUT_POINTS": str(tmp_path / "o.txt")}}[alg]
    with pytest.raises(QgsProcessingException, match=message):
        processing_run(f"bareearth:{alg}", params)
    assert not out.exists() and not (tmp_path / "o.txt").exists()


def test_las_without_laspy_says_what_to_install(processing_run, tmp_path, monkeypatch, cloud_files):
    from qgis.core import QgsProcessingException
    src = _bad_files(tmp_path) / "fake.las"
    monkeypatch.setitem(sys.modules, "laspy", None)                   # as if laspy were not installed
    for alg, params in (("rasterizepoints", {"INPUT": str(src), "OUTPUT": str(tmp_path / "o.tif")}),
                        ("morphological", {"INPUT_POINTS": str(src), "OUTPUT_DTM": str(tmp_path / "o.tif"),
                                           "OUTPUT_MASK": "TEMPORARY_OUTPUT"})):
        with pytest.raises(QgsProcessingException, match="pip install laspy lazrs"):
            processing_run(f"bareearth:{alg}", params)
    assert not (tmp_path / "o.tif").exists()


def test_exactly_one_input(processing_run, scene_files, cloud_files, tmp_path):
    from qgis.core import QgsProcessingException
    outs = {"OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif")}
    with pytest.raises(QgsProcessingException, match="exactly one input.*neither"):
        processing_run("bareearth:morphological", outs)
    with pytest.raises(QgsProcessingException, match="exactly one input.*not both"):
        processing_run("bareearth:morphological", {"INPUT": scene_files["dsm"],
                                                   "INPUT_POINTS": cloud_files["txt"], **outs})


def test_points_far_outside_the_dtm(processing_run, cloud_files, tmp_path):
    from qgis.core import QgsProcessingException

    from bare_earth.core.grid import write_array
    dtm = write_array(tmp_path / "far.tif", np.zeros((50, 50), np.float32),
                      (100000.0, 1.0, 0.0, 200000.0, 0.0, -1.0), 32632)
    with pytest.raises(QgsProcessingException, match="points are outside the DTM.*DTM spans x 100000"):
        processing_run("bareearth:classifypoints", {"INPUT": cloud_files["txt"], "DTM": dtm,
                                                    "OUTPUT": str(tmp_path / "o.txt")})
    assert not (tmp_path / "o.txt").exists()


def test_other_bad_parameters(processing_run, cloud_files, scene_files, tmp_path):
    from qgis.core import QgsProcessingException

    from bare_earth.core.grid import write_array
    from bare_earth.core.points import rasterize_points
    g, gt = rasterize_points(cloud_files["x"], cloud_files["y"], cloud_files["z"], 2.0)
    dtm = write_array(tmp_path / "dtm.tif", g, gt, 32632)
    with pytest.raises(QgsProcessingException, match="LAS/LAZ file or a text file"):
        processing_run("bareearth:classifypoints", {"INPUT": cloud_files["txt"], "DTM": dtm,
                                                    "OUTPUT": str(tmp_path / "o.shp")})
    with pytest.raises(QgsProcessingException, match="3 x 3 cells"):
        processing_run("bareearth:morphological", {"INPUT_POINTS": cloud_files["txt"], "CELL_SIZE_M": 500.0,
                                                   "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                                   "OUTPUT_MASK": "TEMPORARY_OUTPUT"})
    with pytest.raises(QgsProcessingException, match="larger than the points' extent"):
        processing_run("bareearth:morphological", {"INPUT_POINTS": cloud_files["txt"],
                                                   "MAX_OBJECT_SIZE_M": 5000.0, "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                                   "OUTPUT_MASK": "TEMPORARY_OUTPUT"})
    with pytest.raises(QgsProcessingException, match="about .* cells"):
        processing_run("bareearth:rasterizepoints", {"INPUT": cloud_files["txt"], "CELL_SIZE_M": 0.001,
                                                     "OUTPUT": "TEMPORARY_OUTPUT"})
    # evaluate: classified points need their truth or a DTM; truth must be the same points
    with pytest.raises(QgsProcessingException, match=r"\(TRUTH_POINTS\) or .*\(TRUTH_COLUMN\)"):
        processing_run("bareearth:evaluate", {"POINTS": cloud_files["txt"], "OUTPUT_JSON": str(tmp_path / "e.json"),
                                              "OUTPUT_HTML": str(tmp_path / "e.html")})
    other = _write_text(tmp_path / "other.txt", cloud_files["x"] + 1000, cloud_files["y"], cloud_files["z"],
                        cloud_files["truth"])
    with pytest.raises(QgsProcessingException, match="not the same points"):
        processing_run("bareearth:evaluate", {"POINTS": cloud_files["txt"], "TRUTH_POINTS": other,
                                              "OUTPUT_JSON": str(tmp_path / "e.json"),
                                              "OUTPUT_HTML": str(tmp_path / "e.html")})
    with pytest.raises(QgsProcessingException, match="give POINTS too"):
        processing_run("bareearth:evaluate", {"TRUTH_POINTS": other, "OUTPUT_JSON": str(tmp_path / "e.json"),
                                              "OUTPUT_HTML": str(tmp_path / "e.html")})


# --------------------------------------------------------------------------- qgis_process and the model
def test_qgis_process_points_and_evaluate(run_qgis_process, cloud_files, tmp_path):
    rc, out, data = run_qgis_process("bareearth:morphological", {
        "INPUT_POINTS": cloud_files["txt"], "OUTPUT_DTM": tmp_path / "dtm.tif", "OUTPUT_MASK": tmp_path / "mask.tif",
        "OUTPUT_POINTS": tmp_path / "cls.txt"})
    assert rc == 0, out
    assert data["results"]["OUTPUT_POINTS"].endswith("cls.txt") and (tmp_path / "cls.txt").exists()
    rc, out, data = run_qgis_process("bareearth:evaluate", {
        "POINTS": tmp_path / "cls.txt", "TRUTH_POINTS": cloud_files["txt"],
        "OUTPUT_JSON": tmp_path / "e.json", "OUTPUT_HTML": tmp_path / "e.html"})
    assert rc == 0, out
    assert data["results"]["TOTAL"] < 3.0
    rc, out, _ = run_qgis_process("bareearth:rasterizepoints", {"INPUT": tmp_path / "nothing.txt",
                                                                "OUTPUT": tmp_path / "x.tif"}, as_json=False)
    assert rc != 0 and "does not exist" in out


def test_qgis_process_las(run_qgis_process, cloud_files, tmp_path):
    """qgis_process runs QGIS's own Python: LAS works where laspy is installed for it, and
    otherwise the error says what to install."""
    pytest.importorskip("laspy")
    src = _las(tmp_path / "c.las", cloud_files["x"], cloud_files["y"], cloud_files["z"], cloud_files["truth"])
    rc, out, _ = run_qgis_process("bareearth:rasterizepoints", {"INPUT": src, "OUTPUT": tmp_path / "d.tif"},
                                  as_json=False)
    if rc != 0:
        assert "pip install laspy lazrs" in out, out
        assert not (tmp_path / "d.tif").exists()
    else:
        assert (tmp_path / "d.tif").exists()


def test_model_file_is_a_valid_model(qgis_app):
    from qgis.core import QgsProcessingModelAlgorithm
    m = QgsProcessingModelAlgorithm()
    assert m.fromFile(str(MODEL))
    assert [c.algorithmId() for c in sorted(m.childAlgorithms().values(), key=lambda c: c.position().y())] == \
        ["bareearth:rasterizepoints", "bareearth:morphological", "bareearth:classifypoints"]
    ok, errors = m.validate()
    assert ok, errors


def test_model_through_qgis_process(run_qgis_process, cloud_files, tmp_path):
    from bare_earth.core import pointflow as pf
    from bare_earth.core.points import read_points
    rc, out, data = run_qgis_process(str(MODEL), {
        "points": cloud_files["txt"], "classify:classified": tmp_path / "cls.txt",
        "filter:dtm": tmp_path / "dtm.tif", "filter:mask": tmp_path / "mask.tif"})
    assert rc == 0, out
    assert "Points per class" in out
    c = read_points(tmp_path / "cls.txt")
    # rasterize -> morphological -> classify in the model = the core flow
    ref = pf.filter_cloud(read_points(cloud_files["txt"]))
    np.testing.assert_array_equal(c.classification, ref.classes)
    rc, out, data = run_qgis_process("bareearth:evaluate", {
        "POINTS": tmp_path / "cls.txt", "TRUTH_POINTS": cloud_files["txt"],
        "OUTPUT_JSON": tmp_path / "e.json", "OUTPUT_HTML": tmp_path / "e.html"})
    assert rc == 0, out
    assert data["results"]["KAPPA"] > 90


def test_isprs_sample_on_points_and_evaluate(processing_run, shared_data, tmp_path):
    """The issue's criterion: morphological with INPUT_POINTS on an ISPRS sample gives per-point
    classes whose errors evaluate reports."""
    sample = shared_data / "isprs" / "samp11.txt"
    if not sample.exists():
        pytest.skip(f"{sample} is absent")
    r = processing_run("bareearth:morphological", {"INPUT_POINTS": str(sample), "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                                   "OUTPUT_MASK": "TEMPORARY_OUTPUT",
                                                   "OUTPUT_POINTS": str(tmp_path / "samp11_cls.txt")})
    ev = processing_run("bareearth:evaluate", {"POINTS": r["OUTPUT_POINTS"], "TRUTH_POINTS": str(sample),
                                               "OUTPUT_JSON": str(tmp_path / "e.json"),
                                               "OUTPUT_HTML": str(tmp_path / "e.html")})
    figs = json.loads((tmp_path / "e.json").read_text())["results"]["classified points vs truth"]
    assert figs["n"] == 38010 and figs["points_unmatched"] == 0
    baseline = 100.0 * 16224 / 38010                                 # every point ground
    assert ev["TOTAL"] < baseline / 2 and ev["KAPPA"] > 50


def test_real_las_in_feet_on_points(processing_run, shared_data, tmp_path):
    pytest.importorskip("laspy")
    src = shared_data / "lidar" / "4_6_crop.las"
    if not src.exists():
        pytest.skip(f"{src} is absent")
    r = processing_run("bareearth:morphological", {"INPUT_POINTS": str(src), "OUTPUT_DTM": str(tmp_path / "dtm.tif"),
                                                   "OUTPUT_MASK": "TEMPORARY_OUTPUT",
                                                   "OUTPUT_POINTS": str(tmp_path / "cls.las")})
    _, _, gt, crs = _read_raster(r["OUTPUT_DTM"])
    assert gt[1] == pytest.approx(0.5 / 0.30480060960121924) and "ftUS" in crs   # 0.5 m cells in US feet
    ev = processing_run("bareearth:evaluate", {"POINTS": r["OUTPUT_POINTS"], "TRUTH_POINTS": str(src),
                                               "OUTPUT_JSON": str(tmp_path / "e.json"),
                                               "OUTPUT_HTML": str(tmp_path / "e.html")})
    assert ev["TOTAL"] < 10.0


def test_model_with_another_filter(processing_run, cloud_files, tmp_path):
    """Any filter can be the middle step: the example's builder with slopeprofile, run by processing.run."""
    from bare_earth.algorithms.example_model import build
    model = build("slopeprofile")
    ok, errors = model.validate()
    assert ok, errors
    path = tmp_path / "slope.model3"
    assert model.toFile(str(path))
    from qgis.core import QgsProcessingModelAlgorithm
    m = QgsProcessingModelAlgorithm()
    assert m.fromFile(str(path))
    r = processing_run(m, {"points": cloud_files["txt"], "classify:classified": str(tmp_path / "cls.txt"),
                           "filter:dtm": str(tmp_path / "dtm.tif"), "filter:mask": str(tmp_path / "mask.tif")})
    from bare_earth.core.points import read_points
    c = read_points(r["classify:classified"])
    assert len(c) == cloud_files["x"].size and set(np.unique(c.classification)) <= {0, 1, 2, 255}
    assert (c.classification == 0).mean() > 0.3


# --------------------------------------------------------------------------- degenerate point inputs
def _bad_point_file(kind, d):
    rng = np.random.default_rng(3)
    x, y = rng.uniform(0, 60, 2000) + 500000.0, rng.uniform(0, 60, 2000) + 5400000.0
    z = 100.0 + 0.05 * (x - 500000.0)
    if kind == "raster":
        from bare_earth.core import grid
        p = d / "dsm.tif"
        grid.write_array(p, np.ones((20, 20), np.float32), (0.0, 1.0, 0.0, 20.0, 0.0, -1.0), 32632)
        return str(p)
    if kind == "z_all_nan":
        return _write_text(d / "nan.txt", x, y, np.full_like(z, np.nan))
    if kind == "diagonal_line":
        return _write_text(d / "line.txt", x, x - 500000.0 + 5400000.0, z)
    if kind == "one_stray_point":                       # e.g. a bad GPS record at (0, 0)
        return _write_text(d / "stray.txt", np.append(x, 0.0), np.append(y, 0.0), np.append(z, 0.0))
    if kind == "decimal_commas":
        p = d / "eu.txt"
        p.write_text("".join(f"{a:.3f};{b:.3f};{c:.3f}\n".replace(".", ",") for a, b, c in zip(x, y, z)))
        return str(p)
    raise AssertionError(kind)


@pytest.mark.parametrize("kind,message", [
    ("raster", r"not a text point file \(it holds binary data\): a raster DSM goes to INPUT"),
    ("z_all_nan", r"no point of .* has a finite height"),
    ("diagonal_line", r"the points lie along a line, .* m wide across it.*less than the 3 cells"),
    ("decimal_commas", r"6 values per line.*decimal commas and separated by ';'"),
    ("one_stray_point", r"\(INPUT_POINTS\): 1 of the 2001 points lie far from the others: 99 % of them span 59.* x "
                        r"59.* units, but the whole extent is 5.001e\+05 x 5.4e\+06 units \(the farthest stray point "
                        r"is at x 0, y 0\).*Remove those stray points"),
])
def test_degenerate_point_files_refused_before_work(qgis_app, processing_run, tmp_path, kind, message):
    """Before: a raster given as INPUT_POINTS was "a header line but no points", z NaN on every line
    failed inside the run, points along a diagonal line (a square bounding box) were filtered into a
    grid filled from one line, decimal commas with ';' were only "6 values per line", and one stray point
    5000 km away made the default cell 50 km (every other point in one cell) and ran."""
    from qgis.core import QgsApplication, QgsProcessingContext, QgsProcessingException
    params = {"INPUT_POINTS": _bad_point_file(kind, tmp_path), "OUTPUT_DTM": str(tmp_path / "dtm.tif"),
              "OUTPUT_MASK": str(tmp_path / "mask.tif"), "OUTPUT_POINTS": str(tmp_path / "out.txt")}
    alg = QgsApplication.processingRegistry().algorithmById("bareearth:morphological")
    ok, msg = alg.checkParameterValues(params, QgsProcessingContext())
    assert not ok
    with pytest.raises(QgsProcessingException, match=message):
        processing_run("bareearth:morphological", params)
    assert not any((tmp_path / f).exists() for f in ("dtm.tif", "mask.tif", "out.txt"))


@pytest.mark.parametrize("alg,key", [("bareearth:rasterizepoints", "INPUT"),
                                     ("bareearth:morphological", "INPUT_POINTS")])
def test_a_stray_point_near_enough_to_keep_a_grid_refused_before_work(qgis_app, processing_run, tmp_path, alg, key):
    """One point 2 km from a 200 m tile of 40000 points: the default cell became 2.5 m instead of 1 m,
    on a grid of 800 x 800 cells 99 % empty (copies of their nearest point's height), and both
    rasterizepoints and the filters on points ran without a word (only a stray point that left the
    bulk under 3 x 3 cells was refused, by the filters, not by rasterizepoints)."""
    from qgis.core import QgsApplication, QgsProcessingContext, QgsProcessingException
    rng = np.random.default_rng(1)
    x, y = rng.uniform(0, 200, 40000) + 500000.0, rng.uniform(0, 200, 40000) + 5400000.0
    pts = _write_text(tmp_path / "stray.txt", np.append(x, 502000.0), np.append(y, 5402000.0),
                      np.append(100.0 + 0.05 * (x - 500000.0), 100.0))
    outs = ({"OUTPUT": str(tmp_path / "dsm.tif")} if key == "INPUT" else
            {"OUTPUT_DTM": str(tmp_path / "dsm.tif"), "OUTPUT_MASK": str(tmp_path / "mask.tif")})
    params = dict(outs, **{key: pts, "CRS" if key == "INPUT" else "POINTS_CRS": "EPSG:32632"})
    ok, msg = QgsApplication.processingRegistry().algorithmById(alg).checkParameterValues(
        params, QgsProcessingContext())
    assert not ok and re.search(rf"\b{key}\)?: 1 of the 40001 points lie far from the others", msg)
    with pytest.raises(QgsProcessingException, match=r"the farthest stray point is at x 502000, y 5402000\)"):
        processing_run(alg, params)
    assert not (tmp_path / "dsm.tif").exists()


def test_rasterize_points_too_small_a_grid_refused_in_the_check(qgis_app, tmp_path):
    """All points at one place (or a cell larger than the points' extent) give fewer than 3 x 3 cells:
    refused by the check before work (before: only inside the run)."""
    from qgis.core import QgsApplication, QgsProcessingContext
    n = 50
    same = _write_text(tmp_path / "same.txt", np.full(n, 500000.0), np.full(n, 5400000.0), np.arange(n) * 0.1)
    alg = QgsApplication.processingRegistry().algorithmById("bareearth:rasterizepoints")
    ok, msg = alg.checkParameterValues({"INPUT": same, "OUTPUT": str(tmp_path / "d.tif")}, QgsProcessingContext())
    assert not ok and "span only 0 x 0 m" in msg and "3 x 3 cells" in msg
    x = np.linspace(0, 60, 400) + 500000.0
    area = _write_text(tmp_path / "area.txt", x, x[::-1] - 500000.0 + 5400000.0, np.ones(400))
    ok, msg = alg.checkParameterValues({"INPUT": area, "CELL_SIZE_M": 1000.0, "OUTPUT": str(tmp_path / "d.tif")},
                                       QgsProcessingContext())
    assert not ok and "cells of 1000 m" in msg


@pytest.mark.parametrize("kind,message", [
    ("other_crs", r"\(OTHER_TILES\): b.las is not in the CRS / units of the input points"),
    ("raster", r"\(OTHER_TILES\): .*dsm.tif' is not a text point file"),
])
def test_other_tiles_of_another_crs_or_not_points_refused_in_the_check(qgis_app, tmp_path, kind, message):
    """A neighbouring tile in another CRS, or a raster given as a tile, is refused by the check from
    the LAS header / first bytes (before: only once the run had read every tile)."""
    from qgis.core import QgsApplication, QgsProcessingContext
    x, y, z, t = _scene_points(shape=(60, 60))
    a = _las(tmp_path / "a.las", x, y, z, t)
    other = (_las(tmp_path / "b.las", x + 60.0, y, z, t, epsg=25832) if kind == "other_crs"
             else _bad_point_file("raster", tmp_path))
    alg = QgsApplication.processingRegistry().algorithmById("bareearth:morphological")
    ok, msg = alg.checkParameterValues({"INPUT_POINTS": a, "OTHER_TILES": [other],
                                        "OUTPUT_DTM": str(tmp_path / "d.tif"), "OUTPUT_MASK": str(tmp_path / "m.tif"),
                                        "OUTPUT_POINTS": str(tmp_path / "o.las")}, QgsProcessingContext())
    assert not ok
    assert re.search(message, msg), msg


@pytest.mark.parametrize("fails", ["write_rasters", "prepare_points", "place_points"])
def test_points_and_rasters_all_or_nothing(processing_run, cloud_files, tmp_path, monkeypatch, fails):
    """Before: a filter with INPUT_POINTS wrote its rasters, then the points; a points write that
    failed left the rasters, which looked like a finished run. Now a failure of either leaves none
    (the points written first to a work file, the rasters, then the points moved into place: a
    failure of that last move removes the rasters just placed)."""
    from qgis.core import QgsProcessingException

    from bare_earth.core import pointflow

    def broken(*args, **kwargs):
        raise ValueError("disk full (simulated)")

    monkeypatch.setattr(pointflow, fails, broken)
    outs = {"OUTPUT_DTM": tmp_path / "dtm.tif", "OUTPUT_MASK": tmp_path / "mask.tif",
            "OUTPUT_POINTS": tmp_path / "classified.txt"}
    with pytest.raises(QgsProcessingException, match="disk full"):
        processing_run("bareearth:morphological", {"INPUT_POINTS": cloud_files["txt"],
                                                   **{k: str(v) for k, v in outs.items()}})
    assert [p.name for p in outs.values() if p.exists()] == []
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize("percent", [1, 50])
@pytest.mark.parametrize("alg", ["rasterizepoints", "classifypoints"])
def test_point_tools_cancelled_write_nothing(processing_run, cloud_files, scene_files, tmp_path, alg, percent):
    """A cancel asked while rasterizepoints or classifypoints ran was ignored: the run went on and
    wrote its whole output. It stops at the end of the stage and writes nothing."""
    from qgis.core import QgsProcessingFeedback

    class CancelAt(QgsProcessingFeedback):
        def setProgress(self, p):  # noqa: N802
            super().setProgress(p)
            if p >= percent:
                self.cancel()
    out = tmp_path / ("o.tif" if alg == "rasterizepoints" else "o.txt")
    params = {"INPUT": cloud_files["txt"], "OUTPUT": str(out)}
    if alg == "classifypoints":
        params["DTM"] = processing_run("bareearth:rasterizepoints", {"INPUT": cloud_files["txt"],
                                                                     "OUTPUT": str(tmp_path / "dsm.tif")})["OUTPUT"]
    res = processing_run(f"bareearth:{alg}", params, feedback=CancelAt())
    assert not res or not res.get("OUTPUT")
    assert not out.exists()


@pytest.mark.parametrize("crs, said", [
    ("", "The points have no CRS"),
    ("EPSG:32632", None),
    ("EPSG:3857", "does not keep distances here"),
])
@pytest.mark.parametrize("alg", ["bareearth:rasterizepoints", "bareearth:morphological"])
def test_points_without_a_crs_or_in_one_without_distances_warned(processing_run, warning_log, tmp_path, crs, said, alg):
    """Points without a CRS were taken as metres and gave outputs without a CRS, and points in Web
    Mercator (USGS 3DEP's tiles) were converted to ground metres, with an info line only (a raster
    in either case gets a warning); both now warn, as a raster's run does. A UTM cloud: no warning."""
    x, y, z, _ = _scene_points(shape=(60, 70))
    if crs == "EPSG:3857":   # the same cloud placed at 52 deg N in Web Mercator (scale 1.62)
        x, y = x - 500000.0, y - 5400000.0 + 6800000.0
    src = _write_text(tmp_path / "pts.txt", x, y, z)
    log = warning_log()
    if alg == "bareearth:rasterizepoints":
        params = {"INPUT": src, "CRS": crs, "OUTPUT": str(tmp_path / "dsm.tif")}
    else:
        params = {"INPUT_POINTS": src, "POINTS_CRS": crs, "OUTPUT_POINTS": str(tmp_path / "out.txt"),
                  "OUTPUT_DTM": str(tmp_path / "dtm.tif"), "OUTPUT_MASK": str(tmp_path / "mask.tif")}
    processing_run(alg, {k: v for k, v in params.items() if v != ""}, feedback=log)
    hits = [w for w in log.warnings if "CRS" in w]
    if said is None:
        assert not hits, log.warnings
    else:
        assert len(hits) == 1 and said in hits[0], log.warnings


@pytest.mark.parametrize("alg,keys", [
    ("bareearth:rasterizepoints", {"INPUT": None, "OUTPUT": "TEMPORARY_OUTPUT"}),
    ("bareearth:morphological", {"INPUT_POINTS": None, "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                 "OUTPUT_MASK": "TEMPORARY_OUTPUT"}),
])
def test_three_points_over_a_kilometre_at_5_cm_are_refused_before_work(processing_run, tmp_path, alg, keys):
    """3 points over 1 km at CELL_SIZE_M 0.05: 20000 x 20000 = 400 M cells of copies of 3 heights
    (6 GB to rasterize), made without a word; refused now, naming the cells and the cell to use."""
    from qgis.core import QgsProcessingException
    pts = _write_text(tmp_path / "three.txt", np.array([500000.0, 501000.0, 500300.0]),
                      np.array([5400000.0, 5401000.0, 5400700.0]), np.array([100.0, 101.0, 102.0]))
    (tmp_path / "three.prj").write_text("EPSG:32632")
    params = {k: (pts if v is None else v) for k, v in keys.items()}
    refused = r"CELL_SIZE_M\) = 0.05 m gives 20000 x 20000 = 4e\+08 cells over the points' 1000 x 1000 m for 3 point"
    with pytest.raises(QgsProcessingException, match=refused + r"\(s\).* at least 200 m"):
        processing_run(alg, dict(params, CELL_SIZE_M=0.05))


def test_points_without_a_finite_height_are_named_in_the_log(processing_run, warning_log, cloud_files, tmp_path):
    """Points whose z is NaN or infinite (a failed export, 'nan' in a text file) were left out of the grid
    and classed 255 without a word: 1 point in 50 of a tile vanished from the ground silently. The log
    now says how many, and what they became; the other points are classified as before."""
    z = cloud_files["z"].copy()
    z[::50] = np.inf
    z[1::97] = np.nan
    bad = int((~np.isfinite(z)).sum())
    src = _write_text(tmp_path / "holes.txt", cloud_files["x"], cloud_files["y"], z)
    (tmp_path / "holes.prj").write_text("EPSG:32632")
    log = warning_log()
    out = tmp_path / "cls.txt"
    processing_run("bareearth:morphological", {"INPUT_POINTS": src, "OUTPUT_POINTS": str(out),
                                               "OUTPUT_DTM": "TEMPORARY_OUTPUT", "OUTPUT_MASK": "TEMPORARY_OUTPUT"},
                   feedback=log)
    said = [w for w in log.warnings if "have no finite height" in w]
    assert said == [f"{bad} of the {z.size} points have no finite height (z NaN or infinite): they are left out of "
                    "the grid and classed 255, outside the DTM (a LAS output keeps their input class). Check the z "
                    "column of those points."], log.warnings
    classes = np.loadtxt(out, usecols=3)
    assert (classes[~np.isfinite(z)] == 255).all() and (classes[np.isfinite(z)] != 255).all()
    log = warning_log()
    processing_run("bareearth:rasterizepoints", {"INPUT": src, "OUTPUT": str(tmp_path / "dsm.tif")}, feedback=log)
    assert [w for w in log.warnings if "have no finite height" in w] == [
        f"{bad} of the {z.size} points have no finite height (z NaN or infinite): they are left out of the grid. "
        "Check the z column of those points."], log.warnings
