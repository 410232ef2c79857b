"""RASCOR: sequential DSM filtering with automatically determined parameters (Jacobsen 2004).

Jacobsen's program RASCOR filters a raster DSM by a *sequence* of tests, each catching
what the others miss, its parameters derived from an analysis of the DSM itself:

1. **Terrain characterisation** (:func:`characterise_terrain`): the area is classed as
   homogeneous or not and as *flat*, *rolling* (undulated) or *mountainous* from the
   slopes of a lower envelope of the DSM; the class chooses the models and defaults below.
2. **Height distribution** (:func:`remove_height_outliers`): in flat areas only, heights
   far outside the distribution of heights are removed (the paper: in rolling or
   mountainous terrain the height distribution says nothing, the step is skipped).
3. **Height differences of neighbouring points** (:func:`remove_neighbour_differences`):
   the upper point of a pair is removed when the difference exceeds a tolerance made of
   the random error of the DSM and the local slope.
4. **Sudden change of level** (:func:`remove_level_changes`): along X and Y profiles a
   jump up to a higher level, a corresponding jump down later and no vegetation beside
   marks a building; the points between are removed.
5. **Moving local profiles** (:func:`remove_profile_outliers`), first short then long,
   the lengths chosen by analysing a sequence of lengths: each height is checked against
   the profile's mean (flat), linear regression (rolling) or polynomial (mountainous),
   with data snooping on the actual, uneven positions of the points left. In X and Y.
6. **Moving surfaces** (:func:`remove_surface_outliers`): horizontal plane, inclined
   plane or 2nd-order polynomial, the window size chosen by checking a sequence of sizes.
7. **Local prediction** (:func:`remove_prediction_outliers`, optional): least-squares
   prediction of each height from its neighbourhood (Gaussian-weighted moving plane).

Points *below* a reference surface get a weight factor (``low_weight``) instead of being
removed: their tolerance is ``1/sqrt(low_weight)`` times wider and they pull the fits
less, so ditches and cuts stay in the DTM, while the deep low blunders of image matching
are still removed (mask class 2). A second iteration of steps 3, 5, 6, 7 is optional; the
paper warns that it removes small vegetation but may generalise the terrain.

Break lines and special areas (boolean rasters ``breaklines`` and ``special_areas``,
rasterised by the plugin layer and passed by the pipeline as keyword arrays, not Params):
no comparison crosses a break line (neighbour pairs, profile steps and windows are
restricted to the connected region of non-break cells the tested cell lies in; break-line
cells are compared only with each other along the line), so a dam or an embankment keeps
its shoulders; inside special areas only the local filters run (steps 3 and 7), e.g. for
cars and bushes on a dam's slope.

Notes on the vectorised implementation
--------------------------------------
* Moving fits are computed for every cell at once from windowed moment sums (box filters
  or small centred correlations), *leave-one-out*: the tested point is not in its own fit,
  and the prediction variance factor ``h = (N^-1)_00`` of the fit on the points actually
  present is used in the test ``v / (s sqrt(1/p + h)) > k`` (Baarda's data snooping with
  ``p`` the point's weight). Missing neighbours widen ``h``: uneven spacing is handled.
  Where the window's points do not determine the model, the point is not tested.
* The mean / linear profile and the horizontal / inclined plane have dedicated kernels
  (:func:`_fit_rows`, :func:`_fit_box_2d`): running box means of ``w x^j``, ``w z x^j``
  on absolute positions (float64, O(1) per cell for any window), recentred on each cell,
  the centre taken out of the sums, the normal equations solved by cofactors. Fits and
  snooping run in bands of rows (:func:`_fit_and_snoop`; window fits with a halo of rows,
  Y profiles on a transposed copy), so no full-size float temporary is made and the
  result is that of one fit of the whole raster.
* Snooping tests all points at once against fits without them (externally studentised
  residuals); with ``snooping_iterations > 1`` the fit is repeated without the removed
  points and with the weight factor on the points found below it.
* Break lines restrict every comparison to the tested cell's region (a connected
  component of non-break cells; break cells form their own regions along the line). A
  window could still join two cells of one region around the end of a line that stops
  inside the window; in block mode, regions are labelled per block (the halo keeps the
  difference away from the block's core in practice).
* Step 3 tests, without break lines, only the cells a removal is possible for (a
  neighbour lower by more than the tolerance; higher by more than the low tolerance for
  the pits), gathering their neighbours; the result is that of the test of every cell.
* Step 4 scans the profiles of a band of rows at once as one concatenated 1-D array of
  the remaining points; only the steps larger than the jump are examined further.

Defaults: data snooping critical value 4, one fit per length, weight factor 0.02 (low
points' tolerance x 7), step 7 off, no second iteration; on the 7 ISPRS reference samples
(1 m raster of the lowest points) the mean total error is 5.3 %.

References
----------
Jacobsen, K. (2004). Int. Arch. Photogramm. Remote Sens. Spatial Inf. Sci. XXXV-B3
(Istanbul). Describes the program RASCOR (Institute of Photogrammetry and GeoInformation,
Leibniz University Hannover): terrain characterisation, height distribution, neighbour
differences, sudden change of level, moving profiles and surfaces, local prediction,
weights for points below the reference, break lines and special areas, and the highway
example (21.6 % of the points removed without, 10.4 % with break lines).
"""
from math import comb

import numpy as np
from scipy import ndimage

from .estimate import below_surroundings
from .codes import LOW, NODATA, OBJECT
from .common import FilterResult, as_cell_size, as_surface, report, transpose
from .methods import Method, Param

#: Step numbers and names (the values of the ``step`` extra).
STEP_NAMES = {1: "terrain characterisation", 2: "height distribution",
              3: "neighbour height differences", 4: "sudden change of level",
              5: "moving local profiles", 6: "moving surfaces", 7: "local prediction"}
#: Terrain classes and the degree of the profile / surface model each selects.
TERRAIN_CLASSES = ("flat", "rolling", "mountainous")
_DEGREE = {"flat": 0, "rolling": 1, "mountainous": 2}


def model_degree(terrain_class, homogeneous=True):
    """Degree of the profile / surface model: 0 mean or horizontal plane (flat), 1 linear
    regression or inclined plane (rolling), 2 polynomial (mountainous). A flat area that
    is not homogeneous (embankments, cuts, terraces) gets the linear model: a mean is
    biased wherever a window sees a slope from one side only."""
    if terrain_class not in _DEGREE:
        raise ValueError(f"terrain_class must be one of {TERRAIN_CLASSES}; got {terrain_class!r}.")
    d = _DEGREE[terrain_class]
    return d if homogeneous else max(d, 1)
#: Median slope (rise/run) of the lower envelope separating the classes.
_FLAT_MAX_SLOPE, _ROLLING_MAX_SLOPE = 0.05, 0.20
#: Homogeneous: at least this share of the fine tiles has the area's class.
_HOMOGENEOUS_SHARE = 0.9
#: Sequences analysed for the profile lengths and the surface sizes (metres).
PROFILE_LENGTHS_M = (5.0, 9.0, 15.0, 25.0, 41.0, 65.0)
SURFACE_SIZES_M = (9.0, 15.0, 25.0, 41.0, 65.0)
#: A length is accepted while its residual scale stays below this factor of the shortest's.
_SCALE_GROWTH = 2.0
#: Step 2: the limits lie at least this far (m) outside the terrain's lower envelope.
_FAR_M = 20.0
#: Floor of the estimated random error (m): rasterised laser/matching DSMs are never exact.
_SIGMA_FLOOR = 0.10

_STEP_SWITCHES = ("step1_characterise", "step2_height_distribution",
                  "step3_neighbour_differences", "step4_level_change", "step5_profiles",
                  "step6_surfaces", "step7_prediction")


# --------------------------------------------------------------------------- helpers
def _odd(n, minimum=3):
    n = max(int(round(n)), minimum)
    return n if n % 2 else n + 1


def _as_bool_raster(a, shape, name):
    if a is None:
        return None
    a = np.asarray(a)
    if a.shape != shape:
        raise ValueError(f"{name} has shape {a.shape} but the DSM has shape {shape}; rasterise "
                         f"{name} on the DSM's grid (one cell per DSM cell).")
    a = a.astype(bool) if a.dtype != bool else a
    return a if a.any() else None


def _as_homogeneous(v):
    """``homogeneous`` as a bool (accepts the Param's enum strings)."""
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if v in ("homogeneous", "yes", 1):
        return True
    if v in ("inhomogeneous", "no", 0):
        return False
    raise ValueError(f"homogeneous must be True/False, 'homogeneous' or 'inhomogeneous' (or "
                     f"'auto' in resolve_rascor_params); got {v!r}.")


def break_regions(breaklines):
    """Label the regions no comparison may leave.

    Non-break cells are labelled by 4-connected components (a diagonal step between two
    break cells does not leak); break-line cells by 8-connected components of their own,
    so a cell on a line is compared only with cells on the same line.

    Parameters
    ----------
    breaklines : ndarray of bool
        Cells crossed by a break line.

    Returns
    -------
    labels : ndarray of int32
        Region id per cell, 1..n.
    n : int
        Number of regions.
    """
    bl = np.asarray(breaklines, dtype=bool)
    lab, n1 = ndimage.label(~bl)
    lab2, n2 = ndimage.label(bl, structure=np.ones((3, 3), bool))
    lab = lab.astype(np.int32)
    lab[bl] = lab2[bl] + n1
    return lab, n1 + n2


def _region_slices(labels):
    """``[(region id, slice)]`` of every region (bounding boxes)."""
    if labels is None:
        return None
    return [(i + 1, s) for i, s in enumerate(ndimage.find_objects(labels)) if s is not None]


