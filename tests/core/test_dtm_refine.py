"""The dtm's final ground refinement (core/dtm_refine.py): exact floors on tiny arrays, what is and
is not bracketed, and a scene with known truth where it removes what the vote kept."""
import math

import numpy as np
import pytest
from scipy import ndimage
from surfaces import in_blocks

from bare_earth.core import dtm_refine as dr
from bare_earth.core.codes import GROUND, NODATA, OBJECT
from bare_earth.core.common import touching
from bare_earth.core.dtm import filter_dtm, resolve_dtm_params
from bare_earth.core.fill import fill_gaps, find_edge_spikes
from bare_earth.core.methods import get_method
from bare_earth.core.synthetic import make_canopy


def _brute_floor(zg, n, di, dj, inc):
    rows, cols = zg.shape
    out = np.full(zg.shape, np.inf)
    for i in range(rows):
        for j in range(cols):
            for k in range(n + 1):
                a, b = i - k * di, j - k * dj
                if 0 <= a < rows and 0 <= b < cols:
                    out[i, j] = min(out[i, j], zg[a, b] + k * inc)
    return out


@pytest.mark.parametrize("n", [1, 2, 3, 5, 8])
@pytest.mark.parametrize("di,dj", [(0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (-1, -1), (1, -1), (-1, 1)])
def test_floor_equals_brute_force(n, di, dj):
    rng = np.random.default_rng(n)
    zg = rng.normal(0, 2, (9, 11)).astype(np.float32)
    zg[rng.random(zg.shape) < 0.3] = np.inf
    got = dr._floor(zg, n, di, dj, 0.25)
    np.testing.assert_allclose(got, _brute_floor(zg.astype(np.float64), n, di, dj, 0.25), rtol=0, atol=1e-5)


def test_steps_and_halo():
    assert dr.refine_steps((1.0, 1.0), 12.0) == {(0, 1): 12, (1, 0): 12, (1, 1): 8, (1, -1): 8}
    assert dr.refine_steps((2.0, 4.0), 12.0) == {(0, 1): 6, (1, 0): 3, (1, 1): 3, (1, -1): 3}
    assert dr.refine_steps((20.0, 20.0), 12.0) == {(0, 1): 1, (1, 0): 1, (1, 1): 1, (1, -1): 1}
    # the floors' reach plus one, the smoothness test's 2 cells, the edge test's (fill.edge_spikes_reach: 7)
    # and the raised band's (three passes of the plane's half window plus the band's cell: 3 x 7 at 1 m)
    assert dr.band_plane_cells((1.0, 1.0)) == (6, 6) and dr.band_plane_cells((4.0, 4.0)) == (2, 2)
    assert dr.raised_band_reach((1.0, 1.0)) == 21 and dr.raised_band_reach((4.0, 4.0)) == 9
    assert dr.refine_halo((1.0, 1.0), 12.0) == 13 + 2 + 7 + 21
    assert dr.refine_halo((4.0, 4.0), 12.0) == 4 + 2 + 7 + 9
    # floors shorter than the step-top test's reach (find_step_tops: 3 cells and the smoothness test's 2)
    assert dr.refine_halo((20.0, 20.0), 12.0) == dr.STEP_TOP_REACH + 7 + dr.raised_band_reach((20.0, 20.0)) == 5 + 7 + 9


def test_single_bump_on_flat_ground():
    z = np.zeros((7, 9), np.float32)
    z[3, 4] = 1.0
    out = dr.find_bracketed(z, np.ones(z.shape, bool), (1.0, 1.0), slope=0.0, height_m=0.5, reach_m=3.0)
    expect = np.zeros(z.shape, bool)
    expect[3, 4] = True
    np.testing.assert_array_equal(out, expect)


@pytest.mark.parametrize("slope,bracketed", [(0.4, True), (0.6, False)])
def test_slope_allowance(slope, bracketed):
    # the floor beside a 1 m bump is 0 + s * 1 m: above it by more than 0.5 m iff s < 0.5
    z = np.zeros((1, 5), np.float32)
    z[0, 2] = 1.0
    out = dr.find_bracketed(z, np.ones(z.shape, bool), (1.0, 1.0), slope=slope, height_m=0.5, reach_m=2.0)
    assert bool(out[0, 2]) is bracketed and out.sum() == int(bracketed)


@pytest.mark.parametrize("reach_m,bracketed", [(1.0, False), (2.0, True)])
def test_reach(reach_m, bracketed):
    # a 3-cell wide object: its middle sees lower ground only two cells away
    z = np.zeros((1, 9), np.float32)
    z[0, 3:6] = 2.0
    out = dr.find_bracketed(z, np.ones(z.shape, bool), (1.0, 1.0), slope=0.0, height_m=0.5, reach_m=reach_m)
    assert bool(out[0, 4]) is bracketed


@pytest.mark.parametrize("gx,gy", [(2.0, 0.0), (0.0, -1.5), (0.7, 0.7), (3.0, -2.0)])
def test_no_plane_cell_is_bracketed_whatever_its_slope(gx, gy):
    jj, ii = np.meshgrid(np.arange(15), np.arange(13))
    z = (gx * jj + gy * ii).astype(np.float32)
    out = dr.find_bracketed(z, np.ones(z.shape, bool), (1.0, 1.0), slope=0.0, height_m=0.1, reach_m=6.0)
    assert not out.any()


def test_terrace_edge_is_not_bracketed():
    z = np.zeros((9, 12), np.float32)
    z[:, 6:] = 3.0
    out = dr.find_bracketed(z, np.ones(z.shape, bool), (1.0, 1.0), slope=0.0, height_m=0.5, reach_m=5.0)
    assert not out.any()


def test_only_ground_cells_are_sources_and_nodata_ignored():
    z = np.zeros((1, 7), np.float32)
    z[0, 3] = 1.0
    z[0, 0:3] = -5.0
    ground = np.ones(z.shape, bool)
    ground[0, 0:3] = False                  # lower, but not ground: no floor on the left
    out = dr.find_bracketed(z, ground, (1.0, 1.0), slope=0.0, height_m=0.5, reach_m=3.0)
    assert not out.any()
    z2 = z.copy()
    z2[0, 0:3] = np.nan                     # nodata is never a source either
    assert not dr.find_bracketed(z2, np.ones(z.shape, bool), (1.0, 1.0), slope=0.0, height_m=0.5,
                                 reach_m=3.0).any()


@pytest.mark.parametrize("kw", [{"slope": float("nan"), "height_m": 0.5}, {"slope": -0.1, "height_m": 0.5},
                                {"slope": 0.1, "height_m": 0.0}])
def test_bad_parameters(kw):
    with pytest.raises(ValueError, match="slope|height_m"):
        dr.find_bracketed(np.zeros((3, 3), np.float32), np.ones((3, 3), bool), (1.0, 1.0), **kw)


def test_refine_ground_turns_bracketed_ground_into_objects_only():
    z = np.zeros((7, 9), np.float32)
    z[3, 4] = 1.0
    z[0, 0] = np.nan
    mask = np.zeros(z.shape, np.uint8)
    mask[0, 0] = NODATA
    mask[5, 5] = OBJECT
    new, info = dr.refine_ground(z, mask, (1.0, 1.0), tolerance_m=0.5, slope=float("nan"))
    expect = mask.copy()
    expect[3, 4] = OBJECT
    np.testing.assert_array_equal(new, expect)
    assert mask[3, 4] == GROUND                 # the input is not modified
    assert info["refine_slope"] == 0.0 and info["refine_removed_share"] == pytest.approx(1 / 61)


def test_canopy_gaps_the_vote_keeps_are_removed():
    """A closed canopy over gentle ground (synthetic truth): the three members keep low crown
    edges and the bottoms of narrow gaps as ground, and the DTM under the crowns rests on them.
    The refinement removes them: fewer kept objects, hardly any true ground lost, a better DTM."""
    s = make_canopy(192.0, 1.0, seed=3, noise_m=0.05)
    z = s.dsm.astype(np.float32)
    params = resolve_dtm_params(z, (1.0, 1.0))
    votes = sum((get_method(n).run(z, (1.0, 1.0), **p).mask == GROUND).astype(np.uint8)
                for n, p in params["members"].items())
    vote_ground = votes >= 2
    vote_dtm = fill_gaps(z, fill=~vote_ground)
    res = filter_dtm(z, (1.0, 1.0), **{k: v for k, v in params.items() if k != "input_description"})
    ground = res.mask == GROUND
    truth = s.mask == 0
    kept_before = np.count_nonzero(vote_ground & ~truth)
    kept_after = np.count_nonzero(ground & ~truth)
    assert kept_before > 5       # the failure is there (10 cells; 17 before the morphological enclosed tiers)
    assert kept_after < 0.7 * kept_before
    assert np.count_nonzero(vote_ground & truth & ~ground) < 0.01 * np.count_nonzero(truth)
    rmse = lambda d: float(np.sqrt(np.mean((d - s.dtm) ** 2)))     # noqa: E731
    assert rmse(res.dtm) < 0.9 * rmse(vote_dtm)
    assert res.info["refine_removed_share"] > 0
    assert math.isclose(res.info["refine_reach_m"], params["refine_reach_m"]) and params["refine_reach_m"] >= dr.REACH_M


@pytest.mark.parametrize("seed", range(3))
def test_edge_test_keeps_a_steep_bank_whose_heights_scatter_in_their_cells(seed):
    # a bank rising 0.6 m a metre (a dike's face, 31 degrees) on 2 m cells, each height a point anywhere in its
    # cell (a lowest-point grid), given back by the bank stage (spared): along the contour the heights scatter
    # by up to 1.2 m, which the fields' continuation tolerance (0.3 m) does not cover; beside an object the edge
    # test took the face cell by cell (a quarter to a third of the ground) before it allowed, on the banks, for
    # where the heights lie on ground that steep
    i, j = np.mgrid[0:16, 0:18]
    u = np.random.default_rng(seed).uniform(-0.5, 0.5, i.shape)
    z = (0.6 * 2.0 * (j + u)).astype(np.float32)
    hole = (i >= 6) & (i < 10) & (j >= 7) & (j < 11)
    z[hole] += 3.0
    vote = np.where(hole, OBJECT, GROUND).astype(np.uint8)
    kw = dict(tolerance_m=0.5, slope=0.05, edge_tolerance_m=0.3, line_tolerance_m=0.3)
    _, info = dr.refine_ground(z, vote, (2.0, 2.0), spared=~hole, **kw)
    assert info["refine_edge_removed_share"] < 0.05
    _, info = dr.refine_ground(z, vote, (2.0, 2.0), **kw)        # not banks: no allowance, the face is taken
    assert info["refine_edge_removed_share"] > 0.2


def test_edge_spike_in_a_courtyard_is_removed_and_the_dtm_no_longer_rests_on_it():
    # A large building (a 10 m block, 72 m square) with a 7 m courtyard of bare ground; in the courtyard's
    # corners a 1.5 m shed against the walls that the vote took as ground. Every line through a corner runs
    # into the building on one side and finds no ground within the reach there: nothing brackets it (the
    # floors alone keep it, as on main); it stands above every continuation of the courtyard's ground.
    n = 80
    z = np.zeros((n, n), np.float32)
    truth = np.zeros((n, n), bool)
    truth[4:76, 4:76] = True
    truth[34:41, 34:41] = False                     # the courtyard
    z[truth] = 10.0
    corners = [(34, 34), (34, 40), (40, 34), (40, 40)]
    for r, c in corners:
        z[r, c] = 1.5
        truth[r, c] = True
    vote = np.where(truth, OBJECT, GROUND).astype(np.uint8)
    for r, c in corners:
        vote[r, c] = GROUND                         # what the members kept
    bracketed = dr.find_bracketed(z, vote == GROUND, (1.0, 1.0), slope=0.1, height_m=0.5)
    assert not any(bracketed[r, c] for r, c in corners)
    mask, info = dr.refine_ground(z, vote, (1.0, 1.0), tolerance_m=0.5, slope=0.1)
    np.testing.assert_array_equal(mask == OBJECT, truth)
    assert info["refine_edge_removed_share"] == pytest.approx(4 / np.count_nonzero(vote == GROUND))
    dtm = fill_gaps(z, fill=mask == OBJECT)
    assert float(np.abs(dtm).max()) < 1e-3          # the ground is flat at 0 everywhere, under the sheds too
    kept = fill_gaps(z, fill=vote == OBJECT)        # the vote's DTM rests on the sheds: 1.5 m there and
    assert all(kept[r, c] == 1.5 for r, c in corners)                    # raised under the walls behind them
    assert min(kept[r + dr_, c + dc] for (r, c), (dr_, dc) in zip(corners, [(-1, -1), (-1, 1), (1, -1), (1, 1)])) > 0.2


def test_refine_reach_grows_on_gentle_terrain_within_its_limits():
    assert dr.refine_reach(0.5, 0.6, 500.0) == dr.REACH_M                  # steep: 3 x 0.5 / 0.6 = 2.5 m < 12 m
    assert dr.refine_reach(0.5, 0.036, 500.0) == pytest.approx(3 * 0.5 / 0.036)
    assert dr.refine_reach(0.5, 0.001, 100.0) == 100.0                      # the limit
    assert dr.refine_reach(0.5, 0.0, 100.0) == 100.0                        # flat: as far as the limit
    assert dr.refine_reach(0.5, float("nan"), 100.0) == 100.0
    assert dr.refine_reach(0.5, 0.01, 5.0) == dr.REACH_M                    # never below REACH_M


def test_find_smooth_exact():
    z = np.add.outer(0.3 * np.arange(6.0), -0.7 * np.arange(7.0)).astype(np.float32)   # a plane: smooth
    every = np.ones(z.shape, bool)
    np.testing.assert_array_equal(dr.find_smooth(z, every, 0.01), every)
    z[:, 4:] += 1.2                                 # a 1.2 m step between columns 3 and 4
    got = dr.find_smooth(z, every, 1.0)
    # second differences of 1.2 m are centred on columns 3 and 4; their 3 x 3 neighbourhoods: columns 2-5
    np.testing.assert_array_equal(got, np.broadcast_to(~np.isin(np.arange(7), [2, 3, 4, 5]), z.shape))
    np.testing.assert_array_equal(dr.find_smooth(z, every, 1.2 + 1e-3), every)
    only = np.zeros(z.shape, bool)
    only[2, 0] = only[2, 3] = True                  # only the given cells are answered
    np.testing.assert_array_equal(dr.find_smooth(z, only, 1.0), only & got)
    z[:, 4:] = np.nan                               # nodata: its differences are not counted
    np.testing.assert_array_equal(dr.find_smooth(z, every, 0.01), every)


def test_smooth_convex_crest_stays_ground():
    # an embankment's rounded crest: z = 3 - 0.02 (x - 30)^2; at 12 m from the crest the ground lies
    # 2.88 m lower, more than the slope allowance 0.1 x 12 m plus dh: the floors bracket the crest
    # (as on main); its second differences are 0.04 m: smooth ground, kept.
    x = np.arange(61.0)
    z = np.broadcast_to(3.0 - 0.02 * (x - 30.0) ** 2, (21, 61)).astype(np.float32)
    vote = np.full(z.shape, GROUND, np.uint8)
    bracketed = dr.find_bracketed(z, vote == GROUND, (1.0, 1.0), slope=0.1, height_m=0.5)
    assert bracketed[:, 30].all()
    mask, info = dr.refine_ground(z, vote, (1.0, 1.0), tolerance_m=0.5, slope=0.1)
    assert (mask == GROUND).all()
    assert info["refine_removed_share"] == 0.0 and info["refine_smooth_kept_share"] > 0


def test_wide_shrubs_on_flat_land_need_the_longer_reach():
    # 40 m of rough shrubs (1.5 and 3 m, alternating) on flat land that the vote kept: 12 m from their
    # middle there is no ground, so the fixed reach leaves the middle as ground; the reach of gentle
    # terrain (3 x 0.5 m / 0.03 = 50 m) finds ground on both sides of every shrub cell.
    z = np.zeros((30, 90), np.float32)
    i, j = np.mgrid[5:25, 25:65]
    z[5:25, 25:65] = 1.5 + 1.5 * ((i + j) % 2)
    vote = np.full(z.shape, GROUND, np.uint8)
    reach = dr.refine_reach(0.5, 0.03, 500.0)
    assert reach == pytest.approx(50.0)
    fixed, _ = dr.refine_ground(z, vote, (1.0, 1.0), tolerance_m=0.5, slope=0.03, reach_m=dr.REACH_M)
    assert (fixed[5:25, 40:50] == GROUND).any()     # the middle: out of the fixed reach
    mask, _ = dr.refine_ground(z, vote, (1.0, 1.0), tolerance_m=0.5, slope=0.03, reach_m=reach)
    shrubs = np.zeros(z.shape, bool)
    shrubs[5:25, 25:65] = True
    np.testing.assert_array_equal(mask == OBJECT, shrubs)


def test_continue_ground_exact():
    """Disputed cells on smooth ground joined to the anchors within the reach become ground; a step,
    a path longer than the reach, or voted ground cut from the anchors does not carry it."""
    z = np.zeros((5, 12), np.float32)
    z[:, 4:] = 0.5 * np.arange(1, 9)                 # a bank rising at 0.5 m per cell from column 4
    disputed = np.zeros(z.shape, bool)
    disputed[:, 4:] = True
    anchors = ~disputed
    got = dr.continue_ground(z, disputed, anchors, anchors, height_m=1.0, reach_cells=20)
    np.testing.assert_array_equal(got, disputed)     # a plane continues the flat ground: all ground
    # the reach: 3 cells from the anchors, columns 4-6
    got = dr.continue_ground(z, disputed, anchors, anchors, height_m=1.0, reach_cells=3)
    np.testing.assert_array_equal(got.all(axis=0), np.isin(np.arange(12), [4, 5, 6]))
    assert got.any(axis=0).sum() == 3
    # a wall: a 2 m step at column 4 (second differences 2 m around it); beyond its 3 x 3 neighbourhood
    # the roof is smooth but only joined through the step
    wall = z.copy()
    wall[:, 4:] = 2.0
    assert not dr.continue_ground(wall, disputed, anchors, anchors, height_m=1.0, reach_cells=20).any()
    # voted ground cut from the anchors by objects no member calls ground (the walls around a patch of voted
    # ground on a roof): no continuation from it
    anchors2 = np.zeros(z.shape, bool)
    anchors2[:, :2] = True
    ground = anchors2.copy()
    ground[:, 11] = True
    got = dr.continue_ground(z, disputed & ~ground, ground, anchors2, height_m=1.0, reach_cells=20)
    assert not got.any()
    # nodata is never continued; no anchor or no reach: nothing
    holes = z.copy()
    holes[2, 8] = np.nan
    got = dr.continue_ground(holes, disputed, anchors, anchors, height_m=1.0, reach_cells=20)
    assert not got[2, 8] and got[0, 8]
    assert not dr.continue_ground(z, disputed, anchors, np.zeros_like(anchors), height_m=1.0, reach_cells=20).any()
    assert not dr.continue_ground(z, disputed, anchors, anchors, height_m=1.0, reach_cells=0).any()


def test_continue_lines_exact():
    """A disputed cell on the straight continuation of three anchors in a line, with the ground dropping beyond it
    (a step's top), becomes ground in every direction; a bump, a hedge, a roof without anchors, nodata, or
    a too short reach do not."""
    z = np.zeros((7, 9), np.float32)
    z[:, :4] = -3.0                                  # a 3 m wall down to the left of column 4
    disputed = np.zeros(z.shape, bool)
    disputed[:, 4] = True
    anchors = ~disputed
    got = dr.continue_lines(z, disputed, anchors, tolerance_m=0.5, reach_cells=3)
    np.testing.assert_array_equal(got, disputed)     # the upper edge of the wall: ground
    for k in range(4):                               # every orientation: the same on the rotated arrays
        zr, dr_, ar = np.rot90(z, k), np.rot90(disputed, k), np.rot90(anchors, k)
        np.testing.assert_array_equal(dr.continue_lines(zr, dr_, ar, tolerance_m=0.5, reach_cells=3), dr_)
    # a diagonal wall: the edge continues the anchors along the diagonals and rows
    i, j = np.mgrid[0:9, 0:9]
    zd = np.where(i + j < 8, -3.0, 0.1 * (i + j)).astype(np.float32)
    dd = (i + j == 8)
    got = dr.continue_lines(zd, dd, ~dd, tolerance_m=0.5, reach_cells=3)
    assert got[dd & (i >= 2) & (j >= 2)].all() and not got[~dd].any()   # near the corners: too few cells
    # the cell above (a hedge) or below (a ditch) the continuation by more than the tolerance: kept
    for h in (0.6, -0.6):
        zz = z.copy()
        zz[:, 4] = h
        assert not dr.continue_lines(zz, disputed, anchors, tolerance_m=0.5, reach_cells=3).any()
    # a low bump on level ground: the ground beyond continues the line (no drop), not a step's top
    bump = np.zeros(z.shape, np.float32)
    bump[:, 4] = 0.4
    assert not dr.continue_lines(bump, disputed, anchors, tolerance_m=0.5, reach_cells=3).any()
    # the drop beyond must exceed the tolerance of the line continued two cells (0.5 sqrt(14/6) = 0.764 m)
    small = z.copy()
    small[:, :4] = -0.7
    assert not dr.continue_lines(small, disputed, anchors, tolerance_m=0.5, reach_cells=3).any()
    small[:, :4] = -0.8
    assert dr.continue_lines(small, disputed, anchors, tolerance_m=0.5, reach_cells=3)[:, 4].all()
    # no anchors on the upper side (a roof's edge: the vote's ground there is not undisputed)
    roof = anchors.copy()
    roof[:, 5:] = False
    assert not dr.continue_lines(z, disputed, roof, tolerance_m=0.5, reach_cells=3).any()
    # nodata, no reach, bad tolerance
    holes = z.copy()
    holes[3, 4] = np.nan
    got = dr.continue_lines(holes, disputed, anchors, tolerance_m=0.5, reach_cells=3)
    assert not got[3, 4] and got[0, 4]
    assert not dr.continue_lines(z, disputed, anchors, tolerance_m=0.5, reach_cells=2).any()
    # the side must be straight over three cells: a kink in it (rough ground, low vegetation kept by all)
    kink = z.copy()
    kink[:, 7] = 0.6
    assert not dr.continue_lines(kink, disputed, anchors, tolerance_m=0.5, reach_cells=3)[:, 4].any()
    with pytest.raises(ValueError, match="tolerance_m"):
        dr.continue_lines(z, disputed, anchors, tolerance_m=0.0, reach_cells=3)


def test_continue_lines_gives_back_a_face_between_ground():
    """A cell of a step's face (not vertical) between ground cells along a line, more than the continuation's
    tolerance below the higher and above the lower, is ground; an object on a slope (near its uphill neighbour)
    is not; a face two cells wide with no ground next to either cell is not (the passes need known ground)."""
    z = np.zeros((7, 9), np.float32)
    z[:, :4] = -4.0
    z[:, 4] = -2.0                                    # the face between the levels -4 and 0
    disputed = np.zeros(z.shape, bool)
    disputed[:, 4] = True
    np.testing.assert_array_equal(dr.continue_lines(z, disputed, ~disputed, tolerance_m=0.5, reach_cells=3),
                                  disputed)
    z[:, 4] = -0.7                                    # 0.7 m below the upper level: within 0.764 m, kept
    assert not dr.continue_lines(z, disputed, ~disputed, tolerance_m=0.5, reach_cells=3).any()
    slope = np.tile(-0.7 * np.arange(9, dtype=np.float32)[::-1], (7, 1))
    slope[:, 4] += 0.5                                # a bush 0.5 m high on a 35 degree slope
    assert not dr.continue_lines(slope, disputed, ~disputed, tolerance_m=0.5, reach_cells=3).any()
    wide = np.zeros(z.shape, np.float32)
    wide[:, :3] = -4.0
    wide[:, 3], wide[:, 4] = -2.6, -1.3
    d2 = np.zeros(z.shape, bool)
    d2[:, 3:5] = True
    assert not dr.continue_lines(wide, d2, ~d2, tolerance_m=0.5, reach_cells=3).any()


def test_continue_lines_in_blocks_equals_one_pass():
    """A cell's decision depends on cells at most ``reach_cells`` away (``reach_cells // 3`` passes of three
    cells): blocks read with that halo give the one pass, on a quarry whose benches' tops it gives back."""
    from bare_earth.core.synthetic_sites import make_site
    s = make_site("quarry", 2.0, "lowest")
    steps = ndimage.maximum_filter(s.dtm, 3) - ndimage.minimum_filter(s.dtm, 3) > 3.0
    disputed = steps & (s.mask == GROUND)                 # the benches' faces and edges
    anchors = ~steps & (s.mask == GROUND)
    reach = 9
    whole = dr.continue_lines(s.dsm, disputed, anchors, tolerance_m=0.5, reach_cells=reach)
    assert whole.sum() > 100
    got = in_blocks(lambda wr, wc: dr.continue_lines(s.dsm[wr, wc], disputed[wr, wc], anchors[wr, wc],
                                                     tolerance_m=0.5, reach_cells=reach),
                    s.dsm.shape, 40, reach)
    np.testing.assert_array_equal(got, whole)


@pytest.mark.parametrize("chunk", [7, 1 << 18])
def test_continue_lines_with_a_pool_equals_one_thread(monkeypatch, chunk):
    """The directions of each pass on chunks of the candidates, some taken by a second thread: the cells given
    back by one thread exactly (lines across the quarry's benches, along them and the benches' faces)."""
    from concurrent.futures import ThreadPoolExecutor

    from bare_earth.core.synthetic_sites import make_site
    s = make_site("quarry", 2.0, "lowest")
    steps = ndimage.maximum_filter(s.dtm, 3) - ndimage.minimum_filter(s.dtm, 3) > 3.0
    disputed = steps & (s.mask == GROUND)
    anchors = ~steps & (s.mask == GROUND)
    kw = dict(tolerance_m=0.5, reach_cells=9, step_m=0.5, ground=s.mask == GROUND, along_slope=0.1,
              cell_size=(2.0, 2.0))
    ref = dr.continue_lines(s.dsm, disputed, anchors, **kw)
    monkeypatch.setattr(dr, "LINES_CHUNK", chunk)
    with ThreadPoolExecutor(max_workers=1) as pool:
        got = dr.continue_lines(s.dsm, disputed, anchors, **kw, pool=pool)
    assert ref.sum() > 100
    np.testing.assert_array_equal(got, ref)


def test_continue_ground_judged_on_ground_passes_objects_standing_on_the_bank():
    """judge_on_ground: the smoothness of a disputed cell is read on the ground and disputed cells
    (find_smooth's ground), so an object standing on a bank (a bush the caller does not dispute)
    does not cut the bank around it; a wall still does."""
    z = np.zeros((7, 14), np.float32)
    z[:, 4:] = 0.5 * np.arange(1, 11)                 # a bank rising at 0.5 m per cell from column 4
    disputed = np.zeros(z.shape, bool)
    disputed[:, 4:] = True
    bush = np.zeros(z.shape, bool)
    bush[2:5, 7] = True                               # a 3-cell bush, 3 m high, across the bank
    z[bush] += 3.0
    disputed &= ~bush
    anchors = ~disputed & ~bush
    plain = dr.continue_ground(z, disputed, anchors, anchors, height_m=1.0, reach_cells=20)
    judged = dr.continue_ground(z, disputed, anchors, anchors, height_m=1.0, reach_cells=20, judge_on_ground=True)
    assert not plain[2:5, 6].any() and not plain[2:5, 8].any()   # its 3 x 3 neighbours read its step
    np.testing.assert_array_equal(judged, disputed)
    wall = z.copy()
    wall[:, 4:] = 2.0
    assert not dr.continue_ground(wall, disputed, anchors, anchors, height_m=1.0, reach_cells=20,
                                  judge_on_ground=True).any()


@pytest.mark.parametrize("kw", [{"height_m": 0.0}, {"height_m": float("nan")}])
def test_continue_ground_bad_parameters(kw):
    z = np.zeros((4, 4), np.float32)
    with pytest.raises(ValueError, match="height_m"):
        dr.continue_ground(z, z > 0, z == 0, z == 0, reach_cells=3, **kw)
    with pytest.raises(ValueError, match="share the DSM's shape"):
        dr.continue_ground(z, np.zeros((3, 4), bool), z == 0, z == 0, height_m=1.0, reach_cells=3)


def test_continue_ground_blocked_equals_one_pass():
    """On windows of a block plus continuation_cells + 2 cells, the one-pass result in the block."""
    rng = np.random.default_rng(7)
    n = 150
    i, j = np.mgrid[0:n, 0:n].astype(np.float32)
    z = (10 + 3.0 * np.clip((j - 60) / 8.0, 0, 1) + rng.normal(0, 0.03, (n, n))).astype(np.float32)  # a bank
    z[20:40, 20:45] += 8.0                                                                             # a house
    z[100:130, 90:120] += 6.0
    disputed = (j >= 55) & (j < 75) | (z > 15)                # the bank and the roofs
    anchors = (j < 55) & ~(z > 15)
    ground = anchors | (j >= 75) & ~(z > 15)
    anchors &= i < 120                                        # anchors on part of the flat land only
    reach = dr.continuation_cells((1.0, 1.0), 30.0)
    whole = dr.continue_ground(z, disputed, ground, anchors, height_m=1.0, reach_cells=reach)
    assert whole.any() and not whole[z > 15].any()
    halo = reach + 2

    def part(wr, wc):
        return dr.continue_ground(z[wr, wc], disputed[wr, wc], ground[wr, wc], anchors[wr, wc], height_m=1.0,
                                  reach_cells=reach)

    for b in (23, 40):
        assert np.array_equal(in_blocks(part, z.shape, b, halo), whole)


@pytest.mark.parametrize("tile", [4, 8, 64])
def test_reached_on_tiles_equals_the_dilation_of_the_whole_raster(monkeypatch, tile):
    """continue_ground's bounded dilation run only on the tiles holding a target (each grown by the reach):
    the cells of the dilation of the whole raster, on random sources and paths, the targets in a few patches
    or anywhere (tiles of 4 and 8 cells cut the paths; 64 or targets anywhere: one pass over the raster)."""
    from scipy import ndimage
    monkeypatch.setattr(dr, "_REACH_TILE", tile)
    rng = np.random.default_rng(tile)
    tiled = 0
    for k in range(40):
        rows, cols = (int(v) for v in rng.integers(20, 200, 2))
        allowed = rng.random((rows, cols)) < rng.uniform(0.3, 0.9)
        sources = rng.random((rows, cols)) < rng.uniform(0.001, 0.05)
        reach = int(rng.integers(1, 8 if k % 2 else 20))
        if k % 4:                                               # a few patches
            targets = np.zeros((rows, cols), bool)
            for _ in range(int(rng.integers(1, 4))):
                r0, c0 = rng.integers(0, rows - 3), rng.integers(0, cols - 3)
                targets[r0:r0 + 3, c0:c0 + 3] = True
        else:
            targets = rng.random((rows, cols)) < rng.uniform(0.0005, 0.3)
        targets &= allowed
        want = ndimage.binary_dilation(sources, np.ones((3, 3), bool), iterations=reach,
                                       mask=allowed | sources) & targets
        assert np.array_equal(dr._reached(sources, allowed | sources, targets, reach), want)
        t = max(tile, 4 * reach)
        r, c = np.divmod(np.flatnonzero(targets), cols)
        tiled += np.unique(r // t * cols + c // t).size * (t + 2 * reach) ** 2 < targets.size
    assert tiled >= (10 if tile < 64 else 0)          # the tiles ran (not only the one pass)
    # a lone source exactly the reach away in each of the 8 directions from a cell at a tile's first or last
    # row and column is reached, one cell farther not
    reach = 6
    t = max(tile, 4 * reach)
    for at in (2 * t, 2 * t - 1):
        for dr_, dc_ in ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)):
            for far, want in ((reach, True), (reach + 1, False)):
                sources, targets = np.zeros((4 * t, 4 * t), bool), np.zeros((4 * t, 4 * t), bool)
                targets[at, at] = True
                sources[at + dr_ * far, at + dc_ * far] = True
                assert dr._reached(sources, np.ones(sources.shape, bool), targets, reach)[at, at] == want


