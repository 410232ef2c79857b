"""Tests of the morphological filter (core/morphology.py): tiny exact arrays."""
import numpy as np
import pytest

from bare_earth.core import GROUND, LOW, NODATA, OBJECT
from bare_earth.core import morphology as morph
from bare_earth.core.methods import get_method
from bare_earth.core.pipeline import run_array

DTYPES = [np.float32, np.float64, np.int16]


def _box_scene(dtype=np.float32):
    """Flat ground at 10 with a 4 x 5 building 6 high: (scene, truth mask)."""
    z = np.full((24, 30), 10, dtype=dtype)
    z[6:10, 8:13] = 16
    truth = np.zeros(z.shape, np.uint8)
    truth[6:10, 8:13] = OBJECT
    return z, truth


def _ridge(with_box=True):
    """A ridge (tent profile, slopes 0.5) along the rows, with a 5 x 5 box 8 high on its flank."""
    j = np.arange(61, dtype=np.float32)
    z = np.tile(30.0 - 0.5 * np.abs(j - 30.0), (40, 1)).astype(np.float32)
    truth = np.zeros(z.shape, np.uint8)
    if with_box:
        z[15:20, 10:15] += 8.0
        truth[15:20, 10:15] = OBJECT
    return z, truth


# --------------------------------------------------------------------------- opening
def test_opening_removes_a_narrow_box_and_keeps_a_wide_one():
    z = np.zeros((12, 12), np.float32)
    z[4:7, 4:7] = 5.0                          # 3 x 3 box
    np.testing.assert_array_equal(morph.open_surface(z, 1.0, 5.0), np.zeros_like(z))
    np.testing.assert_array_equal(morph.open_surface(z, 1.0, 3.0), z)   # the 3 x 3 window fits


def test_opening_of_a_step_and_a_spike_profile():
    # one row repeated: a step up (wider than the window) and a two-cell spike
    row = np.array([0, 0, 0, 0, 9, 0, 0, 0, 3, 3, 3, 3, 3, 3, 7, 7, 3, 3, 3, 3], np.float32)
    z = np.tile(row, (7, 1))
    expect = row.copy()
    expect[4] = 0
    expect[14:16] = 3
    out = morph.open_surface(z, 1.0, 3.0)
    np.testing.assert_array_equal(out, np.tile(expect, (7, 1)))
    # both spikes are narrower than the 3-cell window and go; the step stays


def test_opening_keeps_a_ramp_exactly_and_cuts_a_ridge_by_slope_times_radius():
    j = np.arange(41, dtype=np.float32)
    ramp = np.tile(0.5 * j, (20, 1))
    # exact except within one radius (5 cells) of the raster's uphill edge, where the
    # clipped window cannot fit under the ramp's high end
    np.testing.assert_allclose(morph.open_surface(ramp, 1.0, 11.0)[:, :36], ramp[:, :36])
    z, _ = _ridge(with_box=False)
    out = morph.open_surface(z, 1.0, 11.0)         # r = 5 cells
    assert out[20, 30] == pytest.approx(30.0 - 0.5 * 5)     # the top is flattened
    assert np.all(out <= z + 1e-6)


def test_opening_ignores_nodata_and_keeps_it_nan():
    z = np.zeros((10, 10), np.float32)
    z[2:4, 2:4] = 4.0
    z[7, 7] = np.nan
    out = morph.open_surface(z, 1.0, 5.0)
    assert np.isnan(out[7, 7])
    np.testing.assert_array_equal(np.nan_to_num(out, nan=-1.0)[np.isfinite(z)], 0.0)


def test_running_min_max_equal_ndimage():
    from scipy import ndimage
    rng = np.random.default_rng(3)
    a = rng.normal(size=(37, 53)).astype(np.float32)
    for r in (1, 2, 3, 4, 7, 8, 20, 40):
        for axis in (0, 1):
            got = morph._running(a, r, axis, np.minimum)
            ref = ndimage.minimum_filter1d(a, 2 * r + 1, axis=axis, mode="nearest")
            np.testing.assert_array_equal(got, ref)
            got = morph._running(a, r, axis, np.maximum)
            ref = ndimage.maximum_filter1d(a, 2 * r + 1, axis=axis, mode="nearest")
            np.testing.assert_array_equal(got, ref)


@pytest.mark.parametrize("band", [1, 3, 8, 60])
def test_running_in_bands_equals_one_pass(band):
    # bands across the window's axis (ragged last band, bands of one line, one band for all),
    # with +-inf (nodata of the erosion and the dilation) and windows longer than the array
    from scipy import ndimage
    rng = np.random.default_rng(5)
    a = rng.normal(size=(29, 41)).astype(np.float32)
    a[rng.random(a.shape) < 0.1] = np.inf
    a[3, :] = -np.inf
    work = morph._Work()
    for r in (1, 2, 5, 16, 30):
        for axis in (0, 1):
            for op, flt in ((np.minimum, ndimage.minimum_filter1d), (np.maximum, ndimage.maximum_filter1d)):
                got = morph._running_banded(a, r, axis, op, work, band=band)
                np.testing.assert_array_equal(got, morph._running(a, r, axis, op))
                np.testing.assert_array_equal(got, flt(a, 2 * r + 1, axis=axis, mode="nearest"))


def test_window_radii():
    assert [r[1] for r in morph.window_radii(41.0, 1.0, growth=2.0)] == [1, 2, 4, 8, 16, 20]
    assert [r[1] for r in morph.window_radii(11.0, 1.0, growth=1.0)] == [1, 2, 3, 4, 5]
    radii = morph.window_radii(20.0, (0.5, 1.0))
    assert radii[-1][:2] == (10, 20)           # same metres along both axes
    with pytest.raises(ValueError, match="window_growth"):
        morph.window_radii(20.0, 1.0, growth=0.5)


def test_drop_references_measure_the_drop_over_a_doubling_of_the_window():
    """Each step's drop is measured from the window that doubles into it (-1: the surface): the
    previous step for doubling windows and SMRF's one-cell steps, two steps back for sqrt 2."""
    radii = morph.window_radii(41.0, 1.0, growth=2.0)
    assert morph.drop_references(radii, 2.0) == [-1, 0, 1, 2, 3, 4]      # as before: unchanged
    radii = morph.window_radii(81.0, 1.0)      # the default growth, sqrt 2
    assert [r[1] for r in radii] == [1, 2, 3, 5, 8, 12, 17, 25, 36, 40]
    assert morph.drop_references(radii, morph.WINDOW_GROWTH) == [-1, -1, 0, 1, 2, 3, 4, 5, 6, 7]
    assert morph.drop_references(morph.window_radii(5.0, 1.0, growth=1.0), 1.0) == [-1, 0]
    assert morph.drop_references(radii, 1.2) == [-1, -1, -1, -1, 0, 1, 2, 3, 4, 5]


def test_doubling_windows_give_the_previous_filter():
    """window_growth 2 (the dtm member's) measures each drop since the previous step, as before."""
    rng = np.random.default_rng(3)
    z = rng.normal(10, 0.05, (60, 70)).astype(np.float32)
    z[10:30, 10:25] += 6.0
    z[40:44, 50:53] += 9.0
    a, has_nodata = morph._as_inf(z)
    radii = morph.window_radii(41.0, 1.0, growth=2.0)
    flags, last = morph._progressive(a, radii, 0.3, has_nodata, growth=2.0)
    want = np.zeros(z.shape, bool)
    prev = z
    for _ry, rx, rad in radii:
        o = morph.open_surface(z, 1.0, 2 * rx + 1.0)
        want |= (prev - o) > np.float32(0.3 * rad)
        prev = o
    np.testing.assert_array_equal(flags, want)
    np.testing.assert_array_equal(last, prev)


@pytest.mark.parametrize("cell", [1.0, 2.0])
def test_flat_roof_36_m_wide_and_8_m_high_is_an_object(cell):
    """The failure of the simulated urban rows: with doubling windows a flat roof vanishing just
    past a power of two faces SMRF's threshold at up to twice its half-width (36 m wide, 8 m
    high: 0.3 x 32 m = 9.6 m > 8 m, kept as ground). With radii growing by sqrt(2) it is tested
    at 25 m or less (7.5 m < 8 m): the whole roof is an object, and nothing else."""
    n = int(160 / cell)
    rng = np.random.default_rng(0)
    z = (10 + rng.normal(0, 0.03, (n, n))).astype(np.float32)
    w = int(round(36 / cell))
    i0 = (n - w) // 2
    z[i0:i0 + w, i0:i0 + w] += 8.0
    truth = np.zeros(z.shape, np.uint8)
    truth[i0:i0 + w, i0:i0 + w] = OBJECT
    args = dict(mode="progressive", max_object_size_m=80.0, dh_m=0.5, slope=0.3)
    np.testing.assert_array_equal(morph.filter_morphological(z, cell, **args).mask, truth)
    old = morph.filter_morphological(z, cell, window_growth=2.0, **args)
    assert np.all(old.mask[truth == OBJECT] == 0)      # the doubling windows miss it


def test_the_object_size_search_keeps_doubling_windows():
    """The size estimate runs its own search with doubling windows whatever the filter's growth,
    so the filter's sqrt 2 steps do not widen the window from terrain patches they flag."""
    from bare_earth.core.synthetic import make_scene
    z = make_scene("mixed", (128, 128), seed=4).dsm
    sizes = {g: morph.resolve_morphological_params(z, 1.0, window_growth=g)["max_object_size_m"]
             for g in (2.0, morph.WINDOW_GROWTH)}
    assert sizes[2.0] == sizes[morph.WINDOW_GROWTH]
    p = morph.resolve_morphological_params(z, 1.0)
    finer = morph.estimate_object_size(z, 1.0, p["slope"], p["dh_m"], outline_slope=p["outline_slope"],
                                       window_growth=morph.WINDOW_GROWTH)
    assert finer != sizes[2.0]                   # the search's growth matters on this scene
    assert morph._OBJECT_SEARCH_GROWTH == 2.0


# --------------------------------------------------------------------------- the filter
@pytest.mark.parametrize("dtype", DTYPES)
@pytest.mark.parametrize("mode", ["single", "progressive"])
def test_box_building_is_removed(dtype, mode):
    z, truth = _box_scene(dtype)
    res = morph.filter_morphological(z, 1.0, mode=mode, max_object_size_m=9.0, dh_m=0.5, slope=0.3)
    np.testing.assert_array_equal(res.mask, truth)
    assert res.mask.dtype == np.uint8
    assert res.surface.dtype == np.float32
    np.testing.assert_allclose(res.surface, 10.0)      # the ground under the building
    assert res.info["mode"] == mode
    assert res.info["dh_m"] == 0.5


def test_ridge_kept_by_progressive_but_cut_by_single():
    z, truth = _ridge()
    prog = morph.filter_morphological(z, 1.0, mode="progressive", max_object_size_m=21.0, dh_m=0.5,
                                  slope=0.6)
    np.testing.assert_array_equal(prog.mask, truth)
    assert prog.info["window_cells"][-1] == (21, 21)
    single = morph.filter_morphological(z, 1.0, mode="single", max_object_size_m=21.0, dh_m=0.5)
    assert np.all(single.mask[truth == OBJECT] == OBJECT)
    top = single.mask[:, 28:33]
    assert np.all(top == OBJECT)                # the ridge top is cut: Type I errors
    assert single.info["window_sizes_m"] == [21.0]


@pytest.mark.parametrize("mode", ["single", "progressive"])
def test_low_outlier_is_class_2(mode):
    z = np.full((15, 15), 5.0, np.float32)
    z[7, 7] = -10.0
    z[3, 10] = -20.0
    res = morph.filter_morphological(z, 1.0, mode=mode, max_object_size_m=7.0, dh_m=0.5, slope=0.3)
    expect = np.zeros(z.shape, np.uint8)
    expect[7, 7] = expect[3, 10] = LOW
    np.testing.assert_array_equal(res.mask, expect)


