"""Stage 2 of the geodesic filter: gradual geodesic dilation.

For structuring elements doubling in size, the grey opening of the surface (the marker)
is reconstructed by geodesic dilation under the surface; the residual regions the
reconstruction cannot reach are objects when they are high enough and their border is
abrupt (see the package docstring). Wide windows run on grids coarsened by a power of 2.
"""
import numpy as np
from scipy import ndimage

from ..common import report, sub_progress
from .grey import (
    S8,
    block_reduce,
    expand_blocks,
    fill_nodata,
    grey_opening,
    inner_cells,
    reconstruct_by_dilation,
    rect_filter,
    window_cells,
)

#: Steps whose window exceeds this many cells run on a coarser grid (factor a power of 2)
#: so that the coarse window stays about this wide.
COARSE_WINDOW = 4
#: Baseline of the wall test in metres (at least one cell).
WALL_BASE_M = 1.0
#: Markers within this fraction of dh0 under the surface are snapped to it.
NOISE_SNAP = 0.2
#: Geodesic reach of each step's reconstruction, in windows.
RECON_REACH = 1.0
#: A terrain bump as wide as the window may rise tan(slope) * window * this fraction.
BUMP_FRACTION = 0.5
#: A residual region wider or taller than this many ``max_object_size_m`` is never an
#: object (large raised terrain); it also bounds the method's reach (see the halo).
EXTENT_FACTOR = 2.0


def coarse_factor(size):
    """Power-of-2 coarsening factor for a window of ``size`` (rows, cols) cells."""
    f = 1
    while max(size) / (2 * f) > COARSE_WINDOW:
        f *= 2
    return f



def dilation_step(w, valid, wmask, jump, s, dx, dy, dh0, tan_s, edge_ratio, ext_limit, progress=None):
    """One gradual step of ``s`` metres: reconstruction ``R_k`` and the object cells.

    Windows wider than :data:`COARSE_WINDOW` cells run on a grid coarsened ``f`` times
    (``f`` a power of 2): the marker is the opening of the block minima, the mask the
    block maxima; the reconstruction ``Rc`` reaches the block maxima on terrain (so
    ``R_k = min(z, Rc) = z`` there) and only the surrounding terrain level under an
    object. The residual regions are analysed on that grid (residual of a block: its
    maximum minus ``Rc``; the abrupt-rim height grows by the terrain's rise over one
    coarse cell); a fine cell is an object when its block's region is one and its own
    residual exceeds ``dh0``. Coarse grids are aligned on the array origin, so blocks
    must start on multiples of ``f`` (the halo is a multiple of the largest ``f``).

    ``progress(fraction)`` is called between the sub-steps and during the
    reconstruction (it may raise :class:`~bare_earth.core.common.Cancelled`).

    Returns
    -------
    R : ndarray
        ``R_k`` at full resolution (NaN at nodata).
    obj : ndarray of bool
        Cells removed by this step.
    """
    H, W = w.shape
    size = window_cells(s, dx, dy)
    size = (min(size[0], 2 * H + 1), min(size[1], 2 * W + 1))   # no wider than the raster
    f = coarse_factor(size)
    if f == 1:
        zmin = zmax = w
        vc = valid
        size_c = size
    else:
        zmin = block_reduce(fill_nodata(w, valid, np.inf), f, np.minimum, np.inf)
        zmax = block_reduce(fill_nodata(w, valid, -np.inf), f, np.maximum, -np.inf)
        vc = np.isfinite(zmin)
        size_c = window_cells(s, dx * f, dy * f)
    report(progress, 0.1)
    marker = grey_opening(zmin, vc, size_c, sub_progress(progress, 0.1, 0.25))
    report(progress, 0.25)
    mask_c = wmask if f == 1 else np.where(vc, zmax, np.nan)
    if NOISE_SNAP > 0:
        # cells the opening lowered by less than the noise are terrain already: snap the
        # marker to the mask there (moves R by at most NOISE_SNAP * dh0, and saves the
        # reconstruction from chasing noise over the whole raster)
        with np.errstate(invalid="ignore"):
            snap = (mask_c - marker) < NOISE_SNAP * dh0
        np.copyto(marker, mask_c, where=snap)
    reach = max(size_c) * RECON_REACH
    Rc = reconstruct_by_dilation(marker, mask_c, max_iter=max(1, int(round(reach))),
                                 progress=sub_progress(progress, 0.25, 0.7))
    with np.errstate(invalid="ignore"):
        dc = zmax - Rc
        cand = vc & (dc > dh0)
    obj_c = np.zeros(cand.shape, bool)
    if cand.any():
        lab, n = ndimage.label(cand, S8)
        report(progress, 0.75)
        rim = cand & ~inner_cells(cand)
        # the raster's edge ends the data, it is not the region's border: no evidence
        rim[0, :] = rim[-1, :] = False
        rim[:, 0] = rim[:, -1] = False
        # a rim cell is abrupt when it holds a wall: a cell above a neighbour by more
        # than the terrain can rise over one (diagonal) cell, plus 2 dh0
        # and the residual there exceeds 2 dh0 plus the terrain's rise over the block
        abrupt = jump if f == 1 else block_reduce(jump, f, np.maximum, False)
        abrupt = abrupt & (dc >= 2.0 * dh0 + tan_s * f * np.hypot(dx, dy))
        dmax, rim_frac, ext_r, ext_c = _component_stats(lab, n, cand, dc, rim, abrupt)
        report(progress, 0.85)
        dh_k = dh0 + tan_s * s * BUMP_FRACTION
        keep = ((dmax > dh_k) & (rim_frac >= edge_ratio)
                & (ext_r * f * dy <= ext_limit) & (ext_c * f * dx <= ext_limit))
        keep[0] = False
        obj_c = keep[lab]
    report(progress, 0.9)
    if f == 1:
        return Rc, obj_c
    R = np.fmin(expand_blocks(Rc, f, w.shape), wmask)
    report(progress, 0.95)
    with np.errstate(invalid="ignore"):
        obj = expand_blocks(obj_c, f, w.shape) & (w - R > dh0)
    return R, obj


