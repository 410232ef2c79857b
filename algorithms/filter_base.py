"""Shared plumbing of every filter algorithm: INPUT / OUTPUT_DTM / OUTPUT_MASK / OUTPUT_NDSM.

A method's algorithm is a few lines: it names its core method, and this base class builds
the dialog from the method's ``Param`` specs, checks the input before any work starts,
turns ``feedback`` into the core's progress callback, runs the core's block pipeline and
returns the outputs.
"""
import math
import os

from qgis.core import (QgsProcessing, QgsProcessingAlgorithm, QgsProcessingException,
                       QgsProcessingParameterBand, QgsProcessingParameterBoolean,
                       QgsProcessingParameterDefinition, QgsProcessingParameterEnum,
                       QgsProcessingParameterNumber, QgsProcessingParameterRasterDestination,
                       QgsProcessingParameterRasterLayer)
from qgis.PyQt.QtCore import QCoreApplication
from qgis.PyQt.QtGui import QIcon

from ..core import Cancelled
from ..core import grid
from ..core.codes import MASK_CODES
from ..core.methods import get_method
from ..meta import HOMEPAGE, ICON

MASK_HELP = ("UInt8 mask: " + ", ".join(f"{k} {v}" for k, v in MASK_CODES.items())
             + "; a colour table and a .qml style are written with it.")


def tr(text):
    return QCoreApplication.translate("BareEarth", text)


def with_help(param, text, advanced=False):
    """Set a parameter's help (and the advanced flag); returns the parameter."""
    param.setHelp(tr(text))
    if advanced:
        param.setFlags(param.flags() | QgsProcessingParameterDefinition.FlagAdvanced)
    return param


def progress_callback(feedback):
    """The core's plain progress callback for a QGIS feedback (raises Cancelled)."""
    def progress(fraction):
        if feedback is None:
            return
        if feedback.isCanceled():
            raise Cancelled()
        feedback.setProgress(100.0 * fraction)
    return progress


def auto_threads():
    """Threads for THREADS = 0: one per core (core ``blocks.default_workers``), within
    QGIS's "Max cores to use" setting when one is set."""
    from qgis.core import QgsApplication
    from ..core.blocks import default_workers
    n = default_workers()
    limit = QgsApplication.maxThreads()
    return max(1, min(n, limit)) if limit and limit > 0 else n


def raster_path(layer):
    """The GDAL path of a raster layer (``layer.source()``), refusing non-GDAL providers."""
    if layer is None:
        raise QgsProcessingException(tr("No input raster was given."))
    if layer.providerType() != "gdal":
        raise QgsProcessingException(tr(f"The layer '{layer.name()}' is served by the "
                                        f"'{layer.providerType()}' provider; save it as a GeoTIFF first."))
    return layer.source()


def check_dsm(layer, band):
    """Open and check the DSM of a layer; returns (ok, message, DSMInfo or None)."""
    try:
        info = grid.open_dsm(raster_path(layer), band or None)
        grid.check_has_data(info)
    except (ValueError, QgsProcessingException) as exc:
        return False, str(exc), None
    return True, "", info


class BaseAlgorithm(QgsProcessingAlgorithm):
    """Common bits of every Bare Earth algorithm (icon, group, help URL, instance)."""

    GROUP = "filters"
    GROUP_NAME = "DSM filters"

    def icon(self):
        return QIcon(ICON)

    def svgIconPath(self):  # noqa: N802
        return ICON

    def group(self):
        return tr(self.GROUP_NAME)

    def groupId(self):  # noqa: N802
        return self.GROUP

    def helpUrl(self):  # noqa: N802
        return f"{HOMEPAGE}#{self.name()}" if HOMEPAGE else ""

    def createInstance(self):  # noqa: N802
        return type(self)()

    def tr(self, text):
        return tr(text)


