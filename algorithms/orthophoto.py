"""Orthophoto refinement: ``bareearth:orthoparallax`` and ``bareearth:orthorefine``.

Thin over ``core.orthophoto`` (Luong Chinh Ke 2002, section 2.3; Norvelle 1995): this module
reads the rasters and orientation files, checks them before any work, calls
:func:`~..core.orthophoto.refine.orthoparallax` / :func:`~..core.orthophoto.refine.orthorefine`
and writes the outputs on the DEM's grid. Nothing numeric here beyond converting colour
images to grey.
"""
import csv
import math
import os
from pathlib import Path

import numpy as np
from qgis.core import (
    QgsGeometry,
    QgsPointXY,
    QgsProcessingException,
    QgsProcessingOutputNumber,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterFile,
    QgsProcessingParameterFileDestination,
    QgsProcessingParameterFolderDestination,
    QgsProcessingParameterMultipleLayers,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterDestination,
    QgsProcessingParameterRasterLayer,
    QgsProcessingParameterString,
    QgsRectangle,
)

from ..core import Cancelled, grid
from ..core.codes import NODATA
from ..core.orthophoto.iterate import CROSS_CHECK as CROSS_CHECK_DEFAULT
from ..core.orthophoto.iterate import NOT_ROUGHER as NOT_ROUGHER_DEFAULT
from ..core.orthophoto.match import check_min_corr
from ..core.orthophoto.quality import order_reversed
from ..core.survey.io import crs_label
from .compat import FILE_FILE, FILE_FOLDER, NUMBER_DOUBLE, NUMBER_INTEGER, SOURCE_RASTER
from .fill_dtm import grid_mismatch_message, other_crs, same_grid
from .filter_base import (
    BaseAlgorithm,
    check_dsm,
    check_window_sizes,
    destination_path,
    format_params,
    label_of,
    output_options,
    progress_callback,
    raster_path,
    tr,
    with_help,
)

try:
    from osgeo import gdal, osr
except ImportError:  # pragma: no cover - GDAL ships with QGIS
    gdal = osr = None

IMAGE_EXTENSIONS = (".tif", ".tiff", ".jpg", ".jpeg", ".png", ".jp2", ".img", ".bmp", ".vrt")

OPK_HELP = ("Angles in degrees in the photogrammetric omega-phi-kappa convention (orthority, PATB/BLUH, "
            "Pix4D): R = Rx(omega) Ry(phi) Rz(kappa) rotates the camera axes (x right, y up towards the "
            "top of the image, z backwards: the camera looks along -z) into the world axes (X east, "
            "Y north, Z up); omega = phi = kappa = 0 is a vertical photo with the top of the image to "
            "the north, kappa = 180 a vertical photo with its top to the south.")

DH_HELP = ("Float32 height correction dh (m) at the matched cells: the true surface minus the DEM "
           "(positive: an object the DEM lacks); NaN elsewhere.")
QUALITY_HELP = "Float32 peak normalised cross-correlation of the match (0..1), NaN where not computed."
ORTHO_MASK_HELP = ("UInt8 mask from dh against its ground trend: 0 ground, 1 object (dh above the threshold), "
                   "2 low (below minus the threshold), 255 cells not seen in two orthophotos (or, for "
                   "orthoparallax, with no trusted match within a few cells); a colour table and a .qml style "
                   "are written with it.")


# --------------------------------------------------------------------------- helpers
def _warn(feedback, text):
    (feedback.pushWarning if hasattr(feedback, "pushWarning") else feedback.pushInfo)(text)


def _fmt(v):
    if isinstance(v, (float, np.floating)):
        return f"{float(v):.4g}"
    if isinstance(v, (list, tuple)):
        return "(" + ", ".join(_fmt(x) for x in v) + ")"
    return str(v)


def _optional_number(alg, parameters, key, context):
    """An optional number parameter: None when empty, else its value (0 kept)."""
    v = parameters.get(key)
    if v is None or v == "":
        return None
    v = alg.parameterAsDouble(parameters, key, context)
    return None if isinstance(v, float) and math.isnan(v) else v


def _positive_or_none(alg, parameters, key, context):
    """An optional number where empty or 0 means 'from the data'."""
    v = _optional_number(alg, parameters, key, context)
    return v if v is not None and v > 0 else None


def _grid_text(info):
    return (f"{info.shape[1]} x {info.shape[0]} cells, geotransform "
            f"{tuple(round(v, 6) for v in info.geotransform)}")


def _check_metric(info, what):
    """The core works in the CRS's units, which must be metres (heights and distances)."""
    if info.crs_wkt:
        srs = osr.SpatialReference()
        srs.ImportFromWkt(info.crs_wkt)
        if srs.IsGeographic():
            raise ValueError(f"{what} ({info.path}) is in a geographic CRS (degrees): the orthophoto "
                             "refinement needs a projected CRS in metres, the same as the camera "
                             "coordinates. Reproject it first (gdalwarp -t_srs EPSG:<UTM zone>).")
    xy_to_m = info.cell_size_m[0] / abs(info.geotransform[1])   # a compound CRS: its own height unit
    if info.unit_type and abs(info.z_to_m - 1.0) > 1e-9 and abs(xy_to_m - 1.0) <= 1e-9:
        raise ValueError(f"{what} ({info.path}) states its heights are in '{info.unit_type}' ({info.z_to_m:.6g} m): "
                         "the orthophoto tools work in metres. Write the heights in metres first (gdal_calc.py "
                         f"--calc=\"A*{info.z_to_m:.10g}\", then gdal_edit.py -units m).")
    for factor in (info.z_to_m, xy_to_m):
        if abs(factor - 1.0) > 1e-9:
            raise ValueError(f"{what} ({info.path}) is in a CRS whose unit is not the metre (factor "
                             f"{factor:.6g}); reproject it to a metric CRS first.")


def _open_grid(path, what):
    """DSMInfo of band 1 of any raster (for its grid), with a clear error."""
    try:
        return grid.open_dsm(path, 1)
    except ValueError as exc:
        raise ValueError(f"{what}: {exc}") from None


def read_grey(path):
    """A raster as one float32 grey band, NaN where invalid (nodata, alpha = 0, NaN).

    Single band: as is (a paletted band through its colour table). Three or more colour
    bands: luminance 0.299 R + 0.587 G + 0.114 B of the first three; alpha bands are masks.
    ValueError naming the file when it cannot be read (a truncated file opens, then fails).
    """
    try:
        return _read_grey(path)
    except RuntimeError as exc:
        raise ValueError(f"the image {str(path)!r} is not a raster that can be read ({str(exc).strip()}): "
                         "replace it (a partly copied file?) or leave it out.") from None


def _read_grey(path):
    ds = _open_image(path)
    bands = [ds.GetRasterBand(k + 1) for k in range(ds.RasterCount)]
    colour = [b for b in bands if b.GetColorInterpretation() != gdal.GCI_AlphaBand]
    if not colour:
        raise ValueError(f"the raster {path!r} has no image band.")
    if len(colour) >= 3:
        grey = np.zeros((ds.RasterYSize, ds.RasterXSize), np.float32)
        for w, b in zip((0.299, 0.587, 0.114), colour[:3]):
            grey += np.float32(w) * b.ReadAsArray().astype(np.float32)
        used = colour[:3]
    else:
        b = colour[0]
        a = b.ReadAsArray()
        ct = b.GetColorTable()
        if ct is not None and b.GetColorInterpretation() == gdal.GCI_PaletteIndex:
            lut = np.zeros(256 if a.dtype == np.uint8 else 65536, np.float32)
            for k in range(min(ct.GetCount(), lut.size)):
                r, g, bl, _ = ct.GetColorEntry(k)
                lut[k] = 0.299 * r + 0.587 * g + 0.114 * bl
            grey = lut[a.astype(np.int64)]
        else:
            grey = a.astype(np.float32)
        used = [b]
    valid = np.isfinite(grey)
    for b in used:
        if b.GetMaskFlags() != gdal.GMF_ALL_VALID:
            valid &= b.GetMaskBand().ReadAsArray() > 0
    return np.where(valid, grey, np.nan).astype(np.float32)


