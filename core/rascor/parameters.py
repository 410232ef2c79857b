"""RASCOR parameters: derived from an analysis of the DSM (Jacobsen 2004), and the halo.

Jacobsen's program determines its parameters automatically: the terrain class (step 1),
step 2's limits from the height distribution, the profile lengths and surface sizes by
analysing a sequence of lengths and sizes, the standard deviations of the models from the
residuals. :func:`resolve_rascor_params` does this once on the whole raster (so all blocks
agree); :func:`rascor_halo` gives the reach of the whole sequence for block processing.
"""
from typing import Callable, Optional, Sequence, Union

import numpy as np
from scipy import ndimage

from ..common import as_cell_size, as_surface, label8, report, sub_progress
from ..dtm_refine import REACH_M, continuation_cells
from ..estimate import (
    GROUND_BLOCK_M,
    RAISED_REGION_SPAN_M,
    ground_level_cells,
    ground_level_reference,
    noise_ground_level,
    object_widths,
    raised_region_grid,
    sample_windows,
    terrain_bends,
)
from .fits import fit_at_centre
from .kernels import block_reach, finite_float64, gauss_weights, odd_window
from .sequence import SURFACE_RULES, cell_rise, level_step, ring_reach
from .steps import enclosed_levels, remove_level_changes, remove_neighbour_differences
from .terrain import TERRAIN_CLASSES, as_homogeneous, characterise_with_envelope, model_degree

#: Sequences analysed for the profile lengths and the surface sizes (metres).
PROFILE_LENGTHS_M = (5.0, 9.0, 15.0, 25.0, 41.0, 65.0)
SURFACE_SIZES_M = (9.0, 15.0, 25.0, 41.0, 65.0)
#: Step 2: the limits lie at least this far (m) outside the terrain's lower envelope.
_FAR_M = 20.0

DEFAULTS = dict(terrain_class="auto", homogeneous="auto", sigma_m=None, step1_characterise=True,
                step2_height_distribution=True, step3_neighbour_differences=True,
                step4_level_change=True, step5_profiles=True, step6_surfaces=True,
                step7_prediction=False, second_iteration=False, step3_repeat=True,
                spare_continuing_ground=True, height_min_m=None,
                height_max_m=None, neighbour_k=3.0, terrain_slope=None, terrain_bend_m=None, ground_sigma_m=None,
                jump_m=2.0,
                max_building_m=120.0, max_hall_m=None,
                short_profile_m=None, long_profile_m=None, profile_sigma_m=None,
                surface_size_m=None, surface_rule="objects", surface_sigma_m=None,
                prediction_radius_m=None, prediction_sigma_m=None, snooping_k=4.0, snooping_iterations=1,
                low_weight=0.02, fits_per_block=False)
#: A length is accepted while its residual scale stays below this factor of the shortest's.
_SCALE_GROWTH = 2.0


#: The analysis sample of a large raster: windows of this side, this many cells in all
#: (four windows, centred on the quadrants).
_CROP_EDGE = 256
_CROP_CELLS = 4 * _CROP_EDGE ** 2


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


def _scan(windows, sample, degree, sigma, at_least=1, progress=None):
    """:func:`_sample_scale` along the sequence of ``windows`` (cells) as long as
    :func:`_choose` can still accept the next one: the sequence ends at the first window
    whose spread is too large (the longer ones are never chosen), but covers at least
    ``at_least`` windows."""
    out = []
    for i, sizes in enumerate(windows):
        out.append(_sample_scale(sample, sizes, degree))
        report(progress, (i + 1) / len(windows))
        if i + 1 >= at_least and _choose([b for _, b in out], sigma) < i:
            break
    return out


def _longest_following(errors, sigma):
    """Index of the longest window of the sequence up to which the model follows the
    terrain within the random error: the model error ``errors[i]`` (robust scale of the
    leave-one-out residuals on the ground-level reference surface, :func:`_model_errors`)
    at most ``sigma`` for this window and every shorter one (0 when even the first fails)."""
    best = 0
    for i, (e, _) in enumerate(errors):
        if np.isfinite(e) and e <= sigma:
            best = i
        else:
            break
    return best


