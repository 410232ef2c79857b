"""RASCOR's sequence of steps (Jacobsen 2004): :func:`filter_rascor`.

The enabled steps run in the paper's order on the points the previous ones left: 2 height
distribution, 3 neighbour differences, 4 sudden change of level, 5 moving local profiles,
6 moving surfaces, 7 local prediction (step 1, the terrain characterisation, decides the
class in :func:`~.parameters.resolve_rascor_params`). A second iteration repeats 3, 5, 6
(7); without it, step 3 alone runs once more at the end (``step3_repeat``: its test of a
cell against its neighbours changes once the later steps removed a neighbour). Each step
is a named function here; the filters themselves live in :mod:`.steps` and :mod:`.moving`.
"""
from dataclasses import dataclass, field
from typing import Callable, Iterable, Optional, Sequence, Union

import numpy as np
from scipy import ndimage

from ..codes import LOW, NODATA, OBJECT
from ..common import (
    FilterResult,
    as_cell_size,
    as_surface,
    dilate_box,
    label8,
    report,
    sub_progress,
    touching,
    transpose,
)
from ..dtm_refine import REACH_M, SMOOTH_RATIO, continuation_cells, continue_ground
from ..estimate import PIT_CLUSTER_M, PIT_RADIUS_M, below_level_rim, below_surroundings, surroundings_reach
from .kernels import odd_window
from .moving import remove_prediction_outliers, remove_profile_outliers, remove_surface_outliers, slope_breaks
from .regions import as_bool_raster, break_regions, find_ramps, profile_runs
from .steps import (
    enclosed_levels,
    find_terrain_steps,
    joined_levels,
    remove_height_outliers,
    remove_level_changes,
    remove_neighbour_differences,
)
from .terrain import TERRAIN_CLASSES, as_homogeneous, model_degree

#: Step numbers and names (the values of the ``step`` extra).
STEP_NAMES = {1: "terrain characterisation", 2: "height distribution",
              3: "neighbour height differences", 4: "sudden change of level",
              5: "moving local profiles", 6: "moving surfaces", 7: "local prediction"}
#: Steps repeated by the second iteration.
_REPEATED = (3, 5, 6, 7)
#: Relative run time of each step, the share of the progress bar it gets (seconds measured
#: on the 16 Mcells city of ``synthetic.make_dsm`` at 1 m, in the sequence: 0.05, 1.0-1.4,
#: 1.2, 3.1, 1.8; step 7 alone 3.0; step 4's terrain steps add 0.63 x its level changes,
#: measured on a 4 Mcells city).
_COST = {2: 0.05, 3: 1.0, 4: 2.0, 5: 3.0, 6: 2.0, 7: 3.0}


@dataclass
class _Settings:
    """The checked parameters of one run."""
    cell: tuple
    terrain_class: str
    homogeneous: bool
    sigma_m: float
    on: dict
    second_iteration: bool
    step3_repeat: bool
    height_min_m: Optional[float]
    height_max_m: Optional[float]
    neighbour_k: float
    terrain_slope: float
    terrain_bend_m: float
    ground_sigma_m: float
    jump_m: float
    max_building_m: float
    max_hall_m: float
    lengths: list
    surface_size_m: float
    prediction_radius_m: float
    profile_sigma_m: float
    surface_sigma_m: float
    prediction_sigma_m: float
    snooping_k: float
    snooping_iterations: int
    low_weight: float
    fits_per_block: bool = False
    spare_continuing_ground: bool = True


@dataclass
class _State:
    """The points left and what each step removed."""
    z: np.ndarray
    valid: np.ndarray
    keep: np.ndarray
    global_ok: np.ndarray                 # valid and outside the special areas
    special: Optional[np.ndarray]
    labels: Optional[np.ndarray]
    n_regions: int
    breaklines: Optional[np.ndarray]      # the user's break lines (rasterised)
    mask: np.ndarray
    step: np.ndarray
    removed: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    pit: Optional["_Pits"] = None         # cells below every cell of the ring around them
    step_lines: int = 0                   # cells of the terrain's level changes (step 4)
    spared: int = 0                       # objects of steps 5-6 given back as continuing ground
    step_restored: int = 0                # step 3's wall tops given back at the terrain's level changes
    z_t: Optional[np.ndarray] = None      # z transposed (the Y profiles of steps 4 and 5), made once
    lines: Optional[np.ndarray] = None    # the break lines: the user's and the terrain's level changes

    def transposed(self):
        """``z`` transposed (C-contiguous), made on first use and kept for the later steps."""
        if self.z_t is None:
            self.z_t = transpose(self.z)
        return self.z_t


def cell_rise(terrain_slope: float, cell_size: Union[float, Sequence[float]]) -> tuple:
    """``(along X, along Y)``: the rise (m) of ``terrain_slope`` (rise/run) over one cell,
    step 3's allowance for the position of a height inside its cell."""
    dx, dy = as_cell_size(cell_size)
    return float(terrain_slope) * dx, float(terrain_slope) * dy


def ring_reach(cell_size: Union[float, Sequence[float]]) -> tuple:
    """``(rows, cols)``: how far, in cells, the low blunders' ring test reaches from the
    tested cell (:func:`~bare_earth.core.estimate.below_surroundings` with its default
    ``PIT_RADIUS_M`` and ``PIT_CLUSTER_M``): the ring's radius, and at least the cluster
    + 2 cells and 4 cells, along each axis."""
    return surroundings_reach(as_cell_size(cell_size), PIT_RADIUS_M, PIT_CLUSTER_M)[2:]


class _Pits:
    """The cells lying more than ``depth_m`` below every cell of the ring around them
    (:func:`~bare_earth.core.estimate.below_surroundings`) or of the level rim just outside
    their cluster (:func:`~bare_earth.core.estimate.below_level_rim`, level within the rise
    of the terrain slope ``slope``: two blunders within each other's ring, issue 12),
    evaluated at the cells asked about only, each once.

    The test depends on the DSM alone (not on the points the steps left), and the low
    blunder candidates of a step are few (4,500 of the 9.5 Mcells of a 16 Mcells city
    strip): ``below_surroundings`` is asked at those cells only (``candidates``), which
    gathers their rings instead of filtering the whole array, and the answers are kept, so
    a cell asked about again by a later step is not tested twice.
    """

    def __init__(self, z, cell, depth_m, slope=0.0):
        self.z, self.cell, self.depth, self.slope = z, cell, depth_m, slope
        self.known = np.zeros(z.shape, bool)     # cells tested so far
        self.pit = np.zeros(z.shape, bool)       # ... and their answers

    def at(self, idx):
        """Whether each cell of ``idx`` (flat indices) is a pit (boolean array)."""
        known = self.known.reshape(-1)
        need = idx[~known[idx]]
        if need.size:
            ask = np.zeros(self.z.shape, bool)
            ask.reshape(-1)[need] = True
            self.pit |= below_surroundings(self.z, self.cell, self.depth, radius_m=PIT_RADIUS_M,
                                           cluster_m=PIT_CLUSTER_M, candidates=ask)
            ask &= ~self.pit
            self.pit |= below_level_rim(self.z, self.cell, self.depth, self.slope, ask,
                                        cluster_m=PIT_CLUSTER_M)
            known[need] = True
        return self.pit.reshape(-1)[idx]