def test_continuation_cells():
    assert dr.continuation_cells((1.0, 1.0)) == 12
    assert dr.continuation_cells((2.0, 4.0), 30.0) == 15
    assert dr.continuation_cells((50.0, 50.0)) == 1


def test_find_smooth_judged_on_the_ground_beside_an_object():
    # a dike's crest along the rows (0.45 m a cell down on both sides: second differences 0.9 m) with a
    # 5 m tree beside it on the crest line: the tree's step makes the whole neighbourhood rough; the
    # ground's own second differences (13 of 18 read ground only) are smooth
    prof = np.array([0.0, 0.0, 0.45, 0.9, 0.45, 0.0, 0.0], np.float32)
    z = np.repeat(prof[:, None], 7, axis=1)
    z[3, 4] = 5.0
    ground = z < 2.0
    cell = np.zeros(z.shape, bool)
    cell[3, 3] = True
    assert not dr.find_smooth(z, cell, 1.0).any()
    np.testing.assert_array_equal(dr.find_smooth(z, cell, 1.0, ground=ground), cell)
    assert not dr.find_smooth(z, cell, 0.8, ground=ground).any()            # the crest bends by 0.9 m
    # a cell among objects: fewer than half its second differences read ground only, judged with them
    z2 = z.copy()
    z2[2:5, 2:5] = 5.0
    z2[3, 3] = 0.9
    g2 = z2 < 2.0
    assert not dr.find_smooth(z2, cell, 1.0, ground=g2).any()
    assert dr.SMOOTH_DIFFERENCES == 18


