"""Shared plumbing of every filter algorithm: INPUT / OUTPUT_DTM / OUTPUT_MASK / OUTPUT_NDSM.

A method's algorithm is a few lines: it names its core method, and this base class builds
the dialog from the method's ``Param`` specs, checks the input before any work starts,
turns ``feedback`` into the core's progress callback, runs the core's block pipeline and
returns the outputs.
"""
import contextlib
import functools
import math
import os
import re

import numpy as np
from osgeo import gdal, gdal_array
from qgis.core import (
    QgsProcessing,
    QgsProcessingAlgorithm,
    QgsProcessingException,
    QgsProcessingOutputLayerDefinition,
    QgsProcessingParameterBand,
    QgsProcessingParameterBoolean,
    QgsProcessingParameterEnum,
    QgsProcessingParameterMultipleLayers,
    QgsProcessingParameterNumber,
    QgsProcessingParameterRasterDestination,
    QgsProcessingParameterRasterLayer,
    QgsProcessingParameterString,
    QgsProperty,
)
from qgis.PyQt.QtCore import QCoreApplication
from qgis.PyQt.QtGui import QIcon

from ..core import Cancelled, grid
from ..core.codes import MASK_CODES
from ..core.methods import get_method
from ..meta import HOMEPAGE, ICON
from .compat import (
    NUMBER_DOUBLE,
    NUMBER_INTEGER,
    RANGE_INCLUDE_MAX,
    RANGE_INCLUDE_MIN,
    RANGE_INCLUDE_MIN_AND_MAX,
    WKT_PREFERRED_GDAL,
    is_optional,
    mark_advanced,
)
from .labels import extra_label, is_advanced, param_label

MASK_HELP = ("UInt8 mask: " + ", ".join(f"{k} {v}" for k, v in MASK_CODES.items())
             + "; a colour table and a .qml style are written with it.")


def tr(text):
    return QCoreApplication.translate("BareEarth", text)


def with_help(param, text, advanced=False):
    """Set a parameter's help (and the advanced flag); returns the parameter."""
    param.setHelp(tr(text))
    if advanced:
        mark_advanced(param)
    return param


def warning_logger(feedback):
    """A log callback for the core's warnings: QGIS's warning line already says "WARNING", so a
    "Warning: " the core put first is dropped."""
    push = feedback.pushWarning if hasattr(feedback, "pushWarning") else feedback.reportError

    def log(text):
        text = str(text)
        push(text[len("Warning: "):] if text.startswith("Warning: ") else text)
    return log


def run_logger(feedback):
    """The log callback of a filter run (``pipeline.run_file``'s ``log``): the core marks its warnings
    with "Warning: " (dropped: QGIS's warning line already says it) and they go to the warnings;
    its other lines (the window the parameters came from, the blocks, the empty cells filled, the
    nodata declared) are information, shown as such (they were all shown as warnings)."""
    warn = warning_logger(feedback)

    def log(text):
        text = str(text)
        warn(text) if text.startswith("Warning: ") else feedback.pushInfo(text)
    return log


def progress_callback(feedback):
    """The core's plain progress callback for a QGIS feedback (raises Cancelled)."""
    def progress(fraction):
        if feedback is None:
            return
        if feedback.isCanceled():
            raise Cancelled()
        feedback.setProgress(100.0 * fraction)
        if feedback.isCanceled():   # a cancel handled while the bar was drawn stops here, not later
            raise Cancelled()
    return progress


def stage_done(feedback, percent):
    """A stage of a tool that has no progress of its own is done: the bar moves to ``percent``,
    and a cancel asked meanwhile stops the run here (Cancelled), before anything is written."""
    feedback.setProgress(percent)
    if feedback.isCanceled():
        raise Cancelled()


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
    if not layer.isValid():
        src = layer.source()
        hint = tr(" A GeoPackage's raster table is opened as GPKG:file.gpkg:table ('|layername=' names a "
                  "vector layer).") if "|layername=" in src else ""
        raise QgsProcessingException(tr("The layer '{}' is not valid: QGIS could not open its source '{}'. Check "
                                        "the path, or remove the layer and add it again.{}").format(
            layer.name(), src, hint))
    if layer.providerType() != "gdal":
        raise QgsProcessingException(tr("The layer '{}' is served by the '{}' provider; save it as a GeoTIFF "
                                        "first.").format(layer.name(), layer.providerType()))
    check_layer_source(layer)
    check_layer_crs(layer)
    return layer.source()


def check_layer_source(layer):
    """QgsProcessingException for a GDAL raster layer whose source the filters cannot open as QGIS does: opened
    with GDAL open options (``|option:KEY=VALUE`` in its source, set in the Data Source Manager), which GDAL
    cannot be given in a path (the file was refused as missing: "No such file or directory"), or a file
    gone since the layer was loaded (moved, deleted, a drive unplugged)."""
    from qgis.core import QgsProviderRegistry
    src = layer.source()
    parts = QgsProviderRegistry.instance().decodeUri("gdal", src) or {}
    options = [str(o) for o in (parts.get("openOptions") or [])]
    if options:
        oo = " ".join("-oo {}".format(o) for o in options)
        raise QgsProcessingException(tr(
            "The layer '{}' is opened with GDAL open options ({}), which the filters cannot pass on to the file: "
            "write the raster as QGIS reads it (gdal_translate {} '{}' dsm.tif, or Export > Save As), or add the "
            "layer again without the options, then run again.").format(
                layer.name(), ", ".join(options), oo, parts.get("path") or src.split("|")[0]))
    if os.path.isabs(src) and not src.startswith("/vsi") and not os.path.exists(src):
        raise QgsProcessingException(tr(
            "The layer '{}' reads the file '{}', which no longer exists (moved, renamed or deleted since the layer "
            "was loaded, or on a drive no longer mounted): add the layer again from where the file is now.").format(
                layer.name(), src))


def _crs_name(crs):
    return crs.authid() or crs.description() or tr("a custom CRS")


def check_layer_crs(layer):
    """QgsProcessingException when a raster layer was given a CRS in QGIS (Layer Properties > Source) other
    than the one its file declares: GDAL reads the file's, so the cell size, the heights' unit and the
    outputs' CRS were the file's, the outputs placed elsewhere than the layer is drawn (a file declaring
    UTM zone 33 for data of zone 32, assigned 32632 in QGIS: the DTM written in zone 33, no word said).
    A file without a CRS of its own takes the layer's (:func:`layer_crs_wkt`)."""
    prov = layer.dataProvider()
    own = prov.crs() if prov is not None else None
    if own is None or not own.isValid() or not layer.crs().isValid() or layer.crs() == own:
        return
    given = _crs_name(layer.crs())
    raise QgsProcessingException(tr(
        "The layer '{}' is in {} as QGIS draws it (a CRS set in its Properties > Source), but its file declares {}, "
        "which the filters read: the cell size, the heights' unit and the outputs would be the file's, placed "
        "elsewhere than the layer. Write the CRS into the file (Raster > Projections > Assign Projection, or "
        "gdal_edit.py -a_srs {} '{}'), or export the layer to a new file, then run again.").format(
            layer.name(), given, _crs_name(own), given, layer.source()))


def layer_nodata_ranges(layer, band):
    """The additional no-data values a raster layer was given in QGIS (Properties > Transparency)
    for ``band`` (None: the band :func:`grid.open_dsm` chooses, 1 for a single band), as
    ``(low, high, include_low, include_high)`` ranges of heights: QGIS draws those cells
    transparent, so they are nodata for the filters too."""
    if layer is None or layer.dataProvider() is None:
        return ()
    prov = layer.dataProvider()
    b = band or 1
    if not band and prov.bandCount() > 1:
        try:
            b = grid.open_dsm(raster_path(layer)).band_index
        except (ValueError, QgsProcessingException):
            return ()
    out = []
    for r in prov.userNoDataValues(b):
        bounds = r.bounds()
        out.append((r.min(), r.max(), bounds in (RANGE_INCLUDE_MIN_AND_MAX, RANGE_INCLUDE_MIN),
                    bounds in (RANGE_INCLUDE_MIN_AND_MAX, RANGE_INCLUDE_MAX)))
    return tuple(out)


