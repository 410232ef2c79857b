"""Synthetic textured scenes and frame images drawn by ray casting, with known truth.

Tests and benchmarks of the orthophoto refinement (Luong Chinh Ke 2002, section 2.3;
Norvelle 1995) need frames of a scene whose surface, objects and cameras are known exactly.
:func:`make_ortho_scene` builds smooth terrain with flat-roofed buildings and a ground-fixed
random texture; :func:`vertical_cameras` places vertical frames along a base with a chosen
B/H; :func:`render_frame` draws what a :class:`~.camera.Camera` sees, by casting every
pixel's ray onto the surface (vectorised over pixels: a march down in height levels, then
bisection).
"""
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from .camera import Camera, Interior
from .orthorectify import grid_xy

__all__ = ["OrthoScene", "make_ortho_scene", "vertical_cameras", "render_frame", "render_frames", "imaged_in_both"]


@dataclass
class OrthoScene:
    """A synthetic scene with truth.

    Attributes
    ----------
    terrain : ndarray (rows, cols) float32
        Bare-earth heights (m).
    surface : ndarray (rows, cols) float32
        Terrain plus objects (the DSM).
    labels : ndarray (rows, cols) int32
        0 ground, k > 0 building number k, -1 tree crown.
    heights : dict of int -> float
        Height of each building above the terrain at its centre (m).
    transform : tuple
        North-up geotransform of the grid.
    texture : ndarray
        Albedo on a grid ``texture_factor`` times finer than the DEM.
    texture_factor : int
    """
    terrain: np.ndarray
    surface: np.ndarray
    labels: np.ndarray
    heights: dict
    transform: tuple
    texture: np.ndarray
    texture_factor: int = 2
    info: dict = field(default_factory=dict)

    @property
    def cell_size(self):
        return float(self.transform[1])

    def albedo(self, X, Y):
        """Texture value at world points (bilinear on the fine texture grid)."""
        f = self.texture_factor
        x0, dx, _, y0, _, ndy = self.transform
        c = (np.asarray(X) - x0) / dx * f - 0.5
        r = (y0 - np.asarray(Y)) / (-ndy) * f - 0.5
        return ndimage.map_coordinates(self.texture, [r, c], order=1, mode="reflect")


