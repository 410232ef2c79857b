"""Morphological filter: grey opening plus a two-sided height test (issue 7).

Two forms share one module:

**Single window (the 1996 production form).** The lowest surface, with pits narrower
than three cells first closed, is grey-opened (erosion then dilation, Haralick et al.
1987) with one square structuring element a little larger than the largest object to
remove. The opened surface ``O`` is the terrain. A cell more than ``dh`` above ``O`` is an
object (class 1: buildings, trees); a cell more than ``dh`` below it is a blunder (class 2:
image-matching errors); the rest is the topographic surface. ``dh`` comes from prior
knowledge of the object heights and of the data's accuracy (the production system used
5 ft); here it is derived from the data's noise when not given.

**Progressive (Zhang et al. 2003; Pingel et al. 2013, SMRF).** A single large opening cuts
hill tops and ridges by up to ``slope x window radius``, so on sloped terrain the single
form removes ground. The progressive form opens the surface with windows growing from one
cell to the largest object; at step ``k`` (window radius ``r_k``, metres) a cell whose
opened height drops by more than ``t_k = s r_k`` from the previous step is flagged as an
object (SMRF's elevation threshold, ``s`` the terrain slope). The threshold grows with the
window and the slope, so terrain survives while objects, which drop by their full height
once the window outgrows them, are flagged. Then, as in SMRF, a provisional surface
``ZIpro`` is built from the unflagged cells (flagged ones take the last opened surface,
which is the ground reconstructed under them) and every cell is classified against it:
ground when ``|z - ZIpro| <= dh + e_s * slope(ZIpro)`` (SMRF's ``e_t``, ``e_s``), object
above, low outlier below. Candidate low outliers are found first by SMRF's pre-step (the
same progressive filter on the inverted surface, 1 m window, slope 500 %); they are
replaced by the closed surface for the opening and, like SMRF's flagged cells, left out
of ``ZIpro``, so the final test makes a pit class 2 only when it lies below the ground
reconstructed around it (a gap between tree crowns stays ground).

Outline cells (what the paper leaves open on a grid). SMRF classifies points, whose final
test reads ``ZIpro`` between cells. A cell of a DSM straddling an object's outline is part
roof or crown and part ground and stands between the two (in a top-surface DSM a ring of
them around every roof and crown); it drops by only part of the object's height when the
window outgrows the object, so the flags miss it, and at its own height in ``ZIpro`` it
passed the final test as ground. An unflagged cell touching a flagged one is an outline
cell when it stands more than ``dh`` plus the terrain's rise over one cell diagonal above
the lowest unflagged cell next to it (:func:`find_outline_cells`; the rise from the
terrain's 90th-percentile slope, ``outline_slope``, or the opened surface's own slope
there, whichever is steeper); it leaves ``ZIpro`` like the flagged cells. On the 2 m
opengeos top-surface DSM these cells were three quarters of the cells kept as ground more
than 1 m above the reference DTM (DTM RMSE 1.91 -> 1.13 m).

Attached tiers (the same gap of the paper, one level up). A building's annex or lower roof, or
the lower part of a crown, stands on the object: when the window outgrows the object it drops
by only its own height, below ``s r_k`` for a wide object, and SMRF keeps it in ``ZIpro`` at
its own height. A connected region of unflagged cells standing above the last opening by more
than the final test's tolerance, touching a flagged object, fitting in a box sqrt 2 times the
largest window (a square as wide as the window in any orientation), and bounded mostly by walls
(its edge on the ground more than ``dh`` plus the terrain's rise over a cell diagonal above the
lowest ground beside it, the outline test; the raster's border is no wall), or enclosed by the
object and its outline cells with no edge on the ground at all, is a tier of the object and
leaves ``ZIpro`` too (:func:`find_attached_tiers`); terrain the opening cut falls to the ground
at the terrain's slope and stays. On the generalisation matrix: simulated mixed
lidar 2.2 -> 0.1 %, simulated urban lidar 3.4 -> 0.3 %, opengeos DSM 8.4 -> 7.3 % (DTM RMSE
0.97 -> 0.92 m), mean 7.71 -> 7.53 %. Counting the raster's border as a wall (the outline beyond
it unknown) took a region cut by the border on most sides for a tier (ISPRS sample 41 at 2 m:
10 -> 30 %). The enclosed regions (no edge on the ground, no low outlier or nodata cell beside them:
the annexes and lower roofs between a building's wings and its outline cells) that the share of walls
left as ground: ISPRS sample 31 at 1 m 3.63 / 4.30 -> 2.96 / 3.93 % (lowest / highest point), at 2 m
highest 3.84 -> 1.69 %, opengeos DSM 7.30 -> 6.29 % (DTM RMSE 0.92 -> 0.65 m), matrix mean 7.33 ->
7.27 % (half A 3.95 -> 3.87, half B 10.79 -> 10.77). Its cost: ground enclosed by a dike or a road
embankment that the opening flagged (samples 61 and 71, whose flags are the error) held the fill up
there; as tiers they leave it (sample 61 +0.15 to +0.33, sample 71 +0.1 at 1 m, +0.5 at 2 m). Counting
the low outliers as enclosing cells took a scan line of ground between a roof's lines of the
highest-point DSM for a tier (sample 41 at 1 m highest 3.34 -> 4.26 %).

Cut terrain (the paper's one slope for the whole raster). SMRF's threshold ``s r_k`` uses one
terrain slope (the median, at least 0.3); on terrain steeper than that in places (a knoll or a spur on
a mountainside) the opening cuts the top by more than ``s r_k`` and the flags take it for an object.
What tells such a top from an object is what bounds it: an object stands on walls, terrain falls to
the ground around it at the terrain's slope. A connected flagged region none of whose edge cells is
a wall (the outline test: more than ``dh`` plus the terrain's rise over a cell diagonal above the
lowest ground beside it), with cells inside its edge (a region one or two cells wide is its own
outline: a bush, a car), not touching the raster's border and fitting in the tiers' box is
terrain and stays ground (:func:`find_cut_terrain`). On the generalisation matrix: lidar hexbin-crop
(mountain terrain, knolls and spurs) at 1 / 2 / 4 m 2.68 / 4.09 / 35.27 -> 1.38 / 2.66 / 34.28 %,
no other row changed; mean 7.42 -> 7.37 %.

The ground's slope (the paper's one slope, where the threshold is applied). SMRF's threshold ``s r_k``
passes terrain of slope at most ``s``; one ``s`` for the raster (the median slope of the 40 m block-minimum
surface, at least 0.3) is below the slope of much of a rough steep relief, whose knolls, spurs and crests the
opening then cuts by more than ``s r_k``, on regions too long, too wide or too steep at their edges for the cut
terrain's rule. At each cell the threshold is at least ``min(G_k, S) r_k`` (:func:`ground_slope_map`,
:func:`l1_slope`): ``G_k`` the steepest ground slope within the step's window, read on the erosion by the
largest window (no object the filter removes is left in it; it keeps the slopes of the terrain's convex parts,
the parts an opening cuts), as the L1 norm of its gradient (how far a square window's corner reaches below
its centre), its steps (walls of roofs wider than the window, the minimum's switches on level ground) removed
by an opening of the slopes, at most 1.5; ``S`` the cell's own slope, so a level roof on a steep hillside
keeps ``s r_k`` (without it, the simulated mixed lidar at 4 m, a flat roof on a 35-40 degree hillside: 0.70
-> 4.6 %). ``benchmarks/bare.py``: the fBm mountain at 0.5 / 1 / 2 / 4 m 12.2 / 13.2 / 14.7 / 16.5 -> 0.9 /
1.7 / 6.5 / 10.6 % (the crests' level tops are left: a level cell's own slope is 0), mean 2.59 -> 1.75 %.
Generalisation matrix: lidar hexbin-crop (forested mountain) at 1 / 2 / 4 m 1.44 / 2.40 / 9.77 -> 0.94 /
1.14 / 7.55 %, synthetic mixed 6.24 -> 3.68 %, no row worse by more than 0.2; mean 3.139 -> 3.053 % (half A
3.615 -> 3.553, half B 2.650 -> 2.539). The erosion by the largest window misses terrain narrower than it (a
cone 60 m across under 40 m windows, an embankment's flat crest between slopes). Each step also passes the
drop ``G'_k r_k``, ``G'_k`` read on the step's own erosion (:func:`_spare_continuing`), where
that slope holds on half of some straight line as long as the largest window (a flank continues along the
feature; a crown's slope, which the step's erosion keeps too when the crown is wider than the step's
window, covers no line longer than the crown) and where the cell is the top across it (the surface the drop
is measured from rises above it by no more than the drop within the step's window: a shrub on a long slope
lies below the ground uphill). Probe breakline at 0.5 m (a road embankment 5-10 m high with trees):
3.33 -> 0.16 %; generalisation matrix 3.018 -> 3.000 (synthetic mixed 1 m 3.59 -> 1.67; simulated mixed
lidar at 1 m, a level roof on a 35-40 degree hillside, 0.09 -> 0.42), dtm 2.434 -> 2.427. The last step was
left out at first (its erosion is the ground slope map's, which was thought to cover it), but there the threshold is
``min(G_k, S) r_k`` and a level crest's own slope ``S`` is 0: an embankment first cut by the largest window (the
synthetic breakline at 1 m, window 25 m) lost its crest, 1.97 % of the cells. At every step: breakline at 1 m 1.97 ->
0.09 %, lidar hexbin-crop (forested mountain) at 1 / 2 / 4 m 0.86 / 0.93 / 7.33 -> 0.73 / 0.84 / 6.02 %; the cost:
simulated mixed lidar at 4 m 0.70 -> 1.12 % (a flat roof 40 m wide on a 35-40 degree hillside, its uphill edge at
the hillside's level, no higher ground within the last window: at 4 m cells its interior reads like a terrace's
crest). The cut terrain's rules below judge the flags with the last step's passed cells still in them: a crest the
last step passes leaves its shoulders flagged, lines a cell wide with no cell inside their edge, which those rules
keep as outlines (a 4 m dike on a floodplain: 400 of its 3400 cells, against 125 with the crest flagged and given
back by the rules, 36 now).

The raster's edge (windows clipped to the data). At a cell near the edge the opening's windows hold only the
cells the raster has: on a plane rising towards the edge the dilation finds no cell uphill to lift the erosion
back, so the opening sits ``|g_n| (r - e)`` below a cell ``e`` cells from that edge and ``(|g_x| + |g_y|) r``
below the highest corner: the cut of a crest, which SMRF's ``s r`` (``s`` an L2 slope) does not cover on a plane
facing a diagonal and which the threshold's ``min(G_k, S) r_k`` covers in the interior. ``S`` came from central
differences, 0 on the outer rows and columns, so the highest corner of such a plane was flagged (QA: a 30 x 30
plane rising 0.3 per cell each way, cell (29, 29)). ``S`` there is read from the cells the raster holds
(:func:`edge_l1_slope`: one-sided across the edge), and the slopes the threshold reads are raised by the float32
rounding of the heights (:func:`add_rounding`, a few units of the last place per cell of run), since at the corner
the drop equals ``S r_k`` exactly and the rounding decided. The edges of blocks are halos, so blocks still equal
one pass. The object-size search (:func:`objects_on_walls`) counts a region's cells on the raster's border as edge
cells no wall shows (its outline lies beyond the data): the search's crests cut by the border had counted their
flagged border cells so, and without them a cut crest on the mountain of ``benchmarks/bare.py`` at 4 m stood on
walls by 32 of 63 edge cells and sized the window (80 m): 1.67 -> 8.46 % of the ground lost; with them 1.04 %.
``benchmarks/bare.py`` 0.536 -> 0.509 % (mountain at 2 / 4 m 0.59 / 1.67 -> 0.29 / 1.04, terraces at 4 m 0.62 ->
0.48), no row worse. Still open: a raster narrower than the largest window plus its slope map (every window clipped, the
erosion by the largest window level, ``G_k`` 0), and planes steeper than the slope map's bound of 1.5 (L1).

Low cells of the final test (the paper's class 2 under a canopy). Under a closed canopy the
largest window finds little ground, ``ZIpro`` is the opened canopy, and SMRF's final test puts the
gaps between the crowns, the only ground seen, below it as low outliers. A low cell stays class 2
when it lies deeper than the pre-step's depth (``s x 1 m``) below ``ZIpro``, or more than ``dh``
below every cell of the ring around it or below its level neighbours (the pre-step's tests on coarse
cells); else it is ground (:func:`confirm_low_cells`). On the generalisation matrix: synthetic canopy
at 1 m 1.55 -> 0.62 %, forest at 1 / 4 m 0.56 / 1.09 -> 0.10 / 0.29 %, ISPRS sample 11 -0.1 to -0.3,
sample 41 +0.01 to +0.02 at 1 m, -0.1 at 2 m; mean 7.37 -> 7.33 %. The single-window form's two-sided
test has the same gap (over vegetation wider than its window the opened surface is the vegetation) and
the same rule: lidar autzen_trim at 1 m (a flat town, single form derived) 4.90 -> 4.56 %, no other row
changed.

Wide windows (the slope's floor outgrowing the terrain). The threshold ``s r_k`` must pass what an
opening cuts of the terrain; ``s`` is measured on 40 m block minima and bounded below by 0.3, because
terrain features narrower than a block (dikes, ramps, knolls) do not show in the block minima and may be
steeper than the median. An opening cuts such a feature by at most its own height, reached by the radius
of half a block (``R``, 20 m); a feature wider than a block shows in the block-minimum surface, which
rises at its measured slope. So beyond ``R`` the threshold grows by the measured median slope ``s_50``
(SMRF's terrain slope, unbounded) where the floor made ``s`` steeper: ``t_k = s R + s_50 (r_k - R)``
(:func:`step_thresholds`; a given ``slope`` is used at every radius, as in SMRF). With the floor at every
radius a flat roof 10 m high and 80-160 m wide on terrain of slope 0.04 faced 12-24 m and stayed ground
(Type II 100 %); now 6.8-8.8 m: the whole roof is an object. The largest window is widened to raised
regions (halls) up to 200 m wide spanning up to 400 m (a hall 115 x 242 m spans more than 200 m). The
synthetic city site (``benchmarks/sites.py``: halls 60-250 m) 16.5 / 16.3 / 9.9 / 17.3 -> 0.45 / 0.15 /
0.08 / 0.11 % at 1 / 2 m lowest / highest; generalisation matrix mean 3.137 -> 3.139 % (an embankment
45 m wide with 35 degree sides, steeper than the floor, spanning the synthetic mixed scene: 5.72 ->
6.24; ISPRS sample 61 +0.04 to +0.10; simulated dense urban lidar 0.29 / 0.13 -> 0.02 / 0.01, lidar
mvk-thin 6.53 -> 6.09). The 90th percentile instead of the median read the walls of the halls
themselves on a raster they fill (0.18 on terrain of 0.04: the 120 m roof stayed ground); searching
objects with windows up to 200 m instead of widening to raised regions standing on walls took terrain
for objects (ISPRS sample 61 3.7 -> 11 %, matrix mean 3.65 %).

The largest object (what the paper leaves to the user). The window is sized from the objects the
progressive filter itself finds with windows up to 100 m (:func:`estimate_object_size`). On steep relief
that search cuts crests and spurs too (touching the raster's border, so not the cut terrain above): on the
fBm mountain of ``benchmarks/bare.py`` they read 60-88 m and the window, sized from them, cut more
terrain. Only the search's regions standing mostly on walls (:func:`objects_on_walls`, the tiers' test),
or too thin to judge by their walls, size the window; with none the window is 40 m or the width of the
regions flagged if smaller, and ``auto`` uses the progressive form: the single window would be a guess,
not a little larger than the largest object as the 1996 form has it, and cuts any terrain feature
narrower than it by its full height (dikes on a floodplain, which 40 m block minima do not show).
``benchmarks/bare.py``: mountain at 0.5 / 1 / 2 m 0.93 / 1.69 / 6.50 -> 0.04 / 0.11 / 0.83 %, levees at
0.5 / 1 / 2 m 6.20 / 15.64 / 5.13 -> 0.09 / 1.90 / 2.35 %; the cost: the progressive form's flags at its
smallest windows read the noise of a fine raster (``s r_1`` = 0.15-0.3 m against 0.15 m of noise), river
at 0.5 / 1 m 0.06 / 0.05 -> 1.99 / 1.55 %, mounds 0.81 / 0.92 -> 1.37 / 1.29 %; bare mean 1.75 -> 1.12 %.
Generalisation matrix mean 3.053 -> 3.049 % (ISPRS sample 61 -0.04 to -0.11; with its empty cells at
1 m +0.36: its window 29.5 -> 25.6 m once a 4 m embankment is left out). The mountain at 4 m (10.6 %) was
left: its cut crests stood on one-cell rises steeper than the 90th-percentile slope of 40 m blocks, so on
walls (next paragraph).

The single window's cut of the terrain (the 1996 form's premise, read on the terrain itself). ``auto`` takes the
single form where the terrain is flat at the window's scale: the 90th-percentile slope of 40 m block minima times
half the window at most ``dh``. Those blocks do not show terrain features narrower than a block: on the levees at
4 m the search found a region on walls at the dikes' junction (one-cell rises of 2 m), so its 28 m window was
an object's, the block minima read a slope of 0.002 and the single window cut all three dikes (13.1 % of the
ground). The progressive search kept the dikes as ground, so the single opening's cut is counted on the ground
the search kept (:func:`single_window_cuts`), deeper than the search's own object height (``dh``, at least 2 m):
where those cells outnumber the cells of objects the search found, the single window would remove more terrain
than objects and the progressive form is used. Levees at 4 m: 659 cells cut deeper than 2 m against 96 of
objects, 13.08 -> 10.66 % (the progressive form's flags on the dikes' crests are left: next paragraph); lidar
autzen_trim at 1 m (a flat town, the only row of the matrix in the single form) keeps it
(117 cells of the kept ground cut deeper than 2 m against 1967 of objects).

Walls and slopes (what the wall test reads beyond the foot). Every wall test (the outline cells, the attached
tiers, the cut terrain, the objects on walls) compared a cell's rise above the lowest ground beside it with
``dh`` plus the terrain's rise over a cell diagonal, the terrain's slope read on 40 m block minima (0.002 on
a floodplain), which do not show a dike, an embankment or a mountain's crest narrower than a block: their
flanks read as walls. A wall is a step across about one cell; a flank is a slope the ground goes on
descending beyond its foot. So a cell is a wall only when it also stands more than ``dh`` plus the ground's
descent beyond the foot above it (:func:`continuing_rise`: the smaller of the next two steps down, at most
the steepest terrain slope 1.5 over a cell diagonal); two steps, so that the mixed cells of a top-surface
DSM (one cell at part of a roof's height between the roof and the ground, then level ground) do not read as a
slope continuing, and the cap keeps a wall with its mixed cell higher than 1.5 cell diagonals a wall.
``benchmarks/bare.py``: mountain at 4 m 10.55 -> 2.26 %, levees at 1 / 2 m 1.90 / 2.35 -> 1.58 / 0.95 %,
dunes at 4 m 1.98 -> 1.07 %, mean 0.96 -> 0.70 %, no row worse. Generalisation matrix: synthetic breakline
at 1 m 3.15 -> 1.97 %, mean 3.055 -> 3.018 % (half A 3.569 -> 3.536, half B 2.527 -> 2.487); the opengeos
top-surface DSM at 2 m +0.20; dtm (its member) 2.439 -> 2.433 %, no row worse by 0.1. ISPRS 1 m lowest 3.99 ->
3.98 % (dtm 3.32 unchanged); ``benchmarks/sites.py`` mean 2.83 -> 2.80 % (embankment at 1 m 2.30 -> 1.98), no
row worse. The land-side flank of the 6 m dike of the levees at 4 m is three cells of 4 m (6, 4, 2, 0), so its
middle cell's second step beyond its foot is the level floodplain, as beyond a mixed cell (6, 3, 0), and it read
as the crest's outline. What tells them apart is the step down to the cell from the cell opposite its foot (2 m:
the slope runs through the cell; a mixed cell's foot has none beyond it), and that such a flank runs along its
feature: an outline candidate whose rise is within ``dh`` of the smaller of that step and its foot's next one,
where such cells hold half of a line as long as the largest window, is no outline cell
(:func:`_flank_along`, in :func:`find_outline_cells`). ``benchmarks/bare.py``: levees at 4 / 2 m 10.66 / 0.95 ->
9.58 / 0.86 %; generalisation matrix (82 rows, morphological and dtm) unchanged on every row. Without the line (every
cell on such a slope): levees 8.02 / 0.82, ISPRS sample 21 at 2 m -0.4, sample 71 at 2 m lowest -0.24, but the
low crowns and shrubs of the opengeos top-surface DSM at 2 m fall over several cells in even steps of 0.6-1.2 m
too and lost their outlines: 6.56 -> 7.35 % (dtm +0.12; the highest neighbour instead of the cell opposite the
foot 7.75). Still open: the dikes' crests the progressive flags take at 4 m (9.6 %: their edges stand on walls).

Terrain longer than the box (dikes, embankments, crests across the raster). The cut terrain's rule judges whole
regions within the tiers' box and off the raster's border, so a dike narrower than the largest window, steeper
than ``s`` and running across the raster stays flagged (the erosion by the largest window removes it, so the
ground slope map does not see its flanks, and its crest is level). Every object the opening flags is narrower
than the largest window, so the window around any of its cells holds its outline across it, and most of an
object's outline is walls: a flagged cell whose largest window holds edge cells that are no walls and a cell
inside an edge, and no wall at all (nor a flagged cell on the raster's border), is terrain
(:func:`find_cut_slopes`; bounded reach, so blocks equal one pass). ``benchmarks/bare.py``: levees at 1 m
1.58 -> 0.36 % (the curved 6 m dike), mounds at 1 m 0.20 -> 0.18, mean 0.70 -> 0.67; no other row changed.
Generalisation matrix (82 rows), ISPRS and dtm: every row unchanged. Not reached: a crest one or two cells wide
(levees at 2 m: no cell inside its edge) and the levees at 4 m (at 4 m cells a 6 m dike's 1:2 flank is steps
of 2 m then level ground, a wall with a mixed cell there). Reading ``G_k`` on each step's own
erosion too (the erosion by the largest window removes a dike narrower than it) kept such flanks below the
flags (probe: breakline at 0.5 m 3.33 -> 0.18 %, mixed with holes at 1 m 5.76 -> 4.55) but it keeps the crowns
of trees wider than the step's window too: ISPRS sample 71 at 2 m +0.15 / +0.23, dense forest lidar at 1 m
+0.11 (matrix 3.018 -> 3.024); not used.

Whose walls (the outline that tells an object is its own). :func:`find_cut_slopes` kept a cell flagged when any
wall lay within the window, another object's too, and among houses, trees and shrubs some wall always does
(largest window 57 m on the synthetic mixed scene at 1 m: not one flagged cell was free), so an embankment
there stayed flagged along its whole length. The walls and the cell inside an edge are now read on the cell's
own region, reached through the flagged cells within the window's half-width (:func:`_reached`, a geodesic
dilation: bounded reach); a wall with no cell inside an edge beside it is a region one or two cells wide, its own
outline (a shrub on the flank, a car at the foot), which keeps its own cells and their neighbours flagged and
says nothing of the region it touches. A region one or two cells wide that no wall bounds (a hedge, cars, low
lines on a 1 m lowest-point DSM, ISPRS sample 31) reaches no cell inside an edge of its own and stays flagged, as
other objects' walls kept it before (read on the whole window instead, sample 31 at 1 m: 2.96 -> 5.27 %).
Generalisation matrix: synthetic mixed at 1 m (an embankment 45 m wide among houses) 1.67 -> 0.88 %, breakline
at 1 m 0.09 -> 0.08, no other row changed; mean 3.08 -> 3.07 (half A 3.64 -> 3.62, half B 2.50). ISPRS seven
unchanged (3.99 %); ``benchmarks/bare.py`` 0.509 -> 0.509 (outcrops at 0.5 m 0.50 -> 0.49); ``benchmarks/sites.py``
2.788 -> 2.786 % (quarry at 2 m lowest 3.50 -> 3.43, at 1 m highest 3.90 -> 3.91). dtm (a member): matrix
unchanged (2.46 %, halves 2.67 / 2.24), ISPRS sample 71 at 1 m +0.01 (one object point), mean 3.19. Not reached:
the embankments of ISPRS samples 61 and 71 (at 2 m: 5.08 %, Type I 644 points, 410 of them on one raised road
34 m wide whose long sides are steps of 4-6 m at 2 m cells, walls of its own outline).

The noise (Zhang et al. 2003's ``dh_0``, which SMRF drops). SMRF's threshold ``s r_k`` starts at ``s``
times one cell: 0.075-0.15 m at 0.25-0.5 m cells, at or below the noise of the surface. The first steps
measure the drop from the surface itself, which on noisy level ground is the cell's deviation plus the
opening's depth below the noise's mean (on white noise of deviation ``sigma`` more than ``sigma`` at a third
to a half of the cells), so the flags took large parts of a fine raster's ground; those cells took the
opened surface in ``ZIpro``, 1-3 ``sigma`` below the noise's mean, and the final test called the higher ones
objects. Every step's threshold is at least ``dh_0`` = 4.5 ``sigma`` (:func:`noise_allowance`: the 99.9th
percentile of those drops), ``sigma`` the sensor's noise (``noise_m``: the cleanest tiles' noise of the
DSM's ground-level cells). ``benchmarks/bare.py``: river at 0.5 / 1 m 1.99 / 1.55 -> 0.08 / 0.10 %, mounds
1.37 / 1.29 -> 0.13 / 0.52 %; synthetic scenes: mixed at 0.25 m 1.63 -> 0.24 %, city with 0.15 m of noise
and holes at 1 m 3.29 -> 0.63 %, flat 1.39 -> 0.19 %. Zhang's additive ``dh_0 + s r_k`` raised every step's
threshold and lost low objects: ISPRS sample 31 at 1 m (0.05 m of noise) Type II 6.3 -> 8.1 %; the whole
window's noise instead of the cleanest tiles' read the low vegetation of a highest-point DSM (ISPRS sample
11 at 2 m highest: 0.37 m against 0.23 m; total error 26.07 -> 27.66 %, with the cleanest tiles' 26.59 %).

Still open: low objects on slopes (Type II on the ISPRS samples, 11.2 % of the object points). Two gaps hold it,
neither the threshold: without the ground slope term ``min(G_k, S) r_k`` Type II is 11.06 %, without the
continuing slopes' pass 11.12 %, without ``dh_0`` 11.15 %. (1) A flat element rests on the terrain uphill: an
opening lowers a shrub of height ``h`` reaching ``w`` up a slope ``g`` by only about ``max(0, h - g w)``, so no step
flags it. At 1 m lowest the largest share of type II points lies in cells no stage touched
(``benchmarks/morphological_errors.py``'s ``kept``: sample 11 1760 of 3356, sample 51 219 of 650, sample 71 72 of
254), and at the unflagged cells more than 0.5 m above the reference the last opening drops the cell by 0.91 m
against 1.24 m of height (medians, sample 51; the ground slope map reads 0-0.03 there, the terrain 0.5-0.7).
(2) SMRF's final test gives flagged cells back within ``dh + e_s slope(ZIpro)``, and at a flagged
cell ``ZIpro`` steps from the last opening up to the kept vegetation beside it, so it reads 0.8-1.0 where the
terrain is 0.55-0.7 (flagged type II cells, samples 11 / 51 / 71). Tried, not used (ISPRS seven 3.99 %):
the final test's slope read as ``min(slope(ZIpro), slope(O))`` (``O`` the last opening: no step up to kept cells)
3.92 % and generalisation matrix 2.921 -> 2.897 %, but the cells it turns to objects hold more ground than object
points (sample 11 at 1 m: 207 / 142) and ``benchmarks/sites.py`` 2.79 -> 2.85 % (quarry at 1 m 6.26 -> 6.65),
``benchmarks/bare.py`` 0.51 -> 0.54 % (an opening levels the crests it cuts, and those cells lie 0.9-1.9 m above
it with ``slope(O)`` near 0, samples 11 / 21 / 51); read on the
erosion by the largest window instead, 3.65 % (Type II 8.62 %) and matrix 2.786 %, but that erosion lies metres
below wherever a step or an escarpment is within the window (it is level there: tolerance ``dh``), which is
where it gained, and the benches of the quarry and the terraces of the hillside lost their top edges: sites
2.79 -> 2.91 % (quarry at 1 m 6.26 -> 7.50); kept to where the erosion is a plane's copy (``O - E`` within
``L1(E) r + dh``) 3.96 %, its slope's maximum over the window 3.95 %, ``max(slope(E), slope(O))`` 3.93 % (matrix
2.901 %, half B 2.246 -> 2.248, sites 2.79 -> 2.85, bare 0.51 -> 0.54: on bare terrain the opening's flags are given
back by that tolerance, roads at 1 m 0.02 -> 0.14 %, so any reading below ``slope(ZIpro)`` costs terrain). A tilted
element (the same steps on ``z - T``, ``T`` the last opening's mean over the largest window, flags added where
``T`` is steeper than ``s``): Type II 10.81 % but Type I up, 3.97 %, and the forested mountain lidar hexbin-crop at
4 / 2 m 5.96 / 0.76 -> 7.90 / 1.40 % (Type I at 4 m 6.16 -> 8.17 %); also where ``|O - T| <= dh``, 3.98 %. The
cell's own slope ``S`` read on the last opening instead of the DSM 3.97 %; Zhang et al.'s threshold on the
window's increment ``s (r_k - r_ref)`` 5.12 % (Type I of sample 41 8.2 %); the DTM under objects no higher than
``ZIpro`` 4.04 %.
Where the type II points are (``benchmarks/morphological_errors.py``, session 27): at 1 m lowest most lie in
``kept`` cells (sample 11 1760 of 3356, 31 537 of 844, 51 219 of 650); by kind, lower roofs and annexes 3-4 m
high between a building's wings that the tiers' rule rejects because a few of their edge cells reach the ground
without a wall (sample 31: two regions of 100-120 cells, 285 points at 1 m highest, 341 at 2 m lowest), terraced
buildings on sample 11's hillside whose uphill edges meet the ground at their own level or run off the raster,
and low vegetation 1-2 m high on slopes of 0.45-0.7 (sample 51, the flat element above). Counting a region's
outline against the object as walls in the tiers' share (the region stands on the object there): ISPRS 3.99 ->
4.24 % (sample 31 2.96 -> 2.15, but pockets of ground among trees and houses became tiers: 71 2.56 -> 3.80, 21
+0.5, 11 +0.5; their height above the opening or above the ground beside their edge does not tell them from the
tiers), not used. Lowering the slope's floor ``s`` from 0.3 (low wide objects: a 1 m patch wider than ``2 h / s``
is never flagged; the dense forest lidar's understory, 17557 of its 27137 type II points at 1 m) gains type II but
flags the embankments of samples 61 and 71: floor 0.25 / 0.2 ISPRS 4.15 / 4.57 % (sample 71 2.56 -> 3.67 /
6.47). The embankments are the crux: their outlines at 1-2 m cells are walls as much as roofs' (share of walls
0.84-0.92 against 0.94-1.0 for buildings, samples 61 and 71), so no wall rule tells them apart.
Crests between flanks (session 28, branch h-morph 76c7a77: from the third step a newly flagged cell given back
where the reference opening has continuing flanks rising to it on one side of a row or column and falling away on
the other, their tops within the step's threshold, the cell the top across): sample 71 2 m 5.08 / 5.11 -> 2.61 /
2.77, synthetic mixed 1 m 0.88 -> 0.38, matrix 3.07 -> 3.01, sites 2.79 -> 2.73, ISPRS 3.98; but half B 2.50 ->
2.52 (synthetic-lidar mixed 4 m 1.12 -> 1.86: a flat roof flush with a 35-40 degree hillside beside a raised
road), sample 61 unchanged (one side of its embankments is a retaining wall), the filter's CPU +55-67 % and dtm's
+24 % at 4 Mcells for dtm 2.46 -> 2.44: not adopted.

The reference's slopes (session 29: where the crest is narrower than the step's window). Sample 71's raised road
at 2 m (5-6 m high, a crest of 10 cells, flanks of 0.6-0.75 over 4 cells, 16 cells across; window 30 m, 15 cells)
is flagged at the last step: its drop (4.9 m, the whole road, which the window outgrows) exceeds ``s r_k`` = 4.2 m,
and the erosion by the largest window and the step's own erosion hold no road, so neither ``G_k`` nor ``G'_k``
sees a slope. The erosion of the reference (the step whose opening the drop is measured from, radius 3 cells)
holds it, and :func:`_steepest_sides` reads its flanks on its crest (0.38-0.58). Each step also passes the drop
``d <= G'_j r_k`` (``G'_j`` the reference's step slope, kept from that step) by the continuing slopes' test
(:func:`_spare_continuing`: half of a line as long as the largest window, the cell the top across), with ``G'_j``
read as 0 on the cells the earlier steps' drops flagged past their own continuing slopes (:func:`reference_slope`):
terrain is continuous, and the slopes a rough canopy or a wall leave in a small window's erosion lie on cells the
smaller windows already flagged. Generalisation matrix, 73 rows: 2.946 -> 2.856 % (half A 3.476 -> 3.324, half B
2.401 -> 2.375; worst row sample 11 at 2 m highest 26.61 unchanged); sample 71 at 2 m 5.08 / 5.11 -> 2.45 / 2.84,
at 1 m 2.56 -> 2.40, sample 61 at 2 m 4.10 / 4.09 -> 3.51 / 3.92, at 1 m -0.09, synthetic mixed 1 m 0.88 -> 0.49,
opengeos 6.56 -> 6.52 % (DTM RMSE 0.690 -> 0.677 m), breakline 1 m 0.08 -> 0.05; the one row worse: dense forest
lidar at 1 m 1.37 -> 1.38. ISPRS seven 3.99 -> 3.96 %. ``benchmarks/sites.py`` 2.786 -> 2.661 % (quarry 1 m lowest
6.26 -> 4.48, embankment 1 m lowest 1.95 -> 1.07, bridge 1 m -0.3 to -0.5, hillside 2 m lowest 2.24 -> 1.82), no
row worse; ``benchmarks/bare.py`` 0.509 -> 0.465 % (levees 4 m 9.58 -> 7.92, dunes 1 m 0.31 -> 0.17; levees 1 m
0.01 -> 0.03 the one row worse). Measured on the way: the same slopes on every cell gave back crowns of the
opengeos canopy and a flat roof beside a 20 m wall of the simulated mixed lidar (matrix 2.854, but opengeos DTM
RMSE 0.69 -> 0.72, sample 11 at 2 m highest 26.61 -> 26.64, simulated mixed lidar 1 / 4 m +0.39 / +0.24);
requiring as well that the reference falls by the drop on both sides along a row, column or diagonal within twice
the step's half-width (a crest across) kept that row but not the RMSE (0.70; within the half-width it kept nothing
of the road: a feature narrower than the window is cut whole); leaving out the flagged cells of every earlier
step, this rule's passes included, scored 2.844 % but chains the reach step by step (no bounded halo): the flags
read are those before the rule. The dtm's member keeps the rule off (``reference_slopes=False``): there the vote's
matrix gained (2.350 -> 2.329 %) but its opengeos DTM RMSE went 0.63 -> 1.00 m.

The provisional surface differs from SMRF's in one respect: SMRF inpaints the flagged
cells from the unflagged ones, whose reach is unbounded; here they take the last opened
surface, which reconstructs planes and ramps under objects exactly and keeps the
filter's reach bounded (blocks of a large raster give the one-pass result).

Windows grow geometrically (``window_growth``, default sqrt 2: radii 1, 2, 3, 5, 8, 12, ...
cells; 2 gives the doubling windows of Zhang et al. 2003, 1 SMRF's one-cell steps). The drop
at step ``k`` is measured from the opening of the window that doubles into ``r_k``
(:func:`drop_references`: Zhang's doubling interval; the previous step when the windows
double or grow by one cell). An opening with half-width ``r`` cuts terrain of slope ``s`` by at most ``s r`` along
the rows and columns (``sqrt(2) s r`` on slopes facing a diagonal of the square window, where
SMRF's disk would give ``s r``), and the cut between two radii is below the cut at the
larger one, so the SMRF threshold stays valid for steps larger than one cell. A flat object
of half-width ``R`` vanishes at the first radius ``r_k >= R`` and is flagged when its height
exceeds ``s r_k``: with doubling windows ``r_k`` reaches ``2 R`` (a flat roof 36 m wide and 8
m high faced 0.3 x 32 m = 9.6 m and stayed ground: the simulated urban rows at 1 and 2 m,
7.6 and 6.3 % total error), with sqrt 2 at most ``1.41 R`` (the same rows 3.4 and 2.7 %).
Measuring each step's drop over a doubling of the window, not only since the previous step,
keeps what doubling windows catch of objects whose sides fall over several cells (crowns,
gable roofs): with sqrt 2 steps measured from the previous one, the opengeos DSM's DTM RMSE
went 1.13 -> 1.26 m; measured over a doubling 0.97 m. Square
windows are separable: every erosion and dilation is two 1-D running min/max passes,
each ``log2(window) + 1`` vectorised numpy passes (van Herk / Gil-Werman style
doubling), so a 41-cell window costs about twice a 3-cell one.

Nodata (NaN) is ignored by the min/max filters (the windows are restricted to valid
cells), so no gap filling is needed; the reach of the filter is bounded by the largest
window, and :func:`morphological_halo` covers it.

References
----------
Haralick, R. M., Sternberg, S. R., Zhuang, X. (1987). Image analysis using mathematical
morphology. IEEE PAMI 9(4), 532-550.
Zhang, K., Chen, S.-C., Whitman, D., Shyu, M.-L., Yan, J., Zhang, C. (2003). A progressive
morphological filter for removing nonground measurements from airborne LIDAR data. IEEE
TGRS 41(4), 872-882.
Pingel, T. J., Clarke, K. C., McBride, W. A. (2013). An improved simple morphological filter
for the terrain classification of airborne LIDAR data. ISPRS J. Photogramm. Remote Sens.
77, 21-30.
"""
import math
from typing import Callable, Optional, Tuple, Union

