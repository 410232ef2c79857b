"""The curvature filter's orchestration: the paper's steps in order, its parameters
(derived from the data where not given), its reach for blocks, and its registry entry.
"""
from dataclasses import dataclass
from typing import Optional

import numpy as np
from scipy import ndimage

from ..common import FilterResult, as_cell_size, as_surface, report, sub_progress
from ..estimate import (
    GROUND_BLOCK_M,
    RAISED_REGION_MARGIN,
    RAISED_REGION_MAX_M,
    RAISED_REGION_SPAN_M,
    ground_level_cells,
    ground_spread,
    noise_ground_level,
    noise_shared,
    raised_region_grid,
    raised_region_span_walled,
    raised_region_window,
    sample_windows,
    square_opening,
    terrain_slopes,
)
from ..methods import Method, Param
from .derivatives import (
    MODELS,
    CellSize,
    Progress,
    bounded_heights,
    check_model,
    check_window,
    derivative_blocks,
    mark_breaks,
)
from .ground import find_ground, ground_reach, ground_stretch
from .profiles import (
    LONGEST,
    LocalSlopes,
    enclosed_reach,
    find_enclosed_objects,
    find_profile_objects,
    height_spacing,
    profile_reach,
    wall_rise,
)

#: Percentile of the terrain's slopes that is "steep" (:func:`steep_terrain_slope`): the
#: upper quartile, the slopes a hillside reaches, robust to a quarter of the blocks on
#: roofs wider than a block (ISPRS samp31 at 2 m: its upper decile is 1.38 from its roofs).
_STEEP_PERCENTILE = 75.0
#: Break threshold in robust standard deviations of the profile bends (K_g default).
_K_SIGMAS = 1.5
#: Smallest height deviation (m) across a half window that counts as a break on
#: noise-free data (floor of the derived K_g).
_MIN_BREAK_M = 0.05
#: Half window (m) over which that deviation sets the cell-free floor of the bend: 5 cm over
#: 2 m, a curvature radius of 40 m (the 5-cell window at 1 m cells, where the floor was set).
_FLOOR_HALF_M = 2.0
#: Longest object by default, metres (profile runs and enclosed regions longer are ground).
OBJECT_SIZE_M = 100.0
#: The object size is derived on block minima of at most this many cells.
#: Tile edge (cells) and quantile of the tile spreads used for the ground's bend noise.
_TILE = 16
_SMOOTH_QUANTILE = 0.25


def filter_curvature(z: np.ndarray, cell_size: CellSize, *, k_g_per_m2: float, window_cells: int = 5,
                     model: str = "quadratic", min_object_height_m: float = 1.0,
                     wall_slope_deg: float = 45.0, max_object_size_m: float = 100.0,
                     tolerance_m: float = 0.3, terrain_slope: float = 0.0, spacing_m: float = 0.0,
                     progress: Optional[Progress] = None) -> FilterResult:
    """Separate objects from the ground by the Gaussian curvature of local trends.

    Luong Chinh Ke (2002), section 2.2: a local surface fitted by least squares around
    every point gives its Gaussian curvature K = (r t - s^2) / h^4 (eqs. 9-16); a point
    with |K| >= K_g is a break at the foot or the top of an object. Breaks are then
    turned into whole objects along the X and Y profiles (see :mod:`bare_earth.core.curvature`).

    Parameters
    ----------
    z : array_like, 2-D
        DSM in metres, NaN = nodata. Not modified.
    cell_size : float or (float, float)
        ``(dx, dy)`` in metres.
    k_g_per_m2 : float
        Curvature threshold K_g in 1/m^2. A cell is a break when ``|K| >= K_g`` or, with
        the quadratic model, when the bend of its X or Y profile trend ``|r|`` or ``|t|``
        is at least ``sqrt(K_g)`` (a straight roof edge has K = 0 but its profile across
        the edge bends strongly).
    window_cells : int
        Odd number of points per profile group (window edge), >= 3; the paper asks for at
        least 5.
    model : {"quadratic", "bilinear"}
        Local trend surface. ``"bilinear"`` is the paper's eq. 12 (K <= 0 always,
        r = t = 0: only twisted breaks such as corners are seen).
    min_object_height_m : float
        A profile enters an object at a break where it has risen at least this much
        within two cells (a wall); also the depth below the ground surface and below the
        ring around it that makes a concave break a low blunder (class 2).
    wall_slope_deg : float
        That rise must be steeper than this, and three times steeper than the profile
        before it (object walls are steep; dams, embankments and terrace edges are not).
    terrain_slope : float
        Rise/run of the terrain's steep slopes: the rise of a wall over two cells must also
        exceed what this slope rises over them (:func:`.profiles.wall_rise`; it matters at
        coarse cells, where the wall slope judged over 3 m is a few metres).
    spacing_m : float
        Metres between independent heights (0: the cell): the wall's slope is judged over
        this span (within 3 m) where it is longer than two cells (:func:`.profiles.wall_rise`:
        a raster filled from sparser points climbs slopes in risers of one point each).
    max_object_size_m : float
        Longest object (profile runs and enclosed regions larger than this are ground);
        also bounds the method's reach (halo).
    tolerance_m : float
        Final pass: a cell more than this (plus one cell of the surface's slope) above the
        ground surface interpolated under the objects and breaks is an object.
    progress : callable, optional
        ``progress(fraction)``; may raise :class:`~.common.Cancelled`.

    Returns
    -------
    FilterResult
        ``mask`` (0 ground, 1 object, 2 low blunder, 255 nodata), ``extras["curvature"]``
        (float32, bands K in 1/m^2 and H in 1/m, H > 0 convex; NaN at nodata),
        ``surface`` (the ground surface of the final pass), and ``info`` with K_g and the
        shares of valid cells marked by X profiles (``share_marked_x``), by Y profiles
        (``share_marked_y``), by ``|K| >= K_g`` (``share_marked_k``) and found inside
        objects by the X and Y profiles.

    References
    ----------
    Luong Chinh Ke (2002). Filtering of DSM, section 2.2 (local trend, Gaussian curvature).
    """
    z = bounded_heights(as_surface(z))          # +-1e30 and the like: spikes, not overflow
    cell = as_cell_size(cell_size)
    s = _checked_settings(k_g_per_m2, window_cells, model, min_object_height_m, wall_slope_deg,
                          max_object_size_m, tolerance_m, terrain_slope, spacing_m)
    valid = np.isfinite(z)
    n_valid = int(np.count_nonzero(valid))
    some_valid = None if n_valid == valid.size else valid     # None: every cell is valid
    report(progress, 0.0)
    # 1. local trends and curvature (eqs. 9-16); 2. breaks: |K| >= K_g, |r| or |t| >= sqrt(K_g)
    breaks = mark_breaks(z, cell, s.k_g, window=s.window, model=s.model,
                         progress=sub_progress(progress, 0.0, 0.35))
    # 3. along X and Y profiles: from a break going up to the break coming down, the runs
    # bounded across within the largest object
    levels = []                         # lower levels between higher parts along one axis only
    objects, n_obj_x, n_obj_y, edge_runs = find_profile_objects(
        z, breaks.marked, some_valid, cell, window=s.window, h_min=s.h_min, tan_wall=s.tan_wall,
        tol=s.tol, max_size=s.max_size, terrain_slope=s.terrain_slope, spacing=s.spacing, edge_runs=True,
        levels_out=levels, local_slopes=LocalSlopes(z, cell), progress=sub_progress(progress, 0.35, 0.55))
    # 4. regions enclosed by breaks and made mostly of such runs (or of lower levels between higher
    # parts along one axis), and regions of the runs cut by the raster's edge whose walls run within
    # the reach -> whole objects
    objects |= find_enclosed_objects(objects | levels[0], breaks.marked, some_valid, cell, s.max_size,
                                     progress=sub_progress(progress, 0.55, 0.65), edge_runs=edge_runs,
                                     window=s.window, z=z, tol=s.tol)
    del edge_runs, levels
    # 5. final pass against the ground interpolated under objects and breaks (twice)
    mask, surface = find_ground(z, objects, breaks, some_valid, cell, window=s.window,
                                h_min=s.h_min, tol=s.tol, max_size=s.max_size, rise=_ground_step(s, cell),
                                stretch=ground_stretch(cell, s.window, s.spacing),
                                progress=sub_progress(progress, 0.65, 1.0))
    info = _info(s, cell, breaks, n_obj_x, n_obj_y, max(n_valid, 1))
    report(progress, 1.0)
    return FilterResult(mask=mask, extras={"curvature": breaks.curvature}, info=info, surface=surface)


