"""Block engine: run a per-block function over a large surface with a halo.

The one place tiling lives. A block is read with ``halo`` extra cells on every side
(clipped at the raster's edge), processed, and only its core is kept, so a method whose
reach is at most ``halo`` cells gives the same result blocked as in one pass.
"""
import multiprocessing
import os
import sys
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, ThreadPoolExecutor, wait

import numpy as np

from .common import report

#: Default block edge in cells (about 16 MB of float32 per block with its halo).
DEFAULT_BLOCK = 2048


#: Most threads :func:`default_workers` proposes (more gain nothing on memory-bound work).
MAX_AUTO_WORKERS = 8


def default_workers():
    """Threads to use when the caller says 0 (automatic): the cores this process may run
    on (its CPU affinity), at most :data:`MAX_AUTO_WORKERS`."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        n = os.cpu_count() or 1
    return max(1, min(int(n), MAX_AUTO_WORKERS))


def resolve_workers(workers):
    """``workers`` as a thread count: None or <= 0 means :func:`default_workers`."""
    if workers is None or int(workers) <= 0:
        return default_workers()
    return int(workers)


def iter_windows(shape, block=DEFAULT_BLOCK, halo=0):
    """Yield ``(core, outer)`` windows covering ``shape``.

    Each window is ``(r0, r1, c0, c1)`` (half-open). ``outer`` is ``core`` grown by
    ``halo`` cells and clipped to the raster.

    Examples
    --------
    >>> list(iter_windows((3, 5), block=4, halo=1))
    [((0, 3, 0, 4), (0, 3, 0, 5)), ((0, 3, 4, 5), (0, 3, 3, 5))]
    """
    rows, cols = shape
    if isinstance(block, (int, np.integer)):
        block = (int(block), int(block))
    br, bc = max(1, int(block[0])), max(1, int(block[1]))
    halo = max(0, int(halo))
    for r0 in range(0, rows, br):
        r1 = min(rows, r0 + br)
        for c0 in range(0, cols, bc):
            c1 = min(cols, c0 + bc)
            yield ((r0, r1, c0, c1),
                   (max(0, r0 - halo), min(rows, r1 + halo), max(0, c0 - halo), min(cols, c1 + halo)))


def crop(outer, core):
    """Slices that cut ``core`` out of an array read over ``outer``."""
    return (slice(core[0] - outer[0], core[1] - outer[0]), slice(core[2] - outer[2], core[3] - outer[2]))


def block_count(shape, block=DEFAULT_BLOCK):
    """Number of blocks :func:`iter_windows` yields."""
    if isinstance(block, (int, np.integer)):
        block = (int(block), int(block))
    return -(-shape[0] // block[0]) * -(-shape[1] // block[1])


def run_windows(func, windows, *, workers=1, progress=None):
    """Call ``func(core, outer)`` for every window pair, in order of completion.

    ``func`` does the reading, the work and the writing of one block; with
    ``workers > 1`` blocks run in threads (numpy and GDAL release the GIL for most of the
    heavy lifting). At most ``2 * workers`` blocks are in flight, so memory stays bounded
    whatever the raster's size. ``progress`` gets the fraction of blocks done.
    """
    windows = list(windows)
    n = len(windows)
    if workers <= 1 or n <= 1:
        for k, (core, outer) in enumerate(windows):
            func(core, outer)
            report(progress, (k + 1) / n)
        return
    done = 0
    with ThreadPoolExecutor(max_workers=workers) as pool:
        pending = []
        for core, outer in windows:
            pending.append(pool.submit(func, core, outer))
            if len(pending) >= 2 * workers:
                pending.pop(0).result()
                done += 1
                report(progress, done / n)
        for fut in pending:
            fut.result()
            done += 1
            report(progress, done / n)


def python_interpreter():
    """The Python interpreter worker processes are started with: the one running us.

    ``sys.executable`` when it is a Python interpreter. Inside QGIS it is the QGIS binary
    (``qgis``, ``qgis_process``, ``qgis-bin.exe``); the workers then get the interpreter
    QGIS's Python was built with, found from ``sys.base_prefix`` and ``sys.version_info``
    (``<prefix>/bin/python3.11``, ``<prefix>\\python.exe``), never by a PATH lookup: the
    ``python3`` first on PATH may be another build (a pyenv shim) or a planted program.

    Raises
    ------
    RuntimeError
        When no interpreter of our version is found (name it in the message; threads need none).
    """
    exe = sys.executable or ""
    if os.path.basename(exe).lower().startswith("python") and os.access(exe, os.X_OK):
        return exe
    major, minor = sys.version_info[:2]
    candidates = []
    for prefix in dict.fromkeys((sys.base_exec_prefix, sys.base_prefix, sys.exec_prefix, sys.prefix)):
        if not prefix:
            continue
        candidates += [os.path.join(prefix, "bin", f"python{major}.{minor}"),
                       os.path.join(prefix, "bin", f"python{major}"),
                       os.path.join(prefix, "python.exe"), os.path.join(prefix, f"python{major}.exe")]
    for c in candidates:
        if os.path.isfile(c) and os.access(c, os.X_OK):
            return c
    raise RuntimeError(f"cannot find the Python {major}.{minor} interpreter this program runs on (looked "
                       f"for {', '.join(candidates)}) to start worker processes: use threads (THREADS) "
                       "instead of processes.")


def _process_context():
    """A multiprocessing context that is safe wherever we run: spawn, never fork.

    Forking copies a process whose other threads may hold locks (GDAL's tile-compression
    threads, Qt's threads inside QGIS), which deadlocks the child; spawned workers start
    clean, with :func:`python_interpreter`.
    """
    ctx = multiprocessing.get_context("spawn")
    ctx.set_executable(python_interpreter())
    return ctx


def start_pool(workers, warm_up=None):
    """A process pool whose workers start (spawn and import) right away, in the background.

    ``warm_up``: a module-level function each new worker runs first, to import what the
    jobs will need (numpy, scipy, GDAL, the methods) while this process does other work.
    """
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=_process_context())
    if warm_up is not None:
        for _ in range(workers):
            pool.submit(warm_up)
    return pool


def run_processes(job, items, on_result, *, workers=2, progress=None, pool=None):
    """Run ``job(*item)`` for every item in worker processes; ``on_result(core, outer, result)``
    is called here, in this process, as results arrive (so this process does all writing).

    ``pool`` may be one from :func:`start_pool` (it is shut down at the end).
    ``items`` are ``(core, outer, extra)`` tuples; at most ``2 * workers`` are in flight, so
    memory stays bounded. ``progress`` gets the fraction done and may raise ``Cancelled``:
    the pending blocks are then cancelled and the workers stopped.
    """
    n = len(items)
    done = 0
    with (pool or ProcessPoolExecutor(max_workers=workers, mp_context=_process_context())) as pool:
        pending = {}

        def drain(limit):
            """Hand finished blocks to ``on_result`` until at most ``limit`` are pending."""
            nonlocal done
            while len(pending) > limit:
                finished, _ = wait(list(pending), return_when=FIRST_COMPLETED)
                for fut in finished:
                    core, outer, _x = pending.pop(fut)
                    on_result(core, outer, fut.result())
                    done += 1
                    report(progress, done / n)

        try:
            for item in items:
                pending[pool.submit(job, *item)] = item
                drain(2 * workers - 1)
            drain(0)
        except BaseException:
            for fut in pending:
                fut.cancel()
            raise
