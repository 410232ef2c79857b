"""Iterative orthophoto refinement of a DEM (Norvelle 1995; Luong Chinh Ke 2002, section 2.3).

:func:`orthorefine` orthorectifies every frame on the current DEM, measures the residual
parallax of every overlapping pair (:func:`~.refine.match_pair`), merges the pairs'
corrections, and updates the DEM while the pairs' agreement improves; every update is
checked by the next measurement and undone if it made the pairs agree worse.
"""
import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage, special

from ..common import report, sub_progress
from .match import check_min_corr
from .orthorectify import check_transform, grid_xy, orthorectify
from .quality import (
    close_mask,
    merge_pairs,
    nan_median_filter,
    object_mask,
    split_significant,
    spread_corrections,
)
from .refine import MIN_MATCHED_SHARE, as_grey, match_pair, object_cells, parallax_to_dh_vertical, plain_warning
from .smoothness import project_smooth, roughness, roughness_cells, roughness_sd

__all__ = ["orthorefine", "RefineResult", "overlapping_pairs", "pair_families", "cross_check_families",
           "RELAXATION", "MIN_GAIN", "CROSS_CHECK", "FAMILY_TAIL", "NOT_ROUGHER"]

#: Default share of each measured correction applied to the DEM (the whole correction).
RELAXATION = 1.0
#: Default smallest relative improvement of the pairs' agreement that continues the iteration.
MIN_GAIN = 0.05
#: An update after which the pairs lose more than this share of their trusted matches made
#: them agree worse (the parallax of the remaining, easier cells alone would hide it).
MAX_LOST = 0.5
#: Default of ``cross_check``: keep a correction only where pair families of different base
#: directions agree (see :func:`cross_check_families`).
CROSS_CHECK = False
#: Default of ``not_rougher``: an update's unconfirmed smooth part may not make the DEM rougher
#: (:func:`_smooth_update`, a smoothness prior). A start smoother than the terrain (a blurred DSM)
#: then gains only the relief two pairs confirm as detail (README).
NOT_ROUGHER = True
#: One-sided tail of the families' agreement test: the 3 sigma tail of
#: :func:`~.quality.agreement_bound`, so k = 3.
FAMILY_TAIL = 1.35e-3


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
        One row per measurement (orthorectify and match on the DEM of that moment):
        ``iteration``, ``rms_correction_m`` (RMS of the merged correction over matched
        cells), ``matched_share`` (trusted matches / cells seen by two frames), ``pairs``,
        ``rms_parallax_m`` (RMS residual parallax of the pairs' trusted matches, ground
        units), ``agreement`` (RMS parallax on the cells matched now and at the previous
        measurement, over its value then: below 1 the last update made the pairs agree
        better), ``status`` (``applied``: this correction went into the DEM; ``undone``: the
        next measurement showed it made the pairs agree worse, so it was taken back;
        ``measured``: not applied, see ``info['stop']``), ``mean_corr``,
        ``detail_single_pair`` (cells of significant detail not applied because only one
        pair measured them), ``smoothness_mu`` (the multiplier of the smoothness step,
        :func:`_smooth_update`: 0 when the update's unconfirmed smooth part did not make the DEM
        rougher and was applied as measured, ``inf`` when it was shrunk as a whole),
        ``roughness_m`` (the Laplacian sd after the update over the cells seen by two frames
        at the start, eroded by two: :func:`~.smoothness.roughness_sd`) and, with
        ``reference``, ``rmse_reference_m`` of the DEM after that row.
    info : dict
        Parameters used, ``stop`` (why the iteration ended, in words) and ``warning``
        (plain words when the data could not support the refinement, else '').
    parallax_start, parallax : ndarray float32 or None
        Per cell, the RMS residual parallax of the pairs' trusted matches (ground units, NaN
        where no pair matched) measured on the starting DEM and on the returned one: where
        the pairs agree better after the refinement (oriented frames; None in tie-point mode).
    detail : ndarray of bool or None
        Cells where a kept update applied confirmed significant detail (a resolved object or
        step two pairs agree on; oriented frames).
    supported : ndarray float32 or None
        Per cell, the move the data support: for each kept update, the certainty-weighted
        Gaussian mean of the trusted corrections' magnitudes (what the smooth part can carry
        there) plus the largest kept detail within the fill's reach, summed over the kept
        updates and never above ``max_dh_m``; no cell moves farther (a clip that the update,
        bounded so by construction, does not reach; oriented frames).
    """
    dem: np.ndarray
    orthos: list
    dh: np.ndarray
    quality: np.ndarray
    mask: np.ndarray
    table: list
    info: dict = field(default_factory=dict)
    parallax_start: np.ndarray = None
    parallax: np.ndarray = None
    detail: np.ndarray = None
    supported: np.ndarray = None


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


def pair_families(centres, pairs, max_angle_deg=45.0):
    """Group pairs by the direction of their base: the families of independent pairs.

    A pair's base is the horizontal vector between its two camera centres. The first pair
    opens a family; each next pair joins the first family whose opening base lies within
    ``max_angle_deg`` of its own (directions, so a base and its opposite are one), else opens
    a new one. Pairs of one family see a blunder (repetitive texture along the base, a
    shadow) at the same height; pairs of another base direction see it elsewhere.

    Parameters
    ----------
    centres : sequence of 3-vectors
        Camera centres, one per frame.
    pairs : sequence of (int, int)
    max_angle_deg : float

    Returns
    -------
    list of int
        The family of each pair (0, 1, ...).
    """
    cos_max = math.cos(math.radians(float(max_angle_deg)))
    heads, fam = [], []
    for i, j in pairs:
        b = np.asarray(centres[j], float)[:2] - np.asarray(centres[i], float)[:2]
        n = float(np.hypot(*b))
        u = b / n if n > 0 else np.array([1.0, 0.0])
        for f, h in enumerate(heads):
            if abs(float(u @ h)) >= cos_max:
                fam.append(f)
                break
        else:
            heads.append(u)
            fam.append(len(heads) - 1)
    return fam


def cross_check_families(dh, family_dhs, family_sigmas, tail=FAMILY_TAIL):
    """Keep a merged correction only where pair families of different base directions agree.

    At a cell measured by two or more families, the families' corrections agree when every
    two of them differ by at most ``k * sqrt(s_f**2 + s_g**2)`` (``s`` each family's matching
    precision in height, ``k`` the normal quantile of the one-sided ``tail``: 3 for the
    default, the tail of :func:`~.quality.agreement_bound`). There the merged correction
    ``dh`` is confirmed and kept. Where they disagree, only the part they share is kept: the
    smallest of their corrections in magnitude when all have one sign, else 0 (the input
    height). A cell measured by one family alone cannot be cross-checked: NaN (not
    measured; the refinement keeps the input height there beyond the fill's reach).

    Parameters
    ----------
    dh : ndarray
        The merged correction of all pairs (:func:`~.quality.merge_pairs`).
    family_dhs : sequence of ndarray
        Per family, the merge of its own pairs (NaN where none matched).
    family_sigmas : sequence of float
        Per family, the matching precision in height (m).
    tail : float

    Returns
    -------
    out : ndarray float32
        The accepted correction.
    confirmed : ndarray of bool
        Cells where the families agree.
    checked : ndarray of bool
        Cells measured by two or more families.
    """
    if not 0.0 < tail < 1.0:
        raise ValueError(f"tail must lie in (0, 1); got {tail!r}.")
    k = float(-special.ndtri(float(tail)))
    D = np.stack([np.asarray(d, np.float64) for d in family_dhs])
    fin = np.isfinite(D)
    checked = fin.sum(axis=0) >= 2
    agree = checked.copy()
    with np.errstate(invalid="ignore"):
        for f in range(len(D)):
            for g in range(f + 1, len(D)):
                both = fin[f] & fin[g]
                tol = k * math.hypot(float(family_sigmas[f]), float(family_sigmas[g]))
                agree &= ~(both & (np.abs(D[f] - D[g]) > tol))
        lo = np.nanmin(np.where(fin, D, np.inf), axis=0)
        hi = np.nanmax(np.where(fin, D, -np.inf), axis=0)
    shared = np.where(lo > 0, lo, np.where(hi < 0, hi, 0.0))
    dh = np.asarray(dh, np.float64)
    out = np.where(agree, dh, np.where(checked & np.isfinite(dh), shared, np.nan))
    return out.astype(np.float32), agree & np.isfinite(dh), checked


def orthorefine(dem, transform, images, cameras, *, max_iterations=6, tolerance_m=None,
                window=7, shiftable=5, min_corr=0.6, max_dh_m=None, pairs=None,
                min_overlap=0.05, smooth_cells=5, height_threshold_m=None,
                precision_cells=0.2, antialias=True, object_size_m=40.0, fill_sigma_cells=3.0,
                relaxation=RELAXATION, min_gain=MIN_GAIN, outlier_m=None, reference=None,
                reference_cells=None, tie_points=None, base_m=None,
                height_m=None, base_direction=(1.0, 0.0), cross_check=CROSS_CHECK,
                not_rougher=NOT_ROUGHER, progress=None):
    """Iterative orthophoto refinement of a DEM (Norvelle 1995; Luong Chinh Ke 2002, 2.3).

    Each iteration orthorectifies every frame onto the current DEM (collinearity equations,
    bilinear resampling, hidden and unseen cells masked), matches the orthophotos of every
    overlapping pair along its base (:func:`orthoparallax`'s matcher), converts the parallax
    to height corrections with the general geometry, keeps the trusted ones (the matcher's
    per-cell decision and the neighbour test of :func:`~.refine.match_pair`), merges the
    pairs' corrections weighted by correlation, keeps their smooth part (a field, applied as
    such) and their detail where it stands out of the noise (:func:`~.quality.split_significant`)
    and two pairs agree on it (one pair cannot tell a detail from its own blunder), tapered
    to 0 over half the window plus one cell around it (no step the measurements lack), fills
    gaps of a few cells and adds ``relaxation`` x the correction to the DEM. The smooth part
    the confirmed detail's measurements do not make may not make the DEM rougher (the
    Laplacian's variance over the cells seen by two frames): where it would, it is replaced by
    the nearest field, weighted by its certainty, that does not (:func:`_smooth_update`, a
    Tikhonov-regularised projection; ``info['roughness_start_m']``, ``info['roughness_m']``).
    No cell moves by more than the trusted corrections around it support
    (``RefineResult.supported``).

    The iteration rule: each update is checked by the next measurement, which compares
    the pairs' agreement (RMS residual parallax on the cells matched both times) with the
    previous one. An update that made the pairs agree worse (or lost more than
    :data:`MAX_LOST` of the trusted matches) is undone and the iteration stops; when the agreement improved by
    less than ``min_gain`` (relative) the iteration stops keeping the update. Once the pairs'
    RMS residual parallax is below the expected matching precision (``precision_cells`` of
    a cell), what remains is matching noise: the correction measured then is applied and
    checked by one more measurement, the last. It also stops
    when the RMS correction falls below ``tolerance_m``, and after ``max_iterations``
    updates (the last one checked by one more measurement). When fewer than
    :data:`~.refine.MIN_MATCHED_SHARE` of the cells seen by two frames hold a trusted match
    at the first measurement, the DEM is returned unchanged and ``info['warning']`` says
    why. Cells farther than the fill reach from any trusted match keep their height.

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
    precision_cells : float
        Expected matching precision in cells (default 0.2): the blunder tolerance (3 x) and
        the default object threshold, in height.
    window, shiftable, min_corr : matcher settings (see :func:`~.match.match_along`).
    max_dh_m : float, optional
        Largest correction searched (default 0.2 * camera height above the DEM); after an
        update the search range is the 99th percentile of the correction just applied (at
        least 6 x the expected precision). No cell moves by more than ``max_dh_m`` in total:
        nothing larger was measured.
    pairs : list of (int, int), optional
        Pairs to match; default every pair that overlaps by ``min_overlap``.
    smooth_cells : int
        NaN-aware median filter size applied to each iteration's correction (0: none).
    height_threshold_m : float, optional
        Object threshold on the total correction (default from the data, as orthoparallax).
    antialias : bool
        Low-pass the images to the ground cell size before resampling.
    object_size_m : float
        Largest object width: the object mask compares ``dh`` with its ground trend (a
        median of the ground cells over about this width), so smooth DEM errors are not
        objects; 0 compares with 0.
    fill_sigma_cells : float
        Reach (Gaussian sigma, cells) of the interpolation of each iteration's correction
        into unmatched cells, fading to 0 (:func:`~.quality.spread_corrections`); farther
        cells keep their height.
    relaxation : float
        Share of each iteration's correction applied, in (0, 1]; default :data:`RELAXATION`
        = 1 (the whole measured correction: one iteration gives full heights). Below 1
        damps each step; the iteration rule guards against noise either way.
    min_gain : float
        Smallest relative improvement of the pairs' agreement that continues the iteration
        (default :data:`MIN_GAIN`).
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
    cross_check : bool
        Keep a correction only where independent pairs agree (default :data:`CROSS_CHECK`).
        The pairs are grouped by base direction (:func:`pair_families`); with two or more
        families each iteration's merged correction is kept where the families' corrections
        agree within their combined precision, reduced to the part they share where they
        disagree, and dropped where one family alone measured
        (:func:`cross_check_families`). With one base direction (two frames, or all bases
        parallel) nothing can be cross-checked: the refinement runs as without it and
        ``info['cross_check']`` says so. ``info`` gives ``confirmed_share`` (cells with a
        confirmed correction at the first measurement over those matched) and
        ``confirmed_max_m`` (the largest total move of a cell where the families' correction,
        or the part they share, was accepted in some iteration: the bound the independent
        pairs support; ``moved_max_m`` is larger where the smooth part and the fill carry
        it past those cells). Oriented frames only.
    not_rougher : bool
        Default :data:`NOT_ROUGHER` (on): the smooth part of an update that the confirmed detail's
        measurements do not make may not raise the DEM's roughness (:func:`_smooth_update`, a
        smoothness prior); False applies it as measured (a start smoother than the terrain,
        e.g. a blurred DSM, then gains the relief the pairs measure).
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
    if not 0 < float(relaxation) <= 1:
        raise ValueError(f"relaxation must be in (0, 1] (the share of each correction applied); "
                         f"got {relaxation}.")
    if int(max_iterations) < 1:
        raise ValueError(f"max_iterations must be >= 1; got {max_iterations}.")
    min_corr = check_min_corr(min_corr)
    if cameras is None or all(c is None for c in cameras):
        res = _refine_registered(dem0, transform, images, tie_points, base_m, height_m,
                                  base_direction, window=window, shiftable=shiftable,
                                  min_corr=min_corr, max_dh_m=max_dh_m, pairs=pairs,
                                  min_overlap=min_overlap, smooth_cells=smooth_cells,
                                  height_threshold_m=height_threshold_m,
                                  precision_cells=precision_cells, object_size_m=object_size_m,
                                  fill_sigma_cells=fill_sigma_cells, outlier_m=outlier_m,
                                  reference=reference, not_rougher=not_rougher, progress=progress)
        # every registered frame lies along one base_direction: no independent pair
        res.info["cross_check"] = ("not possible: all pairs have one base direction (tie_points mode)"
                                   if cross_check else "off")
        return res
    greys = [as_grey(im) for im in images]
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
        max_dh_m = 0.2 * hgt
    if antialias:
        greys = [_antialias(g, c, dem0, transform) for g, c in zip(greys, cameras)]
    setup = dict(greys=greys, cameras=cameras, transform=transform, valid=valid_dem, pairs=pairs,
                 min_overlap=min_overlap, match=dict(window=window, shiftable=shiftable,
                                                     min_corr=min_corr, max_dh_m=float(max_dh_m),
                                                     precision_cells=precision_cells))
    total = int(max_iterations) + 1
    cur, prev_dem, prev = dem0.copy(), None, None
    table, info, stop, last = [], {}, "", ""
    families, ever_confirmed = None, np.zeros(dem0.shape, bool)
    bound, detail_cells = np.zeros(dem0.shape), np.zeros(dem0.shape, bool)
    prev_bound, prev_detail = bound, detail_cells
    for it in range(total):
        meas = _measure(cur, setup, sub_progress(progress, it / total, (it + 1) / total))
        setup["pairs"] = meas["pairs"]
        if it == 0:
            parallax_start = meas["parallax"]
            # the roughness is measured where the start is seen by two frames (README: Laplacian sd)
            rough_cells = roughness_cells(meas["multi"])
            if reference_cells is None:
                reference_cells = meas["multi"]
            info["sigma_expected_m"] = precision_cells * meas["dh_per_cell_m"]
            if tolerance_m is None:
                tolerance_m = 0.5 * info["sigma_expected_m"]
            outlier = outlier_m if outlier_m is not None else 3.0 * max(info["sigma_expected_m"], 0.1)
        dh_it, meas["quality"] = merge_pairs(meas["dhs"], meas["cors"], outlier)
        merged = dh_it
        matched = np.isfinite(dh_it) & meas["multi"]
        rms = float(np.sqrt(np.mean(dh_it[matched] ** 2))) if matched.any() else float("nan")
        meas["share"] = share = float(matched.sum() / max(1, meas["multi"].sum()))
        row = dict(iteration=it + 1, rms_correction_m=rms, matched_share=share, pairs=len(meas["pinfo"]),
                   rms_parallax_m=meas["rms_parallax_m"], agreement=float("nan"), status="measured",
                   detail_single_pair=0, smoothness_mu=0.0, roughness_m=float("nan"),
                   mean_corr=float(np.nanmean(meas["quality"][matched])) if matched.any() else float("nan"))
        table.append(row)
        if prev is not None:
            common = np.isfinite(prev["parallax"]) & np.isfinite(meas["parallax"])
            before = float(np.sqrt(np.mean(prev["parallax"][common] ** 2))) if common.any() else float("nan")
            after = float(np.sqrt(np.mean(meas["parallax"][common] ** 2))) if common.any() else float("nan")
            row["agreement"] = after / before if before > 0 else float("nan")
            if not (after <= before) or share < (1.0 - MAX_LOST) * prev["share"]:
                cur, meas = prev_dem, prev           # the update made the pairs agree worse: undo it
                bound, detail_cells = prev_bound, prev_detail
                table[-2]["status"] = "undone"
                _reference(table[-2], reference, reference_cells, cur, meas["multi"], valid_dem)
                stop = (f"the last update made the pairs agree worse (RMS parallax {before:.3g} -> "
                        f"{after:.3g} m on the cells matched both times, trusted matches "
                        f"{100 * prev['share']:.0f} -> {100 * share:.0f} %); it was undone")
                break
            if after > (1.0 - min_gain) * before:
                stop = (f"the pairs' agreement improved by less than {100 * min_gain:.0f} % "
                        f"(RMS parallax {before:.3g} -> {after:.3g} m)")
                break
            if last:
                stop = last
                break
            # the pairs' residual parallax is within the matching noise: the correction just
            # measured is applied and checked by one more measurement, the last
            noise = precision_cells * float(np.median([p["step_m"] for p in meas["pinfo"]]))
            if meas["rms_parallax_m"] < noise:
                last = (f"the pairs' RMS residual parallax {meas['rms_parallax_m']:.3g} m fell below the "
                        f"expected matching precision {noise:.3g} m ({precision_cells:g} cell); the "
                        "update measured then was the last, checked")
        if it == total - 1:
            stop = f"{int(max_iterations)} update(s) done, the last one checked"
            break
        if it == 0 and share < MIN_MATCHED_SHARE:
            info["warning"] = _refusal(share, meas["pinfo"], float("nan"), info["sigma_expected_m"])
            stop = "refused: the pairs cannot support a refinement (see the warning)"
            break
        if not np.isfinite(rms) or rms < tolerance_m:
            stop = f"RMS correction {rms:.3g} m below the tolerance {tolerance_m:.3g} m"
            break
        if cross_check:
            families = pair_families([c.centre for c in cameras], [p["pair"] for p in meas["pinfo"]])
            info.setdefault("pair_families", families)
            if max(families) >= 1:
                dh_it, conf, checked, fam_s = _cross_check(dh_it, meas, families, outlier, precision_cells)
                info.setdefault("family_sigma_m", fam_s)
                ever_confirmed |= checked & np.isfinite(dh_it)
                merged = np.where(np.isfinite(dh_it), merged, np.nan)
                if it == 0:
                    info["confirmed_share"] = float(conf.sum() / max(1, matched.sum()))
                    info["checked_share"] = float((checked & matched).sum() / max(1, matched.sum()))
                matched = np.isfinite(dh_it) & meas["multi"]
        if smooth_cells and smooth_cells > 1:
            dh_it = np.where(matched, nan_median_filter(dh_it, int(smooth_cells) | 1)[0], np.nan)
        trusted = dh_it
        smooth, detail, n_single, keep, certainty, smooth_conf = _confirmed_detail(
            dh_it, merged, meas["dhs"], outlier, info["sigma_expected_m"], window)
        row["detail_single_pair"] = n_single
        # the smooth part is a field, applied as such (fading out with its certainty); the
        # detail reaches unmatched cells within the fill distance, fading out; farther cells
        # keep their height (nothing was measured there)
        dh_it = np.where(matched, smooth + detail, np.nan)
        spread = spread_corrections(detail, matched, fill_sigma_cells)
        prev_dem, prev = cur, meas
        prev_bound, prev_detail = bound, detail_cells
        # the data-supported bound of a cell's move: what the trusted corrections around it
        # support (_supported_move), summed over the kept updates; never more than MAX_DH_M
        bound = bound + float(relaxation) * _supported_move(trusted, detail, window, fill_sigma_cells)
        detail_cells = detail_cells | keep
        lim = np.minimum(bound, max_dh_m)
        # the smooth part may not make the DEM rougher than the update's confirmed detail does
        def finish(z, lo=dem0 - lim, hi=dem0 + lim):
            return np.where(valid_dem, np.clip(z, lo, hi), np.nan).astype(np.float32)
        rel = float(relaxation)
        first = finish(cur + rel * (smooth + spread))
        if not_rougher:
            cur, row["smoothness_mu"], row["roughness_m"] = _smooth_update(
                cur, first, rel * (smooth - smooth_conf), rel * (spread + smooth_conf), certainty, rough_cells, finish)
        else:
            cur, row["roughness_m"] = first, roughness_sd(first, rough_cells)
        # what is left after an update is at most what was just measured: the next search
        # range is the 99th percentile of |correction| (at least 6 x the expected precision)
        big = float(np.percentile(np.abs(dh_it[matched]), 99)) if matched.any() else max_dh_m
        setup["match"]["max_dh_m"] = float(min(max_dh_m, max(big, 6 * info["sigma_expected_m"])))
        row["status"] = "applied"
        _reference(row, reference, reference_cells, cur, meas["multi"], valid_dem)
    if "rmse_reference_m" not in table[-1]:
        _reference(table[-1], reference, reference_cells, cur, meas["multi"], valid_dem)
    multi = meas["multi"] & valid_dem
    dh_total = np.where(multi, cur - dem0, np.nan).astype(np.float32)
    mask, thr, sig = object_mask(dh_total, multi, info["sigma_expected_m"], height_threshold_m,
                                 object_cells(object_size_m, transform))
    closed = close_mask(mask, window)
    info["mask_closed_cells"] = int(np.count_nonzero(closed != mask))   # gaps narrower than half the window
    mask = closed
    info.setdefault("warning", _refusal(1.0, meas["pinfo"], sig, info["sigma_expected_m"]))
    info.update(pairs=[tuple(p) for p in setup["pairs"]],
                iterations=sum(r["status"] == "applied" for r in table), measurements=len(table),
                stop=stop, relaxation=float(relaxation), tolerance_m=float(tolerance_m), not_rougher=bool(not_rougher),
                max_dh_m=float(max_dh_m), height_threshold_m=float(thr), sigma_data_m=sig,
                # how far the cells moved, against the bound max_dh_m (README, iteration rule)
                moved_max_m=float(np.nanmax(np.abs(cur - dem0))) if np.isfinite(cur - dem0).any() else 0.0,
                # the data-supported bound of a cell's move (largest over the cells) and the
                # cells of confirmed detail it applied
                supported_max_m=float(min(bound[valid_dem].max(), max_dh_m)),
                detail_cells=int(np.count_nonzero(detail_cells)),
                window=window, shiftable=shiftable, min_corr=min_corr,
                cells_seen_by_two=int(multi.sum()), noise_grey=meas["noise_grey"],
                rms_parallax_m=meas["rms_parallax_m"], rms_parallax_start_m=table[0]["rms_parallax_m"],
                # the roughness the smoothness step keeps from rising (Laplacian sd, cells seen by two)
                roughness_start_m=roughness_sd(dem0, rough_cells), roughness_m=roughness_sd(cur, rough_cells))
    moved = np.abs(cur - dem0)
    if not cross_check:
        info["cross_check"] = "off"
    elif families is None or max(families) < 1:
        info["cross_check"] = ("not possible: all pairs have one base direction, so no independent pair "
                               "could confirm a correction; refined as without the cross-check")
    else:
        info["confirmed_max_m"] = float(moved[ever_confirmed].max()) if ever_confirmed.any() else 0.0
        info["cross_check"] = (f"{max(families) + 1} pair families by base direction; "
                               f"precision {', '.join(f'{v:.2g}' for v in info['family_sigma_m'])} m; "
                               f"{100 * info.get('confirmed_share', 0.0):.1f} % of the matched cells hold a "
                               f"correction the families confirm ({100 * info.get('checked_share', 0.0):.1f} % "
                               f"measured by two or more, the part they share kept where they disagree, "
                               f"nothing where one family alone measured); largest move of a cross-checked "
                               f"cell {info['confirmed_max_m']:.2f} m, of any cell {info['moved_max_m']:.2f} m")
    report(progress, 1.0)
    return RefineResult(cur, meas["orthos"], dh_total,
                        np.where(multi, meas["quality"], np.nan).astype(np.float32), mask, table, info,
                        parallax_start=parallax_start, parallax=meas["parallax"], detail=detail_cells,
                        supported=np.where(valid_dem, np.minimum(bound, max_dh_m), np.nan).astype(np.float32))


