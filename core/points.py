"""Point clouds: read text/LAS points, rasterize them, classify them against a DTM.

The point side of Bare Earth: the ISPRS filter test samples and LiDAR LAS/LAZ files are
point clouds, the filters work on rasters. This module

* reads and writes point files (:mod:`.pointfiles`: :func:`read_points`,
  :func:`write_points`, :class:`PointCloud`, re-exported here),
* turns points into a grid (lowest / highest / mean point per cell,
  :func:`rasterize_points`),
* samples a grid bilinearly at the points (:func:`sample_bilinear`) and labels every point
  ground / above / below the DTM with a slope-dependent tolerance
  (:func:`classify_points`, the usual point-labelling step of raster filters, e.g.
  Pingel et al. 2013, SMRF, ISPRS J. Photogramm. Remote Sens. 77:21-30),

Everything is vectorised (numpy/scipy).
"""
import numpy as np
from scipy import ndimage

from .codes import GROUND, LOW, NODATA, OBJECT
from .common import as_cell_pair, is_rotated, real_array
from .pointfiles import ASPRS_FROM_CLASS, LAS_INSTALL_HINT, PointCloud, import_laspy, read_points, write_points

__all__ = ["PointCloud", "read_points", "rasterize_points", "sample_bilinear", "sample_bilinear_many",
           "classify_points", "write_points", "nice_cell_size", "grid_extent", "dtm_slope", "import_laspy",
           "LAS_INSTALL_HINT", "ASPRS_FROM_CLASS"]


# --------------------------------------------------------------------------- rasterizing
def nice_cell_size(size, *, at_least=False):
    """Round a cell size to 1, 2, 2.5 or 5 times a power of ten: the nearest in ratio, or with
    ``at_least`` the smallest of them not under ``size``."""
    size = float(size)
    if not np.isfinite(size) or size <= 0:
        raise ValueError(f"cannot round the cell size {size!r}; it must be positive.")
    p = 10.0 ** np.floor(np.log10(size))
    steps = np.array([1.0, 2.0, 2.5, 5.0, 10.0]) * p
    if at_least:
        return float(steps[np.argmax(steps >= size * (1 - 1e-9))])
    return float(steps[np.argmin(np.abs(np.log(steps / size)))])


