"""Progress and cancel of a whole file run (issue 15): every stage of ``pipeline.run_file``
reports (reading and deriving the parameters, the blocks, writing), for every method, and a
cancel raised while the parameters are derived or the outputs written stops the run there
and leaves no file. Counts of progress calls, never timings."""
import os

import numpy as np
import pytest

from bare_earth.core import estimate, grid, methods, pipeline, synthetic
from bare_earth.core.common import Cancelled

METHODS = sorted(methods.available_methods())
GT = (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0)
#: The progress range of the parameters' derivation (after reading the window they come from).
DERIVE = (pipeline.READ_SHARE * pipeline.RESOLVED, pipeline.RESOLVED)
#: The progress range of writing the outputs (after the blocks).
WRITE = (0.97, 1.0)


@pytest.fixture(scope="module")
def dsm(tmp_path_factory):
    z = synthetic.make_scene("city", shape=(300, 300), cell_size=1.0, seed=5).dsm
    return grid.write_array(tmp_path_factory.mktemp("dsm") / "city.tif", z, GT, 32632)


def _outputs(folder):
    return {"dtm": str(folder / "dtm.tif"), "mask": str(folder / "mask.tif")}


def _inside(calls, bounds):
    return [f for f in calls if bounds[0] < f < bounds[1]]


@pytest.mark.parametrize("method", METHODS)
def test_file_run_reports_from_inside_every_stage(method, dsm, tmp_path):
    """The method's estimates report while the parameters are derived (not only their end),
    the blocks report, and so does the writing of the outputs; the bar never goes back."""
    calls = []
    pipeline.run_file(method, dsm, _outputs(tmp_path), progress=calls.append, workers=1)
    assert calls == sorted(calls) and calls[-1] == 1.0
    assert len(set(_inside(calls, DERIVE))) >= 3, calls[:20]
    assert len(_inside(calls, (pipeline.RESOLVED, WRITE[0]))) >= 10
    assert _inside(calls, WRITE)


@pytest.mark.parametrize("method", METHODS)
def test_cancel_while_parameters_are_derived_stops_there_and_leaves_nothing(method, dsm, tmp_path):
    calls = []

    def stop(f):
        calls.append(f)
        if len(_inside(calls, DERIVE)) == 2:      # the second report from inside the estimates
            raise Cancelled()

    out = tmp_path / "out"
    out.mkdir()
    with pytest.raises(Cancelled):
        pipeline.run_file(method, dsm, _outputs(out), progress=stop, workers=1)
    assert len(_inside(calls, DERIVE)) == 2 and DERIVE[0] < calls[-1] < DERIVE[1]   # no call after the raise
    assert os.listdir(out) == []


@pytest.mark.parametrize("cog", [False, True])
def test_cancel_while_the_outputs_are_written_leaves_nothing(dsm, tmp_path, cog):
    """Writing reports (the files flushed, a cloud-optimised copy made) and a cancel there
    moves no output into place; no work file is left."""
    calls = []

    def stop(f):
        calls.append(f)
        if len(_inside(calls, WRITE)) == 2:
            raise Cancelled()

    with grid.write_options(cog=cog), pytest.raises(Cancelled):
        pipeline.run_file("morphological", dsm, _outputs(tmp_path), progress=stop, workers=1)
    assert WRITE[0] < calls[-1] < WRITE[1]
    assert os.listdir(tmp_path) == []


def test_block_writing_reports_between_the_blocks(dsm, tmp_path):
    """In a run of several blocks, each block's writing (its arrays, then their compression)
    reports: the bar moves between the end of a block's filter and the next block."""
    calls = []
    pipeline.run_file("morphological", dsm, _outputs(tmp_path), block=128, progress=calls.append, workers=1)
    per_block = (WRITE[0] - pipeline.RESOLVED) / 9               # 9 blocks of 128 x 128 on 300 x 300
    fractions = [(f - pipeline.RESOLVED) / per_block % 1.0 for f in _inside(calls, (pipeline.RESOLVED, WRITE[0]))]
    writing = [x for x in fractions if pipeline.COMPUTE_SHARE < x < 1.0 - 1e-9]
    assert len(writing) >= 9