class FilterAlgorithm(BaseAlgorithm):
    """Base of every DSM filter algorithm. Subclasses set ``METHOD_NAME``.

    Parameters: INPUT, BAND, one per ``Param`` of the core method (name upper-cased),
    BLOCK_SIZE, THREADS and PROCESSES (advanced), OUTPUT_DTM, OUTPUT_MASK, OUTPUT_NDSM (optional) and
    OUTPUT_<EXTRA> for each per-cell side product of the method (optional).
    """

    METHOD_NAME = None
    INPUT = "INPUT"
    BAND = "BAND"
    OUTPUT_DTM = "OUTPUT_DTM"
    OUTPUT_MASK = "OUTPUT_MASK"
    OUTPUT_NDSM = "OUTPUT_NDSM"
    BLOCK_SIZE = "BLOCK_SIZE"
    THREADS = "THREADS"
    PROCESSES = "PROCESSES"
    #: help of each extra output, by the core's extras key
    EXTRA_HELP = {}

    @property
    def method(self):
        return get_method(self.METHOD_NAME)

    def name(self):
        return self.METHOD_NAME

    def displayName(self):  # noqa: N802
        return tr(self.method.title or self.METHOD_NAME)

    def shortHelpString(self):  # noqa: N802
        m = self.method
        rows = "".join(f"<li><b>{p.name.upper()}</b>: {p.help}</li>" for p in m.params)
        extras = "".join(f"<li><b>OUTPUT_{k.upper()}</b>: {self.EXTRA_HELP.get(k, k)}</li>" for k in m.extras)
        return tr(f"{m.description}<h3>Parameters</h3><ul><li><b>INPUT</b>: single-band DSM raster "
                  "(heights in metres, or in the unit of a projected CRS in feet; a geographic CRS has "
                  "its cell size converted to metres at its latitude).</li><li><b>BAND</b>: the height "
                  f"band when the raster has several.</li>{rows}</ul><h3>Outputs</h3><ul>"
                  "<li><b>OUTPUT_DTM</b>: Float32 bare-earth DTM: removed cells filled by interpolation "
                  "from the ground around them, the input's nodata kept.</li>"
                  f"<li><b>OUTPUT_MASK</b>: {MASK_HELP}</li><li><b>OUTPUT_NDSM</b>: DSM minus DTM "
                  f"(optional).</li>{extras}</ul>")

    # -- parameters ----------------------------------------------------------------------
    def extraInputs(self):  # noqa: N802
        """Subclasses add method-specific layer inputs here (e.g. break lines)."""
        return []

    def initAlgorithm(self, config=None):  # noqa: N802
        self.addParameter(with_help(QgsProcessingParameterRasterLayer(self.INPUT, tr("Input DSM")),
                                    "Single-band DSM raster (GDAL). Heights in metres, or in the linear unit "
                                    "of a projected CRS in feet; a geographic CRS has its cell size converted "
                                    "to metres at its latitude."))
        b = QgsProcessingParameterBand(self.BAND, tr("Height band"), None, self.INPUT, optional=True)
        b.setHelp(tr("Band holding the heights; needed only when the raster has several bands."))
        self.addParameter(b)
        for p in self.extraInputs():
            self.addParameter(p)
        for p in self.method.params:
            self.addParameter(self._qgs_param(p))
        for key, label, default, lo, hi, text in (
                (self.BLOCK_SIZE, "Block size (cells, 0 = automatic)", 0, 0, 65536,
                 "Edge of the blocks the raster is processed in, in cells. 0: one block up to 25 "
                 "million cells, else 2048. Blocks overlap by the method's reach, so the result "
                 "does not depend on it; memory does."),
                (self.THREADS, "Threads (0 = one per core)", 0, 0, 64,
                 "Blocks filtered at once in threads. 0 (the default): one per core, at most 8, "
                 "within QGIS's own limit (Settings > Options > Rendering > Max cores). The raster "
                 "is cut into strips of rows that overlap by the method's reach; no start-up cost, "
                 "so this is the first choice on one machine. 1: one block at a time, least memory."),
                (self.PROCESSES, "Worker processes", 1, 1, 64,
                 "Blocks filtered at once in separate Python processes (use up to the number of "
                 "cores). Each holds one block in memory; starting them takes about a second, "
                 "so it pays on large rasters.")):
            self.addParameter(with_help(QgsProcessingParameterNumber(
                key, tr(label), QgsProcessingParameterNumber.Integer, default, optional=True,
                minValue=lo, maxValue=hi), text, advanced=True))
        self.addParameter(with_help(QgsProcessingParameterRasterDestination(self.OUTPUT_DTM, tr("DTM")),
                                    "Float32 bare-earth DTM on the input's grid: removed cells filled by "
                                    "interpolation from the ground around them, the input's nodata kept."))
        self.addParameter(with_help(QgsProcessingParameterRasterDestination(self.OUTPUT_MASK, tr("Object mask")),
                                    MASK_HELP))
        self.addParameter(with_help(QgsProcessingParameterRasterDestination(
            self.OUTPUT_NDSM, tr("nDSM (DSM minus DTM)"), optional=True, createByDefault=False),
            "Float32 normalised DSM: height above the DTM (metres, or the input's height unit)."))
        for key in self.method.extras:
            self.addParameter(with_help(QgsProcessingParameterRasterDestination(
                f"OUTPUT_{key.upper()}", tr(self.EXTRA_HELP.get(key, key)), optional=True,
                createByDefault=False), self.EXTRA_HELP.get(key, key)))

    @staticmethod
    def _qgs_param(p):
        label = p.name.replace("_", " ")
        for unit, text in (("_deg", " (degrees)"), ("_m", " (m)"), ("_cells", " (cells)")):
            if p.name.endswith(unit):
                label = p.name[: -len(unit)].replace("_", " ") + text
        label = label[0].upper() + label[1:]
        if p.default is None:
            label += " [empty: from the data]"
        if p.kind in ("float", "int"):
            typ = (QgsProcessingParameterNumber.Double if p.kind == "float"
                   else QgsProcessingParameterNumber.Integer)
            kw = {}
            if p.minimum is not None:
                kw["minValue"] = p.minimum
            if p.maximum is not None:
                kw["maxValue"] = p.maximum
            q = QgsProcessingParameterNumber(p.name.upper(), tr(label), typ, p.default,
                                             optional=p.default is None, **kw)
        elif p.kind == "bool":
            q = QgsProcessingParameterBoolean(p.name.upper(), tr(label), bool(p.default))
        elif p.kind == "enum":
            q = QgsProcessingParameterEnum(p.name.upper(), tr(label), list(p.options), False,
                                           list(p.options).index(p.default) if p.default in p.options else 0)
        else:  # pragma: no cover - a wrong spec is a programming error
            raise TypeError(f"unknown Param kind {p.kind!r}")
        q.setHelp(tr(p.help))
        if p.advanced:
            q.setFlags(q.flags() | QgsProcessingParameterDefinition.FlagAdvanced)
        return q

    def _user_params(self, parameters, context):
        """The core's keyword arguments; an empty optional number means "from the data" (None)."""
        out = {}
        for p in self.method.params:
            key = p.name.upper()
            if p.kind in ("float", "int"):
                given = parameters.get(key) not in (None, "")
                if not given and p.default is None:
                    v = None
                else:
                    read = self.parameterAsDouble if p.kind == "float" else self.parameterAsInt
                    v = read(parameters, key, context)
                    if p.default is None and isinstance(v, float) and math.isnan(v):
                        v = None
            elif p.kind == "bool":
                v = self.parameterAsBool(parameters, key, context)
            else:
                v = p.options[self.parameterAsEnum(parameters, key, context)]
            out[p.name] = v
        return out

    # -- checks before any work ---------------------------------------------------------------
    def checkParameterValues(self, parameters, context):  # noqa: N802
        ok, msg = super().checkParameterValues(parameters, context)
        if not ok:
            return ok, msg
        layer = self.parameterAsRasterLayer(parameters, self.INPUT, context)
        band = self.parameterAsInt(parameters, self.BAND, context) if parameters.get(self.BAND) else None
        ok, msg, info = check_dsm(layer, band)
        if not ok:
            return False, msg
        user = self._user_params(parameters, context)
        extent_m = max(info.shape[0] * info.cell_size_m[1], info.shape[1] * info.cell_size_m[0])
        defaults = {p.name: p.default for p in self.method.params}
        for name, v in user.items():
            # a default larger than a small raster is clamped by the core; a chosen one is refused
            if v is not None and v != defaults.get(name) and ("window" in name or "size_m" in name) \
                    and name.endswith("_m") and isinstance(v, (int, float)) and v > extent_m:
                return False, tr(f"{name.upper()} = {v} m is larger than the raster itself "
                                 f"({extent_m:.1f} m across): choose a smaller window or a larger raster.")
        return self.checkExtraInputs(parameters, context, info)

    def checkExtraInputs(self, parameters, context, info):  # noqa: N802
        """Subclasses check their own extra inputs; return (ok, message)."""
        return True, ""

    def auxiliaryArrays(self, parameters, context, info, feedback):  # noqa: N802
        """Subclasses turn extra layer inputs into per-cell arrays (e.g. break lines)."""
        return {}

    # -- the run ----------------------------------------------------------------------------
    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        from ..core.pipeline import run_file
        layer = self.parameterAsRasterLayer(parameters, self.INPUT, context)
        band = self.parameterAsInt(parameters, self.BAND, context) if parameters.get(self.BAND) else None
        try:  # checkParameterValues scanned the data; run_file re-checks it from its own first read
            info = grid.open_dsm(raster_path(layer), band or None)
        except ValueError as exc:
            raise QgsProcessingException(str(exc)) from None
        outputs = {"dtm": self.parameterAsOutputLayer(parameters, self.OUTPUT_DTM, context),
                   "mask": self.parameterAsOutputLayer(parameters, self.OUTPUT_MASK, context)}
        if parameters.get(self.OUTPUT_NDSM):
            outputs["ndsm"] = self.parameterAsOutputLayer(parameters, self.OUTPUT_NDSM, context)
        for key in self.method.extras:
            pk = f"OUTPUT_{key.upper()}"
            if parameters.get(pk):
                outputs[key] = self.parameterAsOutputLayer(parameters, pk, context)
        block = self.parameterAsInt(parameters, self.BLOCK_SIZE, context) or None
        processes = self.parameterAsInt(parameters, self.PROCESSES, context) or 1
        threads = self.parameterAsInt(parameters, self.THREADS, context) or auto_threads()
        user = self._user_params(parameters, context)
        aux = self.auxiliaryArrays(parameters, context, info, feedback)
        feedback.pushInfo(tr(f"Input: {info.path} band {info.band_index}, {info.shape[1]} x {info.shape[0]} "
                             f"cells of {info.cell_size_m[0]:.4g} x {info.cell_size_m[1]:.4g} m"))
        try:
            result = run_file(self.METHOD_NAME, info.path, outputs, band=info.band_index, params=user,
                              aux=aux, block=block, workers=threads, processes=processes,
                              progress=progress_callback(feedback),
                              log=feedback.pushWarning if hasattr(feedback, "pushWarning") else feedback.reportError)
        except Cancelled:
            feedback.reportError(tr("Cancelled: no output was written."))
            return {}
        except ValueError as exc:
            raise QgsProcessingException(str(exc)) from None
        self.logResult(result, feedback)
        return {f"OUTPUT_{k.upper()}": v for k, v in outputs.items()}

    def logResult(self, result, feedback):  # noqa: N802
        """Write the values used and the statistics to the log."""
        feedback.pushInfo(tr("Parameters used:"))
        for k, v in result["params"].items():
            feedback.pushInfo(f"  {k} = {_fmt(v)}")
        feedback.pushInfo(tr("Result:"))
        for k, v in result.items():
            if k in ("params", "warnings", "method"):
                continue
            if isinstance(v, dict):
                feedback.pushInfo(f"  {k}: " + ", ".join(f"{a} {_fmt(b)}" for a, b in v.items()))
            else:
                feedback.pushInfo(f"  {k} = {_fmt(v)}")


def _fmt(v):
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, (list, tuple)):
        return "(" + ", ".join(_fmt(x) for x in v) + ")"
    return str(v)