def _model_errors(sample, windows, degree, sigma, at_least=1, progress=None, transposed=False):
    """Model error of each window of the sequence: ``(MAD scale, 90th percentile of |v|)``
    (:func:`_robust_scale`) of the leave-one-out residuals ``v`` of the moving fit
    (``windows`` in cells: an int for profiles, ``(rows, cols)`` for surfaces) on the
    ground-level reference surfaces ``sample`` (:func:`_analysis_sample`); profiles along X
    and, with ``transposed``, Y. The sequence stops after the first window whose MAD scale
    exceeds ``sigma`` (the longer ones are never chosen), but covers at least ``at_least``
    windows."""
    out = []
    for i, sizes in enumerate(windows):
        v = []
        for c, w, kk in sample:
            v.append((c - fit_at_centre(c, w, sizes, degree)[0])[kk])
            if transposed:
                ct, wt = np.ascontiguousarray(c.T), np.ascontiguousarray(w.T)
                v.append((ct - fit_at_centre(ct, wt, sizes, degree)[0])[kk.T])
        out.append(_robust_scale(np.concatenate(v) if v else np.zeros(0)))
        report(progress, (i + 1) / len(windows))
        if i + 1 >= at_least and not (np.isfinite(out[-1][0]) and out[-1][0] <= sigma):
            break
    return out


def _error_at(errors, sequence, value, compute):
    """The model error of the window ``value`` (metres): from ``errors`` (along
    ``sequence``) when it is there, else ``compute(value)``."""
    if value in sequence and sequence.index(value) < len(errors):
        return errors[sequence.index(value)]
    return compute(value)


def _about_model(sigma, error):
    """Standard deviation of a ground height about the model: the random error and the
    model's error combined, ``sqrt(sigma^2 + e^2)``, ``e`` the 90th percentile of the
    model's residuals (:func:`_model_errors`) / 1.645, the Gaussian scale with that tail
    (``sigma`` alone when the error is not measurable)."""
    e = error[1] / 1.645 if error is not None and np.isfinite(error[1]) else 0.0
    return round(float(np.hypot(sigma, e)), 3)


def _analysis_sample(z, cell_size, sigma, p):
    """The analysis crops (the whole surface when small, else windows centred on its
    quadrants: :func:`~bare_earth.core.estimate.sample_windows`): ``(crops, sample, holes)``,
    with ``sample`` the ``[(heights, weights, cells kept)]`` of each crop cleaned by steps 3
    and 4, and ``holes`` each crop's nodata cells and the low blunders step 3 found (holes
    in an object, not its outline: :func:`_objects_width`)."""
    crops, sample, holes = [], [], []
    for crop in sample_windows(z, cells=_CROP_CELLS, side=_CROP_EDGE):
        keep = np.isfinite(crop)
        if keep.sum() < 100:
            continue
        hi, lo = remove_neighbour_differences(crop, keep, sigma_m=sigma, k=p["neighbour_k"],
                                              low_weight=p["low_weight"],
                                              cell_rise_m=cell_rise(p["terrain_slope"], cell_size),
                                              bend_m=p["terrain_bend_m"])
        keep &= ~(hi | lo)
        keep &= ~remove_level_changes(crop, cell_size, keep, jump_m=p["jump_m"],
                                      max_building_m=p["max_building_m"], sigma_m=sigma,
                                      k=p["neighbour_k"], bend_m=p["terrain_bend_m"])
        crops.append(crop)
        sample.append((finite_float64(crop), keep.astype(np.float64), keep))
        holes.append(lo | ~np.isfinite(crop))
    return crops, sample, holes


def _objects_width(crops, cell_size, holes=None):
    """Width (m) of the objects of the analysis crops (:func:`~bare_earth.core.estimate.object_widths`,
    98 % of their area): the cells standing above the ground level
    (:func:`~bare_earth.core.estimate.ground_level_cells` with blocks of the longest surface
    of the sequence: more than 2 m and the terrain's rise over a block above the
    interpolated block minima); 0 without crops. ``holes`` (each crop's nodata cells and low
    blunders, :func:`_analysis_sample`) do not cut an object: its width is measured across
    missing scan lines, dropouts and pits on a roof (``nodata`` of ``object_widths``)."""
    objects = [np.isfinite(c) & ~ground_level_cells(c, cell_size, block_m=SURFACE_SIZES_M[-1], lift_low=True)
               for c in crops]
    if not objects:
        return 0.0
    gaps = None if holes is None else _side_by_side([h & ~o for h, o in zip(holes, objects)])
    return round(object_widths(_side_by_side(objects), cell_size, nodata=gaps), 1)


