"""Area-based matching: normalised cross-correlation along one direction, vectorised.

Luong Chinh Ke (2002, section 2.3) and Norvelle (1995) measure the residual parallax
between two orthophotos by area correlation: for every cell, the window of orthophoto A is
compared with windows of orthophoto B displaced along the base direction, and the
displacement with the highest normalised cross-correlation (NCC) is the parallax. Here:

* NCC for all cells at once, one integer shift at a time, from box filters (window sums of
  ``a, b, a^2, b^2, ab``), NaN cells excluded from the sums;
* optional *shiftable windows* (the best NCC over the windows containing the cell), which
  keeps object edges sharp;
* the volume of NCC over all shifts is never held: its planes come one shift at a time and
  running winners (maximum and first index, as ``argmax``) are kept seen from A, seen from B
  and for the symmetric anchor (with the neighbouring planes of its peak), so memory does
  not grow with the search range;
* a left-right consistency check from the same NCC planes (the best shift seen from A and
  the best shift seen from B must agree), a correlation threshold, and rejection of peaks
  at the end of the search range;
* sub-pixel refinement by a parabola through the NCC peak, and for orthophotos optionally
  by least-squares matching (a windowed Gauss-Newton solve of the shift with a radiometric
  offset, symmetric in A and B).

:func:`match_rectified` is the classic 1-D disparity of a rectified stereo pair (a test of
the matcher on its own); :func:`match_along` matches two orthophotos along any direction.
"""
import numpy as np
from scipy import ndimage

__all__ = ["ncc_volume", "match_rectified", "match_along", "MatchResult", "check_min_corr"]

_BAD = -2.0   # NCC value of "no correlation computed" (below any true NCC)


class MatchResult(dict):
    """Result of :func:`match_along` / :func:`match_rectified` (a dict with attribute access).

    Keys: ``disparity`` (float32, NaN where rejected), ``corr`` (float32 peak NCC, NaN where
    not computed), ``valid`` (bool), ``info`` (dict of counts and parameters).
    """
    __getattr__ = dict.__getitem__


def _shift_cols(arr, s, fill):
    """``out[:, j] = arr[:, j + s]`` (``fill`` outside)."""
    out = np.full_like(arr, fill)
    n = arr.shape[1]
    if s >= 0:
        if s < n:
            out[:, :n - s] = arr[:, s:]
    else:
        if -s < n:
            out[:, -s:] = arr[:, :n + s]
    return out


def _shift_cols_flat(arr, s, fill):
    """:func:`_shift_cols` of a C-contiguous 2-D array by one copy of its flattened rows."""
    rows, n = arr.shape
    if abs(s) >= n:
        return np.full_like(arr, fill)
    out = np.empty_like(arr)
    fo, fa = out.reshape(-1), arr.reshape(-1)
    if s >= 0:
        fo[:fo.size - s] = fa[s:]                     # out[:, j] = arr[:, j + s]
        out[:, n - s:] = fill
    else:
        fo[-s:] = fa[:fa.size + s]
        out[:, :-s] = fill
    return out


def _check_pair(a, b):
    a = np.asarray(a, dtype=np.float32)
    b = np.asarray(b, dtype=np.float32)
    if a.ndim != 2 or b.ndim != 2:
        raise ValueError(f"images must be 2-D single bands; got shapes {a.shape} and {b.shape}. "
                         "Pass one band (or the mean of the bands).")
    if a.shape != b.shape:
        raise ValueError(f"images must be on the same grid; got shapes {a.shape} and {b.shape}. "
                         "Resample both orthophotos to the DEM grid.")
    return a, b


def check_min_corr(min_corr, name="min_corr"):
    """``min_corr`` as a float in 0 .. 1 (1 excluded); ValueError naming ``name`` otherwise.

    A normalised cross-correlation lies in -1 .. 1 and reaches 1 only for identical windows:
    a threshold of 1 or more keeps no match and measures nothing, without a word (2.0 gave an
    empty result); a negative one accepts windows that do not look alike at all."""
    value = float(min_corr)
    if not 0.0 <= value < 1.0:
        raise ValueError(f"{name} must be in 0 .. 1 (1 excluded); got {value:g}. A correlation of exactly 1 is "
                         "reached only by identical windows, never by two orthophotos of one scene, so no match "
                         "would be kept and nothing measured: choose a value below 1 (default 0.6).")
    return value


def _check_window(window):
    window = int(window)
    if window < 3 or window % 2 == 0:
        raise ValueError(f"window must be an odd number of cells >= 3; got {window}.")
    return window


def ncc_volume(a, b, shifts, window, *, shiftable=0, min_fill=0.6, var_floor=None):
    """NCC of the window of ``a`` at column ``j`` with the window of ``b`` at ``j + s``.

    Parameters
    ----------
    a, b : ndarray (rows, cols) float
        Images on the same grid; NaN = invalid.
    shifts : sequence of int
        Column shifts ``s``.
    window : int
        Odd window size in cells.
    shiftable : int
        If > 1, replace each NCC by the maximum over the ``shiftable`` x ``shiftable``
        neighbourhood (shiftable windows: the best window that contains the cell).
    min_fill : float
        Minimum share of valid cell pairs in a window.
    var_floor : float, optional
        Windows with less variance are flat (no match); default 1e-4 of the variance of ``a``.

    Returns
    -------
    ndarray of float32, (len(shifts), rows, cols)
        NCC in [-1, 1]; ``-2`` where it could not be computed (too few valid cells, no texture).
        The matchers do not hold this volume: they take its planes one shift at a time.
    """
    a, b = _check_pair(a, b)
    vol = np.empty((len(shifts),) + a.shape, np.float32)
    for k, plane in enumerate(_ncc_planes(a, b, shifts, window, shiftable=shiftable, min_fill=min_fill,
                                          var_floor=var_floor)):
        vol[k] = plane
    return vol


