"""Writing rasters with GDAL: outputs on the input's grid, in the format their extension names.

Outputs are created on the same grid, written block by block to a hidden work file and moved
into place only when the run succeeds (:class:`OutputSet`); stale work files of killed runs are
removed; the mask gets its 4-code colour table and a QGIS style.
"""
import contextlib
import contextvars
import functools
import math
import os
import re
import stat
import tempfile
import uuid

import numpy as np

from ..codes import MASK_CODES, MASK_COLOURS
from ..common import Cancelled, pid_alive, report, sub_progress, write_failed
from .read import OUTPUT_TILE, gdal, need_gdal, osr, without_side_files

#: Raster formats the outputs are written in, by file extension: (GDAL driver, most bands or
#: None, name for messages). A run writes a tiled GeoTIFF work file; the other formats (and the
#: cloud-optimised GeoTIFF) are copied from it with the driver's CreateCopy once the run succeeded.
OUTPUT_FORMATS = {
    ".tif": ("GTiff", None, "GeoTIFF"), ".tiff": ("GTiff", None, "GeoTIFF"),
    ".img": ("HFA", None, "ERDAS Imagine"),
    ".sdat": ("SAGA", 1, "SAGA grid"),
    ".asc": ("AAIGrid", 1, "Arc/Info ASCII grid"),
    ".nc": ("netCDF", 1, "netCDF"),
    ".gpkg": ("GPKG", 1, "GeoPackage"),
}

#: Extensions GDAL could name but the outputs refuse, with the reason.
REFUSED_FORMATS = {
    ".vrt": "a VRT only points at other rasters; write a GeoTIFF and build the VRT from it (gdalbuildvrt)",
    ".xyz": "XYZ text loses the nodata cells (GDAL reads them back as 0)",
    ".sgrd": "a .sgrd file is the header of a SAGA grid: name its .sdat file (the .sgrd is written beside it)",
}

#: Extension of the work files: GDAL identifies a GeoTIFF by its bytes, so the name (hidden,
#: ``.<output name>.<pid>-<id>.partial``) is what tells people it is not a result.
PARTIAL_SUFFIX = ".partial"
_PARTIAL_RE = re.compile(r"\.(?P<stem>.*)\.(?P<pid>\d{10})-[0-9a-f]{8}\.partial(?P<rest>\..*)?")
_TAG_BYTES = len(".0000000000-00000000.partial".encode())
#: room kept in a work file's name for the extension and sidecars of a copy (.sdat, .aux.xml)
_SIDECAR_BYTES = 16
_LIVE = set()        # work files of this process still being written

_WRITE_OPTIONS = contextvars.ContextVar("bare_earth_write_options", default=((), False))


def output_formats_text():
    """The formats offered, for messages: 'GeoTIFF (.tif, .tiff), ERDAS Imagine (.img), ...'."""
    need_gdal()
    names = {}
    for ext, (drv, _, name) in OUTPUT_FORMATS.items():
        if gdal.GetDriverByName(drv) is not None:
            names.setdefault(name, []).append(ext)
    return ", ".join(f"{n} ({', '.join(e)})" for n, e in names.items())


def output_extensions():
    """Extensions (without the dot) the outputs can be written in with this GDAL."""
    need_gdal()
    return [e[1:] for e, (drv, _, _) in OUTPUT_FORMATS.items() if gdal.GetDriverByName(drv) is not None]


def _name_max(folder):
    try:
        return int(os.pathconf(folder, "PC_NAME_MAX"))
    except (OSError, ValueError):
        return 255


#: Files a format writes beside its main file, named after its root (``x.asc`` -> ``x.prj``).
_SIDECARS = {"AAIGrid": (".prj",), "SAGA": (".sgrd", ".prj")}


def output_files(path, styled=False):
    """Every file writing the raster output ``path`` creates or replaces: the file, its
    ``.aux.xml``, the sidecars of its format (an ASCII grid's ``.prj``, a SAGA grid's ``.sgrd``
    and ``.prj``) and, for a ``styled`` output (a mask), the ``.qml`` style QGIS loads with it."""
    path = os.path.abspath(str(path))
    root = os.path.splitext(path)[0]
    try:
        drv, _ = _output_format(path)
    except ValueError:
        drv = None
    files = [path, path + ".aux.xml"] + [root + ext for ext in _SIDECARS.get(drv, ())]
    return files + ([root + ".qml"] if styled else [])


def _output_format(path, bands=1):
    """(driver name, format name) of an output path, or ValueError naming the formats offered."""
    ext = os.path.splitext(str(path))[1].lower()
    if not ext:
        return "GTiff", "GeoTIFF"
    if ext in REFUSED_FORMATS or ext not in OUTPUT_FORMATS or gdal.GetDriverByName(OUTPUT_FORMATS[ext][0]) is None:
        why = REFUSED_FORMATS.get(ext, "GDAL cannot write it here")
        raise ValueError(f"cannot write the output {str(path)!r} as '{ext}': {why}. Formats offered: "
                         f"{output_formats_text()}; choose one of these extensions.")
    drv, most, name = OUTPUT_FORMATS[ext]
    if most is not None and bands > most:
        raise ValueError(f"the output {str(path)!r} has {bands} bands, but a {name} ('{ext}') holds {most}: "
                         "write it as a GeoTIFF (.tif) or ERDAS Imagine (.img) file.")
    return drv, name


def check_output_path(path, bands=1, styled=False):
    """Check an output path before any work: format, folder, name length, the files beside it.

    ``styled``: the output is a mask, written with a ``.qml`` style (:func:`output_files`).

    Raises
    ------
    ValueError
        For a format not offered (naming the ones that are), a format holding fewer bands than
        the output, a missing or unwritable folder (naming it), a folder given as the file or
        standing where a file written beside it goes (its ``.aux.xml``, its format's sidecars,
        a mask's ``.qml``: found only once the work was done), a file name longer than the
        file system allows (for a mask, with its ``.aux.xml``), or a path beginning or ending with
        a blank.
    """
    need_gdal()
    _refuse_blank_ends(path)
    raw, path = str(path), os.path.abspath(str(path))
    _refuse_folder(raw, os.path.join(path, "dtm.tif"))
    _output_format(path, bands)
    check_side_files(path, styled, raw)
    check_output_folder(path)
    if styled:   # a mask's class names live in its .aux.xml, which GDAL leaves out without a word when too long
        folder, base = os.path.split(path)
        limit, aux = _name_max(folder), len((base + ".aux.xml").encode())
        if aux > limit:
            raise ValueError(f"the output file name is {len(base.encode())} bytes long: the mask's class names go "
                             f"to {base + '.aux.xml'!r} beside it, {aux} bytes, and the file system of {folder!r} "
                             f"allows {limit}: choose a name of at most {limit - 8} bytes.")
    check_geopackage_replaceable(path)


def check_side_files(path, styled=False, raw=None):
    """ValueError when a file writing the output ``path`` puts beside it (:func:`output_files`: its
    ``.aux.xml``, its format's sidecars, a mask's ``.qml``) stands there as a folder, or exists read-only
    (or as no regular file): found only once the work was done (a traceback, the raster already in place)."""
    raw = str(path) if raw is None else raw
    for side in output_files(path, styled)[1:]:
        if os.path.isdir(side):
            raise ValueError(f"the output {raw!r} writes {os.path.basename(side)!r} beside it, but {side!r} is a "
                             "folder: move or rename that folder, or give the output another name.")
        try:
            check_replaceable(side)
        except ValueError:
            raise ValueError(f"the output {raw!r} writes {os.path.basename(side)!r} beside it, but {side!r} exists "
                             "and is read-only (or no regular file): make it writable, delete it, or give the output "
                             "another name.") from None


