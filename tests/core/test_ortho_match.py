"""NCC matcher: exact integer and sub-pixel shifts, directions, left-right check, errors."""
import numpy as np
import pytest
from scipy import ndimage

from bare_earth.core.orthophoto.match import match_along, match_rectified, ncc_volume


def _texture(shape, seed=0, sigma=1.2):
    rng = np.random.default_rng(seed)
    t = ndimage.gaussian_filter(rng.normal(size=shape), sigma)
    return (t / t.std()).astype(np.float64)


def _shifted(t, shift_cols, shift_rows=0.0):
    """t sampled at (r - shift_rows, c - shift_cols): features move by +shift."""
    rr, cc = np.indices(t.shape, dtype=float)
    return ndimage.map_coordinates(t, [rr - shift_rows, cc - shift_cols], order=3, mode="reflect")


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.int16])
def test_ncc_volume_peak_is_one_at_the_true_shift(dtype):
    t = _texture((40, 60))
    a = (t * 100).astype(dtype)
    b = np.roll(a, 3, axis=1)                        # b[:, j + 3] = a[:, j]
    vol = ncc_volume(a, b, [1, 2, 3, 4], 7)
    inner = vol[:, 5:-5, 8:-8]
    assert np.all(np.argmax(inner, axis=0) == 2)
    np.testing.assert_allclose(inner[2], 1.0, atol=1e-4)


@pytest.mark.parametrize("shift", [2.3, -1.6, 0.45])
def test_match_along_subpixel_exact(shift):
    t = _texture((80, 120), seed=1, sigma=1.5)
    b = _shifted(t, shift)
    r = match_along(t, b, (1, 0), 5, window=9, shiftable=0, min_corr=0.5)
    core = r.disparity[15:-15, 15:-15]
    assert np.isfinite(core).mean() > 0.95
    assert np.nanmedian(np.abs(core - shift)) < 0.03
    # parabola only is coarser but still sub-pixel
    r0 = match_along(t, b, (1, 0), 5, window=9, shiftable=0, lsm_iterations=0)
    assert np.nanmedian(np.abs(r0.disparity[15:-15, 15:-15] - shift)) < 0.2


@pytest.mark.parametrize("direction", [(0, 1), (0, -1), (-1, 0), (0.8, 0.6)])
def test_match_along_any_direction(direction):
    t = _texture((90, 90), seed=2, sigma=1.5)
    u = np.asarray(direction) / np.hypot(*direction)
    d = 1.7
    b = _shifted(t, d * u[0], d * u[1])
    r = match_along(t, b, direction, 4, window=9, shiftable=0)
    core = r.disparity[20:-20, 20:-20]
    assert np.isfinite(core).mean() > 0.9
    assert abs(np.nanmedian(core) - d) < 0.1


def test_left_right_check_rejects_occluded_and_flat():
    t = _texture((60, 100), seed=3)
    b = np.roll(t, 4, axis=1)
    b[:, 40:50] = _texture((60, 10), seed=9)          # content only in b: no true match
    a = t.copy()
    a[:, 70:90] = 1.0                                 # flat: NCC undefined
    r = match_along(a, b, (1, 0), 6, window=7, shiftable=0)
    assert np.isnan(r.disparity[10:-10, 75:85]).all()
    ok = r.disparity[10:-10, 10:30]
    assert np.nanmedian(np.abs(ok - 4)) < 0.05 and np.isfinite(ok).mean() > 0.9


def test_match_rectified_middlebury_convention():
    t = _texture((50, 120), seed=4)
    right = t
    left = np.roll(t, 7, axis=1)                      # x_right = x_left - 7
    r = match_rectified(left, right, 0, 12, window=7, shiftable=0)
    assert np.nanmedian(r.disparity[5:-5, 20:-5]) == pytest.approx(7, abs=0.05)


def test_bad_inputs():
    t = _texture((30, 30))
    with pytest.raises(ValueError, match="same grid"):
        match_along(t, t[:, :-1], (1, 0), 3)
    with pytest.raises(ValueError, match="B = 0"):
        match_along(t, t, (0, 0), 3)
    with pytest.raises(ValueError, match="odd"):
        match_along(t, t, (1, 0), 3, window=6)
    with pytest.raises(ValueError, match="d_max"):
        match_rectified(t, t, 5, 2)


