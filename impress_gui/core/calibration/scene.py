"""Scene calibration from the scan itself (the seed's self-calibration, made better).

From the six L-target corners marked in frames t1 and t2 this recovers the motion direction
(least-squares vanishing point of all six corner tracks, valid at infinity), roll and tilt, the
metric corners by motion parallax, a rigid fit of the target model (per-corner residuals, and
the speed implied by the target's known size), then refines everything by minimising the
reprojection error of all twelve picks. The frame is then turned about the motion axis until
the target's base is level across the scan (the camera's turn about the motion axis, which the
motion does not reveal; :func:`~impress_gui.core.calibration.solve.level_across`). Each laser
plane is fitted to every stripe pixel that falls on a known target face, in several frames
around its calibration frame.

This module holds :class:`SceneCalibration` (and its file format) and the entry point
:func:`calibrate_scene`; the geometric solvers are in :mod:`~impress_gui.core.calibration.solve`, the
laser planes and the tilt refinement from the stripes in :mod:`~impress_gui.core.calibration.planes`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from impress_gui import __version__
from impress_gui.core.base import codes
from impress_gui.core.base.errors import CalibrationError, FormatError
from impress_gui.core.base.fileio import float_array, read_json, require, write_json
from impress_gui.core.base.progress import CancelToken, ProgressCallback, report, sub_progress
from impress_gui.core.calibration import motion
from impress_gui.core.calibration.aids import check_stripe_points, three_point_planes
from impress_gui.core.calibration.geometry import Intrinsics, Plane
from impress_gui.core.calibration.picks import Picks
from impress_gui.core.calibration.planes import (
    LaserPlaneFit,
    observe_stripes,
    refine_tilt,
    stripe_window,
)
from impress_gui.core.calibration.solve import (
    SPEED_WARN_FRACTION,
    level_across,
    picks_scatter_px,
    project_points,
    solve_pose,
    vanishing_point,
)
from impress_gui.core.calibration.target import CORNER_NAMES, TargetModel

# public names (LaserPlaneFit, solve_pose and vanishing_point re-exported for the callers)
__all__ = ["CALIBRATION_FORMAT", "PLANE_METHODS", "LaserPlaneFit", "SceneCalibration",
           "calibrate_scene", "check_picks", "solve_pose", "vanishing_point"]

CALIBRATION_FORMAT = "impress.calibration"
#: how the laser planes are found (recorded in each plane's ``method``)
PLANE_METHODS = ("stripe-fit", "three-point")
#: a laser plane fitted from stripe points whose heights span less than this (mm) is warned
#: about (issue 18): the random rigs' targets step 10-25 mm, the default target 30 mm, and
#: the ground beside the target adds height 0
PLANE_SPAN_WARN_MM = 10.0
#: a laser plane whose stripe points lie farther than this from it (RMS, mm) is warned about
#: (the simulator's rigs: 0.01-0.05 mm at 640x360 and 1080p) ...
PLANE_WARN_MM = 0.2
#: ... and beyond this it is refused: heights would be off by millimetres (light on the target
#: that is not this laser's, a wrong target file, a stripe not on the faces)
PLANE_REFUSE_MM = 1.0
#: a tilt refined by more than this (deg) from the picks' tilt has the stripes gathered again
#: with the refined pose, then refined once more (their crops followed the picks' pose)
REGATHER_TILT_DEG = 0.25
#: the click noise (px) the tilt refinement assumes for the corner picks is what their own fit
#: shows - the pose's reprojection RMS x sqrt(24/15) (24 coordinates, 9 pose parameters) -
#: never more than CLICK_SIGMA_PX (a user's clicks; the stripes then set the tilt) and never
#: less than PICKS_SIGMA_FLOOR_PX. Picks consistent to a ten-thousandth of a pixel (the
#: simulator's exact ones, a fitted corner detector's) then hold the tilt the stripes would
#: pull 0.01-0.016 deg off (random rigs 229, 249); clicks as users make them (0.2-0.5 px) weigh
#: what they did before (issue 18, 2026-12-07)
CLICK_SIGMA_PX = 0.5
PICKS_SIGMA_FLOOR_PX = 1e-4


def picks_sigma_px(reprojection_rms_px: float) -> float:
    """The click noise (px) the picks' own pose fit implies (see :data:`CLICK_SIGMA_PX`)."""
    est = picks_scatter_px(reprojection_rms_px)
    if not np.isfinite(est):
        return CLICK_SIGMA_PX
    return float(np.clip(est, PICKS_SIGMA_FLOOR_PX, CLICK_SIGMA_PX))


