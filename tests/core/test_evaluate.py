"""Tests of core/evaluate.py (figures, reports) and the ISPRS benchmark harness."""
import base64
import importlib.util
import json
import math
import os
import re
import uuid
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from bare_earth.core.evaluate import (
    ERROR_LEGEND,
    compare_dtm,
    compare_masks,
    confusion,
    error_map_from_masks,
    write_report,
)

ROOT = Path(__file__).resolve().parents[2]


def _table(a, b, c, d):
    """Prediction / truth arrays realising the cross matrix a, b, c, d."""
    truth = np.array([True] * (a + b) + [False] * (c + d))
    pred = np.array([True] * a + [False] * b + [True] * c + [False] * d)
    return pred, truth


def test_confusion_hand_computed():
    # a=3 b=1 c=2 d=4, n=10: Type I 1/4, Type II 2/6, total 3/10,
    # p_o = 0.7, p_e = (4*5 + 6*5)/100 = 0.5, kappa = 0.2/0.5 = 40 %
    pred, truth = _table(3, 1, 2, 4)
    r = confusion(pred, truth)
    assert (r["a"], r["b"], r["c"], r["d"], r["n"]) == (3, 1, 2, 4, 10)
    assert r["n_ground"] == 4 and r["n_object"] == 6
    assert r["type1"] == pytest.approx(25.0)
    assert r["type2"] == pytest.approx(100 / 3)
    assert r["total"] == pytest.approx(30.0)
    assert r["kappa"] == pytest.approx(40.0)
    json.dumps(r)   # plain Python numbers


def test_confusion_2d_valid_and_edge_cases():
    pred, truth = _table(3, 1, 2, 4)
    valid = np.ones(10, bool)
    valid[[0, 9]] = False                 # drop one a and one d
    r = confusion(pred.reshape(2, 5), truth.reshape(2, 5), valid=valid.reshape(2, 5))
    assert (r["a"], r["b"], r["c"], r["d"]) == (2, 1, 2, 3)
    # perfect classification: kappa 100; all ground: Type II undefined
    r = confusion(truth, truth)
    assert r["kappa"] == pytest.approx(100.0) and r["total"] == 0.0
    r = confusion(np.ones(4, bool), np.ones(4, bool))
    assert np.isnan(r["type2"]) and r["type1"] == 0.0
    # everything predicted ground: kappa 0
    r = confusion(np.ones(10, bool), truth)
    assert r["kappa"] == pytest.approx(0.0) and r["type2"] == 100.0
    with pytest.raises(ValueError, match="shape"):
        confusion(pred, truth[:5])


def test_compare_masks_codes_and_nodata():
    mask = np.array([[0, 0, 1, 2], [0, 255, 1, 0]], np.uint8)
    truth = np.array([[0, 1, 1, 1], [255, 0, 0, 0]], np.uint8)
    r = compare_masks(mask, truth)
    # valid: (0,0) g->g a, (0,1) truth obj pred g c, (0,2) d, (0,3) pred low=obj d,
    # (1,2) truth g pred obj b, (1,3) a
    assert (r["a"], r["b"], r["c"], r["d"], r["n"]) == (2, 1, 1, 2, 6)
    codes, legend = error_map_from_masks(mask, truth)
    np.testing.assert_array_equal(codes, [[0, 2, 0, 0], [255, 255, 1, 0]])
    assert codes.dtype == np.uint8 and legend == ERROR_LEGEND
    assert set(legend) == {0, 1, 2, 255}
    with pytest.raises(ValueError, match="shape"):
        compare_masks(mask, truth[:1])


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int16])
def test_compare_dtm(dtype):
    ref = np.zeros((2, 3), dtype)
    dtm = np.array([[1, -1, 2], [0, 3, 0]], dtype)
    r = compare_dtm(dtm, ref)
    assert r["n"] == 6 and r["mean"] == pytest.approx(5 / 6)
    assert r["rmse"] == pytest.approx(np.sqrt(15 / 6)) and r["max_abs"] == 3
    ground = np.array([[True, True, False], [True, False, False]])
    r = compare_dtm(dtm, ref, ground=ground)
    assert r["ground_n"] == 3 and r["ground_mean"] == 0 and r["ground_max_abs"] == 1
    assert r["ground_rmse"] == pytest.approx(np.sqrt(2 / 3))
    # a mask with codes: ground = 0
    r2 = compare_dtm(dtm, ref, ground=np.where(ground, 0, 1).astype(np.uint8))
    assert r2["ground_n"] == 3
    if np.issubdtype(dtype, np.floating):
        dtm = dtm.copy()
        dtm[1, 1] = np.nan
        r = compare_dtm(dtm, ref)
        assert r["n"] == 5 and r["max_abs"] == 2


def _png_from_html(text):
    m = re.search(r'<img[^>]*src="data:image/png;base64,([A-Za-z0-9+/=]+)"', text)
    assert m, "no embedded PNG"
    return base64.b64decode(m.group(1))


def _read_png(data):
    from osgeo import gdal
    name = f"/vsimem/test_{uuid.uuid4().hex}.png"
    gdal.FileFromMemBuffer(name, data)
    try:
        ds = gdal.Open(name)
        arr = np.stack([ds.GetRasterBand(i + 1).ReadAsArray() for i in range(ds.RasterCount)])
        ds = None
    finally:
        gdal.Unlink(name)
    return arr