class _BoxMean:
    """Window means of float32 grids of one shape, zero outside (``uniform_filter``, ``constant``).

    The box filters of the NCC and of the least-squares matching: ``window`` shifted views
    summed in float32 along each axis (columns, then rows) on a zero-padded copy, every
    view contiguous (along the rows on the flattened padded grid: a padded row holds the
    whole reach of its cells), then scaled by ``1 / window^2``. The same values as
    ``ndimage.uniform_filter(x, window, mode="constant")`` to float32 rounding (a sum of
    ``window`` float32 terms per axis, where that filter keeps a float64 running mean per
    line and rounds between the axes), two to three times faster. The buffers are kept
    between calls: one instance per grid shape.
    """

    def __init__(self, shape, window):
        self.w, self.h = int(window), int(window) // 2
        self.rows, self.cols = rows, cols = shape
        self.width = cols + 2 * self.h
        self.pad = np.zeros((rows + 2 * self.h, self.width), np.float32)
        self.down = np.zeros(rows * self.width, np.float32)
        self.across = np.zeros(rows * self.width, np.float32)
        self.scale = np.float32(1.0 / (self.w * self.w))

    def __call__(self, x, out=None):
        w, h, rows, cols, width = self.w, self.h, self.rows, self.cols, self.width
        pad = self.pad
        pad[h:h + rows, h:h + cols] = x
        _window_sums(pad, w, self.down.reshape(rows, width))        # over the window's rows
        n = rows * width
        _window_sums(self.down, w, self.across[h:n - h])           # then over its columns
        if out is None:
            out = np.empty((rows, cols), np.float32)
        return np.multiply(self.across.reshape(rows, width)[:, h:h + cols], self.scale, out=out)


def _window_sums(v, w, out):
    """``out[i] = v[i] + ... + v[i + w - 1]`` along the first axis, by doubling.

    Sums of runs of 1, 2, 4 ... entries, then the runs of the binary digits of ``w`` one
    after the other (four additions for ``w = 7`` instead of six).
    """
    m = v.shape[0]
    runs, r, run = {1: v}, v, 1
    while 2 * run <= w:
        r = np.add(r[:-run], r[run:])
        run *= 2
        runs[run] = r
    size = m - w + 1
    rest = [q for q in sorted(runs, reverse=True) if q < run and w & q]
    if not rest:
        np.copyto(out, r[:size])
    off = run
    for i, q in enumerate(rest):
        if i == 0:
            np.add(r[:size], runs[q][off:off + size], out=out)
        else:
            out += runs[q][off:off + size]
        off += q
    return out


def _max_filter_nearest(x, size):
    """``ndimage.maximum_filter(x, size, mode="nearest")`` of a 2-D array by shifted maxima.

    The same values (a maximum is exact; near an edge the clipped window's cells are those
    of the edge-padded one, and a maximum does not count repeats), several times faster for
    the small sizes of the shiftable windows: per axis a sparse table (the maxima of runs of
    1, 2, 4 ... cells, then of two overlapping runs: three passes for 5 cells), over
    contiguous memory only. Along the rows the passes run over the flattened array (the
    windows that cross the end of a row, at the first and last ``size // 2`` columns, are
    then taken again within their row): shifted views of whole rows are several times
    slower than contiguous ones.
    """
    h = int(size) // 2
    rows, cols = x.shape
    if h < 1:
        return x.copy()
    if rows <= 2 * h or cols <= 2 * h:
        return _max_filter_shifted(x, h)
    y = _running_max(x, h)
    for i in (*range(h), *range(rows - h, rows)):
        y[i] = x[max(0, i - h):i + h + 1].max(axis=0)
    z = _running_max(y.reshape(-1), h).reshape(rows, cols)
    for j in (*range(h), *range(cols - h, cols)):
        z[:, j] = y[:, max(0, j - h):j + h + 1].max(axis=1)
    return z


def _running_max(v, h):
    """Maxima of ``v[i - h:i + h + 1]`` along the first axis for ``h <= i < len(v) - h``.

    A sparse table: runs of ``L`` cells (the largest power of two <= ``2 h + 1``) by
    doubling, then two overlapping runs per window. The first and last ``h`` entries of the
    result are left for the caller (its windows are clipped there).
    """
    m = v.shape[0]
    r, run = v, 1
    while 2 * run <= 2 * h + 1:
        r = np.maximum(r[:-run], r[run:])
        run *= 2
    out = np.empty_like(v)
    np.maximum(r[0:m - 2 * h], r[2 * h + 1 - run:m - run + 1], out=out[h:m - h])
    return out