@dataclass(frozen=True)
class _Settings:
    """The checked parameters of :func:`filter_curvature` (tan_wall: tan of the wall slope)."""
    k_g: float
    window: int
    model: str
    h_min: float
    wall_slope_deg: float
    tan_wall: float
    max_size: float
    tol: float
    terrain_slope: float
    spacing: float


def _checked_settings(k_g_per_m2, window_cells, model, min_object_height_m, wall_slope_deg,
                      max_object_size_m, tolerance_m, terrain_slope=0.0, spacing_m=0.0):
    """The parameters of :func:`filter_curvature`, checked (ValueError naming the fix)."""
    window = check_window(window_cells)
    model = check_model(model)
    k_g = _positive("k_g_per_m2", k_g_per_m2, "a curvature threshold K_g in 1/m^2, e.g. "
                    "leave it empty to derive it from the data")
    h_min = _positive("min_object_height_m", min_object_height_m, "e.g. 1.0")
    tol = _positive("tolerance_m", tolerance_m, "e.g. 0.3")
    max_size = _positive("max_object_size_m", max_object_size_m, "e.g. 100")
    if not (0.0 < float(wall_slope_deg) < 90.0):
        raise ValueError(f"wall_slope_deg must be between 0 and 90 degrees; got {wall_slope_deg}. "
                         "Use e.g. 45.")
    tan_wall = float(np.tan(np.radians(float(wall_slope_deg))))
    terrain_slope = float(terrain_slope)
    if not (0.0 <= terrain_slope < np.inf):
        raise ValueError(f"terrain_slope must be a rise/run >= 0; got {terrain_slope}. "
                         "Leave it empty to derive it from the data, or use 0 for no terrain term.")
    spacing = float(spacing_m)
    if not (0.0 <= spacing < np.inf):
        raise ValueError(f"spacing_m must be a distance >= 0 in metres; got {spacing_m}. "
                         "Leave it empty to derive it from the data, or use 0 for the cell.")
    return _Settings(k_g, window, model, h_min, float(wall_slope_deg), tan_wall, max_size, tol, terrain_slope,
                     spacing)


def _ground_step(s, cell):
    """Metres ``(along X, along Y)`` that the ground may step between neighbouring cells in the
    final pass's continued ground (:func:`.ground.find_ground`): the tolerance plus the rise of
    the terrain's steep slopes over a cell, or over the spacing of the heights where longer (a
    raster filled from sparser points climbs a slope in risers of one point each)."""
    return tuple(s.tol + s.terrain_slope * max(d, s.spacing) for d in cell)


def _info(s, cell, breaks, n_obj_x, n_obj_y, n_valid):
    """The parameters used, the rise that makes a wall along X and Y
    (:func:`.profiles.wall_rise`) and the shares of valid cells marked and found inside
    objects."""
    return {"k_g_per_m2": float(s.k_g), "window_cells": s.window, "model": s.model,
            "min_object_height_m": s.h_min, "wall_slope_deg": s.wall_slope_deg,
            "terrain_slope": s.terrain_slope, "spacing_m": s.spacing,
            "wall_rise_x_m": round(wall_rise(cell[0], h_min=s.h_min, tan_wall=s.tan_wall,
                                             terrain_slope=s.terrain_slope, spacing=s.spacing), 4),
            "wall_rise_y_m": round(wall_rise(cell[1], h_min=s.h_min, tan_wall=s.tan_wall,
                                             terrain_slope=s.terrain_slope, spacing=s.spacing), 4),
            "max_object_size_m": s.max_size, "tolerance_m": s.tol,
            "share_marked_x": breaks.n_x / n_valid,
            "share_marked_y": breaks.n_y / n_valid,
            "share_marked_k": np.count_nonzero(breaks.by_k) / n_valid,
            "share_marked": np.count_nonzero(breaks.marked) / n_valid,
            "share_objects_x": n_obj_x / n_valid,
            "share_objects_y": n_obj_y / n_valid}


