"""Parameters of the geodesic filter: their specs, defaults derived from the data, checks,
the step sizes and the method's reach (halo)."""
from typing import Tuple, Union

import numpy as np

from ..common import as_cell_size, as_surface, report, sub_progress
from ..estimate import RAISED_REGION_MAX_M, block_minima, noise_ground_level, raised_region_window, surroundings_reach
from ..methods import Param, check_values
from .dilation import BORDER_RINGS, EXTENT_FACTOR, WALL_BASE_M, coarse_factor
from .grey import grey_opening, window_cells
from .outliers import OUTLIER_MAX_CELLS
from .scan import OBLIQUE_REACH

#: The default largest object before it was derived (models saved then store it: no refusal on small rasters).
OBJECT_SIZE_M_BEFORE = 64.0
#: The user parameters (dialog order); their bounds are the limits the core enforces.
PARAMS = (
    Param("min_window_m", "float", 2.0, "Side of the first structuring element in "
          "metres; the following steps double it up to the maximum object size.",
          minimum=0.1, maximum=1000.0),
    Param("max_object_size_m", "float", None, "Largest object to remove (side of the "
          "last structuring element) in metres: the widest building. Scan labelling takes "
          "runs up to this length, or up to sqrt(2) times it between two walls (a building "
          "rotated in the grid). Empty: 64 m, widened (with raised regions on) to 1.25 x the "
          "width of a raised region standing on walls that a 64 m window does not reach "
          "across + 2 cells (a hall, a roof cut by the raster's edge), at most 200 m.",
          minimum=0.5, maximum=5000.0, former_defaults=(OBJECT_SIZE_M_BEFORE,)),
    Param("height_threshold_m", "float", None, "Minimal object height dh0 above the "
          "reconstructed terrain in metres; empty: max(0.5, 3 x the noise of the DSM's ground-level cells).",
          minimum=0.01, maximum=100.0),
    Param("terrain_slope_deg", "float", None, "Terrain slope in degrees tolerated by "
          "the wall test, the height test and scan labelling; empty: 90th percentile "
          "slope of the heavily opened DSM, clipped to 12-22 degrees.",
          minimum=0.0, maximum=89.0, advanced=True),
    Param("edge_ratio", "float", 0.55, "Height heterogeneity threshold (0-1): a "
          "region the reconstruction cannot reach is an object when at least this "
          "fraction of its border cells stand above a cell within 1 m by more than "
          "2 dh0 plus the terrain's rise over that distance (walls jump, hills rise "
          "gently).",
          minimum=0.0, maximum=1.0, advanced=True),
    Param("outlier_threshold_m", "float", None, "Preprocessing: a small cluster this "
          "far below the closing (above the opening) is a low (high) outlier, metres; "
          "empty: max(2, 4 x dh0).", minimum=0.01, maximum=1000.0, advanced=True),
    Param("outlier_width_m", "float", 2.0, "Preprocessing: window of the closing and "
          "opening that find isolated outliers, metres.", minimum=0.1, maximum=100.0,
          advanced=True),
    Param("scan_labelling", "bool", True, "Run scan labelling along rows and columns "
          "after the dilation steps (removes what the dilation left).", advanced=True),
    Param("raised_regions", "bool", True, "When the largest object is derived: widen it from "
          "64 m to 1.25 x the width + 2 cells of the widest raised region wider than 64 m standing on "
          "walls of 2 dh0 (a hall, a roof cut by the raster's edge), at most 200 m, so its last step "
          "removes it. A given largest object is used as given.", advanced=True),
)
#: Default of every parameter (None: derived from the data by :func:`resolve_geodesic_params`).
DEFAULTS = {p.name: p.default for p in PARAMS}
_MAXIMUM = {p.name: p.maximum for p in PARAMS}
#: Default terrain slope: this percentile of the slope of the heavily opened DSM ...
SLOPE_PERCENTILE = 90
#: ... clipped to these degrees (a tolerance, not the steepest slope: on the ISPRS
#: samples above ~25 degrees walls on hillsides pass as terrain).
SLOPE_CLIP_DEG = (12.0, 22.0)
#: Default dh0 = max(0.5 m, NOISE_K x robust noise of the DSM).
NOISE_K = 3.0
#: Largest object (side of the last structuring element), metres, unless a wider raised region
#: standing on walls widens it (:func:`resolve_geodesic_params`).
OBJECT_SIZE_M = 64.0
#: The raised regions are looked for on a grid of at most this many cells (block minima).
RESOLVE_CELLS = 1_000_000


