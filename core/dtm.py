"""DTM from DSM (recommended): the project's filters as independent evidence, with a confidence map.

A user who wants a DTM should not have to choose a paper. :func:`filter_dtm` runs three filters
built on different principles, each with the defaults it derives from the data, and takes a
cell as ground where most of them do:

* **morphological** (grey opening, progressive; Zhang et al. 2003, Pingel et al. 2013): a cell
  is an object when it stands above the lowest surface a window can reach;
* **rascor** (Jacobsen 2004): neighbour differences, level changes, moving profiles and
  surfaces: objects are raised levels and outliers of local fits;
* **geodesic** (gradual geodesic dilation, 2018): objects are what a reconstruction of the
  terrain from below cannot reach.

Their errors are nearly independent (an opening fails on steep shoulders, a profile fit on
large flat roofs, a reconstruction on low vegetation), so the majority of three is right more
often than any one (ISPRS seven, old defaults, total error: 4.26 / 5.35 / 5.50 % alone,
3.84 % by majority). The vote is a rule from that principle, not a tuned constant: a cell is
ground when more members say ground than object, and a low outlier when most say so.

Where the members disagree the vote counts heads; on terrain whose discontinuities a member's window
or slope allowance does not fit (the upper edge of a terrace, an embankment's banks and crown, a
ramp) RASCOR and the geodesic member call the ground an object while the opening, whose height
threshold follows the slope, keeps it, and the majority makes the DTM cut the edge (ISPRS, 1 m:
91-97 % of the final type I errors of samples 11, 41, 61 and 71 come from the vote).
:func:`.dtm_refine.continue_ground` gives such a cell the evidence none of the members uses: it is
ground when it lies on smooth ground (no second difference above twice the threshold ``t``) joined,
within the refinement's reach, to ground every member agrees on; an object's edge is a step and
stops it (ISPRS seven 4.00 -> 3.79 %, generalisation matrix 8.58 -> 8.50 %, halves 4.08 / 13.23
-> 4.05 / 13.11, opengeos DTM RMSE 0.65 -> 0.66 m; largest row regressions +0.18 ISPRS 11 1 m,
+0.11 ISPRS 31 1 m). ``info["continued_ground_rule"]`` says how many cells it gave back.

The upper edge of a step in the ground (a retaining wall on a terraced hillside, a quarry's bench, a
cliff) is one or two cells the windows of RASCOR and the reconstruction straddle: they reject it, the
opening may keep it, and the step's second difference keeps it from :func:`.dtm_refine.continue_ground`
(``core.synthetic_sites``, made for the held-out ISPRS kinds of issue 13: 76-89 % of dtm's type I cells on
the ``hillside`` and ``quarry`` sites within one cell of a step in the true ground).
:func:`.dtm_refine.continue_lines` gives back such a cell of the vote's objects the opening calls ground
when three cells every member calls ground continue to it in a straight line (within the edge tolerance)
and the ground beyond it drops below that line: the shape of a step's top, which an object's edge, a
bump or low vegetation beside the ground does not have; and a cell of a step's face between two such
ground cells, well below the one and above the other. ``benchmarks/sites.py``: hillside 4.03 / 3.61 /
6.03 / 7.26 -> 3.70 / 3.32 / 5.66 / 6.78 % (1 m lowest / highest, 2 m lowest / highest), quarry 6.42 /
6.69 / 3.54 / 6.34 -> 4.93 / 5.40 / 3.21 / 5.60, shrubs 6.93 / 13.28 / 3.14 / 22.30 -> 7.13 / 13.58 /
3.09 / 22.48, the others within 0.04; generalisation matrix 3.152 -> 3.150 % (halves 3.111 / 3.195 ->
3.114 / 3.187), ISPRS seven 3.327 -> 3.334 %, opengeos DTM RMSE 0.59 m unchanged; largest row regressions
+0.19 (ISPRS 11, 2 m highest), +0.16 (``autzen_trim`` 2 m), gains -0.19 (ISPRS 11 2 m lowest), -0.11
(ISPRS 61 2 m lowest). ``info["continued_line_rule"]`` says how many cells it gave back.

Its candidates are every object of the vote, not only the opening's lone ground (``STEP_TOPS_OF_ALL_OBJECTS``,
issue 13): on ISPRS 11 at 2 m (lowest point) the vote takes 717 of the 859 true ground cells the dtm loses (the
refinement 138, the raised regions and detached levels 4), 261 of them rejected by all three members and 456 by
two, at the tops of the hillside's banks and terrace steps, where every member's window straddles the step; the
step-top test's own evidence (three undisputed cells in a line continuing to the cell, the ground dropping beyond
it) is what tells a step's top from an object's edge, whoever voted. ``benchmarks/sites.py`` (dtm): mean 3.81 ->
3.73 %, hillside 2.53 / 2.32 / 2.22 / 4.85 -> 2.25 / 2.04 / 1.80 / 4.73 (1 m lowest / highest, 2 m lowest /
highest), quarry 4.48 / 4.84 / 2.61 / 4.82 -> 4.29 / 4.63 / 2.32 / 4.66, shrubs +0.03 to +0.10; generalisation
matrix (73 rows) 2.485 -> 2.480 % (halves 2.692 / 2.273 -> 2.698 / 2.257), ISPRS 41 2 m lowest 3.89 -> 3.58,
``hexbin-crop`` 2 m 1.30 -> 1.15, ``autzen_trim`` 4 m 1.40 -> 1.28, but ``autzen_trim`` 2 m 2.17 -> 2.32, ISPRS 11
2 m highest 19.21 -> 19.33; ISPRS seven 3.30 % unchanged, opengeos DTM RMSE 0.58 m unchanged.

The rest of the bank's lost ground is out of this test's reach, and of a chord's: measured on the same row, the
true ground cells the vote rejects stand above the chord between the nearest voted ground on both sides of them
(along every row, column and diagonal with ground within the refinement's reach) by 2.5 m at the median (1.6 m at
1 m cells), the objects by 6.4 m (5.1 m); the cells lying on the chords (within the decision threshold, or with an
allowance of a kink of the terrain's steep slope over the gap, ``s L / 4``) are those where the DTM filled from
the ground around is already within the points' tolerance, so giving them back changes few points: ISPRS 11 2 m
lowest 10.40 -> 10.15-10.38 %, but 1 m lowest 9.10 -> 9.17-9.23 (type II +60 to +130 points) whatever the lines
required (2, 3 or 4) and the allowance (0.5-1 of the slope, 1.5-2 decision thresholds). The ground that matters
is convex (a bank's top, a crest), above the interpolation of the ground around by as much as the objects beside
it, as the refinement's tests found for vegetation (:mod:`.dtm_refine`); the refinement's edge test takes more of
it than of objects on that sample (1 m lowest: 179 true ground cells, 14 objects; 2 m: 96 and 10).

Between a house and the edge of a narrow terrace (the house at the terrace's back, 2-5 m from a retaining
wall's top) no line across the step finds ground on its upper side, and RASCOR and the reconstruction reject
the strip while the opening keeps it (``benchmarks/sites.py``, ``hillside``: most of dtm's type I cells). The
step's top runs on beside the house to where the terrace is seen, so the step is also continued *along* itself
(``along_slope``): three voted ground cells in a line continue to the cell within the edge tolerance, and the
cell and the line's first cell each stand above a neighbour off the line by a step, ``2 dh`` (a step
as :func:`.dtm_refine.find_smooth` has one) plus the terrain's steep slope over the distance (what the terrain
itself may drop there). The refinement spares such tops too (``along_steps``), where the edge test along one
line took them (the house hides the upper side, the lower ground does not continue to them); and the drop
beyond the line across a step is at least ``2 dh`` too, as :func:`.dtm_refine.find_step_tops` has it. Only the
lines along a step run on the voted ground: the lines across on it too, with a cell between two ground cells
of a straight line given back and every cell given back spared by the refinement, gave sites 4.65 % but
``shrubs`` 1 m +0.53 / +0.81 (rough low vegetation on voted ground lines up) and on the matrix opengeos +0.38
points (DTM RMSE 0.61 m), ``autzen_trim`` 1 m +0.23, ISPRS 51 1 m +0.17 (mean 2.561, half A 2.788): not
adopted. ``benchmarks/sites.py`` (1 m lowest / highest, 2 m
lowest / highest): hillside 3.41 / 3.11 / 4.76 / 6.22 -> 2.93 / 2.61 / 2.94 / 5.05 %, quarry 5.07 / 5.45 /
3.21 / 5.48 -> 4.67 / 4.97 / 3.00 / 4.98, railway 2 m 3.12 / 2.59 -> 3.06 / 2.49, shrubs 6.46 / 12.59 -> 6.44 /
12.59, bridge within 0.02, mean 5.07 -> 4.78; generalisation matrix 2.566 -> 2.563 % (halves 2.774 / 2.352 ->
2.776 / 2.344), ISPRS seven 3.291 % either way, opengeos DTM RMSE 0.58 m (total 4.46 -> 4.50); largest row
regressions +0.09 (ISPRS 11 2 m highest, the worst row: 21.83 -> 21.92), +0.08 (``autzen_trim`` 2 m), +0.06
(``autzen-thin`` 4 and 5 m, ISPRS 31 2 m highest), gains -0.19 (ISPRS 41 2 m lowest), -0.16 (``mvk-thin``),
-0.12 (ISPRS 11 2 m lowest). The terrain-drop scenes (quarry benches, a river between walls, steps, a terrace,
a cliff at 1 and 2 m) stay all ground.

The vote keeps low objects every member tolerates (bushes, hedges, the bottoms of canopy gaps on
flat wooded ground): :func:`.dtm_refine.refine_ground` then turns into objects the voted ground
cells that stand above lower voted ground on both sides of a row, column or diagonal (a
slope-based test in the manner of Vosselman 2000, with the terrain's 90th-percentile slope and
the threshold ``t`` below; see that module for why both sides, and what it measured), and the
ground at the objects' edges standing more than the edge tolerance above every straight continuation
of the ground beside it (:func:`.fill.find_edge_spikes`: wall feet, crown skirts), on which the DTM
under the objects would otherwise rest. The edge tolerance is three standard deviations of that
continuation on ground (:func:`.dtm_refine.edge_tolerance`: ``sqrt(6)`` times the spread of the
ground's heights, :func:`~.estimate.lowest_point_spread`, from the noise of the ground-level cells and
the spacing of independent heights, :func:`~.estimate.repeated_height_share`, on the terrain's steep
slope), at most ``t``; on the banks the bank stage gave back (ground rising as earth stands: a dike's, an
embankment's or a cut's face) both tolerances grow by three standard deviations of where each height lies in
its cell, the steepest rise of a cell beside it beyond the terrain's slope over ``sqrt(12)`` for each of the
continuation's heights (``sqrt(tol^2 + 4.5 g^2)``, the edge tolerance at most ``t``;
:func:`.fill.find_edge_spikes`' ``sampling``): a dike's face on 2 m lowest-point cells scatters by a metre along
its contour, and the test took the banks given back cell by cell (issue 13, against main eb5f832:
``benchmarks/sites.py`` mean 2.59 -> 2.58 %, ``embankment`` 3.20 / 3.25 / 3.86 / 3.63 -> 3.16 / 3.21 / 3.48 / 3.54
(1 m lowest / highest, 2 m lowest / highest), ``bridge`` 1 m lowest 1.80 -> 1.78, no row worse; generalisation
matrix (72 rows) 2.364 -> 2.362 %, halves 2.669 / 2.042 -> 2.669 / 2.037, ISPRS 21 2 m lowest 1.63 -> 1.40,
worst ``opengeos`` 2 m 4.81 -> 4.88 and ``autzen_trim`` 1 m (outside the mean) 3.01 -> 3.13; ISPRS seven 3.22 %
unchanged; bare 0.26 -> 0.25 %, ``mounds`` 4 m 1.28 -> 0.95). Everywhere, not on the banks only,
it also spared low vegetation along crowns' edges, whose rise from the ground reads as steep ground
(``autzen_trim`` 1 m 3.01 -> 3.64 %, the skirted crowns of ``tests/core/test_dtm_refine.py``: 565 of 762 high
ring cells kept instead of 147); a bracketed cell is
kept as smooth ground when its own neighbourhood is smooth or
when the second differences reading ground only, at least half of them, are (an object's step beside
a dike's crest is not the ground's roughness). ``info["edge_tolerance_rule"]`` gives the tolerance. The band
of ground along the objects' edges standing more than the edge tolerance (and at most ``t``) above the plane of
the ground beyond it, with no ground within two cells as high, is an object too
(:func:`.dtm_refine.find_raised_band`: low vegetation whose cells continue each other along a crown's edge);
``info["raised_band_rule"]`` says how much it took.
On a steep hillside the floors rise along each line at the slope of the ground seen there, not the terrain's
steep slope in every direction (:func:`.dtm_refine.line_slopes`, :data:`ALONG_GROUND`: a bush stands above the
ground along the contour; issues 12 and 13): generalisation matrix 2.61 -> 2.58 % (halves 2.84 / 2.37 -> 2.77 /
2.38), ISPRS seven 3.33 -> 3.30 %, ISPRS 11 9.11 / 9.81 / 10.59 / 22.48 -> 9.02 / 9.67 / 10.50 / 21.65 (1 m
lowest / highest, 2 m lowest / highest point), ``shrubs`` site 7.13 / 13.60 -> 6.37 / 12.39 at 1 m, opengeos
DTM RMSE 0.59 -> 0.57 m; largest row regression +0.82 (ISPRS 21, 2 m highest point: a bank hidden under
trees). Beside the step tops and the raised band (76a9f89): matrix 2.60 -> 2.56 % (halves 2.83 / 2.36 -> 2.76 /
2.36), 28 rows better and 18 worse, worst row ISPRS 11 2 m highest 22.48 -> 21.65, ISPRS seven 3.33 -> 3.29 %,
opengeos DTM RMSE 0.60 -> 0.58 m; largest regressions ISPRS 21 2 m highest +0.82, ``hexbin-crop`` 4 m +0.14, ISPRS
21 2 m lowest +0.12, 61 2 m highest +0.10; ``benchmarks/sites.py`` 5.11 -> 5.06 (``shrubs`` 1 m 7.13 / 13.60 ->
6.43 / 12.50; ``quarry`` 1 m +0.20, ``railway`` 2 m highest +0.19).
The edge test also looks along each line through such a cell (rows, columns, diagonals): where the
ground continues to it from neither side of a line (above the continuation of one side by more than three
standard deviations of a continuation on ground, :func:`.dtm_refine.continuation_tolerance`, unbounded,
and not continued by the other side, often the object) it is an object too: low vegetation along a
crown's edge is continued by its neighbours along the edge, never by the ground across it (issue 13,
``benchmarks/dtm_errors.py``: ``autzen_trim`` 1 m, 551 of its 1577 type II points on voted ground RASCOR
alone rejected, at crowns' and banks' edges). Generalisation matrix 7.075 -> 7.065 % (halves 3.354 /
10.901 -> 3.345 / 10.888), opengeos DTM RMSE 0.689 -> 0.67 m (total error 6.70 -> 5.37), ``autzen_trim``
1 m 3.29 -> 2.67, ``Topography`` 1 m 3.04 -> 2.93, ``autzen-thin`` 4 m 14.79 -> 14.68, ISPRS seven
3.629 -> 3.649 %; largest row regressions +0.30 (ISPRS 21, 2 m lowest point), +0.23 (21, 2 m highest),
+0.20 (``Topography`` 4 m).
Neither test takes the upper edge of a step in the ground (:func:`.dtm_refine.find_step_tops`: three voted
ground cells on smooth ground continue to the cell in a straight line and the ground beyond drops by a step,
the shape :func:`.dtm_refine.continue_lines` gives back): beside a house at the back of a narrow terrace the
edge test found a retaining wall's top continued from neither side of a diagonal, and between tracks the
bracketed test took a platform's uneven edges (``benchmarks/sites.py``: the refinement's removals on the
``hillside`` and ``railway`` at 2 m were all true ground). A roof's edge has the same shape: such cells within
:data:`ROOF_EDGE_CELLS` of a raised region or a detached level are the roof's (``info["roof_edge_cells"]``).
Sites 5.17 -> 5.08 %, generalisation matrix 2.605 % either way, opengeos DTM RMSE 0.590 -> 0.595 m; largest row
regression ``autzen_trim`` 2 m +0.11.

Low vegetation on a steep slope is kept by the majority where one member rejects it (ISPRS 51 at 1 m: of its 364
type II points 100 are voted ground RASCOR alone rejects, 0.7 m above the ground; ISPRS 11 at 2 m highest point 690):
an opening with a flat window rests on the terrain uphill and lowers a shrub ``h`` high reaching ``w`` up a slope
``g`` by ``max(0, h - g w)`` only, and the reconstruction's allowance grows with the slope. ``_disputed_bumps`` turns
into objects the vote's own ground the opening keeps and another member rejects that stands above the plane fitted to
the ground every member agrees on (12 m square; the slope read on that ground, not across the vegetation) by more
than the decision threshold and three standard deviations of that ground about its plane (Student's t for the cells
the window holds), above the straight line between that ground along every row, column or diagonal bracketing it (at
least two) by the threshold, with no such ground within two cells as high above the plane, and neither smooth nor a
step's top (:func:`.dtm_refine.find_disputed_bumps`). ISPRS seven 3.22 -> 3.18 % (type II 6.77 -> 6.55; 51: 2.19 ->
2.01, 11: 9.25 -> 9.16); generalisation matrix (72 rows) 2.364 -> 2.346 % (half A 2.670 -> 2.629, half B 2.042 ->
2.047), worst row ISPRS 11 2 m highest 19.81 -> 19.56; largest row regressions ``hexbin-crop`` 4 m +0.19, ISPRS 41 1 m
highest +0.05; ``benchmarks/sites.py`` 2.592 -> 2.586 (``shrubs`` -0.14 to -0.48, ``quarry`` 2 m highest -0.21;
``hillside`` 1 m highest +0.42, lowest +0.19: the strip between a house and a terrace's edge, which the plane of the
ground on both levels puts above it; ``railway`` 2 m lowest +0.23); bare terrain 0.259 -> 0.263 % (``outcrops`` 4 m
+0.06). Guards (the same session, measured on main 1959371): the lines read the undisputed ground on the
candidate's own level only (no level change, RASCOR's ``jump_m`` beyond the plane's rise, between them along the
vote's ground: the ground below a retaining wall is not the ground of the strip on its top), a cell on a straight
line of ground continuing it both ways stays ground as in the refinement (:func:`.dtm_refine.find_level_lines`: a
platform one cell wide between its edges), and the least height above the plane is also the plane's rise over one
cell (where a height lies in its cell: an outcrop's foot at 4 m). ``info["disputed_bump_rule"]`` says how many
cells it took.

A flat roof wider than the windows of a majority of the members (a warehouse, a mall), or cut by
the raster's edge so that no window sees ground beyond it (a roof over most of a tile), comes out
of the vote as ground: :func:`.dtm_regions.find_raised_regions` turns into objects the voted
ground regions wider than that window (mirrored at the raster's edge, beyond which nothing is
seen) whose outline seen inside the raster stands on steps (a jump of more than the scale ``s``
over one or two cells down to ground that continues beyond it) over more than half its length
and which stand more than ``t`` above the plane of the ground beyond those steps over more than
half their area; the regions are cut at walls higher than ``s = t, 2 t, 4 t, ...``, so that a roof
of several levels is one region above its inner steps. A terrace's upper level joined to the
ground by a bank or a ramp, a plateau, a hilltop or a dam (banks wider than a wall) stays ground
(lidar ``sample_c``, one roof over 75-80 % of its tile: 88 -> 0.2 / 0.01 / 0.3 % at 0.5 / 2 / 4 m). A
level whose wall runs across the raster (meeting two opposite sides: a terrain step, a river's walls)
continues beyond both: the wall's run mirrored at both spans three times what is seen, beyond the
stage's reach unless short, and the level is left to the vote (inside one tile such a wall and a roof's
wall are alike; a wall cutting off a corner of the raster, meeting two adjacent sides, is a roof's,
unless the ground beyond it steps down again: quarry benches, terraces around a pit stay ground).
Every candidate's decision is in ``info["raised_regions"]``. On a steep hillside the members'
thresholds, which grow with the slope, keep the part of a roof nearest the slope: a level narrower than the windows
that the vote calls mostly an object, cut into the hillside on one side (its outline below the ground
beyond) and on steps elsewhere, is tested the same way and its voted ground turned into objects (ISPRS
sample 11 at 1 m: lowest point 9.33 -> 9.11 %, highest 10.11 -> 9.86; no other row of the matrix moves).

A low roof narrower than those windows (an annex, the lower level of a building, 2-4 m high) is kept
by the opening and the reconstruction, whose allowances grow with the window and the terrain slope,
while RASCOR's level changes reject it: :func:`.dtm_regions.find_detached_levels` turns into
objects the voted ground RASCOR alone rejects on a *level* (voted ground cut where a cell stands
more than RASCOR's ``jump_m`` plus the slope allowance above a neighbour) holding no cell every
member calls ground, the mirror of the continuation above (ISPRS seven 3.76 -> 3.65 %, sample 31
3.04 -> 2.30; generalisation matrix 8.37 -> 8.33 %, halves 3.96 / 12.92 -> 3.84 / 12.96, opengeos
DTM RMSE 0.67 -> 0.66 m; largest row regressions +0.33 ISPRS 61 1 m, +0.24 hexbin-crop 4 m, +0.24
ISPRS 21 2 m highest point). ``info["detached_level_rule"]`` says how many cells it took.
Another member's lone *object* on such a level is the same evidence, where the level is one: a tower cut
by the raster's edge (ISPRS 41, 23 m above the ground, 59 cells at 1 m) is accepted by RASCOR and the
reconstruction, which see no ground beyond it, and rejected by the opening alone. RASCOR's objects are
level changes themselves; the others' count on a level with a *top* (a cell whose 8 neighbours all lie
on it): a patch one or two cells wide between level changes is a step of a steep slope, which the opening
calls an object on the banks of ISPRS 61 and 71 (with it there: +0.26 to +0.42 points on all their rows).
A member's *low outlier* is no raised object and no such evidence (the opening takes a quarry's floor one
cell wide for one). Generalisation matrix 5.700 -> 5.660 % (halves 3.25 / 8.22 -> 3.24 / 8.15), ISPRS
seven 3.56 -> 3.46 % (sample 41 at 1 / 2 m lowest point 3.96 / 5.72 -> 3.29 / 5.25), opengeos DTM RMSE
0.61 -> 0.58 m; largest row regression +0.02 (``autzen-thin`` 4 m, synthetic breakline 1 m).
A level lying *below* the undisputed ground is no raised level: where a cell of it has a neighbour more than
the level change above it that is ground of a level joined to the undisputed ground (or too wide to judge),
or the edge cell on such a level, it is a bench of a steep slope cut off by level changes on a coarse grid,
and stays ground (a low annex's higher side is its building, an object or voted ground with no anchor).
A few cells every member calls ground on a low roof (RASCOR's own ground on three cells of a 68-cell roof in
ISPRS 31's courtyard, 1 m) joined the roof to the ground: its 3-4 m roofs against the taller wings stayed
ground (170 of the row's 721 type II points). A level holding anchors, more than half of whose cells RASCOR
rejects, is judged all the same where it is a lower roof (:func:`.dtm_regions.find_detached_levels` with
``plane_m``): it has a top, its cells lie on a plane (median distance from their least-squares plane at most
half the decision threshold), a quarter of its outline (one side of four) is an object standing a level change
above it, and the raster's edge does not cut it. Generalisation matrix (72 rows) 2.392 -> 2.373 % (halves
2.706 / 2.061 -> 2.667 / 2.062), ISPRS 31 1 m lowest / highest point 2.58 / 2.34 -> 1.94 / 1.88, its holes row
1.99 -> 1.80, ISPRS 11 1 m lowest 9.35 -> 9.27; sites and bare terrain unchanged; largest row regression +0.03
(opengeos: a clearing of 28 cells among crowns, 15 of them rejected by RASCOR). Without the roof's plane,
top and taller side (the anchors' minority alone) the stage took pieces of ground between the level changes of
ISPRS 61's banks (+0.24 on its 1 m holes row, +0.11 at 2 m highest point) and clearings among crowns
(``autzen-thin`` 4 m +0.15, ISPRS 11 2 m highest point +0.13): rough, or without a taller object along a side;
without the edge test, two narrow terraces at the raster's edge with houses at their backs
(``benchmarks/sites.py`` hillside 1 m highest point +0.13); with fewer anchors than RASCOR's rejections instead
of the half, a strip of 22 cells RASCOR rejects 9 of (ISPRS 41 1 m holes row +0.12).
On ``hexbin-crop`` at 4 m (a slope of 0.46 rise/run at its 90th percentile, cliffs of 1.8) 15 cells of a cliff
with 124 ground points: 8.41 -> 8.12 %; ISPRS 41 at 2 m lowest point 4.40 -> 4.29.

Where the DSM itself is steeper than the opening's slope allowance ``s``, the opening rejects ground by
construction (its threshold assumes ground no steeper than ``s``, Zhang et al. 2003) and RASCOR's tests,
whose terrain slope is the raster's, reject it too, while the gradual reconstruction from below keeps it:
there the geodesic member's lone ground is disputed as the opening's (:data:`STEEP_MEMBER`,
:func:`.estimate.cell_slopes` at those cells only) and continued on smooth ground joined to the undisputed
ground. With the bench rule above, generalisation matrix (73 rows) 2.565 -> 2.544 % (halves 2.773 / 2.352 ->
2.770 / 2.312; 82 rows 2.636 -> 2.617), ``hexbin-crop`` 4 m 8.41 -> 7.64, 2 m 1.62 -> 1.53, ISPRS 41 2 m lowest
4.40 -> 3.89, simulated forest 2 / 4 m -0.10 / -0.09; largest row regressions +0.11 (ISPRS 11 at 2 m highest
point: 8 cells given back whose highest points stand above the ground of a steep slope), +0.06
(``autzen-thin`` 5 m), +0.05 (opengeos, ``holes`` ISPRS 51).

On cells finer than 1 m the members run on a coarser grid (:mod:`.dtm_coarse`): the lowest cell of each ``f x f``
block, ``f`` the largest power of two keeping the coarse cell at most 1 m (the finest cell the members were built
and measured for; at 2 m the vote lost what its 2 m rows lose). Their parameters are derived on that grid, the
noise and ``dh_0`` the vote's own thresholds come from on the DSM itself; each member's decision is expanded to
full resolution by height tests against the ground blocks around (:meth:`.dtm_coarse.CoarseGrid.expand_mask`),
and the continuation, refinement, raised regions, detached levels, fill and confidence run at full resolution.
Generalisation matrix unchanged but for its 0.5 m rows (``synthetic/city`` 0.5 m 0.00 -> 0.01 %, ``sample_c``
0.5 m 88.34 -> 88.33; mean 5.585, halves 3.135 / 8.104, ISPRS seven, opengeos: the same); a 16 Mcells DSM at
0.5 m 16.9 -> 10.9 s of CPU. ``info["coarse_rule"]`` states ``f``.

The members' defaults are their own, with one measurement made differently (:func:`member_settings`):
RASCOR's random error ``sigma``, the scale of every height test of its steps, is measured on the DSM's
ground-level cells (:func:`~.estimate.noise_ground_level`) rather than on the whole DSM, which under a
canopy measures the crowns (lidar forest ``Topography`` at 1 m: 0.23 m against 0.011 m on its ground;
the low vegetation between the crowns passed every RASCOR test and the vote kept it). Generalisation
matrix: mean 8.29 -> 8.26 % (halves 3.82 / 12.91 -> 3.78 / 12.89), ISPRS seven 3.66 -> 3.64 %,
``Topography`` 1 m 3.58 -> 3.07, 2 m 2.39 -> 2.07, closed canopy 1 m DTM RMSE 0.39 -> 0.07 m, opengeos
DTM RMSE 0.66 -> 0.69 m; largest row regression +0.72 (ISPRS 31, 2 m highest point: a low roof, 22
cells 2.6-3.0 m high, that RASCOR alone rejected and the detached levels below removed; with the
smaller sigma RASCOR keeps 5 of its cells, every member then calls them ground, and the roof's level,
joined to that undisputed ground, stays ground).
The opening's ``dh_0`` (the vote's threshold ``t``) is measured on the same cells without the spread of
where the heights lie on sloping ground, which the opening's slope term already covers (:func:`noise_threshold`,
as the slope-profile filter's ``dh0``): ISPRS 11 at 2 m highest point, ``t`` 1.115 -> 0.918 m, 23.60 -> 23.24 %;
2 m lowest point 10.54 -> 10.51; no other row of the generalisation matrix moves (the others' ``t`` is the 0.5 m
floor either way; mean 5.700 -> 5.695 %, halves 3.25 / 8.22 -> 3.24 / 8.22).
Both read the noise of the cleanest quarter of the window's tiles where it is lower beyond the tiles' sampling and
the heights' rounding (:func:`ground_noise`, ``sigma_cleanest`` of :func:`~.estimate.noise_ground_level`): on a
highest-point DSM of a vegetated hillside low vegetation touches most of the ground-level cells' second
differences (ISPRS 11 at 2 m highest point: 64 % of them; 0.37 m read on the whole window, 0.23 m on the cleanest
tiles, 0.18 m on the lowest point of the same returns), and ``t`` was 3 x that vegetation's roughness: ``t``
0.918 -> 0.5 m, 21.92 -> 19.02 % (type I 17.78 -> 16.26, type II 27.48 -> 22.72); generalisation matrix mean
(73 rows) 2.565 -> 2.526 %, halves 2.773 / 2.352 -> 2.695 / 2.352, the holes rows 3.207 -> 3.205; no other row
moves by more than 0.03 (ISPRS 11 2 m lowest point 10.31 -> 10.34: 0.179 -> 0.125 m, its ``t`` the floor either way).

Measured, not adopted (issue 13, on main 232df97: the rows where the dtm trails a member or a peer; each rule applied
to dtm's final mask and the DTM filled again, on the 40 ISPRS and lidar point rows of the matrix but those of
``4_6_crop``, ``sample_c`` and ``warsaw_small``, 0.00-0.52 %, which the first rule below moved by at most 0.05
points). Where the errors are (``benchmarks/dtm_errors.py``): on ISPRS 61 at 2 m (lowest point) 1017 of the 1474 type
I points lie in cells all three members reject, the DTM there 4.8 m below the reference: an embankment 5-8 m high
whose banks rise about one metre a metre (steeper than :data:`.dtm_refine.BANK_SLOPE`) and whose lowest-point cells,
31 % of them repeating a neighbour's height (0.17 points per m2), step by up to 5 m a cell; 285 more are the opening's
lone ground. On 71 and 41 at 2 m and ``hexbin-crop`` the type I are the same: steep banks every member or all but the
opening reject.

* A vote weighing each member by its own error rates (the latent-class model of Dawid & Skene 1979: each member's
  rates of calling ground and objects ground and the share of ground, fitted by EM to the counts of the eight vote
  patterns of the raster itself): the same decision as the majority for every pattern on all 28 ISPRS rows. On 61 at
  2 m it reads the opening calling 30 % of the objects ground, RASCOR 2 %, the reconstruction 10 %, 91 % of the cells
  ground, and still puts the opening's lone ground at 3.5 % ground: under independence two object votes outweigh it.
  The members' errors on steep banks are correlated, which no vote of counts sees. Fitted apart on the cells within
  and beyond the opening's slope allowance (the DSM's own slope, :func:`~.estimate.cell_slopes`): 1 to 246 cells
  change on 9 of the 40 rows, by -0.09 (11 2 m highest 18.99 -> 18.90) to +0.06 points (71 2 m lowest 2.61 -> 2.67).
* The opening's lone ground given back: 61 2 m 4.30 / 4.25 -> 3.31 / 3.32 (lowest / highest point), ``hexbin-crop``
  1 m 1.15 -> 0.75, 11 2 m lowest 10.38 -> 9.64; but 11 2 m highest 18.99 -> 23.21, 51 1 m +1.8 / +1.9, 31 1 m +2.1 /
  +2.3, ``Topography`` 1 m 2.68 -> 5.19, ``autzen_trim`` 1 m 2.87 -> 4.31 (vegetation and low roofs). The
  reconstruction's lone ground: 61 1 m 3.05 / 3.09 -> 1.79 / 1.74, 2 m highest 4.25 -> 3.46; but 11 2 m highest +3.3,
  31 2 m highest +1.6, 51 +0.8 to +1.1, ``autzen_trim`` 1 m +1.2. Per cell, the worst second difference of the 3 x 3
  neighbourhood, the cell's slope and the size of its part overlap between the right and the wrong lone ground on 11,
  31 and 51.
* RASCOR's lone dissent on voted ground made objects: ``autzen_trim`` 2 m 2.35 -> 1.47 (RASCOR alone 1.16),
  ``Topography`` 1 / 2 m 2.68 / 2.35 -> 2.52 / 2.02, 11 2 m highest 18.99 -> 18.08, ``autzen-thin`` 4 m 14.31 ->
  14.11; but 41 2 m lowest 3.73 -> 6.10, 51 2 m +1.5 / +0.8, 61 2 m +1.2 / +1.3, ``autzen_trim`` 4 m 1.24 -> 3.38,
  ``hexbin-crop`` 4 m 5.68 -> 11.10. Only where the cell is not smooth (:func:`.dtm_refine.find_smooth`, ``2 t``) or
  stands more than ``t`` above the DTM filled without those cells: the same signs (41 2 m lowest 5.25 / 5.32, 61 2 m
  lowest 5.27 / 5.28, ``hexbin-crop`` 4 m 11.10 / 10.59; ``autzen_trim`` 2 m 1.75 / 1.87, 11 2 m highest 18.08 /
  17.43). Only where the cell's own slope is within the opening's allowance (vegetation on gentle ground):
  ``autzen_trim`` 2 m 2.35 -> 1.65, ``Topography`` 2 m 2.35 -> 2.17, but 41 2 m lowest 3.73 -> 5.00, 61 2 m +0.37 /
  +0.41, 71 2 m +0.36 / +0.21, ``autzen_trim`` 4 m 1.24 -> 1.75.
* :func:`.dtm_refine.continue_banks`' step read over the spacing of independent heights ``L`` beyond the cell
  (``L = c / (1 - repeated share)``: a nearest-filled cell's height comes from a point up to ``L - c`` further away;
  step ``(d + L - c) s + t``), in the filter: 61 2 m 4.30 / 4.25 -> 4.27 / 4.02, but ``Topography`` 1 m 2.68 -> 2.76,
  ``autzen_trim`` 1 m 2.87 -> 2.99, 71 2 m lowest 2.61 -> 2.73. :func:`.dtm_refine.continue_ground`'s second
  differences read between independent heights (a stride of ``round(L / c)`` cells) on the opening's lone ground: at
  most 25 cells and 0.07 points on any row (the bank's second differences are 2-4 m, its threshold ``2 t`` 1 m); on
  the reconstruction's lone ground: 61 1 m 3.05 / 3.09 -> 3.04 / 3.06, 2 m highest 4.25 -> 4.17, but ``autzen_trim``
  1 m 2.87 -> 3.00 (on 61 1 m 54 cells pass; of its lone ground cells 346 hold mostly ground points and 30 mostly
  object points, the former's second differences read at one cell 1.4-2.6 m, the quartiles).

What the user knows overrides the vote: ``object_areas`` (forced object, the ground under
them interpolated), ``ground_areas`` (forced ground) and ``breaklines`` (lines no comparison
crosses: RASCOR honours them, and within the reach of the other members from a break line
RASCOR's decision stands alone, since only RASCOR keeps its comparisons on one side).

``confidence`` (uint8 0-100, 255 nodata) says how sure each decision is, from three
independent pieces of evidence, each 0-1:

* *agreement* ``a``: 1 when every member agrees, 0 when the vote was decided by one member;
* *margin* ``m``: how far the cell is from the decision threshold ``t`` (the height tolerance
  the morphological member derives from the noise of the ground): for an object, its height
  above the DTM in units of ``t`` beyond the first ``t`` (``m = clip(h / t - 1, 0, 1)``); for
  ground, how close it lies to the local mean of the DTM around it
  (``m = clip(1 - |z - mean(DTM)| / t, 0, 1)``);
* *support* ``s``: the share of valid cells within ``support_cells`` that carry the same class.

``confidence = 100 (a + m + s) / 3``; cells the user forced are 100.
"""
import threading
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np
from scipy import ndimage

