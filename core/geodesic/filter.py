"""The geodesic filter as its sequence of stages (:func:`filter_geodesic`), and its last
stages, the borders of the removed objects and the islands among them.

Still open (``benchmarks/geodesic_errors.py`` counts the errors by the stage that decided each cell):
opengeos 2 m (9.19 %) is all objects kept, low vegetation in yards 0.6-1.5 m high, and the border
stage's allowed rise taken from ground that this vegetation contaminates; ISPRS 71 at 2 m loses
embankments with 45 degree flanks to scan labelling (a 40 m cross-section reads as a run between
walls) and to the border stage's second and third rings (823 ground against 28 object cells there,
2,754 object against 220 ground on opengeos). Measured and not adopted (main e8816c5, the 73 rows'
mean 2.825): the rise from the lower quartile of the nearby drops (opengeos 8.31, samp71 2 m highest
+0.40), a ring cell no lower than the cells just removed taken as a terrace edge (sites 3.24 -> 3.15,
but matrix half A +0.014 and dtm's +0.009), rings only to cells below the previous ring (samp31 2 m
+0.84), scan regions given back at a smaller multiple of the largest object (opengeos +0.4-0.8).

Measured since (main 5e10dab; sites mean 3.24): every border rule that spares steep ground also spares crown edges
on slopes, every rule that takes opengeos' low vegetation also takes embankment and hillside flanks. The
terrain-level test for every steep border cell, not only a terrace's edge: sites 2.91 (hillside 2 m highest 5.92 ->
3.52, quarry 1 m lowest 4.85 -> 3.21), but ISPRS samp11 2 m highest 22.97 -> 26.06, shrubs 1 m +1.2, forest-dense
1 m +0.3; only where no removed neighbour of the preprocessed surface rises more than dh0 above the cell: samp11
2 m highest 24.31, shrubs 1 m lowest 8.80; terrace_edges' "every removed neighbour below" dropped, or relaxed to
"not above by dh0": sites 3.02-3.20, shrubs 1 m +0.5-0.9, samp11 2 m highest +0.2-0.7; steep cells measured from
the terrain level alone: opengeos 10.81. Every drop above dh0 measured from the level: opengeos 7.12 (DTM RMSE
0.69 m), but hillside 2 m highest 10.57, embankment 1 m lowest 5.45, samp71 2 m 4.80 (the largest step's
reconstruction lies metres under a hillside's ground and the ground around a flank is the plain below); so with
the level the higher of that reconstruction and the ground around's median plus its rise: opengeos 8.12, hillside
2 m highest 6.89. Rim walls of raised_terrain_runs only where the wall's foot stands on level ground (the flank
does not climb on below it): ISPRS samp61 2 m's embankment regions still 58-67 % walls (one 2 m cell holds a
45-degree flank whole, as a wall), samp71 1 m 1.87 -> 2.56 (the bridge's deck given back). ISPRS samp61 2 m
lowest loses 1,062 ground points (3.0 %) to scan labelling on those embankments: the largest class left there.
The border rise capped at the slope of the least-squares plane of the ground around (low vegetation makes that
ground rough without tilting it; branch h-geod 9829cd2): opengeos 9.19 -> 8.25 (DTM RMSE 0.85 -> 0.74 m), matrix
2.94 -> 2.92, dtm 2.46 -> 2.45, but sites 3.24 -> 3.26, bare 0.26 -> 0.27, synthetic forest 4 m 0.53 -> 0.88 (too
few ground cells between crowns to fit a plane) and the filter's CPU +12 %: not adopted."""
import time
from typing import Callable, Optional, Tuple, Union

import numpy as np
from scipy import ndimage

from ..codes import LOW, OBJECT
from ..common import FilterResult, as_cell_size, as_surface, finish_mask, label8, report, sub_progress
from .dilation import BORDER_RINGS, BUMP_FRACTION, EXTENT_FACTOR, gradual_dilation, terrain_at, wall_cells, wall_reach
from .grey import S8, fill_nodata, rect_filter, window_cells
from .outliers import remove_outliers
from .params import OBJECT_SIZE_M, check_params, step_sizes
from .scan import OBLIQUE_REACH, SCAN_PASSES, scan_label

#: ``extras["step"]`` code of a cell removed by scan labelling.
STEP_SCAN = 250
#: ``extras["step"]`` code of a preprocessing outlier (high: mask 1, low: mask 2).
STEP_OUTLIER = 251
#: ``extras["step"]`` code of a border cell of a removed region (wall or crown edge).
STEP_EDGE = 252
#: ``extras["step"]`` code of a kept island inside removed objects, above the terrain.
STEP_ISLAND = 253
#: ``extras["step"]`` code of nodata cells.
STEP_NODATA = 255


