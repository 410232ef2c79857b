"""Synthetic scenes with known truth: DSM, true DTM, true mask, break lines.

Used by the tests (accuracy against a truth that is exact by construction), the demo and
the speed benchmarks. Everything is vectorised: terrain fields are made on a coarse grid
and interpolated, buildings are written into array slices (a loop over buildings), and
trees and cars are stamped with a loop over stamp offsets vectorised over all objects.

Truth conventions
-----------------
* ``dtm`` is the bare earth, finite everywhere; dams, embankments and cuts are part of it.
* ``mask``: 0 ground, 1 object, 2 low blunder, 255 nodata (:mod:`.codes`). A cell is an
  object where an object surface is above the true terrain; every object surface is at
  least 1 m above it (crown edges lower than that are left out), buildings at least 4 m.
* ``dsm`` = object surface or terrain, plus Gaussian noise of ``noise_m`` (truncated at
  4.5 sigma so that "within 5 sigma" is a guarantee); low blunders are 2-20 m below
  ``min(surface, dtm)``; NaN exactly where the mask is 255.
"""
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from .codes import GROUND, LOW, NODATA, OBJECT

KINDS = ("flat", "rolling", "mountain", "city", "forest", "breakline", "mixed")

#: Terrain of each kind: (scale in metres, relative amplitude) of the smooth random
#: components, and the 99th percentile of the terrain slope in degrees.
_TERRAIN = {
    "flat": (((600.0, 1.0), (150.0, 0.3)), 1.0),
    "rolling": (((800.0, 1.0), (250.0, 0.5), (80.0, 0.15)), 8.0),
    "mountain": (((1500.0, 1.0), (500.0, 0.6), (150.0, 0.3), (50.0, 0.08)), 33.0),
    "city": (((800.0, 1.0), (250.0, 0.5), (80.0, 0.15)), 5.0),
    "forest": (((1000.0, 1.0), (300.0, 0.6), (90.0, 0.2)), 18.0),
    "breakline": (((800.0, 1.0), (250.0, 0.4)), 3.0),
    "mixed": (((800.0, 1.0), (250.0, 0.5), (80.0, 0.15)), 8.0),
}
_ORIGIN = (500000.0, 5400000.0)
_EPSG = 32632


@dataclass
class Scene:
    """A synthetic scene and its truth.

    Attributes
    ----------
    dsm : ndarray of float32
        Surface model with noise, objects and low blunders; NaN at nodata holes.
    dtm : ndarray of float32
        True bare-earth terrain, finite everywhere (dams and cuts included).
    mask : ndarray of uint8
        True classes: 0 ground, 1 object, 2 low blunder, 255 nodata.
    cell_size : tuple of float
        ``(dx, dy)`` in metres.
    kind : str
        The scene kind (one of :data:`KINDS`).
    geotransform : tuple of 6 floats
        GDAL geotransform, north-up, origin at the upper-left corner.
    epsg : int
        EPSG code of the map coordinates (32632, UTM 32N).
    breaklines : list of ndarray
        ``(N, 2)`` arrays of map coordinates ``(x, y)`` inside the scene: the two crest
        edges and the two toes of the embankment, then the two bottom edges and the two
        top edges of the cut; empty without such features.
    objects : list of dict
        One dict per object: ``kind`` ("building", "tree", "bush", "car", "dam", "cut"),
        ``height`` (metres above the terrain; depth for a cut), ``bbox`` as
        ``(row0, col0, row1, col1)`` in cells (end exclusive), plus kind-specific keys
        (``roof`` of buildings; for dams and cuts ``ground=True``, ``centreline`` as
        ``(N, 2)`` map coordinates, widths and ``side_slope_deg``).
    """
    dsm: np.ndarray
    dtm: np.ndarray
    mask: np.ndarray
    cell_size: tuple
    kind: str
    geotransform: tuple
    epsg: int = _EPSG
    breaklines: list = field(default_factory=list)
    objects: list = field(default_factory=list)

    def cell_to_map(self, rows, cols):
        """Map coordinates ``(x, y)`` of cell centres ``(rows, cols)``."""
        gt = self.geotransform
        return (gt[0] + (np.asarray(cols) + 0.5) * gt[1],
                gt[3] + (np.asarray(rows) + 0.5) * gt[5])

    def map_to_cell(self, x, y):
        """Fractional ``(rows, cols)`` of map coordinates (cell centres at integers)."""
        gt = self.geotransform
        return ((np.asarray(y) - gt[3]) / gt[5] - 0.5, (np.asarray(x) - gt[0]) / gt[1] - 0.5)


