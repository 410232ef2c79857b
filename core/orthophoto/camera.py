"""Frame cameras: interior and exterior orientation, Brown distortion, collinearity.

The orthophoto refinement of Luong Chinh Ke (2002, section 2.3) and Norvelle (1995) needs
one thing from a camera: where a ground point ``(X, Y, Z)`` appears in the image (the
collinearity equations) so that an orthophoto can be drawn on a DEM. This module holds that
model and the readers of the usual orientation files.

Conventions
-----------
World coordinates ``(X, Y, Z)``: a projected CRS, X east, Y north, Z up (metres).

Rotation (omega, phi, kappa), degrees: the photogrammetric convention used by orthority's
``opk`` files (and PATB/BLUH, Pix4D),

    R = R_x(omega) @ R_y(phi) @ R_z(kappa),

with the right-handed elementary rotations ``R_x(a) = [[1,0,0],[0,cos a,-sin a],[0,sin a,cos a]]``,
``R_y(a) = [[cos a,0,sin a],[0,1,0],[-sin a,0,cos a]]``,
``R_z(a) = [[cos a,-sin a,0],[sin a,cos a,0],[0,0,1]]``. ``R`` rotates *camera* axes into
*world* axes: a vector ``v_c`` in the camera frame is ``R @ v_c`` in the world frame. The camera
frame is x right, y up (towards the top of the image), z backwards (the camera looks along
-z). So omega = phi = kappa = 0 is a vertical photo with the image top to the north, and
kappa = 180 deg a vertical photo with the image top to the south.

Image coordinates: pixel ``(col, row)``, the centre of the top-left pixel at ``(0, 0)``, rows
down. The principal point is ``((w - 1) / 2, (h - 1) / 2)`` plus the offsets ``cx, cy`` given
in normalised units (multiples of ``max(w, h)``, x right, y down), as in OpenSfM and
orthority. The collinearity equations with distortion are, for ``p = R.T @ (P - C)``:

    x = p_x / -p_z,  y = -p_y / -p_z                  (ideal, x right, y down)
    r2 = x^2 + y^2
    x_d = x (1 + k1 r2 + k2 r2^2 + k3 r2^3) + 2 p1 x y + p2 (r2 + 2 x^2)
    y_d = y (1 + k1 r2 + k2 r2^2 + k3 r2^3) + p1 (r2 + 2 y^2) + 2 p2 x y
    col = c0 + f_x x_d,  row = r0 + f_y y_d           (Brown-Conrady, OpenSfM ``brown``)
"""
import csv
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..common import text_of

__all__ = ["Interior", "Camera", "opk_to_rotation", "rotation_to_opk", "read_opk_csv",
           "read_interior_yaml", "read_opensfm_reconstruction", "cameras_from_opk", "read_cameras",
           "parse_tiny_yaml", "read_table_rows"]


# --------------------------------------------------------------------------- rotation
def opk_to_rotation(omega_deg, phi_deg, kappa_deg):
    """Camera-to-world rotation ``R = R_x(omega) R_y(phi) R_z(kappa)`` from angles in degrees.

    Parameters
    ----------
    omega_deg, phi_deg, kappa_deg : float
        Photogrammetric omega, phi, kappa in degrees (orthority / PATB convention, see the
        module docstring).

    Returns
    -------
    ndarray, shape (3, 3)
        ``R`` with ``v_world = R @ v_camera`` (camera x right, y up, z backwards).

    Raises
    ------
    ValueError
        When an angle is not a finite number.
    """
    angles = np.array([omega_deg, phi_deg, kappa_deg], dtype=float)
    if not np.all(np.isfinite(angles)):
        raise ValueError(f"omega, phi, kappa must be finite numbers of degrees; got {angles.tolist()}. "
                         "Fix the exterior orientation.")
    o, p, k = np.radians(angles)
    rx = np.array([[1, 0, 0], [0, math.cos(o), -math.sin(o)], [0, math.sin(o), math.cos(o)]])
    ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    rz = np.array([[math.cos(k), -math.sin(k), 0], [math.sin(k), math.cos(k), 0], [0, 0, 1]])
    return rx @ ry @ rz


