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
:func:`~.iterate.orthorefine` is the iteration over all overlapping pairs of two or more
frames.

Sign: ``dh > 0`` means the true surface is above the DEM (an object the DEM lacks); the
corrected DEM is ``DEM + dh``.
"""
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage, special

from ..codes import GROUND, NODATA, OBJECT
from ..common import real_array, report
from .match import REASONS, check_min_corr, match_along
from .orthorectify import check_transform, grid_xy
from .quality import (
    agree_at_height,
    agreement_bound,
    close_mask,
    fill_holes,
    nan_median_at,
    object_mask,
    remove_blunders,
    settle_boundary,
    window_variance,
)

__all__ = ["view_vectors", "parallax_to_dh", "parallax_to_dh_vertical", "orthoparallax",
           "ParallaxResult", "fill_holes", "as_grey", "pair_geometry", "match_pair",
           "object_cells", "plain_warning", "reasons_text", "MIN_MATCHED_SHARE"]


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
        hgt = np.asarray(C[2] - np.asarray(Z, dtype=float))      # a new array: masked in place
        hgt[~(hgt > 0)] = np.nan
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


def as_grey(img):
    """One float32 grey band of an image: 2-D as is, ``(bands, rows, cols)`` the band mean; the
    masked pixels of a numpy masked array are NaN (invalid), complex values refused."""
    img = real_array(img, "the image", "grey values")     # masked pixels NaN (invalid); no complex
    if img.ndim == 3:
        return np.nanmean(img.astype(np.float32), axis=0) if img.shape[0] > 1 else img[0].astype(np.float32)
    if img.ndim != 2:
        raise ValueError(f"an orthophoto/image must be 2-D or (bands, rows, cols); got shape {img.shape}.")
    return img.astype(np.float32)




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
    out = np.full_like(dh, np.nan)
    outc = np.full_like(corr, np.nan)
    # cells hit once take their value; only cells hit several times need the order by value
    t = tr * dh.shape[1] + tc
    hits = np.bincount(t, minlength=dh.size)
    one = hits[t] == 1
    out.flat[t[one]] = vals[one]
    outc.flat[t[one]] = cv[one]
    many = ~one
    t, vals, cv = t[many], vals[many], cv[many]
    order = np.argsort(vals, kind="stable")                       # last write (highest) wins
    out.flat[t[order]] = vals[order]
    outc.flat[t[order]] = cv[order]
    # single-cell holes from rounding: take the neighbourhood median of written cells
    holes = ~np.isfinite(out) & ndimage.binary_erosion(
        ndimage.binary_closing(np.isfinite(out), iterations=1, border_value=0), border_value=1)
    if holes.any():
        f = nan_median_at(out, np.nonzero(holes), 3)
        if not np.isfinite(f).all():
            f = np.where(np.isfinite(f), f, fill_holes(out, np.isfinite(out), max_sigma=1.0)[holes])
        out[holes] = f
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


def pair_geometry(dem, transform, centres, base_m, height_m, base_direction):
    """Geometry of a pair: the match direction and ``v_b - v_a`` as a function of ``dh``.

    The view vectors belong to the true point, at height ``DEM + dh``; the returned
    ``dv(dh)`` gives ``(v_b - v_a, (v_a + v_b) / 2)`` per cell for a trial ``dh``, ``along(dh)``
    only ``(v_b - v_a) . u`` (``u`` the unit match direction, ``geom['u']``). With B
    and H instead of the centres, the nadir point of the middle of the base is taken at the
    centre of the grid (the pair's overlap, cropped by :func:`match_pair`: two vertical
    frames of one size overlap symmetrically about the middle of their base), so the
    measurements can be moved to their ground point in both modes.
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

        def diff(dh):
            Z = Zs + np.where(np.isfinite(dh), dh, 0.0)
            va = view_vectors(ca, X, Y, Z)
            vb = view_vectors(cb, X, Y, Z)
            return va, vb, (vb[0] - va[0], vb[1] - va[1])

        def dv(dh):
            va, vb, d = diff(dh)
            return d, (0.5 * (va[0] + vb[0]), 0.5 * (va[1] + vb[1]))
    else:
        if base_m is None or height_m is None:
            raise ValueError("give either the two camera centres or both base_m (B) and height_m (H).")
        parallax_to_dh_vertical(1.0, base_m, height_m)          # validates B and H
        B, H = float(base_m), float(height_m)
        e = np.asarray(base_direction, dtype=float).reshape(2)
        if not np.hypot(*e) > 0:
            raise ValueError("base_direction must be a non-zero (X, Y) vector.")
        e = e / np.hypot(*e)

        xm, ym = float(X.mean()), float(Y.mean())

        def dv(dh):
            # camera b = a + B e at height H above the DEM: v_b - v_a = -(B / (H - dh)) e;
            # the mean view vector points from the nadir of the middle of the base (xm, ym)
            hh = H - np.where(np.isfinite(dh), dh, 0.0) + np.zeros(dem.shape)
            hh = np.where(hh > 0, hh, np.nan)
            return (-B / hh * e[0], -B / hh * e[1]), ((X - xm) / hh, (Y - ym) / hh)

        def diff(dh):
            return None, None, dv(dh)[0]
    (dvx, dvy), _ = dv(np.zeros(dem.shape))
    mx, my = float(np.nanmean(dvx)), float(np.nanmean(dvy))
    nrm = math.hypot(mx, my)
    if not nrm > 1e-9:
        raise ValueError("the two cameras give no parallax over this grid (base B = 0 or "
                         "cameras on one vertical line); use another pair.")
    ux, uy = mx / nrm, my / nrm

    def along(dh):
        # (v_b - v_a) . u alone: the conversion's fixed point needs no mean vector
        _, _, (dx_, dy_) = diff(dh)
        return dx_ * ux + dy_ * uy
    return dict(dv=dv, along=along, u=(ux, uy))


