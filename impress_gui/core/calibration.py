"""Scene calibration from the scan itself (the seed's self-calibration, made better).

From the six L-target corners marked in frames t1 and t2 this recovers the motion direction
(least-squares vanishing point of all six corner tracks, valid at infinity), roll and tilt, the
metric corners by motion parallax, a rigid fit of the target model (per-corner residuals, and
the speed implied by the target's known size), then refines everything by minimising the
reprojection error of all twelve picks. Each laser plane is fitted to every stripe pixel that
falls on a known target face, in several frames around its calibration frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from impress_gui import __version__
from impress_gui.core.errors import CalibrationError, FormatError
from impress_gui.core.fileio import float_array, read_json, require, write_json
from impress_gui.core.geometry import (
    Intrinsics,
    Plane,
    fit_plane,
    ideal_rotation,
    roll_tilt_from_direction,
)
from impress_gui.core.picks import Picks
from impress_gui.core.progress import CancelToken, ProgressCallback, report
from impress_gui.core.target import CORNER_NAMES, TargetModel, _inside_convex

CALIBRATION_FORMAT = "impress.calibration"
SPEED_WARN_FRACTION = 0.01


@dataclass(frozen=True)
class LaserPlaneFit:
    name: str
    plane: Plane  # camera-fixed ideal frame, mm
    rms_mm: float
    n_points: int
    frames: tuple[int, ...]
    heights_mm: tuple[float, ...]  # target-face heights the stripe was measured on
    method: str = "stripe-fit"


@dataclass(frozen=True)
class SceneCalibration:
    intrinsics: Intrinsics
    speed_mm_s: float  # as entered; travel of frame k is speed * (t_k - t_ref)
    fps: float
    t1: int
    t2: int
    t_ref_s: float  # time of frame t1: the rail frame's origin is the optical centre then
    motion_dir_cam: np.ndarray
    vanishing_point_px: np.ndarray  # homogeneous, undistorted pixels; [x, y, 0] at infinity
    roll_deg: float
    tilt_deg: float
    rotation: np.ndarray  # camera -> ideal
    corners_parallax_mm: np.ndarray  # (6, 3) rail frame, by motion parallax with the entered speed
    corner_residuals_mm: np.ndarray  # (6,) after the rigid fit of the target model
    target_rotation: np.ndarray  # object -> rail
    target_translation_mm: np.ndarray
    implied_speed_mm_s: float
    reprojection_rms_px: float
    planes: dict[str, LaserPlaneFit]
    warnings: tuple[str, ...] = ()
    inputs: dict = field(default_factory=dict)

    # ----- derived -------------------------------------------------------------------------
    def corners_fit_mm(self, target: TargetModel) -> np.ndarray:
        return target.corner_array() @ self.target_rotation.T + self.target_translation_mm

    @property
    def up_rail(self) -> np.ndarray:
        """Unit 'up' of the target's base (towards the camera) in the rail frame."""
        return self.target_rotation @ np.array([0.0, 0.0, 1.0])

    def reference_depth(self, x_mm: np.ndarray, y_mm: np.ndarray) -> np.ndarray:
        """Depth Z' of the target's base plane (the height reference) at rail (X', Y')."""
        n = -self.up_rail  # pointing away from the camera, n_z > 0
        p0 = self.target_translation_mm
        return p0[2] - (n[0] * (x_mm - p0[0]) + n[1] * (y_mm - p0[1])) / n[2]

    def travel_mm(self, times_s: np.ndarray) -> np.ndarray:
        """Camera travel (mm) at the given frame times, relative to frame t1."""
        return self.speed_mm_s * (np.asarray(times_s, float) - self.t_ref_s)

    def project_rail(self, pts_rail_mm: np.ndarray, travel_mm: float) -> np.ndarray:
        """Distorted pixel positions ``(N, 2)`` of rail-frame points seen from a frame whose
        camera has travelled ``travel_mm`` (e.g. the fitted target corners for an overlay)."""
        return _project(self.intrinsics, self.rotation, np.asarray(pts_rail_mm, float), travel_mm)

    # ----- file format ------------------------------------------------------------------------
    def to_json(self) -> dict:
        return {
            "format": CALIBRATION_FORMAT,
            "version": 1,
            "software": f"impress {__version__}",
            "intrinsics": self.intrinsics.to_json(),
            "speed_mm_s": self.speed_mm_s,
            "fps": self.fps,
            "t1": self.t1,
            "t2": self.t2,
            "t_ref_s": self.t_ref_s,
            "frames": "rail frame: axes of the ideal frame (camera rotated so the motion is +Y), "
                      "origin at the optical centre at frame t1; Z' = depth; planes are in the "
                      "camera-fixed ideal frame",
            "motion_direction_camera": self.motion_dir_cam.tolist(),
            "vanishing_point_px": self.vanishing_point_px.tolist(),
            "roll_deg": self.roll_deg,
            "tilt_deg": self.tilt_deg,
            "rotation_camera_to_ideal": self.rotation.tolist(),
            "corners_parallax_mm": {c: self.corners_parallax_mm[i].tolist()
                                    for i, c in enumerate(CORNER_NAMES)},
            "corner_residuals_mm": {c: float(self.corner_residuals_mm[i])
                                    for i, c in enumerate(CORNER_NAMES)},
            "target_pose": {"rotation": self.target_rotation.tolist(),
                            "translation_mm": self.target_translation_mm.tolist()},
            "implied_speed_mm_s": self.implied_speed_mm_s,
            "reprojection_rms_px": self.reprojection_rms_px,
            "laser_planes": {
                n: {"normal": f.plane.normal.tolist(), "offset_mm": f.plane.offset_mm,
                    "rms_mm": f.rms_mm, "n_points": f.n_points, "frames": list(f.frames),
                    "heights_mm": list(f.heights_mm), "method": f.method}
                for n, f in self.planes.items()},
            "warnings": list(self.warnings),
            "inputs": self.inputs,
        }

    @classmethod
    def from_json(cls, doc: dict, where: str = "") -> SceneCalibration:
        try:
            intr = Intrinsics.from_json(require(doc, "intrinsics", dict, where), where)
            planes = {}
            for name, pd in require(doc, "laser_planes", dict, where).items():
                plane = Plane.from_json(pd, f"{where}laser_planes.{name}")
                planes[name] = LaserPlaneFit(
                    name, plane, float(require(pd, "rms_mm", float, where)),
                    int(require(pd, "n_points", int, where)),
                    tuple(int(v) for v in pd.get("frames", [])),
                    tuple(float(v) for v in pd.get("heights_mm", [])),
                    str(pd.get("method", "stripe-fit")))
            for name in ("green", "red"):
                if name not in planes:
                    raise FormatError(f"{where}the {name} laser plane is missing")
            pose = require(doc, "target_pose", dict, where)
            cp = require(doc, "corners_parallax_mm", dict, where)
            cr = require(doc, "corner_residuals_mm", dict, where)
            speed = float(require(doc, "speed_mm_s", float, where))
            fps = float(require(doc, "fps", float, where))
            if speed <= 0 or fps <= 0:
                raise FormatError(f"{where}speed and fps must be positive")
            return cls(
                intrinsics=intr, speed_mm_s=speed, fps=fps,
                t1=int(require(doc, "t1", int, where)), t2=int(require(doc, "t2", int, where)),
                t_ref_s=float(require(doc, "t_ref_s", float, where)),
                motion_dir_cam=float_array(doc.get("motion_direction_camera"), (3,), "motion"),
                vanishing_point_px=float_array(doc.get("vanishing_point_px"), (3,), "vp"),
                roll_deg=float(require(doc, "roll_deg", float, where)),
                tilt_deg=float(require(doc, "tilt_deg", float, where)),
                rotation=float_array(doc.get("rotation_camera_to_ideal"), (3, 3), "rotation"),
                corners_parallax_mm=np.array([float_array(cp.get(c), (3,), f"corner {c}")
                                              for c in CORNER_NAMES]),
                corner_residuals_mm=np.array([float(cr.get(c, np.nan)) for c in CORNER_NAMES]),
                target_rotation=float_array(pose.get("rotation"), (3, 3), "target rotation"),
                target_translation_mm=float_array(pose.get("translation_mm"), (3,), "target t"),
                implied_speed_mm_s=float(require(doc, "implied_speed_mm_s", float, where)),
                reprojection_rms_px=float(require(doc, "reprojection_rms_px", float, where)),
                planes=planes, warnings=tuple(str(w) for w in doc.get("warnings", [])),
                inputs=dict(doc.get("inputs", {})),
            )
        except (TypeError, ValueError, AttributeError, OverflowError) as exc:
            raise FormatError(f"{where}damaged calibration ({exc})") from None

    def save(self, path) -> None:
        write_json(path, self.to_json())

    @classmethod
    def load(cls, path) -> SceneCalibration:
        return cls.from_json(read_json(path, CALIBRATION_FORMAT), f"{path}: ")


