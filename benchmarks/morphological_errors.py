#!/usr/bin/env python3
"""Where the morphological filter's errors are, stage by stage, on the point rows of the generalisation matrix.

Usage::

    .venv/bin/python benchmarks/morphological_errors.py --only 'isprs/samp71/2m|Topography/1m'

For each row of :mod:`generalise` scored by points (ISPRS and classified lidar) whose name matches ``--only``,
runs ``bareearth:morphological`` with its defaults as the matrix does (:func:`~bare_earth.core.pipeline.run_array`),
classifies the points against its DTM, runs the filter once more on the same filled DSM with the parameters it
derived and ``stages=`` (:func:`~bare_earth.core.morphology.filter_morphological`: the same mask, checked), and
prints the type I points above the DTM, below it, and the type II points by the stage that decided their cell:

* ``step k (w m)``: flagged by the progressive opening, first at step ``k`` (window ``w`` metres);
* ``cut terrain``: flagged, then given back by the cut terrain's rules (regions or cells on no wall);
* ``outline``, ``tier``: the mixed cells on the objects' outlines and the attached tiers left out of ``ZIpro``;
* ``pre-step low``: the low-outlier pre-step's cells; ``low -> ground``: the final test's low cells made ground;
* ``kept``: none of these (the cell kept its own height in ``ZIpro``),

and by the cell's class in the mask (``ground``, ``object``, ``low``), with the median height of the points above
the reference's own DTM. A type II point in a ``kept`` ground cell stands on an object no step flagged (its drop
stayed below ``s r_k``); one in a ``step k`` ground cell was flagged and the final test gave it back.

It writes no log: it says where to look, the matrix says how good a change is.
"""
import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import generalise  # noqa: E402  (imports isprs, whose bootstrap makes ``import bare_earth`` work)
from dtm_errors import error_kinds, point_rows  # noqa: E402  (one copy of the error kinds)

#: The stages other than the opening's steps, in the order they are read (the first that holds names the cell).
FIXED_STAGES = ("kept", "cut terrain", "outline", "tier", "pre-step low", "low -> ground")
CLASSES = {0: "ground", 1: "object", 2: "low"}


def stage_codes(stages, shape, windows_m=()):
    """Per cell, the index into the returned names of the stage that decided it.

    Parameters
    ----------
    stages : dict
        ``filter_morphological(stages=)``'s rasters (progressive form: ``first_step``, ``flagged``,
        ``cut_terrain``, ``outline``, ``tiers``, ``low_prestep``, ``low_ground``; single form: ``low_ground``).
    shape : tuple
        The raster's shape.
    windows_m : sequence of float
        The opening's window sizes (``info["window_sizes_m"]``), for the steps' names.

    Returns
    -------
    codes : ndarray of int16
    names : list of str
        :data:`FIXED_STAGES` then ``step k (w m)`` for each step (code ``len(FIXED_STAGES) + k``).
    """
    names = list(FIXED_STAGES) + [f"step {k} ({w:g} m)" for k, w in enumerate(windows_m)]
    codes = np.zeros(shape, np.int16)
    order = (("low_ground", 5), ("low_prestep", 4), ("tiers", 3), ("outline", 2), ("cut_terrain", 1))
    for key, code in order:                      # later ones win: the opening's flags last
        if key in stages:
            codes[np.asarray(stages[key], bool)] = code
    if "flagged" in stages and "first_step" in stages:
        flagged = np.asarray(stages["flagged"], bool) & (np.asarray(stages["first_step"]) >= 0)
        codes[flagged] = len(FIXED_STAGES) + np.asarray(stages["first_step"], np.int16)[flagged]
    return codes, names


