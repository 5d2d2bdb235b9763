"""How uncertain a scene calibration is, by Monte Carlo (Qt-free; GUM Supplement 1 style).

The calibration file does not keep the pixels it was computed from (the corner picks are a
separate file, the stripe pixels are not written at all), so the Monte Carlo works from what the
file does hold - the solved pose, the target pose, the laser planes with their fit RMS, point
counts and frames, the reprojection RMS of the picks - and the target model:

1. the twelve "model picks" are the fitted target corners projected into frames t1 and t2 (the
   picks as they would be without click noise);
2. each trial adds independent normal click noise of ``click_sigma_px`` to every pick and solves
   the pose again with the product's own solver (:func:`~impress_gui.core.calibration.solve.solve_pose`:
   vanishing point, parallax, rigid fit, bundle refinement), then, when the calibration's
   planes were fitted to the stripes, the tilt refinement by the stripes on the rebuilt
   stripes of step 3, and levels its frame across the scan as the calibration does
   (:func:`~impress_gui.core.calibration.solve.level_across`: each trial in its own levelled
   frame, its planes fitted there) (:func:`_trial`);
3. each laser's stripe on the target is rebuilt from the recorded plane: in each recorded frame
   the line where the plane cuts each top face, seen as camera rays. A trial intersects those
   rays with the target faces of its own pose (and its own travel), adds stripe noise and fits
   the plane again. How (``stripe_model``, :data:`STRIPE_MODELS`): "conservative" adds half
   of the plane's recorded residual variance as one offset per frame and face (neighbouring
   stripe points are not independent) and half per point; "measured", the default, does
   what the calibration did and draws what it measured - the stripe on the ground beside the
   target rebuilt too and fitted with the faces', the recorded ``segment_sd_mm``,
   ``point_sd_mm`` and ``face_sd_mm`` (:func:`~impress_gui.core.calibration.planes.
   stripe_noise`) drawn, each point moved within its face. Checked against real
   recalibrations (``benchmarks/bench_calibration_mc.py``, docs/uncertainty.md; 18
   calibrations of random rigs, their whole errors against the truth): "conservative" RMS
   error / SD 0.96 for heights, 1.04 for lengths; "measured" 1.34 and 1.12 - it draws the
   recalibrations' spread right but not the calibration's own bias with exact picks, which
   "conservative"'s larger offsets happened to cover. The budgets carry that bias in their
   own component (impress_gui.core.measure.uncertainty.METHOD_STRIPE_PX, the method's own
   error), so "measured" is the default since 2 December 2026;
4. a trial's parameters map any reconstructed cell to where that trial would have put it
   (:meth:`CalibrationEnsemble.map_points`: the same camera ray at the same time, through the
   trial's rotation, laser plane and reference plane). The spread of a reading over the trials
   is the calibration's standard uncertainty of that reading, correlations included (both ends
   of a ruler move together).

Trials are relative to a trial without noise (the same procedure, noise-free), so the procedure's
own small departures from the recorded calibration cancel. Results are cached per calibration
(its JSON text), target, sigma, count and seed: the same input gives the same numbers.

The click noise is estimated from the reprojection residuals (RMS x sqrt(24 / (24 - 9)): 24
coordinates, 9 pose parameters) with a floor of :data:`DEFAULT_CLICK_SIGMA_PX` (a person marking a
corner in a video frame is not more precise than that, and picks taken from a simulator are
exact).
"""

from __future__ import annotations

import hashlib
import json
import math
import threading
from dataclasses import dataclass

import numpy as np

from impress_gui.core.base.errors import CalibrationError, InputError
from impress_gui.core.calibration.picks import Picks
from impress_gui.core.calibration.planes import StripeObservations, points_on_ground, refine_tilt
from impress_gui.core.calibration.solve import (
    SPEED_WARN_FRACTION,
    level_across,
    picks_scatter_px,
    solve_pose,
)
from impress_gui.core.calibration.target import CORNER_NAMES, TargetModel


class UnstableCalibration(CalibrationError):
    """The calibration's Monte Carlo failed in most trials: re-solved with the clicks moved by
    their noise, the calibration is mostly refused by the solver (a short baseline, picks that
    barely fit the target). Its uncertainty cannot be evaluated, so no reading made with it
    can be given an expanded uncertainty."""


