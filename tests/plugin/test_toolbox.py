"""Found in the toolbox, helped by the README: tags through QGIS's own toolbox search, and
every help button's anchor against the README's headings (computed as GitHub does)."""
import re
from pathlib import Path

import pytest

pytestmark = pytest.mark.qgis
ROOT = Path(__file__).resolve().parents[2]


def _algorithms(qgis_app):
    from qgis.core import QgsApplication
    return QgsApplication.processingRegistry().providerById("bareearth").algorithms()


def _toolbox_search(text):
    """Ids of the Bare Earth algorithms QGIS's toolbox shows for ``text`` in its search box."""
    from qgis.core import QgsApplication
    from qgis.gui import QgsProcessingToolboxProxyModel
    from qgis.PyQt.QtCore import QModelIndex

    from bare_earth.algorithms.compat import resolve
    model = QgsProcessingToolboxProxyModel(None, QgsApplication.processingRegistry())
    model.setFilters(resolve((QgsProcessingToolboxProxyModel, "Filter.Toolbox"),         # QGIS >= 3.36
                             (QgsProcessingToolboxProxyModel, "Filter.FilterToolbox")))  # QGIS 3.22
    model.setFilterString(text)
    found = set()

    def walk(parent):
        for r in range(model.rowCount(parent)):
            idx = model.index(r, 0, parent)
            alg = model.toolboxModel().algorithmForIndex(model.mapToSource(idx))
            if alg is not None and alg.provider().id() == "bareearth":
                found.add(alg.id())
            walk(idx)
    walk(QModelIndex())
    return found


def test_each_algorithm_found_by_the_words_users_type(qgis_app):
    algs = _algorithms(qgis_app)
    dtm, ground = _toolbox_search("DTM"), _toolbox_search("ground")
    lidar, ortho = _toolbox_search("lidar"), _toolbox_search("orthophoto")
    for a in algs:
        assert a.id() in dtm | ground, f"{a.id()} is found neither by 'DTM' nor by 'ground'"
        assert a.tags(), a.id()
        assert len(set(a.tags())) == len(a.tags()), a.tags()     # geodesic, morphological: four twice
        points = a.group() == "Point clouds" or a.parameterDefinition("INPUT_POINTS") is not None
        if points:
            assert a.id() in lidar, f"{a.id()} works on points but 'lidar' does not find it"
        if a.groupId() == "orthophoto":
            assert a.id() in ortho, a.id()
    filters = {a.id() for a in algs if a.groupId() == "filters"}
    assert filters and filters <= _toolbox_search("terrain") & _toolbox_search("bare earth")
    assert "bareearth:filldtm" in _toolbox_search("nodata")
    assert not _toolbox_search("xyzzy")                           # the search is not "everything"


def github_slug(heading):
    """GitHub's heading anchor (github-slugger): lower case, keep letters, digits, '_', '-' and
    spaces; spaces to '-'."""
    return re.sub(r"[^a-z0-9_\- ]", "", heading.lower()).replace(" ", "-")


def test_github_slug_of_a_readme_heading():
    assert github_slug("`bareearth:slopeprofile`: Slope-profile filter (Luong Chinh Ke 2002)") == \
        "bareearthslopeprofile-slope-profile-filter-luong-chinh-ke-2002"


def test_help_urls_point_at_readme_sections_that_exist(qgis_app):
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    text = re.sub(r"```.*?```", "", text, flags=re.S)
    headings = [m.group(1).strip() for m in re.finditer(r"^#{1,6} (.+)$", text, flags=re.M)]
    anchors = {github_slug(h): h for h in headings}
    for a in _algorithms(qgis_app):
        url = a.helpUrl()
        assert url.startswith("https://github.com/") and "#" in url, url
        anchor = url.split("#", 1)[1]
        assert anchor in anchors, f"{a.id()}: #{anchor} is not a heading of README.md"
        assert f"`{a.id()}`" in anchors[anchor], f"{a.id()}'s help opens '{anchors[anchor]}'"


def test_metadata_about_and_changelog_name_every_algorithm(qgis_app):
    """The plugin manager's texts describe the plugin as it is: every algorithm of the
    provider is named (by its id) in the about text and the changelog."""
    import configparser
    cp = configparser.ConfigParser()
    cp.read(ROOT / "metadata.txt", encoding="utf-8")
    about, changelog = cp["general"]["about"], cp["general"]["changelog"]
    for a in _algorithms(qgis_app):
        assert re.search(rf"\b{a.name()}\b", about), f"metadata about does not name {a.id()}"
        assert re.search(rf"\b{a.name()}\b", changelog), f"metadata changelog does not name {a.id()}"


def test_every_default_is_stated_in_the_parameter_help(qgis_app):
    """``qgis_process help`` (QGIS 3.22, Debian 12's) prints each parameter's help but not its default, so a
    command-line user could not see a default such as geodesic's widest building (64 m) or curvature's
    window: each parameter with a default says it in its help."""
    missing = []
    for alg in _algorithms(qgis_app):
        for d in alg.parameterDefinitions():
            v = d.defaultValue()
            if d.isDestination() or v is None or v == "" or d.type() in ("raster", "source", "vector", "file",
                                                                        "multilayer", "band", "folder"):
                continue
            if not re.search(r"\bdefault\b", d.help(), re.IGNORECASE):
                missing.append(f"{alg.id()} {d.name()} = {v!r}")
    assert not missing, "parameters whose help does not state their default:\n" + "\n".join(missing)


def test_stated_default_reads_as_the_dialog_shows_it(qgis_app):
    from qgis.core import QgsApplication
    reg = QgsApplication.processingRegistry()
    helps = {d.name(): d.help() for d in reg.algorithmById("bareearth:geodesic").parameterDefinitions()}
    assert helps["MIN_WINDOW_M"].endswith(" Default: 2.")
    assert helps["SCAN_LABELLING"].endswith(" Default: yes.")
    helps = {d.name(): d.help() for d in reg.algorithmById("bareearth:morphological").parameterDefinitions()}
    assert helps["MODE"].endswith(" Default: auto.")


def test_every_parameter_is_named_in_its_algorithms_readme_section(qgis_app):
    """A command-line user needs each parameter's key: rascor's section named neither BREAKLINES nor
    SPECIAL_AREAS, geodesic's and morphological's none of their point inputs (INPUT_POINTS, ...), the
    survey's none of its keys (INPUT_LAYERS, SCHEDULER, WORKERS, ...), filldtm's and rasterizepoints'
    not CREATE_OPTIONS / COG. Each key is now named in the section the algorithm's help button opens."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    heads = [(m.start(), len(m.group(1)), github_slug(m.group(2).strip()))
             for m in re.finditer(r"^(#{1,6}) (.+)$", text, flags=re.M)]
    missing = []
    for a in _algorithms(qgis_app):
        anchor = a.helpUrl().split("#", 1)[1]
        i = next(i for i, h in enumerate(heads) if h[2] == anchor)
        end = next((p for p, level, _ in heads[i + 1:] if level <= heads[i][1]), len(text))
        section = text[heads[i][0]:end]
        missing += [f"{a.id()} {d.name()}" for d in a.parameterDefinitions() if f"`{d.name()}`" not in section]
    assert not missing, "parameters the README section of their algorithm does not name:\n" + "\n".join(missing)