def _open_image(path):
    """The GDAL dataset of an image, or ValueError naming the file (GDAL raises RuntimeError on a
    file that is not a raster, such as a partly copied frame)."""
    try:
        ds = gdal.Open(str(path), gdal.GA_ReadOnly)
    except RuntimeError as exc:
        ds, why = None, str(exc).strip()
    else:
        why = "GDAL cannot open it"
    if ds is None:
        raise ValueError(f"the image {path!r} is not a raster that can be read ({why}): replace it (a partly "
                         "copied file?) or leave it out.")
    return ds


def _image_size(path):
    ds = _open_image(path)
    return ds.RasterXSize, ds.RasterYSize


def _stem(path):
    return Path(str(path)).stem


def _decimated(info, max_side=512):
    """A decimated read of a surface (for cheap checks before the work)."""
    rows, cols = info.shape
    step = max(1, int(math.ceil(max(rows, cols) / max_side)))
    b = info.dataset().GetRasterBand(info.band_index)
    a = b.ReadAsArray(0, 0, cols, rows, buf_xsize=max(1, cols // step), buf_ysize=max(1, rows // step),
                      resample_alg=gdal.GRIORA_NearestNeighbour)
    return grid.to_surface(a, info.nodata, info.z_to_m)


#: Largest angle from the nadir (degrees) at which a vertical frame sees: beyond the half-diagonal field of view
#: of mapping cameras (large-format 27-44 deg, a drone's wide-angle lens about 47 deg).
MAX_OFF_NADIR_DEG = 60.0


def check_centres_see_dem(info, centres):
    """ValueError when a camera centre ``(key, (X, Y, Z))`` lies so far from the DEM's extent that the
    DEM's nearest edge is more than :data:`MAX_OFF_NADIR_DEG` from its nadir (horizontal distance above
    ``tan(60 deg)`` times its height above the DEM's median): no vertical frame taken there sees the DEM,
    so the centres are in another CRS (degrees, another zone) or of another place. Before, centres in
    degrees 0.001 apart were called 'at the same place'."""
    gt, (rows, cols) = info.geotransform, info.shape
    xs = sorted((gt[0], gt[0] + cols * gt[1]))
    ys = sorted((gt[3], gt[3] + rows * gt[5]))
    z = _decimated(info)
    ground = float(np.nanmedian(z)) if np.isfinite(z).any() else 0.0
    for key, (x, y, zc) in centres:
        d = math.hypot(max(xs[0] - x, 0.0, x - xs[1]), max(ys[0] - y, 0.0, y - ys[1]))
        if d > math.tan(math.radians(MAX_OFF_NADIR_DEG)) * max(zc - ground, 0.0):
            crs = crs_label(info.crs_wkt)
            raise ValueError(f"{key} {(x, y, zc)} lies {d:.6g} m from the DEM (x {xs[0]:.6g} to {xs[1]:.6g}, y "
                             f"{ys[0]:.6g} to {ys[1]:.6g}), {zc - ground:.6g} m above its median height: no vertical "
                             f"frame taken there sees the DEM (more than {MAX_OFF_NADIR_DEG:g} deg from the nadir). "
                             f"Give the camera centres in the DEM's CRS ({crs}) and height datum.")


def check_parallax_range(info, base_m, height_m, max_dh_m):
    """ValueError when the parallax searched, ``max_dh_m * B / H`` (eq. 18; default ``max_dh_m``
    0.2 H), is wider than the DEM: no pair is matched over more than its own extent, and such a
    search (an absurd MAX_DH_M, or B / H from swapped or mistyped values) runs for hours."""
    dh = 0.2 * height_m if max_dh_m is None else max_dh_m
    p_m = dh * base_m / height_m
    extent_m = min(info.shape[0] * info.cell_size_m[1], info.shape[1] * info.cell_size_m[0])
    if p_m > extent_m:
        raise ValueError(f"the parallax searched, MAX_DH_M x B / H = {dh:.4g} x {base_m:.4g} / {height_m:.4g} = "
                         f"{p_m:.4g} m, is wider than the DEM ({extent_m:.4g} m across): check BASE_M (B) and "
                         f"HEIGHT_M (H) (B / H = {base_m / height_m:.3g}; frames overlap at B / H below about 1) "
                         f"or choose MAX_DH_M below {extent_m * height_m / base_m:.4g} m.")


def _dem_rect(info):
    gt = info.geotransform
    rows, cols = info.shape
    xs = sorted((gt[0], gt[0] + gt[1] * cols))
    ys = sorted((gt[3], gt[3] + gt[5] * rows))
    return QgsRectangle(xs[0], ys[0], xs[1], ys[1])


def _footprint(camera, z):
    """Ground polygon (QgsGeometry) of a frame on the plane of height ``z`` (border samples)."""
    io = camera.interior
    t = np.linspace(0.0, 1.0, 9)
    w, h = io.width - 0.5, io.height - 0.5
    cols = np.concatenate([-0.5 + t * (w + 0.5), np.full(9, w), -0.5 + t * (w + 0.5), np.full(9, -0.5)])
    rows = np.concatenate([np.full(9, -0.5), -0.5 + t * (h + 0.5), np.full(9, h), -0.5 + t * (h + 0.5)])
    with np.errstate(invalid="ignore", divide="ignore"):
        X, Y, _ = camera.pixel_to_world(cols, rows, z)
    ok = np.isfinite(X) & np.isfinite(Y)
    if ok.sum() < 3:
        return None
    pts = [QgsPointXY(float(x), float(y)) for x, y in zip(X[ok], Y[ok])]
    return QgsGeometry.fromMultiPointXY(pts).convexHull()


def parse_xyz(text, key):
    """``"X,Y,Z"`` (commas, semicolons or spaces) -> three floats, or ValueError naming ``key``."""
    parts = [p for p in str(text).replace(";", ",").replace(" ", ",").split(",") if p.strip()]
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        vals = []
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
        raise ValueError(f"{key} must be the camera centre as 'X,Y,Z' (three numbers, a dot as decimal "
                         f"separator, in the DEM's CRS and height datum); got {text!r}.")
    return tuple(vals)


def read_tie_points(path, names):
    """Tie-point CSV ``image,x,y,col,row`` -> per image ``(dem_xy (n, 2), pixel_colrow (n, 2))``.

    ``x, y``: ground coordinates in the DEM's CRS; ``col, row``: pixel of the same point in the
    image (the centre of the top-left pixel at 0, 0). Extensions of image names are dropped.
    """
    from ..core.orthophoto import read_table_rows
    rows = read_table_rows(path, "a header 'image,x,y,col,row' and one row per ground point and image")
    header = [h.lower() for h in rows[0]]
    name_col = next((c for c in ("image", "filename", "file", "name", "id") if c in header), None)
    missing = [c for c in ("x", "y", "col", "row") if c not in header]
    if name_col is None or missing:
        raise ValueError(f"{path}: header {rows[0]} lacks column(s) "
                         f"{(['image'] if name_col is None else []) + missing}; expected 'image,x,y,col,row'.")
    pts = {}
    for ln, r in enumerate(rows[1:], start=2):
        rec = dict(zip(header, r))
        if len(r) < len(header):
            raise ValueError(f"{path} line {ln}: {len(r)} values for {len(header)} columns.")
        try:
            v = [float(rec[c]) for c in ("x", "y", "col", "row")]
        except ValueError:
            raise ValueError(f"{path} line {ln}: x, y, col, row must be numbers; got "
                             f"{[rec[c] for c in ('x', 'y', 'col', 'row')]}.") from None
        if not all(math.isfinite(a) for a in v):
            raise ValueError(f"{path} line {ln}: x, y, col, row must be finite numbers.")
        pts.setdefault(_stem(rec[name_col]) if "." in rec[name_col] else rec[name_col], []).append(v)
    absent = [n for n in names if n not in pts]
    if absent:
        raise ValueError(f"TIE_POINTS: no tie points for image(s) {absent}; the file has "
                         f"{sorted(pts)}. Give at least four ground points per image (eq. 17).")
    few = [f"{n} ({len(pts[n])})" for n in names if len(pts[n]) < 4]
    if few:
        raise ValueError(f"TIE_POINTS: eq. 17 has 8 parameters; give at least four ground points per "
                         f"image: {', '.join(few)}.")
    out = []
    for n in names:
        a = np.asarray(pts[n], dtype=float)
        out.append((a[:, :2], a[:, 2:]))
    return out


# --------------------------------------------------------------------------- parameters
def _num(key, label, help_, typ=NUMBER_DOUBLE, default=None, optional=False,
         advanced=False, **kw):
    p = QgsProcessingParameterNumber(key, tr(label), typ, default, optional, **kw)
    return with_help(p, help_, advanced)


class OrthoAlgorithm(BaseAlgorithm):
    """Shared parameters and outputs of the two orthophoto algorithms."""

    GROUP, GROUP_NAME = "orthophoto", "Orthophoto refinement"
    TAGS = ("orthophoto", "orthorectification", "DEM", "DTM", "DSM", "ground", "terrain", "image matching",
            "parallax", "stereo", "photogrammetry", "aerial images", "refinement")
    DEM = "DEM"
    BASE_M, HEIGHT_M, BASE_DIRECTION_DEG = "BASE_M", "HEIGHT_M", "BASE_DIRECTION_DEG"
    WINDOW_CELLS, MIN_CORRELATION, HEIGHT_THRESHOLD_M = "WINDOW_CELLS", "MIN_CORRELATION", "HEIGHT_THRESHOLD_M"
    MAX_DH_M, OBJECT_SIZE_M = "MAX_DH_M", "OBJECT_SIZE_M"
    OUTPUT_DEM, OUTPUT_DH, OUTPUT_QUALITY, OUTPUT_MASK = "OUTPUT_DEM", "OUTPUT_DH", "OUTPUT_QUALITY", "OUTPUT_MASK"

    def _geometry_params(self, optional_note=""):
        return [
            _num(self.BASE_M, "Base B between the exposures (m)" + optional_note,
                 "Distance B between the projection centres of the two exposures (metres), for vertical "
                 "frames when the camera centres are not given; B > 0.", optional=True),
            _num(self.HEIGHT_M, "Flying height H above the ground (m)" + optional_note,
                 "Height H of the cameras above the ground (metres), for vertical frames; H > 0. "
                 "With B: dh = dx H / B (Luong Chinh Ke 2002, eq. 18).", optional=True),
            _num(self.BASE_DIRECTION_DEG, "Base direction (degrees from +X, counter-clockwise)",
                 "Direction from the first exposure to the second, in degrees counter-clockwise from "
                 "the +X axis (east): 0 = along +X, 90 = along +Y (north), 180 = along -X.",
                 default=0.0, minValue=-360.0, maxValue=360.0)]

    def _matching_params(self):
        return [
            _num(self.WINDOW_CELLS, "Correlation window (cells, odd)",
                 "Side of the normalised cross-correlation window in DEM cells (odd, >= 3). Larger: "
                 "fewer blunders on weak texture, blurrier object edges.",
                 NUMBER_INTEGER, 7, minValue=3, maxValue=51),
            _num(self.MIN_CORRELATION, "Minimum correlation",
                 "Matches whose peak normalised cross-correlation is below this are rejected (0..1).",
                 default=0.6, minValue=0.0, maxValue=1.0),
            _num(self.HEIGHT_THRESHOLD_M, "Object height threshold (m) [empty: from the data]",
                 "A cell is an object when dh exceeds its ground trend by this (metres). Empty: 3 x the "
                 "larger of the expected precision (0.2 cell of parallax converted to height) and the "
                 "robust spread of dh about its trend on the ground.", optional=True, minValue=0.0),
            _num(self.MAX_DH_M, "Largest height correction searched (m) [empty: 0.2 x H]",
                 "Largest |dh| the matching searches for (metres); empty: a fifth of the camera height "
                 "above the DEM. orthorefine searches this range first, then within the 99th percentile "
                 "of the last correction, and moves no cell by more than this in total (nothing larger "
                 "was measured).", optional=True, minValue=0.0, advanced=True),
            _num(self.OBJECT_SIZE_M, "Largest object width (m)",
                 "The object mask compares dh with its ground trend (the median of the ground cells over "
                 "about this width), so smooth DEM errors are not objects; 0 compares dh with 0.",
                 default=40.0, minValue=0.0, advanced=True)]

    def _raster_outputs(self, dem_label):
        self.addParameter(with_help(QgsProcessingParameterRasterDestination(self.OUTPUT_DEM, tr(dem_label)),
                                    "Float32 DEM on the input DEM's grid and CRS: the input plus the "
                                    "height corrections (the input's nodata kept)."))
        self.addParameter(with_help(QgsProcessingParameterRasterDestination(
            self.OUTPUT_DH, tr("Height correction dh"), optional=True, createByDefault=True), DH_HELP))
        self.addParameter(with_help(QgsProcessingParameterRasterDestination(
            self.OUTPUT_QUALITY, tr("Match quality (correlation)"), optional=True, createByDefault=True),
            QUALITY_HELP))
        self.addParameter(with_help(QgsProcessingParameterRasterDestination(
            self.OUTPUT_MASK, tr("Object mask"), optional=True, createByDefault=True), ORTHO_MASK_HELP))

    def _matching_values(self, parameters, context):
        window = self.parameterAsInt(parameters, self.WINDOW_CELLS, context)
        if window < 3 or window % 2 == 0:
            raise ValueError(f"WINDOW_CELLS must be an odd number of cells >= 3; got {window}.")
        min_corr = check_min_corr(self.parameterAsDouble(parameters, self.MIN_CORRELATION, context),
                                  "MIN_CORRELATION")
        max_dh = _optional_number(self, parameters, self.MAX_DH_M, context)
        if max_dh is not None and not max_dh > 0:
            raise ValueError(f"MAX_DH_M must be > 0 m; got {max_dh:g}: a search of 0 m measures no height "
                             "correction. Leave it empty for the default (a fifth of the flying height H) or give "
                             "the largest correction expected, in metres.")
        return dict(window=window,
                    min_corr=min_corr,
                    height_threshold_m=_positive_or_none(self, parameters, self.HEIGHT_THRESHOLD_M, context),
                    max_dh_m=_positive_or_none(self, parameters, self.MAX_DH_M, context),
                    object_size_m=self.parameterAsDouble(parameters, self.OBJECT_SIZE_M, context))

    def _base_height(self, parameters, context):
        """(B, H, direction) or None when neither is given; ValueError for bad values."""
        B = _optional_number(self, parameters, self.BASE_M, context)
        H = _optional_number(self, parameters, self.HEIGHT_M, context)
        if B is None and H is None:
            return None
        if B is None or H is None:
            raise ValueError("give both BASE_M (B) and HEIGHT_M (H), or neither.")
        if not B > 0:
            raise ValueError(f"BASE_M: the base B must be > 0 m; got {B:g}. Two exposures from one place "
                             "give no parallax; give the distance between the camera centres.")
        if not H > 0:
            raise ValueError(f"HEIGHT_M: the flying height H must be > 0 m above the ground; got {H:g}.")
        ang = math.radians(self.parameterAsDouble(parameters, self.BASE_DIRECTION_DEG, context))
        return B, H, (math.cos(ang), math.sin(ang))

    def _dem(self, parameters, context):
        """The DEM, checked (one band, metric), and the windows chosen checked against it."""
        layer = self.parameterAsRasterLayer(parameters, self.DEM, context)
        ok, msg, info = check_dsm(layer, None, self.DEM)
        if not ok:
            raise ValueError(msg if msg.startswith(self.DEM) else f"DEM: {msg}")
        gt = info.geotransform
        if not (gt[1] > 0 and gt[5] < 0):      # the frames' geometry is worked on north-up grids
            raise ValueError(f"DEM: the raster {info.path!r} is stored {'bottom-up' if gt[5] > 0 else 'right to left'} "
                             f"(geotransform cell {gt[1]:g} x {gt[5]:g}): the orthophoto tools work on north-up "
                             "grids. Warp it (and the orthophotos) to north-up first: gdalwarp in.tif out.tif "
                             "writes a north-up raster.")
        _check_metric(info, "The DEM")
        chosen, defaults = {}, {}
        for k in (self.WINDOW_CELLS, self.OBJECT_SIZE_M):
            d = self.parameterDefinition(k)
            if parameters.get(k) is not None:
                whole = d.dataType() == NUMBER_INTEGER
                chosen[k] = (self.parameterAsInt if whole else self.parameterAsDouble)(parameters, k, context)
                defaults[k] = d.defaultValue()
        ok, msg = check_window_sizes(self, chosen, defaults, info)
        if not ok:
            raise ValueError(msg)
        return info

    def _write(self, info, parameters, context, dem, dh, quality, mask, feedback=None):
        """Write the four rasters on the DEM's grid; returns the outputs dict."""
        paths = {"dem": self.parameterAsOutputLayer(parameters, self.OUTPUT_DEM, context)}
        for key, pk in (("dh", self.OUTPUT_DH), ("quality", self.OUTPUT_QUALITY), ("mask", self.OUTPUT_MASK)):
            if parameters.get(pk):
                paths[key] = self.parameterAsOutputLayer(parameters, pk, context)
        nd = info.nodata
        nodata = float("nan") if nd is None or not np.isfinite(np.float32(nd)) else float(np.float32(nd))
        dem_out = np.where(np.isfinite(dem), dem, np.float32(nodata)).astype(np.float32)
        try:   # a write that fails (a full disk): GDAL's reason naming the output, not a traceback
            with output_options(self, parameters, context, feedback), grid.OutputSet(info) as out:
                out.add("dem", paths["dem"], "Float32", nodata=nodata, descriptions=["refined DEM"])
                out.write("dem", dem_out)
                if "dh" in paths:
                    out.add("dh", paths["dh"], "Float32", nodata=float("nan"), descriptions=["dh (m)"])
                    out.write("dh", dh.astype(np.float32))
                if "quality" in paths:
                    out.add("quality", paths["quality"], "Float32", nodata=float("nan"),
                            descriptions=["peak NCC"])
                    out.write("quality", quality.astype(np.float32))
                if "mask" in paths:
                    out.add("mask", paths["mask"], "Byte", nodata=NODATA, mask_style=True, descriptions=["mask"])
                    out.write("mask", mask.astype(np.uint8))
                out.commit()
        except ValueError as exc:
            raise QgsProcessingException(str(exc)) from None
        return {f"OUTPUT_{k.upper()}": v for k, v in paths.items()}

    def _log_info(self, info, feedback, skip=()):
        if info.get("warning"):
            _warn(feedback, tr("Warning: {}.").format(info["warning"]))
        feedback.pushInfo(tr("Values used and statistics:"))
        for k, v in info.items():
            if k in skip or k == "warning":
                continue
            if isinstance(v, dict):
                v = ", ".join(f"{kk} {100 * vv:.1f} %" if isinstance(vv, float) else f"{kk} {vv}"
                              for kk, vv in v.items())
            feedback.pushInfo(f"  {k} = {_fmt(v)}")

    def checkParameterValues(self, parameters, context):  # noqa: N802
        ok, msg = super().checkParameterValues(parameters, context)
        if not ok:
            return ok, msg
        try:
            self._inputs(parameters, context)
        except (ValueError, QgsProcessingException) as exc:
            return False, str(exc)
        return True, ""


# --------------------------------------------------------------------------- orthoparallax
class OrthoParallaxAlgorithm(OrthoAlgorithm):
    """``bareearth:orthoparallax``: DEM error from the residual parallax of two orthophotos."""

    ORTHO_A, ORTHO_B, CAMERA_A, CAMERA_B = "ORTHO_A", "ORTHO_B", "CAMERA_A", "CAMERA_B"

    def name(self):
        return "orthoparallax"

    def displayName(self):  # noqa: N802
        return tr("DEM correction from the parallax of two orthophotos")

    def shortHelpString(self):  # noqa: N802
        return tr(
            "<p>Two orthophotos of overlapping frames made with the same DEM agree where the DEM is right; "
            "where it is wrong by dh (a building or tree the DEM lacks, a matching blunder) they are "
            "displaced by a residual parallax along the base. This algorithm matches the orthophotos "
            "(normalised cross-correlation along the base, left-right check, least-squares sub-pixel) and "
            "converts the parallax to height: dh = dx H / B for vertical frames (Luong Chinh Ke 2002, "
            "section 2.3, eq. 18), or dh = p . (v_b - v_a) / |v_b - v_a|^2 with the camera centres "
            "(any geometry; the measurement is then moved to its ground point). One pass; for frames "
            "with their orientation use <i>orthorefine</i>, which iterates (Norvelle 1995).</p>"
            "<h3>Parameters</h3><ul>"
            "<li><b>ORTHO_A</b>, <b>ORTHO_B</b>: the two orthophotos, on the DEM's grid (same cells and "
            "geotransform); one band, or RGB(A) converted to grey (alpha and nodata are masks).</li>"
            "<li><b>DEM</b>: the DEM both orthophotos were made with (single band, projected CRS in metres).</li>"
            "<li>Geometry, either <b>CAMERA_A</b> and <b>CAMERA_B</b>: projection centres 'X,Y,Z' in the "
            "DEM's CRS and height datum; or <b>BASE_M</b> (B) and <b>HEIGHT_M</b> (H) for vertical frames, "
            "with <b>BASE_DIRECTION_DEG</b> (from A to B, degrees counter-clockwise from +X; 0 = +X).</li>"
            "<li><b>WINDOW_CELLS</b> (odd, default 7), <b>MIN_CORRELATION</b> (default 0.6): matching.</li>"
            "<li><b>HEIGHT_THRESHOLD_M</b>: object threshold on dh; empty: 3 x the larger of the expected "
            "precision (0.2 cell of parallax in height) and the robust spread of dh.</li>"
            "<li><b>MAX_DH_M</b>, <b>OBJECT_SIZE_M</b> (advanced): search range (default 0.2 H) and the "
            "largest object width for the ground trend of the mask (default 40 m).</li></ul>"
            "<h3>Outputs</h3><ul><li><b>OUTPUT_DEM</b>: the DEM plus the trusted dh (gaps of a few cells "
            "interpolated; the input DEM where nothing was measured or the orthophotos do not overlap). Only "
            "matches with a distinct correlation peak, left-right agreement and texture enough against the "
            "noise are trusted; when fewer than 10 % of the cells are, the log says why.</li>"
            "<li><b>OUTPUT_DH</b>: {}</li><li><b>OUTPUT_QUALITY</b>: {}</li>"
            "<li><b>OUTPUT_MASK</b>: {}</li></ul>").format(tr(DH_HELP), tr(QUALITY_HELP), tr(ORTHO_MASK_HELP))

    def initAlgorithm(self, config=None):  # noqa: N802
        for key, label in ((self.ORTHO_A, "Orthophoto A"), (self.ORTHO_B, "Orthophoto B")):
            self.addParameter(with_help(QgsProcessingParameterRasterLayer(key, tr(label)),
                                        "Orthophoto on the DEM's grid made with that DEM: one band, or "
                                        "RGB(A) converted to grey; nodata and alpha mark unseen cells."))
        self.addParameter(with_help(QgsProcessingParameterRasterLayer(self.DEM, tr("DEM used for both orthophotos")),
                                    "Single-band DEM (metres, projected CRS) the orthophotos were made with."))
        for key, label in ((self.CAMERA_A, "Camera centre of A 'X,Y,Z' [or B and H]"),
                           (self.CAMERA_B, "Camera centre of B 'X,Y,Z' [or B and H]")):
            self.addParameter(with_help(QgsProcessingParameterString(key, tr(label), optional=True),
                                        "Projection centre of the frame the orthophoto was made from, as "
                                        "'X,Y,Z' (dot decimals) in the DEM's CRS and height datum. Give both "
                                        "centres, or BASE_M and HEIGHT_M instead. A centre from which the DEM "
                                        "lies more than 60 deg from the nadir (beyond any vertical frame's view: "
                                        "another CRS, another place) is refused."))
        for p in self._geometry_params(" [or camera centres]"):
            self.addParameter(p)
        for p in self._matching_params():
            self.addParameter(p)
        self._raster_outputs("Corrected DEM")
        for p in format_params():
            self.addParameter(p)

    def _inputs(self, parameters, context):
        info = self._dem(parameters, context)
        orthos = []
        for key in (self.ORTHO_A, self.ORTHO_B):
            layer = self.parameterAsRasterLayer(parameters, key, context)
            if layer is None:
                raise ValueError(f"{key}: no orthophoto was given.")
            path = raster_path(layer)
            oi = _open_grid(path, key)
            if other_crs(info, oi, heights=False) is not None:        # grey values: the horizontal CRS counts
                raise ValueError(grid_mismatch_message(info, oi, f"{key} ({path})", of=f"the DEM ({info.path})",
                                                       heights=False))
            if not same_grid(info, oi, heights=False):
                raise ValueError(f"{key} ({path}) is not on the DEM's grid: {key} has {_grid_text(oi)}, the "
                                 f"DEM ({info.path}) has {_grid_text(info)}. Make both orthophotos on the "
                                 "DEM's grid (or resample them onto it: gdalwarp -te/-tr, Raster > Align rasters).")
            orthos.append(path)
        if grid.file_identity(orthos[0]) == grid.file_identity(orthos[1]):      # under any name (a link)
            raise ValueError(f"ORTHO_A and ORTHO_B are one file ({orthos[0]}): an orthophoto matched with itself "
                             "has no parallax. Give the orthophotos of two different frames.")
        ca = (self.parameterAsString(parameters, self.CAMERA_A, context) or "").strip()
        cb = (self.parameterAsString(parameters, self.CAMERA_B, context) or "").strip()
        bh = self._base_height(parameters, context)
        geometry = {}
        if ca or cb:
            if not (ca and cb):
                raise ValueError("give both camera centres CAMERA_A and CAMERA_B ('X,Y,Z'), or BASE_M and "
                                 "HEIGHT_M instead.")
            if bh is not None:
                raise ValueError("give the geometry once: either CAMERA_A and CAMERA_B, or BASE_M and "
                                 "HEIGHT_M, not both.")
            A, B = parse_xyz(ca, self.CAMERA_A), parse_xyz(cb, self.CAMERA_B)
            check_centres_see_dem(info, ((self.CAMERA_A, A), (self.CAMERA_B, B)))
            if math.dist(A, B) < 1e-6 * max(1.0, abs(A[2])):
                raise ValueError(f"CAMERA_A and CAMERA_B are at the same place {A} (base B = 0): no parallax. "
                                 "Give the centres of two different exposures.")
            geometry = dict(centres=(A, B))
        elif bh is not None:
            geometry = dict(base_m=bh[0], height_m=bh[1], base_direction=bh[2])
        else:
            raise ValueError("give the geometry of the pair: CAMERA_A and CAMERA_B ('X,Y,Z'), or BASE_M (B) "
                             "and HEIGHT_M (H) for vertical frames.")
        opts = self._matching_values(parameters, context)
        if bh is not None:
            check_parallax_range(info, bh[0], bh[1], opts["max_dh_m"])
        else:
            z = _decimated(info)
            if np.isfinite(z).any():
                h = 0.5 * (A[2] + B[2]) - float(np.nanmedian(z))
                if h > 0:
                    check_parallax_range(info, math.dist(A[:2], B[:2]), h, opts["max_dh_m"])
        return info, orthos, geometry, opts

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        from ..core.orthophoto import orthoparallax
        try:
            info, (pa, pb), geometry, opts = self._inputs(parameters, context)
            dem = info.read()
            a, b = read_grey(pa), read_grey(pb)
            va, vb = np.isfinite(a) & np.isfinite(dem), np.isfinite(b) & np.isfinite(dem)
            if not (va & vb).any():
                raise ValueError(f"the orthophotos do not overlap: no cell is valid in both ORTHO_A ({pa}, "
                                 f"{int(va.sum())} valid cells on the DEM) and ORTHO_B ({pb}, {int(vb.sum())}). "
                                 "Use orthophotos of two overlapping frames.")
            feedback.pushInfo(tr("DEM {}: {}; {} cells seen in both orthophotos.").format(
                info.path, _grid_text(info), int((va & vb).sum())))
            for w in info.warnings:
                _warn(feedback, w)
            r = orthoparallax(a, b, dem, info.geotransform, progress=progress_callback(feedback),
                              **geometry, **opts)
        except Cancelled:
            feedback.reportError(tr("Cancelled: no output was written."))
            return {}
        except ValueError as exc:
            raise QgsProcessingException(str(exc)) from None
        dem_out = np.where(np.isfinite(dem), r.dem, np.nan)
        outputs = self._write(info, parameters, context, dem_out, r.dh, r.quality, r.mask, feedback)
        self._log_info(r.info, feedback, skip=("crop",))
        reversed_, low, obj = order_reversed(r.mask, opts["window"])
        if reversed_:
            _warn(feedback, tr("{} cells lie below the DEM (low) and only {} above it (objects): objects stand "
                               "above the ground, so the pair may be given in the wrong order. Check that "
                               "CAMERA_A is the centre of ORTHO_A's frame and CAMERA_B of ORTHO_B's (with BASE_M "
                               "and HEIGHT_M: that BASE_DIRECTION_DEG points from A to B).").format(low, obj))
        feedback.setProgress(100)
        return outputs


# --------------------------------------------------------------------------- orthorefine
class OrthoRefineAlgorithm(OrthoAlgorithm):
    """``bareearth:orthorefine``: iterative orthophoto refinement of a DEM (Norvelle 1995)."""

    IMAGES, IMAGE_FOLDER, EXTERIOR, INTERIOR, TIE_POINTS = ("IMAGES", "IMAGE_FOLDER", "EXTERIOR", "INTERIOR",
                                                            "TIE_POINTS")
    MAX_ITERATIONS, TOLERANCE_M, RELAXATION = "MAX_ITERATIONS", "TOLERANCE_M", "RELAXATION"
    CROSS_CHECK = "CROSS_CHECK"
    NOT_ROUGHER = "NOT_ROUGHER"
    OUTPUT_ORTHO_FOLDER, OUTPUT_TABLE = "OUTPUT_ORTHO_FOLDER", "OUTPUT_TABLE"
    TABLE_COLUMNS = ("iteration", "rms_correction_m", "matched_share", "pairs", "rms_parallax_m", "agreement",
                     "status", "mean_corr", "detail_single_pair", "smoothness_mu", "roughness_m")

    def name(self):
        return "orthorefine"

    def displayName(self):  # noqa: N802
        return tr("Refine a DEM with orthophotos of oriented frames")

    def shortHelpString(self):  # noqa: N802
        return tr(
            "<p>Iterative orthophoto refinement of a DEM (Norvelle 1995; Luong Chinh Ke 2002, section 2.3). "
            "Each iteration orthorectifies every frame onto the current DEM (collinearity equations with "
            "Brown distortion, hidden cells masked), matches the orthophotos of every overlapping pair "
            "along its base, keeps the trusted matches (peak correlation, left-right agreement, a distinct "
            "peak, texture enough against the noise, confirmed by the neighbours), converts the residual "
            "parallax to height corrections, merges the pairs (weighted by correlation, outliers dropped), "
            "and adds RELAXATION x the correction to the DEM: its smooth part (a Gaussian mean over about "
            "the window), and its detail where it stands out of the noise and two pairs agree on it (one "
            "pair cannot tell a detail from its own blunder), fading out over half the window plus one cell "
            "around it. With NOT_ROUGHER (default) the smooth part may not make the DEM rougher (the "
            "Laplacian's spread over the cells seen by two frames): where it would, it is replaced by the "
            "nearest smooth part that does not (smoothness_mu in the table; 0: unchanged); confirmed detail "
            "may. No cell moves by more than "
            "MAX_DH_M in total, nor by more than the trusted "
            "corrections around it support (supported_max_m in the log). Each update is checked by the next "
            "measurement: an update that makes the pairs agree worse is undone and the iteration stops; it "
            "also stops when the agreement improves by less than 5 %, one checked update after the pairs' "
            "residual parallax falls within the matching noise (0.2 cell), when the RMS correction is below "
            "TOLERANCE_M, or after MAX_ITERATIONS updates. When fewer than 10 % of the cells seen by two "
            "frames can be matched with confidence (weak texture, noise), the log says why and the DEM is "
            "kept; cells far from any trusted match keep their height. Without orientation, "
            "TIE_POINTS registers orthophotos to the DEM by the 8-parameter bilinear transformation "
            "(eq. 17) and makes one pass with eq. 18 (B and H).</p>"
            "<h3>Parameters</h3><ul>"
            "<li><b>DEM</b>: starting DEM (single band, projected CRS in metres, the cameras' CRS and datum).</li>"
            "<li><b>IMAGES</b> (raster layers) or <b>IMAGE_FOLDER</b> (every image file in it): the frames "
            "(one band or RGB, converted to grey), two or more. Matched to the CSV by file name without "
            "extension; files of IMAGE_FOLDER that EXTERIOR does not name (a DEM beside the frames) are "
            "skipped, and the log lists them.</li>"
            "<li><b>EXTERIOR</b>: CSV (comma, tab or space separated, header) with one row per image: "
            "<code>filename,x,y,z,omega,phi,kappa</code> (orthority's xyz_opk format; an optional "
            "<code>camera</code> column names the interior orientation). x, y, z: projection centre in "
            "the DEM's CRS. {}</li>"
            "<li><b>INTERIOR</b>: interior orientation, orthority YAML <code>{{camera id: {{type: pinhole|brown, "
            "im_size: [w, h], focal_len, sensor_size: [w, h], cx, cy, k1, k2, k3, p1, p2}}}}</code> "
            "(focal length in the units of the sensor size, or normalised by the larger image side without "
            "it; cx, cy principal-point offsets normalised by the larger side; Brown k1 k2 k3 radial, p1 p2 "
            "tangential), or an OpenSfM <code>reconstruction.json</code> (its cameras).</li>"
            "<li><b>TIE_POINTS</b> (instead of EXTERIOR/INTERIOR): CSV <code>image,x,y,col,row</code>, at "
            "least four ground points per image: x, y in the DEM's CRS, col, row the pixel in the image "
            "(top-left pixel centre = 0, 0); needs <b>BASE_M</b> (B between consecutive images, in the "
            "order given), <b>HEIGHT_M</b> (H) and <b>BASE_DIRECTION_DEG</b>.</li>"
            "<li><b>MAX_ITERATIONS</b> (default 6), <b>TOLERANCE_M</b> (empty: half the expected height "
            "precision), <b>RELAXATION</b> (advanced, default 1: the whole correction), <b>CROSS_CHECK</b> "
            "(advanced, default off: with pairs of two or more base directions, keep a correction only where "
            "the pairs of different directions agree within 3 x their combined precision, their shared part "
            "where they disagree, nothing one direction alone measured; the log gives the largest move they "
            "confirm), <b>NOT_ROUGHER</b> (advanced, default on: the smooth part may not roughen the DEM; off "
            "for a start smoother than the terrain), <b>WINDOW_CELLS</b>, "
            "<b>MIN_CORRELATION</b>, <b>HEIGHT_THRESHOLD_M</b>, <b>MAX_DH_M</b> (advanced, empty: 0.2 H; "
            "also the largest total move of a cell), <b>OBJECT_SIZE_M</b> (advanced, 40): as in "
            "orthoparallax.</li></ul>"
            "<h3>Outputs</h3><ul><li><b>OUTPUT_DEM</b>: the refined DEM.</li>"
            "<li><b>OUTPUT_DH</b>: total correction, refined minus input (m), NaN where fewer than two frames "
            "see.</li><li><b>OUTPUT_QUALITY</b>: {}</li><li><b>OUTPUT_MASK</b>: {}</li>"
            "<li><b>OUTPUT_ORTHO_FOLDER</b>: the orthophotos of the last iteration, one Float32 GeoTIFF "
            "'&lt;image&gt;_ortho.tif' per image on the DEM's grid.</li>"
            "<li><b>OUTPUT_TABLE</b>: CSV, one row per measurement: RMS correction (m), share of the cells seen "
            "by two frames with a trusted match, pairs, RMS residual parallax (m), agreement (RMS parallax on "
            "the cells matched now and before, over its value before: below 1 the last update helped), status "
            "(applied, undone, measured), mean correlation, cells of detail left out for lack of a second "
            "pair, the smoothness multiplier and the roughness after the update (Laplacian sd, m); also in "
            "the log.</li></ul>").format(
                tr(OPK_HELP), tr(QUALITY_HELP), tr(ORTHO_MASK_HELP))

    def initAlgorithm(self, config=None):  # noqa: N802
        self.addParameter(with_help(QgsProcessingParameterRasterLayer(self.DEM, tr("Starting DEM")),
                                    "Single-band DEM (metres, projected CRS; the camera coordinates' CRS and "
                                    "height datum) to refine."))
        self.addParameter(with_help(QgsProcessingParameterMultipleLayers(
            self.IMAGES, tr("Frame images [or IMAGE_FOLDER]"), SOURCE_RASTER, None, True),
            "The frames (one band, or RGB converted to grey), two or more; each matched to its EXTERIOR "
            "row (or TIE_POINTS) by file name without extension."))
        self.addParameter(with_help(QgsProcessingParameterFile(
            self.IMAGE_FOLDER, tr("Folder of frame images [or IMAGES]"), FILE_FOLDER,
            optional=True),
            "A folder whose image files (" + ", ".join(IMAGE_EXTENSIONS) + ") are the frames, in name order."))
        self.addParameter(with_help(QgsProcessingParameterFile(
            self.EXTERIOR, tr("Exterior orientation CSV (filename,x,y,z,omega,phi,kappa)"),
            FILE_FILE, "", None, True, "CSV / text (*.csv *.txt);;All files (*.*)"),
            "One row per image: filename,x,y,z,omega,phi,kappa (header; comma, tab or space separated; "
            "optional 'camera' column naming each row's INTERIOR camera; a row naming a camera the INTERIOR "
            "file does not hold is refused). x, y, z in the DEM's CRS. " + OPK_HELP))
        self.addParameter(with_help(QgsProcessingParameterFile(
            self.INTERIOR, tr("Interior orientation (orthority YAML or OpenSfM reconstruction.json)"),
            FILE_FILE, "", None, True,
            "Interior orientation (*.yaml *.yml *.json);;All files (*.*)"),
            "Camera id -> type (pinhole/brown), im_size [w, h], focal_len (with sensor_size [w, h] in the same "
            "units, else normalised by the larger image side), cx, cy, k1, k2, k3, p1, p2; or an OpenSfM "
            "reconstruction.json."))
        self.addParameter(with_help(QgsProcessingParameterFile(
            self.TIE_POINTS, tr("Tie points CSV (image,x,y,col,row) [no orientation]"),
            FILE_FILE, "", None, True, "CSV / text (*.csv *.txt);;All files (*.*)"),
            "Without EXTERIOR/INTERIOR: at least four ground points per image, x, y in the DEM's CRS and "
            "col, row the pixel in the image (top-left pixel centre 0, 0), for the 8-parameter bilinear "
            "registration (eq. 17). Needs BASE_M and HEIGHT_M."))
        for p in self._geometry_params(" [tie points only]"):
            self.addParameter(p)
        self.addParameter(_num(self.MAX_ITERATIONS, "Maximum iterations",
                               "Largest number of orthorectify-match-correct iterations.",
                               NUMBER_INTEGER, 6, minValue=1, maxValue=50))
        self.addParameter(_num(self.TOLERANCE_M, "Stop tolerance (m) [empty: from the data]",
                               "Stop when the RMS correction of an iteration is below this (metres); empty: "
                               "half the expected height precision of the pairs.", optional=True, minValue=0.0))
        self.addParameter(_num(self.RELAXATION, "Share of each correction applied (relaxation)",
                               "Each iteration adds this share of the measured correction to the DEM, in (0, 1]. "
                               "Default 1: the whole correction (one iteration gives full heights); below 1 damps "
                               "each step. Whatever the value, an update that makes the pairs agree worse is "
                               "undone and the iteration stops.", default=1.0, minValue=0.01, maxValue=1.0,
                               advanced=True))
        cross = QgsProcessingParameterBoolean(self.CROSS_CHECK, tr("Keep only corrections independent pairs confirm"),
                                              defaultValue=CROSS_CHECK_DEFAULT)
        self.addParameter(with_help(
            cross, "With pairs of two or more base directions (frames in several strips): a cell's correction is "
                   "kept where the pairs of different directions agree within 3 x their combined precision, "
                   "their shared part where they disagree, and a correction one direction alone measured is "
                   "not taken (the cell keeps its height). Off by default: only the cells seen by two "
                   "directions (the strips' side lap) are refined then. With one base direction nothing can "
                   "be cross-checked and the log says so.", advanced=True))
        smooth = QgsProcessingParameterBoolean(self.NOT_ROUGHER, tr("The smooth correction may not roughen the DEM"),
                                               defaultValue=NOT_ROUGHER_DEFAULT)
        self.addParameter(with_help(
            smooth, "On by default: where an update's smooth part (the part no two pairs confirm as detail) "
                    "would make the DEM rougher (the spread of its Laplacian over the cells seen by two "
                    "frames), it is replaced by the nearest smooth part that does not (a smoothness prior); "
                    "confirmed detail is applied as measured. Off: a start smoother than the terrain (a blurred "
                    "DSM) gains the relief the pairs measure at the smooth part's scale too.", advanced=True))
        for p in self._matching_params():
            self.addParameter(p)
        self._raster_outputs("Refined DEM")
        self.addParameter(with_help(QgsProcessingParameterFolderDestination(
            self.OUTPUT_ORTHO_FOLDER, tr("Folder for the last orthophotos"), optional=True, createByDefault=False),
            "One Float32 GeoTIFF '<image>_ortho.tif' per image on the DEM's grid: the orthophotos of the "
            "last iteration (grey)."))
        self.addParameter(with_help(QgsProcessingParameterFileDestination(
            self.OUTPUT_TABLE, tr("Iteration table (CSV)"), "CSV files (*.csv)", optional=True,
            createByDefault=True),
            "One row per measurement: iteration, rms_correction_m, matched_share, pairs, rms_parallax_m, "
            "agreement, status, mean_corr, detail_single_pair (cells of significant detail left out because "
            "only one pair measured them)."))
        for p in format_params():
            self.addParameter(p)
        for key, label in (("ITERATIONS", "Updates applied"), ("RMS_CORRECTION_M", "Last RMS correction (m)")):
            self.addOutput(QgsProcessingOutputNumber(key, tr(label)))

    def checkOutputs(self, parameters, context):  # noqa: N802
        """The checks of every algorithm, and: no orthophoto written into OUTPUT_ORTHO_FOLDER
        (``<image>_ortho.tif``) replaces an input (the DEM, a frame) or another output."""
        ok, msg = super().checkOutputs(parameters, context)
        folder = destination_path(parameters, self.OUTPUT_ORTHO_FOLDER)
        if not ok or folder is None:
            return ok, msg
        try:
            paths, names = self._images(parameters, context)
        except (ValueError, QgsProcessingException):
            return True, ""                # refused with its reason by the checks of the inputs
        taken = {grid.file_identity(p): label_of(d) for d, p in self.inputPaths(parameters, context)}
        taken.update({grid.file_identity(p): label_of(self.parameterDefinition(self.IMAGES)) for p in paths})
        for d in self.destinationParameterDefinitions():
            out = destination_path(parameters, d.name())
            if out is not None and d.name() != self.OUTPUT_ORTHO_FOLDER:
                taken.setdefault(grid.file_identity(out), label_of(d))
        for n in names:
            target = os.path.join(folder, f"{n}_ortho.tif")
            hit = taken.get(grid.file_identity(target))
            if hit is not None:
                return False, tr("{}: the orthophoto of {} would be written as {}, a file of {}: choose another "
                                 "folder.").format(label_of(self.parameterDefinition(self.OUTPUT_ORTHO_FOLDER)),
                                                   n, target, hit)
        return True, ""

    # -- inputs -------------------------------------------------------------------------
    def _images(self, parameters, context):
        layers = (self.parameterAsLayerList(parameters, self.IMAGES, context)
                  if parameters.get(self.IMAGES) else [])
        folder = (self.parameterAsFile(parameters, self.IMAGE_FOLDER, context)
                  if parameters.get(self.IMAGE_FOLDER) else "")
        if layers and folder:
            raise ValueError("give the images once: IMAGES or IMAGE_FOLDER, not both.")
        if folder:
            if not os.path.isdir(folder):
                raise ValueError(f"IMAGE_FOLDER {folder!r} is not a folder.")
            paths = sorted(str(p) for p in Path(folder).iterdir()
                           if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS)
        else:
            paths = [raster_path(lay) for lay in layers]
        if len(paths) < 2:
            raise ValueError(f"orthorefine needs two or more overlapping images; got {len(paths)}"
                             + (f" in {folder}" if folder else "") + ".")
        names = [_stem(p) for p in paths]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"image name(s) {dup} appear twice; images are matched to the CSV by name.")
        return paths, names

    def _inputs(self, parameters, context):
        from ..core.orthophoto import read_cameras, read_opk_csv
        info = self._dem(parameters, context)
        paths, names = self._images(parameters, context)
        exterior = self.parameterAsFile(parameters, self.EXTERIOR, context) if parameters.get(self.EXTERIOR) else ""
        interior = self.parameterAsFile(parameters, self.INTERIOR, context) if parameters.get(self.INTERIOR) else ""
        ties = self.parameterAsFile(parameters, self.TIE_POINTS, context) if parameters.get(self.TIE_POINTS) else ""
        opts = self._matching_values(parameters, context)
        opts["max_iterations"] = self.parameterAsInt(parameters, self.MAX_ITERATIONS, context)
        opts["tolerance_m"] = _positive_or_none(self, parameters, self.TOLERANCE_M, context)
        opts["relaxation"] = self.parameterAsDouble(parameters, self.RELAXATION, context)
        opts["cross_check"] = self.parameterAsBool(parameters, self.CROSS_CHECK, context)
        opts["not_rougher"] = self.parameterAsBool(parameters, self.NOT_ROUGHER, context)
        if not 0 < opts["relaxation"] <= 1:
            raise ValueError(f"RELAXATION must be in (0, 1] (the share of each correction applied); got "
                             f"{opts['relaxation']:g}.")
        for key, p in ((self.EXTERIOR, exterior), (self.INTERIOR, interior), (self.TIE_POINTS, ties)):
            if p and not os.path.isfile(p):
                raise ValueError(f"{key}: the file {p!r} does not exist.")
        if exterior or interior:
            if not (exterior and interior):
                raise ValueError("give both EXTERIOR (filename,x,y,z,omega,phi,kappa) and INTERIOR (camera "
                                 "YAML / reconstruction.json)" + (", or TIE_POINTS alone." if not ties else "."))
            if ties:
                raise ValueError("give either the orientation (EXTERIOR and INTERIOR) or TIE_POINTS, not both.")
            skipped = []
            if parameters.get(self.IMAGE_FOLDER):
                # a folder may hold other rasters (the DEM beside the frames): use the files the CSV names
                try:
                    known = set(read_opk_csv(exterior))
                except ValueError as exc:
                    raise ValueError(f"EXTERIOR: {exc}") from None
                skipped = [os.path.basename(p) for p, n in zip(paths, names) if n not in known]
                kept = [(p, n) for p, n in zip(paths, names) if n in known]
                if len(kept) < 2:
                    raise ValueError(f"IMAGE_FOLDER: only {len(kept)} of its image files are named in EXTERIOR "
                                     f"({exterior}); the CSV names {sorted(known)}, the folder holds "
                                     f"{[os.path.basename(p) for p in paths]}.")
                paths, names = [p for p, _ in kept], [n for _, n in kept]
            try:
                cams = read_cameras(exterior, interior, names)
            except ValueError as exc:
                raise ValueError(f"EXTERIOR / INTERIOR: {exc}") from None
            for p, c in zip(paths, cams):
                w, h = _image_size(p)
                if (w, h) != (c.interior.width, c.interior.height):
                    raise ValueError(f"image {c.name!r} ({p}) is {w} x {h} pixels but its interior orientation "
                                     f"({c.interior.name or 'camera'}) says {c.interior.width} x "
                                     f"{c.interior.height}; use the matching camera or image.")
            isolated = self._check_overlap(info, cams, opts["window"])
            xyz = np.array([c.centre for c in cams], float)
            gaps = np.hypot(*(xyz[:, None, :2] - xyz[None, :, :2]).transpose(2, 0, 1))
            gaps = gaps[gaps > 0]
            if gaps.size:   # the closest pair: refused only when even its search is wider than the DEM
                h = float(xyz[:, 2].min() - np.nanmedian(_decimated(info)))
                check_parallax_range(info, float(gaps.min()), h, opts["max_dh_m"])
            return info, paths, names, dict(cameras=cams, isolated=isolated, skipped=skipped), opts
        if not ties:
            raise ValueError("give the orientation of the images: EXTERIOR and INTERIOR, or (for orthophotos "
                             "without orientation) TIE_POINTS with BASE_M and HEIGHT_M.")
        bh = self._base_height(parameters, context)
        if bh is None:
            raise ValueError("TIE_POINTS mode needs BASE_M (B between consecutive images) and HEIGHT_M (H).")
        check_parallax_range(info, bh[0], bh[1], opts["max_dh_m"])
        for p in paths:
            _image_size(p)          # every image readable, before any work
        tie = read_tie_points(ties, names)
        return info, paths, names, dict(cameras=None, tie_points=tie, base_m=bh[0], height_m=bh[1],
                                        base_direction=bh[2], isolated=[], skipped=[]), opts

    @staticmethod
    def _check_overlap(info, cams, window):
        """Images must reach the DEM, and at least two of them overlap on it (frame footprints)."""
        z = _decimated(info)
        if not np.isfinite(z).any():
            raise ValueError(f"the DEM {info.path!r} has no valid cell.")
        zmed = float(np.nanmedian(z))
        low = [c.name for c in cams if not c.centre[2] > zmed]
        if low:
            raise ValueError(f"camera(s) {low} are not above the DEM (median height {zmed:.2f}); check the z "
                             "of the EXTERIOR rows and the DEM's height datum.")
        rect = QgsGeometry.fromRect(_dem_rect(info))
        cell_area = abs(info.geotransform[1] * info.geotransform[5])
        fps, outside = [], []
        for c in cams:
            fp = _footprint(c, zmed)
            fp = None if fp is None else fp.intersection(rect)
            if fp is None or fp.isEmpty() or fp.area() < 4 * cell_area:
                outside.append(c.name)
            fps.append(fp)
        if outside:
            r = _dem_rect(info)
            raise ValueError(f"image(s) {outside} do not overlap the DEM (x {r.xMinimum():.2f}..{r.xMaximum():.2f}, "
                             f"y {r.yMinimum():.2f}..{r.yMaximum():.2f}): check their x, y, z and angles, and "
                             "that the CSV and the DEM use the same CRS.")
        need = max(100, 4 * window * window) * cell_area
        linked = set()
        for i in range(len(cams)):
            for j in range(i + 1, len(cams)):
                inter = fps[i].intersection(fps[j])
                if not inter.isEmpty() and inter.area() >= need:
                    linked |= {i, j}
        if not linked:
            raise ValueError(f"no two images overlap on the DEM: the footprints of {[c.name for c in cams]} "
                             "are disjoint. Give frames of the same area with a common overlap.")
        return [cams[i].name for i in range(len(cams)) if i not in linked]

    # -- run -----------------------------------------------------------------------------
    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        from ..core.orthophoto import orthorefine
        try:
            info, paths, names, mode, opts = self._inputs(parameters, context)
            isolated = mode.pop("isolated")
            skipped = mode.pop("skipped")
            if skipped:
                _warn(feedback, tr("IMAGE_FOLDER: skipped {} file(s) that EXTERIOR does not name: {}.").format(
                    len(skipped), ", ".join(skipped)))
            if isolated:
                _warn(feedback, tr("Image(s) {} overlap no other image on the DEM: they are not used.").format(
                    isolated))
            for w in info.warnings:
                _warn(feedback, w)
            dem = info.read()
            feedback.pushInfo(tr("DEM {}: {}; {} images: {}.").format(info.path, _grid_text(info), len(paths),
                                                                     ", ".join(names)))
            images = []
            for k, p in enumerate(paths):
                images.append(read_grey(p))
                if feedback.isCanceled():
                    raise Cancelled()
                feedback.setProgress(2.0 * (k + 1) / len(paths))
            prog = progress_callback(feedback)

            def progress(f):
                prog(0.02 + 0.96 * f)
            r = orthorefine(dem, info.geotransform, images, mode.pop("cameras"), progress=progress,
                            **mode, **opts)
        except Cancelled:
            feedback.reportError(tr("Cancelled: no output was written."))
            return {}
        except ValueError as exc:
            raise QgsProcessingException(str(exc)) from None
        outputs = self._write(info, parameters, context, np.where(np.isfinite(dem), r.dem, np.nan), r.dh,
                              r.quality, r.mask, feedback)
        if parameters.get(self.OUTPUT_ORTHO_FOLDER):
            folder = self.parameterAsFileOutput(parameters, self.OUTPUT_ORTHO_FOLDER, context)
            os.makedirs(folder, exist_ok=True)
            try:
                with output_options(self, parameters, context, feedback), grid.OutputSet(info) as out:
                    for n, o in zip(names, r.orthos):
                        out.add(n, os.path.join(folder, f"{n}_ortho.tif"), "Float32", nodata=float("nan"),
                                descriptions=[f"orthophoto of {n} (grey)"])
                        out.write(n, np.asarray(o, np.float32))
                    out.commit()
            except ValueError as exc:
                raise QgsProcessingException(str(exc)) from None
            outputs[self.OUTPUT_ORTHO_FOLDER] = folder
        feedback.pushInfo(tr("Iterations:"))
        feedback.pushInfo("  " + "  ".join(f"{c:>16}" for c in self.TABLE_COLUMNS))
        for row in r.table:
            feedback.pushInfo("  " + "  ".join(f"{_fmt(row.get(c, '')):>16}" for c in self.TABLE_COLUMNS))
        if parameters.get(self.OUTPUT_TABLE):
            path = self.parameterAsFileOutput(parameters, self.OUTPUT_TABLE, context)
            cols = list(self.TABLE_COLUMNS) + [k for k in r.table[0] if k not in self.TABLE_COLUMNS]
            with open(path, "w", newline="", encoding="utf-8") as f:
                wr = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
                wr.writeheader()
                for row in r.table:
                    wr.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
            outputs[self.OUTPUT_TABLE] = path
        self._log_info(r.info, feedback)
        feedback.pushInfo(tr("Stopped: {}.").format(r.info.get("stop", "")))
        feedback.setProgress(100)
        outputs.update(ITERATIONS=int(r.info.get("iterations", len(r.table))),
                       RMS_CORRECTION_M=float(r.table[-1]["rms_correction_m"]))
        return outputs
