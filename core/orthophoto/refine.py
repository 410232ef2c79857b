"""DEM refinement from the residual parallax of orthophotos (Ke 2002 sec. 2.3; Norvelle 1995).

An orthophoto made with a DEM that is wrong by ``dh`` at a point shows that point displaced
by ``dh * v``, where ``v = (X - X_c, Y - Y_c) / (Z_c - Z)`` is the horizontal vector from the
camera's nadir point to the cell divided by the camera's height above the cell. Two
orthophotos of the same place from cameras ``a`` and ``b`` therefore disagree by the
parallax vector ``p = dh * (v_b - v_a)``; measuring ``p`` by matching the orthophotos gives

    dh = p . (v_b - v_a) / |v_b - v_a|^2                                  (general geometry)

which for vertical frames at one height ``H`` with base ``B`` reduces to Luong Chinh Ke's
eq. 18, ``dh = dx * H / B`` (``dx`` the x-parallax along the base, ground units). Norvelle
(1995) iterates: orthorectify on the current DEM, match, convert, update the DEM, until the
corrections vanish. :func:`orthoparallax` is one such measurement for one pair;
:func:`orthorefine` is the iteration over all overlapping pairs of two or more frames.

Sign: ``dh > 0`` means the true surface is above the DEM (an object the DEM lacks); the
corrected DEM is ``DEM + dh``.
"""
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from ..codes import GROUND, LOW, NODATA, OBJECT
from ..common import report, sub_progress
from .match import match_along
from .orthorectify import check_transform, grid_xy, orthorectify

__all__ = ["view_vectors", "parallax_to_dh", "parallax_to_dh_vertical", "orthoparallax",
           "orthorefine", "ParallaxResult", "RefineResult", "fill_holes"]


# --------------------------------------------------------------------------- geometry
def view_vectors(centre, X, Y, Z):
    """Horizontal vector from the nadir point of ``centre`` to ``(X, Y)`` over height above ``Z``.

    A DEM error ``dh`` at the point moves its orthophoto image by ``dh * v``
    (Norvelle 1995; Luong Chinh Ke 2002, section 2.3).

    Returns
    -------
    vx, vy : ndarray
    """
    C = np.asarray(centre, dtype=float).reshape(3)
    with np.errstate(divide="ignore", invalid="ignore"):
        hgt = C[2] - np.asarray(Z, dtype=float)
        hgt = np.where(hgt > 0, hgt, np.nan)
        return (np.asarray(X, float) - C[0]) / hgt, (np.asarray(Y, float) - C[1]) / hgt


def parallax_to_dh(px, py, va, vb):
    """Height error from the parallax vector of a pair (general geometry).

    Parameters
    ----------
    px, py : array_like
        Parallax: displacement of a feature from orthophoto ``a`` to orthophoto ``b`` in
        ground units (X east, Y north).
    va, vb : (vx, vy) pairs of array_like
        :func:`view_vectors` of cameras ``a`` and ``b`` at the cells.

    Returns
    -------
    ndarray
        ``dh = p . (v_b - v_a) / |v_b - v_a|^2``: the true surface minus the DEM. For
        vertical frames with base ``B`` along x and height ``H`` this is eq. 18 of Luong
        Chinh Ke (2002), ``dh = dx H / B`` (with ``dx`` measured against the base direction).
    """
    dvx = np.asarray(vb[0], float) - np.asarray(va[0], float)
    dvy = np.asarray(vb[1], float) - np.asarray(va[1], float)
    n2 = dvx * dvx + dvy * dvy
    if np.all(~(n2 > 0)):
        raise ValueError("the two cameras see the cells along the same rays (base B = 0); "
                         "parallax gives no height. Use two frames taken from different places.")
    with np.errstate(divide="ignore", invalid="ignore"):
        return (np.asarray(px, float) * dvx + np.asarray(py, float) * dvy) / np.where(n2 > 0, n2, np.nan)


def parallax_to_dh_vertical(dx, base_m, height_m):
    """Eq. 18 of Luong Chinh Ke (2002): ``dh = dx * H / B`` for vertical frames.

    Parameters
    ----------
    dx : array_like
        Residual x-parallax in ground units, positive when the feature in the second
        orthophoto lies *against* the base direction (an object above the DEM).
    base_m : float
        Base B between the exposures (> 0).
    height_m : float
        Flying height H above the ground (> 0).
    """
    base_m, height_m = float(base_m), float(height_m)
    if not base_m > 0:
        raise ValueError(f"base B must be > 0 m; got {base_m}. Two exposures from one place "
                         "give no parallax; pass the distance between the camera centres.")
    if not height_m > 0:
        raise ValueError(f"flying height H must be > 0 m above the ground; got {height_m}.")
    return np.asarray(dx, dtype=float) * height_m / base_m


