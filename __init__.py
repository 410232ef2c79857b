"""Bare Earth: QGIS Processing plugin turning a DSM into a bare-earth DTM and an object mask.

Importing this package does not import QGIS: the numeric core (``bare_earth.core``) is
usable from plain Python. QGIS calls :func:`classFactory`.
"""


def classFactory(iface):  # noqa: N802 (QGIS's name)
    """QGIS plugin entry point."""
    from .plugin import BareEarthPlugin
    return BareEarthPlugin(iface)
