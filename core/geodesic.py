"""Gradual geodesic dilation with scan labelling (``bareearth:geodesic``, 2018).

The paper (in Persian; only its abstract is available to us) separates ground from
non-ground in a DSM with three steps after a noise-removal preprocessing, and was
evaluated on the ISPRS filter test (reported: Type I 4.61 %, Type II 6.97 %, total
3.17 % on five test areas). The details below are our design, documented here and in the
algorithm's help.

1. **Preprocessing** (step code :data:`STEP_OUTLIER`). A cell cluster narrower than
   ``outlier_width_m`` that lies more than ``outlier_threshold_m`` below the grey closing
   (a pit) is a *low outlier* (mask class 2: image-matching blunders, laser multipath);
   one that stands more than ``outlier_threshold_m`` above the grey opening is a *high
   outlier* (mask class 1: birds, clouds, blunders). Clusters larger than
   :data:`OUTLIER_MAX_CELLS` cells are left to the later steps (ditches and walls are
   long, blunders are not). Outliers are replaced by the closing/opening value.
2. **Gradual geodesic dilation** (step codes 1..K). For structuring-element sizes
   ``s_k = min_window_m * 2**k`` (k = 0 .. K-1, the last one ``max_object_size_m``):

   * the marker ``f_k`` is the grey opening of the surface ``z`` by a flat square of
     side ``s_k`` (it lies under ``z`` and has lost every object narrower than ``s_k``);
   * ``R_k`` is the morphological reconstruction by dilation of ``f_k`` under ``z``
     (:func:`reconstruct_by_dilation`, geodesic reach limited to one window): it
     grows the marker back wherever the terrain itself connects to it, so terrain edges
     and ridges that the opening cut are restored, while objects, which the terrain
     cannot reach from below, stay cut;
   * the residual ``d_k = z - R_k`` (what the reconstruction cannot reach) is split into
     8-connected regions where ``d_k > dh0`` (``height_threshold_m``). The *height
     heterogeneity* of each region decides: a region is an object when its highest
     residual exceeds ``dh_k = dh0 + tan(terrain_slope) * s_k *`` :data:`BUMP_FRACTION`
     (what a terrain bump of that width may rise) **and** its border is abrupt: at least
     the fraction ``edge_ratio`` of its border cells hold a *wall*, a cell higher than
     a cell within :data:`WALL_BASE_M` (one cell at 1 m: its 8 neighbours) by more than
     ``2 dh0 + tan(terrain_slope) * diagonal`` (more than the terrain can rise over that
     distance). A building (or tree) jumps at its
     border; a hill of the same footprint with gentle sides does not, and is kept. A
     region whose bounding box exceeds :data:`EXTENT_FACTOR` ``* max_object_size_m`` is
     never an object (it bounds the method's reach).
   * Windows wider than 2 :data:`COARSE_WINDOW` cells run on a grid coarsened by a power
     of 2 ``f`` (marker: opening of the block minima; mask: block maxima; a border block
     is abrupt when it holds a wall and its residual exceeds ``2 dh0`` plus the terrain's
     rise over the block; a fine cell is removed when its block's region is an object
     and its own residual exceeds ``dh0``). This keeps every step's cost near one pass
     over the raster whatever the window; the coarse grids are aligned on the raster's
     origin (see :func:`geodesic_halo`). Before the reconstruction, marker cells less
     than :data:`NOISE_SNAP` ``* dh0`` under the surface are snapped to it (they are
     terrain within the noise; this moves ``R_k`` by at most that much and spares the
     reconstruction from chasing noise over the whole raster).

   The regions found at every step are removed together (the union); the step code is
   the first (smallest) step that removed the cell, so small objects carry small codes
   and large buildings large ones. Each step works on the preprocessed surface, so the
   steps are independent and the reach of the method is that of its largest step.
3. **Scan labelling** (step code :data:`STEP_SCAN`), :func:`scan_label`. Along every row
   and every column of the cleaned surface (removed cells replaced by ``R_k``), the
   height difference between neighbouring cells is labelled a *rise* when it exceeds the
   terrain's own rise over one cell by more than ``dh0`` (``dz > dh0 + tan(slope) *
   cell``), a *fall* symmetrically. A run of cells that opens with a rise, closes with a
   fall, is shorter than ``max_object_size_m`` and stands more than ``dh0`` above the
   straight line joining the cells before the rise and after the fall is non-ground.
   Two passes catch stepped roofs. This removes what the dilation left (objects on
   steep slopes, thin walls, leftovers of merged regions).
4. **Object borders** (step code :data:`STEP_EDGE`). A kept cell that touches a removed
   cell and stands above one of its 8 neighbours by more than ``dh0 + tan(terrain_slope)
   * cell_diagonal`` is the foot of a wall or the edge of a crown (a cell mixing object
   and ground): it is removed too, so the interpolated DTM is not pulled up along the
   objects' borders.
5. Gap filling into the DTM is done by the pipeline (``fill.fill_gaps``).

Speed: openings are separable running min/max filters (log2(size) vectorised passes);
the reconstruction is iterated 3x3 geodesic dilation that runs on the bounding box of the
cells that changed and switches to a vectorised frontier (only the neighbours of cells
that changed) once few cells change, so it stops early where nothing moves; wide steps run
on coarse grids; scan labelling works on the list of rise/fall events, not on every cell.
Measured (``benchmarks/geodesic_paper.py``, 16.8 Mcells synthetic city, shared 2-core
machine): about 3 Mcells/s.
"""
import time

import numpy as np
from scipy import ndimage

from .estimate import noise_ground_level
from .codes import LOW, OBJECT
from .common import FilterResult, as_cell_size, as_surface, finish_mask, report
from .methods import Method, Param

