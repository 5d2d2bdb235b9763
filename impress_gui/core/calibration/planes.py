"""The laser planes of the scene calibration: each plane is fitted to every stripe pixel that
falls on a known face of the L target, in several frames around its calibration frame, and the
tilt (poorly fixed by the corner picks) is refined so the stripe points lie on their planes."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from impress_gui.core.base import codes
from impress_gui.core.base.errors import CalibrationError
from impress_gui.core.base.progress import CancelToken, ProgressCallback, report
from impress_gui.core.calibration.geometry import (
    Intrinsics,
    Plane,
    fit_plane,
    ideal_rotation,
    rail_shift,
)
from impress_gui.core.calibration.picks import Picks
from impress_gui.core.calibration.solve import (
    SPEED_WARN_FRACTION,
    PoseSolution,
    parallax_corners,
    project_points,
    refine_bundle,
    umeyama,
)
from impress_gui.core.calibration.target import TargetModel, _inside_convex

# the calibration detects a laser's stripe with the blooming fallback (detect_band_blooming)
# when the strict colour tests give less than this share of the stripe points on the target's
# faces that the fallback gives (random rigs 0-7 at 640x360: 0 where the strict tests fail,
# 0.49-1.0 where they calibrate; the presets 0.86-0.98)
BLOOM_SWITCH = 0.25
#: how a laser's stripe rows on the target are estimated (see observe_stripes)
ROWS_CENTRE = "centre of mass in a window"  # the detector's default (stripes.window_refine)
ROWS_MIDPOINT = "midpoint of the half-maximum crossings"
ROWS_BLOOMING = "blooming fallback (centre of mass)"
ROWS_GAUSS = "Gaussian fitted to the profile"
#: the ground beside the target (its base plane) whose stripe points join each plane's fit:
#: a ring this wide (mm) around the target's footprint, leaving out this margin (mm) along it
GROUND_RING_MM = 30.0
GROUND_MARGIN_MM = 3.0


def calibration_stripe_params(**kw):
    """The stripe detector's settings the calibration uses (``StripeParams``; ``kw`` as
    there): the reconstruction's, the faint rule (``StripeParams.faint``) included, so a dim or
    pinkish stripe on the light target is found as it is on the ground. (Before the rule
    refused light whose other laser's channel is clipped, kernels.FAINT_CLIP, it took the red
    stripe's clipped core on random rig 22's target for green light, and the calibration ran
    without it.) The calibration tab's stripe overlay shows what these find."""
    from impress_gui.core.reconstruction.stripes import StripeParams

    return StripeParams(**kw)
#: a ground point joins the fit when it lies within max(GROUND_GATE_RMS x the faces' fit
#: RMS, GROUND_GATE_MM) of the plane fitted to the faces alone ...
GROUND_GATE_RMS = 6.0
GROUND_GATE_MM = 0.1
#: ... and the ground is used at all when at least this many points and this share of the
#: ground's points pass (a flat base plane); otherwise the faces alone give the plane
GROUND_MIN_POINTS = 200
GROUND_MIN_SHARE = 0.5


@dataclass(frozen=True)
class LaserPlaneFit:
    name: str
    plane: Plane  # camera-fixed ideal frame, mm
    rms_mm: float
    n_points: int
    frames: tuple[int, ...]
    heights_mm: tuple[float, ...]  # target-face heights the stripe was measured on
    method: str = "stripe-fit"
    stripe_rows: str = ""  # how the stripe's rows were estimated (ROWS_*; "" = not recorded)
    #: stripe points on the ground beside the target (its base plane, height 0) in the fit;
    #: ``ground_note`` says why none were used ("" = not recorded)
    ground_points: int = 0
    ground_note: str = ""
    #: the stripe's noise about the plane on the faces, split as the calibration's Monte
    #: Carlo needs it (:func:`stripe_noise`): the SD of the stripe's offset per frame and face
    #: (each face's median offset over the frames removed) and of single points about their
    #: frame and face's offset (robust); NaN = not recorded (older calibrations, too few frames)
    segment_sd_mm: float = float("nan")
    point_sd_mm: float = float("nan")
    #: the RMS over the faces of each face's median offset from the plane (a bias of the
    #: stripe on that face, the same in every frame: it turns the plane); NaN = not recorded
    face_sd_mm: float = float("nan")


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


def _stripe_uv_in_region(rgb: np.ndarray, laser: str, uv: np.ndarray, params=None,
                         blooming: bool = False, midpoints: bool = False):
    """Sub-pixel stripe positions ``(N, 2)`` of one laser in the image region spanned by the
    projected points ``uv`` (``(M, 2)``; the rows widened by 8 px each way), as
    :func:`stripe_uv_on_target` returns them."""
    from impress_gui.core.reconstruction.stripes import (
        Planes,
        detect_band,
        detect_band_blooming,
        gauss_rows,
        half_max_midpoints,
    )

    h, w = rgb.shape[:2]
    r0 = int(max(0, np.floor(uv[:, 1].min()) - 8))
    r1 = int(min(h, np.ceil(uv[:, 1].max()) + 8))
    c0 = int(max(0, np.floor(uv[:, 0].min())))
    c1 = int(min(w, np.ceil(uv[:, 0].max()) + 1))
    if r1 - r0 < 10 or c1 - c0 < 10:
        return (np.zeros((0, 2)),) * 3 if midpoints else np.zeros((0, 2))
    params = params or calibration_stripe_params()
    band = rgb[r0:r1, c0:c1]
    if blooming:
        res = detect_band_blooming(laser, band, r0, params)
    else:
        res = detect_band(laser, band, r0, params, None)
    cols = np.flatnonzero(res.found)
    out = np.column_stack([cols + c0, res.rows[cols]])
    if not midpoints:
        return out
    luma = Planes.from_rgb(band).y
    mid = half_max_midpoints(luma, res.rows - r0, params.half_window_px) + r0
    fit = gauss_rows(luma, mid - r0, params.half_window_px) + r0  # the midpoint where it fails
    return out, np.column_stack([cols + c0, mid[cols]]), np.column_stack([cols + c0, fit[cols]])


