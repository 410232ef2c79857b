"""Speed and peak memory of each filter, file to file (read, filter, fill the DTM, write).

Usage::

    /usr/bin/python3 benchmarks/speed.py [--methods slopeprofile,...] [--sizes 1,4,16] [--big]
                                          [--stages file,filter,dtm] [--params JSON]
                                          [--threads N] [--processes N] [--repeat N]
                                          [--out benchmarks/results/speed.jsonl]

Stages: ``file`` (the default) reads the GeoTIFF, filters, fills the DTM and writes DTM and
mask, as the plugin does; ``filter`` times the method alone on an array (parameters already
derived); ``dtm`` the filter plus the DTM's gap filling on an array.

Threads default to one per core, as in the plugin (``--threads 1`` for one block at a
time). ``--repeat N`` runs each case N times and reports the fastest (the machine's other
load only ever slows a run down) with the largest peak memory.

Each run is a fresh subprocess, so its peak resident memory (``VmHWM``) is its own;
"extra" is that peak minus the memory of the imports alone. With ``--processes N`` the
blocks run in N worker processes (their memory is not in these figures; each holds one block). Inputs are synthetic city
DSMs (``core.synthetic.make_dsm``) written as tiled GeoTIFFs. ``--big`` adds a 100 Mcells
DSM (written in tiles, never held in memory) run in block mode, and the 16 and 36 Mcells
ones in block mode too, to show memory does not grow with the raster in block mode (16
Mcells has only edge blocks; from 36 Mcells on, interior blocks carry a halo on all sides).
A GDAL read + write of the same file gives the I/O-only speed for scale. "CPU s" is the
process's CPU time over the same span (all its threads, GDAL's included; the fastest of the
runs): on a machine shared with other work it moves far less than the wall time.
``--reuse-memory`` runs each case with the allocator of the plugin's worker processes
(``core/memory.py``: one malloc arena keeping what is freed, so the kernel does not zero the
pages of every raster-sized temporary again); the default is the allocator as inside QGIS.
"""
import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import ROOT, setup_path  # noqa: E402

setup_path()


def make_input(path, mcells, seed=0):
    """Write a synthetic DSM of about ``mcells`` million cells to ``path`` (tiled GeoTIFF)."""
    import numpy as np
    from osgeo import gdal, osr

    from bare_earth.core.synthetic import make_dsm
    side = int(round((mcells * 1e6) ** 0.5))
    tile = min(side, 4000)
    drv = gdal.GetDriverByName("GTiff")
    ds = drv.Create(str(path), side, side, 1, gdal.GDT_Float32,
                    options=["TILED=YES", "COMPRESS=DEFLATE", "PREDICTOR=3", "BIGTIFF=IF_SAFER"])
    ds.SetGeoTransform((500000.0, 1.0, 0.0, 5400000.0 + side, 0.0, -1.0))
    srs = osr.SpatialReference()
    srs.ImportFromEPSG(32632)
    ds.SetProjection(srs.ExportToWkt())
    band = ds.GetRasterBand(1)
    band.SetNoDataValue(-9999.0)
    k = 0
    for r0 in range(0, side, tile):
        for c0 in range(0, side, tile):
            h, w = min(tile, side - r0), min(tile, side - c0)
            sc = make_dsm(h * w, seed=seed + k)
            z = np.asarray(sc.dsm, dtype=np.float32)[:h, :w]
            if z.shape != (h, w):  # make_dsm gives a square; pad a ragged edge tile
                pad = np.full((h, w), float(np.nanmedian(z)), np.float32)
                pad[: z.shape[0], : z.shape[1]] = z
                z = pad
            band.WriteArray(np.where(np.isfinite(z), z, -9999.0).astype(np.float32), c0, r0)
            k += 1
    ds = None
    return side * side


