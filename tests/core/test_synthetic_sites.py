"""The held-out-like sites (core/synthetic_sites.py): seeded, truth consistent with the rasterisation, and
bareearth:dtm's accuracy on each (issue 13: the kinds of the held-out ISPRS samples)."""
import numpy as np
import pytest
from scipy import ndimage

from bare_earth.core.codes import GROUND, OBJECT
from bare_earth.core.evaluate import compare_masks
from bare_earth.core.pipeline import run_array
from bare_earth.core.synthetic_sites import EXTENT_M, SITES, make_site


@pytest.mark.parametrize("kind", SITES)
def test_site_is_seeded_and_consistent(kind):
    """Same arguments, same site; another seed, another; 1 and 2 m grids of the same fine site; truth
    codes ground / object only; the highest point per cell shows more objects than the lowest."""
    a = make_site(kind, 2.0, "lowest", seed=3)
    b = make_site(kind, 2.0, "lowest", seed=3)
    for x, y in ((a.dsm, b.dsm), (a.dtm, b.dtm), (a.mask, b.mask)):
        np.testing.assert_array_equal(x, y)
    assert not np.array_equal(make_site(kind, 2.0, "lowest", seed=4).dsm, a.dsm)
    n = int(EXTENT_M[kind])
    assert a.dsm.shape == a.dtm.shape == a.mask.shape == (n // 2, n // 2)
    assert a.dsm.dtype == np.float32 and a.mask.dtype == np.uint8 and a.cell_size == (2.0, 2.0)
    assert np.isfinite(a.dsm).all() and np.isfinite(a.dtm).all()
    assert set(np.unique(a.mask)) <= {GROUND, OBJECT}
    fine = make_site(kind, 1.0, "lowest", seed=3)
    assert fine.dsm.shape == (n, n)
    # the true DTM is the mean of the same fine ground: the 2 m cells average the 1 m ones
    np.testing.assert_allclose(fine.dtm.reshape(n // 2, 2, n // 2, 2).mean(axis=(1, 3)), a.dtm, atol=1e-3)
    top = make_site(kind, 2.0, "highest", seed=3)
    np.testing.assert_array_equal(top.dtm, a.dtm)
    assert np.mean(top.mask == OBJECT) > np.mean(a.mask == OBJECT)
    # a ground cell's height is a ground point's: within the cell's relief and the noise of the true DTM
    g = a.mask == GROUND
    assert np.median(np.abs(a.dsm - a.dtm)[g]) < 1.0


def test_site_arguments_checked():
    with pytest.raises(ValueError, match="unknown site"):
        make_site("harbour")
    with pytest.raises(ValueError, match="surface"):
        make_site("quarry", surface="mean")
    for cell in (0.75, 3.0, 0.25):                       # not a multiple of 0.5 m dividing 320 m
        with pytest.raises(ValueError, match="cell_size"):
            make_site("quarry", cell)


def test_terrain_steps_are_ground_in_the_truth():
    """The quarry's benches and cliffs, the hillside's retaining walls and the bridge's ramps are ground:
    the true ground has steps of several metres between neighbouring cells."""
    for kind, least in (("quarry", 5.0), ("hillside", 2.0), ("bridge", 1.0)):
        s = make_site(kind, 1.0, "lowest")
        step = max(float(np.abs(np.diff(s.dtm, axis=0)).max()), float(np.abs(np.diff(s.dtm, axis=1)).max()))
        assert step > least, (kind, step)


#: dtm's total error (per cent of cells) on each site, measured on 2026-11-29 (seed 0): hillside 1 m lowest
#: 3.7-4.0, 2 m highest 6.8-7.3; railway 2.2, 2.6; quarry 4.9-6.4, 5.6-6.3; shrubs 6.9-7.1, 22.3-22.5; bridge
#: 2.0, 2.9 (the ranges: before and after the step-top continuation of dtm_refine.continue_lines). The
#: bounds add about a quarter, so that a change elsewhere may move them a little but a broken stage does
#: not pass. Steep slopes under dense shrubs at 2 m highest point are a known limit: every filter fails
#: there (18.7-25.5 %), the shrubs' tops are continuous surfaces 0.5-2 m above the ground.
DTM_BOUNDS = {
    ("hillside", 1.0, "lowest"): 5.0, ("hillside", 2.0, "highest"): 9.0,
    ("railway", 1.0, "lowest"): 3.0, ("railway", 2.0, "highest"): 3.5,
    ("quarry", 1.0, "lowest"): 8.0, ("quarry", 2.0, "highest"): 8.0,
    ("shrubs", 1.0, "lowest"): 9.5, ("shrubs", 2.0, "highest"): 27.0,
    ("bridge", 1.0, "lowest"): 3.0, ("bridge", 2.0, "highest"): 3.8,
    # the sites added for ISPRS 23, 24, 53 and 54 (2026-11-29, seed 0): embankment 2 m lowest 6.55, steps 1 m
    # lowest 2.13, courtyard 1 m lowest 0.02, sparse 2 m highest 0.30
    ("embankment", 2.0, "lowest"): 8.0, ("steps", 1.0, "lowest"): 3.0,
    ("courtyard", 1.0, "lowest"): 0.5, ("sparse", 2.0, "highest"): 0.6,
}


@pytest.mark.parametrize("kind,cell,surface", sorted(DTM_BOUNDS))
def test_dtm_accuracy_on_sites(kind, cell, surface):
    s = make_site(kind, cell, surface)
    res = run_array("dtm", s.dsm, s.cell_size, {})
    total = compare_masks(res.mask, s.mask)["total"]
    assert total <= DTM_BOUNDS[(kind, cell, surface)], total


def test_rascor_keeps_the_quarry_benches_tops():
    """RASCOR alone on the quarry at 2 m, lowest point: its benches' tops, which step 3 took as the
    upper points of the pairs across each face, are tested again along the tops, never against the
    faces' feet (each side of a terrain step a line of its own): 8.56 % total error before, 7.35 %."""
    s = make_site("quarry", 2.0, "lowest")
    res = run_array("rascor", s.dsm, s.cell_size, {})
    assert compare_masks(res.mask, s.mask)["total"] <= 8.0


def test_courtyards_are_ground_enclosed_by_buildings():
    """ISPRS 23's courtyards: ground regions of the truth that no ground path joins to the raster's edge (the
    blocks close round them), at least one 100 m2 large; and the site's data gaps are filled from the
    nearest point, so runs of equal heights stand where the gaps were."""
    s = make_site("courtyard", 1.0, "lowest")
    lab, n = ndimage.label(s.mask == GROUND)
    edge = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
    sizes = np.bincount(lab.ravel(), minlength=n + 1)
    enclosed = np.setdiff1d(np.arange(1, n + 1), edge)
    assert (sizes[enclosed] >= 100).sum() >= 2


def test_steps_site_has_terrain_steps_with_vegetation_on_their_edges():
    """ISPRS 53: the true ground rises by 2 m or more over at most 5 m across its steps, and the objects
    crowd along them (object share within 6 m of a step at least twice that farther away)."""
    s = make_site("steps", 1.0, "lowest")
    rise = ndimage.maximum_filter(s.dtm, size=5) - ndimage.minimum_filter(s.dtm, size=5)
    step = rise > 2.0
    assert step.mean() > 0.01
    near = ndimage.binary_dilation(step, iterations=6)
    obj = s.mask == OBJECT
    assert obj[near].mean() > 2 * obj[~near].mean()


def test_embankment_site_is_ground_with_shrubs_on_its_sides():
    """ISPRS 24: embankments and the cut are ground (the true DTM departs from the site's smooth base by
    3 m or more over a long band), shrubs and trees on their sides are objects."""
    s = make_site("embankment", 1.0, "lowest")
    base = ndimage.median_filter(s.dtm, size=61)
    raised = (s.dtm - base) > 2.0
    assert raised.mean() > 0.01 and (s.mask[raised] == GROUND).mean() > 0.8
    assert (s.mask == OBJECT).mean() > 0.02


def test_sparse_site_has_a_point_every_2_to_3_m():
    """ISPRS 54's low resolution: at 1 m most cells have no point and take the nearest cell's point, so most
    cells equal a 4-neighbour exactly (0.997), on a dense site (1.2 points per m2: a quarter of the cells
    empty) about half (0.47)."""
    def copied(kind):
        z = make_site(kind, 1.0, "lowest").dsm
        same = np.zeros(z.shape, bool)
        same[:, 1:] |= z[:, 1:] == z[:, :-1]
        same[:, :-1] |= z[:, :-1] == z[:, 1:]
        same[1:] |= z[1:] == z[:-1]
        same[:-1] |= z[:-1] == z[1:]
        return same.mean()
    assert copied("sparse") > 0.9
    assert copied("courtyard") < 0.6
