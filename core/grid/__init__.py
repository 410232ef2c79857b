"""Raster I/O with GDAL, the only GDAL caller of the filters' path: :mod:`.read` (open and
check a DSM, nodata, scale/offset, units, geodesy) and :mod:`.outputs` (outputs on the
input's grid, formats, work files, the mask's style). Everything is importable from here.
"""
from .outputs import *  # noqa: F401,F403
from .read import *  # noqa: F401,F403
