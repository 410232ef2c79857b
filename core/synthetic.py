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
# airborne lidar point clouds

#: Landscapes of :func:`make_lidar_points`.
LIDAR_KINDS = ("forest", "mixed", "urban")
#: ASPRS classes the simulated points carry (LAS 1.4): ground, low / medium / high
#: vegetation, building, low noise, high noise.
ASPRS_GROUND, ASPRS_LOW_VEG, ASPRS_MEDIUM_VEG, ASPRS_HIGH_VEG, ASPRS_BUILDING = 2, 3, 4, 5, 6
ASPRS_LOW_NOISE, ASPRS_HIGH_NOISE = 7, 18
#: Heights above the ground (m) at which vegetation passes from low (3) to medium (4) and
#: from medium to high (5).
VEG_CLASS_LIMITS_M = (2.0, 5.0)

# Sensor and survey (a small-footprint discrete-return scanner flown low, as for dense
# surveys): flying height, half field of view, side overlap of the strips, ground speed,
# share of the mirror's sinusoid in its sweep (the rest linear: density rises towards the
# swath's edges, 1.7 x the centre's), detection threshold as a share of the pulse's energy,
# dead zone (the smallest distance at which two returns of one pulse are told apart),
# concentration of the intercepted share (footprint-scale gaps: a low value makes a pulse
# mostly either pass a gap or be stopped), range noise.
_ALT_M, _HALF_FOV_DEG, _OVERLAP, _SPEED_MS = 600.0, 20.0, 0.3, 50.0
_SINE_SHARE, _TAU, _DEAD_ZONE_M, _GAP_CONCENTRATION, _RANGE_NOISE_M = 0.3, 0.05, 1.0, 1.5, 0.03
#: Raster step (m) on which crown and shrub footprints are indexed (the geometry of the
#: crown found there is then evaluated exactly at each pulse).
_INDEX_STEP_M = 0.5


@dataclass
class LidarPoints:
    """A simulated airborne lidar point cloud with its truth.

    Attributes
    ----------
    x, y, z : ndarray of float64
        Map coordinates, metres (UTM 32N, x east, y north), in the order of acquisition
        (flight strip, then pulse, then return).
    classification : ndarray of uint8
        ASPRS class: 2 ground, 3 / 4 / 5 low / medium / high vegetation (height above the
        ground below :data:`VEG_CLASS_LIMITS_M`), 6 building, 7 low noise, 18 high noise.
    return_number, number_of_returns : ndarray of uint8
        1-based index of the return within its pulse, and the pulse's number of returns.
    scan_angle_deg : ndarray of float32
        Angle of the pulse from nadir, positive to the right of the flight line.
    point_source_id : ndarray of uint16
        The flight strip (1, 2, ...).
    kind : str
        One of :data:`LIDAR_KINDS`.
    extent : tuple of float
        ``(x0, y0, x1, y1)`` of the simulated square, map metres.
    density_per_m2 : float
        The requested pulse density (first returns per square metre, over the square).
    terrain : callable
        ``terrain(x, y) -> z``: the true bare earth at map coordinates (the surface the
        ground points lie on, before the range noise).
    objects : dict
        Counts and sizes: ``trees``, ``shrubs``, ``buildings`` (number of buildings),
        ``largest_building_m`` (the longest side of any building), ``max_slope_deg`` (of
        the steep hillside, 0 without one), ``bank`` / ``cutting`` (height / depth, m).
    epsg : int
        32632.
    """
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    classification: np.ndarray
    return_number: np.ndarray
    number_of_returns: np.ndarray
    scan_angle_deg: np.ndarray
    point_source_id: np.ndarray
    kind: str
    extent: tuple
    density_per_m2: float
    terrain: object = field(repr=False)
    objects: dict = field(default_factory=dict)
    epsg: int = _EPSG

    def __len__(self):
        return int(self.x.size)

    def to_cloud(self):
        """The points as a :class:`~bare_earth.core.pointfiles.PointCloud` (metres, no CRS
        record: the unit is the metre), for :mod:`~bare_earth.core.pointflow`."""
        from .pointfiles import PointCloud
        return PointCloud(self.x, self.y, self.z, self.classification.astype(np.int32),
                          units_to_metre=1.0, z_units_to_metre=1.0)