def test_resolve_without_progress_keyword_still_runs(dsm, tmp_path):
    """A method whose resolve takes no ``progress`` is called without one (and the pipeline
    reports the derivation's end itself)."""
    base = methods.get_method("morphological")

    def resolve(z, cell_size, **params):
        return base.resolve(z, cell_size, **params)

    meth = methods.Method(name="plain", run=base.run, resolve=resolve, halo=base.halo, params=base.params)
    calls = []
    pipeline.run_file(meth, dsm, _outputs(tmp_path), progress=calls.append, workers=1)
    assert pipeline.RESOLVED in calls and calls[-1] == 1.0


@pytest.mark.parametrize("name,call", [
    ("noise_ground_level", lambda z, p: estimate.noise_ground_level(z, (1.0, 1.0), progress=p)["sigma"]),
    ("below_surroundings", lambda z, p: estimate.below_surroundings(z, (1.0, 1.0), 0.5, progress=p)),
    ("below_surroundings candidates", lambda z, p: estimate.below_surroundings(
        z, (1.0, 1.0), 0.5, candidates=z < np.nanpercentile(z, 5), progress=p)),
    ("ground_spread", lambda z, p: estimate.ground_spread([z[None, :100, :100], z[None, 100:200, :100]],
                                                          progress=p)),
])
def test_long_estimates_report_and_stop_on_cancel(name, call):
    """The estimates the parameters come from report several times, end at 1, give the same
    answer with a callback, and stop at the call that raises."""
    z = synthetic.make_scene("city", shape=(300, 300), cell_size=1.0, seed=5).dsm
    calls = []
    with_progress = call(z, calls.append)
    np.testing.assert_array_equal(with_progress, call(z, None))
    assert len(calls) >= 2 and calls == sorted(calls) and calls[-1] == 1.0
    seen = []

    def stop(f):
        seen.append(f)
        raise Cancelled()
    with pytest.raises(Cancelled):
        call(z, stop)
    assert len(seen) == 1


def _spy_stages(monkeypatch, module, names, events):
    """Replace each named function of ``module`` by one that logs its name in ``events`` (where the
    stage begins) and then runs it."""
    for name in names:
        f = getattr(module, name)

        def spy(*args, _f=f, _name=name, **kwargs):
            events.append(_name)
            return _f(*args, **kwargs)
        monkeypatch.setattr(module, name, spy)


def _city():
    return synthetic.make_scene("city", shape=(200, 200), cell_size=1.0, seed=5).dsm


def _run_with_events(method, z, events):
    """The method's mask without a callback, then with ``events.append`` as its callback (``events`` cleared
    first): the two masks must be equal."""
    meth = methods.get_method(method)
    params = pipeline.resolve_params(meth, z, 1.0)
    base = meth.run(z, (1.0, 1.0), **params).mask
    events.clear()
    res = meth.run(z, (1.0, 1.0), progress=events.append, **params)
    np.testing.assert_array_equal(res.mask, base)


def _assert_reports_after(events, named, skip=lambda a, b: False):
    """A float report after each named stage (before the next one, or the end), and the fractions rising."""
    for i, j in zip(named, named[1:] + [len(events)]):
        if not skip(events[i], events[j] if j < len(events) else None):
            assert any(isinstance(e, float) for e in events[i + 1:j]), (events[i], events[i + 1:j + 1])
    fractions = [e for e in events if isinstance(e, float)]
    assert fractions == sorted(fractions)


def _named(events):
    return [i for i, e in enumerate(events) if isinstance(e, str)]


def test_dtm_reports_between_its_stages_after_the_vote(monkeypatch):
    """After its members voted, bareearth:dtm ran the continuations, the banks and the refinement
    (seconds on 16 Mcells) without a report: the bar stood still and a cancel waited. Every one of
    these stages is now followed by a report, the refinement's own sub-stages too, the fractions
    rising; the result is the one without a callback."""
    from bare_earth.core import dtm, dtm_refine
    events = []
    _spy_stages(monkeypatch, dtm, ("continue_ground", "continue_lines", "continue_banks"), events)
    _spy_stages(monkeypatch, dtm_refine,        # then refine_ground's own
                ("find_bracketed", "find_step_tops", "find_edge_spikes", "find_raised_band"), events)
    _run_with_events("dtm", _city(), events)
    after = events[min(_named(events)):]
    assert len(_named(after)) >= 6
    _assert_reports_after(after, _named(after))
    _assert_reports_after(events, [])


