"""Profile scans and enclosed regions: steps 3 and 4 of the curvature filter.

Luong Chinh Ke (2002, sec. 2.2) reads the breaks along the X and Y profiles: the points
between a break going up and the matching break coming down belong to an object
(:func:`find_profile_objects`). Regions enclosed by breaks and made mostly of such points
become whole objects (:func:`find_enclosed_objects`).
"""
from typing import Optional, Tuple

import numpy as np
from scipy import ndimage

from ..common import report, sub_progress, transpose
from .derivatives import CHUNK_CELLS, CellSize, Progress

#: Width (cells) within which an object's wall rises, and how much steeper than the
#: profile before it the wall must be.
_WALL_CELLS = 2
_WALL_CONTRAST = 3.0


def _walls(Zp, pad, B, cell, *, reach, h_min, tan_wall):
    """Where a profile (axis 0, scanned downwards) has just risen as a wall.

    ``Zp[pad:]`` holds the positions examined (rows) of all profiles (columns), NaN at
    nodata, below the ``pad >= _WALL_CELLS + reach`` positions before them (NaN before a
    profile's start): a block of rows of the profiles, see :func:`_axis_objects`.
    Only marked positions ``B`` (breaks,
    shaped as ``Zp[pad:]``) are examined. The foot of position j is the lowest of the
    ``_WALL_CELLS`` positions before it. j is the top of a wall when

    * ``z_j - foot >= h_min`` (high enough),
    * the rise is steeper than the wall slope: ``(z_j - foot) / (_WALL_CELLS cell) >=
      tan(wall slope)``, and
    * it is much steeper (``_WALL_CONTRAST`` times) than the profile's own rise over
      the ``reach`` positions before the foot (where that position is nodata or before
      the profile's start: from the farthest valid position within the reach; flat when
      there is none: the test never looks beyond the reach). This keeps terrain
      rasterised in steps
      (sparse points filled from the nearest one: a staircase whose treads are as steep
      as its risers on average) and walls of a terrain cut from looking like object walls,
      while a wall standing on a hillside still stands out.

    The same test mirrored finds where the profile has just come down a wall (by
    ``drop``: the highest of the ``_WALL_CELLS`` positions before, minus ``z_j``). A loop
    over a handful of shifts, each a gather (``take``) over all marked cells from a
    flat view of the rows k positions earlier.

    Returns
    -------
    walls : tuple of ndarray
        ``(flat index, foot height, slope)`` of the wall tops (flat indices of
        ``Zp[pad:]``), in index order; ``slope`` is the profile's rise per position
        before the foot (>= 0), so that the scan can follow the ground under the object.
    downs : tuple of ndarray
        ``(flat index, drop)`` of the positions just below a wall, in index order.
    """
    n = Zp.shape[0] - pad
    if pad < _WALL_CELLS + reach:
        raise ValueError("_walls: the padding must cover the wall and the reach before it")
    idx = np.flatnonzero(B)
    if idx.size == 0:
        e = np.zeros(0, np.int64), np.zeros(0, np.float32)
        return (e[0], e[1], e[1]), e

    def back(k):  # the profiles k positions earlier (NaN before their start), flat view
        return Zp[pad - k:pad - k + n].ravel()

    zc = back(0).take(idx)
    best = back(1).take(idx)
    top = best.copy()
    for k in range(2, _WALL_CELLS + 1):
        v = back(k).take(idx)
        np.fmin(best, v, out=best)
        np.fmax(top, v, out=top)
    base = v if _WALL_CELLS > 1 else best  # the height _WALL_CELLS positions before
    with np.errstate(invalid="ignore"):
        rise = zc - best
        fall = np.subtract(top, zc, out=top)
        # cheap tests first, on all marked cells; the rest only on what passes
        down = fall >= max(np.float32(h_min), np.float32(tan_wall * _WALL_CELLS * cell))
        cand = np.flatnonzero(rise >= np.float32(h_min))
        rate = rise.take(cand)
        rate /= np.float32(_WALL_CELLS * cell)
        steep = rate >= np.float32(tan_wall)
        cand, rate = cand[steep], rate[steep]
        ci = idx.take(cand)
        base = base.take(cand)
        before = back(_WALL_CELLS + reach).take(ci)
        _nearer_before(back, ci, before, base, reach)
        prior = np.maximum((base - before) / np.float32(reach * cell), 0)
        ok = rate >= np.float32(_WALL_CONTRAST) * prior
    wsel = cand[ok]
    return ((ci[ok], best.take(wsel), (prior[ok] * np.float32(cell)).astype(np.float32)),
            (idx[down], fall[down].astype(np.float32)))


