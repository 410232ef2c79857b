"""Empty cells before filtering (issue 12): what the pipeline's fill of a DSM's empty cells does to every filter.

The pipeline fills the empty cells enclosed by data before any filter runs
(:func:`bare_earth.core.pipeline.fill_empty_cells`, :func:`bare_earth.core.fill.fill_empty`). Two inputs
show its two sides:

1. **Image-matching DSMs** (``raster/pleiades``: ``pair_dsm.tif``, mountains, 11 % scattered holes;
   ``triplet_dsm.tif``, 42 % nodata with terrace risers and occlusions; no truth): the share of the
   input's data cells each filter calls objects (class 1), with the pipeline's fill and, with
   ``--unfilled``, with the empty cells left empty (the filters then see NaN). On mountain terrain a
   rise of that share is mostly ground taken for objects.
2. **A lidar DSM with holes punched** (``raster/opengeos``, 2 m, the one raster with a reference DTM):
   25 % of the cells emptied at random plus 60 rectangular holes of 2-8 cells (``--seed``); the RMSE of
   each filter's DTM against ``dtm.tif`` on the cells both hold, and the largest difference between each
   fill of the raster and the flipped fill of its south-up mirror (neither is mirror-symmetric:
   ``fill_empty`` takes a cell's first filled neighbour in a fixed order, ``fill_gaps`` relaxes red
   cells before black ones on a pyramid aligned at the top-left corner).

``--png DIR`` writes a picture per raster and filter (hillshade, filled cells blue, objects red)::

    /usr/bin/python3 benchmarks/empty_cells.py [--methods dtm,geodesic] [--unfilled] [--png /tmp/pics]

Not a test. Data: s2p's test data (AGPL), opengeos sample data (MIT); see the data folder's README.
"""
import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import data_dir, setup_path  # noqa: E402

setup_path()
from osgeo import gdal  # noqa: E402

from bare_earth.core import pipeline  # noqa: E402
from bare_earth.core.codes import OBJECT  # noqa: E402
from bare_earth.core.fill import fill_gaps  # noqa: E402

METHODS = ("dtm", "geodesic", "curvature", "slopeprofile", "rascor", "morphological")


def read(path):
    """Band 1 of ``path`` as float32 with its nodata as NaN, and the cell size (metres)."""
    ds = gdal.Open(str(path))
    band = ds.GetRasterBand(1)
    z = band.ReadAsArray().astype(np.float32)
    nd = band.GetNoDataValue()
    if nd is not None and np.isfinite(nd):
        z[z == nd] = np.nan
    return z, abs(ds.GetGeoTransform()[1])


def punched(z, seed):
    """``z`` with 25 % of its cells emptied at random and 60 rectangular holes of 2-8 cells."""
    rng = np.random.default_rng(seed)
    out = z.copy()
    out[rng.random(z.shape) < 0.25] = np.nan
    for _ in range(60):
        r, c = rng.integers(0, z.shape[0]), rng.integers(0, z.shape[1])
        a, b = rng.integers(2, 9, 2)
        out[r:r + a, c:c + b] = np.nan
    return out


def picture(path, z, filled, mask):
    """A PNG of a DSM: hillshade and height, the filled cells blue, the objects red."""
    from PIL import Image
    g = np.where(np.isfinite(filled), filled, np.nanmin(filled))
    gy, gx = np.gradient(g)
    shade = np.clip(0.5 + 0.5 * (-gx - gy) / np.sqrt(1 + gx ** 2 + gy ** 2), 0, 1)
    lo, hi = np.nanpercentile(filled, [1, 99])
    base = 0.6 * shade + 0.4 * np.clip((g - lo) / max(hi - lo, 1e-6), 0, 1)
    rgb = np.repeat(base[..., None], 3, axis=2)
    fill = ~np.isfinite(z) & np.isfinite(filled)
    rgb[fill] = rgb[fill] * 0.6 + np.array([0.0, 0.0, 0.4])
    rgb[~np.isfinite(filled)] = (0.3, 0.0, 0.3)
    obj = mask == OBJECT
    rgb[obj] = rgb[obj] * 0.4 + np.array([0.6, 0.0, 0.0])
    Image.fromarray((rgb * 255).astype(np.uint8)).save(path)