def make_lidar_points(kind="forest", extent_m=400.0, density_per_m2=10.0, seed=0, crown_density=1.0,
                      noise_rate=1e-5, steep=True, understory=1.0):
    """Simulate an airborne lidar survey of a landscape with known ground.

    The landscape is continuous (every surface a function of map x, y) and the scanner
    samples it pulse by pulse, so the same cloud can be gridded at any cell size.

    * **Terrain**: a smooth random field (slopes of a few degrees) plus, for ``forest`` and
      ``mixed``, a hillside whose slope reaches 34-40 degrees (a logistic step 20-55 m high;
      slopes above 20 degrees over a band about 3.7 step-widths wide), and a bank (``forest``:
      a 2.5-5 m step at 45-60 degrees) or a road cutting (``mixed``: 3-6 m deep, 8-14 m
      floor, 35-45 degree sides) across the scene.
    * **Trees**: stems of a Poisson process in the forested zones (``forest``: 85 % of the
      area, 0.02 stems per m2; ``mixed``: a third of it; ``urban``: street trees, gardens and
      a park), heights 5-35 m (70 % dominant 15-35 m, 30 % suppressed 5-15 m), half conifers
      (cone crowns, radius 0.12-0.2 of the height, base at 0.2-0.5 of it, foliage extinction
      0.4-1.2 per metre of path) and half broadleaves (ellipsoid crowns, radius 0.18-0.3,
      base 0.35-0.6, extinction 0.15-0.6 per metre), radii at most 8 m. **Shrubs**
      0.3-3 m high (half-ellipsoids on the ground, radius 0.5-2 m, extinction 0.8-2.5 per
      metre) under the trees and in open land.
    * **Buildings** (``urban``, ``mixed``): a street grid rotated by up to 35 degrees, blocks
      76-100 m wide between 12-20 m streets, each block cut into 1-3 x 1-3 parcels holding a
      building (set back 1.5-5 m; 15 % of the parcels gardens) with a flat or gable roof
      (pitch 25-45 degrees), eaves 4-30 m above the highest ground under it; the block at the
      centre holds one hall of 64-97 m with a flat roof 8-14 m high.
    * **Pulses**: vertical rays (the tilt of a scan angle of at most 20 degrees is ignored) on
      parallel flight strips (flying height 600 m, half field of view 20 degrees: a 437 m swath;
      30 % side overlap) swept by an oscillating mirror (the pattern's density rises 1.7 x
      from the swath's centre to its edges; overlaps get the two strips' pulses). A pulse
      entering a crown along a path ``L`` loses a random share ``f`` of its energy, drawn
      from a Beta law of mean ``1 - exp(-k L)`` (Beer-Lambert; ``k`` the crown's extinction)
      and concentration 1.5 (the footprint meets a gap or foliage); a return is recorded
      where the intercepted energy is at least 5 % of the pulse's, at a depth drawn from the
      exponential law of the extinction; a second return from the same crown deeper by at
      least the receiver's dead zone (1 m) with probability ``f / 2``; the same for a shrub;
      the remaining energy, if at least 5 %, returns from the roof or the ground. Returns
      closer than 1 m to the previous one of the same pulse are lost (dead zone); range
      noise 3 cm (truncated at 4.5 sigma). So under dense crowns few or no pulses reach the
      ground, and a 4 m cell of a lowest-point grid may hold no ground return at all.
    * **Noise**: a share ``noise_rate`` of the pulses gives a further point 3-30 m below the
      ground (multipath; class 7) and as many 50-300 m above the surface (birds, haze;
      class 18).

    Parameters
    ----------
    kind : str
        ``"forest"``, ``"mixed"`` (town, forest and open land) or ``"urban"``.
    extent_m : float
        Side of the simulated square, metres (at least 50; at least 150 for ``urban`` and
        ``mixed``, whose central block holds the large hall).
    density_per_m2 : float
        Pulses (first returns) per square metre over the square (0.1-100).
    seed : int
        Random seed; the same arguments give the same points.
    crown_density : float
        Factor on every crown's foliage extinction (1: the ranges above; larger: denser
        crowns, fewer pulses through).
    noise_rate : float
        Share of the pulses with a low-noise point and with a high-noise point (0-0.01).
    steep : bool
        False: no hillside, bank or cutting (``forest`` and ``mixed`` on the smooth field
        alone, slopes of a few degrees).
    understory : float
        Factor on the shrubs' stem density (1: 0.03 per m2 before the zones thin them;
        0-100).

    Returns
    -------
    LidarPoints

    Raises
    ------
    ValueError
        For an unknown kind or a parameter out of range.

    Examples
    --------
    >>> p = make_lidar_points("forest", extent_m=100.0, density_per_m2=4.0, seed=1)
    >>> bool((p.classification == 2).any()), p.x.dtype
    (True, dtype('float64'))
    """
    if kind not in LIDAR_KINDS:
        raise ValueError(f"unknown lidar kind {kind!r}; choose one of {', '.join(LIDAR_KINDS)}.")
    e = float(extent_m)
    if not np.isfinite(e) or e < (150.0 if kind != "forest" else 50.0) or e > 5000.0:
        raise ValueError(f"extent_m must be 50-5000 m (150 for urban and mixed); got {extent_m!r}.")
    if not np.isfinite(density_per_m2) or not 0.1 <= density_per_m2 <= 100.0:
        raise ValueError(f"density_per_m2 must be 0.1-100 pulses per m2; got {density_per_m2!r}.")
    if not np.isfinite(crown_density) or not 0.0 <= crown_density <= 100.0:
        raise ValueError(f"crown_density must be 0-100; got {crown_density!r}.")
    if not np.isfinite(understory) or not 0.0 <= understory <= 100.0:
        raise ValueError(f"understory must be 0-100; got {understory!r}.")
    if not np.isfinite(noise_rate) or not 0.0 <= noise_rate <= 0.01:
        raise ValueError(f"noise_rate must be 0-0.01; got {noise_rate!r}.")
    ss = np.random.SeedSequence([int(seed), 100 + LIDAR_KINDS.index(kind)])
    r_ter, r_zone, r_bld, r_tree, r_shrub, r_scan, r_ret, r_noise = (np.random.default_rng(s) for s in ss.spawn(8))
    objects = {}
    terrain, zone = _lidar_terrain(r_ter, r_zone, kind, e, objects, bool(steep))
    bld = _Blocks(r_bld, kind, e, terrain, zone) if kind != "forest" else None
    objects["buildings"] = 0 if bld is None else bld.count
    objects["largest_building_m"] = 0.0 if bld is None else bld.largest_m
    trees = _lidar_trees(r_tree, kind, e, terrain, zone, bld, crown_density)
    shrubs = _lidar_shrubs(r_shrub, kind, e, zone, bld, float(understory))
    objects["trees"], objects["shrubs"] = int(trees["R"].size), int(shrubs["R"].size)
    px, py, angle, strip = _scan(r_scan, e, float(density_per_m2))
    pts = _returns(r_ret, r_noise, px, py, angle, strip, terrain, bld, trees, shrubs, e, float(noise_rate))
    x, y, z, cls, rn, nr, ang, src = pts
    return LidarPoints(x=x + _ORIGIN[0], y=y + _ORIGIN[1], z=z, classification=cls, return_number=rn,
                       number_of_returns=nr, scan_angle_deg=ang, point_source_id=src, kind=kind,
                       extent=(_ORIGIN[0], _ORIGIN[1], _ORIGIN[0] + e, _ORIGIN[1] + e),
                       density_per_m2=float(density_per_m2),
                       terrain=lambda mx, my: terrain(np.asarray(mx, float) - _ORIGIN[0],
                                                      np.asarray(my, float) - _ORIGIN[1]),
                       objects=objects)


