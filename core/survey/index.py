"""The tile index of a survey: which rasters, where each lies on the survey's grid, and
the checks that refuse a bad survey before any work.

A survey is given as several rasters, a VRT over them, or a folder holding them. Every
tile is opened with :func:`core.grid.open_dsm` (single band, north-up, readable); then
the set is checked as a whole: one CRS, one cell size, origins on one grid (a whole
number of cells apart), no two tiles overlapping, no VRT source missing. Each failed
check names the tiles.
"""
import math
import os
import re
from dataclasses import dataclass

import numpy as np

from .. import grid, pipeline
from . import io, record

#: Extensions of the rasters a folder is scanned for.
RASTER_EXTENSIONS = (".tif", ".tiff", ".img", ".asc", ".sdat", ".nc")
#: Relative tolerance on cell sizes and on origins (in cells) between tiles.
GRID_TOLERANCE = 1e-6


@dataclass(frozen=True)
class Tile:
    """One input tile and its place on the survey's grid.

    Attributes
    ----------
    name : str
        The file name without its extension; names the tile's outputs.
    path : str
        The raster.
    window : tuple of int
        ``(r0, r1, c0, c1)`` of the tile on the survey's grid (half-open).
    nodata : float or None
        The tile's declared nodata value.
    geotransform : tuple
        The tile's own GDAL geotransform (its outputs get it).
    z_to_m : float
        Metres per height unit of the tile's CRS.
    scale, offset, dtype : the band's scale and offset (heights = stored value x scale + offset)
        and GDAL data type, which set the nodata of the tile's DTM (:func:`.grid.float_output_nodata`)
    unit_type : the height unit the tile's band states (:attr:`.grid.DSMInfo.unit_type`), or ""
    """
    name: str
    path: str
    window: tuple
    nodata: object
    geotransform: tuple
    z_to_m: float = 1.0
    scale: float = 1.0
    offset: float = 0.0
    dtype: str = "Float32"
    unit_type: str = ""

    @property
    def shape(self):
        return (self.window[1] - self.window[0], self.window[3] - self.window[2])

    @property
    def cells(self):
        return self.shape[0] * self.shape[1]


@dataclass
class TileIndex:
    """The checked tiles of a survey and its grid.

    Attributes
    ----------
    tiles : list of Tile
        In reading order (north to south, west to east).
    shape : (rows, cols)
        The survey's bounding grid.
    geotransform : tuple
        GDAL geotransform of the survey's grid (origin at its upper-left corner).
    crs_wkt : str
    vrt_nodata : float, str or None
        The nodata value of the survey VRT (cells no tile covers).
    """
    tiles: list
    shape: tuple
    geotransform: tuple
    crs_wkt: str
    vrt_nodata: object = None

    @property
    def cells(self):
        """Cells of the tiles (not of the bounding grid)."""
        return sum(t.cells for t in self.tiles)


