"""A whole survey of tiles on Dask (core.survey): seamless masks, real clusters, resume, refusals.

The survey is a 288 x 288 synthetic city cut into 3 x 3 tiles of 96 x 96 cells; the
single pass over the mosaic (``pipeline.run_array`` with the survey's resolved parameters)
is the reference.
"""
import dataclasses
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed", reason="Dask distributed is not installed (scripts/setup.sh installs it)")

from bare_earth.core import grid, pipeline  # noqa: E402
from bare_earth.core.methods import available_methods, get_method  # noqa: E402
from bare_earth.core.survey import index_tiles, list_inputs, output_names, parse_params, plan, run_survey  # noqa: E402
from bare_earth.core.survey import io as survey_io  # noqa: E402
from bare_earth.core.synthetic import make_scene  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
PY = "/usr/bin/python3" if os.path.exists("/usr/bin/python3") else sys.executable
TILE = 96
#: Parameters that keep each method's halo below the tile side where the method's halo is
#: exact for them (so the windows really cut through the neighbours); the others use the
#: defaults (curvature's halo is exact for objects up to max_object_size_m only).
SMALL = {"slopeprofile": {"max_object_size_m": 20.0}, "geodesic": {"max_object_size_m": 8.0},
         "morphological": {"max_object_size_m": 16.0}}


def write_survey(folder, scene, tile=TILE, epsg=None, names=None):
    """Cut ``scene.dsm`` into tiles of ``tile`` cells written as GeoTIFFs (nodata -9999)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    gt = scene.geotransform
    rows, cols = scene.dsm.shape
    paths = []
    for i in range(0, rows, tile):
        for j in range(0, cols, tile):
            a = scene.dsm[i:i + tile, j:j + tile]
            g = (gt[0] + j * gt[1], gt[1], 0.0, gt[3] + i * gt[5], 0.0, gt[5])
            name = f"t{i // tile}{j // tile}"
            p = folder / f"{name}.tif"
            code = (epsg or {}).get(name, scene.epsg)
            grid.write_array(p, np.where(np.isfinite(a), a, -9999.0), g, code, nodata=-9999.0)
            paths.append(str(p))
    return paths


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    d = tmp_path_factory.mktemp("survey")
    sc = make_scene("city", shape=(3 * TILE, 3 * TILE), seed=3, nodata_holes=True)
    return {"scene": sc, "tiles": write_survey(d / "tiles", sc), "dir": d}


def read_mosaic(out_dir, kind):
    info = grid.open_dsm(os.path.join(out_dir, f"{kind}.vrt"))
    if kind == "mask":
        return info.dataset().GetRasterBand(1).ReadAsArray()
    return info.read()


def one_pass(method, scene, rec):
    """The single pass over the mosaic with the run's parameters (derived again from the whole
    mosaic, the survey's own sample when it is small: the same values)."""
    ref = pipeline.run_array(method, scene.dsm, scene.cell_size, rec["arguments"]["params"])
    same = [json.loads(json.dumps(p, default=float)) for p in (ref.info["params"], rec["params"])]
    assert same[0] == same[1]
    return ref


def done(rec):
    """The tiles recorded done."""
    return {k: v for k, v in rec["tiles"].items() if v["status"] == "done"}


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# -- planning -----------------------------------------------------------------------------------
def test_alignment_is_the_halos_power_of_two_at_least_64():
    assert plan.alignment(42) == 64
    assert plan.alignment(416) == 64          # 416 = 32 x 13
    assert plan.alignment(384) == 128         # geodesic-like halo, a multiple of 128
    assert plan.alignment(0) == 64


def test_tile_window_aligns_its_corner_and_keeps_the_tile():
    outer, core = plan.tile_window((96, 192, 192, 288), (288, 288), 42, align=64)
    assert outer == (0, 234, 128, 288)        # 96 - 42 = 54 -> 0; 192 - 42 = 150 -> 128; ends clipped
    a = np.arange(288 * 288).reshape(288, 288)
    win = a[outer[0]:outer[1], outer[2]:outer[3]]
    assert np.array_equal(win[core], a[96:192, 192:288])


def test_sample_is_the_whole_small_survey_and_spread_crops_of_a_large_one(survey):
    index = index_tiles(survey["tiles"])
    assert plan.sample_layout(index.tiles, 288 * 288) is None
    parts, shape = plan.sample_layout(index.tiles, 288 * 288, max_cells=2 * 40 * 40)
    # 9 tiles <= 16: every tile gives a central crop, laid 3 x 3 with nodata gutters between them
    assert len(parts) == 9
    side = parts[0][1][1] - parts[0][1][0]
    assert all(w[1] - w[0] == side and w[3] - w[2] == side for _t, w, _p in parts)
    assert shape == (3 * side + 2 * plan.SAMPLE_GUTTER,) * 2
    big = [t for t in index.tiles for _ in range(4)]          # 36 tiles: 16 spread ones chosen
    chosen = plan.sample_tiles(big)
    assert len(chosen) == 16 and len({t.name for t in chosen}) == 9


def test_sample_of_a_large_survey_takes_its_crops_where_the_data_is(tmp_path):
    """A large survey (5 x 5 tiles; sample limited to 6400 cells: crops of 12 x 12) whose 16 tiles chosen for the
    sample hold only nodata (-9999): their crops give way to the nearest tiles with data, and no nodata
    value reaches the sample. Before: the sample was all NaN and the survey was refused as holding no
    data, though 9 of its tiles hold heights."""
    from bare_earth.core.survey.run import read_sample
    tiles, gt = [], (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0)
    for i in range(5):
        for j in range(5):
            tiles.append((f"t{i}{j}", (gt[0] + 32 * j, 1.0, 0.0, gt[3] - 32 * i, 0.0, -1.0)))
    index = index_tiles([str(grid.write_array(tmp_path / f"{n}.tif", np.zeros((32, 32), np.float32), g, 32632,
                                              nodata=-9999.0)) for n, g in tiles])
    chosen = {t.name for t in plan.sample_tiles(index.tiles)}
    assert len(chosen) == 16
    heights = {}
    for k, (name, g) in enumerate(tiles):
        a = np.full((32, 32), -9999.0 if name in chosen else 100.0 + k, np.float32)
        a[:3, :3] = -9999.0
        grid.write_array(tmp_path / f"{name}.tif", a, g, 32632, nodata=-9999.0)
        if name not in chosen:
            heights[name] = 100.0 + k
    vrt = survey_io.build_vrt(tmp_path / "survey.vrt", [t.path for t in index.tiles], index.vrt_nodata)
    z, where = read_sample(index, grid.open_dsm(vrt), max_cells=16 * 20 * 20)
    values = set(np.unique(z[np.isfinite(z)]).tolist())
    assert values and values <= set(heights.values())            # heights only: no -9999, no empty crop
    assert len(values) == len(heights) == 9
    assert "replaced by the nearest with data" in where and all(n in where for n in heights)



def test_sample_crops_have_their_empty_cells_filled_and_the_gutters_stay_nodata(tmp_path):
    """The crops of a large survey's sample hold their tiles' heights with the empty cells enclosed by data
    filled, as the filters see them (a lowest-point grid's cells without a point); the nodata gutters
    between the crops are no empty cells to fill (they would join two crops by a false edge)."""
    from bare_earth.core.survey.run import read_sample
    rng = np.random.default_rng(0)
    tiles, gt = [], (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0)
    for i in range(5):
        for j in range(5):
            g = (gt[0] + 32 * j, 1.0, 0.0, gt[3] - 32 * i, 0.0, -1.0)
            a = (100.0 + 0.1 * rng.random((32, 32))).astype(np.float32)
            a[rng.random(a.shape) < 0.3] = -9999.0
            tiles.append(str(grid.write_array(tmp_path / f"t{i}{j}.tif", a, g, 32632, nodata=-9999.0)))
    index = index_tiles(tiles)
    vrt = survey_io.build_vrt(tmp_path / "survey.vrt", [t.path for t in index.tiles], index.vrt_nodata)
    z, where = read_sample(index, grid.open_dsm(vrt), max_cells=16 * 20 * 20)
    side, gut = 20 - plan.SAMPLE_GUTTER, plan.SAMPLE_GUTTER
    assert z.shape == (4 * side + 3 * gut,) * 2
    crops = np.zeros(z.shape, bool)
    for k in range(4):
        crops[k * (side + gut):k * (side + gut) + side, :] = True
    crops &= crops.T
    assert np.isfinite(z[crops]).mean() > 0.95 and np.isnan(z[~crops]).all()   # 30 % empty in the tiles
    assert ((z[crops & np.isfinite(z)] >= 100.0) & (z[crops & np.isfinite(z)] <= 100.1)).all()

