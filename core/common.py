"""Small shared pieces: the dtype rule, cell sizes, progress, results."""
import errno
import os
import shutil
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, Optional

import numpy as np
from scipy import ndimage
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components

from .codes import NODATA


class Cancelled(Exception):
    """Raised by a progress callback (or the core) to stop a run early."""


@dataclass
class FilterResult:
    """What a filter returns.

    Attributes
    ----------
    mask : ndarray of uint8
        0 ground, 1 object, 2 low outlier, 255 nodata.
    extras : dict of str -> ndarray
        Per-cell side products, same rows/cols as ``mask`` (2-D, or 3-D with bands
        first), e.g. ``"step"`` (uint8) or ``"curvature"`` (float32, 2 bands).
    info : dict
        Parameters actually used and statistics, for the log.
    surface : ndarray of float32 or None
        The method's own reference surface, when it has one (e.g. the opened surface).
    dtm : ndarray of float32 or None
        A filled DTM when the method computed one anyway: equal to ``z`` at every ground
        cell (mask 0), interpolated at cells 1 and 2. The pipeline then uses it instead of
        filling again.
    """
    mask: np.ndarray
    extras: Dict[str, np.ndarray] = field(default_factory=dict)
    info: Dict[str, Any] = field(default_factory=dict)
    surface: Optional[np.ndarray] = None
    dtm: Optional[np.ndarray] = None


#: A progress callback: ``progress(fraction in [0, 1])``; it may raise :class:`Cancelled`.
Progress = Optional[Callable[[float], None]]


def real_array(a, name="z", what="heights"):
    """``np.asarray(a)`` checked to hold real numbers, with the masked cells of a numpy masked
    array as NaN (nodata).

    A masked array (``rasterio``'s ``read(1, masked=True)``, ``np.ma.masked_equal(z, -9999)``)
    keeps its nodata cells' stored values under the mask: ``np.asarray`` alone would hand them
    on as heights (-9999 m of ground). Copies only a masked array that has masked cells (to
    float32, or float64 for 32- and 64-bit integers and float64).

    Raises ValueError naming ``name`` (and ``what`` it holds) for booleans, non-numeric or
    complex values.

    Examples
    --------
    >>> real_array(np.ma.masked_equal([[1, -9999]], -9999)).tolist()
    [[1.0, nan]]
    """
    masked = np.ma.getmaskarray(a) if np.ma.isMaskedArray(a) else None
    a = np.asarray(np.ma.getdata(a) if masked is not None else a)
    if not np.issubdtype(a.dtype, np.number):
        raise ValueError(f"{name} must be numeric; got dtype {a.dtype}.")
    if np.issubdtype(a.dtype, np.complexfloating):
        raise ValueError(f"{name} holds complex numbers ({a.dtype}): {what} are real numbers. Pass the {what} "
                         "(e.g. the real part, .real) as a real array.")
    if masked is not None and masked.any():
        a = a.astype(np.result_type(a.dtype, np.float32))
        a[masked] = np.nan
    return a


def as_surface(z, name="z"):
    """Return ``z`` as a 2-D float32 array (NaN = nodata), copying only when needed. The
    masked cells of a numpy masked array are nodata (:func:`real_array`).

    Raises ValueError for non-2-D, empty, non-numeric or complex, or all-nodata input.
    """
    z = np.asarray(z) if not np.ma.isMaskedArray(z) else z
    if z.ndim != 2:
        raise ValueError(f"{name} must be a 2-D array (one band); got {z.ndim} dimensions. "
                         "Pass a single band of the DSM.")
    if z.size == 0:
        raise ValueError(f"{name} is empty (shape {z.shape}); pass a raster with cells.")
    z = real_array(z, name)
    with np.errstate(over="ignore"):             # float64 beyond float32's range -> inf = nodata
        z = z.astype(np.float32, copy=False)
    if not np.isfinite(z).any():
        raise ValueError(f"{name} has no valid cell (all nodata/NaN); pass a raster with data.")
    return z


#: Heights beyond this many metres (either sign) are no terrain (the deepest trench and the
#: highest summit lie within 11 km): such cells are nodata, never data a filter sees.
MAX_ABS_HEIGHT_M = 1e5