def test_dtm_derivation_reports_after_its_members(monkeypatch):
    """After its members' parameters were derived, bareearth:dtm's derivation measured the repeated heights
    and the raised regions' span on the whole raster without a report (the bar stood still before the vote
    began); each of those estimates is now followed by one, the fractions rising, the parameters unchanged.
    Since the twenty-eighth session the span is looked for beside the members' derivation (``early_span``), whose
    reports go on meanwhile; where its scales were not known early, the search runs after the members and
    reports after each of its scales (QA 20)."""
    from bare_earth.core import dtm
    events = []
    stages = ("repeated_height_share", "raised_region_grid", "raised_region_span")
    _spy_stages(monkeypatch, dtm, stages, events)
    z = _city()
    base = pipeline.resolve_params("dtm", z, 1.0)
    events.clear()
    assert pipeline.resolve_params("dtm", z, 1.0, progress=events.append) == base
    named = _named(events)
    assert set(stages) <= {events[i] for i in named}
    _assert_reports_after(events, named[-1:])           # a report after the derivation's last estimate
    # the search not started early (its scales unknown before the members end): after the members, reporting
    monkeypatch.setattr(dtm, "early_span", lambda *a, **k: (None, None))
    events.clear()
    assert pipeline.resolve_params("dtm", z, 1.0, progress=events.append) == base
    named = _named(events)[-3:]     # the vote's own, after the members
    assert events[named[-1]] == "raised_region_span", [events[i] for i in named]
    _assert_reports_after(events, named)
    # QA 20: and the span's search reports after each of its scales (the longest gap of dtm's derivation)
    assert len([e for e in events[named[-1] + 1:] if isinstance(e, float) and e < 1.0]) >= 2, events[named[-1]:]


def test_slopeprofile_reports_between_its_stages_after_the_axes(monkeypatch):
    """QA 19: after combining its axes, slopeprofile ran the walled regions, the runs joined to the terrain,
    the platforms, the ramps and the unwalled levels without a report: the longest gap of its run on 16 Mcells
    (17 s under load, from 78 to 80 % of the filter); a cancel waited as long. Each of these stages is now
    followed by a report (the two ramps' scans by one), the fractions rising; the mask is the one without a
    callback."""
    from bare_earth.core import slope_profile
    events = []
    _spy_stages(monkeypatch, slope_profile,
                ("_walled_regions", "_joined_to_terrain", "_platforms", "_ramps", "_level_unwalled"), events)
    _run_with_events("slopeprofile", _city(), events)
    named = _named(events)
    assert [events[i] for i in named] == ["_walled_regions", "_joined_to_terrain", "_platforms", "_platforms",
                                          "_ramps", "_ramps", "_joined_to_terrain", "_level_unwalled"]
    _assert_reports_after(events, named, skip=lambda a, b: a == b == "_ramps")


def test_geodesic_dilation_step_reports_after_its_fine_regions(monkeypatch):
    """QA 19: the tail of a geodesic dilation step (the walled pieces, the fine regions of blocks too wide,
    the fine outline) ran without a report after its 0.95: inside bareearth:dtm on 16 Mcells, its members
    sharing the cores, the longest gap of the run (14 s under load); a cancel waited as long. A report now
    follows each of them, the fractions rising; the mask is the one without a callback."""
    from bare_earth.core.geodesic import dilation
    events = []
    _spy_stages(monkeypatch, dilation, ("_walled_pieces", "_fine_regions", "_fine_outline"), events)
    _run_with_events("geodesic", _city(), events)
    named = _named(events)
    assert "_fine_regions" in [events[i] for i in named]
    _assert_reports_after(events, named)


def test_curvature_derivation_reports_after_its_slope_and_object_size(monkeypatch):
    """QA 19: after the noise, curvature's derivation measured the steep terrain slope and the largest object
    on the window without a report: the longest gap of its run on 16 Mcells (12.2 s under load 11; a cancel
    waited as long). Each is now followed by a report, the fractions rising; the parameters unchanged."""
    from bare_earth.core.curvature import method as curvature
    events = []
    _spy_stages(monkeypatch, curvature, ("steep_terrain_slope", "object_size"), events)
    z = _city()
    base = pipeline.resolve_params("curvature", z, 1.0)
    events.clear()
    assert pipeline.resolve_params("curvature", z, 1.0, progress=events.append) == base
    named = _named(events)
    assert [events[i] for i in named] == ["steep_terrain_slope", "object_size"]
    _assert_reports_after(events, named)


