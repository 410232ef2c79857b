"""QA pass 23: the numeric core's public functions called from Python with arrays and values of the wrong kind.
Each test failed before its fix (a silent wrong answer or a numpy/Python traceback)."""
import numpy as np
import pytest

from bare_earth.core import as_cell_size, filter_dsm
from bare_earth.core.evaluate import compare_dtm, compare_masks, confusion, error_map_from_masks
from bare_earth.core.fill import fill_gaps


def _dsm():
    """A plane of 0.1 m noise with a 8 m block, and the stored value -9999 on a patch the
    reader masked (``rasterio``'s ``read(1, masked=True)`` or ``np.ma.masked_equal``)."""
    rng = np.random.default_rng(0)
    z = (100 + rng.normal(0, 0.1, (40, 40))).astype(np.float32)
    z[10:20, 10:20] += 8
    z[30:36, 30:36] = -9999.0
    return z, np.ma.masked_equal(z, -9999.0)


@pytest.mark.parametrize("method", ["slopeprofile", "dtm"])
def test_a_masked_array_filtered_with_its_masked_cells_as_nodata(method):
    """np.asarray dropped the mask: the -9999 under it was read as a 10 km pit of ground (mask 0, then the DTM
    dips to -9999 m there). The masked cells are nodata now, exactly as NaN there."""
    z, zm = _dsm()
    got = filter_dsm(zm, 1.0, method=method)
    assert (got.mask[30:36, 30:36] == 255).all() and np.isnan(got.dtm[30:36, 30:36]).all()
    as_nan = filter_dsm(np.where(z == -9999.0, np.nan, z), 1.0, method=method)
    assert np.array_equal(got.mask, as_nan.mask)
    assert np.array_equal(got.dtm, as_nan.dtm, equal_nan=True)


def test_a_masked_integer_array_keeps_its_heights():
    """An Int16 masked array (a DSM in dm, nodata -32768 masked) is filtered as its float heights with NaN."""
    z, _ = _dsm()
    zi = np.ma.masked_equal(np.where(z == -9999.0, -32768, np.round(z * 10)).astype(np.int16), -32768)
    got = filter_dsm(zi, 10.0, method="slopeprofile")
    assert (got.mask[30:36, 30:36] == 255).all() and np.nanmin(got.dtm) > 900


def test_fill_gaps_fills_the_masked_cells_of_a_masked_array():
    """fill_gaps(masked array) returned the stored values (no gap at all); it fills the masked cells now."""
    z = np.add.outer(np.arange(8.0), np.arange(8.0))
    hole = np.zeros(z.shape, bool)
    hole[2:5, 3:6] = True
    zm = np.ma.masked_array(np.where(hole, -9999.0, z), mask=hole)
    assert np.allclose(fill_gaps(zm), z, atol=1e-3)


@pytest.mark.parametrize("call", [lambda: filter_dsm(np.ones((8, 8)), 1.0 + 0j),
                                  lambda: as_cell_size("one metre")])
def test_a_cell_size_of_the_wrong_type_is_a_value_error(call):
    """A complex cell size raised float()'s TypeError from inside as_cell_pair; text raised numpy's message."""
    with pytest.raises(ValueError, match="cell_size must be one or two positive numbers"):
        call()


def test_fill_gaps_refuses_complex_heights():
    """numpy dropped the imaginary parts with a ComplexWarning only; refused like as_surface does."""
    with pytest.raises(ValueError, match="complex numbers"):
        fill_gaps(np.ones((5, 5), np.complex64))


@pytest.mark.parametrize("pred, message", [
    (np.array([[0, 1], [255, 0]], np.uint8), "holds 1 other value"),        # a mask of codes: 255 nodata
    (np.array([[1.0, np.nan], [1.0, 0.0]]), "e.g. nan"),                    # NaN: astype(bool) is True
    (np.array([[1, 2], [1, 0]]), "e.g. 2"),
])
def test_confusion_refuses_what_is_no_true_false(pred, message):
    """confusion read every nonzero, NaN included, as ground: a code mask (255 nodata) was scored silently."""
    truth = np.array([[True, True], [False, False]])
    with pytest.raises(ValueError, match=message) as err:
        confusion(pred, truth)
    assert "compare_masks" in str(err.value)
    assert confusion(np.array([[1, 0], [0, 0]]), truth)["a"] == 1          # 0 / 1 stay booleans


