"""Slope-profile filter (Ke 2002, sec. 2.1): tiny exact profiles, synthetic scenes, blocks."""
import numpy as np
import pytest
from scipy import ndimage

from bare_earth.core import slope_profile as sp
from bare_earth.core.codes import GROUND, LOW, NODATA, OBJECT
from bare_earth.core.pipeline import run_array

PARAMS = dict(slope_threshold_deg=30.0, terrain_slope_deg=8.0, tolerance_m=0.2, max_object_size_m=20.0,
              refine=False)


def profile(values, rows=3, pad=4):
    """A raster whose middle ``rows`` rows carry the profile, with ``pad`` rows of flat
    ground at height 0 above and below (so objects are finite in Y too)."""
    v = np.asarray(values, dtype=np.float32)
    z = np.zeros((rows + 2 * pad, v.size), np.float32)
    z[pad:pad + rows] = v
    return z


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int16])
def test_profile_slopes_exact(dtype):
    z = np.array([[0, 1, 1], [0, 0, 2]], dtype=dtype)
    ax, ay = sp.profile_slopes(z, (1.0, 2.0))
    np.testing.assert_allclose(ax, [[45.0, 0.0], [0.0, np.degrees(np.arctan(2.0))]])
    np.testing.assert_allclose(ay, [[0.0, np.degrees(np.arctan(-0.5)), np.degrees(np.arctan(0.5))]])


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int16])
def test_whole_roof_removed_not_only_edges(dtype):
    prof = [0] * 8 + [6] * 10 + [0] * 8        # a 10-cell flat roof 6 m high
    r = sp.filter_slope_profile(profile(prof, 5).astype(dtype), 1.0, **PARAMS)
    expect = np.array([GROUND] * 8 + [OBJECT] * 10 + [GROUND] * 8, np.uint8)
    for row in range(4, 9):
        np.testing.assert_array_equal(r.mask[row], expect)
    assert (r.mask[:4] == GROUND).all() and (r.mask[9:] == GROUND).all()


def test_object_at_profile_start_removed():
    prof = [5] * 6 + [0] * 20                  # the raster's edge cuts a roof
    r = sp.filter_slope_profile(profile(prof), 1.0, **PARAMS)
    np.testing.assert_array_equal(r.mask[5, :6], OBJECT)
    np.testing.assert_array_equal(r.mask[5, 6:], GROUND)


def test_ramp_and_terrace_kept():
    ramp = np.arange(30, dtype=np.float32) * 0.3            # 16.7 deg, below alpha_g
    r = sp.filter_slope_profile(profile(ramp), 1.0, **PARAMS)
    assert (r.mask == GROUND).all()
    terrace = np.tile(np.array([0.0] * 15 + [3.0] * 40, np.float32), (30, 1))  # a terrain step
    r = sp.filter_slope_profile(terrace, 1.0, **PARAMS)
    assert (r.mask[:, 15:] == GROUND).mean() > 0.9           # the scan coming down accepts it


def test_low_blunder_is_class_2_and_neighbours_ground():
    z = np.zeros((9, 9), np.float32)
    z[4, 4] = -5.0                                           # a drop then a rise
    r = sp.filter_slope_profile(z, 1.0, **PARAMS)
    assert r.mask[4, 4] == LOW
    assert (np.delete(r.mask.ravel(), 40) == GROUND).all()


def test_nodata_kept_and_gap_beside_building():
    z = np.zeros((20, 40), np.float32)
    z[:, 10:14] = np.nan                                     # a nodata gap...
    z[5:15, 14:24] = 8.0                                     # ...right before a building
    r = sp.filter_slope_profile(z, 1.0, **PARAMS)
    assert (r.mask[:, 10:14] == NODATA).all()
    assert (r.mask[5:15, 14:24] == OBJECT).all()
    assert (np.delete(r.mask[:5], np.s_[10:14], axis=1) == GROUND).all()


def test_bad_parameters_raise_clear_errors():
    z = np.zeros((5, 5), np.float32)
    with pytest.raises(ValueError, match="slope_threshold_deg"):
        sp.filter_slope_profile(z, 1.0, **dict(PARAMS, slope_threshold_deg=95))
    with pytest.raises(ValueError, match="tolerance_m"):
        sp.filter_slope_profile(z, 1.0, **dict(PARAMS, tolerance_m=-1))
    with pytest.raises(ValueError, match="cell_size"):
        sp.filter_slope_profile(z, 0.0, **PARAMS)
    with pytest.raises(ValueError, match="no valid cell"):
        sp.filter_slope_profile(np.full((5, 5), np.nan), 1.0, **PARAMS)


def test_resolve_derives_from_data():
    flat = np.random.default_rng(0).normal(0, 0.05, (200, 200)).astype(np.float32)
    p = sp.resolve_slope_profile_params(flat, 1.0)
    assert p["terrain_slope_deg"] < 1.0                      # flat ground: the measured slope
    assert p["slope_threshold_deg"] == pytest.approx(sp._MIN_ALPHA_G)   # the floor of alpha_g
    assert 0.15 <= p["tolerance_m"] <= 0.5
    assert p["tolerance_m"] == pytest.approx(3 * 0.05, rel=0.15)  # 3 x the 0.05 m noise
    yy, xx = np.mgrid[0:200, 0:200]
    steep = (0.5 * xx).astype(np.float32)                    # 26.6 deg slope
    p = sp.resolve_slope_profile_params(steep, 1.0)
    assert p["terrain_slope_deg"] == pytest.approx(26.57, abs=0.5)
    assert p["slope_threshold_deg"] == pytest.approx(45.0, abs=1.0)   # tan alpha_g = 2 x 0.5
    p = sp.resolve_slope_profile_params(steep, 1.0, slope_threshold_deg=40.0)
    assert p["slope_threshold_deg"] == 40.0                  # a user value wins


def test_city_scene_whole_roofs_removed_and_type2_low():
    from bare_earth.core.evaluate import compare_masks
    from bare_earth.core.synthetic import make_scene
    sc = make_scene("city", shape=(300, 300), seed=3)
    res = run_array("slopeprofile", sc.dsm, sc.cell_size)
    r = compare_masks(res.mask, sc.mask)
    assert r["type2"] < 10.0, r
    assert r["type1"] < 5.0, r
    buildings = [o for o in sc.objects if o["kind"] == "building"]
    assert buildings
    for o in buildings:
        r0, c0, r1, c1 = o["bbox"]
        inside = sc.mask[r0:r1, c0:c1] == OBJECT
        removed = res.mask[r0:r1, c0:c1][inside] != GROUND
        assert removed.mean() > 0.95, o                     # whole roofs, not edges


def test_tiny_raster():
    z = np.array([[0, 0, 0], [0, 9, 0], [0, 0, 0]], np.float32)
    res = run_array("slopeprofile", z, 1.0)
    assert res.mask.shape == (3, 3)
    assert np.isfinite(res.dtm).all()


def test_sample_spacing_of_nearest_filled_grid():
    rng = np.random.default_rng(1)
    dense = rng.normal(0, 1, (100, 100)).astype(np.float32)
    assert sp.estimate_sample_spacing(dense) == pytest.approx(1.0, abs=0.01)
    blocky = np.repeat(np.repeat(dense[:25, :25], 4, axis=0), 4, axis=1)   # each value over 4 x 4 cells
    assert sp.estimate_sample_spacing(blocky) == pytest.approx(4.0, rel=0.05)


def test_embankment_along_a_profile_kept_building_removed():
    z = np.zeros((80, 120), np.float32)
    z[30:40, :] = 4.0                                       # an embankment along X, 10 m wide
    z[30:40, :][:, np.r_[0:5, 115:120]] = 0.0               # ...cut at the raster's edges
    z[60:72, 50:62] = 8.0                                   # a building
    r = sp.filter_slope_profile(z, 1.0, **PARAMS)
    assert (r.mask[31:39, 20:100] == GROUND).mean() > 0.95  # X profiles run along it
    assert (r.mask[60:72, 50:62] == OBJECT).all()


def test_core_enforces_the_param_limits():
    """The dialog's bounds (PARAMS) are the core's: just inside passes, just outside fails."""
    z = profile([0] * 8 + [6] * 10 + [0] * 8)
    spec = {p.name: p for p in sp.PARAMS}
    assert spec["slope_threshold_deg"].minimum == 0.5 and spec["slope_threshold_deg"].maximum == 89.0
    for name, bad in (("slope_threshold_deg", 0.4), ("slope_threshold_deg", 89.5), ("terrain_slope_deg", 80.5),
                      ("tolerance_m", 50.5), ("max_object_size_m", 0.5), ("sample_spacing_cells", 0.5)):
        with pytest.raises(ValueError, match=rf"{name} = .* is out of range \["):
            sp.filter_slope_profile(z, 1.0, **dict(PARAMS, **{name: bad}))
        with pytest.raises(ValueError, match=name):
            sp.resolve_slope_profile_params(z, 1.0, **{name: bad})
    for name in ("slope_threshold_deg", "terrain_slope_deg", "tolerance_m", "max_object_size_m"):
        for edge in (spec[name].minimum, spec[name].maximum):
            sp.filter_slope_profile(z, 1.0, **dict(PARAMS, **{name: edge}))      # the bounds are valid


@pytest.mark.parametrize("shape,ry,rx", [((7, 9), 1, 2), ((5, 4), 3, 0), ((6, 6), 10, 10), ((1, 8), 0, 3)])
def test_box_sum_exact(shape, ry, rx):
    a = np.random.default_rng(4).integers(-3, 9, shape).astype(np.int32)
    expect = np.array([[a[max(0, i - ry):i + ry + 1, max(0, j - rx):j + rx + 1].sum() for j in range(shape[1])]
                       for i in range(shape[0])])
    np.testing.assert_array_equal(sp._box_sum(a.copy(), ry, rx), expect)


def test_building_touching_a_long_dam_is_an_object_blocked_or_not():
    """#15 defect 4: the share of both-axes rejections was taken over a whole connected
    region, so a building touching a dam longer than the halo was ground in one pass and
    an object in blocks. Regions larger than the largest object share locally now."""
    z = np.zeros((200, 600), np.float32)
    z[100:110, 40:560] = 5.0                 # a dam along X: Y profiles reject it, X ones do not
    z[80:100, 300:316] = 8.0                 # a building touching it
    params = dict(PARAMS)
    one = run_array("slopeprofile", z, 1.0, params)
    blocked = run_array("slopeprofile", z, 1.0, params, block=64)
    assert (one.mask[80:100, 300:316] == OBJECT).all()
    assert (one.mask[100:110, 40:200] == GROUND).all() and (one.mask[100:110, 420:560] == GROUND).all()
    np.testing.assert_array_equal(blocked.mask, one.mask)


def test_dam_with_trees_on_it_is_ground_trees_and_building_objects_blocked_or_not():
    """Issue 12 (synthetic breakline row 4.8 %, ISPRS sample 71's ramps): trees on a dam
    are rejected by both axes, and gave the dam around them the local share of both-axes
    rejections, so the whole dam was an object. The dam's run rejected by one axis only is
    longer than any object turned in the grid: ground; the trees and a building touching
    the dam stay objects, in one pass and in blocks."""
    z = np.zeros((200, 600), np.float32)
    z[100:110, 40:560] = 5.0                 # a dam along X: Y profiles reject it, X ones do not
    trees = np.zeros(z.shape, bool)
    for c in range(60, 540, 8):              # 4 x 4 m crowns 6 m high, a fifth of the crest
        trees[103:107, c:c + 4] = True
    z[trees] += 6.0
    z[80:100, 300:316] = 8.0                 # a building touching it
    params = dict(PARAMS)
    one = run_array("slopeprofile", z, 1.0, params)
    blocked = run_array("slopeprofile", z, 1.0, params, block=64)
    dam = np.zeros(z.shape, bool)
    dam[100:110, 40:560] = True
    dam &= ~ndimage.binary_dilation(trees, iterations=1)
    dam[:, 290:326] = False                  # beside the building
    assert (one.mask[dam] == GROUND).mean() > 0.98
    assert (one.mask[trees] == OBJECT).mean() > 0.95
    assert (one.mask[80:100, 300:316] == OBJECT).all()
    np.testing.assert_array_equal(blocked.mask, one.mask)


@pytest.mark.parametrize("edge", [1, 3])
def test_scan_of_sources_of_unequal_lengths_equals_each_source_alone(edge):
    # one scan over profile sets of different lengths (the short ones first, last and in
    # the middle: the steps shrink to the running ones) gives what each set gives alone
    rng = np.random.default_rng(2)
    long_ = np.cumsum(rng.normal(0, 0.3, (57, 9)), axis=0).astype(np.float32)
    long_[20:31, 3:6] += 6.0                                   # objects
    long_[rng.random(long_.shape) < 0.05] = np.nan
    short = np.cumsum(rng.normal(0, 0.3, (23, 12)), axis=0).astype(np.float32)
    short[8:14, :4] += 4.0
    mid = np.cumsum(rng.normal(0, 0.3, (40, 5)), axis=0).astype(np.float32)
    args = (1.0, np.tan(np.radians(30)), np.tan(np.radians(8)), 0.2, 4, edge)
    for sources in ([(long_, False), (long_, True), (short, False), (short, True)],
                    [(short, False), (long_, True), (mid, False), (short, True)]):
        together = sp._scan(sources, *args)
        for src, got in zip(sources, together):
            np.testing.assert_array_equal(got, sp._scan([src], *args)[0])
        assert any(r.any() for r in together)