def open_one_band(layer, key):
    """The DSMInfo of a raster input that has no BAND parameter (a mask, a DTM to compare) as its
    layer stands (:func:`layer_nodata_ranges`, :func:`layer_crs_wkt`): its one band, beside an
    alpha band that masks it. ValueError naming ``key`` for a raster of several bands: reading its
    band 1 would compare or fill with whatever it holds (the red of a mask exported as a rendered
    RGB image, the first of a stack) without a word."""
    path = raster_path(layer)
    try:
        return grid.open_dsm(path, None, layer_nodata_ranges(layer, None), layer_crs_wkt(layer))
    except grid.SeveralBands as exc:
        raise ValueError(f"{key}: the raster {path!r} has {exc.bands} bands but this input is read from a "
                         "single band (it has no band choice): extract the band it should use first (gdal_translate -b "
                         "<band> in out.tif, or Raster > Conversion > Translate)." + (
                             " A mask saved as a rendered image (RGB colours) holds no codes: give the mask file a "
                             "filter wrote." if "MASK" in key else "")) from None


def layer_crs_wkt(layer):
    """The CRS a raster layer was given in QGIS (WKT), or None: used for a file without a CRS of
    its own (an .asc without .prj), which QGIS draws in the layer's CRS."""
    if layer is None or not layer.crs().isValid():
        return None
    return layer.crs().toWkt(WKT_PREFERRED_GDAL) or None


def check_dsm(layer, band, key=None):
    """Open and check the DSM of a layer; returns (ok, message, DSMInfo or None). ``key``: the id of an input
    that has no BAND parameter (orthorefine's DEM): a raster of several bands is refused as
    :func:`open_one_band` refuses it (the DSM's message named a BAND parameter the algorithm lacks)."""
    try:
        if key is not None:
            info = open_one_band(layer, key)
        else:
            info = grid.open_dsm(raster_path(layer), band or None, layer_nodata_ranges(layer, band),
                                 layer_crs_wkt(layer))
        grid.check_has_data(info)
    except (ValueError, QgsProcessingException) as exc:
        return False, str(exc), None
    return True, "", info


#: README.md beside the plugin: its headings are the targets of the help buttons
README = os.path.join(os.path.dirname(os.path.dirname(__file__)), "README.md")


def github_anchor(heading):
    """The anchor GitHub gives a Markdown heading: lower case, punctuation dropped (letters,
    digits, spaces, '-' and '_' kept), each space a '-'."""
    text = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return text.replace(" ", "-")


def readme_headings(path=README):
    """The README's headings (text after the '#'s), in order; [] when it is absent."""
    try:
        with open(path, encoding="utf-8") as f:
            lines = f.read().splitlines()
    except OSError:
        return []
    out, fenced = [], False
    for line in lines:
        if line.lstrip().startswith("```"):
            fenced = not fenced
        elif not fenced and re.match(r"#{1,6} ", line):
            out.append(line.lstrip("#").strip())
    return out


@functools.lru_cache(maxsize=None)
def help_anchor(alg_id):
    """Anchor of the README section of ``bareearth:<name>``: the first heading naming the
    algorithm, else the "Algorithms" section."""
    headings = readme_headings()
    for h in headings:
        if re.search(rf"`{re.escape(alg_id)}`", h):
            return github_anchor(h)
    return "algorithms"


CREATE_OPTIONS, COG = "CREATE_OPTIONS", "COG"


def format_params():
    """The advanced parameters of GeoTIFF outputs, as QGIS's own raster algorithms offer them:
    GDAL creation options (with QGIS's profile widget in the dialog) and cloud-optimised GeoTIFF."""
    o = QgsProcessingParameterString(CREATE_OPTIONS, tr("Additional creation options"), optional=True)
    o.setMetadata({"widget_wrapper": {
        "class": "processing.algs.gdal.ui.RasterOptionsWidget.RasterOptionsWidgetWrapper"}})
    c = QgsProcessingParameterBoolean(COG, tr("Write cloud-optimised GeoTIFFs (COG)"), False, optional=True)
    return [with_help(o, "GDAL creation options of the GeoTIFF outputs, KEY=VALUE separated by '|' (e.g. "
                         "COMPRESS=ZSTD|PREDICTOR=2 or COMPRESS=LZW); the dialog offers QGIS's compression "
                         "profiles. Empty: DEFLATE (fast level) in 256 x 256 tiles.", advanced=True),
            with_help(c, "Write .tif outputs as cloud-optimised GeoTIFFs (tiled, with overviews, readable "
                         "over HTTP by range requests), compressed with DEFLATE unless the creation options "
                         "say otherwise.", advanced=True)]


@contextlib.contextmanager
def output_options(alg, parameters, context, feedback=None):
    """``grid.write_options`` from an algorithm's CREATE_OPTIONS and COG (if it has them); with
    ``feedback``, a warning for each raster output given in another format than GeoTIFF, which
    they do not apply to (:func:`options_not_used`)."""
    cog = bool(alg.parameterDefinition(COG)) and alg.parameterAsBool(parameters, COG, context)
    text = alg.parameterAsString(parameters, CREATE_OPTIONS, context) if alg.parameterDefinition(CREATE_OPTIONS) \
        else ""
    try:
        opts = grid.parse_creation_options(text, cog=cog)
    except ValueError as exc:
        raise QgsProcessingException(alg.explain(str(exc))) from None
    if feedback is not None and (opts or cog):
        for line in options_not_used(alg, parameters, cog):
            warning_logger(feedback)(line)
    if feedback is not None and opts:
        change = grid.height_change(opts, cog)
        if change > 0:        # lossy for the heights: GDAL writes them so without a word
            lo, hi = grid.PROBE_HEIGHTS_M
            warning_logger(feedback)(tr(
                "The creation options '{}' store the heights of the Float32 outputs (DTM, nDSM) lossily: heights of "
                "{:.0f}-{:.0f} m written with them come back up to {:.3g} m off (NBITS=16 keeps half floats, "
                "DISCARD_LSB drops bits, LERC keeps MAX_Z_ERROR). Leave them out to keep the heights exact.").format(
                    "|".join(opts), lo, hi, change))
    with grid.write_options(opts, cog):
        yield


def options_not_used(alg, parameters, cog):
    """Lines for the log naming each raster output given as a file of another format than
    GeoTIFF (.asc, .img, .sdat, .nc, .gpkg): the creation options and COG are GeoTIFF's and
    are not used for it (written in the format's own way without a word before)."""
    lines = []
    for d in alg.destinationParameterDefinitions():
        if d.type() != "rasterDestination":
            continue
        value = parameters.get(d.name())
        if isinstance(value, QgsProcessingOutputLayerDefinition):
            value = value.sink.staticValue()
        path = value if isinstance(value, str) else ""
        ext = os.path.splitext(path)[1].lower()
        if not path or path == QgsProcessing.TEMPORARY_OUTPUT or path.startswith("memory:") \
                or ext in (".tif", ".tiff") or ext not in grid.OUTPUT_FORMATS:
            continue
        what = "the creation options and COG apply" if cog and parameters.get(CREATE_OPTIONS) else \
            ("COG (a cloud-optimised GeoTIFF) applies" if cog else "the creation options apply")
        are = "is" if what.startswith("COG") else "are"
        lines.append(tr("{} is written as {} ({}): {} to GeoTIFF outputs (.tif) only and {} not "
                        "used for it.").format(label_of(d), grid.OUTPUT_FORMATS[ext][2], ext, what, are))
    return lines