def test_curvature_object_size_reports_between_its_estimates(monkeypatch):
    """QA 19: curvature's largest object (object_size: the block minima, the raised regions on them and on their
    opening, the walled span) took 20 s on 16 Mcells under load without a report. A report now follows each
    estimate; the size unchanged."""
    from bare_earth.core.curvature import method as curvature
    events = []
    _spy_stages(monkeypatch, curvature, ("raised_region_grid", "raised_region_window", "square_opening"), events)
    z = _city()
    base = curvature.object_size(z, (1.0, 1.0), 2.5)
    events.clear()
    assert curvature.object_size(z, (1.0, 1.0), 2.5, progress=events.append) == base
    named = _named(events)
    assert [events[i] for i in named] == ["raised_region_grid", "raised_region_window", "square_opening",
                                          "raised_region_window"]
    _assert_reports_after(events, named)
    assert events[-1] != events[named[-1]]


def test_rascor_reports_between_its_spared_ground_stages(monkeypatch):
    """QA 19: after its last surface fit, RASCOR gave back continuing ground, ramps and slope breaks without a
    report (with the fit's tail, 7.6 s on 16 Mcells under load; a cancel there waited 9 s). A report now
    precedes and follows each; the mask unchanged."""
    from bare_earth.core.rascor import sequence
    events = []
    stages = ("_spare_continuing_ground", "_spare_ramps", "_spare_slope_breaks")
    _spy_stages(monkeypatch, sequence, stages, events)
    _run_with_events("rascor", _city(), events)
    named = _named(events)
    assert [events[i] for i in named] == list(stages)
    _assert_reports_after(events, named)


def test_morphological_reports_between_its_opening_stages(monkeypatch):
    """QA 20: the progressive form ran its low outliers' pit tests, the ground slope map and the cell slopes before
    the opening, and the cut terrain and cut slopes after it, without a report (6-7 s silent on 16 Mcells under
    load; a cancel waited as long). Each is now followed by a report, the fractions rising; the mask unchanged."""
    from bare_earth.core import morphology
    events = []
    stages = ("find_low_outliers", "ground_slope_map", "find_cut_terrain", "find_cut_slopes")
    _spy_stages(monkeypatch, morphology, stages, events)
    meth = methods.get_method("morphological")
    z = _city()
    params = {**pipeline.resolve_params(meth, z, 1.0), "mode": "progressive"}
    events.clear()
    meth.run(z, (1.0, 1.0), progress=events.append, **params)
    named = _named(events)
    assert [events[i] for i in named] == list(stages)
    _assert_reports_after(events, named)


def test_morphological_object_size_reports_after_its_search(monkeypatch):
    """QA 20: after its search (the filter, which reports), the object-size estimate judged the regions on walls
    (twice) and measured two widths without a report, the tail of morphological's derivation. A report now
    follows each; the estimate unchanged."""
    from bare_earth.core import morphology
    events = []
    z = _city()
    base = morphology.estimate_object_size(z, 1.0, 0.3, 0.5, details=True)
    _spy_stages(monkeypatch, morphology, ("objects_on_walls", "object_widths"), events)
    assert morphology.estimate_object_size(z, 1.0, 0.3, 0.5, details=True, progress=events.append) == base
    named = _named(events)
    assert [events[i] for i in named] == ["objects_on_walls", "object_widths", "object_widths", "objects_on_walls"]
    _assert_reports_after(events, named)