def _opt_float(doc: dict, key: str, where: str, top: float = 100.0, unit: str = "mm") -> float:
    """An optional number of a record within 0..``top`` (``unit``); NaN when absent."""
    if key not in doc:
        return float("nan")
    v = float(require(doc, key, float, where))
    if not np.isfinite(v) or not 0 <= v <= top:
        raise FormatError(f"{where}{key} must be a number from 0 to {top:g} {unit}, not {v!r}",
                          code=codes.E_VALUE)
    return v


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
    rotation: np.ndarray  # camera -> levelled ideal frame (R_y(cross) R_x(tilt) R_z(roll))
    corners_parallax_mm: np.ndarray  # (6, 3) rail frame, by motion parallax with the entered speed
    corner_residuals_mm: np.ndarray  # (6,) after the rigid fit of the target model
    target_rotation: np.ndarray  # object -> rail
    target_translation_mm: np.ndarray
    implied_speed_mm_s: float
    reprojection_rms_px: float
    planes: dict[str, LaserPlaneFit]
    warnings: tuple[str, ...] = ()
    inputs: dict = field(default_factory=dict)
    #: the turn (deg) about the motion axis Y that levelled the target's base across the scan
    #: (:func:`~impress_gui.core.calibration.solve.level_across`; informational: ``rotation``
    #: includes it; 0 in files written before the levelling, whose frame is the unlevelled one)
    cross_tilt_deg: float = 0.0
    #: the click noise (px) the tilt refinement weighed the corner picks with
    #: (:func:`picks_sigma_px`); NaN where the tilt was not refined or in older files
    tilt_click_sigma_px: float = float("nan")

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
        return project_points(self.intrinsics, self.rotation, np.asarray(pts_rail_mm, float), travel_mm)

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
            "frames": "rail frame: axes of the ideal frame (camera rotated so the motion is +Y, "
                      "then turned about Y by cross_tilt_deg so the target's base is level "
                      "across the scan), origin at the optical centre at frame t1; Z' = depth; "
                      "planes are in the camera-fixed ideal frame",
            "motion_direction_camera": self.motion_dir_cam.tolist(),
            "vanishing_point_px": self.vanishing_point_px.tolist(),
            "roll_deg": self.roll_deg,
            "tilt_deg": self.tilt_deg,
            "cross_tilt_deg": self.cross_tilt_deg,
            "rotation_camera_to_ideal": self.rotation.tolist(),
            "corners_parallax_mm": {c: self.corners_parallax_mm[i].tolist()
                                    for i, c in enumerate(CORNER_NAMES)},
            "corner_residuals_mm": {c: float(self.corner_residuals_mm[i])
                                    for i, c in enumerate(CORNER_NAMES)},
            "target_pose": {"rotation": self.target_rotation.tolist(),
                            "translation_mm": self.target_translation_mm.tolist()},
            "implied_speed_mm_s": self.implied_speed_mm_s,
            "reprojection_rms_px": self.reprojection_rms_px,
            **({"tilt_click_sigma_px": self.tilt_click_sigma_px}
               if np.isfinite(self.tilt_click_sigma_px) else {}),
            "laser_planes": {
                n: {"normal": f.plane.normal.tolist(), "offset_mm": f.plane.offset_mm,
                    "rms_mm": f.rms_mm, "n_points": f.n_points, "frames": list(f.frames),
                    "heights_mm": list(f.heights_mm), "method": f.method}
                | ({"stripe_rows": f.stripe_rows} if f.stripe_rows else {})
                | ({"ground_points": f.ground_points, "ground_note": f.ground_note}
                   if f.ground_note else {})
                | {k: v for k, v in (("segment_sd_mm", f.segment_sd_mm),
                                     ("point_sd_mm", f.point_sd_mm),
                                     ("face_sd_mm", f.face_sd_mm)) if np.isfinite(v)}
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
                    str(pd.get("method", "stripe-fit")), str(pd.get("stripe_rows", "")),
                    int(pd.get("ground_points", 0)), str(pd.get("ground_note", "")),
                    _opt_float(pd, "segment_sd_mm", f"{where}laser_planes.{name}."),
                    _opt_float(pd, "point_sd_mm", f"{where}laser_planes.{name}."),
                    _opt_float(pd, "face_sd_mm", f"{where}laser_planes.{name}."))
            for name in ("green", "red"):
                if name not in planes:
                    raise FormatError(f"{where}the {name} laser plane is missing")
            pose = require(doc, "target_pose", dict, where)
            cp = require(doc, "corners_parallax_mm", dict, where)
            cr = require(doc, "corner_residuals_mm", dict, where)
            speed = float(require(doc, "speed_mm_s", float, where))
            fps = float(require(doc, "fps", float, where))
            check_range(speed, SPEED_RANGE_MM_S, "the rail speed (mm/s)", where)
            check_range(fps, FPS_RANGE, "the frame rate (frames/s)", where)
            for key in ("t1", "t2"):
                check_range(require(doc, key, int, where), FRAME_RANGE, f"frame {key}", where)
            check_range(require(doc, "t_ref_s", float, where), TIME_RANGE_S,
                        "the reference time (s)", where)
            check_range(require(doc, "implied_speed_mm_s", float, where), (0.0, 1e4),
                        "the implied speed (mm/s)", where)
            check_range(require(doc, "reprojection_rms_px", float, where), (0.0, 1e4),
                        "the reprojection RMS (px)", where)
            check_range(doc.get("cross_tilt_deg", 0.0), (-90.0, 90.0),
                        "the turn about the motion axis (deg)", where)
            for key, rot in (("rotation_camera_to_ideal", doc.get("rotation_camera_to_ideal")),
                             ("target_pose.rotation", pose.get("rotation"))):
                r = float_array(rot, (3, 3), key)
                if not (np.allclose(r @ r.T, np.eye(3), atol=1e-6)
                        and abs(np.linalg.det(r) - 1.0) < 1e-6):
                    raise FormatError(f"{where}{key} is not a rotation (not orthonormal with "
                                      "determinant 1): the file is damaged or forged",
                                      code=codes.E_VALUE)
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
                cross_tilt_deg=float(doc.get("cross_tilt_deg", 0.0)),
                tilt_click_sigma_px=_opt_float(doc, "tilt_click_sigma_px", where, unit="px"),
            )
        except (TypeError, ValueError, AttributeError, OverflowError, KeyError, IndexError):
            raise FormatError(f"{where}damaged calibration (a field has the wrong kind of "
                              "value, or numbers of the wrong count)") from None

    def save(self, path) -> None:
        write_json(path, self.to_json())

    @classmethod
    def from_bytes(cls, raw: bytes, path) -> SceneCalibration:
        from impress_gui.core.base.fileio import parse_json

        return cls.from_json(parse_json(raw, path, CALIBRATION_FORMAT), f"{path}: ")

    @classmethod
    def load(cls, path) -> SceneCalibration:
        return cls.from_json(read_json(path, CALIBRATION_FORMAT), f"{path}: ")


