"""RASCOR kernels: band planning, window sums and the small normal-equation solvers.

The building blocks of the moving fits (:mod:`.fits`) of Jacobsen's (2004) RASCOR steps
5-7: running box sums and centred power sums ``sum v[c+k] k^p`` along one axis, the
first unknown and ``(N^-1)_00`` of stacked symmetric systems, and the bands of rows the
banded kernels work in so their temporaries stay in the cache.
"""
import numpy as np
from scipy import ndimage

from ..common import running_mean_down


def odd_window(n, minimum=3):
    """``n`` rounded to an odd window length of at least ``minimum`` cells."""
    n = max(int(round(n)), minimum)
    return n if n % 2 else n + 1


def power_sums(v, size, powers, axis):
    """``{p: sum_{k=-h..h} v[c+k] k**p}`` along ``axis`` for every centre ``c``.

    Exact centred correlations, O(size) per cell: each cell's sum is made of the same
    products in the same order wherever the array starts, so a block gives the same sums
    as one pass, bit for bit. (A running box sum, or box sums of ``v x**j`` on absolute
    positions ``x`` combined binomially, would be O(1) per cell, but their rounding
    depends on the cells before, and grows with ``|x|**p``, ``x`` counted from the array's
    centre: on a 865-column DSM the degree-2 profile moved by up to 3e-4 m between a block
    and one pass.)
    """
    h = size // 2
    k = np.arange(-h, h + 1, dtype=np.float64)
    return {p: ndimage.correlate1d(v, k ** p, axis=axis, mode="constant", cval=0.0)
            for p in sorted(set(powers))}


def solve3_first(a, r):
    """First unknown and ``(N^-1)_00`` of symmetric 3x3 systems given element-wise."""
    (a00, a01, a02), (_, a11, a12), (_, _, a22) = a
    c00 = a11 * a22 - a12 * a12
    c01 = a12 * a02 - a01 * a22
    c02 = a01 * a12 - a11 * a02
    det = a00 * c00 + a01 * c01 + a02 * c02
    num = r[0] * c00 + r[1] * c01 + r[2] * c02
    ok = det > 1e-9 * np.abs(a00 * a11 * a22)
    with np.errstate(all="ignore"):
        return np.where(ok, num / det, np.nan), np.where(ok, c00 / det, np.nan)


def solve_first_general(M, Z, n_unknowns):
    """First unknown and ``(N^-1)_00`` of stacked symmetric positive systems.

    Vectorised Cholesky factorisation over all cells at once (arrays of cells, a loop over
    the few matrix elements; in chunks of cells, so the many temporaries stay in the
    cache), on the system scaled to a unit diagonal; a pivot below 1e-9 marks a system the
    window's points do not determine (NaN).
    """
    shape = M[0][0].shape
    beta = np.full(shape, np.nan)
    hh = np.full(shape, np.nan)
    with np.errstate(all="ignore"):
        ok = np.isfinite(M[0][0]) & (M[0][0] > 0)
        for i in range(n_unknowns):
            ok &= M[i][i] > 0
        cells = np.flatnonzero(ok)
        u = n_unknowns
        Mf = [[M[i][j].ravel() for j in range(u)] for i in range(u)]
        Zf = [Z[i].ravel() for i in range(u)]
        for c0 in range(0, cells.size, BAND_CELLS):
            idx = cells[c0:c0 + BAND_CELLS]
            d = [np.sqrt(Mf[i][i][idx]) for i in range(u)]
            A = [[Mf[i][j][idx] / (d[i] * d[j]) for j in range(u)] for i in range(u)]
            r = [Zf[i][idx] / d[i] for i in range(u)]
            L = [[None] * u for _ in range(u)]
            good = np.ones(idx.size, bool)
            for j in range(u):
                s = A[j][j]
                for k in range(j):
                    s -= L[j][k] * L[j][k]
                good &= s > 1e-9
                L[j][j] = np.sqrt(np.where(s > 1e-9, s, 1.0))
                for i in range(j + 1, u):
                    t = A[i][j]
                    for k in range(j):
                        t -= L[i][k] * L[j][k]
                    L[i][j] = t / L[j][j]
            # forward substitution for the right-hand side and for e0
            y = [None] * u
            e = [None] * u
            for i in range(u):
                t = r[i]
                q = np.full(idx.size, 1.0) if i == 0 else np.zeros(idx.size)
                for k in range(i):
                    t -= L[i][k] * y[k]
                    q -= L[i][k] * e[k]
                y[i] = t / L[i][i]
                e[i] = q / L[i][i]
            b = [None] * u
            for i in range(u - 1, -1, -1):
                t = y[i]
                for k in range(i + 1, u):
                    t -= L[k][i] * b[k]
                b[i] = t / L[i][i]
            h0 = sum(ek * ek for ek in e)
            beta.ravel()[idx[good]] = (b[0] / d[0])[good]
            hh.ravel()[idx[good]] = (h0 / (d[0] * d[0]))[good]
    return beta, hh


