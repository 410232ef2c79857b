"""Orthorectification: invalid image pixels mask exactly the cells that draw on them."""
import numpy as np
from scipy import ndimage

from bare_earth.core.orthophoto.camera import Camera, Interior
from bare_earth.core.orthophoto.orthorectify import grid_xy, orthorectify


def test_orthophoto_masks_cells_drawing_on_invalid_pixels():
    """A cell is NaN exactly when a bad pixel weighs > 0.01 in its bilinear sample (the mask is
    interpolated only near bad pixels; elsewhere it is exactly 0)."""
    io = Interior(201, 201, 400.0, 400.0, 100.0, 100.0)
    cam = Camera.from_opk(io, 50.0, 50.0, 300.0, 3.0, -4.0, 20.0)
    rows, cols = np.indices((io.height, io.width))
    image = (np.sin(rows * 0.37) + np.cos(cols * 0.23)).astype(np.float32)
    rng = np.random.default_rng(2)
    image[rng.random(image.shape) < 0.01] = np.nan
    image[60:80, 90:130] = np.nan
    transform = (0.0, 1.0, 0.0, 100.0, 0.0, -1.0)
    X, Y = grid_xy((100, 100), transform)
    dem = (20 + 0.1 * X + 0.05 * Y) * np.ones((100, 1))
    ortho, seen = orthorectify(image, cam, dem, transform, occlusion=False)
    col, row = cam.project(X, Y, dem)
    inside = (col >= -0.5) & (col <= 200.5) & (row >= -0.5) & (row <= 200.5)
    rr, cc = np.clip(row[inside], 0, 200), np.clip(col[inside], 0, 200)
    hit = ndimage.map_coordinates(np.isnan(image).astype(np.float32), [rr, cc], order=1, mode="nearest") > 0.01
    assert 0.02 < hit.mean() < 0.5
    np.testing.assert_array_equal(np.isnan(ortho[inside]), hit)
    np.testing.assert_array_equal(seen[inside], ~hit)
