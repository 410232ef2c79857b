"""Point files: read text/LAS points into a :class:`PointCloud`, write classes back.

* reads ``x y z [class]`` text (spaces, tabs or commas; one header line allowed) and
  LAS/LAZ files (through ``laspy``, imported lazily) into a :class:`PointCloud`, with the
  CRS and its horizontal and vertical units,
* writes the labels back (:func:`write_points`): text with a class column, or LAS/LAZ with
  ASPRS codes keeping every other attribute of the input,
* reads one named column of a text file or one LAS dimension (:func:`read_column`).

GDAL's ``osr`` is used only to read the CRS of a LAS file or a ``crs`` argument.
"""
import copy
import io
import os
import re
import struct
import uuid
import warnings
from dataclasses import dataclass

import numpy as np

from .codes import GROUND, LOW, OBJECT
from .common import UTF16_BOMS, pid_alive, text_of, write_failed

__all__ = ["PointCloud", "read_points", "write_points", "prepare_points", "place_points",
           "read_column", "read_crs", "point_output_path", "import_laspy",
           "LAS_INSTALL_HINT", "ASPRS_FROM_CLASS", "POINT_EXTENSIONS", "part_path", "remove_stale_parts"]

#: File extensions written as LAS / as text.
LAS_EXTENSIONS = (".las", ".laz")
TEXT_EXTENSIONS = (".txt", ".csv", ".xyz", ".pts", ".asc")
POINT_EXTENSIONS = LAS_EXTENSIONS + TEXT_EXTENSIONS

#: The message given when laspy (or lazrs for LAZ) is missing.
LAS_INSTALL_HINT = ("Reading and writing LAS/LAZ point clouds needs the Python packages laspy "
                    "and lazrs: run `pip install laspy lazrs` with the Python that QGIS uses "
                    "(OSGeo4W Shell on Windows: `python -m pip install laspy lazrs`).")

#: ASPRS LAS classification codes written for the classes of :func:`classify_points`
#: (NODATA, points outside the DTM, keep the input's classification; 0 if it had none).
ASPRS_FROM_CLASS = {GROUND: 2, OBJECT: 1, LOW: 7}

#: The hidden work file of an output ``<name>`` (points, reports): ``.<name>.<pid of 10 digits>-<8 hex>.part``
#: plus the output's extension when the writer needs it (laspy compresses by it); moved into place once
#: written. The pid tells a later run whether the writer is gone (killed): :func:`remove_stale_parts`.
_PART_RE = re.compile(r"\.(?P<name>.*)\.(?P<pid>\d{10})-[0-9a-f]{8}\.part(\.[^.]*)?")
#: the same without a pid (versions before): ``.<name>.<8 hex>.part[.ext]``
_OLD_PART_RE = re.compile(r"\.(?P<name>.*)\.[0-9a-f]{8}\.part(\.[^.]*)?")
_PART_TAG_BYTES = len(".0000000000-00000000.part".encode())

# EPSG unit-of-measure codes of GeoTIFF keys (ProjLinearUnitsGeoKey 3076,
# VerticalUnitsGeoKey 4099) -> metres per unit.
_EPSG_UNITS = {9001: 1.0, 9002: 0.3048, 9003: 1200.0 / 3937.0, 9036: 1000.0,
               9005: 0.9143985307444408, 9014: 1.8288, 9030: 1852.0, 9096: 0.9144,
               9033: 20.1168, 9039: 20.1168, 9042: 0.201168}
_EPSG_UNIT_NAMES = {9001: "metre", 9002: "foot", 9003: "US survey foot", 9036: "kilometre",
                    9005: "Clarke's foot", 9014: "fathom", 9030: "nautical mile",
                    9096: "yard", 9033: "chain", 9039: "chain", 9042: "link"}


@dataclass
class PointCloud:
    """Points read from a file.

    Attributes
    ----------
    x, y, z : ndarray of float64
        Coordinates, in the file's units (see ``units_to_metre``).
    classification : ndarray of int32 or None
        The file's own class of each point (text: the 4th column, e.g. the ISPRS
        0 = bare earth / 1 = object; LAS: the ASPRS code, 2 = ground), or None.
    crs : str or None
        The coordinate reference system as WKT, when known.
    units_to_metre : float
        Metres per horizontal coordinate unit (1.0 for metres, 0.3048 for feet,
        0.30480060960121924 for US survey feet). 1.0 when unknown or geographic.
    z_units_to_metre : float
        Metres per z unit (the LAS vertical-units key, else the CRS's vertical unit,
        else ``units_to_metre``).
    attrs : object
        For LAS/LAZ: the ``laspy.LasData`` read, so :func:`write_points` keeps every
        attribute; for text: a dict with the header line and the delimiter.
    source_format : str
        ``"text"`` or ``"las"``.
    """
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    classification: np.ndarray = None
    crs: str = None
    units_to_metre: float = 1.0
    attrs: object = None
    source_format: str = "text"
    z_units_to_metre: float = None

    def __post_init__(self):
        if self.z_units_to_metre is None:
            self.z_units_to_metre = self.units_to_metre

    def __len__(self):
        return int(self.x.size)

    @property
    def extent(self):
        """``(xmin, ymin, xmax, ymax)`` of the points."""
        return (float(self.x.min()), float(self.y.min()), float(self.x.max()), float(self.y.max()))

    def ground_truth(self):
        """Boolean "is ground" from the file's classes (None when there are none).

        Text files follow the ISPRS filter-test convention (class 0 = bare earth); LAS/LAZ
        files the ASPRS one (class 2 = ground).
        """
        if self.classification is None:
            return None
        return self.classification == (2 if self.source_format == "las" else 0)


