"""Gap filling: a smooth (harmonic, "soap film") surface across holes of a raster.

Every filter produces a mask; the pipeline then builds the DTM by removing the object and
low-outlier cells and filling them from the ground cells with :func:`fill_gaps`. The
``bareearth:filldtm`` algorithm exposes the same function.

Method
------
The filled surface solves the Laplace equation :math:`\\nabla^2 u = 0` on the cells to fill,
with the known cells as Dirichlet data and zero flux (Neumann) at the raster edges: a
membrane spanning the hole boundary. It is exact at known cells, continuous across hole
edges, and reproduces any plane (hence any linear ramp) exactly, because the discrete
5-point Laplacian annihilates linear functions.

It is solved by a one-way multigrid cascade (nested iteration, "cascadic multigrid",
Bornemann & Deuflhard 1996):

1. **Pyramid.** Level ``l + 1`` halves level ``l``. A coarse cell is *known* when one of
   the two diagonals of its 2 x 2 children is known; its value is the mean of the
   diagonal mid-points. The mid-point of a diagonal is the coarse cell centre, so the
   restriction is exact for planes and the coarse problem is a consistent discretisation
   of the fine one (a plain mean of the known children would be biased towards their
   centroid and tilt the membrane). Along straight hole edges a side of two known
   children is extrapolated linearly (also exact for planes). Isolated data (no exactly
   known coarse cell around) fall back to the mean of the known children, so that
   sparse points still reach the coarse levels.
2. **Coarsest level** (at most 4096 cells): direct sparse solve of the Laplace system.
3. **Each finer level:** cells that are not known start from the bilinear interpolation
   (linear extrapolation at the raster edge) of the coarser solution, then red-black
   sweeps of the Laplace equation relax them. Coarser levels converge their holes with
   successive over-relaxation (omega = 1.8; 8 sweeps on level 1, doubling per level, at
   most 64), which is cheap there. The finest level only smooths the prolongation error,
   which lives next to the known cells: 4 Gauss-Seidel sweeps on the cells within 7-9
   cells of a known cell (deeper cells keep the interpolated coarse solution).

The cascade is not iterated to convergence: against an exact sparse solve of the same
Laplace system the filled heights typically differ by about 0.5-1 % (rms) and 1.5-2.5 %
(max) of the height range across the hole, and planes are reproduced exactly (to float32
rounding).

Reference: F. A. Bornemann and P. Deuflhard (1996), The cascadic multigrid method for
elliptic problems, Numerische Mathematik 75(2):135-152.

All work on a level is vectorised over the unknown cells of that level (gathers of the four
neighbours of flat indices), so the cost is O(number of cells) with a small constant.
"""
import math
from functools import partial

import numpy as np

from .blocks import run_sharing
from .common import real_array, report, touching, transpose

#: Largest number of cells of the coarsest level (solved directly).
_TOP_CELLS = 4096
#: Red-black Gauss-Seidel sweeps on the finest level.
_SWEEPS_FINEST = 2
#: Over-relaxation sweeps on level 1, growth factor per coarser level, cap.
_SWEEPS_COARSE1 = 8
_SWEEPS_GROWTH = 2
_SWEEPS_MAX = 64
#: Over-relaxation factor on the coarser levels (the finest uses plain Gauss-Seidel).
_OMEGA_COARSE = 1.8
#: Level-0 relaxation band: coarse cells within this many coarse cells of known data
#: (fine cells within 7-9 cells of a known cell).
_BAND_COARSE = 4


#: Share of :func:`fill_gaps`'s progress bar given to building its pyramid (the rest to solving its levels).
_BUILD_SHARE = 0.3


