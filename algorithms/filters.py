"""One thin algorithm class per filter method of the core."""
from .filter_base import FilterAlgorithm


class SlopeProfileAlgorithm(FilterAlgorithm):
    """``bareearth:slopeprofile``: slope along X/Y profiles (Luong Chinh Ke 2002, sec. 2.1)."""
    METHOD_NAME = "slopeprofile"
