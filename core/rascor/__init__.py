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
   marks a building; the points between are removed. Where the raster's edge cuts the level
   (a jump up and the profile's end with no jump down between), the level - the part joined
   to those runs by steps within the jump, mostly made of them - is a building when what is
   seen of it lies within the longest building, it stands on its jumps over more than half of
   its seen outline and its walls, mirrored at the sides of the raster they meet, run within
   twice the longest building (:mod:`..edge_walls`, as ``bareearth:dtm``'s raised regions: a
   wall cutting off a corner of the tile runs twice what is seen, a hall over most of a tile
   such as lidar ``sample_c``; one running across the tile three times, a terrain step's).
   A level longer than the longest building along both axes (a hall), which no profile pairs
   jumps across, is a building when its walls close it on every side
   (:func:`~.steps.enclosed_levels`: a part of the DSM joined across small steps, meeting no side
   of the raster, stepping down by the jump on more than half of its outline), up to
   ``max_hall_m`` (the longest such level of the DSM).
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
paper warns that it removes small vegetation but may generalise the terrain. Without it,
step 3 alone runs once more at the end (``step3_repeat``, on by default): the edge of a
crown or a roof passes step 3 as the toe of a slope while the object above it stands, and
is tested again once steps 4-6 removed that object; a test of one cell against its
neighbours, no moving fit (the foot of a bank whose slope the later steps removed goes too).
Before it, the objects of steps 5 and 6 lying on smooth ground that continues the ground kept
(a road embankment, a ramp: raised ground no jump bounds, which the paper leaves to break
lines), in object regions longer than step 6's window, are given back as ground
(``spare_continuing_ground``, on by default; :func:`.dtm_refine.continue_ground`), and so
are shorter object regions of steps 5 and 6 that are ramps between two levels of the kept
ground (an inclined plane whose both ends meet the ground at its own height, no wall along
its sides: :func:`.regions.find_ramps`; a rule of ours, not the paper's).

Break lines and special areas (boolean rasters ``breaklines`` and ``special_areas``,
rasterised by the plugin layer and passed by the pipeline as keyword arrays, not Params):
no comparison crosses a break line (neighbour pairs, profile steps and windows are
restricted to the connected region of non-break cells the tested cell lies in; break-line
cells are compared only with each other along the line), so a dam or an embankment keeps
its shoulders; inside special areas only the local filters run (steps 3 and 7), e.g. for
cars and bushes on a dam's slope. A line that does not close its region (it ends inside the
raster, or has a gap: most of the terrain's level changes of step 4) leaves both of its sides
one region; the profiles of step 5 stop at it all the same (:func:`.regions.profile_runs`: each
run of a row or a column between line cells fitted on its own), where before the profile across
a terrace's riser fitted both levels and took the upper tread's edge. Measured (RASCOR):
synthetic bare terrain (benchmarks/bare.py) 1.40 -> 1.36 % of the ground lost (terraces 0.5 / 1 m
5.74 / 2.79 -> 5.38 / 1.68, river 1 m 1.57 -> 1.39, gullies 1 m 1.02 -> 0.87, no row worse); the
synthetic sites 4.05 -> 3.98 % (hillside 1 m lowest 6.29 -> 5.30, quarry 1 m 5.71 / 5.84 -> 5.40 /
5.45, no row worse); the generalisation matrix's 73 rows 3.242 -> 3.239 % (half A 3.404 -> 3.406,
B 3.074 -> 3.067; lidar hexbin-crop 1 m* 2.01 -> 1.76, ISPRS 51 2 m lowest 3.41 -> 3.47, autzen_trim
2 m 1.16 -> 1.19), ISPRS seven 3.731 -> 3.733, worst row and opengeos unchanged; ``bareearth:dtm``,
whose member RASCOR is, on the rows it moved: hexbin-crop 1 m* 1.15 -> 1.10, ISPRS 61 1 m +0.02, 51 2 m
+0.01, opengeos unchanged. Step 6's
surfaces still reach across such a line around its end (a window is two-dimensional: which
cells lie beyond a line that stops inside it is a matter of visibility, not of runs): on the
0.5 m terraces what step 5 no longer takes step 6 partly does (step 5 2.56 -> 0.32 %, step 6
0.56 -> 2.45 % of the cells), a limit.

Notes on the vectorised implementation
--------------------------------------
* Moving fits are computed for every cell at once from windowed moment sums (box filters
  or small centred correlations), *leave-one-out*: the tested point is not in its own fit,
  and the prediction variance factor ``h = (N^-1)_00`` of the fit on the points actually
  present is used in the test ``v / (s sqrt(1/p + h)) > k`` (Baarda's data snooping with
  ``p`` the point's weight). Missing neighbours widen ``h``: uneven spacing is handled.
  Where the window's points do not determine the model, the point is not tested.
* The mean / linear profile and the horizontal / inclined plane have dedicated kernels
  (:func:`fit_rows`, :func:`fit_box_2d`): running box means of ``w x^j``, ``w z x^j``
  on absolute positions (float64, O(1) per cell for any window), recentred on each cell,
  the centre taken out of the sums, the normal equations solved by cofactors. Fits and
  snooping run in bands of rows (:func:`fit_and_snoop`; window fits with a halo of rows,
  Y profiles on a transposed copy), so no full-size float temporary is made and the
  result is that of one fit of the whole raster. Their rounding depends (around 1e-9 m on
  a 865-column DSM) on where the array starts.
* The polynomial (mountainous terrain) and the Gaussian-weighted prediction sum
  ``w k^p``, ``w z k^p`` by exact centred correlations (O(window) per cell): a block gives
  the same fit as one pass, bit for bit (box sums on absolute positions moved the
  polynomial by up to 3e-4 m and changed 4 cells of a Pleiades DSM between blocks and one
  pass). The polynomial surface runs in tiles with a halo on all sides, so the work
  between two progress reports stays bounded.
* ``progress(fraction)`` is called every band or tile of every step (hundreds of times on
  16 Mcells, at most 0.2 s apart there); a ``Cancelled`` it raises stops the run at once.
* Snooping tests all points at once against fits without them (externally studentised
  residuals); with ``snooping_iterations > 1`` the fit is repeated without the removed
  points and with the weight factor on the points found below it.
* Break lines restrict every comparison to the tested cell's region (a connected
  component of non-break cells; break cells form their own regions along the line). A
  window could still join two cells of one region around the end of a line that stops
  inside the window; in block mode, regions are labelled per block (the halo keeps the
  difference away from the block's core in practice).
* Step 3 tests only the cells a removal is possible for (a neighbour lower by more than
  the tolerance; higher by more than the low tolerance for the pits), gathering their
  neighbours (NaN across a break line); the result is that of the test of every cell.
* Step 4 scans the profiles of a band of rows at once as one concatenated 1-D array of
  the remaining points; only the steps larger than the jump are examined further.

Defaults: data snooping critical value 4, one fit per length, weight factor 0.02 (low
points' tolerance x 7), step 7 off, no second iteration, step 3 repeated; on the 7 ISPRS
reference samples (1 m raster of the lowest points) the mean total error is 5.4 %.

References
----------
Jacobsen, K. (2004). Int. Arch. Photogramm. Remote Sens. Spatial Inf. Sci. XXXV-B3
(Istanbul). Describes the program RASCOR (Institute of Photogrammetry and GeoInformation,
Leibniz University Hannover): terrain characterisation, height distribution, neighbour
differences, sudden change of level, moving profiles and surfaces, local prediction,
weights for points below the reference, break lines and special areas, and the highway
example (21.6 % of the points removed without, 10.4 % with break lines).

Package layout (the method's stages)
------------------------------------
* :mod:`.kernels`: band planning, window sums, small normal-equation solvers;
* :mod:`.fits`: the leave-one-out moving fits and the data snooping (steps 5-7);
* :mod:`.regions`: break lines and special areas;
* :mod:`.terrain`: step 1, terrain characterisation and the random error;
* :mod:`.steps`: steps 2-4; :mod:`.moving`: steps 5-7;
* :mod:`.parameters`: the parameters derived from the DSM, the block halo;
* :mod:`.sequence`: :func:`filter_rascor`, the steps in the paper's order;
* :mod:`.method`: :data:`METHOD`, the registry entry.
"""

from .method import METHOD
from .moving import remove_prediction_outliers, remove_profile_outliers, remove_surface_outliers
from .parameters import DEFAULTS, PROFILE_LENGTHS_M, SURFACE_SIZES_M, rascor_halo, resolve_rascor_params
from .regions import break_regions
from .sequence import STEP_NAMES, filter_rascor
from .steps import remove_height_outliers, remove_level_changes, remove_neighbour_differences
from .terrain import SIGMA_FLOOR, TERRAIN_CLASSES, characterise_terrain, estimate_sigma, model_degree

__all__ = ["DEFAULTS", "METHOD", "PROFILE_LENGTHS_M", "SIGMA_FLOOR", "STEP_NAMES", "SURFACE_SIZES_M",
           "TERRAIN_CLASSES",
           "break_regions", "characterise_terrain", "estimate_sigma", "filter_rascor", "model_degree",
           "rascor_halo", "remove_height_outliers", "remove_level_changes", "remove_neighbour_differences",
           "remove_prediction_outliers", "remove_profile_outliers", "remove_surface_outliers",
           "resolve_rascor_params"]
