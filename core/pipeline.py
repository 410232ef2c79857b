"""The data flow of every filter: resolve parameters -> filter in blocks -> fill the DTM.

::

    DSM --> Grid --> method.run(z, cell, **params) --> mask (0/1/2/255)
                                  |                      |
                                  +-- fill_gaps(z where mask is 1 or 2) --> DTM, nDSM

:func:`run_array` works on arrays in memory (plain Python, tests, benchmarks);
:func:`run_file` streams a raster file block by block into output files with bounded
memory (the plugin's path). Both cut the raster into the same windows with the method's
halo, so blocked and one-pass results agree.
"""
import contextlib
import math
import os
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, Optional, Sequence, Tuple, Union

import numpy as np

from . import blocks, grid, memory
from .codes import GROUND, LOW, NODATA, OBJECT
from .common import (
    Cancelled,
    Progress,
    as_cell_size,
    as_surface,
    check_progress,
    far_heights_message,
    report,
    sub_progress,
    without_far_heights,
)
from .methods import DEFAULT_BYTES_PER_CELL, Method, available_methods, check_values, get_method

#: Rasters up to this many cells are processed in one block by run_file (unless a block
#: size is given); larger ones stream in blocks sized by the memory budget (plan_block).
IN_MEMORY_CELLS = 25_000_000
#: Smallest block plan_block cuts a large raster into from the memory budget, cells (two output
#: tiles): a smaller budget is exceeded rather than the windows made mostly halo.
MIN_BLOCK = 512
#: Share added to a method's ``bytes_per_cell`` (measured on one window at a time) for each window when
#: several run side by side (threads or processes): each holds its finished core (mask, DTM, the
#: DSM's cells for an nDSM) while another is written and compressed, and GDAL's compression of the
#: flushed tiles runs beside both. Measured (QA 17): slopeprofile on 36 Mcells, two windows with a
#: 700 MB bound peaked 705 MB above its baseline, its windows about 15 % above their estimate. QA 19, 36 Mcells,
#: two threads, windows of 1024 cells: slopeprofile under 800 MB peaked 608 MB above its baseline against
#: 2 x 305 MB planned (70 bytes a cell: 58 + 20 %, none to spare), morphological under 1100 MB 867 MB against
#: 2 x 457 MB (125 bytes a cell side by side against 110 one at a time: + 14 %); both runs under their bound.
SIDE_BY_SIDE_SHARE = 0.2
#: Most times a large raster's windows may read its cells (:func:`read_amplification`) under a memory
#: bound the user gave (``BARE_EARTH_MEMORY_MB``): beyond it three quarters of the filtering or more is
#: halo, done again by the neighbouring windows; the run is refused before the blocks, naming the
#: smallest bound within it (:func:`smallest_efficient_budget`). Under the default budget (half the memory
#: available) the log warns instead. QA 17: dtm on 36 Mcells under 700 MB planned 144 windows of 512
#: cells with a 1185-cell halo, reading each cell 25.7 times, with a warning only.
MAX_READ_AMPLIFICATION = 4.0
#: The span of a raster's heights (:func:`relief_ratio`) over its width beyond which its cell size cannot be
#: the ground's: refused before work. No terrain rises more than its width (a cliff's face is about 1:1)
#: and no object a filter removes is twenty times taller than the raster is wide; a cell size in mm or cm
#: given for one in m (a city scene of 4-56 m buildings at 1 mm cells: 0.3 m wide, its heights 96 times that)
#: makes every filter's windows and slopes meaningless (QA 17: morphological kept every cell ground, dtm
#: called 99.99 % objects, without a word).
MAX_RELIEF_RATIO = 20.0
#: The ratio from which the log warns (the heights span more than twice the raster's diagonal: steeper than
#: any terrain across a whole raster unless it is a small crop of tall objects).
STEEP_RELIEF_RATIO = 2.0
#: Parameters of large rasters are derived from a central window of at most this side.
RESOLVE_SIDE = 4096
#: Strips of rows per worker process when a raster is processed in parallel (one when the
#: method's halo would make that many strips cost more than a quarter extra).
STRIPS_PER_PROCESS = 2
#: Share of a block's progress the filter takes (the rest is the DTM's gap filling).
FILTER_SHARE = 0.85
#: Share of a block's progress in run_file before its outputs are written (the rest: writing).
COMPUTE_SHARE = 0.95
#: The part of run_file's progress before the blocks start: the parameters derived (on a
#: 16 Mcells raster that takes a third of the run or more; larger rasters are derived from a
#: window of RESOLVE_SIDE^2 cells, so less).
RESOLVED = 0.1
#: The share of that part taken by reading the window the parameters come from.
READ_SHARE = 0.2
#: Rows read between two progress reports while reading that window.
READ_ROWS = 1024


@dataclass
class PipelineResult:
    """Result of :func:`run_array`: mask (uint8), dtm and ndsm (float32, NaN nodata),
    extras (per-cell side products), info (parameters used and statistics)."""
    mask: np.ndarray
    dtm: np.ndarray
    ndsm: np.ndarray
    extras: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)


def as_method(method: Union[str, Method]) -> Method:
    """A :class:`Method`, or the registered method of that name (ValueError if unknown)."""
    return method if isinstance(method, Method) else get_method(method)


def complete_params(meth: Method, params: Optional[Dict[str, Any]]) -> Dict[str, Any]:
    """The user's params completed with the ``Param`` defaults (``None``: derived later by
    ``meth.resolve``).

    Raises
    ------
    ValueError
        For an unknown name, or a number outside its ``Param``'s [minimum, maximum] (NaN too).
    """
    params = dict(params or {})
    known = {p.name: p for p in meth.params}
    if known:
        unknown = sorted(set(params) - set(known))
        if unknown:
            raise ValueError(f"unknown parameter(s) {unknown} for method {meth.name!r}; "
                             f"it takes {sorted(known)}.")
    full = {p.name: p.default for p in meth.params}
    full.update(params)
    check_values(meth.name, meth.params, full)
    return full


def warm_up_worker():
    """Run first in a new worker process (:func:`blocks.start_pool`): unpickling this function
    imports this module (numpy, scipy), then the methods. Returns the worker's pid."""
    available_methods()
    return os.getpid()


def resolve_params(method: Union[str, Method], z: np.ndarray, cell_size: Union[float, Tuple[float, float]],
                   params: Optional[Dict[str, Any]] = None, progress: Progress = None,
                   fill_empty: bool = True) -> Dict[str, Any]:
    """All parameters of ``method`` for surface ``z``, data-derived ones filled in.

    ``progress(fraction)`` (optional) is fed by the method's estimates while they run; it
    may raise :class:`~.common.Cancelled`, which stops the derivation there. ``fill_empty``:
    derive them on ``z`` with its empty cells filled (:func:`fill_empty_cells`), as the filter
    sees it; False for a surface whose nodata must stay (a survey's sample: crops filled one by
    one, the nodata gutters between them kept).
    """
    meth = as_method(method)
    z, _ = without_far_heights(as_surface(z))
    cell = as_cell_size(cell_size)
    if fill_empty:
        z = fill_empty_cells(z, cell)[0]
    return _resolve(meth, z, cell, complete_params(meth, params), progress)


def _resolve(meth, z, cell, params, progress):
    """``meth.resolve`` with ``progress`` (passed on when the method's own resolve takes it:
    :class:`~.methods.Method`), reported done at the end."""
    out = meth.resolve(z, cell, progress=progress, **params)
    report(progress, 1.0)
    return out