def test_middlebury_cones(shared_data):
    from osgeo import gdal
    d = shared_data / "stereo" / "middlebury_cones"
    left = gdal.Open(str(d / "Cones_LEFT.tif")).ReadAsArray().astype(np.float32)
    right = gdal.Open(str(d / "Cones_RIGHT.tif")).ReadAsArray().astype(np.float32)
    gt = gdal.Open(str(d / "Cones_LEFT_GT.tif")).ReadAsArray()
    nocc = gdal.Open(str(d / "Occlusion_LEFT.png")).ReadAsArray() > 0
    r = match_rectified(left, right, 0, 60, window=7, shiftable=5)
    m = (gt > 0) & nocc
    share = float((np.abs(r.disparity - gt) <= 1)[m].mean())   # unmatched count as wrong
    assert share >= 0.75


def test_row_strips_give_the_same_result(monkeypatch):
    from bare_earth.core.orthophoto import match as match_mod
    t = _texture((70, 90), seed=5, sigma=1.5)
    b = _shifted(t, 1.3)
    b[30:40, 20:50] = _texture((10, 30), seed=8)
    whole = match_along(t, b, (1, 0), 4, window=7, shiftable=5)
    monkeypatch.setattr(match_mod, "MAX_CELLS", 90 * 12)   # strips of 12 rows
    strips = match_along(t, b, (1, 0), 4, window=7, shiftable=5)
    np.testing.assert_array_equal(whole.valid, strips.valid)
    np.testing.assert_allclose(whole.disparity, strips.disparity, atol=1e-5, equal_nan=True)


def test_streamed_planes_give_the_argmax_of_the_volume():
    """match_along takes the NCC planes one shift at a time; its winner is the volume's argmax."""
    t = _texture((60, 80), seed=6, sigma=1.3)
    b = _shifted(t, 2.4)
    b[20:30, 30:45] = 0.5                            # flat patch: no NCC (ties at -2)
    b[40:50, 10:30] = _texture((10, 20), seed=11)    # content only in b
    shifts = np.arange(-5, 6)
    vol = ncc_volume(t, b, shifts, 7, shiftable=5, min_fill=1.0)
    # the symmetric anchor of match_along: S[s, m] = V[s, m - floor(s / 2)]
    sym = np.full_like(vol, -2.0)
    for k, s in enumerate(shifts):
        h = int(np.floor(s / 2))
        if h >= 0:
            sym[k][:, h:] = vol[k][:, :80 - h]
        else:
            sym[k][:, :80 + h] = vol[k][:, -h:]
    k = np.argmax(sym, axis=0)
    rr, cc = np.indices(k.shape)
    c0, cm, cp = sym[k, rr, cc], sym[np.maximum(k - 1, 0), rr, cc], sym[np.minimum(k + 1, 10), rr, cc]
    den = cm - 2 * c0 + cp
    with np.errstate(divide="ignore", invalid="ignore"):
        off = np.clip(np.where((den < 0) & (cm > -2) & (cp > -2), 0.5 * (cm - cp) / den, 0.0), -0.5, 0.5)
    want = (shifts[k] + off).astype(np.float32)
    r = match_along(t, b, (1, 0), 5, window=7, shiftable=5, lsm_iterations=0, min_corr=0.5)
    got = r.disparity
    ok = np.isfinite(got)
    assert ok.mean() > 0.5
    np.testing.assert_array_equal(got[ok], want[ok])
    np.testing.assert_array_equal(np.nan_to_num(r.corr, nan=-2.0), c0)


@pytest.mark.parametrize("cols", [12, 20])
def test_search_range_wider_than_the_image(cols):
    """Shifts beyond the image's width see no cell of the other image: the match is the one of
    a search range clipped to the width (a 60 x 60 pair with the default 0.2 H search once failed
    with a raw broadcast error)."""
    t = _texture((30, cols), seed=4, sigma=1.2)
    b = _shifted(t, 1.0)
    wide = match_along(t, b, (1, 0), cols + 7, window=5, shiftable=0, lsm_iterations=0, min_corr=0.5)
    assert wide.disparity.shape == t.shape
    inner = wide.disparity[5:-5, 4:-4]
    assert np.isfinite(inner).mean() > 0.5
    assert np.nanmedian(np.abs(inner - 1.0)) < 0.2