def breakdown(codes, truth, valid, rows, cols, mask, stage_grid, names, heights=None, reference=None):
    """Counts of the point errors by kind, by the stage that decided their cell and the cell's class.

    Parameters
    ----------
    codes, truth, valid, rows :
        As :func:`error_kinds`.
    cols : ndarray of int
        Per point, its cell's column.
    mask : ndarray of uint8
        The filter's mask (0 ground, 1 object, 2 low).
    stage_grid, names :
        :func:`stage_codes`.
    heights, reference : optional
        Per point heights and the reference DTM (metres): the median of the points' heights above it, per group.

    Returns
    -------
    dict
        ``ground_points``, ``object_points``, ``type1_above``, ``type1_below``, ``type2`` (counts) and ``groups``:
        ``{(kind, stage name, class): {"points": n[, "point_above_ref_m": median]}}``.
    """
    scored, by_kind = error_kinds(codes, truth, valid, rows)
    r, c = np.where(rows >= 0, rows, 0), np.where(cols >= 0, cols, 0)
    kinds = [(k, by_kind[k]) for k in ("type1_above", "type1_below", "type2")]
    out = {"ground_points": int(np.count_nonzero(scored & truth)),
           "object_points": int(np.count_nonzero(scored & ~truth)), "groups": {}}
    lift = None
    if heights is not None and reference is not None:
        lift = np.asarray(heights, np.float64) - np.asarray(reference, np.float64)[r, c]
    st, cl = np.asarray(stage_grid)[r, c], np.asarray(mask)[r, c]
    for kind, sel in kinds:
        out[kind] = int(np.count_nonzero(sel))
        for s_, c_ in sorted(set(zip(st[sel].tolist(), cl[sel].tolist()))):
            g = sel & (st == s_) & (cl == c_)
            group = {"points": int(np.count_nonzero(g))}
            if lift is not None:
                group["point_above_ref_m"] = float(np.median(lift[g]))
            out["groups"][(kind, names[s_], CLASSES.get(c_, str(c_)))] = group
    return out


def format_breakdown(name, b, info=None):
    n = max(1, b["ground_points"] + b["object_points"])
    lines = [f"{name}: {b['ground_points']} ground and {b['object_points']} object points; total error "
             f"{100.0 * (b['type1_above'] + b['type1_below'] + b['type2']) / n:.2f} %: type I above the DTM "
             f"{b['type1_above']}, below it {b['type1_below']}, type II {b['type2']}"]
    if info:
        lines.append("  " + ", ".join(f"{k} {info[k]}" for k in ("mode", "window_sizes_m", "thresholds_m", "dh_m",
                                                                  "slope") if k in info))
    for (kind, st, cl), g in sorted(b["groups"].items(), key=lambda kv: (kv[0][0], -kv[1]["points"])):
        extra = f"  point above ref {g['point_above_ref_m']:+.2f} m" if "point_above_ref_m" in g else ""
        lines.append(f"  {kind:<12} {st:<22} {cl:<7} {g['points']:>7} ({100.0 * g['points'] / n:.2f} %){extra}")
    return "\n".join(lines)


def run(data, only, progress=print):
    from bare_earth.core.methods import get_method
    from bare_earth.core.pipeline import fill_empty_cells, run_array
    meth = get_method("morphological")
    results = {}
    for name, z, cell, score in point_rows(data, only):
        res = run_array(meth, z, cell, {})
        codes = score.classify(np.asarray(res.dtm, np.float32))
        stages = {}
        again = meth.run(fill_empty_cells(z, cell)[0], cell, stages=stages, **dict(res.info["params"]))
        valid = np.isfinite(z)
        differ = int(np.count_nonzero((np.asarray(again.mask) != res.mask) & valid))
        grid, names = stage_codes(stages, z.shape, again.info.get("window_sizes_m", ()))
        rows, cols = score.point_cells()
        b = breakdown(codes, score.truth, score.valid, rows, cols, res.mask, grid, names,
                      heights=score.point_heights(), reference=score.floor_dtm())
        b["cells_differing"] = differ
        results[name] = b
        if progress:
            progress(format_breakdown(name, b, again.info)
                     + (f"\n  WARNING: {differ} cells differ from the matrix's run" if differ else ""))
    return results


def main(argv=None, run=run, description=__doc__):
    """The command line of an error breakdown (this one and ``geodesic_errors``): ``--data``, ``--only``."""
    ap = argparse.ArgumentParser(description=description.split("\n\n")[0])
    ap.add_argument("--data", default=None, help="data folder (default $BARE_EARTH_DATA or ../shared/data)")
    ap.add_argument("--only", required=True, help="regular expression: the rows to look at")
    a = ap.parse_args(argv)
    run(Path(a.data if a.data is not None else generalise.isprs.default_data_dir()), a.only)


if __name__ == "__main__":
    main()