# --------------------------------------------------------------------------- helpers
def fill_holes(values, valid=None, max_sigma=64.0):
    """Fill NaN cells by normalised convolution at growing Gaussian scales (vectorised).

    Returns a copy with every NaN replaced where data lie within about ``3 * max_sigma``.
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


def _grey(img):
    img = np.asarray(img)
    if img.ndim == 3:
        return np.nanmean(img.astype(np.float32), axis=0) if img.shape[0] > 1 else img[0].astype(np.float32)
    if img.ndim != 2:
        raise ValueError(f"an orthophoto/image must be 2-D or (bands, rows, cols); got shape {img.shape}.")
    return img.astype(np.float32)


def _median_nan(x, size=3):
    """Median filter that ignores NaN (NaN cells stay NaN)."""
    ok = np.isfinite(x)
    if not ok.any():
        return x
    f = fill_holes(x, ok, max_sigma=4)
    f = np.where(np.isfinite(f), f, 0)
    m = ndimage.median_filter(f, size, mode="nearest")
    return np.where(ok, m, np.nan).astype(np.float32)


def _relocate(dh, corr, shift_x_m, shift_y_m, transform):
    """Move measurements from the matched location to the ground point (forward warp).

    The symmetric match of a point ``P`` lies at ``P + dh * (v_a + v_b) / 2``; the value is
    written to the cell of ``P`` (the highest ``dh`` wins where several land on one cell,
    as the higher surface hides the lower).
    """
    x0, dx, y0, dy = check_transform(transform)
    ok = np.isfinite(dh) & np.isfinite(shift_x_m) & np.isfinite(shift_y_m)
    if not ok.any():
        return dh, corr
    rr, cc = np.nonzero(ok)
    tc = np.rint(cc - shift_x_m[ok] / dx).astype(np.int64)
    tr = np.rint(rr + shift_y_m[ok] / dy).astype(np.int64)
    inside = (tc >= 0) & (tc < dh.shape[1]) & (tr >= 0) & (tr < dh.shape[0])
    vals = dh[ok][inside]
    cv = corr[ok][inside]
    tr, tc = tr[inside], tc[inside]
    order = np.argsort(vals, kind="stable")                       # last write (highest) wins
    out = np.full_like(dh, np.nan)
    outc = np.full_like(corr, np.nan)
    out[tr[order], tc[order]] = vals[order]
    outc[tr[order], tc[order]] = cv[order]
    # single-cell holes from rounding: take the neighbourhood median of written cells
    holes = ~np.isfinite(out) & ndimage.binary_erosion(
        ndimage.binary_closing(np.isfinite(out), iterations=1, border_value=0), border_value=1)
    if holes.any():
        f = _median_nan(out, 3)
        filled = fill_holes(out, np.isfinite(out), max_sigma=1.0)
        out[holes] = np.where(np.isfinite(f[holes]), f[holes], filled[holes])
        fc = fill_holes(outc, np.isfinite(outc), max_sigma=1.0)
        outc[holes] = fc[holes]
    return out, outc


@dataclass
class ParallaxResult:
    """Result of :func:`orthoparallax`.

    Attributes
    ----------
    dem : ndarray float32
        Corrected DEM: input DEM + ``dh`` (gaps in ``dh`` interpolated); input DEM where the
        orthophotos do not overlap.
    dh : ndarray float32
        Height correction at matched cells (NaN elsewhere).
    quality : ndarray float32
        Peak normalised cross-correlation (NaN where not computed).
    mask : ndarray uint8
        1 object (dh above the threshold), 2 low (below minus the threshold), 0 ground, 255
        cells not seen in both orthophotos.
    info : dict
        Parameters used and statistics (matched share, RMS of dh, threshold ...).
    """
    dem: np.ndarray
    dh: np.ndarray
    quality: np.ndarray
    mask: np.ndarray
    info: dict = field(default_factory=dict)


def _pair_geometry(dem, transform, centres, base_m, height_m, base_direction):
    """Geometry of a pair: the match direction and ``v_b - v_a`` as a function of ``dh``.

    The view vectors belong to the true point, at height ``DEM + dh``; the returned
    ``dv(dh)`` gives ``(v_b - v_a, (v_a + v_b) / 2)`` per cell for a trial ``dh``.
    """
    X, Y = grid_xy(dem.shape, transform)
    Zs = np.where(np.isfinite(dem), dem, np.nanmedian(dem)).astype(np.float64)
    if centres is not None:
        ca, cb = (np.asarray(c, dtype=float).reshape(3) for c in centres)
        if not (np.all(np.isfinite(ca)) and np.all(np.isfinite(cb))):
            raise ValueError("camera centres must be 3 finite numbers (X, Y, Z) each.")
        if np.linalg.norm(ca - cb) < 1e-9 * max(1.0, abs(ca[2])):
            raise ValueError("the two camera centres coincide (base B = 0): no parallax. "
                             "Pass the centres of two different exposures.")
        if np.any(ca[2] <= Zs) or np.any(cb[2] <= Zs):
            raise ValueError("a camera centre is not above the DEM; check the Z of the centres "
                             "and that the DEM heights use the same datum.")

        def dv(dh):
            Z = Zs + np.where(np.isfinite(dh), dh, 0.0)
            va = view_vectors(ca, X, Y, Z)
            vb = view_vectors(cb, X, Y, Z)
            return ((vb[0] - va[0], vb[1] - va[1]),
                    (0.5 * (va[0] + vb[0]), 0.5 * (va[1] + vb[1])))
    else:
        if base_m is None or height_m is None:
            raise ValueError("give either the two camera centres or both base_m (B) and height_m (H).")
        parallax_to_dh_vertical(1.0, base_m, height_m)          # validates B and H
        B, H = float(base_m), float(height_m)
        e = np.asarray(base_direction, dtype=float).reshape(2)
        if not np.hypot(*e) > 0:
            raise ValueError("base_direction must be a non-zero (X, Y) vector.")
        e = e / np.hypot(*e)

        def dv(dh):
            # camera b = a + B e at height H above the DEM: v_b - v_a = -(B / (H - dh)) e
            hh = H - np.where(np.isfinite(dh), dh, 0.0) + np.zeros(dem.shape)
            hh = np.where(hh > 0, hh, np.nan)
            return (-B / hh * e[0], -B / hh * e[1]), None
    (dvx, dvy), _ = dv(np.zeros(dem.shape))
    mx, my = float(np.nanmean(dvx)), float(np.nanmean(dvy))
    nrm = math.hypot(mx, my)
    if not nrm > 1e-9:
        raise ValueError("the two cameras give no parallax over this grid (base B = 0 or "
                         "cameras on one vertical line); use another pair.")
    return dict(dv=dv, u=(mx / nrm, my / nrm), relocatable=centres is not None)


def _match_pair(a, b, dem, transform, geom, *, window, shiftable, min_corr, max_dh_m,
                lsm_iterations, relocate):
    """Match one pair of orthophotos and convert to ``dh`` (helper of both entry points)."""
    ux, uy = geom["u"]
    x0, dx, y0, dy = check_transform(transform)
    # direction in cells (col, row); rows run south
    wc, wr = ux / dx, -uy / dy
    nrm = math.hypot(wc, wr)
    wc, wr = wc / nrm, wr / nrm
    step_m = math.hypot(wc * dx, wr * dy)                 # metres per cell of shift
    (dvx, dvy), _ = geom["dv"](np.zeros(dem.shape))
    along0 = dvx * ux + dvy * uy                           # (v_b - v_a) . u at the DEM
    max_shift = int(math.ceil(max_dh_m * float(np.nanmax(np.abs(along0))) * 1.1 / step_m)) + 1
    m = match_along(a, b, (wc, wr), max_shift, window=window, shiftable=shiftable,
                    min_corr=min_corr, lsm_iterations=lsm_iterations)
    p = m.disparity.astype(np.float64) * step_m            # parallax along u, ground units
    with np.errstate(divide="ignore", invalid="ignore"):
        dh = p / along0
        for _ in range(4):   # the view vectors belong to the true point at DEM + dh
            (dvx, dvy), _ = geom["dv"](dh)
            dh = p / (dvx * ux + dvy * uy)
    dh = np.where(np.abs(dh) <= max_dh_m, dh, np.nan).astype(np.float32)
    corr = m.corr
    if relocate and geom["relocatable"]:
        # the match of ground point P lies at m = P + dh (v_a + v_b) / 2 and measures the
        # surface height DEM(m) + dh: move that height to P, then subtract DEM(P)
        _, mid = geom["dv"](dh)
        z, corr = _relocate((dem + dh).astype(np.float32), corr, dh * mid[0], dh * mid[1], transform)
        dh = (z - dem).astype(np.float32)
    prec = float(np.nanmedian(step_m / np.abs(along0)))   # metres of dh per cell of parallax
    pv = p[np.isfinite(p)]
    return dh, corr, dict(max_shift=max_shift, dh_per_cell_m=prec, direction_xy=(ux, uy),
                          rms_parallax_m=float(np.sqrt(np.mean(pv ** 2))) if pv.size else float("nan"),
                          b_over_h=float(np.nanmedian(np.abs(along0))),
                          matched=int(np.isfinite(dh).sum()))


def _match_pair_cropped(a, b, dem, transform, both, centres, base_m, height_m, base_direction,
                        *, window, shiftable, min_corr, max_dh_m, lsm_iterations, relocate):
    """:func:`_match_pair` on the bounding box of the pair's overlap (plus a margin)."""
    x0, dx, y0, dy = check_transform(transform)
    rows = np.nonzero(both.any(axis=1))[0]
    cols = np.nonzero(both.any(axis=0))[0]
    # margin: the window, and the relocation/search reach in cells
    geom_full = None
    margin = window + 2
    r0, r1 = max(0, rows[0] - margin), min(dem.shape[0], rows[-1] + margin + 1)
    c0, c1 = max(0, cols[0] - margin), min(dem.shape[1], cols[-1] + margin + 1)
    sl = (slice(r0, r1), slice(c0, c1))
    sub_t = (x0 + c0 * dx, dx, 0.0, y0 - r0 * dy, 0.0, -dy)
    geom_full = _pair_geometry(dem[sl], sub_t, centres, base_m, height_m, base_direction)
    dh_s, corr_s, info = _match_pair(np.where(both, a, np.nan)[sl], np.where(both, b, np.nan)[sl],
                                     dem[sl], sub_t, geom_full, window=window,
                                     shiftable=shiftable, min_corr=min_corr, max_dh_m=max_dh_m,
                                     lsm_iterations=lsm_iterations, relocate=relocate)
    dh = np.full(dem.shape, np.nan, np.float32)
    corr = np.full(dem.shape, np.nan, np.float32)
    dh[sl] = dh_s
    corr[sl] = corr_s
    info["crop"] = (int(r0), int(r1), int(c0), int(c1))
    return dh, corr, info