def _rotated(x, y, angle, cx, cy):
    ca, sa = np.cos(angle), np.sin(angle)
    return (x - cx) * ca + (y - cy) * sa, -(x - cx) * sa + (y - cy) * ca


def _lidar_terrain(rng, r_zone, kind, e, objects, steep=True):
    """``terrain(x, y)`` and ``zone(x, y)`` (a smooth field, std about 1) in local metres
    (origin at the square's south-west corner, y north)."""
    g, pad = 1.0, 8
    n = int(np.ceil(e / g)) + 2 * pad + 1
    base_deg = {"forest": 12.0, "mixed": 8.0, "urban": 4.0}[kind]
    field0 = _terrain(rng, (n, n), (g, g), ((800.0, 1.0), (250.0, 0.5), (80.0, 0.15)), base_deg)
    zfield = _smooth_field(r_zone, (n, n), (g, g), ((60.0, 1.0), (25.0, 0.3)))
    feats = []
    if kind != "urban" and steep:
        # a hillside: a logistic step of height A whose steepest slope is A / (4 w)
        a = rng.uniform(35.0, 55.0) if kind == "forest" else rng.uniform(20.0, 35.0)
        smax = np.radians(rng.uniform(34.0, 40.0))
        w = a / (4.0 * np.tan(smax))
        phi, cx, cy = rng.uniform(0, 2 * np.pi), e * rng.uniform(0.35, 0.65), e * rng.uniform(0.35, 0.65)
        feats.append(("hill", a, w, phi, cx, cy))
        objects["max_slope_deg"] = float(np.degrees(smax))
        phi2 = phi + rng.uniform(np.pi / 4, 3 * np.pi / 4)      # across the hillside
        cx2, cy2 = e * rng.uniform(0.3, 0.7), e * rng.uniform(0.3, 0.7)
        if kind == "forest":
            hb, sb = rng.uniform(2.5, 5.0), np.radians(rng.uniform(45.0, 60.0))
            feats.append(("bank", hb, hb / np.tan(sb), phi2, cx2, cy2))
            objects["bank"] = float(hb)
        else:
            dc, fw, sc = rng.uniform(3.0, 6.0), rng.uniform(8.0, 14.0), np.radians(rng.uniform(35.0, 45.0))
            feats.append(("cut", dc, fw, np.tan(sc), phi2, cx2, cy2))
            objects["cutting"] = float(dc)
    else:
        objects["max_slope_deg"] = 0.0

    def sample(grid, x, y):
        return ndimage.map_coordinates(grid, [np.asarray(y, float) / g + pad, np.asarray(x, float) / g + pad],
                                       order=1, mode="nearest")

    def terrain(x, y):
        x, y = np.asarray(x, float), np.asarray(y, float)
        z = sample(field0, x, y).astype(np.float64)
        for f in feats:
            if f[0] == "hill":
                _, a, w, phi, cx, cy = f
                u, _v = _rotated(x, y, phi, cx, cy)
                z += a * 0.5 * (1.0 + np.tanh(u / (2.0 * w)))
            elif f[0] == "bank":
                _, hb, wb, phi, cx, cy = f
                u, _v = _rotated(x, y, phi, cx, cy)
                z += hb * np.clip(u / wb + 0.5, 0.0, 1.0)
            else:
                _, dc, fw, tan_s, phi, cx, cy = f
                u, _v = _rotated(x, y, phi, cx, cy)
                z -= np.clip(dc - (np.abs(u) - fw / 2) * tan_s, 0.0, dc)
        return z

    def zone(x, y):
        return sample(zfield, x, y)
    return terrain, zone


