"""Point clouds: read text/LAS points, rasterize them, classify them against a DTM.

The point side of Bare Earth: the ISPRS filter test samples and LiDAR LAS/LAZ files are
point clouds, the filters work on rasters. This module

* reads ``x y z [class]`` text (spaces, tabs or commas; one header line allowed) and
  LAS/LAZ files (through ``laspy``, imported lazily) into a :class:`PointCloud`,
* turns points into a grid (lowest / highest / mean point per cell,
  :func:`rasterize_points`),
* samples a grid bilinearly at the points (:func:`sample_bilinear`) and labels every point
  ground / above / below the DTM with a slope-dependent tolerance
  (:func:`classify_points`, the usual point-labelling step of raster filters, e.g.
  Pingel et al. 2013, SMRF, ISPRS J. Photogramm. Remote Sens. 77:21-30),
* writes the labels back (:func:`write_points`): text with a class column, or LAS/LAZ with
  ASPRS codes keeping every other attribute of the input.

Everything is vectorised (numpy/scipy); GDAL's ``osr`` is used only to read the CRS of a
LAS file or a ``crs`` argument.
"""
import copy
import io
import os
import re
import struct
import warnings
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .codes import GROUND, LOW, NODATA, OBJECT
from .common import as_cell_size

__all__ = ["PointCloud", "read_points", "rasterize_points", "sample_bilinear",
           "classify_points", "write_points", "nice_cell_size", "LAS_INSTALL_HINT",
           "ASPRS_FROM_CLASS"]

#: The message given when laspy (or lazrs for LAZ) is missing.
LAS_INSTALL_HINT = ("Reading and writing LAS/LAZ point clouds needs the Python packages laspy "
                    "and lazrs: run `pip install laspy lazrs` with the Python that QGIS uses "
                    "(OSGeo4W Shell on Windows: `python -m pip install laspy lazrs`).")

#: ASPRS LAS classification codes written for the classes of :func:`classify_points`
#: (NODATA, points outside the DTM, keep the input's classification; 0 if it had none).
ASPRS_FROM_CLASS = {GROUND: 2, OBJECT: 1, LOW: 7}

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
        line is allowed (if it names the columns, e.g. ``X,Y,Z,Classification,Intensity``,
        the columns are picked by name); blank lines are skipped.
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


_SEPARATORS = bytes.maketrans(b"\t,;\r\v\f", b"      ")   # newlines stay
_NUMBER_BYTES = np.zeros(256, dtype=bool)
_NUMBER_BYTES[np.frombuffer(b"0123456789.+-eE \n", dtype=np.uint8)] = True
_CLASS_NAMES = ("class", "classification", "label", "cls", "c")
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
    with open(path, "rb") as fh:
        data = fh.read()
    if data.startswith(b"\xef\xbb\xbf"):  # UTF-8 byte-order mark
        data = b"   " + data[3:]
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
        names = [t.decode("utf-8", errors="replace").strip().strip('"\'').lower()
                 for t in first_tokens]
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
    if names is not None and len(names) != ncols:
        raise ValueError(f"{path}: the header line names {len(names)} columns but the points "
                         f"have {ncols}; fix the header or remove it.")

    # Pick the columns.
    if names is not None and {"x", "y", "z"} <= set(names):
        cols = [names.index("x"), names.index("y"), names.index("z")]
        cls_col = next((names.index(c) for c in _CLASS_NAMES if c in names), None)
    else:
        if ncols not in (3, 4):
            raise ValueError(f"{path}: {ncols} values per line; expected 3 (x y z) or 4 "
                             "(x y z class), or a header line naming the x, y, z columns.")
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
                             f"numbers; got {c[nonint[0]]!r} in {text!r}.")
        classification = c.astype(np.int32)
    head = data[body_start:body_start + 4096]
    delim = "\t" if b"\t" in head else ("," if b"," in head else " ")
    return PointCloud(x=x, y=y, z=z, classification=classification, crs=None,
                      units_to_metre=1.0, attrs={"header": header, "delimiter": delim},
                      source_format="text")


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
        for t in _line(data, nl, int(ln)).replace(",", " ").replace(";", " ").split():
            try:
                float(t)
            except ValueError:
                return int(ln)
            if "_" in t:   # float() takes "1_000", numpy does not
                return int(ln)
    # float() accepted everything (e.g. "1.5.3" splits into two numbers for numpy)
    for ln in filled:
        for t in _line(data, nl, int(ln)).replace(",", " ").replace(";", " ").split():
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
    h = float(srs.GetLinearUnits()) if srs.IsProjected() else 1.0
    v = None
    if srs.IsCompound() or srs.IsVertical():
        try:
            v = float(srs.GetTargetLinearUnits("VERT_CS"))
        except Exception:
            v = None
    return h, v


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


