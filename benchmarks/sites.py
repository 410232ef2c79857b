#!/usr/bin/env python3
"""The held-out-like sites of ``core.synthetic_sites`` (issue 13): every filter, defaults only.

Usage::

    .venv/bin/python benchmarks/sites.py [--methods a,b] [--only REGEX] [--seed N] [--maps DIR]

Rows ``<site>/<cell>m/<min|max>``: each site of :data:`~bare_earth.core.synthetic_sites.SITES`
(320 m square, the city 480 m; 1.2 points per m2, ``sparse`` 0.16; seed 0) at 1 and 2 m cells, lowest point
per cell (lidar) and highest point per cell (image matching). Figures: total error per cell against the site's truth
mask (per cent), then the mean and the worst row of each filter, and the DTM RMSE of ``dtm``.
``--maps DIR`` writes each row's error codes of the first method as ``.npy`` (1 type I, 2 type II).
``--steps``: with ``rascor`` among the methods, each row's RASCOR Type I and Type II cells (per cent
of the row's cells) by the step whose removal (or keeping, 0) made them, from its ``step`` band:
which of Jacobsen's steps takes the site's ground, or keeps its objects.
Prints only: nothing is appended to ``benchmarks/results``.
"""
import argparse
import re
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import isprs  # noqa: E402,F401  (its bootstrap makes ``import bare_earth`` work)
import numpy as np  # noqa: E402

from bare_earth.core.evaluate import compare_dtm, compare_masks  # noqa: E402
from bare_earth.core.pipeline import run_array  # noqa: E402
from bare_earth.core.synthetic_sites import SITES, make_site  # noqa: E402

METHODS = ("dtm", "slopeprofile", "curvature", "rascor", "geodesic", "morphological")


def errors_by_step(mask, truth, step):
    """``T1 {step: %} T2 {step: %}``: the Type I cells (ground called object or low) and the
    Type II cells (objects called ground) of a RASCOR ``mask`` against ``truth``, in per cent of
    the valid cells, by the step that removed each (0: kept)."""
    valid = mask != 255
    n = max(1, int(np.count_nonzero(valid)))
    t1 = valid & (mask != 0) & (truth == 0)
    t2 = valid & (mask == 0) & (truth != 0)
    out = []
    for tag, err in (("T1", t1), ("T2", t2)):
        counts = np.bincount(step[err].astype(np.int64), minlength=8)
        out.append(tag + " {" + ", ".join(f"{k}: {100.0 * c / n:.2f}" for k, c in enumerate(counts) if c) + "}")
    return " ".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--only", default=None, help="regular expression on the row names")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--maps", default=None)
    ap.add_argument("--steps", action="store_true", help="RASCOR's Type I / II cells by step")
    a = ap.parse_args(argv)
    methods = a.methods.split(",")
    print(f"{'row':<22}" + "".join(f"{m[:9]:>10}" for m in methods) + "   dtm rmse")
    totals = {m: [] for m in methods}
    for kind in SITES:
        for cell in (1.0, 2.0):
            for surface, tag in (("lowest", "min"), ("highest", "max")):
                name = f"{kind}/{cell:g}m/{tag}"
                if a.only and not re.search(a.only, name):
                    continue
                s = make_site(kind, cell, surface, seed=a.seed)
                line, rmse, t0 = f"{name:<22}", "", time.perf_counter()
                by_step = None
                for i, m in enumerate(methods):
                    res = run_array(m, s.dsm, s.cell_size, {})
                    c = compare_masks(res.mask, s.mask)
                    totals[m].append((c["total"], name))
                    line += f"{c['total']:>10.2f}"
                    if m == "rascor" and a.steps:
                        by_step = errors_by_step(res.mask, s.mask, res.extras["step"])
                    if m == "dtm":
                        rmse = f"{compare_dtm(res.dtm, s.dtm)['rmse']:>10.2f}"
                    if a.maps and i == 0:
                        d = Path(a.maps)
                        d.mkdir(parents=True, exist_ok=True)
                        err = np.where((res.mask != 0) & (s.mask == 0), 1, 0) + np.where(
                            (res.mask == 0) & (s.mask != 0), 2, 0)
                        np.save(d / (name.replace("/", "_") + ".npy"), err.astype(np.uint8))
                print(line + rmse + f"   {time.perf_counter() - t0:.1f} s", flush=True)
                if a.steps and by_step is not None:
                    print(f"{'':<22}rascor by step: {by_step}", flush=True)
    print(f"{'mean':<22}" + "".join(f"{np.mean([t for t, _ in totals[m]]):>10.2f}" for m in methods))
    for m in methods:
        worst = max(totals[m])
        print(f"  {m}: worst {worst[0]:.2f} ({worst[1]})")


if __name__ == "__main__":
    main()
