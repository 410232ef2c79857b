"""Speed of the curvature filter (Luong Chinh Ke 2002) on a synthetic DSM.

Prints the Mcells/s of :func:`core.curvature.filter_curvature` (one pass, the
filter itself: curvature, breaks, profile scans, final pass with its ground surface) and of
:func:`core.curvature.compute_curvature` alone, on a rolling terrain with noise and a
few hundred box buildings (``--scene rolling``, the default) or on the synthetic city DSM
of ``benchmarks/speed.py`` (``--scene city``: ``core.synthetic.make_dsm``, about a fifth
of it objects). Default ~16 Mcells (4096 x 4096)::

    /usr/bin/python3 benchmarks/curvature_speed.py [--side 4096] [--repeat 1] [--scene city]

``--progress`` also prints the number of progress calls of one filter run and the largest
gap between them (what a user waits for the bar, and for a cancel to be seen).
``--seams [DSM]`` instead filters a DSM file (default: the 4 Mcells synthetic city written
to a temporary GeoTIFF) through ``pipeline.run_file`` in one block with one thread, with
two threads (strips) and in blocks of 256 cells, and prints how many mask cells differ
from the one-block run (0 when blocks equal one pass)::

    /usr/bin/python3 benchmarks/curvature_speed.py --seams ../shared/data/raster/pleiades/triplet_dsm.tif

Not a test: figures depend on the machine and its load.
"""
import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PLUGINS = ROOT / ".build" / "plugins"
if not (PLUGINS / "bare_earth").exists():
    PLUGINS.mkdir(parents=True, exist_ok=True)
    (PLUGINS / "bare_earth").symlink_to(ROOT, target_is_directory=True)
sys.path.insert(0, str(PLUGINS))

from bare_earth.core.curvature import compute_curvature, filter_curvature, resolve_curvature_params  # noqa: E402


def scene(side, seed=1):
    """Rolling terrain (noise 5 cm) with ``side^2 / 50000`` box buildings 3-15 m high."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:side, 0:side].astype(np.float32)
    z = 20 * np.sin(x / 300) + 15 * np.cos(y / 400) + rng.normal(0, 0.05, (side, side))
    z = z.astype(np.float32)
    for _ in range(max(1, side * side // 50000)):
        r0, c0 = rng.integers(0, side - 40, 2)
        h, w = rng.integers(8, 35, 2)
        z[r0:r0 + h, c0:c0 + w] += rng.uniform(3, 15)
    return z


def progress_gaps(z, params):
    """Calls of ``progress`` during one filter run and the largest gap between them (s)."""
    times = [time.perf_counter()]
    filter_curvature(z, 1.0, progress=lambda f: times.append(time.perf_counter()), **params)
    times.append(time.perf_counter())
    return len(times) - 2, float(np.max(np.diff(times)))


def seams(path):
    """Mask cells of ``run_file`` that differ from one block: with 2 threads, with blocks of 256."""
    import tempfile

    from osgeo import gdal

    from bare_earth.core import grid, pipeline
    from bare_earth.core.synthetic import make_dsm
    with tempfile.TemporaryDirectory() as tmp:
        if path is None:
            path = str(Path(tmp) / "city.tif")
            grid.write_array(path, np.asarray(make_dsm(4_000_000).dsm, np.float32), (0, 1.0, 0, 0, 0, -1.0))
        masks = {}
        for name, kw in (("one block", dict(workers=1)), ("2 threads", dict(workers=2)),
                         ("blocks of 256", dict(workers=1, block=256))):
            out = str(Path(tmp) / f"mask{len(masks)}.tif")
            t0 = time.perf_counter()
            pipeline.run_file("curvature", path, {"mask": out}, **kw)
            ds = gdal.Open(out)                      # kept while its band is read
            masks[name] = ds.GetRasterBand(1).ReadAsArray()
            ds = None
            print(f"{name:14s} {time.perf_counter() - t0:6.1f} s, mask cells differing from one block: "
                  f"{int(np.count_nonzero(masks[name] != masks['one block']))}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--side", type=int, default=4096, help="raster side in cells")
    ap.add_argument("--repeat", type=int, default=1, help="timed runs (best is printed)")
    ap.add_argument("--scene", choices=("rolling", "city"), default="rolling",
                    help="rolling terrain with boxes, or the city DSM of benchmarks/speed.py")
    ap.add_argument("--progress", action="store_true", help="also the largest gap between progress calls")
    ap.add_argument("--seams", nargs="?", const="", default=None, metavar="DSM",
                    help="blocks and threads vs one block on a DSM file (default: synthetic city)")
    a = ap.parse_args(argv)
    if a.seams is not None:
        seams(a.seams or None)
        return
    if a.scene == "city":
        from bare_earth.core.synthetic import make_dsm
        z = np.asarray(make_dsm(a.side * a.side, seed=0).dsm, np.float32)
    else:
        z = scene(a.side)
    cells = z.size / 1e6
    t0 = time.perf_counter()
    params = resolve_curvature_params(z, 1.0)
    t_res = time.perf_counter() - t0
    best = {"compute_curvature": [np.inf, np.inf], "filter_curvature": [np.inf, np.inf]}
    for _ in range(a.repeat):
        for name, call in (("compute_curvature", lambda: compute_curvature(z, 1.0)),
                           ("filter_curvature", lambda: filter_curvature(z, 1.0, **params))):
            w0, c0 = time.perf_counter(), time.process_time()
            res = call()
            w, c = time.perf_counter() - w0, time.process_time() - c0
            best[name] = [min(best[name][0], w), min(best[name][1], c)]
    print(f"{a.scene} raster {z.shape[0]} x {z.shape[1]} = {cells:.1f} Mcells (one thread)")
    print(f"resolve (defaults from a <= 1 Mcell sample): {t_res:.2f} s")
    for name, (w, c) in best.items():
        print(f"{name:18s} wall {w:6.2f} s = {cells / w:5.1f} Mcells/s | "
              f"CPU {c:6.2f} s = {cells / c:5.1f} Mcells/s")
    if a.progress:
        calls, gap = progress_gaps(z, params)
        print(f"progress: {calls} calls, largest gap {gap:.2f} s")
    print(f"objects {100 * np.mean(res.mask == 1):.1f} %, K_g {params['k_g_per_m2']:.4g} 1/m2. "
          "Wall time counts waiting for a CPU on a loaded machine; CPU time does not.")


if __name__ == "__main__":
    main()
