#!/usr/bin/env python3
"""ISPRS filter-test benchmark: Type I / II / total error and kappa of every filter.

Usage::

    /usr/bin/python3 benchmarks/isprs.py [--data DIR] [--methods a,b] [--out FILE]
                                         [--report HTML] [--no-log] [--readme]
    /usr/bin/python3 benchmarks/isprs.py --from-log [--methods a,b] [--out FILE] [--readme]

Protocol, for each reference sample ``<data>/isprs/samp*.txt`` (x y z class, class 0 = bare
earth; Sithole & Vosselman 2004, ISPRS J. Photogramm. Remote Sens. 59(1-2):85-101):

1. read the points;
2. rasterize the lowest point per 1 m cell over the sample's extent, empty cells filled
   from the nearest cell;
3. run the filter with its defaults: ``bare_earth.core.pipeline.run_array(name, z,
   cell_size=(1.0, 1.0), params={})`` -> ``.mask``, ``.dtm`` (filled), ``.info``;
4. classify every point against the DTM (``classify_points``, threshold 0.5 m, slope
   factor 1.25); predicted ground = class 0;
5. Type I, Type II, total error and Cohen's kappa per sample (percent) and their mean over
   the samples; the baseline "every point ground" for comparison.

Each run appends one JSON line per method (date, git commit, method, params, per-sample
figures, mean) to ``benchmarks/results/isprs.jsonl`` so methods can be compared over time.
``--from-log`` prints, instead of running, the README's table from that log: per method its
newest record run by this protocol with its defaults, the methods by mean total error, and the
"every point ground" row from the records' cross matrices; ``--readme`` (after a logged run, or
with ``--from-log``) replaces that table between ``<!-- isprs:begin -->`` and
``<!-- isprs:end -->`` in README.md (:func:`write_readme`).
Data: ``--data``, else env ``BARE_EARTH_DATA``, else ``<repo>/../shared/data``; when the
folder is absent the script says so and exits 0. Cite the data's sources (see
``isprs/provenance``) with any figure.
"""
import argparse
import datetime
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "isprs.jsonl"
README = ROOT / "README.md"
MARK_BEGIN, MARK_END = "<!-- isprs:begin -->", "<!-- isprs:end -->"
#: The README's names of the methods whose defaults need a word (the rest by their own name).
README_LABELS = {"dtm": "dtm (recommended: 2 of 3 vote, refined)",
                 "morphological": "morphological (progressive)"}

#: The protocol's fixed settings.
CELL_SIZE = 1.0
THRESHOLD_M = 0.5
SLOPE_FACTOR = 1.25
MEASURES = ("type1", "type2", "total", "kappa")


def _bootstrap():
    """Make ``import bare_earth`` work (links the repo as .build/plugins/bare_earth)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _common import setup_path
    setup_path()


_bootstrap()

import numpy as np  # noqa: E402
from _common import read_log, replace_block  # noqa: E402

from bare_earth.core.evaluate import confusion, error_map_from_points  # noqa: E402
from bare_earth.core.points import classify_points, rasterize_points, read_points  # noqa: E402


def default_data_dir():
    """``$BARE_EARTH_DATA`` or ``<repo>/../shared/data``."""
    return Path(os.environ.get("BARE_EARTH_DATA", ROOT.parent / "shared" / "data"))


def load_samples(folder):
    """Read every ``samp*.txt`` of ``folder`` (or of ``folder/isprs``).

    Returns
    -------
    dict of str -> PointCloud
        Keyed by sample name (``"samp11"``), sorted.
    """
    folder = Path(folder)
    if not list(folder.glob("samp*.txt")) and (folder / "isprs").is_dir():
        folder = folder / "isprs"
    paths = sorted(folder.glob("samp*.txt"))
    if not paths:
        raise ValueError(f"no ISPRS sample (samp*.txt) in {folder}; pass the folder holding "
                         "them (--data <data> with <data>/isprs/samp11.txt ...).")
    samples = {}
    for p in paths:
        cloud = read_points(p)
        if cloud.classification is None:
            raise ValueError(f"{p} has no class column; ISPRS samples are x y z class.")
        samples[p.stem] = cloud
    return samples


def _as_samples(samples):
    if isinstance(samples, (str, os.PathLike)):
        return load_samples(samples)
    if isinstance(samples, dict):
        return samples
    out = {}
    for p in samples:
        p = Path(p)
        out[p.stem] = read_points(p)
    return out


def _runner(method, params):
    """``run(z, cell_size) -> object with .mask, .dtm, .info`` for a name or a callable."""
    if callable(method) and not isinstance(method, str):
        return method
    from bare_earth.core.pipeline import run_array

    def run(z, cell_size):
        return run_array(method, z, cell_size=cell_size, params=dict(params or {}))
    return run


def scalars(info):
    """The JSON-able scalar items of a filter's info dict (parameters used, stats)."""
    out = {}
    for k, v in (info or {}).items():
        if isinstance(v, (bool, np.bool_)):
            out[str(k)] = bool(v)
        elif isinstance(v, (int, np.integer)):
            out[str(k)] = int(v)
        elif isinstance(v, (float, np.floating)):
            out[str(k)] = float(v) if np.isfinite(v) else None
        elif isinstance(v, str):
            out[str(k)] = v
        elif isinstance(v, (tuple, list)) and len(v) <= 8 and all(
                isinstance(e, (int, float, np.integer, np.floating)) for e in v):
            out[str(k)] = [float(e) for e in v]
    return out


