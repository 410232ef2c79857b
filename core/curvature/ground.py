"""The ground surface of the final pass: step 5 of the curvature filter.

The ground is interpolated under the objects, the breaks next to them and the points with
``|K| >= K_g`` (:func:`_ground_surface`: the harmonic surface of the shared gap filler on a
grid of half the resolution, refined bilinearly); a cell is an object when it stands above
that surface by more than the tolerance plus one cell of the surface's slope. Straight
breaks away from objects (dams, embankments, terrace edges: K ~ 0) are seeds of the
surface, so terrain edges stay ground; a concave break deeper than the minimum object
height below the surface and below every cell of the ring around it is a low blunder
(:func:`find_ground`, Luong Chinh Ke 2002, sec. 2.2).
"""
from typing import Optional, Tuple

import numpy as np

from ..codes import GROUND, LOW, NODATA, OBJECT
from ..common import report, sub_progress
from ..fill import fill_gaps
from .derivatives import CHUNK_CELLS, Breaks, CellSize, Progress, bridge_from_nearest, dilate

#: Final passes against the interpolated ground surface.
_PASSES = 2


def _pits(z, cand, ring, depth):
    """Flat indices of the candidates lower by ``depth`` than every valid cell on the
    square ring at distance ``ring`` around them: spikes down (low blunders), not valleys,
    ditches or cuts, whose bottom continues through the ring. One gather per ring offset,
    over all candidates."""
    idx = np.flatnonzero(cand)
    if idx.size == 0:
        return idx
    rows, cols = z.shape
    rr, cc = np.divmod(idx, cols)
    zf = z.ravel()
    low = np.full(idx.size, np.inf, np.float32)
    k = range(-ring, ring + 1)
    offsets = ([(-ring, d) for d in k] + [(ring, d) for d in k]
               + [(d, -ring) for d in k[1:-1]] + [(d, ring) for d in k[1:-1]])
    with np.errstate(invalid="ignore"):
        for dr, dc in offsets:
            r = rr + dr
            c = cc + dc
            ok = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
            r *= cols
            r += c
            v = zf.take(np.where(ok, r, 0))
            ok &= np.isfinite(v)             # nodata and cells outside: not on the ring
            np.minimum(low, np.where(ok, v, np.float32(np.inf)), out=low)
        return idx[zf.take(idx) < low - np.float32(depth)]