def _max_filter_shifted(x, h):
    """:func:`_max_filter_nearest` by ``2 h`` shifted maxima per axis (any shape)."""
    out = x
    for ax in (0, 1):
        sl = (lambda a, b: np.s_[a:b]) if ax == 0 else (lambda a, b: np.s_[:, a:b])  # noqa: E731
        o = out.copy()
        for t in range(1, min(h, out.shape[ax] - 1) + 1):
            np.maximum(o[sl(0, -t)], out[sl(t, None)], out=o[sl(0, -t)])
            np.maximum(o[sl(t, None)], out[sl(0, -t)], out=o[sl(t, None)])
        out = o
    return out


def _ncc_planes(a, b, shifts, window, *, shiftable=0, min_fill=0.6, var_floor=None):
    """The planes of :func:`ncc_volume`, one shift at a time (a generator: no volume held)."""
    a, b = _check_pair(a, b)
    window = _check_window(window)
    va = np.isfinite(a)
    vb = np.isfinite(b)
    a0 = np.where(va, a, 0).astype(np.float32)
    b0 = np.where(vb, b, 0).astype(np.float32)
    # a texture floor: windows with less variance than this are "flat" (no match)
    if var_floor is None:
        gv = float(np.var(a0[va])) if va.any() else 0.0
        var_floor = max(gv * 1e-4, 1e-12)
    box = _BoxMean(a0.shape, window)
    if min_fill >= 1.0:
        planes = _ncc_full_windows(a0, b0, va, vb, shifts, box, var_floor)
    else:
        planes = _ncc_partial_windows(a0, b0, va, vb, shifts, box, var_floor, min_fill)
    for plane in planes:
        if shiftable and shiftable > 1:
            m = _max_filter_nearest(plane, int(shiftable))
            m[~(plane > _BAD)] = _BAD                 # a new array: = np.where(plane > _BAD, m, _BAD)
            plane = m.astype(np.float32, copy=False)
        yield plane


def _ncc_partial_windows(a0, b0, va, vb, shifts, box, var_floor, min_fill):
    """NCC planes over the valid cell pairs of each window (at least ``min_fill`` of it)."""
    for s in shifts:
        bs = _shift_cols(b0, int(s), 0.0)
        w = (va & _shift_cols(vb, int(s), False)).astype(np.float32)
        n = box(w)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / np.maximum(n, 1e-6)
            aw = a0 * w
            bw = bs * w
            ma = box(aw) * inv
            mb = box(bw) * inv
            vara = box(aw * a0) * inv - ma * ma
            varb = box(bw * bs) * inv - mb * mb
            cov = box(aw * bs) * inv - ma * mb
            ncc = cov / np.sqrt(np.maximum(vara * varb, 1e-30))
        ok = (n >= min_fill) & (vara > var_floor) & (varb > var_floor) & va
        yield np.where(ok, np.clip(ncc, -1, 1), _BAD).astype(np.float32, copy=False)


def _ncc_full_windows(a0, b0, va, vb, shifts, box, var_floor):
    """NCC planes where both windows are complete (``min_fill = 1``): one box filter per shift.

    With every cell of both windows valid, the means and variances of ``a`` are one box
    filter for all shifts and those of ``b`` shift with ``b``; only the cross term
    ``sum a b_s`` depends on the shift. Same values as the general path on those cells.
    """
    full_a = box(va.astype(np.float32)) > 1 - 1e-4
    full_b = box(vb.astype(np.float32)) > 1 - 1e-4
    ma = box(a0)
    vara = box(a0 * a0) - ma * ma
    mb = box(b0)
    varb = box(b0 * b0) - mb * mb
    ok_a = full_a & (vara > var_floor)
    ok_b = full_b & (varb > var_floor)
    sa = np.sqrt(np.maximum(vara, 0))
    sb = np.sqrt(np.maximum(varb, 0))
    rows, n = a0.shape
    size = a0.size
    # the terms of a shift pair a(j) with b(j + s) of the same row; on the flattened grids
    # (rows one after the other) that is the pair of flat indices i, i + s: contiguous views,
    # several times faster than the 2-D column slices. The pairs that cross a row end are
    # the columns without a partner (jo), which take 0 (product) and _BAD (NCC) afterwards.
    fa, fb, fma, fmb, fsa, fsb, foa, fob = (v.reshape(-1) for v in (a0, b0, ma, mb, sa, sb, ok_a, ok_b))
    prod = np.zeros_like(a0)
    fprod = prod.reshape(-1)
    summed = np.empty_like(a0)
    fsum = summed.reshape(-1)
    num = np.empty(size, np.float32)
    den = np.empty(size, np.float32)
    ok = np.empty(size, bool)
    for s in shifts:
        s = int(s)
        plane = np.full(a0.shape, _BAD, np.float32)
        if abs(s) >= n:
            yield plane
            continue
        lo, hi = max(0, -s), size - max(0, s)               # flat i with i + s on the grid
        ia, ib = slice(lo, hi), slice(lo + s, hi + s)
        jo = slice(n - s, n) if s >= 0 else slice(0, -s)
        # a(j) b(j + s) with b = 0 beyond its edge: the same sums as the shifted copy of b
        np.multiply(fa[ia], fb[ib], out=fprod[ia])
        prod[:, jo] = 0.0
        box(prod, summed)
        m = hi - lo
        cov, sd, okv = num[:m], den[:m], ok[:m]
        np.multiply(fma[ia], fmb[ib], out=cov)
        np.subtract(fsum[ia], cov, out=cov)
        np.multiply(fsa[ia], fsb[ib], out=sd)
        np.maximum(sd, 1e-15, out=sd)
        with np.errstate(divide="ignore", invalid="ignore"):
            np.divide(cov, sd, out=cov)
        np.logical_and(foa[ia], fob[ib], out=okv)
        np.maximum(cov, -1, out=cov)                # = np.clip(ncc, -1, 1), in place
        np.minimum(cov, 1, out=cov)
        np.copyto(plane.reshape(-1)[ia], cov, where=okv)
        plane[:, jo] = _BAD
        yield plane


