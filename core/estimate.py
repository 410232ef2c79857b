"""Shared estimates made on a DSM before filtering: noise, terrain slope, block minima,
and the sampling of a large raster for them.

One copy of each estimate lives here, public, with a docstring that says what it measures
and on which surface. Filter modules call these when they derive their defaults (their
``resolve_*`` functions); where a method deliberately needs another statistic, its name
says so:

* :func:`sample_windows`: the cells a parameter estimate looks at on a large raster
  (windows spread over the whole raster; small rasters whole).
* :func:`block_minima`: the minimum surface of ``k x k`` blocks (objects smaller than a
  block vanish from it: an approximation of the terrain under them).
* :func:`terrain_slopes`: slopes (rise/run) of that block-minimum surface.
* :func:`cell_slopes`: the surface's own slope at a few cells (central differences, gathered there).
* :func:`terrain_bends`: its second differences scaled to one cell (how much the ground
  bends from one cell to the next: metres on coarse DEMs of hills, nothing at 1 m).
* Noise of the DSM (the standard deviation ``sigma`` of its random height error), three
  robust statistics for three needs:

  - :func:`noise_second_difference`: median of the absolute second differences
    (a MAD: any surface with fewer than half its cells on edges or objects);
  - :func:`noise_second_difference_quartile`: lower quartile of the centred absolute
    second differences (urban or wooded scenes where edges and crowns may cover most
    of the raster);
  - :func:`noise_plane_residual`: lower quartile of the residual to the mean of the
    four neighbours (the plane through them), the same quantity on a 5-cell stencil;
  - :func:`noise_second_difference_tiles`: the second differences' spread on the smooth
    parts of the surface (:func:`smooth_spread`: a low quantile of per-tile MADs);
  - :func:`height_quantum` and :func:`noise_floor`: the step heights are rounded to (a DSM
    in whole metres) and its rounding error, below which the noise plane residual and the
    ground-level noise never read;
  - :func:`repeated_height_share` and :func:`lowest_point_spread`: how far apart the
    independent heights of a gridded point cloud lie, and the spread of a ground cell's
    height about the surface that this spacing on sloping ground and the noise make.
* The ground level under canopy and roofs (issue 12: estimates made on the right surface):

  - :func:`ground_level_reference`: interpolated 20 m block minima, the level objects
    do not reach (optionally without the blocks a low blunder pulled down,
    :func:`lift_low_blocks`);
  - :func:`ground_level_cells`: the cells within a height band of it;
  - :func:`noise_ground_level`: the noise measured on those cells only (never the
    canopy's or the roofs' roughness);
  - :func:`sensor_noise`: of that estimate, the cleanest quarter of its tiles where they read
    less than the whole window (low vegetation among the ground-level cells);
  - :func:`ground_spread`: :func:`smooth_spread` on chosen cells only;
  - :func:`below_surroundings`: a pit lies below every cell of the ring around it (a
    low blunder, not a gap between crowns);
  - :func:`below_level_rim`: a pit lies below the level rim just around it (a blunder in
    open ground, even with another blunder within that ring), and the candidates it leaves
    :func:`below_narrow_gap` (a line or cluster of blunders along a wall: far below the
    level ground on one side of a gap narrower than a cluster);
  - :func:`below_level_neighbours`: a pit lies below its level neighbours (a blunder in a
    level surface, however many blunders lie around it).
* :func:`object_widths`: how wide the widest objects of a mask are (the window a moving
  fit needs to reach ground beyond them).
* :func:`raised_parts`: the parts of a DSM standing on walls (more of their rim steps down
  than up: roofs, decks, crowns), which block minima wider than them no longer see.
"""
import contextlib
import hashlib
import math
import threading
from functools import partial

import numpy as np
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from .blocks import run_sharing
from .common import report, running_mean_down

#: Cells a parameter estimate looks at on a large raster (:func:`sample_windows`):
#: medians and quantiles are stable far below that.
SAMPLE_CELLS = 1_000_000
#: Side (cells) of the windows :func:`sample_windows` spreads over a large raster.
SAMPLE_WINDOW = 256
#: Quantiles of ``|N(0, 1)|``: its median (1 / 1.4826) and its lower quartile.
_ABS_NORMAL_MEDIAN_INV = 1.4826
_ABS_NORMAL_QUARTILE = 0.3186