def bridge_dropouts(z):
    """``z`` with its one-cell dropouts bridged, and the cells that were valid (None: no nodata).

    A nodata cell between two valid cells along its row or its column (a dropout) takes the
    lower of the straight lines across it (the mean of its row pair, of its column pair), so
    that a profile crossing it is not cut; a wider gap keeps its nodata and still ends runs.
    A straight line, not the lowest neighbour: on a steep slope the lowest neighbour is a pit
    that opens runs (issue 12).

    Examples
    --------
    >>> z = np.array([[1, 2, 3], [4, np.nan, 8], [7, 9, 9]], np.float32)
    >>> bridged, valid = bridge_dropouts(z)
    >>> float(bridged[1, 1]), valid.tolist()
    (5.5, [[True, True, True], [True, False, True], [True, True, True]])
    """
    bad = np.isnan(z)
    if not bad.any():
        return z, None
    line = np.full((2,) + z.shape, np.nan, z.dtype)
    line[0, :, 1:-1] = (z[:, :-2] + z[:, 2:]) / 2
    line[1, 1:-1, :] = (z[:-2, :] + z[2:, :]) / 2
    low = np.fmin(line[0], line[1])
    out = z.copy()
    np.copyto(out, low, where=bad & np.isfinite(low))
    return out, ~bad


def label_scans(cleaned, cell_size, p, removed, step, progress=None, pool=None):
    """Stage 3: scan labelling of the cleaned surface (:func:`~.scan.scan_label`).

    Runs of cells that open with a rise and close with a fall are removed (``removed``
    updated in place); cells not coded yet get :data:`STEP_SCAN`. Returns their count.

    Nodata ends a run, so scattered nodata (an image-matching DSM) leaves no run across an
    object. The scan is repeated on the surface with one-cell dropouts bridged
    (:func:`bridge_dropouts`); a run it adds is kept when its region holds a core labelled
    by both the row and the column scans that is at least 3 x 3 cells (an object is a 2-D
    region; a run of matching noise along one profile is not); only valid cells are labelled
    (issue 12). ``pool``: threads that may scan the rows when idle (:func:`~.scan.scan_label`).

    The runs of a region longer than :data:`~.dilation.EXTENT_FACTOR` largest objects whose rim
    is mostly not walls are not labelled (:func:`raised_terrain_runs`): an embankment or a dike.
    The regions are those of all the labelled cells, the dilation's objects among them included
    (cells a step removed stay removed): the pieces a step takes from a region too wide to be one
    (:func:`~.dilation._wide_pieces`: shrubs on an embankment) cut its runs into regions shorter
    than that, which were no longer given back (ISPRS samp61 at 1 m, 1.79 -> 2.32 %; 1.87 % so;
    only the labelled cells no step removed and the pieces: 1.85 %, but samp71 at 1 m 2.56 %,
    1.86 % so).
    """
    kw = dict(jump_m=p["height_threshold_m"], height_m=p["height_threshold_m"],
              max_length_m=p["max_object_size_m"], terrain_slope_deg=p["terrain_slope_deg"],
              oblique_length_m=OBLIQUE_REACH * p["max_object_size_m"], passes=SCAN_PASSES, pool=pool)
    surface, valid = bridge_dropouts(cleaned)
    lab = scan_label(cleaned, cell_size, progress=progress, **kw)
    if valid is not None and np.isfinite(surface).sum() > valid.sum():
        bridged = scan_label(surface, cell_size, **kw)
        both = scan_label(surface, cell_size, axes=(1,), **kw) & scan_label(surface, cell_size, axes=(0,), **kw)
        core = ndimage.binary_opening(both, S8)
        lab |= ndimage.binary_propagation(core, S8, mask=bridged) & valid
    free = ~removed & (step == 0)                 # raised terrain longer than any object: kept
    # the regions of all the labelled cells: a dilation step's pieces inside a run do not cut it
    lab &= ~raised_terrain_runs(cleaned, lab, cell_size, p["max_object_size_m"], p["height_threshold_m"],
                                np.tan(np.radians(p["terrain_slope_deg"])), p["edge_ratio"])
    new = lab & free                              # removed and step are those of ``free``
    step[new] = STEP_SCAN
    removed |= lab
    return int(new.sum())