def check_geopackage_replaceable(path):
    """ValueError when ``path`` is an existing GeoPackage holding anything but the raster table
    the output writes (named after the file): writing the output replaces the whole file, so
    its other layers would be lost (QGIS projects keep many layers in one GeoPackage)."""
    if os.path.splitext(str(path))[1].lower() != ".gpkg" or not os.path.isfile(path):
        return
    table = os.path.splitext(os.path.basename(str(path)))[0]
    names = []
    try:
        with without_side_files():
            ds = gdal.OpenEx(str(path), gdal.OF_READONLY | gdal.OF_RASTER | gdal.OF_VECTOR)
            if ds is not None:
                names = [ds.GetLayer(i).GetName() for i in range(ds.GetLayerCount())]
                subs = ds.GetSubDatasets() or []
                names += [sub.rsplit(":", 1)[-1] for sub, _ in subs]
                if not subs and ds.RasterCount:
                    names.append(ds.GetMetadataItem("IDENTIFIER") or table)
            ds = None
    except RuntimeError:
        raise ValueError(f"the output {str(path)!r} exists and is no GeoPackage GDAL can read: writing the output "
                         "would replace it; choose another file.") from None
    others = sorted(set(n for n in names if n != table))
    if others:
        raise ValueError(f"the output {str(path)!r} is an existing GeoPackage that holds other layers "
                         f"({', '.join(others)}); writing the output replaces the whole file: choose another file "
                         "(to add a raster to a GeoPackage, write a GeoTIFF and run gdal_translate -of GPKG -co "
                         "APPEND_SUBDATASET=YES -co RASTER_TABLE=<name> on it).")


def check_output_file(path, example="output.txt"):
    """Check an output file of any kind (a report, a table, a point file) before any work: not
    a folder (the message suggests ``example`` inside it), its folder exists and takes files, its
    name fits (:func:`check_output_folder`).

    Raises
    ------
    ValueError
        Naming the folder given as the file, or the folder's problem.
    """
    _refuse_blank_ends(path)
    raw, path = str(path), os.path.abspath(str(path))
    _refuse_folder(raw, os.path.join(path, example))
    check_output_folder(path)


def _refuse_folder(path, example):
    """A folder given as an output file: one that exists, or a path ending in a separator (typed as
    the folder to write in, which would be written as a file of the folder's name)."""
    if os.path.isdir(path) or path.endswith(("/", os.sep)):
        raise ValueError(f"the output {path!r} is a folder: give a file name in it (e.g. {example!r}).")


def check_output_cells(path, geotransform):
    """Check that an output's format holds the input's cells: a SAGA grid (``.sdat``) has
    square cells only.

    Raises
    ------
    ValueError
        Naming the cell size and the formats that hold it.
    """
    need_gdal()
    drv, name = _output_format(path)
    dx, dy = abs(float(geotransform[1])), abs(float(geotransform[5]))
    if drv == "SAGA" and not math.isclose(dx, dy, rel_tol=1e-9):
        raise ValueError(f"the output {str(path)!r} is a {name}, which holds square cells only, but the input's "
                         f"cells are {dx:g} x {dy:g}: write it as a GeoTIFF (.tif) or ERDAS Imagine (.img) file.")


def _linear_unit(srs):
    """(metres per unit, unit name) of a CRS's horizontal axes; (None, 'degree') when geographic."""
    if srs.IsGeographic():
        return None, "degree"
    return float(srs.GetLinearUnits()), srs.GetLinearUnitsName()


@functools.lru_cache(maxsize=32)
def _crs_copy_problem(drv, crs_wkt, geotransform):
    """None, or why a raster in ``crs_wkt`` copied from a GeoTIFF work file into driver ``drv``
    (as :meth:`OutputSet.commit` writes every format but GeoTIFF) is not where the input is:
    GDAL fails to write its CRS (netCDF on an oblique Mercator CRS, EPSG:2056), leaves it out,
    or writes another unit (a GeoPackage names a transverse Mercator in kilometres on the
    parameters of a UTM zone EPSG:326xx, in metres). Tried on a 2 x 2 raster in a temporary folder."""
    folder = tempfile.mkdtemp(prefix="bare-earth-crs-")
    ext = next(e for e, (d, _, _) in OUTPUT_FORMATS.items() if d == drv)
    messages = []
    try:
        with _quiet_gdal(messages):        # side files on, as for the outputs (a CRS may live in .aux.xml)
            work = os.path.join(folder, "probe.tif")
            ds = gdal.GetDriverByName("GTiff").Create(work, 2, 2, 1, gdal.GDT_Float32)
            ds.SetGeoTransform(geotransform)
            ds.SetProjection(crs_wkt)
            ds.GetRasterBand(1).Fill(1.0)
            ds = None
            gdal.ErrorReset()
            try:
                out = gdal.GetDriverByName(drv).CreateCopy(os.path.join(folder, "probe" + ext), gdal.Open(work))
                if out is None:
                    raise RuntimeError("")
                out = None
                back = gdal.Open(os.path.join(folder, "probe" + ext))
                written = back.GetProjection() or ""
                back = None
            except RuntimeError as exc:
                why = str(exc).strip() or gdal.GetLastErrorMsg().strip() or "\n".join(messages).strip()
                return f"GDAL cannot write its CRS in that format ({(why or 'GDAL gave no reason').splitlines()[0]})"
    finally:
        for name in os.listdir(folder):
            os.remove(os.path.join(folder, name))
        os.rmdir(folder)
    if not written:
        return "GDAL writes it in that format without its CRS"
    given, got = osr.SpatialReference(), osr.SpatialReference()
    given.ImportFromWkt(crs_wkt)
    got.ImportFromWkt(written)
    (f0, u0), (f1, u1) = _linear_unit(given), _linear_unit(got)
    if (f0 is None) != (f1 is None) or (f0 is not None and not math.isclose(f0, f1, rel_tol=1e-9)):
        return (f"GDAL writes its CRS ({given.GetName()}, in {u0}) in that format as {got.GetName()} "
                f"(in {u1}): the output would not lie where the input does")
    return None


def check_output_crs(path, crs_wkt, geotransform=(0.0, 1.0, 0.0, 2.0, 0.0, -1.0)):
    """Check before any work that an output written as ``path``'s format keeps the input's CRS
    ``crs_wkt`` (a GeoTIFF always does: its work file is written with it). ValueError naming the
    CRS, what GDAL does with it, and the formats to write instead."""
    need_gdal()
    drv, name = _output_format(path)
    if not crs_wkt or drv == "GTiff":
        return
    why = _crs_copy_problem(drv, str(crs_wkt), tuple(float(v) for v in geotransform))
    if why:
        raise ValueError(f"the output {str(path)!r} is a {name}, but {why}. Write it as a GeoTIFF (.tif), "
                         "which keeps the CRS.")


