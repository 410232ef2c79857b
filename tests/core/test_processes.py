"""run_file with worker processes: same mask as one pass, bounded, cancellable."""
import numpy as np
import pytest
from osgeo import gdal

from bare_earth.core import Cancelled
from bare_earth.core.grid import write_array
from bare_earth.core.pipeline import run_file
from bare_earth.core.synthetic import make_scene


@pytest.fixture
def dsm(tmp_path):
    sc = make_scene("city", shape=(300, 260), seed=4)
    return write_array(tmp_path / "dsm.tif", sc.dsm, sc.geotransform, sc.epsg)


def _read(p):
    ds = gdal.Open(str(p))
    return ds.GetRasterBand(1).ReadAsArray()


def test_processes_give_the_one_pass_mask(dsm, tmp_path):
    one = run_file("slopeprofile", dsm, {"mask": tmp_path / "m1.tif", "dtm": tmp_path / "d1.tif"})
    par = run_file("slopeprofile", dsm, {"mask": tmp_path / "m2.tif", "dtm": tmp_path / "d2.tif"},
                   processes=2, block=100)
    assert one["blocks"] == 1 and par["blocks"] > 2
    np.testing.assert_array_equal(_read(tmp_path / "m1.tif"), _read(tmp_path / "m2.tif"))
    d1, d2 = _read(tmp_path / "d1.tif"), _read(tmp_path / "d2.tif")
    ground = _read(tmp_path / "m1.tif") == 0
    np.testing.assert_array_equal(d1[ground], d2[ground])           # ground cells exact in both
    assert np.abs(d1 - d2).max() < 1.0                               # filled cells: nearly the same
    assert par["classes_percent"] == one["classes_percent"]


def test_a_worker_killed_mid_run_refused_saying_what_to_change(dsm, tmp_path):
    """A worker process killed while blocks run (the system's out-of-memory killer, PROCESSES > 1 on a large
    raster) ended the run with the pool's traceback, "BrokenProcessPool: A child process terminated
    abruptly"; now a ValueError says what happened and the settings that use less memory, and nothing is written."""
    import multiprocessing
    import os
    import signal
    killed = []

    def progress(f):
        children = multiprocessing.active_children()
        if children and not killed:       # the pool's workers are running blocks
            os.kill(children[0].pid, signal.SIGKILL)
            killed.append(children[0].pid)

    with pytest.raises(ValueError, match=r"a worker process ended abruptly while filtering the blocks .*nothing was "
                                         r"written\. Run again with fewer worker processes \(PROCESSES\), smaller "
                                         r"blocks \(BLOCK_SIZE\), or threads"):
        run_file("slopeprofile", dsm, {"mask": tmp_path / "m.tif", "dtm": tmp_path / "d.tif"},
                 processes=2, block=64, progress=progress)
    assert killed
    assert not (tmp_path / "m.tif").exists() and not (tmp_path / "d.tif").exists()
    assert not list(tmp_path.glob("*.partial*"))


def test_processes_cancel_leaves_nothing(dsm, tmp_path):
    calls = []

    def progress(f):
        calls.append(f)
        if f > 0.2:
            raise Cancelled()

    with pytest.raises(Cancelled):
        run_file("slopeprofile", dsm, {"mask": tmp_path / "m.tif", "dtm": tmp_path / "d.tif"},
                 processes=2, block=64, progress=progress)
    assert not (tmp_path / "m.tif").exists() and not (tmp_path / "d.tif").exists()
    assert not list(tmp_path.glob("*.partial*"))


@pytest.fixture
def planted_python(tmp_path, monkeypatch):
    """A ``python3`` first on PATH that must never run (it leaves a marker), and a
    ``sys.executable`` that is not a Python (as inside QGIS: the QGIS binary)."""
    import os
    import sys
    bindir = tmp_path / "bin"
    bindir.mkdir()
    marker = tmp_path / "planted-ran"
    for name in ("python3", "python"):
        p = bindir / name
        p.write_text(f"#!/bin/sh\ntouch {marker}\nexit 1\n")
        p.chmod(0o755)
    monkeypatch.setenv("PATH", f"{bindir}{os.pathsep}{os.environ.get('PATH', '')}")
    fake_qgis = bindir / "qgis"
    fake_qgis.write_text("#!/bin/sh\nexit 1\n")
    fake_qgis.chmod(0o755)
    monkeypatch.setattr(sys, "executable", str(fake_qgis))
    return marker