def _terrain_slope_deg(z, dx, dy, max_size_m):
    """Robust steep-terrain slope: 90th percentile slope of the largest-window opening,
    computed on a grid coarsened to about 4 m (or the cell) so objects are gone."""
    f = max(1, int(round(4.0 / max(dx, dy))))
    H, W = z.shape
    Hc, Wc = H // f, W // f
    if Hc < 3 or Wc < 3:
        f, Hc, Wc = 1, H, W
    zc = block_minima(z[:Hc * f, :Wc * f], f)    # whole blocks only
    vc = np.isfinite(zc)
    if vc.sum() < 9:
        return 30.0
    size = window_cells(max_size_m, dx * f, dy * f)
    o = grey_opening(zc, vc, size)
    o = np.where(vc & np.isfinite(o), o, np.nan)
    if min(o.shape) < 2:
        return SLOPE_CLIP_DEG[0]
    gy, gx = np.gradient(o, dy * f, dx * f)
    s = np.hypot(gx, gy)
    s = s[np.isfinite(s)]
    if s.size == 0:
        return 30.0
    return float(np.clip(np.degrees(np.arctan(np.percentile(s, SLOPE_PERCENTILE))),
                         *SLOPE_CLIP_DEG))


def _object_size_m(z, dx, dy, dh0, raised_regions):
    """The derived largest object: :data:`OBJECT_SIZE_M`, widened to the window of a wider raised
    region standing on walls of ``2 dh0`` (``raised_regions``), on block minima of at most
    :data:`RESOLVE_CELLS` cells."""
    if not raised_regions:
        return OBJECT_SIZE_M
    k = max(1, int(np.ceil(np.sqrt(z.size / RESOLVE_CELLS))))
    zs = block_minima(z, k) if k > 1 else z
    window = raised_region_window(zs, (dx * k, dy * k), 2.0 * dh0, OBJECT_SIZE_M)
    return round(max(OBJECT_SIZE_M, min(window, RAISED_REGION_MAX_M)), 1)


def resolve_geodesic_params(z: np.ndarray, cell_size: Union[float, Tuple[float, float]], progress=None,
                            **params) -> dict:
    """Complete the parameters of :func:`filter_geodesic`, deriving ``None`` from the data.

    * ``height_threshold_m`` (dh0): ``max(0.5, 3 sigma)`` (at most its Param's maximum) with ``sigma`` the robust noise
      of the DSM (lower quartile of the absolute second differences, scaled to a normal
      sigma: edges and objects fill the upper tail and barely move it;
      :func:`~bare_earth.core.estimate.noise_second_difference_quartile`).
    * ``outlier_threshold_m``: ``max(2.0, 4 dh0)``.
    * ``max_object_size_m``: :data:`OBJECT_SIZE_M` (64 m); with ``raised_regions``, widened to
      the window of the widest raised region standing on walls that is wider than it
      (:func:`~bare_earth.core.estimate.raised_region_window`: 1.25 x its width + 2 cells, at
      most 200 m; walls of ``2 dh0``, the dilation's wall height, on the block minima of a grid of
      at most :data:`RESOLVE_CELLS`). Such a region (a hall, a roof cut by the raster's edge,
      which the window truncated at the edge fits into) is what the 64 m step cannot reach
      across: its opening keeps the roof, and the reconstruction then calls it terrain (issue
      12: synthetic-lidar/mixed at 1 m, a hall of 82 m and a roof cut by the tile's edge kept,
      total 5.94 %).
    * ``terrain_slope_deg``: 90th percentile slope of the surface opened by the largest
      window on a ~4 m grid (objects gone), clipped to [12, 22] degrees: it is the slope
      *tolerated* by the wall and rise tests, and on the ISPRS samples a tolerance above
      ~25 degrees lets walls on hillsides pass as terrain (see :data:`SLOPE_CLIP_DEG`).

    ``progress(fraction)`` (optional, may raise ``Cancelled``) from inside the estimates.

    Raises
    ------
    ValueError
        Unknown parameter names or values out of range.
    """
    unknown = set(params) - set(DEFAULTS)
    if unknown:
        raise ValueError(f"unknown geodesic parameter(s) {sorted(unknown)}; "
                         f"valid names: {sorted(DEFAULTS)}.")
    z = as_surface(z)
    dx, dy = as_cell_size(cell_size)
    p = dict(DEFAULTS)
    p.update({k: v for k, v in params.items() if v is not None})
    check_params(p)
    if p["height_threshold_m"] is None:
        sigma = noise_ground_level(z, (dx, dy), progress=sub_progress(progress, 0.0, 0.6))["sigma"]
        dh0 = max(0.5, NOISE_K * sigma) if np.isfinite(sigma) else 0.5
        p["height_threshold_m"] = round(min(dh0, _MAXIMUM["height_threshold_m"]), 3)
    if p["outlier_threshold_m"] is None:
        p["outlier_threshold_m"] = round(max(2.0, 4 * p["height_threshold_m"]), 3)
    report(progress, 0.6)
    if p["max_object_size_m"] is None:
        p["max_object_size_m"] = _object_size_m(z, dx, dy, p["height_threshold_m"], p["raised_regions"])
    report(progress, 0.8)
    if p["terrain_slope_deg"] is None:
        p["terrain_slope_deg"] = round(_terrain_slope_deg(z, dx, dy, p["max_object_size_m"]), 2)
    check_params(p)
    return p


