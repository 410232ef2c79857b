"""Slope-profile filter (Luong Chinh Ke 2002, section 2.1).

Along every profile in X (rows) and in Y (columns) the slope between consecutive points
is ``alpha = atan(dZ / dX)``. A point whose slope from the ground before it exceeds the
terrain slope threshold ``alpha_g`` is on an object. The height of a rejected point is
corrected by ``dZ`` (the paper's rule), i.e. the profile keeps the last ground height as
its reference, so the points that follow on a roof or a tree crown stay rejected until
the profile comes back down to the ground: whole objects are removed, not only their edges.

Details this implementation adds to the paper, each for a failure the paper's rule has:

* **Distance-aware tolerance.** After ``d`` rejected cells the ground may have risen by
  the terrain's own slope: a point is accepted when
  ``dZ <= dh0 + dX tan(alpha_g) + (d - 1) dX tan(alpha_t)``, with ``alpha_t`` the typical
  terrain slope (far below ``alpha_g``) and ``dh0`` the DSM's noise. With ``d = 1`` this
  is the paper's test plus a noise allowance.
* **Objects at the start of a profile.** The reference starts at the lowest point of the
  profile's first ``max_object_size_m``, not at its first point.
* **Both directions.** Each profile is scanned forwards and backwards; a cell is an object
  for that axis only when both scans reject it. A scan that climbs a terrace edge or a
  steep slope rejects the upper side, but the scan coming down the other way accepts it
  (a drop below the reference resets the reference), so terrain steps survive, while a
  building is rejected from both sides.
* **X and Y combined by connected objects**: the union of the X and Y rejections, keeping
  each connected object only when at least a tenth of its cells are rejected by both axes.
  An object elongated along one axis is short, hence caught, along the other; but a road
  embankment or a dam that a profile runs along is accepted by that profile over most of
  its length, and goes back to the ground.
* **Low blunders** (a drop then a rise, typical of image matching and laser multipath) are
  found first: pits a 3 x 3 grey closing fills that also lie below the lower third of
  their 7 x 7 neighbourhood (so ground hits between tree crowns stay ground). They get
  class 2 and the scans skip them.
* **Refinement** (optional, off by default). Rejected cells lying within the tolerance of
  the surface interpolated from the accepted ones are given back to the ground (as SMRF's
  final step does).

References
----------
Luong Chinh Ke (2002). Filtering of digital surface models. Section 2.1, slope along X/Y
profiles.
"""
import threading
import warnings

import numpy as np
from scipy import ndimage

from .estimate import below_surroundings, noise_ground_level
from .codes import GROUND, LOW, NODATA, OBJECT
from .common import FilterResult, as_cell_size, as_surface, report, sub_progress, transpose
from .methods import Method, Param

#: Bounds of the derived slope threshold alpha_g and floor of alpha_t, degrees.
_MIN_ALPHA_G, _MAX_ALPHA_G = 25.0, 60.0
_MIN_ALPHA_T = 8.0
#: Largest sample spacing (cells) the edge test allows for.
_MAX_SPACING = 4.0


def profile_slopes(z, cell_size):
    """Slope angles between consecutive points along X and Y profiles, in degrees.

    ``alpha_x[i, j] = atan((z[i, j+1] - z[i, j]) / dx)`` and
    ``alpha_y[i, j] = atan((z[i+1, j] - z[i, j]) / dy)`` (the paper's dZ/dX; Y runs
    down the rows). Shapes ``(rows, cols-1)`` and ``(rows-1, cols)``.
    """
    z = as_surface(z).astype(np.float64)
    dx, dy = as_cell_size(cell_size)
    return (np.degrees(np.arctan(np.diff(z, axis=1) / dx)),
            np.degrees(np.arctan(np.diff(z, axis=0) / dy)))


