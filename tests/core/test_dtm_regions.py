"""bareearth:dtm's raised regions: voted ground wider than the vote's windows standing on steps above the ground."""
import numpy as np
import pytest
from scipy import ndimage
from surfaces import grid, in_blocks, noisy, raised_ground

from bare_earth.core import dtm_refine as dr
from bare_earth.core import pipeline
from bare_earth.core.codes import GROUND, OBJECT
from bare_earth.core.dtm import describe_region
from bare_earth.core.dtm_regions import REACH_CELLS, find_detached_levels, find_raised_regions, regions_halo


def _find(z, mask=None, **kw):
    kw = {"tolerance_m": 0.5, "min_width_m": 10.0, "max_cells": 100, **kw}
    m = np.zeros(z.shape, np.uint8) if mask is None else mask
    return find_raised_regions(z, m, (1.0, 1.0), **kw)


def test_a_block_standing_on_walls_is_an_object_with_its_rim():
    z = np.zeros((40, 40), np.float32)
    z[10:30, 8:28] = 5.0
    objects, decisions = _find(z)
    box = np.zeros(z.shape, bool)
    box[10:30, 8:28] = True
    assert np.array_equal(objects, box)             # the region (18 x 18) and its rim on top of the walls
    roof = [d for d in decisions if d["object"]]
    assert len(roof) == 1 and roof[0]["cells"] == 18 * 18
    assert roof[0]["step_share"] == 1.0 and roof[0]["above_share"] == 1.0
    assert not any(d["object"] for d in decisions if d is not roof[0])     # the ground around: no steps


def test_objects_on_the_roof_do_not_hide_its_walls():
    z = np.zeros((40, 40), np.float32)
    z[10:30, 8:28] = 5.0
    mask = np.zeros(z.shape, np.uint8)
    mask[14:17, 12:15] = OBJECT                     # plant rooms on the roof: holes of the region
    mask[20:26, 18:24] = OBJECT
    objects, decisions = _find(z, mask)
    assert objects[10:30, 8:28][mask[10:30, 8:28] == GROUND].all()
    assert [d["step_share"] for d in decisions if d["object"]] == [1.0]


def test_what_the_vote_reaches_or_the_stage_cannot_see_whole_is_left_alone():
    z = np.zeros((40, 40), np.float32)
    z[10:30, 8:28] = 5.0
    assert not _find(z, min_width_m=40.0)[0].any()          # narrower than the vote's window
    assert not _find(z, max_cells=17)[0].any()              # spans more cells than the stage reaches
    assert not _find(z, tolerance_m=6.0)[0].any()           # walls lower than the object height threshold
    assert not _find(z, max_cells=0)[0].any() and regions_halo(0) == 0
    assert regions_halo(17) == 17 + REACH_CELLS


def test_a_level_running_off_the_raster_on_walls_is_an_object_within_the_reach():
    # a raised level with walls on two sides and the raster's edge on the other two (a roof running off a
    # corner of the tile): beyond the edge nothing is seen, so its outline is its walls, and it stands on
    # steps; its width and its span are those of the level mirrored at the edge
    z = np.zeros((40, 40), np.float32)
    z[15:, 15:] = 4.0
    objects, decisions = _find(z)
    level = np.zeros(z.shape, bool)
    level[15:, 15:] = True
    assert np.array_equal(objects, level)
    upper = [d for d in decisions if d["object"]]
    # the region (rows and columns 16-39: the wall's top is its rim) mirrored: twice 24 cells less one
    assert len(upper) == 1 and upper[0]["step_share"] == 1.0 and upper[0]["width_m"] == 47.0
    assert upper[0]["outline_cells"] == 47                   # next to the walls' top only, not the raster's edge
    # mirrored, wider than the stage reaches (2 x 25 = 50 cells > 45), though spanning fewer cells: left alone
    assert not _find(z, max_cells=45)[0].any()


def test_a_level_cut_by_two_opposite_edges_is_left_alone():
    # a terrain step running across the raster (a retaining wall, a river bank, a quarry bench): its upper
    # level is cut by the raster's edge on two opposite sides, so it continues beyond both; mirrored at each,
    # it spans three times what is seen (3 x 40 = 120 cells), more than the stage reaches (100): left alone,
    # though within the raster it looks like a roof running off it on three sides
    z = np.zeros((40, 40), np.float32)
    z[:, 15:] = 4.0
    objects, decisions = _find(z)
    assert not objects.any() and not any(d["object"] for d in decisions)
    # the decision says why: its wall runs across the raster, 3 x 40 cells mirrored at both ends
    left = [d for d in decisions if d["bbox"] == [0, 16, 40, 40]]      # the upper level (its wall's top: rims)
    assert len(left) == 1 and not left[0]["reached"] and left[0]["walls_m"] == 120.0
    assert describe_region(left[0]).endswith("beyond the stage's reach: left to the vote")
    # a stage reaching that far takes it for a roof: the terrain step and the roof are alike within the raster
    assert np.array_equal(_find(z, max_cells=120)[0], z > 0)


