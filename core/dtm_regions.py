"""Raised regions wider than the vote's windows: voted ground bounded by steps down to the ground.

Every member of ``bareearth:dtm`` looks at the surface through a window: the opening removes
what its largest window cannot reach across, RASCOR's level changes what is shorter than its
longest raised level, the geodesic reconstruction what its largest window spans. A flat roof
wider than the windows of a majority of the members (a warehouse, a mall, a roof over most of
a tile) comes out of the vote as ground, and the DTM then runs over it.

Such a roof is recognised by its outline, as the slope-profile scans (Luong Chinh Ke 2002:
a rise steeper than any terrain slope, the profile staying up until it comes back down) and
the geodesic reconstruction's scan labelling recognise a building's edge: it stands on steep
*steps* - a height jump over one or two cells - down to ground that continues beyond the step.
:func:`find_raised_regions` tests that, region by region:

1. **Regions.** The voted ground cells with no 8-neighbour more than ``s`` lower are labelled
   into 8-connected regions: a roof's rim (cells above a wall) and every cell of a slope steeper
   than ``s`` per cell separate the region on top from the ground around. ``s`` takes the
   scales ``t, 2 t, 4 t, ...`` (``t``: the vote's object height threshold) up to the highest
   such drop: a roof of several levels (a lower level by its wall, a parapet, a roof step: steps
   lower than its walls between them) is cut into levels at the small scales, some narrower than
   the windows, and is one region at the scales above its inner steps; each scale's regions are
   tested as below, and the objects of every scale are kept (a scale cutting the same cells as
   the one before has the same regions with fewer steps: it is skipped). Candidates are the
   regions whose footprint (holes filled) is wider (twice the largest distance from a cell to a
   cell seen outside it, less a cell) than ``min_width_m``, the window of the vote's majority:
   narrower ones the members' windows reach, and their vote stands. Beyond the raster's edge
   nothing is seen: a region cut by it may continue there, and its width is that of the region
   mirrored at the edge (as the slope-profile and curvature filters take a profile cut by the
   edge); a region spanning more cells than the stage reaches (``max_cells``), or wider, is left
   alone, and so is a region whose *walls* run farther: the box of its outer outline (below) along
   each axis, mirrored at every side of the raster the wall meets, a side both the outline and the
   ground at the wall's foot (the cells ``a`` of step 2) reach (:func:`~.common.walls_runs`: a wall
   running across the raster, from one side to the opposite one, continues beyond both and spans
   three times what is seen; a wall cutting off a corner meets two adjacent sides and spans twice
   what is seen; where such a wall ends in the corner, the roof beside its end reaches the third
   side but the ground beyond the wall does not).
   **Cut into a hillside.** On a steep hillside the members' thresholds, which grow with the terrain slope
   and their windows, pass the part of a roof nearest the slope: the vote splits the roof's level into
   objects (its part standing high above the hillside) and ground (its part against it). Such a *level* - an
   8-connected region of the cells, voted ground or objects, with no neighbour more than ``s`` lower (a
   roof's unevenness at the scales below; crowns and walls stay cuts) - is a
   candidate too when it is narrower than ``min_width_m``, holds voted ground and more voted objects, is
   seen whole (not cut by the raster's edge) and is cut into a hillside: its outer outline cells below the
   ground beyond them (the mirror of a step: the continuation of that ground more than ``s`` above ``p``) and
   on no step are at least ``CUT_IN_MIN_CELLS`` and at least as many as the level is wide, and some of them
   are voted ground (the part the slope allowances kept is the part against the hillside). Its walls are
   measured as for any region on its other outline cells (the cut-in side says nothing of walls), the plane
   of step 3 on the ground beyond them; a decided level turns only its voted ground (and the rims on top of
   its walls) into objects. A terrace cut into the hillside and joined to the ground below by banks has no
   steps and stays ground. The levels are looked for at the scales of a roof's unevenness, ``s = t`` and
   ``2 t`` (their object part is cut as their ground part there; above, the walls of the cut itself no
   longer cut the level from the hillside). Only the stage's ground regions narrower than ``min_width_m``,
   away from the raster's edge, next to a level object cell and holding a voted ground cell below the
   ground beyond it (the cut-in test on each such cell of their box) can be such a level's ground part: the
   levels are labelled in windows around those alone (:func:`_cut_in_at`), not on the raster.
2. **Outline of steps.** An outer outline cell ``p`` of the region (a cell next to the cells
   seen outside its footprint; the edges of its holes - objects on a roof, a courtyard - say
   nothing of what bounds it, nor does the raster's edge) stands on a *step* when, along some
   direction ``d`` leaving the region, the ground beyond a wall of one or two cells (cells
   ``a = p + j d``, ``j`` = 2 or 3, and ``b = a + 2 d``, both voted ground, outside the region
   and not rims themselves) continues below it: ``z(p) - (z(a) + j (z(a) - z(b)) / 2) > s``, the
   straight continuation of the ground beyond the wall extended to ``p``. A slope wider than the
   wall (a bank, a hillside, an embankment's side) carries its own continuation up to ``p`` and
   is no step. The region is *bounded by steps* when more than half of its outer outline cells
   stand on steps (a majority, as in the vote).
3. **Above the ground around.** A plane is fitted (least squares) to the ground cells ``a``
   beyond the outer outline; the region is an object when more than half of its cells stand
   more than ``t`` above that plane. A terrace's upper level joined to the lower ground by a
   bank or a ramp over more than half of its seen outline, a plateau, a hilltop or a dam with
   banks of more than two cells fails the outline test; a region that sinks below the ground
   around behind its walls fails the plane. An upper level whose whole seen edge is a wall
   and which runs off the raster elsewhere looks, within the raster, like a roof running off it
   (lidar ``sample_c``: a roof over 75-80 % of its tile); within the stage's reach it is taken
   as one. A terrain step running across the raster (a retaining wall, a river's walls, quarry
   benches) is such a level whose wall meets two opposite sides: mirrored at both, the wall is
   beyond the stage's reach unless shorter than a third of it (a 5 m step across a 200 m tile at
   1 m cells came out half objects before). The reach is that of the walls, not of the level's
   own box: ``sample_c``'s roof meets all four sides of its tile (a corner of it at one side, by
   a few cells or none depending on the cell size) while its one wall cuts off the opposite
   corner, and the level's box mirrored at both pairs of sides left it to the vote at 0.5 and
   4 m and took it at 2 m. Its wall ends on the left side next to the bottom corner, so at 1-4 m
   the roof's own corner beside the wall's end reaches the bottom side too: the outline's box
   mirrored there ran 225-228 m, beyond the 200 m of the geodesic and morphological filters'
   raised regions (which kept the roof at 1, 2 and 4 m); the ground at the wall's foot does not
   reach the bottom, and the wall is mirrored at the top and left sides only (150-152 m). A roof
   stands on the ground: a level the raster cuts on two opposite sides is judged only while the
   ground seen beyond its walls steps down no further (rims of the scale beyond its own, over at
   most half as many cells as its outer outline); quarry
   benches or terraces around a pit in a corner of the raster are a sequence of such levels,
   each stepping down to the next, and are left to the vote.

The decided regions and their rims (voted ground cells next to the region standing more than
``t`` above the plane: the cells on top of the walls) become objects; the DTM is then
interpolated under them from the ground around, as under every object.

**Blocks.** A region's decision depends on its cells and the 5 cells beyond its outline.
Regions spanning more than ``max_cells`` cells (rows or columns) are never candidates, so the
decision about any cell depends on cells within ``max_cells`` + :data:`REACH_CELLS` of it
(:func:`regions_halo`): a region reaching a block's window edge spans more than that and is
left alone there as in the single pass (the mirror at the edge is only ever used on regions
cut by the raster's own edge). ``bareearth:dtm`` takes ``max_cells`` as twice the
widest window of its members (:func:`.dtm.region_scales`): one more doubling of the windows;
or, where the data shows a longer raised region standing on walls (a hall of 180 x 260 m), that
region's span (:func:`~.estimate.raised_region_span`, on the whole raster in the resolve, at most
:data:`~.estimate.RAISED_REGION_SPAN_M`), the halo growing with it; longer regions (a roof running off
the raster, a mall longer than that) are left to the vote and, where known, to the user's object areas.
"""
import math

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .codes import GROUND
from .common import report, steps_beyond, walls_runs
from .geodesic.grey import filter3x3