def test_write_report_json_and_html(tmp_path):
    mask = np.array([[0, 0, 1], [1, 0, 255]], np.uint8)
    truth = np.array([[0, 1, 0], [1, 0, 0]], np.uint8)
    res = compare_masks(mask, truth)
    codes, _ = error_map_from_masks(mask, truth)
    results = {"samp11": res, "samp21": dict(res, kappa=float("nan"))}
    out = write_report(results, json_path=tmp_path / "r.json", html_path=tmp_path / "r.html",
                       error_map=codes, geotransform=(10, 1, 0, 20, 0, -1), title="My test")
    assert Path(out["html"]).is_file()
    data = json.loads((tmp_path / "r.json").read_text())
    assert data["title"] == "My test" and data["results"]["samp11"]["b"] == 1
    assert data["results"]["samp21"]["kappa"] is None     # NaN -> null
    text = (tmp_path / "r.html").read_text()
    assert "<table>" in text and "<th>samp11</th>" in text and "<th>kappa</th>" in text
    assert "<title>My test</title>" in text and "origin (10.000, 20.000)" in text
    png = _png_from_html(text)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    rgb = _read_png(png)
    assert rgb.shape == (3, 2, 3)
    for (r, c), code in np.ndenumerate(codes):
        assert tuple(rgb[:, r, c]) == ERROR_LEGEND[code][1]


def test_write_report_flat_and_large_map(tmp_path):
    codes = np.zeros((4100, 10), np.uint8)
    codes[2001, 3] = 2                                     # one Type II cell survives
    write_report(confusion(*_table(3, 1, 2, 4)), html_path=tmp_path / "f.html", error_map=codes)
    text = (tmp_path / "f.html").read_text()
    assert "<th>type1</th><td>25.00</td>" in text
    rgb = _read_png(_png_from_html(text))
    assert max(rgb.shape[1:]) <= 2000
    assert (rgb.transpose(1, 2, 0) == ERROR_LEGEND[2][1]).all(axis=2).sum() == 1
    with pytest.raises(ValueError, match="json_path"):
        write_report({})