def test_edge_tolerance_exact():
    assert dr.edge_tolerance(0.5, 0.02) == pytest.approx(3.0 * math.sqrt(6.0) * 0.02)
    assert dr.edge_tolerance(0.5, 0.1) == 0.5                               # never above t
    assert dr.edge_tolerance(0.5, float("nan")) == 0.5                      # noise not measurable: t


def test_refine_ground_edge_tolerance():
    # a bush (2 m) on flat ground with a 0.3 m skirt cell at its edge: above the continuation of the
    # ground by 0.3 m, less than dh 0.5 m, more than an edge tolerance of 0.15 m
    z = np.zeros((9, 11), np.float32)
    z[3:6, 5:8] = 2.0
    z[4, 4] = 0.3
    vote = np.where(z > 1.0, OBJECT, GROUND).astype(np.uint8)
    kept, info = dr.refine_ground(z, vote, (1.0, 1.0), tolerance_m=0.5, slope=0.05, reach_m=3.0)
    assert kept[4, 4] == GROUND and info["refine_edge_tolerance_m"] == 0.5
    mask, info = dr.refine_ground(z, vote, (1.0, 1.0), tolerance_m=0.5, slope=0.05, reach_m=3.0,
                                  edge_tolerance_m=0.15)
    expect = vote.copy()
    expect[4, 4] = OBJECT
    np.testing.assert_array_equal(mask, expect)
    assert info["refine_edge_tolerance_m"] == 0.15
    same, info = dr.refine_ground(z, vote, (1.0, 1.0), tolerance_m=0.5, slope=0.05, reach_m=3.0,
                                  edge_tolerance_m=2.0)                     # never above dh
    np.testing.assert_array_equal(same, kept)
    assert info["refine_edge_tolerance_m"] == 0.5


def test_dike_with_trees_stays_ground_while_bushes_on_flat_land_go():
    # flat land (noise-free) with a smooth dike 1.2 m high along the rows, trees (6 m) on its crest every
    # 6 cells, and bushes (1.2 m, 3 x 3) on the flat land, all but the trees voted ground: the crest is
    # bracketed by the lower land on both sides; beside a tree the tree's step made its neighbourhood rough
    # and cut the crest there; judged on the ground, it is smooth and stays; the bushes are still found
    n = 41
    i = np.arange(n, dtype=np.float32)
    across = np.clip(1.2 - 0.3 * np.abs(i - 20.0), 0.0, None)             # 8 m wide, 0.3 m a cell
    z = np.repeat(across[:, None], 60, axis=1).astype(np.float32)
    trees = np.zeros(z.shape, bool)
    trees[20, 3::6] = True
    z[trees] = 6.0
    bushes = np.zeros(z.shape, bool)
    for c in (10, 30, 50):
        bushes[5:8, c:c + 3] = True
        bushes[33:36, c:c + 3] = True
    z[bushes] = 1.2
    vote = np.where(trees, OBJECT, GROUND).astype(np.uint8)
    beside = np.zeros(z.shape, bool)
    beside[20, 2::6] = beside[20, 4::6] = True
    beside &= ~trees
    old = dr.find_smooth(z, beside, 1.0)
    assert not old.any()                                                    # with the trees' steps: rough
    mask, info = dr.refine_ground(z, vote, (1.0, 1.0), tolerance_m=0.5, slope=0.03, reach_m=12.0)
    assert (mask[beside] == GROUND).all()                                   # the crest beside the trees stays
    assert (mask[19:22][~trees[19:22]] == GROUND).all()
    assert (mask[bushes] == OBJECT).all()                                   # the bushes are found
    assert (mask[trees] == OBJECT).all()


def test_skirts_of_bushes_found_by_the_edge_tolerance_of_the_grounds_spread():
    # lidar-like ground (noise 0.02 m) with bushes (1.5 m, 3 x 3), each with a skirt cell 0.3 m high in the
    # middle of each side (low vegetation the vote kept): the skirt stands less than t = 0.5 m above the
    # ground's continuation, more than three standard deviations of it (sqrt(6) x the spread); the noisy
    # ground stays ground
    from bare_earth.core.estimate import lowest_point_spread, repeated_height_share
    rng = np.random.default_rng(3)
    z = rng.normal(0.0, 0.02, (60, 60)).astype(np.float32)
    bush = np.zeros(z.shape, bool)
    skirt = np.zeros(z.shape, bool)
    for r in (10, 30, 48):
        for c in (8, 27, 46):
            skirt[r - 1, c + 1] = skirt[r + 3, c + 1] = skirt[r + 1, c - 1] = skirt[r + 1, c + 3] = True
            bush[r:r + 3, c:c + 3] = True
    z[skirt] += 0.3
    z[bush] += 1.5
    vote = np.where(bush, OBJECT, GROUND).astype(np.uint8)
    spread = lowest_point_spread(0.02, 0.0, 1.0, repeated_height_share(z))
    tol = dr.edge_tolerance(0.5, spread)
    assert tol == pytest.approx(3 * math.sqrt(6) * 0.02)
    kept, _ = dr.refine_ground(z, vote, (1.0, 1.0), tolerance_m=0.5, slope=0.05, reach_m=3.0)
    assert (kept[skirt] == GROUND).all()                                    # t: the skirts stay
    mask, info = dr.refine_ground(z, vote, (1.0, 1.0), tolerance_m=0.5, slope=0.05, reach_m=3.0,
                                  edge_tolerance_m=tol)
    np.testing.assert_array_equal(mask == OBJECT, bush | skirt)


def test_low_vegetation_along_crown_edges_found_along_one_line():
    # lidar-like ground (noise 0.02 m) with crowns (8 m, 5 x 5), each with low vegetation 0.4 m high along
    # one side (a strip of 3 cells the vote kept as ground): each strip cell is continued by its neighbours
    # along the edge, so none stands above every continuation; across the edge the ground continues to it
    # from neither side (the crown on one side, the ground 0.4 m lower on the other)
    from bare_earth.core.estimate import lowest_point_spread, repeated_height_share
    rng = np.random.default_rng(3)
    z = rng.normal(0.0, 0.02, (60, 60)).astype(np.float32)
    crown = np.zeros(z.shape, bool)
    strip = np.zeros(z.shape, bool)
    for r in (8, 27, 46):
        for c in (8, 27, 46):
            crown[r:r + 5, c:c + 5] = True
            strip[r + 1:r + 4, c - 1] = True
    z[strip] += 0.4
    z[crown] += 8.0
    vote = np.where(crown, OBJECT, GROUND).astype(np.uint8)
    spread = lowest_point_spread(0.02, 0.0, 1.0, repeated_height_share(z))
    et, lt = dr.edge_tolerance(0.5, spread), dr.continuation_tolerance(spread)
    assert et == lt == pytest.approx(3 * math.sqrt(6) * 0.02)
    kept, _ = dr.refine_ground(z, vote, (1.0, 1.0), tolerance_m=0.5, slope=0.05, reach_m=3.0, edge_tolerance_m=et)
    assert (kept[strip] == GROUND).all()                                    # every line: the strips stay
    mask, _ = dr.refine_ground(z, vote, (1.0, 1.0), tolerance_m=0.5, slope=0.05, reach_m=3.0, edge_tolerance_m=et,
                               line_tolerance_m=lt)
    np.testing.assert_array_equal(mask == OBJECT, crown | strip)            # the noisy ground stays
    # the DTM under the crowns no longer rests on the strips
    dtm_kept = fill_gaps(z, fill=kept != GROUND)
    dtm = fill_gaps(z, fill=mask != GROUND)
    assert np.abs(dtm[crown]).max() < 0.1 < np.abs(dtm_kept[crown]).max()


def test_continuation_tolerance_exact():
    assert dr.continuation_tolerance(0.1) == pytest.approx(3.0 * math.sqrt(6.0) * 0.1)
    assert dr.edge_tolerance(0.5, 0.1) == 0.5 < dr.continuation_tolerance(0.1)   # unbounded by t
    assert math.isnan(dr.continuation_tolerance(float("nan")))


# ---- the seen ground's slope along each line (dtm_refine.line_slopes, issues 12 and 13)
@pytest.mark.parametrize("n", [1, 3, 6])
@pytest.mark.parametrize("di,dj", [(0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (-1, -1), (1, -1), (-1, 1)])
def test_floor_at_equals_brute_force(n, di, dj):
    """Each cell's floor with its own rise per step: ``min_k zg[x - k d] + k inc[x]`` (at the cells asked)."""
    rng = np.random.default_rng(n)
    zg = rng.normal(0, 2, (14, 11)).astype(np.float32)
    zg[rng.random(zg.shape) < 0.3] = np.inf
    inc = rng.uniform(0, 0.5, zg.shape).astype(np.float32)
    a, b = 3, 10
    i, j = np.indices((b - a, zg.shape[1]))
    zp = dr._padded(zg, n, n, np.float32(np.inf))          # every term within the padding
    w = zp.shape[1]
    x = ((i + a + n) * w + j + n).ravel()
    got = dr._floor_at(zp.ravel(), x, inc[a:b].ravel(), n, di * w + dj).reshape(i.shape)
    rows, cols = zg.shape
    want = np.full((b - a, cols), np.inf)
    for i in range(a, b):
        for j in range(cols):
            for k in range(n + 1):
                r, c = i - k * di, j - k * dj
                if 0 <= r < rows and 0 <= c < cols:
                    want[i - a, j] = min(want[i - a, j], zg[r, c] + k * inc[i, j])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-5)


def test_halo_with_the_planes_of_the_seen_ground():
    # the floors' reach plus one, the planes' squares (half-side the reach), the smoothness test's 2 cells (at
    # least the step tops' 5), the edge test's 7 and the raised band's (3 x 7 at 1 m, 3 x 3 at 4 m)
    assert dr.refine_halo((1.0, 1.0), 12.0, along_ground=True) == 13 + 12 + 2 + 7 + 21
    assert dr.refine_halo((4.0, 4.0), 12.0, along_ground=True) == 4 + 3 + 2 + 7 + 9


def test_line_slopes_of_a_plane_and_a_ridge():
    """On a plane the slope along each line is the plane's along it (nil along the contour); across a ridge
    each cell takes the largest slope of the planes along the line within the reach (its crest the flanks')."""
    y, x = np.mgrid[0:40, 0:40].astype(np.float32)
    plane = dr.seen_ground_gradient(0.6 * x, np.ones(x.shape, bool), (1.0, 1.0), reach_m=4.0)
    along, magnitude = dr.line_slopes(plane, (1.0, 1.0), reach_m=4.0)
    np.testing.assert_allclose(along[(0, 1)], 0.6, atol=1e-4)
    np.testing.assert_allclose(along[(1, 0)], 0.0, atol=1e-4)
    np.testing.assert_allclose(along[(1, 1)], 0.6 / math.sqrt(2), atol=1e-4)
    np.testing.assert_allclose(along[(1, -1)], 0.6 / math.sqrt(2), atol=1e-4)
    np.testing.assert_allclose(magnitude, 0.6, atol=1e-4)
    ridge = -0.02 * (x - 20) ** 2                      # crest on column 20, slope 0.04 per metre from it
    along, _ = dr.line_slopes(dr.seen_ground_gradient(ridge, np.ones(x.shape, bool), (1.0, 1.0), 4.0), (1.0, 1.0),
                              reach_m=4.0)
    inner = along[(0, 1)][:, 8:32]                      # planes whole (4 cells) over their reach (4 cells)
    want = np.broadcast_to(0.04 * (np.abs(np.arange(8, 32) - 20) + 4), inner.shape)
    np.testing.assert_allclose(inner, want, atol=1e-4)


def test_a_bush_on_a_steep_hillside_is_bracketed_along_the_contour():
    """A 1 m bush on a 30 degree plane: the terrain's steep slope allows 0.6 m over a cell in every direction,
    so its floors stand within ``dh`` of it; along the contour the ground does not rise, and the seen ground's
    slope brackets it (by ``sqrt(dh^2 + (3 sqrt(2/12) |g| c)^2)`` = 0.87 m: where the heights lie in their
    cells). The plane itself, and a 0.8 m bush, are not bracketed."""
    y, x = np.mgrid[0:41, 0:41].astype(np.float32)
    z = (math.tan(math.radians(30.0)) * x).astype(np.float32)    # contours along the columns (rows step)
    z[20, 20] += 1.0
    z[10, 30] += 0.8
    ground = np.ones(z.shape, bool)
    kw = dict(slope=0.6, height_m=0.5, reach_m=12.0)
    assert not dr.find_bracketed(z, ground, (1.0, 1.0), **kw).any()
    seen = dr.seen_ground_gradient(z, ground, (1.0, 1.0), 12.0)
    out = dr.find_bracketed(z, ground, (1.0, 1.0), seen_gradient=seen, **kw)
    expect = np.zeros(z.shape, bool)
    expect[20, 20] = True
    np.testing.assert_array_equal(out, expect)


