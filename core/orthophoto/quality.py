"""Trust in the measured height corrections: blunders, merging, ground trend, object mask.

The orthophoto refinement (Luong Chinh Ke 2002, section 2.3; Norvelle 1995) measures a
height correction ``dh`` per cell from the residual parallax of orthophoto pairs. The
matcher decides per cell whether a match is trusted (:func:`~.match.match_along`); this
module keeps the corrections consistent with their neighbours and with each other:

* :func:`nan_median_filter`: the median of the valid values around each cell;
* :func:`remove_blunders`: a robust test of each corrected height ``z = DEM + dh`` against
  the median of its neighbours (a spike is a blunder unless a cluster of neighbours
  confirms it, as on the corners of roofs);
* :func:`split_significant`: the smooth part of the corrections (a normalised Gaussian mean)
  and where their detail stands out of the noise (the rest is not applied: the refined DEM
  gets no rougher than the data support);
* :func:`merge_pairs`: the correlation-weighted mean of the pairs after dropping the pairs
  that disagree with the median;
* :func:`ground_trend` and :func:`object_mask`: the smooth ground part of ``dh`` (a median of
  the cells below the threshold, iterated) and the mask of the cells above it, with the
  threshold derived from the spread of the very quantity it is applied to;
* :func:`settle_boundary`: the cells along the object outlines decided by testing the object's
  and the ground's height on the orthophotos with small shiftable windows;
* :func:`fill_holes`: normalised convolution into unmatched cells;
* :func:`spread_corrections`: the same, fading to 0 away from the measurements (no step in
  the DEM where the measurements end).
"""
import functools
import math
import warnings

import numpy as np
from scipy import ndimage, special

from ..codes import GROUND, LOW, NODATA, OBJECT

__all__ = ["fill_holes", "spread_corrections", "nan_median_filter", "nan_median_at", "remove_blunders", "merge_pairs",
           "split_significant",
           "ground_trend", "object_mask", "settle_boundary", "window_variance", "agree_at_height",
           "close_mask"]

#: Rows per band of the stacked neighbourhoods (bounded memory).
_BAND_ROWS = 128
_INF32 = np.float32(np.inf)


def fill_holes(values, valid=None, max_sigma=64.0):
    """Fill NaN cells by normalised convolution at growing Gaussian scales (vectorised).

    Returns a float32 copy with every NaN replaced where data lie within about
    ``3 * max_sigma`` cells; farther cells stay NaN.
    """
    v = np.asarray(values, dtype=np.float64)
    ok = np.isfinite(v) if valid is None else (valid & np.isfinite(v))
    out = np.where(ok, v, np.nan)
    if ok.all() or not ok.any():
        return out.astype(np.float32)
    z = np.where(ok, v, 0.0)
    w = ok.astype(np.float64)
    s = 1.0
    while s <= max_sigma:
        holes = ~np.isfinite(out)
        if not holes.any():
            break
        num = ndimage.gaussian_filter(z, s, mode="nearest")
        den = ndimage.gaussian_filter(w, s, mode="nearest")
        fill = holes & (den > 1e-3)
        out[fill] = num[fill] / den[fill]
        s *= 2
    return out.astype(np.float32)


def spread_corrections(dh, valid, sigma_cells):
    """Corrections at every cell: measured where ``valid``, elsewhere filled, then fading out.

    An unmatched cell takes the normalised Gaussian mean (sigma ``sigma_cells``) of the
    measured corrections around it: the whole value within ``2 * sigma_cells`` cells of a
    measurement (gaps next to walls, occlusions), fading linearly to 0 at ``4 * sigma_cells``
    (the corrected DEM has no step where the measurements end); farther cells get 0.

    Returns
    -------
    ndarray float32
        No NaN.
    """
    ok = np.asarray(valid, bool) & np.isfinite(dh)
    if not ok.any():
        return np.zeros(np.shape(dh), np.float32)
    z = np.where(ok, dh, 0.0).astype(np.float64)
    num = ndimage.gaussian_filter(z, sigma_cells, mode="nearest")
    den = ndimage.gaussian_filter(ok.astype(np.float64), sigma_cells, mode="nearest")
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(den > 1e-9, num / den, 0.0)
    dist = ndimage.distance_transform_edt(~ok)
    fade = np.clip((4.0 * sigma_cells - dist) / (2.0 * sigma_cells), 0.0, 1.0)
    return np.where(ok, z, mean * fade).astype(np.float32)


