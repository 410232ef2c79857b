"""Shared set-up of the benchmark scripts: make ``import bare_earth`` work from a clone."""
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PLUGINS = ROOT / ".build" / "plugins"


def setup_path():
    link = PLUGINS / "bare_earth"
    if not link.exists():
        PLUGINS.mkdir(parents=True, exist_ok=True)
        try:
            link.symlink_to(Path("..") / "..", target_is_directory=True)
        except FileExistsError:
            pass
    if str(PLUGINS) not in sys.path:
        sys.path.insert(0, str(PLUGINS))


def data_dir(arg=None):
    return Path(arg or os.environ.get("BARE_EARTH_DATA", ROOT.parent / "shared" / "data"))
