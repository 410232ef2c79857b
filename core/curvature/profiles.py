"""Profile scans and enclosed regions: steps 3 and 4 of the curvature filter.

Luong Chinh Ke (2002, sec. 2.2) reads the breaks along the X and Y profiles: the points
between a break going up and the matching break coming down belong to an object
(:func:`find_profile_objects`); where the raster's edge cuts an object, the profile is
taken as mirrored there (:func:`_cut_runs`), unless the region of such runs, mirrored at
the edges across the profiles too, is longer than the largest object (a terrain step running
across the raster, :func:`_drop_running_off`). Regions enclosed by breaks and made mostly of such points
become whole objects (:func:`find_enclosed_objects`).
"""
import functools
from typing import Optional

import numpy as np
from scipy import ndimage

from ..common import as_cell_size, as_surface, edge_mirrored_extents, pad_constant, report, sub_progress, transpose
from ..edge_walls import walled_levels
from ..estimate import (
    GROUND_BLOCK_M,
    lowest_point_spread,
    repeated_height_share,
    running_minimum,
    running_minimum_gradient,
)
from .derivatives import CHUNK_CELLS, CellSize, Progress

#: Width (cells) within which an object's wall rises, and how much steeper than the
#: profile before it the wall must be.
_WALL_CELLS = 2
_WALL_CONTRAST = 3.0
#: Widest horizontal span (m) over which the wall slope is judged (:func:`wall_rise`).
_WALL_SPAN_M = 3.0
#: Critical value of the scatter of two heights' places inside their cells (:func:`wall_rise`).
_SPREAD_K = 3.0
#: Longest object, in largest objects (the runs' length along a profile): one doubling, as the
#: longest raised region the resolves look at is one doubling of the widest
#: (:data:`~bare_earth.core.estimate.RAISED_REGION_SPAN_M`): a hall 115 m wide is 242 m long
#: (:func:`bounded_stretches`).
LONGEST = 2.0


def wall_rise(cell: float, *, h_min: float, tan_wall: float, terrain_slope: float = 0.0,
              spacing: float = 0.0) -> float:
    """Metres a profile must rise (or fall) within ``_WALL_CELLS`` cells of ``cell``
    metres to be an object's wall: the minimum object height ``h_min``, the rise of the
    wall slope over those cells, but over :data:`_WALL_SPAN_M` at most, and the rise of
    the terrain's steep slopes (``terrain_slope``, rise/run) over those cells.

    A vertical wall is smeared over two cells (one of them mixed), so over two cells the
    slope test demands ``2 cell tan(wall)``: 2 m at 1 m cells, but 8 m at 4 m cells,
    where no shrub, hedge or house would be a wall. Judged over at most
    :data:`_WALL_SPAN_M`, the demand stops growing where the raster no longer resolves
    the slope (it is unchanged up to 1.5 m cells). A rise the terrain itself makes over two
    cells is no wall either: at 24 m cells a 3 m rise over 48 m is a 3.6 degree slope, and
    every foot of a hillside rising from a valley floor passed the test (15 % of a
    bare-earth DEM of hills taken for objects). Where the cells are fine the wall slope
    sets the demand; where they are coarse, the terrain's own slopes do: their rise over the
    two cells, plus ``3 sqrt(2)`` times the scatter of where the two heights lie on that slope
    (each anywhere within its cell, or within ``spacing``, the longer:
    :func:`~bare_earth.core.estimate.lowest_point_spread`, ``s c / sqrt(12)``; the critical value
    of a difference of two heights, as RASCOR's step 3 takes it). Both are metres per metre of
    cell, the same test at every cell size. On lidar at 4 m cells a rock step of a hillside
    rises 4-6 m within one cell: lidar ``hexbin-crop`` at 4 m had its steps taken for walls
    (10.72 % total error -> 4.97 %, the lowest-point grid's own 4.97 %).

    The wall slope's span is the two cells or ``spacing`` (metres between independent
    heights, :func:`height_spacing`), the larger: a raster filled
    from points sparser than its cells repeats each point's height over the cells around it,
    so its profile climbs a slope in steps of one riser per point, and a vertical wall too
    lies between two points ``spacing`` apart, the last on the ground and the first on the
    roof. What rises less than the wall slope over that spacing cannot be told from the
    terrain: on ISPRS samp61 at 1 m (points 2.25 m apart where it has data), the risers of the staircase
    that a 25-30 degree embankment becomes, up to 2.2 m in one cell, were walls, and the
    embankments objects (3.2 % of its points wrong, two thirds of its 4.94 %; 3.67 % now). The same data
    at 2 m cells already had that demand (two cells are 4 m), so the rule makes the 1 m and
    2 m rasters of one survey agree; with a height per cell (``spacing`` = the cell) nothing
    changes.
    """
    span = max(_WALL_CELLS * float(cell), float(spacing))
    terrain = float(terrain_slope) * _WALL_CELLS * float(cell) + _SPREAD_K * np.sqrt(2.0) * lowest_point_spread(
        0.0, terrain_slope, max(float(cell), float(spacing)))
    return max(float(h_min), float(tan_wall) * min(span, _WALL_SPAN_M), terrain)


def terrain_rise_per_slope(cell: float, spacing: float = 0.0) -> float:
    """Metres per unit of slope (rise/run) that the terrain term of :func:`wall_rise` demands:
    the rise over ``_WALL_CELLS`` cells plus ``3 sqrt(2)`` times the scatter of two heights' places
    (:func:`~bare_earth.core.estimate.lowest_point_spread` without noise, ``s c / sqrt(12)``, ``c``
    the cell or ``spacing``, the longer): ``wall_rise(..., terrain_slope=s)`` is at least ``s`` times
    this, and :func:`_walls` demands it of the terrain's local slope at each wall."""
    c = max(float(cell), float(spacing))
    return _WALL_CELLS * float(cell) + _SPREAD_K * np.sqrt(2.0) * lowest_point_spread(0.0, 1.0, c)


def local_rise_cap(cell: float, tan_wall: float, spacing: float = 0.0) -> float:
    """The most (metres) that the terrain's local slope may demand of a wall (:func:`_walls`): the
    wall slope's rise over the wall's span, two cells or ``spacing`` (the longer), without
    :func:`wall_rise`'s cap of :data:`_WALL_SPAN_M`. Where that span is within the cap (cells up to
    1.5 m, heights no farther apart) the wall slope already demands it and the local slope changes
    nothing: a rise steeper than the wall slope is a wall whatever the terrain around (at 1 m cells a
    hall's side read as the terrain's slope beside it, and the low objects within 12 m of it, cars and
    annexes, lost their walls: ISPRS samp31 2.17 -> 2.81 %). Where it is longer, the raster cannot
    show the wall's slope, the test judges it over 3 m, and a flank of the terrain steeper than 3 m
    over two cells passes it unless its own slope is read."""
    return float(tan_wall) * max(_WALL_CELLS * float(cell), float(spacing))


def local_slope_cells(cell_size: CellSize) -> int:
    """Side (cells) of the running minimum whose slope is the terrain's local slope at a wall
    (:func:`local_terrain_slopes`): the 20 m block of the terrain's slopes
    (:data:`~bare_earth.core.estimate.GROUND_BLOCK_M`), at least 2 cells."""
    return max(2, int(round(GROUND_BLOCK_M / max(as_cell_size(cell_size)))))


