"""RASCOR steps 2-4: height distribution, neighbour differences, sudden change of level.

Jacobsen (2004): each step removes what the others miss, on the points the previous ones
left; these three test heights against the distribution of heights (step 2), against
their neighbours (step 3) and along X and Y profiles for raised levels (step 4).
"""
import math
from functools import partial
from typing import Callable, Optional, Sequence, Tuple, Union

import numpy as np
from scipy import ndimage

from ..common import as_cell_size, dilate_box, label8, report, sub_progress, transpose
from ..edge_walls import walled_levels
from ..estimate import joined_runs, smooth_parts
from .kernels import BAND_CELLS, row_bands


def remove_height_outliers(z: np.ndarray, keep: np.ndarray, height_min_m: float,
                           height_max_m: float) -> Tuple[np.ndarray, np.ndarray]:
    """Step 2: remove heights far outside the distribution of heights (flat areas only).

    Parameters
    ----------
    z : ndarray
        DSM.
    keep : ndarray of bool
        Cells still in the data (tested and used).
    height_min_m, height_max_m : float
        Limits; :func:`resolve_rascor_params` sets them to Tukey's far fences
        ``Q1 - 3 IQR`` and ``Q3 + 3 IQR`` of the heights, and at least 20 m outside the
        range of the terrain's lower envelope (gross errors, not embankments).

    Returns
    -------
    high, low : ndarray of bool
        Cells above ``height_max_m`` (objects, high blunders) / below ``height_min_m``
        (low blunders).
    """
    with np.errstate(invalid="ignore"):
        return keep & (z > height_max_m), keep & (z < height_min_m)


# ------------------------------------------------------------------- step 3
_DIRS8 = ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (-1, -1), (1, -1), (-1, 1))


def remove_neighbour_differences(z: np.ndarray, keep: np.ndarray, *, sigma_m: float, k: float = 3.0,
                                 low_weight: float = 0.02, labels: Optional[np.ndarray] = None,
                                 cell_rise_m: Union[float, Tuple[float, float]] = 0.0,
                                 bend_m: float = 0.0, ground_sigma_m: Optional[float] = None,
                                 progress: Optional[Callable[[float], None]] = None
                                 ) -> Tuple[np.ndarray, np.ndarray]:
    """Step 3: remove the upper point of neighbouring pairs differing beyond a tolerance.

    For each of the 8 directions ``e``, with ``u`` the tested cell, ``l = u + e`` its lower
    neighbour and ``b = u + 2e`` the next one, ``u`` is removed when

    ``z_u - z_l > k sigma sqrt(2) + max(0, z_l - z_b)``  (the local slope beyond the pair;
    where ``b`` is missing, the slope above ``u``; with neither, the pair is not tested)

    unless the terrain above ``u`` rises at least as steeply (``z_{u-e} - z_u >= z_u - z_l
    - tol``: a straight or concave slope, e.g. the toe of an embankment).

    The tolerance is that of a difference of two heights, ``k sqrt(2) sigma_h``. A raster
    cell's height is a point somewhere inside the cell (the lowest of a lidar cell, the
    nearest to its centre): on ground rising by ``g`` over one cell its position alone
    changes the height by ``g`` times a uniform offset of variance 1/12, so
    ``sigma_h^2 = sigma^2 + g^2 / 12`` and the tolerance is ``sqrt(tol^2 + k^2 g^2 / 6)``
    with ``tol = k sqrt(2) sigma``. ``g`` is the local rise beyond the pair (the slope
    the test already uses), at most the terrain's rise over one step of the pair
    (``cell_rise_m`` along X and Y, their hypotenuse along the diagonals): steeper rises
    are walls and crowns, not ground. (A height's place inside its cell moves it across the
    pair's axis too, so the gradient's magnitude, the slope across the pair in quadrature,
    would be the rule: tried, synthetic hillside 1 m 12.5 -> 11.2 %, lidar hexbin-crop 4 m
    11.8 -> 9.2 %, but on a bare 24 m DEM of hills the 20 m boxes three cells wide were found
    89 % instead of over 90 %, and shrubs on 28-38 degree slopes at 2 m, highest point,
    18.2 -> 20.8 %: not adopted.) With that allowance (``cell_rise_m`` > 0, sloping
    terrain) two equal heights measure no slope: on a slope they are one point copied into
    an empty cell (a nearest-filled grid: 30 % of the cells of a 1 m grid of a point per
    m2), and a copy beyond the pair read as level ground took the next point up the slope,
    two cells' rise above the copy, for an object's edge; the slope above ``u`` stands for
    it, and with neither known the pair is not tested.
    The slope beyond the pair is itself measured by two heights: where it is subtracted,
    ``z_u - z_l - (z_l - z_b)`` is a second difference, of variance ``6 sigma_h^2``, three
    times the pair's, and the pair's tolerance took the noise of sloping bare ground for
    objects' edges (a plane rising 0.2 m per cell with sigma = 0.1 m: 3.4 % of its cells, about
    4 % per downhill direction; synthetic bare terrain lost 2.9 % of its ground, 12.8 % of
    terraced 1 m ground, to this step). With ``cell_rise_m`` > 0, where the slope beyond lies
    within the terrain's rise over the step plus ``k sqrt(2) sigma_g`` (ground; steeper: crowns
    and walls, the pair's tolerance), the random part of the tolerance (``tol`` without the
    bend) gains the variance the slope's two heights add, ``2 w (k sqrt(2) sigma_g)^2``, ``w`` =
    :func:`slope_weight` of that rise and ``sigma_g`` (``ground_sigma_m``: the random error of
    the ground's heights; the probability that a slope measured by two heights on ground rising
    that much has the terrain's sign; 0 on level ground: the paper's test): the noise of a
    sloping plane then passes (0.02 %). The band and ``sigma_g`` are the ground's: ``sigma``
    measured on a vegetated slope reads its crowns, and widening by it let low vegetation pass.
    Objects standing less than the widened tolerance above sloping ground are left to steps
    4-7 (synthetic shrubs on 28-38 degree slopes, 2 m highest point: 18.2 -> 22.7 % total
    error).
    The rise of a slope over one cell grows with the cell, and so does this term; with
    ``cell_rise_m = 0`` the tolerance is the paper's ``k sqrt(2) sigma`` alone. A point that is
    a pit along all four axes (on both sides, within 2 cells, a point higher by more than
    the tolerance widened by the weight factor, ``tol / sqrt(low_weight)``) is a low
    blunder (class 2, up to 3 cells wide) and takes no part in the pairs, so it does not
    take its neighbours with it; a ditch is no pit along its own axis and stays. Pairs never cross a region boundary
    (break line).

    Parameters
    ----------
    z : ndarray
        DSM.
    keep : ndarray of bool
        Cells still in the data.
    sigma_m : float
        Random error of the DSM, metres.
    k : float
        Critical value of the tolerance.
    low_weight : float
        Weight factor of low points (0 < p <= 1).
    labels : ndarray of int, optional
        Break-line regions (:func:`break_regions`).
    cell_rise_m : float or (float, float)
        The terrain's rise over one cell along X and Y, metres (:func:`filter_rascor`: the
        median terrain slope of step 1 times the cell); 0: no allowance for the position
        inside the cell.
    bend_m : float
        The terrain's own second difference over one cell (m): the tolerance widens by ``k``
        times it in quadrature.
    ground_sigma_m : float, optional
        Random error of the ground's heights (m), the noise of the slope beyond a pair (None:
        ``sigma_m``; :func:`filter_rascor`: the noise of the DSM's ground-level cells, which the
        crowns of a vegetated slope do not widen as they widen ``sigma_m``).
    progress : callable, optional
        ``progress(fraction)``, called every band of rows; it may raise ``Cancelled``.

    Returns
    -------
    high, low : ndarray of bool
    """
    tol = float(np.hypot(k * sigma_m * np.sqrt(2.0), k * max(0.0, float(bend_m))))
    rx, ry = (cell_rise_m, cell_rise_m) if np.isscalar(cell_rise_m) else cell_rise_m
    rx, ry = max(0.0, float(rx)), max(0.0, float(ry))
    pairs = _pairs if rx == ry == 0.0 else partial(
        _pairs, k=float(k), rise=(rx, ry), sigma=float(sigma_m if ground_sigma_m is None else ground_sigma_m))
    tol_low = tol / np.sqrt(low_weight)
    rows, cols = z.shape
    zp = np.full((rows + 2 * _PAD, cols + 2 * _PAD), np.nan, np.float32)
    inner = (slice(_PAD, -_PAD), slice(_PAD, -_PAD))
    zp[inner] = z
    zp[inner][~keep] = np.nan
    lp = None
    if labels is not None:
        lp = np.full(zp.shape, -1, np.int64)
        lp[inner] = labels
    low = np.zeros(z.shape, bool)
    high = np.zeros(z.shape, bool)
    with np.errstate(invalid="ignore"):
        _test_bands(_pits, tol_low, zp, lp, keep, 2, low, sub_progress(progress, 0.0, 0.4))
        zp[inner][low] = np.nan
        _test_bands(pairs, tol, zp, lp, keep & ~low, 1, high,
                    sub_progress(progress, 0.4, 1.0))
    return high, low


