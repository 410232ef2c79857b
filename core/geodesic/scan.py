"""Stage 3 of the geodesic filter: scan labelling along rows and columns."""
import functools

import numpy as np

from ..blocks import run_sharing
from ..common import as_cell_size, as_surface, report, transpose
from .dilation import BUMP_FRACTION
from .grey import rect_filter

#: Scan labelling passes run by the filter.
SCAN_PASSES = 2


#: Share of a run's height above its base line that one of its two edges (the rise or the
#: fall), beyond the terrain's rise over that cell, must carry: an object stands on a wall;
#: a ridge or an embankment whose flanks are steeper than the tolerated slope rises over
#: many cells, and at coarse cells its flanks exceed the per-cell tolerance
#: ``dh0 + tan(slope) cell`` (a slope of ``tan(slope) + dh0 / cell``, lower at every
#: coarser cell) while each edge carries only a fraction of its height (issue 12).
WALL_SHARE = 0.5

#: Longest scan run, in widths of the largest object: a row or a column crosses an object
#: of width ``S`` (one holding an ``S`` x ``S`` square, whatever its orientation) over up
#: to its diagonal, ``sqrt(2) S`` (a building rotated by 45 degrees). A run longer than ``S``
#: is an object only when both its rise and its fall are walls (each carries
#: :data:`WALL_SHARE` of its height): raised terrain wider than ``S`` beyond one steep bank
#: falls gently on its other side (issue 12).
OBLIQUE_REACH = float(np.sqrt(2.0))

#: Edges per chunk of the event pass (the chunk's differences stay in the cache).
_CHUNK = 1 << 16


def _events(a, axis, t_jump, has_nan):
    """The edges between neighbours along ``axis`` that rise or fall by more than
    ``t_jump`` or touch nodata (when ``has_nan``), profile by profile.

    The differences are taken chunk by chunk on the flat array (an edge ``e`` joins the cell
    ``e`` and the next one along the axis); columns' events are listed in column order
    through the transposed event array (a bool array: a quarter of the surface's bytes).

    Returns
    -------
    line, pos : ndarray of intp
        Profile (row or column) and position along it of the cell before each edge, sorted
        by profile then position.
    """
    H, W = a.shape
    af = a.ravel()
    step = 1 if axis == 1 else W
    n = af.size - step
    ev = np.empty(n, bool)
    buf = np.empty(min(n, _CHUNK), af.dtype)
    with np.errstate(invalid="ignore"):
        for s in range(0, n, _CHUNK):
            e = min(n, s + _CHUNK)
            d = buf[:e - s]
            np.subtract(af[s + step:e + step], af[s:e], out=d)
            np.abs(d, out=d)
            if has_nan:                           # nodata breaks runs
                np.less_equal(d, t_jump, out=ev[s:e])
                np.logical_not(ev[s:e], out=ev[s:e])
            else:
                np.greater(d, t_jump, out=ev[s:e])
    if axis == 1:
        ev[W - 1::W] = False                      # a row's last cell and the next row's first
        return np.divmod(np.flatnonzero(ev), W)
    return np.divmod(np.flatnonzero(transpose(ev.reshape(H - 1, W))), H - 1)


def climb_feet(at, lo, hi, n, rise_m, jump_m, reach):
    """The feet of the climb before a run's rise and of the descent after its fall.

    ``at(q)``: the heights at positions ``q`` of each run's profile (of ``n`` cells); ``lo``
    the cell before the rise, ``hi`` the cell after the fall. Each foot moves outward while
    the next step towards the run rises more than the terrain's rise over a cell
    (``rise_m``) and at most ``jump_m`` (a larger step is an edge of its own), by at most
    ``reach`` cells (per run): the cells before a wall stand on level ground, while a flank
    steeper than the tolerated slope climbs to the rise over several cells, and where the
    returns are sparser than the cells part of its height falls into one step (issue 12).

    Examples
    --------
    >>> p = np.array([0.0, 0.0, 0.8, 1.5, 3.5, 3.6, 3.5, 0.0, 0.0])
    >>> lo, hi = climb_feet(lambda q: p[q], np.array([3]), np.array([7]), 9, 0.4, 1.0,
    ...                     np.array([3]))
    >>> int(lo[0]), int(hi[0])
    (1, 7)
    """
    lo, hi = np.array(lo, copy=True), np.array(hi, copy=True)
    up, down = np.ones(lo.size, bool), np.ones(hi.size, bool)
    with np.errstate(invalid="ignore"):
        for k in range(int(np.max(reach, initial=0))):
            du, dd = at(lo) - at(lo - 1), at(hi) - at(hi + 1)
            up &= (lo > 0) & (du > rise_m) & (du <= jump_m) & (k < reach)
            down &= (hi < n - 1) & (dd > rise_m) & (dd <= jump_m) & (k < reach)
            if not (up.any() or down.any()):
                break
            lo -= up
            hi += down
    return lo, hi