class _Blocks:
    """Buildings on a rotated street grid: blocks cut into parcels, one building per parcel;
    ``lookup(x, y) -> (inside, roof z)`` exact at any point (local metres)."""

    def __init__(self, rng, kind, e, terrain, zone):
        self.theta = np.radians(rng.uniform(-35.0, 35.0))
        self.b = rng.uniform(76.0, 100.0)                  # block side
        self.pitch = self.b + rng.uniform(12.0, 20.0)      # + street
        # block (0, 0) centred on the square: its hall is inside whatever the rotation
        self.c = (e / 2 - self.b / 2 * (np.cos(self.theta) - np.sin(self.theta)),
                  e / 2 - self.b / 2 * (np.sin(self.theta) + np.cos(self.theta)))
        k = int(np.ceil(e * 1.5 / self.pitch)) + 1
        self.k = k
        nb = 2 * k + 1
        nu, nv = rng.integers(1, 4, (nb, nb)), rng.integers(1, 4, (nb, nb))
        nu[k, k] = nv[k, k] = 1
        self.nu, self.nv = nu, nv
        shp = (nb, nb, 3, 3)
        su, sv = self.b / nu[:, :, None, None], self.b / nv[:, :, None, None]
        iu, iv = np.arange(3)[None, None, :, None], np.arange(3)[None, None, None, :]
        set_back = rng.uniform(1.5, 5.0, (4,) + shp)
        u0, u1 = iu * su + set_back[0], (iu + 1) * su - set_back[1]
        v0, v1 = iv * sv + set_back[2], (iv + 1) * sv - set_back[3]
        exists = (iu < nu[:, :, None, None]) & (iv < nv[:, :, None, None]) & (rng.random(shp) >= 0.15)
        eave = np.clip(rng.uniform(4.0, 10.0, shp) + rng.exponential(4.0, shp), 4.0, 30.0)
        gable = rng.random(shp) < 0.5
        pitch = np.tan(np.radians(rng.uniform(25.0, 45.0, shp)))
        # the central hall
        sb = rng.uniform(2.0, 6.0, 4)
        u0[k, k, 0, 0], u1[k, k, 0, 0], v0[k, k, 0, 0], v1[k, k, 0, 0] = sb[0], self.b - sb[1], sb[2], self.b - sb[3]
        exists[k, k, 0, 0], gable[k, k, 0, 0] = True, False
        eave[k, k, 0, 0] = rng.uniform(8.0, 14.0)
        # blocks of a mixed scene stand in its town zone only (the centre's block always)
        bi = (np.arange(nb) - k)[:, None]
        bj = (np.arange(nb) - k)[None, :]
        mu, mv = bi * self.pitch + self.b / 2, bj * self.pitch + self.b / 2
        mx, my = self._to_local(mu, mv)
        town = (zone(mx, my) < -0.35) if kind == "mixed" else np.ones((nb, nb), bool)
        town[k, k] = True
        park = np.zeros((nb, nb), bool)
        if kind == "urban":                                # one park block next to the hall's
            park[k + 1, k] = True
        self.town, self.park = town, park
        exists &= (town & ~park)[:, :, None, None]
        # eaves above the highest ground under the building (corners and centre)
        cu = np.stack([u0, u1, u0, u1, 0.5 * (u0 + u1)]) + bi[..., None, None] * self.pitch
        cv = np.stack([v0, v0, v1, v1, 0.5 * (v0 + v1)]) + bj[..., None, None] * self.pitch
        gx, gy = self._to_local(cu, cv)
        inside = (gx >= 0) & (gx <= e) & (gy >= 0) & (gy <= e)
        self.base = terrain(gx, gy).max(axis=0)
        self.u0, self.u1, self.v0, self.v1 = u0, u1, v0, v1
        self.exists, self.eave, self.gable, self.pitch_tan = exists, eave, gable, pitch
        seen = exists & inside.any(axis=0)
        self.count = int(seen.sum())
        self.largest_m = float(np.max(np.maximum(u1 - u0, v1 - v0)[seen])) if self.count else 0.0

    def _to_local(self, u, v):
        ca, sa = np.cos(self.theta), np.sin(self.theta)
        return self.c[0] + u * ca - v * sa, self.c[1] + u * sa + v * ca

    def _frame(self, x, y):
        ca, sa = np.cos(self.theta), np.sin(self.theta)
        u = (x - self.c[0]) * ca + (y - self.c[1]) * sa
        v = -(x - self.c[0]) * sa + (y - self.c[1]) * ca
        bu, bv = np.floor(u / self.pitch).astype(np.intp), np.floor(v / self.pitch).astype(np.intp)
        lu, lv = u - bu * self.pitch, v - bv * self.pitch
        iu, iv = np.clip(bu + self.k, 0, 2 * self.k), np.clip(bv + self.k, 0, 2 * self.k)
        return lu, lv, iu, iv

    def street(self, x, y):
        """True in the streets (outside every block)."""
        lu, lv, _, _ = self._frame(x, y)
        return (lu >= self.b) | (lv >= self.b)

    def in_park(self, x, y):
        lu, lv, iu, iv = self._frame(x, y)
        return self.park[iu, iv] & (lu < self.b) & (lv < self.b)

    def in_town(self, x, y):
        _, _, iu, iv = self._frame(x, y)
        return self.town[iu, iv]

    def lookup(self, x, y, margin=0.0):
        """``(inside, roof z)`` at local points; ``margin`` grows the footprints."""
        lu, lv, iu, iv = self._frame(x, y)
        pu = np.minimum((lu / (self.b / self.nu[iu, iv])).astype(np.intp), 2)
        pv = np.minimum((lv / (self.b / self.nv[iu, iv])).astype(np.intp), 2)
        idx = (iu, iv, np.clip(pu, 0, 2), np.clip(pv, 0, 2))
        u0, u1, v0, v1 = self.u0[idx], self.u1[idx], self.v0[idx], self.v1[idx]
        inside = (self.exists[idx] & (lu < self.b) & (lv < self.b) & (lu >= u0 - margin) & (lu <= u1 + margin)
                  & (lv >= v0 - margin) & (lv <= v1 + margin))
        # gable: the ridge along the longer side, the roof rising from the eaves to it
        along_u = (u1 - u0) >= (v1 - v0)
        half = np.where(along_u, v1 - v0, u1 - u0) / 2
        off = np.where(along_u, np.abs(lv - (v0 + v1) / 2), np.abs(lu - (u0 + u1) / 2))
        rise = np.where(self.gable[idx], np.clip(half - off, 0.0, None) * self.pitch_tan[idx], 0.0)
        return inside, self.base[idx] + self.eave[idx] + rise