def _box(v, size, axis):
    """Sum of ``v`` over a centred window of ``size`` (odd) cells along ``axis``; 0 outside."""
    return ndimage.uniform_filter1d(v, size, axis=axis, mode="constant", cval=0.0) * size


def _power_sums(v, size, powers, axis):
    """``{p: sum_{k=-h..h} v[c+k] k**p}`` along ``axis`` for every centre ``c``.

    Small windows use exact centred correlations; long ones box sums of ``v x**j`` on
    centred absolute positions ``x`` combined binomially (float64), O(1) per cell.
    """
    h = size // 2
    out = {}
    powers = sorted(set(powers))
    if size <= 15 or powers == [0]:
        k = np.arange(-h, h + 1, dtype=np.float64)
        for p in powers:
            out[p] = _box(v, size, axis) if p == 0 else ndimage.correlate1d(
                v, k ** p, axis=axis, mode="constant", cval=0.0)
        return out
    n = v.shape[axis]
    shp = [1] * v.ndim
    shp[axis] = n
    x = (np.arange(n, dtype=np.float64) - n // 2).reshape(shp)
    raw = [_box(v * x ** j if j else v, size, axis) for j in range(max(powers) + 1)]
    for p in powers:
        s = raw[p].copy()
        for j in range(p):
            s += comb(p, j) * (-x) ** (p - j) * raw[j]
        out[p] = s
    return out


def _solve3_first(a, r):
    """First unknown and ``(N^-1)_00`` of symmetric 3x3 systems given element-wise."""
    (a00, a01, a02), (_, a11, a12), (_, _, a22) = a
    c00 = a11 * a22 - a12 * a12
    c01 = a12 * a02 - a01 * a22
    c02 = a01 * a12 - a11 * a02
    det = a00 * c00 + a01 * c01 + a02 * c02
    num = r[0] * c00 + r[1] * c01 + r[2] * c02
    ok = det > 1e-9 * np.abs(a00 * a11 * a22)
    with np.errstate(all="ignore"):
        return np.where(ok, num / det, np.nan), np.where(ok, c00 / det, np.nan)


def _solve_first_general(M, Z, n_unknowns):
    """First unknown and ``(N^-1)_00`` of stacked symmetric positive systems.

    Vectorised Cholesky factorisation over all cells at once (arrays of cells, a loop over
    the few matrix elements; in chunks of cells, so the many temporaries stay in the
    cache), on the system scaled to a unit diagonal; a pivot below 1e-9 marks a system the
    window's points do not determine (NaN).
    """
    shape = M[0][0].shape
    beta = np.full(shape, np.nan)
    hh = np.full(shape, np.nan)
    with np.errstate(all="ignore"):
        ok = np.isfinite(M[0][0]) & (M[0][0] > 0)
        for i in range(n_unknowns):
            ok &= M[i][i] > 0
        cells = np.flatnonzero(ok)
        u = n_unknowns
        Mf = [[M[i][j].ravel() for j in range(u)] for i in range(u)]
        Zf = [Z[i].ravel() for i in range(u)]
        for c0 in range(0, cells.size, _BAND_CELLS):
            idx = cells[c0:c0 + _BAND_CELLS]
            d = [np.sqrt(Mf[i][i][idx]) for i in range(u)]
            A = [[Mf[i][j][idx] / (d[i] * d[j]) for j in range(u)] for i in range(u)]
            r = [Zf[i][idx] / d[i] for i in range(u)]
            L = [[None] * u for _ in range(u)]
            good = np.ones(idx.size, bool)
            for j in range(u):
                s = A[j][j]
                for k in range(j):
                    s -= L[j][k] * L[j][k]
                good &= s > 1e-9
                L[j][j] = np.sqrt(np.where(s > 1e-9, s, 1.0))
                for i in range(j + 1, u):
                    t = A[i][j]
                    for k in range(j):
                        t -= L[i][k] * L[j][k]
                    L[i][j] = t / L[j][j]
            # forward substitution for the right-hand side and for e0
            y = [None] * u
            e = [None] * u
            for i in range(u):
                t = r[i]
                q = np.full(idx.size, 1.0) if i == 0 else np.zeros(idx.size)
                for k in range(i):
                    t -= L[i][k] * y[k]
                    q -= L[i][k] * e[k]
                y[i] = t / L[i][i]
                e[i] = q / L[i][i]
            b = [None] * u
            for i in range(u - 1, -1, -1):
                t = y[i]
                for k in range(i + 1, u):
                    t -= L[k][i] * b[k]
                b[i] = t / L[i][i]
            h0 = sum(ek * ek for ek in e)
            beta.ravel()[idx[good]] = (b[0] / d[0])[good]
            hh.ravel()[idx[good]] = (h0 / (d[0] * d[0]))[good]
    return beta, hh


#: Cells per band of the banded kernels: their many temporaries (256 kB of float64 each)
#: stay in the core's cache, and no full-size temporary is allocated per moment. Steps 3
#: and 4 (few passes per band) take bands 4 and 16 times larger.
_BAND_CELLS = 1 << 15
#: Cells per band (halo included) of the window fits run in bands of rows with a halo.
_HALO_BAND_CELLS = 1 << 20


def _bands(rows, cols, cells=None):
    """Row slices of about ``cells`` (default :data:`_BAND_CELLS`) cells covering ``rows``
    rows."""
    step = max(1, (cells or _BAND_CELLS) // max(1, cols))
    return [slice(r0, min(rows, r0 + step)) for r0 in range(0, rows, step)]


def _scratch(work, key, n, shape):
    """``n`` float64 scratch arrays of ``shape``: views of arrays kept in the dict ``work``
    (allocated once, reused by the next bands; new arrays without ``work``)."""
    if work is None:
        return [np.empty(shape) for _ in range(n)]
    a = work.get(key)
    if a is None or a.shape[1] < shape[0] or a.shape[2] != shape[1]:
        a = work[key] = np.empty((n,) + shape)
    return [b[:shape[0]] for b in a]


def _mean1(v, size, axis, out=None):
    """Mean of ``v`` (float64) over a centred window of ``size`` (odd) cells along
    ``axis``; 0 outside."""
    if out is None:
        out = np.empty(v.shape, np.float64)
    return ndimage.uniform_filter1d(v, size, axis=axis, mode="constant", cval=0.0, output=out)


def _centred(x, s0, s1, s2=None):
    """Turn window sums on absolute positions into sums on positions relative to the
    centre ``x``: ``sum w (x' - x) = s1 - x s0``, ``sum w (x' - x)^2 = s2 - x (2 s1 - x s0)``
    (in place in ``s1``, ``s2``)."""
    t = np.multiply(s0, x)
    if s2 is not None:
        u = np.multiply(s1, 2.0)
        u -= t
        u *= x
        s2 -= u
    s1 -= t


def _fit_rows(z, w, size, degree):
    """Leave-one-out mean (degree 0) or linear regression (degree 1) along axis 1.

    The same result as :func:`_fit_at_centre` for 1-D windows (to rounding), computed in
    bands of rows: the window moments ``M0 = sum w``, ``M1 = sum w k``, ``M2 = sum w k^2``,
    ``Z0 = sum w z``, ``Z1 = sum w z k`` (``k`` the position relative to the centre) come
    from running box means of ``w x^j`` and ``w z x^j`` on absolute positions ``x``
    (float64, O(1) per cell whatever the length), recentred by :func:`_centred`; the
    centre is then taken out of ``M0`` and ``Z0`` (its ``k`` is 0).

    ``z`` must be finite wherever ``w`` is 0 (any value). Returns ``zhat, h`` like
    :func:`_fit_at_centre`.
    """
    rows, cols = z.shape
    zhat = np.empty(z.shape)
    hh = np.empty(z.shape)
    x = np.arange(cols, dtype=np.float64) - cols // 2
    inv = 1.0 / size
    bands = _bands(rows, cols)
    buf = np.empty((8, bands[0].stop, cols))         # scratch, reused by every band
    with np.errstate(all="ignore"):
        for b in bands:
            wz, t, u, m0, z0, m1, m2, z1 = (a[:b.stop - b.start] for a in buf)
            wb = w[b]
            np.multiply(wb, z[b], out=wz)
            _mean1(wb, size, 1, out=m0)
            _mean1(wz, size, 1, out=z0)
            if degree == 1:
                np.multiply(wb, x, out=t)
                _mean1(t, size, 1, out=m1)
                t *= x
                _mean1(t, size, 1, out=m2)
                np.multiply(wz, x, out=t)
                _mean1(t, size, 1, out=z1)
                # recentre on each cell (see _centred)
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


def _fit_box_2d(z, w, sizes, degree, out_rows=None, work=None):
    """Leave-one-out horizontal (degree 0) or inclined plane (degree 1) in a moving
    ``rows x cols`` box window, for every cell at once.

    The same result as :func:`_fit_at_centre` (to rounding) with few passes over the
    data: separable window sums, first along the columns (axis 0: ``w y^j``, ``w z y^j``
    box means on absolute positions, recentred by :func:`_centred`), then along the rows in
    bands (the moments ``sum w kx^p ky^q``, ``p + q <= 2``, and ``sum w z kx^p ky^q``,
    ``p + q <= 1``); the 3 x 3 normal equations are solved by cofactors for the height at
    the centre and ``h = (N^-1)_00``, the centre having been taken out of ``M00``, ``Z00``.

    ``z`` must be finite wherever ``w`` is 0. ``out_rows`` (a slice) limits the result to
    those rows (the others only feed the windows). ``work`` (a dict) keeps the large
    scratch arrays from one call to the next. Returns ``zhat, h`` like
    :func:`_fit_at_centre` (views of ``work`` arrays when given).
    """
    sy, sx = sizes
    rows, cols = z.shape
    o0, o1, _ = (out_rows or slice(0, rows)).indices(rows)
    inv = 1.0 / (sy * sx)
    wz, c0, d0, t, c1, c2, d1 = _scratch(work, "box", 7, (rows, cols))
    np.multiply(w, z, out=wz)
    y = (np.arange(rows, dtype=np.float64) - (o0 + o1) // 2)[:, None]
    c0 = _mean1(w, sy, 0, out=c0)[o0:o1]
    d0 = _mean1(wz, sy, 0, out=d0)[o0:o1]
    if degree == 1:
        np.multiply(w, y, out=t)
        c1 = _mean1(t, sy, 0, out=c1)[o0:o1]
        t *= y
        c2 = _mean1(t, sy, 0, out=c2)[o0:o1]
        np.multiply(wz, y, out=t)
        d1 = _mean1(t, sy, 0, out=d1)[o0:o1]
        y = y[o0:o1]
        for b in _bands(o1 - o0, cols):
            _centred(y[b], c0[b], c1[b], c2[b])
            _centred(y[b], d0[b], d1[b])
    w, wz = w[o0:o1], wz[o0:o1]
    x = np.arange(cols, dtype=np.float64) - cols // 2
    zhat, hh = _scratch(work, "fit", 2, (o1 - o0, cols))
    bands = _bands(o1 - o0, cols)
    buf = np.empty((16, bands[0].stop, cols))        # scratch, reused by every band
    with np.errstate(all="ignore"):
        for b in bands:
            (t, u, v, m00, z00, m10, m20, m01, m11, m02, z10, z01, c00, c01, c02,
             small) = (a[:b.stop - b.start] for a in buf)
            _mean1(c0[b], sx, 1, out=m00)
            _mean1(d0[b], sx, 1, out=z00)
            if degree == 1:
                np.multiply(c0[b], x, out=t)
                _mean1(t, sx, 1, out=m10)
                t *= x
                _mean1(t, sx, 1, out=m20)
                np.multiply(c1[b], x, out=t)
                _mean1(c1[b], sx, 1, out=m01)
                _mean1(t, sx, 1, out=m11)
                _mean1(c2[b], sx, 1, out=m02)
                np.multiply(d0[b], x, out=t)
                _mean1(t, sx, 1, out=z10)
                _mean1(d1[b], sx, 1, out=z01)
                # recentre on each cell (see _centred)
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


def _fit_at_centre(z, w, sizes, degree, leave_one_out=True, kernels=None):
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
        return _fit_box_2d(z, w, sizes, degree) if two_d else _fit_rows(z, w, sizes, degree)
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
            return _power_sums(v, sizes, px, 1)
        sy, sx = sizes
        ty = _power_sums(v, sy, py, 0)             # the slow axis (0) first: fewer passes
        out = {}
        top = max(max(px), max(py))
        for q in set(py):
            ps = [p for p in set(px) if p + q <= top]   # only the moments the model needs
            tx = _power_sums(ty[q], sx, ps, 1)
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
                zhat, hh = _solve3_first(((m[0], m[1], m[2]), (m[1], m[2], m[3]),
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
            return _solve3_first(M, [zz[mons[i]] for i in range(3)])
        return _solve_first_general(M, [zz[mons[i]] for i in range(6)], 6)


def _snoop(z, zhat, hh, test, s, k, low_weight):
    """Data snooping of prediction residuals ``v = z - zhat``.

    ``v / (s sqrt(1/p + h)) > k`` flags an object (p = 1), ``< -k`` a low blunder with
    the weight factor ``p = low_weight`` of points below the reference. Cells where the
    fit is undetermined (``zhat`` or ``h`` NaN) are not tested.

    Returns
    -------
    high, low, below : ndarray of bool
        Objects, low blunders, and the tested cells below their fit (``v < 0``: the
        weight factor applies to them in a next fit).
    """
    ks2 = (k * s) ** 2
    with np.errstate(invalid="ignore"):
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


def _fit_and_snoop(z, keep, test, below, fit, s, k, low_weight, *, halo=0, labels=None,
                   work=None):
    """Fit every cell by ``fit`` and snoop the cells of ``test`` (:func:`_snoop`), in bands.

    ``fit(z, w, out_rows) -> (zhat, h)`` is a leave-one-out moving fit on float64 arrays
    (``z`` finite, ``w`` the weights: 1 where ``keep``, ``low_weight`` where also
    ``below``, else 0), evaluated on the rows ``out_rows``. It runs on bands of whole rows
    (profile fits along the rows: ``halo`` 0) or on bands of rows with ``halo`` rows above
    and below (window fits of at most ``2 halo + 1`` rows): the same result as one fit of
    the whole arrays, without any full-size float temporary. With break-line ``labels`` each region
    runs alone on its bounding box, the other cells having weight 0 and no test. ``work``
    (a dict, shared with ``fit``) keeps the band's scratch arrays from band to band.

    Returns
    -------
    high, low, below : ndarray of bool
    """
    high = np.zeros(z.shape, bool)
    low = np.zeros(z.shape, bool)
    under = np.zeros(z.shape, bool)
    if labels is not None:
        for rid, sl in _region_slices(labels):
            inside = labels[sl] == rid
            if np.count_nonzero(inside) < 3:
                continue
            res = _fit_and_snoop(z[sl], keep[sl] & inside, test[sl] & inside,
                                 None if below is None else below[sl], fit, s, k, low_weight,
                                 halo=halo, work=work)
            for o, r in zip((high, low, under), res):
                o[sl] |= r
        return high, low, under
    rows, cols = z.shape
    if halo:
        step = max(2 * halo, _HALO_BAND_CELLS // max(1, cols) - 2 * halo)
        bands = [slice(r0, min(rows, r0 + step)) for r0 in range(0, rows, step)]
    else:
        bands = _bands(rows, cols)
    work = {} if work is None else work
    for b in bands:
        if halo:
            r0, r1 = max(0, b.start - halo), min(rows, b.stop + halo)
            src, out = slice(r0, r1), slice(b.start - r0, b.stop - r0)
        else:
            src, out = b, slice(None)
        kb = keep[src]
        zb, wb = _scratch(work, "band", 2, kb.shape)
        np.copyto(zb, z[src])
        np.copyto(zb, 0.0, where=~kb)            # weight 0 there (NaN must not reach the sums)
        np.copyto(wb, kb)                        # the fit weights
        if below is not None:
            np.copyto(wb, low_weight, where=below[src] & kb)
        zhat, hh = fit(zb, wb, out)
        zo, tb, hb, lb, ub = zb[out], test[b], high[b], low[b], under[b]
        for sb in _bands(*zo.shape):            # in cache-sized pieces
            hb[sb], lb[sb], ub[sb] = _snoop(zo[sb], zhat[sb], hh[sb], tb[sb], s, k, low_weight)
    return high, low, under


# ------------------------------------------------------------------- step 1
def _tile_low(z, n):
    """Low envelope on non-overlapping ``n x n`` tiles: the 5th percentile of each tile.

    The order statistic comes from sorting each tile, or, for large full tiles (all of the
    same rank), from partial sorting (``np.partition``: the same value, faster).
    """
    rows, cols = z.shape
    R, C = -(-rows // n), -(-cols // n)
    pad = np.asarray(z, np.float32)              # NaN sorts last, like missing cells
    if (R * n, C * n) != pad.shape:
        pad = np.full((R * n, C * n), np.nan, np.float32)
        pad[:rows, :cols] = z
    pad = np.where(np.isinf(pad), np.nan, pad) if np.isinf(pad).any() else pad
    t = pad.reshape(R, n, C, n).transpose(0, 2, 1, 3).reshape(R * C, n * n)
    if np.may_share_memory(t, z):               # sorted in place below: never sort z
        t = t.copy()
    del pad
    cnt = np.count_nonzero(np.isfinite(t), axis=1)
    kth = (0.05 * cnt).astype(int)
    low = np.empty(R * C, np.float32)
    full = cnt == n * n
    if n * n >= 256 and full.any():
        k0 = int(kth[np.argmax(full)])
        tf = t if full.all() else t[full]
        tf.partition(k0, axis=1)                 # in place: t is a copy of z
        low[full] = tf[:, k0]
        rest = np.flatnonzero(~full)
        if rest.size:
            srt = np.sort(t[rest], axis=1)
            low[rest] = srt[np.arange(rest.size), kth[rest]]
    else:
        t.sort(axis=1)
        low[:] = np.take_along_axis(t, kth[:, None], axis=1)[:, 0]
    low[cnt < max(3, n * n // 10)] = np.nan
    return low.reshape(R, C)


def estimate_sigma(z):
    """Random error of the DSM (m) from the 4-neighbour Laplacian residual.

    ``r = z - mean(4 neighbours)`` has standard deviation ``sigma sqrt(1.25)`` on smooth
    ground; the lower quartile of ``|r|`` (0.3186 standard deviations for normal errors,
    robust to objects, edges and vegetation even when they cover half the area) gives
    ``sigma``, floored at 0.1 m.
    """
    z = np.asarray(z, dtype=np.float64)
    if z.shape[0] < 3 or z.shape[1] < 3:
        return _SIGMA_FLOOR
    c = z[1:-1, 1:-1]
    r = c - 0.25 * (z[:-2, 1:-1] + z[2:, 1:-1] + z[1:-1, :-2] + z[1:-1, 2:])
    r = r[np.isfinite(r)]
    if r.size < 10:
        return _SIGMA_FLOOR
    return float(max(_SIGMA_FLOOR, np.percentile(np.abs(r), 25) / 0.3186 / np.sqrt(1.25)))


def _tile_slopes(low, sx, sy):
    """Slopes (rise/run) of a tile envelope: per tile the steepest step to a neighbour in
    x and in y, combined; finite values only."""
    with np.errstate(invalid="ignore"):
        gx = np.full(low.shape, np.nan)
        gy = np.full(low.shape, np.nan)
        if low.shape[1] > 1:
            d = np.abs(np.diff(low, axis=1)) / sx
            gx = np.fmax(np.pad(d, ((0, 0), (0, 1)), constant_values=np.nan),
                         np.pad(d, ((0, 0), (1, 0)), constant_values=np.nan))
        if low.shape[0] > 1:
            d = np.abs(np.diff(low, axis=0)) / sy
            gy = np.fmax(np.pad(d, ((0, 1), (0, 0)), constant_values=np.nan),
                         np.pad(d, ((1, 0), (0, 0)), constant_values=np.nan))
        slope = np.hypot(np.nan_to_num(gx), np.nan_to_num(gy))
    slope[~(np.isfinite(gx) | np.isfinite(gy))] = np.nan
    return slope[np.isfinite(slope)]


def characterise_terrain(z, cell_size, tile_m=25.0):
    """Step 1: class the area as flat / rolling / mountainous and (in)homogeneous.

    The DSM is reduced to a lower envelope (5th percentile of ``tile_m`` tiles: objects
    smaller than a tile vanish) and the slopes (rise/run) between neighbouring tiles are
    analysed (Jacobsen 2004: the terrain type selects the filter models and defaults).

    Parameters
    ----------
    z : array_like
        DSM, NaN = nodata.
    cell_size : float or (float, float)
        Cell size (dx, dy) in metres.
    tile_m : float
        Tile edge of the envelope, metres.

    Returns
    -------
    dict
        ``terrain_class`` ("flat" median slope < 5 %, "rolling" < 20 %, else
        "mountainous"), ``homogeneous`` (at least 75 % of the tiles have that class),
        ``class_shares`` (share of tiles per class), ``slope_median``, ``slope_p90``
        (rise/run), ``relief_m`` (2-98 % range of the envelope), ``sigma_m`` (random error,
        :func:`estimate_sigma`), ``tile_m``.
    """
    return _characterise(as_surface(z), as_cell_size(cell_size), tile_m)[0]


def _characterise(z, cell_size, tile_m=25.0):
    """:func:`characterise_terrain` and its lower envelope (for step 2's limits)."""
    dx, dy = cell_size
    if tile_m <= 0:
        raise ValueError(f"tile_m must be positive (metres); got {tile_m}.")
    n = max(3, int(round(tile_m / max(dx, dy))))
    n = min(n, max(3, min(z.shape) // 3))
    low = _tile_low(z, n).astype(np.float64)
    s = _tile_slopes(low, n * dx, n * dy)
    med = float(np.median(s)) if s.size else 0.0
    cls = "flat" if med < _FLAT_MAX_SLOPE else "rolling" if med < _ROLLING_MAX_SLOPE else "mountainous"
    # homogeneity on tiles 2.5 x finer: embankments, cuts and terraces show up there
    nf = max(3, n * 2 // 5)
    sf = _tile_slopes(_tile_low(z, nf).astype(np.float64), nf * dx, nf * dy)
    sf = sf if sf.size else np.zeros(1)
    tiles = np.where(sf < _FLAT_MAX_SLOPE, 0, np.where(sf < _ROLLING_MAX_SLOPE, 1, 2))
    shares = {c: float(np.mean(tiles == i)) for i, c in enumerate(TERRAIN_CLASSES)}
    if not s.size:
        s = np.zeros(1)
    lv = low[np.isfinite(low)]
    relief = float(np.percentile(lv, 98) - np.percentile(lv, 2)) if lv.size else 0.0
    # sigma on a central crop of at most 1024 x 1024 cells
    r0 = max(0, z.shape[0] // 2 - 512)
    c0 = max(0, z.shape[1] // 2 - 512)
    sigma = estimate_sigma(z[r0:r0 + 1024, c0:c0 + 1024])
    return {"terrain_class": cls, "homogeneous": bool(shares[cls] >= _HOMOGENEOUS_SHARE),
            "class_shares": shares, "slope_median": med,
            "slope_p90": float(np.percentile(s, 90)), "relief_m": relief,
            "sigma_m": sigma, "tile_m": n * max(dx, dy)}, low


# ------------------------------------------------------------------- step 2
def remove_height_outliers(z, keep, height_min_m, height_max_m):
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


def remove_neighbour_differences(z, keep, *, sigma_m, k=3.0, low_weight=0.02, labels=None):
    """Step 3: remove the upper point of neighbouring pairs differing beyond a tolerance.

    For each of the 8 directions ``e``, with ``u`` the tested cell, ``l = u + e`` its lower
    neighbour and ``b = u + 2e`` the next one, ``u`` is removed when

    ``z_u - z_l > k sigma sqrt(2) + max(0, z_l - z_b)``  (the local slope beyond the pair;
    where ``b`` is missing, the slope above ``u``; with neither, the pair is not tested)

    unless the terrain above ``u`` rises at least as steeply (``z_{u-e} - z_u >= z_u - z_l
    - tol``: a straight or concave slope, e.g. the toe of an embankment). A point that is
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

    Returns
    -------
    high, low : ndarray of bool
    """
    tol = k * sigma_m * np.sqrt(2.0)
    tol_low = tol / np.sqrt(low_weight)
    rows, cols = z.shape
    P = 2
    zp = np.full((rows + 2 * P, cols + 2 * P), np.nan, np.float32)
    zp[P:-P, P:-P] = z
    zp[P:-P, P:-P][~keep] = np.nan
    lp = None
    if labels is not None:
        lp = np.full(zp.shape, -1, np.int64)
        lp[P:-P, P:-P] = labels
    low = np.zeros(z.shape, bool)
    high = np.zeros(z.shape, bool)
    axes = ((0, 1), (1, 0), (1, 1), (1, -1))

    W = cols + 2 * P

    def run(core, src, reach, tol_c, out, keep_b=None):
        # bands of rows: the few temporaries of each stay in the cache. Without break
        # lines, only the candidates are tested: cells with a neighbour (within ``reach``
        # cells along the 8 directions) lower (``reach`` 1) / higher (``reach`` 2) by
        # more than ``tol_c``, which every removal needs; their neighbours are gathered.
        flat = src.ravel()
        for b in _bands(rows, W, 4 * _BAND_CELLS):
            r0, r1 = b.start, b.stop
            zc = src[P + r0:P + r1, P:P + cols]
            if lp is not None:
                def nb(dr, dc):
                    v = src[P + r0 + dr:P + r1 + dr, P + dc:P + dc + cols]
                    return np.where(lp[P + r0 + dr:P + r1 + dr, P + dc:P + dc + cols]
                                    == labels[b], v, np.nan)
                out[b] = core(nb, keep[b] if keep_b is None else keep_b[b])
                continue
            ext = None
            for dr, dc in _DIRS8:
                for m in range(1, reach + 1):
                    v = src[P + r0 + m * dr:P + r1 + m * dr, P + m * dc:P + m * dc + cols]
                    ext = v.copy() if ext is None else (np.fmax(ext, v, out=ext) if reach == 2
                                                         else np.fmin(ext, v, out=ext))
            ext -= zc
            cand = ext > tol_c if reach == 2 else ext < -tol_c
            cand &= keep[b] if keep_b is None else keep_b[b]
            idx = np.flatnonzero(cand)
            ob = out[b]
            ob[:] = False
            if not idx.size:
                continue
            base = idx + (idx // cols) * (2 * P) + (P + r0) * W + P
            kb = np.ones(idx.size, bool)
            ob.ravel()[idx] = core(lambda dr, dc: flat[base + (dr * W + dc)], kb)

    def pits(nb, kb):
        # low blunders: pits in every direction. Along each of the 4 axes the cell is a pit
        # when, on both sides within 2 cells, a point lies higher by more than tol_low
        # (fills blunders up to 3 cells wide); a ditch or a cut continues along its own
        # axis, so it is no pit there and stays.
        zc = nb(0, 0)
        n_axes = np.zeros(zc.shape, np.int8)
        n_pits = np.zeros(zc.shape, np.int8)
        for dr, dc in axes:
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

    def pairs(nb, kb):
        zc = nb(0, 0)
        hi = np.zeros(zc.shape, bool)
        for dr, dc in axes:
            zf, zr = nb(dr, dc), nb(-dr, -dc)        # the next cell forward / backward
            d_f, d_r = zc - zf, zc - zr
            for dz, up_neg, zl, far in ((d_f, d_r, zf, (2 * dr, 2 * dc)),
                                        (d_r, d_f, zr, (-2 * dr, -2 * dc))):
                # pair (u = centre, l = next cell); b the cell beyond l; the far cell must
                # lie in the region of l too (nb checks the centre's region for both)
                beyond = zl - nb(*far)
                up = -up_neg                           # rise above u: z_{u-e} - z_u
                # the local slope: beyond the pair, else above u; neither known: no test
                np.copyto(beyond, up, where=np.isnan(beyond))
                np.maximum(beyond, 0.0, out=beyond)
                beyond += tol
                t = dz > beyond
                # unless the terrain above u rises at least as steeply (straight or concave)
                t &= ~(up >= dz - tol)
                hi |= t
        hi &= kb
        return hi

    with np.errstate(invalid="ignore"):
        run(pits, zp, 2, tol_low, low)
        zp[P:-P, P:-P][low] = np.nan
        run(pairs, zp, 1, tol, high, keep_b=keep & ~low)
    return high, low


# ------------------------------------------------------------------- step 4
def _raised_rows(z, keep, labels, jump, lmax, veg_tol):
    """Cells between a jump up and a later jump down along the rows (axis 1).

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
    zc[:] = z[keep]
    sp = np.zeros(n + 2 * P, bool)
    same = sp[P:P + n]                                    # same profile as the previous point
    same[:] = True
    cnt = np.count_nonzero(keep, axis=1)
    same[(np.cumsum(cnt) - cnt)[cnt > 0]] = False         # the first point of each row
    if labels is not None:
        lab = labels[keep]
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
        up &= np.where(s3, np.abs(z1 - 2 * z2 + z3) <= veg_tol, s2)
        down &= np.where(n2, np.abs(z0 - 2 * zn + znn) <= veg_tol, n1)
    # events along the concatenated profiles: 1 jump up, 2 jump down, 0 profile start.
    # A raised level is a run from a jump up to the next event when that is a jump down.
    starts = np.flatnonzero(~same)
    ev = np.concatenate([starts, i[up], i[down]])
    typ = np.concatenate([np.zeros(starts.size, np.int8), np.ones(int(up.sum()), np.int8),
                          np.full(int(down.sum()), 2, np.int8)])
    order = np.argsort(ev, kind="stable")
    ev, typ = ev[order], typ[order]
    k = np.flatnonzero((typ[:-1] == 1) & (typ[1:] == 2))
    a, b = ev[k], ev[k + 1]
    pos = flat
    ok = (pos[b] - pos[a]) <= lmax
    a, b = a[ok], b[ok]
    lens = b - a
    if not lens.size:
        return out
    first = np.repeat(a, lens)
    c = np.arange(lens.sum()) - np.repeat(np.cumsum(lens) - lens, lens) + first
    pa = first - 1                             # the ground point before the jump up
    bb = np.repeat(b, lens)                    # the ground point after the jump down
    z0, z1 = zc[pa], zc[bb]
    t = (pos[c] - pos[pa]) / np.maximum(pos[bb] - pos[pa], 1)
    ground = z0 + (z1 - z0) * t
    with np.errstate(invalid="ignore"):
        hit = zc[c] - ground > 0.5 * jump
    out.ravel()[flat[c[hit]]] = True
    return out


def remove_level_changes(z, cell_size, keep, *, jump_m, max_building_m, sigma_m, k=3.0,
                         labels=None, passes=2):
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
    repetitions peel nested levels (roof superstructures).

    Returns
    -------
    high : ndarray of bool
    """
    dx, dy = as_cell_size(cell_size)
    veg_tol = 2.0 * k * sigma_m
    cur = keep.copy()
    high = np.zeros(z.shape, bool)
    # Y profiles run along the rows of the transposed arrays; bands of whole rows
    views = [(z, labels, int(max_building_m / dx), lambda a: a),
             (transpose(z), None if labels is None else transpose(labels),
              int(max_building_m / dy), transpose)]
    redo = [None, None]
    for _ in range(passes):
        new = np.zeros(z.shape, bool)
        for (zz, lab, lmax, fwd), todo in zip(views, redo):
            c = fwd(cur)
            found = np.zeros(zz.shape, bool)
            for b in _bands(*zz.shape, 16 * _BAND_CELLS):
                # a profile's result depends on that profile alone: later passes redo
                # only the bands of rows / columns where something was removed
                if todo is None or todo[b].any():
                    found[b] = _raised_rows(zz[b], c[b], None if lab is None else lab[b],
                                            jump_m, lmax, veg_tol)
            new |= fwd(found)
        new &= cur
        if not new.any():
            break
        high |= new
        cur &= ~new
        redo = [new.any(axis=1), new.any(axis=0)]
    return high


# ------------------------------------------------------------------- step 5
def _finite64(z):
    """``z`` as float64 with 0 in place of NaN (the fits need finite heights everywhere;
    the cells concerned have weight 0 and are never tested)."""
    z = np.array(z, dtype=np.float64)
    np.copyto(z, 0.0, where=~np.isfinite(z))
    return z


def remove_profile_outliers(z, cell_size, keep, *, lengths_m, terrain_class, scale_m,
                            k=4.0, low_weight=0.02, iterations=1, test=None, labels=None,
                            homogeneous=True):
    """Step 5: moving local profiles in X and Y, short then long, with data snooping.

    For each length of ``lengths_m`` and each direction, every height is compared with the
    leave-one-out fit of the profile through the remaining points in its window: the mean
    (flat), a linear regression (rolling) or a 2nd-order polynomial (mountainous terrain).
    The test is Baarda's data snooping ``v / (scale sqrt(1/p + h)) > k`` with the actual
    positions of the remaining points (``h`` grows where earlier steps left gaps); points
    below the fit get the weight factor ``p = low_weight`` in the next fit and are removed
    (class 2) only beyond ``-k``. ``iterations`` fits per length and direction.

    Parameters
    ----------
    lengths_m : sequence of float
        Profile lengths in metres, applied in order (short first).
    terrain_class : {"flat", "rolling", "mountainous"}
    homogeneous : bool
        False upgrades the flat model to linear (:func:`model_degree`).
    scale_m : float
        Standard deviation of a height about the profile model (random error + model
        error), from the analysis of the sequence of lengths.
    test : ndarray of bool, optional
        Cells that may be removed (default ``keep``); others only support the fits.

    Returns
    -------
    high, low : ndarray of bool
    """
    dx, dy = as_cell_size(cell_size)
    degree = model_degree(terrain_class, homogeneous)
    test = keep if test is None else test & keep
    cur = keep.copy()
    high = np.zeros(z.shape, bool)
    low = np.zeros(z.shape, bool)
    # Y profiles run along the rows of the transposed arrays
    views = [(z, labels, dx, None), (transpose(z), None if labels is None else
                                     transpose(labels), dy, transpose)]
    for L in lengths_m:
        for zz, lab, step, tr in views:
            fwd = tr or (lambda a: a)
            size = _odd(L / step, 3)

            def fit(zr, wr, out, size=size):
                return _fit_rows(zr, wr, size, degree) if degree <= 1 else \
                    _fit_at_centre(zr, wr, size, degree)

            below = None
            c, t = fwd(cur), fwd(test & cur)
            for _ in range(iterations):
                hi, lo, below = _fit_and_snoop(zz, c, t, below, fit, scale_m, k, low_weight,
                                               labels=lab)
                gone = hi | lo
                c &= ~gone
                t &= ~gone
                _or_into(high, hi, tr is not None)
                _or_into(low, lo, tr is not None)
            cur &= ~(high | low)
    return high, low


def _or_into(dst, src, transposed):
    """``dst |= src`` (``src.T`` when ``transposed``; a sparse ``src`` by its indices)."""
    if not transposed:
        dst |= src
        return
    idx = np.flatnonzero(src)
    if idx.size > src.size // 64:
        dst |= transpose(src)
    elif idx.size:
        r, c = np.divmod(idx, src.shape[1])
        dst[c, r] = True


# ------------------------------------------------------------------- step 6
def remove_surface_outliers(z, cell_size, keep, *, size_m, terrain_class, scale_m, k=4.0,
                            low_weight=0.02, iterations=1, test=None, labels=None,
                            homogeneous=True):
    """Step 6: moving surfaces: horizontal plane, inclined plane or polynomial.

    Every height is compared with the leave-one-out weighted least-squares surface of its
    ``size_m`` x ``size_m`` window (horizontal plane in flat, inclined plane in rolling,
    2nd-order polynomial in mountainous terrain), with the same data snooping and weight
    factor as :func:`remove_profile_outliers`. Windows never reach across a break line.
    A flat but inhomogeneous area gets the inclined plane (:func:`model_degree`).

    Returns
    -------
    high, low : ndarray of bool
    """
    dx, dy = as_cell_size(cell_size)
    degree = model_degree(terrain_class, homogeneous)
    sizes = (_odd(size_m / dy, 3), _odd(size_m / dx, 3))
    test = keep if test is None else test & keep
    cur = keep.copy()
    high = np.zeros(z.shape, bool)
    low = np.zeros(z.shape, bool)
    below = None
    work = {}                                   # scratch arrays reused by every band

    def fit(zz, ww, out):
        return _fit_box_2d(zz, ww, sizes, degree, out, work) if degree <= 1 else \
            tuple(a[out] for a in _fit_at_centre(zz, ww, sizes, degree))

    for _ in range(iterations):
        hi, lo, below = _fit_and_snoop(z, cur, test & cur, below, fit, scale_m, k, low_weight,
                                       halo=sizes[0] // 2, labels=labels, work=work)
        high |= hi
        low |= lo
        cur &= ~(hi | lo)
    return high, low


# ------------------------------------------------------------------- step 7
def _gauss(radius_cells):
    r = max(1, int(np.ceil(radius_cells)))
    x = np.arange(-r, r + 1.0)
    return np.exp(-0.5 * (x / max(radius_cells / 2.0, 0.5)) ** 2)


def remove_prediction_outliers(z, cell_size, keep, *, radius_m, scale_m, k=4.0,
                               low_weight=0.02, test=None, labels=None):
    """Step 7: final local prediction (least-squares interpolation from the neighbourhood).

    Each height is predicted from the remaining points within ``radius_m`` by a weighted
    least-squares inclined plane with Gaussian (covariance-like) weights, itself excluded,
    and tested as in :func:`remove_profile_outliers`.

    Returns
    -------
    high, low : ndarray of bool
    """
    dx, dy = as_cell_size(cell_size)
    kernels = (_gauss(radius_m / dy), _gauss(radius_m / dx))
    test = keep if test is None else test & keep
    sizes = (len(kernels[0]), len(kernels[1]))

    def fit(zz, ww, out):
        return tuple(a[out] for a in _fit_at_centre(zz, ww, sizes, 1, kernels=kernels))

    hi, lo, _ = _fit_and_snoop(z, keep, test, None, fit, scale_m, k, low_weight,
                               halo=sizes[0] // 2, labels=labels)
    return hi, lo


# ----------------------------------------------------------- the whole sequence
def filter_rascor(z, cell_size, *, terrain_class="rolling", homogeneous=True, sigma_m=0.15,
                  step1_characterise=True, step2_height_distribution=True,
                  step3_neighbour_differences=True, step4_level_change=True,
                  step5_profiles=True, step6_surfaces=True, step7_prediction=False,
                  second_iteration=False, height_min_m=None, height_max_m=None,
                  neighbour_k=3.0, jump_m=2.0, max_building_m=120.0,
                  short_profile_m=9.0, long_profile_m=25.0, profile_sigma_m=None,
                  surface_size_m=25.0, surface_sigma_m=None, prediction_radius_m=3.0,
                  prediction_sigma_m=None, snooping_k=4.0, snooping_iterations=1,
                  low_weight=0.02, steps=None, breaklines=None, special_areas=None,
                  progress=None):
    """RASCOR sequential filter of a raster DSM (Jacobsen 2004).

    Runs the enabled steps in order on the points the previous ones left (see the module
    docstring); each step is switchable (``stepN_...`` or ``steps``) and reported.

    Parameters
    ----------
    z : array_like
        DSM (2-D, NaN = nodata); not modified.
    cell_size : float or (float, float)
        (dx, dy) in metres.
    terrain_class : {"flat", "rolling", "mountainous"}
        Terrain type (step 1, :func:`characterise_terrain`, done by
        :func:`resolve_rascor_params` on the whole raster so that blocks agree).
    homogeneous : bool or {"homogeneous", "inhomogeneous"}
        Whether the area is homogeneous (step 1); a flat, inhomogeneous area gets the
        linear / inclined-plane models (:func:`model_degree`).
    sigma_m : float
        Random error of the DSM, metres.
    step1_characterise ... step7_prediction : bool
        Switch each step (step 1 only decides the class, in ``resolve``).
    second_iteration : bool
        Repeat steps 3, 5, 6 (7) once more on the points left.
    height_min_m, height_max_m : float or None
        Step 2 limits (None: step 2 does nothing).
    neighbour_k : float
        Critical value of step 3.
    jump_m, max_building_m : float
        Step 4: minimum level change and maximum building length, metres.
    short_profile_m, long_profile_m : float
        Step 5 profile lengths, metres.
    profile_sigma_m, surface_sigma_m, prediction_sigma_m : float or None
        Standard deviation of a height about the model of steps 5, 6, 7 (None: sigma_m).
    surface_size_m : float
        Step 6 window edge, metres.
    prediction_radius_m : float
        Step 7 neighbourhood radius, metres.
    snooping_k : float
        Critical value of the data snooping of steps 5-7.
    snooping_iterations : int
        Fits per length / direction (step 5) and per surface (step 6).
    low_weight : float
        Weight factor of points below the reference (0 < p <= 1).
    steps : iterable of int, optional
        If given, overrides the switches: the step numbers (1-7) to run.
    breaklines : array_like of bool, optional
        Cells crossed by a break line (rasterised by the plugin; not a Param).
    special_areas : array_like of bool, optional
        Cells where only the local filters (steps 3 and 7) run (not a Param).
    progress : callable, optional
        ``progress(fraction)``; may raise :class:`Cancelled`.

    Returns
    -------
    FilterResult
        ``mask`` (0 ground, 1 object, 2 low blunder, 255 nodata), ``extras["step"]``
        (uint8: 0 kept, k removed by step k, 255 nodata) and ``info`` with
        ``removed_share_by_step`` (share of valid cells removed by each step).
    """
    z = as_surface(z)
    dx, dy = as_cell_size(cell_size)
    if terrain_class not in TERRAIN_CLASSES:
        raise ValueError(f"terrain_class must be one of {TERRAIN_CLASSES}; got {terrain_class!r}. "
                         "Pass 'auto' to resolve_rascor_params to derive it (step 1).")
    homogeneous = _as_homogeneous(homogeneous)
    for name, val in (("sigma_m", sigma_m), ("jump_m", jump_m), ("max_building_m", max_building_m),
                      ("short_profile_m", short_profile_m), ("long_profile_m", long_profile_m),
                      ("surface_size_m", surface_size_m), ("prediction_radius_m", prediction_radius_m),
                      ("snooping_k", snooping_k), ("neighbour_k", neighbour_k)):
        if val is None or not np.isfinite(val) or val <= 0:
            raise ValueError(f"{name} must be a positive number; got {val!r}. Pass a value or "
                             "call resolve_rascor_params to derive it from the DSM.")
    if not 0 < low_weight <= 1:
        raise ValueError(f"low_weight must be in (0, 1]; got {low_weight}. It is the weight "
                         "factor of points below the reference (0.02: tolerance x 7).")
    if int(snooping_iterations) < 1:
        raise ValueError(f"snooping_iterations must be >= 1; got {snooping_iterations}.")
    if steps is not None:
        steps = {int(s) for s in steps}
        bad = steps - set(STEP_NAMES)
        if bad:
            raise ValueError(f"steps {sorted(bad)} do not exist; RASCOR steps are 1-7 "
                             f"({STEP_NAMES}).")
        on = {i + 1: (i + 1) in steps for i in range(7)}
    else:
        on = dict(zip(range(1, 8), (step1_characterise, step2_height_distribution,
                                    step3_neighbour_differences, step4_level_change,
                                    step5_profiles, step6_surfaces, step7_prediction)))
    bl = _as_bool_raster(breaklines, z.shape, "breaklines")
    sp = _as_bool_raster(special_areas, z.shape, "special_areas")
    labels = None
    n_regions = 1
    if bl is not None:
        labels, n_regions = break_regions(bl)
    s5 = max(sigma_m, profile_sigma_m or sigma_m)
    s6 = max(sigma_m, surface_sigma_m or sigma_m)
    s7 = max(sigma_m, prediction_sigma_m or sigma_m)
    lengths = [short_profile_m] if long_profile_m <= short_profile_m else [short_profile_m,
                                                                          long_profile_m]

    valid = np.isfinite(z)
    keep = valid.copy()
    global_ok = valid if sp is None else valid & ~sp
    mask = np.zeros(z.shape, np.uint8)
    step = np.zeros(z.shape, np.uint8)
    removed = {}

    # a low blunder lies below all the ground around it; a gap between crowns or roofs is
    # at the level of the other low cells within _PIT_RADIUS_M and is not one
    pit = below_surroundings(z, (dx, dy), 3.0 * sigma_m * np.sqrt(2.0))

    def record(k, hi, lo):
        new_hi = hi & keep
        new_lo = lo & keep & pit
        new_lo &= ~new_hi
        np.copyto(mask, OBJECT, where=new_hi)
        np.copyto(mask, LOW, where=new_lo)
        new = np.logical_or(new_hi, new_lo, out=new_hi)
        np.copyto(step, k, where=new)
        np.copyto(keep, False, where=new)
        removed[k] = removed.get(k, 0) + int(np.count_nonzero(new))

    kw = dict(k=snooping_k, low_weight=low_weight, labels=labels)
    mkw = dict(terrain_class=terrain_class, homogeneous=bool(homogeneous),
               iterations=int(snooping_iterations), test=global_ok)
    n_iter = 2 if second_iteration else 1
    work = [k for k in (2, 3, 4, 5, 6, 7) if on[k] or (k == 7 and sp is not None)]
    total = max(1, len(work) + (n_iter - 1) * len([k for k in work if k in (3, 5, 6, 7)]))
    done = 0

    def tick():
        nonlocal done
        done += 1
        report(progress, done / total)

    report(progress, 0.0)
    skipped = []
    for it in range(n_iter):
        if it == 0 and 2 in work:
            if terrain_class == "flat" and height_min_m is not None and height_max_m is not None:
                hi, lo = remove_height_outliers(z, keep & global_ok, height_min_m, height_max_m)
                record(2, hi, lo)
            else:
                skipped.append("2: height distribution skipped (terrain is "
                               f"{terrain_class}, the step applies to flat areas only)")
            tick()
        if 3 in work:
            hi, lo = remove_neighbour_differences(z, keep, sigma_m=sigma_m, k=neighbour_k,
                                                  low_weight=low_weight, labels=labels)
            record(3, hi, lo)
            tick()
        if it == 0 and 4 in work:
            hi = remove_level_changes(z, (dx, dy), keep, jump_m=jump_m,
                                      max_building_m=max_building_m, sigma_m=sigma_m,
                                      k=neighbour_k, labels=labels)
            record(4, hi & global_ok, np.zeros_like(hi))
            tick()
        if 5 in work:
            hi, lo = remove_profile_outliers(z, (dx, dy), keep, lengths_m=lengths,
                                             scale_m=s5, **mkw, **kw)
            record(5, hi, lo)
            tick()
        if 6 in work:
            hi, lo = remove_surface_outliers(z, (dx, dy), keep, size_m=surface_size_m,
                                             scale_m=s6, **mkw, **kw)
            record(6, hi, lo)
            tick()
        if 7 in work:
            test = valid if on[7] else sp
            hi, lo = remove_prediction_outliers(z, (dx, dy), keep, radius_m=prediction_radius_m,
                                                scale_m=s7, test=test, **kw)
            record(7, hi, lo)
            tick()
    n_valid = max(1, int(valid.sum()))
    mask[~valid] = NODATA
    step[~valid] = 255
    shares = {f"{k} {STEP_NAMES[k]}": removed.get(k, 0) / n_valid for k in range(2, 8)}
    info = {"terrain_class": terrain_class, "homogeneous": bool(homogeneous),
            "model": ("mean / horizontal plane", "linear regression / inclined plane",
                      "polynomial")[model_degree(terrain_class, homogeneous)],
            "sigma_m": sigma_m,
            "steps_on": [k for k in range(1, 8) if on[k]],
            "removed_share_by_step": shares,
            "removed_share": float(sum(removed.values()) / n_valid),
            "low_share": float(np.mean(mask[valid] == LOW)),
            "breakline_regions": n_regions if bl is not None else 0,
            "special_area_share": float(sp[valid].mean()) if sp is not None else 0.0,
            "second_iteration": bool(second_iteration), "notes": skipped}
    report(progress, 1.0)
    return FilterResult(mask=mask, extras={"step": step}, info=info)


# ----------------------------------------------------------------- parameters
DEFAULTS = dict(terrain_class="auto", homogeneous="auto", sigma_m=None, step1_characterise=True,
                step2_height_distribution=True, step3_neighbour_differences=True,
                step4_level_change=True, step5_profiles=True, step6_surfaces=True,
                step7_prediction=False, second_iteration=False, height_min_m=None,
                height_max_m=None, neighbour_k=3.0, jump_m=2.0, max_building_m=120.0,
                short_profile_m=None, long_profile_m=None, profile_sigma_m=None,
                surface_size_m=None, surface_sigma_m=None, prediction_radius_m=None,
                prediction_sigma_m=None, snooping_k=4.0, snooping_iterations=1,
                low_weight=0.02)


def _analysis_crops(z, edge=256):
    """The analysis sample: the whole surface when small, else 4 crops at the quadrants."""
    rows, cols = z.shape
    if rows * cols <= (2 * edge) ** 2:
        return [z]
    out = []
    for fr in (0.25, 0.75):
        for fc in (0.25, 0.75):
            r0 = int(max(0, min(rows - edge, fr * rows - edge / 2)))
            c0 = int(max(0, min(cols - edge, fc * cols - edge / 2)))
            out.append(z[r0:r0 + edge, c0:c0 + edge])
    return out


#: Residuals beyond this count are subsampled (regularly) for their robust scales.
_SCALE_SAMPLE = 1 << 18


def _robust_scale(v):
    """``(MAD scale, 90th percentile of |v|)`` of residuals (NaN when too few)."""
    v = v[np.isfinite(v)]
    if v.size < 20:
        return np.nan, np.nan
    if v.size > _SCALE_SAMPLE:             # a regular subsample: the scales need no more
        v = v[:: -(-v.size // _SCALE_SAMPLE)]
    return (float(1.4826 * np.median(np.abs(v - np.median(v)))),
            float(np.percentile(np.abs(v), 90)))


def _choose(spreads, sigma):
    """Index of the longest length whose residual spread stays within ``_SCALE_GROWTH`` x
    the shortest's (the spread grows with the length once the model no longer follows the
    terrain, or objects larger than the length remain)."""
    ref = max(sigma, spreads[0]) if np.isfinite(spreads[0]) else sigma
    best = 0
    for i, s in enumerate(spreads):
        if np.isfinite(s) and s <= _SCALE_GROWTH * ref:
            best = i
        else:
            break
    return best


def _scan(sequence, scale_of, sigma, at_least=1):
    """``scale_of(value)`` along ``sequence`` as long as :func:`_choose` can still accept
    the next value: the sequence ends at the first length whose spread is too large (the
    longer ones are never chosen), but covers at least ``at_least`` values."""
    out = []
    for i, value in enumerate(sequence):
        out.append(scale_of(value))
        if i + 1 >= at_least and _choose([b for _, b in out], sigma) < i:
            break
    return out


def resolve_rascor_params(z, cell_size, **params):
    """Complete RASCOR's parameters from an analysis of the DSM (Jacobsen 2004).

    ``None`` (and ``"auto"``) values are derived from the whole raster, once, so that all
    blocks use the same values:

    * terrain class, homogeneity and random error ``sigma_m`` by step 1
      (:func:`characterise_terrain`);
    * step 2's limits (flat terrain only) from the height distribution: Tukey's far fences,
      and at least 20 m outside the range of the terrain's lower envelope;
    * the profile lengths by analysing the sequence :data:`PROFILE_LENGTHS_M` on a sample
      (the whole raster up to 512 x 512 cells, else 4 crops of 256 x 256 cells at the
      quadrants) cleaned by steps 3 and 4: per length, the leave-one-out profile
      residuals of the class model; the long profile is the longest length before the
      90th percentile of ``|v|`` exceeds twice the shortest's (the model stops following
      the terrain, or objects as long as the profile remain; the analysis of the sequence
      stops there), the short one the longest of the sequence at most half of it;
      ``profile_sigma_m`` is the robust (MAD) scale of the residuals at the long length
      (scales from a regular subsample of at most 262144 residuals);
    * the surface size and ``surface_sigma_m`` likewise from :data:`SURFACE_SIZES_M`;
    * ``prediction_sigma_m`` from the residuals of the local prediction; its radius 3 cells.

    Returns
    -------
    dict
        Every parameter of :func:`filter_rascor` except the rasters and ``progress``.
    """
    unknown = sorted(set(params) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"unknown RASCOR parameter(s) {unknown}; known: {sorted(DEFAULTS)}.")
    p = dict(DEFAULTS)
    p.update({k: v for k, v in params.items() if v is not None or DEFAULTS[k] is None})
    z = as_surface(z)
    dx, dy = as_cell_size(cell_size)
    cs = max(dx, dy)
    tc = None if p["terrain_class"] in (None, "auto") else p["terrain_class"]
    if tc is not None and tc not in TERRAIN_CLASSES:
        raise ValueError(f"terrain_class must be one of {TERRAIN_CLASSES} or 'auto' (derived "
                         f"by step 1); got {tc!r}.")
    ch, low_env = _characterise(z, (dx, dy))
    if tc is None:
        tc = ch["terrain_class"] if p["step1_characterise"] else "rolling"
    p["terrain_class"] = tc
    if p["homogeneous"] in (None, "auto"):
        p["homogeneous"] = bool(ch["homogeneous"]) if p["step1_characterise"] else True
    else:
        p["homogeneous"] = _as_homogeneous(p["homogeneous"])
    if p["sigma_m"] is None:
        p["sigma_m"] = round(ch["sigma_m"], 3)
    sigma = float(p["sigma_m"])
    if tc == "flat" and (p["height_min_m"] is None or p["height_max_m"] is None):
        v = z.ravel()
        if v.size > 2_000_000:                   # a regular sample of about 1 M cells
            v = v[:: v.size // 1_000_000]
        v = v[np.isfinite(v)]
        q1, q3 = np.percentile(v, [25, 75])
        iqr = max(q3 - q1, 10 * sigma)
        lv = low_env[np.isfinite(low_env)]
        gmin, gmax = (float(lv.min()), float(lv.max())) if lv.size else (q1, q3)
        # far outside: beyond Tukey's far fences and at least _FAR_M beyond the terrain's
        # lower envelope (a dam or an embankment in a flat area is not far outside)
        if p["height_min_m"] is None:
            p["height_min_m"] = round(float(min(q1 - 3 * iqr, gmin - _FAR_M)), 2)
        if p["height_max_m"] is None:
            p["height_max_m"] = round(float(max(q3 + 3 * iqr, gmax + _FAR_M)), 2)
    if p["prediction_radius_m"] is None:
        p["prediction_radius_m"] = round(3.0 * cs, 3)
    need = any(p[k] is None for k in ("short_profile_m", "long_profile_m", "profile_sigma_m",
                                      "surface_size_m", "surface_sigma_m", "prediction_sigma_m"))
    if need:
        deg = model_degree(tc, p["homogeneous"])
        sample = []          # (heights, weights, cells kept) of each crop, after steps 3, 4
        for crop in _analysis_crops(z):
            keep = np.isfinite(crop)
            if keep.sum() < 100:
                continue
            hi, lo = remove_neighbour_differences(crop, keep, sigma_m=sigma, k=p["neighbour_k"],
                                                  low_weight=p["low_weight"])
            keep &= ~(hi | lo)
            keep &= ~remove_level_changes(crop, (dx, dy), keep, jump_m=p["jump_m"],
                                          max_building_m=p["max_building_m"], sigma_m=sigma)
            sample.append((_finite64(crop), keep.astype(np.float64), keep))

        def scale(fit):
            """Robust scale of the leave-one-out residuals of ``fit(z, w)`` on the sample."""
            v = [(c - fit(c, w)[0])[kk] for c, w, kk in sample]
            return _robust_scale(np.concatenate(v) if v else np.zeros(0))

        ps = _scan(PROFILE_LENGTHS_M, lambda L: scale(
            lambda c, w: _fit_at_centre(c, w, _odd(L / dx), deg)), sigma, at_least=2)
        i_long = max(_choose([b for _, b in ps], sigma), 1)
        long_m = PROFILE_LENGTHS_M[i_long]
        i_short = max(i for i, L in enumerate(PROFILE_LENGTHS_M) if L <= max(long_m / 2, PROFILE_LENGTHS_M[0]))
        if p["long_profile_m"] is None:
            p["long_profile_m"] = long_m
        if p["short_profile_m"] is None:
            p["short_profile_m"] = PROFILE_LENGTHS_M[i_short]
        if p["profile_sigma_m"] is None:
            s = ps[i_long][0]
            p["profile_sigma_m"] = round(float(max(sigma, s if np.isfinite(s) else sigma)), 3)
        if p["surface_size_m"] is None or p["surface_sigma_m"] is None:
            ss = _scan(SURFACE_SIZES_M, lambda S: scale(
                lambda c, w: _fit_at_centre(c, w, (_odd(S / dy), _odd(S / dx)), min(deg, 1))),
                sigma)
            i_s = _choose([b for _, b in ss], sigma)
            if p["surface_size_m"] is None:
                p["surface_size_m"] = SURFACE_SIZES_M[i_s]
            if p["surface_sigma_m"] is None:
                s = ss[i_s][0]
                p["surface_sigma_m"] = round(float(max(sigma, s if np.isfinite(s) else sigma)), 3)
        if p["prediction_sigma_m"] is None:
            g = (_gauss(p["prediction_radius_m"] / dy), _gauss(p["prediction_radius_m"] / dx))
            s = scale(lambda c, w: _fit_at_centre(c, w, (len(g[0]), len(g[1])), 1, kernels=g))[0]
            p["prediction_sigma_m"] = round(float(max(sigma, s if np.isfinite(s) else sigma)), 3)
    return p


def rascor_halo(params, cell_size):
    """Reach of the whole sequence in cells (the sum of the enabled steps' reaches).

    Steps are chained, so a cell's fate depends on what earlier steps did within their
    reach around every cell of the later windows: the reaches add up (x 2 with the second
    iteration).
    """
    dx, dy = as_cell_size(cell_size)
    cs = min(dx, dy)
    p = dict(DEFAULTS)
    p.update({k: v for k, v in params.items() if v is not None})

    def cells(m):
        return int(np.ceil((m or 0) / cs))

    iters = int(p.get("snooping_iterations") or 1)
    r3 = 3 if p["step3_neighbour_differences"] else 0
    r4 = 2 * (cells(p["max_building_m"]) + 4) if p["step4_level_change"] else 0
    r5 = iters * sum(cells(L) // 2 + 1 for L in (p["short_profile_m"] or max(PROFILE_LENGTHS_M),
                                                p["long_profile_m"] or max(PROFILE_LENGTHS_M))) \
        if p["step5_profiles"] else 0
    r6 = iters * (cells(p["surface_size_m"] or max(SURFACE_SIZES_M)) // 2 + 1) \
        if p["step6_surfaces"] else 0
    r7 = cells(p["prediction_radius_m"] or 3 * cs) + 1
    once = r3 + r5 + r6 + r7
    return int(r4 + once * (2 if p["second_iteration"] else 1))


def _run(z, cell_size, progress=None, breaklines=None, special_areas=None, **params):
    return filter_rascor(z, cell_size, breaklines=breaklines, special_areas=special_areas,
                         progress=progress, **params)


METHOD = Method(
    name="rascor", run=_run, resolve=resolve_rascor_params, halo=rascor_halo,
    extras={"step": (np.uint8, 1, 255)},
    params=(
        Param("terrain_class", "enum", "auto", "Terrain type choosing the models (mean / "
              "linear / polynomial) and defaults; auto: classed from the DSM (step 1).",
              options=("auto",) + TERRAIN_CLASSES),
        Param("homogeneous", "enum", "auto", "Whether the area is homogeneous; auto: from "
              "step 1 (90 % of 10 m tiles in the area's class). A flat, inhomogeneous area "
              "(embankments, cuts) gets the linear models instead of the mean.",
              options=("auto", "homogeneous", "inhomogeneous")),
        Param("sigma_m", "float", None, "Random error of the DSM in metres; empty: "
              "estimated from the Laplacian residuals (at least 0.1 m).", minimum=0.001,
              maximum=100.0),
        Param("step1_characterise", "bool", True, "Step 1: class the terrain from the DSM "
              "(off: 'rolling' unless a terrain class is given)."),
        Param("step2_height_distribution", "bool", True, "Step 2: remove heights far "
              "outside the height distribution (flat terrain only; skipped otherwise)."),
        Param("step3_neighbour_differences", "bool", True, "Step 3: remove the upper point "
              "of neighbouring pairs differing beyond sigma and the local slope."),
        Param("step4_level_change", "bool", True, "Step 4: remove raised levels between a "
              "jump up and a jump down along X / Y profiles (buildings)."),
        Param("step5_profiles", "bool", True, "Step 5: moving local profiles in X and Y, "
              "short then long, with data snooping."),
        Param("step6_surfaces", "bool", True, "Step 6: moving surfaces (horizontal, "
              "inclined plane or polynomial by terrain class)."),
        Param("step7_prediction", "bool", False, "Step 7: final local least-squares "
              "prediction (optional; always on inside special areas)."),
        Param("second_iteration", "bool", False, "Repeat steps 3, 5, 6, 7 once. Warning "
              "(Jacobsen): removes small vegetation but may generalise the terrain."),
        Param("height_min_m", "float", None, "Step 2 lower height limit in metres; empty: "
              "far fence of the height distribution (flat terrain).", advanced=True),
        Param("height_max_m", "float", None, "Step 2 upper height limit in metres; empty: "
              "far fence of the height distribution (flat terrain).", advanced=True),
        Param("neighbour_k", "float", 3.0, "Step 3 critical value: tolerance = k sigma "
              "sqrt(2) + local slope.", minimum=0.5, maximum=20.0, advanced=True),
        Param("jump_m", "float", 2.0, "Step 4 minimum sudden change of level in metres.",
              minimum=0.1, maximum=100.0, advanced=True),
        Param("max_building_m", "float", 120.0, "Step 4 longest raised level removed "
              "(metres); also sets the block halo.", minimum=1.0, maximum=2000.0,
              advanced=True),
        Param("short_profile_m", "float", None, "Step 5 short profile length in metres; "
              "empty: chosen by analysing a sequence of lengths.", minimum=0.1,
              maximum=10000.0, advanced=True),
        Param("long_profile_m", "float", None, "Step 5 long profile length in metres; "
              "empty: the longest of the sequence whose residual scale stays within twice "
              "the shortest's.", minimum=0.1, maximum=10000.0, advanced=True),
        Param("profile_sigma_m", "float", None, "Step 5 standard deviation of a height "
              "about the profile model (m); empty: from the length analysis.", minimum=0.001,
              maximum=100.0, advanced=True),
        Param("surface_size_m", "float", None, "Step 6 moving-surface window edge in "
              "metres; empty: chosen by checking a sequence of sizes.", minimum=0.1,
              maximum=10000.0, advanced=True),
        Param("surface_sigma_m", "float", None, "Step 6 standard deviation about the "
              "surface (m); empty: from the size analysis.", minimum=0.001, maximum=100.0,
              advanced=True),
        Param("prediction_radius_m", "float", None, "Step 7 neighbourhood radius in "
              "metres; empty: 3 cells.", minimum=0.01, maximum=1000.0, advanced=True),
        Param("prediction_sigma_m", "float", None, "Step 7 standard deviation of the "
              "prediction (m); empty: from the prediction residuals.", minimum=0.001,
              maximum=100.0, advanced=True),
        Param("snooping_k", "float", 4.0, "Critical value of the data snooping in steps "
              "5-7 (standardised residual).", minimum=0.5, maximum=20.0, advanced=True),
        Param("snooping_iterations", "int", 1, "Fits per profile length / direction and "
              "per surface (outliers removed between fits).", minimum=1, maximum=10,
              advanced=True),
        Param("low_weight", "float", 0.02, "Weight factor of points below the reference: "
              "their tolerance is 1/sqrt(weight) wider, so ditches stay while deep low "
              "blunders go (class 2).", minimum=0.001, maximum=1.0, advanced=True),
    ),
    title="RASCOR sequential filter (Jacobsen 2004)",
    description=(
        "<p>Filters a raster DSM by a sequence of tests, each catching what the others "
        "miss, with parameters determined from an analysis of the DSM (Jacobsen 2004, "
        "program RASCOR): 1 terrain characterisation (flat / rolling / mountainous, "
        "homogeneity), 2 height distribution (flat terrain only), 3 height differences of "
        "neighbours (tolerance from the random error and the local slope), 4 sudden change "
        "of level along X and Y profiles (buildings), 5 moving local profiles short then "
        "long (mean, linear regression or polynomial, with data snooping), 6 moving "
        "surfaces (horizontal, inclined plane or polynomial), 7 optional local prediction. "
        "Points below the reference get a weight factor instead of removal, so ditches and "
        "cuts stay while deep low blunders are removed (class 2).</p>"
        "<p><b>Second iteration</b>: removes small vegetation but may generalise the "
        "terrain (the paper's warning).</p>"
        "<p><b>Break lines</b> (optional line layer, rasterised to the cells it crosses): "
        "no comparison crosses a break line, so dams, embankments and cuts keep their "
        "shoulders. <b>Special areas</b> (optional polygons): inside them only the local "
        "filters (steps 3 and 7) run, e.g. for cars and bushes on a dam's slope. The core "
        "receives both as boolean rasters <code>breaklines</code> and "
        "<code>special_areas</code> (keyword arrays, not parameters).</p>"
        "<p>Output extra <i>step</i>: which step removed each cell (0 kept).</p>"),
)
