"""Accuracy of a filter: Type I / II / total error, Cohen's kappa, DTM errors, reports.

The measures are those of the ISPRS filter test, Sithole & Vosselman (2004), "Experimental
comparison of filter algorithms for bare-Earth extraction from airborne laser scanning
point clouds", ISPRS J. Photogramm. Remote Sens. 59(1-2):85-101. With the cross matrix

============  ==================  ==================
reference     filtered: ground    filtered: object
============  ==================  ==================
ground        a                   b   (Type I)
object        c   (Type II)       d
============  ==================  ==================

Type I = b / (a + b), Type II = c / (c + d), total = (b + c) / n, all in percent, and
Cohen's kappa (percent) = (p_o - p_e) / (1 - p_e), with p_o = (a + d) / n and
p_e = ((a + b)(a + c) + (c + d)(b + d)) / n^2.

Reports: :func:`write_report` writes the figures as JSON and as one self-contained HTML
file (a table and, optionally, a map of the Type I / Type II errors embedded as a base64
PNG made with GDAL's PNG driver; no matplotlib).
"""
import base64
import datetime
import html
import json
import math
import os
import uuid

import numpy as np

from .codes import GROUND, NODATA, as_mask_codes
from .common import real_array, without_far_heights
from .pointfiles import part_path, remove_stale_parts

__all__ = ["confusion", "compare_masks", "compare_dtm", "error_map_from_masks",
           "error_map_from_points",
           "write_report", "ERROR_CORRECT", "ERROR_TYPE1", "ERROR_TYPE2", "ERROR_INVALID",
           "ERROR_LEGEND"]

ERROR_CORRECT = 0   #: classified as the reference says
ERROR_TYPE1 = 1     #: ground rejected (classified as object)
ERROR_TYPE2 = 2     #: object accepted as ground
ERROR_INVALID = 255  #: not evaluated (nodata in the result or the reference)

#: ``{code: (label, (r, g, b))}``: the fixed colours of an error map.
ERROR_LEGEND = {
    ERROR_CORRECT: ("correct", (222, 222, 222)),
    ERROR_TYPE1: ("Type I: ground rejected", (230, 50, 40)),
    ERROR_TYPE2: ("Type II: object accepted as ground", (30, 100, 230)),
    ERROR_INVALID: ("not evaluated", (255, 255, 255)),
}


def _pct(num, den):
    return float(100.0 * num / den) if den else float("nan")


def _as_bool(a, name):
    """``a`` as a bool array; ValueError when it holds anything but True / False (or 0 / 1).

    ``astype(bool)`` would read NaN and every code but 0 as True: a mask of codes (0 ground,
    1 object, 255 nodata) given as ``pred_ground`` would be scored with ground and objects
    swapped and its nodata as ground, without a word."""
    a = np.ma.filled(a, np.nan) if np.ma.isMaskedArray(a) else np.asarray(a)
    if a.dtype == bool:
        return a
    with np.errstate(invalid="ignore"):
        bad = ~((a == 0) | (a == 1))
    if bad.any():
        raise ValueError(f"{name} must be True / False per element (True = ground); it holds "
                         f"{int(np.count_nonzero(bad))} other value(s) (e.g. {a[bad].ravel()[0]!r}). For masks of "
                         "codes (0 ground, 1 object, 2 low outlier, 255 nodata) call compare_masks, or pass "
                         "mask == 0 and leave nodata out with valid.")
    return a.astype(bool)


