"""Bare Earth numeric core: DSM filtering, gap filling, evaluation.

Imports no QGIS. Usable from plain Python::

    from bare_earth.core import filter_dsm
    result = filter_dsm(z, cell_size=(1.0, 1.0), method="slopeprofile")
    result.mask, result.dtm

Conventions (every module follows them):

* Surfaces are 2-D ``float32`` arrays with ``NaN`` as nodata (:func:`as_surface`).
* ``cell_size`` is ``(dx, dy)`` in metres, both positive (a scalar means square cells).
* Masks are ``uint8``: 0 ground, 1 object above the ground, 2 low outlier below the
  ground, 255 nodata (:mod:`bare_earth.core.codes`).
* Long functions take ``progress``, a plain callable ``progress(fraction)`` with
  ``fraction`` in [0, 1]; it may raise :class:`Cancelled` to stop the work.
* Bad arguments raise ``ValueError`` whose message names the problem and the fix.
"""
from .codes import GROUND, LOW, MASK_CODES, NODATA, OBJECT
from .common import Cancelled, FilterResult, as_cell_size, as_surface

__all__ = ["GROUND", "OBJECT", "LOW", "NODATA", "MASK_CODES", "Cancelled",
           "FilterResult", "as_surface", "as_cell_size", "filter_dsm"]


def filter_dsm(z, cell_size, method="slopeprofile", progress=None, **params):
    """Filter a DSM array with a registered method and fill the DTM.

    Thin convenience wrapper around :func:`bare_earth.core.pipeline.run_array`.
    """
    from .pipeline import run_array
    return run_array(method, z, cell_size, params=params, progress=progress)
