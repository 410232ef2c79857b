"""Benchmark of the morphological filter (issue 7): ISPRS accuracy of both forms and speed.

1. The seven ISPRS reference samples under the benchmark protocol of ``benchmarks/isprs.py``
   (lowest point per 1 m cell, the filter with its defaults, the filled DTM, every point
   classified with 0.5 m + 1.25 x slope): Type I / II / total error and kappa per sample
   for the progressive form (``mode="progressive"``), the single-window 1996 form
   (``mode="single"``) and the default (``mode="auto"``).
2. Speed of :func:`core.morphology.filter_morphological` (the filter alone, one pass,
   parameters given so that no data-derived default is computed) on a synthetic
   ``side x side`` DSM at 1 m cells (default 4096: ~16.8 Mcells) with a 41 m largest
   window, and of the data-derived defaults (:func:`resolve_morphological_params`)::

    /usr/bin/python3 benchmarks/morphological.py [--data DIR] [--side 4096] [--no-isprs]
                                                 [--no-speed] [--growth 2]

Not a test: figures depend on the machine and its load. Data: Sithole & Vosselman (2004),
ISPRS J. Photogramm. Remote Sens. 59(1-2):85-101 (see ``isprs/provenance``).
"""
import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

import isprs  # noqa: E402  (links the repo as the package bare_earth)

from bare_earth.core.morphology import filter_morphological, resolve_morphological_params  # noqa: E402


def scene(side, seed=1):
    """Rolling terrain (5 cm noise, slopes up to ~0.15) with ``side^2 / 40000`` box
    buildings 3-15 m high, 8-35 m wide, and a few low blunders."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:side, 0:side].astype(np.float32)
    z = 20 * np.sin(x / 300) + 15 * np.cos(y / 400) + rng.normal(0, 0.05, (side, side))
    z = z.astype(np.float32)
    for _ in range(max(1, side * side // 40000)):
        r0, c0 = rng.integers(0, side - 40, 2)
        h, w = rng.integers(8, 35, 2)
        z[r0:r0 + h, c0:c0 + w] += rng.uniform(3, 15)
    idx = rng.integers(0, side, (2, max(1, side * side // 100000)))
    z[idx[0], idx[1]] -= 10.0
    return z


def run_isprs(data):
    folder = data / "isprs" if (data / "isprs").is_dir() else data
    if not folder.is_dir() or not list(folder.glob("samp*.txt")):
        print(f"ISPRS part skipped: no samp*.txt under {data} (pass --data or set BARE_EARTH_DATA).")
        return
    samples = isprs.load_samples(folder)
    results = {}
    for mode in ("progressive", "single", "auto"):
        r = isprs.evaluate_method("morphological", samples, params={"mode": mode})
        r["method"] = f"morphological/{mode}"
        results[mode] = r
    print(isprs.format_table(results, isprs.baseline(samples)))
    print("Parameters derived per sample (progressive run):")
    for s, r in results["progressive"]["samples"].items():
        i = r.get("info", {})
        print(f"  {s}: dh {i.get('dh_m', float('nan')):.2f} m, slope {i.get('slope', float('nan')):.3f}, "
              f"largest object {i.get('max_object_size_m', float('nan')):.1f} m, "
              f"noise {i.get('noise_m', float('nan')):.3f} m")
    print("Auto mode per sample:",
          ", ".join(f"{s}: {r.get('info', {}).get('mode')}" for s, r in results["auto"]["samples"].items()))


def run_speed(side, growth, repeat):
    z = scene(side)
    print(f"\nSpeed on a {side} x {side} DSM ({z.size / 1e6:.1f} Mcells, 1 m cells), "
          f"largest window 41 m, window_growth {growth}:")
    for mode in ("progressive", "single"):
        best = float("inf")
        for _ in range(repeat):
            t0 = time.perf_counter()
            res = filter_morphological(z, 1.0, mode=mode, max_object_size_m=41.0, dh_m=0.5, slope=0.3,
                                       window_growth=growth)
            best = min(best, time.perf_counter() - t0)
        print(f"  {mode:<12} {best:6.2f} s  {z.size / best / 1e6:6.2f} Mcells/s  "
              f"windows {res.info['window_sizes_m']}")
    t0 = time.perf_counter()
    p = resolve_morphological_params(z, 1.0)
    dt = time.perf_counter() - t0
    print(f"  defaults     {dt:6.2f} s  (mode {p['mode']}, dh {p['dh_m']:.2f} m, slope {p['slope']:.3f}, "
          f"largest object {p['max_object_size_m']:.1f} m)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=None, help="data folder (default $BARE_EARTH_DATA "
                    "or <repo>/../shared/data)")
    ap.add_argument("--side", type=int, default=4096, help="side of the speed DSM in cells")
    ap.add_argument("--growth", type=float, default=2.0, help="window_growth of the speed run")
    ap.add_argument("--repeat", type=int, default=1, help="speed runs (the best is printed)")
    ap.add_argument("--no-isprs", action="store_true")
    ap.add_argument("--no-speed", action="store_true")
    args = ap.parse_args(argv)
    if not args.no_isprs:
        run_isprs(args.data if args.data is not None else isprs.default_data_dir())
    if not args.no_speed:
        run_speed(args.side, args.growth, args.repeat)
    return 0


if __name__ == "__main__":
    sys.exit(main())
