"""bareearth:dtm's members on a coarser grid (core/dtm_coarse.py): the factor, the expansion's rules, the log."""
import numpy as np
import pytest

from bare_earth.core import dtm as dtm_method
from bare_earth.core import pipeline
from bare_earth.core.codes import GROUND, LOW, NODATA, OBJECT
from bare_earth.core.dtm_coarse import CoarseGrid, block_allowance, coarse_factor, coarsen, coarsen_flags
from bare_earth.core.synthetic import make_scene

G, B, L, N = GROUND, OBJECT, LOW, NODATA     # ground, building (object), low, nodata


@pytest.mark.parametrize("cell, f", [(2.0, 1), (1.0, 1), (0.75, 1), (0.5, 2), (0.3, 2), (0.25, 4), (0.1, 8),
                                     ((0.5, 1.0), 1)])
def test_coarse_factor_keeps_coarse_cells_at_most_1_m(cell, f):
    """A power of two (block windows aligned on powers of two see the single pass's coarse grid), the coarse
    cell at most 1 m on its longer side."""
    assert coarse_factor(cell if isinstance(cell, tuple) else (cell, cell)) == f


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_coarsen_lowest_cell_and_flags(dtype):
    z = np.array([[3, 1, 5], [2, 4, np.nan], [7, 8, 9]], dtype)
    assert np.array_equal(coarsen(z, 2), np.array([[1, 5], [7, 9]], np.float32))
    flags = np.zeros((3, 3), bool)
    flags[1, 2] = True
    assert np.array_equal(coarsen_flags(flags, 2, (3, 3)), [[False, True], [False, False]])
    assert coarsen_flags(None, 2, (3, 3)) is None


def test_block_allowance():
    """t plus the slope's rise over the diagonal of a block (f - 1 cells) or of two blocks (2 f - 1)."""
    assert block_allowance(0.5, 1.0, (1.0, 1.0), 2) == pytest.approx(0.5 + 2 ** 0.5)
    assert block_allowance(0.5, 1.0, (1.0, 1.0), 2, blocks=2) == pytest.approx(0.5 + 3 * 2 ** 0.5)
    assert block_allowance(0.5, 0.0, (0.5, 0.5), 4) == 0.5


def test_expand_mask_rules():
    """Blocks of 2 x 2 cells, t = 0.5 m on level ground. Upper left, ground: a cell 3 m above the rest is an
    object. Upper right, a low block: its lowest cell is low, so is the cell 5.9 m below the ground around, the
    cells on the ground are ground. Lower right, an object block whose lowest cell is on the ground (the
    object's edge runs through it): that cell is ground, the roof's cells objects, no height no data."""
    z = np.array([[0, 0, -6, -5.9],
                  [0, 3, 0, 0],
                  [0, 0, 0.2, 5],
                  [0, 0, 5, np.nan]], np.float32)
    grid = CoarseGrid(z, (1.0, 1.0), 2, 0.5, 0.0)
    assert np.array_equal(grid.zc, np.array([[0, -6], [0, 0.2]], np.float32))
    mc = np.array([[G, L], [G, B]], np.uint8)
    assert np.array_equal(grid.expand_mask(mc), [[G, G, L, L],
                                                 [G, B, G, G],
                                                 [G, G, G, B],
                                                 [G, G, B, N]])
    # without ground around, a low block's other cells are objects (nothing to be low against)
    assert np.array_equal(grid.expand_mask(np.array([[B, L], [B, B]], np.uint8))[:2, 2:], [[L, B], [B, B]])


def test_expand_mask_keeps_a_steep_bank():
    """On a 45 degree bank (slope 1) the cells of a ground block stand up to 1.41 m above its lowest cell: within
    the allowance of the terrain's 90th-percentile slope; without that slope, where a ground block above
    continues the bank (every block but the top corner's), the cells are ground too."""
    x = np.arange(6, dtype=np.float32)
    z = np.add.outer(x, x) * np.float32(0.5)                    # rises 0.5 m a cell along rows and columns
    mc = np.full((3, 3), G, np.uint8)
    assert (CoarseGrid(z, (1.0, 1.0), 2, 0.5, 0.71).expand_mask(mc) == G).all()
    flat = CoarseGrid(z, (1.0, 1.0), 2, 0.5, 0.0).expand_mask(mc)
    assert (flat[:4, :4] == G).all() and flat[5, 5] == B
    # a cell raised above every ground block around is an object
    z[3, 3] += 3.0
    assert CoarseGrid(z, (1.0, 1.0), 2, 0.5, 0.71).expand_mask(mc)[3, 3] == B


def test_coarse_path_classifies_as_at_1_m():
    """A 1 m scene given at 0.5 m (each cell repeated over 2 x 2): the members run on its 1 m grid, derive the same
    parameters and the vote classifies every cell as at 1 m; the log states the factor."""
    s = make_scene("city", (96, 96), seed=3)
    one = pipeline.run_array("dtm", s.dsm, 1.0)
    fine = pipeline.run_array("dtm", np.repeat(np.repeat(s.dsm, 2, axis=0), 2, axis=1), 0.5)
    assert one.info["params"]["coarse_factor"] == 1 and "coarse_rule" not in one.info
    assert fine.info["params"]["coarse_factor"] == 2
    assert "2 x 2 block (1 m cells, coarsening factor f = 2)" in fine.info["coarse_rule"]
    assert fine.info["params"]["members"] == one.info["params"]["members"]
    assert np.array_equal(fine.mask, np.repeat(np.repeat(one.mask, 2, axis=0), 2, axis=1))


def test_blocked_equals_one_pass_on_the_coarse_path():
    s = make_scene("city", (128, 160), cell_size=0.5, seed=5, nodata_holes=True)
    one = pipeline.run_array("dtm", s.dsm, 0.5)
    params = dict(one.info["params"])
    assert params["coarse_factor"] == 2
    assert dtm_method.dtm_halo(params, (0.5, 0.5)) % (2 * 64) == 0     # the members' alignment on the coarse grid
    blk = pipeline.run_array("dtm", s.dsm, 0.5, block=40)
    assert blk.info["blocks"] > 1
    assert np.array_equal(one.mask, blk.mask)
    assert np.array_equal(one.extras["confidence"], blk.extras["confidence"])
