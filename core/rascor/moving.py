"""RASCOR steps 5-7: moving local profiles, moving surfaces, local prediction.

Jacobsen (2004): every height is compared with the leave-one-out least-squares fit of its
neighbourhood (profile, surface window, Gaussian-weighted plane) by data snooping, the
model chosen by the terrain class; points below the fit get the weight factor
``low_weight`` instead of removal.
"""
from typing import Callable, Optional, Sequence, Tuple, Union

import numpy as np

from ..common import as_cell_size, sub_progress, transpose
from .fits import fit_and_snoop, fit_at_centre, fit_box_2d, fit_rows, snoop_block_fits
from .kernels import block_window, gauss_weights, odd_window
from .terrain import model_degree

#: Cells per tile (halo included) of the polynomial surface: 65 m windows took 0.8-0.9 s a
#: tile on the shared 2-core machine under a load of 6.5.
_POLY_TILE_CELLS = 1 << 17


def remove_profile_outliers(z: np.ndarray, cell_size: Union[float, Sequence[float]], keep: np.ndarray, *,
                            lengths_m: Sequence[float], terrain_class: str, scale_m: float,
                            k: float = 4.0, low_weight: float = 0.02, iterations: int = 1,
                            test: Optional[np.ndarray] = None, labels: Optional[np.ndarray] = None,
                            homogeneous: bool = True, z_t: Optional[np.ndarray] = None,
                            progress: Optional[Callable[[float], None]] = None,
                            profile_labels: Optional[Tuple[np.ndarray, np.ndarray]] = None
                            ) -> Tuple[np.ndarray, np.ndarray]:
    """Step 5: moving local profiles in X and Y, short then long, with data snooping.

    For each length of ``lengths_m`` and each direction, every height is compared with the
    leave-one-out fit of the profile through the remaining points in its window: the mean
    (flat), a linear regression (rolling) or a 2nd-order polynomial (mountainous terrain).
    The test is Baarda's data snooping ``v / (scale sqrt(1/p + h)) > k`` with the actual
    positions of the remaining points (``h`` grows where earlier steps left gaps); points
    below the fit get the weight factor ``p = low_weight`` in the next fit and are removed
    (class 2) only beyond ``-k``. ``iterations`` fits per length and direction.

    Parameters
    ----------
    lengths_m : sequence of float
        Profile lengths in metres, applied in order (short first).
    terrain_class : {"flat", "rolling", "mountainous"}
    homogeneous : bool
        False upgrades the flat model to linear (:func:`model_degree`).
    scale_m : float
        Standard deviation of a height about the profile model (random error + model
        error), from the analysis of the sequence of lengths.
    test : ndarray of bool, optional
        Cells that may be removed (default ``keep``); others only support the fits.
    z_t : ndarray, optional
        ``transpose(z)`` when the caller has it (made here otherwise).
    progress : callable, optional
        ``progress(fraction)``, called every band of rows; it may raise ``Cancelled``.
    profile_labels : (ndarray, ndarray), optional
        The regions of the X profiles (shaped as ``z``) and of the Y profiles (shaped as its
        transpose, along whose rows they run), instead of ``labels`` for both:
        :func:`~.regions.profile_runs`, whose runs stop at every break-line cell even where the
        line does not close its region (a profile never crosses a break line).

    Returns
    -------
    high, low : ndarray of bool
    """
    dx, dy = as_cell_size(cell_size)
    degree = model_degree(terrain_class, homogeneous)
    test = keep if test is None else test & keep
    cur = keep.copy()
    high = np.zeros(z.shape, bool)
    low = np.zeros(z.shape, bool)
    # Y profiles run along the rows of the transposed arrays
    views = [(z, labels, dx, None), (transpose(z) if z_t is None else z_t, None if labels is None else
                                     transpose(labels), dy, transpose)]
    if profile_labels is not None:
        views = [(z, profile_labels[0], dx, None), (views[1][0], profile_labels[1], dy, transpose)]
    n_fits = len(lengths_m) * len(views) * iterations
    i_fit = 0
    for L in lengths_m:
        for zz, lab, step, tr in views:
            fwd = tr or (lambda a: a)
            size = odd_window(L / step, 3)

            def fit(zr, wr, out, size=size):
                return fit_rows(zr, wr, size, degree) if degree <= 1 else \
                    fit_at_centre(zr, wr, size, degree)

            below = None
            c, t = fwd(cur), fwd(test & cur)
            for _ in range(iterations):
                hi, lo, below = fit_and_snoop(zz, c, t, below, fit, scale_m, k, low_weight, labels=lab,
                                               reach_cols=size // 2, progress=sub_progress(progress, i_fit / n_fits,
                                                                     (i_fit + 1) / n_fits))
                i_fit += 1
                gone = hi | lo
                c &= ~gone
                t &= ~gone
                _or_into(high, hi, tr is not None)
                _or_into(low, lo, tr is not None)
            cur &= ~(high | low)
    return high, low


