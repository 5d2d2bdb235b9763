"""The geometric part of the scene calibration: the motion direction from the L-target's
corner tracks (least-squares vanishing point, valid at infinity), roll and tilt, the metric
corners by motion parallax, a rigid (Umeyama) fit of the target model, and the refinement of
roll, tilt, target pose and travel by the reprojection error of all twelve picks."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from impress_gui.core.base import codes
from impress_gui.core.base.errors import CalibrationError
from impress_gui.core.calibration.geometry import (
    MAX_READOUT_MS,
    Intrinsics,
    ideal_rotation,
    rail_shift,
    roll_tilt_from_direction,
)
from impress_gui.core.calibration.picks import Picks
from impress_gui.core.calibration.target import TargetModel

SPEED_WARN_FRACTION = 0.01


def picks_scatter_px(reprojection_rms_px: float) -> float:
    """The click noise (px, one coordinate) the picks' reprojection RMS implies: the RMS x
    sqrt(24/15) (24 coordinates, 9 pose parameters); NaN when the RMS is not a number."""
    rms = float(reprojection_rms_px)
    return rms * math.sqrt(24.0 / 15.0) if math.isfinite(rms) else math.nan


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


def triangulate_parallax(a1, b1, a2, b2, travel_mm, start_mm=0.0) -> np.ndarray:
    """Rail-frame points from ideal normalized coordinates in two frames separated by a pure
    +Y travel: least squares of ``X = a1 Z = a2 Z``, ``Y - c = b1 Z``, ``Y - d = b2 Z`` (``c``
    = ``start_mm``, 0 but under a rolling shutter; ``d`` = ``travel_mm``; either one per
    point: each point's row was exposed at its own travel)."""
    n = len(a1)
    c = np.broadcast_to(np.asarray(start_mm, float), (n,))
    d = np.broadcast_to(np.asarray(travel_mm, float), (n,))
    pts = []
    for i in range(n):
        A = np.array([[-1, 0, a1[i]], [0, -1, b1[i]], [-1, 0, a2[i]], [0, -1, b2[i]]], float)
        rhs = np.array([0.0, -c[i] if c[i] else 0.0, 0.0, -d[i]])
        pts.append(np.linalg.lstsq(A, rhs, rcond=None)[0])
    return np.array(pts)


def row_offsets(intr: Intrinsics, picks: Picks, dt_s: float | None
                ) -> tuple[np.ndarray, np.ndarray] | None:
    """Under a rolling shutter, how far the camera had moved when each pick's row was
    exposed, per mm of travel from frame t1 to t2: ``(r1, r2)`` for the picks of t1 and t2
    (the travel at a pick of t1 is ``d r1``, at one of t2 ``d (1 + r2)``). None for a global
    shutter (or when the frames' time apart is not known)."""
    lt = intr.line_time_s
    if lt <= 0 or not dt_s:
        return None
    return (picks.array("t1")[:, 1] * lt / dt_s, picks.array("t2")[:, 1] * lt / dt_s)


def parallax_corners(intr: Intrinsics, rot: np.ndarray, picks: Picks, d: float,
                     dt_s: float | None = None) -> np.ndarray:
    """The picks' corners triangulated in the rail frame from the travel ``d`` between t1
    and t2 (each at its row's travel under a rolling shutter)."""
    n1 = intr.undistort_points(picks.array("t1"))
    n2 = intr.undistort_points(picks.array("t2"))
    rows = row_offsets(intr, picks, dt_s)
    if rows is None:
        return triangulate_parallax(*ideal_pair(intr, rot, n1, n2), d)
    return triangulate_parallax(*ideal_pair(intr, rot, n1, n2), d * (1.0 + rows[1]),
                                d * rows[0])


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


#: the relative step of the bundle's forward-difference Jacobian (scipy's "2-point" default)
_REL_STEP = float(np.finfo(float).eps) ** 0.5


def project_points(intr: Intrinsics, rot: np.ndarray, pts_rail: np.ndarray,
                   travel: float) -> np.ndarray:
    """Distorted pixels of rail-frame points seen from a camera that travelled ``travel``
    (one travel, or one per point)."""
    return intr.project((pts_rail - rail_shift(travel)) @ rot)  # rows: R^T (P - C)


def refine_bundle(intr, target, picks, init, d0, fixed_travel: bool = False,
                  fixed_rotation: bool = False, dt_s: float | None = None):
    """Refine roll, tilt (unless ``fixed_rotation``), the target pose and the travel (unless
    ``fixed_travel``) by the reprojection error of all 12 picks. ``dt_s``: the time from t1
    to t2, with which a rolling shutter's rows are placed at their own travel
    (:func:`row_offsets`)."""
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

    rows = row_offsets(intr, picks, dt_s)

    def resid_many(ps: np.ndarray) -> np.ndarray:
        """The residuals of several parameter vectors ``(K, n)`` at once: ``(K, 24)``."""
        parts = [unpack(p) for p in ps]
        rot = np.stack([q[0] for q in parts])
        pts = np.stack([obj @ q[1].T + q[2] for q in parts])  # (K, 6, 3) rail frame
        d = np.array([float(q[3]) for q in parts])[:, None]
        travels = (np.zeros_like(d), d) if rows is None else (d * rows[0], d * (1.0 + rows[1]))
        out = []
        for travel, uv in zip(travels, (uv1, uv2)):
            shifted = pts.copy()
            shifted[..., 1] -= travel  # the camera's travel along the rail (Y)
            out.append((intr.project(np.matmul(shifted, rot)) - uv).reshape(len(ps), -1))
        return np.concatenate(out, axis=1)

    def resid(p):
        return resid_many(p[None])[0]

    def jac(p):
        # scipy's forward differences ("2-point": the same steps), all columns in one batch
        # of projections: the tilt refinement and the calibration's Monte Carlo solve this
        # bundle thousands of times
        h = _REL_STEP * np.where(p >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(p))
        h = (p + h) - p
        f = resid_many(np.vstack([p, p + np.diag(h)]))
        return (f[1:] - f[0]).T / h

    p0 = np.concatenate(([] if fixed_rotation else [[roll, tilt]]) + [_rot_to_vec(r_o), t_o]
                        + ([] if fixed_travel else [[d0]]))
    sol = least_squares(resid, p0, jac=jac, method="lm", xtol=1e-14, ftol=1e-14, gtol=1e-14,
                        max_nfev=4000)
    rot, r_o, t_o, d = unpack(sol.x)
    rms = float(np.sqrt(np.mean(sol.fun**2)))
    if fixed_rotation:
        return roll, tilt, r_o, t_o, float(d), rms
    return sol.x[0], sol.x[1], r_o, t_o, float(d), rms


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
    #: the turn about the motion axis Y of :func:`level_across` (0 until it is applied)
    cross_tilt_rad: float = 0.0
    #: a rolling shutter's readout (ms) the picks showed where the intrinsics gave none
    #: (:func:`estimate_readout`; the pose is then solved with it), else None
    readout_ms_estimated: float | None = None


#: a readout estimated from the picks is used only when the fit with it is better beyond
#: chance at this level (an F test of the one added parameter against the picks' residual)
READOUT_F_LEVEL = 0.999
#: ... and when it takes the picks' reprojection RMS below this share of the rigid pose's
READOUT_RMS_SHARE = 0.5
#: ... from at least this RMS (px): picks that a rigid pose already fits hold nothing to gain
READOUT_MIN_RMS_PX = 0.05


def estimate_readout(intrinsics: Intrinsics, target: TargetModel, picks: Picks,
                     pose: PoseSolution, d: float, dt_s: float, fixed_travel: bool
                     ) -> tuple[float, float, float]:
    """A rolling shutter's readout (ms) from the 12 picks: the bundle of
    :func:`refine_bundle` with the line time free (each pick at its row's travel). Returns
    ``(readout_ms, rms_px with it, F statistic of the added parameter)``; the readout is
    signed (negative: the rows read bottom to top)."""
    from scipy.optimize import least_squares

    obj = target.corner_array()
    uv1, uv2 = picks.array("t1"), picks.array("t2")
    v1, v2 = uv1[:, 1], uv2[:, 1]

    def unpack(p):
        rot = ideal_rotation(p[0], p[1])
        d_ = d if fixed_travel else p[8]
        return rot, _rodrigues(p[2:5]), p[5:8], d_, p[-1]

    def resid(p):
        rot, r_o, t_o, d_, q = unpack(p)
        pts = obj @ r_o.T + t_o
        return np.concatenate([(project_points(intr_, rot, pts, d_ * q * v1) - uv1).ravel(),
                               (project_points(intr_, rot, pts, d_ * (1.0 + q * v2))
                                - uv2).ravel()])

    intr_ = intrinsics
    parts: list[np.ndarray] = [np.array([pose.roll_rad, pose.tilt_rad]),
                               _rot_to_vec(pose.target_rotation),
                               np.asarray(pose.target_translation_mm, float)]
    if not fixed_travel:
        parts.append(np.array([d]))
    p0 = np.concatenate([*parts, np.zeros(1)])
    sol = least_squares(resid, p0, method="lm", xtol=1e-14, ftol=1e-14, gtol=1e-14,
                        max_nfev=4000)
    n = sol.fun.size
    rss1 = float(np.sum(sol.fun**2))
    rss0 = n * pose.reprojection_rms_px**2
    dof = n - len(p0)
    f_stat = (rss0 - rss1) / max(rss1 / max(dof, 1), 1e-300)
    readout_ms = float(sol.x[-1]) * dt_s * 1000.0 * (intrinsics.image_size[1] - 1)
    return readout_ms, float(np.sqrt(rss1 / n)), float(f_stat)


#: below this median motion (px) of the corners between the two frames a refused pose says
#: that the frames lie too close together
SHORT_MOTION_PX = 40.0


def solve_pose(intrinsics: Intrinsics, target: TargetModel, picks: Picks, speed_mm_s: float,
               dt_s: float, mismatch_gate: bool = True) -> PoseSolution:
    """Motion direction, roll, tilt, metric corners and target pose from the picks.

    ``dt_s`` is the time between frames t1 and t2. ``mismatch_gate``: refuse picks whose
    corners, triangulated from their motion alone, do not fit the target's shape
    (E-TARGET-MISMATCH: a wrong corner order or target model). The calibration's Monte Carlo
    turns it off: its noisy picks fit the model by construction, and where the corners move
    only a few tens of pixels the click noise alone can fail the gate (random rig 28: 7 to
    11 of 20 trials), which would leave the widest trials out of the spread."""
    d = speed_mm_s * dt_s
    n1 = intrinsics.undistort_points(picks.array("t1"))
    n2 = intrinsics.undistort_points(picks.array("t2"))
    m = vanishing_point(n1, n2)
    roll, tilt = roll_tilt_from_direction(m)
    rot = ideal_rotation(roll, tilt)

    def ideal(n):
        x = np.column_stack([n, np.ones(len(n))]) @ rot.T
        return x[:, 0] / x[:, 2], x[:, 1] / x[:, 2]

    corners = parallax_corners(intrinsics, rot, picks, d, dt_s)
    if np.median(corners[:, 2]) < 0:  # the sign of the vanishing point: depths must be positive
        m = -m
        roll, tilt = roll_tilt_from_direction(m)
        rot = ideal_rotation(roll, tilt)
        corners = parallax_corners(intrinsics, rot, picks, d, dt_s)
    if np.any(corners[:, 2] <= 0):
        raise CalibrationError("the picks give corners behind the camera; check that t1/t2 and "
                               "the corner order match the target diagram", code=codes.E_PICKS)
    obj = target.corner_array()
    _, r_rigid, t_rigid = umeyama(obj, corners, with_scale=False)
    fitted = obj @ r_rigid.T + t_rigid
    residuals = np.linalg.norm(corners - fitted, axis=1)
    scale, r_s, t_s = umeyama(obj, corners, with_scale=True)
    if mismatch_gate and np.max(residuals) > 0.25 * target.size_mm():
        # the corners' depths come from their motion between the two frames: a few pixels of
        # it make a click's error a large depth error (random rigs 24 and 33 at 640x360: 14 and
        # 18 px of motion, 0.5 px clicks, residuals 12-21 mm)
        shift = float(np.median(np.linalg.norm(picks.array("t2") - picks.array("t1"), axis=1)))
        hint = (f"; the corners move only {shift:.0f} px between the two frames, so each "
                "click's error is a large depth error: mark frames farther apart (the corner "
                "aid suggests them)" if shift < SHORT_MOTION_PX else "")
        raise CalibrationError(
            f"the target model does not match the picks (corner residuals up to "
            f"{np.max(residuals):.1f} mm); check the corner order and the target model{hint}",
            code=codes.E_TARGET_MISMATCH)
    fix_rot = False
    roll_b, tilt_b, r_o, t_o, d_fit, rms_px = refine_bundle(
        intrinsics, target, picks, (roll, tilt, r_s, t_s / scale), d / scale,
        fixed_rotation=fix_rot, dt_s=dt_s)
    implied = d_fit / dt_s
    warnings = []
    if abs(implied - speed_mm_s) <= SPEED_WARN_FRACTION * speed_mm_s:
        # the entered speed is confirmed: the known travel constrains the pose better
        roll_b, tilt_b, r_o, t_o, _, rms_px = refine_bundle(
            intrinsics, target, picks, (roll_b, tilt_b, r_o, t_o), d, fixed_travel=True,
            fixed_rotation=fix_rot, dt_s=dt_s)
    rot_b = ideal_rotation(roll_b, tilt_b)
    m_b = rot_b.T @ np.array([0.0, 1.0, 0.0])
    if abs(implied - speed_mm_s) > SPEED_WARN_FRACTION * speed_mm_s:
        warnings.append(
            f"W-SPEED-MISMATCH: the target's size implies a rail speed of {implied:.4f} mm/s but "
            f"{speed_mm_s:.4f} mm/s was entered ({100 * (implied / speed_mm_s - 1):+.1f} %); "
            "check the speed setting (heights and lengths along the scan scale with it)")
    if rms_px > 2.0:
        warnings.append(f"W-PICKS-POOR-FIT: the corner picks fit the target poorly "
                        f"(reprojection RMS {rms_px:.2f} px)")
    # the corners in the rail frame with the entered speed (what the reconstruction uses)
    corners_entered = parallax_corners(intrinsics, rot_b, picks, d, dt_s)
    _, r_e, t_e = umeyama(obj, corners_entered, with_scale=False)
    residuals = np.linalg.norm(corners_entered - (obj @ r_e.T + t_e), axis=1)

    pose = PoseSolution(m_b, roll_b, tilt_b, rot_b, corners_entered, residuals, r_o, t_o,
                        float(implied), rms_px, tuple(warnings), roll, tilt)
    if intrinsics.readout_ms is None and rms_px >= READOUT_MIN_RMS_PX and dt_s:
        return _with_readout(intrinsics, target, picks, speed_mm_s, dt_s, pose, d,
                             abs(implied - speed_mm_s) <= SPEED_WARN_FRACTION * speed_mm_s,
                             mismatch_gate)
    return pose


def _with_readout(intrinsics, target, picks, speed_mm_s, dt_s, pose, d, speed_ok,
                  mismatch_gate: bool = True):
    """The pose with a rolling shutter's readout estimated from the picks
    (:func:`estimate_readout`) when they clearly show one: better beyond chance
    (:data:`READOUT_F_LEVEL`), the RMS below :data:`READOUT_RMS_SHARE` of the rigid pose's and
    the readout within one frame interval, rows read top to bottom; else ``pose`` as it is."""
    from scipy.stats import f as f_dist

    readout, rms1, f_stat = estimate_readout(intrinsics, target, picks, pose, d, dt_s,
                                             speed_ok)
    frame_ms = 1000.0 * abs(dt_s) / max(abs(picks.t2 - picks.t1), 1)
    dof = 24 - (9 if speed_ok else 10)
    if not (f_stat > f_dist.ppf(READOUT_F_LEVEL, 1, dof)
            and rms1 < READOUT_RMS_SHARE * pose.reprojection_rms_px
            and 0.0 < readout <= min(1.05 * frame_ms, MAX_READOUT_MS)):
        return pose
    from dataclasses import replace as _replace

    rolling = _replace(intrinsics, readout_ms=round(readout, 3))
    solved = solve_pose(rolling, target, picks, speed_mm_s, dt_s, mismatch_gate)
    note = (f"the corner picks show a rolling shutter: a readout of {rolling.readout_ms:.3g} ms "
            f"(reprojection RMS {pose.reprojection_rms_px:.3f} px with a global shutter, "
            f"{solved.reprojection_rms_px:.3f} px with it); each row is placed at its own "
            "travel. Record the camera's readout in its intrinsics (impress calibrate-camera "
            "--readout-ms) to use the known value")
    return _replace(solved, warnings=(*solved.warnings, note),
                    readout_ms_estimated=rolling.readout_ms)


def rot_y(angle_rad: float) -> np.ndarray:
    """Rotation about the Y (motion) axis: X towards Z for a positive angle (the simulator's
    convention for its cross tilt)."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def cross_level_angle(target_rotation: np.ndarray) -> float:
    """The angle (rad) of the turn :func:`rot_y` about the motion axis that levels the target's
    base across the scan: its 'up' ``u`` (object +Z in the rail frame, towards the camera)
    turned to ``(0, u_y, u_z')`` (``c u_x - s u_z = 0``)."""
    u = np.asarray(target_rotation, float) @ np.array([0.0, 0.0, 1.0])
    return float(np.arctan(u[0] / u[2]))


def level_across(pose: PoseSolution) -> PoseSolution:
    """The pose in the levelled frame: the ideal frame turned about the motion axis Y until the
    target's base (the height reference) is level across the scan.

    The motion reveals roll and tilt (it is +Y), not the camera's turn about the motion
    axis itself: left in the ideal frame, that turn tilts the base plane across the map and
    every height is read vertically against a sloping plane (x 1/cos of the turn; 0.35 % at
    4.8 deg), widths across the scan shrink by cos and walls lean. A turn about Y keeps the
    motion on +Y and the origin (the optical centre at t1), so the camera rotation, the target
    pose and the corners are simply re-expressed (a laser plane ``n . X = d`` fitted in this
    frame has the normal turned and the same offset). Idempotent."""
    theta = cross_level_angle(pose.target_rotation)
    m = rot_y(theta)
    return replace(pose, rotation=m @ pose.rotation,
                   corners_parallax_mm=np.asarray(pose.corners_parallax_mm, float) @ m.T,
                   target_rotation=m @ pose.target_rotation,
                   target_translation_mm=m @ pose.target_translation_mm,
                   cross_tilt_rad=float(pose.cross_tilt_rad + theta))


def ideal_pair(intr: Intrinsics, rot: np.ndarray, n1: np.ndarray, n2: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Ideal-frame normalized coordinates ``a1, b1, a2, b2`` of the undistorted picks ``n1``
    (frame t1) and ``n2`` (frame t2), for :func:`triangulate_parallax`."""
    def ideal(n):
        x = np.column_stack([n, np.ones(len(n))]) @ rot.T
        return x[:, 0] / x[:, 2], x[:, 1] / x[:, 2]

    a1, b1 = ideal(n1)
    a2, b2 = ideal(n2)
    return a1, b1, a2, b2
