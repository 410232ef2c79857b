"""RASCOR's highway case (Jacobsen 2004) on a synthetic dam: with and without break lines.

Jacobsen's example: a highway on a dam with trees and bushes on its slopes. Without break
lines the filter takes points out of the dam's upper shoulders (21.6 % of the points
removed); with break lines along the crest and the toes it keeps them (10.4 %) while the
vegetation still goes. This benchmark builds such a scene (1 m cells: rolling ground, a
6 m road embankment with 1:1.5 sides, trees and bushes on its slopes and beside it, a
building), runs :func:`core.rascor.filter_rascor` with its data-derived defaults, without
and with the break-line raster (cells crossed by the crest edges and the toes), and prints::

    share removed, dam ground kept, upper-shoulder ground kept, vegetation removed, Type I/II

    /usr/bin/python3 benchmarks/rascor_highway.py [--rows 160] [--seed 3]

``tests/core/test_rascor.py`` guards the figures (>= 95 % of the dam's ground kept with
break lines, shoulders lost without, vegetation removed in both).
"""
import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PLUGINS = ROOT / ".build" / "plugins"
if not (PLUGINS / "bare_earth").exists():
    PLUGINS.mkdir(parents=True, exist_ok=True)
    (PLUGINS / "bare_earth").symlink_to(ROOT, target_is_directory=True)
if str(PLUGINS) not in sys.path:
    sys.path.insert(0, str(PLUGINS))

from bare_earth.core.rascor import filter_rascor, resolve_rascor_params  # noqa: E402

#: Dam geometry in cells (1 m): centre column, crest half-width, height, side slope (run/rise).
CENTRE, CREST_HALF, HEIGHT, SIDE = 100, 6, 6.0, 1.5
TOE_HALF = CREST_HALF + int(round(HEIGHT * SIDE))  # 15


@dataclass
class HighwayScene:
    """The synthetic highway scene and its truth."""
    dsm: np.ndarray          #: float32 DSM
    dtm: np.ndarray          #: float32 true ground
    objects: np.ndarray      #: bool, cells on an object (> 0.2 m above the ground)
    vegetation: np.ndarray   #: bool, tree and bush cells on the dam's slopes
    dam: np.ndarray          #: bool, ground cells between the toes
    shoulders: np.ndarray    #: bool, ground cells within 2 m of a crest edge
    breaklines: np.ndarray   #: bool, cells crossed by the crest edges and the toes