#: Cells beyond a region's outline its decision reads: the wall (1-2 cells), the ground beyond
#: it (``a`` at 2-3 cells, ``b`` 2 cells further) and the rim test's neighbours.
REACH_CELLS = 8
#: The narrowest level cut into a hillside the stage looks at, in cells: an outline around one cell inside.
CUT_IN_MIN_CELLS = 3
#: The eight directions (row, column) leaving a cell.
_DIRECTIONS = tuple((dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc)


def regions_halo(max_cells):
    """Cells a decision of :func:`find_raised_regions` depends on around a cell (0: off)."""
    return int(max_cells) + REACH_CELLS if max_cells > 0 else 0


def _shifted(a, pad, dr, dc, k):
    """``a[r + k dr, c + k dc]`` for every cell ``(r, c)`` of the unpadded array (``a`` padded by ``pad``)."""
    h, w = a.shape[0] - 2 * pad, a.shape[1] - 2 * pad
    r0, c0 = pad + k * dr, pad + k * dc
    return a[r0:r0 + h, c0:c0 + w]


def find_raised_regions(z, mask, cell_size, *, tolerance_m, min_width_m, max_cells, min_cells=0, progress=None):
    """Voted ground regions wider than the vote's windows that stand on steps above the ground around.

    Parameters
    ----------
    z : ndarray, 2-D float32
        The DSM (NaN nodata).
    mask : ndarray of uint8
        The vote's decision (0 ground).
    cell_size : (float, float)
        Metres.
    tolerance_m : float
        ``t``: the object height threshold (a region above the ground around, by more) and the first scale
        ``s`` of the walls cutting the regions (a step, by more).
    min_width_m : float
        Regions narrower than this are left to the vote (the window of the vote's majority).
    max_cells : int
        Regions spanning more cells (rows or columns), or wider (mirrored at the raster's edge), are left
        alone (the stage's reach, see :func:`regions_halo`); 0 turns the stage off.
    min_cells : int
        Regions spanning at most this many cells (rows or columns; three times as many for a region the
        raster's edge cuts, as far as its walls' run mirrored there reaches) are not candidates: for a caller
        looking only for regions longer than a reach it already has (:func:`~.estimate.raised_region_span`).
    progress : callable, optional
        ``progress(fraction)`` after the regions are labelled and after each scale (may raise ``Cancelled``).

    Returns
    -------
    objects : ndarray of bool
        The cells of the decided regions and their rims.
    decisions : list of dict
        One per candidate region (once, at the first scale it is an object at, else the first it is a
        candidate at): its bounding box (cells), the scale ``s`` (m), size, width (m), the run of its walls
        mirrored at the raster's edge (``walls_m``) and whether the stage reaches it (``reached``; if not, it
        is left to the vote), for a region the raster cuts on two opposite sides the rims beyond its own
        (``steps_beyond``; more than half its outline cells leave it to the vote), share of outline cells on
        steps, share of cells above the plane of the ground around, and the decision.
    """
    z = np.asarray(z, np.float32)
    shape = z.shape
    objects = np.zeros(shape, bool)
    if max_cells <= 0 or min(shape) < 3:
        return objects, []
    t = float(tolerance_m)
    valid = np.isfinite(z)
    ground = (np.asarray(mask) == GROUND) & valid
    if not ground.any():
        return objects, []
    zi = np.where(valid, z, np.float32(np.inf))                # float32, as z (no second copy)
    # the 3 x 3 minimum (cells beyond the raster ignored: ndimage's mode "nearest", the same values) by banded
    # shifted minima, ~10x faster than SciPy's generic filter
    drop = z - filter3x3(zi, np.minimum, np.inf)
    del zi
    highest = float(np.max(drop, where=ground, initial=0.0))      # the highest drop: no scale cuts more above it
    # the regions of the first scale, labelled once; a higher scale frees some of their rims (the cells its
    # walls no longer cut), which join them: its regions are found by merging (:class:`_Scales`)
    scales = _Scales(ground, drop, t)
    # the voted ground cells next to a level object cell (no neighbour more than 2 t lower): where a level the vote
    # split meets its ground part, the only places a level cut into a hillside (below) can hold voted ground
    seeds = _split_level_seeds(valid, ground, drop, 2.0 * t)
    # the scales t, 2 t, 4 t, ... up to the first at least the highest drop: a report after each
    n_scales = 1 + max(0, math.ceil(math.log2(highest / t))) if highest > t > 0 else 1
    report(progress, 0.2)
    done = 0
    decided = {}                                        # each region once: its first object decision, else its first
    step_m, cut = t, -1

    def record(made):
        for d in made:
            key = (tuple(d["bbox"]), d["cells"])
            if key not in decided or (d["object"] and not decided[key]["object"]):
                decided[key] = d

    while True:
        # the walls higher than step_m cut the ground into regions; a scale cutting the same cells as the one
        # before repeats its regions with fewer steps (a subset of its objects): skipped
        rims = scales.rims(step_m)
        if rims != cut:
            found, made = _raised_at(z, valid, ground, drop, scales, cell_size, t, step_m, min_width_m, max_cells,
                                     min_cells)
            objects |= found
            record(made)
        # the levels cut into a hillside, at the scales of a roof's unevenness (t, 2 t): their object part is cut
        # at walls higher than s too
        if seeds.size and step_m <= 2.0 * t:
            for sl, found, made in _cut_in_at(z, valid, ground, drop, scales, seeds, cell_size, t, step_m,
                                              min_width_m):
                objects[sl] |= found
                record(made)
        cut = rims
        done += 1
        report(progress, 0.2 + 0.8 * min(1.0, done / n_scales))
        if step_m >= highest:
            break
        step_m *= 2.0
    report(progress, 1.0)
    return objects, list(decided.values())


class _Scales:
    """The regions of :func:`find_raised_regions` at each scale ``s``: the voted ground cells with no
    8-neighbour more than ``s`` lower, 8-connected.

    The first scale's regions are labelled once (``ndimage.label``); the cells of a higher scale's regions
    are those and the first scale's rims whose drop is at most ``s`` (a few per cent of the cells), so a
    higher scale's regions are the first scale's joined through those rims: a graph of the first regions
    and the freed rims, joined where 8-neighbours, and its connected components. Only the regions the
    cheap tests (span, reach) keep are written into a raster, numbered in the order of their first cell
    in raster order, as ``ndimage.label`` numbers them: the same regions, boxes and numbers.
    """

    def __init__(self, ground, drop, t):
        self.shape = ground.shape
        self.drop = drop
        self.ground = ground
        rim = ground & (drop > t)
        self.rim = np.flatnonzero(rim)                  # the first scale's rims, in raster order
        self.rim_drop = drop.ravel()[self.rim]
        self.labels, self.n = ndimage.label(ground & ~rim, structure=np.ones((3, 3), bool))
        del rim
        boxes = ndimage.find_objects(self.labels)
        self.r0 = np.array([b[0].start for b in boxes], np.int64)
        self.r1 = np.array([b[0].stop for b in boxes], np.int64)
        self.c0 = np.array([b[1].start for b in boxes], np.int64)
        self.c1 = np.array([b[1].stop for b in boxes], np.int64)
        self._components = None

    def rims(self, step_m):
        """Cells the walls higher than ``step_m`` cut (voted ground with a neighbour more than that lower)."""
        return int(np.count_nonzero(self.rim_drop > step_m))

    def free(self, step_m):
        """The cells of the regions at scale ``step_m`` (bool raster)."""
        return self.ground & ~(self.drop > step_m)

    def components(self, step_m):
        """The regions at scale ``step_m`` as components of the graph: ``(new, comp, r0, r1, c0, c1)``, ``new``
        the rims this scale frees (flat indices, raster order), ``comp`` each node's component (node 0 the
        background, ``1..n`` the first scale's regions, ``n + 1 + k`` the freed rim ``new[k]``) and the
        components' boxes (rows and columns, stop exclusive; a component holding no cell has an empty box).
        The last scale's are kept: the raised regions and the levels cut into a hillside read the same."""
        if self._components is not None and self._components[0] == step_m:
            return self._components[1]
        H, W = self.shape
        n = self.n
        new = self.rim[~(self.rim_drop > step_m)]           # the rims this scale frees, in raster order
        m = new.size
        heads, tails = [], []
        if m:
            nr, nc = np.divmod(new, W)
            lab_flat = self.labels.ravel()
            for dr, dc in _DIRECTIONS:                      # each freed cell and its 8 neighbours
                i = np.flatnonzero((nr + dr >= 0) & (nr + dr < H) & (nc + dc >= 0) & (nc + dc < W))
                q = new[i] + dr * W + dc
                node = lab_flat[q].astype(np.int64)         # a first region's cell: its label
                k = np.minimum(np.searchsorted(new, q), m - 1)
                freed = (node == 0) & (new[k] == q)          # a freed rim: its node after the labels
                node[freed] = n + 1 + k[freed]
                on = node > 0
                heads.append(n + 1 + i[on])
                tails.append(node[on])
        a = np.concatenate(heads) if heads else np.zeros(0, np.int64)
        b = np.concatenate(tails) if tails else np.zeros(0, np.int64)
        size = n + 1 + m
        graph = coo_matrix((np.ones(a.size, np.int8), (a, b)), shape=(size, size))
        k_n, comp = connected_components(graph, directed=False)
        # each component's box: the first regions' boxes and the freed cells'
        nr, nc = np.divmod(new, W)
        r0 = np.full(k_n, H, np.int64)
        r1 = np.zeros(k_n, np.int64)
        c0 = np.full(k_n, W, np.int64)
        c1 = np.zeros(k_n, np.int64)
        for lo_hi, first, rest, ufunc in ((r0, self.r0, nr, np.minimum), (r1, self.r1, nr + 1, np.maximum),
                                           (c0, self.c0, nc, np.minimum), (c1, self.c1, nc + 1, np.maximum)):
            ufunc.at(lo_hi, comp[1:], np.concatenate([first, rest]))
        self._components = (step_m, (new, comp, r0, r1, c0, c1))
        return self._components[1]

    def component_of(self, cells, step_m):
        """The component (:meth:`components`) of each of ``cells`` (flat indices of cells of the regions at
        scale ``step_m``: voted ground with no neighbour more than ``step_m`` lower)."""
        new, comp = self.components(step_m)[:2]
        node = self.labels.ravel()[cells].astype(np.int64)
        rest = node == 0                                    # a freed rim: its node after the labels
        if rest.any():
            node[rest] = self.n + 1 + np.searchsorted(new, cells[rest])
        return comp[node]

    def regions(self, step_m, keep):
        """The regions at scale ``step_m`` passing ``keep(r0, r1, c0, c1)`` (arrays of their boxes' rows and
        columns, stop exclusive, one per region: a boolean per region): ``(lab, boxes)``, ``lab`` the raster
        of those regions numbered 1, 2, ... in the order of their first cell (0 elsewhere), ``boxes`` their
        bounding boxes (slices) in that order; ``(None, [])`` when none passes."""
        H, W = self.shape
        n = self.n
        new, comp, r0, r1, c0, c1 = self.components(step_m)
        k_n = r0.size
        real = np.zeros(k_n, bool)
        real[comp[1:]] = True                               # components holding a cell (not the background)
        sel = np.flatnonzero(real & keep(r0, r1, c0, c1))
        if sel.size == 0:
            return None, []
        # the kept components written into a raster (numbers in component order first)
        num = np.zeros(k_n, np.int32)
        num[sel] = np.arange(1, sel.size + 1, dtype=np.int32)
        node_num = num[comp]
        lab = node_num[:n + 1].take(self.labels)
        lab.ravel()[new] = node_num[n + 1:]
        # renumbered in the order of their first cell (the first row of the box holds it)
        first = np.array([r0[j] * W + c0[j] + int(np.argmax(lab[r0[j], c0[j]:c1[j]] == q + 1))
                          for q, j in enumerate(sel)], np.int64)
        order = np.argsort(first, kind="stable")
        renum = np.zeros(sel.size + 1, np.int32)
        renum[order + 1] = np.arange(1, sel.size + 1, dtype=np.int32)
        lab = renum.take(lab)
        sel = sel[order]
        boxes = [(slice(int(r0[j]), int(r1[j])), slice(int(c0[j]), int(c1[j]))) for j in sel]
        return lab, boxes


def _raised_at(z, valid, ground, drop, scales, cell_size, t, step_m, min_width_m, max_cells, min_cells=0):
    """The raised regions of :func:`find_raised_regions` cut at walls higher than ``step_m``."""
    shape = z.shape
    cell = float(min(cell_size))

    def keep(r0, r1, c0, c1):
        # a region cut by the raster's edge may continue beyond it: seen mirrored there, twice as wide;
        # the stage reaches the regions spanning at most max_cells (its walls' run is tested below)
        spans = np.maximum(r1 - r0, c1 - c0)
        cut = (r0 == 0) | (c0 == 0) | (r1 == shape[0]) | (c1 == shape[1])
        return ((np.where(cut, 2, 1) * spans * cell >= min_width_m) & (spans <= max_cells)
                & (np.where(cut, 3, 1) * spans > min_cells))

    lab, boxes = scales.regions(step_m, keep)
    if lab is None:
        return np.zeros(shape, bool), []
    return _decide(z, valid, ground, drop, lab, boxes, cell_size, t, step_m, min_width_m, max_cells)


def _split_level_seeds(valid, ground, drop, level_m):
    """The voted ground cells next to a voted object cell with no neighbour more than ``level_m`` lower (a level
    the vote split between ground and objects meets its ground part there), flat indices in raster order."""
    flat = valid & ~ground & ~(drop > level_m)
    if not flat.any():
        return np.zeros(0, np.int64)
    near = filter3x3(flat.view(np.uint8), np.maximum, 0).view(bool)
    del flat
    near &= ground
    return np.flatnonzero(near)


def _cut_in_at(z, valid, ground, drop, scales, seeds, cell_size, t, step_m, min_width_m):
    """The levels cut into a hillside of :func:`find_raised_regions` at scale ``step_m``.

    A level here is an 8-connected region of the cells (voted ground or objects) with no neighbour more than
    ``s`` lower (``s`` is ``t`` or ``2 t``); a candidate holds voted ground and more
    voted objects, and is narrower than ``min_width_m``. Its ground part is a region of the raised-region
    stage at this scale (:class:`_Scales`) narrower than that and away from the raster's edge, next to a level
    object cell (a ``seeds`` cell): only those are looked at, each in a window reaching ``min_width_m``
    beyond it (a level spanning more is no candidate), so the levels are labelled on a few windows, not on
    the raster. Yields ``(slices, objects, decisions)`` per window.
    """
    H, W = z.shape
    cell = float(min(cell_size))
    dflat, gflat, vflat = drop.ravel(), ground.ravel(), valid.ravel()
    at = seeds[~(dflat[seeds] > step_m)]                # the seeds on this scale's ground regions
    r, c = np.divmod(at, W)
    touch = np.zeros(at.size, bool)
    for dr, dc in _DIRECTIONS:                          # next to a level object cell at this scale
        i = np.flatnonzero((r + dr >= 0) & (r + dr < H) & (c + dc >= 0) & (c + dc < W))
        q = at[i] + dr * W + dc
        touch[i[vflat[q] & ~gflat[q] & ~(dflat[q] > step_m)]] = True
    at = at[touch]
    if at.size == 0:
        return
    _, _, r0, r1, c0, c1 = scales.components(step_m)
    comp = scales.component_of(at, step_m)
    narrow = ((np.maximum(r1 - r0, c1 - c0)[comp] * cell < min_width_m) & (r0[comp] > 0) & (c0[comp] > 0)
              & (r1[comp] < H) & (c1[comp] < W))
    at, comp = at[narrow], comp[narrow]
    if at.size == 0:
        return
    # the cut: a voted ground cell of the ground part below the continuation of the ground 2-3 cells beyond it
    # (the outline test of _decide on every such cell of the part's box): only the parts holding one
    ids = np.unique(comp)
    ids = ids[_below_ground_beyond(z, ground, drop, r0[ids], r1[ids], c0[ids], c1[ids], step_m)]
    if ids.size == 0:
        return
    keep = np.isin(comp, ids)
    at, comp = at[keep], comp[keep]
    # windows: the ground parts' boxes widened by the widest candidate (and one cell), joined where they
    # overlap through a coarse grid of blocks that wide
    reach = int(math.ceil(min_width_m / cell)) + 1
    blocks = np.zeros(((H + reach - 1) // reach, (W + reach - 1) // reach), bool)
    for j in ids.tolist():
        blocks[max(0, r0[j] - reach) // reach:(min(H, r1[j] + reach) - 1) // reach + 1,
               max(0, c0[j] - reach) // reach:(min(W, c1[j] + reach) - 1) // reach + 1] = True
    groups, _ = ndimage.label(blocks)
    ar, ac = np.divmod(at, W)
    for box in ndimage.find_objects(groups):
        a0, a1 = box[0].start * reach, min(H, box[0].stop * reach)
        b0, b1 = box[1].start * reach, min(W, box[1].stop * reach)
        # the window decided on: the labelled one and the cells a decision reads beyond it
        e0, e1 = max(0, a0 - REACH_CELLS), min(H, a1 + REACH_CELLS)
        f0, f1 = max(0, b0 - REACH_CELLS), min(W, b1 + REACH_CELLS)
        sl = (slice(e0, e1), slice(f0, f1))
        zw, vw, gw, dw = z[sl], valid[sl], ground[sl], drop[sl]
        cells = vw & ~(dw > step_m)
        inner = np.zeros(cells.shape, bool)
        inner[a0 - e0:a1 - e0, b0 - f0:b1 - f0] = True
        cells &= inner
        lab, n = ndimage.label(cells, structure=np.ones((3, 3), bool))
        mine = (ar >= a0) & (ar < a1) & (ac >= b0) & (ac < b1)
        hit = np.zeros(n + 1, bool)
        hit[lab[ar[mine] - e0, ac[mine] - f0]] = True
        hit[0] = False
        n_cells = np.bincount(lab.ravel(), minlength=n + 1)
        n_voted = np.bincount(lab[gw], minlength=n + 1)
        # candidates: more voted objects than ground, narrower than the vote's windows, not reaching the
        # labelled window's edge (a level reaching it spans more than the widest candidate, or is cut by the
        # raster's edge and not seen whole)
        boxes = ndimage.find_objects(lab)
        cand = []
        for i in np.flatnonzero(hit & (n_voted > 0) & (2 * n_voted < n_cells)).tolist():
            b = boxes[i - 1]
            span = max(b[0].stop - b[0].start, b[1].stop - b[1].start)
            if (CUT_IN_MIN_CELLS <= span and span * cell < min_width_m and b[0].start > a0 - e0
                    and b[1].start > b0 - f0 and b[0].stop < a1 - e0 and b[1].stop < b1 - f0):
                cand.append(i)
        if not cand:
            continue
        num = np.zeros(n + 1, np.int32)
        num[cand] = np.arange(1, len(cand) + 1, dtype=np.int32)
        found, made = _decide(zw, vw, gw, dw, num[lab], [boxes[i - 1] for i in cand], cell_size, t, step_m,
                              min_width_m, 0, cut_in=True, origin=(e0, f0))
        yield sl, found, made


def _below_ground_beyond(z, ground, drop, r0, r1, c0, c1, step_m):
    """Per box (rows ``r0:r1``, columns ``c0:c1``), whether one of its voted ground cells ``p`` with no neighbour
    more than ``step_m`` lower stands more than ``step_m`` below the straight continuation of such ground beyond
    it along some direction ``d`` (cells ``a = p + j d``, ``j`` = 2 or 3, and ``b = a + 2 d``: :func:`_decide`'s
    cut-in test, whatever the region); the boxes' cells enumerated and tested all at once."""
    H, W = z.shape
    h, w = r1 - r0, c1 - c0
    size = h * w
    own = np.repeat(np.arange(size.size), size)
    local = np.arange(own.size) - np.repeat(np.cumsum(size) - size, size)
    p = (r0[own] + local // w[own]) * W + c0[own] + local % w[own]
    zf, gf, df = z.ravel(), ground.ravel(), drop.ravel()
    on = gf[p] & ~(df[p] > step_m)
    p, own = p[on], own[on]
    r, c = np.divmod(p, W)
    zp = zf[p].astype(np.float64)
    hit = np.zeros(p.size, bool)
    for dr, dc in _DIRECTIONS:
        for j in (2, 3):
            k = j + 2
            i = np.flatnonzero((r + k * dr >= 0) & (r + k * dr < H) & (c + k * dc >= 0) & (c + k * dc < W) & ~hit)
            a = p[i] + j * (dr * W + dc)
            b = p[i] + k * (dr * W + dc)
            ok = gf[a] & gf[b] & ~(df[a] > step_m) & ~(df[b] > step_m)
            za, zb = zf[a].astype(np.float64), zf[b].astype(np.float64)
            hit[i[ok & (za + j * (za - zb) / 2.0 - zp[i] > step_m)]] = True
    return np.bincount(own[hit], minlength=size.size) > 0


def _decide(z, valid, ground, drop, lab, boxes, cell_size, t, step_m, min_width_m, max_cells, cut_in=False,
            origin=(0, 0)):
    """The decisions on the regions ``lab`` (numbered 1, 2, ... in the order of their first cell, ``boxes``
    their boxes) at scale ``step_m``: the raised regions wider than ``min_width_m`` (and spanning at most
    ``max_cells``), or with ``cut_in`` the narrower levels cut into a hillside; the arrays are a window of the
    raster at ``origin`` (row, column) holding the cells each decision reads (:data:`REACH_CELLS`)."""
    shape = z.shape
    objects = np.zeros(shape, bool)
    cell = float(min(cell_size))
    idx = np.arange(1, len(boxes) + 1)
    free = ground & ~(drop > step_m)
    rim = ground & (drop > step_m)
    pad = 6
    lp = np.pad(lab, pad, constant_values=-1)              # -1: beyond the raster
    fp = np.pad(free, pad, constant_values=False)
    zp = np.pad(np.where(valid, z, np.nan), pad, constant_values=np.nan)
    outline = (lab > 0) & np.any([_shifted(lp, pad, dr, dc, 1) != lab for dr, dc in _DIRECTIONS], axis=0)
    step = np.zeros(shape, bool)
    uphill = np.zeros(shape, bool) if cut_in else None  # outline cells below the ground beyond (cut into it)
    samples = []                                        # (region, row, col, z) of the ground beyond the outline
    rows, cols = np.nonzero(outline)
    zo, lo = z[rows, cols], lab[rows, cols]
    for dr, dc in _DIRECTIONS:
        leaves = _shifted(lp, pad, dr, dc, 1)[rows, cols] != lo
        for j in (2, 3):
            la = _shifted(lp, pad, dr, dc, j)[rows, cols]
            ok = (leaves & _shifted(fp, pad, dr, dc, j)[rows, cols] & _shifted(fp, pad, dr, dc, j + 2)[rows, cols]
                  & (la != lo) & (_shifted(lp, pad, dr, dc, j + 2)[rows, cols] != lo))
            za = _shifted(zp, pad, dr, dc, j)[rows, cols]
            zb = _shifted(zp, pad, dr, dc, j + 2)[rows, cols]
            cont = za + j * (za - zb) / 2.0             # the ground beyond the wall continued to p
            on = ok & (zo - cont > step_m)
            step[rows[on], cols[on]] = True
            if cut_in:
                up = ok & (cont - zo > step_m)
                uphill[rows[up], cols[up]] = True
            samples.append((lo[ok], rows[ok], cols[ok], rows[ok] + j * dr, cols[ok] + j * dc, za[ok]))
    s_lab, s_pr, s_pc, s_r, s_c = (np.concatenate([s[q] for s in samples]) for q in range(5))
    s_z = np.concatenate([s[5] for s in samples]).astype(np.float64)
    order = np.argsort(s_lab, kind="stable")            # each region's samples in the same order in any window
    s_lab, s_pr, s_pc, s_r, s_c, s_z = (v[order] for v in (s_lab, s_pr, s_pc, s_r, s_c, s_z))
    starts = np.searchsorted(s_lab, idx, side="left")
    stops = np.searchsorted(s_lab, idx, side="right")
    if cut_in:
        # per level: its outline cells below the ground beyond them and on no step (its cut-in side)
        n_up = np.bincount(lab[uphill & ~step], minlength=len(boxes) + 1)
    decisions = []
    for k, i in enumerate(idx):
        box = boxes[k]
        r0, c0 = box[0].start, box[1].start
        if cut_in and n_up[i] < CUT_IN_MIN_CELLS:
            continue                                    # not cut into a hillside
        # the region and its rim (one cell around it), in coordinates relative to its box's corner
        g0, g1 = max(r0 - 1, 0), max(c0 - 1, 0)
        sub = (slice(g0, min(box[0].stop + 1, shape[0])), slice(g1, min(box[1].stop + 1, shape[1])))
        reg = lab[sub] == i
        # its footprint (holes filled: objects on a roof, a courtyard) and the footprint's width:
        # twice the largest distance from a cell's centre to the nearest cell outside it (the
        # raster's edge included: only what is seen), less one cell (a row of cells is one wide)
        filled = ndimage.binary_fill_holes(np.pad(reg, 1))
        # beyond the raster's edge nothing is seen: the region may continue there (the cells beyond
        # count as its own, as a profile cut by the edge is mirrored there)
        beyond = np.zeros(filled.shape, bool)
        beyond[0] |= r0 == 0
        beyond[-1] |= box[0].stop == shape[0]
        beyond[:, 0] |= c0 == 0
        beyond[:, -1] |= box[1].stop == shape[1]
        seen = ~filled & ~beyond                         # the cells seen outside its footprint
        if not seen.any():
            continue
        dist = ndimage.distance_transform_edt(~seen, sampling=(cell_size[1], cell_size[0]))[1:-1, 1:-1]
        width = 2.0 * float(dist[reg].max()) - cell
        if not cut_in and (width < min_width_m or width > max_cells * cell):
            continue
        # its outer outline: cells next to the outside seen, not to its holes (which say nothing of what
        # bounds it) nor to the raster's edge (nothing is known beyond it)
        outer = reg & ndimage.binary_dilation(seen, structure=np.ones((3, 3), bool))[1:-1, 1:-1]
        cells = int(np.count_nonzero(reg))
        d = {"bbox": [int(r0) + origin[0], int(c0) + origin[1], int(box[0].stop) + origin[0],
                      int(box[1].stop) + origin[1]], "step_m": round(step_m, 3), "cells": cells,
             "width_m": round(width, 1)}
        walls = reg
        if cut_in:
            # cut into a hillside: its outline cells below the ground beyond them and on no step, at least as
            # many as the level is wide (and it at least CUT_IN_MIN_CELLS wide); its walls are its other
            # outline cells, and only its voted ground (and the rims on top of its walls) turns into objects
            cut = outer & uphill[sub] & ~step[sub]
            n_cut = int(np.count_nonzero(cut))
            if (width >= min_width_m or n_cut * cell < width or width < CUT_IN_MIN_CELLS * cell
                    or not (cut & ground[sub]).any()):
                continue
            outer = outer & ~cut
            walls = reg & ~cut
            d.update(cut_in_cells=n_cut, voted_ground_cells=int(np.count_nonzero(reg & ground[sub])))
        n_outer = int(np.count_nonzero(outer))
        step_share = float(np.count_nonzero(outer & step[sub])) / max(1, n_outer)
        d.update(outline_cells=n_outer, step_share=round(step_share, 3), above_share=None, object=False)
        a, b = starts[k], stops[k]
        use = outer[s_pr[a:b] - g0, s_pc[a:b] - g1]      # the ground beyond the outer outline
        if not cut_in:
            # the run of its walls (the outer outline's box) mirrored at every side of the raster they meet, a
            # side both their top (the outer outline) and the ground at their foot (the cells a the step test
            # reads beyond them) reach: a wall running across the raster (meeting two opposite sides: a terrain
            # step, a river's wall, quarry benches) continues beyond both and spans three times what is seen;
            # the stage reaches the region only if it reaches that run (a wall cutting off a corner of the
            # raster meets two adjacent sides). A level cut into a hillside is seen whole: none of this applies.
            o_r, o_c = np.nonzero(outer)
            run = int(walls_runs(o_r + g0, o_c + g1, 1, 1, shape, s_r[a:b][use], s_c[a:b][use], 1)[1])
            d.update(walls_m=round(run * cell, 1), reached=run <= max_cells)
            if not d["reached"]:
                decisions.append(d)                     # beyond the stage's reach: left to the vote
                continue
            if (r0 == 0 and box[0].stop == shape[0]) or (c0 == 0 and box[1].stop == shape[1]):
                # a level the raster cuts on two opposite sides, its walls within the reach (cutting off a
                # corner): a roof stands on the ground, and the ground seen beyond its walls steps down no
                # further; ground there stepping down again (walls of the scale beyond the region's own, the rims
                # not within 3 cells of it) along more than half as many cells as the region's outline makes it
                # one of a sequence of levels (quarry benches, terraces) the raster cuts: left to the vote
                d["steps_beyond"] = steps_beyond(reg, rim[sub])
                if d["steps_beyond"] > n_outer / 2:
                    decisions.append(d)
                    continue
        if step_share > 0.5 and np.count_nonzero(use) >= 3:
            # the plane of the ground beyond the outline, in coordinates centred on its samples
            x = (s_c[a:b][use] - c0).astype(np.float64) * cell_size[0]
            y = (s_r[a:b][use] - r0).astype(np.float64) * cell_size[1]
            zs = s_z[a:b][use]
            xm, ym, zm = x.mean(), y.mean(), zs.mean()
            coef = np.linalg.lstsq(np.column_stack([x - xm, y - ym]), zs - zm, rcond=None)[0]
            rr, cc = np.mgrid[sub[0], sub[1]]
            plane = zm + coef[0] * ((cc - c0) * cell_size[0] - xm) + coef[1] * ((rr - r0) * cell_size[1] - ym)
            above = z[sub] - plane > t
            share = float(np.count_nonzero(above & reg)) / max(1, cells)
            d["above_share"] = round(share, 3)
            if share > 0.5:
                d["object"] = True
                # its rims: on top of its walls
                near = ndimage.binary_dilation(walls, structure=np.ones((3, 3), bool))
                objects[sub] |= (reg & ground[sub]) | (near & rim[sub] & above)
        decisions.append(d)
    return objects, decisions


def _slices2(dr, dc, h, w):
    """Destination and source slices pairing each cell ``(i, j)`` with its neighbour ``(i + dr, j + dc)``."""
    rows = (slice(0, h - dr), slice(dr, h)) if dr >= 0 else (slice(-dr, h), slice(0, h + dr))
    cols = (slice(0, w - dc), slice(dc, w)) if dc >= 0 else (slice(-dc, w), slice(0, w + dc))
    return (rows[0], cols[0]), (rows[1], cols[1])


#: Rows per band of :func:`_level_edges` (a band's differences stay in the cache).
_EDGE_BAND_ROWS = 32


def _level_edges(z, valid, jump_m, s, dx, dy):
    """The cells more than ``jump_m + s d`` above one of their 8 neighbours at distance ``d`` (a level's
    edge; valid cells only count, the value elsewhere is meaningless).

    Each neighbour pair is differenced once (``z(p) - z(q) > thr`` marks ``p``, ``< -thr`` marks ``q``:
    float subtraction is exactly antisymmetric), in bands of rows whose differences stay in the cache
    (a footprint minimum filter is 8 times slower than shifted slices, full-size temporaries twice).
    """
    h, w = z.shape
    zn = z if not np.isinf(z).any() else np.where(valid, z, np.float32(np.nan))    # nodata: no comparison
    edge = np.zeros(z.shape, bool)
    rows = max(1, min(_EDGE_BAND_ROWS, h))
    d = np.empty((rows, w), np.float32)
    c = np.empty((rows, w), bool)
    with np.errstate(invalid="ignore"):
        for dr, dc in ((0, 1), (1, -1), (1, 0), (1, 1)):          # q = p + (dr, dc): the other four are -q
            thr = np.float32(jump_m + s * math.hypot(dr * dy, dc * dx))
            c0, c1 = max(0, -dc), w - max(0, dc)                  # columns of p whose q exists
            for r0 in range(0, h - dr, rows):
                r1 = min(h - dr, r0 + rows)
                n = r1 - r0
                dd, cc = d[:n, :c1 - c0], c[:n, :c1 - c0]
                np.subtract(zn[r0:r1, c0:c1], zn[r0 + dr:r1 + dr, c0 + dc:c1 + dc], out=dd)
                np.greater(dd, thr, out=cc)
                e = edge[r0:r1, c0:c1]
                np.logical_or(e, cc, out=e)
                np.less(dd, -thr, out=cc)
                e = edge[r0 + dr:r1 + dr, c0 + dc:c1 + dc]
                np.logical_or(e, cc, out=e)
    return edge


def _benched(z, levels, edge, labels, terrain, jump_m, s, dx, dy, ids, boxes):
    """Per level label, True where the level lies below the terrain's ground across a level change.

    ``terrain[label]``: the levels that are ground whatever this test says (joined to the undisputed
    ground, or too wide to judge). A level ``ids`` has a cell ``p`` with a neighbour ``q`` at distance
    ``d`` standing more than ``jump_m + s d`` above it, where ``q`` is a terrain level's cell or an edge
    cell on one (voted ground beside a terrain cell and not a level change above it; a wall's top
    above the terrain is not): the level is a bench of the slope below that ground, not a raised
    level. ``boxes``: the bounding boxes of the levels ``ids`` (``ndimage.find_objects``' slices). The test
    runs on the judged levels' own cells and the neighbours of their neighbours only, gathered (a few cells
    on most rasters; the same values as the pairs of shifted slices over the rows they span, 0.37 s per
    16 Mcells).
    """
    h, w = z.shape
    out = np.zeros(terrain.shape, bool)
    # the judged levels' cells, from their boxes (a loop over the few levels judged)
    cells = [np.flatnonzero(labels[br, bc] == i) for i, (br, bc) in zip(ids.tolist(), boxes)]
    if not cells:
        return out
    p = np.concatenate([(k // (bc.stop - bc.start) + br.start) * w + k % (bc.stop - bc.start) + bc.start
                        for k, (br, bc) in zip(cells, boxes)])
    zf, lf, lab_f, ef = z.ravel(), levels.ravel(), labels.ravel(), edge.ravel()
    r, c = np.divmod(p, w)
    zp = zf[p]

    def neighbour(rr, cc, dr, dc, ok):
        # the neighbour (dr, dc) of the cells (rr, cc) where ``ok`` and inside the raster: flat index, in it
        rr, cc = rr + dr, cc + dc
        ok = ok & (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
        return np.where(ok, rr * w + cc, 0), ok

    every = np.ones(p.size, bool)
    below = np.zeros(p.size, bool)
    with np.errstate(invalid="ignore"):
        for dr, dc in _DIRECTIONS:
            thr = np.float32(jump_m + s * math.hypot(dr * dy, dc * dx))
            q, ok = neighbour(r, c, dr, dc, every)
            zq = zf[q]
            # q is near the terrain: on a terrain level, or an edge cell on one (within a level change of one)
            near = ok & lf[q] & terrain[lab_f[q]]
            on_edge = ok & ef[q]
            if on_edge.any():
                for dr2, dc2 in _DIRECTIONS:
                    thr2 = np.float32(jump_m + s * math.hypot(dr2 * dy, dc2 * dx))
                    q2, ok2 = neighbour(r + dr, c + dc, dr2, dc2, on_edge)
                    near |= ok2 & lf[q2] & terrain[lab_f[q2]] & (zq - zf[q2] <= thr2)
            below |= near & (zq - zp > thr)
    out[np.unique(lab_f[p[below]])] = True
    out[0] = False
    return out


#: The share of a level's outline a taller object must hold for a level holding a few anchors to be a lower level
#: of a building (:func:`_lower_roofs`): one of the four sides of a rectangle.
TALLER_SIDE_SHARE = 0.25
#: The outline of a level :func:`_lower_roofs` reads, in cells: the level's edge cell (a wall's top at the level's
#: height) and the cell beyond it.
OUTLINE_CELLS = 2


def _lower_roofs(z, valid, ground, labels, ids, boxes, max_cells, jump_m, plane_m):
    """Per level of ``ids``, True where it is a lower roof of a building: a plane against a taller object.

    Three things a roof's lower level has and a piece of ground between level changes (the banks of ISPRS 61,
    a clearing among crowns) lacks together:

    * a *top*: a cell whose 8 neighbours lie on the level (beyond the raster: on it), as
      :func:`find_detached_levels` asks of another member's dissent (a patch one or two cells wide is a step
      of a slope);
    * a plane: the median absolute residual of its cells from their least-squares plane at most ``plane_m``
      (half the decision threshold: a roof face; ground between crowns or on a bank is rough);
    * a taller object along a side: of its outline (the cells within :data:`OUTLINE_CELLS` of it, off it), at
      least :data:`TALLER_SIDE_SHARE` stand more than ``jump_m`` (a level change) above the highest level cell
      within :data:`OUTLINE_CELLS` of them and are not voted ground (the level's own rise over that width is in
      that highest cell, so no slope allowance is added; a terrace below a rising hillside has voted ground
      above it, not an object).

    Levels spanning more than ``max_cells`` cells, or cut by the raster's edge, are not looked at (False): beyond
    the edge the level may hold the ground that joins it (``benchmarks/sites.py``, ``hillside`` 1 m highest point:
    two narrow terraces at the raster's edge, a house at the back of each, 126 cells of ground; in a window of
    blocks a level reaching the window's edge from a block's cell spans more than ``max_cells`` anyway).
    """
    h, w = z.shape
    k = OUTLINE_CELLS
    foot = np.ones((2 * k + 1, 2 * k + 1), bool)
    eight = np.ones((3, 3), bool)
    rise = np.float32(jump_m)
    out = np.zeros(len(ids), bool)
    for j, i in enumerate(np.asarray(ids).tolist()):
        b = boxes[i - 1]
        if b is None or max(b[0].stop - b[0].start, b[1].stop - b[1].start) > max_cells:
            continue
        if b[0].start == 0 or b[1].start == 0 or b[0].stop == h or b[1].stop == w:
            continue                                     # cut by the raster's edge: its anchors may lie beyond
        r0, r1 = max(0, b[0].start - k), min(h, b[0].stop + k)
        c0, c1 = max(0, b[1].start - k), min(w, b[1].stop + k)
        on = labels[r0:r1, c0:c1] == i
        if not ndimage.binary_erosion(on, eight, border_value=1).any():
            continue                                     # no top
        zz = z[r0:r1, c0:c1]
        rr, cc = np.nonzero(on)
        a = np.column_stack([rr.astype(np.float64), cc.astype(np.float64), np.ones(rr.size)])
        zl = zz[rr, cc].astype(np.float64)
        coef = np.linalg.lstsq(a, zl, rcond=None)[0]
        if not np.median(np.abs(zl - a @ coef)) <= plane_m:
            continue                                     # no plane
        ring = ndimage.binary_dilation(on, foot) & ~on & valid[r0:r1, c0:c1]
        top = ndimage.maximum_filter(np.where(on, zz, -np.inf).astype(np.float32), footprint=foot)
        with np.errstate(invalid="ignore"):
            taller = ring & ~ground[r0:r1, c0:c1] & (zz > top + rise)
        n_ring = np.count_nonzero(ring)
        out[j] = n_ring > 0 and np.count_nonzero(taller) >= TALLER_SIDE_SHARE * n_ring
    return out


def find_detached_levels(z, ground, dissent, anchors, cell_size, *, jump_m, slope, max_cells, top_dissent=None,
                         plane_m=None):
    """The dissented ground of regions cut from every undisputed ground cell by level changes.

    ``bareearth:dtm``'s vote keeps a low roof (a flat annex or a lower level of a building, 3-4 m
    above the ground) wherever the opening and the reconstruction accept it: their thresholds
    grow with the window and the terrain slope they allow (the opening's ``s (w_k - w_{k-1})
    c + dh_0``: 5 m at its 16-32 m step with the slope floor 0.3), while RASCOR's level changes
    (Jacobsen 2004, step 4: a sudden change of level of at least ``jump_m``) reject it. Measured
    on the ISPRS samples (1 m lowest point, before this test): 101 cells of sample 31 (the
    opening and the reconstruction say ground, RASCOR object) are half object (146 of 281 cells
    with a point), the largest of its type II errors (low roofs 3-3.5 m high inside a courtyard
    of taller buildings, 2-4 m above the ground). Where RASCOR alone dissents elsewhere it is
    mostly wrong (sample 61: 25 of 3435 such cells are objects), so its dissent alone is not
    evidence; what decides is whether the ground continues.

    The mirror of :func:`.dtm_refine.continue_ground` (which gives the opening's lone ground back
    when it continues the ground every member agrees on): voted ground is cut into *levels*,
    8-connected regions separated by the cells standing more than ``jump_m + s d`` above a
    neighbour at distance ``d`` (a level change of RASCOR's size, beyond the terrain's slope
    allowance ``s d``; a bank's slope stays inside its level). A level holding no ``anchors``
    cell (ground every member agrees on) is a raised level the vote kept only by the members'
    allowances, and its ``dissent`` cells (ground by the vote, object by RASCOR: a low roof) are
    objects, and its ``top_dissent`` cells (object by another member: the opening on a tower cut by
    the raster's edge, beyond which the others see no ground) where the level has a *top*, a cell
    whose 8 neighbours all lie on it (a patch one or two cells wide between level changes is a step of
    a steep slope, which the opening rejects on steep banks; RASCOR's own dissent is a level change).
    Levels spanning more than ``max_cells`` cells (rows or columns) are left alone, so a cell's
    decision depends on cells within :func:`regions_halo` of it, the raised regions' reach.
    A level lying below the ground across a level change (a cell of it with a neighbour more than
    ``jump_m + s d`` above it on a level holding an anchor or too wide to judge, or on the edge of
    one: :func:`_benched`) is a bench of a steep slope on a coarse grid, not a raised level: left
    alone (``hexbin-crop`` at 4 m: a cliff's 15 cells holding 124 ground points).

    Parameters
    ----------
    z : ndarray, 2-D float32
        The DSM (NaN nodata).
    ground : ndarray of bool
        The voted ground (the levels are cut from it).
    dissent : ndarray of bool
        The cells that may become objects (``bareearth:dtm``: voted ground RASCOR rejects).
    anchors : ndarray of bool
        Ground every member agrees on: a level holding one is joined to the undisputed ground.
    cell_size : (float, float)
        ``(dx, dy)`` metres.
    jump_m : float
        Height of a level change, metres (> 0; RASCOR's ``jump_m``).
    slope : float
        ``s``, the terrain's steep slope (rise/run, >= 0; NaN: 0).
    max_cells : int
        Levels spanning more cells are left alone (0: nothing is looked for).
    top_dissent : ndarray of bool, optional
        Cells that may become objects on levels with a top only.
    plane_m : float, optional
        Given (``bareearth:dtm``: half its decision threshold), a level holding anchors, more than half of whose
        cells are ``dissent``, is still judged when it is a lower roof of a building (:func:`_lower_roofs`: a top,
        a plane within ``plane_m``, a taller object along a side, not cut by the raster's edge): a few cells of a
        low roof every member calls ground (ISPRS 31, 1 m: three cells of a 68-cell roof) do not join it to the
        ground. None: any anchor joins its level.

    Returns
    -------
    ndarray of bool
        The ``dissent`` cells of the levels holding no anchor.

    Examples
    --------
    >>> z = np.zeros((5, 9), np.float32)
    >>> z[1:4, 5:8] = 3.0                          # a low roof beside the ground
    >>> ground = np.ones(z.shape, bool)
    >>> anchors = z == 0
    >>> out = find_detached_levels(z, ground, z > 0, anchors, (1.0, 1.0), jump_m=2.0, slope=0.1, max_cells=20)
    >>> bool(out[2, 6]), int(out.sum())
    (True, 9)
    >>> z[1:4, 5:8] = [[0.5, 1.0, 1.5]]            # a bank rising by less than a level change per cell
    >>> bool(find_detached_levels(z, ground, z > 0, anchors, (1.0, 1.0), jump_m=2.0, slope=0.1,
    ...                           max_cells=20).any())
    False
    """
    z = np.asarray(z, np.float32)
    ground = np.asarray(ground, bool)
    dissent = np.asarray(dissent, bool)
    anchors = np.asarray(anchors, bool)
    if not (ground.shape == dissent.shape == anchors.shape == z.shape):
        raise ValueError(f"z {z.shape}, ground {ground.shape}, dissent {dissent.shape} and anchors "
                         f"{anchors.shape} must share the DSM's shape.")
    if not (np.isfinite(jump_m) and jump_m > 0):
        raise ValueError(f"jump_m must be a positive height in metres; got {jump_m}.")
    s = float(slope) if slope is not None and np.isfinite(slope) and slope > 0 else 0.0
    valid = np.isfinite(z)
    ground = ground & valid
    out = np.zeros(z.shape, bool)
    top_dissent = None if top_dissent is None else np.asarray(top_dissent, bool) & ~dissent
    cand = dissent & ground if top_dissent is None else (dissent | top_dissent) & ground
    if max_cells <= 0 or not cand.any():
        return out
    dx, dy = float(cell_size[0]), float(cell_size[1])
    h, w = z.shape
    edge = _level_edges(z, valid, jump_m, s, dx, dy)
    levels = ground & ~edge
    labels, n = ndimage.label(levels, structure=np.ones((3, 3), bool))
    if n == 0:
        return out
    # a level holding an anchor is joined (label 0, the cells off the levels, counts as joined)
    held = np.bincount(labels[anchors], minlength=n + 1)
    joined = held > 0
    joined[0] = True
    # a level the level member mostly rejects (more than half its cells, so fewer anchors than dissent) holding a
    # few anchors only, a lower roof of a building: judged all the same (the anchors are the members' common
    # error on its roof)
    few = joined & (2 * np.bincount(labels[dissent & levels], minlength=n + 1) > np.bincount(labels.ravel(),
                                                                                              minlength=n + 1))
    few[0] = False
    if plane_m is not None and few.any():
        ids_few = np.flatnonzero(few)
        boxes_few = ndimage.find_objects(labels, max_label=int(ids_few[-1]))
        roofs = _lower_roofs(z, valid, ground, labels, ids_few, boxes_few, max_cells, jump_m, float(plane_m))
        joined[ids_few[roofs]] = False
    # only the candidates' levels matter: their labels, without a raster-sized lookup
    at = np.flatnonzero(cand)
    lab = labels.ravel()[at]
    loose = ~joined[lab]                                # the candidates on levels holding no anchor
    if not loose.any():
        return out
    # each loose level's span (rows or columns); wider than max_cells: too wide to judge within the
    # reach, left to the vote
    ids = np.unique(lab[loose])
    boxes = ndimage.find_objects(labels, max_label=int(ids[-1]))
    span = np.array([max(boxes[i - 1][0].stop - boxes[i - 1][0].start, boxes[i - 1][1].stop - boxes[i - 1][1].start)
                     for i in ids.tolist()])
    judged = np.zeros(n + 1, bool)
    judged[ids] = span <= max_cells
    hit = judged[lab]
    if top_dissent is not None and hit.any():
        # a level has a top: a cell whose 8 neighbours all lie on it; ``top_dissent`` counts only there
        # (a patch one or two cells wide between level changes is a step of a steep slope, not a level)
        sel = [boxes[i - 1][0] for i in np.unique(lab[hit]).tolist()]
        b0, b1 = min(b.start for b in sel), max(b.stop for b in sel)
        e0, e1 = max(0, b0 - 1), min(h, b1 + 1)
        # 8-connected levels: a level cell's neighbours on levels are on its own (beyond the raster: the same)
        on = levels[e0:e1]
        inner = on.copy()
        for dst, src in (_slices2(dr, dc, e1 - e0, w) for dr, dc in _DIRECTIONS):
            inner[dst] &= on[src]
        inner = inner[b0 - e0:b1 - e0]
        lab_b = labels[b0:b1]
        has_top = np.bincount(lab_b[inner & (lab_b > 0)], minlength=n + 1) > 0
        hit &= dissent.ravel()[at] | has_top[lab]
    if hit.any():
        terrain = joined.copy()                          # joined levels and those too wide to judge
        terrain[ids[span > max_cells]] = True
        terrain[0] = False
        ids_hit = np.unique(lab[hit])
        hit &= ~_benched(z, levels, edge & ground, labels, terrain, jump_m, s, dx, dy, ids_hit,
                         [boxes[i - 1] for i in ids_hit.tolist()])[lab]
    if not hit.any():
        return out
    out.ravel()[at] = hit
    # the level's own edge (the cells on top of its walls) goes with it: next to the rows holding some
    r0, r1 = max(0, int(at[hit][0]) // w - 1), min(h, int(at[hit][-1]) // w + 2)
    o = out[r0:r1]
    near = o.copy()
    for _, (dst, src) in [((dr, dc), _slices2(dr, dc, r1 - r0, w)) for dr, dc in _DIRECTIONS]:
        near[dst] |= o[src]
    o |= cand[r0:r1] & edge[r0:r1] & near
    return out