@pytest.mark.parametrize("cell", [1.0, 2.0, 4.0])
@pytest.mark.parametrize("given", [False, True])
def test_a_deep_pit_is_a_low_outlier_at_every_cell_size(cell, given):
    """A pit 8 m below all the ground around it is a low outlier at every cell size. Before, SMRF's
    one-cell pre-step window at 2 and 4 m cells made the threshold 10 and 20 m: the pit stayed in the
    opening, which carried it over the terrace, and the terrace around it became an object."""
    n = int(round(80 / cell))
    z = np.full((n, n), 100.0, np.float32)
    w = int(round(12 / cell))
    z[:, :w] = 102.0                    # a terrace 12 m wide on the raster's edge, 2 m above the ground
    z[n // 2, w // 2] = 94.0            # a pit 8 m below it
    p = dict(dh_m=0.5, slope=0.3, max_object_size_m=40.0, mode="progressive") if given else {}
    res = morph.filter_morphological(z, cell, **p)
    expect = np.zeros(z.shape, np.uint8)
    expect[n // 2, w // 2] = LOW
    np.testing.assert_array_equal(res.mask, expect)


@pytest.mark.parametrize("shape, spike", [((3, 3), (1, 1)), ((20, 20), (1, 1)), ((20, 20), (1, 10)), ((3, 8), (1, 4))])
def test_a_spike_next_to_the_edge_is_an_object_not_low_ground(shape, spike):
    """The low-outlier pre-step treats the outside of the raster as nodata: its windows hang over
    the edge. Cut at the edge, every window of a cell beside a spike one cell in from the edge
    held the spike, and the opening of ``-z`` took that cell for a pit (a 3 x 3 raster with one
    8 m spike: the 8 ground cells low, the spike ground)."""
    z = np.zeros(shape, np.float32)
    z[spike] = 8.0
    res = morph.filter_morphological(z, 1.0, mode="progressive", dh_m=0.5, slope=0.3, max_object_size_m=10.0)
    expect = np.zeros(shape, np.uint8)
    expect[spike] = OBJECT
    np.testing.assert_array_equal(res.mask, expect)
    assert res.info["low_outlier_cells_prestep"] == 0
    np.testing.assert_array_equal(morph.filter_morphological(z, 1.0).mask, expect)     # derived defaults


@pytest.mark.parametrize("side_m, cell, slope", [(80.0, 0.1, 0.45), (30.0, 0.1, 0.5), (30.0, 1.0, 0.5)])
def test_the_slope_of_a_small_hillside_is_measured(side_m, cell, slope):
    """A drone DSM crop of a hillside, under 3 x 3 blocks of 40 m: the slope is measured on blocks of a
    third of the raster's side (the same median of the block-minimum slopes; their minima lie on a
    plane), and the log says so; the outline slope takes it too (the 90th percentile of 9 blocks is
    not read). Before, it was not measurable, SMRF's floor 0.3 was used and the threshold ``0.3 r``
    cut the uphill edge of the plane (800 cells of 80 x 80 m at 0.1 m, 900 of 30 x 30 m at 0.1 m)."""
    n = int(round(side_m / cell))
    x = np.arange(n) * cell
    z = np.tile((slope * x).astype(np.float32), (n, 1))
    p = morph.resolve_morphological_params(z, cell)
    assert p["slope"] == pytest.approx(slope, abs=0.01)
    assert p["outline_slope"] == p["slope"] and np.isnan(p["terrain_slope_p90"])
    block = (n // 3) * cell
    assert f"of the {block:.3g} m (40 m scaled down to a third of the raster's shorter side" in p["slope_source"]
    res = morph.filter_morphological(z, cell)
    assert np.count_nonzero(res.mask) == 0


def test_small_raster_slope_is_not_read_from_blocks_off_a_plane():
    """A roof over most of an 80 m tile stands in most of its 3 x 3 blocks of 26 m: their minima lie
    metres from a plane, their median slope (0.47, the walls) is not the terrain's, and 0.3 is used."""
    z, _ = _tile_nearly_all_roof(1.0)
    p = morph.resolve_morphological_params(z, 1.0)
    assert p["slope"] == 0.3 and np.isnan(p["terrain_slope_p50"])
    assert "> dh from a plane" in p["slope_source"]


def test_slope_on_large_rasters_keeps_the_40_m_blocks():
    x = np.arange(130, dtype=np.float32)
    z = np.tile(0.2 * x, (130, 1))                        # 130 m at 1 m: 3 whole blocks of 40 m
    p = morph.resolve_morphological_params(z, 1.0, max_object_size_m=10.0)
    assert p["terrain_slope_p50"] == pytest.approx(0.2)
    assert "of the 40 m block-minimum surface" in p["slope_source"]
    assert morph.slope_block_cells(z.shape, 1.0, 40.0) == 40


def test_coarse_cells_take_pits_below_their_surroundings_not_gaps_between_crowns():
    """At 2 m cells a pit is a candidate of the pre-step when it lies 5 m (500 % of the paper's 1 m
    window) below its neighbours and below every cell of the ring around it; 4 m is not enough, and
    gaps between crowns at the level of the other gaps around stay out."""
    level = 2 * 0.5 + 0.3 * 2 * np.hypot(2.0, 2.0)     # as open_progressive: dh 0.5 m, outline slope 0.3

    def low(z):
        return morph.find_low_outliers(z, ~np.isfinite(z), (2.0, 2.0), morph.WINDOW_GROWTH,
                                       morph.LOW_OUTLIER_SLOPE, morph._Work(), level_m=level)[0]
    z = np.full((20, 20), 100.0, np.float32)
    z[10, 10] = 96.0
    assert not low(z).any()
    z[10, 10] = 94.9
    assert np.argwhere(low(z)).tolist() == [[10, 10]]
    crowns = np.full((30, 30), 103.0, np.float32)      # crowns' flanks 5 m high and tops 9 m
    crowns[::2, ::2] = 107.0                           # (their closing under the s x 2 m = 10 m of SMRF)
    crowns[1::4, 1::4] = 97.9                          # a gap every 8 m at the ground, 5.1 m below
    assert not low(crowns).any()
    crowns[crowns > 100.0] = 103.0                     # level crowns: the gaps are blunders
    assert low(crowns).sum() == (crowns < 100.0).sum()


@pytest.mark.parametrize("given", [False, True])
def test_a_line_of_blunders_on_a_terrace_at_2_m_cells_is_low(given):
    """ISPRS sample 41 at 2 m (lowest point per cell): blunders 9.5 m deep (under SMRF's one-cell
    threshold of 10 m) every two or three cells along a line on a level terrace beside a building
    hide each other from the ring around each; left in the opening they spread over the terrace,
    which became an object (9.85 % total error at 2 m against 2.99 % at 1 m). Below their level
    neighbours they are low outliers, and the terrace is ground."""
    z = np.full((40, 50), 301.0, np.float32)
    z[:24, :10] = 304.0                                  # a terrace 20 m wide on the raster's edge, 3 m up
    z[:30, 10:22] = 320.0                                # a building beside it
    pits = [(1, 7), (2, 7), (5, 7), (8, 6), (10, 5), (11, 5), (12, 5)]
    for r, c in pits:
        z[r, c] = 294.5
    p = dict(dh_m=0.5, slope=0.3, max_object_size_m=40.0, mode="progressive") if given else {}
    res = morph.filter_morphological(z, 2.0, **p)
    expect = np.zeros(z.shape, np.uint8)
    expect[:30, 10:22] = OBJECT
    for r, c in pits:
        expect[r, c] = LOW
    np.testing.assert_array_equal(res.mask, expect)


def test_blocks_equal_one_pass_with_deep_pits_at_2_m_cells():
    """The pits of coarse cells are judged on their ring (10 m) and level neighbours: the halo covers
    the ring, so blocks give the one-pass mask."""
    from bare_earth.core import synthetic
    sc = synthetic.make_scene("city", shape=(150, 170), cell_size=2.0, seed=3)
    z = np.array(sc.dsm, np.float32)
    rng = np.random.default_rng(3)
    r, c = rng.integers(0, 150, 60), rng.integers(0, 170, 60)
    z[r, c] -= 8.0                                     # blunders below the ground and the roofs
    z[r, np.minimum(c + 1, 169)] -= 8.0                # ... some in pairs
    one = run_array("morphological", z, 2.0)
    assert np.count_nonzero(one.mask == LOW) >= 60
    blk = run_array("morphological", z, 2.0, block=48)
    assert blk.info["blocks"] > 4
    np.testing.assert_array_equal(blk.mask, one.mask)


def test_nodata_cells_are_255_and_do_not_disturb():
    z, truth = _box_scene()
    z[0:3, 20:24] = np.nan
    truth[0:3, 20:24] = NODATA
    for mode in ("single", "progressive"):
        res = morph.filter_morphological(z, 1.0, mode=mode, max_object_size_m=9.0, dh_m=0.5, slope=0.3)
        np.testing.assert_array_equal(res.mask, truth)
        assert np.isnan(res.surface[1, 21])


@pytest.mark.parametrize("kwargs, match", [
    (dict(mode="fast"), "mode"),
    (dict(dh_m=-1.0), "dh_m"),
    (dict(max_object_size_m=0.05), "max_object_size_m"),
    (dict(slope=-0.1), "slope"),
    (dict(window_growth=0.5), "window_growth"),
])
def test_bad_parameters_raise_value_error(kwargs, match):
    z, _ = _box_scene()
    args = dict(mode="progressive", max_object_size_m=9.0, dh_m=0.5, slope=0.3)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        morph.filter_morphological(z, 1.0, **args)


# --------------------------------------------------------------------------- defaults
def test_resolve_derives_parameters_and_chooses_the_mode():
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:200, 0:200].astype(np.float32)
    flat = 100.0 + rng.normal(0, 0.05, (200, 200)).astype(np.float32)
    for r, c in ((20, 30), (100, 120), (150, 40)):
        flat[r:r + 15, c:c + 12] += 9.0
    p = morph.resolve_morphological_params(flat, 1.0)
    assert p["mode"] == "single" and "flat" in p["mode_reason"]
    assert p["dh_m"] == pytest.approx(0.5)                  # 3 x 0.05 m noise -> the 0.5 m floor
    assert p["noise_m"] == pytest.approx(0.05, rel=0.3)
    assert 12.0 <= p["max_object_size_m"] <= 25.0            # the 12-15 m wide buildings
    steep = flat + 0.4 * xx
    p = morph.resolve_morphological_params(steep, 1.0)
    assert p["mode"] == "progressive" and "not flat" in p["mode_reason"]
    assert p["slope"] == pytest.approx(0.4, abs=0.05)
    noisy = flat + rng.normal(0, 0.4, flat.shape).astype(np.float32)
    assert morph.resolve_morphological_params(noisy, 1.0)["dh_m"] == pytest.approx(1.2, rel=0.25)
    # user values are kept
    p = morph.resolve_morphological_params(steep, 1.0, mode="single", dh_m=2.0, slope=0.1,
                                       max_object_size_m=30.0)
    assert (p["mode"], p["dh_m"], p["slope"], p["max_object_size_m"]) == ("single", 2.0, 0.1, 30.0)


def test_auto_mode_is_progressive_when_no_object_is_found():
    """A dike on a flat floodplain (3 m high, 1:3 sides, 22 m at its base) and no object: the 40 m block
    minima do not show the dike, so the slope rule alone chose the single form with the default 40 m
    window, which cut the whole dike (bare.py levees at 1 m: 15.6 % of the ground lost). With no object
    found the single window would be a guess: auto uses the progressive form, which keeps the dike."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:160, 0:160].astype(np.float32)
    dike = np.clip(3.0 - np.maximum(np.abs(xx - 80.0) - 2.0, 0.0) / 3.0, 0.0, None)
    z = (100.0 + dike + rng.normal(0, 0.05, xx.shape)).astype(np.float32)
    p = morph.resolve_morphological_params(z, 1.0)
    assert p["max_object_size_source"].startswith("no object found")
    assert p["mode"] == "progressive" and "no object standing on walls found" in p["mode_reason"]
    run = {k: p[k] for k in ("mode", "max_object_size_m", "dh_m", "slope", "outline_slope", "wide_slope",
                             "wide_radius_m")}
    assert np.count_nonzero(morph.filter_morphological(z, 1.0, **run).mask != GROUND) == 0
    single = morph.filter_morphological(z, 1.0, **dict(run, mode="single")).mask
    assert np.all(single[dike > 0.5] == OBJECT)                  # what the single window would have done


def test_auto_mode_is_progressive_when_the_single_window_would_cut_more_terrain_than_objects():
    """A dike 4 m high (1:2 sides, 20 m at its base) across a flat floodplain beside three buildings on walls: the
    search finds the buildings, so the window is theirs (17 m) and the 40 m block minima, which do not show the
    dike, read flat terrain; the single window would cut the dike's crest and upper sides deeper than the
    search's 2 m (1779 cells of the ground the search kept, against 540 cells of objects found). Auto uses the
    progressive form: the dike stays ground and the buildings are found; the buildings alone keep the single
    form."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:200, 0:200].astype(np.float32)
    dike = np.clip(4.0 - np.maximum(np.abs(xx - 100.0) - 2.0, 0.0) / 2.0, 0.0, None)
    flat = (100.0 + rng.normal(0, 0.05, xx.shape)).astype(np.float32)
    truth = np.zeros(flat.shape, bool)
    for r, c in ((20, 30), (100, 150), (150, 40)):
        flat[r:r + 15, c:c + 12] += 9.0
        truth[r:r + 15, c:c + 12] = True
    p = morph.resolve_morphological_params(flat, 1.0)
    assert p["mode"] == "single" and "terrain flat" in p["mode_reason"]
    z = (flat + dike).astype(np.float32)
    p = morph.resolve_morphological_params(z, 1.0)
    assert p["mode"] == "progressive" and "more than the" in p["mode_reason"]
    assert 12.0 <= p["max_object_size_m"] <= 25.0                # the buildings' window, not a guess
    run = {k: p[k] for k in ("mode", "max_object_size_m", "dh_m", "slope", "outline_slope", "wide_slope",
                             "wide_radius_m", "noise_m")}
    mask = morph.filter_morphological(z, 1.0, **run).mask
    assert np.all(mask[truth] == OBJECT)
    assert np.count_nonzero(mask[dike > 0.5] != GROUND) < 0.05 * np.count_nonzero(dike > 0.5)
    single = morph.filter_morphological(z, 1.0, **dict(run, mode="single")).mask
    assert np.count_nonzero(single[dike > 0.5] != GROUND) > 0.8 * np.count_nonzero(dike > 0.5)


def test_single_window_cuts_counts_the_cells_cut_deeper_than_a_depth():
    """A dike 4 m high, crest 5 m, sides 1:1: a 20 m opening cuts 7 cells of each row deeper than 2 m (3, 4, 4, 4,
    4, 4, 3 m), an 11 m one 5 (3 m), a 9 m one none (2 m is not deeper); only the cells given count; nodata is
    never cut."""
    j = np.tile(np.arange(48, dtype=np.float32), (8, 1))
    z = np.clip(4.0 - np.maximum(np.abs(j - 24.0) - 2.0, 0.0), 0.0, None).astype(np.float32)
    every = np.ones(z.shape, bool)
    assert [morph.single_window_cuts(z, 1.0, w, every, 2.0) for w in (20.0, 11.0, 9.0)] == [56, 40, 0]
    assert morph.single_window_cuts(z, 1.0, 20.0, j < 24, 2.0) == 24
    assert morph.single_window_cuts(z, 1.0, 20.0, every, 3.5) == 40
    z[:, 24] = np.nan
    assert morph.single_window_cuts(z, 1.0, 20.0, every, 2.0) == 48


def test_objects_on_walls_keeps_regions_on_walls_only():
    """A region whose edge stands on walls is kept; one falling to the ground at the terrain's slope is not;
    one with no edge on the ground (filling the raster) is kept."""
    z = np.zeros((9, 20), np.float32)
    z[3:6, 2:5] = 5.0                                        # a block on walls
    z[2:7, 11:18] = 0.4                                      # a terrace 0.4 m high: its edge rises 0.4 m
    z[3:6, 12:17] = 0.8
    z[4, 13:16] = 1.2
    flagged = z > 0.0
    kept = morph.objects_on_walls(z, flagged, ~flagged, (1.0, 1.0), 0.5, 0.0)
    np.testing.assert_array_equal(kept, flagged & (z == 5.0))
    thin = np.zeros_like(flagged)
    thin[7, 2:10] = True                                         # one cell wide: too thin to judge, kept
    kept = morph.objects_on_walls(z, flagged | thin, ~(flagged | thin), (1.0, 1.0), 0.5, 0.0)
    np.testing.assert_array_equal(kept, thin | (z == 5.0))
    kept = morph.objects_on_walls(z, flagged | thin, ~(flagged | thin), (1.0, 1.0), 0.5, 0.0, keep_thin=False)
    np.testing.assert_array_equal(kept, z == 5.0)
    every = np.ones((4, 4), bool)
    assert morph.objects_on_walls(z[:4, :4], every, ~every, (1.0, 1.0), 0.5, 0.0).all()


def test_object_size_leaves_out_terrain_the_search_cut(monkeypatch):
    """A crest with 0.8 sides across the raster, steeper than the search's slope 0.3: the search flags it
    (52 m wide) when its steps read no slope on their reference's erosion (the reference's slopes now keep this
    crest: then only the building is flagged), but it falls to the ground at the terrain's slope; the object size
    is the building's (12 m: 17 m with the margin), as on the fBm mountain of bare.py (59-80 m windows from cut
    crests -> 40 m: 0.5 / 1 / 2 m 0.93 / 1.69 / 6.50 -> 0.60 / 0.94 / 2.21 % of the ground lost)."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:200, 0:200].astype(np.float32)
    z = (100.0 + np.maximum(0.0, 25.0 - 0.8 * np.abs(xx - 60)) + rng.normal(0, 0.05, xx.shape)).astype(np.float32)
    z[90:102, 150:162] += 8.0
    walled, every, walls = morph.estimate_object_size(z, 1.0, 0.3, 0.5, outline_slope=0.3, details=True)
    assert walled == pytest.approx(1.25 * 12 + 2, abs=1.5) and every == walled
    monkeypatch.setattr(morph, "reference_slope", lambda *a, **k: None)
    walled, every, walls = morph.estimate_object_size(z, 1.0, 0.3, 0.5, outline_slope=0.3, details=True)
    assert walled == pytest.approx(1.25 * 12 + 2, abs=1.5) and every > 40.0 and walls
    assert morph.estimate_object_size(z, 1.0, 0.3, 0.5, outline_slope=0.3) == walled
    assert morph.estimate_object_size(z, 1.0, 0.3, 0.5, outline_slope=0.3, on_walls=False) == every
    z[90:102, 150:162] -= 8.0                                    # the crest alone: no object on walls
    walled, every, walls = morph.estimate_object_size(z, 1.0, 0.3, 0.5, outline_slope=0.3, details=True)
    assert np.isnan(walled) and every > 40.0 and not walls
    p = morph.resolve_morphological_params(z, 1.0, slope=0.3)
    assert p["mode"] == "progressive" and "no object standing on walls" in p["mode_reason"]
    assert p["max_object_size_m"] == 40.0                        # the default, smaller than the crest's width


def test_halo_covers_the_reach():
    assert morph.morphological_halo({"max_object_size_m": 41.0}, 1.0) >= 2 * 20 + 2
    assert morph.morphological_halo({"max_object_size_m": 41.0}, 0.5) >= 2 * 40 + 4


def test_registered_method_runs_through_the_pipeline():
    meth = get_method("morphological")
    names = [p.name for p in meth.params]
    assert names[:3] == ["mode", "max_object_size_m", "dh_m"]
    z, truth = _box_scene()
    res = run_array("morphological", z, 1.0, params=dict(max_object_size_m=9.0))
    np.testing.assert_array_equal(res.mask, truth)
    assert res.info["mode"] in ("single", "progressive") and res.info["mode_reason"]
    np.testing.assert_allclose(res.dtm, 10.0, atol=1e-4)


# --------------------------------------------------------------------------- synthetic truth
@pytest.mark.parametrize("kind, max_total", [("city", 2.0), ("forest", 3.0), ("rolling", 0.5)])
def test_defaults_on_synthetic_scenes(kind, max_total):
    synthetic = pytest.importorskip("bare_earth.core.synthetic")
    sc = synthetic.make_scene(kind, (160, 160), 1.0, seed=2)
    res = run_array("morphological", sc.dsm, 1.0)
    valid = sc.mask != NODATA
    truth_ground = sc.mask[valid] == 0
    pred_ground = res.mask[valid] == 0
    total = 100.0 * np.mean(truth_ground != pred_ground)
    assert total < max_total, (kind, total, res.info["params"])
    assert res.info["mode"] == "progressive"
    # the filled DTM follows the true terrain
    assert np.nanmedian(np.abs(res.dtm - sc.dtm)[valid]) < 0.1


def test_core_enforces_the_param_limits():
    """The dialog's bounds (PARAMS) are the core's: just outside fails, the bounds pass."""
    z, _ = _box_scene()
    args = dict(mode="progressive", max_object_size_m=9.0, dh_m=0.5, slope=0.3)
    spec = {p.name: p for p in morph.PARAMS}
    for name in ("dh_m", "slope", "slope_scale_m", "window_growth", "low_outlier_slope"):
        lo, hi = spec[name].minimum, spec[name].maximum
        for bad in (lo - 0.01, hi + 1.0):
            with pytest.raises(ValueError, match=rf"{name} = .* is out of range \["):
                morph.filter_morphological(z, 1.0, **dict(args, **{name: bad}))
        morph.filter_morphological(z, 1.0, **dict(args, **{name: lo if name != "window_growth" else hi}))
    with pytest.raises(ValueError, match="max_object_size_m = .* is out of range"):
        morph.resolve_morphological_params(z, 1.0, max_object_size_m=20000.0)


# --------------------------------------------------------------------------- outlines (issue 12)
def _rimmed_roofs(cell=2.0, seed=0):
    """Gentle ground (slope 0.05, noise 0.05 m) with four roofs 6 m high, each ringed by one
    cell at half height: the mixed cells of a top-surface DSM on the roofs' outlines.
    Returns (dsm, ground, truth mask, rim mask)."""
    rng = np.random.default_rng(seed)
    ground = (20.0 + 0.05 * cell * np.arange(90, dtype=np.float32)[None, :]
              + np.zeros((90, 1), np.float32))
    z = (ground + rng.normal(0, 0.05, (90, 90))).astype(np.float32)
    truth = np.zeros(z.shape, np.uint8)
    rim = np.zeros(z.shape, bool)
    for r, c, h, w in ((10, 10, 8, 12), (15, 50, 12, 10), (55, 15, 10, 10), (55, 55, 11, 11)):
        z[r - 1:r + h + 1, c - 1:c + w + 1] += 3.0
        rim[r - 1:r + h + 1, c - 1:c + w + 1] = True
        z[r:r + h, c:c + w] += 3.0
        rim[r:r + h, c:c + w] = False
        truth[r - 1:r + h + 1, c - 1:c + w + 1] = OBJECT
    return z, ground, truth, rim


def test_outline_cells_exact():
    """A one-cell ring at half height around a flagged roof is outline; ground beside the
    roof, ground on a slope beside it and the roof itself are not."""
    z = np.full((9, 9), 10.0, np.float32)
    z[3:6, 3:6] = 16.0                        # roof (flagged)
    z[2, 2:7] = 13.0                           # rim row above it, half height
    flagged = np.zeros(z.shape, bool)
    flagged[3:6, 3:6] = True
    opened = np.full(z.shape, 10.0, np.float32)
    out = morph.find_outline_cells(z, opened, flagged, (1.0, 1.0), 0.5, 0.0)
    expect = np.zeros(z.shape, bool)
    expect[2, 2:7] = True
    np.testing.assert_array_equal(out, expect)
    # the same roof on a ramp of slope 0.5 (rise 0.71 m over a cell diagonal): the ground
    # cells around it stand 0.5-1 m above their lowest neighbour, under dh + the rise
    ramp = 0.5 * np.arange(9, dtype=np.float32)[None, :] + np.zeros((9, 1), np.float32)
    out = morph.find_outline_cells(ramp + np.where(flagged, 6.0, 0.0).astype(np.float32), ramp, flagged,
                                   (1.0, 1.0), 0.5, 0.0)
    assert not out.any()
    # nodata among the neighbours is ignored; a flagged cell is never outline
    z2 = z.copy()
    z2[1, 1] = np.nan
    out = morph.find_outline_cells(z2, opened, flagged | np.isnan(z2), (1.0, 1.0), 0.5, 0.0)
    np.testing.assert_array_equal(out, expect)


def test_outline_slope_keeps_ground_beside_a_tree_on_a_cut_crest():
    """A tree on a crest (sides 0.6) whose top the largest window cut (the opened surface
    flat): the eight crest cells around the tree stand 0.6 m above their lowest neighbour; with
    outline_slope 0.6 (rise 0.5 + 0.6 sqrt 2 = 1.35 m over a diagonal) they stay ground, and
    without it too, since the crest goes on descending 0.6 m a cell beyond their foot (a slope
    continuing, no wall: continuing_rise); a cell as high as the tree's half-height (3 m) is
    outline either way."""
    j = np.arange(9, dtype=np.float32)
    crest = np.tile(10.0 - 0.6 * np.abs(j - 4.0), (9, 1)).astype(np.float32)
    flagged = np.zeros(crest.shape, bool)
    flagged[4, 4] = True
    z = crest + np.where(flagged, 6.0, 0.0).astype(np.float32)
    opened = np.full(z.shape, 8.0, np.float32)
    assert not morph.find_outline_cells(z, opened, flagged, (1.0, 1.0), 0.5, 0.0).any()
    assert not morph.find_outline_cells(z, opened, flagged, (1.0, 1.0), 0.5, 0.6).any()
    z[3, 4] += 3.0                                          # a mixed cell: half the tree's height
    for outline_slope in (0.0, 0.6):
        out = morph.find_outline_cells(z, opened, flagged, (1.0, 1.0), 0.5, outline_slope)
        np.testing.assert_array_equal(np.argwhere(out), [[3, 4]])


def test_outline_slope_is_derived_and_logged():
    z, _, _, _ = _rimmed_roofs()
    p = morph.resolve_morphological_params(z, 2.0)
    assert p["outline_slope"] == pytest.approx(p["terrain_slope_p90"])
    assert p["outline_slope"] == pytest.approx(0.05, abs=0.02)          # the ground's slope
    assert "90th-percentile" in p["outline_slope_source"]
    small = morph.resolve_morphological_params(z[:4, :4], 2.0)         # under 3 x 3 blocks of 2 cells
    assert small["outline_slope"] == small["slope"] and "3 x 3 blocks" in small["outline_slope_source"]
    assert morph.resolve_morphological_params(z, 2.0, outline_slope=0.2)["outline_slope"] == 0.2
    res = run_array("morphological", z, 2.0)
    assert res.info["outline_slope"] == pytest.approx(p["outline_slope"])
    assert res.info["outline_slope_source"] == p["outline_slope_source"]


def test_half_height_outlines_are_objects_with_derived_defaults():
    """The opengeos failure on a small surface: a 2 m top-surface DSM whose roofs carry a
    one-cell ring of mixed cells. SMRF's flags miss the ring (it drops by 3 m < s r_k when
    the window outgrows the roof) and it passed as ground, lifting the DTM around every roof;
    as outline cells it is classified against the ground under the roof."""
    z, ground, truth, rim = _rimmed_roofs()
    res = run_array("morphological", z, 2.0)
    assert res.info["mode"] == "progressive", res.info["mode_reason"]
    assert np.all(res.mask[rim] == OBJECT)
    assert np.mean(res.mask[truth == 0] == 0) > 0.99
    assert np.abs(res.dtm - ground).max() < 0.5
    assert res.info["outline_percent"] > 0


def test_ground_beside_trees_on_a_slope_stays_ground():
    """Outline cells are those on an object's flank, not the ground beside it: single-cell
    trees on a 0.2 slope at 4 m cells leave the ground around them ground."""
    rng = np.random.default_rng(1)
    n = 64
    z = (0.2 * 4.0 * np.arange(n, dtype=np.float32)[None, :] + np.zeros((n, 1), np.float32)
         + rng.normal(0, 0.05, (n, n)).astype(np.float32))
    trees = np.zeros(z.shape, bool)
    trees[4::8, 4::8] = True
    z[trees] += 8.0
    res = morph.filter_morphological(z, 4.0, mode="progressive", max_object_size_m=20.0, dh_m=0.5, slope=0.3)
    np.testing.assert_array_equal(res.mask == OBJECT, trees)


def test_missing_scan_lines_do_not_shrink_the_window():
    """A 30 m roof crossed by missing scan lines (NaN every 7th row): the object size is
    measured across the gaps, so the opening removes the roof (it stood in the DTM when
    the lines cut it into 6 m strips and the window was sized 10 m)."""
    y, x = np.mgrid[0:120, 0:120]
    z = (100.0 + 0.02 * x).astype(np.float32)
    roof = (abs(y - 60) < 15) & (abs(x - 60) < 15)
    z[roof] += 10.0
    z[::7] = np.nan
    p = morph.resolve_morphological_params(z, (1.0, 1.0))
    assert p["max_object_size_m"] >= 30.0
    r = run_array("morphological", z, 1.0)
    valid = np.isfinite(z)
    assert np.all(r.mask[roof & valid] == OBJECT)
    assert np.nanmax(r.dtm) < 103.0


def test_low_blunders_on_a_roof_do_not_shrink_the_window():
    """Single-cell pits on a 40 m roof (low blunders, class 2) are holes in the object, not
    its outline: the object size is measured across them (at 0.25 m cells a city's roofs
    read narrower than they are, the largest stood in the DTM: 21.6 % of the objects
    kept as ground)."""
    y, x = np.mgrid[0:240, 0:240]
    z = (100.0 + 0.01 * x).astype(np.float32)
    roof = (abs(y - 120) < 80) & (abs(x - 120) < 80)            # 40 m at 0.25 m cells
    z[roof] += 20.0
    pits = roof & (y % 23 == 5) & (x % 29 == 7)
    z[pits] -= 35.0                                              # 15 m below the ground
    p = morph.resolve_morphological_params(z, (0.25, 0.25))
    assert p["max_object_size_m"] >= 40.0
    r = run_array("morphological", z, 0.25)
    assert np.all(r.mask[roof & ~pits] == OBJECT)


def test_a_checkerboard_of_dropouts_keeps_the_roofs_out():
    """Every other cell of a city missing (a checkerboard): a roof's cells touch only at
    corners, yet each roof is one object and the window fits the widest (20.8 % of the
    object cells stayed ground when every cell counted as its own object)."""
    from bare_earth.core.synthetic import make_scene
    s = make_scene("city", (256, 256), seed=5)
    z = s.dsm.copy()
    y, x = np.mgrid[0:256, 0:256]
    z[(y + x) % 2 == 0] = np.nan
    r = run_array("morphological", z, 1.0)
    obj = (s.mask == OBJECT) & np.isfinite(z)
    assert np.count_nonzero(obj & (r.mask == 0)) / np.count_nonzero(obj) < 0.01


# --------------------------------------------------------------------------- attached tiers (issue 12)
def _annexed_building():
    """Flat ground at 0 (80 x 80, 1 m cells) with a building: a 12 x 12 block 10 m high and, attached
    to it, a 12 x 10 annex 2 m high. Returns (dsm, truth mask)."""
    z = np.zeros((80, 80), np.float32)
    z[30:42, 30:42] = 10.0
    z[30:42, 42:52] = 2.0
    truth = np.zeros(z.shape, np.uint8)
    truth[30:42, 30:52] = OBJECT
    return z, truth


def test_annex_of_a_building_is_an_object():
    """SMRF's flags miss a low annex of a wide building: when the window outgrows the building
    (radius 8, 17 cells > 12) the annex drops by its 2 m, under s r_k = 0.3 x 8 = 2.4 m, and
    SMRF keeps it in ZIpro at its own height (ground). It is attached to the flagged block and
    walls bound it (2 m above the ground beside it, over dh + 0.3 sqrt 2): a tier, an object."""
    z, truth = _annexed_building()
    params = dict(mode="progressive", max_object_size_m=30.0, dh_m=0.5, slope=0.3, outline_slope=0.3,
                  window_growth=morph.WINDOW_GROWTH)
    res = morph.filter_morphological(z, 1.0, **params)
    np.testing.assert_array_equal(res.mask, truth)
    assert res.info["attached_tier_percent"] > 100.0 * 100 / z.size      # most of the annex's 120 cells
    # the tier rule alone: the annex's cells, nothing else
    obj = np.zeros(z.shape, bool)
    obj[30:42, 30:42] = True
    tiers = morph.find_attached_tiers(z, np.zeros_like(z), obj, obj, (1.0, 1.0), 0.5, 1.25, 0.3, (15, 15))
    np.testing.assert_array_equal(tiers, truth.astype(bool) & ~obj)
    # not attached to an object, wider than the largest window, or bounded by no wall: not a tier
    assert not morph.find_attached_tiers(z, np.zeros_like(z), obj, np.zeros_like(obj), (1.0, 1.0), 0.5, 1.25,
                                         0.3, (15, 15)).any()
    assert not morph.find_attached_tiers(z, np.zeros_like(z), obj, obj, (1.0, 1.0), 0.5, 1.25, 0.3, (3, 3)).any()
    assert not morph.find_attached_tiers(z, np.zeros_like(z), obj, obj, (1.0, 1.0), 0.5, 1.25, 2.0, (15, 15)).any()


def test_annex_is_ground_without_the_tier_rule(monkeypatch):
    """The failure the rule fixes: SMRF's steps alone keep the annex as ground."""
    z, truth = _annexed_building()
    monkeypatch.setattr(morph, "find_attached_tiers", lambda clean, *a, **k: np.zeros(clean.shape, bool))
    res = morph.filter_morphological(z, 1.0, mode="progressive", max_object_size_m=30.0, dh_m=0.5, slope=0.3,
                                     outline_slope=0.3)
    assert (res.mask[30:42, 43:52] == 0).all()


def test_hill_top_beside_a_tree_is_not_a_tier(monkeypatch):
    """A tree on a round hill top (4 m high, slopes up to 0.4) that the largest window cut: the top,
    about 20 m across, stands above the opened surface by more than dh and touches the tree, but
    it falls to the ground around at the terrain's slope, with no wall: it stays ground (without
    the wall test its 400 cells would be removed)."""
    i, j = np.mgrid[0:81, 0:81].astype(np.float32)
    z = (4.0 * np.exp(-((i - 40) ** 2 + (j - 40) ** 2) / (2 * 6.0 ** 2))).astype(np.float32)
    z[39:42, 39:42] += 8.0                                    # the tree
    tree = np.zeros(z.shape, bool)
    tree[39:42, 39:42] = True
    params = dict(mode="progressive", max_object_size_m=30.0, dh_m=0.5, slope=0.5, outline_slope=0.4)
    res = morph.filter_morphological(z, 1.0, **params)
    assert res.info["attached_tier_percent"] == 0.0
    np.testing.assert_array_equal(res.mask == OBJECT, tree)
    monkeypatch.setattr(morph, "TIER_WALL_SHARE", -1.0)      # any attached region narrower than the window
    assert (morph.filter_morphological(z, 1.0, **params).mask == OBJECT).sum() > 300


def test_lower_roof_enclosed_by_the_object_is_a_tier():
    """A lower roof that the flagged roofs enclose on every side (a courtyard roofed at 2 m inside a
    ring of roofs 10 m high; on ISPRS sample 31, annexes 3 m high between a hall and its outline
    cells): it drops by its 2 m when the window outgrows the building, under s r_k = 0.3 x 12 = 3.6 m,
    so SMRF keeps it as ground. It touches no ground cell: no edge to judge by walls, nothing shows it
    falling to the ground at the terrain's slope, it stands on the object. A tier (it stayed ground,
    324 cells, while a tier needed walls on most of an edge it does not have)."""
    z = np.zeros((70, 70), np.float32)
    z[20:50, 20:50] = 10.0
    z[26:44, 26:44] = 2.0
    truth = np.zeros(z.shape, np.uint8)
    truth[20:50, 20:50] = OBJECT
    params = dict(mode="progressive", max_object_size_m=40.0, dh_m=0.5, slope=0.3, outline_slope=0.3)
    res = morph.filter_morphological(z, 1.0, **params)
    np.testing.assert_array_equal(res.mask, truth)
    obj = z == 10.0
    tiers = morph.find_attached_tiers(z, np.zeros_like(z), obj, obj, (1.0, 1.0), 0.5, 1.25, 0.3, (20, 20))
    np.testing.assert_array_equal(tiers, z == 2.0)
    # not attached to an object, or wider than the box: still not a tier
    assert not morph.find_attached_tiers(z, np.zeros_like(z), obj, np.zeros_like(obj), (1.0, 1.0), 0.5, 1.25,
                                         0.3, (20, 20)).any()
    assert not morph.find_attached_tiers(z, np.zeros_like(z), obj, obj, (1.0, 1.0), 0.5, 1.25, 0.3, (5, 5)).any()
    # touching a low outlier or a nodata cell (hidden: what lies there is unknown), it is not enclosed
    hidden = np.zeros(z.shape, bool)
    hidden[25, 30] = True
    left = obj | hidden
    assert not morph.find_attached_tiers(z, np.zeros_like(z), left, obj & ~hidden, (1.0, 1.0), 0.5, 1.25, 0.3,
                                         (20, 20), hidden=hidden).any()
    np.testing.assert_array_equal(morph.find_attached_tiers(z, np.zeros_like(z), left, obj & ~hidden, (1.0, 1.0),
                                                            0.5, 1.25, 0.3, (20, 20)), z == 2.0)


def test_tier_on_the_raster_border_needs_walls_on_most_of_its_known_edge():
    """A raised strip along the raster's border, attached to a flagged block: its cells on the border
    are edge cells whose outline is unknown, never walls, so with walls on the ground side only
    (under half its edge) it is not a tier; the same strip one cell inside the border is one."""
    z = np.zeros((60, 60), np.float32)
    obj = np.zeros(z.shape, bool)
    obj[25:35, 50:58] = True
    z[obj] = 10.0
    z[10:50, 58:60] = 2.0                       # a 2 m strip two cells wide on the right border
    z[obj] = 10.0
    args = ((1.0, 1.0), 0.5, 1.25, 0.3, (15, 15))
    opened = np.zeros_like(z)
    assert not morph.find_attached_tiers(z, opened, obj, obj, *args).any()
    inner = np.zeros((60, 61), np.float32)      # one more column of ground: the strip's right side is a wall
    inner[:, :60] = z
    obj2 = np.zeros(inner.shape, bool)
    obj2[:, :60] = obj
    tiers = morph.find_attached_tiers(inner, np.zeros_like(inner), obj2, obj2, *args)
    np.testing.assert_array_equal(tiers, (inner == 2.0))


def test_tier_box_holds_a_window_wide_square_in_any_orientation():
    """A square as wide as the largest window (2 r + 1 cells) turned by 45 degrees spans sqrt 2 times
    that along rows and columns: it fits the tier's box, and the halo covers the box."""
    assert morph._tier_box((10, 10)) == (30, 30)                 # ceil(1.414 x 21)
    assert morph._tier_box((3, 5)) == (10, 16)
    p = {"max_object_size_m": 21.0}
    assert morph.morphological_halo(p, 1.0) >= 2 * 10 + 30


def test_surface_slope_rows_equal_np_gradient():
    """The slope of the final test, computed a band of rows at a time, is bit for bit the
    magnitude of ``np.gradient`` (central differences, one-sided at the edges; NaN -> 0) of
    the whole surface, for float32, float64 and int16 surfaces, any cell size and any band."""
    from bare_earth.core.morphology import _surface_slope
    rng = np.random.default_rng(3)
    for t in range(600):
        H, W = rng.integers(2, 9, 2)
        dt = (np.float32, np.float64, np.int16)[t % 3]
        s = (rng.standard_normal((H, W)) * 10).astype(dt)
        if dt != np.int16:
            s[rng.random(s.shape) < 0.2] = np.nan
        cell = (float(rng.choice([0.5, 1.0, 0.3])), float(rng.choice([0.5, 1.0, 2.0])))
        with np.errstate(invalid="ignore"):
            gy, gx = np.gradient(s, cell[1], cell[0])
            ref = np.hypot(gx, gy)
        ref[~np.isfinite(ref)] = 0.0
        ref = ref.astype(np.float32)
        a = int(rng.integers(0, H + 1))
        b = int(rng.integers(a, H + 1))
        with np.errstate(invalid="ignore"):
            assert np.array_equal(_surface_slope(s, cell), ref)
            assert np.array_equal(_surface_slope(s, cell, slice(a, b)), ref[a:b])


# --------------------------------------------------------------------------- roofs wider than the search
def _tile_nearly_all_roof(cell):
    """As lidar/sample_c: a roof 25 m high over ~90 % of an 80 m tile, cut by the tile's edges on
    every side but one wall along a diagonal, a ground wedge in the corner beyond it."""
    from surfaces import grid, noisy
    n = int(80 / cell)
    y, x = grid(n)
    x, y = x * cell, y * cell
    ground = 30 + 0.01 * x
    d = (x + y) / np.sqrt(2)
    roof = (x > 20) & (y > 15)                  # walls on two sides, the tile's edges on the other two
    z = noisy(np.where(roof, 55 + np.where(d < 40, 0.0, 2.0 - 0.05 * np.abs(d - 60)), ground), sd=0.05)
    return z, roof


@pytest.mark.parametrize("cell", [0.5, 1.0, 2.0])
def test_a_tile_nearly_all_roof_widens_the_window_and_is_an_object(cell):
    z, roof = _tile_nearly_all_roof(cell)
    p = morph.resolve_morphological_params(z, cell)
    # the roof mirrored at the tile's edges is wider than the search's 100 m windows
    assert morph._OBJECT_SEARCH_M < p["max_object_size_m"] <= morph.RAISED_REGION_MAX_M
    assert "widened" in p["max_object_size_source"]
    res = run_array("morphological", z, cell, {})
    assert (res.mask[roof] == OBJECT).mean() > 0.99
    assert (res.mask[~roof] == 0).mean() > 0.99


@pytest.mark.parametrize("cell", [0.5, 1.0, 2.0, 4.0])
def test_a_roof_whose_wall_ends_in_a_corner_is_an_object_at_every_cell_size(cell):
    """As lidar/sample_c (0.26 / 88.13 / 88.13 % at 0.5 / 2 / 4 m): a roof over 73 % of an 88 x 76 m tile,
    its one wall ending next to a corner, widens the window at every cell size and is an object; the
    terrace of the same shape joined to the ground by a bank stays ground."""
    from surfaces import level_off_a_corner
    z, roof = level_off_a_corner(cell)
    p = morph.resolve_morphological_params(z, cell)
    assert "widened" in p["max_object_size_source"]
    res = run_array("morphological", z, cell, {})
    assert (res.mask[roof] == OBJECT).all()
    assert (res.mask[~roof] == 0).mean() > 0.98
    z, _ = level_off_a_corner(cell, "terrace")
    assert (run_array("morphological", z, cell, {}).mask == 0).mean() > 0.995


@pytest.mark.parametrize("kind", ["terrace", "plateau", "hilltop", "steep plateau"])
def test_wide_raised_ground_does_not_widen_the_window(kind):
    from surfaces import noisy, raised_ground
    z = noisy(raised_ground(kind), sd=0.05)
    p = morph.resolve_morphological_params(z, 1.0)
    assert "widened" not in p["max_object_size_source"]
    assert p["max_object_size_m"] <= morph._MAX_OBJECT_M


def test_tier_walls_read_at_the_edge_cells_equal_a_grey_erosion_of_the_ground():
    """find_attached_tiers' walls: an edge cell more than ``rise`` above the lowest ground cell of its
    3 x 3 neighbourhood (cells beyond the raster ignored), read at the edge cells only; the same cells as
    with ndimage's grey erosion of the ground's heights (+inf elsewhere) over the raster."""
    from scipy import ndimage

    from bare_earth.core.morphology import _walls
    rng = np.random.default_rng(3)
    clean = (rng.random((41, 37)) * 4).astype(np.float32)
    ground = rng.random(clean.shape) > 0.5
    edge = ~ground & (rng.random(clean.shape) > 0.3)
    edge[0, :] = edge[:, -1] = True                       # the raster's border too
    lowest = ndimage.grey_erosion(np.where(ground, clean, np.float32(np.inf)), size=3, mode="nearest")
    want = edge & (clean - lowest > np.float32(0.7))
    got = _walls(clean, ground, edge, np.float32(0.7))
    assert np.array_equal(got, want) and 0 < np.count_nonzero(got) < np.count_nonzero(edge)


# --------------------------------------------------------------------------- cut terrain (issue 12)
def _knoll_and_building():
    """Flat ground at 0 (61 x 101, 1 m cells) with a round knoll 6 m high (Gaussian, sigma 5 m: slopes
    up to 0.73) and a 10 x 10 building 8 m high on walls. Returns the DSM, the building's cells and the
    parameters: SMRF's slope 0.3 (the floor), the outline slope 0.8 (the knoll's steepest)."""
    i, j = np.mgrid[0:61, 0:101].astype(np.float32)
    z = (6.0 * np.exp(-((i - 30) ** 2 + (j - 30) ** 2) / (2 * 5.0 ** 2))).astype(np.float32)
    building = np.zeros(z.shape, bool)
    building[25:35, 70:80] = True
    z[building] = 8.0
    params = dict(mode="progressive", max_object_size_m=30.0, dh_m=0.5, slope=0.3, outline_slope=0.8)
    return z, building, params


def test_knoll_steeper_than_the_slope_threshold_is_ground():
    """A knoll steeper than SMRF's slope s: the opening cuts its top by more than s r_k and flags it
    (109 cells without the rule), but the flagged top falls to the ground around at the terrain's slope,
    with no wall: terrain, ground. The building beside it stands on walls and stays an object."""
    z, building, params = _knoll_and_building()
    res = morph.filter_morphological(z, 1.0, **params)
    np.testing.assert_array_equal(res.mask == OBJECT, building)
    assert res.info["cut_terrain_percent"] > 100.0 * 100 / z.size


def test_knoll_is_an_object_without_the_cut_terrain_rule(monkeypatch):
    """The failure the rule fixes: SMRF's flags alone take the knoll's top for an object (find_cut_slopes, the
    rule for terrain longer than the box, gives it back too: both off)."""
    z, building, params = _knoll_and_building()
    monkeypatch.setattr(morph, "find_cut_terrain", lambda clean, flagged, *a, **k: np.zeros(flagged.shape, bool))
    monkeypatch.setattr(morph, "find_cut_slopes", lambda clean, flagged, *a, **k: np.zeros(flagged.shape, bool))
    res = morph.filter_morphological(z, 1.0, **params)
    assert np.count_nonzero((res.mask == OBJECT) & ~building) > 100


def test_cut_terrain_needs_no_wall_an_inside_no_border_and_the_box():
    """The rule on exact arrays: a flat-topped mound with 0.5 slopes (flags on its top) is cut terrain;
    the same mound with one wall cell on its edge, a region one cell wide (every cell on its edge), a
    region touching the raster's border, or one wider than the box of the largest window is not."""
    i, j = np.mgrid[0:31, 0:31].astype(np.float32)
    z = np.clip(5.0 - 0.5 * np.maximum(np.abs(i - 15), np.abs(j - 15)), 0.0, 3.0).astype(np.float32)
    flags = z > 2.0                                     # the 9 x 9 top and the ring below it
    args = ((1.0, 1.0), 0.5, 0.5, (10, 10))
    cut = morph.find_cut_terrain(z, flags, ~flags, *args)
    np.testing.assert_array_equal(cut, flags)
    walled = z.copy()
    walled[15, 10] = 6.0                                # one edge cell 3.5 m above the ground beside it
    assert not morph.find_cut_terrain(walled, flags | (walled > 2.0), ~(flags | (walled > 2.0)), *args).any()
    line = np.zeros_like(flags)
    line[15, 5:25] = True                               # one cell wide: no cell inside its edge
    assert not morph.find_cut_terrain(np.where(line, 1.0, 0.0).astype(np.float32), line, ~line, *args).any()
    shifted = np.zeros_like(flags)
    shifted[:9, 11:20] = True                           # on the border
    zs = np.where(shifted, 2.5, 2.0).astype(np.float32)
    assert not morph.find_cut_terrain(zs, shifted, ~shifted, *args).any()
    assert morph.find_cut_terrain(z, flags, ~flags, (1.0, 1.0), 0.5, 0.5, (3, 3)).sum() == 0   # box 10 < 11


def test_halo_covers_the_cut_terrain_and_the_tiers():
    """The cut terrain's region (up to the tier box) and then the tiers' (another box) both lie within
    the halo, beyond the two half-windows of the opening."""
    p = {"max_object_size_m": 21.0}
    assert morph.morphological_halo(p, 1.0) >= 2 * 10 + 2 * (30 + 3)


# --------------------------------------------------------------------------- the final test's low cells (issue 12)
def test_gaps_between_crowns_are_ground_not_low_outliers(monkeypatch):
    """Under a closed canopy (simulated, 96 m at 1 m cells) the largest window finds little ground,
    ZIpro is the opened canopy, and SMRF's final test puts the gaps between the crowns (the ground
    seen) below it: 150 of the 1464 ground cells class 2 without the rule. A gap lies at the level of
    the other gaps within 10 m, not below all of them: ground (46 left, deeper than the pre-step's
    5 m below ZIpro or below the ground seen around them)."""
    from bare_earth.core.synthetic import make_canopy
    s = make_canopy(96.0, 1.0, seed=0, noise_m=0.05)
    ground = s.mask == 0
    res = morph.filter_morphological(s.dsm, s.cell_size)
    with_rule = np.count_nonzero((res.mask == LOW) & ground)
    assert res.info["low_cells_ground_percent"] > 0.5
    monkeypatch.setattr(morph, "confirm_low_cells", lambda z, low, *a, **k: low)
    res = morph.filter_morphological(s.dsm, s.cell_size)
    without = np.count_nonzero((res.mask == LOW) & ground)
    assert without > 100 and with_rule < without / 2


def test_single_window_keeps_gaps_between_crowns_as_ground(monkeypatch):
    """The single-window form's two-sided test has the gap of SMRF's final test: over vegetation wider
    than its window the opened surface is the vegetation, and the ground seen through it falls more
    than dh below it: class 2 (lidar autzen_trim at 1 m, a flat town whose derived mode is the single
    form: 101 ground points). The progressive form's rule (:func:`confirm_low_cells`) applies: on the
    closed canopy (96 m at 1 m cells, a 20 m window) 372 of the 1464 ground cells were class 2 without
    it, 293 with it (the rest lie deeper than the pre-step's 5 m below the opened crowns); a blunder
    8 m below open ground stays class 2."""
    from bare_earth.core.synthetic import make_canopy
    s = make_canopy(96.0, 1.0, seed=0, noise_m=0.05)
    ground = s.mask == 0
    params = dict(mode="single", max_object_size_m=20.0)
    with_rule = np.count_nonzero((morph.filter_morphological(s.dsm, s.cell_size, **params).mask == LOW) & ground)
    z = np.zeros((40, 40), np.float32)
    z[20, 20] = -8.0
    expected = np.zeros(z.shape, np.uint8)
    expected[20, 20] = LOW
    np.testing.assert_array_equal(morph.filter_morphological(z, 1.0, dh_m=0.5, outline_slope=0.3, **params).mask,
                                  expected)
    monkeypatch.setattr(morph, "confirm_low_cells", lambda z, low, *a, **k: low)
    without = np.count_nonzero((morph.filter_morphological(s.dsm, s.cell_size, **params).mask == LOW) & ground)
    assert without > 300 and with_rule < without - 50


@pytest.mark.parametrize("depth", [6.0, 8.0, 30.0])
def test_blunder_below_level_ground_stays_low(depth):
    """A single blunder deeper than the pre-step's 5 m below flat ground stays a low outlier (deeper than
    that below ZIpro, and below every cell of its ring), and nothing else is one."""
    z = np.zeros((60, 60), np.float32)
    z[30, 30] = -depth
    res = morph.filter_morphological(z, 1.0, mode="progressive", max_object_size_m=20.0, dh_m=0.5, slope=0.3,
                                     outline_slope=0.3)
    expected = np.zeros(z.shape, np.uint8)
    expected[30, 30] = LOW
    np.testing.assert_array_equal(res.mask, expected)


def test_confirm_low_cells_rules():
    """Exact: deep below ZIpro, below the ring, or below level neighbours -> low; a gap beside gaps -> not."""
    i, j = np.mgrid[0:25, 0:25]
    z = (10.0 + 2.0 * ((i + j) % 2)).astype(np.float32)        # crowns 10-12 m: no level neighbours
    zpro = np.full_like(z, 10.0)
    z[12, 4] = z[12, 12] = 0.0
    z[4, 20] = -2.0
    low = z < 5.0
    np.testing.assert_array_equal(np.argwhere(morph.confirm_low_cells(z, low, zpro, (1.0, 1.0), 0.5, 12.0, 1.0)),
                                  [[4, 20]])
    assert morph.confirm_low_cells(z, low, zpro, (1.0, 1.0), 0.5, 5.0, 1.0).sum() == 3      # all deeper than 5 m
    flat = np.full_like(z, 10.0)
    flat[12, 4] = flat[12, 12] = 0.0                                # level neighbours (a paved surface)
    assert morph.confirm_low_cells(flat, flat < 5.0, zpro, (1.0, 1.0), 0.5, 12.0, 1.0).sum() == 2


# --------------------------------------------------------------------------- large buildings (issues 12, 13)
def test_step_thresholds_grow_by_the_wide_slope_beyond_half_a_block():
    radii = morph.window_radii(81.0, 1.0, growth=2.0)          # radii 1, 2, 4, 8, 16, 32, 40
    assert morph.step_thresholds(radii, 0.3) == [0.3 * r for _, _, r in radii]       # SMRF's s r_k
    t = morph.step_thresholds(radii, 0.3, 0.05, 20.0)
    assert t == pytest.approx([0.3, 0.6, 1.2, 2.4, 4.8, 6.0 + 0.05 * 12, 6.0 + 0.05 * 20])
    assert morph.step_thresholds(radii, 0.3, 0.3, 0.0) == morph.step_thresholds(radii, 0.3)


def _large_building(side_m, cell=1.0, height=10.0):
    """Gentle terrain (a 2 % tilt and 3 m waves 565 m long, slope at most 0.04) with one flat-roofed
    building ``side_m`` square and ``height`` high, 100 m from the edges."""
    n = int((side_m + 200) / cell)
    y, x = np.mgrid[0:n, 0:n] * cell
    rng = np.random.default_rng(0)
    g = 100 + 0.02 * x + 3 * np.sin(y / 90.0) + rng.normal(0, 0.05, (n, n))
    z = g.astype(np.float32)
    b = slice(int(100 / cell), int((100 + side_m) / cell))
    z[b, b] = g[b, b].max() + height
    truth = np.zeros(z.shape, bool)
    truth[b, b] = True
    return z, truth


@pytest.mark.parametrize("side_m", [80.0, 160.0])
def test_a_large_building_on_gentle_terrain_is_an_object(side_m):
    """SMRF's threshold ``s r_k`` with the slope's floor 0.3 on terrain of slope 0.04 reached 12 m at the
    radius that removes an 80 m roof, and the 10 m high building stayed ground (Type II 100 %). Beyond half
    the 40 m blocks the slope is measured on, the threshold grows by the measured median slope, and the
    raised region's window reaches across the 160 m roof: the whole building is an object, no ground is."""
    z, truth = _large_building(side_m)
    res = run_array("morphological", z, (1.0, 1.0), {})
    info = res.info
    assert info["slope"] == 0.3 and info["wide_radius_m"] == 20.0
    assert 0.02 < info["wide_slope"] < 0.05 and info["wide_slope"] == info["terrain_slope_p50"]
    assert "median slope" in info["wide_slope_source"]
    assert info["max_object_size_m"] >= side_m
    assert max(info["thresholds_m"]) < 10.0
    assert np.count_nonzero((res.mask != OBJECT) & truth) <= 0.01 * truth.sum()
    assert np.count_nonzero((res.mask == OBJECT) & ~truth) <= 0.001 * (~truth).sum()
    # SMRF's one slope at every radius (a slope given): the threshold outgrows the building
    given = run_array("morphological", z, (1.0, 1.0), {"slope": 0.3, "max_object_size_m": info["max_object_size_m"]})
    assert given.info["wide_slope"] == 0.3
    assert given.info["wide_slope_source"] == "slope given: s at every radius (SMRF)"
    assert np.count_nonzero((given.mask == OBJECT) & truth) < 0.01 * truth.sum()


# --------------------------------------------------------------------------- the ground's slope
def test_l1_slope_of_a_plane_is_the_sum_of_its_gradients():
    i, j = np.mgrid[0:5, 0:6]
    g = morph.l1_slope((0.5 * j - 0.25 * i).astype(np.float32), (2.0, 1.0))
    np.testing.assert_allclose(g[1:-1, 1:-1], 0.25 + 0.25)     # 0.5 m over 2 m along the rows, 0.25 down
    assert (g[[0, -1], :] == 0).all() and (g[:, [0, -1]] == 0).all()


def test_edge_l1_slope_reads_a_plane_on_the_raster_edge_from_the_cells_it_holds():
    """On the outer rows and columns (where central differences have no cell beyond) the own slope of a plane is
    its L1 slope too, read across the edge by one-sided differences; the interior is left as it is."""
    i, j = np.mgrid[0:5, 0:6]
    z = (0.5 * j - 0.25 * i).astype(np.float32)
    g = morph.l1_slope(z, (2.0, 1.0))
    inner = g[1:-1, 1:-1].copy()
    out = morph.edge_l1_slope(g, z, (2.0, 1.0))
    assert out is g
    np.testing.assert_allclose(g, 0.25 + 0.25)                 # every cell, corners included
    assert g[1:-1, 1:-1].tobytes() == inner.tobytes()
    z[0, 2] = np.nan                                            # no difference to read: 0, as in the interior
    g = morph.edge_l1_slope(morph.l1_slope(z, (2.0, 1.0)), z, (2.0, 1.0))
    assert g[0, 2] == 0.0


def test_add_rounding_raises_slopes_by_the_heights_rounding_only():
    z = np.array([[0.0, 1000.0], [-1000.0, np.nan]], np.float32)
    s = np.full(z.shape, 0.5, np.float32)
    morph.add_rounding((s,), z, (0.5, 1.0))
    ulp = np.finfo(np.float32).eps * 1000.0
    np.testing.assert_allclose(s, [[0.5, 0.5 + 16 * ulp], [0.5 + 16 * ulp, 0.5]], rtol=1e-6)


#: Tilted planes (rise per metre along the rows and down the columns): facing each corner, each edge and
#: between; their L1 slope at most 1.2, under the ground slope map's bound of 1.5.
_PLANES = [(0.3, 0.3), (-0.6, 0.6), (0.6, -0.6), (-0.3, -0.3), (0.5, 0.0), (0.0, -0.8), (0.7, 0.3), (-0.2, 0.9)]


@pytest.mark.parametrize("cell", [0.5, 1.0, 2.0, 4.0])
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_a_tilted_plane_stays_ground_at_the_raster_edge(cell, dtype):
    """QA: a plane's highest corner was flagged (a 30 x 30 plane rising 0.3 per cell each way: cell (29, 29)). The
    opening's windows are clipped at the raster's edge, so the opening sits ``(|g_x| + |g_y|) r`` below that corner
    (the crest's cut, above SMRF's ``s r`` for a plane facing a diagonal), and the own slope ``S`` the threshold
    ``min(G_k, S) r_k`` reads was 0 on the outer rows and columns. Every plane stays ground, at every corner and
    edge, whatever the cell size, with the derived parameters and with SMRF's slope given below the plane's."""
    n = int(round(60.0 / cell)) + 8                    # wider than the derived largest window (40 m) and its slope map
    i, j = np.mgrid[0:n, 0:n]
    for gx, gy in _PLANES:
        z = (250.0 + cell * (gx * j + gy * i)).astype(dtype)
        for params in ({}, {"slope": 0.3}):
            res = morph.filter_morphological(z, cell, mode="progressive", **params)
            bad = np.argwhere(res.mask != GROUND)
            assert len(bad) == 0, f"plane {gx, gy} at {cell} m {params}: cells {bad[:4].tolist()} not ground"


def test_a_tilted_plane_stays_ground_in_blocks():
    """The blocks' edges inside the raster are halos: a plane run in blocks is ground everywhere, as in one pass."""
    i, j = np.mgrid[0:150, 0:170]
    z = (50.0 + 0.6 * j + 0.6 * i).astype(np.float32)
    blk = run_array("morphological", z, 1.0, {"mode": "progressive"}, block=64)
    assert blk.info["blocks"] > 4
    assert np.count_nonzero(blk.mask != GROUND) == 0


def test_objects_on_walls_count_a_region_cut_by_the_border_there_as_no_wall():
    """A region cut by the raster's border: its outline there lies beyond the data, edge cells no wall shows.
    3 of the 5 edge cells beside the ground are walls (60 %); with its 3 other cells on the border, 3 of 8: not
    on walls (the mountain of benchmarks/bare.py at 4 m: a cut crest on the border sized the window, 80 m,
    once its border cells were no longer flagged: 1.67 -> 8.46 % of the ground lost). With walls on all 5 cells
    beside the ground (5 of 8) it stands on walls."""
    z = np.zeros((7, 7), np.float32)
    z[0:3, 0:3] = 0.3
    z[2, 0:3] = 5.0                                   # the walls: 5 m above the ground below them
    flags = z > 0
    assert not morph.objects_on_walls(z, flags, ~flags, (1.0, 1.0), 0.5, 0.0).any()
    z[0:2, 2] = 5.0
    assert morph.objects_on_walls(z, flags, ~flags, (1.0, 1.0), 0.5, 0.0).sum() == 9


def test_ground_slope_map_reads_slopes_and_not_steps():
    """A plane rising 0.2 / 0.1 per metre reads 0.3 (the square window's corner); a step 3 m high, which
    spans one cell, reads 0 (no ground slope); the slope is at most 1.5, the bound of SMRF's slope."""
    i, j = np.mgrid[0:20, 0:20]
    plane = (0.2 * j + 0.1 * i).astype(np.float32)
    g = morph.ground_slope_map(plane, (2, 2), (1.0, 1.0))
    np.testing.assert_allclose(g[6:14, 6:14], 0.3, atol=1e-5)
    step = np.where(j < 10, 0.0, 3.0).astype(np.float32)
    assert float(morph.ground_slope_map(step, (2, 2), (1.0, 1.0)).max()) == 0.0
    steep = (4.0 * j).astype(np.float32)
    np.testing.assert_allclose(morph.ground_slope_map(steep, (1, 1), (1.0, 1.0))[5:15, 5:15], 1.5)
    # nodata (+inf) windows read 0
    hole = plane.copy()
    hole[:, :] = np.inf
    assert float(morph.ground_slope_map(hole, (2, 2), (1.0, 1.0)).max()) == 0.0


@pytest.mark.parametrize("ry,rx", [(0, 0), (0, 3), (2, 0), (1, 2), (3, 5), (12, 1), (2, 40)])
@pytest.mark.parametrize("op", [np.minimum, np.maximum])
def test_running_box_equals_the_two_separable_passes(ry, rx, op):
    """_running_box (the column pass into the scratch buffer, the row pass banded into ``out``, ``out`` may be the
    input) gives two _running passes' values exactly, with +/-inf cells, windows longer than the raster and
    windows of one cell."""
    rng = np.random.default_rng(7)
    g = rng.normal(0.0, 1.0, (19, 23)).astype(np.float32)
    g[3, 4] = np.inf
    g[10:12, 0:3] = -np.inf
    want = morph._running(morph._running(g.copy(), ry, 0, op), rx, 1, op)
    work = morph._Work()
    out = np.empty_like(g)
    np.testing.assert_array_equal(morph._running_box(g.copy(), ry, rx, op, work, out), want)
    same = g.copy()
    np.testing.assert_array_equal(morph._running_box(same, ry, rx, op, work, same), want)


def test_progressive_takes_the_slope_maps_erosion_for_its_last_step():
    """The erosion ground_slope_map returns is the one the last step would compute from the step before (square
    windows' minima compose exactly): the flags and the last opening are the same with it as without, also with
    nodata and unequal half-widths."""
    rng = np.random.default_rng(5)
    i, j = np.mgrid[0:70, 0:90].astype(np.float32)
    z = (0.4 * j + 3.0 * np.sin(i / 9.0) + rng.normal(0, 0.05, i.shape)).astype(np.float32)
    z[20:34, 30:41] += 12.0
    z[50:53, 70:72] += 3.0
    z[5:8, 60:66] = np.nan
    a, has_nodata = morph._as_inf(z)
    cell = (1.0, 1.5)
    radii = [(1, 1, 1.0), (2, 1, 2.0), (4, 3, 4.0), (8, 5, 8.0), (12, 8, 12.0)]
    slope, widest = morph.ground_slope_map(a, radii[-1][:2], cell, return_erosion=True)
    np.testing.assert_array_equal(morph.ground_slope_map(a, radii[-1][:2], cell), slope)
    own = morph.l1_slope(z, cell)
    args = (a, radii, 0.3, has_nodata)
    flags, last = morph._progressive(*args, growth=2.0, ground_slope=slope.copy(), own_slope=own)
    with_e, last_e = morph._progressive(*args, growth=2.0, ground_slope=slope.copy(), own_slope=own,
                                        last_erosion=widest)
    np.testing.assert_array_equal(with_e, flags)
    np.testing.assert_array_equal(last_e, last)
    assert flags[25, 35] and not flags[60, 10]


def _rounded_ridge():
    """A rounded ridge 30 m high (Gaussian profile, sigma 20 m: slopes up to 0.91) across a raster of 1 m
    cells, running off both ends (no cut-terrain region), and a 12 x 12 m block 6 m high on the gentle
    ground beside it: (z, roof)."""
    i, j = np.mgrid[0:120, 0:170].astype(np.float32)
    z = (30.0 * np.exp(-(j - 60.0) ** 2 / (2 * 20.0 ** 2)) + 0.02 * i).astype(np.float32)
    roof = (i >= 50) & (i < 62) & (j >= 140) & (j < 152)
    z[roof] += 6.0
    return z, roof


def test_a_rounded_ridge_steeper_than_the_slope_stays_ground_and_a_block_beside_it_is_an_object():
    """SMRF's threshold s r_k with one slope s = 0.3 cut the ridge's crest (about 12 m at a 20 m radius)
    and took 16 % of the raster for objects; with the ground's own slope where the cell lies on a slope
    (ground_slope_map, l1_slope) the crest's level top is all that is left (6.5 %), and the block on the
    gentle ground is still an object."""
    z, roof = _rounded_ridge()
    res = morph.filter_morphological(z, 1.0, mode="progressive", max_object_size_m=40.0, dh_m=0.5, slope=0.3,
                                     outline_slope=1.0, wide_slope=0.3, wide_radius_m=20.0)
    assert (res.mask[roof] == OBJECT).all()
    lost = 100.0 * np.count_nonzero(res.mask[~roof] != 0) / np.count_nonzero(~roof)
    assert lost < 8.0


def test_a_level_roof_on_a_steep_hillside_stays_an_object_and_the_hillside_ground():
    """The ground's slope around a roof on a hillside of slope 0.8 is steep, but the roof's own cells are
    level: the threshold there stays s r_k and the roof is flagged. The hillside's cells lie on its slope:
    the uphill edge, which windows cut at the raster's border by more than 0.3 r_k, stays ground (13 % of
    the cells lost with one slope s = 0.3)."""
    i, j = np.mgrid[0:100, 0:100].astype(np.float32)
    z = (0.8 * j).astype(np.float32)
    roof = (i >= 40) & (i < 56) & (j >= 40) & (j < 56)
    z[roof] = 0.8 * 56 + 4.0                     # 4 m above the uphill side, 16.8 m above the downhill side
    res = morph.filter_morphological(z, 1.0, mode="progressive", max_object_size_m=40.0, dh_m=0.5, slope=0.3,
                                     outline_slope=0.8, wide_slope=0.3, wide_radius_m=20.0)
    assert np.count_nonzero(res.mask[roof] == OBJECT) >= 0.95 * roof.sum()
    assert np.count_nonzero(res.mask[~roof] != 0) <= 0.02 * (~roof).sum()


def test_blocks_equal_one_pass_on_rough_steep_relief():
    """The ground slope map's reach (the erosion, its difference, opening and running maximum) is in the
    halo: blocks give the one-pass mask on the fBm mountain."""
    from bare_earth.core.synthetic_bare import make_bare
    s = make_bare("mountain", 2.0)
    z = s.dsm[:150, :170]
    one = run_array("morphological", z, 2.0)
    blk = run_array("morphological", z, 2.0, block=40)
    assert blk.info["blocks"] > 4
    np.testing.assert_array_equal(blk.mask, one.mask)


# --------------------------------------------------------------------------- noise allowance (Zhang's dh_0)
def _noisy_plane_with_car(sigma=0.15, cell=0.5, n=240, seed=3):
    """Level ground with white noise ``sigma`` at ``cell`` m and a car 4 x 2 m, 1.5 m high: (z, truth)."""
    rng = np.random.default_rng(seed)
    z = (50.0 + rng.normal(0.0, sigma, (n, n))).astype(np.float32)
    truth = np.zeros(z.shape, np.uint8)
    car = (slice(100, 100 + int(2 / cell)), slice(60, 60 + int(4 / cell)))
    z[car] += 1.5
    truth[car] = OBJECT
    return z, truth


def test_noise_allowance_keeps_noisy_ground_and_flags_a_car():
    """On 0.5 m cells SMRF's first thresholds ``s r_k`` (0.15-0.3 m) are at the noise (0.15 m): the flags
    took a third of the level ground, which left ZIpro for the opening 1-3 sigma below the noise's mean,
    and the final test took the higher cells for objects (bare.py river at 0.5 m: 1.99 % of the ground
    lost). With every threshold at least Zhang's dh_0 = 4.5 sigma the ground stays ground and the car is
    still an object."""
    z, truth = _noisy_plane_with_car()
    run = dict(mode="progressive", max_object_size_m=10.0, dh_m=0.5, slope=0.3, outline_slope=0.3,
               wide_slope=0.3, wide_radius_m=20.0)
    with_dh0 = morph.filter_morphological(z, 0.5, noise_m=0.15, **run)
    smrf = morph.filter_morphological(z, 0.5, noise_m=0.0, **run)
    ground = truth == GROUND
    lost = lambda m: np.count_nonzero(m[ground] != GROUND) / ground.sum()      # noqa: E731
    assert lost(smrf.mask) > 0.005                            # the defect: SMRF's thresholds read the noise
    assert lost(with_dh0.mask) < 0.001
    assert np.all(with_dh0.mask[truth == OBJECT] == OBJECT)
    assert with_dh0.info["noise_allowance_m"] == pytest.approx(0.675)
    assert smrf.info["flagged_by_opening_percent"] > 10 * with_dh0.info["flagged_by_opening_percent"]


def test_noise_is_measured_or_given():
    """Left empty the noise is measured on the ground-level cells (dh = 3 sigma from it); given, it is used
    as given and dh derives from it; the threshold's floor follows it."""
    z, _ = _noisy_plane_with_car(sigma=0.2)
    p = morph.resolve_morphological_params(z, 0.5)
    assert p["noise_m"] == pytest.approx(0.2, rel=0.15) and p["noise_source"].startswith("measured")
    assert p["dh_m"] == pytest.approx(3.0 * 0.2, rel=0.15)
    q = morph.resolve_morphological_params(z, 0.5, noise_m=0.3)
    assert q["noise_m"] == 0.3 and q["noise_source"] == "given" and q["dh_m"] == pytest.approx(0.9)
    res = run_array("morphological", z, 0.5, {"noise_m": 0.3}, want_dtm=False)
    assert res.info["params"]["noise_m"] == 0.3
    with pytest.raises(ValueError, match="noise_m"):
        morph.resolve_morphological_params(z, 0.5, noise_m=-0.1)


def test_noise_floor_leaves_thresholds_above_it():
    """The floor dh_0 = 4.5 sigma raises only the steps whose s r_k lies below it: a 0.4 m object 2 x 2 cells
    on level ground without noise is flagged at 1 m cells with s = 0.3 whatever the floor below 0.3 m (lidar's
    0.05 m: 0.225 m), and stays unflagged once the floor exceeds its height."""
    z = np.zeros((30, 30), np.float32)
    z[10:12, 10:12] = 0.4
    run = dict(mode="progressive", max_object_size_m=9.0, dh_m=0.2, slope=0.3, outline_slope=0.3,
               wide_slope=0.3, wide_radius_m=20.0)
    lidar = morph.filter_morphological(z, 1.0, noise_m=0.05, **run)
    assert np.all(lidar.mask[10:12, 10:12] == OBJECT) and lidar.info["flagged_by_opening_percent"] > 0
    assert morph.filter_morphological(z, 1.0, noise_m=0.0, **run).info["flagged_by_opening_percent"] == \
        lidar.info["flagged_by_opening_percent"]
    high = morph.filter_morphological(z, 1.0, noise_m=0.1, **run)         # floor 0.45 m above the 0.4 m drop
    assert high.info["flagged_by_opening_percent"] == 0
    assert morph.noise_allowance(0.1) == pytest.approx(0.45) and morph.noise_allowance(None) == 0.0


# --------------------------------------------------------------------------- walls and continuing slopes (issue 12)
def test_continuing_rise_exact():
    """The ground's descent beyond a foot, the smaller of its next two steps down: a plane of slope 0.5 at 1 m
    cells descends 0.5 a step; level ground 0; a mixed cell half a roof high beside level ground 0 (its second
    step is level); a slope of 3 is capped."""
    j = np.arange(12, dtype=np.float32)[None, :] + np.zeros((9, 1), np.float32)
    ground = np.ones(j.shape, bool)
    foot = np.array([4 * 12 + 6])
    assert morph.continuing_rise(0.5 * j, ground, foot, 10.0).tolist() == [0.5]
    assert morph.continuing_rise(np.zeros_like(j), ground, foot, 10.0).tolist() == [0.0]
    mixed = np.zeros_like(j)
    mixed[4, 6] = 3.0
    assert morph.continuing_rise(mixed, ground, foot, 10.0).tolist() == [0.0]
    assert morph.continuing_rise(3.0 * j, ground, foot, 2.0).tolist() == [2.0]
    assert morph.continuing_rise(0.5 * j, ground, np.array([-1]), 10.0).tolist() == [0.0]


def test_outline_cells_leave_out_a_flank_running_along_a_feature():
    """A dike's 1:2 flank at 4 m cells is three steps of 2 m (6, 4, 2, 0): the middle cell's foot has one step down
    and then level ground beside it, as a roof's mixed cell (6, 3, 0) has, so the flank read as the crest's outline.
    The step down to it from the cell opposite its foot (2 m) continues the slope through it, and such cells run
    along the dike: with the largest window's half-width (``r_max``) they are no outline (but on the raster's last
    row, where the cell opposite a diagonal foot lies beyond the raster). A roof's mixed cells stay outline cells,
    and so does the rim of a cone of the same 2 m steps only five cells across (a crown: its rim curves round it
    within a line as long as the window)."""
    dike = np.tile(np.array([0, 0, 0, 2, 4, 6, 6, 6, 4, 2, 0, 0, 0], np.float32), (20, 1))
    flat = np.zeros(dike.shape, np.float32)
    before = morph.find_outline_cells(dike, flat, dike >= 6, (4.0, 4.0), 0.5)
    assert np.unique(np.argwhere(before)[:, 1]).tolist() == [4, 8] and before.sum() == 40
    after = morph.find_outline_cells(dike, flat, dike >= 6, (4.0, 4.0), 0.5, r_max=(3, 3))
    assert not after[:-1].any()
    roof = np.tile(np.array([0, 0, 0, 0, 3, 6, 6, 6, 3, 0, 0, 0, 0], np.float32), (20, 1))
    outline = morph.find_outline_cells(roof, flat, roof >= 6, (4.0, 4.0), 0.5, r_max=(3, 3))
    assert np.unique(np.argwhere(outline)[:, 1]).tolist() == [4, 8] and outline.sum() == 40
    i, j = np.mgrid[0:21, 0:21]
    d = np.maximum(np.abs(i - 10), np.abs(j - 10)).astype(np.float32)
    cone = np.clip(6.0 - 2.0 * np.maximum(d - 1.0, 0.0), 0.0, None).astype(np.float32)
    flat = np.zeros(cone.shape, np.float32)
    rim = morph.find_outline_cells(cone, flat, cone >= 6, (4.0, 4.0), 0.5, r_max=(3, 3))
    np.testing.assert_array_equal(rim, morph.find_outline_cells(cone, flat, cone >= 6, (4.0, 4.0), 0.5))
    assert rim.sum() == 16
    # the cell opposite the foot: 2 m above the flank's middle cell, none above the crest's or beyond the raster
    assert morph._rise_above(dike, np.array([3 * 13 + 4, 3 * 13 + 6, 3 * 13 + 4]),
                             np.array([3 * 13 + 3, 3 * 13 + 5, -1])).tolist() == [2.0, 0.0, 0.0]


def _flank_and_roof():
    """A mound with 1:1 flanks 6 m high (flags on its top, z > 4.5) and a roof 6 m high ringed by one cell of
    mixed cells at half its height, each on level ground, 1 m cells."""
    i, j = np.mgrid[0:31, 0:31].astype(np.float32)
    mound = np.clip(8.0 - np.maximum(np.abs(i - 15), np.abs(j - 15)), 0.0, 6.0).astype(np.float32)
    roof = np.zeros_like(mound)
    roof[11:20, 11:20] = 3.0
    roof[12:19, 12:19] = 6.0
    return mound, mound > 4.5, roof, roof == 6.0


def test_a_flank_continuing_beyond_its_foot_is_no_wall():
    """A wall is a step across about one cell; a dike's or a mountain's flank goes on descending beyond its foot.
    The mound's top, flagged, stands 1 m above the flank cell beside it (a wall for dh 0.5 at the outline slope
    0) but the flank descends 1 m a cell beyond: cut terrain, not an object on walls. The roof stands 3 m above
    its ring of mixed cells, which stands 3 m above level ground (a continuing slope read over one step only):
    a wall, still an object."""
    mound, top, roof, flat = _flank_and_roof()
    args = ((1.0, 1.0), 0.5, 0.0, (10, 10))
    np.testing.assert_array_equal(morph.find_cut_terrain(mound, top, ~top, *args), top)
    assert not morph.find_cut_terrain(roof, flat, ~flat, *args).any()
    assert not morph.objects_on_walls(mound, top, ~top, (1.0, 1.0), 0.5, 0.0, keep_thin=False).any()
    np.testing.assert_array_equal(morph.objects_on_walls(roof, flat, ~flat, (1.0, 1.0), 0.5, 0.0), flat)
    # the flank's cells beside the flags are no outline cells; the roof's ring is
    assert not morph.find_outline_cells(mound, np.zeros_like(mound), top, (1.0, 1.0), 0.5, 0.0).any()
    ring = morph.find_outline_cells(roof, np.zeros_like(roof), flat, (1.0, 1.0), 0.5, 0.0)
    np.testing.assert_array_equal(ring, roof == 3.0)


def test_steep_mountain_at_4_m_keeps_its_ground():
    """The fBm mountain of benchmarks/bare.py at 4 m cells (no object): its crests, cut by the object-size
    search, stood on one-cell rises steeper than the 40 m blocks' 90th-percentile slope, so on 'walls', and
    sized an 80 m window that cut more of them: 10.55 % of the ground lost; their flanks go on descending
    beyond the foot, so they are no walls: 2.26 %."""
    from bare_earth.core.synthetic_bare import make_bare
    s = make_bare("mountain", 4.0, seed=0)
    res = morph.filter_morphological(s.dsm, s.cell_size)
    assert res.info["max_object_size_m"] < 40.0
    assert np.count_nonzero(res.mask != GROUND) < 0.04 * res.mask.size


# --------------------------------------------------------------------------- terrain narrower than the largest window
def _diagonal_dike(n=120, h=6.0, crest=5.0, side=0.5):
    """A dike ``h`` m high with a ``crest`` m crest and flanks of slope ``side`` along the raster's diagonal, on level
    ground at 1 m cells (longer than any window's box: it runs off the raster at two corners)."""
    i, j = np.mgrid[0:n, 0:n].astype(np.float32)
    d = (j - i) / np.float32(np.sqrt(2.0))
    return np.clip(h - np.maximum(np.abs(d) - crest / 2, 0) * side, 0, None).astype(np.float32)


def test_find_cut_slopes_keeps_walls_and_thin_regions():
    """A ridge flagged along its length (longer than the box of find_cut_terrain, off the raster) is terrain
    beyond a window's reach of the raster's border (its own walls there); a block on walls stays flagged, and the
    ridge beside it is terrain (another object's walls say nothing of the ridge); a flagged line one cell wide
    (too thin to judge) stays flagged."""
    i, j = np.mgrid[0:40, 0:30].astype(np.float32)
    z = np.maximum(0.0, 3.0 - 0.5 * np.abs(j - 8)).astype(np.float32)
    flags = z > 1.0
    args = ((1.0, 1.0), 0.5, 0.0, (3, 3))
    cut = morph.find_cut_slopes(z, flags, ~flags, *args)
    np.testing.assert_array_equal(cut[4:36], flags[4:36])
    assert not cut[:4].any() and not cut[36:].any()
    assert not morph.find_cut_terrain(z, flags, ~flags, *args).any()     # the region rule: on the border
    walled = z.copy()
    walled[15:20, 13:18] = 5.0                                         # a block 3 cells from the ridge's edge
    f2 = flags | (walled > 4.0)
    cut2 = morph.find_cut_slopes(walled, f2, ~f2, *args)
    assert not cut2[(walled > 4.0)].any()
    assert cut2[12:23, 5:12].all() and cut2[30:36, 5:12].all()
    line = np.zeros(z.shape, bool)
    line[:, 8] = True
    assert not morph.find_cut_slopes(np.where(line, 1.0, 0.0).astype(np.float32), line, ~line, *args).any()


def test_find_cut_slopes_judges_a_cell_by_its_own_region():
    """The walls that keep a cell flagged are its own object's, reached through the flags within the window: an
    embankment (a ridge longer than any box) among buildings on walls within the window is terrain, the buildings
    stay flagged; a building joined to the ridge keeps the ridge's cells within the window's reach flagged; a low
    line one cell wide beside the ridge (no wall, no cell inside its edge) stays flagged though the ridge's inside
    is within the window; a shrub one cell wide at the ridge's foot (its own outline) keeps only itself and its
    neighbours. Before, any wall within the window kept the ridge beside the building and the shrub flagged."""
    i, j = np.mgrid[0:60, 0:40].astype(np.float32)
    z = np.maximum(0.0, 3.0 - 0.5 * np.abs(j - 12)).astype(np.float32)
    ridge = z > 1.0                                                   # columns 9..15, rows 0..59
    z[20:26, 19:25] = 6.0                                             # a building 4 cells from the ridge
    z[44:50, 16:22] = 6.0                                             # a building joined to the ridge
    z[:, 30] = 0.4                                                    # a low line, one cell wide
    flags = ridge | (z > 5.0) | (z == np.float32(0.4))
    args = ((1.0, 1.0), 0.5, 0.0, (4, 4))
    cut = morph.find_cut_slopes(z, flags, ~flags, *args)
    assert not cut[z > 5.0].any() and not cut[:, 30].any()
    assert cut[10:38, 9:16].all()                                     # the ridge beside the free-standing building
    assert not cut[45:49, 13:16].any()                                # joined to the other: within its reach
    shrub = z.copy()
    shrub[32, 7] = 4.0                                                # at the ridge's foot, a wall one cell wide
    f2 = flags.copy()
    f2[32, 7] = True
    cut2 = morph.find_cut_slopes(shrub, f2, ~f2, *args)
    assert not cut2[32, 7] and cut2[28:37, 9:16].all()


def test_a_dike_longer_than_the_window_stays_ground():
    """A 6 m dike with 1:2 flanks across the raster: the progressive filter flags its crest (level, its own
    slope 0) and find_cut_terrain cannot judge a region off the raster's border; with find_cut_slopes its
    ground stays ground (bare.py levees at 1 m: 1.58 -> 0.00 %); without, over 2000 cells are lost."""
    z = _diagonal_dike()
    kw = dict(mode="progressive", max_object_size_m=40.0, dh_m=0.5, slope=0.3, outline_slope=0.0, wide_slope=0.3,
              wide_radius_m=20.0)
    assert np.count_nonzero(morph.filter_morphological(z, 1.0, **kw).mask != GROUND) == 0


def test_a_dike_is_lost_without_the_cut_slopes_rule(monkeypatch):
    """Without find_cut_slopes (and without the reference's slopes, which keep most of this crest now: 684 cells
    lost without the rule, none with it) over 1000 cells are lost."""
    monkeypatch.setattr(morph, "find_cut_slopes", lambda clean, flagged, *a, **k: np.zeros(flagged.shape, bool))
    monkeypatch.setattr(morph, "reference_slope", lambda *a, **k: None)
    z = _diagonal_dike()
    res = morph.filter_morphological(z, 1.0, mode="progressive", max_object_size_m=40.0, dh_m=0.5, slope=0.3,
                                     outline_slope=0.0, wide_slope=0.3, wide_radius_m=20.0)
    assert np.count_nonzero(res.mask != GROUND) > 1000


def test_blocks_equal_one_pass_on_dikes(monkeypatch):
    """find_cut_slopes' window and its walls' cells are in the halo: blocks give the one-pass mask on the curved
    6 m dike of bare.py's levees at 1 m (which the rule gives back to the ground: over 1500 cells here, with the
    reference's slopes left out), and with them (they keep the crest before the rule: nothing to give back, 45 cells
    lost)."""
    from bare_earth.core.synthetic_bare import make_bare
    z = make_bare("levees", 1.0).dsm[120:320, 130:330]
    with monkeypatch.context() as m:
        m.setattr(morph, "reference_slope", lambda *a, **k: None)
        one = run_array("morphological", z, 1.0, {"mode": "progressive"})
        assert one.info["cut_terrain_percent"] > 3.0
        blk = run_array("morphological", z, 1.0, {"mode": "progressive"}, block=64)
        assert blk.info["blocks"] > 4
        np.testing.assert_array_equal(blk.mask, one.mask)
    one = run_array("morphological", z, 1.0, {"mode": "progressive"})
    blk = run_array("morphological", z, 1.0, {"mode": "progressive"}, block=64)
    np.testing.assert_array_equal(blk.mask, one.mask)


def test_lowest_ground_exact():
    """The lowest ground cell of each 3 x 3 neighbourhood and its index, the first in row order among
    equal heights, on border and inner cells alike (inner ones gathered at once, border ones clipped);
    nodata, non-ground and the outside are none (+inf, -1)."""
    rng = np.random.default_rng(7)
    for shape in ((1, 1), (1, 6), (5, 1), (2, 3), (23, 31)):
        z = rng.integers(0, 3, shape).astype(np.float32)     # many ties
        z[rng.random(shape) < 0.15] = np.nan
        ground = rng.random(shape) < 0.6
        cells = np.flatnonzero(rng.random(shape) < 0.8)
        low, where = morph._lowest_ground(z, ground, cells)
        H, W = shape
        for k, q in enumerate(cells):
            r, c = divmod(int(q), W)
            best, at = np.inf, -1
            for dr in (-1, 0, 1):
                for dc in (-1, 0, 1):
                    rr, cc = r + dr, c + dc
                    if 0 <= rr < H and 0 <= cc < W and ground[rr, cc] and z[rr, cc] < best:
                        best, at = z[rr, cc], rr * W + cc
            assert low[k] == best and where[k] == at


def _embankment_scene():
    from bare_earth.core.synthetic import make_scene
    s = make_scene("breakline", (512, 512), cell_size=0.5, seed=1, noise_m=0.05)
    return s.dsm, np.asarray(s.mask)


def test_a_flat_crest_between_slopes_narrower_than_the_largest_window_is_ground():
    """The road embankment of the synthetic breakline scene (5-10 m high, 30-40 degree sides, crossing the
    raster obliquely, trees on it) at 0.5 m: the erosion by the largest window reads it as level ground, so the
    threshold took SMRF's slope 0.3 and the opening cut its flat crest (8140 cells, 3.1 %, ground taken for
    objects); each step's own erosion keeps the flanks, whose slope continues along the embankment: at most
    0.1 % now, and the trees on it stay objects."""
    z, truth = _embankment_scene()
    res = run_array("morphological", z, 0.5)
    type1 = np.count_nonzero((truth == GROUND) & (res.mask != GROUND))
    type2 = np.count_nonzero((truth == OBJECT) & (res.mask == GROUND))
    assert type1 <= 0.001 * z.size
    assert type2 <= 0.1 * np.count_nonzero(truth == OBJECT)


def test_the_crest_is_cut_without_the_continuing_slopes(monkeypatch):
    """The failure the rule fixes: without it the embankment's crest is flagged (more than 2 % of the cells)."""
    z, truth = _embankment_scene()
    monkeypatch.setattr(morph, "_spare_continuing", lambda *a, **k: None)
    res = run_array("morphological", z, 0.5)
    assert np.count_nonzero((truth == GROUND) & (res.mask != GROUND)) > 0.02 * z.size


def _box_max(a):
    from scipy import ndimage
    return ndimage.maximum_filter(a, size=3, mode="nearest")


def test_spare_continuing_needs_the_slope_along_half_a_line_and_the_top_across():
    """On exact arrays: flagged cells with a drop of 1 m at a step of radius 2 m need a slope of 0.5 on half of
    some line of 2 x 3 + 1 cells; a band of that slope along the rows passes them, a 3 x 3 patch of it does not
    (a crown standing above the ground on all sides), nor does the band where the drop exceeds its slope's, nor
    a cell the reference surface rises above by more than the drop within the step's window (a shrub on a
    slope, below the ground uphill)."""
    g = np.zeros((12, 12), np.float32)
    g[2:5, :] = 0.5
    g[7:10, 4:7] = 0.5
    ref = np.zeros(g.shape, np.float32)
    ref[3, 3] = 1.5                                     # uphill of (3, 2) and (3, 4): 1.5 m above, drop 1 m
    up = np.zeros(g.shape, bool)
    up[3, 2:10] = True
    up[8, 5] = True
    d = np.where(up, 1.0, 0.0).astype(np.float32)
    d[3, 9] = 1.2
    morph._spare_continuing(up, d, g, 0, np.float32(2.0), (3, 3), ref, _box_max(ref))
    assert sorted(zip(*np.nonzero(up))) == [(3, 2), (3, 4), (3, 9), (8, 5)]
    # the same cells with the rise within the drop: passed
    up2 = np.zeros(g.shape, bool)
    up2[3, 2:10] = True
    ref[3, 3] = 0.9
    morph._spare_continuing(up2, d, g, 0, np.float32(2.0), (3, 3), ref, _box_max(ref))
    assert sorted(zip(*np.nonzero(up2))) == [(3, 9)]
    # in a band of rows starting at row 6: the patch still flagged
    band = np.zeros((4, 12), bool)
    band[2, 5] = True
    morph._spare_continuing(band, np.ones((4, 12), np.float32), g, 6, np.float32(2.0), (3, 3), ref, _box_max(ref))
    assert band[2, 5]


def _steepest_sides_whole(s, cell):
    """The reading of :func:`morph._steepest_sides` on the whole array at once (its definition)."""
    dx, dy = cell
    g = np.zeros(s.shape, np.float32)
    with np.errstate(invalid="ignore"):
        c = s[1:-1, 1:-1]
        gx = np.fmax(np.abs(c - s[1:-1, :-2]), np.abs(s[1:-1, 2:] - c))
        gy = np.fmax(np.abs(c - s[:-2, 1:-1]), np.abs(s[2:, 1:-1] - c))
        g[1:-1, 1:-1] = gx / np.float32(dx) + gy / np.float32(dy)
    g[~np.isfinite(g)] = 0.0
    return g


@pytest.mark.parametrize("shape", [(1, 5), (2, 9), (3, 3), (5, 2), (150, 4100), (9, 7)])
def test_steepest_sides_in_bands_equals_the_whole_array(shape):
    """Banded (64 rows of 4100 cells at a time, into ``out``): the same float32 values as the whole array at once,
    bit for bit, with +inf (no erosion) and NaN cells, at the borders and across the bands' seams."""
    rng = np.random.default_rng(4)
    s = (rng.random(shape) * 30).astype(np.float32)
    s[rng.random(shape) < 0.05] = np.inf
    s[rng.random(shape) < 0.02] = np.nan
    want = _steepest_sides_whole(s, (0.3, 0.7))
    out = np.full(shape, 7.0, np.float32)
    got = morph._steepest_sides(s, (0.3, 0.7), out)
    assert got is out
    assert got.tobytes() == want.tobytes()
    assert morph._steepest_sides(s, (0.3, 0.7)).tobytes() == want.tobytes()


@pytest.mark.parametrize("shape", [(1, 6), (2, 2), (3, 9), (6, 1), (70, 4100), (13, 17)])
def test_open_slopes_equals_two_running_boxes(shape):
    """The slopes' opening in one banded 5 x 5 pass per operation: the same float32 values as the minimum then the
    maximum over the clipped (2 run + 1)-cell square by :func:`morph._running_box` (its definition), bit for bit,
    with NaN and +inf cells, at the raster's edges and across the bands' seams (in place where the raster is at least
    two cells wide both ways)."""
    rng = np.random.default_rng(5)
    g = (rng.random(shape) * 3).astype(np.float32)
    g[rng.random(shape) < 0.03] = np.inf
    g[rng.random(shape) < 0.01] = np.nan
    run = morph._SLOPE_RUN_CELLS
    w = morph._Work()
    want = morph._running_box(g.copy(), run, run, np.minimum, w, np.empty_like(g))
    want = morph._running_box(want, run, run, np.maximum, w, want)
    got = g.copy()
    out = morph._open_slopes(got, morph._Work())
    assert out.tobytes() == want.tobytes()
    if min(shape) >= 2:
        assert out is got


@pytest.mark.parametrize("py,px", [(0, 0), (1, 1), (2, 3), (0, 2), (3, 0)])
def test_padded_negative_equals_the_padded_copy(py, px):
    """find_low_outliers' surface -z (+inf at nodata) written into the padded array: the same values as padding a
    copy (``np.pad`` of :func:`morph._as_inf`), bit for bit, float32 and float64 inputs, with nodata."""
    rng = np.random.default_rng(6)
    z = (rng.random((7, 9)) * 20 - 5).astype(np.float32)
    z[rng.random(z.shape) < 0.2] = np.nan
    for zz in (z, z.astype(np.float64)):
        nodata = ~np.isfinite(zz)
        want = np.pad(morph._as_inf(zz, -1.0, nodata)[0], ((py, py), (px, px)), constant_values=np.inf)
        got = morph._padded_negative(zz, nodata, py, px)
        assert got.dtype == want.dtype and got.tobytes() == want.tobytes()


def _l1_slope_whole(s, cell):
    """The reading of :func:`morph.l1_slope` on the whole array at once (its definition before the bands)."""
    dx, dy = cell
    g = np.zeros(s.shape, np.float32)
    with np.errstate(invalid="ignore"):
        if s.shape[0] > 2 and s.shape[1] > 2:
            np.abs(s[1:-1, 2:] - s[1:-1, :-2], out=g[1:-1, 1:-1])
            g[1:-1, 1:-1] *= np.float32(0.5 / dx)
            gy = np.abs(s[2:, 1:-1] - s[:-2, 1:-1])
            gy *= np.float32(0.5 / dy)
            g[1:-1, 1:-1] += gy
    g[~np.isfinite(g)] = 0.0
    return g


@pytest.mark.parametrize("shape", [(1, 5), (2, 9), (3, 3), (5, 2), (150, 4100), (9, 7)])
def test_l1_slope_in_bands_equals_the_whole_array(shape):
    """Banded (64 rows of 4100 cells at a time): the same float32 values as the whole array at once, bit for bit,
    with +inf (no erosion) and NaN cells, at the borders and across the bands' seams."""
    rng = np.random.default_rng(5)
    s = (rng.random(shape) * 30).astype(np.float32)
    s[rng.random(shape) < 0.05] = np.inf
    s[rng.random(shape) < 0.02] = np.nan
    assert morph.l1_slope(s, (0.3, 0.7)).tobytes() == _l1_slope_whole(s, (0.3, 0.7)).tobytes()
    s64 = s.astype(np.float64)                  # a float64 surface: the differences in float64, as before
    assert morph.l1_slope(s64, (0.3, 0.7)).tobytes() == _l1_slope_whole(s64, (0.3, 0.7)).tobytes()


@pytest.mark.parametrize("ry,rx", [(0, 0), (1, 2), (3, 1), (6, 6)])
def test_window_top_at_cells_equals_the_running_box(ry, rx):
    """The reference's top read at some cells (corners, edges, inside; NaN and +inf left out, -inf where a window
    holds no value) equals the running maximum over the raster with non-finite values as -inf."""
    rng = np.random.default_rng(5)
    a = (rng.random((13, 11)) * 10).astype(np.float32)
    a[rng.random(a.shape) < 0.1] = np.nan
    a[2, 3] = np.inf
    a[9:, :4] = np.nan                                     # a window of NaN only at (11, 1) for small windows
    full = np.where(np.isfinite(a), a, np.float32(-np.inf))
    want = morph._running_box(full, ry, rx, np.maximum, morph._Work(), np.empty_like(full))
    cells = np.array([0, 10, 12 * 11, a.size - 1, 2 * 11 + 3, 11 * 11 + 1, 6 * 11 + 5, 3])
    got = morph._window_top(a, cells, ry, rx, chunk=40)
    assert got.tobytes() == want.ravel()[cells].tobytes()
    if ry <= 1 and rx <= 1:
        assert got[5] == -np.inf


def test_spare_continuing_reads_the_top_at_its_cells_as_on_the_raster():
    """``ref_top`` given as the window's half-widths (read at the cells the test needs, as ``_progressive`` does)
    passes the same cells as the running maximum over the raster."""
    rng = np.random.default_rng(6)
    g = (rng.random((40, 50)) * 0.6).astype(np.float32)
    g[10:14, :] = 0.5
    ref = (rng.random(g.shape) * 2.0).astype(np.float32)
    ref[rng.random(g.shape) < 0.05] = np.nan
    up = rng.random(g.shape) < 0.3
    d = (rng.random(g.shape) * 2.0).astype(np.float32)
    full = np.where(np.isfinite(ref), ref, np.float32(-np.inf))
    top = morph._running_box(full, 2, 2, np.maximum, morph._Work(), np.empty_like(full))
    a, b = up.copy(), up.copy()
    morph._spare_continuing(a, d, g, 0, np.float32(2.0), (4, 4), ref, top)
    morph._spare_continuing(b, d, g, 0, np.float32(2.0), (4, 4), ref, (2, 2))
    assert np.count_nonzero(a != up) > 5                   # some cells passed
    np.testing.assert_array_equal(a, b)


def test_stages_name_the_step_that_flagged_each_cell_and_change_nothing():
    """``filter_morphological(stages=)``: a flat box 12 m wide and 6 m high is flagged at the first step whose
    window (17 m: radius 8, the drop over the doubling from radius 3 is 6 m > 0.3 x 8) no longer fits in it; a
    one-cell bump of 1 m at the first (3 m: 1 m > 0.3 x 1); every other cell at no step; the mask is the same."""
    z = np.zeros((64, 64), np.float32)
    z[20:32, 20:32] = 6.0
    z[40, 10] = 1.0
    kw = dict(mode="progressive", max_object_size_m=20.0, dh_m=0.5, slope=0.3, noise_m=0.0, outline_slope=0.0,
              wide_slope=0.3, wide_radius_m=100.0)
    stages = {}
    res = morph.filter_morphological(z, 1.0, stages=stages, **kw)
    assert res.info["window_sizes_m"][4] == 17.0
    expected = np.full(z.shape, -1, np.int8)
    expected[20:32, 20:32] = 4
    expected[40, 10] = 0
    np.testing.assert_array_equal(stages["first_step"], expected)
    np.testing.assert_array_equal(stages["flagged"], expected >= 0)
    for key in ("cut_terrain", "outline", "tiers", "low_prestep", "low_ground"):
        assert stages[key].shape == z.shape and not stages[key].any()
    np.testing.assert_array_equal(res.mask, morph.filter_morphological(z, 1.0, **kw).mask)
    single = {}
    morph.filter_morphological(z, 1.0, stages=single, **dict(kw, mode="single"))
    assert set(single) == {"low_ground"}


def test_the_crest_first_cut_by_the_largest_window_is_ground():
    """The same embankment at 1 m cells (the generalisation matrix's synthetic breakline row): its crest is first cut
    at the last step (window 25 m), which the continuing slopes skipped (the erosion by the largest window was
    thought to cover it, but the ground slope map's ``min(G_k, S)`` is 0 on a level crest): 1.9 % of the cells
    (ground taken for objects) with the continuing slopes at every step but the last, under 0.1 % at every step;
    the trees on it stay objects."""
    from bare_earth.core.synthetic import make_scene
    s = make_scene("breakline", (384, 384), cell_size=1.0, seed=0, noise_m=0.05)
    truth = np.asarray(s.mask)
    res = run_array("morphological", s.dsm, 1.0)
    assert res.info["window_sizes_m"][-1] == 25.0
    type1 = np.count_nonzero((truth == GROUND) & (res.mask != GROUND))
    type2 = np.count_nonzero((truth == OBJECT) & (res.mask == GROUND))
    assert type1 <= 0.001 * truth.size
    assert type2 <= 0.1 * np.count_nonzero(truth == OBJECT)


def test_a_dike_crest_the_last_step_passes_leaves_no_shoulders():
    """A dike 4 m high (1:2 sides) across a flat floodplain beside three buildings, with the parameters auto derives
    (window 17 m): the last step's continuing slopes pass the crest but not its shoulders (the slope breaks, which
    lie below the crest within the window). Judged without the passed crest, the shoulders were lines a cell wide
    that the cut terrain's rules keep as outlines (400 of the dike's 3400 cells lost); judged with it, as the
    regions the drops flagged, the rules give them back: 36 cells (125 when the last step passed nothing)."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:200, 0:200].astype(np.float32)
    dike = np.clip(4.0 - np.maximum(np.abs(xx - 100.0) - 2.0, 0.0) / 2.0, 0.0, None)
    z = (100.0 + rng.normal(0, 0.05, xx.shape)).astype(np.float32)
    for r, c in ((20, 30), (100, 150), (150, 40)):
        z[r:r + 15, c:c + 12] += 9.0
    z = (z + dike).astype(np.float32)
    p = morph.resolve_morphological_params(z, 1.0)
    run = {k: p[k] for k in ("mode", "max_object_size_m", "dh_m", "slope", "outline_slope", "wide_slope",
                             "wide_radius_m", "noise_m")}
    assert run["max_object_size_m"] == 17.0
    mask = morph.filter_morphological(z, 1.0, **run).mask
    assert np.count_nonzero(mask[dike > 0.5] != GROUND) < 0.015 * np.count_nonzero(dike > 0.5)


def _reached_by_dilations(seeds, within, steps):
    """:func:`morphology._reached`'s definition: ``steps`` 3 x 3 dilations of the seeds, each within ``within``."""
    reach = seeds & within
    for _ in range(steps):
        reach = morph.touching(reach) & within
    return reach


def test_reached_is_the_bounded_geodesic_dilation():
    # random masks of any shape (a row, a column, one cell), seeds on the border too, steps 0 to past convergence
    rng = np.random.default_rng(7)
    for shape in [(1, 1), (1, 9), (9, 1), (2, 2), (17, 23), (40, 31)]:
        for density in (0.3, 0.6, 0.9):
            within = rng.random(shape) < density
            seeds = rng.random(shape) < 0.05
            seeds[0, 0] = True
            for steps in (0, 1, 2, 3, 7, 60):
                np.testing.assert_array_equal(morph._reached(seeds, within, steps),
                                              _reached_by_dilations(seeds, within, steps))


def test_reached_grows_the_front_not_the_array(monkeypatch):
    """A path of some 900 cells winding through 60 x 60 cells, followed 500 steps: the whole array's dilations
    (one a step, 3600 cells each; _reached 0.16 -> 0.04 CPU s on the synthetic city of 4 Mcells at 0.5 m cells)
    are one dilation of it, then the front is followed, a cell a step; the same cells."""
    within = np.zeros((60, 60), bool)
    within[::4, :] = True                     # rows 0, 4, 8, ... joined at alternate ends: a serpentine
    for k, r in enumerate(range(0, 56, 4)):
        within[r:r + 5, 59 if k % 2 == 0 else 0] = True
    seeds = np.zeros_like(within)
    seeds[0, 0] = True
    cells = []
    real = morph.touching
    monkeypatch.setattr(morph, "touching", lambda a: cells.append(a.size) or real(a))
    got = morph._reached(seeds, within, 500)
    monkeypatch.setattr(morph, "touching", real)
    assert sum(cells) <= within.size
    np.testing.assert_array_equal(got, _reached_by_dilations(seeds, within, 500))
    assert 0 < got.sum() < within.sum()       # the reach is bounded: the path is longer than 500 steps


# --------------------------------------------------------------------------- the reference's slopes (issue 12)
def _raised_road(with_house=True):
    """A raised road across a level plain at 2 m cells (ISPRS sample 71's ramp: a crest 18 m wide, flanks falling
    1.5 m per cell to 6 m below, a grade of 1 %) and a house 20 x 20 m, 8 m high, that sizes a 30 m window: the
    window outgrows the road, so the last step's drop at its crest is its whole height (6 m against ``s r_k``
    = 4.2 m), and its own erosion holds no road to read a slope on."""
    i, j = np.mgrid[0:70, 0:120].astype(np.float32)
    road = np.clip(6.0 - 1.5 * np.maximum(np.abs(i - 20.0) - 4.0, 0.0), 0.0, None)
    z = 100.0 + road + 0.02 * j
    house = (i >= 45) & (i < 55) & (j >= 50) & (j < 60)
    z = np.where(house, z + 8.0, z).astype(np.float32) if with_house else z.astype(np.float32)
    return z, road > 0.01, house


def _road_run(z):
    return morph.filter_morphological(z, 2.0, mode="progressive", max_object_size_m=30.0, dh_m=0.5, slope=0.3)


def test_a_raised_road_narrower_than_the_window_keeps_its_crest():
    """The erosion the last step's drop is measured from (radius 3 cells) holds the road, and the slope of its
    flanks, read on its crest by the steeper side, continues along the road on cells no earlier step flagged:
    that slope passes the drop (away from the raster's left and right edges, where the lines are cut); the
    house stays an object."""
    z, road, house = _raised_road()
    mask = _road_run(z).mask
    inner = road.copy()
    inner[:, :16] = inner[:, -16:] = False
    assert np.count_nonzero(mask[inner] != GROUND) == 0
    assert np.all(mask[house] == OBJECT)


def test_the_raised_road_is_cut_without_the_reference_slopes(monkeypatch):
    """The failure the rule fixes: without the reference's slopes the road's crest is an object."""
    z, road, _ = _raised_road()
    monkeypatch.setattr(morph, "reference_slope", lambda *a, **k: None)
    mask = _road_run(z).mask
    assert np.count_nonzero(mask[road] == OBJECT) > 100


def test_the_reference_slopes_leave_out_the_cells_flagged_before(monkeypatch):
    """The reference's slopes on the cells the earlier steps flagged are no terrain's: with every cell held the
    crest is cut as without the rule."""
    z, road, _ = _raised_road()
    real = morph.reference_slope
    monkeypatch.setattr(morph, "reference_slope", lambda g, held, out: real(g, np.ones_like(held), out))
    mask = _road_run(z).mask
    assert np.count_nonzero(mask[road] == OBJECT) > 100


def test_blocks_equal_one_pass_on_a_raised_road():
    """The reference's slopes read the earlier flags along a line of the largest window: within the halo."""
    z, _, _ = _raised_road()
    z = np.tile(z, (2, 2))
    params = {"mode": "progressive", "max_object_size_m": 30.0, "dh_m": 0.5, "slope": 0.3}
    one = run_array("morphological", z, 2.0, params)
    blk = run_array("morphological", z, 2.0, params, block=48)
    assert blk.info["blocks"] > 4
    np.testing.assert_array_equal(blk.mask, one.mask)


def test_reference_slopes_off_cut_the_raised_road_as_before():
    """``reference_slopes=False`` (the dtm's member) is the filter without the rule: the crest is an object; the
    parameter reaches the result's info and the object-size search of the resolve."""
    z, road, _ = _raised_road()
    res = morph.filter_morphological(z, 2.0, mode="progressive", max_object_size_m=30.0, dh_m=0.5, slope=0.3,
                                     reference_slopes=False)
    assert np.count_nonzero(res.mask[road] == OBJECT) > 100 and res.info["reference_slopes"] is False
    assert morph.resolve_morphological_params(z, 2.0, reference_slopes=False)["reference_slopes"] is False