#: Padding (cells) of step 3's arrays: the tests reach 2 cells.
_PAD = 2
#: The 4 axes of step 3's pairs and pits.
_AXES = ((0, 1), (1, 0), (1, 1), (1, -1))


class _GatheredNeighbours:
    """``nb(dr, dc)``: the neighbour ``(dr, dc)`` of the candidate cells, whose flat indices
    in the padded array of width ``width`` are ``base``; with the padded break-line regions
    ``regions`` (flat), NaN where it lies in another region than the cell."""

    def __init__(self, flat, base, width, regions=None):
        self.flat, self.base, self.width, self.regions = flat, base, width, regions
        self.own = None if regions is None else regions[base]

    def __call__(self, dr, dc):
        at = self.base + (dr * self.width + dc)
        v = self.flat[at]                        # a copy (gathered)
        if self.regions is not None:
            v[self.regions[at] != self.own] = np.nan
        return v


def _test_bands(test, tol_test, src, lp, keep, reach, out, progress):
    """Run ``test(nb, keep, tol_test)`` (:func:`_pits` or :func:`_pairs`) on every cell of
    ``keep``, in bands of rows, into ``out``.

    Bands of rows keep the few temporaries of each in the cache. Only the candidates are
    tested: cells with a neighbour (within ``reach`` cells along the 8 directions, whatever its
    break-line region) lower (``reach`` 1) / higher (``reach`` 2) by more than ``tol_test``,
    which every removal needs (a neighbour in another region counts as missing, which removes
    nothing); their neighbours are gathered, NaN where they lie in another region (``lp``, the
    padded regions of ``labels``).
    """
    rows, cols = keep.shape
    width = cols + 2 * _PAD
    flat = src.ravel()
    regions = None if lp is None else lp.ravel()
    bands = row_bands(rows, width, 4 * BAND_CELLS)
    for i, b in enumerate(bands):
        report(progress, i / len(bands))
        r0, r1 = b.start, b.stop
        ext = None
        for dr, dc in _DIRS8:
            for m in range(1, reach + 1):
                v = src[_PAD + r0 + m * dr:_PAD + r1 + m * dr, _PAD + m * dc:_PAD + m * dc + cols]
                ext = v.copy() if ext is None else (np.fmax(ext, v, out=ext) if reach == 2
                                                     else np.fmin(ext, v, out=ext))
        ext -= src[_PAD + r0:_PAD + r1, _PAD:_PAD + cols]
        cand = ext > tol_test if reach == 2 else ext < -tol_test
        cand &= keep[b]
        idx = np.flatnonzero(cand)
        ob = out[b]
        ob[:] = False
        if not idx.size:
            continue
        base = idx + (idx // cols) * (2 * _PAD) + (_PAD + r0) * width + _PAD
        ob.ravel()[idx] = test(_GatheredNeighbours(flat, base, width, regions), np.ones(idx.size, bool), tol_test)


def _pits(nb, kb, tol_low):
    """Low blunders: pits in every direction. Along each of the 4 axes the cell is a pit
    when, on both sides within 2 cells, a point lies higher by more than ``tol_low``
    (fills blunders up to 3 cells wide); a ditch or a cut continues along its own axis,
    so it is no pit there and stays."""
    zc = nb(0, 0)
    n_axes = np.zeros(zc.shape, np.int8)
    n_pits = np.zeros(zc.shape, np.int8)
    for dr, dc in _AXES:
        s0 = np.fmax(nb(dr, dc), nb(2 * dr, 2 * dc))
        s0 -= zc
        s1 = np.fmax(nb(-dr, -dc), nb(-2 * dr, -2 * dc))
        s1 -= zc
        has = np.isfinite(s0)
        has &= np.isfinite(s1)
        n_axes += has
        has &= s0 > tol_low
        has &= s1 > tol_low
        n_pits += has
    lo = kb & (n_axes >= 2)
    lo &= n_pits == n_axes
    return lo


def _pairs(nb, kb, tol, k=0.0, rise=None, sigma=0.0):
    """The upper points of neighbouring pairs differing beyond the tolerance and the local
    slope (see :func:`remove_neighbour_differences`; ``rise = (along X, along Y)``: the
    tolerance of each pair widened by the position of the heights inside their cells on
    a slope rising by at most that much per cell, ``k`` the critical value; ``sigma`` > 0 with
    ``rise``: the random error of the ground's heights, the noise of the slope beyond the pair,
    :func:`slope_weight`)."""
    zc = nb(0, 0)
    hi = np.zeros(zc.shape, bool)
    for dr, dc in _AXES:
        zf, zr = nb(dr, dc), nb(-dr, -dc)        # the next cell forward / backward
        d_f, d_r = zc - zf, zc - zr
        cap = None if rise is None else np.float32(np.hypot(dc * rise[0], dr * rise[1]))  # per step
        for dz, up_neg, zl, far in ((d_f, d_r, zf, (2 * dr, 2 * dc)),
                                    (d_r, d_f, zr, (-2 * dr, -2 * dc))):
            # pair (u = centre, l = next cell); b the cell beyond l; the far cell must
            # lie in the region of l too (nb checks the centre's region for both)
            beyond = zl - nb(*far)
            up = -up_neg                           # rise above u: z_{u-e} - z_u
            if cap is not None:
                # on sloping ground two equal heights are one point copied into an empty cell (a
                # nearest-filled grid): no measure of the slope (a lidar grid at 1 m with a point
                # per m2 has 30 % such cells)
                beyond[beyond == 0] = np.nan
                up = np.where(up == 0, np.float32(np.nan), up)
            # the local slope: beyond the pair, else above u; neither known: no test
            np.copyto(beyond, up, where=np.isnan(beyond))
            t_pair = tol
            if cap is not None:
                # sigma_h^2 = sigma^2 + g^2 / 12 for both heights: tol^2 + k^2 g^2 / 6
                g = np.minimum(np.abs(beyond), cap)
                g *= g
                g *= np.float32(k * k / 6.0)
                if sigma > 0:
                    # the slope subtracted is measured by two heights too: z_u - z_l - (z_l - z_b) is a
                    # second difference, of three times the pair's variance, on ground sloping by more
                    # than that slope's noise (weight w = erf(rise / 2 sigma)); at crowns and walls, slopes
                    # beyond the terrain's rise and the noise, the pair's
                    noise = k * sigma * np.sqrt(2.0)
                    g += np.where(np.abs(beyond) <= cap + np.float32(noise),
                                  np.float32(tol * tol + 2.0 * slope_weight(cap, sigma) * noise * noise),
                                  np.float32(tol * tol))
                else:
                    g += np.float32(tol * tol)
                t_pair = np.sqrt(g, out=g)
                np.copyto(t_pair, np.float32(tol), where=np.isnan(t_pair))
            np.maximum(beyond, 0.0, out=beyond)
            beyond += t_pair
            t = dz > beyond
            # unless the terrain above u rises at least as steeply (straight or concave)
            t &= ~(up >= dz - t_pair)
            hi |= t
    hi &= kb
    return hi


def slope_weight(rise_m: float, sigma_m: float) -> float:
    """How far step 3's test of a pair is a second difference: ``erf(rise / (2 sigma))``.

    The pair's allowance for the local slope, ``max(0, z_l - z_b)``, is a slope measured by two
    heights of random error ``sigma``, itself of standard deviation ``sqrt(2) sigma``. On ground
    rising by ``rise`` over the pair's step that slope is told from the noise with probability
    ``2 Phi(rise / (sqrt(2) sigma)) - 1 = erf(rise / (2 sigma))`` (0 on level ground: the test is
    the paper's difference of two heights; 1 on a slope: ``z_u - z_l - (z_l - z_b)``, a second
    difference of three times the pair's variance, :func:`remove_neighbour_differences`).

    Parameters
    ----------
    rise_m : float
        The terrain's rise over the pair's step, metres (>= 0).
    sigma_m : float
        Random error of the heights, metres (> 0; 0: 1).

    Returns
    -------
    float
        The weight in [0, 1].
    """
    if not sigma_m > 0:
        return 1.0
    return float(math.erf(max(0.0, float(rise_m)) / (2.0 * float(sigma_m))))


# ------------------------------------------------------------------- step 4
def _raised_rows(z, keep, labels, jump, lmax, veg_tol, lone=False, cut=None, upper=None, lower=None,
                 faces=False):
    """Cells between a jump up and a later jump down along the rows (axis 1); with
    ``lone``, instead, the cells on both sides of the jumps that no other jump answers
    (no jump up followed within ``lmax`` by a jump down), jumps whatever lies beside them:
    the vegetation test tells a building's walls (Jacobsen: no vegetation beside) from
    crowns, and says nothing of a level change of the terrain (bushes at a bank's foot, the
    far wall of a trench one cell wide, which made its near bank's ground "rough").

    ``upper``, ``lower``, optional (with ``lone``; boolean arrays shaped as ``z``): receive the cells
    on the upper side of each lone jump (after a jump up, before a jump down) and on its lower side.
    ``faces`` (with ``lone``): also the level changes whose face spans two steps (:func:`_face_jumps`,
    their sides' smoothness limit ``veg_tol``; :func:`_lone_faces`).

    ``cut``, optional: a list that receives ``(cells, walls, heights)``, the flat indices into
    ``z`` of the levels the raster's edge cuts, the cells from a jump up to the row's end (no
    jump after it) or from the row's start to a jump down (none before it), at most ``lmax``
    apart and at least ``jump / 2`` above the ground beyond the jump (taken as level: the level
    mirrored at the edge), of their walls (the level's cell at the jump) and the jump's height
    there: :func:`_cut_levels` decides them.

    Works on the remaining points of all rows concatenated in row order (a 1-D array), so
    "the previous point of the profile" is simply the previous element: profile starts
    (a new row, or a new break-line region along the row) reset the scans. Only the steps
    larger than ``jump`` can be jumps; the tests run on those candidates alone.
    """
    out = np.zeros(z.shape, bool)
    flat = np.flatnonzero(keep)           # within a row, differences of flat indices are
    n = flat.size                         # differences of column positions
    if n < 4:
        return out
    P = 3
    zp = np.full(n + 2 * P, np.nan, np.float32)          # padded: i - 3 .. i + 2 exist
    zc = zp[P:P + n]
    np.take(z.ravel(), flat, out=zc, mode="clip")         # z[keep]: a gather by index is faster
    sp = np.zeros(n + 2 * P, bool)
    same = sp[P:P + n]                                    # same profile as the previous point
    same[:] = True
    row_at = np.searchsorted(flat, np.arange(keep.shape[0] + 1) * keep.shape[1])   # each row's first point
    cnt = np.diff(row_at)                                 # points per row
    rows_first = row_at[:-1][cnt > 0]
    same[rows_first] = False                              # the first point of each row
    if labels is not None:
        lab = labels.ravel()[flat]
        same[1:] &= lab[1:] == lab[:-1]
    d = zc[1:] - zc[:-1]                                  # the step to the next point
    with np.errstate(invalid="ignore"):
        i = 1 + np.flatnonzero(np.abs(d) > jump)
    i = i[same[i]]
    # candidates i: the step from i-1 to i exceeds jump (a jump up or down at i)
    j = i + P
    z0, z1, z2, z3 = zp[j], zp[j - 1], zp[j - 2], zp[j - 3]   # z_i, z_{i-1}, z_{i-2}, z_{i-3}
    s2 = sp[j - 1]
    s3 = s2 & sp[j - 2]
    zn, znn = zp[j + 1], zp[j + 2]
    n1 = sp[j + 1]
    n2 = n1 & sp[j + 2]
    with np.errstate(invalid="ignore"):
        # jump up at i: from p = i-1 (ground) to i; slope allowance = rise before p
        rise_before = np.where(s2, np.maximum(z1 - z2, 0.0), 0.0)
        up = z0 - z1 - rise_before > jump
        # jump down at i: from i-1 (high) to i (ground); allowance = fall after i
        fall_after = np.where(n1, np.maximum(z0 - zn, 0.0), 0.0)
        down = z1 - z0 - fall_after > jump
        # no vegetation beside the jump: the 3 ground points outside it lie on a smooth
        # line; crowns and bushes are rough (the roof side is not tested: mixed wall /
        # roof cells make it rough)
        if not lone:
            up &= np.where(s3, np.abs(z1 - 2 * z2 + z3) <= veg_tol, s2)
            down &= np.where(n2, np.abs(z0 - 2 * zn + znn) <= veg_tol, n1)
        else:
            # a level change is a rise beyond the slope before it (a fall beyond the slope after
            # it): at a profile's first (last) step that slope is unknown, and a hillside rising
            # more than the jump per cell would read as a level change along the raster's edge
            up &= s2
            down &= n1
    # events along the concatenated profiles: 1 jump up, 2 jump down, 0 profile start.
    # A raised level is a run from a jump up to the next event when that is a jump down.
    starts = rows_first if labels is None else np.flatnonzero(~same)
    ev = np.concatenate([starts, i[up], i[down]])
    typ = np.concatenate([np.zeros(starts.size, np.int8), np.ones(int(up.sum()), np.int8),
                          np.full(int(down.sum()), 2, np.int8)])
    order = np.argsort(ev, kind="stable")
    ev, typ = ev[order], typ[order]
    k = np.flatnonzero((typ[:-1] == 1) & (typ[1:] == 2))
    a, b = ev[k], ev[k + 1]
    pos = flat
    ok = (pos[b] - pos[a]) <= lmax
    if lone:
        paired = np.zeros(ev.size, bool)
        paired[k[ok]] = True
        paired[k[ok] + 1] = True
        lone_ev = (typ > 0) & ~paired
        alone, up_at = ev[lone_ev], typ[lone_ev] == 1     # a jump is never a profile's first point
        beyond = alone
        face, face_typ = _face_jumps(zp, sp, d, i[up | down], jump, veg_tol, P) if faces else (i[:0], typ[:0])
        if face.size:
            face_lone = _lone_faces(ev, typ, paired, face, face_typ, pos, lmax)
            face, face_typ = face[face_lone], face_typ[face_lone]
            # a face over two steps: its foot and top one point beyond its middle (which lies on neither side)
            alone = np.concatenate([alone, face])
            up_at = np.concatenate([up_at, face_typ == 1])
            beyond = np.concatenate([beyond, face + 1])
        if upper is not None:                   # the upper side: after a jump up, before a jump down
            upper.ravel()[flat[np.where(up_at, beyond, alone - 1)]] = True
            lower.ravel()[flat[np.where(up_at, alone - 1, beyond)]] = True
        out.ravel()[flat[alone]] = True
        out.ravel()[flat[alone - 1]] = True
        out.ravel()[flat[beyond]] = True
        n1 = int(lone_ev.sum())
        if faces:                               # none where the terrain bends beyond its noise (as the faces)
            ground = _smooth_sides(zp, sp, alone[:n1] + P, veg_tol, up_at[:n1], jump)
            _face_cells(out, upper, z, flat, alone[:n1], up_at[:n1], ground, jump)
        return out
    if cut is not None:
        _cut_runs(out, cut, zc, flat, pos, ev, typ, starts, cnt, lmax, jump)
    a, b = a[ok], b[ok]
    lens = b - a
    if not lens.size:
        return out
    c = np.arange(lens.sum()) + np.repeat(a - (np.cumsum(lens) - lens), lens)   # the runs' points
    # the ground's line from the point before the jump up (a - 1) to the one after the jump down (b),
    # each run's terms repeated over its points
    p0 = pos[a - 1]
    z0 = zc[a - 1]
    t = (pos[c] - np.repeat(p0, lens)) / np.repeat(np.maximum(pos[b] - p0, 1), lens)
    ground = np.repeat(z0, lens) + np.repeat(zc[b] - z0, lens) * t
    with np.errstate(invalid="ignore"):
        hit = zc[c] - ground > 0.5 * jump
    out.ravel()[flat[c[hit]]] = True
    return out


#: Widest gap (cells) between the two points of a lone one-step jump whose cells :func:`_face_cells` adds
#: to the jump's line: step 3, which runs before step 4, takes a cell one of whose 8 neighbours lies lower
#: beyond its tolerance, so along a face crossing the rows at a slant the band it took is up to two cells
#: deep along a profile.
FACE_GAP_CELLS = 2


def _smooth_sides(zp, sp, j, smooth, up_at, jump):
    """Whether both sides of the jumps between the padded points ``j - 1`` and ``j`` lie on smooth
    lines, the three points of the profile on each side (second difference within ``smooth``: step
    4's test of vegetation beside a building's walls, :func:`_raised_rows`), the upper side (after a
    jump up, ``up_at``, before a jump down) level: its three points within half the ``jump`` (step 4's
    height of a raised point; the test of both sides of :func:`_face_jumps`)."""
    with np.errstate(invalid="ignore"):
        before = sp[j - 1] & sp[j - 2] & (np.abs(zp[j - 1] - 2 * zp[j - 2] + zp[j - 3]) <= smooth)
        after = sp[j + 1] & sp[j + 2] & (np.abs(zp[j] - 2 * zp[j + 1] + zp[j + 2]) <= smooth)
        level = np.where(up_at, np.abs(zp[j] - zp[j + 2]), np.abs(zp[j - 1] - zp[j - 3])) <= 0.5 * jump
    return before & after & level


def _face_cells(out, upper, z, flat, alone, up_at, ground, tol):
    """Add to the lines ``out`` the cells lying between the two points of each lone one-step jump
    (``alone``: indices into the points kept ``flat`` of the jumps' second points, ``up_at``: a jump
    up) along its profile, where at most :data:`FACE_GAP_CELLS` cells lie between them and all of them
    lie between the heights of the jump's two points (within ``tol``, the jump's threshold: a face lies
    between its foot and its top; a crown or a hedge standing on the edge rises above both); with
    ``upper``, those nearer in height to the upper point join the upper side.

    Step 3 runs before step 4 and takes the upper point of every pair across a level change: the top
    of a terrace's retaining wall or of a quarry bench, one or two cells along each profile. The jump
    step 4 then reads over the points kept steps from the level's last kept cell across that gap to the
    wall's foot: its two sides lie apart, the cells of the one side no longer join those of the other
    into one line along the wall, and each side's line, cut again by every bush and house on the level,
    ran shorter than a building: no break line (a terraced hillside at 1 m: most of its walls; step 5's
    profiles then crossed them and took the front of each terrace, 5.6 % of its cells). The cells
    between are the face the jump crosses; a line drawn along the wall holds them. Only the lines are
    read: the profiles and their jumps are those of the points kept. Only where both sides are ground
    and the upper one a level (``ground``: three points on a smooth line on each side, those of the
    upper side within half the jump, :func:`_smooth_sides`), as a terrace's tread or a quarry's bench
    is: on a steep slope under vegetation the lower edge of each bush is a jump no other answers (the
    slope above it rises as high as its top), whose sides, joined, made lines of the vegetation's
    edges (ISPRS 51 at 1 m, lowest point: 10.5 % of its cells on lines without the smooth sides, none
    with them; ISPRS 11 at 2 m, highest point: 28.03 -> 28.95 % total error with the smooth sides
    alone, 28.70 with the face's heights, 28.03 with the level upper side). Not where the terrain bends beyond
    its noise from one cell to the next (``faces`` off in :func:`_raised_rows`, a coarse DEM of hills)."""
    alone, up_at = alone[ground], up_at[ground]
    if not alone.size:
        return
    p0, p1 = flat[alone - 1], flat[alone]
    gap = p1 - p0 - 1                        # the profile's points lie along one row: flat index = column
    zz = z.ravel()
    top = np.maximum(zz[p0], zz[p1]) + tol
    foot = np.minimum(zz[p0], zz[p1]) - tol
    for g in range(1, FACE_GAP_CELLS + 1):   # a gap cell outside the face's heights: no face there
        at = gap >= g
        with np.errstate(invalid="ignore"):
            gap[at] = np.where((zz[p0[at] + g] <= top[at]) & (zz[p0[at] + g] >= foot[at]), gap[at], 0)
    for g in range(1, FACE_GAP_CELLS + 1):
        at = (gap >= g) & (gap <= FACE_GAP_CELLS)
        if not at.any():
            break
        cell = p0[at] + g
        out.ravel()[cell] = True
        if upper is not None:
            hi_end = np.where(up_at[at], p1[at], p0[at])
            lo_end = np.where(up_at[at], p0[at], p1[at])
            with np.errstate(invalid="ignore"):
                near_hi = np.abs(zz[cell] - zz[hi_end]) <= np.abs(zz[cell] - zz[lo_end])
            upper.ravel()[cell[near_hi]] = True


def _lone_faces(ev, typ, paired, face, face_typ, pos, lmax):
    """Which faces over two steps (:func:`_face_jumps`, sorted) no other level change answers: not
    answered within ``lmax`` among all events (a jump up followed by a jump down, either a face), and
    not between two one-step jumps that answer each other (``paired``; events ``ev, typ`` sorted, 0 a
    profile's start). The one-step jumps keep their own pairing: a face never unpairs a box's walls."""
    ev2 = np.concatenate([ev, face])
    typ2 = np.concatenate([typ, face_typ])
    two = np.concatenate([np.zeros(ev.size, bool), np.ones(face.size, bool)])
    order = np.argsort(ev2, kind="stable")
    ev2, typ2, two = ev2[order], typ2[order], two[order]
    k = np.flatnonzero((typ2[:-1] == 1) & (typ2[1:] == 2))
    k = k[(pos[ev2[k + 1]] - pos[ev2[k]]) <= lmax]
    answered = np.zeros(ev2.size, bool)
    answered[k] = True
    answered[k + 1] = True
    last = np.searchsorted(ev, face, side="right") - 1      # the last one-step event before each face
    inside = (last >= 0) & (typ[np.maximum(last, 0)] == 1) & paired[np.maximum(last, 0)]
    return ~answered[two] & ~inside


def _face_jumps(zp, sp, d, one_step, jump, smooth, P):
    """The level changes of :func:`_raised_rows` (``lone``) whose face spans two steps of the profile:
    ``(middle points, types)`` (1 up, 2 down), indices into the concatenated points.

    A wall or a riser crossing the profile at a slant, or narrower than a cell and sampled midway,
    leaves a point on its face: the change of level splits into two steps of one sign, each possibly
    within the jump, while the two together exceed it. As the one-step test, the rise of the two
    steps beyond the terrain's slope over the same run before them (the fall beyond the slope after
    them) must exceed ``jump``; faces whose first or second step is a one-step level change
    (``one_step``) are not counted twice. A point on the face is weaker evidence than a jump within
    one step: the edge of a crown on a steep hillside falls so too (ISPRS 11 at 2 m: 10.98 -> 11.94 %
    total error without the two tests below). So both sides must be level ground, as a terrace's
    tread or a quarry's bench is: the three points on each lie on a smooth line (second difference
    within ``smooth``: step 4's test of vegetation beside a building's walls, Jacobsen 2004, at the
    ground's own noise) and change by at most half the jump over the face's run (step 4's height of
    a raised point: within it, the side is one level). ``zp``, ``sp``: the padded heights and
    same-profile flags of :func:`_raised_rows` (``P`` points of padding), ``d`` the steps between
    consecutive points.
    """
    with np.errstate(invalid="ignore"):
        # middle points m (1 <= m <= n - 2): z_{m+1} - z_{m-1} beyond the jump, both steps of one sign
        m = 1 + np.flatnonzero((np.abs(d[:-1] + d[1:]) > jump) & (d[:-1] * d[1:] > 0))
    if not m.size:
        return m, np.zeros(0, np.int8)
    j = m + P
    m = m[sp[j] & sp[j + 1]]                              # m - 1, m, m + 1 on one profile
    m = m[~np.isin(m, one_step) & ~np.isin(m + 1, one_step)]
    j = m + P
    zb, za = zp[j - 1], zp[j + 1]                         # before and after the face
    with np.errstate(invalid="ignore"):
        rise_before = np.maximum(zb - zp[j - 3], 0.0)     # the slope over the two steps before
        up = (za - zb - rise_before > jump) & sp[j - 1] & sp[j - 2]
        fall_after = np.maximum(za - zp[j + 3], 0.0)      # ... and after
        down = (zb - za - fall_after > jump) & sp[j + 2] & sp[j + 3]
        sides = ((np.abs(zb - 2 * zp[j - 2] + zp[j - 3]) <= smooth)
                 & (np.abs(za - 2 * zp[j + 2] + zp[j + 3]) <= smooth)
                 & (np.abs(zb - zp[j - 3]) <= 0.5 * jump) & (np.abs(za - zp[j + 3]) <= 0.5 * jump))
    keep = (up | down) & sides & sp[j - 1] & sp[j - 2] & sp[j + 2] & sp[j + 3]
    return m[keep], np.where(up[keep], 1, 2).astype(np.int8)


def _cut_runs(out, cut, zc, flat, pos, ev, typ, starts, cnt, lmax, jump):
    """The levels cut by the raster's edge of :func:`_raised_rows` (its events ``ev, typ``
    along the concatenated rows of the points ``flat``, heights ``zc``, positions ``pos``; the
    first point of each row among ``starts``, ``cnt`` points per row) appended to the list
    ``cut``: ``(cells, walls, heights)`` (flat indices, the jumps' heights at the walls). A row's
    start or end is the raster's edge (a break line's restarts are not)."""
    n = flat.size
    w = out.shape[1]
    rows_first = (np.cumsum(cnt) - cnt)[cnt > 0]          # the first point of each row
    row_end = np.zeros(n, bool)
    row_end[np.cumsum(cnt)[cnt > 0] - 1] = True           # the last point of each row
    is_start = np.zeros(n, bool)
    is_start[rows_first] = True
    # a jump up whose next event is a row's start (or none): the level runs to the row's end
    nxt = np.append(ev[1:], n)
    ntyp = np.append(typ[1:], 0)
    up = np.flatnonzero((typ == 1) & (ntyp == 0) & ((nxt == n) | is_start[np.minimum(nxt, n - 1)]))
    a_up, b_up = ev[up], nxt[up]                          # cells a .. b - 1 (b: the next row's first)
    # a jump down whose previous event is a row's start: the level runs from the row's start
    prev_i = np.flatnonzero((typ[1:] == 2) & (typ[:-1] == 0)) + 1
    prev_i = prev_i[is_start[ev[prev_i - 1]]]
    a_dn, b_dn = ev[prev_i - 1], ev[prev_i]               # cells a .. b - 1, wall b - 1
    a_all = np.concatenate([a_up, a_dn])
    b_all = np.concatenate([b_up, b_dn])
    ok = (pos[b_all - 1] - pos[a_all]) < lmax
    if a_up.size:                                          # the row ends at the raster's edge
        ok[:a_up.size] &= pos[b_up - 1] % w == w - 1
    if a_dn.size:
        ok[a_up.size:] &= pos[a_dn] % w == 0
    # the ground beyond the jump: before the jump up, after the jump down
    g = np.concatenate([a_up - 1, b_dn])
    wall = np.concatenate([a_up, b_dn - 1])
    a_all, b_all, g, wall = a_all[ok], b_all[ok], g[ok], wall[ok]
    lens = b_all - a_all
    if not lens.size:
        return
    first = np.repeat(a_all, lens)
    c = np.arange(lens.sum()) - np.repeat(np.cumsum(lens) - lens, lens) + first
    with np.errstate(invalid="ignore"):
        hit = zc[c] - np.repeat(zc[g], lens) > 0.5 * jump
    cut.append((flat[c[hit]], flat[wall], zc[wall] - zc[g]))          # the jump's height


def _raster_rim(window, shape):
    """The cells of the window ``window`` (a pair of slices with starts and stops) of a raster of
    ``shape`` that lie on the raster's outer rows and columns (bool, the window's shape)."""
    rows, cols = window
    rim = np.zeros((rows.stop - rows.start, cols.stop - cols.start), bool)
    if rows.start == 0:
        rim[0] = True
    if rows.stop == shape[0]:
        rim[-1] = True
    if cols.start == 0:
        rim[:, 0] = True
    if cols.stop == shape[1]:
        rim[:, -1] = True
    return rim


def _cut_levels(z, cells, walls, lmax, jump, heights, paired=None, ground=None):
    """The levels cut by the raster's edge that are buildings, from the cells ``cells`` of
    :func:`_raised_rows`' cut runs along X and Y and their walls ``walls`` (``lmax = (columns,
    rows)``: the longest building in cells).

    A level is the part of the raster joined by steps of at most the ``jump``
    (:func:`~bare_earth.core.estimate.smooth_parts`) holding such runs, mostly made of them; it
    is a building when :func:`~bare_earth.core.edge_walls.walled_levels` takes it: seen within the
    longest building, standing on those walls over more than half its seen outline, and its walls
    running within twice the longest building, mirrored at the raster's edge, and, cut by the
    raster on two opposite sides, the ground beyond its walls stepping down no further at its own
    scale (quarry benches around a pit in a corner of the raster, 80 % objects at 0.5 m without
    this).

    Beyond the raster's edge nothing is seen: a level from a jump up to the edge may be a roof
    running off the raster (a hall over most of a tile: lidar ``sample_c``) or the upper level of
    a terrain step. Its walls tell: mirrored at every side of the raster they meet, a wall cutting
    off a corner runs twice what is seen, within twice the longest building whenever what is
    seen lies within it; a wall running across the raster, from one side to the opposite one (a
    terrace's, a river's or a quarry bench's wall), continues beyond both and runs three times
    what is seen: the terrain's unless shorter than two thirds of the longest building. A level
    that comes down to the ground gradually (a hillside, a terrace's bank, a ramp) stands on no
    wall there. The level, not the runs alone, is the building: a profile with no jump of its own
    across the wall (one along the raster's edge, or one whose ground beside the wall is rough)
    runs on the level from edge to edge and finds nothing. The levels are looked for in the bands
    along the raster's sides that hold cut runs, one longest building (and a cell) deep: one
    reaching farther is longer than that, and so is, in a block, one cut by the block's window.

    ``paired``: the cells the same pass's pairs of jumps took (a jump up and a jump down within the
    longest building). A roof running into the raster's edge at a slant, or an L-shaped one, has
    both: the profiles crossing its far part meet both its walls, those crossing its part at the
    edge one wall and the edge. Its cut runs are then a small part of its level (ISPRS 41's station
    roof, a block running into the tile's corner, 113 x 82 m seen: 416 of its 2,918 cells at 1 m),
    and the part the pairs did not take stood as ground. A level meeting the raster's edge (as a cut
    run does) that holds cut runs is a candidate too when they and the cells the pairs took make
    most of it; its walls are then also its cells stepping down by more than the jump to a
    neighbour (the pairs' walls, which the cut runs do not record). Such levels are decided apart
    from the others (each call of :func:`~bare_earth.core.edge_walls.walled_levels` sees only its
    own levels: a wall of one is no wall of a terrace beside it), by the same tests.

    ``ground``: the cells left as ground (given by :func:`remove_level_changes` from its second
    pass on, whose ``paired`` holds the levels the passes before took). A level rising by more than
    the jump to a cell of ``ground`` beside it (8-neighbours) over more than half of its seen
    outline lies below the terrain around it: the strip of a terrace below a retaining wall, whose
    houses the first pass took (they make most of its cells with its cut runs), not a roof; a lower
    roof rises only to the higher parts taken before it. Such a level is no candidate (the
    synthetic hillside's terraces, 8-31 % objects: 2 m highest 10.31 -> 9.20 %)."""
    h, w = z.shape
    out = np.zeros(z.shape, bool)
    dr, dc = min(h, lmax[1] + 1), min(w, lmax[0] + 1)
    bands = ((slice(0, dr), slice(0, w)), (slice(h - dr, h), slice(0, w)),
             (slice(0, h), slice(0, dc)), (slice(0, h), slice(w - dc, w)))
    for band in bands:
        cb = cells[band]
        if not cb.any():
            continue
        pb = None if paired is None else paired[band]
        zb = z[band]
        idx = np.flatnonzero(np.isfinite(zb))
        n_parts, part = smooth_parts(zb, idx, jump)
        lab = np.zeros(zb.shape, np.int32)
        lab.ravel()[idx] = part + 1
        tot = np.bincount(lab.ravel(), minlength=n_parts + 1)
        hit = np.bincount(lab[cb], minlength=n_parts + 1)
        cand = (hit > 0) & (2 * hit >= tot)
        with_pairs = np.zeros_like(cand)
        if pb is not None and pb.any():
            # a level meeting the raster's edge, mostly its cut runs and the cells the pairs took
            held = np.bincount(lab[cb | pb], minlength=n_parts + 1)
            rim = _raster_rim(band, (h, w))
            meets = np.zeros(n_parts + 1, bool)
            meets[lab[rim]] = True
            with_pairs = (hit > 0) & ~cand & (2 * held >= tot) & meets
        cand[0] = with_pairs[0] = False
        if not (cand.any() or with_pairs.any()):
            continue
        # each cell's drop to its lowest 8-neighbour; a level's own scale: its jumps' heights
        zp = np.pad(np.where(np.isfinite(zb), zb, np.inf), 1, constant_values=np.inf)
        low = np.full(zb.shape, np.inf, np.float32)
        for ddr in (0, 1, 2):
            for ddc in (0, 1, 2):
                np.minimum(low, zp[ddr:ddr + zb.shape[0], ddc:ddc + zb.shape[1]], out=low)
        with np.errstate(invalid="ignore"):
            drops = np.where(np.isfinite(zb), zb - low, 0.0)
        if ground is not None:
            # terrain continuing: a level rising by more than the jump to ground left beside it over
            # more than half of its seen outline (the raster's edge and the band's inner side hold
            # none) lies below the terrain around it, a terrace below a retaining wall, no roof (a
            # lower roof beside a higher one rises to the roof taken)
            fin = np.isfinite(zb)
            gp = np.pad(np.where(ground[band] & fin, zb, -np.inf), 1, constant_values=-np.inf)
            fp = np.pad(fin, 1)
            lp = np.pad(lab, 1)
            rise = np.zeros(zb.shape, bool)
            edge = np.zeros(zb.shape, bool)
            for ddr in (0, 1, 2):
                for ddc in (0, 1, 2):
                    win = (slice(ddr, ddr + zb.shape[0]), slice(ddc, ddc + zb.shape[1]))
                    other = lp[win] != lab
                    edge |= other & fp[win]
                    with np.errstate(invalid="ignore"):
                        rise |= other & (gp[win] - zb > jump)
            n_edge = np.bincount(lab[edge], minlength=n_parts + 1)
            n_rise = np.bincount(lab[rise & edge], minlength=n_parts + 1)
            below = 2 * n_rise > n_edge
            cand &= ~below
            with_pairs &= ~below
        # each kind of level decided on its own, the other levels outside it (a wall of one is no
        # wall of the level beside it); the pairs' walls: the level's cells stepping down by more
        # than the jump
        for take, extra in ((cand, None), (with_pairs, drops > jump)):
            if not take.any():
                continue
            lab_t = np.where(take[lab], lab, 0)
            wb = walls[band] if extra is None else walls[band] | (extra & (lab_t > 0))
            keep = walled_levels(lab_t, n_parts, wb, (lmax[1], lmax[0]), 2 * max(lmax),
                                 origin=(band[0].start, band[1].start), shape=(h, w), drops=drops, step=jump,
                                 wall_heights=heights[band])
            out[band] |= keep[lab_t]
    return out


def _jump_limits(jump_m, sigma_m, k, bend_m):
    """Step 4's ``(jump, smoothness limit)``: ``jump_m`` and ``2 k sigma`` (the ground beside a
    jump lies on a smooth line), each widened in quadrature by ``k`` times the terrain's own
    bend over one cell (``bend_m``)."""
    bend = k * max(0.0, float(bend_m))
    return float(np.hypot(jump_m, bend)), float(np.hypot(2.0 * k * sigma_m, bend))


def find_terrain_steps(z: np.ndarray, cell_size: Union[float, Sequence[float]], keep: np.ndarray, *,
                       jump_m: float, max_building_m: float, sigma_m: float, k: float = 3.0,
                       bend_m: float = 0.0, labels: Optional[np.ndarray] = None,
                       z_t: Optional[np.ndarray] = None, sides: bool = False, join_gap_m: float = 0.0,
                       ground_sigma_m: Optional[float] = None,
                       progress: Optional[Callable[[float], None]] = None) -> np.ndarray:
    """Step 4's level changes that belong to the terrain: break lines derived from the DSM.

    Step 4's jumps (:func:`remove_level_changes`, on the points it left, without its test of
    vegetation beside a building's walls) that no other jump answers (a jump up not followed
    within ``max_building_m`` by a jump down, a jump down not preceded by one), along X and Y;
    the cells on both sides of each, joined 8-connected into lines, are kept where a line spans
    more than ``max_building_m`` (along X or Y): a level change longer than the longest building is the terrain's own (a
    quarry bench, a river bank, a terrace wall). Jacobsen (2004) protects such edges with
    break lines, which no comparison crosses; without them, the moving profiles and surfaces
    of steps 5 and 6, pulled down by the lower level, eat into the upper one.
    ``progress(fraction)`` is called every band of rows (it may raise ``Cancelled``); ``z_t``
    is ``transpose(z)`` when the caller has it (made here otherwise).

    With ``join_gap_m`` > 0, the pieces of a line that a tree, a bush or a gap in the data cut
    (each running further than half of ``max_building_m``, so that two joined run further than
    any building, and than ``join_gap_m``; noise and the edges of crowns join nothing) are joined across
    gaps of up to ``join_gap_m`` (the pieces grown by half of it, in whole cells) and measured
    together: a terrace wall along a hillside whose foot trees stand at every 100 m is one line
    (:data:`~.sequence.WALL_TOP_GAP_M`, as for the wall tops step 3 took).

    A jump over the points kept may step over one or two cells step 3 took (a wall's top): those
    cells, the face, are on its line too where both sides of the jump are ground (:func:`_face_cells`),
    joining its two sides into one line along the wall.

    With ``sides``, also the upper side of the lines: their cells above their jump along a profile
    (after a jump up, before a jump down) and below none. :func:`~.regions.break_regions` makes
    each side a line of its own: a wall's top is then compared with the cells along the top, never
    with the wall's foot (with one line of both sides, the top and foot cells of a wall running
    across the rows at a slant are neighbours along a row, and step 3 took the top again).

    Returns
    -------
    steps : ndarray of bool
        Cells on those lines (empty where none).
    upper : ndarray of bool
        With ``sides`` only: the cells of ``steps`` on the upper side of their jumps.
    """
    dx, dy = as_cell_size(cell_size)
    jump = _jump_limits(jump_m, sigma_m, k, bend_m)[0]
    # a face over two steps: level ground on both sides, at the ground's own noise; none where the
    # terrain itself bends beyond its noise from one cell to the next (a coarse DEM of hills: a height
    # midway down a drop of two cells is as likely the terrain's own bend)
    faces = not float(bend_m) > 0.0
    smooth = _jump_limits(jump_m, sigma_m if ground_sigma_m is None else min(sigma_m, ground_sigma_m), k, bend_m)[1]
    cells = np.zeros(z.shape, bool)
    high = np.zeros(z.shape, bool)
    low = np.zeros(z.shape, bool)
    # Y profiles run along the rows of the transposed arrays; bands of whole rows
    views = [(z, keep, labels, int(max_building_m / dx), lambda a: a),
             (transpose(z) if z_t is None else z_t, transpose(keep), None if labels is None else transpose(labels),
              int(max_building_m / dy), transpose)]
    for d, (zz, kk, lab, lmax, fwd) in enumerate(views):
        found = np.zeros(zz.shape, bool)
        up = np.zeros(zz.shape, bool)
        dn = np.zeros(zz.shape, bool)
        bands = row_bands(*zz.shape, 16 * BAND_CELLS)
        for i, b in enumerate(bands):
            report(progress, (d + i / len(bands)) / 2)
            found[b] = _raised_rows(zz[b], kk[b], None if lab is None else lab[b], jump, lmax, smooth,
                                    lone=True, upper=up[b], lower=dn[b], faces=faces)
        cells |= fwd(found)
        high |= fwd(up)
        low |= fwd(dn)
    lab, n = label8(cells)
    if not n:
        return (cells, cells) if sides else cells
    span = np.array([0.0] + [max((r.stop - r.start) * dy, (c.stop - c.start) * dx)
                             for r, c in ndimage.find_objects(lab)])
    steps = (span > max_building_m)[lab]
    ry, rx = int(join_gap_m // (2 * dy)), int(join_gap_m // (2 * dx))
    if ry or rx:
        # a line's pieces cut by a tree, a bush or a gap in the data: those running further than half
        # the longest building (two of them joined run further than any building) and than the gap
        # they bridge, joined across gaps of up to join_gap_m, measured together (the edges of crowns
        # and of patches of vegetation, shorter, join nothing: joined from 4 m on, they protected the
        # vegetation of ISPRS 11 and 51 as the terrain's lines)
        pieces = (span > max(join_gap_m, 0.5 * max_building_m))[lab] & ~steps
        if pieces.any():
            # (the box's separable dilation, common.dilate_box: the same cells, a tenth of the time)
            grown = dilate_box(pieces | steps, ry, rx)
            jl, jn = label8(grown)
            jl[~(pieces | steps)] = 0
            box = ndimage.find_objects(jl, jn)
            jspan = np.array([0.0] + [0.0 if b is None else max((b[0].stop - b[0].start) * dy,
                                                                 (b[1].stop - b[1].start) * dx) for b in box])
            steps |= (jspan > max_building_m)[jl]
    if not sides:
        return steps
    # the upper side of the lines: cells above their jump along a profile and below none
    return steps, steps & high & ~low


def remove_level_changes(z: np.ndarray, cell_size: Union[float, Sequence[float]], keep: np.ndarray, *,
                         jump_m: float, max_building_m: float, sigma_m: float, k: float = 3.0,
                         bend_m: float = 0.0, labels: Optional[np.ndarray] = None, passes: int = 2,
                         z_t: Optional[np.ndarray] = None, cut_at_edge: bool = False,
                         progress: Optional[Callable[[float], None]] = None) -> np.ndarray:
    """Step 4: sudden change of level along X and Y profiles (buildings).

    Along each profile (consecutive remaining points, never across a break line) a *jump
    up* is a rise of more than ``jump_m`` beyond the slope of the terrain before it, a
    *jump down* a fall of more than ``jump_m`` beyond the slope after it. The points from
    a jump up to the next jump down are removed when the two are at most
    ``max_building_m`` apart, no other jump lies between, the points lie at least
    ``jump_m / 2`` above the line joining the ground points outside the jumps, and there is
    no vegetation beside the jumps (the three points outside each jump lie on a smooth
    line: second difference below ``2 k sigma``; ground is smooth, crowns and bushes are
    not). X and Y profiles are combined by union; ``passes``
    repetitions peel nested levels (roof superstructures). ``progress(fraction)`` is
    called every band of rows (it may raise ``Cancelled``); ``z_t`` is ``transpose(z)`` when
    the caller has it (made here otherwise).

    With ``cut_at_edge``, a level the raster's edge cuts (a jump up and the profile's end at
    the raster's edge with no jump down between, or the reverse), as the first pass finds
    it along X and Y, is a building when its cells seen lie within ``max_building_m`` and its
    walls run within twice that, mirrored at the edge (:func:`_cut_levels`: a roof over most
    of a tile, whose wall cuts off a corner of it, is one; the upper level of a terrain step
    running across the raster is not). Every pass looks for them on the points the passes before
    left: a lower roof between a higher one and the edge is climbed from the ground once the higher
    one is gone (ISPRS 41's corner: 1 m lowest 4.57 -> 3.70 %, 2 m highest 4.96 -> 4.16 %); a band
    of profiles no removal touched keeps its cut runs (a profile's result depends on it alone). The
    cells the passes before took count with the pairs, so a terrace whose houses they took could
    be such a level: from the second pass on, a level rising to the ground left beside it over more
    than half of its outline is the terrain's (:func:`_cut_levels`' ``ground``).
    Without it (the parameters' sample windows, whose edges are not the raster's), such a level is
    never a building, as Jacobsen's pairs of jumps have it.

    A limit at coarse cells on mountains: a bench meeting a steep slope within one cell, or a spur
    crossing a profile, rises beyond the slope before it by more than the jump (lidar hexbin-crop at
    4 m, slope 0.42: 3 m over a 4 m cell; step 4 takes 3.4 % of its cells, 10.5 % total error against
    about 5 % for the other filters). That is the terrain's bend over a cell, which
    :func:`~.parameters.terrain_bend` reads as 0 there (scaled from 20 m blocks by the square of the
    spacing); given as 0.7 / 1.0 m, 7.1 / 5.9 %. Tried and not adopted (generalisation matrix, RASCOR):
    the jump widened in quadrature by ``k g / sqrt(2)`` (the heights' places inside their cells, as
    step 3's pairs, ``g`` the slope beside the jump up to the terrain's rise over a cell): hexbin-crop
    4 m 10.52 -> 9.58 %, but ISPRS 11 2 m highest 28.03 -> 28.46 (houses on its 0.49 slope), half A
    worse; ``g`` the terrain's rise everywhere: 7.10 %, ISPRS 11 2 m highest 32.15. The slope allowance
    extrapolated over the cells an earlier step took between the two points of a jump (up to the rise
    a cell): hexbin-crop 4 m 9.49, 2 m 0.92 -> 1.22, opengeos 2 m 12.84 -> 12.93. The rise before (the fall
    after) as a rise per cell times the step's run, uncapped, from the positions of the points kept
    (twenty-ninth session, on single rows): hexbin-crop 4 m 8.83, 1 m* 2.01 -> 2.58, 2 m 0.92 -> 1.25,
    opengeos 2 m 12.84 -> 13.26, ISPRS 11 2 m lowest 11.20 -> 11.51, 61 2 m lowest 5.66 -> 5.96; never less
    than the paper's one-step rise: much the same; in the building pairs only (not the terrain's lines):
    hexbin-crop 4 m 8.97, ISPRS 11 2 m lowest 11.04, highest 28.03 -> 28.14, opengeos 12.84 -> 13.26 (step 4
    took 10179 -> 8176 of its cells: a one-step rise of two heights is noisy, and scaled by the run its noise
    grows with it; not adopted, the matrix not run). The linear scaling of
    the bend (:func:`~.parameters.terrain_bend`) in this step alone: hexbin-crop 4 m 8.13, 2 m 0.92 -> 2.43,
    ISPRS 41 2 m lowest 6.42 -> 8.46. The joined levels' step (:func:`~.sequence.level_step`) capped at
    half the jump plus the rise instead of half the jump: hexbin-crop 4 m 7.58, ISPRS 11 2 m highest
    31.40 (on a slope a roof's uphill neighbour lies only half the jump less the rise below it: the cap
    would have to shrink with the slope, not grow).

    Returns
    -------
    high : ndarray of bool
    """
    dx, dy = as_cell_size(cell_size)
    jump_m, veg_tol = _jump_limits(jump_m, sigma_m, k, bend_m)
    cur = keep.copy()
    high = np.zeros(z.shape, bool)
    # Y profiles run along the rows of the transposed arrays; bands of whole rows
    views = [(z, labels, int(max_building_m / dx), lambda a: a),
             (transpose(z) if z_t is None else z_t, None if labels is None else transpose(labels),
              int(max_building_m / dy), transpose)]
    redo = [None, None]
    # each band's cut runs, kept from the pass that last ran it: a band no removal touched gives the
    # same runs again (a profile's result depends on that profile alone)
    band_cuts = [{}, {}]
    for p in range(passes):
        new = np.zeros(z.shape, bool)
        cuts = ((np.zeros(z.shape, bool), np.zeros(z.shape, bool), np.zeros(z.shape, np.float32))
                if cut_at_edge else None)
        for d, ((zz, lab, lmax, fwd), todo) in enumerate(zip(views, redo)):
            c = fwd(cur)
            found = np.zeros(zz.shape, bool)
            bands = row_bands(*zz.shape, 16 * BAND_CELLS)
            for i, b in enumerate(bands):
                report(progress, (2 * p + d + i / len(bands)) / (2 * passes))
                # a profile's result depends on that profile alone: later passes redo
                # only the bands of rows / columns where something was removed
                if todo is None or todo[b].any():
                    got = [] if cuts is not None else None
                    found[b] = _raised_rows(zz[b], c[b], None if lab is None else lab[b],
                                            jump_m, lmax, veg_tol, cut=got)
                    if got:                                       # the band's flat indices in the view's
                        band_cuts[d][i] = tuple(a + b.start * zz.shape[1] for a in got[-1][:2]) + got[-1][2:]
                    else:
                        band_cuts[d].pop(i, None)
            new |= fwd(found)
            cut = [band_cuts[d][i] for i in sorted(band_cuts[d])] if cuts is not None else None
            if cut:
                # the cut runs lie along the raster's sides: their indices in the raster, not whole
                # arrays of the view transposed (the heights at a wall: the largest of X's and Y's)
                cells, walls, heights = (np.concatenate(a) for a in zip(*cut))
                if d:
                    cells, walls = ((a % zz.shape[1]) * zz.shape[0] + a // zz.shape[1] for a in (cells, walls))
                cuts[0].ravel()[cells] = True
                cuts[1].ravel()[walls] = True
                cuts[2].ravel()[walls] = np.maximum(cuts[2].ravel()[walls], heights)
        if cuts is not None and cuts[0].any():
            # the cells step 4 took: this pass's pairs and the earlier passes' levels
            new |= _cut_levels(z, cuts[0], cuts[1], (views[0][2], views[1][2]), jump_m, cuts[2],
                               paired=(new & cur) | high,
                               ground=~((new & cur) | high) if p else None)
        new &= cur
        if not new.any():
            break
        high |= new
        cur &= ~new
        redo = [new.any(axis=1), new.any(axis=0)]
    return high





def joined_levels(z: np.ndarray, cell_size: Union[float, Sequence[float]], raised: np.ndarray,
                  kept: np.ndarray, *, step_m: float, max_building_m: float) -> np.ndarray:
    """The cells of step 4's raised levels that the ground continues onto: no building's.

    Step 4 reads one profile at a time: a road embankment or a dike crossing a profile rises
    by a jump and falls by another within the longest building, as a building does, and its
    crown is taken for a roof (ISPRS samples 61 and 71, whose banks sparse points make walls
    of). In plan the two differ: a roof is a level cut off by its walls and no longer than the
    longest building, while the crown of an embankment runs on and joins the ground without a
    level change (a ramp down to the road it carries, a dike's end or its gentler side). The
    ``kept`` cells (which hold ``raised``) are joined across the 4-neighbour edges whose heights
    differ by at most ``step_m``; the ``raised`` cells of a part running further than
    ``max_building_m`` along the rows or the columns (the ground around, or a level longer than
    any building) are returned.

    The parts are the runs of cells joined along the rows, joined down the columns
    (:func:`~bare_earth.core.estimate.joined_runs`: the 4-connected components the labelling
    of a grid of twice the resolution holding the cells and their joined edges gave, in a
    quarter of its time), on the cells within ``max_building_m`` and one cell of a raised cell
    only: a part leaving that window runs further than ``max_building_m`` from the raised cell
    inside it, so the window decides as the whole raster would.

    Parameters
    ----------
    z : ndarray
        DSM (NaN nodata).
    cell_size : float or (float, float)
        (dx, dy) metres.
    raised, kept : ndarray of bool
        Step 4's raised cells and the points the steps before it kept (``raised`` among them).
    step_m : float
        Largest difference of neighbouring heights on continuing ground, metres.
    max_building_m : float
        Step 4's longest building, metres.

    Returns
    -------
    ndarray of bool
        The cells of ``raised`` joined to a part longer than the longest building.

    Examples
    --------
    >>> z = np.zeros((5, 9), np.float32)
    >>> z[1:4, 3:6] = 3.0                          # a roof on walls
    >>> raised = z > 0
    >>> kept = np.ones(z.shape, bool)
    >>> joined_levels(z, 10.0, raised, kept, step_m=0.5, max_building_m=50.0).any()
    False
    >>> z[2, 6:] = [2.0, 1.0, 0.0]                 # ... a ramp down to the ground on its side
    >>> int(joined_levels(z, 10.0, raised, kept, step_m=1.0, max_building_m=50.0).sum())
    9
    """
    dx, dy = as_cell_size(cell_size)
    raised = np.asarray(raised, bool)
    out = np.zeros(raised.shape, bool)
    rows = np.flatnonzero(raised.any(axis=1))
    if not rows.size:
        return out
    cols = np.flatnonzero(raised.any(axis=0))
    mr, mc = int(max_building_m / dy) + 2, int(max_building_m / dx) + 2
    win = (slice(max(0, rows[0] - mr), rows[-1] + 1 + mr), slice(max(0, cols[0] - mc), cols[-1] + 1 + mc))
    zw = np.asarray(z[win], np.float32)
    kw = np.asarray(kept[win], bool) & np.isfinite(zw)
    at = np.flatnonzero(raised[win] & kw)              # the raised cells that are nodes of the graph
    if not at.size:
        return out
    run, comp, first = joined_runs(zw, kw, step_m)
    w = zw.shape[1]
    row, c0, c1 = first // w, first % w, (np.r_[first[1:], zw.size] - 1) % w
    need = np.zeros(int(comp.max()) + 1, bool)
    need[comp[run[at]]] = True
    # the extents of the parts holding raised cells, from their runs
    sel = np.flatnonzero(need[comp])
    order = sel[np.argsort(comp[sel], kind="stable")]
    cs = comp[order]
    first = np.flatnonzero(np.r_[True, cs[1:] != cs[:-1]])
    n_rows = np.maximum.reduceat(row[order], first) - np.minimum.reduceat(row[order], first) + 1
    n_cols = np.maximum.reduceat(c1[order], first) - np.minimum.reduceat(c0[order], first) + 1
    long = np.zeros(need.size, bool)
    long[cs[first]] = np.maximum(n_rows * dy, n_cols * dx) > max_building_m
    ow = np.zeros(zw.shape, bool)
    ow.ravel()[at] = long[comp[run[at]]]
    out[win] = ow
    return out


def enclosed_levels(z: np.ndarray, cell_size: Union[float, Sequence[float]], *, jump_m: float, step_m: float,
                    min_span_m: float, max_span_m: float, k: float = 3.0, bend_m: float = 0.0) -> np.ndarray:
    """Raised levels longer than step 4's profiles see, closed by walls down: roofs of large halls.

    Step 4 pairs a jump up with a jump down at most ``max_building_m`` apart along X or Y: a hall
    longer than that along both (a 200 x 130 m hall, a 120 m block round a courtyard) is no pair
    of jumps on any profile, and :func:`joined_levels` takes its roof, a level running further
    than the longest building, for the ground's. In plan the roof is a level its walls close on
    every side, which a level of the terrain is not: a terrace's or a quarry bench's level rises
    on its uphill side to the slope above, a plateau or a river bank runs on to the raster's edge,
    an embankment's crown comes down to the ground by a ramp (and is then one part with it). The
    cells are joined across the 4-neighbour edges whose heights differ by at most ``step_m``
    (:func:`~bare_earth.core.estimate.joined_runs`, on the DSM itself); a part is a closed raised
    level when it meets no side of the raster and no nodata cell (nothing is seen beyond either:
    a terrace's level running into the raster's outer nodata may run on), runs further than ``min_span_m`` and at most
    ``max_span_m`` along the rows or the columns, and more than half of its outline (its edges to
    the cells of other parts) steps down by more than ``jump_m``, as :mod:`..edge_walls`
    asks of a level cut by the raster's edge (the 24 sites of ``benchmarks/sites.py``: the halls'
    outlines 93-100 % walls, terraces' and quarry benches' longer than 40 m 19-43 %, rising on
    51-75 % of it).

    The decision reads the DSM within ``max_span_m`` and a cell of each level: a window reaching
    that far around a block sees the whole of every level it takes, and a level cut by the
    window's edge meets a side of it (not taken), as in one pass a level longer than
    ``max_span_m`` is not.

    Parameters
    ----------
    z : ndarray
        DSM (NaN nodata).
    cell_size : float or (float, float)
        (dx, dy) metres.
    jump_m : float
        Step 4's jump: the drop of a wall, metres.
    step_m : float
        Largest difference of neighbouring heights within a level, metres.
    min_span_m, max_span_m : float
        The levels taken run further than ``min_span_m`` (step 4's longest building: shorter
        ones are step 4's profiles') and at most ``max_span_m``, metres.
    k, bend_m : float
        Step 4's critical value and the terrain's bend over one cell: the jump is widened by
        ``k bend_m`` in quadrature, as :func:`remove_level_changes` widens it.

    Returns
    -------
    ndarray of bool
        The cells of the closed raised levels.

    Examples
    --------
    >>> z = np.zeros((9, 12), np.float32)
    >>> z[2:7, 2:10] = 6.0                           # a roof 8 cells long, walls all round
    >>> int(enclosed_levels(z, 10.0, jump_m=2.0, step_m=0.5, min_span_m=50.0, max_span_m=100.0).sum())
    40
    >>> z[4, 10:] = 6.0                              # ... the level runs on to the raster's edge
    >>> int(enclosed_levels(z, 10.0, jump_m=2.0, step_m=0.5, min_span_m=50.0, max_span_m=100.0).sum())
    0
    """
    dx, dy = as_cell_size(cell_size)
    jump_m = _jump_limits(jump_m, 0.0, k, bend_m)[0]
    z = np.asarray(z, np.float32)
    h, w = z.shape
    out = np.zeros(z.shape, bool)
    if h < 3 or w < 3:
        return out
    valid = np.isfinite(z)
    run, comp, first = joined_runs(z, valid, step_m)
    n = int(comp.max()) + 1
    cand = np.ones(n, bool)
    for side in (run[:w], run[-w:], run[::w], run[w - 1::w]):   # a level meeting the raster's side runs on
        cand[comp[side]] = False
    gap = np.flatnonzero(~valid)                         # ... or nodata: nothing is seen beyond either
    if gap.size:
        gr, gc = gap // w, gap % w
        for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
            rr, cc = gr + dr, gc + dc
            inside = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
            cand[comp[run[rr[inside] * w + cc[inside]]]] = False
        cand[comp[run[gap]]] = False
    if not cand.any():
        return out
    # the candidates' extents from their runs (a run: cells first .. last of one row)
    last = np.r_[first[1:], h * w] - 1
    sel = np.flatnonzero(cand[comp])
    p = comp[sel]
    order = np.argsort(p, kind="stable")
    sel, p = sel[order], p[order]
    starts = np.flatnonzero(np.r_[True, p[1:] != p[:-1]])
    r = first[sel] // w
    rows = np.maximum.reduceat(r, starts) - np.minimum.reduceat(r, starts) + 1
    cols = np.maximum.reduceat(last[sel] % w, starts) - np.minimum.reduceat(first[sel] % w, starts) + 1
    span = np.maximum(rows * dy, cols * dx)
    ok = np.zeros(n, bool)
    ok[p[starts]] = (span > min_span_m) & (span <= max_span_m)
    if not ok.any():
        return out
    # the cells of the levels left, from their runs
    keep_runs = sel[ok[p]]
    lens = last[keep_runs] - first[keep_runs] + 1
    cells = np.repeat(first[keep_runs], lens) + (np.arange(int(lens.sum())) - np.repeat(np.cumsum(lens) - lens, lens))
    p = comp[run[cells]]
    r, c = cells // w, cells % w
    # the outline: edges to the cells of other parts with data; walls: those stepping down by the jump
    zf = z.ravel()
    vf = valid.ravel()
    edges = np.zeros(n, np.int64)
    walls = np.zeros(n, np.int64)
    zc = zf[cells]
    for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        rr, cc = r + dr, c + dc
        inside = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
        nb = np.where(inside, rr * w + cc, 0)
        e = inside & (comp[run[nb]] != p) & vf[nb]
        edges += np.bincount(p[e], minlength=n)
        with np.errstate(invalid="ignore"):
            walls += np.bincount(p[e & (zc - zf[nb] > jump_m)], minlength=n)
    closed = 2 * walls > edges
    out.ravel()[cells[closed[p]]] = True
    return out