def _scan_runs(a, axis, t_jump, height_m, max_cells, has_nan=True, t_terrain=0.0, one_wall_cells=None):
    """Scan labelling along ``axis`` of ``a`` (see :func:`scan_label`): flat indices of the
    labelled cells.

    Works on the events only (:func:`_events`): a rise followed directly by a fall on the
    same profile, at most ``max_cells`` apart, bounds a run, whose cells are then
    generated and tested against the run's base line, all vectorised. A run is kept when
    its rise or its fall exceeds the terrain's rise over one cell (``t_terrain``) by at
    least :data:`WALL_SHARE` of the run's greatest height above its base line; a run of
    more than ``one_wall_cells`` cells (None: no limit) when both do. A run whose other edge
    carries less than that share, over one cell or over two (one mixed cell), beyond the
    terrain's rise over two cells, stands on one wall only and must also stand higher above
    its base line than a terrain bump of its length may rise, ``height_m + t_terrain *
    (cells + 1) *`` :data:`~.dilation.BUMP_FRACTION` (the dilation's height test ``dh_k``
    for a window of the run's length).
    """
    none = np.zeros(0, np.intp)
    H, W = a.shape
    if a.shape[axis] < 3:
        return none
    line, pos = _events(a, axis, t_jump, has_nan)
    if line.size < 2:
        return none
    # flat index of cell p on profile l: l * fl + p * fp
    fl, fp = (W, 1) if axis == 1 else (1, W)
    af = a.ravel()
    at = line * fl + pos * fp
    d = af[at + fp] - af[at]                      # the events' height steps
    del at
    with np.errstate(invalid="ignore"):
        is_rise, is_fall = d > t_jump, d < -t_jump
    pair = ((line[:-1] == line[1:]) & is_rise[:-1] & is_fall[1:]
            & (pos[1:] - pos[:-1] <= max_cells))
    k = np.flatnonzero(pair)
    if k.size == 0:
        return none
    jl, jr, ln = pos[k], pos[k + 1], line[k]     # rise edge, fall edge, profile
    n_run = jr - jl                               # cells jl+1 .. jr
    first = ln * fl
    n_prof = a.shape[axis]

    def at(q):
        return af[first + np.clip(q, 0, n_prof - 1) * fp]
    # the base line joins the feet of the climb to the rise and of the descent after the fall
    reach = n_run if one_wall_cells is None else np.minimum(n_run, one_wall_cells)
    foot_l, foot_r = climb_feet(at, jl, jr + 1, n_prof, t_terrain, t_jump, reach)
    base_l = at(foot_l)
    slope = (at(foot_r) - base_l) / (foot_r - foot_l).astype(np.float32)
    start = np.cumsum(n_run) - n_run
    off = np.arange(int(n_run.sum()), dtype=n_run.dtype) - np.repeat(start, n_run) + 1
    flat = np.repeat(first + jl * fp, n_run) + off * fp
    base = np.repeat(base_l, n_run) + np.repeat(slope, n_run) * (off + np.repeat(jl - foot_l, n_run))
    above = af[flat] - base
    # the run's greatest height above its base line, and the larger of its two walls
    # beyond the terrain's rise over a cell (the rise and the fall carry the object)
    top = np.maximum.reduceat(np.where(np.isfinite(above), above, -np.inf), start)
    wall = np.maximum(d[k], -d[k + 1]) - t_terrain
    # both edges walls, each over one cell or over two (one mixed cell: a wall's foot or a
    # crown's edge, as in the border stage), beyond the terrain's rise over two cells
    rise2 = np.fmax(np.fmax(at(jl + 2) - at(jl), at(jl + 1) - at(jl - 1)), d[k])
    fall2 = np.fmax(np.fmax(at(jr) - at(jr + 2), at(jr - 1) - at(jr + 1)), -d[k + 1])
    both = np.minimum(rise2, fall2) - 2 * t_terrain >= WALL_SHARE * top
    del rise2, fall2
    if one_wall_cells is not None and one_wall_cells < max_cells:
        wall = np.where(n_run > one_wall_cells, np.minimum(d[k], -d[k + 1]) - t_terrain, wall)
    # a run on one wall only must stand above its base line by more than a terrain bump
    # as long as the run may rise (the dilation's height test dh_k with the run's length)
    bump = top > height_m + t_terrain * (n_run + 1) * BUMP_FRACTION
    on_walls = np.repeat((wall >= WALL_SHARE * top) & (both | bump), n_run)
    keep = (above > height_m) & on_walls
    return flat[keep]