def check_params(p):
    """Raise ValueError for a parameter outside its :data:`PARAMS` bounds (None values,
    still to be derived, pass). A first window larger than the largest object is no error:
    :func:`step_sizes` then runs one step of ``max_object_size_m``."""
    check_values("geodesic", PARAMS, p)


def step_sizes(min_window_m, max_object_size_m):
    """Structuring-element sizes in metres: doubling from min to max (last = max; only max
    when min is not below it)."""
    sizes = []
    s = float(min_window_m)
    while s < max_object_size_m * 0.999:
        sizes.append(s)
        s *= 2.0
    sizes.append(float(max_object_size_m))
    if len(sizes) > 250:
        raise ValueError("too many dilation steps; raise min_window_m or lower "
                         "max_object_size_m.")
    return sizes


def geodesic_halo(params, cell_size):
    """Reach of :func:`filter_geodesic` in cells.

    A cell's residual at the largest step (side ``S = max_object_size_m``) reads ``z``
    within its opening (two half-windows: ``S``) and its geodesic reconstruction (reach
    ``S``); a region spans at most ``EXTENT_FACTOR * S``, so a decision reads ``z``
    within ``(2 + EXTENT_FACTOR) S``. Scan labelling adds two passes of runs up to
    ``OBLIQUE_REACH * S`` (an object crossed obliquely: ``2 sqrt(2) S``), each read with the
    climbs to its edges, no wider than a one-wall run (:func:`~.scan.climb_feet`: ``2 S``
    more); the preprocessing
    two outlier windows and a cluster, and the ring of its pit tests
    (:func:`~bare_earth.core.estimate.surroundings_reach`); the borders (stage 4) :data:`~.dilation.BORDER_RINGS`
    rings and the ground within as many cells of the last; the islands (stage
    5) at most the first window's cells and their ring. The halo is rounded
    up to a multiple of the largest coarsening factor, so that blocks whose edge is a
    multiple of it (the default 2048 is) see the same coarse grids as one pass.
    """
    dx, dy = as_cell_size(cell_size)
    c = min(dx, dy)
    size = float(params.get("max_object_size_m") or OBJECT_SIZE_M)
    width = float(params.get("outlier_width_m", DEFAULTS["outlier_width_m"]))
    params = dict(DEFAULTS, **{k: v for k, v in params.items() if v is not None})
    params["max_object_size_m"] = size
    island = int(np.prod(window_cells(min(params["min_window_m"], size), dx, dy))) + 1
    reach = (int(np.ceil(((4 + 2 * OBLIQUE_REACH + EXTENT_FACTOR) * size + 2 * width + WALL_BASE_M) / c))
             + OUTLIER_MAX_CELLS + 8 + island + 2 * BORDER_RINGS + max(surroundings_reach((dx, dy))[2:]))
    # coarse steps use grids aligned on the block origin: keep blocks aligned on them
    f = max(coarse_factor(window_cells(s, dx, dy))
            for s in step_sizes(params["min_window_m"], params["max_object_size_m"]))
    return int(-(-reach // f) * f)


