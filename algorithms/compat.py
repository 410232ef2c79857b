"""QGIS 3.22 LTR to QGIS 4 (Qt6): every QGIS enum the QGIS layer uses, resolved once, here.

QGIS 3.36 moved the unscoped enums this plugin uses (``QgsProcessing.TypeVectorPolygon``,
``QgsProcessingParameterNumber.Double``, ``QgsProcessingParameterDefinition.FlagAdvanced``, ...)
to scoped ones on ``Qgis`` (``Qgis.ProcessingSourceType.VectorPolygon``, ...); QGIS 4 (PyQt6)
drops the old spellings. Each name below is the scoped value when this QGIS has it, else the
3.22 value written scoped within its class (``QgsProcessing.SourceType.TypeVectorPolygon``:
PyQt5 accepts that form too), so no module of the QGIS layer spells an enum itself and
``tests/plugin/test_qgis4_compat.py`` can scan for the removed forms.

Qt enums are written scoped where they are used (``Qt.AlignmentFlag.AlignLeft``), which PyQt5
and PyQt6 both accept; they need no entry here.
"""
from qgis.core import (
    Qgis,
    QgsColorRampShader,
    QgsCoordinateReferenceSystem,
    QgsFeatureRequest,
    QgsProcessing,
    QgsProcessingFeatureSource,
    QgsProcessingParameterDefinition,
    QgsProcessingParameterFile,
    QgsProcessingParameterNumber,
    QgsRasterRange,
    QgsWkbTypes,
)


def resolve(new, old):
    """The value at ``new`` when this QGIS has it, else the one at ``old``.

    Parameters
    ----------
    new, old : tuple of (object, str)
        An owner (``Qgis``, a class) and a dotted path under it, e.g.
        ``(Qgis, "ProcessingSourceType.VectorPolygon")``. ``new`` is the QGIS >= 3.36 / QGIS 4
        spelling, ``old`` the QGIS 3.22 one.

    Returns
    -------
    The enum value. AttributeError naming both paths when neither exists.
    """
    for owner, path in (new, old):
        value = owner
        try:
            for part in path.split("."):
                value = getattr(value, part)
        except AttributeError:
            continue
        return value
    raise AttributeError("neither {}.{} nor {}.{} exists in this QGIS".format(
        getattr(new[0], "__name__", new[0]), new[1], getattr(old[0], "__name__", old[0]), old[1]))


def as_int(value):
    """An enum value as a plain int (PyQt6 enums are no ints; a list such as
    ``QgsProcessingParameterLimitedDataTypes.dataTypes()`` holds ints in every QGIS)."""
    return value if isinstance(value, int) else int(value.value)


#: name -> (QGIS >= 3.36 / 4 spelling, QGIS 3.22 spelling): the one copy of each mapping.
ENUMS = {
    "SOURCE_FILE": ((Qgis, "ProcessingSourceType.File"), (QgsProcessing, "SourceType.TypeFile")),
    "SOURCE_RASTER": ((Qgis, "ProcessingSourceType.Raster"), (QgsProcessing, "SourceType.TypeRaster")),
    "SOURCE_VECTOR_POINT": ((Qgis, "ProcessingSourceType.VectorPoint"),
                            (QgsProcessing, "SourceType.TypeVectorPoint")),
    "SOURCE_VECTOR_LINE": ((Qgis, "ProcessingSourceType.VectorLine"), (QgsProcessing, "SourceType.TypeVectorLine")),
    "SOURCE_VECTOR_POLYGON": ((Qgis, "ProcessingSourceType.VectorPolygon"),
                              (QgsProcessing, "SourceType.TypeVectorPolygon")),
    "NUMBER_DOUBLE": ((Qgis, "ProcessingNumberParameterType.Double"), (QgsProcessingParameterNumber, "Type.Double")),
    "NUMBER_INTEGER": ((Qgis, "ProcessingNumberParameterType.Integer"),
                       (QgsProcessingParameterNumber, "Type.Integer")),
    "FILE_FILE": ((Qgis, "ProcessingFileParameterBehavior.File"), (QgsProcessingParameterFile, "Behavior.File")),
    "FILE_FOLDER": ((Qgis, "ProcessingFileParameterBehavior.Folder"), (QgsProcessingParameterFile, "Behavior.Folder")),
    "FLAG_ADVANCED": ((Qgis, "ProcessingParameterFlag.Advanced"),
                      (QgsProcessingParameterDefinition, "Flag.FlagAdvanced")),
    "FLAG_OPTIONAL": ((Qgis, "ProcessingParameterFlag.Optional"),
                      (QgsProcessingParameterDefinition, "Flag.FlagOptional")),
    "GEOMETRY_POINT": ((Qgis, "GeometryType.Point"), (QgsWkbTypes, "GeometryType.PointGeometry")),
    "GEOMETRY_LINE": ((Qgis, "GeometryType.Line"), (QgsWkbTypes, "GeometryType.LineGeometry")),
    "GEOMETRY_POLYGON": ((Qgis, "GeometryType.Polygon"), (QgsWkbTypes, "GeometryType.PolygonGeometry")),
    "INVALID_GEOMETRY_NO_CHECK": ((Qgis, "InvalidGeometryCheck.NoCheck"),
                                  (QgsFeatureRequest, "InvalidGeometryCheck.GeometryNoCheck")),
    "INVALID_GEOMETRY_SKIP": ((Qgis, "InvalidGeometryCheck.SkipInvalid"),
                              (QgsFeatureRequest, "InvalidGeometryCheck.GeometrySkipInvalid")),
    "INVALID_GEOMETRY_ABORT": ((Qgis, "InvalidGeometryCheck.AbortOnInvalid"),
                               (QgsFeatureRequest, "InvalidGeometryCheck.GeometryAbortOnInvalid")),
    "SOURCE_SKIP_GEOMETRY_CHECKS": ((Qgis, "ProcessingFeatureSourceFlag.SkipGeometryValidityChecks"),
                                    (QgsProcessingFeatureSource, "Flag.FlagSkipGeometryValidityChecks")),
    "SHADER_LINEAR": ((Qgis, "ShaderInterpolationMethod.Linear"), (QgsColorRampShader, "Type.Interpolated")),
    "RANGE_INCLUDE_MIN_AND_MAX": ((Qgis, "RasterRangeLimit.IncludeMinAndMax"),
                                  (QgsRasterRange, "BoundsType.IncludeMinAndMax")),
    "RANGE_INCLUDE_MIN": ((Qgis, "RasterRangeLimit.IncludeMin"), (QgsRasterRange, "BoundsType.IncludeMin")),
    "RANGE_INCLUDE_MAX": ((Qgis, "RasterRangeLimit.IncludeMax"), (QgsRasterRange, "BoundsType.IncludeMax")),
    "WKT_PREFERRED_GDAL": ((Qgis, "CrsWktVariant.PreferredGdal"),
                           (QgsCoordinateReferenceSystem, "WktVariant.WKT_PREFERRED_GDAL")),
}