def without_far_heights(z, count_in=None):
    """``(z, n)``: float array ``z`` with the cells beyond ``MAX_ABS_HEIGHT_M`` (either sign, or
    infinite) set to NaN, and how many there were (NaN cells not counted; only those inside
    the slices ``count_in`` when given). ``z`` itself is returned when there is none, else a
    copy (the caller's array is never changed).

    Such values are an undeclared nodata (``-3.4e38``, ``-1e30``) or corrupt cells: left in,
    they would overflow the filters' arithmetic (squares of 1e30) and ruin every estimate.
    """
    # the lowest and highest finite-or-infinite values first (NaN skipped; no raster-sized temporary): a raster with
    # no far height, the usual one, is returned as it is after one read (each member's derivation asks again)
    if z.size and z.dtype.kind == "f":
        lo, hi = np.fmin.reduce(z, axis=None), np.fmax.reduce(z, axis=None)
        if not (hi > MAX_ABS_HEIGHT_M or lo < -MAX_ABS_HEIGHT_M):     # NaN (all NaN) compares False
            return z, 0
    with np.errstate(invalid="ignore"):
        far = np.abs(z) > MAX_ABS_HEIGHT_M          # inf too; NaN compares False
    if far.any():
        z = np.where(far, np.array(np.nan, z.dtype), z)
        return z, int(np.count_nonzero(far if count_in is None else far[count_in]))
    return z, 0


def far_heights_message(n, declared=None):
    """The log line for :func:`without_far_heights`'s count (one wording for arrays and files);
    ``declared``: the raster's own nodata value, which those cells then do not hold."""
    text = (f"{n} cell(s) with heights beyond +-{MAX_ABS_HEIGHT_M:g} m (or infinite) were treated as "
            "nodata: no terrain is that high or deep, so they are an undeclared nodata value or corrupt "
            "cells.")
    if declared is None or declared != declared:       # none, or NaN: a value beyond is another one
        return text + " Declare the raster's nodata value to silence this."
    return text + (f" The raster declares {float(declared):g} as its nodata, which they do not hold exactly (a "
                   "nodata value written with fewer digits than the cells hold, -3.40282e+38 for -3.4028235e+38, "
                   "reads so): declare the value its missing cells hold to silence this.")


#: Significant digits of a cell size in metres kept (:func:`as_cell_size`). A cell size
#: computed from an extent (``(xmax - xmin) / n``: 0.8000000000000287) or converted from feet
#: (1 m cells in US survey feet: 1.0000000000000002 m; a lidar grid of 4 m in international
#: feet: 3.9999999999999996 m) carries float noise of about 1e-13 of its value; the filters
#: turn sizes in metres into cells by rounding ``size / cell``, where 30 /
#: 1.0000000000000002 = 29.99... cells is a cell less than 30 / 1. Ten digits is more than
#: any cell size needs (over a row of 1e5 cells, 1e-5 of a cell).
CELL_DIGITS = 10


def is_rotated(geotransform, shape, tolerance=1e-3):
    """Whether a GDAL geotransform's rotation terms matter on a grid of ``shape`` (rows, cols).

    Terms that move no cell centre by more than ``tolerance`` of a cell across the whole grid
    (the ``1e-13`` a reprojection's rounding leaves) are not a rotation: the grid is read as
    north-up, its geotransform kept as given."""
    gt = tuple(float(v) for v in geotransform)
    rows, cols = (int(n) for n in shape)
    return abs(gt[2]) * rows > tolerance * abs(gt[1]) or abs(gt[4]) * cols > tolerance * abs(gt[5])


def as_cell_pair(cell_size):
    """Return ``(dx, dy)`` as floats, exactly as given (in any unit); a scalar means square
    cells. ValueError unless one or two positive finite numbers."""
    try:                                            # a complex or a non-numeric text: TypeError / ValueError
        c = np.atleast_1d(np.asarray(cell_size, dtype=float)).ravel()
    except (TypeError, ValueError):
        c = np.array([np.nan])
    if c.size == 1:
        c = np.array([c[0], c[0]])
    if c.size != 2 or not np.all(np.isfinite(c)) or np.any(c <= 0):
        raise ValueError(f"cell_size must be one or two positive numbers; got {cell_size!r}.")
    return float(c[0]), float(c[1])


def as_cell_size(cell_size):
    """Return ``(dx, dy)`` in metres as floats; a scalar means square cells. Each is kept to
    :data:`CELL_DIGITS` significant digits, so the float noise of its computation does not
    move a window given in metres by a cell (a cell size in a CRS's own unit, e.g. feet,
    is :func:`as_cell_pair`'s: rounding it would put noise into its size in metres)."""
    return tuple(float(f"{v:.{CELL_DIGITS}g}") for v in as_cell_pair(cell_size))


def nodata_mask(z):
    """Boolean mask of nodata cells (NaN or inf)."""
    return ~np.isfinite(z)