# --------------------------------------------------------------------------- rasterizing
def nice_cell_size(size):
    """Round a cell size to 1, 2, 2.5 or 5 times a power of ten (the nearest in ratio)."""
    size = float(size)
    if not np.isfinite(size) or size <= 0:
        raise ValueError(f"cannot round the cell size {size!r}; it must be positive.")
    p = 10.0 ** np.floor(np.log10(size))
    steps = np.array([1.0, 2.0, 2.5, 5.0, 10.0]) * p
    return float(steps[np.argmin(np.abs(np.log(steps / size)))])


def rasterize_points(x, y, z, cell_size=None, *, reducer="min", extent=None,
                     fill_empty="nearest", info=None):
    """Grid points: the lowest, highest or mean z of the points in each cell.

    Parameters
    ----------
    x, y, z : array_like
        Point coordinates (same length). Points with a non-finite coordinate are ignored.
    cell_size : float or (float, float), optional
        Cell size ``(dx, dy)`` in the points' units. Default: about one point per cell,
        ``sqrt(area / n)`` over the bounding box, rounded by :func:`nice_cell_size`
        (1 m at the ISPRS urban density of 1 point/m2). The size used is
        ``geotransform[1]`` (and ``info["cell_size"]``).
    reducer : {"min", "max", "mean"}
        What a cell with several points gets.
    extent : (xmin, ymin, xmax, ymax), optional
        The grid's bounds, used exactly; points outside are dropped. Default: the points'
        bounding box, with the origin snapped to the cell size (``floor(xmin / dx) * dx``,
        ``ceil(ymax / dy) * dy``) so that grids of neighbouring tiles line up. Points on
        the east / south edge fall in the last column / row.
    fill_empty : {"nearest", None}
        ``"nearest"``: empty cells take the value of the nearest non-empty cell
        (``scipy.ndimage.distance_transform_edt``); None: they stay NaN.
    info : dict, optional
        Filled with ``cell_size``, ``shape``, ``n_points`` (used), ``n_empty`` (cells with
        no point, before filling) and ``points_per_cell``.

    Returns
    -------
    grid : ndarray of float32, 2-D
        Rows go north to south.
    geotransform : tuple of 6 floats
        GDAL order ``(x0, dx, 0, y0, 0, -dy)``.

    Notes
    -----
    Vectorised: one ``argsort`` of the cell index and ``np.minimum.reduceat`` /
    ``np.maximum.reduceat`` / ``np.bincount`` (about 3 M points/s on one core).
    """
    if reducer not in ("min", "max", "mean"):
        raise ValueError(f"reducer must be 'min', 'max' or 'mean'; got {reducer!r}.")
    if fill_empty not in ("nearest", None):
        raise ValueError(f"fill_empty must be 'nearest' or None; got {fill_empty!r}.")
    x = np.asarray(x, dtype=np.float64).ravel()
    y = np.asarray(y, dtype=np.float64).ravel()
    z = np.asarray(z, dtype=np.float64).ravel()
    if not (x.size == y.size == z.size):
        raise ValueError(f"x, y and z must have the same length; got {x.size}, {y.size}, {z.size}.")
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
    if not ok.all():
        x, y, z = x[ok], y[ok], z[ok]
    if x.size == 0:
        raise ValueError("no point with finite x, y and z to rasterize; pass a non-empty cloud.")

    if extent is not None:
        ext = np.asarray(extent, dtype=np.float64).ravel()
        if ext.size != 4 or not np.all(np.isfinite(ext)) or ext[2] <= ext[0] or ext[3] <= ext[1]:
            raise ValueError(f"extent must be (xmin, ymin, xmax, ymax) with xmax > xmin and "
                             f"ymax > ymin; got {extent!r}.")
        xmin, ymin, xmax, ymax = (float(v) for v in ext)
    else:
        xmin, ymin, xmax, ymax = float(x.min()), float(y.min()), float(x.max()), float(y.max())

    if cell_size is None:
        area = max(xmax - xmin, 0.0) * max(ymax - ymin, 0.0)
        if area <= 0:  # points on a line or a single point
            area = max(xmax - xmin, ymax - ymin, 1.0) ** 2
        dx = dy = nice_cell_size(np.sqrt(area / x.size))
    else:
        dx, dy = as_cell_size(cell_size)

    if extent is None:
        x0 = np.floor(xmin / dx) * dx
        y0 = np.ceil(ymax / dy) * dy
    else:
        x0, y0 = xmin, ymax
    eps = 1e-9
    ncols = max(1, int(np.ceil((xmax - x0) / dx - eps)))
    nrows = max(1, int(np.ceil((y0 - ymin) / dy - eps)))
    if ncols * nrows > 2_000_000_000:
        raise ValueError(f"a {nrows} x {ncols} grid is too large; use a larger cell_size "
                         f"than {dx:g} x {dy:g} (are the coordinates in degrees?).")

    col = np.floor((x - x0) / dx)
    row = np.floor((y0 - y) / dy)
    if extent is not None:
        inside = (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)
        if not inside.all():
            col, row, z = col[inside], row[inside], z[inside]
        if z.size == 0:
            raise ValueError(f"no point falls inside the extent {tuple(extent)!r}; the points "
                             f"span x {float(x.min()):.3f}..{float(x.max()):.3f}, "
                             f"y {float(y.min()):.3f}..{float(y.max()):.3f}.")
    col = np.clip(col, 0, ncols - 1).astype(np.int64)
    row = np.clip(row, 0, nrows - 1).astype(np.int64)
    cell = row * ncols + col

    grid = np.full(nrows * ncols, np.nan, dtype=np.float64)
    if reducer == "mean":
        count = np.bincount(cell, minlength=grid.size)
        total = np.bincount(cell, weights=z, minlength=grid.size)
        has = count > 0
        grid[has] = total[has] / count[has]
    else:
        order = np.argsort(cell, kind="stable")
        cs = cell[order]
        zs = z[order]
        starts = np.flatnonzero(np.r_[True, cs[1:] != cs[:-1]])
        ufunc = np.minimum if reducer == "min" else np.maximum
        grid[cs[starts]] = ufunc.reduceat(zs, starts)
    grid = grid.reshape(nrows, ncols).astype(np.float32)
    empty = np.isnan(grid)
    n_empty = int(empty.sum())
    if fill_empty == "nearest" and n_empty:
        idx = ndimage.distance_transform_edt(empty, return_distances=False, return_indices=True)
        grid = grid[tuple(idx)]
    gt = (float(x0), float(dx), 0.0, float(y0), 0.0, -float(dy))
    if info is not None:
        info.update(cell_size=(float(dx), float(dy)), shape=(nrows, ncols),
                    n_points=int(z.size), n_empty=n_empty,
                    points_per_cell=float(z.size) / (nrows * ncols))
    return grid, gt


