"""A whole survey of tiles through one filter, on Dask distributed, seamless and resumable.

National and commercial DSMs come as thousands of tiles. :func:`run_survey` filters them
as if they were one raster:

* **Tile index** (:mod:`.index`): the tiles (rasters, a VRT or a folder) are opened and
  checked before any work: one CRS, one cell size, one grid, no overlap, no missing tile.
* **Parameters once** (:mod:`.plan`): derived from the whole survey when small, else from
  central crops of tiles spread over it; logged and kept in ``run.json``.
* **Halo reads**: each task reads its tile plus the method's halo from the neighbours
  through a VRT of the survey, so each tile's mask is that of a single pass over the
  mosaic; the DTM is filled on the same window (its seam difference to a single pass is
  measured by ``benchmarks/scale.py``).
* **Engine** (:mod:`.engine`): a Dask ``LocalCluster`` on this machine's cores, or an
  existing cluster's scheduler.
* **Nothing lost** (:mod:`.record`): tile outputs are written under temporary names and
  renamed when complete, recorded in ``run.json`` (rewritten atomically) only then; a rerun
  with the same arguments (and plugin version) does only the tiles not recorded.
"""
from .engine import INSTALL_HINT, have_dask, require_dask
from .index import Tile, TileIndex, index_tiles, list_inputs
from .run import check_output_folder, check_survey_relief, parse_params, run_survey
from .task import output_names

__all__ = ["INSTALL_HINT", "Tile", "TileIndex", "check_output_folder", "check_survey_relief", "have_dask",
           "index_tiles", "list_inputs", "output_names", "parse_params", "require_dask", "run_survey"]
