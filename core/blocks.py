"""Block engine: run a per-block function over a large surface with a halo.

The one place tiling lives. A block is read with ``halo`` extra cells on every side
(clipped at the raster's edge), processed, and only its core is kept, so a method whose
reach is at most ``halo`` cells gives the same result blocked as in one pass.
"""
import contextlib
import functools
import multiprocessing
import os
import queue as queue_module
import signal
import sys
import threading
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, ThreadPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

import numpy as np

from .common import Cancelled, report
from .memory import reuse_freed_memory

#: Default block edge in cells (about 16 MB of float32 per block with its halo).
DEFAULT_BLOCK = 2048


#: Most threads :func:`default_workers` proposes (more gain nothing on memory-bound work).
MAX_AUTO_WORKERS = 8


def available_cores():
    """The cores this process may run on (its CPU affinity; else the machine's count)."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        n = os.cpu_count() or 1
    return max(1, int(n))


def default_workers():
    """Threads to use when the caller says 0 (automatic): the cores this process may run
    on (:func:`available_cores`), at most :data:`MAX_AUTO_WORKERS`."""
    return min(available_cores(), MAX_AUTO_WORKERS)


def resolve_workers(workers):
    """``workers`` as a thread count: None or <= 0 means :func:`default_workers`."""
    if workers is None or int(workers) <= 0:
        return default_workers()
    return int(workers)


#: Least alignment of a window's upper-left corner on the raster's grid, cells.
MIN_ALIGN = 64


def alignment(halo):
    """Alignment of a window's upper-left corner: the largest power of two dividing ``halo``,
    at least :data:`MIN_ALIGN`.

    Methods that coarsen their grid internally anchor the coarse cells on the array they are
    given. They round their halo up to their coarsening factor (a power of two:
    ``geodesic_halo``) or to an even number (``curvature_halo``); a window whose corner lies
    on a multiple of this sees the coarse grids of the single pass, whatever the block size.

    Examples
    --------
    >>> alignment(42), alignment(416), alignment(384)
    (64, 64, 128)
    """
    halo = int(halo)
    p = halo & -halo if halo > 0 else 1
    return max(MIN_ALIGN, p)


def iter_windows(shape, block=DEFAULT_BLOCK, halo=0, align=None):
    """Yield ``(core, outer)`` windows covering ``shape``.

    Each window is ``(r0, r1, c0, c1)`` (half-open). ``outer`` is ``core`` grown by
    ``halo`` cells and clipped to the raster, its upper-left corner moved further out onto
    a multiple of ``align`` (default :func:`alignment` of the halo; 1 for none), so that
    blocked equals one pass for any block size.

    Examples
    --------
    >>> list(iter_windows((3, 5), block=4, halo=1, align=1))
    [((0, 3, 0, 4), (0, 3, 0, 5)), ((0, 3, 4, 5), (0, 3, 3, 5))]
    >>> list(iter_windows((3, 70), block=(3, 66), halo=1))
    [((0, 3, 0, 66), (0, 3, 0, 67)), ((0, 3, 66, 70), (0, 3, 64, 70))]
    """
    rows, cols = shape
    if isinstance(block, (int, np.integer)):
        block = (int(block), int(block))
    br, bc = max(1, int(block[0])), max(1, int(block[1]))
    halo = max(0, int(halo))
    a = max(1, int(alignment(halo) if align is None else align))
    for r0 in range(0, rows, br):
        r1 = min(rows, r0 + br)
        for c0 in range(0, cols, bc):
            c1 = min(cols, c0 + bc)
            yield ((r0, r1, c0, c1),
                   (max(0, (r0 - halo) // a * a), min(rows, r1 + halo),
                    max(0, (c0 - halo) // a * a), min(cols, c1 + halo)))


def crop(outer, core):
    """Slices that cut ``core`` out of an array read over ``outer``."""
    return (slice(core[0] - outer[0], core[1] - outer[0]), slice(core[2] - outer[2], core[3] - outer[2]))


def block_count(shape, block=DEFAULT_BLOCK):
    """Number of blocks :func:`iter_windows` yields."""
    if isinstance(block, (int, np.integer)):
        block = (int(block), int(block))
    return -(-shape[0] // block[0]) * -(-shape[1] // block[1])


class BlockProgress:
    """The progress of ``n`` blocks running at once, as one fraction for ``progress``.

    Each block reports its own fraction (its method's progress); the whole is the mean of
    the blocks' fractions, so the bar moves while blocks run, not only when one ends.
    Thread-safe. Once ``progress`` has raised (:class:`~.common.Cancelled`), every later
    report raises that again at once: blocks still running stop at their next progress
    call, blocks not started yet do not start.
    """

    def __init__(self, progress, n):
        self._progress, self._n = progress, max(1, int(n))
        self._done = [0.0] * self._n
        self._total = 0.0
        self._lock = threading.Lock()
        self.error = None

    def check(self):
        """Raise the error the callback raised, if it did."""
        if self.error is not None:
            raise self.error

    def report(self, k, fraction):
        """Block ``k`` is ``fraction`` done (0..1); forwards the whole's fraction."""
        self.check()
        f = min(max(float(fraction), 0.0), 1.0)
        with self._lock:
            if f <= self._done[k]:
                return
            self._total += f - self._done[k]
            self._done[k] = f
            try:
                report(self._progress, self._total / self._n)
            except BaseException as exc:
                self.error = exc
                raise

    def of_block(self, k):
        """The ``progress(fraction)`` callback of block ``k`` (checks cancellation even when
        the caller gave no callback)."""
        return lambda f: self.report(k, f)


def run_windows(func, windows, *, workers=1, progress=None):
    """Call ``func(core, outer, block_progress)`` for every window pair, in order of completion.

    ``func`` does the reading, the work and the writing of one block and reports its own
    progress through ``block_progress(fraction)`` (which raises when the run is cancelled);
    ``progress`` gets the whole's fraction (:class:`BlockProgress`). With ``workers > 1``
    blocks run in threads (numpy and GDAL release the GIL for most of the heavy lifting). At
    most ``2 * workers`` blocks are in flight, so memory stays bounded whatever the raster's
    size. On cancellation the blocks not started are dropped and the running ones stop at
    their next progress call.
    """
    windows = list(windows)
    n = len(windows)
    bp = BlockProgress(progress, n)

    def one(k, core, outer):
        bp.check()                                  # cancelled while queued: do not start
        func(core, outer, bp.of_block(k))
        bp.report(k, 1.0)

    if workers <= 1 or n <= 1:
        for k, (core, outer) in enumerate(windows):
            one(k, core, outer)
        return
    with ThreadPoolExecutor(max_workers=workers) as pool:
        pending = []
        try:
            for k, (core, outer) in enumerate(windows):
                pending.append(pool.submit(one, k, core, outer))
                if len(pending) >= 2 * workers:
                    pending.pop(0).result()
            for fut in pending:
                fut.result()
        except BaseException as exc:
            if bp.error is None:
                bp.error = exc                      # the running blocks stop at their next report
            for fut in pending:
                fut.cancel()
            raise


def run_sharing(tasks, pool=None):
    """Run independent ``tasks`` (callables without arguments) and return their results in order; with
    ``pool`` (an executor whose threads may be busy with other work), the threads that fall idle take
    some of them.

    Every task is queued on ``pool``; the calling thread then runs the queued tasks itself from the last
    one back (cancelling each one no thread has taken yet), while the pool's threads take them from the
    first one on as they fall idle, and it waits only for the tasks another thread is running. Without
    ``pool``: one after the other. The calling thread may itself be one of ``pool``'s threads (it never
    waits for a task that no thread runs), so a member of ``bareearth:dtm`` running on the vote's
    threads lends its independent parts to the thread another member has left. The results are those of
    one after the other whoever ran the tasks; an exception of a task is raised (the queued tasks are
    cancelled first).
    """
    tasks = list(tasks)
    if pool is None or len(tasks) < 2:
        return [t() for t in tasks]
    futures = [pool.submit(t) for t in tasks]
    results = [None] * len(tasks)
    try:
        for i in range(len(tasks) - 1, -1, -1):
            if futures[i].cancel():
                results[i] = tasks[i]()
        for i, f in enumerate(futures):
            if not f.cancelled():
                results[i] = f.result()
    except BaseException:
        for f in futures:
            f.cancel()
        raise
    return results


def _is_this_process(exe):
    """False when ``exe`` is known not to be the program running us (Linux: /proc/self/exe)."""
    try:
        me = os.path.realpath("/proc/self/exe")
    except OSError:
        return True
    if not os.path.exists("/proc/self/exe"):
        return True                                   # no /proc: nothing to compare with
    return os.path.realpath(exe) == me


def python_interpreter():
    """The Python interpreter worker processes are started with: the one running us.

    ``sys.executable`` when it is a Python interpreter and the program running us. Inside
    QGIS it is the QGIS binary (``qgis``, ``qgis-bin.exe``), or, in an embedded interpreter
    that looked its program name up on PATH (``qgis_process``), whatever ``python3`` comes
    first on PATH; the workers then get the interpreter QGIS's Python was built with, found
    from ``sys.base_prefix`` and ``sys.version_info`` (``<prefix>/bin/python3.11``,
    ``<prefix>\\python.exe``), never by a PATH lookup: the ``python3`` first on PATH may be
    another build (a pyenv shim) or a planted program.

    Raises
    ------
    RuntimeError
        When no interpreter of our version is found (name it in the message; threads need none).
    """
    exe = sys.executable or ""
    if (os.path.basename(exe).lower().startswith("python") and os.access(exe, os.X_OK)
            and _is_this_process(exe)):
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


@contextlib.contextmanager
def main_not_rerun():
    """Worker processes spawned inside this block do not run this program's main script again.

    A spawned child imports the parent's ``__main__`` (from its file or module name) before it
    runs anything: a PyQGIS or Python script calling the filters with PROCESSES > 1 and no
    ``if __name__ == "__main__":`` guard was run again from its first line in every worker,
    which rewrote the script's files (its input DSM among them) and died on multiprocessing's
    "bootstrapping phase" error (BrokenProcessPool). The workers need nothing of ``__main__``
    (their jobs are this package's functions), so it is hidden from the spawn: no file, no spec."""
    main = sys.modules.get("__main__")
    if main is None:
        yield
        return
    saved = {k: main.__dict__[k] for k in ("__file__", "__spec__") if k in main.__dict__}
    main.__dict__.pop("__file__", None)
    main.__spec__ = None
    try:
        yield
    finally:
        main.__dict__.pop("__file__", None)
        main.__dict__.pop("__spec__", None)
        main.__dict__.update(saved)


#: Set in a worker process by :func:`_init_worker`: the queue its progress goes to and the
#: event that says the run was cancelled.
_worker_channel = {}


#: Seconds between a worker's checks that the process that started it still runs.
PARENT_CHECK_S = 1.0


def exit_with_parent(parent=None, interval=PARENT_CHECK_S):
    """End this (worker) process once the process that started it is gone.

    A run killed outright (``kill -9``, a crash of QGIS) cannot stop its workers: each holds both
    ends of the pool's queues, so none sees them close, and they waited for blocks for ever, holding
    their memory (two idle workers of 96 MB each, or a block's windows). A daemon thread checks every
    ``interval`` seconds that the parent is still the one the worker started under (POSIX gives an
    orphan a new parent) and ends the process at once otherwise. ``parent``: the pid of the process
    that started this one (default the current parent; a pool passes its own, so that a worker whose
    start outlived it, already an orphan when this runs, ends too)."""
    parent = os.getppid() if parent is None else int(parent)

    def watch():
        while True:
            time.sleep(interval)
            if os.getppid() != parent:      # ends the process at once, as a killed worker ends
                os.kill(os.getpid(), getattr(signal, "SIGKILL", signal.SIGTERM))
    threading.Thread(target=watch, name="bare-earth-parent-watch", daemon=True).start()


def _init_worker(queue, cancelled, parent=None):
    # a worker only filters: its freed temporaries are kept for reuse (memory.reuse_freed_memory)
    reuse_freed_memory()
    exit_with_parent(parent)
    _worker_channel.update(queue=queue, cancelled=cancelled, last=0.0)


def _worker_progress(k, fraction):
    """A worker's block ``k`` is ``fraction`` done: raise Cancelled when the run was
    cancelled, else send the fraction home (at most every 1 %)."""
    ch = _worker_channel
    if ch["cancelled"].is_set():
        raise Cancelled()
    if fraction - ch["last"] >= 0.01 or fraction >= 1.0:
        ch["last"] = fraction
        ch["queue"].put((k, fraction))


def _run_job(job, k, *item):
    """Run ``job(*item, progress=...)`` in a worker, its progress sent home as block ``k``."""
    _worker_channel["last"] = 0.0
    if _worker_channel["cancelled"].is_set():
        raise Cancelled()
    return job(*item, progress=functools.partial(_worker_progress, k))


class WorkerPool:
    """Worker processes (spawned with :func:`python_interpreter`) and the channel their
    blocks' progress comes back on: a queue of ``(block, fraction)`` and an event that
    tells them the run was cancelled (they stop at their next progress call)."""

    def __init__(self, workers, warm_up=None):
        ctx = _process_context()
        self.queue, self.cancelled = ctx.Queue(), ctx.Event()
        self.executor = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_init_worker,
                                            initargs=(self.queue, self.cancelled, os.getpid()))
        if warm_up is not None:
            with main_not_rerun():      # submit spawns the workers
                for _ in range(workers):
                    self.executor.submit(warm_up)

    def messages(self):
        """The ``(block, fraction)`` reports that arrived so far."""
        out = []
        while True:
            try:
                out.append(self.queue.get_nowait())
            except queue_module.Empty:
                return out

    def shutdown(self, wait=True):
        """Stop the workers (``wait=False``: running blocks are told to stop and not awaited)."""
        if not wait:
            self.cancelled.set()
        self.executor.shutdown(wait=wait, cancel_futures=True)