#: physical ranges of a calibration's numbers: a value outside is a damaged or forged file
SPEED_RANGE_MM_S = (0.01, 1000.0)  # the rail's slowest crawl to far beyond its fastest
FPS_RANGE = (0.5, 1000.0)
FRAME_RANGE = (0, 10_000_000)  # ~4 days at 30 frames/s
TIME_RANGE_S = (-1e6, 1e6)


def check_range(value, bounds: tuple[float, float], what: str, where: str = "") -> None:
    """FormatError ``E-VALUE`` unless ``bounds[0] <= value <= bounds[1]``."""
    lo, hi = bounds
    if not (lo <= float(value) <= hi):
        raise FormatError(f"{where}{what} is {value:g}, outside the possible range "
                          f"{lo:g} to {hi:g}", code=codes.E_VALUE)


def check_picks(picks: Picks, intrinsics: Intrinsics, frame_count: int) -> None:
    """Each problem with the picks is a clear error naming it (never a silent NaN)."""
    w, h = intrinsics.image_size
    for key, t in (("t1", picks.t1), ("t2", picks.t2)):
        if not 0 <= t < frame_count:
            raise CalibrationError(f"frame {key} = {t} is outside the video (0..{frame_count - 1})",
                                   code=codes.E_FRAME_RANGE)
    if picks.t1 == picks.t2:
        raise CalibrationError("t1 and t2 are the same frame: the corners need two frames "
                               "with travel between them", code=codes.E_PICKS)
    for key in ("t1", "t2"):
        d = picks.corners_t1 if key == "t1" else picks.corners_t2
        missing = [c for c in CORNER_NAMES if c not in d]
        if missing:
            raise CalibrationError(f"corners {', '.join(missing)} are not marked in frame {key}; "
                                   "all six corners A-F are needed in both frames",
                                   code=codes.E_PICKS_INCOMPLETE)
        arr = picks.array(key)
        for c, (u, v) in zip(CORNER_NAMES, arr):
            if not (-0.5 <= u <= w - 0.5 and -0.5 <= v <= h - 0.5):
                raise CalibrationError(f"corner {c} in frame {key} ({u:.1f}, {v:.1f}) is outside "
                                       f"the {w}x{h} image", code=codes.E_PICKS)
        dist = np.linalg.norm(arr[:, None] - arr[None], axis=2) + np.eye(6) * 1e9
        i, j = np.unravel_index(np.argmin(dist), dist.shape)
        if dist[i, j] < 2.0:
            raise CalibrationError(f"corners {CORNER_NAMES[i]} and {CORNER_NAMES[j]} in frame "
                                   f"{key} are at the same place", code=codes.E_PICKS)
        centred = arr - arr.mean(0)
        s = np.linalg.svd(centred, compute_uv=False)
        if s[1] < 0.02 * s[0] or s[1] < 3.0:
            raise CalibrationError(f"the corners in frame {key} are (nearly) collinear; check "
                                   "the order A-F against the target diagram", code=codes.E_PICKS)
    shift = np.linalg.norm(picks.array("t2") - picks.array("t1"), axis=1)
    if np.median(shift) < 5.0:
        raise CalibrationError("the corners barely move between t1 and t2; choose frames "
                               "further apart (where the red stripe crosses the target first, "
                               "t2 is red's first frame on it and t1 green's last)",
                               code=codes.E_PICKS)