def _component_stats(lab, n, sel, values, rim, flag):
    """Per-label max of ``values``, fraction of ``rim`` cells where ``flag``, bbox extents.

    Returns arrays indexed by label (0 unused).
    """
    idx = np.flatnonzero(sel)
    lab_c = lab.ravel()[idx]
    v = values.ravel()[idx]
    order = np.argsort(lab_c, kind="stable")
    ls = lab_c[order]
    starts = np.r_[0, np.flatnonzero(np.diff(ls)) + 1]
    present = ls[starts]
    W = lab.shape[1]
    rows, cols = np.divmod(idx[order], W)
    vmax = np.full(n + 1, -np.inf)
    vmax[present] = np.maximum.reduceat(v[order], starts)
    ext_r = np.zeros(n + 1, np.int64)
    ext_c = np.zeros(n + 1, np.int64)
    ext_r[present] = np.maximum.reduceat(rows, starts) - np.minimum.reduceat(rows, starts) + 1
    # columns are not sorted within a label: min/max of columns via reduceat too
    ext_c[present] = np.maximum.reduceat(cols, starts) - np.minimum.reduceat(cols, starts) + 1
    r = rim.ravel()[idx].astype(np.float64)
    rim_n = np.bincount(lab_c, weights=r, minlength=n + 1)
    rim_s = np.bincount(lab_c, weights=r * flag.ravel()[idx], minlength=n + 1)
    rim_mean = np.divide(rim_s, rim_n, out=np.zeros(n + 1), where=rim_n > 0)
    return vmax, rim_mean, ext_r, ext_c




def wall_cells(w, valid, cell_size, dh0, tan_s):
    """Cells holding a wall: above a cell within :data:`WALL_BASE_M` (one cell at 1 m; two
    at 0.5 m, where matching smears walls) by more than ``2 dh0`` plus the terrain's rise
    over that distance."""
    dx, dy = cell_size
    wr = (max(1, int(round(WALL_BASE_M / dy))), max(1, int(round(WALL_BASE_M / dx))))
    low = rect_filter(fill_nodata(w, valid, np.inf), (2 * wr[0] + 1, 2 * wr[1] + 1), np.minimum, np.inf)
    with np.errstate(invalid="ignore"):
        return valid & (w - low > 2.0 * dh0 + tan_s * np.hypot(wr[0] * dy, wr[1] * dx))


def gradual_dilation(w, valid, cell_size, sizes, dh0, tan_s, edge_ratio, step, progress=None):
    """Stage 2: the dilation steps of ``sizes`` metres, their regions removed together.

    Each step works on the preprocessed surface ``w`` (:func:`dilation_step`), so the
    steps are independent; the union of their objects is removed. ``step`` (uint8) is
    written in place: ``k`` where step ``k`` (from 1) first removed a cell not already
    coded (outliers keep their code).

    Returns
    -------
    removed : ndarray of bool
        Cells removed by any step.
    cleaned : ndarray of float32
        ``w`` with removed cells lowered to the reconstruction.
    counts : list of int
        Cells newly coded per step.
    """
    dx, dy = cell_size
    cleaned = w.copy()
    removed = np.zeros(w.shape, bool)
    ext_limit = EXTENT_FACTOR * sizes[-1]
    jump = wall_cells(w, valid, cell_size, dh0, tan_s)
    report(progress, 0.02)
    counts = []
    for k, s in enumerate(sizes, start=1):
        part = sub_progress(progress, 0.02 + 0.98 * (k - 1) / len(sizes), 0.02 + 0.98 * k / len(sizes))
        R, obj = dilation_step(w, valid, w, jump, s, dx, dy, dh0, tan_s, edge_ratio, ext_limit, part)
        new = obj & ~removed
        removed |= obj
        new &= step == 0                          # outliers keep their own code
        step[new] = k
        report(part, 0.98)
        np.minimum(cleaned, R, out=cleaned, where=obj)
        counts.append(int(np.count_nonzero(new)))
        report(part, 1.0)
    return removed, cleaned, counts