def _block_min(z, k):
    """Minimum over non-overlapping k x k blocks (NaN ignored; all-NaN blocks -> NaN).

    Band by band of ``k`` rows: the minimum down the band's columns (contiguous rows,
    cached), then over each run of ``k`` columns; ``fmin`` ignores NaN without copies.
    """
    rows, cols = z.shape
    R, C = -(-rows // k), -(-cols // k)
    out = np.empty((R, C), np.float32)
    pad = np.full(C * k, np.nan, np.float32) if cols % k else None
    for i in range(R):
        band = np.fmin.reduce(z[i * k:(i + 1) * k], axis=0)
        if pad is not None:
            pad[:cols] = band
            band = pad
        out[i] = np.fmin.reduce(band.reshape(C, k), axis=1)
    return out


def estimate_terrain_slope(z, cell_size, scale_m=20.0):
    """Robust slopes of the terrain under the objects.

    The surface is reduced to the minimum of ``scale_m`` blocks (objects smaller than a
    block vanish from it), and the slopes (rise/run) between neighbouring block minima
    are summarised.

    Returns
    -------
    dict with ``median`` and ``p90`` of |slope| (rise/run) and the block size in cells.
    """
    z = as_surface(z)
    dx, dy = as_cell_size(cell_size)
    k = int(max(2, round(scale_m / min(dx, dy))))
    k = min(k, max(2, min(z.shape) // 3))
    m = _block_min(z, k)
    if min(m.shape) < 2:
        return {"median": 0.0, "p90": 0.0, "block_cells": k}
    # gradient magnitude (rise/run) of the block-minimum surface: the steepest slope of
    # the ground, whatever its direction
    gy, gx = np.gradient(m.astype(np.float64), k * dy, k * dx)
    s = np.hypot(gx, gy).ravel()
    s = s[np.isfinite(s)]
    if s.size == 0:
        return {"median": 0.0, "p90": 0.0, "block_cells": k}
    return {"median": float(np.median(s)), "p90": float(np.percentile(s, 90)), "block_cells": k}


#: Cells that enter the noise and sample-spacing estimates: larger rasters are sampled
#: by windows spread over them (medians and means are stable far below that; ISPRS-sized
#: rasters are used whole).
_SAMPLE_CELLS = 1_000_000
_SAMPLE_WINDOW = 256


def _sample_windows(z, cells=_SAMPLE_CELLS, side=_SAMPLE_WINDOW):
    """``z`` itself when it has at most ``cells`` cells, else about ``cells / side**2``
    windows of ``side`` x ``side`` cells on a regular grid over it (views, no copy; each
    window is contiguous along its rows, so sampling reads a fraction of the raster)."""
    rows, cols = z.shape
    if z.size <= cells or rows < 2 * side or cols < 2 * side:
        return [z]
    n = max(1, cells // (side * side))
    ny = max(1, min(rows // side, int(round(np.sqrt(n * rows / cols)))))
    nx = max(1, min(cols // side, -(-n // ny)))
    r0 = np.linspace(0, rows - side, ny).astype(int)
    c0 = np.linspace(0, cols - side, nx).astype(int)
    return [z[r:r + side, c:c + side] for r in r0 for c in c0]


def estimate_noise(z):
    """Robust standard deviation of the DSM's random error, metres.

    From the second differences along rows and columns (``z[i-1] - 2 z[i] + z[i+1]``,
    whose variance is 6 sigma^2 for white noise on a smooth surface), via the median
    absolute value, so edges and objects do not inflate it. Large rasters are sampled
    (:func:`_sample_windows`).
    """
    z = as_surface(z)
    d = []
    for w in _sample_windows(z):
        if w.shape[1] > 2:
            d.append((w[:, :-2] - 2 * w[:, 1:-1] + w[:, 2:]).ravel())
        if w.shape[0] > 2:
            d.append((w[:-2] - 2 * w[1:-1] + w[2:]).ravel())
    d = np.concatenate(d) if d else np.array([0.0])
    d = d[np.isfinite(d)]
    if d.size == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(d)) / np.sqrt(6.0))


def estimate_sample_spacing(z, longest=8):
    """Mean length (cells) of the runs of identical neighbouring values along rows and columns.

    A DSM measured at every cell gives 1. A DSM gridded from sparser points with empty
    cells filled from the nearest point repeats each value over a run of cells, and its
    height steps come at the run ends: the edge test must span the data's own spacing,
    not one cell. Runs longer than ``longest`` cells are constant areas (water, a flat
    synthetic ground), not gridding, and are left out. Returns a value >= 1. Large
    rasters are sampled (:func:`_sample_windows`).
    """
    z = as_surface(z)
    lengths = []
    for w in _sample_windows(z):
        for a in (w, w.T.copy()):
            if a.shape[1] < 2:
                continue
            start = np.ones(a.shape, bool)
            start[:, 1:] = a[:, 1:] != a[:, :-1]
            idx = np.flatnonzero(start.ravel())
            lengths.append(np.diff(np.append(idx, a.size)))
    if not lengths:
        return 1.0
    runs = np.concatenate(lengths)
    runs = runs[runs <= longest]
    return float(runs.mean()) if runs.size else 1.0


def _extreme3(a, op, out=None, tmp=None):
    """3 x 3 running max or min (``op`` = np.maximum / np.minimum), edges replicated.

    Separable, by slicing: four passes of one ufunc over the array; ``out`` and ``tmp``
    are optional buffers of ``a``'s shape (``out`` may not be ``a``).
    """
    if tmp is None:
        t = a.copy()
    else:
        np.copyto(tmp, a)
        t = tmp
    op(t[:, 1:], a[:, :-1], out=t[:, 1:])
    op(t[:, :-1], a[:, 1:], out=t[:, :-1])
    if out is None:
        out = t.copy()
    else:
        np.copyto(out, t)
    op(out[1:], t[:-1], out=out[1:])
    op(out[:-1], t[1:], out=out[:-1])
    return out


#: Window (cells) and rank of the local ground height a low blunder must lie below.
_LOW_WINDOW, _LOW_RANK = 7, 16


def find_low_blunders(z, tolerance_m):
    """Low blunders: pits of one or two cells deeper than ``tolerance_m`` below the ground.

    Candidates are the cells a 3 x 3 grey closing raises by more than the tolerance (a
    drop then a rise along every profile). A candidate is a blunder only when it is also
    more than the tolerance below the 16th-lowest of the 49 values of its 7 x 7
    neighbourhood (the lower third): a ground hit between tree crowns has other ground
    hits near it and is kept, while a blunder, even a cluster of a dozen cells, has only
    itself and its cluster that low.
    """
    z = as_surface(z)
    valid = np.isfinite(z)
    hi = np.float32(np.nanmax(z)) if valid.any() else np.float32(0.0)
    # candidates: cells a 3 x 3 closing raises by more than the tolerance, in strips of
    # rows (the closing reaches 2 rows), so memory stays a few strips whatever the raster
    rows, cols = z.shape
    strip = 64  # rows: the closing's buffers stay in the cache
    found = []
    for r0 in range(0, rows, strip):
        r1 = min(rows, r0 + strip)
        a0, a1 = max(0, r0 - 2), min(rows, r1 + 2)
        zz = np.where(valid[a0:a1], z[a0:a1], hi)  # nodata: neither a pit's rim nor its bottom
        tmp = np.empty_like(zz)
        dil = _extreme3(zz, np.maximum, tmp=tmp)
        closed = _extreme3(dil, np.minimum, out=tmp, tmp=dil.copy())
        closed -= zz
        cb = closed[r0 - a0:r0 - a0 + (r1 - r0)] > tolerance_m
        cb &= valid[r0:r1]
        q = np.flatnonzero(cb)                   # the band's candidates, while it is cached
        if q.size:
            found.append(q + r0 * cols)
    low = np.zeros(z.shape, bool)
    if not found:
        return low
    r, c = np.divmod(np.concatenate(found), cols)
    h = _LOW_WINDOW // 2
    off = np.arange(-h, h + 1)
    rr = np.clip(r[:, None, None] + off[None, :, None], 0, z.shape[0] - 1)   # edges replicated
    cc = np.clip(c[:, None, None] + off[None, None, :], 0, z.shape[1] - 1)
    neigh = z[rr, cc].reshape(r.size, _LOW_WINDOW * _LOW_WINDOW)
    neigh[np.isnan(neigh)] = np.inf                                            # nodata is no ground
    fifth = np.partition(neigh, _LOW_RANK - 1, axis=1)[:, _LOW_RANK - 1]
    low[r, c] = z[r, c] < fifth - tolerance_m
    return low


def _scan(sources, step_m, tan_g, tan_t, dh0, init_cells, edge_cells=1):
    """Scan many profile sets at once, one numpy operation per step over all profiles.

    ``sources`` is a list of ``(array, reverse)``: an array ``(npos, nprof)`` holds
    profiles along axis 0 (C-contiguous rows), scanned from its first row, or from its
    last with ``reverse``. At each step the current row of every source is copied into
    one small buffer (no stacked copy of the raster is made), so the per-step Python
    overhead is shared by all profiles of all sources.

    The tolerance after ``d`` cells since the reference point is
    ``dh0 + step tan_g min(d, edge_cells) + step tan_t max(d - edge_cells, 0)``.
    Returns one boolean array per source (its shape; views into buffers shared by the
    sources of one array): True where the scan rejects.
    """
    widths = [a.shape[1] for a, _ in sources]
    offs = np.cumsum([0] + widths)
    nprof = int(offs[-1])
    npos = max(a.shape[0] for a, _ in sources)
    g = np.empty(nprof, np.float32)                  # reference ground height per profile
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        for (a, rev), o0, o1 in zip(sources, offs[:-1], offs[1:]):
            head = a[-init_cells:] if rev else a[:init_cells]
            g[o0:o1] = np.nanmin(head, axis=0)
    g[np.isnan(g)] = np.inf     # no ground in the start window: the first valid cell is accepted
    # The tolerance is piecewise linear in k = d - 1, the valid cells rejected since the
    # reference point: line 1, dh0 + step tan_g (k + 1), up to the edge run, then line 2,
    # dh0 + step (tan_g e + tan_t (k + 1 - e)). The lower of the two when tan_g >= tan_t
    # (the higher otherwise); line 2 alone when the edge run is one cell. k is a float32
    # count (exact), so the tolerance costs two operations per step, no table lookup.
    e = int(edge_cells)
    a2 = np.float32(dh0 + step_m * (tan_g * e + tan_t * (1 - e)))
    b2 = np.float32(step_m * tan_t)
    two_lines = e > 1 and tan_g != tan_t
    a1, b1 = np.float32(dh0 + step_m * tan_g), np.float32(step_m * tan_g)
    pick = np.minimum if tan_g >= tan_t else np.maximum
    k = np.zeros(nprof, np.float32)
    # Rejections, step by step: one buffer per array scanned (its forward and backward
    # sources side by side, as many rows as the array), one row written per step.
    groups = []                                  # [array, first, last column in v]
    member = []                                  # per source: its group
    for (a, _), o0, o1 in zip(sources, offs[:-1], offs[1:]):
        if groups and groups[-1][0] is a and groups[-1][2] == o0:
            groups[-1][2] = o1
        else:
            groups.append([a, o0, o1])
        member.append(len(groups) - 1)
    bufs = [np.empty((a.shape[0], o1 - o0), bool) for a, o0, o1 in groups]
    writes = [(buf, a.shape[0], o0, o1) for buf, (a, o0, o1) in zip(bufs, groups)]
    v = np.full(nprof, np.nan, np.float32)
    dz = np.empty(nprof, np.float32)
    thr = np.empty(nprof, np.float32)
    thr[:] = pick(a1, a2) if two_lines else a2           # k = 0
    thr1 = np.empty(nprof, np.float32) if two_lines else None
    up = np.empty(nprof, bool)
    ok = np.empty(nprof, bool)
    # per source: its array, direction, slice of the step buffer, and length
    spans = [(a, rev, v[o0:o1], a.shape[0]) for (a, rev), o0, o1 in zip(sources, offs[:-1], offs[1:])]
    n_min = min(n for *_, n in spans)
    # As few numpy calls per step as possible: each is short, and with blocks in threads
    # every call is a hand-over of the GIL.
    for i in range(npos):
        if i < n_min:                                  # every source still runs: one copy
            np.concatenate([a[n - 1 - i] if rev else a[i] for a, rev, _, n in spans], out=v)
        else:
            for a, rev, vv, n in spans:
                if i < n:
                    vv[...] = a[n - 1 - i] if rev else a[i]
                elif i == n:
                    vv[...] = np.nan                   # a shorter profile set has ended
        np.subtract(v, g, out=dz)
        np.greater(dz, thr, out=up)                    # rejected (NaN compares False)
        np.less_equal(dz, thr, out=ok)                 # accepted: valid and not rejected
        k += up                                        # a nodata cell does not count: a gap does
        np.copyto(k, 0.0, where=ok)                    # not let the reference drift up a roof
        np.copyto(g, v, where=ok)
        np.multiply(k, b2, out=thr)                    # the next step's tolerance
        thr += a2
        if two_lines:
            np.multiply(k, b1, out=thr1)
            thr1 += a1
            pick(thr, thr1, out=thr)
        for buf, n, o0, o1 in writes:
            if i < n:
                buf[i] = up[o0:o1]
    out = []
    for (_, rev), o0, o1, k in zip(sources, offs[:-1], offs[1:], member):
        r = bufs[k][:, o0 - groups[k][1]:o1 - groups[k][1]]
        out.append(r[::-1] if rev else r)                # views: row order of the source
    return out


#: Scans of blocks running in threads take turns: a scan is thousands of short numpy
#: calls, each handing the GIL over, so two at once run no faster than one after the
#: other (measured), while a thread waiting here leaves the core to the other threads'
#: long array operations (filling, labelling).
_SCAN_LOCK = threading.Lock()


def _scan_all(zs, dx, dy, tan_g, tan_t, dh0, init, edge):
    """Forward and backward scans along X and Y; returns ``(objects_x, objects_y)``.

    A cell is rejected along an axis when both its forward and its backward scan reject
    it. The four scans run as one vectorised pass when the two axes share a spacing.
    """
    zx = transpose(zs)                       # X profiles: positions = columns
    sx = [(zx, False), (zx, True)]
    sy = [(zs, False), (zs, True)]
    with _SCAN_LOCK:
        if abs(dx - dy) <= 1e-9 * max(dx, dy) and init[0] == init[1] and edge[0] == edge[1]:
            fx, bx, fy, by = _scan(sx + sy, dx, tan_g, tan_t, dh0, init[0], edge[0])
        else:
            fx, bx = _scan(sx, dx, tan_g, tan_t, dh0, init[0], edge[0])
            fy, by = _scan(sy, dy, tan_g, tan_t, dh0, init[1], edge[1])
    del zx
    fx &= bx
    fy &= by
    return transpose(fx), fy


#: Share of an object's cells that both axes must reject (see :func:`_combine_axes`).
_MIN_BOTH_AXES_SHARE = 0.1


def _combine_axes(obj_x, obj_y, ok):
    """X and Y results -> objects: the union, keeping each connected object only when at
    least a tenth of its cells are rejected by both axes.

    Buildings and crowns are crossed by both axes; a road embankment or a dam that one
    axis runs along is accepted by that axis along most of its length, so the other
    axis's rejections of it are given back to the ground.
    """
    union = obj_x | obj_y
    union &= ok
    if not union.any():
        return union
    lab, n = ndimage.label(union, structure=np.ones((3, 3), bool))
    both = obj_x & obj_y
    both &= ok
    # counts over the labelled cells only (a bincount of the whole raster would cast
    # every cell's label to int64 first)
    lu = lab[union]
    total = np.bincount(lu, minlength=n + 1)
    inboth = np.bincount(lab[both], minlength=n + 1)
    keep = inboth >= _MIN_BOTH_AXES_SHARE * total
    keep[0] = False
    out = np.zeros(union.shape, bool)
    out[union] = keep[lu]          # looked up for the labelled cells only
    return out


def filter_slope_profile(z, cell_size, *, slope_threshold_deg, terrain_slope_deg, tolerance_m,
                         max_object_size_m=100.0, edge_length_m=1.0, sample_spacing_cells=1.0,
                         refine=False, slope_factor=1.25, progress=None):
    """Slope-profile filter (Luong Chinh Ke 2002, section 2.1).

    Parameters
    ----------
    z : array_like, 2-D
        DSM, NaN = nodata.
    cell_size : float or (dx, dy)
        Metres.
    slope_threshold_deg : float
        ``alpha_g``: a step steeper than this from the ground before it starts an object.
    terrain_slope_deg : float
        ``alpha_t``: how fast the ground may rise under an object per cell of its length.
    tolerance_m : float
        ``dh0``: height tolerance for the DSM's noise, added to every test.
    max_object_size_m : float
        Largest object; the reference at a profile's start is the lowest point within it.
    refine : bool
        Give rejected cells within the tolerance of the interpolated ground back to the
        ground.
    slope_factor : float
        Slope term of the refinement tolerance (rise/run of the interpolated ground).
    progress : callable, optional

    Returns
    -------
    FilterResult
        ``info`` holds the share of cells rejected by X and by Y profiles.
    """
    z = as_surface(z)
    dx, dy = as_cell_size(cell_size)
    if not 0 < slope_threshold_deg < 90:
        raise ValueError(f"slope_threshold_deg must be in (0, 90) degrees; got {slope_threshold_deg}.")
    if not 0 <= terrain_slope_deg < 90:
        raise ValueError(f"terrain_slope_deg must be in [0, 90) degrees; got {terrain_slope_deg}.")
    if tolerance_m < 0:
        raise ValueError(f"tolerance_m must be >= 0 metres; got {tolerance_m}.")
    if max_object_size_m <= 0:
        raise ValueError(f"max_object_size_m must be > 0 metres; got {max_object_size_m}.")
    tan_g = float(np.tan(np.radians(slope_threshold_deg)))
    tan_t = float(np.tan(np.radians(terrain_slope_deg)))
    valid = np.isfinite(z)

    low = find_low_blunders(z, tolerance_m + max(dx, dy) * tan_g)
    low &= below_surroundings(z, (dx, dy), tolerance_m)   # below all the ground around, not a gap
    zs = np.where(low, np.float32(np.nan), z)
    report(progress, 0.05)

    init_x = max(1, int(round(max_object_size_m / dx)))
    init_y = max(1, int(round(max_object_size_m / dy)))
    ex = max(1, int(round(edge_length_m / dx)))
    ey = max(1, int(round(edge_length_m / dy)))
    sp_ = min(max(1.0, float(sample_spacing_cells)), _MAX_SPACING)
    # gridded sparse points rise in stair steps: a slope up to alpha_g over the data's own
    # spacing comes in one step, which the edge test must allow
    dh_eff = tolerance_m + (sp_ - 1.0) * min(dx, dy) * tan_g
    obj_x, obj_y = _scan_all(zs, dx, dy, tan_g, tan_t, dh_eff, (init_x, init_y), (ex, ey))
    report(progress, 0.65)
    obj = _combine_axes(obj_x, obj_y, valid & ~low)

    refined = 0
    dtm = None
    if refine and obj.any() and (valid & ~obj & ~low).any():
        from .fill import fill_gaps
        surf = fill_gaps(z, fill=obj | low)
        gy, gx = np.gradient(surf, dy, dx)
        slope = np.hypot(gx, gy)
        back = obj & (np.abs(z - surf) <= tolerance_m + slope_factor * slope)
        refined = int(back.sum())
        obj &= ~back
        if not refined:
            dtm = surf  # nothing given back: this is the DTM, exact at every ground cell
    report(progress, 0.95)

    mask = obj.astype(np.uint8)                      # OBJECT = 1, GROUND = 0
    np.copyto(mask, np.uint8(LOW), where=low)
    np.copyto(mask, np.uint8(NODATA), where=~valid)
    n = max(1, int(np.count_nonzero(valid)))
    info = {"alpha_g_deg": float(slope_threshold_deg), "alpha_t_deg": float(terrain_slope_deg),
            "dh0_m": float(tolerance_m),
            "rejected_by_x_percent": 100.0 * float(np.count_nonzero(obj_x & valid)) / n,
            "rejected_by_y_percent": 100.0 * float(np.count_nonzero(obj_y & valid)) / n,
            "refined_back_percent": 100.0 * refined / n,
            "low_blunders_percent": 100.0 * float(np.count_nonzero(low)) / n}
    report(progress, 1.0)
    return FilterResult(mask=mask, info=info, dtm=dtm)


def resolve_slope_profile_params(z, cell_size, *, slope_threshold_deg=None, terrain_slope_deg=None,
                                 tolerance_m=None, max_object_size_m=100.0, edge_length_m=1.0,
                                 sample_spacing_cells=None, refine=False, slope_factor=1.25):
    """Complete the parameters, deriving the missing ones from the data.

    * ``terrain_slope_deg`` (alpha_t): the median slope of the terrain under the objects
      (:func:`estimate_terrain_slope`: slopes between 20 m block minima, which objects do
      not reach), the paper's "average slope" made robust, and at least 8 degrees: the
      ground under a long object may rise at least that fast.
    * ``slope_threshold_deg`` (alpha_g): twice alpha_t, bounded to [25, 60] degrees:
      steeper than the terrain's usual slope, far gentler than a wall. Below 25 degrees
      the sides of road embankments and the stair steps of gridded sparse points start
      to count as object edges (measured on the ISPRS samples 61 and 71).
    * ``tolerance_m`` (dh0): 3 x the DSM's robust noise (:func:`estimate_noise`),
      bounded to [0.15, 0.5] m.
    * ``sample_spacing_cells``: the mean run of identical neighbouring values
      (:func:`estimate_sample_spacing`); the edge test spans it.

    Measured on the seven ISPRS samples under ``benchmarks/isprs.py`` (see the README).
    """
    z = as_surface(z)
    cell = as_cell_size(cell_size)
    if terrain_slope_deg is None:
        est = estimate_terrain_slope(z, cell, scale_m=20.0)
        terrain_slope_deg = max(_MIN_ALPHA_T, float(np.degrees(np.arctan(est["median"]))))
    if slope_threshold_deg is None:
        slope_threshold_deg = float(np.clip(2.0 * terrain_slope_deg, _MIN_ALPHA_G, _MAX_ALPHA_G))
    if tolerance_m is None:
        sigma = noise_ground_level(z, cell)["sigma"]
        tolerance_m = float(np.clip(3.0 * sigma, 0.15, 0.5)) if np.isfinite(sigma) else 0.5
    if sample_spacing_cells is None:
        sample_spacing_cells = estimate_sample_spacing(z)
    return {"slope_threshold_deg": float(slope_threshold_deg), "terrain_slope_deg": float(terrain_slope_deg),
            "tolerance_m": float(tolerance_m), "max_object_size_m": float(max_object_size_m),
            "edge_length_m": float(edge_length_m), "sample_spacing_cells": float(sample_spacing_cells), "refine": bool(refine), "slope_factor": float(slope_factor)}


def slope_profile_halo(params, cell_size):
    """Reach in cells: the start window plus the longest object crossed by a profile."""
    dx, dy = as_cell_size(cell_size)
    return int(np.ceil(2 * params["max_object_size_m"] / min(dx, dy))) + 2


def _run(z, cell_size, progress=None, **params):
    return filter_slope_profile(z, cell_size, progress=progress, **params)


METHOD = Method(
    name="slopeprofile",
    run=_run,
    resolve=resolve_slope_profile_params,
    halo=slope_profile_halo,
    params=(
        Param("slope_threshold_deg", "float", None,
              "Terrain slope threshold alpha_g, degrees (Ke 2002, sec. 2.1): a step steeper than this "
              "from the ground before it starts an object. Empty: twice the average terrain slope "
              "alpha_t, bounded to 25-60 deg.",
              minimum=0.5, maximum=89.0),
        Param("terrain_slope_deg", "float", None,
              "Average terrain slope alpha_t, degrees: how fast the ground may rise under an object "
              "per cell of its length. Empty: the median slope between 20 m block minima (which objects "
              "do not reach), at least 8 deg.",
              minimum=0.0, maximum=80.0, advanced=True),
        Param("tolerance_m", "float", None,
              "Height tolerance dh0, metres, added to every test for the DSM's noise. Empty: 3 x the "
              "robust noise of the DSM (from second differences), bounded to 0.15-0.5 m.",
              minimum=0.0, maximum=50.0, advanced=True),
        Param("max_object_size_m", "float", 100.0,
              "Largest object, metres: a profile's reference starts at its lowest point within this "
              "length, so objects cut by the raster's edge are still removed.",
              minimum=1.0, maximum=5000.0, advanced=True),
        Param("edge_length_m", "float", 1.0,
              "Edge run, metres: an object's edge must rise faster than alpha_g over this length "
              "(one cell = the paper's point-to-point test; longer runs ignore the stair steps of "
              "sparse or resampled data).",
              minimum=0.0, maximum=50.0, advanced=True),
        Param("sample_spacing_cells", "float", None,
              "Spacing of the DSM's real samples, in cells (at most 4 is used): the height step of "
              "the terrain's slope over it is tolerated. Empty: the mean "
              "run of identical neighbouring values (1 for a DSM measured at every cell; more for a "
              "grid of sparse points with empty cells filled from the nearest point).",
              minimum=1.0, maximum=20.0, advanced=True),
        Param("refine", "bool", False,
              "Give rejected cells lying within the tolerance of the interpolated ground back to the "
              "ground (as SMRF's last step). Off by default: on the ISPRS samples it gained nothing "
              "and it costs one more interpolation.", advanced=True),
        Param("slope_factor", "float", 1.25,
              "Slope term of the refinement tolerance (rise/run of the interpolated ground), as in SMRF.",
              minimum=0.0, maximum=10.0, advanced=True),
    ),
    title="Slope-profile filter (Luong Chinh Ke 2002)",
    description=(
        "<p>Filters a DSM along profiles in X and in Y (Luong Chinh Ke 2002, section 2.1). Along each "
        "profile the slope between consecutive points, alpha = atan(dZ/dX), is compared with the "
        "terrain slope threshold alpha_g; a rejected point's height is corrected by dZ, so the profile "
        "keeps the last ground height and the whole object stays rejected until the profile comes back "
        "to the ground.</p><p>Each profile is scanned forwards and backwards and a cell is an object for "
        "that axis only when both scans reject it (terrain steps are accepted by the scan that comes "
        "down them); the X and Y results are combined by union, so objects long in one direction are "
        "caught in the other; a connected object is kept only where both axes reject part of it, so "
        "road embankments and dams that a profile runs along stay ground. Small pits below the "
        "ground around them are low blunders (class 2).</p>"
        "<p>Defaults are derived from the DSM: alpha_g and the terrain slope from slopes between 20 m "
        "block minima, the tolerance from the DSM's noise. The log lists the values used.</p>"),
)
