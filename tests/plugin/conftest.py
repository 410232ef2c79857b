"""Session-wide QGIS for the plugin tests: one QgsApplication, Processing, the provider.

Also ``run_qgis_process``: runs ``qgis_process.bin`` with the plugin folder on
QGIS_PLUGINPATH (``make test`` enabled the plugin; the fixture enables it if needed).
"""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
PLUGINS = ROOT / ".build" / "plugins"
os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
os.environ.setdefault("XDG_RUNTIME_DIR", f"/tmp/runtime-{os.getuid()}")
os.makedirs(os.environ["XDG_RUNTIME_DIR"], mode=0o700, exist_ok=True)

try:
    import qgis.core  # noqa: F401
    HAVE_QGIS = True
except ImportError:  # pragma: no cover - the test machine has QGIS (make test installs it)
    HAVE_QGIS = False


@pytest.fixture(scope="session")
def qgis_app():
    """An initialised QgsApplication with Processing and the Bare Earth provider."""
    if not HAVE_QGIS:
        pytest.skip("QGIS's Python bindings are not installed (make test installs them)")
    from qgis.core import QgsApplication
    app = QgsApplication.instance()
    if app is None:
        app = QgsApplication([], False)
        app.initQgis()
    for p in ("/usr/share/qgis/python/plugins",):
        if p not in sys.path:
            sys.path.append(p)
    from processing.core.Processing import Processing
    Processing.initialize()
    from bare_earth.plugin import BareEarthPlugin
    plugin = BareEarthPlugin(None)
    plugin.initProcessing()
    yield app
    plugin.unload()


@pytest.fixture(scope="session")
def processing_run(qgis_app):
    """``processing.run`` bound to the session's app."""
    import processing
    return processing.run


@pytest.fixture(scope="session")
def warning_log(qgis_app):
    """A class of processing feedbacks that keep the warnings they are given (``.warnings``)."""
    from qgis.core import QgsProcessingFeedback

    class WarningLog(QgsProcessingFeedback):
        def __init__(self):
            super().__init__()
            self.warnings = []

        def pushWarning(self, text):  # noqa: N802
            self.warnings.append(text)
    return WarningLog


def _qgis_process_bin():
    exe = shutil.which("qgis_process.bin") or "/usr/bin/qgis_process.bin"
    if not os.path.exists(exe):
        pytest.skip("qgis_process.bin is not installed")
    return exe


@pytest.fixture(scope="session")
def run_qgis_process():
    """Run ``qgis_process.bin run ALG -- KEY=VALUE ...``; returns (returncode, stdout+stderr, json or None)."""
    exe = _qgis_process_bin()
    env = dict(os.environ, QT_QPA_PLATFORM="offscreen", QGIS_PLUGINPATH=str(PLUGINS))
    listed = subprocess.run([exe, "plugins"], env=env, capture_output=True, text=True).stdout
    if "* bare_earth" not in listed:
        subprocess.run([exe, "plugins", "enable", "bare_earth"], env=env, capture_output=True, text=True)

    def run(alg, params, as_json=True):
        args = [exe, "run", alg]
        if as_json:
            args.append("--json")
        args.append("--")
        args += [f"{k}={v}" for k, v in params.items()]
        res = subprocess.run(args, env=env, capture_output=True, text=True, timeout=600)
        out = res.stdout + res.stderr
        data = None
        if as_json and res.returncode == 0:
            try:
                data = json.loads(res.stdout[res.stdout.index("{"):])
            except ValueError:
                data = None
        return res.returncode, out, data
    return run


@pytest.fixture
def scene_files(tmp_path):
    """A small synthetic city DSM (GeoTIFF, nodata -9999) with its true DTM and mask."""
    from bare_earth.core.grid import write_array
    from bare_earth.core.synthetic import make_scene
    sc = make_scene("city", shape=(160, 180), seed=11, nodata_holes=True)
    dsm = tmp_path / "dsm.tif"
    write_array(dsm, np.where(np.isfinite(sc.dsm), sc.dsm, -9999.0), sc.geotransform, sc.epsg, nodata=-9999.0)
    write_array(tmp_path / "true_dtm.tif", sc.dtm, sc.geotransform, sc.epsg)
    write_array(tmp_path / "true_mask.tif", sc.mask, sc.geotransform, sc.epsg, nodata=255)
    return {"dsm": str(dsm), "dtm": str(tmp_path / "true_dtm.tif"), "mask": str(tmp_path / "true_mask.tif"),
            "scene": sc, "dir": tmp_path}