#: the smallest click noise assumed (px): a stated default, used when the residuals say less
DEFAULT_CLICK_SIGMA_PX = 0.3
#: trials of the Monte Carlo (the SD of a reading is then known to about 7 % of itself)
DEFAULT_TRIALS = 60
DEFAULT_SEED = 22
LASERS = ("green", "red")
#: points per stripe segment (one frame, one face) of the rebuilt stripes
SEGMENT_POINTS = 24
#: and at most (a calibration's segments hold 50-100 points at 640x360, more at 1080p)
MAX_SEGMENT_POINTS = 160
#: positions tried along a ground line across the ring around the target
LINE_SAMPLES = 2000
#: how a trial rebuilds the stripes and draws their noise. "conservative" (the default): the
#: stripes on the target's faces only, half of each plane's residual variance as one offset
#: per frame and face and half per point (along the plane's normal): about right against a
#: calibration's whole error (benchmarks/bench_calibration_mc.py), over-stated against the
#: spread of recalibrations of one video. "measured": as the calibration works and measured
#: its stripes (the ground beside the target rebuilt and fitted with, the recorded
#: segment_sd_mm / point_sd_mm / face_sd_mm drawn, points moved within their face): the
#: spread right, the calibration's own bias not (heights' coverage 87 % in bench_uncertainty)
STRIPE_MODELS = ("conservative", "measured")
DEFAULT_STRIPE_MODEL = "measured"


@dataclass(frozen=True)
class CalParams:
    """The parameters that map a pixel ray to a heightmap cell, for ``S`` parameter sets:
    ``rotation (S, 3, 3)`` camera -> ideal, per laser ``normals (S, 3)`` and ``offsets (S,)``
    (plane ``n . X = d`` in the camera-fixed ideal frame), ``ref (S, 3)`` the reference depth
    ``c0 + cx x + cy y`` and ``speed_scale (S,)`` (the true travel over the entered one)."""

    rotation: np.ndarray
    normals: dict
    offsets: dict
    ref: np.ndarray
    speed_scale: np.ndarray

    @property
    def size(self) -> int:
        return len(self.rotation)

    @classmethod
    def of_calibration(cls, cal) -> CalParams:
        """The one parameter set of a :class:`~impress_gui.core.calibration.scene.SceneCalibration`."""
        return cls(np.asarray(cal.rotation, float)[None],
                   {n: np.asarray(cal.planes[n].plane.normal, float)[None] for n in LASERS},
                   {n: np.array([float(cal.planes[n].plane.offset_mm)]) for n in LASERS},
                   reference_coeffs(cal.target_rotation, cal.target_translation_mm)[None],
                   np.ones(1))

    def take(self, idx) -> CalParams:
        return CalParams(self.rotation[idx], {n: v[idx] for n, v in self.normals.items()},
                         {n: v[idx] for n, v in self.offsets.items()}, self.ref[idx],
                         self.speed_scale[idx])


def reference_coeffs(target_rotation: np.ndarray, target_translation: np.ndarray) -> np.ndarray:
    """``(c0, cx, cy)`` of the target base plane's depth ``c0 + cx x + cy y`` (as
    :meth:`SceneCalibration.reference_depth`)."""
    n = -np.asarray(target_rotation, float) @ np.array([0.0, 0.0, 1.0])
    p0 = np.asarray(target_translation, float)
    return np.array([p0[2] + (n[0] * p0[0] + n[1] * p0[1]) / n[2], -n[0] / n[2], -n[1] / n[2]])


def map_points(src: CalParams, dst: CalParams, x, y, h, laser) -> tuple:
    """Where the parameter sets ``dst`` put the cells ``(x, y, h)`` (arrays ``(N,)``) that the
    single set ``src`` reconstructed from laser ``laser`` (a name, or ``(N,)`` names): the same
    camera ray at the same time, through each set's rotation, laser plane and reference.
    Returns ``(x', y', h')`` each ``(S, N)``."""
    x, y, h = (np.atleast_1d(np.asarray(v, float)) for v in (x, y, h))
    lasers = np.broadcast_to(np.asarray(laser), x.shape)
    out = [np.full((dst.size, len(x)), np.nan) for _ in range(3)]
    r0 = src.rotation[0]
    for name in LASERS:
        sel = lasers == name
        if not sel.any():
            continue
        xs, ys, hs = x[sel], y[sel], h[sel]
        n0, d0 = src.normals[name][0], src.offsets[name][0]
        z = src.ref[0, 0] + src.ref[0, 1] * xs + src.ref[0, 2] * ys - hs
        travel = (n0[0] * xs + n0[1] * ys + n0[2] * z - d0) / n0[1]
        q_ideal = np.column_stack([xs, ys - travel, z])
        cam = q_ideal @ r0  # rows: R^T q (camera-frame ray directions)
        q = np.einsum("sij,nj->sni", dst.rotation, cam)
        den = np.einsum("sni,si->sn", q, dst.normals[name])
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = dst.offsets[name][:, None] / den
        px = lam * q[..., 0]
        py = lam * q[..., 1] + travel[None] * dst.speed_scale[:, None]
        pz = lam * q[..., 2]
        ph = dst.ref[:, :1] + dst.ref[:, 1:2] * px + dst.ref[:, 2:3] * py - pz
        for o, v in zip(out, (px, py, ph)):
            o[:, sel] = v
    return tuple(out)