def widest_window_m() -> float:
    """The widest window, in metres, that any filter's parameters allow: the largest limit of
    their lengths (the ``*_m`` parameters' :attr:`Param.maximum`; 10 km, the opening's largest
    window and RASCOR's profiles)."""
    from .methods import available_methods, get_method
    return max(float(p.maximum) for name in available_methods() for p in get_method(name).params
               if p.name.endswith("_m") and p.maximum is not None)


def check_cell_size(cell_size) -> None:
    """ValueError, before any work, for cells wider than :func:`widest_window_m`: no object a
    filter removes (a building, a wood) is as wide as one such cell, and the windows a filter
    derives from the cells would break its own limits (a DSM of 0.5 degree cells, 55 km, failed
    in the opening's parameters: WIDE_RADIUS_M = 25000 m out of range, a parameter nobody gave)."""
    cell = as_cell_size(cell_size)
    widest = widest_window_m()
    if max(cell) > widest:
        raise ValueError(f"the raster's cells of {cell[0]:.6g} x {cell[1]:.6g} m are wider than the widest window "
                         f"any filter takes ({widest:g} m): no building or wood a filter removes is as wide as one "
                         "cell. Filter a DSM of finer cells (a cell size in degrees or feet read as another unit: "
                         "check the raster's CRS).")


def relief_ratio(z, cell_size, sample=1_000_000, shape=None):
    """The span of ``z``'s heights (between its 2nd and 98th percentiles: blunders on up to 2 % of the
    cells left out; on at most ``sample`` cells taken evenly, less those holding exactly its lowest or
    highest value, such as an undeclared nodata of any extent) over its diagonal in metres; 0 when fewer
    than two cells hold data. ``shape``: the rows and columns of the raster ``z`` samples (a decimated
    read, :func:`check_relief_file`), whose diagonal it is; default ``z``'s own."""
    z = np.asarray(z)
    rows, cols = z.shape if shape is None else shape
    dx, dy = as_cell_size(cell_size)
    step = max(1, int(math.ceil(math.sqrt(z.size / float(sample)))))
    v = z[::step, ::step]
    v = v[np.isfinite(v)]
    if v.size >= 2:         # the lowest and highest values left out: an undeclared nodata (-9999) on a border
        inner = v[(v > v.min()) & (v < v.max())]
        v = inner if inner.size >= 2 else v
    if v.size < 2:
        return 0.0
    lo, hi = np.percentile(v, [2.0, 98.0])
    return float(hi - lo) / math.hypot(rows * dy, cols * dx)


def check_relief(z, cell_size, shape=None):
    """ValueError, before any work, when ``z``'s heights span more than :data:`MAX_RELIEF_RATIO` times its
    diagonal (:func:`relief_ratio`; ``shape``: the raster a decimated ``z`` samples): the cell size cannot be
    the ground's (millimetres or centimetres given for metres). Returns a warning when they span more than
    :data:`STEEP_RELIEF_RATIO` times it, else None."""
    ratio = relief_ratio(z, cell_size, shape=shape)
    rows, cols = z.shape if shape is None else shape
    dx, dy = as_cell_size(cell_size)
    if ratio <= STEEP_RELIEF_RATIO:
        return None
    what = (f"the heights span {ratio:.3g} times the diagonal of the {cols} x {rows} cells of "
            f"{dx:.6g} x {dy:.6g} m ({math.hypot(rows * dy, cols * dx):.3g} m)")
    if ratio > MAX_RELIEF_RATIO:
        raise ValueError(f"{what}: no terrain nor object a filter removes is that steep, so the cell size is "
                         f"probably wrong (a size in mm or cm read as m, or heights in another unit than the "
                         f"cells'). Give the raster its real cell size (gdal_edit.py -tr) or height unit "
                         "(gdal_edit.py -scale), points their real CRS (POINTS_CRS) or coordinates' unit; every "
                         "filter's windows and slopes follow them.")
    return (f"{what}: steeper than any terrain across a whole raster. If the cell size or the height unit is "
            "wrong (mm or cm read as m), the filters' windows and slopes are too; check them.")


def check_relief_file(info, sample=1_000_000):
    """:func:`check_relief` of the window :func:`run_file` derives the parameters from (the central
    :data:`RESOLVE_SIDE` cells, the whole raster when smaller), read every ``step``-th cell (at most about
    ``sample`` cells, as :func:`relief_ratio` samples them), for the checks before a run (a dialog's, whose
    user expects it to say what the run would refuse). ValueError when refused; the warning or None; None
    too when that window holds no data (the run's own check then takes the data's window)."""
    rw = _resolve_window(info.shape)
    rows, cols = rw[1] - rw[0], rw[3] - rw[2]
    step = max(1, int(math.ceil(math.sqrt(rows * cols / float(sample)))))
    z, _ = without_far_heights(info.surface(info.read_stored(rw, step), rw, step))
    if not np.isfinite(z).any():
        return None
    return check_relief(z, info.cell_size_m, shape=(rows, cols))


def fill_dtm(z, mask, progress=None):
    """The DTM of a filtered surface: cells of class 1 and 2 filled from the ground cells.

    Cells of the input's nodata stay NaN. Returns None when the window has no ground cell.
    ``progress``: the fill's own progress (:func:`.fill.fill_gaps`).
    """
    from .fill import fill_gaps
    holes = np.asarray(mask, np.uint8) - np.uint8(OBJECT) <= np.uint8(LOW - OBJECT)  # 1 or 2
    ground = np.isfinite(z) & ~holes
    if not ground.any():
        return None
    if not holes.any():
        return z.astype(np.float32, copy=True)
    return fill_gaps(z, fill=holes, progress=progress)


def fill_empty_cells(z, cell):
    """``z`` with its empty cells enclosed by data filled from the nearest data (:func:`.fill.fill_empty`,
    runs of at most :data:`.fill.EMPTY_RUN_M`), and the count filled: what every filter sees. The
    outputs keep ``z``'s own nodata."""
    from .fill import empty_run_cells, fill_empty
    return fill_empty(z, empty_run_cells(cell))


def window_halo(method, params, cell):
    """The cells a window read from a file reaches beyond its core: the method's reach plus the
    reach of :func:`fill_empty_cells` (its fill of the window's cells within the method's reach is
    then the whole raster's)."""
    from .fill import empty_run_cells, fill_empty_reach
    return int(as_method(method).halo(params, cell)) + fill_empty_reach(empty_run_cells(cell))


def filled_message(count):
    """The log line of a run that filled ``count`` empty cells before filtering (None for none)."""
    from .fill import EMPTY_RUN_M
    if not count:
        return None
    return (f"{count} empty cell(s) enclosed by data (runs of at most {EMPTY_RUN_M:g} m along a row or a column) "
            "filled from the nearest data before filtering; they stay nodata in every output.")