# --------------------------------------------------------------------------- reading
def read_points(path, crs=None):
    """Read a point cloud from a text/CSV file or a LAS/LAZ file.

    Parameters
    ----------
    path : str or path-like
        ``.las`` / ``.laz`` are read with laspy; anything else as text, one point per
        line: ``x y z`` or ``x y z class``, separated by spaces, tabs or commas. One header
        line is allowed (if it names the columns, e.g. ``X,Y,Z,Classification,Intensity`` or
        ``N,E,H`` / ``Northing,Easting,Elevation`` / ``lat,lon,alt``, the columns are picked by
        name, :func:`_axis_columns`); blank lines are skipped.
    crs : str, optional
        Overrides the file's CRS: anything GDAL understands (``"EPSG:25832"``, WKT,
        PROJ string). For text files without it, a sidecar ``<path>.prj`` or
        ``<stem>.prj`` is read when present.

    Returns
    -------
    PointCloud

    Raises
    ------
    ValueError
        Empty file, unparsable line (the message gives its line number), inconsistent
        columns, non-integer classes, unreadable CRS. ImportError when laspy is missing
        for a LAS/LAZ file (the message says how to install it).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ValueError(f"point file {path!r} does not exist; check the path.")
    ext = os.path.splitext(path)[1].lower()
    if ext in (".las", ".laz"):
        cloud = _read_las(path)
    else:
        cloud = _read_text(path)
        if crs is None:
            for prj in (path + ".prj", os.path.splitext(path)[0] + ".prj"):
                if os.path.isfile(prj):
                    with open(prj, encoding="utf-8", errors="replace") as fh:
                        crs = fh.read().strip() or None
                    break
    if crs is not None:
        wkt, h, v = _crs_units(crs)
        cloud.crs, cloud.units_to_metre, cloud.z_units_to_metre = wkt, h, v
    return cloud


_SEPARATORS = bytes.maketrans(b"\t,;\r\v\f\"", b"       ")   # newlines stay; a quoted field is its value
_NUMBER_BYTES = np.zeros(256, dtype=bool)
_NUMBER_BYTES[np.frombuffer(b"0123456789.+-eE \n", dtype=np.uint8)] = True
_CLASS_NAMES = ("class", "classification", "label", "cls", "c")
#: A header's names of the axes besides x, y, z (surveyors' N E H, a GPS's lat lon alt): the columns in any order.
_AXIS_NAMES = {"x": ("x", "e", "east", "easting", "lon", "long", "longitude"),
               "y": ("y", "n", "north", "northing", "lat", "latitude"),
               "z": ("z", "h", "height", "elevation", "elev", "alt", "altitude")}
# numpy >= 1.23 has a C loadtxt that validates while it parses (faster than fromstring)
_FAST_LOADTXT = tuple(int(v) for v in np.__version__.split(".")[:2]) >= (1, 23)


def _is_number(tok):
    try:
        float(tok)
        return True
    except ValueError:
        return False


def _read_text(path):
    """Read ``x y z [class]`` text quickly: one C-level parse of the whole file.

    numpy >= 1.23: ``np.loadtxt`` (C parser) on the text with every separator made a
    space; when it fails (or with older numpy), :func:`_parse_careful` parses with
    ``np.fromstring`` and finds the line at fault.
    """
    data = _utf8_bytes(path)
    if data.startswith(b"\xef\xbb\xbf"):  # UTF-8 byte-order mark
        data = b"   " + data[3:]
    _refuse_binary(path, data[:4096])
    flat = data.translate(_SEPARATORS)                   # every separator -> space
    m = re.search(rb"[^ \n]", flat)
    if m is None:
        raise ValueError(f"point file {path!r} is empty; it needs one point per line "
                         "(x y z or x y z class).")

    # Header: the first non-blank line, when it is not all numbers.
    a = flat.rfind(b"\n", 0, m.start()) + 1
    b = flat.find(b"\n", m.start())
    b = len(flat) if b < 0 else b
    first_tokens = flat[a:b].split()
    header, names, body_start = None, None, 0
    if not all(_is_number(t) for t in first_tokens):
        header = data[a:b].decode("utf-8", errors="replace").strip()
        names = _column_names(first_tokens)
        body_start = b
    body = flat[body_start:]
    if not body.strip():
        raise ValueError(f"point file {path!r} has a header line but no points.")

    table = None
    if _FAST_LOADTXT:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                table = np.loadtxt(io.BytesIO(body), dtype=np.float64, comments=None,
                                   ndmin=2, encoding=None)
        except ValueError:
            table = None
    if table is None:
        table = _parse_careful(path, data, flat, body_start)
    ncols = table.shape[1]
    head = data[body_start:body_start + 4096]
    # decimal commas: each value split in two at its comma (x y z: 6 columns; a whole class: 7), the
    # values separated by ';', tabs or spaces (a spreadsheet's export in a locale with decimal commas)
    between = re.search(rb"\d,\d+(;|\t|[ ]+)[-+]?\d", head)
    comma = (between is not None
             and ncols in ((2 * len(names), 2 * len(names) - 1) if names is not None else (6, 7, 8)))
    sep_name = {b";": "';'", b"\t": "tabs"}.get(between.group(1), "spaces") if comma else ""
    comma_hint = (f" The values seem to be written with decimal commas and separated by {sep_name}: write them "
                  "with decimal points." if comma else "")
    if names is not None and len(names) != ncols:
        raise ValueError(f"{path}: the header line names {len(names)} columns but the points "
                         f"have {ncols}; fix the header or remove it." + comma_hint)

    # Pick the columns.
    named = _axis_columns(path, header, names) if names is not None else None
    if named is not None:
        cols = named
        cls_col = next((names.index(c) for c in _CLASS_NAMES if c in names), None)
    else:
        if ncols not in (3, 4):
            raise ValueError(f"{path}: {ncols} values per line; expected 3 (x y z) or 4 "
                             "(x y z class), or a header line naming the x, y, z columns." + comma_hint)
        cols, cls_col = [0, 1, 2], (3 if ncols == 4 else None)

    x = np.ascontiguousarray(table[:, cols[0]])
    y = np.ascontiguousarray(table[:, cols[1]])
    z = np.ascontiguousarray(table[:, cols[2]])
    bad = ~(np.isfinite(x) & np.isfinite(y))
    if bad.any():
        ln, text = _row_line(data, body_start, int(np.flatnonzero(bad)[0]))
        raise ValueError(f"{path}: line {ln} has a non-finite x or y: {text!r}; remove it.")
    classification = None
    if cls_col is not None:
        c = table[:, cls_col]
        nonint = np.flatnonzero(~np.isfinite(c) | (c != np.round(c)))
        if nonint.size:
            ln, text = _row_line(data, body_start, int(nonint[0]))
            raise ValueError(f"{path}: line {ln}: the class column must hold whole "
                             f"numbers; got {c[nonint[0]]!r} in {text!r}."
                             + ("" if names is not None else " Without a header line the 4th column is read as "
                                "the class: to keep another value there, add a header line naming the columns "
                                "(e.g. x y z intensity)."))
        classification = c.astype(np.int32)
    delim = "\t" if b"\t" in head else (";" if b";" in head else ("," if b"," in head else " "))
    return PointCloud(x=x, y=y, z=z, classification=classification, crs=None,
                      units_to_metre=1.0, attrs={"header": header, "delimiter": delim},
                      source_format="text")


def _axis_columns(path, header, names):
    """The x, y, z columns a header line names (:data:`_AXIS_NAMES`: x y z itself first), or None to read
    them in the order x y z.

    A header naming the axes in another order (``N,E,H``, ``Northing,Easting,Elevation``, ``lat,lon,alt``)
    was read x y z by position: northings as eastings, the points mirrored about the diagonal and placed
    elsewhere without a word. ValueError when the header names an axis twice, or names some axes where the
    order x y z would read another.
    """
    found = {}
    for axis, synonyms in _AXIS_NAMES.items():
        exact = [i for i, n in enumerate(names) if n == axis]
        cols = exact[:1] or [i for i, n in enumerate(names) if n in synonyms]
        if len(cols) > 1:
            raise ValueError(f"{path}: the header line {header!r} names the {axis} axis {len(cols)} times ("
                             + ", ".join(repr(names[i]) for i in cols) + "): name its columns x, y, z (the others "
                             "anything else).")
        if cols:
            found[axis] = cols[0]
    if len(found) == 3 and len(set(found.values())) == 3:
        return [found["x"], found["y"], found["z"]]
    wrong = sorted((i, axis) for axis, i in found.items() if i != "xyz".index(axis))
    if wrong:
        raise ValueError(f"{path}: the header line {header!r} names " + " and ".join(
            f"column {i + 1} ({names[i]!r}) as {axis}" for i, axis in wrong) + ", but not all three axes, and read "
            "in the order x y z " + ("that column is" if len(wrong) == 1 else "those columns are") + " another "
            "axis: name the three (x y z, or easting northing height).")
    return None


def _utf8_bytes(path, size=-1):
    """The bytes of a text file (the first ``size`` of them, all when -1), UTF-16 text (with its
    byte-order mark: Excel's "Unicode Text", Windows PowerShell's ``>``) recoded to UTF-8, so
    that its NUL bytes are not taken for binary data."""
    with open(path, "rb") as fh:
        data = fh.read(size)
    if not data.startswith(UTF16_BOMS):
        return data
    if size >= 0:                          # a head, maybe cut inside a character
        return data.decode("utf-16", errors="replace").encode("utf-8")[:size]
    return text_of(data, path).encode("utf-8")


def _refuse_binary(path, head):
    """ValueError when the first bytes of a "text" point file hold a NUL byte (never in text)."""
    if b"\x00" in head:
        if os.path.splitext(str(path))[1].lower() in VECTOR_EXTENSIONS:
            raise ValueError(f"{path!r} is a vector layer, not a point file: export its points with their "
                             "heights as text first (Export > Save Features As: CSV with the layer option "
                             "GEOMETRY=AS_XYZ gives x, y, z columns) and give that file.")
        raise ValueError(f"{path!r} is not a text point file (it holds binary data): a raster DSM goes to "
                         "INPUT, not to the points; a LAS/LAZ file needs its .las or .laz extension.")


#: Vector formats a point layer is often kept in (binary: refused with how to export them).
VECTOR_EXTENSIONS = (".shp", ".gpkg", ".fgb", ".sqlite", ".gdb", ".dbf", ".shx")


def read_crs(path, crs=None):
    """The CRS and units of a point file without reading its points.

    Parameters
    ----------
    path : str or path-like
        LAS/LAZ (its header is read) or text (its sidecar ``.prj``, as :func:`read_points`).
    crs : str, optional
        Overrides the file's CRS, as in :func:`read_points`.

    Returns
    -------
    (wkt or None, metres per x/y unit, metres per z unit)

    Raises
    ------
    ValueError
        A missing file, a LAS/LAZ file laspy cannot open, a "text" file holding binary data.
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ValueError(f"point file {path!r} does not exist; check the path.")
    if crs is not None:
        return _crs_units(crs)
    if os.path.splitext(path)[1].lower() in (".las", ".laz"):
        laspy = import_laspy()
        try:
            with laspy.open(path) as fh:
                return _las_crs(fh.header)
        except (laspy.errors.LaspyException, ValueError, OSError, EOFError, struct.error) as exc:
            raise ValueError(f"{path!r} is not a readable LAS/LAZ file: {exc}") from exc
    _refuse_binary(path, _utf8_bytes(path, 4096))
    for prj in (path + ".prj", os.path.splitext(path)[0] + ".prj"):
        if os.path.isfile(prj):
            with open(prj, encoding="utf-8", errors="replace") as fh:
                text = fh.read().strip()
            return _crs_units(text) if text else (None, 1.0, 1.0)
    return None, 1.0, 1.0


