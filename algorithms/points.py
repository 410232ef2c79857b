"""Point-cloud algorithms: ``bareearth:rasterizepoints``, ``bareearth:classifypoints``, and the
``INPUT_POINTS`` side of a filter (:class:`PointsInputMixin`). Thin: the work is in
``core.points`` and ``core.pointflow``."""
import os
import threading

import numpy as np
from qgis.core import (
    QgsProcessing,
    QgsProcessingException,
    QgsProcessingOutputNumber,
    QgsProcessingParameterBand,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterCrs,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFile,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterMultipleLayers,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterDestination,
    QgsProcessingParameterRasterLayer,
    QgsProcessingUtils,
)

from ..core import Cancelled, grid
from ..core import pointflow as pf
from ..core.pointfiles import check_points_writable
from ..core.points import LAS_INSTALL_HINT, read_points
from .compat import FILE_FILE, FLAG_OPTIONAL, NUMBER_DOUBLE, SOURCE_FILE, mark_advanced
from .filter_base import (
    BaseAlgorithm,
    check_dsm,
    destination_path,
    explained,
    format_params,
    label_of,
    output_options,
    progress_callback,
    stage_done,
    tr,
)

POINT_FILE_FILTER = ("Point clouds (*.txt *.csv *.xyz *.pts *.las *.laz);;Text (*.txt *.csv *.xyz *.pts);;"
                     "LAS/LAZ (*.las *.laz);;All files (*.*)")
POINT_OUTPUT_FILTER = "Text (*.txt);;CSV (*.csv);;LAS (*.las);;LAZ (*.laz)"
POINTS_HELP = ("Point file: text/CSV 'x y z [class]' (spaces, tabs or commas; one header line allowed, "
               "naming the axes in any order: x y z, E N H, Easting Northing Elevation, lon lat alt; "
               "the ISPRS format), or LAS/LAZ (needs the Python packages laspy, and lazrs for LAZ: "
               "pip install laspy lazrs).")
CRS_HELP = ("CRS of the points, overriding the file's (LAS header, or a .prj beside a text file). Feet and "
            "degrees are converted to metres for the thresholds.")
OUTPUT_POINTS_HELP = ("Classified points. Text (.txt/.csv): x y z class with 0 ground, 1 above, 2 below, "
                      "255 outside the DTM. LAS/LAZ: every attribute of the input kept, classification set "
                      "to ASPRS 2 ground, 1 unclassified, 7 low noise (points outside the DTM keep theirs). "
                      "A temporary output takes the input's format.")


# --------------------------------------------------------------------------- helpers
_cache_lock = threading.Lock()
_cache = {}


def load_points(path, crs=None):
    """read_points with a one-entry cache keyed by path, size, mtime and CRS, so that the
    check before the run and the run read a file once. Raises ValueError / ImportError."""
    if not path:
        raise ValueError("No point file was given.")
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ValueError(f"The point file {path!r} does not exist; check the path.")
    st = os.stat(path)
    key = (os.path.abspath(path), st.st_size, st.st_mtime_ns, crs or "")
    with _cache_lock:
        if key in _cache:
            return _cache[key]
    if st.st_size == 0:
        raise ValueError(f"The point file {path!r} is empty (0 bytes); it needs one point per line "
                         "(x y z or x y z class), or LAS/LAZ points.")
    cloud = read_points(path, crs=crs or None)
    with _cache_lock:
        _cache.clear()
        _cache[key] = cloud
    return cloud


def release_points():
    """Forget the cached cloud (end of a run)."""
    with _cache_lock:
        _cache.clear()


def check_points(path, crs=None, what="INPUT"):
    """(ok, message, cloud) for a point file, with the file read (and cached)."""
    try:
        cloud = load_points(path, crs)
    except ImportError as exc:
        hint = "" if LAS_INSTALL_HINT in str(exc) else " " + LAS_INSTALL_HINT
        return False, "{}: {}{}".format(what, exc, hint), None
    except ValueError as exc:
        return False, "{}: {}".format(what, exc), None
    if len(cloud) == 0:
        return False, tr("{}: the point file '{}' has no points.").format(what, path), None
    if not (np.isfinite(cloud.x) & np.isfinite(cloud.y) & np.isfinite(cloud.z)).any():
        return False, tr("{}: no point of '{}' has a finite height (z is NaN or infinite on every line); "
                         "check the z column.").format(what, path), None
    return True, "", cloud