def _refuse_blank_ends(path):
    """ValueError for an output path beginning or ending with a space, a tab or a line break (a name
    copied with the space after it, a line read from a list with its line break): invisible in the
    messages that followed ("cannot write it as '.tif '", "the folder '/work/ /data' does not exist")."""
    text = str(path)
    if text != text.strip():
        where = "ends" if text[-1:].isspace() else "begins"
        raise ValueError(f"the output {text!r} {where} with a blank (a space, a tab or a line break, e.g. copied with "
                         f"the name or read from a list): give it without, {text.strip()!r}.")


def _refuse_virtual(path):
    """ValueError for a GDAL virtual path (``/vsimem/``, ``/vsizip/``) given as an output."""
    given = str(path).replace("\\", "/")
    if re.match(r"^/vsi[a-z0-9_]+(/|$)", given):   # was "the output folder '/vsimem' does not exist"
        raise ValueError(f"the output {str(path)!r} is a GDAL virtual file ({given.split('/')[1]}): outputs are "
                         "written as work files on disk and moved into place when complete; give a path on disk "
                         "(or a temporary output).")


def check_output_folder(path):
    """Check that the folder of an output file ``path`` exists and takes new files, and that the
    file's name fits the file system; ValueError naming the folder otherwise."""
    _refuse_virtual(path)
    path = os.path.abspath(str(path))
    folder, base = os.path.split(path)
    if os.path.exists(folder) and not os.path.isdir(folder):
        raise ValueError(f"the output's folder {folder!r} is a file, not a folder: choose a file name in a "
                         "folder.")
    if not os.path.isdir(folder):
        raise ValueError(f"the output folder {folder!r} does not exist: create it or choose another folder.")
    check_folder_takes_files(folder)
    limit = _name_max(folder)
    if len(base.encode()) > limit:
        raise ValueError(f"the output file name is {len(base.encode())} bytes long; the file system of "
                         f"{folder!r} allows {limit}: choose a shorter name.")
    check_replaceable(path)


def check_folder_takes_files(folder, made=None):
    """ValueError naming ``folder`` when a new file cannot be created in it (read-only, an immutable
    folder, a read-only file system): probed with a real file, since ``os.access`` says yes to root.
    ``made``: the folder the outputs go to, still to be created inside ``folder`` (the message names
    both)."""
    try:  # a real file: os.access says yes to root on a read-only or virtual file system
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".bare-earth-probe-"):
            pass
    except OSError as exc:
        where = f" (the output folder {made!r} would be created in it)" if made else ""
        raise ValueError(f"the output folder {folder!r}{where} is not writable ({exc.strerror}): choose a folder "
                         "you can write to.") from None


def check_output_dir(path):
    """ValueError naming the folder when the output folder ``path`` (created when it does not exist, with
    the folders above it) cannot receive files: an existing file, a file on its path, a new folder's name
    longer than the file system allows, or the folder, or the nearest existing folder above a new one,
    taking no new file (:func:`check_folder_takes_files`), or a GDAL virtual path, or one beginning or ending
    with a blank."""
    _refuse_blank_ends(path)
    _refuse_virtual(path)
    path = os.path.abspath(str(path))
    if os.path.exists(path) and not os.path.isdir(path):
        raise ValueError(f"the output folder {path!r} is an existing file, not a folder: choose a folder "
                         "(a new one is created).")
    parent = path          # the folder itself, or the nearest folder above it, where it is created
    while not os.path.isdir(parent) and os.path.dirname(parent) != parent:
        parent = os.path.dirname(parent)
    below = os.path.join(parent, os.path.relpath(path, parent).split(os.sep)[0])
    if parent != path and os.path.exists(below):
        raise ValueError(f"the output folder {path!r} cannot be created: {below!r} is a file, not a folder. "
                         "Choose another output folder.")
    limit = _name_max(parent)
    long = [n for n in os.path.relpath(path, parent).split(os.sep) if len(n.encode()) > limit] if parent != path else []
    if long:
        raise ValueError(f"the output folder's name {long[0]!r} is {len(long[0].encode())} bytes long; the file system "
                         f"of {parent!r} allows {limit}: choose a shorter name.")
    check_folder_takes_files(parent, None if parent == path else path)


def folder_ignores_case(folder):
    """True when the file system of ``folder`` (or of its nearest existing parent) takes two names
    differing only in case for one file (Windows, macOS, a FAT or SMB share mounted on Linux): a file
    created there is found under its name in swapped case. False when that cannot be told (a folder
    that takes no file). POSIX leaves case to the file system: a probe file is the portable test.
    """
    folder = os.path.abspath(str(folder))
    while not os.path.isdir(folder) and os.path.dirname(folder) != folder:
        folder = os.path.dirname(folder)
    return _ignores_case(os.path.realpath(folder))


@functools.lru_cache(maxsize=64)
def _ignores_case(folder):
    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".bare-earth-case-") as probe:
            name = os.path.basename(probe.name)
            return os.path.exists(os.path.join(folder, name.swapcase()))
    except OSError:
        return False


def file_identity(path):
    """A key two paths of one file share, to refuse an output that is an input under another name.

    An existing file: its device and inode, shared by every name of it (``./t.tif``, a symbolic or
    hard link, and on a file system that ignores case ``T.TIF`` for ``t.tif``), which comparing
    resolved paths misses. A file not yet written: its folder's device and inode and its name, case
    folded where the folder ignores case (:func:`folder_ignores_case`: two outputs ``A.tif`` and
    ``a.tif`` are one file there); its resolved path when the folder does not exist either.
    """
    path = os.path.abspath(str(path))
    try:
        st = os.stat(path)
        return (st.st_dev, st.st_ino)
    except OSError:
        pass
    folder, base = os.path.split(path)
    try:
        st = os.stat(folder)
    except OSError:
        return (os.path.realpath(path),)
    return (st.st_dev, st.st_ino, base.casefold() if folder_ignores_case(folder) else base)


def check_replaceable(path):
    """ValueError when ``path`` exists and may not be written (read-only, or locked as an
    immutable file): the run would end, after its work, unable to replace it; or when it is no
    regular file (a device such as ``/dev/null``, a named pipe, a socket), which writing the
    output would delete and replace by a file."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        mode = None
    if mode is not None and not stat.S_ISREG(mode) and not stat.S_ISDIR(mode):
        raise ValueError(f"the output {str(path)!r} exists and is not a regular file (a device, a pipe or a socket): "
                         "writing the output would replace it. Choose a file name (an output you do not want can "
                         "be left out or written as a temporary output).")
    # a link leading nowhere (its file deleted) is replaced like a missing file: not read-only
    if os.path.exists(path) and not os.path.isdir(path) and not os.access(path, os.W_OK):
        raise ValueError(f"the output {str(path)!r} exists and is read-only: make it writable, delete it, or "
                         "choose another file name.")


def _creation_option_specs(driver):
    """{NAME: [allowed values] or None} from a driver's creation option list."""
    import xml.etree.ElementTree as ET
    text = gdal.GetDriverByName(driver).GetMetadataItem("DMD_CREATIONOPTIONLIST") or ""
    if not text:
        return {}
    specs = {}
    for opt in ET.fromstring(text).iter("Option"):
        values = [v.text.upper() for v in opt.iter("Value") if v.text]
        specs[opt.get("name", "").upper()] = values or None
    return specs


