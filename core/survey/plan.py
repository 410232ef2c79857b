"""Planning a survey run: the window each tile's task reads, and the sample the survey's
parameters are derived from.

A task reads its tile grown by the method's halo (``Method.halo``, the method's reach) on
every side, clipped to the survey, from the survey VRT: the neighbours' cells around the
tile are read as if the survey were one raster, so the tile's mask is the one of a single
pass over the mosaic (the block property of every method, ``core.blocks``). The window's
upper-left corner is moved further out onto a multiple of :func:`~.blocks.alignment`, so that the
grids a method coarsens internally (geodesic's power-of-two grids, curvature's 2 x 2 ground
surface, the fill's pyramid) are those of the single pass too, as in ``pipeline.run_file``.
"""
import math

import numpy as np

from ..blocks import alignment

#: Cells of the sample the survey's parameters are derived from (pipeline.RESOLVE_SIDE ** 2).
SAMPLE_CELLS = 4096 * 4096
#: Most tiles the sample is drawn from.
SAMPLE_TILES = 16
#: Nodata gutter between the sample's crops, cells (no false edge between two crops).
SAMPLE_GUTTER = 8


def tile_window(tile_window_, shape, halo, align=None):
    """The window a tile's task reads, and where the tile lies in it.

    Parameters
    ----------
    tile_window_ : (r0, r1, c0, c1)
        The tile on the survey grid.
    shape : (rows, cols)
        The survey grid.
    halo : int
        The method's reach in cells.
    align : int, optional
        Alignment of the window's upper-left corner (default :func:`alignment`).

    Returns
    -------
    outer : (r0, r1, c0, c1)
        The window to read (clipped to the survey).
    core : tuple of slice
        The tile inside an array read over ``outer``.

    Examples
    --------
    >>> tile_window((100, 200, 0, 100), (300, 300), 10, align=64)
    ((64, 210, 0, 110), (slice(36, 136, None), slice(0, 100, None)))
    """
    r0, r1, c0, c1 = (int(v) for v in tile_window_)
    a = int(align or alignment(halo))
    o0 = max(0, (r0 - halo) // a * a)
    o2 = max(0, (c0 - halo) // a * a)
    o1 = min(shape[0], r1 + halo)
    o3 = min(shape[1], c1 + halo)
    return (o0, o1, o2, o3), (slice(r0 - o0, r1 - o0), slice(c0 - o2, c1 - o2))


def sample_tiles(tiles, n=SAMPLE_TILES):
    """Up to ``n`` tiles spread over the survey: the tiles nearest to the nodes of a
    regular grid over the tiles' centres (no repeat), in reading order."""
    if len(tiles) <= n:
        return list(tiles)
    cr = np.array([(t.window[0] + t.window[1]) / 2 for t in tiles])
    cc = np.array([(t.window[2] + t.window[3]) / 2 for t in tiles])
    k = int(math.ceil(math.sqrt(n)))
    chosen = []
    for fr in (np.arange(k) + 0.5) / k:
        for fc in (np.arange(k) + 0.5) / k:
            tr = cr.min() + fr * (cr.max() - cr.min())
            tc = cc.min() + fc * (cc.max() - cc.min())
            d = (cr - tr) ** 2 + (cc - tc) ** 2
            d[chosen] = np.inf
            chosen.append(int(np.argmin(d)))
    return [tiles[i] for i in sorted(chosen[:n])]


def central_crop(tile, side):
    """The window ``(r0, r1, c0, c1)`` on the survey grid of the central ``side x side``
    cells of ``tile`` (the whole tile along a side shorter than ``side``)."""
    r0, r1, c0, c1 = tile.window
    h, w = min(side, r1 - r0), min(side, c1 - c0)
    rr, cc = r0 + (r1 - r0 - h) // 2, c0 + (c1 - c0 - w) // 2
    return rr, rr + h, cc, cc + w


def nearest_tiles(tiles, tile):
    """``tiles`` ordered by the distance of their centres from ``tile``'s (``tile`` first)."""
    def centre(t):
        return (t.window[0] + t.window[1]) / 2, (t.window[2] + t.window[3]) / 2
    r, c = centre(tile)
    return sorted(tiles, key=lambda t: (centre(t)[0] - r) ** 2 + (centre(t)[1] - c) ** 2)


def sample_layout(tiles, survey_cells, max_cells=SAMPLE_CELLS):
    """Where the parameter sample comes from.

    A survey of at most ``max_cells`` is its own sample (the parameters are those of a
    single pass over the mosaic). A larger one is sampled by the central crops of
    :func:`sample_tiles`, each of the same side, at most ``max_cells`` in all, laid side
    by side in a grid with :data:`SAMPLE_GUTTER` nodata cells between them. The side is no
    larger than the longest side of those tiles: crops of tiles smaller than their share of
    ``max_cells`` lie side by side too (two 100 x 100 tiles 50 km apart were laid in slots of
    2040 cells, a sample 99.8 % nodata where the noise was not measurable).

    Returns
    -------
    None for the whole survey, else a list of ``(tile, window on the survey grid,
    (row, col) in the sample)`` and the sample's shape.
    """
    if survey_cells <= max_cells:
        return None
    chosen = sample_tiles(tiles)
    k = int(math.ceil(math.sqrt(len(chosen))))
    longest = max(max(t.window[1] - t.window[0], t.window[3] - t.window[2]) for t in chosen)
    side = min(int(math.sqrt(max_cells)) // k - SAMPLE_GUTTER, longest)
    parts = []
    for j, t in enumerate(chosen):
        parts.append((t, central_crop(t, side), ((j // k) * (side + SAMPLE_GUTTER),
                                                 (j % k) * (side + SAMPLE_GUTTER))))
    rows = -(-len(chosen) // k) * (side + SAMPLE_GUTTER) - SAMPLE_GUTTER
    cols = min(len(chosen), k) * (side + SAMPLE_GUTTER) - SAMPLE_GUTTER
    return parts, (rows, cols)
