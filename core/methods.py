"""Registry of filter methods.

Each filter module defines ``METHOD = Method(...)``; this module collects them.
The pipeline, the block engine, the plugin and the benchmarks see methods only through
this registry, so adding a paper costs one numeric module and one thin algorithm class.
"""
import importlib
from dataclasses import dataclass, field
from typing import Callable


@dataclass(frozen=True)
class Param:
    """One user parameter of a method (the plugin builds its dialog from these).

    Attributes
    ----------
    name : str
        The keyword of the core function, units in the name (``slope_threshold_deg``).
        The Processing parameter is ``name.upper()``.
    kind : str
        ``"float"``, ``"int"``, ``"bool"`` or ``"enum"``.
    default : object
        Default value; ``None`` means "derived from the data" (by ``Method.resolve``).
    help : str
        One or two sentences with the unit and where the default comes from.
    minimum, maximum : float, optional
        Bounds for numbers.
    options : tuple of str
        Allowed values of an enum (the value passed to the core is the string).
    advanced : bool
        Shown under "Advanced parameters" in the dialog.
    """
    name: str
    kind: str
    default: object = None
    help: str = ""
    minimum: float = None
    maximum: float = None
    options: tuple = ()
    advanced: bool = False


@dataclass(frozen=True)
class Method:
    """A filter method.

    Attributes
    ----------
    name : str
        Short id, also the Processing algorithm name (``bareearth:<name>``).
    run : callable
        ``run(z, cell_size, progress=None, **params) -> FilterResult``; ``params`` are
        complete (as returned by ``resolve``).
    resolve : callable
        ``resolve(z, cell_size, **params) -> dict``: the complete parameter set, with every
        ``None`` replaced by a value derived from the data (on the whole raster or a
        sample of it). Called once per raster, before any block runs.
    halo : callable
        ``halo(params, cell_size) -> int``: the method's reach in cells; blocks overlap by
        at least this much so that blocked and one-pass results agree.
    extras : dict
        Per-cell side products the method returns in ``FilterResult.extras``:
        ``{name: (numpy dtype, bands, nodata)}``.
    params : tuple of Param
        The user parameters, in dialog order.
    title : str
        Display name ("Slope-profile filter (Luong Chinh Ke 2002)").
    description : str
        Help text: what the method does, how the defaults are derived, the paper cited.
    """
    name: str
    run: Callable
    resolve: Callable
    halo: Callable
    extras: dict = field(default_factory=dict)
    params: tuple = ()
    title: str = ""
    description: str = ""


# Modules that define METHOD, in the order the plugin lists them.
_MODULES = ["dtm", "slope_profile", "curvature", "rascor", "geodesic", "morphology"]


def available_methods():
    """Return ``{name: Method}`` for every filter module that imports."""
    found = {}
    for mod in _MODULES:
        try:
            m = importlib.import_module(f"{__package__}.{mod}")
        except ImportError as exc:  # a module not written yet
            if f"{__package__}.{mod}" in str(exc) or mod in str(exc):
                continue
            raise
        meth = getattr(m, "METHOD", None)
        if meth is not None:
            found[meth.name] = meth
    return found


def get_method(name):
    """Return the registered :class:`Method` called ``name`` (ValueError if unknown)."""
    methods = available_methods()
    if name not in methods:
        raise ValueError(f"unknown filter method {name!r}; choose one of {sorted(methods)}.")
    return methods[name]
