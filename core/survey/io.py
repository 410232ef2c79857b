"""GDAL I/O of a survey: the survey VRT, the sources of a VRT, CRS comparison and the
tiles' cloud-optimised outputs.

The survey's one GDAL module (the rest of :mod:`core.survey` is GDAL-free). Single rasters
are opened and read through :func:`core.grid.open_dsm`; this module adds what a set of
tiles needs: a VRT over them (the neighbours' cells a task reads as its halo), the list
of a VRT's sources (missing ones included, which GDAL's own file list leaves out), and
COG outputs written under a temporary name and renamed only when complete.
"""
import os
import uuid
import xml.etree.ElementTree as ElementTree

import numpy as np

try:
    from osgeo import gdal, osr
except ImportError:  # pragma: no cover - GDAL ships with QGIS
    gdal = osr = None

from ..codes import MASK_CODES, MASK_COLOURS
from ..common import write_failed

#: Tile edge of the COG outputs, cells.
COG_BLOCK = 256


def _need_gdal():
    if gdal is None:
        raise ImportError("GDAL's Python bindings are needed (python3-gdal on Debian; QGIS ships them).")
    gdal.UseExceptions()


def vrt_sources(path):
    """Paths of every source raster a VRT names (absolute), in order, without repeats.

    Parsed from the VRT's XML, so sources that no longer exist are listed too (GDAL's
    ``GetFileList`` leaves them out).
    """
    path = os.path.abspath(str(path))
    try:
        root = ElementTree.parse(path).getroot()
    except (OSError, ElementTree.ParseError) as exc:
        raise ValueError(f"cannot read the VRT {path!r}: {exc}. Check the path.") from None
    out = []
    for el in root.iter("SourceFilename"):
        name = (el.text or "").strip()
        if not name:
            continue
        if el.get("relativeToVRT", "0") == "1":
            name = os.path.join(os.path.dirname(path), name)
        name = os.path.normpath(name)
        if name not in out:
            out.append(name)
    return out


def same_crs(wkt_a, wkt_b):
    """True when two WKT strings describe the same CRS (both empty counts as the same)."""
    if not wkt_a or not wkt_b:
        return not wkt_a and not wkt_b
    if wkt_a == wkt_b:
        return True
    _need_gdal()
    a, b = osr.SpatialReference(), osr.SpatialReference()
    a.ImportFromWkt(wkt_a)
    b.ImportFromWkt(wkt_b)
    return bool(a.IsSame(b))


def crs_label(wkt):
    """A short name of a CRS for messages: ``EPSG:code`` when known, else its name."""
    if not wkt:
        return "no CRS"
    _need_gdal()
    s = osr.SpatialReference()
    s.ImportFromWkt(wkt)
    s.AutoIdentifyEPSG()
    code = s.GetAuthorityCode(None)
    return f"EPSG:{code}" if code else (s.GetName() or "unnamed CRS")


def build_vrt(path, sources, nodata=None, unit_type=""):
    """Write a VRT mosaic of ``sources`` at ``path`` (atomically) and return ``path``.

    Each source keeps its own nodata value; ``nodata`` is the VRT's, the value of the
    cells no source covers (``"nan"`` for float tiles without a declared nodata). ``unit_type``:
    the height unit the sources' bands state, stated by the VRT's band too (gdalbuildvrt drops it).
    """
    _need_gdal()
    path = str(path)
    tmp = f"{path}.partial-{uuid.uuid4().hex[:8]}.vrt"
    opts = gdal.BuildVRTOptions(VRTNodata=nodata) if nodata is not None else gdal.BuildVRTOptions()
    gdal.ErrorReset()
    ds = gdal.BuildVRT(tmp, [str(s) for s in sources], options=opts)
    if ds is None:
        raise ValueError(f"GDAL could not build a VRT of the {len(sources)} tiles.")
    if unit_type:
        ds.GetRasterBand(1).SetUnitType(unit_type)
    xml = (ds.GetMetadata("xml:VRT") or [""])[0]
    ds = None
    held = [e.text or "" for e in ElementTree.fromstring(xml).iter("SourceFilename")] if xml else []
    if len(held) < len(sources):   # gdalbuildvrt skips, with a warning only, sources it cannot mix
        names = {os.path.basename(h) for h in held}
        left_out = [s for s in sources if os.path.basename(str(s)) not in names] or list(sources)
        os.remove(tmp)
        names = ", ".join(os.path.basename(str(s)) for s in left_out[:8]) + (" ..." if len(left_out) > 8 else "")
        raise ValueError(f"GDAL left {len(sources) - len(held)} of the {len(sources)} tiles out of the VRT: {names} "
                         f"({gdal.GetLastErrorMsg().strip() or 'their bands differ from the others'}).")
    # the VRT names its sources relative to its own folder; the temporary has the same one
    os.replace(tmp, path)
    return path


