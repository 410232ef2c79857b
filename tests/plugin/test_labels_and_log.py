"""Dialog labels written for people, messages naming them, a log people read, and translatable
strings that are constants (tr("... {}").format(x), never tr(f"..."))."""
import ast
import re
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.qgis
ROOT = Path(__file__).resolve().parents[2]


def test_every_param_of_every_method_has_a_written_label():
    from bare_earth.algorithms.labels import has_label
    from bare_earth.core.methods import available_methods, get_method
    missing = [(m, p.name) for m in available_methods() for p in get_method(m).params if not has_label(m, p.name)]
    assert missing == []


def test_dialogs_show_the_written_labels_uniquely(qgis_app):
    from qgis.core import QgsApplication

    from bare_earth.algorithms.compat import FLAG_ADVANCED
    from bare_earth.algorithms.labels import param_label
    from bare_earth.core.methods import get_method
    for alg in QgsApplication.processingRegistry().providerById("bareearth").algorithms():
        labels = [d.description() for d in alg.parameterDefinitions()]
        assert len(labels) == len(set(labels)), (alg.id(), sorted(x for x in labels if labels.count(x) > 1))
        if alg.groupId() != "filters":
            continue
        for p in get_method(alg.name()).params:
            d = alg.parameterDefinition(p.name.upper())
            assert d.description() == param_label(alg.name(), p)      # the written label, not the name
    rascor = QgsApplication.processingRegistry().algorithmById("bareearth:rascor")
    steps = [d for d in rascor.parameterDefinitions() if d.name().startswith("STEP") or d.name() == "SECOND_ITERATION"]
    assert len(steps) == 9                  # the 7 switches, SECOND_ITERATION and STEP3_REPEAT
    assert all(d.flags() & FLAG_ADVANCED for d in steps)


def _dsm(tmp_path, shape=(30, 30)):
    from bare_earth.core.grid import write_array
    z = np.zeros(shape, np.float32)
    z[10:20, 10:20] = 6.0
    return write_array(tmp_path / "dsm.tif", z, (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0), 32632)


def test_core_messages_name_the_label_and_the_id(processing_run, tmp_path):
    from qgis.core import QgsProcessingException
    with pytest.raises(QgsProcessingException, match=r"'Trend window \(cells, odd\)' \(WINDOW_CELLS\)"):
        processing_run("bareearth:curvature", {"INPUT": _dsm(tmp_path), "WINDOW_CELLS": 4,
                                               "OUTPUT_DTM": str(tmp_path / "o.tif"),
                                               "OUTPUT_MASK": str(tmp_path / "m.tif")})


class _Log:
    def __init__(self):
        from qgis.core import QgsProcessingFeedback
        self.lines = []
        self.feedback = QgsProcessingFeedback()
        self.feedback.pushInfo = lambda s: self.lines.append(("info", s))
        self.feedback.pushWarning = lambda s: self.lines.append(("warning", s))
        self.feedback.reportError = lambda s, fatal=False: self.lines.append(("error", s))

    def section(self, start, stop):
        text = [s for _, s in self.lines]
        i = text.index(start)
        j = text.index(stop, i) if stop in text[i:] else len(text)
        return text[i + 1:j]