def finish_mask(mask, z):
    """Return ``mask`` as uint8 with 255 where ``z`` is nodata."""
    mask = np.asarray(mask, dtype=np.uint8)
    mask[~np.isfinite(z)] = NODATA
    return mask


def check_progress(progress):
    """``progress`` itself when it is None or callable; ValueError otherwise (a number or a text
    given for it failed at the first report, after the work had begun, with 'not callable')."""
    if progress is not None and not callable(progress):
        raise ValueError(f"progress must be a callable progress(fraction) or None; got {progress!r}.")
    return progress


def report(progress, fraction):
    """Call ``progress(fraction)`` if a callback was given (it may raise Cancelled)."""
    if progress is not None:
        progress(min(max(float(fraction), 0.0), 1.0))


def sub_progress(progress, start, stop):
    """A callback mapping [0, 1] onto [start, stop] of ``progress`` (None stays None)."""
    if progress is None:
        return None
    return lambda f: progress(start + (stop - start) * min(max(f, 0.0), 1.0))


def cells_of(mask):
    """``np.nonzero(mask)`` of a 2-D boolean array (rows, columns; row-major order) by ``np.flatnonzero``:
    the same arrays, without numpy's 2-D nonzero pass (measured 35 ms on a 4000 x 4000 mask of a few cells,
    2 ms this way).

    Examples
    --------
    >>> [a.tolist() for a in cells_of(np.array([[0, 1], [1, 1]], bool))]
    [[0, 1, 1], [1, 0, 1]]
    """
    mask = np.asarray(mask)
    return np.divmod(np.flatnonzero(mask), mask.shape[1])


def touching(a):
    """Cells of the boolean array ``a`` or with a True cell among their eight neighbours: the
    3 x 3 binary dilation by four shifted ORs (several times faster than
    ``ndimage.binary_dilation`` with a 3 x 3 structure, the same result).

    Examples
    --------
    >>> touching(np.eye(3, dtype=bool)[:, :1]).ravel().tolist()
    [True, True, False]
    """
    a = np.asarray(a, bool)
    g = a.copy()
    g[1:] |= a[:-1]
    g[:-1] |= a[1:]
    out = g.copy()
    out[:, 1:] |= g[:, :-1]
    out[:, :-1] |= g[:, 1:]
    return out


