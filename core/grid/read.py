"""Reading rasters with GDAL: the one place where nodata, scale/offset and units are resolved.

A DSM is opened with :func:`open_dsm`, which checks it before any work starts and works
out the cell size in metres (converting degrees at the raster's latitude, and feet and
other linear units by the CRS's factor). Blocks are read as float32 with NaN as nodata
and heights in metres.
"""
import contextlib
import math
import os
import threading
from dataclasses import dataclass, field
from typing import List, Optional, Tuple

import numpy as np

try:
    from osgeo import gdal, osr
except ImportError:  # pragma: no cover - GDAL ships with QGIS
    gdal = osr = None

from ..codes import as_mask_codes
from ..common import MAX_ABS_HEIGHT_M, as_cell_size, is_rotated, without_far_heights

#: Smallest raster the filters accept, in cells per side.
MIN_SIDE = 3
#: Smallest cell a DSM can have, metres: the finest DSMs (close-range and drone photogrammetry)
#: have cells of a centimetre or more, ten times this. A smaller cell is a cell size in degrees
#: read as metres (a raster without a CRS, or given a projected one by mistake), or a geographic
#: raster's east-west width collapsing near a pole; the filters' windows (metres) would then span
#: millions of cells: hours of work or arrays of hundreds of GB.
MIN_CELL_M = 1e-3

#: Tile edge of the GeoTIFF outputs, cells.
OUTPUT_TILE = 256

#: WGS84 ellipsoid: semi-major axis (m) and first eccentricity squared.
WGS84_A, WGS84_E2 = 6378137.0, 0.00669437999014


def metres_per_degree(lat):
    """Metres per degree of longitude and of latitude at latitude ``lat`` (degrees), on the
    WGS84 ellipsoid: ``pi/180 * N cos(phi)`` and ``pi/180 * M`` with the radii of curvature
    ``N = a / sqrt(1 - e2 sin^2 phi)`` (prime vertical) and ``M = a (1 - e2) / (1 - e2 sin^2
    phi)^1.5`` (meridian). Returns ``(m_per_deg_lon, m_per_deg_lat)``."""
    phi = math.radians(lat)
    s = 1.0 - WGS84_E2 * math.sin(phi) ** 2
    return (math.pi / 180 * WGS84_A * math.cos(phi) / math.sqrt(s),
            math.pi / 180 * WGS84_A * (1 - WGS84_E2) / s ** 1.5)


#: The log line of a raster with NaN cells and no declared nodata (one wording everywhere).
NAN_UNDECLARED_WARNING = ("The raster has NaN cells but declares no nodata value: NaN was treated as nodata, "
                          "and the outputs declare NaN as nodata.")


@contextlib.contextmanager
def _reading(path, what="read"):
    """GDAL calls on an input: raw-band VRTs refused where GDAL honours it, and every GDAL
    error (a RuntimeError, sometimes with an empty message) turned into a ValueError naming
    the file."""
    gdal.SetThreadLocalConfigOption("GDAL_VRT_ENABLE_RAWRASTERBAND", "NO")
    gdal.ErrorReset()
    try:
        yield
    except RuntimeError as exc:
        msg = str(exc).strip().rstrip(".") or gdal.GetLastErrorMsg().strip().rstrip(".") or "GDAL gave no reason"
        raise ValueError(f"cannot {what} the raster {str(path)!r}: {msg}. The file may be truncated or "
                         "corrupt, or a file it refers to is missing: check it (gdalinfo -checksum) or "
                         "export it again.") from None
    finally:
        gdal.SetThreadLocalConfigOption("GDAL_VRT_ENABLE_RAWRASTERBAND", None)


@contextlib.contextmanager
def without_side_files():
    """GDAL's side files (PAM ``.aux.xml``) off, in this thread, while the block runs.

    A dataset opened inside never writes ``<raster>.aux.xml`` beside its file. QGIS computes
    a raster's statistics when it loads it as a layer (for its default renderer) and GDAL
    saves them beside the input when the layer closes; the plugin's algorithms load their
    inputs as layers inside this block, so an input folder is left as it was. Our own reads
    (:func:`open_dsm`) keep PAM on: a nodata, scale or CRS declared in an existing side file
    is still read.
    """
    if gdal is None:
        yield
        return
    old = gdal.GetThreadLocalConfigOption("GDAL_PAM_ENABLED", None)
    gdal.SetThreadLocalConfigOption("GDAL_PAM_ENABLED", "NO")
    try:
        yield
    finally:
        gdal.SetThreadLocalConfigOption("GDAL_PAM_ENABLED", old)


def _vrt_problems(ds, depth=0):
    """Why a VRT input is refused: a raw band (``VRTRawRasterBand`` reads any local file's
    bytes as cells) anywhere in it or in the VRTs it refers to. Returns a message or None."""
    import xml.etree.ElementTree as ET
    xml = (ds.GetMetadata("xml:VRT") or [""])[0]
    try:
        root = ET.fromstring(xml)
    except ET.ParseError:
        return None
    base = os.path.dirname(ds.GetDescription())
    for band in root.iter("VRTRasterBand"):
        if band.get("subClass") == "VRTRawRasterBand":
            src = band.findtext("SourceFilename", "")
            return (f"it has a raw band (VRTRawRasterBand) reading the bytes of {src!r}: such VRTs can read "
                    "any local file and are refused as inputs. Convert the data to a GeoTIFF first")
    if depth < 4:
        for el in root.iter("SourceFilename"):
            name = (el.text or "").strip()
            if el.get("relativeToVRT", el.get("relativetoVRT", "0")) == "1":
                name = os.path.join(base, name)
            if name.lower().endswith(".vrt") and os.path.isfile(name):
                sub = gdal.Open(name, gdal.GA_ReadOnly)
                problem = sub is not None and _vrt_problems(sub, depth + 1)
                if problem:
                    return problem
    return None