def _process(meth, z, cell, params, aux, want_dtm=True, progress=None, workers=1, filled=None):
    """Filter one window and fill its DTM (``workers``: the threads a method with
    ``Method.threads`` may use inside it). ``filled``: ``z`` with its empty cells filled
    (:func:`fill_empty_cells`), when the caller has it; the method filters it, the outputs keep
    ``z``'s nodata."""
    if filled is None:
        filled = fill_empty_cells(z, cell)[0]
    inner = {"workers": int(workers)} if meth.threads else {}
    res = meth.run(filled, cell, progress=sub_progress(progress, 0.0, FILTER_SHARE), **params, **aux, **inner)
    mask = np.asarray(res.mask, dtype=np.uint8)
    if mask.shape != z.shape:
        raise RuntimeError(f"method {meth.name!r} returned a mask of shape {mask.shape} for a "
                           f"surface of shape {z.shape}")
    valid = np.isfinite(z)
    mask[~valid] = NODATA
    if filled is not z and np.count_nonzero(np.isfinite(filled)) > np.count_nonzero(valid):
        # cells filled before filtering: nodata in the side products too
        for name, (_, _, nod) in meth.extras.items():
            if nod is not None and name in res.extras:
                a = np.array(res.extras[name], copy=False)
                a[..., ~valid] = nod
                res.extras[name] = a
    dtm = None
    if want_dtm and res.dtm is not None:
        dtm = np.asarray(res.dtm, dtype=np.float32)
        if dtm.shape != z.shape or not np.isfinite(dtm[valid]).all():
            dtm = None  # not usable: fill below
        else:
            dtm = dtm.copy() if dtm is res.dtm else dtm
            dtm[~valid] = np.nan
    if want_dtm and dtm is None:
        dtm = fill_dtm(z, mask, progress=sub_progress(progress, FILTER_SHARE, 1.0))
    report(progress, 1.0)
    return res, mask, dtm


def _merge_info(infos, weights):
    """Block infos -> one: numbers weighted by block cells; lists that differ between blocks
    (decisions, notes) joined, each entry once, in block order; the rest from the first block
    that has the key."""
    if not infos:
        return {}
    if len(infos) == 1:
        return dict(infos[0])
    out = {}
    for inf in infos:
        for k, v in inf.items():
            out.setdefault(k, v)
    tot = float(sum(weights))
    for k, v in out.items():
        vals = [inf.get(k) for inf in infos]
        if isinstance(v, (int, float, np.floating, np.integer)) and not isinstance(v, bool):
            if all(isinstance(x, (int, float, np.floating, np.integer)) for x in vals):
                out[k] = float(sum(float(x) * w for x, w in zip(vals, weights)) / tot)
        elif isinstance(v, list) and any(x != v for x in vals):
            joined = []
            for x in vals:
                joined.extend(e for e in (x if isinstance(x, list) else []) if e not in joined)
            out[k] = joined
    return out


def _code_counts(mask):
    """``{code: count}`` of a uint8 mask: one count per code of the convention (a bincount
    would first cast every cell to int64), a bincount only when other codes are present."""
    mask = np.asarray(mask, np.uint8)
    out = {c: int(np.count_nonzero(mask == c)) for c in (GROUND, OBJECT, LOW, NODATA)}
    if sum(out.values()) != mask.size:
        n = np.bincount(mask.ravel(), minlength=256)
        out = {int(k): int(n[k]) for k in np.flatnonzero(n)}
    return {k: v for k, v in out.items() if v}


def class_shares(counts):
    """Counts per mask code -> shares (percent of valid cells) with names."""
    valid = sum(v for k, v in counts.items() if k != NODATA)
    shares = {}
    for code, name in ((GROUND, "ground"), (OBJECT, "object"), (LOW, "low outlier")):
        shares[name] = 100.0 * counts.get(code, 0) / valid if valid else 0.0
    shares["nodata cells"] = int(counts.get(NODATA, 0))
    return shares


def no_ground_message(counts, outputs):
    """The log line when a run's mask (``counts`` per code) holds valid cells but no ground and a
    DTM or nDSM is written: with no ground to interpolate from they are nodata everywhere (a
    window inside one roof, a raster of a few cells a filter reads as a step), else None."""
    valid = sum(v for k, v in counts.items() if k != NODATA)
    if not valid or counts.get(GROUND) or not (outputs.get("dtm") or outputs.get("ndsm")):
        return None
    written = " and ".join(n for k, n in (("dtm", "DTM"), ("ndsm", "nDSM")) if outputs.get(k))
    return (f"The filter called none of the {valid} valid cell(s) ground (objects "
            f"{100.0 * counts.get(OBJECT, 0) / valid:.0f} %, low outliers {100.0 * counts.get(LOW, 0) / valid:.0f} %): "
            f"with no ground to interpolate from, the {written} {'are' if ' and ' in written else 'is'} nodata "
            "everywhere. Give a raster that reaches the ground around its objects, or try another method.")


def run_array(method: Union[str, Method], z: np.ndarray, cell_size: Union[float, Tuple[float, float]],
              params: Optional[Dict[str, Any]] = None, *, aux: Optional[Dict[str, Optional[np.ndarray]]] = None,
              block: Optional[Union[int, Tuple[int, int]]] = None, workers: int = 1, progress: Progress = None,
              want_dtm: bool = True) -> PipelineResult:
    """Filter a DSM array and fill its DTM.

    Parameters
    ----------
    method : str or Method
        Registered method name (``"slopeprofile"``, ...) or a Method.
    z : array_like, 2-D
        The DSM (NaN = nodata); not modified.
    cell_size : float or (dx, dy)
        Metres.
    params : dict, optional
        Method parameters; missing or ``None`` ones are derived from the data.
    aux : dict of str -> 2-D array, optional
        Per-cell inputs passed to the method by keyword (e.g. ``breaklines``), cut to blocks.
    block : int, optional
        Block edge in cells; default one pass. The result does not depend on it.
    workers : int
        Threads for blocks (0: one per core, :func:`blocks.default_workers`).
    progress : callable, optional
        ``progress(fraction)``; may raise :class:`Cancelled`.

    Returns
    -------
    PipelineResult
    """
    meth = as_method(method)
    progress = check_progress(progress)
    workers = blocks.resolve_workers(workers)
    z, n_far = without_far_heights(as_surface(z))
    if n_far and not np.isfinite(z).any():
        raise ValueError("z has no valid cell: " + far_heights_message(n_far))
    cell = as_cell_size(cell_size)
    check_cell_size(cell)
    steep = check_relief(z, cell)
    aux = dict(aux or {})
    for k, a in aux.items():
        if a is not None and np.shape(a) != z.shape:
            raise ValueError(f"aux input {k!r} has shape {np.shape(a)} but the DSM has {z.shape}: "
                             "rasterise it on the DSM's grid.")
    t0 = time.perf_counter()
    zf, n_filled = fill_empty_cells(z, cell)   # the whole raster's fill: its windows are cut from it
    params = _resolve(meth, zf, cell, complete_params(meth, params), sub_progress(progress, 0.0, 0.02))
    halo = int(meth.halo(params, cell))
    mask = np.full(z.shape, NODATA, np.uint8)
    dtm = np.full(z.shape, np.nan, np.float32)
    extras = {}
    for name, (dt, bands, nod) in meth.extras.items():
        shape = z.shape if bands == 1 else (bands,) + z.shape
        extras[name] = np.full(shape, nod if nod is not None else 0, dtype=dt)
    infos, weights = [], []
    bshape = block or max(z.shape)
    windows = list(blocks.iter_windows(z.shape, bshape, halo))

    def work(core, outer, block_progress):
        sl = (slice(outer[0], outer[1]), slice(outer[2], outer[3]))
        zb = z[sl]
        if not np.isfinite(zb).any():
            return
        ab = {k: (None if a is None else np.asarray(a)[sl]) for k, a in aux.items()}
        res, m, d = _process(meth, zb, cell, params, ab, want_dtm, block_progress,
                             workers if len(windows) == 1 else 1, filled=zf[sl])
        c = blocks.crop(outer, core)
        dst = (slice(core[0], core[1]), slice(core[2], core[3]))
        mask[dst] = m[c]
        if d is not None:
            dtm[dst] = d[c]
        for name, arr in res.extras.items():
            if name in extras:
                a = np.asarray(arr)
                if a.ndim == 2:
                    extras[name][dst] = a[c]
                else:
                    extras[name][(slice(None),) + dst] = a[(slice(None),) + c]
        infos.append(res.info)
        weights.append((core[1] - core[0]) * (core[3] - core[2]))

    blocks.run_windows(work, windows, workers=workers, progress=sub_progress(progress, 0.02, 0.98))
    dtm[~np.isfinite(z)] = np.nan
    ndsm = (z - dtm).astype(np.float32)
    info = {"method": meth.name, "params": params, "halo_cells": halo, "blocks": len(windows),
            "warnings": ([far_heights_message(n_far)] if n_far else []) + ([steep] if steep else [])}
    info.update(_merge_info(infos, weights))
    info["empty_cells_filled"] = n_filled
    info["classes_percent"] = class_shares(_code_counts(mask))
    info["seconds"] = time.perf_counter() - t0
    report(progress, 1.0)
    return PipelineResult(mask, dtm, ndsm, extras, info)