def _check_settings(cell_size, *, terrain_class, homogeneous, sigma_m, switches, steps,
                    second_iteration, height_min_m, height_max_m, neighbour_k, terrain_slope, terrain_bend_m,
                    jump_m, max_building_m, max_hall_m, short_profile_m, long_profile_m, profile_sigma_m,
                    surface_size_m, surface_sigma_m, prediction_radius_m, prediction_sigma_m,
                    snooping_k, snooping_iterations, low_weight, fits_per_block=False, step3_repeat=True,
                    spare_continuing_ground=True, ground_sigma_m=None):
    """Check the parameters (ValueError naming the fix) and return the :class:`_Settings`."""
    dx, dy = as_cell_size(cell_size)
    if terrain_class not in TERRAIN_CLASSES:
        raise ValueError(f"terrain_class must be one of {TERRAIN_CLASSES}; got {terrain_class!r}. "
                         "Pass 'auto' to resolve_rascor_params to derive it (step 1).")
    homogeneous = as_homogeneous(homogeneous)
    for name, val in (("sigma_m", sigma_m), ("jump_m", jump_m), ("max_building_m", max_building_m),
                      ("short_profile_m", short_profile_m), ("long_profile_m", long_profile_m),
                      ("surface_size_m", surface_size_m), ("prediction_radius_m", prediction_radius_m),
                      ("snooping_k", snooping_k), ("neighbour_k", neighbour_k)):
        if val is None or not np.isfinite(val) or val <= 0:
            raise ValueError(f"{name} must be a positive number; got {val!r}. Pass a value or "
                             "call resolve_rascor_params to derive it from the DSM.")
    if terrain_slope is None or not np.isfinite(terrain_slope) or terrain_slope < 0:
        raise ValueError(f"terrain_slope must be a number >= 0 (rise/run); got {terrain_slope!r}. "
                         "Pass 0 for the paper's step 3 tolerance alone, or call resolve_rascor_params "
                         "to derive it (step 1's median slope).")
    if max_hall_m is None or not np.isfinite(max_hall_m) or max_hall_m < 0:
        raise ValueError(f"max_hall_m must be a number >= 0 (metres); got {max_hall_m!r}. Pass 0 for "
                         "step 4's pairs of jumps alone, or call resolve_rascor_params to derive it (the "
                         "longest level closed by walls).")
    if terrain_bend_m is None or not np.isfinite(terrain_bend_m) or terrain_bend_m < 0:
        raise ValueError(f"terrain_bend_m must be a number >= 0 (metres); got {terrain_bend_m!r}. "
                         "Pass 0 for the paper's tolerances of steps 3 and 4, or call "
                         "resolve_rascor_params to derive it (the bends of the block minima).")
    if ground_sigma_m is None:
        ground_sigma_m = sigma_m
    if not np.isfinite(ground_sigma_m) or ground_sigma_m <= 0:
        raise ValueError(f"ground_sigma_m must be a positive number (metres); got {ground_sigma_m!r}. Leave it "
                         "empty for sigma_m, or call resolve_rascor_params to derive it (the noise of the "
                         "ground-level cells).")
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
        on = dict(zip(range(1, 8), switches))
    lengths = [short_profile_m] if long_profile_m <= short_profile_m else [short_profile_m,
                                                                          long_profile_m]
    return _Settings(
        cell=(dx, dy), terrain_class=terrain_class, homogeneous=homogeneous, sigma_m=sigma_m,
        on=on, second_iteration=bool(second_iteration), step3_repeat=bool(step3_repeat),
        height_min_m=height_min_m,
        height_max_m=height_max_m, neighbour_k=neighbour_k, terrain_slope=float(terrain_slope),
        terrain_bend_m=float(terrain_bend_m), ground_sigma_m=float(ground_sigma_m), jump_m=jump_m,
        max_building_m=max_building_m,
        max_hall_m=float(max_hall_m), lengths=lengths,
        surface_size_m=surface_size_m,
        prediction_radius_m=prediction_radius_m,
        profile_sigma_m=max(sigma_m, profile_sigma_m or sigma_m),
        surface_sigma_m=max(sigma_m, surface_sigma_m or sigma_m),
        prediction_sigma_m=max(sigma_m, prediction_sigma_m or sigma_m),
        snooping_k=snooping_k, snooping_iterations=int(snooping_iterations),
        low_weight=low_weight, fits_per_block=bool(fits_per_block),
        spare_continuing_ground=bool(spare_continuing_ground))


def _start(z, breaklines, special_areas):
    """All valid points kept; the break-line regions and special areas (Jacobsen 2004)."""
    bl = as_bool_raster(breaklines, z.shape, "breaklines")
    sp = as_bool_raster(special_areas, z.shape, "special_areas")
    labels, n_regions = (None, 0) if bl is None else break_regions(bl)
    valid = np.isfinite(z)
    return _State(z=z, valid=valid, keep=valid.copy(),
                  global_ok=valid if sp is None else valid & ~sp, special=sp, labels=labels,
                  n_regions=n_regions, breaklines=bl, mask=np.zeros(z.shape, np.uint8),
                  step=np.zeros(z.shape, np.uint8))


def _plan(cfg, st):
    """The steps to run, in order: the enabled ones (step 7 always inside special areas),
    then those the second iteration repeats, or without it step 3 once more
    (``step3_repeat``: :func:`_step3_neighbour_differences`)."""
    first = [k for k in (2, 3, 4, 5, 6, 7) if cfg.on[k] or (k == 7 and st.special is not None)]
    if cfg.second_iteration:
        again = [k for k in first if k in _REPEATED]
    else:
        again = [3] if cfg.step3_repeat and 3 in first and len(first) > first.index(3) + 1 else []
    return first + again


