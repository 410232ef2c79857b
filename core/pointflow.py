"""Point clouds through a raster filter: rasterize -> filter -> classify the points.

The filters work on rasters; LiDAR and the ISPRS samples are point clouds. This module
chains the finished pieces of :mod:`.points` and :mod:`.pipeline` for one cloud and for a
block of adjoining tiles, in any unit:

* :func:`rasterize_cloud`: the lowest (or highest, mean) point per cell, the cell size in
  metres (default: about one point per cell, at most SMRF's 1 m while 1 m keeps a point
  per 16 cells, :func:`cell_size_for_spacing`), whatever the CRS's unit (metres, feet,
  degrees),
* :func:`classify_cloud`: every point ground / above / below a DTM in metres with the
  SMRF rule ``|z - DTM| <= threshold_m + slope_factor * slope`` (Pingel et al. 2013),
  evaluated in metres; against the lowest points of cells coarser than SMRF's 1 m the slope
  factor grows by where in its cell the lowest point lies (:func:`cell_slope_factor`),
* :func:`filter_cloud`: both around :func:`.pipeline.run_array`,
* :func:`filter_tiles`: several tile files filtered as one block. Each tile is filtered
  in a *unit*: the tile's extent plus an overlap (points of the neighbouring tiles) at
  least the method's reach, on one grid lattice and with one parameter set for the whole
  block; only the tile's own points are classified, so the classes agree along the
  seams with an untiled run,
* :func:`compare_classified`: a classified cloud against per-point truth (Type I / II,
  total error, kappa; Sithole & Vosselman 2004).

QGIS-free; GDAL only through :mod:`.grid` (raster outputs) and ``osr`` for CRSs.

Units. A cloud's coordinates are in its CRS's unit (``PointCloud.units_to_metre``, e.g.
0.3048 for feet) and its heights in ``z_units_to_metre``. Filters take metres: the grid
handed to the filter is ``z * z_units_to_metre`` with the cell size in metres, and the
classification maps x, y, z to local metres. Raster outputs are written in the cloud's
own units on its CRS, so they overlay the points.
"""
import math
import os
import time
from dataclasses import dataclass, field

import numpy as np

from .codes import GROUND, LOW, NODATA, OBJECT
from .common import check_progress, is_rotated, report, sub_progress
from .estimate import lowest_point_spread
from .grid import MIN_CELL_M, ground_scale, metres_per_degree, vertical_unit_factor
from .pipeline import as_method, check_relief, resolve_params, run_array
from .pointfiles import POINT_EXTENSIONS, place_points, point_output_path, prepare_points, read_column, read_crs
from .points import PointCloud, classify_points, nice_cell_size, rasterize_points, read_points, write_points

__all__ = ["CloudGrid", "CloudResult", "TileResult", "rasterize_cloud", "classify_cloud",
           "filter_cloud", "filter_tiles", "check_tiles_crs", "write_rasters", "write_cloud_outputs", "class_counts",
           "compare_classified", "match_points", "read_column", "point_output_path",
           "axis_scales", "crs_warnings", "cell_size_for_spacing", "default_cell_size_m", "DEFAULT_THRESHOLD_M",
           "DEFAULT_SLOPE_FACTOR", "SMRF_CELL_M", "cell_slope_factor", "REDUCERS", "POINT_EXTENSIONS",
           "check_grid_cells", "check_stray_points"]

#: SMRF's point rule (Pingel et al. 2013): elevation threshold and slope scale.
DEFAULT_THRESHOLD_M = 0.5
DEFAULT_SLOPE_FACTOR = 1.25
#: SMRF's cell: Pingel et al. (2013) filter every ISPRS sample on 1 m cells (PDAL's
#: filters.smrf and filters.pmf default to 1 m too). The default grid is no coarser while
#: the points allow it (:func:`cell_size_for_spacing`).
SMRF_CELL_M = 1.0
#: The finest default cell, in point spacings: a quarter (one point per 16 cells).
FINEST_CELL_SPACING = 0.25
#: Peak memory of :func:`rasterize_cloud` per grid cell (bytes; VmHWM of a fresh process on 16 and
#: 64 Mcells, 3 points): the float64 grid, its float32 copy and, filling the empty cells from the
#: nearest, the distance transform's indices.
RASTERIZE_BYTES_PER_CELL = {True: 17, False: 12}
#: The bulk of a cloud along an axis: its points between these quantiles (99 % of them);
#: points beyond it by more than half its span are stray (:func:`check_stray_points`).
STRAY_QUANTILES = (0.005, 0.995)
#: Cell reducers of :func:`rasterize_cloud`, in the order the plugin lists them.
REDUCERS = ("min", "max", "mean")
#: share of :func:`filter_tiles`' progress bar for deriving the block's parameters on its central tile
PARAMS_SHARE = 0.1
#: Class names of :func:`classify_points` codes, for logs.
CLASS_NAMES = {GROUND: "ground", OBJECT: "above", LOW: "below", NODATA: "outside the DTM"}


# --------------------------------------------------------------------------- units
def _srs(crs):
    if not crs:
        return None
    from osgeo import osr
    srs = osr.SpatialReference()
    try:
        if srs.SetFromUserInput(str(crs)) != 0:
            return None
    except RuntimeError:
        return None
    return srs


def axis_scales(cloud, at=None):
    """Metres per unit of x, y and z of a cloud: ``(sx, sy, sz)``, at the point ``at`` ``(x, y)``
    (default: the middle of the cloud's extent; a block of tiles passes its own middle).

    Projected or unknown CRS: ``units_to_metre`` for x and y, times the CRS's scale there when
    it does not keep distances (Web Mercator, as USGS 3DEP's point tiles: :func:`.grid.ground_scale`).
    Geographic CRS (degrees): :func:`.grid.metres_per_degree` at the latitude ``at[1]``.
    """
    sz = float(cloud.z_units_to_metre or 1.0)
    srs = _srs(cloud.crs)
    if at is None and len(cloud.x):
        at = (0.5 * (float(np.min(cloud.x)) + float(np.max(cloud.x))),
              0.5 * (float(np.min(cloud.y)) + float(np.max(cloud.y))))
    if srs is not None and srs.IsGeographic():
        lat = at[1]
        if not -90.0 <= lat <= 90.0:
            raise ValueError(f"the points' CRS is geographic but their mid y {lat:.3f} is not a "
                             "latitude: check the CRS.")
        return metres_per_degree(lat) + (sz,)
    h = float(cloud.units_to_metre or 1.0)
    scale = ground_scale(srs, at[0], at[1], f=h) if srs is not None and srs.IsProjected() and at else None
    if scale is not None:
        return h * scale[0], h * scale[1], sz
    return h, h, sz