def check_output_sizes(alg, parameters, context, shape, dtypes=None):
    """(ok, message): :func:`grid.check_tiff_size` of each raster output given of an algorithm with
    CREATE_OPTIONS, on ``shape`` cells (``dtypes``: {output id: GDAL type name}, default Float32): options
    keeping a GeoTIFF classic (BIGTIFF=NO) over 4 GB are refused here, not when the output is written."""
    if alg.parameterDefinition(CREATE_OPTIONS) is None:
        return True, ""
    cog = bool(alg.parameterDefinition(COG)) and alg.parameterAsBool(parameters, COG, context)
    try:
        opts = grid.parse_creation_options(alg.parameterAsString(parameters, CREATE_OPTIONS, context), cog=cog)
    except ValueError:
        return True, ""      # checkOutputs refuses them, naming the option
    for d in alg.destinationParameterDefinitions():
        path = destination_path(parameters, d.name()) if d.type() == "rasterDestination" else None
        if not path:
            continue
        try:
            grid.check_tiff_size(path, shape, alg.outputBands(d.name()), (dtypes or {}).get(d.name(), "Float32"),
                                 opts, cog)
        except ValueError as exc:
            return False, "{}: {}".format(label_of(d), exc)
    return True, ""


def check_window_sizes(alg, values, defaults, info):
    """(ok, message): a chosen window larger than the raster is refused before any work.

    ``values`` and ``defaults`` map Processing ids to numbers; a parameter whose id names a
    window (``..._CELLS`` in cells against the raster's shorter side, ``..._M`` in metres
    against its extent) or a size in metres (``..._SIZE_M``) is compared with ``info``'s
    raster (a :class:`~bare_earth.core.grid.DSMInfo`). Defaults pass: the cores clamp a
    default larger than a small raster, only a value the user chose is refused. A default may be
    a tuple: the default and its former values (:attr:`~bare_earth.core.methods.Param.former_defaults`,
    stored by models and scripts saved before it changed).
    """
    extent_m = max(info.shape[0] * info.cell_size_m[1], info.shape[1] * info.cell_size_m[0])
    for key, v in values.items():
        name = key.lower()
        known = defaults.get(key)
        if (v is None or isinstance(v, bool) or not isinstance(v, (int, float))
                or v in (known if isinstance(known, tuple) else (known,))
                or ("window" not in name and "size_m" not in name)):
            continue
        label = label_of(alg.parameterDefinition(key))
        if name.endswith("_m") and v > extent_m:
            return False, tr("{} = {} m is larger than the raster itself ({:.1f} m across): choose a "
                             "smaller window or a larger raster.").format(label, v, extent_m)
        if name.endswith("_cells") and v > min(info.shape):
            return False, tr("{} = {} cells is larger than the raster itself ({} x {} cells): choose a "
                             "smaller window or a larger raster.").format(label, v, info.shape[1], info.shape[0])
    return True, ""


#: Smallest block edge a user may ask for (cells): the windows' corners align on 64 cells, and
#: a smaller block reads far more halo than block (1-cell blocks: one filter run per cell).
def not_whole(d, value):
    """(False, message) for a whole-number parameter (a count, a band, a window in cells) given a fraction,
    which QGIS rounds or cuts without a word."""
    return False, tr("{} = {} is not a whole number: give a whole number.").format(label_of(d), value)


MIN_BLOCK_SIZE = 64


def check_block_size(alg, parameters, context):
    """(ok, message): BLOCK_SIZE is 0 (automatic) or at least :data:`MIN_BLOCK_SIZE` cells."""
    d = alg.parameterDefinition("BLOCK_SIZE")
    if d is None or parameters.get("BLOCK_SIZE") in (None, ""):
        return True, ""
    b = alg.parameterAsInt(parameters, "BLOCK_SIZE", context)
    if 0 < b < MIN_BLOCK_SIZE:
        return False, tr("{} = {} cells is too small: use 0 (automatic) or at least {} cells (a block is "
                         "read with the method's reach around it, so tiny blocks repeat the work many "
                         "times over).").format(label_of(d), b, MIN_BLOCK_SIZE)
    return True, ""


def check_processes(alg, parameters, context):
    """(ok, message): PROCESSES at most this computer's cores (each process holds a block and
    its halo in memory; beyond the cores they only share them)."""
    from ..core.blocks import available_cores
    d = alg.parameterDefinition("PROCESSES")
    if d is None or parameters.get("PROCESSES") in (None, ""):
        return True, ""
    n, cores = alg.parameterAsInt(parameters, "PROCESSES", context), available_cores()
    if n > cores:
        return False, tr("{} = {}, but this computer has {} core(s): processes beyond the cores run no faster "
                         "(they share the cores) and each holds a block in memory. Use at most {}.").format(
            label_of(d), n, cores, cores)
    return True, ""


def input_file_list(path):
    """The files of a raster input: GDAL's list (the file and its sidecars: ``.prj``, ``.aux.xml``,
    a SAGA grid's ``.sgrd``) and the ``.qml`` style QGIS loads with it (whether or not there is
    one yet: a mask's style written there would restyle the input)."""
    files = [path]
    try:
        with grid.without_side_files():
            ds = gdal.OpenEx(path, gdal.OF_RASTER | gdal.OF_READONLY)
            files += (ds.GetFileList() or []) if ds is not None else []
            ds = None
    except RuntimeError:
        pass
    return files + [os.path.splitext(path)[0] + ".qml"]


def destination_path(parameters, key):
    """The file a destination parameter names, or None for a temporary output (or none)."""
    v = parameters.get(key)
    if isinstance(v, QgsProcessingOutputLayerDefinition):
        v = v.sink.staticValue()
    if v is None or str(v) in ("", QgsProcessing.TEMPORARY_OUTPUT) or str(v).startswith("memory:"):
        return None
    return str(v)


def gdal_raster_layer(value):
    """A raster layer for a text value naming what GDAL opens but is no file, which QGIS's own loader
    of text values (qgis_process, a script's string) takes for a missing file ("Could not load source
    layer for INPUT: ... not found"): a raster in a zip (``/vsizip/dsm.zip/dsm.tif``), on a server
    (``/vsicurl/``), a GeoPackage's raster table (``GPKG:file.gpkg:table``), a netCDF variable
    (``NETCDF:"file.nc":z``). None for anything else (a file QGIS loads itself, a value that is no text)."""
    if not isinstance(value, str) or not value.strip() or os.path.exists(value):
        return None
    from qgis.core import QgsRasterLayer
    with grid.without_side_files():
        layer = QgsRasterLayer(value, os.path.basename(value.rstrip("/")) or value, "gdal")
    return layer if layer.isValid() else None


def several_rasters(value):
    """The rasters (GDAL's subdatasets) of a file given as text that holds several and so no raster of its
    own (a GeoPackage of several raster tables, a netCDF of several variables), or []."""
    if not isinstance(value, str) or not os.path.isfile(value):
        return []
    try:
        with grid.without_side_files(), grid.gdal_mode_kept():
            gdal.UseExceptions()
            ds = gdal.OpenEx(value, gdal.OF_RASTER | gdal.OF_READONLY)
            subs = [name for name, _ in (ds.GetSubDatasets() or [])] if ds is not None and not ds.RasterCount else []
            ds = None
    except RuntimeError:
        return []
    return subs


#: Text point files' extensions (as the point readers take them); .asc is left to GDAL (an ASCII grid)
TEXT_POINT_EXTENSIONS = (".txt", ".csv", ".xyz", ".pts")


def file_kind(path):
    """What an existing file holds for a layer input: 'points' (LAS/LAZ, or a text point file GDAL opens as
    no raster), 'raster', 'vector' (a layer with geometries), or None (no file, or nothing GDAL reads)."""
    if not isinstance(path, str) or not os.path.isfile(path):
        return None
    try:
        with open(path, "rb") as fh:
            head = fh.read(4)
    except OSError:
        return None
    if head == b"LASF" or path.lower().endswith((".las", ".laz")):
        return "points"
    with grid.without_side_files(), grid.gdal_mode_kept():
        gdal.UseExceptions()
        for flag, kind in ((gdal.OF_RASTER, "raster"), (gdal.OF_VECTOR, "vector")):
            try:
                ds = gdal.OpenEx(path, flag | gdal.OF_READONLY)
            except RuntimeError:
                ds = None
            if ds is None:
                continue
            found = ds.RasterCount > 0 if kind == "raster" else any(
                ds.GetLayer(i).GetGeomType() != 0 for i in range(ds.GetLayerCount()))   # 0: wkbNone, a table
            ds = None
            if found:
                return kind
    return "points" if path.lower().endswith(TEXT_POINT_EXTENSIONS) else None