class SeveralBands(ValueError):
    """A raster of several height-like bands opened without a band chosen (``bands``: how many)."""

    def __init__(self, message, bands):
        super().__init__(message)
        self.bands = bands


def _open_read(path):
    """Open a raster read-only; GeoTIFFs decompress their tiles on every core."""
    with _reading(path, "open"):
        ds = gdal.Open(path, gdal.GA_ReadOnly)
        if ds is not None and ds.GetDriver().ShortName == "GTiff":
            ds = gdal.OpenEx(path, gdal.OF_RASTER | gdal.OF_READONLY, open_options=["NUM_THREADS=ALL_CPUS"]) or ds
    if ds is not None and ds.GetDriver().ShortName == "VRT":
        problem = _vrt_problems(ds)
        if problem:
            raise ValueError(f"the raster {path!r} is refused: {problem}.")
    return ds


def need_gdal():
    if gdal is None:
        raise ImportError("GDAL's Python bindings are needed (python3-gdal on Debian; QGIS ships them).")
    gdal.UseExceptions()


class SessionSetting:
    """A process-wide GDAL setting changed while work runs, in any thread: the value before the
    first change is kept and put back when the last ends. Runs in QGIS's background threads
    overlap; restoring each run's own "before" would let the first to end undo the change under
    the other, and the other then put back the changed value for the rest of the session."""

    def __init__(self, get, put):
        self._get, self._put = get, put
        self._lock = threading.Lock()
        self._depth = 0
        self._before = None

    @contextlib.contextmanager
    def changed(self, value):
        """The setting is ``value(before)`` inside the block (``before``: the value the first
        of the overlapping blocks found)."""
        with self._lock:
            if self._depth == 0:
                self._before = self._get()
            self._depth += 1
            self._put(value(self._before))
        try:
            yield
        finally:
            with self._lock:
                self._depth -= 1
                if self._depth == 0 and self._get() != self._before:
                    self._put(self._before)


def _put_exceptions(on):
    if on:
        gdal.UseExceptions()
    else:
        gdal.DontUseExceptions()


_EXCEPTIONS = SessionSetting(lambda: gdal.GetUseExceptions(), _put_exceptions)
_CACHE = SessionSetting(lambda: gdal.GetCacheMax(), lambda size: gdal.SetCacheMax(size))


@contextlib.contextmanager
def gdal_mode_kept():
    """GDAL's Python exceptions on inside the block (as :func:`need_gdal` turns them on) and
    the mode back as it was when it ends. GDAL's bindings hold one mode for the whole process:
    inside QGIS, every other plugin's ``if gdal.Open(p) is None`` would raise instead once a
    Bare Earth algorithm had run. The plugin's entry points run inside this block; overlapping
    blocks (runs in threads) share the mode (:class:`SessionSetting`)."""
    if gdal is None:
        yield
        return
    with _EXCEPTIONS.changed(lambda before: 1):
        yield