def _object_mask(dh, both, sigma_expected, threshold, object_size_cells, k=3.0):
    """Object mask from height corrections relative to their ground trend.

    The trend is a grey opening of ``dh`` wider than the largest object (it removes the
    objects and keeps smooth DEM errors), smoothed; a cell is an object when ``dh`` exceeds
    the trend by ``threshold`` (default ``k * max(expected precision, robust sd)``).

    Returns
    -------
    mask : ndarray uint8
    threshold : float
    sigma_data : float
    """
    d = np.where(np.isfinite(dh), dh, 0.0).astype(np.float32)
    size = int(object_size_cells) | 1
    if size >= 3:
        trend = ndimage.grey_opening(np.where(both, d, np.nanmax(d[both]) if both.any() else 0), size=size)
        trend = ndimage.uniform_filter(trend, size, mode="nearest")
        trend = np.minimum(trend, ndimage.grey_opening(d, size=3))
    else:
        trend = np.zeros_like(d)
    rel = d - trend
    vals = rel[both & np.isfinite(dh)]
    sig = (1.4826 * float(np.median(np.abs(vals - np.median(vals))))) if vals.size else float("nan")
    if threshold is None:
        threshold = k * max(sigma_expected, sig if np.isfinite(sig) else 0.0)
    mask = np.full(d.shape, NODATA, np.uint8)
    mask[both] = GROUND
    mask[both & (rel > threshold)] = OBJECT
    mask[both & (rel < -threshold)] = LOW
    return mask, float(threshold), sig