def confusion(pred_ground, true_ground, valid=None):
    """Cross matrix and error rates of a ground / object classification.

    Parameters
    ----------
    pred_ground : array_like of bool
        True where the filter says ground (cells or points). Only True / False (or 0 / 1):
        anything else (NaN, a mask's codes 2 or 255) is refused with ValueError.
    true_ground : array_like of bool
        True where the reference says ground; same shape, the same values.
    valid : array_like of bool, optional
        Only these elements are counted (e.g. not nodata).

    Returns
    -------
    dict
        ``a`` ground->ground, ``b`` ground->object (Type I), ``c`` object->ground
        (Type II), ``d`` object->object, ``n``, ``n_ground``, ``n_object`` (ints);
        ``type1``, ``type2``, ``total``, ``kappa`` in percent (floats, NaN when undefined,
        e.g. Type II without any object).
    """
    p = _as_bool(pred_ground, "pred_ground")
    t = _as_bool(true_ground, "true_ground")
    if p.shape != t.shape:
        raise ValueError(f"prediction and reference differ in shape: {p.shape} vs {t.shape}; "
                         "compare arrays of the same cells/points.")
    if valid is not None:
        v = np.asarray(valid, dtype=bool)
        if v.shape != p.shape:
            raise ValueError(f"valid mask shape {v.shape} differs from the data's {p.shape}.")
        p, t = p[v], t[v]
    a = int(np.count_nonzero(p & t))
    b = int(np.count_nonzero(~p & t))
    c = int(np.count_nonzero(p & ~t))
    d = int(p.size - a - b - c)
    n = a + b + c + d
    # (p_o - p_e) / (1 - p_e) in whole numbers, one division: 2 (ad - bc) / ((a+b)(b+d) + (a+c)(c+d))
    # (a perfect classification is 100 exactly, not 100.00000000000001); p_e = 1 (one class only):
    # the denominator is 0 and kappa undefined
    den = (a + b) * (b + d) + (a + c) * (c + d)
    kappa = 200.0 * (a * d - b * c) / den if n and den else float("nan")
    return {"a": a, "b": b, "c": c, "d": d, "n": n, "n_ground": a + b, "n_object": c + d,
            "type1": _pct(b, a + b), "type2": _pct(c, c + d), "total": _pct(b + c, n),
            "kappa": float(kappa)}


def _codes(mask, what):
    """A mask's codes as uint8: NaN cells (a float mask) and a masked array's masked cells are
    255 (nodata); ValueError naming ``what`` when a cell holds no whole number 0-255 (the rule
    of :func:`bare_earth.core.grid.read_mask`: codes other than 0 1 2 255, a classification's,
    are objects). Without it -1 and 256 wrapped to 255 and 0 and 0.5 counted as an object."""
    masked = np.ma.getmaskarray(mask) if np.ma.isMaskedArray(mask) else None
    a = np.asarray(np.ma.getdata(mask) if masked is not None else mask)
    if a.dtype == np.uint8 and masked is None:
        return a
    if a.dtype != bool and not np.issubdtype(a.dtype, np.number) or np.issubdtype(a.dtype, np.complexfloating):
        raise ValueError(f"{what} must hold mask codes (0 ground, 1 object, 2 low outlier, 255 nodata); "
                         f"got dtype {a.dtype}.")
    nodata = np.isnan(a) if a.dtype.kind == "f" else np.zeros(a.shape, bool)
    if masked is not None:
        nodata |= masked
    return as_mask_codes(a, nodata, what, "Pass the mask a filter returned, or convert the array into such codes "
                         "first.")


def _masks(mask, truth_mask):
    m = _codes(mask, "mask")
    t = _codes(truth_mask, "reference mask")
    if m.shape != t.shape:
        raise ValueError(f"mask {m.shape} and reference mask {t.shape} differ in shape; "
                         "resample them to the same grid first.")
    return m, t


def check_reference_mask(codes, what="the reference mask"):
    """ValueError when a reference mask (uint8 codes, 255 nodata) holds no ground cell (code 0).

    Every cell would then be an object: Type I 'not defined' and a total error equal to the
    share of cells the other mask calls ground, without a word. The usual cause is another
    convention (ASPRS classes: 2 ground, 6 building; or 1 ground, 2 object), named with the
    codes found and the fix.
    """
    found = np.unique(np.asarray(codes)[np.asarray(codes) != NODATA])
    if found.size == 0 or (found == GROUND).any():
        return
    shown = ", ".join(str(int(c)) for c in found[:12]) + (", ..." if found.size > 12 else "")
    asprs = bool((found == 2).any() and (found > 2).any())
    hint = (" Code 2 looks like ASPRS classes (2 ground, 6 building)" if asprs
            else " Its ground may have another code")
    raise ValueError(f"{what} holds no ground cell (code 0): its codes are {shown}. Masks are compared with the "
                     f"codes 0 ground, 1 object, 2 low outlier, 255 nodata.{hint}: reclassify it first, 0 where "
                     "ground and 1 elsewhere (Raster calculator: \"reference@1\" != "
                     + ("2" if asprs else "its ground code") + ").")


