#!/usr/bin/env python3
"""bareearth:dtm (issue 13): the ISPRS protocol, the generalisation matrix, and the confidence table.

Usage::

    .venv/bin/python benchmarks/dtm.py [--data DIR] [--members] [--no-matrix] [--no-log]

1. **ISPRS** (the protocol of :mod:`isprs`, its functions reused): total error per sample and
   the mean, for ``dtm`` (and its members with ``--members``).
2. **Generalisation matrix** (:mod:`generalise`'s ``run_matrix`` and summary, when that script
   is present): every input with truth, the mean of its two fixed halves, the worst row and
   the opengeos RMSE.
3. **Confidence table**: does the confidence mean something? For each input with truth, the
   items (ISPRS points, or cells of the synthetic scenes and of opengeos) in three bands of
   confidence, < 50, 50-79 and >= 80: their share, their error rate (per cent wrongly classed)
   and their share of all errors. The confidence is read at each point's cell; a point is wrong
   when the protocol's classification by the DTM disagrees with its class; a cell when the
   mask disagrees with the truth (opengeos: true ground = within 0.5 m + 1.25 slope of the
   reference DTM, as in :mod:`generalise`).

Results are appended to ``benchmarks/results/dtm.jsonl``. Data: ``--data``, else env
``BARE_EARTH_DATA``, else ``<repo>/../shared/data``; ISPRS: Sithole & Vosselman (2004) as
redistributed by PDAL; opengeos/data.
"""
import argparse
import datetime
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import isprs  # noqa: E402  (its bootstrap makes ``import bare_earth`` work)
import numpy as np  # noqa: E402

from bare_earth.core.pipeline import run_array  # noqa: E402
from bare_earth.core.points import classify_points, rasterize_points  # noqa: E402

RESULTS = isprs.ROOT / "benchmarks" / "results" / "dtm.jsonl"
BANDS = ((0, 50, "< 50"), (50, 80, "50-79"), (80, 101, ">= 80"))
MEMBERS = ("morphological", "rascor", "geodesic")


def confidence_rows(conf, wrong):
    """``[{band, n, share, error_percent, errors_share}]`` of items with confidence ``conf`` and
    error flags ``wrong`` (1-D arrays of the same length)."""
    conf = np.asarray(conf).astype(int)
    wrong = np.asarray(wrong, bool)
    n_all, e_all = max(1, conf.size), max(1, int(wrong.sum()))
    out = []
    for lo, hi, name in BANDS:
        sel = (conf >= lo) & (conf < hi)
        n = int(sel.sum())
        e = int(wrong[sel].sum())
        out.append({"band": name, "n": n, "share": 100.0 * n / n_all,
                    "error_percent": 100.0 * e / n if n else None, "errors_share": 100.0 * e / e_all})
    return out


def isprs_confidence(samples):
    """Per ISPRS sample (1 m, lowest point): (confidence at each point's cell, point wrong)."""
    out = {}
    for name, c in samples.items():
        z, gt = rasterize_points(c.x, c.y, c.z, isprs.CELL_SIZE, reducer="min", fill_empty="nearest")
        res = run_array("dtm", z, (isprs.CELL_SIZE, isprs.CELL_SIZE))
        cls = classify_points(c.x, c.y, c.z, res.dtm, gt, threshold_m=isprs.THRESHOLD_M,
                              slope_factor=isprs.SLOPE_FACTOR)
        col = np.clip(((c.x - gt[0]) / gt[1]).astype(int), 0, z.shape[1] - 1)
        row = np.clip(((c.y - gt[3]) / gt[5]).astype(int), 0, z.shape[0] - 1)
        conf = res.extras["confidence"][row, col]
        out[f"isprs/{name}/1m/min"] = (conf, (cls == 0) != (c.classification == 0))
    return out


def synthetic_confidence():
    """Every synthetic scene kind, 1 m, 384 m square, seed 0: (confidence, cell wrong) per cell."""
    from bare_earth.core.synthetic import KINDS, make_scene
    out = {}
    for kind in KINDS:
        s = make_scene(kind, (384, 384), 1.0, seed=0, noise_m=0.05)
        res = run_array("dtm", s.dsm, 1.0)
        valid = s.mask != 255
        out[f"synthetic/{kind}/1m"] = (res.extras["confidence"][valid],
                                       (res.mask[valid] == 0) != (s.mask[valid] == 0))
    return out


