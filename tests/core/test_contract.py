"""The contracts every filter promises (README, docs/DEVELOPING.md), checked for every method
of ``available_methods()``, and the code-health rules checked by code (no private imports
across modules, no import cycle among core modules, no hidden method)."""
import ast
import functools
import importlib.abc
import importlib.util
import re
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from bare_earth.core import methods, pipeline, synthetic
from bare_earth.core.codes import GROUND, LOW, NODATA, OBJECT


class _BrokenFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds ``bare_earth.core.<name>`` and fails while executing it, as a method module with
    a missing dependency (or a missing sibling module) does."""

    def __init__(self, name, body):
        self.fullname, self.body = f"bare_earth.core.{name}", body

    def find_spec(self, fullname, path=None, target=None):
        if fullname == self.fullname:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        return None

    def exec_module(self, module):
        exec(self.body, module.__dict__)


@pytest.mark.parametrize("name,body", [
    # a sibling module missing: the message names the method's own module
    ("curvature_x", "from . import curvature_x_kernels\n"),
    # a third-party dependency missing
    ("broken_method", "import no_such_dependency_xyz\n"),
])
def test_available_methods_does_not_hide_a_failing_import(monkeypatch, name, body):
    finder = _BrokenFinder(name, body)
    monkeypatch.setattr(sys, "meta_path", [finder] + sys.meta_path)
    monkeypatch.setattr(methods, "METHOD_MODULES", methods.METHOD_MODULES + (name,))
    monkeypatch.delitem(sys.modules, finder.fullname, raising=False)
    with pytest.raises(ImportError):
        methods.available_methods()


def test_available_methods_refuses_a_listed_module_without_method(monkeypatch):
    monkeypatch.setattr(methods, "METHOD_MODULES", methods.METHOD_MODULES + ("codes",))
    with pytest.raises(TypeError, match="METHOD"):
        methods.available_methods()


def test_every_listed_module_gives_a_method():
    found = methods.available_methods()
    assert len(found) == len(methods.METHOD_MODULES)


# --------------------------------------------------------------------------- code rules
ROOT = Path(__file__).resolve().parents[2]
SCANNED = ("core", "algorithms", "benchmarks", "scripts")


def _python_files():
    for d in SCANNED:
        yield from sorted((ROOT / d).rglob("*.py"))


def _is_private(name):
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def private_uses(path):
    """``(line, text)`` of every use in ``path`` of another module's private name: ``from x
    import _name`` and ``module._name`` where ``module`` was imported."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    modules, found = set(), []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            modules.update((a.asname or a.name).split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            for a in node.names:
                if _is_private(a.name):
                    found.append((node.lineno, f"from {'.' * node.level}{node.module or ''} import {a.name}"))
                modules.add(a.asname or a.name)
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                and node.value.id in modules and _is_private(node.attr)):
            found.append((node.lineno, f"{node.value.id}.{node.attr}"))
    return found


def test_private_use_detector_sees_both_forms(tmp_path):
    p = tmp_path / "m.py"
    p.write_text("from .points import _slope, ok\nfrom . import pipeline as pl\nimport numpy as np\n"
                 "def f(self):\n    return pl._method(1), self._x, np.__version__, ok._y\n")
    assert sorted(t for _, t in private_uses(p)) == ["from .points import _slope", "ok._y", "pl._method"]


def test_no_module_uses_another_modules_private_names():
    bad = [f"{p.relative_to(ROOT)}:{line}: {text}" for p in _python_files() for line, text in private_uses(p)]
    assert not bad, "private names used across modules (make them public or move them):\n" + "\n".join(bad)


def _core_imports():
    """``{module: set of core modules it imports}`` for every module of the core package
    (imports inside functions included: a cycle through a lazy import is still a cycle)."""
    core = ROOT / "core"
    names = {}
    for p in core.rglob("*.py"):
        rel = p.relative_to(core).with_suffix("")
        parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
        names[".".join(parts)] = p
    graph = {}
    for mod, p in names.items():
        pkg = [x for x in (mod.split(".") if p.name == "__init__.py" else mod.split(".")[:-1]) if x]
        deps = set()
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.ImportFrom) or node.level == 0:
                continue
            base = pkg[:len(pkg) - (node.level - 1)] if node.level > 1 else list(pkg)
            if node.level - 1 > len(pkg):
                continue                                   # above core: the plugin package
            target = base + (node.module.split(".") if node.module else [])
            for a in node.names:
                for cand in (".".join(target + [a.name]), ".".join(target)):
                    if cand in names and cand != mod:
                        deps.add(cand)
                        break
        graph[mod] = deps
    return graph