def stripe_uv_on_target(rgb: np.ndarray, laser: str, intr: Intrinsics, rot: np.ndarray,
                        pose, target: TargetModel, travel_mm: float, params=None,
                        blooming: bool = False, midpoints: bool = False):
    """Sub-pixel stripe positions ``(N, 2)`` of one laser inside the target's image region
    (``blooming``: with the fallback for a saturated stripe, ``detect_band_blooming``).
    ``midpoints``: return ``(centre-of-mass positions, half-maximum midpoint positions)``, the
    same columns re-estimated by :func:`~impress_gui.core.reconstruction.stripes.half_max_midpoints`."""
    faces = _face_polygons(pose, target)
    all_uv = np.concatenate([project_points(intr, rot, f[2], travel_mm) for f in faces])
    return _stripe_uv_in_region(rgb, laser, all_uv, params, blooming, midpoints)


def _ground_ring(target: TargetModel):
    """The target's footprint polygons (object frame, xy) and the ring's outer rectangle."""
    feet = [f.vertices_mm[:, :2] for f in target.top_faces()]
    allv = np.concatenate(feet)
    return feet, allv.min(0) - GROUND_RING_MM, allv.max(0) + GROUND_RING_MM


def stripe_uv_on_ground(rgb: np.ndarray, laser: str, intr: Intrinsics, rot: np.ndarray,
                        pose, target: TargetModel, travel_mm: float, params=None,
                        blooming: bool = False, midpoints: bool = False):
    """Like :func:`stripe_uv_on_target`, over the image region of the ground ring around the
    target (:data:`GROUND_RING_MM`); which of the positions lie on the ground is decided by
    :func:`points_on_ground`."""
    r_o, t_o = pose
    _, lo, hi = _ground_ring(target)
    rect = np.array([[lo[0], lo[1], 0.0], [hi[0], lo[1], 0.0], [hi[0], hi[1], 0.0],
                     [lo[0], hi[1], 0.0]])
    uv = project_points(intr, rot, rect @ r_o.T + t_o, travel_mm)
    if not np.isfinite(uv).all():
        empty = np.zeros((0, 2))
        return (empty,) * 3 if midpoints else empty
    return _stripe_uv_in_region(rgb, laser, uv, params, blooming, midpoints)


def row_times_s(dt_s: float, uv: np.ndarray, intr: Intrinsics):
    """The times (s since frame t1) at which the image points ``uv`` were exposed: the
    frame's ``dt_s`` for a global shutter, plus each point's row times the line time for a
    rolling shutter (one per point then)."""
    if intr.line_time_s <= 0:
        return dt_s
    return dt_s + np.asarray(uv, float)[:, 1] * intr.line_time_s