def check_nodata_not_objects(codes, other, what="the reference mask", other_what="the mask"):
    """ValueError when a mask without any object code has its nodata (255) on the other mask's objects.

    The masks' cells of 255 are not compared. A binary mask of another tool (0 ground, 255 object, e.g.
    footprints burnt with 255) then loses every object cell: the comparison counts ground alone and
    reports a total error of 0 % (Type II and kappa not defined), without a word. Nodata is where the
    data ends, whatever lies there, so the other mask's objects fill its 255 cells in about the share
    they fill the cells it calls ground; here they fill most of them (more than half) and more than
    twice that share. A mask with an object code (1 or 2) is never refused.
    """
    c, o = np.asarray(codes), np.asarray(other)
    if c.shape != o.shape or np.isin(c, (1, 2)).any():
        return
    other_data = o != NODATA
    under_nodata = (c == NODATA) & other_data
    n = int(under_nodata.sum())
    if n == 0:
        return
    other_objects = np.isin(o, (1, 2))
    share_nodata = float(other_objects[under_nodata].sum()) / n
    under_ground = (c == GROUND) & other_data
    share_ground = float(other_objects[under_ground].sum()) / max(int(under_ground.sum()), 1)
    if share_nodata <= 0.5 or share_nodata <= 2.0 * share_ground:
        return
    raise ValueError(f"{what} holds no object code (1 or 2), only 0 and 255, and its {n} cell(s) of 255 where "
                     f"{other_what} has data lie on {other_what}'s objects ({100.0 * share_nodata:.0f} % of them, "
                     f"against {100.0 * share_ground:.0f} % of the cells it calls ground): 255 is nodata, never "
                     "compared, so every object would be left out and the total error would count the ground "
                     "alone. If 255 marks objects there (a 0/255 binary mask), reclassify it to 0 ground and 1 "
                     "object first (Raster calculator: \"mask@1\" = 255).")


def compare_masks(mask, truth_mask, valid=None):
    """:func:`confusion` of two masks with the codes 0 ground, 1/2 object, 255 ignored.

    Cells that are 255 (nodata) in either mask (NaN in a float mask, masked in a masked
    array), or False in ``valid``, are not counted. Codes other than 0, 1, 2 and 255 (a
    classification's) are objects; a value that is no whole number 0-255 is refused
    (ValueError).
    """
    m, t = _masks(mask, truth_mask)
    ok = (m != NODATA) & (t != NODATA)
    if valid is not None:
        ok &= np.asarray(valid, dtype=bool)
    return confusion(m == GROUND, t == GROUND, valid=ok)


def error_map_from_masks(mask, truth):
    """Per-cell error codes of a mask against a reference mask.

    Returns
    -------
    codes : ndarray of uint8
        0 correct, 1 Type I (reference ground, mask object), 2 Type II (reference object,
        mask ground), 255 not evaluated (255 in either mask).
    legend : dict
        :data:`ERROR_LEGEND`, ``{code: (label, (r, g, b))}``.
    """
    m, t = _masks(mask, truth)
    pg, tg = m == GROUND, t == GROUND
    codes = np.full(m.shape, ERROR_CORRECT, dtype=np.uint8)
    codes[tg & ~pg] = ERROR_TYPE1
    codes[~tg & pg] = ERROR_TYPE2
    codes[(m == NODATA) | (t == NODATA)] = ERROR_INVALID
    return codes, dict(ERROR_LEGEND)


