"""bareearth:dtm through processing.run: object areas, ground areas (points), break lines, the
confidence output and the log."""
import numpy as np
import pytest
from surfaces import noisy

pytestmark = pytest.mark.qgis

EPSG = 32633
X0, Y0 = 500000.0, 5000000.0


def _write(tmp_path, name, z):
    from bare_earth.core.grid import write_array
    return write_array(tmp_path / name, z.astype(np.float32), (X0, 1.0, 0.0, Y0, 0.0, -1.0), EPSG)


def _xy(r, c):
    """Map coordinates of a cell corner (row, col) on the 1 m test grid."""
    return X0 + c, Y0 - r


def _layer(kind, geoms):
    from qgis.core import QgsFeature, QgsGeometry, QgsPointXY, QgsVectorLayer
    lay = QgsVectorLayer(f"{kind}?crs=EPSG:{EPSG}", kind.lower(), "memory")
    feats = []
    for g in geoms:
        f = QgsFeature()
        if kind == "Polygon":
            f.setGeometry(QgsGeometry.fromPolygonXY([[QgsPointXY(*p) for p in g]]))
        elif kind == "LineString":
            f.setGeometry(QgsGeometry.fromPolylineXY([QgsPointXY(*p) for p in g]))
        else:
            f.setGeometry(QgsGeometry.fromPointXY(QgsPointXY(*g)))
        feats.append(f)
    lay.dataProvider().addFeatures(feats)
    return lay


def _read(path):
    from osgeo import gdal
    ds = gdal.Open(str(path))      # held while the band is read
    return ds.GetRasterBand(1).ReadAsArray()



def test_object_areas_and_confidence(processing_run, tmp_path):
    y, x = np.mgrid[0:300, 0:300].astype(np.float32)
    ground = 50 + 0.02 * x + 0.01 * y
    wh = np.zeros(ground.shape, bool)
    wh[60:240, 60:240] = True
    path = _write(tmp_path, "warehouse.tif", noisy(ground + np.where(wh, 9.0, 0.0)))
    base = {"INPUT": str(path), "OUTPUT_DTM": str(tmp_path / "dtm0.tif"), "OUTPUT_MASK": str(tmp_path / "m0.tif")}
    processing_run("bareearth:dtm", base)
    # 180 m: wider than every member's window; bounded by walls, it is found alone (dtm_regions)
    assert (_read(tmp_path / "m0.tif")[wh] == 1).all()
    assert np.sqrt(np.mean((_read(tmp_path / "dtm0.tif") - ground)[wh] ** 2)) < 0.1
    square = [_xy(60.25, 60.25), _xy(60.25, 239.75), _xy(239.75, 239.75), _xy(239.75, 60.25), _xy(60.25, 60.25)]
    res = processing_run("bareearth:dtm", {"INPUT": str(path), "OUTPUT_DTM": str(tmp_path / "dtm.tif"),
                                           "OUTPUT_MASK": str(tmp_path / "m.tif"),
                                           "OUTPUT_CONFIDENCE": str(tmp_path / "conf.tif"),
                                           "OBJECT_AREAS": _layer("Polygon", [square])})
    assert (_read(res["OUTPUT_MASK"])[wh] == 1).all()
    assert np.sqrt(np.mean((_read(res["OUTPUT_DTM"]) - ground)[wh] ** 2)) < 0.1
    conf = _read(res["OUTPUT_CONFIDENCE"])
    assert conf.dtype == np.uint8 and (conf[wh] == 100).all() and conf.max() <= 100


def test_breaklines_keep_a_terrace(processing_run, tmp_path):
    y, x = np.mgrid[0:160, 0:160].astype(np.float32)
    ground = 100 + 0.02 * y + np.clip(np.minimum((x - 65) / 3.0, (95 - x) / 3.0), 0, 1) * 4.0
    path = _write(tmp_path, "terrace.tif", noisy(ground))
    lines = [[_xy(0, c + 0.5), _xy(160, c + 0.5)] for c in (65, 68, 92, 95)]
    out = {"OUTPUT_DTM": "TEMPORARY_OUTPUT", "OUTPUT_MASK": str(tmp_path / "m.tif")}
    res = processing_run("bareearth:dtm", {"INPUT": str(path), **out, "BREAKLINES": _layer("LineString", lines)})
    assert (_read(res["OUTPUT_MASK"]) != 0).sum() == 0


def test_ground_area_points_keep_a_car_park(processing_run, tmp_path):
    y, x = np.mgrid[0:200, 0:200].astype(np.float32)
    cp = np.zeros(y.shape, bool)
    cp[80:120, 80:120] = True
    ground = 20 + 0.01 * x + np.where(cp, 2.5, 0.0)
    z = noisy(ground)
    rng = np.random.default_rng(1)
    for cy, cx, r in zip(rng.integers(0, 200, 120), rng.integers(0, 200, 120), rng.uniform(3, 6, 120)):
        d = np.hypot(y - cy, x - cx)
        z = np.where((d < r) & ~cp, np.maximum(z, ground + 12 * (1 - (d / r) ** 2)), z).astype(np.float32)
    path = _write(tmp_path, "carpark.tif", z)
    pts = [_xy(r + 0.5, c + 0.5) for r in range(80, 120) for c in range(80, 120)]
    res = processing_run("bareearth:dtm", {"INPUT": str(path), "OUTPUT_DTM": str(tmp_path / "dtm.tif"),
                                           "OUTPUT_MASK": str(tmp_path / "m.tif"),
                                           "GROUND_AREAS": _layer("Point", pts)})
    assert (_read(res["OUTPUT_MASK"])[cp] == 0).all()
    assert np.sqrt(np.mean((_read(res["OUTPUT_DTM"]) - ground)[cp] ** 2)) < 0.1