from .blocks import BlockProgress, alignment, default_workers
from .codes import GROUND, LOW, NODATA, OBJECT
from .common import (
    FilterResult,
    as_cell_size,
    as_surface,
    report,
    running_mean_down,
    sub_progress,
    touching,
    without_far_heights,
)
from .dtm_coarse import CoarseGrid, coarse_factor, coarsen, coarsen_flags
from .dtm_refine import (
    BAND_PLANE_HALF_M,
    BANK_SLOPE,
    BANK_SMOOTH_LINES,
    EDGE_RING_M,
    LEVEL_LINE_CELLS,
    LEVEL_LINE_M,
    REACH_M,
    SMOOTH_RATIO,
    STEP_TOP_REACH,
    banks_halo,
    bump_tolerance,
    continuation_cells,
    continuation_tolerance,
    continue_banks,
    continue_ground,
    continue_lines,
    disputed_bumps_reach,
    edge_tolerance,
    find_disputed_bumps,
    find_level_lines,
    find_raised_edge_ground,
    find_smooth,
    find_step_tops,
    raised_edge_reach,
    refine_ground,
    refine_halo,
    refine_reach,
)
from .dtm_regions import find_detached_levels, find_raised_regions, regions_halo
from .estimate import (
    RAISED_REGION_SPAN_M,
    cell_slopes,
    height_quantum,
    height_resolution,
    lowest_point_spread,
    noise_floor,
    noise_ground_level,
    noise_shared,
    noise_without_sampling,
    raised_region_grid,
    raised_region_span,
    repeated_height_share,
)
from .fill import fill_gaps
from .methods import Method, get_method

