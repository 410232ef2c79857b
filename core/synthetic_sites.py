"""Synthetic sites like the held-out ISPRS samples (issue 13), sampled as point rasters.

:mod:`.synthetic` builds scenes on the output grid. The held-out ISPRS samples differ from
them in their sites (a steep town hillside with retaining walls, a railway station full of
trains, a quarry with benches and cliffs, steep slopes under dense low vegetation, a bridge with
ramps among large buildings and data gaps) and in how a point raster is made: points, about one
per square metre, the lowest (a lidar DSM) or the highest (an image-matching DSM, the top of every
object) point kept per cell, empty cells taken from the nearest cell, as ``benchmarks/generalise.py``
rasterises the ISPRS samples. :func:`make_site` builds each site on a fine grid (:data:`FINE_M`),
draws the points (seeded), and keeps per cell the chosen point's truth:

* ``mask``: object where the chosen point is an object return (an object surface at least
  :data:`MIN_OBJECT_M` above the ground under it), else ground; the cells without a point take the
  nearest cell's point as their value and truth. Retaining walls, platforms with their ramps, quarry
  benches and cliffs, gravel piles, embankments, dikes, road cuts and terrain steps are ground; buildings, trains,
  platform roofs, bridge decks, trees, shrubs, hedges, sheds and trucks are objects.
* ``dtm``: the mean of the fine ground over the cell (finite everywhere).
* ``dsm``: the chosen point's height with Gaussian noise (``noise_m``, truncated at 4.5 sigma).

``surface="lowest"``: a pulse passes a tree crown to the ground with probability
:data:`PASS_TREE`, a shrub with :data:`PASS_SHRUB` (the last return), and the lowest point of a cell
is kept, so the ground shows between crowns. ``surface="highest"``: no pulse passes vegetation
(the first return) and the highest point is kept, so objects cover every cell they touch.
"""
import numpy as np
from scipy import ndimage

from .codes import GROUND, OBJECT
from .synthetic import Scene

#: The sites :func:`make_site` builds.
SITES = ("hillside", "railway", "quarry", "shrubs", "bridge", "city", "embankment", "steps", "courtyard",
         "sparse")
#: Side of each site's square, metres, when ``make_site`` is not given one (the city's halls are up to
#: 250 m long: it needs room for them and the streets around).
EXTENT_M = {"hillside": 320.0, "railway": 320.0, "quarry": 320.0, "shrubs": 320.0, "bridge": 320.0,
            "city": 480.0, "embankment": 320.0, "steps": 320.0, "courtyard": 320.0, "sparse": 320.0}
#: Points per square metre of the sites whose data are sparser than the urban samples' (about 1 per m2):
#: ``sparse`` is ISPRS 54's low resolution, a point every 2-3 m (Sithole & Vosselman 2003, sites 5-8).
DENSITY_PER_M2 = {"sparse": 0.16}
#: Fine grid of the site's surfaces, metres (points take the value of their fine cell).
FINE_M = 0.5
#: Object surfaces lower than this above the ground under them are ground returns, metres.
MIN_OBJECT_M = 0.5
#: Probability that a pulse through a tree crown / a shrub reaches the ground (lowest surface).
PASS_TREE = 0.35
PASS_SHRUB = 0.15
_ORIGIN_XY = (510000.0, 5410000.0)
_EPSG = 32632


def make_site(kind, cell_size=1.0, surface="lowest", extent_m=None, seed=0, noise_m=0.05,
              density_per_m2=None):
    """Build a site with known truth rasterised from points like the ISPRS samples.

    Parameters
    ----------
    kind : str
        ``"hillside"`` (a 25-35 degree slope cut into terraces by 2-4.5 m retaining walls, rows
        of houses on the terraces, hedges along the walls, trees on the slopes: ISPRS 11 and 12),
        ``"railway"`` (8-14 parallel tracks 4.5-7 m apart with trains 3.6-4.2 m high, 3 m wide,
        50-200 m long, coupler gaps; platforms 1 m high with ramps at their ends under roofs;
        a station hall: ISPRS 42), ``"quarry"`` (a pit of 3-5 benches 5-15 m high and 8-20 m
        wide, merged into one cliff on a sector, gravel piles on the floor, sheds, trucks, trees
        on the rim: ISPRS 53), ``"shrubs"`` (a 28-38 degree slope with a gully and a road cut
        into it, shrubs 0.6-2 m high covering about half of it, scattered trees: ISPRS 52) or
        ``"bridge"`` (a road bridge with a 6-8 m deck over a road, one ramp between retaining
        walls and one on banks, a garage ramp cut 3 m down, large L-shaped buildings with roof
        structures, data gaps, trees and cars: ISPRS 21-24), ``"city"`` (halls up to 250 m long, a
        courtyard block, a ramp down to a car park, data gaps on dark roofs: ISPRS 22-24),
        ``"embankment"`` (a road on an embankment 3-6 m high with 1:1.5-1:2 sides ramping down to the
        ground, a dike, a road cut, shrubs and trees on their sides, houses and cars: ISPRS 24),
        ``"steps"`` (terrain discontinuities: 4-6 steps of 2-10 m with 60-85 degree faces across a
        gentle slope, one fading out along its length, trees and shrubs along their edges, few
        buildings: ISPRS 53), ``"courtyard"`` (blocks of large buildings 10-25 m high enclosing
        courtyards of 12-35 m, some closed, some opening to the street, trees in them, data gaps on
        roofs and in a courtyard: ISPRS 23) or ``"sparse"`` (dense houses on a slope with trees and
        data gaps, a point every 2.5 m: :data:`DENSITY_PER_M2`, ISPRS 54).
    cell_size : float
        Output cell size in metres, a multiple of :data:`FINE_M` dividing ``extent_m``.
    surface : str
        ``"lowest"`` (lidar: lowest point per cell, pulses through vegetation) or ``"highest"``
        (the highest point per cell, vegetation opaque).
    extent_m : float, optional
        Side of the square site, metres; default the site's :data:`EXTENT_M`.
    seed : int
        Random seed; the same arguments give the same site (the fine site does not depend on
        ``cell_size`` or ``surface``).
    noise_m : float
        Standard deviation of the points' height noise, metres.
    density_per_m2 : float, optional
        Points per square metre; default the site's :data:`DENSITY_PER_M2`, else 1.2 (the ISPRS
        urban samples: about 1).

    Returns
    -------
    Scene
        With ``kind`` the site's name and ``objects`` empty.

    Raises
    ------
    ValueError
        For an unknown kind or surface, or a cell size that does not tile the site.
    """
    if kind not in SITES:
        raise ValueError(f"unknown site {kind!r}; choose one of {', '.join(SITES)}.")
    if surface not in ("lowest", "highest"):
        raise ValueError(f"surface must be 'lowest' or 'highest'; got {surface!r}.")
    if extent_m is None:
        extent_m = EXTENT_M[kind]
    k = float(cell_size) / FINE_M
    n = float(extent_m) / FINE_M
    if k < 1 or abs(k - round(k)) > 1e-9 or abs(n - round(n)) > 1e-9 or round(n) % round(k):
        raise ValueError(f"cell_size {cell_size!r} must be a multiple of {FINE_M} m dividing "
                         f"extent_m {extent_m!r}.")
    if density_per_m2 is None:
        density_per_m2 = DENSITY_PER_M2.get(kind, 1.2)
    if not np.isfinite(noise_m) or noise_m < 0 or not density_per_m2 > 0:
        raise ValueError("noise_m must be >= 0 and density_per_m2 > 0.")
    k, n = int(round(k)), int(round(n))
    ss = np.random.SeedSequence([int(seed), SITES.index(kind)])
    r_site, r_points = (np.random.default_rng(s) for s in ss.spawn(2))
    site = _Site(n, float(extent_m))
    _BUILD[kind](site, r_site)
    return site.rasterise(r_points, k, surface, noise_m, density_per_m2, kind)