def make_scene(kind="city", shape=(256, 256), cell_size=1.0, seed=0, noise_m=0.05,
               low_blunders=True, nodata_holes=False):
    """Build a synthetic scene with known truth.

    Parameters
    ----------
    kind : str
        ``"flat"``, ``"rolling"``, ``"mountain"`` (slopes up to about 35-40 degrees),
        ``"city"`` (rolling terrain, buildings 8-80 m wide, 4-40 m high with flat, gable
        and hip roofs, trees, cars), ``"forest"`` (forest patches and single trees, crowns
        5-30 m high), ``"breakline"`` (a 5-10 m road embankment with 30-40 degree sides
        and a flat crest, a cut, trees and bushes on the embankment, one building) or
        ``"mixed"`` (all of these in one scene).
    shape : tuple of int
        ``(rows, cols)``, at least 16 x 16.
    cell_size : float or (float, float)
        Cell size ``(dx, dy)`` in metres.
    seed : int
        Random seed; the same arguments give the same scene.
    noise_m : float
        Standard deviation of the Gaussian noise added to the DSM, metres (truncated at
        4.5 sigma).
    low_blunders : bool
        Add low outliers: single cells and 2 x 2 clusters 2-20 m below the surface.
    nodata_holes : bool
        Punch NaN blobs and a nodata strip along one border (mask 255).

    Returns
    -------
    Scene

    Raises
    ------
    ValueError
        For an unknown kind, a shape smaller than 16 x 16, a bad cell size or a negative
        noise.

    Examples
    --------
    >>> s = make_scene("city", (128, 128), seed=1)
    >>> s.dsm.shape, s.dsm.dtype, s.mask.dtype
    ((128, 128), dtype('float32'), dtype('uint8'))
    """
    if kind not in KINDS:
        raise ValueError(f"unknown scene kind {kind!r}; choose one of {', '.join(KINDS)}.")
    try:
        h, w = (int(v) for v in shape)
    except (TypeError, ValueError):
        raise ValueError(f"shape must be (rows, cols); got {shape!r}.") from None
    if h < 16 or w < 16:
        raise ValueError(f"shape {shape!r} is too small; use at least (16, 16) cells.")
    c = np.atleast_1d(np.asarray(cell_size, dtype=float)).ravel()
    if c.size == 1:
        c = np.array([c[0], c[0]])
    if c.size != 2 or not np.all(np.isfinite(c)) or np.any(c <= 0):
        raise ValueError(f"cell_size must be one or two positive numbers in metres; "
                         f"got {cell_size!r}.")
    dx, dy = float(c[0]), float(c[1])
    if not np.isfinite(noise_m) or noise_m < 0:
        raise ValueError(f"noise_m must be >= 0 metres; got {noise_m!r}.")

    ss = np.random.SeedSequence([int(seed), KINDS.index(kind)])
    r_terrain, r_feat, r_obj, r_noise, r_blund, r_nodata = (
        np.random.default_rng(s) for s in ss.spawn(6))
    b = _Builder((h, w), (dx, dy))

    scales, slope_deg = _TERRAIN[kind]
    b.terrain = _terrain(r_terrain, (h, w), (dx, dy), scales, slope_deg)

    if kind == "breakline":
        b.add_embankment(r_feat, centre_frac=0.3, with_cut=True)
        b.add_trees(r_obj, b.zone_embankment_slopes(), density=0.012, h_range=(5.0, 14.0))
        b.add_trees(r_obj, b.zone_embankment_slopes(), density=0.02, h_range=(1.2, 3.0),
                    kind="bush")
        b.add_buildings(r_obj, coverage=0.0, n_max=1, size_range=(12.0, 25.0))
    elif kind == "city":
        b.add_buildings(r_obj, coverage=0.22)
        b.add_trees(r_obj, None, density=0.0025, h_range=(5.0, 16.0))
        b.add_cars(r_obj, density=0.0012)
    elif kind == "forest":
        pf = _smooth_field(r_feat, (h, w), (dx, dy), ((120.0, 1.0),))
        patches = pf > np.percentile(pf[::4, ::4], 40.0)    # about 60 % forest
        b.add_trees(r_obj, patches, density=0.016, h_range=(8.0, 30.0))
        b.add_trees(r_obj, ~patches, density=0.0008, h_range=(5.0, 25.0))
        b.add_trees(r_obj, ~patches, density=0.001, h_range=(1.0, 3.0), kind="bush")
    elif kind == "mixed":
        zf = _smooth_field(r_feat, (h, w), (dx, dy), ((200.0, 1.0),))
        lo, hi = np.percentile(zf[::4, ::4], [35.0, 65.0])
        city, forest = zf < lo, zf > hi                     # the rest: open land
        b.add_embankment(r_feat, centre_frac=0.5, with_cut=False)
        b.add_buildings(r_obj, coverage=0.2, zone=city)
        b.add_cars(r_obj, density=0.001, zone=city)
        b.add_trees(r_obj, forest, density=0.016, h_range=(8.0, 30.0))
        b.add_trees(r_obj, ~city & ~forest, density=0.001, h_range=(4.0, 20.0))
        b.add_trees(r_obj, b.zone_embankment_slopes(), density=0.01, h_range=(1.2, 3.0),
                    kind="bush")
    # flat / rolling / mountain: bare terrain only

    return b.finish(kind, r_noise, r_blund, r_nodata, noise_m, low_blunders, nodata_holes)


