"""Shared estimates made on a DSM before filtering: noise, terrain slope, block minima,
and the sampling of a large raster for them.

One copy of each estimate lives here, public, with a docstring that says what it measures
and on which surface. Filter modules call these when they derive their defaults (their
``resolve_*`` functions); where a method deliberately needs another statistic, its name
says so.
"""
import math

import numpy as np
from scipy import ndimage

#: Block side (metres) of the ground-level reference surface of
#: :func:`noise_ground_level`: wider than a tree crown or a house, so almost every block
#: holds a ground cell (a gap between crowns, a yard) and its minimum is at ground level.
GROUND_BLOCK_M = 20.0
#: Height (metres) above the ground-level reference surface within which a cell counts as
#: ground level before the noise is known: below any tree, car or building.
GROUND_BAND_M = 2.0
#: Second differences fewer than this on ground-level cells: the noise is not measurable.
GROUND_MIN_SAMPLES = 100
#: Lower quartile of ``|N(0, 1)|``.
_ABS_NORMAL_Q25 = 0.3186
#: Largest window (cells per side) the ground-level noise is measured on.
_GROUND_WINDOW = 1024


def _block_minima(z, k):
    """Minimum of every ``k x k`` block (NaN ignored; all-NaN blocks NaN)."""
    rows, cols = z.shape
    R, C = -(-rows // k), -(-cols // k)
    pad = np.full((R * k, C * k), np.nan, np.float32)
    pad[:rows, :cols] = z
    with np.errstate(invalid="ignore"):
        return np.fmin.reduce(np.fmin.reduce(pad.reshape(R, k, C, k), axis=3), axis=1)


def ground_level_reference(z, cell_size, block_m=GROUND_BLOCK_M):
    """The ground-level reference surface of a DSM and the terrain's median slope under it.

    The minimum of every block of ``block_m`` metres (at least 2 cells; blocks without a
    valid cell take the nearest block's value), interpolated bilinearly between the block
    centres back to the cells. Objects narrower than a block vanish from it; where a block
    holds no ground it stands on the object, which the caller's height band then admits.

    Returns
    -------
    surface : ndarray of float32
        Same shape as ``z``.
    slope : float
        Median gradient magnitude (rise/run) of the block-minimum surface (0 with fewer
        than 2 x 2 blocks).
    k : int
        Block side in cells.
    """
    z = np.asarray(z, np.float32)
    dx, dy = float(cell_size[0]), float(cell_size[1])
    k = max(2, int(round(block_m / max(dx, dy))))
    m = _block_minima(z, k)
    bad = ~np.isfinite(m)
    if bad.all():
        return np.full(z.shape, np.nan, np.float32), 0.0, k
    if bad.any():
        idx = ndimage.distance_transform_edt(bad, return_distances=False, return_indices=True)
        m = m[tuple(idx)]
    slope = 0.0
    if min(m.shape) >= 2:
        gy, gx = np.gradient(m.astype(np.float64), k * dy, k * dx)
        slope = float(np.median(np.hypot(gx, gy)))
    u = (np.arange(z.shape[0]) + 0.5) / k - 0.5
    v = (np.arange(z.shape[1]) + 0.5) / k - 0.5
    # separable bilinear interpolation between block centres (edges held)
    rows = ndimage.map_coordinates(m, np.meshgrid(u, np.arange(m.shape[1]), indexing="ij"),
                                   order=1, mode="nearest")
    surf = ndimage.map_coordinates(rows, np.meshgrid(np.arange(z.shape[0]), v, indexing="ij"),
                                   order=1, mode="nearest")
    return surf.astype(np.float32), slope, k


def ground_level_cells(z, cell_size, sigma=None, *, block_m=GROUND_BLOCK_M, band_m=GROUND_BAND_M):
    """Cells of a DSM standing at ground level (bool, same shape).

    A cell is at ground level when it stands less than ``max(band_m, 6 sigma)`` plus the
    median terrain slope times the block side above the ground-level reference surface
    (:func:`ground_level_reference`); ``sigma`` is the DSM's noise when known (None:
    ``band_m`` alone). Crowns and roofs, which stand metres above it, are left out; the
    ground between them, gaps in a canopy and low vegetation are in.
    """
    z = np.asarray(z, np.float32)
    ref, slope, k = ground_level_reference(z, cell_size, block_m)
    band = (band_m if sigma is None or not np.isfinite(sigma) else max(band_m, 6.0 * sigma))
    band += slope * k * max(float(cell_size[0]), float(cell_size[1]))
    with np.errstate(invalid="ignore"):
        return (z - ref) <= band


def noise_ground_level(z, cell_size, *, block_m=GROUND_BLOCK_M, band_m=GROUND_BAND_M,
                       iterations=3):
    """Standard deviation of the DSM's random height error measured on its ground-level
    cells only, metres (NaN when too few ground-level cells are seen).

    Noise measured on the whole DSM (second differences, residuals to the neighbours)
    measures the canopy wherever trees cover most of it: a forest at 4 m cells reads
    4-5 m of "noise" where the lidar's is 0.05 m, and every threshold derived from it
    (a height test of 3 sigma, a single-window mode) follows. Here the same statistic is
    taken on the cells at ground level:

    1. the ground-level reference surface (:func:`ground_level_reference`: minima of
       ``block_m`` blocks, interpolated), which objects narrower than a block do not
       reach;
    2. a cell is at ground level when it stands less than ``max(band_m, 6 sigma)`` plus
       the median terrain slope times the block side above that surface (``sigma`` the
       previous iteration's estimate; ``band_m`` to start);
    3. ``sigma`` is the lower quartile of the absolute second differences along rows,
       columns and both diagonals whose three cells are all at ground level (four
       directions: twice the samples of rows and columns where the ground shows only in
       small gaps), ``/ 0.3186 / sqrt(6)`` (white
       noise of ``sigma`` gives second differences of variance ``6 sigma^2``; the lower
       quartile ignores the edges and low vegetation left among them).

    Measured at full resolution on a central window of at most 1024 x 1024 cells.

    Parameters
    ----------
    z : array_like, 2-D
        DSM, NaN = nodata.
    cell_size : (float, float)
        ``(dx, dy)`` metres.

    Returns
    -------
    dict
        ``sigma`` (float, NaN when fewer than :data:`GROUND_MIN_SAMPLES` second
        differences lie on ground-level cells), ``samples`` (their number),
        ``ground_share`` (the share of valid cells at ground level), ``block_cells``.
    """
    z = np.asarray(z, np.float32)
    rows, cols = z.shape
    h, w = min(rows, _GROUND_WINDOW), min(cols, _GROUND_WINDOW)
    r0, c0 = (rows - h) // 2, (cols - w) // 2
    z = z[r0:r0 + h, c0:c0 + w]
    out = {"sigma": float("nan"), "samples": 0, "ground_share": 0.0, "block_cells": 0}
    if min(z.shape) < 3 or not np.isfinite(z).any():
        return out
    ref, slope, k = ground_level_reference(z, cell_size, block_m)
    out["block_cells"] = k
    dx, dy = float(cell_size[0]), float(cell_size[1])
    d_row = z[:, :-2] - 2 * z[:, 1:-1] + z[:, 2:]
    d_col = z[:-2] - 2 * z[1:-1] + z[2:]
    d_dia = z[:-2, :-2] - 2 * z[1:-1, 1:-1] + z[2:, 2:]
    d_ant = z[:-2, 2:] - 2 * z[1:-1, 1:-1] + z[2:, :-2]
    height = z - ref
    valid = np.isfinite(z)
    sigma = None
    for _ in range(iterations):
        band = (band_m if sigma is None else max(band_m, 6.0 * sigma)) + slope * k * max(dx, dy)
        with np.errstate(invalid="ignore"):
            g = height <= band
        mid = g[1:-1, 1:-1]
        d = np.concatenate([d_row[g[:, :-2] & g[:, 1:-1] & g[:, 2:]],
                            d_col[g[:-2] & g[1:-1] & g[2:]],
                            d_dia[g[:-2, :-2] & mid & g[2:, 2:]],
                            d_ant[g[:-2, 2:] & mid & g[2:, :-2]]])
        d = d[np.isfinite(d)]
        out["samples"] = int(d.size)
        out["ground_share"] = float(np.count_nonzero(g) / max(1, np.count_nonzero(valid)))
        if d.size < GROUND_MIN_SAMPLES:
            out["sigma"] = float("nan")
            return out
        new = float(np.percentile(np.abs(d), 25.0)) / _ABS_NORMAL_Q25 / math.sqrt(6.0)
        if sigma is not None and abs(new - sigma) <= 1e-3 * max(sigma, 1e-6):
            sigma = new
            break
        sigma = new
    out["sigma"] = sigma
    return out


def ground_spread(stacks, tile=16, quantile=0.25, min_share=0.25):
    """:func:`smooth_spread` of values kept only on chosen cells (the others NaN).

    Per ``tile x tile`` tile the robust spread ``1.4826 MAD`` of its finite values when
    they are at least ``min_share`` of the tile, and the ``quantile`` of those tiles'
    spreads; with no such tile, the spread of all finite values pooled (0 with fewer than
    100). Used on the bends of ground-level cells (curvature's threshold), where the
    ground shows in gaps that rarely fill a tile.
    """
    mads, pooled = [], []
    for v in stacks:
        b, r, c = v.shape
        tr, tc = max(1, min(tile, r)), max(1, min(tile, c))
        nr, nc = r // tr, c // tc
        t = v[:, :nr * tr, :nc * tc].reshape(b, nr, tr, nc, tc).transpose(1, 3, 0, 2, 4)
        t = t.reshape(nr * nc, -1).astype(np.float64)
        ok = np.count_nonzero(np.isfinite(t), axis=1) >= max(1, int(min_share * t.shape[1]))
        if ok.any():
            t = t[ok]
            with np.errstate(invalid="ignore"):
                med = np.nanmedian(t, axis=1, keepdims=True)
                mad = 1.4826 * np.nanmedian(np.abs(t - med), axis=1)
            mads.append(mad[np.isfinite(mad)])
        pooled.append(v[np.isfinite(v)].astype(np.float64))
    mad = np.concatenate(mads) if mads else np.empty(0)
    if mad.size:
        return float(np.quantile(mad, quantile))
    a = np.concatenate(pooled) if pooled else np.empty(0)
    if a.size < 100:
        return 0.0
    return float(1.4826 * np.median(np.abs(a - np.median(a))))


#: Radius (m) of the ring of cells a low blunder must lie below (:func:`below_surroundings`).
PIT_RADIUS_M = 10.0
#: Half-width (m, at least 2 cells) of the blunder cluster left out of that ring.
PIT_CLUSTER_M = 1.0


def _min_over_offsets(b, lo, hi, axis):
    """``out[i] = min(b[i + lo .. i + hi])`` along ``axis`` (+inf outside the array)."""
    n = hi - lo + 1
    pad = max(abs(lo), abs(hi))
    widths = [(0, 0)] * b.ndim
    widths[axis] = (pad, pad)
    m = ndimage.minimum_filter1d(np.pad(b, widths, constant_values=np.inf), n, axis=axis,
                                 mode="constant", cval=np.inf)
    start = pad + lo + n // 2             # m[j] covers j - n//2 .. j - n//2 + n - 1
    idx = [slice(None)] * b.ndim
    idx[axis] = slice(start, start + b.shape[axis])
    return m[tuple(idx)]


def below_surroundings(z, cell_size, depth_m, radius_m=PIT_RADIUS_M, cluster_m=PIT_CLUSTER_M):
    """Cells lying more than ``depth_m`` below every cell of the square ring around them.

    The ring spans ``radius_m`` around the cell without the cell's own cluster (half-width
    ``cluster_m``, at least 2 cells): a matching blunder or multipath pit is below all the
    ground around it, a gap between tree crowns or roofs is at the level of the other gaps
    within the ring. Translation-invariant (four rectangular minimum filters), NaN ignored.
    """
    dx, dy = cell_size
    a = np.where(np.isfinite(z), z, np.inf).astype(np.float32)
    iy = max(2, int(np.ceil(cluster_m / dy)))
    ix = max(2, int(np.ceil(cluster_m / dx)))
    ry = max(iy + 2, int(np.ceil(radius_m / dy)))
    rx = max(ix + 2, int(np.ceil(radius_m / dx)))
    rows = ndimage.minimum_filter1d(a, 2 * rx + 1, axis=1, mode="constant", cval=np.inf)
    mid = ndimage.minimum_filter1d(a, 2 * iy + 1, axis=0, mode="constant", cval=np.inf)
    ring = np.minimum(_min_over_offsets(rows, -ry, -iy - 1, 0), _min_over_offsets(rows, iy + 1, ry, 0))
    np.minimum(ring, _min_over_offsets(mid, -rx, -ix - 1, 1), out=ring)
    np.minimum(ring, _min_over_offsets(mid, ix + 1, rx, 1), out=ring)
    with np.errstate(invalid="ignore"):
        return np.isfinite(ring) & (a < ring - np.float32(depth_m))