import numpy as np

from .codes import GROUND, LOW, NODATA, OBJECT
from .common import (
    FilterResult,
    as_cell_size,
    as_surface,
    dilate_box,
    finish_mask,
    label8,
    report,
    sub_progress,
    touching,
)
from .estimate import (
    RAISED_REGION_MARGIN,
    RAISED_REGION_MAX_M,
    RAISED_REGION_SPAN_M,
    below_level_neighbours,
    below_surroundings,
    block_minima,
    block_minima_plane_residual,
    held_block_side,
    line_share,
    noise_ground_level,
    object_widths,
    raised_region_window,
    surroundings_reach,
    terrain_slopes,
)
from .geodesic.grey import filter5x5
from .methods import Method, Param, check_values

MODES = ("auto", "progressive", "single")
#: SMRF's low-outlier pre-step: slope 500 % over windows up to 1 m (Pingel et al. 2013).
LOW_OUTLIER_SLOPE = 5.0
LOW_OUTLIER_WINDOW_M = 1.0
#: Default ratio between consecutive window radii of the progressive form.
WINDOW_GROWTH = 1.4142135623730951
#: Bounds of the derived parameters.
_MIN_DH, _MAX_DH = 0.5, 5.0
_MIN_SLOPE, _MAX_SLOPE = 0.3, 1.5
#: Steepest outline slope (rise/run): 100 = 89.4 degrees, a wall. A cliff of undeclared nodata
#: (-9999 beside terrain at +300 m) gives block-minimum slopes of hundreds; no ground is steeper.
_MAX_OUTLINE_SLOPE = 100.0
#: dh = _DH_NOISE x the DSM's noise (at least _MIN_DH, SMRF's e_t).
_DH_NOISE = 3.0
#: The drop of a cell of noisy level ground under the first openings, in units of the noise: the cell's own
#: deviation (3 sigma, as dh) and the opening's depth below the noise's mean (0.9 / 1.4 sigma at 3 x 3 / 5 x 5
#: windows on white noise): 4.5 sigma, about the 99.9th percentile of those drops (4.1 / 4.6 sigma measured on a
#: million cells of white noise). :func:`noise_allowance`.
_NOISE_DROP = 4.5
#: Block size of the coarse minimum surface the terrain slope is measured on, metres.
_SLOPE_SCALE_M = 40.0
_MIN_OBJECT_M, _MAX_OBJECT_M = 10.0, 80.0
#: Largest object when the data shows none, metres.
_DEFAULT_OBJECT_M = 40.0
#: Largest object looked for when deriving max_object_size_m, metres.
_OBJECT_SEARCH_M = 100.0
#: Window growth of the object-size search: doubling windows (Zhang et al. 2003). The size is the
#: widest flagged area's, so a terrain patch flagged by mistake widens the window of the whole
#: raster; the finer sqrt 2 steps flag more of them (lidar hexbin-crop at 2 m: 24 -> 39 m, total
#: error 2.6 -> 4.9 %; with the doubling search 4.0 %, the rest of the matrix within 0.1).
_OBJECT_SEARCH_GROWTH = 2.0
#: Safety factor on the width of the largest objects (roof shapes, sloped ground).
_OBJECT_MARGIN = 1.25
#: Minimum height of an object when deriving its size, metres.
_OBJECT_HEIGHT_M = 2.0
#: Parameters are derived on a grid of at most this many cells (block minima).
_RESOLVE_CELLS = 1_000_000


# --------------------------------------------------------------------------- helpers
def _half_widths(size_m, cell):
    """Half-widths ``(ry, rx)`` in cells of a square window of side ``size_m`` metres.

    The window is ``2 r + 1`` cells wide; ``r`` is at least 1.
    """
    dx, dy = cell
    rx = max(1, int(math.floor((size_m / dx - 1.0) / 2.0 + 0.5)))
    ry = max(1, int(math.floor((size_m / dy - 1.0) / 2.0 + 0.5)))
    return ry, rx


def _radii_up_to(r_max, cell, growth):
    """Half-widths ``(ry, rx, radius_m)`` growing by ``growth`` from 1 to ``r_max`` cells
    along the finer axis; the other axis follows in metres."""
    dx, dy = cell
    fine = min(dx, dy)
    seq, r = [], 1
    while r < r_max:
        seq.append(r)
        r = max(r + 1, int(math.ceil(r * growth - 1e-9)))
    seq.append(max(1, r_max))
    out = []
    for r in seq:
        rad_m = r * fine
        rx = max(1, int(math.floor(rad_m / dx + 0.5)))
        ry = max(1, int(math.floor(rad_m / dy + 0.5)))
        if out and (ry, rx) == out[-1][:2]:
            continue
        out.append((ry, rx, rad_m))
    return out


def window_radii(max_object_size_m, cell_size, growth=WINDOW_GROWTH):
    """Window half-widths of the progressive filter, from one cell to the largest object.

    Parameters
    ----------
    max_object_size_m : float
        Side of the largest window, metres (objects narrower than this are removed).
    cell_size : float or (dx, dy)
        Metres.
    growth : float
        Ratio between consecutive radii (>= 1). 1 gives SMRF's steps of one cell
        (Pingel et al. 2013); 2 the doubling windows of Zhang et al. (2003); the default
        :data:`WINDOW_GROWTH` (sqrt 2) tests an object within sqrt 2 of its own half-width.

    Returns
    -------
    list of (ry, rx, radius_m)
        Half-widths in cells along rows and columns and the radius in metres along the
        finer axis (the ``r c`` of SMRF's threshold ``s r c``), increasing.

    Examples
    --------
    >>> [r[1] for r in window_radii(41.0, 1.0, growth=2.0)]
    [1, 2, 4, 8, 16, 20]
    >>> [r[1] for r in window_radii(41.0, 1.0)]
    [1, 2, 3, 5, 8, 12, 17, 20]
    """
    cell = as_cell_size(cell_size)
    if not (np.isfinite(growth) and growth >= 1.0):
        raise ValueError(f"window_growth must be >= 1 (1: one-cell steps as in SMRF, 2: doubling "
                         f"windows as in Zhang et al. 2003); got {growth!r}.")
    ry_max, rx_max = _half_widths(max_object_size_m, cell)
    r_max = rx_max if cell[0] <= cell[1] else ry_max
    return _radii_up_to(r_max, cell, growth)


def _low_radii(cell, growth):
    """SMRF's low-outlier windows: radii up to ``ceil(1 m / cell)`` cells."""
    r_max = max(1, int(math.ceil(LOW_OUTLIER_WINDOW_M / min(cell) - 1e-9)))
    return _radii_up_to(r_max, cell, growth)


class _Work:
    """Reusable float32 scratch buffers for :func:`_running` (no page faults per pass):
    two for the doubling, one for the first pass of a 2-D filter."""

    def __init__(self):
        self._bufs = [np.empty(0, np.float32) for _ in range(3)]

    def get(self, i, shape):
        size = int(np.prod(shape))
        if self._bufs[i].size < size:
            self._bufs[i] = np.empty(size, np.float32)
        return self._bufs[i][:size].reshape(shape)


