"""Eq. 17: the 8-parameter bilinear transformation, registration, tie-point refinement."""
import numpy as np
import pytest
from scipy import ndimage

from bare_earth.core.codes import NODATA
from bare_earth.core.orthophoto.affine8 import Bilinear8, fit_bilinear8, register_orthophoto
from bare_earth.core.orthophoto.iterate import orthorefine
from bare_earth.core.orthophoto.orthorectify import grid_xy, orthorectify
from bare_earth.core.orthophoto.render import make_ortho_scene, render_frames, vertical_cameras


def test_fit_recovers_an_exact_bilinear_transform():
    true = Bilinear8(np.array([10.0, 50.0, -3.0, 0.7]), np.array([-4.0, 2.0, 45.0, -0.4]),
                     (1000.0, 5000.0), 100.0)
    rng = np.random.default_rng(0)
    P = rng.uniform([900, 4900], [1100, 5100], (9, 2))
    Q = np.column_stack(true.apply(P[:, 0], P[:, 1]))
    fit = fit_bilinear8(P, Q)
    X, Y = rng.uniform(900, 1100, 50), rng.uniform(4900, 5100, 50)
    np.testing.assert_allclose(np.column_stack(fit.apply(X, Y)), np.column_stack(true.apply(X, Y)),
                               atol=1e-8)
    assert fit.rmse < 1e-9
    # four points fit exactly (8 equations, 8 unknowns)
    fit4 = fit_bilinear8(P[:4], Q[:4])
    np.testing.assert_allclose(np.column_stack(fit4.apply(P[:4, 0], P[:4, 1])), Q[:4], atol=1e-8)


def test_fit_errors():
    P = np.array([[0.0, 0], [1, 0], [0, 1]])
    with pytest.raises(ValueError, match="at least four"):
        fit_bilinear8(P, P)
    line = np.array([[0.0, 0], [1, 1], [2, 2], [3, 3], [4, 4]])
    with pytest.raises(ValueError, match="collinear"):
        fit_bilinear8(line, line)
    with pytest.raises(ValueError, match="same n"):
        fit_bilinear8(np.zeros((5, 2)), np.zeros((4, 2)))


def test_register_and_refine_without_orientation():
    sc = make_ortho_scene(seed=1)
    cams = vertical_cameras(sc, 2, base_over_height=0.45)
    imgs = render_frames(sc, cams)
    orthos = [orthorectify(im, c, sc.terrain, sc.transform)[0] for im, c in zip(imgs, cams)]
    X, Y = grid_xy(sc.terrain.shape, sc.transform)
    # each orthophoto in its own pixel grid: an affine (a special eq. 17) of the DEM grid
    own, ties = [], []
    for k, o in enumerate(orthos):
        ang = np.radians(3.0 + 4 * k)
        A = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]]) * 1.25
        off = np.array([12.0 + 5 * k, 9.0])
        # DEM cell (c, r) -> own pixel (col, row) = A @ (c, r) + off; build the own image
        h, w = 230, 300
        rr, cc = np.indices((h, w), dtype=float)
        inv = np.linalg.inv(A)
        src = np.tensordot(inv, np.stack([cc - off[0], rr - off[1]]), axes=1)
        img = ndimage.map_coordinates(np.nan_to_num(o, nan=np.nan), [src[1], src[0]], order=1,
                                      mode="constant", cval=np.nan)
        own.append(img)
        # ground points: DEM map (X, Y) and own pixel (col, row)
        cells = np.array([[10, 10], [180, 15], [20, 150], [190, 140], [100, 80]], float)
        pix = cells @ A.T + off
        dem_xy = np.column_stack([X[0, 0] + cells[:, 0] * sc.cell_size, Y[0, 0] - cells[:, 1] * sc.cell_size])
        ties.append((dem_xy, pix))
    reg = register_orthophoto(own[0], fit_bilinear8(*ties[0]), sc.terrain.shape, sc.transform)
    ok = np.isfinite(reg) & np.isfinite(orthos[0])
    assert ok.mean() > 0.5
    assert np.corrcoef(reg[ok], orthos[0][ok])[0, 1] > 0.97
    B = float(cams[1].centre[0] - cams[0].centre[0])
    H = float(cams[0].centre[2] - np.mean(sc.terrain))
    r = orthorefine(sc.terrain, sc.transform, own, None, tie_points=ties, base_m=B, height_m=H)
    assert len(r.table) == 1 and "eq. 17" in r.info["mode"]
    true_dh = sc.surface - sc.terrain
    seen = r.mask != NODATA
    for k in sc.heights:
        m = (sc.labels == k) & seen
        if m.sum() > 50:
            assert np.nanmedian(r.dh[m]) == pytest.approx(np.median(true_dh[m]), rel=0.2)
    with pytest.raises(ValueError, match="tie_points"):
        orthorefine(sc.terrain, sc.transform, own, None)