def _batcher_pairs(n):
    """Comparators of Batcher's odd-even merge sort of ``n`` wires (a power of two), in order."""
    pairs = []
    p = 1
    while p < n:
        k = p
        while k >= 1:
            for j in range(k % p, n - k, 2 * k):
                for i in range(min(k, n - j - k)):
                    if (i + j) // (2 * p) == (i + j + k) // (2 * p):
                        pairs.append((i + j, i + j + k))
            k //= 2
        p *= 2
    return pairs


@functools.lru_cache(maxsize=None)
def _selection_network(n, rank):
    """The comparators of a sorting network of ``n`` values that the ``rank``-th output needs.

    Batcher's network on the next power of two (the extra wires hold +inf, which never
    moves down, so their comparators are dropped), pruned backwards to the comparators
    whose outputs reach wire ``rank``. Each entry is ``(i, j, need_low, need_high)``.
    """
    m = 1 << max(0, (n - 1).bit_length())
    net = [(i, j) for i, j in _batcher_pairs(m) if j < n]   # wire j >= n holds +inf: no change
    need, out = {rank}, []
    for i, j in reversed(net):
        lo, hi = i in need, j in need
        if lo or hi:
            out.append((i, j, lo, hi))
            need |= {i, j}
    return tuple(reversed(out))


def _select(planes, rank):
    """The ``rank``-th smallest of the arrays ``planes`` (elementwise, no NaN) by a network.

    The planes (distinct arrays of one shape and dtype) are overwritten: every comparator
    writes into them or into one spare plane, so the network allocates a single array.
    """
    w = list(planes)
    spare = None
    for i, j, lo, hi in _selection_network(len(w), rank):
        a, b = w[i], w[j]
        if lo and hi:
            if spare is None:
                spare = np.empty_like(a)
            np.minimum(a, b, out=spare)
            np.maximum(a, b, out=b)
            w[i], spare = spare, a
        elif lo:
            np.minimum(a, b, out=a)
        elif hi:
            np.maximum(a, b, out=b)
    return w[rank]


