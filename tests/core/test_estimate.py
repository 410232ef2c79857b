"""Shared estimates (core/estimate.py): tiny exact arrays, then statistics of known noise."""
import math

import numpy as np
import pytest

from bare_earth.core import estimate as est


# --------------------------------------------------------------------------- sampling
def test_sample_windows_small_raster_is_used_whole():
    z = np.zeros((10, 12), np.float32)
    w = est.sample_windows(z, cells=120, side=4)
    assert len(w) == 1 and w[0] is z
    narrow = np.zeros((5, 1000), np.float32)                 # narrower than two windows
    assert est.sample_windows(narrow, cells=100, side=4)[0] is narrow


def test_sample_windows_exact_positions_and_views():
    z = np.arange(20 * 30, dtype=np.float32).reshape(20, 30)
    w = est.sample_windows(z, cells=64, side=4)               # 4 windows of 4 x 4
    # ny = round(sqrt(4 * 20 / 30)) = 2, nx = ceil(4 / 2) = 2, centred on the quadrants:
    # rows int(0.25 * 20 - 2) = 3, int(0.75 * 20 - 2) = 13; cols int(5.5) = 5, int(20.5) = 20
    starts = [(int(v[0, 0]) // 30, int(v[0, 0]) % 30) for v in w]
    assert starts == [(3, 5), (3, 20), (13, 5), (13, 20)]
    assert all(v.shape == (4, 4) and np.shares_memory(v, z) for v in w)
    np.testing.assert_array_equal(w[3], z[13:17, 20:24])


# --------------------------------------------------------------------------- block minima
@pytest.mark.parametrize("shape,k", [((7, 5), 2), ((40, 41), 20), ((20, 20), 20), ((3, 9), 4), ((4, 3), 1)])
def test_block_minima_exact(shape, k):
    rng = np.random.default_rng(1)
    z = rng.random(shape).astype(np.float32)
    z[rng.random(shape) < 0.3] = np.nan
    z[:k, :k] = np.nan                                   # an all-nodata block
    nr, nc = -(-shape[0] // k), -(-shape[1] // k)
    expect = np.full((nr, nc), np.nan, np.float32)
    for i in range(nr):
        for j in range(nc):
            b = z[i * k:(i + 1) * k, j * k:(j + 1) * k]
            if np.isfinite(b).any():
                expect[i, j] = np.nanmin(b)
    got = est.block_minima(z, k)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, expect)


def test_block_minima_inf_is_nodata_and_bad_k():
    z = np.array([[1, -np.inf, 5], [np.inf, 2, 7]], np.float32)
    np.testing.assert_array_equal(est.block_minima(z, 2), [[1, 5]])
    np.testing.assert_array_equal(est.block_minima(np.array([[np.inf, 3]]), 1), [[np.nan, 3]])
    with pytest.raises(ValueError, match="at least 1"):
        est.block_minima(z, 0)


# --------------------------------------------------------------------------- terrain slope
def test_terrain_slopes_of_a_plane_under_objects():
    yy, xx = np.mgrid[0:12, 0:16].astype(np.float32)
    z = 0.5 * xx + 0.25 * yy                              # a plane: slope hypot(0.5, 0.25)
    z[1, 1] += 10.0                                       # an object: not the block's minimum
    s = est.terrain_slopes(z, (1.0, 1.0), 4)                # block minima 3 x 4, spacing 4
    assert s.shape == (12,)
    np.testing.assert_allclose(s, math.hypot(0.5, 0.25))
    s = est.terrain_slopes(z, (2.0, 1.0), 4)                # cells 2 m wide: half the x slope
    np.testing.assert_allclose(s, math.hypot(0.25, 0.25))


def test_terrain_slopes_too_few_blocks_and_nodata():
    z = np.zeros((8, 8), np.float32)
    assert est.terrain_slopes(z, (1.0, 1.0), 4).size == 4          # 2 x 2 blocks
    assert est.terrain_slopes(z, (1.0, 1.0), 4, min_blocks=3).size == 0
    assert est.terrain_slopes(z, (1.0, 1.0), 8).size == 0          # one block
    z[:4, :4] = np.nan                                            # one block without data
    s = est.terrain_slopes(z, (1.0, 1.0), 4)
    assert s.size == 1 and s[0] == 0.0    # NaN gradients dropped: only the block far from it


# --------------------------------------------------------------------------- noise
def test_noise_second_difference_exact():
    # one row: second differences 0 - 2*1 + 0 = -2 and 1 - 0 + 1 = 2: median |d| = 2
    z = np.array([[0, 1, 0, 1]], np.float32)
    assert est.noise_second_difference(z) == pytest.approx(1.4826 * 2 / math.sqrt(6), rel=1e-12)
    yy, xx = np.mgrid[0:5, 0:6].astype(np.float32)
    assert est.noise_second_difference(3 * xx - 2 * yy) == 0.0     # planes have none
    assert est.noise_second_difference(np.ones((2, 2), np.float32)) == 0.0
    z = np.array([[0, 1, 0, np.nan, 0]], np.float32)             # NaN differences dropped
    assert est.noise_second_difference(z) == pytest.approx(1.4826 * 2 / math.sqrt(6), rel=1e-12)


def test_noise_second_difference_quartile_exact():
    # d = [2, -2, 2, -2, ...] along one row: median 0, |d| = 2 everywhere
    z = np.tile(np.array([0, 1], np.float32), 8)[None, :]
    assert est.noise_second_difference_quartile(z) == pytest.approx(2 / 0.3186 / math.sqrt(6), rel=1e-6)
    assert est.noise_second_difference_quartile(z[:, :5]) == 0.1             # fewer than 10
    assert est.noise_second_difference_quartile(z[:, :5], default=0.0) == 0.0


def test_noise_plane_residual_exact():
    z = np.zeros((3, 3), np.float32)
    z[1, 1] = 1.25                                  # one residual: 1.25 - 0
    assert est.noise_plane_residual(z) == pytest.approx(1.25 / 0.3186 / math.sqrt(1.25), rel=1e-7)
    yy, xx = np.mgrid[0:6, 0:7].astype(np.float32)
    assert est.noise_plane_residual(xx - 0.5 * yy) == 0.0
    assert est.noise_plane_residual(np.ones((2, 9), np.float32)) == 0.0


@pytest.mark.parametrize("func", [est.noise_second_difference, est.noise_second_difference_quartile,
                                  est.noise_plane_residual])
def test_noise_estimators_measure_white_noise_on_a_slope(func):
    rng = np.random.default_rng(2)
    yy, xx = np.mgrid[0:300, 0:300]
    z = (0.3 * xx + 0.1 * yy + rng.normal(0, 0.2, xx.shape)).astype(np.float32)
    assert func(z) == pytest.approx(0.2, rel=0.1)
    z[100:160, 100:160] += 15.0                      # an object: its edges barely move it
    assert func(z) == pytest.approx(0.2, rel=0.12)


def test_noise_on_a_large_raster_is_sampled_over_all_of_it():
    # noise everywhere but in a quiet central square: a central window would see none,
    # windows spread over the raster see the noise
    rng = np.random.default_rng(3)
    z = rng.normal(0, 0.2, (1200, 1200)).astype(np.float32)
    z[460:740, 460:740] = 0.0
    w = est.sample_windows(z)
    assert len(w) == 16 and all(v.shape == (256, 256) for v in w)
    assert est.noise_second_difference(z[472:728, 472:728]) == 0.0
    for func in (est.noise_second_difference, est.noise_second_difference_quartile, est.noise_plane_residual):
        assert func(z) == pytest.approx(0.2, rel=0.2)      # the quiet share pulls it down a little


def test_noise_plane_residual_too_few_residuals():
    z = np.zeros((3, 4), np.float32)                # two residuals
    z[1, 1] = 1.25
    assert est.noise_plane_residual(z, min_count=3, default=0.1) == 0.1
    assert est.noise_plane_residual(z, min_count=2) == pytest.approx(
        float(np.percentile([1.25, 0.3125], 25)) / 0.3186 / math.sqrt(1.25), rel=1e-7)


def test_noise_plane_residual_in_float64():
    z = np.zeros((3, 3))
    z[1, 1] = 0.1                                   # not a float32 number
    assert est.noise_plane_residual(z, dtype=np.float64) == 0.1 / 0.3186 / math.sqrt(1.25)
    assert est.noise_plane_residual(z) == float(np.float32(0.1)) / 0.3186 / math.sqrt(1.25)


def test_smooth_spread_exact():
    # two 2 x 2 tiles of one band: [0, 0, 0, 4] has median 0, MAD 0; [0, 2, 4, 6] has
    # median 3, |v - 3| = [3, 1, 1, 3], MAD 2
    v = np.array([[[0, 0, 0, 2], [0, 4, 4, 6]]], np.float32)
    tiles = [0.0, 1.4826 * 2]
    assert est.smooth_spread([v], tile=2, quantile=0.5) == pytest.approx(np.quantile(tiles, 0.5), rel=1e-12)
    assert est.smooth_spread([v], tile=2, quantile=1.0) == pytest.approx(1.4826 * 2, rel=1e-12)
    assert est.smooth_spread([v, v[:, :, :2]], tile=2, quantile=0.0) == 0.0          # pooled
    assert est.smooth_spread([np.full((1, 2, 2), np.nan)], tile=2) == 0.0


def test_noise_second_difference_tiles_exact_and_measured():
    yy, xx = np.mgrid[0:20, 0:20].astype(np.float32)
    assert est.noise_second_difference_tiles(2 * xx + yy) == 0.0
    assert est.noise_second_difference_tiles(np.zeros((2, 50), np.float32)) == 0.0
    rng = np.random.default_rng(5)
    z = (0.2 * xx + rng.normal(0, 0.1, xx.shape)).astype(np.float32)
    big = np.pad(z, 140, mode="reflect")                         # 300 x 300, same noise
    assert est.noise_second_difference_tiles(big, quantile=0.5) == pytest.approx(0.1, rel=0.15)
