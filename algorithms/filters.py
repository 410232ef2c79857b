"""One thin algorithm class per filter method of the core.

Everything but the method name and the help of its side products comes from the core's
``METHOD`` spec (parameters, defaults, help) and from ``FilterAlgorithm``.
"""
from .compat import SOURCE_VECTOR_LINE, SOURCE_VECTOR_POINT, SOURCE_VECTOR_POLYGON
from .filter_base import FilterAlgorithm
from .points import PointsInputMixin


def check_layers(alg, parameters, context, info, keys):
    """(ok, message) before any work: each given layer input holds only the geometry kinds it
    takes, and valid ones as Processing's setting asks (:func:`vector_raster.source_geometries`)."""
    from .filter_base import label_of
    from .vector_raster import source_geometries
    for key in keys:
        if not parameters.get(key):
            continue
        d = alg.parameterDefinition(key)
        src = alg.parameterAsSource(parameters, key, context)
        if src is None:
            return False, alg.tr("{}: the layer cannot be read.").format(label_of(d))
        try:
            source_geometries(src, info, context, label_of(d), d.dataTypes())
        except ValueError as exc:
            return False, str(exc)
    return True, ""


def layer_arrays(alg, parameters, context, info, feedback, keys):
    """``{name: bool array}`` of the layer inputs burnt on the DSM's grid (None for an empty
    layer); the log gives each one's features and cells, and warns when features lie wholly
    outside the DSM (a layer in the wrong CRS, or of another place)."""
    from .filter_base import label_of, warning_logger
    from .vector_raster import rasterize_source
    out = {}
    for key, name in keys:
        if parameters.get(key):
            d = alg.parameterDefinition(key)
            src = alg.parameterAsSource(parameters, key, context)
            try:
                arr, n = rasterize_source(src, info, context, all_touched=True, label=label_of(d),
                                          types=d.dataTypes())
            except ValueError as exc:
                from qgis.core import QgsProcessingException
                raise QgsProcessingException(str(exc)) from None
            feedback.pushInfo(alg.tr("{}: {} feature(s), {} cells").format(name, n, int(arr.sum())))
            if n and not arr.any():
                warning_logger(feedback)(alg.tr(
                    "{}: none of its {} feature(s) touches the DSM, so it changes nothing: check that it "
                    "covers this DSM and that its CRS ({}) is the one its coordinates are in.").format(
                        label_of(d), n, src.sourceCrs().authid() or alg.tr("none")))
            out[name] = arr if n else None
    return out


class DtmAlgorithm(FilterAlgorithm):
    """``bareearth:dtm``: the recommended filter: the majority of three filters built on different
    principles, a confidence map, and what the user knows (object areas, ground areas, break lines)."""
    METHOD_NAME = "dtm"
    METHOD_TAGS = ("recommended", "ensemble", "confidence", "break lines", "building footprints")
    OBJECT_AREAS = "OBJECT_AREAS"
    GROUND_AREAS = "GROUND_AREAS"
    BREAKLINES = "BREAKLINES"
    EXTRA_HELP = {"confidence": "Confidence, UInt8 0-100 (255 nodata): how sure each cell's class is, from the "
                                "members' agreement, the cell's distance from the height threshold and the share "
                                "of cells around it with the same class; cells under the optional layers are "
                                "100. Look first where it is low."}

    def extraInputs(self):  # noqa: N802
        from qgis.core import QgsProcessingParameterFeatureSource

        from .filter_base import with_help
        return [
            with_help(QgsProcessingParameterFeatureSource(
                self.OBJECT_AREAS, self.tr("Object areas (e.g. building footprints)"),
                [SOURCE_VECTOR_POLYGON], optional=True),
                "Optional polygons (any CRS; reprojected to the DSM's) that are objects whatever the filters "
                "say, e.g. building footprints: every cell they touch is an object and the ground under them "
                "is interpolated. An empty layer is allowed; one covering every cell of the DSM (and no ground "
                "area) is refused, as no ground would be left."),
            with_help(QgsProcessingParameterFeatureSource(
                self.GROUND_AREAS, self.tr("Ground areas (known bare ground)"),
                [SOURCE_VECTOR_POLYGON, SOURCE_VECTOR_POINT], optional=True),
                "Optional polygons or points (any CRS) of known bare ground: their cells are ground whatever "
                "the filters say (a car park under trees, survey points). They win over object areas. An "
                "empty layer is allowed."),
            with_help(QgsProcessingParameterFeatureSource(
                self.BREAKLINES, self.tr("Break lines"), [SOURCE_VECTOR_LINE], optional=True),
                "Optional lines (any CRS) along crests, toes, terrace edges and embankment shoulders: no "
                "comparison crosses them (as in RASCOR), and near them RASCOR's decision, which honours them, "
                "stands alone. An empty layer is allowed."),
        ]

    def checkExtraInputs(self, parameters, context, info):  # noqa: N802
        return check_layers(self, parameters, context, info, (self.OBJECT_AREAS, self.GROUND_AREAS, self.BREAKLINES))

    def auxiliaryArrays(self, parameters, context, info, feedback):  # noqa: N802
        arrays = layer_arrays(self, parameters, context, info, feedback, (
            (self.OBJECT_AREAS, "object_areas"), (self.GROUND_AREAS, "ground_areas"), (self.BREAKLINES, "breaklines")))
        objects, ground = arrays.get("object_areas"), arrays.get("ground_areas")
        if objects is not None and objects.all() and (ground is None or not ground.any()):
            # every cell forced an object: no ground left to interpolate the DTM from (a study-area or parcel
            # polygon among the footprints); the run wrote a DTM of nodata and blamed the filter
            from qgis.core import QgsProcessingException

            from .filter_base import label_of
            raise QgsProcessingException(self.tr(
                "{} covers every cell of the DSM, so every cell would be an object and the DTM, with no ground "
                "to interpolate from, nodata everywhere: give the objects' footprints only (a study-area or "
                "parcel polygon is no object), or known ground as GROUND_AREAS.").format(
                    label_of(self.parameterDefinition(self.OBJECT_AREAS))))
        return arrays

    def logResult(self, result, feedback):  # noqa: N802
        """The input's description and each member's parameters on a line of their own, then the rest."""
        from .filter_base import format_value
        params = dict(result.get("params", {}))
        members = params.pop("members", None) or {}
        desc = params.pop("input_description", None) or {}

        def listed(d):
            return ", ".join("{} {}".format(k, format_value(k, v)) for k, v in d.items())
        feedback.pushInfo(self.tr("Input: {}").format(listed(desc)))
        feedback.pushInfo(self.tr("Members (each with the parameters it derived from the data):"))
        for name, p in members.items():
            feedback.pushInfo("  {}: {}".format(name, listed(p)))
        super().logResult(dict(result, params=params), feedback)


