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

A wall ending in a corner of the raster meets both of its sides there, within its own width:
only the wall cells farther than ``corner`` cells from one of the two sides of a corner say
which sides the wall meets (a wall with no other cell keeps its corner cells). Otherwise the
diagonal wall of ``sample_c``'s roof, from the top side to the left one, met the bottom side
too wherever its last cell fell on the corner cell (at 1 and 2 m cells, not at 0.5 and 4 m),
and its run jumped from twice to three times the 72 m seen.
"""
import numpy as np
from scipy import ndimage

from .common import edge_mirrored_spans, touching

#: Cells from the sides of a raster corner within which a wall meets both sides (a wall's width).
CORNER_CELLS = 2


def walls_runs(rows, cols, ids, n, shape, corner=CORNER_CELLS):
    """The runs (cells) of the walls of the regions ``1 .. n`` of a raster of ``shape``.

    ``rows, cols`` are the wall cells and ``ids`` their regions (ints in ``1 .. n``). A region's
    run is the larger span (rows or columns) of the box of its wall cells, mirrored at every side
    of the raster the walls meet (:func:`~bare_earth.core.common.edge_mirrored_spans`), the cells
    within ``corner`` cells of both sides of a raster corner left out where the region has other
    wall cells. Returns an int array of ``n + 1`` runs (0: a region without wall cells, and the
    unused index 0).

    Examples
    --------
    >>> walls_runs([0, 1, 2, 3, 4, 5, 5], [3, 3, 2, 1, 0, 0, 3], [1, 1, 1, 1, 1, 1, 2], 2, (6, 6)).tolist()
    [0, 8, 2]
    """
    rows, cols, ids = (np.asarray(a, np.intp).ravel() for a in (rows, cols, ids))
    h, w = shape
    runs = np.zeros(n + 1, np.intp)
    if ids.size == 0:
        return runs
    in_corner = (((rows < corner) | (rows >= h - corner)) & ((cols < corner) | (cols >= w - corner)))
    other = np.bincount(ids[~in_corner], minlength=n + 1) > 0
    use = ~in_corner | ~other[ids]
    rows, cols, ids = rows[use], cols[use], ids[use]
    big = np.iinfo(np.intp).max
    r0, c0 = np.full(n + 1, big, np.intp), np.full(n + 1, big, np.intp)
    r1, c1 = np.full(n + 1, -1, np.intp), np.full(n + 1, -1, np.intp)
    np.minimum.at(r0, ids, rows)
    np.minimum.at(c0, ids, cols)
    np.maximum.at(r1, ids, rows)
    np.maximum.at(c1, ids, cols)
    has = r1 >= 0
    span_r, span_c = edge_mirrored_spans(r0[has], r1[has] + 1, c0[has], c1[has] + 1, shape)
    runs[has] = np.maximum(span_r, span_c)
    return runs


def walled_levels(lab, n, walls, seen_cells, reach_cells, origin=(0, 0), shape=None, drops=None, step=0.0,
                  wall_heights=None):
    """Which of the regions ``1 .. n`` of ``lab`` (levels cut by the raster's edge, 4-connected;
    ``walls``: the cells of their walls, a bool array of ``lab``'s shape) a stage of reach
    ``seen_cells = (rows, columns)`` takes as objects: a bool table over ``0 .. n``.

    A level is taken when what is seen of it (its box) lies within ``seen_cells``, more than
    half of its seen outline (its cells next to a cell of the raster outside it; nothing is seen
    beyond the raster's edge) lies on its walls (within a cell of one: the rest of it is where
    the level comes down to the ground gradually, a hillside's or a terrace's upper level), and
    its walls run within ``reach_cells`` (:func:`walls_runs`). ``lab`` may be a window of the
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
    rows, cols = np.nonzero(walls & inside)
    runs = walls_runs(rows + origin[0], cols + origin[1], lab[rows, cols], n, lab.shape if shape is None else shape)
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
        square = np.ones((3, 3), bool)
        for i in np.flatnonzero(keep[1:]) + 1:
            b = boxes[i - 1]
            r0, r1 = b[0].start + origin[0], b[0].stop + origin[0]
            c0, c1 = b[1].start + origin[1], b[1].stop + origin[1]
            if not ((r0 == 0 and r1 == h) or (c0 == 0 and c1 == w)):
                continue
            reg = lab[b] == i
            own_drop = (drops if wall_heights is None else wall_heights)[b][reg & walls[b]]
            scale = max(float(step), 0.5 * float(np.median(own_drop)))
            own = ndimage.binary_dilation(reg, structure=square, iterations=3)
            if 2 * np.count_nonzero((drops[b] > scale) & ~own) > n_out[i]:
                keep[i] = False
    return keep
