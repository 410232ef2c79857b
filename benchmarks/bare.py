#!/usr/bin/env python3
"""Bare terrain (issue 12, ``core.synthetic_bare``): the share of ground each filter loses.

Usage::

    .venv/bin/python benchmarks/bare.py [--methods a,b] [--only REGEX] [--cells 0.5,1,2,4] [--seed N]

Rows ``<scene>/<cell>m``: each scene of :data:`~bare_earth.core.synthetic_bare.BARE` (400 m square,
no objects) at 0.5, 1, 2 and 4 m cells. Figures: the per cent of cells a filter does not call
ground (objects and low outliers: every such cell is a Type I error), defaults only; then each
filter's mean and worst row. Prints only: nothing is appended to ``benchmarks/results``.
"""
import argparse
import re
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import setup_path  # noqa: E402

setup_path()
import numpy as np  # noqa: E402

from bare_earth.core.codes import GROUND  # noqa: E402
from bare_earth.core.pipeline import run_array  # noqa: E402
from bare_earth.core.synthetic_bare import BARE, make_bare  # noqa: E402

METHODS = ("dtm", "geodesic", "curvature", "rascor", "slopeprofile", "morphological")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--only", default=None, help="regular expression on the row names")
    ap.add_argument("--cells", default="0.5,1,2,4")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    methods = a.methods.split(",")
    print(f"{'row':<16}" + "".join(f"{m[:9]:>10}" for m in methods))
    totals = {m: [] for m in methods}
    for kind in BARE:
        for cell in (float(c) for c in a.cells.split(",")):
            name = f"{kind}/{cell:g}m"
            if a.only and not re.search(a.only, name):
                continue
            s = make_bare(kind, cell, seed=a.seed)
            line, t0 = f"{name:<16}", time.perf_counter()
            for m in methods:
                res = run_array(m, s.dsm, s.cell_size, {}, want_dtm=False)
                lost = 100.0 * np.count_nonzero(np.asarray(res.mask) != GROUND) / res.mask.size
                totals[m].append((lost, name))
                line += f"{lost:>10.2f}"
            print(line + f"   {time.perf_counter() - t0:.1f} s", flush=True)
    if not any(totals.values()):
        return
    print(f"{'mean':<16}" + "".join(f"{np.mean([t for t, _ in totals[m]]):>10.2f}" for m in methods))
    for m in methods:
        worst = max(totals[m])
        print(f"  {m}: worst {worst[0]:.2f} ({worst[1]})")


if __name__ == "__main__":
    main()