def points_on_ground(rays: np.ndarray, pose, target: TargetModel, travel_mm
                     ) -> np.ndarray:
    """Intersect ideal-frame rays with the target's base plane (height 0) and keep the hits
    in the ring around the target: outside its footprint by :data:`GROUND_MARGIN_MM`, within
    :data:`GROUND_RING_MM`, and not hidden from the camera by the target. 3D points in the
    camera-fixed ideal frame ``(N, 3)``."""
    r_o, t_o = pose
    feet, lo, hi = _ground_ring(target)
    shift = rail_shift(travel_mm)
    n = r_o[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((t_o - shift) @ n) / (rays @ n)
    hit = rays * t[:, None]
    q = (hit + shift - t_o) @ r_o  # object frame
    keep = ((t > 0) & (q[:, 0] > lo[0]) & (q[:, 0] < hi[0]) & (q[:, 1] > lo[1])
            & (q[:, 1] < hi[1]))
    for v in feet:
        grown = v + GROUND_MARGIN_MM * np.sign(v - v.mean(0))
        keep &= ~_inside_convex(grown, q[:, 0], q[:, 1])
    # hidden: the line of sight from the ground point up to the camera passes through the
    # target (sampled at 40 heights up to its top)
    cam = (shift - t_o) @ r_o
    top = max(float(f.vertices_mm[0, 2]) for f in target.top_faces())
    idx = np.flatnonzero(keep)
    qq = q[idx]
    if cam.ndim == 2:  # a rolling shutter: each point's own camera position
        cam = cam[idx]
    rise = np.maximum(cam[..., 2] - qq[:, 2], 1e-9)
    # all 40 heights in one call (40 calls of a few hundred points each took a fifth of the
    # calibration's Monte Carlo); the same values element by element
    zs = np.linspace(0.0, top, 41)[1:]
    pp = qq + (cam - qq) * (zs[:, None] / rise)[..., None]  # (40, N, 3)
    hf = target.heightfield(pp[..., 0], pp[..., 1], grow_mm=GROUND_MARGIN_MM)
    hidden = np.any(np.isfinite(hf) & (hf >= pp[..., 2]), axis=0)
    keep[idx[hidden]] = False
    return hit[keep]


def _cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross`` of two 3-vectors, the same products and differences without its
    overhead (the same values bit for bit)."""
    a0, a1, a2 = a.tolist()
    b0, b1, b2 = b.tolist()
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def points_on_faces(rays: np.ndarray, pose, target: TargetModel, travel_mm):
    """Intersect ideal-frame rays with the target's top faces (seen from a frame whose camera
    travelled ``travel_mm``): 3D points in the camera-fixed ideal frame and face heights, for
    the rays that hit a face (inside it by 1 mm).

    A ray is attributed to the face it meets first (whole faces, not the 1 mm insets), and kept
    only when it is inside that face's inset: a ray through the high face's edge margin goes on
    to the low face's plane behind the step, inside the low face's inset where the step is seen
    obliquely (occluded strip step * |x| / depth > 1 mm; random rig 4: 1.9 mm), and would be
    taken as a low-face point 8-9 mm off the laser plane."""
    best_t = np.full(len(rays), np.inf)
    best_h = np.full(len(rays), np.nan)
    best_in = np.zeros(len(rays), bool)
    for height, poly_in, poly in _face_polygons(pose, target):
        n = _cross3(poly[1] - poly[0], poly[2] - poly[0])
        n /= np.linalg.norm(n)
        p0 = poly[0] - rail_shift(travel_mm)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (p0 @ n) / (rays @ n)
        hit = rays * t[:, None] + rail_shift(travel_mm)  # rail frame
        e1 = poly[1] - poly[0]
        e1 /= np.linalg.norm(e1)
        e2 = _cross3(n, e1)
        hq = hit - poly[0]
        u, v = hq @ e1, hq @ e2

        def inside(pp, poly=poly, e1=e1, e2=e2, u=u, v=v, t=t):
            q = pp - poly[0]
            return _inside_convex(np.column_stack([q @ e1, q @ e2]), u, v) & (t > 0)

        better = inside(poly) & (t < best_t)
        best_t[better] = t[better]
        best_h[better] = height
        best_in[better] = inside(poly_in)[better]
    ok = np.isfinite(best_t) & best_in
    return rays[ok] * best_t[ok, None], best_h[ok], ok


#: a frame's own plane starts the robust fit when the plain fit through every point leaves
#: the points' median distance this many times that frame's plane's (light that is not the
#: laser's on a face - the other laser's blooming stripe, say - turned the plain fit)
FRAME_START_GAIN = 2.0
#: a frame's points must spread this far (RMS, mm) in their second direction to define a plane
FRAME_START_SPREAD_MM = 1.0
#: the most points the frames' planes are judged on (the other frames' median distance)
MEDIAN_POINTS = 2000


def _rank_in_group(group: np.ndarray) -> np.ndarray:
    """Each row's place (0, 1, ...) among the rows of its group, in row order."""
    order = np.argsort(group, kind="stable")
    g = group[order]
    rank = np.empty(len(group), int)
    rank[order] = np.arange(len(g)) - np.searchsorted(g, g, side="left")
    return rank


def _median_excluding(dist: np.ndarray, others: np.ndarray, group: np.ndarray) -> np.ndarray:
    """Per column of ``dist`` (N, C): the median of the rows ``others`` (N, C) marks, where each
    column leaves out the rows of one ``group`` (N,). The rows left out are set to -inf and
    +inf in turn within their group, which leaves the median where it is (to half a rank when
    their number is odd): one partition of the whole array, where masked medians per column
    took most of the calibration's Monte Carlo."""
    fill = np.where(_rank_in_group(group) % 2 == 0, -np.inf, np.inf)[:, None]
    return np.median(np.where(others, dist, fill), axis=0)


def _median_by_level(dist: np.ndarray, others: np.ndarray, group: np.ndarray,
                     levels: np.ndarray | None) -> np.ndarray:
    """Per column of ``dist`` (N, C): the median of the rows ``others`` (N, C) marks (each
    column leaves out the rows of one ``group``). With ``levels`` (each point's face height),
    the largest over the levels of each level's median, levels with fewer than 10 such points
    left out; where two or more levels have 10 points in all, a column judged on fewer than
    two of them is +inf (one face alone is what turned the plane)."""
    if levels is None:
        return _median_excluding(dist, others, group)
    out = np.full(dist.shape[1], -np.inf)
    judged = np.zeros(dist.shape[1], int)
    usable = 0
    for lv in np.unique(levels):
        m = levels == lv
        usable += int(m.sum() >= 10)
        enough = others[m].sum(0) >= 10
        if not enough.any():
            continue
        med = _median_excluding(dist[m][:, enough], others[m][:, enough], group[m])
        out[enough] = np.maximum(out[enough], med)
        judged += enough
    if usable >= 2:
        return np.where(judged >= 2, out, np.inf)
    if not np.isfinite(out).all():
        out = np.where(np.isfinite(out), out, _median_excluding(dist, others, group))
    return out