def highway_scene(rows=160, cols=200, seed=3, noise_m=0.05):
    """Build the scene: rolling ground, a N-S road embankment, vegetation, a building."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:rows, 0:cols].astype(np.float64)
    ground = 100.0 + 0.01 * x + 0.6 * np.sin(y / 35.0) + 0.4 * np.cos(x / 45.0)
    d = np.abs(x - CENTRE)
    dam_h = np.clip(HEIGHT - (d - CREST_HALF) / SIDE, 0.0, HEIGHT)
    dtm = ground + dam_h
    obj_h = np.zeros_like(dtm)

    def crown(r0, c0, radius, height):
        rr = np.hypot(y - r0, x - c0) / radius
        return np.where(rr < 1, height * np.sqrt(np.clip(1 - rr ** 2, 0, 1)) + 0.3 * height, 0.0)

    veg = np.zeros(dtm.shape, bool)
    slope_cols = (CENTRE - (CREST_HALF + TOE_HALF) / 2.0, CENTRE + (CREST_HALF + TOE_HALF) / 2.0)
    for i, r0 in enumerate(range(12, rows - 10, 16)):
        c0 = slope_cols[i % 2] + rng.uniform(-0.5, 0.5)
        if i % 3 == 2:   # bush
            h = crown(r0, c0, rng.uniform(1.2, 1.6), rng.uniform(1.2, 1.8))
        else:            # tree
            h = crown(r0, c0, rng.uniform(2.0, 2.6), rng.uniform(4.0, 7.0))
        veg |= h > 0.2
        obj_h = np.maximum(obj_h, h)
    # trees and bushes on the plain, a building
    for _ in range(10):
        r0 = rng.uniform(10, rows - 10)
        c0 = rng.choice([rng.uniform(8, CENTRE - TOE_HALF - 8), rng.uniform(CENTRE + TOE_HALF + 8, cols - 8)])
        obj_h = np.maximum(obj_h, crown(r0, c0, rng.uniform(1.5, 4.0), rng.uniform(2.0, 12.0)))
    b = (y >= 100) & (y < 124) & (x >= 20) & (x < 42)
    obj_h = np.where(b, 9.0, obj_h)
    dsm = dtm + obj_h + rng.normal(0.0, noise_m, dtm.shape)
    objects = obj_h > 0.2
    dam = (d <= TOE_HALF) & ~objects
    shoulders = (np.abs(d - CREST_HALF) <= 2) & ~objects
    bl = np.zeros(dtm.shape, bool)
    for c in (CENTRE - TOE_HALF, CENTRE - CREST_HALF, CENTRE + CREST_HALF, CENTRE + TOE_HALF):
        bl[:, c] = True
    return HighwayScene(dsm.astype(np.float32), dtm.astype(np.float32), objects, veg, dam,
                        shoulders, bl)


def highway_figures(scene=None, **params):
    """Run RASCOR without and with break lines; return ``{"without": {...}, "with": {...}}``.

    Each entry: ``removed`` (share of all cells), ``dam_kept`` (share of the dam's ground
    cells kept), ``shoulder_kept``, ``vegetation_removed`` (share of the tree / bush cells
    on the slopes removed), ``objects_removed``, ``type1``, ``type2``, ``step_shares``.
    """
    sc = scene or highway_scene()
    p = resolve_rascor_params(sc.dsm, 1.0, **params)
    out = {"params": p}
    for name, bl in (("without", None), ("with", sc.breaklines)):
        res = filter_rascor(sc.dsm, 1.0, breaklines=bl, **p)
        rem = res.mask != 0
        out[name] = {
            "removed": float(rem.mean()),
            "dam_kept": float(1 - rem[sc.dam].mean()),
            "shoulder_kept": float(1 - rem[sc.shoulders].mean()),
            "vegetation_removed": float(rem[sc.vegetation].mean()),
            "objects_removed": float(rem[sc.objects].mean()),
            "type1": float(rem[~sc.objects].mean()),
            "type2": float(1 - rem[sc.objects].mean()),
            "step_shares": res.info["removed_share_by_step"],
        }
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=160, help="scene rows (cells of 1 m)")
    ap.add_argument("--seed", type=int, default=3, help="random seed of the scene")
    a = ap.parse_args(argv)
    f = highway_figures(highway_scene(rows=a.rows, seed=a.seed))
    p = f["params"]
    print(f"terrain class {p['terrain_class']} ({'' if p['homogeneous'] else 'not '}homogeneous), "
          f"sigma {p['sigma_m']} m, profiles "
          f"{p['short_profile_m']}/{p['long_profile_m']} m, surface {p['surface_size_m']} m")
    print(f"{'':22s}{'without':>10s}{'with':>10s}   break lines (paper: 21.6 % vs 10.4 % removed)")
    for key, label in (("removed", "share removed"), ("dam_kept", "dam ground kept"),
                       ("shoulder_kept", "upper shoulders kept"),
                       ("vegetation_removed", "slope vegetation removed"),
                       ("objects_removed", "all objects removed"),
                       ("type1", "Type I (ground lost)"), ("type2", "Type II (objects kept)")):
        print(f"{label:22s}{100 * f['without'][key]:9.1f}%{100 * f['with'][key]:9.1f}%")
    print("removed by step (without / with):")
    for k in f["without"]["step_shares"]:
        print(f"  {k:32s}{100 * f['without']['step_shares'][k]:7.2f}%"
              f"{100 * f['with']['step_shares'][k]:7.2f}%")


if __name__ == "__main__":
    main()
