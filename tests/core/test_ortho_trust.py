"""Issue 16: a dh that is right or absent, honest iterations, refusal on weak data.

Synthetic stereo from the paper's geometry (Luong Chinh Ke 2002, section 2.3: dh = dx H / B;
Norvelle 1995: iterative orthophoto refinement), rendered by ray casting
(:mod:`core.orthophoto.render`) with image noise (grey levels), weak texture (contrast), three
frames and rotated frames. 0.5 m cells, 19 flat-roofed buildings 3-14 m high. The seeds here
are held out: none was used while the defaults were set.
"""
import numpy as np
import pytest
from scipy import ndimage

from bare_earth.core.codes import NODATA, OBJECT
from bare_earth.core.orthophoto import (
    make_ortho_scene,
    match_along,
    orthoparallax,
    orthorectify,
    orthorefine,
    render_frames,
    vertical_cameras,
)
from bare_earth.core.orthophoto.match import REASONS
from bare_earth.core.orthophoto.quality import (
    agree_at_height,
    agreement_bound,
    close_mask,
    ground_trend,
    merge_pairs,
    nan_median_at,
    nan_median_filter,
    object_mask,
    remove_blunders,
    settle_boundary,
)
from bare_earth.core.orthophoto.render import imaged_in_both


def _scene(seed, contrast=0.3125):
    sc = make_ortho_scene(shape=(160, 200), cell_size=0.5, n_buildings=19, seed=seed, contrast=contrast,
                          building_width_cells=(8, 20), building_height_m=(3.0, 14.0))
    assert len(sc.heights) == 19
    return sc


def _buildings_within(sc, dh, valid):
    """Buildings whose median dh is within 10 % or 0.5 m of the truth."""
    true_dh = sc.surface - sc.terrain
    good = 0
    for k in sc.heights:
        m = (sc.labels == k) & valid
        est, tru = float(np.nanmedian(dh[m])), float(np.median(true_dh[m]))
        good += abs(est - tru) <= max(0.1 * tru, 0.5)
    return good


def _far_ground(sc, valid, metres=3.0):
    return ~ndimage.binary_dilation(sc.labels > 0, iterations=int(np.ceil(metres / sc.cell_size))) & valid


# --------------------------------------------------------------------------- exact pieces
def test_nan_median_filter_exact():
    x = np.array([[1, 2, np.nan], [4, 100, 6], [np.nan, 8, 9]], np.float32)
    med, cnt = nan_median_filter(x, 3)
    assert cnt.tolist() == [[4, 5, 3], [5, 7, 5], [3, 5, 4]]
    assert med[1, 1] == np.median([1, 2, 4, 100, 6, 8, 9]) == 6
    assert med[0, 0] == 4                              # [1, 2, 4, 100]: the upper middle value
    med, cnt, sup = nan_median_filter(x, 3, tolerance=2.0)
    assert sup[1, 1] == 0 and sup[0, 0] == 1          # 100 agrees with none; 1 with 2
    with pytest.raises(ValueError, match="odd"):
        nan_median_filter(x, 4)


