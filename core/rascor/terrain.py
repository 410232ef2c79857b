"""RASCOR step 1: terrain characterisation (Jacobsen 2004).

The area is classed as homogeneous or not and as *flat*, *rolling* (undulated) or
*mountainous* from the slopes of a lower envelope of the DSM; the class chooses the models
of the moving profiles and surfaces (:func:`model_degree`) and the defaults. The random
error of the DSM (:func:`estimate_sigma`) is estimated here too.
"""
from typing import Sequence, Union

import numpy as np

from ..common import as_cell_size, as_surface, report
from ..estimate import noise_plane_residual

#: Terrain classes and the degree of the profile / surface model each selects.
TERRAIN_CLASSES = ("flat", "rolling", "mountainous")
_DEGREE = {"flat": 0, "rolling": 1, "mountainous": 2}
#: Median slope (rise/run) of the lower envelope separating the classes.
_FLAT_MAX_SLOPE, _ROLLING_MAX_SLOPE = 0.05, 0.20
#: Homogeneous: at least this share of the fine tiles has the area's class.
_HOMOGENEOUS_SHARE = 0.9
#: Floor of the estimated random error (m): rasterised laser/matching DSMs are never exact.
SIGMA_FLOOR = 0.10


def model_degree(terrain_class: str, homogeneous: bool = True) -> int:
    """Degree of the profile / surface model: 0 mean or horizontal plane (flat), 1 linear
    regression or inclined plane (rolling), 2 polynomial (mountainous). A flat area that
    is not homogeneous (embankments, cuts, terraces) gets the linear model: a mean is
    biased wherever a window sees a slope from one side only."""
    if terrain_class not in _DEGREE:
        raise ValueError(f"terrain_class must be one of {TERRAIN_CLASSES}; got {terrain_class!r}.")
    d = _DEGREE[terrain_class]
    return d if homogeneous else max(d, 1)


def as_homogeneous(v):
    """``homogeneous`` as a bool (accepts the Param's enum strings)."""
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if v in ("homogeneous", "yes", 1):
        return True
    if v in ("inhomogeneous", "no", 0):
        return False
    raise ValueError(f"homogeneous must be True/False, 'homogeneous' or 'inhomogeneous' (or "
                     f"'auto' in resolve_rascor_params); got {v!r}.")