def check_width(cloud, cell_m, scales, what="INPUT_POINTS"):
    """ValueError when the points cannot fill the 3 x 3 cells a filter needs although their
    bounding box does: 99 % of them span less (a cell larger than their spread; a few stray points
    far away are refused before, :func:`.pointflow.check_stray_points`), or they lie along a line
    (across their principal direction, the minor axis of the x/y covariance, in metres, they span
    less than 3 cells; a diagonal line of points has a square bounding box)."""
    ok = np.isfinite(cloud.x) & np.isfinite(cloud.y) & np.isfinite(cloud.z)
    x = (cloud.x[ok] - cloud.x[ok].mean()) * scales[0]
    y = (cloud.y[ok] - cloud.y[ok].mean()) * scales[1]
    if x.size < 3:
        raise ValueError(f"{what}: only {x.size} point(s) with finite x, y and z; a filter needs points "
                         "over at least 3 x 3 cells.")
    qx, qy = np.quantile(x, pf.STRAY_QUANTILES), np.quantile(y, pf.STRAY_QUANTILES)
    bw, bh = float(qx[1] - qx[0]), float(qy[1] - qy[0])
    if bw / cell_m < 3 or bh / cell_m < 3:     # stray points far from these: pointflow.check_stray_points
        raise ValueError(f"{what}: 99 % of the points span only {bw:.4g} x {bh:.4g} m: with cells of {cell_m:g} m "
                         "that is less than the 3 x 3 cells a filter needs. Give points covering an area (or a "
                         "smaller CELL_SIZE_M).")
    _, vecs = np.linalg.eigh(np.cov(np.vstack([x, y])))
    minor = vecs[:, 0]                                  # eigh: ascending eigenvalues
    width = float(np.ptp(x * minor[0] + y * minor[1]))
    if width / cell_m < 3:
        raise ValueError(f"{what}: the points lie along a line, {width:.3g} m wide across it: with cells of "
                         f"{cell_m:g} m that is less than the 3 cells a filter needs. Give points covering an "
                         "area (or a smaller CELL_SIZE_M).")


def crs_value(alg, parameters, key, context):
    """WKT of an optional CRS parameter, or None."""
    if not parameters.get(key):
        return None
    crs = alg.parameterAsCrs(parameters, key, context)
    return crs.toWkt() if crs.isValid() else None


def cell_size_value(alg, parameters, key, context):
    """An optional positive number (None when empty or 0)."""
    v = parameters.get(key)
    if v is None or v == "":
        return None
    v = alg.parameterAsDouble(parameters, key, context)
    return v if v and v > 0 else None


def points_output(alg, parameters, key, context, input_path):
    """The path of a classified-points destination: the given one, or a temporary file
    with the input's extension."""
    value = parameters.get(key)
    path = alg.parameterAsFileOutput(parameters, key, context) if value not in (None, "") else ""
    temporary = not path or str(value) == QgsProcessing.TEMPORARY_OUTPUT or \
        os.path.dirname(os.path.abspath(path)).startswith(QgsProcessingUtils.tempFolder())
    if not path:
        path = QgsProcessingUtils.generateTempFilename("classified_points.txt")
    path = pf.point_output_path(path, input_path, temporary=temporary and not _explicit_ext(value))
    check_points_writable(path)
    return path


def _explicit_ext(value):
    """True when the user named the output file (an extension of a point format)."""
    if value in (None, "") or str(value) == QgsProcessing.TEMPORARY_OUTPUT:
        return False
    sink = getattr(value, "sink", None)
    text = sink.staticValue() if sink is not None else value
    return os.path.splitext(str(text))[1].lower() in pf.POINT_EXTENSIONS


def check_in_grid(cloud, info):
    """(ok, message): refuse points mostly outside a DTM, naming both extents."""
    gt = info.geotransform
    rows, cols = info.shape
    xs = sorted((gt[0], gt[0] + gt[1] * cols))
    ys = sorted((gt[3], gt[3] + gt[5] * rows))
    outside = ~((cloud.x >= xs[0]) & (cloud.x <= xs[1]) & (cloud.y >= ys[0]) & (cloud.y <= ys[1]))
    n_out = int(outside.sum())
    if n_out * 2 > len(cloud):
        x0, y0, x1, y1 = cloud.extent
        differ = crs_warning(cloud, info)     # a DTM in degrees showed as 'x 9.000..9.000' beside metres
        return False, tr("{} of {} points are outside the DTM: the points span x {:.3f}..{:.3f}, y {:.3f}..{:.3f}; "
                         "the DTM spans x {:.6g}..{:.6g}, y {:.6g}..{:.6g}.{} Use a DTM of the same area, in the same "
                         "CRS and units as the points (set the points' CRS if the file has none).").format(
            n_out, len(cloud), x0, x1, y0, y1, xs[0], xs[1], ys[0], ys[1],
            " " + differ.split(":")[0] + "." if differ else "")
    return True, ""


def crs_warning(cloud, info):
    """A warning when the points' and the DTM's CRS differ (both known), else ''."""
    if not cloud.crs or not info.crs_wkt:
        return ""
    from osgeo import osr
    a, b = osr.SpatialReference(), osr.SpatialReference()
    try:
        if a.SetFromUserInput(cloud.crs) != 0 or b.SetFromUserInput(info.crs_wkt) != 0:
            return ""
    except RuntimeError:
        return ""
    if a.IsSame(b):
        return ""
    return (f"The points' CRS ({a.GetName()}) differs from the DTM's ({b.GetName()}): the points are taken "
            "to be in the DTM's coordinates. Reproject one of them if that is wrong.")


