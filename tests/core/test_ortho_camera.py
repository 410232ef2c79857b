"""Camera model: omega-phi-kappa convention, collinearity, Brown distortion, readers."""
import math

import numpy as np
import pytest

from bare_earth.core.orthophoto.camera import (
    Camera,
    Interior,
    cameras_from_opk,
    opk_to_rotation,
    read_interior_yaml,
    read_opensfm_reconstruction,
    read_opk_csv,
    rotation_to_opk,
)
from bare_earth.core.orthophoto.orthorectify import grid_xy, orthorectify


def test_opk_convention_elementary_rotations():
    # R = Rx(omega) Ry(phi) Rz(kappa), camera -> world
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    np.testing.assert_allclose(opk_to_rotation(30, 0, 0), [[1, 0, 0], [0, c, -s], [0, s, c]], atol=1e-15)
    np.testing.assert_allclose(opk_to_rotation(0, 30, 0), [[c, 0, s], [0, 1, 0], [-s, 0, c]], atol=1e-15)
    np.testing.assert_allclose(opk_to_rotation(0, 0, 30), [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-15)
    R = opk_to_rotation(10, -20, 130)
    np.testing.assert_allclose(R, opk_to_rotation(10, 0, 0) @ opk_to_rotation(0, -20, 0)
                               @ opk_to_rotation(0, 0, 130), atol=1e-15)
    np.testing.assert_allclose(rotation_to_opk(R), (10, -20, 130), atol=1e-10)


def test_opk_rejects_bad_angles():
    with pytest.raises(ValueError, match="finite"):
        opk_to_rotation(float("nan"), 0, 0)


def _vertical(kappa=0.0, f=1000.0, w=400, h=300):
    io = Interior(w, h, f, f, (w - 1) / 2, (h - 1) / 2)
    return Camera.vertical(io, 500.0, 1000.0, 1200.0, kappa_deg=kappa)


def test_vertical_camera_projects_as_collinearity_predicts():
    cam = _vertical()
    # nadir point -> principal point; a point 40 m east and 20 m north at 200 m height:
    # x = f * dX / (Zc - Z) = 1000 * 40 / 1000, image rows go south
    col, row = cam.project(np.array([500.0, 540.0]), np.array([1000.0, 1020.0]), np.array([0.0, 200.0]))
    np.testing.assert_allclose(col, [199.5, 199.5 + 40.0], atol=1e-9)
    np.testing.assert_allclose(row, [149.5, 149.5 - 20.0], atol=1e-9)
    # kappa = 180: image top to the south, so east goes left and north goes down
    col, row = _vertical(180).project(540.0, 1020.0, 200.0)
    np.testing.assert_allclose([col, row], [199.5 - 40.0, 149.5 + 20.0], atol=1e-9)


def test_tilted_camera_round_trip_and_behind():
    io = Interior.from_params((640, 480), 0.8, None, 0.01, -0.02, -0.2, 0.08, -0.01, 1e-3, -5e-4)
    cam = Camera.from_opk(io, 10.0, 20.0, 150.0, 25.0, -15.0, 60.0)
    rng = np.random.default_rng(0)
    col = rng.uniform(0, 639, 200)
    row = rng.uniform(0, 479, 200)
    Z = rng.uniform(-10, 40, 200)
    X, Y, Z2 = cam.pixel_to_world(col, row, Z)
    np.testing.assert_allclose(Z2, Z, atol=1e-9)
    c2, r2 = cam.project(X, Y, Z)
    np.testing.assert_allclose(c2, col, atol=1e-6)
    np.testing.assert_allclose(r2, row, atol=1e-6)
    # a point above the camera's back is behind it: NaN
    c3, _ = _vertical().project(500.0, 1000.0, 2000.0)
    assert np.isnan(c3)


def test_brown_inverse_is_exact():
    io = Interior.from_params((1368, 912), 0.666, None, 0, 0, -0.264, 0.1019, -0.0258, 7.3e-4, 2.6e-4)
    x, y = np.meshgrid(np.linspace(-0.7, 0.7, 15), np.linspace(-0.45, 0.45, 11))
    xd, yd = io.distort(x, y)
    assert np.abs(xd - x).max() > 0.05          # the distortion is not negligible
    xu, yu = io.undistort(xd, yd)
    np.testing.assert_allclose(xu, x, atol=1e-10)
    np.testing.assert_allclose(yu, y, atol=1e-10)


def test_interior_from_sensor_size():
    io = Interior.from_params((640, 1152), 120.0, (92.16, 165.888))
    assert io.fx == pytest.approx(120 / 0.144) and io.fy == pytest.approx(120 / 0.144)
    assert (io.c0, io.r0) == (319.5, 575.5)
    with pytest.raises(ValueError, match="focal"):
        Interior(10, 10, -1.0, 1.0, 4.5, 4.5)


def test_orthophoto_lines_up_with_dem():
    """A ground point shows in the orthophoto cell where the collinearity equations put it."""
    io = Interior(201, 201, 400.0, 400.0, 100.0, 100.0)
    cam = Camera.from_opk(io, 50.0, 50.0, 300.0, 3.0, -4.0, 20.0)
    rows, cols = np.indices((io.height, io.width))
    image = (np.sin(rows * 0.37) + np.cos(cols * 0.23) + 0.01 * rows * cols).astype(np.float32)
    transform = (0.0, 1.0, 0.0, 100.0, 0.0, -1.0)
    X, Y = grid_xy((100, 100), transform)
    dem = (20 + 0.1 * X + 0.05 * Y + 3 * np.sin(X / 10)) * np.ones((100, 1))
    ortho, seen = orthorectify(image, cam, dem, transform)
    assert seen.mean() > 0.5
    i, j = 37, 61
    col, row = cam.project(X[0, j], Y[i, 0], dem[i, j])
    # bilinear interpolation of the image at the predicted pixel
    c0, r0 = int(np.floor(col)), int(np.floor(row))
    fc, fr = col - c0, row - r0
    expect = ((1 - fr) * ((1 - fc) * image[r0, c0] + fc * image[r0, c0 + 1])
              + fr * ((1 - fc) * image[r0 + 1, c0] + fc * image[r0 + 1, c0 + 1]))
    assert ortho[i, j] == pytest.approx(expect, abs=1e-4)
    with pytest.raises(ValueError, match="interior orientation"):
        orthorectify(image[:, :-1], cam, dem, transform)


def test_read_opk_csv_errors(tmp_path):
    p = tmp_path / "ext.csv"
    p.write_text("filename,x,y,z,omega,phi,kappa\na.tif,1,2,3,0.5,-0.2,90\nb,1,2,3,0,0,10\n")
    ext = read_opk_csv(p)
    assert set(ext) == {"a", "b"} and ext["a"]["kappa"] == 90
    io = Interior(10, 10, 10.0, 10.0, 4.5, 4.5)
    with pytest.raises(ValueError, match="no exterior orientation for image"):
        cameras_from_opk(ext, io, ["a", "c"])
    p.write_text("filename,x,y,z,omega,phi,kappa\na,1,2,3,0.5,abc,90\n")
    with pytest.raises(ValueError, match="not a number"):
        read_opk_csv(p)
    p.write_text("filename,x,y,z,omega,phi,kappa\na,1,2,3,0.5,700,90\n")
    with pytest.raises(ValueError, match="degrees"):
        read_opk_csv(p)
    p.write_text("filename,x,y,z,omega,phi\na,1,2,3,0.5,7\n")
    with pytest.raises(ValueError, match="kappa"):
        read_opk_csv(p)


def test_read_opk_csv_of_a_spreadsheet_with_semicolons(tmp_path):
    """A spreadsheet's CSV in a locale with decimal commas ('a;1,5;...') reads as the comma CSV
    (it was refused with a header 'lacking' every column); a tie-point file too."""
    from bare_earth.algorithms.orthophoto import read_tie_points
    comma, semi = tmp_path / "comma.csv", tmp_path / "semi.csv"
    comma.write_text("filename,x,y,z,omega,phi,kappa\na.tif,500001.25,5400002.5,300,0.5,-0.25,90\n")
    semi.write_text("filename;x;y;z;omega;phi;kappa\na.tif;500001,25;5400002,5;300;0,5;-0,25;90\n")
    assert read_opk_csv(semi) == read_opk_csv(comma)
    rows = [(n, 500001.5 + k, 5400002.0 - k, 10.25 + k, 20.5 + 2 * k) for n in "ab" for k in range(4)]
    (tmp_path / "ties.csv").write_text("image,x,y,col,row\n" + "".join(",".join(map(str, r)) + "\n" for r in rows))
    (tmp_path / "ties_semi.csv").write_text("image;x;y;col;row\n" + "".join(
        ";".join(str(v).replace(".", ",") for v in r) + "\n" for r in rows))
    want, got = (read_tie_points(tmp_path / f, ["a", "b"]) for f in ("ties.csv", "ties_semi.csv"))
    assert all(np.array_equal(w[0], g[0]) and np.array_equal(w[1], g[1]) for w, g in zip(want, got))
    assert got[1][1][0].tolist() == [10.25, 20.5]


def test_orthority_files(shared_data):
    d = shared_data / "stereo" / "orthority"
    ios = read_interior_yaml(d / "io" / "ngi_int_param.yaml")
    io = ios["Integraph DMC"]
    assert (io.width, io.height) == (640, 1152) and io.fx == pytest.approx(833.333, rel=1e-5)
    cams = cameras_from_opk(read_opk_csv(d / "io" / "ngi_xyz_opk.csv"), ios)
    assert len(cams) == 4
    # the OPK angles orthority wrote for the drone frames equal those of OpenSfM's poses:
    # this pins the convention R = Rx(omega) Ry(phi) Rz(kappa), camera x right, y up, z back.
    _, sfm, ref = read_opensfm_reconstruction(d / "odm" / "opensfm" / "reconstruction.json")
    ext = read_opk_csv(d / "io" / "odm_xyz_opk.csv")
    for name, cam in sfm.items():
        np.testing.assert_allclose(cam.opk_deg, [ext[name][k] for k in ("omega", "phi", "kappa")],
                                   atol=2e-3)
    assert ref["latitude"] == pytest.approx(24.68, abs=0.01)


def test_brown_forward_formula_pinned():
    # OpenSfM / OpenCV Brown-Conrady: radial on r^2, tangential p1 (y), p2 (x)
    io = Interior(100, 100, 50.0, 50.0, 49.5, 49.5, k1=0.1, k2=-0.05, k3=0.02, p1=0.01, p2=-0.02)
    x, y = 0.3, -0.2
    r2 = x * x + y * y
    radial = 1 + 0.1 * r2 - 0.05 * r2 ** 2 + 0.02 * r2 ** 3
    xd = x * radial + 2 * 0.01 * x * y + (-0.02) * (r2 + 2 * x * x)
    yd = y * radial + 0.01 * (r2 + 2 * y * y) + 2 * (-0.02) * x * y
    np.testing.assert_allclose(io.distort(x, y), (xd, yd), rtol=1e-14)
    # the projection applies it: a camera looking down, point at ideal (x, y)
    cam = Camera.vertical(io, 0.0, 0.0, 10.0)
    col, row = cam.project(x * 10.0, -y * 10.0, 0.0)       # image y down = world -Y
    np.testing.assert_allclose([col, row], [49.5 + 50 * xd, 49.5 + 50 * yd], atol=1e-10)


def test_tiny_yaml_parser_reads_interior_files(tmp_path, monkeypatch):
    from bare_earth.core.orthophoto import camera as cam_mod
    text = ("Integraph DMC:\n    type: pinhole\n    im_size: [640, 1152]\n    focal_len: 120.0\n"
            "    sensor_size: [92.16, 165.888]   # mm\n    cx: 0.0\n    cy: 0.0\n"
            "drone cam:\n  type: brown\n  im_size: [1368, 912]\n  focal_len: 0.6665\n"
            "  k1: -0.264\n  k2: 0.1019\n  p1: 0.00073\n  p2: 0.00026\n  k3: -0.0258\n"
            "  cx: -0.0015\n  cy: 0.0048\n")
    parsed = cam_mod.parse_tiny_yaml(text)
    assert parsed["Integraph DMC"]["im_size"] == [640, 1152]
    assert parsed["drone cam"]["k3"] == pytest.approx(-0.0258)
    p = tmp_path / "int.yaml"
    p.write_text(text)
    import builtins
    real_import = builtins.__import__

    def no_yaml(name, *a, **k):
        if name == "yaml":
            raise ImportError("no PyYAML")
        return real_import(name, *a, **k)
    monkeypatch.setattr(builtins, "__import__", no_yaml)
    ios = read_interior_yaml(p)
    assert ios["drone cam"].k1 == pytest.approx(-0.264)
    assert ios["drone cam"].fx == pytest.approx(0.6665 * 1368)
    assert ios["drone cam"].r0 == pytest.approx(455.5 + 0.0048 * 1368)
    p.write_text("cam:\n  type: fisheye\n  im_size: [10, 10]\n  focal_len: 1.0\n")
    with pytest.raises(ValueError, match="supported"):
        read_interior_yaml(p)


def test_read_cameras(shared_data, tmp_path):
    from bare_earth.core.orthophoto.camera import read_cameras
    d = shared_data / "stereo" / "orthority"
    ngi = read_cameras(d / "io" / "ngi_xyz_opk.csv", d / "io" / "ngi_int_param.yaml",
                       ["3324c_2015_1004_06_0251_RGB.tif"])
    assert ngi[0].name == "3324c_2015_1004_06_0251_RGB" and ngi[0].centre[2] == pytest.approx(5229.213)
    odm = read_cameras(d / "io" / "odm_xyz_opk.csv", d / "odm" / "opensfm" / "reconstruction.json")
    assert len(odm) == 4 and odm[0].interior.has_distortion
    with pytest.raises(ValueError, match="unknown interior"):
        read_cameras(d / "io" / "ngi_xyz_opk.csv", tmp_path / "x.txt")


YAML_HEAD = "cam:\n  type: brown\n"
SIZE = YAML_HEAD + "  im_size: [640, 480]\n"
BAD_INTERIOR = [
    ("int.yaml", "cam:\n  im_size: [640, 480\n  focal_len: 0.5\n", r"not valid YAML"),
    ("int.yaml", YAML_HEAD + "  im_size: [640]\n  focal_len: 0.5\n",
     r"camera 'cam': im_size is \[640\]; give \[number, number\]"),
    ("int.yaml", YAML_HEAD + "  im_size: 640x480\n  focal_len: 0.5\n", r"im_size is '640x480'"),
    ("int.yaml", YAML_HEAD + "  im_size: [640.5, 480]\n  focal_len: 0.5\n",
     r"im_size is \[640.5, 480\]; give \[width, height\] in whole"),
    ("int.yaml", SIZE + "  focal_len: 8.8mm\n", r"focal_len is '8.8mm'; give a number or \[number, number\]"),
    ("int.yaml", SIZE + "  focal_len: [0.5, 0.5, 0.5]\n", r"focal_len is \[0.5, 0.5, 0.5\]"),
    ("int.yaml", SIZE + "  focal_len: 0.5\n  cx: abc\n", r"cx is 'abc'; give a number"),
    ("int.yaml", SIZE + "  focal_len: 8\n  sensor_size: 13.2\n", r"sensor_size is 13.2"),
    ("int.yaml", SIZE + "  focal_len: 0.5\n  k1: .nan\n", r"k1 is nan"),
    ("rec.json", "", r"rec.json: not valid JSON"),
    ("rec.json", "[]", r"not an OpenSfM reconstruction"),
    ("rec.json", '"text"', r"not an OpenSfM reconstruction"),
    ("rec.json", '{"cameras": {"c": {"focal": 0.5}}}', r"camera 'c' lacks width, height"),
    ("rec.json", '{"cameras": {"c": {"focal": 0.5, "width": 640, "height": 480}}, "shots": {"a.jpg": '
                 '{"camera": "other", "rotation": [0, 0, 0], "translation": [0, 0, 0]}}}',
     r"shot 'a.jpg': its camera 'other' is not among the reconstruction's cameras \['c'\]"),
    ("rec.json", '{"cameras": {"c": {"focal": 0.5, "width": 640, "height": 480}}, "shots": {"a.jpg": '
                 '{"camera": "c", "rotation": [0, 0], "translation": [0, 0, 0]}}}', r"rotation is \[0, 0\]"),
]


@pytest.mark.parametrize("name,text,message", BAD_INTERIOR)
def test_malformed_interior_orientation_is_a_value_error_naming_the_key(tmp_path, name, text, message):
    """Interior files with a YAML syntax error, units in a number ('8.8mm'), lists of the wrong
    length, a missing key or a shot of an unknown camera: each raised a bare Python error
    (yaml.ParserError, TypeError, KeyError, IndexError, AttributeError; a traceback in QGIS) or
    'not enough values to unpack'; now a ValueError naming the file, the camera and the key."""
    from bare_earth.core.orthophoto.camera import read_cameras
    p = tmp_path / name
    p.write_text(text)
    ext = tmp_path / "ext.csv"
    ext.write_text("filename,x,y,z,omega,phi,kappa,camera\na.jpg,0,0,100,0,0,0,c\n")
    with pytest.raises(ValueError, match=message):
        read_cameras(ext, p)


def test_interior_yaml_with_a_byte_order_mark_and_quoted_numbers_reads(tmp_path):
    p = tmp_path / "int.yaml"
    p.write_text("\ufeffcam:\n  im_size: [640, 480]\n  focal_len: '0.5'\n  cx: 0.01\n", encoding="utf-8")
    io = read_interior_yaml(p)["cam"]
    assert (io.width, io.height) == (640, 480) and io.fx == pytest.approx(320.0)
    assert io.c0 == pytest.approx(319.5 + 6.4)


def test_exterior_from_a_spreadsheets_unicode_text_and_a_legacy_code_page(tmp_path):
    """Excel's "Unicode Text" export: UTF-16 with its byte-order mark, tab-separated, decimal
    commas in a European locale. It raised a bare UnicodeDecodeError naming no file (and the
    tabs' decimal commas were "not a number"). A file in a legacy code page with a non-ASCII
    name is a ValueError naming the file and the fix."""
    p = tmp_path / "ext.txt"
    p.write_bytes("filename\tx\ty\tz\tomega\tphi\tkappa\nÅs_1.jpg\t500000,5\t5400000,25\t300\t0,1\t-0,2\t90\n"
                  .encode("utf-16"))
    e = read_opk_csv(str(p))
    assert e["Ås_1"] == {"x": 500000.5, "y": 5400000.25, "z": 300.0, "omega": 0.1, "phi": -0.2, "kappa": 90.0}
    latin = tmp_path / "latin.csv"
    latin.write_bytes("filename,x,y,z,omega,phi,kappa\nÅs_1.jpg,1,2,3,0,0,0\n".encode("latin-1"))
    with pytest.raises(ValueError, match=r"latin.csv' is not UTF-8 text .*save it as UTF-8"):
        read_opk_csv(str(latin))


def test_a_camera_column_naming_another_camera_than_the_interior_file_is_refused(tmp_path):
    """QA: the EXTERIOR rows name their camera ('camera' column) and the INTERIOR file holds one camera of
    another id: that one camera was used for every frame without a word (the wrong camera file given, e.g.
    another flight's of the same image size, orthorectifies every frame with the wrong focal length). Now
    refused naming the image, the id and the ids held; a camera column naming the one camera, a file whose
    one camera has no id, rows without the column, or an empty cell still take the one camera."""
    (tmp_path / "io.yaml").write_text("DMC:\n  type: pinhole\n  im_size: [640, 480]\n  focal_len: 1.2\n")
    (tmp_path / "anon.yaml").write_text("type: pinhole\nim_size: [640, 480]\nfocal_len: 1.2\n")
    row = "a,500000,5400000,1000,0,0,0"
    (tmp_path / "other.csv").write_text(f"filename,x,y,z,omega,phi,kappa,camera\n{row},UltraCam\n")
    ios, anon = read_interior_yaml(tmp_path / "io.yaml"), read_interior_yaml(tmp_path / "anon.yaml")
    with pytest.raises(ValueError, match=r"image 'a': camera id 'UltraCam' .*not among .*\['DMC'\]"):
        cameras_from_opk(read_opk_csv(tmp_path / "other.csv"), ios)
    assert cameras_from_opk(read_opk_csv(tmp_path / "other.csv"), anon)[0].interior is anon["camera"]
    for name, text in (("same", f"{row},DMC"), ("none", row), ("empty", f"{row},")):
        header = "filename,x,y,z,omega,phi,kappa" + (",camera" if name != "none" else "")
        (tmp_path / f"{name}.csv").write_text(f"{header}\n{text}\n")
        assert cameras_from_opk(read_opk_csv(tmp_path / f"{name}.csv"), ios)[0].interior is ios["DMC"], name