#: the most frames a laser plane is fitted from (``plane_frames``)
MAX_PLANE_FRAMES = 300
#: frames a laser plane is fitted from by default, spread evenly over the stripe's travel
#: across the target (``plane_travel_mm``). The tilt the stripes refine is limited by the
#: stripe rows' noise, which more frames average: on 36 random rigs at 1080p with exact
#: picks, 15 frames left the tilt up to 0.013 deg off (rigs 11 and 67), 45 frames at most
#: 0.006 deg; with the renderer's exact stripe rows it is exact (issue 18, 2026-12-05)
DEFAULT_PLANE_FRAMES = 45


def calibrate_scene(video, intrinsics: Intrinsics, target: TargetModel, picks: Picks,
                    speed_mm_s: float, fps: float | None = None,
                    plane_frames: int = DEFAULT_PLANE_FRAMES,
                    plane_span: int = 300, plane_travel_mm: float = 25.0,
                    refine_with_stripes: bool = True, click_sigma_px: float | None = None,
                    progress: ProgressCallback | None = None,
                    cancel: CancelToken | None = None, inputs: dict | None = None,
                    plane_method: str = "stripe-fit") -> SceneCalibration:
    """Calibrate the rig from one scan. ``video`` is an open :class:`VideoSource`.

    ``plane_method``: ``"stripe-fit"`` fits each laser plane to its stripe on the target's
    faces (and refines the tilt with them); ``"three-point"`` is the seed's fallback, each
    plane through three stripe points the user picked on target edges (``picks.stripe_points``),
    with no stripe detection and the pose from the corner picks alone. ``click_sigma_px``: the
    picks' noise the tilt refinement weighs them with; None: what their own fit shows
    (:func:`picks_sigma_px`)."""
    cancel = cancel or CancelToken()
    if plane_method not in PLANE_METHODS:
        raise CalibrationError(f"unknown laser plane method {plane_method!r} (known: "
                               f"{', '.join(PLANE_METHODS)})", code=codes.E_CALIB)
    if not np.isfinite(speed_mm_s) or not 0.01 <= speed_mm_s <= 1000:
        raise CalibrationError(f"rail speed {speed_mm_s} mm/s is not plausible", code=codes.E_SPEED)
    if (isinstance(plane_frames, bool) or not isinstance(plane_frames, (int, np.integer))
            or not 1 <= plane_frames <= MAX_PLANE_FRAMES):
        raise CalibrationError(f"{plane_frames} frames per laser plane: give 1 to "
                               f"{MAX_PLANE_FRAMES}", code=codes.E_VALUE)
    w, h = video.size
    intrinsics.check_image_size(w, h)
    check_picks(picks, intrinsics, video.frame_count)
    if plane_method == "three-point":
        check_stripe_points(picks, intrinsics, video.frame_count)
    fps = float(fps or video.fps)
    times = video.times_s if fps == video.fps else np.arange(video.frame_count) / fps
    # the corners were marked on frames t1 and t2: both must decode without damage
    for k in (picks.t1, picks.t2):
        video.read(k)
    _refuse_damaged(video, (picks.t1, picks.t2))
    warnings_ramp: list[str] = []
    if plane_method == "stripe-fit":
        # each frame at the time of its travel at constant speed: the frames in the rail's
        # ramps (where the stripes' frames reach the video's ends) moved by the picture's motion
        report(progress, 0.01, "the rail's ramps in the picture's motion")
        times, warnings_ramp = _travel_times(video, times, picks, speed_mm_s, fps, plane_span,
                                             plane_travel_mm, cancel)
    dt = float(times[picks.t2] - times[picks.t1])
    report(progress, 0.05, "motion direction and pose")
    pose = solve_pose(intrinsics, target, picks, speed_mm_s, dt)
    if click_sigma_px is None:
        click_sigma_px = picks_sigma_px(pose.reprojection_rms_px)
    implied, warnings = pose.implied_speed_mm_s, list(pose.warnings) + warnings_ramp
    if pose.readout_ms_estimated is not None:
        # the picks showed a rolling shutter the intrinsics did not give: the stripes, the
        # calibration file and the reconstruction use the readout estimated
        intrinsics = replace(intrinsics, readout_ms=pose.readout_ms_estimated)
    if plane_method == "three-point":
        pose = level_across(pose)
        report(progress, 0.5, "laser planes from the three stripe points")
        # the travel the target's pose was fitted with: the entered speed once confirmed
        v_pose = (speed_mm_s if abs(implied - speed_mm_s) <= SPEED_WARN_FRACTION * speed_mm_s
                  else implied)
        planes = three_point_planes(
            intrinsics, pose.rotation, target,
            (pose.target_rotation, pose.target_translation_mm), picks,
            lambda k: v_pose * float(times[k] - times[picks.t1]))
        check_plane_distances(planes)
        warnings.append("W-THREE-POINT-PLANES: laser planes by the three-point method (three "
                        "picked stripe points per laser): coarser than the stripe fit, with no "
                        "residual check, and the tilt is not refined by the stripes")
    else:
        # ----- stripes on the target around each calibration frame ------------------------
        obs = observe_stripes(video, times, intrinsics, target, picks, pose, fps, plane_frames,
                              plane_span, plane_travel_mm, progress, cancel)
        planes0 = obs.fit_planes(pose.rotation,
                                 (pose.target_rotation, pose.target_translation_mm))
        if refine_with_stripes:
            tilt0 = pose.tilt_rad
            pose = refine_tilt(obs, planes0, intrinsics, target, picks, pose, speed_mm_s, dt,
                               click_sigma_px)
            if abs(pose.tilt_rad - tilt0) > np.radians(REGATHER_TILT_DEG):
                # the stripes were cropped to the faces as the picks' pose saw them: a tilt
                # that moved far moves the faces in the picture, so the stripes are gathered
                # again with the refined pose and the tilt refined once more
                report(progress, 0.46, "stripes gathered again with the refined tilt")
                obs = observe_stripes(video, times, intrinsics, target, picks, pose, fps,
                                      plane_frames, plane_span, plane_travel_mm,
                                      sub_progress(progress, 0.46, 0.6), cancel)
                planes0 = obs.fit_planes(pose.rotation,
                                         (pose.target_rotation, pose.target_translation_mm))
                pose = refine_tilt(obs, planes0, intrinsics, target, picks, pose, speed_mm_s,
                                   dt, click_sigma_px)
        # the frame levelled across the scan (the turn about the motion axis), then the final
        # planes in it: the faces' points and the ground's beside the target
        pose = level_across(pose)
        planes0 = obs.fit_planes(pose.rotation,
                                 (pose.target_rotation, pose.target_translation_mm),
                                 with_ground=True)
        planes = {name: fit for name, (fit, _) in planes0.items()}
        warnings += plane_residual_warnings(planes)
        warnings += face_agreement_warnings(
            obs, planes, pose.rotation, (pose.target_rotation, pose.target_translation_mm))
        check_plane_distances(planes)
        warnings += plane_span_warnings(planes)
        warnings += [f"W-STRIPE-BLOOMS: the {name} stripe blooms (a saturated, nearly white "
                     "core) on the target: found there by the colour it adds to the surface "
                     "against the background, its core's colour being lost; check its plane's "
                     "residual"
                     for name in obs.blooming]
        _refuse_damaged(video, sorted({k for f in planes.values() for k in f.frames}))
    warnings += list(getattr(video, "open_warnings", []))
    report(progress, 1.0, "calibrated")
    return SceneCalibration(
        intrinsics=intrinsics, speed_mm_s=float(speed_mm_s), fps=fps, t1=picks.t1, t2=picks.t2,
        t_ref_s=float(times[picks.t1]), motion_dir_cam=pose.motion_dir_cam,
        vanishing_point_px=_vp_pixels(intrinsics, pose.motion_dir_cam),
        roll_deg=float(np.degrees(pose.roll_rad)), tilt_deg=float(np.degrees(pose.tilt_rad)),
        rotation=pose.rotation, corners_parallax_mm=pose.corners_parallax_mm,
        corner_residuals_mm=pose.corner_residuals_mm, target_rotation=pose.target_rotation,
        target_translation_mm=pose.target_translation_mm, implied_speed_mm_s=float(implied),
        reprojection_rms_px=pose.reprojection_rms_px, planes=planes,
        warnings=tuple(warnings), inputs=dict(inputs or {}),
        cross_tilt_deg=float(np.degrees(pose.cross_tilt_rad)),
        tilt_click_sigma_px=float(click_sigma_px) if plane_method == "stripe-fit"
        and refine_with_stripes else float("nan"),
    )


