"""Bare terrain with no objects (issue 12): natural and man-made ground that must stay ground.

The matrix's synthetic scenes are mostly gentle terrain with objects. Held-out tiles also hold
steep, rough and man-made ground that looks like objects to a filter (the Type I failures of
Sithole & Vosselman 2004: dikes, embankments, cliffs, terrace risers). :func:`make_bare` builds
each scene of :data:`BARE` on a fine grid (:data:`FINE_M`), a square of ``extent_m``, and averages
it over the output cells (the DSM of a bare surface), with Gaussian height noise. Every cell is
ground: ``mask`` is all ``GROUND``, ``dtm`` the noise-free surface.

The shapes' dimensions and their sources:

* ``mountain``: fractional Brownian surface (spectral synthesis, Saupe 1988), Hurst exponent
  H = 0.7 (fractal dimension D = 3 - H = 2.3: Mark & Aronson 1984 measured D of 2.2-2.3 on real
  topography over 0.1-5 km), relief (max - min) 200 m over 500 m (alpine). Below 100 m the
  spectrum falls faster (H = 1.5 there): measured terrain is smoother at metre scales than its
  kilometre fractal law (Mark & Aronson's breaks in scaling). Slopes: median 37 degrees, 1 %
  steeper than 59 (steeper still, the median passes 45 degrees: more than alpine).
* ``upland``: the same with H = 0.9 and relief 50 m over 500 m (rolling upland, slopes mostly
  under 20 degrees).
* ``hills``: rolling hills, three plane waves 150-400 m long, 8-12 m high (slopes up to about 10
  degrees).
* ``dunes``: transverse dunes 100 m apart and 12 m high, sinuous crests, stoss slopes about 8
  degrees, slip faces at 33 degrees (the angle of repose of dry sand, 32-34 degrees: Bagnold 1941),
  crests rounded over 3 m.
* ``gullies``: a 3 degree slope cut by three incised gullies 3, 8 and 20 m deep (gullies are
  0.5-30 m deep: Poesen et al. 2003), floors 2-6 m wide, sides at 60, 50 and 45 degrees, meandering.
* ``river``: a floodplain at 0.2 % with a meandering channel 30 m wide and 3 m deep (bankfull
  width / depth about 10: Leopold & Maddock 1953), its cut banks at 60 degrees, and a river
  terrace's scarp 5 m high at 35 degrees.
* ``levees``: three dikes on a flat floodplain: 2, 4 and 6 m high, crests 3, 4 and 5 m wide,
  slopes 1:3 on the water side and 1:2 on the land side (the usual Dutch dike profile), so bases
  13, 24 and 35 m wide; one of them curved. Narrow raised ground: a classic Type I failure.
* ``roads``: a road 8 m wide cut across a 15 degree hillside, cut slope 1:1 (45 degrees) uphill and
  fill slope 1:1.5 (34 degrees) downhill (usual road design slopes in soil: cuts 1:1-1:2, fills
  1:1.5-1:2), and an embankment 7 m high carrying a second road across a valley (crest 10 m, sides
  1:1.5).
* ``mounds``: 12 burial mounds (round barrows: 10-40 m across, 1-6 m high, Historic England's
  scheduling descriptions), cosine-squared profiles (sides at most about 30 degrees) on gently
  rolling ground.
* ``outcrops``: a 20 degree hillside with a cliff band 15 m high at 75 degrees across it, and
  seven rock outcrops (tors: 3-8 m high, 8-25 m across, sides 60-75 degrees, irregular outlines
  and rough tops; Linton 1955).
* ``terraces``: agricultural terraces on a 20 degree hillside: risers 0.5, 1 and 2 m (dry-stone
  or earth risers, 0.5-2 m: Tarolli et al. 2014) at 70 degrees following the curved contours, the
  treads levelled between them.

The noise alternates between 0.05, 0.10 and 0.15 m with the scene (:data:`NOISE_M`).
"""
import numpy as np
from scipy import ndimage

from .codes import GROUND
from .synthetic import Scene

