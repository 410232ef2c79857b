"""The 8-parameter bilinear transformation between DEM and orthophoto coordinates (eq. 17).

When the orientation of the images is not known but orthophotos are (made elsewhere, e.g.
with an older DEM), Luong Chinh Ke (2002, section 2.3, eq. 17) relates the DEM grid
coordinates ``(X, Y)`` and the orthophoto coordinates ``(x, y)`` by

    x = a0 + a1 X + a2 Y + a3 X Y
    y = b0 + b1 X + b2 Y + b3 X Y

fitted by least squares on at least four ground points identified in both. The orthophoto
can then be resampled onto the DEM grid and matched against another one
(:func:`~.refine.orthoparallax`, with the base B and flying height H, as in Norvelle 1995).
"""
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from ..common import real_array
from .orthorectify import check_transform, grid_xy

__all__ = ["Bilinear8", "fit_bilinear8", "register_orthophoto"]


@dataclass
class Bilinear8:
    """Eq. 17: ``x = a0 + a1 X + a2 Y + a3 X Y``, ``y = b0 + b1 X + b2 Y + b3 X Y``.

    The coefficients act on centred, scaled coordinates ``(X - X0) / s``, ``(Y - Y0) / s``
    for numerical conditioning; :meth:`apply` handles that.

    Attributes
    ----------
    a, b : ndarray (4,)
        Coefficients on the normalised coordinates.
    origin : (float, float)
    scale : float
    residuals : ndarray (n, 2)
        Fit residuals ``(x, y) - apply(X, Y)`` at the points.
    """
    a: np.ndarray
    b: np.ndarray
    origin: tuple
    scale: float
    residuals: np.ndarray = None

    def apply(self, X, Y):
        """Transform DEM coordinates to orthophoto coordinates."""
        u = (np.asarray(X, dtype=float) - self.origin[0]) / self.scale
        v = (np.asarray(Y, dtype=float) - self.origin[1]) / self.scale
        x = self.a[0] + self.a[1] * u + self.a[2] * v + self.a[3] * u * v
        y = self.b[0] + self.b[1] * u + self.b[2] * v + self.b[3] * u * v
        return x, y

    @property
    def rmse(self):
        """RMS of the fit residuals (orthophoto units), NaN with exactly four points."""
        r = self.residuals
        if r is None or len(r) <= 4:
            return float("nan")
        return float(np.sqrt(np.mean(np.sum(r ** 2, axis=1))))


def fit_bilinear8(dem_xy, ortho_xy):
    """Least-squares eq. 17 from ground points known in the DEM and in the orthophoto.

    Parameters
    ----------
    dem_xy : array_like (n, 2)
        Points in DEM (map) coordinates ``(X, Y)``.
    ortho_xy : array_like (n, 2)
        The same points in orthophoto coordinates ``(x, y)`` (e.g. pixel column, row).

    Returns
    -------
    Bilinear8

    Raises
    ------
    ValueError
        Fewer than four points, mismatched lists, non-finite values, or points that do not
        fix the transformation (e.g. collinear): names the fix.
    """
    P = np.asarray(dem_xy, dtype=float)
    Q = np.asarray(ortho_xy, dtype=float)
    if P.ndim != 2 or P.shape[1] != 2 or Q.shape != P.shape:
        raise ValueError(f"dem_xy and ortho_xy must both be (n, 2) with the same n; got "
                         f"{P.shape} and {Q.shape}.")
    if len(P) < 4:
        raise ValueError(f"eq. 17 has 8 parameters: give at least four ground points; got {len(P)}.")
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(Q))):
        raise ValueError("ground point coordinates must be finite numbers.")
    origin = P.mean(axis=0)
    scale = float(np.max(np.abs(P - origin))) or 1.0
    u = (P[:, 0] - origin[0]) / scale
    v = (P[:, 1] - origin[1]) / scale
    A = np.column_stack([np.ones_like(u), u, v, u * v])
    sv = np.linalg.svd(A, compute_uv=False)
    if sv[-1] < 1e-9 * sv[0]:
        raise ValueError("the ground points do not fix eq. 17 (collinear, or on two lines); "
                         "spread at least four points over the overlap, e.g. near its corners.")
    a, *_ = np.linalg.lstsq(A, Q[:, 0], rcond=None)
    b, *_ = np.linalg.lstsq(A, Q[:, 1], rcond=None)
    res = Q - np.column_stack([A @ a, A @ b])
    return Bilinear8(a, b, (float(origin[0]), float(origin[1])), scale, res)


def register_orthophoto(ortho, transform8, shape, transform, *, order=1):
    """Resample an orthophoto onto a DEM grid through eq. 17.

    Parameters
    ----------
    ortho : ndarray, (rows, cols) or (bands, rows, cols)
        The orthophoto in its own pixel grid (NaN = nodata).
    transform8 : Bilinear8
        DEM ``(X, Y)`` -> orthophoto ``(col, row)`` (pixel centres at integers), from
        :func:`fit_bilinear8`.
    shape : (int, int)
        Rows, cols of the DEM grid.
    transform : 6 floats
        North-up geotransform of the DEM grid.

    Returns
    -------
    ndarray of float32
        The orthophoto on the DEM grid, NaN outside it.
    """
    check_transform(transform)
    img = real_array(ortho, "ortho", "grey values")     # masked pixels NaN (invalid); no complex
    bands = img[None] if img.ndim == 2 else img
    if bands.ndim != 3:
        raise ValueError(f"ortho must be 2-D or (bands, rows, cols); got shape {img.shape}.")
    X, Y = grid_xy(shape, transform)
    col, row = transform8.apply(X + 0 * Y, Y + 0 * X)
    h, w = bands.shape[1:]
    inside = (col >= -0.5) & (col <= w - 0.5) & (row >= -0.5) & (row <= h - 0.5)
    out = np.full((bands.shape[0],) + tuple(shape), np.nan, np.float32)
    for k in range(bands.shape[0]):
        band = bands[k].astype(np.float32)
        bad = ~np.isfinite(band)
        vals = ndimage.map_coordinates(np.where(bad, 0, band), [np.clip(row, 0, h - 1),
                                                                np.clip(col, 0, w - 1)],
                                       order=order, mode="nearest")
        if bad.any():
            hit = ndimage.map_coordinates(bad.astype(np.float32), [np.clip(row, 0, h - 1),
                                                                   np.clip(col, 0, w - 1)],
                                          order=1, mode="nearest") > 0.01
            vals = np.where(hit, np.nan, vals)
        out[k] = np.where(inside, vals, np.nan)
    return out[0] if img.ndim == 2 else out
