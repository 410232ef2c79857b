"""The tenth adversarial QA pass: inputs of odd shapes and layouts (several bands where one is
read, ...). Each test failed before the fix it names."""
import json

import numpy as np
import pytest

pytestmark = pytest.mark.qgis
GT = (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0)


def _write(path, arr, gt=GT, epsg=32632, nodata=None, **kw):
    from bare_earth.core.grid import write_array
    return write_array(path, arr, gt, epsg, nodata=nodata, **kw)


def _mask(shape=(40, 40)):
    m = np.zeros(shape, np.uint8)
    m[10:20, 10:20] = 1
    return m


def _rgb(mask):
    """A mask as QGIS exports its rendering (Save as > Rendered image): red, green, blue."""
    return np.stack([np.where(mask == 1, 255, 0), np.where(mask == 1, 0, 160), np.zeros_like(mask)]).astype(np.uint8)


def test_evaluate_and_filldtm_refuse_several_bands_where_they_read_one(processing_run, tmp_path):
    """MASK, REFERENCE_MASK, DTM and REFERENCE_DTM of evaluate and filldtm's MASK have no band
    choice: a raster of several bands was read by its band 1 without a word (a mask exported as
    a rendered RGB image compared by its red: kappa 100 % against itself in colours, or a
    three-band stack compared by its first band)."""
    from qgis.core import QgsProcessingException
    m = _mask()
    rgb = _write(tmp_path / "mask_rgb.tif", _rgb(m))
    codes = _write(tmp_path / "mask.tif", m, nodata=255)
    z = np.zeros((40, 40), np.float32) + np.linspace(0.0, 3.0, 40, dtype=np.float32)
    stack = _write(tmp_path / "stack.tif", np.stack([z + 7.0, z]))
    dtm = _write(tmp_path / "dtm.tif", z)
    out = {"OUTPUT_JSON": str(tmp_path / "e.json"), "OUTPUT_HTML": str(tmp_path / "e.html")}
    for params, key in ((dict(MASK=rgb, REFERENCE_MASK=codes), "MASK"),
                        (dict(MASK=codes, REFERENCE_MASK=rgb), "REFERENCE_MASK"),
                        (dict(DTM=stack, REFERENCE_DTM=dtm), "DTM"),
                        (dict(DTM=dtm, REFERENCE_DTM=stack), "REFERENCE_DTM")):
        with pytest.raises(QgsProcessingException, match=rf"\b{key}\)?: the raster .* has [23] bands but this "
                                                         "input is read from a single band"):
            processing_run("bareearth:evaluate", dict(params, **out))
    assert not (tmp_path / "e.json").exists()
    filled = tmp_path / "filled.tif"
    with pytest.raises(QgsProcessingException, match="MASK: the raster .* has 3 bands.*rendered image"):
        processing_run("bareearth:filldtm", {"INPUT": dtm, "MASK": rgb, "OUTPUT": str(filled)})
    assert not filled.exists()


def test_evaluate_reads_the_height_band_beside_an_alpha_band(processing_run, tmp_path):
    """A DTM with an alpha band (gdalwarp -dstalpha) is one band of heights and its mask: still
    compared, its transparent cells left out."""
    from osgeo import gdal
    z = np.zeros((40, 40), np.float32) + np.linspace(0.0, 3.0, 40, dtype=np.float32)
    alpha = np.full((40, 40), 255, np.float32)
    alpha[:, :10] = 0
    path = _write(tmp_path / "dtm_alpha.tif", np.stack([z + 0.5, alpha]))
    ds = gdal.Open(path, gdal.GA_Update)
    ds.GetRasterBand(2).SetColorInterpretation(gdal.GCI_AlphaBand)
    ds = None
    ref = _write(tmp_path / "ref.tif", z)
    res = processing_run("bareearth:evaluate", {"DTM": path, "REFERENCE_DTM": ref,
                                                "OUTPUT_JSON": str(tmp_path / "e.json"),
                                                "OUTPUT_HTML": str(tmp_path / "e.html")})
    assert res["RMSE"] == pytest.approx(0.5, abs=1e-6)
    report = json.loads((tmp_path / "e.json").read_text())
    assert "1200" in json.dumps(report)                 # 30 x 40 cells compared


def test_orthophoto_tools_refuse_a_bottom_up_dem_before_work_saying_how(processing_run, tmp_path):
    """A DEM stored bottom-up (gt[5] > 0, as some exports write it; the filters take it) failed in
    orthoparallax with "geotransform must be north-up with positive cell size (dx > 0, dy < 0)",
    naming neither the input nor the fix; now refused before work naming the DEM and gdalwarp."""
    from qgis.core import QgsProcessingException
    rng = np.random.default_rng(0)
    up = (500000.0, 1.0, 0.0, 5399960.0, 0.0, 1.0)
    dem = _write(tmp_path / "dem_up.tif", np.full((40, 40), 100.0, np.float32), up)
    a = _write(tmp_path / "a.tif", rng.uniform(0, 255, (40, 40)).astype(np.float32), up)
    b = _write(tmp_path / "b.tif", rng.uniform(0, 255, (40, 40)).astype(np.float32), up)
    out = tmp_path / "out_dem.tif"
    for alg, params in (("orthoparallax", {"ORTHO_A": a, "ORTHO_B": b, "BASE_M": 100.0, "HEIGHT_M": 400.0}),
                        ("orthorefine", {"IMAGES": [a, b], "BASE_M": 100.0, "HEIGHT_M": 400.0})):
        with pytest.raises(QgsProcessingException, match=r"DEM: the raster .*dem_up.tif' is stored bottom-up .*"
                                                         r"gdalwarp"):
            processing_run(f"bareearth:{alg}", dict(params, DEM=dem, OUTPUT_DEM=str(out)))
        assert not out.exists()