# --------------------------------------------------------------------------- sampling
def _check_geotransform(geotransform, shape):
    gt = tuple(float(v) for v in geotransform)
    if len(gt) != 6:
        raise ValueError(f"geotransform must have 6 numbers (GDAL order); got {geotransform!r}.")
    if gt[2] != 0 or gt[4] != 0:
        raise ValueError("rotated grids (geotransform[2] or [4] not 0) are not supported; "
                         "warp the raster to a north-up grid first (gdalwarp).")
    if gt[1] == 0 or gt[5] == 0:
        raise ValueError(f"geotransform has a zero cell size: {gt!r}.")
    return gt


def grid_extent(gt, shape):
    """``(xmin, ymin, xmax, ymax)`` of a north-up grid of ``shape`` on geotransform ``gt``."""
    xs = (gt[0], gt[0] + gt[1] * shape[1])
    ys = (gt[3], gt[3] + gt[5] * shape[0])
    return min(xs), min(ys), max(xs), max(ys)


def sample_bilinear(grid, geotransform, x, y):
    """Bilinear interpolation of a grid at points.

    Cell values sit at cell centres. Inside the grid but within half a cell of its edge,
    the nearest edge values are used (no extrapolation).

    Parameters
    ----------
    grid : array_like, 2-D
        Values (NaN = nodata).
    geotransform : sequence of 6 floats
        GDAL geotransform of the grid (north-up: ``[2] == [4] == 0``).
    x, y : array_like
        Point coordinates in the grid's CRS.

    Returns
    -------
    ndarray of float64
        The interpolated values; NaN for points outside the grid, or where one of the
        cells with a non-zero weight is NaN.
    """
    grid = np.asarray(grid)
    if grid.ndim != 2 or grid.size == 0:
        raise ValueError(f"grid must be a non-empty 2-D array; got shape {grid.shape}.")
    gt = _check_geotransform(geotransform, grid.shape)
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    shape = np.broadcast(x, y).shape
    x, y = np.broadcast_to(x, shape).ravel(), np.broadcast_to(y, shape).ravel()
    return sample_bilinear_many([grid], gt, x, y)[0].reshape(shape)