# ----- building blocks ---------------------------------------------------------------------
def vanishing_point(n1: np.ndarray, n2: np.ndarray) -> np.ndarray:
    """Least-squares intersection of the corner tracks ``n1[i] -> n2[i]`` (normalized image
    coordinates) in homogeneous coordinates: the unit 3-vector ``v`` minimising
    ``sum (l_i . v)^2`` over the unit-normalised track lines ``l_i``. Valid at infinity."""
    h1 = np.column_stack([n1, np.ones(len(n1))])
    h2 = np.column_stack([n2, np.ones(len(n2))])
    lines = np.cross(h1, h2)
    lines /= np.linalg.norm(lines[:, :2], axis=1, keepdims=True)
    _, _, vt = np.linalg.svd(lines)
    return vt[-1] / np.linalg.norm(vt[-1])


def triangulate_parallax(a1, b1, a2, b2, travel_mm: float) -> np.ndarray:
    """Rail-frame points from ideal normalized coordinates in two frames separated by a pure
    +Y travel: least squares of ``X = a1 Z = a2 Z``, ``Y = b1 Z``, ``Y - d = b2 Z``."""
    pts = []
    for i in range(len(a1)):
        A = np.array([[-1, 0, a1[i]], [0, -1, b1[i]], [-1, 0, a2[i]], [0, -1, b2[i]]], float)
        rhs = np.array([0.0, 0.0, 0.0, -travel_mm])
        pts.append(np.linalg.lstsq(A, rhs, rcond=None)[0])
    return np.array(pts)


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool):
    """Similarity (or rigid) transform minimising ``|dst - (s R src + t)|``."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    u, d, vt = np.linalg.svd(cov)
    sgn = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sgn[2, 2] = -1
    rot = u @ sgn @ vt
    scale = float(np.trace(np.diag(d) @ sgn) / (xs**2).sum(1).mean()) if with_scale else 1.0
    t = mu_d - scale * rot @ mu_s
    return scale, rot, t


def _rodrigues(v: np.ndarray) -> np.ndarray:
    theta = np.linalg.norm(v)
    if theta < 1e-15:
        return np.eye(3)
    k = v / theta
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * kx + (1 - np.cos(theta)) * kx @ kx


def _rot_to_vec(r: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(r).as_rotvec()


def check_picks(picks: Picks, intrinsics: Intrinsics, frame_count: int) -> None:
    """Each problem with the picks is a clear error naming it (never a silent NaN)."""
    w, h = intrinsics.image_size
    for key, t in (("t1", picks.t1), ("t2", picks.t2)):
        if not 0 <= t < frame_count:
            raise CalibrationError(f"frame {key} = {t} is outside the video (0..{frame_count - 1})",
                                   code="E-FRAME-RANGE")
    if picks.t1 == picks.t2:
        raise CalibrationError("t1 and t2 are the same frame: the corners need two frames "
                               "with travel between them", code="E-PICKS")
    for key in ("t1", "t2"):
        d = picks.corners_t1 if key == "t1" else picks.corners_t2
        missing = [c for c in CORNER_NAMES if c not in d]
        if missing:
            raise CalibrationError(f"corners {', '.join(missing)} are not marked in frame {key}; "
                                   "all six corners A-F are needed in both frames",
                                   code="E-PICKS-INCOMPLETE")
        arr = picks.array(key)
        for c, (u, v) in zip(CORNER_NAMES, arr):
            if not (-0.5 <= u <= w - 0.5 and -0.5 <= v <= h - 0.5):
                raise CalibrationError(f"corner {c} in frame {key} ({u:.1f}, {v:.1f}) is outside "
                                       f"the {w}x{h} image", code="E-PICKS")
        dist = np.linalg.norm(arr[:, None] - arr[None], axis=2) + np.eye(6) * 1e9
        i, j = np.unravel_index(np.argmin(dist), dist.shape)
        if dist[i, j] < 2.0:
            raise CalibrationError(f"corners {CORNER_NAMES[i]} and {CORNER_NAMES[j]} in frame "
                                   f"{key} are at the same place", code="E-PICKS")
        centred = arr - arr.mean(0)
        s = np.linalg.svd(centred, compute_uv=False)
        if s[1] < 0.02 * s[0] or s[1] < 3.0:
            raise CalibrationError(f"the corners in frame {key} are (nearly) collinear; check "
                                   "the order A-F against the target diagram", code="E-PICKS")
    shift = np.linalg.norm(picks.array("t2") - picks.array("t1"), axis=1)
    if np.median(shift) < 5.0:
        raise CalibrationError("the corners barely move between t1 and t2; choose frames "
                               "further apart", code="E-PICKS")


def _project(intr: Intrinsics, rot: np.ndarray, pts_rail: np.ndarray, travel: float) -> np.ndarray:
    rel = pts_rail - np.array([0.0, travel, 0.0])
    return intr.project(rel @ rot)  # rows: R^T (P - C)


def _bundle(intr, target, picks, init, d0, fixed_travel: bool = False,
            fixed_rotation: bool = False):
    """Refine roll, tilt (unless ``fixed_rotation``), the target pose and the travel (unless
    ``fixed_travel``) by the reprojection error of all 12 picks."""
    from scipy.optimize import least_squares

    obj = target.corner_array()
    uv1, uv2 = picks.array("t1"), picks.array("t2")
    roll, tilt, r_o, t_o = init
    rot_fixed = ideal_rotation(roll, tilt)

    def unpack(p):
        i = 0 if fixed_rotation else 2
        rot = rot_fixed if fixed_rotation else ideal_rotation(p[0], p[1])
        d = d0 if fixed_travel else p[i + 6]
        return rot, _rodrigues(p[i:i + 3]), p[i + 3:i + 6], d

    def resid(p):
        rot, r_o, t_o, d = unpack(p)
        pts = obj @ r_o.T + t_o
        return np.concatenate([(_project(intr, rot, pts, 0.0) - uv1).ravel(),
                               (_project(intr, rot, pts, d) - uv2).ravel()])

    p0 = np.concatenate(([] if fixed_rotation else [[roll, tilt]]) + [_rot_to_vec(r_o), t_o]
                        + ([] if fixed_travel else [[d0]]))
    sol = least_squares(resid, p0, method="lm", xtol=1e-14, ftol=1e-14, gtol=1e-14, max_nfev=4000)
    rot, r_o, t_o, d = unpack(sol.x)
    rms = float(np.sqrt(np.mean(sol.fun**2)))
    if fixed_rotation:
        return roll, tilt, r_o, t_o, float(d), rms
    return sol.x[0], sol.x[1], r_o, t_o, float(d), rms


def _face_polygons(calib_pose, target: TargetModel):
    """Top faces as (height, polygon in rail frame (N, 3), outward up-normal, depth plane)."""
    r_o, t_o = calib_pose
    out = []
    for face in target.top_faces():
        v = face.vertices_mm
        # shrink by 1 mm towards the centroid so edge pixels are not attributed to a face
        c = v.mean(0)
        d = v - c
        scale = np.maximum(0.0, 1.0 - 1.0 / np.maximum(np.abs(d[:, :2]).max(1), 1e-9))
        vs = c + d * scale[:, None]
        out.append((float(v[0, 2]), vs @ r_o.T + t_o, v @ r_o.T + t_o))
    return out


def stripe_uv_on_target(rgb: np.ndarray, laser: str, intr: Intrinsics, rot: np.ndarray,
                        pose, target: TargetModel, travel_mm: float, params=None) -> np.ndarray:
    """Sub-pixel stripe positions ``(N, 2)`` of one laser inside the target's image region."""
    from impress_gui.core.stripes import StripeParams, detect_band

    faces = _face_polygons(pose, target)
    h, w = rgb.shape[:2]
    all_uv = np.concatenate([_project(intr, rot, f[2], travel_mm) for f in faces])
    r0 = int(max(0, np.floor(all_uv[:, 1].min()) - 8))
    r1 = int(min(h, np.ceil(all_uv[:, 1].max()) + 8))
    c0 = int(max(0, np.floor(all_uv[:, 0].min())))
    c1 = int(min(w, np.ceil(all_uv[:, 0].max()) + 1))
    if r1 - r0 < 10 or c1 - c0 < 10:
        return np.zeros((0, 2))
    res = detect_band(laser, rgb[r0:r1, c0:c1], None, r0, params or StripeParams(), None)
    cols = np.flatnonzero(res.found)
    return np.column_stack([cols + c0, res.rows[cols]])


