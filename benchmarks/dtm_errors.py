#!/usr/bin/env python3
"""Where ``bareearth:dtm``'s errors are, on the point rows of the generalisation matrix (issue 13).

Usage::

    .venv/bin/python benchmarks/dtm_errors.py --only 'Topography/1m|autzen_trim/1m' [--maps DIR] [--peer saga]

For each row of :mod:`generalise` scored by points (ISPRS and classified lidar) whose name matches
``--only``, runs ``bareearth:dtm`` with its defaults and each of its members with the parameters the
dtm derived, classifies the points against the DTM as the matrix does, and prints

* the type I errors split into ground points above the DTM (the DTM cut the ground) and below it
  (the DTM rests on objects), and the type II errors (object points within the tolerance of the DTM);
* the type II and type I-above points by the state of their cell (``ground``: the dtm kept the cell,
  its height is the DTM's; ``filled``: the dtm removed it, the DTM is interpolated there) and by the
  members' vote in that cell (``MRG``: morphological, rascor, geodesic called it ground, ``-`` object),
  with the median height of those points and of the DTM above the reference's own DTM (the truth's
  ground points, mean per cell);
* with ``--maps DIR``, ``DIR/<row>.npz``: per cell the counts of type I-above, type I-below and type
  II points, the DSM, the reference DTM, the dtm's DTM and mask, and each member's ground (and with
  ``--peer``, the peer's DTM and mask);
* with ``--peer saga`` (or ``csf``, ``dsm2dtm``: a tool of :mod:`anchors`, run with its defaults on the
  same DSM), the points by the two decisions of their cell (both ground, dtm ground and the peer object,
  the reverse, both object) with each filter's type I and type II points there, and the median of the
  dtm's DTM and of the peer's above the reference in the cells both removed and at the dtm's type II
  points: where the peer does better, whether by removing cells the dtm keeps or by a lower DTM under
  the objects both removed.

It writes no log: it says where to look, the matrix says how good a change is.
"""
import argparse
import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import generalise  # noqa: E402  (imports isprs, whose bootstrap makes ``import bare_earth`` work)

#: Ground (0) and the two type I codes of :func:`bare_earth.core.points.classify_points`.
GROUND, ABOVE, BELOW, OUTSIDE = 0, 1, 2, 255


def error_kinds(codes, truth, valid, rows):
    """The points scored and, among them, each kind of error (one copy for every error breakdown).

    Parameters
    ----------
    codes : ndarray of uint8
        Per point: 0 ground, 1 above the DTM, 2 below it, 255 outside (not scored).
    truth, valid : ndarray of bool
        Per point: a ground point; a point scored.
    rows : ndarray of int
        Per point, its cell's row (-1: off the grid, not scored).

    Returns
    -------
    scored : ndarray of bool
    kinds : dict
        ``{"type2", "type1_above", "type1_below"}``: per point, an object point the DTM calls ground, a
        ground point above the DTM, below it.
    """
    scored = valid & (codes != OUTSIDE) & (rows >= 0)
    return scored, {"type2": scored & ~truth & (codes == GROUND), "type1_above": scored & truth & (codes == ABOVE),
                    "type1_below": scored & truth & (codes == BELOW)}


def vote_patterns(members, rows, cols):
    """Per point, the members' vote in its cell as letters (``'MRG'``, ``'M-G'``, ...).

    ``members``: ``{name: bool ground grid}`` in the dtm's order; a letter is the name's first,
    upper-cased, where that member called the cell ground, ``-`` elsewhere.
    """
    letters = [np.where(g[rows, cols], n[0].upper(), "-") for n, g in members.items()]
    return np.array(["".join(t) for t in zip(*letters)]) if letters else np.array([], str)


