"""How a process that only filters rasters allocates memory: freed memory kept for reuse.

The filters' numpy work allocates and frees raster-sized temporaries by the hundred (a 16
Mcells float32 raster is 64 MB). glibc's ``malloc`` serves each of them with a fresh ``mmap``
and returns it to the system when it is freed, so the kernel zeroes every page of every
temporary again on first touch: on the project's 2-core machine ``bareearth:dtm`` on 16 Mcells
spent 1.8-3.3 s of its 10-13 s CPU in the kernel (about 225,000 page faults). Served from one heap
that keeps what is freed (one malloc arena, no ``mmap``, no trimming), the same run takes 0.3-0.8 s
of kernel time (about 50,000 faults) with the same peak memory (1.10-1.20 GB); the results are the
same bit for bit (only where the bytes live changes).

The settings are process-wide and the arena limit stays for the process's life (threads started
before it keep their arenas), so they are applied only in processes that do nothing but filter:
the plugin's block worker processes (:func:`.blocks.start_pool`) and the benchmarks that ask for
them (``benchmarks/speed.py --reuse-memory``: :data:`ALLOCATOR_ENV` in the environment of the process
it starts). Inside QGIS the plugin leaves the application's allocator alone (one arena for QGIS's
rendering threads would make them wait on one another), and so do the survey's Dask workers (Dask
sets its own trimming for them and restarts a worker whose memory grows).
"""
import contextlib
import contextvars
import ctypes
import ctypes.util
import math
import os

#: glibc ``mallopt`` parameters (``malloc.h``).
_M_TRIM_THRESHOLD, _M_MMAP_MAX, _M_ARENA_MAX = -1, -4, -8
#: Largest ``int`` (``mallopt`` takes an int): free memory at the heap's top is never trimmed.
_NEVER_TRIM = (1 << 31) - 1
#: The same settings as glibc environment variables, read when a process starts: for processes
#: this one starts (they inherit them with the environment).
ALLOCATOR_ENV = {"MALLOC_ARENA_MAX": "1", "MALLOC_MMAP_MAX_": "0", "MALLOC_TRIM_THRESHOLD_": str(_NEVER_TRIM)}

_applied = None


def reuse_freed_memory():
    """Keep freed memory in this process for reuse (glibc: one arena, no ``mmap``, no trim).

    Call it early, before the process starts threads of its own. Idempotent; does nothing where
    the C library is not glibc. Returns True when the settings are in force.
    """
    global _applied
    if _applied is None:
        _applied = False
        name = ctypes.util.find_library("c")
        try:
            libc = ctypes.CDLL(name) if name else None
            mallopt = getattr(libc, "mallopt", None)
            if mallopt is not None and hasattr(libc, "gnu_get_libc_version"):
                mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
                _applied = all(mallopt(k, v) == 1 for k, v in ((_M_ARENA_MAX, 1), (_M_MMAP_MAX, 0),
                                                               (_M_TRIM_THRESHOLD, _NEVER_TRIM)))
        except OSError:
            pass
    return _applied


def allocator_environment(env=None):
    """``env`` (default: this process's environment) with :data:`ALLOCATOR_ENV` added, for a
    process that will do nothing but filter."""
    out = dict(os.environ if env is None else env)
    out.update(ALLOCATOR_ENV)
    return out


#: Environment variable giving the memory a run's windows may take together, megabytes
#: (:func:`window_budget`); unset: a share of the memory available when the run starts.
BUDGET_ENV = "BARE_EARTH_MEMORY_MB"
#: Share of the memory available when a run starts that its windows may take together: the rest
#: stays for the other programs (QGIS, other runs), GDAL's block cache and the outputs' compression.
BUDGET_SHARE = 0.5
#: The budget when the available memory cannot be read (bytes): 2 GB.
FALLBACK_BUDGET = 2 << 30


def _proc_kb(path, key):
    """Bytes of the ``key: N kB`` line of the /proc file ``path`` (``/proc/meminfo``,
    ``/proc/self/status``); None when the file, the line or its number cannot be read."""
    prefix = key + ":"
    try:
        with open(path) as f:
            for line in f:
                if line.startswith(prefix):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def available_memory():
    """Bytes of memory available for new work: ``MemAvailable`` of ``/proc/meminfo`` (Linux: free
    memory plus the page cache the kernel can drop), else the free physical pages; None when unknown."""
    avail = _proc_kb("/proc/meminfo", "MemAvailable")
    if avail is not None:
        return avail
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, OSError, ValueError):
        return None