def points_on_faces(rays: np.ndarray, pose, target: TargetModel, travel_mm: float):
    """Intersect ideal-frame rays with the target's top faces (seen from a frame whose camera
    travelled ``travel_mm``): 3D points in the camera-fixed ideal frame and face heights, for
    the rays that hit a face (inside it by 1 mm)."""
    best_t = np.full(len(rays), np.inf)
    best_h = np.full(len(rays), np.nan)
    for height, poly_in, poly in _face_polygons(pose, target):
        n = np.cross(poly[1] - poly[0], poly[2] - poly[0])
        n /= np.linalg.norm(n)
        p0 = poly[0] - np.array([0.0, travel_mm, 0.0])
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (p0 @ n) / (rays @ n)
        hit = rays * t[:, None] + np.array([0.0, travel_mm, 0.0])  # rail frame
        e1 = poly[1] - poly[0]
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(n, e1)
        q = poly_in - poly[0]
        hq = hit - poly[0]
        inside = _inside_convex(np.column_stack([q @ e1, q @ e2]), hq @ e1, hq @ e2) & (t > 0)
        better = inside & (t < best_t)
        best_t[better] = t[better]
        best_h[better] = height
    ok = np.isfinite(best_t)
    return rays[ok] * best_t[ok, None], best_h[ok], ok