def error_map_from_points(pred_ground, true_ground, x, y, geotransform, shape, valid=None,
                          fill_empty=None):
    """Grid the errors of a point classification: per cell the worst error of its points.

    Parameters
    ----------
    pred_ground, true_ground : array_like of bool
        Per point: the filter's and the reference's "is ground".
    x, y : array_like
        Point coordinates.
    geotransform : sequence of 6 floats
        Of the grid to fill (north-up or south-up: the map is in the grid's row order).
    shape : (rows, cols)
        Of the grid.
    valid : array_like of bool, optional
        Points to use.
    fill_empty : {None, "nearest"}
        Cells without a point: 255 (None), or the code of the nearest cell with a point
        (``"nearest"``; a readable map of sparse points, e.g. scan-line gaps).

    Returns
    -------
    codes : ndarray of uint8
        2 (Type II) if any point of the cell is a Type II error, else 1 (Type I) if any is
        a Type I error, else 0 (correct); 255 for cells without a point (unless filled).
    legend : dict
        :data:`ERROR_LEGEND`.
    """
    from .points import rasterize_points
    p = np.asarray(pred_ground, dtype=bool).ravel()
    t = np.asarray(true_ground, dtype=bool).ravel()
    x = np.asarray(x, dtype=np.float64).ravel()
    y = np.asarray(y, dtype=np.float64).ravel()
    if not (p.size == t.size == x.size == y.size):
        raise ValueError(f"pred_ground, true_ground, x and y differ in length: "
                         f"{p.size}, {t.size}, {x.size}, {y.size}; give one value per point.")
    code = np.where(t & ~p, ERROR_TYPE1, np.where(~t & p, ERROR_TYPE2, ERROR_CORRECT))
    if valid is not None:
        v = np.asarray(valid, dtype=bool).ravel()
        x, y, code = x[v], y[v], code[v]
    rows, cols = (int(v) for v in shape)
    gt = [float(v) for v in geotransform]
    dx, dy = abs(gt[1]), abs(gt[5])
    out = np.full((rows, cols), ERROR_INVALID, dtype=np.uint8)
    if code.size == 0:
        return out, dict(ERROR_LEGEND)
    # the grid's extent whatever its orientation (a south-up raster, gt[5] > 0, has its origin at
    # the south edge); the points are gridded north-up, then put in the grid's row order
    xs, ys = sorted((gt[0], gt[0] + gt[1] * cols)), sorted((gt[3], gt[3] + gt[5] * rows))
    extent = (xs[0], ys[0], xs[1], ys[1])
    inside = (x >= extent[0]) & (x <= extent[2]) & (y >= extent[1]) & (y <= extent[3])
    if not inside.any():
        return out, dict(ERROR_LEGEND)
    # codes 0 < 1 < 2 are also the priority (Type II wins): the highest code per cell
    grid, _ = rasterize_points(x[inside], y[inside], code[inside], (dx, dy), reducer="max",
                               extent=extent, fill_empty=fill_empty)
    r, c = min(rows, grid.shape[0]), min(cols, grid.shape[1])
    g = grid[:r, :c]
    out[:r, :c] = np.where(np.isnan(g), ERROR_INVALID, np.nan_to_num(g)).astype(np.uint8)
    return _in_grid_order(out, gt), dict(ERROR_LEGEND)


def _in_grid_order(a, gt):
    """A north-up array (row 0 north, column 0 west) in the row and column order of the grid
    ``gt`` (and back: the flips are their own inverse)."""
    if gt[5] > 0:
        a = a[::-1]
    if gt[1] < 0:
        a = a[:, ::-1]
    return np.ascontiguousarray(a)


def _stats(diff):
    n = int(diff.size)
    if n == 0:
        nan = float("nan")
        return {"rmse": nan, "mean": nan, "max_abs": nan, "n": 0}
    return {"rmse": float(np.sqrt(np.mean(diff * diff))), "mean": float(np.mean(diff)),
            "max_abs": float(np.max(np.abs(diff))), "n": n}