#: GeoTIFF creation options in the COG driver's words (QGIS's compression profiles are GeoTIFF
#: options: "COMPRESS=DEFLATE|PREDICTOR=2|ZLEVEL=9"): key -> (COG key, {GeoTIFF value: COG value}).
_COG_SPELLING = {"PREDICTOR": ("PREDICTOR", {"1": "NO", "2": "STANDARD", "3": "FLOATING_POINT"}),
                 "ZLEVEL": ("LEVEL", {}), "ZSTD_LEVEL": ("LEVEL", {}), "LZMA_PRESET": ("LEVEL", {}),
                 "JPEG_QUALITY": ("QUALITY", {}), "WEBP_LEVEL": ("QUALITY", {})}


def _as_cog_options(opts):
    """GeoTIFF spellings of ``opts`` as the COG driver takes them: PREDICTOR=2 is STANDARD, ZLEVEL
    is LEVEL, ..., TILED=YES goes (a COG is tiled), square BLOCKXSIZE/BLOCKYSIZE are BLOCKSIZE."""
    out, block = [], {}
    for o in opts:
        key, _, value = o.partition("=")
        k = key.upper()
        if k == "TILED" and value.upper() in ("YES", "TRUE", "ON", "1"):
            continue
        if k in ("BLOCKXSIZE", "BLOCKYSIZE"):
            block[k] = value
            continue
        if k in _COG_SPELLING:
            name, values = _COG_SPELLING[k]
            o = f"{name}={values.get(value.upper(), value)}"
        out.append(o)
    if block:
        if len(set(block.values())) == 1:
            out.append(f"BLOCKSIZE={next(iter(block.values()))}")
        else:
            out += [f"{k}={v}" for k, v in block.items()]     # refused below: a COG's blocks are square
    return out


def parse_creation_options(text, cog=False):
    """``'COMPRESS=ZSTD|PREDICTOR=2'`` (QGIS's separator '|'; spaces and ';' too, as the tiles'
    PARAMETERS take them; spaces around '=' allowed) -> list of 'KEY=VALUE', checked against
    GDAL's GeoTIFF (or COG) driver; ValueError naming an unknown key or value.
    With ``cog``, GeoTIFF spellings (QGIS's profiles) are given in the COG driver's words first."""
    need_gdal()
    text = re.sub(r"\s*=\s*", "=", str(text or "").strip())
    opts = [t for t in re.split(r"[|;\s]+", text) if t]
    if cog:
        opts = _as_cog_options(opts)
    specs = _creation_option_specs("COG" if cog else "GTiff")
    for o in opts:
        key, sep, value = o.partition("=")
        if not sep or not key or not value:
            raise ValueError(f"creation option {o!r} is not KEY=VALUE (e.g. COMPRESS=ZSTD|PREDICTOR=2).")
        if specs and key.upper() not in specs:
            raise ValueError(f"the {'COG' if cog else 'GeoTIFF'} driver has no creation option {key!r}; "
                             f"it has {', '.join(sorted(specs))}.")
        allowed = specs.get(key.upper())
        if allowed and value.upper() not in allowed:
            raise ValueError(f"creation option {key}={value}: allowed values are {', '.join(allowed)}.")
    if opts:
        _probe_creation_options(opts, cog)
    return opts


#: What a creation option probe writes (64 x 64): every value of a UInt8 output (confidence
#: 0-100, any code) and a mask's codes 0, 1, 2, 255 mixed as in a mask (a lossy coder such as
#: LERC with MAX_Z_ERROR=1 keeps a ramp but not those), and heights for a Float32 output.
_PROBE_BYTE = np.vstack([np.arange(256, dtype=np.uint8).reshape(4, 64),
                         np.array([0, 1, 2, 255], np.uint8)[np.random.default_rng(0).choice(
                             4, (60, 64), p=[0.7, 0.2, 0.05, 0.05])]])
_PROBE_FLOAT = (np.arange(4096, dtype=np.float32).reshape(64, 64) * np.float32(0.037) + np.float32(312.5))


def _probe_creation_options(opts, cog=False):
    """Write a small Float32 and UInt8 raster in memory with the creation options the outputs
    will use (:func:`_gtiff_options`, :func:`_cog_options`), so that options GDAL refuses only
    when it creates a file (a tile width that is no multiple of 16, JPEG on Float32) are refused
    before any work, and so are options that change a UInt8 output's values (NBITS=1,
    PIXELTYPE=SIGNEDBYTE, DISCARD_LSB, JPEG): a mask's codes must be read back as written.
    ValueError naming the options and GDAL's reason. Returns the largest change of the Float32 probe's
    heights read back (0.0 when the options keep them exact: :func:`height_change`)."""
    change = 0.0
    base = f"/vsimem/bare-earth-probe-{uuid.uuid4().hex}"
    given = "|".join(opts)
    for dtype, data in (("Float32", _PROBE_FLOAT), ("Byte", _PROBE_BYTE)):
        work, out = f"{base}-{dtype}.tif", f"{base}-{dtype}-cog.tif"
        gdal.ErrorReset()
        messages = []
        try:
            with _quiet_gdal(messages):
                ds = gdal.GetDriverByName("GTiff").Create(work, 64, 64, 1, gdal.GetDataTypeByName(dtype),
                                                          options=_gtiff_options(dtype, () if cog else opts))
                ds.GetRasterBand(1).WriteArray(data)
                ds = None
                path = work
                if cog:
                    gdal.GetDriverByName("COG").CreateCopy(out, gdal.Open(work), options=_cog_options(dtype, opts))
                    path = out
                back = gdal.Open(path)
                read = back.GetRasterBand(1).ReadAsArray()
                kind = gdal.GetDataTypeName(back.GetRasterBand(1).DataType)
                pixeltype = back.GetRasterBand(1).GetMetadataItem("PIXELTYPE", "IMAGE_STRUCTURE")
                back = None
        except RuntimeError as exc:
            why = str(exc).strip() or "; ".join(messages) or "GDAL gave no reason"
            why = why.replace(work, "the output").replace(out, "the output")
            raise ValueError(f"GDAL cannot write a {dtype} output with the creation options {given!r}: "
                             f"{why}. Change or leave out the options.") from None
        finally:
            for f in (work, out):
                if gdal.VSIStatL(f) is not None:
                    gdal.Unlink(f)
        if dtype == "Float32":
            with np.errstate(invalid="ignore"):
                diff = np.abs(np.asarray(read, np.float64) - data)
            change = float(np.max(np.where(np.isfinite(diff), diff, np.inf)))
        if dtype == "Byte" and (kind != "Byte" or pixeltype or not np.array_equal(read, data)):
            raise ValueError(f"the creation options {given!r} change the values of a UInt8 output (the object "
                             "mask's codes 0, 1, 2, 255 would not be read back as written: NBITS, PIXELTYPE, "
                             "DISCARD_LSB and lossy compression such as JPEG, WEBP or LERC with a MAX_Z_ERROR of 1 "
                             "or more change them). Leave those options out.")
    return change


#: The heights of :func:`height_change`'s probe, metres.
PROBE_HEIGHTS_M = (float(_PROBE_FLOAT.min()), float(_PROBE_FLOAT.max()))