def crs_warnings(cloud):
    """Warnings for the log on how a cloud's coordinates were measured, as a raster's reading
    gives them (:func:`.grid.cell_size_metres`): no CRS (metres assumed, outputs without a CRS),
    a geographic CRS (degrees converted at the cloud's latitude), a projected CRS that does not
    keep distances (its units converted to ground metres, :func:`axis_scales`)."""
    srs = _srs(cloud.crs)
    if srs is None:
        return ["The points have no CRS (none in the LAS header, no .prj beside a text file): their coordinates "
                "and heights are taken to be in metres, and the outputs have no CRS. Give the points' CRS "
                "(the algorithm's CRS parameter) if they are in another unit or to have the outputs georeferenced."]
    if not len(cloud.x):
        return []
    sx, sy, _ = axis_scales(cloud)
    mid_y = 0.5 * (float(np.min(cloud.y)) + float(np.max(cloud.y)))
    if srs.IsGeographic():
        return [f"The points' CRS is geographic (degrees): distances were converted to metres at latitude "
                f"{mid_y:.4f} ({sx:.6g} x {sy:.6g} m per degree). Reproject to a projected CRS for exact distances."]
    h = float(cloud.units_to_metre or 1.0)
    if srs.IsProjected() and (abs(sx / h - 1.0) > 1e-12 or abs(sy / h - 1.0) > 1e-12):
        return [f"The points' CRS does not keep distances here: one of its units is {sx:.4g} m on the ground at "
                "the points' middle (e.g. Web Mercator), so cell sizes and thresholds in metres were converted to "
                "its units. Reproject to a projected CRS made for measuring (UTM, a national grid) for exact "
                "distances."]
    return []


def height_warnings(cloud, classified=True):
    """The warning for the log when some of a cloud's points have no finite height (NaN or +-inf z: a
    failed export, a text file's ``nan``), or None. They are left out of the grid (rasterising) and classed
    255, outside the DTM (classifying: a LAS output keeps their input class), without a word before.
    ``classified``: the run writes classified points."""
    bad = int(np.count_nonzero(~np.isfinite(cloud.z)))
    if not bad:
        return None
    return (f"{bad} of the {len(cloud)} points have no finite height (z NaN or infinite): they are left out of "
            "the grid" + (" and classed 255, outside the DTM (a LAS output keeps their input class)"
                          if classified else "") + ". Check the z column of those points.")


def unit_name(cloud):
    """Name of the x/y unit of a cloud's CRS, for logs (``"metre"``, ``"foot"``, ``"degree"``)."""
    srs = _srs(cloud.crs)
    if srs is None:
        return "unit (no CRS: taken as metres)"
    if srs.IsGeographic():
        return "degree"
    return srs.GetLinearUnitsName() or "metre"


# --------------------------------------------------------------------------- rasterize
@dataclass
class CloudGrid:
    """A rasterized cloud.

    Attributes
    ----------
    z : ndarray of float32
        Heights in the cloud's z unit, NaN for empty cells (unless filled).
    geotransform : tuple
        GDAL geotransform in the cloud's CRS units.
    cell_size_m : (dx, dy)
        Cell size in metres (what the filter receives).
    z_to_m : float
        Metres per z unit.
    crs_wkt : str
    info : dict
        ``cell_size`` (CRS units), ``shape``, ``n_points``, ``n_empty``, ``points_per_cell``,
        ``seconds``.
    raster_z_to_m : float
        Metres per height unit of a raster written on this grid: the CRS's linear unit
        (what :func:`.grid.open_dsm` assumes when reading it back), 1 for a geographic
        CRS or none.
    """
    z: np.ndarray
    geotransform: tuple
    cell_size_m: tuple
    z_to_m: float = 1.0
    crs_wkt: str = ""
    info: dict = field(default_factory=dict)
    raster_z_to_m: float = 1.0

    @property
    def shape(self):
        return self.z.shape

    def z_metres(self):
        """Heights in metres (float32, a copy only when a unit conversion is needed)."""
        return self.z if self.z_to_m == 1.0 else self.z * np.float32(self.z_to_m)


def cell_size_for_spacing(spacing_m):
    """The default cell (metres) of points ``spacing_m`` apart (``sqrt(area / n)``).

    About one point per cell (the spacing rounded to 1, 2, 2.5 or 5 times a power of ten,
    :func:`.points.nice_cell_size`) where that is at most :data:`SMRF_CELL_M`; sparser points
    are gridded on SMRF's 1 m cells, or where 1 m would leave fewer than one point per 16 cells
    (the lowest-point surface then nearest-neighbour fill between points), on the finest cell
    that keeps one (a quarter of the spacing, rounded up). A coarser cell places each cell's
    lowest point at its centre: on a slope the ground points of the cell stand above it by up
    to the slope times the cell, and the filters decide on a coarser surface (ISPRS samples
    5-7, 0.16-0.18 points/m2, dtm through the point path: 2.5 m cells 4.60 %, 1 m 3.33 %)."""
    spacing_m = float(spacing_m)
    cell = nice_cell_size(spacing_m)
    if cell <= SMRF_CELL_M:
        return cell
    return min(cell, max(SMRF_CELL_M, nice_cell_size(FINEST_CELL_SPACING * spacing_m, at_least=True)))


def default_cell_size_m(cloud, scales=None):
    """The default cell in metres of a cloud (:func:`cell_size_for_spacing` of ``sqrt(area / n)``
    over its bounding box)."""
    sx, sy, _ = scales or axis_scales(cloud)
    x0, y0, x1, y1 = cloud.extent
    w, h = (x1 - x0) * sx, (y1 - y0) * sy
    area = w * h if w > 0 and h > 0 else max(w, h, 1.0) ** 2
    return cell_size_for_spacing(math.sqrt(area / max(1, len(cloud))))


def check_stray_points(cloud, what="INPUT"):
    """ValueError, before any work, when a few points lie far from the others.

    The grid of a cloud covers its bounding box, and its default cell follows the box's area
    (:func:`default_cell_size_m`). Along each axis the *bulk* is the span of 99 % of the points
    (:data:`STRAY_QUANTILES`); when the whole extent is more than twice the bulk's along x or y,
    points beyond the bulk by more than half its span (fewer than 1 in 200: a bad GPS record at
    (0, 0), LAS noise) would make most of the grid empty cells that copy their nearest point's
    height, and coarsen the default cell by the empty space (one point 2 km from a 200 m tile:
    2.5 m cells instead of 1 m). The message counts them and gives the farthest one. An axis
    along which 99 % of the points share one coordinate is left to the checks of a line.
    Coordinates are compared in the CRS's units (the ratios do not depend on them).
    """
    x, y = np.asarray(cloud.x, float), np.asarray(cloud.y, float)
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(np.asarray(cloud.z, float))
    x, y = x[ok], y[ok]
    if x.size < 3:
        return
    far = np.zeros(x.size, bool)
    spans = []
    for v in (x, y):
        lo, hi = (float(q) for q in np.quantile(v, STRAY_QUANTILES))
        bulk, whole = hi - lo, float(v.max() - v.min())
        spans.append((bulk, whole))
        if bulk > 0 and whole > 2 * bulk:
            far |= (v < lo - 0.5 * bulk) | (v > hi + 0.5 * bulk)
    if not far.any():
        return
    (bw, w), (bh, h) = spans
    cx, cy = 0.5 * (np.quantile(x, STRAY_QUANTILES).sum()), 0.5 * (np.quantile(y, STRAY_QUANTILES).sum())
    k = int(np.flatnonzero(far)[np.argmax(np.hypot(x[far] - cx, y[far] - cy))])
    unit = "units" if _srs(cloud.crs) is None else unit_name(cloud)
    unit = {"metre": "m", "meter": "m", "foot": "ft", "degree": "deg"}.get(unit.lower(), unit)
    raise ValueError(f"{what}: {int(far.sum())} of the {x.size} points lie far from the others: 99 % of them span "
                     f"{bw:.4g} x {bh:.4g} {unit}, but the whole extent is {w:.4g} x {h:.4g} {unit} (the farthest "
                     f"stray point is at x {x[k]:.10g}, y {y[k]:.10g}). The grid covers the whole extent, so most "
                     "of it would be empty cells copying their nearest point's height, and the default cell size "
                     "would follow the empty space. Remove those stray points (e.g. the LAS noise classes 7 and 18, "
                     "or a bad record at 0, 0) or clip the file to the survey's area.")


