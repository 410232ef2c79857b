"""The orthophoto matcher on its own: Middlebury 2003 "Cones" (rectified pair, true disparity).

Runs :func:`core.orthophoto.match.match_rectified` (normalised cross-correlation from box
filters, shiftable windows, left-right check, parabola sub-pixel; the matcher of the
orthophoto refinement of Luong Chinh Ke 2002 section 2.3 and Norvelle 1995) and prints the
share of non-occluded pixels with known disparity whose estimate is within 1 pixel of the
truth. Pixels the matcher rejects (left-right check, correlation threshold) count as wrong.

    /usr/bin/python3 benchmarks/ortho_middlebury.py [--data DIR] [--window 7] [--shiftable 5]

Data: ``stereo/middlebury_cones`` under ``$BARE_EARTH_DATA`` (default ``../shared/data``);
Scharstein & Szeliski (CVPR 2003), as redistributed by CNES Pandora. Skips when absent.
"""
import argparse
import sys
import time

import numpy as np
from _common import data_dir, setup_path

setup_path()
from bare_earth.core.orthophoto.match import match_rectified  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None)
    ap.add_argument("--window", type=int, default=7)
    ap.add_argument("--shiftable", type=int, default=5)
    ap.add_argument("--min-corr", type=float, default=0.3)
    ap.add_argument("--dmax", type=int, default=60)
    a = ap.parse_args(argv)
    d = data_dir(a.data) / "stereo" / "middlebury_cones"
    if not d.is_dir():
        print(f"SKIP: {d} is absent (set BARE_EARTH_DATA)")
        return 0
    from osgeo import gdal
    read = lambda n: gdal.Open(str(d / n)).ReadAsArray()  # noqa: E731
    left = read("Cones_LEFT.tif").astype(np.float32)
    right = read("Cones_RIGHT.tif").astype(np.float32)
    gt = read("Cones_LEFT_GT.tif").astype(np.float32)
    nocc = read("Occlusion_LEFT.png") > 0
    t = time.perf_counter()
    r = match_rectified(left, right, 0, a.dmax, window=a.window, shiftable=a.shiftable,
                        min_corr=a.min_corr)
    dt = time.perf_counter() - t
    m = (gt > 0) & nocc
    err = np.abs(r.disparity - gt)
    within1 = float((err <= 1)[m].mean())
    matched = float(r.valid[m].mean())
    print(f"Middlebury Cones {left.shape[1]}x{left.shape[0]}, disparities 0..{a.dmax}, "
          f"window {a.window}, shiftable {a.shiftable}, min_corr {a.min_corr}")
    print(f"  non-occluded pixels with known disparity: {int(m.sum())}")
    print(f"  within 1 px of the truth (unmatched count as wrong): {100 * within1:.1f} %  (target >= 75 %)")
    print(f"  matched (left-right check + threshold): {100 * matched:.1f} %; "
          f"within 1 px among matched: {100 * float((err <= 1)[m & r.valid].mean()):.1f} %")
    print(f"  within 2 px: {100 * float((err <= 2)[m].mean()):.1f} %; "
          f"median |error| of matched: {float(np.median(err[m & r.valid])):.2f} px")
    print(f"  time {dt:.2f} s")
    return 0 if within1 >= 0.75 else 1


if __name__ == "__main__":
    sys.exit(main())
