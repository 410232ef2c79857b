"""The allocator of processes that only filter (core/memory.py)."""
import os
import platform
import subprocess
import sys

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