def local_terrain_slopes(z: np.ndarray, cell_size: CellSize):
    """The terrain's local slope along X and along Y at every cell (rise/run, two float32 arrays):
    the absolute gradient of the running minimum over :func:`local_slope_cells` cells
    (:func:`~bare_earth.core.estimate.running_minimum_gradient`: objects narrower than 20 m vanish
    from it), the steepest within ``k // 2 + _WALL_CELLS`` cells along that axis: the minimum over
    the square moves a raised flank's slope half the square up it, and a wall spans two cells (a
    knoll's flank 8 m high at 4 m cells, its top at the wall: 0.1 at the top, 0.4 within that).
    Along the axis a profile scans, not the slope's magnitude: a hall wider than the square reads
    its own height ``H`` over the central differences' span, ``H / (2 (k // 2) cell)``, of which the
    wall test demands :func:`terrain_rise_per_slope` (over a cell) times: 0.16 / 0.32 / 0.82 ``H`` at
    1 / 2 / 4 m cells, less than its wall rises (diagonally, ``sqrt(2)`` times more: a
    6 m hall at 4 m cells lost four fifths of its walls). The direct form, raster-wide: the filter
    reads it at the few cells where a wall may stand (:class:`LocalSlopes`, the same values)."""
    k = local_slope_cells(cell_size)
    gx, gy = running_minimum_gradient(as_surface(z), as_cell_size(cell_size), k)
    out = []
    for g, axis in ((gx, 1), (gy, 0)):
        g = np.abs(np.nan_to_num(g, nan=0.0, posinf=0.0, neginf=0.0))
        out.append(ndimage.maximum_filter1d(g, 2 * (k // 2 + _WALL_CELLS) + 1, axis=axis, mode="nearest"))
    return tuple(out)


class LocalSlopes:
    """:func:`local_terrain_slopes` read at given cells only (:func:`_walls` needs it where a wall
    may stand, a few cells of the raster): the same float32 values, without raster-sized slopes.

    Holds the running minimum over :func:`local_slope_cells` ``k`` cells inside a frame of +inf
    (:func:`~bare_earth.core.estimate.running_minimum`; one raster-sized float32 array) wide
    enough for every read; :meth:`at` takes, at each asked cell, the central differences over
    ``k // 2`` on either side at the ``2 (k // 2 + _WALL_CELLS) + 1`` positions around it along
    the axis, and keeps the steepest finite one (0 at least: a position within ``k // 2`` of the
    raster's edge reads the frame, one beside a square without heights +inf, as the direct
    form's 0). A loop over those positions, on the asked cells only. The running minimum is
    computed at the first read: at cells up to 1.5 m the wall test never reads (:func:`_walls`).
    """

    def __init__(self, z: np.ndarray, cell_size: CellSize):
        self.z = as_surface(z)
        self.shape = self.z.shape
        self.cell = as_cell_size(cell_size)
        self.k = local_slope_cells(self.cell)
        self.half, self.around = self.k // 2, self.k // 2 + _WALL_CELLS
        self.frame = self.half + self.around
        self.minimum = None         # computed at the first read (none where the wall test never needs it)

    def at(self, idx: np.ndarray, frame: int, axis: int) -> np.ndarray:
        """The local slope along ``axis`` (1: X, the rows; 0: Y, the columns) at the flat indices
        ``idx`` of the raster inside a frame of ``frame`` cells (:func:`_framed`): float32, equal
        to ``local_terrain_slopes(z, cell_size)[1 - axis]`` there."""
        h, w = self.shape
        f, half = self.frame, self.half
        r, c = np.divmod(np.asarray(idx, np.int64), w + 2 * frame)
        q = r + (f - frame)
        q *= w + 2 * f
        q += c
        q += f - frame
        sd = 1 if axis == 1 else w + 2 * f
        d = np.float32(2 * half * self.cell[0 if axis == 1 else 1])
        best = np.zeros(q.size, np.float32)
        if self.minimum is None:
            self.minimum = running_minimum(self.z, self.k, frame=self.frame).ravel()
        mf = self.minimum
        with np.errstate(invalid="ignore"):
            for j in range(-self.around, self.around + 1):
                g = mf.take(q + (j + half) * sd)
                g -= mf.take(q + (j - half) * sd)
                g /= d
                np.abs(g, out=g)
                np.maximum(best, g, out=best, where=g < np.inf)     # not inf nor NaN: the frame, no heights
        return best


def height_spacing(z, cell_size) -> float:
    """Metres between the independent heights of the raster (the ``spacing`` of
    :func:`wall_rise`): the coarser cell over ``1 - share`` of the neighbours with exactly
    equal heights (:func:`~bare_earth.core.estimate.repeated_height_share`: a raster filled
    from fewer points than cells repeats a point's height over the cells around it), the cell
    where every cell has its own height. Level squares wider than two spacings of
    :data:`_WALL_SPAN_M` (water, a gap filled with one height, a noise-free plane) are left
    out: no single point fills them, and the wall test never uses a spacing above that span."""
    d = max(as_cell_size(cell_size))
    level = 2 * int(np.ceil(_WALL_SPAN_M / d)) + 1
    share = min(max(repeated_height_share(as_surface(z), level_cells=level), 0.0), 0.99)
    return d / (1.0 - share)


def _walls(zf, idx, sd, cell, *, reach, h_min, tan_wall, tol, terrain_slope=0.0, spacing=0.0, local=None):
    """Where the profiles through the flat cells ``idx`` (the marked cells, breaks), read in
    steps of ``sd`` flat cells, have just risen as a wall, and where they have just come
    down one.

    ``zf`` is the flat NaN-framed raster of :func:`_framed` (NaN at nodata and in the frame,
    so positions before a profile's start read NaN). The foot of position j is the lowest of
    the ``_WALL_CELLS`` positions before it. j is the top of a wall when

    * ``z_j - foot >= h_min`` (high enough) and steeper than the wall slope: ``z_j - foot
      >= _WALL_CELLS cell tan(wall slope)``, the slope judged over at most
      :data:`_WALL_SPAN_M`, and higher than the terrain's steep slopes ``terrain_slope``
      rise over those cells, both over ``spacing`` metres where the independent heights lie
      farther apart than two cells (:func:`wall_rise`), and
    * it is much steeper (``_WALL_CONTRAST`` times) than the profile's own rise over
      the ``reach`` positions before the foot (where that position is nodata or before
      the profile's start: from the farthest valid position within the reach; flat when
      there is none: the test never looks beyond the reach), and than its rise over the
      ``_WALL_CELLS`` positions just before those of the wall (NaN there: no test): a wall is
      a step across about a cell, a terrain side continues over several and already rises
      there (bare gullies at 4 m cells, their sides crossed obliquely by the Y profiles
      coming down the other side: the rise over the reach was nil, and 8.07 % of the ground
      was lost, 4.05 % now; 1 m 2.53 -> 0.13 %). This keeps terrain
      rasterised in steps (sparse points filled from the nearest one: a staircase whose
      treads are as steep as its risers on average) and walls of a terrain cut from looking
      like object walls, while a wall standing on a hillside still stands out.

    ``local`` (optional): the terrain's local slope along the profile at given flat indices
    (:meth:`LocalSlopes.at`, read only where it decides: where the rise or the fall passes the rest
    of the height test and is below :func:`local_rise_cap`; nowhere where that cap is no more than
    the rest of the demand, cells up to 1.5 m); the rise must also
    exceed its :func:`terrain_rise_per_slope` over a cell at the wall's top, up to
    :func:`local_rise_cap` (a knoll's flank at 4 m cells). The scatter of the heights' places
    within the cell, not within ``spacing``: a hall's wall reads its own height over the running
    minimum's span, and a demand over a longer spacing exceeded it (lidar autzen-thin at 4 m,
    points 11.8 m apart: 15.64 -> 15.87 % total error).

    The same test mirrored finds where the profile has just come down a wall (by
    ``drop``: the highest of the ``_WALL_CELLS`` positions before, minus ``z_j``). A
    handful of gathers (``take``) over all marked cells.

    Returns
    -------
    walls : tuple of ndarray
        ``(flat index, foot height, slope)`` of the wall tops, in index order; ``slope``
        is the profile's rise per position before the foot (>= 0), so that the run can
        follow the ground under the object.
    downs : tuple of ndarray
        ``(flat index, drop - tol)`` of the positions just below a wall (the drop beyond
        the tolerance, >= 0), in index order.
    """
    def back(k, at):  # the heights k positions before the flat cells ``at``
        return zf.take(at - k * sd)

    zc = zf.take(idx)
    best = back(1, idx)
    top = best.copy()
    for k in range(2, _WALL_CELLS + 1):
        v = back(k, idx)
        np.fmin(best, v, out=best)
        np.fmax(top, v, out=top)
    base = v if _WALL_CELLS > 1 else best  # the height _WALL_CELLS positions before
    with np.errstate(invalid="ignore"):
        rise = zc - best
        fall = np.subtract(top, zc, out=top)
        # cheap tests first, on all marked cells; the rest only on what passes
        need = np.float32(wall_rise(cell, h_min=h_min, tan_wall=tan_wall, terrain_slope=terrain_slope,
                                      spacing=spacing))
        cap = np.float32(local_rise_cap(cell, tan_wall, spacing)) if local is not None else need
        down = fall >= need
        up = rise >= need
        if cap > need:  # and the rise of the terrain's own slope where the wall stands, up to the wall slope's
            # over the wall's whole span (a rise steeper than that is a wall whatever the terrain): it decides
            # only where the rise (or the fall) lies between the rest of the demand and that cap
            pre = np.flatnonzero((up & (rise < cap)) | (down & (fall < cap)))
            need = np.maximum(np.minimum(local(idx.take(pre)) * np.float32(terrain_rise_per_slope(cell, 0.0)),
                                         cap), need)
            down[pre] = fall.take(pre) >= need
            up[pre] = rise.take(pre) >= need
        cand = np.flatnonzero(up)
        del up
        rate = rise.take(cand)
        rate /= np.float32(_WALL_CELLS * cell)
        ci = idx.take(cand)
        base = base.take(cand)
        before = back(_WALL_CELLS + reach, ci)
        _nearer_before(back, ci, before, base, reach)
        prior = np.maximum((base - before) / np.float32(reach * cell), 0)
        ok = rate >= np.float32(_WALL_CONTRAST) * prior
        # nor than a side already rising just before the foot (NaN there: no test)
        near = back(2 * _WALL_CELLS, ci)
        near -= base
        near *= np.float32(-_WALL_CONTRAST / (_WALL_CELLS * cell))
        ok &= ~(rate < near)
    wsel = cand[ok]
    tol = np.float32(tol)
    drop = np.maximum(fall[down], tol)
    drop -= tol
    return ((ci[ok], best.take(wsel), (prior[ok] * np.float32(cell)).astype(np.float32)),
            (idx[down], drop))


def _nearer_before(back, ci, before, base, reach):
    """Where ``before`` (the height ``_WALL_CELLS + reach`` positions before the walls
    ``ci``) is NaN (nodata, or before the profile's start), the farthest valid position
    within the reach (at a profile's start: its first position); ``base`` (a flat
    profile) where there is none. In place; ``back(k, at)`` gathers the heights k
    positions before the flat cells ``at``. Nothing beyond the reach is read, so blocks
    with a halo see what one pass sees."""
    miss = np.flatnonzero(np.isnan(before))
    for k in range(_WALL_CELLS + reach - 1, _WALL_CELLS, -1):
        if miss.size == 0:
            return
        v = back(k, ci.take(miss))
        ok = ~np.isnan(v)
        hit = miss[ok]
        before[hit] = v[ok]
        miss = miss[~ok]
    before[miss] = base.take(miss)


def _runs(zover, walls, sd, tol, max_cells, out, edge=False, h_min=None, land=None):
    """The paper's reading of a profile, every wall at once: the points from a break going
    up (a wall, :func:`_walls`) to the matching break coming down belong to an object.

    Each wall ``(flat index, foot g, slope gs)`` starts its own run, read in steps of
    ``sd`` flat cells; the run covers the wall and the positions after it until the
    profile comes back down to the ground extended from the foot at the slope before the
    wall, ``z - g <= gs dist + tol`` (rising only), or comes down a wall onto ground
    nearer the foot than the top, ``z - g <= gs dist + drop``; or after ``max_cells``
    positions (the largest object), or at the profile's end. ``zover`` (flat int64,
    :func:`_heights_and_drops`) holds each cell's height and, beside it, the drop beyond
    the tolerance where the profile has just come down a wall (0 elsewhere): one gather
    reads both. ``out`` (flat bool) receives the runs' cells. With ``edge``, returns
    ``(wall indices, k)`` of the runs that met the profile's end ``k + 1`` positions after
    their wall (a wall may appear more than once), else None.

    With ``land`` (flat bool) and ``h_min``: a run that comes down a wall onto a level still
    more than ``h_min`` above the ground extended from its foot (beyond the tolerance), ``z - g
    > gs dist + h_min + tol``, has landed on a lower part of its object, not on the ground (a
    lower roof between higher parts of a building); it goes on until the profile comes down
    within ``h_min`` of that ground (the drop it may then come down capped at ``h_min``), within
    the same ``max_cells``, and only if it does so (the matching break down to the ground: not
    at ``max_cells`` nor at the profile's end) its cells after the landing go into ``land``.
    :func:`_axis_runs` keeps those cells where the scans of both directions landed there
    (:func:`_landed_levels`).

    A run depends on its wall and the positions it covers only (every wall starts one,
    also inside another run), so a cell's result depends on the profile within the
    largest object and the wall test's reach before it: blocks with that halo give the
    result of one pass. A loop over the positions after the walls, all runs at once, on
    the runs still going on.
    """
    f, g, gs = walls
    out[f] = True
    f = f + sd
    ids = np.arange(f.size)                           # the wall each run started from
    ended = []                                        # walls whose run met the profile's end
    fg = np.empty((f.size, 2), np.float32)            # foot and slope side by side: one gather
    fg[:, 0], fg[:, 1] = g, gs
    tol = np.float32(tol)
    landing = land is not None
    if landing:
        landed = np.zeros(f.size, bool)               # the runs that landed on a raised level
        cap = np.float32(h_min)
        down = np.zeros(f.size, bool)                 # ... and came down to the ground after it
        land_f, land_id = [], []                      # the cells a landed run covered, and its wall
    with np.errstate(invalid="ignore"):
        for k in range(1, max_cells + 1):
            if f.size == 0:
                break
            zo = zover.take(f).view(np.float32)       # height and drop at f
            rise = np.subtract(zo[0::2], fg[:, 0])
            if edge:                                  # -inf: the frame beyond the profile's end
                e = rise == -np.inf
                if landing:                           # a landed run's end is no object's cut
                    e &= ~landed
                e = np.flatnonzero(e)
                ended.append((ids.take(e), np.full(e.size, k - 1)))
            base = np.multiply(fg[:, 1], np.float32(k))
            base += tol
            lim = base + zo[1::2]
            if landing:
                # a landed run, or one that lands now above the ground by more than h_min, goes on
                # until it comes down within h_min of the ground extended from its foot
                low = base + np.minimum(zo[1::2], cap)
                up = rise > low
                landed |= up & ~(rise > lim)
                np.copyto(lim, low, where=landed)
            on = rise > lim                           # +inf (nodata): the run goes on
            if landing:                               # a landed run back on its ground (not the frame)
                down[ids[landed & ~on & (rise > -np.inf)]] = True
            go = np.flatnonzero(on)
            f = f.take(go)
            ids = ids.take(go)
            fg = fg.view(np.int64).take(go).view(np.float32).reshape(-1, 2)
            if landing:
                landed = landed.take(go)
                land_f.append(f[landed])
                land_id.append(ids[landed])
                out[f[~landed]] = True
            else:
                out[f] = True
            f += sd
    if landing and land_f:
        lf, li = np.concatenate(land_f), np.concatenate(land_id)
        land[lf[down[li]]] = True
    if not edge:
        return None
    if not ended:
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    return tuple(np.concatenate(a) for a in zip(*ended))


def _landed_levels(land_fwd, land_back):
    """The cells (flat bool) where the runs of both directions of a profile landed on a level
    raised above the ground extended from their walls' feet by more than the minimum object
    height (:func:`_runs`' ``land``): a lower part of an object between higher parts of it.

    Luong Chinh Ke (2002) puts an object's points between a break going up from the ground and
    the matching break coming down to it. A profile across a building whose lower roof lies
    between higher wings comes down from the first wing onto that roof, still above the ground
    it rose from: no break down to the ground yet (a lower roof enclosed by higher parts, as
    ISPRS samp22/23's large irregular buildings have, kept its own height as ground: a quarter
    of such an 80 m building). A level that one direction's scan reaches so but the other's
    does not (a terrace of a hillside, above the ground line extended uphill but reached by no
    drop from the other side) stays with the runs' other rules.

    Examples
    --------
    >>> _landed_levels(np.array([0, 1, 1, 1], bool), np.array([1, 1, 1, 0], bool)).astype(int).tolist()
    [0, 1, 1, 0]
    """
    return land_fwd & land_back


#: Largest share of the largest object a run may cover from its wall to the profile's end
#: and still count for the scan from the other side (:func:`_cut_runs`).
_CUT_SHARE = 0.5


def _cut_runs(ended, max_cells):
    """The walls (indices into the walls of :func:`_runs`) whose run met the profile's end
    within half the largest object: an object cut by the raster's edge, taken as mirrored
    there (as the slope-profile filter's scans take a profile's start), is at most the
    largest object with its mirror image, so the scan coming from the edge would have met
    its mirrored wall. A terrace's upper level reaching the edge farther away stays
    rejected by that scan."""
    ids, k = ended
    return np.unique(ids[k + 1 <= _CUT_SHARE * max_cells])


def _drop_running_off(cut, axis, max_cells, cross_cells):
    """Drops, of the cells ``cut`` (bool, the raster's shape) of the runs that met the
    profile's end (:func:`_cut_runs`), the regions (4-connected) too long across the
    profiles to be an object cut by the raster's edge; in place.

    Along the profiles such a run is at most half the largest object (the object mirrored
    at the edge). Across them (along the wall the runs come from), the region is judged as
    ``bareearth:dtm``'s raised regions are: mirrored at every side the raster's edge cuts
    (:func:`~bare_earth.core.common.edge_mirrored_extents`), it must stay within the largest
    object (``cross_cells`` cells). A level cut on the two opposite sides across the profiles
    (a terrace, a quarry bench or a valley side running across the raster) continues beyond
    both and spans three times what is seen; one running obliquely to an edge comes within
    half the largest object of it along a stretch longer than the largest object. The scan
    from the edge then keeps it as ground; a roof in a corner of the tile, cut on one side
    across, stays an object while twice its seen length is within the largest object. Only
    the bands of ``max_cells // 2 + 2`` cells along the profiles' ends hold such runs: they
    alone are labelled."""
    n = cut.shape[axis]
    band = min(n, max_cells // 2 + 2)
    for part in ((slice(None), slice(0, band)), (slice(None), slice(n - band, n))):
        sub = cut[part if axis == 1 else part[::-1]]
        if not sub.any():
            continue
        lab, k = ndimage.label(sub)
        # the band spans the raster across the profiles: its regions' extents there are the raster's
        span = edge_mirrored_extents(ndimage.find_objects(lab), sub.shape)[:, 1 - axis]
        far = np.zeros(k + 1, bool)
        far[1:] = span > cross_cells
        if far.any():
            sub[far[lab]] = False


def _framed(a, frame, fill):
    """``a`` inside a frame of ``frame`` cells of ``fill`` (a flat index then reaches
    ``frame`` positions beyond any profile's ends)."""
    return pad_constant(a, frame, frame, fill)


def _set_frame(zp, frame, v):
    """The frame of ``frame`` cells of ``zp`` (:func:`_framed`) set to ``v``."""
    zp[:frame] = v
    zp[zp.shape[0] - frame:] = v
    zp[:, :frame] = v
    zp[:, zp.shape[1] - frame:] = v


def _heights_and_drops(zp, frame):
    """The heights of the framed ``zp`` (:func:`_framed`) for :func:`_runs`, each beside a
    drop of 0 (float32 pairs): -inf in the frame (a run ends beyond a profile's end),
    +inf at nodata (a run goes on across it)."""
    zover = np.zeros((zp.size, 2), np.float32)
    hz = zover[:, 0]
    np.copyto(hz, zp.ravel())
    hz[np.isnan(hz)] = np.inf
    _set_frame(zover.reshape(zp.shape + (2,))[..., 0], frame, -np.inf)
    return zover


def _axis_runs(zp, bp, frame, shape, cell, axis, *, reach, h_min, tan_wall, tol, max_cells, progress=None,
               zover=None, terrain_slope=0.0, cross_cells=None, spacing=0.0, edge_out=None, landed_out=None,
               local=None):
    """Object cells of the profiles along ``axis`` (0: Y profiles, the columns; 1: X
    profiles, the rows) of the framed heights ``zp`` and breaks ``bp`` (:func:`_framed`),
    shaped as the frame's inside ``shape``: the runs of :func:`_runs` read forwards and
    backwards, kept where both directions agree.

    A step up of the terrain (terrace edge) is an object to the scan climbing it, but the
    scan coming down the other way meets no break going up: only objects, which have a
    break going up from both sides, are kept; a run that meets the profile's end within
    half the largest object counts for both directions (:func:`_cut_runs`: the object cut
    by the raster's edge, taken as mirrored there), unless its region, mirrored at the edges
    across the profiles too, is longer than the largest object (``cross_cells``, default
    ``max_cells``: :func:`_drop_running_off`, a terrain step running across the raster).
    The walls are found by blocks of rows (no index array of the raster's size at once);
    every direction's runs go at once.
    ``zover``: :func:`_heights_and_drops` of ``zp`` when the caller has it (its drops are
    0 again on return). ``edge_out``, optional: two flat bool arrays of ``zp``'s size that
    receive the cells of every run that met the profile's end, whatever its length, and its
    wall's top (for the region stage, :func:`find_enclosed_objects`). The cells where the runs
    of both directions landed on a raised level (:func:`_landed_levels`) join the objects, or
    with ``landed_out`` (a list) are appended to it instead (shaped as the result), for
    :func:`find_profile_objects` to keep those of both axes.
    """
    h, w = shape
    W = zp.shape[1]
    zf, bf = zp.ravel(), bp.ravel()
    s = 1 if axis == 1 else W
    out = np.empty(zf.size, bool)
    rows = max(1, (16 * CHUNK_CELLS) // W)
    found = []
    for i, d in enumerate((1, -1)):   # the walls of both directions, on the NaN frame
        walls, downs = [], []
        for r0 in range(frame, frame + h, rows):
            r1 = min(frame + h, r0 + rows)
            idx = np.flatnonzero(bf[r0 * W:r1 * W])
            idx += r0 * W
            wl, dn = _walls(zf, idx, d * s, cell, reach=reach, h_min=h_min, tan_wall=tan_wall, tol=tol,
                            terrain_slope=terrain_slope, spacing=spacing, local=local)
            walls.append(wl)
            downs.append(dn)
            report(progress, (i + (r1 - frame) / h) / 4)
        found.append((tuple(np.concatenate(a) for a in zip(*walls)), downs))
    if zover is None:
        zover = _heights_and_drops(zp, frame)
    zi = zover.view(np.int64).ravel()
    runs, cuts, lands = [], [], []
    for i, d in enumerate((1, -1)):
        wl, downs = found[i]
        for di, drop in downs:
            zover[di, 1] = drop
        out.fill(False)
        land = np.zeros(zf.size, bool)
        ended = _runs(zi, wl, d * s, tol, max_cells, out, edge=True, h_min=h_min, land=land)
        runs.append(out.copy())
        lands.append(land)
        # the runs that met the profile's end: the other direction's scan starts on them
        cut = np.zeros(zf.size, bool)
        sel = _cut_runs(ended, max_cells)
        if edge_out is not None and ended[0].size:
            every = np.unique(ended[0])
            _runs(zi, tuple(a.take(every) for a in wl), d * s, tol, max_cells, edge_out[0])
            edge_out[1][wl[0].take(every)] = True
        if sel.size:
            _runs(zi, tuple(a.take(sel) for a in wl), d * s, tol, max_cells, cut)
            _drop_running_off(cut.reshape(zp.shape)[frame:frame + h, frame:frame + w], axis, max_cells,
                              max_cells if cross_cells is None else cross_cells)
        cuts.append(cut)
        for di, _ in downs:
            zover[di, 1] = 0
        report(progress, 0.5 + (i + 1) / 4)
    both = runs[0] | cuts[1]
    both &= runs[1] | cuts[0]
    landed = _landed_levels(*lands)
    if landed_out is None:
        both |= landed
    else:
        landed_out.append(landed.reshape(zp.shape)[frame:frame + h, frame:frame + w].copy())
    return both.reshape(zp.shape)[frame:frame + h, frame:frame + w].copy()


def _axis_objects(z, marked, valid, cell, axis, *, reach, h_min, tan_wall, tol, max_cells, progress=None,
                  terrain_slope=0.0, spacing=0.0):
    """:func:`_axis_runs` of the raster ``z`` (NaN at nodata) and its breaks ``marked``,
    ``& valid`` (None: every cell valid)."""
    frame = _WALL_CELLS + reach
    res = _axis_runs(_framed(z, frame, np.nan), _framed(marked, frame, False), frame, z.shape, cell, axis,
                     reach=reach, h_min=h_min, tan_wall=tan_wall, tol=tol, max_cells=max_cells,
                     progress=progress, terrain_slope=terrain_slope, spacing=spacing)
    if valid is not None:
        res &= valid
    return res


def _enclosed_regions(flag, free, max_cells, progress=None, cut=None, max_span=None):
    """Regions of ``free`` cells (4-connected) mostly made of ``flag`` cells.

    A region is kept when at least half its cells are flagged, it does not touch the
    array's edge, it is at most ``max_cells`` wide (holds no square of ``max_cells`` + 1
    cells, :func:`wider_than`) and its bounding box is at most ``max_span`` (default
    ``max_cells``) on each side, so the decision never depends on cells farther than
    ``max_span`` (block-safe). With ``cut`` (the objects the raster's edge cuts,
    :func:`_edge_regions`), a region touching the array's edge is kept too when at least
    half its cells are ``cut`` (and it is as narrow and as short); it then returns the
    regions kept and, apart, those touching the array's edge.
    """
    max_span = max_cells if max_span is None else max(int(max_span), int(max_cells))
    lab, n = ndimage.label(free)
    report(progress, 0.4)
    if n == 0:
        none = np.zeros(flag.shape, bool)
        return none if cut is None else (none, none.copy())
    # cells per label, by blocks of rows (bincount casts its input to intp: a raster-sized
    # int64 copy at once otherwise); flagged cells outside ``free`` count for label 0
    hit = np.zeros(n + 1, np.intp)
    tot = np.zeros(n + 1, np.intp)
    hit_cut = np.zeros(n + 1, np.intp)
    step = max(1, (16 * CHUNK_CELLS) // max(lab.shape[1], 1))
    for i in range(0, lab.shape[0], step):
        lb = lab[i:i + step]
        tot += np.bincount(lb.ravel(), minlength=n + 1)
        hit += np.bincount(lb[flag[i:i + step]], minlength=n + 1)
        if cut is not None:
            hit_cut += np.bincount(lb[cut[i:i + step]], minlength=n + 1)
        report(progress, 0.4 + 0.3 * min(i + step, lab.shape[0]) / lab.shape[0])
    cand = (hit > 0) & (2 * hit >= tot)
    at_edge = np.zeros(n + 1, bool)
    at_edge[np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]])] = True
    cand &= ~at_edge
    if cut is not None:
        cand |= at_edge & (hit_cut > 0) & (2 * hit_cut >= tot)
    cand[0] = False
    # a bounding box wider than max_cells needs more than max_cells cells: only such
    # regions are measured
    big = cand & (tot > max_cells)
    if big.any():
        ids = np.flatnonzero(big)
        if ids[-1] <= 16 * ids.size + 4096:   # few labels up to the last: boxes of all
            boxes = ndimage.find_objects(lab, max_label=int(ids[-1]))
            boxes = [boxes[i - 1] for i in ids]
        else:                                 # many: renumbered 1..k first
            renum = np.zeros(n + 1, np.int32)
            renum[ids] = np.arange(1, ids.size + 1, dtype=np.int32)
            boxes = ndimage.find_objects(_lookup(renum, lab, step), max_label=ids.size)
        ext = np.array([max(b[0].stop - b[0].start, b[1].stop - b[1].start) for b in boxes])
        cand[ids[ext > max_span]] = False
        if max_span > max_cells and (ext > max_cells).any():
            # longer than the largest object: kept only when no wider (an L-shaped hall, a wing)
            wide = np.zeros(n + 1, bool)
            wide[lab[wider_than(free, max_cells)]] = True
            cand &= ~wide
    report(progress, 0.8)
    out = _lookup(cand, lab, step) if cand.any() else np.zeros(flag.shape, bool)
    if cut is None:
        return out
    cand &= at_edge
    return out, (_lookup(cand, lab, step) if cand.any() else np.zeros(flag.shape, bool))


def wider_than(cells: np.ndarray, max_cells: int) -> np.ndarray:
    """The cells (bool) of the squares of ``max_cells`` + 1 by ``max_cells`` + 1 cells lying wholly
    within ``cells`` (the erosion of ``cells`` by such a square, marked at the square's middle
    cell): a connected region of ``cells`` holds one of them when and only when it is
    wider than ``max_cells`` (the width a window must exceed to hold none of it: an L-shaped hall
    180 m long with arms 60 m wide is 60 m wide); the raster's edge bounds ``cells``.

    Examples
    --------
    >>> c = np.zeros((6, 8), bool)
    >>> c[1:3, :] = True          # a strip two cells wide ...
    >>> c[1:5, 5:8] = True        # ... and a block three wide
    >>> int(wider_than(c, 2).sum()), int(wider_than(c, 3).sum())
    (2, 0)
    """
    k = int(max_cells) + 1
    a = np.asarray(cells, bool).view(np.uint8)
    if a.shape[0] < k or a.shape[1] < k:
        return np.zeros(a.shape, bool)
    # a square's minimum by two running minima, marked at its middle cell (one of its own)
    e = ndimage.minimum_filter1d(a, k, axis=0, mode="constant", cval=0)
    e = ndimage.minimum_filter1d(e, k, axis=1, mode="constant", cval=0)
    return e.astype(bool)


def _lookup(table, lab, step):
    """``table[lab]`` by blocks of ``step`` rows (a gather casts its indices to intp: a
    raster-sized int64 copy at once otherwise)."""
    out = np.empty(lab.shape, table.dtype)
    for i in range(0, lab.shape[0], step):
        table.take(lab[i:i + step], out=out[i:i + step])
    return out


def profile_reach(cell_size: CellSize, *, window: int, max_size: float) -> int:
    """Cells (in any direction) within which the heights decide the objects of
    :func:`find_profile_objects`: a run covers at most the largest object after its wall
    (``int(max_size / cell)`` positions), and the wall test reads ``_WALL_CELLS + 2 window +
    1`` positions before it (more than the breaks' window, ``3 (window // 2)`` with the
    nodata bridge); both scan directions mirror it. A run is dropped by the cells of its own
    run within the largest object along the profile (the largest object once more) whose cross
    profile meets no break within twice it (:func:`bounded_runs`, :func:`bounded_stretches`:
    as far across). The wall test also reads the terrain's local slope at the wall
    (:func:`local_terrain_slopes`: a running minimum and central differences over ``k =``
    :func:`local_slope_cells` cells, the steepest within ``k // 2 + _WALL_CELLS`` cells), which
    reaches ``k + k // 2 + _WALL_CELLS`` cells further."""
    dx, dy = cell_size
    k = local_slope_cells(cell_size)
    return (2 * max(int(max_size / dx), int(max_size / dy)) + _WALL_CELLS + 2 * window + 1
            + k + k // 2 + _WALL_CELLS)


def enclosed_reach(cell_size: CellSize, *, max_size: float) -> int:
    """Cells within which the profile objects and breaks decide :func:`find_enclosed_objects`
    at a cell: a region kept is at most ``max_size`` wide and :data:`LONGEST` ``max_size``
    long (its cells and its rim lie within that many cells); one longer is rejected by any
    window that holds that much, one wider by the square of ``max_size`` it holds."""
    dx, dy = cell_size
    return int(max(LONGEST * max_size / dx, LONGEST * max_size / dy))


def find_profile_objects(z: np.ndarray, marked: np.ndarray, valid: Optional[np.ndarray], cell_size: CellSize, *,
                         window: int, h_min: float, tan_wall: float, tol: float, max_size: float,
                         terrain_slope: float = 0.0, spacing: float = 0.0, edge_runs: bool = False,
                         levels_out: Optional[list] = None, local_slopes: Optional["LocalSlopes"] = None,
                         progress: Optional[Progress] = None):
    """Step 3: along the X and Y profiles, the cells from a break going up a wall to the
    break coming down (:func:`_axis_objects`, both scan directions agreeing).

    ``valid`` is None when every cell is valid. The foot search reaches ``2 window + 1``
    positions before a wall; a run longer than ``max_size`` metres is not an object;
    ``terrain_slope`` (rise/run) the terrain's steep slopes and ``spacing`` (metres) that of
    the independent heights (:func:`wall_rise`); ``local_slopes`` (optional): the terrain's local
    slopes along X and along Y (:class:`LocalSlopes` of ``z``), which the walls must also rise above.
    A run with a cell whose cross profile meets no break, no step of ``h_min`` within two cells
    (:func:`height_steps`) and no nodata within :data:`LONGEST` ``max_size`` metres
    (:func:`bounded_stretches`) loses its cells within ``max_size`` of it (:func:`bounded_runs`):
    an object is bounded across its profiles too.
    Returns the union of the X and Y objects and the cells found by each; with ``edge_runs``,
    also ``(cells, walls)``: the cells of the runs of either axis and direction that met the
    raster's edge, whatever their length, and their walls' tops (:func:`find_enclosed_objects`).
    With ``levels_out`` (a list), the lower levels landed on by the scans of both directions of
    one axis only (X or Y, not both; :func:`_landed_levels`) that end along the other axis in a
    drop on one side at least (:func:`dropped_ends`) are appended to it: a lower part between wings
    along one axis, which :func:`find_enclosed_objects` counts with the runs.
    """
    dx, dy = cell_size
    reach = 2 * window + 1
    frame = _WALL_CELLS + reach
    zp, bp = _framed(z, frame, np.nan), _framed(marked, frame, False)
    edge_out = (np.zeros(zp.size, bool), np.zeros(zp.size, bool)) if edge_runs else None
    kw = dict(h_min=h_min, tan_wall=tan_wall, tol=tol, reach=reach, zover=_heights_and_drops(zp, frame),
              terrain_slope=terrain_slope, spacing=spacing, edge_out=edge_out)
    local = (None, None) if local_slopes is None else tuple(
        functools.partial(local_slopes.at, frame=frame, axis=a) for a in (1, 0))
    landed = []                              # the raised levels landed on along X, then along Y
    kw["landed_out"] = landed
    obj_x = _axis_runs(zp, bp, frame, z.shape, dx, 1, max_cells=int(max_size / dx), cross_cells=int(max_size / dy),
                       progress=sub_progress(progress, 0.0, 0.45), local=local[0], **kw)
    obj_y = _axis_runs(zp, bp, frame, z.shape, dy, 0, max_cells=int(max_size / dy), cross_cells=int(max_size / dx),
                       progress=sub_progress(progress, 0.45, 0.9), local=local[1], **kw)
    del local
    del zp, bp
    if valid is not None:
        obj_x &= valid
        obj_y &= valid
    # an object is bounded both ways: a run along X with a cell on a Y profile that meets no break, no
    # step and no nodata within twice the largest object (a level between two gullies) is the terrain's
    free = ~height_steps(transpose(z), h_min)    # along Y: no step, no nodata (NaN is a step), no break
    free &= ~transpose(marked)
    obj_x = bounded_runs(obj_x, transpose(bounded_stretches(free, int(LONGEST * max_size / dy))), int(max_size / dx))
    report(progress, 0.93)      # a report after each raster-wide stage (QA 20: 1.8 s CPU on 16 Mcells without)
    free = ~height_steps(z, h_min)
    free &= ~marked
    obj_y = transpose(bounded_runs(transpose(obj_y), transpose(bounded_stretches(free, int(LONGEST * max_size / dx))),
                                   int(max_size / dy)))
    del free
    report(progress, 0.96)
    # a lower level enclosed by higher parts of an object: landed on from both sides along X and along Y
    if levels_out is not None:
        # landed on along X only: along Y the level must end in a drop (its own end, not a terrain
        # level running on between the crowns along an embankment's crest); and the other way round
        one = landed[0] & ~landed[1]
        one = dropped_ends(transpose(z), transpose(one), h_min, int(max_size / dy)).T
        one |= dropped_ends(z, landed[1] & ~landed[0], h_min, int(max_size / dx))
        if valid is not None:
            one &= valid
        levels_out.append(one)
        report(progress, 0.98)
    landed = landed[0] & landed[1]
    if valid is not None:
        landed &= valid
    obj_x |= landed
    obj_y |= landed
    del landed
    n_x, n_y = int(np.count_nonzero(obj_x)), int(np.count_nonzero(obj_y))
    obj_x |= obj_y
    if not edge_runs:
        return obj_x, n_x, n_y
    h, w = z.shape
    cells, walls = (a.reshape(h + 2 * frame, w + 2 * frame)[frame:frame + h, frame:frame + w].copy()
                    for a in edge_out)
    if valid is not None:
        cells &= valid
        walls &= valid
    return obj_x, n_x, n_y, (cells, walls)


def bounded_stretches(free: np.ndarray, max_cells: int) -> np.ndarray:
    """The cells (bool, ``free``'s shape) that no stretch of ``free`` cells longer than
    ``max_cells`` along their row holds: the cells not in ``free`` (steps, breaks, nodata), and
    those whose stretch (the consecutive ``free`` cells of their row around them) spans at most
    ``max_cells``. A stretch cut by the raster's edge counts what is seen.

    Luong Chinh Ke (2002) puts an object between a break going up and the break coming down of
    a profile, within the largest object; an object is bounded so across its profiles too, within
    its longest (:data:`LONGEST` largest objects: a hall 240 m long and 120 m wide is an object by
    its Y profiles): a run of the X profiles whose cells lie on a Y profile with no break longer
    than that is no object's (the level between two gullies or ditches running along Y, climbed
    from one and left down into the next: bare terrain at 4 m cells lost a fifth of its ground
    so). Where the raster's edge cuts a stretch, what is seen counts (mirrored, a building 90 m
    long cut by the edge of a tile would span 180 m). A cell's answer depends on its row within
    ``max_cells`` + 1 cells (a longer stretch cut by a block's window still spans more than
    ``max_cells``), so blocks with that halo give the answer of one pass.

    Examples
    --------
    >>> bounded_stretches(np.array([[1, 1, 1, 0, 1, 1, 0, 1, 1, 1, 1, 1]], bool), 4).astype(int).tolist()
    [[1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0]]
    """
    free = np.asarray(free, bool)
    h, w = free.shape
    out = ~free
    if not free.any():
        return out
    cols = np.arange(w, dtype=np.int32)
    start = np.where(free, np.int32(-1), cols)                 # the last non-free column at or before
    np.maximum.accumulate(start, axis=1, out=start)
    start += 1                                                 # a stretch's first column
    end = np.where(free, np.int32(w), cols)[:, ::-1]           # the first non-free column at or after
    end = np.minimum.accumulate(end, axis=1)[:, ::-1]          # a stretch's past-the-last column
    end -= start
    out |= end <= max_cells
    return out


def dropped_ends(z: np.ndarray, cells: np.ndarray, height: float, max_cells: int) -> np.ndarray:
    """The ``cells`` (bool) whose level ends, along their row, in a drop at least on one side: going
    each way from the cell, the first height more than ``height`` away from the cell's is found within
    ``max_cells``, on neither side nodata or beyond the raster, and on one side at least it is lower (the
    level's own end, down to the ground; on the other it may rise onto a higher part). A level running on
    (a terrace, an embankment's crest between shrubs) meets no drop. A loop over the positions, on the
    given cells only.

    Examples
    --------
    >>> z = np.array([[0, 2, 2, 2, 0, 5, 5, 2, 2, 9, 2, 2]], np.float32)
    >>> dropped_ends(z, np.ones(z.shape, bool), 1.0, 4).astype(int).tolist()
    [[0, 1, 1, 1, 0, 1, 1, 0, 0, 1, 0, 0]]
    """
    z = np.asarray(z, np.float32)
    h, w = z.shape
    r, c = np.nonzero(cells)
    out = np.zeros(z.shape, bool)
    if r.size == 0:
        return out
    zc = z[r, c]
    ok = np.ones(r.size, bool)
    dropped = np.zeros(r.size, bool)
    hh = np.float32(height)
    for d in (1, -1):
        open_ = np.ones(r.size, bool)                # the side's end not met yet
        for k in range(1, int(max_cells) + 1):
            i = np.flatnonzero(open_)
            if i.size == 0:
                break
            cc = c[i] + d * k
            inside = (cc >= 0) & (cc < w)
            zz = np.full(i.size, np.nan, np.float32)
            zz[inside] = z[r[i[inside]], cc[inside]]
            with np.errstate(invalid="ignore"):
                low = zz < zc[i] - hh
                left = low | (zz > zc[i] + hh) | np.isnan(zz)
            ok[i[left & ~low & ~(zz > zc[i] + hh)]] = False     # nodata or beyond the raster
            dropped[i[low]] = True
            open_[i[left]] = False
        ok &= ~open_                                 # no end within max_cells
    out[r[ok & dropped], c[ok & dropped]] = True
    return out


def height_steps(z: np.ndarray, height: float) -> np.ndarray:
    """The cells (bool) where the profile along the rows has just risen or fallen by at least
    ``height`` within ``_WALL_CELLS`` cells (the height difference to each of the cells before
    it), and the nodata cells (NaN): where an object may end along the profile.

    Examples
    --------
    >>> height_steps(np.array([[0, 0.2, 0.4, 1.5, 1.5, 1.5, 1.6, np.nan, 1]]), 1.0).astype(int).tolist()
    [[0, 0, 0, 1, 1, 0, 0, 1, 0]]
    """
    z = np.asarray(z, np.float32)
    out = np.isnan(z)
    h = np.float32(height)
    with np.errstate(invalid="ignore"):
        for k in range(1, _WALL_CELLS + 1):
            if z.shape[1] > k:
                out[:, k:] |= np.abs(z[:, k:] - z[:, :-k]) >= h
    return out


def bounded_runs(runs: np.ndarray, bounded: np.ndarray, max_cells: int) -> np.ndarray:
    """The cells of ``runs`` (bool; a run: consecutive True cells along a row) with no cell of
    their run that is not ``bounded`` (:func:`bounded_stretches` across the rows) within
    ``max_cells`` along the row; a new array.

    A run along a profile is one object from its wall to the wall coming down: where a cell of
    it lies on a cross profile with no break within the largest object, the run is the
    terrain's (beside a meandering gully the cells near its sides meet the side's breaks across,
    the level's middle does not). A run is at most the largest object long, but runs of
    neighbouring objects touch: within ``max_cells`` only, so a cell's answer depends on the
    cells within that many along the row (:func:`profile_reach` adds it).

    Examples
    --------
    >>> r = np.array([[1, 1, 0, 1, 1, 1, 1, 1]], bool)
    >>> bounded_runs(r, np.array([[1, 1, 1, 1, 0, 1, 1, 1]], bool), 2).astype(int).tolist()
    [[1, 1, 0, 0, 0, 0, 0, 1]]
    """
    runs = np.asarray(runs, bool)
    bad = runs & ~np.asarray(bounded, bool)
    if not bad.any():
        return runs.copy()
    w = runs.shape[1]
    cols = np.arange(w, dtype=np.int32)
    far = np.int32(1 << 30)
    # from the left: the run's first column and the last unbounded cell at or before
    first = np.where(runs, np.int32(-1), cols)
    np.maximum.accumulate(first, axis=1, out=first)
    last = np.where(bad, cols, -far)
    np.maximum.accumulate(last, axis=1, out=last)
    drop = last > first
    drop &= cols - last <= max_cells
    # from the right: the run's past-the-last column and the next unbounded cell at or after
    first = np.minimum.accumulate(np.where(runs, w, cols)[:, ::-1], axis=1)[:, ::-1]
    last = np.minimum.accumulate(np.where(bad, cols, far)[:, ::-1], axis=1)[:, ::-1]
    nxt = last < first
    nxt &= last - cols <= max_cells
    drop |= nxt
    return runs & ~drop


def _edge_regions(cells, walls, max_cells, near=0, z=None, tol=0.0):
    """The regions (4-connected) of ``cells``, the runs that met the raster's edge (whatever
    their length), that are objects cut by the raster's edge
    (:func:`~bare_earth.core.edge_walls.walled_levels`): seen within the largest object
    (``max_cells`` on each side), standing on its walls over more than half its seen outline
    (a hillside's or a terrace's upper level, which the runs climb onto where the ground rises
    beyond the wall's foot line, comes down gradually elsewhere: ``isprs/samp11`` 1 m lowest
    11.3 -> 15.0 % and ``hexbin-crop`` 4 m 34.9 -> 44.4 % without this test) and walled within
    twice that, mirrored at the edge.

    The walls of a region are the tops ``walls`` its runs start from; mirrored at every side
    of the raster they meet (:func:`~bare_earth.core.common.walls_runs`) they run twice what
    is seen where they cut off a corner of the raster (a roof over most of a tile, lidar
    ``sample_c``: 136-148 m at 0.5-4 m cells), within twice the largest object whenever what is
    seen lies within it; a wall running across the raster, from one side to the opposite one (a
    terrace's, a river's or a quarry bench's wall), continues beyond both and runs three times
    what is seen: the terrain's, unless shorter than two thirds of the largest object. Such a
    region spans at most ``max_cells`` from the raster's edge: in a block, one cut by the
    block's window instead lies in the halo. The cells between such a region and the
    raster's edge, within ``near`` cells (half the local fit's window), are added where they
    stand as high as it (heights ``z``, ``tol``: :func:`_to_edge`).
    """
    lab, n = ndimage.label(cells)
    out = np.zeros(cells.shape, bool)
    if n == 0:
        return out
    keep = walled_levels(lab, n, walls, (max_cells, max_cells), 2 * max_cells)
    if keep.any():
        out = keep[lab]
        _to_edge(out, near, z, tol)
    return out


def _close_level(whole, z, m, tol):
    """``whole`` (bool, an object) closed by a square of ``2 m + 1`` cells, the raster's edge
    counting as the object (beyond it, it continues), where the cells added stand no lower than
    the object's lowest cell within that square by more than ``tol`` (heights ``z``); in place.
    On the box of the object grown by the square and a cell (the same result: nothing beyond
    it changes)."""
    rows, cols = np.flatnonzero(whole.any(axis=1)), np.flatnonzero(whole.any(axis=0))
    k = 2 * m + 1
    g = k + 1
    box = (slice(max(rows[0] - g, 0), rows[-1] + 1 + g), slice(max(cols[0] - g, 0), cols[-1] + 1 + g))
    wb, zb = whole[box], z[box]
    add = ndimage.maximum_filter(wb.view(np.uint8), size=k, mode="constant", cval=0)   # separable passes
    add = ndimage.minimum_filter(add, size=k, mode="constant", cval=1).view(bool)
    add &= ~wb
    r, c = np.nonzero(add)
    if r.size == 0:
        return
    # the object's lowest cell within the square around each added cell, gathered at those cells
    low = np.full(r.size, np.inf, np.float32)
    h, w = wb.shape
    for dr in range(-m, m + 1):
        rr = np.clip(r + dr, 0, h - 1)
        for dc in range(-m, m + 1):
            cc = np.clip(c + dc, 0, w - 1)
            on = wb[rr, cc]
            np.minimum(low, np.where(on, zb[rr, cc], np.inf), out=low, where=on & np.isfinite(zb[rr, cc]))
    high = zb[r, c] >= low - np.float32(tol)
    wb[r[high], c[high]] = True


def _to_edge(a, k, z=None, tol=0.0):
    """The cells between a True cell of ``a`` within ``k`` cells of the array's edge and that
    edge (along the rows and the columns) set True, in place. Along the raster's edge the
    local fit is extrapolated and the profile running along the edge itself meets no wall
    where the object meets the edge: its breaks and cells there belong to no run; left out,
    they seeded the final pass's ground surface at the object's height. With heights ``z``,
    only the cells standing as high as the object (not below the object's cell inward of them
    by more than ``tol``), up to the first that does not: the ground at the foot of a wall
    facing the edge stays ground (a raster of a few cells, 5 x 5 with a step across it, was
    all objects: every wall lies within ``k`` cells of an edge there)."""
    h, w = a.shape
    k = min(int(k), h - 1, w - 1)
    if k <= 0:
        return
    src = a.copy()
    sides = ((slice(None), slice(None)), (slice(None), slice(None, None, -1)))
    for t in (False, True):                       # along the rows, then down the columns
        for sl in sides:                          # from the left (top), from the right (bottom)
            band, s_band = (a.T if t else a)[sl][:, :k + 1], (src.T if t else src)[sl][:, :k + 1]
            zb = None if z is None else (z.T if t else z)[sl][:, :k + 1]
            on = s_band[:, k].copy()
            ref = None if zb is None else np.where(on, zb[:, k], np.nan)
            for c in range(k - 1, -1, -1):
                here = s_band[:, c]
                add = on & ~here
                if zb is not None:
                    add &= ~(zb[:, c] < ref - np.float32(tol))        # NaN: no test
                    np.copyto(ref, zb[:, c], where=here)
                band[:, c] |= add
                on = here | add


def find_enclosed_objects(objects: np.ndarray, marked: np.ndarray, valid: Optional[np.ndarray],
                          cell_size: CellSize, max_size: float, progress: Optional[Progress] = None,
                          edge_runs=None, window: int = 5, z: Optional[np.ndarray] = None,
                          tol: float = 0.0) -> np.ndarray:
    """Step 4: regions enclosed by breaks (4-connected valid unmarked cells, at most
    ``max_size`` metres wide and :data:`LONGEST` ``max_size`` long, not touching the raster's
    edge) made mostly of the ``objects`` of the profiles (:func:`_enclosed_regions`; an L-shaped
    hall longer than the largest object, no wider, is on runs longer than it at its corner, and
    its region is mostly runs: its corner, a fifth of it, stayed ground). With ``edge_runs`` (``(cells,
    walls)`` of :func:`find_profile_objects`), also the regions of the runs that met the
    raster's edge, enclosed by their walls and the edge, seen within ``max_size`` and walled
    within twice that, mirrored at the edge (:func:`_edge_regions`), with the cells between
    them no lower than them by more than ``tol`` (heights ``z``) within the ``window`` (the
    breaks along the edge). ``valid`` is None when every cell is valid. ``progress(fraction)``
    as the work goes."""
    dx, dy = cell_size
    max_cells = int(max(max_size / dx, max_size / dy))
    span = int(max(LONGEST * max_size / dx, LONGEST * max_size / dy))
    free = ~marked if valid is None else valid & ~marked
    if edge_runs is None:
        regions = _enclosed_regions(objects, free, max_cells, sub_progress(progress, 0.0, 0.9), max_span=span)
        report(progress, 1.0)
        return regions
    m = window // 2
    cut = _edge_regions(edge_runs[0], edge_runs[1], max_cells, m, z, tol)
    report(progress, 0.1)
    regions, whole = _enclosed_regions(objects, free, max_cells, sub_progress(progress, 0.1, 0.9), cut=cut,
                                       max_span=span)
    if cut.any():
        # the object cut by the raster's edge with the regions mostly made of it, closed over
        # the local fit's window (beyond the raster's edge it continues): the breaks and the
        # specks of unmarked cells between them along the edge, which no run crosses, are its
        # own where they stand as high as it (not below its lowest cell within the window by
        # more than the tolerance; gaps between crowns do)
        whole |= cut
        if z is not None:
            _close_level(whole, z, m, tol)
        regions |= whole
    report(progress, 1.0)
    return regions