def _nearer_before(back, ci, before, base, reach):
    """Where ``before`` (the height ``_WALL_CELLS + reach`` positions before the walls
    ``ci``) is NaN (nodata, or before the profile's start), the farthest valid position
    within the reach (at a profile's start: its first position); ``base`` (a flat
    profile) where there is none. In place; ``back(k)`` is the flat view k positions
    earlier. Nothing beyond the reach is read, so blocks with a halo see what one pass
    sees."""
    miss = np.flatnonzero(np.isnan(before))
    for k in range(_WALL_CELLS + reach - 1, _WALL_CELLS, -1):
        if miss.size == 0:
            return
        v = back(k).take(ci.take(miss))
        ok = ~np.isnan(v)
        hit = miss[ok]
        before[hit] = v[ok]
        miss = miss[~ok]
    before[miss] = base.take(miss)


def _row_slices(flat_idx, n, m):
    """Start offsets of the entries of each row 0..n in a sorted flat-index array."""
    return np.searchsorted(flat_idx // m, np.arange(n + 1))


class _ScanState:
    """What the scan of :func:`_scan_rows` keeps per profile between blocks of rows:
    inside an object, ``g`` the height of the ground before it (its foot), ``gs`` the
    slope of that ground and ``jg`` the position where the object began."""

    def __init__(self, m, tol, max_cells):
        self.g = np.zeros(m, np.float32)
        self.jg = np.zeros(m, np.float32)
        self.gs = np.zeros(m, np.float32)
        self.dist = np.empty(m, np.float32)
        self.lim = np.empty(m, np.float32)
        self.rise = np.empty(m, np.float32)
        self.end = np.empty(m, bool)
        self.far = np.empty(m, bool)
        self.tol = np.float32(tol)
        self.max_cells = max_cells


def _scan_rows(Z, j0, walls, downs, out, st):
    """The scan along axis 0 (positions x profiles), all profiles at once, over the
    positions ``j0 .. j0 + len(Z) - 1`` (``Z``: their heights, ``walls`` and ``downs``
    from :func:`_walls` with flat indices into ``Z``); ``out[j]`` is set to the profiles
    inside an object at position j (``out[j0 - 1]`` must hold the previous position).

    The paper's reading of a profile: the points between a break going up and the
    matching break coming down belong to an object.

    * ground -> object at the top of a wall (``walls``, see :func:`_walls`: marked cells
      only); the state ``st`` (:class:`_ScanState`) takes the wall's foot.
    * object -> ground when the profile comes back down to the ground extended from the
      foot at the slope the profile had before the wall (rising only; within ``tol``),
      or comes down a wall (``downs``) onto ground nearer the foot than the top (the
      matching break coming down, onto ground that rose under the object), or after
      ``max_cells`` (too long for an object). On a slope the scan going uphill
      overshoots, but the scan coming down finds the building's uphill wall;
      :func:`_axis_objects` keeps only what both directions agree on.

    Walls and down-walls are sparse: they are applied by index, row by row. The state is
    only read inside an object and every object starts at a wall, which sets it: the
    dense work per row is the end test alone.
    """
    n, m = Z.shape
    g, jg, gs, dist, lim = st.g, st.jg, st.gs, st.dist, st.lim
    rise, end, far, tol = st.rise, st.end, st.far, st.tol
    w_idx, w_foot, w_slope = walls
    d_idx, d_drop = downs
    w_ptr = _row_slices(w_idx, n, m)
    d_ptr = _row_slices(d_idx, n, m)
    w_col = (w_idx % m).astype(np.intp)
    d_col = (d_idx % m).astype(np.intp)
    d_add = np.maximum(d_drop, tol) - tol
    with np.errstate(invalid="ignore"):
        for i in range(n):
            j = j0 + i
            if j == 0:             # the first position is never inside an object
                out[0] = False
                continue
            obj = out[j - 1]
            np.subtract(Z[i], g, out=rise)
            np.subtract(np.float32(j), jg, out=dist)
            np.multiply(gs, dist, out=lim)
            a, b = d_ptr[i], d_ptr[i + 1]
            if b > a:  # down a wall here: end when rise <= slope * dist + drop
                lim[d_col[a:b]] += d_add[a:b]
            lim += tol
            np.less_equal(rise, lim, out=end)
            np.greater(dist, st.max_cells, out=far)
            end |= far
            now = out[j]
            np.greater(obj, end, out=now)          # obj & ~end: the objects that go on
            a, b = w_ptr[i], w_ptr[i + 1]
            if b > a:
                c = w_col[a:b]
                ok = ~obj.take(c)                  # a profile inside an object does not restart
                if ok.any():
                    c = c[ok]
                    now[c] = True
                    g[c] = w_foot[a:b][ok]
                    gs[c] = w_slope[a:b][ok]
                    jg[c] = j


def _profile_rows(a, j0, j1, dst, fill):
    """Positions ``j0 .. j1 - 1`` of the profiles along axis 0 of ``a`` (its columns),
    forwards then backwards, into ``dst`` (``j1 - j0`` rows): ``dst[:, :m]`` the profiles
    read from their start, ``dst[:, m:]`` read from their end; positions before the
    start are ``fill``."""
    n, m = a.shape
    k0 = min(max(j0, 0), j1)
    if k0 > j0:
        dst[:k0 - j0] = fill
    if j1 <= k0:
        return
    d = dst[k0 - j0:j1 - j0]
    d[:, :m] = a[k0:j1]
    d[:, m:] = a[n - j1:n - k0][::-1]


def _axis_objects(z, marked, valid, cell, axis, *, reach, h_min, tan_wall, tol, max_cells, progress=None):
    """Object cells of the profiles along ``axis`` (0: Y profiles, the columns; 1: X
    profiles, the rows, scanned as the columns of the transposed raster): both scan
    directions must agree.

    A step up of the terrain (terrace edge) is an object to the scan climbing it, but the
    scan coming down the other way meets no break going up: only objects, which have a
    break going up from both sides, are kept.

    Every profile is scanned from its start and from its end at once (the profiles
    forwards, then backwards, side by side), block of positions by block: a block of the
    heights with the positions before it and the block's breaks are copied out of ``z``
    and ``marked``, its walls found (:func:`_walls`) and scanned (:func:`_scan_rows`), so
    that no index array of the raster's size is held. ``z`` is NaN at nodata.
    """
    if axis == 1:
        zt, mt = transpose(z), transpose(marked)
        report(progress, 0.1)
        res = _axis_objects(zt, mt, None, cell, 0, reach=reach, h_min=h_min, tan_wall=tan_wall,
                            tol=tol, max_cells=max_cells, progress=sub_progress(progress, 0.1, 0.9))
        del zt, mt
        res = transpose(res)
        if valid is not None:
            res &= valid
        return res
    n, m = z.shape
    M = 2 * m
    pad = _WALL_CELLS + reach
    rows = max(8, pad, (4 * CHUNK_CELLS) // max(M, 1))
    Zc = np.empty((pad + rows, M), np.float32)
    Bc = np.empty((rows, M), bool)
    out = np.empty((n, M), bool)
    st = _ScanState(M, tol, max_cells)
    for j0 in range(0, n, rows):
        j1 = min(n, j0 + rows)
        k = j1 - j0
        if j0 == 0:
            _profile_rows(z, -pad, j1, Zc[:pad + k], np.nan)
        else:  # the positions before the block: the end of the previous one
            Zc[:pad] = Zc[rows:rows + pad]
            _profile_rows(z, j0, j1, Zc[pad:pad + k], np.nan)
        _profile_rows(marked, j0, j1, Bc[:k], False)
        walls, downs = _walls(Zc[:pad + k], pad, Bc[:k], cell, reach=reach,
                              h_min=h_min, tan_wall=tan_wall)
        _scan_rows(Zc[pad:pad + k], j0, walls, downs, out, st)
        report(progress, j1 / n)
    res = np.logical_and(out[:, :m], out[::-1, m:])
    del out
    if valid is not None:
        res &= valid
    return res


def _enclosed_regions(flag, free, max_cells, progress=None):
    """Regions of ``free`` cells (4-connected) mostly made of ``flag`` cells.

    A region is kept when at least half its cells are flagged, it does not touch the
    array's edge and its bounding box is at most ``max_cells`` on each side, so the
    decision never depends on cells farther than ``max_cells`` (block-safe).
    """
    lab, n = ndimage.label(free)
    report(progress, 0.4)
    if n == 0:
        return np.zeros(flag.shape, bool)
    # cells per label, by blocks of rows (bincount casts its input to intp: a raster-sized
    # int64 copy at once otherwise); flagged cells outside ``free`` count for label 0
    hit = np.zeros(n + 1, np.intp)
    tot = np.zeros(n + 1, np.intp)
    step = max(1, (16 * CHUNK_CELLS) // max(lab.shape[1], 1))
    for i in range(0, lab.shape[0], step):
        lb = lab[i:i + step]
        tot += np.bincount(lb.ravel(), minlength=n + 1)
        hit += np.bincount(lb[flag[i:i + step]], minlength=n + 1)
        report(progress, 0.4 + 0.3 * min(i + step, lab.shape[0]) / lab.shape[0])
    cand = (hit > 0) & (2 * hit >= tot)
    cand[0] = False
    cand[np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]])] = False
    # a bounding box wider than max_cells needs more than max_cells cells: only such
    # regions are measured
    big = cand & (tot > max_cells)
    if big.any():
        ids = np.flatnonzero(big)
        if ids[-1] <= 16 * ids.size + 4096:   # few labels up to the last: boxes of all
            boxes = ndimage.find_objects(lab, max_label=int(ids[-1]))
            boxes = [boxes[i - 1] for i in ids]
        else:                                 # many: renumbered 1..k first
            renum = np.zeros(n + 1, np.int32)
            renum[ids] = np.arange(1, ids.size + 1, dtype=np.int32)
            boxes = ndimage.find_objects(_lookup(renum, lab, step), max_label=ids.size)
        ext = np.array([max(b[0].stop - b[0].start, b[1].stop - b[1].start) for b in boxes])
        cand[ids[ext > max_cells]] = False
    report(progress, 0.8)
    if not cand.any():
        return np.zeros(flag.shape, bool)
    return _lookup(cand, lab, step)


