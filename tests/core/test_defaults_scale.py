"""Derived defaults on the same landscape at 0.5, 1, 2 and 4 m cells (issue 12).

A closed canopy over gentle ground (``synthetic.make_canopy``) is the case where defaults
measured on the whole DSM follow the canopy and the cell size (a whole-DSM noise of 0.2 m
at 0.5 m cells, 4.5 m at 4 m cells). Defaults measured on the right surface are the same in
metres at every cell size. Left out, by design: the curvature threshold K_g (1/m^2: the
bend noise of a least-squares fit falls with the square of the cell, with the cell alone on
slopes: see test_curvature), the morphological
filter's largest object (at coarser cells the gaps between crowns vanish and crowns merge
into wider objects: a property of the coarser DSM) and RASCOR's lengths and sigma (chosen
from its own residual analysis of the whole surface, see the RASCOR help).
"""
import numpy as np
import pytest

from bare_earth.core.methods import get_method
from bare_earth.core.synthetic import make_canopy

CELLS = (0.5, 1.0, 2.0, 4.0)
METRE_DEFAULTS = {
    "morphological": ("dh_m", "slope"),
    "geodesic": ("height_threshold_m", "terrain_slope_deg", "outlier_threshold_m"),
    "slopeprofile": ("tolerance_m", "terrain_slope_deg", "slope_threshold_deg"),
    "curvature": ("tolerance_m",),
}


@pytest.fixture(scope="module")
def canopies():
    return {c: make_canopy(512.0, c, cover=0.85, seed=0, noise_m=0.05) for c in CELLS}


@pytest.mark.parametrize("name", sorted(METRE_DEFAULTS))
def test_defaults_in_metres_agree_within_20_percent_from_0_5_to_4_m(name, canopies):
    meth = get_method(name)
    got = {c: meth.resolve(s.dsm, s.cell_size) for c, s in canopies.items()}
    for key in METRE_DEFAULTS[name]:
        v = np.array([got[c][key] for c in CELLS], float)
        assert np.all(v > 0), (key, v)
        assert v.max() / v.min() <= 1.2, (key, v)
    if name == "morphological":
        assert {got[c]["mode"] for c in CELLS} == {"progressive"}