def _tile_low(z, n):
    """Low envelope on non-overlapping ``n x n`` tiles: the 5th percentile of each tile.

    The order statistic comes from partial sorting (``np.partition``: the value a sort
    gives, 3 x faster on 10 x 10 tiles) for the full tiles (all of the same rank), from
    sorting each tile for the others. One row of tiles at a time: its cells are gathered
    tile by tile into a scratch array that stays in the cache (gathering all tiles at once
    took as long as the partial sorts).
    """
    rows, cols = z.shape
    R, C = -(-rows // n), -(-cols // n)
    z = np.asarray(z)
    low = np.empty((R, C), np.float32)
    slab = np.full((n, C * n), np.nan, np.float32)  # NaN sorts last, like missing cells
    t = np.empty((C, n * n), np.float32)
    for r in range(R):
        r0, r1 = r * n, min(rows, (r + 1) * n)
        if r1 - r0 < n or C * n != cols:
            slab.fill(np.nan)
        slab[:r1 - r0, :cols] = z[r0:r1]
        if np.isinf(slab).any():
            slab[np.isinf(slab)] = np.nan
        t.reshape(C, n, n)[...] = slab.reshape(n, C, n).transpose(1, 0, 2)
        low[r] = _rank_low(t, n)
    return low


def _rank_low(t, n):
    """The 5th percentile of each row of ``t`` (a row of ``n x n`` tiles, NaN for missing
    cells; sorted in place), NaN where fewer than ``max(3, n^2 / 10)`` cells are finite."""
    cnt = np.count_nonzero(np.isfinite(t), axis=1)
    kth = (0.05 * cnt).astype(int)
    low = np.empty(t.shape[0], np.float32)
    full = cnt == n * n
    if full.any():
        k0 = int(kth[np.argmax(full)])
        tf = t if full.all() else t[full]
        tf.partition(k0, axis=1)
        low[full] = tf[:, k0]
        rest = np.flatnonzero(~full)
        if rest.size:
            srt = np.sort(t[rest], axis=1)
            low[rest] = srt[np.arange(rest.size), kth[rest]]
    else:
        t.sort(axis=1)
        low[:] = np.take_along_axis(t, kth[:, None], axis=1)[:, 0]
    low[cnt < max(3, n * n // 10)] = np.nan
    return low


def estimate_sigma(z: np.ndarray) -> float:
    """Random error of the DSM (m) from the 4-neighbour Laplacian residual.

    ``r = z - mean(4 neighbours)`` has standard deviation ``sigma sqrt(1.25)`` on smooth
    ground; the lower quartile of ``|r|`` (0.3186 standard deviations for normal errors,
    robust to objects, edges and vegetation even when they cover half the area) gives
    ``sigma`` (:func:`~bare_earth.core.estimate.noise_plane_residual`, float64, windows
    spread over a large raster), floored at 0.1 m (the floor also when fewer than 10
    residuals exist).
    """
    return float(max(SIGMA_FLOOR, noise_plane_residual(z, dtype=np.float64, min_count=10,
                                                        default=SIGMA_FLOOR)))


def _tile_slopes(low, sx, sy):
    """Slopes (rise/run) of a tile envelope: per tile the steepest step to a neighbour in
    x and in y, combined; finite values only."""
    with np.errstate(invalid="ignore"):
        gx = np.full(low.shape, np.nan)
        gy = np.full(low.shape, np.nan)
        if low.shape[1] > 1:
            d = np.abs(np.diff(low, axis=1)) / sx
            gx = np.fmax(np.pad(d, ((0, 0), (0, 1)), constant_values=np.nan),
                         np.pad(d, ((0, 0), (1, 0)), constant_values=np.nan))
        if low.shape[0] > 1:
            d = np.abs(np.diff(low, axis=0)) / sy
            gy = np.fmax(np.pad(d, ((0, 1), (0, 0)), constant_values=np.nan),
                         np.pad(d, ((1, 0), (0, 0)), constant_values=np.nan))
        slope = np.hypot(np.nan_to_num(gx), np.nan_to_num(gy))
    slope[~(np.isfinite(gx) | np.isfinite(gy))] = np.nan
    return slope[np.isfinite(slope)]


def characterise_terrain(z: np.ndarray, cell_size: Union[float, Sequence[float]],
                         tile_m: float = 25.0) -> dict:
    """Step 1: class the area as flat / rolling / mountainous and (in)homogeneous.

    The DSM is reduced to a lower envelope (5th percentile of ``tile_m`` tiles: objects
    smaller than a tile vanish) and the slopes (rise/run) between neighbouring tiles are
    analysed (Jacobsen 2004: the terrain type selects the filter models and defaults).

    Parameters
    ----------
    z : array_like
        DSM, NaN = nodata.
    cell_size : float or (float, float)
        Cell size (dx, dy) in metres.
    tile_m : float
        Tile edge of the envelope, metres.

    Returns
    -------
    dict
        ``terrain_class`` ("flat" median slope < 5 %, "rolling" < 20 %, else
        "mountainous"), ``homogeneous`` (at least 75 % of the tiles have that class),
        ``class_shares`` (share of tiles per class), ``slope_median``, ``slope_p90``
        (rise/run), ``relief_m`` (2-98 % range of the envelope), ``sigma_m`` (random error,
        :func:`estimate_sigma`), ``tile_m``.
    """
    return characterise_with_envelope(as_surface(z), as_cell_size(cell_size), tile_m)[0]


def characterise_with_envelope(z, cell_size, tile_m=25.0, progress=None, with_sigma=True):
    """:func:`characterise_terrain` and its lower envelope (for step 2's limits).
    ``progress(fraction)`` (optional, may raise ``Cancelled``) after each stage. ``with_sigma`` False: the
    random error is not estimated (``sigma_m`` None; the caller has it: 0.25 s of CPU on 16 Mcells)."""
    dx, dy = cell_size
    if tile_m <= 0:
        raise ValueError(f"tile_m must be positive (metres); got {tile_m}.")
    n = max(3, int(round(tile_m / max(dx, dy))))
    n = min(n, max(3, min(z.shape) // 3))
    low = _tile_low(z, n).astype(np.float64)
    report(progress, 0.4)
    s = _tile_slopes(low, n * dx, n * dy)
    med = float(np.median(s)) if s.size else 0.0
    cls = "flat" if med < _FLAT_MAX_SLOPE else "rolling" if med < _ROLLING_MAX_SLOPE else "mountainous"
    # homogeneity on tiles 2.5 x finer: embankments, cuts and terraces show up there
    nf = max(3, n * 2 // 5)
    sf = _tile_slopes(_tile_low(z, nf).astype(np.float64), nf * dx, nf * dy)
    report(progress, 0.8)
    sf = sf if sf.size else np.zeros(1)
    tiles = np.where(sf < _FLAT_MAX_SLOPE, 0, np.where(sf < _ROLLING_MAX_SLOPE, 1, 2))
    shares = {c: float(np.mean(tiles == i)) for i, c in enumerate(TERRAIN_CLASSES)}
    if not s.size:
        s = np.zeros(1)
    lv = low[np.isfinite(low)]
    relief = float(np.percentile(lv, 98) - np.percentile(lv, 2)) if lv.size else 0.0
    sigma = estimate_sigma(z) if with_sigma else None     # on windows spread over a large raster
    report(progress, 1.0)
    return {"terrain_class": cls, "homogeneous": bool(shares[cls] >= _HOMOGENEOUS_SHARE),
            "class_shares": shares, "slope_median": med,
            "slope_p90": float(np.percentile(s, 90)), "relief_m": relief,
            "sigma_m": sigma, "tile_m": n * max(dx, dy)}, low