def _travel_times(video, times: np.ndarray, picks: Picks, speed_mm_s: float, fps: float,
                  plane_span: int, plane_travel_mm: float, cancel: CancelToken
                  ) -> tuple[np.ndarray, list[str]]:
    """``times`` with the frames in the rail's ramps moved to the time of their travel at
    constant speed (:mod:`.motion`), measured only at an end of the video the stripes' frames
    reach into; and a warning for a calibration frame in a ramp."""
    n = video.frame_count
    reach = int(np.ceil(motion.SEARCH_S * fps))
    windows = [stripe_window(t, speed_mm_s, fps, plane_span, plane_travel_mm, n)
               for t in (picks.t1, picks.t2)]
    ends = (min(lo for lo, _ in windows) < reach, max(hi for _, hi in windows) > n - reach)
    if not any(ends):
        return times, []
    ramps = motion.measure_ramps(video, fps, cancel, ends)
    warnings = [
        f"W-PICK-IN-RAMP: calibration frame {k} ({name}) lies in the rail's acceleration or "
        "deceleration ramp, where the speed is not constant: its travel was taken from the "
        "picture's motion (a few hundredths of a millimetre uncertain); choose frames between "
        f"{int(np.ceil(ramps.constant_from))} and {int(np.floor(ramps.constant_until))} for "
        "the best calibration"
        for name, k in (("t1", picks.t1), ("t2", picks.t2)) if not ramps.at_constant_speed(k)]
    return ramps.travel_times(times, fps), warnings


