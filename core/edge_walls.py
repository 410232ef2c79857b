"""The run of a raised region's walls, mirrored at the raster's edge: how far a stage must reach.

A raised region cut by the raster's edge may continue beyond it: nothing is seen there. Its
*walls* (the steps down from it to the ground) say how far it runs: mirrored at every side of
the raster they meet (:func:`~bare_earth.core.common.edge_mirrored_spans`), a wall cutting off
a corner of the raster (meeting two adjacent sides: a roof over most of a tile, lidar
``sample_c``) spans twice what is seen along each axis, and a wall running across the raster
(meeting two opposite sides: a terrain step, a river's wall, a quarry bench) continues beyond
both and spans three times what is seen. A stage that decides such regions takes those whose
walls run within its reach; ``bareearth:dtm``'s raised regions (:mod:`.dtm_regions`), the
curvature filter's region stage and RASCOR's level changes read the same run.

A wall ending in a corner of the raster meets the third side there only with the roof beside its
end, not with the ground at its foot: a side counts as met where both reach it
(:func:`~bare_earth.core.common.walls_runs`, the one copy). Otherwise the diagonal wall of
``sample_c``'s roof, from the top side to the left one, met the bottom side too wherever its last
cell fell on the corner cell (at 1 and 2 m cells, not at 0.5 and 4 m), and its run jumped from
twice to three times the 72 m seen.
"""
import numpy as np
from scipy import ndimage

from .common import steps_beyond, touching, walls_runs


def walled_levels(lab, n, walls, seen_cells, reach_cells, origin=(0, 0), shape=None, drops=None, step=0.0,
                  wall_heights=None):
    """Which of the regions ``1 .. n`` of ``lab`` (levels cut by the raster's edge, 4-connected;
    ``walls``: the cells of their walls, a bool array of ``lab``'s shape) a stage of reach
    ``seen_cells = (rows, columns)`` takes as objects: a bool table over ``0 .. n``.

    A level is taken when what is seen of it (its box) lies within ``seen_cells``, more than
    half of its seen outline (its cells next to a cell of the raster outside it; nothing is seen
    beyond the raster's edge) lies on its walls (within a cell of one: the rest of it is where
    the level comes down to the ground gradually, a hillside's or a terrace's upper level), and
    its walls run within ``reach_cells`` (:func:`~bare_earth.core.common.walls_runs`). ``lab`` may be a window of the
    raster (``shape``, default ``lab``'s) at ``origin`` (row, column): the walls are mirrored at
    the raster's sides, and the window's own edges hold no outline.

    With ``drops`` (each cell's height above its lowest 8-neighbour, in the window), a level the
    raster cuts on two opposite sides is taken only while the ground seen beyond its walls steps
    down no further at the level's own scale, as ``bareearth:dtm``'s raised regions
    (:mod:`.dtm_regions`): the cells within its box, farther than 3 cells from it, that drop by
    more than half its walls' median drop (``wall_heights`` at its wall cells when given, else
    their ``drops``; and than ``step``) are at most half as many as its outline cells. Quarry
    benches or terraces around a pit in a corner of the raster are a sequence of such levels,
    each stepping down to the next by as much, and are left alone; the crowns beside a roof's
    walls are far lower than the roof (lidar ``sample_c`` at 0.5 m: 210 cells of its corner's
    trees drop by more than 2 m against 145 outline cells; none by half its 22 m walls).

    Examples
    --------
    >>> lab = np.zeros((6, 6), int); lab[:4, :4] = 1
    >>> walls = np.zeros((6, 6), bool); walls[:4, 3] = walls[3, :4] = True
    >>> walled_levels(lab, 1, walls, (5, 5), 8).tolist(), walled_levels(lab, 1, walls, (5, 5), 7).tolist()
    ([False, True], [False, False])
    """
    keep = np.zeros(n + 1, bool)
    if n == 0:
        return keep
    boxes = ndimage.find_objects(lab, max_label=n)
    seen = np.array([[b[0].stop - b[0].start, b[1].stop - b[1].start] if b is not None else [0, 0]
                     for b in boxes], np.intp).reshape(-1, 2)
    inside = lab > 0
    on = walls & inside
    rows, cols = np.nonzero(on)
    # the ground at the walls' foot: the cells outside a level within two cells of its wall cells (a wall
    # cell lies within a cell of the outline)
    foot_of = ndimage.grey_dilation(np.where(on, lab, 0), size=(5, 5))
    f_r, f_c = np.nonzero((foot_of > 0) & (lab != foot_of))
    runs = walls_runs(rows + origin[0], cols + origin[1], lab[rows, cols], n, lab.shape if shape is None else shape,
                      f_r + origin[0], f_c + origin[1], foot_of[f_r, f_c])
    outline = np.zeros(lab.shape, bool)
    outline[1:] |= lab[1:] != lab[:-1]
    outline[:-1] |= lab[:-1] != lab[1:]
    outline[:, 1:] |= lab[:, 1:] != lab[:, :-1]
    outline[:, :-1] |= lab[:, :-1] != lab[:, 1:]
    outline &= inside
    on_wall = outline & touching(walls & inside)
    n_out = np.bincount(lab[outline], minlength=n + 1)
    n_wall = np.bincount(lab[on_wall], minlength=n + 1)
    keep[1:] = ((seen[:, 0] <= seen_cells[0]) & (seen[:, 1] <= seen_cells[1]) & (runs[1:] > 0)
                & (runs[1:] <= reach_cells) & (2 * n_wall[1:] > n_out[1:]))
    if drops is not None:
        h, w = lab.shape if shape is None else shape
        for i in np.flatnonzero(keep[1:]) + 1:
            b = boxes[i - 1]
            r0, r1 = b[0].start + origin[0], b[0].stop + origin[0]
            c0, c1 = b[1].start + origin[1], b[1].stop + origin[1]
            if not ((r0 == 0 and r1 == h) or (c0 == 0 and c1 == w)):
                continue
            reg = lab[b] == i
            own_drop = (drops if wall_heights is None else wall_heights)[b][reg & walls[b]]
            scale = max(float(step), 0.5 * float(np.median(own_drop)))
            if 2 * steps_beyond(reg, drops[b] > scale) > n_out[i]:
                keep[i] = False
    return keep