def compare_dtm(dtm, reference, ground=None):
    """Height errors of a DTM against a reference DTM (``dtm - reference``).

    Parameters
    ----------
    dtm, reference : array_like, 2-D
        Same shape; NaN = nodata (those cells are skipped), and so are the masked cells of
        a numpy masked array and heights beyond +-1e5 m (an undeclared nodata such as 1e30,
        the filters' rule, :data:`~bare_earth.core.common.MAX_ABS_HEIGHT_M`). Complex or
        non-numeric arrays are refused (ValueError).
    ground : array_like, optional
        Where to compute the ground-only figures: a bool array (True = ground), or a mask
        with the codes of :mod:`codes` (ground = 0), e.g. the reference mask.

    Returns
    -------
    dict
        ``rmse``, ``mean`` (bias), ``max_abs``, ``n`` over every cell valid in both;
        with ``ground``: also ``ground_rmse``, ``ground_mean``, ``ground_max_abs``,
        ``ground_n``.
    """
    a = without_far_heights(real_array(dtm, "dtm").astype(np.float64))[0]
    r = without_far_heights(real_array(reference, "reference").astype(np.float64))[0]
    if a.shape != r.shape:
        raise ValueError(f"DTM {a.shape} and reference {r.shape} differ in shape; "
                         "resample them to the same grid first.")
    diff = a - r
    ok = np.isfinite(diff)
    out = _stats(diff[ok])
    if ground is not None:
        g = ground if np.ma.isMaskedArray(ground) else np.asarray(ground)
        if g.shape != a.shape:
            raise ValueError(f"ground {g.shape} differs in shape from the DTM {a.shape}.")
        g = g if g.dtype == bool and not np.ma.isMaskedArray(g) else (_codes(g, "ground") == GROUND)
        out.update({f"ground_{k}": v for k, v in _stats(diff[ok & g]).items()})
    return out


# --------------------------------------------------------------------------- reports
def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return _jsonable(obj.tolist())
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.floating, float)):
        f = float(obj)
        return f if math.isfinite(f) else None
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    return obj


def _png_base64(rgb):
    """Encode an (rows, cols, 3) uint8 array as PNG (GDAL MEM -> PNG driver), base64."""
    from osgeo import gdal
    rows, cols, _ = rgb.shape
    mem = gdal.GetDriverByName("MEM").Create("", cols, rows, 3, gdal.GDT_Byte)
    for i in range(3):
        mem.GetRasterBand(i + 1).WriteArray(np.ascontiguousarray(rgb[:, :, i]))
    name = f"/vsimem/bare_earth_report_{uuid.uuid4().hex}.png"
    png = gdal.GetDriverByName("PNG").CreateCopy(name, mem)
    if png is None:
        raise RuntimeError(f"GDAL could not write the PNG map: {gdal.GetLastErrorMsg()}")
    png = None
    mem = None
    try:
        f = gdal.VSIFOpenL(name, "rb")
        gdal.VSIFSeekL(f, 0, 2)
        size = gdal.VSIFTellL(f)
        gdal.VSIFSeekL(f, 0, 0)
        data = gdal.VSIFReadL(1, size, f)
        gdal.VSIFCloseL(f)
    finally:
        gdal.Unlink(name)
    return base64.b64encode(bytes(data)).decode("ascii")


_PRIORITY = np.zeros(256, dtype=np.uint8)   # which code wins when cells are merged
_PRIORITY[[ERROR_INVALID, ERROR_CORRECT, ERROR_TYPE1, ERROR_TYPE2]] = [0, 1, 2, 3]
_FROM_PRIORITY = np.array([ERROR_INVALID, ERROR_CORRECT, ERROR_TYPE1, ERROR_TYPE2], np.uint8)


