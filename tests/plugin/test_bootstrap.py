"""The plugin as QGIS loads it: classFactory, initGui/initProcessing, unload; styled masks."""
import subprocess
import textwrap
from pathlib import Path

import pytest

pytestmark = pytest.mark.qgis
PLUGINS = Path(__file__).resolve().parents[2] / ".build" / "plugins"

LIFECYCLE = textwrap.dedent("""
    import os, sys
    os.environ["QT_QPA_PLATFORM"] = "offscreen"
    sys.path.insert(0, {plugins!r})
    from qgis.core import QgsApplication
    app = QgsApplication([], False)
    app.initQgis()
    import bare_earth

    class FakeIface:
        pass

    reg = QgsApplication.processingRegistry()
    plugin = bare_earth.classFactory(FakeIface())
    plugin.initGui()
    prov = reg.providerById("bareearth")
    assert prov is not None, "no provider after initGui"
    n = len(prov.algorithms())
    plugin.initGui()                                   # idempotent
    assert [p.id() for p in reg.providers()].count("bareearth") == 1
    plugin.unload()
    assert reg.providerById("bareearth") is None, "provider left after unload"
    plugin.unload()                                    # twice is harmless
    print("OK", n)
""")


def test_class_factory_init_gui_and_unload(qgis_app):
    res = subprocess.run(["/usr/bin/python3", "-c", LIFECYCLE.format(plugins=str(PLUGINS))],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stdout + res.stderr
    n = int(res.stdout.split("OK")[-1])
    assert n >= 10                                      # 5 filters, fill, evaluate, points, ortho


def test_mask_loads_with_its_palette(processing_run, scene_files, tmp_path):
    from qgis.core import QgsRasterLayer
    res = processing_run("bareearth:slopeprofile", {"INPUT": scene_files["dsm"], "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                                    "OUTPUT_MASK": str(tmp_path / "mask.tif")})
    lay = QgsRasterLayer(res["OUTPUT_MASK"], "mask")
    assert lay.isValid()
    msg, ok = lay.loadNamedStyle(str(tmp_path / "mask.qml"))
    assert ok, msg
    assert lay.renderer().type() == "paletted"
    labels = {c.label for c in lay.renderer().classes()}
    assert {"ground", "object above ground", "low outlier below ground"} <= labels
