"""RASCOR break lines and special areas: the regions no comparison may leave.

Jacobsen (2004): no comparison crosses a break line, so a dam or an embankment keeps its
shoulders. The plugin layer rasterises the lines and areas; the core receives boolean
rasters on the DSM's grid.
"""
from typing import Tuple

import numpy as np
from scipy import ndimage


def as_bool_raster(a, shape, name):
    """``a`` as a boolean raster of ``shape`` (None when absent or empty)."""
    if a is None:
        return None
    a = np.asarray(a)
    if a.shape != shape:
        raise ValueError(f"{name} has shape {a.shape} but the DSM has shape {shape}; rasterise "
                         f"{name} on the DSM's grid (one cell per DSM cell).")
    a = a.astype(bool) if a.dtype != bool else a
    return a if a.any() else None


def break_regions(breaklines: np.ndarray) -> Tuple[np.ndarray, int]:
    """Label the regions no comparison may leave.

    Non-break cells are labelled by 4-connected components (a diagonal step between two
    break cells does not leak); break-line cells by 8-connected components of their own,
    so a cell on a line is compared only with cells on the same line.

    Parameters
    ----------
    breaklines : ndarray of bool
        Cells crossed by a break line.

    Returns
    -------
    labels : ndarray of int32
        Region id per cell, 1..n.
    n : int
        Number of regions.
    """
    bl = np.asarray(breaklines, dtype=bool)
    lab, n1 = ndimage.label(~bl)
    lab2, n2 = ndimage.label(bl, structure=np.ones((3, 3), bool))
    lab = lab.astype(np.int32)
    lab[bl] = lab2[bl] + n1
    return lab, n1 + n2


def region_slices(labels):
    """``[(region id, slice)]`` of every region (bounding boxes)."""
    if labels is None:
        return None
    return [(i + 1, s) for i, s in enumerate(ndimage.find_objects(labels)) if s is not None]