# --------------------------------------------------------------------------- benchmark harness
def _load_benchmark(name):
    """The script ``benchmarks/<name>.py`` loaded as a module (the benchmarks are no package)."""
    spec = importlib.util.spec_from_file_location(f"{name}_bench", ROOT / "benchmarks" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _synthetic_sample(path, seed):
    """A plane of ground points with a 'building' block of object points (ISPRS format)."""
    rng = np.random.default_rng(seed)
    n = 3000
    x, y = rng.uniform(0, 60, n), rng.uniform(0, 40, n)
    z = 100 + 0.05 * x
    obj = (x > 20) & (x < 35) & (y > 10) & (y < 25)
    z = z + np.where(obj, 8.0, 0.0)
    with open(path, "w") as fh:
        for row in zip(x, y, z, obj.astype(int)):
            fh.write("%.2f\t%.2f\t%.2f\t%d\n" % row)
    return obj


def test_harness_with_inline_methods(tmp_path):
    bench = _load_benchmark("isprs")
    for i in (1, 2):
        _synthetic_sample(tmp_path / f"samp{i}1.txt", i)
    samples = bench.load_samples(tmp_path)
    assert list(samples) == ["samp11", "samp21"]

    def everything_ground(z, cell_size):
        return SimpleNamespace(mask=np.zeros(z.shape, np.uint8), dtm=z, info={})

    def oracle(z, cell_size):                      # knows the flat terrain under the block
        rows, cols = z.shape
        dtm = z.copy()
        high = z > np.nanmin(z) + 5
        from scipy import ndimage
        dtm[high] = np.nan
        idx = ndimage.distance_transform_edt(np.isnan(dtm), return_distances=False,
                                             return_indices=True)
        return SimpleNamespace(mask=high.astype(np.uint8), dtm=dtm[tuple(idx)], info={})

    base = bench.evaluate_method(everything_ground, samples)
    for r in base["samples"].values():
        assert r["type1"] == 0.0 and r["type2"] == 100.0 and r["kappa"] == pytest.approx(0.0)
    good = bench.evaluate_method(oracle, samples)
    assert good["mean"]["total"] < 2.0 and good["mean"]["kappa"] > 95.0
    assert set(good["samples"]) == {"samp11", "samp21"}
    assert good["mean"]["type1"] == pytest.approx(
        np.mean([r["type1"] for r in good["samples"].values()]))
    table = bench.format_table({"oracle": good}, bench.baseline(samples))
    assert "samp11" in table and "mean" in table and "oracle" in table and "all ground" in table


def _five_points():
    """A 2 x 3 grid of 1 m cells (north-up, origin (0, 2)) and five points with predicted and true
    ground: ``(gt, x, y, pred, truth)``."""
    return ((0.0, 1.0, 0.0, 2.0, 0.0, -1.0), np.array([0.2, 0.8, 1.5, 0.5, 0.6]), np.array([1.5, 1.5, 1.5, 0.5, 0.4]),
            np.array([True, True, False, True, True]), np.array([True, False, True, True, True]))


def test_error_map_from_points_and_several_maps(tmp_path):
    from bare_earth.core.evaluate import error_map_from_points
    gt, x, y, pred, truth = _five_points()
    codes, legend = error_map_from_points(pred, truth, x, y, gt, (2, 3))
    # cell (0,0): correct + Type II -> 2; (0,1): Type I; (1,0): correct; rest: no point
    np.testing.assert_array_equal(codes, [[2, 1, 255], [0, 255, 255]])
    codes_v, _ = error_map_from_points(pred, truth, x, y, gt, (2, 3), valid=x > 0.5)
    assert codes_v[0, 0] == 2 and codes_v[1, 0] == 0
    filled, _ = error_map_from_points(pred, truth, x, y, gt, (2, 3), fill_empty="nearest")
    assert filled[0, 2] == 1 and filled[1, 2] == 1 and (filled != 255).all()
    assert (filled[0, 0], filled[0, 1], filled[1, 0]) == (2, 1, 0)
    write_report({"s": {"total": 1.0}}, html_path=tmp_path / "m.html",
                 error_map={"samp A": codes, "samp B": codes_v}, geotransform={"samp A": gt})
    text = (tmp_path / "m.html").read_text()
    assert text.count('src="data:image/png;base64,') == 2
    assert "<h3>samp A</h3>" in text and "<h3>samp B</h3>" in text and "Error maps" in text


def test_harness_log_line(tmp_path):
    bench = _load_benchmark("isprs")
    _synthetic_sample(tmp_path / "samp11.txt", 1)
    res = bench.evaluate_method(
        lambda z, cs: SimpleNamespace(mask=np.zeros(z.shape, np.uint8), dtm=z,
                                      info={"window_m": 3.0, "arr": np.zeros(3)}),
        tmp_path)
    assert res["samples"]["samp11"]["info"] == {"window_m": 3.0}
    log = tmp_path / "log" / "isprs.jsonl"
    bench.append_jsonl(res, log, data_dir=tmp_path)
    bench.append_jsonl(res, log, data_dir=tmp_path)
    lines = [json.loads(x) for x in log.read_text().splitlines()]
    assert len(lines) == 2
    rec = lines[0]
    assert {"date", "commit", "method", "samples", "mean", "protocol"} <= set(rec)
    assert rec["protocol"]["cell_size"] == 1.0 and rec["samples"]["samp11"]["n"] == 3000
    assert bench.main(["--data", str(tmp_path / "absent")]) == 0


def _isprs_record(method, totals, params=None, cell_size=1.0):
    """A log line of ``benchmarks/isprs.py`` whose samples have these total errors: 100 points each,
    ``o`` of them objects (all taken as ground: the error is theirs), the rest ground."""
    samples = {}
    for sname, (tot, o) in totals.items():
        samples[sname] = {"type1": 0.0, "type2": 100.0 * tot / o, "total": float(tot), "kappa": 50.0,
                          "a": 100 - o, "b": 0, "c": tot, "d": o - tot, "n": 100}
    mean = {k: float(np.mean([r[k] for r in samples.values()])) for k in ("type1", "type2", "total", "kappa")}
    return {"date": "2026-12-01T00:00:00+00:00", "commit": "c0ffee", "method": method, "params": params or {},
            "protocol": {"cell_size": cell_size, "reducer": "min", "threshold_m": 0.5, "slope_factor": 1.25},
            "samples": samples, "mean": mean}


def test_isprs_from_log_rewrites_the_readme_table_only(tmp_path, monkeypatch, capsys):
    """``isprs.py --from-log --readme``: per method its newest record by the protocol with defaults
    (an older run, a run with parameters and one at 2 m left out), best mean first, the row of every
    point ground from the cross matrices; README's rows between the markers rewritten, every other
    line (another script's block too) left as it was."""
    bench = _load_benchmark("isprs")
    log = tmp_path / "isprs.jsonl"
    recs = [_isprs_record("dtm", {"samp11": (9, 40), "samp21": (1, 20)}),
            _isprs_record("geodesic", {"samp11": (4, 40), "samp21": (2, 20)}),
            _isprs_record("dtm", {"samp11": (3, 40), "samp21": (1, 20)}),          # dtm's newest
            _isprs_record("geodesic", {"samp11": (0, 40), "samp21": (0, 20)}, params={"dh_m": 1}),
            _isprs_record("geodesic", {"samp11": (1, 40), "samp21": (1, 20)}, cell_size=2.0)]
    log.write_text("".join(json.dumps(r) + "\n" for r in recs) + "\n")
    head = "# Title\n\nTotal error in percent:\n\n"
    tail = ("\nThe single-window form scores 9.75 %.\n\n<!-- generalise:begin -->\n| keep | me |\n"
            "<!-- generalise:end -->\n")
    readme = tmp_path / "README.md"
    readme.write_text(head + "<!-- isprs:begin -->\n| method | old |\n|---|---|\n| dtm | 9.99 |\n"
                      "<!-- isprs:end -->\n" + tail)
    monkeypatch.setattr(bench, "README", readme)
    assert bench.main(["--from-log", "--out", str(log), "--readme"]) == 0
    assert readme.read_text() == head + (
        "<!-- isprs:begin -->\n"
        "| method | samp11 | samp21 | mean | Type I | Type II | kappa |\n"
        "|---|---|---|---|---|---|---|\n"
        "| dtm (recommended: 2 of 3 vote, refined) | 3.00 | 1.00 | **2.00** | 0.00 | 6.25 | 50.00 |\n"
        "| geodesic | 4.00 | 2.00 | **3.00** | 0.00 | 10.00 | 50.00 |\n"
        "| every point ground | 40.00 | 20.00 | 30.00 | 0 | 100 | 0 |\n"
        "<!-- isprs:end -->\n") + tail
    assert "| geodesic | 4.00 | 2.00 | **3.00** |" in capsys.readouterr().out
    before = readme.read_text()                      # the same log again: nothing moves
    assert bench.main(["--from-log", "--out", str(log), "--readme"]) == 0
    assert readme.read_text() == before
    # bad input named before any work: no markers, no record, --readme of an unlogged run
    bare = tmp_path / "bare.md"
    bare.write_text(head)
    with pytest.raises(ValueError, match="isprs:begin"):
        bench.write_readme("| x |\n", bare)
    assert bare.read_text() == head
    with pytest.raises(ValueError, match="no record of rascor"):
        bench.latest_records(log, ["rascor"])
    with pytest.raises(SystemExit):
        bench.main(["--readme", "--no-log", "--data", str(tmp_path)])


def _isprs_rows(gen, folder):
    notes = []
    return {name: build for _, _, rows in gen.isprs_cases(folder, notes) for name, build in rows}


def test_generalise_grid_column_separates_the_grid_from_the_filter(tmp_path):
    """``grid``: the row's DSM with a perfect object mask. On a building over a plane it is
    near the floor while the raw DSM is not; on bare rough ground rasterised by its highest
    point per 2 m cell, removing the cells that stand too high still leaves most of raw's
    error: it is the grid's."""
    gen = _load_benchmark("generalise")
    (tmp_path / "isprs").mkdir()
    _synthetic_sample(tmp_path / "isprs" / "samp11.txt", 3)
    build = _isprs_rows(gen, tmp_path)["isprs/samp11/1m/min"]
    z, cell, score = build()
    raw = score(SimpleNamespace(dtm=z))["total"]
    grid = score.grid(z, cell)["total"]
    assert raw > 5.0 and grid < 1.0 and grid >= score.floor()["total"] - 0.5

    rng = np.random.default_rng(5)
    n = 20000
    x, y = rng.uniform(0, 60, n), rng.uniform(0, 40, n)
    z = 100 + 0.9 * x + 1.5 * np.sin(x) * np.sin(y)  # steep rough ground, no object
    (tmp_path / "isprs" / "samp11.txt").write_text(
        "".join("%.3f\t%.3f\t%.3f\t0\n" % p for p in zip(x, y, z)))
    build = _isprs_rows(gen, tmp_path)["isprs/samp11/2m/max"]
    z, cell, score = build()
    raw = score(SimpleNamespace(dtm=z))["total"]
    assert raw > 5.0                               # the highest point of a cell stands above its ground
    grid, floor = score.grid(z, cell)["total"], score.floor()["total"]
    assert grid <= raw and grid > floor + 5.0      # what is left is the grid's, no filter's


def test_generalise_log_stays_bounded(tmp_path):
    """The log keeps the derived parameters in its newest record only and at most ``keep``
    records, every record's figures complete."""
    gen = _load_benchmark("generalise")
    log = tmp_path / "g.jsonl"
    for k in range(5):
        rec = {"commit": str(k), "summary": {"m": {"mean_all": float(k)}},
               "rows": [{"row": "r", "filters": {"m": {"total": float(k), "params": {"dh": k}}}}]}
        gen.append_record(log, rec, keep=3)
    recs = [json.loads(ln) for ln in log.read_text().splitlines()]
    assert [r["commit"] for r in recs] == ["2", "3", "4"]
    assert [r["rows"][0]["filters"]["m"]["total"] for r in recs] == [2.0, 3.0, 4.0]
    assert [("params" in r["rows"][0]["filters"]["m"]) for r in recs] == [False, False, True]
    assert not list(tmp_path.glob("*.partial"))


def test_anchors_compare_dtm_with_the_best_peer_row_by_row():
    """The peers' table: per tool means and halves, the best peer per row, and dtm's gap to
    it; the lidar rows beyond the issue's 0.5 points are named."""
    anc = _load_benchmark("anchors")
    rows = [{"row": "lidar/a/2m", "half": "A", "tools": {"saga": {"total": 2.0}, "csf": {"total": 3.0}}},
            {"row": "lidar/b/4m", "half": "B", "tools": {"saga": {"error": "x"}, "csf": {"total": 1.0}}},
            {"row": "isprs/s/1m/min", "half": "A", "tools": {"saga": {"total": 6.0}, "csf": {"total": 4.0}}}]
    ours = {"lidar/a/2m": {"dtm": 2.3}, "lidar/b/4m": {"dtm": 2.0}, "isprs/s/1m/min": {"dtm": 3.0}}
    s = anc.summarise(rows, ["saga", "csf"], ours)
    assert s["saga"]["rows"] == 2 and s["saga"]["mean_all"] == pytest.approx(4.0)
    assert s["best"]["mean_all"] == pytest.approx((2.0 + 1.0 + 4.0) / 3)
    assert s["best"]["mean_A"] == pytest.approx(3.0) and s["best"]["mean_B"] == pytest.approx(1.0)
    gaps = {g["row"]: (g["best_tool"], round(g["gap"], 6)) for g in s["dtm_gap"]}
    assert gaps == {"lidar/a/2m": ("saga", 0.3), "lidar/b/4m": ("csf", 1.0), "isprs/s/1m/min": ("csf", -1.0)}
    text = anc.markdown({"tools": ["saga", "csf"], "rows": rows, "summary": s, "ours": ours,
                         "date": "2026-11-25T00:00:00", "ours_commit": "abc"})
    assert "1 of 2 rows within" in text and "`lidar/b/4m` 2.00 vs csf 1.00" in text


def test_anchor_saga_removes_a_building_when_installed():
    anc = _load_benchmark("anchors")
    if not anc.saga_available():
        pytest.skip("SAGA GIS (saga_cmd) is not installed")
    z = np.full((60, 60), 100.0, np.float32) + np.random.default_rng(2).normal(0, 0.03, (60, 60)).astype(np.float32)
    z[20:29, 25:34] += 9.0                                       # within SAGA's 5-cell kernel of ground
    z[0, 0] = np.nan
    res = anc.run_saga(z, (1.0, 1.0))
    assert res.mask[0, 0] == 255
    assert (res.mask[20:29, 25:34] == 1).all()                  # the roof is removed
    assert (res.mask[45:, :] == 0).mean() > 0.95                 # open ground kept
    assert np.nanmax(np.abs(res.dtm[20:29, 25:34] - 100.0)) < 0.5  # the DTM under it is the ground


def test_generalise_simulated_lidar_rows_are_scored_per_point(tmp_path, monkeypatch):
    """The simulated lidar sources come after every other source (the others keep their
    halves) and their rows score the cloud's points as the lidar files' rows do: the
    reference's own DTM near 0, the raw lowest-point grid well above it."""
    gen = _load_benchmark("generalise")
    monkeypatch.setattr(gen, "SYNTHETIC_LIDAR", (("forest", 100.0, 4.0), ("urban", 150.0, 2.0),
                                                 ("dense", "forest", 100.0, 4.0, {"crown_density": 10.0})))
    notes = []
    cases = gen.all_cases(tmp_path, notes)
    names = [src for src, _, _, _ in cases]
    assert names[-3:] == ["synthetic-lidar/forest", "synthetic-lidar/urban", "synthetic-lidar/dense"]
    assert [h for _, _, h, _ in cases[-3:]] == ["AB"[(len(cases) + k) % 2] for k in (-3, -2, -1)]
    assert [n for n, _ in cases[-1][3]] == ["synthetic-lidar/dense/1m", "synthetic-lidar/dense/2m",
                                            "synthetic-lidar/dense/4m"]
    rows = dict(cases[-2][3])
    assert list(rows) == ["synthetic-lidar/urban/1m", "synthetic-lidar/urban/2m", "synthetic-lidar/urban/4m"]
    z, cell, score = rows["synthetic-lidar/urban/2m"]()
    assert z.shape == (75, 75) and cell == (2.0, 2.0)
    assert score.floor()["total"] < 1.0
    assert score(SimpleNamespace(dtm=z))["total"] > 10.0           # roofs kept as ground
    assert any(n.startswith("synthetic-lidar/urban") for n in notes)


def test_write_report_all_or_nothing(tmp_path):
    """A report that cannot be written (its HTML path a folder) leaves no JSON and no temporary
    file, and says which path and why (it raised IsADirectoryError after writing the JSON)."""
    (tmp_path / "r.html").mkdir()
    with pytest.raises(ValueError, match=r"r.html' is a folder: give a file name in it"):
        write_report({"total": 1.0}, json_path=tmp_path / "r.json", html_path=tmp_path / "r.html")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.html"]
    assert list((tmp_path / "r.html").iterdir()) == []
    write_report({"total": 1.0}, json_path=tmp_path / "r.json", html_path=tmp_path / "page.html")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["page.html", "r.html", "r.json"]


def test_check_reference_mask_needs_a_ground_cell():
    from bare_earth.core.evaluate import check_reference_mask
    check_reference_mask(np.array([[0, 1], [2, 255]], np.uint8))        # ground present
    check_reference_mask(np.full((2, 2), 255, np.uint8))                 # nothing to say: all nodata
    with pytest.raises(ValueError, match=r"its codes are 2, 6\. .*ASPRS.*!= 2\)"):
        check_reference_mask(np.array([[2, 6], [255, 2]], np.uint8))
    with pytest.raises(ValueError, match=r"its codes are 1\. .*another code.*!= its ground code\)"):
        check_reference_mask(np.array([[1, 1]], np.uint8))


def test_check_nodata_not_objects_refuses_a_binary_mask_exactly():
    """A 0/255 mask (255 = object, another tool's convention) left every object out as nodata: total 0 %."""
    from bare_earth.core.evaluate import check_nodata_not_objects
    other = np.array([[0, 0, 1, 1], [0, 0, 1, 1], [0, 0, 0, 255]], np.uint8)
    binary = np.array([[0, 0, 255, 255], [0, 0, 255, 255], [0, 0, 0, 255]], np.uint8)
    with pytest.raises(ValueError, match=r"only 0 and 255, and its 4 cell\(s\) of 255 where the mask has data lie "
                                         r"on the mask's objects \(100 % of them, against 0 % of the cells it calls "
                                         r"ground\).*\"mask@1\" = 255"):
        check_nodata_not_objects(binary, other, "the reference mask", "the mask")
    check_nodata_not_objects(np.where(binary == 255, 1, binary).astype(np.uint8), other)   # 0/1: compared
    check_nodata_not_objects(other, binary)               # the mask with objects: its own 255 matches nothing
    # nodata where the data ends, whatever lies there: the other's objects in it as under its ground
    edge = np.array([[0, 1, 255, 255], [0, 0, 255, 255], [1, 0, 0, 0]], np.uint8)
    under = np.array([[0, 1, 1, 0], [0, 0, 0, 0], [1, 0, 0, 0]], np.uint8)
    check_nodata_not_objects(np.where(edge == 1, 0, edge).astype(np.uint8), under)      # 1 of 4 objects: 25 %
    # more than half but not twice the share under its ground: no sign of 255 marking objects
    g = np.array([[0, 0, 255, 255, 255]], np.uint8)
    check_nodata_not_objects(g, np.array([[1, 0, 1, 1, 0]], np.uint8))   # 67 % under 255, 50 % under 0
    with pytest.raises(ValueError, match=r"its 3 cell\(s\) of 255 .*\(67 % of them, against 0 %"):
        check_nodata_not_objects(g, np.array([[0, 0, 1, 1, 0]], np.uint8))


def test_dtm_errors_breakdown_exact():
    """benchmarks/dtm_errors.py: each point counted once, by kind, cell state and members' vote."""
    bench = _load_benchmark("dtm_errors")
    codes = np.array([0, 0, 1, 2, 0, 0, 255, 1], np.uint8)
    truth = np.array([True, False, True, True, False, False, False, True])
    valid = np.array([True, True, True, True, True, False, True, True])
    rows = np.array([0, 0, 1, 1, 0, 1, 0, -1])
    cols = np.array([0, 1, 0, 1, 1, 1, 0, -1])
    mask = np.array([[0, 0], [1, 1]], np.uint8)
    members = {"morphological": np.array([[True, True], [True, False]]),
               "rascor": np.array([[True, False], [False, False]]),
               "geodesic": np.array([[True, True], [False, True]])}
    heights = np.array([0.0, 1.0, 0.0, 0.0, 2.0, 0.0, 0.0, 0.0])
    ref = np.zeros((2, 2))
    dtm = np.array([[0.0, 0.5], [-1.0, 0.0]])
    b = bench.breakdown(codes, truth, valid, rows, cols, mask, members, heights=heights, dtm=dtm, reference=ref)
    assert (b["ground_points"], b["object_points"]) == (3, 2)         # off the grid, invalid, outside: not scored
    assert (b["type1_above"], b["type1_below"], b["type2"]) == (1, 1, 2)
    assert b["groups"] == {("type2", "ground", "M-G"): {"points": 2, "point_above_ref_m": 1.5, "dtm_above_ref_m": 0.5},
                           ("type1_above", "filled", "M--"): {"points": 1, "point_above_ref_m": 0.0,
                                                              "dtm_above_ref_m": -1.0}}
    maps = bench.error_maps(codes, truth, valid, rows, cols, (2, 2))
    assert maps["type2"].tolist() == [[0, 2], [0, 0]]
    assert maps["type1_above"].tolist() == [[0, 0], [1, 0]] and maps["type1_below"].tolist() == [[0, 0], [0, 1]]
    assert "type II 2" in bench.format_breakdown("row", b)


def test_morphological_errors_by_stage_exact():
    """benchmarks/morphological_errors.py: each cell named by the stage that decided it (the opening's first
    flagging step over the other stages), each scored point counted once, by kind, stage and the cell's class."""
    bench = _load_benchmark("morphological_errors")
    first = np.array([[1, -1, -1], [-1, -1, 0]], np.int8)
    stages = {"first_step": first, "flagged": first >= 0, "cut_terrain": np.array([[0, 1, 0], [0, 0, 0]], bool),
              "outline": np.array([[0, 0, 1], [0, 0, 0]], bool), "tiers": np.zeros((2, 3), bool),
              "low_prestep": np.array([[1, 0, 0], [1, 0, 0]], bool),
              "low_ground": np.array([[0, 0, 0], [1, 0, 1]], bool)}
    grid, names = bench.stage_codes(stages, (2, 3), (3.0, 5.0))
    assert [[names[c] for c in row] for row in grid.tolist()] == [
        ["step 1 (5 m)", "cut terrain", "outline"], ["pre-step low", "kept", "step 0 (3 m)"]]
    mask = np.array([[1, 0, 1], [2, 0, 0]], np.uint8)
    codes = np.array([1, 0, 0, 2, 0, 255, 0], np.uint8)
    truth = np.array([True, False, False, True, False, True, False])
    valid = np.array([True, True, True, True, True, True, False])
    rows = np.array([0, 0, 1, 1, 1, 0, 0])
    cols = np.array([0, 1, 1, 0, 2, 2, 1])
    b = bench.breakdown(codes, truth, valid, rows, cols, mask, grid, names, heights=np.arange(7.0),
                        reference=np.zeros((2, 3)))
    assert (b["ground_points"], b["object_points"]) == (2, 3)          # the 255 and the invalid point: not scored
    assert (b["type1_above"], b["type1_below"], b["type2"]) == (1, 1, 3)
    assert b["groups"] == {("type1_above", "step 1 (5 m)", "object"): {"points": 1, "point_above_ref_m": 0.0},
                           ("type1_below", "pre-step low", "low"): {"points": 1, "point_above_ref_m": 3.0},
                           ("type2", "cut terrain", "ground"): {"points": 1, "point_above_ref_m": 1.0},
                           ("type2", "kept", "ground"): {"points": 1, "point_above_ref_m": 2.0},
                           ("type2", "step 0 (3 m)", "ground"): {"points": 1, "point_above_ref_m": 4.0}}
    assert "type II 3" in bench.format_breakdown("row", b)


def test_morphological_errors_count_what_the_matrix_scores(tmp_path):
    """The breakdown of a row adds up to the generalisation matrix's total error for the filter on it, and the
    filter's second run (with ``stages=``) gives the matrix's mask."""
    bench = _load_benchmark("morphological_errors")
    (tmp_path / "isprs").mkdir()
    _synthetic_sample(tmp_path / "isprs" / "samp11.txt", 1)
    b = bench.run(tmp_path, r"isprs/samp11/2m/min", progress=None)["isprs/samp11/2m/min"]
    rows, _ = bench.generalise.run_matrix(tmp_path, ["morphological"], only=r"isprs/samp11/2m/min", progress=None)
    total = 100.0 * (b["type1_above"] + b["type1_below"] + b["type2"]) / (b["ground_points"] + b["object_points"])
    assert total == pytest.approx(rows[0]["filters"]["morphological"]["total"], abs=1e-9)
    assert sum(g["points"] for g in b["groups"].values()) == b["type1_above"] + b["type1_below"] + b["type2"]
    assert b["cells_differing"] == 0


def test_geodesic_errors_by_stage_exact():
    """benchmarks/geodesic_errors.py: each cell named by the stage its ``extras["step"]`` code gives (the dilation's
    steps by their windows), each scored point counted once, by kind, stage and the cell's class."""
    bench = _load_benchmark("geodesic_errors")
    step = np.array([[0, 1, 2], [250, 252, 255]], np.uint8)
    grid, names = bench.stage_codes(step, (2.0, 4.0))
    assert [[names[c] if c >= 0 else None for c in row] for row in grid.tolist()] == [
        ["kept", "step 1 (2 m)", "step 2 (4 m)"], ["scan", "edge", None]]
    mask = np.array([[0, 1, 1], [1, 1, 255]], np.uint8)
    codes = np.array([0, 1, 0, 1, 2], np.uint8)
    truth = np.array([False, True, False, True, True])
    valid = np.ones(5, bool)
    rows, cols = np.array([0, 0, 0, 1, 1]), np.array([0, 1, 0, 0, 1])
    b = bench.breakdown(codes, truth, valid, rows, cols, mask, grid, names, heights=np.arange(5.0),
                        reference=np.zeros((2, 3)))
    assert (b["type1_above"], b["type1_below"], b["type2"]) == (2, 1, 2)
    assert b["groups"] == {("type2", "kept", "ground"): {"points": 2, "point_above_ref_m": 1.0},
                           ("type1_above", "step 1 (2 m)", "object"): {"points": 1, "point_above_ref_m": 1.0},
                           ("type1_above", "scan", "object"): {"points": 1, "point_above_ref_m": 3.0},
                           ("type1_below", "edge", "object"): {"points": 1, "point_above_ref_m": 4.0}}


def test_geodesic_errors_count_what_the_matrix_scores(tmp_path):
    """The breakdown of a row adds up to the generalisation matrix's total error for geodesic on it."""
    bench = _load_benchmark("geodesic_errors")
    (tmp_path / "isprs").mkdir()
    _synthetic_sample(tmp_path / "isprs" / "samp11.txt", 1)
    b = bench.run(tmp_path, r"isprs/samp11/2m/min", progress=None)["isprs/samp11/2m/min"]
    rows, _ = bench.generalise.run_matrix(tmp_path, ["geodesic"], only=r"isprs/samp11/2m/min", progress=None)
    total = 100.0 * (b["type1_above"] + b["type1_below"] + b["type2"]) / (b["ground_points"] + b["object_points"])
    assert total == pytest.approx(rows[0]["filters"]["geodesic"]["total"], abs=1e-9)
    assert sum(g["points"] for g in b["groups"].values()) == b["type1_above"] + b["type1_below"] + b["type2"]


def test_sites_rascor_errors_by_step_exact():
    """benchmarks/sites.py --steps: RASCOR's Type I / II cells by the step that removed (0 kept)
    each, in per cent of the valid cells (nodata not counted)."""
    bench = _load_benchmark("sites")
    mask = np.array([1, 1, 2, 0, 0, 0, 255, 0], np.uint8)
    truth = np.array([0, 0, 0, 1, 1, 0, 1, 0], np.uint8)
    step = np.array([3, 5, 3, 0, 0, 0, 0, 0], np.uint8)
    # 7 valid cells: Type I at steps 3 (two: one object, one low) and 5; Type II kept (two)
    assert bench.errors_by_step(mask, truth, step) == "T1 {3: 28.57, 5: 14.29} T2 {0: 28.57}"


def test_dtm_errors_peer_crosstab_exact():
    """benchmarks/dtm_errors.py --peer: each point scored by both counted once, by the two decisions on its cell."""
    bench = _load_benchmark("dtm_errors")
    ours = np.array([0, 0, 1, 0, 0, 255, 0], np.uint8)
    peer = np.array([0, 1, 1, 1, 0, 0, 0], np.uint8)
    truth = np.array([True, True, False, False, False, True, True])
    valid = np.ones(7, bool)
    rows = np.array([0, 0, 1, 1, 1, 0, -1])
    cols = np.array([0, 1, 0, 1, 1, 0, -1])
    mask = np.array([[0, 0], [1, 0]], np.uint8)
    peer_mask = np.array([[0, 1], [1, 1]], np.uint8)
    ref = np.zeros((2, 2))
    dtm = np.array([[0.0, 0.0], [0.4, 0.8]])
    peer_dtm = np.array([[0.0, -0.2], [-0.1, -0.3]])
    x = bench.peer_crosstab(ours, peer, truth, valid, rows, cols, mask, peer_mask, dtm=dtm, peer_dtm=peer_dtm,
                            reference=ref)
    zero = {"dtm_type1": 0, "dtm_type2": 0, "peer_type1": 0, "peer_type2": 0}
    assert x["both ground"] == {"points": 1, "ground_points": 1, **zero}      # the 255 and off-grid points: unscored
    assert x["dtm ground, peer object"] == {"points": 3, "ground_points": 1, **zero, "peer_type1": 1,
                                            "dtm_type2": 2, "peer_type2": 1}
    assert x["dtm object, peer ground"] == {"points": 0, "ground_points": 0, **zero}
    assert x["both object"] == {"points": 1, "ground_points": 0, **zero}
    assert x["offsets"] == {"both_object_dtm_m": pytest.approx(0.4), "both_object_peer_m": pytest.approx(-0.1),
                            "dtm_type2_dtm_m": pytest.approx(0.8), "dtm_type2_peer_m": pytest.approx(-0.3)}
    assert "both object" in bench.format_crosstab("saga", x)


def test_dtm_errors_counts_what_the_matrix_scores(tmp_path):
    """The breakdown of a row adds up to the generalisation matrix's total error for the dtm on it."""
    bench = _load_benchmark("dtm_errors")
    (tmp_path / "isprs").mkdir()
    _synthetic_sample(tmp_path / "isprs" / "samp11.txt", 1)
    out = bench.run(tmp_path, r"isprs/samp11/2m/min", maps=tmp_path / "maps", progress=None)
    b = out["isprs/samp11/2m/min"]
    rows, _ = bench.generalise.run_matrix(tmp_path, ["dtm"], only=r"isprs/samp11/2m/min", progress=None)
    total = 100.0 * (b["type1_above"] + b["type1_below"] + b["type2"]) / (b["ground_points"] + b["object_points"])
    assert total == pytest.approx(rows[0]["filters"]["dtm"]["total"], abs=1e-9)
    assert sum(g["points"] for (k, _, _), g in b["groups"].items() if k == "type2") == b["type2"]
    with np.load(tmp_path / "maps" / "isprs_samp11_2m_min.npz") as m:
        assert int(m["type2"].sum()) == b["type2"] and m["dsm"].shape == m["mask"].shape


def test_error_map_from_points_on_south_up_and_east_to_west_grids(tmp_path):
    """The map of a point evaluation on a DTM stored bottom-up (gt[5] > 0, origin at the south
    edge) or right to left: its extent was taken north-up from the origin, so every point fell
    outside ("correct: 0 cells", all "not evaluated"). The map is now in the grid's row and
    column order, and the HTML draws every map north-up (the same picture for both storages)."""
    from bare_earth.core.evaluate import error_map_from_points
    gt, x, y, pred, truth = _five_points()
    north, _ = error_map_from_points(pred, truth, x, y, gt, (2, 3))
    south, _ = error_map_from_points(pred, truth, x, y, (0.0, 1.0, 0.0, 0.0, 0.0, 1.0), (2, 3))
    west, _ = error_map_from_points(pred, truth, x, y, (3.0, -1.0, 0.0, 2.0, 0.0, -1.0), (2, 3))
    np.testing.assert_array_equal(south, north[::-1])
    np.testing.assert_array_equal(west, north[:, ::-1])
    pages = []
    for name, codes, g in (("n", north, gt), ("s", south, (0.0, 1.0, 0.0, 0.0, 0.0, 1.0))):
        write_report({"s": {"total": 1.0}}, html_path=tmp_path / f"{name}.html", error_map=codes, geotransform=g)
        pages.append(re.search(r'src="data:image/png;base64,([^"]+)"', (tmp_path / f"{name}.html").read_text())[1])
    assert pages[0] == pages[1]


def test_kappa_of_a_perfect_classification_is_100_exactly():
    """Cohen's kappa in whole numbers: a perfect classification gave 100.00000000000001 %
    (KAPPA above its range in the log and the outputs)."""
    pred = np.array([True] * 272 + [False] * 28)
    assert confusion(pred, pred)["kappa"] == 100.0
    r = confusion(np.array([True] * 50 + [False] * 10 + [True] * 5 + [False] * 35),
                  np.array([True] * 60 + [False] * 40))
    assert r["kappa"] == pytest.approx(100 * 0.34 / 0.49)
    assert math.isnan(confusion(np.ones(5, bool), np.ones(5, bool))["kappa"])


def test_generalise_rows_with_empty_cells_keep_them_and_come_last(tmp_path, monkeypatch):
    """The rows whose empty cells stay nodata (issue 13) come after every other source (the others keep
    their halves), hold NaN where no point fell and the filled row's heights elsewhere, and score a DTM
    with nodata cells (taken from the nearest for scoring)."""
    from bare_earth.core import pipeline
    gen = _load_benchmark("generalise")
    (tmp_path / "isprs").mkdir()
    _synthetic_sample(tmp_path / "isprs" / "samp11.txt", 3)
    monkeypatch.setattr(gen, "SYNTHETIC_LIDAR", ())
    notes = []
    cases = gen.all_cases(tmp_path, notes)
    monkeypatch.setattr(gen, "holes_cases", lambda data, notes: [])
    before = gen.all_cases(tmp_path, [])
    assert [c[:3] for c in cases[:len(before)]] == [c[:3] for c in before]
    assert [(src, fam) for src, fam, _, _ in cases[len(before):]] == [("holes/samp11", "holes")]
    assert any(n.startswith("holes/autzen_trim skipped") for n in notes)
    (name, build), = cases[-1][3]
    assert name == "holes/isprs/samp11/1m/min"
    z, cell, score = build()
    filled = _isprs_rows(gen, tmp_path)["isprs/samp11/1m/min"]()[0]
    data = np.isfinite(z)
    assert 0.1 < 1 - data.mean() < 0.5 and np.array_equal(z[data], filled[data])
    res = pipeline.run_array("morphological", z, cell)
    assert np.isnan(res.dtm).any()
    total = score(res)["total"]
    assert np.isfinite(total) and total < 5.0
    assert score(SimpleNamespace(dtm=z))["total"] > 5.0       # the raw DSM: the building is no ground


def test_write_report_removes_the_parts_of_a_killed_write(tmp_path):
    """A report write killed with kill -9 left its hidden work file (``.r.json.<id>.part``) for ever.
    The work file names its process; the next write of that report removes those of processes that
    are gone (and of older versions, which named none), and keeps one whose process runs."""
    gone = 4194305                                   # above Linux's largest pid: no such process
    stale = [tmp_path / f".r.json.{gone:010d}-0123abcd.part", tmp_path / ".r.json.0123abcd.part",
             tmp_path / f".r.html.{gone:010d}-89abcdef.part"]
    live = tmp_path / f".r.json.{os.getppid():010d}-0123abcd.part"
    for p in stale + [live]:
        p.write_text("{")
    write_report({"total": 1.0}, json_path=tmp_path / "r.json", html_path=tmp_path / "r.html")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["r.html", "r.json", live.name])