def _row_line(data, body_start, row):
    """Error path: (1-based line number, text) of data row ``row`` (blank lines skipped)."""
    offset = data.count(b"\n", 0, body_start)
    k = -1
    for i, line in enumerate(data[body_start:].split(b"\n")):
        if line.strip():
            k += 1
            if k == row:
                return offset + i + 1, line.decode("utf-8", errors="replace").strip()[:120]
    return offset + 1, ""


def _parse_careful(path, data, flat, body_start):
    """Parse with ``np.fromstring`` and raise a ValueError naming the line at fault."""
    raw = np.frombuffer(data, dtype=np.uint8)
    nl = np.flatnonzero(raw == 10)                       # line ends
    arr = np.frombuffer(flat, dtype=np.uint8)
    sep = (arr == 32) | (arr == 10)
    start = ~sep
    start[1:] &= sep[:-1]
    start[:body_start] = False                           # the header's tokens
    tok = np.flatnonzero(start)                          # first byte of every token
    # tokens per line: tokens before each line end (one binary search per line)
    before = np.concatenate(([0], np.searchsorted(tok, nl), [tok.size]))
    if data.endswith(b"\n"):
        before = before[:-1]
    per_line = np.diff(before)
    filled = np.flatnonzero(per_line)                    # non-blank lines of the body

    counts = per_line[filled]
    ncols = int(counts[0])
    bad = np.flatnonzero(counts != ncols)
    if bad.size:
        ln = int(filled[bad[0]])
        raise ValueError(
            f"{path}: line {ln + 1} has {int(counts[bad[0]])} values but line "
            f"{int(filled[0]) + 1} has {ncols}; every line must have the same columns "
            f"(x y z or x y z class): {_line(data, nl, ln)!r}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        values = np.fromstring(flat[body_start:], dtype=np.float64, sep=" ")
    ntok = int(tok.size)
    # numpy stops quietly at the first unparsable value and may split "1.5.3" in two:
    # a count mismatch, letters other than an exponent (checked line by line, e.g. nan),
    # or a bad last line (where stopping early leaves the count right) are errors.
    suspect = np.zeros(0, dtype=np.int64)
    odd = np.flatnonzero(~_NUMBER_BYTES[arr[body_start:]])
    if odd.size:
        suspect = np.unique(np.searchsorted(nl, odd + body_start))
    suspect = np.append(suspect, filled[-1])
    if values.size != ntok or _first_bad_line(data, nl, suspect) is not None:
        ln = _first_bad_line(data, nl, filled if values.size != ntok else suspect)
        where = (f"line {ln + 1} is not numbers: {_line(data, nl, ln)!r}" if ln is not None
                 else "some value is not a plain number")
        raise ValueError(f"{path}: {where}. Every line after an optional header must be "
                         "x y z [class] numbers separated by spaces, tabs or commas.")
    return values.reshape(-1, ncols)


def _line(data, nl, ln):
    a = int(nl[ln - 1]) + 1 if ln > 0 else 0
    b = int(nl[ln]) if ln < nl.size else len(data)
    return data[a:b].decode("utf-8", errors="replace").strip()[:120]


def _first_bad_line(data, nl, filled):
    """The 0-based number of the first of ``filled`` lines that is not all numbers.

    A Python loop over lines: called on the error path, or on the few lines holding
    letters (``nan``, ``inf``) and the last line.
    """
    for ln in filled:
        for t in _line(data, nl, int(ln)).replace(",", " ").replace(";", " ").replace('"', " ").split():
            try:
                float(t)
            except ValueError:
                return int(ln)
            if "_" in t:   # float() takes "1_000", numpy does not
                return int(ln)
    # float() accepted everything (e.g. "1.5.3" splits into two numbers for numpy)
    for ln in filled:
        for t in _line(data, nl, int(ln)).replace(",", " ").replace(";", " ").replace('"', " ").split():
            if t.count(".") > 1 or "_" in t:
                return int(ln)
    return None


def import_laspy():
    """The ``laspy`` module; ImportError with :data:`LAS_INSTALL_HINT` when it is missing."""
    try:
        import laspy  # noqa: F401
    except ImportError as exc:
        raise ImportError(LAS_INSTALL_HINT) from exc
    return laspy


def _read_las(path):
    laspy = import_laspy()
    try:
        las = laspy.read(path)
    except laspy.errors.LaspyException as exc:
        msg = str(exc).lower()
        if "lazrs" in msg or "laszip" in msg or "backend" in msg:
            raise ImportError(f"cannot decompress {path!r} ({exc}). {LAS_INSTALL_HINT}") from exc
        raise ValueError(f"{path!r} is not a readable LAS/LAZ file: {exc}") from exc
    except (ValueError, OSError, EOFError, struct.error) as exc:   # truncated / corrupt
        raise ValueError(f"{path!r} is not a readable LAS/LAZ file (truncated or corrupt: "
                         f"{exc}); check the file.") from exc
    if las.header.point_count == 0 or len(las.points) == 0:
        raise ValueError(f"LAS file {path!r} has no points; pass a file with points.")
    wkt, h_units, v_units = _las_crs(las.header)
    return PointCloud(x=np.asarray(las.x, dtype=np.float64),
                      y=np.asarray(las.y, dtype=np.float64),
                      z=np.asarray(las.z, dtype=np.float64),
                      classification=np.asarray(las.classification, dtype=np.int32),
                      crs=wkt, units_to_metre=h_units, z_units_to_metre=v_units,
                      attrs=las, source_format="las")


def _las_crs(header):
    """(WKT or None, metres per x/y unit, metres per z unit) from a LAS header.

    Order: a non-empty OGC WKT VLR; else the GeoTIFF keys (ProjectedCSTypeGeoKey 3072,
    GeographicTypeGeoKey 2048); else laspy's ``parse_crs`` (needs pyproj). The GeoTIFF
    linear-units keys (3076 horizontal, 4099 vertical) win over the CRS's own unit:
    files like PDAL's mvk-thin.las declare a metre EPSG code with coordinates in US feet.
    """
    from osgeo import osr

    keys, wkt_string = {}, None
    for v in list(header.vlrs) + list(getattr(header, "evlrs", None) or []):
        kind = type(v).__name__
        if kind == "GeoKeyDirectoryVlr":
            for k in v.geo_keys:
                if k.tiff_tag_location == 0:
                    keys[int(k.id)] = int(k.value_offset)
        elif kind == "WktCoordinateSystemVlr":
            s = v.string.strip("\x00 \n") if isinstance(v.string, str) else ""
            if s:
                wkt_string = s
    srs = None
    if wkt_string:
        srs = osr.SpatialReference()
        if srs.SetFromUserInput(wkt_string) != 0:
            srs = None
    if srs is None:
        for key in (3072, 2048):
            code = keys.get(key)
            if code and 1024 <= code < 32767:
                cand = osr.SpatialReference()
                try:
                    if cand.ImportFromEPSG(code) == 0:
                        srs = cand
                        break
                except RuntimeError:
                    pass
    if srs is None:
        try:
            crs = header.parse_crs()
        except Exception:  # pyproj missing or unusable keys: no CRS
            crs = None
        if crs is not None:
            cand = osr.SpatialReference()
            if cand.SetFromUserInput(crs.to_wkt()) == 0:
                srs = cand
    h = v = None
    if srs is not None:
        srs.SetAxisMappingStrategy(osr.OAMS_TRADITIONAL_GIS_ORDER)
        key_unit = keys.get(3076)
        if key_unit in _EPSG_UNITS and srs.IsProjected():
            want = _EPSG_UNITS[key_unit]
            if abs(srs.GetLinearUnits() - want) > 1e-9 * want:
                # The key says the coordinates are in another unit than the EPSG code's:
                # rewrite the CRS in that unit (false easting/northing converted too).
                srs.SetLinearUnitsAndUpdateParameters(_EPSG_UNIT_NAMES[key_unit], want)
        h, v = _srs_units(srs)
    else:
        h = _EPSG_UNITS.get(keys.get(3076), 1.0)
    if keys.get(4099) in _EPSG_UNITS:
        v = _EPSG_UNITS[keys[4099]]
    return (srs.ExportToWkt() if srs is not None else None), h, (v if v is not None else h)


def _srs_units(srs):
    """(metres per horizontal unit, metres per vertical unit or None) of an osr CRS."""
    from .grid import vertical_unit_factor
    h = float(srs.GetLinearUnits()) if srs.IsProjected() else 1.0
    v = vertical_unit_factor(srs)
    return h, (v[0] if v else None)


def _crs_units(crs):
    """(WKT, metres per x/y unit, metres per z unit) of a user CRS string."""
    from osgeo import osr
    srs = osr.SpatialReference()
    try:
        ok = srs.SetFromUserInput(str(crs)) == 0
    except RuntimeError:
        ok = False
    if not ok:
        raise ValueError(f"cannot read the CRS {str(crs)[:80]!r}; give an EPSG code "
                         "(\"EPSG:25832\"), WKT or a PROJ string.")
    h, v = _srs_units(srs)
    return srs.ExportToWkt(), h, (v if v is not None else h)


# --------------------------------------------------------------------------- writing
def write_points(path, cloud, classes, decimals=None):
    """Write points with their classes.

    Parameters
    ----------
    path : str or path-like
        ``.las`` / ``.laz``: a LAS file (laspy). For a LAS input every attribute, the header
        and the VLRs (CRS) are kept and only ``classification`` changes, to ASPRS codes
        2 ground, 1 unclassified (object), 7 low noise; points of class 255 (outside the
        DTM) keep their input class. A text input gets a new LAS 1.4 file (point format 6,
        0.001 scale, the CRS as WKT). Any other extension: text ``x y z class`` with the
        input's delimiter, and a header line ``x y z class`` when the input had one (our
        codes 0/1/2/255 in the class column).
    cloud : PointCloud
    classes : array_like of int
        One class per point (:func:`classify_points`).
    decimals : int, optional
        Decimals of x, y, z in text output (default 3; 9 for geographic coordinates).

    See Also
    --------
    prepare_points, place_points : the two halves, for a run whose other outputs (rasters) must
        be in place before the points file appears.
    """
    work = prepare_points(path, cloud, classes, decimals)
    try:
        place_points(work, path)
    finally:
        if os.path.exists(work):
            os.remove(work)


def prepare_points(path, cloud, classes, decimals=None):
    """Write the points of output ``path`` (as :func:`write_points`) to a hidden work file beside
    it (:func:`part_path`, with the output's extension: laspy compresses by it) and return the work
    file's name; :func:`place_points` moves it into place. Nothing that looks like the output exists
    until then: a run killed (``kill -9``) before leaves only the hidden work file, which the next
    write of this output removes (:func:`remove_stale_parts`). On an error the work file is removed."""
    path = os.fspath(path)
    classes = np.asarray(classes).ravel()
    if classes.size != len(cloud):
        raise ValueError(f"classes has {classes.size} values but the cloud {len(cloud)} points; "
                         "pass one class per point.")
    ext = os.path.splitext(path)[1].lower()
    remove_stale_parts(path)
    tmp = part_path(path, ext)
    try:
        if ext in (".las", ".laz"):
            _write_las(tmp, cloud, classes)
        else:
            _write_text(tmp, cloud, classes, decimals)
    except OSError as exc:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise write_failed(path, exc.strerror or exc, exc.errno) from None
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
    return tmp


def place_points(work, path):
    """Move the work file of :func:`prepare_points` onto output ``path`` (one rename: atomic)."""
    path = os.fspath(path)
    try:
        os.replace(work, path)
    except OSError as exc:
        raise write_failed(path, exc.strerror or exc, exc.errno) from None


def _part_name(path):
    """The output's name as its work files carry it: cut (UTF-8 bytes) so that the hidden work
    file's name stays within 255 bytes with its tag and an extension of up to 8 bytes."""
    base = os.path.basename(os.path.abspath(os.fspath(path)))
    raw = base.encode("utf-8")[:max(1, 255 - 1 - _PART_TAG_BYTES - 8)]
    return raw.decode("utf-8", "ignore")


def part_path(path, ext=""):
    """A hidden work file beside output ``path``: ``.<name>.<pid>-<8 hex>.part<ext>`` (``ext``: the
    extension a writer needs, e.g. ``.laz`` for laspy). Written there, then moved onto ``path``
    with :func:`os.replace`, so an interrupted write leaves nothing that looks like the output."""
    folder = os.path.dirname(os.path.abspath(os.fspath(path)))
    return os.path.join(folder, f".{_part_name(path)}.{os.getpid():010d}-{uuid.uuid4().hex[:8]}.part{ext}")


def remove_stale_parts(path):
    """Remove the work files of output ``path`` (:func:`part_path`) that a killed earlier write left:
    those whose process is gone, and those of versions that named no process; returns their names.
    A work file of a process still running (a write of the same output in progress) is kept."""
    folder = os.path.dirname(os.path.abspath(os.fspath(path)))
    name = _part_name(path)
    try:
        names = os.listdir(folder)
    except OSError:
        return []
    removed = []
    for f in names:
        m = _PART_RE.fullmatch(f)
        if m is not None:
            if m.group("name") != name or pid_alive(int(m.group("pid"))):
                continue
        else:
            m = _OLD_PART_RE.fullmatch(f)
            if m is None or m.group("name") not in (name, os.path.splitext(name)[0]):
                continue
        try:
            os.remove(os.path.join(folder, f))
            removed.append(f)
        except OSError:
            pass
    return removed


def check_points_writable(path):
    """ValueError, before any work, when the points output ``path`` cannot be written here: a
    LAS/LAZ file without laspy, or a LAZ file without a LAZ backend (lazrs or laszip), which
    laspy only finds when it writes, after the work (a .las file needs no backend)."""
    ext = os.path.splitext(os.fspath(path))[1].lower()
    if ext not in LAS_EXTENSIONS:
        return
    try:
        laspy = import_laspy()
    except ImportError as exc:
        raise ValueError(f"the points output {os.fspath(path)!r} is a LAS/LAZ file. {exc}") from None
    if ext == ".laz" and not laspy.LazBackend.detect_available():
        raise ValueError(f"the points output {os.fspath(path)!r} is a compressed LAZ file, but no LAZ backend "
                         "is installed: write a .las file, or install lazrs (`pip install lazrs` with the "
                         "Python that QGIS uses; OSGeo4W Shell on Windows: `python -m pip install lazrs`).")


def _asprs_codes(classes, original):
    codes = np.zeros(classes.size, dtype=np.uint8) if original is None else \
        np.asarray(original).astype(np.uint8).copy()
    for ours, asprs in ASPRS_FROM_CLASS.items():
        codes[classes == ours] = asprs
    return codes


def _write_las(path, cloud, classes):
    laspy = import_laspy()
    if cloud.source_format == "las" and cloud.attrs is not None:
        src = cloud.attrs
        # a copy of the header: writing updates counts and bounds in place
        out = laspy.LasData(header=copy.deepcopy(src.header), points=src.points.copy())
        out.classification = _asprs_codes(classes, np.asarray(src.classification))
    else:
        header = laspy.LasHeader(point_format=6, version="1.4")
        header.offsets = np.floor([cloud.x.min(), cloud.y.min(), cloud.z.min()])
        header.scales = np.array([0.001, 0.001, 0.001])
        if cloud.crs:
            header.vlrs.append(laspy.vlrs.known.WktCoordinateSystemVlr(cloud.crs))
            header.global_encoding.wkt = True
        out = laspy.LasData(header)
        out.x, out.y, out.z = cloud.x, cloud.y, cloud.z
        out.classification = _asprs_codes(classes, None)
    try:
        out.write(path)
    except laspy.errors.LaspyException as exc:
        raise ImportError(f"cannot write {path!r} ({exc}). {LAS_INSTALL_HINT}") from exc


def _write_text(path, cloud, classes, decimals):
    attrs = cloud.attrs if isinstance(cloud.attrs, dict) else {}
    delim = attrs.get("delimiter", " ")
    if decimals is None:
        geographic = False
        if cloud.crs:
            from osgeo import osr
            srs = osr.SpatialReference()
            geographic = srs.SetFromUserInput(cloud.crs) == 0 and bool(srs.IsGeographic())
        decimals = 9 if geographic else 3
    d = int(decimals)
    row = delim.join([f"%.{d}f"] * 3 + ["%d"]) + "\n"
    table = np.column_stack([cloud.x, cloud.y, cloud.z, classes.astype(np.float64)])
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        if attrs.get("header"):
            names = ["x", "y", "z", "class"]
            fh.write(delim.join(names) + "\n")
        # one C-level %-format per chunk instead of a Python call per line
        step = 200_000
        for i in range(0, table.shape[0], step):
            part = table[i:i + step]
            fh.write((row * part.shape[0]) % tuple(part.ravel().tolist()))


def _header_tokens(path):
    """(first non-empty line as bytes, its tokens lower-cased) of a text point file."""
    first = b""
    with open(path, "rb") as fh:
        utf16 = fh.read(2).startswith(UTF16_BOMS)
        fh.seek(0)
        for line in (_utf8_bytes(path).splitlines(keepends=True) if utf16 else fh):
            if line.strip():
                first = line
                break
    return first, _column_names(first.translate(_SEPARATORS).split())


def _column_names(tokens):
    """The column names of a header line's tokens (bytes): lower case, quotes stripped, and a
    header written as a comment read as one ('//X,Y,Z,R,G,B' from CloudCompare, '# x y z')."""
    names = [t.decode("utf-8", errors="replace").lstrip("\ufeff").strip().strip('"\'').lower() for t in tokens]
    if names:
        names[0] = names[0].lstrip("#/").strip('"\'')
    return [n for n in names if n]


def is_class_column(path, name):
    """Whether ``name`` is the column a point file's classes are read from (LAS:
    ``classification``; text: the header's class column, :data:`_CLASS_NAMES`)."""
    path = os.fspath(path)
    if os.path.splitext(path)[1].lower() in LAS_EXTENSIONS:
        return name.strip().lower() == "classification"
    _, tokens = _header_tokens(path)
    return next((c for c in _CLASS_NAMES if c in tokens), None) == name.strip().lower()


def read_column(path, name):
    """One named column of a text point file with a header line, or one LAS dimension.

    Returns an int64 array (one value per point, in file order). ValueError when the file
    has no header / no such column or dimension.
    """
    path = os.fspath(path)
    if os.path.splitext(path)[1].lower() in LAS_EXTENSIONS:
        laspy = import_laspy()
        las = laspy.read(path)
        dims = list(las.point_format.dimension_names)
        match = [d for d in dims if d.lower() == name.lower()]
        if not match:
            raise ValueError(f"{path!r} has no dimension {name!r}; it has {dims}.")
        return np.asarray(las[match[0]]).astype(np.int64)
    first, tokens = _header_tokens(path)
    if not tokens or all(_is_number(t) for t in tokens):
        raise ValueError(f"{path!r} has no header line naming its columns, so it has no column "
                         f"{name!r}; use a truth points file instead.")
    if name.lower() not in tokens:
        raise ValueError(f"{path!r} has no column {name!r}; its columns are {tokens}.")
    k = tokens.index(name.lower())
    text = _utf8_bytes(path)
    start = text.find(first) + len(first)
    body = text[start:].translate(_SEPARATORS)
    try:
        col = np.loadtxt(body.splitlines(), usecols=(k,), dtype=np.float64, ndmin=1)
    except ValueError as exc:
        raise ValueError(f"{path!r}: cannot read the column {name!r}: {exc}") from None
    if not np.all(col == np.round(col)):
        raise ValueError(f"{path!r}: the column {name!r} must hold whole-number classes.")
    return col.astype(np.int64)


def point_output_path(path, input_path, temporary=False):
    """The path classified points are written to: ``path``, or for a temporary output the
    same path with the input's extension (LAS in, LAS out). ValueError for an extension
    that is neither LAS/LAZ nor text."""
    path = os.fspath(path)
    root, ext = os.path.splitext(path)
    in_ext = os.path.splitext(os.fspath(input_path))[1].lower()
    if temporary or not ext:
        ext = in_ext if in_ext in POINT_EXTENSIONS else ".txt"
        return root + ext
    if ext.lower() not in POINT_EXTENSIONS:
        raise ValueError(f"the classified points go to a LAS/LAZ file or a text file "
                         f"({', '.join(POINT_EXTENSIONS)}); got {path!r}.")
    return path