#: The refusal of a run whose worker process died (:func:`run_processes`).
WORKER_DIED = ("a worker process ended abruptly while filtering the blocks (killed: most often by the system "
               "when the memory ran out, or by a user), so the run stopped and nothing was written. Run again with "
               "fewer worker processes (PROCESSES), smaller blocks (BLOCK_SIZE), or threads in one process "
               "(THREADS) instead.")


def start_pool(workers, warm_up=None):
    """A :class:`WorkerPool` whose workers start (spawn and import) right away, in the background.

    ``warm_up``: a module-level function each new worker runs first, to import what the
    jobs will need (numpy, scipy, GDAL, the methods) while this process does other work.
    """
    return WorkerPool(workers, warm_up)


def run_processes(job, items, on_result, *, workers=2, progress=None, pool=None):
    """Run ``job(*item, progress=...)`` for every item in worker processes; ``on_result(core,
    outer, result)`` is called here, in this process, as results arrive (so this process
    does all writing).

    ``job`` must be picklable and report its progress through its ``progress`` keyword
    (it raises :class:`~.common.Cancelled` once the run is cancelled). ``pool`` may be one
    from :func:`start_pool` (it is shut down at the end). ``items`` are ``(core, outer,
    extra)`` tuples; at most ``2 * workers`` are in flight, so memory stays bounded.
    ``progress`` gets the whole's fraction, blocks' own progress included, and may raise
    ``Cancelled``: the pending blocks are then cancelled, and the running ones stop at their
    next progress call. A worker that dies (the system's out-of-memory killer) raises ValueError
    (:data:`WORKER_DIED`: what happened and the settings that use less memory) instead of the
    pool's BrokenProcessPool traceback.
    """
    pool = pool or WorkerPool(workers)
    bp = BlockProgress(progress, len(items))
    pending = {}

    def drain(limit):
        """Forward progress and hand finished blocks to ``on_result`` until at most ``limit``
        are pending."""
        while len(pending) > limit:
            finished, _ = wait(list(pending), timeout=0.2, return_when=FIRST_COMPLETED)
            for k, f in pool.messages():
                bp.report(k, f)
            for fut in finished:
                k, (core, outer, _x) = pending.pop(fut)
                on_result(core, outer, fut.result())
                bp.report(k, 1.0)

    try:
        for k, item in enumerate(items):
            with main_not_rerun():      # submit spawns the workers not started yet
                pending[pool.executor.submit(_run_job, job, k, *item)] = (k, item)
            drain(2 * workers - 1)
        drain(0)
    except BaseException as exc:
        pool.cancelled.set()                      # running blocks stop at their next progress call
        for fut in pending:
            fut.cancel()
        pool.shutdown(wait=True)
        if isinstance(exc, BrokenProcessPool):
            raise ValueError(WORKER_DIED) from None
        raise
    pool.shutdown(wait=True)