def _poisson_xy(rng, lam, lo, hi):
    n = rng.poisson(lam * (hi - lo) ** 2)
    return rng.uniform(lo, hi, n), rng.uniform(lo, hi, n)


def _lidar_trees(rng, kind, e, terrain, zone, bld, crown_density):
    """Stems (local metres), heights, crown shapes and foliage extinctions."""
    lo, hi = -8.0, e + 8.0
    if kind == "forest":
        x, y = _poisson_xy(rng, 0.02, lo, hi)
        keep = zone(x, y) > -1.04                          # 85 % forest, clearings between
    else:
        x, y = _poisson_xy(rng, 0.02, lo, hi)
        if kind == "mixed":
            forest = zone(x, y) > 0.35
            open_land = ~forest & ~bld.in_town(x, y)
            keep = forest | (open_land & (rng.random(x.size) < 0.05))
            keep |= bld.in_town(x, y) & (rng.random(x.size) < 0.1)
        else:                                             # streets, gardens, the park
            keep = (bld.in_park(x, y) & (rng.random(x.size) < 0.6)) | (rng.random(x.size) < 0.12)
        keep &= ~bld.lookup(x, y, margin=2.0)[0]
    x, y = x[keep], y[keep]
    n = x.size
    dominant = rng.random(n) < 0.7
    hgt = np.where(dominant, rng.uniform(15.0, 35.0, n), rng.uniform(5.0, 15.0, n))
    conifer = rng.random(n) < 0.5
    rad = np.minimum(hgt * np.where(conifer, rng.uniform(0.12, 0.2, n), rng.uniform(0.18, 0.3, n)) + 0.5, 8.0)
    base = hgt * np.where(conifer, rng.uniform(0.2, 0.5, n), rng.uniform(0.35, 0.6, n))
    k = crown_density * np.where(conifer, rng.uniform(0.4, 1.2, n), rng.uniform(0.15, 0.6, n))
    return dict(x=x, y=y, z0=terrain(x, y), H=hgt, R=rad, base=base, conifer=conifer, k=k)


