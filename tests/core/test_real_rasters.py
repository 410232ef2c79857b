"""Every filter on the real DSMs in ../shared/data/raster (skips when the data is absent)."""
import numpy as np
import pytest
from osgeo import gdal

from bare_earth.core.methods import available_methods
from bare_earth.core.pipeline import run_file

RASTERS = ["raster/opengeos/dsm.tif", "raster/drone_dsm/test_dsm.tif", "raster/pleiades/pair_dsm.tif",
           "raster/pleiades/triplet_dsm.tif"]
#: Known failures: (method, raster) -> reason (strict xfail: the test says when one is fixed).
KNOWN = {}


def _cases():
    for r in RASTERS:
        for m in available_methods():
            marks = [pytest.mark.xfail(reason=KNOWN[(m, r)], strict=True)] if (m, r) in KNOWN else []
            yield pytest.param(m, r, marks=marks, id=f"{m}-{r.split('/')[-2]}-{r.split('/')[-1][:-4]}")


@pytest.mark.slow
@pytest.mark.parametrize("method,raster", list(_cases()))
def test_filter_on_real_dsm(shared_data, tmp_path, method, raster):
    src = shared_data / raster
    if not src.exists():
        pytest.skip(f"{src} is absent")
    info = run_file(method, src, {"dtm": tmp_path / "dtm.tif", "mask": tmp_path / "mask.tif"})
    ds = gdal.Open(str(src))
    band = ds.GetRasterBand(1)
    z = band.ReadAsArray().astype(float)
    nd = band.GetNoDataValue()
    nodata = ~np.isfinite(z) if nd is None or np.isnan(nd) else (z == nd) | ~np.isfinite(z)
    mds, dds = gdal.Open(str(tmp_path / "mask.tif")), gdal.Open(str(tmp_path / "dtm.tif"))
    mask, dtm = mds.GetRasterBand(1).ReadAsArray(), dds.GetRasterBand(1).ReadAsArray()
    assert dds.GetGeoTransform() == ds.GetGeoTransform()
    assert set(np.unique(mask)) <= {0, 1, 2, 255}
    np.testing.assert_array_equal(mask == 255, nodata)            # nodata kept, nothing else lost
    assert np.isfinite(dtm[~nodata]).all()
    ground = mask == 0
    np.testing.assert_allclose(dtm[ground], z[ground], rtol=0, atol=1e-3)
    share = info["classes_percent"]["object"]
    assert 0.1 < share < 80.0, share                              # some objects, mostly ground