def _positive(name, value, hint):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive number; got {value!r}: {hint}.") from None
    if not np.isfinite(v) or v <= 0:
        raise ValueError(f"{name} must be a positive number; got {value!r}: {hint}.")
    return v


def _bends(zs, cell_size, window, model):
    """The bands of profile bends of a surface: r and t of the X and Y profile trends
    (quadratic model) or the normalised twist s / h^2 (bilinear model)."""
    quad = model == "quadratic"
    v = np.empty((2 if quad else 1,) + zs.shape, np.float32)
    for sl, p, q, r, s, t in derivative_blocks(zs, cell_size, window, model):
        if quad:
            v[0, sl] = r
            v[1, sl] = t
        else:
            np.divide(s, 1.0 + p * p + q * q, out=v[0, sl])
    return v


def _ground_bends(zs, cell_size, window, model):
    """:func:`_bends` kept only where the whole window stands at ground level
    (:func:`~bare_earth.core.estimate.ground_level_cells`), NaN elsewhere: the bends of the
    ground, not of the canopy or the roofs (a closed canopy's smooth parts are crowns, and
    its K_g read 100 times the ground's)."""
    v = _bends(zs, cell_size, window, model)
    ground = ground_level_cells(zs, cell_size, noise_ground_level(zs, cell_size)["sigma"])
    ground = ndimage.binary_erosion(ground, np.ones((window, window), bool), border_value=1)
    v[:, ~ground] = np.nan
    return v


def bend_noise_gain(cell_size: CellSize, window: int = 5) -> float:
    """Standard deviation (1/m) of the profile bend ``r`` of the quadratic local fit
    (:func:`.derivatives.local_derivatives`) per metre of white height noise:
    ``2 / (sqrt(w B) dx^2)``, ``B = sum (u^2 - c)^2`` over ``u = -m..m`` (``r = 2 d`` with
    ``d = sum((u^2 - c) z) / (w B dx^2)``); the coarser of ``dx``, ``dy``."""
    m = check_window(window) // 2
    u = np.arange(-m, m + 1, dtype=np.float64)
    b = float(np.sum((u * u - np.mean(u * u)) ** 2))
    d = max(as_cell_size(cell_size))
    return 2.0 / (np.sqrt((2 * m + 1) * b) * d * d)


def edge_bend(cell_size: CellSize, window: int, height_m: float) -> float:
    """Bend (1/m) of the quadratic profile trend (:func:`.derivatives.local_derivatives`)
    centred on the foot of a wall of ``height_m``: ``r = 2 d`` with ``d = sum((u^2 - c) z)
    / (B dx^2)`` over ``u = -m..m`` (the mean over the window's rows), ``z = height_m``
    for ``u > 0``: ``2 height_m sum_{u>0}(u^2 - c) / (B dx^2)``; the coarser of ``dx``,
    ``dy`` (5 cells: ``height_m / (7 dx^2)``)."""
    m = check_window(window) // 2
    u = np.arange(-m, m + 1, dtype=np.float64)
    c = float(np.mean(u * u))
    b = float(np.sum((u * u - c) ** 2))
    d = max(as_cell_size(cell_size))
    return 2.0 * float(height_m) * float(np.sum(u[u > 0] ** 2 - c)) / (b * d * d)