def raised_terrain_runs(w, new, cell_size, size_m, dh0, tan_s, edge_ratio):
    """The cells of ``new`` (cells scan labelling took) in raised terrain: an 8-connected region of
    them whose bounding box exceeds :data:`~.dilation.EXTENT_FACTOR` ``* size_m`` (the largest
    object) along the rows or the columns, and fewer than ``edge_ratio`` of whose rim cells (not on
    the raster's edge) hold a wall (:func:`~.dilation.wall_cells`): the dilation's test of height heterogeneity, which
    its steps do not apply to a region that long (never an object there).

    Scan labelling reads profiles one at a time: an embankment, a dike or a road on a fill
    crossed by rows or columns is a run bounded by two flanks, and at 2 m cells of lowest
    points a 1:1.5 flank rises in one or two steps between sparse returns, as a wall with a
    mixed cell does for the profile (synthetic site ``embankment`` at 2 m: its road embankment
    and dike, 3-6 m high and 200-320 m long, went as objects, 7.7 % total error). Seen whole,
    its rim is a flank's top, a little above the flank below it; a hall's or a row of roofs'
    rim holds walls. Within such a region each cell follows the rim cell nearest it: a bridge's
    deck, which the profiles take with the embankments it joins (ISPRS samp71 at 1 m: 2.60 ->
    4.05 % when the whole region was given back), stands on walls over the road below it.

    Examples
    --------
    >>> w = np.zeros((7, 14), np.float32)
    >>> w[2:5, 1:13] = 1.2                   # a crest 12 cells long, 1.2 m above the ground
    >>> new = w > 0
    >>> raised_terrain_runs(w, new, (1.0, 1.0), 5.0, 0.5, 0.2, 0.55).sum()
    36
    >>> w[2:5, 1:13] = 3.0                   # walls all round: an object
    >>> raised_terrain_runs(w, new, (1.0, 1.0), 5.0, 0.5, 0.2, 0.55).sum()
    0
    >>> w[2:5, 1:13] = 1.2                   # 12 m is not beyond 2 x 6 m
    >>> raised_terrain_runs(w, new, (1.0, 1.0), 6.0, 0.5, 0.2, 0.55).sum()
    0
    """
    out = np.zeros(new.shape, bool)
    cells = np.flatnonzero(new)                   # few: what scan labelling adds to the dilation's objects
    if not cells.size:
        return out
    cell_size = as_cell_size(cell_size)
    dx, dy = cell_size
    H, W = new.shape
    lab, n = label8(new)
    lab_c = lab.ravel()[cells]
    # each region's bounding box from its cells (no pass over the raster), rows then columns
    r, c = np.divmod(cells, W)
    order = np.argsort(lab_c, kind="stable")
    starts = np.r_[0, np.flatnonzero(np.diff(lab_c[order])) + 1]      # labels 1..n, each with cells
    ro, co = r[order], c[order]
    ext = np.zeros((n + 1, 2), np.float64)
    ext[1:, 0] = np.maximum.reduceat(ro, starts) - np.minimum.reduceat(ro, starts) + 1
    ext[1:, 1] = np.maximum.reduceat(co, starts) - np.minimum.reduceat(co, starts) + 1
    ext *= (dy, dx)
    wide = (ext > EXTENT_FACTOR * size_m).any(axis=1)
    wide[0] = False
    if not wide.any():
        return out
    # the wide regions' rims and walls on their bounding box only: a margin of one cell for the rim (cells
    # beyond it are no region's) and of the wall test's reach for the walls (the raster's edge stays its own)
    at = wide[lab_c]
    wr = wall_reach(cell_size)
    m = (wr[0] + 1, wr[1] + 1)
    r0, r1, c0, c1 = int(r[at].min()), int(r[at].max()) + 1, int(c[at].min()), int(c[at].max()) + 1
    big = (slice(max(0, r0 - m[0]), min(H, r1 + m[0])), slice(max(0, c0 - m[1]), min(W, c1 + m[1])))
    lab_b = lab[big]
    body = wide[lab_b]
    wb = w[big]
    rim = body & ~ndimage.binary_erosion(body | ~np.isfinite(wb), S8, border_value=1)   # nodata ends the data
    if big[0].start == 0:
        rim[0] = False
    if big[0].stop == H:
        rim[-1] = False
    if big[1].start == 0:
        rim[:, 0] = False
    if big[1].stop == W:
        rim[:, -1] = False
    walls = wall_cells(wb, np.isfinite(wb), cell_size, dh0, tan_s) & rim
    n_rim = np.bincount(lab_b[rim], minlength=n + 1)
    n_wall = np.bincount(lab_b[walls], minlength=n + 1)
    terrain = wide & (n_rim > 0) & (n_wall < edge_ratio * n_rim)
    if not terrain.any():
        return out
    # each cell of such a region follows the rim cell nearest it (within the regions' bounding box): a bridge's
    # deck on its embankments stands on walls over the road below, the embankments on their flanks
    on = terrain[lab_c]
    rt, ct = r[on] - big[0].start, c[on] - big[1].start
    box = (slice(int(rt.min()), int(rt.max()) + 1), slice(int(ct.min()), int(ct.max()) + 1))
    inside = terrain[lab_b[box]]
    rim_b = rim[box] & inside
    ii, jj = ndimage.distance_transform_edt(~rim_b, sampling=(dy, dx), return_distances=False, return_indices=True)
    flank = ~walls[box][ii, jj]
    del ii, jj
    out[big][box] = new[big][box] & inside & flank
    return out


#: Baseline of the terrain level's local slope (stage 4), metres: the ~4 m grid the tolerated
#: slope is measured on (:func:`~.params.resolve_geodesic_params`), so that the mixed cells at
#: an object's foot, which the reconstruction reaches, do not read as a slope.
SLOPE_BASE_M = 4.0