#: The scenes :func:`make_bare` builds.
BARE = ("mountain", "upland", "hills", "dunes", "gullies", "river", "levees", "roads", "mounds",
        "outcrops", "terraces")
#: Fine grid of the scenes' surfaces, metres.
FINE_M = 0.5
#: Height noise of each scene, metres (lidar 0.05, image matching up to 0.15).
NOISE_M = {k: (0.05, 0.10, 0.15)[i % 3] for i, k in enumerate(BARE)}
_ORIGIN_XY = (520000.0, 5420000.0)
_EPSG = 32632


def make_bare(kind, cell_size=1.0, extent_m=400.0, seed=0, noise_m=None):
    """Build a bare-terrain scene: every cell ground.

    Parameters
    ----------
    kind : str
        One of :data:`BARE` (see the module's docstring for each shape and its source).
    cell_size : float
        Output cell size in metres, a multiple of :data:`FINE_M` dividing ``extent_m``.
    extent_m : float
        Side of the square scene, metres.
    seed : int
        Random seed; the fine surface does not depend on ``cell_size``.
    noise_m : float or None
        Standard deviation of the height noise, metres; None: :data:`NOISE_M` of the scene.

    Returns
    -------
    Scene
        ``mask`` all ground, ``dtm`` the cells' mean of the fine surface, ``dsm`` it plus noise.
    """
    if kind not in BARE:
        raise ValueError(f"unknown bare scene {kind!r}; choose one of {', '.join(BARE)}.")
    k = float(cell_size) / FINE_M
    n = float(extent_m) / FINE_M
    if k < 1 or abs(k - round(k)) > 1e-9 or abs(n - round(n)) > 1e-9 or round(n) % round(k):
        raise ValueError(f"cell_size {cell_size!r} must be a multiple of {FINE_M} m dividing "
                         f"extent_m {extent_m!r}.")
    noise = NOISE_M[kind] if noise_m is None else float(noise_m)
    if not np.isfinite(noise) or noise < 0:
        raise ValueError("noise_m must be >= 0.")
    k, n = int(round(k)), int(round(n))
    ss = np.random.SeedSequence([int(seed), BARE.index(kind)])
    r_shape, r_noise = (np.random.default_rng(s) for s in ss.spawn(2))
    x = ((np.arange(n) + 0.5) * FINE_M)
    X, Y = x[None, :], x[:, None]
    fine = _BUILD[kind](X, Y, float(extent_m), r_shape)
    fine = np.broadcast_to(fine, (n, n))
    m = n // k
    dtm = fine.reshape(m, k, m, k).mean(axis=(1, 3)).astype(np.float32)
    dsm = dtm + np.float32(noise) * r_noise.standard_normal((m, m)).astype(np.float32)
    cell = k * FINE_M
    gt = (_ORIGIN_XY[0], cell, 0.0, _ORIGIN_XY[1], 0.0, -cell)
    return Scene(dsm=dsm.astype(np.float32), dtm=dtm, mask=np.full((m, m), GROUND, np.uint8),
                 cell_size=(cell, cell), kind=kind, geotransform=gt, epsg=_EPSG)


# ----------------------------------------------------------------------------------- shapes
def _fbm(X, Y, e, rng, hurst, relief, inner_m):
    """Fractional Brownian surface: power spectrum k^-(2H + 2) above ``inner_m`` wavelengths,
    k^-5 below (smooth at metre scales); synthesised on a grid twice the scene (no wrap-around)
    and scaled to ``relief`` over 500 m (max - min)."""
    n = X.shape[1]
    big = 2 * n
    f = np.fft.fftfreq(big, d=FINE_M)
    kk = np.hypot(f[:, None], f[None, :])
    kk[0, 0] = 1.0
    kc = 1.0 / inner_m
    amp = np.where(kk < kc, kk ** -(hurst + 1.0), kc ** (1.5 - hurst) * kk ** -2.5)
    amp[0, 0] = 0.0
    spec = amp * np.exp(2j * np.pi * rng.random((big, big)))
    z = np.fft.ifft2(spec).real[:n, :n]
    z = (z - z.min()) / (z.max() - z.min())
    return 100.0 + z * relief * (e / 500.0) ** hurst