SOURCE_FILE = resolve(*ENUMS["SOURCE_FILE"])
SOURCE_RASTER = resolve(*ENUMS["SOURCE_RASTER"])
SOURCE_VECTOR_POINT = resolve(*ENUMS["SOURCE_VECTOR_POINT"])
SOURCE_VECTOR_LINE = resolve(*ENUMS["SOURCE_VECTOR_LINE"])
SOURCE_VECTOR_POLYGON = resolve(*ENUMS["SOURCE_VECTOR_POLYGON"])
NUMBER_DOUBLE = resolve(*ENUMS["NUMBER_DOUBLE"])
NUMBER_INTEGER = resolve(*ENUMS["NUMBER_INTEGER"])
FILE_FILE = resolve(*ENUMS["FILE_FILE"])
FILE_FOLDER = resolve(*ENUMS["FILE_FOLDER"])
FLAG_ADVANCED = resolve(*ENUMS["FLAG_ADVANCED"])
FLAG_OPTIONAL = resolve(*ENUMS["FLAG_OPTIONAL"])
GEOMETRY_POINT = resolve(*ENUMS["GEOMETRY_POINT"])
GEOMETRY_LINE = resolve(*ENUMS["GEOMETRY_LINE"])
GEOMETRY_POLYGON = resolve(*ENUMS["GEOMETRY_POLYGON"])
INVALID_GEOMETRY_NO_CHECK = resolve(*ENUMS["INVALID_GEOMETRY_NO_CHECK"])
INVALID_GEOMETRY_SKIP = resolve(*ENUMS["INVALID_GEOMETRY_SKIP"])
INVALID_GEOMETRY_ABORT = resolve(*ENUMS["INVALID_GEOMETRY_ABORT"])
SOURCE_SKIP_GEOMETRY_CHECKS = resolve(*ENUMS["SOURCE_SKIP_GEOMETRY_CHECKS"])
SHADER_LINEAR = resolve(*ENUMS["SHADER_LINEAR"])
RANGE_INCLUDE_MIN_AND_MAX = resolve(*ENUMS["RANGE_INCLUDE_MIN_AND_MAX"])
RANGE_INCLUDE_MIN = resolve(*ENUMS["RANGE_INCLUDE_MIN"])
RANGE_INCLUDE_MAX = resolve(*ENUMS["RANGE_INCLUDE_MAX"])
WKT_PREFERRED_GDAL = resolve(*ENUMS["WKT_PREFERRED_GDAL"])


def mark_advanced(param):
    """Put ``param`` under the dialog's "Advanced parameters"; returns it."""
    param.setFlags(param.flags() | FLAG_ADVANCED)
    return param


def is_optional(definition):
    """Whether a parameter definition is optional."""
    return bool(definition.flags() & FLAG_OPTIONAL)
