"""One thin algorithm class per filter method of the core.

Everything but the method name and the help of its side products comes from the core's
``METHOD`` spec (parameters, defaults, help) and from ``FilterAlgorithm``.
"""
from .filter_base import FilterAlgorithm
from .points import PointsInputMixin


class SlopeProfileAlgorithm(FilterAlgorithm):
    """``bareearth:slopeprofile``: slope along X/Y profiles (Luong Chinh Ke 2002, sec. 2.1)."""
    METHOD_NAME = "slopeprofile"


class CurvatureAlgorithm(FilterAlgorithm):
    """``bareearth:curvature``: local trend by Gaussian curvature (Luong Chinh Ke 2002, sec. 2.2)."""
    METHOD_NAME = "curvature"
    EXTRA_HELP = {"curvature": "Curvature, two Float32 bands: Gaussian curvature K (1/m^2) and mean "
                               "curvature H (1/m; H > 0 convex, H < 0 concave): what the filter saw, to "
                               "choose K_G_PER_M2."}


class GeodesicAlgorithm(FilterAlgorithm):
    """``bareearth:geodesic``: gradual geodesic dilation with scan labelling (2018)."""
    METHOD_NAME = "geodesic"
    EXTRA_HELP = {"step": "Step, UInt8: which dilation step (1, 2, ...) or which later stage removed each "
                          "cell (codes in the algorithm's help); 0 kept, 255 nodata."}


class MorphologicalAlgorithm(PointsInputMixin, FilterAlgorithm):
    """``bareearth:morphological``: grey opening, single or progressive (SMRF / Zhang 2003), on a
    DSM raster (INPUT) or directly on points (INPUT_POINTS: rasterize, filter, classify)."""
    METHOD_NAME = "morphological"