@pytest.mark.parametrize("band_rows", [4, 64])
def test_bracketed_along_the_seen_ground_equals_brute_force(monkeypatch, band_rows):
    """find_bracketed with the seen ground's gradient (each cell's floors at its own slope along the line, found
    only where the floors at ``s`` and at 0 disagree) equals every cell's floors written out: ``min_k zg(x - k d)
    + k |d| min(s, along)`` from both sides of a line, below ``z - sqrt(dh^2 + (3 sqrt(2/12) min(s, |g|) c)^2)``."""
    monkeypatch.setattr(dr, "_BAND_ROWS", band_rows)
    rng = np.random.default_rng(5)
    y, x = np.mgrid[0:30, 0:33].astype(np.float32)
    z = (0.4 * x + 0.01 * (y - 15) ** 2 + rng.normal(0, 0.1, x.shape)).astype(np.float32)
    z[rng.random(z.shape) < 0.08] += 1.2                          # bushes
    z[rng.random(z.shape) < 0.02] = np.nan
    ground = rng.random(z.shape) > 0.15
    cell, s, dh, reach = (1.0, 1.0), 0.5, 0.5, 5.0
    seen = dr.seen_ground_gradient(z, ground, cell, reach)
    got = dr.find_bracketed(z, ground, cell, slope=s, height_m=dh, reach_m=reach, seen_gradient=seen)
    along, magnitude = dr.line_slopes(seen, cell, reach)
    zg = np.where(ground & np.isfinite(z), z, np.inf)
    gm = np.where(magnitude < s, magnitude, s)
    top = z - np.sqrt(np.float32(dh) ** 2 + np.float32(9 * 2 / 12) * gm * gm)
    rows, cols = z.shape
    want = np.zeros(z.shape, bool)
    for (di, dj), n in dr.refine_steps(cell, reach).items():
        inc = np.where(along[(di, dj)] < s, along[(di, dj)], s) * math.hypot(di, dj)
        for i in range(rows):
            for j in range(cols):
                floors = []
                for sd in (1, -1):
                    f = np.inf
                    for k in range(n + 1):
                        r, c = i - sd * k * di, j - sd * k * dj
                        if 0 <= r < rows and 0 <= c < cols:
                            f = min(f, zg[r, c] + k * inc[i, j])
                    floors.append(f)
                want[i, j] |= max(floors) < top[i, j]
    want &= ground & np.isfinite(z)
    assert want.sum() > 10 and np.array_equal(got, want)


def test_a_smooth_ridge_within_the_steep_slope_is_not_bracketed_along_the_seen_ground():
    """Convex ground the planes see (a ridge whose flanks reach the terrain's steep slope) keeps the allowance
    of its flanks' slopes: no cell is bracketed, crest included."""
    y, x = np.mgrid[0:60, 0:61].astype(np.float32)
    z = (-0.02 * (x - 30) ** 2 + 0.1 * y).astype(np.float32)
    ground = np.ones(z.shape, bool)
    seen = dr.seen_ground_gradient(z, ground, (1.0, 1.0), 12.0)
    assert not dr.find_bracketed(z, ground, (1.0, 1.0), slope=1.2, height_m=0.5, reach_m=12.0,
                                 seen_gradient=seen).any()


def _hillside_with_bushes(seed=0, n=120, deg=30.0):
    """A hillside of ``deg`` degrees falling to the south-east, bent by a gentle wave, 0.05 m noise, with 60
    bushes 0.8-1.6 m high of 1-4 cells (1 m cells): heights and the bushes' cells (truth)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:n, 0:n].astype(np.float64)
    g = math.tan(math.radians(deg))
    ground = g * (0.8 * x + 0.6 * y) + 2.0 * np.sin(x / 25.0) + rng.normal(0, 0.05, (n, n))
    bush = np.zeros((n, n), bool)
    for r, c in rng.integers(5, n - 5, (60, 2)):
        h, w = rng.integers(1, 3, 2)
        bush[r:r + h, c:c + w] = True
    return (ground + np.where(bush, rng.uniform(0.8, 1.6, (n, n)), 0.0)).astype(np.float32), bush


def test_refine_ground_takes_the_bushes_on_a_steep_hillside_along_the_seen_ground():
    """Bushes the vote kept on a 30 degree hillside (issues 12 and 13, ISPRS 11 and 52): with the terrain's
    steep slope in every direction the refinement takes 10 of their 124 cells, with the seen ground's slope
    along each line 75; no ground cell either way."""
    z, bush = _hillside_with_bushes()
    vote = np.zeros(z.shape, np.uint8)
    taken = {}
    for along in (False, True):
        mask, _ = dr.refine_ground(z, vote, (1.0, 1.0), tolerance_m=0.5, slope=0.7, along_ground=along)
        obj = mask == OBJECT
        assert not (obj & ~bush).any()
        taken[along] = int(np.count_nonzero(obj & bush))
    assert taken[False] <= 15 and taken[True] >= 70


def test_refine_ground_along_the_seen_ground_in_blocks_equals_one_pass():
    z, bush = _hillside_with_bushes(seed=1)
    vote = np.where(np.random.default_rng(2).random(z.shape) < 0.1, OBJECT, GROUND).astype(np.uint8)
    kw = dict(tolerance_m=0.5, slope=0.7, reach_m=8.0, along_ground=True)
    whole, _ = dr.refine_ground(z, vote, (1.0, 1.0), **kw)
    halo = dr.refine_halo((1.0, 1.0), 8.0, along_ground=True)
    got = in_blocks(lambda wr, wc: dr.refine_ground(z[wr, wc], vote[wr, wc], (1.0, 1.0), **kw)[0], z.shape, 40, halo)
    np.testing.assert_array_equal(got, whole)


def test_dtm_takes_more_shrubs_on_a_steep_slope_along_the_seen_ground(monkeypatch):
    """``bareearth:dtm`` on the steep shrubs site (``core.synthetic_sites``: 0.5-2 m shrubs over about half a
    28-38 degree slope, lowest point of 1 m cells, ISPRS 52's kind): with the refinement's floors along the
    seen ground's slope it keeps fewer shrubs (type II 45.0 -> 39.5 %, total 7.13 -> 6.37 %, type I 0.38 ->
    0.45 %)."""
    from bare_earth.core import dtm as dtm_method
    from bare_earth.core.evaluate import compare_masks
    from bare_earth.core.pipeline import run_array
    from bare_earth.core.synthetic_sites import make_site
    s = make_site("shrubs", 1.0, "lowest")
    got = {}
    for on in (False, True):
        monkeypatch.setattr(dtm_method, "ALONG_GROUND", on)
        got[on] = compare_masks(run_array("dtm", s.dsm, s.cell_size, {}).mask, s.mask)
    assert got[True]["type2"] < got[False]["type2"] - 4.0
    assert got[True]["total"] < got[False]["total"] - 0.5
    assert got[True]["type1"] < got[False]["type1"] + 0.2


def test_find_step_tops_exact():
    """A step's top: three ground cells in a line continue to it and the ground beyond drops; a hedge on the
    edge, a wall's foot, a low drop or rough vegetation whose cells happen to line up is none."""
    z = np.zeros((7, 9), np.float32)
    z[:, :4] = -3.0                                  # a 3 m wall: the terrace's edge at column 4
    ground = np.ones(z.shape, bool)
    tops = dr.find_step_tops(z, ground, ground, tolerance_m=0.5)
    np.testing.assert_array_equal(tops.any(axis=0), np.arange(9) == 4)     # not the foot (column 3)
    assert tops[:, 4].all()
    hedge = z.copy()
    hedge[:, 4] = 1.5                                # a hedge on the edge stands above the line
    assert not dr.find_step_tops(hedge, ground, ground, tolerance_m=0.5).any()
    only_ground = ground.copy()
    only_ground[:, 6] = False                        # the line's cells must be ground
    assert not dr.find_step_tops(z, ground, only_ground, tolerance_m=0.5)[:, 4].any()
    assert dr.find_step_tops(z, ground & (np.arange(9) == 4), ground, tolerance_m=0.5).sum() == 7   # cells
    # a drop smaller than step_m is no step
    low = np.where(z < 0, np.float32(-0.8), z)
    assert dr.find_step_tops(low, ground, ground, tolerance_m=0.3)[:, 4].all()
    assert not dr.find_step_tops(low, ground, ground, tolerance_m=0.3, step_m=1.0).any()
    # rough shrubs (1.5 / 3 m alternating) line up along a diagonal: tops unless the line lies on smooth ground
    rough = np.zeros((12, 12), np.float32)
    i, j = np.mgrid[0:12, 6:12]
    rough[:, 6:] = 1.5 + 1.5 * ((i + j) % 2)
    g = np.ones(rough.shape, bool)
    assert dr.find_step_tops(rough, g, g, tolerance_m=0.5).any()
    assert not dr.find_step_tops(rough, g, g, tolerance_m=0.5, smooth_m=1.0).any()
    assert dr.find_step_tops(z, ground, ground, tolerance_m=0.5, smooth_m=1.0)[:, 4].all()   # the terrace is smooth
    nan = z.copy()
    nan[:, 5] = np.nan                               # nodata never makes a line
    assert not dr.find_step_tops(nan, ground, ground, tolerance_m=0.5).any()
    with pytest.raises(ValueError, match="tolerance_m"):
        dr.find_step_tops(z, ground, ground, tolerance_m=0.0)
    with pytest.raises(ValueError, match="min_cells"):
        dr.find_level_lines(z, z == 0, z == 0, (1.0, 1.0), tolerance_m=0.3, min_cells=0)
    with pytest.raises(ValueError, match="shape"):
        dr.find_step_tops(z, ground[:3], ground, tolerance_m=0.5)


def _terrace_with_house():
    """A terrace 3 m above lower ground falling away, its edge row 5; a house at its back whose corner comes
    within two cells of the edge; the vote took a stretch of the edge (columns 6-8) for an object."""
    z = np.zeros((12, 14), np.float32)
    z[:6] = 3.0
    z[6:] = -0.2 * np.arange(1, 7, dtype=np.float32)[:, None]
    z[0:4, 6:11] = 9.0
    vote = np.where(z > 5, OBJECT, GROUND).astype(np.uint8)
    vote[5, 6:9] = OBJECT
    return z, vote


def test_refine_ground_keeps_a_terrace_edge_beside_a_house():
    """issue 13 (core.synthetic_sites hillside and railway): the upper edge of a step in the ground beside an
    object the edge test took, since along a diagonal the object hides one side and the lower ground does not
    continue to it; as a step's top (find_step_tops) it stays ground."""
    z, vote = _terrace_with_house()
    fill = vote == OBJECT
    spikes = find_edge_spikes(z, fill, 0.5, line_tolerance_m=0.5)
    assert spikes[5, 4] and spikes[5, 5]                     # the edge test alone takes the edge
    mask, info = dr.refine_ground(z, vote, (1.0, 1.0), tolerance_m=0.5, slope=0.1, reach_m=12.0,
                                  edge_tolerance_m=0.5, line_tolerance_m=0.5)
    np.testing.assert_array_equal(mask, vote)                # every ground cell stays ground
    assert info["refine_edge_removed_share"] == 0.0
    # a bush on the same edge stands above the terrace's line: still taken
    z[5, 4] = 4.5
    mask, _ = dr.refine_ground(z, vote, (1.0, 1.0), tolerance_m=0.5, slope=0.1, reach_m=12.0,
                               edge_tolerance_m=0.5, line_tolerance_m=0.5)
    assert mask[5, 4] == OBJECT


def test_refine_ground_keeps_a_platform_edge_between_tracks():
    """A platform 1.2 m high and 6 cells wide between lower ground on both sides (a railway station): its
    edges, bracketed by the tracks within the reach and not smooth, were taken as a low object's; they are
    steps' tops of its smooth top and stay ground (the rows beside them, no step's top and not smooth, are
    still the bracketed test's), while a hedge as high is taken whole."""
    z = np.zeros((20, 30), np.float32)
    z += np.float32(0.02) * np.arange(30, dtype=np.float32)        # a gentle fall along the tracks
    z[7:13] += 1.2
    vote = np.full(z.shape, GROUND, np.uint8)
    mask, _ = dr.refine_ground(z, vote, (1.0, 1.0), tolerance_m=0.5, slope=0.03, reach_m=12.0,
                               edge_tolerance_m=0.5, line_tolerance_m=0.5)
    assert (mask[[7, 12]] == GROUND).all() and (mask[9:11] == GROUND).all()
    hedge = z.copy()
    hedge[7:13] += ((np.arange(30) % 2) * 1.0)[None, :]            # rough: 1.2 and 2.2 m alternating
    mask, _ = dr.refine_ground(hedge, vote, (1.0, 1.0), tolerance_m=0.5, slope=0.03, reach_m=12.0,
                               edge_tolerance_m=0.5, line_tolerance_m=0.5)
    assert (mask[7:13] == OBJECT).mean() > 0.9


def test_refine_ground_with_step_tops_in_blocks_equals_one_pass():
    """Blocks read with refine_halo cells around give the one pass on a quarry (steps' tops spared)."""
    from bare_earth.core.synthetic_sites import make_site
    s = make_site("quarry", 2.0, "lowest")
    vote = s.mask.astype(np.uint8)
    kw = dict(tolerance_m=0.5, slope=0.5, reach_m=12.0, edge_tolerance_m=0.5, line_tolerance_m=1.0)
    whole, _ = dr.refine_ground(s.dsm, vote, s.cell_size, **kw)
    got = in_blocks(lambda wr, wc: dr.refine_ground(s.dsm[wr, wc], vote[wr, wc], s.cell_size, **kw)[0],
                    s.dsm.shape, 48, dr.refine_halo(s.cell_size, 12.0))
    np.testing.assert_array_equal(got, whole)


def _band_scene():
    """A tilted plane (0.05 rise a cell along the rows, 0.02 along the columns), an object on columns 10-13, and
    the ground cells beside it (column 9) raised by known heights."""
    rows, cols = 15, 24
    r, c = np.mgrid[0:rows, 0:cols].astype(np.float32)
    z = 0.02 * c + 0.05 * r
    objects = np.zeros(z.shape, bool)
    objects[:, 10:14] = True
    z[objects] += 5.0
    return z.astype(np.float32), objects


def test_raised_band_exact_on_a_tilted_plane():
    """Band cells above the plane of the ground beyond them by more than the tolerance and at most the height
    are found, exactly; the rest of the ground (on the plane) and a cell above the height are not."""
    z, objects = _band_scene()
    raise_m = {2: 0.3, 4: 0.1, 6: 0.3, 8: 0.8, 10: 0.45}    # row: height above the plane at column 9
    for row, h in raise_m.items():
        z[row, 9] += h
    out = dr.find_raised_band(z, objects, (1.0, 1.0), tolerance_m=0.2, height_m=0.5, passes=1)
    assert sorted(map(tuple, np.argwhere(out).tolist())) == [(2, 9), (6, 9), (10, 9)]
    # a plane needs its cells: a window of fewer than BAND_PLANE_MIN_CELLS known cells decides nothing
    lone = np.zeros((5, 5), np.float32)
    lone[2, 2] = 0.3
    obj = np.ones((5, 5), bool)
    obj[2, 2] = obj[2, 1] = obj[1, 2] = False
    assert not dr.find_raised_band(lone, obj, (1.0, 1.0), tolerance_m=0.2, height_m=0.5).any()
    with pytest.raises(ValueError, match="tolerance_m"):
        dr.find_raised_band(z, objects, (1.0, 1.0), tolerance_m=0.0, height_m=0.5)
    with pytest.raises(ValueError, match="min_cells"):
        dr.find_level_lines(z, z == 0, z == 0, (1.0, 1.0), tolerance_m=0.3, min_cells=0)
    with pytest.raises(ValueError, match="shape"):
        dr.find_raised_band(z, objects[:, :5], (1.0, 1.0), tolerance_m=0.2, height_m=0.5)


def test_raised_band_peels_a_skirt_sloping_away_from_the_object_one_cell_a_pass():
    z, objects = _band_scene()
    z[3:12, 9] += 0.45                              # low vegetation along the object's edge, lower further out
    z[3:12, 8] += 0.25
    one = dr.find_raised_band(z, objects, (1.0, 1.0), tolerance_m=0.2, height_m=0.5, passes=1)
    two = dr.find_raised_band(z, objects, (1.0, 1.0), tolerance_m=0.2, height_m=0.5, passes=2)
    assert set(map(tuple, np.argwhere(one).tolist())) == {(r, 9) for r in range(3, 12)}
    assert set(map(tuple, np.argwhere(two).tolist())) == {(r, c) for r in range(3, 12) for c in (8, 9)}