def plane_residual_warnings(planes: dict[str, LaserPlaneFit]) -> list[str]:
    """A warning per laser plane whose stripe points lie more than :data:`PLANE_WARN_MM` (RMS)
    from it; CalibrationError (``E-CALIB``) beyond :data:`PLANE_REFUSE_MM`."""
    out = []
    for name, fit in planes.items():
        if not np.isfinite(fit.rms_mm) or fit.rms_mm > PLANE_REFUSE_MM:
            raise CalibrationError(
                f"the {name} stripe's points on the target lie {fit.rms_mm:.2f} mm (RMS) from "
                f"the plane fitted to them, more than the {PLANE_REFUSE_MM:g} mm accepted: "
                "heights would be off by millimetres. Check the target file against the "
                "target filmed, that the picks are on its corners, and that no other light "
                "falls on its faces near the calibration frames (choose other frames t1/t2)",
                code=codes.E_CALIB)
        if fit.rms_mm > PLANE_WARN_MM:
            out.append(f"the {name} stripe's points lie {fit.rms_mm:.3f} mm (RMS) from their "
                       f"plane (usually below 0.05 mm): heights may be off by as much; check "
                       "the target file and the picks, or choose other frames t1/t2")
    return out


#: a laser's plane should lie within this many of its RMS (and at least FACE_AGREE_MIN_MM)
#: of most of its stripe's points on each face of the target
FACE_AGREE_RMS = 5.0
FACE_AGREE_MIN_MM = 0.05
#: the share of a face's stripe points the plane must agree with, below which it warns
FACE_AGREE_SHARE = 0.5