def orthoparallax(ortho_a, ortho_b, dem, transform, *, centres=None, base_m=None, height_m=None,
                  base_direction=(1.0, 0.0), window=7, shiftable=5, min_corr=0.6,
                  max_dh_m=None, height_threshold_m=None, precision_cells=0.2,
                  lsm_iterations=3, relocate=True, object_size_m=40.0, progress=None):
    """Measure the DEM error from the residual parallax of two orthophotos (one pass).

    Luong Chinh Ke (2002, section 2.3): two orthophotos of overlapping frames made with
    the same DEM agree where the DEM is right; where it is wrong by ``dh`` (an object the
    DEM lacks, a matching blunder) they are displaced by a parallax ``p`` along the base,
    and ``dh = p H / B`` (eq. 18). With the camera centres the general form
    ``dh = p . (v_b - v_a) / |v_b - v_a|^2`` is used (:func:`parallax_to_dh`), and the
    measurement is moved to the ground point (``relocate``). Matching is normalised
    cross-correlation along the base with a left-right check and sub-pixel least squares
    (:func:`~.match.match_along`), as in Norvelle (1995).

    Parameters
    ----------
    ortho_a, ortho_b : ndarray, (rows, cols) or (bands, rows, cols)
        Orthophotos on the grid of ``dem`` made with ``dem`` (NaN = not seen).
    dem : ndarray (rows, cols)
        The DEM used for both orthophotos.
    transform : 6 floats
        North-up geotransform of the grid (metres).
    centres : ((X, Y, Z), (X, Y, Z)), optional
        Projection centres of the cameras of ``a`` and ``b``.
    base_m, height_m : float, optional
        B and H for vertical frames (instead of ``centres``); camera ``b`` is at
        ``a + B * base_direction``.
    base_direction : (float, float)
        (X, Y) direction from camera ``a`` to camera ``b`` when B and H are given.
    window : int
        Odd correlation window in cells.
    shiftable : int
        Shiftable-window neighbourhood (0: off).
    min_corr : float
        Correlation threshold.
    max_dh_m : float, optional
        Largest |dh| searched; default 0.1 * H (the camera height above the DEM).
    height_threshold_m : float, optional
        Object threshold on dh; default ``3 * max(expected precision, robust sd of dh)``, the
        expected precision being ``precision_cells`` of parallax converted to height.
    precision_cells : float
        Expected matching precision in cells, for the default threshold.
    lsm_iterations : int
        Least-squares sub-pixel iterations.
    relocate : bool
        Move measurements from the matched location to the ground point (needs centres).
    object_size_m : float
        Largest object width: the object mask compares ``dh`` with its ground trend (a grey
        opening of this width), so smooth DEM errors are not objects; 0 compares with 0.
    progress : callable, optional
        ``progress(fraction)``; may raise Cancelled.

    Returns
    -------
    ParallaxResult
    """
    a, b = _grey(ortho_a), _grey(ortho_b)
    dem = np.asarray(dem, dtype=np.float32)
    if dem.ndim != 2:
        raise ValueError(f"dem must be 2-D; got shape {dem.shape}.")
    if a.shape != dem.shape or b.shape != dem.shape:
        raise ValueError(f"orthophotos {a.shape}, {b.shape} and DEM {dem.shape} are not on the same "
                         "grid; make both orthophotos with this DEM (same rows, columns, transform).")
    check_transform(transform)
    both = np.isfinite(a) & np.isfinite(b) & np.isfinite(dem)
    if both.sum() < window * window * 4:
        raise ValueError(f"the orthophotos overlap on only {int(both.sum())} cells; the images do "
                         "not overlap enough to match. Use a pair of overlapping frames.")
    report(progress, 0.05)
    _pair_geometry(dem, transform, centres, base_m, height_m, base_direction)  # validates
    if max_dh_m is None:
        if centres is not None:
            hgt = min(float(np.asarray(c, float)[2]) for c in centres) - float(np.nanmedian(dem))
        else:
            hgt = float(height_m)
        max_dh_m = 0.1 * hgt
    if not max_dh_m > 0:
        raise ValueError(f"max_dh_m must be > 0; got {max_dh_m}.")
    dh, corr, info = _match_pair_cropped(a, b, dem, transform, both, centres, base_m, height_m,
                                         base_direction, window=window, shiftable=shiftable,
                                         min_corr=min_corr, max_dh_m=float(max_dh_m),
                                         lsm_iterations=lsm_iterations, relocate=relocate)
    report(progress, 0.8)
    dh = np.where(both, dh, np.nan).astype(np.float32)
    sigma_exp = precision_cells * info["dh_per_cell_m"]
    filled = fill_holes(_median_nan(dh, 3), both)
    filled = np.where(both, filled, np.nan)
    corrected = np.where(both & np.isfinite(filled), dem + filled, dem).astype(np.float32)
    size = _object_cells(object_size_m, transform)
    mask, thr, sig = _object_mask(filled, both, sigma_exp, height_threshold_m, size)
    matched = np.isfinite(dh)
    info.update(window=window, shiftable=shiftable, min_corr=min_corr, max_dh_m=float(max_dh_m),
                height_threshold_m=float(thr), sigma_expected_m=float(sigma_exp),
                sigma_data_m=sig, overlap_cells=int(both.sum()),
                matched_share=float(matched.sum() / both.sum()),
                rms_dh_m=float(np.sqrt(np.mean(dh[matched] ** 2))) if matched.any() else float("nan"))
    report(progress, 1.0)
    quality = np.where(both, corr, np.nan).astype(np.float32)
    return ParallaxResult(corrected, dh, quality, mask, info)