def list_inputs(inputs):
    """The tile paths of a survey given as rasters, one VRT or one folder.

    Parameters
    ----------
    inputs : str or list of str
        Several rasters; or one ``.vrt`` (its sources are the tiles); or one folder (every
        raster of :data:`RASTER_EXTENSIONS` directly in it, sorted by name, but hidden files:
        work files, and the ``._t00.tif`` AppleDouble files macOS leaves beside each tile on a
        shared drive, which are no rasters).

    Returns
    -------
    list of str
        Absolute paths; missing ones are kept so that :func:`index_tiles` can name them.
    """
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]
    if any(not str(p).strip() for p in inputs):    # an unset variable in a script: the current folder's rasters
        raise ValueError(f"an input path is empty: give the tiles' rasters, a VRT or a folder (an empty path would "
                         f"be the current folder, {os.getcwd()!r}).")
    check_on_disk(inputs)
    inputs = [os.path.abspath(str(p)) for p in inputs]
    if not inputs:
        raise ValueError("no input tile was given: pass rasters, a VRT or a folder of rasters.")
    if len(inputs) == 1 and os.path.isdir(inputs[0]):
        folder = inputs[0]
        if os.path.isfile(record.record_path(folder)):
            raise ValueError(f"the folder {folder!r} holds the outputs of a survey run ({record.NAME}), not "
                             "tiles: give the folder of the input tiles (their paths are in its run.json).")
        found = sorted(os.path.join(folder, f) for f in os.listdir(folder)   # hidden: work files, macOS's ._t.tif
                       if f.lower().endswith(RASTER_EXTENSIONS) and ".partial-" not in f and not f.startswith("."))
        if not found:    # the message named the command line's --input, also in QGIS (INPUT_FOLDER)
            below = sorted(f for f in os.listdir(folder) if not f.startswith(".")
                           and os.path.isdir(os.path.join(folder, f))
                           and any(g.lower().endswith(RASTER_EXTENSIONS) and not g.startswith(".")
                                   for g in os.listdir(os.path.join(folder, f))))
            raise ValueError(f"the folder {folder!r} holds no raster ({', '.join(RASTER_EXTENSIONS)}) "
                             + (f"of its own; its folder(s) {', '.join(below[:5])} do: give the folder that holds "
                                "the tiles themselves (its subfolders are not read)." if below else
                                "directly in it (its subfolders are not read): give the folder that holds the "
                                "tiles."))
        return found
    if len(inputs) == 1 and inputs[0].lower().endswith(".vrt"):
        if not os.path.exists(inputs[0]):
            raise ValueError(f"the VRT {inputs[0]!r} does not exist. Check the path.")
        found = io.vrt_sources(inputs[0])
        check_on_disk(found)
        if not found:
            raise ValueError(f"the VRT {inputs[0]!r} names no source raster.")
        return found
    dirs = [p for p in inputs if os.path.isdir(p) or p.lower().endswith(".vrt")]
    if dirs:
        raise ValueError(f"{', '.join(dirs)}: give one folder or one VRT alone, or a list of rasters.")
    return inputs


def check_on_disk(paths):
    """ValueError naming the first of ``paths`` that is a GDAL virtual file (``/vsimem/``, ``/vsizip/``,
    ``/vsicurl/``, ...) rather than a file on disk: a survey's tasks run in worker processes that read their
    tiles by path, and a tile in GDAL's memory (``/vsimem/``, a layer a script or plugin made there) exists in
    this process alone. Such a tile was reported "missing" (no file of that name on disk) with "check the
    path", which could not help."""
    virtual = [str(p) for p in paths if re.match(r"^/vsi[a-z0-9_]+(/|$)", str(p).replace("\\", "/"))]
    if not virtual:
        return
    first = virtual[0]
    more = f" (and {len(virtual) - 1} more)" if len(virtual) > 1 else ""
    if first.replace("\\", "/").startswith("/vsimem"):
        raise ValueError(f"the tile {first!r}{more} lives in this process's memory (GDAL's /vsimem/), which the "
                         "survey's worker processes cannot read: save the tiles to files in a folder first "
                         "(gdal_translate, or Export > Save As) and give those.")
    raise ValueError(f"the tile {first!r}{more} is a GDAL virtual file ({first.split('/')[1]}), not a file on "
                     "disk: a survey reads its tiles from files; extract or download them to a folder first and "
                     "give that folder.")


def _short(paths, n=8):
    names = [os.path.basename(p) for p in paths]
    return ", ".join(names[:n]) + (f" and {len(names) - n} more" if len(names) > n else "")