#: The members: filters built on different principles (opening, local fits and level
#: changes, reconstruction from below), in the order they run.
#: The slope-profile filter (Luong Chinh Ke 2002) is no member, nor the vote's tie-breaker (issue 13, measured on main
#: e8816c5 with its mask beside the vote's; each rule applied to the final mask, the DTM filled again). On the matrix's
#: point rows (ISPRS and lidar, 41 rows) it is right where the dtm is wrong at 3988 points of cells one member calls
#: ground and wrong where the dtm is right at 5089 (no member: 3835 / 7656; two: 1611 / 2087); on the sites (cells)
#: 11103 / 4704 where one member says ground and the vote's later stages left the cell. Its decision where the
#: members split 2-1 moved the matrix (71 rows)
#: 2.309 -> 2.424 % (ISPRS 11 2 m highest +7.2, 61 2 m highest -1.4) and the sites 2.495 -> 2.265; a vote of four with
#: a tie going to object (ground where 3 of 4 say so) 2.304 % but half B 1.949 -> 1.971 and the sites 2.574; its ground
#: at a wall's foot (below a neighbour by ``2 t``, above none by as much) 2.211 -> 2.224 on 64 rows (ISPRS 61 -0.6 at
#: each row, 11 2 m highest +1.6; half A 2.509 -> 2.590, B 1.894 -> 1.833). Where it alone is right it keeps the ground
#: at walls and terrain steps on coarse cells; where it alone is wrong it keeps low vegetation on slopes, which its
#: profiles accept. No rule tried in the filter told the two apart (the step above the terrain's rise, the feet
#: given to the refinement, smooth ground, the wall's top continuing, straight runs of feet, the disputed bumps'
#: plane): ISPRS 11 2 m highest +1.1 to +2.7 points wherever the others gained. The best of them (the feet, their step
#: ``2 t`` plus the terrain's rise over the distance, given to the refinement as ground): matrix (72 rows) 2.345 ->
#: 2.358 % (half A 2.641 -> 2.675, B 2.032 -> 2.024; ISPRS 41 2 m highest -0.20, 11 2 m lowest -0.16, 61 and 71 2 m
#: -0.06 to -0.10; 11 2 m highest 19.76 -> 20.86, 31 2 m highest +0.26, ``autzen-thin`` 4 m +0.18), sites 2.50 ->
#: 2.42 % (``quarry`` 1 m highest -0.62), for a run of the slope-profile filter beside the members (about 5 s of 13
#: on 16 Mcells): not adopted.
MEMBERS = ("morphological", "rascor", "geodesic")
#: What the vote asks of a member beyond its own defaults: RASCOR's surface size by its
#: model-selection rule alone (``surface_rule="residuals"``), not the window covering the
#: widest objects that RASCOR alone needs. The opening and the reconstruction remove wide
#: objects here, and with the covering window RASCOR's errors followed the opening's
#: (ISPRS seven 3.95 -> 4.34 %, matrix half A 4.08 -> 4.37 %, the same half B). And the paper's
#: tolerances of steps 3 and 4 (``terrain_bend_m=0``): RASCOR alone needs the terrain's bends there
#: on coarse DEMs of hills (objects on a bare 24 m DEM 11.8 -> 2.2 %), the vote does not (1.6 %
#: with or without them: the opening and the reconstruction outvote RASCOR's dissent), and with
#: them matrix row autzen-thin 10 m +0.45 points (mean 7.106 -> 7.111).
#: The morphological member keeps Zhang's doubling windows (``window_growth`` 2): the vote's thresholds
#: and regions were measured with them, and its default sqrt 2 (flat roofs tested nearer their
#: half-width) moved the vote on the matrix 7.11 -> 7.16 %, ISPRS seven 3.64 -> 3.73 %.
#: The vote's raised-region stage (:mod:`.dtm_regions`) judges the roofs wider than the vote's windows, so
#: the morphological member does not widen its window to them (``raised_regions`` off): with the widened
#: window the opening flagged the steps between a wide roof's levels, which cut the stage's regions into
#: pieces narrower than its width (lidar sample_c 0.21 / 0.01 / 0.27 -> 88.3 / 88.1 / 87.3 % at 0.5 / 2 / 4 m).
#: The geodesic member keeps its 64 m largest object for the same reason (``raised_regions`` off): the
#: raised-region stage judges the wider roofs, and the vote's figures were measured with 64 m.
#: The morphological member keeps the reference's slopes off (``reference_slopes``, session 29): with them the vote's
#: matrix gained (73 rows 2.350 -> 2.329 %, ISPRS sample 71 at 2 m 2.61 / 2.77 -> 1.95 / 2.05) but the opengeos DTM
#: RMSE went 0.63 -> 1.00 m (total error 4.79 -> 4.88 %) and ISPRS sample 71 at 1 m 1.81 -> 1.90.
#: RASCOR's moving surfaces of at least 32 cells a side are fitted once per block of cells
#: (``fits_per_block``, :func:`.rascor.fits.snoop_block_fits`: each cell tested against the window
#: centred on its block, at most 1/32 of the window away): the member's step 6 took 1.2-1.5 s of the
#: filter's 10 s of CPU on 16 Mcells.
#: RASCOR's halls closed by walls (``max_hall_m``, :func:`.rascor.steps.enclosed_levels`) are the vote's
#: raised-region stage's (:mod:`.dtm_regions`, which judges the roofs wider than the vote's windows): off in the
#: member (the synthetic city's halls: dtm 0.00-0.07 % without it), which saves its labelling of the whole DSM
#: (about 3 s on 16 Mcells where a hall stands) and the halo it would add.
#: RASCOR's step 3 keeps its own noise of the slope beyond a pair (``ground_sigma_m`` derived: the ground-level
#: cells' noise, :func:`.rascor.steps.slope_weight`). Measured against the paper's tolerance in the member
#: (``ground_sigma_m`` 0.001 m, which adds nothing), main 168d6d2: the matrix's 73 rows 2.437 -> 2.439 % (half A
#: 2.631 -> 2.623, B 2.237 -> 2.249; hexbin-crop 4 m 5.99 -> 6.49, opengeos 2 m 4.75 -> 4.54, ISPRS 11 2 m highest
#: 19.99 -> 19.88, ISPRS 61 2 m highest 4.41 -> 4.46: that row's loss since b2696cb is no longer this setting's),
#: the sites 2.783 -> 2.783 % (shrubs on 28-38 degree slopes -0.28 to -0.43 points, the hillside +0.11 to +0.30),
#: bare terrain 0.363 -> 0.364 % lost, ISPRS seven 3.30 -> 3.31 %, opengeos DTM RMSE 0.61 -> 0.59 m: what the
#: vegetated slopes gain the terraced ones lose, and the vote's other members outweigh the rest.
MEMBER_SETTINGS = {"rascor": {"surface_rule": "residuals", "terrain_bend_m": 0.0, "fits_per_block": True,
                              "max_hall_m": 0.0},
                   "morphological": {"window_growth": 2.0, "raised_regions": False, "reference_slopes": False},
                   "geodesic": {"raised_regions": False}}
