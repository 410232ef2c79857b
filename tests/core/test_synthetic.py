"""Tests of core.synthetic: scenes with known truth."""
import numpy as np
import pytest

from bare_earth.core.codes import GROUND, LOW, NODATA, OBJECT
from bare_earth.core.synthetic import KINDS, Scene, make_dsm, make_scene

SHAPE = (150, 170)


@pytest.fixture(scope="module")
def scenes():
    """Every kind once, with nodata holes (built once for the module)."""
    return {k: make_scene(k, SHAPE, seed=4, nodata_holes=True) for k in KINDS}


@pytest.mark.parametrize("kind", KINDS)
def test_shapes_dtypes_and_georeference(scenes, kind):
    s = scenes[kind]
    assert isinstance(s, Scene) and s.kind == kind
    assert s.dsm.shape == s.dtm.shape == s.mask.shape == SHAPE
    assert s.dsm.dtype == np.float32 and s.dtm.dtype == np.float32
    assert s.mask.dtype == np.uint8
    assert set(np.unique(s.mask)) <= {GROUND, OBJECT, LOW, NODATA}
    assert s.cell_size == (1.0, 1.0)
    assert s.epsg == 32632
    gt = s.geotransform
    assert len(gt) == 6 and gt[1] > 0 and gt[5] < 0 and gt[2] == gt[4] == 0
    assert np.isfinite(s.dtm).all()
    # cell <-> map round trip
    x, y = s.cell_to_map(np.array([0, 10]), np.array([0, 20]))
    r, c = s.map_to_cell(x, y)
    np.testing.assert_allclose(r, [0, 10], atol=1e-6)
    np.testing.assert_allclose(c, [0, 20], atol=1e-6)
    for o in s.objects:
        r0, c0, r1, c1 = o["bbox"]
        assert 0 <= r0 < r1 <= SHAPE[0] and 0 <= c0 < c1 <= SHAPE[1]
        assert o["height"] > 0


@pytest.mark.parametrize("kind", KINDS)
def test_truth_is_consistent(scenes, kind):
    s = scenes[kind]
    noise = 0.05
    m = s.mask
    # NaN exactly where the mask says nodata
    np.testing.assert_array_equal(np.isnan(s.dsm), m == NODATA)
    assert (m == NODATA).mean() > 0.01
    g = m == GROUND
    assert g.mean() > 0.3
    assert np.abs(s.dsm[g] - s.dtm[g]).max() <= 5 * noise
    # ground noise is really there and is about noise_m
    assert 0.8 * noise < np.std(s.dsm[g] - s.dtm[g]) < 1.2 * noise
    o = m == OBJECT
    assert (s.dsm[o] > s.dtm[o] + 1.0 - 5 * noise).all()
    low = m == LOW
    assert low.any()
    assert (s.dsm[low] < s.dtm[low]).all()
    assert (s.dsm[low] < s.dtm[low] - 2.0 + 5 * noise).all()


def test_kinds_have_their_objects(scenes):
    def count(k, what):
        return sum(o["kind"] == what for o in scenes[k].objects)
    for k in ("flat", "rolling", "mountain"):
        assert not scenes[k].objects and (scenes[k].mask == OBJECT).sum() == 0
    assert count("city", "building") >= 3 and count("city", "tree") > 0
    assert count("city", "car") > 0
    assert count("forest", "tree") > 50
    assert (scenes["forest"].mask == OBJECT).mean() > 0.2
    assert count("breakline", "dam") == 1 and count("breakline", "cut") == 1
    assert count("breakline", "building") == 1
    assert count("breakline", "tree") + count("breakline", "bush") > 0
    assert count("mixed", "building") > 0 and count("mixed", "tree") > 0
    assert count("mixed", "dam") == 1


