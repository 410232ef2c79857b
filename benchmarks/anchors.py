#!/usr/bin/env python3
"""Anchors: peer tools with their defaults on the generalisation matrix, scored the same way.

Usage::

    .venv/bin/python benchmarks/anchors.py [--data DIR] [--tools saga,csf,dsm2dtm] [--only REGEX]
                                           [--no-log] [--readme] [--from-log]

Why. The issues judge ``bareearth:dtm`` against the tools a user would otherwise run (issue
13: on each held-out lidar tile within 0.5 points of the best of SAGA, Whitebox, CSF and
dsm2dtm). Their published figures are on data we do not have; this script measures the ones
that install here on every row of ``benchmarks/generalise.py`` (same inputs, same scoring,
:func:`generalise.all_cases`), so each row shows how far dtm is from the best peer.

The tools (each skipped with a note when it is not installed):

* ``saga``: SAGA GIS's "DTM Filter (slope-based)" (``saga_cmd grid_filter 7``, Vosselman
  2000 as implemented by V. Wichmann) with its defaults: kernel radius 5 cells, terrain slope
  30 %, no filter modification, standard deviation 0.1. ``apt-get install saga``.
* ``csf``: the Cloth Simulation Filter (Zhang et al. 2016, Remote Sensing 8(6) 501), package
  ``cloth-simulation-filter`` with its defaults (rigidness 3, time step 0.65, class threshold
  0.5, 500 iterations, slope post-processing on) on the cells' centres as points, its cloth
  resolution the cell size ("usually set to the average distance of the points", the
  authors' R and lidR documentation; the package's 1.0 would give a 4 m grid 16 particles per
  point and run for many minutes). ``.venv/bin/pip install cloth-simulation-filter``.
* ``dsm2dtm``: the ``dsm2dtm`` package's ``algorithm.dsm_to_dtm`` (the library under the QGIS
  plugin: progressive morphological filter, refinement, smoothing) with its defaults.
  ``.venv/bin/pip install --no-deps dsm2dtm`` (its numeric module needs numpy and scipy
  only; it is loaded without the package's rasterio I/O).

What is scored. The point rows classify every point against the tool's DTM, as for the
Bare Earth filters. SAGA and CSF give a ground / object classification: their DTM is their
ground cells filled by the pipeline's ``fill_dtm`` (the interpolation every Bare Earth filter
uses), so the comparison is of the classification. dsm2dtm gives a DTM: it is scored as it
is, and its mask (for the rows scored by mask) is the cells standing more than 0.5 m above it.

Bare Earth's figures per row come from the last record of ``benchmarks/results/
generalise.jsonl`` (its commit is printed); run ``generalise.py`` first on the same data.
Every run appends one JSON line to ``benchmarks/results/anchors.jsonl``; ``--readme``
replaces the block between ``<!-- anchors:begin -->`` and ``<!-- anchors:end -->`` in
README.md; ``--from-log`` renders the log's last record instead of running.
"""
import argparse
import datetime
import importlib.util
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import types
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import generalise  # noqa: E402  (imports isprs, whose bootstrap makes ``import bare_earth`` work)
import isprs  # noqa: E402
import numpy as np  # noqa: E402
from _common import last_record, read_log, replace_block  # noqa: E402

RESULTS = generalise.ROOT / "benchmarks" / "results" / "anchors.jsonl"
MARK_BEGIN, MARK_END = "<!-- anchors:begin -->", "<!-- anchors:end -->"
TOOLS = ("saga", "csf", "dsm2dtm")
#: issue 13: on each lidar tile, dtm within this many points of the best peer
MARGIN = 0.5
fmt = generalise.fmt


class _Result:
    def __init__(self, dtm, mask):
        self.dtm, self.mask = dtm, mask


def _fill(z, ground):
    from bare_earth.core.pipeline import fill_dtm
    valid = np.isfinite(z)
    mask = np.where(valid, np.where(ground, 0, 1), 255).astype(np.uint8)
    return _Result(fill_dtm(np.asarray(z, np.float32), mask), mask)


# --------------------------------------------------------------------------- tools
def saga_available():
    return shutil.which("saga_cmd") is not None