def terrain_slope_at(terrain, cells, shape, cell_size):
    """The slope (rise/run) of the terrain level of :func:`~.dilation.gradual_dilation` (its
    largest step's reconstruction ``(Rc, f)``, which no object reaches) at the flat ``cells`` of
    a raster of ``shape``: differences on its grid of ``f`` x ``f`` blocks across
    ``k = ceil(SLOPE_BASE_M / (f cell))`` blocks each side (clipped at the grid's edge); 0 where
    it is not finite (nodata, no marker within reach)."""
    Rc, f = terrain
    dx, dy = cell_size
    h, w = Rc.shape
    r, c = np.divmod(np.asarray(cells, np.intp), shape[1])
    r, c = r // f, c // f
    g2 = np.zeros(r.size, np.float64)
    for axis, step in ((1, dx * f), (0, dy * f)):
        n = Rc.shape[axis]
        k = max(1, int(np.ceil(SLOPE_BASE_M / step - 1e-9)))
        pos = c if axis == 1 else r
        lo, hi = np.maximum(pos - k, 0), np.minimum(pos + k, n - 1)
        a, b = (Rc[r, lo], Rc[r, hi]) if axis == 1 else (Rc[lo, c], Rc[hi, c])
        with np.errstate(invalid="ignore", divide="ignore"):
            g = (np.asarray(b, np.float64) - a) / ((hi - lo) * step)
        g2 += np.where(np.isfinite(g), g, 0.0) ** 2
    out = np.sqrt(g2)
    bad = ~np.isfinite(Rc[r, c])
    out[bad] = 0.0
    if h * w == 0:
        return np.zeros(r.size)
    return out


def ground_drop(drop, ground, cells, radius, quantile=0.5):
    """The median of ``drop`` over the ``ground`` cells within ``radius`` cells (a square of
    side ``2 radius + 1``) of each of the flat ``cells``; NaN where there is none. Another
    ``quantile`` gives that quantile instead (the nearest rank: the value of rank
    ``round(quantile * (n - 1))`` among the ``n`` ground values, ascending).

    Examples
    --------
    >>> drop = np.arange(25, dtype=np.float32).reshape(5, 5)
    >>> ground = np.ones((5, 5), bool)
    >>> ground[2, 2] = False
    >>> ground_drop(drop, ground, np.array([12, 0]), 1).tolist()
    [12.0, 3.0]
    >>> ground_drop(drop, ground, np.array([12, 0]), 1, quantile=0.75).tolist()
    [16.0, 5.0]
    """
    H, W = drop.shape
    d = np.arange(-radius, radius + 1)
    dr, dc = np.repeat(d, d.size), np.tile(d, d.size)
    r, c = np.divmod(np.asarray(cells, np.intp), W)
    rr, cc = r[:, None] + dr, c[:, None] + dc
    inside = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
    nb = np.where(inside, rr * W + cc, 0)
    v = np.where(inside & ground.ravel()[nb], drop.ravel()[nb], np.nan)
    v[~np.isfinite(v)] = np.nan
    v.sort(axis=1)                                # NaN last
    n = np.count_nonzero(~np.isnan(v), axis=1)
    rows = np.arange(v.shape[0])
    if quantile != 0.5:
        out = v[rows, np.minimum(np.round(quantile * np.maximum(n - 1, 0)).astype(np.intp), v.shape[1] - 1)]
        out[n == 0] = np.nan
        return out
    lo, hi = np.maximum(n - 1, 0) // 2, np.maximum(n, 1) // 2
    out = (v[rows, lo] + v[rows, np.minimum(hi, v.shape[1] - 1)]) / 2
    out[n == 0] = np.nan
    return out


#: The quantile of the heights of the ground around (kept cells touching no removed one) that a
#: border cell is measured from in :func:`remove_borders` where the terrain level of the largest step
#: is higher: on a terrace's (a plateau's) edge the terrace holds at least a quarter of the square around
#: the cell (half along a straight edge, a quarter at a right-angled convex corner), so the upper
#: quartile reaches its level; round a roof the ground around is the lower ground.
GROUND_LEVEL_QUANTILE = 0.75


