"""RASCOR moving fits and data snooping (Jacobsen 2004, steps 5-7).

Moving fits are computed for every cell at once from windowed moment sums (box filters or
small centred correlations), *leave-one-out*: the tested point is not in its own fit, and
the prediction variance factor ``h = (N^-1)_00`` of the fit on the points actually present
is used in the test ``v / (s sqrt(1/p + h)) > k`` (Baarda's data snooping with ``p`` the
point's weight). Missing neighbours widen ``h``: uneven spacing is handled. Where the
window's points do not determine the model, the point is not tested.
"""
import numpy as np
from scipy import ndimage

from ..common import report, sub_progress
from .kernels import (
    BAND_CELLS,
    HALO_BAND_CELLS,
    block_window,
    centred_moments,
    power_sums,
    row_bands,
    running_mean,
    scratch_arrays,
    solve3_first,
    solve_first_general,
)


def fit_rows(z, w, size, degree):
    """Leave-one-out mean (degree 0) or linear regression (degree 1) along axis 1.

    The same result as :func:`fit_at_centre` for 1-D windows (to rounding), computed in
    bands of rows: the window moments ``M0 = sum w``, ``M1 = sum w k``, ``M2 = sum w k^2``,
    ``Z0 = sum w z``, ``Z1 = sum w z k`` (``k`` the position relative to the centre) come
    from running box means of ``w x^j`` and ``w z x^j`` on absolute positions ``x``
    (float64, O(1) per cell whatever the length), recentred by :func:`centred_moments`; the
    centre is then taken out of ``M0`` and ``Z0`` (its ``k`` is 0).

    ``z`` must be finite wherever ``w`` is 0 (any value). Returns ``zhat, h`` like
    :func:`fit_at_centre`.
    """
    rows, cols = z.shape
    zhat = np.empty(z.shape)
    hh = np.empty(z.shape)
    x = np.arange(cols, dtype=np.float64) - cols // 2
    inv = 1.0 / size
    bands = row_bands(rows, cols)
    buf = np.empty((8, bands[0].stop, cols))         # scratch, reused by every band
    with np.errstate(all="ignore"):
        for b in bands:
            wz, t, u, m0, z0, m1, m2, z1 = (a[:b.stop - b.start] for a in buf)
            wb = w[b]
            np.multiply(wb, z[b], out=wz)
            running_mean(wb, size, 1, out=m0)
            running_mean(wz, size, 1, out=z0)
            if degree == 1:
                np.multiply(wb, x, out=t)
                running_mean(t, size, 1, out=m1)
                t *= x
                running_mean(t, size, 1, out=m2)
                np.multiply(wz, x, out=t)
                running_mean(t, size, 1, out=z1)
                # recentre on each cell (see centred_moments)
                np.multiply(m0, x, out=t)
                np.multiply(m1, 2.0, out=u)
                u -= t
                u *= x
                m2 -= u
                m1 -= t
                np.multiply(z0, x, out=t)
                z1 -= t
            m0 -= np.multiply(wb, inv, out=t)       # leave the centre out (k = 0)
            z0 -= np.multiply(wz, inv, out=wz)
            if degree == 0:
                np.copyto(m0, np.nan, where=m0 <= 1e-9 * inv)     # no point: no fit
                np.divide(z0, m0, out=zhat[b])
                np.divide(inv, m0, out=hh[b])
            else:
                det = np.multiply(m0, m2, out=t)
                np.multiply(det, 1e-9, out=u)
                det -= np.multiply(m1, m1, out=wz)
                np.copyto(det, np.nan, where=det <= u)           # undetermined: no fit
                z0 *= m2
                z0 -= np.multiply(z1, m1, out=z1)
                np.divide(z0, det, out=zhat[b])
                m2 *= inv
                np.divide(m2, det, out=hh[b])
    return zhat, hh


