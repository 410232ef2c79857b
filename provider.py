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

    def loadAlgorithms(self):  # noqa: N802
        from .algorithms import all_algorithms
        for alg in all_algorithms():
            self.addAlgorithm(alg)