def rotation_to_opk(R):
    """Inverse of :func:`opk_to_rotation`: (omega, phi, kappa) in degrees.

    Returns phi in [-90, 90]; omega, kappa in (-180, 180].
    """
    R = np.asarray(R, dtype=float)
    omega = math.atan2(-R[1, 2], R[2, 2])
    phi = math.asin(max(-1.0, min(1.0, R[0, 2])))
    kappa = math.atan2(-R[0, 1], R[0, 0])
    return tuple(math.degrees(a) for a in (omega, phi, kappa))


def _rodrigues(rvec):
    """Rotation matrix of an angle-axis vector (radians)."""
    rvec = np.asarray(rvec, dtype=float)
    theta = float(np.linalg.norm(rvec))
    if theta < 1e-15:
        return np.eye(3)
    k = rvec / theta
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(theta) * K + (1 - math.cos(theta)) * K @ K


# camera frame (x right, y up, z back) <-> computer-vision frame (x right, y down, z forward)
_FLIP = np.diag([1.0, -1.0, -1.0])


# --------------------------------------------------------------------------- interior
@dataclass
class Interior:
    """Interior orientation of a frame camera (pinhole + Brown distortion).

    Attributes
    ----------
    width, height : int
        Image size in pixels.
    fx, fy : float
        Focal length in pixels.
    c0, r0 : float
        Principal point in pixel coordinates (top-left pixel centre = 0, 0).
    k1, k2, k3, p1, p2 : float
        Brown-Conrady radial and tangential coefficients on normalised coordinates (OpenSfM).
    name : str
        Camera identifier.
    """
    width: int
    height: int
    fx: float
    fy: float
    c0: float
    r0: float
    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    name: str = ""

    def __post_init__(self):
        if int(self.width) < 1 or int(self.height) < 1:
            raise ValueError(f"image size must be positive pixels; got {self.width} x {self.height}. "
                             "Fix im_size in the interior orientation.")
        if not (np.isfinite(self.fx) and np.isfinite(self.fy) and self.fx > 0 and self.fy > 0):
            raise ValueError(f"focal length must be positive; got fx={self.fx}, fy={self.fy}. "
                             "Fix focal_len (and sensor_size) in the interior orientation.")
        self.width, self.height = int(self.width), int(self.height)

    @classmethod
    def from_params(cls, im_size, focal_len, sensor_size=None, cx=0.0, cy=0.0, k1=0.0, k2=0.0,
                    k3=0.0, p1=0.0, p2=0.0, name=""):
        """Build from orthority / OpenSfM style parameters.

        Parameters
        ----------
        im_size : (int, int)
            ``(width, height)`` in pixels.
        focal_len : float or (float, float)
            Focal length, in the units of ``sensor_size``; without ``sensor_size`` it is
            normalised by ``max(width, height)`` (OpenSfM ``focal``).
        sensor_size : (float, float), optional
            Sensor ``(width, height)`` in the units of ``focal_len`` (e.g. mm): gives the pixel size.
        cx, cy : float
            Principal point offsets in units of ``max(width, height)`` (x right, y down).
        k1, k2, k3, p1, p2 : float
            Brown distortion.
        """
        w, h = (int(v) for v in im_size)
        f = np.atleast_1d(np.asarray(focal_len, dtype=float))
        fxn, fyn = (f[0], f[0]) if f.size == 1 else (f[0], f[1])
        if sensor_size is not None:
            sw, sh = (float(v) for v in sensor_size)
            if sw <= 0 or sh <= 0:
                raise ValueError(f"sensor_size must be positive; got {sensor_size}. Fix the interior orientation.")
            fx, fy = fxn * w / sw, fyn * h / sh       # focal / pixel size
        else:
            fx, fy = fxn * max(w, h), fyn * max(w, h)
        s = max(w, h)
        return cls(w, h, fx, fy, (w - 1) / 2.0 + cx * s, (h - 1) / 2.0 + cy * s,
                   k1, k2, k3, p1, p2, name)

    @property
    def has_distortion(self):
        return any(v != 0 for v in (self.k1, self.k2, self.k3, self.p1, self.p2))

    def distort(self, x, y):
        """Brown-Conrady distortion of ideal normalised coordinates (x right, y down)."""
        if not self.has_distortion:
            return x, y
        r2 = x * x + y * y
        radial = 1 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = x * radial + 2 * self.p1 * x * y + self.p2 * (r2 + 2 * x * x)
        yd = y * radial + self.p1 * (r2 + 2 * y * y) + 2 * self.p2 * x * y
        return xd, yd

    def ideal_extent(self):
        """Largest ``|x|``, ``|y|`` of ideal (undistorted) coordinates on the image border."""
        w, h = self.width, self.height
        t = np.linspace(0, 1, 65)
        cols = np.concatenate([t * (w - 1), t * (w - 1), np.zeros(65), np.full(65, w - 1.0)])
        rows = np.concatenate([np.zeros(65), np.full(65, h - 1.0), t * (h - 1), t * (h - 1)])
        x, y = self.undistort((cols - self.c0) / self.fx, (rows - self.r0) / self.fy)
        return float(np.nanmax(np.abs(x))), float(np.nanmax(np.abs(y)))

    def undistort(self, xd, yd, iterations=30):
        """Inverse of :meth:`distort` by Newton iterations (vectorised, 2-D Jacobian)."""
        xd = np.asarray(xd, dtype=float)
        yd = np.asarray(yd, dtype=float)
        if not self.has_distortion:
            return xd.copy(), yd.copy()
        x, y = xd.copy(), yd.copy()
        k1, k2, k3, p1, p2 = self.k1, self.k2, self.k3, self.p1, self.p2
        for _ in range(iterations):
            r2 = x * x + y * y
            rad = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            drad = k1 + r2 * (2 * k2 + 3 * k3 * r2)          # d rad / d r2
            fx_ = x * rad + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) - xd
            fy_ = y * rad + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y - yd
            a = rad + 2 * x * x * drad + 2 * p1 * y + 6 * p2 * x
            b = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
            c = 2 * x * y * drad + 2 * p1 * x + 2 * p2 * y
            d = rad + 2 * y * y * drad + 6 * p1 * y + 2 * p2 * x
            det = a * d - b * c
            det = np.where(np.abs(det) < 1e-12, 1e-12, det)
            dx = (d * fx_ - b * fy_) / det
            dy = (a * fy_ - c * fx_) / det
            x, y = x - dx, y - dy
            if np.nanmax(np.abs(dx) + np.abs(dy), initial=0.0) < 1e-13:
                break
        return x, y