def _confirmed_detail(dh, merged, dhs, outlier_m, sigma_m, window):
    """The smooth part of the corrections (everywhere) and their confirmed significant detail.

    The smooth part is the normalised Gaussian mean over about the window of
    :func:`~.quality.split_significant`, a field defined between the measurements too and
    weighted by its certainty (Knutsson & Westin 1993): the whole mean where the Gaussian
    holds at least a square of the side the matcher resolves (half the window plus one
    cell) of measurements, in proportion to their weight below that, so it fades out where
    the measurements thin out without a step or a kink; 0 far from any. Applied as such it
    adds no structure finer than its own scale (filling it in again from the matched cells
    alone would: the fill is another filter, and where matches are sparse the two part by a
    step). The detail (correction minus its smooth part) is kept where
    :func:`~.quality.split_significant` finds it standing out of the expected noise over a
    square the matcher resolves. One pair
    alone cannot tell such a detail from its own blunder (repetitive texture, a shadow);
    pairs with other bases see a blunder at another height. So a region of significant
    detail is kept when at least half of its cells hold two or more pairs whose corrections
    agree with the merged one within ``outlier_m`` (the tolerance of
    :func:`~.quality.merge_pairs`). With a single pair nothing can be confirmed and the
    detail is kept as measured.

    Returns
    -------
    smooth : ndarray float64
        The smooth part at every cell.
    detail : ndarray float32
        The kept detail at the cells of ``dh``, tapered to 0 within half the window plus one
        cell around each kept region (:func:`_taper_detail`; 0 elsewhere on them, NaN where
        ``dh`` is NaN).
    single : int
        Cells of detail dropped because only one pair measured them.
    keep : ndarray of bool
        The cells of kept (confirmed) significant detail.
    certainty : ndarray float64
        The smooth part's certainty (:func:`_certainty`, >= 1).
    smooth_conf : ndarray float64
        The share of the smooth part made by the measurements on ``keep`` (confirmed too).
    """
    dh = np.asarray(dh, np.float32)
    num, den, sig = split_significant(dh, sigma_m, window)
    side = max(1, int(window) // 2 + 1)
    smooth = _certainty_mean(num, den, window)
    certainty = _certainty(den, window)
    keep, n_single = sig, 0
    if len(dhs) >= 2 and sig.any():
        support = np.zeros(dh.shape, np.int16)
        with np.errstate(invalid="ignore"):
            for d in dhs:
                support += np.abs(d - merged) <= outlier_m
        labels, n = ndimage.label(sig, structure=np.ones((3, 3), bool))
        confirmed = ndimage.mean(support >= 2, labels, np.arange(1, n + 1)) >= 0.5
        keep = sig & np.concatenate(([False], confirmed))[labels]
        n_single = int(np.count_nonzero(sig & ~keep))
    # the share of the smooth part the confirmed detail's own measurements make (confirmed too)
    smooth_conf = (_certainty_mean(ndimage.gaussian_filter(np.where(keep, np.nan_to_num(dh), 0.0).astype(np.float64),
                                                           max(0.5, float(window)), mode="nearest"), den, window)
                   if keep.any() else np.zeros(dh.shape))
    return smooth, _taper_detail(dh - smooth, keep, sig & ~keep, side), n_single, keep, certainty, smooth_conf


def _full_weight(window):
    """The Gaussian weight (sigma the window) of a square of half the window plus one cell of
    measurements: the smooth part is in full above it."""
    s = max(0.5, float(window))
    side = max(1, int(window) // 2 + 1)
    return side * side / (2.0 * np.pi * s * s)


def _certainty_mean(num, den, window):
    """The certainty-weighted Gaussian mean ``num / den``: in full where the Gaussian (sigma the
    window) holds the weight of a square of half the window plus one cell, in proportion below."""
    return num / np.maximum(den, _full_weight(window))


def _certainty(den, window):
    """The certainty of the smooth part, in units of the full weight: ``max(den, full) / full``.

    Below the full weight the smooth part is the measurements' mean (certainty ``den / full``)
    shrunk towards no change (the prior, certainty ``1 - den / full``): 1 together; above it,
    the measurements alone, ``den / full`` (Knutsson & Westin 1993: the output certainty of a
    normalised convolution is its denominator).
    """
    full = _full_weight(window)
    return np.maximum(den, full) / full


def _smooth_update(cur, first, smooth, confirmed, certainty, cells, finish):
    """The updated DEM whose unconfirmed smooth part does not raise the roughness.

    ``first`` is the update as measured (``finish(cur + smooth + confirmed)``); ``confirmed``
    the confirmed detail spread into the unmatched cells plus the share of the smooth part
    its own measurements make, ``smooth`` the rest of the smooth part (measured by pairs that
    do not confirm it as detail). The budget is the roughness
    (:func:`~.smoothness.roughness`, the Laplacian's variance over ``cells``) of the DEM
    before the update or with the confirmed part alone, the larger: what two pairs confirm
    may add the curvature the DEM lacked, the unconfirmed smooth part may not. Where
    ``first`` meets it, it is returned as it is; else the unconfirmed smooth part is replaced
    by the field nearest to it, weighted by its certainty, that meets it
    (:func:`~.smoothness.project_smooth`; only cells the smooth part reaches move).

    Returns the DEM, the multiplier ``mu`` (0: unchanged) and its Laplacian sd over ``cells``.
    """
    base = cur.astype(np.float64) + confirmed
    budget = max(roughness(cur, cells), roughness(finish(base), cells))
    if roughness(first, cells) <= budget:
        return first, 0.0, roughness_sd(first, cells)
    free = np.isfinite(cur) & (smooth != 0)
    dem, pinfo = project_smooth(base, smooth, certainty, free, cells, budget, finish)
    return dem, float(pinfo["mu"]), roughness_sd(dem, cells)


def _supported_move(trusted, detail, window, fill_sigma_cells):
    """Per cell, the largest update the trusted corrections support (the bound of one update).

    The update is the smooth part plus the detail spread into unmatched cells. The smooth
    part is a certainty-weighted Gaussian mean of the trusted corrections, so by the triangle
    inequality it is at most the same mean of their magnitudes; the spread detail is a
    normalised Gaussian mean of the kept detail (sigma ``fill_sigma_cells``, truncated at 4
    sigma), so at most the largest kept detail within that reach.
    """
    ok = np.isfinite(trusted)
    num = ndimage.gaussian_filter(np.where(ok, np.abs(trusted), 0.0).astype(np.float64), max(0.5, float(window)),
                                  mode="nearest")
    den = ndimage.gaussian_filter(ok.astype(np.float64), max(0.5, float(window)), mode="nearest")
    reach = int(math.ceil(4.0 * float(fill_sigma_cells)))
    near = ndimage.maximum_filter(np.abs(np.nan_to_num(detail)).astype(np.float64), size=2 * reach + 1,
                                  mode="constant", cval=0.0)
    return _certainty_mean(num, den, window) + near


def _taper_detail(detail, keep, dropped, reach):
    """The kept detail, continuous: in full on ``keep``, fading linearly to 0 at ``reach`` cells from it.

    The detail is significant where it exceeds k x its noise; cut there, the applied
    correction would step by at least that much at every region's edge, where the
    measurements themselves are continuous: a window centred within half its side of the
    region sees part of it, and its detail has the region's sign. So the detail within
    ``reach`` cells of a kept region (half the window plus one: the first cell no
    overlapping window reaches) that has the sign of the nearest kept cell is applied with
    the weight ``1 - distance / reach``. Detail of the other sign there is not a share of
    the region (the surface beyond its edge, or noise) and, below the significance
    threshold, stays out like any insignificant detail; dropped detail (``dropped``: one
    pair alone) stays out. NaN where ``detail`` is NaN.
    """
    detail = np.asarray(detail, np.float64)
    if not keep.any():
        return np.where(np.isfinite(detail), 0.0, np.nan).astype(np.float32)
    dist, (ri, ci) = ndimage.distance_transform_edt(~keep, return_indices=True)
    sign = np.sign(np.nan_to_num(detail))
    w = np.where(sign == sign[ri, ci], np.clip(1.0 - dist / float(reach), 0.0, 1.0), 0.0)
    w[dropped] = 0.0
    return np.where(np.isfinite(detail), w * np.nan_to_num(detail), np.nan).astype(np.float32)


def _cross_check(dh, meas, families, outlier, precision_cells):
    """:func:`cross_check_families` on one measurement: each family merged from its own pairs."""
    fam_dhs, fam_s = [], []
    for f in range(max(families) + 1):
        idx = [k for k, g in enumerate(families) if g == f]
        if not idx:
            continue
        d, _ = merge_pairs([meas["dhs"][k] for k in idx], [meas["cors"][k] for k in idx], outlier)
        fam_dhs.append(d)
        fam_s.append(precision_cells * float(np.median([meas["pinfo"][k]["dh_per_cell_m"] for k in idx])))
    return (*cross_check_families(dh, fam_dhs, fam_s), fam_s)


def _measure(cur, setup, prog):
    """Orthorectify every frame on ``cur`` and match every overlapping pair (one measurement)."""
    valid = setup["valid"]
    filled_dem = np.where(valid, cur, np.nan)
    res = [orthorectify(g, c, filled_dem, setup["transform"]) for g, c in zip(setup["greys"], setup["cameras"])]
    orthos = [r[0] for r in res]
    seen = [r[1] for r in res]
    pair_list = setup["pairs"]
    if pair_list is None:
        pair_list = overlapping_pairs(seen, setup["min_overlap"])
        if not pair_list:
            raise ValueError("no two images overlap on the DEM grid (each pair shares less than "
                             f"{setup['min_overlap']:.0%} of its cells); check the orientations, the CRS "
                             "and that the DEM covers the images.")
    report(prog, 0.2)
    window = setup["match"]["window"]
    cams = setup["cameras"]
    dhs, cors, pinfo = [], [], []
    p2, pn = np.zeros(cur.shape), np.zeros(cur.shape, np.int16)
    for k, (i, j) in enumerate(pair_list):
        both = seen[i] & seen[j]
        if both.sum() < window * window * 4:
            continue
        dh, corr, par, pi = match_pair(orthos[i], orthos[j], filled_dem, setup["transform"], both,
                                       centres=(cams[i].centre, cams[j].centre), **setup["match"])
        ok = np.isfinite(dh) & both
        dhs.append(np.where(ok, dh, np.nan).astype(np.float32))
        cors.append(np.where(ok, corr, np.nan).astype(np.float32))
        p2 += np.where(ok, par.astype(np.float64) ** 2, 0.0)
        pn += ok
        pi.update(pair=(i, j), matched_share=float(ok.sum() / both.sum()))
        pinfo.append(pi)
        report(prog, 0.2 + 0.8 * (k + 1) / len(pair_list))
    if not pinfo:
        raise ValueError("no pair of orthophotos overlaps enough to match; check that the images overlap.")
    with np.errstate(invalid="ignore", divide="ignore"):
        parallax = np.where(pn > 0, np.sqrt(p2 / np.maximum(pn, 1)), np.nan).astype(np.float32)
    pv = parallax[np.isfinite(parallax)].astype(np.float64)
    return dict(orthos=orthos, multi=(np.sum(seen, axis=0) >= 2) & valid, pairs=pair_list, dhs=dhs,
                cors=cors, pinfo=pinfo, parallax=parallax,
                rms_parallax_m=float(np.sqrt(np.mean(pv ** 2))) if pv.size else float("nan"),
                dh_per_cell_m=float(np.median([p["dh_per_cell_m"] for p in pinfo])),
                noise_grey=float(np.nanmedian([p["noise_grey"] for p in pinfo])))


def _reference(row, reference, reference_cells, cur, multi, valid):
    """``rmse_reference_m`` of ``cur`` into ``row`` (evaluation only)."""
    if reference is not None:
        ev = (multi if reference_cells is None else reference_cells) & np.isfinite(reference) & valid
        row["rmse_reference_m"] = (float(np.sqrt(np.mean((cur - reference)[ev] ** 2))) if ev.any()
                                   else float("nan"))


def _refusal(share, pinfo, sigma_data, sigma_expected):
    """The warning of the whole refinement, the pairs' decision shares pooled ('' if none)."""
    keys = pinfo[0]["reasons"].keys() if pinfo else ()
    pooled = {k: float(np.mean([p["reasons"][k] for p in pinfo])) for k in keys}
    return plain_warning(share, pooled, sigma_data, sigma_expected)


def _refine_registered(dem0, transform, images, tie_points, base_m, height_m, base_direction,
                       *, window, shiftable, min_corr, max_dh_m, pairs, min_overlap,
                       smooth_cells, height_threshold_m, precision_cells, object_size_m,
                       fill_sigma_cells, outlier_m, reference, not_rougher, progress):
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
        max_dh_m = 0.2 * float(height_m)
    orthos = []
    for img, tp in zip(images, tie_points):
        tr8 = tp if isinstance(tp, Bilinear8) else fit_bilinear8(*tp)
        orthos.append(as_grey(register_orthophoto(img, tr8, dem0.shape, transform)))
    seen = [np.isfinite(o) & np.isfinite(dem0) for o in orthos]
    pair_list = pairs if pairs is not None else overlapping_pairs(seen, min_overlap)
    if not pair_list:
        raise ValueError("no two registered orthophotos overlap on the DEM grid; check the tie points.")
    dhs, cors, pinfo = [], [], []
    for k, (i, j) in enumerate(pair_list):
        both = seen[i] & seen[j]
        if both.sum() < window * window * 4:
            continue
        dh, corr, _, pi = match_pair(orthos[i], orthos[j], dem0, transform, both,
                                     base_m=(j - i) * float(base_m), height_m=float(height_m),
                                     base_direction=base_direction, window=window, shiftable=shiftable,
                                     min_corr=min_corr, max_dh_m=float(max_dh_m),
                                     precision_cells=precision_cells)
        ok = np.isfinite(dh) & both
        dhs.append(np.where(ok, dh, np.nan).astype(np.float32))
        cors.append(np.where(ok, corr, np.nan).astype(np.float32))
        pi.update(pair=(i, j), matched_share=float(ok.sum() / both.sum()))
        pinfo.append(pi)
        report(progress, 0.9 * (k + 1) / len(pair_list))
    sigma = precision_cells * float(np.median([p["dh_per_cell_m"] for p in pinfo])) if pinfo else 1.0
    outlier = outlier_m if outlier_m is not None else 3 * max(sigma, 0.1)
    dh_it, quality = merge_pairs(dhs, cors, outlier)
    merged = dh_it
    multi = (np.sum(seen, axis=0) >= 2)
    matched = np.isfinite(dh_it) & multi
    share = float(matched.sum() / max(1, multi.sum()))
    refused = share < MIN_MATCHED_SHARE
    if smooth_cells and smooth_cells > 1:
        dh_it = np.where(matched, nan_median_filter(dh_it, int(smooth_cells) | 1)[0], np.nan)
    smooth, detail, n_single, keep, certainty, smooth_conf = _confirmed_detail(dh_it, merged, dhs, outlier,
                                                                              sigma, window)
    dh_it = np.where(matched, smooth + detail, np.nan)
    mu, rough = 0.0, roughness_sd(dem0, roughness_cells(multi & np.isfinite(dem0)))
    if refused:
        cur = dem0.copy()
    elif not not_rougher:
        cur = np.where(np.isfinite(dem0), dem0 + (smooth + spread_corrections(detail, matched, fill_sigma_cells))
                       .astype(np.float32), np.nan).astype(np.float32)
        rough = roughness_sd(cur, roughness_cells(multi & np.isfinite(dem0)))
    else:
        spread = spread_corrections(detail, matched, fill_sigma_cells)
        first = np.where(np.isfinite(dem0), dem0 + (smooth + spread).astype(np.float32), np.nan).astype(np.float32)
        cur, mu, rough = _smooth_update(dem0, first, smooth - smooth_conf, spread + smooth_conf, certainty,
                                        roughness_cells(multi & np.isfinite(dem0)),
                                        lambda z: np.where(np.isfinite(dem0), z, np.nan).astype(np.float32))
    rms = float(np.sqrt(np.mean(dh_it[matched] ** 2))) if matched.any() else float("nan")
    row = dict(iteration=1, rms_correction_m=rms, matched_share=share, pairs=len(pinfo),
               rms_parallax_m=float(np.sqrt(np.nanmean([p["rms_parallax_m"] ** 2 for p in pinfo]))),
               agreement=float("nan"), status="measured" if refused else "applied", detail_single_pair=n_single,
               smoothness_mu=mu, roughness_m=rough,
               mean_corr=float(np.nanmean(quality[matched])) if matched.any() else float("nan"))
    _reference(row, reference, None, cur, multi, np.isfinite(dem0))
    dh_total = np.where(multi, cur - dem0, np.nan).astype(np.float32)
    mask, thr, sig = object_mask(dh_total, multi, sigma, height_threshold_m, object_cells(object_size_m, transform))
    closed = close_mask(mask, window)
    n_closed = int(np.count_nonzero(closed != mask))
    mask = closed
    report(progress, 1.0)
    info = dict(mode="eq. 17 registration, one pass (no orientation: orthophotos cannot be redrawn)",
                pairs=[tuple(p) for p in pair_list], iterations=0 if refused else 1, measurements=1,
                stop=("refused: the pairs cannot support a refinement (see the warning)" if refused
                      else "one pass (no orientation)"),
                warning=_refusal(share, pinfo, sig, sigma), sigma_expected_m=sigma, sigma_data_m=sig,
                height_threshold_m=float(thr), max_dh_m=float(max_dh_m), window=window,
                shiftable=shiftable, min_corr=min_corr, cells_seen_by_two=int(multi.sum()),
                mask_closed_cells=n_closed)
    return RefineResult(cur, orthos, dh_total, np.where(multi, quality, np.nan).astype(np.float32),
                        mask, [row], info)


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
