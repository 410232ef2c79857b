#!/usr/bin/env python3
"""Classified LiDAR benchmark: points -> DSM -> filter -> classified points, against the
files' own ground class; and the point throughput of rasterize and classify.

Usage::

    .venv/bin/python benchmarks/lidar.py [--data DIR] [--method morphological] [--cell-size M]
                                         [--speed-points N] [--json FILE]

(laspy, and lazrs for LAZ, must be importable: the project's ``.venv`` has them.)

Protocol, for each ``<data>/lidar/*.las|*.laz`` with ASPRS classes:

1. read the points (``core.points.read_points``); the CRS comes from the LAS header, and its
   units (feet, US survey feet) are converted: the cell size, thresholds and slopes are in
   metres (``core.pointflow``);
2. rasterize the lowest point per cell, cell size from the point density
   (``pointflow.default_cell_size_m``: about one point per cell, rounded to 1, 2, 2.5 or
   5 x 10^k m, at most 1 m while 1 m keeps a point per 16 cells) unless ``--cell-size``;
   empty cells from the nearest;
3. run the filter with its defaults (``pipeline.run_array``, parameters derived from the
   data);
4. classify every point against the DTM (|z - DTM| <= 0.5 m + 1.25 x slope: ground; on
   cells coarser than 1 m the factor grows by (cell - 1 m) / sqrt(12), ``pointflow.cell_slope_factor``);
5. compare with the file's classes: truth ground = ASPRS class 2; truth object = every
   other class except those with no surface meaning here, which are left out and counted:
   0 (never classified), 7 (low noise), 12 (overlap), 18 (high noise). Type I, Type II,
   total error and Cohen's kappa in percent (Sithole & Vosselman 2004).
   Diagnostic column ``obj~gnd %``: the share of the truth's object points lying within
   0.5 m of the truth's own ground surface (ground points, mean per 2 m cell, gaps filled):
   a point rule with a 0.5 m tolerance takes those as ground whatever the filter does, so
   a high value means the reference's ground class is not exhaustive (e.g. decimated),
   and Type II is bounded below by about that much.

Files without a class 2 point, or that cannot be read, are skipped with a note. Then the
throughput of rasterize and classify (core functions, no file I/O) on a synthetic cloud of
``--speed-points`` points (default 4 million) and on each file.

Data: ``--data``, else env ``BARE_EARTH_DATA``, else ``<repo>/../shared/data``; when the
folder is absent the script says so and exits 0. The files are PDAL's and lidR's test data
(see ``lidar/PROVENANCE_*.md``); cite them with any figure.
"""
import argparse
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: ASPRS classes left out of the evaluation (no ground/object meaning).
EXCLUDED = (0, 7, 12, 18)
GROUND_CLASS = 2


sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import setup_path  # noqa: E402

setup_path()

import numpy as np  # noqa: E402

from bare_earth.core import pointflow as pf  # noqa: E402
from bare_earth.core.evaluate import confusion  # noqa: E402
from bare_earth.core.points import PointCloud, read_points  # noqa: E402


def default_data_dir():
    return Path(os.environ.get("BARE_EARTH_DATA", ROOT.parent / "shared" / "data"))


def reference_near_ground(cloud, tolerance_m=0.5, cell_m=2.0):
    """Share (percent) of the truth's object points within ``tolerance_m`` of the truth's
    ground surface (ground points' mean per ``cell_m`` cell, gaps filled harmonically)."""
    from bare_earth.core.fill import fill_gaps
    from bare_earth.core.points import rasterize_points, sample_bilinear
    cls = cloud.classification
    g = cls == GROUND_CLASS
    obj = ~g & ~np.isin(cls, EXCLUDED)
    if g.sum() < 3 or not obj.any():
        return float("nan")
    sx, sy, sz = pf.axis_scales(cloud)
    z, gt = rasterize_points(cloud.x[g], cloud.y[g], cloud.z[g], (cell_m / sx, cell_m / sy), reducer="mean",
                             fill_empty=None)
    if np.isnan(z).all():
        return float("nan")
    zf = fill_gaps(z.astype(np.float32), fill=np.isnan(z)) if np.isnan(z).any() else z
    h = (cloud.z[obj] - sample_bilinear(zf, gt, cloud.x[obj], cloud.y[obj])) * sz
    return float(100.0 * np.nanmean(np.abs(h) < tolerance_m))