@dataclass(frozen=True)
class CalibrationEnsemble:
    """The Monte Carlo trials of one calibration (see the module's description).

    ``nominal`` is the calibration itself, ``base`` the noise-free trial, ``trials`` the noisy
    ones; ``summary`` holds the spread of the solved quantities (roll, tilt, implied speed,
    each plane's angle and offset) for the budget's description."""

    nominal: CalParams
    base: CalParams
    trials: CalParams
    click_sigma_px: float
    sigma_source: str
    seed: int
    summary: dict

    @property
    def n_trials(self) -> int:
        return self.trials.size

    def deltas(self, x, y, h, laser) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(dx, dy, dh)`` each ``(S, N)``: how far each trial moves the cells ``(x, y, h)``
        of the calibration's own reconstruction, relative to the noise-free trial."""
        bx, by, bh = map_points(self.nominal, self.base, x, y, h, laser)
        tx, ty, th = map_points(self.nominal, self.trials, x, y, h, laser)
        return tx - bx, ty - by, th - bh


def click_sigma(cal) -> tuple[float, str]:
    """The click noise (px) assumed for a calibration and where it comes from."""
    rms = float(cal.reprojection_rms_px)
    est = picks_scatter_px(rms) if math.isfinite(rms) else 0.0
    if est > DEFAULT_CLICK_SIGMA_PX:
        return est, (f"from the picks' reprojection RMS {rms:.3f} px x sqrt(24/15) "
                     "(24 coordinates, 9 pose parameters)")
    return DEFAULT_CLICK_SIGMA_PX, (f"the stated default {DEFAULT_CLICK_SIGMA_PX} px (the picks' "
                                    f"reprojection RMS {rms:.3f} px implies less)")


def _pose_travel(cal) -> float:
    """The travel (mm) between t1 and t2 the target's pose was fitted with."""
    dt = (cal.t2 - cal.t1) / cal.fps
    ok = abs(cal.implied_speed_mm_s - cal.speed_mm_s) <= SPEED_WARN_FRACTION * cal.speed_mm_s
    return (cal.speed_mm_s if ok else cal.implied_speed_mm_s) * dt


def model_picks(cal, target: TargetModel) -> Picks:
    """The fitted target corners projected into frames t1 and t2: picks without click noise."""
    corners = cal.corners_fit_mm(target)
    uv1 = cal.project_rail(corners, 0.0)
    uv2 = cal.project_rail(corners, _pose_travel(cal))
    return Picks("", cal.t1, cal.t2,
                 {c: (float(p[0]), float(p[1])) for c, p in zip(CORNER_NAMES, uv1)},
                 {c: (float(p[0]), float(p[1])) for c, p in zip(CORNER_NAMES, uv2)})


def check_target(cal, target: TargetModel, tol_mm: float = 1.0) -> None:
    """InputError unless ``target`` is the model the calibration was fitted with: the model's
    corners fitted rigidly to the corners the calibration triangulated by parallax must leave
    residuals no larger than the calibration's own (recorded with its model) plus ``tol_mm``.
    A check of the model's shape, not of the pose: the parallax corners move by millimetres
    with the clicks' noise on a short baseline (0.5 px clicks: 4-6 mm on random rigs 3 and 19)
    while the fitted pose does not follow them, so comparing the two refused good
    calibrations; the rigid fit's residuals are the same for any pose."""
    from impress_gui.core.calibration.solve import umeyama

    par = np.asarray(cal.corners_parallax_mm, float)
    model = target.corner_array()
    if par.shape != model.shape or not np.all(np.isfinite(par)):
        raise InputError(f"the target model '{target.name}' does not match the calibration")
    _, r, t = umeyama(model, par, with_scale=False)
    res = np.linalg.norm(par - (model @ r.T + t), axis=1)
    own = float(np.nanmax(cal.corner_residuals_mm))
    if not np.all(np.isfinite(res)) or float(np.max(res)) > own + tol_mm:
        raise InputError(f"the target model '{target.name}' does not match the calibration "
                         f"(its corners fit the calibration's up to {float(np.max(res)):.1f} mm "
                         f"off, the calibration's own model {own:.1f} mm)")


