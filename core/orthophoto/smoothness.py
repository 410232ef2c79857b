"""The roughness of a DEM and the smooth correction that does not raise it (a smoothness prior).

Roughness is the spread of the 5-point Laplacian (``scipy.ndimage.laplace``, mirrored at the
raster's edge) over a set of cells: speckle and new hills raise it. :func:`project_smooth`
replaces a smooth correction by the field nearest to it, weighted by its certainty, under
which the corrected DEM is no rougher than a budget: the Tikhonov-regularised projection
(Tikhonov & Arsenin 1977; the smoothness prior of DEM refinement)

    (W + mu C) s' = W s - mu C z_b,      C = L^T P L,

``z_b`` the DEM the correction is added to, ``P`` the centring on the measured cells (so the
constrained quantity is exactly the Laplacian's variance there), ``mu >= 0`` the smallest that
meets the budget (found by bisection in log space; each system solved by conjugate gradients,
matrix-free). ``mu = 0`` when the correction already meets it: then nothing changes.
"""
import math

import numpy as np
from scipy import ndimage
from scipy.sparse.linalg import LinearOperator, cg

__all__ = ["laplacian", "roughness_cells", "roughness", "roughness_sd", "project_smooth"]

#: Relative width at which the bisection on mu stops (mu_hi / mu_lo).
MU_RATIO = 1.01
#: Most conjugate-gradient iterations of one solve (each result is checked against the budget
#: as it is, so an unfinished solve costs optimality, never the bound; warm starts carry on).
MAX_CG = 100


def laplacian(z):
    """The 5-point Laplacian of ``z`` (float64; NaN cells filled with the median, edges mirrored)."""
    z = np.asarray(z)
    return ndimage.laplace(np.where(np.isfinite(z), z, np.nanmedian(z)).astype(np.float64))


def roughness_cells(seen):
    """The cells whose Laplacian is measured: ``seen`` eroded by two cells (their stencil inside it)."""
    seen = np.asarray(seen, bool)
    return seen & ndimage.binary_erosion(seen, iterations=2)


def roughness(z, cells):
    """Centred sum of squares of the Laplacian of ``z`` over ``cells`` (``n`` times its variance)."""
    v = laplacian(z)[cells]
    return float(np.sum((v - v.mean()) ** 2)) if v.size else 0.0


def roughness_sd(z, cells):
    """The Laplacian's standard deviation over ``cells`` (m per cell^2): the roughness measured."""
    v = laplacian(z)[cells]
    return float(np.std(v)) if v.size else 0.0


def _centred(x, cells):
    """``P x``: ``x`` on ``cells`` minus its mean there, 0 elsewhere."""
    out = np.zeros_like(x)
    v = x[cells]
    out[cells] = v - v.mean()
    return out


