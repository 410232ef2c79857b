"""The work of one tile, run on a Dask worker: read the tile and its halo from the survey
VRT, filter and fill the window (``pipeline.run_array``), keep the tile, write its DTM and
mask as COGs (each atomically), and return what the run record keeps about it.
"""
import os
import socket
import time
from dataclasses import dataclass

import numpy as np

from .. import grid, pipeline
from ..codes import GROUND, LOW, NODATA, OBJECT
from ..common import as_cell_size, as_surface
from . import io, plan


@dataclass(frozen=True)
class TileJob:
    """Everything a task needs besides its tile (sent once to every worker).

    Attributes
    ----------
    method : str
        Registered method id.
    params : dict
        The method's complete parameters as its resolve returned them (once for the survey);
        passed to ``Method.run`` as they are, as ``pipeline.run_file`` does for its blocks.
    vrt : str
        The survey VRT the windows are read from.
    out_dir : str
        Where the tile outputs go (a folder every worker sees at this path).
    halo : int
        The method's reach in cells.
    align : int
        Alignment of the windows' corners (:func:`plan.alignment`).
    shape : (rows, cols)
        The survey grid.
    cell_size : (dx, dy)
        Metres, of the survey (the single pass's).
    crs_wkt : str
    """
    method: str
    params: dict
    vrt: str
    out_dir: str
    halo: int
    align: int
    shape: tuple
    cell_size: tuple
    crs_wkt: str = ""


def peak_memory_mb():
    """Peak resident memory of this (worker) process in MB, or None where unknown.

    ``getrusage`` on Unix (``ru_maxrss``, kB on Linux); psutil's peak working set on Windows.
    """
    try:
        import resource
        return round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)
    except ImportError:
        pass
    try:
        import psutil  # installed with distributed
        peak = getattr(psutil.Process().memory_info(), "peak_wset", None)
        return round(peak / 2 ** 20, 1) if peak else None
    except ImportError:
        return None


def output_names(tile_name):
    """The DTM and mask file names of a tile."""
    return f"{tile_name}_dtm.tif", f"{tile_name}_mask.tif"


def filter_array(method, z, cell_size, params):
    """Filter a window with complete parameters and fill its DTM (no resolve on the window).

    The per-window step of the pipeline's blocks: ``Method.run`` with the parameters
    resolved once for the whole survey (a resolve on each window would derive other values
    per tile: seams) on the window with its empty cells enclosed by data filled
    (:func:`pipeline.fill_empty_cells`; the survey's halo covers that fill's reach), nodata
    cells coded 255, the method's own DTM when it returns a usable one, else
    :func:`pipeline.fill_dtm`.

    Returns
    -------
    mask : uint8 array, dtm : float32 array (NaN nodata), info : dict
    """
    meth = pipeline.as_method(method)
    z = as_surface(z)
    cell = as_cell_size(cell_size)
    res = meth.run(pipeline.fill_empty_cells(z, cell)[0], cell, progress=None, **params)
    mask = np.array(res.mask, dtype=np.uint8)
    if mask.shape != z.shape:
        raise RuntimeError(f"method {meth.name!r} returned a mask of shape {mask.shape} for a window of "
                           f"shape {z.shape}")
    valid = np.isfinite(z)
    mask[~valid] = NODATA
    dtm = None
    if res.dtm is not None:
        dtm = np.array(res.dtm, dtype=np.float32)
        if dtm.shape != z.shape or not np.isfinite(dtm[valid]).all():
            dtm = None
        else:
            dtm[~valid] = np.nan
    if dtm is None:
        dtm = pipeline.fill_dtm(z, mask)
    if dtm is None:                                   # no ground cell in the window
        dtm = np.full(z.shape, np.nan, np.float32)
    return mask, dtm, res.info


def filter_window(job, tile):
    """The tile's mask and DTM (metres, NaN nodata) from its window of the survey VRT.

    Returns
    -------
    mask : ndarray of uint8, dtm : ndarray of float32, info : dict, seconds read
    """
    t0 = time.perf_counter()
    outer, core = plan.tile_window(tile.window, job.shape, job.halo, job.align)
    z = grid.open_dsm(job.vrt).read(outer)
    t_read = time.perf_counter() - t0
    if not np.isfinite(z[core]).any():
        shape = tile.shape
        return np.full(shape, NODATA, np.uint8), np.full(shape, np.nan, np.float32), {}, t_read
    mask, dtm, info = filter_array(job.method, z, job.cell_size, job.params)
    return np.ascontiguousarray(mask[core]), np.ascontiguousarray(dtm[core]), info, t_read


def run_tile(job, tile):
    """Filter one tile and write its outputs; returns the tile's entry of the run record.

    The outputs are written under temporary names and renamed when complete
    (:func:`io.write_cog`), so a killed task leaves no file that looks finished.
    """
    start = time.time()
    t0 = time.perf_counter()
    mask, dtm, info, t_read = filter_window(job, tile)
    t_filter = time.perf_counter() - t0 - t_read
    t1 = time.perf_counter()
    # the DTM in the tile's height unit with its nodata; ground cells keep their stored values
    if tile.z_to_m != 1.0:
        dtm = dtm / np.float32(tile.z_to_m)
        raw = io.read_raw(tile.path, (0, tile.shape[0], 0, tile.shape[1]))
        if tile.scale != 1.0 or tile.offset != 0.0:    # stored values -> heights (the band's scale and offset)
            raw = (raw.astype(np.float64) * tile.scale + tile.offset).astype(np.float32)
        ground = mask == GROUND
        dtm[ground] = raw[ground]
    nodata = grid.float_output_nodata(tile.nodata, tile.scale, tile.offset, tile.dtype)
    dtm = dtm.astype(np.float32, copy=False)
    moved = grid.with_output_nodata(dtm, nodata)     # no height written as the nodata value
    dtm_name, mask_name = output_names(tile.name)
    io.write_cog(os.path.join(job.out_dir, dtm_name), dtm, tile.geotransform,
                 job.crs_wkt, nodata, unit_type=tile.unit_type)
    io.write_cog(os.path.join(job.out_dir, mask_name), mask, tile.geotransform, job.crs_wkt, NODATA,
                 mask_style=True)
    t_write = time.perf_counter() - t1
    counts = {name: int(np.count_nonzero(mask == code))
              for code, name in ((GROUND, "ground"), (OBJECT, "object"), (LOW, "low"), (NODATA, "nodata"))}
    return {"status": "done", "files": [dtm_name, mask_name], "cells": int(mask.size), "counts": counts,
            "seconds": round(time.perf_counter() - t0, 4), "read_s": round(t_read, 4),
            "filter_s": round(t_filter, 4), "write_s": round(t_write, 4), "start": start, "end": time.time(),
            "worker": f"{socket.gethostname()}:{os.getpid()}", "moved_off_nodata": moved,
            "peak_rss_mb": peak_memory_mb()}