def segment_points(fit) -> int:
    """Points per rebuilt stripe segment (one frame, one face): as many as the calibration's
    fit had on average (its points on the faces over its frames and faces), so that the
    trials' point noise weighs in the plane as the real points' did and the faces weigh
    against the ground as they did; :data:`SEGMENT_POINTS` when the fit does not say."""
    faces = max(1, len(fit.heights_mm))
    on_faces = int(fit.n_points) - int(fit.ground_points)
    if not fit.frames or on_faces <= 0:
        return SEGMENT_POINTS
    return int(np.clip(round(on_faces / (len(fit.frames) * faces)), 8, MAX_SEGMENT_POINTS))


def _segments(cal, target: TargetModel, laser: str, n_seg: int | None = SEGMENT_POINTS):
    """The rebuilt stripe of ``laser``: per (frame, face) ``(frame, time since t1 (s), points
    in the ideal frame of that frame's camera (M, 3))`` on the recorded plane."""
    fit = cal.planes[laser]
    frames = list(fit.frames) or [cal.t1 if laser == "green" else cal.t2]
    n, d = fit.plane.normal, fit.plane.offset_mm
    r_o, t_o = cal.target_rotation, cal.target_translation_mm
    v_pose = cal.implied_speed_mm_s
    n_seg = segment_points(fit) if n_seg is None else int(n_seg)
    out = []
    for fi, face in enumerate(target.top_faces()):
        poly = face.vertices_mm @ r_o.T + t_o  # rail frame
        for k in frames:
            dt = (k - cal.t1) / cal.fps
            shift = np.array([0.0, v_pose * dt, 0.0])
            s = (poly - shift) @ n - d  # signed distances of the vertices to the laser plane
            pts = []
            for i in range(len(poly)):
                a, b = poly[i], poly[(i + 1) % len(poly)]
                sa, sb = s[i], s[(i + 1) % len(poly)]
                if (sa < 0) != (sb < 0):
                    pts.append(a + sa / (sa - sb) * (b - a))
            if len(pts) < 2:
                continue
            p, q = pts[0], pts[1]
            length = float(np.linalg.norm(q - p))
            if length < 6.0:
                continue
            t = np.linspace(1.5 / length, 1 - 1.5 / length, n_seg)  # inside the inset
            out.append((int(k), dt, p[None] + t[:, None] * (q - p)[None] - shift, fi))
    return out


def _ground_segments(cal, target: TargetModel, laser: str):
    """The rebuilt stripe of ``laser`` on the ground beside the target, for a plane whose fit
    used it (``ground_points`` > 0; none otherwise): per recorded frame ``(frame, time since
    t1 (s), points (M, 3))`` on the line where the recorded plane meets the target's base
    plane, inside the ring around the target and outside its footprint (grown by the margin
    the calibration leaves), about as many points per frame as the calibration used. Which
    of them a trial keeps (its own pose, the target hiding some) is decided by the same test
    as the calibration's (:func:`~impress_gui.core.calibration.planes.points_on_ground`)."""
    fit = cal.planes[laser]
    frames = list(fit.frames)
    if fit.ground_points <= 0 or not frames:
        return []
    per_frame = max(8, int(math.ceil(fit.ground_points / len(frames))))
    out = _ground_lines(cal, target, fit, frames, per_frame)
    # the target hides some of them from the camera (the trials test that as the calibration
    # does): as many visible at the calibration's own pose as its fit had
    seen = sum(len(points_on_ground(p, (cal.target_rotation, cal.target_translation_mm),
                                    target, cal.implied_speed_mm_s * dt)) for _, dt, p in out)
    total = sum(len(p) for _, _, p in out)
    if 0 < seen < total:
        out = _ground_lines(cal, target, fit, frames,
                            int(math.ceil(per_frame * total / seen)))
    return out


