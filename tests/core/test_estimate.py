"""Shared estimates (core/estimate.py): tiny exact arrays, then statistics of known noise."""
import math

import numpy as np
import pytest

from bare_earth.core import estimate as est
from bare_earth.core.estimate import GROUND_MIN_SAMPLES, ground_level_reference, noise_ground_level
from bare_earth.core.synthetic import make_canopy


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


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int16])
def test_cell_slopes_equal_the_gradient_at_the_candidates(dtype):
    """Central differences inside, one-sided at the raster's edges (``np.gradient``), at the candidates only,
    in their flat order; the cell's width and height in metres."""
    rng = np.random.default_rng(3)
    z = rng.integers(-50, 50, (7, 9)).astype(dtype)
    cand = rng.random(z.shape) < 0.4
    cand[0, 0] = cand[-1, -1] = cand[3, 4] = True
    gy, gx = np.gradient(z.astype(np.float64), 0.5, 2.0)
    np.testing.assert_allclose(est.cell_slopes(z, (2.0, 0.5), cand), np.hypot(gx, gy)[cand], rtol=1e-12)
    assert est.cell_slopes(z, (1.0, 1.0), np.zeros(z.shape, bool)).shape == (0,)


def test_cell_slopes_nodata_neighbours_and_single_rows():
    z = np.array([[0.0, 2.0, np.nan, 6.0]], np.float32)        # one row: no slope down the columns
    s = est.cell_slopes(z, (1.0, 1.0), np.ones(z.shape, bool))
    assert s[0] == 2.0 and np.isnan(s[1]) and s[2] == 2.0 and np.isnan(s[3])
    assert est.cell_slopes(z.T, (1.0, 4.0), np.array([[True], [False], [False], [False]])).tolist() == [0.5]


@pytest.mark.parametrize("shape, k, side", [((800, 800), 400, 266), ((3000, 2000), 400, 400), ((120, 500), 40, 40),
                                           ((116, 200), 40, 40), ((80, 200), 40, 26), ((3, 3), 40, 2), ((9, 9), 1, 1)])
def test_held_block_side_exact(shape, k, side):
    """``k`` while the shorter axis holds 3 blocks (the last may be partial), else a third of it,
    at least 2 cells."""
    assert est.held_block_side(shape, k) == side
    assert est.held_block_side((80, 200), 40, min_blocks=2) == 40
    assert est.held_block_side((40, 200), 40, min_blocks=2) == 20
    assert est.held_block_side((12, 12), 40, min_side=5) == 5


def test_block_minima_plane_residual_exact():
    yy, xx = np.mgrid[0:12, 0:12].astype(np.float32)
    z = 0.7 * xx - 0.2 * yy + 5.0                      # a steep tilted plane: the minima lie on a plane
    z[1, 1] += 10.0                                     # an object smaller than a block: not a minimum
    assert est.block_minima_plane_residual(z, (1.0, 1.0), 4) == pytest.approx(0.0, abs=1e-5)
    z[4:, 4:] += 9.0                                    # a roof over 4 of the 9 blocks
    m = est.block_minima(z, 4).astype(np.float64)
    i, j = np.nonzero(np.isfinite(m))
    a = np.column_stack([np.ones(i.size), 4 * j, 4 * i])
    r = m[i, j] - a @ np.linalg.lstsq(a, m[i, j], rcond=None)[0]
    assert est.block_minima_plane_residual(z, (1.0, 1.0), 4) == pytest.approx(np.abs(r).max())
    assert est.block_minima_plane_residual(z, (1.0, 1.0), 4) > 2.0
    assert np.isnan(est.block_minima_plane_residual(z[:4, :8], (1.0, 1.0), 4))     # 2 blocks


# --------------------------------------------------------------------------- terrain bends
def test_terrain_bends_of_a_paraboloid_under_objects_exact():
    """z = c x^2 + e y^2 (x, y >= 0): each block's minimum is its first cell, so the block
    minima are the surface at the block corners and their second differences over ``k``
    cells, divided by ``k^2``, are exactly the surface's over one cell: 2c along the rows,
    2e along the columns, whatever the block; an object on a block's other cells is not
    seen."""
    yy, xx = np.mgrid[0:12, 0:16].astype(np.float64)
    z = 0.25 * xx ** 2 + 0.5 * yy ** 2
    for k in (1, 2, 4):
        d = est.terrain_bends(z if k == 1 else z + 40.0 * ((yy == 5) & (xx == 6)), k)  # not a minimum
        nr, nc = -(-12 // k), -(-16 // k)
        assert d.size == nr * (nc - 2) + (nr - 2) * nc
        np.testing.assert_allclose(d[:nr * (nc - 2)], 0.5)          # along the rows: 2c
        np.testing.assert_allclose(d[nr * (nc - 2):], 1.0)          # along the columns: 2e


def test_terrain_bends_of_a_plane_vanish_too_few_blocks_and_nodata():
    yy, xx = np.mgrid[0:12, 0:16].astype(np.float32)
    np.testing.assert_allclose(est.terrain_bends(3.0 * xx - 2.0 * yy, 4), 0.0, atol=1e-5)
    assert est.terrain_bends(np.zeros((8, 8), np.float32), 4).size == 0        # 2 x 2 blocks
    assert est.terrain_bends(np.zeros((8, 12), np.float32), 4).size == 2       # 3 blocks along x
    z = np.zeros((12, 12), np.float32)
    z[:4, :4] = np.nan                                    # a block without data: its bends dropped
    assert est.terrain_bends(z, 4).size == 2 * 3 * 1 - 2



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
    # a plane (slopes off any grid of heights: on one, e.g. xx - 0.5 yy, its heights read as
    # rounded to 0.5 m and the noise as their rounding error, height_quantum)
    assert est.noise_plane_residual(np.sqrt(2) * xx - np.pi * yy) == pytest.approx(0.0, abs=1e-6)
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


# ------------------------------------------- the ground level under canopy and roofs (#12)
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


def test_lift_low_blocks_lifts_a_blunder_and_keeps_a_ditch_floor_exactly():
    # 3 x 4 blocks of 4 x 4 cells on level ground: a pit of one cell (1/16 of its block)
    # is a blunder, the block takes the minimum of its other cells; a ditch crossing the
    # next block (4/16 of its cells) is its ground and stays
    z = np.zeros((12, 16), np.float32)
    z[5, 5] = -24.0
    z[6, 8:12] = -24.0
    m = est.block_minima(z, 4)
    got, n = est.lift_low_blocks(z, m, 4, 2.0, share=0.1)
    want = np.zeros((3, 4), np.float32)
    want[1, 2] = -24.0
    assert n == 1
    np.testing.assert_array_equal(got, want)


def test_lift_low_blocks_keeps_a_hollow_wider_than_a_block():
    # a hollow 3 x 3 blocks wide, 10 m deep: its blocks hold nothing else (its corners,
    # 4 of their neighbourhood's 9, are below the median but wholly low)
    z = np.zeros((28, 28), np.float32)
    z[8:20, 8:20] = -10.0
    m = est.block_minima(z, 4)
    got, n = est.lift_low_blocks(z, m, 4, 2.0)
    assert n == 0
    np.testing.assert_array_equal(got, m)


def test_ground_level_reference_without_the_blocks_a_multipath_line_pulled_down():
    # a plane with a line of pits 24 m deep along a wall (ISPRS samp41): the plain
    # reference drops by the pits' depth over their blocks; lifted, it is the plane's
    x = np.arange(100, dtype=np.float32)
    z = np.tile(0.05 * x, (100, 1))
    pits = z.copy()
    for i in range(30):                 # a diagonal line of 30 cells
        pits[35 + i // 2, 30 + i] -= 24.0
    clean = ground_level_reference(z, (1.0, 1.0), block_m=20.0)
    plain = ground_level_reference(pits, (1.0, 1.0), block_m=20.0)
    lifted = ground_level_reference(pits, (1.0, 1.0), block_m=20.0, lift_low=True)
    assert np.nanmax(clean[0] - plain[0]) > 20.0
    np.testing.assert_allclose(lifted[0], clean[0], atol=1e-5)
    assert lifted[1] == pytest.approx(clean[1], rel=1e-6)
    # on the plane alone the option changes nothing
    np.testing.assert_array_equal(ground_level_reference(z, (1.0, 1.0), 20.0, lift_low=True)[0], clean[0])


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


@pytest.mark.parametrize("gather", [0.0, 1e9])          # the filters' path, the gathered rings
@pytest.mark.parametrize("cell", [(1.0, 1.0), (0.5, 0.7)])
def test_below_surroundings_at_candidates_equals_the_full_answer_there(cell, gather, monkeypatch):
    monkeypatch.setattr(est, "_RING_GATHER_PER_CELL", gather)
    rng = np.random.default_rng(1)
    z = rng.normal(100.0, 0.2, (120, 110)).astype(np.float32)
    z[10::45, 12::45] -= 5.0                                  # pits farther apart than a ring
    z[rng.random(z.shape) < 0.01] = np.nan
    full = est.below_surroundings(z, cell, 0.3)
    assert full.sum() >= 6
    cand = rng.random(z.shape) < 0.3
    np.testing.assert_array_equal(est.below_surroundings(z, cell, 0.3, candidates=cand), full & cand)
    assert not est.below_surroundings(z, cell, 0.3, candidates=np.zeros(z.shape, bool)).any()


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int16])
def test_below_surroundings_gathered_rings_equal_the_filters_at_edges_and_nodata(dtype, monkeypatch):
    # pits on the raster's edges and corners, next to nodata and in a nodata-only ring
    rng = np.random.default_rng(7)
    z = rng.normal(50.0, 0.3, (41, 37))
    z[::13, ::11] -= 4.0
    z[0, 0] = z[0, 36] = z[40, 5] = z[20, 0] = 40.0
    if dtype != np.int16:
        z[rng.random(z.shape) < 0.05] = np.nan
        z[30:41, 25:37] = np.nan
        z[35, 31] = 30.0                                  # a valid cell in a nodata ring
    z = z.astype(dtype)
    cand = np.ones(z.shape, bool)
    cand[::2, 1::3] = False
    monkeypatch.setattr(est, "_RING_GATHER_PER_CELL", 0.0)
    filters = est.below_surroundings(z, (1.0, 0.8), 0.5, candidates=cand)
    monkeypatch.setattr(est, "_RING_GATHER_PER_CELL", 1e9)
    gathered = est.below_surroundings(z, (1.0, 0.8), 0.5, candidates=cand)
    assert filters.sum() >= 4
    np.testing.assert_array_equal(gathered, filters)
    np.testing.assert_array_equal(gathered, est.below_surroundings(z, (1.0, 0.8), 0.5) & cand)