#: The members whose ``run`` takes ``pool=`` (the vote's threads): independent parts of their work (the geodesic
#: member's dilation steps, :func:`~.blocks.run_sharing`) that a thread left idle by a member done first may take.
#: With 2 threads RASCOR runs on one, the opening then the reconstruction on the other, which had 1.6 s of CPU
#: more on the 16 Mcells benchmark DSM (the steps: about 2.6 s); the same result whoever runs a step.
SHARING_MEMBERS = ("geodesic",)
#: The member whose random error ``sigma`` (Jacobsen 2004, step 1: the scale of every height test of
#: its steps 3-7) the vote measures on the DSM's ground-level cells (:func:`member_settings`).
NOISE_MEMBER = "rascor"
#: The member that keeps its comparisons on one side of a break line.
BREAKLINE_MEMBER = "rascor"
#: The member whose height threshold follows the terrain's slope (the progressive opening's
#: ``dh = s (w_k - w_{k-1}) c + dh_0``, Zhang et al. 2003): where it alone says ground on smooth
#: ground that continues the undisputed ground, the cell is ground (:func:`.dtm_refine.continue_ground`).
#: The other members' lone ground claims are where their fits or reconstruction overshoot (low
#: vegetation, object edges): with them as well, matrix row autzen_trim 1 m +0.62 points, opengeos +0.14.
SLOPE_MEMBER = "morphological"
#: The member whose lone ground is disputed too where the DSM is steeper than the opening's slope allowance
#: ``s`` (:func:`.estimate.cell_slopes`): the opening's threshold assumes ground no steeper than ``s`` (Zhang et
#: al. 2003) and cuts such ground by construction, while the gradual reconstruction (geodesic dilation from
#: below, whose terrain slope is measured) follows it. On a 4 m grid of a steep slope
#: (matrix row hexbin-crop 4 m) the opening and RASCOR reject cliff ground that the reconstruction keeps;
#: everywhere (no slope condition): autzen_trim 1 m +0.42 points, opengeos +0.22 (low vegetation, roofs'
#: gentle faces); on the steep cells only: +0.02 and +0.05.
STEEP_MEMBER = "geodesic"
#: The member that finds raised levels by their level changes (RASCOR's step 4, Jacobsen 2004): its level
#: change ``jump_m`` cuts the voted ground into levels, and where it alone says object on a level cut from
#: all ground every member agrees on, or another member alone says object on such a level with a top, the
#: cell is an object (:func:`.dtm_regions.find_detached_levels`).
LEVEL_MEMBER = "rascor"
#: The decision threshold ``t`` (the morphological member's ``dh_0``) in units of the ground's noise, and its
#: floor, metres (SMRF's elevation threshold; the member's own bounds): :func:`noise_threshold`.
DH_NOISE = 3.0
MIN_TOLERANCE_M = 0.5
#: The refinement's floors rise along each line at the seen ground's own slope along it, at most the terrain's
#: steep slope (:func:`.dtm_refine.line_slopes`): low vegetation on a hillside stands above the ground along the
#: contour, which a plane does not rise along (issues 12 and 13; figures in the module's docstring).
ALONG_GROUND = True
#: Radius of the ground support of the confidence, metres (a car or a bush is smaller; a cell
#: among ground cells a few metres around it is better supported than a lone one).
SUPPORT_M = 3.0
#: Cells per band of the elementwise work done in bands of rows (:func:`characterise`,
#: :func:`confidence_map`): its temporaries stay in the cache.
_BAND_CELLS = 1 << 16
#: The cells of a step's top the refinement spared (:func:`.dtm_refine.find_step_tops`) within this many cells of
#: a raised region or a detached level are the roof's edge, objects: the refinement's edge test took them (the
#: ring of a warehouse's roof the vote kept, a cell or two wide at its corners).
ROOF_EDGE_CELLS = 2
#: The step tops :func:`.dtm_refine.continue_lines` may give back are all of the vote's objects (True), not only the
#: slope member's lone ground (False, before): on ISPRS 11 at 2 m (lowest point) the three members reject 261 true
#: ground cells together (vote 0 of 3) and 456 with one member's ground, 717 of the 859 ground cells the dtm loses,
#: most of them at the tops of banks and of the steps of the hillside's terraces (``benchmarks/dtm_errors.py``)
STEP_TOPS_OF_ALL_OBJECTS = True
#: The span of :func:`.dtm_refine.continue_banks`' bump test, metres: it looks for the ground up to half of it on
#: each side of a cell given back as bank (at most the banks' reach): the refinement's reach (:data:`REACH_M`),
#: the length over which the refinement's floors still tell a bush from the ground (Vosselman 2000's
#: neighbourhood), wider than a shrub and narrower than a mound or a ramp's end (ISPRS sample 21 at 2 m: looking
#: half the widest object, 28 m, each side, 36 of the 40 cells given back on a ramp's end stood above the ground
#: on every line by 0.2 m; 6 m each side, 7).
BUMP_SPAN_M = REACH_M
#: The banks :func:`.dtm_refine.continue_banks` gives back are left by the refinement's bracketed test
#: (:func:`.dtm_refine.refine_ground`'s ``spared``): a dike's or an embankment's crest stands above the fields on
#: both sides of the line across it, as a bush does, and the bank stage's bump test has already judged the cell
#: against the ground on both sides of all four lines (a bush on the bank stands above it along every one); the
#: two sides of one line do not overrule it. The edge test and the raised band still read the banks (with them
#: spared as well: ``embankment`` 2 m lowest 4.80 -> 3.49 %, but ``autzen_trim`` 1 m 3.02 -> 3.30, opengeos 2 m
#: 4.73 -> 4.94, ISPRS 31 1 m 2.53 -> 2.66: shrubs on banks they took). ``benchmarks/sites.py``: ``embankment``
#: 3.32 / 3.34 / 4.80 / 4.70 -> 3.23 / 3.26 / 4.27 / 4.50 (1 m lowest / highest, 2 m lowest / highest),
#: ``railway`` 2 m 2.84 / 2.05 -> 2.69 / 1.96, mean 2.74 -> 2.71, no row worse; generalisation matrix (73 rows)
#: 2.429 -> 2.415 % (halves 2.619 / 2.234 -> 2.601 / 2.224), ISPRS 71 2 m -0.26 / -0.27, 21 2 m lowest -0.19,
#: ISPRS 31 1 m lowest +0.05 (the largest regression); ISPRS seven 3.33 -> 3.34 %.
SPARE_BANKS = True
#: A bracketed cell on a straight line of ground continuing it both ways (:func:`.dtm_refine.find_level_lines`:
#: :data:`~.dtm_refine.LEVEL_LINE_M` each side, at least :data:`~.dtm_refine.LEVEL_LINE_CELLS` cells, every cell
#: within ``t`` of the chord between its ends) stays ground: a railway platform, a dike's or an embankment's crest is
#: bracketed across its width only, and along its length the ground continues it at its own level or grade, which
#: no bush or car has (issue 13, ``benchmarks/sites.py``: the platforms between tracks the vote kept, taken by the
#: bracketed test). With :data:`SPARE_BANKS`, against main 134304c: sites mean 2.74 -> 2.63 % (``railway`` 1.41 /
#: 1.26 / 2.84 / 2.05 -> 1.03 / 0.88 / 1.52 / 1.15, 1 m lowest / highest, 2 m lowest / highest; ``embankment`` 3.32 /
#: 3.34 / 4.80 / 4.70 -> 3.20 / 3.25 / 3.84 / 4.49; no row worse by 0.05); generalisation matrix (73 rows) 2.429 ->
#: 2.416 % (halves 2.619 / 2.234 -> 2.603 / 2.223; ISPRS 71 2 m -0.26 / -0.24, 61 2 m -0.22 / -0.10, 21 2 m lowest
#: -0.19, ``Topography`` 4 m -0.13; worst regressions +0.05: opengeos 2 m, ISPRS 31 1 m lowest), ISPRS seven 3.33
#: -> 3.34 %, opengeos DTM RMSE 0.61 -> 0.62 m; bare terrain (``benchmarks/bare.py``) 0.36 -> 0.27 % of the ground
#: lost (mounds 0.5 m 0.87 -> 0.17, dunes 2 m 0.62 -> 0.06, levees 4 m 3.96 -> 3.74, no row worse); the synthetic
#: scenes' probe 0.274 -> 0.253 %. Its cost: 0.27 s of CPU for 160 000 bracketed cells (1 % of 16 Mcells). With
#: lines of :data:`~.dtm_refine.LEVEL_LINE_M` alone (one or two cells each side on 4-5 m grids): ``autzen-thin`` 4 /
#: 5 m +0.30 / +0.28; with the floors' reach each side (up to 54 m on flat land, longer than a platform running at an
#: angle to the rows): ``railway`` 2 m 1.88 / 1.38.
LEVEL_LINES = True
#: Voted ground a member rejects standing above the plane of the undisputed ground around it is an object
#: (:func:`.dtm_refine.find_disputed_bumps`: low vegetation on a slope, which the members reading the slope across
#: it keep).
DISPUTED_BUMPS = True
#: The vote's ground one member rejects beside an object, standing above most of the ground of its level around it
#: (the median of its heights above the continuations of the ground plane from the ground within
#: :data:`.dtm_refine.EDGE_RING_M`) by more than the edge tolerance, is an object, but for a step's top and a cell on
#: a straight line of ground (:func:`_raised_edge_ground`, :func:`.dtm_refine.find_raised_edge_ground`: low vegetation
#: at a crown's edge on which the DTM under the crown would rest; issue 13, figures in :mod:`.dtm_refine`).
RAISED_EDGE_GROUND = True
#: Each member's parameters giving the widest object its window removes, metres.
MEMBER_WINDOWS = {"morphological": "max_object_size_m", "rascor": "max_building_m", "geodesic": "max_object_size_m"}


def _members(names):
    return [get_method(n) for n in names]


def member_settings(name, z, cell_size, progress=None, noise=None):
    """What the vote asks of member ``name`` beyond its own defaults: :data:`MEMBER_SETTINGS`, and for
    :data:`NOISE_MEMBER` its random error ``sigma_m`` measured on the DSM's ground-level cells.

    RASCOR estimates ``sigma`` from the Laplacian residuals of the whole DSM (the lower quartile:
    the cleanest quarter of the surface). Where vegetation covers more than three quarters of the
    cells, that quarter is canopy, and ``sigma`` is the canopy's roughness: 0.23 m on the lidar
    forest ``Topography`` at 1 m, whose ground-level noise is 0.011 m; 1.06 m on the synthetic closed
    canopy with 0.05 m noise. Every height test of RASCOR's steps 3-7 scales with it, so low
    vegetation passed them all. The vote asks for the noise of the ground-level cells instead
    (:func:`~.estimate.noise_ground_level`, the statistic the morphological member's ``dh`` comes
    from, made for this failure), never below RASCOR's own floor
    (:data:`~.rascor.SIGMA_FLOOR`); RASCOR's estimate stands where it is not measurable. That noise is taken
    without the spread of where the heights lie on sloping ground (:func:`ground_noise`): RASCOR's tests add
    that spread themselves, from the rise beside each pair (``sigma_h^2 = sigma^2 + g^2 / 12``, its step 3),
    and with it in ``sigma`` as well counted it twice (ISPRS 11 at 2 m highest point, ``sigma`` 0.372 -> 0.306 m:
    23.24 -> 22.64 %; at 1 m lowest point 9.62 -> 9.41; ``hexbin-crop`` 4 m, a 4 m grid of a steep slope that
    the grid itself scores 30.19, 32.56 -> 32.98).

    For :data:`SLOPE_MEMBER` (the opening, whose height threshold ``dh = s (w_k - w_{k-1}) c + dh_0``
    already allows for the terrain's slope between its samples) the vote asks ``dh_0`` of the noise
    alone: the second differences of the ground-level cells also scatter by where each height was
    taken within the spacing of independent heights on sloping ground (a lowest or highest point of a
    2 m cell on a 30 degree hillside lies up to 1.2 m above or below the cell's centre), and taken as
    noise that spread raised ``dh_0`` to 1.1 m on ISPRS sample 11 at 2 m (highest point), where low
    vegetation on the hillside then passed every test. ``dh_0`` is :data:`DH_NOISE` times the noise left
    once that spread is removed (:func:`~.estimate.noise_without_sampling`, on the member's median terrain
    slope, :func:`~.morphology.estimate_terrain_slope`, over the spacing of independent heights,
    :func:`~.estimate.repeated_height_share`, as :func:`~.estimate.lowest_point_spread` models it), at
    least :data:`MIN_TOLERANCE_M`; given only where it is below the member's own (the noise measured
    with that spread). The same correction as the slope-profile filter's ``dh0``.

    ``noise``, when given, is a callable ``noise(progress)`` returning :func:`ground_noise` of ``z``
    (:func:`resolve_dtm_params`: measured once for both members that read it).

    Returns
    -------
    settings : dict
        The member's given parameters (None: it derives all of them).
    ground_noise_m : float or None
        The ground-level noise measured (None for the other members; NaN: not measurable).
    """
    settings = dict(MEMBER_SETTINGS.get(name) or {})
    if name == SLOPE_MEMBER:
        dh = noise_threshold(z, cell_size, progress=progress, noise=noise)
        if dh is not None:
            settings["dh_m"] = dh
        return settings or None, None
    if name != NOISE_MEMBER:
        return settings or None, None
    from .rascor import SIGMA_FLOOR
    noise, sigma = ground_noise(z, cell_size, progress=progress) if noise is None else noise(progress)
    if np.isfinite(sigma):
        settings["sigma_m"] = round(max(SIGMA_FLOOR, sigma), 3)
    return settings or None, noise