def breakdown(codes, truth, valid, rows, cols, mask, members, heights=None, dtm=None, reference=None):
    """Counts of the point errors by kind, by the state of their cell and by the members' vote.

    Parameters
    ----------
    codes, truth, valid, rows :
        As :func:`error_kinds`.
    cols : ndarray of int
        Per point, its cell's column.
    mask : ndarray of uint8
        The dtm's mask (0 ground).
    members : dict
        ``{name: bool ground grid}`` of the members, in the dtm's order.
    heights, dtm, reference : optional
        Per point heights, the DTM and the reference DTM (metres): the medians of the heights of
        the points and of the DTM above the reference, per group.

    Returns
    -------
    dict
        ``ground_points``, ``object_points``, ``type1_above``, ``type1_below``, ``type2`` (counts),
        and ``groups``: ``{(kind, state, pattern): {"points": n, "point_above_ref_m": median,
        "dtm_above_ref_m": median}}`` for kind ``type2`` and ``type1_above``, state ``ground`` or
        ``filled``.
    """
    scored, kinds = error_kinds(codes, truth, valid, rows)
    r, c = np.where(rows >= 0, rows, 0), np.where(cols >= 0, cols, 0)
    out = {"ground_points": int(np.count_nonzero(scored & truth)),
           "object_points": int(np.count_nonzero(scored & ~truth)),
           **{k: int(np.count_nonzero(v)) for k, v in kinds.items()}, "groups": {}}
    state = np.where(mask[r, c] == 0, "ground", "filled")
    pattern = vote_patterns(members, r, c)
    above = None if heights is None or reference is None else heights - reference[r, c]
    lift = None if dtm is None or reference is None else (dtm - reference)[r, c]
    for kind in ("type2", "type1_above"):
        sel = kinds[kind]
        for st, pat in sorted(set(zip(state[sel].tolist(), pattern[sel].tolist()))):
            s = sel & (state == st) & (pattern == pat)
            g = {"points": int(np.count_nonzero(s))}
            if above is not None:
                g["point_above_ref_m"] = float(np.median(above[s]))
            if lift is not None:
                g["dtm_above_ref_m"] = float(np.median(lift[s]))
            out["groups"][(kind, st, pat)] = g
    return out


def error_maps(codes, truth, valid, rows, cols, shape):
    """Per cell, the counts of type I-above, type I-below and type II points (int32 grids)."""
    _, kinds = error_kinds(codes, truth, valid, rows)
    out = {}
    for name in ("type1_above", "type1_below", "type2"):
        sel = kinds[name]
        grid = np.zeros(shape, np.int32)
        np.add.at(grid, (rows[sel], cols[sel]), 1)
        out[name] = grid
    return out


#: The cells' decisions of :func:`peer_crosstab`: (dtm keeps the cell, the peer keeps it).
CELL_STATES = (("both ground", True, True), ("dtm ground, peer object", True, False),
               ("dtm object, peer ground", False, True), ("both object", False, False))


def peer_crosstab(ours, peer, truth, valid, rows, cols, mask, peer_mask, dtm=None, peer_dtm=None, reference=None):
    """The points by the dtm's and a peer's decision on their cell, with each one's errors there.

    Parameters
    ----------
    ours, peer : ndarray of uint8
        Per point, the codes of :func:`bare_earth.core.points.classify_points` against the dtm's and the
        peer's DTM (0 ground, 1 above, 2 below, 255 outside).
    truth, valid, rows, cols :
        As for :func:`breakdown`.
    mask, peer_mask : ndarray of uint8
        The dtm's and the peer's masks (0 ground).
    dtm, peer_dtm, reference : ndarray, optional
        The two DTMs and the reference DTM (metres): the medians of each DTM above the reference in the
        cells both removed and at the dtm's type II points.

    Returns
    -------
    dict
        ``{state: {"points", "ground_points", "dtm_type1", "dtm_type2", "peer_type1", "peer_type2"}}`` for
        each state of :data:`CELL_STATES`, a point scored when both codes are (neither 255), and with the
        DTMs ``"offsets"``: ``{"both_object_dtm_m", "both_object_peer_m", "dtm_type2_dtm_m",
        "dtm_type2_peer_m"}`` (NaN where no cell or point).
    """
    r, c = np.where(rows >= 0, rows, 0), np.where(cols >= 0, cols, 0)
    scored = valid & (rows >= 0) & (ours != OUTSIDE) & (peer != OUTSIDE)
    errors = {}
    for who, codes in (("dtm", ours), ("peer", peer)):
        errors[f"{who}_type1"] = scored & truth & (codes != GROUND)
        errors[f"{who}_type2"] = scored & ~truth & (codes == GROUND)
    keep, peer_keep = np.asarray(mask)[r, c] == 0, np.asarray(peer_mask)[r, c] == 0
    out = {}
    for state, k, pk in CELL_STATES:
        s = scored & (keep == k) & (peer_keep == pk)
        out[state] = {"points": int(np.count_nonzero(s)), "ground_points": int(np.count_nonzero(s & truth)),
                      **{name: int(np.count_nonzero(s & e)) for name, e in errors.items()}}
    if dtm is not None and peer_dtm is not None and reference is not None:
        both = (np.asarray(mask) != 0) & (np.asarray(peer_mask) != 0) & np.isfinite(reference)

        def med(a):
            a = a[np.isfinite(a)]
            return float(np.median(a)) if a.size else float("nan")
        lift, peer_lift = np.asarray(dtm) - reference, np.asarray(peer_dtm) - reference
        t2 = errors["dtm_type2"]
        out["offsets"] = {"both_object_dtm_m": med(lift[both]), "both_object_peer_m": med(peer_lift[both]),
                          "dtm_type2_dtm_m": med(lift[r[t2], c[t2]]), "dtm_type2_peer_m": med(peer_lift[r[t2], c[t2]])}
    return out