def _mask():
    m = np.zeros((10, 10), np.uint8)
    m[2:5, 2:5] = 1
    return m


@pytest.mark.parametrize("bad, value", [(256, "256"), (-1, "-1"), (0.5, "0.5")])
def test_compare_masks_refuses_values_that_are_no_code(bad, value):
    """256 and -1 were counted as objects or, cast to uint8 elsewhere, as 0 and 255; 0.5 as an object."""
    m = _mask().astype(float)
    m[0, 0] = bad
    for f in (compare_masks, error_map_from_masks):
        with pytest.raises(ValueError, match=f"e.g. {value}\\).*whole numbers 0-255"):
            f(m, _mask())


def test_compare_masks_reads_nan_and_masked_cells_as_nodata():
    """A float mask's NaN (its nodata) and a masked array's masked cells were objects: 9 Type II errors."""
    ref = _mask()
    m = ref.astype(np.float32)
    m[2:5, 2:5] = np.nan
    r = compare_masks(m, ref)
    assert r["n"] == 91 and r["c"] == 0 and r["n_object"] == 0
    masked = compare_masks(ref, np.ma.masked_array(ref, mask=ref == 1))
    assert [masked[k] for k in "abcdn"] == [r[k] for k in "abcdn"]
    codes, _ = error_map_from_masks(m, ref)
    assert (codes[2:5, 2:5] == 255).all() and (codes[ref == 0] == 0).all()
    assert compare_masks(np.where(ref == 1, 6, 0), ref)["d"] == 9            # a classification's 6: an object


def test_compare_dtm_skips_masked_and_far_cells_and_refuses_complex():
    """The masked cells were compared with their stored values, 1e30 (an undeclared nodata) gave an RMSE of
    1e30, and complex heights lost their imaginary part with a warning only."""
    ref = np.zeros((5, 5))
    dtm = np.ones((5, 5))
    dtm[0, 0] = 500.0
    r = compare_dtm(np.ma.masked_greater(dtm, 100), ref)
    assert r["n"] == 24 and r["rmse"] == 1.0
    assert compare_dtm(np.where(dtm > 100, 1e30, dtm), ref) == r
    assert compare_dtm(dtm, np.where(dtm > 100, -1e30, ref)) == r
    with pytest.raises(ValueError, match="complex numbers"):
        compare_dtm(dtm * 1j, ref)
    with pytest.raises(ValueError, match="no mask code"):
        compare_dtm(dtm, ref, ground=np.full((5, 5), 0.5))


def _orthos():
    rng = np.random.default_rng(3)
    img = rng.random((60, 60)).astype(np.float32)
    return img, np.roll(img, 1, axis=1), np.full((60, 60), 100.0, np.float32), (0.0, 1.0, 0.0, 60.0, 0.0, -1.0)


@pytest.mark.parametrize("min_corr", [1.0, 2.0, -0.5])
def test_orthoparallax_and_matcher_refuse_a_correlation_threshold_beyond_0_1(min_corr):
    """min_corr 2 kept no match and returned an all-NaN correction without a word (the plugin refused it, the
    core did not); -0.5 accepted windows that do not look alike. One check now, the core's (check_min_corr)."""
    from bare_earth.core.orthophoto import match_rectified, orthoparallax
    a, b, dem, gt = _orthos()
    with pytest.raises(ValueError, match=r"min_corr must be in 0 \.\. 1 \(1 excluded\)"):
        orthoparallax(a, b, dem, gt, base_m=500.0, height_m=1000.0, min_corr=min_corr)
    with pytest.raises(ValueError, match=r"min_corr must be in 0 \.\. 1"):
        match_rectified(a, b, 0, 3, min_corr=min_corr)