@pytest.mark.parametrize("size", [3, 5, 7])
def test_nan_median_filter_equals_the_sorted_window(size):
    """The selection network gives the upper middle of the sorted finite values, with ties."""
    rng = np.random.default_rng(size)
    x = np.round(rng.normal(size=(23, 17)) * 2).astype(np.float32)     # many ties
    x[rng.random(x.shape) < 0.35] = np.nan
    x[:6, :6] = np.nan                                                  # windows with no value
    med, cnt = nan_median_filter(x, size)
    h = size // 2
    pad = np.pad(x, h, constant_values=np.nan)
    for r in range(x.shape[0]):
        for c in range(x.shape[1]):
            w = pad[r:r + size, c:c + size]
            v = np.sort(w[np.isfinite(w)])
            assert cnt[r, c] == v.size
            assert (np.isnan(med[r, c]) if v.size == 0 else med[r, c] == v[v.size // 2])
    cells = np.nonzero(rng.random(x.shape) < 0.3)
    np.testing.assert_array_equal(nan_median_at(x, cells, size), med[cells])


def test_remove_blunders_drops_spikes_keeps_roof_corners():
    dem = np.zeros((20, 20), np.float32)
    dh = np.zeros((20, 20), np.float32)
    dh[5:12, 5:12] = 8.0                               # a roof: its corner has 8 roof neighbours in 5 x 5
    dh[16, 16] = 30.0                                  # a spike on the ground
    dh[2, 17] = np.nan
    out, dropped = remove_blunders(dh, dem, tolerance_m=1.0)
    assert dropped == 1 and np.isnan(out[16, 16])
    np.testing.assert_array_equal(out[5:12, 5:12], 8.0)  # corners included
    lone = np.full((9, 9), np.nan, np.float32)
    lone[4, 4] = 3.0                                   # no neighbour: no support
    assert np.isnan(remove_blunders(lone, np.zeros_like(lone), 1.0)[0][4, 4])


def test_merge_pairs_drops_the_odd_pair():
    d = [np.array([[1.0, 1.0]], np.float32), np.array([[1.2, 9.0]], np.float32),
         np.array([[0.9, np.nan]], np.float32)]
    c = [np.ones((1, 2), np.float32)] * 3
    dh, _ = merge_pairs(d, c, outlier_m=1.0)
    assert dh[0, 0] == pytest.approx((1.0 + 1.2 + 0.9) / 3, rel=1e-6)
    assert np.isnan(dh[0, 1])                          # two pairs disagreeing by 8 m: neither trusted


def test_ground_trend_is_unbiased_and_threshold_consistent():
    """Noisy dh on open ground with a smooth offset and objects: the trend follows the ground
    (an opening of noisy dh lies about two sd below it) and the false alarms stay near the
    Gaussian share above 3 sd."""
    rng = np.random.default_rng(3)
    rows, cols = 200, 240
    yy, xx = np.mgrid[0:rows, 0:cols]
    smooth = (1.5 + 0.01 * xx).astype(np.float32)
    dh = smooth + rng.normal(0, 0.3, (rows, cols)).astype(np.float32)
    obj = np.zeros((rows, cols), bool)
    for r0, c0 in ((20, 30), (90, 150), (140, 40), (60, 90)):
        obj[r0:r0 + 25, c0:c0 + 30] = True
    dh[obj] += 6.0
    valid = np.ones((rows, cols), bool)
    trend, thr, sig = ground_trend(dh, valid, 80, 0.1)
    assert abs(float(np.median((trend - smooth)[~obj]))) < 0.05
    assert sig == pytest.approx(0.3, rel=0.1) and thr == pytest.approx(3 * sig)
    mask, _, _ = object_mask(dh, valid, 0.1, None, 80)
    far = ~ndimage.binary_dilation(obj, iterations=3)
    assert (mask[far] == OBJECT).mean() < 0.01
    assert (mask[obj] == OBJECT).mean() > 0.99
    mask0, thr0, _ = object_mask(dh, valid, 0.1, 2.5, 0)          # a given threshold, trend 0
    assert thr0 == 2.5
    np.testing.assert_array_equal(mask0 == OBJECT, dh > 2.5)


def test_matcher_decides_weak_texture_and_keeps_textured():
    rng = np.random.default_rng(4)
    tex = ndimage.gaussian_filter(rng.normal(size=(80, 120)), 1.2)
    tex = (tex / tex.std()).astype(np.float32)
    a = 128 + 30 * tex
    a[:, 60:] = 128 + 0.3 * tex[:, 60:]                # right half: almost no texture
    b = np.roll(a, 2, axis=1)
    a = a + rng.normal(0, 2, a.shape).astype(np.float32)
    b = b + rng.normal(0, 2, b.shape).astype(np.float32)
    m = match_along(a, b, (1, 0), 5, window=7)
    left, right = (slice(10, -10), slice(10, 50)), (slice(10, -10), slice(70, 110))
    assert m.valid[left].mean() > 0.95 and np.nanmedian(np.abs(m.disparity[left] - 2)) < 0.05
    assert m.valid[right].mean() < 0.05
    assert set(np.unique(m.reason[right])) <= {1, 2, 3, 4, 5}
    assert m.info["noise_grey"] == pytest.approx(2.0, rel=0.25)
    assert set(m.info["shares"]) == set(REASONS.values())
    assert np.all(m.precision[left][m.valid[left]] <= 0.2)


def test_close_mask_fills_gaps_narrower_than_half_the_window():
    m = np.zeros((20, 30), np.uint8)
    m[5:15, 3:10] = OBJECT
    m[5:15, 13:20] = OBJECT                               # a 3-cell gap: closed by 4 x 4 (window 7)
    m[5:15, 25:29] = OBJECT                               # a 5-cell gap: two objects stay apart
    m[9, 5] = 0                                           # a hole in a roof
    m[0, :] = NODATA
    out = close_mask(m, 7)
    assert (out[5:15, 3:20] == OBJECT).all()
    assert (out[5:15, 20:25] == 0).all()
    assert (out[0] == NODATA).all() and (out[15:] == 0).all()
    np.testing.assert_array_equal(close_mask(m, 1), m)     # window 1 resolves every gap


def test_settle_boundary_moves_a_wandering_outline_back():
    """A roof seen 2 cells to the west in a and 2 to the east in b (dh = 2 with these
    displacements): an outline that wandered 2 cells inward on one side and one cell outward
    on another is decided by testing both heights on the images."""
    rng = np.random.default_rng(5)
    n = 48
    tex = ndimage.gaussian_filter(rng.normal(size=(n, n)), 1.0)
    tex = (128 + 40 * tex / tex.std()).astype(np.float32)
    truth = np.zeros((n, n), bool)
    truth[12:34, 14:36] = True
    a, b = tex.copy(), tex.copy()
    rr, cc = np.nonzero(truth)
    a[rr, cc - 2] = tex[rr, cc]
    b[rr, cc + 2] = tex[rr, cc]
    a += rng.normal(0, 2, a.shape).astype(np.float32)
    b += rng.normal(0, 2, b.shape).astype(np.float32)
    mask = truth.copy()
    mask[12:34, 14:16] = False                            # the west outline wandered 2 cells in
    mask[11, 14:36] = True                                # the north one a cell out
    dh = np.where(mask, 2.0, 0.0).astype(np.float32)
    new = settle_boundary(a, b, mask, dh, np.zeros((n, n), np.float32), np.ones((n, n), bool),
                          lambda h: (-h, 0 * h, h, 0 * h), 3)
    assert new[truth].all()                               # every roof cell, the west edge back
    assert not new[11, 14:36].any()                       # the north row is ground again
    assert (new != truth).sum() < 0.6 * (mask != truth).sum()
    # heights less than a cell apart in parallax cannot be told apart: nothing changes
    low = settle_boundary(a, b, mask, np.where(mask, 0.4, 0.0).astype(np.float32), np.zeros((n, n), np.float32),
                          np.ones((n, n), bool), lambda h: (-h, 0 * h, h, 0 * h), 3)
    np.testing.assert_array_equal(low, mask)


# --------------------------------------------------------------------------- rendered scenes
@pytest.fixture(scope="module")
def noisy_pair():
    sc = _scene(21)
    cams = vertical_cameras(sc, 2, base_over_height=0.45)
    imgs = render_frames(sc, cams, noise=6.0, seed=21, dz_m=0.5)
    orthos = [orthorectify(im, c, sc.terrain, sc.transform)[0] for im, c in zip(imgs, cams)]
    return sc, cams, orthos


def test_noise_6dn_false_alarms_and_recall(noisy_pair):
    """6 DN image noise: object false alarms on ground more than 3 m from objects <= 3 % (was
    19.7 %: an opening of noisy dh as the trend, biased low), recall >= 95 % (94.2 % before the
    outline was decided on the orthophotos)."""
    sc, cams, (oa, ob) = noisy_pair
    r = orthoparallax(oa, ob, sc.terrain, sc.transform, centres=(cams[0].centre, cams[1].centre))
    seen = r.mask != NODATA
    far = _far_ground(sc, seen)
    fa = float((r.mask[far] == OBJECT).mean())
    # recall on the roofs whose image lies on the grid in both orthophotos (near the grid's edge
    # a roof's image in one of them can lie off the grid: nothing measures it)
    roofs = (sc.labels > 0) & seen & imaged_in_both(sc, cams, (oa, ob))
    recall = float((r.mask[roofs] == OBJECT).mean())
    # measured: false alarms 0.9 %, recall 97.5 % (94.2 % of all roofs seen); main 1.4 %, 97.7 %
    # (96.1 %); without deciding the outline on the orthophotos about 2 % less: the outermost roof cells
    assert fa <= 0.03 and recall >= 0.95, (fa, recall)
    plain = orthoparallax(oa, ob, sc.terrain, sc.transform, centres=(cams[0].centre, cams[1].centre),
                          settle=False)
    assert float((plain.mask[roofs] == OBJECT).mean()) < recall
    ring = ndimage.binary_dilation(sc.labels > 0, iterations=2) & (sc.labels == 0) & seen
    assert (r.mask[ring] == OBJECT).mean() < (plain.mask[ring] == OBJECT).mean()   # less fattening
    assert r.info["outline_to_object"] > 0 and r.info["outline_to_ground"] > 0     # logged, both ways
    # the share of far-ground cells truly above the threshold in the measured dh
    truly = float(np.mean(r.dh[far & np.isfinite(r.dh)] > r.info["height_threshold_m"]))
    assert fa <= truly + 0.02, (fa, truly)
    assert _buildings_within(sc, r.dh, seen) >= 18
    assert r.info["warning"] == "" and r.info["direction_xy"] == pytest.approx((1.0, 0.0), abs=1e-9)


def test_base_and_height_mode_places_corrections_like_centres(noisy_pair):
    """BASE_M/HEIGHT_M: corrections moved to their ground point as with the camera centres."""
    sc, cams, (oa, ob) = noisy_pair
    rc = orthoparallax(oa, ob, sc.terrain, sc.transform, centres=(cams[0].centre, cams[1].centre))
    B = float(cams[1].centre[0] - cams[0].centre[0])
    H = float(cams[0].centre[2] - np.mean(sc.terrain))
    rb = orthoparallax(oa, ob, sc.terrain, sc.transform, base_m=B, height_m=H)
    obj = sc.labels > 0
    ev = (rc.mask != NODATA) & (rb.mask != NODATA)
    e_c = np.sqrt(np.mean((rc.dem - sc.surface)[ev & obj] ** 2))
    e_b = np.sqrt(np.mean((rb.dem - sc.surface)[ev & obj] ** 2))
    assert e_b < 1.25 * e_c + 0.1, (e_b, e_c)
    # without relocation the edges shift: clearly worse
    rn = orthoparallax(oa, ob, sc.terrain, sc.transform, base_m=B, height_m=H, relocate=False)
    e_n = np.sqrt(np.mean((rn.dem - sc.surface)[ev & obj] ** 2))
    assert e_n > 1.2 * e_b, (e_n, e_b)


@pytest.fixture(scope="module")
def clean_three():
    sc = _scene(22)
    cams = vertical_cameras(sc, 3, base_over_height=0.3)
    imgs = render_frames(sc, cams, noise=1.0, seed=22, dz_m=0.5)
    one = orthorefine(sc.terrain, sc.transform, imgs, cams, max_iterations=1)
    return sc, cams, imgs, one


def test_one_iteration_gives_full_heights(clean_three):
    """No hidden damping: one iteration on a clean scene puts >= 90 % of the buildings within
    10 % / 0.5 m (was 0.69-0.71 of every height with the old 0.7 relaxation)."""
    sc, cams, imgs, r = clean_three
    seen = r.mask != NODATA
    assert _buildings_within(sc, r.dh, seen) >= 0.9 * 19
    assert r.info["relaxation"] == 1.0 and r.info["iterations"] == 1 and r.info["mask_closed_cells"] >= 0
    assert [row["status"] for row in r.table] == ["applied", "measured"]
    assert r.table[1]["agreement"] < 0.5                  # the update made the pairs agree
    with pytest.raises(ValueError, match="relaxation"):
        orthorefine(sc.terrain, sc.transform, imgs, cams, relaxation=0.0)


def test_iterations_never_make_it_worse_and_edges_stay_bounded(clean_three):
    """Every kept update lowers the pairs' residual parallax; the RMSE against the truth never
    rises from one kept update to the next; building edges do not fatten with iterations;
    RELAXATION scales the first step."""
    sc, cams, imgs, one = clean_three
    half = orthorefine(sc.terrain, sc.transform, imgs, cams, max_iterations=1, relaxation=0.5)
    ratio = np.nanmedian(half.dh[sc.labels > 0]) / np.nanmedian(one.dh[sc.labels > 0])
    assert ratio == pytest.approx(0.5, abs=0.05)          # one half step
    r = orthorefine(sc.terrain, sc.transform, imgs, cams, max_iterations=3, reference=sc.surface)
    t = r.table
    assert r.info["stop"] and t[0]["status"] == "applied"
    for k, row in enumerate(t[:-1]):
        if row["status"] == "applied":
            assert t[k + 1]["agreement"] < 1 or t[k + 1]["status"] == "undone"
    kept = [row["rmse_reference_m"] for row in t if row["status"] == "applied"]
    assert all(b <= a + 0.05 for a, b in zip(kept, kept[1:])), kept
    seen = (r.mask != NODATA) & (one.mask != NODATA)
    obj = sc.labels > 0
    ring = ndimage.binary_dilation(obj, iterations=6) & ~obj & seen       # ground within 3 m
    e_many = np.sqrt(np.mean((r.dem - sc.surface)[ring] ** 2))
    e_one = np.sqrt(np.mean((one.dem - sc.surface)[ring] ** 2))
    assert e_many <= 1.1 * e_one + 0.05, (e_many, e_one, [(row["status"], row["agreement"]) for row in t], ratio)
    assert e_one < 4.0                                    # measured 3.0 m (edges blur by about a cell)


def test_weak_texture_and_noise_refuses_and_says_why():
    """Contrast 0.03 + 6 DN: the DEM is never worse; either most buildings are right, or the
    result says in plain words that it could not refine and why."""
    sc = _scene(23, contrast=0.03)
    cams = vertical_cameras(sc, 3, base_over_height=0.3)
    imgs = render_frames(sc, cams, noise=6.0, seed=23, dz_m=0.5)
    r = orthorefine(sc.terrain, sc.transform, imgs, cams, max_iterations=3)
    seen = r.mask != NODATA
    e0 = np.sqrt(np.mean((sc.terrain - sc.surface)[seen] ** 2))
    e1 = np.sqrt(np.mean((r.dem - sc.surface)[seen] ** 2))
    assert e1 <= e0 + 1e-6, (e0, e1)
    good = _buildings_within(sc, r.dh, seen)
    if good < 15:
        assert "could be matched with confidence" in r.info["warning"]
        assert "texture" in r.info["warning"] and r.info["stop"].startswith("refused")
        np.testing.assert_array_equal(r.dem, sc.terrain)


def test_rotated_frames_diagonal_base():
    """Frames rotated by kappa 30 degrees along a diagonal base: heights still recovered."""
    sc = make_ortho_scene(shape=(120, 120), cell_size=0.5, n_buildings=6, seed=24,
                          building_width_cells=(10, 18), building_height_m=(3.0, 10.0))
    cams = vertical_cameras(sc, 2, base_over_height=0.45, direction=(1.0, 1.0), kappa_deg=30.0)
    imgs = render_frames(sc, cams, noise=2.0, seed=24, dz_m=0.5)
    oa, ob = (orthorectify(im, c, sc.terrain, sc.transform)[0] for im, c in zip(imgs, cams))
    r = orthoparallax(oa, ob, sc.terrain, sc.transform, centres=(cams[0].centre, cams[1].centre))
    assert _buildings_within(sc, r.dh, r.mask != NODATA) >= len(sc.heights) - 1
    e = np.asarray(r.info["direction_xy"])
    assert e == pytest.approx(np.array([1.0, 1.0]) / np.sqrt(2), abs=0.02)


def _remove_blunders_full_median(dh, dem, tolerance_m, size=5):
    # the former form: the median filter over the whole grid
    dh = np.asarray(dh, np.float32)
    z = np.where(np.isfinite(dh) & np.isfinite(dem), dem + dh, np.nan).astype(np.float32)
    med, cnt, sup = nan_median_filter(z, size, tolerance=float(tolerance_m))
    ok = np.isfinite(z)
    cluster = (size // 2 + 1) ** 2 - 1
    with np.errstate(invalid="ignore"):
        bad = ok & (((np.abs(z - med) > tolerance_m) & (sup < cluster)) | (cnt - 1 < size // 2 + 1))
    return np.where(bad, np.nan, dh).astype(np.float32), int(np.count_nonzero(bad))


@pytest.mark.parametrize("size", [3, 5, 7])
def test_remove_blunders_equals_full_median_form(size):
    rng = np.random.default_rng(size)
    dem = (50 + np.cumsum(rng.normal(0, 0.3, (90, 70)), axis=1)).astype(np.float32)
    dh = rng.normal(0, 0.4, dem.shape).astype(np.float32)
    dh[20:40, 10:30] += 8.0                                   # an object
    dh[rng.random(dem.shape) < 0.05] += rng.normal(0, 6, 1)   # spikes
    dh[rng.random(dem.shape) < 0.3] = np.nan                   # gaps
    dem[5, 5] = np.nan
    for tol in (0.3, 1.0):
        got, n = remove_blunders(dh, dem, tol, size)
        want, m = _remove_blunders_full_median(dh, dem, tol, size)
        np.testing.assert_array_equal(got, want)
        assert n == m and n > 0


def test_agreement_bound_is_the_chi_square_quantile_over_the_window():
    # 3 x 3 window: 8 degrees of freedom; chi2.isf(1.35e-3, 8) = 25.361, / 9 cells
    assert agreement_bound(1.0, 1) == pytest.approx(25.361 / 9, rel=1e-4)
    # scales with the noise variance; a wider window's bound tends to the variance itself
    assert agreement_bound(4.0, 1) == pytest.approx(4 * agreement_bound(1.0, 1))
    assert 1.0 < agreement_bound(1.0, 7) < agreement_bound(1.0, 2) < agreement_bound(1.0, 1)
    # empirical: noise alone exceeds it in about `tail` of windows
    rng = np.random.default_rng(0)
    d = rng.normal(0.0, 1.0, (200000, 9))
    ms = d.var(axis=1)
    assert np.mean(ms > agreement_bound(1.0, 1)) == pytest.approx(1.35e-3, abs=5e-4)
    with pytest.raises(ValueError, match="tail"):
        agreement_bound(1.0, 1, tail=0.0)


def test_agree_at_height_confirms_the_true_height_only():
    """A textured roof seen 3 cells west in a and 3 east in b (dh = 3 with these
    displacements): the images agree within their noise at the roof's height, not at the
    ground's (nor at a wrong height) where the texture is seen at different places."""
    rng = np.random.default_rng(7)
    n = 60
    tex = ndimage.gaussian_filter(rng.normal(size=(n, n)), 1.0)
    tex = (128 + 40 * tex / tex.std()).astype(np.float32)
    a = np.roll(tex, -3, axis=1) + rng.normal(0, 3, (n, n)).astype(np.float32)
    b = np.roll(tex, 3, axis=1) + rng.normal(0, 3, (n, n)).astype(np.float32)
    disp = lambda h: (-h, 0 * h, h, 0 * h)                       # noqa: E731
    inner = (slice(8, -8), slice(8, -8))
    at_roof, tested = agree_at_height(a, b, np.full((n, n), 3.0), disp, 2 * 3.0 ** 2)
    assert at_roof[inner].mean() > 0.99 and tested[inner].all()
    assert not tested[:, :2].any() and not at_roof[:, :2].any()  # images off the grid: no test
    for h in (0.0, 1.5, 5.0):
        assert agree_at_height(a, b, np.full((n, n), h), disp, 2 * 3.0 ** 2)[0][inner].mean() < 0.02, h
    nan_h = np.full((n, n), 3.0)
    nan_h[30, 30] = np.nan                                        # no height: no window through it is tested
    agree, tested = agree_at_height(a, b, nan_h, disp, 2 * 3.0 ** 2)
    assert not agree[30, 30] and not tested[30, 30]


def test_noise_6dn_wide_tall_buildings_hidden_ground_is_not_an_object():
    """Wide buildings (10-25 m) up to 14 m at B/H 0.6: the ground one camera cannot see beside
    the walls is never matched and the fill carried the roofs' heights into it, 5.9 % false
    alarms on ground more than 3 m from any object on this seed (3-6 m out, inside the walls'
    occlusion shadows). Unmatched object cells farther than half the window plus one cell from
    any object measurement stay objects only where the orthophotos agree at their filled height."""
    sc = make_ortho_scene(shape=(240, 300), cell_size=0.5, n_buildings=19, seed=22,
                          building_width_cells=(20, 50), building_height_m=(3.0, 14.0))
    cams = vertical_cameras(sc, 2, base_over_height=0.6)
    imgs = render_frames(sc, cams, noise=6.0, seed=22, dz_m=0.5)
    oa, ob = (orthorectify(im, c, sc.terrain, sc.transform)[0] for im, c in zip(imgs, cams))
    r = orthoparallax(oa, ob, sc.terrain, sc.transform, centres=(cams[0].centre, cams[1].centre))
    seen = r.mask != NODATA
    far = _far_ground(sc, seen)
    fa = float((r.mask[far] == OBJECT).mean())
    recall = float((r.mask[(sc.labels > 0) & seen] == OBJECT).mean())
    # measured: 2.9 % and 98.9 % (main: 5.9 %, 99.4 %; the cells lost are roofs near the grid's
    # edge whose image in one orthophoto lies off the grid: unmeasurable, filled before)
    assert fa <= 0.03 and recall >= 0.97, (fa, recall)
    assert r.info["unconfirmed_to_ground"] > 0
    # the DEM keeps the ground's height there
    gone = (r.mask == 0) & far & ~np.isfinite(r.dh)
    assert np.sqrt(np.mean((r.dem - sc.surface)[gone] ** 2)) < 1.0


def test_noise_6dn_buildings_narrower_than_the_window_are_found_by_a_finer_window():
    """Buildings 3-10 m wide at B/H 0.6 and 6 grey levels of noise: a building 3-3.5 m wide (6-7
    cells) is narrower than the 7 x 7 window, every window through it straddles its outline and
    measures the ground (or fails the left-right check), and the whole building is missed. A 5 x 5
    window (half the window plus one cell, made odd) fits on the roof; its matches are kept where
    the coarse window has none or the images agree better at the fine height than at the coarse
    one, and the images agree within their noise at that height (chi-square bound)."""
    sc = make_ortho_scene(shape=(160, 200), cell_size=0.5, n_buildings=19, seed=27,
                          building_width_cells=(6, 20), building_height_m=(3.0, 14.0))
    cams = vertical_cameras(sc, 2, base_over_height=0.6)
    imgs = render_frames(sc, cams, noise=6.0, seed=27, dz_m=0.5)
    oa, ob = (orthorectify(im, c, sc.terrain, sc.transform)[0] for im, c in zip(imgs, cams))
    narrow = np.zeros(sc.labels.shape, bool)
    for k, sl in enumerate(ndimage.find_objects(sc.labels), start=1):
        if sl is not None and min(s.stop - s.start for s in sl) <= 7:
            narrow[sl] |= sc.labels[sl] == k
    out = {}
    for fine in (0, 1):
        r = orthoparallax(oa, ob, sc.terrain, sc.transform, centres=(cams[0].centre, cams[1].centre), fine=fine,
                          sweep=False)      # the finer window alone (the plane sweep finds these roofs too)
        seen = r.mask != NODATA
        out[fine] = (float((r.mask[narrow & seen] == OBJECT).mean()),
                     float((r.mask[(sc.labels > 0) & seen] == OBJECT).mean()),
                     float((r.mask[_far_ground(sc, seen)] == OBJECT).mean()), r.info["fine_matches"])
    # measured (recall of the narrow buildings, of all, far-ground false alarms): without the finer
    # window 47 %, 88 %, 0.8 %; with it 96 %, 94 %, 0.8 %
    assert out[0][3] == 0 and out[0][0] < 0.6
    assert out[1][3] > 0 and out[1][0] >= 0.9 and out[1][1] >= 0.93 and out[1][2] <= 0.03, out


def test_noise_6dn_a_roof_every_window_misses_is_found_by_the_plane_sweep():
    """Buildings 3-10 m wide at B/H 0.6 and 6 grey levels of noise (seed 22): a roof 3 m wide and
    4.5 m high (building 12) lies beside its walls' occlusions, 5.4 cells of parallax on a roof 6
    cells wide; every 7 x 7 and 5 x 5 window on it fails the left-right check or matches the
    ground, no object is measured near it and the whole roof is missed. The unmatched cells away
    from measured objects and their occlusions are tested at constant heights (plane sweep): the
    height at which the orthophotos agree within their noise, over the best 5 x 5 window and at the
    cell's own pixels, and at no height a cell of parallax away, is kept."""
    sc = make_ortho_scene(shape=(160, 200), cell_size=0.5, n_buildings=19, seed=22,
                          building_width_cells=(6, 20), building_height_m=(3.0, 14.0))
    cams = vertical_cameras(sc, 2, base_over_height=0.6)
    imgs = render_frames(sc, cams, noise=6.0, seed=22, dz_m=0.5)
    oa, ob = (orthorectify(im, c, sc.terrain, sc.transform)[0] for im, c in zip(imgs, cams))
    both = imaged_in_both(sc, cams, (oa, ob))
    out = {}
    for sweep in (False, True):
        r = orthoparallax(oa, ob, sc.terrain, sc.transform, centres=(cams[0].centre, cams[1].centre), sweep=sweep)
        seen = r.mask != NODATA
        out[sweep] = (float((r.mask[(sc.labels == 12) & seen] == OBJECT).mean()),
                      float((r.mask[(sc.labels > 0) & seen & both] == OBJECT).mean()),
                      float((r.mask[_far_ground(sc, seen)] == OBJECT).mean()), r.info["swept"])
    # measured (building 12, all roofs imaged in both, far-ground false alarms, swept cells):
    # without the sweep 4 %, 94.3 %, 1.1 %, 0; with it 70 %, 95.9 %, 1.2 %, 16
    assert out[False][3] == 0 and out[False][0] < 0.1
    assert out[True][3] > 0 and out[True][0] >= 0.5 and out[True][1] >= 0.95 and out[True][2] <= 0.03, out


def test_plane_sweep_keeps_only_unique_heights_on_weak_texture():
    """Texture contrast 0.03 under 6 grey levels of noise: many heights explain the images
    equally, so the sweep keeps almost nothing (a height is kept only where no other height a cell
    of parallax away agrees) and adds no false alarms."""
    sc = _scene(21, contrast=0.03)
    cams = vertical_cameras(sc, 2, base_over_height=0.45)
    imgs = render_frames(sc, cams, noise=6.0, seed=21, dz_m=0.5)
    oa, ob = (orthorectify(im, c, sc.terrain, sc.transform)[0] for im, c in zip(imgs, cams))
    r = orthoparallax(oa, ob, sc.terrain, sc.transform, centres=(cams[0].centre, cams[1].centre))
    seen = r.mask != NODATA
    # measured: 7 cells swept of 29 000 seen, far-ground false alarms 0.0 % (13 % without the sweep:
    # 0.2 % of the cells matched, the trend of so few is not the ground's)
    assert r.info["swept"] <= 0.001 * np.count_nonzero(np.isfinite(oa) & np.isfinite(ob))
    assert float((r.mask[_far_ground(sc, seen)] == OBJECT).mean()) <= 0.03


def test_order_reversed_when_low_cells_outnumber_objects_by_a_window():
    from bare_earth.core.codes import LOW
    from bare_earth.core.orthophoto.quality import order_reversed
    m = np.zeros((20, 20), np.uint8)
    m[2:5, 2:5] = OBJECT                       # 9 object cells
    m[10:13, 10:14] = LOW                      # 12 low cells: more, but fewer than a 5 x 5 window
    m[0, :] = NODATA
    assert order_reversed(m, 5) == (False, 12, 9)
    assert order_reversed(m, 3) == (True, 12, 9)
    m[10:16, 10:16] = LOW                      # 36 >= 25
    assert order_reversed(m, 5) == (True, 36, 9)
    m[2:10, 2:10] = OBJECT                     # 64 objects > 36 low
    assert order_reversed(m, 5) == (False, 36, 64)