def run_saga(z, cell):
    """SAGA's slope-based DTM filter with its defaults; ground = cells it keeps."""
    from bare_earth.core import grid
    if abs(cell[0] - cell[1]) > 1e-9:
        raise ValueError("SAGA grids hold square cells only")
    nodata = -99999.0
    with tempfile.TemporaryDirectory(prefix="anchors-saga-") as tmp:
        src = os.path.join(tmp, "dsm.tif")
        rows = z.shape[0]
        grid.write_array(src, np.where(np.isfinite(z), z, nodata).astype(np.float32),
                         (0.0, cell[0], 0.0, rows * cell[1], 0.0, -cell[1]), nodata=nodata)
        out = os.path.join(tmp, "ground.sdat")
        r = subprocess.run(["saga_cmd", "grid_filter", "7", "-INPUT", src, "-GROUND", out],
                           capture_output=True, text=True)
        if r.returncode != 0 or not os.path.exists(out):
            raise RuntimeError(f"saga_cmd failed: {r.stderr.strip()[-300:] or r.stdout.strip()[-300:]}")
        g = grid.open_dsm(out).read()
    if g.shape != z.shape:
        raise RuntimeError(f"SAGA returned {g.shape} for {z.shape}")
    return _fill(z, np.isfinite(g))


def csf_available():
    return importlib.util.find_spec("CSF") is not None


def run_csf(z, cell):
    """CSF with its defaults (cloth resolution: the cell size) on the cells' centres; ground =
    the points it classes ground."""
    import CSF
    rr, cc = np.nonzero(np.isfinite(z))
    pts = np.column_stack([(cc + 0.5) * cell[0], -(rr + 0.5) * cell[1], z[rr, cc]]).astype(np.float64)
    csf = CSF.CSF()
    csf.params.cloth_resolution = float(max(cell))
    csf.setPointCloud(pts)
    ground, other = CSF.VecInt(), CSF.VecInt()
    devnull = os.open(os.devnull, os.O_WRONLY)      # CSF prints its progress on stdout
    saved = os.dup(1)
    try:
        sys.stdout.flush()
        os.dup2(devnull, 1)
        csf.do_filtering(ground, other, exportCloth=False)
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)
    g = np.zeros(z.shape, bool)
    idx = np.asarray(list(ground), np.int64)
    g[rr[idx], cc[idx]] = True
    return _fill(z, g)


def _dsm2dtm_algorithm():
    """dsm2dtm's numeric module, loaded without the package's ``__init__`` (rasterio I/O)."""
    if "dsm2dtm.algorithm" in sys.modules:
        return sys.modules["dsm2dtm.algorithm"]
    spec = importlib.util.find_spec("dsm2dtm")
    if spec is None or not spec.submodule_search_locations:
        return None
    folder = Path(list(spec.submodule_search_locations)[0])
    if "dsm2dtm" not in sys.modules:
        pkg = types.ModuleType("dsm2dtm")
        pkg.__path__ = [str(folder)]
        sys.modules["dsm2dtm"] = pkg
    for name in ("constants", "algorithm"):
        full = f"dsm2dtm.{name}"
        if full not in sys.modules:
            s = importlib.util.spec_from_file_location(full, folder / f"{name}.py")
            mod = importlib.util.module_from_spec(s)
            sys.modules[full] = mod
            s.loader.exec_module(mod)
    return sys.modules["dsm2dtm.algorithm"]


def dsm2dtm_available():
    try:
        return _dsm2dtm_algorithm() is not None
    except Exception:  # a broken install: reported as not available
        return False


def run_dsm2dtm(z, cell):
    """dsm2dtm's ``dsm_to_dtm`` with its defaults; mask = more than 0.5 m above its DTM."""
    alg = _dsm2dtm_algorithm()
    valid = np.isfinite(z)
    dtm = np.asarray(alg.dsm_to_dtm(np.asarray(z, np.float32), (cell[0], cell[1]), nodata=np.nan), np.float32)
    with np.errstate(invalid="ignore"):
        obj = z - dtm > isprs.THRESHOLD_M
    mask = np.where(valid, obj.astype(np.uint8), 255).astype(np.uint8)
    return _Result(dtm, mask)


RUNNERS = {"saga": (saga_available, run_saga), "csf": (csf_available, run_csf),
           "dsm2dtm": (dsm2dtm_available, run_dsm2dtm)}


