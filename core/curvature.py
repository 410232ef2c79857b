"""Local-trend filter by Gaussian curvature (Luong Chinh Ke 2002, section 2.2).

Luong Chinh Ke (2002) fits local trends of the surface to groups of neighbouring points
along profiles in X (Y constant) and in Y (X constant), at least five points per group,
by least squares, and gives each point the Gaussian curvature of the fitted surface

    K = (r t - s^2) / h^4,      h^2 = 1 + p^2 + q^2                      (eqs. 9-16)

with p = dz/dX, q = dz/dY the first and r = d2z/dX2, s = d2z/dXdY, t = d2z/dY2 the
second derivatives. A point with ``|K| >= K_g`` lies on a break of the surface: at the foot
or the top of an object.

Local trend surfaces
--------------------
``"quadratic"`` (default)
    z = a + b x + c y + d x^2 + e x y + f y^2 fitted by least squares to the
    ``window x window`` cells around every cell (Evans-Young / Zevenbergen-Thorne style):
    p = b, q = c, r = 2 d, s = e, t = 2 f. On a regular grid the normal equations
    separate, so every coefficient is a separable kernel: the whole raster is done with a
    few shifted sums (no loop per cell). Besides K it gives the mean curvature H, whose
    sign separates convex (H > 0) from concave (H < 0) where K alone cannot (K > 0 for a
    dome and for a bowl alike).
``"bilinear"``
    The paper's surface z = a0 + a1 X + a2 Y + a3 X Y (eq. 12), fitted to the window of
    ``window`` neighbouring X profiles (fitted to the points of a single profile it is
    degenerate: with Y constant, a2 and a3 cannot be separated). Its second derivatives
    are r = t = 0, s = a3, so K = -a3^2 / h^4 is never positive: it finds twisted
    breaks (corners) but cannot tell convex from concave, and misses straight edges.

From curvature to objects
-------------------------
1. **Breaks.** A cell is marked when ``|K| >= K_g`` (the paper's test), or by its X
   profile when the bend of the X trend ``|r| >= sqrt(K_g)``, or by its Y profile when
   ``|t| >= sqrt(K_g)``. The profile tests are needed: along a straight roof edge one
   principal curvature is zero, so K = 0, and a tall wall has a tiny K (h^4 is large),
   but the profile across the edge bends strongly. ``sqrt(K_g)`` is the bend of a point
   curved as much both ways (K = kappa^2).
2. **Profiles.** Along every X and Y profile (each scanned both ways, all profiles at
   once) the points between a break going up and the matching break coming down belong
   to an object: the object starts at a marked cell on top of a wall (a rise of at least
   the minimum object height within two cells, steeper than the wall slope and three
   times steeper than the profile before it: dams, embankments, terrace edges and
   terrain rasterised in steps are not walls), and ends where the profile comes back down
   to the ground extended from the wall's foot at the profile's slope before it, or comes
   down a wall onto ground nearer the foot than the top, or after the largest object
   size. A terrace step is climbed by one scan only; objects are kept where both agree.
3. **Regions.** Regions enclosed by breaks (4-connected unmarked cells, no larger than
   the largest object, not touching the raster's edge) made mostly of such points become
   whole objects.
4. **Final pass** (twice). The ground is interpolated (:func:`fill.fill_gaps`, harmonic,
   on a grid of half the resolution refined bilinearly: :func:`_ground_surface`) under
   the objects, the breaks next to them and the points with ``|K| >= K_g``; a cell
   is an object when it stands above that surface by more than the tolerance plus one
   cell of the surface's slope (breaks outside objects: half the minimum object height
   more, as the interpolated surface sags a little under convex terrain edges). Straight
   breaks away from objects (K ~ 0: dams, embankments, terrace edges) are seeds of the
   surface, so terrain edges stay ground. A concave break deeper than the minimum object
   height below the surface and below every cell of the ring around it is a low blunder
   (code 2): a pit, not a valley or a cut.

Reference
---------
Luong Chinh Ke (2002). Filtering of DSM for generating DTM (local trend and Gaussian
curvature, section 2.2). The curvature formulas are those of differential geometry of a
graph surface (e.g. Evans 1980; Zevenbergen & Thorne 1987).
"""
import numpy as np
from scipy import ndimage

from .estimate import ground_level_cells, noise_ground_level
from .codes import GROUND, LOW, NODATA, OBJECT
from .common import FilterResult, as_cell_size, as_surface, report, transpose
from .methods import Method, Param

MODELS = ("quadratic", "bilinear")

#: Break threshold in robust standard deviations of the profile bends (K_g default).
_K_SIGMAS = 1.5
#: Smallest height deviation (m) across a half window that counts as a break on
#: noise-free data (floor of the derived K_g).
_MIN_BREAK_M = 0.05
#: Tile edge (cells) and quantile of the tile spreads used for the smooth-part noise.
_TILE = 16
_SMOOTH_QUANTILE = 0.25
#: Width (cells) within which an object's wall rises, and how much steeper than the
#: profile before it the wall must be.
_WALL_CELLS = 2
_WALL_CONTRAST = 3.0
#: Cells per block of the element-wise curvature formulas (cache-sized).
_CHUNK_CELLS = 1 << 16
#: Final passes against the interpolated ground surface.
_PASSES = 2
#: Largest sample (cells) used to derive defaults on big rasters.
_SAMPLE_CELLS = 1_048_576


# --------------------------------------------------------------------------- curvature
def _check_window(window):
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


def _check_model(model):
    if model not in MODELS:
        raise ValueError(f"model must be one of {MODELS}; got {model!r}. Use 'quadratic' "
                         "(default) or 'bilinear' (the paper's eq. 12).")
    return model


def _bridge_nodata(z):
    """``z`` with NaN cells bridged by the harmonic surface of the shared gap filler
    (planes stay planes, so gaps make no false breaks); ``z`` itself when complete."""
    bad = ~np.isfinite(z)
    if not bad.any():
        return z
    return _fill_surface(z, bad)