def remove_borders(cleaned, valid, vnone, removed, cell_size, dh0, tan_s, step, terrain=None):
    """Stage 4: the borders of the removed objects.

    A kept cell that touches a removed one and stands above its lowest 8-neighbour by more
    than ``dh0`` plus the terrain's rise over a cell diagonal is the foot of a wall or the
    edge of a crown (a cell mixing object and ground): it is removed too (``removed`` and
    ``step`` updated in place, code :data:`STEP_EDGE`), so the interpolated DTM is not pulled
    up along the objects' borders. The test runs in up to :data:`~.dilation.BORDER_RINGS`
    rings, each on the cells touching the previous ring: a wall the DSM smears over a few
    cells leaves a skirt of mixed cells, each above the next one outward. Returns the count.

    The terrain's rise over the diagonal is measured where the cell stands, as the larger of

    * the slope of the terrain level (the largest step's reconstruction, which no object
      reaches; :func:`terrain_slope_at`) when ``terrain`` is given: on a forested slope
      steeper than the tolerance the ground beside every crown stood above its downhill
      neighbour by more than the tolerated rise and was removed (a 38-degree forest at 2 m:
      967 ground cells, type I 7.3 %; with the local slope 323, 4.2 %);
    * the median drop of the ground around (the kept cells within ``BORDER_RINGS`` cells
      that touch no removed cell, each above its own lowest neighbour; :func:`ground_drop`):
      rough or sloping ground shows in its drops, a smeared wall's skirt stands above flat
      ground.

    Where no such ground is near, the tolerated slope ``tan_s`` sets the rise. A cell that only
    a rise below the tolerated one removes must also stand more than ``dh0`` above the terrain
    level (:func:`~.dilation.terrain_at`, as the islands of stage 5): the ground's drops around
    a narrow bank or an embankment's flank are mostly those of the flat ground beside it, and
    its cells are at the terrain level (without ``terrain``: the tolerance stays the least
    rise). That level is the largest step's reconstruction on its coarse blocks, which reaches
    a block's highest cell on terrain: in a town or a wood at 2 m (blocks of 16 m) that is a
    mixed cell at a crown's or a wall's foot, and on a sloping town the level of the ground
    uphill carried down through blocks under canopy (opengeos: 0.5 m above the reference DTM at
    the median kept ground cell, 2-3 m under its wooded parts), so the skirts stayed. Where the
    ground around (the same kept cells, :data:`GROUND_LEVEL_QUANTILE` of their heights, plus the
    rise over a cell diagonal) is lower, the cell is measured from it: a terrace's edge has the
    terrace among the ground around and stays (issue 12: opengeos 10.82 -> 9.28 %, DTM RMSE
    0.91 -> 0.88 m). The tolerated slope (clipped to at least 12 degrees) allowed 0.5 + 0.21 x 2.83 =
    1.1 m at 2 m cells on flat ground, and the skirts of 0.6-2.5 m round the roofs of a 2 m
    DSM stayed (issue 12: opengeos 13.52 % total, 9540 object cells kept, 6528 of them
    touching a removed one; the DTM 0.68 m high on average; now 10.51 %, DTM RMSE 1.04 ->
    0.89 m; without the terrain-level test 8.28 %, but the dtm's raised regions then took a
    bank of ISPRS samp61 at 2 m, 4.25 -> 7.83 %). A steeper rise is measured from the terrain level
    too at a terrace's edge over a face (:func:`terrace_edges`: every removed cell around it below it,
    the terrain continuing beyond it): a quarry's bench edges and terrain steps beside the face's
    scan-labelled cells (issue 12, synthetic sites).
    """
    if not removed.any():
        return 0
    dx, dy = cell_size
    diag = float(np.hypot(dx, dy))
    base = fill_nodata(cleaned, vnone, np.inf)
    lowc = rect_filter(base, (3, 3), np.minimum, np.inf)
    with np.errstate(invalid="ignore"):
        drop = base - lowc                        # each cell above its lowest neighbour
        high = valid & (drop > dh0)               # the least any rise allows
    total = 0
    H, W = removed.shape
    near = rect_filter(removed, (3, 3), np.maximum, False)
    idx = np.flatnonzero(high & near & ~removed & (step == 0))
    ground = valid & ~near & (step == 0)
    for ring in range(BORDER_RINGS):
        if idx.size == 0:
            break
        d = drop.ravel()[idx]
        if terrain is None:                       # no terrain level: the tolerance, as steep as the ground's drops
            s_loc = np.fmax(ground_drop(drop, ground, idx, BORDER_RINGS) / diag, tan_s)
            keep = d > dh0 + s_loc * diag
        else:
            s_loc = ground_drop(drop, ground, idx, BORDER_RINGS) / diag
            s_loc[np.isnan(s_loc)] = tan_s       # no ground near: the tolerance
            s_loc = np.maximum(s_loc, terrain_slope_at(terrain, idx, cleaned.shape, cell_size))
            keep = d > dh0 + s_loc * diag
            # a rise below the tolerated one removes a cell standing above the terrain level only; so does any rise
            # at a terrace's edge over a face (terrace_edges)
            strict = keep & (d <= dh0 + np.maximum(s_loc, tan_s) * diag)
            steep = np.flatnonzero(keep & ~strict)
            if steep.size:
                strict[steep] = terrace_edges(base, removed, step, idx[steep], cell_size, dh0)
            if strict.any():
                at = idx[strict]
                # the terrain level: the block's reconstruction, or the ground around where lower (its upper
                # quartile, plus the rise over a cell diagonal; GROUND_LEVEL_QUANTILE)
                level = np.fmin(terrain_at(terrain, at, cleaned.shape),
                                ground_drop(base, ground, at, BORDER_RINGS, GROUND_LEVEL_QUANTILE)
                                + s_loc[strict] * diag)
                with np.errstate(invalid="ignore"):
                    keep[strict] = cleaned.ravel()[at] - level > dh0
        found = idx[keep]
        if found.size == 0:
            break
        step.ravel()[found] = STEP_EDGE
        removed.ravel()[found] = True
        total += int(found.size)
        if ring + 1 < BORDER_RINGS:
            # the next ring around the cells just removed (few: a pass over the raster per ring cost more): the
            # cells they bring near leave the ground and join the candidates that stayed, when high and not coded
            more = neighbours8(found, (H, W))
            more = more[~near.ravel()[more]]
            near.ravel()[more] = True
            ground.ravel()[more] = False
            more = more[high.ravel()[more] & ~removed.ravel()[more] & (step.ravel()[more] == 0)]
            idx = np.union1d(idx[~keep], more)
    return total