def _lidar_shrubs(rng, kind, e, zone, bld, understory=1.0):
    lo, hi = -2.0, e + 2.0
    x, y = _poisson_xy(rng, 0.03 * understory, lo, hi)
    if kind == "forest":
        keep = rng.random(x.size) < np.where(zone(x, y) > -1.04, 1.0, 0.3)
    elif kind == "mixed":
        keep = rng.random(x.size) < np.where(zone(x, y) > 0.35, 1.0, 0.15) * ~bld.in_town(x, y)
    else:
        keep = rng.random(x.size) < np.where(bld.in_park(x, y), 0.5, 0.05)
    if bld is not None:
        keep &= ~bld.lookup(x, y, margin=1.0)[0]
    x, y = x[keep], y[keep]
    n = x.size
    return dict(x=x, y=y, H=rng.uniform(0.3, 3.0, n), R=rng.uniform(0.5, 2.0, n), k=rng.uniform(0.8, 2.5, n))


def _crown_top(t, idx, d2):
    """Crown top and bottom above the stem's ground at squared relative distance ``d2``."""
    if "conifer" not in t:                                 # shrub: half-ellipsoid on the ground
        top = t["H"][idx] * np.sqrt(np.clip(1.0 - d2, 0.0, None))
        return top, np.zeros_like(top)
    h, b = t["H"][idx], t["base"][idx]
    cone_top = b + (h - b) * (1.0 - np.sqrt(np.clip(d2, 0.0, 1.0)))
    c, a = 0.5 * (h + b), 0.5 * (h - b)
    s = np.sqrt(np.clip(1.0 - d2, 0.0, None))
    con = t["conifer"][idx]
    return np.where(con, cone_top, c + a * s), np.where(con, b, c - a * s)


def _index_crowns(t, e, step):
    """Per cell of a ``step`` raster over the square: the crown whose top is highest at the
    cell's centre (-1: none). A loop over stamp offsets, vectorised over the crowns."""
    n = int(np.ceil(e / step))
    best = np.full((n, n), -np.inf)
    ids = np.full((n, n), -1, np.int32)
    if t["R"].size == 0:
        return ids
    z0 = t.get("z0", np.zeros(t["R"].size))
    ci, cj = np.floor(t["y"] / step).astype(np.intp), np.floor(t["x"] / step).astype(np.intp)
    reach = int(np.ceil(t["R"].max() / step)) + 1
    all_idx = np.arange(t["R"].size)
    for di in range(-reach, reach + 1):
        for dj in range(-reach, reach + 1):
            near = t["R"] >= step * (max(abs(di), abs(dj)) - 1)
            idx = all_idx[near]
            i, j = ci[idx] + di, cj[idx] + dj
            ok = (i >= 0) & (i < n) & (j >= 0) & (j < n)
            idx, i, j = idx[ok], i[ok], j[ok]
            d2 = (((j + 0.5) * step - t["x"][idx]) ** 2 + ((i + 0.5) * step - t["y"][idx]) ** 2) / t["R"][idx] ** 2
            inside = d2 < 1.0
            idx, i, j, d2 = idx[inside], i[inside], j[inside], d2[inside]
            top = _crown_top(t, idx, d2)[0] + z0[idx]
            up = top > best[i, j]
            best[i[up], j[up]] = top[up]
            ids[i[up], j[up]] = idx[up]
    return ids