# --------------------------------------------------------------------------- iteration
@dataclass
class RefineResult:
    """Result of :func:`orthorefine`.

    Attributes
    ----------
    dem : ndarray float32
        Refined DEM.
    orthos : list of ndarray float32
        The orthophotos of the last iteration (made with the DEM of that iteration).
    dh : ndarray float32
        Total correction, refined minus input DEM (NaN where fewer than two frames see).
    quality : ndarray float32
        Correlation-weighted mean peak NCC of the last iteration.
    mask : ndarray uint8
        1 object where ``dh`` exceeds the threshold, 2 low, 0 ground, 255 not seen by two frames.
    table : list of dict
        Per iteration: ``iteration``, ``rms_correction_m`` (RMS of the merged correction
        over matched cells), ``matched_share`` (matched / cells seen by two frames),
        ``pairs``, ``rms_parallax_m`` (RMS residual parallax of the pairs, ground units,
        measured on that iteration's DEM), ``mean_corr`` and, with ``reference``,
        ``rmse_reference_m``.
    info : dict
    """
    dem: np.ndarray
    orthos: list
    dh: np.ndarray
    quality: np.ndarray
    mask: np.ndarray
    table: list
    info: dict = field(default_factory=dict)


def overlapping_pairs(seen, min_overlap=0.05, min_cells=100):
    """Index pairs ``(i, j)`` whose seen-cell masks share at least ``min_overlap`` of the smaller."""
    pairs = []
    for i in range(len(seen)):
        for j in range(i + 1, len(seen)):
            both = int((seen[i] & seen[j]).sum())
            small = max(1, min(int(seen[i].sum()), int(seen[j].sum())))
            if both >= min_cells and both / small >= min_overlap:
                pairs.append((i, j))
    return pairs