def check_points_relief(cloud, cell_m, scales=None):
    """:func:`.pipeline.check_relief` of the grid a cloud is rasterized on (cells of ``cell_m`` metres over
    its extent), from the points' heights, for the checks before a run (the run checks the grid itself):
    ValueError when the heights span more than ``MAX_RELIEF_RATIO`` times the extent's diagonal (coordinates
    in mm read as m, a CRS in another unit than the points'); the warning or None. ``scales``: the
    cloud's :func:`axis_scales` when known."""
    sx, sy, sz = axis_scales(cloud) if scales is None else scales
    if len(cloud.z) < 2:
        return None
    x0, y0, x1, y1 = cloud.extent
    shape = (max(1, int(round((y1 - y0) * sy / cell_m))), max(1, int(round((x1 - x0) * sx / cell_m))))
    return check_relief((np.asarray(cloud.z, np.float64) * sz).reshape(1, -1), cell_m, shape=shape)


def check_grid_cells(n_points, width_m, height_m, cell_m, *, what="CELL_SIZE_M", fill_empty=True,
                     whole=True, available=None):
    """ValueError, before any work, when a grid of ``cell_m`` over the points' ``width_m x height_m``
    is one no run should make: larger than a raster held in one window
    (:data:`~bare_earth.core.pipeline.IN_MEMORY_CELLS`) with fewer than one point per 16 cells (finer
    than the finest default cell, :data:`FINEST_CELL_SPACING`: nearly every cell a copy of its
    nearest point's; 3 points over 1 km at 0.05 m: 400 M cells), or needing more memory to
    rasterize at once (``whole``; :data:`RASTERIZE_BYTES_PER_CELL`) than ``available`` bytes (default:
    the memory available now). The message gives the cell count, the memory and the cells to use."""
    from .memory import available_memory
    from .pipeline import IN_MEMORY_CELLS
    cols, rows = math.ceil(width_m / cell_m), math.ceil(height_m / cell_m)
    cells = cols * rows
    need = cells * RASTERIZE_BYTES_PER_CELL[bool(fill_empty)]
    avail = (available_memory() if available is None else available) if whole else None
    area = max(width_m, cell_m) * max(height_m, cell_m)
    sparse = cells > IN_MEMORY_CELLS and cells > 16 * max(n_points, 1)
    if not sparse and (not avail or need <= avail):
        return
    finest = nice_cell_size(math.sqrt(area / (16 * max(n_points, 1))), at_least=True)
    fits = nice_cell_size(math.sqrt(area * RASTERIZE_BYTES_PER_CELL[bool(fill_empty)] / avail), at_least=True) \
        if avail else finest
    memory = f"rasterizing them takes about {need / 2**30:.3g} GB" + (
        f" ({avail / 2**30:.3g} GB available)" if avail else "")
    if sparse:
        why = (f" for {n_points} point(s), one per {cells / max(n_points, 1):.3g} cells: nearly every cell would be "
               "a copy of its nearest point's" + (f", and {memory}" if whole else ""))
        use = max(finest, fits) if avail and need > avail else finest
        fix = f"use cells of at least {use:g} m (a point per 16 cells or more)"
    else:
        why = f": {memory}"
        fix = f"use cells of at least {fits:g} m, or split the points into tiles"
    raise ValueError(f"{what} = {cell_m:g} m gives {cols} x {rows} = {cells:.3g} cells over the points' "
                     f"{width_m:.4g} x {height_m:.4g} m{why}. Instead {fix}, or leave {what} empty (cells from "
                     "the points' spacing).")


def _check_cell_m(c, crs):
    """Refuse a grid of cells under :data:`.grid.MIN_CELL_M` (what ``open_dsm`` refuses): the
    filters' windows (metres) would span millions of cells."""
    if c < MIN_CELL_M:
        why = ("the points have no CRS, so their coordinates were read as metres: they are probably in degrees. "
               "Give their CRS (the CRS or POINTS_CRS parameter, e.g. EPSG:4326)" if not crs else
               "give a larger cell size (CELL_SIZE_M)")
        raise ValueError(f"the points would give cells of {c:.3g} m, and no DSM has cells under 1 mm: {why}.")


def _cell_units(cloud, cell_size_m, scales):
    sx, sy, _ = scales
    if cell_size_m is None:
        cell_size_m = default_cell_size_m(cloud, scales)
    c = float(cell_size_m)
    if not (np.isfinite(c) and c > 0):
        raise ValueError(f"the cell size must be a positive number of metres; got {cell_size_m!r}.")
    _check_cell_m(c, cloud.crs)
    return c / sx, c / sy


def rasterize_cloud(cloud, cell_size_m=None, *, reducer="min", fill_empty=True, extent=None,
                    cell_size_units=None):
    """Grid a cloud: the lowest / highest / mean z per cell.

    Parameters
    ----------
    cloud : PointCloud
    cell_size_m : float, optional
        Cell size in metres (converted to the CRS's unit: feet, degrees at the cloud's
        latitude). Default :func:`default_cell_size_m`.
    reducer : {"min", "max", "mean"}
    fill_empty : bool
        Empty cells take the nearest cell's value (True) or stay NaN.
    extent : (xmin, ymin, xmax, ymax), optional
        The grid's exact bounds in CRS units (points outside dropped); default the points'
        bounding box with the origin snapped to the cell size.
    cell_size_units : (dx, dy), optional
        The cell size in CRS units, used as is (the tile workflow passes the block's).

    Returns
    -------
    CloudGrid
    """
    if len(cloud) == 0:
        raise ValueError("the point cloud is empty; give a file with points.")
    if reducer not in REDUCERS:
        raise ValueError(f"reducer must be one of {REDUCERS}; got {reducer!r}.")
    scales = axis_scales(cloud)
    cell = cell_size_units or _cell_units(cloud, cell_size_m, scales)
    info = {}
    t0 = time.perf_counter()
    z, gt = rasterize_points(cloud.x, cloud.y, cloud.z, cell, reducer=reducer, extent=extent,
                             fill_empty="nearest" if fill_empty else None, info=info)
    info["seconds"] = time.perf_counter() - t0
    cell_m = (abs(gt[1]) * scales[0], abs(gt[5]) * scales[1])
    if min(z.shape) < 3:
        raise ValueError(f"the points give a grid of only {z.shape[1]} x {z.shape[0]} cells of "
                         f"{cell_m[0]:.3g} m: the filters need at least 3 x 3; use a smaller cell "
                         "size or more points.")
    srs = _srs(cloud.crs)
    vertical = vertical_unit_factor(srs)   # the raster's heights in the unit open_dsm reads them in
    raster_z = vertical[0] if vertical else (scales[0] if srs is not None and srs.IsProjected() else 1.0)
    return CloudGrid(z=z, geotransform=tuple(gt), cell_size_m=cell_m, z_to_m=scales[2],
                     crs_wkt=cloud.crs or "", info=info, raster_z_to_m=raster_z)