def test_worker_interpreter_is_ours_not_path_python3(planted_python):
    import os
    import sys

    from bare_earth.core.blocks import python_interpreter
    exe = python_interpreter()
    assert os.path.dirname(exe) != os.path.dirname(sys.executable)          # not the planted bin dir
    assert os.path.basename(exe).startswith(f"python{sys.version_info[0]}")
    assert os.path.realpath(exe).startswith(os.path.realpath(sys.base_prefix))


def test_embedded_sys_executable_from_path_is_not_trusted(planted_python, monkeypatch):
    """An embedded interpreter (qgis_process) may set sys.executable to the ``python3`` it
    found first on PATH: that program is not the one running us, so it is not used."""
    import os
    import sys

    from bare_earth.core.blocks import python_interpreter
    planted = os.path.join(os.path.dirname(sys.executable), "python3")
    monkeypatch.setattr(sys, "executable", planted)
    exe = python_interpreter()
    assert os.path.realpath(exe) != os.path.realpath(planted)
    assert os.path.realpath(exe).startswith(os.path.realpath(sys.base_prefix))


def test_processes_run_with_planted_python3_first_on_path(dsm, tmp_path, planted_python):
    par = run_file("slopeprofile", dsm, {"mask": tmp_path / "m.tif"}, processes=2, block=100)
    assert par["blocks"] > 2
    assert not planted_python.exists(), "the python3 first on PATH was started"


def test_processes_forward_the_blocks_own_progress(dsm, tmp_path):
    fractions = []
    par = run_file("slopeprofile", dsm, {"mask": tmp_path / "m.tif", "dtm": tmp_path / "d.tif"},
                   processes=2, block=100, progress=fractions.append)
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    # more reports than blocks: the workers' progress (filter and fill) reaches the bar
    assert len(fractions) > par["blocks"] + 3


_POOL_OWNER = r"""
import sys, time
sys.path.insert(0, sys.argv[1])
from bare_earth.core import blocks
pool = blocks.start_pool(2)
for f in [pool.executor.submit(abs, -1) for _ in range(2)]:
    f.result()
print(" ".join(str(p) for p in pool.executor._processes), flush=True)
time.sleep(600)
"""


def test_workers_end_when_their_run_is_killed():
    """A run with PROCESSES > 1 killed outright (kill -9, QGIS crashing) left its worker processes waiting
    for blocks for ever (each holds both ends of the pool's queues, so none sees the parent go), 96 MB each
    when idle, a block's windows when busy. They now end within seconds of their parent."""
    import os
    import signal
    import subprocess
    import sys
    import time

    import bare_earth
    plugins = os.path.dirname(os.path.dirname(os.path.abspath(bare_earth.__file__)))
    owner = subprocess.Popen([sys.executable, "-c", _POOL_OWNER, plugins], stdout=subprocess.PIPE, text=True)
    try:
        workers = [int(p) for p in owner.stdout.readline().split()]
    finally:
        os.kill(owner.pid, signal.SIGKILL)
        owner.wait()
    assert len(workers) == 2

    def alive(pid):
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return False
        with open(f"/proc/{pid}/stat") as fh:              # an exited child of init not yet reaped
            return fh.read().split(")")[-1].split()[0] != "Z"
    deadline = time.time() + 30
    while any(alive(p) for p in workers) and time.time() < deadline:
        time.sleep(0.2)
    left = [p for p in workers if alive(p)]
    for p in left:                                        # do not leave them behind when the test fails
        os.kill(p, signal.SIGKILL)
    assert left == []