def terrace_edges(base, removed, step, cells, cell_size, dh0):
    """Whether each of the flat ``cells`` (kept cells beside removed ones, each above its lowest neighbour by
    more than the terrain's rise) is a terrace's edge over a face rather than the border of an object: it
    stands above every removed cell around it, and the terrain continues beyond it.

    * Every removed 8-neighbour keeps its own height (removed by scan labelling, a previous ring of this
      stage or the preprocessing, not lowered by a dilation step: codes 1 .. K of ``step``) and lies more
      than ``dh0`` below the cell: cells of the face below the edge. An object's border cell mixes the
      object and the ground at its foot: the object's own cells stand at or above it; a dilation step's
      cells are lowered to its reconstruction, which reaches the height of the cells around the object
      (a mixed foot cell among them), so they tell nothing and the cell stays a border.
    * The two cells beyond it, opposite its steepest descent (the 8-neighbour of the largest drop per metre,
      then the next cell on), lie inside the raster, hold data and are kept, and the cell stands no more
      than ``dh0`` above their line extended to it (``2 z1 - z2``): the terrace's level, or a slope rising
      on, continues beyond the edge.

    ``base``: the cleaned surface, nodata ``+inf``. :func:`remove_borders` still measures such a cell from
    the terrain level.

    Examples
    --------
    >>> base = np.array([[5, 5, 5], [5, 5, 5], [5, 5, 5], [2, 2, 2]], np.float32)   # a terrace's edge: row 2
    >>> removed = np.zeros((4, 3), bool)
    >>> step = np.zeros((4, 3), np.uint8)
    >>> removed[3, 2] = True                  # a cell of the face below, scan-labelled (its own height)
    >>> terrace_edges(base, removed, step, np.array([7]), (1.0, 1.0), 0.5).tolist()
    [True]
    >>> removed[1, 2] = True                  # a roof beside the edge, scan-labelled at 5 m: its border
    >>> terrace_edges(base, removed, step, np.array([7]), (1.0, 1.0), 0.5).tolist()
    [False]
    >>> removed[1, 2] = False
    >>> base[1, 1] = 3                        # a ditch beyond the edge: the cell is a crest, not the terrace
    >>> terrace_edges(base, removed, step, np.array([7]), (1.0, 1.0), 0.5).tolist()
    [False]
    """
    H, W = base.shape
    dx, dy = cell_size
    flat, rem, code = base.ravel(), removed.ravel(), step.ravel()
    cells = np.asarray(cells, np.intp)
    r, c = np.divmod(cells, W)
    zc = flat[cells].astype(np.float64)
    out = np.ones(r.size, bool)
    steepest = np.zeros(r.size)
    off = np.zeros((r.size, 2), np.intp)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr or dc:
                rr, cc = r + dr, c + dc
                ok = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
                q = np.where(ok, rr * W + cc, 0)
                v = np.where(ok, flat[q], np.inf).astype(np.float64)
                lowered = (code[q] >= 1) & (code[q] < STEP_SCAN)
                with np.errstate(invalid="ignore"):
                    out &= ~(ok & rem[q]) | (~lowered & (v < zc - dh0))   # removed: a face's cell below it
                    g = (zc - v) / float(np.hypot(dr * dy, dc * dx))
                more = g > steepest
                steepest[more] = g[more]
                off[more] = (dr, dc)
    out &= steepest > 0
    beyond = []
    for k in (1, 2):
        qr, qc = r - k * off[:, 0], c - k * off[:, 1]
        ok = (qr >= 0) & (qr < H) & (qc >= 0) & (qc < W)
        q = np.where(ok, qr * W + qc, 0)
        out &= ok & ~rem[q] & np.isfinite(flat[q])
        beyond.append(flat[q].astype(np.float64))
    with np.errstate(invalid="ignore"):
        return out & (zc <= 2 * beyond[0] - beyond[1] + dh0)


