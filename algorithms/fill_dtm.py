"""``bareearth:filldtm``: fill removed and nodata cells of a surface from the ground around them."""
import numpy as np
from qgis.core import (
    QgsProcessingException,
    QgsProcessingParameterBand,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterRasterDestination,
    QgsProcessingParameterRasterLayer,
    QgsProcessingParameterString,
)

from ..core import Cancelled, grid
from ..core.fill import fill_gaps
from .filter_base import (
    BaseAlgorithm,
    check_dsm,
    check_output_sizes,
    explained,
    format_params,
    open_one_band,
    output_options,
    progress_callback,
    tr,
    warning_logger,
    with_help,
)


def _horizontal(sr):
    """A clone of osr CRS ``sr`` without its vertical part (None where GDAL cannot strip it)."""
    if not sr.IsCompound():
        return sr
    if not hasattr(sr, "StripVertical"):         # GDAL < 3.6: the whole CRS is compared
        return None
    h = sr.Clone()
    h.StripVertical()
    return h


def _crs_pair(a, b):
    """The osr CRS of two DSMInfo, or None when either is unknown or unreadable."""
    if not a.crs_wkt or not b.crs_wkt:
        return None
    from osgeo import osr
    sa, sb = osr.SpatialReference(), osr.SpatialReference()
    try:
        if sa.ImportFromWkt(a.crs_wkt) != 0 or sb.ImportFromWkt(b.crs_wkt) != 0:
            return None
    except RuntimeError:
        return None
    return sa, sb


def other_crs(a, b, heights=True):
    """The names of two DSMInfo's CRS when both are known and differ, else None. With
    ``heights`` False (a mask's codes, an orthophoto's grey values: no height to convert), only
    the horizontal CRS counts: a mask in EPSG:26918 lies on the cells of a DSM in
    EPSG:26918+6360 (NAVD88 height in US feet)."""
    pair = _crs_pair(a, b)
    if pair is None:
        return None
    sa, sb = pair
    if sa.IsSame(sb):
        return None
    if not heights:
        ha, hb = _horizontal(sa), _horizontal(sb)
        if ha is not None and hb is not None and ha.IsSame(hb):
            return None
    return sa.GetName(), sb.GetName()


def same_grid(a, b, heights=True):
    """True when two DSMInfo share shape and geotransform (to a tolerance of 1e-6 cell) and their
    CRS (when both declare one: the same numbers in two CRS are two places; with ``heights``
    False, their horizontal CRS: :func:`other_crs`)."""
    if a.shape != b.shape:
        return False
    tol = 1e-6 * max(1.0, abs(a.geotransform[1]))
    if not all(abs(x - y) <= tol for x, y in zip(a.geotransform, b.geotransform)):
        return False
    return other_crs(a, b, heights) is None


def grid_mismatch_message(a, b, what, of="the DSM", heights=True):
    """Why raster ``b`` (``what``) is not on the grid of ``a`` (``of``), and how to fix it."""
    crs = other_crs(a, b, heights)
    if a.shape == b.shape and crs is not None:
        pair = _crs_pair(a, b)
        ha, hb = (_horizontal(pair[0]), _horizontal(pair[1])) if pair else (None, None)
        if ha is not None and hb is not None and ha.IsSame(hb):     # one place, heights of two vertical CRS
            return (f"{what} has its heights in another vertical CRS ({crs[1]}) than {of} ({crs[0]}), on the "
                    f"same horizontal CRS ({ha.GetName()}): another datum or unit of height, so the heights would "
                    "be compared across it. Write both in one vertical CRS first (gdalwarp -t_srs with the "
                    "compound CRS of the other); if only the declaration differs, declare the same CRS "
                    "(gdal_edit -a_srs).")
        return (f"{what} is in another CRS ({crs[1]}) than {of} ({crs[0]}): the same cell numbers are another "
                "place. Reproject it onto the grid of {} (gdalwarp -t_srs -te -tr, or Raster > Align "
                "rasters).".format(of))
    return (f"{what} is not on {of}'s grid: {b.shape[1]} x {b.shape[0]} cells, geotransform "
            f"{tuple(round(v, 6) for v in b.geotransform)}, but {of} has {a.shape[1]} x {a.shape[0]} "
            f"cells, {tuple(round(v, 6) for v in a.geotransform)}. Resample it onto {of}'s grid "
            "(gdalwarp -te/-tr, or Raster > Align rasters).")