def _ground_sample(crops, cell_size, block_m):
    """``[(heights, weights, cells kept)]`` of the ground-level reference surface of each
    crop (:func:`~bare_earth.core.estimate.ground_level_reference`: the minima of
    ``block_m`` blocks interpolated, which objects narrower than a block do not reach),
    without the blocks a low blunder pulled down (``lift_low``: multipath pits 24 m deep
    lowered 6 of the 54 blocks of ISPRS samp41 at 1 m and made its step-6 scale 1.76 m
    instead of 0.74 m)."""
    out = []
    for crop in crops:
        ref = ground_level_reference(crop, cell_size, block_m=block_m, lift_low=True)[0]
        ok = np.isfinite(ref)
        out.append((finite_float64(ref), ok.astype(np.float64), ok))
    return out


def _side_by_side(masks):
    """The masks in one array, side by side with an empty column between them (their
    objects stay apart)."""
    rows = max(m.shape[0] for m in masks)
    out = np.zeros((rows, sum(m.shape[1] + 1 for m in masks)), bool)
    c = 0
    for m in masks:
        out[:m.shape[0], c:c + m.shape[1]] = m
        c += m.shape[1] + 1
    return out


def _shortest_covering(sequence, need_m):
    """Index of the shortest length of ``sequence`` at least ``need_m`` (the last when none
    is)."""
    for i, L in enumerate(sequence):
        if L >= need_m:
            return i
    return len(sequence) - 1


def _sample_scale(sample, sizes, degree, kernels=None):
    """Robust scales (:func:`_robust_scale`) of the leave-one-out residuals of the moving
    fit of ``sizes`` cells and ``degree`` on the analysis sample."""
    v = [(c - fit_at_centre(c, w, sizes, degree, kernels=kernels)[0])[kk] for c, w, kk in sample]
    return _robust_scale(np.concatenate(v) if v else np.zeros(0))


def terrain_bend(z, cell_size, sigma):
    """Steps 3 and 4: the Gaussian scale (m) of the terrain's own second difference over
    one cell: the 90th percentile of ``|d|`` / 1.645 (the tail the tolerances must cover,
    as :func:`_about_model`), ``d`` the second differences of the minima of
    :data:`~bare_earth.core.estimate.GROUND_BLOCK_M` blocks scaled to one cell
    (:func:`~bare_earth.core.estimate.terrain_bends`). 0 when it does not exceed the random
    error ``sigma`` (the paper's tolerances, which hold ``sigma``, cover such bends, and
    the block minima's own noise and the residue of wide objects in them are of that
    order: at 1-2 m cells the bends read millimetres to centimetres) and with fewer than 3
    blocks."""
    dx, dy = as_cell_size(cell_size)
    d = terrain_bends(z, max(2, int(round(GROUND_BLOCK_M / max(dx, dy)))))
    b = float(np.percentile(np.abs(d), 90)) / 1.645 if d.size else 0.0
    return round(b, 3) if b > sigma else 0.0


def ground_sigma(z, cell_size, sigma):
    """Step 3's ``ground_sigma_m``: the random error of the ground's heights (m), the standard deviation
    of the DSM's ground-level cells (:func:`~bare_earth.core.estimate.noise_ground_level`), at most
    ``sigma`` (the whole DSM's, which the crowns of a vegetated slope widen: 0.35 m on shrubs whose
    lidar noise is 0.05 m) and at least 0.001 m; ``sigma`` when too few ground-level cells are seen."""
    g = float(noise_ground_level(z, as_cell_size(cell_size))["sigma"])
    return round(max(0.001, min(float(sigma), g)), 3) if np.isfinite(g) else float(sigma)