#: ``extras["step"]`` code of a cell removed by scan labelling.
STEP_SCAN = 250
#: ``extras["step"]`` code of a preprocessing outlier (high: mask 1, low: mask 2).
STEP_OUTLIER = 251
#: ``extras["step"]`` code of a border cell of a removed region (wall or crown edge).
STEP_EDGE = 252
#: ``extras["step"]`` code of nodata cells.
STEP_NODATA = 255
#: A residual region wider or taller than this many ``max_object_size_m`` is never an
#: object (large raised terrain); it also bounds the method's reach (see the halo).
EXTENT_FACTOR = 2.0
#: Largest cluster (cells) the preprocessing treats as an isolated outlier.
OUTLIER_MAX_CELLS = 16

_DEFAULTS = dict(min_window_m=2.0, max_object_size_m=64.0, height_threshold_m=None,
                 terrain_slope_deg=None, edge_ratio=0.55, outlier_threshold_m=None,
                 outlier_width_m=2.0, scan_labelling=True)


# --------------------------------------------------------------------------- morphology
def _max3(a, connectivity):
    """3x3 (8-connected) or cross (4-connected) maximum of a padded array's interior."""
    c = a[1:-1, 1:-1]
    if connectivity == 8:
        r = np.maximum(np.maximum(a[:, :-2], a[:, 1:-1]), a[:, 2:])
        return np.maximum(np.maximum(r[:-2], r[1:-1]), r[2:])
    out = np.maximum(c, a[:-2, 1:-1])
    np.maximum(out, a[2:, 1:-1], out=out)
    np.maximum(out, a[1:-1, :-2], out=out)
    np.maximum(out, a[1:-1, 2:], out=out)
    return out


def reconstruct_by_dilation(marker, mask, *, connectivity=8, max_iter=None):
    """Morphological reconstruction by dilation of ``marker`` under ``mask``.

    ``R = sup_n delta^(n)(marker)`` where ``delta(f) = min(dilate_3x3(f), mask)`` is the
    elementary geodesic dilation (Vincent 1993). The iteration runs on the bounding box
    of the cells that changed, and on the 8 (4) neighbours of the changed cells only once
    they are few (a vectorised frontier), so it stops early where nothing changes.

    Parameters
    ----------
    marker, mask : array_like, 2-D, same shape
        Marker and mask surfaces (any numeric dtype). ``marker`` is clipped to ``mask``
        first. NaN in ``mask`` is nodata: it blocks propagation and stays NaN. NaN in
        ``marker`` seeds nothing.
    connectivity : {8, 4}
        Neighbourhood of the elementary dilation.
    max_iter : int, optional
        Stop after this many elementary geodesic dilations (the geodesic reach in
        cells); ``None`` runs to stability (the true reconstruction).

    Returns
    -------
    ndarray
        The reconstruction, float (float32 for float32/int16/uint8 inputs).

    Raises
    ------
    ValueError
        Shapes differ, arrays are not 2-D, bad connectivity or max_iter.
    """
    marker = np.asarray(marker)
    mask = np.asarray(mask)
    if marker.ndim != 2 or mask.shape != marker.shape:
        raise ValueError(f"marker and mask must be 2-D arrays of the same shape; got "
                         f"{marker.shape} and {mask.shape}. Pass two bands of one grid.")
    if connectivity not in (4, 8):
        raise ValueError(f"connectivity must be 4 or 8; got {connectivity!r}.")
    if max_iter is not None and (int(max_iter) != max_iter or max_iter < 0):
        raise ValueError(f"max_iter must be a non-negative integer or None; got {max_iter!r}.")
    dtype = np.result_type(marker.dtype, mask.dtype, np.float32)
    if not np.issubdtype(dtype, np.floating):
        dtype = np.float64
    H, W = mask.shape
    W2 = W + 2
    P = np.empty((H + 2, W2), dtype)              # padded with -inf: nothing outside
    R = np.empty((H + 2, W2), dtype)
    for a in (P, R):
        a[0], a[-1], a[:, 0], a[:, -1] = -np.inf, -np.inf, -np.inf, -np.inf
    Pi, Ri = P[1:-1, 1:-1], R[1:-1, 1:-1]
    np.copyto(Pi, mask, casting="unsafe")
    nodata = np.isnan(Pi)
    has_nodata = bool(nodata.any())
    if has_nodata:
        Pi[nodata] = -np.inf
    np.minimum(marker, Pi, out=Ri, casting="unsafe")
    nan_seed = np.isnan(Ri)
    if nan_seed.any():
        Ri[nan_seed] = -np.inf
    Rf, Pf = R.ravel(), P.ravel()
    if connectivity == 8:
        offs = np.array([-W2 - 1, -W2, -W2 + 1, -1, 1, W2 - 1, W2, W2 + 1], np.intp)
    else:
        offs = np.array([-W2, -1, 1, W2], np.intp)
    box = (1, H, 1, W)          # inclusive interior bounds (padded coordinates)
    frontier = None
    stamp = None
    bufs = None
    it = 0
    while max_iter is None or it < max_iter:
        it += 1
        if frontier is None:                      # dense pass on the bounding box
            r0, r1, c0, c1 = box
            h, w = r1 - r0 + 1, c1 - c0 + 1
            sub = R[r0 - 1:r1 + 2, c0 - 1:c1 + 2]
            if bufs is None:                      # reused buffers: no allocation per pass
                bufs = (np.empty((h + 2, w), dtype), np.empty((h, w), dtype),
                        np.empty((h, w), bool))
            new, ch = bufs[1][:h, :w], bufs[2][:h, :w]
            if connectivity == 8:
                rb = bufs[0][:h + 2, :w]
                np.maximum(sub[:, :-2], sub[:, 1:-1], out=rb)
                np.maximum(rb, sub[:, 2:], out=rb)
                np.maximum(rb[:-2], rb[1:-1], out=new)
                np.maximum(new, rb[2:], out=new)
            else:
                new[...] = _max3(sub, connectivity)
            np.minimum(new, P[r0:r1 + 1, c0:c1 + 1], out=new)
            old = R[r0:r1 + 1, c0:c1 + 1]
            np.greater(new, old, out=ch)          # new >= old everywhere
            n_ch = np.count_nonzero(ch)
            if n_ch == 0:
                break
            old[...] = new
            if n_ch * FRONTIER_RATIO < (r1 - r0 + 1) * (c1 - c0 + 1):
                rr, cc = np.nonzero(ch)
                frontier = (rr + r0) * W2 + (cc + c0)
            elif n_ch * 2 < h * w:                # shrink the box to the changes
                rows = np.flatnonzero(ch.any(axis=1))
                cols = np.flatnonzero(ch.any(axis=0))
                box = (max(rows[0] + r0 - 1, 1), min(rows[-1] + r0 + 1, H),
                       max(cols[0] + c0 - 1, 1), min(cols[-1] + c0 + 1, W))
        else:                                     # sparse pass on the frontier
            nb = (frontier[:, None] + offs).ravel()
            if stamp is None:
                stamp = np.empty(Rf.size, np.int64 if Rf.size >= 2**31 else np.int32)
            seq = np.arange(nb.size, dtype=stamp.dtype)
            stamp[nb] = seq                       # dedupe without sorting: one writer
            cand = nb[stamp[nb] == seq]           # per cell survives
            cand = cand[Rf[cand] < Pf[cand]]
            if cand.size == 0:
                break
            nb = Rf[cand[:, None] + offs].max(axis=1)
            new = np.minimum(nb, Pf[cand])
            ch = new > Rf[cand]
            frontier = cand[ch]
            if frontier.size == 0:
                break
            Rf[frontier] = new[ch]
            if frontier.size * 32 > H * W:
                rr, cc = np.divmod(frontier, W2)
                box = (max(rr.min() - 1, 1), min(rr.max() + 1, H),
                       max(cc.min() - 1, 1), min(cc.max() + 1, W))
                frontier = None
    if has_nodata:
        Ri[nodata] = np.nan
    return Ri


