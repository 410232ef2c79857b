"""QGIS 4 (Qt6, PyQt6) readiness of the QGIS layer, proven here on QGIS 3.22 / PyQt5.

(a) The QGIS layer's source (ast) uses none of what QGIS 4 / PyQt6 removes: PyQt5 imports,
    ``exec_``, Qt5-only classes, ``QVariant`` types, unscoped Qt enums, and no QGIS enum spelt
    outside ``algorithms/compat.py`` (QGIS 3.36 moved them to ``Qgis``; QGIS 4 drops the old
    names). A failure names file:line and the fix.
(b) ``algorithms/compat.py`` resolves every name to 3.22's value here, and to the scoped value
    wherever QGIS has it (simulated: QGIS 4 cannot run on this machine).
"""
import ast
import enum
import types
from pathlib import Path

import pytest

pytestmark = pytest.mark.qgis
ROOT = Path(__file__).resolve().parents[2]
COMPAT = ROOT / "algorithms" / "compat.py"

#: Each compat name and the QGIS 3.22 unscoped spelling it replaces (strings: this file must
#: pass its own scan).
LEGACY = {
    "SOURCE_FILE": ("QgsProcessing", "TypeFile"),
    "SOURCE_RASTER": ("QgsProcessing", "TypeRaster"),
    "SOURCE_VECTOR_POINT": ("QgsProcessing", "TypeVectorPoint"),
    "SOURCE_VECTOR_LINE": ("QgsProcessing", "TypeVectorLine"),
    "SOURCE_VECTOR_POLYGON": ("QgsProcessing", "TypeVectorPolygon"),
    "NUMBER_DOUBLE": ("QgsProcessingParameterNumber", "Double"),
    "NUMBER_INTEGER": ("QgsProcessingParameterNumber", "Integer"),
    "FILE_FILE": ("QgsProcessingParameterFile", "File"),
    "FILE_FOLDER": ("QgsProcessingParameterFile", "Folder"),
    "FLAG_ADVANCED": ("QgsProcessingParameterDefinition", "FlagAdvanced"),
    "FLAG_OPTIONAL": ("QgsProcessingParameterDefinition", "FlagOptional"),
    "GEOMETRY_POINT": ("QgsWkbTypes", "PointGeometry"),
    "GEOMETRY_LINE": ("QgsWkbTypes", "LineGeometry"),
    "GEOMETRY_POLYGON": ("QgsWkbTypes", "PolygonGeometry"),
    "INVALID_GEOMETRY_NO_CHECK": ("QgsFeatureRequest", "GeometryNoCheck"),
    "INVALID_GEOMETRY_SKIP": ("QgsFeatureRequest", "GeometrySkipInvalid"),
    "INVALID_GEOMETRY_ABORT": ("QgsFeatureRequest", "GeometryAbortOnInvalid"),
    "SOURCE_SKIP_GEOMETRY_CHECKS": ("QgsProcessingFeatureSource", "FlagSkipGeometryValidityChecks"),
    "SHADER_LINEAR": ("QgsColorRampShader", "Interpolated"),
    "RANGE_INCLUDE_MIN_AND_MAX": ("QgsRasterRange", "IncludeMinAndMax"),
    "RANGE_INCLUDE_MIN": ("QgsRasterRange", "IncludeMin"),
    "RANGE_INCLUDE_MAX": ("QgsRasterRange", "IncludeMax"),
    "WKT_PREFERRED_GDAL": ("QgsCoordinateReferenceSystem", "WKT_PREFERRED_GDAL"),
}

#: Names PyQt6 / Qt6 no longer has (or has elsewhere), and what to write instead.
QT6_GONE = {
    "QRegExp": "QRegularExpression",
    "QDesktopWidget": "QScreen (QGuiApplication.screens())",
    "qApp": "QApplication.instance()",
    "QVariant": "QMetaType.Type for field types (QGIS >= 3.38), a compat.py entry while 3.22 is supported",
}


def qgis_layer_files():
    """The QGIS layer: algorithms/, the plugin's entry modules, bin/, scripts/ and the plugin tests."""
    files = sorted((ROOT / "algorithms").glob("*.py"))
    files += [ROOT / n for n in ("__init__.py", "plugin.py", "provider.py", "meta.py")]
    files += sorted((ROOT / "scripts").glob("*.py")) + sorted((ROOT / "bin").iterdir())
    files += sorted((ROOT / "tests" / "plugin").glob("*.py")) + [ROOT / "tests" / "conftest.py"]
    return [f for f in files if f.is_file() and (f.suffix == ".py" or f.read_text().startswith("#!/usr/bin/python3"))]


def _namespaces():
    import qgis.core
    import qgis.gui
    import qgis.PyQt.QtCore
    import qgis.PyQt.QtGui
    import qgis.PyQt.QtWidgets
    return [qgis.core, qgis.gui, qgis.PyQt.QtCore, qgis.PyQt.QtGui, qgis.PyQt.QtWidgets]


