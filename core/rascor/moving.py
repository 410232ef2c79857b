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
                            progress: Optional[Callable[[float], None]] = None
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
                                               progress=sub_progress(progress, i_fit / n_fits,
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
                                           halo=sizes[0] // 2, labels=labels, work=work, **tiles, progress=part)
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
                               halo=sizes[0] // 2, labels=labels, progress=progress)
    return hi, lo