# --------------------------------------------------------------------------- classify
def classify_cloud(cloud, dtm_m, geotransform, *, threshold_m=DEFAULT_THRESHOLD_M,
                   slope_factor=DEFAULT_SLOPE_FACTOR, select=None, lowest_cell_m=None):
    """Classify a cloud's points against a DTM in metres, in metres.

    ``dtm_m`` is on ``geotransform`` (the cloud's CRS units) with heights in metres; the
    points' x, y, z are mapped to metres (feet, degrees) so that the slope term and the
    threshold keep their meaning. ``select``: an index or boolean array of the points to
    classify (default all). ``lowest_cell_m``: the cell in metres when the DTM's ground
    heights are the cells' lowest points (the point path's grid): the slope factor then grows
    with the cell beyond SMRF's 1 m (:func:`cell_slope_factor`). Returns uint8 codes 0
    ground, 1 above, 2 below, 255 outside the DTM (or over a DTM hole). ValueError when most
    points are outside the DTM.
    """
    sx, sy, sz = axis_scales(cloud)
    if lowest_cell_m is not None:
        slope_factor = cell_slope_factor(slope_factor, lowest_cell_m)
    x, y, z = cloud.x, cloud.y, cloud.z
    if select is not None:
        x, y, z = x[select], y[select], z[select]
    gt = tuple(float(v) for v in geotransform)
    if sx == sy == 1.0 and sz == 1.0:
        return _classify(x, y, z, dtm_m, gt, threshold_m, slope_factor)
    if sx == sy == sz:
        # one unit for everything (feet): classify in that unit, thresholds converted
        return _classify(x, y, z, np.asarray(dtm_m) / np.float32(sz), gt, threshold_m / sz,
                         slope_factor / sz)
    ox, oy = gt[0], gt[3]            # local metres around the grid's corner
    gtm = (0.0, gt[1] * sx, 0.0, 0.0, 0.0, gt[5] * sy)
    return _classify((x - ox) * sx, (y - oy) * sy, z * sz, dtm_m, gtm, threshold_m, slope_factor)


def cell_slope_factor(slope_factor, cell_m):
    """The slope factor of the point rule against a DTM of lowest points per ``cell_m`` cell.

    SMRF's factor (Pingel et al. 2013) holds on its 1 m cells (:data:`SMRF_CELL_M`). A DTM
    made of each cell's lowest point holds a height taken anywhere inside the cell: on a
    slope ``s`` that position adds ``s c / sqrt(12)`` to its error (its standard deviation,
    :func:`.estimate.lowest_point_spread`), and the points of the cell stand above or below
    it by that much more. On cells coarser than SMRF's the factor grows by the difference,
    ``(c - 1 m) / sqrt(12)`` per unit slope; finer cells keep it. ``cell_m``: metres, a number
    or ``(dx, dy)`` (the larger is taken).

    >>> round(cell_slope_factor(1.25, 4.0), 4)   # 1.25 + 3 / sqrt(12)
    2.116
    >>> cell_slope_factor(1.25, (0.5, 0.5))
    1.25
    """
    c = max(float(v) for v in np.ravel(cell_m))
    grow = lowest_point_spread(0.0, 1.0, c) - lowest_point_spread(0.0, 1.0, SMRF_CELL_M)
    return float(slope_factor) + max(0.0, grow)


#: Points per chunk of :func:`_classify` (temporaries stay in the CPU caches: 3-4x faster
#: than whole-array passes on millions of points).
CLASSIFY_CHUNK = 1 << 17


def _classify(x, y, z, dtm, gt, threshold_m, slope_factor):
    """:func:`.points.classify_points`, exactly (same rule, same codes, same checks and
    messages), in chunks of points with the DTM slope computed once."""
    from .points import dtm_slope, grid_extent, sample_bilinear_many
    x = np.asarray(x, dtype=np.float64).ravel()
    y = np.asarray(y, dtype=np.float64).ravel()
    z = np.asarray(z, dtype=np.float64).ravel()
    dtm = np.asarray(dtm)
    n = x.size
    if n <= CLASSIFY_CHUNK or dtm.ndim != 2 or dtm.size == 0 or not (n == y.size == z.size):
        return classify_points(x, y, z, dtm, gt, threshold_m=threshold_m, slope_factor=slope_factor)
    gx0, gy0, gx1, gy1 = grid_extent(gt, dtm.shape)
    n_out = n - int(np.count_nonzero((x >= gx0) & (x <= gx1) & (y >= gy0) & (y <= gy1)))
    if n_out * 2 > n or not (np.isfinite(threshold_m) and threshold_m >= 0) or \
            not (np.isfinite(slope_factor) and slope_factor >= 0) or is_rotated(gt, dtm.shape) \
            or gt[1] == 0 or gt[5] == 0:
        return classify_points(x, y, z, dtm, gt, threshold_m=threshold_m, slope_factor=slope_factor)
    slope = dtm_slope(dtm, gt)
    out = np.empty(n, dtype=np.uint8)
    for i in range(0, n, CLASSIFY_CHUNK):
        sl = slice(i, i + CLASSIFY_CHUNK)
        ground, s = sample_bilinear_many([dtm, slope], gt, x[sl], y[sl])
        s = np.where(np.isfinite(s), s, 0.0)          # at a DTM hole's edge: flat
        tol = threshold_m + slope_factor * s
        dz = z[sl] - ground
        o = np.full(dz.size, NODATA, dtype=np.uint8)
        ok = np.isfinite(dz)
        o[ok] = GROUND
        o[ok & (dz > tol)] = OBJECT
        o[ok & (dz < -tol)] = LOW
        out[sl] = o
    return out


def class_counts(classes):
    """``{name: count}`` of classify codes (ground, above, below, outside the DTM)."""
    counts = np.bincount(np.asarray(classes, dtype=np.uint8).ravel(), minlength=256)
    return {name: int(counts[code]) for code, name in CLASS_NAMES.items()}


# --------------------------------------------------------------------------- one cloud
@dataclass
class CloudResult:
    """Result of :func:`filter_cloud`: per-point ``classes`` (uint8), the rasterized
    ``grid`` (:class:`CloudGrid`), the pipeline's ``result`` (mask, dtm and ndsm in metres)
    and ``info`` (parameters, counts, timings, points/s)."""
    classes: np.ndarray
    grid: CloudGrid
    result: object
    info: dict = field(default_factory=dict)