def neighbours8(cells, shape):
    """The flat indices (sorted, unique) of the 8-neighbours inside a raster of ``shape`` of the flat ``cells``.

    Examples
    --------
    >>> neighbours8(np.array([0, 8]), (3, 3)).tolist()
    [1, 3, 4, 5, 7]
    """
    H, W = shape
    r, c = np.divmod(np.asarray(cells, np.intp), W)
    out = []
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr or dc:
                ok = (r + dr >= 0) & (r + dr < H) & (c + dc >= 0) & (c + dc < W)
                out.append((r[ok] + dr) * W + c[ok] + dc)
    return np.unique(np.concatenate(out))


def remove_islands(w, valid, removed, mask, terrain, cell_size, size_m, height_m, step):
    """Stage 5: kept islands inside the removed objects that stand above the terrain.

    A set of kept cells (8-connected; outliers count as removed) no larger than the
    first structuring element (``size_m``: its window's cells), enclosed by removed cells
    (not touching the raster's edge, which ends the data), is a gap between objects that
    no step could see as terrain: every step's window is wider. It is the terrain when it
    reaches it; it is a gap in a canopy or a roof (a crown's lower side, a light well)
    when even its lowest cell stands above the terrain level of the largest step (its
    reconstruction, which no object reaches: :func:`~.dilation.terrain_at`) by more than
    ``height_m`` (the first step's height threshold: what a terrain bump of that width
    may rise). Such islands are removed (``removed`` and ``step`` updated in place, code
    :data:`STEP_ISLAND`), so the interpolated DTM does not rest on canopy gaps. Their
    cells are few: the test runs on them only, and the labelling on the kept cells outside every kept
    square larger than that window (a cell of one lies in a larger set; the other cells' parts touching none
    are whole sets). Returns the count.
    """
    kept = ~removed
    kept &= mask == 0                     # outliers (low and high) are not kept
    if valid is not None:
        kept &= valid
    k = int(np.prod(window_cells(size_m, *cell_size)))
    # a cell of a kept square of more than k cells lies in a set larger than k; a part of the other kept cells
    # that touches no such cell is a whole set: only those cells are labelled (the ground's bulk is not)
    s = 3
    while s * s <= k:
        s += 2
    thick = rect_filter(rect_filter(kept, (s, s), np.minimum, False), (s, s), np.maximum, False)
    thin = kept & ~thick
    del kept
    lab, n = label8(thin)
    if n == 0:
        return 0
    idx = np.flatnonzero(thin)
    lab_c = lab.ravel()[idx]
    small = np.bincount(lab_c, minlength=n + 1) <= k
    small[0] = False
    small[lab[0]] = small[lab[-1]] = small[lab[:, 0]] = small[lab[:, -1]] = False
    small[lab[rect_filter(thick, (3, 3), np.maximum, False) & thin]] = False
    del lab, thick, thin
    if not small.any():
        return 0
    at = small[lab_c]                         # the few cells of small enclosed sets
    idx, lab_c = idx[at], lab_c[at]
    with np.errstate(invalid="ignore"):
        above = w.ravel()[idx] - terrain_at(terrain, idx, w.shape)
    lowest = np.full(n + 1, np.inf)
    # no terrain level known (nodata, no marker within reach): no evidence, kept
    np.minimum.at(lowest, lab_c, np.where(np.isfinite(above), above, -np.inf))
    isl = idx[lowest[lab_c] > height_m]
    step.ravel()[isl] = STEP_ISLAND
    removed.ravel()[isl] = True
    return int(isl.size)


def _complete(p):
    """``p`` checked: every value given (not None) and within its bounds."""
    for k, v in p.items():
        if v is None:
            raise ValueError(f"{k} is None: filter_geodesic needs complete parameters; "
                             "call resolve_geodesic_params first (or use the pipeline).")
    check_params(p)
    p["scan_labelling"] = bool(p["scan_labelling"])
    p["raised_regions"] = bool(p["raised_regions"])
    return p


def _lap(stages, name, t0):
    """Record the seconds since the previous stage ended under ``name``."""
    stages[name] = round(time.perf_counter() - t0 - sum(stages.values()), 3)