def vector_layers(value):
    """The names of the vector layers of a file given as a path (no '|layername='), when it holds several:
    QGIS takes the first of them without a word. [] otherwise."""
    if not isinstance(value, str) or "|" in value or not os.path.isfile(value):
        return []
    with grid.without_side_files(), grid.gdal_mode_kept():
        gdal.UseExceptions()
        try:
            ds = gdal.OpenEx(value, gdal.OF_VECTOR | gdal.OF_READONLY)
        except RuntimeError:
            return []
        names = [ds.GetLayer(i).GetName() for i in range(ds.GetLayerCount())] if ds is not None else []
        ds = None
    return names if len(names) > 1 else []


def explained(check):
    """Decorate a ``checkParameterValues``: its refusal names parameters by label and id."""
    @functools.wraps(check)
    def checked(self, parameters, context):
        ok, msg = check(self, parameters, context)
        return ok, (msg if ok else self.explain(msg))
    return checked


def takes_several(definition):
    """Whether a parameter takes a list of values (layers, choices or fields of several, a
    matrix, a range): given to any other, a list is a key given twice."""
    kind = definition.type()
    if kind in ("multilayer", "matrix", "range"):
        return True
    return kind in ("enum", "field") and bool(definition.allowMultiple())


def label_of(definition):
    """How messages and the log name a parameter: its label (without a trailing note such as
    "[empty: from the data]"), and its id for qgis_process."""
    return "'{}' ({})".format(re.sub(r"\s*\[[^\]]*\]$", "", definition.description()), definition.name())


def _copy_definition(src, dst):
    """Help, flags and metadata of ``src`` onto ``dst`` (a definition of the same kind)."""
    dst.setHelp(src.help())
    dst.setFlags(src.flags())
    dst.setMetadata(src.metadata())
    return dst


class InputRasterParameter(QgsProcessingParameterRasterLayer):
    """A raster input whose check loads the layer without GDAL's side file (Processing and
    qgis_process load an input given as a path to check it, and QGIS's statistics of the
    new layer would be saved as ``.aux.xml`` beside the input: :func:`grid.without_side_files`)."""

    def checkValueIsAcceptable(self, value, context=None):  # noqa: N802
        with grid.without_side_files():
            if super().checkValueIsAcceptable(value, context):
                return True
        return context is not None and gdal_raster_layer(value) is not None   # /vsizip/..., GPKG:file:table

    def clone(self):
        return _copy_definition(self, InputRasterParameter(self.name(), self.description(), self.defaultValue(),
                                                           is_optional(self)))


class InputLayersParameter(QgsProcessingParameterMultipleLayers):
    """Several layers, checked as :class:`InputRasterParameter` is."""

    def checkValueIsAcceptable(self, value, context=None):  # noqa: N802
        with grid.without_side_files():
            return super().checkValueIsAcceptable(value, context)

    def clone(self):
        return _copy_definition(self, InputLayersParameter(
            self.name(), self.description(), self.layerType(), self.defaultValue(),
            is_optional(self)))


def reading_inputs_only(param):
    """``param`` as one of the input kinds above when it is a plain raster or multiple-layer
    input (every algorithm's inputs pass through :meth:`BaseAlgorithm.addParameter`)."""
    if type(param) is QgsProcessingParameterRasterLayer:
        return _copy_definition(param, InputRasterParameter(
            param.name(), param.description(), param.defaultValue(),
            is_optional(param)))
    if type(param) is QgsProcessingParameterMultipleLayers:
        q = InputLayersParameter(param.name(), param.description(), param.layerType(), param.defaultValue(),
                                 is_optional(param))
        q.setMinimumNumberInputs(param.minimumNumberInputs())
        return _copy_definition(param, q)
    return param


def default_text(param):
    """A parameter's default as the dialog shows it ('64', 'yes', 'auto', '1,2'), or None when it
    has none (or it is a layer, a file or an output)."""
    v = param.defaultValue()
    if param.isDestination() or v is None or v == "" or isinstance(v, (list, tuple)) or param.type() not in (
            "number", "boolean", "enum", "string"):
        return None
    if param.type() == "boolean":
        return "yes" if v in (True, 1, "1", "true", "True") else "no"
    if param.type() == "enum":
        try:
            return param.options()[int(v)]
        except (ValueError, IndexError):
            return str(v)
    if param.type() == "number" and isinstance(v, float):
        return f"{v:g}"
    return str(v)


def default_stated(param):
    """``param`` with its default at the end of its help when the help does not state it:
    ``qgis_process help`` of QGIS 3.22 prints the help but not the default (the dialog shows it)."""
    text = default_text(param)
    if text is not None and not re.search(r"\bdefault\b", param.help(), re.IGNORECASE):
        param.setHelp((param.help().rstrip() + " " if param.help().strip() else "") + tr("Default: {}.").format(text))
    return param


def gdal_mode_kept(func):
    """Run ``func`` inside :func:`grid.gdal_mode_kept`: QGIS's session keeps GDAL's exception
    mode as it was, whatever the core turned on."""
    @functools.wraps(func)
    def kept(*args, **kwargs):
        with grid.gdal_mode_kept():
            return func(*args, **kwargs)
    kept.gdal_mode_kept = True
    return kept


def outputs_checked(func):
    """``processAlgorithm`` with the outputs checked first (``checkOutputs``: no output is an input or another
    output, each folder exists and takes files, each format is offered). QGIS runs an algorithm's
    ``checkParameterValues`` before a run of its own (the dialog, ``processing.run``, qgis_process), but not
    before a step of a graphical model: there an output given the input's path (classifypoints' points file)
    overwrote the input, and an output in a missing folder failed with GDAL's "Attempt to create new tiff file
    ... failed" after the work."""
    @functools.wraps(func)
    def checked(self, parameters, context, feedback):
        ok, msg = self.checkOutputs(parameters, context)
        if not ok:
            raise QgsProcessingException(self.explain(msg))
        return func(self, parameters, context, feedback)
    checked.outputs_checked = True
    return checked


#: The methods QGIS calls on an algorithm that may reach GDAL's Python bindings.
GDAL_ENTRY_POINTS = ("checkParameterValues", "prepareAlgorithm", "processAlgorithm", "postProcessAlgorithm",
                     "shortHelpString")