def _waves(X, Y, rng, lengths, heights):
    z = 0.0
    for lam, h in zip(lengths, heights):
        a, p = rng.uniform(0, np.pi), rng.uniform(0, 2 * np.pi)
        z = z + 0.5 * h * np.cos(2 * np.pi * (X * np.cos(a) + Y * np.sin(a)) / lam + p)
    return z


def _mountain(X, Y, e, rng):
    return _fbm(X, Y, e, rng, 0.7, 200.0, 100.0)


def _upland(X, Y, e, rng):
    return _fbm(X, Y, e, rng, 0.9, 50.0, 100.0)


def _hills(X, Y, e, rng):
    return 100.0 + _waves(X, Y, rng, (400.0, 250.0, 150.0), (12.0, 10.0, 8.0))


def _dunes(X, Y, e, rng):
    lam, h = 100.0, 12.0
    lee = h / np.tan(np.radians(33.0))                       # slip face's horizontal run
    u = X + 10.0 * np.sin(2 * np.pi * Y / 200.0)          # sinuous crests
    p = np.mod(u, lam)
    crest = lam - lee
    z = np.where(p < crest, h * p / crest, h * (lam - p) / lee)
    z = ndimage.uniform_filter(z, int(3.0 / FINE_M))          # crests and toes rounded over 3 m
    return 50.0 + z + 0.01 * X


def _gullies(X, Y, e, rng):
    z = 100.0 - np.tan(np.radians(3.0)) * Y + _waves(X, Y, rng, (300.0,), (3.0,))
    for x0, depth, floor, side in ((80.0, 3.0, 2.0, 60.0), (200.0, 8.0, 4.0, 50.0),
                                   (320.0, 20.0, 6.0, 45.0)):
        c = x0 / 400.0 * e + 12.0 * np.sin(2 * np.pi * Y / 150.0 + x0)
        d = np.abs(X - c)
        cut = depth * np.clip((floor / 2 + depth / np.tan(np.radians(side)) - d)
                              / (depth / np.tan(np.radians(side))), 0.0, 1.0)
        z = z - cut
    return z


def _river(X, Y, e, rng):
    z = 30.0 + 0.002 * Y + 0.001 * X
    c = 0.45 * e + 40.0 * np.sin(2 * np.pi * Y / 250.0)
    d = np.abs(X - c)
    bank = 3.0 / np.tan(np.radians(60.0))
    z = z - 3.0 * np.clip((15.0 - d) / bank, 0.0, 1.0)
    # a river terrace's scarp, 5 m high at 35 degrees, up on the right side
    s = X - (0.8 * e + 10.0 * np.sin(2 * np.pi * Y / 180.0))
    return z + 5.0 * np.clip(s / (5.0 / np.tan(np.radians(35.0))), 0.0, 1.0)


def _dike(d, h, crest, out_run=3.0, in_run=2.0):
    """A dike's height at signed distance ``d`` from its axis (water side d < 0)."""
    up = np.where(d < 0, (crest / 2 + out_run * h + d) / out_run, (crest / 2 + in_run * h - d) / in_run)
    return np.clip(up, 0.0, h)


def _levees(X, Y, e, rng):
    z = 5.0 + 0.001 * X + 0.0005 * Y
    r = np.hypot(X - 0.95 * e, Y - 0.95 * e)
    dikes = np.maximum(np.maximum(_dike(Y - 0.2 * e, 2.0, 3.0), _dike(X - 0.5 * e, 4.0, 4.0)),
                       _dike(0.6 * e - r, 6.0, 5.0))          # the last curved, water side outwards
    return z + dikes