#: Cells per band of the banded kernels: their many temporaries (256 kB of float64 each)
#: stay in the core's cache, and no full-size temporary is allocated per moment. Steps 3
#: and 4 (few passes per band) take bands 4 and 16 times larger.
BAND_CELLS = 1 << 15
#: Cells per band (halo included) of the window fits run in bands of rows with a halo.
HALO_BAND_CELLS = 1 << 20


def row_bands(rows, cols, cells=None):
    """Row slices of about ``cells`` (default :data:`BAND_CELLS`) cells covering ``rows``
    rows."""
    step = max(1, (cells or BAND_CELLS) // max(1, cols))
    return [slice(r0, min(rows, r0 + step)) for r0 in range(0, rows, step)]


def scratch_arrays(work, key, n, shape):
    """``n`` float64 scratch arrays of ``shape``: views of arrays kept in the dict ``work``
    (allocated once, reused by the next bands; new arrays without ``work``)."""
    if work is None:
        return [np.empty(shape) for _ in range(n)]
    a = work.get(key)
    if a is None or a.shape[1] < shape[0] or a.shape[2] != shape[1]:
        a = work[key] = np.empty((n,) + shape)
    return [b[:shape[0]] for b in a]


def running_mean(v, size, axis, out=None):
    """Mean of ``v`` (float64) over a centred window of ``size`` (odd) cells along
    ``axis``; 0 outside. Down the columns of a 2-D array, SciPy's sums along whole rows
    (:func:`~..common.running_mean_down`, bit for bit)."""
    if out is None:
        out = np.empty(v.shape, np.float64)
    if axis == 0 and np.ndim(v) == 2:
        return running_mean_down(v, size, out, mode="constant")
    return ndimage.uniform_filter1d(v, size, axis=axis, mode="constant", cval=0.0, output=out)


def centred_moments(x, s0, s1, s2=None):
    """Turn window sums on absolute positions into sums on positions relative to the
    centre ``x``: ``sum w (x' - x) = s1 - x s0``, ``sum w (x' - x)^2 = s2 - x (2 s1 - x s0)``
    (in place in ``s1``, ``s2``)."""
    t = np.multiply(s0, x)
    if s2 is not None:
        u = np.multiply(s1, 2.0)
        u -= t
        u *= x
        s2 -= u
    s1 -= t



def finite_float64(z):
    """``z`` as float64 with 0 in place of NaN (the fits need finite heights everywhere;
    the cells concerned have weight 0 and are never tested)."""
    z = np.array(z, dtype=np.float64)
    np.copyto(z, 0.0, where=~np.isfinite(z))
    return z


def gauss_weights(radius_cells):
    """Gaussian window weights reaching ``radius_cells`` (step 7's covariance-like weights)."""
    r = max(1, int(np.ceil(radius_cells)))
    x = np.arange(-r, r + 1.0)
    return np.exp(-0.5 * (x / max(radius_cells / 2.0, 0.5)) ** 2)


#: Blocks across a window of the block fits (:func:`block_window`): the window a cell is
#: tested against is centred on its block, at most ``1 / (2 x 16)`` of the window from the
#: cell (1 m of a 65 m window at 2 m blocks).
BLOCKS_PER_WINDOW = 16
#: Largest block of the block fits, cells: a power of two dividing every window corner of a
#: blocked run (:data:`~bare_earth.core.blocks.MIN_ALIGN`), so blocks see the single pass's grid.
MAX_FIT_BLOCK = 64


def block_window(size, ratio=BLOCKS_PER_WINDOW):
    """Block and window of a moving fit of ``size`` cells computed once per block.

    Returns ``(q, n)``: blocks of ``q`` cells, the largest power of two (at most
    :data:`MAX_FIT_BLOCK`) with ``q <= size / ratio``, and the odd number ``n`` of blocks whose
    span ``n q`` is nearest ``size`` (``(1, size)``: windows too short, one cell per block).

    Examples
    --------
    >>> block_window(65), block_window(25), block_window(129)
    ((4, 17), (1, 25), (8, 17))
    """
    size = int(size)
    q = 1
    while 2 * q <= size / ratio and 2 * q <= MAX_FIT_BLOCK:
        q *= 2
    if q == 1:
        return 1, size
    return q, 2 * int(round((size / q - 1) / 2)) + 1


def block_reach(size, ratio=BLOCKS_PER_WINDOW):
    """Farthest a block fit of a ``size``-cell window (:func:`block_window`) reaches from a
    cell, cells: half the window from the block's centre, plus half a block."""
    q, n = block_window(size, ratio)
    return (n * q) // 2 + q // 2
