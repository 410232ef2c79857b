"""The Dask distributed engine of a survey run.

The default is a ``distributed.LocalCluster`` on this machine's cores: worker processes
(one thread each: the work is numpy on whole windows) started by the spawn method with a
real Python interpreter (inside QGIS ``sys.executable`` is the QGIS binary; the one named
is never looked up on PATH, where another Python without GDAL may come first). Given a
scheduler address, the same tasks go to an existing cluster whose workers import this
plugin's core (``PYTHONPATH`` holding the folder above ``bare_earth``) and see the inputs
and the output folder at the same paths.

Dask is imported lazily, so the rest of the plugin works without it; :func:`require_dask`
names what to install.
"""
import contextlib
import logging
import multiprocessing
import os
import signal
import sys
import threading

from .. import blocks
from ..common import Cancelled, report

#: What to install when Dask is missing.
INSTALL_HINT = ("Filtering a survey of tiles needs Dask distributed. On Debian or Ubuntu: sudo apt install "
                "python3-dask python3-distributed (scripts/setup.sh does it); elsewhere, in the Python that "
                "runs QGIS (OSGeo4W Shell on Windows): python -m pip install \"dask[distributed]\". Every other "
                "Bare Earth algorithm works without it.")
#: Tasks in flight per worker: enough to keep workers busy, few enough that a cancel
#: stops the work soon and the client holds little.
IN_FLIGHT_PER_WORKER = 3
#: Times Dask re-runs a task that raised (a task on a killed worker is rescheduled by
#: the scheduler itself, up to its ``allowed-failures``).
RETRIES = 1
#: Times a tile whose result was lost with its worker (finished, then the worker died
#: before the result reached this client) is submitted again.
RESUBMITS = 3


#: Resident memory of a local worker process before its first tile, MB: Python, numpy, scipy,
#: GDAL, Dask and the plugin's core (measured 110 MB for the imports alone on Debian 12, plus
#: Dask's worker).
WORKER_BASE_MB = 150
#: Peak memory of a filter per cell of the window it works on, bytes: the heaviest filter,
#: dtm (its vote holds its three members' working arrays), peaks at about 970 MB above its
#: input on 16 Mcells (benchmarks/speed.py), 61 B per cell.
WINDOW_BYTES_PER_CELL = 64


def machine_memory():
    """Bytes of memory this process may use (Dask's own figure: RAM, or a cgroup's limit)."""
    from distributed.system import MEMORY_LIMIT
    return int(MEMORY_LIMIT)


def check_workers(workers):
    """ValueError, before any work, when more local worker processes are asked for than this
    computer has cores: one thread each, they only share the cores (no faster), each holds a
    tile's window, and Dask splits the memory between them (a worker beyond its share is
    restarted and its tile fails). 0 or None (one per core) always passes; a negative count
    (``--workers -1``, which ran one per core without a word) is refused."""
    if workers is None:
        return
    if int(workers) < 0:
        raise ValueError(f"WORKERS = {int(workers)}: give a number of local worker processes, or 0 for one per core.")
    if int(workers) == 0:
        return
    cores = blocks.available_cores()
    if int(workers) > cores:
        raise ValueError(f"WORKERS = {int(workers)} local worker processes, but this computer has {cores} core(s) "
                         f"and {machine_memory() / 2 ** 30:.1f} GB of memory: workers beyond the cores run no "
                         "faster (one thread each, sharing the cores), each holds a tile in memory and gets only "
                         f"1/{int(workers)} of it from Dask. Use at most {cores} (0: one per core), or give the "
                         "address of a Dask cluster (SCHEDULER) to use more computers.")


