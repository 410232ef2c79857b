"""Orthophoto refinement on real oriented frames (orthority test data).

1. Drone (OpenDroneMap / OpenSfM, four oblique DJI frames, 1368 x 912): interior
   orientation (Brown) from ``opensfm/reconstruction.json``, exterior orientation from
   ``io/odm_xyz_opk.csv`` (UTM 51N). The 0.8 m photogrammetric DSM is smoothed with a 10 m
   Gaussian (sigma 10 m) and orthorefine (Norvelle 1995; Luong Chinh Ke 2002 section 2.3)
   is started from it; RMSE against the DSM on the cells seen by at least two frames
   (visibility on the DSM), before and after; then started from the DSM itself (made from
   these frames, so it should barely move): how far cells move and the roughness.
2. NGI (four vertical DMC frames in two strips, GSD about 5.7 m, H about 4,750 m): the 24 m
   DEM as it is and resampled (bilinear) to a 12 m grid; RMS residual parallax of the
   pairs' trusted matches on the start DEM and on the final DEM (orthorefine's checking
   measurement), the roughness (Laplacian sd) before and after, on all the cells seen by two
   and without the confirmed detail (regions two pairs agree on, their taper and the
   Laplacian's stencil), and how far cells moved against the data-supported bound
   (``RefineResult.supported``) and ``--ngi-max-dh``; ``--held-out``: refined with the pairs of one base
   direction and checked by the others (is the roughness it adds in the images?);
   ``--cross-check``: orthorefine(cross_check=True), a correction kept only where the pair
   families agree; with ``--held-out`` each family is held out in turn, the others refine
   plain and cross-checked.

    /usr/bin/python3 benchmarks/ortho_real.py [--data DIR] [--iterations 3] [--ngi-cell 24 12] [--held-out]
        [--cross-check] [--skip-drone]

Data credits: see ``stereo/PROVENANCE.md`` (orthority, AGPL-3.0; imagery and DEM of NGI,
the CGA Stellenbosch, Yu-Huang Wang / OpenDroneMap community). Skips when absent.
"""
import argparse
import sys
import time
import warnings

import numpy as np
from _common import data_dir, setup_path
from scipy import ndimage

setup_path()
from bare_earth.core.orthophoto import (  # noqa: E402
    cameras_from_opk,
    orthorectify,
    orthorefine,
    pair_families,
    read_interior_yaml,
    read_opensfm_reconstruction,
    read_opk_csv,
)
from bare_earth.core.orthophoto.smoothness import roughness_cells, roughness_sd  # noqa: E402

#: orthorefine's not_rougher in this run (``--rougher``: False)
NOT_ROUGHER = True


def _read(path):
    from osgeo import gdal
    ds = gdal.Open(str(path))
    if ds is None:
        raise SystemExit(f"cannot open {path}")
    return ds.ReadAsArray().astype(np.float32), ds.GetGeoTransform()


def _table(table):
    for t in table:
        extra = f", RMSE vs DSM {t['rmse_reference_m']:.2f} m" if "rmse_reference_m" in t else ""
        print(f"      measurement {t['iteration']} ({t.get('status', '')}): RMS correction "
              f"{t['rms_correction_m']:.2f} m, trusted {100 * t['matched_share']:.0f} % of cells seen by two, "
              f"{t['pairs']} pairs, RMS parallax {t['rms_parallax_m']:.2f} m, agreement "
              f"{t.get('agreement', float('nan')):.3f}, mean NCC {t['mean_corr']:.3f}{extra}"
              + (f", smoothness mu {t['smoothness_mu']:.3g}, roughness after {t['roughness_m']:.5f} m"
                 if t.get("status") == "applied" else ""))


