"""A whole survey on Dask: throughput with 2 local workers and with 1, memory per worker,
seams against a single pass, per-tile cost and the scheduler's overhead per tile.

Usage::

    /usr/bin/python3 benchmarks/scale.py [--dir /tmp/bare-earth-scale] [--tiles 100] [--side 2000]
                                          [--method slopeprofile] [--params JSON] [--workers 2,1]
                                          [--out benchmarks/results/scale.jsonl]

The survey (``--tiles`` tiles of ``--side`` x ``--side`` cells at 1 m, in a square-ish grid;
the default is 100 tiles of 2000 x 2000 = 400 Mcells) is generated once into ``--dir/tiles``
(reused when present): a continuous terrain of global coordinates (two long sine waves,
slopes up to about 7 degrees) plus, per tile, the objects, noise and low blunders of a
synthetic city (``core.synthetic.make_scene``). Generation runs on the Dask cluster too.

Each ``--workers`` count runs the survey from scratch (``core.survey.run_survey`` on a
LocalCluster of that many processes, one thread each) into ``--dir/out-<n>w`` and prints:

* Mcells/s over the tiles' phase (cluster start excluded; it is printed apart);
* peak memory per worker (the largest resident set a task saw in its worker process);
* per-tile cost (mean task seconds: read + filter + fill + write) and the halo's share;
* the scheduler's overhead per tile: the mean idle gap between two consecutive tasks of a
  worker (result to the client, record, next task handed out), and its share of a tile's
  compute; and the whole idle share (start, tail and gaps: workers x wall - task time).

Seams: the central 2 x 2 tiles (the whole survey when smaller) are filtered in one pass
(``survey.task.filter_array``, same parameters) over a window reaching two halos beyond them,
and compared with the tiled mosaics: mask cells that differ, and the DTM's largest and
RMS difference on filled cells near the internal seams (within one halo) and anywhere.
"""
import argparse
import datetime
import json
import math
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import ROOT, setup_path  # noqa: E402

setup_path()

from bare_earth.core import grid  # noqa: E402
from bare_earth.core.survey import engine, plan, run_survey  # noqa: E402
from bare_earth.core.survey.task import filter_array  # noqa: E402

#: Upper-left corner of the survey (UTM 32N metres).
ORIGIN = (500000.0, 5600000.0)


def terrain(x, y):
    """The survey's continuous terrain at map coordinates (metres): two long waves."""
    return (300.0 + 15.0 * np.sin(2 * np.pi * x / 1700.0) * np.cos(2 * np.pi * y / 2300.0)
            + 8.0 * np.sin(2 * np.pi * (x + y) / 900.0)).astype(np.float32)


def make_tile(path, i, j, side, seed):
    """Write tile (i, j): the survey's terrain plus a synthetic city's objects, noise and blunders."""
    from bare_earth.core.synthetic import make_scene
    sc = make_scene("city", (side, side), seed=seed)
    x0, y0 = ORIGIN[0] + j * side, ORIGIN[1] - i * side
    cols = x0 + np.arange(side) + 0.5
    rows = y0 - np.arange(side) - 0.5
    z = (sc.dsm - sc.dtm) + terrain(cols[None, :], rows[:, None])
    tmp = f"{path}.partial.tif"
    grid.write_array(tmp, z, (x0, 1.0, 0.0, y0, 0.0, -1.0), sc.epsg)
    os.replace(tmp, path)
    return path


def generate(folder, n_tiles, side, workers):
    """The survey's tiles in ``folder`` (missing ones made on a local Dask cluster)."""
    folder.mkdir(parents=True, exist_ok=True)
    k = int(math.ceil(math.sqrt(n_tiles)))
    want = [(folder / f"tile_{i:03d}_{j:03d}.tif", i, j) for n, (i, j) in
            enumerate((a, b) for a in range(k) for b in range(k)) if n < n_tiles]
    for f in folder.glob("*.tif"):
        if f not in {w[0] for w in want}:
            f.unlink()
    todo = [w for w in want if not w[0].exists()]
    if todo:
        t0 = time.perf_counter()
        client, cluster = engine.start_client(workers)
        try:
            futs = [client.submit(make_tile, str(p), i, j, side, 1000 + 7 * i + j, pure=False) for p, i, j in todo]
            client.gather(futs)
        finally:
            client.close()
            cluster.close()
        print(f"generated {len(todo)} tiles of {side} x {side} in {time.perf_counter() - t0:.1f} s")
    return [str(w[0]) for w in want]