def matching(data, methods, png):
    folder = data / "raster" / "pleiades"
    names = [p for p in ("pair", "triplet") if (folder / f"{p}_dsm.tif").is_file()]
    if not names:
        print(f"image-matching part skipped: no {folder}/*_dsm.tif")
        return
    print("objects, % of the data cells" + "".join(f"{m[:9]:>10}" for m in methods))
    for name in names:
        z, cell = read(folder / f"{name}_dsm.tif")
        valid = np.isfinite(z)
        filled, n = pipeline.fill_empty_cells(z, (cell, cell))
        line, t0 = f"{name} ({100 * (1 - valid.mean()):.0f} % empty, {n} filled)", time.perf_counter()
        line = f"{line:<29}"
        for m in methods:
            mask = np.asarray(pipeline.run_array(m, z, cell, want_dtm=False).mask)
            line += f"{100 * np.count_nonzero(mask[valid] == OBJECT) / valid.sum():>10.2f}"
            if png:
                picture(Path(png) / f"{name}_{m}.png", z, filled, mask)
        print(line + f"   {time.perf_counter() - t0:.0f} s", flush=True)


def lidar(data, methods, seed):
    folder = data / "raster" / "opengeos"
    if not (folder / "dsm.tif").is_file():
        print(f"lidar part skipped: no {folder}/dsm.tif")
        return
    z, cell = read(folder / "dsm.tif")
    ref, _ = read(folder / "dtm.tif")
    zz = punched(z, seed)
    empty = mirror_difference(pipeline.fill_empty_cells(zz, (cell, cell))[0],
                              pipeline.fill_empty_cells(zz[::-1], (cell, cell))[0])
    print(f"opengeos, {100 * np.isnan(zz).mean():.0f} % empty: DTM RMSE (m); the fills of the south-up mirror, "
          f"flipped back: empty cells {empty:.4f} m")
    for m in methods:
        res = pipeline.run_array(m, zz, cell)
        ok = np.isfinite(res.dtm) & np.isfinite(ref)
        rmse = float(np.sqrt(np.mean((res.dtm[ok] - ref[ok]) ** 2)))
        # the DTM's gap fill alone, on the same cells mirrored (the filters' masks of a mirror differ too)
        holes = np.isfinite(zz) & (np.asarray(res.mask) != 0)
        gaps = mirror_difference(fill_gaps(zz, holes), fill_gaps(zz[::-1], holes[::-1]))
        print(f"  {m:<14} RMSE {rmse:6.3f}   gap fill of its mask mirrored: {gaps:.4f} m", flush=True)


def mirror_difference(a, b):
    """The largest difference between ``a`` and ``b`` flipped up-down, on the cells both hold."""
    b = b[::-1]
    both = np.isfinite(a) & np.isfinite(b)
    return float(np.max(np.abs(a[both] - b[both]))) if both.any() else float("nan")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None)
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--unfilled", action="store_true",
                    help="leave the empty cells empty (the filters see NaN) instead of the pipeline's fill")
    ap.add_argument("--png", default=None, help="folder for the pictures of the image-matching DSMs")
    ap.add_argument("--seed", type=int, default=12)
    a = ap.parse_args(argv)
    if a.unfilled:
        pipeline.fill_empty_cells = lambda z, cell: (z, 0)
    if a.png:
        Path(a.png).mkdir(parents=True, exist_ok=True)
    data, methods = data_dir(a.data), a.methods.split(",")
    matching(data, methods, a.png)
    lidar(data, methods, a.seed)


if __name__ == "__main__":
    main()
