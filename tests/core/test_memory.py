"""The allocator of processes that only filter (core/memory.py)."""
import os
import platform
import subprocess
import sys

import pytest

from bare_earth.core import blocks, memory

PLUGINS = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(memory.__file__))))


def test_allocator_environment_adds_the_settings_and_keeps_the_rest():
    env = memory.allocator_environment({"PATH": "/bin", "MALLOC_ARENA_MAX": "8"})
    assert env["PATH"] == "/bin"
    assert env["MALLOC_ARENA_MAX"] == "1"
    assert env["MALLOC_MMAP_MAX_"] == "0"
    assert int(env["MALLOC_TRIM_THRESHOLD_"]) == 2 ** 31 - 1


def _in_child(code, env=None):
    out = subprocess.run([sys.executable, "-c", f"import sys; sys.path.insert(0, {PLUGINS!r}); " + code],
                         capture_output=True, text=True, env=env, check=True)
    return out.stdout.strip().splitlines()[-1]


def test_reuse_freed_memory_applies_once_on_glibc():
    # a fresh process: the settings are process-wide and permanent
    got = _in_child("from bare_earth.core import memory; print(memory.reuse_freed_memory(), "
                    "memory.reuse_freed_memory())")
    glibc = platform.system() == "Linux" and platform.libc_ver()[0] == "glibc"
    assert got == ("True True" if glibc else "False False")


def test_block_workers_reuse_freed_memory():
    pool = blocks.start_pool(1)
    try:
        assert pool.executor.submit(_applied).result(timeout=120) is (
            platform.system() == "Linux" and platform.libc_ver()[0] == "glibc")
    finally:
        pool.shutdown()


def _applied():
    return memory._applied


def test_window_budget_from_the_environment_or_half_the_memory_available(monkeypatch):
    """The budget of a run's windows: BARE_EARTH_MEMORY_MB when set (refused when not a positive
    number), else half of MemAvailable, else 2 GB when the memory available is unknown."""
    assert memory.window_budget({"BARE_EARTH_MEMORY_MB": "300"}) == 300 * 2 ** 20
    for bad in ("lots", "0", "-5", "inf", "1e400", "nan"):   # inf: a bare OverflowError before QA21
        with pytest.raises(ValueError, match="BARE_EARTH_MEMORY_MB"):
            memory.window_budget({"BARE_EARTH_MEMORY_MB": bad})
    assert memory.budget_mb({"BARE_EARTH_MEMORY_MB": " 800 "}) == 800.0 and memory.budget_mb({}) is None
    monkeypatch.setattr(memory, "available_memory", lambda: 8 << 30)
    assert memory.window_budget({}) == memory.window_budget({"BARE_EARTH_MEMORY_MB": " "}) == 4 << 30
    monkeypatch.setattr(memory, "available_memory", lambda: None)
    assert memory.window_budget({}) == memory.FALLBACK_BUDGET == 2 << 30


def test_available_memory_is_the_kernels_estimate():
    avail = memory.available_memory()
    assert avail is None or 0 < avail <= os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def test_window_budget_is_the_bound_less_what_the_run_holds(monkeypatch):
    """BARE_EARTH_MEMORY_MB went to the windows alone: what the run held beside them (the inputs read
    and rasterised before the blocks, the parameters' leftovers, GDAL's cache) came on top (a 36 Mcells
    run with 700 MB took 1.04 GB). The windows now get the bound less what the run holds; without the
    variable the budget is half the memory available, which already leaves out what the run holds."""
    mb = 1 << 20
    env = {memory.BUDGET_ENV: "700"}
    assert memory.window_budget(env) == 700 * mb
    assert memory.window_budget(env, held=200 * mb) == 500 * mb
    assert memory.window_budget(env, held=900 * mb) == 0
    monkeypatch.setattr(memory, "available_memory", lambda: 8000 * mb)
    assert memory.window_budget({}, held=200 * mb) == 4000 * mb


def test_held_by_run_measures_from_the_run_baseline():
    """Inside :func:`memory.run_baseline`: the resident memory above its start (100 MB held: counted; freed:
    given back and no longer counted); outside a run: 0. The outermost context's baseline stays."""
    import numpy as np
    mb = 1 << 20
    if memory.resident_bytes() is None:
        pytest.skip("no /proc/self/status here")
    assert memory.held_by_run() == 0
    with memory.run_baseline():
        a = np.ones(100 * mb, np.uint8)                 # touched: resident
        with memory.run_baseline():                     # nested: the outer baseline
            assert memory.held_by_run() >= 90 * mb
        del a
        assert memory.held_by_run() < 30 * mb
    assert memory.held_by_run() == 0


def test_budget_given_only_by_the_variable():
    assert memory.budget_given({memory.BUDGET_ENV: "700"}) and not memory.budget_given({memory.BUDGET_ENV: " "})
    assert not memory.budget_given({})


def test_proc_lines_read_by_one_reader(tmp_path, monkeypatch):
    """available_memory and resident_bytes read their /proc line through one reader: the ``Key: N kB``
    line in bytes, None for a missing file, a missing key or a line without a number (QA 17: two
    copies of the same loop)."""
    f = tmp_path / "meminfo"
    f.write_text("MemTotal:  100 kB\nMemAvailable:   2048 kB\nBroken: kB\nVmRSSX: 5 kB\nVmRSS: 7 kB\n")
    assert memory._proc_kb(str(f), "MemAvailable") == 2048 * 1024
    assert memory._proc_kb(str(f), "VmRSS") == 7 * 1024          # the whole key, not a longer one
    assert memory._proc_kb(str(f), "Broken") is None
    assert memory._proc_kb(str(f), "Missing") is None
    assert memory._proc_kb(str(tmp_path / "none"), "MemAvailable") is None
    seen = []
    monkeypatch.setattr(memory, "_proc_kb", lambda path, key: seen.append((path, key)) or 4096)
    assert memory.available_memory() == 4096 and memory.resident_bytes() == 4096
    assert seen == [("/proc/meminfo", "MemAvailable"), ("/proc/self/status", "VmRSS")]