def filter_cloud(cloud, method="morphological", params=None, *, cell_size_m=None,
                 threshold_m=DEFAULT_THRESHOLD_M, slope_factor=DEFAULT_SLOPE_FACTOR,
                 block=None, workers=1, progress=None, extent=None, cell_size_units=None,
                 select=None):
    """Rasterize a cloud (lowest point per cell, empty cells from the nearest), filter the
    grid with ``method`` and classify the points against the DTM.

    Parameters
    ----------
    cloud : PointCloud
    method : str or Method
    params : dict, optional
        The method's parameters (missing ones derived from the data).
    cell_size_m : float, optional
        Metres; default :func:`default_cell_size_m` (about one point per cell, at most 1 m
        while that keeps a point per 16 cells).
    threshold_m, slope_factor : float
        The point rule (SMRF defaults 0.5 m and 1.25); on cells coarser than SMRF's 1 m the
        slope factor grows by ``(cell - 1 m) / sqrt(12)`` (:func:`cell_slope_factor`: the DTM
        holds each cell's lowest point, taken anywhere inside the cell).
    block, workers : passed to :func:`.pipeline.run_array`.
    progress : callable, optional
    extent, cell_size_units : optional
        The grid's bounds and cell in CRS units (used by :func:`filter_tiles`).
    select : array, optional
        The points to classify (default all); ``classes`` then has their length.

    Returns
    -------
    CloudResult
    """
    progress = check_progress(progress)
    report(progress, 0.0)
    g = rasterize_cloud(cloud, cell_size_m, reducer="min", fill_empty=True, extent=extent,
                        cell_size_units=cell_size_units)
    n_raster = g.info["n_points"]
    report(progress, 0.05)
    res = run_array(method, g.z_metres(), g.cell_size_m, params, block=block, workers=workers,
                    progress=sub_progress(progress, 0.05, 0.95))
    t0 = time.perf_counter()
    classes = classify_cloud(cloud, res.dtm, g.geotransform, threshold_m=threshold_m,
                             slope_factor=slope_factor, select=select, lowest_cell_m=g.cell_size_m)
    t_cls = time.perf_counter() - t0
    info = {"method": res.info.get("method"), "params": res.info.get("params"),
            "cell_size_m": g.cell_size_m, "grid_shape": g.shape, "points": len(cloud),
            "empty_cells": g.info.get("n_empty"),
            "rasterize_seconds": g.info["seconds"], "filter_seconds": res.info.get("seconds"),
            "classify_seconds": t_cls,
            "rasterize_points_per_s": n_raster / max(g.info["seconds"], 1e-9),
            "classify_points_per_s": classes.size / max(t_cls, 1e-9),
            "classes": class_counts(classes), "filter_info": res.info}
    report(progress, 1.0)
    return CloudResult(classes=classes, grid=g, result=res, info=info)


def write_rasters(grid_, result, outputs, extras=None):
    """Write the pipeline's rasters on a cloud's grid, in the cloud's units.

    ``outputs``: ``{"dtm" | "mask" | "ndsm" | "dsm" | <extra>: path}`` (None skipped). Float
    rasters are Float32 with NaN nodata, heights in the CRS's linear unit (the cloud's z
    unit in practice; ``CloudGrid.raster_z_to_m``); the mask is UInt8 with its
    colour table and ``.qml`` style. ``extras``: the method's ``{name: (dtype, bands,
    nodata)}``. Written atomically by :class:`.grid.OutputSet`.
    """
    from . import grid
    outputs = {k: v for k, v in (outputs or {}).items() if v}
    if not outputs:
        return {}
    info = grid.DSMInfo(path="", band_index=1, shape=grid_.shape, geotransform=grid_.geotransform,
                        crs_wkt=grid_.crs_wkt or "", nodata=None, cell_size_m=grid_.cell_size_m,
                        z_to_m=grid_.raster_z_to_m)
    scale = np.float32(1.0 / grid_.raster_z_to_m)           # metres -> raster unit
    zscale = np.float32(grid_.z_to_m / grid_.raster_z_to_m)  # cloud z unit -> raster unit
    nan = float("nan")
    with grid.OutputSet(info) as out:
        for key, path in outputs.items():
            if key == "mask":
                out.add(key, path, "Byte", nodata=NODATA, mask_style=True,
                        descriptions=["mask: 0 ground, 1 object, 2 low outlier, 255 nodata"])
                out.write(key, result.mask)
            elif key in ("dtm", "ndsm"):
                out.add(key, path, "Float32", nodata=nan, descriptions=[key.upper()])
                a = getattr(result, key)
                out.write(key, (a * scale).astype(np.float32) if scale != 1 else a)
            elif key == "dsm":
                out.add(key, path, "Float32", nodata=nan, descriptions=["DSM of the points"])
                out.write(key, grid_.z * zscale if zscale != 1 else grid_.z)
            elif extras and key in extras and key in result.extras:
                dt, bands, nod = extras[key]
                gdt = {np.uint8: "Byte", np.float32: "Float32", np.int16: "Int16",
                       np.uint16: "UInt16", np.int32: "Int32"}[np.dtype(dt).type]
                out.add(key, path, gdt, bands=bands, nodata=nod)
                out.write(key, result.extras[key])
            elif key not in (extras or {}):
                raise ValueError(f"unknown raster output {key!r}.")
        out.commit()
    return outputs


def write_cloud_outputs(points_path, cloud, classes, grid_, result, rasters, extras=None):
    """A point run's outputs, all or nothing: the points file and the rasters of
    :func:`write_rasters`.

    The points are written first to a hidden work file (:func:`.pointfiles.prepare_points`), the
    rasters are written and put in place (:class:`.grid.OutputSet`), and only then is the points
    file moved into place (one rename). A run killed (``kill -9``) or failing while the rasters
    are written leaves no new points file (before, the points file was in place first and looked
    valid without its rasters); the points file of an earlier run stays as it was. Only the
    rename of the rasters and of the points file separate them.
    """
    from . import grid
    work = prepare_points(points_path, cloud, classes)
    try:
        grid.check_replaceable(points_path)     # the points' rename must not fail after the rasters
        placed = write_rasters(grid_, result, rasters, extras=extras)
        try:
            place_points(work, points_path)
        except BaseException:                   # rasters without their points: removed (all or nothing)
            for key, path in placed.items():
                for f in grid.output_files(path, styled=key == "mask"):
                    if os.path.isfile(f):
                        os.remove(f)
            raise
    finally:
        if os.path.exists(work):
            os.remove(work)
    return points_path


# --------------------------------------------------------------------------- tiles
@dataclass
class TileResult:
    """Result of :func:`filter_tiles`: ``classes`` (one uint8 array per tile), ``params``
    (the complete filter parameters used for every unit), ``cell_size_units``,
    ``overlap_m``, ``units`` (each unit's extent), ``info`` (counts, timings) and, with
    ``keep_results``, ``results`` (each unit's :class:`CloudResult`)."""
    classes: list
    params: dict
    cell_size_units: tuple
    overlap_m: float
    units: list
    info: dict = field(default_factory=dict)
    results: list = None


def _same_crs(a, b):
    if not a or not b:
        return True
    sa, sb = _srs(a), _srs(b)
    if sa is None or sb is None:
        return True
    return bool(sa.IsSame(sb))


def _snap_extent(ext, dx, dy):
    """Grow ``(xmin, ymin, xmax, ymax)`` to the lattice of multiples of the cell size (the
    lattice :func:`.points.rasterize_points` snaps an untiled grid to)."""
    x0 = math.floor(ext[0] / dx) * dx
    y1 = math.ceil(ext[3] / dy) * dy
    ncols = max(3, int(math.ceil((ext[2] - x0) / dx - 1e-9)))
    nrows = max(3, int(math.ceil((y1 - ext[1]) / dy - 1e-9)))
    return (x0, y1 - nrows * dy, x0 + ncols * dx, y1)


def _inside(cloud, ext):
    return (cloud.x >= ext[0]) & (cloud.x <= ext[2]) & (cloud.y >= ext[1]) & (cloud.y <= ext[3])


def _merge(clouds):
    c0 = clouds[0]
    return PointCloud(x=np.concatenate([c.x for c in clouds]),
                      y=np.concatenate([c.y for c in clouds]),
                      z=np.concatenate([c.z for c in clouds]), classification=None,
                      crs=c0.crs, units_to_metre=c0.units_to_metre,
                      z_units_to_metre=c0.z_units_to_metre, source_format=c0.source_format)