def height_mismatch_warning(counts):
    """A warning when the points' heights do not fit the DTM, else '': most classified points
    below it (never so for a DTM of these points: it is the ground beneath them), or almost none
    on it. Points in ellipsoidal heights against a DTM in geoid heights (tens of metres apart), or
    heights in another unit, get every point 'below' or 'above' without a word otherwise."""
    n = counts["ground"] + counts["above"] + counts["below"]
    if n < 10:
        return ""
    share = {k: counts[k] / n for k in ("ground", "above", "below")}
    if share["below"] <= 0.5 and share["ground"] >= 0.01:
        return ""
    side = "below" if share["below"] > share["above"] else "above"
    return (f"{counts[side]} of the {n} points on the DTM ({100 * share[side]:.0f} %) are {side} it beyond the "
            f"tolerance and {counts['ground']} on it: the heights of the points and of the DTM do not fit (another "
            "vertical datum, such as ellipsoidal against geoid heights, another unit, or a DTM of another "
            "survey). Bring both to one height reference first.")


def log_counts(feedback, counts, header="Points per class:"):
    total = max(1, sum(counts.values()))
    feedback.pushInfo(tr(header))
    for name, n in counts.items():
        feedback.pushInfo(f"  {name:>16}: {n:>10} ({100.0 * n / total:.2f} %)")


def _number_or_none(value):
    """A parameter's value as a float (text as qgis_process gives it), or None when it is not one."""
    try:
        return float(value)
    except (TypeError, ValueError):
        return None


def warn(feedback, text):
    (feedback.pushWarning if hasattr(feedback, "pushWarning") else feedback.pushInfo)(text)


def _file_param(key, label, help_, optional=False):
    p = QgsProcessingParameterFile(key, tr(label), FILE_FILE, "", None, optional,
                                   POINT_FILE_FILTER)
    p.setHelp(tr(help_))
    return p


def _crs_param(key):
    p = QgsProcessingParameterCrs(key, tr("CRS of the points [empty: from the file]"), None, optional=True)
    p.setHelp(tr(CRS_HELP))
    return p


def _cell_param(key):
    p = QgsProcessingParameterNumber(key, tr("Cell size (m) [empty: from the point density]"),
                                     NUMBER_DOUBLE, None, optional=True,
                                     minValue=0.0, maxValue=100000.0)
    p.setHelp(tr("Cell size of the grid in metres (converted to the CRS's unit: feet, degrees). Empty or 0: "
                 "about one point per cell, sqrt(area / points) rounded to 1, 2, 2.5 or 5 x 10^k m, but at most "
                 "1 m (SMRF's cell) while 1 m keeps a point per 16 cells (sparser: a quarter of the spacing, "
                 "rounded up)."))
    return p


def _rule_params(threshold_key, slope_key, advanced=False):
    t = QgsProcessingParameterNumber(threshold_key, tr("Ground tolerance (m)"), NUMBER_DOUBLE,
                                     pf.DEFAULT_THRESHOLD_M, minValue=0.0, maxValue=1000.0)
    t.setHelp(tr("A point within this height of the DTM, plus the slope term, is ground (metres; SMRF: 0.5)."))
    s = QgsProcessingParameterNumber(slope_key, tr("Slope factor (m per unit slope)"),
                                     NUMBER_DOUBLE, pf.DEFAULT_SLOPE_FACTOR,
                                     minValue=0.0, maxValue=1000.0)
    s.setHelp(tr("Extra tolerance in metres per unit of local DTM slope (rise/run): ground when "
                 "|z - DTM| <= tolerance + factor x slope (SMRF: 1.25, Pingel et al. 2013)."))
    if advanced:
        for p in (t, s):
            mark_advanced(p)
    return t, s


#: what a point-cloud user types in the toolbox search
POINT_TAGS = ("lidar", "point cloud", "points", "LAS", "LAZ", "ALS", "ground", "DTM", "DSM", "classification")


class PointAlgorithmBase(BaseAlgorithm):
    GROUP, GROUP_NAME = "points", "Point clouds"
    TAGS = POINT_TAGS + ("rasterize", "grid", "classify", "ground points")