@pytest.mark.parametrize("cell", [(1.0, 1.0), (0.5, 2.0), (2.0, 0.25)])
def test_surroundings_reach_is_where_the_ring_ends(cell):
    """A pit 5 m deep is below its surroundings unless one cell of its ring is as low: a low
    cell at the reach (ry rows or rx columns away) makes it no pit, one cell farther does not."""
    iy, ix, ry, rx = est.surroundings_reach(cell)
    assert (iy, ix) == tuple(max(2, math.ceil(est.PIT_CLUSTER_M / d)) for d in (cell[1], cell[0]))
    h, w = 2 * ry + 5, 2 * rx + 5
    r0, c0 = h // 2, w // 2
    for dr, dc in ((ry, 0), (0, rx), (ry + 1, 0), (0, rx + 1)):
        z = np.full((h, w), 10.0, np.float32)
        z[r0, c0] = 5.0
        z[r0 + dr, c0 + dc] = 4.0
        inside = dr <= ry and dc <= rx
        assert bool(est.below_surroundings(z, cell, 1.0)[r0, c0]) is (not inside), (dr, dc)


# ----------------------------------------------------------------- object_widths
def test_object_widths_exact_on_tiny_masks():
    m = np.zeros((12, 12), bool)
    assert est.object_widths(m, (1.0, 1.0)) == 0.0            # no object
    m[5, 5] = True
    assert est.object_widths(m, (1.0, 1.0)) == 1.0            # one cell: one cell wide
    m = np.zeros((12, 12), bool)
    m[1:4, 1:4] = True                                        # 3 x 3 cells (9 cells of area)
    assert est.object_widths(m, (1.0, 1.0)) == 3.0
    assert est.object_widths(m, (2.0, 2.0)) == 6.0            # in metres
    m[6:11, 6:11] = True                                      # 5 x 5 (25 cells): 98 % of the area
    assert est.object_widths(m, (1.0, 1.0)) == 5.0            # lies at or below 5 m
    assert est.object_widths(m, (1.0, 1.0), area_share=0.25) == 3.0   # 9 / 34 cells >= 25 %
    bridge = np.zeros((9, 40), bool)
    bridge[3:6, :] = True                                     # long, 3 cells across
    assert est.object_widths(bridge, (1.0, 1.0)) == 3.0
    with pytest.raises(ValueError, match="area_share"):
        est.object_widths(m, (1.0, 1.0), area_share=0.0)


def test_object_widths_across_nodata_gaps():
    """Missing scan lines do not cut an object: a 9 x 9 roof crossed by NaN rows every
    3 rows is 9 cells wide; a wide nodata area stays outside but for its rim (issue: a roof crossed by
    missing scan lines read a few metres wide and the opening left it standing)."""
    m = np.zeros((20, 20), bool)
    m[4:13, 5:14] = True
    gaps = np.zeros_like(m)
    gaps[::3] = True
    cut = m & ~gaps
    assert est.object_widths(cut, (1.0, 1.0)) == 1.0              # cut into strips
    assert est.object_widths(cut, (1.0, 1.0), nodata=gaps) == 9.0
    wide = ~m                                                    # nodata all around it: only
    assert est.object_widths(m, (1.0, 1.0), nodata=wide) == 9.0 + 2.0   # its one-cell rim joins
    edge = np.zeros((9, 9), bool)
    edge[:, :3] = True                                           # cut by the raster's border
    assert est.object_widths(edge, (1.0, 1.0)) == 3.0
    assert est.object_widths(edge, (1.0, 1.0), border_outside=False) == 5.0


# ----------------------------------------------------------------- height_quantum
@pytest.mark.parametrize("dtype", [np.int16, np.float32, np.float64])
def test_height_quantum_and_the_noise_floor_of_rounded_heights(dtype):
    """Heights in whole metres: the step is 1 m and the noise statistics read at least its
    rounding error 1 / sqrt(12) (they read 0: most differences of a rounded slope are 0)."""
    y, x = np.mgrid[0:64, 0:64]
    z = np.round(300.0 + 0.15 * x + 0.05 * y).astype(dtype)
    assert est.height_quantum(z) == pytest.approx(1.0)
    floor = 1.0 / np.sqrt(12.0)
    assert est.noise_plane_residual(z) == pytest.approx(floor)
    assert est.noise_ground_level(z, (1.0, 1.0))["sigma"] == pytest.approx(floor)
    decimetres = np.round(z.astype(np.float64) * 0.1, 1).astype(np.float32)
    assert est.height_quantum(decimetres) == pytest.approx(0.1, rel=1e-4)
    noisy = (300.0 + 0.15 * x + np.random.default_rng(0).normal(0, 0.05, x.shape)).astype(np.float32)
    assert est.height_quantum(noisy) == 0.0                  # float heights: no step
    assert est.height_quantum(np.full((8, 8), 5.0)) == 0.0   # one height: unknown
    assert est.noise_floor(0.4, 1.0) == 0.4                  # above the floor: unchanged
    assert np.isnan(est.noise_floor(float("nan"), 1.0))


def test_height_quantum_reads_the_same_in_the_dsms_dtype():
    """The distinct heights are sorted in the DSM's own dtype (float32: faster) and measured in float64: the step
    is exactly the one of the same heights given in float64, -0.0 and 0.0 one height, NaN and inf never one."""
    y, x = np.mgrid[0:80, 0:90]
    z = (np.round((12.0 + 0.37 * x - 0.21 * y) * 20.0) / 20.0 - 12.0).astype(np.float32)   # 5 cm steps about 0
    z[z == 0.0] = -0.0
    z[3, :7] = np.nan
    z[5, 2] = np.inf
    q = est.height_quantum(z)
    assert q == pytest.approx(0.05, rel=1e-4)
    assert q == est.height_quantum(np.where(np.isfinite(z), z, np.nan).astype(np.float64))


def test_object_widths_across_a_checkerboard_of_dropouts():
    """Half the cells missing in a checkerboard: the roof's cells touch only at corners,
    yet they are one object as wide as the roof (each cell was its own one-cell object)."""
    m = np.zeros((21, 21), bool)
    m[4:17, 4:17] = True                                         # 13 x 13
    yy, xx = np.mgrid[0:21, 0:21]
    holes = (yy + xx) % 2 == 0
    # 11: the outermost ring alternates holes and cells outside; one object, so its width
    # whatever the share of the area asked (cells alone: half of them within 2 cells of it)
    assert est.object_widths(m & ~holes, (1.0, 1.0), nodata=holes) == 11.0
    assert est.object_widths(m & ~holes, (1.0, 1.0), area_share=0.5, nodata=holes) == 11.0
    assert est.object_widths(m & ~holes, (1.0, 1.0)) == 1.0


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int16])
def test_repeated_height_share_exact(dtype):
    z = np.array([[1, 1, 2],
                  [3, 3, 3]], dtype)
    # row pairs: (1, 1) (1, 2) (3, 3) (3, 3): 3 equal; column pairs (1, 3) (1, 3) (2, 3): none
    assert est.repeated_height_share(z) == pytest.approx(3 / 7)
    if np.issubdtype(dtype, np.floating):
        z = z.astype(dtype)
        z[1, 1] = np.nan                          # pairs touching nodata are not counted
        assert est.repeated_height_share(z) == pytest.approx(1 / 4)
        assert est.repeated_height_share(np.full((2, 2), np.nan, dtype)) == 0.0


def test_repeated_height_share_of_a_sparse_cloud_filled_by_its_nearest_return():
    # one return per 2 x 2 cells, nearest fill: every height repeated over its block
    z = np.kron(np.arange(36.0).reshape(6, 6) * 0.37, np.ones((2, 2))).astype(np.float32)
    share = est.repeated_height_share(z)
    assert share == pytest.approx(6 / 11)         # 6 of the 11 pairs of a row (or a column) inside a block
    assert 1.0 / (1.0 - share) == pytest.approx(2.0, rel=0.1)             # about two cells per return


def test_repeated_height_share_leaves_level_squares_out_exact():
    """A level area is no return repeated over its cells: with ``level_cells`` the pairs
    touching a square of that side of one height are left out (here the 4 x 4 level block
    and the pairs reaching into it), the other pairs counted as before."""
    z = np.kron(np.arange(16.0).reshape(4, 4) * 0.37, np.ones((2, 2))).astype(np.float32)   # 8 x 8, 2 x 2 returns
    z[:4, :4] = 50.0                                   # a level square of 4 x 4 cells
    assert est.repeated_height_share(z) == pytest.approx(72 / 112)
    # left out: the 32 pairs touching the square (the 3 x 3 squares inside it cover it); of the
    # 80 left, 48 are equal (24 row and 24 column pairs inside the other 2 x 2 returns)
    assert est.repeated_height_share(z, level_cells=3) == pytest.approx(48 / 80)
    assert est.repeated_height_share(z, level_cells=5) == pytest.approx(72 / 112)     # no 5 x 5 level square
    with pytest.raises(ValueError, match="odd"):
        est.repeated_height_share(z, level_cells=4)


def test_noise_without_sampling_inverts_lowest_point_spread():
    spread = est.lowest_point_spread(0.03, 0.12, 1.0, 0.2)                   # spacing 1.25 m
    assert est.noise_without_sampling(spread, 0.12, 1.25) == pytest.approx(0.03, abs=1e-12)
    assert est.noise_without_sampling(0.05, 0.5, 2.0) == 0.0                 # all the sampling's
    assert est.noise_without_sampling(0.05, float("nan"), 2.0) == pytest.approx(0.05)
    assert est.noise_without_sampling(0.05, 0.0, 2.0) == pytest.approx(0.05)
    assert math.isnan(est.noise_without_sampling(float("nan"), 0.1, 1.0))


def test_lowest_point_spread_exact():
    assert est.lowest_point_spread(0.03, 0.12, 1.0) == pytest.approx(math.sqrt(0.03 ** 2 + 0.12 ** 2 / 12))
    assert est.lowest_point_spread(0.0, 0.1, 1.0, 0.5) == pytest.approx(0.2 / math.sqrt(12))
    assert est.lowest_point_spread(0.05, float("nan"), 2.0) == pytest.approx(0.05)   # slope unknown: the noise
    assert math.isnan(est.lowest_point_spread(float("nan"), 0.1, 1.0))
    assert math.isfinite(est.lowest_point_spread(0.0, 0.1, 1.0, 1.0))                # every pair equal: bounded


