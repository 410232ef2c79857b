"""The contracts every filter promises (README, docs/DEVELOPING.md), checked for every method
of ``available_methods()``, and the code-health rules checked by code (no private imports
across modules, no import cycle among core modules, no hidden method)."""
import importlib.abc
import importlib.util
import sys

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