def face_agreement_warnings(obs, planes: dict[str, LaserPlaneFit], rot: np.ndarray,
                            pose_rt) -> list[str]:
    """A warning per laser plane that most of its stripe's points on one face of the target
    do not lie on (within :data:`FACE_AGREE_RMS` x its RMS): the robust fit left them out
    as outliers. A plane fitted to one face's points and a few frames of another light on
    the other face fits them closely and has a small RMS, yet is turned about the first
    face's line by tens of degrees (random rig 15 at 1080p with 45 frames, before the fit's
    start was judged face by face): its RMS alone does not show it."""
    out = []
    for name, fit in planes.items():
        if fit.method != "stripe-fit" or name not in obs.rays:
            continue
        pts, hts, used = obs.points(name, rot, pose_rt)
        # the frames the fit kept (those whose points disagreed with the others as a whole,
        # an acceleration ramp say, were dropped and are not the plane's to lie on)
        kept = [i for i, k in enumerate(used) if k in set(fit.frames)]
        if not kept:
            continue
        p = np.concatenate([pts[i] for i in kept])
        h = np.concatenate([hts[i] for i in kept])
        near = np.abs(fit.plane.distance(p)) <= max(FACE_AGREE_RMS * fit.rms_mm,
                                                    FACE_AGREE_MIN_MM)
        for lv in np.unique(h):
            m = h == lv
            share = float(near[m].mean())
            if m.sum() >= 10 and share < FACE_AGREE_SHARE:
                out.append(f"the {name} laser plane lies on only {100 * share:.0f} % of its "
                           f"stripe's points on the target's face at {lv:.1f} mm: it may be "
                           "turned by other light on the target; check the stripe on the "
                           "faces in the calibration frames, or choose other frames t1/t2")
    return out