def _resolve_window(shape):
    rows, cols = shape
    h, w = min(rows, RESOLVE_SIDE), min(cols, RESOLVE_SIDE)
    r0, c0 = (rows - h) // 2, (cols - w) // 2
    return (r0, r0 + h, c0, c0 + w)


def concurrent_windows(workers=1, processes=1, threads=False):
    """Windows :func:`run_file` holds in memory at once in block mode: one for a method that uses
    threads inside a window (``Method.threads``) without worker processes (its windows run one
    after the other, each with the run's threads), else one per thread or process."""
    if threads and int(processes) <= 1:
        return 1
    return max(1, int(processes), int(workers))


def window_bytes_per_cell(bytes_per_cell, concurrent=1):
    """Bytes a window cell takes when ``concurrent`` windows are held at once
    (:func:`concurrent_windows`): the method's ``bytes_per_cell`` (one window at a time), plus
    :data:`SIDE_BY_SIDE_SHARE` of it when several run side by side."""
    return float(bytes_per_cell) * (1.0 + (SIDE_BY_SIDE_SHARE if int(concurrent) > 1 else 0.0))


def read_amplification(shape, block, halo):
    """Cells the windows of :func:`blocks.iter_windows` read (and filter) over the raster's cells:
    1 for one pass; ``(b + 2 halo)^2 / b^2`` for square blocks ``b`` inside a large raster."""
    total = sum((o[1] - o[0]) * (o[3] - o[2]) for _, o in blocks.iter_windows(shape, block, halo))
    return total / float(shape[0] * shape[1])


def largest_window(shape, block, halo):
    """Cells of the largest window :func:`blocks.iter_windows` reads."""
    return max((o[1] - o[0]) * (o[3] - o[2]) for _, o in blocks.iter_windows(shape, block, halo))