def make_ortho_scene(shape=(160, 200), cell_size=1.0, *, n_buildings=7, relief_m=8.0,
                     building_height_m=(5.0, 12.0), building_width_cells=(10, 24), seed=0,
                     texture_factor=2, contrast=0.3125, n_trees=0, tree_height_m=(4.0, 12.0),
                     crown_diameter_m=(3.0, 8.0)):
    """Smooth terrain with flat-roofed rectangular buildings and a random texture.

    Parameters
    ----------
    shape : (int, int)
        Grid rows, cols.
    cell_size : float
        Cell size in metres.
    n_buildings : int
        Buildings placed without overlap (fewer if they do not fit).
    relief_m : float
        Peak-to-peak terrain relief.
    building_height_m, building_width_cells : (low, high)
        Ranges of building heights and side lengths.
    seed : int
    texture_factor : int
        The texture grid is this many times finer than the DEM.
    contrast : float
        Standard deviation of the albedo over its mean (128 grey levels): the default 0.31
        is a well-textured scene (sd 40), 0.03 a weak texture (sd 3.8) that image noise of a
        few grey levels drowns.

    Returns
    -------
    OrthoScene
    """
    rng = np.random.default_rng(seed)
    rows, cols = shape
    transform = (0.0, float(cell_size), 0.0, rows * float(cell_size), 0.0, -float(cell_size))
    # terrain: low-frequency noise scaled to the relief
    t = ndimage.gaussian_filter(rng.normal(size=shape), min(shape) / 6.0, mode="reflect")
    t = (t - t.min()) / max(np.ptp(t), 1e-9) * relief_m + 100.0
    t = t.astype(np.float32)
    labels = np.zeros(shape, np.int32)
    surface = t.copy()
    heights = {}
    k = 0
    for _ in range(n_buildings * 30):
        if k >= n_buildings:
            break
        h = int(rng.integers(building_width_cells[0], building_width_cells[1] + 1))
        w = int(rng.integers(building_width_cells[0], building_width_cells[1] + 1))
        r0 = int(rng.integers(6, rows - h - 6))
        c0 = int(rng.integers(6, cols - w - 6))
        if labels[max(0, r0 - 4):r0 + h + 4, max(0, c0 - 4):c0 + w + 4].any():
            continue
        k += 1
        hb = float(rng.uniform(*building_height_m))
        roof = float(t[r0 + h // 2, c0 + w // 2]) + hb           # flat roof
        labels[r0:r0 + h, c0:c0 + w] = k
        surface[r0:r0 + h, c0:c0 + w] = roof
        heights[k] = hb
    f = int(texture_factor)
    tex = rng.normal(size=(rows * f, cols * f))
    if n_trees:
        _add_trees(np.random.default_rng([seed, 1]), t, surface, labels, int(n_trees), float(cell_size),
                   tree_height_m, crown_diameter_m)
    tex = (ndimage.gaussian_filter(tex, 1.0 * f) * 1.0
           + ndimage.gaussian_filter(rng.normal(size=tex.shape), 3.0 * f) * 2.5)
    if not contrast > 0:
        raise ValueError(f"contrast must be > 0 (albedo sd / mean); got {contrast}.")
    tex = ((tex - tex.mean()) / tex.std() * (128.0 * float(contrast)) + 128).astype(np.float32)
    return OrthoScene(t, surface.astype(np.float32), labels, heights, transform, tex, f,
                      info=dict(seed=seed, relief_m=relief_m, contrast=float(contrast)))


def _add_trees(rng, terrain, surface, labels, n, cell, height_m, diameter_m):
    """Half-ellipsoid crowns on free ground (in place); see :func:`make_ortho_scene`."""
    rows, cols = terrain.shape
    rr, cc = np.indices(terrain.shape)
    placed = 0
    for _ in range(n * 30):
        if placed >= n:
            break
        rad = float(rng.uniform(*diameter_m)) / 2.0 / cell             # crown radius in cells
        r0 = float(rng.uniform(rad + 2, rows - rad - 2))
        c0 = float(rng.uniform(rad + 2, cols - rad - 2))
        q = ((rr - r0) ** 2 + (cc - c0) ** 2) / (rad * rad)
        crown = q < 1.0
        lo, hi = int(r0 - rad) - 2, int(r0 + rad) + 3
        lc, hc = int(c0 - rad) - 2, int(c0 + rad) + 3
        if labels[max(0, lo):hi, max(0, lc):hc].any():
            continue
        ht = float(rng.uniform(*height_m))
        z = terrain + ht * np.sqrt(np.clip(1.0 - q, 0.0, 1.0))
        surface[crown] = z[crown]
        labels[crown] = -1
        placed += 1


def vertical_cameras(scene, n=2, *, base_over_height=0.45, height_m=150.0, gsd_m=None,
                     direction=(1.0, 0.0), kappa_deg=0.0, margin_px=4):
    """Vertical frames along a base through the scene centre.

    Parameters
    ----------
    scene : OrthoScene
    n : int
        Number of frames (>= 2), equally spaced; the base between neighbours is
        ``base_over_height * height_m``.
    base_over_height : float
        B/H between neighbouring frames.
    height_m : float
        Flying height above the mean terrain.
    gsd_m : float, optional
        Ground sample distance at the mean terrain; default the cell size.
    direction : (float, float)
        Base direction in world (X, Y).
    kappa_deg : float
        Kappa of all frames.

    Returns
    -------
    list of Camera
        Frames large enough to cover the whole scene.
    """
    if n < 2:
        raise ValueError(f"n must be >= 2 frames for a stereo pair; got {n}.")
    gsd = scene.cell_size if gsd_m is None else float(gsd_m)
    zmean = float(np.mean(scene.terrain))
    zc = zmean + float(height_m)
    f = height_m / gsd
    X, Y = grid_xy(scene.terrain.shape, scene.transform)
    xc, yc = float(X.mean()), float(Y.mean())
    e = np.asarray(direction, float) / np.hypot(*direction)
    B = base_over_height * height_m
    offs = (np.arange(n) - (n - 1) / 2.0) * B
    zmin = float(scene.terrain.min())
    half = lambda d: d / (zc - zmin) * f + margin_px  # noqa: E731
    span_x = (float(X.max() - X.min()) / 2 + np.abs(offs * e[0]).max()) + 2 * scene.cell_size
    span_y = (float(Y.max() - Y.min()) / 2 + np.abs(offs * e[1]).max()) + 2 * scene.cell_size
    k = np.radians(kappa_deg)
    w_g = abs(span_x * np.cos(k)) + abs(span_y * np.sin(k))
    h_g = abs(span_x * np.sin(k)) + abs(span_y * np.cos(k))
    w = int(2 * np.ceil(half(w_g))) + 1
    h = int(2 * np.ceil(half(h_g))) + 1
    io = Interior(w, h, f, f, (w - 1) / 2.0, (h - 1) / 2.0, name="synthetic")
    return [Camera.vertical(io, xc + o * e[0], yc + o * e[1], zc, kappa_deg, name=f"frame{i}")
            for i, o in enumerate(offs)]


def render_frame(scene, camera, *, noise=1.0, seed=0, dz_m=None, bisections=10):
    """Image of ``scene`` seen by ``camera`` (ray casting on the surface, texture albedo).

    Every pixel's ray is followed down from above the highest surface point in height
    steps of ``dz_m`` until it is below the surface, then the crossing is found by
    bisection; the pixel takes the texture at the crossing. Rays that miss the grid are NaN.

    Parameters
    ----------
    noise : float
        Standard deviation of added Gaussian image noise (grey levels).
    dz_m : float, optional
        Height step of the march; default a quarter cell.
    """
    io = camera.interior
    rows, cols = np.indices((io.height, io.width), dtype=float)
    d = camera.pixel_to_ray(cols.ravel(), rows.ravel())            # (3, N)
    if np.any(d[2] >= 0):
        raise ValueError("render_frame needs a camera looking down at every pixel.")
    surf = scene.surface.astype(np.float64)
    x0, dx, _, y0, _, ndy = scene.transform
    dy = -ndy
    C = camera.centre
    zmax, zmin = float(np.nanmax(surf)) + 0.01, float(np.nanmin(surf)) - 0.01
    dz = 0.25 * min(dx, dy) if dz_m is None else float(dz_m)

    def sample(z):
        t = (z - C[2]) / d[2]
        X = C[0] + t * d[0]
        Y = C[1] + t * d[1]
        c = (X - x0) / dx - 0.5
        r = (y0 - Y) / dy - 0.5
        s = ndimage.map_coordinates(surf, [r, c], order=1, mode="nearest")
        inside = (c >= -0.5) & (c <= surf.shape[1] - 0.5) & (r >= -0.5) & (r <= surf.shape[0] - 0.5)
        return s, X, Y, inside

    n = d.shape[1]
    hi = np.full(n, zmax)                     # last level above the surface
    lo = np.full(n, np.nan)                   # first level below
    z = zmax
    while z > zmin - dz:
        z -= dz
        todo = np.isnan(lo)
        if not todo.any():
            break
        s, _, _, _ = sample(z)
        below = todo & (z <= s)
        lo[below] = z
        hi[todo & ~below] = z
    lo = np.where(np.isnan(lo), zmin, lo)
    for _ in range(bisections):
        mid = 0.5 * (hi + lo)
        s, _, _, _ = sample(mid)
        above = mid > s
        hi = np.where(above, mid, hi)
        lo = np.where(above, lo, mid)
    _, X, Y, inside = sample(0.5 * (hi + lo))
    img = scene.albedo(X, Y)
    if noise:
        img = img + np.random.default_rng(seed).normal(0, noise, img.shape)
    img = np.where(inside, img, np.nan)
    return img.reshape(io.height, io.width).astype(np.float32)


def imaged_in_both(scene, cameras, orthos):
    """Object cells whose surface point appears on the grid in both orthophotos (truth for scoring).

    An orthophoto made on the terrain shows a roof point ``P`` where the ray from the camera
    through ``P`` meets the terrain (taken at the terrain height of ``P``); near the edge of
    the grid that place can lie off the grid (at B/H 0.6 a 14 m roof moves by up to 18
    cells), and no matcher can measure ``P`` there.

    Parameters
    ----------
    scene : OrthoScene
    cameras : sequence of Camera
    orthos : sequence of ndarray
        The orthophotos of ``cameras`` on the scene's terrain (NaN = unseen).

    Returns
    -------
    ndarray of bool
    """
    X, Y = grid_xy(scene.terrain.shape, scene.transform)
    X, Y = np.broadcast_to(X, scene.terrain.shape), np.broadcast_to(Y, scene.terrain.shape)
    x0, dx, _, y0, _, ndy = scene.transform
    ok = scene.labels != 0
    for cam, ortho in zip(cameras, orthos):
        C = np.asarray(cam.centre, float)
        s = (C[2] - scene.terrain) / (C[2] - scene.surface)
        c = np.floor((C[0] + (X - C[0]) * s - x0) / dx).astype(int)
        r = np.floor((y0 - (C[1] + (Y - C[1]) * s)) / -ndy).astype(int)
        on = (c >= 0) & (c < scene.terrain.shape[1]) & (r >= 0) & (r < scene.terrain.shape[0])
        ok &= on
        ok[ok] &= np.isfinite(ortho[r[ok], c[ok]])
    return ok


def render_frames(scene, cameras, *, noise=1.0, seed=0, dz_m=None):
    """:func:`render_frame` for every camera (different noise per frame, grey levels sd)."""
    return [render_frame(scene, c, noise=noise, seed=seed + i, dz_m=dz_m) for i, c in enumerate(cameras)]