def _or_into(dst, src, transposed):
    """``dst |= src`` (``src.T`` when ``transposed``; a sparse ``src`` by its indices)."""
    if not transposed:
        dst |= src
        return
    idx = np.flatnonzero(src)
    if idx.size > src.size // 64:
        dst |= transpose(src)
    elif idx.size:
        r, c = np.divmod(idx, src.shape[1])
        dst[c, r] = True


# ------------------------------------------------------------------- step 6
def remove_surface_outliers(z: np.ndarray, cell_size: Union[float, Sequence[float]], keep: np.ndarray, *,
                            size_m: float, terrain_class: str, scale_m: float, k: float = 4.0,
                            low_weight: float = 0.02, iterations: int = 1,
                            test: Optional[np.ndarray] = None, labels: Optional[np.ndarray] = None,
                            homogeneous: bool = True, per_block: bool = False,
                            progress: Optional[Callable[[float], None]] = None
                            ) -> Tuple[np.ndarray, np.ndarray]:
    """Step 6: moving surfaces: horizontal plane, inclined plane or polynomial.

    Every height is compared with the leave-one-out weighted least-squares surface of its
    ``size_m`` x ``size_m`` window (horizontal plane in flat, inclined plane in rolling,
    2nd-order polynomial in mountainous terrain), with the same data snooping and weight
    factor as :func:`remove_profile_outliers`. Windows never reach across a break line.
    A flat but inhomogeneous area gets the inclined plane (:func:`model_degree`). In
    mountainous terrain (the polynomial) the windows run in tiles of bounded work.
    ``per_block``: windows of at least 32 cells a side (horizontal or inclined plane, no break
    lines) fitted once per block of cells, each cell tested against the leave-one-out fit of the
    window centred on its block (:func:`~.fits.snoop_block_fits`, float32 on centred heights).
    ``progress(fraction)`` is called every band or tile (it may raise ``Cancelled``).

    Returns
    -------
    high, low : ndarray of bool
    """
    dx, dy = as_cell_size(cell_size)
    degree = model_degree(terrain_class, homogeneous)
    sizes = (odd_window(size_m / dy, 3), odd_window(size_m / dx, 3))
    blocks = (per_block and degree <= 1 and labels is None
              and max(block_window(sizes[0])[0], block_window(sizes[1])[0]) > 1)
    test = keep if test is None else test & keep
    cur = keep.copy()
    high = np.zeros(z.shape, bool)
    low = np.zeros(z.shape, bool)
    below = None
    work = {}                                   # scratch arrays reused by every band

    def fit(zz, ww, out):
        return fit_box_2d(zz, ww, sizes, degree, out, work) if degree <= 1 else \
            tuple(a[out] for a in fit_at_centre(zz, ww, sizes, degree))

    # the polynomial's centred sums cost O(window) per cell: tiles of bounded work
    tiles = {} if degree <= 1 else dict(halo_cols=sizes[1] // 2, tile_cells=_POLY_TILE_CELLS)
    for i in range(iterations):
        part = sub_progress(progress, i / iterations, (i + 1) / iterations)
        if blocks:
            hi, lo, below = snoop_block_fits(z, cur, test & cur, below, sizes, degree, scale_m, k, low_weight,
                                             progress=part)
        else:
            hi, lo, below = fit_and_snoop(z, cur, test & cur, below, fit, scale_m, k, low_weight,
                                           halo=sizes[0] // 2, labels=labels, reach_cols=sizes[1] // 2, work=work,
                                           **tiles, progress=part)
        high |= hi
        low |= lo
        cur &= ~(hi | lo)
    return high, low


def remove_prediction_outliers(z: np.ndarray, cell_size: Union[float, Sequence[float]], keep: np.ndarray, *,
                               radius_m: float, scale_m: float, k: float = 4.0,
                               low_weight: float = 0.02, test: Optional[np.ndarray] = None,
                               labels: Optional[np.ndarray] = None, progress: Optional[Callable[[float], None]] = None
                               ) -> Tuple[np.ndarray, np.ndarray]:
    """Step 7: final local prediction (least-squares interpolation from the neighbourhood).

    Each height is predicted from the remaining points within ``radius_m`` by a weighted
    least-squares inclined plane with Gaussian (covariance-like) weights, itself excluded,
    and tested as in :func:`remove_profile_outliers`. ``progress(fraction)`` is called
    every band of rows (it may raise ``Cancelled``).

    Returns
    -------
    high, low : ndarray of bool
    """
    dx, dy = as_cell_size(cell_size)
    kernels = (gauss_weights(radius_m / dy), gauss_weights(radius_m / dx))
    test = keep if test is None else test & keep
    sizes = (len(kernels[0]), len(kernels[1]))

    def fit(zz, ww, out):
        return tuple(a[out] for a in fit_at_centre(zz, ww, sizes, 1, kernels=kernels))

    hi, lo, _ = fit_and_snoop(z, keep, test, None, fit, scale_m, k, low_weight,
                               halo=sizes[0] // 2, labels=labels, reach_cols=sizes[1] // 2, progress=progress)
    return hi, lo




# ------------------------------------------------- step 5: the terrain's slope breaks
def slope_breaks(z: np.ndarray, keep: np.ndarray, candidates: np.ndarray, *, scale_m: float, k: float = 4.0,
                 max_run: int = 1, labels: Optional[np.ndarray] = None) -> np.ndarray:
    """The cells of ``candidates`` standing where the slopes on both sides of them meet: a
    crest, a ridge or the shoulder of a bank, not an object on the ground.

    Along the rows or along the columns, a run of at most ``max_run`` candidates lies between
    two kept cells on each side (``a1, a2`` before it, ``b1, b2`` after it, nearest first; all
    four kept and in the run's break-line region). Each side's line extrapolates into the run,
    ``ea(d) = a1 + d (a1 - a2)`` at ``d`` cells from ``a1`` (``eb`` likewise from ``b1``). The run
    is a break of the terrain's slope when

    * both sides rise towards it: their mean rise ``((a1 - a2) + (b1 - b2)) / 2``, the bend that
      a fit of the neighbours misses at a crest, exceeds ``k scale`` (it has the variance of
      one height: a spike on level ground has none);
    * each of its heights lies on the lower of the two lines and not below the chord
      ``a1 -> b1``, within ``k`` standard deviations of each difference (independent heights
      of standard deviation ``scale``): two slopes meeting at a crest sharp against the cell;
      a crown or a roof stands metres above the line of the ground beside it, and a crown whose
      rising edges were kept lies metres below the lines of those edges.

    Jacobsen's (2004) moving profiles compare a height with the fit of its neighbours, which
    at a crest of the terrain sharp against the cell (a dune's brink, a gully's or a dike's
    shoulder at 2-4 m cells) lies below it by half the change of slope times the cell; the
    paper leaves such lines to break lines. Only the candidates are tested.

    Parameters
    ----------
    z : ndarray
        Heights (NaN nodata).
    keep : ndarray of bool
        The points kept (the only ones read besides the candidates).
    candidates : ndarray of bool
        The cells tested (those a moving profile removed).
    scale_m : float
        Standard deviation of a height about the profile (step 5's scale).
    k : float
        Critical value (step 5's snooping ``k``).
    max_run : int
        Longest run of candidates (cells) tested along a row or a column: the half window of
        step 5's longest profile, the reach of a crest's bend in its fits.
    labels : ndarray of int, optional
        Break-line regions: no line crosses from one region to another.

    Returns
    -------
    ndarray of bool
        The candidates that are slope breaks.

    References
    ----------
    Jacobsen, K. (2004). DSM and DEM from space and aerial imagery: program RASCOR. ISPRS
    Archives XXXV-B3.
    """
    out = np.zeros(z.shape, bool)
    if max_run < 1 or not candidates.any():
        return out
    # the candidates are few: the columns are read through the flat indices of the transposed
    # raster (no transposed copy of the heights, the points kept and the regions)
    rows, cols = z.shape
    idx = np.flatnonzero(candidates)
    r, c = np.divmod(idx, cols)
    for view, tr in ((idx, False), (np.sort(c * rows + r), True)):
        good = _runs_between_slopes(z, keep, view, tr, scale_m, k, int(max_run), labels)
        out.reshape(-1)[good] = True
    return out


def _runs_between_slopes(z, keep, idx, transposed, scale, k, max_run, labels):
    """:func:`slope_breaks` along the rows of ``z`` (of its transpose when ``transposed``): ``idx``
    the candidates' flat indices in that view, increasing; the flat indices in ``z`` of the
    candidates of the runs that pass."""
    rows, cols = z.shape[::-1] if transposed else z.shape
    if not idx.size:
        return idx
    r, c = np.divmod(idx, cols)
    new = np.ones(idx.size, bool)
    new[1:] = (np.diff(idx) != 1) | (r[1:] != r[:-1])
    run = np.cumsum(new) - 1
    first = np.flatnonzero(new)
    last = np.r_[first[1:], idx.size] - 1
    n = last - first + 1
    s, e, rr = c[first], c[last], r[first]
    ok = (n <= max_run) & (s >= 2) & (e + 2 < cols)
    s, e = np.clip(s, 2, cols - 1), np.clip(e, 0, cols - 3)
    zf = z.reshape(-1)
    def at(q):                                          # the view's flat index -> z's
        return (q % cols) * rows + q // cols if transposed else q
    base = rr * cols
    pos = [at(base + s - 2), at(base + s - 1), at(base + e + 1), at(base + e + 2)]
    idx = at(idx)
    kf = keep.reshape(-1)
    for p in pos:
        ok &= kf[p]
        if labels is not None:
            ok &= labels.reshape(-1)[p] == labels.reshape(-1)[idx[first]]
    a2, a1, b1, b2 = (zf[p].astype(np.float64) for p in pos)
    with np.errstate(invalid="ignore"):
        ok &= ((a1 - a2) + (b1 - b2)) / 2.0 > k * scale
        # each cell of the runs still passing (few: an object's runs are longer): d cells after a1,
        # n + 1 - d before b1
        cells = np.flatnonzero(ok[run])
        run, c, idx = run[cells], c[cells], idx[cells]
        d = (c - s[run] + 1).astype(np.float64)
        m = (n[run] + 1 - d)
        zc = zf[idx].astype(np.float64)
        ea = a1[run] + d * (a1[run] - a2[run])
        eb = b1[run] + m * (b1[run] - b2[run])
        t = d / (n[run] + 1)
        chord = a1[run] + t * (b1[run] - a1[run])
        tol_a = k * scale * np.sqrt(1.0 + (1.0 + d) ** 2 + d ** 2)
        tol_b = k * scale * np.sqrt(1.0 + (1.0 + m) ** 2 + m ** 2)
        tol_c = k * scale * np.sqrt(1.0 + (1.0 - t) ** 2 + t ** 2)
        on_line = np.where(ea <= eb, np.abs(zc - ea) <= tol_a, np.abs(zc - eb) <= tol_b)
        cell_ok = on_line & (zc >= chord - tol_c)
    ok &= np.bincount(run, weights=~cell_ok, minlength=first.size) == 0
    return idx[ok[run]]