def memory_warning(workers, window_cells, total_bytes=None):
    """The warning (or None) when ``workers`` local workers, each filtering a window of
    ``window_cells`` cells (a tile and its halo), would need more memory than each gets.

    Dask's LocalCluster gives each worker ``total / workers`` and restarts one that passes
    95 % of it (its tile then fails); a worker needs about :data:`WORKER_BASE_MB` plus
    :data:`WINDOW_BYTES_PER_CELL` per cell of its window.
    """
    n = blocks.resolve_workers(workers)
    total = int(total_bytes or machine_memory())
    need = WORKER_BASE_MB * 2 ** 20 + int(window_cells) * WINDOW_BYTES_PER_CELL
    share = total / n
    if need <= 0.95 * share:
        return None
    fits = int(0.95 * total // need)
    fix = (f"use WORKERS = {fits} or fewer" if fits >= 1 else "cut the survey into smaller tiles") + \
        " (or a Dask cluster with more memory)"
    return (f"Memory: each of the {n} local worker(s) gets {share / 2 ** 20:.0f} MB of this computer's "
            f"{total / 2 ** 30:.1f} GB (Dask restarts a worker above 95 % of it, and its tile fails), but a tile's "
            f"window of {window_cells / 1e6:.2f} Mcells (tile and halo) needs about {need / 2 ** 20:.0f} MB: {fix}.")


def have_dask():
    """True when ``distributed`` imports."""
    try:
        import distributed  # noqa: F401
    except ImportError:
        return False
    return True


def require_dask():
    """Import ``distributed`` or raise ImportError with :data:`INSTALL_HINT`."""
    try:
        import distributed
    except ImportError:
        raise ImportError(INSTALL_HINT) from None
    return distributed


def python_executable():
    """The Python interpreter local workers are started with.

    ``sys.executable`` when it is a Python interpreter of this installation (under
    ``sys.exec_prefix``: Debian's /usr/bin/python3, or a virtual environment's python, for
    the command line and the tests). Inside QGIS ``sys.executable`` is the QGIS binary, or
    whatever ``python3`` the embedded interpreter found first on PATH (a pyenv shim, say,
    with another standard library and no GDAL): then the interpreter of the running
    installation itself, ``sys.exec_prefix``/bin/python3.X, is named. Never a PATH lookup.
    """
    exe = sys.executable or ""
    name = os.path.basename(exe).lower()
    prefixes = {os.path.abspath(p) + os.sep for p in (sys.exec_prefix, sys.base_exec_prefix) if p}
    if name.startswith("python") and os.path.exists(exe) and any(os.path.abspath(exe).startswith(p)
                                                                 for p in prefixes):
        return exe
    version = f"python{sys.version_info[0]}.{sys.version_info[1]}"
    for prefix in (sys.exec_prefix, sys.base_exec_prefix):
        for cand in (os.path.join(prefix, "bin", version), os.path.join(prefix, "bin", "python3"),
                     os.path.join(prefix, "python.exe")):
            if os.path.exists(cand):
                return cand
    raise RuntimeError(f"no Python interpreter of this installation ({sys.exec_prefix}) to start Dask workers "
                       f"(sys.executable is {exe!r}): start a cluster yourself and give its scheduler address.")


def check_scheduler_address(scheduler):
    """ValueError, before any work, when ``scheduler`` (not empty) is not a Dask address
    (``protocol://host:port``, e.g. ``tcp://host:8786``; ``host:port`` means tcp)."""
    if not scheduler:
        return
    from distributed.comm.addressing import parse_address, parse_host_port
    try:
        proto, loc = parse_address(str(scheduler))
        if proto in ("tcp", "tls"):
            parse_host_port(loc)
    except ValueError as exc:
        raise ValueError(f"the scheduler address {scheduler!r} is not a Dask address ({exc}): give it as "
                         "tcp://host:8786 (protocol://host:port), or leave it empty for worker processes on this "
                         "computer.") from None


@contextlib.contextmanager
def _interrupts_to_this_process_only():
    """Start worker processes that ignore Ctrl-C (SIGINT, inherited as ignored): a terminal
    sends it to every process of the command, and each worker printed its own traceback
    before the command's one-line message. Only when Ctrl-C raises KeyboardInterrupt here
    (Python's handler), whose handling stops the cluster: a process that Ctrl-C ends at once
    (its default action) must not leave workers behind."""
    if threading.current_thread() is not threading.main_thread() or \
            not callable(signal.getsignal(signal.SIGINT)):
        yield          # QGIS runs algorithms in a task thread: no terminal, and no signals here
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def start_client(workers=0, scheduler=None, log=None):
    """A Dask client: connected to ``scheduler`` (an address such as
    ``tcp://host:8786``), else to a new LocalCluster of ``workers`` processes (0: one per
    core, ``blocks.default_workers``), one thread each.

    Returns
    -------
    client, cluster (None when connected to an existing scheduler)
    """
    distributed = require_dask()
    log = log or (lambda s: None)
    if scheduler:
        try:
            client = distributed.Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as exc:
            raise ValueError(f"cannot reach the Dask scheduler at {scheduler!r} ({exc}): check the address "
                             "and that the scheduler runs.") from None
        return client, None
    n = blocks.resolve_workers(workers)
    exe = python_executable()
    if exe != sys.executable:
        multiprocessing.get_context("spawn").set_executable(exe)
    with _interrupts_to_this_process_only(), blocks.main_not_rerun():    # workers spawn without the script
        cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                           dashboard_address=None, silence_logs=logging.ERROR)
    client = distributed.Client(cluster)
    log(f"Local Dask cluster: {n} worker process(es) of 1 thread ({exe}).")
    return client, cluster