def _find_cycle(graph):
    state, stack = {}, []

    def visit(n):
        state[n] = 1
        stack.append(n)
        for m in sorted(graph.get(n, ())):
            if state.get(m) == 1:
                return stack[stack.index(m):] + [m]
            if m not in state:
                c = visit(m)
                if c:
                    return c
        stack.pop()
        state[n] = 2
        return None

    for n in sorted(graph):
        if n not in state:
            c = visit(n)
            if c:
                return c
    return None


def test_cycle_detector_finds_a_cycle():
    assert _find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert _find_cycle({"a": {"b"}, "b": set()}) is None


def test_no_import_cycle_among_core_modules():
    graph = _core_imports()
    assert "blocks" in graph["pipeline"] and "common" in graph[""]   # the parser sees the imports
    # a package's __init__ re-exporting its modules is not a cycle of the modules themselves
    graph = {m: {d for d in deps if not (m.startswith(d + ".") or d == "")} for m, deps in graph.items()
             if m != ""}
    cycle = _find_cycle(graph)
    assert cycle is None, "import cycle among core modules: " + " -> ".join(cycle)


# --------------------------------------------------------------------------- filter contracts
METHODS = sorted(methods.available_methods())


@functools.lru_cache(maxsize=None)
def _scene(name):
    """Synthetic scenes with known truth: ``(dsm, cell_size)``."""
    if name == "city_holes":          # nodata holes and a nodata border strip, non-square cells
        sc = synthetic.make_scene("city", shape=(200, 170), cell_size=(0.5, 0.6), seed=5, nodata_holes=True)
        return sc.dsm, (0.5, 0.6)
    if name == "mixed":
        sc = synthetic.make_scene("mixed", shape=(160, 192), cell_size=1.0, seed=3)
        return sc.dsm, (1.0, 1.0)
    if name == "integral":            # integral heights >= 1 m, no nodata: every dtype holds them
        sc = synthetic.make_scene("city", shape=(96, 112), cell_size=1.0, seed=7)
        z = np.round(sc.dsm - np.floor(np.nanmin(sc.dsm)) + 1.0)
        assert z.max() < 30000
        return z.astype(np.float64), (1.0, 1.0)
    if name == "small":
        sc = synthetic.make_scene("city", shape=(48, 56), cell_size=1.0, seed=2)
        return sc.dsm, (1.0, 1.0)
    raise KeyError(name)


@functools.lru_cache(maxsize=None)
def _one_pass(method, scene):
    z, cell = _scene(scene)
    return pipeline.run_array(method, z, cell)


@pytest.mark.parametrize("scene", ["city_holes", "mixed"])
@pytest.mark.parametrize("block,workers", [(48, 1), ((37, 61), 2)])
@pytest.mark.parametrize("method", METHODS)
def test_blocked_equals_one_pass(method, scene, block, workers):
    """Blocks smaller than the buildings (cut through objects and holes), in threads or not:
    the mask is the one-pass mask, cell for cell."""
    z, cell = _scene(scene)
    one = _one_pass(method, scene)
    blk = pipeline.run_array(method, z, cell, block=block, workers=workers)
    assert blk.info["blocks"] > 4
    diff = int(np.count_nonzero(blk.mask != one.mask))
    assert diff == 0, f"{diff} cells differ between blocks {block} and one pass"


@pytest.mark.parametrize("method", METHODS)
def test_input_not_modified(method):
    z, cell = _scene("city_holes")
    z = z.astype(np.float32)                   # float32: as_surface passes it through uncopied
    before = z.copy()
    meth = methods.available_methods()[method]
    params = meth.resolve(z, cell, **pipeline.complete_params(meth, None))
    np.testing.assert_array_equal(z, before)
    meth.run(z, cell, **params)
    np.testing.assert_array_equal(z, before)
    pipeline.run_array(method, z, cell, block=64)
    np.testing.assert_array_equal(z, before)


@pytest.mark.parametrize("method", METHODS)
def test_nodata_coded_255_and_only_there(method):
    z, cell = _scene("city_holes")
    res = _one_pass(method, "city_holes")
    nodata = ~np.isfinite(z)
    assert nodata.any()
    np.testing.assert_array_equal(res.mask == NODATA, nodata)
    assert set(np.unique(res.mask[~nodata])) <= {GROUND, OBJECT, LOW}
    assert np.isnan(res.dtm[nodata]).all() and np.isfinite(res.dtm[~nodata]).all()
    meth = methods.available_methods()[method]
    direct = meth.run(z, cell, **res.info["params"])          # the method itself codes nodata 255
    np.testing.assert_array_equal(np.asarray(direct.mask) == NODATA, nodata)