def _ground_lines(cal, target: TargetModel, fit, frames, per_frame: int):
    """The ground lines of :func:`_ground_segments`, ``per_frame`` points in each frame."""
    from impress_gui.core.calibration.planes import GROUND_MARGIN_MM, _ground_ring
    from impress_gui.core.calibration.target import _inside_convex

    n, d = fit.plane.normal, fit.plane.offset_mm
    r_o, t_o = cal.target_rotation, cal.target_translation_mm
    feet, lo, hi = _ground_ring(target)
    a_u, a_v = float(n @ r_o[:, 0]), float(n @ r_o[:, 1])
    out = []
    for k in frames:
        dt = (k - cal.t1) / cal.fps
        shift = np.array([0.0, cal.implied_speed_mm_s * dt, 0.0])
        c = float(n @ (t_o - shift)) - d  # plane: c + a_u u + a_v v = 0 (object u, v)
        # the line, sampled finely across the ring's rectangle along its longer extent
        if abs(a_v) >= abs(a_u):
            u = np.linspace(lo[0], hi[0], LINE_SAMPLES)
            v = -(c + a_u * u) / a_v
        else:
            v = np.linspace(lo[1], hi[1], LINE_SAMPLES)
            u = -(c + a_v * v) / a_u
        keep = (u > lo[0]) & (u < hi[0]) & (v > lo[1]) & (v < hi[1])
        for f in feet:
            grown = f + GROUND_MARGIN_MM * np.sign(f - f.mean(0))
            keep &= ~_inside_convex(grown, u, v)
        if keep.sum() < 2:
            continue
        idx = np.flatnonzero(keep)
        idx = idx[np.linspace(0, len(idx) - 1, min(per_frame, len(idx))).round().astype(int)]
        pts = t_o + u[idx, None] * r_o[:, 0] + v[idx, None] * r_o[:, 1]  # rail frame
        out.append((int(k), dt, pts - shift))
    return out


def stripe_sigmas(fit, rms_mm: float) -> tuple[float, float, float]:
    """The stripe noise a trial draws for a plane: ``(per frame and face, per point, per
    face)`` SDs in mm. The calibration's measured split (``segment_sd_mm``, ``point_sd_mm``,
    ``face_sd_mm``: :func:`~impress_gui.core.calibration.planes.stripe_noise`) where it
    recorded one; for an older calibration half of the plane's residual variance for each of
    the first two (``rms_mm`` / sqrt 2; it over-states the offsets that tilt the motion
    direction: real recalibrations of random rigs, 2-4 times the measured segment SD) and no
    face offset."""
    half = rms_mm / math.sqrt(2)
    seg, pt, face = float(fit.segment_sd_mm), float(fit.point_sd_mm), float(fit.face_sd_mm)
    return ((seg if math.isfinite(seg) else half), (pt if math.isfinite(pt) else half),
            (face if math.isfinite(face) else 0.0))


