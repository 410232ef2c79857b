#!/usr/bin/env python3
"""RASCOR's errors on the ISPRS samples by the step that removed each point's cell.

Usage::

    .venv/bin/python benchmarks/rascor_steps.py [--data DIR] [--samples samp41,samp61]
        [--cells 1,2] [--reducers min,max] [--params '{"surface_sigma_m": 1.0}']

Per sample, cell size and reducer (the rows of ``benchmarks/generalise.py``): RASCOR with
its defaults (or ``--params``) through ``pipeline.run_array``, the points classified by the
ISPRS protocol (:mod:`isprs`: 0.5 m + 1.25 x slope from the filled DTM), then

* the total, Type I and Type II error (percent) and the resolved step-6 scale and size;
* the Type I points (ground called object) by the step that removed their cell (0: kept,
  which the filled DTM still misses on a slope), and the Type II points (object called
  ground) by the same.

A Type I point whose cell a step removed is not always that step's fault: a removed cell
is filled from the ground around it, and a later step that removes that ground (step 6 on
a raised road) lowers the fill of every removed cell near it. Compare two runs
(``--params``) to see which step's change moves the counts. It prints figures; it never
appends to a log. Cite the data's sources (``isprs/provenance``) with any figure.

``--rows REGEX`` instead runs the rows of ``benchmarks/generalise.py`` whose name matches (any
family: ISPRS, classified lidar, opengeos, synthetic) and prints, per row, the share of cells each
step removed and the total / Type I / Type II error with that step's removals given back (the
mask's cells of step k set to ground, the DTM filled again): the step whose undoing lowers the
Type I error most is the one deciding the row's lost ground.
"""
import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import data_dir, setup_path  # noqa: E402

setup_path()

import isprs  # noqa: E402
import numpy as np  # noqa: E402

from bare_earth.core.evaluate import confusion  # noqa: E402
from bare_earth.core.pipeline import run_array  # noqa: E402
from bare_earth.core.points import classify_points, rasterize_points  # noqa: E402
from bare_earth.core.rascor import resolve_rascor_params  # noqa: E402

STEPS = range(0, 8)


def point_cells(x, y, gt, shape):
    """Row and column of each point's cell in the grid of ``gt`` (clipped to ``shape``)."""
    col = np.floor((np.asarray(x) - gt[0]) / gt[1]).astype(np.int64)
    row = np.floor((np.asarray(y) - gt[3]) / gt[5]).astype(np.int64)
    return np.clip(row, 0, shape[0] - 1), np.clip(col, 0, shape[1] - 1)


def by_step(cloud, cell, reducer, params):
    """The figures of one row: errors, the resolved step-6 values and the errors by step."""
    z, gt = rasterize_points(cloud.x, cloud.y, cloud.z, cell, reducer=reducer, fill_empty="nearest")
    res = run_array("rascor", z, cell_size=(cell, cell), params=dict(params))
    cls = classify_points(cloud.x, cloud.y, cloud.z, np.asarray(res.dtm, np.float32), gt,
                          threshold_m=isprs.THRESHOLD_M, slope_factor=isprs.SLOPE_FACTOR)
    truth = cloud.classification == 0
    r = confusion(cls == 0, truth)
    step = res.extras["step"][point_cells(cloud.x, cloud.y, gt, z.shape)]
    t1, t2 = truth & (cls != 0), ~truth & (cls == 0)
    p = resolve_rascor_params(z, (cell, cell), **params)
    return {"total": r["total"], "type1": r["type1"], "type2": r["type2"],
            "surface_size_m": p["surface_size_m"], "surface_sigma_m": p["surface_sigma_m"],
            "type1_by_step": [int(np.count_nonzero(t1 & (step == k))) for k in STEPS],
            "type2_by_step": [int(np.count_nonzero(t2 & (step == k))) for k in STEPS]}


def undo_steps(data, pattern, params):
    """Per matching row of the generalisation matrix: each step's share of the cells and the
    errors with that step's removals given back (see the module docstring)."""
    import re

    import generalise

    from bare_earth.core.pipeline import fill_dtm
    for _src, _fam, _half, rows in generalise.all_cases(data, []):
        for name, build in rows:
            if not re.search(pattern, name):
                continue
            z, cell, score = build()
            res = run_array("rascor", z, cell, dict(params))
            base = score(res)
            step = res.extras["step"]
            shares = res.info["removed_share_by_step"]
            print(f"{name}: total {base['total']:.2f} T1 {base['type1']:.2f} T2 {base['type2']:.2f}; removed % "
                  + " ".join(f"{k.split()[0]}:{100 * v:.2f}" for k, v in shares.items() if v), flush=True)
            for k in range(2, 8):
                sel = (step == k) & (res.mask != 255)
                if not sel.any():
                    continue
                mask = res.mask.copy()
                mask[sel] = 0
                r = score(type("R", (), {"dtm": fill_dtm(np.asarray(z, np.float32), mask), "mask": mask}))
                print(f"  step {k} given back: total {r['total']:.2f} T1 {r['type1']:.2f} T2 {r['type2']:.2f}",
                      flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", help="data folder (default $BARE_EARTH_DATA or ../shared/data)")
    ap.add_argument("--samples", help="comma-separated sample names (default: every one)")
    ap.add_argument("--cells", default="1,2", help="cell sizes in metres (default 1,2)")
    ap.add_argument("--reducers", default="min,max", help="min, max or both (default min,max)")
    ap.add_argument("--params", default="{}", help="RASCOR parameters as JSON (default: defaults)")
    ap.add_argument("--rows", help="regular expression: rows of benchmarks/generalise.py, each step given back")
    a = ap.parse_args(argv)
    if a.rows:
        undo_steps(data_dir(a.data), a.rows, json.loads(a.params))
        return 0
    folder = data_dir(a.data) / "isprs"
    if not folder.is_dir():
        print(f"no ISPRS samples under {folder}; nothing to do")
        return 0
    samples = isprs.load_samples(folder)
    if a.samples:
        samples = {k: v for k, v in samples.items() if k in a.samples.split(",")}
    params = json.loads(a.params)
    head = " ".join(f"{k:>5d}" for k in STEPS)
    print(f"{'row':22s} {'total':>6s} {'T1':>6s} {'T2':>6s} {'S6 m':>5s} {'s6 m':>6s}  "
          f"T1 points by step {head}   T2 points by step {head}")
    totals = []
    for name, cloud in samples.items():
        for cell in (float(c) for c in a.cells.split(",")):
            for red in a.reducers.split(","):
                f = by_step(cloud, cell, red, params)
                totals.append(f["total"])
                print(f"{name}/{cell:g}m/{red:18s}"[:22].ljust(22)
                      + f" {f['total']:6.2f} {f['type1']:6.2f} {f['type2']:6.2f} {f['surface_size_m']:5g}"
                      f" {f['surface_sigma_m']:6.3f}  {'':17s} "
                      + " ".join(f"{v:5d}" for v in f["type1_by_step"]) + f"   {'':17s} "
                      + " ".join(f"{v:5d}" for v in f["type2_by_step"]), flush=True)
    if totals:
        print(f"mean total error {np.mean(totals):.2f} % over {len(totals)} rows")
    return 0


if __name__ == "__main__":
    sys.exit(main())
