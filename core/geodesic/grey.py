"""Grey morphology of the geodesic filter: running min/max, openings and closings that
ignore nodata, block reduction, and the morphological reconstruction by dilation
(Vincent 1993) with a bounded geodesic reach.

Every function here works on whole arrays (separable passes of contiguous slices); the
3 x 3 and 5 x 5 windows and the reconstruction's dense passes run band by band on the flat
arrays, so each pass reads and writes a raster-sized array about once (memory traffic, not
arithmetic, limits them). The filter's stages (:mod:`.dilation`, :mod:`.scan`,
:mod:`.filter`) call them.
"""
import numpy as np

from ..common import pad_constant, report

#: The reconstruction leaves its dense passes once fewer than 1/this of their cells change.
FRONTIER_RATIO = 256
#: 8-connectivity structure for ``ndimage.label``.
S8 = np.ones((3, 3), bool)
#: Bytes of one band of rows in the banded 3 x 3 passes (a band and its few work rows stay
#: in the L2 cache, so a pass reads and writes each raster-sized array once).
BAND_BYTES = 1 << 18


def _band_rows(width, itemsize):
    """Rows per band of a raster ``width`` cells wide (at least 4)."""
    return max(4, BAND_BYTES // max(1, int(width) * int(itemsize)))


def _neutral(op, pad, dtype):
    """True when ``pad`` never changes ``op`` (outside cells then need no handling)."""
    return ((op is np.minimum and pad == np.inf) or (op is np.maximum and pad == -np.inf)
            or (np.dtype(dtype).kind == "b" and pad == (op is np.minimum)))


def _run3_rows(src, op, out):
    """``out[r, c] = op(src[r, c - 1], src[r, c], src[r, c + 1])`` over the cells that exist.

    ``src`` and ``out`` are distinct C-contiguous 2-D arrays of at least 2 columns. The two
    passes run on the flat arrays (contiguous, vectorised); they mix the last cell of a row
    with the first of the next, so the first and last columns are recomputed after.
    """
    sf, of = src.ravel(), out.ravel()
    op(sf[:-1], sf[1:], out=of[:-1])
    op(of[1:], sf[:-1], out=of[1:])
    op(src[:, 0], src[:, 1], out=out[:, 0])
    op(src[:, -1], src[:, -2], out=out[:, -1])


def filter3x3(a, op, pad, out=None):
    """``op`` (np.minimum / np.maximum) over the 3 x 3 window of every cell, cells outside
    the array counting as ``pad``: the same values as ``rect_filter(a, (3, 3), op, pad)``
    (min and max select one of the window's values; NaN anywhere in it gives NaN either way).

    Banded: the row pass of a band of rows (and the two rows around it) is kept in a buffer
    that stays in the cache, so the array is read once and ``out`` written once.

    Parameters
    ----------
    a : ndarray, 2-D, at least 2 x 2
    op : np.minimum or np.maximum
    pad : scalar
    out : ndarray, optional
        Same shape and dtype as ``a``, not ``a`` itself.
    """
    a = np.ascontiguousarray(a)
    H, W = a.shape
    if out is None:
        out = np.empty_like(a)
    B = _band_rows(W, a.itemsize)
    hb = np.empty((B + 2, W), a.dtype)
    for r0 in range(0, H, B):
        r1 = min(H, r0 + B)
        lo, hi = max(0, r0 - 1), min(H, r1 + 1)
        h = hb[:hi - lo]
        _run3_rows(a[lo:hi], op, h)
        o, i0, n = out[r0:r1], r0 - lo, r1 - r0
        nd = min(n, H - 1 - r0)                   # rows of the band with a row below
        op(h[i0:i0 + nd], h[i0 + 1:i0 + 1 + nd], out=o[:nd])
        if nd < n:
            o[nd:] = h[i0 + nd:i0 + n]
        u = 1 if r0 == 0 else 0                   # rows of the band with a row above
        op(o[u:], h[i0 - 1 + u:i0 - 1 + n], out=o[u:])
    if not _neutral(op, pad, a.dtype):
        for edge in (out[0], out[-1], out[:, 0], out[:, -1]):
            op(edge, pad, out=edge)
    return out


def filter5x5(a, op, pad, out=None):
    """``op`` (np.minimum / np.maximum) over the 5 x 5 window of every cell, cells outside
    the array counting as ``pad``: the same values as two :func:`filter3x3` passes (a
    5-cell window is a 3-cell window of the 3-cell windows), in one banded pass (the array
    is read once and ``out`` written once, no raster-sized intermediate). ``a`` and ``out``
    as in :func:`filter3x3`; the array at least 2 x 2."""
    a = np.ascontiguousarray(a)
    if not _neutral(op, pad, a.dtype):           # a pad that counts: the two passes
        return filter3x3(filter3x3(a, op, pad), op, pad, out)
    H, W = a.shape
    if out is None:
        out = np.empty_like(a)
    B = _band_rows(W, a.itemsize)
    h1 = np.empty((B + 4, W), a.dtype)
    hb = np.empty((B + 4, W), a.dtype)
    for r0 in range(0, H, B):
        r1 = min(H, r0 + B)
        lo, hi = max(0, r0 - 2), min(H, r1 + 2)
        h = hb[:hi - lo]
        _run3_rows(a[lo:hi], op, h1[:hi - lo])   # the 5-cell row windows: 3 of 3
        _run3_rows(h1[:hi - lo], op, h)
        o, n = out[r0:r1], r1 - r0
        o[...] = h[r0 - lo:r0 - lo + n]
        for d in (1, -1, 2, -2):                 # the rows above and below that exist
            s0, s1 = max(r0, -d), min(r1, H - d)
            if s0 < s1:
                op(o[s0 - r0:s1 - r0], h[s0 + d - lo:s1 + d - lo], out=o[s0 - r0:s1 - r0])
    return out


class _DenseWork:
    """Buffers of the dense passes of :func:`reconstruct_by_dilation`, and the pass."""

    def __init__(self, H, W2, dtype):
        self.W2 = W2
        self.B = _band_rows(W2, np.dtype(dtype).itemsize)
        self.hb = np.empty((self.B + 2) * W2, dtype)      # row maxima of a band and its 2 rows
        self.new = np.empty(self.B * W2, dtype)
        self.changed = np.zeros((H + 2) * W2, bool)        # cells changed by the last pass

    def _row_max(self, Rbuf, first, last, out, connectivity):
        """Running max over 3 cells along the padded rows ``first..last`` (8-connectivity),
        or the rows themselves (4-connectivity), into ``out`` (flat)."""
        s, e = first * self.W2, (last + 1) * self.W2
        o = out[:e - s]
        if connectivity == 8:                    # Rbuf[k + 1] is cell k: guards at both ends
            np.maximum(Rbuf[s:e], Rbuf[s + 1:e + 1], out=o)
            np.maximum(o, Rbuf[s + 2:e + 2], out=o)
        else:
            o[...] = Rbuf[s + 1:e + 1]

    def dilate(self, Rbuf, Pf, rows, connectivity):
        """One elementary geodesic dilation of the padded rows ``rows`` (inclusive) of ``R``,
        in place, band by band (Jacobi: every new value from the old ones; the row maxima of
        the two rows above a band are carried over from the previous band, computed before
        it was written). Pad cells stay ``-inf`` (``P`` is ``-inf`` there). Returns the
        number of changed cells and the padded rows that changed."""
        W2, B, hb = self.W2, self.B, self.hb
        Rf = Rbuf[1:-1]
        r0, r1 = rows
        self._row_max(Rbuf, r0 - 1, r0, hb, connectivity)
        n_ch, changed_rows = 0, []
        for a in range(r0, r1 + 1, B):
            b = min(r1 + 1, a + B)               # band rows a .. b-1; row maxima of a-1 .. b
            n = b - a
            self._row_max(Rbuf, a + 1, b, hb[2 * W2:], connectivity)
            new = self.new[:n * W2]
            if connectivity == 8:
                np.maximum(hb[:n * W2], hb[W2:(n + 1) * W2], out=new)
                np.maximum(new, hb[2 * W2:(n + 2) * W2], out=new)
            else:                                # the cross: vertical neighbours, and the row's
                np.maximum(hb[:n * W2], hb[2 * W2:(n + 2) * W2], out=new)
                np.maximum(new, Rbuf[a * W2:b * W2], out=new)
                np.maximum(new, Rbuf[a * W2 + 2:b * W2 + 2], out=new)
                np.maximum(new, hb[W2:(n + 1) * W2], out=new)
            np.minimum(new, Pf[a * W2:b * W2], out=new)
            old = Rf[a * W2:b * W2]
            ch = self.changed[a * W2:b * W2]
            np.greater(new, old, out=ch)         # new >= old everywhere
            k = np.count_nonzero(ch)
            if k:
                n_ch += k
                old[...] = new
                changed_rows.append(np.flatnonzero(ch.reshape(n, W2).any(axis=1)) + a)
            hb[:2 * W2] = hb[n * W2:(n + 2) * W2]
        return n_ch, (np.concatenate(changed_rows) if changed_rows else None)


def reconstruct_by_dilation(marker, mask, *, connectivity=8, max_iter=None, progress=None):
    """Morphological reconstruction by dilation of ``marker`` under ``mask``.

    ``R = sup_n delta^(n)(marker)`` where ``delta(f) = min(dilate_3x3(f), mask)`` is the
    elementary geodesic dilation (Vincent 1993). The iteration runs on the rows between
    the first and the last that changed (dense passes, band by band: Jacobi, every new
    value from the previous iteration's), and on the 8 (4) neighbours of the changed cells
    only once they are few (a vectorised frontier), so it stops early where nothing
    changes. Each iteration is one exact elementary dilation, so ``max_iter`` is the
    geodesic reach whichever way it runs.

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
    N = (H + 2) * W2
    # R and P padded with -inf (nothing outside); R's flat buffer has one more guard cell
    # at each end, so the banded row passes read one cell before and after any row range
    Rbuf = np.empty(N + 2, dtype)
    Rbuf[0] = Rbuf[-1] = -np.inf
    Rf = Rbuf[1:-1]
    R = Rf.reshape(H + 2, W2)
    P = np.empty((H + 2, W2), dtype)
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
    Pf = P.ravel()
    if connectivity == 8:
        offs = np.array([-W2 - 1, -W2, -W2 + 1, -1, 1, W2 - 1, W2, W2 + 1], np.intp)
    else:
        offs = np.array([-W2, -1, 1, W2], np.intp)
    rows = (1, H)               # inclusive interior rows of the dense passes (padded coordinates)
    frontier = None
    stamp = None
    work = None
    it = 0
    while max_iter is None or it < max_iter:
        if progress is not None and (frontier is None or it % 16 == 0):
            report(progress, it / max_iter if max_iter else it / (it + 64.0))
        it += 1
        if frontier is None:                      # dense pass on the rows that may change
            if work is None:                      # reused buffers: no allocation per pass
                work = _DenseWork(H, W2, dtype)
            n_ch, changed_rows = work.dilate(Rbuf, Pf, rows, connectivity)
            if n_ch == 0:
                break
            r0, r1 = rows
            if n_ch * FRONTIER_RATIO < (r1 - r0 + 1) * W:
                frontier = np.flatnonzero(work.changed[r0 * W2:(r1 + 1) * W2]) + r0 * W2
            elif n_ch * 2 < (r1 - r0 + 1) * W:    # shrink the rows to the changes
                rows = (max(changed_rows[0] - 1, 1), min(changed_rows[-1] + 1, H))
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
                rr = frontier // W2
                rows = (max(rr.min() - 1, 1), min(rr.max() + 1, H))
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


def rect_filter(a, size, op, pad, out=None):
    """Separable running ``op`` over a ``size = (rows, cols)`` rectangle.

    3 x 3 and 5 x 5 windows (every full-resolution window of the filter) run as one banded
    pass (:func:`filter3x3`, :func:`filter5x5`), into ``out`` when given (``a``'s shape and dtype,
    C-contiguous, not ``a``: a buffer the caller no longer needs, whose pages are already the
    process's); other windows ignore ``out`` (the result is then a new array)."""
    if a.ndim == 2 and min(a.shape) >= 2 and tuple(size) in ((3, 3), (5, 5)):
        return filter3x3(a, op, pad, out) if tuple(size) == (3, 3) else filter5x5(a, op, pad, out)
    return running_extreme(running_extreme(a, size[1], 1, op, pad), size[0], 0, op, pad)


def fill_nodata(z, valid, value):
    """``z`` with ``value`` at nodata; ``z`` itself when every cell is valid."""
    return z if valid is None or valid.all() else np.where(valid, z, value)


def _hang(a, size, fill):
    """``a`` padded with ``fill`` by the window's half-widths: the centres of the windows
    that hang over the border, each keeping its cells inside the raster."""
    return pad_constant(a, size[0] // 2, size[1] // 2, fill)


def _open_close(z, valid, size, first, second, progress, hanging):
    """``second(first(z))`` by a flat rectangle, nodata ignored (``first`` = np.minimum:
    the opening; np.maximum: the closing). ``hanging``: the windows centred outside the
    raster within their half-width take part too, each with its cells inside the raster
    (all but the four that hold a corner cell alone: one cell is compared with nothing)."""
    out = np.inf if first is np.minimum else -np.inf          # neutral value of ``first``
    a = fill_nodata(z, valid, out)
    if hanging:
        a = _hang(a, size, out)
    e = rect_filter(a, size, first, out)
    if hanging:
        e[0, 0] = e[0, -1] = e[-1, 0] = e[-1, -1] = -out
    if valid is not None and not valid.all():
        e[e == out] = -out
    report(progress, 0.5)
    # the second pass into the first's input when that is this function's own copy (nodata filled, or the hanging
    # windows' padded surface): no new raster-sized array, whose pages the kernel would zero (the same values)
    own = a is not z and a.dtype == e.dtype and a.shape == e.shape and a.flags.c_contiguous
    r = rect_filter(e, size, second, -out, out=a if own else None)
    if hanging:
        rh, rw = size[0] // 2, size[1] // 2
        r = r[rh:rh + z.shape[0], rw:rw + z.shape[1]]
    return r


def grey_opening(z, valid, size, progress=None):
    """Grey opening by a flat rectangle ``size`` (rows, cols); nodata ignored.

    Returns ``-inf`` where the whole window is nodata; ``progress(0.5)`` between the
    erosion and the dilation.
    """
    return _open_close(z, valid, size, np.minimum, np.maximum, progress, False)


def grey_closing(z, valid, size, progress=None, hanging=False):
    """Grey closing by a flat rectangle ``size`` (rows, cols); nodata ignored;
    ``progress(0.5)`` between the dilation and the erosion.

    By default only windows centred in the raster count, so a cell on the border is seen
    by fewer windows than one inside: a ground cell on the last column between two roofs
    is then under the closing by the roofs' height although the ground runs on beyond the
    border. ``hanging=True`` also places the window where it hangs over the border (its
    centre up to half a window outside, its cells inside the raster only): every placement
    of the window that meets the raster in two cells or more.
    """
    return _open_close(z, valid, size, np.maximum, np.minimum, progress, hanging)


def inner_cells(cand, nodata=None):
    """Cells of ``cand`` whose 8 neighbours are all in ``cand`` (outside the raster = not), or
    in ``nodata`` (a boolean array, optional): nodata ends the data as the raster's edge does, so
    a cell whose only neighbours outside a region are nodata is no border of it.

    Examples
    --------
    >>> cand = np.zeros((5, 5), bool)
    >>> cand[1:4, 1:4] = True
    >>> int(inner_cells(cand).sum())
    1
    >>> nodata = np.zeros((5, 5), bool)
    >>> nodata[:, 4] = True                  # the column right of the region is empty
    >>> inner_cells(cand, nodata)[1:4, 3].tolist()
    [False, True, False]
    """
    if nodata is not None and nodata.any():
        return rect_filter(cand | nodata, (3, 3), np.minimum, False) & cand
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
