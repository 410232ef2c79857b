"""Session-wide test set-up: make the repo importable as the package ``bare_earth``.

CI clones the repo into a folder of another name, so the plugin is linked under its own
name in ``.build/plugins`` (the same folder `make` gives QGIS as QGIS_PLUGINPATH).
"""
import contextlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PLUGINS = ROOT / ".build" / "plugins"
LINK = PLUGINS / "bare_earth"
if not LINK.exists():
    PLUGINS.mkdir(parents=True, exist_ok=True)
    try:
        LINK.symlink_to(ROOT, target_is_directory=True)
    except FileExistsError:
        pass
if str(PLUGINS) not in sys.path:
    sys.path.insert(0, str(PLUGINS))

DATA = Path(os.environ.get("BARE_EARTH_DATA", ROOT.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data():
    """Path of ../shared/data (env BARE_EARTH_DATA); skips the test when absent."""
    if not DATA.is_dir():
        pytest.skip(f"real data folder {DATA} is absent (set BARE_EARTH_DATA)")
    return DATA


@contextlib.contextmanager
def _read_only(path):
    """``path`` made read-only for this process: chmod for a user, an immutable file for root
    (whom permissions do not stop); the test is skipped where neither works."""
    if os.geteuid() != 0:
        os.chmod(path, 0o444)
        try:
            yield
        finally:
            os.chmod(path, 0o644)
        return
    if subprocess.run(["chattr", "+i", str(path)], capture_output=True).returncode != 0:
        pytest.skip("cannot make a file immutable here (chattr)")
    try:
        yield
    finally:
        subprocess.run(["chattr", "-i", str(path)], capture_output=True)


@pytest.fixture
def read_only():
    """``with read_only(path):`` the file may not be written or replaced inside the block."""
    return _read_only