def dilate_box(a, ry, rx):
    """Cells of the boolean array ``a`` or with a True cell within ``ry`` rows and ``rx`` columns: the binary
    dilation by a ``(2 ry + 1) x (2 rx + 1)`` box, ``ndimage.binary_dilation(a, np.ones((2 ry + 1, 2 rx + 1)))``
    (cells beyond the raster False), by two separable passes of shifted ORs doubling the run (``log2(2 r + 1)``
    passes along each axis: a box is the sum of a column and a row, so the same cells). Measured on a
    4000 x 4000 mask of 2 % of the cells: 0.31 s -> 0.03 s for a 5 x 5 box, 1.0 s -> 0.03 s for 11 x 11.

    In bands of rows (each read with ``ry`` rows around it, about :data:`DILATE_BAND_CELLS` cells): its
    temporaries stay a band's, not the raster's (the result is the only raster-sized array).

    Examples
    --------
    >>> a = np.zeros((5, 7), bool); a[2, 3] = True
    >>> dilate_box(a, 1, 2).astype(int).tolist()[1:4]
    [[0, 1, 1, 1, 1, 1, 0], [0, 1, 1, 1, 1, 1, 0], [0, 1, 1, 1, 1, 1, 0]]
    """
    a = np.asarray(a, bool)
    ry, rx = max(0, int(ry)), max(0, int(rx))
    h, w = a.shape
    out = np.empty((h, w), bool)
    rows = max(1, 4 * ry, DILATE_BAND_CELLS // max(1, w))
    for r0 in range(0, h, rows):
        r1 = min(h, r0 + rows)
        s0, s1 = max(0, r0 - ry), min(h, r1 + ry)      # the band's rows with the windows' reach around them
        down = _or_run(a[s0:s1], ry, 0)                # exact on the band's rows: their windows lie in s0:s1
        out[r0:r1] = _or_run(down[r0 - s0:r1 - s0], rx, 1)
    return out


def pad_constant(a, rows, cols, fill):
    """``a`` inside ``rows`` rows and ``cols`` columns of ``fill`` on each side, each cell written once:
    ``np.pad(a, ((rows, rows), (cols, cols)), constant_values=fill)`` without writing the inside twice.

    Examples
    --------
    >>> pad_constant(np.ones((1, 2), int), 1, 0, 7).tolist()
    [[7, 7], [1, 1], [7, 7]]
    """
    a = np.asarray(a)
    rows, cols = int(rows), int(cols)
    h, w = a.shape
    p = np.empty((h + 2 * rows, w + 2 * cols), a.dtype)
    p[:rows] = fill
    p[rows + h:] = fill
    p[rows:rows + h, :cols] = fill
    p[rows:rows + h, cols + w:] = fill
    p[rows:rows + h, cols:cols + w] = a
    return p


def label_boxes(ids, rows, cols, n, shape):
    """Per label ``0 .. n - 1``, the bounding box ``r0, r1, c0, c1`` (end exclusive) of its cells
    ``(rows, cols)`` (``ids`` the label of each); a label without cells gets ``r0, c0 = shape``,
    ``r1, c1 = 0``.

    Examples
    --------
    >>> [b.tolist() for b in label_boxes(np.array([0, 0, 1]), np.array([2, 4, 1]), np.array([3, 1, 0]), 3, (9, 9))]
    [[2, 1, 9], [5, 2, 0], [1, 0, 9], [4, 1, 0]]
    """
    r0, c0 = np.full(n, shape[0], np.int64), np.full(n, shape[1], np.int64)
    r1, c1 = np.zeros(n, np.int64), np.zeros(n, np.int64)
    np.minimum.at(r0, ids, rows)
    np.maximum.at(r1, ids, np.asarray(rows) + 1)
    np.minimum.at(c0, ids, cols)
    np.maximum.at(c1, ids, np.asarray(cols) + 1)
    return r0, r1, c0, c1


#: Cells per band of rows of :func:`dilate_box` (a quarter of a million: a band's bool temporaries 0.25 MB).
DILATE_BAND_CELLS = 1 << 18


def _or_run(a, r, axis):
    """OR of ``a`` over the window ``[i - r, i + r]`` along ``axis`` (cells beyond the array False): a copy of
    ``a`` for ``r <= 0``."""
    if r <= 0 or a.size == 0:
        return a.copy()
    n, w = a.shape[axis], 2 * r + 1

    def sl(start, stop):
        return (slice(start, stop), slice(None)) if axis == 0 else (slice(None), slice(start, stop))

    shape = list(a.shape)
    shape[axis] = n + 2 * r
    m = np.zeros(shape, bool)                    # padded by r False cells at both ends
    m[sl(r, r + n)] = a
    k, length = 1, n + 2 * r
    while 2 * k <= w:                            # m[j] = OR of the padded cells j .. j + 2k - 1
        m = np.logical_or(m[sl(0, length - k)], m[sl(k, length)])
        length -= k
        k *= 2
    return np.logical_or(m[sl(0, n)], m[sl(w - k, w - k + n)])

def square_counts(mask, rows, cols, half):
    """The number of ``mask`` cells in the square of half-side ``half`` cells around each cell ``(rows, cols)``
    (the square cut by the raster's edge; int64, one per cell).

    ``ndimage.uniform_filter(mask, 2 half + 1, mode="constant")`` times the square's area, or (``> 0``)
    ``ndimage.maximum_filter(mask, 2 half + 1, mode="constant")``, read at the cells only, in integers: prefix
    sums along the rows holding a ``mask`` cell, summed down those rows (memory: those rows, not the raster;
    measured 10-20 times faster than either filter over a 4000 x 4000 raster on a few thousand cells).

    Examples
    --------
    >>> m = np.zeros((5, 5), bool); m[0, 0] = m[4, 4] = m[2, 3] = True
    >>> square_counts(m, np.array([2, 0, 4]), np.array([2, 4, 0]), 1).tolist()
    [1, 0, 0]
    >>> square_counts(m, np.array([2]), np.array([2]), 2).tolist()
    [3]
    """
    mask = np.asarray(mask, bool)
    rows = np.asarray(rows, np.int64)
    cols = np.asarray(cols, np.int64)
    if mask.ndim != 2 or rows.shape != cols.shape:
        raise ValueError(f"square_counts needs a 2-D mask and rows, cols of one shape; got {mask.shape}, "
                         f"{rows.shape}, {cols.shape}.")
    half = int(half)
    if half < 0:
        raise ValueError(f"half must be at least 0 cells; got {half}.")
    w = mask.shape[1]
    held = np.flatnonzero(mask.any(axis=1))               # the rows holding a mask cell, sorted
    if held.size == 0 or rows.size == 0:
        return np.zeros(rows.shape, np.int64)
    # pre[k, j]: the mask cells in the rows held[:k], columns < j
    pre = np.zeros((held.size + 1, w + 1), np.int32 if mask.size < 2 ** 31 else np.int64)
    np.cumsum(mask[held], axis=1, dtype=pre.dtype, out=pre[1:, 1:])
    np.cumsum(pre, axis=0, out=pre)
    lo = np.searchsorted(held, rows - half, "left")
    hi = np.searchsorted(held, rows + half, "right")
    left = np.clip(cols - half, 0, w)
    right = np.clip(cols + half + 1, 0, w)
    return (pre[hi, right].astype(np.int64) - pre[lo, right] - pre[hi, left] + pre[lo, left])



def edge_mirrored_extents(boxes, shape):
    """The extents (rows, columns) of the regions whose bounding boxes are ``boxes`` (slice
    pairs, as ``ndimage.find_objects`` gives) in a raster of ``shape``, each mirrored at every
    side the raster's edge cuts: beyond the edge nothing is seen and a region cut there may
    continue, at least as far again; a region cut on two opposite sides of an axis (a level
    running across the raster, a terrain step) spans three times what is seen along it.
    Returns an int array of shape ``(len(boxes), 2)``.

    Examples
    --------
    >>> edge_mirrored_extents([(slice(0, 4), slice(2, 5)), (slice(1, 3), slice(0, 10))], (10, 10)).tolist()
    [[8, 3], [2, 30]]
    """
    b = np.array([[s.start, s.stop] for box in boxes for s in box], np.intp).reshape(-1, 2, 2)
    return np.stack(edge_mirrored_spans(b[:, 0, 0], b[:, 0, 1], b[:, 1, 0], b[:, 1, 1], shape), axis=1)


def edge_mirrored_spans(r0, r1, c0, c1, shape):
    """:func:`edge_mirrored_extents` of boxes given as arrays of their first and past-the-last
    rows ``r0, r1`` and columns ``c0, c1``: ``(rows, columns)``, two int arrays.

    Examples
    --------
    >>> [a.tolist() for a in edge_mirrored_spans(np.array([0, 1]), np.array([4, 3]), np.array([2, 0]),
    ...                                           np.array([5, 10]), (10, 10))]
    [[8, 2], [3, 30]]
    """
    r0, r1, c0, c1 = (np.asarray(a, np.intp) for a in (r0, r1, c0, c1))
    return ((r1 - r0) * (1 + (r0 == 0) + (r1 == shape[0])),
            (c1 - c0) * (1 + (c0 == 0) + (c1 == shape[1])))


def walls_runs(rows, cols, ids, n, shape, foot_rows=(), foot_cols=(), foot_ids=()):
    """The runs (cells) of the walls of the regions ``1 .. n`` in a raster of ``shape``, mirrored at the
    raster's edge where they meet it: for each region the box of its wall cells (``rows, cols``, region
    ``ids`` in ``1 .. n``: the cells on top of its walls) along each axis, the larger of the two, mirrored
    at every side of the raster the *wall* meets: a side both its top and the ground at its foot (cells
    ``foot_rows, foot_cols`` of regions ``foot_ids``: the ground seen beyond the wall) reach. Returns an int
    array of ``n + 1`` runs (0: a region without wall cells, and the unused index 0).

    Beyond the raster's edge nothing is seen and a wall cut there may continue, at least as far again: a
    wall running across the raster (cut on two opposite sides: a terrain step, a river's walls) spans
    three times what is seen, a wall cutting off a corner (two adjacent sides: a roof running off the
    raster, lidar ``sample_c``) twice. Where such a wall ends in a corner, the roof beside its end reaches
    the third side too, but the ground beyond the wall does not: the wall is not cut there. One copy for
    ``bareearth:dtm``'s raised regions (:mod:`.dtm_regions`, and through
    :func:`.estimate.raised_region_width` those of the geodesic and morphological filters), the curvature
    filter's region stage and RASCOR's level changes (:func:`.edge_walls.walled_levels`).

    Examples
    --------
    >>> roof = np.ones((6, 6), bool)
    >>> roof[:5, :2] = False                 # ground in a corner; the roof's own corner reaches the last row
    >>> run = lambda: int(walls_runs(*np.nonzero(touching(~roof) & roof), 1, 1, roof.shape,
    ...                              *np.nonzero(touching(roof) & ~roof), 1)[1])
    >>> run()                                # 6 rows, mirrored at the top only; 3 columns at the left
    12
    >>> roof[:, :2] = False                  # a step running across, top to bottom
    >>> run()
    18
    """
    runs = np.zeros(n + 1, np.intp)
    rows, cols = np.asarray(rows, np.intp).ravel(), np.asarray(cols, np.intp).ravel()
    ids = np.broadcast_to(np.asarray(ids, np.intp), rows.shape)
    f_r, f_c = np.asarray(foot_rows, np.intp).ravel(), np.asarray(foot_cols, np.intp).ravel()
    f_id = np.broadcast_to(np.asarray(foot_ids, np.intp), f_r.shape)
    if rows.size == 0:
        return runs
    big = np.iinfo(np.intp).max

    def boxes(i, r, c):
        lo = np.full((2, n + 1), big, np.intp)
        hi = np.full((2, n + 1), -1, np.intp)
        for axis, v in enumerate((r, c)):
            np.minimum.at(lo[axis], i, v)
            np.maximum.at(hi[axis], i, v)
        return lo, hi + 1

    lo, hi = boxes(ids, rows, cols)
    f_lo, f_hi = boxes(f_id, f_r, f_c)
    size = np.array(shape, np.intp)[:, None]
    met = ((lo == 0) & (f_lo == 0)).astype(np.intp) + ((hi == size) & (f_hi == size))
    has = hi[0] > 0
    runs[has] = ((hi - lo) * (1 + met)).max(axis=0)[has]
    return runs


def steps_beyond(region, stepping, cells=3):
    """Cells of ``stepping`` (bool, the box of a region) farther than ``cells`` cells (8-connected) from
    ``region`` (bool, same box): the ground beyond a level's walls that steps down again. A level the raster
    cuts on two opposite sides with more such cells than half its outline is one of a sequence of levels
    the raster cuts (quarry benches, terraces), not a roof: ``bareearth:dtm``'s raised regions
    (:mod:`.dtm_regions`) and :func:`.edge_walls.walled_levels` ask it alike."""
    own = ndimage.binary_dilation(region, structure=np.ones((3, 3), bool), iterations=cells)
    return int(np.count_nonzero(stepping & ~own))


def transpose(a, rows=256):
    """C-contiguous transpose of a 2-D array, a band of ``rows`` rows at a time.

    About 2-3 times faster than ``np.ascontiguousarray(a.T)``, which walks the source with
    a large stride; each band's transposed copy stays in the cache. Each band is first
    copied into a buffer whose rows are a little longer than the array's, so that the
    transposed read does not step by a power of two (on widths such as 4096 every row
    would map to the same cache set).
    """
    a = np.asarray(a)
    r, c = a.shape
    out = np.empty((c, r), a.dtype)
    if r == 0 or c == 0:
        return out
    buf = np.empty((min(rows, r), c + 16), a.dtype)
    for i in range(0, r, rows):
        n = min(rows, r - i)
        band = buf[:n, :c]
        band[...] = a[i:i + n]
        out[:, i:i + n] = band.T
    return out


#: Rows per band of :func:`running_mean_down` (a band's float64 sums stay in the cache).
DOWN_BAND_ROWS = 64


def running_mean_down(a, size, out, mode="reflect"):
    """``ndimage.uniform_filter1d(a, size, axis=0, mode=mode, cval=0.0, output=out)`` of a 2-D float32 or
    float64 ``a`` into ``out`` (float32 or float64), bit for bit, computed along whole rows.

    SciPy filters each column as a line gathered with the raster's row stride (measured 28-33 ns
    a cell on 2560 x 4000 cells, against 4-8 ns along the rows). Its arithmetic is reproduced
    here in the same order on whole rows at once: the running sum ``S`` of each column starts
    as the sum, in float64 from 0, of the first window (the rows ``-s1 .. s2``, reflected or 0 beyond
    the raster), each next row adds ``a[i + s2] - a[i - s1 - 1]`` (float64), and the mean ``S / size`` is
    rounded to ``out``'s type as SciPy writes it. ``mode``: ``"reflect"`` or ``"constant"`` (0 beyond the
    raster); columns not longer than the window, other types or modes: SciPy itself.
    """
    n = a.shape[0]
    s1 = size // 2
    s2 = size - s1 - 1
    if n <= size or a.ndim != 2 or a.dtype not in (np.float32, np.float64) or out.dtype not in (
            np.float32, np.float64) or mode not in ("reflect", "constant"):
        return ndimage.uniform_filter1d(a, size, axis=0, mode=mode, cval=0.0, output=out)
    zero = np.zeros(a.shape[1], a.dtype) if mode == "constant" else None

    def ext(i):                                   # row i beyond the raster (-s1 <= i < n + s2): reflected or 0
        if 0 <= i < n:
            return a[i]
        if zero is not None:
            return zero
        return a[-i - 1] if i < 0 else a[2 * n - 1 - i]

    band = np.empty((min(DOWN_BAND_ROWS, n), a.shape[1]), np.float64)
    carry = None
    for r0 in range(0, n, band.shape[0]):
        r1 = min(n, r0 + band.shape[0])
        d = band[:r1 - r0]
        lo, hi = max(r0, s1 + 1), min(r1, n - s2)  # rows whose both terms lie inside the raster
        if lo < hi:
            np.subtract(a[lo + s2:hi + s2], a[lo - s1 - 1:hi - s1 - 1], out=d[lo - r0:hi - r0], dtype=np.float64)
        for i in list(range(r0, min(lo, r1))) + list(range(max(hi, r0), r1)):
            if i == 0:                            # the first window: a sum from 0, in order
                t = np.zeros(a.shape[1], np.float64)
                for j in range(-s1, s2 + 1):
                    np.add(t, ext(j), out=t)
                d[0] = t
            else:
                np.subtract(ext(i + s2), ext(i - s1 - 1), out=d[i - r0], dtype=np.float64)
        if carry is not None:
            np.add(carry, d[0], out=d[0])
        for i in range(1, r1 - r0):               # the running sum, row after row
            np.add(d[i - 1], d[i], out=d[i])
        carry = d[r1 - r0 - 1].copy()
        np.divide(d, float(size), out=out[r0:r1], casting="same_kind")
    return out


#: errno values of a write that ran out of room (full disk, file-size limit, quota)
_NO_ROOM = (errno.ENOSPC, errno.EFBIG, errno.EDQUOT)


def pid_alive(pid):
    """Whether process ``pid`` runs on this machine (one we may not signal counts as running): the
    test of whether a work file's writer is gone (:func:`.pointfiles.remove_stale_parts`,
    :func:`.grid.remove_stale_partials`)."""
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True
    return True


def write_failed(path, reason, code=None):
    """The ValueError of an output that failed while it was written (the checks before the work
    passed): it names the output and why, and for a write that ran out of room (``code`` an errno
    of :data:`_NO_ROOM`, or None: GDAL's errors carry none) the free space of its folder.

    Raise it ``from None`` in place of the OSError (or GDAL's RuntimeError), so that QGIS shows a
    message instead of a traceback."""
    folder = os.path.dirname(os.path.abspath(os.fspath(path)))
    if code is None or code in _NO_ROOM:
        try:
            free = f"{shutil.disk_usage(folder).free / 1e6:.0f} MB free there now"
        except OSError:
            free = "its free space unknown"
        hint = (f"The disk of {folder!r} may be full ({free}) or the file larger than its file system takes: "
                "free some space or choose another folder.")
    else:
        hint = f"Check the folder {folder!r} and choose one you can write to."
    return ValueError(f"cannot write the output {os.fspath(path)!r}: {str(reason).strip() or 'no reason given'}. "
                      f"{hint}")



#: Byte-order marks of UTF-16 text (little- and big-endian): what Excel's "Unicode Text" and
#: Windows PowerShell 5's ``>`` / ``Out-File`` write.
UTF16_BOMS = (b"\xff\xfe", b"\xfe\xff")


def text_of(data, path):
    """The text of a text file's bytes ``data``: UTF-8 (with or without its byte-order mark) or
    UTF-16 with its byte-order mark. ValueError naming ``path`` and the fix for anything else
    (a file in a legacy code page holding a non-ASCII character), instead of a decoding error
    that names neither the file nor the byte."""
    try:
        return data.decode("utf-16") if data.startswith(UTF16_BOMS) else data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{str(path)!r} is not UTF-8 text (byte {exc.start}: {data[exc.start:exc.start + 1]!r}): "
                         "save it as UTF-8 (or UTF-16 with its byte-order mark) text, e.g. 'CSV UTF-8' in a "
                         "spreadsheet.") from None