# ----------------------------------------------------------------------------------- the site
class _Site:
    """Fine-grid ground, object tops, pass probabilities and data gaps of one site."""

    def __init__(self, n, extent):
        self.n, self.e = n, extent
        self.x = ((np.arange(n) + 0.5) * FINE_M).astype(np.float32)
        self.X, self.Y = self.x[None, :], self.x[:, None]
        self.ground = None
        self.top = np.full((n, n), -np.inf, np.float32)
        self.passing = np.zeros((n, n), np.float32)
        self.gap = np.zeros((n, n), bool)

    def window(self, cx, cy, reach):
        """Slices of the fine cells within ``reach`` metres of ``(cx, cy)``, and their x, y."""
        c0, c1 = max(int((cx - reach) / FINE_M), 0), min(int((cx + reach) / FINE_M) + 1, self.n)
        r0, r1 = max(int((cy - reach) / FINE_M), 0), min(int((cy + reach) / FINE_M) + 1, self.n)
        if c0 >= c1 or r0 >= r1:
            return None
        return (slice(r0, r1), slice(c0, c1)), self.x[c0:c1][None, :], self.x[r0:r1][:, None]

    def put(self, sl, where, z, passing=0.0):
        """Raise the object tops to ``z`` where ``where`` and ``z`` stands high enough."""
        where = where & (z >= self.ground[sl] + np.float32(MIN_OBJECT_M))
        t = self.top[sl]
        up = where & (z > t)
        t[up] = np.broadcast_to(z, up.shape)[up]
        self.passing[sl][up] = passing

    def box(self, cx, cy, ang, length, width, height, base=None, passing=0.0, roof=None):
        """A rotated box (``length`` along ``ang``); ``base`` None: on the ground under each cell.
        ``roof(u, v)`` adds a roof shape (metres) to the flat top."""
        w = self.window(cx, cy, 0.5 * np.hypot(length, width) + 1.0)
        if w is None:
            return
        sl, x, y = w
        ca, sa = np.float32(np.cos(ang)), np.float32(np.sin(ang))
        u = (x - cx) * ca + (y - cy) * sa
        v = (y - cy) * ca - (x - cx) * sa
        foot = (np.abs(u) <= length / 2) & (np.abs(v) <= width / 2)
        z = (self.ground[sl] if base is None else np.float32(base)) + np.float32(height)
        if roof is not None:
            z = z + roof(u, v).astype(np.float32)
        self.put(sl, foot, np.broadcast_to(z, foot.shape), passing)

    def plant(self, rng, cx, cy, heights, radii, passing, follow=False):
        """Crowns (paraboloids with rough tops) at ``(cx, cy)``; ``follow``: shrubs whose
        height is above the ground under each cell, else crowns level from their stem's foot."""
        for x0, y0, h, r in zip(cx, cy, heights, radii):
            w = self.window(x0, y0, r)
            if w is None:
                continue
            sl, x, y = w
            q = ((x - x0) ** 2 + (y - y0) ** 2) / np.float32(r * r)
            b = rng.uniform(0.3, 0.6)
            g = self.ground[sl]
            foot = g if follow else self.ground[min(int(y0 / FINE_M), self.n - 1),
                                                 min(int(x0 / FINE_M), self.n - 1)]
            z = foot + np.float32(h) * (1 - np.float32(1 - b) * q)
            z = z + np.float32(0.05 * h) * rng.standard_normal(q.shape).astype(np.float32)
            self.put(sl, q <= 1, z, passing)

    def scatter(self, rng, density, keep=None):
        """Poisson points (x, y) over the site, ``keep(x, y)`` selecting where."""
        m = rng.poisson(density * self.e * self.e)
        x, y = rng.uniform(0, self.e, m), rng.uniform(0, self.e, m)
        if keep is not None:
            ok = keep(x, y)
            x, y = x[ok], y[ok]
        return x, y

    def at(self, a, x, y):
        """Values of fine array ``a`` at points (x, y)."""
        i = np.clip((np.asarray(y) / FINE_M).astype(int), 0, self.n - 1)
        j = np.clip((np.asarray(x) / FINE_M).astype(int), 0, self.n - 1)
        return a[i, j]

    def rasterise(self, rng, k, surface, noise_m, density, kind):
        """Points drawn on the fine cells, the lowest / highest kept per ``k`` x ``k`` block."""
        n, m = self.n, self.n // k
        hit = (rng.random((n, n)) < density * FINE_M * FINE_M) & ~self.gap
        through = rng.random((n, n)) < self.passing
        obj = np.isfinite(self.top)
        if surface == "lowest":
            obj &= ~through
        z = np.where(obj, self.top, self.ground)
        e = rng.standard_normal((n, n)).astype(np.float32)
        np.clip(e, -4.5, 4.5, out=e)
        z += np.float32(noise_m) * e

        def blocks(a):
            return a.reshape(m, k, m, k).transpose(0, 2, 1, 3).reshape(m, m, k * k)
        zb = blocks(np.where(hit, z, np.inf if surface == "lowest" else -np.inf))
        pick = (np.argmin if surface == "lowest" else np.argmax)(zb, axis=2)[..., None]
        val = np.take_along_axis(zb, pick, 2)[..., 0]
        lab = np.take_along_axis(blocks(obj), pick, 2)[..., 0]
        empty = ~blocks(hit).any(axis=2)
        if empty.any():
            ii, jj = ndimage.distance_transform_edt(empty, return_distances=False, return_indices=True)
            val, lab = val[ii, jj], lab[ii, jj]
        dtm = self.ground.reshape(m, k, m, k).mean(axis=(1, 3), dtype=np.float64).astype(np.float32)
        cell = k * FINE_M
        gt = (_ORIGIN_XY[0], cell, 0.0, _ORIGIN_XY[1], 0.0, -cell)
        return Scene(dsm=val.astype(np.float32), dtm=dtm,
                     mask=np.where(lab, np.uint8(OBJECT), np.uint8(GROUND)),
                     cell_size=(cell, cell), kind=kind, geotransform=gt, epsg=_EPSG)