def test_a_level_whose_wall_cuts_off_a_corner_is_judged_by_its_walls_run():
    # a level over most of the raster meeting all four sides (two opposite pairs), its one wall cutting off a
    # corner (meeting two adjacent sides, a roof running off the raster beyond three sides): its wall's run,
    # mirrored at the two sides it meets, spans 2 x 23 cells, within the stage's reach, though the level's own
    # box mirrored at its four sides spans 3 x 40 (a terrain step's wall meets two opposite sides)
    y, x = grid(40)
    z = np.where(x + y > 20, 4.0, 0.0).astype(np.float32)
    objects, decisions = _find(z)
    assert np.array_equal(objects, z > 0)
    upper = [d for d in decisions if d["object"]]
    assert len(upper) == 1 and upper[0]["reached"] and upper[0]["walls_m"] == 46.0
    assert upper[0]["step_share"] > 0.9 and upper[0]["above_share"] == 1.0     # (the wall's ends: no ground beyond)
    assert not _find(z, max_cells=39)[0].any()              # the level spans more cells than the stage reaches
    # quarry benches: beyond that wall the ground steps down again (a second wall, 4 m, cutting off the corner):
    # the level is one of a sequence of levels the raster cuts, left to the vote, and the log says why
    z = np.where(x + y > 20, 4.0, np.where(x + y > 10, 0.0, -4.0)).astype(np.float32)
    objects, decisions = _find(z)
    assert not objects.any()
    upper = [d for d in decisions if d["bbox"] == [0, 0, 40, 40]]
    assert upper and all(d["steps_beyond"] > d["outline_cells"] / 2 for d in upper)
    assert describe_region(upper[0]).endswith("one of a sequence of levels, left to the vote")