def test_sample_of_small_tiles_far_apart_lays_their_crops_side_by_side(tmp_path):
    """Two 100 x 100 tiles 50 km apart (a survey grid of 2.5e9 cells, so a sample of crops): each crop was
    laid in a slot of 2040 cells, a sample of 2040 x 4088 cells 99.8 % nodata, where the noise was not
    measurable (morphological's noise_m NaN, its DH_M the fallback) though each tile gives 0.05 m."""
    from bare_earth.core.survey.run import read_sample
    sc = make_scene("city", shape=(200, 200), seed=5)
    z = sc.dsm.astype(np.float32)
    paths = [grid.write_array(tmp_path / "a.tif", z[:100, :100], (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0), 32632,
                              nodata=-9999.0),
             grid.write_array(tmp_path / "b.tif", z[100:, 100:], (550000.0, 1.0, 0.0, 5350000.0, 0.0, -1.0), 32632,
                              nodata=-9999.0)]
    index = index_tiles([str(p) for p in paths])
    parts, shape = plan.sample_layout(index.tiles, index.shape[0] * index.shape[1])
    assert shape == (100, 200 + plan.SAMPLE_GUTTER)
    assert [w for _t, w, _p in parts] == [t.window for t in index.tiles]
    vrt = survey_io.build_vrt(tmp_path / "survey.vrt", [t.path for t in index.tiles], index.vrt_nodata)
    zs, _where = read_sample(index, grid.open_dsm(vrt))
    assert np.array_equal(zs[:, :100], z[:100, :100]) and np.array_equal(zs[:, -100:], z[100:, 100:])
    noise = pipeline.resolve_params(get_method("morphological"), zs, (1.0, 1.0), {})["noise_m"]
    assert 0.04 < noise < 0.06


# -- checks before any work --------------------------------------------------------------------
def test_index_places_tiles_on_the_survey_grid(survey):
    index = index_tiles(survey["tiles"][::-1])            # any order in, reading order out
    assert index.shape == (288, 288)
    assert [t.name for t in index.tiles] == [f"t{i}{j}" for i in range(3) for j in range(3)]
    assert index.tiles[5].window == (96, 192, 192, 288)
    assert list_inputs(os.path.dirname(survey["tiles"][0])) == sorted(survey["tiles"])


def test_mixed_crs_refused_naming_the_tile(tmp_path):
    sc = make_scene("flat", shape=(64, 64), seed=1)
    paths = write_survey(tmp_path, sc, tile=32, epsg={"t11": 32633})
    with pytest.raises(ValueError, match=r"different CRSs: t11\.tif \(EPSG:32633\)"):
        index_tiles(paths)
    with pytest.raises(ValueError, match="t11.tif"):
        run_survey("slopeprofile", paths, tmp_path / "out", workers=1)
    assert not (tmp_path / "out").exists()                # refused before any work
    # a tile without a CRS is given one, not reprojected (before: 'Reproject them to one CRS')
    g = grid.open_dsm(paths[3]).geotransform
    bare = tmp_path / "bare.tif"
    grid.write_array(bare, grid.open_dsm(paths[3]).read(), g, "")
    with pytest.raises(ValueError, match=r"bare\.tif \(no CRS\) differ .* their CRS \(gdal_edit\.py -a_srs\)"):
        index_tiles(paths[:3] + [str(bare)])


def test_missing_vrt_source_refused_naming_the_tile(tmp_path):
    from osgeo import gdal
    sc = make_scene("flat", shape=(64, 64), seed=1)
    paths = write_survey(tmp_path, sc, tile=32)
    gdal.BuildVRT(str(tmp_path / "mosaic.vrt"), paths)
    os.remove(paths[2])
    with pytest.raises(ValueError, match=r"1 tile\(s\) are missing: t10\.tif\. Restore them or rebuild the VRT"):
        index_tiles(str(tmp_path / "mosaic.vrt"))
    # tiles named one by one (no VRT): the message spoke of rebuilding a VRT
    with pytest.raises(ValueError, match=r"2 tile\(s\) are missing: t10\.tif, gone\.tif\. No such file "
                                         r"\(.*t10\.tif\): check the paths\.$"):
        index_tiles([paths[0], paths[2], str(tmp_path / "gone.tif")])


def test_tiles_in_gdal_memory_or_virtual_files_refused_saying_why(tmp_path):
    """QA 20: a tile in GDAL's memory (/vsimem/, a layer a script made there) was reported "1 tile(s) are missing
    ... No such file: check the path", though it exists (in this process alone, which the survey's workers cannot
    read); a /vsicurl/ tile the same, its URL's // folded by abspath. Refused now saying where the tile lives and
    what to do: given directly, as a folder, or as a VRT's sources."""
    from osgeo import gdal
    sc = make_scene("flat", shape=(64, 64), seed=1)
    paths = write_survey(tmp_path, sc, tile=32)
    mem = [f"/vsimem/qa20_{i}.tif" for i in range(2)]
    try:
        for src, dst in zip(paths, mem):
            gdal.Translate(dst, src)
        vrt = str(tmp_path / "mem.vrt")
        gdal.BuildVRT(vrt, mem).FlushCache()
        for given in (mem, "/vsimem/", vrt):
            with pytest.raises(ValueError, match=r"the tile '/vsimem/.*' .*lives in this process's memory \(GDAL's "
                                                 r"/vsimem/\), which the survey's worker processes cannot read: save"):
                index_tiles(given)
        with pytest.raises(ValueError, match=r"the tile '/vsicurl/https://example\.com/t00\.tif' is a GDAL virtual "
                                             r"file \(vsicurl\), not a file on disk"):
            index_tiles(["/vsicurl/https://example.com/t00.tif"])
    finally:
        for m in mem:
            gdal.Unlink(m)
    assert len(index_tiles(paths).tiles) == len(paths)      # the same tiles on disk pass


def test_other_cell_size_and_overlap_refused_naming_the_tiles(tmp_path):
    sc = make_scene("flat", shape=(64, 64), seed=1)
    paths = write_survey(tmp_path / "a", sc, tile=32)
    gt = sc.geotransform
    fine = tmp_path / "fine.tif"
    grid.write_array(fine, np.zeros((20, 20), np.float32), (gt[0] + 64, 0.5, 0, gt[3], 0, -0.5), sc.epsg)
    with pytest.raises(ValueError, match=r"different cell sizes: fine\.tif \(0\.5 x 0\.5\)"):
        index_tiles(paths + [str(fine)])
    over = tmp_path / "over.tif"
    grid.write_array(over, np.zeros((32, 32), np.float32), (gt[0] + 16, gt[1], 0, gt[3] - 16, 0, gt[5]), sc.epsg)
    with pytest.raises(ValueError, match=r"tiles overlap: .*over\.tif"):
        index_tiles(paths + [str(over)])
    shifted = tmp_path / "shifted.tif"
    grid.write_array(shifted, np.zeros((32, 32), np.float32), (gt[0] + 64.5, gt[1], 0, gt[3], 0, gt[5]), sc.epsg)
    with pytest.raises(ValueError, match=r"shifted\.tif are not on the grid"):
        index_tiles(paths + [str(shifted)])


@pytest.mark.parametrize("kind", ["dtype", "scale"])
def test_tiles_of_another_data_type_or_scale_refused_naming_them(tmp_path, kind):
    """Tiles that GDAL's VRT cannot hold together (another data type, another scale) are refused
    before any work, naming them. Before: gdalbuildvrt left them out of survey.vrt with a warning
    only, the parameters were derived from the rest, and every task failed on 'Access window out
    of range' after the work had started."""
    from osgeo import gdal
    sc = make_scene("flat", shape=(64, 64), seed=1)
    paths = write_survey(tmp_path / "tiles", sc, tile=32)
    odd = paths[3]
    a, gt = grid.open_dsm(odd).read(), grid.open_dsm(odd).geotransform
    if kind == "dtype":
        grid.write_array(odd, np.rint(a * 100), gt, sc.epsg, nodata=-9999, dtype="Int32")
        ds = gdal.Open(odd, gdal.GA_Update)
        ds.GetRasterBand(1).SetScale(0.01)
        ds = None
        message = r"different data types: t11\.tif \(Int32\) differ from t00\.tif \(Float32\)"
    else:
        ds = gdal.Open(odd, gdal.GA_Update)
        ds.GetRasterBand(1).WriteArray(a * 10)
        ds.GetRasterBand(1).SetScale(0.1)
        ds = None
        message = r"different scales or offsets: t11\.tif \(x 0\.1 \+ 0\) differ from t00\.tif \(x 1 \+ 0\)"
    assert np.allclose(grid.open_dsm(odd).read(), a, atol=0.01)      # the same heights, stored otherwise
    with pytest.raises(ValueError, match=message):
        index_tiles(paths)
    with pytest.raises(ValueError, match=message):
        run_survey("morphological", paths, tmp_path / "out", workers=1)
    assert not (tmp_path / "out").exists()                # refused before any work