def sample_windows(z, cells=SAMPLE_CELLS, side=SAMPLE_WINDOW):
    """The parts of a raster a parameter estimate looks at.

    ``z`` itself when it has at most ``cells`` cells (or is narrower than two windows),
    else about ``cells / side**2`` windows of ``side x side`` cells, one centred in each
    cell of a regular ``ny x nx`` grid over the raster (four windows: centred on the
    quadrants), so the sample sees all its parts, not only its centre, and keeps away
    from its edges (nodata collars). Windows are views (no copy), contiguous along their
    rows, so sampling reads a fraction of the raster.

    Parameters
    ----------
    z : ndarray, 2-D
        The raster (any dtype).
    cells : int
        Largest raster used whole, and about the cells sampled from a larger one.
    side : int
        Window side, cells.

    Returns
    -------
    list of ndarray
        Views of ``z``.
    """
    rows, cols = z.shape
    if z.size <= cells or rows < 2 * side or cols < 2 * side:
        return [z]
    n = max(1, cells // (side * side))
    ny = max(1, min(rows // side, int(round(np.sqrt(n * rows / cols)))))
    nx = max(1, min(cols // side, -(-n // ny)))
    r0 = [int(max(0, min(rows - side, (i + 0.5) / ny * rows - side / 2))) for i in range(ny)]
    c0 = [int(max(0, min(cols - side, (j + 0.5) / nx * cols - side / 2))) for j in range(nx)]
    return [z[r:r + side, c:c + side] for r in r0 for c in c0]


def block_minima(z, k):
    """Minimum of every ``k x k`` block of a surface (nodata ignored).

    Blocks start at the raster's origin; the last row and column of blocks may be
    partial. Non-finite cells (NaN, +-inf) are nodata; a block without a valid cell is
    NaN. Objects smaller than a block vanish from this surface: on a DSM it
    approximates the terrain under them.

    Band by band of ``k`` rows: the minimum down the band's columns (contiguous rows,
    cached), then over each run of ``k`` columns; ``fmin`` ignores NaN without copies.

    Parameters
    ----------
    z : array_like, 2-D
        Surface.
    k : int
        Block side, cells (>= 1).

    Returns
    -------
    ndarray of float32, shape ``(ceil(rows / k), ceil(cols / k))``
    """
    z = np.asarray(z, np.float32)
    k = int(k)
    if k < 1:
        raise ValueError(f"block side k must be at least 1 cell; got {k}.")
    if k == 1:
        return np.where(np.isfinite(z), z, np.float32(np.nan))
    rows, cols = z.shape
    nr, nc = -(-rows // k), -(-cols // k)
    out = np.empty((nr, nc), np.float32)
    pad = np.full(nc * k, np.nan, np.float32) if cols % k else None
    has_inf = bool(np.isinf(z).any())
    for i in range(nr):
        rows_i = z[i * k:(i + 1) * k]
        if has_inf:
            rows_i = np.where(np.isinf(rows_i), np.float32(np.nan), rows_i)
        band = np.fmin.reduce(rows_i, axis=0)
        if pad is not None:
            pad[:cols] = band
            band = pad
        out[i] = np.fmin.reduce(band.reshape(nc, k), axis=1)
    return out


def held_block_side(shape, k, min_blocks=3, min_side=2):
    """Block side (cells) for the block-minimum estimates on a raster of ``shape``: ``k`` when
    the raster holds ``min_blocks`` blocks of it along its shorter axis (the last may be
    partial, as on any raster), else scaled down to ``min(shape) // min_blocks`` (whole
    blocks), but never below ``min_side`` cells nor above ``k``.

    A small raster (a drone DSM crop tens of metres wide) still holds enough ground to
    measure the terrain under its objects; blocks as large as a large raster's would leave
    it fewer blocks than a gradient needs. Rasters that hold ``min_blocks`` blocks keep
    ``k``. Under ``min_blocks`` blocks of ``min_side`` cells the estimate has too few blocks
    (not measurable).

    Examples: ``held_block_side((800, 800), 400)`` -> 266 (3 blocks of 266 cells);
    ``held_block_side((116, 200), 40)`` -> 40 (3 blocks, the last of 36 cells);
    ``held_block_side((3, 3), 40)`` -> 2 (2 blocks: not measurable).
    """
    k, n = int(k), min(shape)
    if -(-n // k) >= int(min_blocks):
        return k
    return min(k, max(int(min_side), n // int(min_blocks)))


def terrain_slopes(z, cell_size, k, min_blocks=2):
    """Slopes (rise/run) of the terrain under the objects: the gradient magnitude of the
    block-minimum surface.

    The surface is reduced to the minimum of ``k x k`` blocks (:func:`block_minima`) and
    its gradient is taken by central differences (``np.gradient``, one-sided at the
    edges) with the block spacing ``(k dy, k dx)``; its magnitude is the steepest slope
    of the ground whatever its direction.

    Parameters
    ----------
    z : array_like, 2-D
        DSM, NaN = nodata.
    cell_size : (float, float)
        ``(dx, dy)``, metres.
    k : int
        Block side, cells: larger than the objects to be ignored.
    min_blocks : int
        Fewest blocks along each axis for a slope (>= 2); fewer give no slopes.

    Returns
    -------
    ndarray of float64, 1-D
        The finite slopes, one per block (empty when not measurable). Summarise them
        with the statistic the method needs (median, a percentile).
    """
    dx, dy = cell_size
    m = block_minima(z, k)
    if min(m.shape) < max(2, int(min_blocks)):
        return np.empty(0)
    gy, gx = np.gradient(m.astype(np.float64), k * dy, k * dx)
    s = np.hypot(gx, gy).ravel()
    return s[np.isfinite(s)]


def cell_slopes(z, cell_size, candidates):
    """The surface's own slope (rise/run) at a few cells: the gradient magnitude by central
    differences of the four neighbours (one-sided at the raster's edges, as ``np.gradient``),
    read at ``candidates`` only (no raster-sized gradient).

    Parameters
    ----------
    z : array_like, 2-D
        DSM, NaN = nodata.
    cell_size : (float, float)
        ``(dx, dy)``, metres.
    candidates : array_like of bool, z's shape
        The cells whose slope is wanted.

    Returns
    -------
    ndarray of float64, 1-D
        One slope per candidate, in the order of ``np.flatnonzero(candidates)``; NaN where a
        neighbour it reads is NaN; 0 along an axis of one cell.

    Examples
    --------
    >>> z = np.array([[0.0, 1.0, 2.0], [0.0, 1.0, 2.0]], np.float32)
    >>> cell_slopes(z, (2.0, 1.0), np.ones(z.shape, bool)).tolist()
    [0.5, 0.5, 0.5, 0.5, 0.5, 0.5]
    """
    z = np.asarray(z)
    h, w = z.shape
    idx = np.flatnonzero(np.asarray(candidates, bool))
    r, c = np.divmod(idx, w)
    flat = z.ravel()
    out = np.zeros(idx.size, np.float64)
    for lo, hi, step, width in ((np.maximum(c - 1, 0), np.minimum(c + 1, w - 1), 1, float(cell_size[0])),
                                (np.maximum(r - 1, 0), np.minimum(r + 1, h - 1), w, float(cell_size[1]))):
        base = idx - (c if step == 1 else r * w)           # the row's (column's) first cell
        span = (hi - lo).astype(np.float64)
        d = flat[base + hi * step].astype(np.float64) - flat[base + lo * step]
        with np.errstate(invalid="ignore", divide="ignore"):
            g = np.where(span > 0, d / (span * width), 0.0)
        out += g * g
    return np.sqrt(out)



def block_expand(a, k, shape):
    """Each cell of a block raster ``a`` (as :func:`block_minima` gives it) repeated over its ``k x k``
    block, cut to the full raster's ``shape`` (the rows are cut before the columns are repeated).

    >>> block_expand(np.array([[1, 2], [3, 4]]), 2, (3, 3))
    array([[1, 1, 2],
           [1, 1, 2],
           [3, 3, 4]])
    """
    k = int(k)
    a = np.asarray(a)
    # each block row's cells repeated along the row once, then copied as whole rows k times (a repeat down
    # the columns and one along the rows of the whole raster cost twice as much); the same values, C-ordered
    rows = np.repeat(a, k, axis=1)[:, :shape[1]]
    out = np.empty((a.shape[0] * k, rows.shape[1]), a.dtype)
    out.reshape(a.shape[0], k, rows.shape[1])[...] = rows[:, None, :]
    return out[:shape[0]]


def block_minima_plane_residual(z, cell_size, k):
    """Largest distance (metres, vertical) of the ``k x k`` block minima (:func:`block_minima`)
    from their least-squares plane: 0 on a tilted plane however steep, the height of an object
    wider than the blocks that stands in some of them. NaN with fewer than 3 finite blocks.

    Block ``(i, j)`` sits at ``(j k dx, i k dy)``; the plane ``a + b x + c y`` is fitted to
    the finite minima (``numpy.linalg.lstsq``).
    """
    dx, dy = cell_size
    m = block_minima(z, k).astype(np.float64)
    i, j = np.nonzero(np.isfinite(m))
    if i.size < 3:
        return float("nan")
    a = np.column_stack([np.ones(i.size), j * (k * dx), i * (k * dy)])
    h = m[i, j]
    coef = np.linalg.lstsq(a, h, rcond=None)[0]
    return float(np.abs(h - a @ coef).max())


def terrain_bends(z, k):
    """Second differences of the terrain under the objects over one cell, metres: those of
    the block-minimum surface, scaled from the block spacing to the cell.

    The surface is reduced to the minimum of ``k x k`` blocks (:func:`block_minima`:
    objects smaller than a block vanish) and its second differences ``m[i-1] - 2 m[i] +
    m[i+1]`` along the rows and the columns (block spacing ``k`` cells) are divided by
    ``k^2``: a smooth surface of curvature ``c`` has second difference ``c s^2`` over the
    spacing ``s``, so the one over ``k`` cells is ``k^2`` times the one over a cell. Noise and objects do not scale
    that way, and the block minima hold neither: this is the terrain's own change of
    rise from one cell to the next, which grows with the square of the cell (metres on a
    24 m DEM of hills, millimetres on 1 m lidar).

    Parameters
    ----------
    z : array_like, 2-D
        DSM, NaN = nodata.
    k : int
        Block side, cells (>= 1): larger than the objects to be ignored.

    Returns
    -------
    ndarray of float64, 1-D
        The finite second differences (signed, metres over one cell), along the rows then
        the columns (empty with fewer than 3 blocks along both axes). Summarise them with
        the statistic the method needs.
    """
    k = int(k)
    m = block_minima(z, k).astype(np.float64)
    d = []
    if m.shape[1] >= 3:
        d.append((m[:, :-2] - 2.0 * m[:, 1:-1] + m[:, 2:]).ravel())
    if m.shape[0] >= 3:
        d.append((m[:-2] - 2.0 * m[1:-1] + m[2:]).ravel())
    d = np.concatenate(d) if d else np.empty(0)
    return d[np.isfinite(d)] / float(k * k)


#: Distinct heights :func:`height_quantum` looks at (the lowest of the sample).
QUANTUM_VALUES = 100_000
#: A height lies on the quantum's grid when within this fraction of the quantum of it.
QUANTUM_TOLERANCE = 0.01


def height_quantum(z):
    """The step the DSM's heights are rounded to, metres (0 when they are not rounded).

    Heights stored in whole metres (an Int16 SRTM or Copernicus DEM) or in decimetres lie on
    a grid of multiples of a step ``q``: every difference between two distinct heights is a
    multiple of the smallest one. Rounding adds to each height a uniform error of standard
    deviation ``q / sqrt(12)`` (0.29 m for whole metres), which the noise statistics below
    do not see: on such a DSM most second differences and neighbour residuals are exactly
    0, their lower quartile reads 0 and every threshold set from it is passed by a single
    step of ``q`` on a gentle slope (see :func:`noise_floor`).

    Measured on the distinct heights of :func:`sample_windows` (at most
    :data:`QUANTUM_VALUES` of them): ``q`` is the smallest difference between two
    consecutive distinct heights (refined as the mean step over the differences of up to 10
    steps) when every difference lies within :data:`QUANTUM_TOLERANCE` ``q`` of a multiple
    of it; 0 with fewer than 3 distinct heights, when they are not on such a grid (float
    heights with noise), or when the step is within 16 float32 spacings of the heights (the
    storage's own grid).

    Examples
    --------
    >>> height_quantum(np.array([[1.0, 2.0, 4.0], [7.0, 2.0, 1.0]]))
    1.0
    >>> height_quantum(np.array([[1.0, 2.5, 4.0], [7.5, 2.0, 1.0]]))
    0.5
    >>> height_quantum(np.array([[1.0, 2.013, 4.3], [7.77, 2.0, 1.0]]))
    0.0
    """
    # the distinct heights in the DSM's own dtype, then in float64 (the same values: sorting float32 is faster)
    v = [w[np.isfinite(w)].ravel() for w in sample_windows(np.asarray(z))]
    v = np.unique(np.concatenate(v)).astype(np.float64) if v else np.empty(0)
    if v.size > QUANTUM_VALUES:
        v = v[:QUANTUM_VALUES]
    if v.size < 3:
        return 0.0
    d = np.diff(v)
    q = float(d.min())
    # float32 storage is itself a grid (its spacing at these heights) and moves each height
    # by up to that spacing: steps within a few spacings are no rounding of the heights
    ulp = float(np.spacing(np.float32(np.abs(v).max())))
    if not q > 16 * ulp:
        return 0.0
    small = d <= 10.5 * q                     # the step refined on the small differences
    q = float(d[small].sum() / np.round(d[small] / q).sum())
    n = np.round(d / q)
    if np.any(np.abs(d - n * q) > QUANTUM_TOLERANCE * q + 4 * ulp):
        return 0.0
    return q


def noise_floor(sigma, quantum):
    """A noise estimate ``sigma`` raised to the rounding error of heights stored in steps of
    ``quantum`` (:func:`height_quantum`): ``max(sigma, quantum / sqrt(12))``, the standard
    deviation of a uniform error over one step (NaN stays NaN)."""
    if not np.isfinite(sigma):
        return sigma
    return max(float(sigma), float(quantum) / math.sqrt(12.0))


def repeated_height_share(z, level_cells=0):
    """Share of the pairs of row and column neighbours (both heights finite) whose heights are exactly equal.

    A raster made from points with fewer points than cells repeats a point's height over the
    empty cells around it (nearest-neighbour fill, several cells per return): the independent
    heights then lie ``1 / (1 - share)`` cells apart on average (runs of equal cells), which
    :func:`lowest_point_spread` takes as their spacing. A DSM with a height per cell reads
    near 0; whole-metre heights on flat land read high as well, and their rounding is the
    spread of such a step. Measured on :func:`sample_windows` of a large raster; 0 when no pair
    is finite. With ``level_cells`` > 1 (odd), the pairs touching a ``level_cells`` x ``level_cells``
    square of one height (a level area: water, a constant fill of a gap, a noise-free plane)
    are left out: one return's cells are no wider than the returns' spacing, while a level area
    would count as one return repeated over all its cells.
    """
    if level_cells > 1 and level_cells % 2 == 0:
        raise ValueError(f"level_cells must be odd (a square centred on a cell); got {level_cells}")
    same = pairs = 0
    for w in sample_windows(np.asarray(z)):
        level = None
        if level_cells > 1:       # centres of level squares inside the window, then their cells
            with np.errstate(invalid="ignore"):
                v = np.where(np.isfinite(w), w, np.inf)
                flat = ndimage.maximum_filter(v, level_cells, mode="constant", cval=np.inf) == \
                    ndimage.minimum_filter(v, level_cells, mode="constant", cval=-np.inf)
            flat &= np.isfinite(w)
            level = ndimage.maximum_filter(flat, level_cells, mode="constant")
        for sa, sb in ((np.s_[:, 1:], np.s_[:, :-1]), (np.s_[1:], np.s_[:-1])):
            a, b = w[sa], w[sb]
            ok = np.isfinite(a) & np.isfinite(b)
            if level is not None:
                ok &= ~(level[sa] | level[sb])
            pairs += int(np.count_nonzero(ok))
            same += int(np.count_nonzero(ok & (a == b)))
    return float(same) / pairs if pairs else 0.0


def height_resolution(z):
    """The smallest height difference float32 heights ``z`` can hold at their largest magnitude
    (``np.spacing``), metres: heights known exactly (a synthetic DSM, a hydro-flattened lake, no noise
    and no slope) still scatter by that much, so the tolerances built on a measured spread stay
    positive. NaN when ``z`` has no finite height.

    >>> height_resolution(np.array([[50.0, -430.0]], np.float32)) == float(np.spacing(np.float32(430.0)))
    True
    """
    top = np.nanmax(np.abs(np.asarray(z, np.float32))) if np.isfinite(z).any() else np.nan
    return float(np.spacing(np.float32(top))) if np.isfinite(top) else float("nan")


def lowest_point_spread(sigma, slope, cell_m, repeated_share=0.0):
    """Standard deviation of a gridded ground's heights about the smooth surface under them, metres.

    ``sqrt(sigma^2 + (slope c)^2 / 12)`` with ``c = cell_m / (1 - repeated_share)``: the random
    error ``sigma`` of a height, and where the height was taken: a return anywhere within a
    spacing ``c`` of independent heights (the cell, or the run of cells one return fills,
    :func:`repeated_height_share`) on ground of rise ``slope`` per metre lies up to
    ``slope c`` higher or lower, a uniform error of standard deviation ``slope c / sqrt(12)``.
    ``sigma`` NaN: NaN (not measurable).

    Examples
    --------
    >>> round(lowest_point_spread(0.03, 0.12, 1.0), 4)      # sqrt(0.03^2 + 0.12^2 / 12)
    0.0458
    >>> round(lowest_point_spread(0.0, 0.1, 1.0, 0.5), 4)   # two cells per return: 0.2 / sqrt(12)
    0.0577
    """
    if not np.isfinite(sigma):
        return float("nan")
    s = float(slope) if slope is not None and np.isfinite(slope) and slope > 0 else 0.0
    c = float(cell_m) / max(1e-6, 1.0 - min(max(float(repeated_share), 0.0), 1.0))
    return math.sqrt(float(sigma) ** 2 + (s * c) ** 2 / 12.0)


def noise_without_sampling(spread, slope, spacing_m):
    """The random height error left in a ground spread once the spread of where the heights
    were taken on sloping ground is removed, metres: the inverse of
    :func:`lowest_point_spread`, ``sqrt(max(spread^2 - (slope spacing_m)^2 / 12, 0))``.

    A gridded ground's heights about the smooth surface scatter by the noise and by the
    position of each height within the spacing ``spacing_m`` of independent heights on
    ground of rise ``slope`` per metre; a test that allows for that rise between its
    samples already covers the second part, and takes only the first as its noise.
    ``spread`` NaN: NaN; slope unknown (NaN) or 0: ``spread``.

    Examples
    --------
    >>> round(noise_without_sampling(lowest_point_spread(0.03, 0.12, 1.0), 0.12, 1.0), 6)
    0.03
    >>> noise_without_sampling(0.05, 0.5, 2.0)     # all of it is the sampling's
    0.0
    """
    if not np.isfinite(spread):
        return float("nan")
    s = float(slope) if slope is not None and np.isfinite(slope) and slope > 0 else 0.0
    return math.sqrt(max(float(spread) ** 2 - (s * float(spacing_m)) ** 2 / 12.0, 0.0))


def _second_differences(windows):
    """Second differences ``z[i-1] - 2 z[i] + z[i+1]`` along the rows then the columns of
    every window, finite ones only (1-D, the windows' dtype)."""
    d = []
    for w in windows:
        if w.shape[1] > 2:
            d.append((w[:, :-2] - 2 * w[:, 1:-1] + w[:, 2:]).ravel())
        if w.shape[0] > 2:
            d.append((w[:-2] - 2 * w[1:-1] + w[2:]).ravel())
    d = np.concatenate(d) if d else np.empty(0, np.float32)
    return d[np.isfinite(d)]


def noise_second_difference(z):
    """Standard deviation of the DSM's random height error, metres: the MAD of the
    second differences along rows and columns.

    On a smooth surface the second difference ``z[i-1] - 2 z[i] + z[i+1]`` of white
    noise of standard deviation ``sigma`` has variance ``6 sigma^2``; the median of its
    absolute value (``1 / 1.4826`` standard deviations for a normal law) ignores edges
    and objects as long as they cover less than half the cells. Measured on the DSM
    itself at full resolution, on :func:`sample_windows` of a large raster.

    Returns
    -------
    float
        ``1.4826 median(|d|) / sqrt(6)``; 0 when no second difference exists.
    """
    d = _second_differences(sample_windows(np.asarray(z, np.float32)))
    if d.size == 0:
        return 0.0
    return float(_ABS_NORMAL_MEDIAN_INV * np.median(np.abs(d)) / np.sqrt(6.0))


def noise_second_difference_quartile(z, default=0.1):
    """Standard deviation of the DSM's random height error, metres: the lower quartile
    of the centred absolute second differences along rows and columns.

    As :func:`noise_second_difference`, but from the lower quartile of
    ``|d - median(d)|`` (``0.3186`` standard deviations for a normal law): only the
    quietest quarter of the cells sets it, so edges, roofs and crowns may cover most of
    the raster without moving it. Full resolution, :func:`sample_windows` of a large
    raster.

    Returns
    -------
    float
        ``quantile_25(|d - median(d)|) / 0.3186 / sqrt(6)``; ``default`` when fewer than
        10 second differences exist.
    """
    d = _second_differences(sample_windows(np.asarray(z, np.float32)))
    if d.size < 10:
        return default
    return float(np.percentile(np.abs(d - np.median(d)), 25) / _ABS_NORMAL_QUARTILE / np.sqrt(6.0))


def noise_plane_residual(z, dtype=np.float32, min_count=1, default=0.0):
    """Standard deviation of the DSM's random height error, metres: the lower quartile of
    the residual to the mean of the four neighbours.

    The residual ``r = z - mean(4 neighbours)`` vanishes on planes; for white noise of
    standard deviation ``sigma`` it is normal with standard deviation
    ``sigma sqrt(1.25)``. Edges, roofs and vegetation inflate ``|r|`` on part of the
    cells, so the lower quartile of ``|r|`` (``0.3186`` standard deviations) is used:
    the cleanest quarter of the surface sets the noise. Full resolution,
    :func:`sample_windows` of a large raster; ``dtype`` is the precision of the
    arithmetic (float32, the DSM's own, or float64).

    Returns
    -------
    float
        ``quantile_25(|r|) / 0.3186 / sqrt(1.25)``, at least the rounding error of the
        heights (:func:`noise_floor`); ``default`` when fewer than ``min_count`` residuals
        exist.
    """
    r = []
    for w in sample_windows(np.asarray(z, dtype)):
        if min(w.shape) < 3:
            continue
        c = w[1:-1, 1:-1]
        nb = (w[:-2, 1:-1] + w[2:, 1:-1] + w[1:-1, :-2] + w[1:-1, 2:]) * w.dtype.type(0.25)
        r.append(np.abs(c - nb)[np.isfinite(c) & np.isfinite(nb)])
    r = np.concatenate(r) if r else np.empty(0, dtype)
    if r.size < max(1, min_count):
        return default
    return noise_floor(float(np.percentile(r, 25.0)) / _ABS_NORMAL_QUARTILE / math.sqrt(1.25), height_quantum(z))


def smooth_spread(stacks, tile=16, quantile=0.25):
    """Robust spread of values on the smooth parts of a surface: a low quantile of the
    per-tile MADs.

    Every stack (``bands x rows x cols``, NaN = nodata) is cut into ``tile x tile``
    tiles (all bands of a tile together; partial tiles at the far edges left out), the
    robust spread ``1.4826 MAD`` is taken per tile, and the ``quantile`` of the tiles'
    spreads (pooled over the stacks) is returned: the spread of the smooth ground and
    roofs, not inflated by vegetation or by the objects' edges, which may cover most of
    an urban scene.

    Returns
    -------
    float
        0 when no tile has a finite spread.
    """
    mads = []
    for v in stacks:
        b, r, c = v.shape
        tr, tc = max(1, min(tile, r)), max(1, min(tile, c))
        nr, nc = r // tr, c // tc
        t = v[:, :nr * tr, :nc * tc].reshape(b, nr, tr, nc, tc).transpose(1, 3, 0, 2, 4)
        t = t.reshape(nr * nc, -1).astype(np.float64)  # a copy: partitioned in place
        med = np.median(t, axis=1, keepdims=True, overwrite_input=True)  # nodata: NaN, dropped
        t -= med
        np.abs(t, out=t)
        mad = _ABS_NORMAL_MEDIAN_INV * np.median(t, axis=1, overwrite_input=True)
        mads.append(mad[np.isfinite(mad)])
    mad = np.concatenate(mads) if mads else np.empty(0)
    return float(np.quantile(mad, quantile)) if mad.size else 0.0


def noise_second_difference_tiles(z, tile=16, quantile=0.25):
    """Standard deviation of the DSM's random height error, metres: the spread of the
    second differences on the smooth parts of the surface.

    The second differences along X and Y at every interior cell (variance ``6 sigma^2``
    for white noise) are stacked, and their :func:`smooth_spread` (``1.4826 MAD`` per
    ``tile x tile`` tile, the ``quantile`` of the tiles) is divided by ``sqrt(6)``: the
    noise of the smooth ground and roofs even where edges and crowns cover most of the
    cells. Full resolution, :func:`sample_windows` of a large raster.

    Returns
    -------
    float
        0 when the surface (every window) is narrower than 3 cells.
    """
    stacks = []
    for w in sample_windows(np.asarray(z, np.float32)):
        if min(w.shape) < 3:
            continue
        stacks.append(np.stack([(w[1:-1, :-2] - 2 * w[1:-1, 1:-1] + w[1:-1, 2:]),
                                (w[:-2, 1:-1] - 2 * w[1:-1, 1:-1] + w[2:, 1:-1])]).astype(np.float32))
    if not stacks:
        return 0.0
    return smooth_spread(stacks, tile, quantile) / np.sqrt(6.0)


#: Block side (metres) of the ground-level reference surface of
#: :func:`noise_ground_level`: wider than a tree crown or a house, so almost every block
#: holds a ground cell (a gap between crowns, a yard) and its minimum is at ground level.
GROUND_BLOCK_M = 20.0
#: Height (metres) above the ground-level reference surface within which a cell counts as
#: ground level before the noise is known: below any tree, car or building.
GROUND_BAND_M = 2.0
#: Second differences fewer than this on ground-level cells: the noise is not measurable.
GROUND_MIN_SAMPLES = 100
#: Largest window (cells per side) the ground-level noise is measured on.
_GROUND_WINDOW = 1024


def _median_slope(m, step_y, step_x):
    """Median gradient magnitude (rise/run) of the block minima ``m`` (0 with fewer than
    2 x 2 blocks)."""
    if min(m.shape) < 2:
        return 0.0
    gy, gx = np.gradient(m.astype(np.float64), step_y, step_x)
    return float(np.median(np.hypot(gx, gy)))


#: Largest share of a block's cells a low blunder holds (:func:`lift_low_blocks`).
LOW_BLUNDER_SHARE = 0.1


def lift_low_blocks(z, m, k, depth_m, share=LOW_BLUNDER_SHARE):
    """Block minima ``m`` (blocks of ``k`` cells of ``z``) without the low blunders:
    ``(minima, number of blocks lifted)``.

    A low blunder pulls its block's minimum down by its whole depth: multipath pits along
    a wall, metres to tens of metres below the ground (ISPRS samp41: two lines of 21 and
    30 cells 24 m deep lowered 6 of its 54 blocks of 20 m, four of them a 2 x 2 group),
    drop a 20 m square of the interpolated surface with them. The cells lying more than
    ``depth_m`` below the median of the 3 x 3 block minima around their block (edges
    repeated; a hollow at least 3 blocks wide holds most of each neighbourhood and stays)
    are low; a block whose low cells are fewer than ``share`` of its valid cells takes the
    minimum of its other cells. The floor of a cut, a ditch or a channel crossing a block
    covers more of it and stays (a cut 10 m wide is half a 20 m block).

    Examples
    --------
    >>> z = np.zeros((4, 6), np.float32); z[1, 1] = -24.0
    >>> lift_low_blocks(z, block_minima(z, 2), 2, 2.0, share=0.3)
    (array([[0., 0., 0.],
           [0., 0., 0.]], dtype=float32), 1)
    """
    z = np.asarray(z, np.float32)
    m = np.asarray(m, np.float32)
    med = ndimage.median_filter(m, size=3, mode="nearest")
    blocks = m < med - np.float32(depth_m)
    if not blocks.any():
        return m, 0
    br, bc = np.arange(z.shape[0]) // k, np.arange(z.shape[1]) // k
    with np.errstate(invalid="ignore"):
        low = z < (med - np.float32(depth_m))[np.ix_(br, bc)]
    valid = np.isfinite(z)

    def per_block(a):
        rows = np.add.reduceat(a.astype(np.int64), np.arange(0, z.shape[0], k), axis=0)
        return np.add.reduceat(rows, np.arange(0, z.shape[1], k), axis=1)
    lift = blocks & (per_block(low) < share * per_block(valid))
    rest = block_minima(np.where(low, np.float32(np.nan), z), k)
    lift &= np.isfinite(rest)
    return np.where(lift, rest, m), int(np.count_nonzero(lift))


def ground_level_reference(z, cell_size, block_m=GROUND_BLOCK_M, lift_low=False):
    """The ground-level reference surface of a DSM and the terrain's median slope under it.

    The minimum of every block of ``block_m`` metres (at least 2 cells; blocks without a
    valid cell take the nearest block's value), interpolated bilinearly between the block
    centres back to the cells. Objects narrower than a block vanish from it; where a block
    holds no ground it stands on the object, which the caller's height band then admits.
    With ``lift_low``, a block minimum lying more than :data:`GROUND_BAND_M` and the
    terrain's rise over one block (the median slope of the minima) below the median of its
    3 x 3 blocks is a low blunder and takes that median (:func:`lift_low_blocks`; the
    slope returned is then that of the lifted minima).

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
    m = block_minima(z, k)
    bad = ~np.isfinite(m)
    if bad.all():
        return np.full(z.shape, np.nan, np.float32), 0.0, k
    if bad.any():
        idx = ndimage.distance_transform_edt(bad, return_distances=False, return_indices=True)
        m = m[tuple(idx)]
    slope = _median_slope(m, k * dy, k * dx)
    if lift_low and min(m.shape) >= 2:
        m, lifted = lift_low_blocks(z, m, k, GROUND_BAND_M + slope * k * max(dx, dy))
        if lifted:
            slope = _median_slope(m, k * dy, k * dx)
    u = (np.arange(z.shape[0]) + 0.5) / k - 0.5
    v = (np.arange(z.shape[1]) + 0.5) / k - 0.5
    # separable bilinear interpolation between block centres (edges held)
    rows = ndimage.map_coordinates(m, np.meshgrid(u, np.arange(m.shape[1]), indexing="ij"),
                                   order=1, mode="nearest")
    surf = ndimage.map_coordinates(rows, np.meshgrid(np.arange(z.shape[0]), v, indexing="ij"),
                                   order=1, mode="nearest")
    return surf.astype(np.float32), slope, k


def ground_level_cells(z, cell_size, sigma=None, *, block_m=GROUND_BLOCK_M, band_m=GROUND_BAND_M,
                       lift_low=False):
    """Cells of a DSM standing at ground level (bool, same shape).

    A cell is at ground level when it stands less than ``max(band_m, 6 sigma)`` plus the
    median terrain slope times the block side above the ground-level reference surface
    (:func:`ground_level_reference`, ``lift_low`` passed on: without the blocks a low
    blunder pulled down, under which every cell stands metres above); ``sigma`` is the
    DSM's noise when known (None: ``band_m`` alone). Crowns and roofs, which stand metres
    above it, are left out; the ground between them, gaps in a canopy and low vegetation
    are in.
    """
    z = np.asarray(z, np.float32)
    ref, slope, k = ground_level_reference(z, cell_size, block_m, lift_low=lift_low)
    band = (band_m if sigma is None or not np.isfinite(sigma) else max(band_m, 6.0 * sigma))
    band += slope * k * max(float(cell_size[0]), float(cell_size[1]))
    with np.errstate(invalid="ignore"):
        return (z - ref) <= band


def noise_ground_level(z, cell_size, *, block_m=GROUND_BLOCK_M, band_m=GROUND_BAND_M,
                       iterations=3, progress=None):
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
       quartile ignores the edges and low vegetation left among them);
    4. at least the rounding error of heights stored in steps (:func:`noise_floor`: on a
       DSM in whole metres most second differences are exactly 0);
    5. ``sigma_cleanest``: the same lower quartile in each tile of :data:`NOISE_TILE_CELLS`
       cells holding :data:`GROUND_MIN_SAMPLES` of those second differences, and the lower
       quartile of the tiles' values (at least :data:`NOISE_MIN_TILES` tiles). The lower
       quartile of step 3 reads the noise while low vegetation (within the band) touches fewer
       than about half of the triples; on a highest-point DSM of a vegetated hillside it
       touches most (ISPRS 11 at 2 m highest point: 64 % of the triples touch a cell standing
       above the reference ground by more than the ISPRS tolerance; ``sigma`` 0.37 m, 0.09 m
       on the untouched triples, 0.18 m on the lowest point of the same returns). The noise is
       the sensor's, the same over the raster, while the vegetation is not: the cleanest
       quarter of the tiles still reads it where vegetation touches up to three quarters of
       them (0.23 m there). On clean ground it scatters about ``sigma`` by the tiles' sampling
       and the heights' rounding: it is ``sigma`` unless it lies below by more than those
       (:func:`cleanest_noise`). ``sigma`` itself stays the whole window's (the members' own
       derivations); :func:`bare_earth.core.dtm.ground_noise` takes ``sigma_cleanest``.

    Measured at full resolution on a central window of at most 1024 x 1024 cells.

    Parameters
    ----------
    z : array_like, 2-D
        DSM, NaN = nodata.
    cell_size : (float, float)
        ``(dx, dy)`` metres.
    progress : callable, optional
        ``progress(fraction)`` after the reference surface and each iteration; may raise
        ``Cancelled``.

    Returns
    -------
    dict
        ``sigma`` (float, NaN when fewer than :data:`GROUND_MIN_SAMPLES` second
        differences lie on ground-level cells), ``samples`` (their number),
        ``ground_share`` (the share of valid cells at ground level), ``block_cells``,
        ``tiles`` (the tiles measured in step 5) and ``sigma_cleanest`` (NaN with fewer than
        :data:`NOISE_MIN_TILES` of them).
    """
    z = np.asarray(z, np.float32)
    rows, cols = z.shape
    h, w = min(rows, _GROUND_WINDOW), min(cols, _GROUND_WINDOW)
    r0, c0 = (rows - h) // 2, (cols - w) // 2
    z = z[r0:r0 + h, c0:c0 + w]
    if not _NOISE_SHARING:
        return _noise_ground_level(z, cell_size, block_m, band_m, iterations, progress)
    key = (z.shape, hashlib.blake2b(np.ascontiguousarray(z).data, digest_size=16).digest(),
           float(cell_size[0]), float(cell_size[1]), float(block_m), float(band_m), int(iterations))
    with _NOISE_LOCK:
        entry = _NOISE_MEMO.get(key)
        mine = entry is None
        if mine:
            entry = _NOISE_MEMO[key] = [threading.Event(), None]
            while len(_NOISE_MEMO) > _NOISE_MEMO_SIZE:
                _NOISE_MEMO.pop(next(iter(_NOISE_MEMO)))
    if not mine:
        entry[0].wait()             # the same window measured in another thread (the dtm's members)
        if entry[1] is not None:
            report(progress, 1.0)
            return dict(entry[1])
        return noise_ground_level(z, cell_size, block_m=block_m, band_m=band_m, iterations=iterations,
                                  progress=progress)
    try:
        entry[1] = _noise_ground_level(z, cell_size, block_m, band_m, iterations, progress)
    finally:
        if entry[1] is None:        # failed or cancelled: forgotten, waiters measure it themselves
            with _NOISE_LOCK:
                if _NOISE_MEMO.get(key) is entry:
                    del _NOISE_MEMO[key]
        entry[0].set()
    return dict(entry[1])


#: :func:`noise_ground_level`'s memo inside :func:`noise_shared`: the results by the measured
#: window's content (the dtm filter's members each derive their defaults from the same DSM, side by side).
_NOISE_MEMO = {}
_NOISE_MEMO_SIZE = 8
_NOISE_LOCK = threading.Lock()
_NOISE_SHARING = 0


@contextlib.contextmanager
def noise_shared():
    """Within this context (in any thread) :func:`noise_ground_level` measures each window once: a
    second call on the same content (another member's derivation, side by side) takes the first's
    result, waiting for it if it is still being measured (its progress then reports 1 at once).
    Outside, every call measures. The results are forgotten when the last context ends."""
    global _NOISE_SHARING
    with _NOISE_LOCK:
        _NOISE_SHARING += 1
    try:
        yield
    finally:
        with _NOISE_LOCK:
            _NOISE_SHARING -= 1
            if not _NOISE_SHARING:
                _NOISE_MEMO.clear()


def _noise_ground_level(z, cell_size, block_m, band_m, iterations, progress):
    """:func:`noise_ground_level` on its window ``z`` (float32)."""
    out = {"sigma": float("nan"), "samples": 0, "ground_share": 0.0, "block_cells": 0, "tiles": 0,
           "sigma_cleanest": float("nan")}
    if min(z.shape) < 3 or not np.isfinite(z).any():
        return out
    ref, slope, k = ground_level_reference(z, cell_size, block_m)
    report(progress, 0.4)
    out["block_cells"] = k
    dx, dy = float(cell_size[0]), float(cell_size[1])
    d_row = z[:, :-2] - 2 * z[:, 1:-1] + z[:, 2:]
    d_col = z[:-2] - 2 * z[1:-1] + z[2:]
    d_dia = z[:-2, :-2] - 2 * z[1:-1, 1:-1] + z[2:, 2:]
    d_ant = z[:-2, 2:] - 2 * z[1:-1, 1:-1] + z[2:, :-2]
    height = z - ref
    valid = np.isfinite(z)
    sigma = None
    band = None
    for it in range(iterations):
        report(progress, 0.4 + 0.6 * it / iterations)
        last, band = band, (band_m if sigma is None else max(band_m, 6.0 * sigma)) + slope * k * max(dx, dy)
        if band == last:        # the same cells as the last iteration: the same sigma (converged)
            break
        with np.errstate(invalid="ignore"):
            g = height <= band
        mid = g[1:-1, 1:-1]
        on = (g[:, :-2] & g[:, 1:-1] & g[:, 2:], g[:-2] & g[1:-1] & g[2:],
              g[:-2, :-2] & mid & g[2:, 2:], g[:-2, 2:] & mid & g[2:, :-2])
        d = np.concatenate([d_row[on[0]], d_col[on[1]], d_dia[on[2]], d_ant[on[3]]])
        d = d[np.isfinite(d)]
        out["samples"] = int(d.size)
        out["ground_share"] = float(np.count_nonzero(g) / max(1, np.count_nonzero(valid)))
        if d.size < GROUND_MIN_SAMPLES:
            out["sigma"] = float("nan")
            return out
        new = float(np.percentile(np.abs(d), 25.0)) / _ABS_NORMAL_QUARTILE / math.sqrt(6.0)
        if sigma is not None and abs(new - sigma) <= 1e-3 * max(sigma, 1e-6):
            sigma = new
            break
        sigma = new
    quantum = height_quantum(z)
    out["sigma"] = noise_floor(sigma, quantum)
    # the same statistic tile by tile, on the last iteration's second differences (their middle cells' tiles)
    tiles, counts = _tile_quartiles(z.shape, ((d_row, on[0], (0, 1)), (d_col, on[1], (1, 0)), (d_dia, on[2], (1, 1)),
                                              (d_ant, on[3], (1, 1))), NOISE_TILE_CELLS, GROUND_MIN_SAMPLES)
    out["tiles"] = int(tiles.size)
    if tiles.size >= NOISE_MIN_TILES:
        out["sigma_cleanest"] = cleanest_noise(out["sigma"], tiles, counts, quantum)
    report(progress, 1.0)
    return out


#: Side (cells) of the tiles :func:`noise_ground_level` also measures its noise on (``sigma_cleanest``).
NOISE_TILE_CELLS = 32
#: Fewest tiles with :data:`GROUND_MIN_SAMPLES` second differences for ``sigma_cleanest`` (NaN below).
NOISE_MIN_TILES = 8
#: Relative standard error of the lower quartile of ``n`` absolute normal values, times ``sqrt(n)``:
#: ``sqrt(0.25 0.75) / (2 phi(0.3186) 0.3186)`` (the asymptotic variance of a sample quantile).
_QUARTILE_SE = math.sqrt(0.25 * 0.75) / (2.0 * math.exp(-0.5 * _ABS_NORMAL_QUARTILE ** 2) / math.sqrt(2.0 * math.pi)
                                         * _ABS_NORMAL_QUARTILE)


def cleanest_noise(sigma, tile_quartiles, tile_counts, quantum=0.0):
    """The noise of the cleanest quarter of the tiles, metres: ``sigma`` where the tiles do not read it lower.

    ``c``: the lower quartile of the tiles' lower quartiles of the absolute second differences
    (``tile_quartiles``, each of ``tile_counts`` values), ``/ 0.3186 / sqrt(6)`` as ``sigma``. On clean
    ground every tile reads ``sigma`` within its sampling error (relative standard error
    ``1.79 / sqrt(n)``, :data:`_QUARTILE_SE`) and within one step of the heights' rounding
    (``quantum``: second differences are multiples of it); ``c`` is taken only where it lies below
    ``sigma`` by more than three of those standard errors (at the tiles' median count) and more than one
    such step, else ``sigma``. Never below the rounding error (:func:`noise_floor`).

    Examples
    --------
    >>> round(cleanest_noise(0.37, np.full(12, 0.0765), np.full(12, 1600)), 4)   # 0.0765 / 0.3186 / sqrt 6
    0.098
    >>> cleanest_noise(0.10, np.full(12, 0.0765), np.full(12, 1600))      # within 3 standard errors: sigma
    0.1
    >>> cleanest_noise(0.051, np.full(12, 0.03), np.full(12, 4000), 0.01)  # one step of 1 cm lower: sigma
    0.051
    """
    if not np.isfinite(sigma) or not len(tile_quartiles):
        return sigma
    c = float(np.percentile(tile_quartiles, 25.0)) / _ABS_NORMAL_QUARTILE / math.sqrt(6.0)
    se = _QUARTILE_SE / math.sqrt(max(1.0, float(np.median(tile_counts))))
    step = float(quantum) / _ABS_NORMAL_QUARTILE / math.sqrt(6.0)
    if c * (1.0 + 3.0 * se) < sigma and c + step < sigma:
        return noise_floor(c, quantum)
    return sigma


def sensor_noise(ground_noise):
    """The sensor's noise from :func:`noise_ground_level`'s result, metres: its ``sigma``, or the cleanest
    quarter of its tiles (``sigma_cleanest``) where lower; NaN where ``sigma`` is not measurable.

    The noise is the sensor's, the same over the raster; the ground-level cells' contamination (low
    vegetation among them, which touches most triples of a highest-point DSM of a vegetated hillside) is
    not: where the whole window reads more than its cleanest quarter of tiles, the tiles read the noise
    (:func:`cleanest_noise`). A threshold built as a multiple of the noise takes this one.

    Examples
    --------
    >>> sensor_noise({"sigma": 0.37, "sigma_cleanest": 0.23})
    0.23
    >>> sensor_noise({"sigma": 0.1, "sigma_cleanest": float("nan")})     # too few tiles to rank
    0.1
    >>> sensor_noise({"sigma": float("nan"), "sigma_cleanest": float("nan")})
    nan
    """
    sigma = float(ground_noise["sigma"])
    if not np.isfinite(sigma):
        return float("nan")
    clean = float(ground_noise.get("sigma_cleanest", float("nan")))
    return min(sigma, clean) if np.isfinite(clean) else sigma


def _tile_quartiles(shape, parts, tile, min_samples):
    """Lower quartile of the absolute second differences in each ``tile`` x ``tile`` square (by each
    difference's middle cell) holding at least ``min_samples`` of them, and their numbers (two 1-D arrays,
    one value per such tile, the tiles in raster order).

    ``parts``: ``(d, on, (r0, c0))`` per direction: the differences, where they count, and the offset of
    their middle cell in the raster of ``shape``. The quartile is :func:`numpy.percentile`'s (linear).

    A band of tile rows at a time, each tile's values (``+inf`` where none) in one row of a
    ``(tiles, parts x tile x tile)`` array sorted along its rows: the same order statistics as one sort of all
    the values by tile and value (``np.lexsort``, measured 12x slower on 4 million cells), in a buffer of about
    :data:`_TILE_BAND_VALUES` values.
    """
    rows, cols = shape
    ntr, ntc = -(-rows // tile), -(-cols // tile)
    if not parts or not ntr or not ntc:
        return np.zeros(0), np.zeros(0, np.int64)
    dtype = np.result_type(*[d.dtype for d, _, _ in parts])
    per_row = len(parts) * tile * ntc * tile                # values of one row of tiles
    band = max(1, _TILE_BAND_VALUES // per_row)
    buf = np.empty((len(parts), min(band, ntr) * tile, ntc * tile), dtype)
    quartiles, numbers = [], []
    for t0 in range(0, ntr, band):
        t1 = min(ntr, t0 + band)
        a, b = t0 * tile, t1 * tile                         # the band's raster rows
        v = buf[:, :b - a]
        v.fill(np.inf)
        for k, (d, on, (r0, c0)) in enumerate(parts):
            i0, i1 = max(0, a - r0), min(d.shape[0], b - r0)  # the rows of d whose middle cells lie in the band
            if i0 < i1:
                dd = d[i0:i1]
                np.abs(dd, out=v[k, i0 + r0 - a:i1 + r0 - a, c0:c0 + d.shape[1]], where=on[i0:i1] & np.isfinite(dd))
        n = t1 - t0
        v = np.sort(v.reshape(len(parts), n, tile, ntc, tile).transpose(1, 3, 0, 2, 4).reshape(n * ntc, -1), axis=1)
        counts = np.count_nonzero(v < np.inf, axis=1)
        keep = np.flatnonzero(counts >= max(1, min_samples))
        counts = counts[keep].astype(np.int64)
        pos = 0.25 * (counts - 1)
        lo = np.floor(pos).astype(np.int64)
        hi = np.minimum(lo + 1, counts - 1)
        frac = pos - lo
        quartiles.append(v[keep, lo].astype(np.float64) * (1.0 - frac) + v[keep, hi].astype(np.float64) * frac)
        numbers.append(counts)
    return np.concatenate(quartiles), np.concatenate(numbers)


#: Values (cells x directions) of one band of :func:`_tile_quartiles` (its buffer and sorted copy a few MB each).
_TILE_BAND_VALUES = 1 << 21


def ground_spread(stacks, tile=16, quantile=0.25, min_share=0.25, progress=None):
    """:func:`smooth_spread` of values kept only on chosen cells (the others NaN).

    Per ``tile x tile`` tile the robust spread ``1.4826 MAD`` of its finite values when
    they are at least ``min_share`` of the tile, and the ``quantile`` of those tiles'
    spreads; with no such tile, the spread of all finite values pooled (0 with fewer than
    100). Used on the bends of ground-level cells (curvature's threshold), where the
    ground shows in gaps that rarely fill a tile. ``progress(fraction)`` (optional, may
    raise ``Cancelled``) after each stack.
    """
    mads, pooled = [], []
    stacks = list(stacks)
    for i, v in enumerate(stacks):
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
                mad = _ABS_NORMAL_MEDIAN_INV * np.nanmedian(np.abs(t - med), axis=1)
            mads.append(mad[np.isfinite(mad)])
        pooled.append(v[np.isfinite(v)].astype(np.float64))
        report(progress, (i + 1) / len(stacks))
    mad = np.concatenate(mads) if mads else np.empty(0)
    if mad.size:
        return float(np.quantile(mad, quantile))
    a = np.concatenate(pooled) if pooled else np.empty(0)
    if a.size < 100:
        return 0.0
    return float(_ABS_NORMAL_MEDIAN_INV * np.median(np.abs(a - np.median(a))))


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


#: Candidates per ring gathered at once (:func:`below_surroundings`; bounds the memory).
_RING_CHUNK = 1 << 12
#: The ring's minimum filters cost about as much as gathering this many ring cells per
#: raster cell (measured: 16 Mcells, rings of 416 cells); with more candidates the
#: filters are cheaper than gathering each candidate's ring.
_RING_GATHER_PER_CELL = 3.0


def surroundings_reach(cell_size, radius_m=PIT_RADIUS_M, cluster_m=PIT_CLUSTER_M):
    """``(iy, ix, ry, rx)``: the cells :func:`below_surroundings` leaves out around the
    tested cell (its cluster, half-widths ``iy``, ``ix``: at least 2) and how far its ring
    reaches (``ry``, ``rx``: the radius, at least the cluster + 2), along rows and columns.

    The one copy of the test's reach: a filter's halo that must cover the test uses it.

    Examples
    --------
    >>> surroundings_reach((1.0, 1.0), radius_m=10.0, cluster_m=1.5)
    (2, 2, 10, 10)
    >>> surroundings_reach((0.5, 2.0), radius_m=10.0, cluster_m=1.5)
    (2, 3, 5, 20)
    """
    dx, dy = cell_size
    iy = max(2, int(np.ceil(cluster_m / dy)))
    ix = max(2, int(np.ceil(cluster_m / dx)))
    return iy, ix, max(iy + 2, int(np.ceil(radius_m / dy))), max(ix + 2, int(np.ceil(radius_m / dx)))


def below_surroundings(z, cell_size, depth_m, radius_m=PIT_RADIUS_M, cluster_m=PIT_CLUSTER_M, candidates=None,
                       progress=None):
    """Cells lying more than ``depth_m`` below every cell of the square ring around them.

    The ring spans ``radius_m`` around the cell without the cell's own cluster (half-width
    ``cluster_m``, at least 2 cells): a matching blunder or multipath pit is below all the
    ground around it, a gap between tree crowns or roofs is at the level of the other gaps
    within the ring. Translation-invariant (four rectangular minimum filters), NaN ignored.
    ``candidates`` (optional boolean raster): only these cells are tested (the others are
    False); when they are few (a filter's low-blunder candidates) each one's ring is
    gathered directly, without a pass over the raster: the same answer at a fraction of
    the cost. ``progress(fraction)`` (optional, may raise ``Cancelled``) after each filter.
    """
    iy, ix, ry, rx = surroundings_reach(cell_size, radius_m, cluster_m)
    if candidates is not None:
        idx = np.flatnonzero(candidates)
        ring_cells = (2 * ry + 1) * (2 * rx + 1) - (2 * iy + 1) * (2 * ix + 1)
        if idx.size * ring_cells <= _RING_GATHER_PER_CELL * np.size(z):
            return _below_gathered(np.asarray(z), idx, (iy, ix, ry, rx), depth_m)
    a = np.where(np.isfinite(z), z, np.inf).astype(np.float32)
    rows = ndimage.minimum_filter1d(a, 2 * rx + 1, axis=1, mode="constant", cval=np.inf)
    report(progress, 0.15)
    mid = ndimage.minimum_filter1d(a, 2 * iy + 1, axis=0, mode="constant", cval=np.inf)
    report(progress, 0.3)
    if candidates is not None:
        out = _below_at(a, rows, mid, idx, (iy, ix, ry, rx), depth_m)
        report(progress, 1.0)
        return out
    ring = _min_over_offsets(rows, -ry, -iy - 1, 0)
    report(progress, 0.45)
    np.minimum(ring, _min_over_offsets(rows, iy + 1, ry, 0), out=ring)
    report(progress, 0.6)
    np.minimum(ring, _min_over_offsets(mid, -rx, -ix - 1, 1), out=ring)
    report(progress, 0.75)
    np.minimum(ring, _min_over_offsets(mid, ix + 1, rx, 1), out=ring)
    report(progress, 0.9)
    with np.errstate(invalid="ignore"):
        out = np.isfinite(ring) & (a < ring - np.float32(depth_m))
    report(progress, 1.0)
    return out


def _gather_offsets(flat, shape, idx, dr, dc):
    """Candidates in chunks of :data:`_RING_CHUNK` with the cells at the offsets ``(dr, dc)``
    around each: yields ``(q, v, inside)``, the chunk's flat indices, the cells' values
    (float32, positions clipped to the array: a new array the caller may change) and whether
    each offset lies inside the array."""
    h, w = shape
    for i in range(0, idx.size, _RING_CHUNK):
        q = idx[i:i + _RING_CHUNK]
        r, c = np.divmod(q, w)
        rr = r[:, None] + dr[None, :]
        cc = c[:, None] + dc[None, :]
        inside = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
        np.clip(rr, 0, h - 1, out=rr)
        np.clip(cc, 0, w - 1, out=cc)
        rr *= w
        rr += cc
        v = flat.take(rr)
        yield q, (v if v.dtype == np.float32 else v.astype(np.float32)), inside


def _candidate_cells(z, candidates):
    """``z`` as an array, an all-False mask of its shape and the flat indices of ``candidates``
    (the start of every test that gathers its candidates' neighbourhoods directly)."""
    z = np.asarray(z)
    return z, np.zeros(z.shape, bool), np.flatnonzero(candidates)


def _below_gathered(z, idx, reach, depth_m):
    """:func:`below_surroundings` at the flat indices ``idx`` only, each ring's cells
    gathered from ``z`` itself (NaN and cells outside the array count as +inf), in
    chunks of :data:`_RING_CHUNK` candidates. The ring's minimum is exact whatever the
    order, so the answer is the filters'."""
    iy, ix, ry, rx = reach
    h, w = z.shape
    out = np.zeros(z.shape, bool)
    if idx.size == 0:
        return out
    dr, dc = np.meshgrid(np.arange(-ry, ry + 1), np.arange(-rx, rx + 1), indexing="ij")
    ring = (np.abs(dr) > iy) | (np.abs(dc) > ix)
    dr, dc = dr[ring], dc[ring]
    flat = z.ravel()
    for q, v, inside in _gather_offsets(flat, (h, w), idx, dr, dc):
        v[~(inside & np.isfinite(v))] = np.inf
        lo = v.min(axis=1)
        with np.errstate(invalid="ignore"):
            own = flat.take(q).astype(np.float32, copy=False)
            hit = np.isfinite(lo) & (own < lo - np.float32(depth_m))
        out.ravel()[q[hit]] = True
    return out


def _below_at(a, rows, mid, idx, reach, depth_m):
    """:func:`below_surroundings` at the flat indices ``idx`` only: the ring's minimum is
    gathered from the row minima above and below the cluster and from the column minima
    beside it (the same sets of cells as the full filters), +inf outside the array."""
    iy, ix, ry, rx = reach
    h, w = a.shape
    out = np.zeros(a.shape, bool)
    if idx.size == 0:
        return out
    r, c = np.divmod(idx, w)
    ring = np.full(idx.size, np.inf, np.float32)
    for src, offs, along_rows in ((rows, [*range(-ry, -iy), *range(iy + 1, ry + 1)], True),
                                  (mid, [*range(-rx, -ix), *range(ix + 1, rx + 1)], False)):
        flat = src.ravel()
        for d in offs:
            rr, cc = (r + d, c) if along_rows else (r, c + d)
            ok = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
            v = flat.take(np.where(ok, rr * w + cc, 0))
            np.minimum(ring, np.where(ok, v, np.float32(np.inf)), out=ring)
    with np.errstate(invalid="ignore"):
        hit = np.isfinite(ring) & (a.ravel().take(idx) < ring - np.float32(depth_m))
    out.ravel()[idx[hit]] = True
    return out


def below_level_rim(z, cell_size, depth_m, slope, candidates, cluster_m=PIT_CLUSTER_M):
    """Cells of ``candidates`` lying more than ``depth_m`` below every cell of a level rim.

    The rim is the square of cells just outside the tested cell's cluster (half-widths
    ``iy + 1``, ``ix + 1`` of :func:`surroundings_reach`); it is *level* when its highest
    and lowest cells differ by at most ``2 depth_m`` (noise on both) plus the rise of the
    terrain slope ``slope`` (rise/run) across it. A pit in open ground has such a rim,
    whatever lies further out; a gap between crowns or roofs is rimmed by their sides,
    metres apart. :func:`below_surroundings` asks for every cell of the wider ring, so two
    blunders within that ring of each other hid each other (issue 12: two 2 x 2 pits 18 m
    deep, 10 m apart, on open ground); this test does not look that far. A rim cell outside
    the array is left out; a nodata rim cell, or fewer than half the rim inside, is no
    evidence (False). Candidates are few: their rims are gathered directly. The candidates
    this test leaves are asked :func:`below_narrow_gap` (a line of blunders along a wall,
    whose rim is wall and ground), so the filters asking the shared pit tests get both.
    """
    iy, ix, _, _ = surroundings_reach(cell_size, cluster_m=cluster_m)
    z, out, idx = _candidate_cells(z, candidates)
    if idx.size == 0:
        return out
    h, w = z.shape
    ry, rx = iy + 1, ix + 1
    dr, dc = np.meshgrid(np.arange(-ry, ry + 1), np.arange(-rx, rx + 1), indexing="ij")
    rim = (np.abs(dr) == ry) | (np.abs(dc) == rx)
    dr, dc = dr[rim], dc[rim]
    dx, dy = float(cell_size[0]), float(cell_size[1])
    rise = float(slope) * float(np.hypot(2 * ry * dy, 2 * rx * dx))
    flat = z.ravel()
    for q, v, inside in _gather_offsets(flat, (h, w), idx, dr, dc):
        lo = np.where(inside, v, np.inf).min(axis=1)
        hi = np.where(inside, v, -np.inf).max(axis=1)
        with np.errstate(invalid="ignore"):
            known = (inside & np.isfinite(v)).sum(axis=1)
            ok = (known == inside.sum(axis=1)) & (2 * known >= dr.size)
            own = flat.take(q).astype(np.float32)
            hit = ok & (hi - lo <= 2 * depth_m + rise) & (own < lo - np.float32(depth_m))
        out.ravel()[q[hit]] = True
    rest = np.zeros(z.shape, bool)
    rest.ravel()[idx] = True
    rest &= ~out
    out |= below_narrow_gap(z, cell_size, depth_m, slope, rest, cluster_m=cluster_m)
    return out


def below_level_neighbours(z, depth_m, level_m, candidates, min_neighbours=3):
    """Cells of ``candidates`` lying more than ``depth_m`` below each of their level neighbours.

    The neighbours are the 8 cells around the tested one that are valid and not candidates
    themselves (a line or a cluster of blunders does not hide its members, as it hides them from
    :func:`below_surroundings` and :func:`below_level_rim`, whose rings it reaches); they are *level*
    when their highest and lowest differ by at most ``level_m`` (the caller's noise and the terrain's
    rise across them). A blunder in a paved surface or a flat roof has level neighbours; a gap
    between tree crowns is rimmed by their sides, metres apart. Fewer than ``min_neighbours``
    neighbours is no evidence (False). Candidates are few: their neighbours are gathered directly.

    Examples
    --------
    >>> z = np.full((5, 5), 10.0, np.float32); z[2, 2] = z[2, 3] = 3.0
    >>> below_level_neighbours(z, 5.0, 0.5, z < 5).sum()
    2
    >>> z[1, 1] = 14.0
    >>> np.argwhere(below_level_neighbours(z, 5.0, 0.5, z < 5)).tolist()
    [[2, 3]]
    """
    cand = np.asarray(candidates, bool)
    z, out, idx = _candidate_cells(z, cand)
    if idx.size == 0:
        return out
    h, w = z.shape
    dr = np.array([-1, -1, -1, 0, 0, 1, 1, 1])
    dc = np.array([-1, 0, 1, -1, 1, -1, 0, 1])
    flat, cflat = z.ravel(), cand.ravel()
    for q, v, inside in _gather_offsets(flat, (h, w), idx, dr, dc):
        r, c = np.divmod(q, w)
        at = np.clip(r[:, None] + dr, 0, h - 1) * w + np.clip(c[:, None] + dc, 0, w - 1)
        ok = inside & np.isfinite(v) & ~cflat.take(at)
        lo = np.where(ok, v, np.inf).min(axis=1)
        hi = np.where(ok, v, -np.inf).max(axis=1)
        with np.errstate(invalid="ignore"):
            own = flat.take(q).astype(np.float32)
            hit = ok.sum(axis=1) >= min_neighbours
            hit &= (hi - lo <= np.float32(level_m)) & (own < lo - np.float32(depth_m))
        out.ravel()[q[hit]] = True
    return out


#: The steepest banks (rise/run) a narrow gap in the terrain has on both sides: a gap deeper
#: than the distance between its banks (twice the depth of 45 degree banks meeting in a V)
#: is no ditch (:func:`below_narrow_gap`).
GAP_BANK_SLOPE = 1.0
#: The four directions (row, column steps) across which :func:`below_narrow_gap` looks.
#: A line or a cluster is narrow across at least two of them (a line: across it and both
#: diagonals); a courtyard's corner, an underpass's mouth, only along one diagonal.
_GAP_DIRECTIONS = ((0, 1), (1, 0), (1, 1), (1, -1))
_GAP_MIN_DIRECTIONS = 2
#: The share of the ring of :func:`below_surroundings` below which its ground lies for
#: :func:`below_narrow_gap`: a line of blunders fills less than a quarter of it (a line of
#: 21 cells across a ring of 416 at 1 m: 5 %), the ground beside the buildings more.
GAP_GROUND_QUANTILE = 0.25


def below_narrow_gap(z, cell_size, depth_m, slope, candidates, cluster_m=PIT_CLUSTER_M):
    """Cells of ``candidates`` at the bottom of a gap narrower than a blunder cluster and
    deeper than any terrain explains, below level ground on its lower side.

    Multipath blunders lie in lines and clusters along walls (issue 12: ISPRS samp41, 44
    points 24-35 m below the ground in lines of 21 and 30 cells): each has others of its
    line within the ring of :func:`below_surroundings` and a rim of wall and ground, not
    level (:func:`below_level_rim`). Across the line they are found: along at least two of
    four directions (rows, columns, diagonals) the cell rises, on both sides, more than
    ``depth_m`` above itself within a gap at most the cluster's width wide (``n = 2 i + 1``
    cells, ``i`` the cluster's half-width of :func:`surroundings_reach`, and at most half
    the ring's radius there, so the test reaches no further than that ring); one bank is
    level from there to the ring's radius (within ``2 depth_m`` and the rise of the terrain
    slope ``slope``: ground or a roof, not the crowns around a gap in a canopy); and the
    cell lies below the lower bank by more than ``depth_m`` plus the rise of
    the steeper of ``slope`` and :data:`GAP_BANK_SLOPE` from bank to bank (a ditch, a sunken
    lane: banks no steeper than 45 degrees on both sides, or wider than a cluster; a
    river or a quarry floor: wider than a cluster, one bank only within reach; a courtyard
    among buildings: wider, or level roofs on both sides rise above a gap wider than its
    depth; a courtyard's corner: narrow along one diagonal only). Last, the bank is on the
    ground side: the cell lies below the ground of the ring of :func:`below_surroundings`
    (its lower quartile, :data:`GAP_GROUND_QUANTILE`) and no cell of that ring bridges the
    cell and its lower bank (ground at the cell's level in a gap between buildings or
    crowns, or terrain rising from it, is ground), each beyond ``depth_m`` and the rise of
    ``slope`` across the ring. A cell outside the array or nodata is no bank. Candidates
    are few: their rays and rings are gathered directly.
    """
    iy, ix, ry, rx = surroundings_reach(cell_size, cluster_m=cluster_m)
    z, out, idx = _candidate_cells(z, candidates)
    if idx.size == 0:
        return out
    h, w = z.shape
    dx, dy = float(cell_size[0]), float(cell_size[1])
    bank = max(float(slope), GAP_BANK_SLOPE)
    flat = z.ravel()
    votes = np.zeros(idx.size, np.uint8)               # directions across which each is found
    bank_lo = np.full(idx.size, np.inf, np.float32)    # the lowest bank of those directions
    for sr, sc in _GAP_DIRECTIONS:
        # the ray: as far as the ring of below_surroundings reaches (a filter's halo covers
        # it); the banks within the cluster's width (cells), at most half the ray, and the
        # level ground from the bank on to the ray's end
        ray = min(ry if sr else rx, rx if sc else ry)
        n = min(2 * min(iy if sr else ix, ix if sc else iy) + 1, ray // 2)
        m = ray - n + 1
        step = float(np.hypot(sr * dy, sc * dx))
        k = np.arange(1, ray + 1)
        dr = np.concatenate([k * sr, -k * sr])
        dc = np.concatenate([k * sc, -k * sc])
        level = np.float32(2 * depth_m + float(slope) * (m - 1) * step)
        for i, (q, v, inside) in enumerate(_gather_offsets(flat, (h, w), idx, dr, dc)):
            v[~inside] = np.nan
            own = flat.take(q).astype(np.float32)
            banks, exits = [], []
            for side in (v[:, :ray], v[:, ray:]):
                with np.errstate(invalid="ignore"):
                    up = side[:, :n] > own[:, None] + np.float32(depth_m)
                e = np.where(up.any(axis=1), up.argmax(axis=1), n)       # first cell above, or none
                run = np.take_along_axis(side, np.minimum(e, n - 1)[:, None] + np.arange(m)[None, :], axis=1)
                with np.errstate(invalid="ignore"):                    # NaN: no level bank
                    flat_bank = run.max(axis=1) - run.min(axis=1) <= level
                banks.append((run[:, 0], flat_bank))
                exits.append(e)
            gap = exits[0] + exits[1] + 1                                     # cells between the banks
            (h0, l0), (h1, l1) = banks
            low = np.fmin(h0, h1)                      # the lower bank, with one level bank
            with np.errstate(invalid="ignore"):
                hit = (exits[0] < n) & (exits[1] < n) & (gap <= n) & (l0 | l1) & \
                    (own < low - np.float32(depth_m) - np.float32(bank * step) * (gap + 1))
            part = slice(i * _RING_CHUNK, i * _RING_CHUNK + q.size)
            votes[part] += hit
            np.minimum(bank_lo[part], np.where(hit, low, np.inf), out=bank_lo[part])
    found = votes >= _GAP_MIN_DIRECTIONS
    idx = idx[found]
    found = _below_ground_side(z, idx, bank_lo[found], (iy, ix, ry, rx), depth_m, slope, cell_size)
    out.ravel()[idx[found]] = True
    return out


def _below_ground_side(z, idx, bank, reach, depth_m, slope, cell_size):
    """Whether each cell of ``idx`` (flat) lies below the ground of the ring of
    :func:`below_surroundings` around it, its lower bank ``bank`` on the ground side:
    more than ``depth_m`` plus the terrain's rise across the ring (``slope`` times the
    ring's radius) below the ring's lower quartile (:data:`GAP_GROUND_QUANTILE`), and with
    no ring cell between ``depth_m`` above it and that allowance below the bank (nothing
    bridges the cell and the ground; ground at the cell's level, or rising from it, does)."""
    iy, ix, ry, rx = reach
    dr, dc = np.meshgrid(np.arange(-ry, ry + 1), np.arange(-rx, rx + 1), indexing="ij")
    ring = (np.abs(dr) > iy) | (np.abs(dc) > ix)
    dr, dc = dr[ring], dc[ring]
    ok = np.zeros(idx.size, bool)
    allow = np.float32(depth_m + float(slope) * float(np.hypot(ry * cell_size[1], rx * cell_size[0])))
    flat = z.ravel()
    for i, (q, v, inside) in enumerate(_gather_offsets(flat, z.shape, idx, dr, dc)):
        part = slice(i * _RING_CHUNK, i * _RING_CHUNK + q.size)
        own = flat.take(q).astype(np.float32)
        v[~inside] = np.nan
        with np.errstate(invalid="ignore"):
            ground = _nan_quantile_rows(v, GAP_GROUND_QUANTILE)
            v[~(v > own[:, None] + np.float32(depth_m))] = np.inf         # NaN too
            ok[part] = (own < ground - allow) & (v.min(axis=1) >= bank[part] - allow)
    return ok


def _nan_quantile_rows(v, q):
    """``np.nanquantile(v, q, axis=1)`` as float32 (NaN for a row of NaN only), the same values:
    the rows sorted (NaN last) and :func:`numpy.quantile` asked once per count of finite values
    on those rows' finite values. ``nanquantile`` along an axis calls itself row by row in
    Python (0.48 s for 4096 rings of 416 cells; this: 0.05 s)."""
    s = np.sort(v, axis=1)
    n = np.count_nonzero(~np.isnan(s), axis=1)
    out = np.full(v.shape[0], np.nan, np.float32)
    for k in np.unique(n[n > 0]):
        rows = np.flatnonzero(n == k)
        out[rows] = np.quantile(s[rows, :k], q, axis=1)
    return out


#: Nodata gaps at most this many cells from a valid cell (missing scan lines, a checkerboard of
#: dropouts: gaps up to two cells across) are part of the surface around them for
#: :func:`object_widths`: an object continues under them.
GAP_CELLS = 1.0


def object_widths(objects, cell_size, area_share=0.98, nodata=None, border_outside=True):
    """Width of the widest objects of a mask, metres: the width below which ``area_share``
    of the objects' area lies.

    The width of an object (a 4-connected component of ``objects``) is twice the largest
    distance (metres) from one of its cells to the nearest cell outside it, i.e. the side
    of the largest square, or the diameter of the largest disc, it holds; a long bridge or
    hedge is as wide as it is across, not as long. Objects are ranked by width and their
    areas accumulated: the result is the width at which ``area_share`` of the object area
    is reached (large objects weigh by their area, a few wide ones are not outvoted by many
    small ones). Exact (to the cell) for odd widths in cells, one cell less for even ones
    (a one-cell object is one cell wide); 0 without objects.

    Parameters
    ----------
    objects : array_like of bool, 2-D
        The object cells (e.g. the cells of a DSM left standing above the ground level).
    cell_size : (float, float)
        ``(dx, dy)`` metres.
    area_share : float
        Share of the object area at or below the returned width (0 < share <= 1).
    nodata : array_like of bool, 2-D, optional
        Nodata cells. Those in narrow gaps (within :data:`GAP_CELLS` of a valid cell:
        missing scan lines, scattered dropouts) are not outside an object: the distance is
        measured to the nearest valid cell outside it (a roof crossed by missing scan lines
        every 7 rows read 7 m wide, and a filter's window sized from it left the roof
        standing). Wider nodata areas stay outside. With such gaps, an object's cells that
        touch at a corner are one object (8-connected: a checkerboard of dropouts leaves a
        roof's cells touching only at corners).
    border_outside : bool
        Whether the raster's border is outside every object (True) or an object cut by it
        continues beyond it (False: its width is measured to its outline inside the raster).
    """
    obj = np.asarray(objects, bool)
    if not 0 < area_share <= 1:
        raise ValueError(f"area_share must be in (0, 1]; got {area_share}.")
    if obj.ndim != 2 or not obj.any():
        return 0.0
    dx, dy = float(cell_size[0]), float(cell_size[1])
    inside = obj
    structure = None
    if nodata is not None:
        gaps = np.asarray(nodata, bool)
        if gaps.any():
            gaps = gaps & (ndimage.distance_transform_edt(gaps) <= GAP_CELLS)
            inside = obj | gaps
            if gaps.any():              # cells of an object touching corners across a gap (a
                structure = np.ones((3, 3), bool)   # checkerboard of dropouts) are one object
    lab, n = ndimage.label(obj, structure)
    # distance from each object cell to the nearest non-object cell, counted to the cell's
    # far edge (a one-cell object: half a cell to its edge, so one cell wide)
    pad = 1 if border_outside else 0
    dist = ndimage.distance_transform_edt(np.pad(inside, pad), sampling=(dy, dx))
    dist = dist[pad:dist.shape[0] - pad, pad:dist.shape[1] - pad]
    lab_obj = lab[obj]
    inner = ndimage.maximum(dist[obj], lab_obj, index=np.arange(1, n + 1))
    width = 2.0 * np.asarray(inner, np.float64) - min(dx, dy)
    area = np.bincount(lab_obj, minlength=n + 1)[1:].astype(np.float64)
    order = np.argsort(width, kind="stable")
    cum = np.cumsum(area[order]) / area.sum()
    i = min(int(np.searchsorted(cum, area_share - 1e-12)), n - 1)
    return float(width[order][i])


#: Widest raised region :func:`raised_region_width` reports, metres: one doubling of the widest window a
#: filter derives by default (the morphological object-size search's and the curvature filter's 100 m), as
#: ``bareearth:dtm``'s raised-region stage looks one doubling beyond its members' windows.
RAISED_REGION_MAX_M = 200.0


def raised_region_width(z, cell_size, height_m, min_width_m, max_width_m=RAISED_REGION_MAX_M, max_span_m=None,
                        across=True, progress=None):
    """Width, metres, of the widest raised region standing on walls that is wider than ``min_width_m``.

    A flat roof wider than a filter's largest window (a roof over most of a tile, running off the
    raster: lidar ``sample_c``) is kept as ground by the window (the tile's edge mirrors it). Its
    outline says what it is: steps down of more than ``height_m`` to ground continuing beyond them,
    over most of its seen outline, and its cells above the plane of that ground
    (:func:`~bare_earth.core.dtm_regions.find_raised_regions` with every cell taken as ground). The
    width is the region's footprint's (twice the largest distance from a cell to a cell outside it,
    less a cell), mirrored at the raster's edge where the region may continue; regions wider than
    ``max_width_m`` are not looked at. 0 when there is none.

    Parameters
    ----------
    z : ndarray, 2-D float32
        The DSM (NaN nodata).
    cell_size : (float, float)
        ``(dx, dy)`` metres.
    height_m : float
        The object height threshold: the first scale of the walls and the height above the ground around.
    min_width_m : float
        Regions at most this wide are not reported (the window the filter already has).
    max_width_m : float
        The widest region looked at, metres.
    max_span_m : float, optional
        The longest region looked at (rows or columns spanned, and its walls' run), metres; default
        ``max_width_m``. A hall 115 m wide and 242 m long spans more than 200 m.
    across : bool
        False: a region meeting two opposite sides of the raster (running across it, continuing beyond
        both: a terrace's upper level across a tile) is not reported.
    progress : callable, optional
        ``progress(fraction)`` from inside the search, after each of its scales (may raise ``Cancelled``).
    """
    return float(max((d["width_m"] for d in _raised_region_objects(z, cell_size, height_m, min_width_m,
                                                                   max_width_m, max_span_m, across=across,
                                                                   progress=progress)),
                     default=0.0))


def _raised_region_objects(z, cell_size, height_m, min_width_m, max_width_m, max_span_m, min_cells=0, across=True,
                           progress=None):
    """The decisions of :func:`~bare_earth.core.dtm_regions.find_raised_regions` (every cell taken as ground)
    that found a raised region standing on walls, at most ``max_width_m`` wide, spanning at most
    ``max_span_m`` (default ``max_width_m``; with ``min_cells``, only those spanning more cells); ``progress``
    passed to the search (a report after each scale)."""
    from .dtm_regions import find_raised_regions  # dtm_regions reads the geodesic package: no cycle
    dx, dy = float(cell_size[0]), float(cell_size[1])
    cap = float(max_width_m)
    span = cap if max_span_m is None else max(cap, float(max_span_m))
    _, decisions = find_raised_regions(z, np.zeros(np.shape(z), np.uint8), (dx, dy), tolerance_m=height_m,
                                       min_width_m=min_width_m, max_cells=int(math.ceil(span / min(dx, dy))),
                                       min_cells=int(min_cells), progress=progress)
    h, w = np.shape(z)

    def runs_across(b):
        return (b[0] <= 0 and b[2] >= h) or (b[1] <= 0 and b[3] >= w)
    return [d for d in decisions if d["object"] and d["width_m"] <= cap and (across or not runs_across(d["bbox"]))]


def raised_region_span(z, cell_size, height_m, min_width_m, max_width_m=RAISED_REGION_MAX_M, max_span_m=None,
                       min_cells=0, across=True, progress=None):
    """Cells spanned by the longest raised region standing on walls wider than ``min_width_m``: the rows or
    columns of its box, or its walls' run where longer (mirrored at the raster's sides they meet), as
    :func:`~bare_earth.core.dtm_regions.find_raised_regions` counts the span it reaches (the regions of
    :func:`raised_region_width`: at most ``max_width_m`` wide, spanning at most ``max_span_m``, default
    ``max_width_m``); with ``min_cells``, only the regions spanning more cells are looked at (a reach the
    caller already has: the labelling is the same, the regions judged far fewer). ``across``: as
    :func:`raised_region_width`'s (False: a region running across the raster spans nothing). 0 when there is
    none. ``progress``: as :func:`raised_region_width`'s.

    Examples
    --------
    >>> z = np.zeros((300, 300), np.float32)
    >>> z[20:200, 20:280] = 10.0
    >>> raised_region_span(z, (1.0, 1.0), 2.0, 64.0, max_span_m=400.0)    # the region within its rims
    258
    """
    spans = [max(d["bbox"][2] - d["bbox"][0], d["bbox"][3] - d["bbox"][1],
                 int(round(d.get("walls_m", 0.0) / min(float(cell_size[0]), float(cell_size[1])))))
             for d in _raised_region_objects(z, cell_size, height_m, min_width_m, max_width_m, max_span_m, min_cells,
                                             across=across, progress=progress)]
    spans = [s for s in spans if s > min_cells]
    return int(max(spans, default=0))


#: Longest raised region (rows or columns spanned) a filter's resolve looks at when widening its window,
#: metres: one doubling of the widest (:data:`RAISED_REGION_MAX_M`), as the width's cap is one doubling of the
#: widest window derived (a hall 115 m wide and 242 m long spans more than 200 m). A resolve runs once on the
#: whole raster, so no block's halo depends on it.
RAISED_REGION_SPAN_M = 2.0 * RAISED_REGION_MAX_M


#: The raised-region estimates of a resolve (:func:`raised_region_window`, :func:`raised_region_span`) run on
#: block minima of at most this many cells (:func:`raised_region_grid`): regions wider than a filter's window
#: (40 m and more) stay tens of blocks wide, and labelling every cell of a 16 Mcell raster as ground took 20 s.
RAISED_REGION_CELLS = 1_000_000


def raised_region_grid(z, cell_size):
    """``(zs, (dx k, dy k), k)``: the block minima (:func:`block_minima`) of the smallest ``k`` leaving at
    most :data:`RAISED_REGION_CELLS` cells (``z`` itself when it has no more), on which a resolve looks for
    raised regions.

    Examples
    --------
    >>> zs, cs, k = raised_region_grid(np.zeros((1500, 1500), np.float32), (1.0, 1.0))
    >>> zs.shape, cs, k
    ((750, 750), (2.0, 2.0), 2)
    """
    k = max(1, int(np.ceil(np.sqrt(np.size(z) / RAISED_REGION_CELLS))))
    zs = block_minima(z, k) if k > 1 else z
    return zs, (float(cell_size[0]) * k, float(cell_size[1]) * k), k


#: Margin of a window on the width of the widest raised region (roof shapes, the rims on top of its walls
#: that the region's width leaves out: a window just as wide still fits inside it).
RAISED_REGION_MARGIN = 1.25


def raised_region_window(z, cell_size, height_m, min_window_m, max_width_m=RAISED_REGION_MAX_M, max_span_m=None,
                         across=True, progress=None):
    """The window, metres, that reaches across the widest raised region standing on walls wider than
    ``min_window_m`` (:func:`raised_region_width`, regions spanning up to ``max_span_m``, default
    ``max_width_m``): :data:`RAISED_REGION_MARGIN` x its width + 2 cells, at most ``max_width_m``; 0 when
    there is none. ``across`` and ``progress``: as :func:`raised_region_width`'s.

    Examples
    --------
    >>> z = np.zeros((200, 200), np.float32)
    >>> z[40:160, 40:160] = 10.0
    >>> raised_region_window(z, (1.0, 1.0), 2.0, 64.0)
    148.25
    """
    wide = raised_region_width(z, cell_size, height_m, min_window_m, max_width_m, max_span_m, across=across,
                               progress=progress)
    if wide <= 0:
        return 0.0
    return float(min(max_width_m, RAISED_REGION_MARGIN * wide + 2.0 * max(float(cell_size[0]), float(cell_size[1]))))


#: Cells per band of :func:`joined_runs`' height differences (a float buffer of a quarter of a million cells).
_JOIN_BAND_CELLS = 1 << 18


def joined_runs(z, nodes, step_m, diagonal=False):
    """The parts of the cells ``nodes`` (a boolean array of ``z``'s shape) joined across the
    4-neighbour edges (with ``diagonal``, the 8-neighbour edges) whose heights ``z`` differ by at
    most ``step_m``, by runs: the cells joined along a row make a run, and the runs joined to the
    next row make the parts (``connected_components`` on one edge per pair of runs that touch
    along a stretch of columns in each direction, not one per cell).

    Returns ``(run, comp, first)``: ``run`` the run of each cell (flat, row-major), ``comp`` the
    part of each run (numbered in the order of the parts' first cells), ``first`` each run's first
    cell (flat); a cell outside ``nodes`` is a run and a part of its own.

    Examples
    --------
    >>> z = np.array([[0, 0, 5], [0, 9, 5]], np.float32)
    >>> run, comp, first = joined_runs(z, np.ones(z.shape, bool), 1.0)
    >>> run.tolist(), comp.tolist(), first.tolist()
    ([0, 0, 1, 2, 3, 4], [0, 1, 0, 2, 1], [0, 2, 3, 4, 5])
    """
    h, w = z.shape
    # the differences in bands of rows into a cache-sized buffer: no raster-sized float temporary (at 16 Mcells a
    # new 64 MB array each, whose pages the kernel zeroes on first touch), the same float32 operations per cell
    rows = max(1, _JOIN_BAND_CELLS // max(1, w))
    diff = np.empty((min(rows, h), w), z.dtype)
    with np.errstate(invalid="ignore"):
        def joined(a, b, na, nb):
            e = np.empty(a.shape, bool)
            for r0 in range(0, a.shape[0], rows):
                r1 = min(a.shape[0], r0 + rows)
                d = diff[:r1 - r0, :a.shape[1]]
                np.subtract(a[r0:r1], b[r0:r1], out=d)
                np.abs(d, out=d)
                np.less_equal(d, step_m, out=e[r0:r1])
            e &= na
            e &= nb
            return e
        hj = joined(z[:, 1:], z[:, :-1], nodes[:, 1:], nodes[:, :-1])
        # down the columns: (i, j) - (i + 1, j); with the diagonals (i, j) - (i + 1, j + 1) and
        # (i, j + 1) - (i + 1, j), at column j of arrays one column narrower
        down = [(joined(z[1:], z[:-1], nodes[1:], nodes[:-1]), 0, 0)]
        if diagonal:
            down += [(joined(z[1:, 1:], z[:-1, :-1], nodes[1:, 1:], nodes[:-1, :-1]), 0, 1),
                     (joined(z[1:, :-1], z[:-1, 1:], nodes[1:, :-1], nodes[:-1, 1:]), 1, -1)]
    start = np.ones((h, w), bool)
    np.logical_not(hj, out=start[:, 1:])
    first = np.flatnonzero(start)                      # each run's first cell (every row's first among them)
    del start
    run = np.zeros(h * w, np.int32 if h * w < 2 ** 31 else np.int64)
    run[first[1:]] = 1
    np.cumsum(run, out=run)
    a, b = [], []
    for e, top, dc in down:
        # an edge joins the same two runs as the one left of it when both its cells are joined leftwards
        n = e.shape[1]
        e[:, 1:] &= ~(e[:, :-1] & hj[:-1, top:top + n - 1] & hj[1:, top + dc:top + dc + n - 1])
        i = np.flatnonzero(e)
        i = i // n * w + i % n + top                   # the upper cell, in the rows of w cells
        a.append(run[i])
        b.append(run[i + w + dc])
    del hj, down
    a, b = np.concatenate(a), np.concatenate(b)
    graph = csr_matrix((np.ones(a.size, np.int8), (a, b)), shape=(first.size, first.size))
    return run, connected_components(graph, directed=False)[1], first


def smooth_parts(w, cells, step_m):
    """The parts of the cells ``cells`` (flat indices into ``w``) joined across 8-neighbour
    edges whose heights differ by at most ``step_m`` (a wall, a NaN, a cell outside ``cells``
    separates them): ``(n, part)``, ``part[i]`` in ``0 .. n - 1`` the part of ``cells[i]``,
    numbered in the order of the parts' first cells in ``cells``.

    Cells sorted and filling at least a quarter of the rows they span are joined by runs
    (:func:`joined_runs`: 3 to 6 times faster there); others by a graph of their own edges (much
    faster on a few cells scattered over many rows). Both give the same parts, numbered alike.

    Examples
    --------
    >>> w = np.array([[0, 0, 5, 5], [0, 0, 5, 9]], np.float32)
    >>> smooth_parts(w, np.arange(8), 1.0)
    (3, array([0, 0, 1, 1, 0, 0, 1, 2], dtype=int32))
    """
    H, W = w.shape
    n_c = cells.size
    if n_c == 0:
        return 0, np.zeros(0, np.int32)
    r0, r1 = int(cells[0]) // W, int(cells[-1]) // W + 1
    if 4 * n_c >= (r1 - r0) * W and n_c < 2 ** 31 and bool(np.all(cells[1:] > cells[:-1])):
        loc = cells - r0 * W
        nodes = np.zeros((r1 - r0) * W, bool)
        nodes[loc] = True
        run, comp, _ = joined_runs(w[r0:r1], nodes.reshape(r1 - r0, W), step_m, diagonal=True)
        part = comp[run[loc]]
        # the parts of cells outside ``cells`` (runs of their own) dropped from the numbering
        used = np.zeros(comp.size + 1, np.int32)
        used[part] = 1
        np.cumsum(used, out=used)
        return int(used[-1]), (used[part] - 1).astype(np.int32)
    return _smooth_parts_graph(w, cells, step_m)


def _smooth_parts_graph(w, cells, step_m):
    """:func:`smooth_parts` by a graph of the cells' own forward 8-neighbour edges."""
    H, W = w.shape
    n_c = cells.size
    # the cells in a layout one column wider (a padding column after each row, never a cell): a neighbour
    # beyond the row's end lands there, so no bounds test is needed; each cell's position in ``cells`` is
    # looked up by that index over the span the cells and their neighbours cover (a gather where a sorted
    # search took 3/4 of the time), and the heights are read once, at the cells
    W1 = W + 1
    cp = cells + cells // W
    lo = int(cp.min())
    pos = np.full(int(cp.max()) + W1 + 2 - lo, -1, np.int32 if n_c < 2 ** 31 else np.int64)
    pos[cp - lo] = np.arange(n_c, dtype=pos.dtype)
    cp -= lo
    wc = w.ravel()[cells]
    # each cell's 4 forward neighbours (each 8-neighbour edge once), a row per cell: the smooth ones, row
    # by row, are the graph's CSR rows as they stand (no coordinate list to sort and sum into rows: half
    # the time on a town of 2 million cells), its indices int32 (half the graph's memory)
    nb = np.empty((n_c, 4), pos.dtype)
    for k, (dr, dc) in enumerate(((0, 1), (1, -1), (1, 0), (1, 1))):
        nb[:, k] = pos[cp + (dr * W1 + dc)]              # at least 0: dr * W1 + dc > 0
    del pos
    smooth = nb >= 0
    with np.errstate(invalid="ignore"):
        smooth &= np.abs(wc[np.maximum(nb, 0)] - wc[:, None]) <= step_m
    indptr = np.zeros(n_c + 1, np.int32 if 4 * n_c < 2 ** 31 else np.int64)
    np.cumsum(np.count_nonzero(smooth, axis=1), out=indptr[1:])
    nb = nb[smooth]
    graph = csr_matrix((np.ones(nb.size, np.int8), nb, indptr), shape=(n_c, n_c))
    return connected_components(graph, directed=False)


def raised_parts(z, step_m, max_cells):
    """Cells of a DSM on parts standing on walls: bool, ``z``'s shape.

    The surface is cut into parts (:func:`smooth_parts`: cells joined by steps between
    8-neighbours of at most ``step_m``; a wall, a NaN separates them). A part is raised when
    more than half of its rim steps down: of the 4-neighbour edges from its cells to valid cells
    of other parts, more lead down to a lower part than up to a higher one (nodata and the
    raster's edge are no rim). A roof or a bridge's deck steps down its walls all round, a
    crown down to the ground; the ground steps up to the objects on it, down into a pit or a
    ditch only. A part whose bounding box exceeds ``max_cells = (rows, cols)`` (a plateau, a
    terrace's upper level, the terrain around a pit) is never raised, nor one meeting two
    opposite sides of the raster (running across it: its extent is not seen, a terrace's upper
    level across a tile).

    What it is for: the block minima of a DSM reach the ground only where the blocks are wider
    than the objects (:func:`block_minima`); a hall or a block of buildings round courtyards
    wider than the blocks puts its roof into them, and its walls into their slopes. Left out,
    the block minima are the ground's again.

    Parameters
    ----------
    z : array_like, 2-D
        DSM, NaN = nodata.
    step_m : float
        Highest step within a part, metres (a wall is higher): e.g. the noise tolerance plus a
        cell's rise at :data:`GAP_BANK_SLOPE`, the steepest bank.
    max_cells : (int, int)
        Largest bounding box ``(rows, cols)`` of a raised part.

    Examples
    --------
    >>> z = np.zeros((5, 7), np.float32); z[1:4, 1:4] = 9.0; z[2, 5] = -9.0
    >>> raised_parts(z, 1.0, (4, 4)).astype(int)
    array([[0, 0, 0, 0, 0, 0, 0],
           [0, 1, 1, 1, 0, 0, 0],
           [0, 1, 1, 1, 0, 0, 0],
           [0, 1, 1, 1, 0, 0, 0],
           [0, 0, 0, 0, 0, 0, 0]])
    >>> raised_parts(z, 1.0, (2, 4)).any()        # the roof larger than an object: terrain
    False
    """
    z = np.asarray(z, np.float32)
    valid = np.isfinite(z)
    cells = np.flatnonzero(valid)
    out = np.zeros(z.shape, bool)
    if cells.size == 0:
        return out
    n, part = smooth_parts(z, cells, float(step_m))
    lab = np.full(z.shape, -1, np.int32)
    lab.ravel()[cells] = part
    down = np.zeros(n, np.int64)
    up = np.zeros(n, np.int64)
    for a, b in (((slice(None), slice(None, -1)), (slice(None), slice(1, None))),
                 ((slice(None, -1), slice(None)), (slice(1, None), slice(None)))):
        la, lb = lab[a], lab[b]
        e = (la >= 0) & (lb >= 0) & (la != lb)
        first_higher = z[a][e] > z[b][e]
        la, lb = la[e], lb[e]
        high = np.where(first_higher, la, lb)
        down += np.bincount(high, minlength=n)
        up += np.bincount(np.where(first_higher, lb, la), minlength=n)
    raised = down > up
    cand = np.flatnonzero(raised)
    if cand.size:
        sub = np.zeros(n, np.int32)
        sub[cand] = np.arange(1, cand.size + 1, dtype=np.int32)
        boxes = ndimage.find_objects(np.where(valid, sub[lab], 0), max_label=cand.size)
        b = np.array([(s[0].start, s[0].stop, s[1].start, s[1].stop) for s in boxes]).reshape(-1, 4)
        H, W = z.shape
        across = ((b[:, 0] == 0) & (b[:, 1] == H)) | ((b[:, 2] == 0) & (b[:, 3] == W))
        raised[cand] = (b[:, 1] - b[:, 0] <= max_cells[0]) & (b[:, 3] - b[:, 2] <= max_cells[1]) & ~across
    out.ravel()[cells] = raised[part]
    return out




#: Rows per band of :func:`ground_plane_gradient` (its float64 moments stay a few MB a band).
_PLANE_BAND_ROWS = 256


def ground_plane_gradient(z, ground, cell_size, radius_cells, pool=None, at=None):
    """The gradient of the least-squares plane through the ``ground`` cells of the square of half-side
    ``radius_cells`` around each cell: ``(gx, gy)``, rise per metre along the columns and the rows (float32;
    NaN where the square holds fewer than three ground cells not on one line).

    The ground's own slope where it is seen: the plane through a quadratic surface's cells of a centred
    square has the surface's gradient at the centre, whatever the square's size, and cells above the ground
    (low vegetation the ground cells still hold) tilt it by their height times their offset over the
    square's second moment, little when they are few.

    Parameters
    ----------
    z : ndarray, 2-D
        Heights (NaN nodata).
    ground : ndarray of bool
        The cells the planes are fitted to.
    cell_size : (float, float)
        ``(dx, dy)`` metres.
    radius_cells : int
        Half-side of the squares, cells (>= 1).
    pool : Executor, optional
        Threads that may take some of the bands of rows (:func:`~.blocks.run_sharing`); the same result
        without.
    at : ndarray of bool, optional
        The cells whose planes are wanted (NaN elsewhere): a band of rows holding none is skipped, the pass
        along the rows runs on the rows holding one and the planes are solved at them only (the same values
        there, bit for bit: the passes down the columns are the whole band's). None: every cell.
    """
    z = np.asarray(z)
    ground = np.asarray(ground, bool)
    if at is not None:
        at = np.asarray(at, bool)
        if at.shape != z.shape:
            raise ValueError(f"at has shape {at.shape} but z has {z.shape}: pass a mask of the DSM's grid.")
    r = max(1, int(radius_cells))
    dx, dy = float(cell_size[0]), float(cell_size[1])
    rows, cols = z.shape
    gx = np.full(z.shape, np.nan, np.float32)
    gy = np.full(z.shape, np.nan, np.float32)
    x = np.arange(cols, dtype=np.float64)[None, :] * dx
    # each band writes its own rows of gx, gy: the bands may run in any order, on any thread
    run_sharing([partial(_plane_band, z, ground, a, min(rows, a + _PLANE_BAND_ROWS), r, x, dy, gx, gy, at)
                 for a in range(0, rows, _PLANE_BAND_ROWS)], pool)
    return gx, gy


def _plane_band(z, ground, a, b, r, x, dy, gx, gy, at=None):
    """:func:`ground_plane_gradient` on the rows ``a:b``, read with the squares' ``r`` rows around them (exact),
    into ``gx[a:b]``, ``gy[a:b]``.

    The nine box means of ``ndimage.uniform_filter`` bit for bit, cheaper: the pass down the columns along whole
    rows (:func:`~.common.running_mean_down`; SciPy gathers each column with the row stride), the pass along the
    rows on the band's own rows only, the products in one buffer, and the planes solved a few rows at a time
    (:func:`_plane_solve`: the same arithmetic per cell, its temporaries in the cache). With ``at``: the pass along
    the rows on the band's rows holding a cell of ``at`` only, the planes solved at those cells only (each row's
    pass is its own, each cell's solution too: the same values there)."""
    sel = None
    if at is not None:
        sel = np.flatnonzero(at[a:b].any(axis=1))              # the band's rows holding a wanted cell
        if sel.size == 0:
            return
    rows = z.shape[0]
    size = 2 * r + 1
    lo, hi = max(0, a - r), min(rows, b + r)
    zb = np.asarray(z[lo:hi], np.float64)
    g = ground[lo:hi] & np.isfinite(zb)
    w = g.astype(np.float64)
    y = np.arange(lo, hi, dtype=np.float64)[:, None] * dy - a * dy    # the band's own origin: small moments
    zw = np.where(g, zb, 0.0)

    band = slice(a - lo, b - lo)
    t = np.empty_like(w)                          # the products: band-sized buffers, no temporaries
    d = np.empty_like(w)

    def mean(v):
        # the box mean of ndimage.uniform_filter bit for bit: down the columns (along whole rows, SciPy's sums in
        # its order), then along the rows on the band's own rows only (each row's pass is its own)
        running_mean_down(v, size, d, mode="constant")
        return ndimage.uniform_filter1d(d[band] if sel is None else d[a - lo + sel], size, axis=1, mode="constant",
                                        cval=0.0)

    def moment(u, v, s=None):
        """The box mean of ``u v`` (``u v s``); the products formed as ``u * v * s`` is."""
        np.multiply(u, v, out=t)
        if s is not None:
            np.multiply(t, s, out=t)
        return mean(t)

    means = (mean(w), moment(w, x), moment(w, y), mean(zw), moment(w, x, x), moment(w, y, y), moment(w, x, y),
             moment(zw, x), moment(zw, y))
    del w, zw
    if sel is not None:
        # the wanted cells of those rows, a chunk of cells at a time (the same arithmetic per cell)
        cells = np.flatnonzero(at[a:b][sel])
        px = np.empty(cells.size, np.float32)
        py = np.empty(cells.size, np.float32)
        for i in range(0, cells.size, _PLANE_SOLVE_CELLS):
            k = cells[i:i + _PLANE_SOLVE_CELLS]
            _plane_solve(*(m.ravel()[k] for m in means), size, px[i:i + k.size], py[i:i + k.size])
        ri, ci = np.divmod(cells, gx.shape[1])
        gx[a + sel[ri], ci] = px
        gy[a + sel[ri], ci] = py
        return
    # the planes solved a few rows at a time (the same arithmetic per cell; its temporaries stay in the cache)
    step = max(1, _PLANE_SOLVE_CELLS // max(1, gx.shape[1]))
    for i in range(0, b - a, step):
        rows_ = slice(i, min(b - a, i + step))
        _plane_solve(*(m[rows_] for m in means), size, gx[a + i:a + rows_.stop], gy[a + i:a + rows_.stop])


#: Cells per chunk of :func:`_plane_solve` (its float64 temporaries a few hundred kB).
_PLANE_SOLVE_CELLS = 1 << 15


def _plane_solve(n, ax, ay, az, axx, ayy, axy, axz, ayz, size, gx, gy):
    """The gradient ``(gx, gy)`` (written in place) of the least-squares planes from the squares' box means of
    ``w``, ``w x``, ``w y``, ``w z``, ``w x^2``, ``w y^2``, ``w x y``, ``w z x``, ``w z y``."""
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = np.where(n > 0, 1.0 / n, np.nan)
        mx, my, mz = ax * inv, ay * inv, az * inv
        sxx = axx * inv - mx * mx
        syy = ayy * inv - my * my
        sxy = axy * inv - mx * my
        sxz = axz * inv - mx * mz
        syz = ayz * inv - my * mz
        det = sxx * syy - sxy * sxy
        ok = (np.rint(n * size * size) >= 3) & (det > 1e-9 * (sxx + syy) ** 2)
        gx[...] = np.where(ok, (syy * sxz - sxy * syz) / det, np.nan)
        gy[...] = np.where(ok, (sxx * syz - sxy * sxz) / det, np.nan)


def square_opening(z, size_cells):
    """The grey opening of the heights ``z`` by a square of ``size_cells`` cells (the erosion, the
    lowest height within the square, then the dilation, the highest of those within the square; the cells
    beyond the raster's edge and the nodata cells constrain neither, and nodata stays NaN: a square may
    reach beyond the edge, so a plane keeps its heights up to it and a part cut by the edge keeps what is
    seen of it): every
    part of the surface into which no such square fits is cut down to the surface around it
    (Serra 1982; Zhang et al. 2003, the progressive morphological filter's opening), and a raised
    region that the square fits in all over keeps its height.

    The surface left is the DSM without its objects narrower than the square: a building of several
    heights wider than the square stands there as one level, its lowest part's, on walls all round
    (its parts' own walls on each other are gone), so its width shows
    (:func:`raised_region_window` of the opened surface), where on the DSM its parts, each narrower
    than the square, are raised regions of their own. A plane keeps its heights (the square whose
    lowest corner is a cell holds no lower height).

    Examples
    --------
    >>> z = np.zeros((5, 7), np.float32)
    >>> z[1:4, 1:3] = 4.0          # 3 x 2: the 3 x 3 square does not fit
    >>> z[1:4, 4:7] = 6.0          # 3 x 3, running off the edge: it fits
    >>> z[2, 5] = 9.0              # a spike on it
    >>> square_opening(z, 3).astype(int).tolist()[2]
    [0, 0, 0, 0, 6, 6, 6]
    """
    z = np.asarray(z, np.float32)
    k = int(size_cells)
    if k < 1:
        raise ValueError(f"size_cells must be at least 1; got {size_cells!r}.")
    valid = np.isfinite(z)
    p = k - 1                                      # the squares reaching beyond the edge by up to k - 1 cells
    a = np.pad(np.where(valid, z, np.float32(np.inf)), p, constant_values=np.inf)
    inf = dict(mode="constant", cval=np.inf)
    a = ndimage.minimum_filter1d(ndimage.minimum_filter1d(a, k, axis=0, **inf), k, axis=1, **inf)
    a[np.isinf(a)] = -np.inf                       # squares of nodata only: no height for the dilation
    o = -1 if k % 2 == 0 else 0                    # an even square: the dilation's is the erosion's reflected
    ninf = dict(mode="constant", cval=-np.inf, origin=o)
    a = ndimage.maximum_filter1d(ndimage.maximum_filter1d(a, k, axis=0, **ninf), k, axis=1, **ninf)
    a = a[p:p + z.shape[0], p:p + z.shape[1]].copy()
    a[~valid] = np.nan
    return a



def raised_region_span_walled(z, cell_size, height_m, min_width_m, max_width_m=RAISED_REGION_MAX_M,
                              max_span_m=None, min_cells=0, across=True, progress=None):
    """Cells spanned by the longest raised region standing on walls (:func:`raised_region_span`'s regions and
    count) whose walls run along both sides of its length: the part of its outline not on walls is shorter
    than its span. A building stands on walls all round (a ring round a courtyard, a long wing); a level cut
    into a slope (a quarry's bench, a terrace) stands on walls down on one side only, the other rising to the
    level above or running on at its own, and passes :func:`raised_region_span`'s test (walls over more than
    half its outline) by its ends alone: a bench arc 14 m wide and 226 m long, on walls over 53 % of its
    outline. Only what is seen counts: the rows or columns of the region's box, not its walls' run mirrored
    at the raster's sides (a roof in a corner of ISPRS samp41, 108 m seen, spans 216 m so, and widened a
    filter's largest object to 142 m for a building it does not show). 0 when there is none. ``progress``: as
    :func:`raised_region_width`'s.

    Examples
    --------
    >>> z = np.zeros((140, 140), np.float32)
    >>> z[20:120, 20:120] = 10.0
    >>> z[30:110, 30:110] = 0.0                    # a ring 10 m wide round a courtyard at the ground's level
    >>> raised_region_span_walled(z, (1.0, 1.0), 2.0, 0.0, max_span_m=200.0)
    98
    """
    dx, dy = float(cell_size[0]), float(cell_size[1])
    spans = []
    for d in _raised_region_objects(z, (dx, dy), height_m, min_width_m, max_width_m, max_span_m, min_cells,
                                    across=across, progress=progress):
        s = max(d["bbox"][2] - d["bbox"][0], d["bbox"][3] - d["bbox"][1])
        if s > min_cells and (1.0 - float(d["step_share"])) * float(d["outline_cells"]) < s:
            spans.append(s)
    return int(max(spans, default=0))


#: The four directions (rows, columns per step) of :func:`line_share`: along a row, down a column, the diagonals.
LINE_DIRECTIONS = ((0, 1), (1, 0), (1, 1), (1, -1))


def line_share(g, cells, half_widths, level, chunk=1 << 15):
    """The largest share, over four straight lines centred on each of ``cells``, of the line's cells where
    ``g`` is at least the cell's ``level``: how far a value continues along some line through the cell.

    A value that holds along a line of ``2 h + 1`` cells centred on the cell (along a row, a column or a
    diagonal) belongs to a feature at least that long in that direction (a dike's or an embankment's flank,
    which continues along its length); a value confined to a compact patch (a crown's flank, whose contours
    curve round it within its width) covers at most the patch's width of any line. Cells of a line beyond the
    raster, and those where ``g`` is NaN, are left out of the share (a line cut by the edge is judged on the part
    inside). Read only at ``cells``, gathered in chunks (no raster-sized temporaries): ``4 (2 h + 1)`` reads
    a cell; vectorised counts, no sort.

    Parameters
    ----------
    g : ndarray, 2-D
        The values (a slope map).
    cells : ndarray of int
        Flat indices of the cells to read.
    half_widths : (int, int)
        The lines' half-lengths ``(h_rows, h_cols)`` in cells: down a column ``h_rows``, along a row ``h_cols``,
        the diagonals the smaller.
    level : float or ndarray
        The value each cell's line is compared with (one per cell, or one for all).
    chunk : int
        Cells gathered at once.

    Returns
    -------
    ndarray of float32
        One share (0-1) per cell; 0 where a line has no cell with a value.

    Examples
    --------
    A band of slope 0.5 three cells wide along the rows, and a 3 x 3 patch: the band's centre keeps 0.5 all
    along its row, the patch's centre along 3 of the 7 cells of every line:

    >>> g = np.zeros((12, 12), np.float32)
    >>> g[2:5, :] = 0.5
    >>> g[7:10, 4:7] = 0.5
    >>> [round(float(v), 3) for v in line_share(g, np.array([3 * 12 + 6, 8 * 12 + 5]), (3, 3), 0.4)]
    [1.0, 0.429]
    """
    g = np.asarray(g)
    if g.ndim != 2:
        raise ValueError(f"g must be 2-D; got {g.ndim} dimensions.")
    hr, hc = (int(h) for h in half_widths)
    if hr < 0 or hc < 0:
        raise ValueError(f"half_widths must be at least 0; got {half_widths!r}.")
    cells = np.asarray(cells, np.int64).ravel()
    if cells.size and (cells.min() < 0 or cells.max() >= g.size):
        raise ValueError(f"cells must be flat indices of g (0 to {g.size - 1}).")
    level = np.broadcast_to(np.asarray(level, np.float32), cells.shape)
    out = np.zeros(cells.size, np.float32)
    H, W = g.shape
    flat = g.ravel()
    rows, cols = np.divmod(cells, W)
    for di, dj in LINE_DIRECTIONS:
        h = hc if di == 0 else hr if dj == 0 else min(hr, hc)
        steps = np.arange(-h, h + 1)
        # the cells whose line stays inside the raster (nearly all): gathered by flat offsets, no bounds to test
        whole = np.ones(cells.size, bool)
        if di:
            whole &= (rows >= h) & (rows < H - h)
        if dj:
            whole &= (cols >= h) & (cols < W - h)
        offs = (di * W + dj) * steps
        for part, inner in ((np.flatnonzero(whole), True), (np.flatnonzero(~whole), False)):
            for c0 in range(0, part.size, chunk):
                k = part[c0:c0 + chunk]
                if inner:
                    v = flat[cells[k][:, None] + offs]
                    inside = np.isfinite(v)
                else:
                    r = rows[k][:, None] + di * steps[None, :]
                    q = cols[k][:, None] + dj * steps[None, :]
                    inside = (r >= 0) & (r < H) & (q >= 0) & (q < W)
                    v = flat[np.where(inside, r * W + q, 0)]
                    inside &= np.isfinite(v)
                with np.errstate(invalid="ignore"):
                    held = np.count_nonzero(inside & (v >= level[k][:, None]), axis=1)
                share = held / np.maximum(np.count_nonzero(inside, axis=1), 1)
                np.maximum(out[k], share, out=share)
                out[k] = share
    return out


def _surface_and_cells(z, func, cells, name, least):
    """``z`` as a float32 2-D surface; ValueError naming ``func`` when it is not 2-D, and ``name`` when
    ``cells`` is not a whole number of cells >= ``least`` (the checks of the window estimates)."""
    z = np.asarray(z, np.float32)
    if z.ndim != 2:
        raise ValueError(f"{func} needs a 2-D surface; got {z.ndim} dimensions.")
    if int(cells) != cells or cells < least:
        raise ValueError(f"{name} must be a whole number of cells >= {least}; got {cells}.")
    return z


def under_chords(z, half_cells, tol_m, progress=None):
    """The cells of a surface that stand no higher than ``tol_m`` above any chord between two cells
    of their row lying within ``half_cells`` on either side of them, nor above any such chord along
    their column (bool, ``z``'s shape): the lower envelope of the surface at the scale of
    ``half_cells``.

    A chord between the cells ``i`` before and ``j`` after a cell is the straight line between
    their heights, ``(j z[c - i] + i z[c + j]) / (i + j)`` at the cell, for every ``1 <= i, j <=
    half_cells``. On a plane, or on terrain curved less than ``2 tol_m / (half_cells cell)^2``, every
    cell lies on its chords; a crown, a shrub or any cell standing above the cells on either side
    lies above them, and a ground cell between two crowns below them. A cell needs at least one
    chord on each axis (the cells within ``half_cells`` of the raster's edge along an axis have
    fewer: a cell on the edge has none and is False); a chord with a nodata end is no chord, and a
    nodata cell is False.

    Parameters
    ----------
    z : array_like, 2-D
        Surface (metres), NaN = nodata.
    half_cells : int
        Cells on either side within which the chords' ends lie (>= 1).
    tol_m : float
        Metres a cell may stand above a chord (>= 0).
    progress : callable, optional
        ``progress(fraction)`` after each block of rows (it may raise
        :class:`~bare_earth.core.common.Cancelled`).

    Returns
    -------
    ndarray of bool

    Examples
    --------
    >>> z = np.array([[0, 0, 3, 0, 0], [0, 0, 2, 0, 0], [1, 1, 1, 1, 1]], np.float32)
    >>> under_chords(z, 1, 0.1)[1].tolist()   # the middle row (the edge cells have no chord along it)
    [False, True, False, True, False]
    """
    z = _surface_and_cells(z, "under_chords", half_cells, "half_cells", 1)
    tol = float(tol_m)
    if not (0.0 <= tol < np.inf):
        raise ValueError(f"tol_m must be a height >= 0 in metres; got {tol_m}.")
    m = int(half_cells)
    h, w = z.shape
    out = np.isfinite(z)
    tol = np.float32(tol)
    # by blocks of rows (cache-sized temporaries; a column's chords are rows of the block's
    # neighbours, so no transposed pass): the same sums per cell as over the whole raster
    step = max(1, _CHORD_BLOCK_CELLS // max(w, 1))
    c = np.empty(min(h, step) * w, np.float32)
    t = np.empty(min(h, step) * w, np.float32)
    for i0 in range(0, h, step):
        i1 = min(h, i0 + step)
        zc, o = z[i0:i1], out[i0:i1]
        n = i1 - i0
        seen = np.zeros((n, w), bool)
        for i in range(1, m + 1):           # along the row
            for j in range(1, m + 1):
                if i + j >= w:
                    continue
                cc = c[:n * (w - i - j)].reshape(n, w - i - j)
                tt = t[:n * (w - i - j)].reshape(n, w - i - j)
                np.multiply(zc[:, :w - j - i], np.float32(j), out=cc)
                np.multiply(zc[:, i + j:], np.float32(i), out=tt)
                cc += tt
                cc /= np.float32(i + j)
                cc += tol
                with np.errstate(invalid="ignore"):
                    o[:, i:w - j] &= ~(zc[:, i:w - j] > cc)
                seen[:, i:w - j] |= np.isfinite(cc)
        o &= seen
        seen[:] = False
        for i in range(1, m + 1):           # along the column
            for j in range(1, m + 1):
                r0, r1 = max(i0, i), min(i1, h - j)
                if i + j >= h or r0 >= r1:
                    continue
                cc = c[:(r1 - r0) * w].reshape(r1 - r0, w)
                tt = t[:(r1 - r0) * w].reshape(r1 - r0, w)
                np.multiply(z[r0 - i:r1 - i], np.float32(j), out=cc)
                np.multiply(z[r0 + j:r1 + j], np.float32(i), out=tt)
                cc += tt
                cc /= np.float32(i + j)
                cc += tol
                with np.errstate(invalid="ignore"):
                    o[r0 - i0:r1 - i0] &= ~(z[r0:r1] > cc)
                seen[r0 - i0:r1 - i0] |= np.isfinite(cc)
        o &= seen
        report(progress, i1 / h)
    return out


#: Cells per block of rows of :func:`above_chords` (its temporaries stay cache-sized).
_CHORD_BLOCK_CELLS = 1 << 18
#: The four directions of :func:`above_chords` (row step, column step): the row, the column and the
#: two diagonals.
_CHORD_DIRECTIONS = ((0, 1), (1, 0), (1, 1), (1, -1))


def above_chords(z, half_cells, margin_m, progress=None):
    """The peaks of a surface: the cells that stand more than ``margin_m`` above at least one chord
    between two cells within ``half_cells`` on either side of them, and above both its ends, along
    each of the four directions, their row, their column and both diagonals (bool, ``z``'s shape).

    A chord between the cells ``i`` steps before and ``j`` steps after a cell along a direction is
    the straight line between their heights, ``(j z[c - i] + i z[c + j]) / (i + j)`` at the cell,
    for ``1 <= i, j <= half_cells``. A shrub, a crown or a spike stands above the cells around it
    in every direction; a cell on a slope, a terrain edge (a terrace's or a quarry bench's top, a
    dam's crest, straight or crossed obliquely) or a ledge lies on its chords along the edge, in
    one direction at least, and the rim of a gully's head, curved in plan, stands above the chords
    into the gully but below the ground beyond it (bare gullies at 4 m cells: 126 cells of 10,000
    stood above a chord every way, 5 above one and its ends). A chord with a nodata end, or reaching
    beyond the raster, is no chord; a cell without a chord in one direction is no peak, and neither
    is a nodata cell.

    Parameters
    ----------
    z : array_like, 2-D
        Surface (metres), NaN = nodata.
    half_cells : int
        Steps on either side within which the chords' ends lie (>= 1).
    margin_m : float or array_like
        Metres a cell must stand above a chord: a number, or per cell (``z``'s shape; NaN: no
        peak there).
    progress : callable, optional
        ``progress(fraction)`` after each block of rows.

    Returns
    -------
    ndarray of bool

    Examples
    --------
    >>> z = np.zeros((5, 5), np.float32); z[2, 2] = 1.0
    >>> above_chords(z, 1, 0.3).astype(int)[2].tolist()   # a bump: above its chords every way
    [0, 0, 1, 0, 0]
    >>> z[2, :] = 1.0
    >>> above_chords(z, 1, 0.3).any()                      # a ridge: on its chords along the row
    False
    """
    z = _surface_and_cells(z, "above_chords", half_cells, "half_cells", 1)
    m = int(half_cells)
    margin = np.asarray(margin_m, np.float32)
    if margin.ndim == 0:
        if not (0.0 <= float(margin) < np.inf):
            raise ValueError(f"margin_m must be a height >= 0 in metres; got {margin_m}.")
        margin = np.full(z.shape, margin, np.float32)
    elif margin.shape != z.shape:
        raise ValueError(f"margin_m must be a number or an array of the surface's shape {z.shape}; "
                         f"got {margin.shape}.")
    h, w = z.shape
    out = np.zeros((h, w), bool)
    step = max(1, _CHORD_BLOCK_CELLS // max(w, 1))
    for i0 in range(0, h, step):
        i1 = min(h, i0 + step)
        # the block's rows and m more on either side, padded with nodata (no chord beyond the raster)
        zp = np.full((i1 - i0 + 2 * m, w + 2 * m), np.nan, np.float32)
        lo, hi = max(0, i0 - m), min(h, i1 + m)
        zp[lo - i0 + m:hi - i0 + m, m:m + w] = z[lo:hi]
        zc = z[i0:i1]
        blk = np.isfinite(zc)
        c = np.empty(zc.shape, np.float32)
        t = np.empty(zc.shape, np.float32)
        for dr, dc in _CHORD_DIRECTIONS:
            seen = np.zeros(zc.shape, bool)
            for i in range(1, m + 1):
                za = zp[m - i * dr:m - i * dr + i1 - i0, m - i * dc:m - i * dc + w]
                for j in range(1, m + 1):
                    zb = zp[m + j * dr:m + j * dr + i1 - i0, m + j * dc:m + j * dc + w]
                    np.multiply(za, np.float32(j), out=c)
                    np.multiply(zb, np.float32(i), out=t)
                    c += t
                    c /= np.float32(i + j)
                    c += margin[i0:i1]
                    np.maximum(c, za, out=c)         # and above both its ends
                    np.maximum(c, zb, out=c)
                    with np.errstate(invalid="ignore"):
                        seen |= zc > c
            blk &= seen
        out[i0:i1] = blk
        report(progress, i1 / h)
    return out


def running_minimum_slopes(z, cell_size, side_cells):
    """Slope (rise/run) of the terrain under the objects at every cell: the gradient magnitude of the
    running minimum of the surface over a square of ``side_cells + 1`` cells (objects narrower than
    it vanish), by central differences over ``side_cells`` cells (``side_cells // 2`` on either side;
    0 within that of the raster's edge and where the minimum is not finite).

    The sliding counterpart of :func:`terrain_slopes` (block minima), for a per-cell slope: it does
    not depend on where blocks start, so a window of a larger raster holding a cell's surroundings
    within ``side_cells`` gives the same slope there. Near an object wider than the square it reads
    the object's side too: a steepness, never a ground.

    Parameters
    ----------
    z : array_like, 2-D
        Surface (metres), NaN = nodata.
    cell_size : (float, float)
        ``(dx, dy)`` metres.
    side_cells : int
        Side of the square, cells (>= 2).

    Returns
    -------
    ndarray of float32, ``z``'s shape
    """
    gx, gy = running_minimum_gradient(z, cell_size, side_cells)
    s = np.hypot(gx, gy)
    s[~np.isfinite(s)] = 0.0
    return s


def running_minimum(z, side_cells, frame=0):
    """The running minimum of the surface over a square of ``side_cells + 1`` cells (float32; the
    raster's edge repeated beyond it; +inf where the square holds no finite height), inside a frame
    of ``frame`` cells of +inf on each side (shape ``z``'s plus ``2 frame``): the surface whose
    central differences are :func:`running_minimum_gradient`. The frame lets a flat index reach
    ``frame`` positions beyond the raster's edge (curvature's wall test reads the gradient at a few
    cells only, :class:`~bare_earth.core.curvature.profiles.LocalSlopes`).

    Examples
    --------
    >>> running_minimum(np.array([[3, 1, 2, np.nan]], np.float32), 2, frame=1).tolist()
    [[inf, inf, inf, inf, inf, inf], [inf, 1.0, 1.0, 1.0, 2.0, inf], [inf, inf, inf, inf, inf, inf]]
    """
    z = _surface_and_cells(z, "running_minimum", side_cells, "side_cells", 1)
    f = int(frame)
    zf = np.where(np.isfinite(z), z, np.float32(np.inf))
    if f <= 0:
        return ndimage.minimum_filter(zf, int(side_cells) + 1, mode="nearest")
    out = np.full((z.shape[0] + 2 * f, z.shape[1] + 2 * f), np.inf, np.float32)
    ndimage.minimum_filter(zf, int(side_cells) + 1, output=out[f:f + z.shape[0], f:f + z.shape[1]], mode="nearest")
    return out


def running_minimum_gradient(z, cell_size, side_cells):
    """The gradient ``(gx, gy)`` (rise/run along X and along Y, float32, ``z``'s shape) of the
    running minimum of the surface over a square of ``side_cells + 1`` cells, by central
    differences over ``side_cells`` cells (``side_cells // 2`` on either side; 0 within that of
    the raster's edge, NaN where the minimum is not finite): the components of
    :func:`running_minimum_slopes`, for a slope along one axis (curvature's wall test reads the
    terrain's rise along the profile it scans).

    Examples
    --------
    >>> gx, gy = running_minimum_gradient(0.5 * np.arange(8.0)[None, :].repeat(8, 0), (1.0, 1.0), 2)
    >>> float(gx[4, 4]), float(gy[4, 4])
    (0.5, 0.0)
    """
    z = _surface_and_cells(z, "running_minimum_slopes", side_cells, "side_cells", 2)
    dx, dy = (float(c) for c in cell_size)
    k = int(side_cells)
    h = k // 2
    mf = running_minimum(z, k)
    gx = np.zeros(z.shape, np.float32)
    gy = np.zeros(z.shape, np.float32)
    with np.errstate(invalid="ignore"):
        if z.shape[1] > 2 * h:
            gx[:, h:-h] = (mf[:, 2 * h:] - mf[:, :-2 * h]) / np.float32(2 * h * dx)
        if z.shape[0] > 2 * h:
            gy[h:-h] = (mf[2 * h:] - mf[:-2 * h]) / np.float32(2 * h * dy)
    return gx, gy