@pytest.mark.parametrize("method", METHODS)
def test_progress_from_inside_the_stages_and_cancel_stops_at_once(method):
    """Progress comes from inside the method's stages (many calls), never goes back and ends
    at 1; a Cancelled raised by the N-th call stops the run there (no later call)."""
    from bare_earth.core.common import Cancelled
    z = synthetic.make_scene("city", shape=(400, 400), cell_size=1.0, seed=3).dsm
    meth = methods.available_methods()[method]
    params = meth.resolve(z, (1.0, 1.0), **pipeline.complete_params(meth, None))
    seen = []
    meth.run(z, (1.0, 1.0), progress=seen.append, **params)
    assert len(seen) >= 10 and seen == sorted(seen) and seen[-1] == 1.0
    for n in (1, len(seen) // 2, len(seen) - 1):
        calls = []

        def stop(f, n=n, calls=calls):
            calls.append(f)
            if len(calls) == n:
                raise Cancelled()
        with pytest.raises(Cancelled):
            meth.run(z, (1.0, 1.0), progress=stop, **params)
        assert len(calls) == n


@pytest.mark.parametrize("method", METHODS)
def test_every_input_dtype_gives_the_same_mask(method):
    z64, cell = _scene("integral")
    meth = methods.available_methods()[method]
    masks = {}
    for dt in (np.float32, np.float64, np.int16, np.uint16):
        z = z64.astype(dt)
        params = meth.resolve(z, cell, **pipeline.complete_params(meth, None))
        masks[np.dtype(dt).name] = np.asarray(meth.run(z, cell, **params).mask)
    for name, m in masks.items():
        diff = int(np.count_nonzero(m != masks["float32"]))
        assert diff == 0, f"{name}: {diff} cells differ from float32"


def _bound_cases():
    for name in METHODS:
        meth = methods.available_methods()[name]
        for p in meth.params:
            if p.kind not in ("float", "int"):
                continue
            for side, bound in (("min", p.minimum), ("max", p.maximum)):
                if bound is not None:
                    yield pytest.param(name, p.name, side, id=f"{name}-{p.name}-{side}")


def _outside(p, side):
    bound = p.minimum if side == "min" else p.maximum
    if p.kind == "int":
        return int(bound) - 1 if side == "min" else int(bound) + 1
    step = max(1e-6, 1e-6 * abs(bound))
    return bound - step if side == "min" else bound + step


@pytest.mark.parametrize("method,param,side", list(_bound_cases()))
def test_param_limits_are_the_limits_the_core_enforces(method, param, side):
    """A value at a ``Param``'s bound is accepted by the whole run; a value just outside it is
    refused by the core itself (resolve or run with ValueError), not only by the pipeline's
    check of the ``Param`` limits: the dialog, the checks and the core agree."""
    meth = methods.available_methods()[method]
    p = {q.name: q for q in meth.params}[param]
    bound = p.minimum if side == "min" else p.maximum
    z, cell = _scene("small")
    res = pipeline.run_array(method, z, cell, params={param: int(bound) if p.kind == "int" else bound})
    assert res.info["params"][param] == bound
    bad = _outside(p, side)
    with pytest.raises(ValueError):
        pipeline.run_array(method, z, cell, params={param: bad})
    full = dict(pipeline.complete_params(meth, None), **{param: bad})   # past the Param check
    with pytest.raises(ValueError):
        params = meth.resolve(z, cell, **full)
        meth.run(z, cell, **params)


@pytest.mark.parametrize("method", METHODS)
def test_defaults_are_stated_in_the_info(method):
    """Every parameter left empty is derived, and the value used is in the result's info
    (the log shows it). A value may stay empty only when the step using it did not run and
    the info's notes say so."""
    meth = methods.available_methods()[method]
    res = _one_pass(method, "mixed")
    used = res.info["params"]
    notes = res.info.get("notes", [])
    for p in meth.params:
        assert p.name in used, f"{p.name} missing from the info"
        v = used[p.name]
        if v is None:
            step = re.match(r"Step (\d+)", p.help)
            assert step and any(n.startswith(step.group(1) + ":") and "skipped" in n for n in notes), \
                f"{p.name}: derived value not stated"
            continue
        if p.kind == "float":
            assert np.isfinite(float(v)), (p.name, v)
            if p.minimum is not None:
                assert v >= p.minimum, (p.name, v)
            if p.maximum is not None:
                assert v <= p.maximum, (p.name, v)


@pytest.mark.parametrize("method", [m for m in METHODS
                                    if "max_object_size_m" in [p.name for p in methods.get_method(m).params]])
def test_float_noise_of_the_cell_size_changes_nothing(method):
    """A window given in metres is the same number of cells whether the cell size is 1 m or
    1.0000000000000002 m (1 m cells in a US-feet CRS, a cell size computed from an extent):
    before, floor(30 / 1.0000000000000002) made morphological's 30 m window a cell narrower
    (754 mask cells of this scene differed) and curvature's profiles shorter (155)."""
    sc = synthetic.make_scene("city", shape=(160, 180), seed=11, nodata_holes=True)
    params = {"max_object_size_m": 30.0}
    a = pipeline.run_array(method, sc.dsm, 1.0, params, want_dtm=False)
    for noisy in (1.0000000000000002, 0.9999999999999999):
        b = pipeline.run_array(method, sc.dsm, noisy, params, want_dtm=False)
        assert np.array_equal(a.mask, b.mask), (method, noisy, int((a.mask != b.mask).sum()))


@pytest.mark.parametrize("method", METHODS)
def test_far_heights_never_reach_a_filter(method):
    """+-1e30 cells (an undeclared nodata) are nodata, with a log line and no numpy warning."""
    z, cell = _scene("mixed")
    z = z.copy()
    z[40, 50], z[90, 120], z[91, 120] = 1e30, -1e30, -3.4e38
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        res = pipeline.run_array(method, z, cell)
    assert all(res.mask[rc] == NODATA for rc in ((40, 50), (90, 120), (91, 120)))
    assert any("3 cell" in w for w in res.info["warnings"])
    one = _one_pass(method, "mixed")
    far = np.zeros(z.shape, bool)
    far[40, 50] = far[90, 120] = far[91, 120] = True
    assert np.count_nonzero((res.mask != one.mask) & ~far) < 0.01 * z.size


# ---- #15 defect 4: blocked and threaded equal one pass on large and real DSMs ----------------

@functools.lru_cache(maxsize=None)
def _big_city():
    sc = synthetic.make_dsm(4_000_000)
    return sc.dsm


@functools.lru_cache(maxsize=None)
def _big_one_pass(method):
    return pipeline.run_array(method, _big_city(), 1.0).mask


@pytest.mark.slow
@pytest.mark.parametrize("workers", [1, 2])
@pytest.mark.parametrize("method", METHODS)
def test_blocked_equals_one_pass_4_mcells(method, workers):
    blk = pipeline.run_array(method, _big_city(), 1.0, block=256, workers=workers)
    diff = int(np.count_nonzero(blk.mask != _big_one_pass(method)))
    assert diff == 0, f"{diff} cells differ (block 256, {workers} thread(s))"


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
def test_blocked_equals_one_pass_at_an_odd_block_size(method):
    """A block size no coarse grid divides (333): the windows' corners are moved onto the
    halo's alignment (blocks.alignment), so geodesic's power-of-two grids and curvature's
    2 x 2 grid are those of the single pass (geodesic differed by 2 cells on 1 Mcells
    before)."""
    blk = pipeline.run_array(method, _big_city(), 1.0, block=333, workers=2)
    diff = int(np.count_nonzero(blk.mask != _big_one_pass(method)))
    assert diff == 0, f"{diff} cells differ (block 333, 2 threads)"


def _read_mask(path):
    from osgeo import gdal
    ds = gdal.Open(str(path))                 # kept alive while its band is read
    return ds.GetRasterBand(1).ReadAsArray()


@functools.lru_cache(maxsize=None)
def _pleiades_one_pass(method, src, folder):
    """The one pass's mask and halo (cells), once per method for the parameter sets."""
    out = Path(folder) / f"{method}-one.tif"
    info = pipeline.run_file(method, src, {"mask": out}, workers=1)
    return _read_mask(out), int(info["halo_cells"])


@pytest.mark.slow
@pytest.mark.parametrize("block,workers", [(256, 1), (256, 2), (None, 2)])
@pytest.mark.parametrize("method", METHODS)
def test_blocked_and_threaded_equal_one_pass_on_pleiades(shared_data, tmp_path_factory, method, block, workers):
    src = shared_data / "raster" / "pleiades" / "triplet_dsm.tif"
    if not src.exists():
        pytest.skip(f"{src} is absent")
    folder = tmp_path_factory.getbasetemp() / "pleiades-one-pass"
    folder.mkdir(exist_ok=True)
    one, halo = _pleiades_one_pass(method, str(src), str(folder))
    if block is not None and halo >= max(one.shape):
        # every block's window is the whole raster: the blocked run is the one pass 16 times over
        # (dtm: a halo of 1920 cells; 15 of the suite's 33 minutes), its equality only determinism
        pytest.skip(f"{method}'s halo ({halo} cells) spans the {one.shape} raster: no block of its own")
    out = tmp_path_factory.mktemp("pleiades") / "mask.tif"
    pipeline.run_file(method, src, {"mask": out}, block=block, workers=workers)
    diff = int(np.count_nonzero(_read_mask(out) != one))
    assert diff == 0, f"{diff} cells differ (block {block}, {workers} thread(s))"


@pytest.mark.parametrize("method", METHODS)
def test_a_run_ends_on_an_undeclared_nodata_cliff(method):
    """A DSM whose nodata (-9999) is not declared: a 10 km cliff beside the terrain. Every
    method's run ends (morphological and dtm stopped with "outline_slope = 257.4 is out of range
    [0.0, 100.0]": a value derived from the data refused by its own limits, named as if the
    user had set it)."""
    z, cell = _scene("mixed")
    z = z.copy()
    z[:, :24] = -9999.0
    res = pipeline.run_array(method, z, cell)
    assert res.mask.shape == z.shape and (res.mask != NODATA).all()


@pytest.mark.parametrize("method", ["slopeprofile", "rascor", "dtm"])
def test_filters_asking_the_shared_pit_tests_find_lines_of_blunders_along_walls(method):
    """Issue 12 (ISPRS samp41): multipath blunders 25 m below the ground in lines of 26 and
    20 cells along the two long walls of a 15 m building. Each had others of its line in its
    ring and a rim of wall and ground: the filters asking the shared pit tests kept all 46
    as ground and the DTM dipped 25 m along the walls (estimate.below_narrow_gap). Nearly
    all low now (a line's end may stay: it has ground at its own level on one side), no
    other low cell, no ground lost, no dip in the DTM but at such an end and the low cells
    beside it (filled from it once the building is an object: slopeprofile's raised runs)."""
    rng = np.random.default_rng(0)
    z = (100 + rng.normal(0, 0.05, (80, 80))).astype(np.float32)
    z[20:40, 20:50] += 15.0
    z[40, 22:48] -= 25.0
    z[19, 25:45] -= 25.0
    line = z < 90.0
    r = pipeline.run_array(method, z, 1.0)
    assert (r.mask[line] == LOW).sum() >= line.sum() - 2
    assert not ((r.mask == LOW) & ~line).any()
    assert (r.mask[~line & (z < 105.0)] == 0).all()
    ends = line & (r.mask != LOW)
    assert ends.sum() <= 2
    beside = np.zeros(z.shape, bool)                               # an end and its neighbours
    for dr, dc in np.argwhere(np.ones((3, 3), bool)) - 1:
        beside |= np.roll(ends, (dr, dc), axis=(0, 1))
    assert not (line & ~beside & (r.dtm < 95.0)).any()             # no dip along the walls


@pytest.mark.parametrize("method", METHODS)
def test_every_filter_finds_low_blunders_that_hide_each_other(method):
    """Issue 12, on a 100 x 120 city clip at 1 m (seed 3): two 2 x 2 pits 18-19 m deep lie
    10 m apart in open ground, each below every cell of the other's 10 m ring but the other
    pit. RASCOR and the slope-profile filter found 1 of the 9 low cells (each pit gave the
    other back) and kept a pit 19 m deep in the DTM, until the level rim just around a pit
    (:func:`~bare_earth.core.estimate.below_level_rim`) decided them; geodesic found the 9
    and 14 false ones (6 on the last column under truncated border windows, 8 gaps and dips
    opening onto lower ground), until its closing's windows hung over the border and a low
    outlier had to be a pit. Every filter: the 9 found, no other low cell, the DTM's pit gone."""
    s = synthetic.make_scene("city", (100, 120), 1.0, seed=3)
    truth = s.mask == LOW
    assert truth.sum() == 9
    r = pipeline.run_array(method, s.dsm, 1.0)
    assert (r.mask[truth] == LOW).all()
    assert not ((r.mask == LOW) & ~truth).any(), np.argwhere((r.mask == LOW) & ~truth)
    assert np.abs(r.dtm - s.dtm)[truth].max() < 0.5
