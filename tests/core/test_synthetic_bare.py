"""The bare-terrain scenes (core/synthetic_bare.py, issue 12): seeded, all ground, the same fine surface
at every cell size, and the documented shapes (slopes, heights)."""
import numpy as np
import pytest

from bare_earth.core.codes import GROUND
from bare_earth.core.synthetic_bare import BARE, NOISE_M, make_bare


def _slopes_deg(z, cell):
    gy, gx = np.gradient(z.astype(np.float64), cell)
    return np.degrees(np.arctan(np.hypot(gx, gy)))


@pytest.mark.parametrize("kind", BARE)
def test_bare_scene_is_seeded_and_all_ground(kind):
    a, b = make_bare(kind, 2.0, seed=3), make_bare(kind, 2.0, seed=3)
    np.testing.assert_array_equal(a.dsm, b.dsm)
    assert a.dsm.shape == (200, 200) and a.dsm.dtype == np.float32 and a.cell_size == (2.0, 2.0)
    assert (a.mask == GROUND).all() and np.isfinite(a.dsm).all()
    # the noise is the scene's, around the true surface
    assert abs(float(np.std(a.dsm - a.dtm)) - NOISE_M[kind]) < 0.1 * NOISE_M[kind]
    # 1 and 2 m cells average the same fine surface
    fine = make_bare(kind, 1.0, seed=3)
    np.testing.assert_allclose(fine.dtm.reshape(200, 2, 200, 2).mean(axis=(1, 3)), a.dtm, atol=1e-3)


def test_bare_shapes_as_documented():
    """The slopes the module's docstring gives: dunes' slip faces at the angle of repose, dikes at
    1:2 at most, mounds' sides under 30 degrees (plus the cells' averaging), the mountain's median slope
    near 37 degrees, the levees' and terraces' heights."""
    def p(kind, q):
        return float(np.percentile(_slopes_deg(make_bare(kind, 1.0).dtm, 1.0), q))
    assert 32.0 < p("dunes", 99.9) < 34.5
    assert 25.0 < p("levees", 100) < 27.0
    assert p("mounds", 100) < 31.5
    assert 33.0 < p("mountain", 50) < 41.0
    lev = make_bare("levees", 0.5).dtm
    assert 6.0 < float(lev.max() - np.median(lev)) < 6.6
    with pytest.raises(ValueError, match="unknown bare scene"):
        make_bare("glacier")
    with pytest.raises(ValueError, match="multiple"):
        make_bare("hills", 0.7)
