"""QGIS plugin bootstrap: registers the Processing provider.

``initProcessing`` does the registering (it is all ``qgis_process`` calls);
``initGui`` only calls it.
"""
from qgis.core import QgsApplication

from .provider import BareEarthProvider


class BareEarthPlugin:
    """The plugin object QGIS creates through ``classFactory``."""

    def __init__(self, iface=None):
        self.iface = iface
        self.provider = None

    def initProcessing(self):  # noqa: N802 (QGIS's name)
        if self.provider is None:
            self.provider = BareEarthProvider()
            QgsApplication.processingRegistry().addProvider(self.provider)

    def initGui(self):  # noqa: N802
        self.initProcessing()

    def unload(self):
        if self.provider is not None:
            try:
                QgsApplication.processingRegistry().removeProvider(self.provider)
            except RuntimeError:  # QGIS already deleted it (e.g. while shutting down)
                pass
            self.provider = None