def resident_bytes():
    """This process's resident memory (``VmRSS`` of ``/proc/self/status``), bytes; None when unknown."""
    return _proc_kb("/proc/self/status", "VmRSS")


def release_freed_memory():
    """Give the memory freed at the heap back to the system (glibc ``malloc_trim(0)``), so that the
    resident memory measures what is held; nothing in a process that keeps its freed memory for reuse
    (:func:`reuse_freed_memory`) or where the C library is not glibc. Returns True when trimmed."""
    if _applied:
        return False
    name = ctypes.util.find_library("c")
    try:
        libc = ctypes.CDLL(name) if name else None
        trim = getattr(libc, "malloc_trim", None)
        if trim is None:
            return False
        trim.argtypes = (ctypes.c_size_t,)
        trim(0)
        return True
    except OSError:
        return False


_BASELINE = contextvars.ContextVar("bare_earth_memory_baseline", default=None)


@contextlib.contextmanager
def run_baseline():
    """Within: the run's memory is measured from this process's resident memory when the outermost
    such context was entered (:func:`held_by_run`): an algorithm enters it before its own reads (a
    vector layer rasterised on the DSM's grid, the checks' reads), ``pipeline.run_file`` too (for a
    caller from Python); the memory the application held before (QGIS) is not the run's."""
    token = None
    if _BASELINE.get() is None:
        release_freed_memory()      # measured as held_by_run measures: without the freed memory kept
        token = _BASELINE.set(resident_bytes())
    try:
        yield
    finally:
        if token is not None:
            _BASELINE.reset(token)


def held_by_run():
    """Bytes this process holds above the run's baseline (:func:`run_baseline`) after giving back the
    freed memory (:func:`release_freed_memory`): the run's arrays still alive (the inputs read, the
    parameters' leftovers) that its windows come on top of; 0 outside a run or when unknown."""
    base = _BASELINE.get()
    if base is None:
        return 0
    release_freed_memory()
    now = resident_bytes()
    return max(0, now - base) if now is not None else 0


def budget_given(env=None):
    """True when ``BARE_EARTH_MEMORY_MB`` is set (in ``env``, default this process's environment): the
    budget is then the run's bound, and what the run holds beside its windows counts against it."""
    env = os.environ if env is None else env
    return bool(env.get(BUDGET_ENV, "").strip())


def budget_mb(env=None):
    """The megabytes ``BARE_EARTH_MEMORY_MB`` gives (in ``env``, default this process's environment), None
    when it is not set. ValueError naming the variable when it is no positive finite number: read only when
    a raster of more than ``pipeline.IN_MEMORY_CELLS`` was planned, 'abc' was refused after the parameters'
    derivation and 'inf' failed there with a bare OverflowError; the filters' checks and ``run_file`` call
    this before any work."""
    env = os.environ if env is None else env
    given = env.get(BUDGET_ENV, "").strip()
    if not given:
        return None
    try:
        mb = float(given)
    except ValueError:
        raise ValueError(f"{BUDGET_ENV}={given!r} is not a number of megabytes: give one (e.g. 4000), or unset "
                         "it for half the memory available.") from None
    if not (mb > 0 and math.isfinite(mb)):
        raise ValueError(f"{BUDGET_ENV}={given!r}: give a positive number of megabytes (e.g. 4000), or unset it "
                         "for half the memory available.")
    return mb


def window_budget(env=None, held=0):
    """Bytes the windows of one run may take together: ``BARE_EARTH_MEMORY_MB`` megabytes when set
    (in ``env``, default this process's environment) less ``held``, what the run holds outside its
    windows (:func:`held_by_run`: the inputs it read, the parameters' leftovers; GDAL's block cache),
    at least 0: the variable bounds the whole run's memory above what the process held before it.
    Unset: :data:`BUDGET_SHARE` of :func:`available_memory` (what the run holds is already not
    available; :data:`FALLBACK_BUDGET` when that is unknown)."""
    mb = budget_mb(env)
    if mb is not None:
        return max(0, int(mb * (1 << 20)) - int(held))
    avail = available_memory()
    return int(BUDGET_SHARE * avail) if avail else FALLBACK_BUDGET