def _ground_surface(z, holes, out=None, progress=None):
    """Ground surface of the final pass: ``z`` at the cells not in ``holes``, over the
    holes the harmonic surface (:func:`~bare_earth.core.fill.fill_gaps`) of a grid of half the resolution,
    interpolated bilinearly.

    Each 2 x 2 block of cells is one coarse cell. Its height is the mean of the diagonal
    pairs of known cells it holds (the block centre, exactly on a plane); without a known
    pair, along a straight edge of a hole, the linear extrapolation of two known cells on
    one side and the two beyond them (also exact on a plane), else the mean of its known
    cells, so that a line of known cells one cell wide (the crest of a dam between bands
    of breaks) still holds the coarse surface up; coarse cells with no known cell are
    filled (as one level of the restriction of :func:`fill.fill_gaps`). The fine surface
    over the holes is the bilinear interpolation of the coarse one (linear extrapolation
    at the raster's edge; planes stay planes). A quarter of the cells to interpolate; the
    final pass only compares heights with this surface, with a tolerance. Restriction and
    interpolation go by cache-sized blocks of rows; ``out``, optional: a float32 array of
    ``z``'s shape receiving the surface; ``progress(fraction)`` as the work goes.
    """
    h, w = z.shape
    known = ~holes
    known &= np.isfinite(z)
    if min(h, w) < 8 or not known.any():
        return np.asarray(fill_gaps(z, fill=holes), dtype=np.float32)
    H, W = (h + 1) // 2, (w + 1) // 2
    w1 = w // 2                          # coarse columns with a second child
    s = np.empty((H, W), np.float32)     # coarse heights (NaN: to fill)
    diag = np.zeros((H, W), bool)        # coarse cells set by a known diagonal pair
    part = np.zeros((H, W), bool)        # coarse cells with known cells but no pair
    step = max(1, CHUNK_CELLS // max(w, 1))
    zero = np.float32(0)
    for I0 in range(0, H, step):
        I1 = min(H, I0 + step)
        zb, kb = z[2 * I0:2 * I1], known[2 * I0:2 * I1]
        i1 = zb.shape[0] // 2            # coarse rows of the block with a second child
        k00, k01, k10, k11 = kb[0::2, 0::2], kb[0::2, 1::2], kb[1::2, 0::2], kb[1::2, 1::2]
        v00 = np.where(k00, zb[0::2, 0::2], zero)
        v01 = np.where(k01, zb[0::2, 1::2], zero)
        v10 = np.where(k10, zb[1::2, 0::2], zero)
        v11 = np.where(k11, zb[1::2, 1::2], zero)
        # all known cells of the block
        sb = s[I0:I1]
        np.copyto(sb, v00)
        sb[:, :w1] += v01
        sb[:i1] += v10
        sb[:i1, :w1] += v11
        n = k00.astype(np.float32)
        n[:, :w1] += k01
        n[:i1] += k10
        n[:i1, :w1] += k11
        # the known diagonal pairs, where there is one
        d1 = k00[:i1, :w1] & k11
        d2 = k01[:i1] & k10[:, :w1]
        sd = v00[:i1, :w1] + v11
        sd *= d1
        v01 = v01[:i1] + v10[:, :w1]
        v01 *= d2
        sd += v01
        nd = d1.astype(np.float32)
        nd += d2
        nd *= 2
        db = diag[I0:I0 + i1, :w1]
        np.greater(nd, 0, out=db)
        np.copyto(sb[:i1, :w1], sd, where=db)
        np.copyto(n[:i1, :w1], nd, where=db)
        pb = part[I0:I1]
        np.greater(n, 0, out=pb)
        pb &= ~diag[I0:I1]
        empty = n == 0
        n[empty] = 1
        sb /= n
        sb[empty] = np.nan
        report(progress, 0.2 * I1 / H)
    # known cells without a known pair: along a straight edge of a hole, two known
    # children on one side and the two cells beyond them give the centre by linear
    # extrapolation (exact on a plane); elsewhere (thin crests, corners) their mean
    idx = np.flatnonzero(part)
    del diag, part
    if idx.size:
        i, j = np.divmod(idx, W)
        base = i * (2 * w)
        base += 2 * j                      # flat index of the block's first cell
        kf, zf = known.ravel(), z.ravel()
        acc = np.zeros(idx.size, np.float32)
        cnt = np.zeros(idx.size, np.float32)
        inner_c, inner_r = 2 * j + 1 < w, 2 * i + 1 < h
        # side: where it exists; (inner cells, outer cells) as (row, col) offsets from
        # the block's first cell
        for ok, (a, b), (c, d) in (
                ((i >= 1) & inner_c, ((0, 0), (0, 1)), ((-1, 0), (-1, 1))),         # top
                ((2 * i + 2 < h) & inner_c, ((1, 0), (1, 1)), ((2, 0), (2, 1))),    # bottom
                ((j >= 1) & inner_r, ((0, 0), (1, 0)), ((0, -1), (1, -1))),         # left
                ((2 * j + 2 < w) & inner_r, ((0, 1), (1, 1)), ((0, 2), (1, 2)))):   # right
            q = np.flatnonzero(ok)
            bq = base.take(q)
            fl = [bq + (o[0] * w + o[1]) for o in (a, b, c, d)]
            good = kf.take(fl[0]) & kf.take(fl[1]) & kf.take(fl[2]) & kf.take(fl[3])
            q, fl = q[good], [f[good] for f in fl]
            est = zf.take(fl[0]) + zf.take(fl[1])
            est *= np.float32(0.75)
            est -= np.float32(0.25) * (zf.take(fl[2]) + zf.take(fl[3]))
            acc[q] += est
            cnt[q] += 1
        ok = cnt > 0
        s.ravel()[idx[ok]] = acc[ok] / cnt[ok]
    report(progress, 0.25)
    coarse = fill_gaps(s, progress=sub_progress(progress, 0.25, 0.7))
    del s
    return _upsample2(coarse, (h, w), z, known, out=out, progress=sub_progress(progress, 0.7, 1.0))


def _upsample2(c, shape, z=None, known=None, out=None, progress=None):
    """Bilinear interpolation of a grid of half the resolution at the cells of ``shape``
    (fine cell i lies at coarse coordinate i / 2 - 1/4; the coarse grid is extended by
    linear extrapolation, so planes stay planes); ``z`` where ``known`` when given. By
    cache-sized blocks of rows."""
    H, W = c.shape
    h, w = shape
    cp = np.empty((H + 2, W + 2), np.float32)
    cp[1:-1, 1:-1] = c
    if H > 1:
        np.subtract(2 * c[0], c[1], out=cp[0, 1:-1])
        np.subtract(2 * c[-1], c[-2], out=cp[-1, 1:-1])
    else:
        cp[0, 1:-1] = cp[-1, 1:-1] = c[0]
    if W > 1:
        np.subtract(2 * cp[:, 1], cp[:, 2], out=cp[:, 0])
        np.subtract(2 * cp[:, -2], cp[:, -3], out=cp[:, -1])
    else:
        cp[:, 0] = cp[:, -1] = cp[:, 1]
    a, b = np.float32(0.75), np.float32(0.25)
    out = np.empty((h, w), np.float32) if out is None else out
    step = max(1, CHUNK_CELLS // max(2 * W, 1))
    rows = np.empty((2 * min(step, H), W + 2), np.float32)
    tmp = np.empty((min(step, H), W + 2), np.float32)
    full = np.empty((2 * min(step, H), 2 * W), np.float32)
    tmp2 = np.empty((2 * min(step, H), W), np.float32)
    for I0 in range(0, H, step):
        I1 = min(H, I0 + step)
        n = I1 - I0
        rb, tb = rows[:2 * n], tmp[:n]
        for par, nb in ((0, cp[I0:I1]), (1, cp[I0 + 2:I1 + 2])):  # even rows lean up, odd down
            dst = rb[par::2]
            np.multiply(cp[I0 + 1:I1 + 1], a, out=dst)
            np.multiply(nb, b, out=tb)
            dst += tb
        fb, t2 = full[:2 * n], tmp2[:2 * n]
        for par, nb in ((0, rb[:, :-2]), (1, rb[:, 2:])):
            dst = fb[:, par::2]
            np.multiply(rb[:, 1:-1], a, out=dst)
            np.multiply(nb, b, out=t2)
            dst += t2
        r0, r1 = 2 * I0, min(h, 2 * I1)
        ob = out[r0:r1]
        np.copyto(ob, fb[:r1 - r0, :w])
        if z is not None:
            np.copyto(ob, z[r0:r1], where=known[r0:r1])
        report(progress, I1 / H)
    return out


def _slope(a, dx, dy, progress=None):
    """tan(slope) of a complete surface by central differences (one-sided at the edges),
    block of rows by block (the gradients live in cache-sized buffers)."""
    rows, cols = a.shape
    out = np.empty(a.shape, np.float32)
    step = max(1, CHUNK_CELLS // max(cols, 1))
    gx_b = np.empty((min(step, rows), cols), np.float32)
    gy_b = np.empty((min(step, rows), cols), np.float32)
    for i0 in range(0, rows, step):
        i1 = min(rows, i0 + step)
        n = i1 - i0
        blk, gx, gy = a[i0:i1], gx_b[:n], gy_b[:n]
        if cols > 1:
            np.subtract(blk[:, 2:], blk[:, :-2], out=gx[:, 1:-1])
            gx[:, 1:-1] *= np.float32(0.5 / dx)
            gx[:, 0] = (blk[:, 1] - blk[:, 0]) / dx
            gx[:, -1] = (blk[:, -1] - blk[:, -2]) / dx
        else:
            gx[:] = 0
        if rows > 1:
            lo, hi = max(i0, 1), min(i1, rows - 1)   # rows with both neighbours
            if hi > lo:
                np.subtract(a[lo + 1:hi + 1], a[lo - 1:hi - 1], out=gy[lo - i0:hi - i0])
                gy[lo - i0:hi - i0] *= np.float32(0.5 / dy)
            if i0 == 0:
                gy[0] = (a[1] - a[0]) / dy
            if i1 == rows:
                gy[n - 1] = (a[-1] - a[-2]) / dy
        else:
            gy[:] = 0
        gx *= gx
        gy *= gy
        gx += gy
        np.sqrt(gx, out=out[i0:i1])
        report(progress, i1 / rows)
    return out


def find_ground(z: np.ndarray, objects: np.ndarray, breaks: Breaks, valid: Optional[np.ndarray],
                cell_size: CellSize, *, window: int, h_min: float, tol: float,
                progress: Optional[Progress] = None) -> Tuple[np.ndarray, Optional[np.ndarray]]:
    """Step 5, the final pass (twice): the cells standing above the ground interpolated
    under the objects and the breaks next to them are objects; deep concave spikes are
    low blunders.

    The second pass's surface also rests on the breaks the first found to be ground.
    ``valid`` is None when every cell is valid. Returns the mask (codes of
    :mod:`~bare_earth.core.codes`, 255 at nodata) and the last ground surface (None when
    no cell could seed it).
    """
    dx, dy = cell_size
    m = window // 2
    invalid = None if valid is None else ~valid
    marked = breaks.marked
    holes = _first_holes(objects, breaks, invalid, m)
    report(progress, 0.0)
    concave = np.less(breaks.curvature[1], 0)     # H < 0
    concave &= marked
    edge = marked & ~objects
    mask = np.zeros(z.shape, np.uint8)
    surface = allow = None
    d = np.empty(z.shape, np.float32)
    tmp = np.empty(z.shape, bool)
    for it in range(_PASSES):
        if holes.all():                   # no ground seed (nodata is in holes)
            mask[objects] = OBJECT
            break
        step = sub_progress(progress, it / _PASSES, (it + 1) / _PASSES)
        # the first pass's surface is not needed once d and the allowance are known
        zs, hs = _surface_input(z, holes, invalid, window, sub_progress(step, 0.0, 0.15))
        surface = _ground_surface(zs, hs, out=surface, progress=sub_progress(step, 0.15, 0.7))
        del zs, hs
        np.subtract(z, surface, out=d)
        if allow is None:  # the slope of the first surface serves both passes
            allow = _allowance(surface, edge, dx, dy, h_min=h_min, tol=tol,
                               progress=sub_progress(step, 0.7, 0.85))
        report(step, 0.85)
        _classify(z, d, allow, objects, concave, mask, tmp, ring=m + 2, h_min=h_min)
        np.not_equal(mask, GROUND, out=holes)
        holes |= breaks.by_k
        if invalid is not None:
            holes |= invalid
        report(progress, (it + 1) / _PASSES)
    del d, tmp
    if invalid is not None:
        mask[invalid] = NODATA
    return mask, surface


def _surface_input(z, holes, invalid, reach, progress=None):
    """Heights and holes for :func:`_ground_surface`: nodata (``invalid``) within ``reach``
    cells of a ground seed takes the height of the nearest seed
    (:func:`.derivatives.bridge_from_nearest`) instead of being spanned by the membrane.
    That band shields the surface under an object beside a nodata area from the far side
    of the area (which a block may not hold): the surface depends on the ground near it."""
    if invalid is None:
        return z, holes
    zs = bridge_from_nearest(z, ~holes, reach, reflect=False, fill=invalid, progress=progress)
    bridged = np.isfinite(zs)
    bridged &= invalid
    return zs, holes & ~bridged


def _first_holes(objects, breaks, invalid, m):
    """Cells that do not seed the first ground surface: the objects, the breaks within
    ``m`` cells of them (their feet and walls), the points the paper's test marks,
    ``|K| >= K_g`` (curved both ways: crowns, corners, spikes, pits), and nodata. Straight
    breaks away from objects (dams, embankments, terrace edges: K ~ 0 because one
    principal curvature is zero) stay seeds."""
    holes = dilate(objects, m)           # near objects ...
    holes &= breaks.marked                # ... the breaks
    holes |= objects
    holes |= breaks.by_k
    if invalid is not None:
        holes |= invalid
    return holes


def _allowance(surface, edge, dx, dy, *, h_min, tol, progress=None):
    """How far a cell may stand above the ground surface and still be ground.

    The tolerance grows with the slope of the surface: one cell of horizontal uncertainty
    on a slope is a height difference of tan(slope) * cell. A break that no profile found
    inside an object (``edge``) must stand half the minimum object height more above the
    surface: interpolated across a band of breaks, the surface sags below convex terrain
    edges (crest of a dam) by some decimetres."""
    allow = _slope(surface, dx, dy, progress)
    allow *= np.float32(max(dx, dy))
    allow += np.float32(tol)
    np.maximum(allow, np.float32(0.5 * h_min + tol), out=allow, where=edge)
    return allow


def _classify(z, d, allow, objects, concave, mask, tmp, *, ring, h_min):
    """One final pass into ``mask`` from ``d`` = height above the ground surface.

    OBJECT where ``d > allow``, else GROUND; LOW for the concave breaks more than
    ``h_min`` below the surface that are pits (:func:`_pits` on the ring at ``ring``
    cells); the cells the profiles found between a break up and a break down stay objects
    when they stand clearly (half the minimum object height) above the ground surface (a
    profile that overshot along a rising terrain, a dam behind a bush, does not).
    ``tmp`` is a boolean buffer of the raster's shape."""
    np.greater(d, allow, out=mask.view(bool))       # OBJECT where above, else GROUND
    if OBJECT != 1:  # pragma: no cover - the codes are fixed
        mask *= np.uint8(OBJECT)
    np.less(d, np.float32(-h_min), out=tmp)
    tmp &= concave
    mask.ravel()[_pits(z, tmp, ring, h_min)] = LOW
    np.greater(d, np.float32(0.5 * h_min), out=tmp)
    tmp &= objects
    np.copyto(mask, np.uint8(OBJECT), where=tmp)