def sample_bilinear_many(grids, gt, x, y):
    """Bilinear samples of several grids of one shape at 1-D points (weights computed once).

    As :func:`sample_bilinear` for each grid of ``grids``, with ``gt`` already checked
    (:func:`sample_bilinear` checks it) and ``x``, ``y`` 1-D float64. Returns a list of
    float64 arrays, NaN outside the grid.
    """
    nrows, ncols = grids[0].shape
    u = (x - gt[0]) / gt[1]          # column coordinate, 0 at the west edge
    v = (y - gt[3]) / gt[5]          # row coordinate, 0 at the north edge
    inside = (u >= 0) & (u <= ncols) & (v >= 0) & (v <= nrows)
    fc = np.clip(np.where(inside, u, 0.0) - 0.5, 0.0, ncols - 1.0)
    fr = np.clip(np.where(inside, v, 0.0) - 0.5, 0.0, nrows - 1.0)
    c0 = np.minimum(fc.astype(np.int64), max(ncols - 2, 0))     # fc >= 0: trunc = floor
    r0 = np.minimum(fr.astype(np.int64), max(nrows - 2, 0))
    tc = fc - c0
    tr = fr - r0
    dc = (c0 + 1 < ncols).astype(np.int64)                      # 0 on a one-column grid
    dr = (r0 + 1 < nrows).astype(np.int64) * ncols
    i00 = r0 * ncols + c0
    corners = ((i00, (1 - tr) * (1 - tc)), (i00 + dc, (1 - tr) * tc),
               (i00 + dr, tr * (1 - tc)), (i00 + dr + dc, tr * tc))
    outs = []
    for grid in grids:
        flat = np.asarray(grid).ravel()
        out = np.zeros(x.size)
        for idx, w in corners:
            # a cell with zero weight is not needed: its NaN must not spread
            out += np.where(w > 0, w * flat[idx], 0.0)
        out[~inside] = np.nan
        outs.append(out)
    return outs


def dtm_slope(dtm, gt):
    """Terrain slope (rise / run, dimensionless) of a grid, NaN where the DTM is NaN."""
    dtm = np.asarray(dtm, dtype=np.float64)
    if min(dtm.shape) < 2:
        return np.zeros_like(dtm)
    gy, gx = np.gradient(dtm, abs(gt[5]), abs(gt[1]))
    return np.hypot(gx, gy)