def _mean(per_sample):
    return {m: float(np.mean([r[m] for r in per_sample.values()])) for m in MEASURES}


def figures(conf):
    """The protocol's measures and the cross matrix of a :func:`~bare_earth.core.evaluate.confusion`."""
    keep = MEASURES + ("a", "b", "c", "d", "n")
    return {k: conf[k] for k in keep}


def evaluate_method(name, samples, params=None, maps=None):
    """Run one filter on every sample by the benchmark protocol.

    Parameters
    ----------
    name : str or callable
        A registered method name (run through ``pipeline.run_array`` with ``params``), or
        a callable ``run(z, cell_size) -> object with .mask, .dtm, .info`` (for tests and
        experiments).
    samples : dict of str -> PointCloud, folder, or iterable of paths
        The ISPRS samples (:func:`load_samples`).
    params : dict, optional
        Method parameters (default: the method's defaults, ``{}``).
    maps : dict, optional
        When given, filled with ``{sample: (error codes, geotransform)}``: per 1 m cell the
        worst point error, cells without a point from the nearest one
        (:func:`bare_earth.core.evaluate.error_map_from_points`).

    Returns
    -------
    dict
        ``method``, ``params``, ``samples`` (per sample: type1, type2, total, kappa in
        percent, the cross matrix a, b, c, d, n, ``seconds`` and the filter's scalar
        ``info``), ``mean`` (of the per-sample percentages), ``seconds``.
    """
    samples = _as_samples(samples)
    run = _runner(name, params)
    per, t_all = {}, time.perf_counter()
    for sname, cloud in samples.items():
        t0 = time.perf_counter()
        z, gt = rasterize_points(cloud.x, cloud.y, cloud.z, CELL_SIZE, reducer="min",
                                 fill_empty="nearest")
        res = run(z, (CELL_SIZE, CELL_SIZE))
        dtm = np.asarray(res.dtm, dtype=np.float32)
        if dtm.shape != z.shape:
            raise ValueError(f"method {name!r} returned a DTM of shape {dtm.shape} for a "
                             f"{z.shape} raster on {sname}.")
        cls = classify_points(cloud.x, cloud.y, cloud.z, dtm, gt,
                              threshold_m=THRESHOLD_M, slope_factor=SLOPE_FACTOR)
        truth = cloud.classification == 0
        r = figures(confusion(cls == 0, truth))
        if maps is not None:
            maps[sname] = (error_map_from_points(cls == 0, truth, cloud.x, cloud.y, gt,
                                                 z.shape, fill_empty="nearest")[0], gt)
        r["seconds"] = round(time.perf_counter() - t0, 3)
        r["info"] = scalars(getattr(res, "info", None))
        per[sname] = r
    label = name if isinstance(name, str) else getattr(name, "__name__", "callable")
    return {"method": label, "params": dict(params or {}), "samples": per,
            "mean": _mean(per), "seconds": round(time.perf_counter() - t_all, 3)}


def baseline(samples):
    """The figures of the trivial filter "every point is ground" (kappa 0)."""
    samples = _as_samples(samples)
    per = {}
    for sname, cloud in samples.items():
        truth = cloud.classification == 0
        per[sname] = figures(confusion(np.ones(truth.shape, bool), truth))
    return {"method": "all ground", "params": {}, "samples": per, "mean": _mean(per)}