def _match_geometry(a, b, dem, transform, geom, *, window, shiftable, min_corr, max_dh_m,
                    lsm_iterations, relocate):
    """Match one pair of orthophotos and convert to ``dh`` (the pair's cropped grid)."""
    ux, uy = geom["u"]
    x0, dx, y0, dy = check_transform(transform)
    # direction in cells (col, row); rows run south
    wc, wr = ux / dx, -uy / dy
    nrm = math.hypot(wc, wr)
    wc, wr = wc / nrm, wr / nrm
    step_m = math.hypot(wc * dx, wr * dy)                 # metres per cell of shift
    along0 = geom["along"](np.zeros(dem.shape))            # (v_b - v_a) . u at the DEM
    max_shift = int(math.ceil(max_dh_m * float(np.nanmax(np.abs(along0))) * 1.1 / step_m)) + 1
    m = match_along(a, b, (wc, wr), max_shift, window=window, shiftable=shiftable,
                    min_corr=min_corr, lsm_iterations=lsm_iterations)
    p = m.disparity.astype(np.float64) * step_m            # parallax along u, ground units
    with np.errstate(divide="ignore", invalid="ignore"):
        dh = p / along0
        for _ in range(4):   # the view vectors belong to the true point at DEM + dh
            dh = p / geom["along"](dh)
    dh = np.where(np.abs(dh) <= max_dh_m, dh, np.nan).astype(np.float32)
    corr = m.corr
    if relocate:
        # the match of ground point P lies at m = P + dh (v_a + v_b) / 2 and measures the
        # surface height DEM(m) + dh: move that height to P, then subtract DEM(P)
        _, mid = geom["dv"](dh)
        z, corr = _relocate((dem + dh).astype(np.float32), corr, dh * mid[0], dh * mid[1], transform)
        dh = (z - dem).astype(np.float32)
    prec = float(np.nanmedian(step_m / np.abs(along0)))   # metres of dh per cell of parallax
    pv = p[np.isfinite(p)]
    # direction_xy: from camera a to camera b (v_b - v_a points against the base)
    return dh, corr, np.abs(p).astype(np.float32), dict(
        max_shift=max_shift, dh_per_cell_m=prec, step_m=step_m, direction_xy=(-ux, -uy),
        rms_parallax_m=float(np.sqrt(np.mean(pv ** 2))) if pv.size else float("nan"),
        b_over_h=float(np.nanmedian(np.abs(along0))), noise_grey=m.info["noise_grey"],
        reasons=m.info["shares"])


