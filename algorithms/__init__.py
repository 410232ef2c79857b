"""The QGIS layer: parameters in, core call, outputs out. Nothing numeric here."""


def all_algorithms():
    """Instances of every algorithm whose core method is available, in toolbox order."""
    from ..core.methods import available_methods
    from . import filters
    from .evaluate import EvaluateAlgorithm
    from .fill_dtm import FillDtmAlgorithm
    from .orthophoto import OrthoParallaxAlgorithm, OrthoRefineAlgorithm
    from .points import ClassifyPointsAlgorithm, RasterizePointsAlgorithm
    methods = available_methods()
    algs = []
    for cls in (getattr(filters, n) for n in filters.__dict__ if n.endswith("Algorithm")):
        if isinstance(cls, type) and getattr(cls, "METHOD_NAME", None) in methods:
            algs.append(cls())
    algs += [FillDtmAlgorithm(), EvaluateAlgorithm(), RasterizePointsAlgorithm(), ClassifyPointsAlgorithm()]
    algs += [OrthoParallaxAlgorithm(), OrthoRefineAlgorithm()]
    return algs