def classify_points(x, y, z, dtm, geotransform, *, threshold_m=0.5, slope_factor=1.25):
    """Label points ground / above / below a DTM with a slope-dependent tolerance.

    A point is ground when ``|z - DTM(x, y)| <= threshold_m + slope_factor * s(x, y)``,
    with ``s`` the local DTM slope (rise / run from ``np.gradient`` of the DTM), both
    sampled bilinearly (the point-labelling rule of SMRF, Pingel et al. 2013).

    Parameters
    ----------
    x, y, z : array_like
        Points, in the DTM's CRS and z units.
    dtm : array_like, 2-D
        The bare-earth surface (NaN = nodata).
    geotransform : sequence of 6 floats
        GDAL geotransform of ``dtm``.
    threshold_m : float
        Elevation tolerance on flat ground, in the z units of the points and DTM (metres
        normally; for a cloud in feet pass ``0.5 / cloud.z_units_to_metre``).
    slope_factor : float
        Extra tolerance per unit of slope (z units; 1.25 -> 1.25 m more on a 45 deg slope).

    Returns
    -------
    ndarray of uint8
        0 ground, 1 above the DTM (object), 2 below it (low outlier), 255 outside the DTM or
        where it is NaN.

    Raises
    ------
    ValueError
        When most points are outside the DTM (the message gives both extents): wrong CRS,
        units or DTM.
    """
    if not (np.isfinite(threshold_m) and threshold_m >= 0):
        raise ValueError(f"threshold_m must be >= 0; got {threshold_m!r}.")
    if not (np.isfinite(slope_factor) and slope_factor >= 0):
        raise ValueError(f"slope_factor must be >= 0; got {slope_factor!r}.")
    dtm = np.asarray(dtm)
    if dtm.ndim != 2 or dtm.size == 0:
        raise ValueError(f"dtm must be a non-empty 2-D array; got shape {dtm.shape}.")
    gt = _check_geotransform(geotransform, dtm.shape)
    x = np.asarray(x, dtype=np.float64).ravel()
    y = np.asarray(y, dtype=np.float64).ravel()
    z = np.asarray(z, dtype=np.float64).ravel()
    if not (x.size == y.size == z.size):
        raise ValueError(f"x, y and z must have the same length; got {x.size}, {y.size}, {z.size}.")
    if x.size == 0:
        return np.zeros(0, dtype=np.uint8)
    gx0, gy0, gx1, gy1 = grid_extent(gt, dtm.shape)
    outside = ~((x >= gx0) & (x <= gx1) & (y >= gy0) & (y <= gy1))
    if outside.sum() * 2 > x.size:
        raise ValueError(
            f"{int(outside.sum())} of {x.size} points are outside the DTM: the points span "
            f"x {np.nanmin(x):.3f}..{np.nanmax(x):.3f}, y {np.nanmin(y):.3f}..{np.nanmax(y):.3f}; "
            f"the DTM spans x {gx0:.3f}..{gx1:.3f}, y {gy0:.3f}..{gy1:.3f}. Use a DTM of the "
            "same area, in the same CRS and units as the points.")
    ground, slope = sample_bilinear_many([dtm, dtm_slope(dtm, gt)], gt, x, y)
    slope = np.where(np.isfinite(slope), slope, 0.0)   # at a DTM hole's edge: flat
    tol = threshold_m + slope_factor * slope
    dz = z - ground
    out = np.full(x.size, NODATA, dtype=np.uint8)
    ok = np.isfinite(dz)
    out[ok] = GROUND
    out[ok & (dz > tol)] = OBJECT
    out[ok & (dz < -tol)] = LOW
    return out


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
    """
    path = os.fspath(path)
    classes = np.asarray(classes).ravel()
    if classes.size != len(cloud):
        raise ValueError(f"classes has {classes.size} values but the cloud {len(cloud)} points; "
                         "pass one class per point.")
    ext = os.path.splitext(path)[1].lower()
    if ext in (".las", ".laz"):
        _write_las(path, cloud, classes)
    else:
        _write_text(path, cloud, classes, decimals)


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