def format_table(results, base=None):
    """An aligned text table: one block per method, one row per sample and the mean.

    ``results`` maps a label to an :func:`evaluate_method` result; ``base`` (the
    :func:`baseline`) adds its total error and a final block.
    """
    blocks = list(results.values()) + ([base] if base is not None else [])
    if not blocks:
        return "(no results)"
    names = list(blocks[0]["samples"])
    w = max([len("method"), 10] + [len(b["method"]) for b in blocks])
    head = (f"{'method':<{w}}  {'sample':<8} {'Type I %':>9} {'Type II %':>9} {'total %':>8} "
            f"{'kappa %':>8}" + (f" {'base tot %':>10}" if base is not None else ""))
    lines = [head, "-" * len(head)]
    for b in blocks:
        for s in names + ["mean"]:
            r = b["mean"] if s == "mean" else b["samples"].get(s)
            if r is None:
                continue
            line = (f"{b['method']:<{w}}  {s:<8} {r['type1']:9.2f} {r['type2']:9.2f} "
                    f"{r['total']:8.2f} {r['kappa']:8.2f}")
            if base is not None:
                br = base["mean"] if s == "mean" else base["samples"][s]
                line += f" {br['total']:10.2f}"
            lines.append(line)
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"


def protocol():
    """The protocol's settings as each log record names them."""
    return {"cell_size": CELL_SIZE, "reducer": "min", "threshold_m": THRESHOLD_M, "slope_factor": SLOPE_FACTOR}


def latest_records(path=RESULTS, methods=None):
    """Per method, the newest record of the log at ``path`` run by this protocol with the method's
    defaults (``params`` empty), in the order the methods first appear; only ``methods`` when given."""
    out = {}
    for rec in read_log(path):
        if rec.get("params") or rec.get("protocol") != protocol():
            continue
        if methods is None or rec["method"] in methods:
            out[rec["method"]] = rec
    if not out:
        raise ValueError(f"the log {path} holds no record of {', '.join(methods) if methods else 'any method'} "
                         "by this protocol with defaults: run `benchmarks/isprs.py` without --no-log first")
    return out


def baseline_from_record(record):
    """The "every point ground" figures of a record's samples, from its cross matrices (Type I 0,
    Type II 100, total = the share of object points, kappa 0): the same as :func:`baseline`
    without the data."""
    per = {}
    for sname, r in record["samples"].items():
        objects = r["c"] + r["d"]
        per[sname] = {"type1": 0.0, "type2": 100.0 if objects else float("nan"),
                      "total": 100.0 * objects / r["n"], "kappa": 0.0}
    return {"method": "all ground", "params": {}, "samples": per, "mean": _mean(per)}


def markdown_table(records):
    """The README's table of ``records`` (method -> log record): a row per method, best mean total
    error first (in bold), then the row of every point ground."""
    recs = sorted(records.values(), key=lambda r: r["mean"]["total"])
    names = list(dict.fromkeys(s for r in recs for s in r["samples"]))
    f2 = lambda v: "-" if v is None else f"{v:.2f}"  # noqa: E731
    out = ["| method | " + " | ".join(names) + " | mean | Type I | Type II | kappa |",
           "|---|" + "---|" * (len(names) + 4)]
    for r in recs:
        m = r["mean"]
        out.append(f"| {README_LABELS.get(r['method'], r['method'])} | "
                   + " | ".join(f2(r["samples"].get(s, {}).get("total")) for s in names)
                   + f" | **{m['total']:.2f}** | {m['type1']:.2f} | {m['type2']:.2f} | {m['kappa']:.2f} |")
    base = baseline_from_record(recs[0])
    out.append("| every point ground | " + " | ".join(f2(base["samples"].get(s, {}).get("total")) for s in names)
               + f" | {base['mean']['total']:.2f} | 0 | 100 | 0 |")
    return "\n".join(out) + "\n"


def write_readme(text, path=None):
    """Replace the table between the ISPRS markers of README.md (or of ``path``) with ``text``; the
    markers must be there (under "ISPRS filter test"), the rest of the file stays as it is."""
    replace_block(README if path is None else path, MARK_BEGIN, MARK_END, text)


def git_commit():
    """The repo's HEAD commit (None outside git)."""
    try:
        out = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True,
                             text=True, timeout=10)
        return out.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def uncommitted_files():
    """Files under core/ and benchmarks/ that differ from the commit (None outside git).

    Recorded with the figures: a commit alone does not say what ran when the working
    tree had changes.
    """
    try:
        out = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--",
                              "core", "benchmarks/isprs.py"], capture_output=True, text=True,
                             timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    if out.returncode != 0:
        return None
    return sorted(line[3:].strip() for line in out.stdout.splitlines() if line.strip())