def rasterize_points(x, y, z, cell_size=None, *, reducer="min", extent=None,
                     fill_empty="nearest", info=None):
    """Grid points: the lowest, highest or mean z of the points in each cell.

    Parameters
    ----------
    x, y, z : array_like
        Point coordinates (same length). Points with a non-finite coordinate are ignored.
    cell_size : float or (float, float), optional
        Cell size ``(dx, dy)`` in the points' units. Default: about one point per cell,
        ``sqrt(area / n)`` over the bounding box, rounded by :func:`nice_cell_size`
        (1 m at the ISPRS urban density of 1 point/m2). The size used is
        ``geotransform[1]`` (and ``info["cell_size"]``).
    reducer : {"min", "max", "mean"}
        What a cell with several points gets.
    extent : (xmin, ymin, xmax, ymax), optional
        The grid's bounds, used exactly; points outside are dropped. Default: the points'
        bounding box, with the origin snapped to the cell size (``floor(xmin / dx) * dx``,
        ``ceil(ymax / dy) * dy``) so that grids of neighbouring tiles line up. Points on
        the east / south edge fall in the last column / row.
    fill_empty : {"nearest", None}
        ``"nearest"``: empty cells take the value of the nearest non-empty cell
        (``scipy.ndimage.distance_transform_edt``); None: they stay NaN.
    info : dict, optional
        Filled with ``cell_size``, ``shape``, ``n_points`` (used), ``n_empty`` (cells with
        no point, before filling) and ``points_per_cell``.

    Returns
    -------
    grid : ndarray of float32, 2-D
        Rows go north to south.
    geotransform : tuple of 6 floats
        GDAL order ``(x0, dx, 0, y0, 0, -dy)``.

    Notes
    -----
    Vectorised: one ``argsort`` of the cell index and ``np.minimum.reduceat`` /
    ``np.maximum.reduceat`` / ``np.bincount`` (about 3 M points/s on one core).
    """
    if reducer not in ("min", "max", "mean"):
        raise ValueError(f"reducer must be 'min', 'max' or 'mean'; got {reducer!r}.")
    if fill_empty not in ("nearest", None):
        raise ValueError(f"fill_empty must be 'nearest' or None; got {fill_empty!r}.")
    x = np.asarray(x, dtype=np.float64).ravel()
    y = np.asarray(y, dtype=np.float64).ravel()
    z = np.asarray(z, dtype=np.float64).ravel()
    if not (x.size == y.size == z.size):
        raise ValueError(f"x, y and z must have the same length; got {x.size}, {y.size}, {z.size}.")
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
    if not ok.all():
        x, y, z = x[ok], y[ok], z[ok]
    if x.size == 0:
        raise ValueError("no point with finite x, y and z to rasterize; pass a non-empty cloud.")

    if extent is not None:
        ext = np.asarray(extent, dtype=np.float64).ravel()
        if ext.size != 4 or not np.all(np.isfinite(ext)) or ext[2] <= ext[0] or ext[3] <= ext[1]:
            raise ValueError(f"extent must be (xmin, ymin, xmax, ymax) with xmax > xmin and "
                             f"ymax > ymin; got {extent!r}.")
        xmin, ymin, xmax, ymax = (float(v) for v in ext)
    else:
        xmin, ymin, xmax, ymax = float(x.min()), float(y.min()), float(x.max()), float(y.max())

    if cell_size is None:
        area = max(xmax - xmin, 0.0) * max(ymax - ymin, 0.0)
        if area <= 0:  # points on a line or a single point
            area = max(xmax - xmin, ymax - ymin, 1.0) ** 2
        dx = dy = nice_cell_size(np.sqrt(area / x.size))
    else:
        dx, dy = as_cell_pair(cell_size)     # in the points' unit: as given

    if extent is None:
        x0 = np.floor(xmin / dx) * dx
        y0 = np.ceil(ymax / dy) * dy
    else:
        x0, y0 = xmin, ymax
    eps = 1e-9
    ncols = max(1, int(np.ceil((xmax - x0) / dx - eps)))
    nrows = max(1, int(np.ceil((y0 - ymin) / dy - eps)))
    if ncols * nrows > 2_000_000_000:
        raise ValueError(f"a {nrows} x {ncols} grid is too large; use a larger cell_size "
                         f"than {dx:g} x {dy:g} (are the coordinates in degrees?).")

    col = np.floor((x - x0) / dx)
    row = np.floor((y0 - y) / dy)
    if extent is not None:
        inside = (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)
        if not inside.all():
            col, row, z = col[inside], row[inside], z[inside]
        if z.size == 0:
            raise ValueError(f"no point falls inside the extent {tuple(extent)!r}; the points "
                             f"span x {float(x.min()):.3f}..{float(x.max()):.3f}, "
                             f"y {float(y.min()):.3f}..{float(y.max()):.3f}.")
    col = np.clip(col, 0, ncols - 1).astype(np.int64)
    row = np.clip(row, 0, nrows - 1).astype(np.int64)
    cell = row * ncols + col

    grid = np.full(nrows * ncols, np.nan, dtype=np.float64)
    if reducer == "mean":
        count = np.bincount(cell, minlength=grid.size)
        total = np.bincount(cell, weights=z, minlength=grid.size)
        has = count > 0
        grid[has] = total[has] / count[has]
    else:
        order = np.argsort(cell, kind="stable")
        cs = cell[order]
        zs = z[order]
        starts = np.flatnonzero(np.r_[True, cs[1:] != cs[:-1]])
        ufunc = np.minimum if reducer == "min" else np.maximum
        grid[cs[starts]] = ufunc.reduceat(zs, starts)
    grid = grid.reshape(nrows, ncols).astype(np.float32)
    empty = np.isnan(grid)
    n_empty = int(empty.sum())
    if fill_empty == "nearest" and n_empty:
        idx = ndimage.distance_transform_edt(empty, return_distances=False, return_indices=True)
        grid = grid[tuple(idx)]
    gt = (float(x0), float(dx), 0.0, float(y0), 0.0, -float(dy))
    if info is not None:
        info.update(cell_size=(float(dx), float(dy)), shape=(nrows, ncols),
                    n_points=int(z.size), n_empty=n_empty,
                    points_per_cell=float(z.size) / (nrows * ncols))
    return grid, gt