def parse_codes(text):
    """The mask codes of FILL_CODES: integers 0-255 separated by commas, semicolons or spaces
    ('1,2', '1; 2', '1 2'). ValueError naming the text for anything else, and for an empty entry
    between two separators ('1,,2': a code left out, or a typo), rather than a guess."""
    text = str(text)
    parts = [t.strip() for t in text.replace(";", ",").split(",")]
    if len(parts) > 1 and "" in parts:
        raise ValueError(f"FILL_CODES has an empty entry between two commas or semicolons in {text!r}: give the "
                         "mask codes separated by one comma, semicolon or space (e.g. '1,2').")
    try:
        codes = [int(t) for part in parts for t in part.split()]
    except ValueError:
        raise ValueError(f"FILL_CODES must be integers separated by commas or spaces (e.g. '1,2'); got "
                         f"{text!r}.") from None
    if not codes or any(not 0 <= c <= 255 for c in codes):
        raise ValueError(f"FILL_CODES must list mask codes 0-255 (e.g. '1,2'); got {text!r}.")
    return codes


class FillDtmAlgorithm(BaseAlgorithm):
    """Gap filling (harmonic interpolation, multigrid), as an algorithm of its own."""

    INPUT, BAND, MASK, FILL_CODES, FILL_NODATA, OUTPUT = ("INPUT", "BAND", "MASK", "FILL_CODES",
                                                          "FILL_NODATA", "OUTPUT")
    GROUP, GROUP_NAME = "tools", "DTM tools"
    TAGS = ("DTM", "DEM", "DSM", "ground", "terrain", "bare earth", "nodata", "fill", "gaps", "holes", "voids",
            "interpolation", "fill nodata")

    def name(self):
        return "filldtm"

    def displayName(self):  # noqa: N802
        return tr("Fill DTM gaps")

    def shortHelpString(self):  # noqa: N802
        return tr("<p>Fills removed and nodata cells of a surface from the surrounding ground: a smooth "
                  "interpolation exact at the known cells, with no steps at hole edges, fast on large "
                  "holes (multigrid, no loop per cell). Every Bare Earth filter uses it for its DTM.</p>"
                  "<ul><li><b>INPUT</b>: the surface (DSM or DTM).</li><li><b>MASK</b>: optional UInt8 "
                  "mask on the same grid (a Bare Earth object mask); cells whose code is in FILL_CODES "
                  "are removed and filled.</li><li><b>FILL_CODES</b>: mask codes to fill, separated by "
                  "commas or spaces, default '1,2' (objects and low outliers).</li>"
                  "<li><b>FILL_NODATA</b>: also fill the input's nodata cells (default yes); otherwise they stay "
                  "nodata.</li><li><b>OUTPUT</b>: Float32 "
                  "surface on the input's grid, with its nodata.</li></ul>")

    def initAlgorithm(self, config=None):  # noqa: N802
        self.addParameter(with_help(QgsProcessingParameterRasterLayer(self.INPUT, tr("Surface to fill")),
                                    "Single-band surface (DSM or DTM) whose nodata or masked cells are filled."))
        b = QgsProcessingParameterBand(self.BAND, tr("Height band"), None, self.INPUT, optional=True)
        b.setHelp(tr("Band holding the heights; needed only when the raster has several bands."))
        self.addParameter(b)
        m = QgsProcessingParameterRasterLayer(self.MASK, tr("Mask of cells to fill"), optional=True)
        m.setHelp(tr("UInt8 mask on the same grid; cells whose code is in FILL_CODES are filled."))
        self.addParameter(m)
        c = QgsProcessingParameterString(self.FILL_CODES, tr("Mask codes to fill"), "1,2")
        c.setHelp(tr("Mask codes whose cells are filled (1 object, 2 low outlier), separated by commas or spaces."))
        self.addParameter(c)
        f = QgsProcessingParameterBoolean(self.FILL_NODATA, tr("Also fill nodata cells"), True)
        f.setHelp(tr("Fill the input's nodata cells too; otherwise they stay nodata."))
        self.addParameter(f)
        self.addParameter(with_help(QgsProcessingParameterRasterDestination(self.OUTPUT, tr("Filled surface")),
                                    "Float32 surface on the input's grid with the filled cells."))
        for p in format_params():
            self.addParameter(p)

    def _inputs(self, parameters, context):
        layer = self.parameterAsRasterLayer(parameters, self.INPUT, context)
        band = self.parameterAsInt(parameters, self.BAND, context) if parameters.get(self.BAND) else None
        ok, msg, info = check_dsm(layer, band)
        if not ok:
            raise ValueError(msg)
        mlayer = self.parameterAsRasterLayer(parameters, self.MASK, context)
        minfo = None
        if mlayer is not None:
            minfo = open_one_band(mlayer, self.MASK)
            if not same_grid(info, minfo, heights=False):            # codes: the horizontal CRS counts
                raise ValueError(grid_mismatch_message(info, minfo, "The mask", heights=False))
            grid.read_mask(minfo, "The mask (MASK)")   # codes, not heights: refused now, not read as codes
        codes = parse_codes(self.parameterAsString(parameters, self.FILL_CODES, context))
        return info, minfo, codes

    @explained
    def checkParameterValues(self, parameters, context):  # noqa: N802
        ok, msg = super().checkParameterValues(parameters, context)
        if not ok:
            return ok, msg
        try:
            info, minfo, codes = self._inputs(parameters, context)
            if minfo is None and not self.parameterAsBool(parameters, self.FILL_NODATA, context):
                return False, tr("Nothing to fill: give a MASK, or set FILL_NODATA.")
            ok, msg = check_output_sizes(self, parameters, context, info.shape)
            if not ok:
                return ok, msg
            if minfo is not None:
                known = np.isfinite(info.read()) & ~np.isin(grid.read_mask(minfo, "The mask (MASK)"), codes)
                if not known.any():
                    return False, tr("Nothing to fill from: every cell of the surface (INPUT) is nodata or masked "
                                     "(its code in the mask (MASK) is one of FILL_CODES: {}). Check the mask and "
                                     "the codes."
                                     ).format(", ".join(map(str, codes)))
        except (ValueError, QgsProcessingException) as exc:
            return False, str(exc)
        return True, ""

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        try:
            info, minfo, codes = self._inputs(parameters, context)
        except ValueError as exc:
            raise QgsProcessingException(self.explain(str(exc))) from None
        out_path = self.parameterAsOutputLayer(parameters, self.OUTPUT, context)
        fill_nodata = self.parameterAsBool(parameters, self.FILL_NODATA, context)
        z = info.read()
        fill = ~np.isfinite(z) if fill_nodata else np.zeros(z.shape, bool)
        if minfo is not None:
            m = grid.read_mask(minfo, "The mask (MASK)")
            coded = np.isin(m, codes)
            if not coded.any():
                present = ", ".join(str(int(c)) for c in np.unique(m))
                w = tr("The mask holds none of FILL_CODES ({}); its codes are {}: it fills no cell. Check "
                       "FILL_CODES.").format(", ".join(map(str, codes)), present)
                feedback.pushWarning(w) if hasattr(feedback, "pushWarning") else feedback.pushInfo(w)
            fill |= coded
        feedback.pushInfo(tr("Filling {} of {} cells ({:.2f} %).").format(int(fill.sum()), z.size, 100.0 * fill.mean()))
        for w in info.warnings:
            feedback.pushWarning(w) if hasattr(feedback, "pushWarning") else feedback.pushInfo(w)
        try:
            filled = fill_gaps(z, fill=fill, progress=progress_callback(feedback))
        except Cancelled:
            feedback.reportError(tr("Cancelled: no output was written."))
            return {}
        except ValueError as exc:
            raise QgsProcessingException(self.explain(str(exc))) from None
        stored = (info.nodata, info.scale, info.offset, info.dtype)
        nodata = grid.float_output_nodata(*stored)
        if grid.nodata_not_kept(*stored):
            feedback.pushInfo(grid.nodata_not_kept(*stored))
        filled = filled / np.float32(info.z_to_m) if info.z_to_m != 1.0 else filled
        filled = np.asarray(filled, np.float32).copy() if filled is z else np.asarray(filled, np.float32)
        moved = grid.with_output_nodata(filled, nodata)     # no height written as the nodata value
        if moved:
            warning_logger(feedback)(grid.moved_off_nodata_message(moved, nodata, "filled surface"))
        try:
            with output_options(self, parameters, context, feedback), grid.OutputSet(info) as out:
                out.add("out", out_path, "Float32", nodata=nodata, descriptions=["filled surface"],
                        heights=True)
                out.write("out", filled)
                out.commit()
        except ValueError as exc:
            raise QgsProcessingException(self.explain(str(exc))) from None
        return {self.OUTPUT: out_path}