def test_lowest_point_spread_is_the_spread_of_lowest_returns_on_a_slope():
    # one return per cell, anywhere in it, on a plane rising 0.2 m per metre, noise 0.03 m: the cells'
    # heights scatter about the plane by sqrt(0.03^2 + 0.2^2 / 12)
    rng = np.random.default_rng(0)
    x = rng.uniform(0.0, 1.0, 200_000)
    h = 0.2 * x + rng.normal(0.0, 0.03, x.size)
    assert np.std(h) == pytest.approx(est.lowest_point_spread(0.03, 0.2, 1.0), rel=0.02)


def test_below_level_rim_finds_two_blunders_within_each_others_ring(monkeypatch):
    """Two 2 x 2 pits 18 m deep, 10 cells apart, in open ground (issue 12): each is in the
    other's ring, so below_surroundings finds neither; the level rim just around each
    finds both, and no ground cell."""
    from bare_earth.core.estimate import below_level_rim, below_surroundings
    z = np.zeros((30, 30), np.float32)
    z += np.float32(0.05) * np.arange(30, dtype=np.float32)[None, :]      # a gentle slope
    z[10:12, 10:12] = -18.0
    z[10:12, 20:22] = -18.0
    cand = z < -10.0
    assert not below_surroundings(z, (1.0, 1.0), 0.2, candidates=cand).any()
    got = below_level_rim(z, (1.0, 1.0), 0.2, np.tan(np.radians(8.0)), cand)
    assert (got == cand).all()
    # the slope's rise across the 7-cell rim (0.3 m) needs the terrain allowance (the
    # narrow gaps' test, asked about the cells the level rim leaves, is left out here)
    monkeypatch.setattr(est, "below_narrow_gap", lambda z, *a, **k: np.zeros(np.shape(z), bool))
    assert not below_level_rim(z, (1.0, 1.0), 0.1, 0.0, cand).any()


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_below_level_neighbours_exact(dtype):
    """A line of blunders on a level terrace (ISPRS sample 41 at 2 m): each lies below its level
    neighbours that are not candidates themselves; a gap among crown flanks metres apart does not, nor a
    pit too shallow, nor one with fewer than three neighbours known."""
    from bare_earth.core.estimate import below_level_neighbours, below_surroundings
    z = np.full((12, 12), 304.0, dtype)
    z[:, 8:] = 320.0                                   # a building beside the terrace
    line = [(1, 3), (2, 3), (4, 3), (6, 2), (7, 2)]
    for r, c in line:
        z[r, c] = 294.5
    z[9, 5] = 300.0                                    # 4 m deep: not deep enough
    z[10, 1] = 294.5
    z[9:12, 0:3][[0, 0, 0, 1, 2], [0, 1, 2, 0, 0]] = [304.0, 310.0, 304.0, 306.0, 304.0]   # crowns' flanks
    cand = z < 303.0
    assert not below_surroundings(z, (2.0, 2.0), 5.0, candidates=cand).any()
    got = below_level_neighbours(z, 5.0, 0.5, cand)
    assert sorted(map(tuple, np.argwhere(got).tolist())) == line
    z[0, :] = np.nan
    z[1, 2] = z[1, 4] = z[0, 3] = np.nan               # (1, 3): two neighbours left besides (2, 3)
    got = below_level_neighbours(z, 5.0, 0.5, cand & np.isfinite(z))
    assert not got[1, 3] and got[2, 3]


def test_below_level_rim_leaves_gaps_between_crowns_and_unknown_rims(monkeypatch):
    from bare_earth.core.estimate import below_level_rim
    z = np.random.default_rng(0).uniform(8.0, 25.0, (30, 30)).astype(np.float32)   # crowns
    z[::6, ::6] = 0.0                                  # gaps down to the ground
    z[14:17, 14] = 0.0                                 # a gap
    cand = z < 1.0
    assert not below_level_rim(z, (1.0, 1.0), 0.2, 0.1, cand).any()
    g = np.zeros((20, 20), np.float32)
    g[5, 5] = g[10, 10] = g[0, 18] = g[2, 16] = -5.0
    g[13, 10] = np.nan                                 # a nodata cell on (10, 10)'s rim
    # the narrow gaps' test finds (10, 10) across rows and diagonals; (0, 18) at the edge
    # has no bank beyond it along any direction
    assert set(map(tuple, np.argwhere(below_level_rim(g, (1.0, 1.0), 0.2, 0.1, g < -1.0)))) == {
        (5, 5), (10, 10), (2, 16)}
    monkeypatch.setattr(est, "below_narrow_gap", lambda z, *a, **k: np.zeros(np.shape(z), bool))
    got = below_level_rim(g, (1.0, 1.0), 0.2, 0.1, g < -1.0)
    assert got[5, 5] and not got[10, 10]
    assert got[2, 16]                                  # near the corner: 17 of 24 rim cells inside
    assert not got[0, 18]                              # 8 of 24 inside: no evidence
    assert got.sum() == 2


def _wall_and_ground(shape=(30, 40)):
    z = np.zeros(shape, np.float32)
    z += np.float32(0.02) * np.arange(shape[1], dtype=np.float32)[None, :]   # a gentle slope
    z[:10, :] += 12.0                                                         # a building
    return z


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_below_level_rim_finds_a_line_of_blunders_along_a_wall(dtype):
    """Multipath blunders in a 1 x 20 line 25 m below the ground along a wall (issue 12,
    ISPRS samp41): each has others of its line within its ring, and its rim is wall and
    ground, not level, so neither test found them; across the line the wall and the level
    ground rise within one cell (below_narrow_gap). No other cell is found."""
    z = _wall_and_ground()
    z[10, 5:25] = -25.0
    cand = z < -10.0
    assert not est.below_surroundings(z, (1.0, 1.0), 0.5, candidates=cand).any()
    got = est.below_level_rim(z.astype(dtype), (1.0, 1.0), 0.5, 0.1, cand)
    np.testing.assert_array_equal(got, cand)
    np.testing.assert_array_equal(est.below_narrow_gap(z, (1.0, 1.0), 0.5, 0.1, cand), cand)
    # asked about every cell, only the line answers
    assert not (est.below_narrow_gap(z, (1.0, 1.0), 0.5, 0.1, np.ones(z.shape, bool)) & ~cand).any()


def test_below_narrow_gap_finds_clusters_in_a_street_between_two_buildings():
    """Two 3 x 3 clusters 25 m deep in a 3 m street between two 12 m buildings, 8 m apart
    (each within the other's ring; rims of roofs and street): the street's ground rises
    within two cells on both sides along the street."""
    z = np.zeros((32, 30), np.float32)
    z[:, :10] = 12.0
    z[:, 13:] = 12.0
    z[10:13, 10:13] = -25.0
    z[18:21, 10:13] = -25.0
    cand = z < -10.0
    ring = est.below_surroundings(z, (1.0, 1.0), 0.5, candidates=cand)
    assert not ring.any()
    got = est.below_level_rim(z, (1.0, 1.0), 0.5, 0.1, cand)
    np.testing.assert_array_equal(got, cand)


def _low_ground_scenes():
    y, x = np.mgrid[0:60, 0:60].astype(np.float32)
    base = (0.05 * x + 0.02 * y).astype(np.float32)
    ditch = base - 1.5 * ((x >= 29) & (x <= 30))                          # 2 m wide, 1.5 m deep
    narrow = base - 0.9 * (x == 30)                                         # 1 m wide, 0.9 m deep
    river = base - 4.0 * (np.abs(x - 30) < 15)                             # between walls
    road = base - 4.5 * ((x >= 28) & (x <= 32))                           # 5 m wide, 4.5 m deep
    quarry = base - 6.0 * np.clip(np.floor((25 - np.abs(x - 30)) / 5), 0, 4)     # benches, an 11 m floor
    court = base + 15.0 * ((np.abs(x - 30) < 20) & (np.abs(y - 30) < 20))
    court[22:38, 22:38] = base[22:38, 22:38]                              # a 16 m courtyard
    under = base.copy()
    under[:, 28:33] -= 5.0                                                  # an underpass:
    under[25:31, 26:35] = base[25:31, 26:35] + 1.0                          # a bridge over it
    crowns = np.random.default_rng(1).uniform(8.0, 25.0, (60, 60)).astype(np.float32)
    crowns[::6, ::6] = 0.0
    crowns[20:40, 30] = 0.0                                                 # a path under the canopy
    return {"ditch": ditch, "narrow ditch": narrow, "river": river, "sunken road": road,
            "quarry": quarry, "courtyard": court, "underpass": under, "canopy gaps": crowns}


@pytest.mark.parametrize("cell", [1.0, 2.0])
@pytest.mark.parametrize("name", list(_low_ground_scenes()))
def test_below_narrow_gap_leaves_low_ground(name, cell):
    """Ditches, a river between walls, a sunken road, a quarry's benches, a courtyard
    among buildings, an underpass, the ground between crowns: every cell asked, none is a
    blunder."""
    z = _low_ground_scenes()[name]
    z = (z + np.random.default_rng(0).normal(0.0, 0.05, z.shape)).astype(np.float32)
    everything = np.ones(z.shape, bool)
    assert not est.below_narrow_gap(z, (cell, cell), 0.3, 0.1, everything).any()
    assert not est.below_level_rim(z, (cell, cell), 0.3, 0.1, everything).any()