def _record(st, k, hi, lo):
    """Remove the points step ``k`` found: objects (1) and low blunders (2).

    By the flat indices of the cells found (a step finds a few per cent of the cells at
    most), not by passes over the whole rasters.
    """
    keep = st.keep.reshape(-1)
    new_hi = np.flatnonzero(hi)
    new_hi = new_hi[keep[new_hi]]
    new_lo = np.flatnonzero(lo)
    new_lo = new_lo[keep[new_lo] & ~hi.reshape(-1)[new_lo]]
    if st.pit is not None and new_lo.size:  # a low blunder lies below all the ground around it
        new_lo = new_lo[st.pit.at(new_lo)]
    for idx, code in ((new_hi, OBJECT), (new_lo, LOW)):
        st.mask.reshape(-1)[idx] = code
        st.step.reshape(-1)[idx] = k
        keep[idx] = False
    st.removed[k] = st.removed.get(k, 0) + int(new_hi.size + new_lo.size)


def _step2_height_distribution(st, cfg, progress):
    """Step 2, flat terrain only: heights far outside the height distribution."""
    if cfg.terrain_class == "flat" and cfg.height_min_m is not None and cfg.height_max_m is not None:
        hi, lo = remove_height_outliers(st.z, st.keep & st.global_ok, cfg.height_min_m,
                                        cfg.height_max_m)
        _record(st, 2, hi, lo)
    else:
        st.notes.append("2: height distribution skipped (terrain is "
                        f"{cfg.terrain_class}, the step applies to flat areas only)")


def _step3_neighbour_differences(st, cfg, progress):
    """Step 3: the upper point of neighbouring pairs differing beyond the tolerance.

    Run again after the later steps (``step3_repeat``, or the second iteration): a cell
    whose inner neighbour rises as steeply as its step down passes the first run as the toe
    of a slope (:func:`~.steps.remove_neighbour_differences`); the edge of a crown or a roof
    passes that way too, while the crown or roof above it stands. Once steps 4-6 removed
    that neighbour, the edge is tested against the ground alone (the opengeos 2 m city:
    16.9 -> 11.1 % total error, its DTM's RMSE 1.20 -> 0.95 m)."""
    hi, lo = remove_neighbour_differences(st.z, st.keep, sigma_m=cfg.sigma_m, k=cfg.neighbour_k,
                                          low_weight=cfg.low_weight, labels=st.labels,
                                          cell_rise_m=cell_rise(cfg.terrain_slope, cfg.cell),
                                          bend_m=cfg.terrain_bend_m, ground_sigma_m=cfg.ground_sigma_m,
                                          progress=progress)
    _record(st, 3, hi, lo)


def _step3_tolerance(cfg):
    """Step 3's tolerance of a difference of two heights (m): ``k sqrt(2) sigma``, widened in
    quadrature by ``k`` times the terrain's bend (:func:`~.steps.remove_neighbour_differences`
    without the allowance for a height's position inside its cell)."""
    return float(np.hypot(cfg.neighbour_k * cfg.sigma_m * np.sqrt(2.0), cfg.neighbour_k * cfg.terrain_bend_m))


def level_step(neighbour_k: float, sigma_m: float, terrain_bend_m: float, jump_m: float,
               rise_m: float = 0.0) -> float:
    """The largest difference (m) of neighbouring heights within one level of step 4
    (:func:`~.steps.joined_levels`, :func:`~.steps.enclosed_levels`): step 3's tolerance of a pair,
    ``k sqrt(2) sigma`` widened in quadrature by ``k`` times the terrain's bend (no level change to
    step 3), and less than half the jump (the height step 4 asks of a raised point above the
    ground's line).

    With ``rise_m`` > 0 (the terrain's rise over one cell, :func:`cell_rise`), the ground it joins
    slopes: two neighbouring heights on it differ by that rise, and by the tolerance step 3 gives a
    pair there (:func:`~.steps.remove_neighbour_differences`: ``k sqrt(2) sigma`` widened in
    quadrature by ``k g / sqrt(6)``, a height's position inside its cell on ground rising ``g``
    over the cell), so the step is ``g + sqrt(tol^2 + k^2 g^2 / 6)``. The rise grows with the cell:
    at 2 m the crown of a road embankment rising along the road, or crossed at a slant, left its
    neighbours by more than ``k sqrt(2) sigma`` and its parts were cut shorter than the longest
    building (ISPRS 61, 2 m lowest 6.03 -> 5.66 %, highest 5.85 -> 5.48 %).

    Examples
    --------
    >>> round(level_step(3.0, 0.1, 0.0, 2.0), 4)            # k sqrt(2) sigma
    0.4243
    >>> round(level_step(3.0, 0.1, 0.0, 2.0, rise_m=0.2), 4)  # 0.2 + sqrt(0.424^2 + 9 0.04 / 6)
    0.6899
    >>> level_step(3.0, 0.1, 0.0, 2.0, rise_m=5.0)          # at most half the jump
    1.0
    """
    tol = float(np.hypot(neighbour_k * sigma_m * np.sqrt(2.0), neighbour_k * terrain_bend_m))
    g = max(0.0, float(rise_m))
    if g > 0:
        tol = float(np.hypot(tol, neighbour_k * g / np.sqrt(6.0))) + g
    return min(tol, 0.5 * float(jump_m))


def _terrain_step_jump(cfg):
    """The smallest level change (m) :func:`~.steps.find_terrain_steps` looks at: step 3's
    ``k sqrt(2) sigma`` (widened by the bend there as step 3's is), at most step 4's jump.

    Step 3 takes the upper edge of any level change beyond its tolerance for an object's edge.
    On coarse cells the terrain's own banks and shoulders drop by that much within one cell
    (a 1 m river bank or a road embankment's side is one 4 m cell wide; at 1 m it spans
    several cells and no pair sees more than the slope), yet stay under step 4's 2 m jump, so
    no terrain step protected them: ``lidar/autzen_trim`` at 4 m lost its river bank, 9.6 %
    of its ground points. A level change larger than step 3's tolerance that no other answers
    over more than the longest building is the terrain's whatever its height."""
    return min(float(cfg.jump_m), cfg.neighbour_k * cfg.sigma_m * float(np.sqrt(2.0)))