def _axis_slice(a, axis, start, stop):
    return a[start:stop] if axis == 0 else a[:, start:stop]


def _running(a, size, axis, op, pad):
    """Running ``op`` (np.minimum / np.maximum) over a centred window of odd ``size``
    along ``axis``; cells outside the array count as ``pad``.

    Windows of 2, 4, 8 ... cells by doubling, then two overlapping power-of-2 windows
    cover the odd window: ``log2(size) + 1`` vectorised passes of contiguous slices.
    """
    n = a.shape[axis]
    size = min(int(size), 2 * n + 1)              # wider windows see the same cells
    r = size // 2
    if r == 0:
        return a.copy()
    if r == 1 and n >= 2:                         # 3 cells: two shifted passes
        out = np.empty_like(a)
        lo, hi = _axis_slice(out, axis, 0, n - 1), _axis_slice(out, axis, 1, n)
        op(_axis_slice(a, axis, 0, n - 1), _axis_slice(a, axis, 1, n), out=lo)
        _axis_slice(out, axis, n - 1, n)[...] = _axis_slice(a, axis, n - 1, n)
        op(hi, _axis_slice(a, axis, 0, n - 1), out=hi)
        if not ((op is np.minimum and pad == np.inf) or (op is np.maximum and pad == -np.inf)
                or (a.dtype == bool and pad == (op is np.minimum))):
            first, last = _axis_slice(out, axis, 0, 1), _axis_slice(out, axis, n - 1, n)
            op(first, pad, out=first)
            op(last, pad, out=last)
        return out
    shape = list(a.shape)
    shape[axis] += 2 * r
    m = np.full(shape, pad, a.dtype)
    if axis == 0:
        m[r:r + n] = a
    else:
        m[:, r:r + n] = a
    length = 1
    while 2 * length <= size:
        cur = m.shape[axis]
        m = op(_axis_slice(m, axis, 0, cur - length), _axis_slice(m, axis, length, cur))
        length *= 2
    return op(_axis_slice(m, axis, 0, n), _axis_slice(m, axis, size - length, size - length + n))


def _filter2d(a, size, op, pad):
    """Separable running ``op`` over a ``size = (rows, cols)`` rectangle."""
    return _running(_running(a, size[1], 1, op, pad), size[0], 0, op, pad)


def _fill(z, valid, value):
    """``z`` with ``value`` at nodata; ``z`` itself when every cell is valid."""
    return z if valid is None or valid.all() else np.where(valid, z, value)


def _opening(z, valid, size):
    """Grey opening by a flat rectangle ``size`` (rows, cols); nodata ignored.

    Returns ``-inf`` where the whole window is nodata.
    """
    e = _filter2d(_fill(z, valid, np.inf), size, np.minimum, np.inf)
    if valid is not None and not valid.all():
        e[np.isposinf(e)] = -np.inf
    return _filter2d(e, size, np.maximum, -np.inf)


def _closing(z, valid, size):
    """Grey closing by a flat rectangle ``size`` (rows, cols); nodata ignored."""
    d = _filter2d(_fill(z, valid, -np.inf), size, np.maximum, -np.inf)
    if valid is not None and not valid.all():
        d[np.isneginf(d)] = np.inf
    return _filter2d(d, size, np.minimum, np.inf)


def _inner(cand):
    """Cells of ``cand`` whose 8 neighbours are all in ``cand`` (outside = not)."""
    return _filter2d(cand, (3, 3), np.minimum, False)


def _window(size_m, dx, dy):
    """Odd window (rows, cols) of about ``size_m`` metres, at least 3 x 3."""
    return (2 * max(1, int(round(size_m / (2 * dy)))) + 1,
            2 * max(1, int(round(size_m / (2 * dx)))) + 1)


_S8 = np.ones((3, 3), bool)

