"""Stage 2 of the geodesic filter: gradual geodesic dilation.

For structuring elements doubling in size, the grey opening of the surface (the marker)
is reconstructed by geodesic dilation under the surface; the residual regions the
reconstruction cannot reach are objects when they are high enough and their border is
abrupt (see the package docstring). Wide windows run on grids coarsened by a power of 2.

Measured, not adopted (main 232df97, the 73 rows' mean 2.825): a coarse region high enough but failing
the rim test analysed again at the raster's cells, as a region too wide is (:func:`_fine_regions`): the
coarse blocks' maxima join a roof to the low vegetation around it (lidar ``warsaw_small`` at 0.5 m: a
roof cut by the raster's edge kept, 0.91 -> 0.17 %), but ground raised 1-3 m beside buildings then
passes at the raster's cells through the buildings' walls (ISPRS samp21 at 1 m 1.30 / 1.29 -> 1.69 /
1.66 %, autzen_trim 2 m 2.62 -> 2.85; mean 2.829). Its smooth pieces tested as :func:`_walled_pieces`
does: samp21 1 m 2.04 %; as :func:`_wide_pieces` does (walled drops, three cells wide, a bump's
height for the piece's width), seen whole or not: samp21 1 m 1.67-1.69 %, autzen_trim 2 m 2.85 %,
warsaw 0.91 / 0.26 % (a piece of 724 cells joining roofs and the raised ground by their smeared
walls passed with 170 of 301 rim cells walls).
"""
import functools

import numpy as np
from scipy import ndimage

from ..blocks import run_sharing
from ..common import label8, label_boxes, report, sub_progress
from ..estimate import block_expand, smooth_parts
from .grey import (
    block_reduce,
    fill_nodata,
    grey_opening,
    inner_cells,
    reconstruct_by_dilation,
    rect_filter,
    window_cells,
)

#: Steps whose window exceeds this many cells run on a coarser grid (factor a power of 2)
#: so that the coarse window stays about this wide.
COARSE_WINDOW = 4
#: Baseline of the wall test in metres (at least one cell).
WALL_BASE_M = 1.0
#: Markers within this fraction of dh0 under the surface are snapped to it.
NOISE_SNAP = 0.2
#: Geodesic reach of each step's reconstruction, in windows.
RECON_REACH = 1.0
#: A terrain bump as wide as the window may rise tan(slope) * window * this fraction.
BUMP_FRACTION = 0.5
#: Rings of border cells the border stage (:func:`~.filter.remove_borders`) peels off a removed
#: object, one after the other, and the radius in cells of the ground whose own drops measure the
#: terrain's rise there: a wall that the DSM smears over a few cells (interpolated, smoothed or
#: matched surfaces: a ramp of mixed cells 0.5-2 m above the ground round every roof at 2 m cells)
#: leaves a skirt the first ring alone does not take (issue 12).
BORDER_RINGS = 3
#: A residual region wider or taller than this many ``max_object_size_m`` is never an
#: object (large raised terrain); it also bounds the method's reach (see the halo).
EXTENT_FACTOR = 2.0


def coarse_factor(size):
    """Power-of-2 coarsening factor for a window of ``size`` (rows, cols) cells."""
    f = 1
    while max(size) / (2 * f) > COARSE_WINDOW:
        f *= 2
    return f



def coarse_grids(w, valid, jump, factors):
    """The coarse grids of the steps: for every factor ``f`` in ``factors`` (powers of 2),
    the block minima and maxima of ``w`` (nodata ignored; ``inf`` / ``-inf`` where a block
    holds none) and the block maxima of ``jump``, over ``f`` x ``f`` blocks aligned on the
    array's origin. Each level is reduced from the previous one (a block of ``2f`` is four
    blocks of ``f``: the same cells, so the same extremes as reducing the raster itself).

    Returns
    -------
    dict
        ``{f: (zmin, zmax, jump_c)}``.
    """
    out = {}
    zmin = zmax = jc = None
    f = 1
    for target in sorted(set(factors) - {1}):
        while f < target:
            if f == 1:
                zmin = block_reduce(fill_nodata(w, valid, np.inf), 2, np.minimum, np.inf)
                zmax = block_reduce(fill_nodata(w, valid, -np.inf), 2, np.maximum, -np.inf)
                jc = block_reduce(jump, 2, np.maximum, False)
            else:
                zmin = block_reduce(zmin, 2, np.minimum, np.inf)
                zmax = block_reduce(zmax, 2, np.maximum, -np.inf)
                jc = block_reduce(jc, 2, np.maximum, False)
            f *= 2
        out[f] = (zmin, zmax, jc)
    return out


def _fine_cells(blocks, f, coarse_width, shape):
    """Flat indices of the fine cells of the coarse cells ``blocks`` (flat indices on a grid
    ``coarse_width`` wide, blocks of ``f`` x ``f`` cropped to ``shape``), block by block, and
    for each its block's position in ``blocks``."""
    H, W = shape
    rb, cb = np.divmod(blocks, coarse_width)
    k = np.arange(f)
    rr = rb[:, None] * f + k
    cc = cb[:, None] * f + k
    flat = (rr * W)[:, :, None] + cc[:, None, :]
    owner = np.repeat(np.arange(blocks.size), f * f)
    if H % f or W % f:
        ok = ((rr < H)[:, :, None] & (cc < W)[:, None, :]).ravel()
        return flat.ravel()[ok], owner[ok]
    return flat.ravel(), owner


