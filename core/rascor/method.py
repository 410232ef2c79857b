"""RASCOR's entry in the method registry: :data:`METHOD` (parameters, dialog texts)."""
import numpy as np

from ..methods import Method, Param
from .parameters import check_rascor_given, rascor_halo, resolve_rascor_params, widen_rascor_params
from .sequence import filter_rascor
from .terrain import TERRAIN_CLASSES


def _run(z, cell_size, progress=None, breaklines=None, special_areas=None, **params):
    return filter_rascor(z, cell_size, breaklines=breaklines, special_areas=special_areas,
                         progress=progress, **params)


METHOD = Method(
    name="rascor", run=_run, resolve=resolve_rascor_params, halo=rascor_halo, widen=widen_rascor_params,
    check=check_rascor_given,
    bytes_per_cell=48.0,        # measured 37.6 (benchmarks/speed.py, 16 Mcells, file); 45.9 (2026-11-30)
    extras={"step": (np.uint8, 1, 255)},
    extra_bands={"step": ("RASCOR step that removed the cell (0 kept)",)},
    params=(
        Param("terrain_class", "enum", "auto", "Terrain type choosing the models (mean / "
              "linear / polynomial) and defaults; auto: classed from the DSM (step 1).",
              options=("auto",) + TERRAIN_CLASSES),
        Param("homogeneous", "enum", "auto", "Whether the area is homogeneous; auto: from "
              "step 1 (90 % of 10 m tiles in the area's class). A flat, inhomogeneous area "
              "(embankments, cuts) gets the linear models instead of the mean.",
              options=("auto", "homogeneous", "inhomogeneous")),
        Param("sigma_m", "float", None, "Random error of the DSM in metres; empty: "
              "estimated from the Laplacian residuals (at least 0.1 m).", minimum=0.001,
              maximum=100.0),
        Param("step1_characterise", "bool", True, "Step 1: class the terrain from the DSM "
              "(off: 'rolling' unless a terrain class is given)."),
        Param("step2_height_distribution", "bool", True, "Step 2: remove heights far "
              "outside the height distribution (flat terrain only; skipped otherwise)."),
        Param("step3_neighbour_differences", "bool", True, "Step 3: remove the upper point "
              "of neighbouring pairs differing beyond sigma and the local slope."),
        Param("step4_level_change", "bool", True, "Step 4: remove raised levels between a "
              "jump up and a jump down along X / Y profiles (buildings)."),
        Param("step5_profiles", "bool", True, "Step 5: moving local profiles in X and Y, "
              "short then long, with data snooping."),
        Param("step6_surfaces", "bool", True, "Step 6: moving surfaces (horizontal, "
              "inclined plane or polynomial by terrain class)."),
        Param("step7_prediction", "bool", False, "Step 7: final local least-squares "
              "prediction (optional; always on inside special areas)."),
        Param("second_iteration", "bool", False, "Repeat steps 3, 5, 6, 7 once. Warning "
              "(Jacobsen): removes small vegetation but may generalise the terrain."),
        Param("step3_repeat", "bool", True, "Step 3 once more on the points steps 4-7 left, "
              "without the second iteration: the edge of a crown or a roof that step 3 took for "
              "the toe of a slope (its inner neighbour rising as steeply) is tested again once "
              "the later steps removed that inner neighbour. A test of one cell against its "
              "neighbours at the random error, no moving fit: it does not generalise the terrain (the "
              "foot of a bank whose slope the later steps removed goes too)."),
        Param("spare_continuing_ground", "bool", True, "Give back as ground the objects of steps 5 "
              "and 6 that are smooth ground continuing the ground kept: in an object region longer "
              "than step 6's window, no second difference of their 3 x 3 neighbourhood above twice "
              "step 3's tolerance (read on ground), joined within 12 m to kept ground running further than "
              "the window. Road embankments, ramps "
              "and raised banks that the moving fits take while no jump bounds them (the paper "
              "leaves these to break lines). Also shorter regions of steps 5 and 6 that are ramps: an "
              "inclined plane whose both ends meet the kept ground at its own height, no wall along "
              "its sides."),
        Param("height_min_m", "float", None, "Step 2 lower height limit in metres; empty: "
              "far fence of the height distribution. Used on flat terrain only (the paper's step 2: on "
              "rolling or mountainous terrain the step is skipped, given or not; the log says so).", advanced=True),
        Param("height_max_m", "float", None, "Step 2 upper height limit in metres; empty: "
              "far fence of the height distribution. Used on flat terrain only (the paper's step 2: on "
              "rolling or mountainous terrain the step is skipped, given or not; the log says so).", advanced=True),
        Param("neighbour_k", "float", 3.0, "Step 3 critical value: tolerance = k sigma "
              "sqrt(2) (widened by the terrain slope's rise over one cell) + local slope.",
              minimum=0.5, maximum=20.0, advanced=True),
        Param("terrain_slope", "float", None, "Step 3: terrain slope (rise/run) whose rise over "
              "one cell widens the tolerance: a height lies anywhere inside its cell, so on a "
              "slope its position adds sqrt(1/12) of that rise to its error (coarse cells on "
              "slopes). Empty: the median slope of step 1; 0: the paper's tolerance alone.",
              minimum=0.0, maximum=10.0, advanced=True),
        Param("terrain_bend_m", "float", None, "Steps 3 and 4: the terrain's own second "
              "difference over one cell (m, a Gaussian scale): on cells coarse against the "
              "relief (10-30 m DEMs of hills) the ground bends by metres from one cell to the "
              "next; step 3's tolerance and step 4's jump and smoothness limits widen by k times "
              "it. Empty: the bends of the 20 m block minima scaled to one cell (90th percentile "
              "/ 1.645); 0: the paper's tolerances.", minimum=0.0, maximum=100.0, advanced=True),
        Param("ground_sigma_m", "float", None, "Step 3: the random error of the ground's heights (m), "
              "the noise of the slope beyond a pair on sloping ground, whose second difference has "
              "three times a pair's variance. Empty: the noise of the DSM's ground-level cells, at most "
              "sigma_m (not the crowns' roughness).", minimum=0.001, maximum=10.0, advanced=True),
        Param("jump_m", "float", 2.0, "Step 4 minimum sudden change of level in metres.",
              minimum=0.1, maximum=100.0, advanced=True),
        Param("max_building_m", "float", 120.0, "Step 4 longest raised level removed "
              "(metres); also sets the block halo.", minimum=1.0, maximum=2000.0,
              advanced=True),
        Param("max_hall_m", "float", None, "Step 4 longest hall (metres): a raised level closed by "
              "walls on every side, longer than max_building_m and at most this long, is a building; "
              "empty: the longest such level of the DSM (at most 400 m; none: 0); also sets the block "
              "halo.", minimum=0.0, maximum=2000.0, advanced=True),
        Param("short_profile_m", "float", None, "Step 5 short profile length in metres; "
              "empty: chosen by analysing a sequence of lengths.", minimum=0.1,
              maximum=10000.0, advanced=True),
        Param("long_profile_m", "float", None, "Step 5 long profile length in metres; "
              "empty: the longest of the sequence whose residual scale stays within twice "
              "the shortest's.", minimum=0.1, maximum=10000.0, advanced=True),
        Param("profile_sigma_m", "float", None, "Step 5 standard deviation of a height "
              "about the profile model (m); empty: sigma and the model's error at the long "
              "length on the ground-level surface (20 m block minima).", minimum=0.001,
              maximum=100.0, advanced=True),
        Param("surface_size_m", "float", None, "Step 6 moving-surface window edge in "
              "metres; empty: the shortest of a sequence of sizes covering sqrt(2) x the "
              "width of the objects, as long as the model follows the terrain.", minimum=0.1,
              maximum=10000.0, advanced=True),
        Param("surface_rule", "enum", "objects", "Step 6: how an empty surface size is "
              "derived. objects: the shortest size covering sqrt(2) x the width of the "
              "objects (RASCOR on its own must span its widest objects); residuals: the "
              "longest size before the fits' residual spread grows (the model-selection rule "
              "alone; what the dtm filter asks of its RASCOR member, since the opening and the "
              "reconstruction there remove wide objects).", options=("objects", "residuals"),
              advanced=True),
        Param("surface_sigma_m", "float", None, "Step 6 standard deviation about the "
              "surface (m); empty: sigma and the model's error on the ground-level surface.",
              minimum=0.001, maximum=100.0,
              advanced=True),
        Param("prediction_radius_m", "float", None, "Step 7 neighbourhood radius in "
              "metres; empty: 3 cells.", minimum=0.01, maximum=1000.0, advanced=True),
        Param("prediction_sigma_m", "float", None, "Step 7 standard deviation of the "
              "prediction (m); empty: from the prediction residuals.", minimum=0.001,
              maximum=100.0, advanced=True),
        Param("snooping_k", "float", 4.0, "Critical value of the data snooping in steps "
              "5-7 (standardised residual).", minimum=0.5, maximum=20.0, advanced=True),
        Param("snooping_iterations", "int", 1, "Fits per profile length / direction and "
              "per surface (outliers removed between fits).", minimum=1, maximum=10,
              advanced=True),
        Param("low_weight", "float", 0.02, "Weight factor of points below the reference: "
              "their tolerance is 1/sqrt(weight) wider, so ditches stay while deep low "
              "blunders go (class 2).", minimum=0.001, maximum=1.0, advanced=True),
        Param("fits_per_block", "bool", False, "Step 6: fit surface windows of at least 32 cells "
              "a side once per block of cells (at most 1/16 of the window) and test each cell against the "
              "leave-one-out fit of the window centred on its block: faster, nearly the same tests (what "
              "the dtm filter asks of its RASCOR member).", advanced=True),
    ),
    title="RASCOR sequential filter (Jacobsen 2004)",
    description=(
        "<p>Filters a raster DSM by a sequence of tests, each catching what the others "
        "miss, with parameters determined from an analysis of the DSM (Jacobsen 2004, "
        "program RASCOR): 1 terrain characterisation (flat / rolling / mountainous, "
        "homogeneity), 2 height distribution (flat terrain only), 3 height differences of "
        "neighbours (tolerance from the random error and the local slope), 4 sudden change "
        "of level along X and Y profiles (buildings), 5 moving local profiles short then "
        "long (mean, linear regression or polynomial, with data snooping), 6 moving "
        "surfaces (horizontal, inclined plane or polynomial), 7 optional local prediction. "
        "Points below the reference get a weight factor instead of removal, so ditches and "
        "cuts stay while deep low blunders are removed (class 2). A low blunder must also "
        "lie below every cell within 10 m around it (its own cluster of up to 1 m left out): "
        "where the ground shows only in gaps between crowns or roofs (a closed canopy at "
        "4 m cells), the weight factor alone takes those gaps for blunders; a gap is at the "
        "level of the other gaps around it, a blunder below all of them. Or it lies below "
        "every cell of a level rim just around it (a blunder in open ground, even with "
        "another blunder within 10 m; the crowns around a gap are metres apart).</p>"
        "<p>The moving surface covers sqrt(2) x the width of the objects standing above "
        "the ground level (98 % of their area), so each window holds as much ground as "
        "object: steps 3 and 4 leave pieces of wide objects scattered over their "
        "footprint, which a smaller window keeps as ground. The scales of the profiles and "
        "surfaces are the random error and the model's error on the ground-level surface "
        "(20 m block minima), never the residuals of the DSM that the objects widen. Long "
        "windows cut the shoulders of cuts and embankments: draw break lines there.</p>"
        "<p>The random error sigma is the lower quartile of the whole DSM's Laplacian "
        "residual: the cell-scale roughness that the neighbour and profile tests must pass. "
        "On a closed canopy it measures the crowns, which is what those tests need there; "
        "taken on the ground only, step 3 strips the walls and crown edges before step 4 "
        "can see the level changes (measured in benchmarks/generalise.py). A cell's height "
        "lies anywhere inside the cell: on a slope its position adds the slope's rise over "
        "one cell times sqrt(1/12) to its error, so step 3's tolerance k sqrt(2) sigma "
        "becomes sqrt((k sqrt(2) sigma)^2 + k^2 g^2 / 6), g the local rise beyond the pair "
        "up to the median terrain slope's rise over one cell (steeper rises are walls and "
        "crowns): at 2-4 m cells the same hillside rises 2-4 times more per cell, which "
        "the paper's fixed tolerance took for objects. The position moves a height across the pair's "
        "axis too (along a hillside's contour two lowest points differ by up to a cell's rise); the "
        "gradient's magnitude as g was tried and not adopted: a 24 m DEM of hills hid 20 m boxes "
        "three cells wide, and shrubs on steep slopes passed (synthetic shrubs 2 m highest 18.2 -> "
        "20.8 %). On cells coarse against the relief (10-30 m "
        "DEMs of hills) the ground itself bends by metres from one cell to the next, which steps 3 "
        "and 4 (a second difference against k sqrt(2) sigma, a 2 m jump) took for walls: their "
        "tolerance, jump and smoothness limits widen in quadrature by k times the terrain's bend "
        "(the 90th percentile / 1.645 of the second differences of 20 m block minima scaled to one "
        "cell; 0 where it does not exceed sigma, as at 1-2 m cells): a bare 24 m DEM of hills lost "
        "11.8 % of its cells as objects with the paper's tolerances, 2.2 % with the bend; objects "
        "standing less than those widened limits above such terrain are no longer found. The scaling "
        "to one cell by the square of the block spacing is that of smooth curvature; rough terrain bends at "
        "its ridges and valley lines, whose second differences grow about linearly with the spacing (the "
        "medians of 20 and 40 m block minima on the lidar mountains and the ISPRS hillsides), so on a "
        "mountain at 4 m cells the bend reads 0 and step 3 takes the crests for objects (lidar "
        "hexbin-crop 4 m: 11.8 % total error, 7.5 % with the linear scaling); the linear scaling is not "
        "used because at 1-2 m cells it widens step 3 until vegetation on steep slopes passes (ISPRS 11 "
        "1 m +0.8 points, hexbin-crop 2 m +0.8): a limit of this rule. Empty cells filled from the "
        "nearest point repeat its height, so a slope sampled more sparsely than the grid becomes a "
        "staircase whose risers step 3 takes for objects' edges (ISPRS 61 at 2 m, its embankment's "
        "sides: 7.1 % total error); reading each run of copies as one point fixes that (6.2 %) but "
        "lets low vegetation copied into empty cells pass (ISPRS 11 1 m +0.4 points): also a limit. "
        "On sloping ground (terrain slope > 0) two equal heights beyond a pair measure no slope (a "
        "copy); the slope above the tested point stands for it, and with neither known the pair is "
        "not tested (synthetic sparse houses at 1 m 6.6 -> 2.5 %). The slope beyond the pair is "
        "measured by two heights too: where it is subtracted the test is a second difference, of three "
        "times the pair's variance, and the pair's tolerance took the noise of sloping bare ground for "
        "edges (a plane rising 0.2 m per cell, sigma 0.1 m: 3.4 % of its cells; synthetic bare terrain "
        "2.9 % of its ground). On ground whose slope beyond lies within the terrain's rise plus k sqrt(2) "
        "sigma_g, the tolerance gains that variance, 2 w (k sqrt(2) sigma_g)^2, w = erf(rise / 2 sigma_g) "
        "(0 on level ground: the paper's test; 1 on slopes), sigma_g the noise of the ground-level cells "
        "(ground_sigma_m, at most sigma): bare terrain 2.93 -> 1.81 % of its ground lost, terraces 1 m "
        "12.8 -> 6.1 % (benchmarks/bare.py); synthetic hillside 1 m 11.9 -> 10.1 %, lidar warsaw_small 4 m "
        "3.34 -> 1.91 %. Widening by the whole DSM's sigma, which reads the crowns on a vegetated slope, "
        "was tried: it let low vegetation pass (opengeos 2 m 11.8 -> 14.4 %, ISPRS 11 2 m highest 28.0 "
        "-> 29.4 %). Objects less than the widened tolerance above sloping ground are left to steps 4-7: "
        "on the synthetic steep shrubs (28-38 degrees, where the lowest point's place in its cell makes "
        "the ground's own noise 0.2-0.3 m) 1 m / 2 m highest 12.7 / 18.2 -> 15.5 / 22.7 %; the opengeos "
        "2 m city (ground rising 0.09 m per cell) 11.82 -> 12.65 %, the feet of its crowns: a limit of "
        "this rule. On level ground the paper's test of eight pairs still takes about 0.9 % of pure noise "
        "(bare river banks 1.2-1.8 %).</p>"
        "<p><b>A level cut by the raster's edge</b> (a jump up and the profile's end with no jump "
        "down between: a hall over most of a tile, or a terrace's upper level) is a building when "
        "what is seen of it lies within the longest building, it stands on its jumps over more "
        "than half of its seen outline, and its walls, mirrored at the sides of the raster they "
        "meet, run within twice the longest building: a wall cutting off a corner of the tile runs "
        "twice what is seen, one running across it (a terrain step) three times. A roof running into "
        "the raster's edge at a slant (or an L-shaped one) is met by both walls on the profiles crossing "
        "its far part and by one wall and the edge on those crossing it at the edge: a level meeting the "
        "raster's edge is such a level, too, when its cut runs and the cells the same pass's pairs of "
        "jumps took make most of it, its walls then its cells stepping down by more than the jump (ISPRS "
        "41's station roof, a block running into the tile's corner: 1 m lowest 5.11 -> 4.57 %, with its "
        "empty cells left empty 6.48 -> 5.09 %). The second pass of step 4, which peels nested levels, "
        "looks for levels cut by the edge on the points the first left: a lower roof between a higher one "
        "and the edge is climbed from the ground once the higher one is gone, the cells the first pass took "
        "counting with the pairs (ISPRS 41's corner: 1 m lowest 4.57 -> 3.70 %, 2 m highest 4.96 -> 4.16 "
        "%). A terrace whose houses the first pass took is then mostly taken cells too: a level rising by "
        "more than the jump to the ground left beside it over more than half of its outline lies below "
        "the terrain around it (a terrace below a retaining wall, the terrain continuing upwards) and is "
        "no roof; a lower roof rises only to the higher parts taken before it (synthetic hillside with "
        "retaining walls 1 m lowest / highest, 2 m highest: 10.34 / 10.51 / 10.31 % without this, "
        "9.96 / 10.00 / 9.20 % with it, as with the first pass alone).</p>"
        "<p><b>Vertical drops of the terrain</b> (a quarry bench, a river bank, a terrace wall) "
        "are walls to the paper's steps 3, 5 and 6: the moving profiles and surfaces, pulled down "
        "by the lower level, ate into the upper one (15 % of a quarry of 20 m benches, 7 % beside "
        "vertical river banks). Step 4's level changes that no other jump answers and that run "
        "longer than the longest building (max_building_m) are the terrain's: they serve as break "
        "lines for the steps after it, and step 3, which ran before them and took the top of each "
        "wall (the upper point of each pair), tests those cells again with them where they run "
        "along the wall further than a building: compared with their own level only, they are "
        "ground again (quarry 4.0 -> 0 %, river 1.0 -> 0 %, one 5 m drop 0.5 -> 0 %). Step 4 reads its "
        "profiles on the points step 3 left, so its jump steps over the wall top step 3 took: the "
        "cells between the jump's two points (up to two: the band step 3 takes along a face crossing "
        "the rows at a slant) are the face and belong to its line, which joins the line's two sides "
        "into one along the wall where both sides are ground (three points on a smooth line on each "
        "side), the upper one level (within half the jump, a terrace's tread, a bench) and the cells "
        "between lie between the two levels (the lower edge of a bush on a steep slope, a jump no "
        "other answers, is not joined: ISPRS 11 2 m highest 28.95 % with smooth sides alone, 28.03 "
        "as before with these tests). "
        "Without them each side's line, cut again by every house and hedge on the level, ran shorter "
        "than a building: synthetic terraced hillside (benchmarks/sites.py) 1 m / 2 m lowest point "
        "9.96 / 5.46 -> 6.29 / 3.75 % total error, quarry 6.87 / 6.97 -> 5.71 / 5.02 %. The level "
        "changes are the terrain's whatever lies beside them (step 4's vegetation test is a "
        "building's: bushes at a bank's foot, or the far wall of a trench one cell wide, do not "
        "veto them). They are looked for down to step 3's tolerance (k sqrt(2) sigma, at most "
        "step 4's jump): on coarse cells a bank lower than 2 m drops within one cell, and step 3, "
        "the paper's test of neighbouring points, takes its upper edge for an object's (a river "
        "bank at 4 m cells); at 1 m it spans several cells. A line's pieces that a tree, a hedge or "
        "a gap in the data cut, each running further than half the longest building, are joined "
        "across gaps of up to 4 m (none at 4 m cells and coarser) and measured together: the "
        "retaining walls of a terraced hillside broke into pieces of 85-140 m (synthetic hillside 1 m "
        "12.8 -> 11.9 % total error with the copies above, quarry 1 m 7.9 -> 7.1 %); pieces from 4 m on "
        "joined the edges of vegetation into lines (ISPRS 11 2 m highest 27.9 -> 35.6 %). A face crossing "
        "the profile at a slant, or narrower than a cell, leaves a cell at mid height on it: the drop splits "
        "into two steps of one sign, each within the jump, and the one-step jumps found such a riser in "
        "pieces shorter than a building. Two such steps are a level change when together they exceed the "
        "jump beyond the slope over the same run and both sides are level ground (three heights on a smooth "
        "line at the ground's noise, changing by at most half the jump over the face's run): terraces with "
        "risers of 0.5-2 m at a slant (benchmarks/bare.py) 0.5 / 1 / 2 m 6.12 / 6.08 / 1.36 -> 5.71 / 3.86 / "
        "1.27 % of their ground lost. Without the level sides the edges of crowns on ISPRS 11's steep slope "
        "joined the lines (2 m lowest 10.98 -> 11.94 %, with them 11.06); a face between sloping sides stays "
        "a limit. A face another level change answers within the longest building, or lying between two "
        "jumps that answer each other, is no terrain step (the jumps keep their own pairs), and where the "
        "terrain bends beyond its noise from one cell to the next (terrain_bend_m > 0, a coarse DEM of "
        "hills) no face is read: a height midway down two cells is as likely the terrain's bend (20 m "
        "boxes three cells wide on a 24 m DEM of hills lost 1.4 % of their cells to it). Many lines make "
        "many break-line regions (1655 on the bare terraces at 1 m), each fitted by steps 5 and 6 on its "
        "own points: their bounding boxes are packed into a few mosaics fitted in one pass each (RASCOR "
        "on those terraces: 1.0 s of CPU without the faces; with them 3.5-4.1 s one fit per region, "
        "1.5-1.6 s packed). Drops shorter than "
        "a building, and faces sloping over a few cells (6 m over 3 cells: 13 % of such a "
        "quarry), stay a limit of the paper's rule: draw break lines along them.</p>"
        "<p><b>Raised levels the ground continues onto (step 4)</b>"
        ": a road embankment or a dike crossing a profile rises by a jump and falls by another "
        "within the longest building, as a roof does, where its banks are steep or, sampled by "
        "sparse points, walls; step 4 took its crown for a roof (ISPRS 71, a bridge's ramps and "
        "road embankments, and 61, a dike, lost their ground at 1 and 2 m, lowest and highest "
        "point). In plan a roof is a level cut off by its walls and no longer than the longest "
        "building; a crown runs on and joins the ground without a level change (a ramp, a dike's "
        "end or gentler side). The raised cells whose kept cells join, across neighbouring "
        "heights differing by no more than step 3's tolerance (k sqrt(2) sigma) and less than "
        "half the jump (step 4's own height of a raised point), a part running further than the "
        "longest building are not removed (ISPRS 71 1 m lowest 5.75 -> 3.41 %, 2 m 8.26 -> 4.95; "
        "61 5.17 -> 4.31, 7.32 -> 7.08; opengeos 2 m city 11.46 -> 11.72, DTM RMSE 1.07 -> 1.09 "
        "m: blurred walls of a few roofs join the ground; bareearth:dtm, whose member RASCOR is, "
        "3.15 -> 3.13 % over the generalisation matrix; cost 0.35 s CPU on a 4 Mcells city, 2.35 "
        "-> 2.7 s). Steps 5 and 6 may still take a crown narrower than their windows (see below).</p>"
        "<p><b>Halls longer than the longest building</b> (max_hall_m): step 4's profiles pair a "
        "jump up with a jump down at most max_building_m apart, and a roof longer than that along "
        "both axes (a 200 x 130 m hall, a 120 m block round a courtyard) joins a level longer than a "
        "building, which the rule above keeps as ground. In plan such a roof is a level its walls "
        "close on every side: the cells joined across neighbouring heights within that rule's step "
        "make a part that meets no side of the raster and steps down by more than the jump on more "
        "than half of its outline. A level of the terrain is not closed so: a terrace's or a quarry "
        "bench's rises to the slope above on its uphill side, a plateau or a river bank runs on to "
        "the raster's edge, an embankment's crown comes down to the ground by a ramp. Such a level, "
        "longer than max_building_m and at most max_hall_m, is a building (empty max_hall_m: the "
        "longest such level of the DSM, on its block minima, at most 400 m; the halo reaches across "
        "it only where there is one). Synthetic city of halls (benchmarks/sites.py) 10.9-12.6 -> "
        "0.04-0.07 % total error; a mesa closed by cliffs on every side, longer than a building, would "
        "be taken: draw a special area there.</p>"
        "<p><b>Crests and shoulders of the terrain</b>: steps 3 and 5 compare a height with its "
        "neighbours, which at a crest sharp against the cell (a dune's brink, a gully's or a bank's "
        "shoulder at 2-4 m cells) lie below it by half the change of slope times the cell, as beside "
        "an object's edge; the paper leaves such lines to break lines. After the fits, a run of their "
        "objects along a row or a column (at most step 5's longest profile window) is a slope break "
        "when the two kept cells on each side rise towards it by more than k times step 5's scale on "
        "average, and each of its heights lies on the lower of the two sides' lines (within k standard "
        "deviations of the difference) and not below their chord: two slopes meeting. A roof stands "
        "metres above the ground's line beside it; a crown whose rising edges were kept lies metres "
        "below their lines; a spike on level ground has no slope beside it. But the crown of a bush "
        "whose sides were kept passes (the opengeos 2 m city: 618 of 627 such cells were objects, "
        "12.65 -> 13.47 % total error), so, as the terrain's level changes, a crest is the terrain's "
        "where its line (with the kept cells passing the same test, joined across gaps of up to 4 m) "
        "runs further than the longest building: those slope breaks are given back. "
        "Bare terrain (benchmarks/bare.py) 1.81 -> 1.52 % of its ground lost: dunes 2 m / 4 m 3.55 / 6.48 "
        "-> 0.09 / 2.20, gullies 1 / 2 / 4 m 1.28 / 5.96 / 9.21 -> 1.04 / 3.49 / 7.16, no row worse; the "
        "generalisation matrix and the synthetic sites unchanged (no crest of theirs runs that far). "
        "Given back before step 3's repeat, not within "
        "each step (measured before the line rule): pieces given back there "
        "cut a crest line short of step 6's window, which the continuing ground gives back whole (dunes "
        "1 m 0 -> 0.57 %), and steps 4-6 then read the given-back cells (levees 4 m 12.1 -> 13.3 %). Not "
        "recovered: a dike 2 m high and a gully 3 m deep one or two cells wide at 4 m cells, a "
        "hedge's or a street's shape, and crests shorter than a building (a mound).</p>"
        "<p><b>Second iteration</b>: removes small vegetation but may generalise the "
        "terrain (the paper's warning). Without it, step 3 alone runs once more at the end "
        "(step3_repeat): the edge of a crown or a roof passes step 3 as the toe of a slope while "
        "the object above it stands, and is tested again once steps 4-6 removed the object "
        "(the opengeos 2 m city: 16.9 -> 11.1 % total error, DTM RMSE 1.20 -> 0.95 m).</p>"
        "<p><b>Embankments and ramps</b> (spare_continuing_ground): the paper leaves terrain "
        "discontinuities to break lines; without them its moving profiles and surfaces take a "
        "road embankment or a ramp, which no jump bounds, for an object (its highway example: "
        "21.6 % of the points removed without break lines, 10.4 % with). The objects of steps 5 "
        "and 6 that lie on smooth ground continuing the ground kept (no second difference of a "
        "3 x 3 neighbourhood above twice step 3's tolerance, within 12 m of kept ground that runs "
        "further than step 6's window, not a piece of a crown left kept), in an object "
        "region longer than step 6's window, are given back as ground; a wall or a crown's edge "
        "is a step whose second difference is its height, and a mound or a crown narrower than "
        "the window stays an object. Its cost: understorey under tree canopy with no ground "
        "return rises from the kept ground as gently as an embankment's side at 1 m cells "
        "(lidar/autzen_trim/1m: 2.20 -> 2.85 % total error). A shorter object region of steps 5 and 6 "
        "(at most step 6's window + 12 m, holding a whole 3 x 3 neighbourhood of its cells) is given back "
        "when it is a ramp between two levels: its heights "
        "lie on an inclined plane (root mean square within step 3's tolerance, rising by more than it), "
        "the kept ground beside both of its ends lies at the plane's own height, and no ground beside it "
        "lies more than step 4's jump below it; a roof is level, or, sloped, stands on walls at its "
        "eaves, and stays an object. This rule is not the paper's (it leaves ramps to break lines).</p>"
        "<p><b>Break lines</b> (optional line layer, rasterised to the cells it crosses): "
        "no comparison crosses a break line, so dams, embankments and cuts keep their "
        "shoulders. <b>Special areas</b> (optional polygons): inside them only the local "
        "filters (steps 3 and 7) run, e.g. for cars and bushes on a dam's slope. The core "
        "receives both as boolean rasters <code>breaklines</code> and "
        "<code>special_areas</code> (keyword arrays, not parameters).</p>"
        "<p>Output extra <i>step</i>: which step removed each cell (0 kept).</p>"),
)