def opengeos_confidence(data):
    """The opengeos 2 m lidar DSM against its reference DTM: (confidence, cell wrong) and the RMSE."""
    folder = data / "raster" / "opengeos"
    if not (folder / "dsm.tif").is_file():
        return {}, None
    from bare_earth.core import grid
    info = grid.open_dsm(str(folder / "dsm.tif"))
    z = info.read()
    ref = grid.open_dsm(str(folder / "dtm.tif")).read()
    dx, dy = info.cell_size_m
    gy, gx = np.gradient(np.where(np.isfinite(ref), ref, np.nanmean(ref)).astype(np.float64), dy, dx)
    truth = np.abs(z - ref) <= isprs.THRESHOLD_M + isprs.SLOPE_FACTOR * np.hypot(gx, gy)
    res = run_array("dtm", z, info.cell_size_m)
    valid = np.isfinite(z) & np.isfinite(ref)
    d = (res.dtm - ref)[valid & np.isfinite(res.dtm)]
    rmse = float(np.sqrt(np.mean(d ** 2)))
    return {"opengeos/dsm/2m": (res.extras["confidence"][valid], (res.mask[valid] == 0) != truth[valid])}, rmse


def format_confidence(table):
    lines = [f"{'input':<26}" + "".join(f"{'conf ' + b[2]:>26}" for b in BANDS),
             f"{'':<26}" + "".join(f"{'share  err %  errors':>26}" for _ in BANDS), "-" * 104]
    for name, rows in table.items():
        cells = []
        for r in rows:
            err = "-" if r["error_percent"] is None else f"{r['error_percent']:.2f}"
            cells.append(f"{r['share']:>9.1f} {err:>7} {r['errors_share']:>7.1f}")
        lines.append(f"{name:<26}" + "".join(f"{c:>26}" for c in cells))
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=None)
    ap.add_argument("--members", action="store_true", help="also run the members alone on the ISPRS samples")
    ap.add_argument("--no-matrix", action="store_true", help="skip the generalisation matrix")
    ap.add_argument("--no-log", action="store_true", help=f"do not append to {RESULTS}")
    args = ap.parse_args(argv)
    data = Path(args.data or isprs.default_data_dir())
    record = {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
              "commit": isprs.git_commit(), "uncommitted": isprs.uncommitted_files(), "data": str(data)}
    t0 = time.perf_counter()
    samples = isprs.load_samples(data / "isprs") if (data / "isprs").is_dir() else {}
    if samples:
        print("ISPRS, 1 m lowest point, the protocol of benchmarks/isprs.py (total error %):")
        names = ("dtm",) + (MEMBERS if args.members else ())
        res = {m: isprs.evaluate_method(m, samples) for m in names}
        print(f"  {'sample':<10}" + "".join(f"{m:>15}" for m in names))
        for s in samples:
            print(f"  {s:<10}" + "".join(f"{res[m]['samples'][s]['total']:>15.2f}" for m in names))
        print(f"  {'mean':<10}" + "".join(f"{res[m]['mean']['total']:>15.2f}" for m in names))
        record["isprs"] = {m: {"mean": r["mean"], "totals": {s: v["total"] for s, v in r["samples"].items()}}
                           for m, r in res.items()}
    if not args.no_matrix:
        try:
            import generalise
        except ImportError:
            generalise = None
            print("\nbenchmarks/generalise.py is not in this tree: no matrix.")
        if generalise is not None:
            print("\nGeneralisation matrix (benchmarks/generalise.py's rows), dtm:")
            rows, _ = generalise.run_matrix(data, ["dtm"])
            summary = generalise.summarise(rows, ["dtm"])
            print(generalise.format_summary(summary, ["dtm"]))
            record["matrix"] = {"summary": summary, "rows": {r["row"]: r["filters"]["dtm"].get("total")
                                                             for r in rows}}
    print("\nConfidence table: share of items (%), their error rate (%), their share of all errors (%)")
    items = {}
    if samples:
        items.update(isprs_confidence(samples))
    items.update(synthetic_confidence())
    og, rmse = opengeos_confidence(data)
    items.update(og)
    table = {k: confidence_rows(c, w) for k, (c, w) in items.items()}
    allc = np.concatenate([c for c, _ in items.values()])
    allw = np.concatenate([w for _, w in items.values()])
    table["all items"] = confidence_rows(allc, allw)
    print(format_confidence(table))
    if rmse is not None:
        print(f"\nopengeos: DTM RMSE against the reference {rmse:.2f} m")
        record["opengeos_rmse_m"] = rmse
    record["confidence"] = table
    record["seconds"] = round(time.perf_counter() - t0, 1)
    if not args.no_log:
        RESULTS.parent.mkdir(parents=True, exist_ok=True)
        with open(RESULTS, "a", encoding="utf-8") as f:
            f.write(json.dumps(record) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
