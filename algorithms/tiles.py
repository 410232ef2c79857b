"""``bareearth:tiles``: a whole survey of tiles through one filter on Dask distributed.

The QGIS face of ``core.survey.run_survey``: the tiles (several raster layers, a VRT, or a
folder), the method, its parameters as KEY=VALUE text, an output folder and optionally a
Dask scheduler's address. Progress per finished tile; cancel stops handing out tiles.
Without Dask the algorithm says what to install; every other algorithm works without it.
"""
from qgis.core import (
    QgsProcessingContext,
    QgsProcessingException,
    QgsProcessingOutputFile,
    QgsProcessingOutputRasterLayer,
    QgsProcessingParameterEnum,
    QgsProcessingParameterFile,
    QgsProcessingParameterFolderDestination,
    QgsProcessingParameterMultipleLayers,
    QgsProcessingParameterNumber,
    QgsProcessingParameterString,
)

from ..core import Cancelled
from ..core.methods import available_methods
from .compat import FILE_FOLDER, NUMBER_INTEGER, SOURCE_RASTER
from .filter_base import (
    BaseAlgorithm,
    layer_crs_wkt,
    layer_nodata_ranges,
    progress_callback,
    raster_path,
    run_logger,
    tr,
    with_help,
)


def check_layer_settings_in_file(layer):
    """QgsProcessingException when a tile layer carries settings its file does not: additional
    no-data values (Properties > Transparency) or a CRS given in QGIS to a file without one. The
    survey's workers read the tiles' files, where those settings are not, so the tiles would be
    filtered otherwise than QGIS draws them (a -9999 border taken as heights, feet as metres)."""
    path = raster_path(layer)
    if layer_nodata_ranges(layer, None):
        raise QgsProcessingException(tr(
            "The tile layer '{}' has additional no-data values set in QGIS (Properties > Transparency), "
            "which the survey's workers, reading {}, do not see: declare the no-data value in the file "
            "(gdal_edit -a_nodata VALUE) or give the tiles as a folder.").format(layer.name(), path))
    from osgeo import gdal
    try:
        ds = gdal.OpenEx(path, gdal.OF_RASTER)
    except RuntimeError:                  # unreadable: index_tiles names it
        ds = None
    if ds is not None and not ds.GetProjection() and layer_crs_wkt(layer):
        raise QgsProcessingException(tr(
            "The tile layer '{}' was given a CRS in QGIS ({}) that its file {} does not hold; the survey's "
            "workers read the file: write the CRS into it (gdal_edit -a_srs {}).").format(
            layer.name(), layer.crs().authid() or layer.crs().description(), path,
            layer.crs().authid() or "EPSG:XXXX"))

