"""RASCOR break lines and special areas: the regions no comparison may leave.

Jacobsen (2004): no comparison crosses a break line, so a dam or an embankment keeps its
shoulders. The plugin layer rasterises the lines and areas; the core receives boolean
rasters on the DSM's grid.
"""
from typing import Optional, Tuple

import numpy as np
from scipy import ndimage

from ..common import as_cell_size, cells_of, label8


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


def break_regions(breaklines: np.ndarray, upper: Optional[np.ndarray] = None) -> Tuple[np.ndarray, int]:
    """Label the regions no comparison may leave.

    Non-break cells are labelled by 4-connected components (a diagonal step between two
    break cells does not leak); break-line cells by 8-connected components of their own,
    so a cell on a line is compared only with cells on the same line. With ``upper``, the line
    cells in it and the others are two sets of lines (a terrain step's upper and lower side,
    :func:`~.steps.find_terrain_steps`): a wall's top is compared along the top only, its foot
    along the foot.

    Parameters
    ----------
    breaklines : ndarray of bool
        Cells crossed by a break line.
    upper : ndarray of bool, optional
        The line cells on the upper side of their level change.

    Returns
    -------
    labels : ndarray of int32
        Region id per cell, 1..n.
    n : int
        Number of regions.
    """
    bl = np.asarray(breaklines, dtype=bool)
    lab, n1 = ndimage.label(~bl)
    lab = lab.astype(np.int32)
    if upper is None:
        lab2, n2 = ndimage.label(bl, structure=np.ones((3, 3), bool))
        lab[bl] = lab2[bl] + n1
        return lab, n1 + n2
    up = bl & np.asarray(upper, dtype=bool)
    lo = bl & ~up
    lab2, n2 = ndimage.label(lo, structure=np.ones((3, 3), bool))
    lab3, n3 = ndimage.label(up, structure=np.ones((3, 3), bool))
    lab[lo] = lab2[lo] + n1
    lab[up] = lab3[up] + n1 + n2
    return lab, n1 + n2 + n3


def region_slices(labels):
    """``[(region id, slice)]`` of every region (bounding boxes)."""
    if labels is None:
        return None
    return [(i + 1, s) for i, s in enumerate(ndimage.find_objects(labels)) if s is not None]