@dataclass
class DSMInfo:
    """An opened, checked DSM band and everything known about its grid.

    Attributes
    ----------
    path, band_index : the source
    shape : (rows, cols)
    geotransform : GDAL 6-tuple
    crs_wkt : str ('' when the raster has no CRS)
    nodata : float or None, the declared nodata value (of the stored values, before scale/offset)
    cell_size_m : (dx, dy) in metres
    z_to_m : factor from the raster's height unit to metres (1 unless the CRS is in feet...)
    nan_undeclared : True when NaN cells are present without a declared nodata value
    dtype : GDAL data type name of the band
    warnings : list of str for the log
    scale, offset : the band's scale and offset: heights = stored value * scale + offset
    notes : list of str, facts for the log that are no warning (scale and offset applied)
    far_cells : cells seen by :meth:`read` with heights beyond ``common.MAX_ABS_HEIGHT_M``
        (or infinite), read as nodata
    masked : 0 when only the nodata value marks missing cells; else where the cells that are
        nodata too come from (0 in it, drawn transparent by QGIS): the index of the raster's
        alpha band (whatever its data type: ``gdalwarp -dstalpha`` writes a Float32 one, which
        GDAL's own mask ignores), or -1 for GDAL's mask band (an internal or ``.msk`` mask)
    georeferenced : False when the raster has no geotransform (``geotransform`` is then 1 m
        cells from the top left corner, for the cell size only; outputs are written without one,
        as the input, so that QGIS draws them over it), with its ground control points ``gcps``
        (``(x, y, z, pixel, line)`` each, in ``gcp_wkt``) when it has some
    nodata_ranges : ``(low, high, include_low, include_high)`` ranges of heights (the raster's
        unit, scale and offset applied) that are nodata too: the additional no-data values a
        QGIS layer of the raster was given (Properties > Transparency)
    unit_type : the height unit the band states (GDAL's unit type) when it names one of
        :data:`BAND_HEIGHT_UNITS` (``z_to_m`` is then its), else ""; the DTM and nDSM outputs state it too
    """
    path: str
    band_index: int
    shape: Tuple[int, int]
    geotransform: tuple
    crs_wkt: str
    nodata: Optional[float]
    cell_size_m: Tuple[float, float]
    z_to_m: float = 1.0
    nan_undeclared: bool = False
    dtype: str = "Float32"
    warnings: List[str] = field(default_factory=list)
    _ds: object = None
    scale: float = 1.0
    offset: float = 0.0
    notes: List[str] = field(default_factory=list)
    far_cells: int = 0
    masked: int = 0
    nodata_ranges: tuple = ()
    georeferenced: bool = True
    gcps: tuple = ()
    gcp_wkt: str = ""
    unit_type: str = ""

    @property
    def cells(self):
        return self.shape[0] * self.shape[1]

    def dataset(self):
        if self._ds is None:
            self._ds = _open_read(self.path)
        return self._ds

    def read_stored(self, window=None, step=1):
        """The band's stored values over ``(r0, r1, c0, c1)`` (default all), as GDAL gives them
        (no nodata, scale or unit applied); every ``step``-th cell when ``step > 1``
        (nearest-neighbour decimation). ValueError naming the file when GDAL fails."""
        r0, r1, c0, c1 = window or (0, self.shape[0], 0, self.shape[1])
        with _reading(self.path):
            band = self.dataset().GetRasterBand(self.band_index)
            if step > 1:
                a = band.ReadAsArray(c0, r0, c1 - c0, r1 - r0, buf_xsize=max(1, (c1 - c0) // step),
                                     buf_ysize=max(1, (r1 - r0) // step),
                                     resample_alg=gdal.GRIORA_NearestNeighbour)
            else:
                a = band.ReadAsArray(c0, r0, c1 - c0, r1 - r0)
        if a is None:
            raise ValueError(f"cannot read the raster {self.path!r} (rows {r0}-{r1}, columns {c0}-{c1}): "
                             f"{gdal.GetLastErrorMsg() or 'GDAL gave no reason'}. Check the file.")
        return a

    def mask_valid(self, window=None, step=1):
        """Where the band's mask or alpha band says a cell is valid over ``window`` (read as
        :meth:`read_stored` reads the band), or None when the band has no such mask."""
        if not self.masked:
            return None
        r0, r1, c0, c1 = window or (0, self.shape[0], 0, self.shape[1])
        with _reading(self.path):
            ds = self.dataset()
            mb = ds.GetRasterBand(self.band_index).GetMaskBand() if self.masked < 0 else ds.GetRasterBand(self.masked)
            if step > 1:
                m = mb.ReadAsArray(c0, r0, c1 - c0, r1 - r0, buf_xsize=max(1, (c1 - c0) // step),
                                   buf_ysize=max(1, (r1 - r0) // step), resample_alg=gdal.GRIORA_NearestNeighbour)
            else:
                m = mb.ReadAsArray(c0, r0, c1 - c0, r1 - r0)
        with np.errstate(invalid="ignore"):
            return m > 0                  # 0 transparent; NaN (an alpha band read through a VRT) too

    def surface(self, stored, window=None, step=1, z_to_m=None):
        """Stored values read over ``window`` (every ``step``-th cell) -> float32 heights with NaN
        for nodata: the declared nodata and the cells the band's mask or alpha band masks."""
        z = to_surface(stored, self.nodata, self.z_to_m if z_to_m is None else z_to_m, self.scale, self.offset)
        valid = self.mask_valid(window, step)
        if valid is not None:
            z[~valid] = np.nan
        if self.nodata_ranges:
            z[in_ranges(_apply_scale(stored, self.scale, self.offset), self.nodata_ranges)] = np.nan
        return z

    def read_heights(self, window=None):
        """Heights over ``window`` in the raster's own unit (scale and offset applied, float32;
        nodata cells hold whatever is stored there): the values an output DTM copies."""
        return _apply_scale(self.read_stored(window), self.scale, self.offset)

    def read(self, window=None, step=1, far_in=None):
        """Read ``(r0, r1, c0, c1)`` (default all) as float32 metres, NaN = nodata.

        Heights beyond ``common.MAX_ABS_HEIGHT_M`` are nodata too (counted in ``far_cells``:
        those inside the slices ``far_in`` of the window when given, e.g. a block's core);
        NaN without a declared nodata is noted (:meth:`note_nan`).
        """
        a = self.read_stored(window, step)
        self.note_nan(a)
        z, n_far = without_far_heights(self.surface(a, window, step), far_in)
        self.far_cells += n_far
        return z

    def note_nan(self, stored):
        """Record (once) that ``stored`` values hold NaN while the band declares no nodata."""
        if (not self.nan_undeclared and self.nodata is None and np.asarray(stored).dtype.kind == "f"
                and np.isnan(stored).any()):
            self.nan_undeclared = True
            self.warnings.append(NAN_UNDECLARED_WARNING)


def in_ranges(a, ranges):
    """Where ``a`` lies in any of ``ranges``, ``(low, high, include_low, include_high)`` each."""
    out = np.zeros(np.shape(a), bool)
    with np.errstate(invalid="ignore"):
        for lo, hi, inc_lo, inc_hi in ranges:
            above = a >= lo if inc_lo else a > lo
            below = a <= hi if inc_hi else a < hi
            out |= above & below
    return out


def _apply_scale(a, scale=1.0, offset=0.0):
    """Stored values -> heights in the raster's unit, float32 (``a * scale + offset`` in float64)."""
    if scale == 1.0 and offset == 0.0:
        with np.errstate(over="ignore"):       # float64 beyond float32 (a -1e300 nodata): -inf, nodata
            return np.array(a, dtype=np.float32, copy=True)
    with np.errstate(over="ignore", invalid="ignore"):
        return (np.asarray(a, np.float64) * scale + offset).astype(np.float32)


def to_surface(a, nodata=None, z_to_m=1.0, scale=1.0, offset=0.0):
    """Stored band values -> float32 metres with NaN for nodata (``a`` untouched).

    ``nodata`` is compared with the stored values; then ``a * scale + offset`` (the band's
    scale and offset) and ``* z_to_m`` (the height unit in metres). Non-finite cells are NaN.
    """
    z = _apply_scale(a, scale, offset)
    if nodata is not None and not (isinstance(nodata, float) and math.isnan(nodata)):
        z[a == nodata] = np.nan
    z[~np.isfinite(z)] = np.nan
    if z_to_m != 1.0:
        z *= np.float32(z_to_m)
    return z


def _linear_unit_factor(srs):
    """Metres per CRS linear unit, or None for a geographic CRS."""
    if srs.IsGeographic():
        return None
    f = srs.GetLinearUnits()
    return float(f) if f and f > 0 else 1.0


def vertical_unit_factor(srs):
    """Metres per unit of the vertical axis of a compound (or vertical) CRS, with its name, e.g.
    ``(0.3048006, 'US survey foot')`` for ``EPSG:26917+6360`` (UTM in metres, NAVD88 heights
    in US survey feet); None when the CRS has no vertical part (heights then in its linear
    unit, or metres)."""
    if srs is None or not (srs.IsCompound() or srs.IsVertical()):
        return None
    try:
        f = float(srs.GetTargetLinearUnits("VERT_CS"))
    except (RuntimeError, TypeError, ValueError):
        return None
    if not (math.isfinite(f) and f > 0):
        return None
    return f, srs.GetAttrValue("VERT_CS|UNIT") or f"{f:.6g} m"


#: Metres per unit of a band's stated unit (GDAL's unit type, ``gdal_edit.py -units`` or
#: ``gdal_translate -a_unittype``: "m" or "ft" for heights), by its lower-case name.
_US_FOOT = 1200.0 / 3937.0
BAND_HEIGHT_UNITS = {
    "m": 1.0, "metre": 1.0, "meter": 1.0, "metres": 1.0, "meters": 1.0,
    "ft": 0.3048, "foot": 0.3048, "feet": 0.3048, "international foot": 0.3048, "foot_international": 0.3048,
    "us-ft": _US_FOOT, "ftus": _US_FOOT, "us survey foot": _US_FOOT, "us_survey_foot": _US_FOOT,
    "foot_us": _US_FOOT, "us foot": _US_FOOT,
    "cm": 0.01, "centimetre": 0.01, "centimeter": 0.01, "mm": 0.001, "millimetre": 0.001, "millimeter": 0.001,
}


def band_height_unit(band, z_to_m):
    """``(metres per height unit, warning or None, the unit's name or "")``: the unit the band states for its values
    (GDAL's unit type) when it names a length of :data:`BAND_HEIGHT_UNITS`, else ``z_to_m``
    (the unit the CRS gives, :func:`cell_size_metres`). The band's own statement of its values
    wins over the CRS's unit: a grid in US feet with heights in metres, or in metres with heights
    in feet, is read as its band says."""
    unit = (band.GetUnitType() or "").strip()
    f = BAND_HEIGHT_UNITS.get(unit.lower())
    if f is None:
        return z_to_m, None, ""
    if math.isclose(f, z_to_m, rel_tol=1e-9):
        return z_to_m, None, unit
    return f, (f"The band states its heights are in '{unit}' ({f:.6g} m; its CRS would give {z_to_m:.6g} m): "
               "they were converted to metres for the thresholds with the band's unit; outputs are written "
               "back in it."), unit


#: A projected CRS made for measuring (UTM, national and state grids: transverse Mercator, Lambert
#: conformal conic...) keeps its scale within about 0.1 % of 1 over its zone; beyond 1 % the CRS
#: does not keep distances (Web Mercator: 1 / cos(latitude), 1.62 at 52 deg) and its units are not
#: metres on the ground.
PROJECTION_SCALE_TOLERANCE = 0.01


def projection_scale(srs, x, y, step_x=1.0, step_y=1.0, f=1.0):
    """Metres on the ground per metre of a projected CRS at the point ``(x, y)``, along x and
    along y: ``step_x`` east and ``step_y`` north of it (CRS units) taken to the CRS's
    geographic CRS (:func:`metres_per_degree`). ``f``: metres per CRS unit. ``(1.0, 1.0)``
    when the points cannot be transformed."""
    try:
        geo = srs.CloneGeogCS()
        for ref in (srs, geo):
            ref.SetAxisMappingStrategy(osr.OAMS_TRADITIONAL_GIS_ORDER)
        tr = osr.CoordinateTransformation(srs, geo)
        (lon0, lat0, _), (lon1, lat1, _), (lon2, lat2, _) = tr.TransformPoints(
            [(x, y), (x + step_x, y), (x, y + step_y)])
    except (RuntimeError, TypeError, ValueError, AttributeError):
        return 1.0, 1.0
    if not all(map(math.isfinite, (lon0, lat0, lon1, lat1, lon2, lat2))) or abs(lat0) > 90:
        return 1.0, 1.0
    mx, my = metres_per_degree(lat0)
    ground_x = math.hypot((lon1 - lon0) * mx, (lat1 - lat0) * my)
    ground_y = math.hypot((lon2 - lon0) * mx, (lat2 - lat0) * my)
    if not (ground_x > 0 and ground_y > 0):
        return 1.0, 1.0
    return ground_x / (step_x * f), ground_y / (step_y * f)


def ground_scale(srs, x, y, step_x=1.0, step_y=1.0, f=1.0):
    """The scale :func:`projection_scale` finds when it is beyond :data:`PROJECTION_SCALE_TOLERANCE`
    (one value for both axes when they agree within it: a conformal CRS such as Web Mercator,
    whose sphere on the WGS84 ellipsoid differs by 0.3 %), else None: the CRS keeps distances."""
    kx, ky = projection_scale(srs, x, y, step_x, step_y, f)
    if max(abs(kx - 1.0), abs(ky - 1.0)) <= PROJECTION_SCALE_TOLERANCE:
        return None
    if abs(kx / ky - 1.0) <= PROJECTION_SCALE_TOLERANCE:
        kx = ky = math.sqrt(kx * ky)
    return kx, ky


def cell_size_metres(geotransform, shape, srs=None):
    """Cell size ``(dx, dy)`` in metres, warnings, and metres per height unit, from a
    geotransform and a CRS.

    Geographic CRSs (degrees) are converted at the latitude of the raster's centre with
    the WGS84 ellipsoid's radii of curvature (:func:`metres_per_degree`). Heights are in the
    unit of the CRS's vertical part when it has one (a compound CRS,
    :func:`vertical_unit_factor`), else in a projected CRS's linear unit, else metres.
    """
    gt = geotransform
    dx, dy = abs(gt[1]), abs(gt[5])
    warns = []
    if srs is None or (srs.IsGeographic() == 0 and srs.IsProjected() == 0 and srs.IsVertical() == 0
                       and not srs.ExportToWkt()):
        warns.append("The raster has no CRS: its cell size and heights are taken to be in metres.")
        return (dx, dy), warns, 1.0
    vertical = vertical_unit_factor(srs)
    zf = vertical[0] if vertical else None
    if srs.IsGeographic():
        lat = gt[3] + gt[5] * shape[0] / 2.0
        if not -90 <= lat <= 90:
            raise ValueError(f"the raster's CRS is geographic but its centre latitude {lat:.3f} is "
                             "not a latitude: check the georeference.")
        m_per_deg_lon, m_per_deg_lat = metres_per_degree(lat)
        cell = (dx * m_per_deg_lon, dy * m_per_deg_lat)
        heights = ("are taken to be in metres" if zf is None or abs(zf - 1.0) <= 1e-9 else
                   f"are in its vertical unit '{vertical[1]}' ({zf:.6g} m), converted to metres for the "
                   "thresholds (outputs are written back in that unit)")
        warns.append(f"The raster's CRS is geographic (degrees): its cell size {dx:.3g} x {dy:.3g} deg "
                     f"was converted to {cell[0]:.4g} x {cell[1]:.4g} m at latitude {lat:.4f}; heights "
                     f"{heights}. Reproject to a projected CRS for exact distances.")
        return cell, warns, 1.0 if zf is None else zf
    if srs.IsProjected():
        f = float(srs.GetTargetLinearUnits("PROJCS")) if srs.IsCompound() else _linear_unit_factor(srs)
        f = f if math.isfinite(f) and f > 0 else 1.0
    else:                                   # a vertical CRS alone: no horizontal unit known
        f = 1.0
    if zf is None:
        zf = f
        if abs(f - 1.0) > 1e-9:
            unit = srs.GetLinearUnitsName()
            warns.append(f"The CRS's linear unit is '{unit}' ({f:.6g} m): cell size and heights were "
                         "converted to metres for the thresholds; outputs are written back in the raster's unit.")
    elif abs(f - 1.0) > 1e-9 or abs(zf - 1.0) > 1e-9:
        unit = srs.GetAttrValue("PROJCS|UNIT") or f"{f:.6g} m"
        warns.append(f"The CRS's horizontal unit is '{unit}' ({f:.6g} m) and its vertical unit '{vertical[1]}' "
                     f"({zf:.6g} m): cell size and heights were converted to metres for the thresholds; outputs "
                     "are written back in the raster's units.")
    cell = (dx * f, dy * f)
    scale = None
    if srs.IsProjected():
        scale = ground_scale(srs, gt[0] + gt[1] * shape[1] / 2.0 + gt[2] * shape[0] / 2.0,
                             gt[3] + gt[4] * shape[1] / 2.0 + gt[5] * shape[0] / 2.0, dx, dy, f)
    if scale is not None:
        kx, ky = scale
        cell = (cell[0] * kx, cell[1] * ky)
        warns.append(f"The CRS does not keep distances here: one of its metres is {kx:.4g} m on the ground at "
                     f"the raster's centre (e.g. Web Mercator), so its cell size {dx:.4g} x {dy:.4g} was "
                     f"converted to {cell[0]:.4g} x {cell[1]:.4g} m on the ground. Reproject to a projected "
                     "CRS made for measuring (UTM, a national grid) for exact distances.")
    return cell, warns, zf


def open_dsm(path, band=None, nodata_ranges=(), crs_wkt=None):
    """Open and check a single-band DSM before any work starts.

    Parameters
    ----------
    path : str
        Anything GDAL opens (VRTs with raw bands refused).
    band : int, optional
        1-based band index; required when the raster has several bands.
    nodata_ranges : sequence of (low, high, include_low, include_high), optional
        Heights (the raster's unit) that are nodata besides its own nodata: the additional
        no-data values of the QGIS layer the raster was given as (:attr:`DSMInfo.nodata_ranges`).
    crs_wkt : str, optional
        The CRS of a raster whose file has none (the CRS its QGIS layer was given): its cell
        size, heights and outputs are in that CRS. Ignored when the file has a CRS.

    Returns
    -------
    DSMInfo

    Raises
    ------
    ValueError
        For an unreadable (missing, corrupt, truncated at its first cell), empty, too small,
        rotated, complex-valued or multi-band raster without ``band``, cells under
        :data:`MIN_CELL_M`, a band out of range, or a refused VRT.
    """
    need_gdal()
    try:
        ds = _open_read(str(path))
    except ValueError as exc:
        if "is refused" in str(exc):
            raise
        raise ValueError(f"{exc} Check the path and format.") from None
    if ds is None:
        raise ValueError(f"cannot open the raster {str(path)!r}. Check the path and format.")
    nb = ds.RasterCount
    if nb == 0:
        raise ValueError(f"the raster {path!r} has no band: pass a single-band DSM.")
    alpha = [k for k in range(1, nb + 1) if ds.GetRasterBand(k).GetColorInterpretation() == gdal.GCI_AlphaBand]
    if band in (None, 0) and nb > 1 and nb - len(alpha) == 1:
        band = next(k for k in range(1, nb + 1) if k not in alpha)   # heights + alpha: the heights
    if band in (None, 0):
        if nb > 1:
            names = [(ds.GetRasterBand(k).GetDescription() or "").strip() for k in range(1, nb + 1)]
            named = (" Its bands: " + ", ".join(f"{k} {n}" for k, n in enumerate(names, 1) if n) + "."
                     if any(names) else "")       # PDAL's writers.gdal: min, max, mean, idw, count, stdev
            raise SeveralBands(f"the raster {path!r} has {nb} bands: a DSM has one. Choose the height band "
                               "with the BAND parameter (1..{nb}) or extract it first.".replace("{nb}", str(nb))
                               + named, nb)
        band = 1
    if not 1 <= int(band) <= nb:
        raise ValueError(f"band {band} does not exist: the raster {path!r} has {nb} band(s).")
    if int(band) in alpha:     # its 0 / 255 read as heights: a flat DTM of 255 m, every cell ground
        others = [k for k in range(1, nb + 1) if k not in alpha]
        raise ValueError(f"band {band} of the raster {path!r} is its alpha band (transparency: 0 where a cell is "
                         f"not drawn), not heights: choose the height band"
                         + (f" ({', '.join(map(str, others))})." if others else "."))
    kind = ds.GetRasterBand(int(band)).DataType
    if gdal.DataTypeIsComplex(kind):          # numpy would drop the imaginary parts with a warning only
        raise ValueError(f"the raster {path!r} holds complex numbers ({gdal.GetDataTypeName(kind)}): heights are "
                         "real numbers. Write the heights as a real type first (gdal_translate -ot Float32).")
    rows, cols = ds.RasterYSize, ds.RasterXSize
    if rows == 0 or cols == 0:
        raise ValueError(f"the raster {path!r} is empty ({cols} x {rows} cells).")
    if rows < MIN_SIDE or cols < MIN_SIDE:
        raise ValueError(f"the raster {path!r} is too small ({cols} x {rows} cells): the filters need at "
                         f"least {MIN_SIDE} x {MIN_SIDE} cells.")
    gt = ds.GetGeoTransform(can_return_null=True)
    warns = []
    if gt is None:
        gt = (0.0, 1.0, 0.0, float(rows), 0.0, -1.0)
        warns.append("The raster has no georeference: cells are taken as 1 m squares.")
    if is_rotated(gt, (rows, cols)):
        raise ValueError(f"the raster {path!r} is rotated (geotransform terms {gt[2]}, {gt[4]}): "
                         "warp it to a north-up grid first (gdalwarp).")
    wkt = ds.GetProjection() or ""
    if not wkt and crs_wkt:
        wkt = str(crs_wkt)
        warns.append("The raster has no CRS of its own: the CRS its layer was given in QGIS is used (its cell "
                     "size, heights and outputs are in it).")
    srs = None
    if wkt:
        srs = osr.SpatialReference()
        srs.ImportFromWkt(wkt)
    cell, w2, z_to_m = cell_size_metres(gt, (rows, cols), srs)
    cell = as_cell_size(cell)               # without the float noise of its computation
    if min(cell) < MIN_CELL_M:
        size = f"{cell[0]:.3g} x {cell[1]:.3g} m"
        if srs is not None and srs.IsGeographic():
            raise ValueError(f"the raster {path!r} has cells of {size} on the ground at its latitude: degrees of "
                             "longitude shrink to nothing near a pole, and no DSM has cells under 1 mm. Reproject "
                             "it to a projected CRS (near a pole a polar stereographic one, e.g. EPSG:3413 or "
                             "EPSG:3031) first.")
        raise ValueError(f"the raster {path!r} has cells of {size} ({abs(gt[1]):.3g} x {abs(gt[5]):.3g} in "
                         f"{'its CRS' if srs is not None else 'metres, having no CRS'}): no DSM has cells under "
                         "1 mm, so its cell size is probably in degrees. Give it its real CRS (e.g. gdal_edit.py "
                         "-a_srs EPSG:4326) first.")
    warns += w2
    b = ds.GetRasterBand(int(band))
    z_to_m, unit_warning, unit_type = band_height_unit(b, z_to_m)
    if unit_warning:
        warns.append(unit_warning)
    nodata = b.GetNoDataValue()
    dtype = gdal.GetDataTypeName(b.DataType)
    scale, offset = b.GetScale(), b.GetOffset()
    scale = 1.0 if scale in (None, 0) else float(scale)
    offset = 0.0 if offset is None else float(offset)
    if not (math.isfinite(scale) and math.isfinite(offset)):   # every height NaN: was "every cell is nodata"
        raise ValueError(f"the raster {str(path)!r} band {int(band)} declares a scale of {scale:g} and an offset of "
                         f"{offset:g} (heights = stored values x scale + offset): no height can be read. Give the band "
                         "a finite scale and offset (gdal_edit.py -scale 1 -offset 0 <file>, or the values the data "
                         "was stored with).")
    if abs(cell[0] - cell[1]) > 1e-6 * max(cell):
        warns.append(f"Cells are not square ({cell[0]:.4g} x {cell[1]:.4g} m): each direction uses its own spacing.")
    info = DSMInfo(str(path), int(band), (rows, cols), tuple(gt), wkt, nodata, cell, z_to_m,
                   dtype=dtype, warnings=warns, _ds=ds, scale=scale, offset=offset, unit_type=unit_type)
    if ds.GetGeoTransform(can_return_null=True) is None:
        info.georeferenced = False
        info.gcps = tuple((g.GCPX, g.GCPY, g.GCPZ, g.GCPPixel, g.GCPLine) for g in (ds.GetGCPs() or ()))
        info.gcp_wkt = ds.GetGCPProjection() or ""
    if nodata_ranges:
        info.nodata_ranges = tuple((float(lo), float(hi), bool(a), bool(b)) for lo, hi, a, b in nodata_ranges)
        info.notes.append("Cells of the layer's additional no-data values ({}) are nodata.".format(", ".join(
            f"{lo:g}" if lo == hi else f"{lo:g} to {hi:g}" for lo, hi, _, _ in info.nodata_ranges)))
    own_alpha = [k for k in alpha if k != int(band)]
    if own_alpha:
        info.masked = own_alpha[0]
        info.notes.append(f"Cells where the alpha band (band {own_alpha[0]}) is 0 (drawn transparent) are nodata.")
    elif not b.GetMaskFlags() & (gdal.GMF_ALL_VALID | gdal.GMF_NODATA):
        info.masked = -1
        info.notes.append("Cells masked by the raster's mask band (drawn transparent) are nodata.")
    if scale != 1.0 or offset != 0.0:
        info.notes.append(f"Heights are the band's stored values x {scale:g} + {offset:g} (its scale and "
                          "offset); the DTM and nDSM are written as those heights.")
    info.read_stored((rows // 2, rows // 2 + 1, cols // 2, cols // 2 + 1))   # unreadable: ValueError now
    return info


def _sample_windows(info, max_cells):
    """Windows ``(r0, r1, c0, c1)`` of whole blocks of the band's own layout (tiles, or strips of whole rows; cut to
    ``max_cells`` cells where a block holds more), spread evenly over the raster, holding about ``max_cells`` cells
    together: a sample that decompresses only the blocks it reads (a decimated read of a raster without overviews
    decompresses every block)."""
    rows, cols = info.shape
    bw, bh = info.dataset().GetRasterBand(info.band_index).GetBlockSize()
    bw, bh = max(1, min(int(bw), cols)), max(1, min(int(bh), rows))
    if bw * bh < 4096:                      # small blocks (strips of a row or a few): several in one window
        bh *= max(1, int(math.ceil(4096 / (bw * bh))))
        bh = min(bh, rows)
    if bw * bh > max_cells:                 # huge blocks (one strip of the whole raster): a window of max_cells
        bh = max(1, min(bh, max_cells // bw))
        bw = min(bw, max_cells)
    n_r, n_c = -(-rows // bh), -(-cols // bw)
    n = max(1, int(max_cells // (bw * bh)))
    pick_r = max(1, min(n_r, int(round(math.sqrt(n * n_r / n_c)))))
    pick_c = max(1, min(n_c, n // pick_r))
    out = []
    for br in np.unique(np.linspace(0, n_r - 1, pick_r).round().astype(int)):
        for bc in np.unique(np.linspace(0, n_c - 1, pick_c).round().astype(int)):
            out.append((int(br) * bh, min(rows, (int(br) + 1) * bh), int(bc) * bw, min(cols, (int(bc) + 1) * bw)))
    return out


def _has_overviews(info):
    return info.dataset().GetRasterBand(info.band_index).GetOverviewCount() > 0


def _empty_region(info, window):
    """Whether GDAL says ``window`` holds no written block (a sparse GeoTIFF's missing blocks) that reads as
    the declared nodata: skipped by a scan for data. False when the driver cannot tell or no nodata is
    declared (missing blocks then read as 0, a height)."""
    if info.nodata is None or info.masked:
        return False
    r0, r1, c0, c1 = window
    try:
        flags, _ = info.dataset().GetRasterBand(info.band_index).GetDataCoverageStatus(c0, r0, c1 - c0, r1 - r0)
    except (RuntimeError, AttributeError, TypeError):
        return False
    return flags == gdal.GDAL_DATA_COVERAGE_STATUS_EMPTY


def check_has_data(info, max_cells=4_000_000):
    """Scan the band (sampled when large) and raise ValueError if it holds no valid cell.

    A raster of at most ``max_cells`` cells is read whole; a larger one every ``step``-th cell when it has
    overviews (GDAL reads them), else on whole blocks spread over it (:func:`_sample_windows`): a decimated
    read of a raster without overviews decompressed every block (16 s for a dialog's check of a sparse
    33000 x 33000 GeoTIFF). When the sample holds no valid cell (sparse data between the samples), every cell
    is checked, strip by strip, skipping the strips GDAL says hold no written block.

    The message says whether the cells are all nodata or hold heights beyond
    ``common.MAX_ABS_HEIGHT_M`` (heights in millimetres or centimetres without the band's
    scale, or an undeclared nodata). Also notes NaN cells without a declared nodata
    (``info.note_nan``). Returns the fraction of valid cells seen.
    """
    rows, cols = info.shape
    step = max(1, int(math.ceil(math.sqrt(info.cells / max_cells))))

    def heights(a, window=None, step=1):   # metres, as the filters read them
        return without_far_heights(info.surface(a, window, step))

    if step == 1 or _has_overviews(info):
        a = info.read_stored(step=step)
        z, n_far = heights(a, step=step)
        info.note_nan(a)
        seen, n_valid = z.size, int(np.count_nonzero(np.isfinite(z)))
    else:
        seen = n_valid = n_far = 0
        for w in _sample_windows(info, max_cells):
            a = info.read_stored(w)
            z, n = heights(a, w)
            info.note_nan(a)
            n_far += n
            seen += z.size
            n_valid += int(np.count_nonzero(np.isfinite(z)))
    if step > 1 and not n_valid:  # sparse data may fall between the samples: check every cell
        strip = max(1, max_cells // cols)
        for r in range(0, rows, strip):
            w = (r, min(rows, r + strip), 0, cols)
            if _empty_region(info, w):
                continue
            zs, n = heights(info.read_stored(w), w)
            n_far += n
            if np.isfinite(zs).any():
                n_valid, seen = int(np.count_nonzero(np.isfinite(zs))), zs.size
                break
    if not n_valid and n_far:
        unit = ""
        if info.z_to_m != 1.0:
            unit = (f" Its heights are read in its CRS's unit ({info.z_to_m:g} m): if they are in metres, give "
                    "it a compound CRS whose vertical axis is in metres, or reproject it to a CRS in metres.")
        raise ValueError(f"the raster {info.path!r} has no valid cell: its cells are nodata or hold heights "
                         f"beyond +-{MAX_ABS_HEIGHT_M:g} m (or infinite), which no terrain has.{unit} If the "
                         "heights are in millimetres or centimetres, give the band its scale (e.g. gdal_edit.py "
                         "-scale 0.001 for millimetres); if that value marks missing cells, declare it as the "
                         "nodata value.")
    if not n_valid:
        raise ValueError(f"the raster {info.path!r} has no valid cell: every cell is nodata"
                         f"{'' if info.nodata is None else f' ({info.nodata})'}. Check the nodata value.")
    return n_valid / max(1, seen)


#: Values software writes for missing cells (ESRI and most GIS -9999, Int16 rasters -32767 and
#: -32768, older exports -99999, -999 of many exports, instruments and the netCDF/ASCII grids of
#: agencies, unsigned rasters and many exports' background 0; above the heights: 9999, the
#: largest Int16 and UInt16): when a raster does not declare one, its cells read as heights. 0 is
#: also sea level: only a 0 standing further below the other heights than they span is named (a
#: coast's sea beside its land is not).
COMMON_NODATA = (-9999.0, -99999.0, -999.0, -32767.0, -32768.0, 0.0, 9999.0, 32767.0, 65535.0)


def undeclared_nodata_warning(info, z):
    """The log line when heights ``z`` (float32 metres, NaN nodata, read from ``info``) hold a
    value of :data:`COMMON_NODATA` that the band does not declare, standing further below (or
    above) every other height than those heights span (a cliff no terrain has: -9999 beside
    ground at +300 m), else None. Such cells are filtered as heights: below, the DTM beside them
    is pulled down; above, they are objects with a DTM interpolated under them.

    Such a value is the lowest (highest) height, so only a value read as ``min(z)`` (``max(z)``)
    is looked at (two passes over the raster, two more when it is one of them)."""
    if not np.isfinite(z).any():
        return None
    ends = (np.nanmin(z), np.nanmax(z))
    for v in COMMON_NODATA:
        if info.nodata is not None and float(info.nodata) == v:
            continue
        h = to_surface(np.array([v]), None, info.z_to_m, info.scale, info.offset)[0]   # as read
        if h not in ends:
            continue
        hit = z == h
        n = int(np.count_nonzero(hit))
        rest = np.where(hit, np.float32(np.nan), z)
        if not np.isfinite(rest).any():
            return None
        lo, hi = float(np.nanmin(rest)), float(np.nanmax(rest))
        below = float(h) < lo
        gap = lo - float(h) if below else float(h) - hi
        if gap > hi - lo:
            effect = ("which pulls the DTM beside them down" if below else
                      "so the mask calls them objects and the DTM is interpolated under them")
            return (f"{n} cell(s) hold {v:g}, a common nodata value, {gap:.0f} m {'below' if below else 'above'} "
                    f"every other height (those span {lo:.1f} to {hi:.1f} m), but the raster does not declare "
                    f"{v:g} as its nodata: they were filtered as heights, {effect}. If they are missing cells, "
                    f"declare it (gdal_edit.py -a_nodata {v:g} <file>; in QGIS, give the layer {v:g} as an "
                    "additional no-data value in its Properties > Transparency) and run again.")
    return None


def nodata_among_heights_warning(info, z, max_cells=250_000):
    """The log line when the band's declared nodata value, read as a height, lies among the
    heights ``z`` (float32 metres, NaN nodata, read from ``info``): strictly between their 1st
    and 99th percentiles (a DSM of heights rounded to whole metres declaring 300 as nodata on a
    hill at 290-310 m, or 0 on a polder below and above sea level), else None. Every cell that
    holds it is read as missing, so where it is also a real height, those heights are lost
    without a word: their cells are left out of the filtering, and nodata in the DTM and mask.

    A nodata value below (or above) the heights, as software writes them (-9999, 0 under
    ground above sea level), is never named. The percentiles come from at most ``max_cells``
    cells of ``z`` (every ``step``-th row and column)."""
    nd = info.nodata
    if nd is None or not math.isfinite(float(nd)):
        return None
    h = float(to_surface(np.array([nd], np.float64), None, info.z_to_m, info.scale, info.offset)[0])
    if not math.isfinite(h):
        return None
    step = max(1, int(math.ceil(math.sqrt(z.size / max_cells))))
    sample = z[::step, ::step]
    heights = sample[np.isfinite(sample)]
    if heights.size < 2:
        return None
    lo, hi = (float(v) for v in np.percentile(heights, [1.0, 99.0]))
    if not lo < h < hi:
        return None
    n = int(z.size - np.count_nonzero(np.isfinite(z)))
    value = f"{float(nd):g}" + ("" if h == float(nd) else f" (a height of {h:g} m)")
    return (f"The raster declares {float(nd):g} as its nodata value, but {value} lies among its heights "
            f"(98 % of them span {lo:.1f} to {hi:.1f} m): every cell holding exactly {float(nd):g} is read as "
            f"missing ({n} cell(s) read as nodata), left out of the filtering and nodata in the DTM and mask. "
            f"If {float(nd):g} is also a real height there (heights rounded to whole units, ground at sea "
            "level), those heights are lost: export the DSM again with a nodata value outside its heights "
            "(e.g. -9999).")


def read_mask(info, what="the mask"):
    """The codes of a mask band as uint8; NaN cells and those of a declared nodata outside
    0-255 (e.g. -9999) are 255 (a nodata within 0-255 is itself a code and stays as stored).

    A mask holds whole numbers 0-255 (a Bare Earth mask: 0 ground, 1 object, 2 low outlier,
    255 nodata; a classification's codes are accepted too). ValueError naming ``what``, the
    file and a value found when a cell holds anything else (a DSM or a float raster given as
    a mask), so it is refused before any work instead of read as codes.
    """
    a = info.read_stored()
    nodata = np.zeros(a.shape, bool)
    if a.dtype.kind == "f":
        nodata |= np.isnan(a)
    if info.nodata is not None and not math.isnan(info.nodata) and not 0 <= info.nodata <= 255:
        nodata |= a == info.nodata
    return as_mask_codes(a, nodata, f"{what} {info.path!r}", "Give the object mask a Bare Earth filter wrote, "
                         "or convert the raster into such codes first.")


#: GDAL's block cache during a blocked run, bytes. Blocks (2048) are whole 256-cell output
#: tiles, so no tile waits in the cache for a later block.
BLOCK_MODE_CACHE = 64 * 2 ** 20


@contextlib.contextmanager
def bounded_cache(active=True, size=BLOCK_MODE_CACHE):
    """Cap GDAL's block cache while a raster is processed block by block.

    GDAL keeps written tiles in its cache (by default 5 % of the RAM); in block mode that
    cache, not the blocks, would grow with the raster. The previous size is restored when the
    last of overlapping runs ends (:class:`SessionSetting`).
    """
    if not active or gdal is None:
        yield
        return
    with _CACHE.changed(lambda before: min(before, size)):
        yield