#: Strips of rows (and of columns) :func:`scan_label` scans side by side when given threads.
SCAN_STRIPS = 2


def _strips(n):
    """``(start, stop)`` of :data:`SCAN_STRIPS` strips of ``n`` profiles (fewer when ``n`` is smaller)."""
    k = max(1, min(SCAN_STRIPS, n))
    edges = [n * j // k for j in range(k + 1)]
    return [(edges[j], edges[j + 1]) for j in range(k)]


def _scan_strip(a, axis, *args, part=None):
    """:func:`_scan_runs` of ``a`` along ``axis`` on the profiles ``part = (start, stop)`` only (rows for
    ``axis=1``, columns for ``axis=0``; None: all): flat indices of ``a``. Each profile is scanned on its own,
    so a strip's profiles give the cells they give in the whole array."""
    if part is None:
        return _scan_runs(a, axis, *args)
    lo, hi = part
    H, W = a.shape
    if axis == 1:
        return _scan_runs(a[lo:hi], 1, *args) + lo * W
    r, c = np.divmod(_scan_runs(np.ascontiguousarray(a[:, lo:hi]), 0, *args), hi - lo)
    return r * W + c + lo


def scan_label(z, cell_size, *, jump_m, height_m, max_length_m, terrain_slope_deg=0.0,
               passes=2, reference=None, oblique_length_m=None, axes=(1, 0), progress=None, pool=None):
    """Scan labelling: non-ground runs along rows and columns.

    Along each row and each column, the edge between neighbouring cells ``i, i+1`` is a
    *rise* when ``z[i+1] - z[i] > jump_m + tan(terrain_slope) * cell`` (the slope
    differential: steeper than the terrain may be by more than ``jump_m`` over one
    cell), a *fall* when ``z[i+1] - z[i] < -(...)``. A run of cells that opens with a
    rise, closes with the next event being a fall, spans at most ``max_length_m`` and
    stands more than ``height_m`` above the straight line from the foot of the climb to the
    rise to the foot of the descent after the fall (:func:`climb_feet`: the cells before a wall
    are level; a flank steeper than the terrain climbs to its largest step over several cells,
    issue 12) is labelled non-ground, when its rise or its fall carries at
    least :data:`WALL_SHARE` of the run's greatest height above that line beyond the
    terrain's rise over the cell (an object stands on a wall; a ridge or an embankment
    steeper than the tolerated slope rises over many cells: each of its edges carries a
    fraction of its height). A run on one wall only (its other edge carries less than that
    share, over one cell or, with one mixed cell, over two) must also stand above that line
    by more than a terrain bump of its length ``L``
    may rise, ``height_m + tan(terrain_slope) * L *`` :data:`~.dilation.BUMP_FRACTION` (the
    dilation's height test ``dh_k`` for a window of the run's length): where the returns are
    sparser than the cells, an embankment's flank rises in one step between two returns on
    one side and over several cells on the other (issue 12: the ramps of ISPRS samp71, 3.4 m
    over 29 cells, went as objects). A run longer than ``max_length_m`` and at most
    ``oblique_length_m`` (an object crossed obliquely: the filter passes
    :data:`OBLIQUE_REACH` ``* max_length_m``) is labelled when both its rise and its fall
    carry that share (an object stands on walls on both sides; raised terrain beyond a
    bank falls gently on its other side). Rows and columns are combined with OR.
    ``passes`` > 1 repeats the labelling on the surface with the labelled cells lowered
    to their base line, so stepped roofs (a rise, a rise, a fall, a fall) are peeled
    level by level. NaN cells break runs.

    Parameters
    ----------
    z : array_like, 2-D
        Surface (NaN = nodata).
    cell_size : float or (float, float)
        ``(dx, dy)`` in metres.
    jump_m : float
        Excess height step over one cell, beyond the terrain slope, that makes a rise/fall.
    height_m : float
        Minimal height of a labelled cell above the run's base line.
    max_length_m : float
        Longest run labelled when one of its edges is a wall (the largest object).
    oblique_length_m : float, optional
        Longest run labelled when both its edges are walls (None: ``max_length_m``).
    terrain_slope_deg : float
        Steepest terrain slope (degrees); its rise over one cell is tolerated.
    passes : int
        Number of labelling passes (>= 1).
    reference : array_like, optional
        A terrain approximation (the filter passes its lowest geodesic reconstruction):
        a labelled cell must also stand more than ``height_m`` above it, so terrain
        ridges, which the reconstruction follows, are never labelled.
    axes : tuple of int
        The profiles scanned: 1 rows, 0 columns (default both).
    progress : callable, optional
        ``progress(fraction)`` after each axis of each pass; it may raise
        :class:`~bare_earth.core.common.Cancelled`.
    pool : concurrent.futures.Executor, optional
        Threads that may scan some of the strips of rows and of columns (:data:`SCAN_STRIPS` each) while this
        one scans the others, when idle (:func:`~bare_earth.core.blocks.run_sharing`; all read the surface
        only); the same result.

    Returns
    -------
    ndarray of bool
        True where a cell is labelled non-ground.
    """
    z = as_surface(z)
    dx, dy = as_cell_size(cell_size)
    long_m = max_length_m if oblique_length_m is None else max(max_length_m, oblique_length_m)
    if jump_m < 0 or height_m < 0 or max_length_m <= 0:
        raise ValueError(f"scan_label needs jump_m >= 0, height_m >= 0, max_length_m > 0; "
                         f"got {jump_m}, {height_m}, {max_length_m}.")
    if not 0 <= terrain_slope_deg < 90:
        raise ValueError(f"terrain_slope_deg must be in [0, 90); got {terrain_slope_deg}.")
    if not axes or not set(axes) <= {0, 1}:
        raise ValueError(f"axes must hold 1 (rows) and/or 0 (columns); got {axes}.")
    if int(passes) < 1:
        raise ValueError(f"passes must be at least 1; got {passes}.")
    s = np.tan(np.radians(terrain_slope_deg))
    a = z.copy()
    labelled = np.zeros(z.shape, bool)
    allowed = np.ones(z.shape, bool)
    if reference is not None:
        reference = np.asarray(reference, dtype=np.float64)
        if reference.shape != z.shape:
            raise ValueError(f"reference must have the shape of z {z.shape}; got "
                             f"{reference.shape}. Pass a surface of the same grid.")
        with np.errstate(invalid="ignore"):
            allowed = (a - reference) > height_m
    tx, ty = jump_m + s * dx, jump_m + s * dy
    has_nan = bool(np.isnan(a).any())
    n = int(passes)
    for i in range(n):
        none = functools.partial(np.zeros, 0, np.intp)
        rows = functools.partial(_scan_strip, a, 1, tx, height_m, max(2, int(long_m / dx)), has_nan, s * dx,
                                 max(2, int(max_length_m / dx))) if 1 in axes else none
        cols = functools.partial(_scan_strip, a, 0, ty, height_m, max(2, int(long_m / dy)), has_nan, s * dy,
                                 max(2, int(max_length_m / dy))) if 0 in axes else none
        if pool is None:
            lr = rows()
            report(progress, (i + 0.35) / n)
            lc = cols()
            found = [lr, lc]
        else:
            # every profile is scanned alone: strips of rows (of columns) scan their rows (columns), all reading
            # ``a`` only, so an idle thread may take some (the same cells, listed in another order)
            found = run_sharing([functools.partial(f, part=k) for f in (rows, cols) if f is not none
                                 for k in _strips(a.shape[0 if f is rows else 1])], pool)
            report(progress, (i + 0.35) / n)
        report(progress, (i + 0.7) / n)
        new = np.concatenate(found)               # a cell may be in two: set twice below (the same value)
        del found
        new = new[~labelled.ravel()[new] & allowed.ravel()[new]]
        if new.size == 0:
            break
        labelled.ravel()[new] = True
        report(progress, (i + 0.8) / n)
        if i + 1 < n:
            # lower the labelled cells to the surrounding level (3 x 3 minimum, nodata
            # ignored) for the next pass
            low = rect_filter(np.where(np.isnan(a), np.inf, a) if has_nan else a, (3, 3), np.minimum, np.inf)
            af = a.ravel()
            af[new] = np.minimum(af[new], low.ravel()[new])
            del low
        report(progress, (i + 1.0) / n)
    return labelled