def find_ramps(z: np.ndarray, cell_size, taken: np.ndarray, ground: np.ndarray, *, tolerance_m: float,
               wall_m: float, max_span_m: float) -> np.ndarray:
    """The regions of ``taken`` that are ramps between two levels of ``ground``.

    A ramp (or a road's approach) is an inclined plane: the heights of its region
    (8-connected) lie within ``tolerance_m`` (root mean square) of the region's least-squares
    plane, the plane rises by more than ``tolerance_m`` over the region, and the ground beside
    both of its ends (the cells of ``ground`` touching the region within one cell's rise of its
    lowest and of its highest point along the plane) lies at the plane's own height (within
    ``tolerance_m``); no ground beside it lies more than ``wall_m`` below the plane (its sides
    stand at most a wall above the ground beside them). A roof is level, or, sloped, stands on
    walls at its eaves: no ground meets it at its own height at both ends. Regions running
    further than ``max_span_m`` along the rows or the columns are not tested (their extent
    bounds the reach of the test), nor regions holding no whole 3 x 3 neighbourhood of their
    cells (a few cells or a line fit some plane within any tolerance).

    Parameters
    ----------
    z : ndarray
        DSM (NaN = nodata).
    cell_size : float or (float, float)
        (dx, dy) metres.
    taken, ground : ndarray of bool
        The candidate object cells and the ground kept.
    tolerance_m, wall_m, max_span_m : float

    Returns
    -------
    ndarray of bool
        The cells of the ramp regions.
    """
    dx, dy = as_cell_size(cell_size)
    lab, n = label8(taken)
    out = np.zeros(taken.shape, bool)
    if not n:
        return out
    box = np.array([(b[0].start, b[0].stop, b[1].start, b[1].stop) for b in ndimage.find_objects(lab)],
                   np.intp).reshape(-1, 4)
    span = np.maximum((box[:, 1] - box[:, 0]) * dy, (box[:, 3] - box[:, 2]) * dx)
    ok = np.zeros(n + 1, bool)
    ok[1:] = span <= max_span_m
    # a plane needs a region holding at least one whole 3 x 3 neighbourhood: a thinner region (a few
    # cells, a line along a crown's edge) fits some plane within any tolerance
    held = np.zeros(n + 1, bool)
    held[lab[ndimage.binary_erosion(taken, np.ones((3, 3), bool))]] = True
    ok &= held
    # the region's cells: least-squares plane on coordinates centred on the region's mean
    r, c = cells_of(taken)
    li = lab[r, c]
    zz = z[r, c].astype(np.float64)
    x, y = c * dx, r * dy
    m = n + 1
    cnt = np.bincount(li, minlength=m).astype(np.float64)
    safe = np.maximum(cnt, 1.0)
    mx, my, mz = (np.bincount(li, v, m) / safe for v in (x, y, zz))
    xc, yc, zc = x - mx[li], y - my[li], zz - mz[li]
    sxx, syy, sxy = (np.bincount(li, v, m) for v in (xc * xc, yc * yc, xc * yc))
    sxz, syz = np.bincount(li, xc * zc, m), np.bincount(li, yc * zc, m)
    det = sxx * syy - sxy * sxy
    good = det > 1e-9 * np.maximum(sxx * syy, 1e-30)
    dets = np.where(good, det, 1.0)
    bx = np.where(good, (sxz * syy - syz * sxy) / dets, 0.0)
    by = np.where(good, (syz * sxx - sxz * sxy) / dets, 0.0)
    res = zc - bx[li] * xc - by[li] * yc
    rms = np.sqrt(np.bincount(li, res * res, m) / safe)
    plane = zz - res                                      # the plane's height at each cell
    lo = np.full(m, np.inf)
    hi = np.full(m, -np.inf)
    np.minimum.at(lo, li, plane)
    np.maximum.at(hi, li, plane)
    ok &= good & (rms <= tolerance_m) & (hi - lo > tolerance_m)
    if not ok.any():
        return out
    # the ground touching each region (a ground cell touching two regions is read for each)
    rise = np.hypot(bx * dx, by * dy)                     # the plane's rise over one cell (either axis)
    low_end = np.zeros(m, bool)
    high_end = np.zeros(m, bool)
    walled = np.zeros(m, bool)
    pad = np.pad(lab, 1)
    gr, gc = np.nonzero(ground & np.isfinite(z))
    for di in (-1, 0, 1):
        for dj in (-1, 0, 1):
            if di == 0 and dj == 0:
                continue
            lj = pad[gr + 1 + di, gc + 1 + dj]
            sel = (lj > 0) & ok[lj]
            if not sel.any():
                continue
            lj, rr, cc = lj[sel], gr[sel], gc[sel]
            p = mz[lj] + bx[lj] * (cc * dx - mx[lj]) + by[lj] * (rr * dy - my[lj])
            d = z[rr, cc] - p
            at = np.abs(d) <= tolerance_m
            reach = 1.5 * rise[lj]
            np.logical_or.at(low_end, lj[at & (p <= lo[lj] + reach)], True)
            np.logical_or.at(high_end, lj[at & (p >= hi[lj] - reach)], True)
            np.logical_or.at(walled, lj[d < -wall_m], True)
    ok &= low_end & high_end & ~walled
    return ok[lab] & taken


def profile_runs(labels: np.ndarray, lines: np.ndarray) -> np.ndarray:
    """The regions of the profiles along the rows: each run of non-line cells of one region along
    a row that holds line cells a region of its own, so a profile stops at a break line (Jacobsen
    2004: no comparison crosses a break line) even where the line does not close the region (it
    ends, or has a gap, and the two sides join around it). The other cells keep their regions
    (``labels``, from :func:`break_regions`): the line cells, compared along the line only, and
    the rows without a line cell, whose profiles are those of their regions' rows (each row of a
    region is fitted on its own, :func:`~.fits.fit_and_snoop`).

    Returns
    -------
    ndarray of int32
        Region id per cell, from 1 (``labels``' own, then the runs in row order).
    """
    lab = np.asarray(labels, np.int32)
    bl = np.asarray(lines, bool)
    cut = ~bl & bl.any(axis=1)[:, None]              # the non-line cells of the rows a line crosses
    start = cut.copy()
    start[:, 1:] &= bl[:, :-1] | (lab[:, 1:] != lab[:, :-1])
    run = np.cumsum(start, axis=None, dtype=np.int32).reshape(lab.shape)
    run += np.int32(lab.max() if lab.size else 0)
    return np.where(cut, run, lab)