#: Steps whose window exceeds this many cells run on a coarser grid (factor a power of 2)
#: so that the coarse window stays about this wide.
COARSE_WINDOW = 4
#: Scan labelling passes run by the filter.
SCAN_PASSES = 2
#: Baseline of the wall test in metres (at least one cell).
WALL_BASE_M = 1.0
#: The reconstruction leaves its dense passes once fewer than 1/this of the box change.
FRONTIER_RATIO = 256
#: Markers within this fraction of dh0 under the surface are snapped to it.
NOISE_SNAP = 0.2
#: Geodesic reach of each step's reconstruction, in windows.
RECON_REACH = 1.0
#: Default terrain slope: this percentile of the slope of the heavily opened DSM ...
SLOPE_PERCENTILE = 90
#: ... clipped to these degrees (a tolerance, not the steepest slope: on the ISPRS
#: samples above ~25 degrees walls on hillsides pass as terrain).
SLOPE_CLIP_DEG = (12.0, 22.0)
#: Default dh0 = max(0.5 m, NOISE_K x robust noise of the DSM).
NOISE_K = 3.0
#: A terrain bump as wide as the window may rise tan(slope) * window * this fraction.
BUMP_FRACTION = 0.5


def _coarse_factor(size):
    """Power-of-2 coarsening factor for a window of ``size`` (rows, cols) cells."""
    f = 1
    while max(size) / (2 * f) > COARSE_WINDOW:
        f *= 2
    return f


