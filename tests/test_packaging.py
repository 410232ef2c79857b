"""The plugin's packaging: metadata for the official repository, the zip, QGIS-free core."""
import configparser
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_metadata_complete():
    cp = configparser.ConfigParser()
    cp.read(ROOT / "metadata.txt", encoding="utf-8")
    g = cp["general"]
    for key in ("name", "qgisMinimumVersion", "description", "about", "version", "author", "email",
                "tracker", "repository", "homepage", "tags", "icon", "changelog", "category"):
        assert g.get(key, "").strip(), f"metadata.txt lacks {key}"
    assert g["qgisMinimumVersion"] == "3.22"
    assert g["hasProcessingProvider"] == "yes"
    assert (ROOT / g["icon"]).exists()


def test_core_imports_without_qgis():
    code = ("import sys; sys.path.insert(0, %r); import bare_earth.core.pipeline, bare_earth.core.methods;"
            "import bare_earth.core.orthophoto; "
            "assert not any(m == 'qgis' or m.startswith('qgis.') for m in sys.modules), "
            "[m for m in sys.modules if m.startswith('qgis')]" % str(ROOT / ".build" / "plugins"))
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert res.returncode == 0, res.stderr


@pytest.mark.skipif(not (ROOT / ".git").exists(), reason="make package lists files with git")
def test_make_package_builds_a_clean_zip():
    res = subprocess.run(["make", "-s", "package"], cwd=ROOT, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    zpath = ROOT / res.stdout.strip().splitlines()[-1]
    names = zipfile.ZipFile(zpath).namelist()
    assert "bare_earth/metadata.txt" in names and "bare_earth/__init__.py" in names
    assert "bare_earth/provider.py" in names and "bare_earth/icons/bare_earth.svg" in names
    assert any(n.startswith("bare_earth/core/") for n in names)
    for n in names:
        assert not n.startswith(("bare_earth/tests/", "bare_earth/benchmarks/", "bare_earth/.ci/")), n
        assert "__pycache__" not in n and not n.endswith(".pyc"), n
