"""run_file with worker processes: same mask as one pass, bounded, cancellable."""
import numpy as np
import pytest
from osgeo import gdal

from bare_earth.core import Cancelled
from bare_earth.core.grid import write_array
from bare_earth.core.pipeline import run_file
from bare_earth.core.synthetic import make_scene


@pytest.fixture
def dsm(tmp_path):
    sc = make_scene("city", shape=(300, 260), seed=4)
    return write_array(tmp_path / "dsm.tif", sc.dsm, sc.geotransform, sc.epsg)


def _read(p):
    ds = gdal.Open(str(p))
    return ds.GetRasterBand(1).ReadAsArray()


def test_processes_give_the_one_pass_mask(dsm, tmp_path):
    one = run_file("slopeprofile", dsm, {"mask": tmp_path / "m1.tif", "dtm": tmp_path / "d1.tif"})
    par = run_file("slopeprofile", dsm, {"mask": tmp_path / "m2.tif", "dtm": tmp_path / "d2.tif"},
                   processes=2, block=100)
    assert one["blocks"] == 1 and par["blocks"] > 2
    np.testing.assert_array_equal(_read(tmp_path / "m1.tif"), _read(tmp_path / "m2.tif"))
    d1, d2 = _read(tmp_path / "d1.tif"), _read(tmp_path / "d2.tif")
    ground = _read(tmp_path / "m1.tif") == 0
    np.testing.assert_array_equal(d1[ground], d2[ground])           # ground cells exact in both
    assert np.abs(d1 - d2).max() < 1.0                               # filled cells: nearly the same
    assert par["classes_percent"] == one["classes_percent"]


def test_processes_cancel_leaves_nothing(dsm, tmp_path):
    calls = []

    def progress(f):
        calls.append(f)
        if f > 0.2:
            raise Cancelled()

    with pytest.raises(Cancelled):
        run_file("slopeprofile", dsm, {"mask": tmp_path / "m.tif", "dtm": tmp_path / "d.tif"},
                 processes=2, block=64, progress=progress)
    assert not (tmp_path / "m.tif").exists() and not (tmp_path / "d.tif").exists()
    assert not list(tmp_path.glob("*.partial*"))