def height_change(opts, cog=False):
    """The largest change, metres, of heights of :data:`PROBE_HEIGHTS_M` written as a Float32 output with the
    creation options ``opts`` (checked ones, :func:`parse_creation_options`) and read back: 0.0 when they keep
    every height exact, more for lossy ones (NBITS=16: half floats, 0.25 m at 300-460 m; DISCARD_LSB; LERC with a
    MAX_Z_ERROR), which GDAL applies to a DTM without a word (DISCARD_LSB=20 wrote a DTM of one height).

    Examples
    --------
    >>> height_change(["COMPRESS=ZSTD"])
    0.0
    >>> 0.0 < height_change(["NBITS=16"]) < 0.3
    True
    """
    return _probe_creation_options(list(opts), cog) if opts else 0.0


@contextlib.contextmanager
def _quiet_gdal(messages):
    """GDAL's warnings collected in the list ``messages`` instead of printed (a probe's warnings
    are not the user's run's)."""
    def handler(level, _number, text):
        if level >= gdal.CE_Warning:
            messages.append(str(text).strip())
    gdal.PushErrorHandler(handler)
    try:
        yield messages
    finally:
        gdal.PopErrorHandler()


@contextlib.contextmanager
def write_options(creation_options=(), cog=False):
    """GeoTIFF creation options (``['COMPRESS=ZSTD', ...]``) and cloud-optimised GeoTIFF for the
    :class:`OutputSet` s made inside the block (the caller's thread)."""
    token = _WRITE_OPTIONS.set((tuple(creation_options or ()), bool(cog)))
    try:
        yield
    finally:
        _WRITE_OPTIONS.reset(token)


def _merge_options(defaults, given):
    out = {o.partition("=")[0].upper(): o for o in defaults}
    out.update({o.partition("=")[0].upper(): o for o in given})
    return list(out.values())


def _truncate_utf8(text, nbytes):
    return text.encode()[:max(0, nbytes)].decode("utf-8", "ignore")


def _work_stem(path):
    """The stem of ``path``'s work files: its name without extension, cut so that a work file's
    name (dot, stem, tag, a copy's extension and sidecar) stays within the file-name limit."""
    folder, base = os.path.split(os.path.abspath(str(path)))
    root = os.path.splitext(base)[0]
    return _truncate_utf8(root, _name_max(folder) - 1 - _TAG_BYTES - _SIDECAR_BYTES)


def _work_path(path):
    folder = os.path.dirname(os.path.abspath(str(path)))
    tag = f".{os.getpid():010d}-{uuid.uuid4().hex[:8]}{PARTIAL_SUFFIX}"
    return os.path.join(folder, f".{_work_stem(path)}{tag}")


def remove_stale_partials(path):
    """Remove the work files of earlier runs of the output ``path`` that were killed (their
    process is gone, or it is this process and the file is not being written), and the work
    files of any other output in its folder whose process is gone (a run killed by SIGTERM or
    a crash while writing another name there); returns their names. Only names of the writer's
    exact pattern (``.<stem>.<pid of 10 digits>-<8 hex>.partial`` and its sidecars) are
    touched. Also removes the ``<name>.partial-<id><ext>`` files of older versions."""
    path = os.path.abspath(str(path))
    folder, base = os.path.split(path)
    root, ext = os.path.splitext(base)
    stem = _work_stem(path)
    old = re.compile(re.escape(root) + r"\.partial-[0-9a-f]{8}" + re.escape(ext) + r"(\.aux\.xml)?")
    try:
        names = os.listdir(folder)
    except OSError:
        return []
    removed = []
    for name in names:
        full = os.path.join(folder, name)
        m = _PARTIAL_RE.fullmatch(name)
        if m:
            pid = int(m.group("pid"))
            work = full[:len(full) - len(m.group("rest") or "")]
            if work in _LIVE or (pid == os.getpid() and m.group("stem") != stem) or (
                    pid != os.getpid() and pid_alive(pid)):
                continue     # being written, this process's for another output, or its process runs
        elif not old.fullmatch(name):
            continue
        try:
            os.remove(full)
            removed.append(name)
        except OSError:
            pass
    return removed


def _remove_work(work):
    """Remove a work file and every file named after it (sidecars, copies)."""
    _LIVE.discard(work)
    folder, base = os.path.split(work)
    try:
        names = os.listdir(folder)
    except OSError:
        return
    for name in names:
        if name == base or name.startswith(base + "."):
            try:
                os.remove(os.path.join(folder, name))
            except OSError:
                pass


def _move_dataset(files, tmp_main, work, path):
    """Rename the files of a finished dataset ``tmp_main`` (named ``work`` + extension) to the
    output ``path``: the main file to ``path``, ``<tmp_main>.aux.xml`` to ``<path>.aux.xml``, and
    ``<work>.sgrd``-like sidecars to ``<root of path>.sgrd``. A sidecar whose final name would pass
    the file-name limit is dropped (the raster does not need it)."""
    root = os.path.splitext(path)[0]
    limit = _name_max(os.path.dirname(path))
    _delete_raster(path)
    for f in files:
        if f == tmp_main:
            new = path
        elif f.startswith(tmp_main):
            new = path + f[len(tmp_main):]
        elif f.startswith(work):
            new = root + f[len(work):]
        else:
            continue
        if f != tmp_main and len(os.path.basename(new).encode()) > limit:
            os.remove(f)
            continue
        os.replace(f, new)


#: GeoTIFF creation options of the work file: fast and readable anywhere; tiles compressed on
#: every core
_GTIFF_OPTIONS = ["TILED=YES", f"BLOCKXSIZE={OUTPUT_TILE}", f"BLOCKYSIZE={OUTPUT_TILE}", "COMPRESS=DEFLATE",
                  "ZLEVEL=1", "BIGTIFF=IF_SAFER", "NUM_THREADS=ALL_CPUS"]
_COG_OPTIONS = ["COMPRESS=DEFLATE", "BIGTIFF=IF_SAFER", "NUM_THREADS=ALL_CPUS"]


#: Uncompressed bytes of a GeoTIFF above which GDAL makes it a BigTIFF by itself when BIGTIFF=IF_NEEDED (the
#: classic TIFF's 32-bit offsets reach 4 GiB; GDAL keeps room for its directories and tiles' tables).
CLASSIC_TIFF_BYTES = 4_200_000_000


def check_tiff_size(path, shape, bands=1, dtype="Float32", options=(), cog=False):
    """ValueError, before any work, when the creation options keep a GeoTIFF output of ``shape`` cells of
    ``bands`` bands of ``dtype`` a classic TIFF (``BIGTIFF=NO``, or ``IF_NEEDED`` with compression: GDAL
    then never chooses BigTIFF) while its cells hold more than :data:`CLASSIC_TIFF_BYTES` uncompressed:
    GDAL refuses such a file when it creates it uncompressed, and a compressed one fails when its data
    passes 4 GB, once the work is done. Other formats and BIGTIFF=YES / IF_SAFER (the default): nothing."""
    given = {}
    for o in options or ():
        key, _, value = str(o).partition("=")
        given[key.strip().upper()] = value.strip().upper()
    big = given.get("BIGTIFF")
    compressed = given.get("COMPRESS", "DEFLATE") != "NONE"
    if big not in ("NO", "IF_NEEDED") or (big == "IF_NEEDED" and not compressed):
        return
    if path and _output_format(path, bands)[0] != "GTiff":
        return
    size = float(shape[0]) * float(shape[1]) * int(bands) * gdal.GetDataTypeSize(gdal.GetDataTypeByName(dtype)) / 8
    if size <= CLASSIC_TIFF_BYTES:
        return
    why = ("a classic TIFF holds at most 4 GB" if not compressed else
           "a classic TIFF holds at most 4 GB and compression may not bring it below (GDAL would fail when "
           "its data passes 4 GB, once the work is done)")
    raise ValueError(f"the output {str(path)!r} holds {size / 1e9:.2f} GB uncompressed ({shape[1]} x {shape[0]} "
                     f"cells of {dtype}{f' x {bands} bands' if bands > 1 else ''}) but the creation options say "
                     f"BIGTIFF={given['BIGTIFF']}{'' if compressed else ' COMPRESS=NONE'}: {why}. Leave BIGTIFF out "
                     "(IF_SAFER, the default) or give BIGTIFF=YES" + (" (a cloud-optimised GeoTIFF too)" if cog else "")
                     + ".")