def drone(root, iterations):
    d = root / "odm"
    dsm, gt = _read(d / "odm_dem" / "dsm.tif")
    ios, _, _ = read_opensfm_reconstruction(d / "opensfm" / "reconstruction.json")
    ext = read_opk_csv(root / "io" / "odm_xyz_opk.csv")
    names = sorted(ext)
    cams = cameras_from_opk(ext, ios, names)
    imgs = [_read(d / "images" / f"{n}.tif")[0] for n in names]
    ok = np.isfinite(dsm)
    s = 10.0 / gt[1]
    with np.errstate(invalid="ignore", divide="ignore"):
        start = (ndimage.gaussian_filter(np.where(ok, dsm, 0), s)
                 / ndimage.gaussian_filter(ok.astype(np.float64), s))
    start = np.where(ok, start, np.nan).astype(np.float32)
    seen = [orthorectify(im, c, dsm, gt)[1] for im, c in zip(imgs, cams)]
    ev = (np.sum(seen, axis=0) >= 2) & ok
    t = time.perf_counter()
    r = orthorefine(start, gt, imgs, cams, max_iterations=iterations, reference=dsm, reference_cells=ev,
                    not_rougher=NOT_ROUGHER)
    dt = time.perf_counter() - t
    e0 = float(np.sqrt(np.mean((start - dsm)[ev] ** 2)))
    e1 = float(np.sqrt(np.mean((r.dem - dsm)[ev] ** 2)))
    m0 = float(np.mean(np.abs(start - dsm)[ev]))
    m1 = float(np.mean(np.abs(r.dem - dsm)[ev]))
    print(f"1. drone, {len(imgs)} frames {imgs[0].shape[-1]}x{imgs[0].shape[-2]}, DSM {dsm.shape[1]}x"
          f"{dsm.shape[0]} at {gt[1]:.2f} m, start = DSM smoothed (Gaussian sigma 10 m)")
    print(f"   cells seen by >= 2 frames: {int(ev.sum())}; pairs {r.info['pairs']}")
    print(f"   RMSE vs DSM {e0:.2f} m -> {e1:.2f} m (reduction {100 * (1 - e1 / e0):.1f} %); "
          f"mean |error| {m0:.2f} -> {m1:.2f} m; {r.info['iterations']} update(s) kept, {len(r.table)} "
          f"measurements in {dt:.1f} s; stop: {r.info['stop']}")
    _table(r.table)
    # a DSM made from these frames is already right: refinement started from it should barely
    # move it (the issue measured 1.05 m RMS) and must not roughen it
    t = time.perf_counter()
    r2 = orthorefine(dsm, gt, imgs, cams, max_iterations=iterations, not_rougher=NOT_ROUGHER)
    dt = time.perf_counter() - t
    mv = (r2.dem - dsm)[ev]
    sig = r2.info["sigma_expected_m"]
    q0, q1 = _roughness(dsm, ev), _roughness(r2.dem, ev)
    print(f"   started from the DSM itself: cells moved RMS {np.sqrt(np.mean(mv ** 2)):.2f} m, "
          f"mean {mv.mean():+.2f} m, "
          f"{100 * np.mean(np.abs(mv) > 3 * sig):.1f} % by more than 3 x the expected precision ({3 * sig:.2f} m), "
          f"max {np.abs(mv).max():.1f} m; roughness {q0:.3f} -> {q1:.3f} m; {r2.info['iterations']} update(s) kept, "
          f"{len(r2.table)} measurements in {dt:.1f} s; stop: {r2.info['stop']}")
    _table(r2.table)
    return e1 < e0 and q1 <= q0


def _roughness(z, ev):
    """Laplacian sd of a surface on the cells ``ev`` eroded by two (m per cell^2): speckle raises it
    (the measure orthorefine's smoothness step keeps from rising, :mod:`.smoothness`)."""
    return roughness_sd(z, roughness_cells(ev))