# --------------------------------------------------------------------------- camera
@dataclass
class Camera:
    """A frame camera: interior orientation, projection centre and rotation.

    Attributes
    ----------
    interior : Interior
    centre : ndarray (3,)
        Projection centre ``(X, Y, Z)`` in world units.
    R : ndarray (3, 3)
        Camera-to-world rotation (camera x right, y up, z backwards; see module docstring).
    name : str
    """
    interior: Interior
    centre: np.ndarray
    R: np.ndarray
    name: str = ""
    opk_deg: tuple = field(default=None)

    def __post_init__(self):
        self.centre = np.asarray(self.centre, dtype=float).reshape(3)
        self.R = np.asarray(self.R, dtype=float).reshape(3, 3)
        if not np.all(np.isfinite(self.centre)):
            raise ValueError(f"camera {self.name!r}: centre must be finite; got {self.centre}.")
        if not np.allclose(self.R @ self.R.T, np.eye(3), atol=1e-6):
            raise ValueError(f"camera {self.name!r}: R is not a rotation matrix; check the angles.")

    @classmethod
    def from_opk(cls, interior, x, y, z, omega_deg, phi_deg, kappa_deg, name=""):
        """Camera from a projection centre and omega, phi, kappa in degrees."""
        return cls(interior, (x, y, z), opk_to_rotation(omega_deg, phi_deg, kappa_deg), name,
                   (float(omega_deg), float(phi_deg), float(kappa_deg)))

    @classmethod
    def vertical(cls, interior, x, y, z, kappa_deg=0.0, name=""):
        """A vertical (nadir) camera at ``(x, y, z)``."""
        return cls.from_opk(interior, x, y, z, 0.0, 0.0, kappa_deg, name)

    def world_to_camera(self, X, Y, Z):
        """Coordinates in the computer-vision camera frame (x right, y down, z forward)."""
        Rcv = (self.R @ _FLIP).T                      # world -> cv camera
        dX = np.asarray(X, dtype=float) - self.centre[0]
        dY = np.asarray(Y, dtype=float) - self.centre[1]
        dZ = np.asarray(Z, dtype=float) - self.centre[2]
        xc = Rcv[0, 0] * dX + Rcv[0, 1] * dY + Rcv[0, 2] * dZ
        yc = Rcv[1, 0] * dX + Rcv[1, 1] * dY + Rcv[1, 2] * dZ
        zc = Rcv[2, 0] * dX + Rcv[2, 1] * dY + Rcv[2, 2] * dZ
        return xc, yc, zc

    def project(self, X, Y, Z):
        """Collinearity equations: pixel ``(col, row)`` of ground points, with distortion.

        Parameters
        ----------
        X, Y, Z : array_like
            World coordinates (broadcast together).

        Returns
        -------
        col, row : ndarray of float64
            Pixel coordinates (top-left pixel centre = 0, 0); NaN for points behind the camera.
        """
        xc, yc, zc = self.world_to_camera(X, Y, Z)
        with np.errstate(divide="ignore", invalid="ignore"):
            front = zc > 0
            x = np.where(front, xc / np.where(front, zc, 1.0), np.nan)
            y = np.where(front, yc / np.where(front, zc, 1.0), np.nan)
        io = self.interior
        if io.has_distortion:
            # the Brown polynomial folds back far outside the frame: keep rays within the
            # field of view (ideal coordinates of the image border, plus a margin)
            xmax, ymax = io.ideal_extent()
            with np.errstate(invalid="ignore"):
                out = (np.abs(x) > 1.1 * xmax) | (np.abs(y) > 1.1 * ymax)
            x = np.where(out, np.nan, x)
            y = np.where(out, np.nan, y)
        xd, yd = io.distort(x, y)
        return io.c0 + io.fx * xd, io.r0 + io.fy * yd

    def pixel_to_ray(self, col, row):
        """World direction vectors (3, ...) of the rays through pixels (distortion removed)."""
        io = self.interior
        xd = (np.asarray(col, dtype=float) - io.c0) / io.fx
        yd = (np.asarray(row, dtype=float) - io.r0) / io.fy
        x, y = io.undistort(xd, yd)
        Rcv = self.R @ _FLIP                           # cv camera -> world
        v = np.stack([x, y, np.ones_like(x)])
        return np.tensordot(Rcv, v, axes=1)

    def pixel_to_world(self, col, row, Z):
        """Intersect the rays of pixels with the horizontal plane(s) of height ``Z``."""
        d = self.pixel_to_ray(col, row)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (np.asarray(Z, dtype=float) - self.centre[2]) / d[2]
            t = np.where(t > 0, t, np.nan)
        return self.centre[0] + t * d[0], self.centre[1] + t * d[1], self.centre[2] + t * d[2]

    def footprint(self, Z):
        """Ground polygon (4, 2) of the image corners on the plane of height ``Z``."""
        w, h = self.interior.width, self.interior.height
        c = np.array([-0.5, w - 0.5, w - 0.5, -0.5])
        r = np.array([-0.5, -0.5, h - 0.5, h - 0.5])
        X, Y, _ = self.pixel_to_world(c, r, Z)
        return np.column_stack([X, Y])