def _step4_level_change(st, cfg, progress):
    """Step 4: raised levels between a jump up and a jump down (buildings); the level changes
    beyond step 3's tolerance (:func:`_terrain_step_jump`) no jump answers over more than the
    longest building are the terrain's (a quarry bench, a river bank): break lines for the
    steps after (:func:`~.steps.find_terrain_steps`).

    A raised level the ground continues onto is no building (:func:`~.steps.joined_levels`):
    the kept cells joined across neighbouring heights that differ by no more than step 3's
    tolerance (``k sqrt(2) sigma``: no level change to step 3) and less than half the jump (the
    height step 4 asks of a raised point above the ground's line) into a part running further
    than the longest building. An embankment's crown between walls (its banks, made walls by
    sparse points, or steep) joined to the ground by a ramp or a gentler side is kept, a roof
    cut off by its walls is not (ISPRS 71, its bridge's ramps, 1 m lowest 5.75 -> 3.41 % total
    error, 2 m 8.26 -> 4.95; 61, its dike, 5.17 -> 4.31, 7.32 -> 7.08)."""
    hi = remove_level_changes(st.z, cfg.cell, st.keep, jump_m=cfg.jump_m,
                              max_building_m=cfg.max_building_m, sigma_m=cfg.sigma_m,
                              k=cfg.neighbour_k, bend_m=cfg.terrain_bend_m, labels=st.labels,
                              z_t=st.transposed(), cut_at_edge=True, progress=sub_progress(progress, 0.0, 0.6))
    # an embankment's crown the ground continues onto (a ramp, a gentler side) is no roof
    step_m = level_step(cfg.neighbour_k, cfg.sigma_m, cfg.terrain_bend_m, cfg.jump_m,
                        rise_m=max(cell_rise(cfg.terrain_slope, cfg.cell)))
    hi &= ~joined_levels(st.z, cfg.cell, hi, st.keep, step_m=step_m, max_building_m=cfg.max_building_m)
    # a hall longer than the longest building along both axes: a level its walls close on every side
    halls = None
    if cfg.max_hall_m > cfg.max_building_m:
        halls = enclosed_levels(st.z, cfg.cell, jump_m=cfg.jump_m, step_m=step_m, min_span_m=cfg.max_building_m,
                                max_span_m=cfg.max_hall_m, k=cfg.neighbour_k, bend_m=cfg.terrain_bend_m)
        hi |= halls
    _record(st, 4, hi & st.global_ok, np.zeros_like(hi))
    # the level changes longer than the longest building are the terrain's: break lines for
    # the steps after (Jacobsen's break lines along cuts, banks and terrace walls), each side of a
    # line a line of its own: a wall's top is compared along the top, never with its foot
    steps, upper = find_terrain_steps(st.z, cfg.cell, st.keep, jump_m=_terrain_step_jump(cfg),
                                      max_building_m=cfg.max_building_m, sigma_m=cfg.sigma_m, k=cfg.neighbour_k,
                                      bend_m=cfg.terrain_bend_m, labels=st.labels, z_t=st.transposed(),
                                      sides=True, join_gap_m=WALL_TOP_GAP_M, ground_sigma_m=cfg.ground_sigma_m,
                                      progress=sub_progress(progress, 0.6, 1.0))
    if halls is not None and halls.any():
        # a hall's walls are a building's, not the terrain's: the profiles over the points kept
        # cross its removed roof from ground to ground, a jump of the terrain's rise over its length
        near = touching(halls)
        steps &= ~near
        upper &= ~near
    st.step_lines = int(np.count_nonzero(steps))
    if st.step_lines:
        lines = steps if st.breaklines is None else steps | st.breaklines
        st.lines = lines
        st.labels, st.n_regions = break_regions(lines, upper if st.breaklines is None else upper & ~st.breaklines)
        report(progress, 1.0)
        _retest_step3_at_terrain_steps(st, cfg, steps)
        report(progress, 1.0)