def test_survey_vrt_missing_a_tile_is_an_error_naming_it(tmp_path):
    """A VRT that GDAL built without one of its sources (gdalbuildvrt skips what it cannot mix)
    is an error naming the tile, never a smaller mosaic."""
    sc = make_scene("flat", shape=(64, 64), seed=1)
    paths = write_survey(tmp_path / "tiles", sc, tile=32)
    other = tmp_path / "other.tif"
    grid.write_array(other, np.zeros((32, 32), np.uint8), grid.open_dsm(paths[3]).geotransform, sc.epsg)
    with pytest.raises(ValueError, match=r"GDAL left 1 of the 4 tiles out of the VRT: other\.tif"):
        survey_io.build_vrt(tmp_path / "m.vrt", paths[:3] + [str(other)])
    assert not list(tmp_path.glob("m.vrt*"))


def test_south_up_and_multiband_tiles_refused_with_what_to_do(tmp_path):
    """A south-up tile (positive row step) was refused as of 'different cell sizes: flip.tif (1 x 1)
    differ from t00.tif (1 x 1)', and a survey of south-up tiles only failed after creating its
    output folder ('GDAL could not build a VRT'); a multi-band tile was told to use a BAND
    parameter the survey does not have."""
    from osgeo import gdal
    sc = make_scene("flat", shape=(64, 64), seed=1)
    paths = write_survey(tmp_path / "tiles", sc, tile=32)
    flipped = []
    for p in paths[2:]:
        g = grid.open_dsm(p).geotransform
        a = grid.open_dsm(p).read()
        q = tmp_path / ("s_" + os.path.basename(p))
        grid.write_array(q, a[::-1], (g[0], g[1], 0, g[3] + 32 * g[5], 0, -g[5]), sc.epsg)
        flipped.append(str(q))
    for tiles in (paths[:2] + flipped, flipped):
        with pytest.raises(ValueError, match=r"s_t10\.tif.* south-up \(rows from south to north\).*gdalwarp"):
            index_tiles(tiles)
    with pytest.raises(ValueError, match="south-up"):
        run_survey("morphological", flipped, tmp_path / "out", workers=1)
    assert not (tmp_path / "out").exists()                # refused before any work
    two = tmp_path / "two.tif"
    g = grid.open_dsm(paths[3]).geotransform
    ds = gdal.GetDriverByName("GTiff").Create(str(two), 32, 32, 2, gdal.GDT_Float32)
    ds.SetGeoTransform(g)
    ds = None
    with pytest.raises(ValueError, match=r"two\.tif .*has 2 bands.*extract the height band \(gdal_translate -b\)"):
        index_tiles(paths[:3] + [str(two)])


def test_a_tile_given_twice_refused_as_such(survey, tmp_path):
    """QA14: one file given twice (tiles/t.tif and ./tiles/t.tif, or a link to it) was refused as 'several tiles
    are named t: rename them' (the link as two overlapping tiles); it is one tile given twice."""
    paths = [str(p) for p in survey["tiles"][:3]]
    again = os.path.join(os.path.dirname(paths[0]), ".", os.path.basename(paths[0]))
    with pytest.raises(ValueError, match=rf"^1 tile\(s\) are given twice: {re.escape(paths[0])}\. Give each tile "
                                         r"once\.$"):
        index_tiles(paths + [again])
    link = tmp_path / "link.tif"
    link.symlink_to(paths[1])
    with pytest.raises(ValueError, match=rf"given twice: {re.escape(paths[1])} \(and as .*link\.tif, the same file\)"):
        index_tiles(paths + [str(link)])


def test_parse_params_converts_to_the_params_kinds():
    meth = get_method("slopeprofile")
    assert parse_params(meth, "max_object_size_m=30; refine=true tolerance_m=") == {
        "max_object_size_m": 30.0, "refine": True, "tolerance_m": None}
    with pytest.raises(ValueError, match="method 'slopeprofile' takes"):
        parse_params(meth, ["size=3"])
    # out of its range or not a number: refused here, before the survey starts its cluster and
    # creates the output folder (the range was checked only once the tiles were running)
    with pytest.raises(ValueError, match=r"max_object_size_m = -5.0 is out of range \[.*\] for method 'slopeprofile'"):
        parse_params(meth, "max_object_size_m=-5")
    with pytest.raises(ValueError, match="max_object_size_m takes a number; got 'abc'"):
        parse_params(meth, "max_object_size_m=abc")


def test_parse_params_of_a_method_without_parameters_says_so():
    """dtm, the recommended filter and the survey's default method, takes no parameter: a KEY=VALUE given to it
    was refused as "method 'dtm' takes ." (an empty list), after the help's example gave two."""
    with pytest.raises(ValueError, match=r"^parameter max_object_size_m: method 'dtm' takes no parameter \(it "
                                         r"derives every value from the data\): give none, or choose a method that "
                                         r"takes it\.$"):
        parse_params("dtm", ["max_object_size_m=60"])
    assert parse_params("dtm", []) == {} and parse_params("dtm", "") == {}
    with pytest.raises(ValueError, match=r"method 'geodesic' takes edge_ratio, height_threshold_m, "):
        parse_params("geodesic", ["foo=1"])


def test_parse_params_reads_values_as_users_type_them():
    """What the dialog and qgis_process take elsewhere: a whole number written as 2.0, an option
    in any case (the key already was), and a decimal comma said to be one (before: 'sigma_m=0,1'
    was refused as "parameter '1': write KEY=VALUE", 'snooping_iterations=2.0' and
    'terrain_class=Flat' refused)."""
    meth = get_method("rascor")
    assert parse_params(meth, "SNOOPING_ITERATIONS=2.0 terrain_class=Flat surface_rule=RESIDUALS") == {
        "snooping_iterations": 2, "terrain_class": "flat", "surface_rule": "residuals"}
    with pytest.raises(ValueError, match="snooping_iterations takes a whole number; got '2.5'"):
        parse_params(meth, "snooping_iterations=2.5")
    with pytest.raises(ValueError, match=r"'sigma_m=0,1'.*decimal point \(0\.1\)"):
        parse_params(meth, "sigma_m=0,1 jump_m=2")
    with pytest.raises(ValueError, match=r"parameter '7': write KEY=VALUE"):
        parse_params(meth, "sigma_m=0.1 7")


def test_parse_params_refuses_a_parameter_given_twice():
    """QA14: 'dh_m=1 ... dh_m=2' (two --param, or PARAMETERS text) ran the survey with the last, 2, without a
    word; a key given twice in another case (DH_M, as the algorithm names it) the same."""
    meth = get_method("morphological")
    with pytest.raises(ValueError, match=r"^parameter dh_m is given twice \('dh_m=1' and 'dh_m=2'\): give it once\.$"):
        parse_params(meth, ["dh_m=1", "dh_m=2"])
    with pytest.raises(ValueError, match=r"parameter dh_m is given twice \('dh_m=1' and 'DH_M='\)"):
        parse_params(meth, "dh_m=1, max_object_size_m=40, DH_M=")
    assert parse_params(meth, "dh_m=1, max_object_size_m=40") == {"dh_m": 1.0, "max_object_size_m": 40.0}


# -- seamless ------------------------------------------------------------------------------------
@pytest.mark.parametrize("method", sorted(available_methods()))
def test_tiled_mask_equals_the_one_pass_mask(survey, method):
    out = survey["dir"] / f"out-{method}"
    rec = run_survey(method, survey["tiles"], out, SMALL.get(method), workers=2)
    sc = survey["scene"]
    assert rec["sample"].startswith("the whole survey")
    assert len(done(rec)) == 9 and not rec["this_run"]["failed"]
    ref = one_pass(method, sc, rec)
    mask = read_mosaic(out, "mask")
    assert mask.shape == sc.dsm.shape
    assert np.array_equal(mask, ref.mask), f"{int((mask != ref.mask).sum())} cells differ"
    dtm = read_mosaic(out, "dtm")
    ground = ref.mask == 0
    assert np.array_equal(dtm[ground], sc.dsm[ground])            # ground cells are the DSM's
    assert np.array_equal(np.isnan(dtm), np.isnan(ref.dtm))
    filled = np.isfinite(dtm) & ~ground
    # the fill sees the tile's window, not the mosaic: within the cascade's own error
    # (1.5-2.5 % of the relief across a hole, fill.py) of the single pass
    assert np.abs(dtm[filled] - ref.dtm[filled]).max() <= 0.025 * float(np.ptp(sc.dsm[ground]))
    # one COG per tile on the tile's grid
    from osgeo import gdal
    for t in survey["tiles"]:
        name = os.path.splitext(os.path.basename(t))[0]
        for f in output_names(name):
            ds = gdal.Open(str(out / f))
            assert ds.GetMetadata("IMAGE_STRUCTURE").get("LAYOUT") == "COG"
            assert ds.GetGeoTransform() == gdal.Open(t).GetGeoTransform()
    ds = gdal.Open(str(out / output_names("t11")[1]))
    m = ds.GetRasterBand(1)
    assert m.GetNoDataValue() == 255 and m.GetColorTable().GetColorEntry(1) == (220, 40, 40, 255)
    assert json.loads((out / "run.json").read_text())["halo_cells"] == rec["halo_cells"]