def _observations(cal, target, segs, rng, laser_rms: dict | None,
                  ground: dict | None = None, model: str = DEFAULT_STRIPE_MODEL
                  ) -> StripeObservations:
    """Stripe observations (camera rays) of the rebuilt stripes (``segs`` on the faces,
    ``ground`` beside the target), with stripe noise when ``laser_rms`` (each plane's
    recorded RMS) is given: :func:`stripe_sigmas`, one offset per frame and face (or ground
    line; neighbouring stripe points are not independent) and one per point. A point is
    moved within its face (the target's faces and its base plane share one normal) so that
    its distance from the laser plane changes by the drawn amount: the detector's error moves
    the ray along the surface it meets (moved along the laser plane's normal, the point's
    ray met the face again only about 80 % as far from the plane). ``model`` "conservative"
    (:data:`STRIPE_MODELS`): half of the plane's residual variance per frame and face and
    half per point, moved along the plane's normal, no face offsets."""
    m = np.asarray(cal.target_rotation, float)[:, 2]  # the faces' normal (rail frame)

    def rays_of(laser: str, segments: list) -> list:
        nrm = np.asarray(cal.planes[laser].plane.normal, float)
        c = float(nrm @ m)
        along = (nrm - c * m) / max(1.0 - c * c, 1e-6)  # in the face; along . nrm = 1
        s_seg, s_pt, s_face = stripe_sigmas(cal.planes[laser], laser_rms[laser]) \
            if laser_rms else (0.0, 0.0, 0.0)
        if model == "conservative":
            along = nrm
            s_seg = s_pt = laser_rms[laser] / math.sqrt(2) if laser_rms else 0.0
            s_face = 0.0
        face_offset: dict[int, float] = {}  # one per face and trial (the ground has none)
        by_frame: dict[int, list] = {}
        for seg in segments:
            k, dt, pts = seg[:3]
            if laser_rms:
                off = rng.normal(0.0, s_seg) + rng.normal(0.0, s_pt, (len(pts), 1))
                if len(seg) > 3 and s_face > 0:
                    if seg[3] not in face_offset:
                        face_offset[seg[3]] = float(rng.normal(0.0, s_face))
                    off = off + face_offset[seg[3]]
                pts = pts + along * off
            cam = pts @ cal.rotation  # rows R^T X: camera frame
            by_frame.setdefault(k, [dt, []])[1].append(cam / cam[:, 2:3])
        return [(k, dt, np.concatenate(c)) for k, (dt, c) in sorted(by_frame.items())]

    rays = {laser: rays_of(laser, segs[laser]) for laser in LASERS}
    on_ground = {laser: rays_of(laser, ground[laser]) for laser in LASERS
                 if ground and ground.get(laser)}
    return StripeObservations(target, cal.implied_speed_mm_s, {"green": cal.t1, "red": cal.t2},
                              rays, ground=on_ground)


def _trial(cal, target, picks: Picks, segs, rng, sigma_px: float, dt: float, refine: bool,
           ground: dict | None = None, model: str = DEFAULT_STRIPE_MODEL):
    """One trial: ``(rotation, {laser: (normal, offset)}, ref coeffs, roll, tilt, implied)``:
    the product's pose solver on noisy picks, its tilt refinement and plane fits on the
    rebuilt, noisy stripes."""
    if sigma_px > 0:
        noisy = {}
        for key in ("corners_t1", "corners_t2"):
            noisy[key] = {c: (float(v[0] + rng.normal(0.0, sigma_px)),
                              float(v[1] + rng.normal(0.0, sigma_px)))
                          for c, v in getattr(picks, key).items()}
        picks = Picks("", picks.t1, picks.t2, noisy["corners_t1"], noisy["corners_t2"])
    rms = {la: float(cal.planes[la].rms_mm) for la in LASERS} if sigma_px > 0 else None
    obs = _observations(cal, target, segs, rng, rms, ground, model)
    pose = solve_pose(cal.intrinsics, target, picks, cal.speed_mm_s, dt, mismatch_gate=False)
    if refine:
        fits = obs.fit_planes(pose.rotation, (pose.target_rotation, pose.target_translation_mm))
        pose = refine_tilt(obs, fits, cal.intrinsics, target, picks, pose, cal.speed_mm_s, dt,
                           max(sigma_px, 0.05))
    # each trial in its own levelled frame, as the calibration (scene.calibrate_scene)
    pose = level_across(pose)
    # the final planes as the calibration fits them: the faces' points and, where its fit
    # used them, the ground's beside the target (which pin the plane at height 0)
    fits = obs.fit_planes(pose.rotation, (pose.target_rotation, pose.target_translation_mm),
                          with_ground=bool(obs.ground))
    planes = {}
    for la in LASERS:
        pl = fits[la][0].plane.oriented_like(cal.planes[la].plane)
        planes[la] = (np.asarray(pl.normal, float), float(pl.offset_mm))
    return (pose.rotation, planes, reference_coeffs(pose.target_rotation,
                                                    pose.target_translation_mm),
            pose.roll_rad, pose.tilt_rad, pose.implied_speed_mm_s)


def _angle_sd_deg(a: np.ndarray, ref: float) -> float:
    d = (np.degrees(a - ref) + 180.0) % 360.0 - 180.0
    return float(np.sqrt(np.mean(d**2)))


_CACHE: dict = {}
_CACHE_LOCK = threading.Lock()


