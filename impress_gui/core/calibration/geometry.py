"""Camera model and rig geometry shared by the simulator, calibration and reconstruction.

Frames (all lengths in mm):

- camera frame ``o-xyz`` (OpenCV): x to the image right, y to the image bottom, z forward;
- ideal frame ``O-XYZ``: the camera frame rotated so that the rail's motion is +Y,
  ``X = R x`` with ``R = R_x(tilt) @ R_z(roll)`` (see :func:`ideal_rotation`);
- rail frame ``O'-X'Y'Z'``: axes of the ideal frame, origin at the optical centre at the
  reference time; a point at ideal-frame position ``P`` in a frame whose camera has travelled
  ``s`` mm has rail position ``P + (0, s, 0)``. ``Z'`` is depth away from the camera.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from impress_gui.core.base import codes
from impress_gui.core.base.errors import FormatError, InputError
from impress_gui.core.base.fileio import float_array, read_json, require, write_json

INTRINSICS_FORMAT = "impress.intrinsics"
#: the longest rolling-shutter readout accepted (ms): a frame interval at 10 frames/s
MAX_READOUT_MS = 100.0


def rail_shift(travel_mm) -> np.ndarray:
    """The camera's displacement along the rail (the Y axis): ``(3,)`` for one travel, ``(N, 3)``
    for one per point (a rolling shutter: each image row was exposed at its own travel)."""
    if np.ndim(travel_mm) == 0:
        return np.array([0.0, float(travel_mm), 0.0])
    tr = np.asarray(travel_mm, float)
    return np.column_stack([np.zeros(len(tr)), tr, np.zeros(len(tr))])


def rot_x(angle_rad: float) -> np.ndarray:
    """R_x with second row (0, cos a, sin a): the seed's eq. 3.10 with its misprint fixed."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