def _scan1(values, tan_g, tan_t, dh0, init_cells=1, edge_cells=1):
    """One profile scanned forwards alone: its rejections as a list of bools."""
    a = np.asarray(values, np.float32)[:, None]
    return sp._scan([(a, False)], 1.0, tan_g, tan_t, dh0, init_cells, edge_cells)[0][:, 0].tolist()


def test_scan_tolerance_is_the_larger_of_edge_and_terrain_rise_not_their_sum():
    # tan_g 0.5, tan_t 0.1, dh0 0, level ground: d cells after the reference (0 at index 1)
    # the tolerance is max(0.5 - 0.1, 0.1 d) (the edge's margin over the level ground's
    # continuation, alpha_g - alpha_t). After the 3 m step, 0.45 (d = 2) and 0.55 (d = 3)
    # are above 0.4: rejected; 0.35 is ground again. The old rule added the two
    # (0.4 + 0.1 (d - 1): 0.5, 0.6) and accepted them.
    z = [0.0, 0.0, 3.0, 0.45, 0.55, 0.35, 0.5]
    assert _scan1(z, 0.5, 0.1, 0.0) == [False, False, True, True, True, False, False]
    # after a long object the terrain's rise takes over: 0.55 m at d = 6 is within 0.6
    assert _scan1([0.0, 0.0, 3, 3, 3, 3, 3, 0.55], 0.5, 0.1, 0.0) == [False, False] + [True] * 5 + [False]
    assert _scan1([0.0, 0.0, 3, 3, 3, 3, 3, 0.65], 0.5, 0.1, 0.0) == [False, False] + [True] * 6
    # an edge run of 2 cells: the paper's slope test 0.5 per cell over it (1.0 m at d = 2)
    assert _scan1(z, 0.5, 0.1, 0.0, edge_cells=2) == [False, False, True, False, False, False, False]
    # dh0 is added to every test: with 0.2 m, 0.45 is within 0.2 + 0.4
    assert _scan1(z, 0.5, 0.1, 0.2) == [False, False, True, False, False, False, False]
    # right after an accepted cell the test is the edge's: 0.55 <= 0.2 + 0.5 - 0.1 from the
    # level 0.0; 1.5 is not (0.95 above 0.55, the ground rising: 0.2 + 0.5)
    assert _scan1([0.0, 0.0, 0.55, 1.5], 0.5, 0.1, 0.2) == [False, False, False, True]


def test_scan_coming_down_off_an_object_reaches_the_ground_at_the_bottom_of_the_descent():
    # tan_g 0.5, tan_t 0.1, dh0 0: after 12 cells of roof the terrain's rise allows 1.2 m,
    # so the wall's foot 1.0 m high (a mixed cell) was taken as the ground; it lies 1.0 m
    # above the next cell, a step steeper than alpha_g: still on the way down, rejected
    roof = [0.0, 0.0] + [3.0] * 12
    assert _scan1(roof + [1.0, 0.0, 0.0], 0.5, 0.1, 0.0) == [False, False] + [True] * 13 + [False, False]
    # ground going on down at a slope below alpha_g (0.4 per cell) is the ground: accepted
    assert _scan1(roof + [1.0, 0.6, 0.2], 0.5, 0.1, 0.0) == [False, False] + [True] * 12 + [False] * 3
    # only a re-entry is held: ground at the top of a terrain step stays ground
    assert _scan1([0.0, 0.0, 0.0, 0.35, -1.5, -1.5], 0.5, 0.1, 0.0) == [False] * 6
    # a profile's last cell has no next one: the foot is accepted as before
    assert _scan1(roof + [1.0], 0.5, 0.1, 0.0) == [False, False] + [True] * 12 + [False]


def test_wall_foot_of_mixed_cells_is_part_of_the_building():
    """opengeos (issue 12): the cells at a wall's foot, half on the wall (0.6-1.5 m above the
    ground), were ground: the scan coming off the roof accepted them by the terrain's rise
    over the roof's length, the scan along the wall's foot by its rise over the foot's.
    A building 20 m square and 6 m high ringed by foot cells 1.0 m high: all of it is an
    object but for the ring's four corners (profiles along the foot take it as ground by
    the terrain's rise, and at a corner none comes off the roof), the ground around stays
    ground."""
    z = np.zeros((60, 60), np.float32)
    z[19:41, 19:41] = 1.0                  # the ring of foot cells
    z[20:40, 20:40] = 6.0                  # the roof
    p = dict(PARAMS, max_object_size_m=30.0)
    r = sp.filter_slope_profile(z, 1.0, **p)
    building = r.mask[19:41, 19:41] == OBJECT
    assert not building[::21, ::21].any()
    building[::21, ::21] = True
    assert building.all()
    ground = np.ones(z.shape, bool)
    ground[19:41, 19:41] = False
    assert (r.mask[ground] == GROUND).all()


def test_scan_edge_test_along_the_ground_fall_before_the_reference():
    # tan_g 0.6, tan_t 0.2, dh0 0: ground falling 0.2 m a cell, then a cell 0.25 m above the
    # last ground: 0.45 above the ground's continuation, more than the edge's margin over it
    # (0.6 - 0.2): rejected (it was accepted from the last ground's level); 0.15 above it
    # (0.35 above the continuation) is not
    assert _scan1([1.0, 0.8, 0.6, 0.4, 0.65], 0.6, 0.2, 0.0) == [False] * 4 + [True]
    assert _scan1([1.0, 0.8, 0.6, 0.4, 0.55], 0.6, 0.2, 0.0) == [False] * 5
    # going up the slope at tan_t nothing changes: 0.55 above the last ground is within 0.6
    assert _scan1([0.0, 0.2, 0.4, 0.6, 1.15], 0.6, 0.2, 0.0) == [False] * 5
    # the fall is the ground's own (0.1 a cell: 0.35 rejected, 0.25 not) ...
    assert _scan1([0.3, 0.2, 0.1, 0.0, 0.35], 0.6, 0.2, 0.0) == [False] * 4 + [True]
    assert _scan1([0.3, 0.2, 0.1, 0.0, 0.25], 0.6, 0.2, 0.0) == [False] * 5
    # ... at most the terrain's slope (1 m a cell taken as 0.2), and the terrain's rise from
    # the reference stays allowed: the far side of a valley rising at tan_t is ground
    assert _scan1([3.0, 2.0, 1.0, 0.0, 0.25], 0.6, 0.2, 0.0) == [False] * 4 + [True]
    assert _scan1([3.0, 2.0, 1.0, 0.0, 0.2], 0.6, 0.2, 0.0) == [False] * 5
    assert _scan1([0.8, 0.5, 0.25, 0.0, 0.3], 0.3, 0.3, 0.0) == [False] * 5


def test_scan_edge_margin_over_the_ground_trend_level_ground():
    """The ground's part of the edge's allowance is its own trend before the reference, not
    the terrain's slope wherever it did not fall: along a contour of a hillside (level ground)
    a crown's edge must rise alpha_g - alpha_t above the level, where the ground rising at
    alpha_t gives alpha_g above the last ground (ISPRS samp11: shrubs 0.5-1 m high on 21-30
    degree slopes were accepted by the profiles along the contours)."""
    # tan_g 0.6, tan_t 0.2, dh0 0: 0.5 m above level ground is more than 0.6 - 0.2 (the old
    # rule allowed 0.6 from any ground that did not fall) ...
    assert _scan1([0.0, 0.0, 0.0, 0.0, 0.5], 0.6, 0.2, 0.0) == [False] * 4 + [True]
    assert _scan1([0.0, 0.0, 0.0, 0.0, 0.4], 0.6, 0.2, 0.0) == [False] * 5
    # ... and is within it above ground rising at tan_t (0.2 a cell)
    assert _scan1([0.0, 0.2, 0.4, 0.6, 1.1], 0.6, 0.2, 0.0) == [False] * 5
    # ground rising faster (0.3 a cell) counts as tan_t: 0.65 above it is not within 0.6
    assert _scan1([0.0, 0.3, 0.6, 0.9, 1.55], 0.6, 0.2, 0.0) == [False] * 4 + [True]
    # the terrain's rise from the reference stays the floor: alpha_g below alpha_t (a user's
    # value) still accepts the terrain's slope over a cell
    assert _scan1([0.0, 0.0, 0.0, 0.0, 0.2], 0.1, 0.2, 0.0) == [False] * 5
    # the edge keeps at least the ground's micro-relief (5 degrees, the derived alpha_g's
    # floor) over level ground: tan_g 0.15, tan_t 0.05 leave 0.1 (0.09 accepted, 0.11 not) ...
    micro = float(np.tan(np.radians(5.0)))
    assert _scan1([0.0, 0.0, 0.0, 0.0, 0.09], 0.15, 0.05, 0.0) == [False] * 5
    assert _scan1([0.0, 0.0, 0.0, 0.0, 0.11], 0.15, 0.05, 0.0) == [False] * 4 + [True]
    # ... and alpha_g at that floor keeps all of it (0.08 of 0.0875 accepted, not 0.0875 - 0.05)
    assert _scan1([0.0, 0.0, 0.0, 0.0, 0.08], micro, 0.05, 0.0) == [False] * 5
    assert _scan1([0.0, 0.0, 0.0, 0.0, 0.095], micro, 0.05, 0.0) == [False] * 4 + [True]


def hillside_scene(cell, extent_m=160.0, deg=32.0, seed=3, noise_m=0.05):
    """A hillside falling ``deg`` degrees along Y with 60 flat-topped crowns 1.5-4 m high,
    2-4 m in radius (shrubs and small trees), the same landscape at any cell size. Returns
    (dsm, ground, crown heights)."""
    n = int(round(extent_m / cell))
    rng = np.random.default_rng(seed)
    c = (np.arange(n) + 0.5) * cell
    xx, yy = np.meshgrid(c, c)
    ground = 500.0 - np.tan(np.radians(deg)) * yy
    top = np.zeros((n, n))
    k = 60
    cx, cy = rng.uniform(10, extent_m - 10, k), rng.uniform(10, extent_m - 10, k)
    r, h = rng.uniform(2.0, 4.0, k), rng.uniform(1.5, 4.0, k)
    for i in range(k):
        d2 = (xx - cx[i]) ** 2 + (yy - cy[i]) ** 2
        np.maximum(top, np.where(d2 < r[i] ** 2, h[i], 0.0), out=top)
    noise = np.clip(rng.normal(0.0, 1.0, (n, n)), -4.0, 4.0) * noise_m
    return (ground + top + noise).astype(np.float32), ground, top


@pytest.mark.parametrize("cell, share", [(1.0, 0.9), (2.0, 0.5)])
def test_crowns_on_a_32_degree_hillside_are_objects_with_the_defaults(cell, share):
    """ISPRS samp11 (issue 12): on a steep hillside the scan coming down the slope compared
    a crown's rise with the level of the ground before it, lower by the hillside's fall over
    a cell (1.25 m at 2 m cells of a 32 degree hill), and both scans must reject: 84 % (1 m)
    and 4 % (2 m) of these crowns were objects, 94 % and 53 % with the edge test along the
    ground's fall. The hillside stays ground."""
    z, ground, top = hillside_scene(cell)
    res = run_array("slopeprofile", z, cell, {})
    obj = res.mask == OBJECT
    assert obj[top > 0].mean() >= share
    assert not obj[top == 0].any()
    assert res.info["params"]["terrain_slope_deg"] == pytest.approx(32.0, abs=1.0)


def test_scan_start_minimum_is_the_reference_mirrored_before_the_first_cell():
    # ground sloping down into the profile, 0.3 m per cell (tan_t 0.3): the start window's
    # minimum lies m = 3 cells in, taken as 3 cells before the first cell: 0.8 m there is
    # within dh0 + 3 x 0.3 = 0.9 m of it, so the slope is ground (the old start, 0.3 m of
    # tolerance at the first cell, rejected 0.8)
    assert _scan1([0.8, 0.5, 0.25, 0.0, 0.1], 0.3, 0.3, 0.0, init_cells=4) == [False] * 5
    # an object cut by the raster's edge stays rejected: 2 m at 2 and 1 cells from the
    # start minimum (2 cells in) is far above 0.1 m per cell
    assert _scan1([2.0, 2.0, 0.0, 0.0, 0.0], 0.5, 0.1, 0.1, init_cells=4) == [True, True, False, False, False]


@pytest.mark.parametrize("median, p75, expected", [
    (np.tan(np.radians(1.0)), np.tan(np.radians(3.0)), 3.0),     # raised to the upper quartile
    (np.tan(np.radians(1.0)), np.tan(np.radians(30.0)), 8.0),    # ... at most 8 deg
    (np.tan(np.radians(20.0)), np.tan(np.radians(30.0)), 20.0),  # never below the median
    (0.0, 0.0, 0.0),                                             # no floor
])
def test_derive_terrain_slope_exact(median, p75, expected):
    got = sp.derive_terrain_slope({"median": median, "p75": p75, "p90": p75, "block_cells": 20})
    assert got == pytest.approx(expected, abs=1e-9)