def test_raised_region_search_reports_after_each_scale():
    """QA 20: curvature's largest object searched the raised regions on walls (three searches, the last the
    walled span: 12 s on 16 Mcells under load) with a report only after each search. The search
    (dtm_regions.find_raised_regions, through estimate's raised_region_* estimates) now reports after its labelling
    and after each of its scales (t, 2 t, 4 t ... up to the highest step), ends at 1, stops at the call that raises;
    the results unchanged."""
    from bare_earth.core.curvature import method as curvature
    z = _city()
    calls = []
    base = estimate.raised_region_span_walled(z, (1.0, 1.0), 1.0, 0.0, max_span_m=400.0)
    assert estimate.raised_region_span_walled(z, (1.0, 1.0), 1.0, 0.0, max_span_m=400.0,
                                              progress=calls.append) == base
    highest = float(np.nanmax(z) - np.nanmin(z))
    assert len(calls) >= 2 + int(np.log2(highest / 8.0)) and calls == sorted(calls) and calls[-1] == 1.0
    assert estimate.raised_region_window(z, (1.0, 1.0), 1.0, 20.0, progress=calls.append) == \
        estimate.raised_region_window(z, (1.0, 1.0), 1.0, 20.0)
    seen = []

    def stop(f):
        seen.append(f)
        raise Cancelled()
    with pytest.raises(Cancelled):
        estimate.raised_region_span_walled(z, (1.0, 1.0), 1.0, 0.0, max_span_m=400.0, progress=stop)
    assert len(seen) == 1
    # inside curvature's largest object: the walled span (after 0.7) reports from inside
    calls.clear()
    assert curvature.object_size(z, (1.0, 1.0), 1.0, progress=calls.append) == curvature.object_size(z, (1.0, 1.0), 1.0)
    assert len([f for f in calls if 0.7 < f < 1.0]) >= 2 and calls == sorted(calls)


def test_slopeprofile_refinement_reports_from_inside_its_fill(monkeypatch):
    """QA 20: slopeprofile's final refinement (REFINE) interpolated the ground under its objects (fill_gaps, a
    second of CPU on 16 Mcells) without a callback: the bar stood at 87 % and a cancel waited. The fill now
    reports from inside it; the mask unchanged."""
    from bare_earth.core import fill
    meth = methods.get_method("slopeprofile")
    z = _city()
    params = {**pipeline.resolve_params(meth, z, 1.0), "refine": True}
    base = meth.run(z, (1.0, 1.0), **params).mask
    events = []
    _spy_stages(monkeypatch, fill, ("fill_gaps",), events)
    np.testing.assert_array_equal(meth.run(z, (1.0, 1.0), progress=events.append, **params).mask, base)
    named = _named(events)
    assert [events[i] for i in named] == ["fill_gaps"]
    inside = [e for e in events[named[0] + 1:] if isinstance(e, float) and 0.87 < e < 0.95]
    assert len(inside) >= 3, events[named[0]:]
    _assert_reports_after(events, named)


def test_fill_reports_while_its_pyramid_is_built(monkeypatch):
    """QA 20: fill_gaps reported once per level solved, the first after building its whole pyramid (a third of its
    time: 0.27 of 0.63 s CPU on 16 Mcells). A report now follows each level built, before the coarsest is solved;
    the fill unchanged, the fractions rising to 1."""
    from bare_earth.core import fill
    z = synthetic.make_scene("city", shape=(300, 300), cell_size=1.0, seed=5).dsm
    holes = z > np.nanpercentile(z, 70)
    base = fill.fill_gaps(z, fill=holes)
    events = []
    _spy_stages(monkeypatch, fill, ("_restrict", "_solve_direct"), events)
    np.testing.assert_array_equal(fill.fill_gaps(z, fill=holes, progress=events.append), base)
    named = _named(events)
    assert [events[i] for i in named] == ["_restrict"] * (len(fill.pyramid_shapes(z.shape)) - 1) + ["_solve_direct"]
    _assert_reports_after(events, named)
    assert events[-1] == 1.0


def test_curvature_reports_between_its_profile_and_ground_stages(monkeypatch):
    """QA 20: curvature ran, without a report, the bounds of its profiles' runs across (both axes), the cut objects
    at the raster's edge, the first stages of its final pass (the low bowls, the first holes, the bowls beside
    objects: 2.4 s CPU on 16 Mcells, 23 s under load) and, in each pass, the classification and the ground
    continued from it. A report now follows each of these stages, the fractions rising; the mask unchanged."""
    from bare_earth.core.curvature import ground, profiles
    events = []
    _spy_stages(monkeypatch, profiles, ("bounded_runs", "_edge_regions"), events)
    _spy_stages(monkeypatch, ground, ("_low_bowls", "_first_holes", "_ground_bowls", "_classify",
                                      "_continue_ground"), events)
    _run_with_events("curvature", _city(), events)
    named = _named(events)
    names = [events[i] for i in named]
    assert names[:3] == ["bounded_runs", "bounded_runs", "_edge_regions"]
    assert names[3:6] == ["_low_bowls", "_first_holes", "_ground_bowls"]
    assert names.count("_classify") == names.count("_continue_ground") >= 2
    _assert_reports_after(events, named)


