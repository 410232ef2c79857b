"""Vector layers -> boolean rasters on a DSM's grid (break lines, special areas)."""
import math

import numpy as np
from osgeo import gdal, ogr, osr
from qgis.core import (
    QgsCoordinateReferenceSystem,
    QgsFeatureRequest,
    QgsGeometry,
    QgsProcessingFeatureSource,
    QgsWkbTypes,
)

from .compat import (
    GEOMETRY_LINE,
    GEOMETRY_POINT,
    GEOMETRY_POLYGON,
    INVALID_GEOMETRY_ABORT,
    INVALID_GEOMETRY_NO_CHECK,
    INVALID_GEOMETRY_SKIP,
    SOURCE_SKIP_GEOMETRY_CHECKS,
    SOURCE_VECTOR_LINE,
    SOURCE_VECTOR_POINT,
    SOURCE_VECTOR_POLYGON,
    as_int,
)

#: The geometry kind and its name of each Processing vector type a layer input accepts, by the
#: type's int (``dataTypes()`` lists ints in every QGIS; PyQt6 enums are no ints).
KINDS = {as_int(SOURCE_VECTOR_POINT): (GEOMETRY_POINT, "points"),
         as_int(SOURCE_VECTOR_LINE): (GEOMETRY_LINE, "lines"),
         as_int(SOURCE_VECTOR_POLYGON): (GEOMETRY_POLYGON, "polygons")}


def _has_geometry(source, fid):
    """Whether feature ``fid`` of ``source`` has a geometry in the layer's own CRS (a point QGIS
    cannot reproject comes back without one)."""
    g = next(iter(source.getFeatures(QgsFeatureRequest(fid))), None)
    g = None if g is None else g.geometry()
    return g is not None and not g.isNull() and not g.isEmpty()


def _not_in_crs_message(source, fid, label, dest):
    """The refusal of a feature whose coordinates the layer's CRS cannot take to the DSM's (the
    transform gave infinite coordinates): projected metres in a layer said to be in degrees."""
    crs = source.sourceCrs()
    name = crs.authid() or crs.description() or "unknown"
    where = ""
    for f in source.getFeatures(QgsFeatureRequest(fid)):
        box = f.geometry().boundingBox()
        where = f" ({box.xMinimum():.10g}, {box.yMinimum():.10g})"
    return (f"{label}: the coordinates of feature {fid}{where} are not coordinates of the layer's CRS "
            f"({name}): they cannot be taken to the DSM's ({dest.authid() or dest.description()}). Give the layer "
            "the CRS its coordinates are in (Layer Properties > Source > Assigned Coordinate Reference System, "
            "or Vector > Data Management Tools > Assign Projection).")


def source_geometries(source, info, context, label="the layer", types=None):
    """The geometries of a Processing feature source in the DSM's CRS, checked.

    Empty geometries are left out. ValueError naming ``label`` and the fix for a geometry of
    a kind the input does not take (``types``: Processing vector types, e.g. points given
    as object areas) and, as Processing's "invalid features filtering" setting says (stop,
    the default), for an invalid one; with "skip" invalid ones are left out, with "do not
    filter" kept (GDAL burns them as drawn). QGIS's own check is not used: its exception
    raised inside the feature iterator broke the next Python call of the session.

    Returns
    -------
    list of QgsGeometry, number of invalid geometries skipped
    """
    dest = QgsCoordinateReferenceSystem()
    if info.crs_wkt:
        dest = QgsCoordinateReferenceSystem.fromWkt(info.crs_wkt)
    req = QgsFeatureRequest()
    if dest.isValid() and source.sourceCrs().isValid() and source.sourceCrs() != dest:
        req.setDestinationCrs(dest, context.transformContext())
    allowed = {KINDS[as_int(t)][0]: KINDS[as_int(t)][1] for t in (types or ()) if as_int(t) in KINDS}
    names = {k: n for k, n in KINDS.values()}
    check = context.invalidGeometryCheck() if context is not None else INVALID_GEOMETRY_ABORT
    if isinstance(source, QgsProcessingFeatureSource):
        features = source.getFeatures(req, SOURCE_SKIP_GEOMETRY_CHECKS)
    else:
        features = source.getFeatures(req)
    out, skipped = [], 0
    for f in features:
        g = f.geometry()
        if g is None or g.isNull() or g.isEmpty():
            if req.destinationCrs().isValid() and _has_geometry(source, f.id()):   # lost in the reprojection
                raise ValueError(_not_in_crs_message(source, f.id(), label, dest))
            continue
        if req.destinationCrs().isValid():
            box = g.boundingBox()
            if not all(math.isfinite(v) for v in (box.xMinimum(), box.yMinimum(), box.xMaximum(), box.yMaximum())):
                raise ValueError(_not_in_crs_message(source, f.id(), label, dest))
        if allowed and g.type() not in allowed:
            kind = names.get(g.type()) or f"{QgsWkbTypes.displayString(g.wkbType())} geometries"  # a collection
            raise ValueError(f"{label} holds {kind} (feature {f.id()}) but takes "
                             f"{' or '.join(allowed.values())}: give a layer of {' or '.join(allowed.values())}.")
        if check != INVALID_GEOMETRY_NO_CHECK and not g.isGeosValid():
            if check == INVALID_GEOMETRY_SKIP:
                skipped += 1
                continue
            errors = g.validateGeometry()
            why = errors[0].what() if errors else "invalid"
            raise ValueError(f"{label}: feature {f.id()} has an invalid geometry ({why}): repair the layer "
                             "(Vector > Geometry Tools > Fix Geometries), or set Processing's invalid features "
                             "filtering to skip or not to filter them.")
        out.append(g)
    return out, skipped


def rasterize_source(source, info, context, all_touched=True, label="the layer", types=None):
    """Burn the features of a Processing feature source onto ``info``'s grid.

    Features are reprojected to the DSM's CRS and checked (:func:`source_geometries`); curved
    ones are burned as their segmented shape (QGIS's default segmentation).
    Returns ``(bool array, feature count)``; an empty or missing source gives an all-False
    array.
    """
    rows, cols = info.shape
    out = np.zeros((rows, cols), bool)
    if source is None:
        return out, 0
    geometries, _skipped = source_geometries(source, info, context, label, types)
    drv = ogr.GetDriverByName("Memory")
    vds = drv.CreateDataSource("burn")
    srs = osr.SpatialReference()
    if info.crs_wkt:
        srs.ImportFromWkt(info.crs_wkt)
    layer = vds.CreateLayer("burn", srs if info.crs_wkt else None)
    n = 0
    for g in geometries:
        if g.constGet().hasCurvedSegments():   # arcs (CurvePolygon, CompoundCurve...): GDAL burns none
            g = QgsGeometry(g.constGet().segmentize())
        og = ogr.CreateGeometryFromWkb(bytes(g.asWkb()))
        if og is None:
            continue
        feat = ogr.Feature(layer.GetLayerDefn())
        feat.SetGeometry(og)
        layer.CreateFeature(feat)
        n += 1
    if n == 0:
        return out, 0
    mem = gdal.GetDriverByName("MEM").Create("", cols, rows, 1, gdal.GDT_Byte)
    mem.SetGeoTransform(info.geotransform)
    if info.crs_wkt:
        mem.SetProjection(info.crs_wkt)
    opts = ["ALL_TOUCHED=TRUE"] if all_touched else []
    gdal.RasterizeLayer(mem, [1], layer, burn_values=[1], options=opts)
    out = mem.GetRasterBand(1).ReadAsArray().astype(bool)
    return out, n