def test_orthoparallax_reads_masked_pixels_as_invalid_and_refuses_complex():
    """A masked orthophoto was matched on the values under its mask; complex grey values lost their imaginary
    part with a ComplexWarning only."""
    from bare_earth.core.orthophoto import orthoparallax
    a, b, dem, gt = _orthos()
    hole = np.zeros(a.shape, bool)
    hole[20:30, 20:30] = True
    kw = dict(base_m=500.0, height_m=1000.0)
    masked = orthoparallax(np.ma.masked_array(np.where(hole, 0.0, a), mask=hole), b, dem, gt, **kw)
    as_nan = orthoparallax(np.where(hole, np.nan, a), b, dem, gt, **kw)
    assert np.array_equal(masked.dh, as_nan.dh, equal_nan=True)
    with pytest.raises(ValueError, match="complex numbers"):
        orthoparallax(a.astype(np.complex64), b, dem, gt, **kw)


@pytest.mark.parametrize("method, name, value, message", [
    ("slopeprofile", "slope_threshold_deg", "30", "is not a number"),           # TypeError '>=' str and float
    ("curvature", "window_cells", [5], "is not a number"),                      # TypeError '>=' list and int
    ("rascor", "height_min_m", 3 + 0j, "is not a number"),                      # ran, the complex taken somehow
    ("morphological", "dh_m", True, "is not a number"),                         # ran with dh 1 m
    ("rascor", "step1_characterise", "no", "is not True or False"),             # 'no' ran step 1
    ("geodesic", "scan_labelling", 2, "is not True or False"),
])
def test_a_parameter_of_the_wrong_kind_is_a_value_error_naming_it(method, name, value, message):
    """filter_dsm's keyword parameters given as text, a list, a complex or a bool where a number is due raised
    a TypeError from the limits check, or ran on a silent conversion; a yes/no given 'no' was read as yes."""
    z, _ = _dsm()
    with pytest.raises(ValueError, match=f"{name} = .* {message} for method '{method}'"):
        filter_dsm(np.where(z == -9999.0, np.nan, z), 1.0, method=method, **{name: value})


def test_numbers_of_numpy_and_0_or_1_yes_no_are_accepted():
    """The guard of the kind check above (passed before it too): numpy scalars, a 0-d array and 0 / 1 for a
    yes/no stay accepted, with the same result."""
    z, _ = _dsm()
    z = np.where(z == -9999.0, np.nan, z)
    a = filter_dsm(z, 1.0, method="geodesic", max_object_size_m=np.float32(30.0), scan_labelling=np.bool_(False))
    b = filter_dsm(z, 1.0, method="geodesic", max_object_size_m=np.array(30.0), scan_labelling=0)
    assert np.array_equal(a.mask, b.mask)


def test_points_sampled_and_classified_on_a_masked_dtm_see_its_mask():
    """sample_bilinear and classify_points read a masked DTM's stored values (-9999) under its mask: a point
    there was 'above' the DTM by 10 km. It is outside the DTM (NaN, class 255) now, as on NaN."""
    from bare_earth.core.points import classify_points, sample_bilinear
    dtm = np.full((4, 4), 10.0)
    dtm[1, 1] = -9999.0
    masked = np.ma.masked_equal(dtm, -9999.0)
    gt = (0.0, 1.0, 0.0, 4.0, 0.0, -1.0)
    assert np.isnan(sample_bilinear(masked, gt, [1.5], [2.5]))[0]
    x, y, z = np.array([1.5, 3.5]), np.array([2.5, 0.5]), np.array([10.0, 10.0])
    assert classify_points(x, y, z, masked, gt).tolist() == [255, 0]


@pytest.mark.parametrize("progress", [5, "log"])
def test_a_progress_that_is_not_callable_is_refused_before_work(progress):
    """filter_dsm(progress=5) failed at the first report, inside the run, with "'int' object is not callable"."""
    with pytest.raises(ValueError, match=r"progress must be a callable progress\(fraction\) or None"):
        filter_dsm(np.ones((8, 8), np.float32), 1.0, progress=progress)


def test_a_point_filter_with_a_progress_that_is_not_callable_is_refused_before_work():
    """filter_cloud(progress=5) failed at its first report with "'int' object is not callable"."""
    from bare_earth.core.pointflow import filter_cloud
    from bare_earth.core.points import PointCloud
    rng = np.random.default_rng(0)
    x, y = rng.uniform(0, 30, 500), rng.uniform(0, 30, 500)
    with pytest.raises(ValueError, match=r"progress must be a callable progress\(fraction\) or None"):
        filter_cloud(PointCloud(x=x, y=y, z=100.0 + 0 * x), progress=5)