def test_vrt_input_and_cancel_then_rerun_redoes_only_the_rest(survey, tmp_path):
    from osgeo import gdal

    from bare_earth.core.common import Cancelled
    vrt = str(tmp_path / "survey_in.vrt")
    gdal.BuildVRT(vrt, survey["tiles"])
    out = tmp_path / "out"
    params = SMALL["slopeprofile"]

    def stop_after_three(fraction):
        if fraction >= 3 / 9:
            raise Cancelled()

    with pytest.raises(Cancelled):
        run_survey("slopeprofile", vrt, out, params, workers=1, progress=stop_after_three)
    first = json.loads((out / "run.json").read_text())
    done_first = {k: v["start"] for k, v in done(first).items()}
    assert 3 <= len(done_first) < 9 and first["runs"][0]["cancelled"]
    assert {v["status"] for k, v in first["tiles"].items() if k not in done_first} == {"pending"}
    rec = run_survey("slopeprofile", vrt, out, params, workers=1)
    assert rec["this_run"]["tiles_to_do"] == 9 - len(done_first) == rec["this_run"]["tiles_done"]
    assert {k: rec["tiles"][k]["start"] for k in done_first} == done_first      # not redone
    assert np.array_equal(read_mosaic(out, "mask"), one_pass("slopeprofile", survey["scene"], rec).mask)
    with pytest.raises(ValueError, match="holds a run of other arguments"):
        run_survey("slopeprofile", vrt, out, {"max_object_size_m": 30.0}, workers=1)


