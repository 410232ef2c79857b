"""Exact tests of the shared estimates of core/estimate.py."""
import numpy as np
import pytest

from bare_earth.core.estimate import GROUND_MIN_SAMPLES, ground_level_reference, noise_ground_level
from bare_earth.core.synthetic import make_canopy


def test_ground_level_reference_of_a_plane_is_the_plane_minus_the_block_drop():
    # a plane rising 0.1 per metre in x: each 20 m block's minimum is at its west column
    x = np.arange(80, dtype=np.float32)
    z = np.tile(0.1 * x, (40, 1))
    ref, slope, k = ground_level_reference(z, (1.0, 1.0), block_m=20.0)
    assert k == 20
    assert slope == pytest.approx(0.1, rel=1e-6)
    # block centres sit at column 9.5 + 20 j with the value of column 20 j: 0.95 m lower
    inner = ref[:, 10:70]
    assert np.allclose(z[:, 10:70] - inner, 0.95, atol=1e-4)


@pytest.mark.parametrize("noise", [0.05, 0.3])
def test_noise_on_ground_level_cells_ignores_a_closed_canopy_at_every_cell_size(noise):
    # 85 % crowns over gentle ground: measured on the whole surface the "noise" of the
    # 4 m grid is the canopy's relief (metres); on the ground-level cells it is the noise
    values = []
    for cell in (0.5, 1.0, 2.0, 4.0):
        s = make_canopy(512.0, cell, cover=0.85, seed=0, noise_m=noise)
        got = noise_ground_level(s.dsm, s.cell_size)
        assert got["samples"] >= GROUND_MIN_SAMPLES
        assert got["sigma"] == pytest.approx(noise, rel=0.2), cell
        values.append(got["sigma"])
    assert max(values) / min(values) < 1.2


def test_noise_on_a_bare_noisy_plane_is_its_standard_deviation():
    rng = np.random.default_rng(1)
    y, x = np.mgrid[0:300, 0:300]
    z = (0.2 * x + 0.05 * y + rng.normal(0.0, 0.1, x.shape)).astype(np.float32)
    got = noise_ground_level(z, (1.0, 1.0))
    assert got["ground_share"] > 0.99
    assert got["sigma"] == pytest.approx(0.1, rel=0.05)


def test_noise_is_nan_when_too_few_ground_level_cells_are_seen():
    z = np.zeros((5, 5), np.float32)
    got = noise_ground_level(z, (1.0, 1.0))
    assert np.isnan(got["sigma"]) and got["samples"] < GROUND_MIN_SAMPLES
    assert np.isnan(noise_ground_level(np.full((8, 8), np.nan, np.float32), (1.0, 1.0))["sigma"])


def test_morphological_defaults_on_a_canopy_at_4_m_stay_progressive_with_the_ground_noise():
    # the issue-12 failure: noise 4.46 m measured on the canopy -> dh 5 m, single window
    from bare_earth.core.morphology import resolve_morphological_params
    s = make_canopy(512.0, 4.0, cover=0.85, seed=0, noise_m=0.05)
    p = resolve_morphological_params(s.dsm, s.cell_size)
    assert p["noise_m"] == pytest.approx(0.05, rel=0.3)
    assert p["dh_m"] == 0.5
    assert p["mode"] == "progressive"


def test_make_canopy_is_the_same_landscape_at_every_cell_size():
    a = make_canopy(64.0, 1.0, seed=2, noise_m=0.0)
    b = make_canopy(64.0, 0.5, seed=2, noise_m=0.0)
    # cell centres of the 1 m grid are corners of the 0.5 m grid's cells: compare the
    # cover and the terrain instead, which are continuous functions sampled
    assert abs((a.mask == 1).mean() - (b.mask == 1).mean()) < 0.03
    assert np.allclose(a.dtm, b.dtm.reshape(64, 2, 64, 2).mean(axis=(1, 3)), atol=0.01)
    with pytest.raises(ValueError, match="16 cells"):
        make_canopy(10.0, 1.0)


def _brute_below_ring(z, depth, r, c):
    out = np.zeros(z.shape, bool)
    for i in range(z.shape[0]):
        for j in range(z.shape[1]):
            lo = np.inf
            for di in range(-r, r + 1):
                for dj in range(-r, r + 1):
                    ii, jj = i + di, j + dj
                    if max(abs(di), abs(dj)) > c and 0 <= ii < z.shape[0] and 0 <= jj < z.shape[1] \
                            and np.isfinite(z[ii, jj]):
                        lo = min(lo, z[ii, jj])
            out[i, j] = np.isfinite(lo) and z[i, j] < lo - depth
    return out


@pytest.mark.parametrize("cell", [1.0, 0.5])
def test_below_surroundings_equals_the_brute_force_ring_minimum(cell):
    from bare_earth.core.estimate import below_surroundings
    rng = np.random.default_rng(4)
    z = rng.normal(0.0, 1.0, (23, 29)).astype(np.float32)
    z[5, 7] = np.nan
    got = below_surroundings(z, (cell, cell), 0.5, radius_m=6.0, cluster_m=1.0)
    r, c = int(np.ceil(6.0 / cell)), max(2, int(np.ceil(1.0 / cell)))
    assert (got == _brute_below_ring(z, 0.5, r, c)).all()


def test_below_surroundings_tells_a_blunder_from_a_gap_between_crowns():
    from bare_earth.core.estimate import below_surroundings
    z = np.full((40, 40), 20.0, np.float32)          # canopy
    z[::6, ::6] = 0.0                                  # gaps down to the ground every 6 m
    z[21, 21] = -5.0                                   # a blunder below the ground
    got = below_surroundings(z, (1.0, 1.0), 0.5)
    assert got[21, 21]
    assert not got[::6, ::6].any()


def test_low_blunders_of_the_filters_are_not_the_gaps_of_a_canopy_at_4_m():
    from bare_earth.core.codes import LOW
    from bare_earth.core.pipeline import run_array
    s = make_canopy(512.0, 4.0, cover=0.85, seed=0, noise_m=0.05)
    gaps = s.mask == 0
    for name in ("slopeprofile", "rascor"):
        res = run_array(name, s.dsm, s.cell_size)
        assert np.mean(res.mask[gaps] == LOW) < 0.05, name   # slope profile before: 0.92


def test_curvature_threshold_comes_from_the_ground_not_the_canopy():
    # the same ground with and without a closed canopy gives the same K_g (order of
    # magnitude); on the whole surface the canopy's bends set it thousands of times higher
    from bare_earth.core.curvature import derive_k_g
    s = make_canopy(256.0, 1.0, cover=0.85, seed=1, noise_m=0.05)
    bare = make_canopy(256.0, 1.0, cover=0.0, seed=1, noise_m=0.05)
    k_canopy = derive_k_g(s.dsm, s.cell_size)
    k_bare = derive_k_g(bare.dsm, bare.cell_size)
    assert k_canopy < 10 * k_bare
