"""Grey morphology of the geodesic filter: running min/max, openings and closings that
ignore nodata, block reduction and expansion, and the morphological reconstruction by
dilation (Vincent 1993) with a bounded geodesic reach.

Every function here works on whole arrays (separable passes of contiguous slices); the
filter's stages (:mod:`.dilation`, :mod:`.scan`, :mod:`.filter`) call them.
"""
import numpy as np

from ..common import report

#: The reconstruction leaves its dense passes once fewer than 1/this of the box change.
FRONTIER_RATIO = 256
#: 8-connectivity structure for ``ndimage.label``.
S8 = np.ones((3, 3), bool)


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


def reconstruct_by_dilation(marker, mask, *, connectivity=8, max_iter=None, progress=None):
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
    progress : callable, optional
        ``progress(fraction)`` after every dense pass (the share of ``max_iter`` done;
        without ``max_iter`` it approaches 1); it may raise
        :class:`~bare_earth.core.common.Cancelled`.

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
        if progress is not None and (frontier is None or it % 16 == 0):
            report(progress, it / max_iter if max_iter else it / (it + 64.0))
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


def running_extreme(a, size, axis, op, pad):
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


def rect_filter(a, size, op, pad):
    """Separable running ``op`` over a ``size = (rows, cols)`` rectangle."""
    return running_extreme(running_extreme(a, size[1], 1, op, pad), size[0], 0, op, pad)


def fill_nodata(z, valid, value):
    """``z`` with ``value`` at nodata; ``z`` itself when every cell is valid."""
    return z if valid is None or valid.all() else np.where(valid, z, value)


def grey_opening(z, valid, size, progress=None):
    """Grey opening by a flat rectangle ``size`` (rows, cols); nodata ignored.

    Returns ``-inf`` where the whole window is nodata; ``progress(0.5)`` between the
    erosion and the dilation.
    """
    e = rect_filter(fill_nodata(z, valid, np.inf), size, np.minimum, np.inf)
    if valid is not None and not valid.all():
        e[np.isposinf(e)] = -np.inf
    report(progress, 0.5)
    return rect_filter(e, size, np.maximum, -np.inf)


def grey_closing(z, valid, size, progress=None):
    """Grey closing by a flat rectangle ``size`` (rows, cols); nodata ignored;
    ``progress(0.5)`` between the dilation and the erosion."""
    d = rect_filter(fill_nodata(z, valid, -np.inf), size, np.maximum, -np.inf)
    if valid is not None and not valid.all():
        d[np.isneginf(d)] = np.inf
    report(progress, 0.5)
    return rect_filter(d, size, np.minimum, np.inf)


def inner_cells(cand):
    """Cells of ``cand`` whose 8 neighbours are all in ``cand`` (outside = not)."""
    return rect_filter(cand, (3, 3), np.minimum, False)


def window_cells(size_m, dx, dy):
    """Odd window (rows, cols) of about ``size_m`` metres, at least 3 x 3."""
    return (2 * max(1, int(round(size_m / (2 * dy)))) + 1,
            2 * max(1, int(round(size_m / (2 * dx)))) + 1)



def block_reduce(a, f, op, fill):
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


def expand_blocks(c, f, shape):
    """Nearest expansion of a coarse grid by ``f``, cropped to ``shape``."""
    if f == 1:
        return c
    Hc, Wc = c.shape
    out = np.empty((Hc, f, Wc, f), c.dtype)
    out[...] = c[:, None, :, None]
    return out.reshape(Hc * f, Wc * f)[:shape[0], :shape[1]]