class BaseAlgorithm(QgsProcessingAlgorithm):
    """Common bits of every Bare Earth algorithm (icon, group, tags, help URL, instance).

    Its ``processAlgorithm`` checks the outputs first (:func:`outputs_checked`: a model's steps are not
    checked by QGIS). Each entry point of :data:`GDAL_ENTRY_POINTS` a class defines runs with GDAL's exception
    mode restored afterwards (:func:`gdal_mode_kept`)."""

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        run = getattr(cls, "processAlgorithm", None)
        if run is not None and not getattr(run, "outputs_checked", False):   # a model's step is not checked
            cls.processAlgorithm = outputs_checked(run)
        for name in GDAL_ENTRY_POINTS:   # its own, and a mixin's before BaseAlgorithm in the MRO
            f = getattr(cls, name, None)
            if f is not None and not getattr(f, "gdal_mode_kept", False):
                setattr(cls, name, gdal_mode_kept(f))

    GROUP = "filters"
    GROUP_NAME = "DSM filters"
    #: words users type in the toolbox's search box (the toolbox matches tags, id and name)
    TAGS = ()

    def icon(self):
        return QIcon(ICON)

    def svgIconPath(self):  # noqa: N802
        return ICON

    def group(self):
        return tr(self.GROUP_NAME)

    def groupId(self):  # noqa: N802
        return self.GROUP

    def tags(self):
        """The words the toolbox search finds it by, each once (a filter on points adds the point
        tools' words, some of which every filter has: 'ground', 'DTM', 'DSM', 'classification')."""
        return list(dict.fromkeys(tr(t) for t in self.TAGS))

    def helpUrl(self):  # noqa: N802
        return "{}#{}".format(HOMEPAGE, help_anchor("bareearth:" + self.name())) if HOMEPAGE else ""

    def createInstance(self):  # noqa: N802
        return type(self)()

    def tr(self, text):
        return tr(text)

    # -- messages ----------------------------------------------------------------------------
    def messageNames(self):  # noqa: N802
        """{name in messages: definition}: the ids with an underscore (single words such as DTM or
        MASK are also ordinary words in messages)."""
        return {d.name(): d for d in self.parameterDefinitions() if "_" in d.name()}

    def explain(self, message):
        """A message with each parameter it names by id (or by the core's name) given as the
        dialog's label and the id for qgis_process; names already so given are kept, whole (a label
        may hold a name: morphological's 'Terrain slope (rise/run)' (SLOPE) holds ``slope``). A
        single word (``slope``, ``mode``: also ordinary words) is a name only as the core writes
        one, ``slope = ...`` or ``slope must ...``."""
        names = self.messageNames()
        if not names or not message:
            return message
        labels = sorted({label_of(d) for d in names.values()}, key=len, reverse=True)
        words = "|".join(sorted(map(re.escape, names), key=len, reverse=True))
        pattern = re.compile("(" + "|".join(map(re.escape, labels)) + r")|(?<![\w'/\\.-])(" + words
                             + r")(?![\w'.])")

        def named(m):
            if m.group(1) is not None:                       # a label already given
                return m.group(0)
            before, after = message[m.start() - 1:m.start()], message[m.end():m.end() + 1]
            if before == "(" and after == ")":               # an id already given
                return m.group(0)
            if "_" not in m.group(2) and not re.match(r" (=|must )", message[m.end():m.end() + 6]):
                return m.group(0)                            # an ordinary word
            return label_of(names[m.group(2)])
        return pattern.sub(named, message)

    # -- outputs ---------------------------------------------------------------------------
    def outputBands(self, key):  # noqa: N802
        """Bands of the raster output ``key`` (1; a filter's side products may have more)."""
        return 1

    def inputPaths(self, parameters, context):  # noqa: N802
        """(definition, path) of every file the given inputs read."""
        out = []
        for d in self.parameterDefinitions():
            if d.isDestination() or parameters.get(d.name()) in (None, "", []):
                continue
            if d.type() == "raster":
                lay = self.parameterAsRasterLayer(parameters, d.name(), context)
                out += [(d, lay.source())] if lay is not None else []
            elif d.type() == "file":
                out.append((d, self.parameterAsFile(parameters, d.name(), context)))
            elif d.type() == "multilayer":
                out += [(d, p) for p in self.parameterAsFileList(parameters, d.name(), context)]
                out += [(d, lay.source()) for lay in self.parameterAsLayerList(parameters, d.name(), context)]
            elif d.type() in ("source", "vector"):
                lay = self.parameterAsVectorLayer(parameters, d.name(), context)
                if lay is not None and lay.providerType() == "ogr":   # a file: its path before '|layername='
                    out.append((d, lay.source().split("|")[0]))
        return [(d, p) for d, p in out if p]

    def checkOutputs(self, parameters, context):  # noqa: N802
        """(ok, message): no output overwrites an input or another output; each output's folder
        exists and takes files; each raster output's extension names a format offered (and
        holds its bands). Runs before any work."""
        inputs = [(d, os.path.realpath(p)) for d, p in self.inputPaths(parameters, context)]
        input_files = {}     # every file of a raster input (sidecars, its QGIS style) -> (definition, input)
        if any(d.type() == "rasterDestination" and destination_path(parameters, d.name())
               for d in self.destinationParameterDefinitions()):
            for di, p in inputs:
                if di.type() in ("raster", "multilayer"):
                    files = input_file_list(p)
                elif di.type() in ("source", "vector"):   # a vector layer's file and its QGIS style
                    files = [p, os.path.splitext(p)[0] + ".qml"]
                else:
                    continue
                for f in files:
                    input_files.setdefault(grid.file_identity(f), (di, p))
        seen, styles = {}, {}
        input_ids = [(di, grid.file_identity(p)) for di, p in inputs]
        for d in self.destinationParameterDefinitions():
            path = destination_path(parameters, d.name())
            if path is None:
                continue
            real = grid.file_identity(path)    # one file under two names: a link, another case
            for di, p in input_ids:
                if p == real:
                    return False, tr("The output {} is the input {} ({}): the input would be overwritten. "
                                     "Choose another file for the output.").format(label_of(d), label_of(di), path)
            if real in seen:
                other = seen[real][1]
                return False, tr("The outputs {} and {} are one file ({}{}): give each output its own "
                                 "file.").format(label_of(seen[real][0]), label_of(d), path,
                                                 "" if other == path else tr(" and {}, two names of it").format(other))
            if d.type() == "rasterDestination":
                for f in grid.output_files(path, styled=d.name().endswith("MASK")):
                    hit = input_files.get(grid.file_identity(f))
                    if hit is not None and grid.file_identity(f) == real:   # a file a VRT input reads
                        return False, tr("The output {} ({}) would write {}, a file the input {} ({}) reads: "
                                         "the input would change. Choose another file for the output.").format(
                            label_of(d), path, f, label_of(hit[0]), hit[1])
                    if hit is not None:
                        return False, tr("The output {} ({}) would write {}, a file of the input {} ({}): its "
                                         "sidecar, or the style QGIS loads with it. Choose another name for the "
                                         "output.").format(
                            label_of(d), path, f, label_of(hit[0]), hit[1])
            seen[real] = (d, path)
            if d.type() == "rasterDestination":   # a mask's style is another output's style too
                style_path = os.path.realpath(os.path.splitext(path)[0] + ".qml")
                style = grid.file_identity(style_path)
                other = styles.get(style)
                if other is not None and (d.name().endswith("MASK") or other[1]):
                    return False, tr("The outputs {} and {} share the name {} (another extension): QGIS would "
                                     "draw both with the mask's style ({}). Give them different names.").format(
                        label_of(other[0]), label_of(d), os.path.splitext(os.path.basename(path))[0], style_path)
                styles[style] = (d, d.name().endswith("MASK"))
            try:
                if d.type() == "rasterDestination":
                    grid.check_output_path(path, self.outputBands(d.name()), styled=d.name().endswith("MASK"))
                elif d.type() == "folderDestination":   # the folder takes files (was its parent's test)
                    grid.check_output_dir(path)
                else:                              # a report, a table, a point or vector file
                    grid.check_output_file(path, "output." + (d.defaultFileExtension() or "txt"))
            except ValueError as exc:
                return False, "{}: {}".format(label_of(d), exc)
        if self.parameterDefinition(CREATE_OPTIONS) is not None:
            try:
                grid.parse_creation_options(self.parameterAsString(parameters, CREATE_OPTIONS, context),
                                            cog=self.parameterAsBool(parameters, COG, context))
            except ValueError as exc:
                return False, "{}: {}".format(label_of(self.parameterDefinition(CREATE_OPTIONS)), exc)
        return True, ""

    # -- inputs loaded as layers without writing beside them ----------------------------------
    def addParameter(self, param, createOutput=True):  # noqa: N802,N803
        return super().addParameter(default_stated(reading_inputs_only(param)), createOutput)

    def parameterAsOutputLayer(self, parameters, name, context):  # noqa: N802
        """The file of an output; a raster output given as ``memory:`` (QGIS's memory layers, which
        rasters do not have) is a temporary output as ``TEMPORARY_OUTPUT`` is (it was written as a
        file named 'memory:' in the working folder, and two such outputs were one file)."""
        d = self.parameterDefinition(name)
        v = parameters.get(name)
        sink = v.sink.staticValue() if isinstance(v, QgsProcessingOutputLayerDefinition) else v
        if d is not None and d.type() == "rasterDestination" and isinstance(sink, str) and sink.startswith("memory:"):
            if isinstance(v, QgsProcessingOutputLayerDefinition):
                v = QgsProcessingOutputLayerDefinition(v)
                v.sink = QgsProperty.fromValue(QgsProcessing.TEMPORARY_OUTPUT)
            else:
                v = QgsProcessing.TEMPORARY_OUTPUT
            parameters = dict(parameters, **{name: v})
        return super().parameterAsOutputLayer(parameters, name, context)

    def parameterAsRasterLayer(self, parameters, name, context):  # noqa: N802
        """The layer of a raster input; one Processing loads from a path is opened without GDAL's
        side file, so QGIS's statistics are not saved as ``.aux.xml`` beside the input
        (:func:`grid.without_side_files`)."""
        with grid.without_side_files():
            layer = super().parameterAsRasterLayer(parameters, name, context)
        if layer is None:     # text naming a GDAL raster that is no file: QGIS's loader takes it for a missing file
            layer = gdal_raster_layer(parameters.get(name))
            if layer is not None:
                context.temporaryLayerStore().addMapLayer(layer)
        return layer

    def parameterAsLayerList(self, parameters, name, context):  # noqa: N802
        with grid.without_side_files():
            return super().parameterAsLayerList(parameters, name, context)

    def checkValuesGiven(self, parameters):  # noqa: N802
        """(ok, message): every key names a parameter of this algorithm (a misspelt one would be
        silently left out, its default used), and a number, band or yes/no given as text (as
        qgis_process gives every value) reads as one: QGIS reads 'abc' as 0 or false and runs,
        and 'nan' as "not given"; a NaN given as a number (a script's, a model's expression) passes
        QGIS's range check and reads as -2147483648 (BLOCK_SIZE: a run that never ended); a list
        given to a parameter of one value (qgis_process makes one of a key given twice,
        TOLERANCE_M=0.3 TOLERANCE_M=0.3) is refused: QGIS reads an optional number's list as 0; a
        fraction given to a whole number (a count, a band, a window in cells) is refused: QGIS cut
        THREADS=1.5 to 1 and rounded BAND=2.7 to band 3; an input file's path with a blank at either end
        (copied with the space after it) is refused naming it without (it was "not found")."""
        defs = {d.name(): d for d in self.parameterDefinitions()}
        unknown = sorted(k for k in parameters if k not in defs)
        if unknown:
            return False, tr("{} is no parameter of {} (a misspelt name would be left out and its default "
                             "used): 'qgis_process help {}' lists its parameters.").format(
                ", ".join(unknown), self.id(), self.id())
        for key, v in parameters.items():
            d = defs[key]
            if isinstance(v, (list, tuple)) and not takes_several(d):    # qgis_process: KEY given twice
                listed = ", ".join(str(x) for x in v)
                return False, (tr("{} is given {} times ({}): give it once.").format(label_of(d), len(v), listed)
                               if len(v) > 1 else tr("{} is given as a list ([{}]): give {}.").format(
                                   label_of(d), listed, tr("the value alone") if v else tr("a value")))
            if isinstance(v, float) and not math.isfinite(v) and d.type() in ("number", "band") \
                    and d.checkValueIsAcceptable(v):       # NaN: within every range, read as -2147483648
                return False, tr("{} = {} is not a number: give a number{}.").format(
                    label_of(d), v, tr(", or leave it out") if is_optional(d) else "")
            whole = d.type() == "band" or (d.type() == "number" and d.dataType() == NUMBER_INTEGER)
            if whole and isinstance(v, float) and math.isfinite(v) and v != math.floor(v):
                return not_whole(d, v)          # a script's 1.5: QGIS took 1 for THREADS, band 2 for BAND 1.5
            if d.type() == "string" and not is_optional(d) and isinstance(v, str) and v.strip() == "":
                return False, tr("{} is empty: give a value{} (QGIS said only 'Incorrect parameter value').").format(
                    label_of(d), tr(", or leave it out for its default '{}'").format(d.defaultValue())
                    if d.defaultValue() not in (None, "") else "")
            if not isinstance(v, str) or v.strip() == "":
                continue
            text = v.strip()
            if text != v and d.type() in ("raster", "file", "vector", "source") and os.path.exists(text):
                return False, tr("{}: '{}' {} with a blank (a space, a tab or a line break), which is kept in the file "
                                 "name: give it without, '{}'.").format(
                    label_of(d), v, "ends" if v[-1:].isspace() else "begins", text)   # was "not found"
            if d.type() in ("number", "band"):
                try:
                    number = float(text)
                except ValueError:
                    number = float("nan")
                if whole and math.isfinite(number) and number != math.floor(number):
                    return not_whole(d, text)     # qgis_process's BAND=2.7: QGIS read band 3, WINDOW_CELLS=7.5 7
                if not math.isfinite(number):
                    point = text.replace(",", ".", 1) if text.count(",") == 1 and "." not in text else ""
                    try:
                        comma = point != "" and math.isfinite(float(point))
                    except ValueError:
                        comma = False
                    return False, tr("{} = '{}' is not a number: give a number{}{}.").format(
                        label_of(d), text, tr(", or leave it out") if is_optional(d) else "",
                        tr(" (with a decimal point: {})").format(point) if comma else "")
            elif d.type() == "boolean" and text.lower() not in ("true", "false", "1", "0", "yes", "no", "on", "off"):
                return False, tr("{} = '{}' is not a yes/no value: give true or false.").format(label_of(d), text)
        return True, ""

    @explained
    def checkParameterValues(self, parameters, context):  # noqa: N802
        ok, msg = self.checkValuesGiven(parameters)
        if not ok:
            return ok, msg
        with grid.without_side_files():  # Processing loads the inputs given as paths here
            ok, msg = super().checkParameterValues(parameters, context)
        if not ok:
            return ok, (self.several_rasters_given(parameters) or self.wrong_kind_given(parameters)
                        or self.out_of_range(parameters, context) or msg)
        msg = self.several_layers_given(parameters)
        if msg:
            return False, msg
        for check in (check_block_size, check_processes):
            ok, msg = check(self, parameters, context)
            if not ok:
                return ok, msg
        return self.checkOutputs(parameters, context)

    def several_rasters_given(self, parameters):
        """The refusal of a raster input given as a file holding several rasters (QGIS's own: "Could not load
        source layer for INPUT: x.gpkg not found"), naming them as they may be given, or a GeoPackage's raster
        table named the vector way, or None."""
        for d in self.parameterDefinitions():
            value = parameters.get(d.name())
            if d.type() != "raster" or not isinstance(value, str):
                continue
            if "|layername=" in value:      # QGIS's way to name a vector layer of a file, not a raster table
                path, table = value.split("|layername=", 1)
                return tr("{}: '{}' names a vector layer ('|layername='); a GeoPackage's raster table is given as "
                          "GPKG:{}:{}.").format(label_of(d), value, path, table.split("|")[0])
            subs = several_rasters(value)
            if subs:
                shown = ", ".join(subs[:5]) + (tr(" and {} more").format(len(subs) - 5) if len(subs) > 5 else "")
                return tr("{}: the file '{}' holds {} rasters (a GeoPackage's raster tables, a netCDF's variables), "
                          "so it names none: give one of them ({}).").format(
                    label_of(d), parameters[d.name()], len(subs), shown)
        return None

    def wrong_kind_given(self, parameters):
        """The refusal of a layer input given as a file of another kind, which QGIS's loader of text values
        called missing ("Could not load source layer for INPUT: points.las not found", the file there): a
        point cloud or a vector layer given as a raster, a raster or a point cloud given as a vector layer;
        or None."""
        for d in self.parameterDefinitions():
            value, kind = parameters.get(d.name()), d.type()
            if kind not in ("raster", "source", "vector") or not isinstance(value, str):
                continue
            if not os.path.isfile(value):
                continue                   # QGIS's "not found" is true
            held = file_kind(value)
            if held == ("raster" if kind == "raster" else "vector"):
                continue                   # of its kind: another input failed
            if kind == "raster" and held == "points":
                how = (tr("give it as {} instead, which makes the DSM of the points").format(
                    label_of(self.parameterDefinition("INPUT_POINTS")))
                    if self.parameterDefinition("INPUT_POINTS") is not None and d.name() == "INPUT" else
                    tr("rasterize it first (bareearth:rasterizepoints)"))
                return tr("{}: '{}' is a point cloud or a text file, not a raster: if it holds points, {}.").format(
                    label_of(d), value, how)
            if kind == "raster" and held == "vector":
                return tr("{}: '{}' is a vector layer, not a raster: give a raster (GeoTIFF, ...).").format(
                    label_of(d), value)
            if kind != "raster" and held == "raster":
                return tr("{}: '{}' is a raster, not a vector layer: give a vector layer (a raster of the areas "
                          "becomes polygons with Raster > Conversion > Polygonize, gdal_polygonize).").format(
                    label_of(d), value)
            if kind != "raster" and held == "points":
                return tr("{}: '{}' is a point cloud, not a vector layer: give a vector layer.").format(
                    label_of(d), value)
            return tr("{}: GDAL cannot open '{}' as a {}: check the file (gdalinfo, ogrinfo) or export it again "
                      "in a format GDAL reads.").format(label_of(d), value,
                                                          tr("raster") if kind == "raster" else tr("vector layer"))
        return None

    def several_layers_given(self, parameters):
        """The refusal of a vector input given as the path of a file of several vector layers (a GeoPackage),
        of which QGIS takes the first without a word, naming them as they may be given; or None."""
        for d in self.parameterDefinitions():
            if d.type() not in ("source", "vector"):
                continue
            names = vector_layers(parameters.get(d.name()))
            if names:
                path = parameters[d.name()]
                shown = ", ".join(names[:5]) + (tr(" and {} more").format(len(names) - 5) if len(names) > 5 else "")
                return tr("{}: the file '{}' holds {} vector layers ({}): QGIS would take the first, '{}', without a "
                          "word. Give the layer: '{}|layername={}'.").format(
                    label_of(d), path, len(names), shown, names[0], path, names[-1])
        return None

    def out_of_range(self, parameters, context):
        """The refusal of the first number given outside its limits, naming its label, id and
        range (QGIS's own says "Incorrect parameter value for THREADS"), or of the first choice
        given neither as one of its options' numbers, naming them (MODE=progressive: QGIS takes
        the number, 1), or None."""
        for d in self.parameterDefinitions():
            if d.type() == "enum" and parameters.get(d.name()) not in (None, "") and not d.checkValueIsAcceptable(
                    parameters[d.name()], context):
                given = parameters[d.name()]
                options = list(d.options())
                named = [i for i, o in enumerate(options) if str(o).lower() == str(given).strip().lower()]
                listed = ", ".join("{} = {}".format(i, o) for i, o in enumerate(options))
                return (tr("{} = '{}' is not one of its options' numbers: give {} ({}).").format(
                    label_of(d), given, named[0], listed) if named else
                    tr("{} = '{}' is not one of its options' numbers ({}).").format(label_of(d), given, listed))
            if d.type() != "number" or parameters.get(d.name()) in (None, "") or d.checkValueIsAcceptable(
                    parameters[d.name()], context):
                continue
            value, lo, hi = self.parameterAsDouble(parameters, d.name(), context), d.minimum(), d.maximum()
            limits = (tr("at least {:g}").format(lo) if hi > 1e300 else tr("at most {:g}").format(hi)
                      if lo < -1e300 else tr("within [{:g}, {:g}]").format(lo, hi))
            return tr("{} = {:g} is out of range: give a value {}.").format(label_of(d), value, limits)
        return None

    def postProcessAlgorithm(self, context, feedback):  # noqa: N802
        """Style the outputs Processing loads (the mask's classes, side products' renderers)."""
        from .styles import style_loaded_outputs
        style_loaded_outputs(self, context)
        return {}