def _joined_longer_than(cells, cell_size, length_m, gap_m=None):
    """The cells of ``cells`` whose groups, joined across gaps of up to ``gap_m`` metres
    (:data:`WALL_TOP_GAP_M`; the regions of ``cells`` grown by half of it, in whole cells: no
    joining where a cell is wider than half the gap), run further than ``length_m`` metres along
    the rows or the columns (``cell_size`` (dx, dy)), measured on the cells themselves."""
    dx, dy = as_cell_size(cell_size)
    gap = WALL_TOP_GAP_M if gap_m is None else float(gap_m)
    ry, rx = int(gap // (2 * dy)), int(gap // (2 * dx))
    if not (ry or rx):
        return longer_than(cells, cell_size, length_m)
    # the dilation by that rectangle: separable passes of shifted ORs (common.dilate_box; binary_dilation's
    # generic structure visits every cell of the rectangle at every cell: 3.5 s on 16 Mcells, SciPy's running
    # maxima of uint8 0.12 s, these 0.03 s)
    grown = dilate_box(cells, ry, rx)
    return longer_than(cells, cell_size, length_m, joined=grown)


#: Widest gap (metres) across which :func:`_retest_step3_at_terrain_steps` joins the pieces of a wall
#: top step 3 took, and :func:`~.steps.find_terrain_steps` the pieces of the terrain's level changes
#: (step 4): a bush on the edge or a gap in the data, a few metres (2 cells at 2 m, 4 at 1 m;
#: none at 4 m and coarser, where a gap of a cell would join crowns standing beside a terrace's wall).
WALL_TOP_GAP_M = 4.0
#: Tile edge (cells) of :func:`_retest_step3_at_terrain_steps` (a diagonal terrain step across 4 Mcells:
#: 0.30 s with tiles of 64 cells, 0.35 s of 128, 0.71 s of 256, at load 10 on 2 cores).
_RETEST_TILE = 64


def _retest_step3_at_terrain_steps(st, cfg, steps):
    """Step 3 again, with the terrain's level changes as break lines, on the cells it removed
    beside them.

    Step 3 runs before step 4 finds the terrain's level changes, so it compares the top of a
    quarry bench, a river bank or a terrace wall with the foot of the wall and removes the
    upper point of the pair (the wall tops: 4 % of a quarry of 6 m benches, 1 % of a river
    between walls). Jacobsen (2004) protects such edges with break lines, which no comparison
    crosses; had they been drawn, step 3 would have compared those cells with their own level
    only. The object cells step 3 removed within one cell of a line, in groups that run further
    than a building (a wall top runs along its wall; its pieces joined across gaps of up to
    :data:`WALL_TOP_GAP_M`, :func:`_joined_longer_than`: a gap in the data, a bush or a cell step 3
    kept cuts it),
    or that do so together with the lines they lie along (on a rough hillside at coarse cells step
    3 removed only every other cell of a terrace's edge, whose pieces alone are short), are tested
    again, with the lines' regions (:func:`~.regions.break_regions`), against the points kept, and
    given back where that test keeps them; the pieces that run that far only with their lines must
    also continue a kept cell of their region (:func:`_continues_kept_level`: a crown beside a
    terrace wall does not). Lidar ``hexbin-crop`` (rock steps on a 21 degree hillside): 1 / 2 / 4 m
    1.83 / 2.43 / 12.11 -> 1.75 / 2.34 / 11.78 % total error with the lines alone; a terraced
    hillside at 4 m (tests/core/test_coarse_slopes.py) 76.6 -> 84.3 % of its ground kept, every
    tree still found; a terraced hillside at 2 m, its wall tops cut every few metres: 9.96 -> 7.52
    % with the joined pieces alone.
    """
    near = ndimage.binary_dilation(steps, np.ones((3, 3), bool))
    cand = near & (st.step == 3) & (st.mask == OBJECT)
    if not cand.any():
        return
    # a wall top runs along its wall, longer than a building as the terrain's lines do (the edge
    # of a box on a steep hill, whose one wall no jump answers, is as short as the box); its pieces
    # joined across gaps (a gap in the data, a bush or a cell step 3 kept), or measured with the
    # lines it lies along (the removed cells of a rough terrace edge are pieces of it, which must
    # then continue the kept level too)
    alone = _joined_longer_than(cand, cfg.cell, cfg.max_building_m)
    cand &= alone | longer_than(cand | steps, cfg.cell, cfg.max_building_m)
    if not cand.any():
        return
    # tested in tiles holding candidates, each with the 3 cells step 3 reads around it (the tiles'
    # results are those of one pass; a line crossing a large raster touches few of its tiles)
    back = np.zeros(st.z.shape, bool)
    rise = cell_rise(cfg.terrain_slope, cfg.cell)
    rows, cols = st.z.shape
    t, h = _RETEST_TILE, 3
    has = np.zeros((-(-rows // t), -(-cols // t)), bool)
    r, c = np.nonzero(cand)
    has[r // t, c // t] = True
    for tr, tc in zip(*np.nonzero(has)):
        a0, a1, b0, b1 = tr * t, min(rows, tr * t + t), tc * t, min(cols, tc * t + t)
        w0, w1, v0, v1 = max(0, a0 - h), min(rows, a1 + h), max(0, b0 - h), min(cols, b1 + h)
        win = (slice(w0, w1), slice(v0, v1))
        hi, lo = remove_neighbour_differences(st.z[win], st.keep[win] | cand[win], sigma_m=cfg.sigma_m,
                                              k=cfg.neighbour_k, low_weight=cfg.low_weight,
                                              labels=st.labels[win], cell_rise_m=rise, bend_m=cfg.terrain_bend_m,
                                              ground_sigma_m=cfg.ground_sigma_m)
        core = (slice(a0 - w0, a1 - w0), slice(b0 - v0, b1 - v0))
        back[a0:a1, b0:b1] = cand[a0:a1, b0:b1] & ~hi[core] & ~lo[core]
    back &= alone | _continues_kept_level(st, cfg, back & ~alone)
    idx = np.flatnonzero(back)
    if not idx.size:
        return
    st.removed[3] -= int(idx.size)
    st.mask.reshape(-1)[idx] = 0
    st.step.reshape(-1)[idx] = 0
    st.keep.reshape(-1)[idx] = True
    st.step_restored = int(idx.size)


def _continues_kept_level(st, cfg, cand):
    """The cells of ``cand`` that continue a kept cell of their own break-line region: a neighbour
    (8 directions) kept, in the same region, within step 3's tolerance of a pair
    (:func:`_step3_tolerance`: ``k sqrt(2) sigma``, widened by the terrain's bend).

    A wall's top is the edge of the level above it and continues it, along the edge or behind it;
    the cells given back beside a terrain step must show that, not only pass step 3 again among
    other candidates: the cells of a crown beside a terrace wall, tested together, shield each
    other (each pair within a crown differs by little) while every kept cell around them lies
    metres lower. No rise of the terrain's slope is allowed here: at coarse cells on hills (24 m)
    a box 20 m high stands within that rise of the ground uphill."""
    tol = _step3_tolerance(cfg)
    rows, cols = cand.shape
    r, c = np.nonzero(cand)
    ok = np.zeros(r.size, bool)
    zc = st.z[r, c]
    lab = st.labels[r, c] if st.labels is not None else None
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr == dc == 0:
                continue
            rr, cc = r + dr, c + dc
            inside = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
            rr, cc = np.clip(rr, 0, rows - 1), np.clip(cc, 0, cols - 1)
            near = inside & st.keep[rr, cc] & ~cand[rr, cc]
            if lab is not None:
                near &= st.labels[rr, cc] == lab
            with np.errstate(invalid="ignore"):
                near &= np.abs(zc - st.z[rr, cc]) <= tol
            ok |= near
    out = np.zeros(cand.shape, bool)
    out[r[ok], c[ok]] = True
    return out


def _spare_slope_breaks(st, cfg):
    """Give back the objects of steps 3 and 5 standing where the terrain's slopes on both sides meet
    (:func:`~.moving.slope_breaks`: a crest, a ridge, a bank's shoulder) along a line running further
    than the longest building, after the spares of the fits.

    Both steps compare a height with its neighbours (step 3 a pair and the slope beyond it, step 5
    the fit of a profile), which at a crest sharp against the cell lie below it by half the change
    of slope times the cell: a dune's brink, a gully's shoulder at 2-4 m cells. The test reads the
    two kept cells on each side of a run of such objects along a row or a column (runs up to the
    window of step 5's longest profile, in whose fits a crest's bend shows; step 5's scale and
    ``k``): both sides rise towards it and each of its heights lies on the lower of their lines.
    The crown of a bush whose sides the steps kept passes that test too (the opengeos 2 m city:
    618 of 627 cells given back were objects); a crest of the terrain runs on, as its level
    changes do (:func:`~.steps.find_terrain_steps`): the cells given back are those whose line,
    with the kept cells passing the same test and joined across gaps of up to
    :data:`WALL_TOP_GAP_M` (:func:`_joined_longer_than`), runs further than ``max_building_m``.
    Run after the spares of the fits (:func:`_spare_continuing_ground` gives back a whole crest
    line running further than step 6's window, which pieces given back earlier would have cut
    short) and before step 3's repeat, which tests the cells again once the objects around them
    are gone."""
    taken = (st.mask == OBJECT) & ((st.step == 3) | (st.step == 5))
    if not taken.any():
        return
    run = odd_window(max(cfg.lengths) / max(cfg.cell), 3)
    back = slope_breaks(st.z, st.keep, taken, scale_m=cfg.profile_sigma_m, k=cfg.snooping_k, max_run=run,
                        labels=st.labels)
    if not back.any():
        return
    bent = _bent(st.z, st.keep, cfg.snooping_k * cfg.profile_sigma_m)
    kept = slope_breaks(st.z, st.keep & ~bent, bent, scale_m=cfg.profile_sigma_m, k=cfg.snooping_k, max_run=run,
                        labels=st.labels)
    _give_back(st, back & _joined_longer_than(back | kept, cfg.cell, cfg.max_building_m))


#: Cells per band of rows of :func:`_bent` (its float32 differences about 1 MB).
_BENT_BAND_CELLS = 1 << 18


def _bent(z, keep, bend_m):
    """The kept cells whose two neighbours on each side along a row or a column rise towards them
    by more than ``bend_m`` on average (the first test of :func:`~.moving.slope_breaks`)."""
    out = np.zeros(z.shape, bool)
    h, w = z.shape
    # in bands of rows whose differences stay in the cache (each band's columns read two rows around it): the
    # same operations on every cell as on the whole raster, so the same cells (4000 x 4000: 0.12-0.43 -> 0.04 s)
    rows = max(1, _BENT_BAND_CELLS // max(1, w))
    with np.errstate(invalid="ignore"):
        for r0 in range(0, h, rows):
            r1 = min(h, r0 + rows)
            d = np.diff(z[r0:r1], axis=1)
            b = (d[:, :-3] - d[:, 3:]) / 2.0
            out[r0:r1, 2:-2] |= b > bend_m
            a0, a1 = max(2, r0), min(h - 2, r1)          # the band's rows with two rows on each side
            if a1 > a0:
                d = np.diff(z[a0 - 2:a1 + 2], axis=0)
                b = (d[:-3] - d[3:]) / 2.0
                out[a0:a1] |= b > bend_m
    out &= keep
    return out


def _step5_profiles(st, cfg, progress):
    """Step 5: moving local profiles in X and Y, short then long, with data snooping.

    A profile stops at a break line (the user's and the terrain's level changes of step 4,
    :func:`~.regions.profile_runs`), also where the line does not close its region: the profile
    across a terrace's riser whose line ends inside the raster fitted both levels and took the
    upper tread's edge (synthetic bare terraces 1 m: step 5 took 1.49 % of the cells, 0.11 % cut)."""
    lines = st.lines if st.lines is not None else st.breaklines
    cut = lines is not None and st.labels is not None
    hi, lo = remove_profile_outliers(
        st.z, cfg.cell, st.keep, lengths_m=cfg.lengths, scale_m=cfg.profile_sigma_m,
        terrain_class=cfg.terrain_class, homogeneous=cfg.homogeneous,
        iterations=cfg.snooping_iterations, test=st.global_ok, k=cfg.snooping_k,
        low_weight=cfg.low_weight, labels=st.labels, z_t=st.transposed(), progress=progress,
        profile_labels=(profile_runs(st.labels, lines), profile_runs(transpose(st.labels), transpose(lines)))
        if cut else None)
    st.z_t = None                         # its last reader: freed (made again by a second iteration)
    _record(st, 5, hi, lo)


def _step6_surfaces(st, cfg, progress):
    """Step 6: moving surfaces (horizontal, inclined plane or polynomial)."""
    hi, lo = remove_surface_outliers(
        st.z, cfg.cell, st.keep, size_m=cfg.surface_size_m, scale_m=cfg.surface_sigma_m,
        terrain_class=cfg.terrain_class, homogeneous=cfg.homogeneous,
        iterations=cfg.snooping_iterations, test=st.global_ok, k=cfg.snooping_k,
        low_weight=cfg.low_weight, labels=st.labels, per_block=cfg.fits_per_block, progress=progress)
    _record(st, 6, hi, lo)


def _step7_prediction(st, cfg, progress):
    """Step 7: local least-squares prediction (everywhere when on, else in special areas)."""
    hi, lo = remove_prediction_outliers(
        st.z, cfg.cell, st.keep, radius_m=cfg.prediction_radius_m, scale_m=cfg.prediction_sigma_m,
        test=st.valid if cfg.on[7] else st.special, k=cfg.snooping_k, low_weight=cfg.low_weight,
        labels=st.labels, progress=progress)
    _record(st, 7, hi, lo)


def _spare_height(cfg):
    """The largest second difference of smooth ground (:func:`_spare_continuing_ground`), metres."""
    return SMOOTH_RATIO * _step3_tolerance(cfg)


def longer_than(objects, cell_size, length_m, joined=None):
    """The cells of the regions of ``objects`` (8-connected) that run further than ``length_m``
    metres along the rows or the columns (``cell_size`` (dx, dy) metres); with ``joined`` (a mask
    holding ``objects``, e.g. grown across gaps), the regions are those of ``joined`` and each
    runs as far as its ``objects`` cells do."""
    lab, n = label8(objects if joined is None else joined)
    if not n:
        return np.zeros(np.shape(objects), bool)
    if joined is not None:
        lab[~np.asarray(objects, bool)] = 0
    dx, dy = as_cell_size(cell_size)
    # the regions' extents from their bounding boxes (one pass; labelled minima and maxima sort the raster)
    box = np.array([(0, 0, 0, 0) if b is None else (b[0].start, b[0].stop, b[1].start, b[1].stop)
                    for b in ndimage.find_objects(lab, n)], np.intp).reshape(-1, 4)
    span = np.zeros(n + 1)
    span[1:] = np.maximum((box[:, 1] - box[:, 0]) * dy, (box[:, 3] - box[:, 2]) * dx)
    return (span > length_m)[lab]


def _spare_continuing_ground(st, cfg):
    """Give back the objects of steps 5 and 6 that are smooth ground continuing the ground kept.

    The moving profiles and surfaces compare a height with a fit of its window only: a road
    embankment, a ramp or a raised bank that stands above that fit over more of its width than
    the window's own slope explains is taken as an object, although nothing bounds it by the
    jumps steps 3 and 4 find at an object's edge. Jacobsen (2004) leaves such terrain
    discontinuities to break lines (his highway example: 21.6 % of the points removed without,
    10.4 % with them). Without break lines, what tells them apart is what
    ``bareearth:dtm`` already uses between its members (:func:`~..dtm_refine.continue_ground`):
    ground continues, without a step, from the ground kept; an object stands on a step (a wall,
    a crown's edge) whose second difference is its height. A cell steps 5 or 6 removed as an
    object is ground again when its object region (8-connected, whatever step removed its
    cells) runs further than step 6's window (:func:`longer_than`: the window is sized to hold
    the objects; a mound, a crown or a dome narrower than it is one of them), no second
    difference of its 3 x 3 neighbourhood exceeds ``SMOOTH_RATIO`` (2) times step 3's tolerance
    (``k sqrt(2) sigma``, widened by the terrain's bend), read on the kept and the disputed cells
    (a bush or a tree on the bank that another step removed does not cut it), and it is joined
    within ``REACH_M`` (12 m) through such cells to kept ground that itself runs further than
    the window (not a piece of a crown or a roof the steps left, cut off by the objects around).

    Its measured cost: ``lidar/autzen_trim/1m`` 2.20 -> 2.85 % total error (``bareearth:dtm``
    2.80 -> 3.26). 224 of the 948 cells given back there lie 0.3-1.5 m above the reference ground
    (putting them back as objects alone gives 2.15 %): understorey under tree canopy, no ground
    return in the cell and returns spread up to 16 m above it, whose lowest returns rise from the
    kept ground by 0.25-0.4 m a cell, as an embankment's side does (the synthetic embankments:
    0.5 m a cell), and stay within the 0.85 m allowance. Their regions' span, their outlines'
    share of kept ground, their height above the kept ground around them, the objects of steps 3
    and 4 around them and their roughness were measured; none tells them from the embankments.
    """
    if not cfg.spare_continuing_ground:
        return
    objects = st.mask == OBJECT
    taken = objects & ((st.step == 5) | (st.step == 6))
    if not taken.any():
        return
    taken &= longer_than(objects, cfg.cell, cfg.surface_size_m)
    if not taken.any():
        return
    # the paths start on kept ground running further than the window, not on a piece of a crown or a
    # roof the steps left (ground cut off by objects around it)
    anchors = st.keep & longer_than(st.keep, cfg.cell, cfg.surface_size_m)
    back = continue_ground(st.z, taken, st.keep, anchors,
                           height_m=_spare_height(cfg),
                           reach_cells=continuation_cells(cfg.cell, REACH_M), judge_on_ground=True)
    n = _give_back(st, back)
    if n:
        st.spared = n


def _give_back(st, back):
    """Make the cells ``back`` (objects of steps 3, 5 and 6) kept ground again, their steps' counts
    lowered; the number of cells."""
    idx = np.flatnonzero(back)
    if not idx.size:
        return 0
    for k in (3, 5, 6):
        st.removed[k] = st.removed.get(k, 0) - int(np.count_nonzero(st.step.reshape(-1)[idx] == k))
    st.mask.reshape(-1)[idx] = 0
    st.step.reshape(-1)[idx] = 0
    st.keep.reshape(-1)[idx] = True
    return int(idx.size)


def _spare_ramps(st, cfg):
    """Give back the object regions of steps 5 and 6 that are ramps between two levels of kept ground
    (:func:`~.regions.find_ramps`, tolerance step 3's, a wall step 4's jump)."""
    if not cfg.spare_continuing_ground:
        return
    taken = (st.mask == OBJECT) & ((st.step == 5) | (st.step == 6))
    if not taken.any():
        return
    back = find_ramps(st.z, cfg.cell, taken, st.keep, tolerance_m=_spare_height(cfg) / SMOOTH_RATIO,
                      wall_m=cfg.jump_m, max_span_m=cfg.surface_size_m + REACH_M)
    st.spared += _give_back(st, back)


#: The steps of the sequence, by number.
_STEPS = {2: _step2_height_distribution, 3: _step3_neighbour_differences,
          4: _step4_level_change, 5: _step5_profiles, 6: _step6_surfaces, 7: _step7_prediction}


def _result(st, cfg):
    """The mask, the ``step`` extra and the log's figures."""
    valid = st.valid
    n_valid = max(1, int(valid.sum()))
    st.mask[~valid] = NODATA
    st.step[~valid] = 255
    shares = {f"{k} {STEP_NAMES[k]}": st.removed.get(k, 0) / n_valid for k in range(2, 8)}
    info = {"terrain_class": cfg.terrain_class, "homogeneous": bool(cfg.homogeneous),
            "model": ("mean / horizontal plane", "linear regression / inclined plane",
                      "polynomial")[model_degree(cfg.terrain_class, cfg.homogeneous)],
            "sigma_m": cfg.sigma_m,
            "step3_cell_rise_m": [round(v, 4) for v in cell_rise(cfg.terrain_slope, cfg.cell)],
            "steps_on": [k for k in range(1, 8) if cfg.on[k]],
            "removed_share_by_step": shares,
            "removed_share": float(sum(st.removed.values()) / n_valid),
            "low_share": float(np.mean(st.mask[valid] == LOW)),
            "breakline_regions": st.n_regions,
            "terrain_step_share": st.step_lines / n_valid,
            "terrain_step_jump_m": round(_terrain_step_jump(cfg), 3),
            "continuing_ground_share": st.spared / n_valid,
            "terrain_step_restored_share": st.step_restored / n_valid,
            "special_area_share": float(st.special[valid].mean()) if st.special is not None else 0.0,
            "second_iteration": cfg.second_iteration,
            "step3_repeated": bool(not cfg.second_iteration and _plan(cfg, st).count(3) > 1),
            "notes": st.notes}
    return FilterResult(mask=st.mask, extras={"step": st.step}, info=info)


#: How :func:`~.parameters.resolve_rascor_params` derives an empty ``surface_size_m``.
SURFACE_RULES = ("objects", "residuals")


def filter_rascor(z: np.ndarray, cell_size: Union[float, Sequence[float]], *,
                  terrain_class: str = "rolling", homogeneous: Union[bool, str] = True,
                  sigma_m: float = 0.15, step1_characterise: bool = True,
                  step2_height_distribution: bool = True, step3_neighbour_differences: bool = True,
                  step4_level_change: bool = True, step5_profiles: bool = True,
                  step6_surfaces: bool = True, step7_prediction: bool = False,
                  second_iteration: bool = False, step3_repeat: bool = True,
                  height_min_m: Optional[float] = None,
                  height_max_m: Optional[float] = None, neighbour_k: float = 3.0,
                  terrain_slope: float = 0.0, terrain_bend_m: float = 0.0,
                  ground_sigma_m: Optional[float] = None, jump_m: float = 2.0,
                  max_building_m: float = 120.0, max_hall_m: float = 0.0,
                  short_profile_m: float = 9.0, long_profile_m: float = 25.0,
                  profile_sigma_m: Optional[float] = None, surface_size_m: float = 25.0,
                  surface_rule: str = "objects",
                  surface_sigma_m: Optional[float] = None, prediction_radius_m: float = 3.0,
                  prediction_sigma_m: Optional[float] = None, snooping_k: float = 4.0,
                  snooping_iterations: int = 1, low_weight: float = 0.02, fits_per_block: bool = False,
                  spare_continuing_ground: bool = True, steps: Optional[Iterable[int]] = None,
                  breaklines: Optional[np.ndarray] = None,
                  special_areas: Optional[np.ndarray] = None,
                  progress: Optional[Callable[[float], None]] = None) -> FilterResult:
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
    step3_repeat : bool
        Without the second iteration, run step 3 once more after the last step (when step 3
        and a later step are on): edges of crowns and roofs that passed it as the toe of a
        slope while the object above them stood.
    height_min_m, height_max_m : float or None
        Step 2 limits (None: step 2 does nothing).
    neighbour_k : float
        Critical value of step 3.
    terrain_slope : float
        Step 3: the terrain's slope (rise/run) whose rise over one cell widens the
        tolerance (:func:`remove_neighbour_differences`; 0: the paper's ``k sigma sqrt(2)``
        alone; :func:`resolve_rascor_params` derives it, step 1's median slope).
    terrain_bend_m : float
        Steps 3 and 4: the Gaussian scale of the terrain's own second difference over one
        cell (m); the tolerance of step 3 and the jump and smoothness limits of step 4
        widen by ``k`` times it in quadrature (0: the paper's tolerances;
        :func:`resolve_rascor_params` derives it from the block minima, metres on coarse
        DEMs of hills, millimetres on 1 m lidar).
    ground_sigma_m : float, optional
        Step 3: the random error of the ground's heights (m), the noise of the slope beyond a
        pair on sloping ground (:func:`~.steps.slope_weight`); None: ``sigma_m``
        (:func:`resolve_rascor_params` derives it: the noise of the ground-level cells,
        :func:`~bare_earth.core.estimate.noise_ground_level`, at most ``sigma_m``).
    jump_m, max_building_m : float
        Step 4: minimum level change and maximum building length, metres.
    max_hall_m : float
        Step 4: the longest hall, metres: a raised level its walls close on every side, running
        further than ``max_building_m`` and at most this far, is a building
        (:func:`~.steps.enclosed_levels`; :func:`resolve_rascor_params` derives it, the longest
        such level of the DSM); at most ``max_building_m`` (0): none.
    short_profile_m, long_profile_m : float
        Step 5 profile lengths, metres.
    profile_sigma_m, surface_sigma_m, prediction_sigma_m : float or None
        Standard deviation of a height about the model of steps 5, 6, 7 (None: sigma_m).
    surface_size_m : float
        Step 6 window edge, metres.
    surface_rule : {"objects", "residuals"}
        How :func:`resolve_rascor_params` derived an empty ``surface_size_m`` (checked and
        kept in ``info``; the filter itself uses only ``surface_size_m``).
    prediction_radius_m : float
        Step 7 neighbourhood radius, metres.
    snooping_k : float
        Critical value of the data snooping of steps 5-7.
    snooping_iterations : int
        Fits per length / direction (step 5) and per surface (step 6).
    low_weight : float
        Weight factor of points below the reference (0 < p <= 1).
    fits_per_block : bool
        Step 6: surfaces of at least 32 cells a side (horizontal or inclined plane, no break
        lines) fitted once per block of cells and evaluated at each cell, leave-one-out
        (:func:`~.fits.snoop_block_fits`): a cell is tested against the window centred on its
        block instead of on itself (at most 1/32 of the window away, the window's side rounded
        to whole blocks). Faster; what the dtm filter asks of its RASCOR member. (Step 5's profiles
        gain nothing from it: one axis of blocks saves less than the blocks cost.)
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
    if surface_rule not in SURFACE_RULES:
        raise ValueError(f"surface_rule must be one of {SURFACE_RULES}; got {surface_rule!r}.")
    cfg = _check_settings(
        cell_size, terrain_class=terrain_class, homogeneous=homogeneous, sigma_m=sigma_m,
        switches=(step1_characterise, step2_height_distribution, step3_neighbour_differences,
                  step4_level_change, step5_profiles, step6_surfaces, step7_prediction),
        steps=steps, second_iteration=second_iteration, step3_repeat=step3_repeat,
        height_min_m=height_min_m,
        height_max_m=height_max_m, neighbour_k=neighbour_k, terrain_slope=terrain_slope,
        terrain_bend_m=terrain_bend_m, ground_sigma_m=ground_sigma_m, jump_m=jump_m,
        max_building_m=max_building_m, max_hall_m=max_hall_m, short_profile_m=short_profile_m,
        long_profile_m=long_profile_m, profile_sigma_m=profile_sigma_m,
        surface_size_m=surface_size_m, surface_sigma_m=surface_sigma_m,
        prediction_radius_m=prediction_radius_m, prediction_sigma_m=prediction_sigma_m,
        snooping_k=snooping_k, snooping_iterations=snooping_iterations, low_weight=low_weight,
        fits_per_block=fits_per_block, spare_continuing_ground=spare_continuing_ground)
    report(progress, 0.0)
    st = _start(z, breaklines, special_areas)
    # a gap between crowns or roofs is at the level of the other low cells around it and is
    # no blunder (Jacobsen's weight factor alone takes it for one where the ground shows
    # only in such gaps: a closed canopy at 4 m cells)
    st.pit = _Pits(z, cfg.cell, 3.0 * cfg.sigma_m * np.sqrt(2.0), cfg.terrain_slope)
    plan = _plan(cfg, st)
    ends = np.cumsum([_COST[k] for k in plan]) / max(1e-9, sum(_COST[k] for k in plan))
    last_fit = max((i for i, k in enumerate(plan) if k in (5, 6)), default=None)
    for i, (k, a, b) in enumerate(zip(plan, np.concatenate([[0.0], ends[:-1]]), ends)):
        _STEPS[k](st, cfg, sub_progress(progress, a, b))
        if i == last_fit:        # each followed by a report: seconds on 16 Mcells
            report(progress, b)
            _spare_continuing_ground(st, cfg)
            report(progress, b)
            _spare_ramps(st, cfg)
            report(progress, b)
            _spare_slope_breaks(st, cfg)
        report(progress, b)
    result = _result(st, cfg)
    report(progress, 1.0)
    return result