def make_dsm(n_cells, seed=0, cell_size=1.0):
    """A square city scene of about ``n_cells`` cells, for speed benchmarks.

    Parameters
    ----------
    n_cells : int
        Approximate number of cells (the side is ``round(sqrt(n_cells))``, at least 16,
        so any ``n_cells >= 1`` is accepted).
    seed : int
        Random seed.
    cell_size : float
        Cell size in metres.

    Returns
    -------
    Scene
        A ``"city"`` scene with noise and low blunders, no nodata.

    Raises
    ------
    ValueError
        If ``n_cells`` is not a positive number.
    """
    if not np.isfinite(n_cells) or n_cells < 1:
        raise ValueError(f"n_cells must be a positive number of cells; got {n_cells!r}.")
    side = max(16, int(round(float(n_cells) ** 0.5)))
    return make_scene("city", (side, side), cell_size=cell_size, seed=seed)


def make_canopy(extent_m=512.0, cell_size=1.0, cover=0.85, seed=0, noise_m=0.05):
    """Closed canopy over gentle ground, the same landscape at any cell size.

    The failure case of data-derived defaults (issue 12): where crowns cover most of the
    DSM, statistics taken on the whole surface (noise, roughness) measure the canopy. The
    ground is a plane rising 4 % in x and 2 % in y with a 2 m undulation; crowns stand on
    a 7 m lattice jittered by up to 2 m, each present with probability ``cover``, radius
    3.5-5.5 m, height ``h`` of 12-25 m with a rounded top ``h (1 - 0.6 d^2)`` (``d`` the
    distance from the stem over the radius), so a crown's edge drops by ``0.4 h`` to the
    ground as in a real DSM. The scene is a continuous landscape sampled at the cell
    centres: the same ``seed`` at 0.5, 1, 2 and 4 m cells is the same forest.

    Parameters
    ----------
    extent_m : float
        Side of the square scene, metres.
    cell_size : float
        Cell size in metres (``extent_m / cell_size`` cells per side, at least 16).
    cover : float
        Probability that a lattice site holds a crown (0-1); 0.85 covers about 85 % of
        the ground.
    seed : int
    noise_m : float
        Standard deviation of the Gaussian height noise of the DSM.

    Returns
    -------
    Scene
        ``kind="canopy"``; mask 1 under crowns, 0 elsewhere; no low blunders or nodata.
    """
    n = int(round(float(extent_m) / float(cell_size)))
    if n < 16 or not np.isfinite(cell_size) or cell_size <= 0:
        raise ValueError(f"extent_m / cell_size must give at least 16 cells; got {extent_m!r} / "
                         f"{cell_size!r}.")
    if not 0.0 <= cover <= 1.0 or not np.isfinite(noise_m) or noise_m < 0:
        raise ValueError(f"cover must be in [0, 1] and noise_m >= 0; got {cover!r}, {noise_m!r}.")
    c = float(cell_size)
    rng = np.random.default_rng(int(seed))
    lat = 7.0
    m = int(np.ceil(extent_m / lat)) + 2
    jx, jy = rng.uniform(-2, 2, (m, m)), rng.uniform(-2, 2, (m, m))
    rad, hgt = rng.uniform(3.5, 5.5, (m, m)), rng.uniform(12, 25, (m, m))
    present = rng.random((m, m)) < cover
    x = (np.arange(n) + 0.5) * c
    X, Y = np.meshgrid(x, x[::-1])                   # north up: y decreases down the rows
    ground = 0.04 * X + 0.02 * Y + 2.0 * np.sin(X / 90.0) * np.cos(Y / 120.0) + 300.0
    top = np.zeros((n, n))
    ci, cj = np.floor(Y / lat).astype(int), np.floor(X / lat).astype(int)
    for di in (-1, 0, 1):                            # the 3 x 3 lattice sites around a cell
        for dj in (-1, 0, 1):
            i, j = np.clip(ci + di, 0, m - 1), np.clip(cj + dj, 0, m - 1)
            sx, sy = (j + 0.5) * lat + jx[i, j], (i + 0.5) * lat + jy[i, j]
            d2 = ((X - sx) ** 2 + (Y - sy) ** 2) / rad[i, j] ** 2
            crown = np.where(present[i, j] & (d2 < 1.0), hgt[i, j] * (1.0 - 0.6 * d2), 0.0)
            np.maximum(top, crown, out=top)
    noise = np.clip(rng.normal(0.0, 1.0, (n, n)), -4.5, 4.5) * noise_m
    dsm = (ground + top + noise).astype(np.float32)
    mask = np.where(top > 0, OBJECT, GROUND).astype(np.uint8)
    gt = (_ORIGIN[0], c, 0.0, _ORIGIN[1] + n * c, 0.0, -c)
    return Scene(dsm=dsm, dtm=ground.astype(np.float32), mask=mask, cell_size=(c, c), kind="canopy",
                 geotransform=gt)


# ---------------------------------------------------------------------------------------
# terrain