def test_failed_tile_leaves_no_mosaic_and_the_rerun_finishes_it(survey, tmp_path):
    """A tile that fails (its output name taken by a folder) leaves no dtm.vrt / mask.vrt, a record saying
    incomplete and a log naming the tile and the rerun; before: the mosaics were written over the 8 finished
    tiles, a hole where t11 was, and looked like the survey's result. A rerun that fails again removes the
    mosaics of the earlier complete run."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "t11_dtm.tif").mkdir()                   # os.replace onto a folder fails: the tile fails
    params = SMALL["slopeprofile"]
    lines = []
    rec = run_survey("slopeprofile", survey["tiles"], out, params, workers=1, log=lines.append)
    assert list(rec["this_run"]["failed"]) == ["t11"] and len(done(rec)) == 8
    assert not (out / "dtm.vrt").exists() and not (out / "mask.vrt").exists()
    assert not (out / "t11_mask.tif").exists()
    saved = json.loads((out / "run.json").read_text())
    assert saved["complete"] is False and saved["missing_tiles"] == ["t11"] and "mosaics" not in saved
    text = "\n".join(lines)
    assert "INCOMPLETE: 1 of 9 tile(s) not done" in text and "t11 failed: " in text
    assert "Run the same command again" in text
    (out / "t11_dtm.tif").rmdir()
    rec = run_survey("slopeprofile", survey["tiles"], out, params, workers=1)
    assert rec["this_run"]["tiles_to_do"] == 1 and rec["complete"] is True
    assert np.array_equal(read_mosaic(out, "mask"), one_pass("slopeprofile", survey["scene"], rec).mask)
    os.remove(out / "t22_dtm.tif")                  # gone since: t22 is redone, and fails
    (out / "t22_dtm.tif").mkdir()
    rec = run_survey("slopeprofile", survey["tiles"], out, params, workers=1)
    assert list(rec["this_run"]["failed"]) == ["t22"] and rec["complete"] is False
    assert not (out / "dtm.vrt").exists() and not (out / "mask.vrt").exists()


def test_more_workers_than_cores_refused_before_any_work(survey, tmp_path):
    """WORKERS = 256 on this computer: refused naming its cores and memory (before: 256 processes were
    started, each given 1/256 of the memory by Dask, and the tiles failed as the workers were restarted)."""
    from bare_earth.core.blocks import available_cores
    n = available_cores() + 1
    with pytest.raises(ValueError, match=rf"WORKERS = {n} local worker processes, but this computer has "
                                         rf"{n - 1} core\(s\) and [0-9.]+ GB of memory.*Use at most {n - 1}"):
        run_survey("slopeprofile", survey["tiles"], tmp_path / "out", workers=n)
    assert not (tmp_path / "out").exists()
    # QA14: a negative count (bin/bare-earth --workers -1) ran one worker per core without a word
    with pytest.raises(ValueError, match=r"^WORKERS = -1: give a number of local worker processes, or 0 for one "
                                         r"per core\.$"):
        run_survey("slopeprofile", survey["tiles"], tmp_path / "out", workers=-1)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("name", ["mask.qml", "dtm.vrt", "survey.vrt"])
def test_a_folder_named_as_a_survey_file_refused_before_any_work(survey, tmp_path, name):
    """QA14: a folder named mask.qml or dtm.vrt in the output folder raised a bare IsADirectoryError once every
    tile was done (survey.vrt's at the start)."""
    out = tmp_path / "out"
    (out / name).mkdir(parents=True)
    with pytest.raises(ValueError, match=rf"^the output folder '{out}' holds a folder named {re.escape(name)}, a file "
                                         r"the survey writes: move or rename that folder"):
        run_survey("slopeprofile", survey["tiles"], out, workers=1)
    assert sorted(os.listdir(out)) == [name]


def test_an_output_folder_taking_no_file_refused_before_any_work(survey, tmp_path, read_only):
    """QA24: a read-only output folder (or a new one under a read-only folder) passed the checks and the run
    ended in a traceback (FileNotFoundError renaming survey.vrt's work file) after the tiles had been indexed; a
    new folder below a file was a NotADirectoryError."""
    out = tmp_path / "out"
    out.mkdir()
    with read_only(out):
        with pytest.raises(ValueError, match=rf"^the output folder '{out}' is not writable \(.+\): choose a folder "
                                             "you can write to"):
            run_survey("slopeprofile", survey["tiles"], out, workers=1)
        with pytest.raises(ValueError, match=rf"^the output folder '{out}' \(the output folder '{out / 'a' / 'b'}' "
                                             r"would be created in it\) is not writable"):
            run_survey("slopeprofile", survey["tiles"], out / "a" / "b", workers=1)
    assert os.listdir(out) == []
    (tmp_path / "file").write_text("")
    with pytest.raises(ValueError, match=rf"^the output folder '{tmp_path / 'file' / 'x'}' cannot be created: "
                                         rf"'{tmp_path / 'file'}' is a file, not a folder"):
        run_survey("slopeprofile", survey["tiles"], tmp_path / "file" / "x", workers=1)


@pytest.mark.parametrize("name", ["mask.qml", "run.json", "t00_mask.tif.aux.xml"])
def test_a_read_only_survey_file_in_the_output_folder_refused_before_any_work(survey, tmp_path, read_only, name):
    """QA24: a read-only mask.qml in the output folder ended the run in a PermissionError traceback once every
    tile was done (run.json and a tile's .aux.xml likewise, or as a failed tile)."""
    out = tmp_path / "out"
    out.mkdir()
    (out / name).write_text("keep")
    with read_only(out / name):
        with pytest.raises(ValueError, match=rf"{re.escape(name)}.* read-only \(or no regular file\): make it"):
            run_survey("slopeprofile", survey["tiles"], out, workers=1)
    assert os.listdir(out) == [name] and (out / name).read_text() == "keep"


def test_an_empty_input_or_output_path_refused_before_any_work(survey, tmp_path, monkeypatch):
    """QA14: bin/bare-earth tiles ... --output-dir "$OUT" with OUT unset wrote the survey's files into the current
    folder; --input "" filtered the current folder's rasters."""
    monkeypatch.chdir(os.path.dirname(survey["tiles"][0]))       # the tiles' folder: '' would be a survey
    with pytest.raises(ValueError, match=r"^the output folder is empty: give the folder the outputs go to \(an "
                                         r"empty one would be the current folder, '.*'\)\.$"):
        run_survey("slopeprofile", survey["tiles"], "", workers=1)
    with pytest.raises(ValueError, match=r"^an input path is empty: give the tiles' rasters, a VRT or a folder"):
        run_survey("slopeprofile", "", tmp_path / "out", workers=1)
    with pytest.raises(ValueError, match=r"^an input path is empty"):
        run_survey("slopeprofile", survey["tiles"][:2] + [" "], tmp_path / "out", workers=1)
    assert not (tmp_path / "out").exists() and not [f for f in os.listdir(".") if not f.endswith(".tif")]


def test_memory_warning_names_the_workers_that_fit():
    from bare_earth.core.survey import engine
    gb = 2 ** 30
    # 150 MB + 10 Mcells x 64 B (610 MB) = 760 MB per worker: 2 sharing 2 GB (1 GB each) fit, 4 (512 MB) not
    assert engine.memory_warning(2, 10_000_000, total_bytes=2 * gb) is None
    text = engine.memory_warning(4, 10_000_000, total_bytes=2 * gb)
    assert "each of the 4 local worker(s) gets 512 MB of this computer's 2.0 GB" in text
    assert "needs about 760 MB: use WORKERS = 2 or fewer" in text
    assert "cut the survey into smaller tiles" in engine.memory_warning(1, 100_000_000, total_bytes=2 * gb)


def test_integer_tiles_without_nodata_say_which_value_is_read_as_nodata(tmp_path):
    """UInt16 tiles declaring no nodata: the survey VRT's gaps take 0, so their cells of 0 are nodata; the log
    says so and how to change it (before: those cells were dropped without a word, a single file keeps them)."""
    sc = make_scene("flat", shape=(64, 64), seed=1)
    paths = []
    for k in range(2):
        a = np.round(sc.dsm[:, 32 * k:32 * k + 32] * 10 + 100).astype(np.uint16)
        a[:2, :2] = 0
        g = (sc.geotransform[0] + 32 * k, 1.0, 0.0, sc.geotransform[3], 0.0, -1.0)
        paths.append(str(grid.write_array(tmp_path / f"t{k}.tif", a, g, sc.epsg, dtype="UInt16")))
    lines = []
    run_survey("morphological", paths, tmp_path / "out", SMALL["morphological"], workers=1, log=lines.append)
    assert any("2 tile(s) declare no nodata value (t0, t1): their cells of 0" in t for t in lines), lines
    dtm = grid.open_dsm(str(tmp_path / "out" / "t0_dtm.tif")).read()
    assert np.isnan(dtm[:2, :2]).all() and np.isfinite(dtm[2:, 2:]).all()


# -- a real cluster --------------------------------------------------------------------------------
@pytest.fixture
def cluster(tmp_path):
    """A dask-scheduler and two dask-worker processes (no nanny) on 127.0.0.1, torn down after."""
    port = free_port()
    addr = f"tcp://127.0.0.1:{port}"
    env = dict(os.environ, PYTHONPATH=str(ROOT / ".build" / "plugins"))
    procs = [subprocess.Popen([PY, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port",
                               str(port), "--no-dashboard"], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, cwd=tmp_path)]
    workers = []
    try:
        for k in range(2):
            w = subprocess.Popen([PY, "-m", "distributed.cli.dask_worker", addr, "--nthreads", "1", "--no-nanny",
                                  "--no-dashboard", "--name", f"w{k}", "--death-timeout", "60"],
                                 env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=tmp_path)
            procs.append(w)
            workers.append(w)
        from distributed import Client
        with Client(addr, timeout="30s") as c:
            c.wait_for_workers(2, timeout=60)
        yield addr, workers
    finally:
        for p in procs[::-1]:
            if p.poll() is None:
                p.terminate()
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()


def test_runs_on_an_existing_cluster_and_survives_a_killed_worker(survey, cluster, tmp_path):
    addr, workers = cluster
    out = tmp_path / "out"
    killed = []

    def kill_second_worker(fraction):
        if not killed:
            workers[1].send_signal(signal.SIGKILL)     # mid-run: its tiles in flight are lost
            workers[1].wait(timeout=20)
            killed.append(fraction)

    rec = run_survey("geodesic", survey["tiles"], out, SMALL["geodesic"], scheduler=addr, progress=kill_second_worker)
    assert killed and killed[0] < 1.0
    run = rec["this_run"]
    assert run["scheduler"] == addr and len(run["workers"]) >= 1
    assert not run["failed"] and len(done(rec)) == 9
    pids = {int(v["worker"].rsplit(":", 1)[1]) for v in done(rec).values()}
    assert pids <= {w.pid for w in workers}           # the tiles ran in the cluster's processes
    assert workers[0].pid in pids
    ref = one_pass("geodesic", survey["scene"], rec)
    assert np.array_equal(read_mosaic(out, "mask"), ref.mask)


# -- the command line ----------------------------------------------------------------------------
def test_cli_killed_run_resumes_only_unrecorded_tiles(survey, tmp_path):
    out = tmp_path / "out"
    cmd = [str(ROOT / "bin" / "bare-earth"), "tiles", "rascor", "--input", *survey["tiles"], "--output-dir",
           str(out), "--workers", "1", "--quiet"]
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    rec_path = out / "run.json"
    recorded = {}
    t0 = time.time()
    while time.time() - t0 < 240 and p.poll() is None:
        if rec_path.exists():
            recorded = done(json.loads(rec_path.read_text()))
            if recorded:
                os.killpg(p.pid, signal.SIGKILL)     # the client and its local workers
                break
        time.sleep(0.02)
    p.wait(timeout=60)
    assert 1 <= len(recorded) < 9, "the run finished before it could be killed"
    (out / "t22_dtm.partial-0123abcd.tif").write_bytes(b"half a GeoTIFF")     # as a write cut short leaves
    (out / "t22_mask.partial-0123abcd.tif.aux.xml").write_text("<PAMDataset/>")
    res = subprocess.run(cmd[:-1], capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    assert f"{len(recorded)} tile(s) already done" in res.stdout
    assert "9/9 tiles done" in res.stdout and "unfinished file(s) of an earlier run" in res.stdout
    rec = json.loads(rec_path.read_text())
    assert rec["runs"][-1]["tiles_done"] == 9 - len(recorded)
    assert {k: rec["tiles"][k]["start"] for k in recorded} == {k: v["start"] for k, v in recorded.items()}
    assert not any(".partial-" in f for f in os.listdir(out))          # a killed write's leftovers removed
    assert np.array_equal(read_mosaic(out, "mask"), one_pass("rascor", survey["scene"], rec).mask)


def test_cli_ctrl_c_gives_one_message_not_the_workers_tracebacks(survey, tmp_path):
    """Ctrl-C reaches every process of the command (the terminal's process group): each Dask
    worker printed a traceback (CancelledError, KeyboardInterrupt) around the command's
    message. The workers now ignore it; the command stops them and says how to finish."""
    out = tmp_path / "out"
    cmd = [str(ROOT / "bin" / "bare-earth"), "tiles", "rascor", "--input", *survey["tiles"], "--output-dir",
           str(out), "--workers", "2"]
    # a terminal's command takes Ctrl-C; a test suite started in the background of a shell without job
    # control has SIGINT ignored, which its children would inherit (and Python then installs no handler)
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    for line in p.stdout:                          # the first tile done: the run is under way
        if ": done in " in line:
            os.killpg(p.pid, signal.SIGINT)          # what Ctrl-C in a terminal does
            break
    stdout, stderr = p.communicate(timeout=120)
    assert p.returncode == 130, stderr
    assert "interrupted; the finished tiles are recorded, rerun to finish" in stderr
    assert "Traceback" not in stderr + stdout, stderr
    assert (out / "run.json").exists() and not (out / "mask.vrt").exists()


def test_cli_refuses_mixed_crs_naming_the_tile(tmp_path):
    sc = make_scene("flat", shape=(64, 64), seed=1)
    paths = write_survey(tmp_path, sc, tile=32, epsg={"t01": 32633})
    res = subprocess.run([str(ROOT / "bin" / "bare-earth"), "tiles", "morphological", "--input", str(tmp_path),
                          "--output-dir", str(tmp_path / "out")], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and "t01.tif (EPSG:32633)" in res.stderr
    assert len(paths) == 4 and not (tmp_path / "out").exists()


def test_tiles_with_an_alpha_band_keep_their_transparent_cells_as_nodata(tmp_path):
    """Tiles warped with an alpha band (heights 0 where it is 0): nodata in the tiles' outputs, as
    in a single tile's run (the survey read them as heights of 0 through its mosaic VRT)."""
    from osgeo import gdal, osr
    sc = make_scene("city", shape=(64, 128), seed=2)
    gt, srs = sc.geotransform, osr.SpatialReference()
    srs.ImportFromEPSG(sc.epsg)
    paths = []
    for k in range(2):
        z = sc.dsm[:, 64 * k:64 * (k + 1)].copy()
        alpha = np.full(z.shape, 255, np.float32)
        if k == 0:
            alpha[:, :8] = 0
            z[:, :8] = 0.0
        p = str(tmp_path / f"t{k}.tif")
        ds = gdal.GetDriverByName("GTiff").Create(p, 64, 64, 2, gdal.GDT_Float32)
        ds.SetGeoTransform((gt[0] + 64 * k * gt[1], gt[1], 0.0, gt[3], 0.0, gt[5]))
        ds.SetProjection(srs.ExportToWkt())
        ds.GetRasterBand(1).WriteArray(z)
        ds.GetRasterBand(2).SetColorInterpretation(gdal.GCI_AlphaBand)
        ds.GetRasterBand(2).WriteArray(alpha)
        ds = None
        paths.append(p)
    run_survey("morphological", paths, tmp_path / "out", {"max_object_size_m": 16.0}, workers=1)
    mask = grid.open_dsm(tmp_path / "out" / output_names("t0")[1]).read_stored()
    dtm = grid.open_dsm(tmp_path / "out" / output_names("t0")[0]).read()
    assert (mask[:, :8] == 255).all() and (mask[:, 8:] != 255).all()
    assert np.isnan(dtm[:, :8]).all() and np.nanmin(dtm) > 100


def test_a_read_only_tile_output_refused_before_any_work(tmp_path, read_only):
    """A tile output left from an earlier run (run.json gone) that cannot be replaced: refused
    naming it before any task runs. The task failed and the survey stopped with a PermissionError
    traceback while removing it."""
    sc = make_scene("flat", shape=(64, 64), seed=1)
    paths = write_survey(tmp_path / "tiles", sc, tile=32)
    out = tmp_path / "out"
    run_survey("slopeprofile", paths, out, {"max_object_size_m": 8.0}, workers=1)
    os.remove(out / "run.json")
    locked = out / output_names("t00")[0]
    before = locked.read_bytes()
    with read_only(locked):
        with pytest.raises(ValueError, match=r"t00_dtm\.tif' exists and is read-only"):
            run_survey("slopeprofile", paths, out, {"max_object_size_m": 8.0}, workers=1)
        assert locked.read_bytes() == before


def test_tiles_with_an_undeclared_minus_9999_border_warned(tmp_path):
    """Tiles exported with -9999 in their empty corners and no declared nodata: the survey's log
    names the value and how to declare it, as a single raster's run does."""
    sc = make_scene("flat", shape=(64, 64), seed=1)
    z = sc.dsm.copy()
    z[:, :6] = -9999.0
    gt = sc.geotransform
    paths = []
    for k in range(2):
        p = tmp_path / f"t{k}.tif"
        grid.write_array(p, z[:, 32 * k:32 * (k + 1)], (gt[0] + 32 * k * gt[1], gt[1], 0.0, gt[3], 0.0, gt[5]),
                         sc.epsg)
        paths.append(str(p))
    logs = []
    run_survey("slopeprofile", paths, tmp_path / "out", {"max_object_size_m": 8.0}, workers=1, log=logs.append)
    said = [s for s in logs if "a common nodata value" in s]
    assert said and "384 cell(s) hold -9999" in said[0] and "gdal_edit.py -a_nodata -9999 <tile>" in said[0]


def test_tiles_declaring_a_nodata_value_among_their_heights_warned(tmp_path):
    """Tiles of heights rounded to whole metres declaring one of those heights as their nodata: the
    survey's log says every cell holding it is read as missing, as a single raster's run does."""
    sc = make_scene("flat", shape=(64, 64), seed=1)
    z = np.round(sc.dsm).astype(np.float32)
    nd = float(np.median(z))
    gt = sc.geotransform
    paths = []
    for k in range(2):
        p = tmp_path / f"t{k}.tif"
        grid.write_array(p, z[:, 32 * k:32 * (k + 1)], (gt[0] + 32 * k * gt[1], gt[1], 0.0, gt[3], 0.0, gt[5]),
                         sc.epsg, nodata=nd)
        paths.append(str(p))
    logs = []
    run_survey("slopeprofile", paths, tmp_path / "out", {"max_object_size_m": 8.0}, workers=1, log=logs.append)
    said = [s for s in logs if "lies among its heights" in s]
    assert said and f"declares {nd:g} as its nodata value" in said[0], logs


@pytest.mark.parametrize("crs", [32633, 2264])   # metres; NC State Plane, US feet (heights too)
def test_scaled_tiles_write_heights_with_a_nodata_no_height_has(tmp_path, crs):
    """UInt16 tiles with nodata 0, scale 0.01 and offset -100 (heights from -100): each tile's DTM
    declared the stored 0 as its nodata, so its ground at 0 (sea level) read as nodata; it now
    declares -100, the height of the nodata cells. In a CRS in feet the ground cells of the DTM
    got the stored counts (10000) instead of their heights."""
    from osgeo import gdal
    sc = make_scene("flat", shape=(64, 64), seed=1)
    counts = np.round((sc.dsm - np.median(sc.dsm) + 100.0) * 100).astype(np.uint16)
    counts[:, 3] = 10000      # ground at 0
    counts[0, :2] = 0         # nodata
    gt = (500000.0, 1.0, 0.0, 4000000.0, 0.0, -1.0) if crs == 32633 else (2000000.0, 1.0, 0.0, 700000.0, 0.0, -1.0)
    paths = []
    for k in range(2):
        p = tmp_path / f"t{k}.tif"
        grid.write_array(p, counts[:, 32 * k:32 * (k + 1)], (gt[0] + 32 * k, 1.0, 0.0, gt[3], 0.0, -1.0), crs,
                         nodata=0, dtype="UInt16")
        ds = gdal.Open(str(p), gdal.GA_Update)
        ds.GetRasterBand(1).SetScale(0.01)
        ds.GetRasterBand(1).SetOffset(-100.0)
        ds = None
        paths.append(str(p))
    run_survey("slopeprofile", paths, tmp_path / "out", {"max_object_size_m": 8.0}, workers=1)
    ds = gdal.Open(str(tmp_path / "out" / "t0_dtm.tif"))
    band = ds.GetRasterBand(1)
    dtm = band.ReadAsArray()
    assert band.GetNoDataValue() == -100.0
    assert np.count_nonzero(dtm == -100.0) == 2 and (dtm[:, 3] == 0.0).all()
    heights = (counts[:, :32] * 0.01 - 100.0).astype(np.float32)
    ok = counts[:, :32] != 0
    assert np.abs(dtm[ok] - heights[ok]).max() < 1.0


def _state_unit(paths, unit):
    from osgeo import gdal
    for p in paths:
        ds = gdal.Open(str(p), gdal.GA_Update)
        ds.GetRasterBand(1).SetUnitType(unit)
        ds = None


def test_tiles_stating_their_heights_in_feet_give_the_one_pass_dtm_in_feet(tmp_path):
    """Tiles in a UTM CRS whose bands state feet (GDAL's unit type): the survey reads them through
    its VRT, which gdalbuildvrt writes without the unit, so the heights were read as metres there
    and written back in feet (x 3.28): the VRTs state the tiles' unit now, the tiles' DTMs too, and
    the mosaic is the one-pass DTM; tiles stating different units are refused before any work."""
    from osgeo import gdal
    sc = make_scene("city", shape=(64, 64), seed=2)
    feet = sc.dsm / 0.3048
    paths = write_survey(tmp_path / "tiles", dataclasses.replace(sc, dsm=feet), tile=32)
    _state_unit(paths, "ft")
    src = grid.write_array(tmp_path / "whole.tif", feet.astype(np.float32), sc.geotransform, sc.epsg)
    _state_unit([src], "ft")
    params = {"max_object_size_m": 8.0}
    pipeline.run_file("slopeprofile", src, {"dtm": tmp_path / "one.tif"}, params=params)
    run_survey("slopeprofile", paths, tmp_path / "out", params, workers=1)
    ds = gdal.Open(str(tmp_path / "one.tif"))
    one = ds.ReadAsArray()
    ds = gdal.Open(str(tmp_path / "out" / "dtm.vrt"))
    mosaic, unit = ds.ReadAsArray(), ds.GetRasterBand(1).GetUnitType()
    np.testing.assert_allclose(mosaic, one, atol=1e-3)
    ds = gdal.Open(str(tmp_path / "out" / "t00_dtm.tif"))
    assert unit == "ft" and ds.GetRasterBand(1).GetUnitType() == "ft"
    ds = None
    _state_unit(paths[1:2], "m")
    with pytest.raises(ValueError, match=r"heights are in different units: t01\.tif \('m', 1 m\) differ from "
                                         r"t00\.tif \('ft', 0\.3048 m\)"):
        run_survey("slopeprofile", paths, tmp_path / "out2", params, workers=1)
    assert not (tmp_path / "out2").exists()


def test_a_tile_written_on_a_full_disk_fails_naming_its_output(tmp_path):
    """A tile's COG that cannot be written (the disk full: here a file-size limit) fails with the message
    naming the output and the disk, as the other outputs do (the survey's log gave GDAL's bare
    "RuntimeError: TIFFAppendToStrip:Seek error"), and leaves no file."""
    import textwrap
    plugins = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(survey_io.__file__))))
    code = textwrap.dedent(f"""
        import resource, signal, sys
        sys.path.insert(0, {plugins!r})
        import numpy as np
        from bare_earth.core.survey.io import write_cog
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, resource.RLIM_INFINITY))
        a = np.random.default_rng(0).normal(100, 1, (400, 400)).astype(np.float32)
        try:
            write_cog({str(tmp_path / "t_dtm.tif")!r}, a, (0, 1, 0, 400, 0, -1))
            print("WROTE")
        except ValueError as exc:
            print("VALUEERROR", exc)
    """)
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.stdout.startswith("VALUEERROR cannot write the output"), res.stdout + res.stderr[-1500:]
    assert "t_dtm.tif" in res.stdout and "disk" in res.stdout
    assert os.listdir(tmp_path) == []