def _waves(rng, scale, amp, count=6):
    """A smooth random field f(x, y) (a sum of plane waves about ``scale`` metres long, standard
    deviation about ``amp``), evaluable anywhere."""
    th = rng.uniform(0, np.pi, count)
    lam = scale * rng.uniform(0.6, 1.6, count)
    ph = rng.uniform(0, 2 * np.pi, count)
    a = np.float32(amp * np.sqrt(2.0 / count))

    def f(x, y):
        out = 0
        for t, la, p in zip(th, lam, ph):
            out = out + np.sin((x * np.cos(t) + y * np.sin(t)) * (2 * np.pi / la) + p).astype(np.float32)
        return a * out
    return f


def _trees(site, rng, density, h_range, keep=None, shrub=False):
    x, y = site.scatter(rng, density, keep)
    h = rng.uniform(*h_range, x.size)
    if shrub:
        r = np.maximum(h * rng.uniform(0.6, 1.2, x.size), 0.8)
        site.plant(rng, x, y, h, r, PASS_SHRUB, follow=True)
    else:
        r = np.clip(h * rng.uniform(0.2, 0.35, x.size), 1.5, 6.0)
        site.plant(rng, x, y, h, r, PASS_TREE)


def _trees_and_cars(site, rng, free, tree_density, car_density):
    """Trees 5-16 m high and cars (4.5 x 1.8 m, 1.4-1.7 m high) on the cells ``free`` with no top yet."""
    def open_ground(x, y):
        return site.at(free, x, y) & ~np.isfinite(site.at(site.top, x, y))
    _trees(site, rng, tree_density, (5.0, 16.0), open_ground)
    x, y = site.scatter(rng, car_density, open_ground)
    for cx, cy in zip(x, y):
        site.box(cx, cy, rng.choice([0.0, np.pi / 2]), 4.5, 1.8, rng.uniform(1.4, 1.7))


def _gable(pitch, width):
    return lambda u, v: np.clip(width / 2 - np.abs(v), 0, None) * pitch


# ----------------------------------------------------------------------------------- sites
def _hillside(s, rng):
    e = s.e
    a = rng.uniform(-0.25, 0.25)
    ts = np.tan(np.radians(rng.uniform(25.0, 35.0)))
    sa, ca = np.float32(np.sin(a)), np.float32(np.cos(a))
    u = (s.X - e / 2) * sa + (e - s.Y) * ca          # uphill
    v = (s.X - e / 2) * ca + (s.Y - e) * sa          # along the contours
    starts, ls, ws, ps, z0 = [], [], [], [], []
    pos, z = float(u.min()) - 5.0, 0.0
    while pos < float(u.max()):
        lb, wb, pb = rng.uniform(8.0, 16.0), rng.uniform(2.0, 4.5), rng.uniform(9.0, 14.0)
        starts.append(pos), ls.append(lb), ws.append(wb), ps.append(pb), z0.append(z)
        pos, z = pos + lb + pb, z + ts * lb + wb
    starts, ls, ws, ps, z0 = (np.asarray(t, np.float32) for t in (starts, ls, ws, ps, z0))
    b = np.searchsorted(starts, u, side="right") - 1
    t = u - starts[b]
    g = z0[b] + np.float32(ts) * np.minimum(t, ls[b]) + np.where(t > ls[b], ws[b], 0)
    s.ground = (200 + g + _waves(rng, 60.0, 0.8)(s.X, s.Y)).astype(np.float32)
    # houses against the back of each terrace (ridges along the contours), gaps 0-8 m
    vmin, vmax = float(v.min()), float(v.max())
    for i in range(starts.size):
        level = 200 + z0[i] + ts * ls[i] + ws[i]
        depth_max = min(9.0, ps[i] - 2.0)
        vc = vmin + rng.uniform(0, 8)
        while vc < vmax:
            width, depth = rng.uniform(7.0, 14.0), rng.uniform(6.0, depth_max)
            if rng.random() > 0.2:
                uc = starts[i] + ls[i] + ps[i] - depth / 2 - rng.uniform(0.0, 1.0)
                vm = vc + width / 2
                cx, cy = e / 2 + uc * sa + vm * ca, e - uc * ca + vm * sa
                roof = None if rng.random() < 0.3 else _gable(np.tan(np.radians(rng.uniform(25, 40))), depth)
                s.box(cx, cy, a, width, depth, rng.uniform(5.0, 8.0), base=level, roof=roof)
            vc += width + (0.0 if rng.random() < 0.3 else rng.uniform(2.0, 8.0))
        if rng.random() < 0.5:   # a hedge along the top of the wall
            for _ in range(3):
                vm, ln = rng.uniform(vmin, vmax), rng.uniform(10.0, 30.0)
                uc = starts[i] + ls[i] + 0.8
                cx, cy = e / 2 + uc * sa + vm * ca, e - uc * ca + vm * sa
                s.box(cx, cy, a, ln, 1.2, rng.uniform(1.2, 2.0), passing=PASS_SHRUB)

    def on_slope(x, y):
        ub = (x - e / 2) * sa + (e - y) * ca
        bb = np.searchsorted(starts, ub, side="right") - 1
        tb = ub - starts[bb]
        return (tb < ls[bb] - 1.0) & ~np.isfinite(s.at(s.top, x, y))
    _trees(s, rng, 0.006, (5.0, 15.0), on_slope)


