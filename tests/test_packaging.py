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


#: what the official plugin repository's validator (plugins.qgis.org, QGIS-Django plugins/validator.py)
#: requires of an upload
REQUIRED_METADATA = ("name", "description", "version", "qgisMinimumVersion", "author", "email", "about",
                     "tracker", "repository")
BINARY_SUFFIXES = (".pyc", ".pyo", ".so", ".pyd", ".dll", ".dylib", ".exe", ".o", ".a")


def validate_plugin_zip(path):
    """The plugin repository's upload checks, as a list of problems (empty: accepted)."""
    import codecs
    import configparser
    import re
    from io import StringIO
    from urllib.parse import urlparse
    problems = []
    if Path(path).stat().st_size > 25_000_000:
        problems.append("larger than 25 MB")
    z = zipfile.ZipFile(path)
    names = z.namelist()
    for n in names:
        if ".." in n or n.startswith("/"):
            problems.append(f"path information in {n}")
        if ".pyc" in n:
            problems.append(f".pyc file {n}")
        if {"__MACOSX", ".git", "__pycache__"} & set(n.split("/")):
            problems.append(f"forbidden folder in {n}")
        if n.lower().endswith(BINARY_SUFFIXES):
            problems.append(f"binary file {n}")
        if not n.endswith("/") and not n.endswith((".svg", ".png")) and b"\0" in z.read(n):
            problems.append(f"binary content in {n}")
    if z.testzip():
        problems.append("bad zip")
    top = {n.split("/")[0] for n in names}
    if len(top) != 1:
        return problems + [f"several top folders {sorted(top)}"]
    pkg = top.pop()
    if not re.match(r"^[A-Za-z][A-Za-z0-9-_]+$", pkg):
        problems.append(f"bad package name {pkg}")
    for f in ("__init__.py", "metadata.txt", "LICENSE"):
        if f"{pkg}/{f}" not in names:
            problems.append(f"no {f}")
    if problems:
        return problems
    cp = configparser.ConfigParser()
    cp.optionxform = str
    cp.read_file(StringIO(codecs.decode(z.read(f"{pkg}/metadata.txt"), "utf8")))
    md = dict(cp.items("general"))
    problems += [f"metadata lacks {k}" for k in REQUIRED_METADATA if not md.get(k, "").strip()]
    if "/" in md.get("author", ""):
        problems.append("author contains a slash")
    for key in ("tracker", "repository", "homepage"):
        u = urlparse(md.get(key, ""))
        if not (u.scheme and u.netloc):
            problems.append(f"{key} is not a URL")
    if md.get("icon") and f"{pkg}/{md['icon']}" not in names:
        problems.append(f"icon {md['icon']} not in the zip")
    return problems


@pytest.mark.skipif(not (ROOT / ".git").exists(), reason="make package lists files with git")
def test_make_package_builds_a_zip_the_plugin_repository_accepts():
    res = subprocess.run(["make", "-s", "package"], cwd=ROOT, capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    zpath = ROOT / res.stdout.strip().splitlines()[-1]
    assert validate_plugin_zip(zpath) == []
    z = zipfile.ZipFile(zpath)
    names = z.namelist()
    assert "bare_earth/provider.py" in names and "bare_earth/icons/bare_earth.svg" in names
    assert any(n.startswith("bare_earth/core/") for n in names)
    for n in names:
        assert not n.startswith(("bare_earth/tests/", "bare_earth/benchmarks/", "bare_earth/.ci/")), n
    licence = z.read("bare_earth/LICENSE").decode("ascii")
    assert "GNU GENERAL PUBLIC LICENSE" in licence and "Version 2, June 1991" in licence
    assert "any later version" in licence and "END OF TERMS AND CONDITIONS" in licence


def test_validator_refuses_what_the_repository_refuses(tmp_path):
    """The checks above are not vacuous: a zip without LICENSE, or with a cache, is refused."""
    good = {"pk/__init__.py": "", "pk/LICENSE": "GPL", "pk/metadata.txt":
            "[general]\n" + "\n".join(f"{k}=" + ("A" if k == "author" else "https://x.org/a")
                                   for k in REQUIRED_METADATA + ("homepage",)) + "\n"}
    for extra, drop, expect in (({}, None, None), ({}, "pk/LICENSE", "no LICENSE"),
                                ({"pk/__pycache__/a.cpython-311.pyc": "x"}, None, ".pyc"),
                                ({"pk/lib.so": "x"}, None, "binary")):
        files = {k: v for k, v in {**good, **extra}.items() if k != drop}
        zpath = tmp_path / "t.zip"
        with zipfile.ZipFile(zpath, "w") as z:
            for k, v in files.items():
                z.writestr(k, v)
        problems = validate_plugin_zip(zpath)
        assert (not problems) if expect is None else any(expect in p for p in problems), (expect, problems)


def test_metadata_accepted_by_qgis_4_and_licence_named():
    cp = configparser.ConfigParser()
    cp.read(ROOT / "metadata.txt", encoding="utf-8")
    g = cp["general"]
    assert tuple(int(v) for v in g["qgisMaximumVersion"].split(".")[:2]) >= (4, 0)
    # the key the plugin repository reads for Qt6 builds; earned by tests/plugin/test_qgis4_compat.py
    assert g.getboolean("supportsQt6") is True
    assert "GPL" in g["about"] and "LICENSE" in g["about"]
    for alg in ("slope", "curvature", "RASCOR", "geodesic", "morpholog", "point", "orthophoto"):
        assert alg.lower() in g["about"].lower(), alg


def test_readme_algorithm_reference_is_generated_from_the_code():
    # the README's algorithm reference is what scripts/algorithm_docs.py renders from the methods'
    # help and parameters: a help text edited in one place only is caught here
    res = subprocess.run(["/usr/bin/python3" if Path("/usr/bin/python3").exists() else sys.executable,
                          str(ROOT / "scripts" / "algorithm_docs.py")], capture_output=True, text=True, cwd=ROOT)
    assert res.returncode == 0, res.stderr
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    begin, end = "<!-- algorithms:begin -->", "<!-- algorithms:end -->"
    section = readme[readme.index(begin) + len(begin):readme.index(end)].strip()
    assert section == res.stdout.strip(), ("README.md's algorithm reference differs from the code's help: run "
                                           "`/usr/bin/python3 scripts/algorithm_docs.py --write README.md`")