def test_city_buildings_stand_high_with_roof_types():
    s = make_scene("city", (400, 400), seed=1, low_blunders=False)
    roofs = set()
    for o in s.objects:
        if o["kind"] != "building":
            continue
        roofs.add(o["roof"])
        assert 4.0 <= o["height"] <= 70.0
        r0, c0, r1, c1 = o["bbox"]
        sl = (slice(r0, r1), slice(c0, c1))
        obj = s.mask[sl] == OBJECT
        # the footprint (object cells of the bbox, few of them tree crowns) is >= 4 m high
        high = (s.dsm[sl] - s.dtm[sl])[obj] > 1.0 + 3.0
        assert obj.sum() > 0 and high.mean() > 0.9
        assert ((s.dsm[sl] - s.dtm[sl])[obj] > 1.0).all()
    assert roofs == {"flat", "gable", "hip"}
    heights = [o["height"] for o in s.objects if o["kind"] == "building"]
    assert max(heights) > 12


def test_mountain_is_steep():
    s = make_scene("mountain", (300, 300), seed=0)
    gy, gx = np.gradient(s.dtm.astype(np.float64), 1.0)
    slope = np.degrees(np.arctan(np.hypot(gx, gy)))
    assert 30 <= np.percentile(slope, 99) <= 36
    assert slope.max() < 50
    flat = make_scene("flat", (300, 300), seed=0)
    gy, gx = np.gradient(flat.dtm.astype(np.float64), 1.0)
    assert np.degrees(np.arctan(np.hypot(gx, gy))).max() < 3


def test_forest_crowns_are_5_to_30_m():
    s = make_scene("forest", (200, 200), seed=3, noise_m=0.0, low_blunders=False)
    trees = [o for o in s.objects if o["kind"] == "tree"]
    hs = np.array([o["height"] for o in trees])
    assert hs.min() >= 5.0 and hs.max() <= 30.0
    ndsm = s.dsm - s.dtm
    assert 20.0 < ndsm.max() <= 30.0 * 1.2


def test_reproducible_and_seed_dependent():
    a = make_scene("mixed", (120, 130), seed=7, nodata_holes=True)
    b = make_scene("mixed", (120, 130), seed=7, nodata_holes=True)
    c = make_scene("mixed", (120, 130), seed=8, nodata_holes=True)
    np.testing.assert_array_equal(a.dsm, b.dsm)
    np.testing.assert_array_equal(a.dtm, b.dtm)
    np.testing.assert_array_equal(a.mask, b.mask)
    assert len(a.objects) == len(b.objects)
    for p, q in zip(a.objects, b.objects):
        assert p.keys() == q.keys()
        assert all(np.array_equal(p[k], q[k]) for k in p)
    assert len(a.breaklines) == len(b.breaklines)
    for p, q in zip(a.breaklines, b.breaklines):
        np.testing.assert_array_equal(p, q)
    assert not np.array_equal(a.dtm, c.dtm)