def derive_k_g(z: np.ndarray, cell_size: CellSize, *, window: int = 5, model: str = "quadratic",
               min_object_height_m: Optional[float] = None, spacing_m: Optional[float] = None,
               progress=None) -> float:
    """Curvature threshold K_g (1/m^2) from the data's own curvature distribution.

    The bends r and t of the X and Y profile trends (quadratic model) or the normalised
    twist s / h^2 (bilinear model) are taken on the whole raster, or on windows spread
    over a large one (:func:`~bare_earth.core.estimate.sample_windows`), on the cells whose
    whole window stands at ground level (:func:`~bare_earth.core.estimate.ground_level_cells`:
    never the crowns or roofs, whose smooth parts fill a closed canopy). Their robust
    spread ``1.4826 MAD`` is computed per 16 x 16 tile holding at least a quarter of such
    cells and ``sigma`` is the first quartile of the tiles
    (:func:`~bare_earth.core.estimate.ground_spread`): the curvature noise of the smooth
    ground. Low vegetation among the ground-level cells (a highest-point DSM of a vegetated hillside, where
    it touches most tiles) bends the fit as much as it moves the heights: the fit's bend is a linear
    function of the heights, so ``sigma`` is scaled by the share of the ground-level cells' height spread
    that is the sensor's noise, ``sigma_cleanest / sigma`` of
    :func:`~bare_earth.core.estimate.noise_ground_level` (:func:`_clean_share`; 1 on clean ground: ISPRS
    samp11 at 2 m highest point, 0.63, K_g 0.0162 -> 0.0066 1/m^2, whose threshold stood above the bend of
    a 3 m object and left the shrubs on the slope ground: 33.0 -> 29.1 % total error; the synthetic hillside
    site's terrace edges read as such too, +0.20 / +0.34 at 1 / 2 m highest point). The smoothest tiles
    are the flat ones; on sloping ground a cell's height is a
    point somewhere inside the cell, and its place alone moves the height by ``g / sqrt(12)``
    (``g = s cell`` the rise of the ground's median slope ``s`` over one cell, the slope of
    20 m block minima, :func:`~bare_earth.core.estimate.terrain_slopes`; over ``spacing_m``
    where the independent heights lie farther apart than a cell, default
    :func:`.profiles.height_spacing`: a point filled over the cells around it was taken
    anywhere within that spacing, as :func:`~bare_earth.core.estimate.lowest_point_spread`
    models it; ISPRS samp61 at 1 m 3.67 -> 3.52 %, hexbin-crop 1 / 2 / 4 m -0.14 / -0.15 /
    -1.81), which bends the
    fit by :func:`bend_noise_gain` times that; the two add in quadrature,
    ``sigma_b = hypot(sigma, gain g / sqrt(12))`` (the term grows with the cell: a 2 m cell
    on a slope holds twice the rise of a 1 m cell, so the fit's bend noise falls as 1 /
    cell there, not as 1 / cell^2). ``K_g = (1.5 sigma_b)^2``, the Gaussian curvature of a
    point bent by 1.5 sigma_b both ways, floored at the bend of a 5 cm deviation over half a
    window so that noise-free data do not mark every gentle bend. With
    ``min_object_height_m`` the floor is at least the bend of 5 cm over 2 m (a curvature
    radius of 40 m, the same at every cell) but at most the bend of an object of that
    height over half a window: the ground's own bends are the same in 1/m at every cell
    size while a window's noise bends, and the floor of 5 cm over half a window, fall as
    1/cell^2, so at 2 and 4 m cells most of the ground became breaks (ISPRS samp71 at 2 m:
    9 % total error; a forest at 4 m), and the final pass interpolated the ground under
    them; the smallest object the filter looks for still bends the fit by at least the
    threshold at 10 or 20 m cells. At 1 m cells and finer the floor is unchanged. (1.5
    rather than a stricter 3 sigma: the wall and surface tests downstream reject the extra breaks, and
    missed breaks cost whole objects.) ``progress(fraction)`` (optional, may raise
    ``Cancelled``) after each window.
    """
    dx, dy = as_cell_size(cell_size)
    window = check_window(window)
    model = check_model(model)
    windows = sample_windows(as_surface(z))
    bends = []
    for i, w in enumerate(windows):
        bends.append(_ground_bends(w, (dx, dy), window, model))
        report(progress, 0.6 * (i + 1) / len(windows))
    sigma = ground_spread(bends, tile=_TILE, quantile=_SMOOTH_QUANTILE, progress=sub_progress(progress, 0.6, 0.9))
    sigma *= _clean_share(z, (dx, dy), progress=sub_progress(progress, 0.9, 1.0))
    if spacing_m is None:
        spacing_m = height_spacing(z, (dx, dy))
    sigma = float(np.hypot(sigma, _place_bend(z, (dx, dy), window, spacing_m)))
    half = (window // 2) * max(dx, dy)
    floor = 2.0 * _MIN_BREAK_M / (half * half)
    if min_object_height_m is not None:
        floor = max(floor, min(2.0 * _MIN_BREAK_M / (_FLOOR_HALF_M * _FLOOR_HALF_M),
                               edge_bend((dx, dy), window, float(min_object_height_m))))
    kappa = max(_K_SIGMAS * sigma, floor)
    return kappa * kappa


def _clean_share(z, cell_size, progress=None):
    """The part of the ground-level cells' height spread that is the sensor's noise: ``sigma_cleanest /
    sigma`` of :func:`~bare_earth.core.estimate.noise_ground_level` (at most 1; 1 where either is not
    measurable)."""
    gn = noise_ground_level(as_surface(z), cell_size, progress=progress)
    s, c = gn["sigma"], gn["sigma_cleanest"]
    if not (np.isfinite(s) and np.isfinite(c) and s > 0):
        return 1.0
    return float(min(1.0, c / s))


def _place_bend(z, cell_size, window, spacing_m=0.0):
    """Bend noise (1/m) of the fit from the place of a height inside its cell on ground of
    the median slope (20 m block minima): :func:`bend_noise_gain` x ``s c / sqrt(12)``, ``c``
    the cell or, where the independent heights lie farther apart (``spacing_m``,
    :func:`.profiles.height_spacing`), their spacing: a point filled over the cells around it
    was taken anywhere within that spacing (the spacing
    :func:`~bare_earth.core.estimate.lowest_point_spread` models)."""
    dx, dy = cell_size
    d = max(dx, dy)
    s = terrain_slopes(as_surface(z), (dx, dy), max(2, int(round(GROUND_BLOCK_M / d))))
    s = float(np.median(s)) if s.size else 0.0
    return bend_noise_gain((dx, dy), window) * s * max(d, float(spacing_m)) / np.sqrt(12.0)


def steep_terrain_slope(z, cell_size) -> float:
    """The terrain's steep slopes (rise/run): the upper quartile of the slopes of the 20 m
    block minima (:func:`~bare_earth.core.estimate.terrain_slopes`: the surface objects
    narrower than a block do not reach), 0 where they cannot be measured. The upper
    quartile, not a higher percentile: roofs wider than a block and low blunders tilt
    some blocks' slopes, and the quartile holds while they are under a quarter of them.
    A wall must rise more over two cells than this slope does (:func:`.profiles.wall_rise`)."""
    dx, dy = cell_size
    d = max(dx, dy)
    s = terrain_slopes(as_surface(z), (dx, dy), max(2, int(round(GROUND_BLOCK_M / d))))
    return float(np.percentile(s, _STEEP_PERCENTILE)) if s.size else 0.0


def object_size(z: np.ndarray, cell_size: CellSize, height_m: float, progress=None) -> float:
    """The derived longest object, metres: :data:`OBJECT_SIZE_M`, widened to the window of a wider raised
    region standing on walls higher than ``height_m`` (a hall: its profile runs and its enclosed region are
    longer than 100 m, and were ground), :func:`~bare_earth.core.estimate.raised_region_window` (1.25 x its
    width + 2 cells, regions up to 200 m wide spanning up to 400 m), at most 200 m; on block minima of at
    most :data:`~bare_earth.core.estimate.RAISED_REGION_CELLS` cells
    (:func:`~bare_earth.core.estimate.raised_region_grid`). A region running across the raster (meeting two
    opposite sides) widens nothing: its extent is not seen, and the profiles, mirrored at both sides, would
    then take a terrace's upper level across a tile for a roof. The raised regions are looked for on the block
    minima and on their opening by the square of :data:`OBJECT_SIZE_M`
    (:func:`~bare_earth.core.estimate.square_opening`): a building 160 x 120 m of parts 4-18 m high, each
    narrower than 100 m, is one raised region there (its profiles ran 160 m and it was 0.57 object at 2 m
    cells; 1.00 with the largest object widened to 148 m). A long narrow building (a ring of wings round a
    courtyard, a wing) is no wider than the largest object, but the cross profiles along a wing run its whole
    length without a break, and a run whose cross profile does so for more than :data:`.profiles.LONGEST`
    largest objects is dropped (:func:`.profiles.bounded_stretches`: the level between two gullies): the
    largest object is widened so that that many reach along the longest raised region standing on walls along
    both sides of its length (:func:`~bare_earth.core.estimate.raised_region_span_walled`, not running across
    the raster), as the window reaches across a width (``(1.25 span + 2 cells) / LONGEST``): a ring 220 x
    140 m of wings 20 m wide was 0.87 / 0.31 / 0.32 object at 1 / 2 / 4 m, its long wings or its corners
    ground. A quarry's bench arc, on walls down on one side only, widens nothing.
    ``progress(fraction)`` (optional, may raise ``Cancelled``): after each estimate, and from inside the raised
    regions' searches after each of their scales."""
    zs, cs, _ = raised_region_grid(z, cell_size)
    report(progress, 0.2)
    window = raised_region_window(zs, cs, height_m, OBJECT_SIZE_M, max_span_m=RAISED_REGION_SPAN_M, across=False,
                                  progress=sub_progress(progress, 0.2, 0.4))
    # a building of several heights: its parts are raised regions of their own, each narrower; opened by
    # the square of the default largest object, it stands as one level on walls all round
    opened = square_opening(zs, int(OBJECT_SIZE_M / min(cs)) + 1)
    report(progress, 0.5)
    window = max(window, raised_region_window(opened, cs, height_m, OBJECT_SIZE_M, max_span_m=RAISED_REGION_SPAN_M,
                                              across=False, progress=sub_progress(progress, 0.5, 0.7)))
    # a long narrow building (a ring round a courtyard, a wing): its runs across are short, but its cross
    # profiles run its whole length, which LONGEST largest objects must reach (as a width, with the margin);
    # walls along both sides of its length (not a quarry's bench or a terrace, on walls down on one side)
    span = raised_region_span_walled(zs, cs, height_m, 0.0, max_span_m=RAISED_REGION_SPAN_M,
                                     min_cells=int(OBJECT_SIZE_M / min(cs)), across=False,
                                     progress=sub_progress(progress, 0.7, 1.0)) * min(cs)
    if span > 0:
        window = max(window, (RAISED_REGION_MARGIN * span + 2.0 * max(cs)) / LONGEST)
    return round(max(OBJECT_SIZE_M, min(window, RAISED_REGION_MAX_M)), 1)


def resolve_curvature_params(z: np.ndarray, cell_size: CellSize, *, k_g_per_m2: Optional[float] = None,
                             window_cells: int = 5, model: str = "quadratic",
                             min_object_height_m: float = 1.0, wall_slope_deg: float = 45.0,
                             max_object_size_m: Optional[float] = None,
                             tolerance_m: Optional[float] = None, terrain_slope: Optional[float] = None,
                             spacing_m: Optional[float] = None, progress=None) -> dict:
    """Complete parameter set for :func:`filter_curvature`, ``None`` derived from the data.

    ``k_g_per_m2``: :func:`derive_k_g` (1.5 robust sigmas of the profile bends of the
    ground, squared; its floor at least 5 cm over 2 m, at most the bend of a
    ``min_object_height_m`` object over half a window). ``tolerance_m``: three times the
    noise of the DSM's ground-level cells (:func:`~bare_earth.core.estimate.noise_ground_level`), kept within
    [0.3, 1.0] m; 0.5 m when too few ground cells are seen. ``terrain_slope``:
    :func:`steep_terrain_slope`. ``spacing_m``: :func:`.profiles.height_spacing`.
    ``max_object_size_m``: :func:`object_size` (100 m, or the window of a wider raised region standing on
    walls higher than ``min_object_height_m``). The others have
    fixed defaults (see :data:`METHOD`). ``progress(fraction)`` (optional, may raise
    ``Cancelled``) from inside the estimates.
    """
    z = bounded_heights(as_surface(z))
    dx, dy = as_cell_size(cell_size)
    window_cells = check_window(window_cells)
    model = check_model(model)
    if spacing_m is None:
        spacing_m = height_spacing(z, (dx, dy))
    with noise_shared():      # the ground-level noise measured once for K_g and the tolerance
        if k_g_per_m2 is None:
            k_g_per_m2 = derive_k_g(z, (dx, dy), window=window_cells, model=model,
                                    min_object_height_m=min_object_height_m, spacing_m=spacing_m,
                                    progress=sub_progress(progress, 0.0, 0.75))
        if tolerance_m is None:
            sigma = noise_ground_level(z, (dx, dy), progress=sub_progress(progress, 0.75, 0.85))["sigma"]
            tolerance_m = float(np.clip(3.0 * sigma, 0.3, 1.0)) if np.isfinite(sigma) else 0.5
    report(progress, 0.85)
    if terrain_slope is None:
        terrain_slope = steep_terrain_slope(z, (dx, dy))
        report(progress, 0.9)
    if max_object_size_m is None:
        max_object_size_m = object_size(z, (dx, dy), float(min_object_height_m), sub_progress(progress, 0.9, 1.0))
        report(progress, 1.0)
    return {"k_g_per_m2": float(k_g_per_m2), "window_cells": window_cells, "model": model,
            "min_object_height_m": float(min_object_height_m),
            "wall_slope_deg": float(wall_slope_deg),
            "max_object_size_m": float(max_object_size_m), "tolerance_m": float(tolerance_m),
            "terrain_slope": float(terrain_slope), "spacing_m": float(spacing_m)}


def curvature_halo(params: dict, cell_size: CellSize) -> int:
    """Reach of the filter in cells, the sum of its stages' reaches: the profile objects
    (:func:`.profiles.profile_reach`: the largest object plus the wall test), the enclosed
    regions (:func:`.profiles.enclosed_reach`: twice the largest object, as long as a region may
    be) and the final pass's two ground surfaces (:func:`.ground.ground_reach`: twice half the largest object, plus the
    windows and the continued ground's stretches, :func:`.ground.ground_stretch`); even. Every
    rule of the filter is local within its reach, so blocks with this halo give the mask of one
    pass."""
    dx, dy = as_cell_size(cell_size)
    w = check_window(params.get("window_cells", 5))
    size = float(params.get("max_object_size_m") or OBJECT_SIZE_M)
    stretch = max(ground_stretch((dx, dy), w, float(params.get("spacing_m", 0.0))))
    halo = (profile_reach((dx, dy), window=w, max_size=size) + enclosed_reach((dx, dy), max_size=size)
            + ground_reach((dx, dy), window=w, max_size=size, stretch=stretch))
    return halo + (halo & 1)


def _run(z, cell_size, progress=None, **params):
    return filter_curvature(z, cell_size, progress=progress, **params)


def check_curvature_given(values):
    """ValueError for given values no data makes valid: an even or fractional ``window_cells``
    (:func:`check_window`; its bounds are the Param's)."""
    if values.get("window_cells") is not None:
        check_window(values["window_cells"])


METHOD = Method(
    name="curvature",
    check=check_curvature_given,
    bytes_per_cell=104.0,       # measured 57.8 (benchmarks/speed.py, 16 Mcells, file); 88.6 with the large
    #                            buildings' block-minima opening and enclosed regions; 99.7 with the
    #                            envelope between crowns (2026-11-30, session 24)
    run=_run,
    resolve=resolve_curvature_params,
    halo=curvature_halo,
    extras={"curvature": (np.float32, 2, float("nan"))},
    extra_bands={"curvature": ("Gaussian curvature K (1/m^2)", "mean curvature H (1/m)")},
    params=(
        Param("k_g_per_m2", "float", None,
              "Gaussian-curvature threshold K_g in 1/m^2 (Luong Chinh Ke 2002, sec. 2.2): a "
              "cell with |K| >= K_g, or whose X or Y profile bends by sqrt(K_g) 1/m or more, "
              "is a break. Empty: (1.5 robust sigmas of the data's profile bends on the ground, "
              "scaled by the share of the ground's height spread that is the sensor's noise, with the "
              "bend a height's place inside its cell (or the spacing of the heights) gives "
              "on the median slope)^2, at least "
              "the bend of 5 cm over 2 m (at most that of a minimum-height object over half "
              "a window); see "
              "the CURVATURE output to choose it.", minimum=1e-9, maximum=1e6),
        Param("window_cells", "int", 5,
              "Points per profile group (odd window edge, cells) of the local least-squares "
              "trend; the paper asks for at least 5.", minimum=3, maximum=51),
        Param("model", "enum", "quadratic",
              "Local trend surface: 'quadratic' (z = a + bx + cy + dx^2 + exy + fy^2, gives K "
              "and the mean curvature H) or 'bilinear', the paper's eq. 12 (r = t = 0, so "
              "K <= 0 and straight edges are not seen).", options=MODELS, advanced=True),
        Param("min_object_height_m", "float", 1.0,
              "Metres a profile must rise at a break, within two cells, to enter an object "
              "(Luong Chinh Ke 2002: points between a break going up and the break coming "
              "down); also the depth of a low blunder (class 2).",
              minimum=0.05, maximum=100.0),
        Param("wall_slope_deg", "float", 45.0,
              "Degrees: that rise must be steeper than this (and 3x steeper than the profile "
              "before it, and than the profile over the two cells before its foot) to be an "
              "object's wall; dams, embankments and terrace edges are "
              "gentler and stay ground. The slope is judged over two cells but over 3 m at "
              "most (coarser cells cannot show it; the log gives the rise used).",
              minimum=1.0, maximum=89.0, advanced=True),
        Param("max_object_size_m", "float", None,
              "Metres: largest object; wider enclosed regions, or longer than twice it, are ground. Also the method's "
              "reach for block processing. Empty: 100 m, widened to 1.25 x the width + 2 cells of a wider "
              "raised region standing on walls (a hall; also looked for on the DSM opened by a 100 m square, "
              "where a building of several heights stands as one level), and to half of 1.25 x the span + 2 "
              "cells of a raised region longer than 200 m on walls along both sides of its length (a ring of "
              "wings round a courtyard: its wings' runs lay on profiles running its whole length, and were "
              "dropped; not a quarry's bench, on walls down on one side), at most 200 m.", minimum=1.0, maximum=2000.0),
        Param("tolerance_m", "float", None,
              "Metres above the ground surface interpolated under objects and breaks that a "
              "cell may stand (plus one cell of the surface's slope) and still be ground "
              "(final pass). Empty: 3 x the noise of the DSM's ground-level cells, within [0.3, 1] m.",
              minimum=0.01, maximum=10.0, advanced=True),
        Param("terrain_slope", "float", None,
              "Rise/run of the terrain's steep slopes: a wall must also rise more within two "
              "cells than this slope does, so the foot of a hillside is no wall at coarse "
              "cells. Empty: the upper quartile of the slopes of 20 m block minima (the log "
              "gives it and the rise used).", minimum=0.0, maximum=100.0, advanced=True),
        Param("spacing_m", "float", None,
              "Metres between independent heights: where longer than two cells, a wall's "
              "slope is judged over it (within 3 m), since a raster filled from sparser "
              "points climbs a slope in risers of one point each; the derived K_g allows "
              "for a height's place within it. Empty: the cell over 1 - the share of "
              "neighbours with equal heights, level areas left out (0: the cell).",
              minimum=0.0, maximum=1000.0, advanced=True),
    ),
    title="Curvature filter (Luong Chinh Ke 2002)",
    description=(
        "<p>Local-trend filter by Gaussian curvature (Luong Chinh Ke 2002, section 2.2). A "
        "local surface is fitted by least squares to the <i>window</i> x <i>window</i> "
        "points around every cell (at least five points per X and Y profile) and gives "
        "the Gaussian curvature K = (r t - s<sup>2</sup>) / h<sup>4</sup>, "
        "h<sup>2</sup> = 1 + p<sup>2</sup> + q<sup>2</sup> (eqs. 9-16), and the mean "
        "curvature H (H &gt; 0 convex, H &lt; 0 concave). Cells with |K| &ge; K<sub>g</sub>, "
        "or whose X or Y profile bends by &radic;K<sub>g</sub> or more (a straight roof "
        "edge has K = 0), are breaks at the feet and tops of objects.</p>"
        "<p>Along each X and Y profile, scanned both ways, the points between a break going "
        "up a wall (a rise of at least the minimum object height within two cells, steeper "
        "than the wall slope and three times steeper than the profile before it, over the reach of "
        "the test and over the two cells just before its foot: a wall is a step across about a cell, a "
        "terrain side continues over several; a gully's side crossed obliquely at 4 m cells rose as "
        "much within two cells as a wall, and bare gullies lost 8 % of their ground) and the matching "
        "break coming "
        "down belong to an object, unless a cell of that run lies on a cross profile that meets no "
        "break, no step of the minimum object height and no nodata within twice the largest object "
        "(an object is bounded both ways, and at most one doubling of its width long: the level "
        "between two gullies running along Y is climbed from one and left down into the next, but "
        "continues along Y; bare gullies at 4 m cells lost a fifth of their ground so. A shorter "
        "level is still an object, and a bridge is bounded only by the breaks along its deck); "
        "a lower level that the scans of both directions, along X and along Y, come down onto "
        "from a higher part, still more than the minimum object height above the ground their wall "
        "rose from, and leave down to that ground within the largest object, is the object's too (a "
        "lower roof enclosed by higher wings kept its own height as ground: a quarter of such an "
        "80 m building); "
        "regions enclosed by breaks and made mostly of such "
        "points become whole objects, when no wider than the largest object and at most twice as long "
        "(the corner of an L-shaped warehouse 180 m long, with arms 60 m wide, is on profiles running "
        "180 m both ways: it stayed ground, a fifth of the building); the lower levels that the scans of "
        "both directions along one axis only come down onto count with those points where, along the other "
        "axis, the level ends in a drop on one side at least (a low middle part between two wings, open "
        "along the other axis, where its ends rise 1.5 m, no wall at 2-4 m cells: half the building stayed "
        "ground; a level running on beyond the wings is enclosed by no breaks and stays ground, and so does "
        "an embankment's level between the bushes on its sides, which runs on along it: without the drop, "
        "the total error of a 2 m embankment scene rose 0.46 -> 0.60 %). Where the raster's edge cuts an "
        "object, the profile is taken as mirrored there: a run from a wall that meets the edge within half the "
        "largest object counts for both directions (a roof in a corner of the tile), unless the "
        "region of such runs, mirrored at every side the edge cuts across the profiles too, "
        "is longer than the largest object (a terrace or quarry bench running across the "
        "tile stays ground). A roof cut farther from its wall (a hall over most of the tile) is "
        "judged by its walls: the region of the runs that met the edge is an object when what is "
        "seen of it lies within the largest object, its seen outline stands on their walls over "
        "more than half its length, and those walls, mirrored at the sides of the raster they "
        "meet, run within twice the largest object (a wall cutting off a corner runs twice what "
        "is seen; one across the tile, three times: a terrain step's, ground). A final "
        "pass compares every cell with the ground "
        "interpolated under the objects and their breaks (objects only where a wall stands "
        "within half the largest object: the terrain's own crests, curved both ways, are "
        "no objects on a coarse bare-earth DEM): straight breaks of the terrain "
        "itself (dams, embankments, terrace edges) stay ground; so does the ground showing "
        "between objects, which holds that surface too: a cell curved up both ways with an "
        "object within half a window on either side along its row or column, at the lowest "
        "level within a window, below those objects and not below the surface made without it "
        "(in a wood whose lowest points hit a shrub or a crown every few cells, every ground "
        "cell is that near one, and the surface came from beyond the wood, sagging metres under "
        "a knoll: a forest lidar tile at 1 m, 6.4 -&gt; 4.5 % total error), and so does the lower envelope "
        "between crowns: a cell no higher than the tolerance above every chord between the cells within half "
        "a window on either side along its row and its column, at the ground's level (above the lowest cell "
        "within a window by no more than the rise, over the window's diagonal, of the steeper of the "
        "terrain's steep slope and its local slope, the slope of the running minimum over 20 m) and below "
        "every object cell within half a window by more than the ground's step (not on a flat part of a roof "
        "the profiles did not reach): on a "
        "wooded knoll the ground between two crowns is a saddle, no bowl, and the surface from the clearings "
        "sagged 2 m under it (the same tile at 2 m, 5.07 -&gt; 4.46 %; a lower envelope of low vegetation "
        "is taken for ground too: ISPRS samp51 at 1 m +0.3-0.4 points); concave breaks deeper than "
        "the minimum object height below the ground and the cells around them are low "
        "blunders (class 2). A ground cell between an object and ground lower by more than the "
        "ground's own step (the tolerance, the terrain's slope over a cell and the ground's fall "
        "beyond) is on the object's wall: at 2 m cells and coarser a wall spreads over the cell "
        "beside it (a roof's eave, a crown's rim), which no break sets apart. A cell may stand above that "
        "surface by the tolerance plus its slope's rise over a cell (a height is a point anywhere in its cell), "
        "and a convex break no profile found inside an object by half the minimum object height more (the "
        "surface sags under a dam's crest); a peak gets the tolerance alone: a cell standing above a chord "
        "between the cells within half a window on either side by more than the tolerance plus its slope's "
        "rise, and above both ends of that chord, along its row, its column and both diagonals. A shrub or a "
        "crown's lowest return stands so above the ground around it; a cell on a slope, a terrain edge "
        "(straight or crossed obliquely) or a ledge lies on its chords along the edge, and a gully's rim "
        "lies below the ground beyond it (low vegetation 0.4-0.8 m high stood within the convex breaks' "
        "allowance of 0.8 m: ISPRS samp31 at 1 m 2.41 -&gt; 2.17 %, opengeos at 2 m 7.14 -&gt; 6.97 %). "
        "A cell above its chords every way by the tolerance alone (a plane lies on its chords) seeds no ground "
        "surface either: a shrub one cell wide bends the window's trend by its height / (17.5 cell<sup>2</sup>), "
        "under the threshold's floor at 2 m cells, so it was no break, the surface ran through it and it "
        "stayed ground (ISPRS samp11 at 2 m highest point 29.1 -&gt; 28.0 %, lidar Topography at 2 m "
        "4.36 -&gt; 3.87 %, autzen_trim at 2 m 3.13 -&gt; 2.47 %, opengeos at 2 m 6.97 -&gt; 6.51 %).</p>"
        "<p><b>The paper's bilinear surface</b> z = a0 + a1 X + a2 Y + a3 XY (eq. 12) is "
        "available as the <i>bilinear</i> model. It has a limit: fitted to the points of "
        "one profile it is degenerate (with Y constant, a2 and a3 cannot be separated), so "
        "it is fitted here to the window of neighbouring profiles; and its second "
        "derivatives are r = t = 0, so r t - s<sup>2</sup> = -a3<sup>2</sup> is never "
        "positive: it cannot tell convex from concave and sees only twisted breaks "
        "(corners), not straight edges. The default quadratic surface has none of these "
        "limits.</p>"
        "<p>Defaults: K<sub>g</sub> = (1.5 robust standard deviations of the profile bends "
        "of the ground: cells whose whole window stands at ground level, combined in "
        "quadrature with the bend that a height's place inside its cell gives the fit on "
        "ground of the median slope s: a cell's height is a point anywhere inside it, which "
        "moves it by s x cell / sqrt(12); the smoothest ground tiles are flat and do not "
        "show it, and at 2-4 m cells it marked a third of a sloping plane as "
        "breaks; the bends' spread is scaled by the share of the ground-level cells' height spread that "
        "is the sensor's noise, the cleanest quarter of the tiles against the whole: low vegetation among "
        "the ground cells, which touches most tiles on a highest-point DSM of a vegetated hillside, bends "
        "the fit as much as it moves the heights, and ISPRS samp11 at 2 m highest point took a threshold "
        "above the bend of a 3 m object, its shrubs ground: 33.0 -&gt; 29.1 %)<sup>2</sup>; the "
        "paper derives K<sub>g</sub> from the data's curvature, and on a closed canopy the "
        "smooth parts are crowns, whose bends set K<sub>g</sub> a hundred times too high "
        "(no break found, half the cells wrong). Tolerance = 3 x the noise of the DSM's "
        "ground-level cells (0.3 to 1 m). K<sub>g</sub> is in 1/m<sup>2</sup>: the bend "
        "noise of the fit falls with the square of the cell (with the cell alone where the "
        "place of the heights on a slope sets it), so it differs between cell sizes by design. "
        "A wall's slope is judged over two cells, but over 3 m at most: "
        "a vertical wall is smeared over two cells, and at 4 m cells a 45&deg; slope over "
        "two cells would demand 8 m of rise, so shrubs, hedges and houses would never be "
        "walls. Nor is a rise the terrain itself makes over two cells: the rise of its steep "
        "slopes (the upper quartile of the slopes of 20 m block minima) over two cells is "
        "the least a wall must rise; at 20-30 m cells (SRTM, Copernicus) the foot of every "
        "hillside rising from a valley floor was a wall and its run an object (15 % of a "
        "24 m terrain model of hills), and objects lower than that rise are not seen there "
        "(the log gives the rise used along X and Y). Where two cells span more than those 3 m "
        "(cells coarser than 1.5 m, or heights farther apart) a wall must also rise more than the "
        "terrain's own slope where it stands does over two cells (with the scatter of the "
        "heights' places in their cells), up to the wall slope's rise over the two cells: the slope along the "
        "profile of the running minimum over 20 m (objects narrower vanish from it), the steepest "
        "within 10 m and two cells (the minimum moves a flank's slope that far up it). The tile's "
        "upper quartile is a flat tile's slope where only knolls and outcrops are steep, and at 4 m "
        "cells their flanks rose 3-4.6 m within two cells, past the 3 m a wall needs: lidar "
        "Topography at 4 m 3.85 -&gt; 3.11 %, 8 % of its ground profile objects. A hall wider than "
        "20 m reads its own height over the minimum's span there, less than its wall rises at 1-4 m "
        "cells. The OUTPUT_CURVATURE output (band 1 "
        "K in 1/m<sup>2</sup>, band 2 H in "
        "1/m) shows what the filter saw; the log gives K<sub>g</sub> and the share of "
        "cells marked by X and by Y profiles. The curvature is attenuated within "
        "<i>window</i>/2 cells of the raster's edge (the edge is extended as a plane).</p>"
        "<p>Reference: Luong Chinh Ke (2002), filtering of DSM, section 2.2.</p>"),
)