def dilation_step(w, valid, wmask, jump, s, dx, dy, dh0, tan_s, edge_ratio, ext_limit, progress=None,
                  grids=None, reconstruction=None, shared=None, split=False):
    """One gradual step of ``s`` metres: reconstruction ``R_k`` and the object cells.

    Windows wider than :data:`COARSE_WINDOW` cells run on a grid coarsened ``f`` times
    (``f`` a power of 2): the marker is the opening of the block minima, the mask the
    block maxima; the reconstruction ``Rc`` reaches the block maxima on terrain (so
    ``R_k = min(z, Rc) = z`` there) and only the surrounding terrain level under an
    object. The residual regions are analysed on that grid (residual of a block: its
    maximum minus ``Rc``; the abrupt-rim height grows by the terrain's rise over one
    coarse cell); a fine cell is an object when its block's region is one and its own
    residual exceeds ``dh0``. Coarse grids are aligned on the array origin, so blocks
    must start on multiples of ``f`` (the halo is a multiple of the largest ``f``).

    ``progress(fraction)`` is called between the sub-steps and during the
    reconstruction (it may raise :class:`~bare_earth.core.common.Cancelled`).

    Parameters
    ----------
    grids : dict, optional
        :func:`coarse_grids` of ``w`` (computed here when a coarse step needs one).
    reconstruction : list, optional
        Receives ``(Rc, f)``: the step's reconstruction on its grid and the grid's factor.
    shared : dict, optional
        Estimates of ``w`` the steps share (:func:`_fine_outline`'s 3 x 3 minimum), kept from
        one step to the next.
    split : bool
        A step wider than the default largest object (the window widened to a raised region
        standing on walls): the regions high enough but failing the rim test are split at their
        walls and each piece is tested as a region (:func:`_walled_pieces`).

    Returns
    -------
    cells : ndarray of intp
        Flat indices of the cells removed by this step.
    R : ndarray
        ``R_k`` at those cells (the reconstruction, under ``w`` there).
    """
    H, W = w.shape
    size = window_cells(s, dx, dy)
    size = (min(size[0], 2 * H + 1), min(size[1], 2 * W + 1))   # no wider than the raster
    f = coarse_factor(size)
    if f == 1:
        zmin = zmax = w
        vc = valid
        size_c = size
        jump_c = jump
    else:
        if grids is None or f not in grids:
            grids = coarse_grids(w, valid, jump, [f])
        zmin, zmax, jump_c = grids[f]
        vc = np.isfinite(zmin)
        size_c = window_cells(s, dx * f, dy * f)
    report(progress, 0.1)
    marker = grey_opening(zmin, vc, size_c, sub_progress(progress, 0.1, 0.25))
    report(progress, 0.25)
    mask_c = wmask if f == 1 else np.where(vc, zmax, np.nan)
    if NOISE_SNAP > 0:
        # cells the opening lowered by less than the noise are terrain already: snap the
        # marker to the mask there (moves R by at most NOISE_SNAP * dh0, and saves the
        # reconstruction from chasing noise over the whole raster)
        with np.errstate(invalid="ignore"):
            snap = (mask_c - marker) < NOISE_SNAP * dh0
        np.copyto(marker, mask_c, where=snap)
        del snap
    reach = max(size_c) * RECON_REACH
    Rc = reconstruct_by_dilation(marker, mask_c, max_iter=max(1, int(round(reach))),
                                 progress=sub_progress(progress, 0.25, 0.7))
    del marker
    if reconstruction is not None:
        reconstruction.append((Rc, f))
    with np.errstate(invalid="ignore"):
        dc = zmax - Rc
        cand = vc & (dc > dh0)
    none = np.zeros(0, np.intp)
    if not cand.any():
        report(progress, 0.9)
        return none, Rc.ravel()[none]
    lab, n = label8(cand)                         # sparse at the fine steps: by runs
    report(progress, 0.75)
    # a rim cell is abrupt when it holds a wall: a cell above a neighbour by more
    # than the terrain can rise over one (diagonal) cell, plus 2 dh0
    # and the residual there exceeds 2 dh0 plus the terrain's rise over the block
    idx, lab_c, dmax, rim_frac, ext_r, ext_c = _component_stats(
        lab, n, cand, dc, inner_cells(cand, None if vc.all() else ~vc), jump_c,
        2.0 * dh0 + tan_s * f * np.hypot(dx, dy))
    del lab
    report(progress, 0.85)
    dh_k = dh0 + tan_s * s * BUMP_FRACTION
    small = (ext_r * f * dy <= ext_limit) & (ext_c * f * dx <= ext_limit)
    keep = (dmax > dh_k) & (rim_frac >= edge_ratio) & small
    keep[0] = False
    obj_c = idx[keep[lab_c]]                      # the coarse cells of object regions
    wide = (dmax > dh_k) & ~small
    wide[0] = False
    wide_c = idx[wide[lab_c]]                     # the coarse cells of regions too wide on the grid
    walled_c = none
    if split:
        walled = (dmax > dh_k) & small & ~(rim_frac >= edge_ratio)
        walled[0] = False
        walled_c = idx[walled[lab_c]]             # the coarse cells of high regions failing the rim test
    del idx, lab_c
    report(progress, 0.9)
    Rcf = Rc.ravel()
    pieces = none
    gaps = None if valid is None or valid.all() else ~valid    # nodata ends a region's rim
    if walled_c.size:
        # their cells keep their height in the cleaned surface (R_k = w there), as _fine_regions' do
        pieces = _walled_pieces(w, walled_c, Rc, f, dh0 + tan_s * np.hypot(dx, dy), dh0, dh_k, edge_ratio,
                                ext_limit, dx, dy)
        report(progress, 0.92)
    if f == 1:
        return np.concatenate([obj_c, pieces]), np.concatenate([Rcf[obj_c], w.ravel()[pieces]])
    # a fine cell of an object block is removed when its own residual exceeds dh0; there
    # R_k = min(w, Rc) = Rc of its block
    cells, owner = _fine_cells(obj_c, f, Rc.shape[1], w.shape)
    Rk = Rcf[obj_c][owner]
    report(progress, 0.95)
    with np.errstate(invalid="ignore"):
        sel = (w.ravel()[cells] - Rk) > dh0
    cells, Rk = cells[sel], Rk[sel]
    if wide_c.size:
        more = _fine_regions(w, wide_c, Rc, f, jump, 2.0 * dh0 + tan_s * f * np.hypot(dx, dy), dh0, dh_k,
                             edge_ratio, ext_limit, dx, dy, gaps, dh0 + tan_s * np.hypot(dx, dy), tan_s)
        # their cells keep their height in the cleaned surface (R_k = w there): see _fine_regions
        cells, Rk = np.concatenate([cells, more]), np.concatenate([Rk, w.ravel()[more]])
        report(progress, 0.96)
    if pieces.size:
        cells, Rk = np.concatenate([cells, pieces]), np.concatenate([Rk, w.ravel()[pieces]])
    # each cell's residual above its block's reconstruction (the cells of _fine_regions and the pieces keep
    # their height in Rk): the courtyards among them are given back by _fine_outline
    rows, cols = np.divmod(cells, W)
    with np.errstate(invalid="ignore"):
        res = w.ravel()[cells] - Rcf[(rows // f) * Rc.shape[1] + cols // f]
    del rows, cols
    sel = _fine_outline(w, cells, dh0 + tan_s * np.hypot(dx, dy), edge_ratio, shared, gaps, res=res, dh_k=dh_k)
    report(progress, 0.97)
    return cells[sel], Rk[sel]


def _fine_regions(w, blocks, Rc, f, jump, flag_min, dh0, dh_k, edge_ratio, ext_limit, dx, dy, nodata=None,
                  step_m=None, tan_s=0.0):
    """The objects among the fine cells of a coarse step's regions too wide to be one
    (``blocks``: their coarse cells, flat on the grid of ``Rc``): the region tests of
    :func:`dilation_step` on the fine cells whose own residual above their block's
    reconstruction exceeds ``dh0``, 8-connected at the raster's resolution.

    A coarse block's maximum stands for all its cells, so a block holding the corner of a roof
    and the street beside it is as high as the roof: where objects stand closer together than
    a few coarse cells (a dense city; a DSM of highest points, whose roofs spread over the
    street's mixed cells), the blocks join the buildings of whole quarters into one region
    wider than :data:`EXTENT_FACTOR` largest objects, which no step removes, and only scan
    labelling took them (issue 12: on ISPRS samp31 and samp41 at 1 m, highest points, and
    synthetic-lidar/urban at 1 m the 32 m and 64 m steps removed nothing; samp41 1 m highest
    points 5.57 -> 2.89 %, synthetic-lidar/urban 1 m 2.51 -> 0.03 %). The paper
    analyses the residual at the raster's cells, where the street's cells are under the
    reconstruction and part the buildings: each fine region is an object when it is higher
    than ``dh_k``, no wider than ``ext_limit`` metres, and at least ``edge_ratio`` of its rim
    cells (not on the raster's edge) hold a wall (``jump``) with a residual of at least
    ``flag_min``, as a coarse region is; a cell whose only neighbours outside its region are
    ``nodata`` (a boolean array, optional) is no rim cell. With ``step_m`` (dh0 plus the terrain's
    rise over a cell diagonal; ``tan_s`` the tolerated slope), the high regions still too wide are cut
    into their smooth pieces, each tested as a region (:func:`_wide_pieces`). Returns the flat indices
    of their cells (sorted).

    The caller leaves these cells at their height in the cleaned surface that scan labelling
    reads: their block's reconstruction is the level of the highest ground the coarse region
    reaches, which on a slope or beside a terrace can stand metres above or below the ground
    at their foot; lowered to it, a building joined the terrace beside it into one raised run
    that scan labelling then took with the terrace's ground (ISPRS samp41 at 1 m lowest points,
    3.95 -> 5.85 %; kept at their height 3.17 %).
    """
    H, W = w.shape
    # each block's reconstruction over its cells (inf outside the blocks): raster-sized arrays, where a
    # list of the blocks' cells and their owners took twice the memory
    lvl = np.full(Rc.size, np.inf, Rc.dtype)
    lvl[blocks] = Rc.ravel()[blocks]
    lvl = block_expand(lvl.reshape(Rc.shape), f, (H, W))
    with np.errstate(invalid="ignore"):
        np.subtract(w, lvl, out=lvl)              # the residual (NaN at nodata, -inf off the blocks)
    cand = lvl > dh0
    cells = np.flatnonzero(cand)
    if cells.size == 0:
        return cells
    res = lvl.ravel()[cells]
    del lvl
    lab, n = label8(cand)
    lab_c = lab.ravel()[cells]
    # the tests of _component_stats, without its sort: counts per label and the labels' boxes
    high = np.bincount(lab_c, weights=res > dh_k, minlength=n + 1) > 0
    # a rim cell has a valid neighbour outside; the raster's edge and nodata are none
    edge = inner_cells(cand, nodata)
    del cand
    edge[0] = edge[-1] = True
    edge[:, 0] = edge[:, -1] = True
    rim = ~edge.ravel()[cells]
    del edge
    rim_n = np.bincount(lab_c, weights=rim, minlength=n + 1)
    rim_s = np.bincount(lab_c, weights=rim & jump.ravel()[cells] & (res >= flag_min), minlength=n + 1)
    keep = high & (rim_s >= edge_ratio * rim_n) & (rim_n > 0)
    box = ndimage.find_objects(lab)
    del lab
    ext = np.array([(b[0].stop - b[0].start, b[1].stop - b[1].start) for b in box], np.float64).reshape(-1, 2)
    small = np.ones(n + 1, bool)
    small[1:] = (ext[:, 0] * dy <= ext_limit) & (ext[:, 1] * dx <= ext_limit)
    keep &= small
    keep[0] = False
    out = cells[keep[lab_c]]
    wide = high & ~small
    wide[0] = False
    if step_m is None or not wide.any():
        return out
    on = wide[lab_c]
    del lab_c
    sub = cells[on]
    more = _wide_pieces(w, sub, res[on], (jump.ravel()[sub] & (res[on] >= flag_min)), step_m, dh0, tan_s, dh_k,
                        edge_ratio, ext_limit, dx, dy)
    return np.union1d(out, more)


def _wide_pieces(w, cells, res, wall, step_m, dh0, tan_s, dh_k, edge_ratio, ext_limit, dx, dy):
    """The objects among the ``cells`` (flat, sorted) of :func:`_fine_regions`' regions too wide to be one:
    their smooth pieces (:func:`~bare_earth.core.estimate.smooth_parts`: 8-neighbours joined where their
    heights differ by at most ``step_m``, dh0 plus the terrain's rise over a cell diagonal), each tested as a
    region. ``res``: each cell's residual; ``wall``: it holds a wall with a residual of at least the step's
    wall height (the rim test of :func:`_fine_regions`). Returns the flat indices of the pieces' cells.

    A region wider than :data:`EXTENT_FACTOR` largest objects is never an object: a closed canopy over a
    hillside (a third of its cells without a ground return at 1 m), a ring of roofs round a courtyard with
    lower roofs inside it, whose cells all join. The paper's height-heterogeneity test still applies to
    what its walls part: a piece is an object when

    * it is no wider than the largest step's limit and its outline lies inside the raster (a piece the
      raster's edge cuts is not seen whole);
    * it holds a cell whose 8 neighbours are all its own (it is at least three cells wide: a line of
      cells between two steps on a steep rough slope is none);
    * its highest residual exceeds ``dh_k`` and what a terrain bump as wide as the piece may rise,
      ``dh0 + tan(slope) * width *`` :data:`BUMP_FRACTION`, the width ``2 area / outline`` (the
      dilation's height test, with the piece's own width for the window's);
    * at least ``edge_ratio`` of its outline cells (a valid neighbour outside the piece; the raster's edge
      and nodata are none) hold a wall (``wall``) that drops to the outside: the cell stands above its
      lowest neighbour outside the piece by more than ``2 dh0`` plus the terrain's rise over a cell
      diagonal (the wall test of :func:`wall_cells`; on a slope a piece's uphill side does not drop).
    """
    H, W = w.shape
    wall_m = 2.0 * dh0 + tan_s * np.hypot(dx, dy)
    n_p, piece = smooth_parts(w, cells, step_m)
    plab = np.full(H * W, -1, np.int32)
    plab[cells] = piece
    r, c = np.divmod(cells, W)
    inside = (r > 0) & (r < H - 1) & (c > 0) & (c < W - 1)
    q0, own = cells[inside], piece[inside]
    wf = w.ravel()
    rim = np.zeros(cells.size, bool)
    outline = np.zeros(q0.size, bool)             # a neighbour not in the piece (nodata included)
    rim_in = np.zeros(q0.size, bool)              # a valid neighbour not in the piece
    low_out = np.full(q0.size, np.inf, wf.dtype)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr or dc:
                q = q0 + dr * W + dc
                out = plab[q] != own
                outline |= out
                out &= np.isfinite(wf[q])
                rim_in |= out
                np.copyto(low_out, np.fmin(low_out, wf[q]), where=out)
    del plab
    rim[inside] = rim_in
    drops = np.zeros(cells.size, bool)
    with np.errstate(invalid="ignore"):
        drops[inside] = wf[q0] - low_out > wall_m
    n_rim = np.bincount(piece, weights=rim, minlength=n_p)
    n_wall = np.bincount(piece, weights=rim & wall & drops, minlength=n_p)
    top = np.full(n_p, -np.inf)
    np.maximum.at(top, piece, res)
    area = np.bincount(piece, minlength=n_p) * (dx * dy)
    width = 2.0 * area / np.maximum(n_rim, 1) / np.sqrt(dx * dy)
    high = top > np.maximum(dh_k, dh0 + tan_s * width * BUMP_FRACTION)
    core = np.bincount(own, weights=~outline, minlength=n_p) > 0
    r0, r1, c0, c1 = label_boxes(piece, r, c, n_p, (H, W))
    seen = (r0 > 0) & (c0 > 0) & (r1 < H) & (c1 < W)
    keep = (high & core & seen & (n_rim > 0) & (n_wall >= edge_ratio * n_rim)
            & ((r1 - r0) * dy <= ext_limit) & ((c1 - c0) * dx <= ext_limit))
    return cells[keep[piece]]


def _walled_pieces(w, blocks, Rc, f, step_m, dh0, dh_k, edge_ratio, ext_limit, dx, dy):
    """The objects among the regions of a widened step that are high enough but fail the rim test
    (``blocks``: their cells on the step's grid of factor ``f``, flat on the grid of ``Rc``): their
    cells whose own residual above their block's reconstruction exceeds ``dh0``, split at their walls
    into smooth pieces (:func:`~bare_earth.core.estimate.smooth_parts`: 8-neighbours joined where their
    heights differ by at most ``step_m``), each tested as a region: an object when higher than ``dh_k``,
    no wider than ``ext_limit`` metres, and at least ``edge_ratio`` of its outline cells (a neighbour
    outside the piece; the raster's edge is none) stand above one of their 8 neighbours by more than
    ``step_m`` (:func:`_fine_outline`'s wall test). Returns the flat indices of their cells (sorted).

    A step is widened to the window of a raised region standing on walls (a hall, a roof cut by the
    raster's edge: :func:`~bare_earth.core.estimate.raised_region_window`), and such a window is wider
    than the ground seen beyond those walls: its opening falls to the lowest ground, so the ground
    beyond the walls that rises more than ``dh0`` above it joins the roof in one residual region, whose
    rim (on that ground, not on the walls) fails the test (issue 12: lidar ``sample_c``, a roof over
    75 % of the tile, kept at every cell size with the window widened to 174-183 m). Its walls part
    the roof from that ground, as the smooth pieces of :func:`_fine_outline` part a roof from raised
    ground at its foot.
    """
    H, W = w.shape
    cells, owner = _fine_cells(blocks, f, Rc.shape[1], (H, W))
    wf = w.ravel()
    with np.errstate(invalid="ignore"):
        res = wf[cells] - Rc.ravel()[blocks][owner]
        on = res > dh0
    cells, res = cells[on], res[on]
    order = np.argsort(cells, kind="stable")
    cells, res = cells[order], res[order]
    if cells.size == 0:
        return cells
    n, piece = smooth_parts(w, cells, step_m)
    lab = np.full(H * W, -1, np.int32)
    lab[cells] = piece
    r, c = np.divmod(cells, W)
    inside = np.flatnonzero((r > 0) & (r < H - 1) & (c > 0) & (c < W - 1))
    q0, own = cells[inside], piece[inside]
    outline = np.zeros(cells.size, bool)
    low = np.full(inside.size, np.inf, np.float64)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr or dc:
                q = q0 + dr * W + dc
                outline[inside] |= (lab[q] != own) & np.isfinite(wf[q])     # nodata is no outline
                low = np.fmin(low, wf[q])
    del lab
    abrupt = np.zeros(cells.size, bool)
    with np.errstate(invalid="ignore"):
        abrupt[inside] = outline[inside] & (wf[q0] - low > step_m)
    n_out = np.bincount(piece, weights=outline, minlength=n)
    n_abr = np.bincount(piece, weights=abrupt, minlength=n)
    high = np.bincount(piece, weights=res > dh_k, minlength=n) > 0
    r0, r1, c0, c1 = label_boxes(piece, r, c, n, (H, W))
    keep = (high & (n_out > 0) & (n_abr >= edge_ratio * n_out) & ((r1 - r0) * dy <= ext_limit)
            & ((c1 - c0) * dx <= ext_limit))
    return cells[keep[piece]]


def _fine_outline(w, cells, step_m, edge_ratio, shared=None, nodata=None, res=None, dh_k=None):
    """Which ``cells`` of a coarse step's objects lie in a part with an abrupt outline.

    A coarse block holding a wall anywhere counts as a wall, so one coarse region can
    join separate objects with raised terrain and pass the rim test through their walls:
    on a small clip the 64 m step kept the terrain at the high corner of gentle ground
    (the window, truncated by the raster's edge, cuts a slope there) as an object, through
    the walls of the buildings standing on it (issue 12: 12-37 % total error on city clips
    of 100 x 120 m, and a result changing with the clip's orientation). The removed cells
    (``cells``: flat indices of the cells whose own residual exceeds dh0) are therefore
    split into their 8-connected parts, and a part stays an object when at least
    ``edge_ratio`` of its outline cells (a kept neighbour; the raster's edge and ``nodata``, a boolean
    array, optional, end the data and are no outline) stand above one of their 8 neighbours by more than ``step_m`` (dh0
    plus the terrain's rise over a cell diagonal: the border stage's test of a wall's foot
    or a crown's edge). A part with no outline inside the raster keeps its region's
    decision.

    The same test then runs on the smooth pieces of the parts (:func:`smooth_parts`:
    8-neighbours joined where their heights differ by at most ``step_m``, so a wall
    separates a roof from raised ground at its foot; the wall to another piece is no
    outline) and a cell stays an object when both its part and its piece pass: ground
    raised above the terrain level of a coarse step and walled by the buildings around it
    joined them in one 8-connected part and went with them through their walls (a
    courtyard or a street at a raster's corner, 2-3 m above the ground a 32 m window
    reaches; issue 12: ISPRS samp41 at 2 m, 576 of 1043 wrongly removed ground points,
    total 11.42 -> 6.53 %). Returns a boolean per cell. ``shared`` (a dict) keeps the 3 x 3
    minimum of ``w`` for the next coarse step (the same ``w``).

    With ``res`` (each cell's residual above its block's reconstruction) and ``dh_k`` (the step's
    height test), the cells of a passing part no higher than ``dh_k`` that form a courtyard inside it
    (:func:`_enclosed_low_pieces`: a smooth piece with no outline cell, not standing on walls) are
    given back: the part's outline is the ring's outer walls, and the pieces were tested only where
    an outline cell is no wall (issue 12: the synthetic site ``courtyard`` at 1 m, a yard 34 x 29 m
    taken by the step widened to 141 m, 0.78 -> 0.00 %).
    """
    if cells.size == 0:
        return np.zeros(0, bool)
    H, W = w.shape
    fine = np.zeros(H * W, bool)
    fine[cells] = True
    fine = fine.reshape(H, W)
    rows, cols = np.divmod(cells, W)
    rim = ~inner_cells(fine, nodata).ravel()[cells] & (rows > 0) & (rows < H - 1) & (cols > 0) & (cols < W - 1)
    lab, n = label8(fine)
    part = lab.ravel()[cells]
    del fine, lab
    low3 = None if shared is None else shared.get("low3")
    if low3 is None:
        low3 = rect_filter(np.where(np.isfinite(w), w, np.inf), (3, 3), np.minimum, np.inf).ravel()
        if shared is not None:
            shared["low3"] = low3
    low = low3[cells]
    with np.errstate(invalid="ignore"):
        abrupt = rim & (w.ravel()[cells] - low > step_m)
    rim_n = np.bincount(part, weights=rim, minlength=n + 1)
    rim_s = np.bincount(part, weights=abrupt, minlength=n + 1)
    keep = (rim_s >= edge_ratio * rim_n)[part]
    # a smooth piece lies inside one part, and the outline of its pieces is the part's own: only the pieces
    # of the parts that passed with an outline cell that is no wall can fail (a part whose outline cells all
    # hold one passes with all its pieces: a town re-analysed at the raster's cells, 2 million cells at
    # 16 Mcells, is mostly roofs walled all round)
    sub = np.flatnonzero(keep & (rim_s < rim_n)[part])
    rim_all = rim
    if sub.size:
        n_p, parts = smooth_parts(w, cells[sub], step_m)
        rim, abrupt = rim[sub], abrupt[sub]
        rim_n = np.bincount(parts, weights=rim, minlength=n_p + 1)
        rim_s = np.bincount(parts, weights=abrupt, minlength=n_p + 1)
        keep[sub] = (rim_s >= edge_ratio * rim_n)[parts]
    if res is not None and dh_k is not None:
        low = np.flatnonzero(keep & (res <= dh_k))
        if low.size:
            keep[low[_enclosed_low_pieces(w, cells[low], rim_all[low], step_m, edge_ratio)]] = False
    return keep


def _enclosed_low_pieces(w, cells, outline, step_m, edge_ratio):
    """Which ``cells`` (flat indices) lie in a courtyard of the objects a coarse step removes: a smooth
    piece of them (:func:`~bare_earth.core.estimate.smooth_parts`, neighbours joined where their heights
    differ by at most ``step_m``) with no ``outline`` cell (a cell beside a kept one: the piece lies wholly
    inside the removed cells, the raster's edge and nodata ending the data) that does not stand on walls:
    fewer than ``edge_ratio`` of its boundary cells (a valid neighbour outside the piece, inside the raster)
    stand above their lowest such neighbour by more than ``step_m`` (the outline test of :func:`_fine_outline`).

    The caller passes the cells of the step's objects no higher above their block's reconstruction than
    the step's height test ``dh_k``: alone they are no object of the step (the paper's height test), and
    they are in it only as the 8-connected neighbours of the walls around them. A courtyard enclosed by a
    ring of buildings is such a piece: its cells stand above a widened step's reconstruction by more than
    ``dh0`` where the window reaches lower ground (0.8 m in the synthetic site ``courtyard`` on its slope),
    so they join the ring's part, whose outline is the ring's outer walls, and went with it; its own
    boundary climbs the walls. A roof on walls inside the ring (a garage in the yard) drops to the yard;
    a lower roof in a ring of higher ones stands higher above the reconstruction than ``dh_k`` of the
    steps whose window spans it.

    Examples
    --------
    >>> w = np.zeros((9, 9), np.float32)
    >>> w[1:8, 1:8] = 10.0                   # a ring of roofs ...
    >>> w[3:6, 3:6] = 0.8                    # ... round a courtyard above the step's level
    >>> cells = np.flatnonzero(w.ravel() == np.float32(0.8))
    >>> _enclosed_low_pieces(w, cells, np.zeros(cells.size, bool), 0.8, 0.55).all()
    True
    >>> w[4, 4] = 3.0                        # a shed in the courtyard: its own piece, on walls
    >>> cells = np.flatnonzero((w > 0) & (w < 5))
    >>> _enclosed_low_pieces(w, cells, np.zeros(cells.size, bool), 0.8, 0.55).tolist()
    [True, True, True, True, False, True, True, True, True]
    """
    n_q, piece = smooth_parts(w, cells, step_m)
    H, W = w.shape
    plab = np.full(H * W, -1, np.int32)
    plab[cells] = piece
    r, c = np.divmod(cells, W)
    inside = (r > 0) & (r < H - 1) & (c > 0) & (c < W - 1)
    q0, own = cells[inside], piece[inside]
    wf = w.ravel()
    bound = np.zeros(q0.size, bool)            # a valid neighbour outside the piece
    low_out = np.full(q0.size, np.inf, wf.dtype)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            if dr or dc:
                q = q0 + dr * W + dc
                out = (plab[q] != own) & np.isfinite(wf[q])
                bound |= out
                np.copyto(low_out, np.fmin(low_out, wf[q]), where=out)
    del plab
    with np.errstate(invalid="ignore"):
        drop = bound & (wf[q0] - low_out > step_m)
    n_b = np.bincount(own, weights=bound, minlength=n_q)
    n_d = np.bincount(own, weights=drop, minlength=n_q)
    enclosed = np.bincount(piece, weights=outline, minlength=n_q) == 0
    return (enclosed & (n_b > 0) & (n_d < edge_ratio * n_b))[piece]


def _component_stats(lab, n, sel, values, inner, flag, flag_min):
    """Per-label statistics of the cells of ``sel`` (labelled ``lab``, ``n`` labels).

    A cell is on its region's *rim* when it is not ``inner`` (a neighbour is outside the
    region) and not on the raster's edge (the edge ends the data, it is no border). A rim
    cell is *abrupt* when ``flag`` holds there and ``values >= flag_min``.

    Returns
    -------
    idx, lab_c : ndarray
        Flat indices of the cells of ``sel`` and their labels.
    vmax, rim_mean, ext_r, ext_c : ndarray, indexed by label (0 unused)
        Max of ``values``; share of rim cells that are abrupt; bounding-box rows, columns.
    """
    idx = np.flatnonzero(sel)
    lab_c = lab.ravel()[idx]
    v = values.ravel()[idx]
    order = np.argsort(lab_c, kind="stable")
    ls = lab_c[order]
    starts = np.r_[0, np.flatnonzero(np.diff(ls)) + 1]
    present = ls[starts]
    H, W = lab.shape
    rows, cols = np.divmod(idx, W)
    vmax = np.full(n + 1, -np.inf)
    vmax[present] = np.maximum.reduceat(v[order], starts)
    ext_r = np.zeros(n + 1, np.int64)
    ext_c = np.zeros(n + 1, np.int64)
    ro, co = rows[order], cols[order]
    ext_r[present] = np.maximum.reduceat(ro, starts) - np.minimum.reduceat(ro, starts) + 1
    # columns are not sorted within a label: min/max of columns via reduceat too
    ext_c[present] = np.maximum.reduceat(co, starts) - np.minimum.reduceat(co, starts) + 1
    rim = ~inner.ravel()[idx] & (rows > 0) & (rows < H - 1) & (cols > 0) & (cols < W - 1)
    r = rim.astype(np.float64)
    rim_n = np.bincount(lab_c, weights=r, minlength=n + 1)
    rim_s = np.bincount(lab_c, weights=r * (flag.ravel()[idx] & (v >= flag_min)), minlength=n + 1)
    rim_mean = np.divide(rim_s, rim_n, out=np.zeros(n + 1), where=rim_n > 0)
    return idx, lab_c, vmax, rim_mean, ext_r, ext_c


def wall_reach(cell_size):
    """The reach ``(rows, columns)`` in cells of :func:`wall_cells`' test: :data:`WALL_BASE_M`, at least one
    cell."""
    dx, dy = cell_size
    return max(1, int(round(WALL_BASE_M / dy))), max(1, int(round(WALL_BASE_M / dx)))


def wall_cells(w, valid, cell_size, dh0, tan_s):
    """Cells holding a wall: above a cell within :data:`WALL_BASE_M` (one cell at 1 m; two
    at 0.5 m, where matching smears walls) by more than ``2 dh0`` plus the terrain's rise
    over that distance."""
    dx, dy = cell_size
    wr = wall_reach(cell_size)
    low = rect_filter(fill_nodata(w, valid, np.inf), (2 * wr[0] + 1, 2 * wr[1] + 1), np.minimum, np.inf)
    with np.errstate(invalid="ignore"):
        return valid & (w - low > 2.0 * dh0 + tan_s * np.hypot(wr[0] * dy, wr[1] * dx))


def gradual_dilation(w, valid, cell_size, sizes, dh0, tan_s, edge_ratio, step, progress=None, pool=None,
                     split_beyond_m=None):
    """Stage 2: the dilation steps of ``sizes`` metres, their regions removed together.

    Each step works on the preprocessed surface ``w`` (:func:`dilation_step`), so the
    steps are independent; the union of their objects is removed. ``step`` (uint8) is
    written in place: ``k`` where step ``k`` (from 1) first removed a cell not already
    coded (outliers keep their code).

    Returns
    -------
    removed : ndarray of bool
        Cells removed by any step.
    cleaned : ndarray of float32
        ``w`` with removed cells lowered to the reconstruction of the first (finest) step that
        removed each (the cells of regions analysed at the raster's cells keep their height:
        :func:`_fine_regions`). The finest step reconstructs the ground from markers within its own
        window on its finest grid; a wider step's level comes from farther (one wider window) on
        coarser blocks, and under a canopy on a slope it lay up to 2 m under the ground kept between
        the crowns: scan labelling, which reads this surface, then took that ground as runs rising
        out of one crown and falling into the next (synthetic forest on an 8-degree slope at 0.25 m
        cells, 80-128 m tiles: 4.02 % total with the lowest level of all the steps, 0.11 % with
        the finest step's; issue 12).
    counts : list of int
        Cells newly coded per step.
    terrain : (ndarray, int)
        The last (largest) step's reconstruction on its grid and the grid's factor: the
        terrain level that no object reaches (see :func:`terrain_at`).

    ``pool`` (optional, an executor): its idle threads may run some of the steps
    (:func:`~bare_earth.core.blocks.run_sharing`); the same result. The steps wider than
    ``split_beyond_m`` (the default largest object: steps widened to a raised region) split their
    high regions that fail the rim test at their walls (:func:`dilation_step`'s ``split``).
    """
    dx, dy = cell_size
    cleaned = w.copy()
    removed = np.zeros(w.shape, bool)
    ext_limit = EXTENT_FACTOR * sizes[-1]
    jump = wall_cells(w, valid, cell_size, dh0, tan_s)
    H, W = w.shape
    factors = [coarse_factor((min(c[0], 2 * H + 1), min(c[1], 2 * W + 1)))
               for c in (window_cells(s, dx, dy) for s in sizes)]
    grids = coarse_grids(w, valid, jump, factors)
    report(progress, 0.02)
    counts, recon, shared = [], [], {}
    rf, sf, cf = removed.ravel(), step.ravel(), cleaned.ravel()
    parts = [sub_progress(progress, 0.02 + 0.98 * (k - 1) / len(sizes), 0.02 + 0.98 * k / len(sizes))
             for k in range(1, len(sizes) + 1)]

    def one(k, s):
        keep = recon if k == len(sizes) else None
        return dilation_step(w, valid, w, jump, s, dx, dy, dh0, tan_s, edge_ratio, ext_limit, parts[k - 1], grids,
                             reconstruction=keep, shared=shared,
                             split=split_beyond_m is not None and s > split_beyond_m * 1.001)

    # the steps are independent: with ``pool``, the threads it has idle take some (blocks.run_sharing; their
    # results kept until all are done), else each is applied as it ends
    tasks = [functools.partial(one, k, s) for k, s in enumerate(sizes, start=1)]
    steps = run_sharing(tasks, pool) if pool is not None else (t() for t in tasks)
    for k, (cells, R) in enumerate(steps, start=1):
        part = parts[k - 1]
        first = ~rf[cells]                        # the finest step removing a cell sets its level
        new = first & (sf[cells] == 0)            # outliers keep their own code
        rf[cells] = True
        sf[cells[new]] = k
        report(part, 0.98)
        cf[cells[first]] = np.minimum(cf[cells[first]], R[first])
        counts.append(int(np.count_nonzero(new)))
        report(part, 1.0)
    return removed, cleaned, counts, recon[0]


def terrain_at(terrain, cells, shape):
    """The terrain level of :func:`gradual_dilation` (its largest step's reconstruction
    ``(Rc, f)``) at the flat ``cells`` of a raster of ``shape``: ``Rc`` of the block of
    ``f`` x ``f`` cells holding each (NaN at nodata, ``-inf`` where no marker reaches)."""
    Rc, f = terrain
    r, c = np.divmod(cells, shape[1])
    return Rc[r // f, c // f]