# --------------------------------------------------------------------------- readers
_DECIMAL_COMMA = re.compile(r"^[+-]?\d*,\d+(?:[eE][+-]?\d+)?$")


def read_table_rows(path, expected="a header and one row per image"):
    """Rows of a CSV / whitespace table with a header, quotes ``'`` or ``"`` allowed: comma-,
    semicolon- (a spreadsheet's CSV in a locale with decimal commas: ``1,5`` reads as 1.5),
    tab- or space-separated, as the header line is (decimal commas read in all but the
    comma-separated, as a spreadsheet's "Unicode Text" writes them: tabs, UTF-16). UTF-8 or
    UTF-16 text (:func:`~bare_earth.core.common.text_of`)."""
    text = text_of(Path(path).read_bytes(), path)
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        raise ValueError(f"{path}: empty file; expected {expected}.")
    delim = next((d for d in (";", ",", "\t") if d in lines[0]), None)
    if delim:
        reader = csv.reader(lines, delimiter=delim, skipinitialspace=True)
        rows = [[c.strip().strip("'\"") for c in r] for r in reader]
    else:
        token = re.compile(r"'[^']*'|\"[^\"]*\"|\S+")
        rows = [[t.strip("'\"") for t in token.findall(ln)] for ln in lines]
    if delim != ",":                    # a comma separates nothing there: it is a decimal comma
        rows = [[c.replace(",", ".") if _DECIMAL_COMMA.match(c) else c for c in r] for r in rows]
    return rows