def test_tolerance_is_the_noise_not_where_the_heights_lie_on_a_slope():
    """Issue 12, ISPRS sample 11: lowest points of 1 m cells on ground rising 0.4 m per
    metre lie anywhere in their cell, so the heights scatter by 0.4 / sqrt(12) = 0.115 m
    about the plane besides their 0.03 m noise. The scans' slope allowance covers that
    part; taken as noise it raised dh0 to 3 x 0.12 = 0.36 m (samp11: 0.46 m) and let low
    objects on slopes pass. dh0 is 3 x what is left of the spread once that part is
    removed (0.18 m: the ground-level estimate reads 0.130 m for 0.119 m)."""
    rng = np.random.default_rng(1)
    yy, xx = np.mgrid[0:200, 0:200]
    z = (0.4 * (xx + rng.uniform(-0.5, 0.5, xx.shape)) + rng.normal(0, 0.03, xx.shape)).astype(np.float32)
    spread = sp.noise_ground_level(z, (1.0, 1.0))["sigma"]
    assert spread == pytest.approx(np.hypot(0.03, 0.4 / np.sqrt(12)), rel=0.2)   # what was taken as noise
    p = sp.resolve_slope_profile_params(z, 1.0)
    assert 3.0 * spread > 0.35                                                   # the former dh0
    assert 0.15 <= p["tolerance_m"] <= 0.2


def test_tolerance_is_the_sensors_noise_where_low_vegetation_covers_most_of_the_ground(monkeypatch):
    """Issue 12, ISPRS sample 11 at 2 m highest point: low vegetation (0.6-1.5 m, within the ground-level
    band) on 60 % of two thirds of a hillside's cells makes the ground-level second differences the
    vegetation's roughness (0.24 m for 0.1 m of noise), and dh0 = 3 x that hit its 0.5 m cap: the scans
    accepted most of the vegetation. The noise is the sensor's, read on the cleanest quarter of the tiles
    (``sigma_cleanest``, :func:`~bare_earth.core.estimate.sensor_noise`): dh0 falls to 3 x 0.1 m less the
    sampling's spread, and most of the vegetation is rejected."""
    from bare_earth.core import estimate as est
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:192, 0:192]
    z = 0.3 * x + 0.1 * y + rng.normal(0.0, 0.1, x.shape)
    veg = (rng.random(x.shape) < 0.6) & (x < 128)
    z[veg] += rng.uniform(0.6, 1.5, np.count_nonzero(veg))
    z = z.astype(np.float32)
    gn = est.noise_ground_level(z, (1.0, 1.0))
    assert gn["sigma_cleanest"] == pytest.approx(0.1, rel=0.1) and gn["sigma"] > 2.0 * gn["sigma_cleanest"]
    p = sp.resolve_slope_profile_params(z, 1.0)
    assert p["tolerance_m"] < 0.2
    res = run_array("slopeprofile", z, (1.0, 1.0), {})
    assert np.mean(res.mask[veg] == GROUND) < 0.3 and np.mean(res.mask[~veg] != GROUND) < 0.01
    # the whole window's spread as the noise (the tiles not ranked): dh0 at its cap, the vegetation ground
    real = est._noise_ground_level
    monkeypatch.setattr(est, "_noise_ground_level", lambda *a: {**real(*a), "sigma_cleanest": float("nan")})
    whole = run_array("slopeprofile", z, (1.0, 1.0), {})
    assert whole.info["params"]["tolerance_m"] == 0.5 and np.mean(whole.mask[veg] == GROUND) > 0.8


@pytest.mark.parametrize("alpha_t, expected", [
    (0.0, sp._MIN_ALPHA_G), (2.0, 5.0), (5.0, np.degrees(np.arctan(2 * np.tan(np.radians(5.0))))),
    (21.8014, 38.6598), (45.0, 60.0)])
def test_derive_slope_threshold_doubles_rise_over_run(alpha_t, expected):
    assert sp.derive_slope_threshold(alpha_t) == pytest.approx(expected, abs=1e-3)


def test_shrub_on_steep_slope_is_an_object_with_the_derived_threshold():
    """Issue 12, ISPRS sample 11: ground rising 0.4 m per metre (21.8 deg) across the X
    profiles with a shrub 1.5 m high, one cell by three along the contour. Coming down the
    slope, the shrub stands 1.5 - 0.4 = 1.1 m above the ground before it: rejected with
    tan alpha_g = 2 x 0.4 (1.0 m with dh0 0.2 m), accepted with alpha_g = twice the angle
    (43.6 deg, 1.15 m), so the X profiles kept it and, rejected by one axis only, the
    connected object went back to the ground."""
    yy, xx = np.mgrid[0:40, 0:40]
    ground = (0.4 * xx).astype(np.float32)
    z = ground.copy()
    z[19:22, 20] += 1.5
    alpha_t = float(np.degrees(np.arctan(0.4)))
    kw = dict(terrain_slope_deg=alpha_t, tolerance_m=0.2, max_object_size_m=20.0)
    new = sp.filter_slope_profile(z, 1.0, slope_threshold_deg=sp.derive_slope_threshold(alpha_t), **kw)
    assert np.all(new.mask[19:22, 20] == OBJECT)
    assert np.count_nonzero(new.mask == OBJECT) == 3
    # twice the angle (43.6 deg, 1.15 m) accepted it from the ground's level before it; the
    # edge test along the ground's fall (0.4 m a cell) now sees it 1.5 m above the hillside
    old = sp.filter_slope_profile(z, 1.0, slope_threshold_deg=2 * alpha_t, **kw)
    assert np.count_nonzero(old.mask == OBJECT) == 3


def shrub_scene(extent_m, cell, seed=0, noise_m=0.05):
    """Shrubs 1-3 m high over gentle ground (the opengeos failure of issue 12), the same
    landscape at any cell size: ground rising 2 % in x and 1 % in y with a 1 m undulation;
    about 30 % covered by domes ``h (1 - d^2)`` of radius 2.5-6 m (rounded: their edges rise
    gently, less than 1 m per 2 m cell). Returns (dsm, ground, shrub heights)."""
    n = int(round(extent_m / cell))
    rng = np.random.default_rng(seed)
    x = (np.arange(n) + 0.5) * cell
    xx, yy = np.meshgrid(x, x[::-1])
    ground = 300.0 + 0.02 * xx + 0.01 * yy + np.sin(xx / 70.0) * np.cos(yy / 90.0)
    k = int(extent_m * extent_m * 0.3 / (np.pi * 16.0))
    cx, cy = rng.uniform(0, extent_m, k), rng.uniform(0, extent_m, k)
    r, h = rng.uniform(2.5, 6.0, k), rng.uniform(1.0, 3.0, k)
    top = np.zeros((n, n))
    for i in range(k):
        d2 = ((xx - cx[i]) ** 2 + (yy - cy[i]) ** 2) / r[i] ** 2
        np.maximum(top, np.where(d2 < 1.0, h[i] * (1.0 - d2), 0.0), out=top)
    noise = np.clip(rng.normal(0.0, 1.0, (n, n)), -4.5, 4.5) * noise_m
    return (ground + top + noise).astype(np.float32), ground, top


@pytest.mark.parametrize("cell", [2.0, 4.0])
def test_shrubs_over_gentle_ground_are_objects_with_the_defaults(cell):
    # the old defaults (alpha_g 25, alpha_t 8 deg floors) kept 92 % (2 m) and 100 % (4 m)
    # of these shrubs as ground, DTM RMSE 0.63 / 0.68 m
    z, ground, top = shrub_scene(256.0, cell)
    res = run_array("slopeprofile", z, cell, {})
    obj = res.mask == OBJECT
    assert obj[top > 0.5].mean() >= 0.75
    assert (~obj[top == 0]).mean() >= 0.98
    assert np.sqrt(np.mean((res.dtm - ground) ** 2)) < 0.3
    p = res.info["params"]
    assert p["slope_threshold_deg"] < 15.0 and p["terrain_slope_deg"] < 5.0


def test_shrub_defaults_agree_from_0_5_to_4_m():
    got = [sp.resolve_slope_profile_params(shrub_scene(256.0, c)[0], c) for c in (0.5, 1.0, 2.0, 4.0)]
    for key in ("terrain_slope_deg", "slope_threshold_deg"):
        v = np.array([p[key] for p in got])
        assert v.max() / v.min() <= 1.2, (key, v)


def _runs1(values, tan_g, tan_t, dh0, init_cells):
    """One profile scanned forwards alone: the cells of its raised runs closed on the ground."""
    a = np.asarray(values, np.float32)[:, None]
    return sp._scan([(a, False)], 1.0, tan_g, tan_t, dh0, init_cells, 1, None, True)[1][0][:, 0].tolist()


def test_scan_raised_run_between_walls_down_to_the_ground_before_it():
    # tan_g 0.5, tan_t 0.1, dh0 0: after a wall 3 m up the terrain's rise accepts the roof
    # from d = 30 (3.0 <= 0.1 x 30) to its end: a raised run. A wall 3 m down (steeper than
    # any bank: more than max(tan_g, 1) per cell) closes it: the run is an object.
    roof = [0.0, 0.0] + [3.0] * 40
    plain = _scan1(roof + [0.0, 0.0], 0.5, 0.1, 0.0, init_cells=60)
    assert plain == [False, False] + [True] * 29 + [False] * 13       # the paper's rule alone
    runs = _runs1(roof + [0.0, 0.0], 0.5, 0.1, 0.0, 60)
    assert runs == [False] * 31 + [True] * 11 + [False, False]
    # the same level but no wall down: a terrace, no run closed
    assert not any(_runs1(roof, 0.5, 0.1, 0.0, 60))
    # a bank 0.75 m per cell (37 deg) down to the same level: terrain, no wall
    assert not any(_runs1(roof + [2.25, 1.5, 0.75, 0.0, 0.0], 0.5, 0.1, 0.0, 60))
    # a bank 0.75 m per cell up to the same roof: no wall up, no run
    assert not any(_runs1([0.0, 0.0, 0.75, 1.5, 2.25] + [3.0] * 40 + [0.0, 0.0], 0.5, 0.1, 0.0, 60))
    # a run longer than the largest object (init_cells 20): the ground rose, no object
    assert not any(_runs1(roof + [0.0, 0.0], 0.5, 0.1, 0.0, 20))


def test_wide_flat_roof_on_sloping_ground_is_an_object_plateau_larger_than_objects_ground():
    """synthetic-lidar/urban (2 m cells, issue 12): a flat roof 90 m wide, 6-9 m above ground
    falling 1.7 degrees under it, was ground in its middle: the terrain's rise of alpha_t = 8
    deg (0.28 m per cell) reached the roof from both sides. Closed by walls down to the ground it
    rose from, it is an object; a plateau between walls wider than the largest object stays
    ground, and so does the ground around."""
    n, cell = 120, 2.0
    x = np.arange(n, dtype=np.float32) * cell
    z = np.tile(100.0 - 0.03 * x, (n, 1)).astype(np.float32)          # 1.7 deg down along X
    z[30:75, 30:75] = 104.2                                           # the roof, 90 m square
    p = dict(PARAMS, slope_threshold_deg=15.7, terrain_slope_deg=8.0, tolerance_m=0.15,
             max_object_size_m=100.0)
    r = sp.filter_slope_profile(z, cell, **p)
    assert (r.mask[30:75, 30:75] == OBJECT).all()
    ground = np.ones(z.shape, bool)
    ground[29:76, 29:76] = False
    assert (r.mask[ground] == GROUND).all()
    wide = np.tile(100.0 - 0.03 * x, (n, 1)).astype(np.float32)
    wide[:, 20:100] += 6.0                                            # 160 m between walls
    r = sp.filter_slope_profile(wide, cell, **dict(p, max_object_size_m=60.0))
    assert (r.mask[:, 20:100] == GROUND).mean() > 0.95