def test_log_parameters_and_result_do_not_repeat(processing_run, tmp_path):
    for alg in ("geodesic", "slopeprofile", "rascor"):
        log = _Log()
        processing_run(f"bareearth:{alg}", {"INPUT": _dsm(tmp_path), "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                            "OUTPUT_MASK": "TEMPORARY_OUTPUT"}, feedback=log.feedback)
        used = log.section("Parameters used:", "Result:")
        result = log.section("Result:", "__end__")
        assert used and result
        values = {re.search(r"\((\w+)\) = (.*)$", s).group(1).lower(): re.search(r"= (.*)$", s).group(1)
                  for s in used}
        for line in result:
            key = line.strip().split(" ")[0].rstrip(":")
            assert key not in values, f"{alg}: {key} in both Parameters used and Result"
        assert all(re.match(r"  '.+' \([A-Z0-9_]+\) = ", s) for s in used), used
        for line in result:
            if "percent" in line or "share" in line or "fraction" in line:
                assert "%" in line, line
            assert not re.match(r"  (halo_cells|blocks|removed_scan|removed_edge|\w+_outliers) = \d+\.\d", line)


def test_log_warnings_are_not_doubled(processing_run, tmp_path):
    from bare_earth.core.grid import write_array
    log = _Log()
    src = write_array(tmp_path / "nocrs.tif", np.zeros((30, 30), np.float32), (0, 1, 0, 30, 0, -1))
    processing_run("bareearth:slopeprofile", {"INPUT": src, "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                              "OUTPUT_MASK": "TEMPORARY_OUTPUT"}, feedback=log.feedback)
    warnings = [s for kind, s in log.lines if kind == "warning"]
    assert warnings and not any(s.lower().startswith("warning") for s in warnings)


def test_evaluate_log_says_what_the_cells_are(processing_run, tmp_path):
    from bare_earth.core.grid import write_array
    gt = (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0)
    truth = np.zeros((20, 20), np.uint8)
    truth[5:10, 5:10] = 1
    result = truth.copy()
    result[0, :3] = 1                 # 3 ground cells rejected (b)
    result[5, 5] = 0                  # 1 object accepted (c)
    write_array(tmp_path / "t.tif", truth, gt, 32632, nodata=255)
    write_array(tmp_path / "r.tif", result, gt, 32632, nodata=255)
    log = _Log()
    processing_run("bareearth:evaluate", {"MASK": str(tmp_path / "r.tif"), "REFERENCE_MASK": str(tmp_path / "t.tif"),
                                          "OUTPUT_JSON": "TEMPORARY_OUTPUT", "OUTPUT_HTML": "TEMPORARY_OUTPUT"},
                   feedback=log.feedback)
    text = "\n".join(s for _, s in log.lines)
    assert re.search(r"a: ground kept as ground\s+372 cells", text)
    assert re.search(r"b: ground rejected \(Type I errors\)\s+3 cells", text)
    assert re.search(r"c: objects accepted as ground \(Type II errors\)\s+1 cells", text)
    assert re.search(r"d: objects rejected\s+24 cells", text)
    assert re.search(r"Type I error, b / \(a \+ b\)\s+0\.8 %", text)
    assert re.search(r"Type II error, c / \(c \+ d\)\s+4 %", text)


def _tr_calls_with_fstrings(path):
    tree = ast.parse(path.read_text(encoding="utf-8"))
    bad = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and node.args and (
                isinstance(node.func, ast.Name) and node.func.id == "tr"
                or isinstance(node.func, ast.Attribute) and node.func.attr == "tr"):
            if any(isinstance(n, ast.JoinedStr) for n in ast.walk(node.args[0])):
                bad.append(f"{path.name}:{node.lineno}")
    return bad


def test_translatable_strings_are_constants():
    bad = [b for f in sorted((ROOT / "algorithms").glob("*.py")) for b in _tr_calls_with_fstrings(f)]
    assert bad == [], "tr(f'...') cannot be translated; use tr('... {}').format(x): " + ", ".join(bad)


def test_refusals_name_the_label_and_the_id(processing_run, tmp_path):
    from qgis.core import QgsProcessingException
    with pytest.raises(QgsProcessingException, match=r"'Mask codes to fill' \(FILL_CODES\) must be integers"):
        processing_run("bareearth:filldtm", {"INPUT": _dsm(tmp_path), "MASK": _dsm(tmp_path), "FILL_CODES": "a,b",
                                             "OUTPUT": "TEMPORARY_OUTPUT"})


def test_names_in_paths_are_left_alone(qgis_app):
    from qgis.core import QgsApplication
    alg = QgsApplication.processingRegistry().algorithmById("bareearth:slopeprofile")
    msg = alg.explain("cannot write /tmp/x/OUTPUT_DTM.tif: OUTPUT_MASK and 'DTM' (OUTPUT_DTM) and tolerance_m")
    assert msg == ("cannot write /tmp/x/OUTPUT_DTM.tif: 'Object mask' (OUTPUT_MASK) and 'DTM' (OUTPUT_DTM) and "
                   "'Height tolerance (m)' (TOLERANCE_M)")


def test_a_label_holding_a_parameter_name_is_given_once(processing_run, tmp_path):
    """morphological's SLOPE (the core's ``slope``) is labelled 'Terrain slope (rise/run)': each of the
    nested checks named the word in the label again, 'Terrain 'Terrain 'Terrain 'Terrain slope
    (rise/run)' (SLOPE) (rise/run)' (SLOPE) (rise/run)' (SLOPE) (rise/run)' (SLOPE) = -1'. Labels
    already given are kept, and single-word names (slope, mode, model) are named only as the
    core writes them, ``slope = ...`` / ``slope must ...``."""
    from qgis.core import QgsApplication, QgsProcessingException
    with pytest.raises(QgsProcessingException) as err:
        processing_run("bareearth:morphological", {"INPUT": _dsm(tmp_path), "SLOPE_FACTOR": -1,
                                                   "OUTPUT_DTM": "TEMPORARY_OUTPUT", "OUTPUT_MASK": "TEMPORARY_OUTPUT"})
    assert str(err.value).endswith("'Slope factor (m per unit slope)' (SLOPE_FACTOR) = -1 is out of range: give a "
                                   "value within [0, 1000].")
    alg = QgsApplication.processingRegistry().algorithmById("bareearth:morphological")
    once = alg.explain("slope = -1 is out of range; mode must be one of ...; on a steep slope the mode of")
    assert once == ("'Terrain slope (rise/run)' (SLOPE) = -1 is out of range; 'Single or progressive windows' "
                    "(MODE) must be one of ...; on a steep slope the mode of")
    assert alg.explain(once) == once


@pytest.mark.parametrize("key,value,message", [
    ("THREADS", 1000, r"'Threads \(0 = one per core\)' \(THREADS\) = 1000 is out of range: give a value within "
                      r"\[0, 64\]"),
    ("PROCESSES", 0, r"'Worker processes' \(PROCESSES\) = 0 is out of range: give a value within \[1, 64\]"),
    ("EDGE_LENGTH_M", -1, r"'Object edge length \(m\)' \(EDGE_LENGTH_M\) = -1 is out of range: give a value"),
])
def test_a_number_out_of_range_is_refused_naming_its_label_and_range(processing_run, tmp_path, key, value, message):
    """QGIS's refusal of a number beyond its limits said "Incorrect parameter value for THREADS":
    neither the label nor the range. It names both now."""
    from qgis.core import QgsProcessingException
    with pytest.raises(QgsProcessingException, match=message):
        processing_run("bareearth:slopeprofile", {"INPUT": _dsm(tmp_path), key: value, "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                                  "OUTPUT_MASK": "TEMPORARY_OUTPUT"})


def _switches_on_by_default():
    from bare_earth.core.methods import available_methods, get_method
    return [(m, p.name.upper()) for m in available_methods() for p in get_method(m).params
            if p.kind == "bool" and p.default]


@pytest.mark.parametrize("alg,key", _switches_on_by_default(), ids=lambda v: str(v))
def test_an_empty_switch_keeps_its_default(processing_run, tmp_path, alg, key):
    """An empty yes/no (qgis_process ``KEY=``, processing.run ``''``) is its default, as an empty number is
    derived: QGIS reads '' as false, which turned off RASCOR's continuing ground, geodesic's raised regions
    and the like without a word."""
    log = _Log()
    processing_run(f"bareearth:{alg}", {"INPUT": _dsm(tmp_path), "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                        "OUTPUT_MASK": "TEMPORARY_OUTPUT", key: ""}, feedback=log.feedback)
    used = [s for s in log.section("Parameters used:", "Result:") if f"({key}) = " in s]
    assert len(used) == 1 and used[0].endswith(f"({key}) = True"), used


def test_help_names_outputs_and_parameters_by_their_ids(qgis_app):
    """Help that names an output names it by its id (curvature's said 'The CURVATURE output' and
    geodesic's 'Output STEP:' for OUTPUT_CURVATURE and OUTPUT_STEP, ids no one can type), and the
    ids with an underscore it names are parameters of a Bare Earth algorithm (a filter's
    INPUT_POINTS in evaluate's) or the memory variable."""
    from qgis.core import QgsApplication
    algs = [a for a in QgsApplication.processingRegistry().algorithms() if a.provider().id() == "bareearth"]
    every = {d.name() for a in algs for d in a.parameterDefinitions()} | {"BARE_EARTH_MEMORY_MB"}
    for a in algs:
        text = a.shortHelpString() + " ".join(d.help() or "" for d in a.parameterDefinitions())
        outputs = {d.name() for d in a.destinationParameterDefinitions()}
        named = set(re.findall(r"\b(?:The|Output) ([A-Z][A-Z0-9_]{2,})(?= output|:)", text))
        assert named <= outputs, (a.id(), named - outputs)
        ids = set(re.findall(r"\b[A-Z][A-Z0-9]*_[A-Z0-9_]+\b", text))
        assert ids <= every, (a.id(), ids - every)


@pytest.mark.parametrize("value,message", [
    ("progressive", r"'Single or progressive windows' \(MODE\) = 'progressive' is not one of its options' numbers: "
                    r"give 1 \(0 = auto, 1 = progressive, 2 = single\)"),
    (7, r"'Single or progressive windows' \(MODE\) = '7' is not one of its options' numbers \(0 = auto, 1 = "),
])
def test_a_choice_given_by_name_is_refused_naming_its_number(processing_run, tmp_path, value, message):
    """MODE=progressive (the option as the help and the log write it) was refused with QGIS's 'Incorrect
    parameter value for MODE': neither the label nor the options. QGIS takes a choice by its number."""
    from qgis.core import QgsProcessingException
    with pytest.raises(QgsProcessingException, match=message):
        processing_run("bareearth:morphological", {"INPUT": _dsm(tmp_path), "MODE": value,
                                                   "OUTPUT_DTM": "TEMPORARY_OUTPUT", "OUTPUT_MASK": "TEMPORARY_OUTPUT"})


def test_the_runs_information_is_not_shown_as_warnings(processing_run, tmp_path):
    """Every line the core logged during a run went to QGIS's warnings (orange, "WARNING" in
    qgis_process): the empty cells filled, the window the parameters came from, the blocks. The
    core marks its warnings ("Warning: "); its other lines are information."""
    from bare_earth.core.grid import write_array
    z = np.zeros((40, 40), np.float32)
    z[10:20, 10:20] = 6.0
    z[30, 5] = np.nan                                   # an empty cell: filled, logged as information
    z[5, 30] = 1e7                                      # a height no terrain has: a warning
    src = write_array(tmp_path / "dsm.tif", z, (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0), 32632)
    log = _Log()
    processing_run("bareearth:morphological", {"INPUT": src, "OUTPUT_DTM": "TEMPORARY_OUTPUT",
                                               "OUTPUT_MASK": "TEMPORARY_OUTPUT"}, feedback=log.feedback)
    infos = [s for kind, s in log.lines if kind == "info"]
    warnings = [s for kind, s in log.lines if kind == "warning"]
    assert any("empty cell(s) enclosed by data" in s for s in infos), log.lines
    assert not any("empty cell(s) enclosed by data" in s for s in warnings), warnings
    assert any(s.startswith("1 cell(s) with heights beyond +-100000 m") for s in warnings), warnings