def read_opk_csv(path):
    """Read exterior orientation: one row per image, ``filename, x, y, z, omega, phi, kappa``.

    Comma-, semicolon-, tab- or space-separated, with a header naming the columns (orthority's
    ``xyz_opk`` format; extra columns such as ``camera`` are kept). Angles in degrees in the
    omega-phi-kappa convention of :func:`opk_to_rotation`. File extensions in ``filename``
    are dropped.

    Returns
    -------
    dict
        ``{name: {"x", "y", "z", "omega", "phi", "kappa", <extra columns>}}``.

    Raises
    ------
    ValueError
        Missing columns, non-numeric or non-finite values, angles outside [-360, 360] deg
        (radians or garbage), duplicate image names.
    """
    rows = read_table_rows(path)
    header = [h.strip().lower() for h in rows[0]]
    need = ["x", "y", "z", "omega", "phi", "kappa"]
    name_col = next((c for c in ("filename", "file", "image", "name", "id") if c in header), None)
    missing = [c for c in need if c not in header]
    if name_col is None or missing:
        raise ValueError(f"{path}: header {rows[0]} lacks column(s) "
                         f"{(['filename'] if name_col is None else []) + missing}; expected "
                         "'filename,x,y,z,omega,phi,kappa' (angles in degrees).")
    out = {}
    for ln, r in enumerate(rows[1:], start=2):
        if len(r) < len(header):
            raise ValueError(f"{path} line {ln}: {len(r)} values for {len(header)} columns; "
                             "every image needs x, y, z, omega, phi, kappa.")
        rec = dict(zip(header, r))
        name = Path(rec[name_col]).stem if "." in rec[name_col] else rec[name_col]
        vals = {}
        for c in need:
            try:
                v = float(rec[c])
            except ValueError:
                raise ValueError(f"{path} line {ln}: {c}={rec[c]!r} is not a number; "
                                 "fix the exterior orientation row.") from None
            if not math.isfinite(v):
                raise ValueError(f"{path} line {ln}: {c}={rec[c]!r} is not finite.")
            vals[c] = v
        bad = [c for c in ("omega", "phi", "kappa") if abs(vals[c]) > 360]
        if bad:
            raise ValueError(f"{path} line {ln} ({name}): angle(s) {bad} outside [-360, 360]; "
                             "omega, phi, kappa must be in degrees.")
        if abs(vals["omega"]) >= 90 or abs(vals["phi"]) >= 90:
            raise ValueError(f"{path} line {ln} ({name}): omega={vals['omega']}, phi={vals['phi']} "
                             "tilt the camera 90 deg or more from the nadir; a frame for an "
                             "orthophoto looks down. Check the angle units and order.")
        if name in out:
            raise ValueError(f"{path}: image {name!r} appears twice; keep one row per image.")
        extra = {k: v for k, v in rec.items() if k not in need and k != name_col}
        out[name] = {**vals, **extra}
    if not out:
        raise ValueError(f"{path}: no image rows after the header.")
    return out