# --------------------------------------------------------------------------- rasterize
class RasterizePointsAlgorithm(PointAlgorithmBase):
    """``bareearth:rasterizepoints``: points to a DSM raster (lowest / highest / mean z per cell)."""

    INPUT, CRS, CELL_SIZE_M, REDUCER, FILL_EMPTY, OUTPUT = ("INPUT", "CRS", "CELL_SIZE_M", "REDUCER",
                                                            "FILL_EMPTY", "OUTPUT")
    REDUCER_NAMES = ("lowest", "highest", "mean")

    def name(self):
        return "rasterizepoints"

    def displayName(self):  # noqa: N802
        return tr("Rasterize points to a DSM")

    def shortHelpString(self):  # noqa: N802
        return tr("<p>Grids a point cloud: the lowest (default, the surface the filters expect), highest or mean "
                  "z of the points in each cell. Vectorised (several million points per second).</p><ul>"
                  "<li><b>INPUT</b>: {}</li><li><b>CRS</b>: {}</li>"
                  "<li><b>CELL_SIZE_M</b>: metres; empty: about one point per cell, at most 1 m while 1 m keeps a "
                  "point per 16 cells.</li>"
                  "<li><b>REDUCER</b>: lowest, highest or mean z per cell.</li>"
                  "<li><b>FILL_EMPTY</b>: cells without a point take the nearest cell's value (default); "
                  "otherwise they are nodata.</li>"
                  "<li><b>OUTPUT</b>: Float32 GeoTIFF in the points' CRS, heights in its unit, NaN nodata; "
                  "the origin is a multiple of the cell size, so grids of neighbouring tiles line up.</li></ul>"
                  ).format(tr(POINTS_HELP), tr(CRS_HELP))

    def initAlgorithm(self, config=None):  # noqa: N802
        self.addParameter(_file_param(self.INPUT, "Points (text/CSV or LAS/LAZ)", POINTS_HELP))
        self.addParameter(_crs_param(self.CRS))
        self.addParameter(_cell_param(self.CELL_SIZE_M))
        r = QgsProcessingParameterEnum(self.REDUCER, tr("Height per cell"), list(self.REDUCER_NAMES), False, 0)
        r.setHelp(tr("lowest: the lowest point (DSM for the filters); highest; mean."))
        self.addParameter(r)
        f = QgsProcessingParameterBoolean(self.FILL_EMPTY, tr("Fill empty cells from the nearest cell"), True)
        f.setHelp(tr("Cells without a point take the value of the nearest cell with one; otherwise nodata."))
        self.addParameter(f)
        o = QgsProcessingParameterRasterDestination(self.OUTPUT, tr("DSM"))
        o.setHelp(tr("Float32 raster on the points' CRS, NaN nodata."))
        self.addParameter(o)
        for p in format_params():
            self.addParameter(p)
        for key, label in (("POINTS", "Points"), ("CELL_SIZE", "Cell size (m)"), ("EMPTY_CELLS", "Empty cells")):
            self.addOutput(QgsProcessingOutputNumber(key, tr(label)))

    def _inputs(self, parameters, context):
        path = self.parameterAsFile(parameters, self.INPUT, context)
        crs = crs_value(self, parameters, self.CRS, context)
        ok, msg, cloud = check_points(path, crs)
        if not ok:
            raise ValueError(msg)
        pf.check_stray_points(cloud, self.INPUT)
        cell = cell_size_value(self, parameters, self.CELL_SIZE_M, context)
        c = cell or pf.default_cell_size_m(cloud)
        sx, sy, _ = pf.axis_scales(cloud)
        x0, y0, x1, y1 = cloud.extent
        cells = ((x1 - x0) * sx / c + 1) * ((y1 - y0) * sy / c + 1)
        if cells > 1e9:
            raise ValueError(f"CELL_SIZE_M = {c:g} m gives about {cells:.3g} cells over the points' "
                             f"{(x1 - x0) * sx:.0f} x {(y1 - y0) * sy:.0f} m: use a larger cell size"
                             " (or check the CRS: degrees read as metres?).")
        w, h = (x1 - x0) * sx, (y1 - y0) * sy
        if w / c < 3 or h / c < 3:
            raise ValueError(f"INPUT: the points span only {w:.3g} x {h:.3g} m: with cells of {c:g} m that is less "
                             "than the 3 x 3 cells of a DSM the filters can use; use a smaller CELL_SIZE_M or more "
                             "points.")
        if cell:
            pf.check_grid_cells(len(cloud), w, h, c, fill_empty=self.parameterAsBool(parameters, self.FILL_EMPTY,
                                                                                      context))
        return path, cloud, cell

    @explained
    def checkParameterValues(self, parameters, context):  # noqa: N802
        ok, msg = super().checkParameterValues(parameters, context)
        if not ok:
            return ok, msg
        try:
            self._inputs(parameters, context)
        except ValueError as exc:
            return False, str(exc)
        return True, ""

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        try:
            path, cloud, cell = self._inputs(parameters, context)
            reducer = pf.REDUCERS[self.parameterAsEnum(parameters, self.REDUCER, context)]
            fill = self.parameterAsBool(parameters, self.FILL_EMPTY, context)
            out = self.parameterAsOutputLayer(parameters, self.OUTPUT, context)
            feedback.pushInfo(tr("Read {} points from {} (x/y unit: {}).").format(len(cloud), path,
                                                                                  pf.unit_name(cloud)))
            for w in pf.crs_warnings(cloud) + [pf.height_warnings(cloud, classified=False)]:
                if w:
                    warn(feedback, w)
            stage_done(feedback, 30)
            g = pf.rasterize_cloud(cloud, cell, reducer=reducer, fill_empty=fill)
            stage_done(feedback, 70)
            with output_options(self, parameters, context, feedback):
                pf.write_rasters(g, None, {"dsm": out})
        except Cancelled:
            feedback.reportError(tr("Cancelled: no output was written."))
            return {}
        except (ValueError, ImportError) as exc:
            raise QgsProcessingException(self.explain(str(exc))) from None
        finally:
            release_points()
        i = g.info
        feedback.pushInfo(tr("Grid: {} x {} cells of {:.4g} x {:.4g} m ({:.6g} CRS units), {:.2f} points per cell, "
                             "{} empty cells ({}).").format(
            g.shape[1], g.shape[0], g.cell_size_m[0], g.cell_size_m[1], i["cell_size"][0], i["points_per_cell"],
            int(i["n_empty"]), tr("filled from the nearest") if fill else tr("nodata")))
        feedback.pushInfo(tr("Rasterized in {:.3f} s ({:.2f} million points/s).").format(
            i["seconds"], i["n_points"] / max(i["seconds"], 1e-9) / 1e6))
        return {self.OUTPUT: out, "POINTS": len(cloud), "CELL_SIZE": float(g.cell_size_m[0]),
                "EMPTY_CELLS": int(i["n_empty"])}