def filter_tiles(tiles, outputs=None, *, method="morphological", params=None, cell_size_m=None,
                 overlap_m=None, crs=None, threshold_m=DEFAULT_THRESHOLD_M,
                 slope_factor=DEFAULT_SLOPE_FACTOR, only=None, keep_results=False, progress=None,
                 log=None):
    """Filter adjoining tiles of a point cloud as one block, tile by tile.

    Every tile is filtered in a *unit*: its extent grown by ``overlap_m`` and filled with
    the points of every tile inside it; only the tile's own points are classified. All
    units share one grid lattice (multiples of the cell size, the lattice of an untiled
    grid), one cell size (the whole block's density) and one parameter set (derived once,
    from the tile nearest the block's centre, unless given completely), and the overlap
    covers the method's reach (its halo plus the slope and interpolation stencils), so a
    tile's classes equal those of an untiled run of the whole block with the same
    parameters, seams included.

    Parameters
    ----------
    tiles : list of str / path-like / PointCloud
        The tiles (same CRS and units).
    outputs : list of paths, optional
        One classified-points file per tile (``None`` entries skipped), written with
        :func:`.points.write_points` (LAS keeps every attribute).
    method, params, cell_size_m, threshold_m, slope_factor : as :func:`filter_cloud`.
    overlap_m : float, optional
        Metres added around each tile; default the method's reach plus 4 cells. A smaller
        value than the reach is refused.
    crs : str, optional
        Overrides the files' CRS.
    only : list of int, optional
        Filter and classify only these tiles (the others serve as neighbours); their
        classes are then None. The parameters still come from the block's central tile,
        so separate runs over the same files agree.
    keep_results : bool
        Keep each unit's :class:`CloudResult` (grid, mask, DTM) in ``TileResult.results``.
    progress : callable, optional
    log : callable, optional
        ``log(str)`` for a line per tile.

    Returns
    -------
    TileResult
    """
    progress = check_progress(progress)
    log = log or (lambda s: None)
    clouds, names = _load_tiles(tiles, outputs, crs)
    meth = as_method(method)
    lattice, scales = _block_lattice(clouds, cell_size_m)
    full, fixed = _block_params(meth, clouds, names, params, lattice, log,
                                sub_progress(progress, 0.0, PARAMS_SHARE))
    cell_m = (lattice.dx * scales[0], lattice.dy * scales[1])
    halo = int(meth.halo(full, cell_m))
    lattice.margin = halo + 4                     # cells near a unit edge that may differ
    need_m = lattice.margin * max(cell_m)
    if overlap_m is None:
        overlap_m = need_m
    elif overlap_m < need_m:
        raise ValueError(f"overlap_m = {overlap_m:g} m is less than the filter's reach ({need_m:.1f} m = "
                         f"{halo} + 4 cells of {max(cell_m):.3g} m): the tiles would not agree at their "
                         "seams. Give a larger overlap or leave it empty.")
    overlap = (int(math.ceil(overlap_m / scales[1] / lattice.dy - 1e-9)),
               int(math.ceil(overlap_m / scales[0] / lattice.dx - 1e-9)))
    report(progress, PARAMS_SHARE)
    run = _TileRun(meth, fixed, threshold_m, slope_factor)
    todo = list(range(len(clouds))) if only is None else sorted(set(int(k) for k in only))
    out_classes, units, per_tile = [None] * len(clouds), [None] * len(clouds), []
    results = [None] * len(clouds) if keep_results else None
    t_all = time.perf_counter()
    for step, i in enumerate(todo):
        span = 0.98 - PARAMS_SHARE
        prog = sub_progress(progress, PARAMS_SHARE + span * step / len(todo),
                            PARAMS_SHARE + span * (step + 1) / len(todo))
        r, n_unit, win, grown = _filter_tile(run, clouds, i, lattice, overlap, prog)
        out_classes[i] = r.classes
        units[i] = lattice.extent_of(win)
        if keep_results:
            results[i] = r
        per_tile.append(_tile_summary(names[i], len(clouds[i]), n_unit, r, grown, log))
        if outputs is not None and outputs[i]:
            write_points(outputs[i], clouds[i], r.classes)
    report(progress, 1.0)
    return TileResult(classes=out_classes, params=full, cell_size_units=(lattice.dx, lattice.dy),
                      overlap_m=float(overlap_m), units=units,
                      info={"tiles": per_tile, "halo_cells": halo, "cell_size_m": cell_m,
                            "seconds": time.perf_counter() - t_all}, results=results)


def check_tiles_crs(paths, cloud, crs=None):
    """ValueError, before any point is read, when a point file of ``paths`` is not in the CRS /
    units of ``cloud`` (the block's first tile), is not a point file, or is missing: the test
    :func:`filter_tiles` makes after reading them, on the LAS headers / ``.prj`` files only."""
    for p in paths:
        wkt, h, v = read_crs(p, crs)
        if not _same_crs(cloud.crs, wkt) or abs(h - cloud.units_to_metre) > 1e-12 or \
                abs((v if v is not None else h) - cloud.z_units_to_metre) > 1e-12:
            raise ValueError(f"{os.path.basename(os.fspath(p))} is not in the CRS / units of the input points: "
                             "tiles of one block must share them (reproject first, or pass the CRS).")


def _load_tiles(tiles, outputs, crs):
    """The tiles as clouds (read when paths) with their names; ValueError for no tile, an
    output list of another length, an empty tile, tiles of different CRSs / units or a tile with
    stray points (:func:`check_stray_points`)."""
    tiles = list(tiles)
    if not tiles:
        raise ValueError("no tile given; pass the point files of the block.")
    if outputs is not None and len(outputs) != len(tiles):
        raise ValueError(f"{len(outputs)} outputs for {len(tiles)} tiles: give one per tile.")
    clouds = [t if isinstance(t, PointCloud) else read_points(t, crs=crs) for t in tiles]
    names = [getattr(t, "name", None) or (os.path.basename(os.fspath(t)) if not isinstance(t, PointCloud)
                                          else f"tile {i + 1}") for i, t in enumerate(tiles)]
    for i, c in enumerate(clouds):
        if len(c) == 0:
            raise ValueError(f"{names[i]} has no points.")
        if not _same_crs(clouds[0].crs, c.crs) or \
                abs(c.units_to_metre - clouds[0].units_to_metre) > 1e-12 or \
                abs(c.z_units_to_metre - clouds[0].z_units_to_metre) > 1e-12:
            raise ValueError(f"{names[i]} is not in the CRS / units of {names[0]}: tiles of one block "
                             "must share them (reproject first, or pass the CRS).")
        check_stray_points(c, names[i])     # the block's cell and lattice follow every tile's extent
    return clouds, names


def _merged_extent(clouds):
    return (min(c.extent[0] for c in clouds), min(c.extent[1] for c in clouds),
            max(c.extent[2] for c in clouds), max(c.extent[3] for c in clouds))