def _lookup(table, lab, step):
    """``table[lab]`` by blocks of ``step`` rows (a gather casts its indices to intp: a
    raster-sized int64 copy at once otherwise)."""
    out = np.empty(lab.shape, table.dtype)
    for i in range(0, lab.shape[0], step):
        table.take(lab[i:i + step], out=out[i:i + step])
    return out


def find_profile_objects(z: np.ndarray, marked: np.ndarray, valid: Optional[np.ndarray], cell_size: CellSize, *,
                         window: int, h_min: float, tan_wall: float, tol: float, max_size: float,
                         progress: Optional[Progress] = None) -> Tuple[np.ndarray, int, int]:
    """Step 3: along the X and Y profiles, the cells from a break going up a wall to the
    break coming down (:func:`_axis_objects`, both scan directions agreeing).

    ``valid`` is None when every cell is valid. The foot search reaches ``2 window + 1``
    positions before a wall; a run longer than ``max_size`` metres is not an object.
    Returns the union of the X and Y objects and the cells found by each.
    """
    dx, dy = cell_size
    kw = dict(h_min=h_min, tan_wall=tan_wall, tol=tol, reach=2 * window + 1)
    obj_x = _axis_objects(z, marked, valid, dx, 1, max_cells=int(max_size / dx),
                          progress=sub_progress(progress, 0.0, 0.5), **kw)
    obj_y = _axis_objects(z, marked, valid, dy, 0, max_cells=int(max_size / dy),
                          progress=sub_progress(progress, 0.5, 1.0), **kw)
    n_x, n_y = int(np.count_nonzero(obj_x)), int(np.count_nonzero(obj_y))
    obj_x |= obj_y
    return obj_x, n_x, n_y


def find_enclosed_objects(objects: np.ndarray, marked: np.ndarray, valid: Optional[np.ndarray],
                          cell_size: CellSize, max_size: float, progress: Optional[Progress] = None) -> np.ndarray:
    """Step 4: regions enclosed by breaks (4-connected valid unmarked cells, at most
    ``max_size`` metres across, not touching the raster's edge) made mostly of the
    ``objects`` of the profiles (:func:`_enclosed_regions`). ``valid`` is None when every
    cell is valid. ``progress(fraction)`` as the work goes."""
    dx, dy = cell_size
    free = ~marked if valid is None else valid & ~marked
    regions = _enclosed_regions(objects, free, int(max(max_size / dx, max_size / dy)), progress)
    report(progress, 1.0)
    return regions