def parse_tiny_yaml(text):
    """Parse the small nested-mapping YAML of interior-orientation files (no PyYAML needed)."""
    root = {}
    stack = [(-1, root)]
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].rstrip()
        if not line.strip():
            continue
        indent = len(line) - len(line.lstrip())
        key, _, val = line.strip().partition(":")
        key = key.strip().strip("'\"")
        while stack[-1][0] >= indent:
            stack.pop()
        parent = stack[-1][1]
        val = val.strip()
        if not val:
            child = {}
            parent[key] = child
            stack.append((indent, child))
        else:
            parent[key] = _yaml_scalar(val)
    return root


def _yaml_scalar(val):
    if val.startswith("[") and val.endswith("]"):
        return [_yaml_scalar(v.strip()) for v in val[1:-1].split(",") if v.strip()]
    v = val.strip("'\"")
    if v.lower() in ("null", "~", ""):
        return None
    try:
        return int(v)
    except ValueError:
        try:
            return float(v)
        except ValueError:
            return v


def _numbers(where, key, value, counts=(1,)):
    """``value`` of ``key`` as a float (``counts`` ``(1,)``) or a list of floats whose length is
    one of ``counts``; ValueError naming ``where`` (file and camera), the key and the form
    expected (a text such as '8.8mm', a missing value, a list of the wrong length)."""
    if isinstance(value, (list, tuple)):
        vals = list(value) if len(value) in counts and counts != (1,) else None
    else:
        vals = [value] if 1 in counts else None
    try:
        out = [float(v) for v in vals if not isinstance(v, bool)] if vals is not None else None
    except (TypeError, ValueError):
        out = None
    if out is None or len(out) != len(vals) or not all(math.isfinite(v) for v in out):
        form = " or ".join("a number" if n == 1 else f"[{', '.join(['number'] * n)}]" for n in counts)
        raise ValueError(f"{where}: {key} is {value!r}; give {form} (numbers without units).")
    return out[0] if counts == (1,) else out


#: The id :func:`read_interior_yaml` gives the one camera of a YAML without ids (its parameters at the top).
UNNAMED_CAMERA = "camera"


def read_interior_yaml(path):
    """Read orthority-style interior orientation YAML: ``{camera id: {type, im_size, ...}}``.

    Keys per camera: ``type`` (pinhole or brown), ``im_size [w, h]``, ``focal_len`` (with
    ``sensor_size [w, h]`` in the same units, else normalised by the larger image side),
    ``cx``, ``cy`` (normalised), ``k1 k2 k3 p1 p2`` (brown).

    Returns
    -------
    dict of str -> Interior
    """
    text = text_of(Path(path).read_bytes(), path)
    try:
        import yaml  # optional; the tiny parser below covers these files
    except ImportError:
        data = parse_tiny_yaml(text)
    else:
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise ValueError(f"{path}: not valid YAML ({' '.join(str(exc).split())}); expected a mapping of "
                             "camera id -> parameters (type, im_size [w, h], focal_len, ...).") from None
    if not isinstance(data, dict) or not data:
        raise ValueError(f"{path}: expected a mapping of camera id -> parameters.")
    if "im_size" in data:                        # a single camera without an id
        data = {UNNAMED_CAMERA: data}
    out = {}
    for cam_id, p in data.items():
        if not isinstance(p, dict):
            raise ValueError(f"{path}: camera {cam_id!r} must be a mapping of parameters.")
        typ = str(p.get("type", "pinhole")).lower()
        if typ not in ("pinhole", "brown", "opencv"):
            raise ValueError(f"{path}: camera {cam_id!r} has type {typ!r}; supported: pinhole, "
                             "brown (k1, k2, k3, p1, p2).")
        miss = [k for k in ("im_size", "focal_len") if p.get(k) is None]
        if miss:
            raise ValueError(f"{path}: camera {cam_id!r} lacks {miss}; give im_size [w, h] and focal_len.")
        where = f"{path}: camera {cam_id!r}"
        size = _numbers(where, "im_size", p["im_size"], (2,))
        if any(v != int(v) or v < 1 for v in size):
            raise ValueError(f"{where}: im_size is {p['im_size']!r}; give [width, height] in whole pixels.")
        sensor = p.get("sensor_size")
        out[str(cam_id)] = Interior.from_params(
            size, _numbers(where, "focal_len", p["focal_len"], (1, 2)),
            None if sensor is None else _numbers(where, "sensor_size", sensor, (2,)),
            *(_numbers(where, k, p.get(k) if p.get(k) is not None else 0.0)
              for k in ("cx", "cy", "k1", "k2", "k3", "p1", "p2")),
            name=str(cam_id))
    return out