def match_pair(a, b, dem, transform, both, *, centres=None, base_m=None, height_m=None,
               base_direction=(1.0, 0.0), window=7, shiftable=5, min_corr=0.6, max_dh_m,
               lsm_iterations=3, relocate=True, precision_cells=0.2):
    """Height corrections of one pair of orthophotos, cropped to their overlap.

    Matches ``a`` and ``b`` along the pair's base (:func:`~.match.match_along`, which
    decides per cell whether a match is trusted), converts the parallax to ``dh``
    (:func:`parallax_to_dh`, iterated so the view vectors belong to the point at
    ``DEM + dh``), moves each value to its ground point (``relocate``) and drops the values
    the neighbours do not confirm (:func:`~.quality.remove_blunders`, tolerance 3 x the
    expected precision, ``precision_cells`` of parallax in height).

    Returns
    -------
    dh, corr, parallax : ndarray float32 (the full grid)
        Trusted corrections (NaN elsewhere), peak NCC and ``|parallax|`` (ground units)
        at those cells.
    info : dict
        ``max_shift``, ``dh_per_cell_m``, ``step_m`` (ground metres per cell of parallax),
        ``direction_xy`` (camera a to b), ``rms_parallax_m``,
        ``b_over_h``, ``noise_grey``, ``reasons`` (share of cells per matcher decision),
        ``blunders``, ``crop``.
    """
    x0, dx, y0, dy = check_transform(transform)
    rows = np.nonzero(both.any(axis=1))[0]
    cols = np.nonzero(both.any(axis=0))[0]
    margin = window + 2
    r0, r1 = max(0, rows[0] - margin), min(dem.shape[0], rows[-1] + margin + 1)
    c0, c1 = max(0, cols[0] - margin), min(dem.shape[1], cols[-1] + margin + 1)
    sl = (slice(r0, r1), slice(c0, c1))
    sub_t = (x0 + c0 * dx, dx, 0.0, y0 - r0 * dy, 0.0, -dy)
    geom = pair_geometry(dem[sl], sub_t, centres, base_m, height_m, base_direction)
    dh_s, corr_s, p_s, info = _match_geometry(
        np.where(both, a, np.nan)[sl], np.where(both, b, np.nan)[sl], dem[sl], sub_t, geom,
        window=window, shiftable=shiftable, min_corr=min_corr, max_dh_m=max_dh_m,
        lsm_iterations=lsm_iterations, relocate=relocate)
    dh_s = np.where(both[sl], dh_s, np.nan)
    tol = 3.0 * max(precision_cells * info["dh_per_cell_m"], 1e-6)
    dh_s, dropped = remove_blunders(dh_s, dem[sl], tol)
    out = [np.full(dem.shape, np.nan, np.float32) for _ in range(3)]
    ok = np.isfinite(dh_s)
    for arr, v in zip(out, (dh_s, corr_s, p_s)):
        arr[sl] = np.where(ok, v, np.nan)
    info.update(crop=(int(r0), int(r1), int(c0), int(c1)), blunders=dropped,
                matched=int(np.count_nonzero(ok)))
    return out[0], out[1], out[2], info


def object_cells(object_size_m, transform):
    """The largest object width in cells (0 when not given)."""
    _, dx, _, dy = check_transform(transform)
    if object_size_m is None or object_size_m <= 0:
        return 0
    return int(math.ceil(float(object_size_m) / min(dx, dy)))


def reasons_text(reasons):
    """Plain words for the matcher's decision shares, most frequent rejection first."""
    rej = sorted(((v, k) for k, v in reasons.items() if k != REASONS[0] and v > 0), reverse=True)
    return ", ".join(f"{k} {100 * v:.0f} %" for v, k in rej[:3]) or "none"