def _railway(s, rng):
    e = s.e
    s.ground = (100 + 0.005 * s.X + _waves(rng, 150.0, 0.5)(s.X, s.Y)).astype(np.float32)
    a = rng.uniform(-0.15, 0.15)
    sa, ca = np.float32(np.sin(a)), np.float32(np.cos(a))
    al = (s.X - e / 2) * ca + (s.Y - e / 2) * sa
    ac = (s.Y - e / 2) * ca - (s.X - e / 2) * sa

    def xy(along, across):
        return e / 2 + along * ca - across * sa, e / 2 + along * sa + across * ca
    pos, tracks, platforms = -0.3 * e, [], []
    for i in range(int(rng.integers(8, 15))):
        tracks.append(pos)
        pos += rng.uniform(4.5, 7.0)
        if i % 3 == 1 and rng.random() < 0.8:       # a platform between two tracks
            w = rng.uniform(6.0, 10.0)
            platforms.append((pos - 1.5 + w / 2, w))
            pos += w
    for pc, w in platforms:                         # 1 m high, ramps of 10 m at both ends
        ln = rng.uniform(150.0, 250.0)
        lift = np.float32(rng.uniform(0.9, 1.1)) * np.clip((ln / 2 + 10 - np.abs(al)) / 10, 0, 1)
        s.ground = s.ground + np.where(np.abs(ac - pc) <= w / 2, lift, 0).astype(np.float32)
    for pc, w in platforms:                         # roofs 4.5-5.5 m over the platforms
        cx, cy = xy(rng.uniform(-30, 30), pc)
        s.box(cx, cy, a, rng.uniform(60.0, 150.0), w - 1.5, rng.uniform(4.5, 5.5))
    for tc in tracks:                               # trains of coaches with coupler gaps
        along = -0.7 * e + rng.uniform(0, 40)
        while along < 0.7 * e:
            ln = rng.uniform(50.0, 200.0)
            if rng.random() < 0.75:
                h = rng.uniform(3.6, 4.2)
                coach = rng.uniform(20.0, 26.0)
                nc = max(1, int(ln // coach))
                for c in range(nc):
                    cx, cy = xy(along + (c + 0.5) * coach, tc)
                    s.box(cx, cy, a, coach - 1.0, 3.0, h)
                    gx, gy = xy(along + (c + 1) * coach - 0.5, tc)
                    s.box(gx, gy, a, 1.0, 2.0, 1.2)
                ln = nc * coach
            along += ln + rng.uniform(5.0, 60.0)
    side = pos + rng.uniform(15.0, 25.0)           # the station hall beyond the last track
    dh = rng.uniform(20.0, 30.0)
    cx, cy = xy(rng.uniform(-40, 40), side + dh / 2)
    s.box(cx, cy, a, rng.uniform(100.0, 160.0), dh, rng.uniform(12.0, 16.0),
          base=float(s.at(s.ground, cx, cy)) + 0.5)
    top0 = tracks[0]

    def outside(x, y):
        acx = (y - e / 2) * ca - (x - e / 2) * sa
        return (acx < top0 - 6) | (acx > side + dh + 5)
    _trees(s, rng, 0.004, (6.0, 16.0), outside)


def _quarry(s, rng):
    e = s.e
    g0 = 100 + 0.03 * s.X + _waves(rng, 120.0, 1.5)(s.X, s.Y)
    cx, cy = e / 2 + rng.uniform(-20, 20), e / 2 + rng.uniform(-20, 20)
    th = np.arctan2(s.Y - cy, s.X - cx)
    p1, p2, tc = rng.uniform(0, 2 * np.pi, 3)
    rho = np.hypot(s.X - cx, s.Y - cy) / (1 + 0.12 * np.sin(2 * th + p1) + 0.08 * np.sin(3 * th + p2))
    r0 = rng.uniform(0.33, 0.4) * e
    off = np.abs(np.angle(np.exp(1j * (th - tc))))          # angle from the cliff's centre
    wid = np.clip((np.degrees(off) - 25.0) / 20.0, 0.08, 1.0).astype(np.float32)
    depth = np.zeros_like(rho, dtype=np.float32)
    edge, total = np.float32(r0), 0.0
    for _ in range(int(rng.integers(3, 6))):
        d, bw = rng.uniform(5.0, 15.0), rng.uniform(8.0, 20.0)
        face = d / np.tan(np.radians(rng.uniform(75.0, 85.0)))
        depth += np.float32(d) * np.clip((edge - rho) / face, 0, 1)
        edge = edge - wid * np.float32(bw)
        total += d
    rim = float(np.median(g0[np.abs(rho - r0) < 2]))
    floor = rim - total
    pit = rim - depth + 0.2 * _waves(rng, 40.0, 1.0)(s.X, s.Y)
    g = np.where(depth > 0, np.minimum(g0, pit), g0)
    floor_cells = np.flatnonzero((depth >= total - 0.01).ravel()[::97])
    for _ in range(3):                                     # gravel piles (ground), 35 degree sides
        if floor_cells.size == 0:
            break
        i = floor_cells[rng.integers(floor_cells.size)] * 97
        px, py = s.x[i % s.n], s.x[i // s.n]
        h = rng.uniform(4.0, 8.0)
        g = np.maximum(g, floor + h - np.hypot(s.X - px, s.Y - py) * np.tan(np.radians(35)))
    s.ground = g.astype(np.float32)
    for _ in range(4):                                     # trucks on the floor
        if floor_cells.size == 0:
            break
        i = floor_cells[rng.integers(floor_cells.size)] * 97
        s.box(s.x[i % s.n], s.x[i // s.n], rng.uniform(0, np.pi), 9.0, 3.0, 3.5)
    for _ in range(3):                                     # sheds on the rim
        t = rng.uniform(0, 2 * np.pi)
        rr = r0 * 1.25 + 15
        bx, by = cx + rr * np.cos(t), cy + rr * np.sin(t)
        s.box(bx, by, rng.uniform(0, np.pi), rng.uniform(12, 25), rng.uniform(8, 14), rng.uniform(5, 8),
              base=float(s.at(s.ground, bx, by)))
    dep = depth

    def rim_band(x, y):
        d = s.at(dep, x, y)
        return (d == 0) & ~np.isfinite(s.at(s.top, x, y))

    def benches(x, y):
        return (s.at(dep, x, y) > 0) & ~np.isfinite(s.at(s.top, x, y))
    _trees(s, rng, 0.008, (6.0, 18.0), rim_band)
    _trees(s, rng, 0.01, (0.6, 1.8), benches, shrub=True)


def _shrubs(s, rng):
    e = s.e
    a = rng.uniform(0, 2 * np.pi)
    ts = np.float32(np.tan(np.radians(rng.uniform(28.0, 38.0))))
    sa, ca = np.float32(np.sin(a)), np.float32(np.cos(a))
    wv = _waves(rng, 80.0, 2.0)
    v0 = rng.uniform(-60, 60)

    def natural(u, v):
        return ts * u + wv(u, v) - 6.0 * np.exp(-((v - v0) / 15.0) ** 2)
    u = (s.X - e / 2) * ca + (s.Y - e / 2) * sa
    v = (s.Y - e / 2) * ca - (s.X - e / 2) * sa
    ur = rng.uniform(-60, 60)
    d = np.maximum(np.abs(u - ur) - 3.0, 0)
    road = natural(np.float32(ur), v)
    g = np.clip(natural(u, v), road - d * np.float32(np.tan(np.radians(35))),
                road + d * np.float32(np.tan(np.radians(60))))
    s.ground = (300 + g).astype(np.float32)
    patch = _waves(rng, 40.0, 1.0)

    def in_patch(x, y):
        ux = (x - e / 2) * ca + (y - e / 2) * sa
        return (patch(x, y) > -0.1) & (np.abs(ux - ur) > 4.5)

    def off_road(x, y):
        return np.abs((x - e / 2) * ca + (y - e / 2) * sa - ur) > 4.5
    _trees(s, rng, 0.08, (0.6, 2.0), in_patch, shrub=True)
    _trees(s, rng, 0.002, (6.0, 20.0), off_road)


def _bridge(s, rng):
    e = s.e
    g = 100 + _waves(rng, 150.0, 1.0)(s.X, s.Y)
    occ = np.zeros((s.n, s.n), bool)
    yr = e / 2 + rng.uniform(-30, 30)                       # the road below, along x
    occ |= np.abs(s.Y - yr) < 12
    xb = e / 2 + rng.uniform(-60, 60)                        # the bridge road, along y
    w, hd, span = rng.uniform(10.0, 14.0), rng.uniform(6.0, 8.0), rng.uniform(30.0, 50.0)
    ramp = hd / rng.uniform(0.06, 0.09)
    dy_ = np.abs(s.Y - yr)
    base = float(np.median(g[np.broadcast_to(np.abs(s.Y - yr) < 3, g.shape)]))
    level = base + hd * np.clip(1 - (dy_ - span / 2) / ramp, 0, 1)
    on_ramp = (dy_ > span / 2) & (dy_ < span / 2 + ramp)
    walls = (s.Y < yr) & on_ramp & (np.abs(s.X - xb) <= w / 2)
    banks = (s.Y > yr) & on_ramp
    g = np.where(walls, np.maximum(g, level), g)
    g = np.where(banks, np.maximum(g, level - np.maximum(np.abs(s.X - xb) - w / 2, 0) / 1.5), g)
    occ |= (np.abs(s.X - xb) < w / 2 + 10) & (dy_ < span / 2 + ramp + 5)
    s.ground = g.astype(np.float32)
    s.box(xb, yr, 0.0, w, span, hd + 0.8, base=base)      # deck with parapets 0.8 m
    # large buildings: L shapes, flat roofs, some with a roof structure
    placed = 0
    for _ in range(60):
        if placed >= 5:
            break
        ln, wd = rng.uniform(40.0, 110.0), rng.uniform(20.0, 45.0)
        bx, by = rng.uniform(ln / 2, e - ln / 2), rng.uniform(ln / 2, e - ln / 2)
        ang = rng.choice([0.0, np.pi / 2])
        win = s.window(bx, by, ln / 2 + 6)
        if occ[win[0]].any():
            continue
        r = 0.5 * ln + 6
        occ[win[0]] |= np.hypot(win[1] - bx, win[2] - by) < r
        h = rng.uniform(8.0, 25.0)
        bz = float(s.at(s.ground, bx, by)) + 0.3
        s.box(bx, by, ang, ln, wd, h, base=bz)
        ox = ln / 2 - wd / 2
        lx, ly = (bx + ox, by + wd / 2) if ang == 0 else (bx + wd / 2, by + ox)
        s.box(lx, ly, ang + np.pi / 2, wd * 1.5, wd, h * rng.uniform(0.6, 1.0), base=bz)
        if rng.random() < 0.6:
            s.box(bx + rng.uniform(-10, 10), by + rng.uniform(-5, 5), ang, 10.0, 8.0, h + 3.0, base=bz)
        if placed == 0:                                     # a garage ramp down to it, 3 m, walls
            rx0, rl = bx - ln / 2 if ang == 0 else bx - wd / 2, 25.0
            strip = (np.abs(s.Y - (by + wd / 4)) < 3) & (s.X < rx0) & (s.X > rx0 - rl)
            s.ground = np.where(strip & ~np.isfinite(s.top),
                                s.ground - 3.0 * np.clip((s.X - (rx0 - rl)) / rl, 0, 1),
                                s.ground).astype(np.float32)
        placed += 1
    for _ in range(3):                                      # data gaps (dark roofs, water)
        gx, gy, gr = rng.uniform(0, e), rng.uniform(0, e), rng.uniform(6.0, 15.0)
        s.gap |= np.hypot(s.X - gx, s.Y - gy) < gr
    _trees_and_cars(s, rng, ~occ, 0.001, 0.0015)


def _city(s, rng):
    """Large buildings on gentle terrain between streets (ISPRS 22-24, an urban lidar tile)."""
    e = s.e
    s.ground = (100 + rng.uniform(0.005, 0.02) * s.X + rng.uniform(-0.01, 0.01) * s.Y
                + _waves(rng, 150.0, 1.0)(s.X, s.Y)).astype(np.float32)
    occ = np.zeros((s.n, s.n), bool)

    def building(x0, y0, lx, ly, h, roof_structure=False):
        """A flat-roofed box over [x0, x0 + lx] x [y0, y0 + ly] on its highest ground point + 0.3 m."""
        w = s.window(x0 + lx / 2, y0 + ly / 2, 0.5 * max(lx, ly) + 1.0)
        foot = ((w[1] >= x0) & (w[1] <= x0 + lx) & (w[2] >= y0) & (w[2] <= y0 + ly))
        bz = float(s.ground[w[0]][foot].max()) + 0.3
        s.box(x0 + lx / 2, y0 + ly / 2, 0.0, lx, ly, h, base=bz)
        occ[w[0]] |= foot
        if roof_structure:                                  # a plant room on the roof
            s.box(x0 + lx * rng.uniform(0.3, 0.7), y0 + ly * rng.uniform(0.3, 0.7), 0.0, rng.uniform(8, 20),
                  rng.uniform(6, 12), h + rng.uniform(2.5, 4.0), base=bz)
        return bz
    # north: the large hall, the courtyard block beside it
    lx, ly = rng.uniform(180.0, 250.0), rng.uniform(100.0, 160.0)
    hx, hy = 15.0 + rng.uniform(0, 10), 15.0 + rng.uniform(0, 10)
    hall_h = rng.uniform(8.0, 20.0)
    building(hx, hy, lx, ly, hall_h, roof_structure=True)
    bx0 = hx + lx + rng.uniform(20.0, 30.0)
    b = min(rng.uniform(100.0, 150.0), e - 10.0 - bx0)
    by0 = 15.0 + rng.uniform(0, 10)
    c = rng.uniform(30.0, 60.0)
    building(bx0, by0, b, b, rng.uniform(12.0, 20.0))
    cw = s.window(bx0 + b / 2, by0 + b / 2, c / 2 + 1.0)    # the courtyard: ground
    court = (np.abs(cw[1] - (bx0 + b / 2)) <= c / 2) & (np.abs(cw[2] - (by0 + b / 2)) <= c / 2)
    s.top[cw[0]][court] = -np.inf
    occ[cw[0]] &= ~court
    # south of the street: a second hall, a long shed, then smaller buildings
    y1 = max(hy + ly, by0 + b) + rng.uniform(20.0, 30.0)
    l2, w2 = rng.uniform(60.0, 120.0), rng.uniform(60.0, 100.0)
    building(15.0, y1, l2, w2, rng.uniform(5.0, 12.0))
    x2 = 15.0 + l2 + rng.uniform(20.0, 30.0)
    l3, w3 = min(rng.uniform(120.0, 200.0), e - 10.0 - x2), rng.uniform(25.0, 40.0)
    building(x2, y1, l3, w3, rng.uniform(5.0, 7.0))
    y2 = y1 + w3 + rng.uniform(20.0, 30.0)
    for yb in np.arange(y2, e - 20.0, 45.0):                # blocks of 50 x 45 m between streets
        for xb in np.arange(15.0, e - 30.0, 50.0):
            if rng.random() < 0.8:
                bl, bw = rng.uniform(15.0, 30.0), rng.uniform(12.0, min(30.0, e - 5.0 - yb))
                building(xb, yb, bl, bw, rng.uniform(6.0, 15.0), roof_structure=rng.random() < 0.3)
    # a ramp 6 m wide descending 3-4 m over 30-40 m to the car park's entrance in the hall's south wall
    rx, rl, rd = hx + lx * rng.uniform(0.3, 0.7), rng.uniform(30.0, 40.0), rng.uniform(3.0, 4.0)
    ramp = (np.abs(s.X - rx) <= 3.0) & (s.Y > hy + ly) & (s.Y < hy + ly + rl) & ~np.isfinite(s.top)
    s.ground = np.where(ramp, s.ground - rd * np.clip((hy + ly + rl - s.Y) / rl, 0, 1), s.ground).astype(np.float32)
    occ |= (np.abs(s.X - rx) <= 5.0) & (s.Y > hy + ly) & (s.Y < hy + ly + rl + 5)
    # data gaps on two dark roofs
    for gx, gy, gr in ((hx + lx * rng.uniform(0.2, 0.8), hy + ly * rng.uniform(0.2, 0.8), rng.uniform(6.0, 12.0)),
                       (bx0 + rng.uniform(0.1, 0.25) * b, by0 + rng.uniform(0.1, 0.25) * b, rng.uniform(4.0, 8.0))):
        s.gap |= np.hypot(s.X - gx, s.Y - gy) < gr
    _trees_and_cars(s, rng, ~ndimage.binary_dilation(occ, iterations=6), 0.002, 0.002)


def _embankment(s, rng):
    """A road on an embankment with a ramp, a dike and a road cut among fields (ISPRS 24: ramps,
    embankments, vegetation). Side slopes 1:1.5-1:2 (the usual road and dike batters, 27-34 degrees);
    the ramp's grade 4-8 %. The embankments and the cut are ground; vegetation on their sides, houses,
    cars on the roads are objects."""
    e = s.e
    g0 = 100 + rng.uniform(0.005, 0.015) * s.X + _waves(rng, 150.0, 1.0)(s.X, s.Y)
    a = rng.uniform(-0.3, 0.3)
    sa, ca = np.float32(np.sin(a)), np.float32(np.cos(a))
    u = (s.X - e / 2) * ca + (s.Y - e / 2) * sa               # along the road
    d1 = (s.Y - e / 2) * ca - (s.X - e / 2) * sa - rng.uniform(-50, -20)
    hb, crest, k1 = rng.uniform(3.0, 6.0), rng.uniform(10.0, 14.0), rng.uniform(1.5, 2.0)
    u_end = rng.uniform(0.0, 0.2 * e)                          # where the ramp reaches the ground
    ramp = hb / rng.uniform(0.04, 0.08)
    h_u = np.float32(hb) * np.clip((u_end - u) / ramp, 0, 1)
    side1 = np.maximum(np.abs(d1) - crest / 2, 0)
    lift1 = np.clip(h_u - side1 / np.float32(k1), 0, None)
    # a dike 2-3 m high across the site beyond the road, a road cut 3-5 m deep near the other edge
    d2 = (s.Y - e / 2) * ca - (s.X - e / 2) * sa - rng.uniform(40, 70)
    hd, cd = rng.uniform(2.0, 3.0), rng.uniform(3.0, 5.0)
    side2 = np.maximum(np.abs(d2) - cd / 2, 0)
    lift2 = np.clip(np.float32(hd) - side2 / np.float32(rng.uniform(1.5, 2.5)), 0, None)
    v3 = u - rng.uniform(0.25, 0.35) * e                       # the cut runs across, near the far end
    dc, wc = rng.uniform(3.0, 5.0), rng.uniform(8.0, 11.0)
    side3 = np.maximum(np.abs(v3) - wc / 2, 0)
    cut = np.clip(np.float32(dc) - side3 / np.float32(1.5), 0, None) * (np.abs(d1) > crest / 2 + 3 * k1 + hb * k1)
    s.ground = (g0 + np.maximum(lift1, lift2) - cut).astype(np.float32)
    on_sides = ((lift1 > 0.3) & (side1 > 0)) | ((lift2 > 0.3) & (side2 > 0)) | ((cut > 0.3) & (side3 > 0))
    on_sides_b = ndimage.binary_dilation(on_sides, iterations=4)   # and a few metres beyond their toes
    on_top = ((lift1 > 0) & (side1 == 0)) | ((cut > 0) & (side3 == 0))

    def sides(x, y):
        return s.at(on_sides_b, x, y) & ~np.isfinite(s.at(s.top, x, y))
    _trees(s, rng, 0.05, (0.6, 2.0), sides, shrub=True)
    _trees(s, rng, 0.01, (5.0, 14.0), sides)
    free = ~ndimage.binary_dilation(on_sides | on_top, iterations=8)
    for _ in range(10):                                        # houses on the fields
        hx, hy = rng.uniform(15, e - 15), rng.uniform(15, e - 15)
        w = s.window(hx, hy, 12.0)
        if not free[w[0]].all():
            continue
        free[w[0]] = False
        depth = rng.uniform(8.0, 12.0)
        s.box(hx, hy, a + rng.choice([0.0, np.pi / 2]), rng.uniform(10.0, 16.0), depth, rng.uniform(4.0, 7.0),
              base=float(s.at(s.ground, hx, hy)) + 0.3, roof=_gable(np.tan(np.radians(35)), depth))
    x, y = s.scatter(rng, 0.004, lambda x, y: s.at(on_top, x, y))   # cars on the roads above and below
    for cx, cy in zip(x, y):
        s.box(cx, cy, a, 4.5, 1.8, rng.uniform(1.4, 1.7))
    _trees_and_cars(s, rng, free, 0.001, 0.0)


def _steps(s, rng):
    """Terrain discontinuities (ISPRS 53): steps of 2-10 m with faces of 60-85 degrees winding across a
    gentle slope (terrace and quarry edges, old embankments), one fading out along its length, trees and
    shrubs along their edges where machines cannot mow, a few sheds. Mostly ground: Type I errors
    dominate such a sample (Sithole & Vosselman 2003)."""
    e = s.e
    a = rng.uniform(0, 2 * np.pi)
    sa, ca = np.float32(np.sin(a)), np.float32(np.cos(a))
    u = (s.X - e / 2) * ca + (s.Y - e / 2) * sa
    v = (s.Y - e / 2) * ca - (s.X - e / 2) * sa
    g = 150 + np.float32(rng.uniform(0.02, 0.06)) * u + _waves(rng, 100.0, 0.8)(s.X, s.Y)
    count = int(rng.integers(4, 7))
    pos = np.sort(rng.uniform(-0.42 * e, 0.42 * e, count))
    near = np.zeros((s.n, s.n), bool)
    fade = int(rng.integers(count))
    for i, p in enumerate(pos):
        h = rng.uniform(2.0, 10.0) * (1 if rng.random() < 0.7 else -1)
        face = abs(h) / np.tan(np.radians(rng.uniform(60.0, 85.0)))
        wv = _waves(rng, 120.0, rng.uniform(3.0, 8.0), count=3)
        du = u - np.float32(p) - wv(v, v)
        hv = np.float32(h)
        if i == fade:                                         # a step that ends: 0 to full over 40-80 m
            v0, lv = rng.uniform(-0.3 * e, 0.1 * e), rng.uniform(40.0, 80.0)
            hv = hv * np.clip((v - v0) / lv, 0, 1)
        g = g + hv * np.clip(du / np.float32(face) + 0.5, 0, 1)
        near |= np.abs(du) < face / 2 + 6.0
    s.ground = g.astype(np.float32)
    for _ in range(3):                                        # sheds away from the steps
        bx, by = rng.uniform(20, e - 20), rng.uniform(20, e - 20)
        w = s.window(bx, by, 10.0)
        if near[w[0]].any():
            continue
        s.box(bx, by, a, rng.uniform(8.0, 15.0), rng.uniform(6.0, 10.0), rng.uniform(3.0, 6.0),
              base=float(s.ground[w[0]].max()) + 0.2)

    def edges(x, y):
        return s.at(near, x, y) & ~np.isfinite(s.at(s.top, x, y))

    def elsewhere(x, y):
        return ~s.at(near, x, y) & ~np.isfinite(s.at(s.top, x, y))
    _trees(s, rng, 0.012, (5.0, 16.0), edges)
    _trees(s, rng, 0.04, (0.6, 2.0), edges, shrub=True)
    _trees(s, rng, 0.0015, (6.0, 16.0), elsewhere)


def _courtyard(s, rng):
    """Blocks of large buildings enclosing courtyards (ISPRS 23: large complex buildings, courtyards, data
    gaps): 2 x 2 blocks of 110-140 m between streets, each a ring 10-25 m high around 1-3 courtyards of
    12-35 m, some opening to the street by a passage 5-8 m wide; trees in the courtyards, data gaps on
    dark roofs and over a courtyard, cars in the streets."""
    e = s.e
    s.ground = (100 + rng.uniform(0.005, 0.03) * s.X + rng.uniform(-0.01, 0.01) * s.Y
                + _waves(rng, 150.0, 0.8)(s.X, s.Y)).astype(np.float32)
    occ = np.zeros((s.n, s.n), bool)
    courts = np.zeros((s.n, s.n), bool)
    street = rng.uniform(15.0, 25.0)
    size = (e - 3 * street) / 2
    for bi in range(2):
        for bj in range(2):
            x0, y0 = street + bi * (size + street), street + bj * (size + street)
            lx, ly = size * rng.uniform(0.85, 1.0), size * rng.uniform(0.85, 1.0)
            w = s.window(x0 + lx / 2, y0 + ly / 2, 0.5 * max(lx, ly) + 1.0)
            foot = (w[1] >= x0) & (w[1] <= x0 + lx) & (w[2] >= y0) & (w[2] <= y0 + ly)
            h = rng.uniform(10.0, 25.0)
            bz = float(s.ground[w[0]][foot].max()) + 0.3
            # wings of different heights: the block's halves
            s.box(x0 + lx / 4, y0 + ly / 2, 0.0, lx / 2, ly, h, base=bz)
            s.box(x0 + 3 * lx / 4, y0 + ly / 2, 0.0, lx / 2, ly, h * rng.uniform(0.6, 1.0), base=bz)
            occ[w[0]] |= foot
            nc = int(rng.integers(1, 4))
            for c in range(nc):                               # courtyards along the block's x axis
                cw, ch = rng.uniform(12.0, 35.0), rng.uniform(12.0, 35.0)
                cx = x0 + lx * (c + 0.5) / nc + rng.uniform(-3, 3)
                cy = y0 + ly / 2 + rng.uniform(-0.2, 0.2) * (ly - ch - 20)
                cw = min(cw, lx / nc - 12.0)
                if cw < 10.0:
                    continue
                cwin = s.window(cx, cy, max(cw, ch) / 2 + 1.0)
                court = (np.abs(cwin[1] - cx) <= cw / 2) & (np.abs(cwin[2] - cy) <= ch / 2)
                if rng.random() < 0.4:                        # a passage to the street
                    pw = rng.uniform(5.0, 8.0)
                    pwin = s.window(cx, y0 - 1.0, (ly + 2.0))
                    passage = ((np.abs(pwin[1] - cx) <= pw / 2) & (pwin[2] >= y0 - 1.0) & (pwin[2] <= cy))
                    s.top[pwin[0]][passage] = -np.inf
                    occ[pwin[0]] &= ~passage
                s.top[cwin[0]][court] = -np.inf
                occ[cwin[0]] &= ~court
                courts[cwin[0]] |= court
                if rng.random() < 0.6:                        # a roof structure beside it
                    s.box(cx, cy + ch / 2 + 5.0, 0.0, min(cw, 12.0), 6.0, h + rng.uniform(2.5, 4.0), base=bz)
    inner = courts & ~ndimage.binary_dilation(~courts, iterations=6)

    def in_court(x, y):
        return s.at(inner, x, y) & ~np.isfinite(s.at(s.top, x, y))
    _trees(s, rng, 0.01, (5.0, 14.0), in_court)
    for _ in range(4):                                        # data gaps on dark roofs
        for _ in range(50):
            gx, gy = rng.uniform(0, e), rng.uniform(0, e)
            if s.at(occ, gx, gy):
                break
        s.gap |= np.hypot(s.X - gx, s.Y - gy) < rng.uniform(5.0, 12.0)
    cy, cx = np.nonzero(courts)                               # and over part of one courtyard
    if cx.size:
        i = rng.integers(cx.size)
        s.gap |= np.hypot(s.X - s.x[cx[i]], s.Y - s.x[cy[i]]) < rng.uniform(4.0, 8.0)
    _trees_and_cars(s, rng, ~ndimage.binary_dilation(occ | courts, iterations=4), 0.001, 0.003)


def _sparse(s, rng):
    """Dense houses on a slope at low point density (ISPRS 54: low resolution, buildings, data gaps): rows
    of houses 8-16 m x 8-12 m, 5-10 m high with gable roofs, 3-10 m apart along streets on a 3-8 degree
    slope, gardens with trees, data gaps; :data:`DENSITY_PER_M2` draws a point every 2.5 m."""
    e = s.e
    a = rng.uniform(0, 2 * np.pi)
    ts = np.float32(np.tan(np.radians(rng.uniform(3.0, 8.0))))
    sa, ca = np.float32(np.sin(a)), np.float32(np.cos(a))
    s.ground = (200 + ts * ((s.X - e / 2) * ca + (s.Y - e / 2) * sa)
                + _waves(rng, 100.0, 1.0)(s.X, s.Y)).astype(np.float32)
    occ = np.zeros((s.n, s.n), bool)
    for ys in np.arange(10.0, e - 10.0, rng.uniform(32.0, 40.0)):   # a street, then a row each side
        for side in (-1, 1):
            xh = rng.uniform(0, 8)
            while xh < e - 8:
                ln, dp = rng.uniform(8.0, 16.0), rng.uniform(8.0, 12.0)
                cy = ys + side * (4.0 + rng.uniform(2.0, 5.0) + dp / 2)
                cx = xh + ln / 2
                if rng.random() < 0.85 and 0 < cy < e:
                    w = s.window(cx, cy, 0.5 * np.hypot(ln, dp))
                    s.box(cx, cy, 0.0, ln, dp, rng.uniform(3.0, 6.0), base=float(s.ground[w[0]].max()) + 0.2,
                          roof=_gable(np.tan(np.radians(rng.uniform(25, 45))), dp))
                    occ[w[0]] = True
                xh += ln + rng.uniform(3.0, 10.0)
    for _ in range(3):
        gx, gy = rng.uniform(0, e), rng.uniform(0, e)
        s.gap |= np.hypot(s.X - gx, s.Y - gy) < rng.uniform(5.0, 10.0)
    _trees_and_cars(s, rng, ~occ, 0.003, 0.002)


_BUILD = {"hillside": _hillside, "railway": _railway, "quarry": _quarry, "shrubs": _shrubs,
          "bridge": _bridge, "city": _city,
          "embankment": _embankment, "steps": _steps, "courtyard": _courtyard, "sparse": _sparse}
