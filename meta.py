"""Version and links, read from metadata.txt (the one place they are written)."""
import configparser
import os

_cp = configparser.ConfigParser()
_cp.read(os.path.join(os.path.dirname(__file__), "metadata.txt"), encoding="utf-8")
VERSION = _cp.get("general", "version", fallback="0.0.0")
HOMEPAGE = _cp.get("general", "homepage", fallback="")
TRACKER = _cp.get("general", "tracker", fallback="")