def _lookup(name, spaces):
    for ns in spaces:
        if hasattr(ns, name):
            return getattr(ns, name)
    return None


def _is_enum_value(v):
    """A value of a C++ enum as this PyQt/sip shows it (PyQt5: an int subclass; PyQt6: enum.Enum)."""
    return isinstance(v, enum.Enum) or (isinstance(v, int) and type(v) not in (int, bool))


def _is_enum_type(v):
    return isinstance(v, type) and (issubclass(v, enum.Enum) or (issubclass(v, int) and v not in (int, bool)))


def _qgis_enum_members(spaces):
    """Names of the enum members of every QGIS class (to catch ``definition.FlagOptional``)."""
    names = set()
    for ns in spaces[:2]:
        for cls_name in dir(ns):
            cls = getattr(ns, cls_name)
            if isinstance(cls, type) and cls_name.startswith("Qgs"):
                names.update(k for k, v in vars(cls).items() if _is_enum_value(v))
    return names


def scan(path, spaces, qgis_members):
    """Problems in one file: list of "file:line: what -> fix"."""
    rel = path.relative_to(ROOT)
    tree = ast.parse(path.read_text(), str(path))
    out = []

    def say(node, text):
        out.append(f"{rel}:{node.lineno}: {text}")

    parents = {c: p for p in ast.walk(tree) for c in ast.iter_child_nodes(p)}
    imported = {(a.asname or a.name).split(".")[0] for n in ast.walk(tree)
                if isinstance(n, (ast.Import, ast.ImportFrom)) for a in n.names}
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in ("PyQt5", "PyQt6"):
            say(node, f"from {node.module} import ... -> from qgis.PyQt.{node.module.split('.', 1)[-1]} import ...")
        elif isinstance(node, ast.Import) and any(a.name.split(".")[0] in ("PyQt5", "PyQt6") for a in node.names):
            say(node, "import PyQt5/PyQt6 -> import from qgis.PyQt")
        if isinstance(node, ast.ImportFrom) and node.module == "qgis.PyQt.QtWidgets" and \
                any(a.name == "QAction" for a in node.names):
            say(node, "QAction from QtWidgets (Qt6 moved it to QtGui) -> from qgis.PyQt.QtGui import QAction "
                      "(QGIS >= 3.18 re-exports it there under Qt5 too)")
        if isinstance(node, ast.ImportFrom) and node.module == "qgis.PyQt.Qt":
            say(node, "qgis.PyQt.Qt -> from qgis.PyQt.QtCore import Qt")
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("qgis.PyQt"):
            for a in node.names:
                if a.name in QT6_GONE:
                    say(node, f"{a.name} (gone in Qt6) -> {QT6_GONE[a.name]}")
        if isinstance(node, ast.Name) and node.id in QT6_GONE:
            say(node, f"{node.id} (gone in Qt6) -> {QT6_GONE[node.id]}")
        if isinstance(node, ast.Attribute) and node.attr in ("exec_", "print_"):
            say(node, f".{node.attr}( -> .{node.attr[:-1]}(")
        if isinstance(node, ast.FunctionDef) and node.name == "exec_":
            say(node, "def exec_ -> def exec")
        if not isinstance(node, ast.Attribute) or path == COMPAT:
            continue
        if isinstance(node.value, ast.Name):                      # Owner.Member
            owner = _lookup(node.value.id, spaces)
            if owner is None:
                if node.attr in qgis_members and not node.attr.isupper() and node.value.id not in imported:
                    say(node, f"{node.value.id}.{node.attr}: a QGIS enum member through an instance -> "
                              "a name from algorithms/compat.py")
                continue
            v = getattr(owner, node.attr, None)
            if _is_enum_value(v):
                if node.value.id.startswith("Qgs") or node.value.id == "Qgis":
                    say(node, f"{node.value.id}.{node.attr}: unscoped QGIS enum (removed in QGIS 4) -> "
                              "a name from algorithms/compat.py")
                else:
                    say(node, f"{node.value.id}.{node.attr}: unscoped Qt enum (PyQt6 needs scoped) -> "
                              f"{node.value.id}.{type(v).__name__}.{node.attr}")
        elif isinstance(node.value, ast.Attribute) and isinstance(node.value.value, ast.Name) and \
                node.value.value.id.startswith("Qgs") and not isinstance(parents.get(node), ast.Attribute):
            owner = _lookup(node.value.value.id, spaces)      # QgsClass.Enum.Member
            if owner is not None and _is_enum_type(getattr(owner, node.value.attr, None)):
                say(node, f"{node.value.value.id}.{node.value.attr}.{node.attr}: a QGIS class enum (QGIS 3.36+ "
                          "moved many to Qgis) -> an entry in algorithms/compat.py, resolve() in a test")
    return out


def test_qgis_layer_uses_nothing_qgis4_or_pyqt6_removed(qgis_app):
    spaces = _namespaces()
    members = _qgis_enum_members(spaces)
    files = qgis_layer_files()
    assert COMPAT in files and ROOT / "algorithms" / "filter_base.py" in files and len(files) > 25
    problems = [p for f in files for p in scan(f, spaces, members)]
    assert problems == [], "\n".join(problems)