def read_opensfm_reconstruction(path):
    """Read an OpenSfM ``reconstruction.json``: cameras (Brown) and shot poses.

    OpenSfM stores world-to-camera angle-axis rotations in the computer-vision camera frame
    and translations ``t`` with ``C = -R_wc.T @ t``, in a local topocentric frame (east,
    north, up) around ``reference_lla``.

    Returns
    -------
    interiors : dict of str -> Interior
        By camera id; ids are also registered without a leading ``"v2 "`` (orthority's CSV
        ``camera`` column drops it).
    cameras : dict of str -> Camera
        By shot name (extension dropped), in the topocentric frame.
    reference_lla : dict or None
    """
    try:
        data = json.loads(text_of(Path(path).read_bytes(), path))
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: not valid JSON ({exc}); expected an OpenSfM reconstruction.json.") from None
    rec = data[0] if isinstance(data, list) and data else data
    if not (isinstance(rec, dict) and isinstance(rec.get("cameras", {}), dict)
            and isinstance(rec.get("shots", {}), dict)):
        raise ValueError(f"{path}: not an OpenSfM reconstruction (a list of reconstructions, each a mapping "
                         "with 'cameras' and 'shots' mappings).")
    interiors = {}
    for cid, p in rec.get("cameras", {}).items():
        where = f"{path}: camera {cid!r}"
        if not isinstance(p, dict):
            raise ValueError(f"{where} must be a mapping of parameters.")
        typ = p.get("projection_type", "perspective")
        if typ not in ("brown", "perspective", "simple_radial", "radial"):
            raise ValueError(f"{path}: camera {cid!r} has projection {typ!r}; supported: brown, perspective.")
        miss = [k for k in ("width", "height") if p.get(k) is None] + (
            [] if p.get("focal_x", p.get("focal")) is not None else ["focal (or focal_x)"])
        if miss:
            raise ValueError(f"{where} lacks {', '.join(miss)}.")
        fx = _numbers(where, "focal_x", p.get("focal_x", p.get("focal")))
        fy = _numbers(where, "focal_y", p.get("focal_y", fx))
        size = _numbers(where, "width, height", [p["width"], p["height"]], (2,))
        io = Interior.from_params(size, (fx, fy), None,
                                  *(_numbers(where, k, p.get(k) if p.get(k) is not None else 0.0)
                                    for k in ("c_x", "c_y", "k1", "k2", "k3", "p1", "p2")), name=cid)
        interiors[cid] = io
        if cid.startswith("v2 "):
            interiors[cid[3:]] = io
    cameras = {}
    for sname, s in rec.get("shots", {}).items():
        where = f"{path}: shot {sname!r}"
        if not isinstance(s, dict) or s.get("camera") not in interiors:
            raise ValueError(f"{where}: its camera {s.get('camera') if isinstance(s, dict) else None!r} is not "
                             f"among the reconstruction's cameras {sorted(rec.get('cameras', {}))}.")
        Rwc = _rodrigues(_numbers(where, "rotation", s.get("rotation"), (3,)))    # world -> cv camera
        C = -Rwc.T @ np.asarray(_numbers(where, "translation", s.get("translation"), (3,)), dtype=float)
        R = Rwc.T @ _FLIP                              # camera (x right, y up, z back) -> world
        name = Path(sname).stem
        cameras[name] = Camera(interiors[s["camera"]], C, R, name, rotation_to_opk(R))
    return interiors, cameras, rec.get("reference_lla")