def project_smooth(base, smooth, weight, free, cells, budget, finish=None, tol=1e-6):
    """The smooth correction nearest to ``smooth`` under which ``finish(base + s')`` meets ``budget``.

    Minimises ``sum weight (s' - smooth)**2`` over the ``free`` cells (``s' = 0`` elsewhere)
    subject to ``roughness(finish(base + s'), cells) <= budget``: the Lagrangian's
    stationary point ``(W + mu C) s' = W smooth - mu C base`` (``C = L P L``, ``L`` the
    Laplacian, symmetric with mirrored edges; ``P`` the centring on ``cells``) for the
    smallest ``mu`` that meets the budget, by bisection on ``log mu`` to a ratio
    :data:`MU_RATIO` (the roughness falls as ``mu`` grows). Each system is solved by
    conjugate gradients with a Jacobi preconditioner on the whole grid (memory of a few
    rasters). When ``smooth`` itself meets the budget, it is returned unchanged (``mu = 0``).
    A solve that does not converge within :data:`MAX_CG` iterations ends the search (larger
    ``mu`` are only harder); then, or when no ``mu`` meets the budget (a ``finish`` that clips
    can cost what the projection saved), the correction is shrunk as a whole instead,
    ``s' = a smooth`` with the largest ``a`` in [0, 1] that meets it (bisection; a uniform
    shrink adds no curvature of its own; ``a = 0`` meets it when ``finish(base)`` does).

    Parameters
    ----------
    base : ndarray
        The DEM the correction is added to (float64).
    smooth : ndarray
        The smooth correction (0 where none).
    weight : ndarray
        Its certainty, > 0 on the free cells.
    free : ndarray of bool
        Cells the correction may move.
    cells : ndarray of bool
        Cells whose Laplacian is measured (:func:`roughness_cells`).
    budget : float
        Largest allowed :func:`roughness` (a centred sum of squares).
    finish : callable, optional
        Maps a candidate DEM to the one returned (clip to bounds, cast); default identity.

    Returns
    -------
    dem : ndarray
        ``finish(base + s')``.
    info : dict
        ``mu`` (``inf`` when the whole correction was shrunk), ``shrink`` (``a``, 1 unless
        shrunk), ``roughness_in`` (with ``smooth`` as given) and ``roughness_out`` (the
        returned DEM), ``solves`` (conjugate-gradient solves), ``iterations`` (in all).
    """
    if finish is None:
        def finish(z):
            return z
    base = np.asarray(base, np.float64)
    smooth = np.where(free, np.nan_to_num(np.asarray(smooth, np.float64)), 0.0)
    first = finish(base + smooth)
    r_in = roughness(first, cells)
    info = dict(mu=0.0, shrink=1.0, roughness_in=r_in, roughness_out=r_in, solves=0, iterations=0)
    if r_in <= budget:
        return first, info
    shape, n = base.shape, base.size
    w = np.where(free, np.asarray(weight, np.float64), 1.0)
    fmask = free.astype(np.float64)
    zb = np.where(np.isfinite(base), base, np.nanmedian(base))

    def curv(x):
        return ndimage.laplace(_centred(ndimage.laplace(x), cells))

    # Jacobi preconditioner: the diagonal of C is about the sum of the squared stencil over cells
    cdiag = ndimage.correlate(cells.astype(np.float64), np.array([[0, 1, 0], [1, 16, 1], [0, 1, 0]], float),
                              mode="constant") * fmask
    c_base = curv(zb) * fmask
    state = dict(x=smooth.ravel().copy())

    def solve(mu):
        def matvec(v):
            v = v.reshape(shape)
            return (w * v + mu * fmask * curv(fmask * v)).ravel()
        op = LinearOperator((n, n), dtype=np.float64, matvec=matvec)
        pre = LinearOperator((n, n), dtype=np.float64, matvec=lambda v: v / (w.ravel() + mu * cdiag.ravel()))
        rhs = (w * smooth - mu * c_base).ravel()
        count = [0]

        def step(_):
            count[0] += 1
        x, fail = cg(op, rhs, x0=state["x"], tol=tol, atol=0.0, M=pre, maxiter=MAX_CG, callback=step)
        state["x"] = x
        info["solves"] += 1
        info["iterations"] += count[0]
        s = np.where(free, x.reshape(shape), 0.0)
        out = finish(base + s)
        return roughness(out, cells), out, fail != 0

    # first guess from the linearised constraint: R falls by about 2 mu |C (z_b + s)|^2_W^-1
    g = curv(zb + smooth) * fmask
    gg = float(np.sum(g * g / w))
    mu = (r_in - budget) / (2.0 * gg) if gg > 0 else 1.0
    mu = mu if np.isfinite(mu) and mu > 0 else 1.0
    lo, hi, best, stuck = None, None, None, False
    for _ in range(40):                                  # bracket: factors of 10
        r, out, stuck = solve(mu)
        if stuck:
            break
        if r <= budget:
            hi, best = mu, (r, out)
            if lo is not None:
                break
            mu /= 10.0
        else:
            lo = mu
            if hi is not None:
                break
            mu *= 10.0
    if hi is None:                         # no mu met it, or too costly to find: shrink as a whole
        return _shrink(base, smooth, cells, budget, finish, info)
    if lo is not None:
        while hi / lo > MU_RATIO:
            mid = math.sqrt(lo * hi)
            r, out, _ = solve(mid)
            if r <= budget:
                hi, best = mid, (r, out)
            else:
                lo = mid
    info.update(mu=hi, roughness_out=best[0])
    return best[1], info


def _shrink(base, smooth, cells, budget, finish, info):
    """``finish(base + a smooth)`` with the largest ``a`` in [0, 1] meeting ``budget`` (bisection)."""
    lo, hi = 0.0, 1.0
    best = finish(base)
    r_best = roughness(best, cells)
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        out = finish(base + mid * smooth)
        r = roughness(out, cells)
        if r <= budget:
            lo, best, r_best = mid, out, r
        else:
            hi = mid
    info.update(mu=math.inf, shrink=lo, roughness_out=r_best)
    return best, info