def ground_noise(z, cell_size, progress=None):
    """The noise of the DSM's ground-level cells (:func:`~.estimate.noise_ground_level`: its ``sigma``, or the
    cleanest quarter of its tiles, ``sigma_cleanest``, where lower: low vegetation among the ground-level cells
    of most of the window, a highest-point DSM of a vegetated hillside, reads as noise on the whole window) and
    what is left of it without the spread of where the heights lie on sloping ground
    (:func:`~.estimate.noise_without_sampling` on the morphological member's median terrain slope,
    :func:`~.morphology.estimate_terrain_slope`, over the spacing of independent heights,
    :func:`~.estimate.repeated_height_share`, as :func:`~.estimate.lowest_point_spread` models it), metres:
    ``(measured, noise)``, NaN where not measurable; ``noise`` is ``measured`` where the slope is not measurable,
    and never below the rounding error of heights stored in steps (:func:`~.estimate.noise_floor`)."""
    from .morphology import estimate_terrain_slope
    cell = as_cell_size(cell_size)
    zz = without_far_heights(z)[0]
    gn = noise_ground_level(zz, cell, progress=progress)
    # the noise is the sensor's, the same everywhere; the ground-level cells' contamination (low vegetation
    # among them) is not: the cleanest quarter of the tiles where the whole window reads more
    measured = float(np.nanmin([gn["sigma"], gn["sigma_cleanest"]])) if np.isfinite(gn["sigma"]) else float("nan")
    if not np.isfinite(measured):
        return measured, measured
    slope = estimate_terrain_slope(zz, cell, percentile=50.0)
    if not (np.isfinite(slope) and slope > 0):
        return measured, measured
    spacing = max(cell) / max(1e-6, 1.0 - repeated_height_share(zz))
    # heights rounded to whole metres repeat along the contours (read as a wide spacing) and their
    # rounding error is noise no sampling explains: never below it (:func:`~.estimate.noise_floor`)
    return measured, float(noise_floor(noise_without_sampling(measured, slope, spacing), height_quantum(zz)))


def noise_threshold(z, cell_size, progress=None, noise=None):
    """``dh_0`` of :data:`SLOPE_MEMBER` from the noise of the DSM's ground-level cells without the spread of
    where the heights lie on sloping ground (:func:`ground_noise`, :func:`member_settings`), metres; None where
    not measurable, or where it is not below the member's own noise (the ground-level noise of the whole window:
    no slope to take out and no cleaner tiles), or 3 x that noise is under the floor (the member's own
    derivation stands: the same value). ``noise``: as in :func:`member_settings`."""
    measured, noise = ground_noise(z, cell_size, progress=progress) if noise is None else noise(progress)
    # the member's own derivation reads the ground-level noise of the whole window (measured once per window
    # inside estimate.noise_shared)
    own = float(noise_ground_level(without_far_heights(z)[0], as_cell_size(cell_size))["sigma"])
    if not (np.isfinite(noise) and noise < own and DH_NOISE * own > MIN_TOLERANCE_M):
        return None
    return round(max(MIN_TOLERANCE_M, DH_NOISE * noise), 3)


def refine_slope(members):
    """``s`` of the refinement: the morphological member's 90th-percentile terrain slope (rise/run), its
    slope parameter where the raster is too small to measure it."""
    morph = members.get("morphological", {})
    slope = morph.get("terrain_slope_p90", float("nan"))
    return float(slope) if slope is not None and np.isfinite(slope) else float(morph.get("slope", 0.0))


def region_scales(members, cell_size):
    """The scales of the raised-region stage (:func:`.dtm_regions.find_raised_regions`).

    Returns ``(width_m, max_cells)``: the widest object the vote's majority removes (the
    widest object windows of the members, :data:`MEMBER_WINDOWS`, sorted: the one of the
    member that makes the majority; wider raised regions are the stage's candidates), and the
    largest span the stage looks at, in cells: one more doubling of the widest window any
    member uses (the morphological member's progression of windows, ``window_growth`` 2,
    taken one step further). The span is added to the filter's halo (:func:`dtm_halo`): the
    farthest a member looks (up to 7 times its window) would have doubled the halo and made a
    blocked run of a large raster 1.8 times as slow; twice the majority's window (64 m where
    the morphological member measured 40 m) missed a 150 m warehouse. :func:`resolve_dtm_params` widens
    the span to the longest raised region standing on walls the raster shows
    (:func:`~.estimate.raised_region_span`, at most :data:`~.estimate.RAISED_REGION_SPAN_M`): twice the
    windows missed a 180 x 260 m hall (Type II 61 %).
    """
    cell = as_cell_size(cell_size)
    windows = sorted((float(members[n].get(k) or 0.0) for n, k in MEMBER_WINDOWS.items() if n in members),
                     reverse=True)
    need = len(MEMBERS) // 2 + 1
    width = windows[need - 1] if len(windows) >= need else 0.0
    return width, int(np.ceil(2.0 * (windows[0] if windows else 0.0) / min(cell)))


def describe_region(d):
    """One decision of :func:`.dtm_regions.find_raised_regions` as a sentence for the log."""
    r0, c0, r1, c1 = d["bbox"]
    above = "not tested" if d["above_share"] is None else "{:.0f} %".format(100 * d["above_share"])
    head = "rows {}-{}, columns {}-{} (cut at walls over {:g} m): {} cells, {:g} m wide, ".format(
        r0, r1, c0, c1, d.get("step_m", 0.0), d["cells"], d["width_m"])
    if not d.get("reached", True):
        return head + ("its walls run {:g} m mirrored at the raster's edge (a wall across the raster continues "
                       "beyond both sides), beyond the stage's reach: left to the vote").format(d["walls_m"])
    if d.get("steps_beyond", 0) > d["outline_cells"] / 2:
        return head + ("cut by the raster's edge on two opposite sides, the ground beyond its walls stepping down "
                       "again over {} cells (its outline {}): one of a sequence of levels, left to the vote").format(
                           d["steps_beyond"], d["outline_cells"])
    return head + "{:.0f} % of its outline on steps, {} above the ground around: {}".format(
        100 * d["step_share"], above, "object" if d["object"] else "ground")


