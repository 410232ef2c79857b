#!/usr/bin/env python3
"""The held-out-like sites of ``core.synthetic_sites`` (issue 13): every filter, defaults only.

Usage::

    .venv/bin/python benchmarks/sites.py [--methods a,b] [--only REGEX] [--seed N] [--maps DIR]

Rows ``<site>/<cell>m/<min|max>``: each site of :data:`~bare_earth.core.synthetic_sites.SITES`
(320 m square, the city 480 m; 1.2 points per m2, seed 0) at 1 and 2 m cells, lowest point per cell (lidar) and
highest point per cell (image matching). Figures: total error per cell against the site's truth
mask (per cent), then the mean and the worst row of each filter, and the DTM RMSE of ``dtm``.
``--maps DIR`` writes each row's error codes of the first method as ``.npy`` (1 type I, 2 type II).
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


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--only", default=None, help="regular expression on the row names")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--maps", default=None)
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
                for i, m in enumerate(methods):
                    res = run_array(m, s.dsm, s.cell_size, {})
                    c = compare_masks(res.mask, s.mask)
                    totals[m].append((c["total"], name))
                    line += f"{c['total']:>10.2f}"
                    if m == "dtm":
                        rmse = f"{compare_dtm(res.dtm, s.dtm)['rmse']:>10.2f}"
                    if a.maps and i == 0:
                        d = Path(a.maps)
                        d.mkdir(parents=True, exist_ok=True)
                        err = np.where((res.mask != 0) & (s.mask == 0), 1, 0) + np.where(
                            (res.mask == 0) & (s.mask != 0), 2, 0)
                        np.save(d / (name.replace("/", "_") + ".npy"), err.astype(np.uint8))
                print(line + rmse + f"   {time.perf_counter() - t0:.1f} s", flush=True)
    print(f"{'mean':<22}" + "".join(f"{np.mean([t for t, _ in totals[m]]):>10.2f}" for m in methods))
    for m in methods:
        worst = max(totals[m])
        print(f"  {m}: worst {worst[0]:.2f} ({worst[1]})")


if __name__ == "__main__":
    main()