def cameras_from_opk(exterior, interior, names=None):
    """Cameras for ``names`` from :func:`read_opk_csv` rows and interior orientation(s).

    Parameters
    ----------
    exterior : dict
        From :func:`read_opk_csv`.
    interior : Interior or dict of str -> Interior
        One camera for all images, or by camera id (matched with a ``camera`` column). A row
        whose ``camera`` names an id the dict does not hold is refused, even when the dict holds
        one camera (the wrong interior file), but when that camera has no id of its own
        (:data:`UNNAMED_CAMERA`: a YAML of one camera's parameters).
    names : sequence of str, optional
        Images wanted (extensions dropped); default all rows.

    Raises
    ------
    ValueError
        An image without a row (names the missing ones), without a known camera id, or whose
        ``camera`` column names a camera the interior orientation does not hold.
    """
    names = list(exterior) if names is None else [Path(n).stem if "." in str(n) else str(n)
                                                  for n in names]
    missing = [n for n in names if n not in exterior]
    if missing:
        raise ValueError(f"no exterior orientation for image(s) {missing}; the CSV has "
                         f"{sorted(exterior)}. Add a row per image (filename,x,y,z,omega,phi,kappa).")
    cams = []
    for n in names:
        e = exterior[n]
        cid = e.get("camera")
        cid = None if cid is None or not str(cid).strip() else str(cid).strip()
        if isinstance(interior, Interior):
            io = interior
        elif cid in interior:
            io = interior[cid]
        elif cid is not None and set(interior) != {UNNAMED_CAMERA}:
            # the rows name their camera and the file holds others: the wrong camera file, not one for all
            raise ValueError(f"image {n!r}: camera id {cid!r} (the exterior orientation's 'camera' column) is "
                             f"not among the interior orientation's cameras {sorted(interior)}: give the "
                             "interior orientation of that camera, or correct the column.")
        elif len({id(v) for v in interior.values()}) == 1:   # one camera (OpenSfM's under two ids)
            io = next(iter(interior.values()))
        else:
            raise ValueError(f"image {n!r}: camera id {cid!r} not among {sorted(interior)}; "
                             "add a 'camera' column naming the interior orientation.")
        cams.append(Camera.from_opk(io, e["x"], e["y"], e["z"], e["omega"], e["phi"], e["kappa"], n))
    return cams


def read_cameras(exterior_csv, interior_path, names=None):
    """Cameras from an exterior-orientation CSV and an interior-orientation file.

    Parameters
    ----------
    exterior_csv : path
        ``filename, x, y, z, omega, phi, kappa`` (degrees), see :func:`read_opk_csv`.
    interior_path : path
        Orthority-style YAML (``.yaml`` / ``.yml``, :func:`read_interior_yaml`) or an
        OpenSfM ``reconstruction.json`` (its cameras; the poses come from the CSV).
    names : sequence of str, optional
        Images wanted, in this order (file names or stems); default every CSV row.

    Returns
    -------
    list of Camera
    """
    path = Path(interior_path)
    suffix = path.suffix.lower()
    if suffix in (".yaml", ".yml"):
        interiors = read_interior_yaml(path)
    elif suffix == ".json":
        interiors = read_opensfm_reconstruction(path)[0]
    else:
        raise ValueError(f"{path}: unknown interior orientation format {suffix!r}; give an "
                         "orthority .yaml or an OpenSfM reconstruction.json.")
    return cameras_from_opk(read_opk_csv(exterior_csv), interiors, names)