def stripe_points_on_target(rgb: np.ndarray, laser: str, intr: Intrinsics, rot: np.ndarray,
                            pose, target: TargetModel, travel_mm: float, params=None):
    """3D points (camera-fixed ideal frame) of the laser stripe where it falls on the target's
    top faces in one frame, and the face height of each point."""
    uv = stripe_uv_on_target(rgb, laser, intr, rot, pose, target, travel_mm, params)
    if len(uv) == 0:
        return np.zeros((0, 3)), np.zeros(0)
    pts, hts, _ = points_on_faces(intr.rays(uv) @ rot.T, pose, target, travel_mm)
    return pts, hts


def fit_laser_plane(name: str, points: np.ndarray, heights: np.ndarray, frames) -> LaserPlaneFit:
    """SVD plane through the stripe points with outlier rejection; refuse when the stripe did
    not cross faces at two different heights (the plane would be undetermined)."""
    levels = sorted({round(float(h), 3) for h in np.unique(heights)
                     if np.sum(heights == h) >= 10})
    if len(levels) < 2:
        raise CalibrationError(
            f"the {name} stripe does not cross target faces at two different heights "
            f"(found {', '.join(f'{v:g} mm' for v in levels) or 'none'}); its plane is "
            "undetermined - choose a frame where it crosses both the low and the high face",
            code="E-PLANE-UNDETERMINED")
    keep = np.ones(len(points), bool)
    for _ in range(4):
        plane, rms, _ = fit_plane(points[keep])
        res = np.abs(plane.distance(points))
        mad = np.median(res[keep]) * 1.4826 + 1e-6
        new = res < max(4 * mad, 0.02)
        if np.array_equal(new, keep):
            break
        keep = new
    plane, rms, _ = fit_plane(points[keep])
    if plane.normal[2] < 0:  # orient consistently: normal with positive depth component
        plane = Plane(-plane.normal, -plane.offset_mm)
    return LaserPlaneFit(name, plane, rms, int(keep.sum()), tuple(frames), tuple(levels))