def nan_median_filter(x, size=5, *, tolerance=None):
    """Median of the finite values in the ``size x size`` window of every cell.

    For an even number of finite values, the upper of the two middle ones. The missing
    values of a window are set alternately to +inf and -inf, so the middle element of the
    whole window is the median of the finite ones; it is taken by a pruned sorting network
    (Batcher 1968) of elementwise minima and maxima over the window's shifted planes.

    Parameters
    ----------
    x : ndarray (rows, cols)
        Values; NaN = missing.
    size : int
        Odd window side in cells.
    tolerance : float or ndarray, optional
        With it, also count the neighbours (the cell itself excluded) within ``tolerance``
        of the cell's own value.

    Returns
    -------
    median : ndarray float32
        NaN where the window holds no finite value.
    count : ndarray int16
        Finite values in the window.
    support : ndarray int16
        Only with ``tolerance``: neighbours agreeing with the cell.
    """
    x = np.asarray(x, dtype=np.float32)
    size = int(size)
    if size < 1 or size % 2 == 0:
        raise ValueError(f"size must be an odd number of cells >= 1; got {size}.")
    rows, cols = x.shape
    h = size // 2
    med = np.full(x.shape, np.nan, np.float32)
    cnt = np.zeros(x.shape, np.int16)
    sup = np.zeros(x.shape, np.int16) if tolerance is not None else None
    tol = None if tolerance is None else np.broadcast_to(np.asarray(tolerance, np.float32), x.shape)
    mid = size * size // 2
    band = max(_BAND_ROWS, 4 * _BAND_ROWS * 25 // (size * size))
    for r0 in range(0, rows, band):
        r1 = min(rows, r0 + band)
        pad = np.full((r1 - r0 + 2 * h, cols + 2 * h), np.nan, np.float32)
        s0, s1 = max(0, r0 - h), min(rows, r1 + h)
        pad[s0 - (r0 - h):s1 - (r0 - h), h:h + cols] = x[s0:s1]
        nan_pad = np.isnan(pad)
        planes, n, parity = [], np.zeros((r1 - r0, cols), np.int16), np.zeros((r1 - r0, cols), bool)
        xc = x[r0:r1]
        if sup is not None:
            sup_b = -np.isfinite(xc).astype(np.int16)
        for i in range(size):
            for j in range(size):
                v = pad[i:i + r1 - r0, j:j + cols]
                nan = nan_pad[i:i + r1 - r0, j:j + cols]
                if sup is not None:
                    with np.errstate(invalid="ignore"):
                        sup_b += np.abs(v - xc) <= tol[r0:r1]
                parity ^= nan                               # odd count of NaN so far: +inf
                n += ~nan
                planes.append(np.where(nan, np.where(parity, _INF32, -_INF32), v))   # float32 throughout
        m = _select(planes, mid)
        med[r0:r1] = np.where(n > 0, m, np.nan)
        cnt[r0:r1] = n
        if sup is not None:
            sup[r0:r1] = sup_b
    return (med, cnt, sup) if sup is not None else (med, cnt)


def nan_median_at(x, cells, size=3):
    """:func:`nan_median_filter` at the given cells only (for a few cells of a large grid).

    Parameters
    ----------
    x : ndarray (rows, cols)
    cells : (ndarray, ndarray)
        Row and column indices (as from ``np.nonzero``).
    size : int
        Odd window side.

    Returns
    -------
    ndarray
        The upper middle of the sorted finite values of each window (NaN sorts last), NaN
        where none is finite: the values of :func:`nan_median_filter` at those cells.
    """
    size = int(size)
    if size < 1 or size % 2 == 0:
        raise ValueError(f"size must be an odd number of cells >= 1; got {size}.")
    rr, cc = cells
    h = size // 2
    pad = np.pad(np.asarray(x, np.float32), h, constant_values=np.nan)
    nb = np.stack([pad[rr + i, cc + j] for i in range(size) for j in range(size)], axis=1)
    nb.sort(axis=1)
    n = np.count_nonzero(np.isfinite(nb), axis=1)
    m = nb[np.arange(nb.shape[0]), n // 2] if nb.shape[0] else np.zeros(0, np.float32)
    return np.where(n > 0, m, np.nan).astype(np.float32)


def remove_blunders(dh, dem, tolerance_m, size=5):
    """Drop corrections that the neighbouring corrected heights do not confirm.

    The corrected surface ``z = DEM + dh`` is tested against the median of the valid ``z``
    in the ``size x size`` window (a robust estimate of what the neighbours say; on a
    smooth DEM it follows the DEM's slope): a value farther than ``tolerance_m`` from it is
    a blunder unless at least ``(size // 2 + 1)^2 - 1`` neighbours agree with it within
    ``tolerance_m`` (the corner of a roof, where the median belongs to the ground). A value
    with fewer than ``size // 2 + 1`` valid neighbours has no support and is dropped too.

    Parameters
    ----------
    dh : ndarray
        Corrections (NaN = not measured).
    dem : ndarray
        The DEM they correct.
    tolerance_m : float
        Largest departure from the neighbours' median that needs no confirmation
        (3 x the expected precision of ``dh``).
    size : int
        Odd window side in cells.

    Returns
    -------
    dh : ndarray float32
        The corrections with the blunders set to NaN.
    dropped : int
        Number of blunders removed.
    """
    dh = np.asarray(dh, np.float32)
    z = np.where(np.isfinite(dh) & np.isfinite(dem), dem + dh, np.nan).astype(np.float32)
    cnt, sup = _count_support(z, size, float(tolerance_m))
    ok = np.isfinite(z)
    cluster = (size // 2 + 1) ** 2 - 1
    bad = ok & (cnt - 1 < size // 2 + 1)
    # the median decides only where too few neighbours confirm the value: take it there
    # (the values of nan_median_filter at those cells)
    test = np.nonzero(ok & ~bad & (sup < cluster))
    med = nan_median_at(z, test, size)
    with np.errstate(invalid="ignore"):
        bad[test] = np.abs(z[test] - med) > tolerance_m
    return np.where(bad, np.nan, dh).astype(np.float32), int(np.count_nonzero(bad))


def _count_support(z, size, tolerance):
    """Finite values in the ``size x size`` window and neighbours within ``tolerance`` of the cell.

    The ``count`` and ``support`` of :func:`nan_median_filter` with ``tolerance``, without
    the median.
    """
    rows, cols = z.shape
    h = size // 2
    pad = np.pad(z, h, constant_values=np.nan)
    fin = np.isfinite(pad)
    tol = np.float32(tolerance)
    cnt = np.zeros(z.shape, np.int16)
    sup = -np.isfinite(z).astype(np.int16)
    with np.errstate(invalid="ignore"):
        for i in range(size):
            for j in range(size):
                cnt += fin[i:i + rows, j:j + cols]
                sup += np.abs(pad[i:i + rows, j:j + cols] - z) <= tol
    return cnt, sup


def _nanmedian_stack(D):
    """``np.nanmedian(D, axis=0)`` for a short stack (a few pairs): one sort, same values.

    NaN sorts last; the median of the ``n`` finite values is the middle one, or the mean of
    the two middle ones for even ``n``; NaN where none is finite.
    """
    S = np.sort(D, axis=0)
    n = np.sum(np.isfinite(D), axis=0)
    last = D.shape[0] - 1
    lo = np.take_along_axis(S, np.clip((n - 1) // 2, 0, last)[None], 0)[0]
    hi = np.take_along_axis(S, np.clip(n // 2, 0, last)[None], 0)[0]
    return np.where(n > 0, np.where(n % 2 == 1, hi, (lo + hi) / 2), np.nan).astype(D.dtype)


def merge_pairs(dhs, cors, outlier_m):
    """Correlation-weighted mean of the pairs' corrections after dropping per-cell outliers.

    With three or more pairs at a cell, values farther than ``outlier_m`` from their median
    are dropped; two values that differ by more than ``2 * outlier_m`` are both dropped.

    Returns
    -------
    dh, quality : ndarray float32
        The merged correction (NaN where no pair matched) and the correlation-weighted mean
        peak NCC.
    """
    if not dhs:
        raise ValueError("no pair of orthophotos could be matched; check that the images overlap.")
    D = np.stack(dhs)
    C = np.stack(cors)
    if len(dhs) > 1:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            med = _nanmedian_stack(D)
            n = np.sum(np.isfinite(D), axis=0)
            with np.errstate(invalid="ignore"):
                far = (np.abs(D - med) > outlier_m) & (n >= 3)
            D = np.where(far, np.nan, D)
            spread = np.nanmax(D, axis=0) - np.nanmin(D, axis=0)
            with np.errstate(invalid="ignore"):
                two_bad = (n == 2) & (spread > 2 * outlier_m)
            D = np.where(two_bad, np.nan, D)
    W = np.where(np.isfinite(D), np.clip(np.nan_to_num(C, nan=0.0), 1e-3, 1), 0.0)
    den = W.sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        dh = np.where(den > 0, np.nansum(np.where(W > 0, D, 0) * W, axis=0) / den, np.nan)
        q = np.where(den > 0, np.nansum(np.nan_to_num(C) * W, axis=0) / den, np.nan)
    return dh.astype(np.float32), q.astype(np.float32)


def split_significant(dh, sigma_m, scale_cells, k=3.0):
    """The corrections' normalised Gaussian mean and where their detail is significant.

    Each correction measures an average over the correlation window, with noise of sd
    ``sigma_m``; applied cell by cell, that noise becomes speckle in the DEM. The smooth part
    is the normalised Gaussian mean of ``dh`` with sigma ``scale_cells`` (the window), whose
    noise is several times smaller (normalised convolution, Knutsson & Westin 1993: ``num /
    den``, ``den`` the weight of the measurements under the Gaussian); the detail ``dh -
    smooth`` is significant where ``|detail| > k * sigma_m`` in a region that holds a square
    of ``scale_cells // 2 + 1`` cells (an object or a step the window resolves).

    Returns
    -------
    num, den : ndarray float64
        The Gaussian sums of the finite ``dh`` and of their weight (``num / den`` is the mean).
    sig : ndarray of bool
        The cells of significant detail (never where ``dh`` is NaN).
    """
    dh = np.asarray(dh, np.float32)
    ok = np.isfinite(dh)
    s = max(0.5, float(scale_cells))
    num = ndimage.gaussian_filter(np.where(ok, dh, 0).astype(np.float64), s, mode="nearest")
    den = ndimage.gaussian_filter(ok.astype(np.float64), s, mode="nearest")
    with np.errstate(invalid="ignore", divide="ignore"):
        smooth = np.where(den > 1e-3, num / den, np.nan)
        sig = np.abs(dh - smooth) > k * float(sigma_m)
    # the matcher cannot resolve features narrower than about half its window: significant
    # detail must hold a square of that side
    side = max(1, int(scale_cells) // 2 + 1)
    sig = ndimage.binary_opening(sig, structure=np.ones((side, side), bool))
    return num, den, sig


def _block_median(x, b):
    """Median of the finite values of ``x`` in ``b x b`` blocks (NaN for blocks under a quarter full)."""
    rows, cols = x.shape
    nr, nc = -(-rows // b), -(-cols // b)
    pad = np.full((nr * b, nc * b), np.nan, np.float32)
    pad[:rows, :cols] = x
    blocks = pad.reshape(nr, b, nc, b).transpose(0, 2, 1, 3).reshape(nr, nc, b * b)
    n = np.count_nonzero(np.isfinite(blocks), axis=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(blocks, axis=2)
    return np.where(n >= max(1, b * b // 4), med, np.nan).astype(np.float32)


def ground_trend(dh, valid, object_size_cells, sigma_expected, threshold=None, k=3.0, passes=3):
    """The smooth ground part of ``dh`` and the object threshold, computed consistently.

    The ground trend is the median of the ground cells' ``dh`` in blocks of a quarter of
    the largest object width, then the median of those over 5 x 5 blocks (1.25 object
    widths), interpolated back to the cells; a median, so it is not biased by the noise of
    ``dh`` the way a grey opening is (an opening of noisy values lies below their median by
    about two standard deviations). The ground cells start as all valid cells; each pass
    drops the cells above the threshold and recomputes. The spread is measured on the same
    quantity the threshold is applied to, ``rel = dh - trend``: ``sigma_data = 1.4826 x``
    the median of ``|rel|`` of the ground cells below the trend (objects lie above it and do
    not widen it), and ``threshold = k * max(sigma_expected, sigma_data)``.

    Parameters
    ----------
    dh : ndarray
        Height corrections (NaN = none).
    valid : ndarray of bool
        Cells to classify.
    object_size_cells : int
        Largest object width in cells (0: the trend is 0).
    sigma_expected : float
        Expected precision of ``dh`` (m).
    threshold : float, optional
        A given threshold (m) instead of the derived one.
    k : float
        Multiple of the spread for the derived threshold.

    Returns
    -------
    trend : ndarray float32
    threshold : float
    sigma_data : float
    """
    d = np.where(valid & np.isfinite(dh), dh, np.nan).astype(np.float32)
    trend = np.zeros(d.shape, np.float32)
    ground = np.isfinite(d)
    thr = threshold
    sig = float("nan")
    size = int(object_size_cells)
    for _ in range(passes if size >= 3 else 1):
        if size >= 3 and ground.any():
            b = max(1, int(math.ceil(size / 4)))
            coarse = _block_median(np.where(ground, d, np.nan), b)
            coarse, _ = nan_median_filter(coarse, 5)
            coarse = fill_holes(coarse, max_sigma=max(coarse.shape))
            if np.isfinite(coarse).any():
                coarse = np.where(np.isfinite(coarse), coarse, np.nanmedian(coarse))
                rr = (np.arange(d.shape[0]) + 0.5) / b - 0.5
                cc = (np.arange(d.shape[1]) + 0.5) / b - 0.5
                trend = ndimage.map_coordinates(coarse, np.meshgrid(rr, cc, indexing="ij"), order=1,
                                                mode="nearest").astype(np.float32)
        rel = d - trend
        below = rel[ground & (rel <= 0)]
        sig = 1.4826 * float(np.median(-below)) if below.size else float("nan")
        if threshold is None:
            thr = k * max(float(sigma_expected), sig if np.isfinite(sig) else 0.0)
        with np.errstate(invalid="ignore"):
            ground = np.isfinite(d) & (rel <= thr)
    return trend, float(thr), sig


def object_mask(dh, valid, sigma_expected, threshold, object_size_cells, k=3.0, return_trend=False):
    """Mask of the cells whose ``dh`` exceeds its ground trend (:func:`ground_trend`).

    Returns
    -------
    mask : ndarray uint8
        1 object (``dh - trend > threshold``), 2 low (``< -threshold``), 0 ground, 255 not
        ``valid``.
    threshold, sigma_data : float
    trend : ndarray float32
        Only with ``return_trend``: the ground trend.
    """
    trend, thr, sig = ground_trend(dh, valid, object_size_cells, sigma_expected, threshold, k)
    d = np.where(np.isfinite(dh), dh, trend)
    rel = d - trend
    mask = np.full(d.shape, NODATA, np.uint8)
    mask[valid] = GROUND
    mask[valid & (rel > thr)] = OBJECT
    mask[valid & (rel < -thr)] = LOW
    return (mask, thr, sig, trend) if return_trend else (mask, thr, sig)


def _window_residual(a, b, rr, cc, disp, half, centred=False):
    """Squared difference of ``a`` and ``b`` over the best small window containing a cell.

    ``disp = (dca, dra, dcb, drb)`` per candidate cell: where a point of the cell's
    neighbourhood appears in ``a`` and in ``b`` (cells). For each of the ``(2 half + 1)^2``
    windows of side ``2 half + 1`` that contain the cell (shiftable windows), the mean of
    ``(a - b)^2`` (``centred``: of ``(a - b - mean(a - b))^2``, free of a radiometric offset);
    the smallest of them (NaN where no window is seen whole).
    """
    dca, dra, dcb, drb = disp
    w = 2 * half + 1
    r = 2 * half
    D = np.empty((2 * r + 1, 2 * r + 1, rr.size), np.float64)
    for i in range(-r, r + 1):
        for j in range(-r, r + 1):
            va = ndimage.map_coordinates(a, [rr + i + dra, cc + j + dca], order=1, mode="constant", cval=np.nan)
            vb = ndimage.map_coordinates(b, [rr + i + drb, cc + j + dcb], order=1, mode="constant", cval=np.nan)
            D[i + r, j + r] = va - vb
    best = np.full(rr.size, np.inf)
    for i in range(w):
        for j in range(w):
            sub = D[i:i + w, j:j + w].reshape(w * w, -1)
            if centred:
                sub = sub - np.mean(sub, axis=0)
            s = np.mean(sub * sub, axis=0)                # NaN when a pixel is unseen
            best = np.where(s < best, s, best)
    return np.where(np.isfinite(best), best, np.nan)


def settle_boundary(a, b, is_object, dh, trend, valid, displacement, radius, half=1, chunk=1 << 17):
    """Decide the cells along the object outlines by testing the two heights they may have.

    A correlation window of side ``2 * radius + 1`` that straddles an outline measures
    whichever surface fills most of it (a shiftable window may even prefer the ground's
    side), so the outline of the object mask wanders by up to ``radius`` cells both ways. A
    cell within ``radius`` of the outline with object measurements in its window can carry
    one of two heights: the object's (median ``dh`` of the object cells of that window) or
    the ground's (median of its ground cells, else the trend). For each, the two
    orthophotos are sampled where that height puts the cell and its neighbours, and the
    best of the small windows of side ``2 * half + 1`` containing the cell (shiftable, so
    one can lie wholly on the cell's own side of the outline) gives the mean squared
    difference ``(a - b)^2``; the height under which the orthophotos agree better decides
    the cell (the maximum-likelihood choice under Gaussian image noise). A cell is decided
    only when the two heights put its images at least a cell apart relative to each other;
    closer, their windows overlap and the test cannot tell them apart.

    Parameters
    ----------
    a, b : ndarray
        The orthophotos (grey, NaN = unseen).
    is_object : ndarray of bool
        Current object mask.
    dh : ndarray
        Measured corrections (NaN = none).
    trend : ndarray
        The ground trend of ``dh`` (:func:`ground_trend`).
    valid : ndarray of bool
        Cells to decide.
    displacement : callable
        ``displacement(h) -> (dca, dra, dcb, drb)``: for an array ``h`` of height errors per
        cell, where a point of the cell appears in ``a`` and ``b`` relative to the cell
        (cells, column and row).
    radius : int
        Half the matcher's window.
    half : int
        Half the side of the test windows.
    chunk : int
        Candidate cells per batch (bounded memory).

    Returns
    -------
    ndarray of bool
        The object mask with the outline cells decided.
    """
    obj = np.asarray(is_object, bool) & valid
    gnd = ~obj & valid
    size = 2 * int(radius) + 1
    fin = np.isfinite(dh)
    box = np.ones((size, size), bool)
    o_meas = np.where(obj & fin, dh, np.nan).astype(np.float32)
    g_meas = np.where(gnd & fin, dh, np.nan).astype(np.float32)
    cand = (valid & ndimage.binary_dilation(np.isfinite(o_meas), box)
            & ndimage.binary_dilation(gnd, box))
    new = obj.copy()
    if not cand.any():
        return new
    rr_all, cc_all = np.nonzero(cand)
    h_obj = np.zeros(dh.shape)
    h_gnd = np.zeros(dh.shape)
    for k0 in range(0, rr_all.size, chunk):             # the two medians at the candidates only
        cells = (rr_all[k0:k0 + chunk], cc_all[k0:k0 + chunk])
        h_obj[cells] = nan_median_at(o_meas, cells, size)
        g = nan_median_at(g_meas, cells, size)
        h_gnd[cells] = np.where(np.isfinite(g), g, np.asarray(trend)[cells])
    d_obj = displacement(h_obj)
    d_gnd = displacement(h_gnd)
    a = np.asarray(a, np.float32)
    b = np.asarray(b, np.float32)
    for k0 in range(0, rr_all.size, chunk):
        rr, cc = rr_all[k0:k0 + chunk], cc_all[k0:k0 + chunk]
        p1 = [np.asarray(x)[rr, cc] for x in d_obj]
        p0 = [np.asarray(x)[rr, cc] for x in d_gnd]
        # relative displacement of the two images under each height, in cells
        sep = np.hypot((p1[2] - p1[0]) - (p0[2] - p0[0]), (p1[3] - p1[1]) - (p0[3] - p0[1]))
        t = sep >= 1.0
        rr, cc, p1, p0 = rr[t], cc[t], [x[t] for x in p1], [x[t] for x in p0]
        s_obj = _window_residual(a, b, rr.astype(float), cc.astype(float), p1, half)
        s_gnd = _window_residual(a, b, rr.astype(float), cc.astype(float), p0, half)
        decided = np.isfinite(s_obj) & np.isfinite(s_gnd)
        new[rr[decided], cc[decided]] = (s_obj < s_gnd)[decided]
    return new


def agreement_bound(noise_var, half, tail=1.35e-3):
    """The largest offset-free mean square of ``a - b`` over a window that noise alone explains.

    Over a window of ``n = (2 half + 1)**2`` cells where two orthophotos show the same ground,
    ``a - b`` is noise of variance ``noise_var``; its sum of squares about the window's mean
    over ``noise_var`` is chi-square with ``n - 1`` degrees of freedom. The bound is the
    quantile exceeded with probability ``tail`` (default 1.35e-3, the one-sided 3 sigma tail),
    divided by ``n``.

    Parameters
    ----------
    noise_var : float
        Variance of ``a - b`` where they agree.
    half : int
        Half the side of the window.
    tail : float
        Probability that agreeing windows exceed the bound.

    Returns
    -------
    float
    """
    if not 0.0 < tail < 1.0:
        raise ValueError("tail must lie in (0, 1), got {!r}".format(tail))
    n = (2 * int(half) + 1) ** 2
    return float(noise_var) * 2.0 * float(special.gammainccinv((n - 1) / 2.0, tail)) / n   # chi2.isf(tail, n - 1) / n


def window_variance(d, w):
    """Variance of the differences ``d`` of two orthophotos in the ``w`` x ``w`` window centred
    on each cell (float32), +inf where the window is not whole (a NaN difference in it, or the
    array's edge): the spread :func:`agree_at_height` bounds.

    Examples
    --------
    >>> d = np.zeros((5, 5), np.float32); d[2, 2] = 3.0
    >>> v = window_variance(d, 3)
    >>> round(float(v[2, 2]), 4), bool(np.isinf(v[0, 0]))
    (0.8889, True)
    """
    fin = np.isfinite(d)
    d0 = np.where(fin, d, np.float32(0))
    full = ndimage.uniform_filter(fin.astype(np.float32), w, mode="constant") > 1 - 1e-4
    m1 = ndimage.uniform_filter(d0, w, mode="constant")
    m2 = ndimage.uniform_filter(d0 * d0, w, mode="constant")
    return np.where(full, m2 - m1 * m1, np.inf).astype(np.float32)


def agree_at_height(a, b, h, displacement, noise_var, half=2, tail=1.35e-3, where=None):
    """Where the orthophotos agree, within their noise, at the heights ``h``.

    A surface point seen by both cameras appears in ``a`` and ``b`` where its height puts
    it, and the two images agree there up to their noise: over a window of ``n = (2 half +
    1)^2`` cells the offset-free mean square of ``a - b``, times ``n / var(a - b)``, follows a
    chi-square law with ``n - 1`` degrees of freedom. A cell agrees when the best of the
    windows containing it (shiftable, so one can lie wholly on the cell's side of an outline)
    stays below that law's upper ``tail`` quantile (the one-sided 3 sigma share by default).
    Each cell of a window is sampled where its own ``h`` puts it (``h`` smooth over a
    window: the object's height near it). Where the cell is no surface point at that
    height (ground hidden from one camera beside a wall, which one orthophoto shows as the
    wall's roof), the images disagree by about twice the texture's variance.

    Parameters
    ----------
    a, b : ndarray
        The orthophotos (grey, NaN = unseen).
    h : ndarray
        Height error tested per cell (NaN = none: no window through the cell is tested).
    displacement : callable
        ``displacement(h) -> (dca, dra, dcb, drb)``: where a point of each cell appears in
        ``a`` and ``b`` relative to the cell (cells, column and row), as for
        :func:`settle_boundary`.
    noise_var : float
        Variance of ``a - b`` where they agree (twice an orthophoto's noise variance).
    half : int
        Half the side of the test windows.
    where : ndarray of bool, optional
        The cells to test (the work is confined to their bounding box); default all.

    Returns
    -------
    agree : ndarray of bool
    tested : ndarray of bool
        Cells with a window seen whole in both images (elsewhere the test cannot be made:
        the height puts the cell's images off an orthophoto).
    """
    bound = agreement_bound(noise_var, half, tail)
    h = np.asarray(h, np.float64)
    agree = np.zeros(h.shape, bool)
    tested = np.zeros(h.shape, bool)
    if where is None:
        where = np.ones(h.shape, bool)
    rows, cols = np.nonzero(where.any(axis=1))[0], np.nonzero(where.any(axis=0))[0]
    if rows.size == 0:
        return agree, tested
    w = 2 * int(half) + 1
    m = 2 * w                                   # the windows through a cell reach 2 * half cells
    r0, r1 = max(0, rows[0] - m), min(h.shape[0], rows[-1] + m + 1)
    c0, c1 = max(0, cols[0] - m), min(h.shape[1], cols[-1] + m + 1)
    box = (slice(r0, r1), slice(c0, c1))
    ok = np.isfinite(h)
    dca, dra, dcb, drb = (np.asarray(x)[box] for x in displacement(np.where(ok, h, 0.0)))
    rr, cc = np.indices((r1 - r0, c1 - c0), dtype=np.float64)
    rr += r0
    cc += c0
    va = ndimage.map_coordinates(np.asarray(a, np.float32), [rr + dra, cc + dca], order=1, mode="constant", cval=np.nan)
    vb = ndimage.map_coordinates(np.asarray(b, np.float32), [rr + drb, cc + dcb], order=1, mode="constant", cval=np.nan)
    d = np.where(ok[box], va - vb, np.nan).astype(np.float32)
    best = ndimage.minimum_filter(window_variance(d, w), w, mode="constant", cval=np.inf)
    agree[box] = (best <= bound) & where[box]
    tested[box] = np.isfinite(best) & where[box]
    return agree, tested


def close_mask(mask, window):
    """Close the objects of a mask (codes) over ``window // 2 + 1`` cells.

    The matcher resolves no gap narrower than about half its window (as
    :func:`split_significant` finds no narrower detail), so ground gaps and notches that
    narrow inside or between objects are closed; only cells seen by two frames change.
    """
    side = int(window) // 2 + 1
    valid = mask != NODATA
    obj = mask == OBJECT
    new = ndimage.binary_closing(obj, structure=np.ones((side, side), bool)) & valid & ~obj
    out = mask.copy()
    out[new] = OBJECT
    return out


def order_reversed(mask, window):
    """Whether a pair's mask reads as if its two orthophotos were given in the wrong order.

    Giving A's camera to B and B's to A (or the base direction turned by 180 deg) turns
    the sign of every parallax, so every dh: objects come out as low cells below the DEM
    and the DEM corrected is pulled down into the ground. Objects stand above the ground
    and low cells are blunders, so a mask holding more low cells than object cells, and
    at least one matching window's area of them (the smallest patch the matcher resolves,
    :func:`close_mask`), says the order is reversed.

    Returns
    -------
    (bool, int, int)
        The verdict, the low cells and the object cells.
    """
    low = int(np.count_nonzero(mask == LOW))
    obj = int(np.count_nonzero(mask == OBJECT))
    return low > obj and low >= int(window) ** 2, low, obj