def test_noise_ground_level_is_measured_once_per_window_content(monkeypatch):
    """The dtm filter's members each ask for the noise of the same DSM, side by side: inside
    noise_shared the window is measured once (the others wait for it); a changed window, another
    cell size or another band is measured again; the results equal a fresh measurement."""
    import threading
    rng = np.random.default_rng(3)
    z = (rng.normal(0, 0.05, (120, 130)) + np.arange(130) * 0.1).astype(np.float32)
    z[40:60, 40:70] += 8.0
    est._NOISE_MEMO.clear()
    fresh = est._noise_ground_level(z, (1.0, 1.0), est.GROUND_BLOCK_M, est.GROUND_BAND_M, 3, None)
    calls = []
    real = est._noise_ground_level

    def counted(*a):
        calls.append(1)
        return real(*a)

    monkeypatch.setattr(est, "_noise_ground_level", counted)
    noise_ground_level(z, (1.0, 1.0))
    noise_ground_level(z, (1.0, 1.0))
    assert len(calls) == 2 and not est._NOISE_MEMO           # outside noise_shared: measured every time
    calls.clear()
    shared = est.noise_shared()
    shared.__enter__()
    out = [None] * 3
    threads = [threading.Thread(target=lambda i=i: out.__setitem__(i, noise_ground_level(z.copy(), (1.0, 1.0))))
               for i in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(calls) == 1 and all(o == fresh for o in out)
    z2 = z.copy()
    z2[5, 5] += 0.5
    assert noise_ground_level(z2, (1.0, 1.0)) == real(z2, (1.0, 1.0), est.GROUND_BLOCK_M, est.GROUND_BAND_M, 3, None)
    noise_ground_level(z, (2.0, 2.0))
    noise_ground_level(z, (1.0, 1.0), band_m=1.0)
    assert len(calls) == 4
    out[0]["sigma"] = -1.0                       # a caller's copy: the memo keeps its own
    assert noise_ground_level(z, (1.0, 1.0)) == fresh and len(calls) == 4
    shared.__exit__(None, None, None)
    assert not est._NOISE_MEMO                   # forgotten when the context ends


def test_noise_ground_level_forgets_a_cancelled_measurement(monkeypatch):
    from bare_earth.core.common import Cancelled
    z = (np.random.default_rng(4).normal(0, 0.05, (80, 80))).astype(np.float32)
    est._NOISE_MEMO.clear()

    def cancel(f):
        raise Cancelled()

    with est.noise_shared():
        with pytest.raises(Cancelled):
            noise_ground_level(z, (1.0, 1.0), progress=cancel)
        assert not est._NOISE_MEMO
        assert np.isfinite(noise_ground_level(z, (1.0, 1.0))["sigma"])
        assert len(est._NOISE_MEMO) == 1


def test_raised_region_window_reaches_across_the_widest_raised_region():
    # the level of the test below (47 m wide mirrored at the edge): a window of 1.25 x 47 + 2 cells, capped
    z = np.zeros((40, 40), np.float32)
    z[15:, 15:] = 4.0
    assert est.raised_region_window(z, (1.0, 1.0), 0.5, 10.0) == 1.25 * 47.0 + 2.0
    assert est.raised_region_window(z, (2.0, 2.0), 0.5, 10.0) == 1.25 * 94.0 + 4.0
    assert est.raised_region_window(z, (1.0, 1.0), 0.5, 10.0, max_width_m=50.0) == 50.0
    assert est.raised_region_window(z, (1.0, 1.0), 0.5, 48.0) == 0.0           # the window reaches across
    assert est.raised_region_window(np.zeros((40, 40), np.float32), (1.0, 1.0), 0.5, 10.0) == 0.0


def test_raised_region_longer_than_the_width_cap_needs_the_span():
    # a hall 30 m wide and 70 m long inside the raster: looked at up to 50 m wide it spans 70 rows, beyond the
    # 50 cells the stage reaches unless the span is given (morphology's resolve: twice the width's cap)
    z = np.zeros((90, 60), np.float32)
    z[10:80, 15:45] = 8.0
    assert est.raised_region_width(z, (1.0, 1.0), 2.0, 10.0, max_width_m=50.0) == 0.0
    wide = est.raised_region_width(z, (1.0, 1.0), 2.0, 10.0, max_width_m=50.0, max_span_m=100.0)
    assert 25.0 <= wide <= 30.0
    assert est.raised_region_window(z, (1.0, 1.0), 2.0, 10.0, max_width_m=50.0, max_span_m=100.0) == 1.25 * wide + 2.0
    # a span under the width is the width
    assert est.raised_region_width(z, (1.0, 1.0), 2.0, 10.0, max_width_m=50.0, max_span_m=20.0) == 0.0


def test_raised_region_width_of_a_level_running_off_the_raster():
    # a raised level 4 m high on two walls, running off a corner of the raster: the region (rows and columns
    # 16-39, the walls' top a rim) mirrored at the edge is twice 24 cells less one wide
    z = np.zeros((40, 40), np.float32)
    z[15:, 15:] = 4.0
    assert est.raised_region_width(z, (1.0, 1.0), 0.5, 10.0) == 47.0
    assert est.raised_region_width(z, (2.0, 2.0), 0.5, 10.0) == 94.0
    assert est.raised_region_width(z, (1.0, 1.0), 0.5, 48.0) == 0.0          # the window reaches across
    assert est.raised_region_width(z, (1.0, 1.0), 0.5, 10.0, max_width_m=45.0) == 0.0   # wider than looked at
    assert est.raised_region_width(z, (1.0, 1.0), 5.0, 10.0) == 0.0          # lower than the height
    step = np.zeros((40, 40), np.float32)
    step[:, 15:] = 4.0
    # cut on two opposite sides: mirrored at both, 3 x 40 cells, beyond a reach of 100 m (not of 200 m)
    assert est.raised_region_width(step, (1.0, 1.0), 0.5, 10.0, max_width_m=100.0) == 0.0
    assert est.raised_region_width(step, (1.0, 1.0), 0.5, 10.0) == 47.0
    bank = np.clip(np.arange(40, dtype=np.float32) - 11.0, 0.0, 4.0) * np.ones((40, 1), np.float32)
    assert est.raised_region_width(bank, (1.0, 1.0), 0.5, 10.0) == 0.0       # a bank, no wall
    box = np.zeros((40, 40), np.float32)
    box[10:15, 10:16] = 6.0
    assert est.raised_region_width(box, (1.0, 1.0), 0.5, 10.0) == 0.0        # a small building


@pytest.mark.parametrize("cell", [0.5, 1.0, 2.0, 4.0])
def test_raised_region_width_of_a_roof_whose_wall_ends_in_a_corner(cell):
    """As lidar/sample_c: a roof over 73 % of an 88 x 76 m tile, its one wall cutting off the top-left
    corner and ending on the left side 2 m above the bottom, is a raised region wider than 64 m at every
    cell size: the roof's corner beside the wall's end reaches the bottom side, but the ground at the
    wall's foot does not, so the wall is not mirrored there (it was at 2 and 4 m: walls of 228 m, beyond
    the 200 m looked at, and the filters kept the roof). The terrace of the same shape on a bank is none."""
    from surfaces import level_off_a_corner
    z, roof = level_off_a_corner(cell)
    assert 64.0 < est.raised_region_width(z, (cell, cell), 2.0, 64.0) <= 200.0
    z, _ = level_off_a_corner(cell, "terrace")
    assert est.raised_region_width(z, (cell, cell), 2.0, 64.0) == 0.0


def test_smooth_parts_joined_across_steps_up_to_step_m():
    from bare_earth.core.estimate import smooth_parts
    w = np.array([[0, 0.5, 5, 5], [0, 0, 5, 9]], np.float32)
    n, part = smooth_parts(w, np.arange(8), 1.0)
    assert n == 3 and part.tolist() == [0, 0, 1, 1, 0, 0, 1, 2]
    n, part = smooth_parts(w, np.arange(8), 0.4)    # the 0.5 step splits the left part too
    assert n == 4 and part.tolist() == [0, 1, 2, 2, 0, 0, 2, 3]


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("order", ["random", "sorted"])
def test_smooth_parts_are_the_components_of_the_smooth_neighbour_edges(seed, order):
    """On a random raster (heights in 0.5 m steps, NaNs) and a random subset of its cells in random
    order (joined by a graph of their edges) or sorted (joined by runs): the parts are those of a
    union-find over every pair of 8-neighbours among the cells whose heights differ by at most
    step_m, numbered in the order of their first cell in ``cells``."""
    from bare_earth.core.estimate import smooth_parts
    rng = np.random.default_rng(seed)
    w = (rng.integers(0, 6, (17, 23)) * 0.5).astype(np.float32)
    w[rng.random(w.shape) < 0.05] = np.nan
    cells = rng.permutation(np.flatnonzero(rng.random(w.shape) < 0.7))
    if order == "sorted":
        cells = np.sort(cells)
    H, W = w.shape
    at = {int(c): i for i, c in enumerate(cells)}
    root = list(range(cells.size))

    def find(i):
        while root[i] != i:
            i = root[i]
        return i
    for i, c in enumerate(cells):
        r, q = divmod(int(c), W)
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                j = at.get((r + dr) * W + q + dc) if 0 <= r + dr < H and 0 <= q + dc < W else None
                if j is not None and abs(float(w[r, q]) - float(w[r + dr, q + dc])) <= 0.5:
                    root[find(i)] = find(j)
    first = {}
    want = [first.setdefault(find(i), len(first)) for i in range(cells.size)]
    n, part = smooth_parts(w, cells, 0.5)
    assert n == len(first) and part.tolist() == want


@pytest.mark.parametrize("seed", range(6))
def test_smooth_parts_by_runs_equal_the_graph_of_the_cells_edges(seed):
    """smooth_parts' runs (sorted cells filling a quarter of their rows or more) give the parts and
    the numbering of the graph of the cells' own 8-neighbour edges, bit for bit: terraced and
    rough random rasters, NaNs, dense and sparse cells over a band of rows, steps from none to
    any."""
    rng = np.random.default_rng(seed)
    h, w = rng.integers(3, 70, 2)
    z = (np.round(rng.normal(0, 1.0, (h, w)).cumsum(axis=seed % 2) / 2) * 0.5
         + rng.normal(0, 0.05, (h, w))).astype(np.float32)
    if seed >= 3:                       # rough: a cell joined to two that are not joined to each other
        z = rng.uniform(0.0, 1.0, (h, w)).astype(np.float32)
    z[rng.random(z.shape) < 0.03] = np.nan
    runs = 0
    for frac in (0.3, 0.6, 0.95, 1.0):
        cells = np.flatnonzero(rng.random(z.shape) < frac)
        cells = cells[(cells >= w * (h // 5)) & (cells < w * (h - h // 5))]      # a band of rows
        for step in (0.0, 0.3, 0.6, np.inf):
            got = est.smooth_parts(z, cells, step)
            want = est._smooth_parts_graph(z, cells, step)
            assert got[0] == want[0] and np.array_equal(got[1], want[1]) and got[1].dtype == want[1].dtype
            runs += cells.size > 0 and 4 * cells.size >= (cells[-1] // w - cells[0] // w + 1) * w
    assert runs >= 8


@pytest.mark.parametrize("cell", [(1.0, 1.0), (1.0, 2.0)])
def test_ground_plane_gradient_of_a_plane_under_objects_exact(cell):
    """The plane through the ground cells of each square is the ground's plane, whatever stands on the other
    cells; NaN where a square holds fewer than three ground cells."""
    rows, cols = 40, 30
    y, x = np.mgrid[0:rows, 0:cols]
    z = (5.0 + 0.6 * x * cell[0] - 0.25 * y * cell[1]).astype(np.float32)
    rng = np.random.default_rng(1)
    ground = rng.random(z.shape) > 0.4
    z[~ground] += 3.0                                   # objects: not read
    gx, gy = est.ground_plane_gradient(z, ground, cell, 3)
    np.testing.assert_allclose(gx, 0.6, atol=1e-4)
    np.testing.assert_allclose(gy, -0.25, atol=1e-4)
    lone = np.zeros(z.shape, bool)
    lone[20, 15] = lone[20, 16] = True                  # two cells: no plane
    gx, gy = est.ground_plane_gradient(z, lone, cell, 2)
    assert np.isnan(gx).all() and np.isnan(gy).all()


def test_ground_plane_gradient_of_a_quadratic_is_its_gradient_at_the_centre():
    """A centred square's plane through a quadratic surface has the surface's gradient at its centre (the
    quadratic terms are even about the centre): a ridge's crest reads level, its flanks their slope."""
    y, x = np.mgrid[0:30, 0:40].astype(np.float64)
    z = 0.02 * (x - 17.3) ** 2 - 0.01 * (y - 11) ** 2 + 0.005 * x * y + 0.3 * x
    gx, gy = est.ground_plane_gradient(z, np.ones(z.shape, bool), (1.0, 1.0), 4)
    inner = np.s_[4:-4, 4:-4]
    np.testing.assert_allclose(gx[inner], (0.04 * (x - 17.3) + 0.005 * y + 0.3)[inner], atol=1e-4)
    np.testing.assert_allclose(gy[inner], (-0.02 * (y - 11) + 0.005 * x)[inner], atol=1e-4)


def test_ground_plane_gradient_in_bands_equals_one_band(monkeypatch):
    rng = np.random.default_rng(3)
    z = np.cumsum(rng.normal(0, 0.3, (300, 50)), axis=0).astype(np.float32)
    z[rng.random(z.shape) < 0.05] = np.nan
    ground = rng.random(z.shape) > 0.3
    banded = est.ground_plane_gradient(z, ground, (1.0, 1.0), 6)
    monkeypatch.setattr(est, "_PLANE_BAND_ROWS", 1000)
    whole = est.ground_plane_gradient(z, ground, (1.0, 1.0), 6)
    for a, b in zip(banded, whole):
        np.testing.assert_array_equal(a, b)


def _ground_plane_gradient_oracle(z, ground, cell_size, radius_cells, band_rows):
    """ground_plane_gradient as it was (803735d): the nine box means of ``ndimage.uniform_filter`` on each band
    with the squares' rows around it, the planes solved on all of them, the band's rows kept."""
    from scipy import ndimage
    z = np.asarray(z)
    ground = np.asarray(ground, bool)
    r = max(1, int(radius_cells))
    size = 2 * r + 1
    dx, dy = float(cell_size[0]), float(cell_size[1])
    rows, cols = z.shape
    gx = np.full(z.shape, np.nan, np.float32)
    gy = np.full(z.shape, np.nan, np.float32)
    x = np.arange(cols, dtype=np.float64)[None, :] * dx

    def mean(a):
        return ndimage.uniform_filter(a, size, mode="constant", cval=0.0)

    for a in range(0, rows, band_rows):
        b = min(rows, a + band_rows)
        lo, hi = max(0, a - r), min(rows, b + r)
        zb = np.asarray(z[lo:hi], np.float64)
        g = ground[lo:hi] & np.isfinite(zb)
        w = g.astype(np.float64)
        y = np.arange(lo, hi, dtype=np.float64)[:, None] * dy - a * dy
        zw = np.where(g, zb, 0.0)
        n = mean(w)
        with np.errstate(invalid="ignore", divide="ignore"):
            inv = np.where(n > 0, 1.0 / n, np.nan)
            mx, my, mz = mean(w * x) * inv, mean(w * y) * inv, mean(zw) * inv
            sxx = mean(w * x * x) * inv - mx * mx
            syy = mean(w * y * y) * inv - my * my
            sxy = mean(w * x * y) * inv - mx * my
            sxz = mean(zw * x) * inv - mx * mz
            syz = mean(zw * y) * inv - my * mz
            det = sxx * syy - sxy * sxy
            ok = (np.rint(n * size * size) >= 3) & (det > 1e-9 * (sxx + syy) ** 2)
            band = slice(a - lo, b - lo)
            gx[a:b] = np.where(ok, (syy * sxz - sxy * syz) / det, np.nan)[band]
            gy[a:b] = np.where(ok, (sxx * syz - sxy * sxz) / det, np.nan)[band]
    return gx, gy


@pytest.mark.parametrize("shape,r,cell,band", [((300, 50), 6, (1.0, 1.0), 256), ((97, 41), 3, (0.5, 2.0), 1000),
                                               ((5, 60), 4, (1.0, 1.0), 256), ((230, 37), 12, (1.0, 1.0), 64),
                                               ((130, 70), 1, (2.0, 1.0), 16), ((61, 45), 9, (1.0, 1.0), 7)])
@pytest.mark.parametrize("threads", [1, 2])
@pytest.mark.parametrize("solve_cells", [1 << 15, 100, 1])
def test_ground_plane_gradient_equals_its_straightforward_means(monkeypatch, shape, r, cell, band, threads,
                                                                 solve_cells):
    """The bands side by side on a pool's threads (or one after the other), their sums down the columns along
    whole rows and their planes solved a few rows at a time: bit for bit the planes of the bands one after the
    other in one loop of ``ndimage.uniform_filter`` means (the implementation before, kept here). Heights with
    nodata, ground with a part bare of ground (NaN planes), bands narrower than the squares, one band, bands
    shorter than the squares (SciPy's own pass)."""
    from concurrent.futures import ThreadPoolExecutor
    rng = np.random.default_rng(sum(shape) + r)
    z = (np.cumsum(rng.normal(0, 0.3, shape), axis=0) + 40.0).astype(np.float32)
    z[rng.random(shape) < 0.05] = np.nan
    ground = rng.random(shape) > 0.35
    ground[: shape[0] // 3, : shape[1] // 2] = False
    monkeypatch.setattr(est, "_PLANE_BAND_ROWS", band)
    monkeypatch.setattr(est, "_PLANE_SOLVE_CELLS", solve_cells)
    oracle = _ground_plane_gradient_oracle(z, ground, cell, r, band)
    assert np.isfinite(oracle[0]).mean() > 0.5
    assert np.isnan(oracle[0]).any() == (min(shape[0] // 3, shape[1] // 2) > r)
    with ThreadPoolExecutor(max_workers=1) as pool:
        got = est.ground_plane_gradient(z, ground, cell, r, pool=pool if threads > 1 else None)
        # at some cells only (refine_ground's bracketed cells): the same values there, NaN elsewhere; bands
        # without such a cell skipped
        at = rng.random(shape) < 0.03
        at[: shape[0] // 2] = False
        part = est.ground_plane_gradient(z, ground, cell, r, pool=pool if threads > 1 else None, at=at)
    for a, b, c in zip(got, oracle, part):
        assert a.dtype == np.float32 and c.dtype == np.float32
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(c[at], b[at])
        assert np.isnan(c[~at]).all()


@pytest.mark.parametrize("dtype", [np.float32, np.float64, bool, np.uint8])
def test_block_expand_equals_two_repeats(dtype):
    """estimate.block_expand (geodesic's fine re-analysis, dtm's coarse grid) gives the two repeats' raster
    exactly: every factor, rasters cut inside the last block row and column or not, 1-row and 1-column."""
    from bare_earth.core.estimate import block_expand
    rng = np.random.default_rng(2)
    for k, shape in ((1, (5, 7)), (2, (6, 8)), (2, (5, 7)), (3, (7, 10)), (4, (1, 9)), (4, (9, 1)), (8, (17, 23))):
        a = (rng.random((-(-shape[0] // k), -(-shape[1] // k))) * 9).astype(dtype)
        ref = np.repeat(np.repeat(a, k, axis=0)[:shape[0]], k, axis=1)[:, :shape[1]]
        got = block_expand(a, k, shape)
        assert got.shape == shape and got.dtype == ref.dtype and np.array_equal(got, ref)
        got[...] = 0                                        # a new array the callers may write
        assert a.any()


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int16])
def test_height_resolution_is_float32_spacing_at_the_largest_height(dtype):
    z = np.array([[50, -430], [7, 0]], dtype)
    assert est.height_resolution(z) == float(np.spacing(np.float32(430.0)))
    f = np.array([[np.nan, 2.0]], np.float32)
    assert est.height_resolution(f) == float(np.spacing(np.float32(2.0)))
    assert math.isnan(est.height_resolution(np.full((2, 2), np.nan, np.float32)))


def test_raised_region_span_counts_the_rows_or_columns_of_the_longest_raised_region():
    # the hall of the test above (30 x 70 m) and a 20 x 20 m shed: the hall's 68 rows within its rims
    z = np.zeros((90, 80), np.float32)
    z[10:80, 15:45] = 8.0
    z[30:50, 55:75] = 6.0
    assert est.raised_region_span(z, (1.0, 1.0), 2.0, 10.0, max_width_m=50.0, max_span_m=100.0) == 68
    # only regions spanning more than min_cells are looked at: the hall's span, or none beyond it
    assert est.raised_region_span(z, (1.0, 1.0), 2.0, 10.0, max_width_m=50.0, max_span_m=100.0, min_cells=30) == 68
    assert est.raised_region_span(z, (1.0, 1.0), 2.0, 10.0, max_width_m=50.0, max_span_m=100.0, min_cells=68) == 0
    # the hall beyond the span looked at: the shed's 18; none wider than min_width_m: none
    assert est.raised_region_span(z, (1.0, 1.0), 2.0, 10.0, max_width_m=50.0, max_span_m=60.0) == 18
    assert est.raised_region_span(z, (1.0, 1.0), 2.0, 40.0, max_width_m=50.0, max_span_m=100.0) == 0
    assert est.raised_region_span(np.zeros((40, 40), np.float32), (1.0, 1.0), 2.0, 10.0) == 0
    # across=False: a level running across the raster (meeting two opposite sides: its walls' run, mirrored
    # at both, is three times the rows) spans nothing; the hall and the shed, inside, span as before
    t = np.zeros((60, 40), np.float32)
    t[:, 10:30] = 6.0
    assert est.raised_region_span(t, (1.0, 1.0), 2.0, 0.0, max_width_m=100.0, max_span_m=200.0) == 180
    assert est.raised_region_span(t, (1.0, 1.0), 2.0, 0.0, max_width_m=100.0, max_span_m=200.0, across=False) == 0
    assert est.raised_region_span(z, (1.0, 1.0), 2.0, 0.0, max_width_m=50.0, max_span_m=100.0, across=False) == 68


def test_raised_region_span_walled_counts_regions_on_walls_along_both_sides():
    # a ring 10 m wide round a courtyard at the ground's level, 100 m square: on walls all round
    z = np.zeros((140, 140), np.float32)
    z[20:120, 20:120] = 10.0
    z[30:110, 30:110] = 0.0
    assert est.raised_region_span_walled(z, (1.0, 1.0), 2.0, 0.0, max_span_m=200.0) == 98
    assert est.raised_region_span_walled(z, (1.0, 1.0), 2.0, 0.0, max_span_m=200.0, min_cells=98) == 0
    # a straight wing 100 x 12 m: the same span
    w = np.zeros((140, 60), np.float32)
    w[20:120, 24:36] = 10.0
    assert est.raised_region_span_walled(w, (1.0, 1.0), 2.0, 0.0, max_span_m=200.0) == 98
    # a wing 70 m long cut by the raster's edge: what is seen (raised_region_span mirrors its walls)
    e = np.zeros((100, 60), np.float32)
    e[0:70, 24:36] = 10.0
    assert est.raised_region_span(e, (1.0, 1.0), 2.0, 0.0, max_span_m=200.0) == 138
    assert est.raised_region_span_walled(e, (1.0, 1.0), 2.0, 0.0, max_span_m=200.0) == 69
    # the quarry site at 2 m (regions longer than 100 m): a bench arc 14 m wide and 226 m long within the pit
    # is a raised region on walls (over 53 % of its outline: its inner side and its ends), its outer side
    # rising to the bench above: its walls do not run along both sides
    from bare_earth.core.synthetic_sites import make_site
    q = make_site("quarry", 2.0, "lowest", seed=0).dsm
    assert est.raised_region_span(q, (2.0, 2.0), 1.0, 0.0, max_span_m=400.0, min_cells=50, across=False) == 113
    assert est.raised_region_span_walled(q, (2.0, 2.0), 1.0, 0.0, max_span_m=400.0, min_cells=50,
                                          across=False) == 0


def test_raised_region_grid_is_the_block_minima_of_at_most_the_cells_allowed(monkeypatch):
    z = np.arange(36, dtype=np.float32).reshape(6, 6)
    zs, cs, k = est.raised_region_grid(z, (1.0, 2.0))
    assert zs is z and cs == (1.0, 2.0) and k == 1
    monkeypatch.setattr(est, "RAISED_REGION_CELLS", 9)
    zs, cs, k = est.raised_region_grid(z, (1.0, 2.0))
    assert k == 2 and cs == (2.0, 4.0)
    np.testing.assert_array_equal(zs, est.block_minima(z, 2))


def _plane_with_low_vegetation(seed=0, n=192, noise=0.1, cover=0.6, clean_cols=64):
    """A plane (noise ``noise`` m) whose cells left of the last ``clean_cols`` columns carry low vegetation
    0.6-1.5 m high on ``cover`` of them, within the ground-level band: a highest-point DSM of shrubs on a
    hillside. Returns ``(z, vegetation)``."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:n, 0:n]
    z = 0.3 * x + 0.1 * y + rng.normal(0.0, noise, (n, n))
    veg = (rng.random((n, n)) < cover) & (x < n - clean_cols)
    z[veg] += rng.uniform(0.6, 1.5, np.count_nonzero(veg))
    return z.astype(np.float32), veg


def test_noise_of_the_cleanest_tiles_ignores_low_vegetation_on_most_of_the_ground():
    """Low vegetation on most ground-level cells (60 % of two thirds of the raster) makes the lower quartile of
    the second differences the vegetation's roughness; the noise, the same everywhere, is read on the cleanest
    quarter of the 32-cell tiles (the third without vegetation): ``sigma_cleanest``. Without vegetation both
    agree."""
    z, _ = _plane_with_low_vegetation()
    got = noise_ground_level(z, (1.0, 1.0))
    assert got["sigma"] > 2.0 * 0.1                               # the whole window: the vegetation's
    assert got["tiles"] == 36
    assert got["sigma_cleanest"] == pytest.approx(0.1, rel=0.1)
    clean, _ = _plane_with_low_vegetation(cover=0.0)
    got = noise_ground_level(clean, (1.0, 1.0))
    assert got["sigma"] == pytest.approx(0.1, rel=0.05)
    assert got["sigma_cleanest"] == pytest.approx(got["sigma"], rel=0.1)
    small = noise_ground_level(clean[:64, :64], (1.0, 1.0))      # 4 tiles: too few to rank
    assert np.isfinite(small["sigma"]) and small["tiles"] == 4 and np.isnan(small["sigma_cleanest"])


def test_sensor_noise_is_the_cleanest_tiles_where_lower():
    """The sensor's noise: ``sigma_cleanest`` where the whole window reads more (low vegetation on most of it),
    ``sigma`` where the tiles are too few to rank or read it higher, NaN where ``sigma`` is not measurable."""
    assert est.sensor_noise({"sigma": 0.37, "sigma_cleanest": 0.23}) == 0.23
    assert est.sensor_noise({"sigma": 0.1, "sigma_cleanest": 0.12}) == 0.1
    assert est.sensor_noise({"sigma": 0.1, "sigma_cleanest": float("nan")}) == 0.1
    assert math.isnan(est.sensor_noise({"sigma": float("nan"), "sigma_cleanest": 0.1}))
    z, _ = _plane_with_low_vegetation()
    got = noise_ground_level(z, (1.0, 1.0))
    assert est.sensor_noise(got) == got["sigma_cleanest"] == pytest.approx(0.1, rel=0.1)


def test_tile_quartiles_are_each_tiles_lower_quartile():
    d = np.arange(1.0, 9.0).reshape(2, 4)
    on = np.ones(d.shape, bool)
    on[0, 0] = False
    # middle cells at rows 0-1, columns 1-4 of a 2 x 6 raster; tiles of 2 cells: columns 0-1, 2-3, 4-5
    got, counts = est._tile_quartiles((2, 6), ((d, on, (0, 1)),), 2, 1)
    # tile 0 (columns 0-1): |d| 5 -> 5; tile 1 (2-3): 2, 3, 6, 7 -> 2.75; tile 2 (4-5): 4, 8 -> 5
    np.testing.assert_allclose(got, [5.0, 2.75, 5.0])
    assert counts.tolist() == [1, 4, 2]
    assert est._tile_quartiles((2, 6), ((d, on, (0, 1)),), 2, 3)[0].tolist() == [2.75]


@pytest.mark.parametrize("band_values", [1 << 21, 600, 1])
def test_tile_quartiles_equal_each_tiles_percentile_in_any_band(monkeypatch, band_values):
    """Each tile's np.percentile(25) of its directions' |d| (by their middle cells, offsets included), the tiles
    in raster order, with bands of one tile row or several (the band's rows read from each direction's own
    rows), float32 and float64 differences, partial tiles at the raster's ends and tiles below min_samples left
    out."""
    monkeypatch.setattr(est, "_TILE_BAND_VALUES", band_values)
    rng = np.random.default_rng(11)
    H, W, tile = 23, 29, 4
    z = rng.normal(0.0, 1.0, (H, W)).astype(np.float32)
    z[5, 7] = np.nan
    parts = ((z[:, :-2] - 2 * z[:, 1:-1] + z[:, 2:], (0, 1)),
             ((z[:-2] - 2 * z[1:-1] + z[2:]).astype(np.float64), (1, 0)))
    parts = tuple((d, rng.random(d.shape) < 0.7, off) for d, off in parts)
    got, counts = est._tile_quartiles((H, W), parts, tile, 5)
    want, n = [], []
    for tr in range(-(-H // tile)):
        for tc in range(-(-W // tile)):
            v = []
            for d, on, (r0, c0) in parts:
                r, c = np.nonzero(on & np.isfinite(d))
                at = ((r + r0) // tile == tr) & ((c + c0) // tile == tc)
                v.extend(np.abs(d[r[at], c[at]]).astype(np.float64))
            if len(v) >= 5:
                want.append(np.percentile(v, 25.0))
                n.append(len(v))
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert counts.tolist() == n and counts.dtype == np.int64


def test_cleanest_noise_needs_the_tiles_lower_beyond_their_sampling_and_rounding():
    q = 0.3186 * math.sqrt(6.0)                       # a tile quartile of q reads 1 m
    tiles, counts = np.full(12, 0.1 * q), np.full(12, 900)          # standard error 1.79 / 30 = 0.06
    assert est.cleanest_noise(0.5, tiles, counts) == pytest.approx(0.1)
    assert est.cleanest_noise(0.117, tiles, counts) == 0.117        # within 3 standard errors (0.1 x 1.179)
    assert est.cleanest_noise(0.125, tiles, counts) == pytest.approx(0.1)
    assert est.cleanest_noise(0.125, tiles, counts, quantum=0.03) == 0.125   # one step of 3 cm reads 0.038
    assert est.cleanest_noise(0.05, tiles, counts) == 0.05          # never above sigma
    assert np.isnan(est.cleanest_noise(float("nan"), tiles, counts))
    assert est.cleanest_noise(0.5, np.full(12, 0.0), counts, quantum=0.01) == pytest.approx(0.01 / math.sqrt(12.0))


def test_raised_parts_are_roofs_and_crowns_not_the_ground_pits_ramps_or_terraces():
    z = np.zeros((40, 60), np.float32)
    z[5:15, 5:20] = 10.0                                  # a roof: walls down all round
    z[25:28, 40:43] = 6.0                                 # a crown
    z[30, 30] = -5.0                                      # a pit: its rim steps up
    z[32:38, 5:15] = 2.0                                  # a platform reached by a ramp: one part
    z[32:38, 15:25] = np.linspace(1.8, 0.0, 10, dtype=np.float32)   # with the ground
    z[:, 50:] += 3.0                                      # a terrace's upper level across the raster
    want = np.zeros(z.shape, bool)
    want[5:15, 5:20] = want[25:28, 40:43] = True
    got = est.raised_parts(z, 1.0, (40, 40))         # the terrace fits, but runs across the raster
    np.testing.assert_array_equal(got, want)
    # a roof larger than the largest object is terrain (a plateau)
    want[5:15, 5:20] = False
    np.testing.assert_array_equal(est.raised_parts(z, 1.0, (20, 14)), want)
    # a step lower than a wall joins the crown to the ground; nodata is no rim
    np.testing.assert_array_equal(est.raised_parts(z, 6.5, (20, 14)), np.zeros(z.shape, bool))
    z[:, :3] = np.nan
    z[5:15, 3:5] = np.nan                                 # the roof's west wall is a gap: still raised
    got = est.raised_parts(z, 1.0, (20, 20))
    assert got[5:15, 5:20].all() and not got[:, :5].any()


def test_raised_parts_on_a_tilted_plane_with_one_hall_in_float64():
    yy, xx = np.mgrid[0:50, 0:50]
    z = 0.3 * xx + 0.1 * yy                               # a bank-free slope: one part
    z[10:30, 10:30] += 8.0                                # a hall
    got = est.raised_parts(z.astype(np.float64), 1.3, (30, 30))
    assert got.sum() == 400 and got[10:30, 10:30].all()


def test_ground_plane_gradient_at_refuses_a_mask_of_another_shape():
    z = np.zeros((6, 7), np.float32)
    with pytest.raises(ValueError, match="at has shape"):
        est.ground_plane_gradient(z, z == 0, (1.0, 1.0), 2, at=np.ones((6, 6), bool))


def test_square_opening_exact():
    """The opening by a square: a raised part narrower than the square (either way) is cut down to the
    ground around, one the square fits in all over keeps its height, a spike on it goes, a plane keeps
    its heights, nodata stays NaN and is left out of both steps; the brute force agrees."""
    z = np.zeros((7, 9), np.float32)
    z[1:4, 1:3] = 4.0                                  # 3 x 2: no 3 x 3 square fits
    z[1:5, 4:8] = 6.0                                  # 4 x 4: fits
    z[2, 5] = 9.0                                      # a spike on it
    z[6, 0] = np.nan
    got = est.square_opening(z, 3)
    want = np.zeros_like(z)
    want[1:5, 4:8] = 6.0
    want[6, 0] = np.nan
    np.testing.assert_array_equal(got, want)
    plane = (0.3 * np.arange(8)[:, None] + 0.7 * np.arange(10)[None, :]).astype(np.float32)
    np.testing.assert_allclose(est.square_opening(plane, 4), plane, atol=1e-5)
    rng = np.random.default_rng(0)
    r = rng.normal(0, 1, (12, 11)).astype(np.float32)
    # brute force: the highest of the lowest heights of the 3 x 3 squares holding a cell (squares reaching
    # beyond the edge by up to two cells, whose cells there count for nothing)
    pad = np.pad(r, 2, constant_values=np.inf)
    h, w = pad.shape
    ero = np.array([[pad[max(0, i - 1):i + 2, max(0, j - 1):j + 2].min() for j in range(w)] for i in range(h)])
    dil = np.array([[ero[max(0, i - 1):i + 2, max(0, j - 1):j + 2].max() for j in range(w)] for i in range(h)])
    np.testing.assert_allclose(est.square_opening(r, 3), dil[2:-2, 2:-2])
    assert (est.square_opening(r, 3) <= r).all()
    with pytest.raises(ValueError, match="size_cells"):
        est.square_opening(z, 0)


def test_nan_quantile_rows_equals_nanquantile():
    """below_narrow_gap's ring quantile: the rows' np.nanquantile (linear), float32, NaN for a row of
    NaN only, on rows with every count of finite values (one, two, all, none)."""
    import warnings
    rng = np.random.default_rng(2)
    v = rng.normal(0.0, 3.0, (300, 41)).astype(np.float32)
    v[rng.random(v.shape) < rng.random((300, 1))] = np.nan
    v[0] = np.nan
    v[1, 1:] = np.nan
    v[2, 2:] = np.nan
    v[3] = rng.normal(0.0, 3.0, 41)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for q in (0.25, 0.5, 0.9):
            want = np.nanquantile(v, q, axis=1).astype(np.float32)
            got = est._nan_quantile_rows(v, q)
            assert got.dtype == np.float32
            assert np.array_equal(got, want, equal_nan=True)
    assert np.isnan(got[0]) and not np.isnan(got[1:4]).any()


def test_line_share_counts_the_cells_holding_the_level_on_the_best_line():
    """A band three cells wide along the rows holds the level all along its row; a 3 x 3 patch holds it on 3 of
    the 7 cells of every line through its centre; a line cut by the raster's edge is judged on the part inside,
    NaN cells are left out, and each cell takes its own level."""
    g = np.zeros((12, 12), np.float32)
    g[2:5, :] = 0.5
    g[7:10, 4:7] = 0.5
    cells = np.array([3 * 12 + 6, 8 * 12 + 5, 3 * 12 + 0])
    np.testing.assert_allclose(est.line_share(g, cells, (3, 3), 0.4), [1.0, 3 / 7, 1.0], rtol=1e-6)
    # the corner cell's row line keeps 4 cells inside the raster, all on the band
    np.testing.assert_allclose(est.line_share(g, [3 * 12 + 11], (3, 3), 0.4), [1.0])
    # a level above the band's value: no cell holds it
    np.testing.assert_allclose(est.line_share(g, cells, (3, 3), [0.6, 0.4, 0.6]), [0.0, 3 / 7, 0.0], rtol=1e-6)
    # NaN cells on the patch's row are left out: 3 of the 5 cells with a value
    h = g.copy()
    h[8, 2:4] = np.nan
    np.testing.assert_allclose(est.line_share(h, [8 * 12 + 5], (3, 3), 0.4), [3 / 5], rtol=1e-6)
    # the diagonals take the smaller half-length, columns and rows their own
    d = np.zeros((9, 9), np.float32)
    d[np.arange(9), np.arange(9)] = 1.0
    np.testing.assert_allclose(est.line_share(d, [4 * 9 + 4], (4, 1), 1.0), [1.0])
    assert est.line_share(g, np.array([], np.int64), (3, 3), 0.4).size == 0



def _line_share_by_cell(g, cell, half_widths, level):
    """line_share's definition, one cell and one line cell at a time."""
    H, W = g.shape
    i, j = divmod(int(cell), W)
    best = 0.0
    for di, dj in est.LINE_DIRECTIONS:
        h = half_widths[1] if di == 0 else half_widths[0] if dj == 0 else min(half_widths)
        vals = [g[i + di * t, j + dj * t] for t in range(-h, h + 1)
                if 0 <= i + di * t < H and 0 <= j + dj * t < W and np.isfinite(g[i + di * t, j + dj * t])]
        if vals:
            best = max(best, sum(v >= level for v in vals) / len(vals))
    return best


def test_line_share_equals_its_definition_inside_and_at_the_edges():
    """Lines inside the raster (gathered by flat offsets) and lines cut by its edges (bounds tested) give the
    definition's shares, NaN and +inf left out, in chunks smaller than the cells."""
    rng = np.random.default_rng(7)
    g = rng.random((23, 31)).astype(np.float32)
    g[rng.random(g.shape) < 0.1] = np.nan
    g[rng.random(g.shape) < 0.03] = np.inf
    cells = rng.choice(g.size, 120, replace=False)
    level = rng.random(cells.size).astype(np.float32)
    for hw in ((4, 6), (0, 3), (12, 2)):
        want = [_line_share_by_cell(g, c, hw, lv) for c, lv in zip(cells, level)]
        got = est.line_share(g, cells, hw, level, chunk=17)
        np.testing.assert_array_equal(got, np.float32(want))

def test_line_share_refuses_bad_input():
    g = np.zeros((4, 4), np.float32)
    with pytest.raises(ValueError, match="2-D"):
        est.line_share(g.ravel(), [0], (1, 1), 0.0)
    with pytest.raises(ValueError, match="half_widths"):
        est.line_share(g, [0], (-1, 1), 0.0)
    with pytest.raises(ValueError, match="flat indices"):
        est.line_share(g, [16], (1, 1), 0.0)


def test_under_chords_exact():
    """A cell is under its chords along its row and its column (ends within the half width), by the
    tolerance: a plane lies on its chords, a bump above them, a cell between two bumps under them;
    a cell without a chord on an axis (on the raster's edge) and a nodata cell are False."""
    y, x = np.mgrid[0:7, 0:9].astype(np.float32)
    plane = 0.7 * x - 0.4 * y
    got = est.under_chords(plane, 2, 0.01)
    want = np.zeros(plane.shape, bool)
    want[1:-1, 1:-1] = True
    np.testing.assert_array_equal(got, want)
    z = plane.copy()
    z[3, 4] += 0.5                                   # a bump: above the chords along both axes
    z[3, 2] += 3.0                                   # crowns on either side of (3, 3) along its row
    got = est.under_chords(z, 2, 0.3)
    assert not got[3, 4] and not got[3, 2]
    assert got[3, 3]                                 # between them: under every chord
    assert est.under_chords(z, 2, 0.6)[3, 4]          # within a larger tolerance
    # the bump lies within reach of (3, 6)'s chords (ends at columns 4..5 and 7..8): (3, 6) is under them
    assert got[3, 6]
    # the bump at (3, 4) is one end of (3, 5)'s chord (4, 6): (3, 5) stands under it; the chord (3, 7)
    # of half width 1 does not reach it
    assert got[3, 5]
    n = z.copy()
    n[3, 3] = np.nan                                 # nodata: False, and no chord through it
    g2 = est.under_chords(n, 1, 0.3)
    assert not g2[3, 3]
    assert g2[3, 1]                                  # its other chords: along the column
    # one cell wide: no chord along the row
    assert not est.under_chords(np.zeros((5, 1), np.float32), 1, 0.1).any()


def _under_chords_by_cell(z, m, tol):
    """The definition of under_chords, cell by cell (float32 as the function sums): finite, at least one chord
    with finite ends on each axis, and no higher than tol above any of them."""
    h, w = z.shape
    out = np.zeros((h, w), bool)
    for r in range(h):
        for c in range(w):
            if not np.isfinite(z[r, c]):
                continue
            ok = True
            for line, k, n in ((z[r], c, w), (z[:, c], r, h)):
                seen = False
                for i in range(1, m + 1):
                    for j in range(1, m + 1):
                        if k - i < 0 or k + j >= n:
                            continue
                        ch = line[k - i] * np.float32(j) + line[k + j] * np.float32(i)
                        ch = ch / np.float32(i + j) + np.float32(tol)
                        seen |= bool(np.isfinite(ch))
                        ok &= not (line[k] > ch)
                ok &= seen
            out[r, c] = ok
    return out


@pytest.mark.parametrize("m", [1, 2, 3, 6])
def test_under_chords_equals_its_definition_across_blocks(monkeypatch, m):
    """By blocks of rows (a column's chords read the rows of the blocks around it) the cells are those of the
    definition, bit for bit: random and curved surfaces with crowns and nodata, blocks of 3 rows (smaller than
    the chords' reach), a surface narrower than a chord."""
    monkeypatch.setattr(est, "_CHORD_BLOCK_CELLS", 3 * 17)
    rng = np.random.default_rng(m)
    y, x = np.mgrid[0:23, 0:17].astype(np.float32)
    curved = 0.02 * x * x - 0.3 * y + 4.0 * (rng.random(x.shape) < 0.1)
    for z in (rng.normal(0.0, 1.0, (23, 17)), curved, rng.normal(0.0, 1.0, (4, 17)), rng.normal(0.0, 1.0, (23, 2))):
        z = np.asarray(z, np.float32)
        z[rng.random(z.shape) < 0.15] = np.nan
        for tol in (0.0, 0.3):
            np.testing.assert_array_equal(est.under_chords(z, m, tol), _under_chords_by_cell(z, m, tol))


def test_under_chords_refuses_bad_input():
    with pytest.raises(ValueError, match="2-D"):
        est.under_chords(np.zeros(5), 1, 0.1)
    with pytest.raises(ValueError, match="half_cells"):
        est.under_chords(np.zeros((3, 3)), 0, 0.1)
    with pytest.raises(ValueError, match="tol_m"):
        est.under_chords(np.zeros((3, 3)), 1, -0.1)


def test_running_minimum_slopes_exact():
    """On a plane the slope is the plane's, away from the raster's edge (the square's side: its minimum
    is clipped there; 0 in a corner within half of it); a pit is read by the squares holding it only; nodata is
    left out of the minimum (near it the minimum moves to its neighbour)."""
    y, x = np.mgrid[0:30, 0:40].astype(np.float32)
    plane = 0.3 * x * 2.0 + 0.4 * y * 2.0              # 2 m cells: slopes 0.3 along X, 0.4 along Y
    s = est.running_minimum_slopes(plane, (2.0, 2.0), 6)
    np.testing.assert_allclose(s[6:-6, 6:-6], 0.5, rtol=1e-5)
    assert (s[:3, :3] == 0).all()                    # neither difference reaches the corner
    z = plane.copy()
    z[20:23, 18:21] -= 10.0                          # a pit 3 x 3 cells: the squares holding it read its floor
    s = est.running_minimum_slopes(z, (2.0, 2.0), 6)
    np.testing.assert_allclose(s[6:10, 6:-6], 0.5, rtol=1e-5)   # beyond the squares holding it: the plane's
    assert abs(s[21, 15] - 0.5) > 0.1                # its squares reach the pit: another slope
    z = plane.copy()
    z[5, 30] = np.nan                                # nodata: a finite slope everywhere, the plane's beyond it
    s = est.running_minimum_slopes(z, (2.0, 2.0), 6)
    assert np.isfinite(s).all()
    np.testing.assert_allclose(s[12:-6, 6:-6], 0.5, rtol=1e-5)
    with pytest.raises(ValueError, match="side_cells"):
        est.running_minimum_slopes(plane, (2.0, 2.0), 1)
    with pytest.raises(ValueError, match="2-D"):
        est.running_minimum_slopes(plane.ravel(), (2.0, 2.0), 4)


def test_running_minimum_gradient_exact():
    """The components of :func:`running_minimum_slopes`: on a plane its slopes along X and Y (signed)
    away from the raster's edge, 0 within half the square's side of it along that axis; their magnitude
    is the slope.
    A step of 4 m along X (a wall): the minimum over the square rises it over the central differences'
    span, 4 / (2 (k // 2) dx) at most, and not along Y."""
    y, x = np.mgrid[0:30, 0:40].astype(np.float32)
    plane = -0.3 * x * 2.0 + 0.4 * y * 2.0
    gx, gy = est.running_minimum_gradient(plane, (2.0, 2.0), 6)
    np.testing.assert_allclose(gx[:, 6:-6], -0.3, rtol=1e-5)   # beyond the square's side: its minimum
    np.testing.assert_allclose(gy[6:-6], 0.4, rtol=1e-5)       # is clipped by the edge there
    assert not gx[:, :3].any() and not gy[:3].any()
    np.testing.assert_array_equal(np.hypot(gx, gy), est.running_minimum_slopes(plane, (2.0, 2.0), 6))
    step = np.where(x >= 20, 4.0, 0.0).astype(np.float32)
    gx, gy = est.running_minimum_gradient(step, (1.0, 1.0), 6)
    assert gx.max() == pytest.approx(4.0 / 6.0) and gx.min() == 0.0 and not gy.any()


def test_running_minimum_exact():
    """The running minimum over a square of ``side + 1`` cells (the edge repeated beyond it), +inf
    where the square holds no finite height; inside a frame of +inf it is the same array."""
    z = np.array([[5, 4, 9, 9, 9],
                  [6, 7, 9, np.nan, 9],
                  [9, 9, 9, np.nan, np.nan],
                  [9, 9, 1, np.nan, np.nan]], np.float32)
    m = est.running_minimum(z, 2)
    assert m.dtype == np.float32
    assert m.tolist() == [[4, 4, 4, 9, 9], [4, 4, 4, 9, 9], [6, 1, 1, 1, 9], [9, 1, 1, 1, np.inf]]
    f = est.running_minimum(z, 2, frame=3)
    assert f.shape == (10, 11)
    np.testing.assert_array_equal(f[3:-3, 3:-3], m)
    f[3:-3, 3:-3] = np.inf
    assert (f == np.inf).all()


def test_above_chords_exact():
    """A peak stands above a chord of its neighbours by more than the margin, and above both its
    ends, along its row, its column and both diagonals: a plane of any slope has none, a bump is one
    (not where the plane rises more over a cell than the bump's height), a ridge along a row or a
    diagonal is none (it lies on its chords along itself), nor is a cell without a chord in one
    direction (the raster's edge, nodata ends) or a nodata cell; the margin may vary by cell."""
    y, x = np.mgrid[0:9, 0:9].astype(np.float32)
    steep = 0.9 * x - 0.4 * y
    assert not est.above_chords(steep, 2, 0.01).any()
    bumped = steep.copy()
    bumped[4, 4] += 0.5                                   # below its uphill neighbour: no peak
    assert not est.above_chords(bumped, 2, 0.3).any()
    plane = 0.2 * x - 0.1 * y
    z = plane.copy()
    z[4, 4] += 0.5
    got = est.above_chords(z, 2, 0.3)
    want = np.zeros(z.shape, bool)
    want[4, 4] = True
    np.testing.assert_array_equal(got, want)
    assert not est.above_chords(z, 2, 0.5).any()          # within a larger margin
    margin = np.full(z.shape, 0.3, np.float32)
    margin[4, 4] = 0.6                                     # the margin per cell
    assert not est.above_chords(z, 2, margin).any()
    # a ridge along the row and one along a diagonal: on their chords along themselves
    r = plane.copy()
    r[4, :] += 1.0
    assert not est.above_chords(r, 2, 0.3).any()
    d = plane + np.where(x == y, np.float32(1.0), np.float32(0.0))
    assert not est.above_chords(d, 2, 0.3).any()
    # a step running diagonally: its top edge is on its chords along the edge
    s = plane + np.where(x + y > 8, np.float32(1.5), np.float32(0.0))
    assert not est.above_chords(s, 2, 0.3).any()
    # a bump on the raster's edge has no chord across it; nodata ends are no chords
    e = plane.copy()
    e[0, 4] += 1.0
    assert not est.above_chords(e, 2, 0.3).any()
    n = z.copy()
    n[4, 3] = n[4, 2] = np.nan                              # no chord along the row from the left
    assert not est.above_chords(n, 2, 0.3)[4, 4]
    n = z.copy()
    n[4, 4] = np.nan
    assert not est.above_chords(n, 2, 0.3).any()


def test_above_chords_by_blocks_of_rows_equals_one_block(monkeypatch):
    rng = np.random.default_rng(3)
    z = rng.normal(0.0, 1.0, (40, 23)).astype(np.float32)
    z[5:9, 4:7] = np.nan
    one = est.above_chords(z, 2, 0.5)
    assert one.any()
    monkeypatch.setattr(est, "_CHORD_BLOCK_CELLS", 23 * 3)
    np.testing.assert_array_equal(est.above_chords(z, 2, 0.5), one)


def test_above_chords_refuses_bad_input():
    with pytest.raises(ValueError, match="2-D"):
        est.above_chords(np.zeros(5), 1, 0.1)
    with pytest.raises(ValueError, match="half_cells"):
        est.above_chords(np.zeros((3, 3)), 0, 0.1)
    with pytest.raises(ValueError, match="margin_m"):
        est.above_chords(np.zeros((3, 3)), 1, -0.1)
    with pytest.raises(ValueError, match="margin_m"):
        est.above_chords(np.zeros((3, 3)), 1, np.zeros((2, 2)))


@pytest.mark.parametrize("diagonal", [False, True])
@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int16])
def test_joined_runs_in_bands_equals_one_band(monkeypatch, diagonal, dtype):
    """The height differences of :func:`est.joined_runs` taken in bands of rows (down to one row a band) give the
    runs and parts of the whole raster at once (the same float operations per cell), with NaN and at the edges."""
    rng = np.random.default_rng(12)
    z = np.round(rng.random((37, 23)) * 6).astype(np.float64)
    if dtype != np.int16:
        z[rng.random(z.shape) < 0.05] = np.nan
    z = z.astype(dtype)
    nodes = rng.random(z.shape) > 0.2
    monkeypatch.setattr(est, "_JOIN_BAND_CELLS", 1 << 40)
    want = est.joined_runs(z, nodes, 1.5, diagonal=diagonal)
    for cells in (1, 23, 5 * 23 + 7):
        monkeypatch.setattr(est, "_JOIN_BAND_CELLS", cells)
        got = est.joined_runs(z, nodes, 1.5, diagonal=diagonal)
        for g, w in zip(got, want):
            assert np.array_equal(g, w)