def characterise(z, cell_size):
    """Describe a DSM for the log: cell size, coverage, and how rough its surface is.

    Parameters
    ----------
    z : ndarray, 2-D float32 (NaN nodata)
        The DSM.
    cell_size : (float, float)
        Metres.

    Returns
    -------
    dict
        ``cell_m`` (the larger cell side), ``valid_share`` (cells with a height),
        ``relief_m`` (2-98 % height range), ``rough_share`` (share of cells differing from a
        neighbour by more than 1 m: walls, crowns and steep slopes).
    """
    valid = np.isfinite(z)
    vals = z[valid]
    step = max(1, vals.size // 1_000_000)
    lo, hi = np.percentile(vals[::step], [2.0, 98.0]) if vals.size else (0.0, 0.0)
    steep = finite = 0
    rows = max(1, _BAND_CELLS // max(1, z.shape[1]))
    for r0 in range(0, z.shape[0], rows):            # in bands of rows: no raster-sized temporaries
        dz = np.abs(np.diff(z[r0:r0 + rows], axis=1))
        steep += int(np.count_nonzero(dz > 1.0))
        finite += int(np.count_nonzero(np.isfinite(dz)))
    rough = float(steep) / max(1, finite)
    return {"cell_m": float(max(cell_size)), "valid_share": float(valid.mean()),
            "relief_m": float(hi - lo), "rough_share": rough}


def early_span(pool, derived, zs, cs, block, cell_size, cancel=None):
    """The raised-region search of :func:`resolve_dtm_params` (:func:`~.estimate.raised_region_span` on the grid
    ``zs``, cells ``cs``, ``block`` cells of the DSM a cell of it) started in ``pool`` before every member is derived.

    Its scales are the decision threshold (the morphological member's ``dh_m``) and the members' windows
    (:func:`region_scales`); a member whose window is not derived from the data (RASCOR's ``max_building_m``: its
    default, the vote asks no other) has it before its derivation ends. Waits for the members whose windows are
    derived (``derived``: ``{name: Future of (params, noise)}``) and the morphological member, then submits the
    search with the other members' windows taken from their defaults and :data:`MEMBER_SETTINGS`. Returns
    ``((tol, width, span), Future of the span in grid cells)``: the caller takes the result only where the scales
    it derives are those (the same call, the same value; else it searches itself). The longest
    derivation (RASCOR's, after the ground noise) then no longer waits for the search: 16 Mcells, the
    derivation's serial tail of 0.29-0.34 s of CPU ran beside it. ``cancel()`` (optional) is called after each
    scale of the search (it raises to stop it).
    """
    from .pipeline import complete_params
    cell = as_cell_size(cell_size)
    known = {}
    for n, fut in derived.items():
        key = MEMBER_WINDOWS.get(n)
        default = None if key is None else complete_params(get_method(n), MEMBER_SETTINGS.get(n)).get(key)
        if n == "morphological" or (key is not None and default is None):
            known[n] = fut.result()[0]          # derived from the data: its own value
        elif key is not None:
            known[n] = {key: default}
    tol = float(known["morphological"].get("dh_m") or MIN_TOLERANCE_M)
    width, span = region_scales(known, cell)
    found = pool.submit(raised_region_span, zs, cs, tol, width, max_span_m=RAISED_REGION_SPAN_M,
                        min_cells=-(-span // block), progress=None if cancel is None else (lambda fraction: cancel()))
    return (tol, width, span), found


def resolve_dtm_params(z, cell_size, progress=None, **params):
    """Every member's parameters derived from the data, and the confidence's scales.

    Parameters
    ----------
    z : ndarray, 2-D
        The DSM (NaN nodata).
    cell_size : float or (float, float)
        Metres.
    progress : callable, optional
        ``progress(fraction)`` from inside each member's estimates; may raise ``Cancelled``.
    **params
        None are taken (the method has no user parameter); unknown names are refused.

    Returns
    -------
    dict
        ``members`` ({name: complete parameters}), ``tolerance_m`` (the decision threshold
        ``t`` of the confidence's margin: the morphological member's dh, 3 x the robust noise
        of the ground), ``support_cells`` (radius of the ground support), ``refine_reach_m``
        (the refinement's reach, :func:`.dtm_refine.refine_reach` with the terrain slope of
        :func:`refine_slope`, at most the farthest a member looks), ``edge_tolerance_m`` (the
        tolerance of the refinement's edge test, :func:`.dtm_refine.edge_tolerance` of the spread of
        the ground's heights, :func:`~.estimate.lowest_point_spread`), ``line_tolerance_m`` (that of its
        test along one line: :func:`.dtm_refine.continuation_tolerance` of the same spread, unbounded),
        ``coarse_factor`` (the members' grid, :func:`.dtm_coarse.coarse_factor`: their parameters other than the
        noise and ``dh_0`` are derived on it) and the description of the input (:func:`characterise`, with
        ``ground_noise_m``: the noise of the ground-level cells
        that :func:`member_settings` gave RASCOR, None where not measurable; ``repeated_height_share``,
        :func:`~.estimate.repeated_height_share`; ``ground_spread_m``, that spread).
    """
    if params:
        raise ValueError(f"the dtm method takes no parameters (got {sorted(params)}): every choice is "
                         "derived from the data; use a method filter to set parameters.")
    from .pipeline import resolve_params
    z = as_surface(z)
    cell = as_cell_size(cell_size)
    # the members run on the coarse grid (dtm_coarse): the rest of their parameters are derived on it
    f = coarse_factor(cell)
    zm, cm = coarsen(z, f), (cell[0] * f, cell[1] * f)
    # the members' derivations and the description are independent reads of z: they run side
    # by side, one per core (numpy releases the GIL in their array work); the same values as
    # one after the other. Their progress is the mean of the members' fractions (BlockProgress:
    # thread-safe, and a cancel raised by one stops the others at their next report).
    shares = BlockProgress(sub_progress(progress, 0.0, 0.95), len(MEMBERS))

    def derive(i, n):
        # a member's given settings first (RASCOR's: its noise, on the surface its derivation reads)
        share = shares.of_block(i)
        split = 0.1 if n in (NOISE_MEMBER, SLOPE_MEMBER) else 0.0
        # the noise and dh_0 measured on the DSM itself: the vote's own thresholds at full resolution come from them
        given, noise = member_settings(n, z, cell, progress=sub_progress(share, 0.0, split), noise=shared_noise)
        # (zm: the coarse grid of the surface the pipeline gave, its empty cells already filled)
        return resolve_params(n, zm, cm, given, progress=sub_progress(share, split, 1.0), fill_empty=False), noise

    # the ground noise both members read (RASCOR's sigma, the opening's dh_0): measured by the first that asks, the
    # other waiting for it (the same value; once, not side by side twice)
    noise_lock, noise_memo = threading.Lock(), []

    def shared_noise(progress):
        with noise_lock:
            if not noise_memo:
                noise_memo.append(ground_noise(z, cell, progress=progress))
        report(progress, 1.0)
        return noise_memo[0]

    # the members measure the noise of the same ground-level cells: once (estimate.noise_shared)
    with noise_shared(), ThreadPoolExecutor(max_workers=min(len(MEMBERS) + 1, default_workers())) as pool:
        # the first member measures the noise; the members that need none and the description take the other
        # thread meanwhile, then the other noise reader (it waits for the noise less): the same results by name
        first = [n for n in MEMBERS if n == SLOPE_MEMBER]
        last = [n for n in MEMBERS if n == NOISE_MEMBER and n not in first]
        futures = {n: pool.submit(derive, MEMBERS.index(n), n) for n in first}
        futures.update({n: pool.submit(derive, i, n) for i, n in enumerate(MEMBERS) if n not in first + last})
        description = pool.submit(characterise, z, cell)
        futures.update({n: pool.submit(derive, MEMBERS.index(n), n) for n in last})
        derived = {n: futures[n] for n in MEMBERS}
        # the raised regions' grid (z's block minima) in this thread, while the members derive theirs
        zs, cs, k = raised_region_grid(zm, cm)
        # the longest raised region looked for as soon as its scales are known (early_span), on the thread the
        # members done first leave while the longest derivation (RASCOR's, after the noise) runs
        early = early_span(pool, derived, zs, cs, f * k, cell, cancel=shares.check)
        results = {n: f.result() for n, f in derived.items()}
        description = description.result()
        members = {n: r[0] for n, r in results.items()}
        tol = float(members["morphological"].get("dh_m") or MIN_TOLERANCE_M)
        width, span = region_scales(members, cell)
        found = early[1].result() if early is not None and early[0] == (tol, width, span) else None
    noise = results[NOISE_MEMBER][1] if NOISE_MEMBER in results else None
    if noise is not None:
        description["ground_noise_m"] = noise if np.isfinite(noise) else None
    support = max(1, int(round(SUPPORT_M / min(cell))))
    # the refinement's reach: longer on gentle terrain, never beyond the farthest a member looks
    limit = max(member_halo(m, members, cell, f) for m in _members(MEMBERS)) * min(cell)
    reach = refine_reach(tol, refine_slope(members), limit)
    report(progress, 0.95)      # the members derived; below, the raster-wide estimates of the vote's own stages
    # the edge test's tolerance: three standard deviations of its statistic on ground (dtm_refine.edge_tolerance)
    repeated = repeated_height_share(z)
    report(progress, 0.96)
    spread = lowest_point_spread(noise if noise is not None else float("nan"), refine_slope(members),
                                 max(cell), repeated)
    if spread == 0.0:       # exact heights, flat (no noise, no slope): their float32 resolution, not 0 m
        spread = height_resolution(z)
    description["repeated_height_share"] = repeated
    description["ground_spread_m"] = spread if np.isfinite(spread) else None
    # the stage reaches the longest raised region standing on walls the data shows (a hall longer than twice the
    # members' widest window), at most RAISED_REGION_SPAN_M; the halo grows only when there is one
    # (on block minima: a wall found there may stand one block further out at full resolution)
    report(progress, 0.97)
    if found is None:       # not looked for early (its scales were not known before every member was derived)
        found = raised_region_span(zs, cs, tol, width, max_span_m=RAISED_REGION_SPAN_M, min_cells=-(-span // (f * k)),
                                   progress=sub_progress(progress, 0.97, 1.0))
    report(progress, 1.0)
    found = min((found + 1) * k * f, int(np.ceil(RAISED_REGION_SPAN_M / min(cell)))) if found else 0
    description["raised_region_span_m"] = round(found * min(cell), 1)
    span = max(span, found)
    return {"members": members, "tolerance_m": tol, "support_cells": support, "refine_reach_m": reach,
            "edge_tolerance_m": edge_tolerance(tol, spread),
            "line_tolerance_m": continuation_tolerance(spread) if np.isfinite(spread) else tol,
            "region_width_m": width, "region_max_cells": span, "coarse_factor": f, "input_description": description}


def bank_scales(members, region_width_m, cell_size):
    """The scales of :func:`.dtm_refine.continue_banks`, in cells: ``(reach, wall)``.

    The reach: half the widest object the vote's majority removes (``region_width_m``, :func:`region_scales`):
    a raised region the members reject is at most that wide, so each of its cells lies within half of it of
    its rim (at least the continuation's reach, :func:`.dtm_refine.continuation_cells`). The wall: half the
    widest object the data shows (the morphological member's window, derived from the objects' widths): a
    cell of a deck or a roof lies within half its width of its walls.
    """
    cell = min(as_cell_size(cell_size))
    reach = max(continuation_cells((cell, cell)), int(np.ceil(0.5 * float(region_width_m or 0.0) / cell)))
    widest = float(members.get(SLOPE_MEMBER, {}).get("max_object_size_m") or 0.0)
    return reach, int(np.ceil(0.5 * widest / cell))


def member_halo(meth, members, cell_size, f=1):
    """A member's reach in full-resolution cells when it runs on the grid coarsened by ``f``."""
    cell = as_cell_size(cell_size)
    return int(meth.halo(members[meth.name], (cell[0] * f, cell[1] * f))) * int(f)


def dtm_halo(params, cell_size):
    """Reach in cells: the largest member reach, plus the continuation's
    (:func:`.dtm_refine.continuation_cells` and its smoothness test's two cells), the refinement's,
    the raised regions' and the confidence's windows, rounded up to a multiple of the members' window alignment
    (:func:`~.blocks.alignment` of each member's halo), so that a window's corner keeps the
    members' coarse grids those of the single pass."""
    f = int(params.get("coarse_factor", 1))
    cell = as_cell_size(cell_size)
    halos = [member_halo(m, params["members"], cell, f) for m in _members(MEMBERS)]
    reach_m = params.get("refine_reach_m", REACH_M)
    reach = (max(halos) + continuation_cells(cell, reach_m) + 2 + refine_halo(cell, reach_m, ALONG_GROUND)
             + regions_halo(int(params.get("region_max_cells", 0))) + ROOF_EDGE_CELLS + 2 * int(params["support_cells"])
             + banks_halo(*bank_scales(params["members"], params.get("region_width_m", 0.0), cell)) + 2
             + (disputed_bumps_reach(cell) + STEP_TOP_REACH + 2 if DISPUTED_BUMPS else 0)
             + (raised_edge_reach(cell) if RAISED_EDGE_GROUND else 0))
    a = max(alignment(h // f) for h in halos) * f      # the members' alignment on the coarse grid, in cells
    return -(-reach // a) * a


def _as_bool(a, shape, name):
    if a is None:
        return None
    a = np.asarray(a)
    if a.shape != shape:
        raise ValueError(f"{name} has shape {a.shape} but the DSM has {shape}: rasterise it on the DSM's grid.")
    a = a.astype(bool, copy=False)
    return a if a.any() else None


def _uniform(a, size):
    """``ndimage.uniform_filter(a, size, mode="reflect")`` of a 2-D float32 array, bit for bit:
    SciPy's pass down the columns (:func:`.common.running_mean_down`) then its pass along the rows, in
    place, as SciPy runs them."""
    out = np.empty(a.shape, np.float32)
    if size <= 1:
        out[...] = a
        return out
    running_mean_down(a, size, out)
    return ndimage.uniform_filter1d(out, size, axis=1, mode="reflect", output=out)


def _box_mean(a, r, valid, all_valid):
    """Mean of ``a`` over the valid cells of a (2r+1)^2 window (reflected at the raster's edges)."""
    size = 2 * r + 1
    if all_valid:
        return _uniform(a.astype(np.float32, copy=False), size)
    num = _uniform(np.where(valid, a, 0).astype(np.float32), size)
    den = _uniform(valid.astype(np.float32), size)
    return num / np.maximum(den, 1e-6)


def _select(pick, a, b, out):
    """``where(pick, a, b)`` of float32 arrays, bit for bit, with ``pick`` 0 or all bits (uint32)."""
    ai, bi = a.view(np.uint32), b.view(np.uint32)
    d = np.bitwise_xor(ai, bi)
    np.bitwise_and(d, pick, out=d)
    np.bitwise_xor(bi, d, out=out.view(np.uint32))
    return out


def confidence_map(z, mask, dtm, ground_votes, n_members, tolerance_m, support_cells, progress=None):
    """Per-cell confidence 0-100 (uint8, 255 nodata) of a ground / object decision.

    Parameters
    ----------
    z, dtm : ndarray, 2-D float32
        The DSM and its DTM (equal at ground cells); ``dtm`` may be a ``concurrent.futures.Future``
        of it (the terms that do not need it are computed while it is being filled).
    mask : ndarray of uint8
        The decision: 0 ground, 1 object, 2 low outlier, 255 nodata.
    ground_votes : ndarray of uint8
        How many of the ``n_members`` members said ground.
    tolerance_m : float
        The decision threshold ``t`` (metres).
    support_cells : int
        Radius of the support window (cells).
    progress : callable, optional
        ``progress(fraction)`` between the terms; may raise ``Cancelled``.

    Returns
    -------
    ndarray of uint8
        ``100 (a + m + s) / 3`` (see the module's docstring).
    """
    valid = mask != NODATA
    ground = mask == GROUND
    # every term in float32 with the same operations as the formulas above, in place (few
    # full-size temporaries); the agreement takes one of 2 (n + 1) values: a table, indexed.
    # The terms without the DTM first: ``dtm`` may still be being filled (a Future)
    n = float(n_members)
    votes = np.asarray(ground_votes, np.uint8)
    top = max(int(n_members), int(votes.max()) if votes.size else 0) + 1
    v = np.arange(top, dtype=np.float32)
    half = n / 2.0
    table = np.clip((np.concatenate([n - v, v]) - half) / (n - half), 0.0, 1.0)   # [object: n - v, ground: v]
    all_valid = bool(valid.all())
    # the two box means are the only terms that need whole arrays; the rest runs in bands of rows whose
    # temporaries stay in the cache (raster-sized ones cost the kernel zeroing their pages)
    share = _box_mean(ground.astype(np.float32), int(support_cells), valid, all_valid)
    if isinstance(dtm, Future):
        dtm = dtm.result()
    report(progress, 0.35)
    t = max(float(tolerance_m), 1e-3)
    zz = np.asarray(z, np.float32) if all_valid else np.where(valid, z, 0.0).astype(np.float32)
    dd = np.asarray(dtm, np.float32) if all_valid else np.where(valid, dtm, 0.0).astype(np.float32)
    m = _box_mean(dd, 1, valid, all_valid)                       # ground: the local mean of the DTM
    report(progress, 0.6)
    out = np.empty(mask.shape, np.uint8)
    rows = max(1, _BAND_CELLS // max(1, mask.shape[1]))
    for r0 in range(0, mask.shape[0], rows):
        report(progress, 0.6 + 0.4 * r0 / mask.shape[0])
        b = slice(r0, min(mask.shape[0], r0 + rows))
        _confidence_band(ground[b], votes[b], table, top, share[b], zz[b], dd[b], m[b], t, out[b])
    out[~valid] = NODATA
    return out


def _confidence_band(ground, votes, table, top, share, zz, dd, m, t, out):
    """``100 (a + m + s) / 3`` on a band of rows (the formulas of :func:`confidence_map`), into ``out``;
    ``share`` and ``m`` (the box means) are overwritten."""
    key = ground.astype(np.uint16)
    key *= top
    key += votes
    a = table.take(key)                                          # n agreeing: 1, bare majority of 3: 1/3
    # the class's choices by bit masks (a boolean ``where`` costs 5-10 elementwise operations),
    # clips by maximum / minimum (the same values, NaN kept, 4x faster than np.clip)
    one = ground.view(np.uint8).astype(np.uint32)                # 1 at ground
    pick = np.negative(one)                                      # all bits at ground, none elsewhere
    s = np.subtract(1.0, share)
    _select(pick, share, s, out=s)                               # the share of the cell's own class
    _select(pick, m, dd, out=m)                                  # object: the DTM under it
    np.subtract(zz, m, out=m)
    np.abs(m, out=m)
    np.divide(m, t, out=m)
    np.subtract(m, 1.0, out=m)                                   # object: |z - DTM| / t - 1
    np.left_shift(one, 31, out=one)
    np.bitwise_xor(m.view(np.uint32), one, out=m.view(np.uint32))   # ground: 1 - |z - mean| / t (exact negation)
    np.maximum(m, 0.0, out=m)
    np.minimum(m, 1.0, out=m)
    np.add(a, m, out=a)
    np.add(a, s, out=a)
    np.multiply(a, 100.0, out=a)
    np.divide(a, 3.0, out=a)
    np.rint(a, out=a)
    np.maximum(a, 0, out=a)
    np.minimum(a, 100, out=a)
    out[...] = a.astype(np.uint8)


def _fill_dtm(z, holes, valid, progress):
    """The DTM: ``z`` with the ``holes`` filled (:func:`.fill.fill_gaps`), NaN off ``valid``."""
    dtm = fill_gaps(z, fill=holes, progress=progress) if holes.any() else z.astype(np.float32, copy=True)
    dtm[~valid] = np.nan
    return dtm


def _disputed_bumps(z, mask, ground_votes, n, need, tops, spared, slope_ground, cell, tolerance_m, edge_m, slope,
                    jump_m=None):
    """The vote's ground standing above the undisputed ground's plane (:func:`.dtm_refine.find_disputed_bumps`).

    The candidates are the vote's own ground (``need`` votes or more: not the cells the continuations gave back, a
    step's top or a bank, nor the step tops and banks the refinement spared) that the slope-following member keeps
    (an opening with a flat window rests on the terrain uphill and lowers a shrub ``h`` high reaching ``w`` up a
    slope ``g`` by ``max(0, h - g w)`` only) and another member rejects. The plane's ground is every member's
    ground the refinement left, but for the step tops and banks it spared (where the ground bends). The least
    height above the plane (and above each bracketing line) is the decision threshold ``t``, the members' own on
    flat ground: what stands less above the ground's plane every member may keep (a floor of three standard
    deviations of one height about a smooth surface, the edge tolerance over ``sqrt(6)``, let the bumps of bare
    ground and ISPRS 21's bank under trees through: bare terrain 0.259 -> 0.267 %, matrix half B 2.04 -> 2.05).
    Found cells on smooth ground stay ground
    (:func:`.dtm_refine.find_smooth` at ``2 t`` on the voted ground, as the refinement has it, and at the edge
    tolerance on the candidates themselves: a raised level, a platform, is as smooth as ground, vegetation is
    not), and so do the tops of steps (:func:`.dtm_refine.find_step_tops`, as the refinement spares them) and the
    cells on a straight line of ground continuing them both ways (:func:`.dtm_refine.find_level_lines`, as the
    refinement spares its bracketed cells: a platform between tracks, one cell of ground wide between its
    edges). The bracketing lines read the undisputed ground on the candidate's own level only (``jump_m``,
    RASCOR's level change: the ground below a retaining wall is not the ground of the strip along its top).
    """
    kept = (mask == GROUND) & (ground_votes >= need) & ~tops
    if spared is not None:
        kept &= ~spared
    # the plane's ground: every member's, still ground after the refinement, neither a step's top nor a bank
    anchors = kept & (ground_votes == n)
    if slope_ground is not None:
        kept &= slope_ground
    bumps = find_disputed_bumps(z, kept, anchors, cell, tolerance_m=tolerance_m, jump_m=jump_m)
    if bumps.any():
        g = mask == GROUND
        bumps &= ~find_smooth(z, bumps, SMOOTH_RATIO * tolerance_m, ground=g)
        bumps &= ~find_smooth(z, bumps, edge_m, ground=kept & ~anchors)
        bumps &= ~find_step_tops(z, bumps, g, tolerance_m=edge_m, step_m=SMOOTH_RATIO * tolerance_m,
                                 smooth_m=SMOOTH_RATIO * tolerance_m, along_slope=slope, cell_size=cell)
    if bumps.any():
        bumps &= ~find_level_lines(z, mask == GROUND, bumps, cell, tolerance_m=tolerance_m,
                                   reach_m=LEVEL_LINE_M, min_cells=LEVEL_LINE_CELLS)
    return bumps


def _raised_edge_ground(z, mask, voted, members, cell, tolerance_m, edge_m, pool=None):
    """The vote's ground beside an object standing above most of the ground of its level around it
    (:func:`.dtm_refine.find_raised_edge_ground`, :data:`RAISED_EDGE_GROUND`), but for a step's top and a cell on a
    straight line of ground (the guards of :func:`_disputed_bumps`: a terrace's edge beside a house at its back
    stands above the ground below the terrace, a platform's edge above the tracks). ``pool``: threads that may take
    some of its planes' bands and rings' chunks (the same result)."""
    g = mask == GROUND
    jump = float(members[LEVEL_MEMBER]["jump_m"]) if LEVEL_MEMBER in members else float("nan")
    edge = find_raised_edge_ground(z, g, g & voted & touching((mask == OBJECT) | (mask == LOW)), cell,
                                   tolerance_m=edge_m, level_m=jump if np.isfinite(jump) else None, pool=pool)
    if edge.any():
        edge &= ~find_step_tops(z, edge, g, tolerance_m=edge_m, step_m=SMOOTH_RATIO * tolerance_m,
                                smooth_m=SMOOTH_RATIO * tolerance_m, along_slope=refine_slope(members), cell_size=cell)
    if edge.any():
        edge &= ~find_level_lines(z, g, edge, cell, tolerance_m=tolerance_m, reach_m=LEVEL_LINE_M,
                                  min_cells=LEVEL_LINE_CELLS)
    return edge


def filter_dtm(z, cell_size, *, members, tolerance_m, support_cells, refine_reach_m=REACH_M, edge_tolerance_m=None,
               line_tolerance_m=None,
               region_width_m=0.0, region_max_cells=0, object_areas=None, ground_areas=None, breaklines=None,
               coarse_factor=1, workers=1, progress=None):
    """Ground / object mask, DTM and confidence by the majority of independent filters.

    Parameters
    ----------
    z : array_like, 2-D
        The DSM (NaN nodata).
    cell_size : float or (float, float)
        Metres.
    members : dict
        ``{member name: complete parameters}`` (from :func:`resolve_dtm_params`).
    tolerance_m : float
        Decision threshold of the confidence's margin, metres.
    support_cells : int
        Radius of the confidence's support window, cells.
    refine_reach_m : float
        Length of the refinement's floors, metres.
    edge_tolerance_m : float, optional
        Tolerance of the refinement's edge test, metres (at most ``tolerance_m``; None: ``tolerance_m``).
    line_tolerance_m : float, optional
        Tolerance of the edge test along one line (:func:`.fill.find_edge_spikes`), metres (at least the
        edge tolerance; None: not looked for).
    region_width_m, region_max_cells : float, int
        Voted ground regions wider than ``region_width_m`` and spanning at most
        ``region_max_cells`` cells, standing on steps above the ground around, become objects
        (:func:`.dtm_regions.find_raised_regions`; ``region_max_cells`` 0: not looked for).
    object_areas, ground_areas, breaklines : ndarray of bool, optional
        Forced object cells (the ground under them interpolated), forced ground cells, cells
        crossed by a break line.
    coarse_factor : int
        The members run on the lowest cell of each ``coarse_factor x coarse_factor`` block, their decisions
        expanded to every cell (:mod:`.dtm_coarse`; 1: on the DSM itself).
    workers : int
        Threads the members run in, side by side, and the DTM is filled in beside the confidence (1: one
        after the other; the same result).
    progress : callable, optional

    Returns
    -------
    FilterResult
        ``mask``, ``dtm`` (filled), ``extras["confidence"]`` and ``info`` (each member's
        share of object cells, the vote's agreement, the overrides applied).
    """
    z = as_surface(z)
    cell = as_cell_size(cell_size)
    shape = z.shape
    objects = _as_bool(object_areas, shape, "object_areas")
    known_ground = _as_bool(ground_areas, shape, "ground_areas")
    bl = _as_bool(breaklines, shape, "breaklines")
    valid = np.isfinite(z)
    nvalid = max(1, int(np.count_nonzero(valid)))
    meths = _members(members)
    ground_votes = np.zeros(shape, np.uint8)
    slope_ground = None
    level_ground = None
    steep_ground = None
    low_votes = np.zeros(shape, np.uint8)
    object_votes = np.zeros(shape, np.uint8)
    line_decision = None
    info = {}
    f = int(coarse_factor)
    grid = CoarseGrid(z, cell, f, tolerance_m, refine_slope(members)) if f > 1 else None
    zm, cm = (z, cell) if grid is None else (grid.zc, grid.cell)
    blm = coarsen_flags(bl, f, shape)
    if grid is not None:
        info["coarse_rule"] = (
            "the members ran on the lowest cell of each {f} x {f} block ({:g} m cells, coarsening factor f = {f}); "
            "a cell of a block they call ground standing more than {:.3f} m above the block's lowest cell and {:g} m "
            "above the highest ground block around is their object, a cell of a block they reject within {:.3f} m of "
            "the lowest ground block around and not {:g} m above the highest is their ground").format(
                max(cm), grid.allow, tolerance_m, grid.allow_near, tolerance_m, f=f)
    # the members are independent reads of z: with workers > 1 they run side by side (numpy
    # and SciPy release the GIL in their array work), each result taken in the members' order,
    # so the vote, the counts and the info are those of one after the other
    shares = BlockProgress(sub_progress(progress, 0.0, 0.8), len(meths))

    pool = None

    def run_member(i):
        meth = meths[i]
        aux = {"breaklines": blm} if meth.name == BREAKLINE_MEMBER and bl is not None else {}
        if meth.name in SHARING_MEMBERS and pool is not None:
            aux["pool"] = pool
        mk = np.asarray(meth.run(zm, cm, progress=shares.of_block(i), **members[meth.name], **aux).mask, np.uint8)
        return mk if grid is None else grid.expand_mask(mk)

    def tally(i, mk):
        nonlocal line_decision, slope_ground, level_ground, steep_ground
        meth = meths[i]
        g = mk == GROUND
        np.add(ground_votes, g, out=ground_votes)
        np.add(low_votes, mk == LOW, out=low_votes)
        np.add(object_votes, mk == OBJECT, out=object_votes)
        if meth.name == BREAKLINE_MEMBER and bl is not None:
            line_decision = mk
        if meth.name == SLOPE_MEMBER:
            slope_ground = g
        if meth.name == LEVEL_MEMBER:
            level_ground = g
        if meth.name == STEEP_MEMBER:
            steep_ground = g
        info[f"{meth.name}_object_share"] = float(np.count_nonzero(valid & ~g)) / nvalid

    if workers <= 1:
        for i in range(len(meths)):
            tally(i, run_member(i))
    else:
        with ThreadPoolExecutor(max_workers=min(int(workers), len(meths))) as pool:
            # the longest first (RASCOR's sequence), so the others share the second thread; the thread RASCOR
            # leaves takes the geodesic member's dilation steps not yet begun (SHARING_MEMBERS)
            order = sorted(range(len(meths)), key=lambda i: meths[i].name != BREAKLINE_MEMBER)
            futures = {i: pool.submit(run_member, i) for i in order}
            try:
                for i in range(len(meths)):
                    tally(i, futures[i].result())
            except BaseException as exc:
                if shares.error is None:
                    shares.error = exc               # the running members stop at their next report
                raise
    report(progress, 0.8)                           # the vote's stages below: seconds on 16 Mcells, each reports
    n = len(meths)
    need = n // 2 + 1
    info["rule"] = f"ground where at least {need} of the {n} members say ground"
    mask = np.full(shape, OBJECT, np.uint8)          # the vote, in uint8 (no int64 temporaries)
    mask[low_votes >= need] = LOW
    mask[ground_votes >= need] = GROUND
    low_votes = None                                # freed
    # the voted ground the level member rejects, and that another member calls an object (a raised object; a
    # low outlier is not one), judged after the refinement on levels with a top: find_detached_levels
    dissent = None if slope_ground is None or level_ground is None else ~level_ground
    top_dissent = None if dissent is None else object_votes > 0
    level_ground = object_votes = None              # freed
    # with workers > 1 a second thread takes some of the lines' directions below, of the banks' chunks of cells and
    # of the refinement's bands of rows and chunks of cells (the same result); shut down after the refinement
    helper = ThreadPoolExecutor(max_workers=1) if workers > 1 else None
    # the slope-following member's lone ground on smooth ground continuing the undisputed ground (dtm_refine)
    if slope_ground is not None:
        reach_cells = continuation_cells(cell, refine_reach_m)
        disputed = (mask == OBJECT) & slope_ground
        if steep_ground is not None:
            # the steep member's lone ground where the DSM is steeper than the opening's slope allowance
            lone = (mask == OBJECT) & steep_ground & ~slope_ground
            if lone.any():
                at = np.flatnonzero(lone)
                lone.ravel()[at] = cell_slopes(z, cell, lone) > float(members[SLOPE_MEMBER].get("slope", np.inf))
                disputed |= lone
            info["steep_disputed_cells"] = int(np.count_nonzero(lone))
            del lone
        continued = continue_ground(z, disputed, mask == GROUND, ground_votes == n,
                                    height_m=SMOOTH_RATIO * tolerance_m, reach_cells=reach_cells)
        report(progress, 0.802)
        # the upper edges of steps in the ground: on the straight continuation of the undisputed ground; every
        # object of the vote is a candidate, not only the slope member's lone ground: at a step's top the three
        # members may all reject the ground (their windows straddle the step), and the test's own evidence (three
        # undisputed cells in a line continuing to the cell, the ground dropping beyond it) is what tells a step's
        # top from an object's edge (STEP_TOPS_OF_ALL_OBJECTS)
        candidates = (mask == OBJECT) if STEP_TOPS_OF_ALL_OBJECTS else disputed
        lined = continue_lines(z, candidates & ~continued, ground_votes == n, reach_cells=reach_cells,
                               tolerance_m=tolerance_m if edge_tolerance_m is None else edge_tolerance_m,
                               step_m=SMOOTH_RATIO * tolerance_m, ground=(mask == GROUND) | continued,
                               along_slope=refine_slope(members), cell_size=cell, pool=helper)
        report(progress, 0.806)
        mask[continued] = GROUND
        mask[lined] = GROUND
        info["continued_line_rule"] = (
            "{} cells: the vote's objects within {:.3f} m of the straight "
            "continuation of three cells in a line every member calls ground along a row, column or diagonal, "
            "with the ground beyond them dropping below that line (the upper edge of a wall or a cliff in the "
            "ground), or between two such ground cells on a step's face, are ground").format(
                int(np.count_nonzero(lined)), tolerance_m if edge_tolerance_m is None else edge_tolerance_m)
        del lined, disputed
        info["continued_ground_share"] = float(np.count_nonzero(continued)) / nvalid
        info["continued_ground_rule"] = (
            "{} cells: the vote's objects the {} member takes as ground, on smooth ground (no second difference "
            "above {:g} m) joined within {} cells to ground every member agrees on, are ground").format(
                int(np.count_nonzero(continued)), SLOPE_MEMBER, SMOOTH_RATIO * tolerance_m, reach_cells)
        del continued, steep_ground
    # the vote's objects on banks rising from the voted ground, no steeper than earth stands, away from the top of
    # a wall (an embankment, a dike, a ramp, a cut's sides; not a deck or a roof reached up a ramp): dtm_refine
    reach_b, wall_b = bank_scales(members, region_width_m, cell)
    bump_m = bump_tolerance(line_tolerance_m, tolerance_m)
    bump_b = min(reach_b, max(1, int(round(0.5 * BUMP_SPAN_M / min(cell)))))
    banked = continue_banks(z, mask == OBJECT, mask == GROUND, cell, tolerance_m=tolerance_m,
                            smooth_m=SMOOTH_RATIO * tolerance_m, reach_cells=reach_b, wall_cells=wall_b,
                            bump_m=bump_m, bump_cells=bump_b, pool=helper)
    report(progress, 0.81)
    mask[banked] = GROUND
    spared = banked if SPARE_BANKS else None
    info["banked_ground_share"] = float(np.count_nonzero(banked)) / nvalid
    info["banked_ground_rule"] = (
        "{} cells: the vote's objects smooth along {} of their 4 lines (second difference at most {:g} m), joined "
        "to the voted ground within {} cells by steps rising at most {:g} times their length plus {:g} m (a bank of "
        "earth, not a wall), no nearer than {} cells to the top of a wall continuing such cells straight (a "
        "deck's or a roof's edge), filling the side of that square with such cells (a long bank, not a car) and "
        "not standing more than {:.3f} m above the ground interpolated from both sides within {} cells along all "
        "four lines (a shrub on the bank), are ground").format(
            int(np.count_nonzero(banked)), BANK_SMOOTH_LINES, SMOOTH_RATIO * tolerance_m, reach_b, BANK_SLOPE,
            tolerance_m, wall_b, bump_m, bump_b)
    del banked
    # low objects every member kept: voted ground standing above lower ground on both sides (dtm_refine); with
    # workers > 1 the second thread takes some of its bands of rows and chunks of cells (the same result)
    try:
        mask, refined = refine_ground(z, mask, cell, tolerance_m=tolerance_m, slope=refine_slope(members),
                                      reach_m=refine_reach_m, edge_tolerance_m=edge_tolerance_m,
                                      line_tolerance_m=line_tolerance_m, band_tolerance_m=edge_tolerance_m,
                                      along_ground=ALONG_GROUND, along_steps=True, level_lines=LEVEL_LINES,
                                      spared=spared, pool=helper,
                                      progress=sub_progress(progress, 0.81, 0.82))
    finally:
        if helper is not None:
            helper.shutdown()
    report(progress, 0.82)                          # the refinement's planes and floors: seconds on 16 Mcells
    tops = refined.pop("step_tops")
    info.update(refined)
    if DISPUTED_BUMPS:
        jump = float(members[LEVEL_MEMBER]["jump_m"]) if LEVEL_MEMBER in members else float("nan")
        bumps = _disputed_bumps(z, mask, ground_votes, n, need, tops, spared, slope_ground, cell, tolerance_m,
                                refined["refine_edge_tolerance_m"], refine_slope(members),
                                jump_m=jump if np.isfinite(jump) else None)
        mask[bumps] = OBJECT
        info["disputed_bump_rule"] = (
            "{} cells: the vote's ground the {} member keeps and another rejects, standing above the plane of the "
            "ground every member agrees on within {:g} m by more than three standard deviations of that ground about "
            "its plane, its rise over one cell and {:g} m (the decision threshold), above the straight line between "
            "that ground on its own level (no level change of {:g} m between them) along every row, column or "
            "diagonal bracketing it (at least two) by as much, with no such ground within two cells as high above "
            "the plane, and neither smooth, a step's top nor on a straight line of ground, are objects (low "
            "vegetation on a slope)").format(int(np.count_nonzero(bumps)), SLOPE_MEMBER, BAND_PLANE_HALF_M,
                                             tolerance_m, jump)
        del bumps
    slope_ground = None
    info["edge_tolerance_rule"] = (
        "voted ground at an object's edge standing more than {:.3f} m above every straight continuation of the "
        "ground beside it is an object: three standard deviations of that continuation on ground (sqrt(6) times "
        "the spread of ground heights from the ground's noise and the spacing of independent heights on the "
        "terrain's slope), at most the decision threshold {:g} m").format(refined["refine_edge_tolerance_m"],
                                                                          tolerance_m)
    if refined["refine_band_removed_share"] > 0:
        info["raised_band_rule"] = (
            "{:.2%} of the voted ground: cells of the band of ground along the objects' edges standing more than "
            "{:.3f} m (the edge tolerance) and at most {:g} m (the decision threshold) above the plane of the "
            "ground beyond the band within {:g} m are objects (low vegetation along a crown's or a hedge's "
            "edge)").format(refined["refine_band_removed_share"], refined["refine_band_tolerance_m"], tolerance_m,
                            BAND_PLANE_HALF_M)
    # raised regions wider than the vote's windows: voted ground standing on steps above the ground around;
    # with workers > 1 found in a second thread while the detached levels below (which read the same mask,
    # neither changing it) are looked for
    region_args = (z, mask, cell)
    region_kw = dict(tolerance_m=tolerance_m, min_width_m=region_width_m, max_cells=region_max_cells)
    regions = None
    if workers > 1 and dissent is not None:
        regions = ThreadPoolExecutor(max_workers=1)
        raised = regions.submit(find_raised_regions, *region_args, **region_kw)
    else:       # in this thread: a report after each of its scales (QA 20), the bar rising
        raised = find_raised_regions(*region_args, **region_kw, progress=sub_progress(progress, 0.82, 0.835))
    try:
        # raised levels only the level member rejects, cut by level changes from the undisputed ground
        jump = float(members[LEVEL_MEMBER]["jump_m"]) if dissent is not None else None
        detached = None if dissent is None else find_detached_levels(
            z, mask == GROUND, dissent, ground_votes == n, cell, jump_m=jump, slope=refine_slope(members),
            max_cells=region_max_cells, top_dissent=top_dissent, plane_m=0.5 * tolerance_m)
        report(progress, 0.84)
        if regions is not None:
            raised = raised.result()
    finally:
        if regions is not None:
            regions.shutdown()
    raised, decisions = raised
    dissent = top_dissent = None                    # freed
    if detached is not None:
        mask[detached] = OBJECT
        info["detached_level_share"] = float(np.count_nonzero(detached)) / nvalid
        info["detached_level_rule"] = (
            "{} cells: voted ground the {} member rejects, or another member calls an object on a level with a top "
            "(a cell whose 8 neighbours lie on it), in levels (cut where a cell stands more than {:g} m plus the "
            "slope allowance above a neighbour) holding no ground every member agrees on, are "
            "objects").format(int(np.count_nonzero(detached)), LEVEL_MEMBER, jump)
    mask[raised & valid] = OBJECT
    info["raised_region_cells"] = int(np.count_nonzero(raised & valid))
    # a step's top the refinement spared on a level found to be a roof (a raised region, a detached level) is the
    # roof's edge: within ROOF_EDGE_CELLS of it, an object too
    roofs = raised if detached is None else raised | detached
    del detached
    if tops.any() and roofs.any():
        edge = tops & (mask == GROUND) & ndimage.binary_dilation(roofs, np.ones((3, 3), bool),
                                                                  iterations=ROOF_EDGE_CELLS)
        mask[edge] = OBJECT
        info["roof_edge_cells"] = int(np.count_nonzero(edge))
    del tops, roofs
    if RAISED_EDGE_GROUND:
        # the vote's ground at an object's edge standing above most of the ground around it (dtm_refine)
        disputed = (ground_votes >= need) & (ground_votes < n)
        # with workers > 1 a second thread takes some of its planes' bands and rings' chunks (the same result)
        edge_pool = ThreadPoolExecutor(max_workers=1) if workers > 1 else None
        try:
            edge_ground = _raised_edge_ground(z, mask, disputed, members, cell, tolerance_m,
                                              refined["refine_edge_tolerance_m"], pool=edge_pool)
        finally:
            if edge_pool is not None:
                edge_pool.shutdown()
        del disputed
        mask[edge_ground] = OBJECT
        info["raised_edge_rule"] = (
            "{} cells: the vote's ground beside an object whose height above the continuations of the ground's "
            "plane from the ground cells of its level within {:g} m has a median over {:.3f} m (the edge tolerance, "
            "with where the heights lie in their cells on the plane's slope), neither a step's top nor on a "
            "straight line of ground, are objects").format(
                int(np.count_nonzero(edge_ground)), EDGE_RING_M, refined["refine_edge_tolerance_m"])
        del edge_ground
    report(progress, 0.845)
    info["raised_regions"] = [describe_region(d) for d in decisions]
    if line_decision is not None:
        # within the other members' reach of a break line, only RASCOR kept to one side
        reach = max(member_halo(m, members, cell, f) for m in meths if m.name != BREAKLINE_MEMBER)
        near = ndimage.distance_transform_edt(~bl) <= max(1, reach // 2)
        mask[near] = line_decision[near]
        info["breakline_band_share"] = float(np.count_nonzero(near & valid)) / nvalid
        ground_votes = np.where(near, np.where(line_decision == GROUND, n, 0), ground_votes).astype(np.uint8)
    if objects is not None:
        mask[objects] = OBJECT
        info["object_area_cells"] = int(np.count_nonzero(objects & valid))
    if known_ground is not None:
        mask[known_ground] = GROUND
        info["ground_area_cells"] = int(np.count_nonzero(known_ground & valid))
    mask[~valid] = NODATA
    report(progress, 0.85)
    holes = (mask == OBJECT) | (mask == LOW)
    dtm = None
    # with workers > 1 the DTM is filled in a second thread while the confidence computes its terms without it
    pool = ThreadPoolExecutor(max_workers=1) if workers > 1 and holes.any() else None
    try:
        if (valid & ~holes).any():          # a window of objects only (a block inside a roof): no DTM here
            args = (z, holes, valid, sub_progress(progress, 0.85, 0.93))
            dtm = _fill_dtm(*args) if pool is None else pool.submit(_fill_dtm, *args)
        else:
            info["warning"] = "no ground cell in this window: its DTM is left empty"
        if pool is None:
            report(progress, 0.93)
        conf = confidence_map(z, mask, z if dtm is None else dtm, ground_votes, n, tolerance_m, support_cells,
                              progress=sub_progress(progress, 0.93, 1.0))
        if isinstance(dtm, Future):
            dtm = dtm.result()
    finally:
        if pool is not None:
            pool.shutdown()
    for forced in (objects, known_ground):
        if forced is not None:
            conf[forced & valid] = 100
    unanimous = (ground_votes == 0) | (ground_votes == n)
    info["unanimous_share"] = float(np.count_nonzero(unanimous & valid)) / nvalid
    info["low_confidence_share"] = float(np.count_nonzero(conf < 50)) / nvalid
    report(progress, 1.0)
    return FilterResult(mask=mask, dtm=dtm, extras={"confidence": conf}, info=info)


def _run(z, cell_size, progress=None, input_description=None, **params):
    """Registry entry: the input's description is for the log (it is in the parameters used)."""
    return filter_dtm(z, cell_size, progress=progress, **params)


def widen_dtm_params(params, given, overview, cell_size):
    """``Method.widen`` of the vote: each member's own, on its parameters (the user gives the
    members nothing, so each member's derived heights are widened)."""
    members = dict(params["members"])
    for meth in _members(MEMBERS):
        if meth.widen is not None and meth.name in members:
            members[meth.name] = meth.widen(members[meth.name], {}, overview, cell_size)
    return dict(params, members=members)


METHOD = Method(
    name="dtm",
    bytes_per_cell=104.0,      # measured 81.5 (speed.py, 16 Mcells), 91.4 (49.6 Mcells windows); 99-102 (16 Mcells)
    #                            with the morphological member's slope maps (2026-11-29); 114-118 with its
    #                            continuing slopes (2026-11-30); 96.5 with their one buffer and the top read at its
    #                            cells (113.4 for main back to back, 2026-11-30); 98.4 with the level lines and
    #                            spared banks (session 24)
    run=_run,
    resolve=resolve_dtm_params,
    halo=dtm_halo,
    widen=widen_dtm_params,
    extras={"confidence": (np.uint8, 1, NODATA)},
    extra_bands={"confidence": ("confidence (%)",)},
    params=(),
    threads=True,
    title="DTM from DSM (recommended)",
    description=(
        "<p>The filter to start with: no parameter to choose. Three filters built on different principles "
        "(the progressive morphological opening, RASCOR's sequence of local tests, the gradual geodesic "
        "dilation), each with the defaults it derives from the data (RASCOR's random error measured on the "
        "DSM's ground-level cells, not on a canopy's crowns), vote on every cell; a cell is ground "
        "where most of them say so, or where the opening (whose threshold follows the slope) alone says so on "
        "smooth ground joined to ground every member agrees on (a terrace's edge, an embankment, a ramp: an "
        "object's edge is a step and stops it; the reconstruction's lone ground too where the DSM is steeper than "
        "the opening's slope allowance, which cuts such ground by construction), or, whatever the members say, on "
        "the straight continuation of such ground with the ground "
        "dropping beyond it (the upper edge of a retaining wall, a quarry's bench or a cliff), or on banks: cells "
        "smooth along three of their four lines joined to the voted ground by steps no steeper than earth stands "
        "(35 degrees) plus the decision threshold, away from the top of a wall such cells lead to and long (an "
        "embankment, a dike, a ramp or a cut's sides, which every member may reject; not a bridge's deck reached up "
        "its ramp nor a car), and not standing above the ground interpolated from both sides along all four lines "
        "by more than three standard deviations of that interpolation on ground (a shrub on a bank: a bank's face "
        "is straight along its contour, its crest level along its length); voted "
        "ground "
        "standing above lower ground on both sides of a line (bushes, "
        "hedges, the bottoms of gaps in a canopy, which every member may keep; the line's reach grows on gentle "
        "terrain, the lower ground's allowance rises along the line at the slope of the ground seen around it, "
        "so a bush on a hillside stands out along the contour, and smooth ground such as a rounded crest, or a "
        "dike's crest beside a tree, is kept, as are the banks given back and cells a straight line of ground "
        "continues both ways for 6 m and at least three cells: a platform, a dike's crest along its length) is then "
        "taken as an object, as is voted ground at an object's edge standing above every straight continuation "
        "of the ground beside it by more than three standard deviations of that continuation on ground (from the "
        "ground's noise and the spacing of its heights on the terrain's slope; wall feet, crown skirts, low "
        "vegetation at a crown's edge), or which the ground continues to from neither side of a line through "
        "it (low vegetation along a crown's edge), both tolerances growing on the banks given back by three "
        "standard deviations of where each height lies in its cell (a bank's face, whose heights on coarse cells "
        "scatter by a cell's rise), or which stands above the plane "
        "of the ground beyond that edge "
        "(fitted over 12 m) by more than that tolerance and at most the decision threshold with no ground within two "
        "cells as high (a rough band of low vegetation whose cells continue each other), but for the upper edges of "
        "steps in the ground (three ground cells on smooth ground continuing to the cell in a line, the ground "
        "beyond dropping by a step: a retaining wall's top beside a house, a platform's edge); so is voted ground "
        "the opening keeps and another member rejects that stands above the plane of the ground every member agrees "
        "on (fitted over 12 m, the slope read on that ground and not across the vegetation) by more than the "
        "decision threshold and three standard deviations of that ground about its plane (Student's t for the "
        "ground cells the window holds) and its rise over one cell, above the straight line between that ground "
        "on its own level (not across a level change: the ground below a retaining wall) along every row, column "
        "or diagonal "
        "bracketing it (at least two) by the threshold, with no such ground within two cells as high above the "
        "plane, neither smooth, a step's top nor on a straight line of ground continuing it both ways (low "
        "vegetation on a slope: an opening with a flat window rests on the terrain uphill and lowers a shrub by its "
        "height less the slope's rise over its width; a platform or a terrace's top is as smooth as ground); so is "
        "a region "
        "wider than the members' windows (a warehouse's "
        "flat roof, or a roof running off the raster, taken as mirrored at its edge; a level cut on two opposite "
        "sides, a terrain step across the raster, reaches too far and is left to the vote) whose outline seen "
        "inside the raster stands on walls down to the ground over more than half its length and which stands "
        "above the ground around it, the regions cut at walls of doubling heights so that a roof of several levels "
        "is one region (a terrace joined to the ground by a bank or a ramp, a plateau or a dam, with banks, stays "
        "ground); so is voted ground that RASCOR alone rejects, or another member alone calls an object where the "
        "level is wider than a step of a slope, on a level cut off by level changes "
        "(RASCOR's jump beyond the terrain's slope allowance) from every cell "
        "all members call ground (a low annex or a lower roof level, which the allowances of the opening and the "
        "reconstruction keep; a tower cut by the raster's edge, which only the opening rejects), or from all but "
        "a few such cells where RASCOR rejects more than half of the level and the level is a lower roof: a plane "
        "(median distance from its least-squares plane at most half the decision threshold) with a top, a quarter "
        "of its outline an object standing a level change above it (a taller part of the building), not cut by "
        "the raster's edge, unless the "
        "level lies below that ground across a level change (a bench of a cliff); so is voted ground one "
        "member rejects beside an object that stands above most of the ground of its level within 2 m (the median "
        "of its heights above the continuations of the ground's plane from those cells) by more than the edge "
        "tolerance and where the heights lie in their cells on that plane, but for a step's top and a cell on a "
        "straight line of ground (low vegetation at a crown's edge on a sparse lidar grid, on which the DTM under "
        "the crown would rest); the DTM is "
        "interpolated under the rest. On cells finer than 1 m the members run on the lowest cell of each block of "
        "1 m or less (a power of two of cells), their decisions brought back to every cell by height tests against "
        "the ground around; the log states the factor. The log gives each member's parameters, "
        "the refinement's reach and edge tolerance, each raised region's decision, the cells of detached levels "
        "and how often the members agreed.</p>"
        "<p>The confidence map (0-100) combines the members' agreement, the cell's distance from the "
        "height threshold, and the share of cells around it with the same class: low values mark where "
        "to look first.</p>"
        "<p>Optional layers: object areas (e.g. building footprints: forced object, ground under them "
        "interpolated), ground areas (polygons or points of known bare ground: forced ground), break lines "
        "(no comparison crosses them; near a line RASCOR, which honours it, decides).</p>"),
)