def format_crosstab(peer_name, x):
    lines = [f"  against {peer_name}: points by the cell's decisions (dtm type I / II | {peer_name} type I / II)"]
    for state, _, _ in CELL_STATES:
        g = x[state]
        lines.append(f"    {state:<24} {g['points']:>7} points, {g['ground_points']:>6} ground: dtm "
                     f"{g['dtm_type1']:>5} / {g['dtm_type2']:>5} | {peer_name} "
                     f"{g['peer_type1']:>5} / {g['peer_type2']:>5}")
    if "offsets" in x:
        o = x["offsets"]
        lines.append(f"    DTM above the reference (median): cells both removed dtm {o['both_object_dtm_m']:+.2f} m, "
                     f"{peer_name} {o['both_object_peer_m']:+.2f} m; at dtm's type II points dtm "
                     f"{o['dtm_type2_dtm_m']:+.2f} m, {peer_name} {o['dtm_type2_peer_m']:+.2f} m")
    return "\n".join(lines)


def format_breakdown(name, b):
    n = max(1, b["ground_points"] + b["object_points"])
    lines = [f"{name}: {b['ground_points']} ground and {b['object_points']} object points; total error "
             f"{100.0 * (b['type1_above'] + b['type1_below'] + b['type2']) / n:.2f} %: type I above the DTM "
             f"{b['type1_above']}, below it {b['type1_below']}, type II {b['type2']}"]
    for (kind, st, pat), g in sorted(b["groups"].items(), key=lambda kv: (kv[0][0], -kv[1]["points"])):
        extra = "".join(f"  {k} {g[k]:+.2f}" for k in ("point_above_ref_m", "dtm_above_ref_m") if k in g)
        lines.append(f"  {kind:<12} {st:<7} {pat}  {g['points']:>7}{extra}")
    return "\n".join(lines)


def point_rows(data, only):
    """The generalisation matrix's rows scored by points whose name matches ``only`` (a regular
    expression): ``(name, z, cell, score)`` each, built one at a time."""
    for _src, _fam, _half, builds in generalise.all_cases(data, []):
        for name, build in builds:
            if not re.search(only, name):
                continue
            z, cell, score = build()
            if hasattr(score, "point_cells"):              # else scored by cells, not points
                yield name, z, cell, score


def run(data, only, maps=None, progress=print, peer=None):
    from bare_earth.core.dtm import MEMBERS
    from bare_earth.core.methods import get_method
    from bare_earth.core.pipeline import resolve_params, run_array
    results = {}
    for name, z, cell, score in point_rows(data, only):
        res = run_array("dtm", z, cell, {})
        params = resolve_params("dtm", z, cell, {})
        members = {n: np.asarray(get_method(n).run(z, cell, **params["members"][n]).mask) == 0 for n in MEMBERS}
        codes = score.classify(np.asarray(res.dtm, np.float32))
        rows, cols = score.point_cells()
        ref = np.asarray(score.floor_dtm(), np.float64)
        b = breakdown(codes, score.truth, score.valid, rows, cols, res.mask, members,
                      heights=score.point_heights(), dtm=np.asarray(res.dtm, np.float64), reference=ref)
        results[name] = b
        if progress:
            progress(format_breakdown(name, b))
        extra = {}
        if peer:
            import anchors
            p = getattr(anchors, f"run_{peer}")(z, cell)
            x = peer_crosstab(codes, score.classify(np.asarray(p.dtm, np.float32)), score.truth, score.valid,
                              rows, cols, res.mask, p.mask, dtm=res.dtm, peer_dtm=p.dtm, reference=ref)
            b["peer"] = {"name": peer, **x}
            extra = {"peer_dtm": p.dtm, "peer_mask": p.mask}
            if progress:
                progress(format_crosstab(peer, x))
        if maps:
            Path(maps).mkdir(parents=True, exist_ok=True)
            grids = error_maps(codes, score.truth, score.valid, rows, cols, z.shape)
            np.savez_compressed(Path(maps) / (re.sub(r"[^\w.-]+", "_", name) + ".npz"), dsm=z, reference=ref,
                                dtm=res.dtm, mask=res.mask, **grids,
                                **{f"{n}_ground": g for n, g in members.items()}, **extra)
    return results


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=None, help="data folder (default $BARE_EARTH_DATA or ../shared/data)")
    ap.add_argument("--only", required=True, help="regular expression: the rows to look at")
    ap.add_argument("--maps", default=None, help="folder for the per-cell error maps (npz)")
    ap.add_argument("--peer", default=None, choices=("saga", "csf", "dsm2dtm"),
                    help="a tool of anchors.py to compare with, cell by cell")
    a = ap.parse_args(argv)
    run(Path(a.data if a.data is not None else generalise.isprs.default_data_dir()), a.only, a.maps, peer=a.peer)


if __name__ == "__main__":
    main()