def _frame_start(points: np.ndarray, groups: np.ndarray, floor_mm: float,
                 levels: np.ndarray | None = None):
    """The points near the plane of the frame (``groups``: each point's frame, -1 for none)
    whose plane leaves the other frames' points the smallest median distance, when that
    median is well below the plain fit's over all points (:data:`FRAME_START_GAIN`); None
    otherwise. A frame's stripe on two
    faces of different heights lies on two lines of the laser's plane, which fix it.

    ``levels`` (each point's face height): the median is taken on each face apart and the
    largest counts. Over all points at once, the face with more than half of them decided
    alone: every plane through its line left a median near zero, and a frame whose points
    on the other face were another light's won (random rig 15 at 1080p with 45 frames: a
    red plane 64 deg off, fitted to three frames' wrong points and left with an RMS of
    0.002 mm)."""
    plane0, _, _ = fit_plane(points)
    d0 = np.abs(plane0.distance(points))[:, None]
    best_med = float(_median_by_level(d0, np.ones_like(d0, bool), np.zeros(len(d0), int),
                                      levels)[0])
    limit, best = best_med / FRAME_START_GAIN, None
    ids, inv, cnt = np.unique(groups, return_inverse=True, return_counts=True)
    # judged by the points it was not fitted to: as many as its own at least
    cand = (ids >= 0) & (cnt >= 10) & (len(points) - cnt >= cnt)
    if not cand.any():
        return None
    # every frame's own plane at once (the tilt refinement asks for this thousands of times):
    # the smallest principal axis of the frame's points' scatter, from sums over each
    # frame's points about the points' mean
    q = points - points.mean(0)
    nb = len(ids)
    centre_q = np.column_stack([np.bincount(inv, q[:, j], nb) for j in range(3)]) / cnt[:, None]
    second = np.empty((nb, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            second[:, a, b] = second[:, b, a] = np.bincount(inv, q[:, a] * q[:, b], nb)
    scatter = second - cnt[:, None, None] * centre_q[:, :, None] * centre_q[:, None, :]
    scatter, centre_q, cnt, frame = scatter[cand], centre_q[cand], cnt[cand], np.flatnonzero(cand)
    w, v = np.linalg.eigh(scatter)  # ascending eigenvalues: the normal is the first axis
    normal = v[:, :, 0]
    spread = np.sqrt(np.maximum(w[:, 1], 0.0))  # the second singular value of the points
    # the other frames' median distance, on at most MEDIAN_POINTS of the points (evenly
    # strided): it only chooses where the robust fit starts
    rows = np.arange(0, len(q), max(1, -(-len(q) // MEDIAN_POINTS)))
    dist = np.abs(q[rows] @ normal.T - np.einsum("ij,ij->i", centre_q, normal))  # (n, frames)
    others = inv[rows][:, None] != frame[None, :]
    meds = _median_by_level(dist, others, inv[rows], None if levels is None else levels[rows])
    for i in range(len(frame)):
        if spread[i] / math.sqrt(cnt[i]) < FRAME_START_SPREAD_MM:
            continue
        med = float(meds[i])
        if med < limit:
            limit, best = med, i
    if best is None:
        return None
    d_best = np.abs(q @ normal[best] - centre_q[best] @ normal[best])
    return d_best < max(4 * 1.4826 * limit, floor_mm)


def robust_plane(points: np.ndarray, rounds: int = 4, floor_mm: float = 0.02,
                 groups: np.ndarray | None = None, levels: np.ndarray | None = None
                 ) -> tuple[Plane, float, np.ndarray]:
    """SVD plane through ``points`` with outlier rejection (points farther than 4 robust SDs,
    at least ``floor_mm``, left out; refitted until the set holds): plane, RMS of the kept
    points and the kept mask. ``groups`` (each point's frame): where the plain fit is turned
    by gross outliers, the rejection starts from the best frame's own plane
    (:func:`_frame_start`; ``levels``, each point's face height, judges it face by face)."""
    keep = np.ones(len(points), bool)
    if groups is not None and len(points) >= 3:
        start = _frame_start(points, np.asarray(groups), floor_mm,
                             None if levels is None else np.asarray(levels, float))
        if start is not None and start.sum() >= 3:
            keep = start
    for _ in range(rounds):
        plane, rms, _ = fit_plane(points[keep])
        res = np.abs(plane.distance(points))
        mad = np.median(res[keep]) * 1.4826 + 1e-6
        new = res < max(4 * mad, floor_mm)
        if np.array_equal(new, keep):
            break
        keep = new
    plane, rms, _ = fit_plane(points[keep])
    return plane, rms, keep


def frame_groups(pts: list) -> np.ndarray:
    """Each point's frame index (0, 1, ...) for points given per frame."""
    return np.repeat(np.arange(len(pts)), [len(p) for p in pts])


def stripe_noise(plane: Plane, pts: list, hts: list) -> tuple[float, float, float]:
    """How the stripe points ``pts`` (per frame, with their faces' heights ``hts``) scatter
    about ``plane``: ``(segment SD, point SD, face SD)`` in mm. A segment is one frame's stripe on one
    face; its offset is the median distance of its points from the plane. The segment SD is
    the SD of those offsets after each face's median offset over the frames is taken out
    (a face's constant offset moves the plane; offsets that change from frame to frame tilt
    the motion direction the calibration refines, and are what a Monte Carlo of the tilt must
    draw), less what the point noise alone gives a median of the segment's points (pi/2 x
    point SD^2 / points, in variance; floored at 0); the point SD is 1.4826 x the median
    absolute deviation of the points from their segment's offset; the face SD the RMS over
    the faces of each face's median offset (a bias of the stripe on that face, the same in
    every frame, which turns the plane). Measured on the simulator's
    random rigs (2026-11-29, 640x360): segment SD 0.004-0.016 mm where the plane's RMS is
    0.024-0.047 mm. Segment SD NaN (not stated) with fewer than :data:`SEGMENT_DOF` degrees of
    freedom."""
    offs: dict[float, list[float]] = {}
    dev = []
    sizes = []
    for p, h in zip(pts, hts):
        r = plane.distance(p)
        for lv in np.unique(h):
            m = h == lv
            if m.sum() < 5:
                continue
            c = float(np.median(r[m]))
            offs.setdefault(round(float(lv), 3), []).append(c)
            dev.append(r[m] - c)
            sizes.append(int(m.sum()))
    point = float(1.4826 * np.median(np.abs(np.concatenate(dev)))) if dev else float("nan")
    resid = [np.asarray(v) - np.median(v) for v in offs.values() if len(v) >= 2]
    face = float(np.sqrt(np.mean([np.median(v) ** 2 for v in offs.values()]))) if offs \
        else float("nan")
    dof = sum(len(v) - 1 for v in resid)
    if dof < SEGMENT_DOF:
        return float("nan"), point, face
    var = sum(float(np.sum(v**2)) for v in resid) / dof
    var -= 0.5 * math.pi * point**2 * float(np.mean(1.0 / np.asarray(sizes, float)))
    return math.sqrt(max(var, 0.0)), point, face


#: the fewest degrees of freedom (segments less faces) a segment SD is stated from
SEGMENT_DOF = 6


def fit_laser_plane(name: str, points: np.ndarray, heights: np.ndarray, frames,
                    ground: np.ndarray | None = None, groups: np.ndarray | None = None
                    ) -> LaserPlaneFit:
    """SVD plane through the stripe points (and the ``ground`` points, if any) with outlier
    rejection; refuse when the stripe did not cross faces at two different heights (the plane
    would be undetermined)."""
    levels = sorted({round(float(h), 3) for h in np.unique(heights)
                     if np.sum(heights == h) >= 10})
    if len(levels) < 2:
        raise CalibrationError(
            f"the {name} stripe does not cross target faces at two different heights "
            f"(found {', '.join(f'{v:g} mm' for v in levels) or 'none'}); its plane is "
            "undetermined - choose a frame where it crosses both the low and the high face",
            code=codes.E_PLANE_UNDETERMINED)
    levels_all = np.asarray(heights, float)
    if ground is not None and len(ground):
        points = np.concatenate([points, ground])
        levels_all = np.concatenate([levels_all, np.zeros(len(ground))])
        if groups is not None:
            groups = np.concatenate([groups, np.full(len(ground), -1)])
    plane, rms, keep = robust_plane(points, groups=groups, levels=levels_all)
    if plane.normal[2] < 0:  # orient consistently: normal with positive depth component
        plane = Plane(-plane.normal, -plane.offset_mm)
    return LaserPlaneFit(name, plane, rms, int(keep.sum()), tuple(frames), tuple(levels))


@dataclass(frozen=True)
class StripeObservations:
    """Each laser's stripe on the target (as camera rays) in frames around its calibration
    frame: ``rays[name]`` lists ``(frame, time since frame t1 in s, rays (N, 3))``; under a
    rolling shutter the time is one per ray (its row's, :func:`row_times_s`)."""

    target: TargetModel
    speed_mm_s: float  # the travel between frames that matches the target's pose
    frames: dict[str, int]  # calibration frame of each laser
    rays: dict[str, list]
    blooming: tuple[str, ...] = ()  # lasers detected with the blooming fallback
    rows: dict[str, str] = field(default_factory=dict)  # each laser's row estimator
    #: each laser's stripe on the ground ring around the target, like ``rays``
    ground: dict[str, list] = field(default_factory=dict)

    def ground_points(self, name: str, rot: np.ndarray, pose_rt, frames) -> list:
        """The stripe points on the ground beside the target in ``frames`` (per frame)."""
        return [points_on_ground(rays @ rot.T, pose_rt, self.target, self.speed_mm_s * dt_k)
                for k, dt_k, rays in self.ground.get(name, []) if k in frames]

    def points(self, name: str, rot: np.ndarray, pose_rt):
        """The stripe points on the target's faces, their heights and frames (only frames where
        the stripe crosses two faces with at least 10 points each)."""
        pts: list[np.ndarray] = []
        hts: list[np.ndarray] = []
        used: list[int] = []
        frames = self.rays[name]
        if not frames:
            return pts, hts, used
        # all frames' rays in one intersection (each ray with its own travel): the tilt
        # refinement and the Monte Carlo ask for these points thousands of times
        sizes = [len(rays) for _, _, rays in frames]
        rays = np.concatenate([rays for _, _, rays in frames]) @ rot.T
        travel = np.concatenate([np.broadcast_to(self.speed_mm_s * np.asarray(dt_k, float), (n,))
                                 for (_, dt_k, _), n in zip(frames, sizes)])
        p_all, h_all, ok = points_on_faces(rays, pose_rt, self.target, travel)
        counts = np.bincount(np.repeat(np.arange(len(frames)), sizes)[ok],
                             minlength=len(frames))
        cuts = np.cumsum(counts)[:-1]
        for (k, _, _), p, hh in zip(frames, np.split(p_all, cuts), np.split(h_all, cuts)):
            levels = np.unique(hh)
            if len(levels) >= 2 and min(np.sum(hh == v) for v in levels) >= 10:
                pts.append(p)
                hts.append(hh)
                used.append(k)
        return pts, hts, used

    def fit_planes(self, rot: np.ndarray, pose_rt, with_ground: bool = False
                   ) -> dict[str, tuple[LaserPlaneFit, list]]:
        """Each laser's plane fit and the stripe points on the faces (per frame) it was
        fitted to. ``with_ground``: the stripe points on the ground beside the target join
        the fit (:meth:`_with_ground`)."""
        faces: dict[str, tuple] = {}  # each laser's fit to the faces alone, first
        for name, t_c in self.frames.items():
            pts, hts, used = self.points(name, rot, pose_rt)
            if not pts:
                raise CalibrationError(
                    f"the {name} stripe was not found on two target faces around frame {t_c}; "
                    "choose a frame where it crosses both the low and the high face",
                    code=codes.E_PLANE_UNDETERMINED)
            # frames whose points disagree with the others (acceleration ramp, a passing
            # shadow) are dropped: their travel does not follow the constant speed
            dropped: set[int] = set()
            if len(used) >= 4:
                first = fit_laser_plane(name, np.concatenate(pts), np.concatenate(hts), used,
                                        groups=frame_groups(pts))
                err = np.array([np.median(np.abs(first.plane.distance(p))) for p in pts])
                good = err <= max(3 * np.median(err), 0.02)
                dropped = {k for k, g in zip(used, good) if not g}
                pts = [p for p, g in zip(pts, good) if g]
                hts = [h for h, g in zip(hts, good) if g]
                used = [k for k, g in zip(used, good) if g]
            fit = fit_laser_plane(name, np.concatenate(pts), np.concatenate(hts), used,
                                  groups=frame_groups(pts))
            faces[name] = (fit, pts, hts, dropped)
        out = {}
        for name, (fit, pts, hts, dropped) in faces.items():
            if with_ground:
                # the ground in every frame observed, but those whose face points disagreed
                frames = {k for k, _, _ in self.ground.get(name, [])} - dropped
                others = [f for n, (f, _, _, _) in faces.items() if n != name]
                fit = self._with_ground(name, fit, np.concatenate(pts), np.concatenate(hts),
                                        rot, pose_rt, frames, others)
            seg_sd, point_sd, face_sd = stripe_noise(fit.plane, pts, hts)
            out[name] = (replace(fit, stripe_rows=self.rows.get(name, ""), segment_sd_mm=seg_sd,
                                 point_sd_mm=point_sd, face_sd_mm=face_sd), pts)
        return out

    def _with_ground(self, name: str, fit: LaserPlaneFit, pts: np.ndarray, hts: np.ndarray,
                     rot: np.ndarray, pose_rt, frames: set[int],
                     others: list[LaserPlaneFit] | None = None) -> LaserPlaneFit:
        """The plane refitted with the stripe points on the ground beside the target.

        The target's faces span a few centimetres; a plane fitted to them alone is tilted by
        the stripe's sub-pixel bias on each face and extrapolated across the picture and down
        to the ground (random rigs: height biases of 0.01-0.02 mm, height-scale errors up to
        0.4 %). The base plane the target stands on is height 0 of the map: its stripe points
        pin the plane where most of the evidence lies. A ground point is kept when it lies
        near the faces' plane (the ground is flat there), and the ground is used only when
        enough of its points do; soil heaped or dug beside the target leaves it out. Points
        that lie on the ``others``' planes (fitted to the faces) and not on this one are the
        other laser's light taken for this one's (random rig 28: green's blooming stripe, 60 %
        of red's ground points, 70 mm off red's plane); they count neither way."""
        ground = self.ground_points(name, rot, pose_rt, frames)
        g = np.concatenate(ground) if ground else np.zeros((0, 3))
        if not len(g):
            return replace(fit, ground_note="no stripe seen on the ground beside the target")
        gate = max(GROUND_GATE_RMS * fit.rms_mm, GROUND_GATE_MM)
        near = np.abs(fit.plane.distance(g)) <= gate
        foreign = np.zeros(len(g), bool)
        for o in others or ():
            foreign |= ~near & (np.abs(o.plane.distance(g))
                                <= max(GROUND_GATE_RMS * o.rms_mm, GROUND_GATE_MM))
        n_own = len(g) - int(foreign.sum())
        other_note = (f" ({int(foreign.sum())} more on the other laser's plane: its light, left "
                      "out)" if foreign.any() else "")
        if near.sum() < GROUND_MIN_POINTS or near.sum() < GROUND_MIN_SHARE * n_own:
            return replace(fit, ground_note=(
                f"ground beside the target not used: {int(near.sum())} of {n_own} stripe "
                f"points within {gate:.3f} mm of the faces' plane (not flat there)"
                f"{other_note}"))
        # the ground's points were gated by the faces' robust plane: a plain start here (a
        # frame's own plane would outvote the ground it is meant to be corrected by)
        joint = fit_laser_plane(name, pts, hts, fit.frames, g[near])
        return replace(joint, ground_points=int(near.sum()),
                       ground_note=f"{int(near.sum())} of {n_own} stripe points on the "
                       f"ground beside the target joined the faces' points{other_note}")


def stripe_window(t_c: int, speed_mm_s: float, fps: float, plane_span: int,
                  plane_travel_mm: float, frame_count: int) -> tuple[int, int]:
    """The frames ``lo..hi-1`` around calibration frame ``t_c`` its stripe is gathered from:
    ``plane_travel_mm`` of travel before and after it (at most ``plane_span`` frames each)."""
    span = max(3, min(plane_span, int(round(plane_travel_mm / max(speed_mm_s, 1e-6) * fps))))
    return max(0, t_c - span), min(frame_count, t_c + span + 1)


def observe_stripes(video, times: np.ndarray, intrinsics: Intrinsics, target: TargetModel,
                    picks: Picks, pose: PoseSolution, fps: float, plane_frames: int,
                    plane_span: int, plane_travel_mm: float,
                    progress: ProgressCallback | None = None,
                    cancel: CancelToken | None = None) -> StripeObservations:
    """Detect the green stripe around frame t1 and the red one around t2 on the target
    (``times``: each frame's time of travel at constant speed, see
    :meth:`.motion.Ramps.travel_times`)."""
    cancel = cancel or CancelToken()
    rot_b, r_o, t_o = pose.rotation, pose.target_rotation, pose.target_translation_mm
    v_true = pose.implied_speed_mm_s  # the travel between frames that matches the target's pose
    frames = {"green": picks.t1, "red": picks.t2}
    variants = (ROWS_CENTRE, ROWS_MIDPOINT, ROWS_GAUSS, ROWS_BLOOMING)
    found: dict[str, dict[str, list]] = {v: {} for v in variants}
    on_ground: dict[str, dict[str, list]] = {v: {} for v in variants}
    for i, (name, t_c) in enumerate(frames.items()):
        cancel.check()
        report(progress, 0.15 + 0.3 * i, f"{name} stripe on the target")
        lo, hi = stripe_window(t_c, v_true, fps, plane_span, plane_travel_mm,
                               video.frame_count)
        wanted = sorted(set(np.linspace(lo, hi - 1, max(1, plane_frames)).astype(int)) | {t_c})
        for v in variants:
            found[v][name] = []
            on_ground[v][name] = []
        for k in wanted:
            cancel.check()
            dt_k = float(times[k] - times[picks.t1])
            rgb = video.read(int(k))
            args = (rgb, name, intrinsics, rot_b, (r_o, t_o), target, v_true * dt_k)
            com, mid, fit = stripe_uv_on_target(*args, midpoints=True)
            uvs = {ROWS_CENTRE: com, ROWS_MIDPOINT: mid, ROWS_GAUSS: fit,
                   ROWS_BLOOMING: stripe_uv_on_target(*args, blooming=True)}
            for v, uv in uvs.items():
                if len(uv):
                    found[v][name].append((int(k), row_times_s(dt_k, uv, intrinsics),
                                           intrinsics.rays(uv)))
            g_com, g_mid, g_fit = stripe_uv_on_ground(*args, midpoints=True)
            guvs = {ROWS_CENTRE: g_com, ROWS_MIDPOINT: g_mid, ROWS_GAUSS: g_fit,
                    ROWS_BLOOMING: stripe_uv_on_ground(*args, blooming=True)}
            for v, uv in guvs.items():
                if len(uv):
                    on_ground[v][name].append((int(k), row_times_s(dt_k, uv, intrinsics),
                                               intrinsics.rays(uv)))
    # a blooming stripe (a saturated, nearly white core on the light target) escapes the
    # colour tests in most columns: a laser is detected with the fallback in all its frames
    # when the strict tests give less than BLOOM_SWITCH of the fallback's points on the faces
    # (in the frames where the stripe crosses two faces, as the plane fit takes them)
    by = {v: StripeObservations(target, v_true, frames, found[v]) for v in variants}
    rt = (r_o, t_o)
    rows = {}
    for name in frames:
        if (_face_points(by[ROWS_CENTRE], name, rot_b, rt)
                < BLOOM_SWITCH * _face_points(by[ROWS_BLOOMING], name, rot_b, rt)):
            rows[name] = ROWS_BLOOMING
        else:
            # the centre of mass is pulled towards whole pixels by the stripe's phase, and on
            # a face of constant height the phase is the same in every frame: the faces'
            # points shift by different amounts and turn the plane. The crossings' midpoint
            # is locked 2-5 times less on most stripes, not on all (a narrow, strongly
            # saturated core); a Gaussian fitted to the profile's unclipped rows less again
            # where the profile is Gaussian, but noise, speckle and compression move it more
            # (the sample case at 960x540: green turned 0.0605 deg with the midpoint, 0.0022
            # with the fit): take the estimator whose points lie best on one plane
            cands = (ROWS_CENTRE, ROWS_MIDPOINT, ROWS_GAUSS)
            rms = {v: _plane_rms(by[v], name, rot_b, rt) for v in cands}
            rows[name] = min(cands, key=lambda v: (rms[v], cands.index(v)))
    return StripeObservations(target, v_true, frames,
                              {name: found[rows[name]][name] for name in frames},
                              tuple(n for n in frames if rows[n] == ROWS_BLOOMING), rows,
                              {name: on_ground[rows[name]][name] for name in frames})


def _plane_rms(obs: StripeObservations, name: str, rot: np.ndarray, pose_rt) -> float:
    """The plane fit's RMS (mm) of one laser's stripe points (inf when it cannot be fitted)."""
    pts, hts, used = obs.points(name, rot, pose_rt)
    if not pts:
        return float("inf")
    try:
        return fit_laser_plane(name, np.concatenate(pts), np.concatenate(hts), used,
                               groups=frame_groups(pts)).rms_mm
    except CalibrationError:
        return float("inf")


def _face_points(obs: StripeObservations, name: str, rot: np.ndarray, pose_rt) -> int:
    return sum(len(p) for p in obs.points(name, rot, pose_rt)[0])


#: the tilt refinement's search: a grid of this step (deg) over +-STEPS steps around the picks'
#: tilt (+-10 deg), then a bounded search within one step of the best grid point
TILT_GRID_STEP_DEG = 0.5
TILT_GRID_STEPS = 20
#: stripe points farther than this (mm) from a laser's plane (and 4 robust SDs) are left out of
#: the plane the tilt refinement fits: another object's light, not a tilt's residual
GROSS_OUTLIER_MM = 0.5


def refine_tilt(obs: StripeObservations, planes0: dict, intrinsics: Intrinsics,
                target: TargetModel, picks: Picks, pose: PoseSolution, speed_mm_s: float,
                dt: float, click_sigma_px: float) -> PoseSolution:
    """The pose with its tilt refined by the stripes (``planes0``: the planes fitted with the
    pose from the picks).

    The clicks fix roll well but tilt poorly (a tilt of 0.05 deg moves the corners by less
    than 0.1 px). The stripe on the target's faces, seen over a stretch of travel, is only
    consistent with one motion direction: refine the tilt to minimise the plane residuals of
    the stripe points together with the reprojection of the picks."""
    from scipy.optimize import minimize_scalar

    implied, v_true = pose.implied_speed_mm_s, obs.speed_mm_s
    sigma_s = max(1e-3, np.mean([f.rms_mm for f, _ in planes0.values()]))
    n_ref = {name: sum(len(p) for p in pts) for name, (_, pts) in planes0.items()}
    weight = float(np.mean(list(n_ref.values())))
    speed_ok = abs(implied - speed_mm_s) <= SPEED_WARN_FRACTION * speed_mm_s
    d_use = (speed_mm_s if speed_ok else v_true) * dt
    base = (pose.roll_rad, pose.tilt_rad, pose.target_rotation, pose.target_translation_mm)

    def cost(tilt):
        roll = pose.roll_rad
        _, _, ro, to, _, rms = refine_bundle(intrinsics, target, picks,
                                             (roll, tilt, base[2], base[3]),
                                             d_use, fixed_travel=True, fixed_rotation=True,
                                             dt_s=dt)
        rot = ideal_rotation(roll, tilt)
        total = 24 * (rms / click_sigma_px) ** 2
        for name in ("green", "red"):
            pts, hts, _ = obs.points(name, rot, (ro, to))
            n_pts = sum(len(p) for p in pts)
            if n_pts < 0.8 * n_ref[name]:
                return 1e12  # the stripe no longer falls on the faces: not a candidate
            allp = np.concatenate(pts)
            # the plane with outliers left out (a few stripe points off the faces - another
            # object's light, a frame off the constant speed - would turn a plain fit and
            # hide the tilt's signal in the other points' residuals); they still count,
            # capped, in the cost
            plane, _, _ = robust_plane(allp, floor_mm=GROSS_OUTLIER_MM,
                                       groups=frame_groups(pts), levels=np.concatenate(hts))
            r = np.clip(np.abs(plane.distance(allp)) / sigma_s, 0, 5)  # outliers capped
            # the two lasers weigh alike: their errors are biases per face and frame, not
            # independent per point, and the laser with more points is not the better witness
            # (weighted by their points, rigs 7 and 21 followed red's biased minimum)
            total += weight * float(np.mean(r**2))
        return total

    # tilt only: roll is fixed well by the picks (the stripes would add their own bias). The
    # picks' tilt can be degrees off (0.5 px of click noise: 1-4 deg on a random rig, where the
    # stripes' residual still falls steadily towards the true tilt), so the whole plausible
    # range is scanned on a grid first and the best grid step refined: a search bounded to a
    # fraction of a degree around the picks' tilt stopped at its bound and kept the error.
    step = np.radians(TILT_GRID_STEP_DEG)
    grid = pose.tilt_rad + step * np.arange(-TILT_GRID_STEPS, TILT_GRID_STEPS + 1)
    best = int(np.argmin([cost(t) for t in grid]))
    res = minimize_scalar(cost, bounds=(grid[best] - step, grid[best] + step),
                          method="bounded", options={"xatol": 2e-7})
    roll_r, tilt_r = pose.roll_rad, float(res.x)
    _, _, r_o, t_o, _, rms_px = refine_bundle(intrinsics, target, picks,
                                              (roll_r, tilt_r, base[2], base[3]), d_use,
                                              fixed_travel=True, fixed_rotation=True, dt_s=dt)
    rot_b = ideal_rotation(roll_r, tilt_r)
    m_b = rot_b.T @ np.array([0.0, 1.0, 0.0])
    corners = parallax_corners(intrinsics, rot_b, picks, speed_mm_s * dt, dt)
    _, r_e, t_e = umeyama(target.corner_array(), corners, with_scale=False)
    residuals = np.linalg.norm(corners - (target.corner_array() @ r_e.T + t_e), axis=1)
    return replace(pose, roll_rad=float(roll_r), tilt_rad=float(tilt_r), rotation=rot_b,
                   motion_dir_cam=m_b, corners_parallax_mm=corners,
                   corner_residuals_mm=residuals, target_rotation=r_o,
                   target_translation_mm=t_o, reprojection_rms_px=rms_px)