#: a laser's plane this near the camera's centre (mm) sees its stripe almost edge-on: no
#: triangulation (a real laser sits beside the camera; the thesis rig 130 mm, the
#: simulator's random rigs 60-250 mm). Found so on picks whose t1 and t2 were swapped.
#: Checked when a calibration is made and when one is used to process, not when a file or
#: a project is read (a project saved with such a calibration still opens)
PLANE_MIN_DISTANCE_MM = 10.0


def check_plane_distances(planes: dict[str, LaserPlaneFit]) -> None:
    """CalibrationError (``E-CALIB``) when a laser's plane passes within
    :data:`PLANE_MIN_DISTANCE_MM` of the camera's centre."""
    for name, fit in planes.items():
        d = abs(float(fit.plane.distance(np.zeros(3))))
        if not np.isfinite(d) or d < PLANE_MIN_DISTANCE_MM:
            other = "red" if name == "green" else "green"
            raise CalibrationError(
                f"the {name} laser's plane was found {d:.1f} mm from the camera's centre (a "
                f"laser beside the camera is tens of millimetres away at least): its heights "
                f"could not be triangulated. Check that t1 shows the green stripe on both top "
                f"faces of the target and t2 the red one (t1 and t2 swapped give this), and "
                f"that the {name} stripe is not taken for the {other} one",
                code=codes.E_CALIB)


def plane_span_warnings(planes: dict[str, LaserPlaneFit]) -> list[str]:
    """A warning per laser plane fitted from stripe points whose heights (the target's faces,
    and the ground when its points joined) span less than :data:`PLANE_SPAN_WARN_MM`."""
    out = []
    for name, fit in planes.items():
        levels = sorted(set(fit.heights_mm) | ({0.0} if fit.ground_points else set()))
        span = levels[-1] - levels[0] if levels else 0.0
        if span < PLANE_SPAN_WARN_MM:
            out.append(
                f"the {name} laser plane is fitted from heights spanning only {span:g} mm "
                f"({', '.join(f'{h:g}' for h in levels)} mm): heights far from them are "
                "extrapolated and may be scaled wrongly; use a target with a taller step or "
                "flat ground beside it")
    return out


def _refuse_damaged(video, frames) -> None:
    """CalibrationError ``E-VIDEO-DAMAGED`` when a frame the calibration uses was decoded from
    damaged data."""
    bad = [(int(k), video.frame_damage(k)) for k in frames
           if hasattr(video, "frame_damage") and video.frame_damage(k)]
    if bad:
        k, why = bad[0]
        raise CalibrationError(f"frame {k}, used by the calibration, is damaged ({why}); "
                               "choose other frames t1/t2 or a sound copy of the video",
                               code=codes.E_VIDEO_DAMAGED)


def _vp_pixels(intr: Intrinsics, m: np.ndarray) -> np.ndarray:
    v = intr.camera_matrix @ m
    if abs(v[2]) < 1e-12 * np.linalg.norm(v):
        return np.array([v[0], v[1], 0.0])
    return v / v[2]
