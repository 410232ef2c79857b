"""Orthorectification of frame images onto a DEM grid (collinearity + bilinear resampling).

Each DEM cell centre ``(X, Y, Z = DEM)`` is projected into the image with the collinearity
equations (:meth:`Camera.project`) and the image is sampled there bilinearly. This is the
"orthophoto made with the DEM" of Norvelle (1995) and Luong Chinh Ke (2002, section 2.3):
where the DEM is wrong by ``dh``, the orthophoto cell shows a ground point displaced by
``dh`` times the camera's view vector, which is the parallax the refinement measures.

Grids are north-up GDAL geotransforms ``(x0, dx, 0, y0, 0, -dy)``; cell ``(i, j)`` has its
centre at ``X = x0 + (j + 0.5) dx``, ``Y = y0 - (i + 0.5) dy``.
"""
import numpy as np
from scipy import ndimage

from ..common import real_array

__all__ = ["grid_xy", "check_transform", "orthorectify", "visibility"]


def check_transform(transform):
    """Validate a north-up geotransform; return ``(x0, dx, y0, dy)`` with ``dx, dy > 0``."""
    t = tuple(float(v) for v in transform)
    if len(t) != 6:
        raise ValueError(f"transform must be a 6-number GDAL geotransform; got {transform!r}.")
    if t[2] != 0 or t[4] != 0:
        raise ValueError("rotated grids are not supported; warp the DEM to a north-up grid first.")
    if not (t[1] > 0 and t[5] < 0):
        raise ValueError(f"geotransform must be north-up with positive cell size (dx > 0, dy < 0); "
                         f"got dx={t[1]}, dy={t[5]}.")
    return t[0], t[1], t[3], -t[5]


def grid_xy(shape, transform):
    """Cell-centre coordinates ``X (1, cols)`` and ``Y (rows, 1)`` of a grid (broadcastable)."""
    x0, dx, y0, dy = check_transform(transform)
    rows, cols = shape
    X = x0 + (np.arange(cols) + 0.5) * dx
    Y = y0 - (np.arange(rows) + 0.5) * dy
    return X[None, :], Y[:, None]


def visibility(camera, dem, transform, col=None, row=None, tolerance_m=None):
    """Cells of ``dem`` seen by ``camera`` (not hidden by a nearer part of the surface).

    A vectorised z-buffer: every cell in the image is projected; image pixels are binned at
    about the projected cell size and a cell is visible when its distance to the camera is
    within ``tolerance_m`` of the nearest cell falling in the same bin.

    Returns
    -------
    ndarray of bool, shape of ``dem``
    """
    X, Y = grid_xy(dem.shape, transform)
    _, dx, _, dy = check_transform(transform)
    if col is None:
        col, row = camera.project(X, Y, dem)
    ok = np.isfinite(col) & np.isfinite(row) & np.isfinite(dem)
    if camera is not None:
        w, h = camera.interior.width, camera.interior.height
        ok &= (col >= -1) & (col <= w) & (row >= -1) & (row <= h)
    vis = np.zeros(dem.shape, bool)
    if not ok.any():
        return vis
    dist = np.sqrt((X - camera.centre[0]) ** 2 + (Y - camera.centre[1]) ** 2
                   + (dem - camera.centre[2]) ** 2)
    # projected size of one cell in pixels, robustly (median of column steps)
    step = np.hypot(np.diff(col, axis=1), np.diff(row, axis=1))
    step = step[np.isfinite(step)]
    binsize = max(1.0, 1.5 * float(np.median(step))) if step.size else 1.0
    if tolerance_m is None:
        tolerance_m = 1.5 * max(dx, dy)
    bc = np.floor(col[ok] / binsize).astype(np.int64)
    br = np.floor(row[ok] / binsize).astype(np.int64)
    bc -= bc.min()
    br -= br.min()
    key = br * (bc.max() + 1) + bc
    d = dist[ok]
    zbuf = np.full(int(key.max()) + 1, np.inf)
    # nearest distance per bin (= np.minimum.at, much faster): write, then rewrite with the
    # cells still nearer than their bin's value; each round lowers every such bin to one of
    # its own distances, so it ends with every bin at its minimum
    kk, dd = key, d
    while kk.size:
        zbuf[kk] = dd
        nearer = dd < zbuf[kk]
        kk, dd = kk[nearer], dd[nearer]
    vis[ok] = d <= zbuf[key] + tolerance_m
    return vis