@pytest.mark.parametrize("n", [200, 400])
def test_dtm_keeps_terrain_steps_across_the_raster(n):
    # vertical drops of bare ground across the raster at 1 m cells: a 5 m step, a river 30 m wide between
    # walls 4 m high, a terrace 60 m wide on a 3 m wall: no cell is an object
    rng = np.random.default_rng(3)
    y, x = np.mgrid[0:n, 0:n].astype(np.float32)
    for g in (100.0 - 5.0 * (x > n // 2), 100.0 - 4.0 * (np.abs(x - n // 2) < 15), 100.0 - 3.0 * (x > 60)):
        z = (g + rng.normal(0, 0.05, g.shape)).astype(np.float32)
        r = pipeline.run_array("dtm", z, 1.0)
        assert np.count_nonzero(r.mask == OBJECT) == 0


def test_a_level_joined_to_the_ground_by_a_bank_is_no_object():
    # a terrace's upper level running off a corner of the raster: a wall over a quarter of its seen outline
    # (rows 25-39 of its west side), a bank (4 cells, 45 degrees) over the rest: not bounded by steps
    y, x = grid(40)
    z = np.zeros((40, 40), np.float32)
    bank = (x >= 11) & (y >= 6) & ~((y >= 25) & (x < 15))
    z[bank] = np.clip(np.minimum(x[bank] - 11.0, y[bank] - 6.0), 0.0, 4.0)
    assert (z[10:, 15:] == 4.0).all()
    objects, decisions = _find(z)
    assert not objects.any()
    upper = [d for d in decisions if d["bbox"][1] > 0]
    assert len(upper) >= 1 and all(0 < d["step_share"] <= 0.5 for d in upper)


def test_a_roof_of_two_levels_is_one_object():
    # a building cut by the raster's edge on two sides (ground on the left and at the top): a lower level 6
    # cells wide (narrower than the vote's window) beside an upper one 2 m higher. Cut at walls higher than the
    # threshold the lower level is a region of its own, too narrow to judge (the upper one stands on steps
    # down to it); cut at walls higher than 2 m (the second doubling) both are one region standing on its walls
    z = np.zeros((40, 40), np.float32)
    z[8:, 10:] = 10.0
    z[8:, 17:] = 12.0
    objects, decisions = _find(z)
    assert objects[8:, 10:].all() and not objects[:8].any() and not objects[:, :10].any()
    roofs = {d["step_m"]: d["bbox"] for d in decisions if d["object"]}
    assert roofs == {0.5: [9, 18, 40, 40], 2.0: [9, 11, 40, 40]}     # at 0.5 m alone: the upper level only


def test_a_raised_level_on_banks_wider_than_a_wall_is_no_object():
    y, x = grid(60)
    r = np.maximum(np.abs(y - 30), np.abs(x - 30))
    for rise in (1.0, 2.0):                      # 45 and 63 degree banks, 6 m high: 6 and 3 cells wide
        z = np.clip((24 - r) * rise, 0, 6).astype(np.float32)
        objects, decisions = _find(z)
        assert not objects.any()
        assert all(d["step_share"] == 0.0 for d in decisions)


def test_a_region_on_steps_but_mostly_below_the_ground_around_is_no_object():
    # walls 2 m high at its outline, then the region sinks 0.3 m per cell to 4 m below the ground
    # around: steps all round, but only the cells within 4 cells of its edge stand above the ground
    y, x = grid(60)
    inside = (y >= 10) & (y < 50) & (x >= 10) & (x < 50)
    depth = np.minimum(np.minimum(y - 10, 49 - y), np.minimum(x - 10, 49 - x))
    z = np.where(inside, np.maximum(2.0 - 0.3 * depth, -4.0), 0.0).astype(np.float32)
    objects, decisions = _find(z)
    bowl = [d for d in decisions if d["step_share"] > 0.5]
    assert len(bowl) == 1 and bowl[0]["step_share"] == 1.0
    assert bowl[0]["above_share"] == pytest.approx((38 ** 2 - 30 ** 2) / 38 ** 2, abs=1e-3)
    assert not objects.any()


def _cut_into_hillside(walls):
    """A steep hillside (0.5 m per metre, down the rows) with a yard dug into it to the hillside's level at its
    downhill end, and on the yard a level 2 m below the hillside uphill: a building's flat roof on walls
    (``walls``) or a terrace joined to the yard by banks of 1 m per metre; the vote calls the level's
    downhill part (most of it, standing highest above the hillside) an object, its part against the hillside
    ground."""
    from scipy import ndimage
    z = np.broadcast_to(40.0 - 0.5 * np.arange(80.0)[:, None], (80, 70)).copy()
    foot = 40.0 - 0.5 * 49
    z[25:49, 14:56] = foot
    top = 40.0 - 0.5 * 25 - 2.0
    level = np.zeros(z.shape, bool)
    level[25:46, 20:50] = True
    z[level] = top if walls else np.minimum(top, foot + ndimage.distance_transform_edt(level)[level])
    mask = np.zeros(z.shape, np.uint8)
    mask[33:46, 20:50] = OBJECT
    return z.astype(np.float32), mask, level


def test_a_building_cut_into_a_hillside_is_an_object_and_a_terrace_without_walls_stays_ground():
    # narrower than the vote's window (64 m): a candidate only because it is cut into the hillside (its uphill
    # outline below the ground beyond) and the vote calls most of it an object; its walls are its other sides
    z, mask, level = _cut_into_hillside(walls=True)
    objects, decisions = _find(z, mask, min_width_m=64.0, max_cells=160)
    assert objects[level & (mask == GROUND)].all()           # the part the vote kept as ground
    assert np.count_nonzero(objects & ~level) <= 6           # the hillside above stays ground (a corner cell or so)
    roof = [d for d in decisions if d["object"]]
    assert len(roof) == 1 and roof[0]["cut_in_cells"] > 0 and roof[0]["step_share"] == 1.0
    # the same level joined to the yard by banks: no walls, ground
    z, mask, level = _cut_into_hillside(walls=False)
    objects, decisions = _find(z, mask, min_width_m=64.0, max_cells=160)
    assert not objects.any() and not any(d["object"] for d in decisions)
    # a level the vote calls ground on most of its cells is its decision: left alone
    z, mask, level = _cut_into_hillside(walls=True)
    mask[:] = GROUND
    mask[40:46, 20:50] = OBJECT
    assert not _find(z, mask, min_width_m=64.0, max_cells=160)[0].any()
    # the vote's ground downhill, its objects against the hillside: the slope allowances do not explain the split
    # (the cut holds no voted ground), left to the vote
    mask[:] = GROUND
    mask[25:40, 20:50] = OBJECT
    assert not _find(z, mask, min_width_m=64.0, max_cells=160)[0].any()


def test_levels_cut_into_a_hillside_in_blocks_equal_one_pass():
    """The levels cut into a hillside are looked for in windows around their ground parts: blocks read with
    regions_halo cells around them give the one-pass decision, on three buildings side by side (the middle
    one a terrace with banks) whose windows overlap and one whose level runs off the raster."""
    parts = [_cut_into_hillside(walls=w) for w in (True, False, True)]
    z = np.concatenate([p[0] for p in parts], axis=1)
    mask = np.concatenate([p[1] for p in parts], axis=1)
    level = np.concatenate([p[2] & w for p, w in zip(parts, (True, False, True))], axis=1)
    kw = {"tolerance_m": 0.5, "min_width_m": 40.0, "max_cells": 60}
    whole, _ = find_raised_regions(z, mask, (1.0, 1.0), **kw)
    assert whole[level & (mask == GROUND)].all() and not whole[:, 70:140].any()
    halo = regions_halo(kw["max_cells"])

    def part(wr, wc):
        return find_raised_regions(z[wr, wc], mask[wr, wc], (1.0, 1.0), **kw)[0]

    for b in (37, 50):
        assert np.array_equal(in_blocks(part, z.shape, b, halo), whole)
    # cut by the raster's edge (not seen whole): left to the vote
    cut, _ = find_raised_regions(z[:, 30:], mask[:, 30:], (1.0, 1.0), **kw)
    assert not cut[:, :40].any() and np.array_equal(cut[:, 110:], whole[:, 140:])


def test_blocked_equals_one_pass():
    """The stage on windows of a block plus regions_halo cells gives the one-pass decision in the block."""
    rng = np.random.default_rng(4)
    n = 180
    y, x = grid(n)
    z = (10 + 0.02 * x + 0.01 * y + rng.normal(0, 0.03, (n, n))).astype(np.float32)
    mask = np.zeros((n, n), np.uint8)
    for r0, c0, h, w, top in ((5, 5, 30, 40, 6.0), (60, 20, 50, 70, 9.0), (20, 100, 70, 60, 4.0),
                              (130, 110, 40, 25, 7.0), (120, 10, 55, 55, 3.0), (0, 165, 45, 15, 5.0)):
        z[r0:r0 + h, c0:c0 + w] += top
        mask[r0 + h // 2, c0 + w // 2] = OBJECT
    z[12:28, 25:45] += 2.0                          # a roof of two levels
    z[168:, 60:100] += 8.0                          # a roof cut by the raster's edge
    kw = {"tolerance_m": 0.5, "min_width_m": 20.0, "max_cells": 60}
    whole, _ = find_raised_regions(z, mask, (1.0, 1.0), **kw)
    assert whole.any() and not whole.all()
    halo = regions_halo(kw["max_cells"])

    def part(wr, wc):
        return find_raised_regions(z[wr, wc], mask[wr, wc], (1.0, 1.0), **kw)[0]

    for b in (37, 50):
        assert np.array_equal(in_blocks(part, z.shape, b, halo), whole)


# ----------------------------------------------------------------------------- detached levels

def _annex(n=60):
    """Ground at 0 (every member agrees), a 3 m annex (RASCOR alone dissents) against a 12 m block."""
    z = np.zeros((n, n), np.float32)
    z[10:20, 10:50] = 12.0                          # the tall block: objects of the vote
    z[20:32, 15:45] = 3.0                           # the annex: 12 x 30 cells
    ground = z < 10
    dissent = z == 3.0
    anchors = z == 0.0
    return z, ground, dissent, anchors


def _detached(z, ground, dissent, anchors, **kw):
    kw = {"jump_m": 2.0, "slope": 0.1, "max_cells": 40, **kw}
    return find_detached_levels(z, ground, dissent, anchors, (1.0, 1.0), **kw)


def test_a_level_cut_by_level_changes_from_the_undisputed_ground_is_an_object_with_its_edge():
    z, ground, dissent, anchors = _annex()
    out = _detached(z, ground, dissent, anchors)
    assert np.array_equal(out, dissent)             # its inside, and its edge on top of the walls


def test_a_level_joined_to_the_undisputed_ground_or_not_dissented_stays_ground():
    z, ground, dissent, anchors = _annex()
    free = z.copy()
    free[10:20, 10:50] = 0.0                        # the annex standing alone (no taller block beside it)
    anchored = anchors.copy()
    anchored[25, 30] = True                         # one cell of it every member agrees on
    assert not _detached(free, free < 10, dissent, anchored, plane_m=0.25).any()
    anchored[20:32, 15:30] = True                   # against the tall block: as many anchors as dissent
    assert not _detached(z, ground, dissent & ~anchored, anchored, plane_m=0.25).any()
    assert not _detached(z, ground, np.zeros_like(dissent), anchors).any()          # RASCOR agrees: no dissent
    assert not _detached(z, ground, dissent, anchors, jump_m=3.5).any()             # walls below a level change
    assert not _detached(z, ground, dissent, anchors, max_cells=27).any()           # wider (28) than the reach
    assert not _detached(z, ground, dissent, anchors, max_cells=0).any()


def test_a_level_holding_a_few_anchors_against_a_taller_object_is_an_object():
    """A low roof against a taller part of the building (ISPRS 31's courtyard, 1 m: 3-4 m roofs RASCOR rejects,
    three of their cells every member calls ground) is a lower level of the building: those few anchors, fewer
    than the level member's dissent on it, do not join it to the ground. Without the taller block (a piece of
    ground between the level changes of a bank), or with the taller side below TALLER_SIDE_SHARE of its outline,
    it stays ground."""
    z, ground, dissent, anchors = _annex()
    anchored = anchors.copy()
    anchored[25, 30] = anchored[26, 30] = anchored[27, 30] = True     # three cells of it every member agrees on
    out = _detached(z, ground, dissent & ~anchored, anchored, plane_m=0.25)
    assert np.array_equal(out, dissent & ~anchored)
    assert not _detached(z, ground, dissent & ~anchored, anchored).any()           # no plane_m: joined
    # RASCOR rejects only a third of it (its other cells: ground by the vote, RASCOR agreeing): joined
    third = dissent & ~anchored & (np.arange(60)[None, :] < 25)
    assert not _detached(z, ground, third, anchored, plane_m=0.25).any()
    rough = z.copy()
    rough[20:32, 15:45] += np.where((np.indices((12, 30)).sum(0) % 2) == 0, 0.6, -0.6).astype(np.float32)
    assert not _detached(rough, ground, dissent & ~anchored, anchored, plane_m=0.25).any()    # no plane
    # the same annex with the block only along a short stretch of its side: no side of it against a taller object
    short = z.copy()
    short[10:20, 10:50] = 0.0
    short[16:20, 26:34] = 12.0
    assert not _detached(short, short < 10, dissent & ~anchored, anchored, plane_m=0.25).any()
    # the block is voted ground (a hillside rising above a terrace, not an object): stays ground
    assert not _detached(z, np.ones(z.shape, bool), dissent & ~anchored, anchored | (z == 12.0), plane_m=0.25).any()
    # cut by the raster's edge (its anchors may lie beyond): stays ground
    cut = (slice(None), slice(15, None))
    assert not _detached(z[cut], ground[cut], (dissent & ~anchored)[cut], anchored[cut], plane_m=0.25).any()
    # a patch without a top (two cells wide) is a step of a slope, not a roof
    thin = z.copy()
    thin[22:32, 15:45] = 0.0
    held = (thin == 0.0) | (np.arange(60)[None, :] == 30) & (thin == 3.0)       # a cell of each of its rows
    assert not _detached(thin, thin < 10, (thin == 3.0) & ~held, held, plane_m=0.25).any()


def test_another_members_dissent_counts_on_levels_with_a_top_only():
    z, ground, dissent, anchors = _annex()
    none = np.zeros_like(dissent)
    # another member's objects: the annex (a level with a top: cells whose 8 neighbours all lie on it)
    assert np.array_equal(_detached(z, ground, none, anchors, top_dissent=dissent), dissent)
    # a patch two cells wide between level changes (a step of a steep slope) has no top: only the level
    # member's own dissent takes it
    # (its walls' tops are objects of the vote: a patch below voted ground joined to the anchors is a bench of
    # the ground, see test_a_level_below_the_ground_across_a_level_change_stays_ground)
    z2 = np.zeros((30, 30), np.float32)
    z2[10:20, 14:16] = -3.0
    patch = z2 < 0
    voted = ~(ndimage.binary_dilation(patch, np.ones((3, 3), bool)) & ~patch)
    assert not _detached(z2, voted, np.zeros_like(patch), z2 == 0, top_dissent=patch).any()
    assert np.array_equal(_detached(z2, voted, patch, z2 == 0, top_dissent=patch), patch)


def test_a_level_below_the_ground_across_a_level_change_stays_ground():
    """A patch of a steep slope cut off by level changes whose higher side is voted ground joined to the
    undisputed ground (a bench of a cliff on a 4 m grid, matrix row hexbin-crop 4 m: 15 cells holding 124
    ground points, 8.41 -> 8.12 %) lies below the ground: no raised level, whoever rejects it. A low annex
    keeps its higher side on an object, or on voted ground not joined to the undisputed ground."""
    y, x = grid(40)
    z = (0.5 * x).astype(np.float32)                # a slope rising 0.5 m per cell
    bench = (np.abs(y - 20) < 3) & (np.abs(x - 20) < 3)
    z[bench] -= 3.0                                 # 3 m below the slope around: level changes on every side
    ground = np.ones(z.shape, bool)
    assert not _detached(z, ground, bench, ~bench).any()
    # the same patch whose higher neighbours are the vote's objects (a courtyard's walls) is a level
    walls = ndimage.binary_dilation(bench, np.ones((3, 3), bool)) & ~bench
    assert np.array_equal(_detached(z, ~walls, bench, ~bench & ~walls), bench)
    # a low annex against a tall block the vote kept (voted ground, no anchor on it): still an object
    z, ground, dissent, anchors = _annex()
    assert np.array_equal(_detached(z, np.ones(z.shape, bool), dissent, anchors), dissent)


def test_a_bank_rising_within_the_slope_allowance_is_one_level_with_the_ground():
    # the same 3 m reached over a bank of 1 m per cell (< jump_m + s d): no level change, joined to the ground
    z, ground, dissent, anchors = _annex()
    z[20:23, 15:45] = np.array([[1.0], [2.0], [3.0]], np.float32) * np.ones((1, 30), np.float32)
    z[20:32, 12:15] = np.array([1.0, 2.0, 3.0], np.float32)
    z[20:32, 45:48] = np.array([3.0, 2.0, 1.0], np.float32)
    z[32:35, 12:48] = np.array([[2.0], [1.0], [0.0]], np.float32)
    ground = z < 10
    assert not _detached(z, ground, ground & (z > 0), anchors).any()


def test_detached_levels_refuse_bad_input():
    z, ground, dissent, anchors = _annex()
    with pytest.raises(ValueError, match="jump_m"):
        _detached(z, ground, dissent, anchors, jump_m=0.0)
    with pytest.raises(ValueError, match="shape"):
        _detached(z, ground[:-1], dissent, anchors)


def test_detached_levels_blocked_equal_one_pass():
    """On windows of a block plus regions_halo cells, the one-pass decision in the block."""
    rng = np.random.default_rng(7)
    n = 180
    y, x = grid(n)
    z = (10 + 0.02 * x + 0.01 * y + rng.normal(0, 0.03, (n, n))).astype(np.float32)
    dissent = np.zeros((n, n), bool)
    for r0, c0, h, w, top in ((5, 5, 30, 40, 3.0), (60, 20, 50, 70, 2.5), (20, 100, 70, 60, 4.0),
                              (130, 110, 40, 25, 3.5), (120, 10, 55, 55, 6.0)):
        z[r0:r0 + h, c0:c0 + w] += top
        dissent[r0:r0 + h, c0:c0 + w] = True
    for r0, c0, h, w in ((150, 70, 20, 30), (75, 150, 30, 12)):     # benches below the ground (left alone)
        z[r0:r0 + h, c0:c0 + w] -= 4.0
        dissent[r0:r0 + h, c0:c0 + w] = True
    ground = np.ones((n, n), bool)
    z[130:170, 135:143] += 12.0                                       # a taller block along a level's side
    ground[130:170, 135:143] = False
    dissent[130:170, 135:143] = False
    anchors = ~dissent & ground & (rng.random((n, n)) < 0.5)
    anchors[60:110, 20:90] |= rng.random((50, 70)) < 0.001          # a few joined levels
    anchors[140:143, 120:123] = True                                  # a few anchors on the lower roof
    anchors[22:28, 120:125] = True                                    # a level holding a few anchors, no block
    kw = {"jump_m": 2.0, "slope": 0.05, "max_cells": 60, "plane_m": 0.25}
    whole = find_detached_levels(z, ground, dissent, anchors, (1.0, 1.0), **kw)
    assert whole.any() and not whole.all()
    assert not whole[150:170, 70:100].any()
    assert whole[130:170, 110:135].any() and not whole[20:90, 100:160].any()  # the lower roof; the level held

    def part(wr, wc):
        return find_detached_levels(z[wr, wc], ground[wr, wc], dissent[wr, wc], anchors[wr, wc], (1.0, 1.0), **kw)

    for b in (37, 50):
        assert np.array_equal(in_blocks(part, z.shape, b, regions_halo(kw["max_cells"])), whole)


def test_dtm_takes_a_low_annex_only_rascor_rejects_as_an_object(monkeypatch):
    """A 3 m annex against a tall block, which the opening and the reconstruction both accept (as on
    ISPRS sample 31, where their allowances grow with the window and the terrain slope): the vote
    keeps it; RASCOR's dissent on a level cut by walls from all undisputed ground makes it an object."""
    from bare_earth.core import dtm as dtm_method
    from bare_earth.core.methods import get_method
    y, x = grid(128)
    ground = 50 + 0.01 * x + 0.005 * y
    tall = (np.abs(x - 64) < 40) & (y >= 20) & (y < 40)
    annex = (np.abs(x - 64) < 25) & (y >= 40) & (y < 54)
    z = noisy(ground + np.where(tall, 12.0, 0.0) + np.where(annex, 3.0, 0.0), sd=0.05)
    p = dtm_method.resolve_dtm_params(z, 1.0)
    import dataclasses

    def accepting(real):                                   # a member accepting the annex
        def run(z_, cell, progress=None, **kw):
            res = real.run(z_, cell, progress=progress, **kw)
            res.mask[(res.mask == OBJECT) & (np.abs(z_ - ground.astype(np.float32)) < 3.5)] = GROUND
            return res
        return dataclasses.replace(real, run=run)

    # the reconstruction, and the opening (whose attached-tier rule now takes this annex itself,
    # morphology.find_attached_tiers), accept it
    fakes = {name: accepting(get_method(name)) for name in ("geodesic", "morphological")}
    monkeypatch.setattr(dtm_method, "get_method", lambda name: fakes.get(name) or get_method(name))
    res = dtm_method.filter_dtm(z, 1.0, **{k: v for k, v in p.items() if k != "input_description"})
    assert (res.mask[annex] == OBJECT).mean() > 0.95
    assert (res.mask[~annex & ~tall] == GROUND).mean() > 0.99
    assert res.info["detached_level_share"] > 0.5 * annex.sum() / z.size
    monkeypatch.setattr(dtm_method, "find_detached_levels", lambda z_, *a, **k: np.zeros(z_.shape, bool))
    without = dtm_method.filter_dtm(z, 1.0, **{k: v for k, v in p.items() if k != "input_description"})
    assert (without.mask[annex] == GROUND).mean() > 0.5          # the vote alone keeps it


def test_dtm_takes_a_roof_only_the_opening_rejects_as_an_object(monkeypatch):
    """A roof 12 m high cut by the raster's edge (as on ISPRS sample 41 at 1 m, a tower running off the
    tile), which RASCOR and the reconstruction both accept: the vote keeps it; the opening's dissent on a
    level cut by walls from all undisputed ground makes it an object, as RASCOR's does for a low annex."""
    from bare_earth.core import dtm as dtm_method
    from bare_earth.core.methods import get_method
    y, x = grid(128)
    ground = 50 + 0.01 * x + 0.005 * y
    roof = (x >= 116) & (np.abs(y - 64) < 10)
    z = noisy(ground + np.where(roof, 12.0, 0.0), sd=0.05)
    p = dtm_method.resolve_dtm_params(z, 1.0)
    import dataclasses

    def accepting(real):                                   # a member accepting the roof
        def run(z_, cell, progress=None, **kw):
            res = real.run(z_, cell, progress=progress, **kw)
            res.mask[roof & (res.mask == OBJECT)] = GROUND
            return res
        return dataclasses.replace(real, run=run)

    fakes = {name: accepting(get_method(name)) for name in ("geodesic", "rascor")}
    monkeypatch.setattr(dtm_method, "get_method", lambda name: fakes.get(name) or get_method(name))
    assert (get_method("morphological").run(z, 1.0, **p["members"]["morphological"]).mask[roof] == OBJECT).mean() > 0.9
    res = dtm_method.filter_dtm(z, 1.0, **{k: v for k, v in p.items() if k != "input_description"})
    assert (res.mask[roof] == OBJECT).mean() > 0.95
    assert (res.mask[~roof] == GROUND).mean() > 0.99
    assert res.info["detached_level_share"] > 0.5 * roof.sum() / z.size


def test_dtm_keeps_a_trench_a_member_calls_a_low_outlier():
    """A quarry's floor one cell wide, 6 m below its benches: the opening calls it a low outlier, the others
    ground; a member's low outlier is no raised object, so its level (cut by the benches' walls from all
    undisputed ground) stays ground."""
    y, x = grid(200)
    r = np.abs(x - 100)
    z = noisy(100.0 - 6.0 * np.clip(np.floor((80 - r) / 20), 0, None), sd=0.05)
    res = pipeline.run_array("dtm", z, 1.0)
    assert (res.mask == GROUND).mean() > 0.995


# ----------------------------------------------------------------------------- through bareearth:dtm

@pytest.mark.parametrize("slope", [0.0, 0.02, 0.08])
def test_dtm_takes_a_warehouse_wider_than_every_window_as_an_object(slope):
    y, x = grid(300)
    ground = 50 + slope * x + slope / 2 * y                           # flat, gentle, sloping (5.1 degrees)
    wh = (np.abs(x - 150) < 75) & (np.abs(y - 150) < 75)          # 150 m x 150 m flat roof, walls 9 m high uphill
    z = noisy(np.where(wh, 50 + 1.5 * slope * 225 + 9.0, ground), sd=0.05)
    res = pipeline.run_array("dtm", z, 1.0)
    p = res.info["params"]
    assert p["region_width_m"] < 150 and p["region_max_cells"] >= 150
    assert (res.mask[wh] == OBJECT).all()
    assert (res.mask[~wh] == GROUND).mean() > 0.99
    assert np.sqrt(np.mean((res.dtm - ground)[wh] ** 2)) < 0.1          # the ground under it interpolated
    assert res.info["raised_region_cells"] > 0.9 * wh.sum()
    assert any(s.endswith(": object") for s in res.info["raised_regions"])


@pytest.mark.parametrize("kind", ["terrace", "plateau", "embankment", "hilltop", "hilltop30", "steep plateau"])
def test_dtm_keeps_raised_ground(kind):
    z = noisy(raised_ground(kind), sd=0.05)
    res = pipeline.run_array("dtm", z, 1.0)
    assert res.info["raised_region_cells"] == 0
    assert all(s.endswith(": ground") for s in res.info["raised_regions"])


@pytest.mark.parametrize("cell", [0.5, 1.0, 2.0])
def test_dtm_takes_a_tile_nearly_all_roof_as_an_object(cell):
    # as lidar/sample_c: a roof 25 m high over 90 % of an 80 m tile, cut by the tile's edges on every side
    # but one wall along a diagonal, with a ground wedge in the corner beyond it; by the wall a lower level
    # 15 m wide, 1-2 m below a gabled roof (every member takes it as ground: no window sees ground beyond it)
    n = int(80 / cell)
    y, x = grid(n)
    x, y = x * cell, y * cell
    ground = 30 + 0.01 * x
    d = (x + y) / np.sqrt(2)
    roof = d > 25
    z = noisy(np.where(roof, 55 + np.where(d < 40, 0.0, 2.0 - 0.05 * np.abs(d - 60)), ground), sd=0.05)
    res = pipeline.run_array("dtm", z, cell)
    assert (res.mask[roof] == OBJECT).all()
    assert (res.mask[~roof] == GROUND).all()
    assert np.sqrt(np.mean((res.dtm - ground)[roof] ** 2)) < 0.5         # the ground under it interpolated
    assert any(s.endswith(": object") for s in res.info["raised_regions"])


def test_dtm_halo_adds_the_stage_reach_to_the_members():
    """dtm's halo covers the members' reach and, beyond it, the stages' (each reads the one before):
    the continuation, the banks, the refinement, the raised regions and the confidence."""
    from bare_earth.core import dtm as dtm_method
    from bare_earth.core.methods import get_method
    y, x = grid(128)
    z = noisy(20 + 0.01 * x, sd=0.05)
    p = dtm_method.resolve_dtm_params(z, 1.0)
    width, span = dtm_method.region_scales(p["members"], 1.0)
    assert (p["region_width_m"], p["region_max_cells"]) == (width, span)
    windows = [p["members"][n][k] for n, k in dtm_method.MEMBER_WINDOWS.items()]
    assert width == sorted(windows)[-2] and span == int(np.ceil(2 * max(windows)))
    members = max(int(get_method(n).halo(p["members"][n], (1.0, 1.0))) for n in dtm_method.MEMBERS)
    cell = (1.0, 1.0)
    stages = (dr.continuation_cells(cell, p["refine_reach_m"]) + 2 + dr.refine_halo(cell, p["refine_reach_m"])
              + dr.banks_halo(*dtm_method.bank_scales(p["members"], p["region_width_m"], cell))
              + 2 * p["support_cells"] + 2)
    assert dtm_method.dtm_halo(p, 1.0) >= members + stages + regions_halo(span)
    assert dtm_method.dtm_halo(dict(p, region_max_cells=0), 1.0) < members + stages + regions_halo(span)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_scales_regions_merged_from_one_labelling_are_those_of_a_labelling_per_scale(seed):
    """The regions of every scale come from the first scale's labelling joined through the rims a higher
    scale frees (:class:`~bare_earth.core.dtm_regions._Scales`): the same cells, the same numbers (by
    first cell, as ``ndimage.label`` numbers them) and the same boxes as labelling each scale anew."""
    from scipy import ndimage

    from bare_earth.core.dtm_regions import _Scales
    rng = np.random.default_rng(seed)
    z = np.round(rng.random((60, 70)) * 3, 0).astype(np.float32) + ndimage.uniform_filter(
        rng.random((60, 70)).astype(np.float32) * 40, 9)
    ground = rng.random(z.shape) > 0.1
    drop = z - ndimage.minimum_filter(z, 3, mode="nearest")
    scales = _Scales(ground, drop, 0.5)
    seen = 0
    for s in (0.5, 1.0, 2.0, 4.0, 8.0):
        lab, boxes = scales.regions(s, lambda r0, r1, c0, c1: np.ones(r0.shape, bool))   # every region
        want, n = ndimage.label(ground & ~(drop > s), structure=np.ones((3, 3), bool))
        assert np.array_equal(lab, want) and boxes == ndimage.find_objects(want)
        assert scales.rims(s) == np.count_nonzero(ground & (drop > s))
        # a test on the boxes keeps some: those, renumbered 1, 2, ... in the same order, the others 0
        wide = np.array([b[1].stop - b[1].start >= 3 for b in boxes])
        lab, kept = scales.regions(s, lambda r0, r1, c0, c1: c1 - c0 >= 3)
        assert kept == [b for b, k in zip(boxes, wide) if k]
        renum = np.r_[0, np.cumsum(wide) * wide].astype(np.int32)
        assert np.array_equal(lab, renum[want])
        seen += n
    assert seen > 50


def _tile(cell, width_m=84.0, height_m=75.0):
    """Cell-centre coordinates (metres) of a ``width_m`` x ``height_m`` tile at ``cell`` metres."""
    y, x = np.mgrid[0:int(round(height_m / cell)), 0:int(round(width_m / cell))].astype(np.float32)
    return (y + 0.5) * cell, (x + 0.5) * cell


def _corner_cut(y, x):
    """Distance (metres, positive beyond it) from the line cutting off the tile's top left corner from
    (50, 0) to (0, 72): the far side covers 71 % of an 84 m x 75 m tile and meets all four of its sides."""
    return (x * 72.0 + y * 50.0 - 3600.0) / np.hypot(72.0, 50.0)


@pytest.mark.parametrize("cell", [0.5, 1.0, 2.0, 4.0])
@pytest.mark.parametrize("shape", ["corner", "diagonal"])
def test_dtm_takes_a_roof_over_most_of_a_tile_as_an_object_at_every_cell_size(cell, shape):
    # as lidar/sample_c (84 m x 75 m, a roof 25 m high over three quarters of it): a flat roof over about
    # 70 % of the tile, cut by its edges; ``corner``: walls on two sides, the tile's edges on the other two;
    # ``diagonal``: one straight wall cutting off the tile's top left corner, so the roof meets all four
    # sides (two opposite pairs) though its wall meets two adjacent ones. Before the wall's run decided the
    # reach (the region's own box mirrored at every side it meets: 3 x 84 m, beyond the stage's 240 m), the
    # diagonal roof was left to the vote at every cell size
    y, x = _tile(cell)
    ground = 30 + 0.01 * x
    roof = (x > 15) & (y > 12) if shape == "corner" else _corner_cut(y, x) > 0
    assert 0.65 < roof.mean() < 0.75
    z = noisy(np.where(roof, 50.0, ground), sd=0.05)
    res = pipeline.run_array("dtm", z, cell)
    inner = roof & ~ndimage.binary_dilation(~roof, iterations=1)          # the roof less its edge cells
    assert (res.mask[inner] == OBJECT).all()
    assert (res.mask[~roof] == GROUND).mean() > 0.99
    assert any(s.endswith(": object") for s in res.info["raised_regions"])


@pytest.mark.parametrize("cell", [0.5, 1.0, 2.0, 4.0])
def test_dtm_keeps_a_terrace_over_most_of_a_tile_joined_by_a_bank(cell):
    # the same level as the diagonal roof, 6 m high, joined to the lower ground by a bank of slope 1:2 (12 m
    # wide) along its whole edge: ground at every cell size
    y, x = _tile(cell)
    d = _corner_cut(y, x)
    z = noisy(30 + 0.01 * x + np.clip(d / 2.0, 0.0, 6.0), sd=0.05)
    res = pipeline.run_array("dtm", z, cell)
    assert np.count_nonzero(res.mask == OBJECT) == 0
    assert res.info["raised_region_cells"] == 0


@pytest.mark.parametrize("cell", [0.5, 1.0, 2.0])
@pytest.mark.parametrize("shape", ["straight", "round"])
def test_dtm_keeps_quarry_benches_cutting_off_a_corner(cell, shape):
    # a quarry in a corner of the raster (200 x 200 cells): benches 30 cells wide, 6 m apart, the floor in
    # the corner; the level around the pit meets all four sides and its wall cuts off the corner, as the
    # roof above, but the ground beyond that wall steps down again: ground at every cell size (with the
    # walls' run alone, 79 % (straight) and 71 % (round) of the cells were objects at 0.5 m)
    y, x = grid(200)
    r = (x + y) / np.sqrt(2) if shape == "straight" else np.hypot(x, y)
    top = 120 if shape == "straight" else 150
    z = noisy(100 - 6.0 * np.clip(np.floor((top - r) / 30), 0, None), sd=0.05)
    res = pipeline.run_array("dtm", z, cell)
    assert np.count_nonzero(res.mask == OBJECT) == 0


def _benched_slab(z, levels, edge, labels, terrain, jump_m, s, dx, dy, ids, rows):
    """dtm_regions._benched as pairs of shifted slices over the levels' rows and two around them (its definition
    before it gathered the judged levels' cells)."""
    import math

    from bare_earth.core.dtm_regions import _DIRECTIONS, _slices2
    h, w = z.shape
    out = np.zeros(terrain.shape, bool)
    e0, e1 = max(0, int(rows[0]) - 2), min(h, int(rows[1]) + 2)
    lab = labels[e0:e1]
    zz = z[e0:e1]
    on = levels[e0:e1] & terrain[lab]
    near = on.copy()
    ed = edge[e0:e1]
    mine = np.zeros(terrain.shape, bool)
    mine[ids] = True
    low = levels[e0:e1] & mine[lab]
    below = np.zeros(low.shape, bool)
    with np.errstate(invalid="ignore"):
        for dr_, dc in _DIRECTIONS:
            dst, src = _slices2(dr_, dc, e1 - e0, w)
            thr = np.float32(jump_m + s * math.hypot(dr_ * dy, dc * dx))
            near[dst] |= on[src] & ed[dst] & (zz[dst] - zz[src] <= thr)
        for dr_, dc in _DIRECTIONS:
            dst, src = _slices2(dr_, dc, e1 - e0, w)
            thr = np.float32(jump_m + s * math.hypot(dr_ * dy, dc * dx))
            below[dst] |= low[dst] & near[src] & (zz[src] - zz[dst] > thr)
    out[np.unique(lab[below])] = True
    out[0] = False
    return out


@pytest.mark.parametrize("seed", range(6))
def test_benched_levels_at_their_cells_equal_the_shifted_slices(seed):
    """_benched on the judged levels' cells and their neighbours, gathered: the same levels as the shifted slices
    over the rows they span (random terraced surfaces with NaN, levels at the raster's edges and corners, a
    slope allowance, every judged subset)."""
    from bare_earth.core import dtm_regions as reg
    rng = np.random.default_rng(seed)
    h, w = 23, 31
    z = (np.round(rng.random((h, w)) * 3) * 2.5 + rng.random((h, w)) * 0.3).astype(np.float32)
    z[rng.random((h, w)) < 0.05] = np.nan
    valid = np.isfinite(z)
    jump, s = 2.0, 0.2 * seed
    edge = reg._level_edges(z, valid, jump, s, 1.0, 1.5)
    ground = valid & (rng.random((h, w)) < 0.9)
    levels = ground & ~edge
    labels, n = ndimage.label(levels, structure=np.ones((3, 3), bool))
    assert n > 3
    boxes = ndimage.find_objects(labels)
    terrain = rng.random(n + 1) < 0.5
    terrain[0] = False
    seen = []
    for ids in (np.arange(1, n + 1), np.unique(rng.integers(1, n + 1, size=max(1, n // 3)))):
        rows = (min(boxes[i - 1][0].start for i in ids), max(boxes[i - 1][0].stop for i in ids))
        want = _benched_slab(z, levels, edge & ground, labels, terrain, jump, s, 1.0, 1.5, ids, rows)
        got = reg._benched(z, levels, edge & ground, labels, terrain, jump, s, 1.0, 1.5, ids,
                           [boxes[i - 1] for i in ids.tolist()])
        assert np.array_equal(got, want)
        seen.append(int(want.sum()))
    assert seen[0] > 0                                       # benched levels among them: the test sees some