# --------------------------------------------------------------------------- sampling
def _check_geotransform(geotransform, shape):
    gt = tuple(float(v) for v in geotransform)
    if len(gt) != 6:
        raise ValueError(f"geotransform must have 6 numbers (GDAL order); got {geotransform!r}.")
    if is_rotated(gt, shape):
        raise ValueError("rotated grids (geotransform[2] or [4] not 0) are not supported; "
                         "warp the raster to a north-up grid first (gdalwarp).")
    if gt[1] == 0 or gt[5] == 0:
        raise ValueError(f"geotransform has a zero cell size: {gt!r}.")
    return gt


def grid_extent(gt, shape):
    """``(xmin, ymin, xmax, ymax)`` of a north-up grid of ``shape`` on geotransform ``gt``."""
    xs = (gt[0], gt[0] + gt[1] * shape[1])
    ys = (gt[3], gt[3] + gt[5] * shape[0])
    return min(xs), min(ys), max(xs), max(ys)


def sample_bilinear(grid, geotransform, x, y):
    """Bilinear interpolation of a grid at points.

    Cell values sit at cell centres. Inside the grid but within half a cell of its edge,
    the nearest edge values are used (no extrapolation).

    Parameters
    ----------
    grid : array_like, 2-D
        Values (NaN = nodata; the masked cells of a numpy masked array too).
    geotransform : sequence of 6 floats
        GDAL geotransform of the grid (north-up: ``[2] == [4] == 0``).
    x, y : array_like
        Point coordinates in the grid's CRS.

    Returns
    -------
    ndarray of float64
        The interpolated values; NaN for points outside the grid, or where one of the
        cells with a non-zero weight is NaN.
    """
    grid = real_array(grid, "grid", "values")      # a masked array's masked cells are NaN; no complex
    if grid.ndim != 2 or grid.size == 0:
        raise ValueError(f"grid must be a non-empty 2-D array; got shape {grid.shape}.")
    gt = _check_geotransform(geotransform, grid.shape)
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    shape = np.broadcast(x, y).shape
    x, y = np.broadcast_to(x, shape).ravel(), np.broadcast_to(y, shape).ravel()
    return sample_bilinear_many([grid], gt, x, y)[0].reshape(shape)


def sample_bilinear_many(grids, gt, x, y):
    """Bilinear samples of several grids of one shape at 1-D points (weights computed once).

    As :func:`sample_bilinear` for each grid of ``grids``, with ``gt`` already checked
    (:func:`sample_bilinear` checks it) and ``x``, ``y`` 1-D float64. Returns a list of
    float64 arrays, NaN outside the grid.
    """
    nrows, ncols = grids[0].shape
    u = (x - gt[0]) / gt[1]          # column coordinate, 0 at the west edge
    v = (y - gt[3]) / gt[5]          # row coordinate, 0 at the north edge
    inside = (u >= 0) & (u <= ncols) & (v >= 0) & (v <= nrows)
    fc = np.clip(np.where(inside, u, 0.0) - 0.5, 0.0, ncols - 1.0)
    fr = np.clip(np.where(inside, v, 0.0) - 0.5, 0.0, nrows - 1.0)
    c0 = np.minimum(fc.astype(np.int64), max(ncols - 2, 0))     # fc >= 0: trunc = floor
    r0 = np.minimum(fr.astype(np.int64), max(nrows - 2, 0))
    tc = fc - c0
    tr = fr - r0
    dc = (c0 + 1 < ncols).astype(np.int64)                      # 0 on a one-column grid
    dr = (r0 + 1 < nrows).astype(np.int64) * ncols
    i00 = r0 * ncols + c0
    corners = ((i00, (1 - tr) * (1 - tc)), (i00 + dc, (1 - tr) * tc),
               (i00 + dr, tr * (1 - tc)), (i00 + dr + dc, tr * tc))
    outs = []
    for grid in grids:
        flat = np.asarray(grid).ravel()
        out = np.zeros(x.size)
        for idx, w in corners:
            # a cell with zero weight is not needed: its NaN must not spread
            out += np.where(w > 0, w * flat[idx], 0.0)
        out[~inside] = np.nan
        outs.append(out)
    return outs