def orthorefine(dem, transform, images, cameras, *, max_iterations=6, tolerance_m=None,
                window=7, shiftable=5, min_corr=0.6, max_dh_m=None, pairs=None,
                min_overlap=0.05, smooth_cells=5, height_threshold_m=None,
                precision_cells=0.2, antialias=True, object_size_m=40.0, fill_sigma_cells=3.0,
                relaxation=0.7, outlier_m=None, reference=None, reference_cells=None,
                tie_points=None, base_m=None,
                height_m=None, base_direction=(1.0, 0.0), progress=None):
    """Iterative orthophoto refinement of a DEM (Norvelle 1995; Luong Chinh Ke 2002, 2.3).

    Each iteration orthorectifies every frame onto the current DEM (collinearity equations,
    bilinear resampling, hidden and unseen cells masked), matches the orthophotos of every
    overlapping pair along its base (:func:`orthoparallax`'s matcher), converts the parallax
    to height corrections with the general geometry, merges the pairs' corrections weighted
    by correlation, removes blunders with a 3 x 3 median, fills gaps and adds the correction
    to the DEM. It stops when the RMS correction falls below ``tolerance_m`` or after
    ``max_iterations``.

    Parameters
    ----------
    dem : ndarray (rows, cols)
        Starting DEM (NaN = nodata).
    transform : 6 floats
        North-up geotransform of ``dem`` (same CRS and units as the camera centres).
    images : sequence of ndarray
        Frame images, (rows, cols) or (bands, rows, cols).
    cameras : sequence of Camera, or None
        One per image (:mod:`.camera`). ``None`` when no orientation is known: then
        ``images`` are orthophotos registered to the DEM by eq. 17 from ``tie_points``.
    max_iterations : int
    tolerance_m : float, optional
        Stop when the RMS correction of an iteration is below this; default half the
        expected height precision of the pairs (``precision_cells`` of parallax).
    window, shiftable, min_corr : matcher settings (see :func:`~.match.match_along`).
    max_dh_m : float, optional
        Largest correction searched per iteration; default 0.1 * camera height above the DEM.
    pairs : list of (int, int), optional
        Pairs to match; default every pair that overlaps by ``min_overlap``.
    smooth_cells : int
        Median filter size applied to each iteration's correction (0: none).
    height_threshold_m : float, optional
        Object threshold on the total correction (default from the data, as orthoparallax).
    antialias : bool
        Low-pass the images to the ground cell size before resampling.
    object_size_m : float
        Largest object width: the object mask compares ``dh`` with its ground trend (a grey
        opening of this width), so smooth DEM errors are not objects; 0 compares with 0.
    fill_sigma_cells : float
        Reach (Gaussian sigma, cells) of the interpolation of each iteration's correction
        into unmatched cells; farther cells keep their height.
    relaxation : float
        Share of each iteration's correction applied (1: all); below 1 damps the matching
        noise that the iterations would otherwise accumulate on real images.
    outlier_m : float, optional
        Pair corrections farther than this from the per-cell median of the pairs are
        dropped before the correlation-weighted mean; default 3 x the expected precision.
    reference : ndarray, optional
        A reference surface for evaluation only: adds ``rmse_reference_m`` to the table.
    reference_cells : ndarray of bool, optional
        Cells of that evaluation (default: the cells seen by two frames in the iteration).
    tie_points : sequence, optional
        Without ``cameras``: per image, a :class:`~.affine8.Bilinear8` or a pair
        ``(dem_xy, ortho_xy)`` of at least four ground points (DEM map coordinates and the
        image's pixel column, row) for eq. 17 of Luong Chinh Ke (2002). The orthophotos
        cannot be redrawn on a new DEM without an orientation, so this is one pass
        (:func:`orthoparallax` on every overlapping pair, merged), with the vertical-frame
        geometry of ``base_m`` (B between consecutive images, along ``base_direction``)
        and ``height_m`` (H).
    base_m, height_m, base_direction : float, float, (float, float)
        B, H and the base direction for ``tie_points`` mode.
    progress : callable, optional
        ``progress(fraction)``; may raise Cancelled.

    Returns
    -------
    RefineResult
    """
    dem0 = np.asarray(dem, dtype=np.float32)
    if dem0.ndim != 2:
        raise ValueError(f"dem must be 2-D; got shape {dem0.shape}.")
    check_transform(transform)
    images = list(images)
    cameras = None if cameras is None else list(cameras)
    if len(images) < 2:
        raise ValueError(f"orthorefine needs two or more overlapping frames; got {len(images)}.")
    if cameras is not None and any(c is None for c in cameras) and not all(c is None for c in cameras):
        raise ValueError("give a camera for every image, or none (tie_points mode).")
    if cameras is not None and len(images) != len(cameras):
        raise ValueError(f"{len(images)} images but {len(cameras)} cameras; give one camera per image.")
    if int(max_iterations) < 1:
        raise ValueError(f"max_iterations must be >= 1; got {max_iterations}.")
    if cameras is None or all(c is None for c in cameras):
        return _refine_registered(dem0, transform, images, tie_points, base_m, height_m,
                                  base_direction, window=window, shiftable=shiftable,
                                  min_corr=min_corr, max_dh_m=max_dh_m, pairs=pairs,
                                  min_overlap=min_overlap, smooth_cells=smooth_cells,
                                  height_threshold_m=height_threshold_m,
                                  precision_cells=precision_cells, object_size_m=object_size_m,
                                  fill_sigma_cells=fill_sigma_cells, outlier_m=outlier_m,
                                  reference=reference, progress=progress)
    greys = [_grey(im) for im in images]
    for g, c in zip(greys, cameras):
        if (g.shape[1], g.shape[0]) != (c.interior.width, c.interior.height):
            raise ValueError(f"image of camera {c.name!r} is {g.shape[1]} x {g.shape[0]} pixels, its "
                             f"interior orientation {c.interior.width} x {c.interior.height}.")
    valid_dem = np.isfinite(dem0)
    if not valid_dem.any():
        raise ValueError("dem has no valid cell.")
    hgt = min(float(c.centre[2]) for c in cameras) - float(np.nanmedian(dem0))
    if not hgt > 0:
        raise ValueError("the cameras are not above the DEM; check the camera Z and the DEM datum.")
    if max_dh_m is None:
        max_dh_m = 0.1 * hgt
    if antialias:
        greys = [_antialias(g, c, dem0, transform) for g, c in zip(greys, cameras)]
    cur = dem0.copy()
    table = []
    pair_list = pairs
    info = {}
    orthos, quality, seen_count = None, None, None
    for it in range(int(max_iterations)):
        prog = sub_progress(progress, it / max_iterations, (it + 1) / max_iterations)
        filled_dem = np.where(valid_dem, cur, np.nan)
        res = [orthorectify(g, c, filled_dem, transform) for g, c in zip(greys, cameras)]
        orthos = [r[0] for r in res]
        seen = [r[1] for r in res]
        seen_count = np.sum(seen, axis=0)
        if pair_list is None:
            pair_list = overlapping_pairs(seen, min_overlap)
            if not pair_list:
                raise ValueError("no two images overlap on the DEM grid (each pair shares less than "
                                 f"{min_overlap:.0%} of its cells); check the orientations, the CRS "
                                 "and that the DEM covers the images.")
        report(prog, 0.2)
        dhs, cors, pinfo = [], [], []
        for k, (i, j) in enumerate(pair_list):
            both = seen[i] & seen[j]
            if both.sum() < window * window * 4:
                continue
            dh, corr, pi = _match_pair_cropped(
                orthos[i], orthos[j], filled_dem, transform, both,
                (cameras[i].centre, cameras[j].centre), None, None, None, window=window,
                shiftable=shiftable, min_corr=min_corr, max_dh_m=float(max_dh_m),
                lsm_iterations=3, relocate=True)
            ok = np.isfinite(dh) & both & np.isfinite(corr)
            dhs.append(np.where(ok, dh, np.nan).astype(np.float32))
            cors.append(np.where(ok, corr, np.nan).astype(np.float32))
            pi.update(pair=(i, j), matched_share=float(ok.sum() / both.sum()))
            pinfo.append(pi)
            report(prog, 0.2 + 0.7 * (k + 1) / len(pair_list))
        if it == 0:
            prec = float(np.median([p["dh_per_cell_m"] for p in pinfo])) if pinfo else 1.0
            info["sigma_expected_m"] = precision_cells * prec
            if tolerance_m is None:
                tolerance_m = 0.5 * info["sigma_expected_m"]
        multi = (seen_count >= 2) & valid_dem
        dh_it, quality = _merge_pairs(dhs, cors, outlier_m if outlier_m is not None
                                      else 3.0 * max(info["sigma_expected_m"], 0.1))
        matched = np.isfinite(dh_it) & multi
        if smooth_cells and smooth_cells > 1:
            dh_it = _median_nan(dh_it, int(smooth_cells))
        corr_full = fill_holes(dh_it, matched, max_sigma=fill_sigma_cells)
        # corrections reach unmatched cells within the fill distance (smooth DEM errors)
        corr_full = np.where(np.isfinite(corr_full), corr_full, 0.0)
        cur = np.where(valid_dem, cur + relaxation * corr_full, np.nan).astype(np.float32)
        rms = float(np.sqrt(np.mean(dh_it[matched] ** 2))) if matched.any() else float("nan")
        row = dict(iteration=it + 1, rms_correction_m=rms,
                   matched_share=float(matched.sum() / max(1, multi.sum())),
                   pairs=len(pinfo),
                   rms_parallax_m=float(np.sqrt(np.nanmean([pi["rms_parallax_m"] ** 2 for pi in pinfo]))),
                   mean_corr=float(np.nanmean(quality[matched])) if matched.any() else float("nan"))
        if reference is not None:
            ev = (multi if reference_cells is None else reference_cells) & np.isfinite(reference) & valid_dem
            row["rmse_reference_m"] = float(np.sqrt(np.mean((cur - reference)[ev] ** 2))) if ev.any() else float("nan")
        table.append(row)
        report(prog, 1.0)
        if not np.isfinite(rms) or rms < tolerance_m:
            break
    multi = (seen_count >= 2) & valid_dem
    dh_total = np.where(multi, cur - dem0, np.nan).astype(np.float32)
    mask, thr, sig = _object_mask(dh_total, multi, info["sigma_expected_m"], height_threshold_m,
                                  _object_cells(object_size_m, transform))
    info.update(pairs=[tuple(p) for p in pair_list], iterations=len(table),
                tolerance_m=float(tolerance_m), max_dh_m=float(max_dh_m),
                height_threshold_m=float(thr), window=window, shiftable=shiftable,
                min_corr=min_corr, cells_seen_by_two=int(multi.sum()))
    return RefineResult(cur, orthos, dh_total, np.where(multi, quality, np.nan).astype(np.float32),
                        mask, table, info)