def test_curvature_reports_inside_its_ground_seeds(monkeypatch):
    """QA 20: after the reports above, the longest silent stretches of curvature's run on 16 Mcells were inside the
    bowls beside objects (two minimum filters, 1.3 s CPU) and the lower envelope's ground level (a minimum filter and
    the local slopes, 1.2 s): each now reports between its filters; the mask unchanged."""
    from bare_earth.core.curvature import ground
    events = []
    _spy_stages(monkeypatch, ground, ("_ground_bowls", "under_chords", "_local_slopes"), events)
    _run_with_events("curvature", _city(), events)
    named = _named(events)
    first = [events[i] for i in named][:3]
    assert first == ["_ground_bowls", "under_chords", "_local_slopes"], first
    for a, b in zip(named[:2], named[1:3]):
        assert len([e for e in events[a + 1:b] if isinstance(e, float)]) >= 2, events[a:b + 1]


def test_dtm_reports_after_its_raised_regions_and_detached_levels(monkeypatch):
    """QA 20: after its refinement (0.82), bareearth:dtm searched the raised regions (every scale of walls), the
    detached levels and the roofs' edges without a report up to 0.85. The search now reports after each of its
    scales (one thread) and a report follows each stage; the mask unchanged."""
    from bare_earth.core import dtm
    events = []
    _spy_stages(monkeypatch, dtm, ("find_raised_regions", "find_detached_levels", "describe_region"), events)
    _run_with_events("dtm", _city(), events)
    named = _named(events)
    names = [events[i] for i in named]
    assert names[:2] == ["find_raised_regions", "find_detached_levels"], names
    assert len([e for e in events[named[0] + 1:named[1]] if isinstance(e, float)]) >= 2
    _assert_reports_after(events, named[:2])


def test_curvature_reports_inside_its_envelope_and_continued_ground(monkeypatch):
    """QA 25: on 16 Mcells two stages of curvature's ground still ran without a report: the lower envelope's chord
    test (estimate.under_chords, 0.9 s CPU) and the ground continued over the final pass's objects
    (_continue_ground, 1.4 s). Each now reports from inside (blocks of rows; the profile's stages and the cells of
    its stretches), several times between its start and its end; the mask unchanged (with and without a callback)."""
    from bare_earth.core.curvature import ground
    monkeypatch.setattr(estimate, "_CHORD_BLOCK_CELLS", 200 * 40)    # the 200-column city in 5 blocks of rows
    events = []
    for name in ("under_chords", "_continue_ground"):
        f = getattr(ground, name)

        def spy(*args, _f=f, _name=name, **kwargs):
            events.append(_name)
            r = _f(*args, **kwargs)
            events.append("/" + _name)
            return r
        monkeypatch.setattr(ground, name, spy)
    _run_with_events("curvature", _city(), events)
    for name in ("under_chords", "_continue_ground"):
        starts = [i for i, e in enumerate(events) if e == name]
        ends = [i for i, e in enumerate(events) if e == "/" + name]
        assert starts and len(starts) == len(ends)
        for a, b in zip(starts, ends):
            inside = [e for e in events[a + 1:b] if isinstance(e, float)]
            assert len(inside) >= 3, (name, events[a:b + 1])
    fractions = [e for e in events if isinstance(e, float)]
    assert fractions == sorted(fractions)


def test_under_chords_reports_by_blocks_and_stops_on_cancel(monkeypatch):
    """estimate.under_chords reports after each block of rows, ends at 1, gives the same cells with a callback,
    and stops at the report that raises."""
    monkeypatch.setattr(estimate, "_CHORD_BLOCK_CELLS", 300 * 30)
    z = synthetic.make_scene("city", shape=(300, 300), cell_size=1.0, seed=5).dsm
    calls = []
    got = estimate.under_chords(z, 2, 0.3, progress=calls.append)
    np.testing.assert_array_equal(got, estimate.under_chords(z, 2, 0.3))
    assert len(calls) == 10 and calls == sorted(calls) and calls[-1] == 1.0
    seen = []

    def stop(f):
        seen.append(f)
        raise Cancelled()
    with pytest.raises(Cancelled):
        estimate.under_chords(z, 2, 0.3, progress=stop)
    assert seen == [0.1]