def _running_banded(a, r, axis, op, work=None, out=None, band=None):
    """:func:`_running` in bands across ``axis`` (rows for ``axis=1``, columns for
    ``axis=0``) of about :data:`_BAND_BYTES` each, so that the ``log2(2 r + 1)`` passes of a
    band run in the cache instead of streaming the whole array through memory each time.
    The bands are independent (the window runs along ``axis``): the same result.

    Measured on 1108 x 4000 float32 cells, radii 1-40: along the rows 0.155 -> 0.115 s
    (bands of 64 rows); down the columns no gain (its passes are whole contiguous rows
    already), so :func:`_erode` and :func:`_dilate` band only the pass along the rows."""
    if r <= 0:
        return a
    n, m = a.shape[axis], a.shape[1 - axis]
    if band is None:
        band = max(8, _BAND_BYTES // max(1, n * a.itemsize))
    if band >= m or n < 2 * r + 2:
        return _running(a, r, axis, op, work, out)
    work = work or _Work()
    if out is None:
        out = np.empty(a.shape, a.dtype)
    for j0 in range(0, m, band):
        j1 = min(m, j0 + band)
        sl = (slice(None), slice(j0, j1)) if axis == 0 else (slice(j0, j1), slice(None))
        _running(a[sl], r, axis, op, work, out[sl])
    return out


#: Bytes of one band of :func:`_running_banded` (64 rows of 4000 float32 cells).
_BAND_BYTES = 1 << 20


def _running(a, r, axis, op, work=None, out=None):
    """``op`` (np.minimum / np.maximum) over the window ``[i - r, i + r]`` along ``axis``.

    Windows are clipped at the array's edge (the same as replicating the edge values).
    Van Herk-style doubling: ``M_2k[i] = op(M_k[i], M_k[i + k])`` covers ``2k`` cells, and a
    window of ``w = 2r + 1`` cells is ``op(M_k[i - r], M_k[i + r + 1 - k])`` with ``k`` the
    largest power of two <= ``w``: ``log2(w) + 1`` vectorised passes on contiguous slices,
    exact for any data (min and max are idempotent, so the two halves may overlap). The
    ``r`` cells at each end take a running accumulation of the clipped window.
    """
    if r <= 0:
        return a
    w = 2 * r + 1
    n = a.shape[axis]

    def sl(start, stop):
        s = slice(start, stop)
        return (s, slice(None)) if axis == 0 else (slice(None), s)

    if n < 2 * r + 2:                          # window as long as the array: pad (small case)
        shape = list(a.shape)
        shape[axis] = n + 2 * r
        m = np.empty(shape, a.dtype)
        m[sl(r, r + n)] = a
        m[sl(0, r)] = a[sl(0, 1)]
        m[sl(r + n, None)] = a[sl(n - 1, n)]
        k = 1
        while 2 * k <= w:
            length = m.shape[axis]
            m = op(m[sl(0, length - k)], m[sl(k, length)])
            k *= 2
        return np.ascontiguousarray(op(m[sl(0, n)], m[sl(w - k, w - k + n)]))
    work = work or _Work()
    if out is None:
        out = np.empty(a.shape, a.dtype)
    if axis == 1 and a.flags.c_contiguous and out.flags.c_contiguous:
        _running_rows_flat(a, r, op, work, out)
    else:
        src, k, length, i = a, 1, n, 0
        while 2 * k <= w:                      # src[j] = op over a[j .. j + 2k - 1]
            dst = work.get(i % 2, a.shape)[sl(0, length - k)]
            op(src[sl(0, length - k)], src[sl(k, length)], out=dst)
            src, length, k, i = dst, length - k, 2 * k, i + 1
        op(src[sl(0, n - 2 * r)], src[sl(w - k, w - k + n - 2 * r)], out=out[sl(r, n - r)])
    head = op.accumulate(a[sl(0, 2 * r)], axis=axis)            # window [0, j + r]
    out[sl(0, r)] = head[sl(r, 2 * r)]
    tail = np.flip(op.accumulate(np.flip(a[sl(n - 2 * r, n)], axis=axis), axis=axis), axis=axis)
    out[sl(n - r, n)] = tail[sl(0, r)]                        # window [j - r, n - 1]
    return out


def _running_rows_flat(a, r, op, work, out):
    """The doubling passes of :func:`_running` along the rows (``axis=1``) on the flat arrays.

    ``a`` and ``out`` C-contiguous. A pass over the flat array computes, at every cell whose
    window stays inside its row, the value of the per-row pass (the same operation on the same
    two values); the cells whose window runs into the next row get other values, and no later
    pass reads them (each pass reads only the cells of the previous one that were inside their
    row). The last pass fills ``out[:, r:n - r]`` and spills into the ``r`` cells at each end of
    the rows, which the caller then overwrites. One contiguous pass instead of one strided pass
    per row: measured 5x faster on 65 x 4000 float32 bands (numpy's inner loop on strided 2-D
    slices is not vectorised as on a contiguous run).
    """
    rows, n = a.shape
    w = 2 * r + 1
    size = rows * n
    src, k, i = a.reshape(-1), 1, 0
    while 2 * k <= w:                          # src[j] = op over a[j .. j + 2k - 1] (inside a row)
        dst = work.get(i % 2, (size,))
        op(src[:size - k], src[k:size], out=dst[:size - k])
        src, k, i = dst, 2 * k, i + 1
    m = size - 2 * r                           # out[j + r] = op(src[j], src[j + w - k])
    op(src[:m], src[w - k:w - k + m], out=out.reshape(-1)[r:r + m])


def _erode(a, ry, rx, work=None, progress=None, out=None):
    """Grey erosion (running minimum) over a (2ry+1) x (2rx+1) window; +inf = nodata.
    ``progress(0.5)`` between the two separable passes. ``out`` (optional, not ``a``) receives the
    result when both passes run (else a new array, or ``a`` itself for a window of one cell)."""
    tmp = work.get(2, a.shape) if work is not None and rx > 0 and ry > 0 else None
    down = _running(a, ry, 0, np.minimum, work, tmp)
    report(progress, 0.5)
    return _running_banded(down, rx, 1, np.minimum, work, out=out if rx > 0 and ry > 0 else None)


def _dilate(e, ry, rx, has_nodata, work=None, progress=None, out=None):
    """Grey dilation (running maximum) of an eroded surface ``e`` (+inf = no valid cell).

    Returns the dilated surface with NaN where no valid cell is within reach;
    ``progress(0.5)`` between the two separable passes. ``out`` (optional, not ``e``) receives
    the result when both passes run (else a new array, or ``e`` itself for a window of one cell).
    """
    both = work is not None and rx > 0 and ry > 0
    if has_nodata:
        if both and out is not None:            # the column pass reads it before out is written
            np.copyto(out, e)
            e = out
            np.copyto(e, np.float32(-np.inf), where=np.isposinf(e))
        else:
            e = np.where(np.isposinf(e), np.float32(-np.inf), e)
    tmp = work.get(2, e.shape) if both else None
    down = _running(e, ry, 0, np.maximum, work, tmp)
    report(progress, 0.5)
    d = _running_banded(down, rx, 1, np.maximum, work, out=out if both else None)
    if has_nodata:
        d[np.isneginf(d)] = np.nan
    return d


def _as_inf(z, sign=1.0, bad=None, copy=True):
    """``sign * z`` as float32 with nodata set to +inf (ignored by the erosion).

    ``bad`` (nodata cells) is computed when not given; ``copy=False`` lets a positive
    ``sign`` work in place on an array the caller owns.
    """
    if sign > 0:
        a = np.array(z, dtype=np.float32, copy=copy)
    else:
        a = np.negative(z, dtype=np.float32)
    if bad is None:
        bad = ~np.isfinite(z)
    has_nodata = bool(bad.any())
    if has_nodata:
        a[bad] = np.inf
    return a, has_nodata


def open_surface(z, cell_size, size_m, *, close_pits=False):
    """Grey opening of a surface with a square window of side ``size_m`` metres.

    The opening (erosion then dilation with the same flat square, Haralick et al. 1987)
    removes every bump the window does not fit into (objects narrower than ``size_m``)
    and keeps terrain, planes and ramps included, wherever the window fits under it.
    Nodata (NaN) cells are ignored by both passes.

    Parameters
    ----------
    z : array_like, 2-D
        Surface (NaN = nodata); not modified.
    cell_size : float or (dx, dy)
        Metres.
    size_m : float
        Side of the square structuring element, metres (``2 r + 1`` cells, ``r >= 1``).
    close_pits : bool
        First close the surface with a 3 x 3 window, which fills pits one or two cells
        wide (blunders) so that they do not spread into the opening.

    Returns
    -------
    ndarray of float32
        The opened surface (<= the closed surface), NaN where ``z`` is nodata.
    """
    z = as_surface(z)
    cell = as_cell_size(cell_size)
    if not (np.isfinite(size_m) and size_m > 0):
        raise ValueError(f"size_m must be a positive window size in metres; got {size_m!r}.")
    ry, rx = _half_widths(size_m, cell)
    base = _close3(z) if close_pits else z
    a, has_nodata = _as_inf(base)
    out = _dilate(_erode(a, ry, rx), ry, rx, has_nodata)
    out[~np.isfinite(z)] = np.nan
    return out


def _close3(z, work=None):
    """3 x 3 grey closing (dilation then erosion), nodata ignored; NaN stays NaN."""
    neg, has_nodata = _as_inf(z, -1.0)          # -z, nodata +inf: erosion of -z = -dilation of z
    closed = _dilate(_erode(neg, 1, 1, work), 1, 1, has_nodata, work)
    np.negative(closed, out=closed)             # -(opening of -z) = closing of z
    closed[~np.isfinite(z)] = np.nan
    return closed


def drop_references(radii, growth):
    """For each step of ``radii`` (``(ry, rx, radius_m)``, increasing, growing by ``growth``), the
    index of the step whose opening its drop is measured from (-1: the surface itself, radius 0):
    ``m = round(ln 2 / ln growth)`` steps back, the window that doubles into this one (Zhang et al.
    2003's doubling interval); one step back for ``growth`` 2 or more and for SMRF's one-cell steps
    (``growth`` 1, Pingel et al. 2013).

    With a growth below 2 every step still measures the drop over a doubling of the window, so an
    object whose sides fall over several cells (a crown, a gable roof) drops by as much as between
    doubling windows, while a flat roof is tested at a radius within ``growth`` of its own
    half-width (doubling windows test it at up to twice that).

    Examples
    --------
    >>> drop_references([(1, 1, 1.0), (2, 2, 2.0), (3, 3, 3.0), (5, 5, 5.0), (8, 8, 8.0)], 2 ** 0.5)
    [-1, -1, 0, 1, 2]
    >>> drop_references([(1, 1, 1.0), (2, 2, 2.0), (4, 4, 4.0), (5, 5, 5.0)], 2.0)
    [-1, 0, 1, 2]
    """
    m = 1 if growth >= 2.0 or growth <= 1.0 else max(1, int(round(math.log(2.0) / math.log(growth))))
    return [k - m if k >= m else -1 for k in range(len(radii))]


def step_thresholds(radii, slope, wide_slope=None, wide_radius_m=math.inf):
    """The elevation threshold of each step of the progressive filter, metres: the most an opening
    of radius ``r_k`` may cut the terrain.

    SMRF's ``t_k = s r_k`` (Pingel et al. 2013), up to the radius ``wide_radius_m``; beyond it the
    threshold grows by ``wide_slope`` per metre: ``t_k = s R + s_w (r_k - R)``. The terrain slope ``s``
    is measured on a surface of block minima, which shows only terrain features wider than its blocks,
    and bounded below (:data:`_MIN_SLOPE`) for the narrower ones it cannot see (dikes, ramps, knolls
    steeper than the median); an opening cuts such a feature by at most its height, reached at the
    radius of half a block (``R``). A feature wider than a block shows in the block-minimum surface,
    so it rises, and an opening cuts it, by at most the rate that surface's slopes reach there
    (``s_w``, its 90th percentile). Where the floor made ``s`` steeper than the terrain measured
    (``s_w < s``), SMRF's threshold outgrew any cut of the terrain: a flat roof 10 m high and 80 m wide
    faced ``0.3 x 40`` m = 12 m and stayed ground on terrain of slope 0.04. ``wide_slope`` None: ``s``
    at every radius (SMRF's).

    Examples
    --------
    >>> step_thresholds([(1, 1, 1.0), (20, 20, 20.0), (40, 40, 40.0)], 0.3, 0.05, 20.0)
    [0.3, 6.0, 7.0]
    >>> step_thresholds([(1, 1, 1.0), (40, 40, 40.0)], 0.3)
    [0.3, 12.0]
    """
    s_w = slope if wide_slope is None else wide_slope
    return [round(slope * min(r, wide_radius_m) + s_w * max(0.0, r - wide_radius_m), 6) for _, _, r in radii]


def noise_allowance(noise_m):
    """The least elevation threshold of every step of the progressive filter, metres: the drop of a cell
    under the first openings that the noise of level ground alone may show (Zhang et al. 2003's initial
    threshold ``dh_0``, which covers the measurement error; SMRF has none).

    SMRF's threshold ``s r_k`` (Pingel et al. 2013) starts at ``s`` times one cell: 0.075-0.15 m at
    0.25-0.5 m cells, at or below the noise of the surface. The first steps measure the drop from the
    surface itself, and an opening drops a cell of noisy level ground by its own deviation plus the
    opening's depth below the noise's mean: on white noise of deviation ``sigma`` those drops exceed
    ``sigma`` at a third to a half of the cells, 3 ``sigma`` at 1-2 %, 4.1 / 4.6 ``sigma`` at 0.1 % (3 x 3 /
    5 x 5 windows, a million cells). The cells flagged left ``ZIpro`` for the opened surface, 1-3 ``sigma``
    below the noise's mean, and the final test took the higher ones for objects: bare terrain with 0.15 m
    of noise at 0.5-1 m cells lost 1.3-2.0 % of its ground. Each step's threshold is at least
    :data:`_NOISE_DROP` ``sigma`` (``t_k = max(s r_k, dh_0)``: the noise's drop does not grow with the
    window, unlike Zhang's additive ``dh_0 + s r_k``, which raised every step's threshold and lost low
    objects on the ISPRS samples: sample 31 at 1 m, 0.05 m of noise, Type II 6.3 -> 8.1 %). Where ``s``
    times one cell already exceeds it (lidar at 1 m cells and coarser) nothing changes. ``sigma`` is the
    sensor's noise (``noise_m``: the cleanest tiles' noise of the ground-level cells,
    :func:`~bare_earth.core.estimate.noise_ground_level`'s ``sigma_cleanest``), not the roughness of low
    vegetation on a highest-point DSM.

    Examples
    --------
    >>> noise_allowance(0.1)
    0.45
    >>> noise_allowance(0.0)
    0.0
    """
    return round(_NOISE_DROP * float(noise_m or 0.0), 6)


#: Cells a slope of the ground runs over at least, in the ground slope map (:func:`ground_slope_map`): its
#: opening's half-width. A step (a wall of a region wider than the largest window, a switch of the
#: erosion's minimum from one cell to another) spans one cell and its central difference two.
_SLOPE_RUN_CELLS = 2


def l1_slope(s, cell):
    """``|dz/dx| + |dz/dy|`` of a surface by central differences, 0 on the outer rows and columns and where
    a difference is not finite (float32): the most a square window's corner lies below its centre per
    metre of half-width on a plane of that gradient.

    Examples
    --------
    >>> i, j = np.mgrid[0:4, 0:4]
    >>> l1_slope((0.5 * j - 0.25 * i).astype(np.float32), (1.0, 1.0))[1:3, 1:3].tolist()
    [[0.75, 0.75], [0.75, 0.75]]
    """
    dx, dy = cell
    g = np.zeros(s.shape, np.float32)
    H, W = s.shape
    if H <= 2 or W <= 2:
        return g
    # in bands of rows whose temporaries stay in the cache: the same operations on every cell as on the whole
    # array, so the same values, without four raster-sized temporaries (0.24 s -> 0.1 s per 16 Mcells call)
    band = max(1, _BAND_BYTES // 4 // W)
    kind = np.result_type(s.dtype, s.dtype)      # the differences' type (float32 for a float32 surface)
    t1 = np.empty((min(band, H - 2), W - 2), kind)
    t2 = np.empty(t1.shape, kind)
    fx, fy = np.float32(0.5 / dx), np.float32(0.5 / dy)
    with np.errstate(invalid="ignore"):
        for i0 in range(1, H - 1, band):
            i1 = min(H - 1, i0 + band)
            gi, a, b = g[i0:i1, 1:-1], t1[:i1 - i0], t2[:i1 - i0]
            np.subtract(s[i0:i1, 2:], s[i0:i1, :-2], out=a)
            np.abs(a, out=gi)
            gi *= fx
            np.subtract(s[i0 + 1:i1 + 1, 1:-1], s[i0 - 1:i1 - 1, 1:-1], out=b)
            np.abs(b, out=b)
            b *= fy
            gi += b
            np.copyto(gi, np.float32(0.0), where=~np.isfinite(gi))
    return g


def edge_l1_slope(g, s, cell):
    """Give the outer rows and columns of an :func:`l1_slope` reading ``g`` (in place) the L1 slope of ``s`` from
    the cells the raster holds: one-sided differences across the edge, central ones along it (one-sided at the
    corners); 0 where a difference is not finite. Returns ``g``.

    At the raster's edge the opening's windows are clipped to the data: on a plane rising towards the edge the
    dilation reaches no cell uphill to lift the erosion back, so the opening sits ``|g_n| (r - e)`` below a
    cell ``e`` cells from the edge (``g_n`` the gradient across the edge) and ``(|g_x| + |g_y|) r`` below the
    highest corner, as it sits below a crest in the interior. The threshold's ``min(G_k, S) r_k``
    (:func:`_progressive`) covers a crest; with ``S`` 0 on the edge (central differences have no cell beyond
    it) the highest corner of a plane steeper than ``s`` was flagged.

    Examples
    --------
    >>> i, j = np.mgrid[0:4, 0:4]
    >>> s = (0.5 * j - 0.25 * i).astype(np.float32)
    >>> edge_l1_slope(l1_slope(s, (1.0, 1.0)), s, (1.0, 1.0)).tolist()[0]
    [0.75, 0.75, 0.75, 0.75]
    """
    H, W = s.shape
    if H < 2 or W < 2:
        return g
    dx, dy = cell
    with np.errstate(invalid="ignore"):
        for r, inner in ((0, 1), (H - 1, H - 2)):            # top and bottom rows: across them down the columns
            t = np.abs(np.gradient(s[r], dx)) + np.abs(s[r] - s[inner]) / dy
            g[r] = np.where(np.isfinite(t), t, 0.0)
        for c, inner in ((0, 1), (W - 1, W - 2)):            # left and right columns: across them along the rows
            t = np.abs(np.gradient(s[:, c], dy)) + np.abs(s[:, c] - s[:, inner]) / dx
            g[:, c] = np.where(np.isfinite(t), t, 0.0)
    return g


#: Float32 units of the last place (of a cell's height) that the slopes the threshold reads may be off by, per cell
#: of run: the L1 slope's two differences round each height by half a unit, and the drop it is compared with is a
#: difference of two rounded heights up to the window's half-width away (:func:`add_rounding`).
_ROUNDING_ULPS = 8


def add_rounding(slopes, z, cell):
    """Raise the slopes ``slopes`` (in place, float32, ``z``'s shape; each a reading the threshold ``min(G_k, S)
    r_k`` takes) by the rounding of the float32 heights they are read from: :data:`_ROUNDING_ULPS` units of the
    last place of each cell's height ``z`` per cell of run (0 at nodata). Returns nothing.

    A plane's drop at the raster's highest corner equals ``S r_k`` (:func:`edge_l1_slope`) exactly, so the
    heights' rounding decided whether the corner was flagged (a plane rising 0.2 each way at 2 m cells: a drop
    of 0.8000011 m against a threshold of 0.7999992 m). The raise is a few millimetres at most (0.1 mm per cell
    of run at 1000 m): ties go to the ground, nothing else moves.
    """
    H = z.shape[0]
    band = max(1, _BAND_BYTES // 4 // max(1, z.shape[1]))
    rate = np.float32(_ROUNDING_ULPS * np.finfo(np.float32).eps / min(cell))
    t = np.empty((min(band, H), z.shape[1]), np.float32)
    with np.errstate(invalid="ignore"):
        for i0 in range(0, H, band):
            i1 = min(H, i0 + band)
            b = t[:i1 - i0]
            np.abs(z[i0:i1], out=b)
            b *= rate
            np.copyto(b, np.float32(0.0), where=~np.isfinite(b))
            for s in slopes:
                s[i0:i1] += b


def ground_slope_map(a, r_max, cell, work=None, return_erosion=False):
    """The slope of the ground around each cell, read on the erosion by the largest window: SMRF's terrain
    slope ``s`` where the threshold ``s r_k`` is applied.

    SMRF's threshold ``t_k = s r_k`` passes terrain whose slope is at most ``s`` (Pingel et al. 2013; Zhang
    et al. 2003): an opening of radius ``r`` cuts a knoll or a ridge of slope ``g`` by up to about ``g r``.
    One ``s`` for the whole raster (the median slope of the 40 m block-minimum surface, at least 0.3) is below
    the slope of much of a rough steep relief, where the opening cuts every knoll and spur by more than
    ``s r_k``: the fBm mountain of ``benchmarks/bare.py`` (median slope 37 degrees, ``s`` measured 0.44)
    lost 12-17 % of its ground at 0.5-4 m cells, the forested mountain tile lidar hexbin-crop at 4 m 9.8 %.
    The erosion ``E`` by the largest window (the minimum over it, the first half of the last opening) holds
    no object the filter removes and keeps the slopes of the terrain's convex parts, the only parts an opening
    cuts (the minimum of a window sliding down a flank descends at the flank's slope; valleys become level
    floors, where an opening cuts nothing). A square window of half-width ``r`` reaches ``(|g_x| + |g_y|) r``
    below its centre on a plane of gradient ``(g_x, g_y)`` (a disk, SMRF's element, ``hypot(g_x, g_y) r``):
    the slope is the L1 norm of ``E``'s gradient (:func:`l1_slope`). A slope of the ground runs over several
    cells; the steps of ``E`` do not (the walls of a roof wider than the window, the switches of the minimum
    from one cell to another on noisy level ground): a grey opening of the slopes by
    :data:`_SLOPE_RUN_CELLS` cells removes them (on the simulated urban lidar, whose level streets the
    steps of ``E`` made read 0.1-0.3, the flags of roofs were lost: 0.02 -> 4.5 % total error at 1 m).
    At most :data:`_MAX_SLOPE`, the bound of ``s``.

    Parameters
    ----------
    a : ndarray, float32
        The surface the opening runs on, nodata +inf.
    r_max : (int, int)
        Half-widths (rows, columns) of the largest window, cells.
    cell : (dx, dy)
        Metres.
    work : _Work, optional
        Scratch buffers.
    return_erosion : bool
        Return the erosion ``E`` too (the progressive opening's last step takes it: :func:`_progressive`'s
        ``last_erosion``).

    Returns
    -------
    ndarray of float32
        The slope (rise/run), 0 where the erosion has no value (no valid cell in the window) or beside it.
    ndarray of float32
        With ``return_erosion``: ``E`` (+inf where no valid cell is in the window).

    Examples
    --------
    A plane rising 0.2 along the rows and 0.1 down the columns: 0.3 (a square's corner) inside, 0 on a
    step 3 m high, which runs over one cell:

    >>> i, j = np.mgrid[0:16, 0:16]
    >>> a = (0.2 * j + 0.1 * i).astype(np.float32)
    >>> round(float(ground_slope_map(a, (1, 1), (1.0, 1.0))[8, 8]), 4)
    0.3
    >>> step = np.where(j < 8, 0.0, 3.0).astype(np.float32)
    >>> float(ground_slope_map(step, (1, 1), (1.0, 1.0)).max())
    0.0
    """
    work = work or _Work()
    e = _erode(a, r_max[0], r_max[1], work)
    g = l1_slope(e, cell)
    if not return_erosion:
        del e
    g = _open_slopes(g, work)
    np.minimum(g, np.float32(_MAX_SLOPE), out=g)
    return (g, e) if return_erosion else g


def _open_slopes(g, work):
    """The grey opening of the slopes ``g`` (float32) by :data:`_SLOPE_RUN_CELLS` cells (a square window of that
    half-width, clipped at the raster's edge); ``work``'s third buffer is its scratch. Returns the opened slopes:
    ``g`` itself (in place) on a raster at least two cells wide both ways.

    The 5 x 5 window of :data:`_SLOPE_RUN_CELLS` 2 in one banded pass per operation (:func:`.geodesic.grey.filter5x5`,
    the cells beyond the edge neutral: the clipped window), else two :func:`_running_box` passes: a minimum and a
    maximum select one of the window's values, in any order, so the same values bit for bit (16 Mcells: two
    passes 0.058 -> 0.047 s CPU).
    """
    run = _SLOPE_RUN_CELLS
    if run == 2 and min(g.shape) >= 2 and g.flags.c_contiguous:
        t = work.get(2, g.shape)
        filter5x5(g, np.minimum, np.inf, out=t)
        return filter5x5(t, np.maximum, -np.inf, out=g)
    g = _running_box(g, run, run, np.minimum, work, g)
    return _running_box(g, run, run, np.maximum, work, g)


def _progressive(a, radii, slope, has_nodata, progress=None, work=None, growth=WINDOW_GROWTH, thresholds=None,
                 ground_slope=None, own_slope=None, last_erosion=None, allowance=0.0, cell=None, first_step=None,
                 spared_last=None, reference_slopes=True):
    """SMRF's progressive opening of ``a`` (+inf = nodata).

    Returns the boolean flags (a cell whose opened height dropped by more than
    ``slope * radius_m`` at some step, or ``thresholds[k]`` when given (:func:`step_thresholds`), the drop
    measured from the opening of the window that doubles into it: :func:`drop_references`) and the last
    opened surface. With ``ground_slope`` and ``own_slope`` (:func:`ground_slope_map`, :func:`l1_slope`) the
    threshold of step ``k`` at a cell is at least ``min(G_k, S) r_k``: ``G_k`` the steepest ground slope
    within the step's window (a running maximum grown by each step's increment, as the erosions are, in
    ``ground_slope``'s own buffer: it is overwritten), ``S`` the cell's own slope. ``last_erosion``: the erosion
    of ``a`` by the last window when the caller has it (:func:`ground_slope_map`), taken by the last step instead
    of eroding the step before's erosion further (the same values: square windows' minima compose exactly).
    With ``cell`` (metres) every step also passes the drops the slope of its own erosion allows where that slope
    continues along the terrain (:func:`_spare_continuing`; at the last step that erosion is ``last_erosion``).
    ``first_step`` (optional, int8, ``a``'s shape, -1 where no step has flagged the cell yet) receives the index of
    the first step that flagged each cell (diagnostics: ``filter_morphological(stages=)``). ``spared_last``
    (optional, bool, ``a``'s shape) receives the cells the last step's continuing slopes passed (its drop flagged
    them otherwise).
    """
    if thresholds is None:
        thresholds = [slope * r for _, _, r in radii]
    flags = np.zeros(a.shape, bool)
    # the drop test in bands of rows whose temporaries stay in the cache (no raster-sized ones)
    band = max(1, _BAND_BYTES // max(1, a.shape[1] * 4))
    diff = np.empty((min(band, a.shape[0]), a.shape[1]), np.float32)
    above = np.empty(diff.shape, bool)
    refs = drop_references(radii, growth)
    last_use = {j: k for k, j in enumerate(refs)}       # an opening is kept until its last reader
    opens = {-1: a}
    eroded = a
    pry = prx = 0
    n = len(radii)
    # the steps' erosions and openings rotate through a few raster buffers: a new raster-sized array
    # per step costs the kernel zeroing its pages on first touch (a third of the opening's CPU)
    pool = []

    def spare(*busy):
        for b in pool:
            if not any(b is x for x in busy):
                return b
        pool.append(np.empty(a.shape, a.dtype))
        return pool[-1]

    opened = a
    steep = own_step = ref_step = held = masked = None
    kept = {}                                  # G'_j of the steps a later step's drop is measured from
    slope_pool = []
    if ground_slope is not None:
        steep, gry, grx = ground_slope, 0, 0
        limit = np.empty(diff.shape, np.float32)
    for k, (ry, rx, _) in enumerate(radii):
        busy = tuple(opens.values()) + (eroded, opened)
        # Square windows compose: eroding the previous erosion by the increment gives the
        # erosion by the full window (cheaper than starting from the surface).
        if k == n - 1 and last_erosion is not None:
            eroded = last_erosion
        else:
            eroded = _erode(eroded, ry - pry, rx - prx, work, sub_progress(progress, k / n, (k + 0.5) / n),
                            out=spare(*busy))
        report(progress, (k + 0.5) / n)
        opened = _dilate(eroded, ry, rx, has_nodata, work, sub_progress(progress, (k + 0.5) / n, (k + 0.9) / n),
                         out=spare(eroded, *busy))
        report(progress, (k + 0.9) / n)
        ref = opens[refs[k]]
        t_k = np.float32(max(thresholds[k], allowance))       # SMRF: t_k = s * r_k * c, at least dh_0
        if steep is not None:                  # G_k: the steepest ground within the step's window
            steep = _running_box(steep, ry - gry, rx - grx, np.maximum, work, ground_slope)
            gry, grx = ry, rx
            r_k = np.float32(radii[k][2])
            own_step = None
            if cell is not None:               # G'_k in a few buffers for every step (no new pages per step)
                own_step = _step_slope(eroded, cell, work, _free_buffer(a.shape, slope_pool, kept.values()))
                if held is None and reference_slopes:
                    held = np.zeros(a.shape, bool)
                    masked = np.empty(a.shape, np.float32)
                ref_step = reference_slope(kept.get(refs[k]), held, masked) if reference_slopes else None
                ref_top = (ry, rx)             # the reference's top, read at the cells that need it
        with np.errstate(invalid="ignore"):
            for i0 in range(0, a.shape[0], band):
                i1 = min(a.shape[0], i0 + band)
                d, up = diff[:i1 - i0], above[:i1 - i0]
                np.subtract(ref[i0:i1], opened[i0:i1], out=d)
                if steep is None:
                    np.greater(d, t_k, out=up)
                else:                          # t_k(x) = max(t_k, min(G_k(x), S(x)) r_k)
                    t = limit[:i1 - i0]
                    np.minimum(steep[i0:i1], own_slope[i0:i1], out=t)
                    t *= r_k
                    np.maximum(t, t_k, out=t)
                    np.greater(d, t, out=up)
                    if own_step is not None:
                        last = spared_last is not None and k == n - 1
                        if last:
                            np.copyto(spared_last[i0:i1], up)
                        _spare_continuing(up, d, own_step, i0, r_k, radii[-1][:2], ref, ref_top)
                        if held is not None:
                            held[i0:i1] |= up
                        if ref_step is not None:
                            _spare_continuing(up, d, ref_step, i0, r_k, radii[-1][:2], ref, ref_top)
                        if last:
                            spared_last[i0:i1] &= ~up
                if first_step is not None:
                    fs = first_step[i0:i1]
                    np.copyto(fs, np.int8(k), where=up & (fs < 0))
                flags[i0:i1] |= up
        opens = {j: o for j, o in opens.items() if last_use.get(j, -1) > k}
        if last_use.get(k, -1) > k:
            opens[k] = opened
        if own_step is not None and reference_slopes:
            kept = {j: g for j, g in kept.items() if last_use.get(j, -1) > k}
            if last_use.get(k, -1) > k:
                kept[k] = own_step
        pry, prx = ry, rx
        report(progress, (k + 1) / n)
    return flags, opened


def _free_buffer(shape, pool, busy):
    """A float32 buffer of ``shape`` from ``pool`` that is none of ``busy`` (a new one appended when all are)."""
    for b in pool:
        if not any(b is x for x in busy):
            return b
    pool.append(np.empty(shape, np.float32))
    return pool[-1]


def reference_slope(g, held, out):
    """The reference step's ground slope ``G'_j`` (``g``, :func:`_step_slope` of the erosion the step's drop is
    measured from; None: no such step) where the cells are still terrain: 0 at the cells ``held`` (bool: the
    drops flagged at the earlier steps, past their own continuing slopes), into ``out``. Returns ``out``, or None
    without ``g``.

    The slope that passes a drop must be the terrain's: an embankment's flanks run along it through cells no step
    flagged, while the slopes a rough canopy or a roof's walls leave in a small window's erosion lie on cells the
    smaller windows already flagged (objects). ``held`` leaves out the cells this reading passed at the earlier
    steps, so the reach stays bounded (one line of the largest window more, :func:`morphological_halo`).

    Examples
    --------
    >>> g = np.full((2, 3), 0.5, np.float32)
    >>> reference_slope(g, np.array([[True, False, False], [False, False, True]]), np.empty_like(g)).tolist()
    [[0.0, 0.5, 0.5], [0.5, 0.5, 0.0]]
    >>> reference_slope(None, np.zeros((2, 3), bool), np.empty((2, 3), np.float32)) is None
    True
    """
    if g is None:
        return None
    np.copyto(out, g)
    out[held] = 0.0
    return out


def _steepest_sides(s, cell, out=None):
    """``max(|dz| to the left, to the right) / dx + max(up, down) / dy``: :func:`l1_slope` by the steeper of the
    one-sided differences, which reads a ridge's flanks on its crest line (central differences read 0 there).

    ``out`` (optional, float32, ``s``'s shape, not ``s``) receives the result. Computed in bands of rows whose
    temporaries stay in the cache (the same float32 operations in the same order on every cell as on the whole
    array, so the same values; no raster-sized temporaries: 0.44 s -> 0.14 s per 16 Mcells call). A cell's
    difference to the right is its right neighbour's to the left (``s[j + 1] - s[j]`` either way), and the one
    below the one above of the row below: each is formed once per band (the same operands in the same order).
    """
    dx, dy = cell
    g = np.empty(s.shape, np.float32) if out is None else out
    if s.shape[0] < 3 or s.shape[1] < 3:
        g[...] = 0.0
        return g
    g[0] = 0.0
    g[-1] = 0.0
    g[:, 0] = 0.0
    g[:, -1] = 0.0
    rx, ry = np.float32(dx), np.float32(dy)
    H, W = s.shape
    band = max(1, _BAND_BYTES // 4 // max(1, W))
    n0 = min(band, H - 2)
    hd = np.empty((n0, W - 1), np.float32)          # |s[j + 1] - s[j]| along the band's rows
    vd = np.empty((n0 + 1, W - 2), np.float32)      # |s[i + 1] - s[i]| down the inner columns, one row more
    t1 = np.empty((n0, W - 2), np.float32)
    with np.errstate(invalid="ignore"):
        for i0 in range(1, H - 1, band):
            i1 = min(H - 1, i0 + band)
            n = i1 - i0
            h, v, a, gi = hd[:n], vd[:n + 1], t1[:n], g[i0:i1, 1:-1]
            np.subtract(s[i0:i1, 1:], s[i0:i1, :-1], out=h)
            np.abs(h, out=h)
            np.fmax(h[:, :-1], h[:, 1:], out=a)     # |c - left|, |right - c|
            np.divide(a, rx, out=gi)                   # gx / dx
            np.subtract(s[i0:i1 + 1, 1:-1], s[i0 - 1:i1, 1:-1], out=v)
            np.abs(v, out=v)
            np.fmax(v[:-1], v[1:], out=a)               # |c - up|, |down - c|
            np.divide(a, ry, out=a)                    # gy / dy
            np.add(gi, a, out=gi)
            np.copyto(gi, np.float32(0.0), where=~np.isfinite(gi))
    return g


def _step_slope(e, cell, work, out=None):
    """The slope of a step's erosion ``e`` (:func:`ground_slope_map`'s reading: the L1 slope opened by
    :data:`_SLOPE_RUN_CELLS` cells, at most :data:`_MAX_SLOPE`). ``out`` (optional, not ``e``) receives it."""
    g = _open_slopes(_steepest_sides(e, cell, out), work or _Work())
    np.minimum(g, np.float32(_MAX_SLOPE), out=g)
    return g


def _spare_continuing(up, d, own_step, i0, r_k, r_max, ref, ref_top):
    """Unflag, in the band of rows of ``up`` starting at row ``i0``, the cells whose drop ``d`` the step's own
    ground slope passes where that slope continues along the terrain: ``d <= G'_k r_k`` on at least
    :data:`_CONTINUING_SHARE` of some straight line as long as the largest window (``estimate.line_share``).

    ``G'_k`` (``own_step``, :func:`_step_slope`) is read on the erosion by the step's own window. The erosion by
    the largest window (:func:`ground_slope_map`) holds no feature narrower than that window: the flanks of an
    embankment, a dike or a ridge crossing the raster read as level there, and SMRF's threshold ``s r_k`` (one
    slope for the raster, Pingel et al. 2013) cuts their flat crests, which are terrain. A step's own erosion
    keeps such a feature when it is wider than the step's window, and its slope there is the flank's. It keeps
    a crown (or a domed roof) wider than the step's window too, which stands above the ground on every side: its
    slope covers no line longer than the crown is wide, while a flank continues along the feature's length
    (Sithole and Vosselman 2004: terrain is continuous; objects are bounded). The line is as long as the
    largest window (``2 r_max + 1`` cells), the widest object the filter removes; half of it (a line crossing
    a crest's ridge, where the erosion's slope turns, or a tree on the flank) must hold the slope. An opening
    cuts terrain only where it is convex, at the top across the feature; a shrub or a crown on a long slope,
    lower than the slope's rise over the step's window, lies below the ground uphill: a cell is passed only
    where the reference opening ``ref`` (the surface the drop is measured from) rises above it by no more
    than the drop ``d`` within the step's window (``ref_top``, the running maximum of ``ref`` over that window;
    ISPRS samp51, vegetation on an escarpment, at 1 m: 112 cells passed without this test, 18 with it).
    ``ref_top`` is that maximum as a raster, or the window's half-widths ``(ry, rx)``: then it is read at the
    cells the test needs only (:func:`_window_top`; 0.04-0.5 % of the cells, not a running box over the raster
    per step).
    """
    with np.errstate(invalid="ignore"):
        cand = up & (d <= own_step[i0:i0 + up.shape[0]] * r_k)
    if not cand.any():
        return
    loc = np.flatnonzero(cand)
    cells = loc + i0 * up.shape[1]
    drop = d.ravel()[loc]
    # the top across first (nothing within the step's window rises above it; most candidates fail it), then the
    # slope along a line as long as the largest window on the cells left
    with np.errstate(invalid="ignore"):
        high = _window_top(ref, cells, *ref_top) if isinstance(ref_top, tuple) else ref_top.ravel()[cells]
        top = high <= ref.ravel()[cells] + drop
    loc, cells, drop = loc[top], cells[top], drop[top]
    if loc.size:
        keep = line_share(own_step, cells, r_max, drop / r_k) >= _CONTINUING_SHARE
        up.ravel()[loc[keep]] = False


def _window_top(a, cells, ry, rx, chunk=1 << 21):
    """The highest value of ``a`` (NaN left out: ``-inf`` where the window has none) within the (2ry+1) x (2rx+1)
    window of each of the flat indices ``cells``, clipped at the raster's edge: :func:`_running_box`'s
    ``np.maximum`` of ``a`` with NaN as ``-inf``, read at those cells only (a maximum is exact in any order)."""
    H, W = a.shape
    i, j = np.divmod(np.asarray(cells, np.int64), W)
    di = np.arange(-ry, ry + 1)
    dj = np.arange(-rx, rx + 1)
    out = np.empty(i.size, np.float32)
    step = max(1, chunk // (di.size * dj.size))
    for c0 in range(0, i.size, step):
        r = np.clip(i[c0:c0 + step, None] + di, 0, H - 1)
        q = np.clip(j[c0:c0 + step, None] + dj, 0, W - 1)
        v = a[r[:, :, None], q[:, None, :]]
        v[~np.isfinite(v)] = -np.inf
        out[c0:c0 + step] = v.max(axis=(1, 2))
    return out


#: Share of a line as long as the largest window on which a step's ground slope must hold (:func:`_spare_continuing`).
_CONTINUING_SHARE = 0.5


def _running_box(g, ry, rx, op, work, out):
    """``op`` (np.minimum / np.maximum) of ``g`` over a (2ry+1) x (2rx+1) window into ``out`` (not one of the
    scratch buffers of ``work``; ``g`` may be ``out``): the pass down the columns into ``work``'s third buffer,
    the pass along the rows in bands (:func:`_running_banded`). The same values as two :func:`_running` passes
    (a minimum or a maximum is exact in any order) without a new raster-sized array per pass (the kernel zeroes
    a new array's pages on first touch). Returns the result: ``out`` (``g`` itself for a window of one cell, a
    new array for a window longer than the raster).

    Examples
    --------
    >>> g = np.zeros((5, 7), np.float32)
    >>> g[2, 3] = 1.0
    >>> out = np.empty_like(g)
    >>> _running_box(g, 1, 2, np.maximum, _Work(), out).astype(int).tolist()[0:2]
    [[0, 0, 0, 0, 0, 0, 0], [0, 1, 1, 1, 1, 1, 0]]
    """
    if ry <= 0 and rx <= 0:
        return g
    work = work or _Work()
    down = g
    if ry > 0:
        down = _running(g, ry, 0, op, work, work.get(2, g.shape))
    elif g is out:                             # the pass along the rows reads a copy of its input
        down = work.get(2, g.shape)
        np.copyto(down, g)
    if rx <= 0:
        np.copyto(out, down)
        return out
    return _running_banded(down, rx, 1, op, work, out=out)


def _surface_slope(s, cell, rows=None):
    """Slope (rise/run) of a surface by central differences (``np.gradient``: one-sided at the
    edges); NaN -> 0. ``rows`` (a slice of whole rows, default all) limits the result to those
    rows: the same values as the whole array's, read from them and the row beside each end."""
    dx, dy = cell
    H, W = s.shape
    r0, r1, _ = (rows or slice(0, H)).indices(H)
    if min(s.shape) < 2 or r1 <= r0:
        return np.zeros((max(0, r1 - r0), W), np.float32)
    if not np.issubdtype(s.dtype, np.floating):
        s = s.astype(np.float64)
    gx = np.empty((r1 - r0, W), s.dtype)
    gy = np.empty((r1 - r0, W), s.dtype)
    f = s[r0:r1]
    gx[:, 1:-1] = (f[:, 2:] - f[:, :-2]) / (2. * dx)
    gx[:, 0] = (f[:, 1] - f[:, 0]) / dx
    gx[:, -1] = (f[:, -1] - f[:, -2]) / dx
    i0, i1 = max(r0, 1), min(r1, H - 1)            # rows with a row on both sides
    if i0 < i1:
        gy[i0 - r0:i1 - r0] = (s[i0 + 1:i1 + 1] - s[i0 - 1:i1 - 1]) / (2. * dy)
    if r0 == 0:
        gy[0] = (s[1] - s[0]) / dy
    if r1 == H:
        gy[-1] = (s[H - 1] - s[H - 2]) / dy
    g = np.hypot(gx, gy, out=gx)
    g[~np.isfinite(g)] = 0.0
    return g.astype(np.float32, copy=False)


def _complete(z, cell, p):
    """The filter's parameters ``p`` complete (derived from the data where None or where
    the mode is "auto") and checked against :data:`PARAMS` and the cell size."""
    if any(p[k] is None for k in ("max_object_size_m", "dh_m", "slope", "outline_slope", "wide_slope",
                                  "wide_radius_m", "noise_m")) or p["mode"] == "auto":
        p = resolve_morphological_params(z, cell, **p)
    if p["mode"] not in ("progressive", "single"):
        raise ValueError(f"mode must be one of {MODES}; got {p['mode']!r}.")
    for name in _NUMBERS:
        if p[name] is None:
            raise ValueError(f"{name} is None: give a number or leave it to resolve_morphological_params.")
    check_values("morphological", PARAMS, p)      # a window under 3 cells is 3 cells (_half_widths)
    return p


def open_single(z, cell, size_m, dh, work, progress=None):
    """The single-window form (1996): one opening of the pit-closed surface, then the
    two-sided test ``|z - O| > dh``.

    Returns the mask (1 above, 2 below, 0 ground), the opened surface ``O`` (NaN at
    nodata) and the window for the log. The cells below ``O`` are then confirmed as in the
    progressive form (:func:`confirm_low_cells`, in :func:`filter_morphological`).
    """
    ry, rx = _half_widths(size_m, cell)
    report(progress, 0.05)
    base = _close3(z, work)                # pits 1-2 cells wide must not spread
    report(progress, 0.3)
    a, has_nodata = _as_inf(base)
    eroded = _erode(a, ry, rx, work, sub_progress(progress, 0.3, 0.6))
    report(progress, 0.6)
    opened = _dilate(eroded, ry, rx, has_nodata, work, sub_progress(progress, 0.6, 0.9))
    report(progress, 0.9)
    with np.errstate(invalid="ignore"):
        d = z - opened
        mask = np.where(d > dh, OBJECT, np.where(d < -dh, LOW, GROUND)).astype(np.uint8)
    opened[~np.isfinite(z)] = np.nan
    return mask, opened, {"window_sizes_m": [round((2 * rx + 1) * cell[0], 3)],
                          "window_cells": [(2 * ry + 1, 2 * rx + 1)]}


def _padded_negative(z, nodata, py, px):
    """``-z`` as float32 with +inf at ``nodata`` (:func:`_as_inf` with ``sign`` -1) padded by ``py`` rows and ``px``
    columns of +inf on each side: ``np.pad(_as_inf(z, -1.0, nodata)[0], ((py, py), (px, px)),
    constant_values=np.inf)``, written into the padded array itself (no raster-sized copy to pad: 0.15 s per
    16 Mcells).

    Examples
    --------
    >>> z = np.array([[1.0, np.nan]], np.float32)
    >>> _padded_negative(z, np.isnan(z), 1, 1).tolist()
    [[inf, inf, inf, inf], [inf, -1.0, inf, inf], [inf, inf, inf, inf]]
    """
    H, W = z.shape
    neg = np.empty((H + 2 * py, W + 2 * px), np.float32)
    neg[:py] = np.inf
    neg[py + H:] = np.inf
    neg[py:py + H, :px] = np.inf
    neg[py:py + H, px + W:] = np.inf
    inner = neg[py:py + H, px:px + W]
    np.negative(z, dtype=np.float32, out=inner)
    if nodata.any():
        inner[nodata] = np.inf
    return neg


def find_low_outliers(z, nodata, cell, growth, low_slope, work, progress=None, level_m=0.0):
    """SMRF's low-outlier pre-step: the progressive filter on ``-z`` (1 m window, slope
    ``low_slope``). Returns the candidate pits and the surface with them replaced by the
    closing.

    On cells coarser than the 1 m window the pre-step's one window is one cell, and its threshold
    ``s c`` grows with the cell (10 m at 2 m cells, 20 m at 4 m). That keeps the gaps between tree
    crowns (single cells metres below the crowns) out of the candidates: capped at ``s x 1 m`` at
    every cell size, they became candidates, the opening lost the ground they show and the canopy
    stayed ground (closed canopy at 4 m: 0.09 -> 35.6 % total error; forest at 4 m 1.0 -> 20.7 %).
    But it keeps blunders in the opening too, where they spread over the ground around them. There a
    pit deeper than the paper's threshold over its 1 m window (``s x 1 m``, 5 m) is a candidate when
    it also lies that far below every cell of the ring around it
    (:func:`~bare_earth.core.estimate.below_surroundings`: a gap between crowns is at the level of the
    other gaps around it, a blunder below all the ground): simulated urban lidar at 4 m 2.27 -> 0.06 %;
    or when it lies that far below its neighbours that are no such pits themselves and are level within
    ``level_m`` (:func:`~bare_earth.core.estimate.below_level_neighbours`: a blunder in a paved or
    roofed level surface, however many lie around it; a gap between crowns is rimmed by their sides,
    metres apart). A line of blunders 9.5 m deep on a terrace beside a building (ISPRS sample 41,
    lowest point per 2 m cell; candidates at 1 m, where the threshold is 5 m) hid each other from the
    ring, stayed in the opening, spread over the terrace and took it for an object: 9.85 % total error
    at 2 m against 2.99 % at 1 m, 4.52 % with the level neighbours.
    """
    radii = _low_radii(cell, growth)
    # beyond the raster's edge is nodata, as in a gap inside it: windows hang over the edge. Cut at
    # it, every window of a cell next to the edge held the object beside it, which the opening of
    # -z then spread over that cell (one 8 m spike filled a 3 x 3 raster's closing: 8 low cells).
    # No window reaches past a corner (-inf there: no placement), so a corner cell is still judged
    # against the cells beside it along the edge, not against itself alone
    py, px = radii[-1][0], radii[-1][1]
    neg = _padded_negative(z, nodata, py, px)
    report(progress, 0.05)
    if py and px:
        for rows in (slice(0, py), slice(-py, None)):
            neg[rows, :px] = neg[rows, -px:] = -np.inf
    low, neg_open = _progressive(neg, radii, low_slope, True, progress, work, growth)
    del neg
    low, neg_open = low[py:py + z.shape[0], px:px + z.shape[1]], neg_open[py:py + z.shape[0], px:px + z.shape[1]]
    low &= ~nodata
    depth = np.float32(low_slope * LOW_OUTLIER_WINDOW_M)
    if low_slope > 0 and radii[-1][2] > LOW_OUTLIER_WINDOW_M + 1e-9:     # its last threshold above s x 1 m
        with np.errstate(invalid="ignore"):
            deep = ~low & (np.negative(neg_open) - z > depth)     # closing - z: depth below the neighbours
        if deep.any():
            pit = below_surroundings(z, cell, float(depth), candidates=deep)
            pit |= below_level_neighbours(z, float(depth), level_m, deep)
            low |= pit
    clean = z.copy()
    clean[low] = -neg_open[low]             # pits replaced by the closing
    return low, clean


def classify_provisional(z, zpro, cell, dh, es, progress=None):
    """SMRF's final test: ground when ``|z - ZIpro| <= e_t + e_s * slope(ZIpro)``, object
    above, low outlier below (a pit of the pre-step is class 2 only when it lies below the
    ground reconstructed around it: a gap between tree crowns does not)."""
    mask = np.zeros(z.shape, np.uint8)
    with np.errstate(invalid="ignore"):
        for b, thr in _tolerance_bands(zpro, cell, es, dh):
            d = np.subtract(z[b], zpro[b])
            m = mask[b]
            m[d > thr] = OBJECT
            np.negative(thr, out=thr)
            m[d < thr] = LOW
            report(progress, b.stop / zpro.shape[0])
    return mask


def confirm_low_cells(z, low, zpro, cell, dh, depth, level_m):
    """The final test's low cells that are low outliers: the rest of ``low`` is ground.

    SMRF's final test makes a cell lying below ``ZIpro`` by more than its tolerance class 2. Under a
    closed canopy the largest window finds no ground, ``ZIpro`` is the opened canopy, and the gaps
    between the crowns, the only ground seen there, lie metres below it. What tells a blunder from
    such a gap is what lies around it, as in the pre-step on coarse cells (:func:`find_low_outliers`):
    a low cell stays class 2 when it lies

    * more than ``depth`` below ``ZIpro``: the pre-step's own depth (SMRF's slope of 500 % over its
      1 m window), deeper than any gap the largest window's ground leaves open; or
    * more than ``dh`` below every cell of the ring around it
      (:func:`~bare_earth.core.estimate.below_surroundings`: a blunder lies below all the ground
      within 10 m, a gap between crowns at the level of the other gaps); or
    * more than ``dh`` below its level neighbours
      (:func:`~bare_earth.core.estimate.below_level_neighbours`, level within ``level_m``: a line of
      blunders in a paved surface, which hides its members from the ring).

    Parameters
    ----------
    z : ndarray, float32
        The DSM (NaN = nodata).
    low : ndarray of bool
        The cells the final test put below ``ZIpro``.
    zpro : ndarray, float32
        SMRF's provisional surface.
    cell : (dx, dy)
        Metres.
    dh, depth, level_m : float
        SMRF's ``e_t``, the pre-step's depth and the level of the neighbours, metres.

    Returns
    -------
    ndarray of bool
        The cells of ``low`` that stay low outliers.

    Examples
    --------
    Ground at 0 under crowns 10-12 m high, opened at 10 m: a gap at 0 beside another gap is ground,
    a blunder 2 m below the gaps is not; deeper than ``depth`` below ZIpro, every one is a blunder:

    >>> i, j = np.mgrid[0:25, 0:25]
    >>> z = (10.0 + 2.0 * ((i + j) % 2)).astype(np.float32); zpro = np.full_like(z, 10.0)
    >>> z[12, 4] = z[12, 12] = 0.0; z[4, 20] = -2.0
    >>> low = z < 5.0
    >>> np.argwhere(confirm_low_cells(z, low, zpro, (1.0, 1.0), 0.5, 12.0, 1.0)).tolist()
    [[4, 20]]
    >>> int(confirm_low_cells(z, low, zpro, (1.0, 1.0), 0.5, 5.0, 1.0).sum())
    3
    """
    if not low.any():
        return low
    with np.errstate(invalid="ignore"):
        keep = low & (z < zpro - np.float32(depth))
    rest = low & ~keep
    if rest.any():
        keep |= below_surroundings(z, cell, float(dh), candidates=rest)
        keep |= below_level_neighbours(z, float(dh), level_m, low)      # every low cell left out of the neighbours
    return keep


def _tolerance_bands(surface, cell, es, dh):
    """The final test's tolerance ``e_t + e_s slope(surface)`` in bands of rows whose temporaries
    stay in the cache (no raster-sized ones): yields ``(rows, tolerance)``, the rows a slice."""
    rows = surface.shape[0]
    band = max(1, _BAND_BYTES // max(1, surface.shape[1] * 8))
    for r0 in range(0, rows, band):
        b = slice(r0, min(rows, r0 + band))
        thr = _surface_slope(surface, cell, b)
        thr *= np.float32(es)
        thr += np.float32(dh)
        yield b, thr


def find_outline_cells(clean, opened, flagged, cell, dh, slope=0.0, work=None, r_max=None):
    """Mixed cells on the outlines of the flagged objects: cells next to them that stand on
    the object's flank, not on the ground beside it.

    A cell of a DSM straddling an object's outline holds part roof or crown and part
    ground: in a top-surface DSM it stands between the two (a one-cell ramp around every
    roof and crown). SMRF's flags miss it: when the window outgrows the object it drops
    by only part of the object's height, below ``s r_k``, and as an unflagged cell it
    enters ``ZIpro`` at its own height and passes the final test as ground (on the 2 m
    opengeos DSM three quarters of the cells kept as ground more than 1 m above the
    reference DTM are such outline cells). SMRF works on points, whose final test reads
    ``ZIpro`` between cells; on a grid the outline is uncertain by one cell, which the
    paper leaves open.

    An unflagged cell touching a flagged cell (8-neighbourhood) is an outline cell when
    it stands more than ``dh`` plus the terrain's rise over one cell diagonal above the
    lowest unflagged cell next to it: ground beside an object has a neighbour at its own
    level, a cell on the object's flank stands above the ground around it. The rise is the
    diagonal times the larger of ``slope`` (the terrain's slope measured on the whole
    raster) and the slope of the opened surface there (central differences): the opened
    surface alone is flat where the largest window cuts a dike or a crest, whose ground
    beside trees must stay ground.

    Parameters
    ----------
    clean : ndarray, float32
        The surface the opening ran on (NaN = nodata).
    opened : ndarray, float32
        The last opened surface (the ground reconstructed under the objects).
    flagged : ndarray of bool
        Cells left out of ``ZIpro`` (objects, low outliers, nodata).
    cell : (dx, dy)
        Metres.
    dh : float
        SMRF's elevation threshold ``e_t``, metres.
    slope : float
        The terrain's slope (rise/run) the ground beside an object may show.
    work : _Work, optional
        Scratch buffers.
    r_max : (int, int), optional
        Half-widths of the largest window, cells: with it, a cell on a slope running through it along a feature
        at least that long is no outline cell (:func:`_flank_along`).

    Returns
    -------
    ndarray of bool
        The outline cells (never flagged ones).

    Examples
    --------
    >>> z = np.full((5, 5), 10.0, np.float32); z[2, 2] = 16.0; z[1, 2] = 13.0
    >>> flagged = z == 16.0
    >>> np.argwhere(find_outline_cells(z, np.full_like(z, 10.0), flagged, (1.0, 1.0), 0.5))
    array([[1, 2]])
    """
    near = touching(flagged)
    near &= ~flagged
    un = np.array(clean, np.float32)
    un[flagged] = np.inf
    lowest = _erode(un, 1, 1, work)                   # the lowest unflagged cell around
    with np.errstate(invalid="ignore"):
        np.subtract(clean, lowest, out=un)              # height above it
        near &= un > np.float32(dh)                     # rise >= 0: only these can pass
    idx = np.flatnonzero(near)
    if idx.size == 0:
        return near
    rows, cols = clean.shape
    i, j = np.divmod(idx, cols)
    dx, dy = cell
    o = opened.ravel()
    gx = (o[idx + (j < cols - 1)] - o[idx - (j > 0)]) / np.float32(2 * dx)
    gy = (o[idx + cols * (i < rows - 1)] - o[idx - cols * (i > 0)]) / np.float32(2 * dy)
    rise = np.maximum(np.hypot(gx, gy), np.float32(slope)) * np.float32(math.hypot(dx, dy)) + np.float32(dh)
    with np.errstate(invalid="ignore"):
        keep = un.ravel()[idx] > rise
    if keep.any():                                  # a slope the ground continues beyond its foot: no outline
        sel = idx[keep]
        ground = ~flagged & np.isfinite(clean)
        _, foot = _lowest_ground(clean, ground, sel)
        beyond = continuing_rise(clean, ground, foot, _MAX_SLOPE * math.hypot(dx, dy))
        with np.errstate(invalid="ignore"):
            out = un.ravel()[sel] > np.float32(dh) + beyond
        if r_max is not None and out.any():             # a flank of a few cells along a feature: no outline
            k = np.flatnonzero(out)
            out[k[_flank_along(clean, ground, sel[k], foot[k], un.ravel()[sel[k]], dh, cell, r_max)]] = False
        keep[keep] = out
    near.ravel()[idx[~keep]] = False
    return near


def _tier_box(r_max):
    """Rows and columns of the box a tier fits in: a square as wide as the largest window
    (``2 r + 1`` cells), in any orientation, fits in ``sqrt 2`` times that."""
    return tuple(int(math.ceil(math.sqrt(2.0) * (2 * r + 1))) for r in r_max)


#: Share of a raised region's edge on the ground that must be a wall for the region to be part of the
#: object it is attached to (:func:`find_attached_tiers`): most of it, so a region is a tier of the
#: object when walls, not terrain, bound it.
TIER_WALL_SHARE = 0.5


def _lowest_ground(clean, ground, cells):
    """The lowest ``ground`` cell of the 3 x 3 neighbourhood of each of ``cells`` (flat indices; cells beyond the
    raster ignored): its height (+inf where there is none) and its flat index (-1 where there is none)."""
    H, W = clean.shape
    rows, cols = np.divmod(cells, W)
    cf, gf = clean.ravel(), ground.ravel()
    lowest = np.full(cells.size, np.inf, np.float32)
    where = np.full(cells.size, -1, np.intp)
    inf = np.float32(np.inf)
    # the cells off the raster's border (nearly all): their 9 neighbours gathered at once by flat offsets,
    # the first lowest ground cell in the order of the loop below (argmin's first minimum)
    inner = np.flatnonzero((rows > 0) & (rows < H - 1) & (cols > 0) & (cols < W - 1))
    offs = (np.arange(-1, 2)[:, None] * W + np.arange(-1, 2)[None, :]).ravel()
    for i in range(0, inner.size, _LOWEST_CHUNK):
        k = inner[i:i + _LOWEST_CHUNK]
        q = cells[k][:, None] + offs
        v = cf[q]
        v[~gf[q] | ~(v < inf)] = inf                       # not ground, nodata: none
        j = np.argmin(v, axis=1)
        low = v[np.arange(k.size), j]
        lowest[k] = low
        where[k] = np.where(low < inf, q[np.arange(k.size), j], -1)
    if inner.size == cells.size:
        return lowest, where
    border = np.ones(cells.size, bool)
    border[inner] = False
    keep = (lowest, where)
    cells, rows, cols = cells[border], rows[border], cols[border]
    lowest = np.full(cells.size, np.inf, np.float32)
    where = np.full(cells.size, -1, np.intp)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            r, c = rows + dr, cols + dc
            q = np.clip(r, 0, H - 1) * W + np.clip(c, 0, W - 1)
            ok = (r >= 0) & (r < H) & (c >= 0) & (c < W) & gf[q]
            v = np.where(ok, cf[q], inf)
            lower = v < lowest
            lowest[lower] = v[lower]
            where[lower] = q[lower]
    keep[0][border], keep[1][border] = lowest, where
    return keep


#: Cells per chunk of :func:`_lowest_ground`'s gathered neighbourhoods (9 heights and indices each).
_LOWEST_CHUNK = 1 << 16


def _walls(clean, ground, edge, rise, dh=None, steepest=_MAX_SLOPE, cell=(1.0, 1.0)):
    """The cells of ``edge`` standing more than ``rise`` above the lowest ``ground`` cell of their 3 x 3
    neighbourhood (cells beyond the raster ignored): the 3 x 3 minimum read at the edge cells only (a
    few per cent of the raster), the values of a grey erosion of the ground's heights there.

    With ``dh`` given, a step the ground continues is no wall (:func:`continuing_rise`): the cell is a wall
    when it stands more than ``dh`` plus the ground's own descent beyond its foot above that foot, too."""
    cells = np.flatnonzero(edge)
    cf = clean.ravel()
    lowest, foot = _lowest_ground(clean, ground, cells)
    wall = np.zeros(edge.shape, bool)
    with np.errstate(invalid="ignore"):
        step = np.subtract(cf[cells], lowest)
        is_wall = step > rise
        if dh is not None and is_wall.any():
            sel = np.flatnonzero(is_wall)
            beyond = continuing_rise(clean, ground, foot[sel], steepest * math.hypot(*cell))
            is_wall[sel] = step[sel] > np.float32(dh) + beyond
    wall.ravel()[cells[is_wall]] = True
    return wall


def _flank_along(clean, ground, cells, feet, rise, dh, cell, r_max):
    """Which of ``cells`` (flat indices; their ``feet``, the lowest ``ground`` cell around, and their ``rise`` above
    it) lie on a slope running through them along a feature: the step down to the cell from the cell opposite its
    foot and the foot's own next step down both continue the cell's step (``rise <= dh +`` the smaller of the two,
    at most :data:`_MAX_SLOPE` over a cell diagonal), and such cells hold half of some straight line as long as the
    largest window (``2 r_max + 1`` cells, :func:`~bare_earth.core.estimate.line_share`).

    A dike's 1:2 flank at 4 m cells is three steps of 2 m (6, 4, 2, 0): beyond the foot of its middle cell lies
    one step and then level ground, as beyond a roof's mixed cell (6, 3, 0), so :func:`continuing_rise` reads a
    wall. The step from above tells them apart (2 m on the flank: the slope runs through the cell; 0 beyond the
    mixed cell's foot). Low crowns and shrubs of a top-surface DSM fall over several cells in even steps too
    (opengeos at 2 m: 0.6-1.2 m a cell), but their rims curve round them within their width, while a flank runs
    along its feature (Sithole and Vosselman 2004: terrain is continuous; objects are bounded).
    """
    cf = clean.ravel()
    has = feet >= 0
    base = np.where(has, feet, cells)
    z2, _ = _lowest_ground(clean, ground, base)
    with np.errstate(invalid="ignore"):
        run = np.minimum(_rise_above(clean, cells, feet), cf[base] - z2)
    run[~np.isfinite(run) | ~has] = 0.0
    np.minimum(run, np.float32(_MAX_SLOPE * math.hypot(*cell)), out=run)
    with np.errstate(invalid="ignore"):
        on = rise <= np.float32(dh) + run
    if not on.any():
        return on
    marks = np.zeros(clean.shape, np.float32)
    marks.ravel()[cells[on]] = 1.0
    on[on] = line_share(marks, cells[on], r_max, 0.5) >= _CONTINUING_SHARE
    return on


def _rise_above(clean, cells, feet):
    """How far the cell opposite each foot across each of ``cells`` (flat indices; the foot one of its 8
    neighbours, -1 for none) stands above the cell, metres (0 where it is lower, beyond the raster or nodata): the
    step down to the cell along the line the step to its foot continues."""
    H, W = clean.shape
    r, c = np.divmod(cells, W)
    fr, fc = np.divmod(np.where(feet >= 0, feet, cells), W)
    orow, ocol = 2 * r - fr, 2 * c - fc
    ok = (feet >= 0) & (orow >= 0) & (orow < H) & (ocol >= 0) & (ocol < W)
    cf = clean.ravel()
    with np.errstate(invalid="ignore"):
        up = cf[np.clip(orow, 0, H - 1) * W + np.clip(ocol, 0, W - 1)] - cf[cells]
    up[~ok | ~np.isfinite(up) | (up < 0)] = 0.0
    return up.astype(np.float32)


#: Cells beyond a wall's foot that :func:`continuing_rise` reads (two steps down).
_CONTINUE_CELLS = 2


def continuing_rise(clean, ground, feet, cap):
    """How far the ground keeps descending beyond each of ``feet``: the rise a wall test allows a cell above
    its foot besides ``dh``.

    A wall is a step across about one cell: the ground at its foot goes on level (or at the terrain's slope).
    The flank of a dike, an embankment or a mountain's crest is a slope continuing across several cells: the
    ground beyond its foot goes on descending about as much per cell. The wall tests of the progressive filter
    (Pingel et al. 2013 leave the outline of an object on a grid open) read the terrain's slope on 40 m block
    minima, which do not show such features narrower than a block; their flanks read as walls. Two steps, so
    that the mixed cells of a top-surface DSM's outline (one cell between a roof and the ground, at part of the
    roof's height, then level ground) do not read as a slope continuing.

    Parameters
    ----------
    clean : ndarray, float32
        The surface (NaN = nodata).
    ground : ndarray of bool
        The cells the steps may go down to.
    feet : ndarray of int
        Flat indices of the feet (ground cells; -1 for none).
    cap : float
        The most a step may count, metres (the steepest terrain slope over a cell diagonal).

    Returns
    -------
    ndarray of float32
        The smaller of the two next steps down from each foot to the lowest ground cell of the 3 x 3
        neighbourhood (``q1 -> q2 -> q3``), at most ``cap``; 0 where the ground stops descending or where
        there is no foot.

    Examples
    --------
    >>> ramp = np.tile(0.5 * np.arange(6, dtype=np.float32), (3, 1))
    >>> continuing_rise(ramp, np.ones(ramp.shape, bool), np.array([1 * 6 + 4, -1]), 10.0).tolist()
    [0.5, 0.0]
    """
    out = np.zeros(feet.size, np.float32)
    ok = feet >= 0
    if not ok.any():
        return out
    cf = clean.ravel()
    q1 = feet[ok]
    z2, q2 = _lowest_ground(clean, ground, q1)
    z3, q3 = _lowest_ground(clean, ground, np.where(q2 >= 0, q2, q1))
    with np.errstate(invalid="ignore"):
        d = np.minimum(cf[q1] - z2, z2 - z3)
    d[~np.isfinite(d) | (d < 0)] = 0.0
    out[ok] = np.minimum(d, np.float32(cap))
    return out


def find_attached_tiers(clean, opened, left_out, objects, cell, dh, es, slope, r_max, work=None, progress=None,
                        hidden=None):
    """Lower tiers of the objects: unflagged raised regions attached to an object and bounded by walls.

    A building's annex, a lower roof or the lower part of a crown stands on the object, not on
    the ground: when the window outgrows the object it drops by only its own height, which is
    below SMRF's ``s r_k`` for a wide object (a 2.5 m annex of a building 40 m across faces
    0.3 x 20 m = 6 m), so it is not flagged, and SMRF keeps it in ``ZIpro`` at its own height,
    where the final test calls it ground. The paper leaves such regions open; here they are
    told from terrain by what bounds them. A raised region is a connected set (8-neighbours) of
    unflagged cells standing above the last opened surface by more than the final test's
    tolerance ``dh + e_s slope(O)``; it is a tier when

    * it touches a flagged object (or an outline cell),
    * it fits in a box ``sqrt 2`` times the largest window along rows and columns
      (:func:`_tier_box`: a square as wide as the window, in any orientation; the opening
      removed it, so the region is no wider than the window, and the box bounds the reach), and
    * most (:data:`TIER_WALL_SHARE`) of its edge cells are walls: its cells next to the
      unflagged ground below it that stand more than ``dh`` plus the terrain's rise over one
      cell diagonal (``slope``, the outline slope) above the lowest ground cell around, the test
      of :func:`find_outline_cells`; its cells on the raster's border are edge cells, never walls
      (the outline beyond is unknown). Terrain the opening cut (a crest, a hill top with trees)
      descends to the ground around at the terrain's own slope, and stays ground. A region with no
      edge at all (no cell next to the ground, none on the border: objects and their outline cells
      enclose it, a lower roof between a building's wings) shows no such descent: it stands on the
      object and is a tier, unless it touches a ``hidden`` cell (a low outlier or nodata, whose
      height hides the ground there: a scan line of ground between a roof's lines of a
      highest-point DSM, whose neighbours the pre-step took for pits).

    Its cells leave ``ZIpro`` like the flagged ones and are classified against the ground
    under the object. The reach is bounded: a region outside the box is never a tier
    (:func:`morphological_halo` adds the box's width).

    Parameters
    ----------
    clean, opened : ndarray, float32
        The surface the opening ran on and the last opened surface (NaN = nodata).
    left_out : ndarray of bool
        Cells already left out of ``ZIpro`` (flags, low outliers, outline cells, nodata).
    objects : ndarray of bool
        The flagged objects and their outline cells.
    cell : (dx, dy)
        Metres.
    dh, es : float
        SMRF's ``e_t`` (metres) and ``e_s`` (metres per unit slope).
    slope : float
        The terrain's slope (rise/run) the ground may show over one cell (``outline_slope``).
    r_max : (int, int)
        Half-widths (rows, columns) of the largest window, cells.
    progress : callable, optional
        ``progress(fraction)`` between the steps; may raise ``Cancelled``.
    hidden : ndarray of bool, optional
        Cells whose height says nothing of the ground there (low outliers, nodata): a region
        touching one is not enclosed by the objects.

    Returns
    -------
    ndarray of bool
        The tier cells (never already left out).
    """
    raised = np.empty(clean.shape, bool)
    with np.errstate(invalid="ignore"):
        for b, thr in _tolerance_bands(opened, cell, es, dh):    # by rows: the same values
            np.greater(np.subtract(clean[b], opened[b]), thr, out=raised[b])
            raised[b] &= ~left_out[b]
    if not raised.any():
        return raised
    report(progress, 0.2)
    lab, n = label8(raised)
    report(progress, 0.5)
    ground = ~raised & ~left_out
    edge = raised & touching(ground)                  # the region's cells next to the ground
    rise = np.float32(dh + slope * math.hypot(*cell))
    wall = _walls(clean, ground, edge, rise, dh=dh, cell=cell)
    # at the raster's border the region's outline is unknown: its cells there count as edge, never wall
    rim = np.zeros(raised.shape, bool)
    rim[[0, -1], :] = True
    rim[:, [0, -1]] = True
    rim &= raised
    edge |= rim
    wall &= ~rim
    report(progress, 0.8)
    n_edge = np.bincount(lab[edge], minlength=n + 1)
    n_wall = np.bincount(lab[wall], minlength=n + 1)
    attached = np.bincount(lab[raised & touching(objects)], minlength=n + 1) > 0
    # no edge on the ground and none on the border: enclosed, by the objects alone when no low
    # outlier or nodata cell (which hide what lies there) touches it
    enclosed = n_edge == 0
    if hidden is not None and hidden.any():
        enclosed &= np.bincount(lab[raised & touching(hidden)], minlength=n + 1) == 0
    tier = attached & ((n_wall > TIER_WALL_SHARE * n_edge) | enclosed)
    tier[0] = False
    # the box, on the candidates' cells only (a few per cent of the raised cells)
    cand = tier[lab]
    if not cand.any():
        return cand
    span_r, span_c = _region_boxes(lab, n, cand)
    box_r, box_c = _tier_box(r_max)
    tier &= (span_r <= box_r) & (span_c <= box_c)
    return tier[lab]


def _region_boxes(lab, n, cells):
    """Rows and columns spanned by each label ``1..n`` of ``lab`` over the boolean ``cells`` (index 0 and
    labels without such cells span 0): ``(rows, cols)``, int arrays of ``n + 1``."""
    at = np.flatnonzero(cells)
    rows, cols = np.divmod(at, cells.shape[1])
    lab_c = lab.ravel()[at]
    big = max(lab.shape)
    lo_r, hi_r = np.full(n + 1, big, np.int64), np.full(n + 1, -1, np.int64)
    lo_c, hi_c = np.full(n + 1, big, np.int64), np.full(n + 1, -1, np.int64)
    np.minimum.at(lo_r, lab_c, rows)
    np.maximum.at(hi_r, lab_c, rows)
    np.minimum.at(lo_c, lab_c, cols)
    np.maximum.at(hi_c, lab_c, cols)
    return np.maximum(hi_r - lo_r + 1, 0), np.maximum(hi_c - lo_c + 1, 0)


def find_cut_terrain(clean, flagged, ground, cell, dh, slope, r_max):
    """Terrain the opening cut: flagged regions that stand on no wall anywhere along their edge.

    SMRF's threshold ``s r_k`` uses one terrain slope for the whole raster (the median slope, at least
    0.3); on terrain steeper than that in places (a knoll or a spur on a mountainside) the opening cuts
    the top by more than ``s r_k`` and the flags take it for an object. The paper leaves the slope to
    the user; what tells the cut top from an object is what bounds it: an object stands on walls (a
    building's, a crown's side), while terrain falls to the ground around it at the terrain's slope on
    every side. A connected region (8-neighbours) of flagged cells is terrain when

    * none of its edge cells (its cells next to ``ground``) is a wall: a cell standing more than
      ``dh`` plus the terrain's rise over one cell diagonal (``slope``, the outline slope) above the
      lowest ground cell around it, the test of :func:`find_outline_cells` and
      :func:`find_attached_tiers`;
    * it has a cell inside its edge: a region whose every cell touches the ground is an outline
      itself (a bush, a hedge, a car one or two cells wide), too thin to be judged by its walls;
    * it does not touch the raster's border (its outline beyond is unknown); and
    * it fits in the box of the attached tiers (:func:`_tier_box`: a square as wide as the largest
      window in any orientation), which bounds the reach (:func:`morphological_halo`); a wider cut
      stays flagged.

    Parameters
    ----------
    clean : ndarray, float32
        The surface the opening ran on (NaN = nodata).
    flagged : ndarray of bool
        The opening's flags (objects).
    ground : ndarray of bool
        The unflagged valid cells (not low outliers).
    cell : (dx, dy)
        Metres.
    dh : float
        SMRF's ``e_t``, metres.
    slope : float
        The terrain's slope (rise/run) the ground may show over one cell (``outline_slope``).
    r_max : (int, int)
        Half-widths (rows, columns) of the largest window, cells.

    Returns
    -------
    ndarray of bool
        The flagged cells that are terrain.

    Examples
    --------
    A mound 4 m high with 0.5 slopes that the flags took whole, and a 4 m block on walls:

    >>> i, j = np.mgrid[0:21, 0:41].astype(np.float32)
    >>> z = np.maximum(0.0, 4.0 - 0.5 * np.hypot(i - 10, j - 10)).astype(np.float32)
    >>> z[8:13, 28:33] = 4.0
    >>> flags = z > 1.0
    >>> cut = find_cut_terrain(z, flags, ~flags, (1.0, 1.0), 0.5, 0.5, (10, 10))
    >>> bool(cut[:, :20].sum() == flags[:, :20].sum()), bool(cut[:, 20:].any())
    (True, False)
    """
    none = np.zeros(flagged.shape, bool)
    lab, n = label8(flagged)
    if n == 0:
        return none
    edge = flagged & touching(ground)
    flat = lab.ravel()
    e_idx = np.flatnonzero(edge)
    e_lab = flat[e_idx]
    # the cheap tests first, on label tables: an edge, a cell inside it, not on the raster's border
    cut = np.bincount(e_lab, minlength=n + 1) > 0
    inside = np.zeros(n + 1, bool)
    inside[lab[flagged & ~edge]] = True
    cut &= inside
    cut[lab[[0, -1], :]] = False
    cut[lab[:, [0, -1]]] = False
    cut[0] = False
    if not cut.any():
        return none
    # then the walls, on the edge cells of the regions left (wall cells found anywhere keep a region)
    sel = cut[e_lab]
    edge_left = np.zeros(flagged.shape, bool)
    edge_left.ravel()[e_idx[sel]] = True
    wall = _walls(clean, ground, edge_left, np.float32(dh + slope * math.hypot(*cell)), dh=dh, cell=cell)
    cut[flat[np.flatnonzero(wall)]] = False
    cut[0] = False
    if not cut.any():
        return none
    span_r, span_c = _region_boxes(lab, n, cut[lab])
    box_r, box_c = _tier_box(r_max)
    cut &= (span_r <= box_r) & (span_c <= box_c)
    return cut[lab]


def find_cut_slopes(clean, flagged, ground, cell, dh, slope, r_max):
    """Terrain the opening cut along a feature longer than the window: flagged cells with no wall in their window.

    :func:`find_cut_terrain` judges whole regions, within the box of the largest window and off the raster's
    border, so a dike, an embankment or a crest running further than that stays flagged. Every object the
    opening flags is narrower than the largest window, so the window around any of its cells holds its outline
    across it, and most of an object's outline is walls. A flagged cell is terrain when the largest window
    around it (half-widths ``r_max``) holds an edge cell (flagged, next to the ground) that is no wall and a
    cell inside an edge (the region is no bush or hedge one or two cells wide, too thin to be judged by its
    walls: :func:`find_cut_terrain`'s rule), and no wall (:func:`_walls`, the test of the other wall rules: a
    step the ground does not continue beyond its foot) and no flagged cell on the raster's border (the outline
    beyond is unknown). The walls and the cell inside an edge are the cell's own region's: reached from it through
    the flagged cells within the window's half-width (:func:`_reached`), since the outline that tells an object
    is its own; another object's walls within the window (a house beside an embankment, a shrub on its flank) say
    nothing of it. A wall with no cell inside an edge beside it belongs to a region one or two cells wide, its own
    outline: it keeps its own cells and their neighbours flagged, and is no wall of the region it touches.
    (Before, any wall in the window kept the cell flagged: on the synthetic mixed scene at 1 m, an embankment
    among houses lost 1918 cells, 1.67 % -> 0.88 %.) The reach is the window and the walls' three cells, so
    blocks equal one pass.

    Parameters
    ----------
    clean : ndarray, float32
        The surface the opening ran on (NaN = nodata).
    flagged, ground : ndarray of bool
        The opening's flags and the unflagged valid cells (not low outliers).
    cell : (dx, dy)
        Metres.
    dh : float
        SMRF's ``e_t``, metres.
    slope : float
        The terrain's slope (rise/run) over one cell (``outline_slope``).
    r_max : (int, int)
        Half-widths (rows, columns) of the largest window, cells.

    Returns
    -------
    ndarray of bool
        The flagged cells that are terrain.

    Examples
    --------
    A ridge 3 m high with 0.5 slopes along the columns, flagged, and a 4 m block on walls beside it:

    >>> i, j = np.mgrid[0:40, 0:30].astype(np.float32)
    >>> z = np.maximum(0.0, 3.0 - 0.5 * np.abs(j - 8)).astype(np.float32)
    >>> z[15:20, 22:27] = 4.0
    >>> flags = z > 1.0
    >>> cut = find_cut_slopes(z, flags, ~flags, (1.0, 1.0), 0.5, 0.0, (3, 3))
    >>> int(cut[:, :15].sum()), int(flags[4:36, :15].sum()), bool(cut[:, 15:].any())
    (224, 224, False)
    """
    none = np.zeros(flagged.shape, bool)
    edge = flagged & touching(ground)
    if not edge.any():
        return none
    wall = _walls(clean, ground, edge, np.float32(dh + slope * math.hypot(*cell)), dh=dh, cell=cell)
    #    an object's walls hold a cell inside them; a region one or two cells wide (a shrub, a car on the flank)
    #    is its own outline: its walls keep its own cells flagged, not the window around them
    inside = flagged & ~edge
    thin_wall = wall & ~touching(inside)
    wall &= ~thin_wall
    wall[[0, -1], :] |= flagged[[0, -1], :]
    wall[:, [0, -1]] |= flagged[:, [0, -1]]
    def near(cells):
        # the box dilation (common.dilate_box: the same cells as SciPy's running maxima of uint8, a third of the time)
        return dilate_box(cells, int(r_max[0]), int(r_max[1]))

    free = flagged & ~touching(thin_wall)
    if free.any():
        free &= near(edge & ~wall & ~thin_wall)
    if free.any():
        #    a cell inside an edge and no wall among the cells of its own region within the window's reach (a path
        #    of at most that many steps to a cell left lies in the box that far around the cells left: read there)
        steps = int(max(r_max))
        rr, cc = np.nonzero(free)
        box = (slice(max(0, rr.min() - steps - 1), rr.max() + steps + 2),
               slice(max(0, cc.min() - steps - 1), cc.max() + steps + 2))
        part = free[box]
        part &= _reached(inside[box], flagged[box], steps)
        if part.any():
            part &= ~_reached(wall[box] & flagged[box], flagged[box], steps)
    return free


def _reached(seeds, within, steps):
    """The cells of ``within`` joined to a cell of ``seeds`` by a path of at most ``steps`` 8-neighbour steps
    through ``within`` (a geodesic dilation: bounded reach, so blocks equal one pass).

    The first step is one 3 x 3 dilation of the array; the others grow the front alone (the cells the last step
    added, as flat indices into a copy of ``within`` with a border of one cell, each cell taken once): the work
    of a step is its front's, not the array's, and no longer grows with the window's half-width. The same cells as
    ``steps`` dilations of the array; CPU of the synthetic city (4 Mcells at 0.5 m cells) 0.16 -> 0.04 s here,
    find_cut_slopes 0.25 -> 0.13 s; on flagged hills over 2000 x 2000 cells, windows of 61 / 241 cells,
    find_cut_slopes 0.16 / 0.35 -> 0.06 / 0.10 s.

    Examples
    --------
    >>> within = np.array([[1, 1, 1, 0, 1, 1]], bool)
    >>> _reached(np.array([[1, 0, 0, 0, 0, 0]], bool), within, 1).astype(int).tolist()
    [[1, 1, 0, 0, 0, 0]]
    """
    reach = seeds & within
    if steps <= 0 or not reach.any():
        return reach
    grown = touching(reach)
    grown &= within
    if steps == 1:
        return grown
    h, w = within.shape
    wide = w + 2
    free = np.zeros((h + 2, wide), bool)          # with a border of one cell, never free
    np.greater(grown, reach, out=free[1:-1, 1:-1])      # the first step's cells (a > b: a and not b)
    front = np.flatnonzero(free)
    np.greater(within, grown, out=free[1:-1, 1:-1])     # the cells not reached yet
    del reach, grown
    offsets = (-wide - 1, -wide, -wide + 1, -1, 1, wide - 1, wide, wide + 1)
    flat = free.reshape(-1)
    for _ in range(steps - 1):
        if front.size == 0:
            break
        added = []
        for off in offsets:                        # one neighbour at a time: marked as it is taken, each once
            nb = front + off
            nb = nb[flat[nb]]
            flat[nb] = False
            added.append(nb)
        front = np.concatenate(added)
    return np.greater(within, free[1:-1, 1:-1])    # reached: the cells of within no longer free


def open_progressive(z, cell, p, work, progress=None, stages=None):
    """The progressive form (Zhang et al. 2003; Pingel et al. 2013, SMRF), in SMRF's four
    steps. Returns the mask, the provisional surface ``ZIpro`` (NaN at nodata) and the
    windows, thresholds and counts for the log. ``stages`` (optional dict) receives each stage's
    cells (:func:`filter_morphological`'s ``stages``)."""
    valid = np.isfinite(z)
    nodata = ~valid
    s, growth = p["slope"], p["window_growth"]
    # 1. low-outlier pre-step on the inverted surface
    #    (level neighbours of a coarse cell's pit: within twice dh, noise on both, and the terrain's rise
    #    over two cell diagonals at the outline slope)
    level = 2.0 * p["dh_m"] + p["outline_slope"] * 2.0 * math.hypot(*cell)
    low, clean = find_low_outliers(z, nodata, cell, growth, p["low_outlier_slope"], work,
                                   sub_progress(progress, 0.0, 0.1), level_m=level)
    report(progress, 0.1)       # its pits' tests after the opening of -z: a report after each stage (QA 20)
    # 2. progressive opening of the cleaned surface: flags where the opening drops by > s r_k
    radii = window_radii(p["max_object_size_m"], cell, growth)
    thresholds = step_thresholds(radii, s, p["wide_slope"], p["wide_radius_m"])
    a, has_nodata = _as_inf(clean, 1.0, nodata)
    #    at each cell at least the slope of the ground around it where the cell itself lies on a slope
    #    (ground_slope_map, l1_slope)
    #    (ground_slope_map, l1_slope); the erosion it reads is the opening's last (_progressive's last_erosion)
    steep, widest = ground_slope_map(a, radii[-1][:2], cell, work, return_erosion=True)
    report(progress, 0.105)
    own = edge_l1_slope(l1_slope(clean, cell), clean, cell)    # on the edge from the cells the raster holds
    add_rounding((own, steep), clean, cell)                     # ties of a plane's drop go to the ground
    report(progress, 0.11)
    #    each step's threshold at least Zhang et al.'s dh_0, the drop the noise alone shows (noise_allowance)
    allowance = noise_allowance(p["noise_m"])
    first = None if stages is None else np.full(z.shape, -1, np.int8)
    spared = np.zeros(z.shape, bool)
    obj, opened = _progressive(a, radii, s, has_nodata, sub_progress(progress, 0.11, 0.85), work, growth,
                               thresholds, ground_slope=steep, own_slope=own, last_erosion=widest, allowance=allowance,
                               cell=cell, first_step=first, spared_last=spared,
                               reference_slopes=bool(p.get("reference_slopes", True)))
    del steep, own, widest
    del a
    obj &= valid
    #    the cut terrain's rules judge the regions the drops flagged, the last step's continuing slopes included
    #    (a crest they pass leaves its shoulders flagged, lines no wider than an outline, which those rules keep)
    spared &= ~obj
    obj |= spared
    #    flagged regions on no wall: terrain the opening cut (find_cut_terrain)
    cut = find_cut_terrain(clean, obj, valid & ~obj & ~low, cell, p["dh_m"], p["outline_slope"], radii[-1][:2])
    obj &= ~cut
    report(progress, 0.852)
    #    and flagged cells with no wall within the window: a dike, an embankment longer than that (find_cut_slopes)
    along = find_cut_slopes(clean, obj, valid & ~obj & ~low, cell, p["dh_m"], p["outline_slope"], radii[-1][:2])
    obj &= ~along
    cut |= along
    obj &= ~spared
    del spared
    report(progress, 0.855)
    # 3. provisional surface ZIpro: flagged and low cells, which SMRF leaves out and
    #    interpolates, take the last opening (the ground reconstructed under them), and
    #    so do the mixed cells on the objects' outlines (find_outline_cells)
    left_out = obj | low | nodata
    #    (a flank of a few cells along a feature as long as the largest window is none: _flank_along)
    outline = find_outline_cells(clean, opened, left_out, cell, p["dh_m"], p["outline_slope"], work,
                                 r_max=radii[-1][:2])
    left_out |= outline
    report(progress, 0.86)
    #    and the lower tiers attached to the objects (find_attached_tiers)
    tiers = find_attached_tiers(clean, opened, left_out, obj | outline, cell, p["dh_m"], p["slope_scale_m"],
                                p["outline_slope"], radii[-1][:2], work, sub_progress(progress, 0.86, 0.9),
                                hidden=low | nodata)
    left_out |= tiers
    zpro = clean
    np.copyto(zpro, opened, where=left_out)
    report(progress, 0.9)
    # 4. SMRF's final test against ZIpro
    mask = classify_provisional(z, zpro, cell, p["dh_m"], p["slope_scale_m"], sub_progress(progress, 0.9, 0.96))
    #    its low cells: low outliers when deep or below the ground around them, else ground (confirm_low_cells)
    low_final = mask == LOW
    confirmed = confirm_low_cells(z, low_final, zpro, cell, p["dh_m"], p["low_outlier_slope"] * LOW_OUTLIER_WINDOW_M,
                                  level)
    mask[low_final & ~confirmed] = GROUND
    if stages is not None:
        first[~valid] = -1
        stages.update(low_prestep=low, first_step=first, flagged=obj, cut_terrain=cut, outline=outline, tiers=tiers,
                      low_ground=low_final & ~confirmed)
    report(progress, 0.97)
    zpro[~valid] = np.nan
    info = {"window_sizes_m": [round((2 * rx + 1) * cell[0], 3) for ry, rx, _ in radii],
            "window_cells": [(2 * ry + 1, 2 * rx + 1) for ry, rx, _ in radii],
            "thresholds_m": [round(t, 4) for t in thresholds], "slope_scale_m": p["slope_scale_m"],
            "window_growth": growth, "low_outlier_cells_prestep": int(low.sum()), "outline_slope": p["outline_slope"],
            "flagged_by_opening_percent": 100.0 * float(obj.sum()) / max(1, int(valid.sum())),
            "cut_terrain_percent": 100.0 * float(cut.sum()) / max(1, int(valid.sum())),
            "low_cells_ground_percent": 100.0 * float(np.count_nonzero(low_final & ~confirmed))
            / max(1, int(valid.sum())),
            "outline_percent": 100.0 * float(outline.sum()) / max(1, int(valid.sum())),
            "attached_tier_percent": 100.0 * float(tiers.sum()) / max(1, int(valid.sum()))}
    return mask, zpro, info


# --------------------------------------------------------------------------- the filter
def filter_morphological(z: np.ndarray, cell_size: Union[float, Tuple[float, float]], *, mode: str = "auto",
                         max_object_size_m: Optional[float] = None, dh_m: Optional[float] = None,
                         slope: Optional[float] = None, slope_scale_m: float = 1.25,
                         window_growth: float = WINDOW_GROWTH, low_outlier_slope: float = LOW_OUTLIER_SLOPE,
                         outline_slope: Optional[float] = None, wide_slope: Optional[float] = None,
                         wide_radius_m: Optional[float] = None, noise_m: Optional[float] = None,
                         reference_slopes: bool = True,
                         progress: Optional[Callable[[float], None]] = None, stages: Optional[dict] = None
                         ) -> FilterResult:
    """Classify a DSM into ground, objects and low outliers by grey opening.

    Parameters
    ----------
    z : array_like, 2-D
        The lowest surface (DSM), NaN = nodata; not modified.
    cell_size : float or (dx, dy)
        Metres.
    mode : {"auto", "progressive", "single"}
        ``"single"``: one opening with a window of ``max_object_size_m`` and the two-sided
        test with ``dh_m`` (the 1996 form). ``"progressive"``: SMRF / Zhang et al. (2003)
        growing windows with a slope-dependent threshold, then SMRF's final test against
        the provisional surface. ``"auto"``: resolved by
        :func:`resolve_morphological_params` (progressive unless the terrain is flat at
        the scale of the window).
    max_object_size_m, dh_m, slope : float, optional
        Largest object (side of the largest window, metres), height threshold of the
        two-sided test (metres, SMRF's ``e_t``) and terrain slope ``s`` (rise/run) of the
        progressive threshold ``t_k = s r_k``. Default: derived from the data.
    slope_scale_m : float
        SMRF's ``e_s``: metres of extra tolerance per unit of slope of the provisional
        surface in the final test of the progressive form (1.25 in SMRF).
    window_growth : float
        Ratio between consecutive window radii of the progressive form (1: SMRF's
        one-cell steps; 2: Zhang's doubling windows, the default, 3-5x faster).
    low_outlier_slope : float
        Slope of SMRF's low-outlier pre-step (inverted surface, 1 m window); 5 = 500 %.
    outline_slope : float, optional
        Terrain slope (rise/run) the ground beside an object may show over one cell
        (:func:`find_outline_cells`); progressive form. Default: derived from the data.
    wide_slope, wide_radius_m : float, optional
        Beyond the radius ``wide_radius_m`` (metres) the threshold grows by ``wide_slope`` per metre
        instead of ``slope`` (:func:`step_thresholds`); progressive form. Default: derived from the data
        (``slope`` at every radius when ``slope`` is given).
    noise_m : float, optional
        The noise (standard deviation, metres) of the DSM's ground; progressive form: every step's
        threshold is at least ``dh_0`` = 4.5 x it (:func:`noise_allowance`, Zhang et al. 2003). Default:
        measured (:func:`resolve_morphological_params`).
    reference_slopes : bool
        Progressive form: each step also passes the drops the slope of its reference's erosion allows where that
        slope continues along the terrain on cells no earlier step flagged (:func:`reference_slope`; default on;
        the dtm's morphological member keeps it off).
    progress : callable, optional
        ``progress(fraction)`` within every step; may raise
        :class:`~bare_earth.core.common.Cancelled`.
    stages : dict, optional
        Diagnostics (``benchmarks/morphological_errors.py``): receives each stage's cells as boolean
        rasters, progressive form: ``low_prestep`` (the pre-step's low outliers), ``first_step`` (int8: the
        index of the first step of the opening that flagged the cell, -1 none), ``flagged`` (the opening's
        flags left after ``cut_terrain``, the flagged cells :func:`find_cut_terrain` and :func:`find_cut_slopes`
        gave back), ``outline`` (:func:`find_outline_cells`), ``tiers`` (:func:`find_attached_tiers`),
        ``low_ground`` (the final test's low cells :func:`confirm_low_cells` made ground); single form:
        ``low_ground``. The result does not depend on it.

    Returns
    -------
    FilterResult
        ``mask`` (0 ground, 1 object, 2 low outlier, 255 nodata), ``surface`` (the
        opened surface of the single form or SMRF's provisional surface of the
        progressive form, float32) and ``info`` (mode and why, dh, slope, window sizes,
        class counts).

    Raises
    ------
    ValueError
        For an unknown mode or a parameter out of range (the message says which).
    """
    z = as_surface(z)
    cell = as_cell_size(cell_size)
    p = _complete(z, cell, dict(mode=mode, max_object_size_m=max_object_size_m, dh_m=dh_m, slope=slope,
                                slope_scale_m=slope_scale_m, window_growth=window_growth,
                                low_outlier_slope=low_outlier_slope, outline_slope=outline_slope,
                                wide_slope=wide_slope, wide_radius_m=wide_radius_m, noise_m=noise_m,
                                reference_slopes=reference_slopes))
    p = {k: (float(v) if k in _NUMBERS else v) for k, v in p.items()}
    info = {"mode": p["mode"], "mode_reason": p.get("mode_reason", "mode given by the user"),
            "dh_m": p["dh_m"], "noise_m": p["noise_m"], "noise_allowance_m": noise_allowance(p["noise_m"]),
            "slope": p["slope"], "wide_slope": p["wide_slope"], "wide_radius_m": p["wide_radius_m"],
            "max_object_size_m": p["max_object_size_m"], "reference_slopes": bool(p["reference_slopes"])}
    if p["mode"] == "single":
        mask, surface, more = open_single(z, cell, p["max_object_size_m"], p["dh_m"], _Work(), progress)
        #  its low cells as the progressive form's: low outliers when deep or below the ground around them
        #  (a gap in vegetation wider than the window is ground), with the pre-step's depth and level
        low = mask == LOW
        level = 2.0 * p["dh_m"] + p["outline_slope"] * 2.0 * math.hypot(*cell)
        confirmed = confirm_low_cells(z, low, surface, cell, p["dh_m"], p["low_outlier_slope"] * LOW_OUTLIER_WINDOW_M,
                                      level)
        mask[low & ~confirmed] = GROUND
        if stages is not None:
            stages["low_ground"] = low & ~confirmed
    else:
        mask, surface, more = open_progressive(z, cell, p, _Work(), progress, stages)
    info.update(more)
    report(progress, 0.97)
    mask = finish_mask(mask, z)
    nval = max(1, int(np.count_nonzero(mask != NODATA)))
    info["object_percent"] = 100.0 * float(np.count_nonzero(mask == OBJECT)) / nval
    info["low_percent"] = 100.0 * float(np.count_nonzero(mask == LOW)) / nval
    info.update({k: p[k] for k in _DERIVED[1:] if k in p})
    report(progress, 1.0)
    return FilterResult(mask=mask, info=info, surface=surface)


#: The numeric parameters (floats in the log).
_NUMBERS = ("max_object_size_m", "dh_m", "slope", "slope_scale_m", "window_growth", "low_outlier_slope",
            "outline_slope", "wide_slope", "wide_radius_m", "noise_m")


# --------------------------------------------------------------------------- defaults
def slope_block_cells(shape, cell_size, scale_m, scale_down=True):
    """Block side (cells) of :func:`estimate_terrain_slope` on a raster of ``shape``: ``scale_m``
    over the coarser axis's cell, scaled down to a third of the raster's shorter side when the
    raster holds fewer than 3 x 3 such blocks, the last may be partial
    (:func:`~bare_earth.core.estimate.held_block_side`), at least 2 cells (unless ``scale_m`` is under 1.5 cells)."""
    dx, dy = as_cell_size(cell_size)
    k = max(1, int(round(scale_m / max(dx, dy))))
    return held_block_side(shape, k, min_blocks=3) if scale_down else k


def estimate_terrain_slope(z, cell_size, scale_m=20.0, percentile=90.0, scale_down=False):
    """Robust terrain slope (rise/run): a high percentile of a coarse minimum surface's slope.

    The surface is reduced to the minimum of ``scale_m`` blocks (objects smaller than a
    block vanish from it; the block side in cells from the coarser axis, scaled down to a
    third of the raster's shorter side on a raster under three blocks wide,
    :func:`slope_block_cells`) and the slope of that coarse surface is taken by central
    differences (:func:`~bare_earth.core.estimate.terrain_slopes`, at least 3 x 3 blocks);
    the ``percentile`` of it is returned, NaN when not measurable (under 3 x 3 blocks of 2
    cells).
    """
    z = as_surface(z)
    dx, dy = as_cell_size(cell_size)
    k = slope_block_cells(z.shape, (dx, dy), scale_m, scale_down)
    g = terrain_slopes(z, (dx, dy), k, min_blocks=3)
    return float(np.percentile(g, percentile)) if g.size else float("nan")


def estimate_object_size(z, cell_size, slope, dh, search_m=_OBJECT_SEARCH_M, progress=None, outline_slope=None,
                         window_growth=_OBJECT_SEARCH_GROWTH, wide_slope=None, wide_radius_m=None, on_walls=True,
                         details=False, noise_m=0.0, with_mask=False, reference_slopes=True):
    """Side of the largest object, metres, found by the progressive filter itself.

    The progressive filter with windows up to ``search_m`` flags the cells standing more
    than ``_OBJECT_HEIGHT_M`` (and ``dh``) above the provisional ground; with ``on_walls`` (default)
    only its regions standing mostly on walls are objects (:func:`objects_on_walls`: terrain the
    search's opening cut, a knoll or a crest steeper than its slope threshold, falls to the ground at
    the terrain's slope; on the fBm mountain of ``benchmarks/bare.py`` such regions read 60-88 m and
    the filter's window, sized from them, cut more terrain). The width of each
    object is twice the largest distance from its inside to its outline (the largest
    square window it holds; :func:`~bare_earth.core.estimate.object_widths`, across nodata gaps
    and the low outliers on a roof). The object size is the width below which 98 % of the object
    area lies, times 1.25 (stepped roofs and sloped ground need a larger window than the
    footprint's inscribed square) plus two cells, or NaN when there are no objects.
    ``outline_slope`` (default ``slope``) is the filter's, so the objects include their
    outline cells. ``window_growth`` (default :data:`_OBJECT_SEARCH_GROWTH`, Zhang's doubling
    windows) is the search's own. ``wide_slope`` and ``wide_radius_m`` are the filter's (default
    ``slope`` at every radius). ``progress(fraction)`` (optional, may raise ``Cancelled``)
    from inside the filter. ``details``: return ``(size of the objects on walls, size of every region
    flagged, whether a region wider than its outline was judged to stand on walls)`` from the one search;
    with ``with_mask`` too, the search's mask (0 ground, 1 object, 2 low, 255 nodata) as a fourth item.
    """
    z = as_surface(z)
    cell = as_cell_size(cell_size)
    res = filter_morphological(z, cell, mode="progressive", max_object_size_m=search_m,
                               dh_m=max(dh, _OBJECT_HEIGHT_M), slope=slope,
                               outline_slope=slope if outline_slope is None else outline_slope,
                               wide_slope=slope if wide_slope is None else wide_slope,
                               wide_radius_m=0.0 if wide_radius_m is None else wide_radius_m,
                               window_growth=window_growth, noise_m=noise_m, reference_slopes=reference_slopes,
                               progress=sub_progress(progress, 0.0, 0.9))
    flagged = res.mask == OBJECT
    # twice the distance from the inside to the outline, counted to the cell's centre (the
    # estimate's width counts to its far edge); nodata gaps and low outliers (blunders on a
    # roof, one cell or a 2 x 2 cluster) do not cut an object
    holes = (res.mask == LOW) | ~np.isfinite(z)

    def size(obj):
        if not obj.any():
            return float("nan")
        w = object_widths(obj, cell, 0.98, nodata=holes, border_outside=False) + min(cell)
        return _OBJECT_MARGIN * w + 2.0 * max(cell)

    walled = flagged
    args = (z, flagged, res.mask == GROUND, cell, res.info["dh_m"], res.info["outline_slope"])
    if on_walls or details:
        walled = objects_on_walls(*args, hidden=holes)
        report(progress, 0.93)          # each estimate after the search reports (QA 20: 0.6 s CPU on 16 Mcells)
    if details:
        found = (size(walled),)
        report(progress, 0.95)
        found += (size(flagged),)
        report(progress, 0.97)
        found += (bool(objects_on_walls(*args, hidden=holes, keep_thin=False).any()),)
        report(progress, 1.0)
        return found + (res.mask,) if with_mask else found
    return size(walled if on_walls else flagged)


def single_window_cuts(z, cell_size, size_m, cells, depth_m):
    """How many of ``cells`` (bool) the single window's opening lies more than ``depth_m`` below: what the 1996
    form would cut that deep there.

    The single form removes every raised feature narrower than its window and higher than ``dh``, terrain
    included: it is the production form where the terrain is flat at the window's scale (the 1996 system's
    premise). :func:`resolve_morphological_params` judges that from the slope of 40 m block minima, which do not
    show terrain features narrower than a block (dikes on a floodplain, a crest); counted on the ground the
    progressive object-size search kept (terrain passed at its slope) below the search's own object height,
    the opening's cut shows them.

    Examples
    --------
    A dike 4 m high on a level plain, its crest 5 m wide and its sides 1:1: a 20 m window cuts its crest and the
    top of its sides by more than 2 m (7 cells of each row), an 11 m window its crest (5 cells), a 9 m window
    nothing that deep.

    >>> j = np.tile(np.arange(48, dtype=np.float32), (8, 1))
    >>> z = np.clip(4.0 - np.maximum(np.abs(j - 24.0) - 2.0, 0.0), 0.0, None).astype(np.float32)
    >>> [single_window_cuts(z, 1.0, w, np.ones(z.shape, bool), 2.0) // 8 for w in (20.0, 11.0, 9.0)]
    [7, 5, 0]
    >>> single_window_cuts(z, 1.0, 20.0, z == 0, 2.0)
    0
    """
    z = as_surface(z)
    with np.errstate(invalid="ignore"):
        deep = (z - open_surface(z, cell_size, size_m)) > np.float32(depth_m)
    return int(np.count_nonzero(deep & np.asarray(cells, bool)))


def objects_on_walls(z, objects, ground, cell, dh, slope, hidden=None, keep_thin=True):
    """The connected regions (8-neighbours) of ``objects`` standing mostly on walls: more than
    :data:`TIER_WALL_SHARE` of their edge cells (those next to ``ground``) stand more than ``dh`` plus the
    terrain's rise over a cell diagonal (``slope``) above the lowest ground cell around (the test of
    :func:`find_outline_cells`), or no edge cell at all (a region filling the raster or enclosed by
    nodata; a region's cells on the raster's border are edge cells too, on no wall: its outline there lies
    beyond the data), or (``keep_thin``) no cell inside its outline (every cell next to a cell of another kind: a
    region one or two cells wide is an outline itself, too thin to be judged by its walls,
    :func:`find_cut_terrain`'s rule; ``keep_thin=False``: only the regions judged to stand on walls).
    Terrain the opening cut falls to the ground around at the terrain's slope and is left out.
    ``hidden`` (optional, bool): cells whose height hides what lies there (nodata, low outliers); those
    next to an object join the regions on their sides (a roof crossed by lines of empty cells is one
    region, not strips each with a few edge cells).

    Examples
    --------
    >>> z = np.zeros((5, 9), np.float32); z[1:4, 1:4] = 5.0; z[1:4, 5:8] = 0.3; z[2, 6] = 0.6
    >>> flags = z > 0
    >>> objects_on_walls(z, flags, ~flags, (1.0, 1.0), 0.5, 0.0).sum(axis=0)
    array([0, 3, 3, 3, 0, 0, 0, 0, 0])
    """
    regions = objects
    if hidden is not None and hidden.any():
        regions = objects | (hidden & touching(objects))
    lab, n = label8(regions)
    if n == 0:
        return objects
    edge = objects & touching(ground)
    wall = _walls(z, ground, edge, np.float32(dh + slope * math.hypot(*cell)), dh=dh, cell=cell)
    # where a region meets the raster's border its outline lies beyond the data: edge cells no wall shows
    # (as when the opening flagged the border cells of a plane or a crest there, which the edge's own slope
    # now passes: edge_l1_slope)
    n_ground = np.bincount(lab[edge], minlength=n + 1)
    edge[[0, -1], :] |= objects[[0, -1], :]
    edge[:, [0, -1]] |= objects[:, [0, -1]]
    n_edge = np.bincount(lab[edge], minlength=n + 1)
    n_wall = np.bincount(lab[wall], minlength=n + 1)
    # a region with no cell inside its outline (every cell next to something else) is an outline itself,
    # too thin to be judged by its walls (find_cut_terrain's rule): kept
    judged = np.bincount(lab[objects & ~touching(~objects)], minlength=n + 1) > 0
    keep = (n_wall > TIER_WALL_SHARE * n_edge) | (n_ground == 0)
    keep = keep | ~judged if keep_thin else keep & judged
    keep[0] = False
    return keep[lab] & objects


def resolve_morphological_params(z: np.ndarray, cell_size: Union[float, Tuple[float, float]], *,
                                 mode: str = "auto", max_object_size_m: Optional[float] = None,
                                 dh_m: Optional[float] = None, slope: Optional[float] = None,
                                 slope_scale_m: float = 1.25, window_growth: float = WINDOW_GROWTH,
                                 low_outlier_slope: float = LOW_OUTLIER_SLOPE, outline_slope: Optional[float] = None,
                                 wide_slope: Optional[float] = None, wide_radius_m: Optional[float] = None,
                                 noise_m: Optional[float] = None, raised_regions: bool = True,
                                 reference_slopes: bool = True, progress=None, **_ignored) -> dict:
    """Complete the parameters of :func:`filter_morphological` from the data.

    * ``dh_m``: ``3 sigma``, ``sigma`` the noise of the DSM's ground-level cells
      (:func:`~bare_earth.core.estimate.noise_ground_level`: never the canopy's or the roofs'
      roughness, which reads metres on a forest at 4 m cells and switched the single-window
      form on), bounded to 0.5-5 m (0.5 m is SMRF's ``e_t``; LiDAR noise is far below it,
      image-matching noise often above); 0.5 m when too few ground cells are seen; with ``noise_m``
      given, ``3 noise_m`` bounded the same way.
    * ``noise_m``: the sensor's noise, ``sigma_cleanest`` of the same estimate (the cleanest quarter of its
      tiles: on a highest-point DSM of a vegetated hillside ``sigma`` reads the low vegetation), ``sigma``
      when the tiles are too few, 0 when not measurable; the progressive thresholds' floor
      (:func:`noise_allowance`).
    * ``slope``: the median slope of the 40 m block-minimum surface
      (:func:`estimate_terrain_slope`; on a raster that holds fewer than 3 such blocks, up to
      80 m, blocks of a third of its shorter side when their minima lie within ``dh`` of a plane,
      :func:`~bare_earth.core.estimate.block_minima_plane_residual`: a drone crop of a hillside
      still shows its slope, a roof over most of a tile does not), bounded to 0.3-1.5:
      the threshold ``s r`` must pass the terrain's own relief and the median of a coarse
      surface underestimates it; 0.3 is the best single value on the ISPRS samples, and the
      value used when the raster holds under 3 x 3 blocks of 2 cells (not measurable).
    * ``wide_radius_m``: half the blocks the slope is read from (20 m); ``wide_slope``: the median
      slope ``s_50`` when the floor made ``slope`` steeper (``slope`` derived, 40 m blocks held), else
      ``slope``: beyond that radius the threshold grows by it (:func:`step_thresholds`; features
      narrower than a block, which the floor is for, are cut in full by then).
    * ``max_object_size_m``: the width of the largest objects the progressive filter
      finds with doubling windows up to 100 m (:func:`estimate_object_size`), bounded to 10-80 m: its
      regions standing mostly on walls or too thin to judge (:func:`objects_on_walls`; a region falling
      to the ground at the terrain's slope is terrain the search cut: on the fBm mountain of
      ``benchmarks/bare.py`` such crests made the window 60-80 m); without any, 40 m or the width of the
      regions flagged if smaller (40 m when nothing is flagged); with ``raised_regions``, widened to the width of the
      widest raised region standing on walls that this window does not reach across
      (:func:`~bare_earth.core.estimate.raised_region_window`, at most 200 m wide, spanning at most
      :data:`~bare_earth.core.estimate.RAISED_REGION_SPAN_M`: a roof over most of
      a tile, running off it). Its walls must run within those 200 m, mirrored at the sides of the
      raster they meet (:func:`~bare_earth.core.common.walls_runs`, dtm's raised regions' copy): a
      side both the wall's top and the ground at its foot reach. Lidar ``sample_c``'s wall cuts off a
      corner and ends next to the opposite one, where the roof's own corner reaches the third side:
      mirrored there too its walls ran 225-228 m at 1-4 m, the window stayed 30-44 m and the roof
      ground (88.13 % at 2 and 4 m, 0.26 at 0.5 m where it was widened); mirrored at the two sides
      the wall meets (150-152 m) the window widens at every cell size (174-183 m): 0.00 / 0.27 %.
    * ``outline_slope``: the terrain's 90th-percentile slope ``s90`` (below), the rise
      over one cell the ground beside an object may show before a cell on the object's
      outline is taken for a mixed cell (:func:`find_outline_cells`); SMRF's ``slope``
      when the raster holds fewer than 3 x 3 blocks of 40 m (the 90th percentile of a few smaller
      blocks is the slope of a wall between two of them).
    * ``mode``: ``"auto"`` becomes ``"progressive"`` when ``s90 * max_object_size_m / 2 >
      dh_m``, ``s90`` the 90th-percentile slope of the coarse minimum surface (a single
      opening would cut the terrain by more than ``dh``), else ``"single"``, except when the
      object-size search found no object standing on walls (:func:`objects_on_walls`): the single window
      would then be a guess, not a width a little larger than the largest object (the 1996 form's rule),
      and it removes every terrain feature narrower than it and higher than ``dh``, which the 40 m block
      minima do not show (dikes on a floodplain: ``benchmarks/bare.py`` levees at 0.5 / 1 / 2 m 6.20 /
      15.64 / 5.13 -> 0.09 / 1.90 / 2.35 % of the ground lost), so the progressive form is used;
      ``mode_reason`` says why. Where objects on walls were found and the slope rule reads flat terrain, the
      single window's cut is read on the terrain too: the progressive form is used when the cells of the ground
      the search kept that the single opening would cut deeper than the search's object height (``dh``, at least
      2 m) outnumber the cells of the objects it found (:func:`single_window_cuts`: terrain features narrower
      than the blocks; levees at 4 m, where the search's region at the dikes' junction stands on one-cell rises
      of 2 m: 13.08 -> 10.66 % of the ground lost).

    Large rasters are reduced to block minima of at most a million cells for the slope
    and the object size; the noise is measured at full resolution on windows spread over
    the raster (:func:`~bare_earth.core.estimate.sample_windows`). ``progress(fraction)``
    (optional, may raise ``Cancelled``) from inside the estimates.
    """
    z = as_surface(z)
    cell = as_cell_size(cell_size)
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}; got {mode!r}.")
    check_values("morphological", PARAMS, dict(max_object_size_m=max_object_size_m, dh_m=dh_m, slope=slope,
                                slope_scale_m=slope_scale_m, window_growth=window_growth,
                                low_outlier_slope=low_outlier_slope, outline_slope=outline_slope,
                                wide_slope=wide_slope, wide_radius_m=wide_radius_m, noise_m=noise_m))
    k = max(1, int(math.ceil(math.sqrt(z.size / _RESOLVE_CELLS))))
    zs = block_minima(z, k)
    report(progress, 0.1)
    cs = (cell[0] * k, cell[1] * k)
    out = dict(mode=mode, max_object_size_m=max_object_size_m, dh_m=dh_m, slope=slope,
               slope_scale_m=slope_scale_m, window_growth=window_growth,
               low_outlier_slope=low_outlier_slope, outline_slope=outline_slope, wide_slope=wide_slope,
               wide_radius_m=wide_radius_m, raised_regions=bool(raised_regions),
               reference_slopes=bool(reference_slopes))
    if noise_m is None:
        gn = noise_ground_level(z, cell, progress=sub_progress(progress, 0.1, 0.4))  # full resolution, ground level
        noise = gn["sigma"]
        clean = gn.get("sigma_cleanest", float("nan"))
        sensor = clean if np.isfinite(clean) else noise
        out["noise_m"] = float(sensor) if np.isfinite(sensor) else 0.0
        out["noise_source"] = (
            f"measured on the DSM's ground-level cells ({100 * gn['ground_share']:.0f} % of the cells), "
            + ("in the cleanest quarter of their tiles" if np.isfinite(clean) else "the whole window")
            if np.isfinite(sensor) else
            f"not measurable on ground-level cells ({gn['samples']} samples): 0, no allowance")
    else:
        noise = out["noise_m"] = float(noise_m)
        out["noise_source"] = "given"
    if dh_m is None:
        if np.isfinite(noise):
            out["dh_m"] = float(min(_MAX_DH, max(_MIN_DH, _DH_NOISE * noise)))
            out["dh_source"] = (f"derived: {_DH_NOISE:g} x the noise {noise:.3f} m of the DSM's ground-level "
                                f"cells ({out['noise_source']}), bounded to {_MIN_DH:g}-{_MAX_DH:g} m")
        else:
            out["dh_m"] = _MIN_DH
            out["dh_source"] = (f"the noise is not measurable on ground-level cells ({gn['samples']} "
                                f"samples): {_MIN_DH:g} m (SMRF's elevation threshold)")
    else:
        out["dh_source"] = "given"
    s50 = estimate_terrain_slope(zs, cs, _SLOPE_SCALE_M, 50.0, scale_down=True)
    s90 = estimate_terrain_slope(zs, cs, _SLOPE_SCALE_M, 90.0, scale_down=True)
    kb = slope_block_cells(zs.shape, cs, _SLOPE_SCALE_M)
    block_m = kb * max(cs)
    blocks = f"{_SLOPE_SCALE_M:g} m"                   # the blocks the slopes are read from
    unmeasured = f"3 x 3 blocks of {block_m:.3g} m"     # what the raster holds too few of
    if kb < slope_block_cells(zs.shape, cs, _SLOPE_SCALE_M, scale_down=False):
        # a raster under 3 blocks of 40 m: its slope from blocks of a third of its side, only where their
        # minima lie on a plane within dh (else an object wider than them stands in some: a roof over most
        # of the tile); the 90th percentile of so few blocks is their largest slope or two (a wall), so
        # the outline slope and the mode take the median
        res = block_minima_plane_residual(zs, cs, kb)
        s90 = float("nan")
        if res <= out["dh_m"]:
            blocks = (f"{block_m:.3g} m ({_SLOPE_SCALE_M:g} m scaled down to a third of the raster's shorter "
                      f"side; their minima within {res:.2f} m <= dh of a plane)")
        elif np.isfinite(res):
            s50 = float("nan")
            unmeasured = (f"3 x 3 blocks of {_SLOPE_SCALE_M:g} m, and on blocks of {block_m:.3g} m the minima lie "
                          f"up to {res:.2f} m > dh from a plane (objects wider than the blocks)")
    report(progress, 0.45)
    out["terrain_slope_p50"], out["terrain_slope_p90"] = s50, s90
    if slope is None:
        out["slope"] = float(min(_MAX_SLOPE, max(_MIN_SLOPE, s50 if np.isfinite(s50) else 0.0)))
        if np.isfinite(s50):
            out["slope_source"] = (f"derived: median slope {s50:.3f} of the {blocks} "
                                   f"block-minimum surface, bounded to {_MIN_SLOPE:g}-{_MAX_SLOPE:g}")
        else:
            out["slope_source"] = f"raster under {unmeasured}: slope not measurable, {_MIN_SLOPE:g} used"
    else:
        out["slope_source"] = "given"
    if outline_slope is None:
        if np.isfinite(s90):
            out["outline_slope"] = float(min(_MAX_OUTLINE_SLOPE, s90))
            out["outline_slope_source"] = (f"derived: 90th-percentile slope {s90:.3f} of the {blocks} "
                                           f"block-minimum surface, at most {_MAX_OUTLINE_SLOPE:g} (a wall)")
        else:
            out["outline_slope"] = out["slope"]
            out["outline_slope_source"] = (f"raster under 3 x 3 blocks of {_SLOPE_SCALE_M:g} m: the terrain slope "
                                           f"s = {out['slope']:.3f} used")
    else:
        out["outline_slope_source"] = "given"
    if wide_radius_m is None:                           # features narrower than a block: cut in full by then
        out["wide_radius_m"] = block_m / 2.0
    if wide_slope is None:
        if slope is None and np.isfinite(s50) and np.isfinite(s90):
            out["wide_slope"] = float(min(out["slope"], s50))
            out["wide_slope_source"] = (f"derived: beyond a radius of {out['wide_radius_m']:.3g} m (half a block) the "
                                        f"threshold grows by the median slope {s50:.3f} of the {blocks} "
                                        f"block-minimum surface (SMRF's terrain slope, not bounded), at most "
                                        f"s = {out['slope']:.3f}")
        else:
            out["wide_slope"] = out["slope"]
            out["wide_slope_source"] = ("slope given: s at every radius (SMRF)" if slope is not None else
                                        f"raster under 3 x 3 blocks of {_SLOPE_SCALE_M:g} m: s at every radius (SMRF)")
    else:
        out["wide_slope_source"] = "given"
    unfounded = False                                   # the window is a default, no object's width
    search = None                                       # the object-size search's mask
    if max_object_size_m is None:
        w, w_all, walls, search = estimate_object_size(zs, cs, out["slope"], out["dh_m"], noise_m=out["noise_m"],
                                                     progress=sub_progress(progress, 0.45, 1.0),
                                                     outline_slope=out["outline_slope"], wide_slope=out["wide_slope"],
                                                     wide_radius_m=out["wide_radius_m"], details=True,
                                                     with_mask=True, reference_slopes=out["reference_slopes"])
        unfounded = not walls
        if np.isfinite(w):
            out["max_object_size_m"] = float(min(_MAX_OBJECT_M, max(_MIN_OBJECT_M, w)))
            out["max_object_size_source"] = (
                f"derived: widest objects found {w:.1f} m (1.25 x the 98 % area width + 2 cells; regions standing "
                f"mostly on walls or too thin to judge), bounded to {_MIN_OBJECT_M:g}-{_MAX_OBJECT_M:g} m")
        elif np.isfinite(w_all):
            # every region the search flagged falls to the ground at the terrain's slope: terrain it cut; the
            # window need not be wider than they are
            out["max_object_size_m"] = float(min(_DEFAULT_OBJECT_M, max(_MIN_OBJECT_M, w_all)))
            out["max_object_size_source"] = (
                f"no object standing on walls found (the regions flagged, {w_all:.1f} m, fall to the ground at the "
                f"terrain's slope): the default {_DEFAULT_OBJECT_M:g} m or their width if smaller, at least "
                f"{_MIN_OBJECT_M:g} m")
            unfounded = True
        else:
            out["max_object_size_m"] = _DEFAULT_OBJECT_M
            out["max_object_size_source"] = f"no object found: default {_DEFAULT_OBJECT_M:g} m"
            unfounded = True
        # the margin of the objects found (1.25 x their width + 2 cells): the region's width leaves out the
        # rims on top of its walls, and a window just as wide still fits inside it
        window = raised_region_window(zs, cs, max(out["dh_m"], _OBJECT_HEIGHT_M), out["max_object_size_m"],
                                      max_span_m=RAISED_REGION_SPAN_M) if raised_regions else 0.0
        if window > out["max_object_size_m"]:
            out["max_object_size_m"] = window
            out["max_object_size_source"] += (
                f"; widened to {window:.1f} m, {RAISED_REGION_MARGIN:g} x the width of a raised region bounded by "
                f"walls that the search's windows do not reach across + 2 cells (at most {RAISED_REGION_MAX_M:g} m)")
    else:
        out["max_object_size_source"] = "given"
    if mode == "auto":
        s_t = s90 if np.isfinite(s90) else out["slope"]
        cut = s_t * out["max_object_size_m"] / 2.0
        if unfounded:
            # the 1996 form's window is a little larger than the largest object; with no object found it
            # would be a guess (the default, or the width of terrain the search cut) that removes every
            # terrain feature narrower than it and more than dh high (dikes on a floodplain, which 40 m
            # block minima do not show: bare.py levees at 1 m lost 15.6 % of the ground), while the
            # progressive form passes terrain at its slope
            out["mode"] = "progressive"
            out["mode_reason"] = (f"no object standing on walls found by the progressive search: a single "
                                  f"opening would use a window of {out['max_object_size_m']:.1f} m, not the width "
                                  "of an object, and cut any terrain feature narrower than it (a dike) by its "
                                  "full height, so the progressive filter (SMRF) is used")
        elif cut > out["dh_m"]:
            out["mode"] = "progressive"
            out["mode_reason"] = (f"terrain not flat: a single {out['max_object_size_m']:.1f} m "
                                  f"opening would cut the terrain's 90th-percentile slope {s_t:.3f} "
                                  f"by up to {cut:.2f} m > dh {out['dh_m']:.2f} m, so the progressive "
                                  "filter (SMRF) is used")
        else:
            # the window's cut read on the terrain itself: the ground the progressive search kept that the single
            # opening would cut deeper than the search's least object height (terrain features narrower than the
            # slope's 40 m blocks: dikes), against the objects the search found
            deep = found = 0
            if search is not None:
                deep = single_window_cuts(zs, cs, out["max_object_size_m"], search == GROUND,
                                          max(out["dh_m"], _OBJECT_HEIGHT_M))
                found = int(np.count_nonzero(search == OBJECT))
            if deep > found:
                out["mode"] = "progressive"
                out["mode_reason"] = (f"terrain flat at the scale of 40 m blocks (90th-percentile slope {s_t:.3f}), "
                                      f"but a single {out['max_object_size_m']:.1f} m opening would cut {deep} cells "
                                      f"of the ground the object-size search kept by more than "
                                      f"{max(out['dh_m'], _OBJECT_HEIGHT_M):.2f} m, more than the {found} cells of "
                                      "objects it found (terrain features narrower than the blocks: dikes), so the "
                                      "progressive filter (SMRF) is used")
            else:
                out["mode"] = "single"
                out["mode_reason"] = (f"terrain flat: a single {out['max_object_size_m']:.1f} m opening "
                                      f"cuts the terrain's 90th-percentile slope {s_t:.3f} by at most "
                                      f"{cut:.2f} m <= dh {out['dh_m']:.2f} m, and {deep} cells of the ground the "
                                      f"object-size search kept by more than {max(out['dh_m'], _OBJECT_HEIGHT_M):.2f} "
                                      f"m (objects found: {found} cells), so the single-window 1996 form is used")
    else:
        out["mode_reason"] = f"mode {mode!r} given by the user"
    return out


def morphological_halo(params, cell_size):
    """Reach of the filter in cells: two largest half-windows (erosion then dilation; the ground slope map's
    erosion, central difference, opening and running maximum: ``1 + 2 _SLOPE_RUN_CELLS`` cells more),
    the 3 x 3 closing or low-outlier step (or the ring of its pits), the outline cells (their neighbours and the
    opened surface's slope there) and the slope's central difference; then the attached
    tiers (:func:`find_attached_tiers`): a region up to the largest window wide, its edge's
    neighbours and their lowest neighbour; before them the cut terrain (:func:`find_cut_terrain`), a
    flagged region as wide as the same box, its edge's neighbours and their lowest neighbour; last the
    final test's low cells (:func:`confirm_low_cells`): their neighbours' classes and the ring around
    them. The outline cells' test reads a line as long as the largest window through each cell on a flank
    (:func:`_flank_along`) and the cell opposite its foot: the largest half-window and two cells more."""
    cell = as_cell_size(cell_size)
    size = params.get("max_object_size_m") or _MAX_OBJECT_M
    ry, rx = _half_widths(size, cell)
    low = _low_radii(cell, 1.0)[-1]
    # the ring of the pits deeper than s x 1 m where the pre-step's window reaches beyond 1 m (find_low_outliers)
    pit = max(surroundings_reach(cell)[2:]) if low[2] > LOW_OUTLIER_WINDOW_M + 1e-9 else 0
    # the flags: the opening's two half-windows; the ground slope's (ground_slope_map: the erosion, its central
    # difference, the opening of the slopes, the step's running maximum) 1 + 2 _SLOPE_RUN_CELLS cells more
    # (each wall and outline test reads the ground two steps beyond its foot: continuing_rise, 2 cells more)
    # (the outline cells' flanks along a feature: a line of the largest window's half-width, _flank_along)
    # (the reference's slopes read on the cells the earlier drops held: a line of the largest window's half-width
    # on those flags, reference_slope)
    core = int(2 * max(ry, rx) + 1 + 2 * _SLOPE_RUN_CELLS + 2 * max(low[0], low[1], pit) + 4 + 2 * _CONTINUE_CELLS
               + 2 * (max(_tier_box((ry, rx))) + 3 + _CONTINUE_CELLS) + max(ry, rx) + 2 + max(ry, rx))
    # the final test's low cells: their neighbours' classes and the ring around them (confirm_low_cells)
    return max(core + 1, max(surroundings_reach(cell)[2:]) + 1)


#: Keys of the resolved parameters that are statistics for the log, not arguments.
_DERIVED = ("mode_reason", "noise_source", "terrain_slope_p50", "terrain_slope_p90", "dh_source",
            "outline_slope_source", "slope_source", "max_object_size_source", "raised_regions", "wide_slope_source")


#: The user parameters (dialog order); their bounds are the limits the core enforces.
PARAMS = (
    Param("mode", "enum", "auto",
          "auto: progressive windows where the terrain is not flat (slope x half the largest window "
          "> dh) or no object was found (the one window would be a guess that cuts dikes), else one window; "
          "progressive: growing windows with a slope-dependent threshold "
          "(Zhang et al. 2003, SMRF); single: one opening and the two-sided dh test (1996 form).",
          options=MODES),
    Param("max_object_size_m", "float", None,
          "Largest object to remove, metres (side of the largest window). Empty: the width of the "
          "largest objects found by the progressive filter with windows up to 100 m, standing on walls (terrain "
          "the search cut falls to the ground at the terrain's slope and is left out), 10-80 m (see "
          "raised_regions).",
          minimum=0.1, maximum=10000.0),
    Param("dh_m", "float", None,
          "Height threshold dh, metres: cells more than dh above the opened / provisional surface are "
          "objects, more than dh below are low outliers. Empty: 3 x the noise of the DSM's ground-level cells, "
          "0.5-5 m.", minimum=0.0, maximum=1000.0),
    Param("slope", "float", None,
          "Terrain slope s (rise/run) of the progressive threshold s x window radius (up to wide_radius_m). "
          "Empty: the median slope of the 40 m block-minimum surface, 0.3-1.5.",
          minimum=0.0, maximum=100.0, advanced=True),
    Param("slope_scale_m", "float", 1.25,
          "Extra tolerance of the final test per unit of slope of the provisional surface, metres "
          "(SMRF's e_s). Progressive form only.", minimum=0.0, maximum=100.0, advanced=True),
    Param("window_growth", "float", WINDOW_GROWTH,
          "Ratio between consecutive window radii of the progressive form: 1 = one-cell steps "
          "(SMRF), 2 = doubling windows (Zhang et al. 2003, faster), sqrt 2 (default) = a flat object "
          "is tested within 1.41 times its own half-width (doubling windows test it at up to twice "
          "that, and miss flat roofs 30-60 m wide). Each step's drop is measured over a doubling of the window.",
          minimum=1.0, maximum=10.0, advanced=True),
    Param("outline_slope", "float", None,
          "Terrain slope (rise/run) the ground beside an object may show over one cell: a cell next to an "
          "object standing more than dh plus this rise over a cell diagonal above its lowest ground neighbour "
          "is a mixed cell of the object's outline, classified against the ground under the object. Empty: "
          "the 90th-percentile slope of the 40 m block-minimum surface (at most 100). Progressive form only.",
          minimum=0.0, maximum=_MAX_OUTLINE_SLOPE, advanced=True),
    Param("wide_slope", "float", None,
          "Terrain slope (rise/run) the progressive threshold grows by beyond wide_radius_m: t_k = s R + "
          "wide_slope (r_k - R). Empty: the median slope of the 40 m block-minimum surface, at most "
          "slope (slope itself when slope is given or the raster is too small to measure it). Progressive form only.",
          minimum=0.0, maximum=100.0, advanced=True),
    Param("wide_radius_m", "float", None,
          "Window radius, metres, beyond which the progressive threshold grows by wide_slope instead of slope. "
          "Empty: half the blocks the terrain slope is measured on (20 m). Progressive form only.",
          minimum=0.0, maximum=10000.0, advanced=True),
    Param("noise_m", "float", None,
          "Noise (sigma, metres) of the DSM's ground: every progressive step's threshold is at least dh_0 = "
          "4.5 x sigma, the drop the noise of level ground alone shows under the first windows (Zhang et al. "
          "2003's initial threshold; SMRF's slope x one cell is below the noise at fine cells). Given, dh "
          "derives from it too. Empty: measured on the DSM's ground-level cells in the cleanest quarter of "
          "their tiles (the sensor's noise, not low vegetation; 0 when not measurable).",
          minimum=0.0, maximum=100.0, advanced=True),
    Param("raised_regions", "bool", True,
          "When the largest object size is derived: widen it to 1.25 x the width + 2 cells of the widest "
          "raised region standing on walls (steps down to ground continuing beyond them over most of its "
          "outline) that the derived window does not reach across, at most 200 m (a roof over most of a tile, "
          "running off its edges, which the object-size search's windows keep as ground). A given largest "
          "object is used as given.", advanced=True),
    Param("reference_slopes", "bool", True,
          "Progressive form: each step also passes the drops that the slope of its reference's erosion (the "
          "smaller window its drop is measured from) allows where that slope continues along a line as long "
          "as the largest window on cells no earlier step flagged: a raised road or dike narrower than the "
          "largest window keeps its crest, which SMRF's one slope cuts.", advanced=True),
    Param("low_outlier_slope", "float", LOW_OUTLIER_SLOPE,
          "Slope of SMRF's low-outlier pre-step (inverted surface, 1 m window): a pit deeper than "
          "this x its radius is a low outlier. 5 = 500 % (SMRF).",
          minimum=0.0, maximum=1000.0, advanced=True),
)


def _run(z, cell_size, progress=None, **params):
    """Registry entry: run the filter on complete parameters, log the derived statistics."""
    derived = {k: params.pop(k) for k in _DERIVED if k in params}
    res = filter_morphological(z, cell_size, progress=progress, **params)
    res.info.update(derived)
    return res


METHOD = Method(
    name="morphological",
    bytes_per_cell=101.0,      # measured 61.1 (benchmarks/speed.py, 16 Mcells, file) + the ground slope maps;
    #                            106 with each step's own slope and the reference's top (2026-11-30); 83.0 with
    #                            one buffer for the steps' slopes and the top read at its cells (twice, 2026-11-30);
    #                            + 13 estimated for the reference's slopes (two kept step slopes, their masked copy
    #                            and the flags they leave out; session 29, not measured)
    run=_run,
    resolve=resolve_morphological_params,
    halo=morphological_halo,
    params=PARAMS,
    title="Morphological filter (opening; progressive SMRF / Zhang 2003)",
    description=(
        "<p>Grey opening of the lowest surface. <b>single</b>: one square window a little larger than "
        "the largest object; cells more than dh above the opened surface are objects (class 1), more "
        "than dh below are blunders (class 2), as in the 1996 image-matching production system. "
        "<b>progressive</b>: windows growing from one cell to the largest object, a cell is flagged "
        "when its opened height drops by more than slope x window radius (Zhang et al. 2003; Pingel et "
        "al. 2013, SMRF); the flagged cells take the last opened surface, and every cell is classified "
        "against that provisional surface with dh + 1.25 x its slope. Low outliers are found first by "
        "SMRF's inverted-surface pre-step. <b>auto</b> (default) uses the progressive form unless the "
        "terrain is flat at the scale of the window; the log says which and why.</p>"
        "<p>Defaults from the data: dh from the noise of the DSM's ground-level cells (never the "
        "canopy's or the roofs' roughness: on a closed forest at 4 m cells that reads 4-5 m, which "
        "made dh 5 m and chose the single window), the slope from a coarse minimum surface, the "
        "largest object from the objects the progressive filter finds.</p>"
        "<p>The threshold at a cell is at least the slope of the ground around it (read on the erosion by the "
        "largest window, steps left out, at most 1.5) times the window radius where the cell itself lies on a "
        "slope: knolls, spurs and crests of rough steep relief steeper than the one slope stay ground, a level "
        "roof on a hillside keeps the slope threshold. Every step also passes the drop the slope of its own erosion "
        "allows where that slope holds along half of a straight line as long as the largest window and the cell is "
        "the top across it: the flat crest of an embankment or a dike narrower than the window stays ground. "
        "So does the drop that the slope of the reference's erosion (the smaller window the step's drop is "
        "measured from) allows where that slope continues so on cells no earlier step flagged "
        "(reference_slopes): a raised road whose flanks and crest together are narrower than the step's window "
        "leaves no slope in the step's own erosion, and SMRF's one slope cut its crest by its whole height. On "
        "the raster's outer rows and columns the cell's own slope is read from the cells the raster holds "
        "(one-sided differences across the edge): the windows are clipped there, so the opening sits below a "
        "plane's highest corner as below a crest, by its slope times the radius along both axes, which the slope "
        "threshold did not cover (a plane facing a diagonal lost that corner). Ties of a plane's drop with its "
        "slope threshold (the heights' float32 rounding) go to the ground.</p>"
        "<p>Mixed cells on the outlines of the objects (part roof or crown, part ground: a ring around "
        "every roof in a top-surface DSM) stand more than dh plus the terrain's rise over one cell above "
        "the ground beside them; they are classified against the ground under the object, not at their own "
        "height (outline_slope: the terrain's 90th-percentile slope; a cell whose ground goes on descending "
        "beyond its foot about as much is on a flank, not an outline). A flagged region standing on no wall "
        "anywhere along its edge (every edge cell within dh plus that rise of the ground beside it, or within dh "
        "plus the ground's descent beyond its foot: a flank continuing, not a step across one cell), with "
        "cells inside its edge, inside the raster and no wider than the largest window, is terrain the "
        "opening cut (a knoll or spur steeper than the slope threshold) and stays ground; so does a flagged cell "
        "of such terrain longer than that (a dike, an embankment across the raster) with no wall of its own "
        "flagged region within the window's reach through the flags (another object's walls nearby, a house "
        "beside the embankment or a shrub on its flank, say nothing of it). A cell the final "
        "test puts below the provisional surface is a low outlier (class 2) when it lies deeper than the "
        "pre-step's depth below it, or below every cell within 10 m or its level neighbours by dh; a gap "
        "between tree crowns, at the level of the other gaps, is ground.</p>"
        "<p>Known limit: SMRF's slope parameter has a floor of 0.3 up to a radius of half the 40 m blocks the "
        "slope is measured on (beyond it the threshold grows by the measured median slope), so the threshold "
        "slope x radius reaches 6 m at a 20 m radius: a roof 30-50 m wide and lower than that is never flagged "
        "and stays ground (window radii grow by sqrt 2, so a roof is tested within 1.41 times its half-width; "
        "doubling windows tested it at up to twice that). "
        "Slopes measured on a coarse minimum surface instead of the floor miss narrow dikes and ramps "
        "(ISPRS sample 71: 2.4 % -> 18 %), and so does a cap on the threshold from the coarse terrain's "
        "relief (Zhang et al. 2003's dh_max: 11.7 %).</p>"
        "<p>Zhang K. et al. (2003) IEEE TGRS 41(4):872-882. Pingel T.J., Clarke K.C., McBride W.A. (2013) "
        "ISPRS J. Photogramm. Remote Sens. 77:21-30.</p>"),
)