def ngi(root, iterations, cell, max_dh_m, held_out=False, cross_check=False):
    dem24, gt24 = _read(root / "ngi" / "dem.tif")
    if cell == gt24[1]:
        dem, gt = dem24, gt24
    else:
        f = gt24[1] / cell
        rows, cols = int(dem24.shape[0] * f), int(dem24.shape[1] * f)
        rr, cc = np.indices((rows, cols), dtype=np.float64)
        dem = ndimage.map_coordinates(dem24, [(rr + 0.5) / f - 0.5, (cc + 0.5) / f - 0.5], order=1,
                                      mode="nearest").astype(np.float32)
        gt = (gt24[0], cell, 0.0, gt24[3], 0.0, -cell)
    ios = read_interior_yaml(root / "io" / "ngi_int_param.yaml")
    ext = read_opk_csv(root / "io" / "ngi_xyz_opk.csv")
    names = sorted(ext)
    cams = cameras_from_opk(ext, ios, names)
    imgs = [_read(root / "ngi" / f"{n}.tif")[0] for n in names]
    t = time.perf_counter()
    r = orthorefine(dem, gt, imgs, cams, max_iterations=iterations, max_dh_m=max_dh_m, cross_check=cross_check,
                    not_rougher=NOT_ROUGHER)
    dt = time.perf_counter() - t
    # the cells seen by two frames on the start DEM: the same cells for every build
    ev = (np.sum([orthorectify(im, c, dem, gt)[1] for im, c in zip(imgs, cams)], axis=0) >= 2) & np.isfinite(dem)
    p0, p1 = r.info["rms_parallax_start_m"], r.info["rms_parallax_m"]
    moved = np.abs(r.dem - dem)[ev]
    moved_max = float(np.nanmax(np.abs(r.dem - dem)))      # over the whole DEM
    l0, l1 = _roughness(dem, ev), _roughness(r.dem, ev)
    print(f"2. NGI, {len(imgs)} frames, DEM {gt24[1]:g} m" + (f" resampled to {cell:g} m" if cell != gt24[1] else "")
          + f" ({dem.shape[1]}x{dem.shape[0]}); pairs {r.info['pairs']}; max_dh_m {max_dh_m:g}")
    print(f"   RMS residual parallax {p0:.2f} m -> {p1:.2f} m on the final DEM (reduction "
          f"{100 * (1 - p1 / p0):.1f} %); {r.info['iterations']} update(s) kept, {len(r.table)} measurements, "
          f"{dt:.1f} s; stop: {r.info['stop']}")
    print(f"   roughness (Laplacian sd, cells seen by two on the start DEM) {l0:.5f} -> {l1:.5f} m; cells moved: RMS "
          f"{np.sqrt(np.mean(moved ** 2)):.2f} m, 99.9 % {np.percentile(moved, 99.9):.1f} m, max {moved_max:.1f} m "
          f"(bound {max_dh_m:g} m); warning: {r.info['warning'] or 'none'}")
    # the correction's own curvature, and how it goes with the start's (0: independent, so the
    # variances add; > 0: it deepens the start's valleys and raises its ridges)
    inner = ev & ndimage.binary_erosion(ev, iterations=2)
    lap_c = ndimage.laplace(np.nan_to_num(r.dem - dem).astype(np.float64))[inner]
    lap_0 = ndimage.laplace(np.nan_to_num(dem).astype(np.float64))[inner]
    print(f"   the correction's Laplacian: sd {lap_c.std():.3f} m, correlation with the start's "
          f"{np.corrcoef(lap_c, lap_0)[0, 1]:+.3f}")
    # the roughness where no confirmed detail was applied: without the regions of detail two
    # pairs agree on, their taper (half the window plus one cell) and the Laplacian's stencil
    near = ndimage.binary_dilation(r.detail, iterations=r.info["window"] // 2 + 2) if r.detail.any() else r.detail
    rest = ev & ~near
    s0, s1 = _roughness(dem, rest), _roughness(r.dem, rest)
    over = np.abs(r.dem - dem) - r.supported
    print(f"   confirmed detail: {int(r.detail.sum())} cells; roughness without them and {r.info['window'] // 2 + 2} "
          f"cells around ({100 * rest.sum() / ev.sum():.1f} % of the cells) {s0:.5f} -> {s1:.5f} m "
          f"({100 * (s1 / s0 - 1):+.3f} %); whole {100 * (l1 / l0 - 1):+.3f} %")
    print(f"   data-supported bound of a cell's move (per update the certainty-weighted mean magnitude of the "
          f"trusted corrections around it plus the largest kept detail within the fill's reach; summed over "
          f"the kept updates): largest {r.info['supported_max_m']:.1f} m, median "
          f"{np.nanmedian(r.supported[ev]):.1f} m; cells beyond it {int(np.nansum(over > 1e-3))}")
    print(f"   cross-check of the pair families: {r.info['cross_check']}")
    _rise_where_agreement(r, dem, ev)
    _speckle_and_local_proof(r, dem, ev)
    _table(r.table)
    if held_out:
        _held_out(dem, gt, imgs, cams, r.info["pairs"], iterations, max_dh_m, ev, cross_check)
    return p1 < p0 and l1 <= l0 and moved_max <= max_dh_m + 1e-3 and not np.nansum(over > 1e-3)


def _held_out(dem, gt, imgs, cams, pairs, iterations, max_dh_m, ev, cross_check=False):
    """Is the roughness the refinement adds terrain? Refine with some pairs, check with the others.

    The pairs are split by the direction of their base (:func:`pair_families`). Without
    ``cross_check``: the first family (along the strip) against all the others. With it,
    every family in turn is held out and the refinement uses the other families (two or more
    are needed to cross-check, so three base directions), plain and cross-checked. The held-out
    pairs measure each refined DEM next to the start DEM: their RMS residual parallax, and
    their first update on the 1 % of cells the refinement moved most. A change the held-out
    pairs also measure on the start DEM, and no longer on the refined one, is in the images,
    not speckle of the pairs that made it.
    """
    fam = pair_families([k.centre for k in cams], pairs)
    if max(fam) == 0:
        print("   held-out check: all pairs have one base direction; skipped")
        return
    if cross_check:
        if max(fam) < 2:
            print("   held-out check of the cross-check: needs three base directions (two to cross-check, "
                  "one to hold out); skipped")
            return
        splits = [([p for p, f in zip(pairs, fam) if f != g], [p for p, f in zip(pairs, fam) if f == g])
                  for g in range(max(fam) + 1)]
    else:
        fams = [[p for p, f in zip(pairs, fam) if f == 0], [p for p, f in zip(pairs, fam) if f != 0]]
        splits = [fams, fams[::-1]]
    for train, held in splits:
        runs = [(False, orthorefine(dem, gt, imgs, cams, max_iterations=iterations, max_dh_m=max_dh_m,
                                    pairs=train))]
        if cross_check:
            runs.append((True, orthorefine(dem, gt, imgs, cams, max_iterations=iterations, max_dh_m=max_dh_m,
                                           pairs=train, cross_check=True)))
        h0 = orthorefine(dem, gt, imgs, cams, max_iterations=1, max_dh_m=max_dh_m, pairs=held)
        for checked, t in runs:
            move = t.dem - dem
            top = ev & (np.abs(move) >= np.percentile(np.abs(move[ev]), 99))
            words = []
            for name, z in (("start", dem), ("refined", t.dem)):
                h = h0 if name == "start" else orthorefine(z, gt, imgs, cams, max_iterations=1, max_dh_m=max_dh_m,
                                                            pairs=held)
                # the held-out update along the move, as a share of the move (1: they measure it all, 0: nothing)
                along = np.nanmean(np.sign(move[top]) * h.dh[top]) / np.mean(np.abs(move[top]))
                words.append(f"on the {name} DEM RMS parallax {h.table[0]['rms_parallax_m']:.3f} m and along the "
                             f"move {100 * along:+.0f} % of it")
            kind = "cross-checked, " if checked else ""
            print(f"   held-out check, refined with {train} ({kind}largest move {t.info['moved_max_m']:.1f} m, "
                  f"parallax {t.info['rms_parallax_start_m']:.3f} -> {t.info['rms_parallax_m']:.3f} m): "
                  f"roughness {_roughness(dem, ev):.4f} -> {_roughness(t.dem, ev):.4f} m, the 1 % of cells moved "
                  f"most by {np.mean(np.abs(move[top])):.1f} m (mean |move|); the pairs {held} measure "
                  + "; ".join(words))


def _speckle_and_local_proof(r, dem, ev):
    """Is the added roughness speckle, and does the pairs' agreement prove it cell by cell?

    Speckle: the move's departure from the median of its 3 x 3 neighbours, against 3 x the
    expected precision in height (a cell moved alone beyond the matching noise). Local proof:
    the fall of the squared residual parallax ``p0**2 - p1**2`` over the cells matched on the
    start and on the final DEM, averaged with the smooth part's Gaussian (sigma the window),
    against its standard error (the local sd of the fall, the Gaussian's effective count of
    cells and the matcher's window as the area over which cells share their pixels, W^2
    cells); the same over all those cells (the iteration rule's evidence). The rise of the
    summed squared Laplacian is split by the sign of the local fall.
    """
    move = np.where(np.isfinite(r.dem - dem), r.dem - dem, 0.0).astype(np.float64)
    dep = np.abs(move - ndimage.median_filter(move, 3))[ev]
    sig = r.info["sigma_expected_m"]
    p0, p1 = r.parallax_start.astype(np.float64), r.parallax.astype(np.float64)
    both = np.isfinite(p0) & np.isfinite(p1)
    g = np.where(both, p0 ** 2 - p1 ** 2, 0.0)
    w = float(r.info["window"])
    den = ndimage.gaussian_filter(both.astype(np.float64), w, mode="constant")
    ok = ev & (den > 1e-3)
    mean = ndimage.gaussian_filter(g, w, mode="constant") / np.maximum(den, 1e-12)
    var = np.maximum(ndimage.gaussian_filter(g * g, w, mode="constant") / np.maximum(den, 1e-12) - mean ** 2, 0.0)
    # effective count of a normalised Gaussian: (sum w)^2 / sum w^2, with sum w^2 the Gaussian of
    # sigma / sqrt(2) over 4 pi sigma^2
    w2 = ndimage.gaussian_filter(both.astype(np.float64), w / np.sqrt(2.0), mode="constant") / (4 * np.pi * w * w)
    z = mean / np.sqrt(np.maximum(var * w * w / np.maximum(den ** 2 / np.maximum(w2, 1e-12), 1e-12), 1e-12))
    gb = g[both & ev]
    z_all = gb.mean() / (gb.std() * np.sqrt(w * w / gb.size))
    def lap(s):
        return ndimage.laplace(np.where(np.isfinite(s), s, np.nanmedian(s)).astype(np.float64))
    rise = ndimage.uniform_filter(lap(r.dem) ** 2 - lap(dem) ** 2, 3)    # as _rise_where_agreement
    inner = ev & ndimage.binary_erosion(ev, iterations=2)
    z = np.where(ok, z, 0.0)
    print(f"   speckle: the move departs from its 3 x 3 median by {np.percentile(dep, 99):.2f} m (99 %), "
          f"{dep.max():.2f} m at most; {int(np.sum(dep > 3 * sig))} cells beyond 3 x the expected precision "
          f"({3 * sig:.2f} m)")
    print("   local proof (fall of the squared parallax over the smooth part's scale / its standard error): "
          + ", ".join(f"z > {k}: {100 * np.mean(z[ok] > k):.1f} %" for k in (0, 1, 2, 3))
          + f" of the cells; over all the cells matched both times z = {z_all:.1f}; rise of the summed squared "
          f"Laplacian where z > 0 {rise[inner & (z > 0)].sum():+.0f} m^2, elsewhere "
          f"{rise[inner & ~(z > 0)].sum():+.0f} m^2")


def _rise_where_agreement(r, dem, ev):
    """Where the DEM gained roughness: on cells whose pairs agree better after the refinement or not.

    The rise of the squared Laplacian (averaged over its 3 x 3 stencil) is summed over the cells
    matched on the start and on the final DEM whose residual parallax fell, those where it did
    not, and the cells not matched both times. Roughness the pairs confirm (a true step the DEM
    lacked) lies on the first; speckle the pairs do not confirm on the others.
    """
    def lap(z):
        return ndimage.laplace(np.where(np.isfinite(z), z, np.nanmedian(z)).astype(np.float64))
    inner = ev & ndimage.binary_erosion(ev, iterations=2)
    rise = ndimage.uniform_filter(lap(r.dem) ** 2 - lap(dem) ** 2, 3)
    p0, p1 = r.parallax_start, r.parallax
    both = np.isfinite(p0) & np.isfinite(p1)
    parts = {"agree better": inner & both & (p1 < p0), "agree no better": inner & both & ~(p1 < p0),
             "not matched both times": inner & ~both}
    total = float(rise[inner].sum())
    words = []
    for name, m in parts.items():
        extra = ""
        if name != "not matched both times" and m.any():
            extra = (f", RMS parallax {np.sqrt(np.mean(p0[m] ** 2)):.2f} -> {np.sqrt(np.mean(p1[m] ** 2)):.2f} m")
        words.append(f"{name} {100 * m.sum() / inner.sum():.0f} % of the cells, {rise[m].sum():+.0f} m^2{extra}")
    print(f"   rise of the summed squared Laplacian {total:+.0f} m^2: " + "; ".join(words))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", default=None)
    ap.add_argument("--iterations", type=int, default=3)
    ap.add_argument("--ngi-cell", type=float, nargs="*", default=[24.0, 12.0])
    ap.add_argument("--ngi-max-dh", type=float, default=60.0,
                    help="largest height change of a cell (m): twice the tallest buildings of the "
                         "Stellenbosch frames (about 30 m), far above the 24 m DEM's own error")
    ap.add_argument("--held-out", action="store_true",
                    help="NGI: refine with the pairs of one base direction, check with the others")
    ap.add_argument("--cross-check", action="store_true",
                    help="NGI: orthorefine(cross_check=True), a correction kept only where the pair families agree")
    ap.add_argument("--skip-drone", action="store_true", help="NGI only")
    ap.add_argument("--rougher", action="store_true",
                    help="orthorefine(not_rougher=False): the unconfirmed smooth part applied as measured")
    a = ap.parse_args(argv)
    global NOT_ROUGHER
    NOT_ROUGHER = not a.rougher
    root = data_dir(a.data) / "stereo" / "orthority"
    if not root.is_dir():
        print(f"SKIP: {root} is absent (set BARE_EARTH_DATA)")
        return 0
    warnings.simplefilter("ignore", RuntimeWarning)
    ok = True if a.skip_drone else drone(root, a.iterations)
    for cell in a.ngi_cell:
        ok &= ngi(root, a.iterations, cell, a.ngi_max_dh, a.held_out, a.cross_check)
    print("ALL CHECKS MET" if ok else "SOME CHECK MISSED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