def test_survey_workers_do_not_run_an_unguarded_script_again(tmp_path):
    """A script running a survey at its top level (no __main__ guard): each Dask worker ran the
    script again, whose survey started workers of its own, which ran it again (96 runs in 5 min,
    no end). Now the script runs once and the survey completes."""
    from tests.core.test_blocks import run_unguarded_script
    sc = make_scene("flat", shape=(64, 64), seed=1)
    gt = sc.geotransform
    paths = []
    for k in range(2):
        p = tmp_path / f"t{k}.tif"
        grid.write_array(p, sc.dsm[:, 32 * k:32 * (k + 1)], (gt[0] + 32 * k * gt[1], gt[1], 0.0, gt[3], 0.0, gt[5]),
                         sc.epsg)
        paths.append(str(p))
    body = (f"from bare_earth.core.survey.run import run_survey\n"
            f"rec = run_survey('slopeprofile', {paths!r}, {str(tmp_path / 'out')!r}, {{'max_object_size_m': 8.0}},\n"
            f"                 workers=2)\n"
            f"assert rec['complete']")
    code, out, runs = run_unguarded_script(tmp_path, body)
    assert code == 0 and "finished" in out and runs == 1, (runs, out[-2000:])


def test_rascor_height_limits_of_a_sampled_survey_hold_all_its_heights(tmp_path, monkeypatch):
    """RASCOR's step 2 limits are heights: from a sample of the tiles' central crops on a flat
    plain (terrain class flat), a hill 40 m high where four tiles meet (between the crops) lost its
    top as far outside the heights. The limits now hold the whole survey's heights (read every step-th cell)."""
    monkeypatch.setattr(plan, "SAMPLE_CELLS", 2 * 40 * 40)          # crops of 20 x 20 at the tiles' centres
    rng = np.random.default_rng(2)
    y, x = np.mgrid[0:192, 0:192]
    hill = 40.0 * np.exp(-((y - 96.0) ** 2 + (x - 96.0) ** 2) / (2 * 30.0 ** 2))
    z = (100.0 + hill + rng.normal(0.0, 0.05, hill.shape)).astype(np.float32)
    gt = (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0)
    tiles = []
    for i in range(0, 192, 96):
        for j in range(0, 192, 96):
            g = (gt[0] + j, 1.0, 0.0, gt[3] - i, 0.0, -1.0)
            tiles.append(grid.write_array(tmp_path / f"t{i // 96}{j // 96}.tif", z[i:i + 96, j:j + 96], g, 32632))
    logs = []
    rec = run_survey("rascor", tiles, tmp_path / "out", {"terrain_class": "flat"}, workers=1, log=logs.append)
    assert rec["sample"].startswith("central crops") and any("widened" in s for s in logs)
    assert rec["params"]["height_max_m"] > float(z.max())       # step 2 removes none of the hill