def _scan(rng, e, density):
    """Pulse positions (local metres) of parallel strips swept by an oscillating mirror."""
    swath = 2.0 * _ALT_M * np.tan(np.radians(_HALF_FOV_DEG))
    spacing = swath * (1.0 - _OVERLAP)
    first = rng.uniform(-spacing / 2, spacing / 2)
    centres = first + spacing * np.arange(-int(np.ceil(e / spacing)) - 2, int(np.ceil(e / spacing)) + 3)
    centres = centres[np.abs(centres - e / 2) < e / 2 + swath / 2]
    # the share of each strip's sweep that falls on the square, so that the square gets
    # `density` pulses per m2 on average (overlaps more, single coverage less)
    ph = np.linspace(0.0, 2.0 * np.pi, 4096, endpoint=False)
    sweep = (1.0 - _SINE_SHARE) * (2.0 / np.pi) * np.arcsin(np.sin(ph)) + _SINE_SHARE * np.sin(ph)
    on = [np.mean((c + 0.5 * swath * sweep >= 0) & (c + 0.5 * swath * sweep < e)) for c in centres]
    rho = density * e / (swath * sum(on))                 # pulses per m2 of one strip's swath
    length = e + 20.0
    prf = rho * swath * _SPEED_MS                          # pulses per second
    f_scan = np.sqrt(_SPEED_MS * prf / (4.0 * swath))     # scan lines as far apart as the pulses on them
    xs, ys, angs, src = [], [], [], []
    for s, c in enumerate(centres):                       # a handful of strips
        npulse = int(round(prf * length / _SPEED_MS))
        t = np.arange(npulse) / prf
        ph = 2.0 * np.pi * f_scan * t + rng.uniform(0, 2 * np.pi)
        sweep = (1.0 - _SINE_SHARE) * (2.0 / np.pi) * np.arcsin(np.sin(ph)) + _SINE_SHARE * np.sin(ph)
        x = c + 0.5 * swath * sweep + rng.normal(0.0, 0.02, npulse)
        y = -10.0 + _SPEED_MS * t + rng.normal(0.0, 0.02, npulse)
        if s % 2:
            y = e - y                                      # flown back and forth
        ok = (x >= 0) & (x < e) & (y >= 0) & (y < e)
        xs.append(x[ok])
        ys.append(y[ok])
        angs.append(np.degrees(np.arctan((x[ok] - c) / _ALT_M)).astype(np.float32))
        src.append(np.full(int(ok.sum()), s + 1, np.uint16))
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(angs), np.concatenate(src)


def _trunc_exp(rng, k, length):
    """Depths of first interception along a path ``length`` of extinction ``k`` (Beer-Lambert,
    truncated to the path)."""
    u = rng.random(k.size)
    return -np.log1p(-u * -np.expm1(-k * length)) / np.maximum(k, 1e-9)


def _intercept(rng, k, length):
    """Share of a pulse's energy a path through foliage intercepts: Beta, mean 1 - exp(-k L)."""
    m = np.clip(-np.expm1(-k * length), 1e-6, 1.0 - 1e-6)
    return rng.beta(m * _GAP_CONCENTRATION, (1.0 - m) * _GAP_CONCENTRATION)


