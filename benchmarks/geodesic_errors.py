#!/usr/bin/env python3
"""Where the geodesic filter's errors are, stage by stage, on rows of the generalisation matrix.

Usage::

    .venv/bin/python benchmarks/geodesic_errors.py --only 'opengeos|isprs/samp71/2m'

For each row of :mod:`generalise` whose name matches ``--only``, runs ``bareearth:geodesic`` with its defaults as
the matrix does (:func:`~bare_earth.core.pipeline.run_array`) and prints its errors by the stage that decided
their cell, read from the filter's own ``extras["step"]`` (:func:`stage_codes`):

* ``step k (w m)``: removed by the gradual geodesic dilation, first at step ``k`` (window ``w`` metres);
* ``scan``: removed by scan labelling; ``outlier``: a preprocessing outlier (high or low);
* ``edge``: a border cell of a removed object (stage 4, wall feet and crown edges);
* ``island``: a kept island inside removed objects, above the terrain (stage 5);
* ``kept``: none of these,

and by the cell's class in the mask (``ground``, ``object``, ``low``), with the median height above the
reference's own DTM. Rows scored by points (ISPRS, classified lidar) count points (type I above / below the DTM,
type II); the rows scored by cells (``opengeos/dsm/2m``) count cells (a type I cell is true ground the mask does
not call ground, ``type1_above``; a type II cell an object cell it calls ground). A type II in a ``kept`` ground
cell stands on an object no stage took; a type I in an ``edge`` cell was ground the border stage peeled off.

It writes no log: it says where to look, the matrix says how good a change is.
"""
import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import generalise  # noqa: E402  (imports isprs, whose bootstrap makes ``import bare_earth`` work)
from morphological_errors import breakdown, format_breakdown  # noqa: E402  (one copy of the breakdown)
from morphological_errors import main as errors_main  # noqa: E402  (and of the command line)

#: The codes of ``extras["step"]`` other than the dilation's steps (core/geodesic/filter.py's ``STEP_*``).
FIXED_CODES = {0: "kept", 250: "scan", 251: "outlier", 252: "edge", 253: "island"}


def stage_codes(step, sizes_m=()):
    """Per cell, the index into the returned names of the stage that decided it.

    Parameters
    ----------
    step : ndarray of uint8
        ``filter_geodesic``'s ``extras["step"]`` (0 kept, ``k`` removed first at dilation step ``k``, 250 scan,
        251 outlier, 252 edge, 253 island, 255 nodata).
    sizes_m : sequence of float
        The dilation's window sizes (``info["step_sizes_m"]``), for the steps' names.

    Returns
    -------
    codes : ndarray of int16
        0 .. 4 :data:`FIXED_CODES` in order, ``5 + k - 1`` dilation step ``k``, -1 nodata.
    names : list of str
    """
    step = np.asarray(step)
    names = list(FIXED_CODES.values()) + [f"step {k} ({w:g} m)" for k, w in enumerate(sizes_m, start=1)]
    codes = np.full(step.shape, -1, np.int16)
    for i, c in enumerate(FIXED_CODES):
        codes[step == c] = i
    for k in range(1, len(sizes_m) + 1):
        codes[step == k] = len(FIXED_CODES) + k - 1
    return codes, names


def cell_row(z, score, res):
    """A row scored by cells (``opengeos``) as points of :func:`breakdown`: one point per valid cell."""
    from bare_earth.core.codes import GROUND
    truth_grid, valid_grid, ref = score.cell_truth()
    rows, cols = np.nonzero(valid_grid & (np.asarray(res.mask) != 255))
    ground = np.asarray(res.mask)[rows, cols] == GROUND
    codes = np.where(ground, 0, 1).astype(np.uint8)                 # not ground: counted as type I above
    return codes, truth_grid[rows, cols], np.ones(rows.size, bool), rows, cols, z[rows, cols], ref


def run(data, only, progress=print):
    from bare_earth.core.pipeline import run_array
    results = {}
    for _src, _fam, _half, builds in generalise.all_cases(data, []):
        for name, build in builds:
            if not re.search(only, name):
                continue
            z, cell, score = build()
            res = run_array("geodesic", z, cell, {})
            if "step" not in res.extras:
                continue
            grid, names = stage_codes(res.extras["step"], res.info.get("step_sizes_m", ()))
            if hasattr(score, "point_cells"):
                codes = score.classify(np.asarray(res.dtm, np.float32))
                rows, cols = score.point_cells()
                b = breakdown(codes, score.truth, score.valid, rows, cols, res.mask, grid, names,
                              heights=score.point_heights(), reference=score.floor_dtm())
            elif hasattr(score, "cell_truth"):
                codes, truth, valid, rows, cols, heights, ref = cell_row(np.asarray(z, np.float64), score, res)
                b = breakdown(codes, truth, valid, rows, cols, res.mask, grid, names, heights=heights,
                              reference=ref)
            else:
                continue
            results[name] = b
            if progress:
                progress(format_breakdown(name, b))
    return results


def main(argv=None):
    errors_main(argv, run=run, description=__doc__)


if __name__ == "__main__":
    main()