def rot_z(angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def ideal_rotation(roll_rad: float, tilt_rad: float) -> np.ndarray:
    """Rotation from the camera frame to the ideal frame: ``X = R_x(tilt) R_z(roll) x``."""
    return rot_x(tilt_rad) @ rot_z(roll_rad)


def roll_tilt_from_direction(m: np.ndarray) -> tuple[float, float]:
    """Roll and tilt (radians) that rotate the camera-frame motion direction ``m`` onto +Y.

    Equivalent to the seed's ``roll = atan(x_v / y_v)`` and
    ``tilt = sign(y_v) atan(f / sqrt(x_v^2 + y_v^2))`` for the vanishing point ``v``,
    but also valid when the vanishing point is at infinity (perfect alignment).
    """
    m = np.asarray(m, dtype=float)
    m = m / np.linalg.norm(m)
    roll = float(np.arctan2(m[0], m[1]))
    my = float(np.hypot(m[0], m[1]))
    tilt = float(np.arctan2(m[2], my))
    return roll, tilt


#: focal lengths accepted, in multiples of the picture's longer side (a fisheye of 180 deg is
#: about 0.3, a long telephoto lens tens)
FOCAL_RANGE = (0.05, 500.0)


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole camera with OpenCV distortion ``(k1, k2, p1, p2, k3)``.

    ``camera_matrix`` is 3x3 in pixels; ``image_size`` is ``(width, height)`` in pixels.
    ``readout_ms``: a rolling shutter's readout, the time from the exposure of the first image
    row to that of the last (0: a global shutter; None: not given - the scene calibration
    then estimates it from the picks and uses it when they clearly show one). A CMOS camcorder
    reads its rows one after another, so while the carriage moves, row ``v`` of a frame shows
    the scene ``v * line_time_s`` after row 0; the calibration and the reconstruction place
    each row where the camera was then.
    """

    camera_matrix: np.ndarray
    dist_coeffs: np.ndarray
    image_size: tuple[int, int]
    rms_px: float | None = None
    frames_used: tuple[int, ...] = field(default_factory=tuple)
    source: str = ""
    readout_ms: float | None = None

    def __post_init__(self) -> None:
        k = np.asarray(self.camera_matrix, dtype=float)
        d = np.zeros(5)
        dc = np.asarray(self.dist_coeffs, dtype=float).ravel()
        if dc.size not in (4, 5, 8) or not np.all(np.isfinite(dc)):
            raise InputError("distortion needs 4, 5 or 8 finite coefficients")
        d = dc if dc.size != 4 else np.concatenate([dc, [0.0]])
        if k.shape != (3, 3) or not np.all(np.isfinite(k)) or k[0, 0] <= 0 or k[1, 1] <= 0:
            raise InputError("camera matrix must be 3x3 with positive focal lengths")
        w, h = (int(v) for v in self.image_size)
        if w <= 0 or h <= 0:
            raise InputError("image size must be positive")
        if not np.allclose(k[2], [0.0, 0.0, 1.0], atol=1e-9, rtol=0.0) or k[1, 0] != 0.0:
            raise InputError("the camera matrix's last row must be [0, 0, 1] and its element "
                             "[1][0] zero (a camera matrix as OpenCV writes it)")
        side = max(w, h)
        if not (FOCAL_RANGE[0] * side <= min(k[0, 0], k[1, 1])
                and max(k[0, 0], k[1, 1]) <= FOCAL_RANGE[1] * side):
            raise InputError(f"focal lengths of {k[0, 0]:.6g} and {k[1, 1]:.6g} pixels are not "
                             f"a camera's for a {w}x{h} picture ({FOCAL_RANGE[0]:g} to "
                             f"{FOCAL_RANGE[1]:g} times its longer side)")
        if not (-w <= k[0, 2] <= 2 * w and -h <= k[1, 2] <= 2 * h):
            raise InputError(f"the principal point ({k[0, 2]:.6g}, {k[1, 2]:.6g}) lies far "
                             f"outside the {w}x{h} picture")
        ro = None if self.readout_ms is None else float(self.readout_ms)
        if ro is not None and not (math.isfinite(ro) and 0.0 <= ro <= MAX_READOUT_MS):
            raise InputError(f"readout_ms (a rolling shutter's readout) must be between 0 and "
                             f"{MAX_READOUT_MS:g} ms")
        object.__setattr__(self, "camera_matrix", k)
        object.__setattr__(self, "dist_coeffs", d)
        object.__setattr__(self, "image_size", (w, h))
        object.__setattr__(self, "readout_ms", ro)

    @property
    def line_time_s(self) -> float:
        """The time from one image row's exposure to the next, s (0: a global shutter, or
        the readout not given)."""
        if not self.readout_ms:
            return 0.0
        return self.readout_ms / 1000.0 / max(self.image_size[1] - 1, 1)

    @property
    def fx(self) -> float:
        return float(self.camera_matrix[0, 0])

    @property
    def fy(self) -> float:
        return float(self.camera_matrix[1, 1])

    @property
    def cx(self) -> float:
        return float(self.camera_matrix[0, 2])

    @property
    def cy(self) -> float:
        return float(self.camera_matrix[1, 2])

    def distort_normalized(self, xn: np.ndarray, yn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Apply lens distortion to normalized coordinates; return pixel coordinates."""
        k1, k2, p1, p2, k3 = self.dist_coeffs[:5]
        r2 = xn * xn + yn * yn
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        if self.dist_coeffs.size == 8:
            k4, k5, k6 = self.dist_coeffs[5:8]
            radial = radial / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xd = xn * radial + 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn)
        yd = yn * radial + p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn
        k = self.camera_matrix
        return k[0, 0] * xd + k[0, 1] * yd + k[0, 2], k[1, 1] * yd + k[1, 2]

    def fold_radius(self, limit: float = 4.0) -> float:
        """The normalized radius (``sqrt(x^2 + y^2)`` at ``z = 1``) beyond which the lens's
        radial distortion stops moving points outwards (inf if it does not up to ``limit``).
        Past it a barrel lens folds rays from far outside the view back into the picture:
        a projection of such points lands among the real ones (random rig 65: a laser's line
        on the ground projected up to 135 rows off in its edge columns). Tangential terms
        are left out (a few tenths of a percent of the radius)."""
        d = self.dist_coeffs
        r = np.linspace(0.0, limit, 40001)
        r2 = r * r
        radial = 1 + r2 * (d[0] + r2 * (d[1] + r2 * d[4]))
        if d.size == 8:
            radial = radial / (1 + r2 * (d[5] + r2 * (d[6] + r2 * d[7])))
        out = r * radial
        bad = np.flatnonzero((np.diff(out) <= 0) | ~np.isfinite(out[1:]))
        return float(r[bad[0]]) if len(bad) else math.inf

    def project(self, pts_cam: np.ndarray) -> np.ndarray:
        """Project camera-frame points ``(..., 3)`` in mm to distorted pixels ``(..., 2)``."""
        p = np.asarray(pts_cam, dtype=float)
        z = p[..., 2]
        u, v = self.distort_normalized(p[..., 0] / z, p[..., 1] / z)
        return np.stack([u, v], axis=-1)

    def undistort_points(self, pts_px: np.ndarray) -> np.ndarray:
        """Distorted pixels ``(N, 2)`` -> normalized undistorted coordinates ``(N, 2)``.

        Iterates to convergence (OpenCV's default five iterations leave errors of a tenth of
        a pixel at the image corners of a wide lens).
        """
        pts = np.asarray(pts_px, dtype=np.float64).reshape(-1, 2)
        k = self.camera_matrix
        yd = (pts[:, 1] - k[1, 2]) / k[1, 1]
        xd = (pts[:, 0] - k[0, 2] - k[0, 1] * yd) / k[0, 0]
        x, y = xd.copy(), yd.copy()
        k1, k2, p1, p2, k3 = self.dist_coeffs[:5]
        rat = self.dist_coeffs.size == 8
        for _ in range(100):
            r2 = x * x + y * y
            radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
            if rat:
                k4, k5, k6 = self.dist_coeffs[5:8]
                radial = radial / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
            dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
            dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
            xn, yn = (xd - dx) / radial, (yd - dy) / radial
            delta = max(float(np.max(np.abs(xn - x), initial=0)),
                        float(np.max(np.abs(yn - y), initial=0)))
            x, y = xn, yn
            if delta < 1e-13:
                break
        return np.column_stack([x, y])

    def rays(self, pts_px: np.ndarray) -> np.ndarray:
        """Camera-frame ray directions ``(N, 3)`` (z = 1) through distorted pixels."""
        n = self.undistort_points(pts_px)
        return np.column_stack([n, np.ones(len(n))])

    def check_image_size(self, width: int, height: int, what: str = "the video") -> None:
        w, h = self.image_size
        if (w, h) == (width, height):
            return
        # camcorders code 1080 lines as 1088: accept the padded height
        if w == width and h == 1080 and height == 1088:
            return
        raise InputError(
            f"the intrinsics are for {w}x{h} images but {what} is {width}x{height}",
            code=codes.E_SIZE_MISMATCH,
        )

    # ----- file format ---------------------------------------------------------------
    def to_json(self) -> dict:
        return {
            "format": INTRINSICS_FORMAT,
            "version": 1,
            "image_size": list(self.image_size),
            "camera_matrix": self.camera_matrix.tolist(),
            "dist_coeffs": self.dist_coeffs.tolist(),
            "rms_px": self.rms_px,
            "frames_used": list(self.frames_used),
            "source": self.source,
            # only when given: the files written before rolling shutters stay as they were
            **({"readout_ms": self.readout_ms} if self.readout_ms is not None else {}),
        }

    @classmethod
    def from_json(cls, doc: dict, where: str = "") -> Intrinsics:
        size = require(doc, "image_size", list, where)
        if len(size) != 2 or not all(isinstance(v, int) and 0 < v < 100000 for v in size):
            raise FormatError(f"{where}image_size must be [width, height] in pixels")
        k = float_array(require(doc, "camera_matrix", list, where), (3, 3), "camera_matrix")
        d_raw = require(doc, "dist_coeffs", list, where)
        if len(d_raw) not in (4, 5, 8):
            raise FormatError(f"{where}dist_coeffs must have 4, 5 or 8 values")
        d = float_array(d_raw, (len(d_raw),), "dist_coeffs")
        rms = doc.get("rms_px")
        readout = doc.get("readout_ms")
        if readout is not None and (isinstance(readout, bool)
                                    or not isinstance(readout, (int, float))):
            raise FormatError(f"{where}readout_ms must be a number of milliseconds")
        try:
            return cls(k, d, (size[0], size[1]), rms_px=rms,
                       frames_used=tuple(doc.get("frames_used", [])),
                       source=str(doc.get("source", "")),
                       readout_ms=None if readout is None else float(readout))
        except (InputError, TypeError, ValueError) as exc:
            raise FormatError(f"{where}{exc}") from None

    def save(self, path) -> None:
        write_json(path, self.to_json())

    @classmethod
    def load(cls, path) -> Intrinsics:
        return cls.from_json(read_json(path, INTRINSICS_FORMAT), f"{path}: ")