def _returns(rng, r_noise, x, y, ang, strip, terrain, bld, trees, shrubs, e, noise_rate):
    n = x.size
    zg = terrain(x, y)
    if bld is not None:
        in_bld, zroof = bld.lookup(x, y)
    else:
        in_bld, zroof = np.zeros(n, bool), zg
    zsolid = np.where(in_bld, zroof, zg)
    energy = np.ones(n)
    cand = np.full((n, 4), np.nan)                         # crown, crown deeper, shrub, solid
    ccls = np.zeros((n, 4), np.uint8)
    i_cell = np.minimum((y / _INDEX_STEP_M).astype(np.intp), int(np.ceil(e / _INDEX_STEP_M)) - 1)
    j_cell = np.minimum((x / _INDEX_STEP_M).astype(np.intp), int(np.ceil(e / _INDEX_STEP_M)) - 1)
    for col, t in ((0, trees), (2, shrubs)):
        tid = _index_crowns(t, e, _INDEX_STEP_M)[i_cell, j_cell]
        p = np.nonzero(tid >= 0)[0]
        idx = tid[p]
        d2 = ((x[p] - t["x"][idx]) ** 2 + (y[p] - t["y"][idx]) ** 2) / t["R"][idx] ** 2
        inside = d2 < 1.0
        p, idx, d2 = p[inside], idx[inside], d2[inside]
        top, bot = _crown_top(t, idx, d2)
        g0 = t["z0"][idx] if "z0" in t else zg[p]
        top, bot = top + g0, np.maximum(bot + g0, zsolid[p])
        length = top - bot
        ok = (length > 0) & ~(in_bld[p] & (col == 2))
        p, idx, top, length = p[ok], idx[ok], top[ok], length[ok]
        k = t["k"][idx]
        f = _intercept(rng, k, length)
        hit = f * energy[p] >= _TAU
        d1 = _trunc_exp(rng, k, length)
        cand[p[hit], col] = top[hit] - d1[hit]
        if col == 0:                                      # a second return deeper in the crown
            rest = length - d1 - _DEAD_ZONE_M
            second = hit & (rest > 0) & (rng.random(p.size) < 0.5 * f)
            d2nd = d1 + _DEAD_ZONE_M + _trunc_exp(rng, k, np.maximum(rest, 0.0))
            cand[p[second], 1] = top[second] - d2nd[second]
        energy[p] *= 1.0 - f
    solid = energy >= _TAU
    cand[solid, 3] = zsolid[solid]
    # the receiver's dead zone: a return closer than it to the previous one is lost
    prev = np.full(n, np.inf)
    for col in range(4):
        c = cand[:, col]
        lost = np.isfinite(c) & (prev - c < _DEAD_ZONE_M)
        c[lost] = np.nan
        prev = np.where(np.isfinite(c), c, prev)
    valid = np.isfinite(cand)
    nret = valid.sum(axis=1).astype(np.uint8)
    rnum = np.cumsum(valid, axis=1).astype(np.uint8)
    noise = np.clip(rng.normal(0.0, 1.0, cand.shape), -4.5, 4.5) * _RANGE_NOISE_M
    hag = cand - zg[:, None]
    veg = np.where(hag < VEG_CLASS_LIMITS_M[0], ASPRS_LOW_VEG,
                   np.where(hag < VEG_CLASS_LIMITS_M[1], ASPRS_MEDIUM_VEG, ASPRS_HIGH_VEG))
    ccls[:, :3] = veg[:, :3]
    ccls[:, 3] = np.where(in_bld, ASPRS_BUILDING, ASPRS_GROUND)
    pulse, col = np.nonzero(valid)                         # row-major: pulse by pulse, top down
    xo, yo = x[pulse], y[pulse]
    zo = cand[pulse, col] + noise[pulse, col]
    co, rn, nr = ccls[pulse, col], rnum[pulse, col], nret[pulse]
    ao, so = ang[pulse], strip[pulse]
    # noise points: multipath below the ground, birds and haze above
    m = r_noise.binomial(n, noise_rate) if noise_rate > 0 else 0
    if m:
        lo, hi = r_noise.integers(0, n, m), r_noise.integers(0, n, m)
        xo = np.concatenate([xo, x[lo], x[hi]])
        yo = np.concatenate([yo, y[lo], y[hi]])
        zo = np.concatenate([zo, zg[lo] - r_noise.uniform(3.0, 30.0, m), zsolid[hi] + r_noise.uniform(50.0, 300.0, m)])
        co = np.concatenate([co, np.full(m, ASPRS_LOW_NOISE, np.uint8), np.full(m, ASPRS_HIGH_NOISE, np.uint8)])
        one = np.ones(2 * m, np.uint8)
        rn, nr = np.concatenate([rn, one]), np.concatenate([nr, one])
        ao, so = np.concatenate([ao, ang[lo], ang[hi]]), np.concatenate([so, strip[lo], strip[hi]])
    return xo, yo, zo, co.astype(np.uint8), rn, nr, ao, so


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
