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
        from .core.grid import output_extensions
        return output_extensions()

    def defaultRasterFileExtension(self):  # noqa: N802
        return "tif"

    def loadAlgorithms(self):  # noqa: N802
        from .algorithms import all_algorithms
        for alg in all_algorithms():
            self.addAlgorithm(alg)
