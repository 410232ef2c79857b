"""The Bare Earth Processing provider (id ``bareearth``)."""
from qgis.core import QgsProcessingProvider
from qgis.PyQt.QtGui import QIcon

from .meta import ICON, VERSION


class BareEarthProvider(QgsProcessingProvider):
    """Registers every Bare Earth algorithm explicitly."""

    def id(self):
        return "bareearth"

    def name(self):
        return "Bare Earth"

    def longName(self):  # noqa: N802
        return f"Bare Earth {VERSION}"

    def icon(self):
        return QIcon(ICON)

    def svgIconPath(self):  # noqa: N802
        return ICON

    def supportedOutputRasterLayerExtensions(self):  # noqa: N802
        """The raster formats the outputs are written in (others are refused by name)."""
        from .core.grid import gdal_mode_kept, output_extensions
        with gdal_mode_kept():
            return output_extensions()

    def defaultRasterFileExtension(self):  # noqa: N802
        return "tif"

    def loadAlgorithms(self):  # noqa: N802
        from .algorithms import all_algorithms
        from .core.grid import gdal_mode_kept
        with gdal_mode_kept():
            algs = list(all_algorithms())
        for alg in algs:
            self.addAlgorithm(alg)
        from .algorithms.tiles import TilesAlgorithm  # a whole survey on Dask (imported lazily inside)
        self.addAlgorithm(TilesAlgorithm())