def pyramid_shapes(shape):
    """The shapes of :func:`fill_gaps`'s levels (each the previous halved, rounded up, until at most
    :data:`_TOP_CELLS` cells): how many levels it builds, known before it builds them.

    Examples
    --------
    >>> pyramid_shapes((300, 200))
    [(300, 200), (150, 100), (75, 50)]
    """
    shapes = [(int(shape[0]), int(shape[1]))]
    while shapes[-1][0] * shapes[-1][1] > _TOP_CELLS:
        h, w = shapes[-1]
        shapes.append((h // 2 + h % 2, w // 2 + w % 2))
    return shapes


def fill_gaps(z, fill=None, *, progress=None):
    """Fill cells of a raster with a smooth harmonic (membrane) interpolation.

    Parameters
    ----------
    z : array_like, 2-D, any real numeric dtype
        Surface heights; NaN (or inf) = nodata, and so are the masked cells of a numpy masked
        array. Not modified.
    fill : array_like of bool, optional
        Cells to (re)compute, same shape as ``z``. Default: every non-finite cell.
        Cells that are finite and not in ``fill`` are the *known* cells, the only sources
        of the interpolation. Non-finite cells not in ``fill`` stay NaN in the result and
        are never used as sources (so the input's nodata stays nodata while the cells of
        removed objects are filled); the membrane passes through them.
    progress : callable, optional
        ``progress(fraction)`` called after each pyramid level is built (up to 0.3: the first
        level, a pass over the whole raster, was a third of the fill's time without a report) and
        after each level is solved; it may raise :class:`~bare_earth.core.common.Cancelled`.

    Returns
    -------
    ndarray of float32
        Same shape as ``z``: the known cells equal ``z`` (as float32) exactly, the cells
        of ``fill`` hold the interpolated surface (always finite), the other non-finite
        cells are NaN. It may be a view into a working array one cell larger on every
        side (not C-contiguous).

    Raises
    ------
    ValueError
        If ``z`` is not a non-empty 2-D real numeric array, if ``fill`` has another shape, or
        if there is no known cell to interpolate from.

    Notes
    -----
    The result approximates the solution of the discrete Laplace equation with the known
    cells as Dirichlet data and zero-flux raster edges; it is exact for planes (a hole in
    a plane or a linear ramp is filled by that plane). Holes touching the raster edge are
    continued with zero normal slope at the edge. Cost is O(N): a few full-array passes
    plus a few sweeps over the unknown cells; memory about 4 times a float32 copy of
    ``z`` (result included). A 4000 x 4000 raster with 20 % of its cells in holes of
    5-100 cells takes about 0.8-1 s of CPU (``python -m bare_earth.core.fill``).

    Examples
    --------
    >>> z = np.add.outer(np.arange(8.0), np.arange(8.0)).astype(np.float32)
    >>> z[2:5, 3:6] = np.nan
    >>> bool(np.allclose(fill_gaps(z), np.add.outer(np.arange(8.0), np.arange(8.0)), atol=1e-4))
    True
    """
    z = np.asarray(z) if not np.ma.isMaskedArray(z) else z
    if z.ndim != 2:
        raise ValueError(f"z must be a 2-D array (one band); got {z.ndim} dimensions. "
                         "Pass a single band of the surface.")
    if z.size == 0:
        raise ValueError(f"z is empty (shape {z.shape}); pass a raster with cells.")
    z = real_array(z)                       # masked cells of a masked array are nodata; no complex
    finite = np.isfinite(z)
    fill_given = fill is not None
    if fill_given:
        fill = np.asarray(fill)
        if fill.shape != z.shape:
            raise ValueError(f"fill must have the shape of z {z.shape}; got {fill.shape}. "
                             "Pass a boolean mask of the cells to fill, one per cell of z.")
        fill = fill.astype(bool, copy=False)
    unknown = ~finite if fill is None else fill | ~finite
    known = ~unknown
    if not known.any():
        raise ValueError("fill_gaps: no known cell to interpolate from (every cell is "
                         "nodata or to be filled); pass a surface with at least one finite "
                         "cell outside `fill`.")
    if fill is None:
        fill = unknown  # every non-finite cell
    if not fill.any():
        zf = np.array(z, dtype=np.float32)  # a copy: z is never modified
        zf[~finite] = np.nan
        report(progress, 1.0)
        return zf

    # Work relative to a reference height: keeps float32 sums precise for large heights.
    sample = np.asarray(z[::16, ::16], np.float32)[known[::16, ::16]]
    z0 = np.float32(np.median(sample) if sample.size else np.float32(z[known][0]))
    h, w = z.shape
    # Level 0 with a padding ring; its core becomes the result (no separate copy of z).
    work = np.zeros((h + 2, w + 2), dtype=np.float32)
    val0 = work[1:-1, 1:-1]
    if z.dtype == np.float32:
        np.subtract(z, z0, out=val0)
    else:
        val0[...] = z                                # as float32 first, as the result keeps it
        val0 -= z0
    np.copyto(val0, 0.0, where=unknown)              # 0 at the unknown cells (faster than
                                                     # a ufunc's where=)
    nodata_kept = (unknown & ~fill) if fill_given else None  # nodata outside `fill`
    keep_nan = nodata_kept is not None and bool(nodata_kept.any())

    # 1. Pyramid of (known, value) pairs, exact for planes.
    n_levels = len(pyramid_shapes(z.shape))
    built = _BUILD_SHARE / max(1, n_levels - 1)
    levels = [(known, val0)]
    while levels[-1][0].size > _TOP_CELLS:
        levels.append(_restrict(*levels[-1]))
        report(progress, built * (len(levels) - 1))

    def solved(done):
        return _BUILD_SHARE + (1.0 - _BUILD_SHARE) * done / n_levels

    # 2. Coarsest level: direct solve.
    u = _solve_direct(*levels[-1])
    done = 1
    report(progress, solved(done))

    # 3. Finer levels: bilinear prolongation + red-black relaxation on the unknown cells.
    for lev in range(n_levels - 2, -1, -1):
        kn, val = levels[lev]
        sweeps = _SWEEPS_FINEST if lev == 0 else min(_SWEEPS_COARSE1 * _SWEEPS_GROWTH ** (lev - 1), _SWEEPS_MAX)
        if lev == 0:
            # Level 0 smooths the prolongation error, which lives next to the known
            # cells: relax only the cells of `fill` within a few cells of a known cell;
            # the others (and nodata outside `fill`) keep their prolongated values.
            u = _relax_level(kn, val, u, sweeps, fill if keep_nan else None, 1.0,
                             work=work, near=_near_known(known, _BAND_COARSE))
        else:
            u = _relax_level(kn, val, u, sweeps, None, _OMEGA_COARSE)
        done += 1
        report(progress, solved(done))

    # Known cells keep their exact input values (as float32); the others get z0 + solution.
    out = work[1:-1, 1:-1]
    if not np.shares_memory(u, work):                # a single level: solved directly
        out[...] = u
    out += z0
    np.copyto(out, z, where=known, casting="unsafe")
    if keep_nan:
        np.copyto(out, np.float32(np.nan), where=nodata_kept)
    return out


#: The four lines of :func:`find_edge_spikes` (row step, column step of one direction; the other is
#: its opposite): the eight directions of its continuations.
EDGE_LINES = ((0, 1), (1, 0), (1, 1), (1, -1))
#: Standard deviations of a continuation's sampling error that :func:`find_edge_spikes`' ``sampling`` adds to its
#: tolerances: three, as the tolerances themselves are three of the continuation's error on ground
#: (:func:`.dtm_refine.continuation_tolerance`).
SAMPLING_SIGMAS = 3.0
#: Passes of :func:`find_edge_spikes`: each pass peels at most one cell off the sloping skirt of an
#: object (a crown's edge in a top-surface DSM spans a few cells); measured on the generalisation
#: matrix, a fourth pass and more found nothing the third had not.
EDGE_PASSES = 3


def edge_spikes_reach(passes=EDGE_PASSES):
    """Reach of :func:`find_edge_spikes` in cells: a pass reads two cells beyond the cell it tests,
    and a cell found by one pass changes the sources of the next."""
    return 2 * int(passes) + 1


def find_edge_spikes(z, fill, tolerance_m, *, line_tolerance_m=None, passes=EDGE_PASSES, spared=None,
                     pool=None, sampling=None, sampled=None):
    """Known cells at the edge of the cells to fill that stand above every straight continuation of their neighbours.

    A cell bordering the cells to fill (one of its eight neighbours is in ``fill``) is a *spike*
    when, along every one of the eight directions ``d`` whose two cells ``x + d`` and
    ``x + 2d`` are known, it stands more than ``tolerance_m`` above the continuation
    ``max(2 z(x + d) - z(x + 2d), z(x + d))`` of those two cells: their linear extrapolation (a
    second difference: zero on any plane, the ground's curvature and noise otherwise), and never
    below the nearest of them (a cell is not raised by a bump two cells away, which would tilt
    the extrapolation down). Ground bordering an object continues the ground
    around it; the foot of a wall, low vegetation at a crown's edge, or the mixed cell of a
    crown's skirt in a top-surface DSM stands above it from every side. Such cells carry the
    object's height into the surface interpolated under it, which rests on its boundary.

    With ``line_tolerance_m``, a cell is also a spike when along one of the four lines (rows, columns,
    diagonals) through it the ground continues to it from neither side: it stands more than
    ``line_tolerance_m`` above the continuation from one side, and the other side does not continue
    within that tolerance either (it stands above that continuation too, or that side has no two known
    cells: the object). Low vegetation along a crown's edge, a skirt cell among other skirt cells,
    is continued by its neighbours along the edge, never by the ground across it; a bank, a plane or a
    terrace's upper edge is continued from one side of every line. The side it stands above must read
    two different heights: the tolerance bounds the error of a continuation from two independent
    heights, while a repeated height (a cell filled from its neighbour's point on a sparse raster, as
    ISPRS 21 at 1 m, where ground 0.4-0.75 m above such a continuation was taken) is one height, the
    slope from it unknown. (Exactly flat ground reads repeated heights too: there only the test of
    every line applies.)

    Cells with no direction of two known cells (thin strips, lone cells) are never spikes. Each
    of ``passes`` passes treats the spikes found so far as cells to fill, so the next pass tests
    the cells they uncovered (a skirt sloping down over a few cells is peeled one cell per pass).

    Parameters
    ----------
    z : array_like, 2-D
        Heights (NaN nodata: never known, never a spike).
    fill : array_like of bool
        The cells to fill (objects), same shape.
    tolerance_m : float
        How far above every continuation a spike stands (metres, > 0): a height the ground's
        noise and curvature do not reach (``bareearth:dtm`` passes its decision threshold,
        3 x the noise of the ground).
    line_tolerance_m : float, optional
        How far above the continuation from one side of a line, not continued from the other, a spike
        stands (metres, > 0; ``bareearth:dtm``: three standard deviations of a continuation on ground,
        :func:`.dtm_refine.continuation_tolerance`, at least ``tolerance_m``); None: not looked for.
    passes : int
        Passes (>= 1); the result depends on cells within :func:`edge_spikes_reach` cells.
    spared : array_like of bool, optional
        Cells never taken as spikes (``bareearth:dtm``: the upper edges of steps in the ground,
        :func:`.dtm_refine.find_step_tops`); they stay sources of the continuations.
    pool : Executor, optional
        Threads that may take some of a pass's chunks of cells (:func:`~.blocks.run_sharing`); the
        same result without.
    sampling : (float, (float, float), float), optional
        ``(slope, (dx, dy), bound_m)``: allow for where each height lies in its cell on ground steeper than
        ``slope`` (rise per metre; the tolerances' own allowance). A raster cell holds a point anywhere in it (the
        lowest or highest of a cell); on ground rising ``g`` metres a cell that place alone scatters its height
        by ``g / sqrt(12)``, so a continuation ``2 z(x + d) - z(x + 2d)`` against ``z(x)`` by ``sqrt(6)`` times
        that. ``g`` is the steepest rise beside the cell beyond ``slope`` (over the eight pairs of source
        cells ``x + d``, ``x + 2d``, per cell of ``sqrt(dx dy)``), and both tolerances grow in quadrature by
        :data:`SAMPLING_SIGMAS` such standard deviations: ``sqrt(tol^2 + 4.5 g^2)``, the every-direction
        tolerance at most ``max(bound_m, tolerance_m)``. On a bank's face (a dike's at 2 m cells scatters by a
        metre along its contour) the face is no spike; on ground no steeper than ``slope`` nothing changes.
        None: no allowance.
    sampled : array_like of bool, optional
        The cells whose tolerances get the ``sampling`` allowance (``bareearth:dtm``: the banks its bank stage
        gave back, ground it found rising as earth stands); None: every cell.

    Returns
    -------
    ndarray of bool
        The spikes (known cells only).

    Examples
    --------
    >>> z = np.zeros((5, 7), np.float32)
    >>> z[:, 4:] = 3.0                     # an object on columns 4-6
    >>> z[2, 3] = 1.0                      # a raised cell at its edge
    >>> out = find_edge_spikes(z, z > 2.0, 0.5)
    >>> [tuple(map(int, p)) for p in np.argwhere(out)]
    [(2, 3)]
    """
    z = np.asarray(z, np.float32)
    fill = np.asarray(fill, bool)
    if z.ndim != 2 or fill.shape != z.shape:
        raise ValueError(f"z must be 2-D and fill of its shape; got z {z.shape}, fill {fill.shape}.")
    if not (np.isfinite(tolerance_m) and tolerance_m > 0):
        raise ValueError(f"tolerance_m must be a positive height in metres; got {tolerance_m}.")
    if line_tolerance_m is not None and not (np.isfinite(line_tolerance_m) and line_tolerance_m > 0):
        raise ValueError(f"line_tolerance_m must be a positive height in metres or None; got {line_tolerance_m}.")
    if int(passes) < 1:
        raise ValueError(f"passes must be at least 1; got {passes}.")
    h, w = z.shape
    pad = 2
    wp = w + 2 * pad
    # the known heights in a frame of two NaN cells: every neighbour read is inside it
    zp = np.full((h + 2 * pad, wp), np.nan, np.float32)
    core = zp[pad:-pad, pad:-pad]
    np.copyto(core, z)
    np.copyto(core, np.float32(np.nan), where=fill)
    found = np.zeros((h, w), bool)
    if spared is not None:
        spared_flat = _framed_flags(spared, "spared", z.shape, pad)
    tol = np.float32(tolerance_m)
    line_tol = None if line_tolerance_m is None else np.float32(line_tolerance_m)
    rise = None
    if sampling is not None:
        rise = _sampling_rises(sampling, wp)
        if sampled is not None:
            rise = rise + (_framed_flags(sampled, "sampled", z.shape, pad),)
        else:
            rise = rise + (None,)
    flat = zp.ravel()
    # the known cells with a cell to fill among their neighbours, as indices into the frame
    edge = touching(fill)
    edge &= np.isfinite(core)
    if spared is not None:
        edge &= ~spared
    cand = np.flatnonzero(edge)
    del edge
    r, c = np.divmod(cand, w)
    idx = (r + pad) * wp + (c + pad)
    del cand, r, c
    around = np.array([dr * wp + dc for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc])
    for _ in range(int(passes)):
        if idx.size == 0:
            break
        new = np.empty(idx.size, bool)
        chunks = [slice(i, min(idx.size, i + EDGE_CHUNK)) for i in range(0, idx.size, EDGE_CHUNK)]
        run_sharing([partial(_edge_spikes_at, flat, idx, s, wp, tol, line_tol, new, rise) for s in chunks], pool)
        if not new.any():
            break
        spikes = idx[new]
        rs, cs = np.divmod(spikes, wp)
        found[rs - pad, cs - pad] = True
        flat[spikes] = np.nan                        # no longer a source of the next pass
        # the next pass's cells: the known cells beside these spikes (the frame's cells around them that
        # hold a height; a spike no longer does, the frame's border never), as touching() of the spikes
        # gives them, read at a few cells instead of over the raster
        idx = np.unique((spikes[:, None] + around).ravel())
        keep = np.isfinite(flat.take(idx))
        if spared is not None:
            keep &= ~spared_flat.take(idx)
        idx = idx[keep]
    return found


#: Candidates per chunk of :func:`find_edge_spikes` (a chunk's temporaries stay in the cache; the
#: chunks of a pass may run in parallel).
EDGE_CHUNK = 1 << 16


def _framed_flags(flags, name, shape, pad):
    """``flags`` (a boolean raster of ``shape``, the argument ``name``) in a frame of ``pad`` False cells
    each side, raveled; ValueError naming it when its shape is not ``shape``."""
    flags = np.asarray(flags, bool)
    if flags.shape != tuple(shape):
        raise ValueError(f"{name} must have z's shape {tuple(shape)}; got {flags.shape}.")
    framed = np.zeros((shape[0] + 2 * pad, shape[1] + 2 * pad), bool)
    framed[pad:-pad, pad:-pad] = flags
    return framed.ravel()


def _sampling_rises(sampling, wp):
    """The pairs of :func:`find_edge_spikes`' ``sampling``: ``(bound_m, [(offset, allowed_m, cells_per_step)])``,
    for each of the eight directions its offset in a frame ``wp`` cells a row, the rise between its two source
    cells the tolerances already allow (the slope times the step's length) and the cell's size over the step's
    length (a rise a step to a rise a cell); ``bound_m`` bounds the every-direction tolerance."""
    if len(sampling) != 3:
        raise ValueError(f"sampling must be (slope, (dx, dy), bound_m); got {sampling!r}.")
    slope, bound = float(sampling[0]), float(sampling[2])
    dx, dy = (float(v) for v in sampling[1])
    if not (np.isfinite(bound) and bound > 0) or not (dx > 0 and dy > 0):
        raise ValueError(f"sampling's cell size and bound must be positive; got {sampling!r}.")
    slope = slope if np.isfinite(slope) and slope > 0 else 0.0
    cell = math.sqrt(dx * dy)
    pairs = []
    for di, dj in EDGE_LINES:
        length = math.hypot(di * dy, dj * dx)
        for sgn in (1, -1):
            pairs.append((sgn * (di * wp + dj), np.float32(slope * length), np.float32(cell / length)))
    return np.float32(bound), pairs


def _edge_spikes_at(flat, idx, sl, wp, tol, line_tol, new, rise=None):
    """:func:`find_edge_spikes`' test of the cells ``idx[sl]`` (indices into the frame ``flat``, ``wp``
    cells a row) into ``new[sl]`` (``rise``: :func:`_sampling_rises`, or None)."""
    idx = idx[sl]
    zc = flat.take(idx)
    out = np.zeros(idx.size, bool)
    every = np.ones(idx.size, bool)
    seen = np.zeros(idx.size, bool)
    if rise is not None:
        # the ground's rise a cell beside the cell beyond the rise the tolerances allow, the steepest of its eight
        # pairs of source cells: where in its cell each height lies adds rise^2 / 12 to its variance, six of those
        # to a continuation's (2 z1 - z2 against z), SAMPLING_SIGMAS of that standard deviation to its tolerance
        bound, pairs, where = rise
        g = np.zeros(idx.size, np.float32)
        for off, allowed, per_cell in pairs:
            d = np.abs(flat.take(idx + off) - flat.take(idx + 2 * off))
            d -= allowed
            d *= per_cell
            np.fmax(g, d, out=g)                                   # NaN (a source unknown) is ignored
        if where is not None:
            g *= where.take(idx)                                   # only at the cells sampled
        g *= g
        g *= np.float32(SAMPLING_SIGMAS ** 2 * 6.0 / 12.0)
        tol = np.minimum(np.sqrt(tol * tol + g), max(bound, tol))
        line_tol = None if line_tol is None else np.sqrt(line_tol * line_tol + g)
        del g
    # a spike stands above the continuation from one side of a line, and the other side does not
    # continue the ground to it (it stands above that continuation too, or the side is unknown)
    for di, dj in EDGE_LINES:
        res, slope_known = [], []
        for sgn in (1, -1):
            off = sgn * (di * wp + dj)
            z1 = flat.take(idx + off)
            z2 = flat.take(idx + 2 * off)
            cont = 2 * z1 - z2                                     # NaN where a source is unknown
            np.maximum(cont, z1, out=cont)                         # and never below the neighbour
            res.append(zc - cont)
            slope_known.append(z1 != z2)                           # two heights, not one repeated
        a, b = res
        seen |= np.isfinite(a) | np.isfinite(b)
        np.logical_and(every, ~(a <= tol) & ~(b <= tol), out=every)     # NaN (no continuation) keeps it
        if line_tol is not None:
            above = ((a > line_tol) & slope_known[0]) | ((b > line_tol) & slope_known[1])
            out |= ~(a <= line_tol) & ~(b <= line_tol) & above
    out |= every & seen
    new[sl] = out


def _near_known(known, reach):
    """Coarse (2 x 2) cells within ``reach`` coarse cells of a cell with a known child.

    A fine cell whose coarse cell is in the result is at most ``2 * reach + 1`` fine
    cells (chessboard) from a known cell, and every fine cell within ``2 * reach - 1``
    of a known cell is in it.
    """
    h, w = known.shape
    if h % 2 or w % 2:
        known = np.pad(known, ((0, h % 2), (0, w % 2)))
    near = known[0::2, 0::2] | known[0::2, 1::2]
    near |= known[1::2, 0::2]
    near |= known[1::2, 1::2]
    for axis in (0, 1):  # separable dilation by `reach`
        src = near.copy()
        n = near.shape[axis]
        for k in range(1, min(reach, n - 1) + 1):
            a = [slice(None)] * 2
            b = [slice(None)] * 2
            a[axis], b[axis] = slice(k, None), slice(None, n - k)
            near[tuple(a)] |= src[tuple(b)]
            near[tuple(b)] |= src[tuple(a)]
    return near


def _restrict(known, val):
    """One pyramid level up: plane-exact 2 x 2 restriction of the known cells.

    A coarse cell is known when

    1. one of the diagonals of its 2 x 2 children is known: the mean of the diagonal
       mid-points (exact for planes); else
    2. two children along one side and the two fine cells beyond that side are known:
       linear extrapolation to the centre (exact for planes; straight hole edges); else
    3. it has a known child but no coarse cell of its 3 x 3 neighbourhood is known by
       rules 1-2 (sparse data, isolated points): the mean of its known children, biased
       by at most half a coarse cell but keeping the information on the coarse levels.

    Returns ``(known, value)`` of the coarse level, ``value`` 0 where not known.
    """
    h, w = known.shape
    if h % 2 or w % 2:
        known = np.pad(known, ((0, h % 2), (0, w % 2)))
        val = np.pad(val, ((0, h % 2), (0, w % 2)))
    h2, w2 = h // 2 + h % 2, w // 2 + w % 2
    ck = np.empty((h2, w2), bool)
    s = np.empty((h2, w2), np.float32)
    code = np.empty((h2, w2), np.uint8)
    t = np.empty((min(h2, _BAND), w2), np.float32)
    ps = []
    # The dense part in bands of rows: the four strided children of a band are read while
    # they are in the cache.
    for i0 in range(0, h2, _BAND):
        i1 = min(h2, i0 + _BAND)
        kk, vv = known[2 * i0:2 * i1], val[2 * i0:2 * i1]
        ka, kb, kc, kd = kk[0::2, 0::2], kk[0::2, 1::2], kk[1::2, 0::2], kk[1::2, 1::2]
        va, vb, vc, vd = vv[0::2, 0::2], vv[0::2, 1::2], vv[1::2, 0::2], vv[1::2, 1::2]
        # 1. Diagonals a-d and b-c; their mid-points are the coarse cell centre.
        d1 = ka & kd
        d2 = kb & kc
        cb = ck[i0:i1]
        np.bitwise_or(d1, d2, out=cb)
        sb = s[i0:i1]
        tb = t[:i1 - i0]
        np.add(va, vd, out=sb)
        sb *= d1
        np.add(vb, vc, out=tb)
        tb *= d2
        sb += tb
        sb *= np.float32(0.25)                         # mean of the diagonals' mid-points:
        d1 ^= d2                                       # x 1/4 for two, x 1/2 for one (exact)
        np.multiply(sb, np.float32(2.0), out=sb, where=d1)
        # Cells with known children but no known diagonal (e.g. along a straight hole
        # edge, or isolated points); vectorised over these few cells only. `code` holds
        # the four children as bits: a = 1, b = 2, c = 4, d = 8.
        cd = code[i0:i1]
        np.copyto(cd, ka)
        cd |= kb.view(np.uint8) << 1
        cd |= kc.view(np.uint8) << 2
        cd |= kd.view(np.uint8) << 3
        part = cd != 0
        part &= ~cb
        q = np.flatnonzero(part)
        if q.size:
            ps.append(q + i0 * w2)
    del t
    p = np.concatenate(ps) if ps else np.empty(0, np.intp)
    if p.size == 0:
        return ck, s
    i, j = np.divmod(p, w2)
    cflat = code.ravel()
    # 2. Linear extrapolation across a known side of two children from the two fine cells
    # beyond it (the neighbour's adjacent children): exact for planes.
    acc = np.zeros(p.size, dtype=np.float32)
    cnt = np.zeros(p.size, dtype=np.float32)
    own = cflat.take(p)
    r0, c0 = 2 * i, 2 * j                      # fine row / column of child a
    # (inner bits, outer bits of the neighbour, neighbour offset (di, dj), inner cells as
    # fine offsets from child a, outer cells as fine offsets from child a)
    sides = ((5, 10, 0, -1, ((0, 0), (1, 0)), ((0, -1), (1, -1))),     # left
             (10, 5, 0, 1, ((0, 1), (1, 1)), ((0, 2), (1, 2))),        # right
             (3, 12, -1, 0, ((0, 0), (0, 1)), ((-1, 0), (-1, 1))),     # top
             (12, 3, 1, 0, ((1, 0), (1, 1)), ((2, 0), (2, 1))))        # bottom
    for inner, outer, di, dj, ins, outs in sides:
        ok = (own & inner) == inner
        if di:
            ok &= (i > 0) if di < 0 else (i < h2 - 1)
        else:
            ok &= (j > 0) if dj < 0 else (j < w2 - 1)
        q = np.flatnonzero(ok)
        if q.size == 0:
            continue
        nb = cflat.take(np.clip(p[q] + (di * w2 + dj), 0, cflat.size - 1))
        q = q[(nb & outer) == outer]
        if q.size == 0:
            continue
        rq, cq = r0[q], c0[q]
        est = val[rq + ins[0][0], cq + ins[0][1]] + val[rq + ins[1][0], cq + ins[1][1]]
        est *= np.float32(0.75)
        est -= np.float32(0.25) * (val[rq + outs[0][0], cq + outs[0][1]]
                                   + val[rq + outs[1][0], cq + outs[1][1]])
        acc[q] += est
        cnt[q] += 1.0
    ok = cnt > 0
    s.ravel()[p[ok]] = acc[ok] / cnt[ok]
    # 3. Isolated partial cells: no coarse cell of the 3 x 3 neighbourhood is known by
    # rules 1-2 (checked before adding rule 2's cells).
    rest = np.flatnonzero(~ok)
    lonely = np.ones(rest.size, bool)
    ckf = ck.ravel()
    ir, jr = i[rest], j[rest]
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            ii = np.clip(ir + di, 0, h2 - 1)
            jj = np.clip(jr + dj, 0, w2 - 1)
            lonely &= ~ckf.take(ii * w2 + jj)
    ckf[p[ok]] = True
    rest = rest[lonely]
    if rest.size:
        rq, cq = r0[rest], c0[rest]
        n = np.zeros(rest.size, np.float32)
        tot = np.zeros(rest.size, np.float32)
        for dr in (0, 1):
            for dc in (0, 1):
                n += known[rq + dr, cq + dc]
                tot += val[rq + dr, cq + dc]
        s.ravel()[p[rest]] = tot / n
        ckf[p[rest]] = True
    return ck, s


#: Coarse rows per band of the restriction's dense part.
_BAND = 64


def _solve_direct(known, val):
    """Solve the Laplace system on a small level exactly (sparse LU)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import spsolve

    h, w = known.shape
    u = val.astype(np.float64)
    free = ~known
    n = int(free.sum())
    if n == 0:
        return u.astype(np.float32)
    ids = np.full((h, w), -1, dtype=np.int64)
    ids[free] = np.arange(n)
    diag = np.zeros(n)
    rhs = np.zeros(n)
    rows, cols = [], []
    # (destination slice, neighbour slice) for the four neighbours.
    pairs = [((slice(1, None), slice(None)), (slice(None, -1), slice(None))),
             ((slice(None, -1), slice(None)), (slice(1, None), slice(None))),
             ((slice(None), slice(1, None)), (slice(None), slice(None, -1))),
             ((slice(None), slice(None, -1)), (slice(None), slice(1, None)))]
    for dst, src in pairs:
        fd = free[dst]
        i = ids[dst][fd]
        j = ids[src][fd]
        np.add.at(diag, i, 1.0)
        nb_free = j >= 0
        rows.append(i[nb_free])
        cols.append(j[nb_free])
        np.add.at(rhs, i[~nb_free], u[src][fd][~nb_free])
    rows = np.concatenate(rows + [np.arange(n)])
    cols = np.concatenate(cols + [np.arange(n)])
    data = np.concatenate([-np.ones(rows.size - n), np.maximum(diag, 1.0)])
    a = coo_matrix((data, (rows, cols)), shape=(n, n)).tocsc()
    u[free] = spsolve(a, rhs)
    return u.astype(np.float32)


def _pad_linear(c):
    """Pad a 2-D array by one cell on each side by linear extrapolation."""
    h, w = c.shape
    p = np.empty((h + 2, w + 2), dtype=np.float32)
    p[1:-1, 1:-1] = c
    if h >= 2:
        p[0, 1:-1] = 2 * c[0] - c[1]
        p[-1, 1:-1] = 2 * c[-1] - c[-2]
    else:
        p[0, 1:-1] = p[-1, 1:-1] = c[0]
    if w >= 2:
        p[:, 0] = 2 * p[:, 1] - p[:, 2]
        p[:, -1] = 2 * p[:, -2] - p[:, -3]
    else:
        p[:, 0] = p[:, -1] = p[:, 1]
    return p


def _prolong(cp, r, c):
    """Bilinear interpolation of the coarser level at fine cells ``(r, c)``.

    ``cp`` is the coarser solution padded by :func:`_pad_linear`. Fine cell ``r`` lies at
    coarse coordinate ``r / 2 - 0.25`` (cell centres), so its upper coarse neighbour (in
    the padded array) is ``(r + 1) // 2`` with weight 0.25 for even ``r`` and 0.75 for
    odd ``r``.
    """
    wp = cp.shape[1]
    flat = cp.ravel()
    fy = _LOWER_WEIGHT.take(r & 1)                 # weight of the lower row
    fx = _LOWER_WEIGHT.take(c & 1)                 # weight of the right column
    base = ((r + 1) >> 1) * wp
    base += (c + 1) >> 1
    top = flat.take(base)
    top += fx * (flat.take(base + 1) - top)
    base += wp
    bot = flat.take(base)
    bot += fx * (flat.take(base + 1) - bot)
    top += fy * (bot - top)
    return top


_LOWER_WEIGHT = np.array([0.75, 0.25], dtype=np.float32)
#: Unknown cells handled per chunk while setting a level up (bounds the temporaries).
_CHUNK = 1 << 19


def _relax_level(known, val, coarse, sweeps, relax=None, omega=1.0, work=None, near=None):
    """Initialise the unknown cells of a level from ``coarse`` and relax them.

    Parameters
    ----------
    known, val : ndarray
        Known cells of this level and their values (0 elsewhere).
    coarse : ndarray of float32
        Solution of the next coarser level.
    sweeps : int
        Red-black sweeps.
    relax : ndarray of bool, optional
        Cells that may be relaxed (default: every unknown cell). Unknown cells outside
        ``relax`` keep the prolongated coarse values and act as Dirichlet data.
    omega : float
        Over-relaxation factor (1: Gauss-Seidel).
    work : ndarray of float32, optional
        ``(rows + 2, cols + 2)`` working array whose core already holds ``val`` and whose
        ring is 0 (saves a copy); allocated when None.
    near : ndarray of bool, optional
        Coarse mask from :func:`_near_known`: relax only cells whose coarse cell is in it.

    Returns
    -------
    ndarray of float32
        The level's solution (a view into the padded working array).
    """
    h, w = known.shape
    wp = w + 2
    if work is None:
        work = np.zeros((h + 2, w + 2), dtype=np.float32)
        work[1:-1, 1:-1] = val
    uf = work.ravel()
    cp = _pad_linear(coarse)
    # Set up in blocks of rows (bounded temporaries): prolongate every unknown cell, and
    # collect the flat (padded) indices of the cells to relax, split into the two colours
    # of the red-black ordering and into interior / raster-edge cells. Cells of one colour
    # never touch each other, so the groups of a colour may be updated one after another.
    rows_per_block = max(1, _CHUNK // max(w, 1))
    parts = {key: [] for key in ((0, False), (1, False), (0, True), (1, True))}
    relax_flat = None if relax is None else np.ascontiguousarray(relax).ravel()
    near_flat, w2 = (None, 0) if near is None else (near.ravel(), near.shape[1])
    for b0 in range(0, h, rows_per_block):
        b1 = min(h, b0 + rows_per_block)
        idx = np.flatnonzero(~known[b0:b1])
        if idx.size == 0:
            continue
        idx += b0 * w                       # flat index in the level
        r, c = np.divmod(idx, w)
        pidx = r * wp
        pidx += c + (wp + 1)               # flat index in the padded array
        uf[pidx] = _prolong(cp, r, c)
        if sweeps <= 0:
            continue
        sel = None
        if relax_flat is not None:
            sel = relax_flat.take(idx)
        if near_flat is not None:
            nsel = near_flat.take((r >> 1) * w2 + (c >> 1))
            sel = nsel if sel is None else sel & nsel
        if sel is not None:
            r, c, pidx = r[sel], c[sel], pidx[sel]
        del idx, sel
        # raster-edge cells (few) get their own groups; 1 <= c <= w - 2 in one compare
        edge = (c - 1).astype(np.uint64, copy=False) >= np.uint64(max(w - 2, 0))
        if b0 == 0 or b1 == h:
            edge |= (r == 0) | (r == h - 1)
        colour = ((r + c) & 1).astype(bool)
        any_edge = bool(edge.any())
        for col in (0, 1):
            is_col = colour if col else ~colour
            if any_edge:
                parts[(col, False)].append(pidx[is_col & ~edge])
                parts[(col, True)].append(pidx[is_col & edge])
            else:
                parts[(col, False)].append(pidx[is_col])
    core = work[1:-1, 1:-1]
    groups = []
    for (col, is_edge), chunks in parts.items():
        idx = np.concatenate(chunks) if chunks else np.empty(0, np.intp)
        if idx.size == 0:
            continue
        parts[(col, is_edge)] = None
        inv = np.float32(0.25)
        if is_edge:  # Neumann edges: the padding ring stays 0, divide by the neighbours
            rr, cc = np.divmod(idx, wp)
            cnt = 4 - (rr == 1).astype(np.int8) - (rr == h) - (cc == 1) - (cc == w)
            inv = (1.0 / np.maximum(cnt, 1)).astype(np.float32)
        groups.append((col, idx, inv))
    if not groups:
        return core
    groups.sort(key=lambda g: g[0])  # all of colour 0, then all of colour 1
    nmax = min(max(g[1].size for g in groups), _SWEEP_CHUNK)
    s_buf = np.empty(nmax, dtype=np.float32)
    t_buf = np.empty(nmax, dtype=np.float32)
    # The four neighbours (and the cell) gathered through views of the padded array shifted
    # so that one index array serves all five: idx - wp - 1 (>= 0, every cell to relax lies
    # inside the padding ring); no index arithmetic per sweep.
    left, up = uf[wp:], uf[1:]
    right, down, own = uf[wp + 2:], uf[2 * wp + 1:], uf[wp + 1:]
    for _col, idx, _inv in groups:
        idx -= wp + 1
    # Cells of one colour never touch each other: a group is relaxed in chunks whose
    # buffers stay in the cache, with the same result.
    for _ in range(sweeps):
        for _col, idx_all, inv_all in groups:
            for c0 in range(0, idx_all.size, _SWEEP_CHUNK):
                idx = idx_all[c0:c0 + _SWEEP_CHUNK]
                inv = inv_all if np.ndim(inv_all) == 0 else inv_all[c0:c0 + _SWEEP_CHUNK]
                m = idx.size
                s, t = s_buf[:m], t_buf[:m]
                np.take(left, idx, out=s, mode="clip")
                np.take(right, idx, out=t, mode="clip")
                s += t
                np.take(up, idx, out=t, mode="clip")
                s += t
                np.take(down, idx, out=t, mode="clip")
                s += t
                s *= inv
                if omega != 1.0:                 # successive over-relaxation
                    np.take(own, idx, out=t, mode="clip")
                    s -= t
                    s *= omega
                    s += t
                own[idx] = s
    return core


#: Cells relaxed per chunk of a sweep (their buffers stay in the cache).
_SWEEP_CHUNK = 1 << 14


def _benchmark(n=4000, hole_fraction=0.2, seed=0):
    """Print the speed of :func:`fill_gaps` on an ``n`` x ``n`` float32 surface with about
    ``hole_fraction`` of the cells in rectangular holes of 5-100 cells
    (``python -m bare_earth.core.fill [n]``)."""
    import time
    import tracemalloc

    rng = np.random.default_rng(seed)
    x = np.arange(n, dtype=np.float32)
    z = (300 + 20 * np.sin(x / 300)[None, :] + 15 * np.cos(x / 170)[:, None]
         + 0.01 * x[None, :]).astype(np.float32)
    holes = np.zeros((n, n), bool)
    k = int(hole_fraction * n * n / 2000)
    for a, b, hh, ww in zip(rng.integers(0, n, k), rng.integers(0, n, k),
                            rng.integers(5, 101, k), rng.integers(5, 101, k)):
        holes[a:a + hh, b:b + ww] = True
    z[holes] = np.nan
    print(f"fill_gaps on {n} x {n} float32, {holes.mean() * 100:.1f} % of the cells in "
          "holes of 5-100 cells")
    for rep in range(3):
        t, c = time.perf_counter(), time.process_time()
        fill_gaps(z)
        dt, dc = time.perf_counter() - t, time.process_time() - c
        print(f"  run {rep}: wall {dt:.3f} s ({n * n / dt / 1e6:.1f} Mcells/s), "
              f"cpu {dc:.3f} s ({n * n / dc / 1e6:.1f} Mcells/s)")
    tracemalloc.start()
    fill_gaps(z)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    print(f"  peak memory {peak / 2 ** 20:.0f} MB = {peak / z.nbytes:.1f} x the input "
          "(result included)")


if __name__ == "__main__":
    import sys
    _benchmark(int(sys.argv[1]) if len(sys.argv) > 1 else 4000)


#: The widest run of empty cells (metres, along a row or a column, bounded by data at both ends) that
#: :func:`fill_empty` fills before a filter runs. Bounded so that the fill stays local (its reach joins
#: every window's halo: blocks equal one pass) and a lake or a river wider than a building block stays
#: nodata to the filters. Measured on the ISPRS samples with their empty cells left empty, mean total
#: error of dtm / geodesic with runs of 16, 32, 64 m and unbounded: 1 m 3.72 / 4.41, 3.48 / 4.54,
#: 3.35 / 4.31, 3.46 / 4.54; 2 m 4.83 / 5.15, 4.49 / 5.10, 4.39 / 4.90, 4.43 / 4.95 (samp41's gap of
#: about 40 m needs more than 32 m; the whole raster's nearest fill gives 3.29 / 3.81 and 4.28 / 4.80).
EMPTY_RUN_M = 64.0
#: ... and at most this many cells: on finer grids (a drone DSM of 2.6 cm cells would make 64 m 2300
#: cells) the fill's reach, added to every window's halo, stays within 193 cells (64 m at 0.5 m).
EMPTY_RUN_MAX_CELLS = 128
#: The eight neighbours a cell of :func:`fill_empty` takes its value from, first found first: the four
#: sides, then the corners (a fixed order, so any window of a raster fills a cell the same way).
_NEIGHBOURS = ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (-1, 1), (1, -1), (1, 1))


def empty_run_cells(cell_size):
    """:data:`EMPTY_RUN_M` in cells of ``cell_size`` (metres, a number or ``(dx, dy)``; the larger side),
    at most :data:`EMPTY_RUN_MAX_CELLS`."""
    return max(1, min(EMPTY_RUN_MAX_CELLS, int(EMPTY_RUN_M / float(np.max(cell_size)) + 1e-9)))


def fill_empty_reach(width):
    """Cells beyond which the data do not change :func:`fill_empty`'s value at a cell, for runs of at
    most ``width`` cells: a filled cell takes its value through at most ``(width + 1) // 2`` filled
    neighbours, and whether each of them is filled depends on the data ``width`` cells along its row
    and its column. A window read this much beyond the cells it must get right fills them exactly as
    the whole raster would."""
    return int(width) + (int(width) + 1) // 2 + 1


def enclosed_empty(valid, width):
    """Cells without data that lie in a run of at most ``width`` empty cells bounded by data at both
    ends, along their row or their column.

    The raster's outer nodata border (a run reaching the edge) and the inside of holes wider than
    ``width`` both ways (a lake) are not enclosed.
    """
    valid = np.ascontiguousarray(valid, dtype=bool)
    return _enclosed_down(valid, width) | transpose(_enclosed_down(transpose(valid), width))


def _enclosed_down(valid, width):
    """:func:`enclosed_empty` down the columns only: two passes over the rows (each a vector across the
    columns; numpy's accumulate along axis 0 walks the columns one by one)."""
    n, m = valid.shape
    last = np.empty((n, m), np.int32)                    # the row of the last data cell above (or at)
    prev = np.full(m, -1, np.int32)
    for i in range(n):
        np.copyto(prev, np.int32(i), where=valid[i])
        last[i] = prev
    out = np.empty((n, m), bool)
    nxt = np.full(m, n, np.int32)                        # the row of the next data cell below (or at)
    run = np.empty(m, np.int32)
    for i in range(n - 1, -1, -1):
        np.copyto(nxt, np.int32(i), where=valid[i])
        np.subtract(nxt, last[i], out=run)               # the run's length + 1 (ends included)
        o = out[i]
        np.less_equal(run, np.int32(int(width) + 1), out=o)
        o &= last[i] >= 0
        o &= nxt < n
    out &= ~valid
    return out


def fill_empty(z, width):
    """The empty cells of a surface enclosed by data filled from their nearest data, before a filter runs.

    A lidar DSM gridded as the lowest point per cell (PDAL ``writers.gdal output_type=min``, LAStools,
    QGIS) leaves cells without a point empty: between the points where the cell is smaller than their
    spacing, and on water, dark roofs and in occlusions. SMRF (Pingel et al. 2013) fills these cells of
    its minimum surface before filtering; the filters here see the same: each empty cell in a run of at
    most ``width`` cells bounded by data along its row or its column (:func:`enclosed_empty`) takes the
    value of the nearest data cell (chessboard distance: the front grows one cell a round from the data,
    each cell taking its first filled neighbour in the order of ``_NEIGHBOURS``; the first round on
    shifted slices of the whole raster, the next ones on the neighbours of the cells still empty), as
    the benchmarks' nearest fill of the empty cells. The raster's outer nodata border and holes wider
    than ``width`` stay NaN. The result at a cell depends only on the data within :func:`fill_empty_reach` cells.

    Measured on the ISPRS samples gridded at 1 m and 2 m, lowest point per cell, with the empty cells
    left empty (32-85 % of the cells at 1 m): the nearest data's value keeps every filter's total error
    within 0.1-0.5 points of the samples filled by the protocol (dtm 1 m 3.29 either way), the harmonic
    fill of :func:`fill_gaps` costs 0.3-2.7 points at 1 m (dtm 4.29, geodesic 6.55), the lowest
    neighbour 0.7-2.2 (dtm 4.02 at 1 m, 6.52 at 2 m: every filled cell a low blunder). The cells filled
    stay nodata in every output (the pipeline keeps the input's nodata).

    On image-matching DSMs (Pleiades, ``benchmarks/empty_cells.py``) the fill raises the share of
    objects (pair / triplet: geodesic 0.96 / 0.92 % unfilled, 5.57 / 7.60 % filled; dtm 4.52 / 2.25,
    5.46 / 3.87): their scattered empty cells had cut the geodesic scan's runs (an edge touching nodata
    ends a run), so filled they run on along rows and columns of noisy terrain (the straight streaks
    of its mask; filling only runs of at most 4 cells with the mean of their ends already gives
    2.94 / 1.89 %), and nearest values on slopes and across occlusions make steps. Alternatives
    measured against this fill (mean total error of the generalisation matrix's nine ``holes/`` rows,
    dtm / geodesic 3.21 / 4.35; opengeos with 25 % of its cells and 60 small holes emptied, DTM RMSE
    dtm 0.60 m), all worse on the data with truth: linear interpolation between the ends of the row
    and column runs (weights 1 / span^2; 3.75 / 5.12, 0.68 m), the same with the nearest end where the
    ends differ by more than 45 degrees (3.83 / 4.82; with the lower end there, ground being the lower
    side of an occlusion, Pleiades objects rose above this fill's: dtm 5.69 / 5.42, geodesic 5.84 /
    11.31 %), linear only where the run continues both ends' slopes within 1 m (3.25 / 4.43,
    0.59 m; Pleiades dtm 5.21 / 3.68), the mean or the lowest of a cell's filled neighbours instead of
    the first (mirror-symmetric: 3.54 / 4.69 and 3.55 / 4.16; Pleiades dtm 4.82 / 3.14 and 8.61 /
    6.47 %), runs enclosed both ways only (3.82 / 6.32), runs not reaching the raster's edge (3.61 /
    5.71: samp41's gap). Linear runs halve the Pleiades rise (geodesic 3.91 / 4.02 %, dtm 4.73 / 2.62).

    Parameters
    ----------
    z : ndarray of float32, 2-D
        The surface, NaN = nodata. Not modified.
    width : int
        The widest run of empty cells filled (:func:`empty_run_cells`).

    Returns
    -------
    filled : ndarray of float32
        ``z`` itself when no cell is filled, else a copy with the enclosed empty cells filled.
    count : int
        The cells filled.
    """
    valid = np.isfinite(z)
    if valid.all():                                       # nothing empty (most DSMs): no pass over the rows
        return z, 0
    todo = enclosed_empty(valid, width)
    count = int(np.count_nonzero(todo))
    if not count:
        return z, 0
    h, w = z.shape
    # padded by a cell of nothing known, so the neighbours of any cell are flat offsets
    val = np.zeros((h + 2, w + 2), np.float32)
    val[1:-1, 1:-1] = np.where(valid, z, np.float32(0))
    known = np.zeros((h + 2, w + 2), bool)
    known[1:-1, 1:-1] = valid
    pending = np.zeros((h + 2, w + 2), bool)
    pending[1:-1, 1:-1] = todo
    del valid, todo
    val, known, pending = val.ravel(), known.ravel(), pending.ravel()
    offsets = [dr * (w + 2) + dc for dr, dc in _NEIGHBOURS]
    # the first round on the whole raster (most empty cells of a lowest-point grid touch data):
    # each neighbour a contiguous shifted slice of the padded arrays
    a, b = w + 3, (h + 1) * (w + 2) - 1                   # the inner cells' flat range
    got = np.zeros(b - a, bool)
    take = np.zeros(b - a, np.float32)
    for off in offsets:
        k = known[a + off:b + off] & pending[a:b]
        k &= ~got
        np.copyto(take, val[a + off:b + off], where=k)
        got |= k
    np.copyto(val[a:b], take, where=got)
    known[a:b] |= got
    pending[a:b] &= ~got
    del got, take
    cells = np.flatnonzero(pending)                      # the rest: their neighbours gathered
    del pending
    while cells.size:
        got = np.zeros(cells.size, bool)
        take = np.empty(cells.size, np.float32)
        for off in offsets:                              # the first known neighbour in that order
            nb = cells + off
            k = known[nb] & ~got
            take[k] = val[nb[k]]
            got |= k
        if not got.any():                                # cannot happen: every run has data at its ends
            break
        done = cells[got]
        val[done] = take[got]
        known[done] = True
        cells = cells[~got]
    out = np.array(z, dtype=np.float32, copy=True)
    filled = val.reshape(h + 2, w + 2)[1:-1, 1:-1]
    np.copyto(out, filled, where=known.reshape(h + 2, w + 2)[1:-1, 1:-1] & ~np.isfinite(z))
    return out, count