def test_tiles_under_other_names_and_names_differing_in_case(survey, tmp_path, monkeypatch):
    """QA15: a hard link of a tile (two names of one file, as 't00.TIF' is of 't00.tif' where case is ignored)
    was taken for a second tile, refused as 'tiles overlap'; tiles 'x' and 'X' (two folders) wrote one
    x_dtm.tif where the output folder ignores case, and an input VRT 'DTM.vrt' in the output folder was
    replaced by the survey's dtm.vrt there. Each is refused before any work, naming the files."""
    from bare_earth.core.grid import outputs
    from bare_earth.core.survey import check_output_folder
    paths = [str(p) for p in survey["tiles"][:3]]
    hard = tmp_path / "hard.tif"
    os.link(paths[1], hard)
    with pytest.raises(ValueError, match=rf"given twice: {re.escape(paths[1])} \(and as .*hard\.tif, the same file\)"):
        index_tiles(paths + [str(hard)])
    for sub, name, src in (("a", "x.tif", paths[0]), ("b", "X.tif", paths[1])):
        (tmp_path / sub).mkdir()
        (tmp_path / sub / name).write_bytes(Path(src).read_bytes())
    index = index_tiles([str(tmp_path / "a" / "x.tif"), str(tmp_path / "b" / "X.tif")])
    out = tmp_path / "out"
    out.mkdir()
    vrt = out / "DTM.vrt"
    vrt.write_text("<VRTDataset/>")
    assert outputs.folder_ignores_case(out) is False          # Linux's file systems count case: no collision
    check_output_folder(index, out, [str(vrt)])
    # the same where the output folder ignores case (mimicked, and 'DTM.vrt' made the file 'dtm.vrt' names)
    for module in (outputs, grid):
        monkeypatch.setattr(module, "folder_ignores_case", lambda folder: True)
    with pytest.raises(ValueError, match=r"have names differing only in case \(x, X\), but the output folder .*"
                                         r"ignores case: their outputs would be one file"):
        check_output_folder(index, out, [str(tmp_path / "a" / "x.tif"), str(tmp_path / "b" / "X.tif")])
    os.link(vrt, out / "dtm.vrt")
    with pytest.raises(ValueError, match=r"would replace the input '.*DTM\.vrt'"):
        check_output_folder(index_tiles(paths), out, [str(vrt)])


@pytest.mark.parametrize("method", ["morphological", "dtm"])
def test_progress_and_cancel_while_the_parameters_are_derived(survey, tmp_path, method):
    """QA15: the survey derived its parameters (a minute for dtm on a sample of 4096 x 4096 cells) without
    a progress report: the bar stood at 0 and a cancel waited for the first tile. The derivation takes the
    first tenth of the bar; a cancel there leaves nothing (no output folder, no run.json, no survey.vrt)."""
    from bare_earth.core.common import Cancelled
    from bare_earth.core.survey import run as survey_run
    seen = []

    def cancel_at_first(fraction):
        seen.append(fraction)
        raise Cancelled()

    out = tmp_path / "out"
    with pytest.raises(Cancelled):
        run_survey(method, survey["tiles"], out, workers=1, progress=cancel_at_first)
    assert len(seen) == 1 and 0.0 <= seen[0] <= survey_run.DERIVE_SHARE == 0.1
    assert not out.exists()


def test_a_folder_of_tiles_with_hidden_files(survey, tmp_path):
    """QA15: a folder of tiles copied from macOS onto a shared drive holds an AppleDouble file '._t00.tif'
    beside each tile (no raster): the survey refused every such folder ('tile(s) cannot be used: ._t00.tif').
    Hidden files are no tiles."""
    import shutil
    folder = tmp_path / "tiles"
    folder.mkdir()
    for p in survey["tiles"]:
        shutil.copy(p, folder)
        (folder / ("._" + os.path.basename(p))).write_bytes(b"\x00\x05\x16\x07\x00\x02\x00\x00Mac OS X")
    assert list_inputs(str(folder)) == sorted(str(folder / os.path.basename(p)) for p in survey["tiles"])
    assert len(index_tiles(str(folder)).tiles) == len(survey["tiles"])


def test_a_folder_without_tiles_names_the_fix_not_a_command_line_option(tmp_path):
    """QA25: a folder holding no raster was refused saying "point --input at the folder of the tiles", the
    command line's option, also in QGIS (whose parameter is INPUT_FOLDER); tiles in subfolders were not
    named. The message now says the subfolders are not read and names those holding rasters."""
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError) as exc:
        list_inputs(str(empty))
    assert "--input" not in str(exc.value) and "give the folder that holds the tiles" in str(exc.value)
    (tmp_path / "survey" / "block_a").mkdir(parents=True)
    (tmp_path / "survey" / "block_a" / "t00.tif").write_bytes(b"")
    (tmp_path / "survey" / "notes").mkdir()
    with pytest.raises(ValueError, match=r"its folder\(s\) block_a do: give the folder that holds the tiles "):
        list_inputs(str(tmp_path / "survey"))


