"""Aids for the person calibrating: snap a rough click to the true corner, propose the two
calibration frames, and the seed's three-point laser plane as a fallback."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from impress_gui.core.base import codes
from impress_gui.core.base.errors import CalibrationError, InputError
from impress_gui.core.base.progress import CancelToken, ProgressCallback, report
from impress_gui.core.calibration.geometry import Intrinsics, Plane
from impress_gui.core.calibration.picks import LASER_NAMES, Picks
from impress_gui.core.calibration.planes import LaserPlaneFit
from impress_gui.core.calibration.target import CORNER_NAMES, TargetModel
from impress_gui.core.reconstruction.stripes import LASERS, StripeParams, auto_rois, detect


@dataclass(frozen=True)
class CornerRefinement:
    uv_px: tuple[float, float]
    moved_px: float
    accepted: bool  # False: no clear corner near the click, the click is kept


#: a laser stripe (saturated pixels, with a margin for its halo) hides the edges under it
_SATURATED = 245
#: an edge must stand out of the texture around it: median edge gradient / median gradient
_MIN_CONTRAST = 3.0
#: largest RMS distance (px) of an edge's points from its fitted line
_MAX_RMS_PX = 0.4
#: smallest share of an edge's profiles that agree with its line
_MIN_INLIERS = 0.6


def _sample(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples of a float32 image at (x, y) of any equal shapes."""
    import cv2

    x = np.asarray(x, np.float32)
    y = np.asarray(y, np.float32)
    n, cols = x.size, 1024
    rows = -(-n // cols)
    xx = np.zeros(rows * cols, np.float32)
    yy = np.zeros(rows * cols, np.float32)
    xx[:n], yy[:n] = x.ravel(), y.ravel()
    out = cv2.remap(img, xx.reshape(rows, cols), yy.reshape(rows, cols), cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.ravel()[:n].reshape(x.shape)


def _wedge(gx, gy, centre, radius, spacing, click, d0, s):
    """Best corner candidate on a grid around ``centre``: the mean gradient across rays from a
    candidate, per direction, is positive along one edge and negative along the other (20-160
    degrees apart). Scores are weighted down with the distance from the click."""
    from scipy.ndimage import maximum_filter1d

    nt = 180  # 2-degree bins
    th = np.arange(nt) * (2 * np.pi / nt)
    g = np.arange(-radius, radius + 1e-9, spacing)
    qx, qy = np.meshgrid(g, g)
    m = qx**2 + qy**2 <= radius * radius + 1e-9
    q = centre[None, :] + np.column_stack([qx[m], qy[m]])
    ex, ey = np.cos(th), np.sin(th)
    px = q[:, 0, None, None] + s[None, None, :] * ex[None, :, None]
    py = q[:, 1, None, None] + s[None, None, :] * ey[None, :, None]
    a = (_sample(gx, px, py) * -ey[None, :, None] + _sample(gy, px, py) * ex[None, :, None]).mean(2)
    pos, neg = np.maximum(a, 0.0), np.maximum(-a, 0.0)
    nmax = maximum_filter1d(neg, 71, axis=1, mode="wrap")  # +-70 degrees around +-90
    partner = np.maximum(np.roll(nmax, -45, axis=1), np.roll(nmax, 45, axis=1))
    score = np.minimum(pos, partner)
    dist = np.hypot(*(q - click).T)
    k = int(np.argmax(score.max(1) / (1.0 + (dist / d0) ** 2)))
    i1 = int(np.argmax(score[k]))
    cand = (i1 + np.r_[10:81, -80:-9]) % nt
    i2 = int(cand[np.argmax(neg[k, cand])])
    return float(score[k, i1]), q[k], th[i1], th[i2]


def _edge_points(gx, gy, bad, q, theta, sign, s0, s1, hw, step=0.25):
    """Sub-pixel points of the edge leaving ``q`` in direction ``theta``: on profiles across
    it, one per pixel of length, the centroid of the gradient's peak of the expected sign
    (the part above half its height, within 1 px). Profiles touching ``bad`` are dropped."""
    e = np.array([np.cos(theta), np.sin(theta)])
    n = np.array([-e[1], e[0]])
    s = np.arange(s0, s1 + 1e-9, 1.0)
    t = np.arange(-hw, hw + 1e-9, step)
    px = q[0] + s[:, None] * e[0] + t[None, :] * n[0]
    py = q[1] + s[:, None] * e[1] + t[None, :] * n[1]
    d = sign * (_sample(gx, px, py) * n[0] + _sample(gy, px, py) * n[1])
    dirty = _sample(bad, px, py).max(1) > 0
    j = np.argmax(d, axis=1)
    peak = d[np.arange(len(s)), j]
    win = np.abs(t[None, :] - t[j][:, None]) <= 1.0
    wgt = np.where(win & (d >= 0.5 * peak[:, None]), d - 0.5 * peak[:, None], 0.0)
    tc = (wgt * t[None, :]).sum(1) / np.maximum(wgt.sum(1), 1e-12)
    pts = q[None, :] + s[:, None] * e[None, :] + tc[:, None] * n[None, :]
    ok = (peak > 0) & ~dirty & (np.abs(tc) < hw - 0.5)
    return pts, peak, ok


def _fit_line(pts, w):
    """Weighted total least squares line, refitted without points beyond 3 robust sigmas."""
    keep = np.ones(len(pts), bool)
    for _ in range(4):
        ww = w * keep
        c = (pts * ww[:, None]).sum(0) / ww.sum()
        d = np.linalg.svd((pts - c) * np.sqrt(ww)[:, None], full_matrices=False)[2][0]
        res = (pts - c) @ np.array([-d[1], d[0]])
        sig = max(1.4826 * float(np.median(np.abs(res[keep]))), 0.15)
        keep = np.abs(res) <= 3 * sig
    return c, d, res, keep


def refine_corner(rgb: np.ndarray, uv_px, radius_px: int | None = None) -> CornerRefinement:
    """Refine a click to the sub-pixel corner nearby: the intersection of the two straight
    edges that meet there.

    A coarse search (within ``radius_px`` of the click, nearer corners preferred) finds the
    point from which two edges leave 20-160 degrees apart; each edge is then located to a
    fraction of a pixel on profiles across it (gradient peak centroids on the luma, one per
    pixel over about 2 x ``radius_px`` of its length), a robust line is fitted to each and
    the two are intersected (three rounds). The click is kept (``accepted`` False) when an
    edge is hidden by a laser stripe, does not stand out of the texture around it, or its
    points do not lie on a line, and when the corner is further than ``radius_px``."""
    import cv2

    h, w = rgb.shape[:2]
    u, v = float(uv_px[0]), float(uv_px[1])
    if not (0 <= u < w and 0 <= v < h):
        raise InputError(f"the click ({u:.1f}, {v:.1f}) is outside the {w}x{h} image",
                         code=codes.E_PICKS)
    r = radius_px or max(6, w // 120)
    length = max(10, 2 * r)  # edge length used, px
    pad = r + length + 8
    x0, y0 = int(max(0, u - pad)), int(max(0, v - pad))
    x1, y1 = int(min(w, u + pad + 1)), int(min(h, v + pad + 1))
    sub = np.ascontiguousarray(rgb[y0:y1, x0:x1])
    if sub.shape[0] < 8 or sub.shape[1] < 8:
        return CornerRefinement((u, v), 0.0, False)
    grey = cv2.cvtColor(sub, cv2.COLOR_RGB2GRAY).astype(np.float32)
    gx = cv2.Scharr(grey, cv2.CV_32F, 1, 0) / 32.0
    gy = cv2.Scharr(grey, cv2.CV_32F, 0, 1) / 32.0
    rad = max(2, int(round(3 * w / 1920)))
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * rad + 1, 2 * rad + 1))
    bad = cv2.dilate((sub.max(axis=2) >= _SATURATED).astype(np.uint8), disk).astype(np.float32)
    clean = bad == 0
    if not clean.any():
        return CornerRefinement((u, v), 0.0, False)
    gxm = np.where(clean, gx, 0.0).astype(np.float32)
    gym = np.where(clean, gy, 0.0).astype(np.float32)
    noise = max(float(np.median(np.hypot(gx, gy)[clean])), 1e-3)

    click = np.array([u - x0, v - y0])
    s = np.arange(3.0, length + 1e-9, 1.0)
    score, q, t1, t2 = _wedge(gxm, gym, click, r, 2.0, click, max(2.0, r / 3.0), s)
    score, q, t1, t2 = _wedge(gxm, gym, q, 2.0, 0.5, click, max(2.0, r / 3.0), s)
    if score <= 0:
        return CornerRefinement((u, v), 0.0, False)
    thetas, hw = [t1, t2], 3.0
    for it in range(3):
        hwi = hw + 1.0 if it == 0 else hw
        ang = abs(float(np.angle(np.exp(1j * (thetas[0] - thetas[1])))))
        if not np.radians(20) <= ang <= np.radians(160):
            return CornerRefinement((u, v), 0.0, False)
        s0 = hwi / np.sin(ang) + 1.5  # profiles clear of the other edge
        lines, stats = [], []
        for th, sign in zip(thetas, (1.0, -1.0)):
            pts, peak, ok = _edge_points(gx, gy, bad, q, th, sign, s0, length + s0 - 3, hwi)
            if ok.sum() < 6:
                return CornerRefinement((u, v), 0.0, False)
            c, d, res, keep = _fit_line(pts[ok], peak[ok])
            if d @ [np.cos(th), np.sin(th)] < 0:
                d = -d
            lines.append((c, d))
            stats.append((float(np.median(peak[ok][keep])) / noise,
                          float(np.sqrt(np.mean(res[keep] ** 2))), keep.sum() / len(ok)))
        (ca, da), (cb, db) = lines
        m = np.column_stack([da, -db])
        if abs(np.linalg.det(m)) < 0.3:
            return CornerRefinement((u, v), 0.0, False)
        q = ca + np.linalg.solve(m, cb - ca)[0] * da
        thetas = [float(np.arctan2(da[1], da[0])), float(np.arctan2(db[1], db[0]))]
    ref = q + [x0, y0]
    moved = float(np.hypot(ref[0] - u, ref[1] - v))
    contrast = min(st[0] for st in stats)
    rms = max(st[1] for st in stats)
    inliers = min(st[2] for st in stats)
    if (moved > r or contrast < _MIN_CONTRAST or rms > _MAX_RMS_PX or inliers < _MIN_INLIERS
            or not (0 <= ref[0] < w and 0 <= ref[1] < h)):
        return CornerRefinement((u, v), 0.0, False)
    return CornerRefinement((float(ref[0]), float(ref[1])), moved, True)


def propose_calibration_frames(video, sample_step: int | None = None,
                               progress: ProgressCallback | None = None,
                               cancel: CancelToken | None = None) -> dict[str, int]:
    """Frames where each laser's stripe lies on the calibration target.

    The target is the tallest object of a scan, so its stripe is displaced furthest from the
    stripe's usual row: per sampled frame the 95th percentile of that displacement is scored,
    and the frames scoring at least 60 % of the best form the run where the stripe is on the
    target. The green stripe (leading) is taken a third into its run and the red one two thirds
    into its run: far apart (parallax) with the whole target still likely in view. The user
    checks that all six corners are visible and adjusts. Returns ``{"t1": ..., "t2": ...}``."""
    cancel = cancel or CancelToken()
    n = video.frame_count
    step = sample_step or max(1, n // 400)
    probe = [video.read(int(k)) for k in np.linspace(0, n - 1, 6).astype(int)]
    rois = auto_rois(probe, margin_px=probe[0].shape[0] // 6)
    params = StripeParams(rois=rois)
    disp: dict[str, list] = {name: [] for name in LASERS}
    frames = []
    for k, rgb in video.iter_frames(0, n):
        if k % step:
            continue
        cancel.check()
        res = detect(rgb, params)
        frames.append(k)
        for name in LASERS:
            rows = res[name].rows
            if np.isfinite(rows).sum() < 0.1 * len(rows):
                disp[name].append(0.0)
                continue
            dev = np.abs(rows - np.nanmedian(rows))
            disp[name].append(float(np.nanpercentile(dev, 95)))
        report(progress, k / n, f"scanning frame {k}")
    out = {}
    for key, name, where in (("t1", "green", 0.35), ("t2", "red", 0.65)):
        score = np.array(disp[name])
        if score.max() <= 2.0:
            raise CalibrationError(f"no frame shows the {name} stripe displaced by the target",
                                   code=codes.E_NO_TARGET)
        strong = np.flatnonzero(score >= 0.6 * score.max())
        runs = np.split(strong, np.flatnonzero(np.diff(strong) > 2) + 1)
        run = max(runs, key=lambda r: score[r].sum())
        out[key] = int(frames[run[int(round(where * (len(run) - 1)))]])
    return out


def _rays_meet_edges(intr: Intrinsics, rotation: np.ndarray, travel_mm: float,
                     pixels: np.ndarray, edges_rail):
    """For each stripe pixel and its target edge (rail frame, two points): the point of the
    edge nearest to the pixel's ray (camera-fixed ideal frame), the distance by which the ray
    misses the edge (mm), the point's position along the edge (0 and 1 at its ends) and its
    depth along the ray (camera z)."""
    rays = intr.rays(np.asarray(pixels, float)) @ rotation.T
    pts, miss, along, depth = [], [], [], []
    for ray, (a, b) in zip(rays, edges_rail):
        a = np.asarray(a, float) - [0.0, travel_mm, 0.0]
        b = np.asarray(b, float) - [0.0, travel_mm, 0.0]
        e = b - a
        # closest points of the ray through the origin (t) and the edge (s)
        A = np.array([[ray @ ray, -(ray @ e)], [ray @ e, -(e @ e)]])
        rhs = np.array([ray @ a, e @ a])
        try:
            t, s = np.linalg.solve(A, rhs)
        except np.linalg.LinAlgError:
            raise CalibrationError("a pick ray is parallel to its target edge",
                                   code=codes.E_PICKS) from None
        pts.append(a + s * e)
        miss.append(float(np.linalg.norm(t * ray - (a + s * e))))
        along.append(float(s))
        depth.append(float(t))
    return np.array(pts), np.array(miss), np.array(along), np.array(depth)


def _plane_through(p: np.ndarray) -> Plane:
    n = np.cross(p[1] - p[0], p[2] - p[1])
    spread = max(float(np.linalg.norm(p[1] - p[0])), float(np.linalg.norm(p[2] - p[0])), 1e-9)
    if np.linalg.norm(n) < 1e-6 * spread**2 or spread < 1e-6:
        raise CalibrationError("the three stripe points are collinear: the plane is "
                               "undetermined", code=codes.E_PLANE_UNDETERMINED)
    n /= np.linalg.norm(n)
    if n[2] < 0:
        n = -n
    return Plane(n, float(n @ p[0]))


def three_point_plane(intr: Intrinsics, rotation: np.ndarray, travel_mm: float,
                      pixels_lmn: np.ndarray, edges_rail: list[tuple[np.ndarray, np.ndarray]]
                      ) -> Plane:
    """The seed's method: rays through stripe pixels L, M, N that lie on three target edges,
    intersected with those 3D edges (rail frame, each given by two points), give three points;
    the plane through them in the camera-fixed ideal frame."""
    pts = _rays_meet_edges(intr, rotation, travel_mm, pixels_lmn, edges_rail)[0]
    return _plane_through(pts)


def check_stripe_points(picks: Picks, intrinsics: Intrinsics, frame_count: int) -> None:
    """The three stripe points of both lasers, as the three-point planes need them: present,
    in a frame of the video and inside the image; each problem a clear error."""
    w, h = intrinsics.image_size
    missing = [n for n in LASER_NAMES if n not in picks.stripe_points]
    if missing:
        raise CalibrationError(
            f"the picks have no stripe points (L, M, N) for the {' and '.join(missing)} "
            f"laser{'s' if len(missing) > 1 else ''}; the three-point planes need three "
            "points on target edges per laser (picks field 'stripe_points')",
            code=codes.E_PICKS_STRIPE)
    for name in LASER_NAMES:
        sp = picks.stripe_points[name]
        if not 0 <= sp.frame < frame_count:
            raise CalibrationError(f"the {name} stripe points' frame {sp.frame} is outside the "
                                   f"video (0..{frame_count - 1})", code=codes.E_FRAME_RANGE)
        for lbl, p in zip("LMN", sp.points):
            u, v = p.uv_px
            if not (-0.5 <= u <= w - 0.5 and -0.5 <= v <= h - 0.5):
                raise CalibrationError(f"the {name} stripe point {lbl} ({u:.1f}, {v:.1f}) is "
                                       f"outside the {w}x{h} image", code=codes.E_PICKS)


#: largest distance (px) of a three-point stripe pick from its target edge's image
MAX_EDGE_OFFSET_PX = 5.0


def three_point_planes(intr: Intrinsics, rotation: np.ndarray, target: TargetModel,
                       target_pose: tuple[np.ndarray, np.ndarray], picks: Picks,
                       travel_mm: Callable[[int], float]) -> dict[str, LaserPlaneFit]:
    """Both laser planes by the seed's three-point method from the picks' stripe points.

    ``target_pose`` is the fitted target (object -> rail rotation, translation); ``travel_mm``
    gives the camera's travel since frame t1 at a frame (the travel that matches the pose).
    ``rms_mm`` of each fit is the RMS distance by which the three pick rays miss their edges
    (0 for exact picks); ``heights_mm`` the target heights of the three points."""
    r_o, t_o = target_pose
    corners = target.corner_array() @ np.asarray(r_o).T + np.asarray(t_o)
    obj = target.corner_array()
    idx = {c: i for i, c in enumerate(CORNER_NAMES)}
    out = {}
    for name in LASER_NAMES:
        sp = picks.stripe_points[name]
        ia = [idx[p.edge[0]] for p in sp.points]
        ib = [idx[p.edge[1]] for p in sp.points]
        edges = [(corners[i], corners[j]) for i, j in zip(ia, ib)]
        pts, miss, along, depth = _rays_meet_edges(intr, rotation, travel_mm(sp.frame),
                                                   sp.pixels(), edges)
        for lbl, p, s, m, z in zip("LMN", sp.points, along, miss, depth):
            edge = f"{p.edge[0]}-{p.edge[1]}"
            if not -0.1 <= s <= 1.1:
                raise CalibrationError(
                    f"the {name} stripe point {lbl} is beyond the ends of target edge {edge}: "
                    "check the edge named for it", code=codes.E_PICKS)
            off_px = m * intr.fx / max(z, 1e-9)
            if z <= 0 or off_px > MAX_EDGE_OFFSET_PX:
                raise CalibrationError(
                    f"the {name} stripe point {lbl} is {off_px:.1f} px off target edge {edge} "
                    "(where the corner picks place it): check the edge named for it and that "
                    "the point is where the stripe crosses that edge", code=codes.E_PICKS)
        heights = obj[ia, 2] + along * (obj[ib, 2] - obj[ia, 2])
        levels = sorted({round(float(z), 3) for z in heights})
        if max(levels) - min(levels) < 1.0:
            raise CalibrationError(
                f"the three {name} stripe points lie at one height of the target "
                f"({levels[0]:g} mm); its plane is undetermined - pick them on edges at two "
                "heights (the low face's outer edge and the high face's edges)",
                code=codes.E_PLANE_UNDETERMINED)
        plane = _plane_through(pts)
        out[name] = LaserPlaneFit(name, plane, float(np.sqrt(np.mean(miss**2))), 3,
                                  (sp.frame,), tuple(levels), method="three-point")
    return out