def filter_geodesic(z: np.ndarray, cell_size: Union[float, Tuple[float, float]], *, min_window_m: float = 2.0,
                    max_object_size_m: float = 64.0, height_threshold_m: float = 0.5,
                    terrain_slope_deg: float = 20.0, edge_ratio: float = 0.55, outlier_threshold_m: float = 2.0,
                    outlier_width_m: float = 2.0, scan_labelling: bool = True, raised_regions: bool = True,
                    progress: Optional[Callable[[float], None]] = None, pool=None) -> FilterResult:
    """Gradual geodesic dilation with scan labelling (2018; ISPRS filter test).

    See the package docstring for the method. Parameters are complete values (use
    :func:`~.params.resolve_geodesic_params` to derive defaults from the data).

    Parameters
    ----------
    z : array_like, 2-D
        DSM, NaN = nodata (not modified).
    cell_size : float or (float, float)
        ``(dx, dy)`` in metres.
    min_window_m, max_object_size_m : float
        Sides of the first (smallest) and the last structuring element, metres.
    height_threshold_m : float
        dh0: minimal height of an object above the reconstructed terrain, metres.
    terrain_slope_deg : float
        Terrain slope tolerance (degrees) of the wall test, the height test and scan
        labelling.
    edge_ratio : float
        Height heterogeneity threshold in [0, 1]: a region is an object when at least
        this fraction of its border cells hold a wall.
    outlier_threshold_m, outlier_width_m : float
        Preprocessing: depth (height) below the closing (above the opening) of a low
        (high) outlier, and the width of their window, metres.
    scan_labelling : bool
        Run scan labelling after the dilation steps.
    raised_regions : bool
        Used by :func:`~.params.resolve_geodesic_params` only (whether the derived largest object
        widens to a raised region); recorded in ``info``.
    progress : callable, optional
        ``progress(fraction)`` within every stage; may raise
        :class:`~bare_earth.core.common.Cancelled`.
    pool : concurrent.futures.Executor, optional
        Threads that may run some of the independent dilation steps, and the row scans of the scan
        labelling, when idle (:func:`~bare_earth.core.blocks.run_sharing`: ``bareearth:dtm`` lends the
        thread another member has left); the same result.

    Returns
    -------
    FilterResult
        ``mask`` (0 ground, 1 object, 2 low outlier, 255 nodata); ``extras["step"]``
        (uint8: 0 kept, k = removed at dilation step k, :data:`STEP_SCAN`,
        :data:`STEP_OUTLIER`, :data:`STEP_EDGE`, :data:`STEP_ISLAND`, 255 nodata); ``surface`` the cleaned
        surface (removed cells lowered to the reconstruction); ``info`` parameters, step
        sizes and counts.
    """
    t0 = time.perf_counter()
    z = as_surface(z)
    cell = as_cell_size(cell_size)
    p = _complete(dict(min_window_m=min_window_m, max_object_size_m=max_object_size_m,
                       height_threshold_m=height_threshold_m, terrain_slope_deg=terrain_slope_deg,
                       edge_ratio=edge_ratio, outlier_threshold_m=outlier_threshold_m,
                       outlier_width_m=outlier_width_m, scan_labelling=scan_labelling,
                       raised_regions=raised_regions))
    valid = np.isfinite(z)
    vnone = None if valid.all() else valid        # fast paths when there is no nodata
    dh0, tan_s = float(height_threshold_m), float(np.tan(np.radians(terrain_slope_deg)))
    step, mask, outlier = np.zeros(z.shape, np.uint8), np.zeros(z.shape, np.uint8), np.zeros(z.shape, bool)
    stages = {}
    report(progress, 0.0)
    # 1. preprocessing: isolated low and high outliers
    w, n_low, n_high = remove_outliers(z, valid, vnone, cell, outlier_threshold_m, outlier_width_m,
                                       mask, outlier, tan_s, sub_progress(progress, 0.0, 0.05))
    step[outlier] = STEP_OUTLIER
    _lap(stages, "preprocessing", t0)
    # 2. gradual geodesic dilation
    sizes = step_sizes(min_window_m, max_object_size_m)
    removed, cleaned, counts, terrain = gradual_dilation(w, valid, cell, sizes, dh0, tan_s, edge_ratio, step,
                                                         sub_progress(progress, 0.05, 0.85), pool=pool,
                                                         split_beyond_m=OBJECT_SIZE_M)
    _lap(stages, "dilation", t0)
    # 3. scan labelling on the cleaned surface
    n_scan = (label_scans(cleaned, cell, p, removed, step, sub_progress(progress, 0.85, 0.95), pool=pool)
              if scan_labelling else 0)
    _lap(stages, "scan", t0)
    report(progress, 0.95)
    # 4. object borders (wall feet, crown edges)
    n_edge = remove_borders(cleaned, valid, vnone, removed, cell, dh0, tan_s, step, terrain)
    # 5. islands inside the objects that stand above the terrain (canopy gaps)
    n_island = remove_islands(w, vnone, removed, mask, terrain, cell, sizes[0],
                              dh0 + tan_s * sizes[0] * BUMP_FRACTION, step)
    mask[removed & (mask != LOW)] = OBJECT
    mask = finish_mask(mask, z)
    step[~valid] = STEP_NODATA
    cleaned[~valid] = np.nan
    info = dict(p, method="geodesic", step_sizes_m=sizes, removed_per_step=counts, removed_scan=n_scan,
                removed_edge=n_edge, removed_island=n_island, low_outliers=n_low, high_outliers=n_high,
                object_fraction=float((mask == OBJECT).sum() / max(valid.sum(), 1)),
                seconds=round(time.perf_counter() - t0, 3), stage_seconds=stages)
    report(progress, 1.0)
    return FilterResult(mask=mask, extras={"step": step}, info=info, surface=cleaned.astype(np.float32, copy=False))