@pytest.mark.parametrize("text", ["dh_m = 1", "dh_m =1", "dh_m= 1 slope=0.3"])
def test_parse_params_spaces_around_the_equals_sign(text):
    """QA15: 'dh_m = 1' in bareearth:tiles' PARAMETERS was refused as "parameter 'dh_m': write KEY=VALUE",
    which it was ('dh_m= 1': "parameter '1'"); the message says what is wrong. An empty value before the
    next parameter ('dh_m= slope=0.3': dh_m derived) is still taken."""
    meth = get_method("morphological")
    with pytest.raises(ValueError, match=r"write each KEY=VALUE without spaces around '=' \(spaces separate "
                                         r"parameters\)\.$"):
        parse_params(meth, text)
    assert parse_params(meth, "dh_m= slope=0.3") == {"dh_m": None, "slope": 0.3}


def test_tile_dtm_cells_interpolated_to_the_declared_nodata_stay_heights(tmp_path):
    """Tiles declaring 300 as nodata over ground alternating 299 / 301 m: a tile's DTM under a building,
    interpolated from that ground, held exactly 300 in many cells, read back as nodata in the tile and the
    mosaic. They are written just above, beyond GDAL's tolerance (one float32 step was still nodata in the
    VRT mosaic), and the log names the tile."""
    c = np.arange(160, dtype=np.float64)
    z = np.tile(299.0 + 2.0 * (c % 2), (60, 1))
    z[20:40, 30:50] += 12.0
    z[20:40, 110:130] += 12.0
    paths = []
    for k in range(2):
        p = tmp_path / f"t{k}.tif"
        grid.write_array(p, z[:, 80 * k:80 * (k + 1)].astype(np.float32),
                         (500000.0 + 80 * k, 1.0, 0.0, 5400000.0, 0.0, -1.0), 32632, nodata=300.0)
        paths.append(str(p))
    logs = []
    run_survey("morphological", paths, tmp_path / "out", workers=1, log=logs.append)
    d = read_mosaic(tmp_path / "out", "dtm")
    m = read_mosaic(tmp_path / "out", "mask")
    assert (m == 1).sum() == 800 and np.isfinite(d).all()          # no DTM cell read as nodata
    up = np.float32(300.00030517578125)                 # beyond GDAL's tolerance: the VRT reads it as a height
    assert (d == up).sum() > 100 and (m[d == up] == 1).all()
    said = [s for s in logs if "hold the declared nodata value 300 as a height" in s]
    assert len(said) == 2 and all(s.startswith("Warning: t") for s in said), logs


def test_tiles_of_cells_too_fine_for_their_heights_refused_before_any_work(tmp_path):
    """QA 17: a city at 1 mm cells made every filter's windows and slopes meaningless without a word
    (pipeline.check_relief); a survey of such tiles is refused too, before the cluster starts and with no
    output folder left; at 1 cm it runs with a warning in the log."""
    sc = make_scene("city", shape=(2 * TILE, 2 * TILE), seed=3)
    fine = dataclasses.replace(sc, geotransform=(500000.0, 0.001, 0.0, 5400000.0, 0.0, -0.001))
    tiles = write_survey(tmp_path / "mm", fine)
    with pytest.raises(ValueError, match=r"heights span [\d.]+ times the diagonal.*cell size is probably wrong"
                                         r".*\(in the whole survey"):
        run_survey("slopeprofile", tiles, tmp_path / "out", workers=1)
    assert not (tmp_path / "out").exists()
    cm = dataclasses.replace(sc, geotransform=(500000.0, 0.01, 0.0, 5400000.0, 0.0, -0.01))
    logs = []
    run_survey("slopeprofile", write_survey(tmp_path / "cm", cm), tmp_path / "out_cm", workers=1, log=logs.append)
    assert any(s.startswith("Warning: the heights span") for s in logs), logs


def test_survey_relief_checked_before_a_run_as_the_run_checks_it(tmp_path, monkeypatch):
    """QA 19: the survey's relief check ran in run_survey only, after the algorithm's dialog had accepted the
    tiles. check_survey_relief reads a survey that is its own sample (decimated) and refuses what run_survey
    refuses (a city at 1 mm cells, naming the whole survey), warns at 1 cm, passes at 1 m, and leaves nothing
    behind; a survey larger than the sample: None (the run checks its crops)."""
    from bare_earth.core.survey import check_survey_relief
    sc = make_scene("city", shape=(2 * TILE, 2 * TILE), seed=3)
    fine = dataclasses.replace(sc, geotransform=(500000.0, 0.001, 0.0, 5400000.0, 0.0, -0.001))
    index = index_tiles(write_survey(tmp_path / "mm", fine))
    with pytest.raises(ValueError, match=r"heights span [\d.]+ times the diagonal of the 192 x 192 cells of "
                                         r"0\.001 x 0\.001 m.*cell size is probably wrong.*\(in the whole survey "
                                         r"\(192 x 192 cells\)\)"):
        check_survey_relief(index)
    assert sorted(os.listdir(tmp_path / "mm")) == sorted(os.path.basename(t.path) for t in index.tiles)
    cm = dataclasses.replace(sc, geotransform=(500000.0, 0.01, 0.0, 5400000.0, 0.0, -0.01))
    assert "steeper than any terrain" in check_survey_relief(index_tiles(write_survey(tmp_path / "cm", cm)))
    assert check_survey_relief(index_tiles(write_survey(tmp_path / "m", sc))) is None
    monkeypatch.setattr(plan, "SAMPLE_CELLS", 100 * 100)
    assert check_survey_relief(index) is None


@pytest.mark.parametrize("mask_style", [False, True], ids=["dtm", "mask"])
def test_a_rewritten_tile_output_keeps_no_stale_side_file(tmp_path, mask_style):
    """A tile redone (after a kill, a failure, or a run.json deleted to start again) replaces its COG, but the
    old ``<tile>_dtm.tif.aux.xml`` stayed: ``gdalinfo -stats`` (or any tool computing statistics) writes one,
    and GDAL and QGIS then read the old file's statistics (and any georeferencing kept there, which GDAL reads
    before the TIFF's own) for the new file: a DTM of 100-104 m stated 0-4.47 m and drawn saturated."""
    from osgeo import gdal
    gt = (500000.0, 1.0, 0.0, 5400000.0, 0.0, -1.0)
    path = str(tmp_path / "t00_dtm.tif")
    old = np.arange(64 * 64, dtype=np.float32).reshape(64, 64) / 1000.0
    survey_io.write_cog(path, old.astype(np.uint8) if mask_style else old, gt, "", 255 if mask_style else None,
                        mask_style=mask_style)
    ds = gdal.Open(path)
    ds.GetRasterBand(1).ComputeStatistics(False)          # as gdalinfo -stats: written to the .aux.xml
    ds = None
    assert os.path.exists(path + ".aux.xml")
    new = np.full((64, 64), 100.0 if not mask_style else 1, np.float32)
    survey_io.write_cog(path, new.astype(np.uint8) if mask_style else new, gt, "", 255 if mask_style else None,
                        mask_style=mask_style)
    ds = gdal.Open(path)
    band = ds.GetRasterBand(1)
    assert band.GetMetadataItem("STATISTICS_MAXIMUM") is None     # the old file's statistics are gone
    assert band.ComputeRasterMinMax(False)[0] == new[0, 0]
    if mask_style:                                         # the mask keeps its category names
        assert band.GetCategoryNames()[1] == "object above ground"
    ds = None


def test_a_run_of_another_plugin_version_is_not_resumed(survey, tmp_path):
    """QA 22: a run killed (or cancelled, or with a failed tile) and resumed after the plugin was updated: the
    resume kept the old version's tiles and parameters and filtered the rest with the new code, so the mosaic
    joined tiles of two versions (their rules and derived parameters may differ: seams) and the new method got
    the old version's parameters. Now refused before any work, naming both versions; a record of this version,
    or of one that did not say its version, resumes as before."""
    from bare_earth.core.survey import record
    from bare_earth.meta import VERSION
    out = tmp_path / "out"
    out.mkdir()
    params = SMALL["slopeprofile"]
    index = index_tiles(survey["tiles"])
    rec = record.new_record({"method": "slopeprofile", "params": params, "tiles": [t.path for t in index.tiles]})
    assert rec["plugin_version"] == VERSION
    rec["plugin_version"] = "0.0.1-old"
    record.save_record(out, rec)
    before = sorted(os.listdir(out))
    with pytest.raises(ValueError, match=rf"made by Bare Earth 0\.0\.1-old.* this is {re.escape(VERSION)}"):
        run_survey("slopeprofile", survey["tiles"], out, params, workers=1)
    assert sorted(os.listdir(out)) == before