def _integer_predictor(dtype, given):
    """The user's options for an output of ``dtype``: the floating-point predictor asked for the
    Float32 outputs (PREDICTOR=3 or FLOATING_POINT) becomes horizontal differencing on an
    integer output (a mask), which GDAL refuses it for."""
    if dtype.startswith("Float"):
        return list(given)
    out = []
    for o in given:
        key, _, value = o.partition("=")
        if key.upper() == "PREDICTOR" and value.upper() in ("3", "FLOATING_POINT"):
            o = f"{key}={'2' if value == '3' else 'STANDARD'}"
        out.append(o)
    return out


def _gtiff_options(dtype, given=()):
    """Creation options of a work file of ``dtype`` (:data:`_GTIFF_OPTIONS`, the floating-point
    predictor for Float32) with the user's ``given`` options over them."""
    opts = list(_GTIFF_OPTIONS) + (["PREDICTOR=3"] if dtype == "Float32" else [])
    return _merge_options(opts, _integer_predictor(dtype, given))


def _cog_options(dtype, given=()):
    """Creation options of a cloud-optimised GeoTIFF output of ``dtype``."""
    opts = _COG_OPTIONS + (["PREDICTOR=FLOATING_POINT"] if dtype == "Float32" else [])
    return _merge_options(opts, _integer_predictor(dtype, given))


@contextlib.contextmanager
def _writing(path):
    """GDAL calls writing the output ``path``: a GDAL error (a RuntimeError) becomes
    :func:`~bare_earth.core.common.write_failed`'s ValueError, so the algorithms report it and the
    output set discards its work files."""
    try:
        yield
    except RuntimeError as exc:
        raise write_failed(path, str(exc).strip() or gdal.GetLastErrorMsg().strip() or "GDAL gave no reason") \
            from None


def _close_written(item):
    """Flush and close an output's work file; an error while closing (the last blocks and the TIFF
    directory are written then, and GDAL reports it only as its last error) raises as a write error."""
    with _writing(item["path"]):
        item["ds"].FlushCache()
        gdal.ErrorReset()
        item["ds"] = None
        if gdal.GetLastErrorType() >= gdal.CE_Failure:
            raise RuntimeError(gdal.GetLastErrorMsg())