# --------------------------------------------------------------------------- running
def run_rows(data, tools, only=None, progress=print):
    notes = []
    rows = []
    for _src, _fam, half, builds in generalise.all_cases(data, notes):
        for name, build in builds:
            if only and not re.search(only, name):
                continue
            z, cell, score = build()
            z = np.asarray(z, np.float32)
            row = {"row": name, "half": half, "shape": list(z.shape), "cell_m": float(cell[0]), "tools": {}}
            for t in tools:
                t0 = time.perf_counter()
                try:
                    r = score(RUNNERS[t][1](z, cell))
                except Exception as exc:  # one tool failing must not hide the others
                    row["tools"][t] = {"error": f"{type(exc).__name__}: {exc}"}
                    continue
                r = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in r.items()}
                r["seconds"] = round(time.perf_counter() - t0, 2)
                row["tools"][t] = r
            rows.append(row)
            if progress:
                progress(f"  {name:<34} " + " ".join(
                    f"{fmt(row['tools'][t].get('total')):>8}" for t in tools))
    return rows, notes


def ours_by_row(path=generalise.RESULTS):
    """``(commit, {row: {filter: total}})`` from generalise's last record (empty when none)."""
    if not Path(path).exists():
        return None, {}
    records = read_log(path)
    if not records:
        return None, {}
    rec = records[-1]
    return rec.get("commit"), {r["row"]: {m: f.get("total") for m, f in r["filters"].items()} for r in rec["rows"]}


def _best(row, tools):
    vals = [(row["tools"].get(t, {}).get("total"), t) for t in tools]
    vals = [(v, t) for v, t in vals if v is not None]
    return min(vals) if vals else (None, None)


def summarise(rows, tools, ours):
    out = {}
    for t in tools + ["best"]:
        vals = []
        for r in rows:
            v = _best(r, tools)[0] if t == "best" else r["tools"].get(t, {}).get("total")
            vals.append((r["row"], r["half"], v))
        ok = [(n, h, v) for n, h, v in vals if v is not None]
        s = {"rows": len(ok)}
        if ok:
            s["mean_all"] = float(np.mean([v for _, _, v in ok]))
            for h in "AB":
                hv = [v for _, hh, v in ok if hh == h]
                s[f"mean_{h}"] = float(np.mean(hv)) if hv else None
            w = max(ok, key=lambda x: x[2])
            s["worst"], s["worst_row"] = w[2], w[0]
        og = [r for r in rows if r["row"].startswith("opengeos/")]
        if og and t != "best":
            s["opengeos_rmse_m"] = og[0]["tools"].get(t, {}).get("rmse_m")
        out[t] = s
    # dtm against the best peer, row by row (lidar rows: the criterion)
    gaps = []
    for r in rows:
        b, who = _best(r, tools)
        d = ours.get(r["row"], {}).get("dtm")
        if b is not None and d is not None:
            gaps.append({"row": r["row"], "dtm": d, "best": b, "best_tool": who, "gap": d - b})
    out["dtm_gap"] = gaps
    return out


def markdown(record):
    tools, rows, summ = record["tools"], record["rows"], record["summary"]
    ours = record.get("ours", {})
    lidar = [g for g in summ["dtm_gap"] if g["row"].startswith(("lidar/", "synthetic-lidar/"))]
    over = [g for g in lidar if g["gap"] > MARGIN]
    out = [f"Peer tools with their defaults on the same matrix (`benchmarks/anchors.py`, "
           f"{record['date'][:10]}; dtm from `generalise.py` at commit {str(record.get('ours_commit'))[:8]}): "
           "total error % (lower is better), scored as the Bare Earth filters are.", "",
           "| tool | mean | half A | half B | worst | worst input | opengeos DTM RMSE m |",
           "|---|---|---|---|---|---|---|"]
    for t in tools:
        s = summ[t]
        out.append(f"| {t} | {fmt(s.get('mean_all'))} | {fmt(s.get('mean_A'))} | {fmt(s.get('mean_B'))} | "
                   f"{fmt(s.get('worst'))} | `{s.get('worst_row', '-')}` | {fmt(s.get('opengeos_rmse_m'))} |")
    s = summ["best"]
    out.append(f"| best peer per row | {fmt(s.get('mean_all'))} | {fmt(s.get('mean_A'))} | "
               f"{fmt(s.get('mean_B'))} | {fmt(s.get('worst'))} | `{s.get('worst_row', '-')}` | - |")
    out += ["", f"dtm against the best peer on the lidar rows (issue 13: within {MARGIN} points on each "
            f"tile): {len(lidar) - len(over)} of {len(lidar)} rows within; "
            + ("beyond: " + ", ".join(f"`{g['row']}` {g['dtm']:.2f} vs {g['best_tool']} {g['best']:.2f}"
                                      for g in over) if over else "none beyond") + ".", "",
            "<details><summary>Row by row</summary>", "",
            "| input | half | " + " | ".join(tools) + " | dtm | dtm - best |",
            "|---|---|" + "---|" * (len(tools) + 2)]
    gap = {g["row"]: g["gap"] for g in summ["dtm_gap"]}
    for r in rows:
        out.append(f"| `{r['row']}` | {r['half']} | " + " | ".join(
            fmt(r["tools"].get(t, {}).get("total")) for t in tools)
            + f" | {fmt(ours.get(r['row'], {}).get('dtm'))} | {fmt(gap.get(r['row']))} |")
    out += ["", "</details>"]
    for n in record.get("notes", []):
        out.append(f"\n- note: {n}")
    return "\n".join(out) + "\n"


