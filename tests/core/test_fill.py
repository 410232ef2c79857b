"""Tests of core.fill.fill_gaps: harmonic gap filling."""
import numpy as np
import pytest

from bare_earth.core.common import Cancelled
from bare_earth.core.fill import edge_spikes_reach, fill_gaps, find_edge_spikes

DTYPES = [np.float32, np.float64, np.int16]


def _plane(shape, a=0.3, b=-0.2, c=100.0):
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]].astype(np.float64)
    return c + a * xx + b * yy


def _with_nan(z, dtype):
    """Cast ``z`` to ``dtype``; for int16 nodata is expressed through ``fill``."""
    return np.asarray(z).astype(dtype)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("shape", [(64, 80), (257, 301)])
def test_hole_in_plane_is_the_plane(dtype, shape):
    truth = _plane(shape)
    z = truth.astype(dtype)
    h, w = shape
    z[h // 4:h // 4 + h // 3, w // 5:w // 5 + w // 2] = np.nan
    z[h // 2 + 10:h // 2 + 14, 3:9] = np.nan
    out = fill_gaps(z)
    assert out.dtype == np.float32 and out.shape == z.shape
    assert np.abs(out - truth).max() < 1e-3


@pytest.mark.parametrize("dtype", DTYPES)
def test_ramp_with_fill_mask(dtype):
    # A linear ramp (integers, so int16 is exact); the holes are given through `fill`.
    shape = (150, 170)
    truth = _plane(shape, a=2.0, b=1.0, c=10.0)
    z = truth.astype(dtype)
    fill = np.zeros(shape, bool)
    fill[30:110, 40:90] = True
    fill[120:135, 100:160] = True
    z_before = z.copy()
    out = fill_gaps(z, fill)
    np.testing.assert_array_equal(z, z_before)  # input not modified
    assert np.abs(out - truth)[fill].max() < 1e-3
    # known cells unchanged, exactly
    np.testing.assert_array_equal(out[~fill], z[~fill].astype(np.float32))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_known_cells_exact_and_input_untouched(dtype):
    rng = np.random.default_rng(3)
    z = (rng.normal(0, 5, (90, 110)) + 1234.567).astype(dtype)
    z[rng.random(z.shape) < 0.3] = np.nan
    z_before = z.copy()
    out = fill_gaps(z)
    np.testing.assert_array_equal(z, z_before)
    known = np.isfinite(z)
    np.testing.assert_array_equal(out[known], z[known].astype(np.float32))
    assert np.isfinite(out).all()
    # a membrane never leaves the range of its data (maximum principle)
    assert out.min() >= np.nanmin(z).astype(np.float32) - 1e-3
    assert out.max() <= np.nanmax(z).astype(np.float32) + 1e-3


def test_nodata_outside_fill_stays_nan_and_is_no_source():
    truth = _plane((100, 120))
    z = truth.astype(np.float32)
    nodata = np.zeros(z.shape, bool)
    nodata[:, :10] = True            # nodata border strip
    nodata[60:80, 60:80] = True      # nodata blob
    z[nodata] = np.nan
    fill = np.zeros(z.shape, bool)
    fill[20:50, 30:70] = True        # removed object: heights are garbage
    fill[45:65, 50:70] = True        # touches the nodata blob
    z[fill & ~nodata] = 9999.0       # must not leak into the result
    fill[62:66, 62:66] = True        # nodata cells inside `fill` are filled
    out = fill_gaps(z, fill)
    assert np.isnan(out[nodata & ~fill]).all()
    assert np.isfinite(out[fill]).all()
    assert np.isfinite(out[~nodata]).all()
    assert out[fill].max() < truth.max() + 1.0  # the 9999 values were not used
    # the hole is surrounded by plane data on all sides but the nodata blob
    assert np.abs(out - truth)[20:40, 30:60].max() < 0.5


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_edge_holes_and_unknown_regions_get_finite_values(dtype):
    truth = _plane((80, 90))
    z = truth.astype(dtype)
    z[:25, :30] = np.nan       # corner
    z[:, 85:] = np.nan         # whole right strip
    z[70:, :] = np.nan         # whole bottom strip
    out = fill_gaps(z)
    assert np.isfinite(out).all()
    # zero-flux edge: the fill stays within the data range
    assert np.nanmin(z) - 1e-3 <= out.min() and out.max() <= np.nanmax(z) + 1e-3


def test_single_known_cell_fills_everything_with_its_value():
    z = np.full((300, 200), np.nan, np.float32)
    z[123, 45] = 7.5
    out = fill_gaps(z)
    np.testing.assert_allclose(out, 7.5, atol=1e-4)


def test_no_steps_at_hole_edges():
    # Curved terrain: differences across hole edges bounded by the surface gradient.
    yy, xx = np.mgrid[0:200, 0:240].astype(np.float64)
    truth = 50 + 8 * np.sin(xx / 25) + 5 * np.cos(yy / 19) + 0.002 * (xx - 120) ** 2
    z = truth.astype(np.float32)
    hole = np.zeros(z.shape, bool)
    hole[40:120, 50:150] = True
    hole[150:190, 20:60] = True
    hole[10:14, 200:230] = True
    z[hole] = np.nan
    out = fill_gaps(z)
    gmax = max(np.abs(np.diff(truth, axis=0)).max(), np.abs(np.diff(truth, axis=1)).max())
    for axis in (0, 1):
        d = np.abs(np.diff(out, axis=axis))
        a = np.take(hole, np.arange(hole.shape[axis] - 1), axis=axis)
        b = np.take(hole, np.arange(1, hole.shape[axis]), axis=axis)
        across = a != b                                  # one filled, one known cell
        assert d[across].max() <= 1.5 * gmax
        inside = a & b
        assert d[inside].max() <= 1.5 * gmax


def test_matches_exact_harmonic_solution_closely():
    # Large single hole: compare with a direct sparse solve of the Laplace equation.
    from scipy.sparse import diags, identity, kron
    from scipy.sparse.linalg import spsolve
    n = 70
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float64)
    truth = np.sin(xx / 9.0) * 6 + np.cos(yy / 7.0) * 4 + 0.05 * xx * yy / n
    hole = np.zeros((n, n), bool)
    hole[10:60, 15:55] = True
    z = truth.copy()
    z[hole] = np.nan
    # exact: interior Dirichlet problem on the hole (all of its neighbours are known)
    hh, hw = 50, 40

    def t(m):
        return diags([-1, 2, -1], [-1, 0, 1], shape=(m, m))

    a = (kron(identity(hh), t(hw)) + kron(t(hh), identity(hw))).tocsc()
    rhs = np.zeros((hh, hw))
    rhs[0, :] += truth[9, 15:55]
    rhs[-1, :] += truth[60, 15:55]
    rhs[:, 0] += truth[10:60, 14]
    rhs[:, -1] += truth[10:60, 55]
    exact = spsolve(a, rhs.ravel()).reshape(hh, hw)
    out = fill_gaps(z)
    err = np.abs(out[10:60, 15:55] - exact)
    assert err.max() < 0.03 * np.ptp(exact)
    assert np.sqrt(np.mean(err ** 2)) < 0.012 * np.ptp(exact)


def test_progress_called_per_level_and_cancel():
    z = _plane((300, 300)).astype(np.float32)
    z[100:200, 100:200] = np.nan
    calls = []
    fill_gaps(z, progress=calls.append)
    assert len(calls) >= 3 and calls[-1] == pytest.approx(1.0)
    assert all(b >= a for a, b in zip(calls, calls[1:]))

    def cancel(f):
        raise Cancelled()
    with pytest.raises(Cancelled):
        fill_gaps(z, progress=cancel)


def test_nothing_to_fill_returns_copy():
    z = _plane((20, 30)).astype(np.float64)
    out = fill_gaps(z)
    assert out.dtype == np.float32
    np.testing.assert_array_equal(out, z.astype(np.float32))
    z[3, 4] = np.nan
    out = fill_gaps(z, np.zeros(z.shape, bool))
    assert np.isnan(out[3, 4]) and np.isfinite(np.delete(out.ravel(), 3 * 30 + 4)).all()


def test_errors():
    with pytest.raises(ValueError, match="no known cell"):
        fill_gaps(np.full((10, 10), np.nan))
    z = np.ones((10, 10), np.float32)
    with pytest.raises(ValueError, match="no known cell"):
        fill_gaps(z, np.ones((10, 10), bool))
    with pytest.raises(ValueError, match="shape"):
        fill_gaps(z, np.ones((5, 10), bool))
    with pytest.raises(ValueError, match="2-D"):
        fill_gaps(np.ones(10))
    with pytest.raises(ValueError, match="empty"):
        fill_gaps(np.ones((0, 3)))


def _exact_laplace(z):
    """Exact discrete Laplace fill (Neumann raster edges) by a sparse direct solve."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import spsolve
    h, w = z.shape
    free = ~np.isfinite(z)
    ids = np.full((h, w), -1)
    ids[free] = np.arange(free.sum())
    zz = np.where(free, 0.0, z)
    rows, cols, vals = [], [], []
    rhs = np.zeros(free.sum())
    diag = np.zeros(free.sum())
    for dst, src in (((slice(1, None), slice(None)), (slice(None, -1), slice(None))),
                     ((slice(None, -1), slice(None)), (slice(1, None), slice(None))),
                     ((slice(None), slice(1, None)), (slice(None), slice(None, -1))),
                     ((slice(None), slice(None, -1)), (slice(None), slice(1, None)))):
        f = free[dst]
        i, j = ids[dst][f], ids[src][f]
        np.add.at(diag, i, 1.0)
        rows.append(i[j >= 0])
        cols.append(j[j >= 0])
        vals.append(-np.ones((j >= 0).sum()))
        np.add.at(rhs, i[j < 0], zz[src][f][j < 0])
    n = free.sum()
    a = coo_matrix((np.concatenate(vals + [diag]),
                    (np.concatenate(rows + [np.arange(n)]), np.concatenate(cols + [np.arange(n)]))),
                   shape=(n, n)).tocsc()
    out = z.astype(np.float64).copy()
    out[free] = spsolve(a, rhs)
    return out


@pytest.mark.parametrize("known_fraction", [0.01, 0.1, 0.6])
def test_scattered_data_close_to_exact_membrane(known_fraction):
    # Sparse random points (and a mid-density case) on a curved surface, 120 x 140 cells
    # (large enough for three pyramid levels).
    rng = np.random.default_rng(11)
    yy, xx = np.mgrid[0:120, 0:140].astype(np.float64)
    truth = 0.05 * xx + 0.02 * yy + 3 * np.sin(xx / 17) * np.cos(yy / 23)
    z = np.full(truth.shape, np.nan)
    k = rng.random(truth.shape) < known_fraction
    z[k] = truth[k]
    exact = _exact_laplace(z)
    out = fill_gaps(z)
    err = np.abs(out - exact)
    span = np.ptp(exact)
    assert np.sqrt(np.mean(err ** 2)) < 0.01 * span
    assert err.max() < 0.04 * span


def _relax_reference(known, val, coarse, sweeps, relax, omega):
    """Cell-by-cell red-black relaxation with the kernel's float32 arithmetic (the order of
    the sums included): the exact values :func:`fill._relax_level` must give."""
    from bare_earth.core import fill
    h, w = known.shape
    u = np.zeros((h + 2, w + 2), np.float32)
    u[1:-1, 1:-1] = val
    r, c = np.nonzero(~known)
    u[r + 1, c + 1] = fill._prolong(fill._pad_linear(coarse), r, c)
    cells = [(i, j) for i, j in zip(r, c) if relax is None or relax[i, j]]
    for _ in range(sweeps):
        for colour in (0, 1):
            for i, j in cells:
                if (i + j) % 2 != colour:
                    continue
                n = 4 - (i == 0) - (i == h - 1) - (j == 0) - (j == w - 1)
                inv = np.float32(0.25) if n == 4 else np.float32(1.0 / max(n, 1))
                s = u[i + 1, j] + u[i + 1, j + 2]
                s = s + u[i, j + 1]
                s = s + u[i + 2, j + 1]
                s = np.float32(s * inv)
                if omega != 1.0:
                    t = u[i + 1, j + 1]
                    s = np.float32((s - t) * np.float32(omega) + t)
                u[i + 1, j + 1] = s
    return u[1:-1, 1:-1]


@pytest.mark.parametrize("chunk", [5, 1 << 14])              # sweeps in chunks of 5 cells, one chunk
@pytest.mark.parametrize("omega,use_relax", [(1.0, False), (1.8, False), (1.0, True)])
def test_relax_level_equals_the_cell_by_cell_reference(omega, use_relax, chunk, monkeypatch):
    # holes on the raster's edges and corners (Neumann cells, own weights), one inside
    from bare_earth.core import fill
    monkeypatch.setattr(fill, "_SWEEP_CHUNK", chunk)
    rng = np.random.default_rng(11)
    h, w = 14, 17
    known = rng.random((h, w)) > 0.45
    known[0, :] = False
    known[:, -1] = False
    known[5:9, 4:10] = False
    val = np.where(known, rng.normal(10.0, 2.0, (h, w)), 0.0).astype(np.float32)
    coarse = rng.normal(10.0, 2.0, ((h + 1) // 2, (w + 1) // 2)).astype(np.float32)
    relax = (rng.random((h, w)) > 0.3) if use_relax else None
    got = fill._relax_level(known, val, coarse, 3, relax, omega)
    ref = _relax_reference(known, val, coarse, 3, relax, omega)
    np.testing.assert_array_equal(got, ref)


# --------------------------------------------------------------------------- find_edge_spikes
def _spikes(z, fill, tol=0.5, passes=3):
    return [tuple(int(v) for v in p) for p in np.argwhere(find_edge_spikes(z, fill, tol, passes=passes))]


def test_edge_spike_above_every_continuation():
    z = np.zeros((5, 7), np.float32)
    z[:, 4:] = 3.0                                  # an object on columns 4-6
    z[2, 3] = 1.0                                   # a raised cell at its edge: 1 m above every continuation
    assert _spikes(z, z > 2.0) == [(2, 3)]
    assert _spikes(z, z > 2.0, tol=1.0) == []       # not more than 1 m above them
    z[2, 3] = 0.4                                   # within the tolerance
    assert _spikes(z, z > 2.0) == []


def test_edge_spikes_never_on_a_plane():
    i, j = np.mgrid[0:12, 0:12]
    z = (0.7 * i - 0.9 * j).astype(np.float32)     # steep plane: every continuation is exact
    hole = (i >= 4) & (i < 8) & (j >= 3) & (j < 9)
    z[hole] += 5.0
    assert _spikes(z, hole) == []


def test_edge_spike_needs_two_known_cells_in_a_direction():
    z = np.full((5, 5), 5.0, np.float32)
    z[2, 2] = 1.0                                   # a lone known cell amid an object: no continuation
    assert _spikes(z, z > 2.0) == []
    z[2, 3] = 0.0                                   # one known neighbour: still no direction of two cells
    assert _spikes(z, z > 2.0) == []
    z[2, 4] = 0.0                                   # (2, 3), (2, 4) continue to 0 at (2, 2): 1 m below it;
    assert _spikes(z, z > 2.0) == [(2, 2)]          # (2, 4) is not raised by the bump two cells away


def test_edge_spike_passes_peel_a_skirt():
    z = np.zeros((7, 9), np.float32)
    z[:, 6:] = 5.0                                  # the object
    z[3, 5] = 2.0                                   # its skirt: 2 m at the edge,
    z[3, 4] = 0.6                                   # 0.6 m one cell further out
    hole = z > 4.0
    assert _spikes(z, hole, passes=1) == [(3, 5)]   # (3, 4) borders no cell to fill yet
    assert _spikes(z, hole, passes=2) == [(3, 4), (3, 5)]
    assert _spikes(z, hole, passes=3) == [(3, 4), (3, 5)]


def test_edge_spikes_ignore_nodata_and_refuse_bad_input():
    z = np.zeros((5, 7), np.float32)
    z[:, 4:] = np.nan                               # nodata, not to fill: no edge
    z[2, 3] = 1.0
    assert _spikes(z, np.zeros(z.shape, bool)) == []
    with pytest.raises(ValueError, match="tolerance_m"):
        find_edge_spikes(z, np.zeros(z.shape, bool), 0.0)
    with pytest.raises(ValueError, match="shape"):
        find_edge_spikes(z, np.zeros((2, 2), bool), 0.5)
    assert edge_spikes_reach(3) == 7


def test_edge_spikes_along_one_line_find_a_skirt_its_neighbours_continue():
    z = np.tile(0.05 * np.arange(9, dtype=np.float32), (7, 1))   # ground rising 5 cm a cell
    z[:, 6:] = 5.0                                  # the object
    z[1:6, 5] += 0.6                                # low vegetation along its edge: 0.6 m, five cells long
    hole = z > 4.0
    assert _spikes(z, hole) == []                   # each cell is continued by its neighbours along the edge
    got = find_edge_spikes(z, hole, 0.5, line_tolerance_m=0.5)
    assert [tuple(map(int, p)) for p in np.argwhere(got)] == [(r, 5) for r in range(1, 6)]
    assert not find_edge_spikes(z, hole, 0.5, line_tolerance_m=0.7).any()     # within that tolerance


def test_edge_spikes_along_one_line_need_two_heights_on_the_side_below():
    # ISPRS 21 at 1 m: ground cells 0.4-0.75 m above the continuation of a side whose two cells hold one
    # point's height (a cell without a point filled from its neighbour's): that continuation's slope is
    # unknown, its error not bounded by the tolerance of a continuation from two heights
    z = np.zeros((7, 9), np.float32)
    z[:, 0:3] = -0.3                                # points every two cells: columns 3-4 one height
    z[:, 6:] = 5.0                                  # the object
    z[1:6, 5] = 0.6                                 # the ground bending up along the object's edge
    hole = z > 4.0
    assert not find_edge_spikes(z, hole, 0.5, line_tolerance_m=0.5).any()
    z[:, 3] = -0.05                                 # two heights, 5 cm a cell: 0.55 m above their continuation
    got = find_edge_spikes(z, hole, 0.5, line_tolerance_m=0.5)
    assert [tuple(map(int, p)) for p in np.argwhere(got)] == [(r, 5) for r in range(1, 6)]


def test_edge_spikes_along_one_line_keep_a_terrace_edge_beside_an_object():
    z = np.zeros((8, 9), np.float32)
    z[:, 4:] = 2.0                                  # a terrace: lower level columns 0-3, upper 4-8
    z[0:3, 4] = 9.0                                 # an object on the upper edge
    hole = z > 4.0
    # (3, 4), beside the object on the upper edge, stands 2 m above the lower level's continuation;
    # the upper level continues it along every line
    assert not find_edge_spikes(z, hole, 0.5, line_tolerance_m=0.5).any()
    i, j = np.mgrid[0:12, 0:12]
    plane = (0.7 * i - 0.9 * j).astype(np.float32)
    box = (i >= 4) & (i < 8) & (j >= 3) & (j < 9)
    plane[box] += 5.0
    assert not find_edge_spikes(plane, box, 0.5, line_tolerance_m=0.5).any()  # never on a plane


def test_edge_spikes_along_one_line_include_the_spikes_of_every_line():
    rng = np.random.default_rng(5)
    z = rng.normal(0.0, 0.4, (40, 50)).astype(np.float32)
    hole = rng.random(z.shape) < 0.15
    old = find_edge_spikes(z, hole, 0.5, passes=1)
    new = find_edge_spikes(z, hole, 0.5, line_tolerance_m=0.5, passes=1)
    assert old.any() and (new & old).sum() == old.sum() and new.sum() > old.sum()
    with pytest.raises(ValueError, match="line_tolerance_m"):
        find_edge_spikes(z, hole, 0.5, line_tolerance_m=0.0)


def _sampled_bank(seed, rise=0.6, cell=2.0):
    """A bank face rising ``rise`` m a metre along the rows on ``cell`` m cells, each height taken at a random
    place in its cell (a lowest- or highest-point grid), beside a 3 m object: (z, hole)."""
    i, j = np.mgrid[0:12, 0:14]
    u = np.random.default_rng(seed).uniform(-0.5, 0.5, i.shape)      # where in its cell the point lies, cells
    z = (rise * cell * (j + u)).astype(np.float32)
    hole = (i >= 4) & (i < 8) & (j >= 5) & (j < 9)
    z[hole] += 3.0
    return z, hole


@pytest.mark.parametrize("seed", range(4))
def test_edge_spikes_allow_for_where_heights_lie_on_a_steep_bank(seed):
    # a bank steeper than the terrain's slope the tolerances assume (a dike's face at 2 m cells): the heights
    # scatter by up to 1.2 m about the face along its contour, which no continuation's tolerance of the fields
    # covers; with the sampling allowance (the rise beside each cell: 3 sigma of a continuation of heights
    # scattered by rise / sqrt(12) each) no face cell is a spike
    z, hole = _sampled_bank(seed)
    plain = find_edge_spikes(z, hole, 0.3, line_tolerance_m=0.3)
    assert plain.sum() > 10
    assert not find_edge_spikes(z, hole, 0.3, line_tolerance_m=0.3, sampling=(0.0, (2.0, 2.0), 0.5)).any()
    # the allowance at the sampled cells only (bareearth:dtm: the banks): the others as without it
    sampled = np.zeros(z.shape, bool)
    sampled[:, :7] = True
    got = find_edge_spikes(z, hole, 0.3, line_tolerance_m=0.3, sampling=(0.0, (2.0, 2.0), 0.5), sampled=sampled)
    assert not (got & sampled).any() and (got & ~sampled).any() and (plain & ~sampled).any()
    with pytest.raises(ValueError, match="sampled"):
        find_edge_spikes(z, hole, 0.3, sampling=(0.0, (2.0, 2.0), 0.5), sampled=sampled[:2])


def test_edge_spikes_sampling_allowance_keeps_skirts_on_level_and_allowed_slopes():
    # ground rising within the slope the tolerances already allow gets no allowance: a skirt is still found
    z = np.tile(0.05 * np.arange(9, dtype=np.float32), (7, 1))   # ground rising 5 cm a cell
    z[:, 6:] = 5.0                                  # the object
    z[3, 5] += 0.6                                  # a skirt cell at its edge
    hole = z > 4.0
    for sampling in (None, (0.05, (1.0, 1.0), 0.5)):
        got = find_edge_spikes(z, hole, 0.5, line_tolerance_m=0.5, sampling=sampling)
        assert [tuple(map(int, p)) for p in np.argwhere(got)] == [(3, 5)]
    # on level ground rising 0.1 m a cell that is not allowed for: 0.6 m stays above sqrt(0.5^2 + 4.5 0.1^2)
    z[:, :6] += 0.05 * np.arange(6, dtype=np.float32)
    got = find_edge_spikes(z, hole, 0.5, sampling=(0.0, (1.0, 1.0), 0.5))
    assert [tuple(map(int, p)) for p in np.argwhere(got)] == [(3, 5)]
    with pytest.raises(ValueError, match="sampling"):
        find_edge_spikes(z, hole, 0.5, sampling=(0.0, (1.0, 1.0), 0.0))


def test_edge_spikes_spared_cells_are_never_spikes_and_stay_sources():
    z = np.zeros((5, 7), np.float32)
    z[:, 4:] = 3.0
    z[2, 3] = 1.0                                    # a raised cell at the object's edge
    fill = z > 2.0
    assert find_edge_spikes(z, fill, 0.5)[2, 3]
    spared = np.zeros(z.shape, bool)
    spared[2, 3] = True
    assert not find_edge_spikes(z, fill, 0.5, spared=spared).any()
    with pytest.raises(ValueError, match="spared"):
        find_edge_spikes(z, fill, 0.5, spared=spared[:2])


def _edge_spikes_reference(z, fill, tolerance_m, line_tolerance_m=None, passes=3):
    """find_edge_spikes as first written: every pass looks for its cells over the whole raster
    (touching() of the cells to fill, then of the last pass's spikes) and tests them all at once."""
    from bare_earth.core.common import touching
    from bare_earth.core.fill import EDGE_LINES
    h, w = z.shape
    pad = 2
    wp = w + 2 * pad
    zp = np.full((h + 2 * pad, wp), np.nan, np.float32)
    core = zp[pad:-pad, pad:-pad]
    np.copyto(core, z)
    np.copyto(core, np.float32(np.nan), where=fill)
    found = np.zeros((h, w), bool)
    test = fill
    tol = np.float32(tolerance_m)
    line_tol = None if line_tolerance_m is None else np.float32(line_tolerance_m)
    flat = zp.ravel()
    for _ in range(passes):
        edge = touching(test) & np.isfinite(core)
        cand = np.flatnonzero(edge)
        if cand.size == 0:
            break
        r, c = np.divmod(cand, w)
        idx = (r + pad) * wp + (c + pad)
        zc = flat[idx]
        new = np.zeros(idx.size, bool)
        every = np.ones(idx.size, bool)
        seen = np.zeros(idx.size, bool)
        for di, dj in EDGE_LINES:
            res, slope_known = [], []
            for sgn in (1, -1):
                off = sgn * (di * wp + dj)
                z1, z2 = flat[idx + off], flat[idx + 2 * off]
                cont = np.maximum(2 * z1 - z2, z1)
                res.append(zc - cont)
                slope_known.append(z1 != z2)
            a, b = res
            seen |= np.isfinite(a) | np.isfinite(b)
            every &= ~(a <= tol) & ~(b <= tol)
            if line_tol is not None:
                above = ((a > line_tol) & slope_known[0]) | ((b > line_tol) & slope_known[1])
                new |= ~(a <= line_tol) & ~(b <= line_tol) & above
        new |= every & seen
        if not new.any():
            break
        test = np.zeros((h, w), bool)
        test[r[new], c[new]] = True
        found |= test
        flat[idx[new]] = np.nan
    return found


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("chunk", [7, 1 << 16])
@pytest.mark.parametrize("threads", [False, True])
def test_edge_spikes_chunks_and_local_passes_equal_whole_raster_passes(monkeypatch, seed, chunk, threads):
    """The chunked test (in parallel or not) and the later passes' cells gathered around the last spikes
    give the whole-raster passes' spikes exactly, with and without the test along one line, on rough
    skirts whose spikes are peeled over several passes and at the raster's edges and nodata."""
    from concurrent.futures import ThreadPoolExecutor

    from bare_earth.core import fill
    monkeypatch.setattr(fill, "EDGE_CHUNK", chunk)
    rng = np.random.default_rng(seed)
    h, w = 37, 53
    z = rng.normal(0.0, 0.3, (h, w)).astype(np.float32)
    hole = rng.random(z.shape) < 0.08
    hole[10:20, 15:35] = True
    z[9:21, 14:36] += rng.random((12, 22)).astype(np.float32) * 2.0      # a skirt around the object
    z[rng.random(z.shape) < 0.03] = np.nan
    pool = ThreadPoolExecutor(max_workers=1) if threads else None
    try:
        for line in (None, 0.6):
            for passes in (1, 2, 3, 5):
                ref = _edge_spikes_reference(z, hole, 0.4, line, passes)
                got = find_edge_spikes(z, hole, 0.4, line_tolerance_m=line, passes=passes, pool=pool)
                np.testing.assert_array_equal(got, ref)
            assert ref.any() and not np.array_equal(ref, _edge_spikes_reference(z, hole, 0.4, line, 1))
    finally:
        if pool is not None:
            pool.shutdown()