CHILD = r"""
import json, sys, time
sys.path.insert(0, {plugins!r})
from bare_earth.core import pipeline
from osgeo import gdal
import numpy, scipy.ndimage
if {method!r} != "io":  # the plugin has its methods imported before a run starts
    from bare_earth.core.methods import get_method
    get_method({method!r})

def status_kb(key):
    # VmHWM is this process image's peak RSS (ru_maxrss would carry the parent's over exec)
    for line in open("/proc/self/status"):
        if line.startswith(key + ":"):
            return int(line.split()[1])
    return 0

base = status_kb("VmRSS")
t = time.perf_counter()
c = time.process_time()
if {stage!r} != "file":
    from bare_earth.core.synthetic import make_dsm
    from bare_earth.core.methods import get_method
    z = make_dsm(int({mcells} * 1e6)).dsm
    meth = get_method({method!r})
    prm = meth.resolve(z, (1.0, 1.0), **pipeline.complete_params(meth, {params!r}))
    base = status_kb("VmRSS")
    t = time.perf_counter()
    c = time.process_time()
    if {stage!r} == "filter":
        meth.run(z, (1.0, 1.0), **prm)
    else:
        pipeline.run_array(meth, z, 1.0, params={params!r})
    info = {{}}
elif {method!r} == "io":
    src = gdal.Open({src!r})
    b = src.GetRasterBand(1)
    drv = gdal.GetDriverByName("GTiff")
    dst = drv.Create({dtm!r}, src.RasterXSize, src.RasterYSize, 1, gdal.GDT_Float32,
                     options=["TILED=YES", "COMPRESS=DEFLATE", "ZLEVEL=1", "PREDICTOR=3",
                              "BIGTIFF=IF_SAFER"])  # the options of the plugin's outputs
    for r0 in range(0, src.RasterYSize, 2048):
        h = min(2048, src.RasterYSize - r0)
        dst.GetRasterBand(1).WriteArray(b.ReadAsArray(0, r0, src.RasterXSize, h), 0, r0)
    dst = None
    info = {{}}
else:
    info = pipeline.run_file({method!r}, {src!r}, {{"dtm": {dtm!r}, "mask": {mask!r}}}, block={block},
                             processes={workers}, workers={threads})
dt = time.perf_counter() - t
cpu = time.process_time() - c   # every thread of the process (GDAL's too): less sensitive to the host's load
peak = status_kb("VmHWM")
print(json.dumps({{"seconds": dt, "cpu_seconds": cpu, "peak_mb": peak / 1024, "extra_mb": (peak - base) / 1024,
                  "blocks": info.get("blocks", 0)}}))
"""


def run_child(method, src, tmp, block=None, workers=1, stage="file", mcells=0, params=None, threads=1,
              reuse_memory=False):
    code = CHILD.format(plugins=str(ROOT / ".build" / "plugins"), method=method, src=str(src),
                        dtm=str(Path(tmp) / "dtm.tif"), mask=str(Path(tmp) / "mask.tif"),
                        block=repr(block), workers=int(workers), threads=int(threads), stage=stage,
                        mcells=mcells,
                        params=dict(params or {}))
    env = None
    if reuse_memory:                     # the allocator of a process that only filters (core.memory)
        from bare_earth.core.memory import allocator_environment
        env = allocator_environment()
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    if res.returncode != 0:
        return {"error": (res.stderr.strip().splitlines() or ["failed"])[-1]}
    return json.loads(res.stdout.strip().splitlines()[-1])