def evaluate_file(path, method="morphological", cell_size_m=None, params=None):
    """Run the protocol on one file. Returns a dict of figures, or ``{"skipped": reason}``."""
    try:
        cloud = read_points(path)
    except (ValueError, ImportError) as exc:
        return {"skipped": f"cannot be read: {exc}"}
    if cloud.classification is None or not (cloud.classification == GROUND_CLASS).any():
        return {"skipped": "no ASPRS class 2 (ground) point: no truth to compare with"}
    unit = pf.unit_name(cloud)
    t0 = time.perf_counter()
    try:
        res = pf.filter_cloud(cloud, method, params, cell_size_m=cell_size_m)
    except ValueError as exc:
        return {"skipped": f"the filter refused it ({len(cloud)} points over "
                           f"{(cloud.extent[2] - cloud.extent[0]):.0f} x {(cloud.extent[3] - cloud.extent[1]):.0f} "
                           f"CRS units ({unit}), cell "
                           f"{pf.default_cell_size_m(cloud) if cell_size_m is None else cell_size_m:g} m): "
                           f"{exc}"}
    seconds = time.perf_counter() - t0
    cls = cloud.classification
    keep = ~np.isin(cls, EXCLUDED) & (res.classes != 255)
    r = confusion(res.classes == 0, cls == GROUND_CLASS, valid=keep)
    info = res.info
    p = info["filter_info"].get("params", {})
    return {
        "points": len(cloud), "evaluated": r["n"], "left_out": int(len(cloud) - r["n"]),
        "unit": unit, "units_to_metre": cloud.units_to_metre, "crs": bool(cloud.crs),
        "cell_size_m": info["cell_size_m"][0], "grid": info["grid_shape"],
        "type1": r["type1"], "type2": r["type2"], "total": r["total"], "kappa": r["kappa"],
        "n_ground": r["n_ground"], "n_object": r["n_object"],
        "object_near_ground": reference_near_ground(cloud),
        "mode": p.get("mode"), "dh_m": p.get("dh_m"), "max_object_size_m": p.get("max_object_size_m"),
        "slope": p.get("slope"),
        "rasterize_Mpts_s": info["rasterize_points_per_s"] / 1e6,
        "classify_Mpts_s": info["classify_points_per_s"] / 1e6, "seconds": seconds,
    }


def speed(n_points=4_000_000, seed=0, repeat=3):
    """Points per second of rasterize (lowest per cell + nearest fill) and classify on a
    synthetic cloud of ``n_points`` over 2 x 2 km (about 1 point per m2)."""
    rng = np.random.default_rng(seed)
    side = float(np.sqrt(n_points))
    x = rng.uniform(0, side, n_points) + 500000.0
    y = rng.uniform(0, side, n_points) + 5400000.0
    z = 100 + 20 * np.sin((x - 500000) / 150.0) * np.cos((y - 5400000) / 200.0) + rng.normal(0, 0.1, n_points)
    tall = rng.random(n_points) < 0.2
    z[tall] += rng.uniform(2, 20, int(tall.sum()))
    cloud = PointCloud(x, y, z, crs="EPSG:32632")
    best_r = best_c = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        g = pf.rasterize_cloud(cloud, 1.0)
        best_r = min(best_r, time.perf_counter() - t0)
        dtm = g.z_metres()
        t0 = time.perf_counter()
        cls = pf.classify_cloud(cloud, dtm, g.geotransform)
        best_c = min(best_c, time.perf_counter() - t0)
    return {"points": n_points, "grid": g.shape, "rasterize_s": best_r, "classify_s": best_c,
            "rasterize_Mpts_s": n_points / best_r / 1e6, "classify_Mpts_s": n_points / best_c / 1e6,
            "ground_share": float((cls == 0).mean())}