def calibration_key(cal, target: TargetModel, sigma_px: float, n: int, seed: int,
                    model: str = "conservative") -> str:
    h = hashlib.sha256(json.dumps(cal.to_json() | {"software": "", "inputs": {}},
                                  sort_keys=True, default=str).encode())
    h.update(json.dumps({n: (f.vertices_mm.tolist()) for n, f in
                         zip(range(99), target.faces)}, sort_keys=True).encode())
    h.update(json.dumps(target.corner_array().tolist()).encode())
    h.update(f"{sigma_px:.6f}/{n}/{seed}".encode())
    if model != "conservative":
        h.update(model.encode())
    return h.hexdigest()


def calibration_ensemble(cal, target: TargetModel, click_sigma_px: float | None = None,
                         n: int = DEFAULT_TRIALS, seed: int = DEFAULT_SEED,
                         cancel=None, stripe_model: str = DEFAULT_STRIPE_MODEL
                         ) -> CalibrationEnsemble:
    """The Monte Carlo trials of ``cal`` (fitted with ``target``); ``click_sigma_px`` None:
    :func:`click_sigma`. Deterministic (``seed``) and cached. ``cancel``: a
    :class:`~impress_gui.core.base.progress.CancelToken` checked before each trial.
    ``stripe_model``: how the stripes are rebuilt and made noisy (:data:`STRIPE_MODELS`)."""
    if stripe_model not in STRIPE_MODELS:
        raise ValueError(f"stripe_model must be one of {STRIPE_MODELS}")
    if click_sigma_px is None:
        sigma, source = click_sigma(cal)
    else:
        sigma, source = float(click_sigma_px), "given"
    key = calibration_key(cal, target, sigma, n, seed, stripe_model)
    with _CACHE_LOCK:
        hit = _CACHE.get(key)
    if isinstance(hit, UnstableCalibration):  # a failed Monte Carlo is not run again
        raise UnstableCalibration(str(hit))
    if hit is not None:
        return hit
    check_target(cal, target)
    picks = model_picks(cal, target)
    measured = stripe_model == "measured"
    segs = {laser: _segments(cal, target, laser, None if measured else SEGMENT_POINTS)
            for laser in LASERS}
    ground = {laser: _ground_segments(cal, target, laser) for laser in LASERS} if measured \
        else {}
    dt = (cal.t2 - cal.t1) / cal.fps
    rng = np.random.default_rng(seed)
    refine = all(f.method == "stripe-fit" for f in cal.planes.values())
    results = [_trial(cal, target, picks, segs, rng, 0.0, dt, refine, ground, stripe_model)]
    for _ in range(n):
        if cancel is not None:
            cancel.check()
        try:
            results.append(_trial(cal, target, picks, segs, rng, sigma, dt, refine, ground,
                                  stripe_model))
        except CalibrationError:  # a trial the solver refuses is left out (counted)
            continue

    def params(rs) -> CalParams:
        return CalParams(np.array([r[0] for r in rs]),
                         {la: np.array([r[1][la][0] for r in rs]) for la in LASERS},
                         {la: np.array([r[1][la][1] for r in rs]) for la in LASERS},
                         np.array([r[2] for r in rs]), np.ones(len(rs)))

    base, trials = params(results[:1]), params(results[1:])
    if trials.size < max(2, n // 2):
        failed = UnstableCalibration(
            f"the calibration's Monte Carlo failed in most trials ({n - trials.size} of {n} "
            "re-solved calibrations refused by the solver under the click noise)")
        with _CACHE_LOCK:
            _CACHE[key] = failed
        raise failed
    arr = np.array([[r[3], r[4], r[5]] for r in results[1:]])
    summary = {"trials": trials.size, "refused": n - trials.size,
               "roll_sd_deg": _angle_sd_deg(arr[:, 0], results[0][3]),
               "tilt_sd_deg": _angle_sd_deg(arr[:, 1], results[0][4]),
               "implied_speed_sd_mm_s": float(arr[:, 2].std(ddof=1))}
    for la in LASERS:
        nn = trials.normals[la]
        ang = np.degrees(np.arccos(np.clip(nn @ base.normals[la][0], -1, 1)))
        summary[f"{la}_plane_angle_sd_deg"] = float(np.sqrt(np.mean(ang**2)))
        summary[f"{la}_plane_offset_sd_mm"] = float(trials.offsets[la].std(ddof=1))
        summary[f"{la}_plane_rms_mm"] = float(cal.planes[la].rms_mm)
    ens = CalibrationEnsemble(CalParams.of_calibration(cal), base, trials, sigma, source, seed,
                              summary)
    with _CACHE_LOCK:
        _CACHE[key] = ens
    return ens