def _upsample_linear(c, shape, f):
    """Separable linear interpolation of coarse grid ``c`` (node spacing ``f`` cells per axis)."""
    out = c
    for axis, n in ((1, shape[1]), (0, shape[0])):  # columns on the small array first
        pos = (np.arange(n, dtype=np.float64) + 0.5) / f[axis]
        i0 = np.minimum(pos.astype(np.intp), out.shape[axis] - 2)
        t = (pos - i0).astype(np.float32)
        a = np.take(out, i0, axis=axis)
        bb = np.take(out, i0 + 1, axis=axis)
        t = t[:, None] if axis == 0 else t[None, :]
        bb -= a
        bb *= t
        a += bb
        out = a
    return out


def _smooth_field(rng, shape, cell, scales):
    """Sum of Gaussian-filtered white noise at several scales, zero mean, std about 1.

    ``scales`` are ``(sigma in metres, weight)``. Each component is made on its own
    coarse grid (4 nodes per sigma, filtered with sigma = 4 nodes) and all are linearly
    interpolated, so the cost is O(N) whatever the scales.
    """
    h, w = shape
    dx, dy = cell
    step = min(s for s, _ in scales) / 4.0                 # metres between nodes of acc
    sy, sx = max(step, dy), max(step, dx)
    ch, cw = int(np.ceil(h * dy / sy)) + 2, int(np.ceil(w * dx / sx)) + 2
    acc = np.zeros((ch, cw), dtype=np.float32)
    for sigma_m, weight in scales:
        gy, gx = max(sigma_m / 4.0, sy), max(sigma_m / 4.0, sx)  # this component's grid
        gh, gw = int(np.ceil(ch * sy / gy)) + 2, int(np.ceil(cw * sx / gx)) + 2
        sig = (sigma_m / gy, sigma_m / gx)
        py, px = int(3 * sig[0]) + 2, int(3 * sig[1]) + 2
        noise = rng.standard_normal((gh + 2 * py, gw + 2 * px))
        g = ndimage.gaussian_filter(noise, sig, mode="wrap")[py:py + gh, px:px + gw]
        g -= g.mean()
        g /= g.std() if g.std() > 0 else 1.0
        acc += np.float32(weight) * _upsample_linear(g.astype(np.float32), (ch, cw),
                                                     (gy / sy, gx / sx))
    acc /= np.float32(np.sqrt(sum(wt * wt for _, wt in scales)))
    return _upsample_linear(acc, (h, w), (sy / dy, sx / dx))


def _terrain(rng, shape, cell, scales, slope_deg):
    """Terrain heights (float32): a smooth field scaled to a slope percentile."""
    z = _smooth_field(rng, shape, cell, scales)
    dx, dy = cell
    gy, gx = np.gradient(z[::2, ::2], 2 * dy, 2 * dx) if min(shape) >= 8 else np.gradient(z)
    slope = np.hypot(gx, gy)
    p = float(np.percentile(slope, 99))
    scale = np.tan(np.radians(slope_deg)) / p if p > 0 else 1.0
    z *= np.float32(scale)
    z += np.float32(300.0 - float(z.mean()))
    return z


# ---------------------------------------------------------------------------------------
# scene builder


