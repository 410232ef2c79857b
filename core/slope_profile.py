"""Slope-profile filter (Luong Chinh Ke 2002, section 2.1).

Along every profile in X (rows) and in Y (columns) the slope between consecutive points
is ``alpha = atan(dZ / dX)``. A point whose slope from the ground before it exceeds the
terrain slope threshold ``alpha_g`` is on an object. The height of a rejected point is
corrected by ``dZ`` (the paper's rule), i.e. the profile keeps the last ground height as
its reference, so the points that follow on a roof or a tree crown stay rejected until
the profile comes back down to the ground: whole objects are removed, not only their edges.

Details this implementation adds to the paper, each for a failure the paper's rule has:

* **Distance-aware tolerance.** A point ``d`` cells after the reference (the last ground
  point) is accepted when ``dZ <= dh0 + d dX tan(alpha_g)`` over the edge run
  (``d dX <= edge_length_m``; with ``d = 1`` the paper's test plus a noise allowance
  ``dh0``), and further on when ``dZ <= dh0 + max(e dX tan(alpha_g), d dX tan(alpha_t))``
  (``e`` the edge run in cells): under an object the ground may have risen at the
  terrain's slope ``alpha_t`` (far below ``alpha_g``) over the whole distance from the
  reference. The edge's allowance is not added to that rise: added, it let every object
  lower than ``dX tan(alpha_g)`` plus the terrain's rise pass (shrubs 1-3 m at 2 m
  cells, issue 12).
* **The edge test along the ground's fall.** The edge's allowance is measured from the
  ground continued down its fall before the reference (``dZ`` over the last step to the
  reference, per cell; at most the terrain's slope ``alpha_t``, none where the ground
  rose) over the edge run: ``dZ <= max(dh0 + d dX tan(alpha_t), edge + f min(d, e))``,
  ``f <= 0`` that fall. A scan coming down a hillside compared an object's rise with the
  level of the last ground cell, so it saw the object lower by the hillside's fall over a
  cell (``dX tan(alpha_t)``: 1.25 m at 2 m cells of a 32 degree hill), and both scans
  must reject: crowns 1.5-4 m high on such a hill were 4 % objects at 2 m cells, 53 % with
  the fall (ISPRS samp11 2 m highest 33.94 -> 32.75 %, matrix 3.54 -> 3.49). The terrain's
  rise from the reference stays allowed (a valley's far side is ground), and a scan going
  up a slope is unchanged (its allowance ``alpha_g`` covers the rise).
  The ground's part of the allowance is its own trend before the reference, not the
  terrain's slope wherever it did not fall: ``alpha_g`` is the slope the test allows from
  ground rising at ``alpha_t``, so the edge's own margin over the ground's continuation is
  ``alpha_g - alpha_t`` (at least the ground's micro-relief, 5 degrees, the derived
  ``alpha_g``'s floor: ``c = min(tan alpha_t, tan alpha_g - tan 5 deg)``, at least 0, is the
  ground's rise ``alpha_g`` allows for), and the continuation is the ground's change per cell
  before the reference within ``[-alpha_t, c]``:
  ``dZ <= max(dh0 + d dX tan(alpha_t), edge + (f - dX c) min(d, e))``. Along a
  contour of a hillside (level ground, ``f = 0``) a crown's edge had the whole ``alpha_g``
  (0.78 m per metre on ISPRS samp11, twice its 21 degree terrain), the margin of ground
  rising at ``alpha_t`` that the level ground does not use, and shrubs up to 1 m high were
  accepted by the profiles along the contours (samp11 1 m lowest 11.11 -> 10.82 %, 1 m
  highest 12.92 -> 12.46 %; ISPRS seven 3.77 -> 3.62 % with the crossed runs below). With
  the derived ``alpha_g`` (twice ``alpha_t``) the test is unchanged where the ground rises
  or falls at ``alpha_t``; the terrain's rise from the reference stays its floor. Without the
  micro-relief's floor, flat samples whose ``alpha_g`` is the 5 degree floor lost kerbs and
  furrows (ISPRS samp21 2 m lowest 1.98 -> 2.15 %, 1.98 with it).
* **The terrain's rise along the ground's fall.** The terrain's line is measured from the
  ground continued down its fall at the reference too: ``dZ <= dh0 + d (dX tan(alpha_t) + t)``,
  ``t`` the ground's fall per cell there (``-dX tan(alpha_t) <= t <= 0``; 0 where the ground
  rises or is level: the paper's rise from the reference). ``t`` is the less steep of the
  ground's trend (:func:`ground_trends`: the slope along the profile of the running minimum over
  :data:`TREND_SIDE_M`, 10 m, which reaches below a shrub or a crown beside the reference) and of
  the ground's last step to the reference less that step's noise (``sqrt(2) dh0 / 3``, the noise
  of the difference of two heights, ``dh0`` being three times a height's): a fall that only one
  of them shows, or one within the noise, is none. The terrain's rise from the reference's own
  level let a scan coming down a hillside accept an object up to ``dh0 + dX tan(alpha_t)`` above
  the reference, ``dX tan(alpha_t)`` more above the ground's continuation, and let the ground
  under a crown rise at ``alpha_t`` from a level it had left: shrubs and crowns 1-5 m high on
  ISPRS samp11's 20 degree hillside (2 m highest 32.36 -> 30.19 %, 2 m lowest 10.29 -> 10.06 %,
  lidar Topography 2 m 3.57 -> 3.40 %). A scan going up a slope is unchanged, and a valley's far
  side stays ground (the scan coming down it accepts it; both scans must reject). The trend
  alone (without the step) took the ground's fall into a ditch or off a bank for the terrain's
  (ISPRS samp61 2 m highest 2.20 -> 2.38 %, samp71 1 m 2.47 -> 2.76 %); the step alone or without
  its noise, one cell's noise on gentle ground (samp21 1 m lowest 1.71 -> 2.23 %, synthetic_sites
  embankment 1 m lowest 1.72 -> 3.13 %, its crest after the trees on it rejected), though it
  gave samp11 2 m highest 24.5-28.7 %.
* **The ground's change before the reference follows its trends.** The change per cell that the edge
  test continues (and the terrain line's step) is the last step to the reference, but no more rising
  than the ground's trends show plus that step's noise (``f <= T + sqrt(2) dh0 / 3``): ``T`` the
  more rising, for the scan, of the trend at the reference (:func:`ground_trends`) and the trend
  about 10 m behind it (``2 (s // 2)`` cells, ``s`` :func:`trend_cells`), whose running minimum
  holds only cells the scan has passed (:func:`trends_before`). On ISPRS samp11's 20-30 degree
  hillside the scans coming down the slope accepted the crowns (87-91 % of the 2 m highest-point
  cells called ground on objects, 72-82 % rejected by the scans going up): a crown's top entered
  level from the hillside above, or its flank climbed by steps within the edge's allowance, became
  the reference and its level or rising steps the ground's trend, while the hillside under it fell.
  With both trends a bench's edge ahead does not count (the trend behind the reference is the
  bench's level) nor does one trend's fall alone (the more rising of the two): samp11 2 m highest
  30.19 -> 29.08 %, 1 m highest 12.51 -> 12.27, lidar Topography 2 m 3.40 -> 3.32. The centred trend
  alone (``f <= t + noise``) gave 28.74 but cost the shoulders of quarry benches whose lower bench
  the running minimum reaches ahead (``synthetic_sites`` quarry 2 m lowest 1.71 -> 2.45 %, steps
  0.75 -> 1.13); the trend behind alone, 29.29, cost gullies' banks at 4 m (2.87 -> 3.10 % of the
  ground lost); capping only rises (29.99) or only falls (29.93) gained little. What it costs: one
  tor of ``synthetic_bare`` outcrops at 4 m (a rock 10 m high with 60-75 degree sides, the shape of
  a hall on a hillside) now has a tenth of its cells rejected by both axes and stays an object (0.67
  -> 0.91 %; bare mean 0.215 -> 0.220), gullies at 4 m 2.87 -> 2.96, samp11 1 m lowest 10.70 ->
  10.79 (ISPRS seven 3.61 -> 3.62); matrix 2.637 / 3.201 / 2.041 -> 2.614 / 3.158 / 2.040 (72 rows
  without ``*``), sites 2.297 -> 2.298.
* **Coming down off an object.** A cell after a rejected run that lies above the next
  cell by more than the edge's step ``dh0 + dX tan(alpha_g)`` is still on the way down
  (a wall's foot or a crown's rim, a cell half on the object): it stays rejected, and the
  ground is where the descent ends. The terrain's rise allowed under a long object had
  taken it for the ground (opengeos, 2 m: the rims of buildings and trees, 11.1 -> 7.9 %
  total error; issue 12). Ground going on down at a slope below ``alpha_g`` is the ground.
* **Objects crossed along their length.** A low object long along one axis (a hedge, a row
  of cars, 1 m high) is lost by both scans of the profiles along it to the terrain's rise
  after a few cells (each scan accepts the far part of it), so only the axis across it
  rejects it, and the combination below (a tenth of an object's cells rejected by both
  axes) gave it back as an embankment. Where its run of rejected cells along the accepting
  axis, at most the largest object long, stands on a step at both its ends (both cells
  beyond each end lower than it by more than the paper's one-cell test ``dh0 + dX tan
  alpha_g``; a one-cell hole is no step), that axis crossed an object: its cells count as
  rejected by both axes in the combination. An embankment that the profiles along it reach
  by ramps gentler than ``alpha_g`` has no such steps (:func:`_stepped_runs`; ISPRS samp41
  1 m lowest 3.92 -> 3.39 %, samp71 2.48 -> 2.38 %; a bridge's ramp between walls with a
  one-cell hole in it stays ground).
* **Raised runs closed by walls.** Cells accepted after a rejected run only by the
  terrain's rise under an object (higher than the edge's allowance above the reference),
  the run having begun with a wall up (a one-cell step steeper than any bank,
  ``dh0 + dX max(tan alpha_g, 1)``: :data:`~.estimate.GAP_BANK_SLOPE`), open a raised run.
  When the profile comes down a wall as steep within the largest object's length from the
  ground before the run, the run was the top of an object between two walls: a flat roof
  wide enough for the terrain's rise to reach its height, whose middle was accepted from
  both sides (synthetic-lidar urban, 2.6 % total error at 1-4 m cells; issue 12).
  Those cells join the objects where they belong to a connected region of such cells (the
  objects they touch left out) within the largest object turned in the grid; a longer region
  is an embankment or a terrace between walls (ISPRS samp61's road embankments), and its runs
  stay ground. Measured with the objects they touch, a roof's runs beside trees or hedges
  running on across the raster made a region longer than any object, and stayed ground
  (ISPRS samp31 1 m lowest, 3.37 -> 1.99 % total error; matrix 3.60 -> 3.54). A region also needs walls
  where it meets the ground: at least half its edges to ground cells drop as steeply as the
  walls. A profile that climbs out of a pit or a line of low blunders (samp41's multipath
  pits far below the ground, not all class 2), crosses level ground and drops into another
  saw two "walls", but the level area goes on into the ground on its other sides
  (samp41 1 m lowest, 7.46 -> 6.54 % total error).
  Nor is a region that goes on level into the terrain: its smooth part (cells joined by
  steps between neighbours of at most the tolerance ``dh0``,
  :func:`~.estimate.smooth_parts`) being mostly ground. A roof's part is the roof; level
  ground enclosed by pits, with gaps between them, is the terrain's (samp41 1 m lowest,
  6.54 -> 3.89 %). Steps of the terrain's slope (``dh0 + dX tan(alpha_t)``) joined roofs
  cut into a steep hillside, level with it at their uphill edge, to the hillside (samp11,
  20 degrees: up to 1.2 m at 2 m cells; 1 m lowest 11.91 -> 11.59 %, samp41 3.86 -> 3.89).
* **Ramps.** A connected run of cells rejected by one axis only (the profiles across it
  climb its flanks, walls) whose smooth part is mostly ground and which joins ground
  cells on both sides along the other axis by steps of the terrain's slope
  (``dh0 + dX tan(alpha_t)``) is a ramp or an embankment's crest: the profiles along it run
  from the ground onto it and off it onto the ground. It is ground even where it touches
  trees or a building, whose cells both axes reject, that kept it by their share (ISPRS
  samp71's ramps down from the bridge, 6.42 -> 4.28 % total error at 1 m lowest; issue
  12). A roof on a hillside joins the uphill ground on one side only; a bridge crossing
  the grid obliquely is rejected by both axes. One profile must cross it: a single run of
  rejected cells along a row (or column) joined to the ground at both its ends; a crown or
  a roof on a steep hillside (a step of the terrain's slope is up to 1.2 m at 2 m cells on
  samp11) that such steps join to the ground on one row at one end and on another row at
  the other is no ramp (samp11 2 m highest 35.09 -> 34.15 %, matrix 3.63 -> 3.60). Nor are the
  cells of a walled region (a roof, above): the profiles coming down the hillside onto a roof cut
  into it, where the ground beside the roof's end falls, reject its uphill edge by one axis
  (the terrain's rise along the ground's fall), and those one-axis cells, joined to the hillside
  by steps of the terrain's slope, were given back while the rest of the roof stayed an object.
* **Platforms.** A connected region rejected by one axis only that is longer along the
  other axis than across it and more than a cell across, lies along its length on the line
  between its own cells a sample spacing before and after (a level or an even slope going
  on; a ground cell between two of its own counts as its own: a sample the scans accepted),
  is joined by steps of a slope the paper's test accepts (``dh0 + dX tan(alpha_g)``)
  to a smooth part mostly of ground that reaches down nearer the foot of its sides than its
  lowest cell (a ramp), and is not walled, is a platform or a level reached along its
  length: ground, with the cells of the rejected objects on its level (steps of at most
  ``dh0``; the strip of it that both axes reject where the profiles along it climbed its
  side and the terrain's rise never reached its height) where they are not walled (a
  bridge's deck beyond its ramp). The levels are found on the one-axis cells before the
  ramps' test (below) gives any back, so which of the two rules takes a ramp does not
  change the mask (``synthetic_sites`` bridge 1 m highest at alpha_t 2.07/2.08/2.09
  degrees: 2.19/1.93/2.18 % total error, now 1.93 at each). A platform turned to the grid is
  crossed by no single profile from ramp to ramp (``synthetic_sites`` railway: 3.1-3.3 ->
  0.5-0.6 % total error at 1 and 2 m cells; issue 12, ISPRS samp42). A crown's fringe is
  rough or too short to go on, a roof's tier joined only to another tier stays at its
  level, and a bridge's deck reached by its ramps stands on walls.
* **Bridges' decks.** Cells rejected by one axis only whose run across (along the profiles that
  reject them, at most the largest object) stands on walls at both its ends (a drop over two
  cells steeper than any bank, :data:`~.estimate.GAP_BANK_SLOPE`, to ground accepted by both
  axes) and is even (half its inner cells on the line between its cells a sample spacing
  before and after within ``dh0``: a level deck, not a mountain's rough ridge) are a
  bridge's deck, given back by none of the rules above that take one axis's runs for an
  embankment's crest, a ramp or a platform: the profiles along a deck run onto it level from the
  road, but it has walls where an embankment has banks (ISPRS samp71's bridge over the river:
  3.91 -> 2.45 % total error at 1 m lowest). A stretch of such runs (8-connected, with what
  stands on them) longer than the largest object turned in the grid is a dam or a terrace
  between walls, and stays ground (:func:`_decks`).
* **Islands of ground on the objects' level.** A profile holding no ground within the largest
  object (a roof cut by the raster's edge and longer than the raster) starts on the roof and
  accepts it, and so does the profile across it, while the profiles beside them that reached
  the ground reject the same roof. Ground enclosed by objects (8-connected, fitting the largest
  object) whose edges to them mostly go on level (fewer than half step up by more than
  ``dh0 + dX tan(alpha_t)``) is theirs; a courtyard, a clearing or a street lies below the
  objects around it (lidar sample_c at 4 m, a roof filling the raster's bottom rows: 3.49 ->
  0.01 % total error; :func:`_islands_level`).
* **Objects at the start of a profile.** The reference starts at the lowest point of the
  profile's first ``max_object_size_m``, ``m`` cells in, not at its first point; the
  profile is taken as mirrored at its start, so that point lies ``m`` cells before the
  first one and the tolerance grows with the distance from it as anywhere else (ground
  sloping down into the raster is not rejected up to that point).
* **Both directions.** Each profile is scanned forwards and backwards; a cell is an object
  for that axis only when both scans reject it. A scan that climbs a terrace edge or a
  steep slope rejects the upper side, but the scan coming down the other way accepts it
  (a drop below the reference resets the reference), so terrain steps survive, while a
  building is rejected from both sides.
* **X and Y combined by connected objects**: the union of the X and Y rejections, keeping
  each connected object only when at least a tenth of its cells are rejected by both axes.
  An object elongated along one axis is short, hence caught, along the other; but a road
  embankment or a dam that a profile runs along is accepted by that profile over most of
  its length, and goes back to the ground. A region larger than the largest object
  (objects touching a dam or one another) takes that share locally, over its cells within
  half the largest object, so the rule's reach is bounded (blocks give the one-pass mask);
  its runs rejected by one axis only whose extent exceeds the largest object turned in the
  grid (``sqrt(2)`` times it) are embankments or dams, ground even with trees or a bridge
  on them (issue 12). So are its levels (cells joined by steps of at most the tolerance
  ``dh0``) whose extent exceeds that turned object where fewer than half of the steps down out
  of them within half the largest object drop like walls (``dh0 + dX max(tan alpha_g, 1)``
  in one cell): the crest of an embankment that crosses the grid obliquely, whose profiles
  both axes climb up its banks (opengeos, 2 m: a highway embankment 5 m high, 7.97 -> 6.76 %
  total error; issue 12); a level's extent counts its stretches given back as one-axis runs
  (at 0.5 m cells the part of a curved dike's crest that both axes climb was shorter than
  that object between the stretches along the axes). A roof that long ends on walls and
  stays an object. The paper's slope test cannot tell a bank from an object's side, but a
  bank goes down from such a crest or run all along its length: cells reached from them
  going down by steps each lower than the noise ``dh0`` and gentler than a wall, within
  half the largest object (:func:`_banks_below`), are ground too, while a crown on the bank
  rises above it, a shrub on it stands above the bank round it in every direction, a roof
  beside the crest ends on a wall and a bridge's deck goes on level from its ramp
  (``synthetic_bare`` levees, dikes 2-6 m high with 1:2 and 1:3 banks: 2.9-5.4 -> 0.00-0.06 %
  of the ground lost at 0.5-4 m cells; ISPRS samp71 2 m lowest 4.47 -> 3.62 %, opengeos 2 m
  6.76 -> 6.13 % total error; issue 12).
* **Low blunders** (a drop then a rise, typical of image matching and laser multipath) are
  found first: pits a 3 x 3 grey closing fills that also lie below the lower third of
  their 7 x 7 neighbourhood (so ground hits between tree crowns stay ground), and below
  every cell of the ring within 10 m or of a level rim just around them
  (:func:`~.estimate.below_surroundings`, :func:`~.estimate.below_level_rim`: two blunders
  within 10 m of each other hid each other from the ring; issue 12). They get class 2 and
  the scans skip them.
* **The tolerance is the sensor's noise.** ``dh0`` is three times the noise of the DSM's ground-level
  cells, read on the cleanest quarter of the tiles where the whole window reads more
  (:func:`~.estimate.sensor_noise`, ``sigma_cleanest`` of :func:`~.estimate.noise_ground_level`, as
  ``bareearth:dtm``'s vote reads it): on a highest-point DSM of a vegetated hillside low vegetation
  touches most ground-level triples and the whole window's spread is its roughness, not the noise (ISPRS
  samp11 at 2 m highest point: 0.37 m read, 0.23 m on the cleanest tiles; dh0 at its 0.5 m cap -> 0.30 m).
  The noise is the same over the raster, the vegetation is not. Measured: samp11 2 m highest 29.08 ->
  25.61 % (the worst row), 1 m highest 12.27 -> 12.12; samp71 2 m highest 2.78 -> 2.95 (its dh0 0.18 ->
  0.15 m, the floor); matrix 2.658 / 3.064 / 2.241 -> 2.611 / 2.971 / 2.241 (73 rows, halves A / B),
  ISPRS seven 3.617 -> 3.616, sites 2.30 and bare unchanged, opengeos RMSE 0.68 m unchanged; the
  ``holes`` row of samp11 (1 m lowest, empty cells left empty) 10.62 -> 11.20.
* **Refinement** (optional, off by default). Rejected cells lying within the tolerance of
  the surface interpolated from the accepted ones are given back to the ground (as SMRF's
  final step does).

References
----------
Luong Chinh Ke (2002). Filtering of digital surface models. Section 2.1, slope along X/Y
profiles.
"""
import threading
import warnings
from typing import Callable, Optional, Tuple, Union