@dataclass(frozen=True)
class PoseSolution:
    """The geometric part of the calibration (no laser planes)."""

    motion_dir_cam: np.ndarray
    roll_rad: float
    tilt_rad: float
    rotation: np.ndarray
    corners_parallax_mm: np.ndarray
    corner_residuals_mm: np.ndarray
    target_rotation: np.ndarray
    target_translation_mm: np.ndarray
    implied_speed_mm_s: float
    reprojection_rms_px: float
    warnings: tuple[str, ...]
    initial_roll_rad: float
    initial_tilt_rad: float


def solve_pose(intrinsics: Intrinsics, target: TargetModel, picks: Picks, speed_mm_s: float,
               dt_s: float) -> PoseSolution:
    """Motion direction, roll, tilt, metric corners and target pose from the picks.

    ``dt_s`` is the time between frames t1 and t2."""
    d = speed_mm_s * dt_s
    n1 = intrinsics.undistort_points(picks.array("t1"))
    n2 = intrinsics.undistort_points(picks.array("t2"))
    m = vanishing_point(n1, n2)
    roll, tilt = roll_tilt_from_direction(m)
    rot = ideal_rotation(roll, tilt)

    def ideal(n):
        x = np.column_stack([n, np.ones(len(n))]) @ rot.T
        return x[:, 0] / x[:, 2], x[:, 1] / x[:, 2]

    a1, b1 = ideal(n1)
    a2, b2 = ideal(n2)
    corners = triangulate_parallax(a1, b1, a2, b2, d)
    if np.median(corners[:, 2]) < 0:  # the sign of the vanishing point: depths must be positive
        m = -m
        roll, tilt = roll_tilt_from_direction(m)
        rot = ideal_rotation(roll, tilt)
        a1, b1 = ideal(n1)
        a2, b2 = ideal(n2)
        corners = triangulate_parallax(a1, b1, a2, b2, d)
    if np.any(corners[:, 2] <= 0):
        raise CalibrationError("the picks give corners behind the camera; check that t1/t2 and "
                               "the corner order match the target diagram", code="E-PICKS")
    obj = target.corner_array()
    _, r_rigid, t_rigid = umeyama(obj, corners, with_scale=False)
    fitted = obj @ r_rigid.T + t_rigid
    residuals = np.linalg.norm(corners - fitted, axis=1)
    scale, r_s, t_s = umeyama(obj, corners, with_scale=True)
    if np.max(residuals) > 0.25 * target.size_mm():
        raise CalibrationError(
            f"the target model does not match the picks (corner residuals up to "
            f"{np.max(residuals):.1f} mm); check the corner order and the target model",
            code="E-TARGET-MISMATCH")
    fix_rot = False
    roll_b, tilt_b, r_o, t_o, d_fit, rms_px = _bundle(
        intrinsics, target, picks, (roll, tilt, r_s, t_s / scale), d / scale,
        fixed_rotation=fix_rot)
    implied = d_fit / dt_s
    warnings = []
    if abs(implied - speed_mm_s) <= SPEED_WARN_FRACTION * speed_mm_s:
        # the entered speed is confirmed: the known travel constrains the pose better
        roll_b, tilt_b, r_o, t_o, _, rms_px = _bundle(
            intrinsics, target, picks, (roll_b, tilt_b, r_o, t_o), d, fixed_travel=True,
            fixed_rotation=fix_rot)
    rot_b = ideal_rotation(roll_b, tilt_b)
    m_b = rot_b.T @ np.array([0.0, 1.0, 0.0])
    if abs(implied - speed_mm_s) > SPEED_WARN_FRACTION * speed_mm_s:
        warnings.append(
            f"the target's size implies a rail speed of {implied:.4f} mm/s but "
            f"{speed_mm_s:.4f} mm/s was entered ({100 * (implied / speed_mm_s - 1):+.1f} %); "
            "check the speed setting (heights and lengths along the scan scale with it)")
    if rms_px > 2.0:
        warnings.append(f"the corner picks fit the target poorly (reprojection RMS {rms_px:.2f} px)")
    # the corners in the rail frame with the entered speed (what the reconstruction uses)
    corners_entered = triangulate_parallax(*ideal_pair(intrinsics, rot_b, n1, n2), d)
    _, r_e, t_e = umeyama(obj, corners_entered, with_scale=False)
    residuals = np.linalg.norm(corners_entered - (obj @ r_e.T + t_e), axis=1)

    return PoseSolution(m_b, roll_b, tilt_b, rot_b, corners_entered, residuals, r_o, t_o,
                        float(implied), rms_px, tuple(warnings), roll, tilt)