def _refine_registered(dem0, transform, images, tie_points, base_m, height_m, base_direction,
                       *, window, shiftable, min_corr, max_dh_m, pairs, min_overlap,
                       smooth_cells, height_threshold_m, precision_cells, object_size_m,
                       fill_sigma_cells, outlier_m, reference, progress):
    """One refinement pass on orthophotos registered by eq. 17 (no orientation known)."""
    from .affine8 import Bilinear8, fit_bilinear8, register_orthophoto
    if tie_points is None or len(tie_points) != len(images):
        raise ValueError("without cameras, give tie_points: per image a Bilinear8 or "
                         "(dem_xy, ortho_xy) with at least four ground points (eq. 17).")
    if base_m is None or height_m is None:
        raise ValueError("without cameras, give base_m (B between consecutive images) and "
                         "height_m (H) for eq. 18.")
    parallax_to_dh_vertical(1.0, base_m, height_m)                      # validates B and H
    if max_dh_m is None:
        max_dh_m = 0.1 * float(height_m)
    orthos = []
    for img, tp in zip(images, tie_points):
        tr8 = tp if isinstance(tp, Bilinear8) else fit_bilinear8(*tp)
        orthos.append(_grey(register_orthophoto(img, tr8, dem0.shape, transform)))
    seen = [np.isfinite(o) & np.isfinite(dem0) for o in orthos]
    pair_list = pairs if pairs is not None else overlapping_pairs(seen, min_overlap)
    if not pair_list:
        raise ValueError("no two registered orthophotos overlap on the DEM grid; check the tie points.")
    dhs, cors, pinfo = [], [], []
    for k, (i, j) in enumerate(pair_list):
        both = seen[i] & seen[j]
        if both.sum() < window * window * 4:
            continue
        dh, corr, pi = _match_pair_cropped(
            orthos[i], orthos[j], dem0, transform, both, None, (j - i) * float(base_m),
            float(height_m), base_direction, window=window, shiftable=shiftable,
            min_corr=min_corr, max_dh_m=float(max_dh_m), lsm_iterations=3, relocate=False)
        ok = np.isfinite(dh) & both
        dhs.append(np.where(ok, dh, np.nan).astype(np.float32))
        cors.append(np.where(ok, corr, np.nan).astype(np.float32))
        pi.update(pair=(i, j), matched_share=float(ok.sum() / both.sum()))
        pinfo.append(pi)
        report(progress, 0.9 * (k + 1) / len(pair_list))
    sigma = precision_cells * float(np.median([p["dh_per_cell_m"] for p in pinfo])) if pinfo else 1.0
    dh_it, quality = _merge_pairs(dhs, cors, outlier_m if outlier_m is not None else 3 * max(sigma, 0.1))
    multi = (np.sum(seen, axis=0) >= 2)
    matched = np.isfinite(dh_it) & multi
    if smooth_cells and smooth_cells > 1:
        dh_it = _median_nan(dh_it, int(smooth_cells))
    full = fill_holes(dh_it, matched, max_sigma=fill_sigma_cells)
    cur = np.where(np.isfinite(dem0), dem0 + np.where(np.isfinite(full), full, 0), np.nan).astype(np.float32)
    row = dict(iteration=1, rms_correction_m=float(np.sqrt(np.mean(dh_it[matched] ** 2))) if matched.any() else float("nan"),
               matched_share=float(matched.sum() / max(1, multi.sum())), pairs=len(pinfo),
               rms_parallax_m=float(np.sqrt(np.nanmean([p["rms_parallax_m"] ** 2 for p in pinfo]))),
               mean_corr=float(np.nanmean(quality[matched])) if matched.any() else float("nan"))
    if reference is not None:
        ev = multi & np.isfinite(reference)
        row["rmse_reference_m"] = float(np.sqrt(np.mean((cur - reference)[ev] ** 2))) if ev.any() else float("nan")
    dh_total = np.where(multi, cur - dem0, np.nan).astype(np.float32)
    mask, thr, _ = _object_mask(dh_total, multi, sigma, height_threshold_m,
                                _object_cells(object_size_m, transform))
    report(progress, 1.0)
    info = dict(mode="eq. 17 registration, one pass (no orientation: orthophotos cannot be redrawn)",
                pairs=[tuple(p) for p in pair_list], iterations=1, sigma_expected_m=sigma,
                height_threshold_m=float(thr), max_dh_m=float(max_dh_m), window=window,
                shiftable=shiftable, min_corr=min_corr, cells_seen_by_two=int(multi.sum()))
    return RefineResult(cur, orthos, dh_total, np.where(multi, quality, np.nan).astype(np.float32),
                        mask, [row], info)