def _height_limits(z, low_env, sigma):
    """Step 2's limits ``(height_min_m, height_max_m)`` of the heights ``z``, whose lower envelope
    (step 1's tile minima) is ``low_env``: far outside the distribution, beyond Tukey's far
    fences and at least ``_FAR_M`` beyond the terrain's lower envelope (a dam or an embankment
    in a flat area is not far outside)."""
    v = z.ravel()
    if v.size > 2_000_000:                   # a regular sample of about 1 M cells
        v = v[:: v.size // 1_000_000]
    v = v[np.isfinite(v)]
    q1, q3 = np.percentile(v, [25, 75])
    iqr = max(q3 - q1, 10 * sigma)
    lv = low_env[np.isfinite(low_env)]
    gmin, gmax = (float(lv.min()), float(lv.max())) if lv.size else (q1, q3)
    return round(float(min(q1 - 3 * iqr, gmin - _FAR_M)), 2), round(float(max(q3 + 3 * iqr, gmax + _FAR_M)), 2)


def longest_hall(z, cell_size, *, jump_m, max_building_m, sigma_m, neighbour_k=3.0, terrain_bend_m=0.0,
                 terrain_slope=0.0):
    """Step 4's ``max_hall_m``: the span (m) of the longest raised level closed by walls on every side
    that runs further than ``max_building_m`` (:func:`~.steps.enclosed_levels`, levels of
    :func:`~.sequence.level_step`), at most :data:`~bare_earth.core.estimate.RAISED_REGION_SPAN_M`; 0
    when the DSM shows none.

    Looked for on the block minima of :func:`~bare_earth.core.estimate.raised_region_grid` (at most 1 M
    cells; ``k`` cells a block): a roof keeps its walls there and loses at most a block at each side,
    so the levels longer than ``max_building_m`` less two blocks are looked at and the span found
    grows by two blocks. The span decides the halo (:func:`rascor_halo`): a raster without such a
    level keeps step 4's. The levels are joined across the step step 4 joins its levels across
    (:func:`~.sequence.level_step` with the rise of ``terrain_slope`` over one cell of the grid looked
    at, :func:`~.sequence.cell_rise`): the same levels as step 4's own, so the span found is that of a
    level step 4 can take (measured without the rise, a sloping level broke into parts step 4 joins).

    Examples
    --------
    >>> z = np.zeros((200, 300), np.float32)
    >>> z[20:170, 30:230] = 10.0                           # a hall of 200 x 150 m
    >>> longest_hall(z, 1.0, jump_m=2.0, max_building_m=120.0, sigma_m=0.05)
    200.0
    >>> z[90, 230:] = 10.0                                 # ... that the ground continues (a bridge)
    >>> longest_hall(z, 1.0, jump_m=2.0, max_building_m=120.0, sigma_m=0.05)
    0.0
    """
    zs, (dx, dy), k = raised_region_grid(as_surface(z), as_cell_size(cell_size))
    margin = 2.0 * max(dx, dy) if k > 1 else 0.0
    levels = enclosed_levels(zs, (dx, dy), jump_m=jump_m,
                             step_m=level_step(neighbour_k, sigma_m, terrain_bend_m, jump_m,
                                               rise_m=max(cell_rise(terrain_slope, (dx, dy)))),
                             min_span_m=max_building_m - margin, max_span_m=RAISED_REGION_SPAN_M,
                             k=neighbour_k, bend_m=terrain_bend_m)
    lab, n = label8(levels)
    if not n:
        return 0.0
    span = max(max((b[0].stop - b[0].start) * dy, (b[1].stop - b[1].start) * dx)
               for b in ndimage.find_objects(lab))
    return float(min(np.ceil(span + margin), RAISED_REGION_SPAN_M))


def widen_rascor_params(params, given, overview, cell_size):
    """Step 2's derived limits widened to the heights of a whole raster larger than the window
    the parameters came from (``Method.widen``).

    The limits are heights, not a statistic a window estimates: taken from the raster's central
    window alone, the terrain beyond it that rises (or falls) further than the window's terrain
    plus ``_FAR_M`` (a valley side, a hill at the survey's end, a corridor climbing 1000 m along
    its 100 km) was removed whole by step 2. ``overview``: the whole raster read every
    ``step``-th cell (``cell_size`` its cells); the limits become the widest of the window's and
    the overview's (:func:`_height_limits` on it, with its own lower envelope). Limits the user
    gave (``given``) are kept."""
    p = dict(params)
    if p.get("terrain_class") != "flat" or not np.isfinite(overview).any():
        return p
    todo = [k for k in ("height_min_m", "height_max_m") if given.get(k) is None and p.get(k) is not None]
    if not todo:
        return p
    z = as_surface(overview)
    if min(z.shape) < 3:
        return p
    _ch, low_env = characterise_with_envelope(z, as_cell_size(cell_size), with_sigma=False)
    lo, hi = _height_limits(z, low_env, float(p["sigma_m"]))
    if "height_min_m" in todo:
        p["height_min_m"] = min(p["height_min_m"], lo)
    if "height_max_m" in todo:
        p["height_max_m"] = max(p["height_max_m"], hi)
    return p


def check_rascor_given(values):
    """ValueError for given values no data makes valid: ``height_min_m`` not below a given
    ``height_max_m`` (step 2 would remove every height)."""
    lo_given, hi_given = values.get("height_min_m"), values.get("height_max_m")
    if lo_given is not None and hi_given is not None and not float(lo_given) < float(hi_given):
        raise ValueError(f"height_min_m ({lo_given}) must be below height_max_m ({hi_given}): step 2 would "
                         "remove every height; swap them or leave them empty (derived).")


def resolve_rascor_params(z: np.ndarray, cell_size: Union[float, Sequence[float]], *,
                          progress: Optional[Callable[[float], None]] = None, **params) -> dict:
    """Complete RASCOR's parameters from an analysis of the DSM (Jacobsen 2004).

    ``None`` (and ``"auto"``) values are derived from the whole raster, once, so that all
    blocks use the same values:

    * terrain class, homogeneity and random error ``sigma_m`` by step 1
      (:func:`characterise_terrain`);
    * ``terrain_slope``: the median slope of step 1's lower envelope; step 3 widens its
      tolerance by the rise of that slope over one cell (the position of a height inside
      its cell, :func:`remove_neighbour_differences`), so that its test means the same
      at every cell size;
    * step 2's limits (flat terrain only) from the height distribution: Tukey's far fences,
      and at least 20 m outside the range of the terrain's lower envelope;
    * the profile lengths by analysing the sequence :data:`PROFILE_LENGTHS_M` on a sample
      (the whole raster up to 512 x 512 cells, else 4 crops of 256 x 256 cells at the
      quadrants) cleaned by steps 3 and 4: per length, the leave-one-out profile
      residuals of the class model; the long profile is the longest length before the
      90th percentile of ``|v|`` exceeds twice the shortest's (the model stops following
      the terrain, or objects as long as the profile remain; the analysis of the sequence
      stops there; long profiles cut the shoulders of cuts and embankments, which break
      lines protect), the short one the longest of the sequence at most half of it;
    * the scales ``profile_sigma_m`` and ``surface_sigma_m``: the standard deviation of a
      ground height about the model, ``sqrt(sigma^2 + e^2)`` with ``e`` the model's error
      at the chosen length or size measured where objects are not, on the ground-level
      reference surface of the crops (:func:`~bare_earth.core.estimate.ground_level_reference`:
      20 m block minima interpolated, the blocks a low blunder pulled down lifted), as the
      90th percentile of its leave-one-out residuals / 1.645 (the tail a Gaussian scale
      must cover, so that ground at the terrain's bends, the shoulders of cuts and
      embankments, passes the snooping; the robust MAD scale instead cut them: ISPRS
      samp71 4.1 -> 9.7 %). The residuals of the DSM itself, which the objects left by
      steps 3 and 4 widen, gave 0.56 m and a 15 m surface on the opengeos 2 m city (DTM
      2.87 m RMSE);
    * the surface size ``surface_size_m``: the shortest of :data:`SURFACE_SIZES_M`
      covering ``sqrt(2)`` times the width of the objects
      (:func:`~bare_earth.core.estimate.object_widths`, 98 % of their area; the cells
      standing above the ground level of 65 m blocks,
      :func:`~bare_earth.core.estimate.ground_level_cells`: what steps 3 and 4 leave of an
      object is scattered over its footprint), so that a window holds at least as much
      ground as object and its plane stays on the ground; and at most the longest size
      whose model error (robust scale) stays within ``sigma`` (the model follows the
      terrain within the random error), measured on block minima as wide as the covering
      window (objects wider than 20 m blocks lift those). That is ``surface_rule="objects"``
      (the default); ``surface_rule="residuals"`` keeps the model-selection rule alone,
      the longest size before the fits' residual spread grows (as for the profile lengths):
      what :mod:`~bare_earth.core.dtm` asks of its RASCOR member, whose opening and
      reconstruction members remove the wide objects (in that vote the covering window
      made RASCOR's errors follow the opening's: ISPRS seven 3.95 -> 4.34 %);
    * ``prediction_sigma_m`` from the residuals of the local prediction; its radius 3 cells;
    * ``max_hall_m``: the span of the longest raised level closed by walls on every side that runs
      further than ``max_building_m`` (:func:`longest_hall`; 0: none), so that step 4 takes such a
      hall (:func:`~.steps.enclosed_levels`) and the halo reaches across it only where there is one.

    ``progress(fraction)`` (optional) is called after each stage of the analysis; it may
    raise ``Cancelled``.

    Returns
    -------
    dict
        Every parameter of :func:`filter_rascor` except the rasters and ``progress``, and
        ``surface_rule``.
    """
    unknown = sorted(set(params) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"unknown RASCOR parameter(s) {unknown}; known: {sorted(DEFAULTS)}.")
    p = dict(DEFAULTS)
    p.update({k: v for k, v in params.items() if k in DEFAULTS and (v is not None or DEFAULTS[k] is None)})
    z = as_surface(z)
    dx, dy = as_cell_size(cell_size)
    cs = max(dx, dy)
    tc = None if p["terrain_class"] in (None, "auto") else p["terrain_class"]
    if tc is not None and tc not in TERRAIN_CLASSES:
        raise ValueError(f"terrain_class must be one of {TERRAIN_CLASSES} or 'auto' (derived "
                         f"by step 1); got {tc!r}.")
    if p["surface_rule"] not in SURFACE_RULES:
        raise ValueError(f"surface_rule must be one of {SURFACE_RULES}; got {p['surface_rule']!r}.")
    check_rascor_given(p)
    ch, low_env = characterise_with_envelope(z, (dx, dy), progress=sub_progress(progress, 0.0, 0.5),
                                             with_sigma=p["sigma_m"] is None)
    if tc is None:
        tc = ch["terrain_class"] if p["step1_characterise"] else "rolling"
    p["terrain_class"] = tc
    if p["homogeneous"] in (None, "auto"):
        p["homogeneous"] = bool(ch["homogeneous"]) if p["step1_characterise"] else True
    else:
        p["homogeneous"] = as_homogeneous(p["homogeneous"])
    if p["sigma_m"] is None:
        p["sigma_m"] = round(ch["sigma_m"], 3)
    sigma = float(p["sigma_m"])
    if tc == "flat" and (p["height_min_m"] is None or p["height_max_m"] is None):
        lo, hi = _height_limits(z, low_env, sigma)
        if p["height_min_m"] is None:
            p["height_min_m"] = lo
        if p["height_max_m"] is None:
            p["height_max_m"] = hi
    if p["terrain_slope"] is None:
        # step 3's tolerance: the rise of the typical ground over one cell (a height's
        # position inside its cell); the median slope of step 1's lower envelope
        p["terrain_slope"] = round(float(ch["slope_median"]), 4)
    if p["terrain_bend_m"] is None:
        p["terrain_bend_m"] = terrain_bend(z, (dx, dy), sigma)
    if p["ground_sigma_m"] is None:
        # step 3: the noise of the slope beyond a pair is the ground heights', not the crowns'
        p["ground_sigma_m"] = ground_sigma(z, (dx, dy), sigma)
    if p["max_hall_m"] is None:
        p["max_hall_m"] = longest_hall(z, (dx, dy), jump_m=p["jump_m"], max_building_m=p["max_building_m"],
                                       sigma_m=sigma, neighbour_k=p["neighbour_k"],
                                       terrain_bend_m=p["terrain_bend_m"], terrain_slope=p["terrain_slope"])
    if p["prediction_radius_m"] is None:
        p["prediction_radius_m"] = round(3.0 * cs, 3)
    need = [k for k in ("short_profile_m", "long_profile_m", "profile_sigma_m", "surface_size_m",
                        "surface_sigma_m", "prediction_sigma_m") if p[k] is None]
    if need:
        crops, sample, holes = _analysis_sample(z, (dx, dy), sigma, p)
        # the crops without the low blunders step 3 found: scattered ones pull most wide
        # blocks' minima down (the objects' width and the model errors then measure them)
        clean = [np.where(h, np.float32(np.nan), c) for c, h in zip(crops, holes)]
        report(progress, 0.6)
        # the terrain's own bends: the minima of 20 m blocks (wider blocks hide the shoulders
        # of cuts and embankments, whose ground then fails the snooping)
        ground = _ground_sample(clean, (dx, dy), GROUND_BLOCK_M)
        deg = model_degree(tc, p["homogeneous"])
        if any(p[k] is None for k in ("short_profile_m", "long_profile_m", "profile_sigma_m")):
            ps = _scan([odd_window(L / dx) for L in PROFILE_LENGTHS_M], sample, deg, sigma, at_least=2,
                       progress=sub_progress(progress, 0.6, 0.8))
            i_long = max(_choose([b for _, b in ps], sigma), 1)
            long_m = PROFILE_LENGTHS_M[i_long]
            i_short = max(i for i, L in enumerate(PROFILE_LENGTHS_M) if L <= max(long_m / 2, PROFILE_LENGTHS_M[0]))
            if p["long_profile_m"] is None:
                p["long_profile_m"] = long_m
            if p["short_profile_m"] is None:
                p["short_profile_m"] = PROFILE_LENGTHS_M[i_short]
            if p["profile_sigma_m"] is None:
                e = _model_errors(ground, [odd_window(p["long_profile_m"] / dx)], deg, np.inf, transposed=True)[0]
                p["profile_sigma_m"] = _about_model(sigma, e)
        if p["surface_size_m"] is None or p["surface_sigma_m"] is None:
            def win(S):
                return odd_window(S / dy), odd_window(S / dx)
            ss = _model_errors(ground, [win(S) for S in SURFACE_SIZES_M], min(deg, 1), sigma,
                               progress=sub_progress(progress, 0.8, 0.9))
            if p["surface_size_m"] is None:
                # how far the model follows the terrain, on block minima the objects do not
                # reach (blocks as wide as the window that covers them)
                if p["surface_rule"] == "residuals":
                    # the model-selection rule alone: the longest size before the residual
                    # spread of the fits grows (_choose)
                    spread = _scan([win(S) for S in SURFACE_SIZES_M], sample, min(deg, 1), sigma)
                    p["surface_size_m"] = SURFACE_SIZES_M[_choose([b for _, b in spread], sigma)]
                else:
                    # how wide the objects are: a surface window holds at least as much
                    # ground as object when it is sqrt(2) x as wide
                    i_o = _shortest_covering(SURFACE_SIZES_M, np.sqrt(2.0) * _objects_width(clean, (dx, dy), holes))
                    block = max(GROUND_BLOCK_M, SURFACE_SIZES_M[i_o])
                    bound = ss if block == GROUND_BLOCK_M else _model_errors(
                        _ground_sample(clean, (dx, dy), block), [win(S) for S in SURFACE_SIZES_M], min(deg, 1),
                        sigma)
                    p["surface_size_m"] = SURFACE_SIZES_M[min(_longest_following(bound, sigma), i_o)]
            e_s = _error_at(ss, SURFACE_SIZES_M, p["surface_size_m"],
                            lambda S: _model_errors(ground, [win(S)], min(deg, 1), np.inf)[0])
            if p["surface_sigma_m"] is None:
                p["surface_sigma_m"] = _about_model(sigma, e_s)
        if p["prediction_sigma_m"] is None:
            report(progress, 0.95)
            g = (gauss_weights(p["prediction_radius_m"] / dy), gauss_weights(p["prediction_radius_m"] / dx))
            s = _sample_scale(sample, (len(g[0]), len(g[1])), 1, kernels=g)[0]
            p["prediction_sigma_m"] = round(float(max(sigma, s if np.isfinite(s) else sigma)), 3)
    report(progress, 1.0)
    return p


def rascor_halo(params: dict, cell_size: Union[float, Sequence[float]]) -> int:
    """Reach of the whole sequence in cells (the sum of the enabled steps' reaches).

    Steps are chained, so a cell's fate depends on what earlier steps did within their
    reach around every cell of the later windows: the reaches add up (x 2 with the second
    iteration; step 3's once more without it, ``step3_repeat``). A step removing low
    blunders (3, 5, 6, 7) reaches at least as far as the ring test that confirms them
    (:func:`~.sequence.ring_reach`, 10 m). A ``steps`` entry (the override
    :func:`filter_rascor` takes) chooses the steps instead of the switches; step 7's reach
    always counts (it runs inside special areas).
    """
    dx, dy = as_cell_size(cell_size)
    cs = min(dx, dy)
    p = dict(DEFAULTS)
    p.update({k: v for k, v in params.items() if v is not None})

    def cells(m):
        return int(np.ceil((m or 0) / cs))

    ring = max(ring_reach((dx, dy)))
    iters = int(p.get("snooping_iterations") or 1)
    on = {3: p["step3_neighbour_differences"], 4: p["step4_level_change"], 5: p["step5_profiles"],
          6: p["step6_surfaces"]}
    if p.get("steps") is not None:          # filter_rascor's ``steps`` overrides the switches
        chosen = {int(k) for k in p["steps"]}
        on = {k: k in chosen for k in on}
    r3 = max(3, ring) if on[3] else 0
    # a closed level up to max_hall_m (steps.enclosed_levels): the whole level and a cell around it
    hall = cells(p["max_hall_m"]) + 2 if (p.get("max_hall_m") or 0) > p["max_building_m"] else 0
    r4 = max(2 * (cells(p["max_building_m"]) + 4), hall) if on[4] else 0
    r5 = iters * sum(max(cells(L) // 2 + 1, ring) for L in (p["short_profile_m"] or max(PROFILE_LENGTHS_M),
                                                            p["long_profile_m"] or max(PROFILE_LENGTHS_M))) \
        if on[5] else 0
    size6 = p["surface_size_m"] or max(SURFACE_SIZES_M)
    half6 = max(cells(size6) // 2, block_reach(odd_window(size6 / cs)) if p.get("fits_per_block") else 0)
    r6 = iters * max(half6 + 1, ring) if on[6] else 0   # a block fit reaches half a block further
    r7 = max(cells(p["prediction_radius_m"] or 3 * cs) + 1, ring)
    # steps 5-6's objects given back as ground continuing the kept ground: the path and its 3 x 3 test,
    # and the object regions' span compared with step 6's window (a region the block cuts spans the halo)
    # (the ramps of find_ramps: regions of at most step 6's window + REACH_M, and the ground touching them)
    r_cont = cells(size6) + continuation_cells((dx, dy), REACH_M) + 2 if (on[5] or on[6]) and \
        p.get("spare_continuing_ground", True) else 0
    # steps 3 and 5's objects given back at the terrain's slope breaks (sequence._spare_slope_breaks):
    # a run up to step 5's longest profile window and the two kept cells on each side (their line's
    # span against max_building_m: a line the window cuts spans step 4's reach r4, more than that)
    long_m = max(p["short_profile_m"] or max(PROFILE_LENGTHS_M), p["long_profile_m"] or max(PROFILE_LENGTHS_M))
    r_break = odd_window(long_m / cs) + 2 if on[3] or on[5] else 0
    once = r3 + r5 + r6 + r_cont + r_break + r7
    if p["second_iteration"]:
        return int(r4 + 2 * once)
    # step 3 once more after the last step (:func:`~.sequence.filter_rascor`'s step3_repeat)
    again = r3 if p.get("step3_repeat", True) else 0
    return int(r4 + once + again)