def _balanced(n, most, unit):
    """The smallest multiple of ``unit`` cutting ``n`` cells into as few blocks as blocks of ``most``
    (itself when none is smaller): no thin last block reading a whole halo for a few rows (not
    always fewer cells read: the raster's edges clip the halos of the first and last blocks)."""
    k = -(-n // most)
    even = -(-n // k)
    b = -(-even // unit) * unit
    return b if b <= most else most


def _budget_block(shape, halo, cells):
    """The block whose windows read the fewest cells among the largest square blocks and strips of
    whole rows, as they are and balanced over the raster (:func:`_balanced`), whose window holds at
    most ``cells`` cells (a side: the block, a halo on each side and up to ``alignment - 1`` cells
    the window's corner moves out to; at least :data:`MIN_BLOCK`); sides multiples of the output
    tile and of the windows' alignment."""
    rows, cols = shape
    a = blocks.alignment(halo)
    unit, grow = max(grid.OUTPUT_TILE, a), 2 * halo + a - 1
    side = math.isqrt(max(0, int(cells)))
    most = max(MIN_BLOCK, (side - grow) // unit * unit)
    candidates = [(most, most), (_balanced(rows, most, unit), _balanced(cols, most, unit))]
    strip = (int(cells) // cols - grow) // unit * unit        # whole rows: no halo at the sides
    if strip >= MIN_BLOCK:
        candidates += [(strip, cols), (_balanced(rows, strip, unit), cols)]
    return min(candidates, key=lambda b: read_amplification(shape, b, halo))


def plan_block(shape, halo, *, block=None, workers=1, processes=1, threads=False,
               bytes_per_cell=DEFAULT_BYTES_PER_CELL, budget=None):
    """The block shape :func:`run_file` cuts a raster of ``shape`` into (a pure function given
    ``budget``).

    A given ``block`` is used as is. A raster of up to :data:`IN_MEMORY_CELLS` is one block
    (with several threads or processes: strips of whole rows, :data:`STRIPS_PER_PROCESS` per
    worker, one per worker when the halo would add more than a quarter; also one block with
    several threads when the method uses them inside a window, ``threads``: strips would each
    recompute a halo), their height a multiple of 64 cells (coarsened grids align as in one
    pass) or of the output tile for long strips (each strip's tiles are whole when it is
    flushed), at least ``2 * halo`` and 64 rows.

    A larger raster is cut into the blocks that read the fewest cells (:func:`read_amplification`)
    while the windows held at once (:func:`concurrent_windows`) fit ``budget`` bytes
    (default :func:`.memory.window_budget`: half the memory available) at ``bytes_per_cell`` bytes
    per window cell (the method's ``Method.bytes_per_cell``, :data:`SIDE_BY_SIDE_SHARE` more for windows
    side by side: :func:`window_bytes_per_cell`): each window (block + 2 halo) at most
    ``budget / concurrent / window_bytes_per_cell`` cells; square blocks, or strips of whole rows when a
    window can span the raster's width, balanced over the raster, at least :data:`MIN_BLOCK`
    (a budget smaller than such a window is exceeded rather than the blocks shrunk further).
    The whole raster is one block when it fits the budget, and when the halo reaches across it
    from any block (each block would read all of it: the memory of one pass, times the blocks in
    time; the method's reach in metres at very fine cells, 1-2 cm).

    Returns
    -------
    int or (rows, cols)
    """
    if block is not None:
        return block
    rows_all = shape[0]
    if shape[0] * shape[1] > IN_MEMORY_CELLS:
        if budget is None:
            budget = memory.window_budget()
        n = concurrent_windows(workers, processes, threads)
        cells = budget / n / window_bytes_per_cell(bytes_per_cell, n)
        if shape[0] * shape[1] <= cells:
            return max(shape)       # the whole raster fits the budget: one pass
        bshape = _budget_block(shape, halo, cells)
        if all(halo >= n - b for n, b in zip(shape, bshape)):
            return max(shape)       # every block would read (and filter) the whole raster: one pass instead
        return bshape
    block = max(shape)
    n = max(int(processes), int(workers))
    if n <= 1 or (threads and int(processes) <= 1):
        return block
    strips = n * STRIPS_PER_PROCESS
    if 2 * halo * strips > rows_all // 4:
        strips = n
    rows = -(-rows_all // strips)
    align = grid.OUTPUT_TILE if rows >= 4 * grid.OUTPUT_TILE else 64
    rows = -(-rows // align) * align
    return (max(rows, 2 * halo, 64), shape[1])


def smallest_efficient_budget(shape, halo, *, workers=1, processes=1, threads=False,
                              bytes_per_cell=DEFAULT_BYTES_PER_CELL, most=MAX_READ_AMPLIFICATION):
    """The smallest windows' budget (bytes, to 1 MB) under which :func:`plan_block` cuts a raster of
    ``shape`` (above :data:`IN_MEMORY_CELLS`) into windows that fit it and read its cells at most
    ``most`` times (:func:`read_amplification`; one pass always does)."""
    n = concurrent_windows(workers, processes, threads)
    bpc = window_bytes_per_cell(bytes_per_cell, n)
    mb = float(1 << 20)

    def fits(budget):
        b = plan_block(shape, halo, workers=workers, processes=processes, threads=threads,
                       bytes_per_cell=bytes_per_cell, budget=budget)
        return largest_window(shape, b, halo) * bpc * n <= budget and read_amplification(shape, b, halo) <= most

    lo, hi = 0, int(math.ceil(shape[0] * shape[1] * bpc * n / mb))     # hi MB: one pass fits
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if fits(mid * mb):
            hi = mid
        else:
            lo = mid
    return hi * (1 << 20)


def check_plan(shape, bshape, halo, budget, *, held=0, workers=1, processes=1, threads=False,
               bytes_per_cell=DEFAULT_BYTES_PER_CELL, method="the method"):
    """ValueError, before the blocks, when a bound the user gave (``BARE_EARTH_MEMORY_MB``; ``budget``:
    what it leaves for the windows, ``held``: what the run holds beside them) makes :func:`plan_block`'s
    windows ``bshape`` read the raster's cells more than :data:`MAX_READ_AMPLIFICATION` times or exceed
    the bound, naming the smallest bound that works; None when the plan is fine."""
    if sum(1 for _ in blocks.iter_windows(shape, bshape, halo)) <= 1:
        return None
    n = concurrent_windows(workers, processes, threads)
    bpc = window_bytes_per_cell(bytes_per_cell, n)
    amp = read_amplification(shape, bshape, halo)
    need = largest_window(shape, bshape, halo) * bpc * n
    if amp <= MAX_READ_AMPLIFICATION and need <= budget:
        return None
    good = smallest_efficient_budget(shape, halo, workers=workers, processes=processes, threads=threads,
                                     bytes_per_cell=bytes_per_cell)
    rows, cols = (bshape, bshape) if np.ndim(bshape) == 0 else bshape
    raise ValueError(
        f"{memory.BUDGET_ENV} leaves {budget / 2 ** 20:.0f} MB for {method}'s windows on this raster of "
        f"{shape[1]} x {shape[0]} cells: its blocks of {cols} x {rows} cells with a halo of {halo} cells (the "
        f"method's reach) would read the raster's cells {amp:.1f} times"
        + (f" and still take about {need / 2 ** 20:.0f} MB" if need > budget else "")
        + f" (at most {MAX_READ_AMPLIFICATION:g} keeps the run efficient). Set {memory.BUDGET_ENV} to at least "
        f"{math.ceil((good + held) / 2 ** 20)}, or filter a coarser cell (gdalwarp -tr), or choose the blocks "
        "yourself (BLOCK_SIZE).")


@dataclass
class FileRun:
    """The settings of one :func:`run_file` call, checked (``params`` complete but for the
    ``None`` values the method derives)."""
    meth: Method
    outputs: Dict[str, Any]
    params: Dict[str, Any]
    aux: Dict[str, Optional[np.ndarray]]
    block: Optional[Union[int, Tuple[int, int]]]
    workers: int
    processes: int
    progress: Progress
    log: Callable[[str], None]
    t0: float = field(default_factory=time.perf_counter)


def run_file(method: Union[str, Method], path: str, outputs: Dict[str, Any], *, band: Optional[int] = None,
             params: Optional[Dict[str, Any]] = None, aux: Optional[Dict[str, Optional[np.ndarray]]] = None,
             block: Optional[Union[int, Tuple[int, int]]] = None, workers: int = 1, processes: int = 1,
             progress: Progress = None, log: Optional[Callable[[str], None]] = None,
             nodata_ranges: Sequence[Tuple[float, float, bool, bool]] = (),
             crs_wkt: Optional[str] = None) -> Dict[str, Any]:
    """Filter a DSM file into output files, block by block, with bounded memory.

    Parameters
    ----------
    method : str or Method
    path : str
        The DSM (any GDAL raster; checked by :func:`grid.open_dsm` before any work; its
        band's scale and offset applied, heights beyond ``common.MAX_ABS_HEIGHT_M`` nodata).
    outputs : dict
        Keys ``"dtm"``, ``"mask"``, ``"ndsm"`` and any of the method's extras, each a
        path or None. Outputs are on the DSM's grid with its CRS; the DTM and nDSM keep
        the DSM's nodata (NaN when it declares none; the nDSM NaN when it is 0) and its height unit; the mask is
        UInt8 with a colour table, nodata 255, and a ``.qml`` style beside it.
    aux : dict of str -> 2-D bool/number array on the DSM's grid, optional
    block : int, optional
        Block edge in cells; default :func:`plan_block`.
    workers : int
        Threads running blocks (numpy, scipy and GDAL release the GIL for the heavy work;
        no start-up cost); 0: one per core (:func:`blocks.default_workers`). With more than
        one and no ``block``, the raster is cut into strips of rows as for ``processes``,
        except for a method that uses threads inside a window (``Method.threads``, e.g.
        ``dtm``'s members side by side): a raster of up to IN_MEMORY_CELLS is then one
        window filtered with the threads (no halo computed twice; the result of one pass).
    processes : int
        Worker processes running blocks (each reads its own windows; this process writes).
        With more than one and no ``block`` given, a raster of up to IN_MEMORY_CELLS is cut
        into two strips of rows per process. The mask is the same as in one pass; the DTM's
        filled cells may differ slightly (the interpolation sees the block and its halo,
        not the whole raster).
    progress : callable, optional
        ``progress(fraction)``, fed by the methods' own progress in every block; may raise
        :class:`Cancelled` (nothing is then written; running blocks stop at their next
        progress call).
    log : callable, optional
        ``log(str)`` for warnings and the values used.
    nodata_ranges : sequence of (low, high, include_low, include_high), optional
        Heights that are nodata besides the DSM's own (a QGIS layer's additional no-data
        values; :func:`grid.open_dsm`).
    crs_wkt : str, optional
        The CRS of a DSM whose file has none (its QGIS layer's; :func:`grid.open_dsm`).

    Returns
    -------
    dict : the run's info (parameters used, warnings, class shares, timings).
    """
    meth = as_method(method)
    progress = check_progress(progress)
    check_run_counts(block, workers, processes)
    memory.budget_mb()          # a BARE_EARTH_MEMORY_MB that is no number: refused now, not after the parameters
    info = grid.open_dsm(path, band, nodata_ranges, crs_wkt)
    check_cell_size(info.cell_size_m)
    check_process_reach(info.path, processes)
    for target in outputs.values():
        if target:
            grid.check_output_cells(target, info.geotransform)
            grid.check_output_crs(target, info.crs_wkt, info.geotransform)
    aux = dict(aux or {})
    for k, a in aux.items():
        if a is not None and np.shape(a) != info.shape:
            raise ValueError(f"aux input {k!r} has shape {np.shape(a)} but the DSM has {info.shape}.")
    run = FileRun(meth, dict(outputs), complete_params(meth, params), aux, block, blocks.resolve_workers(workers),
                  int(processes), progress, log or (lambda s: None))
    # worker processes start (spawn, imports) while this process derives the parameters
    pool = (blocks.start_pool(run.processes, warm_up=warm_up_worker)
            if run.processes > 1 and info.cells >= 1_000_000 else None)
    try:
        with memory.run_baseline():      # BARE_EARTH_MEMORY_MB: the run's memory above what the process held
            return _run_file(info, run, pool)
    finally:
        if pool is not None:
            pool.shutdown(wait=False)


def check_process_reach(path, processes=1):
    """ValueError, before any work, when worker ``processes`` (more than one) could not open the raster
    ``path``: one in GDAL's memory of this process (``/vsimem/``, a layer another plugin or script made
    there) exists for this process alone; its workers failed reading it once the parameters were derived
    ("No such file or directory ... may be truncated or corrupt")."""
    if int(processes) > 1 and str(path).replace("\\", "/").startswith("/vsimem/"):
        raise ValueError(f"the raster {str(path)!r} lives in this process's memory (GDAL's /vsimem/), which "
                         f"worker processes cannot read: run it with PROCESSES = 1 (the threads still share the "
                         "work), or save it to a file first (gdal_translate, or Export > Save As).")


def check_run_counts(block=None, workers=1, processes=1):
    """ValueError, before any work, unless ``block`` is None or whole numbers of cells of at least
    1 (one, or rows and columns), ``workers`` a whole number (0 or less: one per core) and
    ``processes`` a whole number of at least 1. A block of -2147483648 cells (a NaN given as a
    whole number, C's conversion) ran for ever, cutting the raster into windows of no extent."""
    def whole(v):
        return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) \
            and float(v).is_integer()
    sizes = block if isinstance(block, (tuple, list)) else (block,)
    if block is not None and not (len(sizes) in (1, 2) and all(whole(b) and b >= 1 for b in sizes)):
        raise ValueError(f"the block size must be a whole number of cells of at least 1 (or rows and columns), "
                         f"or None for automatic blocks; got {block!r}.")
    if not whole(workers):
        raise ValueError(f"workers must be a whole number of threads (0: one per core); got {workers!r}.")
    if not (whole(processes) and processes >= 1):
        raise ValueError(f"processes must be a whole number of worker processes, at least 1; got {processes!r}.")


def _read_reporting(info, window, progress):
    """``info.read(window)`` in bands of :data:`READ_ROWS` rows, reporting after each."""
    r0, r1, c0, c1 = window
    if progress is None or r1 - r0 <= READ_ROWS:
        z = info.read(window)
    else:
        z = np.empty((r1 - r0, c1 - c0), np.float32)
        for a in range(r0, r1, READ_ROWS):
            b = min(a + READ_ROWS, r1)
            z[a - r0:b - r0] = info.read((a, b, c0, c1))
            report(progress, (b - r0) / (r1 - r0))
    report(progress, 1.0)
    return z


def _window_on_data(info, max_cells=4_000_000):
    """The window of :func:`_resolve_window`'s size centred on the valid cell nearest the raster's
    centre, for a raster whose centre holds no data (an L-shaped survey, a corridor): found on a
    decimated read of at most ``max_cells`` as :func:`grid.check_has_data` scans. The whole
    raster when that read misses the data (it sits between the samples)."""
    rows, cols = info.shape
    step = max(1, int(math.ceil(math.sqrt(info.cells / max_cells))))
    rr, cc = np.nonzero(np.isfinite(info.surface(info.read_stored(step=step), None, step)))
    if rr.size == 0:
        return (0, rows, 0, cols)
    k = int(np.argmin((rr * step - rows / 2.0) ** 2 + (cc * step - cols / 2.0) ** 2))
    h, w = min(rows, RESOLVE_SIDE), min(cols, RESOLVE_SIDE)
    r0 = int(min(max(rr[k] * step - h // 2, 0), rows - h))
    c0 = int(min(max(cc[k] * step - w // 2, 0), cols - w))
    return (r0, r0 + h, c0, c0 + w)


def _derive_params(info, run):
    """The complete parameters (from a central window, or the whole raster when it fits in
    one) and the raster itself when it was read whole (else None); logs what it did.
    Reports progress on ``run.progress``'s [0, RESOLVED] while reading and deriving."""
    # The window the parameters come from also proves the raster has data (a full scan only
    # when it is empty), so a valid raster is not decompressed twice before the work.
    rw = _resolve_window(info.shape)
    where = "the central"
    zr = _read_reporting(info, rw, sub_progress(run.progress, 0.0, READ_SHARE * RESOLVED))
    if not np.isfinite(zr).any():
        grid.check_has_data(info)  # raises ValueError when no cell is valid
        rw = _window_on_data(info)
        where = f"the {'whole raster' if rw == (0, info.shape[0], 0, info.shape[1]) else 'data'}'s"
        zr = _read_reporting(info, rw, None)
    steep = check_relief(zr, info.cell_size_m)
    if steep:
        run.log("Warning: " + steep + ("" if zr.shape == info.shape else " (in the window the parameters come from)"))
    for w in info.warnings:
        run.log("Warning: " + w)
    in_window = "" if zr.shape == info.shape else " (in the window the parameters come from)"
    for suspect in (grid.undeclared_nodata_warning(info, zr), grid.nodata_among_heights_warning(info, zr)):
        if suspect:
            run.log("Warning: " + suspect + in_window)
    for note in info.notes:
        run.log(note)
    params = _resolve(run.meth, fill_empty_cells(zr, info.cell_size_m)[0], info.cell_size_m, run.params,
                      sub_progress(run.progress, READ_SHARE * RESOLVED, RESOLVED))
    whole = zr if zr.shape == info.shape else None   # the raster itself: not read twice
    if whole is None:
        run.log(f"Parameters derived from {where} {rw[1] - rw[0]} x {rw[3] - rw[2]} cells (rows {rw[0]}-{rw[1]}, "
                f"columns {rw[2]}-{rw[3]}).")
        params = widen_params(run.meth, info, params, run.params, run.log)
        if info.far_cells:
            run.log("Warning: " + far_heights_message(info.far_cells, info.nodata) + " (in that window)")
    return params, whole


def widen_params(method, info, params, given=None, log=None, max_cells=4_000_000):
    """``Method.widen`` of ``method`` (the parameters that are heights of the whole raster, which
    the window or sample the others came from does not hold) on the raster of ``info`` read
    every ``step``-th cell (at most ``max_cells``, as :func:`grid.check_has_data` reads it);
    ``params`` as they are for a method without it. ``given``: the user's values."""
    meth = as_method(method)
    if meth.widen is None:
        return params
    step = max(1, int(math.ceil(math.sqrt(info.cells / max_cells))))
    far = info.far_cells
    overview = info.read(step=step)
    info.far_cells = far                        # counted where the blocks read them
    cell = (info.cell_size_m[0] * step, info.cell_size_m[1] * step)
    wider = meth.widen(params, dict(given or {}), overview, cell)
    if wider != params and log is not None:
        log(f"Parameters that are heights of the whole raster widened to its heights read at one cell in "
            f"{step} along each axis (RASCOR's step 2 limits).")
    return wider


def _ndsm_nodata(float_nodata):
    """The nDSM's nodata: the DTM's, except 0 (every ground cell of an nDSM is DSM - DTM = 0,
    so a nodata of 0 would hide them all): NaN then."""
    return float("nan") if float_nodata == 0 else float_nodata


def _add_outputs(out, meth, outputs, float_nodata):
    """Create the requested outputs in ``out`` (a :class:`grid.OutputSet`)."""
    if outputs.get("dtm"):
        out.add("dtm", outputs["dtm"], "Float32", nodata=float_nodata, descriptions=["DTM"], heights=True)
    if outputs.get("ndsm"):
        out.add("ndsm", outputs["ndsm"], "Float32", nodata=_ndsm_nodata(float_nodata), descriptions=["nDSM"],
                heights=True)
    if outputs.get("mask"):
        out.add("mask", outputs["mask"], "Byte", nodata=NODATA, mask_style=True,
                descriptions=["mask: 0 ground, 1 object, 2 low outlier, 255 nodata"])
    for name, (dt, bands, nod) in meth.extras.items():
        if outputs.get(name):
            gdt = {np.uint8: "Byte", np.float32: "Float32", np.int16: "Int16",
                   np.uint16: "UInt16", np.int32: "Int32"}[np.dtype(dt).type]
            out.add(name, outputs[name], gdt, bands=bands, nodata=nod,
                    descriptions=list(meth.extra_bands.get(name, ())) or None)


def _aux_window(aux, outer):
    return {k: (None if a is None else np.asarray(a)[outer[0]:outer[1], outer[2]:outer[3]])
            for k, a in aux.items()}


class _BlockWriter:
    """Writes each finished block's core into the outputs (in this process, one block at a
    time: GDAL datasets are not safe for concurrent use) and tallies what the run saw."""

    def __init__(self, out, meth, info, float_nodata, flush):
        self.out, self.meth, self.info = out, meth, info
        self.scale, self.float_nodata, self.flush = 1.0 / info.z_to_m, float_nodata, flush
        self.io_lock = threading.Lock()
        self.counts, self.infos, self.weights = {}, [], []
        self.far_cells = 0
        self.filled = 0      # empty cells filled before filtering (fill_empty_cells), in the blocks' cores
        self.moved = {"dtm": 0, "ndsm": 0}   # valid cells that held the outputs' nodata (with_output_nodata)

    def __call__(self, core, outer, result, progress=None):
        m, d, zc, res_extras, res_info, n_far, n_filled = result
        h, w = core[1] - core[0], core[3] - core[2]
        with self.io_lock:
            moved = _write_block(self.out, self.meth, core, m, d, zc, self.scale, self.float_nodata, res_extras, h, w)
            for k, v in moved.items():
                self.moved[k] += v
            report(progress, 0.3)
            if self.flush:
                self.out.flush(sub_progress(progress, 0.3, 1.0))  # compress now, while others are filtered
            report(progress, 1.0)
            for k, v in _code_counts(m).items():
                self.counts[k] = self.counts.get(k, 0) + v
            if res_info is not None:
                self.infos.append(res_info)
                self.weights.append(h * w)
            self.far_cells += n_far
            self.filled += n_filled


def _run_file(info, run, pool):
    """The body of :func:`run_file` once the inputs are checked: derive the parameters, plan
    the windows, filter them into the outputs, summarise."""
    cell = info.cell_size_m
    params, whole = _derive_params(info, run)
    halo = window_halo(run.meth, params, cell)
    budget = None
    held = 0
    if info.cells > IN_MEMORY_CELLS and run.block is None:
        # a given bound covers what the run holds beside its windows (half the memory available leaves it out)
        held = held_outside_windows() if memory.budget_given() else 0
        budget = memory.window_budget(held=held)
    bshape = plan_block(info.shape, halo, block=run.block, workers=run.workers, processes=run.processes,
                        threads=run.meth.threads, bytes_per_cell=run.meth.bytes_per_cell, budget=budget)
    if budget is not None and memory.budget_given():
        check_plan(info.shape, bshape, halo, budget, held=held, workers=run.workers, processes=run.processes,
                   threads=run.meth.threads, bytes_per_cell=run.meth.bytes_per_cell, method=run.meth.name)
    windows = list(blocks.iter_windows(info.shape, bshape, halo))
    # the planned windows of a method using threads inside a window: one at a time, with the threads
    # (the budget is for one window); given blocks run side by side, one thread each
    sequential = (len(windows) > 1 and budget is not None
                  and concurrent_windows(run.workers, run.processes, run.meth.threads) == 1)
    if budget is not None:
        _log_plan(run, info, bshape, halo, windows, budget)
    report(run.progress, RESOLVED)
    stored = (info.nodata, info.scale, info.offset, info.dtype)
    float_nodata = grid.float_output_nodata(*stored)
    if grid.nodata_not_kept(*stored):
        run.log(grid.nodata_not_kept(*stored))
    if run.outputs.get("ndsm") and float_nodata == 0:
        run.log("The DSM's nodata is 0, the height of every ground cell in an nDSM: the nDSM declares NaN "
                "as nodata instead.")
    progress = sub_progress(run.progress, RESOLVED, 0.97)
    with grid.OutputSet(info) as out, grid.bounded_cache(len(windows) > 1):
        _add_outputs(out, run.meth, run.outputs, float_nodata)
        want_dtm = "dtm" in out or "ndsm" in out
        job = _BlockJob(run.meth, info.path, info.band_index, cell, params, want_dtm, want_z="ndsm" in out,
                        workers=run.workers if len(windows) == 1 or sequential else 1,
                        nodata_ranges=info.nodata_ranges,
                        crs_wkt=info.crs_wkt or None)
        writer = _BlockWriter(out, run.meth, info, float_nodata, flush=len(windows) > 1)
        if run.processes > 1 and len(windows) > 1:
            blocks.run_processes(job, [(core, outer, _aux_window(run.aux, outer)) for core, outer in windows],
                                 writer, workers=run.processes, progress=progress, pool=pool)
        else:
            job.use_dataset(info)

            def work(core, outer, block_progress):
                if whole is not None:                 # already in memory: a view, no read
                    zb, n_far = whole[outer[0]:outer[1], outer[2]:outer[3]], 0
                else:
                    with writer.io_lock:
                        zb, n_far = job.read(core, outer)
                writer(core, outer, job.compute(core, outer, _aux_window(run.aux, outer), zb, n_far,
                                                sub_progress(block_progress, 0.0, COMPUTE_SHARE)),
                       progress=sub_progress(block_progress, COMPUTE_SHARE, 1.0))

            blocks.run_windows(work, windows, workers=1 if sequential else run.workers, progress=progress)
        out.commit(progress=sub_progress(run.progress, 0.97, 1.0))
    far = info.far_cells if whole is not None else writer.far_cells
    warnings = list(info.warnings) + ([far_heights_message(far, info.nodata)] if far else [])
    if far:                 # whole or in blocks, the log (QGIS's warnings) says it
        run.log("Warning: " + far_heights_message(far, info.nodata))
    if filled_message(writer.filled):
        run.log(filled_message(writer.filled))
    for what, nod in (("dtm", float_nodata), ("ndsm", _ndsm_nodata(float_nodata))):
        if grid.moved_off_nodata_message(writer.moved[what], nod, what.upper()):
            run.log("Warning: " + grid.moved_off_nodata_message(writer.moved[what], nod, what.upper()))
    empty = no_ground_message(writer.counts, run.outputs)
    if empty:
        warnings.append(empty)
        run.log("Warning: " + empty)
    result = {"method": run.meth.name, "params": params, "halo_cells": halo, "blocks": len(windows),
              "cell_size_m": cell, "warnings": warnings, "notes": list(info.notes)}
    result.update(_merge_info(writer.infos, writer.weights))
    result["empty_cells_filled"] = writer.filled
    result["classes_percent"] = class_shares(writer.counts)
    result["seconds"] = time.perf_counter() - run.t0
    with contextlib.suppress(Cancelled):   # the outputs are in place: a cancel now comes too late
        report(run.progress, 1.0)
    return result


def held_outside_windows():
    """Bytes a run holds beside its windows, which ``BARE_EARTH_MEMORY_MB`` bounds with them
    (:func:`.memory.window_budget`): what it holds above its baseline once GDAL's block cache is emptied
    and the freed memory given back (:func:`.memory.held_by_run`: the inputs read and rasterised before
    the blocks, the parameters' leftovers), and the block cache the blocks may fill
    (:data:`.grid.BLOCK_MODE_CACHE`). Before, the budget went to the windows alone: a 36 Mcells run
    with a 700 MB bound took 1.04 GB."""
    with grid.bounded_cache(True, size=0):
        held = memory.held_by_run()
    return held + grid.BLOCK_MODE_CACHE


def _log_plan(run, info, bshape, halo, windows, budget):
    """Log the blocks :func:`plan_block` chose for a raster above :data:`IN_MEMORY_CELLS`: their size,
    the read amplification, the largest window's memory against the budget (a warning when the
    halo spans the raster or the smallest block exceeds the budget)."""
    n = concurrent_windows(run.workers, run.processes, run.meth.threads) if len(windows) > 1 else 1
    bpc = window_bytes_per_cell(run.meth.bytes_per_cell, n)
    window_mb = largest_window(info.shape, bshape, halo) * bpc / 2 ** 20
    budget_mb = budget / 2 ** 20
    if len(windows) == 1:
        if window_mb <= budget_mb:
            run.log(f"Filtered in one pass over its {info.shape[1]} x {info.shape[0]} cells: about {window_mb:.0f} MB "
                    f"at {bpc:.0f} bytes a cell, within the memory budget of {budget_mb:.0f} MB "
                    f"({memory.BUDGET_ENV} or half the memory available).")
        else:
            run.log(f"Warning: the method's reach, {halo} cells ({halo * max(info.cell_size_m):.0f} m at cells of "
                    f"{max(info.cell_size_m):.3g} m), spans the raster from any block: it is filtered in one pass over "
                    f"its {info.shape[1]} x {info.shape[0]} cells, with the memory that takes "
                    f"(about {window_mb:.0f} MB). A coarser cell (gdalwarp -tr) makes the reach fewer cells.")
        return
    rows, cols = (bshape, bshape) if isinstance(bshape, (int, np.integer)) else bshape
    amp = read_amplification(info.shape, bshape, halo)
    over = window_mb * n > budget_mb
    slow = amp > MAX_READ_AMPLIFICATION
    advice = ""
    if over or slow:
        good = smallest_efficient_budget(info.shape, halo, workers=run.workers, processes=run.processes,
                                         threads=run.meth.threads, bytes_per_cell=run.meth.bytes_per_cell)
        advice = (f" The windows would read at most {MAX_READ_AMPLIFICATION:g} x the raster's cells with "
                  f"{math.ceil(good / 2 ** 20)} MB ({memory.BUDGET_ENV}, or memory freed), or at a coarser cell.")
    run.log(f"{'Warning: ' if over or slow else ''}Blocks of {cols} x {rows} cells with a halo of {halo} cells: "
            f"{len(windows)} windows reading {amp:.2f} x the raster's cells; the largest about {window_mb:.0f} MB "
            f"at {bpc:.0f} bytes a cell, {n} at a time, against a memory budget of {budget_mb:.0f} MB "
            f"({memory.BUDGET_ENV} or half the memory available)"
            + (": the smallest block exceeds it." if over else ".") + advice)


class _BlockJob:
    """The per-block work of :func:`run_file`, picklable for worker processes."""

    def __init__(self, meth, path, band, cell, params, want_dtm, want_z=True, workers=1, nodata_ranges=(),
                 crs_wkt=None):
        self.meth, self.path, self.band, self.nodata_ranges = meth, path, band, tuple(nodata_ranges)
        self.crs_wkt = crs_wkt  # the CRS a file without one reads in (its height unit)
        self.cell, self.params, self.want_dtm = cell, params, want_dtm
        self.workers = workers  # threads inside a block (Method.threads), when blocks do not run side by side
        self.want_z = want_z  # the input block is sent back only when an nDSM is written
        self._info = None

    def __getstate__(self):
        d = dict(self.__dict__)
        d["_info"] = None  # a GDAL dataset does not cross processes: each reopens the file
        return d

    def use_dataset(self, info):
        """Read through ``info`` (an opened :class:`grid.DSMInfo`) instead of reopening the file."""
        self._info = info

    def read(self, core, outer):
        """The block over ``outer`` (float32 metres) and its core's count of far heights."""
        if self._info is None:
            self._info = grid.open_dsm(self.path, self.band, self.nodata_ranges, self.crs_wkt)
        before = self._info.far_cells
        z = self._info.read(outer, far_in=blocks.crop(outer, core))
        return z, self._info.far_cells - before

    def __call__(self, core, outer, aux, progress=None):
        """Read, filter and fill one block (in a worker process)."""
        zb, n_far = self.read(core, outer)
        return self.compute(core, outer, aux, zb, n_far, progress)

    def compute(self, core, outer, aux, zb, n_far, progress):
        """Filter and fill one block read over ``outer``; returns its core's arrays, the
        method's info and ``n_far`` (the core's far heights, for the tally)."""
        meth = self.meth
        c = blocks.crop(outer, core)
        h, w = core[1] - core[0], core[3] - core[2]
        if not np.isfinite(zb).any():
            return (np.full((h, w), NODATA, np.uint8), np.full((h, w), np.nan, np.float32),
                    zb[c] if self.want_z else None, {}, None, n_far, 0)
        filled, n_filled = fill_empty_cells(zb, self.cell)
        if n_filled:
            n_filled = int(np.count_nonzero(np.isfinite(filled[c]))) - int(np.count_nonzero(np.isfinite(zb[c])))
        res, m, d = _process(meth, zb, self.cell, self.params, aux, self.want_dtm, progress, self.workers,
                             filled=filled)
        del filled
        extras = {k: (np.asarray(a)[c] if np.ndim(a) == 2 else np.asarray(a)[(slice(None),) + c])
                  for k, a in res.extras.items()}
        d = d[c] if d is not None else np.full((h, w), np.nan, np.float32)
        return (m[c], d, zb[c] if self.want_z else None, extras, res.info, n_far, n_filled)


def _write_block(out, meth, core, m, d, zc, scale, float_nodata, extras, h, w):
    """Write one block's core (already cropped arrays) into every requested output; returns the
    cells of the DTM and of the nDSM moved off their nodata (:func:`grid.with_output_nodata`)."""
    moved = {"dtm": 0, "ndsm": 0}
    if "mask" in out:
        out.write("mask", m, core)
    if "ndsm" in out:   # before the DTM, which may be converted in place
        ndsm = _to_unit(zc - d, scale)
        moved["ndsm"] = grid.with_output_nodata(ndsm, _ndsm_nodata(float_nodata))
        out.write("ndsm", ndsm, core)
    if "dtm" in out:
        dtm = _to_unit(d, scale)   # this block's DTM is ours: converted in place
        if scale != 1.0:  # ground cells get the input's own heights, not a float32 round trip via metres
            own = out.info.read_heights(core)
            g = m == GROUND
            dtm[g] = own[g]
        moved["dtm"] = grid.with_output_nodata(dtm, float_nodata)
        out.write("dtm", dtm, core)
    for name, (dt, bands, nod) in meth.extras.items():
        if name not in out:
            continue
        if name in extras:
            out.write(name, extras[name], core)
        else:
            shape = (h, w) if bands == 1 else (bands, h, w)
            out.write(name, np.full(shape, nod if nod is not None else 0, dtype=dt), core)
    return moved


def _to_unit(a, scale):
    """``a`` (owned by the caller, changed in place when float32) as float32 in the input's
    height unit."""
    a = a.astype(np.float32, copy=False)
    if scale != 1.0:
        a *= np.float32(scale)
    return a