def worker_summary(client):
    """``{address: {"name", "nthreads", "memory_limit_mb", "host"}}`` of the cluster's workers."""
    out = {}
    for addr, w in client.scheduler_info().get("workers", {}).items():
        out[addr] = {"name": str(w.get("name")), "nthreads": w.get("nthreads"), "host": w.get("host"),
                     "memory_limit_mb": round((w.get("memory_limit") or 0) / 2 ** 20, 1)}
    return out


def run_tasks(client, func, job, items, on_done, on_failed, progress=None):
    """Run ``func(job, item)`` for every item on the cluster, handing results over as they come.

    At most :data:`IN_FLIGHT_PER_WORKER` tasks per worker are submitted at a time; more are
    handed out as tasks finish, so a cancel (``progress`` raising :class:`Cancelled`) stops
    the work at once: the pending futures are cancelled and nothing new is submitted.

    Parameters
    ----------
    on_done : callable
        ``on_done(item, result)``, called here as each task finishes.
    on_failed : callable
        ``on_failed(item, exception)`` for a task that raised (after its retries) or whose
        workers kept dying.
    progress : callable, optional
        ``progress(fraction of items finished)``; may raise Cancelled.
    """
    distributed = require_dask()
    items = list(items)
    n = len(items)
    if n == 0:
        return
    queue = iter(items)
    inflight = {}
    again = []                 # items whose result was lost with their worker
    resubmitted = {}
    ac = distributed.as_completed()

    def submit(item):
        fut = client.submit(func, job, item, pure=False, retries=RETRIES)
        inflight[fut] = item
        ac.add(fut)

    def top_up():
        limit = max(2, IN_FLIGHT_PER_WORKER * max(1, len(client.scheduler_info().get("workers", {}))))
        while again:
            submit(again.pop())
        while len(inflight) < limit:
            item = next(queue, None)
            if item is None:
                return
            submit(item)

    finished = 0
    try:
        top_up()
        for fut in ac:
            item = inflight.pop(fut)
            status, result = fut.status, None
            if status == "finished":
                try:
                    result = fut.result()
                except Exception:            # noqa: BLE001 - lost between the status and the fetch
                    status = "lost"
            elif status == "error":
                result = fut.exception()
            fut.release()
            if status not in ("finished", "error") and resubmitted.get(id(item), 0) < RESUBMITS:
                resubmitted[id(item)] = resubmitted.get(id(item), 0) + 1
                again.append(item)
                top_up()
                continue
            if status == "finished":
                on_done(item, result)
            elif status == "error":
                on_failed(item, result)
            else:
                on_failed(item, RuntimeError(f"the task ended {status} {RESUBMITS + 1} times"))
            finished += 1
            report(progress, finished / n)
            top_up()
    except (Cancelled, KeyboardInterrupt):
        client.cancel(list(inflight))
        raise