class _Builder:
    """Accumulates terrain edits and object surfaces of one scene."""

    def __init__(self, shape, cell):
        self.shape = shape
        self.dx, self.dy = cell
        self.terrain = None          # natural terrain (before dams and cuts)
        self.dtm = None              # set lazily: terrain with dams and cuts
        self.top = np.full(shape, -np.inf, dtype=np.float32)   # object surfaces
        self.occ = np.zeros(shape, dtype=bool)                  # building / road space
        self.objects = []
        self.breaklines = []
        self._emb = None             # (signed distance, crest half width, toe half width)

    # -- helpers -------------------------------------------------------------------------
    def ground(self):
        return self.terrain if self.dtm is None else self.dtm

    def _line_coords(self, centre, angle):
        """Along/across coordinates (metres) of every cell for a line through ``centre``."""
        h, w = self.shape
        x = ((np.arange(w, dtype=np.float32) + 0.5) * self.dx - centre[0])[None, :]
        y = ((np.arange(h, dtype=np.float32) + 0.5) * self.dy - centre[1])[:, None]
        ca, sa = np.float32(np.cos(angle)), np.float32(np.sin(angle))
        along = x * ca + y * sa
        across = y * ca - x * sa
        return along, across

    def _sample(self, z, xm, ym):
        """Bilinear sample of ``z`` at metric coordinates (x right, y down)."""
        rows = np.asarray(ym) / self.dy - 0.5
        cols = np.asarray(xm) / self.dx - 0.5
        return ndimage.map_coordinates(z, [rows, cols], order=1, mode="nearest")

    def _to_map(self, xm, ym):
        return np.column_stack([_ORIGIN[0] + np.asarray(xm), _ORIGIN[1] - np.asarray(ym)])

    def _add_line(self, xm, ym):
        """Append the part of a polyline (metric x right, y down) inside the scene."""
        xm, ym = np.asarray(xm), np.asarray(ym)
        ins = ((xm >= 0) & (xm <= self.shape[1] * self.dx)
               & (ym >= 0) & (ym <= self.shape[0] * self.dy))
        if ins.sum() >= 2:
            self.breaklines.append(self._to_map(xm[ins], ym[ins]))

    # -- terrain features ----------------------------------------------------------------
    def add_embankment(self, rng, centre_frac=0.3, with_cut=True):
        """A straight embankment (dam / road) across the scene, optionally a cut."""
        h, w = self.shape
        wm, hm = w * self.dx, h * self.dy
        z = self.ground().copy()
        # -- embankment: constant-grade crest 5-10 m above the terrain along the line
        angle = np.radians(rng.uniform(-10.0, 10.0))
        centre = (wm * rng.uniform(0.4, 0.6), hm * centre_frac)
        height = rng.uniform(7.0, 10.0)
        crest = rng.uniform(6.0, 14.0)                       # crest width, m
        side = np.radians(rng.uniform(30.0, 40.0))           # side slope
        tan_s = np.tan(side)
        half_len = 0.75 * np.hypot(wm, hm)
        s = np.linspace(-half_len, half_len, 400)
        ca, sa = np.cos(angle), np.sin(angle)
        pts = [(centre[0] + s * ca - o * sa, centre[1] + s * sa + o * ca)
               for o in np.linspace(-crest / 2, crest / 2, 5)]
        inside = [(px >= 0) & (px <= wm) & (py >= 0) & (py <= hm) for px, py in pts]
        tz = np.max([np.where(ins, self._sample(z, px, py), -np.inf)
                     for (px, py), ins in zip(pts, inside)], axis=0)
        ok = np.isfinite(tz)
        grade = np.polyfit(s[ok], tz[ok], 1)
        lift = height + max(0.0, float(np.max(tz[ok] - np.polyval(grade, s[ok]))))
        along, across = self._line_coords(centre, angle)
        top_z = np.float32(grade[1] + lift) + np.float32(grade[0]) * along
        emb = top_z - np.maximum(np.abs(across) - np.float32(crest / 2), 0) * np.float32(tan_s)
        raised = emb > z
        z = np.where(raised, emb, z)
        self._emb = (across, crest / 2, raised)
        self.occ |= raised
        rows, cols = np.nonzero(raised)
        self.objects.append(dict(kind="dam", height=float(lift), ground=True,
                                 crest_width_m=float(crest),
                                 side_slope_deg=float(np.degrees(side)),
                                 bbox=_bbox(rows, cols)))
        # break lines: crest edges, then toes, sampled along the line inside the scene
        keep = inside[2]
        sk = s[keep]
        self.objects[-1]["centreline"] = self._to_map(centre[0] + sk * ca, centre[1] + sk * sa)
        toes = []
        for sign in (-1.0, 1.0):
            o = sign * crest / 2
            self._add_line(centre[0] + sk * ca - o * sa, centre[1] + sk * sa + o * ca)
            # toe: where the side slope meets the terrain (fixed-point iterations)
            ez = np.polyval(grade, sk) + lift
            off = np.full(sk.shape, crest / 2 + height / tan_s)
            for _ in range(3):
                tx = centre[0] + sk * ca - sign * off * sa
                ty = centre[1] + sk * sa + sign * off * ca
                tt = self._sample(self.ground(), tx, ty)
                off = crest / 2 + np.maximum(ez - tt, 0.0) / tan_s
            toes.append((centre[0] + sk * ca - sign * off * sa,
                         centre[1] + sk * sa + sign * off * ca))
        for tx, ty in toes:
            self._add_line(tx, ty)

        if with_cut:
            # -- cut: a finite trench through the lower part of the scene
            angle = np.radians(rng.uniform(-10.0, 10.0))
            centre = (wm * rng.uniform(0.45, 0.55), hm * 0.78)
            depth = rng.uniform(4.0, 8.0)
            bottom = rng.uniform(6.0, 12.0)
            side = np.radians(rng.uniform(30.0, 40.0))
            tan_s = np.tan(side)
            half_len = 0.3 * wm
            ca, sa = np.cos(angle), np.sin(angle)
            s = np.linspace(-half_len, half_len, 200)
            tz = self._sample(z, centre[0] + s * ca, centre[1] + s * sa)
            grade = np.polyfit(s, tz, 1)
            drop = depth + max(0.0, float(np.max(np.polyval(grade, s) - tz)))
            along, across = self._line_coords(centre, angle)
            cl = np.clip(along, -half_len, half_len)
            dist = np.hypot(along - cl, across)             # distance to the segment
            bot_z = np.float32(grade[1] - drop) + np.float32(grade[0]) * cl
            cut = bot_z + np.maximum(dist - np.float32(bottom / 2), 0) * np.float32(tan_s)
            lowered = cut < z
            z_before_cut = z
            z = np.where(lowered, cut, z)
            self.occ |= lowered
            rows, cols = np.nonzero(lowered)
            self.objects.append(dict(kind="cut", height=float(drop), ground=True,
                                     bottom_width_m=float(bottom),
                                     side_slope_deg=float(np.degrees(side)),
                                     bbox=_bbox(rows, cols)))
            self.objects[-1]["centreline"] = self._to_map(centre[0] + s * ca,
                                                          centre[1] + s * sa)
            # bottom edges, then top edges (where the side slope meets the terrain)
            for o in (-bottom / 2, bottom / 2):
                self._add_line(centre[0] + s * ca - o * sa, centre[1] + s * sa + o * ca)
            ez = np.polyval(grade, s) - drop
            for sign in (-1.0, 1.0):
                off = np.full(s.shape, bottom / 2 + drop / tan_s)
                for _ in range(3):
                    tx = centre[0] + s * ca - sign * off * sa
                    ty = centre[1] + s * sa + sign * off * ca
                    tt = self._sample(z_before_cut, tx, ty)
                    off = bottom / 2 + np.maximum(tt - ez, 0.0) / tan_s
                self._add_line(centre[0] + s * ca - sign * off * sa,
                               centre[1] + s * sa + sign * off * ca)
        self.dtm = z.astype(np.float32, copy=False)

    def zone_embankment_slopes(self):
        """Cells on the embankment side slopes (not the crest)."""
        if self._emb is None:
            return np.zeros(self.shape, bool)
        across, half_crest, raised = self._emb
        return raised & (np.abs(across) > half_crest + 1.0)

    # -- objects -------------------------------------------------------------------------
    def add_buildings(self, rng, coverage=0.22, zone=None, n_max=None,
                      size_range=(8.0, 80.0)):
        """Buildings with flat, gable or hip roofs, written into array slices."""
        h, w = self.shape
        dx, dy = self.dx, self.dy
        g = self.ground()
        area = h * w * dx * dy
        mean_fp = 950.0  # mean footprint of the size distribution, m2
        if n_max is not None:
            n_target = int(n_max)
        else:  # at least one building in a small scene
            n_target = max(1, int(round(coverage * area / mean_fp))) if coverage > 0 else 0
        if zone is not None and zone.any():
            zr, zc = np.nonzero(zone[::4, ::4])
            zr, zc = zr * 4, zc * 4
        elif zone is not None:
            return
        else:
            zr = zc = None
        placed, tries = 0, 0
        lo, hi = size_range
        while placed < n_target and tries < 6 * n_target + 200:
            tries += 1
            # footprint: log-uniform length, width 0.4-1 of it
            length = float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
            width = max(lo, length * rng.uniform(0.4, 1.0))
            theta = rng.choice([0.0, np.pi / 2, rng.uniform(0, np.pi)], p=[0.4, 0.3, 0.3])
            if zr is not None:
                k = rng.integers(zr.size)
                cy, cx = (zr[k] + 0.5) * dy, (zc[k] + 0.5) * dx
            else:
                cy, cx = rng.uniform(0, h * dy), rng.uniform(0, w * dx)
            ext = 0.5 * (abs(length * np.cos(theta)) + abs(width * np.sin(theta)))
            eyt = 0.5 * (abs(length * np.sin(theta)) + abs(width * np.cos(theta)))
            r0 = int(np.floor((cy - eyt) / dy)) - 1
            r1 = int(np.ceil((cy + eyt) / dy)) + 1
            c0 = int(np.floor((cx - ext) / dx)) - 1
            c1 = int(np.ceil((cx + ext) / dx)) + 1
            if r0 < 0 or c0 < 0 or r1 > h or c1 > w:
                continue
            gap_r, gap_c = max(1, int(3 / dy)), max(1, int(3 / dx))
            if self.occ[max(0, r0 - gap_r):r1 + gap_r, max(0, c0 - gap_c):c1 + gap_c].any():
                continue
            yy = ((np.arange(r0, r1) + 0.5) * dy - cy)[:, None]
            xx = ((np.arange(c0, c1) + 0.5) * dx - cx)[None, :]
            u = xx * np.cos(theta) + yy * np.sin(theta)     # along the ridge
            v = -xx * np.sin(theta) + yy * np.cos(theta)    # across
            du = length / 2 - np.abs(u)
            dv = width / 2 - np.abs(v)
            foot = (du >= 0) & (dv >= 0)
            if foot.sum() < 2:
                continue
            base = float(g[r0:r1, c0:c1][foot].max())
            eave = float(np.clip(rng.uniform(4.0, 9.0) + rng.exponential(0.25 * width), 4, 40))
            if width > 30 or rng.random() < 0.35:
                roof = "flat"
                z = np.full(foot.shape, base + eave)
            else:
                roof = "gable" if rng.random() < 0.55 else "hip"
                pitch = np.tan(np.radians(rng.uniform(20.0, 40.0)))
                rise = dv if roof == "gable" else np.minimum(dv, du)
                z = base + eave + np.clip(rise, 0, None) * pitch
            sl = (slice(r0, r1), slice(c0, c1))
            self.top[sl] = np.where(foot, np.maximum(self.top[sl], z), self.top[sl])
            self.occ[sl] |= foot
            self.objects.append(dict(kind="building", roof=roof,
                                     height=float(z[foot].max() - base),
                                     bbox=(r0, c0, r1, c1)))
            placed += 1

    def add_trees(self, rng, zone, density, h_range, kind="tree"):
        """Trees (or bushes): crowns as noisy paraboloids, stamped vectorised.

        ``density`` is trees per square metre of ``zone`` (None: whole scene).
        """
        h, w = self.shape
        dx, dy = self.dx, self.dy
        if zone is None:
            n_zone = h * w
        else:
            n_zone = int(zone.sum())
        n = rng.poisson(density * n_zone * dx * dy)
        if n == 0 or n_zone == 0:
            return
        if zone is None:
            r = rng.integers(0, h, n)
            c = rng.integers(0, w, n)
        else:
            flat = np.flatnonzero(zone)
            pick = flat[rng.integers(0, flat.size, n)]
            r, c = np.divmod(pick, w)
        keep = ~self.occ[r, c] | self._slopes_ok(r, c)  # not on buildings, crests, cuts
        r, c = r[keep], c[keep]
        _, first = np.unique(r * w + c, return_index=True)  # one tree per cell
        r, c = r[first], c[first]
        n = r.size
        if n == 0:
            return
        hgt = rng.uniform(*h_range, n).astype(np.float32)
        if kind == "tree":
            rad = hgt * rng.uniform(0.15, 0.3, n).astype(np.float32)
            rad = np.maximum(rad, 1.5)
            b = rng.uniform(0.25, 0.5, n).astype(np.float32)      # crown base / height
        else:
            rad = np.maximum(hgt * rng.uniform(0.6, 1.0, n).astype(np.float32), 0.6)
            b = rng.uniform(0.3, 0.6, n).astype(np.float32)
        base = self.ground()[r, c]
        gflat = self.ground().ravel()
        tf = self.top.ravel()
        # stamp in radius classes so each class loops over a small set of offsets
        rcell = np.ceil(rad / min(dx, dy)).astype(int)
        for rc in np.unique(rcell):
            sel = np.flatnonzero(rcell == rc)
            oy, ox = np.mgrid[-rc:rc + 1, -rc:rc + 1]
            dist2 = ((oy * dy) ** 2 + (ox * dx) ** 2).ravel().astype(np.float32)
            for k in range(dist2.size):
                q = dist2[k] / (rad[sel] ** 2)
                on = q <= 1.0
                if not on.any():
                    continue
                s = sel[on]
                rr = r[s] + oy.ravel()[k]
                cc = c[s] + ox.ravel()[k]
                inb = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
                s, rr, cc, q = s[inb], rr[inb], cc[inb], q[on][inb]
                zc = base[s] + hgt[s] * (1.0 - (1.0 - b[s]) * q)
                zc += hgt[s] * np.float32(0.04) * rng.standard_normal(s.size).astype(np.float32)
                idx = rr * w + cc
                # parts of a crown less than 1 m above the local ground are not objects
                up = zc >= gflat[idx] + np.float32(1.0)
                idx, zc = idx[up], zc[up]
                tf[idx] = np.maximum(tf[idx], zc)
        r0 = np.maximum(r - rcell, 0)
        c0 = np.maximum(c - rcell, 0)
        r1 = np.minimum(r + rcell + 1, h)
        c1 = np.minimum(c + rcell + 1, w)
        self.objects.extend(dict(kind=kind, height=hh, bbox=(a, bb, cc_, d))
                            for hh, a, bb, cc_, d in zip(hgt.tolist(), r0.tolist(),
                                                         c0.tolist(), r1.tolist(), c1.tolist()))

    def _slopes_ok(self, r, c):
        """Trees may stand on embankment slopes (which are ground, part of ``occ``)."""
        if self._emb is None:
            return np.zeros(r.shape, bool)
        return self.zone_embankment_slopes()[r, c]

    def add_cars(self, rng, density, zone=None):
        """Cars: 1.8 x 4.5 m boxes, 1.5 m high, on free ground (axis-aligned)."""
        h, w = self.shape
        dx, dy = self.dx, self.dy
        if max(dx, dy) > 2.0:
            return  # smaller than a cell
        n = rng.poisson(density * h * w * dx * dy)
        if n == 0:
            return
        r = rng.integers(0, h, n)
        c = rng.integers(0, w, n)
        ok = ~self.occ[r, c]
        if zone is not None:
            ok &= zone[r, c]
        r, c = r[ok], c[ok]
        _, first = np.unique(r * w + c, return_index=True)
        r, c = r[first], c[first]
        if r.size == 0:
            return
        along_x = rng.random(r.size) < 0.5
        hgt = rng.uniform(1.4, 1.7, r.size).astype(np.float32)
        base = self.ground()[r, c]
        gflat = self.ground().ravel()
        tf = self.top.ravel()
        for ax in (True, False):
            sel = along_x == ax
            lx, ly = (4.5, 1.8) if ax else (1.8, 4.5)
            nx, ny = max(1, int(round(lx / dx))), max(1, int(round(ly / dy)))
            for oy in range(ny):
                for ox in range(nx):
                    rr = r[sel] + oy - ny // 2
                    cc = c[sel] + ox - nx // 2
                    inb = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
                    rr, cc = rr[inb], cc[inb]
                    zc = base[sel][inb] + hgt[sel][inb]
                    idx = rr * w + cc
                    up = zc >= gflat[idx] + np.float32(1.0)  # >= 1 m above local ground
                    idx, zc = idx[up], zc[up]
                    tf[idx] = np.maximum(tf[idx], zc)
            rs, cs = r[sel] - ny // 2, c[sel] - nx // 2       # upper-left cell
            self.objects.extend(
                dict(kind="car", height=hh, bbox=(max(a, 0), max(b, 0),
                                                  min(a + ny, h), min(b + nx, w)))
                for hh, a, b in zip(hgt[sel].tolist(), rs.tolist(), cs.tolist()))

    # -- final assembly ------------------------------------------------------------------
    def finish(self, kind, r_noise, r_blund, r_nodata, noise_m, low_blunders, nodata_holes):
        h, w = self.shape
        dtm = self.ground().astype(np.float32, copy=False)
        obj = self.top > dtm
        dsm = np.where(obj, self.top, dtm)
        mask = np.where(obj, np.uint8(OBJECT), np.uint8(GROUND))
        if noise_m > 0:
            e = r_noise.standard_normal((h, w), dtype=np.float32)
            np.clip(e, -4.5, 4.5, out=e)
            e *= np.float32(noise_m)
            dsm += e
        if low_blunders:
            n = max(1, int(round(h * w / 4000)))
            r = r_blund.integers(0, h - 1, n)
            c = r_blund.integers(0, w - 1, n)
            big = r_blund.random(n) < 0.3                  # 2 x 2 clusters
            depth = r_blund.uniform(2.0, 20.0, n).astype(np.float32)
            for dr, dc, use in ((0, 0, np.ones(n, bool)), (0, 1, big), (1, 0, big), (1, 1, big)):
                rr, cc = r[use] + dr, c[use] + dc
                dsm[rr, cc] = np.minimum(dsm[rr, cc], dtm[rr, cc]) - depth[use]
                mask[rr, cc] = LOW
        if nodata_holes:
            nod = self._nodata(r_nodata)
            dsm[nod] = np.nan
            mask[nod] = NODATA
        gt = (_ORIGIN[0], self.dx, 0.0, _ORIGIN[1], 0.0, -self.dy)
        return Scene(dsm=dsm.astype(np.float32, copy=False), dtm=dtm, mask=mask,
                     cell_size=(self.dx, self.dy), kind=kind, geotransform=gt, epsg=_EPSG,
                     breaklines=self.breaklines, objects=self.objects)

    def _nodata(self, rng):
        """NaN blobs (about 3 % of the cells) and a strip along one border."""
        h, w = self.shape
        field_ = _smooth_field(rng, (h, w), (self.dx, self.dy), ((15.0 * max(self.dx, self.dy), 1.0),))
        nod = field_ > np.percentile(field_[::4, ::4], 97.0)
        side = rng.integers(4)
        width = max(2, int(min(h, w) * rng.uniform(0.02, 0.05)))
        wobble = (np.sin(np.arange(max(h, w)) / 7.0) * width / 3).astype(int)
        if side in (0, 1):
            wcol = width + wobble[:h]
            cols = np.arange(w)[None, :]
            strip = cols < wcol[:, None] if side == 0 else cols >= (w - wcol)[:, None]
        else:
            wrow = width + wobble[:w]
            rows = np.arange(h)[:, None]
            strip = rows < wrow[None, :] if side == 2 else rows >= (h - wrow)[None, :]
        return nod | strip


def _bbox(rows, cols):
    if rows.size == 0:
        return (0, 0, 0, 0)
    return (int(rows.min()), int(cols.min()), int(rows.max()) + 1, int(cols.max()) + 1)


def _benchmark(n=4000):
    """Print the build time of ``n`` x ``n`` scenes (``python -m bare_earth.core.synthetic``)."""
    import time
    for kind in KINDS:
        t, c = time.perf_counter(), time.process_time()
        s = make_scene(kind, (n, n), nodata_holes=True)
        dt, dc = time.perf_counter() - t, time.process_time() - c
        frac = {name: float(np.mean(s.mask == code)) for code, name in
                ((GROUND, "ground"), (OBJECT, "object"), (LOW, "low"), (NODATA, "nodata"))}
        print(f"{kind:9s} {n} x {n}: wall {dt:.2f} s, cpu {dc:.2f} s, "
              f"{len(s.objects)} objects, " + ", ".join(f"{k} {v:.4f}" for k, v in frac.items()))


if __name__ == "__main__":
    import sys
    _benchmark(int(sys.argv[1]) if len(sys.argv) > 1 else 4000)