#: :func:`label8` labels by runs a mask with at most this share of its cells set and at most
#: :data:`LABEL_RUNS_RUNS` runs a cell (estimated on every :data:`LABEL_SAMPLE_STEP`-th row); else
#: ``ndimage.label``. Its cost follows the runs (about 0.17 us a run
#: and 0.025 s for 16 Mcells), ``ndimage.label``'s the raster (0.055-0.11 s for 16 Mcells, more with more
#: cells set): measured on 4000 x 4000 masks of smoothed random blobs of 1-30 % of the cells, the two cost the
#: same at 0.010-0.012 runs a cell; on the masks of the 16 Mcells DSM the runs took 0.05-0.9 of its time
#: below 0.009 runs a cell and 1.0-1.6 times it at 0.011-0.012.
LABEL_RUNS_SHARE = 0.25
#: See :data:`LABEL_RUNS_SHARE`.
LABEL_RUNS_RUNS = 0.01
#: :func:`label8` estimates the shares of cells and runs on every this many rows (counting them on the whole
#: mask cost as much as labelling a sparse mask's runs).
LABEL_SAMPLE_STEP = 8


def label8(mask):
    """``ndimage.label(mask, np.ones((3, 3)))`` (8-connected parts, labels 1..n in the order of each part's
    first cell, int32), for a sparse 2-D ``mask`` by its runs: the cells joined along the rows, and the
    runs of consecutive rows that touch (their column spans, widened by one cell for the diagonals,
    overlap) joined by ``connected_components``. The same array and count; a mask with more than
    :data:`LABEL_RUNS_SHARE` of its cells set or :data:`LABEL_RUNS_RUNS` runs a cell goes to ``ndimage.label``.

    Examples
    --------
    >>> m = np.array([[1, 0, 0, 1], [0, 1, 0, 1], [0, 0, 0, 0], [1, 1, 0, 0]], bool)
    >>> lab, n = label8(m)
    >>> n, lab.tolist()
    (3, [[1, 0, 0, 2], [0, 1, 0, 2], [0, 0, 0, 0], [3, 3, 0, 0]])
    """
    mask = np.asarray(mask, bool)
    if mask.ndim != 2 or mask.size == 0 or mask.size >= 2 ** 31:
        return ndimage.label(mask, np.ones((3,) * mask.ndim, bool))
    h, w = mask.shape
    # the shares of cells and runs estimated on a sample of rows (the choice of method only: both give the same)
    sample = mask[::LABEL_SAMPLE_STEP]
    n_s = max(1, sample.size)
    if (np.count_nonzero(sample) > LABEL_RUNS_SHARE * n_s or np.count_nonzero(sample[:, 0])
            + np.count_nonzero(sample[:, 1:] & ~sample[:, :-1]) > LABEL_RUNS_RUNS * n_s):
        return ndimage.label(mask, np.ones((3, 3), bool))
    idx = np.flatnonzero(mask)
    out = np.zeros((h, w), np.int32)
    if idx.size == 0:
        return out, 0
    # runs: cells consecutive along a row
    brk = np.empty(idx.size, bool)
    brk[0] = True
    np.not_equal(idx[1:] - idx[:-1], 1, out=brk[1:])
    # a row's first cell following the last of the row above: consecutive, yet a new run
    wrap = (np.flatnonzero(mask[1:, 0] & mask[:-1, -1]) + 1) * w
    brk[np.searchsorted(idx, wrap)] = True
    first = np.flatnonzero(brk)                      # each run's first cell, in idx
    if first.size > 2 * LABEL_RUNS_RUNS * mask.size:       # the rows sampled were not like the others
        return ndimage.label(mask, np.ones((3, 3), bool))
    run = np.cumsum(brk, dtype=np.int32) - 1         # each cell's run
    del brk
    start = idx[first]
    end = idx[np.append(first[1:] - 1, idx.size - 1)]
    # keys on rows two cells longer: a run's span widened by one cell never reaches another row
    w2 = w + 2
    row = start // w
    k_start = row * w2 + start % w
    k_end = row * w2 + end % w
    # the runs of the row above touching each run: a range of runs (a row's runs are disjoint and sorted)
    above = (row - 1) * w2
    lo = np.searchsorted(k_end, above + (start % w) - 1, "left")
    hi = np.searchsorted(k_start, above + (end % w) + 1, "right")
    cnt = np.maximum(hi - lo, 0)
    total = int(cnt.sum())
    nr = start.size
    if total:
        a = np.repeat(np.arange(nr, dtype=np.int32), cnt)
        b = (np.arange(total) - np.repeat(np.cumsum(cnt) - cnt, cnt) + np.repeat(lo, cnt)).astype(np.int32)
        graph = csr_matrix((np.ones(total, np.int8), (a, b)), shape=(nr, nr))
        n, comp = connected_components(graph, directed=False)
    else:
        n, comp = nr, np.arange(nr)
    # numbered in the order of each part's first run (the runs are in raster order): connected_components
    # numbers them so (each new part's number one above the largest so far); else renumbered
    seen = np.maximum.accumulate(comp)
    if comp[0] == 0 and not np.any(seen[1:] - seen[:-1] > 1):
        rank = np.arange(1, n + 1, dtype=np.int32)
    else:
        _, first_run = np.unique(comp, return_index=True)
        rank = np.empty(n, np.int32)
        rank[np.argsort(first_run, kind="stable")] = np.arange(1, n + 1, dtype=np.int32)
    out.ravel()[idx] = rank[comp][run]
    return out, int(n)
