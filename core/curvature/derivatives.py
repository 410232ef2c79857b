"""The local surface fit and its curvatures (Luong Chinh Ke 2002, sec. 2.2, eqs. 9-16).

Steps 1 and 2 of the filter: the least-squares local trend around every cell gives the
derivatives p, q, r, s, t, the Gaussian curvature K and the mean curvature H; breaks are
the cells with ``|K| >= K_g`` or whose X or Y profile bends by ``sqrt(K_g)`` or more
(:func:`mark_breaks`).
"""
from dataclasses import dataclass
from typing import Callable, Iterator, Optional, Tuple, Union

import numpy as np

from ..common import as_cell_size, as_surface, report

MODELS = ("quadratic", "bilinear")

#: ``(dx, dy)`` in metres, or one number for square cells.
CellSize = Union[float, Tuple[float, float]]
#: ``progress(fraction)``; it may raise :class:`~bare_earth.core.common.Cancelled`.
Progress = Callable[[float], None]

#: Heights are bounded to +-this (m) for the arithmetic: no terrain comes near it, and with
#: bounded heights every product of the fit and of K and H stays within float32's range
#: (cells down to 1 mm), so heights such as +-1e30 (a nodata value not declared) give
#: large spikes, not overflow.
HEIGHT_BOUND_M = 1.0e6

#: Cells per block of rows of the element-wise work (cache-sized); used by every
#: submodule of the filter.
CHUNK_CELLS = 1 << 16


def bounded_heights(z: np.ndarray) -> np.ndarray:
    """``z`` (float32) with heights beyond +-:data:`HEIGHT_BOUND_M` set to that bound
    (a copy only when some are); NaN stays NaN."""
    with np.errstate(invalid="ignore"):
        lo, hi = np.nanmin(z), np.nanmax(z)
    if lo >= -HEIGHT_BOUND_M and hi <= HEIGHT_BOUND_M:
        return z
    return np.clip(z, np.float32(-HEIGHT_BOUND_M), np.float32(HEIGHT_BOUND_M))


def check_window(window: int) -> int:
    """``window`` as an odd integer >= 3 (ValueError naming the fix otherwise)."""
    if isinstance(window, bool) or not isinstance(window, (int, np.integer)):
        if isinstance(window, float) and float(window).is_integer():
            window = int(window)
        else:
            raise ValueError(f"window_cells must be an odd integer >= 3 (cells per profile "
                             f"group; the paper uses at least 5); got {window!r}.")
    window = int(window)
    if window < 3 or window % 2 == 0:
        raise ValueError(f"window_cells must be an odd integer >= 3 (cells per profile "
                         f"group; the paper uses at least 5); got {window}. Use e.g. 5 or 7.")
    return window


def check_model(model: str) -> str:
    """``model`` if it is one of :data:`MODELS` (ValueError naming the fix otherwise)."""
    if model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}; got {model!r}. Use 'quadratic' "
                         "(default) or 'bilinear' (the paper's eq. 12).")
    return model


def _bridge_nodata(z, m):
    """``z`` with the NaN cells within ``m`` cells of a valid one bridged from their
    nearest valid cell by point reflection (:func:`bridge_from_nearest`: planes stay
    planes, so gaps make no false breaks); ``z`` itself when complete. Those are all the
    nodata cells a window around a valid cell holds; the others stay NaN (they reach only
    the derivatives of nodata cells, which are NaN anyway)."""
    valid = np.isfinite(z)
    if valid.all():
        return z
    return bridge_from_nearest(z, valid, m, reflect=True)