# --------------------------------------------------------------------------- classify
class ClassifyPointsAlgorithm(PointAlgorithmBase):
    """``bareearth:classifypoints``: points + DTM -> ground / above / below per point."""

    INPUT, CRS, DTM, BAND, THRESHOLD_M, SLOPE_FACTOR, OUTPUT = (
        "INPUT", "CRS", "DTM", "BAND", "THRESHOLD_M", "SLOPE_FACTOR", "OUTPUT")

    def name(self):
        return "classifypoints"

    def displayName(self):  # noqa: N802
        return tr("Classify points by a DTM")

    def shortHelpString(self):  # noqa: N802
        return tr("<p>Labels every point against a bare-earth DTM: <b>ground</b> when |z - DTM| &lt;= THRESHOLD_M + "
                  "SLOPE_FACTOR x the local DTM slope (bilinear samples; the SMRF rule, Pingel et al. 2013, "
                  "defaults 0.5 m and 1.25), <b>above</b> when higher, <b>below</b> when lower. Works in metres "
                  "whatever the CRS's unit (feet, degrees). Counts per class go to the log.</p><ul>"
                  "<li><b>INPUT</b>: {}</li><li><b>CRS</b>: {}</li>"
                  "<li><b>DTM</b>: the DTM raster, in the points' CRS (e.g. the DTM of a Bare Earth filter).</li>"
                  "<li><b>OUTPUT</b>: {}</li></ul>").format(tr(POINTS_HELP), tr(CRS_HELP), tr(OUTPUT_POINTS_HELP))

    def initAlgorithm(self, config=None):  # noqa: N802
        self.addParameter(_file_param(self.INPUT, "Points (text/CSV or LAS/LAZ)", POINTS_HELP))
        self.addParameter(_crs_param(self.CRS))
        d = QgsProcessingParameterRasterLayer(self.DTM, tr("DTM"))
        d.setHelp(tr("Bare-earth DTM in the points' CRS (heights in metres, or in the CRS's unit)."))
        self.addParameter(d)
        b = QgsProcessingParameterBand(self.BAND, tr("DTM band"), None, self.DTM, optional=True)
        b.setHelp(tr("Band holding the heights; needed only when the raster has several bands."))
        mark_advanced(b)
        self.addParameter(b)
        for p in _rule_params(self.THRESHOLD_M, self.SLOPE_FACTOR):
            self.addParameter(p)
        o = QgsProcessingParameterFileDestination(self.OUTPUT, tr("Classified points"), POINT_OUTPUT_FILTER)
        o.setHelp(tr(OUTPUT_POINTS_HELP))
        self.addParameter(o)
        for key, label in (("GROUND", "Ground points"), ("ABOVE", "Points above the DTM"),
                           ("BELOW", "Points below the DTM"), ("OUTSIDE", "Points outside the DTM")):
            self.addOutput(QgsProcessingOutputNumber(key, tr(label)))

    def _inputs(self, parameters, context):
        path = self.parameterAsFile(parameters, self.INPUT, context)
        ok, msg, cloud = check_points(path, crs_value(self, parameters, self.CRS, context))
        if not ok:
            raise ValueError(msg)
        layer = self.parameterAsRasterLayer(parameters, self.DTM, context)
        band = self.parameterAsInt(parameters, self.BAND, context) if parameters.get(self.BAND) else None
        ok, msg, info = check_dsm(layer, band)
        if not ok:
            raise ValueError(f"DTM: {msg}")
        ok, msg = check_in_grid(cloud, info)
        if not ok:
            raise ValueError(msg)
        return path, cloud, info

    @explained
    def checkParameterValues(self, parameters, context):  # noqa: N802
        ok, msg = super().checkParameterValues(parameters, context)
        if not ok:
            return ok, msg
        try:
            path, _, _ = self._inputs(parameters, context)
            points_output(self, parameters, self.OUTPUT, context, path)
        except (ValueError, QgsProcessingException) as exc:
            return False, str(exc)
        return True, ""

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        import time
        try:
            path, cloud, info = self._inputs(parameters, context)
            out = points_output(self, parameters, self.OUTPUT, context, path)
            for w in (crs_warning(cloud, info), pf.height_warnings(cloud)):
                if w:
                    warn(feedback, w)
            feedback.pushInfo(tr("Read {} points from {}.").format(len(cloud), path))
            dtm = info.read()
            stage_done(feedback, 30)
            t0 = time.perf_counter()
            classes = pf.classify_cloud(cloud, dtm, info.geotransform,
                                        threshold_m=self.parameterAsDouble(parameters, self.THRESHOLD_M, context),
                                        slope_factor=self.parameterAsDouble(parameters, self.SLOPE_FACTOR, context))
            dt = time.perf_counter() - t0
            stage_done(feedback, 60)
            from ..core.points import write_points
            write_points(out, cloud, classes)
        except Cancelled:
            feedback.reportError(tr("Cancelled: no output was written."))
            return {}
        except (ValueError, ImportError) as exc:
            raise QgsProcessingException(self.explain(str(exc))) from None
        finally:
            release_points()
        counts = pf.class_counts(classes)
        log_counts(feedback, counts)
        w = height_mismatch_warning(counts)
        if w:
            warn(feedback, w)
        feedback.pushInfo(tr("Classified in {:.3f} s ({:.2f} million points/s); written to {}.").format(
            dt, len(cloud) / max(dt, 1e-9) / 1e6, out))
        return {self.OUTPUT: out, "GROUND": counts["ground"], "ABOVE": counts["above"],
                "BELOW": counts["below"], "OUTSIDE": counts["outside the DTM"]}