class OutputSet:
    """Output rasters on a DSM's grid, written to hidden work files until :meth:`commit`.

    Each output is written to a tiled GeoTIFF named ``.<name>.<pid>-<id>.partial`` beside it
    (within the file-name limit, whatever the output's length); work files of killed earlier
    runs of the same output are removed first. :meth:`commit` moves them into place, or copies
    them into the format the output's extension names (:data:`OUTPUT_FORMATS`; a
    cloud-optimised GeoTIFF with ``write_options(cog=True)``). A failed or cancelled run calls
    :meth:`discard` (also done by the context manager for an uncommitted set), so no
    half-written output looks valid.

    Use::

        with OutputSet(info) as out:
            out.add("dtm", path, "Float32", nodata=...)
            out.write("dtm", array, window)
            out.commit()
    """

    def __init__(self, info):
        need_gdal()
        self.info = info
        self._items = {}
        self._committed = False
        self._options, self._cog = _WRITE_OPTIONS.get()

    def add(self, key, path, dtype="Float32", bands=1, nodata=None, mask_style=False, descriptions=None,
            heights=False):
        """Create output ``key`` at ``path`` (written to a hidden work file beside it); an output of
        ``heights`` (a DTM, an nDSM) states the height unit the input's band states."""
        _refuse_folder(str(path), os.path.join(os.path.abspath(str(path)), f"{key}.tif"))
        path = os.path.abspath(str(path))
        if self.info.path and file_identity(self.info.path) == file_identity(path):    # under any name of it
            raise ValueError(f"the output {path!r} is the input raster: choose another file name.")
        for other, item in self._items.items():
            if file_identity(item["path"]) == file_identity(path):
                raise ValueError(f"the outputs {other!r} and {key!r} have one path {path!r}: give each its own file.")
        drv, _ = _output_format(path, bands)
        if drv == "GTiff":
            check_tiff_size(path, self.info.shape, bands, dtype, self._options, self._cog)
        check_output_cells(path, self.info.geotransform)
        check_output_crs(path, self.info.crs_wkt, self.info.geotransform)
        check_replaceable(path)
        check_side_files(path, mask_style)
        check_geopackage_replaceable(path)
        remove_stale_partials(path)
        work = _work_path(path)
        opts = _gtiff_options(dtype, self._options if drv == "GTiff" and not self._cog else ())
        rows, cols = self.info.shape
        try:
            ds = gdal.GetDriverByName("GTiff").Create(work, cols, rows, bands, gdal.GetDataTypeByName(dtype),
                                                      options=opts)
        except RuntimeError as exc:
            _remove_work(work)
            raise ValueError(f"cannot create the output {path!r}: {exc}. Check the folder and the "
                             "creation options.") from None
        _LIVE.add(work)
        if self.info.georeferenced:
            ds.SetGeoTransform(self.info.geotransform)
        elif self.info.gcps:   # the input's control points: drawn where the input is
            ds.SetGCPs([gdal.GCP(*g) for g in self.info.gcps], self.info.gcp_wkt)
        if self.info.crs_wkt:
            ds.SetProjection(self.info.crs_wkt)
        for k in range(1, bands + 1):
            b = ds.GetRasterBand(k)
            if nodata is not None:
                b.SetNoDataValue(float(nodata))
            if descriptions:
                b.SetDescription(descriptions[k - 1])
            if heights and self.info.unit_type:
                b.SetUnitType(self.info.unit_type)
        if mask_style:
            style_mask_band(ds.GetRasterBand(1))
        self._items[key] = dict(path=path, tmp=work, ds=ds, driver=drv, dtype=dtype, mask_style=mask_style,
                                nodata=nodata)
        return key

    def __contains__(self, key):
        return key in self._items

    def write(self, key, array, window=None):
        """Write ``array`` (2-D, or 3-D bands first) at ``window`` ``(r0, r1, c0, c1)``."""
        item = self._items[key]
        r0, c0 = (window[0], window[2]) if window else (0, 0)
        a = np.asarray(array)
        if a.ndim == 2:
            a = a[None]
        with _writing(item["path"]):
            for k in range(a.shape[0]):
                item["ds"].GetRasterBand(k + 1).WriteArray(a[k], c0, r0)

    def flush(self, progress=None):
        """Compress and write every block written so far (GDAL's threads do the work).

        Called after each finished window of a multi-window run, so the compression of
        the first windows overlaps the filtering of the later ones instead of all coming
        at :meth:`commit`. Windows must cover whole output tiles (256 x 256), or a tile
        flushed half-written is written twice. ``progress(fraction)`` (optional, may raise
        ``Cancelled``) after each output.
        """
        for i, item in enumerate(self._items.values()):
            with _writing(item["path"]):
                item["ds"].FlushCache()
            report(progress, (i + 1) / len(self._items))

    def commit(self, progress=None):
        """Close the work files and move (or copy into the output's format) them to their
        final paths; a ``.qml`` style beside each mask.

        ``progress(fraction)`` (optional) after each file is flushed and while copies are
        made; it may raise ``Cancelled`` until the first output is moved into place (then
        the work files and copies are removed as for :meth:`discard`, nothing is left).
        """
        items = list(self._items.values())
        n = max(1, len(items))
        for i, item in enumerate(items):
            _close_written(item)
            report(progress, 0.5 * (i + 1) / n)
        moves = []
        for i, item in enumerate(items):
            work = item["tmp"]
            if item["driver"] == "GTiff" and not self._cog:
                files = [work] + [work + ".aux.xml"] * os.path.exists(work + ".aux.xml")
                moves.append((files, work))
            else:
                moves.append(self._copy(item, sub_progress(progress, 0.5 + 0.5 * i / n,
                                                           0.5 + 0.5 * (i + 1) / n)))
        report(progress, 1.0)             # the last point a cancel stops at: the outputs move now
        for item in items:                # one output that cannot be replaced: none is (a matching set)
            check_replaceable(item["path"])
            check_side_files(item["path"], item["mask_style"])
        for item, (files, tmp_main) in zip(items, moves):
            work, path = item["tmp"], item["path"]
            try:
                _move_dataset(files, tmp_main, work, path)
            except OSError as exc:
                raise ValueError(f"cannot put the output {path!r} in place: {exc.strerror or exc}. Check the "
                                 "file and its folder.") from None
            if tmp_main != work:
                _remove_work(work)
            _LIVE.discard(work)
            if item["mask_style"]:
                write_mask_qml(os.path.splitext(path)[0] + ".qml")
        self._committed = True

    def _copy(self, item, progress=None):
        """Copy a finished work file into its output's format beside it (the copy's files
        are named after the work file until they are moved); returns ``(files, main file)``."""
        work, path, drv = item["tmp"], item["path"], item["driver"]
        cog = drv == "GTiff" and self._cog
        ext = os.path.splitext(path)[1] or ".tif"
        tmp_main = work + ext
        opts = _cog_options(item["dtype"], self._options) if cog else []
        if drv == "GPKG":   # the raster table named after the output, lossless tiles (PNG for bytes)
            opts = [f"RASTER_TABLE={os.path.splitext(os.path.basename(path))[0]}"] + \
                (["TILE_FORMAT=PNG"] if item["dtype"] == "Byte" else [])
        stopped = []

        def callback(fraction, _message, _data):
            try:
                report(progress, fraction)
            except Cancelled as exc:
                stopped.append(exc)
                return 0
            return 1

        vrt = None
        try:
            src = gdal.Open(work)
            if drv in _FINITE_NODATA_DRIVERS and item["nodata"] is not None and math.isnan(float(item["nodata"])):
                vrt = f"/vsimem/{os.path.basename(work)}.vrt"
                x0, dx, _, y0, _, dy = src.GetGeoTransform()
                src = gdal.Warp(vrt, src, format="VRT", srcNodata="nan", dstNodata=finite_text_nodata(src),
                                outputBounds=(x0, y0 + dy * src.RasterYSize, x0 + dx * src.RasterXSize, y0),
                                xRes=abs(dx), yRes=abs(dy), resampleAlg="near")
            out = gdal.GetDriverByName("COG" if cog else drv).CreateCopy(tmp_main, src, options=opts,
                                                                          callback=callback)
            if out is None:
                raise RuntimeError("the copy was stopped")
            out.FlushCache()
            files = out.GetFileList() or [tmp_main]
            out = src = None
        except RuntimeError as exc:
            out = src = None
            _remove_work(work)
            if stopped:
                raise stopped[0] from None
            raise ValueError(f"cannot write the output {path!r} as {drv}: {exc}") from None
        finally:
            if vrt is not None:
                gdal.Unlink(vrt)
        return files, tmp_main

    def discard(self):
        """Remove every work file (nothing is left that looks like a result)."""
        for item in self._items.values():
            item["ds"] = None
            _remove_work(item["tmp"])
        self._items = {}

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if not self._committed:
            self.discard()
        return False


def _delete_raster(path):
    """Remove an existing raster with its sidecars (by its own driver), or a plain file."""
    if not os.path.exists(path):
        return
    try:
        drv = gdal.IdentifyDriver(path)
        if drv is not None:
            drv.Delete(path)
            return
    except RuntimeError:
        pass
    os.remove(path)


def style_mask_band(band):
    """Give a mask band its palette: the mask codes' colours and names, every other entry
    unnamed (and transparent where the format keeps alpha; a TIFF palette of 8-bit data always
    holds 256 RGB entries, so QGIS is given the 4-class style by the .qml and the algorithms)."""
    ct = gdal.ColorTable()
    for code in range(256):
        ct.SetColorEntry(code, MASK_COLOURS.get(code, (0, 0, 0, 0)))
    band.SetRasterColorTable(ct)
    band.SetRasterColorInterpretation(gdal.GCI_PaletteIndex)
    names = [""] * 256
    for code, name in MASK_CODES.items():
        names[code] = name
    band.SetRasterCategoryNames(names)


def write_mask_qml(path):
    """Write a QGIS paletted style for the mask codes next to the mask raster."""
    entries = "\n".join(
        f'        <paletteEntry value="{code}" color="#{r:02x}{g:02x}{b:02x}" alpha="{a}" label="{MASK_CODES[code]}"/>'
        for code, (r, g, b, a) in MASK_COLOURS.items())
    qml = f"""<!DOCTYPE qgis PUBLIC 'http://mrcc.com/qgis.dtd' 'SYSTEM'>
<qgis version="3.22" styleCategories="Symbology">
  <pipe>
    <rasterrenderer type="paletted" band="1" opacity="1" alphaBand="-1" nodataColor="">
      <colorPalette>
{entries}
      </colorPalette>
    </rasterrenderer>
  </pipe>
</qgis>
"""
    with open(path, "w", encoding="utf-8") as f:
        f.write(qml)


#: Formats whose header carries the nodata value as text read by other software (ESRI's ASCII
#: grid, SAGA): a NaN nodata is written there as a finite value (:func:`finite_text_nodata`).
#: GeoPackage: its coverage table takes no NaN. ERDAS Imagine: GDAL keeps a NaN nodata there, but
#: every open of the file then warns "NaN converted to INT_MAX" (gdalinfo, QGIS's log).
_FINITE_NODATA_DRIVERS = ("AAIGrid", "SAGA", "GPKG", "HFA")
#: The finite nodata of those formats when the raster declares NaN (ESRI's convention).
TEXT_NODATA = -9999.0


