"""Registry of filter methods.

Each filter module defines ``METHOD = Method(...)``; this module collects them.
The pipeline, the block engine, the plugin and the benchmarks see methods only through
this registry, so adding a paper costs one numeric module and one thin algorithm class.
"""
import importlib
import inspect
import numbers
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, Optional, Tuple

import numpy as np


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
    former_defaults : tuple
        Defaults of earlier versions. Models and scripts saved then store them as given values;
        the plugin's checks treat them as a default (a default window larger than a small raster
        is clamped by the core, not refused).
    """
    name: str
    kind: str
    default: Any = None
    help: str = ""
    minimum: Optional[float] = None
    maximum: Optional[float] = None
    options: Tuple[str, ...] = ()
    advanced: bool = False
    former_defaults: Tuple[Any, ...] = ()


def check_values(method_name: str, params: Tuple[Param, ...], values: Dict[str, Any]) -> None:
    """Refuse a number outside its :class:`Param`'s ``[minimum, maximum]`` (NaN too), and a
    value of the wrong kind: a number parameter given anything but a real number (text such
    as ``"30"``, a list, a complex, True / False), a yes/no parameter anything but True /
    False (or 0 / 1): ``"no"`` was read as yes.

    The one copy of the limits check: every ``Method.resolve`` runs it on the values it is
    given (``None``, derived later, is not checked), so the limits the dialog shows are the
    limits the core enforces.

    Raises
    ------
    ValueError
        Naming the parameter, the range and the parameter's help.
    """
    for p in params:
        value = values.get(p.name)
        if value is None:
            continue
        if p.kind == "bool":
            if not isinstance(value, (bool, np.bool_)) and not (isinstance(value, numbers.Integral)
                                                                 and value in (0, 1)):
                raise ValueError(f"{p.name} = {value!r} is not True or False for method {method_name!r}: give "
                                 f"True or False (text such as 'no' is not read). {p.help}")
            continue
        if p.kind not in ("float", "int"):
            continue
        if isinstance(value, np.ndarray) and value.ndim == 0 and value.dtype.kind in "iuf":
            value = value.item()                                          # a 0-d array a derivation returned
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
            raise ValueError(f"{p.name} = {value!r} is not a number for method {method_name!r}: give a number "
                             f"(not text or {type(value).__name__}), or None to derive it. {p.help}")
        if ((p.minimum is not None and not value >= p.minimum)          # NaN is out of range too
                or (p.maximum is not None and not value <= p.maximum)):
            raise ValueError(f"{p.name} = {value} is out of range [{p.minimum}, {p.maximum}] for method "
                             f"{method_name!r}: {p.help}")


def _takes_progress(func) -> bool:
    """Whether ``func`` has a keyword parameter named ``progress``."""
    try:
        return "progress" in inspect.signature(func).parameters
    except (TypeError, ValueError):
        return False


class _CheckedResolve:
    """A method's ``resolve`` with its ``Param`` limits and its ``check`` run first (picklable:
    worker processes receive the Method). ``progress`` (optional, may raise ``Cancelled``) goes
    to a resolve that takes one (its estimates report through it)."""

    def __init__(self, resolve, method_name, params, check=None):
        self.resolve, self.method_name, self.params, self.check = resolve, method_name, params, check

    def __call__(self, z, cell_size, progress=None, **values):
        check_values(self.method_name, self.params, values)
        if self.check is not None:
            self.check(values)
        if progress is not None and _takes_progress(self.resolve):
            values["progress"] = progress
        return self.resolve(z, cell_size, **values)


#: Memory a window of a method takes at its peak in :func:`.pipeline.run_file`, bytes per cell of
#: the window (its heights, the method's temporaries, the outputs' arrays, GDAL's cache): for a
#: method that states none, the largest measured, rounded up (``benchmarks/speed.py --sizes 16``,
#: stage ``file``, two threads: "extra MB" x 2^20 over the cells, 81.5 for dtm, 37.6-61.1 for the
#: others; dtm in the 7040 x 7040 windows of a blocked 12000 x 12000 run: 91.4, its peak less the imports).
DEFAULT_BYTES_PER_CELL = 92.0


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
        sample of it). Called once per raster, before any block runs. The given values are
        first checked against ``params``' limits (:func:`check_values`). A resolve with a
        keyword ``progress`` is given the pipeline's callback (its long estimates report
        through it, at least about once a second; it may raise ``Cancelled``).
    halo : callable
        ``halo(params, cell_size) -> int``: the method's reach in cells; blocks overlap by
        at least this much so that blocked and one-pass results agree.
    extras : dict
        Per-cell side products the method returns in ``FilterResult.extras``:
        ``{name: (numpy dtype, bands, nodata)}``.
    extra_bands : dict
        What each band of a side product holds, ``{name: (description, ...)}``: the band
        descriptions of its output file (what QGIS shows instead of "Band 1").
    params : tuple of Param
        The user parameters, in dialog order.
    title : str
        Display name ("Slope-profile filter (Luong Chinh Ke 2002)").
    description : str
        Help text: what the method does, how the defaults are derived, the paper cited.
    threads : bool
        ``run`` takes ``workers=`` (threads it may use inside one window, the same result
        with any count): :func:`.pipeline.run_file` then runs a raster that fits in memory
        in one window with its threads rather than in strips that each recompute a halo.
    widen : callable, optional
        ``widen(params, given, overview, cell_size) -> dict``: for parameters that are heights
        of the whole raster rather than statistics a window estimates (RASCOR's step 2 limits).
        :func:`.pipeline.run_file` resolves a raster larger than its window on the window, then
        calls it with the user's ``given`` values and the whole raster read every ``step``-th
        cell (``cell_size`` its cells).
    bytes_per_cell : float
        Memory a window takes at its peak in :func:`.pipeline.run_file`, bytes per window cell
        (measured); :func:`.pipeline.plan_block` sizes the blocks of a large raster by it.
    check : callable, optional
        ``check(values)``: ValueError for given values that no data can make valid beyond the
        ``Param`` limits (an even window where the method needs an odd one, two limits in the
        wrong order); ``None`` values are not given. Run by ``resolve`` before it reads the data
        and by :meth:`check_given`, which the plugin's dialog check calls before any work.
    """
    name: str
    run: Callable[..., Any]                     # (z, cell_size, progress=None, **params) -> FilterResult
    resolve: Callable[..., Dict[str, Any]]      # (z, cell_size, **params) -> complete params
    halo: Callable[[Dict[str, Any], Tuple[float, float]], int]
    extras: Dict[str, Tuple[Any, int, Optional[float]]] = field(default_factory=dict)
    extra_bands: Dict[str, Tuple[str, ...]] = field(default_factory=dict)
    params: Tuple[Param, ...] = ()
    title: str = ""
    description: str = ""
    threads: bool = False
    widen: Optional[Callable[..., Dict[str, Any]]] = None
    bytes_per_cell: float = DEFAULT_BYTES_PER_CELL
    check: Optional[Callable[[Dict[str, Any]], None]] = None

    def __post_init__(self):
        if not isinstance(self.resolve, _CheckedResolve):
            object.__setattr__(self, "resolve", _CheckedResolve(self.resolve, self.name, tuple(self.params),
                                                                self.check))

    def check_given(self, values: Dict[str, Any]) -> None:
        """ValueError for given ``values`` (core names; ``None`` = derived) that ``resolve`` would
        refuse whatever the data: the ``Param`` limits (:func:`check_values`) and ``check``."""
        check_values(self.name, self.params, values)
        if self.check is not None:
            self.check(values)


#: Modules that define METHOD, in the order the plugin lists them.
METHOD_MODULES = ("dtm", "slope_profile", "curvature", "rascor", "geodesic", "morphology")


def available_methods() -> Dict[str, Method]:
    """Return ``{name: Method}`` for every filter module of :data:`METHOD_MODULES`.

    A module that fails to import is a bug, not a missing method: its ImportError
    propagates (a toolbox that silently lacks a filter hides it).
    """
    found = {}
    for mod in METHOD_MODULES:
        m = importlib.import_module(f"{__package__}.{mod}")
        meth = getattr(m, "METHOD", None)
        if not isinstance(meth, Method):
            raise TypeError(f"{m.__name__} is listed in methods.METHOD_MODULES but defines no METHOD.")
        found[meth.name] = meth
    return found


def get_method(name: str) -> Method:
    """Return the registered :class:`Method` called ``name`` (ValueError if unknown)."""
    methods = available_methods()
    if name not in methods:
        raise ValueError(f"unknown filter method {name!r}; choose one of {sorted(methods)}.")
    return methods[name]