def calibrate_scene(video, intrinsics: Intrinsics, target: TargetModel, picks: Picks,
                    speed_mm_s: float, fps: float | None = None, plane_frames: int = 15,
                    plane_span: int = 300, plane_travel_mm: float = 25.0,
                    refine_with_stripes: bool = True, click_sigma_px: float = 0.5,
                    progress: ProgressCallback | None = None,
                    cancel: CancelToken | None = None, inputs: dict | None = None
                    ) -> SceneCalibration:
    """Calibrate the rig from one scan. ``video`` is an open :class:`VideoSource`."""
    cancel = cancel or CancelToken()
    if not np.isfinite(speed_mm_s) or not 0.01 <= speed_mm_s <= 1000:
        raise CalibrationError(f"rail speed {speed_mm_s} mm/s is not plausible", code="E-SPEED")
    w, h = video.size
    intrinsics.check_image_size(w, h)
    check_picks(picks, intrinsics, video.frame_count)
    fps = float(fps or video.fps)
    times = video.times_s if fps == video.fps else np.arange(video.frame_count) / fps
    dt = float(times[picks.t2] - times[picks.t1])
    report(progress, 0.05, "motion direction and pose")
    pose = solve_pose(intrinsics, target, picks, speed_mm_s, dt)
    rot_b, r_o, t_o = pose.rotation, pose.target_rotation, pose.target_translation_mm
    implied, warnings = pose.implied_speed_mm_s, list(pose.warnings)
    # ----- stripes on the target around each calibration frame ----------------------------
    v_true = implied  # the travel between frames that matches the target's pose
    obs: dict[str, list] = {}
    for i, (name, t_c) in enumerate((("green", picks.t1), ("red", picks.t2))):
        cancel.check()
        report(progress, 0.15 + 0.3 * i, f"{name} stripe on the target")
        span = max(3, min(plane_span, int(round(plane_travel_mm / max(v_true, 1e-6) * fps))))
        lo, hi = max(0, t_c - span), min(video.frame_count, t_c + span + 1)
        wanted = sorted(set(np.linspace(lo, hi - 1, max(1, plane_frames)).astype(int)) | {t_c})
        obs[name] = []
        for k in wanted:
            cancel.check()
            dt_k = float(times[k] - times[picks.t1])
            uv = stripe_uv_on_target(video.read(int(k)), name, intrinsics, rot_b, (r_o, t_o),
                                     target, v_true * dt_k)
            if len(uv):
                obs[name].append((int(k), dt_k, intrinsics.rays(uv)))

    def stripe_points(name, rot, pose_rt):
        pts, hts, used = [], [], []
        for k, dt_k, rays in obs[name]:
            p, hh, _ = points_on_faces(rays @ rot.T, pose_rt, target, v_true * dt_k)
            levels = np.unique(hh)
            if len(levels) >= 2 and min(np.sum(hh == v) for v in levels) >= 10:
                pts.append(p)
                hts.append(hh)
                used.append(k)
        return pts, hts, used

    def planes_for(rot, pose_rt):
        out = {}
        for name, t_c in (("green", picks.t1), ("red", picks.t2)):
            pts, hts, used = stripe_points(name, rot, pose_rt)
            if not pts:
                raise CalibrationError(
                    f"the {name} stripe was not found on two target faces around frame {t_c}; "
                    "choose a frame where it crosses both the low and the high face",
                    code="E-PLANE-UNDETERMINED")
            # frames whose points disagree with the others (acceleration ramp, a passing
            # shadow) are dropped: their travel does not follow the constant speed
            if len(used) >= 4:
                first = fit_laser_plane(name, np.concatenate(pts), np.concatenate(hts), used)
                err = np.array([np.median(np.abs(first.plane.distance(p))) for p in pts])
                good = err <= max(3 * np.median(err), 0.02)
                pts = [p for p, g in zip(pts, good) if g]
                hts = [h for h, g in zip(hts, good) if g]
                used = [k for k, g in zip(used, good) if g]
            out[name] = (fit_laser_plane(name, np.concatenate(pts), np.concatenate(hts), used),
                         pts)
        return out

    planes0 = planes_for(rot_b, (r_o, t_o))
    if refine_with_stripes:
        # The clicks fix roll well but tilt poorly (a tilt of 0.05 deg moves the corners by
        # less than 0.1 px). The stripe on the target's faces, seen over a stretch of travel,
        # is only consistent with one motion direction: refine the tilt to minimise the plane
        # residuals of the stripe points together with the reprojection of the picks.
        from scipy.optimize import minimize_scalar

        sigma_s = max(1e-3, np.mean([f.rms_mm for f, _ in planes0.values()]))
        n_ref = {name: sum(len(p) for p in pts) for name, (_, pts) in planes0.items()}
        speed_ok = abs(implied - speed_mm_s) <= SPEED_WARN_FRACTION * speed_mm_s
        d_use = (speed_mm_s if speed_ok else v_true) * dt
        base = (pose.roll_rad, pose.tilt_rad, r_o, t_o)

        def cost(tilt):
            roll = pose.roll_rad
            _, _, ro, to, _, rms = _bundle(intrinsics, target, picks, (roll, tilt, base[2],
                                                                       base[3]),
                                           d_use, fixed_travel=True, fixed_rotation=True)
            rot = ideal_rotation(roll, tilt)
            total = 24 * (rms / click_sigma_px) ** 2
            for name in ("green", "red"):
                pts, hts, _ = stripe_points(name, rot, (ro, to))
                n_pts = sum(len(p) for p in pts)
                if n_pts < 0.8 * n_ref[name]:
                    return 1e12  # the stripe no longer falls on the faces: not a candidate
                allp = np.concatenate(pts)
                plane, _, _ = fit_plane(allp)
                r = np.clip(np.abs(plane.distance(allp)) / sigma_s, 0, 5)  # outliers capped
                total += n_ref[name] * float(np.mean(r**2))
            return total

        # tilt only: roll is fixed well by the picks (the stripes would add their own bias)
        span = np.radians(0.6)
        res = minimize_scalar(cost, bounds=(pose.tilt_rad - span, pose.tilt_rad + span),
                              method="bounded", options={"xatol": 2e-7})
        roll_r, tilt_r = pose.roll_rad, float(res.x)
        _, _, r_o, t_o, _, rms_px = _bundle(intrinsics, target, picks,
                                            (roll_r, tilt_r, base[2], base[3]), d_use,
                                            fixed_travel=True, fixed_rotation=True)
        rot_b = ideal_rotation(roll_r, tilt_r)
        m_b = rot_b.T @ np.array([0.0, 1.0, 0.0])
        n1 = intrinsics.undistort_points(picks.array("t1"))
        n2 = intrinsics.undistort_points(picks.array("t2"))
        corners = triangulate_parallax(*ideal_pair(intrinsics, rot_b, n1, n2), speed_mm_s * dt)
        _, r_e, t_e = umeyama(target.corner_array(), corners, with_scale=False)
        residuals = np.linalg.norm(corners - (target.corner_array() @ r_e.T + t_e), axis=1)
        pose = replace(pose, roll_rad=float(roll_r), tilt_rad=float(tilt_r), rotation=rot_b,
                       motion_dir_cam=m_b, corners_parallax_mm=corners,
                       corner_residuals_mm=residuals, target_rotation=r_o,
                       target_translation_mm=t_o, reprojection_rms_px=rms_px)
        planes0 = planes_for(rot_b, (r_o, t_o))
    planes = {name: fit for name, (fit, _) in planes0.items()}
    report(progress, 1.0, "calibrated")
    return SceneCalibration(
        intrinsics=intrinsics, speed_mm_s=float(speed_mm_s), fps=fps, t1=picks.t1, t2=picks.t2,
        t_ref_s=float(times[picks.t1]), motion_dir_cam=pose.motion_dir_cam,
        vanishing_point_px=_vp_pixels(intrinsics, pose.motion_dir_cam),
        roll_deg=float(np.degrees(pose.roll_rad)), tilt_deg=float(np.degrees(pose.tilt_rad)),
        rotation=rot_b, corners_parallax_mm=pose.corners_parallax_mm,
        corner_residuals_mm=pose.corner_residuals_mm, target_rotation=r_o,
        target_translation_mm=t_o, implied_speed_mm_s=float(implied),
        reprojection_rms_px=pose.reprojection_rms_px, planes=planes,
        warnings=tuple(warnings), inputs=dict(inputs or {}),
    )


def ideal_pair(intr, rot, n1, n2):
    def ideal(n):
        x = np.column_stack([n, np.ones(len(n))]) @ rot.T
        return x[:, 0] / x[:, 2], x[:, 1] / x[:, 2]

    a1, b1 = ideal(n1)
    a2, b2 = ideal(n2)
    return a1, b1, a2, b2


def _vp_pixels(intr: Intrinsics, m: np.ndarray) -> np.ndarray:
    v = intr.camera_matrix @ m
    if abs(v[2]) < 1e-12 * np.linalg.norm(v):
        return np.array([v[0], v[1], 0.0])
    return v / v[2]
