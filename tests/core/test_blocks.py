"""Block engine: windows cover the raster once, halos are clipped, run_windows runs each once."""
import threading
import time

import numpy as np
import pytest

from bare_earth.core import blocks
from bare_earth.core.common import Cancelled


@pytest.mark.parametrize("shape,block,halo", [
    ((3, 5), 4, 1), ((10, 10), 3, 2), ((7, 13), (2, 5), 3), ((1, 1), 4, 2), ((9, 4), 9, 0),
    ((6, 6), 1, 1), ((5, 8), 100, 4)])
@pytest.mark.parametrize("align", [1, 4, None])
def test_windows_cover_every_cell_once_and_halo_clipped(shape, block, halo, align):
    rows, cols = shape
    seen = np.zeros(shape, int)
    wins = list(blocks.iter_windows(shape, block, halo, align=align))
    a = blocks.alignment(halo) if align is None else align
    br, bc = (block, block) if isinstance(block, int) else block
    for core, outer in wins:
        r0, r1, c0, c1 = core
        assert 0 <= r0 < r1 <= rows and 0 <= c0 < c1 <= cols
        assert r1 - r0 <= br and c1 - c0 <= bc
        seen[r0:r1, c0:c1] += 1
        # grown by the halo, the upper-left corner moved out onto a multiple of the alignment
        assert outer == (max(0, (r0 - halo) // a * a), min(rows, r1 + halo),
                         max(0, (c0 - halo) // a * a), min(cols, c1 + halo))
        assert outer[0] % a == 0 and outer[2] % a == 0
        # crop cuts the core back out of an array read over the outer window
        grid = np.arange(rows * cols).reshape(shape)
        read = grid[outer[0]:outer[1], outer[2]:outer[3]]
        np.testing.assert_array_equal(read[blocks.crop(outer, core)], grid[r0:r1, c0:c1])
    np.testing.assert_array_equal(seen, 1)
    assert len(wins) == blocks.block_count(shape, block)


def test_iter_windows_exact_small_case():
    assert list(blocks.iter_windows((3, 5), block=4, halo=1, align=1)) == [
        ((0, 3, 0, 4), (0, 3, 0, 5)), ((0, 3, 4, 5), (0, 3, 3, 5))]
    assert list(blocks.iter_windows((3, 70), block=(3, 66), halo=1)) == [      # corner on 64
        ((0, 3, 0, 66), (0, 3, 0, 67)), ((0, 3, 66, 70), (0, 3, 64, 70))]
    assert list(blocks.iter_windows((4, 4), block=2, halo=1, align=1)) == [
        ((0, 2, 0, 2), (0, 3, 0, 3)), ((0, 2, 2, 4), (0, 3, 1, 4)),
        ((2, 4, 0, 2), (1, 4, 0, 3)), ((2, 4, 2, 4), (1, 4, 1, 4))]
    assert blocks.crop((1, 4, 1, 4), (2, 4, 2, 4)) == (slice(1, 3), slice(1, 3))


@pytest.mark.parametrize("shape,block,n", [((3, 5), 4, 2), ((10, 10), 3, 16), ((7, 13), (2, 5), 12),
                                           ((8, 8), 8, 1), ((8, 8), np.int64(4), 4)])
def test_block_count(shape, block, n):
    assert blocks.block_count(shape, block) == n


@pytest.mark.parametrize("workers", [1, 2])
def test_run_windows_calls_each_window_once_and_reaches_one(workers):
    wins = list(blocks.iter_windows((10, 11), 3, 1))
    calls, fractions = [], []
    lock = threading.Lock()

    def func(core, outer, block_progress):
        with lock:
            calls.append((core, outer))

    blocks.run_windows(func, iter(wins), workers=workers, progress=fractions.append)
    assert sorted(calls) == sorted(wins) and len(calls) == len(wins)
    assert len(fractions) == len(wins)
    assert fractions == sorted(fractions) and fractions[-1] == pytest.approx(1.0)
    assert all(0.0 < f <= 1.0 for f in fractions)


@pytest.mark.parametrize("workers", [1, 2])
def test_run_windows_error_in_func_propagates(workers):
    wins = list(blocks.iter_windows((6, 6), 2, 0))

    def func(core, outer, block_progress):
        if core == wins[3][0]:
            raise ZeroDivisionError("boom")

    with pytest.raises(ZeroDivisionError):
        blocks.run_windows(func, wins, workers=workers)


@pytest.mark.parametrize("workers", [1, 2])
def test_progress_raising_cancelled_stops(workers):
    wins = list(blocks.iter_windows((20, 20), 2, 1))       # 100 windows
    calls = []
    lock = threading.Lock()

    def func(core, outer, block_progress):
        with lock:
            calls.append(core)

    def progress(f):
        if f > 0:
            raise Cancelled()

    with pytest.raises(Cancelled):
        blocks.run_windows(func, wins, workers=workers, progress=progress)
    # stopped after the first report: at most the blocks already in flight ran
    assert 1 <= len(calls) <= 2 * workers + 1 < len(wins)


def test_workers_zero_means_one_per_core(monkeypatch):
    monkeypatch.setattr(blocks.os, "sched_getaffinity", lambda pid: {0, 1, 2}, raising=False)
    assert blocks.default_workers() == 3
    assert blocks.resolve_workers(0) == 3 and blocks.resolve_workers(None) == 3
    assert blocks.resolve_workers(2) == 2
    monkeypatch.setattr(blocks.os, "sched_getaffinity", lambda pid: set(range(64)), raising=False)
    assert blocks.default_workers() == blocks.MAX_AUTO_WORKERS


@pytest.mark.parametrize("shape", [(1, 1), (0, 5), (3, 700), (700, 3), (300, 512), (513, 256)])
@pytest.mark.parametrize("dtype", [np.float32, bool, np.uint8])
def test_banded_transpose_exact(shape, dtype):
    from bare_earth.core.common import transpose
    a = (np.arange(int(np.prod(shape))).reshape(shape) % 7 > 2).astype(dtype)
    t = transpose(a, rows=64)
    assert t.flags.c_contiguous and t.dtype == a.dtype and t.shape == shape[::-1]
    np.testing.assert_array_equal(t, a.T)
    # a strided view (as the scan's results) transposes the same
    b = np.zeros((shape[0], 2 * shape[1]), dtype)[:, ::2]
    b[...] = a
    np.testing.assert_array_equal(transpose(b, rows=64), a.T)


@pytest.mark.parametrize("mode", ["reflect", "constant"])
@pytest.mark.parametrize("dtypes", [(np.float32, np.float32), (np.float64, np.float64), (np.float32, np.float64)])
@pytest.mark.parametrize("band", [1, 4, 64])
def test_running_mean_down_is_scipys_bit_for_bit(monkeypatch, mode, dtypes, band):
    """The pass down the columns along whole rows reproduces SciPy's running sums exactly: any band of rows
    (the running sums carried across), reflected or zero edges, float32 or float64 in and out, columns as short
    as the window or shorter (SciPy itself), large offsets (rounding), NaN, a non-contiguous input."""
    from scipy import ndimage

    from bare_earth.core import common
    monkeypatch.setattr(common, "DOWN_BAND_ROWS", band)
    src, dst = dtypes
    rng = np.random.default_rng(11)
    for rows, cols in ((1, 5), (3, 4), (7, 9), (8, 3), (61, 47), (130, 20)):
        for a in ((rng.normal(size=(rows, cols)) * 40 + 1500).astype(src),
                  (rng.random((rows, cols)) < 0.4).astype(src) * np.arange(cols, dtype=src) * 0.37):
            a[rng.random(a.shape) < 0.02] = np.nan
            for view in (a, np.repeat(a, 2, axis=1)[:, ::2]):
                for size in (1, 3, 7, 13, 25):
                    got = common.running_mean_down(view, size, np.empty(a.shape, dst), mode=mode)
                    ref = ndimage.uniform_filter1d(a, size, axis=0, mode=mode, cval=0.0,
                                                   output=np.empty(a.shape, dst))
                    assert got.dtype == dst
                    np.testing.assert_array_equal(got.view(np.uint8), ref.view(np.uint8))   # every bit


@pytest.mark.parametrize("workers", [1, 2])
def test_run_windows_forwards_each_blocks_progress_scaled(workers):
    """Each block's own progress moves the whole (mean of the blocks), monotonic, ending at 1."""
    wins = list(blocks.iter_windows((8, 8), 4, 0))          # 4 windows
    fractions = []
    lock = threading.Lock()

    def func(core, outer, block_progress):
        for f in (0.25, 0.5, 0.75):
            block_progress(f)

    def progress(f):
        with lock:
            fractions.append(f)

    blocks.run_windows(func, wins, workers=workers, progress=progress)
    assert fractions == sorted(fractions) and fractions[-1] == pytest.approx(1.0)
    assert len(fractions) == 4 * 4                          # 3 steps + the end, per block
    if workers == 1:                                         # in order: exact quarters of quarters
        np.testing.assert_allclose(fractions[:4], [0.0625, 0.125, 0.1875, 0.25])


def test_cancel_stops_running_blocks_at_their_next_progress_call():
    """A block still running when the run is cancelled stops at its next progress call,
    instead of running to its end."""
    wins = list(blocks.iter_windows((4, 8), 4, 0))          # 2 windows, both start at once
    steps = {0: 0, 4: 0}
    started = threading.Barrier(2, timeout=5)

    def func(core, outer, block_progress):
        started.wait()
        for _ in range(200):
            steps[core[2]] += 1
            if core[2] == 0 and steps[0] == 3:
                raise Cancelled()                            # block 0 is cancelled here
            block_progress(steps[core[2]] / 400)
            time.sleep(0.002)

    with pytest.raises(Cancelled):
        blocks.run_windows(func, wins, workers=2)
    assert steps[4] < 150         # the other block stopped at a progress call soon after, not at 200


def test_block_progress_repeats_the_callbacks_error():
    calls = []

    def progress(f):
        calls.append(f)
        raise Cancelled()

    bp = blocks.BlockProgress(progress, 2)
    with pytest.raises(Cancelled):
        bp.report(0, 0.5)
    with pytest.raises(Cancelled):
        bp.report(1, 0.1)
    assert calls == [0.25]                                  # the callback is not asked again


def test_run_sharing_results_in_order_each_task_once():
    from concurrent.futures import ThreadPoolExecutor
    calls = []

    def task(i):
        calls.append(i)
        return i * i
    tasks = [lambda i=i: task(i) for i in range(7)]
    assert blocks.run_sharing(tasks) == [i * i for i in range(7)]
    with ThreadPoolExecutor(max_workers=2) as pool:
        calls.clear()
        assert blocks.run_sharing(tasks, pool) == [i * i for i in range(7)]
        assert sorted(calls) == list(range(7))
        with pytest.raises(ZeroDivisionError):
            blocks.run_sharing([lambda: 1, lambda: 1 / 0, lambda: 2], pool)


def test_run_sharing_an_idle_thread_takes_the_first_tasks():
    """The caller runs the tasks from the last one back; a pool thread left idle takes the first: the last
    task can only end once the first has begun on another thread."""
    from concurrent.futures import ThreadPoolExecutor
    first_began = threading.Event()
    where = {}

    def first():
        where["first"] = threading.get_ident()
        first_began.set()
        return "first"

    def last():
        where["last"] = threading.get_ident()
        return first_began.wait(30)
    with ThreadPoolExecutor(max_workers=1) as pool:
        assert blocks.run_sharing([first, lambda: "middle", last], pool) == ["first", "middle", True]
    assert where["first"] != where["last"] == threading.get_ident()


def test_run_sharing_from_a_pool_thread_while_the_other_is_busy_never_waits_for_a_queued_task():
    """A member running on one of the vote's threads shares its steps with the pool while the other thread
    is busy until it returns: it runs them all itself (no deadlock)."""
    from concurrent.futures import ThreadPoolExecutor
    done = threading.Event()
    with ThreadPoolExecutor(max_workers=2) as pool:
        busy = pool.submit(done.wait, 30)

        def member():
            out = blocks.run_sharing([lambda i=i: (i, threading.get_ident()) for i in range(4)], pool)
            done.set()
            return out
        out = pool.submit(member).result(timeout=30)
        assert busy.result() is True
    assert [i for i, _ in out] == [0, 1, 2, 3] and len({t for _, t in out}) == 1


def test_touching_is_the_3x3_binary_dilation():
    """common.touching (fill's edge test and morphology's outline cells use it) equals the
    3 x 3 binary dilation exactly, edges and empty arrays included."""
    from scipy import ndimage

    from bare_earth.core.common import touching
    rng = np.random.default_rng(3)
    for shape in ((1, 1), (1, 7), (6, 1), (9, 13)):
        a = rng.random(shape) < 0.15
        assert np.array_equal(touching(a), ndimage.binary_dilation(a, np.ones((3, 3), bool)))
    a = np.zeros((4, 5), bool)
    a[0, 4] = True
    expect = np.zeros((4, 5), bool)
    expect[0:2, 3:5] = True
    assert np.array_equal(touching(a), expect)
    assert touching(np.zeros((0, 3), bool)).shape == (0, 3)


def test_dilate_box_is_the_box_binary_dilation(monkeypatch):
    """common.dilate_box (RASCOR's joining of a terrain line's pieces and of a crest's, morphology's cut slopes'
    reach) equals ``ndimage.binary_dilation`` by the box and ``ndimage.maximum_filter`` of the mask exactly: every
    half-size from none to wider than the array, edges and empty arrays included."""
    from scipy import ndimage

    from bare_earth.core import common
    from bare_earth.core.common import dilate_box
    rng = np.random.default_rng(4)
    for shape in ((1, 1), (1, 7), (6, 1), (9, 13), (40, 33)):
        a = rng.random(shape) < 0.08
        for ry in (0, 1, 2, 3, 5, 12):
            for rx in (0, 1, 2, 4, 7, 20):
                want = ndimage.binary_dilation(a, np.ones((2 * ry + 1, 2 * rx + 1), bool))
                assert np.array_equal(dilate_box(a, ry, rx), want), (shape, ry, rx)
                # in bands of one row and more (each read with the windows' reach around it): the same cells
                monkeypatch.setattr(common, "DILATE_BAND_CELLS", 1)
                assert np.array_equal(dilate_box(a, ry, rx), want), (shape, ry, rx)
                monkeypatch.setattr(common, "DILATE_BAND_CELLS", 1 << 18)
                # and SciPy's running maxima of the mask as uint8 (what morphology's and RASCOR's joins used)
                runs = ndimage.maximum_filter(a.view(np.uint8), size=(2 * ry + 1, 2 * rx + 1), mode="constant", cval=0)
                assert np.array_equal(runs.view(bool), want), (shape, ry, rx)
    a = np.zeros((3, 4), bool)
    out = dilate_box(a, 0, 0)
    assert out is not a and not out.any()
    assert dilate_box(np.zeros((0, 3), bool), 2, 2).shape == (0, 3)


@pytest.mark.parametrize("share, runs", [(1.0, 1.0), (0.25, 0.01), (0.02, 0.5)])
def test_label8_by_runs_equals_ndimage_label(monkeypatch, share, runs):
    """common.label8 (the sparse labellings of geodesic's outliers and fine steps, RASCOR's ramps and
    terrain steps) gives ndimage.label's 8-connected array, numbering and count exactly: masks of every
    density (runs wrapping from a row's end to the next row's start, diagonal joins, single rows and
    columns, empty), by runs up to the shares of cells and runs and by ndimage.label above them."""
    from scipy import ndimage

    from bare_earth.core import common
    monkeypatch.setattr(common, "LABEL_RUNS_SHARE", share)
    monkeypatch.setattr(common, "LABEL_RUNS_RUNS", runs)
    s8 = np.ones((3, 3), bool)
    rng = np.random.default_rng(7)
    masks = [rng.random((h, w)) < p for h, w in ((1, 1), (1, 9), (8, 1), (13, 17), (40, 31), (64, 64))
             for p in (0.0, 0.01, 0.1, 0.3, 0.6, 0.95)]
    wrap = np.zeros((5, 6), bool)
    wrap[1, 5] = wrap[2, 0] = True                        # consecutive in memory, not neighbours
    diag = np.eye(6, dtype=bool)[::-1] | np.eye(6, dtype=bool)   # an X: one part through its diagonals
    u = np.zeros((6, 7), bool)
    u[1:5, 1] = u[1:5, 5] = u[4, 1:6] = True              # a U: joined below, first seen as two runs
    u[0, 3] = True                                        # a later part first seen before the U's join
    for m in masks + [wrap, diag, u, np.zeros((0, 4), bool), np.zeros((3, 0), bool)]:
        lab, n = common.label8(m)
        ref, ref_n = ndimage.label(m, s8)
        assert n == ref_n and lab.dtype == ref.dtype and np.array_equal(lab, ref)
    assert common.label8(wrap)[1] == 2 and common.label8(diag)[1] == 1 and common.label8(u)[1] == 2


def test_cells_of_is_nonzero():
    """common.cells_of (dtm_refine's smoothness and line tests, morphology's region boxes, RASCOR's ramps)
    gives np.nonzero's rows and columns exactly, in the same order and dtype."""
    from bare_earth.core.common import cells_of
    rng = np.random.default_rng(5)
    for shape, p in (((1, 1), 1.0), ((1, 9), 0.5), ((7, 1), 0.5), ((33, 47), 0.1), ((20, 20), 0.0)):
        m = rng.random(shape) < p
        for got, ref in zip(cells_of(m), np.nonzero(m)):
            assert got.dtype == ref.dtype and np.array_equal(got, ref)


def test_edge_mirrored_extents_exact():
    """common.edge_mirrored_extents (dtm's raised regions and the curvature filter's runs cut
    by the edge): each box's extent along rows and columns, doubled for each side of that axis
    the raster's edge cuts (tripled when cut on both)."""
    from bare_earth.core.common import edge_mirrored_extents
    boxes = [(slice(0, 4), slice(2, 5)), (slice(1, 3), slice(0, 10)), (slice(3, 10), slice(9, 10)),
             (slice(2, 5), slice(3, 4))]
    got = edge_mirrored_extents(boxes, (10, 10))
    np.testing.assert_array_equal(got, [[8, 3], [2, 30], [14, 2], [3, 1]])
    assert got.shape == (4, 2) and edge_mirrored_extents([], (5, 5)).shape == (0, 2)



def test_walls_runs_mirrors_a_wall_only_at_the_sides_it_is_cut_by():
    """common.walls_runs (the raised regions of dtm, and through estimate.raised_region_width those of
    the geodesic and morphological filters): the outline's box along each axis, mirrored at a side only
    when both the outline and the ground at the wall's foot reach it; the larger span."""
    from bare_earth.core.common import walls_runs

    def run(outline, foot, shape=(10, 12)):
        o, f = np.array(outline, np.intp).reshape(-1, 2), np.array(foot, np.intp).reshape(-1, 2)
        return int(walls_runs(o[:, 0], o[:, 1], 1, 1, shape, f[:, 0], f[:, 1], 1)[1])

    # a wall cutting off the top-left corner: rows 0-5 mirrored at the top, columns 0-4 at the left
    assert run([(0, 4), (3, 2), (5, 0)], [(0, 2), (4, 0)]) == 12
    # the same wall ending in the corner: the roof's own corner reaches the last row, its foot does not
    assert run([(0, 4), (5, 2), (9, 0)], [(0, 2), (8, 0)]) == 20           # not 30
    # its foot in the last row too: a wall running across the raster, top to bottom
    assert run([(0, 4), (5, 2), (9, 0)], [(0, 2), (9, 0)]) == 30
    assert run([(2, 3), (6, 8)], [(1, 2), (7, 9)]) == 6                      # inside: not mirrored
    assert run([(0, 3), (6, 8)], []) == 7                                    # no ground seen beyond
    assert run([], [(0, 0)]) == 0
    assert run([(3, 0), (3, 11)], [(2, 0), (2, 11)]) == 36                  # across, left to right

_UNGUARDED_SCRIPT = """
import sys
sys.path.insert(0, {plugins!r})
from bare_earth.core import grid, pipeline
from bare_earth.core.synthetic import make_scene
with open({ran!r}, "a") as fh:
    fh.write("ran\\n")
{body}
print("finished")
"""


def run_unguarded_script(tmp_path, body):
    """Run ``body`` as a script's top-level code, without an ``if __name__ == "__main__":`` guard;
    returns (returncode, output, times the script ran)."""
    import os
    import subprocess
    import sys
    plugins = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(blocks.__file__))))
    ran = tmp_path / "ran.txt"
    script = tmp_path / "script.py"
    script.write_text(_UNGUARDED_SCRIPT.format(plugins=plugins, ran=str(ran), body=body))
    try:
        res = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=240,
                             cwd=str(tmp_path))
        code, out = res.returncode, res.stdout + res.stderr
    except subprocess.TimeoutExpired as exc:     # before the fix the survey's workers ran it in a loop
        code, out = None, f"no end after {exc.timeout} s"
    return code, out, ran.read_text().count("ran") if ran.exists() else 0