def index_tiles(inputs):
    """Open and check the tiles of a survey; return its :class:`TileIndex`.

    Raises
    ------
    ValueError
        Before any work, naming the tiles: missing or unreadable tiles, tiles of another
        CRS, cell size, data type or scale and offset (one VRT holds them all), tiles off the
        survey's grid, overlapping tiles, two tiles of the same name (their outputs would collide),
        one file given twice.
    """
    paths = list_inputs(inputs)
    missing = [p for p in paths if not os.path.exists(p)]
    if missing:
        one = [inputs] if isinstance(inputs, (str, os.PathLike)) else list(inputs)
        from_vrt = len(one) == 1 and str(one[0]).lower().endswith(".vrt")
        raise ValueError(f"{len(missing)} tile(s) are missing: {_short(missing)}. " + (
            "Restore them or rebuild the VRT without them." if from_vrt else
            f"No such file ({missing[0]}): check the path{'s' if len(missing) > 1 else ''}."))
    first, twice = {}, []
    for p in paths:             # one file named twice (./t.tif and t.tif, a link to it, two layers of it)
        real = grid.file_identity(p)
        if real in first:
            twice.append((first[real], p))
        first.setdefault(real, p)
    if twice:
        a, b = twice[0]
        also = f" (and as {b}, the same file)" if b != a else ""
        raise ValueError(f"{len(twice)} tile(s) are given twice: {a}{also}. Give each tile once.")
    infos, bad = [], []
    for p in paths:
        try:
            infos.append(grid.open_dsm(p))
        except grid.SeveralBands as exc:          # a survey has no BAND parameter
            bad.append(f"{os.path.basename(p)} (it has {exc.bands} bands: a tile holds one, its heights; extract "
                       "the height band (gdal_translate -b) first)")
        except ValueError as exc:
            bad.append(f"{os.path.basename(p)} ({exc})")
    if bad:
        raise ValueError(f"{len(bad)} tile(s) cannot be used: " + "; ".join(bad[:5]))
    names = [os.path.splitext(os.path.basename(p))[0] for p in paths]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"several tiles are named {', '.join(dup)}: each tile's outputs are named after it; "
                         "rename them or filter the folders separately.")
    ref = infos[0]
    pipeline.check_cell_size(ref.cell_size_m)       # the others share it (checked below)
    other_crs = [i.path for i in infos[1:] if not io.same_crs(i.crs_wkt, ref.crs_wkt)]
    if other_crs:
        other = grid.open_dsm(other_crs[0]).crs_wkt
        fix = ("Give the tiles without one their CRS (gdal_edit.py -a_srs) first." if not (other and ref.crs_wkt)
               else "Reproject them to one CRS (gdalwarp -t_srs) first.")
        raise ValueError(f"the tiles are in different CRSs: {_short(other_crs)} ({io.crs_label(other)}) differ "
                         f"from {os.path.basename(ref.path)} ({io.crs_label(ref.crs_wkt)}). {fix}")
    gts = np.array([i.geotransform for i in infos], float)
    flipped = [i.path for i, g in zip(infos, gts) if g[1] < 0 or g[5] > 0]
    if flipped:                # gdalbuildvrt takes north-up grids only (it skips the others)
        raise ValueError(f"tiles {_short(flipped)} are stored south-up (rows from south to north) or east to "
                         "west: a survey's mosaic takes north-up tiles. Write them north-up (gdalwarp) first.")
    dx, dy = gts[0, 1], gts[0, 5]
    other_cell = [i.path for i, g in zip(infos, gts)
                  if abs(g[1] - dx) > GRID_TOLERANCE * abs(dx) or abs(g[5] - dy) > GRID_TOLERANCE * abs(dy)]
    if other_cell:
        g = other_cell[0]
        raise ValueError(f"the tiles have different cell sizes: {_short(other_cell)} "
                         f"({abs(grid.open_dsm(g).geotransform[1]):.6g} x {abs(grid.open_dsm(g).geotransform[5]):.6g}) "
                         f"differ from {os.path.basename(ref.path)} ({abs(dx):.6g} x {abs(dy):.6g}). Resample them "
                         "to one cell size (gdalwarp -tr) first.")
    # a VRT holds one data type and one scale and offset: gdalbuildvrt leaves other tiles out
    other_type = [i.path for i in infos[1:] if i.dtype != ref.dtype]
    if other_type:
        raise ValueError(f"the tiles have different data types: {_short(other_type)} "
                         f"({grid.open_dsm(other_type[0]).dtype}) differ from {os.path.basename(ref.path)} "
                         f"({ref.dtype}). Convert them to one type (gdal_translate -ot Float32 -unscale) first.")
    other_scale = [i.path for i in infos[1:] if (i.scale, i.offset) != (ref.scale, ref.offset)]
    if other_scale:
        o = grid.open_dsm(other_scale[0])
        raise ValueError(f"the tiles have different scales or offsets: {_short(other_scale)} "
                         f"(x {o.scale:.6g} + {o.offset:.6g}) differ from {os.path.basename(ref.path)} "
                         f"(x {ref.scale:.6g} + {ref.offset:.6g}). Store them alike (gdal_translate -ot Float32 "
                         "-unscale) first.")
    other_unit = [i.path for i in infos[1:] if not math.isclose(i.z_to_m, ref.z_to_m, rel_tol=1e-9)]
    if other_unit:       # one CRS, but bands stating different height units (GDAL's unit type)
        o = grid.open_dsm(other_unit[0])
        raise ValueError(f"the tiles' heights are in different units: {_short(other_unit)} "
                         f"('{o.unit_type or 'the CRS unit'}', {o.z_to_m:.6g} m) differ from "
                         f"{os.path.basename(ref.path)} ('{ref.unit_type or 'the CRS unit'}', {ref.z_to_m:.6g} m). "
                         "Store them in one unit (gdal_edit.py -units, gdal_translate -scale) first.")
    x0 = gts[:, 0].min() if dx > 0 else gts[:, 0].max()
    y0 = gts[:, 3].max() if dy < 0 else gts[:, 3].min()
    cols_f = (gts[:, 0] - x0) / dx
    rows_f = (gts[:, 3] - y0) / dy
    c0, r0 = np.rint(cols_f), np.rint(rows_f)
    off = (np.abs(cols_f - c0) > 1e-3) | (np.abs(rows_f - r0) > 1e-3)
    if off.any():
        shifted = [i.path for i, o in zip(infos, off) if o]
        raise ValueError(f"tiles {_short(shifted)} are not on the grid of "
                         f"{os.path.basename(ref.path)}: their origins are not a whole number of cells apart. "
                         "Resample them onto one grid (gdalwarp -tap) first.")
    r0, c0 = r0.astype(np.int64), c0.astype(np.int64)
    r1 = r0 + np.array([i.shape[0] for i in infos])
    c1 = c0 + np.array([i.shape[1] for i in infos])
    pairs = _overlaps(r0, r1, c0, c1)
    if pairs:
        txt = "; ".join(f"{os.path.basename(paths[a])} and {os.path.basename(paths[b])}" for a, b in pairs[:5])
        more = f" and {len(pairs) - 5} more pair(s)" if len(pairs) > 5 else ""
        raise ValueError(f"tiles overlap: {txt}{more}. Each cell must come from one tile: clip the overlaps "
                         "(or build the VRT from tiles that only touch).")
    order = np.lexsort((c0, r0))
    tiles = [Tile(names[k], paths[k], (int(r0[k]), int(r1[k]), int(c0[k]), int(c1[k])), infos[k].nodata,
                  tuple(infos[k].geotransform), infos[k].z_to_m, infos[k].scale, infos[k].offset,
                  infos[k].dtype, infos[k].unit_type) for k in order]
    gt = (float(x0), float(dx), 0.0, float(y0), 0.0, float(dy))
    return TileIndex(tiles, (int(r1.max()), int(c1.max())), gt, ref.crs_wkt, _vrt_nodata(infos))