def _block_reduce(a, f, op, fill):
    """``op`` (np.minimum / np.maximum) over ``f`` x ``f`` blocks (``f`` a power of 2),
    edges padded with ``fill``; pairwise halving of strided slices."""
    H, W = a.shape
    Hc, Wc = -(-H // f), -(-W // f)
    if Hc * f != H or Wc * f != W:
        p = np.full((Hc * f, Wc * f), fill, a.dtype)
        p[:H, :W] = a
        a = p
    while a.shape[0] > Hc:
        a = op(a[0::2], a[1::2])
    while a.shape[1] > Wc:
        a = op(a[:, 0::2], a[:, 1::2])
    return a


def _expand(c, f, shape):
    """Nearest expansion of a coarse grid by ``f``, cropped to ``shape``."""
    if f == 1:
        return c
    Hc, Wc = c.shape
    out = np.empty((Hc, f, Wc, f), c.dtype)
    out[...] = c[:, None, :, None]
    return out.reshape(Hc * f, Wc * f)[:shape[0], :shape[1]]


def _step(w, valid, wmask, jump, s, dx, dy, dh0, tan_s, edge_ratio, ext_limit):
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

    Returns
    -------
    R : ndarray
        ``R_k`` at full resolution (NaN at nodata).
    obj : ndarray of bool
        Cells removed by this step.
    """
    H, W = w.shape
    size = _window(s, dx, dy)
    size = (min(size[0], 2 * H + 1), min(size[1], 2 * W + 1))   # no wider than the raster
    f = _coarse_factor(size)
    if f == 1:
        zmin = zmax = w
        vc = valid
        size_c = size
    else:
        zmin = _block_reduce(_fill(w, valid, np.inf), f, np.minimum, np.inf)
        zmax = _block_reduce(_fill(w, valid, -np.inf), f, np.maximum, -np.inf)
        vc = np.isfinite(zmin)
        size_c = _window(s, dx * f, dy * f)
    marker = _opening(zmin, vc, size_c)
    mask_c = wmask if f == 1 else np.where(vc, zmax, np.nan)
    if NOISE_SNAP > 0:
        # cells the opening lowered by less than the noise are terrain already: snap the
        # marker to the mask there (moves R by at most NOISE_SNAP * dh0, and saves the
        # reconstruction from chasing noise over the whole raster)
        with np.errstate(invalid="ignore"):
            snap = (mask_c - marker) < NOISE_SNAP * dh0
        np.copyto(marker, mask_c, where=snap)
    reach = max(size_c) * RECON_REACH
    Rc = reconstruct_by_dilation(marker, mask_c, max_iter=max(1, int(round(reach))))
    with np.errstate(invalid="ignore"):
        dc = zmax - Rc
        cand = vc & (dc > dh0)
    obj_c = np.zeros(cand.shape, bool)
    if cand.any():
        lab, n = ndimage.label(cand, _S8)
        rim = cand & ~_inner(cand)
        # the raster's edge ends the data, it is not the region's border: no evidence
        rim[0, :] = rim[-1, :] = False
        rim[:, 0] = rim[:, -1] = False
        # a rim cell is abrupt when it holds a wall: a cell above a neighbour by more
        # than the terrain can rise over one (diagonal) cell, plus 2 dh0
        # and the residual there exceeds 2 dh0 plus the terrain's rise over the block
        abrupt = jump if f == 1 else _block_reduce(jump, f, np.maximum, False)
        abrupt = abrupt & (dc >= 2.0 * dh0 + tan_s * f * np.hypot(dx, dy))
        dmax, rim_frac, ext_r, ext_c = _component_stats(lab, n, cand, dc, rim, abrupt)
        dh_k = dh0 + tan_s * s * BUMP_FRACTION
        keep = ((dmax > dh_k) & (rim_frac >= edge_ratio)
                & (ext_r * f * dy <= ext_limit) & (ext_c * f * dx <= ext_limit))
        keep[0] = False
        obj_c = keep[lab]
    if f == 1:
        return Rc, obj_c
    R = np.fmin(_expand(Rc, f, w.shape), wmask)
    with np.errstate(invalid="ignore"):
        obj = _expand(obj_c, f, w.shape) & (w - R > dh0)
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


# -------------------------------------------------------------------------- scan labels


def _scan_axis(a, axis, t_jump, height_m, max_cells, has_nan=True):
    """Scan labelling along ``axis`` of ``a`` (see :func:`scan_label`).

    Works on the events only: the edges between neighbours that rise, fall or touch
    nodata are listed profile by profile; a rise followed directly by a fall on the same
    profile, at most ``max_cells`` apart, bounds a run, whose cells are then generated
    and tested against the run's base line, all vectorised.
    """
    out = np.zeros(a.shape, bool)
    if a.shape[axis] < 3:
        return out
    dz = np.diff(a, axis=axis)                    # edge j: between cells j and j+1
    with np.errstate(invalid="ignore"):
        rise = dz > t_jump
        fall = dz < -t_jump
    ev = rise | fall
    if has_nan:
        ev |= np.isnan(dz)                        # nodata breaks runs
    if axis == 0:                                 # events profile by profile (columns)
        c, r = np.nonzero(ev.T)
        line, pos = c, r
    else:
        r, c = np.nonzero(ev)
        line, pos = r, c
    if r.size < 2:
        return out
    is_rise, is_fall = rise[r, c], fall[r, c]
    pair = ((line[:-1] == line[1:]) & is_rise[:-1] & is_fall[1:]
            & (pos[1:] - pos[:-1] <= max_cells))
    k = np.flatnonzero(pair)
    if k.size == 0:
        return out
    jl, jr, ln = pos[k], pos[k + 1], line[k]     # rise edge, fall edge, profile
    n_run = jr - jl                               # cells jl+1 .. jr
    # flat index of cell p on profile l, and the step between neighbours on a profile
    W = a.shape[1]
    first, stride = (ln * W, 1) if axis == 1 else (ln, W)
    af = a.ravel()
    base_l = af[first + jl * stride]              # the cell before the rise
    slope = (af[first + (jr + 1) * stride] - base_l) / (n_run + 1).astype(np.float32)
    start = np.cumsum(n_run) - n_run
    off = np.arange(int(n_run.sum()), dtype=n_run.dtype) - np.repeat(start, n_run) + 1
    flat = np.repeat(first + jl * stride, n_run) + off * stride
    base = np.repeat(base_l, n_run) + np.repeat(slope, n_run) * off
    keep = (af[flat] - base) > height_m
    out.ravel()[flat[keep]] = True
    return out


def scan_label(z, cell_size, *, jump_m, height_m, max_length_m, terrain_slope_deg=0.0,
               passes=2, reference=None):
    """Scan labelling: non-ground runs along rows and columns.

    Along each row and each column, the edge between neighbouring cells ``i, i+1`` is a
    *rise* when ``z[i+1] - z[i] > jump_m + tan(terrain_slope) * cell`` (the slope
    differential: steeper than the terrain may be by more than ``jump_m`` over one
    cell), a *fall* when ``z[i+1] - z[i] < -(...)``. A run of cells that opens with a
    rise, closes with the next event being a fall, spans at most ``max_length_m`` and
    stands more than ``height_m`` above the straight line from the cell before the rise to
    the cell after the fall is labelled non-ground. Rows and columns are combined with OR.
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
        Longest labelled run (the largest object).
    terrain_slope_deg : float
        Steepest terrain slope (degrees); its rise over one cell is tolerated.
    passes : int
        Number of labelling passes (>= 1).
    reference : array_like, optional
        A terrain approximation (the filter passes its lowest geodesic reconstruction):
        a labelled cell must also stand more than ``height_m`` above it, so terrain
        ridges, which the reconstruction follows, are never labelled.

    Returns
    -------
    ndarray of bool
        True where a cell is labelled non-ground.
    """
    z = as_surface(z)
    dx, dy = as_cell_size(cell_size)
    if jump_m < 0 or height_m < 0 or max_length_m <= 0:
        raise ValueError(f"scan_label needs jump_m >= 0, height_m >= 0, max_length_m > 0; "
                         f"got {jump_m}, {height_m}, {max_length_m}.")
    if not 0 <= terrain_slope_deg < 90:
        raise ValueError(f"terrain_slope_deg must be in [0, 90); got {terrain_slope_deg}.")
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
    for _ in range(int(passes)):
        lr = _scan_axis(a, 1, tx, height_m, max(2, int(max_length_m / dx)), has_nan)
        lc = _scan_axis(a, 0, ty, height_m, max(2, int(max_length_m / dy)), has_nan)
        new = (lr | lc) & ~labelled & allowed
        if not new.any():
            break
        labelled |= new
        # lower the labelled cells to the surrounding level for the next pass
        low = _filter2d(np.where(np.isnan(a), np.inf, a), (3, 3), np.minimum, np.inf)
        a = np.where(new, np.minimum(a, low), a)
    return labelled


# ------------------------------------------------------------------------------ filter
def _noise_sigma(z, valid):
    """Robust noise of the surface: MAD of second differences along rows and columns."""
    st = max(1, int(np.sqrt(z.size / 1e6)))
    zs = z[::st, ::st]
    d = np.concatenate([(zs[:, 2:] - 2 * zs[:, 1:-1] + zs[:, :-2]).ravel(),
                        (zs[2:] - 2 * zs[1:-1] + zs[:-2]).ravel()])
    d = d[np.isfinite(d)]
    if d.size < 10:
        return 0.1
    # 25th percentile of |d| (0.3186 sigma_d for a normal law): edges and objects, which
    # fill the upper tail, barely move it
    return float(np.percentile(np.abs(d - np.median(d)), 25) / 0.3186 / np.sqrt(6.0))


def _terrain_slope_deg(z, valid, dx, dy, max_size_m):
    """Robust steep-terrain slope: 90th percentile slope of the largest-window opening,
    computed on a grid coarsened to about 4 m (or the cell) so objects are gone."""
    f = max(1, int(round(4.0 / max(dx, dy))))
    H, W = z.shape
    Hc, Wc = H // f, W // f
    if Hc < 3 or Wc < 3:
        f, Hc, Wc = 1, H, W
    zc = np.where(valid, z, np.inf)[:Hc * f, :Wc * f].reshape(Hc, f, Wc, f).min(axis=(1, 3))
    vc = np.isfinite(zc)
    if vc.sum() < 9:
        return 30.0
    size = _window(max_size_m, dx * f, dy * f)
    o = _opening(zc, vc, size)
    o = np.where(vc & np.isfinite(o), o, np.nan)
    if min(o.shape) < 2:
        return SLOPE_CLIP_DEG[0]
    gy, gx = np.gradient(o, dy * f, dx * f)
    s = np.hypot(gx, gy)
    s = s[np.isfinite(s)]
    if s.size == 0:
        return 30.0
    return float(np.clip(np.degrees(np.arctan(np.percentile(s, SLOPE_PERCENTILE))),
                         *SLOPE_CLIP_DEG))


def resolve_geodesic_params(z, cell_size, **params):
    """Complete the parameters of :func:`filter_geodesic`, deriving ``None`` from the data.

    * ``height_threshold_m`` (dh0): ``max(0.5, 3 sigma)`` with ``sigma`` the robust noise
      of the DSM (lower quartile of the absolute second differences, scaled to a normal
      sigma: edges and objects fill the upper tail and barely move it).
    * ``outlier_threshold_m``: ``max(2.0, 4 dh0)``.
    * ``terrain_slope_deg``: 90th percentile slope of the surface opened by the largest
      window on a ~4 m grid (objects gone), clipped to [12, 22] degrees: it is the slope
      *tolerated* by the wall and rise tests, and on the ISPRS samples a tolerance above
      ~25 degrees lets walls on hillsides pass as terrain (see :data:`SLOPE_CLIP_DEG`).

    Raises
    ------
    ValueError
        Unknown parameter names or values out of range.
    """
    unknown = set(params) - set(_DEFAULTS)
    if unknown:
        raise ValueError(f"unknown geodesic parameter(s) {sorted(unknown)}; "
                         f"valid names: {sorted(_DEFAULTS)}.")
    z = as_surface(z)
    dx, dy = as_cell_size(cell_size)
    p = dict(_DEFAULTS)
    p.update({k: v for k, v in params.items() if v is not None})
    _check(p)
    valid = np.isfinite(z)
    if p["height_threshold_m"] is None:
        sigma = noise_ground_level(z, (dx, dy))["sigma"]
        p["height_threshold_m"] = round(max(0.5, NOISE_K * sigma), 3) if np.isfinite(sigma) else 0.5
    if p["outlier_threshold_m"] is None:
        p["outlier_threshold_m"] = round(max(2.0, 4 * p["height_threshold_m"]), 3)
    if p["terrain_slope_deg"] is None:
        p["terrain_slope_deg"] = round(_terrain_slope_deg(z, valid, dx, dy,
                                                          p["max_object_size_m"]), 2)
    _check(p)
    return p


def _check(p):
    def bad(name, cond, what):
        v = p.get(name)
        if v is not None and not cond(v):
            raise ValueError(f"{name} must be {what}; got {v!r}. Fix the parameter or leave "
                             "it empty for the default.")
    bad("min_window_m", lambda v: v > 0, "> 0 metres")
    bad("max_object_size_m", lambda v: v > 0, "> 0 metres")
    bad("height_threshold_m", lambda v: v > 0, "> 0 metres")
    bad("terrain_slope_deg", lambda v: 0 <= v < 90, "in [0, 90) degrees")
    bad("edge_ratio", lambda v: 0 <= v <= 1, "in [0, 1]")
    bad("outlier_threshold_m", lambda v: v > 0, "> 0 metres")
    bad("outlier_width_m", lambda v: v > 0, "> 0 metres")
    if p["max_object_size_m"] < p["min_window_m"]:
        raise ValueError(f"max_object_size_m ({p['max_object_size_m']}) is smaller than "
                         f"min_window_m ({p['min_window_m']}); raise the first or lower "
                         "the second.")


def _steps(min_window_m, max_object_size_m):
    """Structuring-element sizes in metres: doubling from min to max (last = max)."""
    sizes = []
    s = float(min_window_m)
    while s < max_object_size_m * 0.999:
        sizes.append(s)
        s *= 2.0
    sizes.append(float(max_object_size_m))
    if len(sizes) > 250:
        raise ValueError("too many dilation steps; raise min_window_m or lower "
                         "max_object_size_m.")
    return sizes


def geodesic_halo(params, cell_size):
    """Reach of :func:`filter_geodesic` in cells.

    A cell's residual at the largest step (side ``S = max_object_size_m``) reads ``z``
    within its opening (two half-windows: ``S``) and its geodesic reconstruction (reach
    ``S``); a region spans at most ``EXTENT_FACTOR * S``, so a decision reads ``z``
    within ``(2 + EXTENT_FACTOR) S``. Scan labelling adds two passes of runs up to ``S``
    (``2 S``); the preprocessing two outlier windows and a cluster. The halo is rounded
    up to a multiple of the largest coarsening factor, so that blocks whose edge is a
    multiple of it (the default 2048 is) see the same coarse grids as one pass.
    """
    dx, dy = as_cell_size(cell_size)
    c = min(dx, dy)
    size = float(params.get("max_object_size_m", _DEFAULTS["max_object_size_m"]))
    width = float(params.get("outlier_width_m", _DEFAULTS["outlier_width_m"]))
    reach = (int(np.ceil(((4 + EXTENT_FACTOR) * size + 2 * width + WALL_BASE_M) / c))
             + OUTLIER_MAX_CELLS + 8)
    # coarse steps use grids aligned on the block origin: keep blocks aligned on them
    params = dict(_DEFAULTS, **{k: v for k, v in params.items() if v is not None})
    f = max(_coarse_factor(_window(s, dx, dy))
            for s in _steps(params["min_window_m"], params["max_object_size_m"]))
    return int(-(-reach // f) * f)


def filter_geodesic(z, cell_size, *, min_window_m=2.0, max_object_size_m=64.0,
                    height_threshold_m=0.5, terrain_slope_deg=20.0, edge_ratio=0.55,
                    outlier_threshold_m=2.0, outlier_width_m=2.0, scan_labelling=True,
                    progress=None):
    """Gradual geodesic dilation with scan labelling (2018; ISPRS filter test).

    See the module docstring for the method. Parameters are complete values (use
    :func:`resolve_geodesic_params` to derive defaults from the data).

    Parameters
    ----------
    z : array_like, 2-D
        DSM, NaN = nodata (not modified).
    cell_size : float or (float, float)
        ``(dx, dy)`` in metres.
    min_window_m : float
        Side of the first (smallest) structuring element, metres.
    max_object_size_m : float
        Side of the last structuring element: the largest object removed, metres.
    height_threshold_m : float
        dh0: minimal height of an object above the reconstructed terrain, metres.
    terrain_slope_deg : float
        Terrain slope tolerance (degrees): a wall rises more than ``2 dh0 + tan(slope)``
        times its baseline, a terrain bump of width ``s`` may rise ``tan(slope) * s *``
        :data:`BUMP_FRACTION` above the reconstruction, and scan labelling's rises
        exceed ``dh0 + tan(slope) * cell``.
    edge_ratio : float
        Height heterogeneity threshold in [0, 1]: a region is an object when at least
        this fraction of its border cells hold a wall (a cell above a cell within
        :data:`WALL_BASE_M` by more than ``2 dh0 + tan(slope) * distance``).
    outlier_threshold_m : float
        Preprocessing: depth (height) below the closing (above the opening) of a low
        (high) outlier, metres.
    outlier_width_m : float
        Preprocessing: width of the closing/opening window, metres.
    scan_labelling : bool
        Run scan labelling after the dilation steps.
    progress : callable, optional
        ``progress(fraction)``; may raise :class:`~bare_earth.core.common.Cancelled`.

    Returns
    -------
    FilterResult
        ``mask`` (0 ground, 1 object, 2 low outlier, 255 nodata); ``extras["step"]``
        (uint8: 0 kept, k = removed at dilation step k, :data:`STEP_SCAN`,
        :data:`STEP_OUTLIER`, :data:`STEP_EDGE`, 255 nodata); ``surface`` the cleaned
        surface (removed cells lowered to the reconstruction); ``info`` parameters, step
        sizes and counts.
    """
    t0 = time.perf_counter()
    z = as_surface(z)
    dx, dy = as_cell_size(cell_size)
    p = dict(min_window_m=min_window_m, max_object_size_m=max_object_size_m,
             height_threshold_m=height_threshold_m, terrain_slope_deg=terrain_slope_deg,
             edge_ratio=edge_ratio, outlier_threshold_m=outlier_threshold_m,
             outlier_width_m=outlier_width_m, scan_labelling=bool(scan_labelling))
    for k, v in p.items():
        if v is None:
            raise ValueError(f"{k} is None: filter_geodesic needs complete parameters; "
                             "call resolve_geodesic_params first (or use the pipeline).")
    _check(p)
    valid = np.isfinite(z)
    vnone = None if valid.all() else valid        # fast paths when there is no nodata
    dh0 = float(height_threshold_m)
    tan_s = float(np.tan(np.radians(terrain_slope_deg)))
    step = np.zeros(z.shape, np.uint8)
    mask = np.zeros(z.shape, np.uint8)
    report(progress, 0.0)

    # 1. preprocessing: isolated low and high outliers
    win = _window(outlier_width_m, dx, dy)
    w = np.where(valid, z, np.float32(np.nan))     # inf counts as nodata too
    clo = _closing(z, vnone, win)
    ope = _opening(z, vnone, win)
    with np.errstate(invalid="ignore"):
        low_c = valid & (clo - z > outlier_threshold_m)
        high_c = valid & (z - ope > outlier_threshold_m)
    n_low = n_high = 0
    for cand, code, repl in ((low_c, LOW, clo), (high_c, OBJECT, ope)):
        if not cand.any():
            continue
        lab, n = ndimage.label(cand, _S8)
        size = np.bincount(lab.ravel(), minlength=n + 1)
        small = size <= OUTLIER_MAX_CELLS
        small[0] = False
        sel = small[lab]
        mask[sel] = code
        step[sel] = STEP_OUTLIER
        w[sel] = repl[sel]
        if code == LOW:
            n_low = int(sel.sum())
        else:
            n_high = int(sel.sum())
    stages = {"preprocessing": round(time.perf_counter() - t0, 3)}
    report(progress, 0.05)

    # 2. gradual geodesic dilation
    sizes = _steps(min_window_m, max_object_size_m)
    wmask = w                                     # NaN at nodata already
    cleaned = w.copy()
    removed = np.zeros(z.shape, bool)
    ext_limit = EXTENT_FACTOR * max_object_size_m
    # walls: cells above a neighbour within WALL_BASE_M (one cell at 1 m; two at 0.5 m,
    # where matching smears walls) by more than 2 dh0 + the terrain's rise over that
    wr = (max(1, int(round(WALL_BASE_M / dy))), max(1, int(round(WALL_BASE_M / dx))))
    low = _filter2d(_fill(w, valid, np.inf), (2 * wr[0] + 1, 2 * wr[1] + 1), np.minimum,
                    np.inf)
    with np.errstate(invalid="ignore"):
        jump = valid & (w - low > 2.0 * dh0 + tan_s * np.hypot(wr[0] * dy, wr[1] * dx))
    del low
    counts = []
    for k, s in enumerate(sizes, start=1):
        R, obj = _step(w, valid, wmask, jump, s, dx, dy, dh0, tan_s, edge_ratio, ext_limit)
        new = obj & ~removed
        removed |= obj
        new &= step == 0                          # outliers keep their own code
        step[new] = k
        np.minimum(cleaned, R, out=cleaned, where=obj)
        counts.append(int(np.count_nonzero(new)))
        report(progress, 0.05 + 0.8 * k / len(sizes))

    stages["dilation"] = round(time.perf_counter() - t0 - sum(stages.values()), 3)

    # 3. scan labelling on the cleaned surface
    n_scan = 0
    if scan_labelling:
        lab_s = scan_label(cleaned, (dx, dy), jump_m=dh0,
                           height_m=dh0, max_length_m=max_object_size_m,
                           terrain_slope_deg=terrain_slope_deg, passes=SCAN_PASSES)
        new = lab_s & ~removed & (step == 0)
        step[new] = STEP_SCAN
        removed |= lab_s
        n_scan = int(new.sum())
    stages["scan"] = round(time.perf_counter() - t0 - sum(stages.values()), 3)
    report(progress, 0.95)

    # 4. object borders: a kept cell touching a removed one that stands above one of its
    # neighbours by more than dh0 plus the terrain's rise over a cell diagonal is a wall
    # foot or crown edge (a mixed cell): removed too
    n_edge = 0
    if removed.any():
        lowc = _filter2d(_fill(cleaned, vnone, np.inf), (3, 3), np.minimum, np.inf)
        with np.errstate(invalid="ignore"):
            edge = valid & (cleaned - lowc > dh0 + tan_s * np.hypot(dx, dy))
        edge &= _filter2d(removed, (3, 3), np.maximum, False) & ~removed & (step == 0)
        step[edge] = STEP_EDGE
        removed |= edge
        n_edge = int(edge.sum())
    mask[removed & (mask != LOW)] = OBJECT
    mask = finish_mask(mask, z)
    step[~valid] = STEP_NODATA
    cleaned[~valid] = np.nan
    info = dict(p, method="geodesic", step_sizes_m=sizes, removed_per_step=counts,
                removed_scan=n_scan, removed_edge=n_edge, low_outliers=n_low,
                high_outliers=n_high,
                object_fraction=float((mask == OBJECT).sum() / max(valid.sum(), 1)),
                seconds=round(time.perf_counter() - t0, 3), stage_seconds=stages)
    report(progress, 1.0)
    return FilterResult(mask=mask, extras={"step": step}, info=info,
                        surface=cleaned.astype(np.float32))


def _run(z, cell_size, progress=None, **params):
    return filter_geodesic(z, cell_size, progress=progress, **params)


METHOD = Method(
    name="geodesic",
    run=_run,
    resolve=resolve_geodesic_params,
    halo=geodesic_halo,
    extras={"step": (np.uint8, 1, STEP_NODATA)},
    params=(
        Param("min_window_m", "float", 2.0, "Side of the first structuring element in "
              "metres; the following steps double it up to the maximum object size.",
              minimum=0.1, maximum=1000.0),
        Param("max_object_size_m", "float", 64.0, "Largest object to remove (side of the "
              "last structuring element) in metres: the widest building.",
              minimum=0.5, maximum=5000.0),
        Param("height_threshold_m", "float", None, "Minimal object height dh0 above the "
              "reconstructed terrain in metres; empty: max(0.5, 3 x robust noise of the DSM).",
              minimum=0.01, maximum=100.0),
        Param("terrain_slope_deg", "float", None, "Terrain slope in degrees tolerated by "
              "the wall test, the height test and scan labelling; empty: 90th percentile "
              "slope of the heavily opened DSM, clipped to 12-22 degrees.",
              minimum=0.0, maximum=89.0, advanced=True),
        Param("edge_ratio", "float", 0.55, "Height heterogeneity threshold (0-1): a "
              "region the reconstruction cannot reach is an object when at least this "
              "fraction of its border cells stand above a cell within 1 m by more than "
              "2 dh0 plus the terrain's rise over that distance (walls jump, hills rise "
              "gently).",
              minimum=0.0, maximum=1.0, advanced=True),
        Param("outlier_threshold_m", "float", None, "Preprocessing: a small cluster this "
              "far below the closing (above the opening) is a low (high) outlier, metres; "
              "empty: max(2, 4 x dh0).", minimum=0.01, maximum=1000.0, advanced=True),
        Param("outlier_width_m", "float", 2.0, "Preprocessing: window of the closing and "
              "opening that find isolated outliers, metres.", minimum=0.1, maximum=100.0,
              advanced=True),
        Param("scan_labelling", "bool", True, "Run scan labelling along rows and columns "
              "after the dilation steps (removes what the dilation left).", advanced=True),
    ),
    title="Gradual geodesic dilation with scan labelling (2018)",
    description=(
        "<p>Separates ground from objects in a DSM in four stages and a border pass. "
        "<b>Preprocessing</b> "
        "finds isolated outliers: small clusters far below the grey closing (low outliers, "
        "mask class 2: matching blunders, multipath) or far above the grey opening (high "
        "outliers). <b>Gradual geodesic dilation</b>: for structuring elements doubling "
        "from the first window to the maximum object size, the opening of the DSM is "
        "reconstructed by geodesic dilation under the DSM; the residual (what the "
        "reconstruction cannot reach) is split into regions, and a region is removed when "
        "it is higher than dh0 plus the rise the terrain slope allows over half the window, "
        "and its border is abrupt (at least the edge ratio of its border cells stand above "
        "a cell within 1 m by more than 2 dh0 plus the terrain's rise over it). Wide "
        "windows run on coarsened grids. Small objects go at the small steps, large "
        "buildings at the large ones; terrain edges are restored by the reconstruction "
        "and hills with gentle sides are kept. <b>Scan labelling</b> along rows and "
        "columns removes runs that open with a rise, close with a fall and stand above "
        "their neighbours; then the border cells of removed regions that stand above a "
        "neighbour by more than dh0 plus the terrain's rise (wall feet, crown edges) are "
        "removed. The DTM is the "
        "DSM with the removed cells filled by "
        "interpolation.</p><p>Defaults: dh0 = max(0.5 m, 3 x robust DSM noise); terrain "
        "slope = 90th percentile slope of the heavily opened DSM, clipped to 12-22 "
        "degrees; outlier threshold = max(2 m, 4 dh0). Output STEP: 0 kept, "
        "k removed at dilation step k, 250 scan labelling, 251 preprocessing outlier, "
        "252 object border.</p>"
        "<p>After: gradual geodesic dilation and scan labelling for DSM filtering "
        "(2018, in Persian; evaluated on the ISPRS filter test: Type I 4.61 %, Type II "
        "6.97 %, total 3.17 %).</p>"),
)