def test_breakline_scene_dam_is_ground_and_stands_high():
    s = make_scene("breakline", (300, 320), seed=5, noise_m=0.0, low_blunders=False)
    assert len(s.breaklines) == 8   # dam: 2 crests, 2 toes; cut: 2 bottoms, 2 tops
    gt = s.geotransform
    x_min, x_max = gt[0], gt[0] + 320 * gt[1]
    y_max, y_min = gt[3], gt[3] + 300 * gt[5]
    for bl in s.breaklines:
        assert bl.ndim == 2 and bl.shape[1] == 2 and len(bl) >= 2 and np.isfinite(bl).all()
        assert (bl[:, 0] >= x_min - 1).all() and (bl[:, 0] <= x_max + 1).all()
        assert (bl[:, 1] >= y_min - 1).all() and (bl[:, 1] <= y_max + 1).all()
    dam = next(o for o in s.objects if o["kind"] == "dam")
    assert dam["ground"] and 5.0 <= dam["height"]
    assert 30.0 <= dam["side_slope_deg"] <= 40.0
    # crest centre line and its normal
    mid = dam["centreline"]
    t = np.gradient(mid, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    normal = np.column_stack([-t[:, 1], t[:, 0]])
    reach = dam["crest_width_m"] / 2 + dam["height"] / np.tan(np.radians(dam["side_slope_deg"]))
    rows, cols = s.map_to_cell(mid[:, 0], mid[:, 1])
    inside = (rows > 2) & (rows < 297) & (cols > 2) & (cols < 317)
    ri, ci = np.rint(rows[inside]).astype(int), np.rint(cols[inside]).astype(int)
    # the crest is ground (trees and bushes stand on the side slopes only)
    assert (s.mask[ri, ci] == GROUND).mean() > 0.95
    crest = s.dtm[ri, ci]
    sides = []
    for sign in (-1, 1):
        p = mid[inside] + sign * (reach + 8.0) * normal[inside]
        r, c = s.map_to_cell(p[:, 0], p[:, 1])
        ok = (r >= 0) & (r <= 299) & (c >= 0) & (c <= 319)
        v = np.full(r.shape, -np.inf)
        v[ok] = s.dtm[np.rint(r[ok]).astype(int), np.rint(c[ok]).astype(int)]
        sides.append(v)
    surround = np.maximum(*sides)
    ok = np.isfinite(surround)
    assert ok.sum() > 50
    assert np.median(crest[ok] - surround[ok]) >= 5.0
    assert (crest[ok] - surround[ok]).min() >= 5.0
    # the cut is lower than its surroundings, and also ground
    cut = next(o for o in s.objects if o["kind"] == "cut")
    assert cut["ground"] and cut["height"] >= 4.0


def test_options_cell_size_and_no_extras():
    s = make_scene("city", (100, 120), cell_size=(2.5, 2.0), seed=2, noise_m=0.0,
                   low_blunders=False, nodata_holes=False)
    assert s.cell_size == (2.5, 2.0)
    assert s.geotransform[1] == 2.5 and s.geotransform[5] == -2.0
    assert not (s.mask == LOW).any() and not (s.mask == NODATA).any()
    assert np.isfinite(s.dsm).all()
    g = s.mask == GROUND
    np.testing.assert_array_equal(s.dsm[g], s.dtm[g])          # no noise
    assert not any(o["kind"] == "car" for o in s.objects)      # cars < one 2.5 m cell


def test_make_dsm():
    s = make_dsm(40_000, seed=3)
    assert s.dsm.shape == (200, 200) and s.kind == "city"
    assert (s.mask == OBJECT).any()
    assert make_dsm(1).dsm.shape == (16, 16)  # tiny requests still give a scene


def test_small_city_still_has_a_building():
    s = make_scene("city", (40, 40), seed=3, low_blunders=False)
    assert any(o["kind"] == "building" for o in s.objects)


def test_errors():
    with pytest.raises(ValueError, match="unknown scene kind"):
        make_scene("moon")
    with pytest.raises(ValueError, match="too small"):
        make_scene("flat", (8, 100))
    with pytest.raises(ValueError, match="cell_size"):
        make_scene("flat", (32, 32), cell_size=-1)
    with pytest.raises(ValueError, match="noise_m"):
        make_scene("flat", (32, 32), noise_m=-0.1)
    with pytest.raises(ValueError, match="n_cells"):
        make_dsm(0)


@pytest.mark.parametrize("seed", [0, 1, 5])
def test_truth_over_seeds_shapes_and_cell_sizes(seed):
    shape, cell = [((100, 300), 1.0), ((120, 90), 0.5), ((80, 96), (2.0, 1.5))][seed % 3]
    noise = 0.1
    for kind in KINDS:
        s = make_scene(kind, shape, cell_size=cell, seed=seed, noise_m=noise,
                       nodata_holes=bool(seed % 2))
        m = s.mask
        assert np.array_equal(np.isnan(s.dsm), m == NODATA), kind
        g, o, low = m == GROUND, m == OBJECT, m == LOW
        assert np.abs(s.dsm[g] - s.dtm[g]).max() <= 5 * noise, kind
        assert (s.dsm[o] > s.dtm[o] + 1.0 - 5 * noise).all(), kind
        assert (s.dsm[low] < s.dtm[low]).all(), kind


# --------------------------------------------------------------------------- lidar points
from bare_earth.core.synthetic import LIDAR_KINDS, make_lidar_points  # noqa: E402


@pytest.fixture(scope="module")
def clouds():
    """Each kind once: 200 m square, 6 pulses per m2, no noise points."""
    return {k: make_lidar_points(k, extent_m=200.0, density_per_m2=6.0, seed=3, noise_rate=0.0)
            for k in LIDAR_KINDS}


def _pulses(p):
    """Pulse index of every point (points are stored pulse by pulse, top down)."""
    return np.cumsum(p.return_number == 1) - 1


def test_lidar_points_arrays_classes_and_density(clouds):
    for p in clouds.values():
        n = len(p)
        for a in (p.x, p.y, p.z):
            assert a.dtype == np.float64 and a.shape == (n,) and np.isfinite(a).all()
        x0, y0, x1, y1 = p.extent
        assert x1 - x0 == y1 - y0 == 200.0
        assert (p.x >= x0).all() and (p.x < x1).all() and (p.y >= y0).all() and (p.y < y1).all()
        assert set(np.unique(p.classification)) <= {2, 3, 4, 5, 6}
        # first returns: the requested pulse density; later returns add points
        first = np.count_nonzero(p.return_number == 1) / 200.0 ** 2
        assert first == pytest.approx(6.0, rel=0.03)
        assert n / 200.0 ** 2 > first
        # returns of a pulse numbered 1..n, top down
        assert (p.return_number >= 1).all() and (p.return_number <= p.number_of_returns).all()
        pid = _pulses(p)
        last = np.r_[pid[1:] != pid[:-1], True]
        np.testing.assert_array_equal(p.return_number[last], p.number_of_returns[last])
        later = p.return_number > 1
        assert (p.z[later] < p.z[np.nonzero(later)[0] - 1]).all()
        # strips: overlapping flight lines make the density vary
        assert np.unique(p.point_source_id).size >= 2
        cell = ((p.y - y0) // 10).astype(int) * 20 + ((p.x - x0) // 10).astype(int)
        fr = np.bincount(cell[p.return_number == 1], minlength=400)
        assert fr.std() / fr.mean() > 0.05
    share = {k: {c: np.mean(p.classification == c) for c in (2, 3, 4, 5, 6)} for k, p in clouds.items()}
    assert share["forest"][6] == 0 and share["forest"][5] > 0.4 and 0.15 < share["forest"][2] < 0.5
    assert share["urban"][6] > 0.2 and share["urban"][2] > 0.3
    assert share["mixed"][6] > 0.05 and share["mixed"][5] > 0.1 and share["mixed"][2] > 0.2
    for k in LIDAR_KINDS:
        assert share[k][3] > 0                              # shrubs and low crowns


def test_lidar_points_lie_on_their_surfaces(clouds):
    for p in clouds.values():
        hag = p.z - p.terrain(p.x, p.y)
        g = p.classification == 2
        assert np.abs(hag[g]).max() <= 4.5 * 0.03 + 1e-9       # range noise only
        assert 0.02 < hag[g].std() < 0.04
        assert (hag[p.classification == 6] > 4.0 - 0.2).all()  # eaves at least 4 m above the ground
        v = np.isin(p.classification, (3, 4, 5))
        assert (hag[p.classification == 5] >= 5.0 - 0.14).all()
        assert (hag[p.classification == 4] >= 2.0 - 0.14).all() and (hag[p.classification == 4] < 5.0 + 0.14).all()
        assert (hag[p.classification == 3] < 2.0 + 0.14).all()
        assert hag[v].max() <= 35.0 + 8.0 * np.tan(np.radians(40.0))   # a crown's edge over lower ground


def test_lidar_terrain_steep_bank_and_large_building(clouds):
    f = clouds["forest"]
    x0, y0, _, _ = f.extent
    xx, yy = np.meshgrid(x0 + np.arange(0, 200, 1.0), y0 + np.arange(0, 200, 1.0))
    z = f.terrain(xx, yy)
    gy, gx = np.gradient(z, 1.0)
    slope = np.degrees(np.arctan(np.hypot(gx, gy)))
    assert np.mean(slope > 20.0) > 0.05 and np.percentile(slope, 99) > 30.0
    assert 34.0 <= f.objects["max_slope_deg"] <= 40.0 and 2.5 <= f.objects["bank"] <= 5.0
    assert clouds["mixed"].objects["cutting"] >= 3.0
    for k in ("urban", "mixed"):
        assert clouds[k].objects["largest_building_m"] > 60.0 and clouds[k].objects["buildings"] >= 5


def test_lidar_penetration_depends_on_crown_density():
    """Pulses whose first return is a crown reach the ground less often than pulses in the
    open, and less often still under denser crowns; at 4 m some cells of a dense forest hold
    no ground return at all."""
    share, empty = {}, {}
    for cd in (1.0, 3.0):
        p = make_lidar_points("forest", extent_m=150.0, density_per_m2=8.0, seed=5, crown_density=cd,
                              noise_rate=0.0)
        pid = _pulses(p)
        first_cls = p.classification[p.return_number == 1][pid]
        last = np.r_[pid[1:] != pid[:-1], True]
        crown = first_cls[last] == 5
        ground = p.classification[last] == 2
        share[cd] = (ground[crown].mean(), ground[~crown & (first_cls[last] == 2)].mean())
        g = p.classification == 2
        ix = ((p.x[g] - p.extent[0]) // 4).astype(int)
        iy = ((p.y[g] - p.extent[1]) // 4).astype(int)
        has = np.zeros((38, 38), bool)
        has[iy, ix] = True
        empty[cd] = 1.0 - has[:37, :37].mean()
    assert share[1.0][1] == 1.0                                  # open ground: every pulse
    assert 0.05 < share[1.0][0] < 0.7
    assert share[3.0][0] < 0.7 * share[1.0][0]
    assert 0.0 < empty[1.0] < empty[3.0] < 0.5


def test_lidar_points_deterministic_and_noise():
    a = make_lidar_points("urban", extent_m=150.0, density_per_m2=2.0, seed=7, noise_rate=1e-3)
    b = make_lidar_points("urban", extent_m=150.0, density_per_m2=2.0, seed=7, noise_rate=1e-3)
    c = make_lidar_points("urban", extent_m=150.0, density_per_m2=2.0, seed=8, noise_rate=1e-3)
    for f in ("x", "y", "z", "classification", "return_number", "number_of_returns", "point_source_id"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
    assert len(a) != len(c) or not np.array_equal(a.z, c.z)
    hag = a.z - a.terrain(a.x, a.y)
    assert (hag[a.classification == 7] < -2.9).all() and (a.classification == 7).sum() > 0
    assert (hag[a.classification == 18] > 49.0).all() and (a.classification == 18).sum() > 0
    cloud = a.to_cloud()
    assert len(cloud) == len(a) and cloud.units_to_metre == 1.0
    np.testing.assert_array_equal(cloud.classification, a.classification)


def test_lidar_points_errors():
    with pytest.raises(ValueError, match="kind"):
        make_lidar_points("desert")
    with pytest.raises(ValueError, match="extent_m"):
        make_lidar_points("urban", extent_m=100.0)
    with pytest.raises(ValueError, match="density"):
        make_lidar_points("forest", density_per_m2=0.0)
    with pytest.raises(ValueError, match="crown_density"):
        make_lidar_points("forest", crown_density=-1.0)


def test_lidar_gentle_terrain_without_hillside():
    p = make_lidar_points("forest", extent_m=150.0, density_per_m2=1.0, seed=3, steep=False)
    assert "bank" not in p.objects and p.objects["max_slope_deg"] == 0.0
    xx, yy = np.meshgrid(p.extent[0] + np.arange(0, 150, 1.0), p.extent[1] + np.arange(0, 150, 1.0))
    gy, gx = np.gradient(p.terrain(xx, yy), 1.0)
    assert np.percentile(np.degrees(np.arctan(np.hypot(gx, gy))), 99) < 15.0


def test_lidar_understory_hides_the_ground():
    """More shrubs: more low-vegetation points and more 2 m cells without a ground return."""
    out = {}
    for us in (0.0, 10.0):
        p = make_lidar_points("forest", extent_m=100.0, density_per_m2=5.0, seed=2, understory=us, noise_rate=0.0,
                              steep=False)
        g = p.classification == 2
        has = np.zeros((50, 50), bool)
        has[((p.y[g] - p.extent[1]) // 2).astype(int), ((p.x[g] - p.extent[0]) // 2).astype(int)] = True
        out[us] = (np.mean(p.classification == 3), 1.0 - has.mean(), p.objects["shrubs"])
    assert out[0.0][2] == 0 and out[10.0][2] > 1000
    assert out[10.0][0] > 3 * out[0.0][0] and out[10.0][1] > out[0.0][1] + 0.05
    with pytest.raises(ValueError, match="understory"):
        make_lidar_points("forest", understory=-1.0)