def _overlaps(r0, r1, c0, c1):
    """Pairs ``(i, j)`` of rectangles that share a cell: a sweep over the columns (each tile
    is compared with the tiles starting before it ends), vectorised per tile."""
    order = np.argsort(c0, kind="stable")
    cs = c0[order]
    pairs = []
    for k, i in enumerate(order):
        stop = int(np.searchsorted(cs, c1[i], side="left"))
        cand = order[k + 1:stop]
        if cand.size == 0:
            continue
        hit = cand[(r0[cand] < r1[i]) & (r0[i] < r1[cand])]
        pairs += [(int(min(i, j)), int(max(i, j))) for j in hit]
    return sorted(pairs)


def _vrt_nodata(infos):
    """The survey VRT's nodata: the tiles' common value; NaN for float tiles without one
    or with different ones; the type's minimum for integer tiles without one."""
    values = {None if v is None else float(v) for v in (i.nodata for i in infos)}
    if len(values) == 1 and None not in values:
        v = values.pop()
        return "nan" if math.isnan(v) else v
    if all(i.dtype.startswith("Float") for i in infos):
        return "nan"
    if len(values - {None}) > 1:
        raise ValueError("the integer tiles declare different nodata values: give them one value "
                         "(gdal_translate -a_nodata) first.")
    limits = {"Byte": 0, "UInt16": 0, "Int16": -32768, "UInt32": 0, "Int32": -2147483648}
    v = (values - {None}).pop() if values - {None} else limits.get(infos[0].dtype, -32768)
    return float(v)