def read_raw(path, window):
    """Values of band 1 of ``path`` over ``(r0, r1, c0, c1)`` as stored (no unit or nodata
    conversion)."""
    _need_gdal()
    ds = gdal.Open(str(path))
    r0, r1, c0, c1 = window
    return ds.GetRasterBand(1).ReadAsArray(c0, r0, c1 - c0, r1 - r0)


def write_cog(path, array, geotransform, crs_wkt="", nodata=None, mask_style=False, unit_type=""):
    """Write a 2-D array as a cloud-optimised GeoTIFF, atomically.

    The COG is written under a temporary name in the same folder and renamed to ``path``
    only when complete, so a file at ``path`` is always whole; the ``.aux.xml`` of a file it replaces
    goes with it (its statistics, written by ``gdalinfo -stats``, would be read for the new file). Float32 arrays get
    DEFLATE with the floating-point predictor and averaged overviews; UInt8 masks
    (``mask_style``) a colour table with the mask codes and nearest-neighbour overviews.
    One thread per task (the workers already use every core). ``unit_type``: the height unit
    the band states (a DTM's, as its tile's band states it).
    """
    _need_gdal()
    a = np.asarray(array)
    gdt = gdal.GDT_Byte if a.dtype == np.uint8 else gdal.GDT_Float32
    mem = gdal.GetDriverByName("MEM").Create("", a.shape[1], a.shape[0], 1, gdt)
    mem.SetGeoTransform(tuple(geotransform))
    if crs_wkt:
        mem.SetProjection(crs_wkt)
    band = mem.GetRasterBand(1)
    if nodata is not None:
        band.SetNoDataValue(float(nodata))
    if unit_type:
        band.SetUnitType(unit_type)
    if mask_style:
        ct = gdal.ColorTable()
        for code, rgba in MASK_COLOURS.items():
            ct.SetColorEntry(code, rgba)
        band.SetRasterColorTable(ct)
        band.SetRasterColorInterpretation(gdal.GCI_PaletteIndex)
        names = [""] * 256
        for code, name in MASK_CODES.items():
            names[code] = name
        band.SetRasterCategoryNames(names)
    band.WriteArray(a)
    opts = [f"BLOCKSIZE={COG_BLOCK}", "COMPRESS=DEFLATE", "LEVEL=1", "NUM_THREADS=1", "BIGTIFF=IF_SAFER",
            "RESAMPLING=" + ("NEAREST" if mask_style else "AVERAGE")]
    if gdt == gdal.GDT_Float32:
        opts.append("PREDICTOR=YES")
    path = str(path)
    root, ext = os.path.splitext(path)
    tmp = f"{root}.partial-{uuid.uuid4().hex[:8]}{ext or '.tif'}"
    try:
        try:
            out = gdal.Translate(tmp, mem, options=gdal.TranslateOptions(format="COG", creationOptions=opts))
            if out is None:
                raise ValueError(f"GDAL could not write the COG {path!r}.")
            gdal.ErrorReset()
            out = None                          # closing writes the rest: GDAL only records its errors
            if gdal.GetLastErrorType() >= gdal.CE_Failure:
                raise RuntimeError(gdal.GetLastErrorMsg())
        except RuntimeError as exc:             # a full disk: the message every output gives
            raise write_failed(path, str(exc).strip() or gdal.GetLastErrorMsg().strip() or "GDAL gave no reason") \
                from None
        if os.path.exists(tmp + ".aux.xml"):    # the category names (GDAL's side file)
            os.replace(tmp + ".aux.xml", path + ".aux.xml")
        elif os.path.lexists(path + ".aux.xml"):  # the replaced file's (gdalinfo -stats): GDAL would read its
            os.remove(path + ".aux.xml")          # statistics and georeferencing for the new file
        os.replace(tmp, path)
    finally:
        for p in (tmp, tmp + ".aux.xml"):
            if os.path.exists(p):
                os.remove(p)
    return path