def local_derivatives(z, cell_size, *, window=5, model="quadratic"):
    """Least-squares local surface derivatives p, q, r, s, t for every cell.

    Parameters
    ----------
    z : array_like, 2-D
        Surface (NaN = nodata; nodata cells are bridged by a harmonic surface for the
        fit and get NaN derivatives).
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
    window = _check_window(window)
    model = _check_model(model)
    out = tuple(np.empty(as_surface(z).shape, np.float32) for _ in range(5))
    for _ in _derivative_blocks(z, cell_size, window, model, out=out):
        pass
    return out


def _padded_relief(z, m):
    """``z`` (float32, nodata bridged) padded by ``m`` cells by odd reflection, minus a
    reference height (float32 sums of relief, not of absolute heights: precision)."""
    zf = _bridge_nodata(z)
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
    ref = np.float32(np.median(zf[np.isfinite(zf)][:: max(1, zf.size // 4096)]))
    zp -= ref
    return zp


def _derivative_blocks(z, cell_size, window, model, out=None):
    """The local derivatives of :func:`local_derivatives`, block of rows by block.

    Yields ``(rows, p, q, r, s, t)`` for consecutive row slices ``rows``. Without ``out``
    the five arrays are buffers reused by the next block (cache-sized; nothing of the
    raster's size is allocated but the padded copy of ``z``); with ``out`` (five float32
    arrays of ``z``'s shape) they are written there and the views are yielded. NaN at
    nodata cells.
    """
    dx, dy = as_cell_size(cell_size)
    z = as_surface(z)
    bad = ~np.isfinite(z)
    any_bad = bool(bad.any())
    m = window // 2
    zp = _padded_relief(z, m)
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
    step = max(8, _CHUNK_CELLS // max(cols, 1))
    nb = min(step, rows)
    # buffers: the X pass over the block and its halo, the Y pass, the taps' pair sums
    bx = {k: np.empty((nb + 2 * m, cols), np.float32) for k in ("box", "slope", "bend", "tmp")}
    pairs = [np.empty((nb + 2 * m, cols), np.float32) for _ in range(m)]
    ytmp = np.empty((nb, cols), np.float32)
    ypairs = [np.empty((nb, cols), np.float32) for _ in range(m)]
    res = [np.empty((nb, cols), np.float32) for _ in range(5)] if out is None else None

    # the three separable kernels (box 1, slope u, bend u^2 - c), as sums of shifted
    # slices: symmetric pairs a[+k] +- a[-k] are formed once
    def kernels(a, axis, n, which, dst, sums, tmp):
        def tap(k):  # the slice of a at offset k (0 .. 2m) along axis
            return a[:, k:k + n] if axis == 1 else a[k:k + n]
        centre = tap(m)
        if "box" in which or "bend" in which:
            for k in range(1, m + 1):
                np.add(tap(m + k), tap(m - k), out=sums[k - 1])
        if "box" in which:
            o = dst["box"]
            np.copyto(o, centre)
            for sk in sums:
                o += sk
        if "slope" in which:
            o = dst["slope"]
            np.subtract(tap(m + 1), tap(m - 1), out=o)
            for k in range(2, m + 1):
                np.subtract(tap(m + k), tap(m - k), out=tmp)
                tmp *= np.float32(k)
                o += tmp
        if "bend" in which:
            o = dst["bend"]
            np.multiply(centre, np.float32(-c), out=o)
            for k, sk in enumerate(sums, start=1):
                np.multiply(sk, np.float32(k * k - c), out=tmp)
                o += tmp

    for i0 in range(0, rows, step):
        n = min(step, rows - i0)
        sl = slice(i0, i0 + n)
        blk = zp[i0:i0 + n + 2 * m]
        h = n + 2 * m
        xk = {k: v[:h] for k, v in bx.items()}
        sums = [v[:h] for v in pairs]
        ysums = [v[:n] for v in ypairs]
        yt = ytmp[:n]
        if out is None:
            p_o, q_o, r_o, s_o, t_o = (v[:n] for v in res)
        else:
            p_o, q_o, r_o, s_o, t_o = (v[sl] for v in out)
        # profiles in X (along rows, axis 1) first, then across them in Y (axis 0)
        kernels(blk, 1, cols, ("box", "slope", "bend") if quad else ("box", "slope"),
                xk, sums, xk["tmp"][:, :cols])
        # Y pass of the X box: q (slope) and t (bend); of the X slope: p (box), s (slope);
        # of the X bend: r (box). Each written straight into its output, then scaled.
        kernels(xk["box"], 0, n, ("slope", "bend") if quad else ("slope",),
                {"slope": q_o, "bend": t_o}, ysums, yt)
        kernels(xk["slope"], 0, n, ("box", "slope"), {"box": p_o, "slope": s_o}, ysums, yt)
        p_o *= scale["p"]
        q_o *= scale["q"]
        s_o *= scale["s"]
        if quad:
            kernels(xk["bend"], 0, n, ("box",), {"box": r_o}, ysums, yt)
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


def curvatures_from_derivatives(p, q, r, s, t, out=None):
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
    step = max(1, _CHUNK_CELLS // max(1, p.size // max(rows, 1)))
    if p.ndim == 2 and rows > step:  # row blocks that stay in the cache
        for i in range(0, rows, step):
            sl = slice(i, i + step)
            curvatures_from_derivatives(p[sl], q[sl], r[sl], s[sl], t[sl], out=out[:, sl])
        return out[0], out[1]
    K, H = out[0], out[1]
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


def compute_curvature(z, cell_size, *, window=5, model="quadratic"):
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


# --------------------------------------------------------------------------- profiles
def _walls(Zp, pad, B, first, cell, *, reach, h_min, tan_wall):
    """Where a profile (axis 0, scanned downwards) has just risen as a wall.

    ``Zp[pad:]`` holds the positions examined (rows) of all profiles (columns), NaN at
    nodata, below the ``pad >= _WALL_CELLS + reach`` positions before them (NaN before a
    profile's start): a block of rows of the profiles, see :func:`_axis_objects`.
    ``first`` is every profile's first position. Only marked positions ``B`` (breaks,
    shaped as ``Zp[pad:]``) are examined. The foot of position j is the lowest of the
    ``_WALL_CELLS`` positions before it. j is the top of a wall when

    * ``z_j - foot >= h_min`` (high enough),
    * the rise is steeper than the wall slope: ``(z_j - foot) / (_WALL_CELLS cell) >=
      tan(wall slope)``, and
    * it is much steeper (``_WALL_CONTRAST`` times) than the profile's own rise over
      the ``reach`` positions before the foot. This keeps terrain rasterised in steps
      (sparse points filled from the nearest one: a staircase whose treads are as steep
      as its risers on average) and walls of a terrain cut from looking like object walls,
      while a wall standing on a hillside still stands out.

    The same test mirrored finds where the profile has just come down a wall (by
    ``drop``: the highest of the ``_WALL_CELLS`` positions before, minus ``z_j``). A loop
    over a handful of shifts, each a gather (``take``) over all marked cells from a
    flat view of the rows k positions earlier.

    Returns
    -------
    walls : tuple of ndarray
        ``(flat index, foot height, slope)`` of the wall tops (flat indices of
        ``Zp[pad:]``), in index order; ``slope`` is the profile's rise per position
        before the foot (>= 0), so that the scan can follow the ground under the object.
    downs : tuple of ndarray
        ``(flat index, drop)`` of the positions just below a wall, in index order.
    """
    n = Zp.shape[0] - pad
    if pad < _WALL_CELLS + reach:
        raise ValueError("_walls: the padding must cover the wall and the reach before it")
    idx = np.flatnonzero(B)
    if idx.size == 0:
        e = np.zeros(0, np.int64), np.zeros(0, np.float32)
        return (e[0], e[1], e[1]), e

    def back(k):  # the profiles k positions earlier (NaN before their start), flat view
        return Zp[pad - k:pad - k + n].ravel()

    zc = back(0).take(idx)
    best = back(1).take(idx)
    top = best.copy()
    for k in range(2, _WALL_CELLS + 1):
        v = back(k).take(idx)
        np.fmin(best, v, out=best)
        np.fmax(top, v, out=top)
    base = v if _WALL_CELLS > 1 else best  # the height _WALL_CELLS positions before
    with np.errstate(invalid="ignore"):
        rise = zc - best
        fall = np.subtract(top, zc, out=top)
        # cheap tests first, on all marked cells; the rest only on what passes
        down = fall >= max(np.float32(h_min), np.float32(tan_wall * _WALL_CELLS * cell))
        cand = np.flatnonzero(rise >= np.float32(h_min))
        rate = rise.take(cand)
        rate /= np.float32(_WALL_CELLS * cell)
        steep = rate >= np.float32(tan_wall)
        cand, rate = cand[steep], rate[steep]
        ci = idx.take(cand)
        before = back(_WALL_CELLS + reach).take(ci)
        nb = np.isnan(before)
        if nb.any():  # near the start of a profile (or nodata): its first position
            before[nb] = first.take(ci[nb] % Zp.shape[1])
        prior = np.maximum((base.take(cand) - before) / np.float32(reach * cell), 0)
        ok = rate >= np.float32(_WALL_CONTRAST) * prior
    wsel = cand[ok]
    return ((ci[ok], best.take(wsel), (prior[ok] * np.float32(cell)).astype(np.float32)),
            (idx[down], fall[down].astype(np.float32)))


def _row_slices(flat_idx, n, m):
    """Start offsets of the entries of each row 0..n in a sorted flat-index array."""
    return np.searchsorted(flat_idx // m, np.arange(n + 1))


class _ScanState:
    """What the scan of :func:`_scan_rows` keeps per profile between blocks of rows:
    inside an object, ``g`` the height of the ground before it (its foot), ``gs`` the
    slope of that ground and ``jg`` the position where the object began."""

    def __init__(self, m, tol, max_cells):
        self.g = np.zeros(m, np.float32)
        self.jg = np.zeros(m, np.float32)
        self.gs = np.zeros(m, np.float32)
        self.dist = np.empty(m, np.float32)
        self.lim = np.empty(m, np.float32)
        self.rise = np.empty(m, np.float32)
        self.end = np.empty(m, bool)
        self.far = np.empty(m, bool)
        self.tol = np.float32(tol)
        self.max_cells = max_cells


def _scan_rows(Z, j0, walls, downs, out, st):
    """The scan along axis 0 (positions x profiles), all profiles at once, over the
    positions ``j0 .. j0 + len(Z) - 1`` (``Z``: their heights, ``walls`` and ``downs``
    from :func:`_walls` with flat indices into ``Z``); ``out[j]`` is set to the profiles
    inside an object at position j (``out[j0 - 1]`` must hold the previous position).

    The paper's reading of a profile: the points between a break going up and the
    matching break coming down belong to an object.

    * ground -> object at the top of a wall (``walls``, see :func:`_walls`: marked cells
      only); the state ``st`` (:class:`_ScanState`) takes the wall's foot.
    * object -> ground when the profile comes back down to the ground extended from the
      foot at the slope the profile had before the wall (rising only; within ``tol``),
      or comes down a wall (``downs``) onto ground nearer the foot than the top (the
      matching break coming down, onto ground that rose under the object), or after
      ``max_cells`` (too long for an object). On a slope the scan going uphill
      overshoots, but the scan coming down finds the building's uphill wall;
      :func:`_axis_objects` keeps only what both directions agree on.

    Walls and down-walls are sparse: they are applied by index, row by row. The state is
    only read inside an object and every object starts at a wall, which sets it: the
    dense work per row is the end test alone.
    """
    n, m = Z.shape
    g, jg, gs, dist, lim = st.g, st.jg, st.gs, st.dist, st.lim
    rise, end, far, tol = st.rise, st.end, st.far, st.tol
    w_idx, w_foot, w_slope = walls
    d_idx, d_drop = downs
    w_ptr = _row_slices(w_idx, n, m)
    d_ptr = _row_slices(d_idx, n, m)
    w_col = (w_idx % m).astype(np.intp)
    d_col = (d_idx % m).astype(np.intp)
    d_add = np.maximum(d_drop, tol) - tol
    with np.errstate(invalid="ignore"):
        for i in range(n):
            j = j0 + i
            if j == 0:             # the first position is never inside an object
                out[0] = False
                continue
            obj = out[j - 1]
            np.subtract(Z[i], g, out=rise)
            np.subtract(np.float32(j), jg, out=dist)
            np.multiply(gs, dist, out=lim)
            a, b = d_ptr[i], d_ptr[i + 1]
            if b > a:  # down a wall here: end when rise <= slope * dist + drop
                lim[d_col[a:b]] += d_add[a:b]
            lim += tol
            np.less_equal(rise, lim, out=end)
            np.greater(dist, st.max_cells, out=far)
            end |= far
            now = out[j]
            np.greater(obj, end, out=now)          # obj & ~end: the objects that go on
            a, b = w_ptr[i], w_ptr[i + 1]
            if b > a:
                c = w_col[a:b]
                ok = ~obj.take(c)                  # a profile inside an object does not restart
                if ok.any():
                    c = c[ok]
                    now[c] = True
                    g[c] = w_foot[a:b][ok]
                    gs[c] = w_slope[a:b][ok]
                    jg[c] = j


def _profile_rows(a, j0, j1, dst, fill):
    """Positions ``j0 .. j1 - 1`` of the profiles along axis 0 of ``a`` (its columns),
    forwards then backwards, into ``dst`` (``j1 - j0`` rows): ``dst[:, :m]`` the profiles
    read from their start, ``dst[:, m:]`` read from their end; positions before the
    start are ``fill``."""
    n, m = a.shape
    k0 = min(max(j0, 0), j1)
    if k0 > j0:
        dst[:k0 - j0] = fill
    if j1 <= k0:
        return
    d = dst[k0 - j0:j1 - j0]
    d[:, :m] = a[k0:j1]
    d[:, m:] = a[n - j1:n - k0][::-1]


def _axis_objects(z, marked, valid, cell, axis, *, reach, h_min, tan_wall, tol, max_cells):
    """Object cells of the profiles along ``axis`` (0: Y profiles, the columns; 1: X
    profiles, the rows, scanned as the columns of the transposed raster): both scan
    directions must agree.

    A step up of the terrain (terrace edge) is an object to the scan climbing it, but the
    scan coming down the other way meets no break going up: only objects, which have a
    break going up from both sides, are kept.

    Every profile is scanned from its start and from its end at once (the profiles
    forwards, then backwards, side by side), block of positions by block: a block of the
    heights with the positions before it and the block's breaks are copied out of ``z``
    and ``marked``, its walls found (:func:`_walls`) and scanned (:func:`_scan_rows`), so
    that no index array of the raster's size is held. ``z`` is NaN at nodata.
    """
    if axis == 1:
        res = transpose(_axis_objects(transpose(z), transpose(marked), None, cell, 0,
                                       reach=reach, h_min=h_min, tan_wall=tan_wall, tol=tol,
                                       max_cells=max_cells))
        if valid is not None:
            res &= valid
        return res
    n, m = z.shape
    M = 2 * m
    pad = _WALL_CELLS + reach
    rows = max(8, pad, (4 * _CHUNK_CELLS) // max(M, 1))
    Zc = np.empty((pad + rows, M), np.float32)
    Bc = np.empty((rows, M), bool)
    first = np.empty((1, M), np.float32)
    _profile_rows(z, 0, 1, first, np.nan)
    first = first[0]
    out = np.empty((n, M), bool)
    st = _ScanState(M, tol, max_cells)
    for j0 in range(0, n, rows):
        j1 = min(n, j0 + rows)
        k = j1 - j0
        if j0 == 0:
            _profile_rows(z, -pad, j1, Zc[:pad + k], np.nan)
        else:  # the positions before the block: the end of the previous one
            Zc[:pad] = Zc[rows:rows + pad]
            _profile_rows(z, j0, j1, Zc[pad:pad + k], np.nan)
        _profile_rows(marked, j0, j1, Bc[:k], False)
        walls, downs = _walls(Zc[:pad + k], pad, Bc[:k], first, cell, reach=reach,
                              h_min=h_min, tan_wall=tan_wall)
        _scan_rows(Zc[pad:pad + k], j0, walls, downs, out, st)
    res = np.logical_and(out[:, :m], out[::-1, m:])
    del out
    if valid is not None:
        res &= valid
    return res


def _enclosed_regions(flag, free, max_cells):
    """Regions of ``free`` cells (4-connected) mostly made of ``flag`` cells.

    A region is kept when at least half its cells are flagged, it does not touch the
    array's edge and its bounding box is at most ``max_cells`` on each side, so the
    decision never depends on cells farther than ``max_cells`` (block-safe).
    """
    lab, n = ndimage.label(free)
    if n == 0:
        return np.zeros(flag.shape, bool)
    # cells per label, by blocks of rows (bincount casts its input to intp: a raster-sized
    # int64 copy at once otherwise); flagged cells outside ``free`` count for label 0
    hit = np.zeros(n + 1, np.intp)
    tot = np.zeros(n + 1, np.intp)
    step = max(1, (16 * _CHUNK_CELLS) // max(lab.shape[1], 1))
    for i in range(0, lab.shape[0], step):
        lb = lab[i:i + step]
        tot += np.bincount(lb.ravel(), minlength=n + 1)
        hit += np.bincount(lb[flag[i:i + step]], minlength=n + 1)
    cand = (hit > 0) & (2 * hit >= tot)
    cand[0] = False
    cand[np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]])] = False
    # a bounding box wider than max_cells needs more than max_cells cells: only such
    # regions are measured
    big = cand & (tot > max_cells)
    if big.any():
        ids = np.flatnonzero(big)
        if ids[-1] <= 16 * ids.size + 4096:   # few labels up to the last: boxes of all
            boxes = ndimage.find_objects(lab, max_label=int(ids[-1]))
            boxes = [boxes[i - 1] for i in ids]
        else:                                 # many: renumbered 1..k first
            renum = np.zeros(n + 1, np.int32)
            renum[ids] = np.arange(1, ids.size + 1, dtype=np.int32)
            boxes = ndimage.find_objects(_lookup(renum, lab, step), max_label=ids.size)
        ext = np.array([max(b[0].stop - b[0].start, b[1].stop - b[1].start) for b in boxes])
        cand[ids[ext > max_cells]] = False
    if not cand.any():
        return np.zeros(flag.shape, bool)
    return _lookup(cand, lab, step)


def _lookup(table, lab, step):
    """``table[lab]`` by blocks of ``step`` rows (a gather casts its indices to intp: a
    raster-sized int64 copy at once otherwise)."""
    out = np.empty(lab.shape, table.dtype)
    for i in range(0, lab.shape[0], step):
        table.take(lab[i:i + step], out=out[i:i + step])
    return out


def _pits(z, cand, ring, depth):
    """Flat indices of the candidates lower by ``depth`` than every valid cell on the
    square ring at distance ``ring`` around them: spikes down (low blunders), not valleys,
    ditches or cuts, whose bottom continues through the ring. One gather per ring offset,
    over all candidates."""
    idx = np.flatnonzero(cand)
    if idx.size == 0:
        return idx
    rows, cols = z.shape
    rr, cc = np.divmod(idx, cols)
    zf = z.ravel()
    low = np.full(idx.size, np.inf, np.float32)
    k = range(-ring, ring + 1)
    offsets = ([(-ring, d) for d in k] + [(ring, d) for d in k]
               + [(d, -ring) for d in k[1:-1]] + [(d, ring) for d in k[1:-1]])
    with np.errstate(invalid="ignore"):
        for dr, dc in offsets:
            r = rr + dr
            c = cc + dc
            ok = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
            r *= cols
            r += c
            v = zf.take(np.where(ok, r, 0))
            ok &= np.isfinite(v)             # nodata and cells outside: not on the ring
            np.minimum(low, np.where(ok, v, np.float32(np.inf)), out=low)
        return idx[zf.take(idx) < low - np.float32(depth)]


def _dilate(mask, m):
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


def _fill_surface(z, holes):
    """Surface through the cells not in ``holes``, interpolated smoothly over them.

    Uses the shared gap filler :func:`fill.fill_gaps` (harmonic interpolation) when it is
    installed, else :func:`_push_pull_fill`.
    """
    try:
        from .fill import fill_gaps
    except ImportError:  # pragma: no cover - the shared filler is part of the package
        return _push_pull_fill(z, holes)
    return np.asarray(fill_gaps(z, fill=holes), dtype=np.float32)


def _ground_surface(z, holes, out=None):
    """Ground surface of the final pass: ``z`` at the cells not in ``holes``, over the
    holes the harmonic surface (:func:`fill.fill_gaps`) of a grid of half the resolution,
    interpolated bilinearly.

    Each 2 x 2 block of cells is one coarse cell. Its height is the mean of the diagonal
    pairs of known cells it holds (the block centre, exactly on a plane); without a known
    pair, along a straight edge of a hole, the linear extrapolation of two known cells on
    one side and the two beyond them (also exact on a plane), else the mean of its known
    cells, so that a line of known cells one cell wide (the crest of a dam between bands
    of breaks) still holds the coarse surface up; coarse cells with no known cell are
    filled (as one level of the restriction of :func:`fill.fill_gaps`). The fine surface
    over the holes is the bilinear interpolation of the coarse one (linear extrapolation
    at the raster's edge; planes stay planes). A quarter of the cells to interpolate; the
    final pass only compares heights with this surface, with a tolerance. Restriction and
    interpolation go by cache-sized blocks of rows; ``out``, optional: a float32 array of
    ``z``'s shape receiving the surface.
    """
    h, w = z.shape
    known = ~holes
    known &= np.isfinite(z)
    if min(h, w) < 8 or not known.any():
        return _fill_surface(z, holes)
    H, W = (h + 1) // 2, (w + 1) // 2
    w1 = w // 2                          # coarse columns with a second child
    s = np.empty((H, W), np.float32)     # coarse heights (NaN: to fill)
    diag = np.zeros((H, W), bool)        # coarse cells set by a known diagonal pair
    part = np.zeros((H, W), bool)        # coarse cells with known cells but no pair
    step = max(1, _CHUNK_CELLS // max(w, 1))
    zero = np.float32(0)
    for I0 in range(0, H, step):
        I1 = min(H, I0 + step)
        zb, kb = z[2 * I0:2 * I1], known[2 * I0:2 * I1]
        i1 = zb.shape[0] // 2            # coarse rows of the block with a second child
        k00, k01, k10, k11 = kb[0::2, 0::2], kb[0::2, 1::2], kb[1::2, 0::2], kb[1::2, 1::2]
        v00 = np.where(k00, zb[0::2, 0::2], zero)
        v01 = np.where(k01, zb[0::2, 1::2], zero)
        v10 = np.where(k10, zb[1::2, 0::2], zero)
        v11 = np.where(k11, zb[1::2, 1::2], zero)
        # all known cells of the block
        sb = s[I0:I1]
        np.copyto(sb, v00)
        sb[:, :w1] += v01
        sb[:i1] += v10
        sb[:i1, :w1] += v11
        n = k00.astype(np.float32)
        n[:, :w1] += k01
        n[:i1] += k10
        n[:i1, :w1] += k11
        # the known diagonal pairs, where there is one
        d1 = k00[:i1, :w1] & k11
        d2 = k01[:i1] & k10[:, :w1]
        sd = v00[:i1, :w1] + v11
        sd *= d1
        v01 = v01[:i1] + v10[:, :w1]
        v01 *= d2
        sd += v01
        nd = d1.astype(np.float32)
        nd += d2
        nd *= 2
        db = diag[I0:I0 + i1, :w1]
        np.greater(nd, 0, out=db)
        np.copyto(sb[:i1, :w1], sd, where=db)
        np.copyto(n[:i1, :w1], nd, where=db)
        pb = part[I0:I1]
        np.greater(n, 0, out=pb)
        pb &= ~diag[I0:I1]
        empty = n == 0
        n[empty] = 1
        sb /= n
        sb[empty] = np.nan
    # known cells without a known pair: along a straight edge of a hole, two known
    # children on one side and the two cells beyond them give the centre by linear
    # extrapolation (exact on a plane); elsewhere (thin crests, corners) their mean
    idx = np.flatnonzero(part)
    del diag, part
    if idx.size:
        i, j = np.divmod(idx, W)
        base = i * (2 * w)
        base += 2 * j                      # flat index of the block's first cell
        kf, zf = known.ravel(), z.ravel()
        acc = np.zeros(idx.size, np.float32)
        cnt = np.zeros(idx.size, np.float32)
        inner_c, inner_r = 2 * j + 1 < w, 2 * i + 1 < h
        # side: where it exists; (inner cells, outer cells) as (row, col) offsets from
        # the block's first cell
        for ok, (a, b), (c, d) in (
                ((i >= 1) & inner_c, ((0, 0), (0, 1)), ((-1, 0), (-1, 1))),         # top
                ((2 * i + 2 < h) & inner_c, ((1, 0), (1, 1)), ((2, 0), (2, 1))),    # bottom
                ((j >= 1) & inner_r, ((0, 0), (1, 0)), ((0, -1), (1, -1))),         # left
                ((2 * j + 2 < w) & inner_r, ((0, 1), (1, 1)), ((0, 2), (1, 2)))):   # right
            q = np.flatnonzero(ok)
            bq = base.take(q)
            fl = [bq + (o[0] * w + o[1]) for o in (a, b, c, d)]
            good = kf.take(fl[0]) & kf.take(fl[1]) & kf.take(fl[2]) & kf.take(fl[3])
            q, fl = q[good], [f[good] for f in fl]
            est = zf.take(fl[0]) + zf.take(fl[1])
            est *= np.float32(0.75)
            est -= np.float32(0.25) * (zf.take(fl[2]) + zf.take(fl[3]))
            acc[q] += est
            cnt[q] += 1
        ok = cnt > 0
        s.ravel()[idx[ok]] = acc[ok] / cnt[ok]
    from .fill import fill_gaps
    coarse = fill_gaps(s)
    del s
    return _upsample2(coarse, (h, w), z, known, out=out)


def _upsample2(c, shape, z=None, known=None, out=None):
    """Bilinear interpolation of a grid of half the resolution at the cells of ``shape``
    (fine cell i lies at coarse coordinate i / 2 - 1/4; the coarse grid is extended by
    linear extrapolation, so planes stay planes); ``z`` where ``known`` when given. By
    cache-sized blocks of rows."""
    H, W = c.shape
    h, w = shape
    cp = np.empty((H + 2, W + 2), np.float32)
    cp[1:-1, 1:-1] = c
    if H > 1:
        np.subtract(2 * c[0], c[1], out=cp[0, 1:-1])
        np.subtract(2 * c[-1], c[-2], out=cp[-1, 1:-1])
    else:
        cp[0, 1:-1] = cp[-1, 1:-1] = c[0]
    if W > 1:
        np.subtract(2 * cp[:, 1], cp[:, 2], out=cp[:, 0])
        np.subtract(2 * cp[:, -2], cp[:, -3], out=cp[:, -1])
    else:
        cp[:, 0] = cp[:, -1] = cp[:, 1]
    a, b = np.float32(0.75), np.float32(0.25)
    out = np.empty((h, w), np.float32) if out is None else out
    step = max(1, _CHUNK_CELLS // max(2 * W, 1))
    rows = np.empty((2 * min(step, H), W + 2), np.float32)
    tmp = np.empty((min(step, H), W + 2), np.float32)
    full = np.empty((2 * min(step, H), 2 * W), np.float32)
    tmp2 = np.empty((2 * min(step, H), W), np.float32)
    for I0 in range(0, H, step):
        I1 = min(H, I0 + step)
        n = I1 - I0
        rb, tb = rows[:2 * n], tmp[:n]
        for par, nb in ((0, cp[I0:I1]), (1, cp[I0 + 2:I1 + 2])):  # even rows lean up, odd down
            dst = rb[par::2]
            np.multiply(cp[I0 + 1:I1 + 1], a, out=dst)
            np.multiply(nb, b, out=tb)
            dst += tb
        fb, t2 = full[:2 * n], tmp2[:2 * n]
        for par, nb in ((0, rb[:, :-2]), (1, rb[:, 2:])):
            dst = fb[:, par::2]
            np.multiply(rb[:, 1:-1], a, out=dst)
            np.multiply(nb, b, out=t2)
            dst += t2
        r0, r1 = 2 * I0, min(h, 2 * I1)
        ob = out[r0:r1]
        np.copyto(ob, fb[:r1 - r0, :w])
        if z is not None:
            np.copyto(ob, z[r0:r1], where=known[r0:r1])
    return out


def _push_pull_fill(z, holes):
    """Pyramid (push-pull) interpolation of ``z`` over ``holes`` and NaN cells.

    Push: 2 x 2 means of the known cells, level by level, until every cell is known.
    Pull: each level's unknown cells take the bilinear upsampling of the coarser level.
    """
    known = np.isfinite(z) & ~holes
    val = np.where(known, z, 0).astype(np.float64)
    wgt = known.astype(np.float64)
    levels = []
    while True:
        levels.append((val, wgt))
        if (wgt > 0).all() or min(val.shape) <= 1:
            break
        r, c = val.shape
        pr, pc = r % 2, c % 2
        v = np.pad(val * wgt, ((0, pr), (0, pc)))
        w = np.pad(wgt, ((0, pr), (0, pc)))
        v = v.reshape(v.shape[0] // 2, 2, v.shape[1] // 2, 2).sum(axis=(1, 3))
        w = w.reshape(w.shape[0] // 2, 2, w.shape[1] // 2, 2).sum(axis=(1, 3))
        val = np.divide(v, w, out=np.zeros_like(v), where=w > 0)
        wgt = np.minimum(w, 1.0)
    filled = levels[-1][0]
    for val, wgt in reversed(levels[:-1]):
        up = ndimage.zoom(filled, (val.shape[0] / filled.shape[0], val.shape[1] / filled.shape[1]),
                          order=1, mode="nearest", grid_mode=True)
        filled = np.where(wgt > 0, val, up)
    out = np.where(known, z, filled).astype(np.float32)
    return out


def _noise_sigma(z):
    """Robust noise (m) of the smooth parts of ``z``: spread of the second differences
    along X and Y (1.4826 MAD, of the quieter tiles, see :func:`_smooth_spread`) / sqrt(6)."""
    if min(z.shape) < 3:
        return 0.0
    d2 = np.stack([(z[1:-1, :-2] - 2 * z[1:-1, 1:-1] + z[1:-1, 2:]),
                   (z[:-2, 1:-1] - 2 * z[1:-1, 1:-1] + z[2:, 1:-1])]).astype(np.float32)
    return _smooth_spread(d2) / np.sqrt(6.0)


def _smooth_spread(v, tile=_TILE):
    """Robust spread (1.4826 MAD) of ``v`` (bands x rows x cols) on its smooth parts.

    The spread is taken per ``tile x tile`` tile and the ``_SMOOTH_QUANTILE`` quantile of
    the tiles is returned: the noise of the smooth ground and roofs, not inflated by
    vegetation or by the objects' edges, which may cover most of an urban scene.
    """
    b, r, c = v.shape
    tr, tc = max(1, min(tile, r)), max(1, min(tile, c))
    nr, nc = r // tr, c // tc
    t = v[:, :nr * tr, :nc * tc].reshape(b, nr, tr, nc, tc).transpose(1, 3, 0, 2, 4)
    t = t.reshape(nr * nc, -1).astype(np.float64)  # a copy: partitioned in place
    med = np.median(t, axis=1, keepdims=True, overwrite_input=True)  # nodata: NaN, dropped
    t -= med
    np.abs(t, out=t)
    mad = 1.4826 * np.median(t, axis=1, overwrite_input=True)
    mad = mad[np.isfinite(mad)]
    return float(np.quantile(mad, _SMOOTH_QUANTILE)) if mad.size else 0.0


def _ground_spread(v, tile=_TILE):
    """:func:`_smooth_spread` of bends with the off-ground cells NaN: per tile the robust
    spread of its ground cells when they are at least a quarter of the tile; with no such
    tile, the spread of all ground cells pooled (0 with fewer than 100)."""
    b, r, c = v.shape
    tr, tc = max(1, min(tile, r)), max(1, min(tile, c))
    nr, nc = r // tr, c // tc
    t = v[:, :nr * tr, :nc * tc].reshape(b, nr, tr, nc, tc).transpose(1, 3, 0, 2, 4)
    t = t.reshape(nr * nc, -1).astype(np.float64)
    n = np.count_nonzero(np.isfinite(t), axis=1)
    ok = n >= t.shape[1] // 4
    if ok.any():
        t = t[ok]
        with np.errstate(invalid="ignore"):
            med = np.nanmedian(t, axis=1, keepdims=True)
            mad = 1.4826 * np.nanmedian(np.abs(t - med), axis=1)
        mad = mad[np.isfinite(mad)]
        if mad.size:
            return float(np.quantile(mad, _SMOOTH_QUANTILE))
    a = v[np.isfinite(v)].astype(np.float64)
    if a.size < 100:
        return 0.0
    return float(1.4826 * np.median(np.abs(a - np.median(a))))


def _sample(z):
    """Central window of at most ``_SAMPLE_CELLS`` cells (defaults on big rasters)."""
    side = int(np.sqrt(_SAMPLE_CELLS))
    r, c = z.shape
    h, w = min(r, side), min(c, side)
    r0, c0 = (r - h) // 2, (c - w) // 2
    return z[r0:r0 + h, c0:c0 + w]


# --------------------------------------------------------------------------- filter
def filter_curvature(z, cell_size, *, k_g_per_m2, window_cells=5, model="quadratic",
                     min_object_height_m=1.0, wall_slope_deg=45.0, max_object_size_m=100.0,
                     tolerance_m=0.3, progress=None):
    """Separate objects from the ground by the Gaussian curvature of local trends.

    Luong Chinh Ke (2002), section 2.2: a local surface fitted by least squares around
    every point gives its Gaussian curvature K = (r t - s^2) / h^4 (eqs. 9-16); a point
    with |K| >= K_g is a break at the foot or the top of an object. Breaks are then
    turned into whole objects along the X and Y profiles (see the module docstring).

    Parameters
    ----------
    z : array_like, 2-D
        DSM in metres, NaN = nodata. Not modified.
    cell_size : float or (float, float)
        ``(dx, dy)`` in metres.
    k_g_per_m2 : float
        Curvature threshold K_g in 1/m^2. A cell is a break when ``|K| >= K_g`` or, with
        the quadratic model, when the bend of its X or Y profile trend ``|r|`` or ``|t|``
        is at least ``sqrt(K_g)`` (a straight roof edge has K = 0 but its profile across
        the edge bends strongly).
    window_cells : int
        Odd number of points per profile group (window edge), >= 3; the paper asks for at
        least 5.
    model : {"quadratic", "bilinear"}
        Local trend surface. ``"bilinear"`` is the paper's eq. 12 (K <= 0 always,
        r = t = 0: only twisted breaks such as corners are seen).
    min_object_height_m : float
        A profile enters an object at a break where it has risen at least this much
        within two cells (a wall); also the depth below the ground surface and below the
        ring around it that makes a concave break a low blunder (class 2).
    wall_slope_deg : float
        That rise must be steeper than this, and three times steeper than the profile
        before it (object walls are steep; dams, embankments and terrace edges are not).
    max_object_size_m : float
        Longest object (profile runs and enclosed regions larger than this are ground);
        also bounds the method's reach (halo).
    tolerance_m : float
        Final pass: a cell more than this (plus one cell of the surface's slope) above the
        ground surface interpolated under the objects and breaks is an object.
    progress : callable, optional
        ``progress(fraction)``; may raise :class:`~.common.Cancelled`.

    Returns
    -------
    FilterResult
        ``mask`` (0 ground, 1 object, 2 low blunder, 255 nodata), ``extras["curvature"]``
        (float32, bands K in 1/m^2 and H in 1/m, H > 0 convex; NaN at nodata),
        ``surface`` (the ground surface of the final pass), and ``info`` with K_g and the
        shares of valid cells marked by X profiles (``share_marked_x``), by Y profiles
        (``share_marked_y``), by ``|K| >= K_g`` (``share_marked_k``) and found inside
        objects by the X and Y profiles.

    References
    ----------
    Luong Chinh Ke (2002). Filtering of DSM, section 2.2 (local trend, Gaussian curvature).
    """
    z = as_surface(z)
    dx, dy = as_cell_size(cell_size)
    window_cells = _check_window(window_cells)
    model = _check_model(model)
    k_g = _positive("k_g_per_m2", k_g_per_m2, "a curvature threshold K_g in 1/m^2, e.g. "
                    "leave it empty to derive it from the data")
    h_min = _positive("min_object_height_m", min_object_height_m, "e.g. 1.0")
    tol = _positive("tolerance_m", tolerance_m, "e.g. 0.3")
    max_size = _positive("max_object_size_m", max_object_size_m, "e.g. 100")
    if not (0.0 < float(wall_slope_deg) < 90.0):
        raise ValueError(f"wall_slope_deg must be between 0 and 90 degrees; got {wall_slope_deg}. "
                         "Use e.g. 45.")
    tan_wall = float(np.tan(np.radians(float(wall_slope_deg))))
    valid = np.isfinite(z)
    report(progress, 0.0)

    # 1. local trends and curvature (eqs. 9-16), and
    # 2. breaks: |K| >= K_g (the paper), and the bending of the X and Y profile trends,
    #    |r| or |t| >= kappa_g = sqrt(K_g): a straight roof edge has K = 0 (one principal
    #    curvature is zero) and a tall wall has a tiny K (h^4 is large), but its profile
    #    across the edge bends strongly.
    # Block of rows by block: the derivatives p, q, r, s, t live in cache-sized buffers.
    kappa_g = np.float32(np.sqrt(k_g))
    curv = np.empty((2,) + z.shape, np.float32)
    mark_k = np.empty(z.shape, bool)
    marked = np.empty(z.shape, bool)
    n_mark_x = n_mark_y = 0
    buf = None
    for sl, p, q, r, s, t in _derivative_blocks(z, (dx, dy), window_cells, model):
        K, H = curvatures_from_derivatives(p, q, r, s, t, out=curv[:, sl])
        if buf is None:
            buf = (np.empty(p.shape, np.float32), np.empty(p.shape, bool))
        a, mx = buf[0][:p.shape[0]], buf[1][:p.shape[0]]
        mk, mb = mark_k[sl], marked[sl]
        np.greater_equal(np.abs(K, out=a), np.float32(k_g), out=mk)  # NaN (nodata): False
        np.copyto(mb, mk)
        np.greater_equal(np.abs(r, out=a), kappa_g, out=mx)
        n_mark_x += int(np.count_nonzero(mx))
        mb |= mx
        np.greater_equal(np.abs(t, out=a), kappa_g, out=mx)
        n_mark_y += int(np.count_nonzero(mx))
        mb |= mx
    K, H = curv[0], curv[1]
    del p, q, r, s, t, buf
    report(progress, 0.25)

    n_valid = int(np.count_nonzero(valid))
    all_valid = n_valid == valid.size
    n_valid = max(n_valid, 1)
    report(progress, 0.35)

    # 3. along X and Y profiles: from a break going up to the break coming down
    m = window_cells // 2
    kw = dict(h_min=h_min, tan_wall=tan_wall, tol=tol, reach=2 * window_cells + 1)
    obj_x = _axis_objects(z, marked, None if all_valid else valid, dx, 1,
                          max_cells=int(max_size / dx), **kw)
    report(progress, 0.45)
    obj_y = _axis_objects(z, marked, None if all_valid else valid, dy, 0,
                          max_cells=int(max_size / dy), **kw)
    report(progress, 0.55)

    # 4. regions enclosed by breaks and mostly such runs -> whole objects
    free = ~marked if all_valid else valid & ~marked
    objects = obj_x | obj_y
    n_obj_x, n_obj_y = int(np.count_nonzero(obj_x)), int(np.count_nonzero(obj_y))
    del obj_x, obj_y
    objects |= _enclosed_regions(objects, free, int(max(max_size / dx, max_size / dy)))
    del free
    report(progress, 0.65)

    # 5. final pass against the ground interpolated under objects and breaks (twice:
    #    the second surface also rests on the breaks found to be ground)
    mask = np.zeros(z.shape, np.uint8)
    surface = None
    # not ground seeds: breaks next to objects (their feet and walls) and the points the
    # paper's test marks, |K| >= K_g: curved both ways (crowns, corners, spikes, pits).
    # Straight breaks away from objects (dams, embankments, terrace edges: K ~ 0 because
    # one principal curvature is zero) stay seeds.
    invalid = None if all_valid else ~valid
    holes = _dilate(objects, m)           # near objects ...
    holes &= marked                       # ... the breaks
    holes |= objects
    holes |= mark_k
    if invalid is not None:
        holes |= invalid
    concave = np.less(H, 0)
    concave &= marked
    edge = marked & ~objects
    allow = None
    d = np.empty(z.shape, np.float32)
    tmp = np.empty(z.shape, bool)
    for it in range(_PASSES):
        if holes.all():                   # no ground seed (nodata is in holes)
            mask[objects] = OBJECT
            break
        # the first pass's surface is not needed once d and the allowance are known
        surface = _ground_surface(z, holes, out=surface)
        np.subtract(z, surface, out=d)
        if allow is None:  # the slope of the first surface serves both passes
            # the tolerance grows with the slope of the surface: one cell of horizontal
            # uncertainty on a slope is a height difference of tan(slope) * cell
            allow = _slope(surface, dx, dy)
            allow *= np.float32(max(dx, dy))
            allow += np.float32(tol)
            # a break that no profile found inside an object must stand half the minimum
            # object height more above the surface: interpolated across a band of breaks,
            # the surface sags below convex terrain edges (crest of a dam) by some decimetres
            np.maximum(allow, np.float32(0.5 * h_min + tol), out=allow, where=edge)
        np.greater(d, allow, out=mask.view(bool))       # OBJECT where above, else GROUND
        if OBJECT != 1:  # pragma: no cover - the codes are fixed
            mask *= np.uint8(OBJECT)
        np.less(d, np.float32(-h_min), out=tmp)
        tmp &= concave
        mask.ravel()[_pits(z, tmp, m + 2, h_min)] = LOW
        # cells the profiles found between a break up and a break down stay objects when
        # they stand clearly (half the minimum object height) above the ground surface;
        # a profile that overshot along a rising terrain (a dam behind a bush) does not
        np.greater(d, np.float32(0.5 * h_min), out=tmp)
        tmp &= objects
        np.copyto(mask, np.uint8(OBJECT), where=tmp)
        np.not_equal(mask, GROUND, out=holes)
        holes |= mark_k
        if invalid is not None:
            holes |= invalid
        report(progress, 0.8 + 0.1 * it)
    del d, tmp
    if invalid is not None:
        mask[invalid] = NODATA

    info = {"k_g_per_m2": float(k_g), "window_cells": window_cells, "model": model,
            "min_object_height_m": h_min, "wall_slope_deg": float(wall_slope_deg),
            "max_object_size_m": max_size, "tolerance_m": tol,
            "share_marked_x": n_mark_x / n_valid,
            "share_marked_y": n_mark_y / n_valid,
            "share_marked_k": np.count_nonzero(mark_k) / n_valid,
            "share_marked": np.count_nonzero(marked) / n_valid,
            "share_objects_x": n_obj_x / n_valid,
            "share_objects_y": n_obj_y / n_valid}
    report(progress, 1.0)
    return FilterResult(mask=mask, extras={"curvature": curv}, info=info, surface=surface)


def _slope(a, dx, dy):
    """tan(slope) of a complete surface by central differences (one-sided at the edges),
    block of rows by block (the gradients live in cache-sized buffers)."""
    rows, cols = a.shape
    out = np.empty(a.shape, np.float32)
    step = max(1, _CHUNK_CELLS // max(cols, 1))
    gx_b = np.empty((min(step, rows), cols), np.float32)
    gy_b = np.empty((min(step, rows), cols), np.float32)
    for i0 in range(0, rows, step):
        i1 = min(rows, i0 + step)
        n = i1 - i0
        blk, gx, gy = a[i0:i1], gx_b[:n], gy_b[:n]
        if cols > 1:
            np.subtract(blk[:, 2:], blk[:, :-2], out=gx[:, 1:-1])
            gx[:, 1:-1] *= np.float32(0.5 / dx)
            gx[:, 0] = (blk[:, 1] - blk[:, 0]) / dx
            gx[:, -1] = (blk[:, -1] - blk[:, -2]) / dx
        else:
            gx[:] = 0
        if rows > 1:
            lo, hi = max(i0, 1), min(i1, rows - 1)   # rows with both neighbours
            if hi > lo:
                np.subtract(a[lo + 1:hi + 1], a[lo - 1:hi - 1], out=gy[lo - i0:hi - i0])
                gy[lo - i0:hi - i0] *= np.float32(0.5 / dy)
            if i0 == 0:
                gy[0] = (a[1] - a[0]) / dy
            if i1 == rows:
                gy[n - 1] = (a[-1] - a[-2]) / dy
        else:
            gy[:] = 0
        gx *= gx
        gy *= gy
        gx += gy
        np.sqrt(gx, out=out[i0:i1])
    return out


def _positive(name, value, hint):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive number; got {value!r}: {hint}.") from None
    if not np.isfinite(v) or v <= 0:
        raise ValueError(f"{name} must be a positive number; got {value!r}: {hint}.")
    return v


def derive_k_g(z, cell_size, *, window=5, model="quadratic"):
    """Curvature threshold K_g (1/m^2) from the data's own curvature distribution.

    The bends r and t of the X and Y profile trends (quadratic model) or the normalised
    twist s / h^2 (bilinear model) are taken on a central sample of at most
    ``_SAMPLE_CELLS`` cells. Their robust spread ``1.4826 MAD`` is computed per 16 x 16
    tile and ``sigma`` is the first quartile of the tiles: the curvature noise of the
    smooth ground and roofs, not inflated by vegetation and object edges, which cover
    most of an urban scene. ``K_g = (1.5 sigma)^2``, the Gaussian curvature of a point
    bent by 1.5 sigma both ways, floored at the bend of a 5 cm deviation over half a
    window so that noise-free data do not mark every gentle bend. (1.5 rather than a
    stricter 3 sigma: the wall and surface tests downstream reject the extra breaks, and
    missed breaks cost whole objects.)
    """
    dx, dy = as_cell_size(cell_size)
    window = _check_window(window)
    model = _check_model(model)
    zs = _sample(as_surface(z))
    quad = model == "quadratic"
    v = np.empty((2 if quad else 1,) + zs.shape, np.float32)  # the bands of bends
    for sl, p, q, r, s, t in _derivative_blocks(zs, (dx, dy), window, model):
        if quad:
            v[0, sl] = r
            v[1, sl] = t
        else:
            np.divide(s, 1.0 + p * p + q * q, out=v[0, sl])
    # the bends of the ground, not of the canopy or the roofs: cells off the ground level
    # are left out, tiles keep their robust spread when at least a quarter is ground
    ground = ground_level_cells(zs, (dx, dy), noise_ground_level(zs, (dx, dy))["sigma"])
    ground = ndimage.binary_erosion(ground, np.ones((window, window), bool), border_value=1)
    v[:, ~ground] = np.nan
    sigma = _ground_spread(v)
    half = (window // 2) * max(dx, dy)
    floor = 2.0 * _MIN_BREAK_M / (half * half)
    kappa = max(_K_SIGMAS * sigma, floor)
    return kappa * kappa


def resolve_curvature_params(z, cell_size, *, k_g_per_m2=None, window_cells=5,
                             model="quadratic", min_object_height_m=1.0, wall_slope_deg=45.0,
                             max_object_size_m=100.0, tolerance_m=None):
    """Complete parameter set for :func:`filter_curvature`, ``None`` derived from the data.

    ``k_g_per_m2``: :func:`derive_k_g` (1.5 robust sigmas of the data's profile bends on
    its smooth parts, squared). ``tolerance_m``: three times the robust noise of the
    DSM's smooth parts (second differences), kept within [0.3, 1.0] m. The others have
    fixed defaults (see :data:`METHOD`).
    """
    z = as_surface(z)
    dx, dy = as_cell_size(cell_size)
    window_cells = _check_window(window_cells)
    model = _check_model(model)
    if k_g_per_m2 is None:
        k_g_per_m2 = derive_k_g(z, (dx, dy), window=window_cells, model=model)
    if tolerance_m is None:
        sigma = noise_ground_level(z, (dx, dy))["sigma"]
        tolerance_m = float(np.clip(3.0 * sigma, 0.3, 1.0)) if np.isfinite(sigma) else 0.5
    return {"k_g_per_m2": float(k_g_per_m2), "window_cells": window_cells, "model": model,
            "min_object_height_m": float(min_object_height_m),
            "wall_slope_deg": float(wall_slope_deg),
            "max_object_size_m": float(max_object_size_m), "tolerance_m": float(tolerance_m)}


def curvature_halo(params, cell_size):
    """Reach of the filter in cells: the window, the foot search beyond a break, and
    twice the largest object (runs, enclosed regions and the ground surface under them);
    even, so that blocks cut at even rows keep the 2 x 2 grid of the ground surface
    (:func:`_ground_surface`) of one pass."""
    dx, dy = as_cell_size(cell_size)
    w = _check_window(params.get("window_cells", 5))
    size = float(params.get("max_object_size_m", 100.0))
    halo = int(w // 2 + 2 * w + 2 * int(np.ceil(size / min(dx, dy))) + 2)
    return halo + (halo & 1)


def _run(z, cell_size, progress=None, **params):
    return filter_curvature(z, cell_size, progress=progress, **params)


METHOD = Method(
    name="curvature",
    run=_run,
    resolve=resolve_curvature_params,
    halo=curvature_halo,
    extras={"curvature": (np.float32, 2, float("nan"))},
    params=(
        Param("k_g_per_m2", "float", None,
              "Gaussian-curvature threshold K_g in 1/m^2 (Luong Chinh Ke 2002, sec. 2.2): a "
              "cell with |K| >= K_g, or whose X or Y profile bends by sqrt(K_g) 1/m or more, "
              "is a break. Empty: (1.5 robust sigmas of the data's profile bends)^2; see "
              "the CURVATURE output to choose it.", minimum=1e-9, maximum=1e6),
        Param("window_cells", "int", 5,
              "Points per profile group (odd window edge, cells) of the local least-squares "
              "trend; the paper asks for at least 5.", minimum=3, maximum=51),
        Param("model", "enum", "quadratic",
              "Local trend surface: 'quadratic' (z = a + bx + cy + dx^2 + exy + fy^2, gives K "
              "and the mean curvature H) or 'bilinear', the paper's eq. 12 (r = t = 0, so "
              "K <= 0 and straight edges are not seen).", options=MODELS, advanced=True),
        Param("min_object_height_m", "float", 1.0,
              "Metres a profile must rise at a break, within two cells, to enter an object "
              "(Luong Chinh Ke 2002: points between a break going up and the break coming "
              "down); also the depth of a low blunder (class 2).",
              minimum=0.05, maximum=100.0),
        Param("wall_slope_deg", "float", 45.0,
              "Degrees: that rise must be steeper than this (and 3x steeper than the profile "
              "before it) to be an object's wall; dams, embankments and terrace edges are "
              "gentler and stay ground.", minimum=1.0, maximum=89.0, advanced=True),
        Param("max_object_size_m", "float", 100.0,
              "Metres: largest object; larger enclosed regions are ground. Also the method's "
              "reach for block processing.", minimum=1.0, maximum=2000.0),
        Param("tolerance_m", "float", None,
              "Metres above the ground surface interpolated under objects and breaks that a "
              "cell may stand (plus one cell of the surface's slope) and still be ground "
              "(final pass). Empty: 3 x the DSM's robust noise, within [0.3, 1] m.",
              minimum=0.01, maximum=10.0, advanced=True),
    ),
    title="Curvature filter (Luong Chinh Ke 2002)",
    description=(
        "<p>Local-trend filter by Gaussian curvature (Luong Chinh Ke 2002, section 2.2). A "
        "local surface is fitted by least squares to the <i>window</i> x <i>window</i> "
        "points around every cell (at least five points per X and Y profile) and gives "
        "the Gaussian curvature K = (r t - s<sup>2</sup>) / h<sup>4</sup>, "
        "h<sup>2</sup> = 1 + p<sup>2</sup> + q<sup>2</sup> (eqs. 9-16), and the mean "
        "curvature H (H &gt; 0 convex, H &lt; 0 concave). Cells with |K| &ge; K<sub>g</sub>, "
        "or whose X or Y profile bends by &radic;K<sub>g</sub> or more (a straight roof "
        "edge has K = 0), are breaks at the feet and tops of objects.</p>"
        "<p>Along each X and Y profile, scanned both ways, the points between a break going "
        "up a wall (a rise of at least the minimum object height within two cells, steeper "
        "than the wall slope and than the profile before it) and the matching break coming "
        "down belong to an object; regions enclosed by breaks and made mostly of such "
        "points become whole objects. A final pass compares every cell with the ground "
        "interpolated under the objects and their breaks: straight breaks of the terrain "
        "itself (dams, embankments, terrace edges) stay ground; concave breaks deeper than "
        "the minimum object height below the ground and the cells around them are low "
        "blunders (class 2).</p>"
        "<p><b>The paper's bilinear surface</b> z = a0 + a1 X + a2 Y + a3 XY (eq. 12) is "
        "available as the <i>bilinear</i> model. It has a limit: fitted to the points of "
        "one profile it is degenerate (with Y constant, a2 and a3 cannot be separated), so "
        "it is fitted here to the window of neighbouring profiles; and its second "
        "derivatives are r = t = 0, so r t - s<sup>2</sup> = -a3<sup>2</sup> is never "
        "positive: it cannot tell convex from concave and sees only twisted breaks "
        "(corners), not straight edges. The default quadratic surface has none of these "
        "limits.</p>"
        "<p>Defaults: K<sub>g</sub> = (1.5 robust standard deviations of the profile bends "
        "of the data's smooth parts)<sup>2</sup>; tolerance = 3 x the DSM's robust noise "
        "(0.3 to 1 m). The CURVATURE output (band 1 K in 1/m<sup>2</sup>, band 2 H in "
        "1/m) shows what the filter saw; the log gives K<sub>g</sub> and the share of "
        "cells marked by X and by Y profiles. The curvature is attenuated within "
        "<i>window</i>/2 cells of the raster's edge (the edge is extended as a plane).</p>"
        "<p>Reference: Luong Chinh Ke (2002), filtering of DSM, section 2.2.</p>"),
)