def test_wide_flat_roof_touching_a_long_row_of_trees_is_an_object():
    """The raised runs' extent is their own, not that of the objects they touch: the wide
    roof of the test above with a chain of tree crowns (rejected by both axes) running from
    it across the raster was ground in its middle (10 % of the roof an object), the roof's
    raised runs and the crowns making one region longer than the largest object (ISPRS
    samp31, 1 m lowest: 3.37 -> 1.99 % total error)."""
    n, cell = 120, 2.0
    x = np.arange(n, dtype=np.float32) * cell
    z = np.tile(100.0 - 0.03 * x, (n, 1)).astype(np.float32)
    z[30:75, 30:75] = 104.2                                           # the roof, 90 m square
    trees = np.zeros(z.shape, bool)
    for k in range(n // 3):                                           # crowns touching at corners
        trees[75 + 3 * (k % 2):78 + 3 * (k % 2), 3 * k:3 * k + 3] = True
    z[trees] += 5.0
    p = dict(PARAMS, slope_threshold_deg=15.7, terrain_slope_deg=8.0, tolerance_m=0.15,
             max_object_size_m=100.0)
    r = sp.filter_slope_profile(z, cell, **p)
    assert (r.mask[30:75, 30:75] == OBJECT).all()
    assert (r.mask[trees] == OBJECT).all()
    ground = np.ones(z.shape, bool)
    ground[29:76, 29:76] = False
    ground &= ~trees
    assert (r.mask[ground] == GROUND).all()


def test_walled_regions_need_walls_on_half_their_ground_edges():
    # a raised 2 x 2 region at 3 m: walled all round (8 edges drop 3 m) is kept
    z = np.zeros((6, 6), np.float32)
    z[2:4, 2:4] = 3.0
    raised = z > 1.0
    none = np.zeros(z.shape, bool)
    assert (sp._walled_regions(raised, none, z, (1.0, 1.0)) == raised).all()
    # the same level as the ground on its right (the two edges there are level, 2 of 8): kept
    z[2:4, 4:] = 3.0
    assert (sp._walled_regions(raised, none, z, (1.0, 1.0)) == raised).all()
    # level on its right and below (4 of 8 edges level, 4 walls): kept; below and beside too: not
    z[4:, 2:] = 3.0
    assert (sp._walled_regions(raised, none, z, (1.0, 1.0)) == raised).all()
    z[2:, :2] = 3.0
    assert not sp._walled_regions(raised, none, z, (1.0, 1.0)).any()
    # edges to objects do not count: a roof's middle among its rims is kept
    assert (sp._walled_regions(raised, ~raised, z, (1.0, 1.0)) == raised).all()
    # a drop of 1 m is no wall of 1 m, nor is a nodata neighbour ground
    z = np.zeros((6, 6), np.float32)
    z[2:4, 2:4] = 1.0
    z[4, 2:4] = np.nan
    assert not sp._walled_regions(z > 0.5, none, z, (1.0, 1.0)).any()


def test_level_ground_between_pits_and_a_roof_stays_ground():
    """ISPRS samp41 (1 m lowest, issue 12): profiles climbed out of multipath pits far below
    the ground (too wide for class 2), crossed level ground the terrain's rise accepted and
    dropped into another pit or came down off a roof: level ground read as a raised run
    between two walls. The level ground beside the pits goes on level into the ground: it
    stays ground, and the roof between the pits is still an object."""
    z = np.zeros((80, 80), np.float32)
    z[38:42, 20:24] = -2.5                          # two pits of 4 x 4 cells, 2.5 m deep
    z[38:42, 54:58] = -2.5
    z[30:50, 30:50] = 3.0                           # a roof between them
    p = dict(PARAMS, slope_threshold_deg=15.7, terrain_slope_deg=8.0, tolerance_m=0.15,
             max_object_size_m=40.0)
    r = sp.filter_slope_profile(z, 1.0, **p)
    assert (r.mask[30:50, 30:50] == OBJECT).all()
    ground = np.ones(z.shape, bool)
    ground[29:51, 29:51] = False                    # the roof and its wall's foot
    ground[37:43, 19:25] = ground[37:43, 53:59] = False   # the pits and their sides
    assert (r.mask[ground] == GROUND).all()


def test_joined_to_terrain_parts_mostly_ground():
    z = np.zeros((12, 12), np.float32)
    z[2:6, 2:6] = 3.0                               # a roof, walled all round
    z[7:10, 6:10] = 0.1                             # a level area 0.1 m above the ground
    roof = z > 1.0
    level = (z > 0.05) & (z < 1.0)
    valid = np.ones(z.shape, bool)
    walled = roof | level
    got = sp._joined_to_terrain(z, walled, walled, valid, 0.2)
    assert (got == level).all()                     # the level area's part is the terrain's
    # a roof with cells the scans missed (ground on it) is still its own part: not returned
    obj = walled.copy()
    obj[2:4, 2:4] = False
    assert (sp._joined_to_terrain(z, walled, obj, valid, 0.2) == level).all()
    # a step above step_m separates the parts
    assert not sp._joined_to_terrain(z, level, level, valid, 0.05).any()
    # half the part's cells objects: joined; more: not
    flat = np.zeros((4, 4), np.float32)
    half = np.zeros((4, 4), bool)
    half[:2] = True
    assert (sp._joined_to_terrain(flat, half, half, np.ones((4, 4), bool), 0.2) == half).all()
    more = half.copy()
    more[2, 0] = True
    assert not sp._joined_to_terrain(flat, half, more, np.ones((4, 4), bool), 0.2).any()


@pytest.mark.parametrize("gap", [6, 12])
def test_level_ground_inside_a_ring_of_pits_joined_to_the_ground_stays_ground(gap):
    """ISPRS samp41 (1 m lowest, issue 12): level ground enclosed by multipath pits far
    below the ground (too wide for class 2) read as a raised run between walls, walled on
    more than half its edges; it goes on level into the ground through the gaps between
    the pits (6.54 -> 3.89 % total error). A roof beside it stays an object."""
    z = np.zeros((100, 100), np.float32)
    z[27:73, 27:73] = -2.5                          # a ring of pits 3 cells wide, 2.5 m deep
    z[30:70, 30:70] = 0.0
    z[47:47 + gap, 27:30] = z[47:47 + gap, 70:73] = 0.0   # two gaps in the ring
    z[10:20, 80:90] = 3.0                           # a roof
    p = dict(PARAMS, slope_threshold_deg=15.7, terrain_slope_deg=8.0, tolerance_m=0.15,
             max_object_size_m=60.0)
    r = sp.filter_slope_profile(z, 1.0, **p)
    assert (r.mask[30:70, 30:70] == GROUND).all()
    assert (r.mask[10:20, 80:90] == OBJECT).all()


def test_ramps_join_the_ground_on_both_sides_along_the_accepting_axis():
    z = np.zeros((5, 8), np.float32)
    z[1:4, 2:6] = [0.1, 0.2, 0.2, 0.1]              # a ramp's crest along the rows
    one = z > 0.05
    ground = ~one
    assert (sp._ramps(z, one, one, ground, 0.15, 1) == one).all()
    assert not sp._ramps(z, one, one, ground, 0.05, 1).any()   # steps above step_m: no join
    assert (sp._ramps(z.T, one.T, one.T, ground.T, 0.15, 0) == one.T).all()   # along the columns
    z[1:4, 6] = 3.0                                  # a wall on its right: joined on one side only
    assert not sp._ramps(z, one, one, ground, 0.15, 1).any()
    assert not sp._ramps(z.T, one.T, one.T, ground.T, 0.15, 0).any()


def test_ramps_need_one_profile_from_the_ground_across_them_to_the_ground():
    """A region joined to the ground on its left along one row and on its right along
    another, walls at the other ends, is crossed by no profile from the ground to the
    ground (ISPRS samp11: crowns and roofs on a 20 degree hillside, where a step of the
    terrain's slope is up to 1.2 m at 2 m cells): no ramp. Objects inside a row's run
    (trees on the ramp) do not break it."""
    z = np.zeros((4, 8), np.float32)
    one = np.zeros(z.shape, bool)
    one[1, 2:4] = one[2, 4:6] = True                 # 8-connected through (1, 3) - (2, 4)
    z[one] = 0.1
    z[1, 4] = z[2, 3] = 3.0                          # walls: row 1 joins on the left only, row 2 on the right
    rejected = one | (z > 1.0)
    ground = ~rejected
    assert not sp._ramps(z, one, rejected, ground, 0.15, 1).any()
    assert not sp._ramps(z.T, one.T, rejected.T, ground.T, 0.15, 0).any()
    z[1, 4] = 0.1                                    # row 1 now runs from the ground across it to the ground
    one[1, 4] = True
    rejected = one | (z > 1.0)
    ground = ~rejected
    assert (sp._ramps(z, one, rejected, ground, 0.15, 1) == one).all()
    assert (sp._ramps(z.T, one.T, rejected.T, ground.T, 0.15, 0) == one.T).all()
    one[1, 3] = False                                # a tree on row 1's run, rejected by both axes
    z[1, 3] = 5.0
    assert sp._ramps(z, one, one | (z > 1.0), ~(one | (z > 1.0)), 0.15, 1)[1, 2]


def test_roofs_on_a_20_degree_hillside_are_objects_a_ramp_on_it_ground():
    """ISPRS samp11 (a steep urban hillside): a step of the terrain's slope is up to 1.2 m
    at 2 m cells there, and roofs joined the hillside through such steps. A ramp along the
    contour of a 20 degree hillside (up 2 m over 30 m and down, its flanks steps of 2 m) is
    ground; a flat L-shaped roof 4 m above the hillside's top under it and an L-shaped roof
    cut into the hillside (0.5 m above it at its uphill edge, walls down to it elsewhere)
    stay objects, but for the cut roof's uphill edge (within the tolerance of the hill);
    the hillside stays ground. A walled region is the terrain's only when it goes on level
    into the ground (steps within the tolerance), as between pits in level ground."""
    t = np.float32(np.tan(np.radians(20.0)))
    y, x = np.mgrid[0:160, 0:160].astype(np.float32)
    z = t * x
    z[:, 30:40] += np.clip(2.0 - np.abs(y[:, 30:40] - 80.0) / 15.0, 0, None)
    roof = np.zeros(z.shape, bool)
    roof[110:140, 60:80] = True
    roof[140:150, 60:70] = True
    z[roof] = t * 80 + 4.0
    cut = np.zeros(z.shape, bool)
    cut[20:50, 90:120] = True
    cut[50:70, 90:105] = True
    z[cut] = t * 120 + 0.5
    p = dict(PARAMS, slope_threshold_deg=float(sp.derive_slope_threshold(20.0)), terrain_slope_deg=20.0,
             tolerance_m=0.15, max_object_size_m=60.0)
    m = sp.filter_slope_profile(z, 1.0, **p).mask
    assert (m[:, 30:40] == GROUND).all()
    assert (m[roof] == OBJECT).all()
    assert (m[cut & (x < 119)] == OBJECT).all()
    assert (m[~roof & ~cut] == GROUND).all()


def test_ramp_beside_a_building_is_ground_the_buildings_objects():
    """ISPRS samp71 (issue 12): the ramps down from the bridge, rejected by the profiles across
    them (their flanks are walls) and accepted by those along them, touched trees and were
    kept as objects by the share of cells both axes reject (6.42 -> 4.28 % total error at 1 m
    lowest). Along the ramp the profiles run from the ground onto it and off it onto the
    ground at the terrain's slope: ground; the building against its flank stays an object."""
    z = np.zeros((160, 160), np.float32)
    x = np.arange(160, dtype=np.float32)
    z[60:80] = np.clip(4.0 - np.abs(x - 80.0) / 15.0, 0, None)   # up 4 m over 60 m and down
    z[80:105, 68:93] = 8.0                           # a building against its flank
    z[20:40, 100:120] = 3.0                          # a lone building
    p = dict(PARAMS, slope_threshold_deg=15.7, terrain_slope_deg=8.0, tolerance_m=0.15,
             max_object_size_m=60.0)
    r = sp.filter_slope_profile(z, 1.0, **p)
    assert (r.mask[60:80] == GROUND).all()
    assert (r.mask[80:105, 68:93] == OBJECT).all()
    assert (r.mask[20:40, 100:120] == OBJECT).all()


class _CountingNumpy:
    """numpy, counting the cells ``np.subtract(..., out=)`` writes (two per profile and step in
    :func:`slope_profile._scan`): the scan's work, not its time."""

    def __init__(self):
        self.cells = 0

    def __getattr__(self, name):
        return getattr(np, name)

    def subtract(self, a, b, out=None, **kw):
        if out is not None:
            self.cells += out.size
        return np.subtract(a, b, out=out, **kw)


def test_a_tall_strip_scans_its_short_profiles_once(monkeypatch):
    """A raster much taller than wide: the X profiles (one per row, a few cells long) end after a
    few steps, the Y profiles run on. They were scanned after the X profiles, and each of the Y
    profiles' steps worked on all the X profiles too (3 x 50000 cells: 134 s, against 1-5 s for the
    other filters); the same masks as the strip lying across (transposed)."""
    rng = np.random.default_rng(3)
    z = (100 + 0.01 * np.arange(3000, dtype=np.float32)[:, None] + rng.normal(0, 0.05, (3000, 3))).astype(np.float32)
    z[1500:1520, 1] += 10
    counting = _CountingNumpy()
    monkeypatch.setattr(sp, "np", counting)
    got = sp.scan_profiles(z, (1.0, 1.0), 0.1, 0.02, 0.15, (100, 100), (1, 1))
    work = counting.cells
    monkeypatch.setattr(sp, "np", np)
    assert work <= 20 * z.size                 # was 2 x 3000 steps x 6006 profiles = 4000 x the cells
    across = sp.scan_profiles(np.ascontiguousarray(z.T), (1.0, 1.0), 0.1, 0.02, 0.15, (100, 100), (1, 1))
    for a, b in zip(got, (across[1].T, across[0].T, across[3].T, across[2].T)):
        np.testing.assert_array_equal(a, b)
    assert got[1][1500:1520, 1].all()           # the block, along the strip


def _band(shape, half_width, bank_m, crest_m=3.0):
    """A level band ``|r - c| <= half_width`` at ``crest_m`` on flat ground 0, with banks
    one cell wide at ``bank_m`` on both sides (the band's cells: ``|r - c| <= half_width + 1``)."""
    r, c = np.indices(shape)
    d = np.abs(r - c)
    z = np.zeros(shape, np.float32)
    z[d == half_width + 1] = bank_m
    z[d <= half_width] = crest_m
    return z, d <= half_width, d <= half_width + 1


def test_long_levels_exact():
    """A level longer than the largest object turned in the grid (reach 9 -> 13 cells) ending
    on banks is released; ending on walls, shorter, or not level (steps above the tolerance),
    it is not."""
    z, crest, big = _band((24, 24), 1, 1.5)
    args = (0.2, (2.0, 2.0))
    # (the banks, one cell wide at one height along the band, are long levels too)
    np.testing.assert_array_equal(sp._long_levels(big, z, *args, reach=(9, 9)), big)
    np.testing.assert_array_equal(sp._long_levels(crest, z, *args, reach=(9, 9)), crest)
    # the same crest on walls: drops of 3 m > 2 m
    z, crest, big = _band((24, 24), 1, 0.0)
    assert not sp._long_levels(big, z, *args, reach=(9, 9)).any()
    # the crest with a bank on one side, walls on the other: half its steps down are walls,
    # its middle and its side along the walls are kept (the windows along the bank's side
    # hold more of that side: 14 walls of 32 steps down)
    z, crest, big = _band((24, 24), 1, 1.5)
    r, c = np.indices(z.shape)
    z[(r - c == 2)] = 0.0
    out = sp._long_levels(crest, z, *args, reach=(9, 9))
    assert not out[(r - c >= 0)].any() and out[(r - c == -1)][5:-5].all()
    # shorter than the turned object: bounding box 13 <= 13
    z, crest, big = _band((24, 24), 1, 1.5)
    short = np.zeros(z.shape, bool)
    short[:13, :13] = True
    assert not sp._long_levels(big & short, z, *args, reach=(9, 9)).any()
    # not level: steps of 0.5 m between every other row split the crest into parts of one row
    z, crest, big = _band((24, 24), 1, 1.5)
    z[crest & (r % 2 == 1)] += 0.5
    assert not sp._long_levels(crest, z, *args, reach=(9, 9)).any()


def _oblique_distance(shape, c0, r0, angle_deg=34.0):
    """Distance (cells) of every cell from the line through column ``c0``, row ``r0`` at
    ``angle_deg`` to X."""
    r, c = np.indices(shape).astype(np.float64)
    a = np.radians(angle_deg)
    return np.abs(-(c - c0) * np.sin(a) + (r - r0) * np.cos(a))


def _oblique_embankment(shape=(160, 240)):
    """Flat ground 0 crossed by a road embankment 4 m high at 34 degrees to X: a level crest
    8 m wide and banks of 1:1 (4 m wide on each side; 0.56 m per cell along X, 0.83 m along
    Y, steeper than the scans' 10 degrees and gentler than a wall)."""
    d = _oblique_distance(shape, 20, 10)
    z = np.clip(8.0 - d, 0.0, 4.0).astype(np.float32)
    return z, d <= 3.0


def test_oblique_embankment_crest_is_ground_roofs_and_a_long_hall_objects_blocked_or_not():
    """Issue 12 (opengeos, 2 m: a highway embankment crossing the tile obliquely was an
    object, both axes' profiles climbing its banks): its crest, a level longer than the
    largest object turned in the grid ending on banks, is ground; a building and a hall as
    long as the crest but walled stay objects, in one pass and in blocks."""
    z, crest = _oblique_embankment()
    z[120:136, 20:36] = 7.0                  # a building
    hall = (_oblique_distance(z.shape, 120, 10) <= 6.0) & (np.indices(z.shape)[1] >= 110)
    z[hall] = 6.0                            # a hall 12 m wide parallel to it, as long, walled
    params = dict(PARAMS, slope_threshold_deg=10.0, terrain_slope_deg=3.0)   # flat ground's
    one = run_array("slopeprofile", z, 1.0, params)
    assert (one.mask[crest] == GROUND).mean() > 0.95
    assert (one.mask[120:136, 20:36] == OBJECT).all()
    assert (one.mask[hall] == OBJECT).mean() > 0.99
    blocked = run_array("slopeprofile", z, 1.0, params, block=64)
    np.testing.assert_array_equal(blocked.mask, one.mask)


def test_banks_below_exact():
    """From a level (row 0) down a bank by steps between 8-neighbours each lower than the noise
    (0.2 m) and gentler than a wall (1 m along an axis, 0.2 + hypot(0.8, 0.8) m along a
    diagonal): reached; a cell level with the one before it (a bridge's deck going on from
    its ramp), one rising above it (a crown) and one below a wall's drop (a pit) are not, nor
    cells beyond ``steps`` or outside the candidates."""
    z = np.array([[4.0, 4.0, 4.0, 4.0, 4.0],
                  [4.0, 3.2, 6.0, 3.2, 3.2],
                  [2.4, 2.4, 2.4, -1.0, 2.4],
                  [1.6, 1.6, 1.6, 1.6, 1.6]], np.float32)
    level = np.zeros(z.shape, bool)
    level[0] = True
    cand = np.ones(z.shape, bool)
    got = sp._banks_below(level, cand, z, 0.2, (1.0, 1.0), steps=10)
    expect = np.array([[0, 0, 0, 0, 0],
                       [0, 1, 0, 1, 1],
                       [1, 1, 1, 0, 1],
                       [1, 1, 1, 1, 1]], bool)
    np.testing.assert_array_equal(got, expect)
    # (2, 2) down the diagonal from (1, 1), (2, 0) from (1, 1); row 3 three steps away
    got = sp._banks_below(level, cand, z, 0.2, (1.0, 1.0), steps=2)
    expect[3] = False
    np.testing.assert_array_equal(got, expect)
    # a wall of 0.7 m along the axes (0.2 + hypot(0.5, 0.5) = 0.91 m along the diagonals):
    # the steps of 0.8 m only down the diagonals
    got = sp._banks_below(level, cand, z, 0.2, (0.7, 0.7), steps=10)
    np.testing.assert_array_equal(got, [[0, 0, 0, 0, 0], [0, 1, 0, 1, 1], [1, 0, 1, 0, 1], [0, 1, 0, 1, 0]])
    cand[:, :2] = False
    assert not sp._banks_below(level, cand, z, 0.2, (1.0, 1.0), steps=10)[:, :2].any()
    # a shrub on a plane bank (0.5 m above it, 0.3 m below the cell above it) stands above the
    # line between its opposite neighbours in every direction: not reached, the bank round it is
    z = (4.0 - 0.8 * np.arange(6, dtype=np.float32))[:, None] * np.ones((1, 5), np.float32)
    z[3, 2] += 0.5
    got = sp._banks_below(level[:1].repeat(6, 0) & (np.arange(6)[:, None] == 0), np.ones(z.shape, bool), z,
                          0.2, (1.0, 1.0), steps=10)
    expect = np.ones(z.shape, bool)
    expect[0] = False
    expect[3, 2] = False
    np.testing.assert_array_equal(got, expect)


def test_oblique_embankment_banks_are_ground_a_crown_on_them_an_object_blocked_or_not():
    """Issue 12 (synthetic_bare ``levees``: dikes crossing the grid obliquely lost their banks,
    2.9-5.4 % of the ground at 0.5-4 m cells): both axes' profiles climb an oblique
    embankment's banks and reject them as an object's sides, but they go down from its crest
    (a long level ending on banks) by steps of a bank: ground. A crown standing on a bank
    rises above it and stays an object, as does a walled building beside it, in one pass and
    in blocks."""
    z, crest = _oblique_embankment()
    d = _oblique_distance(z.shape, 20, 10)
    banks = (d > 3.0) & (d < 7.5)
    r, c = np.indices(z.shape)
    z[120:136, 20:36] = 7.0                  # a building
    crown = (np.hypot(r - 63.0, c - 100.0) <= 2.5)
    assert banks[63, 100] or crest[63, 100]
    crown &= ~crest
    z[crown] = 7.5                           # a crown on the bank, 3.5 m above the crest
    banks &= ~crown & ~ndimage.binary_dilation(crown, iterations=1)
    params = dict(PARAMS, slope_threshold_deg=10.0, terrain_slope_deg=3.0)   # flat ground's
    one = run_array("slopeprofile", z, 1.0, params)
    assert (one.mask[crest] == GROUND).mean() > 0.95
    assert (one.mask[banks] == GROUND).mean() > 0.95
    assert (one.mask[crown] == OBJECT).all()
    assert (one.mask[120:136, 20:36] == OBJECT).all()
    blocked = run_array("slopeprofile", z, 1.0, params, block=64)
    np.testing.assert_array_equal(blocked.mask, one.mask)


def _plane_with_halls(wide):
    """A plane rising 2 % along x, 200 m at 1 m cells, with four halls 12 m high: 60 m wide (wider than
    the 20 m blocks of the terrain slope) or 8 m wide and 60 m long."""
    yy, xx = np.mgrid[0:200, 0:200].astype(np.float32)
    z = 100.0 + 0.02 * xx
    for r in (20, 120):
        for c in (20, 120):
            if wide:
                z[r:r + 60, c:c + 60] += 12.0
            else:
                z[r:r + 60, c + 26:c + 34] += 12.0
    return z


def test_terrain_slope_leaves_out_the_blocks_on_a_hall_wider_than_them():
    z = _plane_with_halls(True)
    whole = sp.estimate_terrain_slope(z, 1.0)
    assert whole["median"] > 0.1 and whole["raised"] == 0.0          # the halls' walls read as slopes
    got = sp.estimate_terrain_slope(z, 1.0, tolerance_m=0.15, spacing_cells=1.0, max_object_m=100.0)
    assert got["median"] == pytest.approx(0.02, rel=1e-3) and got["p90"] == pytest.approx(0.02, rel=1e-3)
    assert got["raised"] == pytest.approx(4 * 60.0 * 60.0 / z.size)  # the 3 x 3 blocks wholly on each
    # halls narrower than the blocks leave the ground in each: the block minima as they were
    z = _plane_with_halls(False)
    got = sp.estimate_terrain_slope(z, 1.0, tolerance_m=0.15, spacing_cells=1.0, max_object_m=100.0)
    assert got == sp.estimate_terrain_slope(z, 1.0)
    # halls larger than the largest object turned in the grid are no objects: kept
    z = _plane_with_halls(True)
    got = sp.estimate_terrain_slope(z, 1.0, tolerance_m=0.15, spacing_cells=1.0, max_object_m=40.0)
    assert got == sp.estimate_terrain_slope(z, 1.0)


def test_resolve_terrain_slope_under_wide_halls_and_the_halls_are_objects():
    z = _plane_with_halls(True)
    p = sp.resolve_slope_profile_params(z, 1.0)
    assert p["terrain_slope_deg"] == pytest.approx(np.degrees(np.arctan(0.02)), rel=1e-3)
    res = run_array("slopeprofile", z, 1.0)
    halls = z > 100.0 + 0.02 * np.arange(200, dtype=np.float32) + 1.0
    np.testing.assert_array_equal(res.mask, halls.astype(np.uint8))
    assert sp.resolve_slope_profile_params(z, 1.0, terrain_slope_deg=20.0)["terrain_slope_deg"] == 20.0


@pytest.mark.parametrize("cell,surface", [(1.0, "lowest"), (2.0, "highest")])
def test_courtyard_blocks_are_objects_with_the_defaults(cell, surface):
    """Blocks of buildings 110-140 m round courtyards (like ISPRS samp23): their roofs filled the 20 m
    blocks of the terrain slope, which read 19-20 degrees on level ground, and whole blocks stayed ground
    (33.7 and 36.0 % total error)."""
    from bare_earth.core.evaluate import compare_masks
    from bare_earth.core.synthetic_sites import make_site
    s = make_site("courtyard", cell, surface)
    res = run_array("slopeprofile", s.dsm, s.cell_size)
    assert res.info["params"]["terrain_slope_deg"] < 2.0
    assert compare_masks(res.mask, s.mask)["total"] < 0.5


def test_platforms_exact():
    """A level 3 cells across and 8 along the rows, 1 m up, reached by a ramp at its left
    end (0.1 m per cell, 0.25 allowed): ground; a one-cell rim, a rough one, one not joined
    to the ground below it (the ramp's foot a wall) and one walled on its sides stay."""
    z = np.zeros((9, 24), np.float32)
    z[3:6, 4:14] = np.linspace(0.1, 1.0, 10)          # the ramp (ground)
    z[3:6, 14:22] = 1.0                                 # the level, rejected across only
    one = np.zeros(z.shape, bool)
    one[3:6, 14:22] = True
    obj = one.copy()
    ok = np.ones(z.shape, bool)
    wall = (0.15 + 1.0, 0.15 + 1.0)
    got = sp._platforms(z, one, obj, ok, 0.15, 0.25, 1, 1, wall)
    assert (got == one).all()
    # along the columns: the same level transposed
    assert (sp._platforms(z.T, one.T, obj.T, ok.T, 0.15, 0.25, 0, 1, wall) == one.T).all()
    # not longer along the accepting axis than across: the columns do not accept it
    assert not sp._platforms(z, one, obj, ok, 0.15, 0.25, 0, 1, wall).any()
    # steps of the ramp above ramp_m: not joined
    assert not sp._platforms(z, one, obj, ok, 0.15, 0.05, 1, 1, wall).any()
    # a rim one cell across
    rim = np.zeros(z.shape, bool)
    rim[4, 14:22] = True
    assert not sp._platforms(z, rim, rim, ok, 0.15, 0.25, 1, 1, wall).any()
    # rough along its length: a bump every other cell
    zr = z.copy()
    zr[3:6, 15:22:2] += 0.5
    assert not sp._platforms(zr, one, obj, ok, 0.15, 0.25, 1, 1, wall).any()
    # the ramp's smooth part does not reach nearer the foot than the level: a tier beside a
    # tier (the ramp starts 0.9 m up, a wall down to the ground)
    zt = z.copy()
    zt[3:6, 4:14] = np.linspace(0.8, 0.98, 10)
    assert not sp._platforms(zt, one, obj, ok, 0.15, 0.25, 1, 1, wall).any()
    # high walls along its sides: a bridge's deck
    zd = z.copy()
    zd[3:6, 4:14] = np.linspace(0.5, 5.0, 10)
    zd[3:6, 14:22] = 5.0
    assert not sp._platforms(zd, one, obj, ok, 0.15, 0.6, 1, 1, wall).any()
    assert sp._platforms(zd, one, obj, ok, 0.15, 0.6, 1, 1, (6.0, 6.0)).any()   # lower "walls"


def test_platforms_go_on_across_a_sample_the_scans_accepted():
    """A level 2 cells across and 1 m up, reached by ramps at both ends (0.25 m per cell), that
    the profiles across it reject but for one column the scans accepted: both pieces are
    platforms, the short one's cell beside the gap lying on the line through the gap's ground
    cell (counted between its own cells only, 2 of its 6 cells did, and such a piece stayed an
    object as the gap opened or closed with alpha_t's hundredths: synthetic_sites railway 2 m
    highest, 0.28 / 0.42 % total error at 1.57 / 1.58 degrees). Without the long piece (the
    level beside it accepted), or with an object in the gap, the short piece stays."""
    z = np.zeros((8, 26), np.float32)
    z[3:5, 4:8] = np.linspace(0.25, 1.0, 4)           # up ramp (ground)
    z[3:5, 8:18] = 1.0                                  # the level
    z[3:5, 18:21] = np.linspace(0.75, 0.25, 3)         # down ramp (ground)
    one = np.zeros(z.shape, bool)
    one[3:5, 8:18] = True                               # rejected across only ...
    one[3:5, 14] = False                                # ... but for column 14 (ground)
    ok = np.ones(z.shape, bool)
    wall = (0.15 + 1.0, 0.15 + 1.0)
    assert (sp._platforms(z, one, one.copy(), ok, 0.15, 0.25, 1, 1, wall) == one).all()
    # along the columns: the same, transposed
    assert (sp._platforms(z.T, one.T, one.T.copy(), ok.T, 0.15, 0.25, 0, 1, wall) == one.T).all()
    short = np.zeros(z.shape, bool)
    short[3:5, 15:18] = True
    assert not sp._platforms(z, short, short.copy(), ok, 0.15, 0.25, 1, 1, wall).any()
    obj = one.copy()
    obj[3:5, 14] = True                                 # an object in the gap
    got = sp._platforms(z, one, obj, ok, 0.15, 0.25, 1, 1, wall)
    assert got[3:5, 8:14].all() and not got[3:5, 15:18].any()


def _platform_scene(cell, seed=0):
    """Flat ground (a 0.5 % slope) with three platforms 1 m high, 8 m wide and 90 m long with
    10 m ramps at both ends, turned 6 degrees to the grid, trains 4 m high between them, and a
    bridge deck 6 m up on the same bearing reached by 60 m ramps (an object)."""
    rng = np.random.default_rng(seed)
    n = int(round(240 / cell))
    yy, xx = (np.mgrid[0:n, 0:n].astype(np.float32) + 0.5) * np.float32(cell)
    ground = 100 + 0.005 * xx
    a = np.radians(6.0)
    al = (xx - 120) * np.cos(a) + (yy - 120) * np.sin(a)
    ac = (yy - 120) * np.cos(a) - (xx - 120) * np.sin(a)
    z = ground.copy()
    truth = np.zeros((n, n), np.uint8)
    for c in (-60.0, -35.0, -10.0):
        lift = np.clip((55 - np.abs(al)) / 10, 0, 1) * (np.abs(ac - c) <= 4)
        z += lift.astype(np.float32)
        train = (np.abs(ac - (c + 7.5)) <= 1.5) & (np.abs(al) <= 50)
        z[train] = ground[train] + 4.0
        truth[train] = 1
    deck = (np.abs(ac - 40) <= 4) & (np.abs(al) <= 25)
    ramp = (np.abs(ac - 40) <= 4) & (np.abs(al) > 25) & (np.abs(al) <= 85)
    z[ramp] = (ground + 6.0 * (85 - np.abs(al)) / 60)[ramp]
    z[deck] = ground[deck] + 6.0
    truth[deck] = 1
    return (z + rng.normal(0, 0.03, z.shape)).astype(np.float32), truth, (np.abs(al) <= 45) & (
        (np.abs(ac + 60) <= 3) | (np.abs(ac + 35) <= 3) | (np.abs(ac + 10) <= 3))


@pytest.mark.parametrize("cell", [1.0, 2.0])
def test_oblique_platforms_with_ramps_are_ground_trains_and_a_bridge_deck_objects(cell):
    """Platforms 1 m high between tracks, turned to the grid, reached by ramps at their ends
    (synthetic_sites railway: 3.1-3.3 % total error at 1 and 2 m cells, their tops rejected by
    the profiles across them) are ground with the defaults; the trains and a bridge's deck
    on walls 6 m high reached by its ramps stay objects."""
    z, truth, tops = _platform_scene(cell)
    r = run_array("slopeprofile", z, cell, {})
    assert (r.mask[tops] == GROUND).mean() > 0.97
    assert (r.mask[truth == 1] == OBJECT).mean() > 0.95


def test_same_level_exact():
    """Object cells joined to a level by steps of at most step_m through object cells join
    it; a wall (a train beside it) or a ground cell between stops it."""
    z = np.array([[1.0, 1.1, 1.2, 5.0, 5.0, 1.0, 1.0],
                  [1.0, 1.1, 1.2, 5.0, 5.0, 1.0, 1.0]], np.float32)
    obj = np.ones(z.shape, bool)
    obj[:, 5] = False                                  # ground between
    level = np.zeros(z.shape, bool)
    level[:, 0] = True
    got = sp._same_level(z, level, obj, 0.15)
    assert (got == (np.arange(7) < 3)[None, :].repeat(2, 0)).all()
    assert (sp._same_level(z, level, obj, 0.05) == level).all()    # steps of 0.1 above step_m
    assert not sp._same_level(z, np.zeros(z.shape, bool), obj, 0.15).any()


def test_level_unwalled_exact():
    """Object cells on a platform's level join it unless walled where they meet the ground:
    a deck 5 m above the ground on both sides stays an object, the same cells 0.5 m above it
    (a platform's strip) join."""
    z = np.zeros((7, 12), np.float32)
    z[2:5, :] = 5.0                                   # the level along the rows
    level = np.zeros(z.shape, bool)
    level[2:5, :4] = True                             # given back (a platform's part)
    obj = np.zeros(z.shape, bool)
    obj[2:5, 4:] = True                               # the rest, rejected by both axes
    wall = (1.15, 1.15)
    assert not sp._level_unwalled(z, level, obj, 0.15, wall).any()     # 5 m walls: a deck
    low = np.where(z > 0, np.float32(0.5), z)
    assert (sp._level_unwalled(low, level, obj, 0.15, wall) == obj).all()


def test_walled_across_exact():
    """Runs along the rows on walls at both ends (the higher of the end cell and the next one in
    above the ground beyond by more than wall_m), and the even ones among them (half their inner
    cells on the line between their cells lag apart; a run with no inner cells: level steps)."""
    rows = [([0, 5, 5, 5, 0, 0, 0, 0, 0], [0, 1, 1, 1, 0, 0, 0, 0, 0], True, True),      # a deck
            ([0, 1, 2, 3, 2, 1, 0, 0, 0], [0, 1, 1, 1, 1, 1, 0, 0, 0], False, False),    # banks
            ([0, 5, 8, 5, 0, 0, 0, 0, 0], [0, 1, 1, 1, 0, 0, 0, 0, 0], True, False),     # walled, rough
            ([5, 5, 5, 0, 0, 0, 0, 0, 0], [1, 1, 1, 0, 0, 0, 0, 0, 0], False, False),    # the raster's edge
            ([0, 5, 5, 5, 5, 5, 5, 5, 0], [0, 1, 1, 1, 1, 1, 1, 1, 0], False, False),    # longer than 6
            ([0, 1, 5, 5, 5, 5, 0, 0, 0], [0, 1, 1, 1, 1, 1, 0, 0, 0], True, True),     # an end cell on the wall
            ([0, 5, 6, 7, 6, 5, 0, 0, 0], [0, 1, 1, 1, 1, 1, 0, 0, 0], True, True),     # a gable: 2 of 3 on the line
            ([0, 5, 5, 0, 0, 0, 0, 0, 0], [0, 1, 1, 0, 0, 0, 0, 0, 0], True, True),     # no inner cells: level
            ([0, 5, 7, 0, 0, 0, 0, 0, 0], [0, 1, 1, 0, 0, 0, 0, 0, 0], True, False),
            ([0, 5, 0, 0, 0, 0, 0, 0, 0], [0, 1, 0, 0, 0, 0, 0, 0, 0], False, False)]   # one cell
    z = np.array([r[0] for r in rows], np.float32)
    rej = np.array([r[1] for r in rows], bool)
    walled, even = sp._walled_across(rej, ~rej, z, 0.0, 1.0, 6, 0.2)     # walls: over 1 m per cell
    for i, (_, _, w, ev) in enumerate(rows):
        assert (walled[i] == (rej[i] & w)).all(), i
        assert (even[i] == (rej[i] & ev)).all(), i
    # an even slope the nearest point's fill repeats in pairs: even over two cells, not one
    z2 = np.array([[0, 5, 5, 6, 6, 7, 7, 0]], np.float32)
    rej2 = np.array([[0, 1, 1, 1, 1, 1, 1, 0]], bool)
    assert not sp._walled_across(rej2, ~rej2, z2, 0.0, 1.0, 10, 0.2, lag=1)[1].any()
    assert (sp._walled_across(rej2, ~rej2, z2, 0.0, 1.0, 10, 0.2, lag=2)[1] == rej2).all()
    # what stands on it left out of its edge: trees on an embankment's banks (the crest 3 m up
    # drops to the ground 4 cells away: a bank), a railing on a deck (6 m up, 3 cells: a wall)
    z3 = np.array([[0, 6, 6, 3, 3, 3, 6, 6, 0], [0, 7, 6, 6, 6, 6, 7, 0, 0]], np.float32)
    rej3 = np.array([[0, 1, 1, 1, 1, 1, 1, 1, 0], [0, 1, 1, 1, 1, 1, 1, 0, 0]], bool)
    on = np.array([[0, 1, 1, 0, 0, 0, 1, 1, 0], [0, 1, 0, 0, 0, 0, 1, 0, 0]], bool)
    walled, even = sp._walled_across(rej3, ~rej3, z3, 0.0, 1.0, 10, 0.2, standing=on)
    assert (walled == rej3).all()                     # the stretch: with what stands on it
    assert not even[0].any() and (even[1] == rej3[1]).all()


def _walled_across_by_runs(rej, ground, z, tol_m, bank_m, limit, step_m, lag, standing):
    """_walled_across's rule run by run, row by row (a reference for the random scenes)."""
    walled, even = np.zeros(rej.shape, bool), np.zeros(rej.shape, bool)
    W = rej.shape[1]
    for r in range(rej.shape[0]):
        c = 0
        while c < W:
            if not rej[r, c]:
                c += 1
                continue
            s = c
            while c < W and rej[r, c]:
                c += 1
            e = c - 1
            if not (e - s + 1 <= limit and e - s >= lag):
                continue

            def on_walls(free, r=r, s=s, e=e):
                f = [i for i in range(s, e + 1) if free[i]]
                if not f:
                    return False
                for beyond, near, far in ((s - 1, f[0], f[min(1, len(f) - 1)]),
                                          (e + 1, f[-1], f[max(len(f) - 2, 0)])):
                    if not (0 <= beyond < W and ground[r, beyond]):
                        return False
                    rise = np.fmax(z[r, near], z[r, far]) - z[r, beyond]
                    if not rise > tol_m + abs(beyond - far) * bank_m:
                        return False
                return True
            walled[r, s:e + 1] = on_walls(np.ones(W, bool))
            if not on_walls(~standing[r]):             # its edge: what stands on it left out
                continue
            steps = [abs(z[r, i + lag] - z[r, i]) <= step_m for i in range(s, e - lag + 1)]
            level = 2 * sum(steps) >= len(steps)
            inner = [abs(z[r, i - lag] - 2 * z[r, i] + z[r, i + lag]) <= step_m for i in range(s + lag, e - lag + 1)]
            if inner:
                level = 2 * sum(inner) >= len(inner)
            even[r, s:e + 1] = level
    return walled, even


@pytest.mark.parametrize("seed", range(4))
def test_walled_across_equals_its_rule_run_by_run(seed):
    """The runs are found on the rejected cells alone (their flat indices): a run ending at a row's
    last cell and one starting at the next row's first cell stay two runs; random runs, heights
    (some NaN), ground and what stands on them give the rule's result run by run."""
    rng = np.random.default_rng(seed)
    H, W = 60, 17
    rej = rng.random((H, W)) < 0.6
    rej[::3, -3:] = rej[1::3, :3] = True               # runs across the rows' ends
    z = rng.integers(0, 3, (H, W)).astype(np.float32)
    z[rej] += rng.integers(0, 2, (H, W))[rej] * 4      # walls up to some runs' cells
    z[rng.random((H, W)) < 0.05] = np.nan
    ground = ~rej & (rng.random((H, W)) < 0.9)
    standing = rej & (rng.random((H, W)) < 0.2)
    for lag in (1, 2):
        got = sp._walled_across(rej, ground, z, 0.5, 1.0, 8, 1.0, lag=lag, standing=standing)
        ref = _walled_across_by_runs(rej, ground, z, 0.5, 1.0, 8, 1.0, lag, standing)
        np.testing.assert_array_equal(got[0], ref[0])
        np.testing.assert_array_equal(got[1], ref[1])
        assert ref[1].any() and (ref[0] & ~ref[1]).any()   # the scene tests both outcomes


@pytest.mark.parametrize("seed", range(4))
def test_islands_level_equals_its_rule_region_by_region(seed):
    """_islands_level, which reads the edges of the small regions' cells alone, gives the rule
    region by region: a region of ground fitting the largest object with fewer than half its
    edges to the objects stepping up by more than the step."""
    rng = np.random.default_rng(seed)
    H, W = 20, 23
    obj = rng.random((H, W)) < 0.6
    ok = rng.random((H, W)) < 0.95
    z = rng.integers(0, 4, (H, W)).astype(np.float32)
    z[rng.random((H, W)) < 0.05] = np.nan
    reach = (4, 5)
    ref = np.zeros((H, W), bool)
    lab, n = ndimage.label(ok & ~obj, structure=np.ones((3, 3), bool))
    for i, box in enumerate(ndimage.find_objects(lab), 1):
        if box[0].stop - box[0].start > reach[0] or box[1].stop - box[1].start > reach[1]:
            continue
        edges = ups = 0
        for r, c in zip(*np.nonzero(lab == i)):
            for rr, cc in ((r, c - 1), (r, c + 1), (r - 1, c), (r + 1, c)):
                if 0 <= rr < H and 0 <= cc < W and obj[rr, cc]:
                    edges += 1
                    ups += bool(z[rr, cc] > z[r, c] + np.float32(1.0))
        ref[lab == i] = edges > 0 and 2 * ups < edges
    np.testing.assert_array_equal(sp._islands_level(z, obj, ok, 1.0, reach), ref)
    assert ref.any() and (ref != (lab > 0)).any()      # the scene tests both outcomes


def test_decks_exact():
    """One axis's band on walls across, level: a deck when shorter than the largest object turned
    in the grid; a dam that long is ground (with trees on it too), banks are no walls."""
    z = np.zeros((30, 80), np.float32)
    band = np.zeros(z.shape, bool)
    band[10:14, 20:44] = True                         # 24 cells along X, rejected by the Y profiles
    z[band] = 5.0
    none = np.zeros(z.shape, bool)
    tol, bank = 0.2, (1.0, 1.0)                        # walls: over 2.2 m in two cells
    got = sp._decks(none, band, ~band, z, tol, bank, (20, 20), 0.2, 1)
    assert (got == band).all()
    assert not sp._decks(band, none, ~band, z, tol, bank, (20, 20), 0.2, 1).any()   # 24 across: wider than 20
    dam = np.zeros(z.shape, bool)
    dam[10:14, 5:75] = True                           # 70 cells: longer than 29 (20 turned)
    zd = np.where(dam, np.float32(5.0), z)
    assert not sp._decks(none, dam, ~dam, zd, tol, bank, (20, 20), 0.2, 1).any()
    trees = np.zeros(z.shape, bool)
    trees[10:14, 30:34] = trees[10:14, 50:54] = True  # rejected by both axes: they break no stretch
    zt = np.where(trees, np.float32(11.0), zd)
    assert not sp._decks(trees, dam, ~dam, zt, tol, bank, (20, 20), 0.2, 1).any()
    banks = np.where(band, np.float32(1.5), z)
    banks[11:13] = np.where(band[11:13], np.float32(3.0), z[11:13])   # 1:1.5 banks, no walls
    assert not sp._decks(none, band, ~band, banks, tol, bank, (20, 20), 0.2, 1).any()


def _bridge_scene():
    """A road embankment along X (1:1 banks, 3 m) crossing a river 20 m wide and 2 m deep on a
    bridge: the deck 5 m above the water, with three cars on it."""
    z = np.zeros((80, 240), np.float32)
    z[35:45] = np.array([1, 2, 3, 3, 3, 3, 3, 3, 2, 1], np.float32)[:, None]
    z[:, 110:130] = -2.0
    z[37:43, 110:130] = 3.0
    cars = np.zeros(z.shape, bool)
    for r, c in ((38, 112), (40, 118), (38, 124)):
        cars[r:r + 2, c:c + 4] = True
    z[cars] += 1.5
    deck = np.zeros(z.shape, bool)
    deck[37:43, 110:130] = True
    return z, deck, cars


def test_bridge_deck_on_an_embankment_road_is_an_object_blocked_or_not():
    """ISPRS samp71 (issue 12): a bridge's deck goes on level from the road's embankment, so the
    profiles along it accept it and the embankment's one-axis run gave it back to the ground (30 %
    of the bridge's points called ground). Its run across stands on walls, not banks: an object;
    the embankment, its banks and the river stay ground, in one pass and in blocks."""
    z, deck, cars = _bridge_scene()
    one = run_array("slopeprofile", z, 1.0, dict(PARAMS))
    assert (one.mask[deck] == OBJECT).all()           # 0 % of the deck without the rule
    assert (one.mask[~deck] == GROUND).all()
    blocked = run_array("slopeprofile", z, 1.0, dict(PARAMS), block=48)
    np.testing.assert_array_equal(blocked.mask, one.mask)


def test_islands_level_exact():
    """Ground enclosed by objects on their level is theirs; a courtyard below them, or ground
    larger than the largest object, is not."""
    z = np.zeros((11, 11), np.float32)
    obj = np.zeros(z.shape, bool)
    obj[1:10, 1:10] = True
    obj[4:7, 4:7] = False                             # the island
    island = np.zeros(z.shape, bool)
    island[4:7, 4:7] = True
    roof = np.where(obj | island, np.float32(6.0), z)
    ok = np.ones(z.shape, bool)
    assert (sp._islands_level(roof, obj, ok, 0.3, (20, 20)) == island).all()
    court = np.where(obj, np.float32(6.0), z)         # the island at the ground's level
    assert not sp._islands_level(court, obj, ok, 0.3, (20, 20)).any()
    assert not sp._islands_level(roof, obj, ok, 0.3, (2, 2)).any()


def test_roof_filling_the_rasters_corner_is_an_object():
    """lidar sample_c 4 m (3.5 % total error): the profiles through a roof's corner filling the
    raster's last rows and columns hold no ground to start from and accepted it; the profiles
    beside them reject the same roof. With the islands on the objects' level: all of it."""
    r, c = np.mgrid[0:16, 0:18]
    ground = r + c < 12
    z = np.where(ground, 0.0, 6.0 + 0.05 * c).astype(np.float32)
    m = sp.filter_slope_profile(z, 1.0, **PARAMS).mask
    assert (m[~ground] == OBJECT).all()               # 89 % without the rule
    assert (m[ground] == GROUND).all()


def test_stepped_runs_stand_on_steps_at_both_ends_beyond_one_cell_holes():
    one = np.zeros((4, 9), bool)
    one[:, 3:6] = True
    z = np.zeros((4, 9), np.float32)
    z[:, 3:6] = 1.0
    z[1, 6] = 0.8                      # row 1: the cell after the run is 0.2 below its end
    z[2, 7] = 2.0                      # row 2: the second cell after it is higher: no step
    z[3, 1] = 5.0                      # row 3: a one-cell hole before it, ground higher beyond
    z[3, 2] = 0.0
    got = sp._stepped_runs(one, z, 0.5, 1, 3)
    assert got[0].tolist() == one[0].tolist()          # a step of 1 m at both ends
    assert not got[1:].any()
    # the same along the columns
    np.testing.assert_array_equal(sp._stepped_runs(one.T.copy(), z.T.copy(), 0.5, 0, 3), got.T)
    # no longer than the largest object
    assert not sp._stepped_runs(one, z, 0.5, 1, 2).any()
    # a smaller step only
    assert not sp._stepped_runs(one, z, 1.0, 1, 3).any()
    # runs at the raster's edge or next to nodata stand on no step there
    assert not sp._stepped_runs(one[:, 3:], z[:, 3:], 0.5, 1, 3).any()
    zn = z.copy()
    zn[0, 6] = np.nan
    assert not sp._stepped_runs(one, zn, 0.5, 1, 3)[0].any()


def test_low_hedge_accepted_along_its_length_is_an_object_a_ramped_embankment_is_not():
    """A hedge 1 m high, 3 cells across and 40 long: the profiles along it accept it by the
    terrain's rise (each of their two scans loses it to alpha_t after a few cells), so only
    the profiles across reject it and the combination gave all of it back as an embankment.
    Its runs along the accepting axis stand on steps at both their ends: it is crossed, an
    object (ISPRS samp71 and samp41: cars and hedges). An embankment as high between walls
    but reached by ramps gentler than alpha_g at both ends stays ground."""
    p = dict(slope_threshold_deg=16.0, terrain_slope_deg=8.0, tolerance_m=0.15, max_object_size_m=100.0)
    z = np.zeros((40, 60), np.float32)
    z[18:21, 10:50] = 1.0
    r = sp.filter_slope_profile(z, 1.0, **p)
    assert (r.mask[18:21, 10:50] == OBJECT).all()
    assert (r.mask[:18] == GROUND).all() and (r.mask[21:] == GROUND).all()
    c = np.arange(60, dtype=np.float32)
    ramp = np.clip(np.minimum(0.1 * (c - 9), 0.1 * (50 - c)), 0.0, 1.0)
    z[18:21] = ramp
    r = sp.filter_slope_profile(z, 1.0, **p)
    assert (r.mask == GROUND).all()


def _scan1_trend(values, trend, tan_g, tan_t, dh0, reverse=False):
    """One profile scanned alone with the ground's trend (rise per cell along the profile's
    forward direction): its rejections as a list of bools in the profile's order."""
    a = np.asarray(values, np.float32)[:, None]
    t = np.full(a.shape, trend, np.float32)
    return sp._scan([(a, reverse)], 1.0, tan_g, tan_t, dh0, 1, 1, trends=[t])[0][:, 0].tolist()


def test_scan_terrain_rise_follows_the_ground_fall_at_the_reference():
    # tan_g 0.6, tan_t 0.2, dh0 0: ground falling 0.2 m a cell to the reference (0.4), a
    # 3 m object, then a cell 0.3 m above the reference at d = 2. From the reference's level
    # the terrain's line allows 0.4 m there: accepted (the old rule, and without a trend).
    # Continued down its fall the ground lies at 0.0 there, and the rise alpha_t from it
    # allows only the reference's level (the edge's 0.2 m over the fall is larger): rejected.
    z = [1.0, 0.8, 0.6, 0.4, 3.0, 0.7]
    assert _scan1(z, 0.6, 0.2, 0.0) == [False] * 4 + [True, False]
    assert _scan1_trend(z, 0.0, 0.6, 0.2, 0.0) == [False] * 4 + [True, False]
    assert _scan1_trend(z, -0.2, 0.6, 0.2, 0.0) == [False] * 4 + [True, True]
    # a fall steeper than alpha_t counts as alpha_t: the same
    assert _scan1_trend(z, -1.0, 0.6, 0.2, 0.0) == [False] * 4 + [True, True]
    # and below the ground's continuation plus the edge's 0.2 m (0.15 above it) is ground
    assert _scan1_trend([1.0, 0.8, 0.6, 0.4, 3.0, 0.15], -0.2, 0.6, 0.2, 0.0) == [False] * 4 + [True, False]
    # the fall must be the trend's and the last step's: level ground before the object with
    # a falling trend, or a falling step with a level trend, keeps the reference's level
    assert _scan1_trend([0.4, 0.4, 0.4, 0.4, 3.0, 0.7], -0.2, 0.6, 0.2, 0.0) == [False] * 4 + [True, False]
    assert _scan1_trend(z, 0.0, 0.6, 0.2, 0.0) == [False] * 4 + [True, False]
    # the step's fall counts beyond its noise, sqrt(2) dh0 / 3: with dh0 0.3 (0.14 m) a fall of
    # 0.2 m a cell continues at 0.06 m a cell (0.65 above the reference at d = 2: above
    # 0.3 + 2 (0.2 - 0.06) = 0.58, rejected; the reference's level allowed 0.7), a fall of 0.1 m
    # a cell is noise: the reference's level
    assert _scan1_trend(z[:5] + [1.05], -0.2, 0.6, 0.2, 0.3) == [False] * 4 + [True, True]
    assert _scan1(z[:5] + [1.05], 0.6, 0.2, 0.3) == [False] * 4 + [True, False]
    assert _scan1_trend([0.7, 0.6, 0.5, 0.4, 3.0, 1.05], -0.2, 0.6, 0.2, 0.3) == [False] * 4 + [True, False]
    # a rising trend changes nothing: the terrain's rise from the reference
    assert _scan1_trend([0.0, 0.2, 0.4, 0.6, 3.0, 1.0], 0.2, 0.6, 0.2, 0.0) == [False] * 4 + [True, False]
    # scanned backwards the trend's sign turns: the same profile mirrored, rising forwards
    assert _scan1_trend(z[::-1], 0.2, 0.6, 0.2, 0.0, reverse=True) == [True, True] + [False] * 4
    assert _scan1_trend(z[::-1], -0.2, 0.6, 0.2, 0.0, reverse=True) == [False, True] + [False] * 4


def test_ground_trends_are_the_running_minimum_slope_per_cell_below_objects():
    # a plane rising 0.3 m per metre along X and falling 0.1 along Y, 2 m cells: 0.6 and -0.2
    # m per cell (the 10 m minimum: 5 cells); beside a 2 x 2 object of 5 m the minimum
    # reaches below it (on the ground within the window's 6 cells, a cell or two off the
    # plane's lowest corner: within half the trend, of its sign), further away exactly; 0
    # near the raster's edge and where the minimum is not finite
    yy, xx = np.mgrid[0:30, 0:30].astype(np.float32) * 2.0
    z = (0.3 * xx - 0.1 * yy).astype(np.float32)
    gx, gy = sp.ground_trends(z, 2.0)
    np.testing.assert_allclose(gx[:, 5:25], 0.6, atol=1e-4)
    np.testing.assert_allclose(gy[5:25], -0.2, atol=1e-4)
    z[14:16, 14:16] += 5.0
    gx2, gy2 = sp.ground_trends(z, 2.0)
    np.testing.assert_allclose(gx2[:, 5:25], 0.6, atol=0.3 + 1e-5)
    np.testing.assert_allclose(gy2[5:25], -0.2, atol=0.1 + 1e-5)
    far = np.ones(z.shape, bool)
    far[8:22, 8:22] = False
    np.testing.assert_array_equal(gx2[far], gx[far])
    np.testing.assert_array_equal(gy2[far], gy[far])
    assert (gx[:, :2] == 0).all() and (gy[:2] == 0).all()
    z[:, :] = np.nan
    gx, gy = sp.ground_trends(z, 2.0)
    assert (gx == 0).all() and (gy == 0).all()


def test_low_shrubs_on_a_steep_hillside_rejected_by_the_scans_coming_down_it():
    """ISPRS samp11 (issue 12): shrubs 1.2 m high on a 20 degree hillside (falling along both
    axes, 2 m cells, alpha_t 20 degrees) were ground: the scans coming down the hillside let
    the ground rise alpha_t from the reference's level under them (0.2 + 0.73 m at their first
    cell, 0.51 m below the reference there: 1.2 m passed), the profiles along neither axis
    rejected them both ways. Counted from the ground continued down its fall, their uphill
    row and column are rejected by both axes' scans: each shrub is an object (the cells
    further in are accepted by the edge's allowance), the hillside stays ground."""
    yy, xx = np.mgrid[0:80, 0:80].astype(np.float32) * 2.0
    z = (np.tan(np.radians(20.0)) / np.sqrt(2.0) * (xx + yy)).astype(np.float32)
    shrubs = np.zeros(z.shape, bool)
    for r in range(8, 72, 8):
        for c in range(8, 72, 8):
            shrubs[r:r + 3, c:c + 3] = True
    z[shrubs] += 1.2
    p = dict(slope_threshold_deg=float(np.degrees(np.arctan(2.0 * np.tan(np.radians(20.0))))),
             terrain_slope_deg=20.0, tolerance_m=0.2, max_object_size_m=30.0)
    r = sp.filter_slope_profile(z, 2.0, **p)
    assert (r.mask[~shrubs] == GROUND).all()
    lab, n = ndimage.label(shrubs)
    for i in range(1, n + 1):
        obj = (r.mask == OBJECT) & (lab == i)
        r0, c0 = np.argwhere(lab == i).min(axis=0)
        # the uphill row and column (the highest x and y) of every shrub: 5 of its 9 cells
        assert obj[r0 + 2, c0:c0 + 3].all() and obj[r0:r0 + 3, c0 + 2].all()


def test_scan_bounds_the_terrain_fall_with_ufuncs_not_clip(monkeypatch):
    """The terrain line's fall, ``max(clip(t, -b2, 0), min(step, 0))`` (the trend ``t`` within [-b2, 0], the
    step's fall no steeper than 0), is taken as ``max(min(max(t, step), 0), -b2)``: min and max are monotone, so
    the same values for any ``t`` and step (a step below -b2 too, NaN alike), and the scan calls no np.clip, whose
    Python wrapper cost two of them a step (scan_profiles on the synthetic city, 4 Mcells at 1 m: 0.47 -> 0.43
    CPU s)."""
    rng = np.random.default_rng(5)
    b2 = np.float32(0.3)
    t = np.concatenate([rng.normal(0, 0.4, 2000), [-0.3, 0.3, 0.0, -0.0, np.nan, 1.0, -1.0]]).astype(np.float32)
    s = np.concatenate([rng.normal(0, 0.4, 2000), [np.nextafter(-b2, -1), -0.3, np.nan, 0.0, 0.5, -2.0, 0.0]])
    s = s.astype(np.float32)
    want = np.maximum(np.clip(t, -b2, 0), np.minimum(s, 0))
    got = np.maximum(np.minimum(np.maximum(t, s), 0), -b2)
    np.testing.assert_array_equal(got, want)

    class NoClip:
        def __getattr__(self, name):
            return getattr(np, name)

        def clip(self, *a, **k):
            raise AssertionError("np.clip in the scan")

    z = (0.2 * np.arange(40, dtype=np.float32))[::-1, None] + np.zeros((1, 3), np.float32)
    z[10:14] += 3.0
    trend = np.full(z.shape, -0.2, np.float32)
    want = sp._scan([(z, False), (z, True)], 1.0, 0.6, 0.2, 0.15, 1, 1, trends=[trend, trend])
    monkeypatch.setattr(sp, "np", NoClip())
    got = sp._scan([(z, False), (z, True)], 1.0, 0.6, 0.2, 0.15, 1, 1, trends=[trend, trend])
    monkeypatch.setattr(sp, "np", np)
    for a, b in zip(want, got):
        np.testing.assert_array_equal(a, b)


def _scan1_edge(values, trend, edge_trend, tan_g, tan_t, dh0, reverse=False):
    """One profile scanned alone with the ground's trend and its trend before the scan's position
    (both rise per cell in the profile's forward direction): its rejections in the profile's order."""
    a = np.asarray(values, np.float32)[:, None]
    t = np.full(a.shape, trend, np.float32)
    e = np.full(a.shape, edge_trend, np.float32)
    return sp._scan([(a, reverse)], 1.0, tan_g, tan_t, dh0, 1, 1, trends=[t], edge_trends=[e])[0][:, 0].tolist()


def test_scan_ground_change_before_the_reference_follows_its_trend():
    # tan_g 0.6, tan_t 0.2 (c = 0.2), dh0 0. Level ground, then a flank climbed in steps of
    # 0.35 and 0.5 m: each within the edge's allowance from the step before it (0.35 <= 0.6 - 0.2
    # over level ground; then 0.5 <= 0.6 over ground rising at c): accepted without the trend
    # before the reference (the old rule)
    z = [0.0, 0.0, 0.0, 0.35, 0.85, 1.35]
    assert _scan1_trend(z, 0.0, 0.6, 0.2, 0.0) == [False] * 6
    # the ground's trends are level there: the 0.35 m step is none of the ground's, the edge's
    # allowance stays 0.4 over the level, and 0.5 m above the flank's first cell is rejected
    assert _scan1_edge(z, 0.0, 0.0, 0.6, 0.2, 0.0) == [False] * 4 + [True, True]
    # ground rising along its trend is unchanged: its steps are the trend's
    assert _scan1_edge(z, 0.0, 0.35, 0.6, 0.2, 0.0) == [False] * 6
    # the step's noise (sqrt(2) dh0 / 3 = 0.33 m with dh0 0.7) is allowed beyond the trend
    assert _scan1_edge([0.0, 0.0, 0.0, 0.35, 1.0], 0.0, 0.0, 0.6, 0.2, 0.0) == [False] * 4 + [True]
    assert _scan1_edge([0.0, 0.0, 0.0, 0.35, 1.0], 0.0, 0.0, 0.6, 0.2, 0.7) == [False] * 5
    # a level top on ground falling 1 m a cell (a crown entered level from the hillside above):
    # the level step is not the ground's, which falls at alpha_t at least: 0.3 m above the level
    # is beyond the edge's 0.2 over that fall (0.6 - 0.2 - 0.2); the old rule allowed 0.4
    z = [2.0, 1.0, 0.0, 0.0, 0.3]
    assert _scan1_trend(z, 0.0, 0.6, 0.2, 0.0) == [False] * 5
    assert _scan1_edge(z, 0.0, -1.0, 0.6, 0.2, 0.0) == [False] * 4 + [True]
    # scanned backwards the trend's sign turns: the same profile mirrored
    assert _scan1_edge(z[::-1], 0.0, 1.0, 0.6, 0.2, 0.0, reverse=True) == [True] + [False] * 4
    with pytest.raises(ValueError, match="one edge trend array per source"):
        sp._scan([(np.zeros((3, 1), np.float32), False)], 1.0, 0.6, 0.2, 0.0, 1, 1,
                 trends=[np.zeros((3, 1), np.float32)], edge_trends=[])
    with pytest.raises(ValueError, match="need the terrain line's trends"):
        sp._scan([(np.zeros((3, 1), np.float32), False)], 1.0, 0.6, 0.2, 0.0, 1, 1,
                 edge_trends=[np.zeros((3, 1), np.float32)])


def test_trends_before_are_the_more_rising_of_the_trend_here_and_behind():
    # 2 m cells: trend_cells 5, the trend 4 cells behind (2 (5 // 2)); 0 beyond the edge
    t = np.array([0.0, 0.5, -1.0, 0.2, -0.3, 0.0, 0.4, -0.6], np.float32)
    f, b = sp.trends_before(t[None, :], 1, (2.0, 2.0))
    assert f[0].tolist() == pytest.approx([0.0, 0.5, 0.0, 0.2, 0.0, 0.5, 0.4, 0.2])
    assert b[0].tolist() == pytest.approx([-0.3, 0.0, -1.0, -0.6, -0.3, 0.0, 0.0, -0.6])
    # along Y (axis 0) the same on the columns; the input is not changed
    f2, b2 = sp.trends_before(np.repeat(t[:, None], 3, axis=1), 0, (2.0, 2.0))
    assert np.array_equal(f2, np.repeat(f[0][:, None], 3, axis=1))
    assert np.array_equal(b2, np.repeat(b[0][:, None], 3, axis=1))
    assert t[2] == -1.0


def test_scan_profiles_reject_a_crown_flank_climbed_in_steps():
    # level ground with a ridge of 0.35 / 0.5 m steps across the X profiles (tan_g 0.6, tan_t 0.2,
    # dh0 0): each step from the one before is within the edge's allowance, so both X scans
    # climbed it; the ground's trends (level: the running minimum goes below the 7 m ridge) do not
    # follow the steps, and its upper three cells are rejected by both
    row = np.array([0.0] * 14 + [0.35, 0.85, 1.35, 1.85, 1.35, 0.85, 0.35] + [0.0] * 14, np.float32)
    z = np.tile(row, (35, 1))
    ox, oy, _, _ = sp.scan_profiles(z, (1.0, 1.0), 0.6, 0.2, 0.0, (10, 10), (1, 1))
    assert np.flatnonzero(ox[17]).tolist() == [16, 17, 18]
    assert not oy.any()
    ox, _, _, _ = sp.scan_profiles(z, (1.0, 1.0), 0.6, 0.2, 0.0, (10, 10), (1, 1), trends=False)
    assert not ox.any()
