"""Version, links and the icon path: plain constants with no QGIS import, so the provider and
the algorithms both import them from here (neither imports the other for them)."""
import configparser
import os

_cp = configparser.ConfigParser()
_cp.read(os.path.join(os.path.dirname(__file__), "metadata.txt"), encoding="utf-8")
VERSION = _cp.get("general", "version", fallback="0.0.0")
HOMEPAGE = _cp.get("general", "homepage", fallback="")
TRACKER = _cp.get("general", "tracker", fallback="")

#: The plugin's icon (provider and every algorithm).
ICON = os.path.join(os.path.dirname(__file__), "icons", "bare_earth.svg")