def _shrink(codes, max_side):
    """Block-reduce an error map so its longest side is <= max_side; errors win."""
    f = int(math.ceil(max(codes.shape) / max_side))
    if f <= 1:
        return codes
    r, c = codes.shape
    pr = _PRIORITY[codes]
    pad = np.zeros((-(-r // f) * f, -(-c // f) * f), dtype=np.uint8)
    pad[:r, :c] = pr
    blocks = pad.reshape(pad.shape[0] // f, f, pad.shape[1] // f, f).max(axis=(1, 3))
    return _FROM_PRIORITY[blocks]


def _error_map_rgb(codes, legend):
    lut = np.zeros((256, 3), dtype=np.uint8)
    lut[:] = (0, 0, 0)
    for code, (_, colour) in legend.items():
        lut[code] = colour
    return lut[np.asarray(codes, dtype=np.uint8)]


def _fmt(v):
    if isinstance(v, (bool, np.bool_)):
        return str(bool(v))
    if isinstance(v, (int, np.integer)):
        return f"{int(v):,}"
    if isinstance(v, (float, np.floating)):
        return "&ndash;" if not math.isfinite(float(v)) else f"{float(v):.2f}"
    return html.escape(str(v))


def _table(results):
    """HTML table: dict of dicts -> one row per key; flat dict -> measure / value rows."""
    rows = {k: v for k, v in results.items() if isinstance(v, dict)}
    scalars = {k: v for k, v in results.items() if not isinstance(v, (dict, list, tuple))}
    parts = []
    if rows:
        cols = []
        for v in rows.values():
            for k, x in v.items():
                if k not in cols and not isinstance(x, (dict, list, tuple, np.ndarray)):
                    cols.append(k)
        parts.append("<table>\n<tr><th></th>" + "".join(f"<th>{html.escape(str(c))}</th>"
                                                         for c in cols) + "</tr>")
        for name, v in rows.items():
            parts.append(f"<tr><th>{html.escape(str(name))}</th>" +
                         "".join(f"<td>{_fmt(v[c]) if c in v else ''}</td>" for c in cols)
                         + "</tr>")
        parts.append("</table>")
    if scalars:
        parts.append("<table>\n<tr><th>measure</th><th>value</th></tr>")
        for k, v in scalars.items():
            parts.append(f"<tr><th>{html.escape(str(k))}</th><td>{_fmt(v)}</td></tr>")
        parts.append("</table>")
    return "\n".join(parts)


_CSS = ("body{font-family:sans-serif;margin:2em;color:#222}table{border-collapse:collapse;"
        "margin:1em 0}th,td{border:1px solid #bbb;padding:3px 8px;text-align:right}"
        "th{background:#f0f0f0}img{image-rendering:pixelated;border:1px solid #888;"
        "max-width:100%}.sw{display:inline-block;width:1em;height:1em;border:1px solid #888;"
        "vertical-align:middle;margin-right:.4em}")


def _map_html(codes, geotransform, legend, caption, max_side):
    """One error map as HTML: caption, embedded PNG, legend with counts, grid size."""
    codes = np.asarray(codes)
    if codes.ndim != 2 or codes.size == 0:
        raise ValueError(f"error map {caption!r} must be a non-empty 2-D array; "
                         f"got shape {codes.shape}.")
    codes = codes.astype(np.uint8, copy=False)
    if geotransform is not None:           # drawn north-up whatever the grid's row order
        codes = _in_grid_order(codes, [float(v) for v in geotransform])
    small = _shrink(codes, max_side)
    b64 = _png_base64(_error_map_rgb(small, legend))
    zoom = max(1, 300 // max(small.shape))          # tiny maps shown at >= 300 px
    counts = {c: int(np.count_nonzero(codes == c)) for c in legend}
    out = [f"<h3>{html.escape(str(caption))}</h3>"] if caption else []
    out.append(f'<img alt="error map {html.escape(str(caption))}" width="{small.shape[1] * zoom}" '
               f'src="data:image/png;base64,{b64}">')
    items = "".join(f'<li><span class="sw" style="background:rgb{tuple(col)}"></span>'
                    f"{html.escape(label)}: {counts[c]:,} cells</li>"
                    for c, (label, col) in legend.items())
    out.append(f"<ul>{items}</ul>")
    size = f"<p>{codes.shape[0]} rows x {codes.shape[1]} columns"
    if geotransform is not None:
        gt = [float(v) for v in geotransform]
        size += f", origin ({gt[0]:.3f}, {gt[3]:.3f}), cell {gt[1]:g} x {abs(gt[5]):g}"
    if small.shape != codes.shape:
        size += f"; shown reduced to {small.shape[0]} x {small.shape[1]}"
    out.append(size + ".</p>")
    return "\n".join(out)


def _write_all(pages):
    """Write ``{path: (example name, text)}`` all or nothing: each to a hidden temporary file beside it, moved into
    place once every one is written, so that a failed report leaves no file that looks valid (a
    JSON beside a missing HTML). ValueError naming the path that cannot be written."""
    done = []
    try:
        for path, (name, text) in pages.items():
            path = os.path.abspath(os.fspath(path))
            if os.path.isdir(path):
                raise ValueError(f"the report output {path!r} is a folder: give a file name in it "
                                 f"(e.g. {os.path.join(path, name)!r}).")
            remove_stale_parts(path)         # a killed earlier write's work file
            tmp = part_path(path)
            done.append((tmp, path))
            try:
                with open(tmp, "w", encoding="utf-8") as fh:
                    fh.write(text)
            except OSError as exc:
                raise ValueError(f"the report {path!r} cannot be written ({exc.strerror}): choose a folder "
                                 "you can write to.") from None
        for tmp, path in done:
            os.replace(tmp, path)
        done = []
    finally:
        for tmp, _ in done:
            if os.path.exists(tmp):
                os.remove(tmp)


def write_report(results, json_path=None, html_path=None, error_map=None, geotransform=None,
                 title="Bare Earth accuracy report", legend=None, max_map_side=2000):
    """Write accuracy figures as JSON and/or a self-contained HTML page.

    Parameters
    ----------
    results : dict
        Figures: a flat dict (e.g. from :func:`confusion`) or a dict of dicts (one row per
        sample / method). NaN becomes ``null`` in JSON.
    json_path, html_path : str, optional
        Files to write (either or both).
    error_map : ndarray of uint8, or dict of str -> ndarray, optional
        Error codes (:func:`error_map_from_masks`) shown as a map in the HTML, embedded as
        a base64 PNG (maps larger than ``max_map_side`` are block-reduced, errors win).
        A dict gives several maps, each under its key as caption.
    geotransform : sequence of 6 floats, or dict of str -> sequence, optional
        Of ``error_map`` (a dict: one per map); origin and cell size are printed under
        the map.
    title : str
    legend : dict, optional
        ``{code: (label, (r, g, b))}``; default :data:`ERROR_LEGEND`.

    Returns
    -------
    dict
        ``{"json": path or None, "html": path or None}``.
    """
    if json_path is None and html_path is None:
        raise ValueError("write_report needs json_path and/or html_path; give a file to write.")
    if not isinstance(results, dict):
        raise ValueError(f"results must be a dict of figures; got {type(results).__name__}.")
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    pages = {}
    if json_path is not None:
        pages[json_path] = "report.json", json.dumps({"title": title, "created": stamp, "results": _jsonable(results)},
                                      indent=2, allow_nan=False)
    if html_path is not None:
        legend = dict(ERROR_LEGEND if legend is None else legend)
        body = [f"<h1>{html.escape(title)}</h1>", f"<p>Created {stamp}. Measures as in "
                "Sithole &amp; Vosselman (2004): Type I = ground rejected / all ground, "
                "Type II = objects accepted as ground / all objects, total = misclassified / "
                "all, Cohen's kappa; all in percent.</p>", _table(results)]
        if error_map is not None:
            maps = error_map if isinstance(error_map, dict) else {"": error_map}
            gts = geotransform if isinstance(geotransform, dict) else \
                {k: geotransform for k in maps}
            body.append("<h2>Error map" + ("s" if len(maps) > 1 else "") + "</h2>")
            for caption, codes in maps.items():
                body.append(_map_html(codes, gts.get(caption), legend, caption,
                                      int(max_map_side)))
        page = ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\">"
                f"<title>{html.escape(title)}</title><style>{_CSS}</style></head>\n<body>\n"
                + "\n".join(body) + "\n</body></html>\n")
        pages[html_path] = "report.html", page
    _write_all(pages)
    return {"json": None if json_path is None else os.fspath(json_path),
            "html": None if html_path is None else os.fspath(html_path)}