def _roads(X, Y, e, rng):
    t = np.tan(np.radians(15.0))
    wave = _waves(X, Y, rng, (200.0,), (4.0,))
    z = 100.0 + t * Y + wave
    # a valley 7 m deep along the x axis at yv, crossed by road 2
    yv = 0.75 * e
    z = z - 7.0 * np.exp(-((Y - yv) / 30.0) ** 2)
    # road 1 (8 m wide) along the contour at y0, level across it: cut uphill at 1:1 (its face
    # rising 1 m a metre away from the road), fill downhill at 1:1.5
    y0 = 0.3 * e + 8.0 * np.sin(2 * np.pi * X / 300.0)
    lev = 100.0 + t * y0
    d = np.maximum(np.abs(Y - y0) - 4.0, 0.0)
    z = np.where(z >= lev, np.minimum(z, lev + d), np.maximum(z, lev - d / 1.5))
    # road 2 along y at x0 on an embankment across the valley: its crest the hillside before the
    # valley (7 m above the valley's floor), 10 m wide, sides 1:1.5
    x0 = 0.6 * e
    emb = 100.0 + t * Y + wave - np.maximum(np.abs(X - x0) - 5.0, 0.0) / 1.5
    return np.where(np.abs(Y - yv) < 60.0, np.maximum(z, emb), z)


def _mounds(X, Y, e, rng):
    z = 60.0 + _waves(X, Y, rng, (300.0, 180.0), (4.0, 2.0))
    for _ in range(12):
        d = rng.uniform(10.0, 40.0)
        h = min(rng.uniform(1.0, 6.0), 0.18 * d)             # sides at most 30 degrees
        cx, cy = rng.uniform(25.0, e - 25.0, 2)
        r = np.hypot(X - cx, Y - cy)
        z = z + h * np.cos(np.clip(r / (d / 2), 0.0, 1.0) * np.pi / 2) ** 2
    return z


def _outcrops(X, Y, e, rng):
    t = np.tan(np.radians(20.0))
    z = 100.0 + t * Y + _waves(X, Y, rng, (250.0,), (5.0,))
    # a cliff band 15 m high at 75 degrees across the slope at y0
    y0 = 0.55 * e + 10.0 * np.sin(2 * np.pi * X / 220.0)
    z = z + 15.0 * np.clip((Y - y0) / (15.0 / np.tan(np.radians(75.0))) + 0.5, 0.0, 1.0)
    rough = ndimage.gaussian_filter(rng.standard_normal(X.shape[1:] + Y.shape[:1]), 2.0 / FINE_M)
    rough = rough / rough.std()
    for _ in range(7):
        h, w = rng.uniform(3.0, 8.0), rng.uniform(8.0, 25.0)
        side = np.tan(np.radians(rng.uniform(60.0, 75.0)))
        cx, cy = rng.uniform(30.0, e - 30.0), rng.uniform(30.0, 0.45 * e)
        ang = np.arctan2(Y - cy, X - cx)
        rad = w / 2 * (1 + 0.2 * np.sin(3 * ang + rng.uniform(0, 6)) + 0.1 * np.sin(5 * ang))
        r = np.hypot(X - cx, Y - cy)
        top = h + 0.3 * rough
        z = z + np.clip((rad - r) * side, 0.0, top)
    return z


def _terraces(X, Y, e, rng):
    """Terraces follow the contours of a hillside curved around a centre above the scene."""
    t = np.tan(np.radians(20.0))
    r = np.hypot(X - 0.5 * e, Y + 1.5 * e)                    # contours: arcs
    s = r - 1.5 * e                                           # distance down the slope
    z = 200.0 - t * s
    out = z.copy()
    for lo, hi, riser in ((0.0, 0.33, 0.5), (0.33, 0.66, 1.0), (0.66, 1.01, 2.0)):
        band = (X >= lo * e) & (X < hi * e)
        run = riser / t                                       # tread + riser, horizontal
        face = riser / np.tan(np.radians(70.0))
        p = np.mod(s, run)
        step = np.floor(s / run)
        level = 200.0 - t * step * run - riser * np.clip((p - (run - face)) / face, 0.0, 1.0)
        out = np.where(band, level, out)
    return out


_BUILD = {"mountain": _mountain, "upland": _upland, "hills": _hills, "dunes": _dunes,
          "gullies": _gullies, "river": _river, "levees": _levees, "roads": _roads,
          "mounds": _mounds, "outcrops": _outcrops, "terraces": _terraces}