def dtm_slope(dtm, gt):
    """Terrain slope (rise / run, dimensionless) of a grid, NaN where the DTM is NaN."""
    dtm = np.asarray(dtm, dtype=np.float64)
    if min(dtm.shape) < 2:
        return np.zeros_like(dtm)
    gy, gx = np.gradient(dtm, abs(gt[5]), abs(gt[1]))
    return np.hypot(gx, gy)


def classify_points(x, y, z, dtm, geotransform, *, threshold_m=0.5, slope_factor=1.25):
    """Label points ground / above / below a DTM with a slope-dependent tolerance.

    A point is ground when ``|z - DTM(x, y)| <= threshold_m + slope_factor * s(x, y)``,
    with ``s`` the local DTM slope (rise / run from ``np.gradient`` of the DTM), both
    sampled bilinearly (the point-labelling rule of SMRF, Pingel et al. 2013).

    Parameters
    ----------
    x, y, z : array_like
        Points, in the DTM's CRS and z units.
    dtm : array_like, 2-D
        The bare-earth surface (NaN = nodata).
    geotransform : sequence of 6 floats
        GDAL geotransform of ``dtm``.
    threshold_m : float
        Elevation tolerance on flat ground, in the z units of the points and DTM (metres
        normally; for a cloud in feet pass ``0.5 / cloud.z_units_to_metre``).
    slope_factor : float
        Extra tolerance per unit of slope (z units; 1.25 -> 1.25 m more on a 45 deg slope).

    Returns
    -------
    ndarray of uint8
        0 ground, 1 above the DTM (object), 2 below it (low outlier), 255 outside the DTM or
        where it is NaN.

    Raises
    ------
    ValueError
        When most points are outside the DTM (the message gives both extents): wrong CRS,
        units or DTM.
    """
    if not (np.isfinite(threshold_m) and threshold_m >= 0):
        raise ValueError(f"threshold_m must be >= 0; got {threshold_m!r}.")
    if not (np.isfinite(slope_factor) and slope_factor >= 0):
        raise ValueError(f"slope_factor must be >= 0; got {slope_factor!r}.")
    dtm = real_array(dtm, "dtm")                   # a masked array's masked cells are NaN (outside the DTM)
    if dtm.ndim != 2 or dtm.size == 0:
        raise ValueError(f"dtm must be a non-empty 2-D array; got shape {dtm.shape}.")
    gt = _check_geotransform(geotransform, dtm.shape)
    x = np.asarray(x, dtype=np.float64).ravel()
    y = np.asarray(y, dtype=np.float64).ravel()
    z = np.asarray(z, dtype=np.float64).ravel()
    if not (x.size == y.size == z.size):
        raise ValueError(f"x, y and z must have the same length; got {x.size}, {y.size}, {z.size}.")
    if x.size == 0:
        return np.zeros(0, dtype=np.uint8)
    gx0, gy0, gx1, gy1 = grid_extent(gt, dtm.shape)
    outside = ~((x >= gx0) & (x <= gx1) & (y >= gy0) & (y <= gy1))
    if outside.sum() * 2 > x.size:
        raise ValueError(
            f"{int(outside.sum())} of {x.size} points are outside the DTM: the points span "
            f"x {np.nanmin(x):.3f}..{np.nanmax(x):.3f}, y {np.nanmin(y):.3f}..{np.nanmax(y):.3f}; "
            f"the DTM spans x {gx0:.3f}..{gx1:.3f}, y {gy0:.3f}..{gy1:.3f}. Use a DTM of the "
            "same area, in the same CRS and units as the points.")
    ground, slope = sample_bilinear_many([dtm, dtm_slope(dtm, gt)], gt, x, y)
    slope = np.where(np.isfinite(slope), slope, 0.0)   # at a DTM hole's edge: flat
    tol = threshold_m + slope_factor * slope
    dz = z - ground
    out = np.full(x.size, NODATA, dtype=np.uint8)
    ok = np.isfinite(dz)
    out[ok] = GROUND
    out[ok & (dz > tol)] = OBJECT
    out[ok & (dz < -tol)] = LOW
    return out