def test_raised_band_keeps_a_platform_edge_beside_a_train():
    """A platform (ground 1 m above the track bed) beside a train: the plane of the window, mostly the lower track
    bed, passes below the platform's edge, but the platform beside it stands as high: ground."""
    z = np.zeros((20, 30), np.float32)
    z[:, 12:] = 1.0                                 # the platform, from column 12
    objects = np.zeros(z.shape, bool)
    objects[:, 8:11] = True                         # a train on the track bed beside it (column 11: a gap)
    z[objects] = 4.0
    z[:, 11] = 1.0                                  # the platform's edge beside the train
    plane = dr._plane_residuals(z, ~objects & (np.arange(30) != 11)[None, :], ~objects & (np.arange(30) == 11)[None, :],
                                (6, 6))
    assert np.nanmax(plane[:, 11]) > 0.2            # above the window's plane ...
    assert not dr.find_raised_band(z, objects, (1.0, 1.0), tolerance_m=0.2, height_m=0.5).any()   # ... yet ground


def _skirted_crowns(seed=0, n=128):
    """Crowns 6 m high on a gentle slope (noise 0.03 m), each ringed by low vegetation 0.15-0.45 m high two to
    three cells wide with gaps (80 % of the ring's cells): the rough band along a crown's edge whose cells continue
    each other. Returns the DSM, the true ground surface, the objects and the ring."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:n, 0:n].astype(np.float64)
    ground = 0.02 * x + 0.01 * y
    z = ground + rng.normal(0.0, 0.03, (n, n))
    truth = np.zeros((n, n), bool)
    ring = np.zeros((n, n), bool)
    for cy in range(16, n - 8, 24):
        for cx in range(16, n - 8, 24):
            d = np.hypot(y - cy, x - cx)
            crown = d <= 5
            z[crown] = ground[crown] + 6.0 - 0.1 * d[crown]
            veg = (d > 5) & (d <= 7.5) & (rng.random((n, n)) < 0.8)
            z[veg] = ground[veg] + rng.uniform(0.15, 0.45, int(veg.sum()))
            truth |= crown | veg
            ring |= veg
    return z.astype(np.float32), ground, truth, ring


def test_low_vegetation_along_crowns_is_removed_and_the_dtm_under_them_is_lower():
    """The sparse lidar rows where dtm trailed SAGA (``autzen_trim`` 1 m): a rough band of low vegetation along
    the crowns' edges that the members keep and the edge test's continuations read as ground (its cells continue
    each other), the DTM under the crowns resting on it. Against the plane of the ground beyond the band, the
    cells standing more than the edge tolerance above it (and within the threshold) with no ground beside them as
    high are objects; no true ground is lost. (Without the band test: 270 of the 762 ring cells more than 0.33 m
    high kept, DTM under the objects +0.172 m.)"""
    z, ground, truth, ring = _skirted_crowns()
    params = resolve_dtm_params(z, (1.0, 1.0))
    res = filter_dtm(z, (1.0, 1.0), **{k: v for k, v in params.items() if k != "input_description"})
    kept = res.mask == GROUND
    et = res.info["refine_edge_tolerance_m"]
    assert 0.2 < et < 0.3 and res.info["refine_height_m"] == 0.5
    high = ring & (z - ground > 0.33)               # above the edge tolerance by two standard deviations of the noise
    assert np.count_nonzero(high) > 700
    assert np.count_nonzero(kept & high) < 0.25 * np.count_nonzero(high)        # 147 (270 without the band test)
    assert res.info["refine_band_removed_share"] > 0.005
    assert np.count_nonzero(~kept & ~truth) == 0    # every true ground cell kept
    assert float(np.mean((res.dtm - ground)[truth])) < 0.16                      # 0.144 m (0.172)


def test_raised_band_in_blocks_equals_one_pass():
    z, ground, truth, ring = _skirted_crowns(seed=1, n=96)
    objects = truth & ~ring                         # the crowns; the ring is ground to be tested
    whole = dr.find_raised_band(z, objects, (1.0, 1.0), tolerance_m=0.25, height_m=0.5)
    assert whole.sum() > 50
    halo = dr.raised_band_reach((1.0, 1.0))
    for b in (23, 40):
        got = in_blocks(lambda wr, wc: dr.find_raised_band(z[wr, wc], objects[wr, wc], (1.0, 1.0), tolerance_m=0.25,
                                                           height_m=0.5), z.shape, b, halo)
        np.testing.assert_array_equal(got, whole)


def _worst_second_difference_reference(z, r, c):
    """_worst_second_difference as first written: gathers from a copy of the raster in a frame of NaN."""
    h, w = z.shape
    pad = 2
    wp = w + 2 * pad
    zp = np.full((h + 2 * pad, wp), np.nan, np.float32)
    zp[pad:-pad, pad:-pad] = z
    flat = zp.ravel()
    idx = (r + pad) * wp + (c + pad)
    worst = np.zeros(idx.size, np.float32)
    count = np.zeros(idx.size, np.int32)
    for a in (-1, 0, 1):
        for b in (-1, 0, 1):
            p = idx + (a * wp + b)
            mid = 2 * flat[p]
            for step in (1, wp):
                d = np.abs(flat[p - step] - mid + flat[p + step])
                count += np.isfinite(d)
                np.fmax(worst, d, out=worst)
    return worst, count


@pytest.mark.parametrize("chunk", [5, 1 << 14])
@pytest.mark.parametrize("seed", range(3))
def test_worst_second_difference_gathered_equals_framed_copy(monkeypatch, chunk, seed):
    """The heights gathered per chunk of cells (NaN beyond the raster; ``keep``: NaN outside it) give the
    framed copy's differences and counts exactly, at the raster's edges and corners and beside nodata."""
    monkeypatch.setattr(dr, "SMOOTH_CHUNK", chunk)
    rng = np.random.default_rng(seed)
    z = rng.normal(0.0, 2.0, (23, 31)).astype(np.float32)
    z[rng.random(z.shape) < 0.1] = np.nan
    keep = rng.random(z.shape) < 0.7
    cells = rng.random(z.shape) < 0.4
    cells[0, 0] = cells[-1, -1] = cells[0, -1] = cells[-1, 0] = True
    r, c = np.nonzero(cells)
    for k, zz in ((None, z), (keep, np.where(keep, z, np.float32(np.nan)))):
        worst, count = dr._worst_second_difference(z, r, c, keep=k)
        ref_w, ref_c = _worst_second_difference_reference(zz, r, c)
        np.testing.assert_array_equal(worst, ref_w)
        np.testing.assert_array_equal(count, ref_c)
        assert worst.dtype == np.float32 and count.min() < 18 and (k is not None or count.max() == 18)


@pytest.mark.parametrize("along_ground", [False, True])
@pytest.mark.parametrize("band_rows", [3, 64])
def test_refine_ground_with_a_pool_equals_one_thread(monkeypatch, band_rows, along_ground):
    """The bands of find_bracketed and the chunks of the edge test taken by a second thread give the
    mask and the info of one thread exactly (bands of a few rows: many bands, each with its halo; along the
    seen ground, each band's slopes along the lines read from the planes' rows around it)."""
    from concurrent.futures import ThreadPoolExecutor

    from bare_earth.core import fill
    monkeypatch.setattr(dr, "_BAND_ROWS", band_rows)
    monkeypatch.setattr(fill, "EDGE_CHUNK", 11)
    rng = np.random.default_rng(3)
    z = rng.normal(0.0, 0.2, (41, 47)).astype(np.float32)
    z[rng.random(z.shape) < 0.04] += 1.5                          # low objects bracketed by ground
    z[20:28, 10:30] += 4.0
    z[rng.random(z.shape) < 0.02] = np.nan
    mask = np.where(z > 3.0, OBJECT, GROUND).astype(np.uint8)
    mask[np.isnan(z)] = NODATA
    z += np.float32(0.1) * np.arange(z.shape[1], dtype=np.float32)   # a hillside: the planes' slopes differ by line
    kw = dict(tolerance_m=0.5, slope=0.2, reach_m=6.0, edge_tolerance_m=0.4, line_tolerance_m=0.6,
              band_tolerance_m=0.3, along_ground=along_ground)
    if along_ground:
        flat, _ = dr.refine_ground(z, mask, (1.0, 1.0), **dict(kw, along_ground=False))
    ref, ref_info = dr.refine_ground(z, mask, (1.0, 1.0), **kw)
    with ThreadPoolExecutor(max_workers=1) as pool:
        got, info = dr.refine_ground(z, mask, (1.0, 1.0), **kw, pool=pool)
    np.testing.assert_array_equal(got, ref)
    np.testing.assert_array_equal(info.pop("step_tops"), ref_info.pop("step_tops"))
    assert info == ref_info and info["refine_removed_share"] > 0 and info["refine_edge_removed_share"] > 0
    assert not along_ground or not np.array_equal(ref, flat)


def _strip_beside_house():
    """A terrace 3 m above ground falling away below its edge (row 5), a house (rows 1-4, columns 6-13) standing
    one cell from the edge: the strip of the edge beside it (row 5, columns 6-13) has the house on its upper
    side, so no line across the step finds ground there; the terrace is seen beyond both ends of the house."""
    z = np.zeros((12, 20), np.float32)
    z[:6] = 3.0
    z[6:] = -0.2 * np.arange(1, 7, dtype=np.float32)[:, None]
    house = np.zeros(z.shape, bool)
    house[1:5, 6:14] = True
    z[house] = 9.0
    strip = np.zeros(z.shape, bool)
    strip[5, 6:14] = True
    return z, house, strip


def test_continue_lines_along_a_step_beside_a_house():
    """issue 13 (core.synthetic_sites hillside): the top of a retaining wall between a house and the wall's edge
    is continued along the step from the terrace seen beyond the house (three ground cells in a line, the cell
    and the line's first cell both above a neighbour off the line by a step): ground; a hedge on the
    edge, a drop the terrain's slope explains, a roof's edge with no ground at its level, or without
    ``along_slope``: not."""
    z, house, strip = _strip_beside_house()
    near = np.zeros(z.shape, bool)
    near[:6, 3:17] = True                              # the terrace near the house: voted ground, not undisputed
    anchors = ~house & ~strip & ~near
    ground = ~house & ~strip
    kw = dict(tolerance_m=0.5, reach_cells=12, step_m=1.0)
    assert not dr.continue_lines(z, strip, anchors, **kw).any()            # across the step: the house hides it
    assert not dr.continue_lines(z, strip, anchors, **kw, ground=ground).any()
    got = dr.continue_lines(z, strip, anchors, **kw, ground=ground, along_slope=0.1)
    np.testing.assert_array_equal(got, strip)                             # from both ends, 4 passes
    for k in range(4):                                                    # every orientation
        rot = [np.rot90(a, k) for a in (z, strip, anchors, ground)]
        got = dr.continue_lines(rot[0], rot[1], rot[2], **kw, ground=rot[3], along_slope=0.1)
        np.testing.assert_array_equal(got, rot[1])
    short = dr.continue_lines(z, strip, anchors, **dict(kw, reach_cells=6), ground=ground, along_slope=0.1)
    assert short.sum() == 4                                               # 2 passes: two cells from each end
    # the ground must be given: the anchors alone stop three cells short of the house
    assert not dr.continue_lines(z, strip, anchors, **kw, along_slope=0.1).any()
    # a hedge on the strip stands above the line
    hedge = z.copy()
    hedge[5, 6:14] = 4.5
    assert not dr.continue_lines(hedge, strip, anchors, **kw, ground=ground, along_slope=0.1).any()
    # a drop within step_m plus the terrain's slope over the cell (1 + 2.5 x 1 m): no step
    assert not dr.continue_lines(z, strip, anchors, **kw, ground=ground, along_slope=2.5).any()
    # a roof's edge: the roof (3 m) stands on walls all round, its edge continued by no ground at its level
    roof = np.zeros((12, 20), np.float32)
    roof[1:6, 6:14] = 3.0
    edge = np.zeros(roof.shape, bool)
    edge[5, 6:14] = True
    others = ~edge & (roof == 0)
    assert not dr.continue_lines(roof, edge, others, **kw, ground=others, along_slope=0.1).any()


def test_find_step_tops_along_a_step_beside_a_house():
    """The same strip is a step's top along the step (find_step_tops with along_slope) and refine_ground with
    along_steps keeps it, where the edge test along one line (the house hides the upper side, the lower ground
    does not continue to it) took it; a bush on the strip is still taken."""
    z, house, strip = _strip_beside_house()
    ground = ~house
    assert not dr.find_step_tops(z, strip, ground, tolerance_m=0.5, step_m=1.0, smooth_m=1.0)[5, 8:12].any()
    tops = dr.find_step_tops(z, strip, ground, tolerance_m=0.5, step_m=1.0, smooth_m=1.0, along_slope=0.1)
    np.testing.assert_array_equal(tops, strip)
    vote = np.where(house, OBJECT, GROUND).astype(np.uint8)
    kw = dict(tolerance_m=0.5, slope=0.1, reach_m=12.0, edge_tolerance_m=0.5, line_tolerance_m=0.5)
    taken, _ = dr.refine_ground(z, vote, (1.0, 1.0), **kw)
    assert (taken[strip] == OBJECT).sum() >= 4                           # the edge test takes the strip
    kept, info = dr.refine_ground(z, vote, (1.0, 1.0), **kw, along_steps=True)
    np.testing.assert_array_equal(kept, vote)
    bush = z.copy()
    bush[5, 9] = 4.5
    mask, _ = dr.refine_ground(bush, vote, (1.0, 1.0), **kw, along_steps=True)
    assert mask[5, 9] == OBJECT


def test_along_steps_in_blocks_equal_one_pass():
    """The lines along a step read at most one cell beside the line: continue_lines (with along_slope) and
    refine_ground (with along_steps) in blocks equal the one pass on the hillside site."""
    from bare_earth.core.synthetic_sites import make_site
    s = make_site("hillside", 2.0, "lowest", extent_m=160)
    vote = s.mask.astype(np.uint8)
    g = s.mask == GROUND
    steps = ndimage.maximum_filter(s.dtm, 3) - ndimage.minimum_filter(s.dtm, 3) > 3.0
    disputed, anchors = steps & g, ~steps & g
    reach = 9
    kw = dict(tolerance_m=0.5, reach_cells=reach, step_m=1.0, ground=g, along_slope=0.4, cell_size=s.cell_size)
    whole = dr.continue_lines(s.dsm, disputed, anchors, **kw)
    assert whole.sum() > 50
    got = in_blocks(lambda wr, wc: dr.continue_lines(s.dsm[wr, wc], disputed[wr, wc], anchors[wr, wc],
                                                     **dict(kw, ground=g[wr, wc])), s.dsm.shape, 40, reach)
    np.testing.assert_array_equal(got, whole)
    kw = dict(tolerance_m=0.5, slope=0.4, reach_m=12.0, edge_tolerance_m=0.5, line_tolerance_m=1.0, along_steps=True)
    whole, _ = dr.refine_ground(s.dsm, vote, s.cell_size, **kw)
    got = in_blocks(lambda wr, wc: dr.refine_ground(s.dsm[wr, wc], vote[wr, wc], s.cell_size, **kw)[0],
                    s.dsm.shape, 48, dr.refine_halo(s.cell_size, 12.0))
    np.testing.assert_array_equal(got, whole)


def test_continue_lines_along_a_staircase_wall():
    """A wall at an angle to the raster runs in a staircase: where its edge steps a row down, the drop beside the
    line's first cell lies diagonally, not straight across, so the drop is looked for off the line in any
    direction; the strip between the house and the wall's top is given back whole (the drop straight across
    and on the same side for both cells gave back none of it)."""
    i, j = np.mgrid[0:16, 0:24]
    edge = 6 + j // 6                                  # the terrace's edge row steps down every 6 columns
    z = np.where(i <= edge, np.float32(3.0), np.float32(-0.2) * (i - edge)).astype(np.float32)
    house = (i >= 2) & (i < 7) & (j >= 8) & (j < 18)
    z[house] = 9.0
    strip = (i == edge) & (j >= 8) & (j < 18)
    ground = ~house & ~strip
    anchors = ground & ~((i <= edge) & (j >= 5) & (j < 21))
    got = dr.continue_lines(z, strip, anchors, tolerance_m=0.5, reach_cells=18, step_m=1.0, ground=ground,
                            along_slope=0.1)
    np.testing.assert_array_equal(got, strip)


def _continue_lines_measuring_every_line(z, disputed, anchors, *, tolerance_m, reach_cells, step_m, ground,
                                         along_slope, cell_size):
    """continue_lines' passes with every candidate's lines measured before the first pass (the rule as written)."""
    rows, cols = z.shape
    valid = np.isfinite(z)
    r, c = np.nonzero(disputed & valid)
    zf = z.ravel()
    known = (anchors & valid).ravel().copy()
    known2 = known | (ground & valid).ravel()
    tol_beyond = np.float32(tolerance_m * np.sqrt(14.0 / 6.0))
    pairs = dr._step_top_lines(zf, rows, cols, r, c, tolerance_m, step_m)
    along = dr._along_step_lines(zf, rows, cols, r, c, tolerance_m, step_m, along_slope, cell_size)
    faces = []
    for di, dj in ((0, 1), (1, 0), (1, 1), (1, -1)):
        ra, ca, rb, cb = r + di, c + dj, r - di, c - dj
        inside = (ra >= 0) & (ra < rows) & (ca >= 0) & (ca < cols) & (rb >= 0) & (rb < rows) & (cb >= 0) & (cb < cols)
        ia, ib = np.where(inside, ra * cols + ca, 0), np.where(inside, rb * cols + cb, 0)
        hi, lo = np.fmax(zf[ia], zf[ib]), np.fmin(zf[ia], zf[ib])
        ok = inside & (hi - zf[r * cols + c] > tol_beyond) & (zf[r * cols + c] - lo > tol_beyond)
        faces.append((ia[ok], ib[ok], np.flatnonzero(ok)))
    done = np.zeros(r.size, bool)
    for _ in range(reach_cells // 3):
        new = np.zeros(r.size, bool)
        for i1, i2, i3, k in pairs:
            new[k] |= known[i1] & known[i2] & known[i3]
        for i1, i2, i3, k in along:
            new[k] |= known2[i1] & known2[i2] & known2[i3]
        for ia, ib, k in faces:
            new[k] |= known[ia] & known[ib]
        new &= ~done
        done |= new
        known[(r * cols + c)[new]] = True
        known2[(r * cols + c)[new]] = True
    out = np.zeros(z.shape, bool)
    out[r[done], c[done]] = True
    return out


@pytest.mark.parametrize("kind", ["quarry", "hillside", "steps"])
def test_continue_lines_measures_each_line_when_it_can_first_fire(kind):
    """continue_lines measures a line's shape only once its first cell (a face's two neighbours) is ground, in the
    pass it can first give its cell back: the cells given back equal those of every candidate's lines measured
    up front, pass by pass, on sites whose step tops and faces are given back over several passes (lines across
    a step, along it and faces starting from cells given back in an earlier pass), with the vote's objects all
    candidates and noisy anchors."""
    from bare_earth.core.synthetic_sites import make_site
    s = make_site(kind, 1.0, "lowest")
    z = s.dsm.astype(np.float32)
    rng = np.random.default_rng(3)
    steps = ndimage.maximum_filter(s.dtm, 3) - ndimage.minimum_filter(s.dtm, 3) > 1.5
    disputed = (steps | (s.mask != GROUND) | (rng.random(z.shape) < 0.05)) & np.isfinite(z)
    anchors = ~disputed & (rng.random(z.shape) < 0.7)
    ground = ~disputed
    kw = dict(tolerance_m=0.5, reach_cells=12, step_m=1.0, ground=ground, along_slope=0.1, cell_size=(1.0, 1.0))
    got = dr.continue_lines(z, disputed, anchors, **kw)
    want = _continue_lines_measuring_every_line(z, disputed, anchors, **kw)
    one = _continue_lines_measuring_every_line(z, disputed, anchors, **dict(kw, reach_cells=3))
    assert want.sum() > one.sum() > 0                 # cells given back in later passes too
    np.testing.assert_array_equal(got, want)


def _dike(rows, cols, profile):
    """A dike along the rows: ``profile`` (heights down a column) on flat ground, 1 m cells."""
    z = np.zeros((rows, cols), np.float32)
    z[:len(profile)] = np.asarray(profile, np.float32)[:, None]
    return z


BANKS = dict(tolerance_m=0.5, smooth_m=1.0, reach_cells=8, wall_cells=6)


def test_continue_banks_gives_back_a_dike_with_trees_but_not_a_steeper_wall():
    # a dike of 1 m a cell banks (within the bank's 0.7 m plus the tolerance 0.5 m) with a 3-cell crest, trees
    # (8 m) on its crest: the dike is ground, the trees are not (rough along every line); the same dike at 2 m a
    # cell (63 degrees, a wall) is not
    z = _dike(11, 40, [0, 0, 1, 2, 3, 3, 3, 2, 1, 0, 0])
    trees = np.zeros(z.shape, bool)
    trees[5, 5::10] = True
    z[trees] = 8.0
    objects = z > 0
    got = dr.continue_banks(z, objects, ~objects, (1.0, 1.0), **BANKS)
    np.testing.assert_array_equal(got, objects & ~trees)
    steep = _dike(11, 40, [0, 0, 0, 2, 4, 4, 4, 2, 0, 0, 0])
    assert not dr.continue_banks(steep, steep > 0, steep == 0, (1.0, 1.0), **BANKS).any()
    # at 3 m cells the steep dike's faces rise 2 m over 3 m (34 degrees): banks (its crest, bending by 2 m, is
    # not smooth)
    got = dr.continue_banks(steep, steep > 0, steep == 0, (3.0, 3.0), **BANKS)
    assert got[3].all() and got[7].all() and not got[4:7].any()
    # the reach: a path of at most reach_cells steps from the ground
    wide = _dike(41, 10, np.r_[np.zeros(2), np.ones(37), np.zeros(2)])
    got = dr.continue_banks(wide, wide > 0, wide == 0, (1.0, 1.0), **{**BANKS, "reach_cells": 5})
    assert got[2:7].all() and not got[7:34].any() and got[34:39].all()


def test_continue_banks_keeps_a_deck_reached_up_a_ramp_an_object():
    # a ramp (0.5 m a cell, banks of 0.5 m a cell on its sides) up to a bridge's deck standing 5 m on walls: the
    # deck's edges are wall tops continuing the deck straight, so the deck and the ramp within wall_cells of
    # them stay objects; the ramp farther away is ground
    z = np.zeros((30, 40), np.float32)
    i, j = np.mgrid[0:30, 0:40]
    ramp = np.clip(0.5 * (j - 4), 0, 5.0).astype(np.float32)
    ramp[:, 15:] = 0.0
    side = np.maximum(np.maximum(10 - i, i - 19), 0)
    z = np.maximum(z, ramp - 0.5 * side).astype(np.float32)
    deck = (i >= 10) & (i < 20) & (j >= 15) & (j < 30)
    z[deck] = 5.0
    objects = z > 0
    got = dr.continue_banks(z, objects, ~objects, (1.0, 1.0), **{**BANKS, "reach_cells": 20})
    assert not got[deck].any()
    assert not got[:, 9:].any()                              # within 6 cells of the deck's walls
    assert got[10:20, 5:7].all()                              # the ramp's foot
    # without the wall tops' exclusion the deck would be reached along the ramp
    free = dr.continue_banks(z, objects, ~objects, (1.0, 1.0), **{**BANKS, "reach_cells": 20, "wall_cells": 0})
    assert free[deck].sum() > deck.sum() // 2


def test_continue_banks_roof_on_walls_and_nodata():
    z = np.zeros((20, 20), np.float32)
    z[5:15, 5:15] = 4.0                                       # a flat roof on walls
    objects = z > 0
    assert not dr.continue_banks(z, objects, ~objects, (1.0, 1.0), **BANKS).any()
    d = _dike(11, 12, [0, 0, 1, 2, 3, 3, 3, 2, 1, 0, 0])
    d[:, 6] = np.nan                                          # a column of nodata: never given back
    got = dr.continue_banks(d, d > 0, d == 0, (1.0, 1.0), **BANKS)
    assert got[2:9, :5].all() and not got[:, 6].any()


@pytest.mark.parametrize("kw, match", [({"tolerance_m": 0.0}, "tolerance_m"), ({"smooth_m": np.nan}, "smooth_m"),
                                       ({"slope": -1.0}, "slope"), ({"reach_cells": -1}, "at least 0")])
def test_continue_banks_bad_parameters(kw, match):
    z = np.zeros((4, 4), np.float32)
    with pytest.raises(ValueError, match=match):
        dr.continue_banks(z, z > 0, z == 0, (1.0, 1.0), **{**BANKS, **kw})
    with pytest.raises(ValueError, match="share the DSM's"):
        dr.continue_banks(z, np.zeros((3, 4), bool), z == 0, (1.0, 1.0), **BANKS)


def _bank_with_shrubs():
    """A river bank rising 0.5 m a cell (27 degrees) over 8 rows between level ground, with clumps of shrubs
    (3 x 3 cells, their lowest points 0.5 m above the face) along it, two cells of the face between clumps."""
    i = np.mgrid[0:30, 0:60][0]
    z = np.clip(0.5 * (i - 10), 0.0, 4.0).astype(np.float32)
    shrubs = np.zeros(z.shape, bool)
    for c0 in range(4, 56, 5):
        shrubs[13:16, c0:c0 + 3] = True
    z[shrubs] += 0.5
    return z, shrubs


def test_stands_above_ground_bump_ridge_and_unjudged_lines():
    z = np.zeros((9, 9), np.float32)
    ground = np.ones(z.shape, bool)
    z[4, 4] = 0.4
    ground[4, 4] = False
    cells = ~ground
    assert dr.stands_above_ground(z, ground, cells, height_m=0.3, reach_cells=2)[4, 4]
    assert not dr.stands_above_ground(z, ground, cells, height_m=0.4, reach_cells=2).any()   # not above 0.4
    # on a plane rising 1 m a cell the same cell 0.4 m above the plane: excess measured from the interpolation
    plane = (np.mgrid[0:9, 0:9][1] * 1.0).astype(np.float32)
    zp = plane.copy()
    zp[4, 4] += 0.4
    assert dr.stands_above_ground(zp, ground, cells, height_m=0.3, reach_cells=2)[4, 4]
    # a ridge along the row, level with the ground it continues: the row line is not above (spared)
    zr = np.zeros((9, 9), np.float32)
    zr[4, :] = 0.4
    zr[4, 0] = 0.4
    gr = np.ones(zr.shape, bool)
    gr[4, 1:] = False
    got = dr.stands_above_ground(zr, gr, ~gr, height_m=0.3, reach_cells=2)
    assert not got.any()
    # a line without ground within the reach on one side is not judged: the cell is spared
    gl = ground.copy()
    gl[4, 5:7] = False
    assert not dr.stands_above_ground(z, gl, cells, height_m=0.3, reach_cells=2)[4, 4]
    assert dr.stands_above_ground(z, gl, cells, height_m=0.3, reach_cells=3)[4, 4]    # ground at 3 cells
    # the ground farther along a line counts by its distance: ground 0 at 1 cell, 3 at 3 cells -> line 0.75
    z2 = np.zeros((9, 9), np.float32)
    z2[4, 4] = 1.0
    z2[4, 7] = 3.0
    g2 = np.ones(z2.shape, bool)
    g2[4, 4:7] = False
    got = dr.stands_above_ground(z2, g2, g2 == 0, height_m=0.2, reach_cells=3)
    assert got[4, 4]
    assert not dr.stands_above_ground(z2, g2, g2 == 0, height_m=0.3, reach_cells=3)[4, 4]   # 1.0 - 0.75
    # NaN heights are no ground and never above
    zn = z.copy()
    zn[4, 4] = np.nan
    assert not dr.stands_above_ground(zn, ground, cells, height_m=0.3, reach_cells=2).any()
    for kw, match in (({"height_m": -1.0}, "height_m"), ({"reach_cells": 0}, "reach_cells")):
        with pytest.raises(ValueError, match=match):
            dr.stands_above_ground(z, ground, cells, **{"height_m": 0.3, "reach_cells": 2, **kw})
    with pytest.raises(ValueError, match="one 2-D shape"):
        dr.stands_above_ground(z, ground[:3], cells, height_m=0.3, reach_cells=2)


def test_bump_tolerance_three_sigmas_of_the_interpolation():
    assert dr.bump_tolerance(dr.continuation_tolerance(0.05), 0.5) == pytest.approx(3.0 * np.sqrt(2.0) * 0.05)
    assert dr.bump_tolerance(dr.continuation_tolerance(0.5), 0.5) == 0.5
    assert dr.bump_tolerance(None, 0.4) == 0.4 and dr.bump_tolerance(float("nan"), 0.4) == 0.4


def test_continue_banks_keeps_shrubs_on_a_bank_but_gives_back_a_dike():
    # clumps of shrubs on a bank's face, ground between them, are smooth enough and long enough to be given back
    # as bank (autzen_trim 1 m: riparian shrubs); standing above the face along every line, they stay objects
    # with the bump test, and the dike (level along its length) is still given back
    z, shrubs = _bank_with_shrubs()
    ground = ~shrubs
    kw = {**BANKS, "reach_cells": 8}
    assert dr.continue_banks(z, shrubs, ground, (1.0, 1.0), **kw)[shrubs].mean() > 0.9   # given back without
    got = dr.continue_banks(z, shrubs, ground, (1.0, 1.0), **kw, bump_m=0.17, bump_cells=6)
    assert not got.any()
    d = _dike(11, 40, [0, 0, 1, 2, 3, 3, 3, 2, 1, 0, 0])
    objects = d > 0
    np.testing.assert_array_equal(
        dr.continue_banks(d, objects, ~objects, (1.0, 1.0), **BANKS, bump_m=0.17, bump_cells=6), objects)
    for bad, match in (({"bump_m": 0.0, "bump_cells": 3}, "bump_m"), ({"bump_m": 0.2, "bump_cells": 0}, "bump_cells"),
                       ({"bump_m": 0.2, "bump_cells": 9}, "bump_cells")):
        with pytest.raises(ValueError, match=match):
            dr.continue_banks(z, shrubs, ground, (1.0, 1.0), **kw, **bad)


def test_continue_banks_bump_test_blocked_equals_one_pass():
    # shrubs on a bank (kept objects by the bump test) above a dike (given back): windows of a block plus
    # banks_halo cells give the one-pass result
    z, shrubs = _bank_with_shrubs()
    d = _dike(11, 60, [0, 0, 1, 2, 3, 3, 3, 2, 1, 0, 0])
    z = np.vstack([z, d + z[-1:]]).astype(np.float32)
    objects = np.vstack([shrubs, d > 0])
    kw = dict(BANKS, bump_m=0.17, bump_cells=6)
    whole = dr.continue_banks(z, objects, ~objects, (1.0, 1.0), **kw)
    assert not whole[:30].any() and whole[30:].sum() == np.count_nonzero(d > 0)
    halo = dr.banks_halo(BANKS["reach_cells"], BANKS["wall_cells"])

    def part(wr, wc):
        return dr.continue_banks(z[wr, wc], objects[wr, wc], ~objects[wr, wc], (1.0, 1.0), **kw)

    for b in (9, 23):
        assert np.array_equal(in_blocks(part, z.shape, b, halo), whole)


def test_continue_banks_blocked_equals_one_pass():
    """On windows of a block plus banks_halo cells, the one-pass result in the block."""
    rng = np.random.default_rng(5)
    n = 120
    i, j = np.mgrid[0:n, 0:n].astype(np.float32)
    z = (np.clip(4.0 - 0.8 * np.abs(i - 60), 0, None) + rng.normal(0, 0.05, (n, n))).astype(np.float32)  # a dike
    z[20:35, 20:50] += 6.0                                                                            # a house
    z += np.clip(0.4 * (j - 70), 0, 6.0) * ((i > 80) & (i < 95))                                       # a ramp
    z[81:95, 86:110] = 6.5                                                                            # a deck
    objects = z > 0.3
    whole = dr.continue_banks(z, objects, ~objects, (1.0, 1.0), **BANKS)
    assert whole.any() and not whole[20:35, 20:50].any()
    halo = dr.banks_halo(BANKS["reach_cells"], BANKS["wall_cells"])

    def part(wr, wc):
        return dr.continue_banks(z[wr, wc], objects[wr, wc], ~objects[wr, wc], (1.0, 1.0), **BANKS)

    for b in (17, 40):
        assert np.array_equal(in_blocks(part, z.shape, b, halo), whole)


@pytest.mark.parametrize("chunk", [5, 1 << 14])
def test_continue_banks_with_a_pool_equals_one_thread(monkeypatch, chunk):
    """The candidates' smoothness and the paths' first cells on chunks of cells, some taken by a second thread:
    the cells given back by one thread exactly (a dike, a house, a ramp to a deck)."""
    from concurrent.futures import ThreadPoolExecutor
    rng = np.random.default_rng(5)
    n = 120
    i, j = np.mgrid[0:n, 0:n].astype(np.float32)
    z = (np.clip(4.0 - 0.8 * np.abs(i - 60), 0, None) + rng.normal(0, 0.05, (n, n))).astype(np.float32)
    z[20:35, 20:50] += 6.0
    z += np.clip(0.4 * (j - 70), 0, 6.0) * ((i > 80) & (i < 95))
    z[81:95, 86:110] = 6.5
    objects = z > 0.3
    ref = dr.continue_banks(z, objects, ~objects, (1.0, 1.0), **BANKS)
    monkeypatch.setattr(dr, "SMOOTH_CHUNK", chunk)
    with ThreadPoolExecutor(max_workers=1) as pool:
        got = dr.continue_banks(z, objects, ~objects, (1.0, 1.0), **BANKS, pool=pool)
    assert ref.sum() > 100
    np.testing.assert_array_equal(got, ref)


def test_square_counts_equals_the_filters_at_the_cells():
    """common.square_counts (continue_banks' wall tops and bank lengths): the counts of uniform_filter times the
    square's area, and maximum_filter's cells, exactly, on sparse and dense masks, cut by the edges."""
    from bare_earth.core.common import square_counts
    rng = np.random.default_rng(3)
    for share in (0.0, 0.002, 0.05, 0.5, 1.0):
        for half in (0, 1, 4, 13):
            m = rng.random((37, 29)) < share
            side = 2 * half + 1
            r, c = np.divmod(np.arange(m.size), m.shape[1])
            got = square_counts(m, r, c, half).reshape(m.shape)
            want = np.rint(ndimage.uniform_filter(m.astype(np.float64), side, mode="constant") * side * side)
            np.testing.assert_array_equal(got, want.astype(np.int64))
            np.testing.assert_array_equal(got > 0, ndimage.maximum_filter(m, side, mode="constant"))
    m = np.zeros((6, 7), bool)
    m[0, 0] = m[5, 6] = m[2, 3] = True
    assert square_counts(m, np.array([2, 0, 5, 3]), np.array([2, 6, 0, 3]), 1).tolist() == [1, 0, 0, 1]
    assert square_counts(m, np.array([], int), np.array([], int), 2).size == 0
    with pytest.raises(ValueError, match="half"):
        square_counts(m, np.array([0]), np.array([0]), -1)


def test_continue_banks_squares_as_the_filters_over_the_raster(monkeypatch):
    """continue_banks counts its squares (the wall tops' exclusion, the bank's length) at the path cells only: the
    same cells as with the filters over the whole raster (maximum_filter of the tops, uniform_filter of the cells
    given back times the square's area) on a dike, a ramp to a deck, a low mound and noise."""
    rng = np.random.default_rng(11)
    n = 150
    i, j = np.mgrid[0:n, 0:n].astype(np.float32)
    z = (np.clip(4.0 - 0.8 * np.abs(i - 60), 0, None) + rng.normal(0, 0.05, (n, n))).astype(np.float32)
    z += np.clip(0.4 * (j - 70), 0, 6.0) * ((i > 80) & (i < 95))
    z[81:95, 86:110] = 6.5
    z[120:140, 10:60] += np.clip(1.0 - 0.1 * np.abs(j[120:140, 10:60] - 35), 0, None)
    objects = z > 0.3
    got = {w: dr.continue_banks(z, objects, ~objects, (1.0, 1.0), **{**BANKS, "wall_cells": w}) for w in (0, 3, 8)}

    def filtered(mask, rows, cols, half):
        side = 2 * half + 1
        count = ndimage.uniform_filter(mask.astype(np.float32), side, mode="constant") * float(side * side)
        return np.rint(count[rows, cols]).astype(np.int64)

    monkeypatch.setattr(dr, "square_counts", filtered)
    for w, g in got.items():
        assert g.any()
        np.testing.assert_array_equal(g, dr.continue_banks(z, objects, ~objects, (1.0, 1.0), **{**BANKS,
                                                                                                "wall_cells": w}))
    # the exclusion and the length both act here (else the comparison would not test them)
    assert got[3].sum() < got[0].sum() and got[8].sum() < got[3].sum()


@pytest.mark.parametrize("wall", [2, 4, 6])
def test_continue_banks_a_bank_as_long_as_the_square_side_is_given_back(wall):
    """A low bank of two rows given back whole counts 2 x its length in the square (half-side ``wall``) of each of
    its cells: ``wall`` cells long (2 wall = the side - 1) it is too short, one cell longer it is given back."""
    kw = {**BANKS, "wall_cells": wall, "reach_cells": 10}
    for length, kept in ((wall, False), (wall + 1, True)):
        z = np.zeros((9, 30), np.float32)
        z[3:5, 5:5 + length] = 0.5
        got = dr.continue_banks(z, z > 0, z == 0, (1.0, 1.0), **kw)
        assert got.sum() == (2 * length if kept else 0)


@pytest.mark.parametrize("wall", [0, 2, 3, 6])
def test_continue_banks_clears_the_square_around_a_wall_top(wall):
    """A long low bank of two rows ending at a drop of 2 m (a wall): its cell before the drop's edge is a wall top
    (the cell ahead continues the bank straight, the next lies 2 m lower) and the bank's cells within ``wall``
    columns of it stay objects, exactly (0: the top alone)."""
    z = np.zeros((9, 40), np.float32)
    z[3:5, 2:32] = 0.5
    z[3:5, 32:36] = -1.5
    got = dr.continue_banks(z, z != 0, z == 0, (1.0, 1.0), **{**BANKS, "reach_cells": 40, "wall_cells": wall})
    want = np.zeros(z.shape, bool)
    want[3:5, 2:30 - wall] = True             # the top at column 30; column 31 is rough (the drop beside it)
    np.testing.assert_array_equal(got, want)



@pytest.mark.parametrize("band_rows, sparse", [(4, 1.0 / 16), (64, 1.0 / 16), (7, 0.0), (64, 1.0)])
def test_bracketed_with_the_planes_asked_where_needed_equals_the_whole_planes(monkeypatch, band_rows, sparse):
    """find_bracketed asking for the seen ground's planes only where they can change the result
    (``seen_gradient_of``: the cells above the lowest ground on both sides of a line by nearly dh, and that line
    within the reach) gives the cells of the planes computed everywhere, whether the first pass keeps its floors
    (sparse) or the second computes them again (``LOWEST_SPARSE`` 0); the planes are asked at a few cells."""
    monkeypatch.setattr(dr, "_BAND_ROWS", band_rows)
    monkeypatch.setattr(dr, "LOWEST_SPARSE", sparse)
    rng = np.random.default_rng(8)
    y, x = np.mgrid[0:90, 0:70].astype(np.float32)
    z = (0.35 * x + 0.01 * (y - 45) ** 2 + rng.normal(0, 0.1, x.shape)).astype(np.float32)
    z[rng.random(z.shape) < 0.03] += rng.uniform(0.4, 1.5)        # bushes, some near the threshold
    z[rng.random(z.shape) < 0.02] = np.nan
    ground = rng.random(z.shape) > 0.1
    cell, s, dh, reach = (1.0, 1.0), 0.5, 0.5, 6.0
    whole = dr.find_bracketed(z, ground, cell, slope=s, height_m=dh, reach_m=reach,
                              seen_gradient=dr.seen_ground_gradient(z, ground, cell, reach))
    asked = []

    def planes(at):
        asked.append(at)
        return dr.seen_ground_gradient(z, ground, cell, reach, at=at)

    got = dr.find_bracketed(z, ground, cell, slope=s, height_m=dh, reach_m=reach, seen_gradient_of=planes)
    assert whole.sum() > 20
    np.testing.assert_array_equal(got, whole)
    assert len(asked) == 1 and asked[0][whole].all()
    if sparse:
        assert asked[0].mean() < 0.6
    # refine_ground asks for them so: its mask as with the planes everywhere
    mask = np.where(ground, GROUND, OBJECT).astype(np.uint8)
    new, _ = dr.refine_ground(z, mask, cell, tolerance_m=dh, slope=s, reach_m=reach, along_ground=True)
    assert (new[whole] == OBJECT).all()


def test_bracketed_with_the_planes_asked_where_needed_keeps_the_bumps_just_above_dh():
    """On nearly level ground (the planes raise the height to exceed by little, the noise's slope over a long
    reach little) bumps 0.53-0.545 m high stand above floors 0.5 m below them: the first pass keeps every cell
    standing ``LOWEST_MARGIN dh`` above the lowest ground on both sides, so none of them is lost."""
    rng = np.random.default_rng(4)
    y, x = np.mgrid[0:80, 0:80].astype(np.float32)
    z = (14.0 + 0.005 * x + rng.normal(0, 0.002, x.shape)).astype(np.float32)
    bumps = rng.random(z.shape) < 0.02
    z[bumps] += rng.uniform(0.53, 0.545, bumps.sum()).astype(np.float32)
    ground = np.ones(z.shape, bool)
    cell, s, dh, reach = (1.0, 1.0), 0.5, 0.5, 30.0
    whole = dr.find_bracketed(z, ground, cell, slope=s, height_m=dh, reach_m=reach,
                              seen_gradient=dr.seen_ground_gradient(z, ground, cell, reach))
    got = dr.find_bracketed(z, ground, cell, slope=s, height_m=dh, reach_m=reach,
                            seen_gradient_of=lambda at: dr.seen_ground_gradient(z, ground, cell, reach, at=at))
    assert whole.sum() > 0.5 * bumps.sum()
    np.testing.assert_array_equal(got, whole)


def test_refine_ground_spares_the_given_cells_from_every_test():
    """The cells ``spared`` (``bareearth:dtm``: the banks continue_banks gave back) are left by the bracketed
    test: a narrow dike 2.4 m high (a crest of two cells, sharp at 2 m cells) is bracketed by the fields on both
    sides of the line across it, as a bush is; the bush on the fields is still taken."""
    z = _dike(15, 40, [0, 0, 0, 0, 0, 1.2, 2.4, 2.4, 1.2, 0, 0, 0, 0, 0, 0])
    z[12, 20] = 1.0                                  # a bush 1 m high on the fields
    mask = np.zeros(z.shape, np.uint8)
    cell = (2.0, 2.0)
    taken, _ = dr.refine_ground(z, mask, cell, tolerance_m=0.5, slope=0.05, edge_tolerance_m=0.3)
    dike = z > 0
    dike[12, 20] = False
    assert (taken[dike] == OBJECT).mean() > 0.9          # without the sparing the dike is cut
    assert taken[12, 20] == OBJECT
    kept, _ = dr.refine_ground(z, mask, cell, tolerance_m=0.5, slope=0.05, edge_tolerance_m=0.3, spared=dike)
    assert (kept[dike] == GROUND).all()
    assert kept[12, 20] == OBJECT
    # only the spared cells differ
    np.testing.assert_array_equal(kept[~dike], taken[~dike])


def test_find_level_lines_long_straight_ground_only():
    """A graded crest (0.1 m a cell) along the rows lies on its level line; a hedge's rough top (+-0.6 m) does not;
    nor a line cut by a cell that is no ground, nor a bush's cell; only the cells asked are read."""
    z = np.zeros((12, 40), np.float32)
    z[2, :] = 1.0 + 0.1 * np.arange(40)                       # a graded crest
    z[5, :] = 1.0 + 0.6 * (np.arange(40) % 2)                 # a hedge's rough top
    z[8, :] = 1.0
    z[10, 20] = 1.0                                           # a bush
    ground = np.ones(z.shape, bool)
    ground[8, 25] = False                                     # an object cuts row 8
    cells = z > 0
    got = dr.find_level_lines(z, ground, cells, (1.0, 1.0), tolerance_m=0.3, reach_m=5.0)
    assert got[2, 5:35].all()
    assert not got[5].any()
    assert got[8, 5:19].all() and not got[8, 20:31].any() and got[8, 31:35].all()
    assert not got[10, 20]
    assert not got[~cells].any()
    # half a metre of reach at 1 m cells: one cell each side, still a line
    assert dr.find_level_lines(z, ground, cells, (1.0, 1.0), tolerance_m=0.3, reach_m=0.5)[2, 1:39].all()
    # at least min_cells each side: a line of one cell each side then cut at three is not long
    short = dr.find_level_lines(z, ground, cells, (1.0, 1.0), tolerance_m=0.3, reach_m=1.0, min_cells=3)
    assert short[8, 3:22].all() and not short[8, 22:29].any() and short[8, 29:37].all()
    # nodata breaks a line
    zn = z.copy()
    zn[2, 12] = np.nan
    assert not dr.find_level_lines(zn, ground, cells, (1.0, 1.0), tolerance_m=0.3, reach_m=5.0)[2, 8:17].any()


@pytest.mark.parametrize("kw, match", [({"tolerance_m": 0.0}, "tolerance_m"), ({"reach_m": -1.0}, "reach_m"),
                                       ({"tolerance_m": float("nan")}, "tolerance_m")])
def test_find_level_lines_bad_parameters(kw, match):
    z = np.zeros((5, 5), np.float32)
    args = {"tolerance_m": 0.3, "reach_m": 2.0, **kw}
    with pytest.raises(ValueError, match=match):
        dr.find_level_lines(z, z == 0, z == 0, (1.0, 1.0), **args)
    with pytest.raises(ValueError, match="min_cells"):
        dr.find_level_lines(z, z == 0, z == 0, (1.0, 1.0), tolerance_m=0.3, min_cells=0)
    with pytest.raises(ValueError, match="shape"):
        dr.find_level_lines(z, np.ones((4, 5), bool), z == 0, (1.0, 1.0), tolerance_m=0.3)


def test_refine_ground_level_lines_keep_a_platform_and_take_a_bush():
    """A railway platform 1.2 m high and four cells wide between tracks, along the rows (2 m cells, noise 5 cm):
    the bracketed test takes it (lower ground on both sides across); on a straight line of ground running
    LEVEL_LINE_M both ways (level_lines) it stays ground; a bush beside it is still taken, and the blocks equal
    one pass."""
    z = np.random.default_rng(0).normal(0.0, 0.05, (20, 60)).astype(np.float32)
    z[8:12, 5:55] += 1.2
    z[15, 30] += 1.0                                          # a bush
    mask = np.zeros(z.shape, np.uint8)
    kw = dict(tolerance_m=0.5, slope=0.02, edge_tolerance_m=0.3)
    taken, _ = dr.refine_ground(z, mask, (2.0, 2.0), **kw)
    assert (taken[8:12, 10:50] == OBJECT).mean() > 0.9
    kept, _ = dr.refine_ground(z, mask, (2.0, 2.0), level_lines=True, **kw)
    assert (kept[8:12, 10:50] == GROUND).all()
    assert kept[15, 30] == OBJECT
    halo = dr.refine_halo((2.0, 2.0))

    def run(rows, cols):
        zb = z[rows, cols]
        return dr.refine_ground(zb, np.zeros(zb.shape, np.uint8), (2.0, 2.0), level_lines=True, **kw)[0]
    np.testing.assert_array_equal(in_blocks(run, z.shape, 7, halo), kept)


def _hillside(rows=21, cols=21, slope=0.3):
    y, x = np.mgrid[0:rows, 0:cols].astype(np.float32)
    return x, y, (slope * x + 0.02 * ((x + y) % 2)).astype(np.float32)


def test_find_disputed_bumps_a_shrub_on_a_slope_and_not_the_noise():
    """A 0.4 m shrub on a slope rising 0.3 per cell stands 0.4 m above the plane of the ground around it (the
    opening's flat window would lower it by max(0, 0.4 - 0.3 w) only); a cell 0.05 m up, within the tolerance,
    and the ground every member agrees on are not judged."""
    _, _, z = _hillside()
    z[10, 10] += 0.4
    z[10, 11] += 0.05
    anchors = np.ones(z.shape, bool)
    anchors[10, 10:12] = False
    found = dr.find_disputed_bumps(z, np.ones(z.shape, bool), anchors, (1.0, 1.0), tolerance_m=0.1)
    assert np.argwhere(found).tolist() == [[10, 10]]
    # more than three standard deviations of the ground about its plane: on rough ground (0.3 m) it is not
    rough = z + 0.3 * np.random.default_rng(0).standard_normal(z.shape).astype(np.float32)
    rough[10, 10] = z[10, 10]
    assert not dr.find_disputed_bumps(rough, np.ones(z.shape, bool), anchors, (1.0, 1.0), tolerance_m=0.1)[10, 10]


def test_find_disputed_bumps_spares_a_steps_top_and_a_raised_level():
    """A terrace's upper edge (the ground every member agrees on lying on both levels, the disputed strip at the
    top of the 2 m step) stands above the plane the window fits across the step, but an anchor beside it stands
    as high above that plane, and on the lines across, the ground beside it on its own level continues it."""
    x, _, z = _hillside()
    z = z + 2.0 * (x >= 10)
    anchors = np.ones(z.shape, bool)
    anchors[:, 10:12] = False
    assert not dr.find_disputed_bumps(z, np.ones(z.shape, bool), anchors, (1.0, 1.0), tolerance_m=0.1).any()


def test_find_disputed_bumps_judges_only_the_candidates():
    """Only ground not among the anchors is a candidate; no ground, no candidates: nothing found."""
    _, _, z = _hillside()
    z[10, 10] += 0.4
    anchors = np.ones(z.shape, bool)
    assert not dr.find_disputed_bumps(z, np.ones(z.shape, bool), anchors, (1.0, 1.0), tolerance_m=0.1).any()
    anchors[10, 10] = False
    ground = np.ones(z.shape, bool)
    ground[10, 10] = False
    assert not dr.find_disputed_bumps(z, ground, anchors, (1.0, 1.0), tolerance_m=0.1).any()
    with pytest.raises(ValueError, match="tolerance_m"):
        dr.find_disputed_bumps(z, ground, anchors, (1.0, 1.0), tolerance_m=0.0)


def test_stands_above_ground_min_lines_judges_the_bracketing_lines_only():
    """With min_lines a line without ground on both sides is not judged (rather than sparing the cell): a bump
    in a patch wider along the rows than the reach is above the columns' and diagonals' lines."""
    z = np.zeros((9, 9), np.float32)
    z[4, 4] = 0.6
    ground = np.ones(z.shape, bool)
    ground[4, :] = False                      # the patch runs along the whole row
    cells = np.zeros(z.shape, bool)
    cells[4, 4] = True
    assert not dr.stands_above_ground(z, ground, cells, height_m=0.3, reach_cells=3).any()
    assert dr.stands_above_ground(z, ground, cells, height_m=0.3, reach_cells=3, min_lines=3)[4, 4]
    assert not dr.stands_above_ground(z, ground, cells, height_m=0.3, reach_cells=3, min_lines=4).any()
    z[3, 3] = z[5, 5] = 0.6                   # ground as high on a diagonal: not above every judged line
    assert not dr.stands_above_ground(z, ground, cells, height_m=0.3, reach_cells=3, min_lines=2).any()


def test_find_disputed_bumps_not_within_a_cells_rise():
    """On a slope rising 1.5 m per cell (an outcrop's foot at 4 m) a cell 1.2 m above the plane may be ground
    whose height lies elsewhere in its cell than the anchors' do: the least height is the plane's rise over one
    cell; 2 m above it is a bump."""
    _, _, z = _hillside(slope=1.5)
    anchors = np.ones(z.shape, bool)
    anchors[10, 10] = False
    low, high = z.copy(), z.copy()
    low[10, 10] += 1.2
    high[10, 10] += 2.0
    assert not dr.find_disputed_bumps(low, np.ones(z.shape, bool), anchors, (4.0, 4.0), tolerance_m=0.1).any()
    found = dr.find_disputed_bumps(high, np.ones(z.shape, bool), anchors, (4.0, 4.0), tolerance_m=0.1)
    assert np.argwhere(found).tolist() == [[10, 10]]


def test_stands_above_ground_reads_the_ground_on_the_cells_own_level():
    """With ``jump_m`` a line's ground beyond a level change (a 3 m retaining wall below the cell) is another
    level's: the line is not judged; a tree between the cell and its ground (not among the levels' cells) is
    stepped over, and a line rising with the terrain's gradient is no level change."""
    z = np.zeros((5, 11), np.float32)
    z[:, :5] = -3.0                                     # the terrace below the wall, beside the cell
    z[2, 5] = 0.6                                       # the cell, 0.6 m above its own level's ground
    ground = np.ones(z.shape, bool)
    ground[2, 5] = False
    cells = ~ground
    kw = dict(height_m=0.3, reach_cells=5, min_lines=1)
    assert dr.stands_above_ground(z, ground, cells, **kw)[2, 5]                  # the row, across the wall
    got = dr.stands_above_ground(z, ground, cells, jump_m=2.0, **kw)
    assert got[2, 5]                                    # the column: ground on its own level both sides
    rows = np.zeros(z.shape, bool)
    rows[2, :] = True                                   # only the row's ground: the wall's line alone
    assert dr.stands_above_ground(z, ground & rows, cells, **kw)[2, 5]
    assert not dr.stands_above_ground(z, ground & rows, cells, jump_m=2.0, **kw)[2, 5]
    # a tree (8 m, not ground) between the cell and its ground on both sides: stepped over
    t = np.zeros((1, 11), np.float32)
    t[0, 3] = t[0, 7] = 8.0
    t[0, 5] = 0.6
    g = np.ones(t.shape, bool)
    g[0, [3, 5, 7]] = False
    c = np.zeros(t.shape, bool)
    c[0, 5] = True
    assert dr.stands_above_ground(t, g, c, jump_m=2.0, levels=g | c, **kw)[0, 5]
    # the ground rising 2.5 m per cell along the row, the gradient given: no level change
    s = np.tile(2.5 * np.arange(11, dtype=np.float32), (1, 1))
    s[0, 5] += 0.6
    grad = (np.full(s.shape, 2.5), np.zeros(s.shape))
    assert not dr.stands_above_ground(s, c == 0, c, jump_m=2.0, **kw)[0, 5]
    assert dr.stands_above_ground(s, c == 0, c, jump_m=2.0, gradient=grad, **kw)[0, 5]


@pytest.mark.parametrize("half", [(1, 1), (2, 3), (6, 6)])
def test_window_sums_gathered_at_a_few_cells_equal_the_whole_rasters_correlations(half):
    """The plane's sums at a few cells, their windows gathered, are ndimage.correlate1d's of the whole raster
    (rows, then columns; zeros beyond the raster) to the last bit: the same sums whichever way a block takes."""
    rng = np.random.default_rng(3)
    z = rng.normal(100.0, 5.0, (40, 50)).astype(np.float32)
    z[rng.random(z.shape) < 0.05] = np.nan
    known = rng.random(z.shape) < 0.7
    r, c = np.nonzero(rng.random(z.shape) < 0.2)
    r, c = np.r_[r, 0, 39, 0], np.r_[c, 0, 49, 49]          # the raster's corners too
    ky, kx = half
    oy, ox = np.arange(-ky, ky + 1.0), np.arange(-kx, kx + 1.0)
    k = known & np.isfinite(z)
    kf, kz = k.astype(np.float64), np.where(k, z.astype(np.float64), 0.0)

    def corr(a, wx, wy):
        a = ndimage.correlate1d(a, wx, axis=1, mode="constant", cval=0.0)
        return ndimage.correlate1d(a, wy, axis=0, mode="constant", cval=0.0)[r, c]
    one_x, one_y = np.ones_like(ox), np.ones_like(oy)
    want = [corr(kf, one_x, one_y), corr(kf, ox, one_y), corr(kf, one_x, oy), corr(kf, ox * ox, one_y),
            corr(kf, ox, oy), corr(kf, one_x, oy * oy), corr(kz, one_x, one_y), corr(kz, ox, one_y),
            corr(kz, one_x, oy), corr(kz * kz, one_x, one_y)]
    for gather in (True, False, None):
        got = dr._window_sums(z, known, r, c, half, squares=True, gather=gather)
        assert len(got) == len(want)
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g, w)


def test_find_disputed_bumps_reads_only_the_candidates_windows(monkeypatch):
    """A few candidates (one shrub among 40 x 40 anchors) take the gathered windows, never a correlation of the
    whole raster, and find the shrub as the whole raster's sums do."""
    _, _, z = _hillside(40, 40)
    z[20, 20] += 0.4
    anchors = np.ones(z.shape, bool)
    anchors[20, 20] = False
    calls = []
    real, real_sums = dr.ndimage.correlate1d, dr._window_sums
    monkeypatch.setattr(dr.ndimage, "correlate1d", lambda *a, **k: calls.append(1) or real(*a, **k))
    found = dr.find_disputed_bumps(z, np.ones(z.shape, bool), anchors, (1.0, 1.0), tolerance_m=0.1)
    assert np.argwhere(found).tolist() == [[20, 20]] and not calls
    monkeypatch.setattr(dr, "_window_sums", lambda *a, **k: real_sums(*a, **{**k, "gather": False}))
    np.testing.assert_array_equal(dr.find_disputed_bumps(z, np.ones(z.shape, bool), anchors, (1.0, 1.0),
                                                         tolerance_m=0.1), found)
    assert calls


def _edge_scene(band=0.45):
    """Level ground (z = 0) with a crown (z = 6) in columns 8-11 and a one-cell band of low vegetation
    ``band`` m high along its western edge (column 7): each band cell is continued by its neighbours along the
    edge, so no single continuation finds it above every one of them."""
    z = np.zeros((16, 16), np.float32)
    z[:, 8:12] = 6.0
    z[:, 7] = band
    objects = z > 3.0
    ground = ~objects
    return z, ground, ground & touching(objects)


def test_raised_edge_ground_takes_a_band_above_most_of_the_ground_around():
    z, ground, candidates = _edge_scene(0.45)
    out = dr.find_raised_edge_ground(z, ground, candidates, (1.0, 1.0), tolerance_m=0.3)
    # the 5 x 5 ring of a band cell holds 19 ground cells: 4 of the band (0.45 m, height 0 above it) and 15 of the
    # level ground (0.45 m above their continuation): the median is 0.45 > 0.3
    assert out[:, 7].all() and np.count_nonzero(out) == 16
    # the edge test, which asks for a cell above *every* continuation, finds none of them: the band continues itself
    assert not find_edge_spikes(z, ~ground, 0.3)[:, 7].any()


@pytest.mark.parametrize("chunk", [7, 1 << 16])
def test_raised_edge_ground_with_a_pool_equals_one_thread(monkeypatch, chunk):
    """The rings' chunks of candidates and the planes' bands of rows taken by a second thread give the cells of one
    thread exactly (chunks of 7 candidates and bands of 5 rows: many of each, the bands' seams between candidates;
    nodata among the ground, a hillside, low vegetation along the crowns' edges)."""
    from concurrent.futures import ThreadPoolExecutor

    from bare_earth.core import estimate
    monkeypatch.setattr(dr, "_EDGE_CHUNK", chunk)
    monkeypatch.setattr(estimate, "_PLANE_BAND_ROWS", 5)
    rng = np.random.default_rng(5)
    z = rng.normal(0.0, 0.1, (37, 43)).astype(np.float32) + np.float32(0.2) * np.arange(43, dtype=np.float32)
    objects = np.zeros(z.shape, bool)
    for r0, c0 in ((4, 5), (18, 20), (27, 8), (10, 31)):
        objects[r0:r0 + 6, c0:c0 + 5] = True
    z[objects] += 5.0
    band = touching(objects) & ~objects & (rng.random(z.shape) < 0.7)
    z[band] += rng.uniform(0.2, 0.8, np.count_nonzero(band)).astype(np.float32)
    z[rng.random(z.shape) < 0.03] = np.nan
    ground = ~objects & np.isfinite(z)
    candidates = ground & touching(objects)
    kw = dict(tolerance_m=0.3, level_m=2.0, reach_m=6.0)
    ref = dr.find_raised_edge_ground(z, ground, candidates, (1.0, 1.0), **kw)
    with ThreadPoolExecutor(max_workers=1) as pool:
        got = dr.find_raised_edge_ground(z, ground, candidates, (1.0, 1.0), **kw, pool=pool)
    np.testing.assert_array_equal(got, ref)
    assert 0 < np.count_nonzero(ref) < np.count_nonzero(candidates)


def test_raised_edge_ground_keeps_ground_within_the_tolerance_and_on_a_bank():
    z, ground, candidates = _edge_scene(0.25)
    assert not dr.find_raised_edge_ground(z, ground, candidates, (1.0, 1.0), tolerance_m=0.3).any()
    # a bank rising at 0.5 towards the crown (the cells beside it lie on the plane the ground is seen on)
    z, ground, candidates = _edge_scene(0.0)
    cols = np.arange(z.shape[1], dtype=np.float32)
    z = np.where(ground, 0.5 * cols[None, :], z).astype(np.float32)
    assert not dr.find_raised_edge_ground(z, ground, candidates, (1.0, 1.0), tolerance_m=0.3).any()
    # the same bank read with a level plane (no ground seen around) would take the bank's top: its slope matters
    assert np.all(dr.raised_edge_tolerance(0.3, 0.5, 2.0) > dr.raised_edge_tolerance(0.3, 0.0, 2.0))


def test_raised_edge_ring_and_reach():
    assert dr.raised_edge_ring((1.0, 1.0)) == 2 and dr.raised_edge_ring((2.0, 2.0)) == 1
    assert dr.raised_edge_ring((4.0, 4.0)) == 1 and dr.raised_edge_ring((0.5, 0.5)) == 4
    assert dr.raised_edge_reach((1.0, 1.0)) == 2 + dr.line_slope_radius((1.0, 1.0)) + 1