def bridge_from_nearest(z: np.ndarray, known: np.ndarray, reach: int, *, reflect: bool,
                        fill: Optional[np.ndarray] = None, progress: Optional[Progress] = None) -> np.ndarray:
    """``z`` (float32, a copy) with the cells within ``reach`` cells (chessboard) of a
    ``known`` cell (and in ``fill``, when given) set from their nearest known cell n; the
    others as in ``z``.

    The nearest is searched among the offsets within the reach in a fixed order (by
    Euclidean distance, then row and column offset), so the value of a cell depends only
    on the cells within ``2 reach`` of it: a block that holds them gives the value of one
    pass. With ``reflect``, the point reflection through n, ``2 z[n] - z[2n - x]``, where
    the mirror cell 2n - x is known (exact on planes), else ``z[n]``; without, ``z[n]``.
    The cells are taken by chunks (bounded temporaries); ``progress(fraction)`` after each.
    """
    band = dilate(known, reach)
    band &= ~known
    if fill is not None:
        band &= fill
    report(progress, 0.0)
    out = np.array(z, dtype=np.float32)
    span = range(-reach, reach + 1)
    offsets = sorted(((a, b) for a in span for b in span if a or b), key=lambda o: (o[0] ** 2 + o[1] ** 2, o))
    kf, zf = known.ravel(), out.ravel()
    step = max(1, (16 * CHUNK_CELLS) // max(z.shape[1], 1))
    for i0 in range(0, z.shape[0], step):
        cells = np.flatnonzero(band[i0:i0 + step])
        if cells.size:
            cells += i0 * z.shape[1]
            zf[cells] = _from_nearest(zf, kf, z.shape, cells, offsets, reflect)
        report(progress, min(i0 + step, z.shape[0]) / z.shape[0])
    return out


def _from_nearest(zf, kf, shape, cells, offsets, reflect):
    """The values :func:`bridge_from_nearest` gives the flat ``cells`` (each has a known
    cell among ``offsets``); ``zf``, ``kf``: flat heights and known cells."""
    h, w = shape
    r, c = np.divmod(cells, w)
    near = np.zeros(cells.size, np.intp)
    todo = np.arange(cells.size)
    for dr, dc in offsets:
        rr, cc = r.take(todo) + dr, c.take(todo) + dc
        ok = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
        q = np.where(ok, rr * w + cc, 0)
        ok &= kf.take(q)
        near[todo[ok]] = q[ok]
        todo = todo[~ok]
        if todo.size == 0:
            break
    val = zf.take(near)
    if reflect:
        nr, nc = np.divmod(near, w)
        mr, mc = 2 * nr - r, 2 * nc - c
        ok = (mr >= 0) & (mr < h) & (mc >= 0) & (mc < w)
        m = np.where(ok, mr * w + mc, 0)
        ok &= kf.take(m)
        np.subtract(2 * val, zf.take(m), out=val, where=ok)
    return val


def dilate(mask: np.ndarray, m: int) -> np.ndarray:
    """``mask`` grown by ``m`` cells (square neighbourhood), by shifted ORs."""
    out = mask.copy()
    for k in range(1, m + 1):
        out[:, k:] |= mask[:, :-k]
        out[:, :-k] |= mask[:, k:]
    tmp = out.copy()
    for k in range(1, m + 1):
        out[k:] |= tmp[:-k]
        out[:-k] |= tmp[k:]
    return out


def local_derivatives(z: np.ndarray, cell_size: CellSize, *, window: int = 5,
                      model: str = "quadratic") -> Tuple[np.ndarray, ...]:
    """Least-squares local surface derivatives p, q, r, s, t for every cell.

    Parameters
    ----------
    z : array_like, 2-D
        Surface (NaN = nodata; nodata cells are bridged from their nearest valid cell
        for the fit, :func:`bridge_from_nearest`, and get NaN derivatives).
    cell_size : float or (float, float)
        ``(dx, dy)`` in metres.
    window : int
        Odd window edge in cells: the number of points per profile group (the paper asks
        for at least five).
    model : {"quadratic", "bilinear"}
        ``"quadratic"``: z = a + b x + c y + d x^2 + e xy + f y^2 (p=b, q=c, r=2d, s=e,
        t=2f). ``"bilinear"``: Luong Chinh Ke (2002) eq. 12, z = a0 + a1 X + a2 Y + a3 XY
        (p=a1, q=a2, s=a3, r=t=0).

    Returns
    -------
    p, q, r, s, t : ndarray of float32
        Derivatives at the window centre; x runs along columns, y along rows (down the
        array), in metres.

    Notes
    -----
    With centred coordinates u, v = -m..m (cells) over a full window, the columns 1, u,
    v, uv, u^2 - c, v^2 - c (c = mean u^2) of the design matrix are mutually orthogonal,
    so each least-squares coefficient is one separable kernel:
    b = sum(u z) / (w A dx), d = sum((u^2 - c) z) / (w B dx^2), e = sum(uv z) / (A^2 dx dy),
    with A = sum u^2, B = sum (u^2 - c)^2. The raster's edge is extended by odd
    reflection (planes stay planes), so edges do not create false breaks.
    """
    window = check_window(window)
    model = check_model(model)
    out = tuple(np.empty(as_surface(z).shape, np.float32) for _ in range(5))
    for _ in derivative_blocks(z, cell_size, window, model, out=out):
        pass
    return out


def _padded(z, m):
    """``z`` (float32, nodata bridged) padded by ``m`` cells by odd reflection (planes
    stay planes)."""
    zf = _bridge_nodata(z, m)
    rows, cols = z.shape
    if m <= min(rows, cols) - 1:
        # odd reflection written in place (as np.pad's "reflect"/"odd": rows first, then
        # columns over the padded rows), in float32
        zp = np.empty((rows + 2 * m, cols + 2 * m), np.float32)
        zp[m:m + rows, m:m + cols] = zf
        mid = zp[:, m:m + cols]
        for k in range(1, m + 1):
            np.subtract(2 * mid[m], mid[m + k], out=mid[m - k])
            np.subtract(2 * mid[m + rows - 1], mid[m + rows - 1 - k], out=mid[m + rows - 1 + k])
        for k in range(1, m + 1):
            np.subtract(2 * zp[:, m], zp[:, m + k], out=zp[:, m - k])
            np.subtract(2 * zp[:, m + cols - 1], zp[:, m + cols - 1 - k], out=zp[:, m + cols - 1 + k])
    elif min(rows, cols) < 2:
        zp = np.pad(zf, m, mode="edge").astype(np.float32)
    else:
        # odd reflection needs m < size; repeat for tiny arrays
        zp = zf
        left = m
        while left > 0:
            k = min(left, min(zp.shape) - 1)
            zp = np.pad(zp, k, mode="reflect", reflect_type="odd")
            left -= k
        zp = zp.astype(np.float32)
    return zp


def derivative_blocks(z: np.ndarray, cell_size: CellSize, window: int, model: str,
                      out: Optional[Tuple[np.ndarray, ...]] = None) -> Iterator[tuple]:
    """The local derivatives of :func:`local_derivatives`, block of rows by block.

    Yields ``(rows, p, q, r, s, t)`` for consecutive row slices ``rows``. Without ``out``
    the five arrays are buffers reused by the next block (cache-sized; nothing of the
    raster's size is allocated but the padded copy of ``z``); with ``out`` (five float32
    arrays of ``z``'s shape) they are written there and the views are yielded. NaN at
    nodata cells.
    """
    dx, dy = as_cell_size(cell_size)
    z = bounded_heights(as_surface(z))
    bad = ~np.isfinite(z)
    any_bad = bool(bad.any())
    m = window // 2
    zp = _padded(z, m)
    u = np.arange(-m, m + 1, dtype=np.float64)
    c = float(np.mean(u * u))
    A = float(np.sum(u * u))
    B = float(np.sum((u * u - c) ** 2))
    w = float(window)
    rows, cols = z.shape
    quad = model == "quadratic"
    scale = {"p": np.float32(1.0 / (w * A * dx)), "q": np.float32(1.0 / (w * A * dy)),
             "s": np.float32(1.0 / (A * A * dx * dy)), "r": np.float32(2.0 / (w * B * dx * dx)),
             "t": np.float32(2.0 / (w * B * dy * dy))}
    step = max(8, CHUNK_CELLS // max(cols, 1))
    nb = min(step, rows)
    first = ("slope", "bend") if quad else ("slope",)
    # buffers: the X pass over the block and its halo rows, the Y pass over the block's
    # rows and the halo columns, two scratch arrays for each
    bx = {k: np.empty((nb + 2 * m, cols), np.float32) for k in first + ("t1", "t2")}
    by = {k: np.empty((nb, cols + 2 * m), np.float32) for k in first + ("t1", "t2")}
    res = [np.empty((nb, cols), np.float32) for _ in range(5)] if out is None else None

    for i0 in range(0, rows, step):
        n = min(step, rows - i0)
        sl = slice(i0, i0 + n)
        blk = zp[i0:i0 + n + 2 * m]
        xk = {k: v[:n + 2 * m] for k, v in bx.items()}
        yk = {k: v[:n] for k, v in by.items()}
        if out is None:
            p_o, q_o, r_o, s_o, t_o = (v[:n] for v in res)
        else:
            p_o, q_o, r_o, s_o, t_o = (v[sl] for v in out)
        # first along the X profiles (axis 1) and along the Y profiles (axis 0) of the
        # heights: slopes and bends, differences only (no sum of absolute heights, so no
        # reference height is needed and a cell's result depends on its window alone)
        _kernels(blk, 1, cols, m, c, first, xk, xk["t1"], xk["t2"])
        _kernels(blk, 0, n, m, c, first, yk, yk["t1"], yk["t2"])
        # then across: p = Y box of the X slope, s = Y slope of the X slope, r = Y box of
        # the X bend; q = X box of the Y slope, t = X box of the Y bend
        _kernels(xk["slope"], 0, n, m, c, ("box", "slope"), {"box": p_o, "slope": s_o},
                 xk["t1"][:n], xk["t2"][:n])
        _kernels(yk["slope"], 1, cols, m, c, ("box",), {"box": q_o}, None, None)
        p_o *= scale["p"]
        q_o *= scale["q"]
        s_o *= scale["s"]
        if quad:
            _kernels(xk["bend"], 0, n, m, c, ("box",), {"box": r_o}, None, None)
            _kernels(yk["bend"], 1, cols, m, c, ("box",), {"box": t_o}, None, None)
            r_o *= scale["r"]
            t_o *= scale["t"]
        else:
            r_o[:] = 0
            t_o[:] = 0
        if any_bad:
            b = bad[sl]
            for a in (p_o, q_o, r_o, s_o, t_o):
                a[b] = np.nan
        yield sl, p_o, q_o, r_o, s_o, t_o


def _tap(a, axis, k, n):
    """The ``n`` positions of ``a`` from offset ``k`` along ``axis`` (a window's tap)."""
    return a[:, k:k + n] if axis == 1 else a[k:k + n]


def _kernels(a, axis, n, m, c, which, dst, tmp, tmp2):
    """The separable kernels of the local fit along ``axis`` of ``a`` (box 1, slope u,
    bend u^2 - c; u = -m..m) for the ``n`` window centres, as sums of shifted slices:
    ``dst[name]`` receives each kernel named in ``which``.

    The slope sums ``k (a[+k] - a[-k])`` and the bend ``(k^2 - c) ((a[+k] - a[0]) +
    (a[-k] - a[0]))`` (the weights sum to zero) are sums of differences, exact for any
    height offset; only the box sums the values themselves (used on derivatives).
    ``tmp`` and ``tmp2`` are scratch arrays of the output's shape (slope and bend).
    """
    centre = _tap(a, axis, m, n)
    if "box" in which:
        o = dst["box"]
        np.copyto(o, centre)
        for k in range(1, m + 1):
            o += _tap(a, axis, m + k, n)
            o += _tap(a, axis, m - k, n)
    if "slope" in which:
        o = dst["slope"]
        np.subtract(_tap(a, axis, m + 1, n), _tap(a, axis, m - 1, n), out=o)
        for k in range(2, m + 1):
            np.subtract(_tap(a, axis, m + k, n), _tap(a, axis, m - k, n), out=tmp)
            tmp *= np.float32(k)
            o += tmp
    if "bend" in which:
        o = dst["bend"]
        o[...] = 0
        for k in range(1, m + 1):
            np.subtract(_tap(a, axis, m + k, n), centre, out=tmp)
            np.subtract(_tap(a, axis, m - k, n), centre, out=tmp2)
            tmp += tmp2
            tmp *= np.float32(k * k - c)
            o += tmp


def curvatures_from_derivatives(p: np.ndarray, q: np.ndarray, r: np.ndarray, s: np.ndarray,
                                t: np.ndarray, out: Optional[np.ndarray] = None
                                ) -> Tuple[np.ndarray, np.ndarray]:
    """Gaussian curvature K and mean curvature H from the local derivatives.

    ``out``, optional: a float32 array of shape ``(2,) + p.shape`` receiving K and H.

    Returns
    -------
    K : ndarray
        ``(r t - s^2) / h^4`` with ``h^2 = 1 + p^2 + q^2`` (Luong Chinh Ke 2002, eqs.
        9-16), in 1/m^2. K > 0: elliptic point (dome or bowl), K < 0: saddle.
    H : ndarray
        ``-((1 + q^2) r - 2 p q s + (1 + p^2) t) / (2 h^3)`` in 1/m, signed so that
        H > 0 is convex (dome, top of a wall) and H < 0 concave (pit, foot of a wall).
    """
    p, q, r, s, t = (np.asarray(a, dtype=np.float32) for a in (p, q, r, s, t))
    if out is None:
        out = np.empty((2,) + p.shape, np.float32)
    rows = p.shape[0] if p.ndim else 1
    step = max(1, CHUNK_CELLS // max(1, p.size // max(rows, 1)))
    if p.ndim == 2 and rows > step:  # row blocks that stay in the cache
        for i in range(0, rows, step):
            sl = slice(i, i + step)
            curvatures_from_derivatives(p[sl], q[sl], r[sl], s[sl], t[sl], out=out[:, sl])
        return out[0], out[1]
    K, H = out[0], out[1]
    # slopes beyond ~1e9 (heights far outside any terrain) overflow h^4 to inf: K and H
    # are then 0 or NaN (not breaks), without numpy's warnings
    with np.errstate(over="ignore", invalid="ignore"):
        pp = p * p
        qq = q * q
        h2 = pp + qq
        h2 += 1
        # K = (r t - s^2) / h^4
        np.multiply(r, t, out=K)
        tmp = s * s
        K -= tmp
        K /= h2
        K /= h2
        # H = -((1 + q^2) r - 2 p q s + (1 + p^2) t) / (2 h^3)
        qq += 1
        np.multiply(qq, r, out=H)
        pp += 1
        pp *= t
        H += pp
        np.multiply(p, q, out=tmp)
        tmp *= s
        tmp *= 2
        H -= tmp
        np.sqrt(h2, out=tmp)
        tmp *= h2
        tmp *= -2
        H /= tmp
    return K, H


def compute_curvature(z: np.ndarray, cell_size: CellSize, *, window: int = 5,
                      model: str = "quadratic") -> Tuple[np.ndarray, ...]:
    """Gaussian and mean curvature of a local least-squares surface at every cell.

    Luong Chinh Ke (2002), section 2.2: the local trend of the surface around each point
    is fitted by least squares to at least five neighbouring points per profile, and the
    point's Gaussian curvature is K = (r t - s^2) / h^4, h^2 = 1 + p^2 + q^2 (eqs. 9-16).

    Parameters
    ----------
    z : array_like, 2-D
        Surface in metres (NaN = nodata).
    cell_size : float or (float, float)
        ``(dx, dy)`` in metres.
    window : int
        Odd window edge in cells (points per profile group), >= 3; default 5.
    model : {"quadratic", "bilinear"}
        Local surface: ``"quadratic"`` (default) or the paper's bilinear eq. 12, for which
        r = t = 0 and K = -a3^2 / h^4 <= 0 (see :func:`local_derivatives`).

    Returns
    -------
    K, H, p, q, r, s, t : ndarray of float32
        Gaussian curvature (1/m^2), mean curvature (1/m, > 0 convex), and the derivatives
        (x along columns, y down the rows). NaN at nodata cells.

    Examples
    --------
    >>> import numpy as np
    >>> y, x = np.mgrid[0:9, 0:9].astype(float)
    >>> K, H, *_ = compute_curvature(2 + 0.1 * x - 0.3 * y, 1.0)
    >>> float(abs(K).max()) < 1e-6 and float(abs(H).max()) < 1e-6
    True
    """
    p, q, r, s, t = local_derivatives(z, cell_size, window=window, model=model)
    K, H = curvatures_from_derivatives(p, q, r, s, t)
    return K, H, p, q, r, s, t



@dataclass
class Breaks:
    """The breaks of step 2 and the curvature they come from.

    Attributes
    ----------
    curvature : ndarray of float32, shape (2, rows, cols)
        K (1/m^2) and H (1/m, > 0 convex); NaN at nodata.
    marked : ndarray of bool
        Every break: ``|K| >= K_g`` or ``|r| >= sqrt(K_g)`` or ``|t| >= sqrt(K_g)``.
    by_k : ndarray of bool
        The paper's test alone, ``|K| >= K_g``: curved both ways (crowns, corners, spikes).
    n_x, n_y : int
        Cells marked by the bend of the X profiles (``|r|``) and of the Y profiles (``|t|``).
    """
    curvature: np.ndarray
    marked: np.ndarray
    by_k: np.ndarray
    n_x: int
    n_y: int


def mark_breaks(z: np.ndarray, cell_size: CellSize, k_g: float, *, window: int, model: str,
                progress: Optional[Progress] = None) -> Breaks:
    """Steps 1 and 2: local trends and curvature (eqs. 9-16), and the breaks.

    A cell is a break when ``|K| >= K_g`` (Luong Chinh Ke 2002), or when the bend of its X
    or Y profile trend ``|r|`` or ``|t|`` is at least ``kappa_g = sqrt(K_g)``: a straight
    roof edge has K = 0 (one principal curvature is zero) and a tall wall has a tiny K
    (h^4 is large), but its profile across the edge bends strongly. Block of rows by block:
    the derivatives p, q, r, s, t live in cache-sized buffers (:func:`derivative_blocks`).
    ``z`` is float32 (NaN = nodata); ``progress(fraction)`` is called per block of rows.
    """
    rows = z.shape[0]
    kappa_g = np.float32(np.sqrt(k_g))
    curv = np.empty((2,) + z.shape, np.float32)
    mark_k = np.empty(z.shape, bool)
    marked = np.empty(z.shape, bool)
    n_mark_x = n_mark_y = 0
    a = mx = None
    for sl, p, q, r, s, t in derivative_blocks(z, cell_size, window, model):
        curvatures_from_derivatives(p, q, r, s, t, out=curv[:, sl])
        if a is None:
            a, mx = np.empty(p.shape, np.float32), np.empty(p.shape, bool)
        n = p.shape[0]
        mk, mb = mark_k[sl], marked[sl]
        np.greater_equal(np.abs(curv[0, sl], out=a[:n]), np.float32(k_g), out=mk)  # NaN: False
        np.copyto(mb, mk)
        np.greater_equal(np.abs(r, out=a[:n]), kappa_g, out=mx[:n])
        n_mark_x += int(np.count_nonzero(mx[:n]))
        mb |= mx[:n]
        np.greater_equal(np.abs(t, out=a[:n]), kappa_g, out=mx[:n])
        n_mark_y += int(np.count_nonzero(mx[:n]))
        mb |= mx[:n]
        report(progress, sl.stop / rows)
    return Breaks(curv, marked, mark_k, n_mark_x, n_mark_y)