def _f(v, d=2):
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else f"{v:.{d}f}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=None, help="data folder holding lidar/ (default $BARE_EARTH_DATA "
                                                 "or ../shared/data)")
    ap.add_argument("--method", default="morphological", help="filter method (default morphological)")
    ap.add_argument("--cell-size", type=float, default=None, help="cell size in metres (default: density)")
    ap.add_argument("--speed-points", type=int, default=4_000_000,
                    help="points of the synthetic throughput test (0: skip)")
    ap.add_argument("--json", default=None, help="also write the figures to this JSON file")
    args = ap.parse_args(argv)

    data = Path(args.data) if args.data else default_data_dir()
    folder = data / "lidar" if (data / "lidar").is_dir() else data
    files = sorted(list(folder.glob("*.las")) + list(folder.glob("*.laz"))) if folder.is_dir() else []
    out = {"method": args.method, "files": {}, "speed": None}
    if not files:
        print(f"No LAS/LAZ files in {folder} (absent data folder?): nothing to benchmark. "
              "Set --data or BARE_EARTH_DATA.")
    else:
        print(f"Classified LiDAR benchmark: {args.method} (defaults), lowest point per cell, "
              f"{'cell from the point density' if args.cell_size is None else f'{args.cell_size:g} m cells'}; "
              f"truth: ASPRS class 2 = ground, classes {EXCLUDED} left out.\n")
        head = (f"{'file':<18} {'points':>8} {'eval':>8} {'unit':<16} {'cell m':>6} {'mode':<11} "
                f"{'TypeI %':>8} {'TypeII %':>8} {'total %':>8} {'kappa %':>8} {'obj~gnd %':>9} {'rast Mpt/s':>10} "
                f"{'cls Mpt/s':>9} {'s':>6}")
        print(head)
        print("-" * len(head))
        notes = []
        rows = []
        for p in files:
            r = evaluate_file(p, args.method, args.cell_size)
            out["files"][p.name] = r
            if "skipped" in r:
                notes.append(f"{p.name}: skipped, {r['skipped']}")
                continue
            rows.append(r)
            if not r["crs"]:
                notes.append(f"{p.name}: no CRS in the header: coordinates and heights taken as metres")
            elif r["units_to_metre"] != 1.0:
                notes.append(f"{p.name}: CRS unit {r['unit']} ({r['units_to_metre']:.6g} m): converted to metres")
            print(f"{p.name:<18} {r['points']:>8} {r['evaluated']:>8} {r['unit'][:16]:<16} {r['cell_size_m']:>6g} "
                  f"{str(r['mode']):<11} {_f(r['type1']):>8} {_f(r['type2']):>8} {_f(r['total']):>8} "
                  f"{_f(r['kappa']):>8} {_f(r['object_near_ground'], 1):>9} {_f(r['rasterize_Mpts_s']):>10} "
                  f"{_f(r['classify_Mpts_s']):>9} "
                  f"{r['seconds']:>6.2f}")
        if rows:
            mean = {k: float(np.nanmean([r[k] for r in rows])) for k in ("type1", "type2", "total", "kappa")}
            out["mean"] = mean
            print("-" * len(head))
            print(f"{'mean of ' + str(len(rows)) + ' files':<52} {'':<11} {_f(mean['type1']):>8} "
                  f"{_f(mean['type2']):>8} {_f(mean['total']):>8} {_f(mean['kappa']):>8}")
        for n in notes:
            print("  note: " + n)
        print("  (per-file throughput is dominated by fixed costs on these small files; see below)")
    if args.speed_points:
        s = speed(args.speed_points)
        out["speed"] = s
        print(f"\nThroughput on {s['points']:,} synthetic points ({s['grid'][1]} x {s['grid'][0]} cells of 1 m, "
              f"best of 3, one thread):")
        print(f"  rasterize (lowest per cell + nearest fill): {s['rasterize_s']:.3f} s = "
              f"{s['rasterize_Mpts_s']:.2f} million points/s")
        print(f"  classify (bilinear DTM and slope, SMRF rule): {s['classify_s']:.3f} s = "
              f"{s['classify_Mpts_s']:.2f} million points/s")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(out, fh, indent=1, default=lambda o: o if not isinstance(o, np.generic) else o.item())
    return 0


if __name__ == "__main__":
    sys.exit(main())