for _name in GDAL_ENTRY_POINTS:   # BaseAlgorithm's own entry points too
    if _name in BaseAlgorithm.__dict__:
        setattr(BaseAlgorithm, _name, gdal_mode_kept(BaseAlgorithm.__dict__[_name]))


class FilterAlgorithm(BaseAlgorithm):
    """Base of every DSM filter algorithm. Subclasses set ``METHOD_NAME``.

    Parameters: INPUT, BAND, one per ``Param`` of the core method (name upper-cased),
    BLOCK_SIZE, THREADS and PROCESSES (advanced), OUTPUT_DTM, OUTPUT_MASK, OUTPUT_NDSM (optional) and
    OUTPUT_<EXTRA> for each per-cell side product of the method (optional).
    """

    METHOD_NAME = None
    #: every filter; a subclass adds its own words in METHOD_TAGS
    FILTER_TAGS = ("DTM", "DEM", "DSM", "digital terrain model", "ground", "ground filter", "terrain",
                   "bare earth", "filter", "object mask", "buildings", "trees", "vegetation", "nodata",
                   "classification", "photogrammetry")
    METHOD_TAGS = ()
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

    def outputBands(self, key):  # noqa: N802
        extra = key[len("OUTPUT_"):].lower()
        return self.method.extras[extra][1] if key.startswith("OUTPUT_") and extra in self.method.extras else 1

    def name(self):
        return self.METHOD_NAME

    @property
    def TAGS(self):  # noqa: N802 (the class constant of BaseAlgorithm)
        return self.FILTER_TAGS + self.METHOD_TAGS

    def displayName(self):  # noqa: N802
        return tr(self.method.title or self.METHOD_NAME)

    def shortHelpString(self):  # noqa: N802
        m = self.method
        rows = "".join("<li><b>{}</b> ({}): {}</li>".format(tr(param_label(self.METHOD_NAME, p)), p.name.upper(),
                                                            tr(p.help)) for p in m.params)
        extras = "".join("<li><b>{}</b> (OUTPUT_{}): {}</li>".format(tr(extra_label(k)), k.upper(),
                                                                     tr(self.EXTRA_HELP.get(k, k))) for k in m.extras)
        return tr("{}<h3>Parameters</h3><ul><li><b>Input DSM</b> (INPUT): single-band DSM raster (heights in "
                  "metres, or in the unit of a projected CRS in feet; a geographic CRS has its cell size converted "
                  "to metres at its latitude).</li><li><b>Height band</b> (BAND): the height band when the raster "
                  "has several.</li>{}</ul><h3>Outputs</h3><ul><li><b>DTM</b> (OUTPUT_DTM): Float32 bare-earth "
                  "DTM: removed cells filled by interpolation from the ground around them, the input's nodata "
                  "kept.</li><li><b>Object mask</b> (OUTPUT_MASK): {}</li><li><b>nDSM</b> (OUTPUT_NDSM): DSM "
                  "minus DTM (optional).</li>{}</ul><p>Outputs are written in the format their extension names: "
                  "{}.</p>").format(tr(m.description), rows, tr(MASK_HELP), extras, grid.output_formats_text())

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
                 "Edge of the blocks the raster is processed in, in cells: 0 or at least 64. 0: one "
                 "block up to 25 million cells, else the largest blocks whose windows (block and reach) fit "
                 "half the memory available (or BARE_EARTH_MEMORY_MB megabytes: a bound so small that the windows "
                 "would read the raster's cells more than 4 times is refused before the blocks, naming the "
                 "smallest that works). Blocks overlap by the method's reach, so the result does not depend "
                 "on it; memory does."),
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
                key, tr(label), NUMBER_INTEGER, default, optional=True,
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
                f"OUTPUT_{key.upper()}", tr(extra_label(key)), optional=True,
                createByDefault=False), self.EXTRA_HELP.get(key, key)))
        for p in format_params():
            self.addParameter(p)

    def _qgs_param(self, p):
        """The QGIS parameter of a core ``Param``: its label from ``labels.py``, its help from the core."""
        label = param_label(self.METHOD_NAME, p)
        if p.kind in ("float", "int"):
            typ = NUMBER_DOUBLE if p.kind == "float" else NUMBER_INTEGER
            kw = {}
            if p.minimum is not None:
                kw["minValue"] = p.minimum
            if p.maximum is not None:
                kw["maxValue"] = p.maximum
            q = QgsProcessingParameterNumber(p.name.upper(), tr(label), typ, p.default,
                                             optional=p.default is None, **kw)
        elif p.kind == "bool":
            # optional, with its default: a model saved before the switch existed stays valid
            q = QgsProcessingParameterBoolean(p.name.upper(), tr(label), bool(p.default), optional=True)
        elif p.kind == "enum":
            q = QgsProcessingParameterEnum(p.name.upper(), tr(label), list(p.options), False,
                                           list(p.options).index(p.default) if p.default in p.options else 0)
        else:  # pragma: no cover - a wrong spec is a programming error
            raise TypeError(f"unknown Param kind {p.kind!r}")
        q.setHelp(tr(p.help))
        if is_advanced(self.METHOD_NAME, p):
            mark_advanced(q)
        return q

    def messageNames(self):  # noqa: N802
        """{name in messages: definition}: the parameter ids, and the core's names of its Params."""
        out = super().messageNames()
        for p in self.method.params:
            d = self.parameterDefinition(p.name.upper())
            if d is not None:
                out[p.name] = d
        return out

    def _user_params(self, parameters, context):
        """The core's keyword arguments; an empty optional number means "from the data" (None), an
        empty yes/no its default (QGIS reads an empty string as false)."""
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
            elif p.kind == "bool":   # empty (qgis_process KEY=, processing.run ''): its default, as a number's
                v = (bool(p.default) if parameters.get(key) in (None, "")
                     else self.parameterAsBool(parameters, key, context))
            else:
                v = p.options[self.parameterAsEnum(parameters, key, context)]
            out[p.name] = v
        return out

    # -- checks before any work ---------------------------------------------------------------
    @explained
    def checkParameterValues(self, parameters, context):  # noqa: N802
        ok, msg = super().checkParameterValues(parameters, context)
        if not ok:
            return ok, msg
        layer = self.parameterAsRasterLayer(parameters, self.INPUT, context)
        band = self.parameterAsInt(parameters, self.BAND, context) if parameters.get(self.BAND) else None
        ok, msg, info = check_dsm(layer, band)
        if not ok:
            return False, msg
        from ..core import memory
        from ..core.pipeline import check_cell_size, check_process_reach, check_relief_file
        try:
            memory.budget_mb()           # BARE_EARTH_MEMORY_MB 'abc' or 'inf': here, not after the parameters
            check_cell_size(info.cell_size_m)
            if parameters.get(self.PROCESSES) not in (None, ""):
                check_process_reach(info.path, self.parameterAsInt(parameters, self.PROCESSES, context))
            check_relief_file(info)      # heights far steeper than any terrain: refused here, not after Run
        except ValueError as exc:
            return False, str(exc)
        given = self._user_params(parameters, context)
        try:
            self.method.check_given(given)   # an even WINDOW_CELLS, limits in the wrong order: here, not after Run
        except ValueError as exc:
            return False, str(exc)
        user = {name.upper(): v for name, v in given.items()}
        ok, msg = check_window_sizes(self, user, {p.name.upper(): (p.default, *p.former_defaults)
                                                  for p in self.method.params}, info)
        if not ok:
            return False, msg
        types = {"OUTPUT_MASK": "Byte"}
        for k, (dt, _bands, _nodata) in self.method.extras.items():
            code = gdal_array.NumericTypeCodeToGDALTypeCode(np.dtype(dt).type)
            types[f"OUTPUT_{k.upper()}"] = gdal.GetDataTypeName(code)
        ok, msg = check_output_sizes(self, parameters, context, info.shape, types)
        if not ok:
            return False, msg
        return self.checkExtraInputs(parameters, context, info)

    def checkExtraInputs(self, parameters, context, info):  # noqa: N802
        """Subclasses check their own extra inputs; return (ok, message)."""
        return True, ""

    def auxiliaryArrays(self, parameters, context, info, feedback):  # noqa: N802
        """Subclasses turn extra layer inputs into per-cell arrays (e.g. break lines)."""
        return {}

    # -- the run ----------------------------------------------------------------------------
    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        from ..core import memory
        # BARE_EARTH_MEMORY_MB bounds the run's memory from here: the vector layers rasterised on the DSM's
        # grid and the parameters' window included, not QGIS's own
        with memory.run_baseline():
            return self._process_raster(parameters, context, feedback)

    def _process_raster(self, parameters, context, feedback):
        from ..core.pipeline import run_file
        layer = self.parameterAsRasterLayer(parameters, self.INPUT, context)
        band = self.parameterAsInt(parameters, self.BAND, context) if parameters.get(self.BAND) else None
        ranges = layer_nodata_ranges(layer, band)
        try:  # checkParameterValues scanned the data; run_file re-checks it from its own first read
            info = grid.open_dsm(raster_path(layer), band or None, ranges, layer_crs_wkt(layer))
        except ValueError as exc:
            raise QgsProcessingException(self.explain(str(exc))) from None
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
        feedback.pushInfo(tr("Input: {} band {}, {} x {} cells of {:.4g} x {:.4g} m").format(
            info.path, info.band_index, info.shape[1], info.shape[0], info.cell_size_m[0], info.cell_size_m[1]))
        try:
            log = run_logger(feedback)
            with output_options(self, parameters, context, feedback):
                result = run_file(self.METHOD_NAME, info.path, outputs, band=info.band_index, params=user,
                                  aux=aux, block=block, workers=threads, processes=processes,
                                  progress=progress_callback(feedback), log=log, nodata_ranges=ranges,
                                  crs_wkt=layer_crs_wkt(layer))
        except Cancelled:
            feedback.reportError(tr("Cancelled: no output was written."))
            return {}
        except ValueError as exc:
            raise QgsProcessingException(self.explain(str(exc))) from None
        self.logResult(result, feedback)
        return {f"OUTPUT_{k.upper()}": v for k, v in outputs.items()}

    def logResult(self, result, feedback):  # noqa: N802
        """Write the values used (by their labels) and the statistics (each once, with units)."""
        params = result.get("params", {})
        feedback.pushInfo(tr("Parameters used:"))
        for k, v in params.items():
            d = self.parameterDefinition(k.upper())
            feedback.pushInfo("  {} = {}".format(label_of(d) if d is not None else k, format_value(k, v)))
        feedback.pushInfo(tr("Result:"))
        for k, v in result.items():
            if k in ("params", "warnings", "method") or repeats_parameter(k, v, params):
                continue
            if isinstance(v, dict):
                feedback.pushInfo("  {}: {}".format(k, ", ".join("{} {}".format(a, format_value(inner_key(k, a), b))
                                                                   for a, b in v.items())))
            else:
                feedback.pushInfo("  {} = {}".format(k, format_value(k, v)))