def _parabola_offset(c0, cm, cp):
    """Sub-pixel offset of an NCC peak ``c0`` by a parabola through its neighbours ``cm``, ``cp``."""
    den = cm - 2 * c0 + cp
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.where((den < 0) & (cm > _BAD) & (cp > _BAD), 0.5 * (cm - cp) / den, 0.0)
    return np.clip(off, -0.5, 0.5)


def match_rectified(left, right, d_min, d_max, *, window=9, shiftable=5, min_corr=0.3,
                    lr_tolerance=1.0, min_fill=0.6):
    """Disparity of a rectified stereo pair by NCC, left-right check and parabola sub-pixel.

    The convention of Middlebury: a left pixel at column ``x`` is at ``x - d`` in the right
    image. This is the matcher of the orthophoto refinement (Luong Chinh Ke 2002, section
    2.3; Norvelle 1995) on its own, for tests against ground truth.

    Parameters
    ----------
    left, right : ndarray (rows, cols)
        Rectified images (NaN = invalid).
    d_min, d_max : int
        Disparity search range in pixels, inclusive.
    window : int
        Odd NCC window size.
    shiftable : int
        Shiftable-window neighbourhood (0 or 1: off).
    min_corr : float
        Correlation threshold: lower peaks are rejected.
    lr_tolerance : float
        Largest disagreement (pixels) between the left- and right-anchored disparities.

    Returns
    -------
    MatchResult
        ``disparity`` (float32, NaN where rejected), ``corr``, ``valid``, ``info``.
    """
    left, right = _check_pair(left, right)
    min_corr = check_min_corr(min_corr)
    d_min, d_max = int(d_min), int(d_max)
    if d_max < d_min:
        raise ValueError(f"d_max ({d_max}) must be >= d_min ({d_min}).")
    shifts = np.arange(-d_max, -d_min + 1)            # b column = j + s = j - d
    cols = left.shape[1]
    win_a = _RunningBest(left.shape, neighbours=True)       # left-anchored, with the peak's neighbours
    win_b = _RunningBest(left.shape)                        # right-anchored: V[s, y - s]
    for k, plane in enumerate(_ncc_planes(left, right, shifts, window, shiftable=shiftable, min_fill=min_fill)):
        win_a.offer(k, plane)
        sk = int(shifts[k])
        if sk >= 0:
            win_b.offer_cols(k, plane[:, :cols - sk], sk, cols)
        else:
            win_b.offer_cols(k, plane[:, -sk:], 0, cols + sk)
    win_a.finish()
    k, c = win_a.k, win_a.best
    rr, cc = np.indices(k.shape)
    s = shifts[k] + _parabola_offset(c, win_a.before, win_a.after)
    # right-anchored winner: for right column y the left column is y - s
    sb = shifts[win_b.k].astype(np.float32)
    target = np.clip(np.rint(cc + shifts[k]), 0, left.shape[1] - 1).astype(int)
    lr_ok = np.abs(sb[rr, target] - shifts[k]) <= lr_tolerance
    valid = (c > _BAD) & (c >= min_corr) & lr_ok
    disp = np.where(valid, -s, np.nan).astype(np.float32)
    corr = np.where(c > _BAD, c, np.nan).astype(np.float32)
    return MatchResult(disparity=disp, corr=corr, valid=valid,
                       info=dict(window=window, shiftable=shiftable, min_corr=min_corr,
                                 lr_tolerance=lr_tolerance, d_min=d_min, d_max=d_max,
                                 matched_share=float(valid.mean())))


def _row_table(img, grad, valid):
    """What :func:`_sample_rows` gathers at a cell: the values and their steps along the row.

    ``(img, step of img, grad, step of grad)`` as float32 arrays, the step being the
    difference to the next column of the row (0 at the last column, whose next column is
    itself as :func:`_sample_rows` clips: ``v1 - v0`` of the interpolation, so one gather
    per array), and a uint8 code of the validity of the cell (bit 0) and of its next
    column (bit 1).
    """
    out = []
    for x in (img, grad):
        step = np.empty_like(x)
        np.subtract(x[:, 1:], x[:, :-1], out=step[:, :-1])
        step[:, -1] = x[:, -1] - x[:, -1]
        out += [x.reshape(-1), step.reshape(-1)]
    code = valid.astype(np.uint8)
    code[:, :-1] |= valid[:, 1:].view(np.uint8) << 1
    code[:, -1] |= valid[:, -1].view(np.uint8) << 1
    return out, code.reshape(-1)


