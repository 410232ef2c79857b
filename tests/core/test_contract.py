"""The contracts every filter promises (README, docs/DEVELOPING.md), checked for every method
of ``available_methods()``, and the code-health rules checked by code (no private imports
across modules, no import cycle among core modules, no hidden method)."""
import ast
import importlib.abc
import importlib.util
import sys
from pathlib import Path

import pytest

from bare_earth.core import methods


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