def main(argv=None):
    from bare_earth.core.methods import available_methods
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--methods", default=",".join(available_methods()))
    ap.add_argument("--sizes", default="1,4,16", help="Mcells, comma-separated")
    ap.add_argument("--big", action="store_true", help="add 16, 36 and 100 Mcells in block mode")
    ap.add_argument("--processes", dest="workers", type=int, default=1,
                    help="worker processes running blocks")
    ap.add_argument("--threads", type=int, default=0,
                    help="threads running blocks (0, the default as in the plugin: one per core)")
    ap.add_argument("--repeat", type=int, default=1,
                    help="runs per case (fresh processes); the fastest is reported, with the largest peak memory")
    ap.add_argument("--stages", default="file",
                    help="comma-separated: file (read, filter, fill the DTM, write: the default), "
                         "filter (the filter alone on an array), dtm (filter and DTM fill on an array)")
    ap.add_argument("--params", default="{}", help="method parameters as JSON, e.g. '{\"mode\": \"progressive\"}'")
    ap.add_argument("--reuse-memory", action="store_true",
                    help="run each case with the allocator settings of the plugin's worker processes (one malloc "
                         "arena keeping freed memory: core/memory.py); the default is the allocator as in QGIS")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "speed.jsonl"))
    ap.add_argument("--no-log", action="store_true")
    args = ap.parse_args(argv)
    methods = [m for m in args.methods.split(",") if m]
    stages = [x for x in args.stages.split(",") if x]
    params = json.loads(args.params)
    sizes = [float(s) for s in args.sizes.split(",") if s]
    from bare_earth.core.blocks import resolve_workers
    threads = resolve_workers(args.threads)
    rows = []
    with tempfile.TemporaryDirectory(prefix="bare_earth_speed_") as tmp:
        cases = [(s, None) for s in sizes]
        if args.big:
            cases += [(16.0, 2048), (36.0, 2048), (100.0, 2048)]
        inputs = {}
        print(f"{'method':>14} {'Mcells':>7} {'mode':>12} {'seconds':>8} {'Mcells/s':>9} {'CPU s':>6} {'peak MB':>8} "
              f"{'extra MB':>9} {'input MB':>9}")
        for size, block in cases:
            if size not in inputs:
                p = Path(tmp) / f"dsm_{size:g}.tif"
                n = make_input(p, size)
                inputs[size] = (p, n)
            p, n = inputs[size]
            for m in ["io"] + methods:
                for stage in (["file"] if m == "io" else stages):
                    if m == "io" and block is not None:
                        continue
                    if stage != "file" and block is not None:
                        continue
                    runs = [run_child(m, p, tmp, block=block, workers=args.workers, stage=stage, mcells=size,
                                      params=params, threads=threads, reuse_memory=args.reuse_memory)
                            for _ in range(max(1, args.repeat))]
                    ok = [x for x in runs if "error" not in x]
                    r = runs[0] if not ok else dict(min(ok, key=lambda x: x["seconds"]),
                                                    cpu_seconds=min(x["cpu_seconds"] for x in ok),
                                                    peak_mb=max(x["peak_mb"] for x in ok),
                                                    extra_mb=max(x["extra_mb"] for x in ok),
                                                    runs=[round(x["seconds"], 3) for x in ok])
                    mode = ("io only" if m == "io" else
                            {"filter": "filter", "dtm": "filter+DTM"}.get(stage) if stage != "file" else
                            ("file" if block is None else f"file {block}"))
                    if "error" in r:
                        print(f"{m:>14} {n / 1e6:7.1f} {mode:>12}  ERROR {r['error']}")
                        continue
                    row = dict(method=m, mcells=n / 1e6, mode=mode, workers=args.workers, threads=threads,
                               params=params, reuse_memory=args.reuse_memory, **r,
                               mcells_per_s=n / 1e6 / r["seconds"], input_mb=n * 4 / 2 ** 20)
                    rows.append(row)
                    print(f"{m:>14} {n / 1e6:7.1f} {mode:>12} {r['seconds']:8.2f} {row['mcells_per_s']:9.2f} "
                          f"{r['cpu_seconds']:6.2f} {r['peak_mb']:8.0f} {r['extra_mb']:9.0f} {row['input_mb']:9.0f}")
    if not args.no_log and rows:
        commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True).stdout.strip()
        with open(args.out, "a") as f:
            f.write(json.dumps({"date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                                "commit": commit, "cpus": os.cpu_count(),
                                "load": os.getloadavg()[0], "rows": rows}) + "\n")
    return rows


if __name__ == "__main__":
    main()