def test_the_scan_finds_what_qgis4_removes(qgis_app, tmp_path):
    """The scanner itself: each removed form in a throw-away file is reported with its line."""
    spaces = _namespaces()
    members = _qgis_enum_members(spaces)
    bad = ("from PyQt5.QtCore import QTimer\n"                                   # 1
           "from qgis.PyQt.QtWidgets import QAction\n"                           # 2
           "from qgis.core import QgsProcessing, QgsProcessingParameterNumber\n"
           "from qgis.PyQt.QtCore import Qt, QVariant\n"                         # 4 (QVariant)
           "a = QgsProcessing.TypeVectorPolygon\n"                               # 5
           "b = QgsProcessingParameterNumber.Double\n"                           # 6
           "c = Qt.AlignLeft\n"                                                  # 7
           "d = Qt.AlignmentFlag.AlignLeft\n"                                    # fine
           "e = QgsProcessing.SourceType.TypeRaster\n"                           # 9
           "dialog.exec_()\n"                                                    # 10
           "f = definition.FlagOptional\n"                                       # 11
           "g = QgsProcessing.TEMPORARY_OUTPUT\n")                               # fine
    f = ROOT / "tests" / "plugin" / "_scan_probe.py"   # under ROOT: scan() names files relative to it
    try:
        f.write_text(bad)
        found = scan(f, spaces, members)
    finally:
        f.unlink()
    lines = sorted({int(p.split(":")[1]) for p in found})
    assert lines == [1, 2, 4, 5, 6, 7, 9, 10, 11], "\n".join(found)
    assert any("Qt.AlignmentFlag.AlignLeft" in p for p in found)           # the fix is named


def test_compat_gives_the_322_values_here(qgis_app):
    import qgis.core

    from bare_earth.algorithms import compat
    assert set(compat.ENUMS) == set(LEGACY)
    for name, (cls, member) in LEGACY.items():
        legacy = getattr(getattr(qgis.core, cls), member)
        value = getattr(compat, name)
        assert value == legacy and type(value) is type(legacy), name
        new, old = compat.ENUMS[name]
        assert compat.resolve(new, old) == value


def test_compat_prefers_the_scoped_value_wherever_qgis_has_it(qgis_app):
    """On every QGIS: the Qgis.* path wins when it exists, and equals the old one when both do;
    here (3.22) the scoped paths are absent, so the 3.22 branch is what ran."""
    from qgis.core import Qgis

    from bare_earth.algorithms import compat

    def at(owner, path):
        for part in path.split("."):
            owner = getattr(owner, part, None)
        return owner

    for name, (new, old) in compat.ENUMS.items():
        assert new[0] is Qgis, name
        scoped, legacy = at(*new), at(*old)
        expected = scoped if scoped is not None else legacy
        assert getattr(compat, name) == expected and type(getattr(compat, name)) is type(expected), name
        if scoped is not None and legacy is not None:
            assert scoped == legacy, name
    if Qgis.QGIS_VERSION_INT < 33000:
        assert all(at(*new) is None for new, _old in compat.ENUMS.values())


def test_resolve_on_a_simulated_qgis4():
    """QGIS 4 as compat sees it: the scoped enum on Qgis, the unscoped name gone from the class."""
    from bare_earth.algorithms.compat import as_int, resolve

    class ProcessingSourceType(enum.Enum):     # PyQt6 enums are enum.Enum, not ints
        VectorPolygon = 2

    qgis4 = types.SimpleNamespace(ProcessingSourceType=ProcessingSourceType)
    processing4 = types.SimpleNamespace()      # QgsProcessing without SourceType / TypeVectorPolygon
    v = resolve((qgis4, "ProcessingSourceType.VectorPolygon"), (processing4, "SourceType.TypeVectorPolygon"))
    assert v is ProcessingSourceType.VectorPolygon
    assert as_int(v) == 2 and as_int(7) == 7
    with pytest.raises(AttributeError, match="ProcessingSourceType.VectorLine.*SourceType.TypeVectorLine"):
        resolve((qgis4, "ProcessingSourceType.VectorLine"), (processing4, "SourceType.TypeVectorLine"))


def test_vector_kinds_accept_the_ints_datatypes_gives(qgis_app):
    """``dataTypes()`` lists ints in every QGIS: the kinds table is keyed so that they match."""
    from qgis.core import QgsProcessingParameterFeatureSource

    from bare_earth.algorithms.compat import GEOMETRY_LINE, GEOMETRY_POLYGON, SOURCE_VECTOR_LINE, SOURCE_VECTOR_POLYGON
    from bare_earth.algorithms.vector_raster import KINDS
    d = QgsProcessingParameterFeatureSource("X", "x", [SOURCE_VECTOR_POLYGON, SOURCE_VECTOR_LINE])
    assert [KINDS[t][0] for t in d.dataTypes()] == [GEOMETRY_POLYGON, GEOMETRY_LINE]