import numpy as np
from scipy import ndimage

from .codes import LOW, NODATA
from .common import FilterResult, as_cell_size, as_surface, report, sub_progress, transpose
from .estimate import (
    GAP_BANK_SLOPE,
    below_level_rim,
    below_surroundings,
    block_minima,
    held_block_side,
    noise_ground_level,
    noise_without_sampling,
    raised_parts,
    raised_region_grid,
    running_minimum_gradient,
    sample_windows,
    sensor_noise,
    smooth_parts,
    terrain_slopes,
)
from .methods import Method, Param, check_values

#: Bounds of the derived slope threshold alpha_g, degrees. The lower one is the slope of the
#: ground's micro-relief (a kerb or a furrow, 0.1-0.2 m over 1-2 m), which the 20 m block
#: minima of the terrain slope do not see.
_MIN_ALPHA_G, _MAX_ALPHA_G = 5.0, 60.0
#: The slope of that micro-relief, rise over run: the least margin of the edge test over the
#: ground's continuation (see :func:`_scan`).
_TAN_MICRO_RELIEF = float(np.tan(np.radians(_MIN_ALPHA_G)))
#: Highest value (degrees) up to which the terrain's upper-quartile slope raises the derived
#: alpha_t above its median: beyond it the upper quartile of block-minimum slopes measures
#: roofs and crowns wider than a block (a closed canopy reads 30-40 degrees), not terrain.
_MAX_QUARTILE_ALPHA_T = 8.0
#: Largest sample spacing (cells) the edge test allows for.
_MAX_SPACING = 4.0
#: Side (metres) of the running minimum whose slope along a profile is the ground's trend at a
#: reference point (:func:`ground_trends`): half the 20 m blocks of the terrain's slope
#: (:func:`estimate_terrain_slope`), so that it reaches under a shrub or a crown beside the
#: reference and keeps the trend of the ground there, not of the hillside 20 m away.
TREND_SIDE_M = 10.0
#: The noise of a step between two heights, in units of dh0 (three times the heights' noise
#: sigma): sqrt(2) sigma. A step's fall counts beyond it (:func:`_scan`'s terrain line).
_STEP_NOISE = float(np.sqrt(2.0) / 3.0)


def profile_slopes(z, cell_size):
    """Slope angles between consecutive points along X and Y profiles, in degrees.

    ``alpha_x[i, j] = atan((z[i, j+1] - z[i, j]) / dx)`` and
    ``alpha_y[i, j] = atan((z[i+1, j] - z[i, j]) / dy)`` (the paper's dZ/dX; Y runs
    down the rows). Shapes ``(rows, cols-1)`` and ``(rows-1, cols)``.
    """
    z = as_surface(z).astype(np.float64)
    dx, dy = as_cell_size(cell_size)
    return (np.degrees(np.arctan(np.diff(z, axis=1) / dx)),
            np.degrees(np.arctan(np.diff(z, axis=0) / dy)))