# --------------------------------------------------------------------------- fast kernels
@pytest.mark.parametrize("shape", [(40, 57), (7, 9), (3, 30), (25, 4)])
@pytest.mark.parametrize("window", [3, 5, 7, 9, 11])
def test_box_mean_is_the_constant_mode_uniform_filter(shape, window):
    """The matcher's box filter: ndimage's window mean (zero outside) to float32 rounding."""
    from bare_earth.core.orthophoto import match as match_mod
    rng = np.random.default_rng(window)
    x = (rng.random(shape) * 255).astype(np.float32) ** 2          # squared grey levels, as in the NCC
    box = match_mod._BoxMean(shape, window)
    got = box(x)
    want = ndimage.uniform_filter(x.astype(np.float64), window, mode="constant")
    np.testing.assert_allclose(got, want, rtol=0, atol=2e-6 * float(x.max()))
    out = np.empty(shape, np.float32)                               # the kept buffers: a second call
    assert box(x[::-1].copy(), out) is out
    np.testing.assert_allclose(out, ndimage.uniform_filter(x[::-1].astype(np.float64), window,
                                                           mode="constant"), rtol=0, atol=2e-6 * float(x.max()))


@pytest.mark.parametrize("w", list(range(1, 14)))
def test_window_sums_by_doubling_are_the_sums(w):
    from bare_earth.core.orthophoto import match as match_mod
    v = np.arange(40, dtype=np.float32) ** 2                        # integers: every sum exact
    out = np.empty(40 - w + 1, np.float32)
    match_mod._window_sums(v, w, out)
    np.testing.assert_array_equal(out, [v[i:i + w].sum() for i in range(40 - w + 1)])


@pytest.mark.parametrize("shape", [(30, 41), (5, 5), (4, 30), (30, 3), (12, 12)])
@pytest.mark.parametrize("size", [3, 5, 7, 9])
def test_shiftable_maximum_is_the_nearest_mode_maximum_filter(shape, size):
    from bare_earth.core.orthophoto import match as match_mod
    x = np.random.default_rng(size).random(shape).astype(np.float32)
    x[x < 0.2] = -2.0                                               # cells without an NCC
    np.testing.assert_array_equal(match_mod._max_filter_nearest(x, size),
                                  ndimage.maximum_filter(x, size, mode="nearest"))


def test_sample_rows_is_linear_interpolation_along_rows():
    from bare_earth.core.orthophoto import match as match_mod
    rng = np.random.default_rng(3)
    img = rng.random((6, 20)).astype(np.float32)
    grad = rng.random((6, 20)).astype(np.float32)
    valid = np.ones(img.shape, bool)
    valid[2, 7] = False
    cols = (np.arange(20, dtype=np.float32)[None, :] + rng.uniform(-3, 3, img.shape)).astype(np.float32)
    (val, g), ok = match_mod._sample_rows(match_mod._row_table(img, grad, valid), cols)
    rr = np.indices(img.shape)[0]
    c = np.clip(cols, 0, 19)
    for arr, got in ((img, val), (grad, g)):
        want = ndimage.map_coordinates(arr.astype(np.float64), [rr, c], order=1, mode="nearest")
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)
    inside = (cols >= -1e-3) & (cols <= 19 + 1e-3)
    j0 = np.floor(c).astype(int)
    touches_bad = (rr == 2) & ((j0 == 7) | ((j0 == 6) & (c - j0 >= 1e-3)))
    np.testing.assert_array_equal(ok, inside & ~touches_bad)


@pytest.mark.parametrize("s", [-7, -1, 0, 3, 11])
def test_shifted_offer_is_the_column_offer(s):
    """The b-anchored winner fed through the flattened rows equals the 2-D column offer."""
    from bare_earth.core.orthophoto import match as match_mod
    rng = np.random.default_rng(abs(s))
    cols = 16
    planes = [rng.uniform(-1, 1, (5, cols)).astype(np.float32) for _ in range(3)]
    flat, ref = match_mod._RunningBest((5, cols)), np.full((5, cols), -2.0, np.float32)
    kref = np.zeros((5, cols), np.int32)
    for k, p in enumerate(planes):
        p = p.copy()
        p[:, slice(cols - s, cols) if s >= 0 else slice(0, -s)] = -2.0   # no partner in b
        flat.offer_shifted(k, p, s)
        view = p[:, :cols - s] if s >= 0 else p[:, -s:]
        lo = max(0, s)
        upd = view > ref[:, lo:lo + view.shape[1]]
        ref[:, lo:lo + view.shape[1]][upd] = view[upd]
        kref[:, lo:lo + view.shape[1]][upd] = k
    np.testing.assert_array_equal(flat.best, ref)
    np.testing.assert_array_equal(flat.k, kref)