def test_worker_processes_do_not_run_an_unguarded_script_again(tmp_path):
    """A script calling the filters with processes > 1 at its top level (PyQGIS scripts often have
    no __main__ guard): every spawned worker ran it again from its first line (rewriting its input
    DSM) and died on multiprocessing's bootstrapping error, a BrokenProcessPool traceback. Now
    the script runs once and the run finishes."""
    body = (f"sc = make_scene('flat', shape=(200, 200), seed=1)\n"
            f"p = grid.write_array({str(tmp_path / 'dsm.tif')!r}, sc.dsm, sc.geotransform, sc.epsg)\n"
            f"pipeline.run_file('slopeprofile', p, {{'mask': {str(tmp_path / 'm.tif')!r}}}, block=64, processes=2,\n"
            f"                  params={{'max_object_size_m': 8.0}})")
    code, out, runs = run_unguarded_script(tmp_path, body)
    assert code == 0 and "finished" in out and runs == 1, (runs, out[-2000:])
    assert (tmp_path / "m.tif").exists()


def test_pad_constant_is_np_pad():
    """common.pad_constant (geodesic's hanging windows, curvature's framed profiles) equals ``np.pad`` with a
    constant: every side, rows and columns apart, no padding, float, int and bool."""
    from bare_earth.core.common import pad_constant
    rng = np.random.default_rng(9)
    for a in ((rng.random((5, 7)) * 10).astype(np.float32), rng.integers(0, 9, (1, 4)), rng.random((3, 1)) > 0.5):
        for rows, cols in ((0, 0), (1, 0), (0, 2), (3, 1), (2, 5)):
            fill = a.dtype.type(1) if a.dtype == bool else -7
            got = pad_constant(a, rows, cols, fill)
            want = np.pad(a, ((rows, rows), (cols, cols)), constant_values=fill)
            assert got.dtype == a.dtype and np.array_equal(got, want)


def test_label_boxes_exact():
    """common.label_boxes: each label's bounding box (end exclusive) from its cells, as ``ndimage.find_objects``
    gives it; a label without cells gets the empty box (shape, 0)."""
    from scipy import ndimage

    from bare_earth.core.common import label_boxes
    rng = np.random.default_rng(3)
    lab = rng.integers(0, 5, (11, 8))
    lab[lab == 3] = 0                                       # label 3 has no cells
    r, c = np.nonzero(lab)
    ids = lab[r, c] - 1
    r0, r1, c0, c1 = label_boxes(ids, r, c, 4, lab.shape)
    for k, sl in enumerate(ndimage.find_objects(lab, 4)):
        if sl is None:
            assert (r0[k], r1[k], c0[k], c1[k]) == (11, 0, 8, 0)
        else:
            assert (r0[k], r1[k], c0[k], c1[k]) == (sl[0].start, sl[0].stop, sl[1].start, sl[1].stop)
