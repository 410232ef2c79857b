"""dtm's members on a coarser grid: the lowest cell of each ``f x f`` block, then back to full resolution.

The members' windows, thresholds and their vote were built for, and measured on, DSMs of 1-4 m cells:
the finest rows of the generalisation matrix with a reference below 1 m are 0.5 m lidar tiles, whose
points (a few a square metre) leave most 0.5 m cells with a height interpolated between them. On a
grid finer than :data:`COARSE_CELL_M` the members spend most of their work on cells that say nothing
new: :func:`coarse_factor` coarsens it by the largest power of two ``f`` keeping a coarse cell at most
that size (a power of two, so that block windows, aligned on powers of two, see the coarse grid of the
single pass; :func:`~.blocks.alignment`). The coarse surface is the lowest height of each block
(:func:`~.estimate.block_minima`): the minimum keeps the ground wherever a block holds some, so a
member's decision on a block is its decision on the block's lowest cell.

Not coarser: with the members at 2 m on 1 m DSMs (``f`` 2 on the matrix's 1 m rows) the vote lost what
its 2 m rows lose (ISPRS seven at 1 m, lowest point, 3.38 -> 4.30 %; a road embankment's crest taken by
RASCOR's profiles at 2 m as a raised strip, synthetic ``mixed`` 1 m 0.54 -> 3.89 %), and so did each
member alone at 2 m (ISPRS seven +0.19 to +0.20 for the opening or the reconstruction).

:meth:`CoarseGrid.expand_mask` gives each full-resolution cell its member's decision on its block, tested
at full resolution the way the refinement tests voted ground:

* a cell of a *ground* block standing more than the allowance above the block's lowest cell (the
  threshold ``t`` plus what the terrain's 90th-percentile slope raises a cell over the block's diagonal,
  :func:`block_allowance`) and more than ``t`` above the highest ground block around (a wall's top beside
  its foot, a bush's crown: on a steep bank the ground continues upwards beside the cell) is an object;
* a cell of an *object* block (each stands at or above its block's lowest cell, which is one), or one of
  the other cells of a *low* block, is ground where it lies within the allowance (over two blocks) of the
  lowest ground block around, above or below, and not more than ``t`` above the highest: the coarse
  decision is a block's, the edge of an object runs through blocks; a low block's other cells further
  below that ground than the allowance are low too (a pit wider than one cell), the rest objects.
"""
import numpy as np
from scipy import ndimage

from .codes import GROUND, LOW, NODATA, OBJECT
from .estimate import block_expand, block_minima

#: The largest coarse cell the members run on, metres: the finest cell they were built and measured for.
COARSE_CELL_M = 1.0


def coarse_factor(cell_size, coarse_cell_m=COARSE_CELL_M):
    """The largest power of two ``f`` (>= 1) keeping cells of ``cell_size`` (metres, ``(dx, dy)``) coarsened by it
    at most ``coarse_cell_m`` a side.

    >>> coarse_factor((1.0, 1.0)), coarse_factor((0.5, 0.5)), coarse_factor((0.3, 0.3)), coarse_factor((0.25, 0.25))
    (1, 2, 2, 4)
    """
    f = 1
    while 2 * f * max(cell_size) <= coarse_cell_m * (1 + 1e-9):
        f *= 2
    return f


def coarsen(z, f):
    """The lowest height of every ``f x f`` block of ``z`` (blocks from the origin; NaN where none)."""
    return z if f <= 1 else block_minima(z, f)


def coarsen_flags(a, f, shape):
    """Any flag (bool) of each ``f x f`` block of a raster of ``shape``, on the coarse grid (break lines)."""
    if a is None or f <= 1:
        return a
    rows, cols = shape
    nr, nc = -(-rows // f), -(-cols // f)
    p = np.zeros((nr * f, nc * f), bool)
    p[:rows, :cols] = a
    return p.reshape(nr, f, nc, f).any(axis=(1, 3))


def block_allowance(tolerance_m, slope, cell_size, f, blocks=1):
    """How far a ground cell may stand above the lowest cell of its block (``blocks`` 1), or of a block beside
    it (``blocks`` 2), metres: the threshold ``t`` plus the rise of the terrain's slope ``s`` (rise / run) over
    the longest distance between the two cells (``blocks f - 1`` cells along the diagonal)."""
    d = (blocks * f - 1) * float(np.hypot(*cell_size))
    return float(tolerance_m) + max(0.0, float(slope)) * d


class CoarseGrid:
    """A DSM's coarse grid (:func:`coarsen`) and the full-resolution tests its members' decisions are expanded
    with (:meth:`expand_mask`).

    Parameters
    ----------
    z : ndarray, 2-D float32
        The DSM (NaN nodata).
    cell_size : (float, float)
        Metres.
    f : int
        The coarsening factor (:func:`coarse_factor`).
    tolerance_m : float
        The vote's decision threshold ``t``, metres.
    slope : float
        The terrain's 90th-percentile slope (rise / run), the refinement's.
    """

    def __init__(self, z, cell_size, f, tolerance_m, slope):
        self.f = int(f)
        self.shape = z.shape
        self.z = z
        self.cell = (cell_size[0] * self.f, cell_size[1] * self.f)
        self.zc = coarsen(z, self.f)
        self.tolerance = float(tolerance_m)
        self.allow = block_allowance(tolerance_m, slope, cell_size, self.f)
        self.allow_near = block_allowance(tolerance_m, slope, cell_size, self.f, blocks=2)
        self.above = self.lowest = None
        if self.f > 1:                       # once, before the members' threads read them
            with np.errstate(invalid="ignore"):
                h = self.z - block_expand(self.zc, self.f, self.shape)
                self.above = h > self.allow
                self.lowest = h <= 0

    def expand_mask(self, mc):
        """A member's coarse mask (uint8 codes) at full resolution (the rules of :mod:`.dtm_coarse`)."""
        if self.f <= 1:
            return mc
        out = block_expand(mc, self.f, self.shape)          # a new array: written in place
        ground_c = np.where(mc == GROUND, self.zc, -np.inf).astype(np.float32)
        high = block_expand(ndimage.maximum_filter(ground_c, size=3, mode="nearest"), self.f, self.shape)
        np.copyto(ground_c, np.where(mc == GROUND, self.zc, np.inf))
        near = block_expand(ndimage.minimum_filter(ground_c, size=3, mode="nearest"), self.f, self.shape)
        with np.errstate(invalid="ignore"):
            above_high = self.z - high
            d = self.z - near
        # ground blocks: raised cells are objects
        out[self.above & (above_high > self.tolerance) & (out == GROUND)] = OBJECT
        # object blocks and the other cells of low blocks: ground within reach of the ground around
        others = (out == LOW) & ~self.lowest
        out[others] = OBJECT
        out[others & (d < -self.allow_near) & np.isfinite(near)] = LOW     # no ground around: no depth
        ok = (d <= self.allow_near) & (d >= -self.allow_near) & (above_high <= self.tolerance)
        out[(out == OBJECT) & ok] = GROUND
        out[~np.isfinite(self.z)] = NODATA
        return out