def fit_box_2d(z, w, sizes, degree, out_rows=None, work=None):
    """Leave-one-out horizontal (degree 0) or inclined plane (degree 1) in a moving
    ``rows x cols`` box window, for every cell at once.

    The same result as :func:`fit_at_centre` (to rounding) with few passes over the
    data: separable window sums, first along the columns (axis 0: ``w y^j``, ``w z y^j``
    box means on absolute positions, recentred by :func:`centred_moments`), then along the rows in
    bands (the moments ``sum w kx^p ky^q``, ``p + q <= 2``, and ``sum w z kx^p ky^q``,
    ``p + q <= 1``); the 3 x 3 normal equations are solved by cofactors for the height at
    the centre and ``h = (N^-1)_00``, the centre having been taken out of ``M00``, ``Z00``.

    ``z`` must be finite wherever ``w`` is 0. ``out_rows`` (a slice) limits the result to
    those rows (the others only feed the windows). ``work`` (a dict) keeps the large
    scratch arrays from one call to the next. Returns ``zhat, h`` like
    :func:`fit_at_centre` (views of ``work`` arrays when given).
    """
    sy, sx = sizes
    rows, cols = z.shape
    o0, o1, _ = (out_rows or slice(0, rows)).indices(rows)
    inv = 1.0 / (sy * sx)
    wz, c0, d0, t, c1, c2, d1 = scratch_arrays(work, "box", 7, (rows, cols))
    np.multiply(w, z, out=wz)
    y = (np.arange(rows, dtype=np.float64) - (o0 + o1) // 2)[:, None]
    c0 = running_mean(w, sy, 0, out=c0)[o0:o1]
    d0 = running_mean(wz, sy, 0, out=d0)[o0:o1]
    if degree == 1:
        np.multiply(w, y, out=t)
        c1 = running_mean(t, sy, 0, out=c1)[o0:o1]
        t *= y
        c2 = running_mean(t, sy, 0, out=c2)[o0:o1]
        np.multiply(wz, y, out=t)
        d1 = running_mean(t, sy, 0, out=d1)[o0:o1]
        y = y[o0:o1]
        for b in row_bands(o1 - o0, cols):
            centred_moments(y[b], c0[b], c1[b], c2[b])
            centred_moments(y[b], d0[b], d1[b])
    w, wz = w[o0:o1], wz[o0:o1]
    x = np.arange(cols, dtype=np.float64) - cols // 2
    zhat, hh = scratch_arrays(work, "fit", 2, (o1 - o0, cols))
    bands = row_bands(o1 - o0, cols)
    buf = np.empty((16, bands[0].stop, cols))        # scratch, reused by every band
    with np.errstate(all="ignore"):
        for b in bands:
            (t, u, v, m00, z00, m10, m20, m01, m11, m02, z10, z01, c00, c01, c02,
             small) = (a[:b.stop - b.start] for a in buf)
            running_mean(c0[b], sx, 1, out=m00)
            running_mean(d0[b], sx, 1, out=z00)
            if degree == 1:
                np.multiply(c0[b], x, out=t)
                running_mean(t, sx, 1, out=m10)
                t *= x
                running_mean(t, sx, 1, out=m20)
                np.multiply(c1[b], x, out=t)
                running_mean(c1[b], sx, 1, out=m01)
                running_mean(t, sx, 1, out=m11)
                running_mean(c2[b], sx, 1, out=m02)
                np.multiply(d0[b], x, out=t)
                running_mean(t, sx, 1, out=z10)
                running_mean(d1[b], sx, 1, out=z01)
                # recentre on each cell (see centred_moments)
                np.multiply(m00, x, out=t)
                np.multiply(m10, 2.0, out=u)
                u -= t
                u *= x
                m20 -= u
                m10 -= t
                m11 -= np.multiply(m01, x, out=t)
                z10 -= np.multiply(z00, x, out=t)
            m00 -= np.multiply(w[b], inv, out=t)   # leave the centre out (k = 0)
            z00 -= np.multiply(wz[b], inv, out=t)
            if degree == 0:
                np.copyto(m00, np.nan, where=m00 <= 1e-9 * inv)   # no point: no fit
                np.divide(z00, m00, out=zhat[b])
                np.divide(inv, m00, out=hh[b])
                continue
            # cofactors of N = [[m00, m10, m01], [m10, m20, m11], [m01, m11, m02]]
            np.multiply(m20, m02, out=c00)
            np.multiply(c00, m00, out=small)
            np.abs(small, out=small)
            small *= 1e-9
            c00 -= np.multiply(m11, m11, out=t)
            np.multiply(m11, m01, out=c01)
            c01 -= np.multiply(m10, m02, out=t)
            np.multiply(m10, m11, out=c02)
            c02 -= np.multiply(m20, m01, out=t)
            det = np.multiply(m00, c00, out=v)
            det += np.multiply(m10, c01, out=t)
            det += np.multiply(m01, c02, out=t)
            np.copyto(det, np.nan, where=det <= small)           # undetermined: no fit
            z00 *= c00
            z00 += np.multiply(z10, c01, out=t)
            z00 += np.multiply(z01, c02, out=t)
            np.divide(z00, det, out=zhat[b])
            c00 *= inv
            np.divide(c00, det, out=hh[b])
    return zhat, hh


def fit_at_centre(z, w, sizes, degree, leave_one_out=True, kernels=None):
    """Weighted polynomial fit in a moving window, evaluated at the window's centre.

    Parameters
    ----------
    z, w : ndarray (float64)
        Heights (any value where ``w == 0``) and weights (0 = not in the fits).
    sizes : (int, int) or int
        Window in cells: an int for a 1-D profile along axis 1, ``(rows, cols)`` for 2-D.
    degree : int
        0 mean / horizontal plane, 1 linear / inclined plane, 2 polynomial.
    leave_one_out : bool
        Exclude the centre point from its own fit (prediction residuals).
    kernels : (ndarray, ndarray), optional
        Separable window weights (rows, cols) instead of a box (Gaussian for step 7).

    Returns
    -------
    zhat, h : ndarray
        Fitted height at the centre and the variance factor ``(N^-1)_00``; NaN where the
        window's points do not determine the model (no test there: a lower-degree model
        would be biased on a slope).
    """
    z = np.where(w > 0, z, 0.0)
    two_d = not np.isscalar(sizes)
    if leave_one_out and kernels is None and degree <= 1:
        return fit_box_2d(z, w, sizes, degree) if two_d else fit_rows(z, w, sizes, degree)
    wz = w * z

    def sums(v, px, py=None):
        if kernels is not None:
            ky, kx = kernels
            hx, hy = len(kx) // 2, len(ky) // 2
            out = {}
            top = max(max(px), max(py))
            # the slow axis (0) first: fewer passes along it
            for q in set(py):
                t = ndimage.correlate1d(v, ky * np.arange(-hy, hy + 1.0) ** q, axis=0,
                                        mode="constant", cval=0.0)
                for p in (p for p in set(px) if p + q <= top):
                    out[p, q] = ndimage.correlate1d(t, kx * np.arange(-hx, hx + 1.0) ** p,
                                                    axis=1, mode="constant", cval=0.0)
            return out
        if not two_d:
            return power_sums(v, sizes, px, 1)
        sy, sx = sizes
        ty = power_sums(v, sy, py, 0)             # the slow axis (0) first: fewer passes
        out = {}
        top = max(max(px), max(py))
        for q in set(py):
            ps = [p for p in set(px) if p + q <= top]   # only the moments the model needs
            tx = power_sums(ty[q], sx, ps, 1)
            for p in ps:
                out[p, q] = tx[p]
        return out

    if not two_d:
        m = sums(w, range(2 * degree + 1))
        zz = sums(wz, range(degree + 1))
        if leave_one_out:
            m[0] = m[0] - w
            zz[0] = zz[0] - wz
        with np.errstate(all="ignore"):
            if degree == 0:
                ok = m[0] > 1e-9
                zhat, hh = zz[0] / m[0], 1.0 / m[0]
            elif degree == 1:
                det = m[0] * m[2] - m[1] ** 2
                ok = det > 1e-9 * m[0] * m[2]
                zhat, hh = (zz[0] * m[2] - zz[1] * m[1]) / det, m[2] / det
            else:
                zhat, hh = solve3_first(((m[0], m[1], m[2]), (m[1], m[2], m[3]),
                                          (m[2], m[3], m[4])), (zz[0], zz[1], zz[2]))
                ok = np.isfinite(zhat)
        return np.where(ok, zhat, np.nan), np.where(ok, hh, np.nan)

    # 2-D: monomials x^a y^b with a + b <= degree
    mons = [(a, b) for d in range(degree + 1) for a in range(d, -1, -1) for b in (d - a,)]
    px = range(2 * degree + 1)
    m = sums(w, px, px)
    zz = sums(wz, range(degree + 1), range(degree + 1))
    if leave_one_out:
        m[0, 0] = m[0, 0] - w
        zz[0, 0] = zz[0, 0] - wz
    nu = len(mons)
    M = [[m[mons[i][0] + mons[j][0], mons[i][1] + mons[j][1]] for j in range(nu)]
         for i in range(nu)]
    with np.errstate(all="ignore"):
        if degree == 0:
            ok = m[0, 0] > 1e-9
            zhat, hh = zz[0, 0] / m[0, 0], 1.0 / m[0, 0]
            return np.where(ok, zhat, np.nan), np.where(ok, hh, np.nan)
        if degree == 1:
            return solve3_first(M, [zz[mons[i]] for i in range(3)])
        return solve_first_general(M, [zz[mons[i]] for i in range(6)], 6)


def _snoop(z, zhat, hh, test, s, k, low_weight):
    """Data snooping of prediction residuals ``v = z - zhat``.

    ``v / (s sqrt(1/p + h)) > k`` flags an object (p = 1), ``< -k`` a low blunder with
    the weight factor ``p = low_weight`` of points below the reference. Cells where the
    fit is undetermined (``zhat`` or ``h`` NaN) are not tested: their comparisons are
    False (the caller silences NumPy's warning about them, once for all its bands).

    Returns
    -------
    high, low, below : ndarray of bool
        Objects, low blunders, and the tested cells below their fit (``v < 0``: the
        weight factor applies to them in a next fit).
    """
    ks2 = (k * s) ** 2
    v = np.subtract(z, zhat, dtype=np.float64)
    h = np.maximum(hh, 0.0)                     # NaN stays NaN: no test
    below = v < 0.0
    below &= test
    v *= v
    # v > k s sqrt(1/p + h)  <=>  v^2 > (k s)^2 (1/p + h)  (v > 0, resp. v < 0)
    h *= ks2
    h += ks2
    high = v > h
    high &= test
    high &= ~below
    h += ks2 / low_weight - ks2
    low = v > h
    low &= below
    return high, low, below


def _tiles(rows, cols, halo, halo_cols, cells=None):
    """``[(row slice, column slice)]`` covering a ``rows x cols`` array, for fits of
    windows reaching ``halo`` rows and ``halo_cols`` columns.

    Without a halo, bands of whole rows of :data:`BAND_CELLS` cells; with a row halo,
    bands of whole rows of about ``cells`` (default :data:`HALO_BAND_CELLS`) cells, halo
    included; with a column halo too, tiles of about ``cells`` cells, halos included.
    """
    whole = slice(0, cols)
    if not halo:
        return [(b, whole) for b in row_bands(rows, cols)]
    cells = cells or HALO_BAND_CELLS
    if not halo_cols:
        step = max(2 * halo, cells // max(1, cols) - 2 * halo)
        return [(slice(r0, min(rows, r0 + step)), whole) for r0 in range(0, rows, step)]
    side = int(np.sqrt(cells))
    step_r, step_c = max(2 * halo, side - 2 * halo), max(2 * halo_cols, side - 2 * halo_cols)
    return [(slice(r0, min(rows, r0 + step_r)), slice(c0, min(cols, c0 + step_c)))
            for r0 in range(0, rows, step_r) for c0 in range(0, cols, step_c)]


def fit_and_snoop(z, keep, test, below, fit, s, k, low_weight, *, halo=0, halo_cols=0,
                   tile_cells=None, labels=None, reach_cols=None, work=None, progress=None):
    """Fit every cell by ``fit`` and snoop the cells of ``test`` (:func:`_snoop`), in bands.

    ``fit(z, w, out_rows) -> (zhat, h)`` is a leave-one-out moving fit on float64 arrays
    (``z`` finite, ``w`` the weights: 1 where ``keep``, ``low_weight`` where also
    ``below``, else 0), evaluated on the rows ``out_rows``. It runs on bands of whole rows
    (profile fits along the rows: ``halo`` 0) or on bands of rows with ``halo`` rows above
    and below (window fits of at most ``2 halo + 1`` rows): the same result as one fit of
    the whole arrays, without any full-size float temporary. With ``halo_cols`` too, it
    runs on tiles of about ``tile_cells`` cells with a halo on all sides (:func:`_tiles`;
    for fits whose result at a cell does not depend on where the array starts: the
    polynomial surface, whose bands would take seconds each). With break-line ``labels`` each region
    is fitted on its own points only, the other cells having weight 0 and no test: the regions'
    bounding boxes packed into mosaics (:func:`_snoop_regions`; ``reach_cols``: the columns a fit
    reaches from its cell, default ``halo_cols`` or else ``halo``). ``work``
    (a dict, shared with ``fit``) keeps the band's scratch arrays from band to band.
    ``progress(fraction)`` is called before each band (it may raise ``Cancelled``).

    Returns
    -------
    high, low, below : ndarray of bool
    """
    if labels is not None:
        return _snoop_regions(z, keep, test, below, fit, s, k, low_weight, labels, halo=halo,
                              halo_cols=halo_cols, reach_cols=reach_cols, tile_cells=tile_cells, work=work,
                              progress=progress)
    high = np.zeros(z.shape, bool)
    low = np.zeros(z.shape, bool)
    under = np.zeros(z.shape, bool)
    rows, cols = z.shape
    tiles = _tiles(rows, cols, halo, halo_cols, tile_cells)
    work = {} if work is None else work
    with np.errstate(invalid="ignore"):            # NaN fits are not tested (_snoop)
        for i, (b, bc) in enumerate(tiles):
            report(progress, i / len(tiles))
            r0, r1 = max(0, b.start - halo), min(rows, b.stop + halo)
            c0, c1 = max(0, bc.start - halo_cols), min(cols, bc.stop + halo_cols)
            src = (slice(r0, r1), slice(c0, c1))
            out, out_c = slice(b.start - r0, b.stop - r0), slice(bc.start - c0, bc.stop - c0)
            kb = keep[src]
            zb, wb = scratch_arrays(work, ("band", kb.shape[1]), 2, kb.shape)
            np.copyto(zb, z[src])
            np.copyto(zb, 0.0, where=~kb)            # weight 0 there (NaN must not reach the sums)
            np.copyto(wb, kb)                        # the fit weights
            if below is not None:
                np.copyto(wb, low_weight, where=below[src] & kb)
            zhat, hh = fit(zb, wb, out)
            zhat, hh, zo = zhat[:, out_c], hh[:, out_c], zb[out, out_c]
            tb, hb, lb, ub = test[b, bc], high[b, bc], low[b, bc], under[b, bc]
            for sb in row_bands(*zo.shape):            # in cache-sized pieces
                hb[sb], lb[sb], ub[sb] = _snoop(zo[sb], zhat[sb], hh[sb], tb[sb], s, k, low_weight)
    return high, low, under


#: Cells of a mosaic of break-line regions (:func:`_snoop_regions`), gaps included: its copies and
#: index arrays (about 40 bytes a cell) stay near 40 MB; a region whose shelf alone would exceed
#: it is fitted on its own bounding box.
MOSAIC_CELLS = 1 << 20


def pack_boxes(heights, widths, width, gap_rows, gap_cols, max_cells=None):
    """Shelf packing of boxes into mosaics ``width`` columns wide, each of at most ``max_cells``
    (default :data:`MOSAIC_CELLS`) cells, the boxes at least ``gap_rows`` rows and ``gap_cols`` columns apart.

    The boxes, tallest first, fill shelves from the left; a shelf whose boxes would pass ``width``
    ends, and a mosaic whose next shelf would pass ``max_cells`` ends. A box that does not fit a
    mosaic alone (wider than ``width``, or its shelf beyond ``max_cells``) is not packed.

    Returns
    -------
    mosaic, row, col : ndarray of int
        Each box's mosaic (-1: not packed) and its upper-left cell in it.
    heights_out : ndarray of int
        Each mosaic's rows.

    Examples
    --------
    >>> m, r, c, h = pack_boxes(np.array([2, 3, 1]), np.array([4, 2, 5]), 10, 1, 2)
    >>> m.tolist(), r.tolist(), c.tolist(), h.tolist()
    ([0, 0, 0], [0, 0, 4], [4, 0, 0], [5])
    """
    max_cells = MOSAIC_CELLS if max_cells is None else max_cells
    heights = np.asarray(heights, np.int64)
    widths = np.asarray(widths, np.int64)
    n = heights.size
    mosaic = np.full(n, -1, np.int64)
    row = np.zeros(n, np.int64)
    col = np.zeros(n, np.int64)
    out = []
    fits_alone = (widths <= width) & (heights * width <= max_cells)
    top = x = shelf = 0                      # the current shelf's top row, next column, height
    m = -1
    for i in np.argsort(-heights, kind="stable"):
        if not fits_alone[i]:
            continue
        if m < 0 or x + widths[i] > width:   # a new shelf, in a new mosaic when it would not fit
            below = top + shelf + gap_rows
            if m < 0 or (below + heights[i]) * width > max_cells:
                if m >= 0:
                    out.append(top + shelf)
                m, below = m + 1, 0
            top, x, shelf = below, 0, int(heights[i])
        mosaic[i], row[i], col[i] = m, top, x
        x += int(widths[i]) + gap_cols
    if m >= 0:
        out.append(top + shelf)
    return mosaic, row, col, np.asarray(out, np.int64)


def _snoop_regions(z, keep, test, below, fit, s, k, low_weight, labels, *, halo, halo_cols, reach_cols,
                   tile_cells, work, progress):
    """:func:`fit_and_snoop` of each break-line region of ``labels`` on its own points (the other
    cells weight 0 and no test; regions of fewer than 3 cells are not tested).

    The regions' bounding boxes are packed into mosaics (:func:`pack_boxes`), ``halo`` rows and
    ``reach_cols`` columns apart (no window reaches from one box into another; boxes one cell high
    or wide in mosaics one cell high or wide; for profiles along the rows, ``halo`` 0, each row of a
    region shifted to its box's left edge), each mosaic fitted in one pass: the cost of a region
    is its box's cells, not a call of the fit (terraced hillsides hold thousands of regions). A
    region too large for a mosaic is fitted on its own bounding box. The fits of a window's own
    points do not depend on where the window lies (the polynomial's centred sums bit for bit, the
    planes' and lines' to rounding)."""
    rows, cols = z.shape
    high = np.zeros(z.shape, bool)
    low = np.zeros(z.shape, bool)
    under = np.zeros(z.shape, bool)
    gap_c = int(reach_cols if reach_cols is not None else (halo_cols or halo))
    boxes = ndimage.find_objects(labels)
    count = np.bincount(labels.reshape(-1), minlength=len(boxes) + 1)
    ids = np.array([i + 1 for i, b in enumerate(boxes) if b is not None and count[i + 1] >= 3], np.int64)
    if not ids.size:
        return high, low, under
    r0, r1, c0, c1 = (np.array([getattr(boxes[i - 1][a], e) for i in ids], np.int64)
                      for a, e in ((0, "start"), (0, "stop"), (1, "start"), (1, "stop")))
    h, w = r1 - r0, c1 - c0
    lab = labels.reshape(-1)
    of = np.full(len(boxes) + 1, -1, np.int64)
    of[ids] = np.arange(ids.size)
    sheared = None
    if not halo:
        # profiles along the rows: each row of a region is fitted on its own, so its cells move to
        # the box's left edge row by row (a curved line's box is as wide as its widest row), in the
        # boxes a mosaic may hold
        small = np.zeros(len(boxes) + 1, bool)
        small[ids] = (h * (cols + gap_c) <= MOSAIC_CELLS) | (h == 1) | (w == 1)
        cand = np.flatnonzero(small[lab])
        key = of[lab[cand]] * rows + cand // cols
        order = np.argsort(key, kind="stable")      # each row's cells stay in column order
        key = key[order]
        start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
        stop = np.r_[start[1:], key.size]
        left = cand[order[start]] % cols
        span = cand[order[stop - 1]] % cols - left + 1
        first_row = np.flatnonzero(np.r_[True, key[start[1:]] // rows != key[start[:-1]] // rows])
        widest = np.zeros(ids.size, np.int64)
        widest[key[start[first_row]] // rows] = np.maximum.reduceat(span, first_row)
        w = np.where(small[ids], widest, w)
        edge = np.empty(cand.size, np.int64)
        edge[order] = np.repeat(left, stop - start)
        sheared = (cand, edge)
        del key, order, start, stop, left, span, first_row
    # boxes one cell high (wide) go to mosaics one cell high (wide), all of a box's rows (columns) at
    # the fits' origin as on its own box: the plane of a line's points is then exactly undetermined,
    # not a rounding away from it
    mosaic = np.full(ids.size, -1, np.int64)
    mr, mc = np.zeros(ids.size, np.int64), np.zeros(ids.size, np.int64)
    shapes = []
    for kind in ("row", "column", "box"):
        sel = np.flatnonzero((h == 1) if kind == "row" else (w == 1) & (h > 1) if kind == "column"
                             else (h > 1) & (w > 1))
        if not sel.size:
            continue
        room = MOSAIC_CELLS if kind == "row" else 1 if kind == "column" else cols + gap_c
        m, r, c, mh = pack_boxes(h[sel], w[sel], room, int(halo), gap_c)
        used = np.zeros(mh.size, np.int64)
        np.maximum.at(used, m[m >= 0], (c + w[sel])[m >= 0])
        sizes = list(zip(mh.tolist(), used.tolist()))
        packed = m >= 0
        mosaic[sel[packed]] = m[packed] + len(shapes)
        mr[sel], mc[sel] = r, c
        shapes += sizes
    alone = np.flatnonzero(mosaic < 0)
    cost = np.r_[[a * b for a, b in shapes], (h * w)[alone]].astype(np.float64)
    ends = np.cumsum(cost) / max(1.0, cost.sum())
    starts = np.r_[0.0, ends[:-1]]
    kw = dict(halo=halo, halo_cols=halo_cols, tile_cells=tile_cells, work=work)
    zf, kf, tf = z.reshape(-1), keep.reshape(-1), test.reshape(-1)
    # the cells of the packed regions, mosaic after mosaic, and their places in their mosaics
    packed = np.full(len(boxes) + 1, False)
    packed[ids] = mosaic >= 0
    cells = np.flatnonzero(packed[lab]) if shapes else np.zeros(0, np.int64)
    reg = of[lab[cells]]
    edge = c0[reg] if sheared is None else sheared[1][np.searchsorted(sheared[0], cells)]
    order = np.argsort(mosaic[reg], kind="stable")
    cells, reg, edge = cells[order], reg[order], edge[order]
    bounds = np.searchsorted(mosaic[reg], np.arange(len(shapes) + 1))
    del order, sheared
    for m, shape in enumerate(shapes):
        report(progress, starts[m])
        src, rg, e = (a[bounds[m]:bounds[m + 1]] for a in (cells, reg, edge))
        rr, cc = np.divmod(src, cols)
        dst = (rr - r0[rg] + mr[rg]) * shape[1] + (cc - e + mc[rg])
        del rr, cc, rg, e
        mz = np.zeros(shape, z.dtype)
        mk, mt = np.zeros(mz.shape, bool), np.zeros(mz.shape, bool)
        mz.reshape(-1)[dst] = zf[src]
        mk.reshape(-1)[dst] = kf[src]
        mt.reshape(-1)[dst] = tf[src]
        mb = None
        if below is not None:
            mb = np.zeros(mz.shape, bool)
            mb.reshape(-1)[dst] = below.reshape(-1)[src]
        res = fit_and_snoop(mz, mk, mt, mb, fit, s, k, low_weight, **kw,
                            progress=sub_progress(progress, starts[m], ends[m]))
        for o, r in zip((high, low, under), res):
            o.reshape(-1)[src] = r.reshape(-1)[dst]
    for j, i in enumerate(alone):
        a, e = starts[len(shapes) + j], ends[len(shapes) + j]
        report(progress, a)
        sl = (slice(int(r0[i]), int(r1[i])), slice(int(c0[i]), int(c1[i])))
        inside = labels[sl] == ids[i]
        res = fit_and_snoop(z[sl], keep[sl] & inside, test[sl] & inside, None if below is None else below[sl],
                            fit, s, k, low_weight, **kw, progress=sub_progress(progress, a, e))
        for o, r in zip((high, low, under), res):
            o[sl] |= r
    return high, low, under




def _block_sums(a, q, powers, axis):
    """Sums over blocks of ``q`` cells along ``axis`` (0 or 1 of a 2-D array whose length there is
    a multiple of ``q``) of ``a k^p`` for each ``p`` of ``powers``, ``k`` the cell's offset from its
    block's centre: ``{p: sums}``. Along the rows one matrix product gives every power (a sum over
    a short last axis costs five times as much); down the columns, weighted sums of whole rows."""
    k = np.arange(q, dtype=np.float64) - (q - 1) / 2.0
    powers = list(powers)
    if axis == 1:
        rows, cols = a.shape
        res = a.reshape(-1, q) @ np.stack([k ** p for p in powers], 1)
        res = np.ascontiguousarray(res.T)
        return {p: res[i].reshape(rows, cols // q) for i, p in enumerate(powers)}
    v = a.reshape(a.shape[0] // q, q, a.shape[1])
    out = {}
    for p in powers:
        t = v[:, 0] * k[0] ** p
        for j in range(1, q):
            t += v[:, j] * k[j] ** p if p else v[:, j]
        out[p] = t
    return out


def _absolute_window_sums(sums, pos, n, axis):
    """Window sums of ``n`` blocks along ``axis`` of the block moments ``sums`` ({p: sum w k^p},
    ``k`` about each block's centre ``pos``), about the window's centre block (p <= 2).

    Each block's moments are moved to absolute positions (``sum w (pos + k)^p``), summed over the
    window as a running mean times ``n`` (0 beyond the raster) and recentred on the centre block's
    position (:func:`~.kernels.centred_moments`)."""
    b0 = sums[0]
    out = {0: running_mean(b0, n, axis) * n}
    if 1 in sums:
        a1 = sums[1] + pos * b0
        out[1] = running_mean(a1, n, axis) * n
        if 2 in sums:
            a2 = sums[2] + pos * (2.0 * sums[1] + pos * b0)
            out[2] = running_mean(a2, n, axis) * n
            centred_moments(pos, out[0], out[1], out[2])
        else:
            centred_moments(pos, out[0], out[1])
    return out


def block_fit_model(band, shape, sizes, degree):
    """The weighted least-squares fits of moving windows computed once per block of cells.

    The raster is cut into blocks of ``qy x qx`` cells from its upper-left corner
    (:func:`~.kernels.block_window` of each window side; ``sizes[0] == 1``: profiles along the
    rows, 1-D). The window of a block spans ``ny x nx`` blocks centred on it; its fit (all its
    points, the block's own included) is solved from the blocks' moment sums: the model's
    coefficients about the block's centre and the inverse normal matrix, for :func:`block_fits`
    to evaluate at each cell.

    Parameters
    ----------
    band : callable
        ``band(r0, r1) -> (z, w)``: heights (finite where ``w > 0``) and weights of rows
        ``r0:r1``, float64 (read in bands: no full-size temporary).
    shape : (int, int)
    sizes : (int, int)
        Window in cells (rows, columns).
    degree : int
        0 mean / horizontal plane, 1 linear / inclined plane.

    Returns
    -------
    dict
        ``blocks`` (qy, qx), ``coef`` (the model's coefficients: mean; or height, x-slope[, y-slope]
        at the block's centre, per cell of x and y), ``ginv`` (the entries of ``N^-1`` weighting
        ``1, dx, dy`` and their products: ``g = v^T N^-1 v``), each a coarse array (NaN where the
        window's points do not determine the model).
    """
    sy, sx = sizes
    two_d = sy > 1
    qy, ny = block_window(sy) if two_d else (1, 1)
    qx, nx = block_window(sx)
    rows, cols = shape
    R, C = -(-rows // qy), -(-cols // qx)
    top_w, top_z = (2, 1) if degree else (0, 0)
    keys_w = [(p, q) for p in range(top_w + 1) for q in range(top_w + 1 - p) if two_d or q == 0]
    keys_z = [(p, q) for p in range(top_z + 1) for q in range(top_z + 1 - p) if two_d or q == 0]
    m = {key: np.empty((R, C)) for key in keys_w}
    zz = {key: np.empty((R, C)) for key in keys_z}
    step = qy * max(1, (HALO_BAND_CELLS // 4) // max(1, cols * qy))
    wp = np.zeros((step, C * qx))
    zp = np.zeros((step, C * qx))
    for r0 in range(0, R * qy, step):             # block moments in bands of whole blocks
        r1 = min(rows, r0 + step)
        hb = -(-(r1 - r0) // qy) * qy
        zb, wb = band(r0, r1)
        if hb == r1 - r0 and cols == C * qx:          # whole blocks: no padding
            wv, zv = wb, np.multiply(wb, zb, out=zp[:hb])
        else:
            wp[:hb] = 0.0
            wp[:r1 - r0, :cols] = wb
            zp[:hb] = 0.0
            np.multiply(wb, zb, out=zp[:r1 - r0, :cols])
            wv, zv = wp[:hb], zp[:hb]
        for v, keys, out in ((wv, keys_w, m), (zv, keys_z, zz)):
            xs = _block_sums(v, qx, sorted({p for p, _ in keys}), 1)       # along x, then y
            for p, s in xs.items():
                ys = _block_sums(s, qy, sorted({q for pp, q in keys if pp == p}), 0)
                for q, t in ys.items():
                    out[p, q][r0 // qy:r0 // qy + hb // qy] = t
    X = (np.arange(C) * qx + (qx - 1) / 2.0 - cols // 2)[None, :]
    Y = (np.arange(R) * qy + (qy - 1) / 2.0 - rows // 2)[:, None]
    for src in (m, zz):
        if two_d:                                   # along y: each x-moment's y-moments over the window
            for p in sorted({p for p, _ in src}):
                for q, v in _absolute_window_sums({q: src[p, q] for pp, q in src if pp == p}, Y, ny, 0).items():
                    src[p, q] = v
        for q in sorted({q for _, q in src}):       # then along x
            for p, v in _absolute_window_sums({p: src[p, q] for p, qq in src if qq == q}, X, nx, 1).items():
                src[p, q] = v
    with np.errstate(all="ignore"):
        if degree == 0:
            m00 = m[0, 0]
            ok = m00 > 1e-9
            inv = np.where(ok, 1.0 / m00, np.nan)
            return {"blocks": (qy, qx), "coef": (zz[0, 0] * inv,), "ginv": (inv,), "two_d": two_d}
        if not two_d:
            m0, m1, m2, z0, z1 = m[0, 0], m[1, 0], m[2, 0], zz[0, 0], zz[1, 0]
            det = m0 * m2 - m1 * m1
            det = np.where(det > 1e-9 * m0 * m2, det, np.nan)
            a = (z0 * m2 - z1 * m1) / det
            b = (m0 * z1 - m1 * z0) / det
            return {"blocks": (qy, qx), "coef": (a, b), "ginv": (m2 / det, -2.0 * m1 / det, m0 / det),
                    "two_d": False}
        m00, m10, m01, m20, m11, m02 = m[0, 0], m[1, 0], m[0, 1], m[2, 0], m[1, 1], m[0, 2]
        z00, z10, z01 = zz[0, 0], zz[1, 0], zz[0, 1]
        c00 = m20 * m02 - m11 * m11
        c01 = m11 * m01 - m10 * m02
        c02 = m10 * m11 - m20 * m01
        c11 = m00 * m02 - m01 * m01
        c12 = m10 * m01 - m00 * m11
        c22 = m00 * m20 - m10 * m10
        det = m00 * c00 + m10 * c01 + m01 * c02
        det = np.where(det > 1e-9 * np.abs(m00 * c00), det, np.nan)
        a = (c00 * z00 + c01 * z10 + c02 * z01) / det
        bxs = (c01 * z00 + c11 * z10 + c12 * z01) / det
        bys = (c02 * z00 + c12 * z10 + c22 * z01) / det
        # g = v^T N^-1 v, v = (1, dx, dy): c00 + 2 dx c01 + 2 dy c02 + dx^2 c11 + 2 dx dy c12 + dy^2 c22, / det
        return {"blocks": (qy, qx), "coef": (a, bxs, bys),
                "ginv": tuple(c / det for c in (c00, 2.0 * c01, 2.0 * c02, c11, 2.0 * c12, c22)), "two_d": True}


def block_fits(model, z, w, r0, r1, row0=None):
    """Leave-one-out fit ``zhat`` and variance factor ``h`` at the cells of rows ``r0:r1`` of ``z``
    and ``w`` (the raster's rows ``row0 + r0 ...``, ``row0`` default 0; the raster's row a multiple
    of the block's rows) from the block fits of :func:`block_fit_model`, float32.

    A cell at ``(dx, dy)`` from its block's centre takes the model of its block's window there,
    ``z_f = a + b_x dx + b_y dy``, with ``g = v^T N^-1 v``; leaving the cell (weight ``w``) out of
    that fit gives (Sherman-Morrison) the residual ``(z - z_f) / (1 - w g)`` and the prediction
    variance factor ``g / (1 - w g)``: the leave-one-out fit of :func:`fit_box_2d` /
    :func:`fit_rows` for the window centred on the cell's block. Heights are those given (the
    caller centres them so float32 keeps them to a tenth of a millimetre). NaN where undetermined.
    """
    r, h = block_residuals(model, z, w, r0, r1, row0)
    return np.subtract(z[r0:r1], r, out=r), h


def block_residuals(model, z, w, r0, r1, row0=None):
    """:func:`block_fits` as the leave-one-out residuals ``z - zhat`` and ``h`` (float32)."""
    qy, qx = model["blocks"]
    rows, cols = r1 - r0, z.shape[1]
    R, C = -(-rows // qy), -(-cols // qx)
    b0 = (r0 + (row0 or 0)) // qy
    whole = rows == R * qy and cols == C * qx

    def coarse(a):                                 # the band's blocks, broadcast over their cells
        return a[b0:b0 + R].astype(np.float32)[:, None, :, None]

    def fine(a):                                   # the band's cells as (blocks, qy, blocks, qx)
        if whole:
            return np.asarray(a[r0:r1], np.float32).reshape(R, qy, C, qx)
        out = np.zeros((R * qy, C * qx), np.float32)
        out[:rows, :cols] = a[r0:r1]
        return out.reshape(R, qy, C, qx)

    dx = (np.arange(qx, dtype=np.float32) - (qx - 1) / 2.0)[None, None, None, :]
    dy = (np.arange(qy, dtype=np.float32) - (qy - 1) / 2.0)[None, :, None, None]
    coef = [coarse(c) for c in model["coef"]]
    gi = [coarse(c) for c in model["ginv"]]
    full = (R, qy, C, qx)
    r = np.subtract(fine(z), coef[0])              # z - z_f, z_f = a + b_x dx + b_y dy
    if len(coef) == 1:                             # the mean: g = 1 / M0 wherever the cell lies
        g = np.broadcast_to(gi[0], full).copy()
    else:
        r -= coef[1] * dx
        g = gi[0] + dx * (gi[1] + dx * gi[2 if len(coef) == 2 else 3])
        if len(coef) == 3:
            r -= coef[2] * dy
            g = g + dy * (gi[2] + dx * gi[4] + dy * gi[5])
        else:
            g = np.broadcast_to(g, full).copy()
    den = np.multiply(fine(w), g)
    np.subtract(1.0, den, out=den)
    with np.errstate(all="ignore"):
        np.copyto(den, np.nan, where=den <= 1e-6)  # the cell alone determines its window: no fit
        r /= den
        g /= den
    return r.reshape(R * qy, C * qx)[:rows, :cols], g.reshape(R * qy, C * qx)[:rows, :cols]


#: Cells per slab of rows whose profile moments :func:`snoop_block_fits` computes at once.
_PROFILE_SLAB_CELLS = 1 << 20


def snoop_block_fits(z, keep, test, below, sizes, degree, s, k, low_weight, progress=None):
    """:func:`fit_and_snoop` with the fits computed once per block of cells (:func:`block_fit_model`,
    :func:`block_fits`): a cell is tested against the leave-one-out fit of the window centred on
    its block (at most half a block, ``1 / 32`` of the window, from its own), in float32 on heights
    centred on the raster's median (their spread, not their magnitude, sets the precision).

    ``sizes`` ``(rows, cols)`` of the window (``(1, cols)``: profiles along the rows), ``degree``
    0 or 1. The cells' weights as in :func:`fit_and_snoop` (1 where ``keep``, ``low_weight``
    where also ``below``). Returns ``high, low, below`` like :func:`fit_and_snoop`.
    """
    rows, cols = z.shape
    sample = z.reshape(-1)[::max(1, z.size // 100_000)]
    sample = sample[np.isfinite(sample)]
    ref = float(np.median(sample)) if sample.size else 0.0

    def band(r0, r1, dtype=np.float64):
        kb = keep[r0:r1]
        zb = np.subtract(z[r0:r1], ref, dtype=dtype)
        np.copyto(zb, 0.0, where=~kb)             # weight 0 there (NaN must not reach the sums)
        wb = kb.astype(dtype)
        if below is not None:
            np.copyto(wb, low_weight, where=below[r0:r1] & kb)
        return zb, wb

    two_d = sizes[0] > 1
    # a window's model: of the whole raster (surfaces), or of each slab of rows (profiles: a slab
    # holds its whole windows; the model's moments are 1 / q of the slab)
    model = block_fit_model(band, z.shape, sizes, degree) if two_d else None
    qy = model["blocks"][0] if two_d else 1
    high = np.zeros(z.shape, bool)
    low = np.zeros(z.shape, bool)
    under = np.zeros(z.shape, bool)
    ks2 = np.float32((k * s) ** 2)
    step = qy * max(1, BAND_CELLS // max(1, cols * qy))
    slab = step * max(1, _PROFILE_SLAB_CELLS // max(1, cols * step))
    with np.errstate(invalid="ignore"):            # NaN fits are not tested
        for r0 in range(0, rows, step):
            report(progress, r0 / rows)
            r1 = min(rows, r0 + step)
            if not two_d and r0 % slab == 0:
                s1 = min(rows, r0 + slab)
                model = block_fit_model(lambda a, b, s0=r0: band(s0 + a, s0 + b), (s1 - r0, cols), sizes, degree)
                s0 = r0
            zb, wb = band(r0, r1, np.float32)
            v, h = block_residuals(model, zb, wb, 0, r1 - r0, row0=r0 if two_d else r0 - s0)
            tb = test[r0:r1]
            bl = v < 0.0
            bl &= tb
            v *= v
            np.maximum(h, 0.0, out=h)
            h *= ks2
            h += ks2
            hi = v > h
            hi &= tb
            hi &= ~bl
            h += ks2 / np.float32(low_weight) - ks2
            lo = v > h
            lo &= bl
            high[r0:r1], low[r0:r1], under[r0:r1] = hi, lo, bl
    return high, low, under