def _merge_pairs(dhs, cors, outlier_m):
    """Correlation-weighted mean of the pairs' corrections after dropping per-cell outliers.

    Returns ``(dh, quality)``: the merged correction (NaN where no pair matched) and the
    correlation-weighted mean peak NCC.
    """
    if not dhs:
        raise ValueError("no pair of orthophotos could be matched; check that the images overlap.")
    D = np.stack(dhs)
    C = np.stack(cors)
    if len(dhs) > 1:
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(D, axis=0)
            n = np.sum(np.isfinite(D), axis=0)
            # with three or more values the median is robust: drop the far ones
            with np.errstate(invalid="ignore"):
                far = (np.abs(D - med) > outlier_m) & (n >= 3)
            D = np.where(far, np.nan, D)
            # two values that disagree: neither is trusted
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


def _object_cells(object_size_m, transform):
    _, dx, _, dy = check_transform(transform)
    if object_size_m is None or object_size_m <= 0:
        return 0
    return int(math.ceil(float(object_size_m) / min(dx, dy)))


def _antialias(img, camera, dem, transform):
    """Gaussian low-pass of a frame to the ground cell size (avoids aliasing in orthophotos)."""
    _, dx, _, dy = check_transform(transform)
    X, Y = grid_xy(dem.shape, transform)
    z = float(np.nanmedian(dem))
    # pixels per cell near the image centre, from the nadir-ish scale f * cell / distance
    dist = float(np.linalg.norm(camera.centre - np.array([X.mean(), Y.mean(), z])))
    ppc = camera.interior.fx * min(dx, dy) / max(dist, 1e-9)
    if ppc <= 1.5:
        return img
    sigma = 0.5 * math.sqrt(ppc * ppc - 1.0)
    ok = np.isfinite(img)
    z0 = np.where(ok, img, 0).astype(np.float32)
    num = ndimage.gaussian_filter(z0, sigma)
    den = ndimage.gaussian_filter(ok.astype(np.float32), sigma)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(ok & (den > 0.5), num / den, np.nan).astype(np.float32)
