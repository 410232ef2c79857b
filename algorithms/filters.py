"""One thin algorithm class per filter method of the core."""
from .filter_base import FilterAlgorithm
from .points import PointsInputMixin


class SlopeProfileAlgorithm(FilterAlgorithm):
    """``bareearth:slopeprofile``: slope along X/Y profiles (Luong Chinh Ke 2002, sec. 2.1)."""
    METHOD_NAME = "slopeprofile"


class MorphologicalAlgorithm(PointsInputMixin, FilterAlgorithm):
    """``bareearth:morphological``: grey opening, single or progressive (SMRF / Zhang 2003), on a
    DSM raster (INPUT) or directly on points (INPUT_POINTS: rasterize, filter, classify)."""
    METHOD_NAME = "morphological"
