"""PNG previews: DSM, DTM and mask side by side (hillshades and the mask colours)."""
import numpy as np

from .codes import MASK_COLOURS


def hillshade(z, cell=(1.0, 1.0), azimuth_deg=315.0, altitude_deg=45.0):
    """Hillshade in [0, 1] (NaN where ``z`` is NaN)."""
    dx, dy = cell
    zz = np.where(np.isfinite(z), z, np.nanmean(z))
    gy, gx = np.gradient(zz.astype(np.float64), dy, dx)
    slope = np.arctan(np.hypot(gx, gy))
    aspect = np.arctan2(-gx, gy)
    az, alt = np.radians(360.0 - azimuth_deg + 90.0), np.radians(altitude_deg)
    hs = np.sin(alt) * np.cos(slope) + np.cos(alt) * np.sin(slope) * np.cos(az - aspect)
    hs = np.clip(hs, 0, 1)
    hs[~np.isfinite(z)] = np.nan
    return hs


def _shade_rgb(z, cell, lo, hi):
    """Hypsometric tint times hillshade, uint8 RGB."""
    t = np.clip((z - lo) / max(hi - lo, 1e-6), 0, 1)
    base = np.stack([0.35 + 0.55 * t, 0.55 + 0.25 * t, 0.30 + 0.20 * t], axis=-1)
    hs = hillshade(z, cell)
    rgb = base * (0.35 + 0.65 * np.nan_to_num(hs, nan=1.0))[..., None]
    rgb[~np.isfinite(z)] = 1.0
    return (255 * np.clip(rgb, 0, 1)).astype(np.uint8)


def mask_rgb(mask):
    rgb = np.full(mask.shape + (3,), 255, np.uint8)
    for code, (r, g, b, a) in MASK_COLOURS.items():
        if a:
            rgb[mask == code] = (r, g, b)
    return rgb


def write_preview(path, dsm_path, dtm_path, mask_path, gap=8):
    """Write ``path`` (PNG): DSM | DTM | mask, each shaded, side by side. Returns the path."""
    from osgeo import gdal

    from .grid import open_dsm
    dsm, dtm = open_dsm(dsm_path), open_dsm(dtm_path)
    zd, zt = dsm.read(), dtm.read()
    mds = gdal.Open(str(mask_path))  # keep the dataset alive while its band is read
    m = mds.GetRasterBand(1).ReadAsArray()
    mds = None
    lo, hi = np.nanpercentile(zt, 1), np.nanpercentile(zd, 99)
    panels = [_shade_rgb(zd, dsm.cell_size_m, lo, hi), _shade_rgb(zt, dtm.cell_size_m, lo, hi), mask_rgb(m)]
    h, w = zd.shape
    img = np.full((h, 3 * w + 2 * gap, 3), 255, np.uint8)
    for k, p in enumerate(panels):
        img[:, k * (w + gap): k * (w + gap) + w] = p
    mem = gdal.GetDriverByName("MEM").Create("", img.shape[1], img.shape[0], 3, gdal.GDT_Byte)
    for b in range(3):
        mem.GetRasterBand(b + 1).WriteArray(img[..., b])
    gdal.GetDriverByName("PNG").CreateCopy(str(path), mem)
    return str(path)