def append_jsonl(result, path=RESULTS, data_dir=None):
    """Append one JSON line for one method's run to ``path`` (created when missing)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    record = {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
              "commit": git_commit(), "uncommitted": uncommitted_files(),
              "protocol": protocol(),
              "data": None if data_dir is None else str(data_dir)}
    record.update(result)
    with open(path, "a", encoding="utf-8") as fh:
        fh.write(json.dumps(record, allow_nan=False, default=str) + "\n")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=None,
                    help="data folder holding isprs/samp*.txt (default $BARE_EARTH_DATA "
                         "or <repo>/../shared/data)")
    ap.add_argument("--methods", default=None,
                    help="comma-separated method names (default: every registered method)")
    ap.add_argument("--out", type=Path, default=RESULTS, help=f"JSON-lines log (default {RESULTS})")
    ap.add_argument("--no-log", action="store_true", help="do not append to the log")
    ap.add_argument("--report", type=Path, default=None, help="also write an HTML report")
    ap.add_argument("--from-log", action="store_true",
                    help="print the README's table from the log (each method's newest record by this "
                         "protocol with defaults) instead of running")
    ap.add_argument("--readme", action="store_true",
                    help=f"replace the table between {MARK_BEGIN} and {MARK_END} in README.md with the log's")
    args = ap.parse_args(argv)
    wanted = [m.strip() for m in args.methods.split(",") if m.strip()] if args.methods else None
    if args.readme and args.no_log and not args.from_log:
        ap.error("--readme writes the log's figures: drop --no-log (the run is then logged first) or add --from-log")
    if args.from_log:
        return from_log(args.out, wanted, args.readme)

    data = args.data if args.data is not None else default_data_dir()
    folder = data / "isprs" if (data / "isprs").is_dir() else data
    if not data.is_dir() or not list(folder.glob("samp*.txt")):
        print(f"ISPRS benchmark skipped: no samp*.txt under {data} (pass --data or set "
              "BARE_EARTH_DATA).")
        return 0
    samples = load_samples(folder)
    print(f"ISPRS filter test: {len(samples)} samples from {folder} "
          f"({sum(len(c) for c in samples.values()):,} points)")

    if wanted:
        names = wanted
    else:
        from bare_earth.core.methods import available_methods
        names = list(available_methods())
    base = baseline(samples)
    results, failed, maps = {}, {}, {}
    for name in names:
        try:
            results[name] = evaluate_method(name, samples, maps=maps.setdefault(name, {}))
        except Exception as exc:  # one broken method must not hide the others' figures
            failed[name] = f"{type(exc).__name__}: {exc}"
            print(f"method {name}: FAILED ({failed[name]})", file=sys.stderr)
            continue
        if not args.no_log:
            append_jsonl(results[name], args.out, data_dir=folder)
    if not names:
        print("no filter method is registered yet; only the baseline is shown.")
    print()
    print(format_table(results, base))
    for name, r in results.items():
        print(f"{name}: {r['seconds']:.1f} s")
    if results and not args.no_log:
        print(f"appended {len(results)} line(s) to {args.out}")
    if args.report is not None:
        from bare_earth.core.evaluate import write_report
        rows = {}
        for label, r in list(results.items()) + [("all ground", base)]:
            for s, f in list(r["samples"].items()) + [("mean", r["mean"])]:
                rows[f"{label} / {s}"] = {k: v for k, v in f.items() if k != "info"}
        emaps = {f"{m} / {s}": codes for m in results for s, (codes, _) in maps[m].items()}
        gts = {f"{m} / {s}": gt for m in results for s, (_, gt) in maps[m].items()}
        write_report(rows, html_path=args.report, error_map=emaps or None, geotransform=gts,
                     title="ISPRS filter test (Sithole & Vosselman 2004 protocol)")
        print(f"report: {args.report}")
    if args.readme and results:
        from_log(args.out, None, True)
    return 1 if failed and not results else 0


def from_log(path=RESULTS, methods=None, readme=False):
    """Print (and with ``readme`` write into README.md) the table of the log's newest records."""
    records = latest_records(path, methods)
    text = markdown_table(records)
    print(f"ISPRS filter test from {path}: " + ", ".join(
        f"{m} {str(r.get('commit'))[:8]} {str(r.get('date'))[:10]}" for m, r in records.items()))
    print()
    print(text)
    if readme:
        write_readme(text)
        print(f"README table rewritten ({README})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
