"""Vector layers -> boolean rasters on a DSM's grid (break lines, special areas)."""
import numpy as np
from osgeo import gdal, ogr, osr
from qgis.core import QgsCoordinateReferenceSystem, QgsFeatureRequest


def rasterize_source(source, info, context, all_touched=True):
    """Burn the features of a Processing feature source onto ``info``'s grid.

    Features are reprojected to the DSM's CRS. Returns ``(bool array, feature count)``; an
    empty or missing source gives an all-False array.
    """
    rows, cols = info.shape
    out = np.zeros((rows, cols), bool)
    if source is None:
        return out, 0
    dest = QgsCoordinateReferenceSystem()
    if info.crs_wkt:
        dest = QgsCoordinateReferenceSystem.fromWkt(info.crs_wkt)
    req = QgsFeatureRequest()
    if dest.isValid() and source.sourceCrs().isValid() and source.sourceCrs() != dest:
        req.setDestinationCrs(dest, context.transformContext())
    drv = ogr.GetDriverByName("Memory")
    vds = drv.CreateDataSource("burn")
    srs = osr.SpatialReference()
    if info.crs_wkt:
        srs.ImportFromWkt(info.crs_wkt)
    layer = vds.CreateLayer("burn", srs if info.crs_wkt else None)
    n = 0
    for f in source.getFeatures(req):
        g = f.geometry()
        if g is None or g.isEmpty():
            continue
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