def test_generalise_out_is_written_with_no_log(tmp_path, monkeypatch):
    """``--no-log`` keeps the committed log untouched; ``--out FILE`` still writes FILE (the
    helpers compare their runs row by row), and ``--no-log`` alone writes nothing."""
    gen = _load_benchmark("generalise")
    rows = [{"row": "isprs/samp11/1m/min", "source": "isprs/samp11", "family": "isprs", "half": "A",
             "shape": [30, 20], "cell_m": 1.0, "floor": 1.0, "grid": 1.5, "raw": 30.0, "seconds": 0.1,
             "filters": {"dtm": {"type1": 1.0, "type2": 3.0, "total": 2.5, "kappa": 90.0, "n": 600}}}]
    monkeypatch.setattr(gen, "run_matrix", lambda data, methods, only: (rows, []))
    committed = tmp_path / "committed.jsonl"
    monkeypatch.setattr(gen, "RESULTS", committed)
    (tmp_path / "data").mkdir()
    out = tmp_path / "mine.jsonl"
    assert gen.main(["--data", str(tmp_path / "data"), "--methods", "dtm", "--no-log", "--out", str(out)]) == 0
    rec = json.loads(out.read_text().splitlines()[-1])
    assert rec["rows"][0]["filters"]["dtm"]["total"] == 2.5 and rec["methods"] == ["dtm"]
    assert not committed.exists()
    out.unlink()
    assert gen.main(["--data", str(tmp_path / "data"), "--methods", "dtm", "--no-log"]) == 0
    assert not out.exists() and not committed.exists()