# --------------------------------------------------------------------------- filters on points
class PointsInputMixin:
    """Gives a filter algorithm an ``INPUT_POINTS`` alternative to its DSM ``INPUT``.

    With points, the algorithm rasterizes them (lowest point per cell, ``CELL_SIZE_M`` or
    the default cell of :func:`.pointflow.default_cell_size_m`, empty cells from the nearest),
    runs the filter on that grid,
    writes the usual rasters on it (in the points' CRS) and classifies the points against
    the DTM into ``OUTPUT_POINTS``. ``OTHER_TILES``: the neighbouring tiles of a block;
    the input tile is then filtered with an overlap of their points and one parameter set
    for the block, so that the tiles' classes agree along the seams.
    """

    INPUT_POINTS, POINTS_CRS, CELL_SIZE_M = "INPUT_POINTS", "POINTS_CRS", "CELL_SIZE_M"

    @property
    def TAGS(self):  # noqa: N802
        return super().TAGS + POINT_TAGS
    THRESHOLD_M, SLOPE_FACTOR, OTHER_TILES, OUTPUT_POINTS = ("THRESHOLD_M", "SLOPE_FACTOR", "OTHER_TILES",
                                                             "OUTPUT_POINTS")

    def shortHelpString(self):  # noqa: N802
        return super().shortHelpString() + tr(
            "<h3>On points</h3><p>Give <b>INPUT_POINTS</b> instead of INPUT (exactly one of them): "
            "{} The points are rasterized (lowest point per cell, <b>CELL_SIZE_M</b> or about one "
            "point per cell but at most 1 m while 1 m keeps a point per 16 cells, empty cells from the "
            "nearest), filtered, and classified against the DTM (ground when |z - DTM| &lt;= THRESHOLD_M + "
            "SLOPE_FACTOR x slope, SMRF; on cells coarser than SMRF's 1 m the factor grows by "
            "(cell - 1 m) / sqrt(12): each cell's lowest point lies anywhere inside it) into "
            "<b>OUTPUT_POINTS</b>: {} The rasters are written on the points' grid and CRS. "
            "<b>OTHER_TILES</b>: the neighbouring tiles of a block; the input tile is filtered with their "
            "points around it (an overlap of the filter's reach) and one parameter set for the block, so "
            "the tiles agree along their seams.</p>").format(tr(POINTS_HELP), tr(OUTPUT_POINTS_HELP))

    def initAlgorithm(self, config=None):  # noqa: N802
        super().initAlgorithm(config)
        inp = self.parameterDefinition(self.INPUT)
        inp.setFlags(inp.flags() | FLAG_OPTIONAL)
        inp.setDescription(tr("Input DSM [or INPUT_POINTS]"))
        self.addParameter(_file_param(self.INPUT_POINTS, "Input points [or INPUT]", POINTS_HELP, optional=True))
        crs = _crs_param(self.POINTS_CRS)
        mark_advanced(crs)
        self.addParameter(crs)
        self.addParameter(_cell_param(self.CELL_SIZE_M))
        for p in _rule_params(self.THRESHOLD_M, self.SLOPE_FACTOR, advanced=True):
            self.addParameter(p)
        t = QgsProcessingParameterMultipleLayers(self.OTHER_TILES, tr("Neighbouring tiles of the points"),
                                                 SOURCE_FILE, None, optional=True)
        t.setHelp(tr("Other point files of the same block (same CRS), each once (the block's whole list, holding "
                     "INPUT_POINTS too, is taken). Their points around INPUT_POINTS are filtered with it so that "
                     "classes agree along tile seams; only INPUT_POINTS is classified."))
        mark_advanced(t)
        self.addParameter(t)
        o = QgsProcessingParameterFileDestination(self.OUTPUT_POINTS, tr("Classified points"), POINT_OUTPUT_FILTER,
                                                  optional=True, createByDefault=True)
        o.setHelp(tr(OUTPUT_POINTS_HELP + " Only with INPUT_POINTS."))
        self.addParameter(o)

    @staticmethod
    def _given(parameters, key):
        v = parameters.get(key)
        return v is not None and v != "" and not (isinstance(v, (list, tuple)) and not v)

    def _use_points(self, parameters):
        return self._given(parameters, self.INPUT_POINTS)

    @explained
    def checkParameterValues(self, parameters, context):  # noqa: N802
        has_r, has_p = self._given(parameters, self.INPUT), self._given(parameters, self.INPUT_POINTS)
        if has_r == has_p:
            return False, tr("Give exactly one input: INPUT (a DSM raster) or INPUT_POINTS (a point file), "
                             + ("not both." if has_r else "neither was given."))
        if has_r:
            return super().checkParameterValues(parameters, context)
        ok, msg = BaseAlgorithm.checkParameterValues(self, parameters, context)
        if not ok:
            return ok, msg
        try:
            self._point_inputs(parameters, context)
        except ValueError as exc:
            return False, str(exc)
        return True, ""

    def _point_inputs(self, parameters, context):
        path = self.parameterAsFile(parameters, self.INPUT_POINTS, context)
        crs = crs_value(self, parameters, self.POINTS_CRS, context)
        ok, msg, cloud = check_points(path, crs, self.INPUT_POINTS)
        if not ok:
            raise ValueError(msg)
        pf.check_stray_points(cloud, self.INPUT_POINTS)
        given = (self.parameterAsFileList(parameters, self.OTHER_TILES, context)
                 if self._given(parameters, self.OTHER_TILES) else [])
        for t in given:
            if not os.path.isfile(t):
                raise ValueError(f"OTHER_TILES: the point file {t!r} does not exist.")
        # the input among its neighbours (the block's whole list) is left out; a tile given twice (another
        # name of one file: ./a.las, a link) counted its points twice in the block's cell size
        seen, tiles = {grid.file_identity(path): None}, []       # None: the input itself
        for t in given:
            key = grid.file_identity(t)
            if key not in seen:
                seen[key] = t
                tiles.append(t)
            elif seen[key] is not None:
                first = seen[key]
                raise ValueError(f"OTHER_TILES: the point file {t!r} is given twice"
                                 + (f" (also as {first!r}, the same file)" if first != t else "")
                                 + ": give each neighbouring tile once.")
        try:
            pf.check_tiles_crs(tiles, cloud, crs)
        except ValueError as exc:
            raise ValueError(f"OTHER_TILES: {exc}") from None
        cell = cell_size_value(self, parameters, self.CELL_SIZE_M, context)
        c = cell or pf.default_cell_size_m(cloud)
        sx, sy, _ = pf.axis_scales(cloud)
        x0, y0, x1, y1 = cloud.extent
        w, h = (x1 - x0) * sx, (y1 - y0) * sy
        if w / c < 3 or h / c < 3:
            raise ValueError(f"INPUT_POINTS span only {w:.1f} x {h:.1f} m: with cells of {c:g} m that is less than "
                             "the 3 x 3 cells a filter needs; use a smaller CELL_SIZE_M or more points.")
        if (w / c) * (h / c) > 1e9:
            raise ValueError(f"CELL_SIZE_M = {c:g} m gives about {(w / c) * (h / c):.3g} cells: use a larger "
                             "cell size.")
        if cell:
            pf.check_grid_cells(len(cloud), w, h, c, whole=False)
        check_width(cloud, c, (sx, sy), self.INPUT_POINTS)
        try:       # heights far steeper than any terrain: refused here, not after the points are rasterized
            pf.check_points_relief(cloud, c, (sx, sy, pf.axis_scales(cloud)[2]))
        except ValueError as exc:
            raise ValueError(f"{self.INPUT_POINTS}: {exc}") from None
        user = self._user_params(parameters, context)
        defaults = {p.name: p.default for p in self.method.params}
        extent_m = max(w, h)
        for name, v in user.items():
            if v is not None and v != defaults.get(name) and ("window" in name or "size_m" in name) \
                    and name.endswith("_m") and isinstance(v, (int, float)) and v > extent_m:
                raise ValueError(f"{name.upper()} = {v} m is larger than the points' extent ({extent_m:.1f} m "
                                 "across): choose a smaller window.")
        out = points_output(self, parameters, self.OUTPUT_POINTS, context, path)
        return path, crs, cloud, cell, tiles, out

    def points_only_given(self, parameters):
        """Labels of the parameters of INPUT_POINTS alone given a value of their own: a point
        output file, neighbouring tiles, a CRS or cell size, a classification rule other than its
        default (with a raster INPUT they are not used)."""
        given = [k for k in (self.POINTS_CRS, self.CELL_SIZE_M, self.OTHER_TILES) if self._given(parameters, k)]
        given += [k for k in (self.THRESHOLD_M, self.SLOPE_FACTOR) if self._given(parameters, k)
                  and _number_or_none(parameters[k]) != self.parameterDefinition(k).defaultValue()]
        given += [self.OUTPUT_POINTS] if destination_path(parameters, self.OUTPUT_POINTS) else []
        return [label_of(self.parameterDefinition(k)) for k in given]

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        if not self._use_points(parameters):
            unused = self.points_only_given(parameters)
            if unused:      # a point file asked for and not written without a word
                none = tr(" No point file is written.") if destination_path(parameters, self.OUTPUT_POINTS) else ""
                warn(feedback, tr("INPUT is a DSM raster, so what was given for INPUT_POINTS is not used: "
                                  "{}.{}").format(", ".join(unused), none))
            return super().processAlgorithm(parameters, context, feedback)
        try:
            path, crs, cloud, cell, tiles, out_points = self._point_inputs(parameters, context)
            rasters = {"dtm": self.parameterAsOutputLayer(parameters, self.OUTPUT_DTM, context),
                       "mask": self.parameterAsOutputLayer(parameters, self.OUTPUT_MASK, context)}
            if parameters.get(self.OUTPUT_NDSM):
                rasters["ndsm"] = self.parameterAsOutputLayer(parameters, self.OUTPUT_NDSM, context)
            for key in self.method.extras:
                pk = f"OUTPUT_{key.upper()}"
                if parameters.get(pk):
                    rasters[key] = self.parameterAsOutputLayer(parameters, pk, context)
            user = self._user_params(parameters, context)
            thr = self.parameterAsDouble(parameters, self.THRESHOLD_M, context)
            sf = self.parameterAsDouble(parameters, self.SLOPE_FACTOR, context)
            block = self.parameterAsInt(parameters, self.BLOCK_SIZE, context) or None
            progress = progress_callback(feedback)
            feedback.pushInfo(tr("Read {} points from {} (x/y unit: {}).").format(len(cloud), path,
                                                                                  pf.unit_name(cloud)))
            for w in pf.crs_warnings(cloud) + [pf.height_warnings(cloud)]:
                if w:
                    warn(feedback, w)
            if tiles:
                feedback.pushInfo(tr("Filtering as one block with {} neighbouring tile(s).").format(len(tiles)))
                tr_ = pf.filter_tiles([cloud] + tiles, method=self.METHOD_NAME, params=user, cell_size_m=cell,
                                      crs=crs, threshold_m=thr, slope_factor=sf, only=[0], keep_results=True,
                                      progress=progress, log=feedback.pushInfo)
                res = tr_.results[0]
                feedback.pushInfo(tr("Overlap {:.1f} m; the rasters cover the tile and its overlap.").format(
                    tr_.overlap_m))
            else:
                res = pf.filter_cloud(cloud, self.METHOD_NAME, user, cell_size_m=cell, threshold_m=thr,
                                      slope_factor=sf, block=block, progress=progress)
            # all or nothing: the points to a hidden work file, the rasters (one atomic set),
            # then the points moved into place (a kill -9 meanwhile leaves no new points file)
            with output_options(self, parameters, context, feedback):
                pf.write_cloud_outputs(out_points, cloud, res.classes, res.grid, res.result, rasters,
                                       extras=self.method.extras)
        except Cancelled:
            feedback.reportError(tr("Cancelled: no output was written."))
            return {}
        except (ValueError, ImportError) as exc:
            raise QgsProcessingException(self.explain(str(exc))) from None
        finally:
            release_points()
        i = res.info
        feedback.pushInfo(tr("Grid: {} x {} cells of {:.4g} m, {} empty cells filled from the nearest.").format(
            res.grid.shape[1], res.grid.shape[0], i["cell_size_m"][0], int(i["empty_cells"])))
        info = dict(res.result.info)
        info["cell_size_m"] = i["cell_size_m"]
        info.setdefault("warnings", [])
        self.logResult(info, feedback)
        log_counts(feedback, i["classes"])
        feedback.pushInfo(tr("Rasterize {:.2f} M points/s, classify {:.2f} M points/s; points written to {}.").format(
            i["rasterize_points_per_s"] / 1e6, i["classify_points_per_s"] / 1e6, out_points))
        outs = {f"OUTPUT_{k.upper()}": v for k, v in rasters.items()}
        outs[self.OUTPUT_POINTS] = out_points
        return outs


# --------------------------------------------------------------------------- evaluate helper
def evaluate_classified(points, truth_points=None, truth_column=None, feedback=None):
    """Errors of a classified point file against truth (for ``bareearth:evaluate``).

    Returns (figures dict, error map, geotransform). Raises ValueError / ImportError.
    """
    from ..core import evaluate as ev
    from ..core.points import rasterize_points
    pred = read_points(points)
    if pred.classification is None:
        raise ValueError(f"POINTS {points!r} has no class column: with TRUTH_POINTS or TRUTH_COLUMN, POINTS must be "
                         "classified points (e.g. the output of bareearth:classifypoints).")
    if truth_column:
        r = pf.compare_classified(pred, truth_column=pf.read_column(points, truth_column))
    else:
        truth = read_points(truth_points)
        r = pf.compare_classified(pred, truth)
    arrays = r.pop("_arrays")
    info = {}
    _, gt = rasterize_points(pred.x, pred.y, pred.z, None, fill_empty=None, info=info)
    emap, _ = ev.error_map_from_points(arrays["pred_ground"], arrays["true_ground"], pred.x, pred.y, gt,
                                       info["shape"], valid=arrays["valid"], fill_empty="nearest")
    return r, emap, gt