def _sample_rows(table, cols):
    """Linear interpolation of an image and its gradient at fractional columns of their rows.

    ``table`` from :func:`_row_table`. Columns beyond the edges take the edge value; the
    sample is valid when the cells it draws on are valid and it lies inside the row (the
    shift of the matcher is along rows, so this is the 1-D case of
    ``map_coordinates(order=1)``, several times faster). Returns ``(value, gradient), ok``.
    """
    (x, dx, g, dg), code = table
    rows, n = cols.shape
    c = np.maximum(cols, 0)                          # = np.clip(cols, 0, n - 1)
    np.minimum(c, n - 1, out=c)
    fl = np.floor(c)
    j0 = fl.astype(np.intp)
    f = np.subtract(c, fl, out=c)                    # the fraction of a float32 is exact in float32
    j0 += (np.arange(rows, dtype=np.intp) * n)[:, None]
    i0 = j0.reshape(-1)                              # flat indices: one gather per array
    out = []
    for v0, step in ((x, dx), (g, dg)):
        v = step.take(i0).reshape(rows, n)
        v *= f
        v += v0.take(i0).reshape(rows, n)            # = v0 + f (v1 - v0)
        out.append(v)
    k = code.take(i0).reshape(rows, n)
    ok = (k == 3) | ((k == 1) & (f < 1e-3))           # = valid(j0) & (valid(j1) | f < 1e-3)
    ok &= (cols >= -1e-3) & (cols <= n - 1 + 1e-3)
    return out, ok


def _lsm_refine(a, b, s, valid, window, iterations):
    """Least-squares refinement of a symmetric shift ``s`` (a at j - s/2, b at j + s/2).

    Gauss-Newton on ``sum_w (b(j + s/2) - a(j - s/2) - offset)^2`` for every cell at once
    (window sums by box filters); the radiometric offset is eliminated by centring in the
    window. Returns ``(s, residual, energy)``: the shift, and at that shift the window mean
    of the squared residual ``r = b - a - offset`` and of the squared gradient ``g`` along
    the match direction (the normal equation ``sum g^2`` of the adjustment), for the
    precision of the match (:func:`_decide`).
    """
    cc = np.arange(a.shape[1], dtype=np.float32)[None, :]
    va, vb = np.isfinite(a), np.isfinite(b)
    a0 = np.where(va, a, 0).astype(np.float32)
    b0 = np.where(vb, b, 0).astype(np.float32)
    ta = _row_table(a0, np.gradient(a0, axis=1).astype(np.float32), va)
    tb = _row_table(b0, np.gradient(b0, axis=1).astype(np.float32), vb)
    box = _BoxMean(a.shape, window)
    s = np.where(valid, s, 0).astype(np.float32)
    sq, term = np.empty_like(s), np.empty_like(s)
    for it in range(iterations + 1):
        half = s / 2
        (A, GA), wa = _sample_rows(ta, cc - half)
        (B, GB), wb = _sample_rows(tb, cc + half)
        w = np.logical_and(wa, wb, out=wa).astype(np.float32)
        r = np.subtract(B, A, out=B)
        r *= w                                        # r = (B - A) w
        g = np.add(GA, GB, out=GA)
        g *= 0.5
        g *= w                                        # g = (GA + GB) / 2 w
        n = box(w)
        np.maximum(n, 1e-6, out=n)
        with np.errstate(divide="ignore", invalid="ignore"):
            br, bg = box(r), box(g)
            den = box(np.multiply(g, g, out=sq))
            den -= np.divide(np.square(bg, out=term), n, out=term)          # sum g^2 - (sum g)^2 / n
            if it == iterations:      # statistics at the final shift (per cell of window)
                res = box(np.multiply(r, r, out=sq))
                res -= np.divide(np.square(br, out=term), n, out=term)
                res /= n
                return s, res, np.divide(den, n, out=den)
            num = box(np.multiply(r, g, out=sq))
            num -= np.divide(np.multiply(br, bg, out=term), n, out=term)    # sum r g - sum r sum g / n
            ds = np.divide(np.negative(num, out=num), den, out=num)
            ds[~(den > 1e-12)] = 0.0
        np.maximum(ds, -0.5, out=ds)                  # = np.clip(ds, -0.5, 0.5)
        np.minimum(ds, 0.5, out=ds)
        s += ds


#: Largest number of cells matched at once; bigger inputs are matched in row strips. The NCC
#: volume is never held (its planes are taken one shift at a time), so the working set is
#: about twenty float32 planes of a strip whatever the search range.
MAX_CELLS = 4_000_000