@dataclass
class TileLattice:
    """The untiled grid of a block of tiles: its bounds ``(x0, y0, x1, y1)`` on the lattice of
    multiples of the cell ``(dx, dy)`` (CRS units), ``rows`` x ``cols`` cells, and ``margin``:
    the cells near a unit's edge that may differ from one pass (the halo plus 4). Windows
    are ``(r0, r1, c0, c1)`` cells from its north-west corner."""
    x0: float
    y0: float
    x1: float
    y1: float
    dx: float
    dy: float
    rows: int
    cols: int
    margin: int = 0

    @classmethod
    def around(cls, ext, dx, dy):
        x0, y0, x1, y1 = _snap_extent(ext, dx, dy)
        return cls(x0, y0, x1, y1, dx, dy, int(round((y1 - y0) / dy)), int(round((x1 - x0) / dx)))

    def cells_of(self, ext, grow_r=0, grow_c=0):
        """The window of whole cells covering extent ``ext``, grown by ``grow_r`` rows and
        ``grow_c`` columns, never past the lattice's bounds."""
        c0 = int(math.floor((ext[0] - self.x0) / self.dx + 1e-9)) - grow_c
        c1 = int(math.ceil((ext[2] - self.x0) / self.dx - 1e-9)) + grow_c
        r0 = int(math.floor((self.y1 - ext[3]) / self.dy + 1e-9)) - grow_r
        r1 = int(math.ceil((self.y1 - ext[1]) / self.dy - 1e-9)) + grow_r
        return max(r0, 0), min(max(r1, r0 + 1), self.rows), max(c0, 0), min(max(c1, c0 + 1), self.cols)

    def extent_of(self, win):
        """The extent ``(xmin, ymin, xmax, ymax)`` of window ``win``."""
        r0, r1, c0, c1 = win
        return (self.x0 + c0 * self.dx, self.y1 - r1 * self.dy, self.x0 + c1 * self.dx, self.y1 - r0 * self.dy)

    def trusted(self, win):
        """The part of ``win`` away from its edges that are not the block's (``margin`` cells)."""
        m = self.margin
        return (win[0] + (m if win[0] > 0 else 0), win[1] - (m if win[1] < self.rows else 0),
                win[2] + (m if win[2] > 0 else 0), win[3] - (m if win[3] < self.cols else 0))

    def grow(self, win, g):
        """``win`` grown past the holes that stick out by ``g`` cells (N, S, W, E), plus the margin."""
        m = self.margin
        return (max(0, win[0] - (g[0] + m if g[0] else 0)), min(self.rows, win[1] + (g[1] + m if g[1] else 0)),
                max(0, win[2] - (g[2] + m if g[2] else 0)), min(self.cols, win[3] + (g[3] + m if g[3] else 0)))


def _block_lattice(clouds, cell_size_m):
    """The block's lattice (cell: ``cell_size_m``, default :func:`cell_size_for_spacing` of the
    points' spacing over the tiles' own areas) and the metres per x, y, z unit at the block's mid latitude."""
    merged_ext = _merged_extent(clouds)
    scales = axis_scales(clouds[0], at=(0.5 * (merged_ext[0] + merged_ext[2]),
                                        0.5 * (merged_ext[1] + merged_ext[3])))
    if cell_size_m is None:
        area = 0.0
        for c in clouds:
            e = c.extent
            area += max(e[2] - e[0], 0.0) * scales[0] * max(e[3] - e[1], 0.0) * scales[1]
        cell_size_m = cell_size_for_spacing(math.sqrt(max(area, 1.0) / sum(len(c) for c in clouds)))
    _check_cell_m(float(cell_size_m), clouds[0].crs)
    dx, dy = float(cell_size_m) / scales[0], float(cell_size_m) / scales[1]
    return TileLattice.around(merged_ext, dx, dy), scales


def _block_params(meth, clouds, names, params, lattice, log, progress=None):
    """One parameter set for the block: derived on the tile nearest the block's centre,
    unless complete. Returns ``(full, fixed)``: every parameter, and the method's own.
    ``progress`` (optional, may raise :class:`~.common.Cancelled`) is fed while the central
    tile is gridded and the parameters derived (seconds to minutes on a dense tile)."""
    user = dict(params or {})
    names_p = [p.name for p in meth.params]
    if any(user.get(k) is None for k in names_p):
        ext = _merged_extent(clouds)
        cx, cy = 0.5 * (ext[0] + ext[2]), 0.5 * (ext[1] + ext[3])
        centre = int(np.argmin([math.hypot(0.5 * (c.extent[0] + c.extent[2]) - cx,
                                           0.5 * (c.extent[1] + c.extent[3]) - cy) for c in clouds]))
        report(progress, 0.0)
        g = rasterize_cloud(clouds[centre], cell_size_units=(lattice.dx, lattice.dy))
        report(progress, 0.1)
        full = resolve_params(meth, g.z_metres(), g.cell_size_m, user, progress=sub_progress(progress, 0.1, 1.0))
        log(f"Parameters derived from {names[centre]} (the tile nearest the block's centre).")
    else:
        full = user
    return full, {k: full[k] for k in names_p if k in full}


@dataclass
class _TileRun:
    """What every unit of a block is filtered and classified with."""
    meth: object
    params: dict
    threshold_m: float
    slope_factor: float


def _unit_cloud(clouds, i, unit):
    """Tile ``i``'s points first, then every other tile's points inside extent ``unit``."""
    c = clouds[i]
    parts = [c]
    for j, o in enumerate(clouds):
        if j == i:
            continue
        oe = o.extent
        if oe[0] > unit[2] or oe[2] < unit[0] or oe[1] > unit[3] or oe[3] < unit[1]:
            continue
        sel = _inside(o, unit)
        if sel.any():
            parts.append(PointCloud(o.x[sel], o.y[sel], o.z[sel], crs=o.crs, units_to_metre=o.units_to_metre,
                                    z_units_to_metre=o.z_units_to_metre))
    return _merge(parts) if len(parts) > 1 else c


def _holes_beyond_trust(mask, win, twin, lattice):
    """Cells to add on each side (N, S, W, E) of unit ``win`` so that every hole (mask 1/2)
    reaching the tile's cells ``twin`` lies inside the unit's trusted part (its gap filling
    then sees the whole hole, as one pass does)."""
    from scipy import ndimage
    holes = (mask == OBJECT) | (mask == LOW)
    if not holes.any():
        return (0, 0, 0, 0)
    t0, t1, u0, u1 = lattice.trusted(win)
    # the tile's cells plus the stencils of the bilinear sample and the slope
    a0, a1 = max(twin[0] - 3, win[0]) - win[0], min(twin[1] + 3, win[1]) - win[0]
    b0, b1 = max(twin[2] - 3, win[2]) - win[2], min(twin[3] + 3, win[3]) - win[2]
    lab, _ = ndimage.label(holes)
    ids = np.unique(lab[a0:a1, b0:b1])
    ids = ids[ids > 0]
    grow = [0, 0, 0, 0]
    boxes = ndimage.find_objects(lab)
    for k in ids:
        rs, cs = boxes[k - 1]
        grow[0] = max(grow[0], t0 - (rs.start + win[0]))
        grow[1] = max(grow[1], rs.stop + win[0] - t1)
        grow[2] = max(grow[2], u0 - (cs.start + win[2]))
        grow[3] = max(grow[3], cs.stop + win[2] - u1)
    return tuple(max(0, g) for g in grow)