class SlopeProfileAlgorithm(FilterAlgorithm):
    """``bareearth:slopeprofile``: slope along X/Y profiles (Luong Chinh Ke 2002, sec. 2.1)."""
    METHOD_NAME = "slopeprofile"
    METHOD_TAGS = ("slope", "profile")


class CurvatureAlgorithm(FilterAlgorithm):
    """``bareearth:curvature``: local trend by Gaussian curvature (Luong Chinh Ke 2002, sec. 2.2)."""
    METHOD_NAME = "curvature"
    METHOD_TAGS = ("curvature", "Gaussian curvature")
    EXTRA_HELP = {"curvature": "Curvature, two Float32 bands: Gaussian curvature K (1/m^2) and mean "
                               "curvature H (1/m; H > 0 convex, H < 0 concave): what the filter saw, to "
                               "choose K_G_PER_M2."}


class GeodesicAlgorithm(PointsInputMixin, FilterAlgorithm):
    """``bareearth:geodesic``: gradual geodesic dilation with scan labelling (2018), on a DSM
    raster (INPUT) or directly on points (INPUT_POINTS: rasterize, filter, classify)."""
    METHOD_NAME = "geodesic"
    METHOD_TAGS = ("geodesic", "dilation", "reconstruction")
    EXTRA_HELP = {"step": "Step, UInt8: which dilation step (1, 2, ...) or which later stage removed each "
                          "cell (codes in the algorithm's help); 0 kept, 255 nodata."}


class RascorAlgorithm(FilterAlgorithm):
    """``bareearth:rascor``: the RASCOR sequence (Jacobsen 2004), with break lines and special areas."""
    METHOD_NAME = "rascor"
    METHOD_TAGS = ("RASCOR", "break lines", "matching blunders")
    BREAKLINES = "BREAKLINES"
    SPECIAL_AREAS = "SPECIAL_AREAS"
    EXTRA_HELP = {"step": "Step, UInt8: which RASCOR step removed each cell (0 kept, k = step k, 255 "
                          "nodata); the share removed by each step is in the log."}

    def extraInputs(self):  # noqa: N802
        from qgis.core import QgsProcessingParameterFeatureSource

        from .filter_base import with_help
        return [
            with_help(QgsProcessingParameterFeatureSource(
                self.BREAKLINES, self.tr("Break lines"), [SOURCE_VECTOR_LINE], optional=True),
                "Optional lines (any CRS; reprojected to the DSM's) along crests, toes, cuts and "
                "embankment shoulders: no comparison crosses them, so a dam or a road embankment keeps "
                "its shoulders. An empty layer is allowed."),
            with_help(QgsProcessingParameterFeatureSource(
                self.SPECIAL_AREAS, self.tr("Special areas"), [SOURCE_VECTOR_POLYGON], optional=True),
                "Optional polygons (any CRS) inside which only a local filter runs (cars and bushes on a "
                "dam's slope). An empty layer is allowed."),
        ]

    def checkExtraInputs(self, parameters, context, info):  # noqa: N802
        return check_layers(self, parameters, context, info, (self.BREAKLINES, self.SPECIAL_AREAS))

    def auxiliaryArrays(self, parameters, context, info, feedback):  # noqa: N802
        return layer_arrays(self, parameters, context, info, feedback,
                            ((self.BREAKLINES, "breaklines"), (self.SPECIAL_AREAS, "special_areas")))


class MorphologicalAlgorithm(PointsInputMixin, FilterAlgorithm):
    """``bareearth:morphological``: grey opening, single or progressive (SMRF / Zhang 2003), on a
    DSM raster (INPUT) or directly on points (INPUT_POINTS: rasterize, filter, classify)."""
    METHOD_NAME = "morphological"
    METHOD_TAGS = ("morphology", "morphological", "opening", "SMRF", "progressive")