def orthorectify(image, camera, dem, transform, *, occlusion=True, order=1):
    """Orthophoto of ``image`` on the grid of ``dem`` (collinearity, bilinear resampling).

    Parameters
    ----------
    image : ndarray, (rows, cols) or (bands, rows, cols)
        The frame image; NaN marks invalid pixels in float images.
    camera : Camera
        Its interior and exterior orientation (world units of ``transform``).
    dem : ndarray (rows, cols)
        Heights of the grid cells (NaN = nodata).
    transform : 6 floats
        North-up GDAL geotransform of ``dem``.
    occlusion : bool
        Mask cells hidden from the camera by a nearer part of the DEM (z-buffer).
    order : int
        Spline order of the resampling; 1 = bilinear.

    Returns
    -------
    ortho : ndarray of float32, shape of ``dem`` (or (bands,) + shape)
        NaN where the camera does not see the cell (outside the image, behind the camera,
        hidden, or DEM nodata).
    seen : ndarray of bool
        Cells with a valid orthophoto value.
    """
    img = real_array(image, "image", "grey values")     # masked pixels NaN (invalid); no complex
    if img.ndim not in (2, 3):
        raise ValueError(f"image must be 2-D or (bands, rows, cols); got shape {img.shape}.")
    dem = np.asarray(dem, dtype=np.float64)
    if dem.ndim != 2:
        raise ValueError(f"dem must be 2-D; got shape {dem.shape}.")
    bands = img[None] if img.ndim == 2 else img
    h, w = bands.shape[1:]
    io = camera.interior
    if (w, h) != (io.width, io.height):
        raise ValueError(f"image {camera.name!r} is {w} x {h} pixels but its interior orientation "
                         f"says {io.width} x {io.height}; use the matching camera or image.")
    X, Y = grid_xy(dem.shape, transform)
    col, row = camera.project(X, Y, dem)
    seen = (np.isfinite(col) & np.isfinite(row) & (col >= -0.5) & (col <= w - 0.5)
            & (row >= -0.5) & (row <= h - 0.5) & np.isfinite(dem))
    if occlusion and seen.any():
        seen &= visibility(camera, dem, transform, col, row)
    out = np.full((bands.shape[0],) + dem.shape, np.nan, np.float32)
    if seen.any():
        cc = np.clip(col[seen], 0, w - 1)
        rr = np.clip(row[seen], 0, h - 1)
        for b in range(bands.shape[0]):
            band = bands[b].astype(np.float32, copy=False)
            bad = ~np.isfinite(band)
            if bad.any():
                band = np.where(bad, 0, band)
            out[b][seen] = ndimage.map_coordinates(band, [rr, cc], order=order, mode="nearest",
                                                   prefilter=order > 1)
            if bad.any():
                vals = out[b][seen]
                near = _near_bad(bad, rr, cc)
                hit = ndimage.map_coordinates(bad.astype(np.float32), [rr[near], cc[near]], order=1,
                                              mode="nearest") > 0.01
                vals[np.flatnonzero(near)[hit]] = np.nan
                out[b][seen] = vals
        seen = seen & np.all(np.isfinite(out), axis=0)
    return (out[0] if img.ndim == 2 else out), seen


def _near_bad(bad, rr, cc):
    """Samples at ``(rr, cc)`` whose bilinear cells (the 2 x 2 block from the floor) hold a bad pixel.

    Elsewhere the interpolated bad mask is exactly 0: only these samples need it.
    """
    h, w = bad.shape
    block = bad.copy()
    block[:-1] |= bad[1:]
    block[:, :-1] |= block[:, 1:].copy()
    r0 = np.clip(np.floor(rr), 0, h - 1).astype(np.intp)
    c0 = np.clip(np.floor(cc), 0, w - 1).astype(np.intp)
    return block[r0, c0]