@dataclass(frozen=True)
class Plane:
    """Plane ``normal . X = offset_mm`` with a unit normal, in the camera-fixed ideal frame."""

    normal: np.ndarray
    offset_mm: float

    def __post_init__(self) -> None:
        n = np.asarray(self.normal, dtype=float)
        norm = np.linalg.norm(n)
        if not np.isfinite(norm) or norm == 0:
            raise InputError("plane normal must be a finite non-zero vector")
        object.__setattr__(self, "normal", n / norm)
        object.__setattr__(self, "offset_mm", float(self.offset_mm) / norm)

    def distance(self, pts: np.ndarray) -> np.ndarray:
        return np.asarray(pts, dtype=float) @ self.normal - self.offset_mm

    def angle_to_deg(self, other: Plane) -> float:
        c = abs(float(self.normal @ other.normal))
        return float(np.degrees(np.arccos(min(1.0, c))))

    def oriented_like(self, other: Plane) -> Plane:
        if float(self.normal @ other.normal) < 0:
            return Plane(-self.normal, -self.offset_mm)
        return self

    def to_json(self) -> dict:
        return {"normal": self.normal.tolist(), "offset_mm": self.offset_mm}

    @classmethod
    def from_json(cls, doc: dict, name: str) -> Plane:
        if not isinstance(doc, dict):
            raise FormatError(f"{name} must be an object with normal and offset_mm")
        n = float_array(require(doc, "normal", list, f"{name}: "), (3,), f"{name}.normal")
        off = require(doc, "offset_mm", float, f"{name}: ")
        try:
            return cls(n, off)
        except InputError as exc:
            raise FormatError(f"{name}: {exc}") from None


def fit_plane(points: np.ndarray) -> tuple[Plane, float, np.ndarray]:
    """Least-squares plane through ``(N, 3)`` points (SVD); return plane, RMS (mm), singulars."""
    pts = np.asarray(points, dtype=float)
    c = pts.mean(axis=0)
    _, s, vt = np.linalg.svd(pts - c, full_matrices=False)
    n = vt[2]
    plane = Plane(n, float(n @ c))
    rms = float(np.sqrt(np.mean(plane.distance(pts) ** 2)))
    return plane, rms, s