#: name endings of the statistics that are fractions (printed in percent) and counts (integers)
_SHARE_WORDS = ("share", "fraction")
_COUNT_ENDINGS = ("_cells", "_outliers", "_regions", "_points", "_count", "_per_step", "_scan", "_edge")


def _is_count(key):
    return key.startswith(("n_", "removed_")) and not any(w in key for w in _SHARE_WORDS + ("percent", "seconds")) \
        or key.endswith(_COUNT_ENDINGS)


def inner_key(key, name):
    """The key a value inside a dict statistic is formatted by: its own name when that names a
    count ('nodata cells' in ``classes_percent`` is a number of cells, not a percentage)."""
    own = str(name).replace(" ", "_")
    return own if _is_count(own) else key


def format_value(key, v):
    """A value for the log: percentages with '%', shares (0-1) as percentages, counts as integers,
    seconds with 's', None as 'not used'."""
    if isinstance(v, (list, tuple)):
        return "(" + ", ".join(format_value(key, x) for x in v) + ")"
    if v is None:
        return "not used"
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)):
        return str(v)
    if "percent" in key:
        return "{:.4g} %".format(v)
    if any(w in key for w in _SHARE_WORDS):
        return "{:.4g} %".format(100.0 * v)
    if _is_count(key):
        return str(int(round(float(v))))
    if key.endswith("seconds"):
        return "{:.3g} s".format(v)
    return "{:.4g}".format(v) if isinstance(v, (float, np.floating)) else str(v)


def repeats_parameter(key, value, params):
    """True when a statistic only repeats a parameter used: the same name, or the same number in
    the same unit under the paper's symbol (alpha_g_deg = slope_threshold_deg)."""
    if key in params:
        return params[key] == value
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)):
        return False
    for name, v in params.items():
        unit = next((u for u in ("_deg", "_m") if name.endswith(u)), None)
        if unit and key.endswith(unit) and isinstance(v, (int, float)) and not isinstance(v, bool) \
                and math.isclose(float(v), float(value), rel_tol=1e-9, abs_tol=1e-12):
            return True
    return False