class TilesAlgorithm(BaseAlgorithm):
    """Filter a survey of tiles seamlessly into one DTM and one mask per tile plus mosaics."""

    GROUP = "survey"
    GROUP_NAME = "Surveys"
    TAGS = ("DTM", "ground", "bare earth", "terrain", "survey", "tiles", "mosaic", "VRT", "Dask", "cluster",
            "batch", "seamless")
    INPUT_LAYERS = "INPUT_LAYERS"
    INPUT_FOLDER = "INPUT_FOLDER"
    METHOD = "METHOD"
    PARAMETERS = "PARAMETERS"
    SCHEDULER = "SCHEDULER"
    WORKERS = "WORKERS"
    OUTPUT_FOLDER = "OUTPUT_FOLDER"
    OUTPUT_DTM = "OUTPUT_DTM"
    OUTPUT_MASK = "OUTPUT_MASK"
    OUTPUT_RECORD = "OUTPUT_RECORD"

    @staticmethod
    def _methods():
        return sorted(available_methods())

    def name(self):
        return "tiles"

    def displayName(self):  # noqa: N802
        return tr("Filter a whole survey of tiles (Dask)")

    def shortHelpString(self):  # noqa: N802
        return tr("<p>Filters a whole survey of DSM tiles with one method, as if it were one raster: the "
                  "parameters are derived once for the survey (from a sample spread over its tiles) and each "
                  "tile is read with the method's reach (halo) from its neighbours, so the mask has no seam. "
                  "The tiles run on Dask distributed: worker processes on this computer's cores, or an existing "
                  "Dask cluster given by its scheduler's address.</p>"
                  "<p>Outputs in the folder: one DTM and one mask per tile (cloud-optimised GeoTIFF on the "
                  "tile's grid), dtm.vrt and mask.vrt (loaded into the project; written only when every tile is "
                  "done: a run with a failed tile fails, naming it), run.json (parameters used, "
                  "each tile's status and timings, the workers). Running again with the same inputs and "
                  "parameters into the same folder does only the tiles not recorded as done (a run begun by another "
                  "version of the plugin is refused: its tiles would not join seamlessly).</p>"
                  "<p>Needs Dask distributed (python3-distributed on Debian; pip install \"dask[distributed]\" "
                  "elsewhere).</p><h3>Parameters</h3><ul>"
                  "<li><b>INPUT_LAYERS</b>: the tiles as raster layers, or one VRT over them.</li>"
                  "<li><b>INPUT_FOLDER</b>: or a folder holding the tiles.</li>"
                  "<li><b>METHOD</b>: the filter.</li>"
                  "<li><b>PARAMETERS</b>: the method's parameters as KEY=VALUE separated by spaces or "
                  "semicolons (names as in the method's own algorithm, in lower case); the others are "
                  "derived from the data.</li>"
                  "<li><b>SCHEDULER</b>: address of a Dask scheduler (tcp://host:8786); its workers must import "
                  "bare_earth and see the tiles and the output folder at the same paths. Empty: a local "
                  "cluster.</li><li><b>WORKERS</b>: local worker processes (0: one per core).</li></ul>")

    def initAlgorithm(self, config=None):  # noqa: N802
        self.addParameter(with_help(QgsProcessingParameterMultipleLayers(
            self.INPUT_LAYERS, tr("Tiles (raster layers, or one VRT)"), SOURCE_RASTER, optional=True),
            "The DSM tiles of the survey: one CRS, one cell size, one grid, not overlapping. One VRT layer "
            "stands for its source tiles."))
        self.addParameter(with_help(QgsProcessingParameterFile(
            self.INPUT_FOLDER, tr("Or a folder of tiles"), FILE_FOLDER, optional=True),
            "A folder whose rasters (.tif, .tiff, .img, ...) are the tiles."))
        methods = self._methods()
        self.addParameter(with_help(QgsProcessingParameterEnum(
            self.METHOD, tr("Method"), methods, False,
            next((methods.index(m) for m in ("dtm", "slopeprofile") if m in methods), 0)),
            "The filter run on every tile (default: the recommended one)."))
        self.addParameter(with_help(QgsProcessingParameterString(
            self.PARAMETERS, tr("Method parameters (KEY=VALUE ...)"), "", multiLine=False, optional=True),
            "For example, with slopeprofile: max_object_size_m=60 slope_threshold_deg=30 (dtm takes none). "
            "Empty: every parameter derived from the data (once for the whole survey)."))
        self.addParameter(with_help(QgsProcessingParameterString(
            self.SCHEDULER, tr("Dask scheduler address (empty: this computer)"), "", optional=True),
            "tcp://host:8786 of a running dask-scheduler; empty starts worker processes on this computer."))
        self.addParameter(with_help(QgsProcessingParameterNumber(
            self.WORKERS, tr("Local worker processes (0 = one per core)"), NUMBER_INTEGER,
            0, optional=True, minValue=0, maxValue=256),
            "Worker processes of the local cluster, one thread each; ignored with a scheduler address.",
            advanced=True))
        self.addParameter(with_help(QgsProcessingParameterFolderDestination(
            self.OUTPUT_FOLDER, tr("Output folder")),
            "Receives <tile>_dtm.tif and <tile>_mask.tif per tile, dtm.vrt, mask.vrt and run.json."))
        self.addOutput(QgsProcessingOutputRasterLayer(self.OUTPUT_DTM, tr("DTM mosaic (dtm.vrt)")))
        self.addOutput(QgsProcessingOutputRasterLayer(self.OUTPUT_MASK, tr("Mask mosaic (mask.vrt)")))
        self.addOutput(QgsProcessingOutputFile(self.OUTPUT_RECORD, tr("Run record (run.json)")))

    def _inputs(self, parameters, context):
        layers = self.parameterAsLayerList(parameters, self.INPUT_LAYERS, context) or []
        folder = self.parameterAsFile(parameters, self.INPUT_FOLDER, context) if parameters.get(self.INPUT_FOLDER) \
            else ""
        if layers and folder:
            raise QgsProcessingException(tr("Give the tiles as layers or as a folder, not both."))
        if folder:
            return folder
        if not layers:
            raise QgsProcessingException(tr("No tiles: choose raster layers, a VRT or a folder."))
        for lyr in layers:
            check_layer_settings_in_file(lyr)
        return [raster_path(lyr) for lyr in layers]

    def _method(self, parameters, context):
        return self._methods()[self.parameterAsEnum(parameters, self.METHOD, context)]

    def checkParameterValues(self, parameters, context):  # noqa: N802
        ok, msg = super().checkParameterValues(parameters, context)
        if not ok:
            return ok, msg
        from ..core.survey import (
            INSTALL_HINT,
            check_output_folder,
            check_survey_relief,
            engine,
            have_dask,
            index_tiles,
            parse_params,
        )
        if not have_dask():
            return False, tr(INSTALL_HINT)
        try:
            parse_params(self._method(parameters, context),
                         self.parameterAsString(parameters, self.PARAMETERS, context))
            scheduler = (self.parameterAsString(parameters, self.SCHEDULER, context) or "").strip()
            engine.check_scheduler_address(scheduler)
            if not scheduler and parameters.get(self.WORKERS) not in (None, ""):
                engine.check_workers(self.parameterAsInt(parameters, self.WORKERS, context))
            inputs = self._inputs(parameters, context)
            index = index_tiles(inputs)
            check_survey_relief(index)   # heights far steeper than any terrain: refused here, not after Run
            out_dir = self.parameterAsString(parameters, self.OUTPUT_FOLDER, context)
            if out_dir:
                check_output_folder(index, out_dir, inputs)
        except (ValueError, QgsProcessingException) as exc:
            return False, str(exc)
        return True, ""

    def processAlgorithm(self, parameters, context, feedback):  # noqa: N802
        import os

        from ..core.survey import parse_params, require_dask, run_survey
        try:
            require_dask()
            method = self._method(parameters, context)
            params = parse_params(method, self.parameterAsString(parameters, self.PARAMETERS, context))
            inputs = self._inputs(parameters, context)
        except (ImportError, ValueError) as exc:
            raise QgsProcessingException(str(exc)) from None
        out_dir = self.parameterAsString(parameters, self.OUTPUT_FOLDER, context)
        scheduler = (self.parameterAsString(parameters, self.SCHEDULER, context) or "").strip() or None
        workers = self.parameterAsInt(parameters, self.WORKERS, context) if parameters.get(self.WORKERS) else 0
        try:
            rec = run_survey(method, inputs, out_dir, params, workers=workers, scheduler=scheduler,
                             progress=progress_callback(feedback), log=run_logger(feedback))
        except Cancelled:
            if not os.path.isfile(os.path.join(out_dir, "run.json")):     # while the parameters were derived
                feedback.reportError(tr("Cancelled while the parameters were derived: nothing was written."))
                return {}
            feedback.reportError(tr("Cancelled: the finished tiles are recorded in run.json; run again to finish."))
            return {self.OUTPUT_FOLDER: out_dir}
        except (ValueError, ImportError) as exc:
            raise QgsProcessingException(str(exc)) from None
        failed = rec["this_run"]["failed"]
        if not rec.get("complete"):
            missing = rec.get("missing_tiles", [])
            raise QgsProcessingException(tr(
                "The survey is incomplete: {} tile(s) not done ({} failed: {}), so no dtm.vrt or mask.vrt was "
                "written; the log gives each failure. Run the algorithm again with the same inputs, parameters "
                "and output folder {}: the finished tiles are kept (run.json) and only the missing ones are "
                "done.").format(len(missing), len(failed), ", ".join(sorted(failed)[:10]) or "none", out_dir))
        out = {self.OUTPUT_FOLDER: out_dir, self.OUTPUT_RECORD: os.path.join(out_dir, "run.json")}
        for key, name in ((self.OUTPUT_DTM, "dtm.vrt"), (self.OUTPUT_MASK, "mask.vrt")):
            path = os.path.join(out_dir, name)
            if os.path.exists(path):
                out[key] = path
                if context.project() is not None:
                    context.addLayerToLoadOnCompletion(path, QgsProcessingContext.LayerDetails(
                        os.path.splitext(name)[0], context.project(), key))
        return out