def estimate_terrain_slope(z, cell_size, scale_m=20.0, tolerance_m=None, spacing_cells=1.0, max_object_m=None):
    """Robust slopes of the terrain under the objects.

    The surface is reduced to the minimum of ``scale_m`` blocks (objects smaller than a
    block vanish from it; the block side in cells from the finer axis, a third of the
    raster's shorter side on a raster under three blocks wide:
    :func:`~bare_earth.core.estimate.held_block_side`), and the slopes (rise/run) between neighbouring block
    minima are summarised (:func:`~bare_earth.core.estimate.terrain_slopes`).

    With ``tolerance_m`` and ``max_object_m``, the cells of parts standing on walls and fitting
    the largest object turned in the grid (``sqrt(2) max_object_m``) are left out first
    (:func:`~bare_earth.core.estimate.raised_parts`; a wall: a step higher than ``tolerance_m``
    plus the steepest bank's rise, :data:`~bare_earth.core.estimate.GAP_BANK_SLOPE`, over the
    data's sample spacing ``spacing_cells``, at most :data:`_MAX_SPACING`) where they fill whole
    blocks: objects wider than a block put their roofs into its minimum and their walls into
    the slopes (a narrower one leaves the ground beside it in every block). A block of
    buildings 110-140 m round courtyards (``synthetic_sites`` ``courtyard``, like ISPRS
    samp23) read 20 degrees on level ground, 1.4 degrees without them. The parts are found on
    the block minima of at most a million cells
    (:func:`~bare_earth.core.estimate.raised_region_grid`, a step over their side). Where
    nothing is left to measure, the slopes of the whole surface are taken.

    Returns
    -------
    dict with ``median``, upper quartile ``p75`` and ``p90`` of |slope| (rise/run), the
    block size in cells and the share of the cells left out (``raised``: the blocks on
    raised parts).
    """
    z = as_surface(z)
    dx, dy = as_cell_size(cell_size)
    k = held_block_side(z.shape, max(2, round(scale_m / min(dx, dy))), min_blocks=3)
    s, share = np.empty(0), 0.0
    if tolerance_m is not None and max_object_m is not None:
        zs, (cx, cy), f = raised_region_grid(z, (dx, dy))
        lim = _oblique_reach((max(1, int(round(max_object_m / cy))), max(1, int(round(max_object_m / cx)))))
        spacing = max(1.0, min(float(spacing_cells), _MAX_SPACING) / f)
        raised = raised_parts(zs, float(tolerance_m) + min(cx, cy) * GAP_BANK_SLOPE * spacing, lim)
        if raised.any():
            if f > 1:
                raised = raised[np.arange(z.shape[0]) // f][:, np.arange(z.shape[1]) // f]
            # the blocks on such parts only (a narrower object leaves the ground beside it in
            # every block: those block minima stay as they are)
            on = ~np.isfinite(block_minima(np.where(raised, np.float32(np.nan), z), k))
            on &= np.isfinite(block_minima(z, k))
            if on.any():
                on = on[np.arange(z.shape[0]) // k][:, np.arange(z.shape[1]) // k]
                share = float(np.count_nonzero(on)) / z.size
                s = terrain_slopes(np.where(on, np.float32(np.nan), z), (dx, dy), k)
            del on
        del raised, zs
    if s.size == 0:
        s, share = terrain_slopes(z, (dx, dy), k), 0.0
    if s.size == 0:
        return {"median": 0.0, "p75": 0.0, "p90": 0.0, "block_cells": k, "raised": share}
    p50, p75, p90 = np.percentile(s, [50, 75, 90])
    return {"median": float(p50), "p75": float(p75), "p90": float(p90), "block_cells": k, "raised": share}


def estimate_sample_spacing(z, longest=8):
    """Mean length (cells) of the runs of identical neighbouring values along rows and columns.

    A DSM measured at every cell gives 1. A DSM gridded from sparser points with empty
    cells filled from the nearest point repeats each value over a run of cells, and its
    height steps come at the run ends: the edge test must span the data's own spacing,
    not one cell. Runs longer than ``longest`` cells are constant areas (water, a flat
    synthetic ground), not gridding, and are left out. Returns a value >= 1. Large
    rasters are sampled (:func:`~bare_earth.core.estimate.sample_windows`).
    """
    z = as_surface(z)
    lengths = []
    for w in sample_windows(z):
        for a in (w, w.T.copy()):
            if a.shape[1] < 2:
                continue
            start = np.ones(a.shape, bool)
            start[:, 1:] = a[:, 1:] != a[:, :-1]
            idx = np.flatnonzero(start.ravel())
            lengths.append(np.diff(np.append(idx, a.size)))
    if not lengths:
        return 1.0
    runs = np.concatenate(lengths)
    runs = runs[runs <= longest]
    return float(runs.mean()) if runs.size else 1.0


def _extreme3(a, op, out=None, tmp=None):
    """3 x 3 running max or min (``op`` = np.maximum / np.minimum), edges replicated.

    Separable, by slicing: four passes of one ufunc over the array; ``out`` and ``tmp``
    are optional buffers of ``a``'s shape (``out`` may not be ``a``).
    """
    if tmp is None:
        t = a.copy()
    else:
        np.copyto(tmp, a)
        t = tmp
    op(t[:, 1:], a[:, :-1], out=t[:, 1:])
    op(t[:, :-1], a[:, 1:], out=t[:, :-1])
    if out is None:
        out = t.copy()
    else:
        np.copyto(out, t)
    op(out[1:], t[:-1], out=out[1:])
    op(out[:-1], t[1:], out=out[:-1])
    return out


#: Window (cells) and rank of the local ground height a low blunder must lie below.
_LOW_WINDOW, _LOW_RANK = 7, 16
#: Candidates whose neighbourhoods are ranked at once.
_LOW_CHUNK = 1 << 16


def find_low_blunders(z, tolerance_m, progress=None):
    """Low blunders: pits of one or two cells deeper than ``tolerance_m`` below the ground.

    Candidates are the cells a 3 x 3 grey closing raises by more than the tolerance (a
    drop then a rise along every profile). A candidate is a blunder only when it is also
    more than the tolerance below the 16th-lowest of the 49 values of its 7 x 7
    neighbourhood (the lower third): a ground hit between tree crowns has other ground
    hits near it and is kept, while a blunder, even a cluster of a dozen cells, has only
    itself and its cluster that low.
    """
    z = as_surface(z)
    valid = np.isfinite(z)
    hi = np.float32(np.nanmax(z)) if valid.any() else np.float32(0.0)
    # candidates: cells a 3 x 3 closing raises by more than the tolerance, in strips of
    # rows (the closing reaches 2 rows), so memory stays a few strips whatever the raster
    rows, cols = z.shape
    strip = 64  # rows: the closing's buffers stay in the cache
    found = []
    for r0 in range(0, rows, strip):
        if r0 % (4 * strip) == 0:
            report(progress, 0.7 * r0 / rows)
        r1 = min(rows, r0 + strip)
        a0, a1 = max(0, r0 - 2), min(rows, r1 + 2)
        zz = np.where(valid[a0:a1], z[a0:a1], hi)  # nodata: neither a pit's rim nor its bottom
        tmp = np.empty_like(zz)
        dil = _extreme3(zz, np.maximum, tmp=tmp)
        closed = _extreme3(dil, np.minimum, out=tmp, tmp=dil.copy())
        closed -= zz
        cb = closed[r0 - a0:r0 - a0 + (r1 - r0)] > tolerance_m
        cb &= valid[r0:r1]
        q = np.flatnonzero(cb)                   # the band's candidates, while it is cached
        if q.size:
            found.append(q + r0 * cols)
    low = np.zeros(z.shape, bool)
    if not found:
        return low
    report(progress, 0.7)
    cand = np.concatenate(found)
    h = _LOW_WINDOW // 2
    off = np.arange(-h, h + 1)
    for i in range(0, cand.size, _LOW_CHUNK):          # bounded memory: 49 neighbours each
        r, c = np.divmod(cand[i:i + _LOW_CHUNK], cols)
        rr = np.clip(r[:, None, None] + off[None, :, None], 0, z.shape[0] - 1)   # edges replicated
        cc = np.clip(c[:, None, None] + off[None, None, :], 0, z.shape[1] - 1)
        neigh = z[rr, cc].reshape(r.size, _LOW_WINDOW * _LOW_WINDOW)
        neigh[np.isnan(neigh)] = np.inf                                        # nodata is no ground
        fifth = np.partition(neigh, _LOW_RANK - 1, axis=1)[:, _LOW_RANK - 1]
        low[r, c] = z[r, c] < fifth - tolerance_m
        report(progress, 0.7 + 0.3 * min(cand.size, i + _LOW_CHUNK) / cand.size)
    return low


#: Profile positions scanned between two progress reports.
_REPORT_STEPS = 128


def _scan(sources, step_m, tan_g, tan_t, dh0, init_cells, edge_cells=1, progress=None, with_runs=False,
          trends=None, edge_trends=None):
    """Scan many profile sets at once, one numpy operation per step over all profiles.

    ``sources`` is a list of ``(array, reverse)``: an array ``(npos, nprof)`` holds
    profiles along axis 0 (C-contiguous rows), scanned from its first row, or from its
    last with ``reverse``. At each step the current row of every source is copied into
    one small buffer (no stacked copy of the raster is made), so the per-step Python
    overhead is shared by all profiles of all sources.

    The tolerance ``d`` cells after the reference point is
    ``dh0 + step max(tan_g min(d, edge_cells), tan_t d)``: the paper's slope test from the
    reference point over the edge run, and further on the larger of the edge's allowance
    and the terrain's rise over the whole distance from the reference (the edge's
    allowance is not added to the terrain's rise along the object). The edge's allowance
    follows the ground's trend before the reference continued over the edge run:
    ``(f - step c) min(d, edge_cells)``, ``f`` the height change per cell from the
    previous reference to the last accepted cell, within ``[-step tan_t, step c]``, ``c`` the
    ground's rise ``tan_g`` allows for: ``tan_t``, but at most ``tan_g`` less the ground's
    micro-relief (:data:`_TAN_MICRO_RELIEF`), at least 0 (level ground gives the edge
    ``tan_g - c``; at a profile's start the ground is taken as rising at ``c``).
    With ``edge_trends`` (per source an array of its layout, forward sign: :func:`trends_before`)
    that change is at most the ground's trend before the reference plus the step's noise
    (``sqrt(2) dh0 / 3``): a step the trend does not follow, up a crown's flank or level across a
    crown on a falling hillside, is not the ground's; the terrain line's step below is that change.
    The terrain's line follows the ground's fall too: ``dh0 + d (step tan_t + t)``, ``t`` the
    ground's fall per cell at the reference (``<= 0``, at least ``-step tan_t``): the less steep
    of its trend there (``trends``: per source an array of its layout, the ground's rise per
    cell along the profile in the forward direction, metres; :func:`ground_trends`) and the
    step from the previous reference less its noise (``sqrt(2) dh0 / 3``, :data:`_STEP_NOISE`:
    a fall the two do not agree on is none); ``t = 0`` without ``trends``.
    A profile starts from
    the lowest point of its first ``init_cells``, ``m`` cells in: the profile is taken as
    mirrored at its start, so that point is the reference ``m`` cells before the first
    cell, and the tolerance grows with the distance from it as anywhere else.
    A cell the tolerance accepts after a rejected run (``d > 1``: coming down off an
    object) while the next cell lies below it by more than the edge's one-cell step
    ``dh0 + step tan_g`` is still on the object's flank: rejected, the reference kept.
    Returns one boolean array per source (its shape; views into buffers shared by the
    sources of one array): True where the scan rejects. ``progress(fraction)`` is called
    every :data:`_REPORT_STEPS` positions (it may raise Cancelled).

    Raised runs: a cell accepted after a rejected run (``d > 1``) only by the terrain's
    rise (above the edge's allowance), the rejected run having begun with a wall up (a
    one-cell rise above ``aw = dh0 + step max(tan_g, 1)``, steeper than any bank), opens a
    run ``d0`` cells after the reference. The run is closed on the ground when an
    accepted cell lies more than ``aw`` below the reference (a wall down); it lapses
    ``init_cells`` (the largest object) after that reference. With ``with_runs`` a second
    list (same layout) is returned: the cells of the runs closed on the ground.
    """
    widths = [a.shape[1] for a, _ in sources]
    offs = np.cumsum([0] + widths)
    nprof = int(offs[-1])
    npos = max(a.shape[0] for a, _ in sources)
    g = np.empty(nprof, np.float32)                  # reference ground height per profile
    k = np.zeros(nprof, np.float32)                  # k = d - 1 (see below)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for (a, rev), o0, o1 in zip(sources, offs[:-1], offs[1:]):
            head = a[-init_cells:] if rev else a[:init_cells]
            g[o0:o1] = np.nanmin(head, axis=0)
            # the start minimum's position m from the scan's start: mirrored, it lies m
            # cells before the first cell (d = m there, k = m - 1)
            head = np.where(np.isnan(head), np.inf, head)
            m = np.argmin(head[::-1] if rev else head, axis=0)
            k[o0:o1] = np.maximum(m - 1, 0)
    g[np.isnan(g)] = np.inf     # no ground in the start window: the first valid cell is accepted
    # The tolerance is dh0 + step max(tan_g min(d, e), tan_t d) in k = d - 1, the valid
    # cells rejected since the reference point: the terrain's line a2 + b2 k, raised to the
    # edge's line a1 + b1 k held at its value at the edge run's end (a1e). k is a float32
    # count (exact), so a line costs two operations per step, no table lookup; with a
    # one-cell edge run the edge's line is the constant a1: one maximum.
    e = int(edge_cells)
    a2, b2 = np.float32(dh0 + step_m * tan_t), np.float32(step_m * tan_t)
    a1, b1 = np.float32(dh0 + step_m * tan_g), np.float32(step_m * tan_g)
    a1e = np.float32(dh0 + step_m * tan_g * max(e, 1))
    two_lines = e > 1
    # Rejections, step by step: one buffer per array scanned (its forward and backward
    # sources side by side, as many rows as the array), one row written per step.
    groups = []                                  # [array, first, last column in v]
    member = []                                  # per source: its group
    for (a, _), o0, o1 in zip(sources, offs[:-1], offs[1:]):
        if groups and groups[-1][0] is a and groups[-1][2] == o0:
            groups[-1][2] = o1
        else:
            groups.append([a, o0, o1])
        member.append(len(groups) - 1)
    bufs = [np.empty((a.shape[0], o1 - o0), bool) for a, o0, o1 in groups]
    runs = [np.empty((a.shape[0], o1 - o0), bool) for a, o0, o1 in groups]    # cells within a raised run
    writes = [(buf, rb, a.shape[0], o0, o1) for buf, rb, (a, o0, o1) in zip(bufs, runs, groups)]
    v = np.full(nprof, np.nan, np.float32)
    dz = np.empty(nprof, np.float32)
    thr = np.empty(nprof, np.float32)              # the terrain's line
    thr[:] = a2 + k * b2                           # (the mirrored start's distances)
    thr1 = np.empty(nprof, np.float32) if two_lines else None    # the edge's line
    if two_lines:
        thr1[:] = np.minimum(a1 + k * b1, a1e)
    up = np.empty(nprof, bool)
    ok = np.empty(nprof, bool)
    # per source: its array, direction, slice of the step buffer, and length
    spans = [(a, rev, v[o0:o1], a.shape[0]) for (a, rev), o0, o1 in zip(sources, offs[:-1], offs[1:])]
    n_min = min(n for *_, n in spans)
    # Once the trailing sources have ended, the steps work on the profiles before them only
    # (a strip's Y profiles end before its X profiles: a third less work there).
    ends = np.zeros(npos, np.intp)                 # per step: the end of the last running source
    for (a, _), o1 in zip(sources, offs[1:]):
        np.maximum(ends[:a.shape[0]], o1, out=ends[:a.shape[0]])
    ends = ends.tolist()
    nok = np.empty(nprof, bool)
    # the next cell of every profile (NaN past its end) and the re-entries it holds back
    nx = np.full(nprof, np.nan, np.float32)
    held = np.empty(nprof, bool)
    # raised runs: accepted only through the terrain's rise under an object (see above)
    run = np.zeros(nprof, bool)                    # a run is open
    d0 = np.zeros(nprof, np.float32)               # cells from the ground before it to the current one
    rise = np.empty(nprof, bool)
    wall = np.zeros(nprof, bool)                   # the rejected run began with a wall up
    # the ground's change per cell up to the reference less the rise c that tan_g allows for
    # (within [-b2 - c, 0]; 0 at the start: rising at c) and the edge test's change along it
    # (see above)
    fall = np.zeros(nprof, np.float32)
    along = np.empty(nprof, np.float32)
    # the ground's fall per cell at the reference along the terrain's line (within [-b2, 0]),
    # the trend at the cell being scanned, and each profile's direction (+1 forward, -1 back)
    tfall = np.zeros(nprof, np.float32)
    tcur = np.zeros(nprof, np.float32) if trends is not None else None
    if trends is not None:
        if len(trends) != len(sources):
            raise ValueError("one trend array per source")
        tsign = np.concatenate([np.full(o1 - o0, -1.0 if rev else 1.0, np.float32)
                                for (_, rev), o0, o1 in zip(sources, offs[:-1], offs[1:])])
        tspans = [(t, rev, tcur[o0:o1], a.shape[0]) for t, (a, rev), o0, o1 in zip(trends, sources, offs[:-1],
                                                                                   offs[1:])]
        step_noise = np.float32(_STEP_NOISE * dh0)
        if edge_trends is not None:
            if len(edge_trends) != len(sources):
                raise ValueError("one edge trend array per source")
            etcur = np.zeros(nprof, np.float32)
            etspans = [(t, rev, etcur[o0:o1], a.shape[0]) for t, (a, rev), o0, o1 in
                       zip(edge_trends, sources, offs[:-1], offs[1:])]
    elif edge_trends is not None:
        raise ValueError("edge trends need the terrain line's trends")
    fall_min, e_cells = np.float32(-b2), np.float32(max(e, 1))
    # the ground's rise tan_g allows for: tan_t, but no more than leaves the edge the ground's
    # micro-relief (the derived alpha_g's floor) over level ground
    rise_c = np.float32(step_m * max(0.0, min(tan_t, tan_g - _TAN_MICRO_RELIEF)))
    dzr = np.empty(nprof, np.float32)
    lim = np.empty(nprof, np.float32)
    kills = {}                                     # scan position -> profiles whose run ends on the ground
    run_cells = np.float32(init_cells)
    aw = np.float32(dh0 + step_m * max(tan_g, GAP_BANK_SLOPE))   # a wall's drop: steeper than any bank
    nspans = [(a, rev, nx[o0:o1], a.shape[0]) for (a, rev), o0, o1 in zip(sources, offs[:-1], offs[1:])]
    state = (v, dz, thr, up, ok, k, g, nok, nx, held, run, d0, rise, dzr, lim, wall, fall, along, tfall) + \
        ((thr1,) if two_lines else ())
    views, end = state, nprof
    # As few numpy calls per step as possible: each is short, and with blocks in threads
    # every call is a hand-over of the GIL.
    for i in range(npos):
        if progress is not None and i % _REPORT_STEPS == 0:
            report(progress, i / npos)
        if ends[i] != end:
            end = ends[i]
            views = tuple(x[:end] for x in state)
        (vw, dzw, thrw, upw, okw, kw, gw, nokw, nxw, heldw, runw, d0w, risew, dzrw, limw, wallw, fw, alw,
         tfw) = views[:19]
        if i < n_min:                                  # every source still runs: one copy
            np.concatenate([a[n - 1 - i] if rev else a[i] for a, rev, _, n in spans], out=v)
        else:
            for a, rev, vv, n in spans:
                if i < n:
                    vv[...] = a[n - 1 - i] if rev else a[i]
                elif i == n:
                    vv[...] = np.nan                   # a shorter profile set has ended
        if i + 1 < n_min:
            np.concatenate([a[n - 2 - i] if rev else a[i + 1] for a, rev, _, n in nspans], out=nx)
        else:
            for a, rev, vv, n in nspans:
                if i + 1 < n:
                    vv[...] = a[n - 2 - i] if rev else a[i + 1]
                elif i + 1 == n:
                    vv[...] = np.nan                   # this profile set's last cell: no next
        np.subtract(vw, gw, out=dzrw)                  # above the reference
        # the tolerance: the terrain's line, or the edge's along the ground's trend
        # continued from the reference over the edge run (d cells, at most e)
        np.add(kw, 1, out=alw)
        np.minimum(alw, e_cells, out=alw)
        alw *= fw
        if two_lines:
            alw += views[19]
        else:
            alw += a1
        np.maximum(alw, thrw, out=alw)
        np.greater(dzrw, alw, out=upw)                 # rejected (NaN compares False)
        np.less_equal(dzrw, alw, out=okw)              # accepted: valid and not rejected
        # coming down off an object (k > 0), a cell above the next by more than the edge's
        # step is still on the way down (a wall's foot, a crown's rim): not yet the ground
        np.subtract(vw, nxw, out=dzw)
        np.greater(dzw, a1, out=heldw)
        heldw &= okw
        np.logical_and(heldw, kw, out=heldw)
        okw ^= heldw
        upw |= heldw
        # raised runs. An open run whose profile comes down a wall (an accepted cell below
        # the reference by more than aw) ends on the ground: the run was an object's top.
        # (The wall's foot is below the level the ground before the run, d0 cells back,
        # may have risen to: the run's first cell was accepted within it, aw higher.)
        d0w += runw
        np.less(dzrw, -aw, out=risew)
        risew &= runw
        risew &= okw
        if risew.any():
            kills[i] = np.flatnonzero(risew)
            runw ^= risew
        np.logical_and(runw, d0w <= run_cells, out=runw)   # no object is longer: the ground rose
        # a rejected run begins (k = 0): with a wall up, steeper than any bank?
        np.logical_not(kw, out=risew)
        risew &= upw
        np.putmask(wallw, risew, dzrw > aw)
        # a run opens at a cell accepted after a rejected run (k > 0) only through the
        # terrain's rise: higher than the edge's allowance above the reference
        if two_lines:
            np.multiply(kw, b1, out=limw)
            limw += a1
            np.minimum(limw, a1e, out=limw)
            np.greater(dzrw, limw, out=risew)
        else:
            np.greater(dzrw, a1, out=risew)
        risew &= okw
        np.logical_and(risew, kw, out=risew)
        np.logical_and(risew, ~runw, out=risew)
        risew &= wallw
        np.putmask(d0w, risew, kw + 1)
        runw |= risew
        np.add(kw, 1, out=alw)                         # an accepted cell: the ground's change
        np.divide(dzrw, alw, out=alw)                  # per cell from the reference
        if edge_trends is not None:
            # no more rising than the ground's trends before the reference show, beyond the
            # step's noise (a step onto a crown's flank or a level top they do not follow)
            _load_rows(etspans, i, n_min, etcur)
            etw = etcur[:end]
            etw *= tsign[:end]
            etw += step_noise
            np.minimum(alw, etw, out=alw)
        np.maximum(alw, fall_min, out=alw)             # within the terrain's slope, less the rise
        np.minimum(alw, rise_c, out=alw)               # (two ufuncs: np.clip's wrapper costs 1.5 x)
        alw -= rise_c                                  # tan_g allows for: f - c <= 0
        np.putmask(fw, okw, alw)
        if trends is not None:
            # the terrain line's fall at an accepted cell: the less steep of the ground's trend
            # there and its step from the reference (both within [-b2, 0])
            _load_rows(tspans, i, n_min, tcur)
            tw = tcur[:end]
            tw *= tsign[:end]
            np.add(alw, rise_c, out=limw)                  # the step, within [-b2, rise_c],
            limw += step_noise                             # beyond its noise
            # max(clip(t, -b2, 0), min(step, 0)) as max(min(max(t, step), 0), -b2): the same
            # values (min and max are monotone), three ufuncs instead of np.clip's wrapper
            np.maximum(tw, limw, out=tw)
            np.minimum(tw, 0, out=tw)
            np.maximum(tw, fall_min, out=tw)
            np.putmask(tfw, okw, tw)
        kw += upw                                      # a nodata cell does not count: a gap does
        np.logical_not(okw, out=nokw)                  # not let the reference drift up a roof.
        kw *= nokw                                     # k = 0 and g = v where accepted: a product
        np.putmask(gw, okw, vw)                        # and putmask, 2-5 x faster than where=
        np.add(tfw, b2, out=limw)                      # the next step's terrain line, along the
        np.multiply(kw, limw, out=thrw)                # ground's fall: dh0 + d (b2 + t), as
        thrw += a2                                     # a2 + k (b2 + t) + t
        thrw += tfw
        if two_lines:                                  # the edge's line, up to the edge run
            thr1w = views[19]
            np.multiply(kw, b1, out=thr1w)
            thr1w += a1
            np.minimum(thr1w, a1e, out=thr1w)
        for buf, rb, n, o0, o1 in writes:
            if i < n:
                buf[i] = up[o0:o1]
                rb[i] = run[o0:o1]
    # the runs that ended on the ground: back from their end, along their cells
    carry = np.zeros(nprof, bool)
    for i in range(npos - 1, -1, -1):
        for _, rb, n, o0, o1 in writes:
            if i < n:
                c = carry[o0:o1]
                c &= rb[i]
                rb[i] = c
        if i in kills:                                 # the cell ending the run is ground
            carry[kills[i]] = True
    if not with_runs:
        return _source_views(sources, offs, member, groups, bufs)
    return (_source_views(sources, offs, member, groups, bufs),
            _source_views(sources, offs, member, groups, runs))


def _load_rows(spans, i, n_min, out):
    """Step ``i``'s row of every source's array of ``spans`` (``(array, reverse, view of out, length)``)
    into ``out``: one copy while every source runs, then the running ones only."""
    if i < n_min:
        np.concatenate([t[n - 1 - i] if rev else t[i] for t, rev, _, n in spans], out=out)
    else:
        for t, rev, tt, n in spans:
            if i < n:
                tt[...] = t[n - 1 - i] if rev else t[i]


def _source_views(sources, offs, member, groups, bufs):
    """Per source, its columns of its group's step buffer, in the source's row order."""
    out = []
    for (_, rev), o0, o1, k in zip(sources, offs[:-1], offs[1:], member):
        r = bufs[k][:, o0 - groups[k][1]:o1 - groups[k][1]]
        out.append(r[::-1] if rev else r)                # views: row order of the source
    return out


#: Scans of blocks running in threads take turns: a scan is thousands of short numpy
#: calls, each handing the GIL over, so two at once run no faster than one after the
#: other (measured), while a thread waiting here leaves the core to the other threads'
#: long array operations (filling, labelling).
_SCAN_LOCK = threading.Lock()


def trend_cells(cell_size):
    """Side in cells of the running minimum of :func:`ground_trends` (:data:`TREND_SIDE_M`, at
    least 2): also how far from a cell the surface it reads reaches (the halo's share)."""
    return max(2, int(round(TREND_SIDE_M / min(as_cell_size(cell_size)))))


def ground_trends(zs, cell_size):
    """The ground's trend along X and along Y, rise per cell (metres, float32, ``zs``'s shape):
    the gradient of the running minimum over :func:`trend_cells` cells
    (:func:`~bare_earth.core.estimate.running_minimum_gradient`: the ground's slope around a cell,
    below the shrubs and crowns beside it) times the cell's size along the axis; 0 where not
    finite (nodata or low blunders all around: no trend).

    Examples
    --------
    >>> gx, gy = ground_trends(np.tile(0.5 * np.arange(12, dtype=np.float32), (12, 1)), (2.0, 2.0))
    >>> float(gx[6, 6]), float(gy[6, 6])
    (0.5, 0.0)
    """
    dx, dy = as_cell_size(cell_size)
    gx, gy = running_minimum_gradient(zs, (dx, dy), trend_cells((dx, dy)))
    for g, step in ((gx, dx), (gy, dy)):
        g *= np.float32(step)
        g[~np.isfinite(g)] = 0.0
    return gx, gy


def trends_before(trend, axis, cell_size):
    """The ground's trend before a scan's position, for the forward and the backward scans along
    ``axis`` (1: X, the rows; 0: Y, the columns) of ``trend`` (:func:`ground_trends`' array for that
    axis, rise per cell in the forward direction): at each cell the more rising, for the scan, of
    the trend there and the trend ``2 (s // 2)`` cells behind it (``s`` :func:`trend_cells`), whose
    running minimum covers only cells the scan has passed (0 where that lies beyond the raster's
    edge, as the trend there). Returns ``(forward, backward)``, ``trend``'s shape, both in the
    forward direction's sign: the forward scan's ``max(t[i - 2h], t[i])``, the backward scan's
    ``min(t[i + 2h], t[i])``.

    Examples
    --------
    >>> t = np.array([[0.0, 0.0, -1.0, -1.0, -1.0, -1.0, 0.0, 0.0]], np.float32)
    >>> f, b = trends_before(t, 1, (5.0, 5.0))      # 2 cells behind at 5 m cells (s = 2)
    >>> f.tolist(), b.tolist()
    ([[0.0, 0.0, 0.0, 0.0, -1.0, -1.0, 0.0, 0.0]], [[-1.0, -1.0, -1.0, -1.0, -1.0, -1.0, 0.0, 0.0]])
    """
    lag = 2 * (trend_cells(cell_size) // 2)
    fwd = np.array(trend, np.float32)
    bwd = fwd.copy()
    n = fwd.shape[axis]
    before = np.zeros(fwd.shape, np.float32)

    def part(a, b):
        return (slice(None), slice(a, b)) if axis == 1 else (slice(a, b), slice(None))
    if n > lag:
        before[part(lag, n)] = trend[part(0, n - lag)]
    np.maximum(fwd, before, out=fwd)
    before[...] = 0.0
    if n > lag:
        before[part(0, n - lag)] = trend[part(lag, n)]
    np.minimum(bwd, before, out=bwd)
    return fwd, bwd


def scan_profiles(zs, cell_size, tan_g, tan_t, dh0, init, edge, progress=None, trends=True):
    """Forward and backward scans along X and Y; returns ``(objects_x, objects_y, raised_x,
    raised_y)``.

    A cell is rejected along an axis when both its forward and its backward scan reject
    it. The four scans run as one vectorised pass when the two axes share a spacing.
    ``init`` and ``edge`` are the start windows and edge runs ``(x, y)`` in cells.
    ``raised_*`` are the rejections with the raised runs of each scan added
    (:func:`_scan`). ``trends``: the terrain's line follows the ground's trend
    (:func:`ground_trends`; False: the terrain's rise from the reference only).
    """
    dx, dy = cell_size
    tx = ty = ex = ey = None
    if trends:
        gx, ty = ground_trends(zs, cell_size)
        ex = [transpose(e) for e in trends_before(gx, 1, cell_size)]
        ey = list(trends_before(ty, 0, cell_size))
        tx = transpose(gx)
        del gx
        tx, ty = [tx, tx], [ty, ty]
    report(progress, 0.03)
    zx = transpose(zs)                       # X profiles: positions = columns
    report(progress, 0.05)
    sx = [(zx, False), (zx, True)]
    sy = [(zs, False), (zs, True)]
    with _SCAN_LOCK:
        if abs(dx - dy) <= 1e-9 * max(dx, dy) and init[0] == init[1] and edge[0] == edge[1]:
            # the longer profiles first: once the shorter have ended, each step works on the
            # longer ones only (a 3 x 50000 strip's 100000 X profiles of 3 cells scanned
            # along with its Y profiles at each of their 50000 steps: 134 s)
            tall = zs.shape[0] > zs.shape[1]
            (f1, b1, f2, b2), (r1, s1, r2, s2) = _scan(
                sy + sx if tall else sx + sy, dx, tan_g, tan_t, dh0, init[0], edge[0],
                sub_progress(progress, 0.05, 0.9), True,
                None if tx is None else (ty + tx if tall else tx + ty),
                None if ex is None else (ey + ex if tall else ex + ey))
            (fx, bx, fy, by), (rfx, rbx, rfy, rby) = \
                ((f2, b2, f1, b1), (r2, s2, r1, s1)) if tall else ((f1, b1, f2, b2), (r1, s1, r2, s2))
        else:
            (fx, bx), (rfx, rbx) = _scan(sx, dx, tan_g, tan_t, dh0, init[0], edge[0],
                                         sub_progress(progress, 0.05, 0.45), True, tx, ex)
            (fy, by), (rfy, rby) = _scan(sy, dy, tan_g, tan_t, dh0, init[1], edge[1],
                                         sub_progress(progress, 0.45, 0.9), True, ty, ey)
    del zx, tx, ty, ex, ey
    rfx |= fx
    rbx |= bx
    rfx &= rbx
    rfy |= fy
    rby |= by
    rfy &= rby
    fx &= bx
    fy &= by
    report(progress, 0.9)
    return transpose(fx), fy, transpose(rfx), rfy


#: Share of an object's cells that both axes must reject (see :func:`_combine_axes`).
_MIN_BOTH_AXES_SHARE = 0.1


def _window_sum(a, buf, r, axis):
    """``a`` (int32) replaced in place by its sums over ``[i - r, i + r]`` along ``axis``
    (clipped at the edges), from its running sum in ``buf``."""
    if axis == 1:
        np.cumsum(a, axis=1, out=buf)        # along the rows: contiguous, fast
        a, buf = a.T, buf.T                  # the window arithmetic below runs on axis 0
    else:                                    # row by row: numpy's cumsum down the columns is
        buf[0] = a[0]                        # ten times slower
        for i in range(1, a.shape[0]):
            np.add(buf[i - 1], a[i], out=buf[i])
    n = a.shape[0]
    if r >= n:
        a[...] = buf[n - 1]
        return
    a[:n - r] = buf[r:]                      # window end inside
    a[n - r:] = buf[n - 1]                   # window end clipped
    a[r + 1:] -= buf[:n - r - 1]             # minus the running sum before the window


def _box_sum(a, ry, rx):
    """``a`` (int32, changed in place and returned) summed over the (2 ry + 1) x (2 rx + 1)
    window around every cell, windows clipped at the edges: exact integer running sums,
    one buffer."""
    buf = np.empty_like(a)
    _window_sum(a, buf, ry, 0)
    _window_sum(a, buf, rx, 1)
    return a


def _large_regions(lab, total, reach):
    """Labels (bool, index = label) of the regions of ``lab`` whose bounding box exceeds
    ``reach = (rows, cols)``; ``total`` holds their cell counts (only regions with more
    cells than the smaller reach can be that large)."""
    large = np.zeros(total.size, bool)
    cand = np.flatnonzero(total > min(reach))
    cand = cand[cand > 0]
    if cand.size == 0:
        return large
    boxes = ndimage.find_objects(lab)
    ext = np.array([(boxes[i - 1][0].stop - boxes[i - 1][0].start, boxes[i - 1][1].stop - boxes[i - 1][1].start)
                    for i in cand])
    large[cand] = (ext[:, 0] > reach[0]) | (ext[:, 1] > reach[1])
    return large


def _local_share_kept(big, both, reach):
    """Cells of the large regions ``big`` where at least :data:`_MIN_BOTH_AXES_SHARE` of the
    large regions' cells within ``reach / 2`` are rejected by both axes.

    share >= 1/10 <=> the window's sum of (9 where both, -1 elsewhere on ``big``) >= 0,
    an exact integer box sum, on the bounding box of ``big`` grown by the window only.
    """
    ry, rx = reach[0] // 2, reach[1] // 2
    rows = np.flatnonzero(big.any(axis=1))
    cols = np.flatnonzero(big.any(axis=0))
    r0, r1 = max(0, rows[0] - ry), min(big.shape[0], rows[-1] + ry + 1)
    c0, c1 = max(0, cols[0] - rx), min(big.shape[1], cols[-1] + rx + 1)
    sub = (slice(r0, r1), slice(c0, c1))
    w = np.zeros((r1 - r0, c1 - c0), np.int32)
    w[big[sub]] = -1
    w[big[sub] & both[sub]] = round(1.0 / _MIN_BOTH_AXES_SHARE) - 1
    out = np.zeros(big.shape, bool)
    out[sub] = big[sub] & (_box_sum(w, ry, rx) >= 0)
    return out


def _oblique_reach(reach):
    """The bounding box ``(rows, cols)`` of the largest object turned in the grid:
    ``ceil(sqrt(2) reach)`` (a square of side ``L`` at 45 degrees spans ``sqrt(2) L``)."""
    return tuple(int(np.ceil(np.sqrt(2.0) * r)) for r in reach)


def _one_axis_runs(big, obj_x, obj_y, reach):
    """Cells of the large regions ``big`` on a connected run rejected by one axis only
    (by X and not Y, or by Y and not X) whose bounding box exceeds the largest object
    turned in the grid (:func:`_oblique_reach`).

    Such a run is no part of an object: an object's cells rejected by one axis only lie
    within its own extent, while a road embankment or a dam that the other axis's profiles
    run along is accepted by them over its whole length. Trees or a bridge on it (rejected
    by both axes) gave it the local share of :func:`_local_share_kept` and kept all of it
    as an object (issue 12: the synthetic embankment, ISPRS sample 71's ramps).
    """
    out = np.zeros(big.shape, bool)
    lim = _oblique_reach(reach)
    for one in (big & obj_x & ~obj_y, big & obj_y & ~obj_x):
        if not one.any():
            continue
        lab, n = ndimage.label(one, structure=np.ones((3, 3), bool))
        total = np.bincount(lab[one], minlength=n + 1)
        long_runs = _large_regions(lab, total, lim)
        out[one] |= long_runs[lab[one]]
    return out


def _raised_objects(obj, reach):
    """The connected regions of ``obj`` whose bounding box fits the largest object turned
    in the grid (:func:`_oblique_reach` of ``reach = (rows, cols)``). A raised run ends on
    a wall down to the ground before it: a roof, or a stretch of an embankment, a dam or a
    terrace between walls; a region that exceeds the largest object is terrain. ``obj`` holds
    the raised runs' cells only, not the objects they touch (a roof beside a row of trees
    crossing the raster is no longer region)."""
    lab, n = ndimage.label(obj, structure=np.ones((3, 3), bool))
    if n == 0:
        return obj
    total = np.bincount(lab[obj], minlength=n + 1)
    large = _large_regions(lab, total, _oblique_reach(reach))
    large[0] = True
    return ~large[lab]


def _walled_regions(raised, obj, z, wall_m):
    """The connected regions of ``raised`` (cells not in ``obj``) walled where they meet the
    ground: at least half of their edges to ground cells (4-neighbours, valid, outside
    ``obj`` and ``raised``) drop by more than a wall (``wall_m = (x, y)``, the one-cell drop
    steeper than any bank along each axis), or no edge meets the ground (a roof's middle
    among its rims). A roof is walled all round; a level area that a profile entered up
    the side of a pit or of a blunder line (a wall whose foot is a low outlier) is walled
    only where the pits are, and elsewhere goes on level into the ground."""
    lab, n = ndimage.label(raised, structure=np.ones((3, 3), bool))
    if n == 0:
        return raised
    ground = np.isfinite(z) & ~obj & ~raised
    edges = np.zeros(n + 1, np.int64)
    walls = np.zeros(n + 1, np.int64)
    for a, b, w in (((slice(None), slice(None, -1)), (slice(None), slice(1, None)), wall_m[0]),
                    ((slice(None, -1), slice(None)), (slice(1, None), slice(None)), wall_m[1])):
        for s, t in ((a, b), (b, a)):
            e = (lab[s] > 0) & ground[t]
            li = lab[s][e]
            edges += np.bincount(li, minlength=n + 1)
            with np.errstate(invalid="ignore"):
                walls += np.bincount(li[z[t][e] < z[s][e] - np.float32(w)], minlength=n + 1)
    keep = 2 * walls >= edges
    keep[0] = False
    return keep[lab]


def _long_levels(big, z, step_m, wall_m, reach):
    """Cells of the large regions ``big`` on a level longer than any object and not walled:
    a smooth part of ``big`` (cells joined by steps between 8-neighbours of at most
    ``step_m``, :func:`~.estimate.smooth_parts`) whose bounding box exceeds the largest object
    turned in the grid (:func:`_oblique_reach`), at cells where fewer than half of the steps
    down out of such levels within ``reach / 2`` (4-neighbour edges to cells outside them,
    lower by more than ``step_m``) drop like walls (by more than ``wall_m = (x, y)``, the
    one-cell drop steeper than any bank).

    A road or railway embankment crossing the grid obliquely is climbed by both axes'
    profiles, so neither gives it back (:func:`_one_axis_runs`), but its crest is one level
    longer than any object that ends on banks. A roof that long ends on walls; a closed
    canopy is no level at the tolerance's steps (opengeos, 2 m: a highway embankment
    5 m high crossing the tile; issue 12).
    """
    cells = np.flatnonzero(big)
    n, part = smooth_parts(z, cells, step_m)
    lab = np.zeros(big.shape, np.int32)
    lab.ravel()[cells] = part + 1
    total = np.bincount(part + 1, minlength=n + 1)
    long_lv = _large_regions(lab, total, _oblique_reach(reach))
    long_lv[0] = False
    level = long_lv[lab]
    if not level.any():
        return level
    # steps down out of the levels, and those steep as walls, counted at the level's cell
    down = np.zeros(big.shape, np.int32)
    walls = np.zeros(big.shape, np.int32)
    for a, b, w in (((slice(None), slice(None, -1)), (slice(None), slice(1, None)), wall_m[0]),
                    ((slice(None, -1), slice(None)), (slice(1, None), slice(None)), wall_m[1])):
        for s, t in ((a, b), (b, a)):
            with np.errstate(invalid="ignore"):
                drop = z[s] - z[t]
                e = level[s] & ~level[t] & (drop > np.float32(step_m))
                down[s] += e
                walls[s] += e & (drop > np.float32(w))
    # walled where 2 walls >= downs over the window: an exact integer box sum
    w = 2 * walls - down
    return level & (_box_sum(w, reach[0] // 2, reach[1] // 2) < 0)


def _banks_below(level, cand, z, step_m, wall_m, steps):
    """Cells of ``cand`` reached from ``level`` going down a bank: by steps between
    8-neighbours each lower by more than the noise ``step_m`` and by less than a wall
    (``wall_m = (x, y)``, the one-cell drop steeper than any bank, along the diagonals the
    same slope over its length), within ``steps`` steps of the level, and not bumps: cells
    standing above the line between their opposite neighbours by more than ``step_m`` in all
    four directions (a shrub on the bank, lower than the bank above it; a bank's cell lies on
    that line at least along its contour, a crest's shoulder too).

    The banks of an embankment's crest (:func:`_long_levels`: a level longer than any
    object that ends on banks; or a run given back by :func:`_one_axis_runs`) are climbed by
    the profiles of both axes where it crosses the grid obliquely or turns, so both reject
    them, as they reject an object's side; but a bank goes down from the crest to the ground
    all along its length, while a crown beside the crest rises above it, a roof ends on a
    wall, and a bridge's deck goes on level from its ramp (synthetic_bare ``levees``: dikes
    2-6 m high with 1:2 and 1:3 banks, 2.9-5.4 % of the ground lost; issue 12). Without the
    bumps left out, the shrubs on a road embankment's sides were given back too
    (``synthetic_sites`` embankment 2 m highest: 2.73 -> 3.02 % total error, 2.91 with them).
    """
    rows = np.flatnonzero((level | cand).any(axis=1))
    cols = np.flatnonzero((level | cand).any(axis=0))
    sub = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
    zz, lv, cd = z[sub], level[sub], cand[sub] & ~level[sub]
    lo = np.float32(step_m)
    # a bump (a shrub or a crown on the bank) stands above the line between its opposite
    # neighbours in every direction; a bank's cell lies on it at least along its contour
    bump = cd.copy()
    mid = (slice(1, -1), slice(1, -1))
    with np.errstate(invalid="ignore"):
        for a, b in (((slice(1, -1), slice(None, -2)), (slice(1, -1), slice(2, None))),
                     ((slice(None, -2), slice(1, -1)), (slice(2, None), slice(1, -1))),
                     ((slice(None, -2), slice(None, -2)), (slice(2, None), slice(2, None))),
                     ((slice(None, -2), slice(2, None)), (slice(2, None), slice(None, -2)))):
            bump[mid] &= zz[mid] - 0.5 * (zz[a] + zz[b]) > lo
    bump[0], bump[-1], bump[:, 0], bump[:, -1] = False, False, False, False
    cd &= ~bump
    wd = float(step_m) + float(np.hypot(wall_m[0] - step_m, wall_m[1] - step_m))
    moves = []                        # (source slice, target slice, edge allowed)
    for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
        w = wall_m[0] if dr == 0 else wall_m[1] if dc == 0 else wd
        a = (slice(None, -dr if dr else None), slice(max(0, -dc), zz.shape[1] - max(0, dc)))
        b = (slice(dr, None), slice(max(0, dc), zz.shape[1] - max(0, -dc)))
        for s, t in ((a, b), (b, a)):
            with np.errstate(invalid="ignore"):
                drop = zz[s] - zz[t]
                ok = cd[t] & (drop > lo) & (drop <= np.float32(w))
            moves.append((s, t, ok))
    reached = lv.copy()
    front = lv
    for _ in range(int(steps)):
        new = np.zeros(lv.shape, bool)
        for s, t, ok in moves:
            new[t] |= front[s] & ok
        new &= ~reached
        if not new.any():
            break
        reached |= new
        front = new
    out = np.zeros(level.shape, bool)
    out[sub] = reached & ~lv
    return out


def _stepped_runs(one, z, step_m, axis, longest):
    """Cells of ``one`` whose run along ``axis`` (a maximal run of its cells along the rows,
    ``axis=1``, or the columns, ``axis=0``) of at most ``longest`` cells stands on a step at both
    its ends: both cells beyond its first cell, and both beyond its last, lie below that end by
    more than ``step_m`` (the paper's one-cell test, steeper than alpha_g; a one-cell hole
    beside a run is no step). NaN cells and the raster's edge within them are no step.

    Works on the runs' ends only (their flat indices), not on raster-sized heights.
    """
    a = one if axis == 1 else one.T
    n, m = a.shape
    out = np.zeros(one.shape, bool)
    if m < 3 or not a.any():
        return out
    start = a.copy()
    start[:, 1:] &= ~a[:, :-1]
    s = np.flatnonzero(start)
    del start
    end = a.copy()
    end[:, :-1] &= ~a[:, 1:]
    e = np.flatnonzero(end)                  # the k-th run's last cell: runs never span lines
    del end

    def height(flat):
        r, c = np.divmod(flat, m)
        return z[r, c] if axis == 1 else z[c, r]

    lim = np.float32(step_m)
    ok = (e - s < int(longest)) & (s % m >= 2) & (e % m <= m - 3)
    s, e = s[ok], e[ok]
    with np.errstate(invalid="ignore"):
        zs, ze = height(s), height(e)
        ok = zs - np.maximum(height(s - 1), height(s - 2)) > lim
        ok &= ze - np.maximum(height(e + 1), height(e + 2)) > lim    # NaN compares False
    s, e = s[ok], e[ok]
    if s.size == 0:
        return out
    lens = e - s + 1
    cells = np.arange(int(lens.sum()), dtype=np.int64) + np.repeat(s - (np.cumsum(lens) - lens), lens)
    r, c = np.divmod(cells, m)
    if axis == 1:
        out[r, c] = True
    else:
        out[c, r] = True
    return out


def _combine_axes(obj_x, obj_y, ok, reach, progress=None, levels=None, decks=None, crossed=None):
    """X and Y results -> objects: the union, keeping each connected object only when at
    least a tenth of its cells are rejected by both axes.

    Buildings and crowns are crossed by both axes; a road embankment or a dam that one
    axis runs along is accepted by that axis along most of its length, so the other
    axis's rejections of it are given back to the ground.

    An object is at most ``reach = (rows, cols)`` cells (the largest object): a connected
    region larger than that is objects touching embankments, hedges or each other, and
    its share is taken locally, over the region's cells within ``reach / 2`` of each cell
    (so a building touching a long dam stays an object, and the decision does not depend
    on how far the region runs: blocks give the one-pass result), once its runs rejected
    by one axis only and longer than any object (:func:`_one_axis_runs`: embankments and
    dams, with trees or a bridge on them) are given back to the ground.
    """
    union = obj_x | obj_y
    union &= ok
    if not union.any():
        return union
    lab, n = ndimage.label(union, structure=np.ones((3, 3), bool))
    report(progress, 0.4)
    both = obj_x & obj_y
    if crossed is not None:
        both |= crossed
    both &= ok
    # counts over the labelled cells only (a bincount of the whole raster would cast
    # every cell's label to int64 first)
    lu = lab[union]
    total = np.bincount(lu, minlength=n + 1)
    inboth = np.bincount(lab[both], minlength=n + 1)
    keep = inboth >= _MIN_BOTH_AXES_SHARE * total
    large = _large_regions(lab, total, reach)
    keep &= ~large
    keep[0] = False
    out = np.zeros(union.shape, bool)
    out[union] = keep[lu]          # looked up for the labelled cells only
    if large.any():
        report(progress, 0.6)
        big = np.zeros(union.shape, bool)
        big[union] = large[lu]
        back = _one_axis_runs(big, obj_x, obj_y, reach)
        if decks is not None:
            back &= ~decks                     # a bridge's deck stands on walls, not banks
        big &= ~back
        report(progress, 0.7)
        if levels is not None and big.any():
            # (a crest's extent counts its stretches given back already)
            level = _long_levels(big | back, *levels, reach=reach) & big
            big &= ~level
            back |= level
            report(progress, 0.8)
        if big.any():
            out |= _local_share_kept(big, both, reach)
            report(progress, 0.9)
            if levels is not None and back.any():
                out &= ~_banks_below(back, big, *levels, steps=max(reach) // 2)
    return out


def _joined_to_terrain(z, walled, objects, ground_ok, step_m, foot=None):
    """The cells of ``walled`` whose smooth part is mostly ground: joined to the ground by
    steps between neighbours of at most ``step_m`` (:func:`~.estimate.smooth_parts` over the
    valid cells ``ground_ok``), in a part of which at most half are ``objects``.

    A roof is separated from the ground by walls all round, so its smooth part is the roof
    (with any of its cells a scan missed). A level area that a profile climbed into up the
    side of a pit or of a blunder line and left down another goes on level into the
    ground (``step_m`` the tolerance; with the terrain's slope a roof cut into a steep
    hillside joined the hillside at its uphill edge): its part is the terrain's (ISPRS samp41 1 m lowest: the level
    ground between multipath pits, 6.54 -> 3.89 % total error; issue 12). The parts are
    taken within each walled region's bounding box grown by its own extent on every side
    (eight times its box's area around it: a region joined to the terrain has a majority of
    ground there), so the work follows the regions' size and stays within the halo.
    With ``foot`` (heights, ``walled``'s shape, read at its cells), a cell's part must also reach down to
    its ``foot`` (hold a cell no higher): the level goes on into the ground its walls stand
    on, not only into a level beside it (a roof's tier beside another tier the scans missed).
    """
    idx = np.flatnonzero(walled)
    if idx.size == 0:
        return walled
    H, W = walled.shape
    n, comp = smooth_parts(z, idx, np.inf)          # the regions (8-connected), at their cells only
    r, c = np.divmod(idx, W)
    box = [np.full(n, H), np.zeros(n, np.intp), np.full(n, W), np.zeros(n, np.intp)]
    np.minimum.at(box[0], comp, r)
    np.maximum.at(box[1], comp, r + 1)
    np.minimum.at(box[2], comp, c)
    np.maximum.at(box[3], comp, c + 1)
    near = np.zeros(walled.shape, bool)
    for r0, r1, c0, c1 in zip(*(b.tolist() for b in box)):
        h, w = r1 - r0, c1 - c0
        near[max(0, r0 - h):min(H, r1 + h), max(0, c0 - w):min(W, c1 + w)] = True
    cells = np.flatnonzero(near & ground_ok)
    n_p, part = smooth_parts(z, cells, step_m)
    on_obj = objects.ravel()[cells]
    terrain = 2 * np.bincount(part[on_obj], minlength=n_p) <= np.bincount(part, minlength=n_p)
    out = np.zeros(walled.size, bool)
    out[cells] = terrain[part]
    if foot is not None:
        low = np.full(n_p, np.inf, np.float32)
        np.minimum.at(low, part, z.ravel()[cells])
        at = np.full(walled.size, -np.inf, np.float32)
        at[cells] = low[part]
        reach = np.zeros(walled.shape, bool)
        with np.errstate(invalid="ignore"):
            reach[walled] = at.reshape(walled.shape)[walled] <= foot[walled]
        out &= reach.ravel()
    return out.reshape(walled.shape) & walled


def _ramps(z, one, rejected, ground, step_m, axis):
    """The connected regions of ``one`` (cells rejected by the profiles across ``axis`` only,
    whose profiles along ``axis`` accept them) crossed by a profile along ``axis`` that runs
    from ``ground`` onto them and off them onto ``ground`` by steps of at most ``step_m``: one
    run of the region's cells along a row (``axis`` 1) or a column (``axis`` 0) joined to the
    ground at both its ends at the terrain's slope (a ramp or an embankment's crest, joined
    to ground at both ends; its flanks are walls across it). A roof on a hillside joins the
    uphill ground on one side only; an irregular crown or roof that a hillside's gentle steps
    join to the ground here on one row and there on another is not crossed by any one
    profile (ISPRS samp11, a 20 degree hillside, where such a step is up to 1.2 m at 2 m
    cells: 2 m highest 35.09 -> 34.15 % total error). Rejected cells inside a run (trees
    on the ramp) do not break it."""
    cells = np.flatnonzero(one)
    if cells.size == 0:
        return one
    n, comp = smooth_parts(z, cells, np.inf)        # the regions (8-connected), at their cells only
    H, W = one.shape
    pos = cells // W if axis == 0 else cells % W
    size = H if axis == 0 else W
    stride = W if axis == 0 else 1
    # the runs of rejected cells along ``axis`` (a profile's stretch off the ground), numbered
    # in line order; the region's cells read their run
    rej = rejected if axis == 1 else transpose(rejected)
    first = rej.copy()
    first[:, 1:] &= ~rej[:, :-1]
    runs = np.cumsum(first.ravel(), dtype=np.int64 if first.size >= 2 ** 31 else np.int32)
    runs -= 1
    # read at the region's cells (their place in the transposed raster along the columns)
    run = runs[cells] if axis == 1 else runs[(cells % W) * H + cells // W]
    del runs, first
    n_run = int(run.max()) + 1
    zf, gf = z.ravel(), ground.ravel()
    joined = np.zeros(n_run, np.int8)               # ends of a run joined to the ground (0, 1, 2)
    for d in (1, -1):
        i = np.flatnonzero((pos + d >= 0) & (pos + d < size))
        q = cells[i] + d * stride
        with np.errstate(invalid="ignore"):
            e = gf[q] & (np.abs(zf[q] - zf[cells[i]]) <= np.float32(step_m))
        joined[run[i[e]]] += 1                      # a run's end cell only: its next cell is ground
    keep = np.zeros(n, bool)
    keep[comp[joined[run] == 2]] = True           # a region's cell on a run joined at both ends
    out = np.zeros(one.size, bool)
    out[cells] = keep[comp]
    return out.reshape(one.shape)


def _platforms(z, one, obj, ok, step_m, ramp_m, axis, lag, wall_m):
    """The connected regions of ``one`` (cells rejected by the profiles across ``axis`` only,
    whose profiles along ``axis`` accept them) that are levels going on into the ground they
    stand on: a platform between tracks, a ramp's top, a terrace reached along its length.

    A region is one when

    * it is longer along ``axis`` than across it, and more than one cell across (the profiles
      along it accept it over its length; those across it climb its sides, steps across a
      short run; a rim of mixed cells along a wall is one cell across);
    * at least half its cells lie on the line between its own cells ``lag`` cells (the
      data's sample spacing) before and after them along ``axis`` within ``step_m`` (a level
      or an even slope going on along its length; a crown's fringe is a bump, or too short
      to go on: none of its cells has its own cells on both sides). A ground cell between two
      of its own cells that far apart counts as its own: a sample of the level the scans
      accepted, which split a platform into pieces; a piece 3 cells long had 2 of its 6
      cells on the line, and whether it split off changed with ``alpha_t``'s hundredths
      (``synthetic_sites`` railway 2 m highest: 0.28 / 0.42 % total error at 1.57 / 1.58
      degrees; 0.28 now from 1.5 to 1.7);
    * at least half its cells are joined, by steps between neighbours of at most ``ramp_m``
      (``dh0 + dX tan alpha_g``: a slope the paper's test accepts), to a smooth part mostly of
      ground that reaches down nearer the foot of the region's sides (the lowest ground cell
      next to it) than the region's own lowest cell: its ramp (:func:`_joined_to_terrain`; a
      roof's tier joined only to another tier the scans missed stays at its level). Those
      cells are the level;
    * fewer than half of their edges to the ground drop like walls (``wall_m = (x, y)``,
      :func:`_walled_regions`): a bridge's deck reached by its ramps, a roof's level, stand on
      walls (ISPRS samp41 1 m lowest with its empty cells left empty: 2.76 % total error, 3.29
      % without this test; 2.89 % before these levels).

    The paper's slope test rejects a platform 1 m high from the profiles across it, and its
    ramps join it to the ground only at its ends along the other axis: a platform running
    obliquely to the grid is crossed by no single profile from ramp to ramp (:func:`_ramps`)
    and stayed an object (``synthetic_sites`` railway, 3.1-3.3 % total error at 1 and 2 m
    cells; like ISPRS samp42; issue 12). Steps of ``dh0`` alone do not join a ramp at 2 m
    cells (0.2 m per cell at 10 %), so its result flipped with ``alpha_t``'s hundredths.
    """
    lab, n = ndimage.label(one, structure=np.ones((3, 3), bool))
    if n == 0:
        return one
    # the work is on the regions' cells only (flat indices), not on the raster
    H, W = one.shape
    cells = np.flatnonzero(one)
    lf, of, kf, zf = lab.ravel(), one.ravel(), ok.ravel(), z.ravel()
    lc = lf[cells]
    tot = np.bincount(lc, minlength=n + 1)
    ext = np.array([(b[axis].stop - b[axis].start, b[1 - axis].stop - b[1 - axis].start)
                    for b in ndimage.find_objects(lab)])
    keep = np.zeros(n + 1, bool)
    keep[1:] = (ext[:, 0] > ext[:, 1]) & (ext[:, 1] > 1)
    # on the line between its neighbours lag cells before and after along the axis
    q = int(lag)
    size, d = (W, q) if axis == 1 else (H, q * W)
    pos = cells % W if axis == 1 else cells // W
    inner = (pos >= q) & (pos < size - q)
    i, pi = cells[inner], pos[inner]

    def own(x, px):
        """Its own cells, and the ground cells between two of its own (a sample the scans accepted)."""
        out = of[x]
        m = (px >= q) & (px < size - q)
        xm = x[m]
        out[m] |= kf[xm] & ~obj.ravel()[xm] & of[xm - d] & of[xm + d]
        return out
    with np.errstate(invalid="ignore"):
        on = np.abs(zf[i - d] - 2 * zf[i] + zf[i + d]) <= np.float32(step_m)
    on &= own(i - d, pi - q) & own(i + d, pi + q)        # the region's own cells on both sides
    keep &= 2 * np.bincount(lf[i[on]], minlength=n + 1) >= tot
    del on, i, pi, inner, pos
    keep[0] = False
    if not keep.any():
        return np.zeros(one.shape, bool)
    sel = keep[lc]
    cc, lcc = cells[sel], lc[sel]
    cand = np.zeros(one.shape, bool)
    cand.ravel()[cc] = True
    # the foot of its sides: the lowest ground cell next to it (its 3 x 3 cells within the raster)
    ground = ok & ~obj
    gf = ground.ravel()
    r, c = np.divmod(cc, W)
    low = np.full(cc.size, np.inf, np.float32)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            inside = (r + dr >= 0) & (r + dr < H) & (c + dc >= 0) & (c + dc < W)
            nb = np.where(inside, cc + dr * W + dc, cc)
            np.minimum(low, np.where(inside & gf[nb], zf[nb], np.float32(np.inf)), out=low)
    del ground, gf, r, c
    foot = np.full(n + 1, np.inf, np.float32)
    np.minimum.at(foot, lcc, low)
    del low
    base = np.full(n + 1, np.inf, np.float32)
    np.minimum.at(base, lcc, zf[cc])
    half = 0.5 * (foot + base)                      # nearer the foot than the region's lowest cell
    at = np.zeros(one.shape, np.float32)
    at.ravel()[cc] = half[lcc]
    joined = _joined_to_terrain(z, cand, obj, ok, ramp_m, foot=at).ravel()[cc]
    del at
    keep &= 2 * np.bincount(lcc[joined], minlength=n + 1) >= tot
    keep[0] = False
    cand = np.zeros(one.shape, bool)
    cand.ravel()[cc] = keep[lcc] & joined
    if cand.any():
        cand &= ~_walled_regions(cand, obj & ~cand, z, wall_m)
    return cand


def _walled_across(rej, ground, z, tol_m, bank_m, limit, step_m, lag=1, standing=None):
    """Runs along the rows (consecutive cells of ``rej``, more than ``lag`` and at most ``limit``
    cells) standing on walls at both their ends. At each end, the first two of its cells not in
    ``standing`` (what stands on a deck: a railing, a vehicle, a tree; the end cell itself when
    nothing stands there) are its edge: the higher of them lies above the ``ground`` cell beyond the
    run by more than ``tol_m + n bank_m``, ``n`` the cells from the farther of them to that ground
    cell, ``bank_m`` the steepest bank's rise per cell: a drop steeper than any bank (over two cells
    at least: an end cell half on the wall does not hide it). A tree on an embankment's bank is no
    deck's edge: the crest's level drops to the ground beyond the trees no faster than a bank (the
    probe's breakline scene at 0.5 m, a crest between two rows of trees: 0.03 -> 0.23 % total error
    measured from the run's end). Returns ``(walled, even)``: the cells of the runs walled at their
    ends (what stands there included), and of the runs walled at their edges that are even: at
    least half of their inner cells lie on the line between their cells ``lag`` cells (the data's
    sample spacing) before and after within ``step_m`` (a level or an even slope: a deck, a roof's
    plane), or, for a run with no inner cells, at least half of the steps between its cells ``lag``
    apart are at most ``step_m``.

    Across a bridge's deck the profiles climb a wall from the ground below, cross the level deck
    and come down a wall; across a road embankment, a dam or a ramp they climb and descend banks;
    a mountain's rock ridge between cliffs is rough (lidar hexbin-crop 1 m: 0.81 -> 0.96 % total
    error without the test, 0.88 with a level test, which a ridge's flat top passed and ISPRS
    samp21 and samp11's roofs failed, 0.81 with this one). Over one cell the nearest point's fill
    makes an even slope steps in pairs: hence ``lag``. Runs along the columns: call it on the
    transposed arrays.

    The work is on the cells of ``rej`` only, and from the runs whose length fits with ground beyond
    both ends on theirs only: it costs in proportion to the rejected cells, not to the raster.
    """
    H, W = rej.shape
    q = max(1, int(lag))
    walled_cells, level_cells = np.zeros(rej.shape, bool), np.zeros(rej.shape, bool)
    if W <= q or not rej.any():
        return walled_cells, level_cells
    cells = np.flatnonzero(rej)                    # the rejected cells, row by row
    pos = cells % W                                # their column
    start = np.ones(cells.size, bool)              # a run's first cell: not next to the cell before it
    start[1:] = (cells[1:] != cells[:-1] + 1) | (pos[1:] == 0)
    end = np.ones(cells.size, bool)
    end[:-1] = start[1:]
    first_at, last_at = np.flatnonzero(start), np.flatnonzero(end)
    sc, ec = pos[first_at], pos[last_at]
    # the runs that may stand on walls: their length fits, ground beyond both ends
    gf = ground.ravel()
    cand = (ec - sc + 1 <= int(limit)) & (ec - sc >= q) & (sc > 0) & (ec < W - 1)
    cand[cand] &= gf[cells[first_at[cand]] - 1] & gf[cells[last_at[cand]] + 1]
    if not cand.any():
        return walled_cells, level_cells
    keep = np.repeat(cand, last_at - first_at + 1)  # their cells
    cells, pos, start = cells[keep], pos[keep], start[keep]
    del keep, end
    nc = cells.size
    rc = np.cumsum(start) - 1                      # each cell's run, numbered in line order
    first_at = np.flatnonzero(start)               # each run's first cell (its index in ``cells``)
    last_at = np.r_[first_at[1:] - 1, nc - 1]
    nr = first_at.size
    sc, ec = pos[first_at], pos[last_at]
    zf = z.ravel()
    zc = zf[cells]

    def on_walls(fi):
        """Per run: both ends' edges (their first two cells ``fi``, indices into ``cells``) on walls."""
        out = np.zeros(nr, bool)
        if fi.size == 0:
            return out
        fr = rc[fi]
        f1 = np.flatnonzero(np.r_[True, fr[1:] != fr[:-1]])            # each run's first cell of ``fi``
        l1 = np.r_[f1[1:] - 1, fi.size - 1]                             # and its last
        runs = fr[f1]
        two = l1 > f1
        ok = np.ones(runs.size, bool)
        for side, (near, far) in enumerate(((fi[f1], fi[np.where(two, f1 + 1, f1)]),
                                             (fi[l1], fi[np.where(two, l1 - 1, l1)]))):
            beyond = sc[runs] - 1 if side == 0 else ec[runs] + 1
            b = cells[first_at[runs]] - 1 if side == 0 else cells[last_at[runs]] + 1     # ground (the runs' test)
            n = np.abs(beyond - pos[far])
            with np.errstate(invalid="ignore"):
                ok &= np.fmax(zc[near], zc[far]) - zf[b] > np.float32(tol_m) + n * np.float32(bank_m)
        out[runs] = ok
        return out
    walled = on_walls(np.arange(nc))              # the stretch: with what stands on it
    edge = walled if standing is None else on_walls(np.flatnonzero(~standing.ravel()[cells]))
    if not edge.any():
        return walled_cells, level_cells
    # level across: the steps between the run's cells q apart, counted at the first one
    pair = rc[:-q] == rc[q:]                       # cells of one run are consecutive in ``cells``
    with np.errstate(invalid="ignore"):
        flat = pair & (np.abs(zc[q:] - zc[:-q]) <= np.float32(step_m))
    first = rc[:-q]
    level = 2 * np.bincount(first[flat], minlength=nr) >= np.bincount(first[pair], minlength=nr)
    del pair, flat, first
    # even across: its inner cells (q cells of the run on both sides) on the line between them
    if nc > 2 * q:
        mid = rc[q:-q]
        inner = (rc[:-2 * q] == mid) & (rc[2 * q:] == mid)
        with np.errstate(invalid="ignore"):
            on = inner & (np.abs(zc[:-2 * q] - 2 * zc[q:-q] + zc[2 * q:]) <= np.float32(step_m))
        n_in = np.bincount(mid[inner], minlength=nr)
        level = np.where(n_in > 0, 2 * np.bincount(mid[on], minlength=nr) >= n_in, level)
    level &= edge
    walled_cells.ravel()[cells] = walled[rc]
    level_cells.ravel()[cells] = level[rc]
    return walled_cells, level_cells


def _decks(obj_x, obj_y, ground, z, tol_m, bank_m, reach, step_m, lag):
    """Cells rejected by one axis only whose run across (along the profiles that reject them, at
    most the largest object ``reach = (rows, cols)``) stands on walls at both its ends above
    ``ground`` and is even (:func:`_walled_across`: its edge, what the other axis rejects on it left
    out, drops steeper than any bank, ``tol_m`` plus ``bank_m = (x, y)`` per cell; on the line
    between its cells ``lag`` cells apart within ``step_m``): a bridge's deck. The profiles along it
    run from its ramps onto it level, so they accept it, and it goes on into the road: the rules
    that give back one axis's runs (an embankment's crest, :func:`_one_axis_runs`; a ramp,
    :func:`_ramps`; a platform, :func:`_platforms`) took it for the road's embankment, whose banks
    it lacks (ISPRS samp71: the bridge over the river, 30 % of its object points called ground at
    1 m lowest). A stretch of walled runs (8-connected, with what stands on them: trees on a dam
    break no stretch) longer than the largest object turned in the grid (:func:`_oblique_reach`) is
    a dam or a terrace between walls, and stays ground.
    """
    lim = _oblique_reach(reach)
    out = np.zeros(obj_x.shape, bool)
    for rej, other, b, n_lim, t in ((obj_x, obj_y, bank_m[0], reach[1], False),
                                    (obj_y, obj_x, bank_m[1], reach[0], True)):
        if t:
            walled, level = (transpose(a) for a in _walled_across(
                transpose(rej), transpose(ground), transpose(z), tol_m, b, n_lim, step_m, lag, transpose(other)))
        else:
            walled, level = _walled_across(rej, ground, z, tol_m, b, n_lim, step_m, lag, other)
        level &= ~other
        if not level.any():
            continue
        lab, n = ndimage.label(walled, structure=np.ones((3, 3), bool))
        level[level] = ~_large_regions(lab, np.bincount(lab[walled], minlength=n + 1), lim)[lab[level]]
        out |= level
    return out


def _islands_level(z, obj, ok, step_m, reach):
    """Connected regions of ground (``ok`` and not ``obj``, 8-connected) fitting the largest
    object ``reach = (rows, cols)`` whose edges to ``obj`` (4-neighbours) mostly go on level: fewer
    than half of them step up into the objects by more than ``step_m``.

    A profile that holds no ground within the largest object (a roof cut by the raster's edge and
    longer than the raster) starts its reference on the roof, and accepts it; so does the profile
    across it. Such cells are ground only for want of a ground reference, while the profiles next
    to them that reached the ground reject the same roof: an island of ground in the objects on
    their level (lidar sample_c at 4 m: 3.5 % total error, the bottom rows of a roof filling the
    raster's width). Ground enclosed by objects lies below them: a courtyard among walls, a
    clearing or a gap among crowns, a street among roofs.
    """
    ground = ok & ~obj
    lab, n = ndimage.label(ground, structure=np.ones((3, 3), bool))
    out = np.zeros(obj.shape, bool)
    if n == 0:
        return out
    total = np.bincount(lab[ground], minlength=n + 1)
    small = ~_large_regions(lab, total, reach)
    small[0] = False
    if not small.any():
        return out
    # the edges of the small regions' cells only (4-neighbours in ``obj``)
    H, W = obj.shape
    cells = np.flatnonzero(small[lab])
    li = lab.ravel()[cells]
    r, c = np.divmod(cells, W)
    zf, of = z.ravel(), obj.ravel()
    edges = np.zeros(n + 1, np.int64)
    ups = np.zeros(n + 1, np.int64)
    for d, inside in ((1, c < W - 1), (-1, c > 0), (W, r < H - 1), (-W, r > 0)):
        i = cells[inside]
        e = of[i + d]
        i = i[e]
        lj = li[inside][e]
        edges += np.bincount(lj, minlength=n + 1)
        with np.errstate(invalid="ignore"):
            ups += np.bincount(lj[zf[i + d] > zf[i] + np.float32(step_m)], minlength=n + 1)
    level = small & (edges > 0) & (2 * ups < edges)
    out.ravel()[cells] = level[li]
    return out


def _same_level(z, level, obj, step_m):
    """The cells of ``obj`` (and ``level``) on the levels ``level``: joined to them by steps
    between 8-neighbours of at most ``step_m`` through cells of ``obj``
    (:func:`~.estimate.smooth_parts`).

    Where the terrain's slope ``alpha_t`` is low, the profiles along a platform turned to the
    grid that climbed its side stay rejected along all of it (the terrain's rise never reaches
    its height), so both axes reject that strip of it; it is the same level as the part the
    profiles along it accept (:func:`_platforms`), walls apart from trains and roofs.
    """
    if not level.any():
        return level
    cells = np.flatnonzero(obj | level)
    n, part = smooth_parts(z, cells, step_m)
    on = np.zeros(n, bool)
    on[part[level.ravel()[cells]]] = True
    out = np.zeros(obj.size, bool)
    out[cells] = on[part]
    return out.reshape(obj.shape)


def _level_unwalled(z, level, obj, step_m, wall_m):
    """The cells of ``obj`` on the levels ``level`` (ground now, not in ``obj``), joined to them
    by steps of at most ``step_m`` (:func:`_same_level`), in connected regions not walled where
    they meet the ground (:func:`_walled_regions`, ``wall_m = (x, y)``): the rest of a
    platform; a bridge's deck going on level beyond its ramp stands on walls (ISPRS samp21 1 m
    lowest: 1.7 % total error, 6.4 % with its deck taken)."""
    grown = _same_level(z, level, obj | level, step_m)
    grown &= ~level
    if grown.any():
        grown &= ~_walled_regions(grown, obj & ~grown, z, wall_m)
    return grown


def refine_objects(z, obj, low, valid, cell_size, tolerance_m, slope_factor, progress=None):
    """Give rejected cells lying within the tolerance of the interpolated ground back to
    the ground (as SMRF's final step).

    The ground is interpolated under the objects and low blunders (``fill.fill_gaps``); a
    rejected cell within ``tolerance_m + slope_factor * slope`` of it is ground again.
    ``progress(fraction)`` (optional, may raise ``Cancelled``): from inside the interpolation and after
    the test.

    Returns
    -------
    obj : ndarray of bool
        The objects left.
    refined : int
        Cells given back.
    dtm : ndarray of float32 or None
        The interpolated ground when nothing was given back (then it is the DTM, exact at
        every ground cell), else None.
    """
    if not obj.any() or not (valid & ~obj & ~low).any():
        return obj, 0, None
    from .fill import fill_gaps
    dx, dy = cell_size
    surf = fill_gaps(z, fill=obj | low, progress=sub_progress(progress, 0.0, 0.8))
    gy, gx = np.gradient(surf, dy, dx)
    report(progress, 0.9)
    back = obj & (np.abs(z - surf) <= tolerance_m + slope_factor * np.hypot(gx, gy))
    refined = int(back.sum())
    report(progress, 1.0)
    return obj & ~back, refined, (None if refined else surf)


def _mask_and_info(obj, low, valid, obj_x, obj_y, refined, p):
    """The mask (1 objects, 2 low blunders, 255 nodata) and the run's info."""
    mask = obj.astype(np.uint8)                      # OBJECT = 1, GROUND = 0
    np.copyto(mask, np.uint8(LOW), where=low)
    np.copyto(mask, np.uint8(NODATA), where=~valid)
    n = max(1, int(np.count_nonzero(valid)))
    info = {"alpha_g_deg": float(p["slope_threshold_deg"]), "alpha_t_deg": float(p["terrain_slope_deg"]),
            "dh0_m": float(p["tolerance_m"]),
            "rejected_by_x_percent": 100.0 * float(np.count_nonzero(obj_x & valid)) / n,
            "rejected_by_y_percent": 100.0 * float(np.count_nonzero(obj_y & valid)) / n,
            "refined_back_percent": 100.0 * refined / n,
            "low_blunders_percent": 100.0 * float(np.count_nonzero(low)) / n}
    return mask, info


def _scan_geometry(cell_size, tan_g, tolerance_m, max_object_size_m, edge_length_m, sample_spacing_cells):
    """Start windows and edge runs ``(x, y)`` in cells, and the scans' tolerance dh0.

    Gridded sparse points rise in stair steps: a slope up to alpha_g over the data's own
    spacing comes in one step, which the edge test must allow.
    """
    dx, dy = cell_size
    init = (max(1, int(round(max_object_size_m / dx))), max(1, int(round(max_object_size_m / dy))))
    edge = (max(1, int(round(edge_length_m / dx))), max(1, int(round(edge_length_m / dy))))
    spacing = min(max(1.0, float(sample_spacing_cells)), _MAX_SPACING)
    return init, edge, tolerance_m + (spacing - 1.0) * min(dx, dy) * tan_g


def filter_slope_profile(z: np.ndarray, cell_size: Union[float, Tuple[float, float]], *,
                         slope_threshold_deg: float, terrain_slope_deg: float, tolerance_m: float,
                         max_object_size_m: float = 100.0, edge_length_m: float = 1.0,
                         sample_spacing_cells: float = 1.0, refine: bool = False, slope_factor: float = 1.25,
                         progress: Optional[Callable[[float], None]] = None) -> FilterResult:
    """Slope-profile filter (Luong Chinh Ke 2002, section 2.1).

    Parameters
    ----------
    z : array_like, 2-D
        DSM, NaN = nodata.
    cell_size : float or (dx, dy)
        Metres.
    slope_threshold_deg : float
        ``alpha_g``: a step steeper than this from the ground before it starts an object.
    terrain_slope_deg : float
        ``alpha_t``: how fast the ground may rise under an object per cell of its length.
    tolerance_m : float
        ``dh0``: height tolerance for the DSM's noise, added to every test.
    max_object_size_m : float
        Largest object; the reference at a profile's start is the lowest point within it.
    edge_length_m, sample_spacing_cells : float
        Edge run (metres) and spacing of the real samples (cells) of the edge test.
    refine : bool
        Give rejected cells within the tolerance of the interpolated ground back to the
        ground.
    slope_factor : float
        Slope term of the refinement tolerance (rise/run of the interpolated ground).
    progress : callable, optional
        ``progress(fraction)`` within every step; may raise
        :class:`~bare_earth.core.common.Cancelled`.

    Returns
    -------
    FilterResult
        ``info`` holds the share of cells rejected by X and by Y profiles.
    """
    z = as_surface(z)
    cell = as_cell_size(cell_size)
    p = dict(slope_threshold_deg=slope_threshold_deg, terrain_slope_deg=terrain_slope_deg,
             tolerance_m=tolerance_m, max_object_size_m=max_object_size_m, edge_length_m=edge_length_m,
             sample_spacing_cells=sample_spacing_cells, slope_factor=slope_factor)
    check_values("slopeprofile", PARAMS, p)
    tan_g = float(np.tan(np.radians(slope_threshold_deg)))
    tan_t = float(np.tan(np.radians(terrain_slope_deg)))
    valid = np.isfinite(z)
    # 1. low blunders (a drop then a rise): class 2, left out of the scans
    pits = find_low_blunders(z, tolerance_m + max(cell) * tan_g, sub_progress(progress, 0.0, 0.05))
    low = below_surroundings(z, cell, tolerance_m, candidates=pits,  # below all the ground around: not a gap
                             progress=sub_progress(progress, 0.05, 0.07))
    low |= below_level_rim(z, cell, tolerance_m, tan_t, pits & ~low)   # or below the level ground just around
    zs = np.where(low, np.float32(np.nan), z)
    # 2. the slope test along X and Y profiles, forwards and backwards (Ke 2002, sec. 2.1)
    init, edge, dh_eff = _scan_geometry(cell, tan_g, tolerance_m, max_object_size_m, edge_length_m,
                                        sample_spacing_cells)
    obj_x, obj_y, raised_x, raised_y = scan_profiles(zs, cell, tan_g, tan_t, dh_eff, init, edge,
                                                     sub_progress(progress, 0.07, 0.7))
    # 3. X and Y combined by connected objects; raised runs where they close objects and
    # are walled where they meet the ground
    reach = (init[1], init[0])
    wall_m = tuple(dh_eff + c * max(tan_g, GAP_BANK_SLOPE) for c in cell)
    ok = valid & ~low
    lag = max(1, int(round(min(max(1.0, float(sample_spacing_cells)), _MAX_SPACING))))   # sample spacing
    # bridges' decks: one axis's runs on walls at both ends across (no embankment, ramp or platform)
    decks = _decks(obj_x, obj_y, ok & ~obj_x & ~obj_y, zs, dh_eff,
                   tuple(c * max(tan_g, GAP_BANK_SLOPE) for c in cell), reach, dh_eff, lag)
    # an object both scans of one axis lost to the terrain's rise along it (a hedge, a row of
    # cars): rejected across, and along it standing on a step up and a step down at the ends
    # of its run (at most the largest object) of rejected cells: crossed by that axis too
    rejected = (obj_x | obj_y) & ok
    crossed = _stepped_runs(rejected, zs, dh_eff + cell[0] * tan_g, 1, init[0]) & obj_y
    crossed |= _stepped_runs(rejected, zs, dh_eff + cell[1] * tan_g, 0, init[1]) & obj_x
    del rejected
    obj = _combine_axes(obj_x, obj_y, ok, reach, sub_progress(progress, 0.7, 0.75),
                        levels=(zs, dh_eff, wall_m), decks=decks, crossed=crossed)
    # (the raised runs' own extent, without the objects they touch)
    raised = _raised_objects(_combine_axes(raised_x, raised_y, valid & ~low, reach,
                                           sub_progress(progress, 0.75, 0.8)) & ~obj, reach)
    report(progress, 0.805)
    walled = _walled_regions(raised, obj, zs, wall_m)
    report(progress, 0.81)
    # ... and not going on level into the terrain (steps within the tolerance)
    walled &= ~_joined_to_terrain(zs, walled, obj | walled, valid & ~low, dh_eff)
    obj |= walled
    report(progress, 0.82)
    # ... and runs of one axis on a ramp: joined to the ground on both sides along the other
    # (a walled region's cells are a roof's, not a run on a ramp)
    one = obj & (obj_x ^ obj_y) & ~decks & ~walled
    ground = ok & ~obj
    # levels of one axis going on into the ground they stand on (platforms), found on the
    # same cells whatever the ramps' test below gives back
    ramp = dh_eff + min(cell) * tan_g
    level = _platforms(zs, one & obj_y, obj, ok, dh_eff, ramp, 1, lag, wall_m)
    report(progress, 0.83)
    level |= _platforms(zs, one & obj_x, obj, ok, dh_eff, ramp, 0, lag, wall_m)
    report(progress, 0.84)
    one = (_ramps(zs, one & obj_y, obj, ground, dh_eff + cell[0] * tan_t, 1)
           | _ramps(zs, one & obj_x, obj, ground, dh_eff + cell[1] * tan_t, 0))
    report(progress, 0.85)
    obj &= ~_joined_to_terrain(zs, one, obj, ok, dh_eff + min(cell) * tan_t)
    report(progress, 0.86)
    # ... each platform with the rest of its level (not walled: a bridge's deck beyond it)
    obj &= ~level
    obj &= ~_level_unwalled(zs, level, obj, dh_eff, wall_m)
    del level, decks
    # 4. islands of ground on the objects' level: their profiles held no ground to start from
    obj |= _islands_level(zs, obj, ok, dh_eff + min(cell) * tan_t, reach)
    del raised_x, raised_y, zs
    report(progress, 0.87)
    # 5. optional refinement against the interpolated ground
    refined, dtm = 0, None
    if refine:
        obj, refined, dtm = refine_objects(z, obj, low, valid, cell, tolerance_m, slope_factor,
                                           sub_progress(progress, 0.87, 0.95))
    report(progress, 0.95)
    mask, info = _mask_and_info(obj, low, valid, obj_x, obj_y, refined, p)
    report(progress, 1.0)
    return FilterResult(mask=mask, info=info, dtm=dtm)


def derive_terrain_slope(est):
    """alpha_t, degrees, from the terrain's slopes.

    The median (the paper's average slope), raised towards the upper quartile (the slope
    three quarters of the terrain stays under: the ground under most objects rises no
    faster), but by the quartile no higher than :data:`_MAX_QUARTILE_ALPHA_T`:
    ``max(median, min(p75, 8 deg))``, continuous in both (no mode flips at a threshold);
    at most the Param's maximum.

    Parameters
    ----------
    est : dict
        ``median`` and ``p75`` of the terrain's slopes, rise/run
        (:func:`estimate_terrain_slope`).

    Returns
    -------
    float
    """
    med = float(np.degrees(np.arctan(est["median"])))
    upper = float(np.degrees(np.arctan(est.get("p75", est["median"]))))
    return float(min(max(med, min(upper, _MAX_QUARTILE_ALPHA_T)), _MAX_ALPHA_T))


def derive_slope_threshold(terrain_slope_deg):
    """alpha_g, degrees: twice the terrain's slope as the scans compare it, rise over run
    (``tan alpha_g = 2 tan alpha_t``, the paper's ``dZ / dX``), bounded to
    [:data:`_MIN_ALPHA_G`, :data:`_MAX_ALPHA_G`].

    Twice the angle instead lets a step pass that is more than twice the terrain's rise
    per cell on steep ground (21 deg terrain: 0.92 m per metre instead of 0.78 m), so
    shrubs 1-2 m high on a slope were accepted by the scan coming down the slope (ISPRS
    sample 11, issue 12); on gentle ground the two agree.
    """
    tan_g = 2.0 * np.tan(np.radians(float(terrain_slope_deg)))
    return float(np.clip(np.degrees(np.arctan(tan_g)), _MIN_ALPHA_G, _MAX_ALPHA_G))


def resolve_slope_profile_params(z: np.ndarray, cell_size: Union[float, Tuple[float, float]], *,
                                 slope_threshold_deg: Optional[float] = None,
                                 terrain_slope_deg: Optional[float] = None, tolerance_m: Optional[float] = None,
                                 max_object_size_m: float = 100.0, edge_length_m: float = 1.0,
                                 sample_spacing_cells: Optional[float] = None, refine: bool = False,
                                 slope_factor: float = 1.25, progress=None) -> dict:
    """Complete the parameters, deriving the missing ones from the data.

    * ``terrain_slope_deg`` (alpha_t): the slope of the terrain under the objects
      (:func:`estimate_terrain_slope`: slopes between 20 m block minima, which objects do
      not reach, without the blocks lying wholly on parts that stand on walls (steps higher
      than dh0 plus the steepest bank's rise over the sample spacing) and fit the largest
      object turned in the grid, :func:`~bare_earth.core.estimate.raised_parts`: halls and
      blocks of buildings wider than a block, whose roofs and walls the block minima reach;
      ``courtyard`` of ``synthetic_sites``, like ISPRS samp23, 20 -> 1.4 degrees on level
      ground, 36.0 -> 0.0 % total error at 2 m highest): the median (the paper's "average
      slope" made robust), raised to the
      upper quartile (the ground under three objects in four rises no faster), by it no
      higher than 8 degrees (:func:`derive_terrain_slope`: beyond, the quartile measures
      roofs and crowns wider than a block); at most its Param's maximum. No floor: the
      former 8 degree floor let the ground rise 0.28 m per 2 m cell under an object, so
      shrubs and trees 1-5 m high on flat ground were taken back as ground (opengeos).
    * ``slope_threshold_deg`` (alpha_g): twice alpha_t as rise over run
      (:func:`derive_slope_threshold`; steeper than the terrain's usual slope, far gentler
      than a wall), bounded to [5, 60] degrees: 5 degrees is the slope
      of the ground's micro-relief that 20 m block minima do not see (a kerb or a furrow,
      0.1-0.2 m over 1-2 m). The former floor of 25 degrees let every object rise 0.93 m
      per 2 m cell (1.9 m per 4 m cell) and stay ground.
    * ``tolerance_m`` (dh0): 3 x the noise of the DSM's ground-level cells
      (:func:`~bare_earth.core.estimate.noise_ground_level`, not the canopy's roughness; the
      cleanest quarter of its tiles where lower, :func:`~bare_earth.core.estimate.sensor_noise`:
      low vegetation among the ground-level cells is no noise)
      without the spread of where the heights lie on the ground's median slope over the
      sample spacing (:func:`~bare_earth.core.estimate.noise_without_sampling`: the scans'
      slope allowance covers it; taken as noise it raised dh0 on steep ground, 0.46 m on
      ISPRS sample 11, and low objects on slopes passed), bounded to [0.15, 0.5] m; 0.5 m
      when too few ground cells are seen.
    * ``sample_spacing_cells``: the mean run of identical neighbouring values
      (:func:`estimate_sample_spacing`); the edge test spans it.

    Measured on the seven ISPRS samples under ``benchmarks/isprs.py`` (see the README).
    ``progress(fraction)`` (optional, may raise ``Cancelled``) from inside the estimates.
    """
    z = as_surface(z)
    cell = as_cell_size(cell_size)
    check_values("slopeprofile", PARAMS, dict(
        slope_threshold_deg=slope_threshold_deg, terrain_slope_deg=terrain_slope_deg, tolerance_m=tolerance_m,
        max_object_size_m=max_object_size_m, edge_length_m=edge_length_m,
        sample_spacing_cells=sample_spacing_cells, slope_factor=slope_factor))
    if sample_spacing_cells is None:
        sample_spacing_cells = estimate_sample_spacing(z)
    report(progress, 0.1)
    if tolerance_m is None:
        est = estimate_terrain_slope(z, cell, scale_m=20.0)
        # the sensor's noise: the cleanest quarter of the tiles where low vegetation touches most of
        # the ground-level cells (a highest-point DSM of a vegetated hillside)
        spread = sensor_noise(noise_ground_level(z, cell, progress=sub_progress(progress, 0.1, 0.6)))
        # where the heights were taken on the ground's median slope spreads them too: the
        # scans' slope allowance covers that part, dh0 only the noise
        sigma = noise_without_sampling(spread, est["median"], min(cell) * float(sample_spacing_cells))
        tolerance_m = float(np.clip(3.0 * sigma, 0.15, 0.5)) if np.isfinite(sigma) else 0.5
    report(progress, 0.6)
    if terrain_slope_deg is None:
        # the terrain's slopes without the parts standing on walls that an object may be
        terrain_slope_deg = derive_terrain_slope(estimate_terrain_slope(
            z, cell, scale_m=20.0, tolerance_m=tolerance_m, spacing_cells=sample_spacing_cells,
            max_object_m=max_object_size_m))
    report(progress, 0.9)
    if slope_threshold_deg is None:
        slope_threshold_deg = derive_slope_threshold(terrain_slope_deg)
    out = {"slope_threshold_deg": float(slope_threshold_deg), "terrain_slope_deg": float(terrain_slope_deg),
           "tolerance_m": float(tolerance_m), "max_object_size_m": float(max_object_size_m),
           "edge_length_m": float(edge_length_m), "sample_spacing_cells": float(sample_spacing_cells),
           "refine": bool(refine), "slope_factor": float(slope_factor)}
    check_values("slopeprofile", PARAMS, out)
    return out


def slope_profile_halo(params, cell_size):
    """Reach in cells: the scans' (the start window plus the longest object crossed by a
    profile, ``2 L + 2`` with ``L`` the largest object in cells) plus the combination's
    (:func:`_combine_axes`: a region's extent is known ``L + 1`` cells around a cell, a
    one-axis run's or a level's ``ceil(sqrt(2) L) + 1`` (:func:`_one_axis_runs`,
    :func:`_long_levels`), a level's walls are counted over ``L / 2`` cells, and large regions
    are shared over ``L / 2`` cells, or their banks reached within ``L / 2`` cells of a level,
    :func:`_banks_below`, after the sharing; a bridge's deck's run across, at most ``L``, and its
    stretch's extent, :func:`_decks`, on the scans' results as the one-axis runs), plus the islands'
    on the objects (:func:`_islands_level`: an island's extent is known ``L + 1`` cells around a
    cell, and its edges one cell further), plus the crossed runs' on the scans' results before
    the combination (:func:`_stepped_runs`: a run of at most ``L`` cells and the two cells beyond
    each end, ``L + 2``), plus the ground's trends' (:func:`ground_trends`: the surface within
    :func:`trend_cells` of a reference point; :func:`trends_before`: that trend read up to
    :func:`trend_cells` behind the scan's position, twice it in all), so blocks give the one-pass mask."""
    dx, dy = as_cell_size(cell_size)
    big = int(np.ceil(params["max_object_size_m"] / min(dx, dy)))
    return (2 * big + 2 + _oblique_reach((big,))[0] + 1 + 2 * (big // 2) + big + 2 + big + 2
            + 2 * trend_cells((dx, dy)))


#: The user parameters (dialog order); their bounds are the limits the core enforces.
PARAMS = (
    Param("slope_threshold_deg", "float", None,
          "Terrain slope threshold alpha_g, degrees (Ke 2002, sec. 2.1): a step steeper than this "
          "from the ground before it starts an object. Empty: twice the terrain slope "
          "alpha_t as rise over run (tan alpha_g = 2 tan alpha_t), bounded to 5-60 deg.",
          minimum=0.5, maximum=89.0),
    Param("terrain_slope_deg", "float", None,
          "Average terrain slope alpha_t, degrees: how fast the ground may rise under an object "
          "per cell of its length. Empty: the median slope between 20 m block minima (which objects "
          "do not reach; blocks wholly on a part standing on walls, a hall wider than a block, left "
          "out), raised towards their upper quartile (by it no higher than 8 deg).",
          minimum=0.0, maximum=80.0, advanced=True),
    Param("tolerance_m", "float", None,
          "Height tolerance dh0, metres, added to every test for the DSM's noise. Empty: 3 x the "
          "noise of the DSM's ground-level cells (never the canopy's; the cleanest quarter of the tiles "
          "where low vegetation roughens the rest; without the spread of where "
          "the heights lie on sloping ground, which the slope test allows for), bounded to 0.15-0.5 m.",
          minimum=0.0, maximum=50.0, advanced=True),
    Param("max_object_size_m", "float", 100.0,
          "Largest object, metres: a profile's reference starts at its lowest point within this "
          "length, so objects cut by the raster's edge are still removed.",
          minimum=1.0, maximum=5000.0, advanced=True),
    Param("edge_length_m", "float", 1.0,
          "Edge run, metres: an object's edge must rise faster than alpha_g over this length "
          "(one cell = the paper's point-to-point test; longer runs ignore the stair steps of "
          "sparse or resampled data).",
          minimum=0.0, maximum=50.0, advanced=True),
    Param("sample_spacing_cells", "float", None,
          "Spacing of the DSM's real samples, in cells (at most 4 is used): the height step of "
          "the terrain's slope over it is tolerated. Empty: the mean "
          "run of identical neighbouring values (1 for a DSM measured at every cell; more for a "
          "grid of sparse points with empty cells filled from the nearest point).",
          minimum=1.0, maximum=20.0, advanced=True),
    Param("refine", "bool", False,
          "Give rejected cells lying within the tolerance of the interpolated ground back to the "
          "ground (as SMRF's last step). Off by default: on the ISPRS samples it gained nothing "
          "and it costs one more interpolation.", advanced=True),
    Param("slope_factor", "float", 1.25,
          "Slope term of the refinement tolerance (rise/run of the interpolated ground), as in SMRF.",
          minimum=0.0, maximum=10.0, advanced=True),
)
#: Largest derived alpha_t: the maximum of its Param.
_MAX_ALPHA_T = next(p.maximum for p in PARAMS if p.name == "terrain_slope_deg")


def _run(z, cell_size, progress=None, **params):
    return filter_slope_profile(z, cell_size, progress=progress, **params)


METHOD = Method(
    name="slopeprofile",
    bytes_per_cell=96.0,       # measured 45.4 (benchmarks/speed.py, 16 Mcells, file); 55.3; 68.9 with decks (11-30);
                               # + 8: the ground's trends along X and Y held through the scans;
                               # + 16: their reading before each scan's position (forward, backward)
    run=_run,
    resolve=resolve_slope_profile_params,
    halo=slope_profile_halo,
    params=PARAMS,
    title="Slope-profile filter (Luong Chinh Ke 2002)",
    description=(
        "<p>Filters a DSM along profiles in X and in Y (Luong Chinh Ke 2002, section 2.1). Along each "
        "profile the slope between consecutive points, alpha = atan(dZ/dX), is compared with the "
        "terrain slope threshold alpha_g; a rejected point's height is corrected by dZ, so the profile "
        "keeps the last ground height and the whole object stays rejected until the profile comes back "
        "to the ground.</p><p>Each profile is scanned forwards and backwards and a cell is an object for "
        "that axis only when both scans reject it (terrain steps are accepted by the scan that comes "
        "down them); the X and Y results are combined by union, so objects long in one direction are "
        "caught in the other; a connected object is kept only where both axes reject part of it, so "
        "road embankments and dams that a profile runs along stay ground. Small pits below the "
        "ground around them are low blunders (class 2), provided they also lie below every cell "
        "within 10 m (a gap between crowns is at the level of the other gaps around it) or below a "
        "level rim just around them (a blunder in open ground, even with another blunder within "
        "10 m; the crowns around a gap are metres apart).</p>"
        "<p>Where a profile climbs a wall, crosses a raised run and comes down an equally steep "
        "wall within the largest object's length, the run is an object even where the terrain's "
        "allowed rise had accepted its middle (a wide flat roof); regions longer than the largest "
        "object (embankments, terraces between walls) stay ground, and so do the crests of embankments "
        "crossing the grid obliquely (a level longer than the largest object ending on banks, not walls), "
        "with their banks (cells reached from the crest going down by steps gentler than a wall), and "
        "regions not walled "
        "where they meet the ground (at least half their edges to the ground dropping like walls): "
        "level ground between the sides of pits goes on level into the ground. A level that the "
        "profiles along it accept and those across it reject (a platform between tracks, turned to "
        "the grid), going on evenly along its length, joined by a ramp gentler than alpha_g to the "
        "ground its sides stand on and not walled, is ground with the rest of its level; a "
        "bridge's deck stands on walls: one axis's runs even across and on walls at both ends (not banks) "
        "stay objects, unless they go on for longer than the largest object (a dam). Ground enclosed by "
        "objects and level with them (its profiles held no ground to start from: a roof cut by the "
        "raster's edge) is theirs.</p>"
        "<p>Defaults are derived from the DSM: alpha_g and the terrain slope from slopes between 20 m "
        "block minima (without the blocks lying wholly on roofs that stand on walls: halls and blocks of "
        "buildings wider than a block), the tolerance from the noise of the DSM's ground-level cells (not the "
        "canopy's roughness; the cleanest quarter of the tiles where low vegetation among the ground-level cells "
        "roughens the rest, as on a highest-point DSM of a vegetated hillside). The log lists the values used.</p>"
        "<p>Known limit of the paper's rule: one terrain slope alpha_t and threshold alpha_g for the "
        "whole raster. Where gentle ground is cut by a few steep banks (a cutting, a river bank), a "
        "plateau that profiles reach only by climbing a bank may stay rejected: the measured slope "
        "of the gentle ground lets its level rise too slowly under the profile (ISPRS sample 71: "
        "6.4 % total error at 1 m lowest point).</p>"
        "<p>The slope test's allowance follows the ground's own trend before the reference (its change "
        "per cell, within plus or minus alpha_t): alpha_g is the slope allowed from ground rising at "
        "alpha_t, so where the ground is level (along a hillside's contours) or falls, an object's edge "
        "must rise alpha_g - alpha_t above the ground's continuation (at least the ground's "
        "micro-relief, 5 degrees), never less than the terrain's rise alpha_t. A low object long "
        "along one axis (a hedge, a row of cars) that the profiles "
        "along it accept by the terrain's rise counts as crossed by them where its run of rejected "
        "cells along them (at most the largest object) stands on a step steeper than alpha_g at both "
        "ends; an embankment reached by ramps has none.</p>"
        "<p>The terrain's rise under an object follows the ground's fall too: where the ground falls "
        "along the profile at the reference, the rise alpha_t is counted from the ground continued down "
        "its fall (dh0 + d dX tan(alpha_t) + d f, f the fall per cell, at most alpha_t), not from the "
        "reference's level. The fall is the less steep of the ground's trend there (the slope along the "
        "profile of the running minimum over 10 m, which reaches below a shrub or a crown beside the "
        "reference) and its last step less that step's noise (sqrt(2) dh0 / 3): a fall the two do not "
        "agree on, or within the noise, is none. A shrub 1-2 m high on a hillside was accepted by the "
        "scan coming down the slope, which let the ground rise alpha_t from the reference's level under "
        "it (ISPRS sample 11, 2 m highest point: 32.4 -> 30.2 % total error). The scan going up a slope "
        "is unchanged, and a valley's far side stays ground: the scan coming down it accepts it.</p>"
        "<p>The ground's change before the reference, which the edge test continues and the terrain line "
        "takes as its last step, is no more rising than the ground's trends show (plus the step's noise): "
        "the more rising, for the scan, of the trend at the reference and the trend 10 m behind it, whose "
        "running minimum holds only cells the scan has passed. A scan coming down a hillside took a crown's "
        "top, entered level from the slope above, or its flank, climbed in steps within the edge's "
        "allowance, for the ground and its level or rising steps for the ground's trend, while the hillside "
        "under it fell (ISPRS sample 11, 2 m highest point: 30.2 -> 29.1 % total error). The trend behind "
        "the reference keeps a bench's edge ahead from counting as a fall.</p>"
        "<p>Known limit on steep vegetated slopes: with alpha_g twice the terrain's slope, an object "
        "lower than about dh0 + dX tan(alpha_t) above the ground passes the slope test; a crown is kept "
        "only where both axes reject part of it, so low vegetation on a steep "
        "slope stays ground (synthetic shrubs 0.6-2 m high on a 28-38 degree slope: 11 % total error at "
        "1 m lowest point, 25 % at 2 m highest point, 96-99 % of the shrub cells called ground rejected "
        "by neither axis; ISPRS samples 11 and 52). A threshold nearer the terrain's slope (its 90th "
        "percentile, 35 instead of 50 degrees there) leaves the contour's profiles accepting them "
        "(11.1 -> 10.9 %) and rejects the shoulders of quarry benches (3.0 -> 3.9 % at 1 m highest point).</p>"),
)