def _filter_tile(run, clouds, i, lattice, overlap, progress):
    """Filter tile ``i`` in its unit (its cells grown by ``overlap`` (rows, cols)); a unit
    whose edge cuts a hole reaching the tile grows past it and runs again (at most 8 times).
    Returns ``(CloudResult, points in the unit, the unit's window, times grown)``."""
    c = clouds[i]
    twin = lattice.cells_of(c.extent)
    win = lattice.cells_of(c.extent, *overlap)
    grown = 0
    while True:
        merged = _unit_cloud(clouds, i, lattice.extent_of(win))
        r = filter_cloud(merged, run.meth, run.params, threshold_m=run.threshold_m,
                         slope_factor=run.slope_factor, extent=lattice.extent_of(win),
                         cell_size_units=(lattice.dx, lattice.dy), select=slice(0, len(c)), progress=progress)
        g = _holes_beyond_trust(r.result.mask, win, twin, lattice)
        if not any(g) or grown >= 8:
            return r, len(merged), win, grown
        grown += 1
        win = lattice.grow(win, g)


def _tile_summary(name, n_points, n_unit, r, grown, log):
    """One tile's line of the info (and of the log)."""
    counts = class_counts(r.classes)
    log(f"{name}: {n_points} points ({n_unit - n_points} from neighbours), "
        f"{r.grid.shape[1]} x {r.grid.shape[0]} cells"
        + (f" (unit grown {grown}x to hold whole holes)" if grown else "") + "; "
        + ", ".join(f"{k} {v}" for k, v in counts.items()))
    return {"tile": name, "points": n_points, "unit_points": n_unit, "grid_shape": r.grid.shape,
            "classes": counts, "unit_grown": grown,
            "seconds": r.info["rasterize_seconds"] + (r.info["filter_seconds"] or 0) + r.info["classify_seconds"]}


# --------------------------------------------------------------------------- evaluation
def match_points(a, b, tolerance=None):
    """Index into ``b`` of each point of ``a`` (-1 when none within ``tolerance``).

    Same length and the same x, y in order: the identity (fast path). Otherwise the
    nearest point of ``b`` in x, y, z (``scipy.spatial.cKDTree``). ``tolerance`` defaults
    to 0.002 units (classified text keeps 3 decimals).
    """
    tol = 0.002 if tolerance is None else float(tolerance)
    if len(a) == len(b) and np.allclose(a.x, b.x, rtol=0, atol=tol) and \
            np.allclose(a.y, b.y, rtol=0, atol=tol):
        return np.arange(len(a))
    from scipy.spatial import cKDTree
    ox, oy, oz = float(b.x.min()), float(b.y.min()), float(b.z.min())
    tree = cKDTree(np.column_stack([b.x - ox, b.y - oy, b.z - oz]))
    d, idx = tree.query(np.column_stack([a.x - ox, a.y - oy, a.z - oz]), k=1,
                        distance_upper_bound=tol * math.sqrt(3))
    idx = np.where(np.isfinite(d), idx, -1)
    return idx.astype(np.int64)


def _ground_code(cloud_or_format, codes=None):
    if codes is not None:
        return codes
    fmt = cloud_or_format if isinstance(cloud_or_format, str) else cloud_or_format.source_format
    return (2,) if fmt == "las" else (0,)


def truth_ground(classes, fmt, what="the truth points", codes=None):
    """Boolean ground of per-point true classes (``codes``, else by ``fmt``: ISPRS text 0,
    LAS ASPRS 2). ValueError when no point holds a ground code: a truth without ground is a
    file in the other convention (LAS codes in a text file, ISPRS codes in a LAS file) or not
    classified, and would give a Type I error of nothing and every point an object."""
    classes = np.asarray(classes).ravel()
    codes = _ground_code(fmt, codes)
    ground = np.isin(classes, codes)
    if classes.size and not ground.any():
        found = np.unique(classes)
        shown = ", ".join(str(int(c)) for c in found[:12]) + (", ..." if found.size > 12 else "")
        kind = "LAS/LAZ file (ASPRS classes)" if fmt == "las" else "text file (ISPRS classes)"
        if fmt == "las":
            hint = ("it is not classified into ground: classify it first (ASPRS class 2 = ground), or give "
                    "truth that is" + (" (class 0 = ground is the text convention: write it as text)"
                                       if 0 in found else ""))
        else:
            hint = ("class 2 looks like ASPRS LAS codes: recode them to 0 = ground, 1 = object"
                    if 2 in found else "recode the ground points to 0 and the others to 1")
        raise ValueError(f"{what} hold no ground point: ground is class {', '.join(map(str, codes))} in a {kind}, "
                         f"and their classes are {shown}; {hint}.")
    return ground


def compare_classified(pred, truth=None, truth_column=None, *, truth_ground_codes=None,
                       tolerance=None):
    """Errors of a classified cloud against per-point truth.

    Parameters
    ----------
    pred : PointCloud
        Classified points (e.g. written by ``classifypoints``): text class 0 = ground,
        255 = not classified (left out); LAS class 2 = ground.
    truth : PointCloud, optional
        The same points with the true classes (ISPRS text: 0 = ground; LAS: ASPRS 2 =
        ground), matched by position (:func:`match_points`).
    truth_column : ndarray, optional
        The true class per point of ``pred`` instead (:func:`read_column`); ground codes
        by ``pred``'s format unless ``truth_ground_codes`` is given.
    truth_ground_codes : tuple of int, optional
        The truth's ground classes (default (0,) text, (2,) LAS).

    Returns
    -------
    dict
        :func:`.evaluate.confusion` plus ``points_not_classified`` and ``points_unmatched``,
        and under ``"_arrays"`` the per-point ``pred_ground``, ``true_ground``, ``valid``.
    """
    from .evaluate import confusion
    if pred.classification is None:
        raise ValueError("the classified points have no class column; classify them first "
                         "(bareearth:classifypoints).")
    if (truth is None) == (truth_column is None):
        raise ValueError("give the truth as a points file or as a column, one of them.")
    pc = pred.classification
    if pred.source_format == "las":
        pred_ground, valid = pc == 2, np.ones(pc.size, bool)
    else:
        pred_ground, valid = pc == GROUND, pc != NODATA
    n_not = int((~valid).sum())
    unmatched = 0
    if truth is not None:
        if truth.classification is None:
            raise ValueError("the truth points have no class column.")
        idx = match_points(pred, truth, tolerance)
        ok = idx >= 0
        unmatched = int((~ok).sum())
        if unmatched > 0.01 * len(pred):
            raise ValueError(f"{unmatched} of {len(pred)} classified points have no truth point at "
                             "the same position: the files are not the same points (give the file "
                             "the classified points came from).")
        codes = _ground_code(truth, truth_ground_codes)
        true_ground = np.zeros(len(pred), bool)
        true_ground[ok] = truth_ground(truth.classification[idx[ok]], truth.source_format, codes=codes)
        valid &= ok
    else:
        tc = np.asarray(truth_column).ravel()
        if tc.size != len(pred):
            raise ValueError(f"the truth column has {tc.size} values for {len(pred)} points.")
        true_ground = truth_ground(tc, pred.source_format, "the truth column",
                                   codes=_ground_code(pred, truth_ground_codes))
    r = confusion(pred_ground, true_ground, valid=valid)
    r["points_not_classified"] = n_not
    r["points_unmatched"] = unmatched
    r["_arrays"] = {"pred_ground": pred_ground, "true_ground": true_ground, "valid": valid}
    return r