def _match_symmetric_rows(a, b, max_shift, window, shiftable, min_corr, lr_tolerance,
                          lsm_iterations, min_fill, max_cells=None):
    """Row strips of :func:`_match_rows_once` (identical result: strips overlap by the reach)."""
    max_cells = MAX_CELLS if max_cells is None else max_cells
    rows, cols = a.shape
    va = np.isfinite(a)
    gv = float(np.var(a[va])) if va.any() else 0.0
    var_floor = max(gv * 1e-4, 1e-12)
    args = (max_shift, window, shiftable, min_corr, lr_tolerance, lsm_iterations, min_fill, var_floor)
    strip = max(1, int(max_cells // max(1, cols)))
    if strip >= rows:
        return _match_rows_once(a, b, *args)
    names = ("disparity", "corr", "reason", "peak_ok", "residual", "energy")
    # reach of one output row in rows: NCC window, shiftable window, each LSM iteration
    halo = window // 2 + max(int(shiftable), 1) // 2 + lsm_iterations * (window // 2) + 1
    strip = max(strip, 2 * halo + 1)
    out = None
    for r0 in range(0, rows, strip):
        r1 = min(rows, r0 + strip)
        s0, s1 = max(0, r0 - halo), min(rows, r1 + halo)
        part = _match_rows_once(a[s0:s1], b[s0:s1], *args)
        if out is None:
            out = {k: np.empty(a.shape, part[k].dtype) for k in names}
        for k in names:
            out[k][r0:r1] = part[k][r0 - s0:r1 - s0]
    return out


class _RunningBest:
    """Running maximum and its first index over planes offered one at a time (``np.argmax``).

    ``offer(k, plane, lo, hi)`` offers ``plane`` for columns ``lo:hi`` (the other columns
    hold ``_BAD`` there, which never beats the start value ``_BAD``); ties keep the first.
    With ``neighbours``, the plane values at ``k - 1`` and ``k + 1`` of the winner are kept
    too (clipped at the ends of the range, as the parabola of the peak needs them).
    """

    def __init__(self, shape, neighbours=False):
        self.best = np.full(shape, _BAD, np.float32)
        self.k = np.zeros(shape, np.int32)         # shift indices (few): half the traffic of intp
        self.neighbours = neighbours
        if neighbours:
            self.before = np.empty(shape, np.float32)
            self.after = np.empty(shape, np.float32)
            self.prev = None

    def offer(self, k, plane):
        upd = plane > self.best
        np.maximum(self.best, plane, out=self.best)     # = where(upd, plane, best), no masked copy
        np.copyto(self.k, k, where=upd)
        if self.neighbours:
            if k == 0:
                self.before[...] = plane
            else:
                np.copyto(self.after, plane, where=self.k == k - 1)
                np.copyto(self.before, self.prev, where=upd)
            self.prev, self.last = plane, k

    def offer_cols(self, k, plane, lo, hi):
        view = self.best[:, lo:hi]
        upd = plane > view
        np.copyto(view, plane, where=upd)
        np.copyto(self.k[:, lo:hi], k, where=upd)

    def offer_shifted(self, k, plane, s):
        """Offer ``plane[:, j]`` to column ``j + s``: the flat views of whole rows, shifted by ``s``.

        The cells whose ``j + s`` falls off their row land at the start of the next row (or
        the end of the previous one): ``plane`` must hold ``_BAD`` there (the ``|s|`` columns
        of its far side), which never beats a winner.
        """
        fb, fp = self.best.reshape(-1), plane.reshape(-1)
        lo, hi = max(0, -s), fb.size - max(0, s)
        view, p = fb[lo + s:hi + s], fp[lo:hi]
        upd = p > view
        np.maximum(view, p, out=view)
        np.copyto(self.k.reshape(-1)[lo + s:hi + s], k, where=upd)

    def finish(self):
        if self.neighbours and self.prev is not None:
            np.copyto(self.after, self.prev, where=self.k == self.last)
        return self


def _match_rows_once(a, b, max_shift, window, shiftable, min_corr, lr_tolerance,
                     lsm_iterations, min_fill, var_floor):
    """Symmetric matching along rows: disparity ``s`` at cell j means a(j - s/2) ~ b(j + s/2).

    The NCC planes are taken one shift at a time and three running winners kept (seen from
    ``a``, from ``b`` and from the symmetric anchor, with the neighbouring planes of that
    peak): the volume is never held, the result is the one of the argmax over it.
    """
    shifts = np.arange(-max_shift, max_shift + 1)
    rows, cols = a.shape
    rr, cc = np.indices(a.shape)
    win_a = _RunningBest(a.shape)                     # a-anchored: V[s, j]
    win_b = _RunningBest(a.shape)                     # b-anchored: V[s, y - s]
    win_s = _RunningBest(a.shape, neighbours=True)    # symmetric: V[s, m - floor(s/2)]
    for k, plane in enumerate(_ncc_planes(a, b, shifts, window, shiftable=shiftable, min_fill=min_fill,
                                          var_floor=var_floor)):
        s = int(shifts[k])
        win_s.offer(k, _shift_cols_flat(plane, -int(np.floor(s / 2)), _BAD))
        win_a.offer(k, plane)
        if abs(s) < cols:                             # else no cell of b is seen at this shift
            # the cells of a without a partner in b hold no NCC (the plane is ours now)
            plane[:, slice(cols - s, cols) if s >= 0 else slice(0, -s)] = _BAD
            win_b.offer_shifted(k, plane, s)
    win_s.finish()
    ka, kb, k = win_a.k, win_b.k, win_s.k
    c = win_s.best
    si = shifts[k]
    # parabola through the peak and its neighbours (k - 1, k + 1, clipped at the ends)
    cm, cp = win_s.before, win_s.after
    s = si + _parabola_offset(c, cm, cp)
    # a distinct peak: the NCC falls to the neighbouring shifts by more than the sampling
    # sd of an NCC of n cells at that level, (1 - c^2) / sqrt(n) (Fisher)
    drop = c - 0.5 * (cm + cp)
    peak_ok = drop >= (1.0 - np.minimum(c * c, 1.0)) / window
    ja = np.clip(cc - np.floor(si / 2).astype(int), 0, cols - 1)
    jb = np.clip(cc + np.ceil(si / 2).astype(int), 0, cols - 1)
    lr_ok = ((np.abs(shifts[ka[rr, ja]] - si) <= lr_tolerance)
             & (np.abs(shifts[kb[rr, jb]] - si) <= lr_tolerance))
    inner = (k > 0) & (k < len(shifts) - 1)
    valid = (c > _BAD) & (c >= min_corr) & lr_ok & inner
    s_lsm, res, energy = _lsm_refine(a, b, s, valid, window, lsm_iterations)
    if lsm_iterations and valid.any():
        # keep the least-squares result where it stays near the correlation peak
        good = np.abs(s_lsm - s) <= 1.0
        s = np.where(good, s_lsm, s)
    corr = np.where(c > _BAD, c, np.nan).astype(np.float32)
    # reasons, kept apart for the decision: 1 low correlation, 2 left-right, 5 edge of range
    base = np.where(c <= _BAD, 1, np.where(~inner, 5, np.where(c < min_corr, 1, np.where(~lr_ok, 2, 0))))
    return dict(disparity=np.where(valid, s, np.nan).astype(np.float32), corr=corr,
                reason=base.astype(np.uint8), peak_ok=peak_ok, residual=res, energy=energy)


#: Decision codes of :func:`match_along` (``reason``).
ACCEPTED = 0
REASONS = {0: "accepted", 1: "low correlation", 2: "left-right disagreement", 3: "flat peak",
           4: "weak texture", 5: "edge of the search range"}
#: Default largest predicted sd of an accepted match, in cells (the expected matching
#: precision of the refinement, ``precision_cells``).
MAX_SIGMA_CELLS = 0.2


def _decide(out, seen, window, max_sigma_cells):
    """Explicit per-cell decision on a match from the matcher's quality measures.

    A match is accepted when its peak correlation reaches ``min_corr``, the matches seen
    from ``a`` and from ``b`` agree (left-right), the NCC peak is distinct (it drops to the
    neighbouring shifts by more than the sampling sd of an NCC, ``(1 - c^2) / sqrt(n)``) and
    the window has texture enough against the noise: the least-squares precision of the
    shift (Foerstner 1984), ``sigma_s^2 = var(r) / sum_w g_s^2``, is at most
    ``max_sigma_cells``. ``var(r)`` is the noise of the residual ``b - a`` estimated once for
    the pair (median over the cells whose correlation, left-right and range tests passed),
    and ``g_s`` the signal
    part of the gradient (the noise adds ``var(r) / 8`` to the mean square of the averaged
    central-difference gradient).

    Returns
    -------
    reason : ndarray uint8
    precision : ndarray float32
        Predicted sd of the disparity in cells (NaN where not computed).
    noise : float
        Estimated image noise (sd, grey levels) of one orthophoto.
    """
    reason = np.where(seen, out["reason"], 1).astype(np.uint8)
    res = out["residual"]
    pool = res[(reason == ACCEPTED) & np.isfinite(res)]
    var_r = float(np.median(pool)) if pool.size else float("nan")
    with np.errstate(divide="ignore", invalid="ignore"):
        signal = out["energy"] - var_r / 8.0
        precision = np.where(signal > 0, np.sqrt(var_r / (np.maximum(signal, 1e-30) * window * window)),
                             np.inf).astype(np.float32)
    precision = np.where(np.isfinite(out["corr"]), precision, np.nan).astype(np.float32)
    reason[(reason == ACCEPTED) & ~out["peak_ok"].astype(bool)] = 3
    with np.errstate(invalid="ignore"):
        reason[(reason == ACCEPTED) & ~(precision <= max_sigma_cells)] = 4
    return reason, precision, float(np.sqrt(max(var_r, 0.0) / 2.0)) if np.isfinite(var_r) else float("nan")


def _rotation_grid(shape, u):
    """Sampling grid of a frame whose rows run along ``u = (du_col, du_row)`` (unit)."""
    rows, cols = shape
    half = 0.5 * np.hypot(rows, cols)
    n = int(np.ceil(2 * half)) + 3
    o_c, o_r = (cols - 1) / 2.0, (rows - 1) / 2.0
    q = np.arange(n) - (n - 1) / 2.0                               # along u (new columns)
    p = np.arange(n) - (n - 1) / 2.0                               # along normal (new rows)
    nv = (-u[1], u[0])
    C = o_c + q[None, :] * u[0] + p[:, None] * nv[0]
    R = o_r + q[None, :] * u[1] + p[:, None] * nv[1]
    return C, R, (o_c, o_r, n, nv)


def match_along(a, b, direction, max_shift, *, window=7, shiftable=5, min_corr=0.5,
                lr_tolerance=1.0, lsm_iterations=3, min_fill=1.0, max_sigma_cells=MAX_SIGMA_CELLS):
    """Parallax of orthophoto ``b`` against ``a`` along ``direction`` by NCC (and LSM).

    The matching of two orthophotos along the base in Luong Chinh Ke (2002, section 2.3)
    and Norvelle (1995): for every cell, the window of A and the window of B are slid in
    opposite directions along ``direction``; the shift with the highest NCC, refined to
    sub-pixel by a parabola and least-squares matching, is the parallax. Symmetric: the
    result at cell ``m`` means ``a(m - d u / 2)`` matches ``b(m + d u / 2)``.

    Parameters
    ----------
    a, b : ndarray (rows, cols)
        Orthophotos on the same grid (NaN = not seen).
    direction : (float, float)
        ``(d_col, d_row)`` of the base direction in grid cells (normalised here). Axis
        directions are matched exactly, others on a rotated resampling of both images.
    max_shift : int
        Search range ``[-max_shift, max_shift]`` in cells along ``direction``.
    window : int
        Odd NCC window size in cells.
    shiftable : int
        Shiftable-window neighbourhood (0: off).
    min_corr : float
        Correlation threshold.
    lr_tolerance : float
        Left-right consistency tolerance in cells.
    lsm_iterations : int
        Least-squares sub-pixel iterations (0: parabola only).
    max_sigma_cells : float
        Largest predicted standard deviation of a match (cells) that is accepted (texture
        against noise, see :func:`_decide`).

    Returns
    -------
    MatchResult
        ``disparity`` in cells along ``direction`` (``b`` displaced by ``d * u`` from
        ``a``), ``corr``, ``valid``, ``reason`` (uint8 per cell, :data:`REASONS`: 0 accepted,
        1 low correlation, 2 left-right disagreement, 3 flat peak, 4 weak texture, 5 edge of
        the search range), ``precision`` (predicted sd of the disparity in cells) and
        ``info`` (with ``noise_grey``, the image noise estimated from the pair, and the
        ``shares`` of the cells seen in both images per reason).
    """
    a, b = _check_pair(a, b)
    window = _check_window(window)
    min_corr = check_min_corr(min_corr)
    u = np.asarray(direction, dtype=float).reshape(2)
    nrm = float(np.hypot(*u))
    if not np.isfinite(nrm) or nrm == 0:
        raise ValueError(f"direction must be a non-zero vector (d_col, d_row); got {direction!r}. "
                         "Camera centres at the same place (base B = 0) give no parallax.")
    u = u / nrm
    max_shift = int(max_shift)
    if max_shift < 1:
        raise ValueError(f"max_shift must be >= 1 cell; got {max_shift}.")
    args = (max_shift, window, shiftable, min_corr, lr_tolerance, lsm_iterations, min_fill)
    axis = None
    for key, vec in (("+c", (1, 0)), ("-c", (-1, 0)), ("+r", (0, 1)), ("-r", (0, -1))):
        if np.allclose(u, vec, atol=1e-9):
            axis = key
    if axis is not None:
        fwd = {"+c": lambda x: x, "-c": lambda x: x[:, ::-1],
               "+r": lambda x: x.T, "-r": lambda x: x[::-1, :].T}[axis]
        inv = {"+c": lambda x: x, "-c": lambda x: x[:, ::-1],
               "+r": lambda x: x.T, "-r": lambda x: x.T[::-1, :]}[axis]
        out = _match_symmetric_rows(np.ascontiguousarray(fwd(a)), np.ascontiguousarray(fwd(b)), *args)
        out = {k: inv(v) for k, v in out.items()}
    else:
        C, R, (o_c, o_r, n, nv) = _rotation_grid(a.shape, u)
        ra = ndimage.map_coordinates(a, [R, C], order=1, mode="constant", cval=np.nan)
        rb = ndimage.map_coordinates(b, [R, C], order=1, mode="constant", cval=np.nan)
        out_r = _match_symmetric_rows(ra, rb, *args)
        rr, cc = np.indices(a.shape, dtype=float)
        q = (cc - o_c) * u[0] + (rr - o_r) * u[1] + (n - 1) / 2.0
        p = (cc - o_c) * nv[0] + (rr - o_r) * nv[1] + (n - 1) / 2.0
        out = {}
        for k, v in out_r.items():
            cval = np.nan if v.dtype.kind == "f" else 1
            out[k] = ndimage.map_coordinates(v.astype(np.float32), [p, q], order=0, mode="constant",
                                             cval=cval).astype(v.dtype)
    seen = np.isfinite(a) & np.isfinite(b)
    reason, precision, noise = _decide(out, seen, window, max_sigma_cells)
    v = (reason == ACCEPTED) & np.isfinite(out["disparity"])
    d = np.where(v, out["disparity"], np.nan).astype(np.float32)
    c = out["corr"]
    shares = {name: float(np.count_nonzero(seen & (reason == code)) / max(1, np.count_nonzero(seen)))
              for code, name in REASONS.items()}
    return MatchResult(disparity=d, corr=np.asarray(c, np.float32), valid=v,
                       info=dict(window=window, shiftable=shiftable, min_corr=min_corr,
                                 lr_tolerance=lr_tolerance, max_shift=max_shift,
                                 lsm_iterations=lsm_iterations, direction=tuple(u.tolist()),
                                 max_sigma_cells=max_sigma_cells, noise_grey=noise, shares=shares,
                                 matched_share=float(v.sum() / max(1, seen.sum()))),
                       reason=reason, precision=precision)