def orthoparallax(ortho_a, ortho_b, dem, transform, *, centres=None, base_m=None, height_m=None,
                  base_direction=(1.0, 0.0), window=7, shiftable=5, min_corr=0.6,
                  max_dh_m=None, height_threshold_m=None, precision_cells=0.2,
                  lsm_iterations=3, relocate=True, object_size_m=40.0, settle=True, fine=True,
                  sweep=True, progress=None):
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
        Largest |dh| searched; default 0.2 * H (the camera height above the DEM): objects up to a fifth of it.
    height_threshold_m : float, optional
        Object threshold on ``dh - trend``; default ``3 * max(expected precision, robust sd
        of dh - trend on the ground)``, the expected precision being ``precision_cells`` of
        parallax converted to height.
    precision_cells : float
        Expected matching precision in cells, for the default threshold.
    lsm_iterations : int
        Least-squares sub-pixel iterations.
    relocate : bool
        Move measurements from the matched location to the ground point (needs centres).
    fine : bool
        Match a finer window (half the window plus one cell, made odd) where the window's own
        matching fails, and keep its matches where the orthophotos agree at their height
        (:func:`_fine_matches`): objects narrower than the window.
    sweep : bool
        Test the unmatched cells not hidden by measured objects at constant heights and keep the
        height at which the orthophotos alone agree, uniquely and within their noise
        (:func:`_sweep_unmatched`): roofs narrower than the window on which every window fails
        the left-right check.
    settle : bool
        Decide the cells along the object outlines on the orthophotos
        (:func:`~.quality.settle_boundary`: the object's or the ground's height, whichever
        makes the two agree better in small shiftable windows), then close the mask over
        half the window plus one cell (gaps the matcher cannot resolve).
    object_size_m : float
        Largest object width: the object mask compares ``dh`` with its ground trend (a
        median of the ground cells over about this width, :func:`~.quality.ground_trend`),
        so smooth DEM errors are not objects; 0 compares with 0.
    progress : callable, optional
        ``progress(fraction)``; may raise Cancelled.

    Returns
    -------
    ParallaxResult
    """
    a, b = as_grey(ortho_a), as_grey(ortho_b)
    min_corr = check_min_corr(min_corr)
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
    pair_geometry(dem, transform, centres, base_m, height_m, base_direction)  # validates
    if max_dh_m is None:
        if centres is not None:
            hgt = min(float(np.asarray(c, float)[2]) for c in centres) - float(np.nanmedian(dem))
        else:
            hgt = float(height_m)
        max_dh_m = 0.2 * hgt
    if not max_dh_m > 0:
        raise ValueError(f"max_dh_m must be > 0; got {max_dh_m}.")
    dh, corr, _, info = match_pair(a, b, dem, transform, both, centres=centres, base_m=base_m,
                                   height_m=height_m, base_direction=base_direction, window=window,
                                   shiftable=shiftable, min_corr=min_corr, max_dh_m=float(max_dh_m),
                                   lsm_iterations=lsm_iterations, relocate=relocate,
                                   precision_cells=precision_cells)
    cam = dict(centres=centres, base_m=base_m, height_m=height_m, base_direction=base_direction)
    info["fine_matches"] = 0
    if fine:
        dh, corr, info["fine_matches"] = _fine_matches(
            a, b, dh, corr, dem, transform, both, info, cam, window=window, min_corr=min_corr,
            max_dh_m=float(max_dh_m), lsm_iterations=lsm_iterations, relocate=relocate,
            precision_cells=precision_cells)
    info["swept"] = 0
    if sweep:
        dh, info["swept"] = _sweep_unmatched(a, b, dh, dem, transform, both, info, cam, window=window,
                                             max_dh_m=float(max_dh_m), precision_cells=precision_cells)
    report(progress, 0.8)
    sigma_exp = precision_cells * info["dh_per_cell_m"]
    matched = np.isfinite(dh)
    # corrections reach the unmatched cells near matched ones (a few cells); farther cells,
    # where nothing was measured, keep the input DEM
    filled = fill_holes(dh, matched, max_sigma=4.0)
    filled = np.where(both, filled, np.nan)
    corrected = np.where(both & np.isfinite(filled), dem + filled, dem).astype(np.float32)
    size = object_cells(object_size_m, transform)
    mask, thr, sig, trend = object_mask(filled, both & np.isfinite(filled), sigma_exp, height_threshold_m, size,
                                        return_trend=True)
    before = mask == OBJECT
    unconfirmed = np.zeros(mask.shape, bool)
    if settle:
        mask, unconfirmed = _settle_mask(mask, a, b, dh, filled, dem, transform, info["crop"], window, cam, trend,
                                         2.0 * info["noise_grey"] ** 2)
        # unmatched cells the images do not confirm at the filled height are ground: the DEM keeps its trend there
        corrected = np.where(unconfirmed, dem + trend, corrected).astype(np.float32)
    after = mask == OBJECT
    # the outline test and the closing, counted for the log
    info.update(outline_to_object=int(np.count_nonzero(after & ~before)),
                outline_to_ground=int(np.count_nonzero(before & ~after)),
                unconfirmed_to_ground=int(np.count_nonzero(unconfirmed)))
    info.update(window=window, shiftable=shiftable, min_corr=min_corr, max_dh_m=float(max_dh_m),
                height_threshold_m=float(thr), sigma_expected_m=float(sigma_exp),
                sigma_data_m=sig, overlap_cells=int(both.sum()),
                matched_share=float(matched.sum() / both.sum()),
                rms_dh_m=float(np.sqrt(np.mean(dh[matched] ** 2))) if matched.any() else float("nan"))
    info["warning"] = plain_warning(info["matched_share"], info["reasons"], sig, sigma_exp)
    report(progress, 1.0)
    quality = np.where(both, corr, np.nan).astype(np.float32)
    return ParallaxResult(corrected, dh, quality, mask, info)


def _crop_displacement(dem, transform, crop, cam):
    """The pair's crop (slices) and ``displacement(h)`` on it: where a point of each cell with
    height error ``h`` appears in ``a`` and ``b`` (cells, ``(dca, dra, dcb, drb)``)."""
    r0, r1, c0, c1 = crop
    sl = (slice(r0, r1), slice(c0, c1))
    x0, dx, y0, dy = check_transform(transform)
    sub_t = (x0 + c0 * dx, dx, 0.0, y0 - r0 * dy, 0.0, -dy)
    geom = pair_geometry(dem[sl], sub_t, cam["centres"], cam["base_m"], cam["height_m"], cam["base_direction"])

    def displacement(h):
        # a DEM error h moves a point by h * v in an orthophoto: v_a, v_b from v_b - v_a and their mean
        (dvx, dvy), (mx, my) = geom["dv"](h)
        return (h * (mx - 0.5 * dvx) / dx, -h * (my - 0.5 * dvy) / dy,
                h * (mx + 0.5 * dvx) / dx, -h * (my + 0.5 * dvy) / dy)
    return sl, displacement


def _shadowed(dh, displacement, min_dh):
    """The objects (``dh > min_dh``) and the cells they hide in either orthophoto: a column of
    height ``h`` at ``Q`` appears along the segment from ``Q`` to ``Q + h v`` in an orthophoto made
    on the DEM, and hides the ground there."""
    obj = np.isfinite(dh) & (dh > min_dh)
    out = np.zeros(dh.shape, bool)
    if not obj.any():
        return out
    rr, cc = np.nonzero(obj)
    h = np.where(obj, dh, 0.0)
    disp = displacement(h)
    for dc, dr in ((disp[0], disp[1]), (disp[2], disp[3])):
        dc, dr = np.asarray(dc)[rr, cc], np.asarray(dr)[rr, cc]
        n = int(np.ceil(np.nanmax(np.hypot(dc, dr)))) + 1
        for t in np.linspace(0.0, 1.0, n + 1)[1:]:
            r = np.rint(rr + t * dr).astype(np.int64)
            c = np.rint(cc + t * dc).astype(np.int64)
            ok = (r >= 0) & (r < dh.shape[0]) & (c >= 0) & (c < dh.shape[1])
            out[r[ok], c[ok]] = True
    return out | obj


def _sweep_unmatched(a, b, dh, dem, transform, both, info, cam, *, window, max_dh_m, precision_cells, half=2,
                     tail=1.35e-3):
    """Heights at the unmatched cells by a plane sweep, kept where the images confirm them alone.

    Where every window through a cell fails the matcher's left-right check (a roof narrower than
    the window beside its walls' occlusions, seen by neither window size), nothing is measured and
    the whole roof can be missed. Each unmatched cell farther than half the window plus one cell
    from a measured object (nearer, the outline test decides), where the corrections filled over a
    few cells show no object and no object hides it in either orthophoto (:func:`_shadowed`), is
    tested at constant heights (a plane sweep; Collins 1996) over the range
    of the pair's trusted corrections (0.1 to 99.9 %, with 0), in steps of half a cell of parallax:
    the orthophotos are sampled where each height puts the cell and its neighbours, and the best
    window of side ``2 half + 1`` containing the cell gives the offset-free mean square of
    ``a - b`` (as :func:`~.quality.agree_at_height`). The best height is kept where (1) that mean
    square is within the chi-square bound of the pair's noise (:func:`~.quality.agreement_bound`),
    (2) the cell's own pixels agree within the same tail (chi-square, one degree of freedom): the
    cell itself is a surface point at that height, not only its window, and (3) no height a cell of
    parallax or more away passes (1) and (2): the height is unique, so weak texture, where many
    heights agree, gives nothing; and (4) the height exceeds 3 x the expected precision (the sweep
    looks for objects; ground keeps the fill).

    Returns
    -------
    dh : ndarray float32
    swept : int
        Cells whose correction comes from the sweep.
    """
    noise_var = 2.0 * info["noise_grey"] ** 2
    hole = both & ~np.isfinite(dh)
    fin = dh[np.isfinite(dh)]
    if not hole.any() or not np.isfinite(noise_var) or not noise_var > 0 or not fin.size:
        return dh, 0
    sl, displacement = _crop_displacement(dem, transform, info["crop"], cam)
    min_dh = 3.0 * precision_cells * info["dh_per_cell_m"]           # the blunder tolerance of the pair
    # near a measured object (within half the window plus one cell, as close_mask) the outline test
    # decides; the sweep looks for the objects the matcher missed, on ground no object hides
    measured = np.isfinite(dh[sl]) & (dh[sl] > min_dh)
    reach = int(window) // 2 + 1
    near = ndimage.maximum_filter(measured.view(np.uint8), 2 * reach + 1, mode="constant", cval=0).view(bool)
    # the objects and their occlusions, their unmatched parts included (the corrections filled over
    # a few cells, as for the object mask): the sweep looks where the fill shows ground, and a cell
    # hidden in one orthophoto has no height to find
    filled = fill_holes(dh[sl], np.isfinite(dh[sl]), max_sigma=4.0)
    sub = hole[sl] & ~near & ~_shadowed(filled, displacement, min_dh)
    if not sub.any():
        return dh, 0
    w = 2 * half + 1
    m = 2 * w                                   # the windows through a cell reach 2 * half cells
    rows, cols = np.nonzero(sub.any(axis=1))[0], np.nonzero(sub.any(axis=0))[0]
    r0, r1 = max(0, rows[0] - m), min(sub.shape[0], rows[-1] + m + 1)
    c0, c1 = max(0, cols[0] - m), min(sub.shape[1], cols[-1] + m + 1)
    box = (slice(r0, r1), slice(c0, c1))
    A = np.asarray(a[sl], np.float32)
    B = np.asarray(b[sl], np.float32)
    rr, cc = np.indices((r1 - r0, c1 - c0), dtype=np.float32)
    rr += r0
    cc += c0
    step = 0.5 * info["dh_per_cell_m"]
    lo, hi = np.percentile(fin, [0.1, 99.9])
    heights = np.arange(max(min(0.0, float(lo)), -max_dh_m), min(max(0.0, float(hi)), max_dh_m) + step / 2, step)
    own_bound = noise_var * 2.0 * float(special.gammainccinv(0.5, tail))     # chi2.isf(tail, 1) x var
    bound = agreement_bound(noise_var, half, tail)
    best = np.full(rr.shape, np.inf, np.float32)
    kbest = np.zeros(rr.shape, np.int64)
    kmin = np.full(rr.shape, heights.size, np.int64)       # the lowest and highest passing heights
    kmax = np.full(rr.shape, -1, np.int64)
    for k, h in enumerate(heights):
        dca, dra, dcb, drb = (np.asarray(x)[box] for x in displacement(np.full(sub.shape, h)))
        va = ndimage.map_coordinates(A, [rr + dra, cc + dca], order=1, mode="constant", cval=np.nan)
        vb = ndimage.map_coordinates(B, [rr + drb, cc + dcb], order=1, mode="constant", cval=np.nan)
        d = va - vb
        ok = np.isfinite(d)
        d0 = np.where(ok, d, np.float32(0))
        var = window_variance(d, w)
        bw = np.where(ok & (d0 * d0 <= own_bound), ndimage.minimum_filter(var, w, mode="constant", cval=np.inf),
                      np.inf)
        better = bw < best
        best[better] = bw[better]
        kbest[better] = k
        passing = bw <= bound
        kmin = np.where(passing & (kmin > k), k, kmin)
        kmax = np.where(passing, k, kmax)
    # unique: every passing height within a cell of parallax (two steps) of the best
    hk = heights[kbest]
    keep = (sub[box] & (best <= bound) & (kmax - kbest <= 1) & (kbest - kmin <= 1) & (hk > min_dh))
    out = dh.copy()
    out[sl][box][keep] = hk[keep]
    return out, int(np.count_nonzero(keep))


def _fine_matches(a, b, dh, corr, dem, transform, both, info, cam, *, window, min_corr, max_dh_m,
                  lsm_iterations, relocate, precision_cells):
    """Matches of a finer window where the coarse one has none or a worse one, kept where the images agree.

    A window wider than an object straddles its outline everywhere and measures the surface
    that fills most of it (or nothing: the left-right check fails): a building narrower than
    the window is missed whole. The finer window is the smallest odd one that holds a square
    of half the coarse window plus one cell (the narrowest detail the coarse window resolves,
    as :func:`~.quality.close_mask`): 5 x 5 for 7 x 7, without shiftable windows (the best
    window containing the cell would reach over the outline again). Its match is taken at a
    cell where the coarse window has none (a rejected match: left-right disagreement, low or
    flat correlation), or has one farther than the blunder tolerance (3 x the expected
    precision) from it at which the images agree worse (a window mostly on the ground beside
    a narrow roof measures the ground there). A fine window holds fewer cells, so its correlation alone does
    not tell a small object from a blunder: the match is kept only where the orthophotos,
    sampled where its height puts the cell, agree within their noise over the best fine
    window containing the cell (:func:`_agree_constant`, the chi-square bound of
    :func:`~.quality.agree_at_height` with the noise the matcher estimated from the pair).

    Returns
    -------
    dh, corr : ndarray float32
    added : int
        Cells whose correction comes from the finer window.
    """
    fw = (int(window) // 2 + 1) | 1
    hole = both & ~np.isfinite(dh)
    if fw >= window or not hole.any() or not np.isfinite(info["noise_grey"]):
        return dh, corr, 0
    dh_f, corr_f, _, _ = match_pair(a, b, dem, transform, both, centres=cam["centres"], base_m=cam["base_m"],
                                    height_m=cam["height_m"], base_direction=cam["base_direction"], window=fw,
                                    shiftable=0, min_corr=min_corr, max_dh_m=max_dh_m,
                                    lsm_iterations=lsm_iterations, relocate=relocate,
                                    precision_cells=precision_cells)
    tol = 3.0 * precision_cells * info["dh_per_cell_m"]       # the blunder tolerance of the pair
    with np.errstate(invalid="ignore"):
        differ = both & np.isfinite(dh) & np.isfinite(dh_f) & (np.abs(dh_f - dh) > tol)
    cand = (hole & np.isfinite(dh_f)) | differ
    if not cand.any():
        return dh, corr, 0
    sl, displacement = _crop_displacement(dem, transform, info["crop"], cam)
    noise_var = 2.0 * info["noise_grey"] ** 2
    rr, cc = np.nonzero(cand[sl])
    hf = dh_f[sl][rr, cc]
    agree, best_f = _agree_constant(a[sl], b[sl], rr, cc, hf, displacement, noise_var, fw // 2)
    was = np.isfinite(dh[sl][rr, cc])
    if was.any():
        # where both windows measured, the coarse height stays unless the images agree better at the fine one
        _, best_c = _agree_constant(a[sl], b[sl], rr[was], cc[was], dh[sl][rr[was], cc[was]], displacement,
                                    noise_var, fw // 2)
        agree[was] &= best_f[was] < best_c
    use = np.zeros(dh.shape, bool)
    use[sl][rr[agree], cc[agree]] = True
    return (np.where(use, dh_f, dh).astype(np.float32), np.where(use, corr_f, corr).astype(np.float32),
            int(np.count_nonzero(use)))


def _agree_constant(a, b, rr, cc, h, displacement, noise_var, half, tail=1.35e-3):
    """The orthophotos at cells ``(rr, cc)``, each at its own constant height ``h`` over its windows.

    As :func:`~.quality.agree_at_height`, but every window through a cell is sampled where
    the cell's own height puts it (a plane hypothesis, as a match is): the best of the
    windows of side ``2 half + 1`` containing the cell, offset-free mean square of ``a - b``
    against the chi-square bound of the pair's noise. Returns (agree, best mean square).
    """
    bound = agreement_bound(noise_var, half, tail)
    full = np.zeros(a.shape)
    full[rr, cc] = h
    dca, dra, dcb, drb = (np.asarray(x)[rr, cc] for x in displacement(full))
    o = np.arange(-2 * half, 2 * half + 1, dtype=np.float64)
    orr, occ = np.broadcast_arrays(rr[:, None, None] + o[None, :, None], cc[:, None, None] + o[None, None, :])
    va = ndimage.map_coordinates(np.asarray(a, np.float32), [orr + dra[:, None, None], occ + dca[:, None, None]],
                                 order=1, mode="constant", cval=np.nan)
    vb = ndimage.map_coordinates(np.asarray(b, np.float32), [orr + drb[:, None, None], occ + dcb[:, None, None]],
                                 order=1, mode="constant", cval=np.nan)
    d = (va - vb).astype(np.float64)
    w = 2 * half + 1
    # the mean square about the mean of every window of side w inside the 2w - 1 square (NaN: unseen)
    s1 = ndimage.uniform_filter(d, (1, w, w), mode="constant")[:, half:-half or None, half:-half or None]
    s2 = ndimage.uniform_filter(d * d, (1, w, w), mode="constant")[:, half:-half or None, half:-half or None]
    var = (s2 - s1 * s1).reshape(len(rr), -1)
    best = np.min(np.where(np.isfinite(var), var, np.inf), axis=1)
    return best <= bound, best


def _settle_mask(mask, a, b, dh, filled, dem, transform, crop, window, cam, trend, noise_var):
    """The object mask with its unmatched cells confirmed and its outline decided on the orthophotos.

    First, an unmatched cell the fill made an object, farther than half the window plus one
    cell from any object measurement (nearer, it lies in that measurement's window), stays
    one unless the orthophotos, seen there, disagree beyond their noise at its filled height
    (:func:`~.quality.agree_at_height`): ground hidden from one camera beside a wall is never
    matched, the fill carries the roof's height into it, and the orthophotos show the roof
    there in one image and the ground in the other. Then the outline (:func:`~.quality.settle_boundary`), then the
    closing over half the window plus one cell (:func:`~.quality.close_mask`).

    Returns
    -------
    mask : ndarray uint8
    unconfirmed : ndarray of bool
        The unmatched cells turned to ground by the first step.
    """
    sl, displacement = _crop_displacement(dem, transform, crop, cam)
    valid = (mask != NODATA)[sl]
    is_obj = (mask == OBJECT)[sl]
    unconfirmed = np.zeros(mask.shape, bool)
    sub_dh = dh[sl]
    o_meas = np.where(is_obj & np.isfinite(sub_dh), sub_dh, np.nan).astype(np.float32)
    # cells within half the window plus one cell of an object measurement (as close_mask)
    reach = window // 2 + 1
    # (an opening by a square of that side, then a dilation by twice it plus one: separable
    # minimum and maximum filters, the same sets as the binary morphology)
    u8 = np.isfinite(o_meas).view(np.uint8)
    held = ndimage.maximum_filter(ndimage.minimum_filter(u8, reach, mode="constant", cval=0), reach,
                                  origin=-1 if reach % 2 == 0 else 0, mode="constant", cval=0)
    near = ndimage.maximum_filter(held, 2 * reach + 1, mode="constant", cval=0).view(bool)
    cand = is_obj & ~np.isfinite(sub_dh) & ~near
    if cand.any() and np.isfinite(noise_var) and noise_var > 0:
        agree, tested = agree_at_height(a[sl], b[sl], filled[sl], displacement, noise_var, where=cand)
        gone = cand & tested & ~agree
        is_obj &= ~gone
        unconfirmed[sl] = gone
    new = settle_boundary(a[sl], b[sl], is_obj, sub_dh, trend[sl], valid, displacement, window // 2)
    out = mask.copy()
    sub = out[sl]
    sub[new] = OBJECT
    sub[valid & ~new & (sub == OBJECT)] = GROUND
    return close_mask(out, window), unconfirmed & (out != OBJECT)


#: Below this share of trusted matches among the cells seen by two frames, the pairs
#: cannot support a refinement (the log says so): the matches are then more than about
#: three cells apart, beyond what the fill of a few cells bridges.
MIN_MATCHED_SHARE = 0.1


def plain_warning(matched_share, reasons, sigma_data, sigma_expected):
    """A plain-words warning when the data cannot support the correction, else ''."""
    out = []
    if matched_share < MIN_MATCHED_SHARE:
        out.append(f"only {100 * matched_share:.0f} % of the cells seen in two orthophotos could be "
                   f"matched with confidence (rejected: {reasons_text(reasons)}); the images have too "
                   "little texture against their noise, or differ too much, to measure heights here. "
                   "The DEM is kept where nothing was measured")
    if np.isfinite(sigma_data) and sigma_data > 3 * sigma_expected:
        out.append(f"the corrections scatter by {sigma_data:.2f} m on the ground, more than 3 x the "
                   f"expected precision ({sigma_expected:.2f} m): many matches may be wrong")
    return "; ".join(out)