def finite_text_nodata(ds):
    """The finite nodata an Arc/Info ASCII, SAGA or GeoPackage copy of the Float32 raster ``ds`` (NaN
    nodata) declares instead of NaN, which other software cannot read from the header (a GeoPackage
    cannot record it):
    :data:`TEXT_NODATA` (-9999), or, when the heights reach it, the next power of ten below
    the lowest height (-99999, ...), so no height is taken for nodata."""
    try:
        lo = ds.GetRasterBand(1).ComputeRasterMinMax(False)[0]
    except RuntimeError:            # no valid cell
        lo = math.inf
    value = TEXT_NODATA
    while math.isfinite(lo) and lo <= value:
        value = value * 10.0 - 9.0
    return value


#: numpy types of GDAL's integer band types (the others hold fractions: any height).
_INTEGER_TYPES = {"Byte": np.uint8, "Int8": np.int8, "UInt16": np.uint16, "Int16": np.int16,
                  "UInt32": np.uint32, "Int32": np.int32, "UInt64": np.uint64, "Int64": np.int64}


def _stored_heights_range(dtype, scale, offset):
    """The heights ``stored * scale + offset`` a band of GDAL type ``dtype`` can hold (low, high):
    every value for a type that is no integer."""
    kind = _INTEGER_TYPES.get(str(dtype))
    if kind is None:
        return -math.inf, math.inf
    lim = np.iinfo(kind)
    ends = sorted((float(lim.min) * scale + offset, float(lim.max) * scale + offset))
    return ends[0], ends[1]


def float_output_nodata(nodata, scale=1.0, offset=0.0, dtype="Float32"):
    """The nodata of the Float32 outputs (DTM, nDSM, filled surface) of an input declaring
    ``nodata``: the same value when float32 holds it as a finite number, else NaN (the
    convention of an input without a declared nodata). An input's nodata of +-inf (or one
    beyond float32, such as -1e300) is read as nodata like any other (:func:`to_surface`),
    but is no value to write: an output cell of +-inf is read as a height by tools that do
    not check the declared nodata, and float32 turns -1e300 into -inf. See
    :func:`nodata_not_kept`.

    The outputs hold heights, the input's stored values x ``scale`` + ``offset`` (its band's
    scale and offset), while its nodata is a stored value: when that value is also a height
    the band can hold (UInt16 with nodata 0, scale 0.01 and offset -100: 0 is the height of
    the stored 10000, sea level), the outputs declare the height of the nodata cells instead
    (0 x 0.01 - 100 = -100 m), which no valid cell has; they kept 0 and every cell at 0 m
    was read as nodata. A value no height can take (Int16 -32768 with scale 0.1 and offset
    100: heights -3176.8 to 3376.7) is kept."""
    if nodata is None or math.isnan(float(nodata)):
        return float("nan")
    v = float(nodata)
    if scale != 1.0 or offset != 0.0:
        lo, hi = _stored_heights_range(dtype, scale, offset)
        if lo <= v <= hi:
            v = v * scale + offset
    with np.errstate(over="ignore"):
        v = np.float32(v)
    return float(v) if np.isfinite(v) else float("nan")


def above_nodata(nodata):
    """The float32 value nearest above ``nodata`` that GDAL does not take for it. GDAL compares a float
    band's values with its nodata within a few units in the last place (``ARE_REAL_EQUAL``: closer than
    2 float32 epsilons of their sum; its mask bands and VRT mosaics do), so a value one float32 step above
    300 was read as nodata in a VRT of the tiles; this one is beyond twice that tolerance (about 3e-4 m
    at 300 m)."""
    nd = np.float32(nodata)
    eps = np.finfo(np.float32).eps
    v = nd
    for _ in range(64):
        with np.errstate(over="ignore"):    # above the largest float32 (ESRI's -3.4e38 negated): inf, quietly
            v = np.nextafter(v, np.float32(np.inf))
        if abs(float(v) - float(nd)) >= 4.0 * eps * abs(float(v) + float(nd)):
            break
    return v


def with_output_nodata(a, nodata):
    """Float32 heights ``a`` (changed in place) made ready to write with the declared ``nodata``: its
    NaN / inf cells set to ``nodata``, and its valid cells that hold ``nodata`` (a DTM cell interpolated
    to 300 m under a DSM declaring 300 as nodata: ground at 299 and 301 m around it), or a value GDAL
    takes for it, moved just above it (:func:`above_nodata`), so that no height is read back as nodata.
    Returns the number of cells moved. ``nodata`` NaN: nothing to do, 0."""
    if math.isnan(nodata):
        return 0
    nd = np.float32(nodata)
    up = above_nodata(nd)
    down = -above_nodata(-nd)
    hit = (a > down) & (a < up)
    n = int(np.count_nonzero(hit))
    if n:
        a[hit] = up
    np.copyto(a, nd, where=~np.isfinite(a))
    return n


def moved_off_nodata_message(n, nodata, what="DTM"):
    """The log line for :func:`with_output_nodata`'s ``n`` cells moved off ``nodata`` (None for none)."""
    if not n:
        return None
    return (f"{n} cell(s) of the {what} hold the declared nodata value {float(nodata):g} as a height: they are "
            f"written as {float(above_nodata(nodata)):.9g} (just above it) so that they are not read as nodata. "
            "The DSM's nodata lies among its heights: export it again with a nodata outside them (e.g. -9999).")


def nodata_not_kept(nodata, scale=1.0, offset=0.0, dtype="Float32"):
    """The log line saying the float outputs declare another nodata than the input's ``nodata``
    (:func:`float_output_nodata`: NaN, or the height of the nodata cells of a scaled band), or
    None when they keep it (or the input declares none)."""
    if nodata is None or math.isnan(float(nodata)):
        return None
    out = float_output_nodata(nodata, scale, offset, dtype)
    if math.isnan(out):
        return (f"The input's nodata value is {float(nodata):g}, which a Float32 output cannot carry as a finite "
                "value: the DTM and nDSM declare NaN as nodata instead (their nodata cells are NaN), as for an "
                "input without a declared nodata.")
    if out != float(np.float32(float(nodata))):
        return (f"The input's nodata value is the stored value {float(nodata):g}, which is also a height the band "
                f"can hold through its scale and offset: the DTM and nDSM, written as heights, declare the height "
                f"of the nodata cells, {out:g}, as their nodata instead.")
    return None


def write_array(path, array, geotransform, crs_wkt="", nodata=None, dtype=None, mask_style=False):
    """Write a whole array as a GeoTIFF (tests, demo and benchmarks)."""
    need_gdal()
    a = np.asarray(array)
    if a.ndim == 2:
        a = a[None]
    dtype = dtype or {np.dtype(np.uint8): "Byte", np.dtype(np.float64): "Float64",
                      np.dtype(np.int16): "Int16"}.get(a.dtype, "Float32")
    drv = gdal.GetDriverByName("GTiff")
    ds = drv.Create(str(path), a.shape[2], a.shape[1], a.shape[0], gdal.GetDataTypeByName(dtype),
                    options=["TILED=YES", "COMPRESS=DEFLATE"])
    ds.SetGeoTransform(tuple(geotransform))
    if crs_wkt:
        if isinstance(crs_wkt, int):
            srs = osr.SpatialReference()
            srs.ImportFromEPSG(crs_wkt)
            crs_wkt = srs.ExportToWkt()
        ds.SetProjection(crs_wkt)
    for k in range(a.shape[0]):
        b = ds.GetRasterBand(k + 1)
        if nodata is not None:
            b.SetNoDataValue(float(nodata))
        b.WriteArray(a[k])
    if mask_style:
        style_mask_band(ds.GetRasterBand(1))
    ds = None
    return str(path)