def summarise(rec, workers):
    """The figures of one run from its record."""
    run = rec["this_run"]
    tiles = [v for v in rec["tiles"].values() if v.get("status") == "done"]
    by_worker = {}
    for t in tiles:
        by_worker.setdefault(t["worker"], []).append(t)
    gaps = []
    for ts in by_worker.values():
        ts.sort(key=lambda t: t["start"])
        gaps += [b["start"] - a["end"] for a, b in zip(ts, ts[1:])]
    compute = float(np.mean([t["seconds"] for t in tiles]))
    cells = sum(t["cells"] for t in tiles)
    wall = run["tiles_wall_s"]
    gap = float(np.mean(gaps)) if gaps else float("nan")
    return {"workers": workers, "tiles": len(tiles), "mcells": cells / 1e6, "wall_s": wall,
            "total_wall_s": run["wall_s"], "mcells_per_s": cells / 1e6 / wall,
            "tile_s": compute, "tile_read_s": float(np.mean([t["read_s"] for t in tiles])),
            "tile_filter_s": float(np.mean([t["filter_s"] for t in tiles])),
            "tile_write_s": float(np.mean([t["write_s"] for t in tiles])),
            "peak_mb_per_worker": {w: max(t["peak_rss_mb"] for t in ts) for w, ts in by_worker.items()},
            "gap_s_per_tile": gap, "gap_share": gap / compute if gaps else float("nan"),
            "idle_share": (workers * wall - sum(t["seconds"] for t in tiles)) / (workers * wall),
            "failed": len(run["failed"])}