def write_readme(text, path=generalise.README):
    def place(src, block):                     # no markers yet: after the generalisation matrix
        end = src.index(generalise.MARK_END) + len(generalise.MARK_END)
        return src[:end] + "\n\n" + block + src[end:]
    replace_block(path, MARK_BEGIN, MARK_END, text, place)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=None, help="data folder (default $BARE_EARTH_DATA or ../shared/data)")
    ap.add_argument("--tools", default=",".join(TOOLS), help=f"comma-separated tools (default {','.join(TOOLS)})")
    ap.add_argument("--only", default=None, help="regular expression: run only the rows whose name matches")
    ap.add_argument("--out", type=Path, default=RESULTS, help=f"JSON-lines log (default {RESULTS})")
    ap.add_argument("--no-log", action="store_true", help="do not append to the log")
    ap.add_argument("--readme", action="store_true", help="replace the anchors block of README.md")
    ap.add_argument("--from-log", action="store_true",
                    help="render the log's last record (dtm's figures from generalise.py's last record) "
                         "instead of running")
    args = ap.parse_args(argv)
    if args.from_log:
        # the peers' figures do not depend on our code: their last record, beside dtm's figures
        # from generalise.py's last record (the peers need not be re-run after a change of ours)
        record = last_record(args.out)
        commit, ours = ours_by_row()
        if ours:
            record["ours_commit"] = commit
            record["ours"] = {r["row"]: ours.get(r["row"], {}) for r in record["rows"]}
            record["summary"] = summarise(record["rows"], record["tools"], ours)
    else:
        data = args.data if args.data is not None else isprs.default_data_dir()
        if not data.is_dir():
            print(f"anchors benchmark skipped: no data folder {data} (pass --data or set BARE_EARTH_DATA).")
            return 0
        wanted = [t.strip() for t in args.tools.split(",") if t.strip()]
        unknown = [t for t in wanted if t not in RUNNERS]
        if unknown:
            ap.error(f"unknown tool(s) {unknown}: choose from {', '.join(TOOLS)}")
        tools = [t for t in wanted if RUNNERS[t][0]()]
        missing = [t for t in wanted if t not in tools]
        if not tools:
            print(f"anchors benchmark skipped: none of {', '.join(wanted)} is installed (see --help).")
            return 0
        t0 = time.perf_counter()
        print(f"Anchors: {', '.join(tools)} (defaults) on {data}")
        rows, notes = run_rows(data, tools, args.only)
        notes += [f"{t}: not installed, skipped" for t in missing]
        commit, ours = ours_by_row()
        record = {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                  "commit": isprs.git_commit(), "data": str(data), "only": args.only, "tools": tools,
                  "seconds": round(time.perf_counter() - t0, 1), "notes": notes, "ours_commit": commit,
                  "ours": {r["row"]: ours.get(r["row"], {}) for r in rows},
                  "summary": summarise(rows, tools, ours), "rows": rows}
        if not args.no_log:
            generalise.append_record(args.out, record)
    text = markdown(record)
    print()
    print(text)
    if args.readme:
        write_readme(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