def seams(rec, out_dir, method, side, n_tiles):
    """Tiled mosaics against a single pass over the central 2 x 2 tiles (plus two halos)."""
    halo = rec["halo_cells"]
    shape = tuple(rec["survey"]["shape"])
    k = int(math.ceil(math.sqrt(n_tiles)))
    rows_t = shape[0] // side
    i0, j0 = max(0, rows_t // 2 - 1), max(0, k // 2 - 1)
    block = (i0 * side, min(shape[0], (i0 + 2) * side), j0 * side, min(shape[1], (j0 + 2) * side))
    a = plan.alignment(halo)
    win = (max(0, (block[0] - 2 * halo) // a * a), min(shape[0], block[1] + 2 * halo),
           max(0, (block[2] - 2 * halo) // a * a), min(shape[1], block[3] + 2 * halo))
    z = grid.open_dsm(os.path.join(out_dir, "survey.vrt")).read(win)
    t0 = time.perf_counter()
    ref_mask, ref_dtm, _info = filter_array(method, z, rec["survey"]["cell_size_m"], rec["params"])
    t_one = time.perf_counter() - t0
    inner = (slice(block[0] - win[0], block[1] - win[0]), slice(block[2] - win[2], block[3] - win[2]))
    rm, rd, zi = ref_mask[inner], ref_dtm[inner], z[inner]
    del ref_mask, ref_dtm, z
    mask_info = grid.open_dsm(os.path.join(out_dir, "mask.vrt"))
    tm = mask_info.dataset().GetRasterBand(1).ReadAsArray(block[2], block[0], block[3] - block[2],
                                                          block[1] - block[0])
    td = grid.open_dsm(os.path.join(out_dir, "dtm.vrt")).read(block)
    rr = np.arange(block[0], block[1])[:, None]
    cc = np.arange(block[2], block[3])[None, :]
    near = (np.abs((rr + side // 2) % side - side // 2) < halo) | (np.abs((cc + side // 2) % side - side // 2) < halo)
    near &= (rr > 0) & (cc > 0)              # internal seams only
    filled = (rm != 0) & np.isfinite(rd) & np.isfinite(td)
    d = np.abs(td - rd)
    ground = rm == 0
    return {"block_cells": int(tm.size), "one_pass_s": t_one, "mask_cells_differ": int(np.count_nonzero(tm != rm)),
            "ground_identical": bool(np.array_equal(td[ground], zi[ground])),
            "dtm_max_diff_seams_m": float(d[filled & near].max()) if (filled & near).any() else 0.0,
            "dtm_rms_diff_seams_m": float(np.sqrt(np.mean(d[filled & near] ** 2))) if (filled & near).any() else 0.0,
            "dtm_max_diff_m": float(d[filled].max()) if filled.any() else 0.0,
            "dtm_p99_diff_m": float(np.percentile(d[filled], 99)) if filled.any() else 0.0,
            "filled_cells": int(np.count_nonzero(filled))}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dir", default="/tmp/bare-earth-scale")
    ap.add_argument("--tiles", type=int, default=100)
    ap.add_argument("--side", type=int, default=2000)
    ap.add_argument("--method", default="slopeprofile")
    ap.add_argument("--params", default="{}", help="JSON of the method's parameters")
    ap.add_argument("--workers", default="2,1", help="worker counts to run, comma separated")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "scale.jsonl"))
    args = ap.parse_args()
    base = Path(args.dir)
    counts = [int(v) for v in args.workers.split(",")]
    load0 = os.getloadavg()
    tiles = generate(base / "tiles", args.tiles, args.side, max(counts))
    print(f"survey: {len(tiles)} tiles of {args.side} x {args.side} = {len(tiles) * args.side ** 2 / 1e6:.0f} Mcells; "
          f"method {args.method}; load average {load0[0]:.2f} on {os.cpu_count()} cores")
    rows = []
    for w in counts:
        out = base / f"out-{w}w"
        shutil.rmtree(out, ignore_errors=True)
        t0 = time.perf_counter()
        rec = run_survey(args.method, str(base / "tiles"), str(out), json.loads(args.params), workers=w)
        total = time.perf_counter() - t0
        s = summarise(rec, w)
        s["run_s"] = total
        s["load"] = os.getloadavg()[0]
        s["halo_cells"] = rec["halo_cells"]
        s["halo_share"] = ((args.side + 2 * rec["halo_cells"]) ** 2 / args.side ** 2) - 1
        rows.append((s, rec, out))
        peaks = ", ".join(f"{v:.0f}" for v in s["peak_mb_per_worker"].values())
        print(f"{w} worker(s): {s['mcells_per_s']:.2f} Mcells/s ({s['mcells']:.0f} Mcells in {s['wall_s']:.1f} s; "
              f"run with start-up and mosaics {total:.1f} s); peak MB per worker {peaks}; tile {s['tile_s']:.2f} s "
              f"(read {s['tile_read_s']:.2f}, filter+fill {s['tile_filter_s']:.2f}, write {s['tile_write_s']:.2f}; "
              f"halo +{100 * s['halo_share']:.0f} % cells); scheduler gap {1000 * s['gap_s_per_tile']:.1f} ms per "
              f"tile = {100 * s['gap_share']:.2f} % of a tile; idle share {100 * s['idle_share']:.1f} %; "
              f"failed {s['failed']}; load {s['load']:.2f}", flush=True)
    speed = {s["workers"]: s["mcells_per_s"] for s, _r, _o in rows}
    if 1 in speed and 2 in speed:
        print(f"speed-up 2 workers / 1: {speed[2] / speed[1]:.2f}x")
    s, rec, out = rows[0]
    st = seams(rec, str(out), args.method, args.side, len(tiles))
    print(f"seams ({st['block_cells'] / 1e6:.0f} Mcells around the central seams against one pass in "
          f"{st['one_pass_s']:.1f} s): mask cells differing {st['mask_cells_differ']}; ground cells identical "
          f"{st['ground_identical']}; DTM on filled cells within a halo of the seams: max "
          f"{st['dtm_max_diff_seams_m']:.4f} m, rms {st['dtm_rms_diff_seams_m']:.4f} m; anywhere: max "
          f"{st['dtm_max_diff_m']:.4f} m, "
          f"99 % {st['dtm_p99_diff_m']:.4f} m over {st['filled_cells']} filled cells")
    line = {"date": datetime.datetime.now().isoformat(timespec="seconds"), "method": args.method,
            "params": json.loads(args.params), "tiles": len(tiles), "side": args.side, "load_start": load0[0],
            "runs": [r for r, _x, _o in rows], "seams": st,
            "speedup_2_over_1": speed[2] / speed[1] if 1 in speed and 2 in speed else None}
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "a", encoding="utf-8") as f:
        f.write(json.dumps(line) + "\n")


if __name__ == "__main__":
    main()
