"""Aids for the person calibrating: snap a rough click to the true corner, propose the two
calibration frames, and the seed's three-point laser plane as a fallback."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from impress_gui.core.errors import CalibrationError, InputError
from impress_gui.core.geometry import Intrinsics, Plane
from impress_gui.core.progress import CancelToken, ProgressCallback, report
from impress_gui.core.stripes import LASERS, StripeParams, auto_rois, detect


@dataclass(frozen=True)
class CornerRefinement:
    uv_px: tuple[float, float]
    moved_px: float
    accepted: bool  # False: no clear corner near the click, the click is kept


def refine_corner(rgb: np.ndarray, uv_px, radius_px: int | None = None) -> CornerRefinement:
    """Refine a click to the sub-pixel corner nearby (OpenCV's cornerSubPix on the grey image,
    started from the strongest Shi-Tomasi corner within ``radius_px``)."""
    import cv2

    h, w = rgb.shape[:2]
    u, v = float(uv_px[0]), float(uv_px[1])
    if not (0 <= u < w and 0 <= v < h):
        raise InputError(f"the click ({u:.1f}, {v:.1f}) is outside the {w}x{h} image",
                         code="E-PICKS")
    r = radius_px or max(6, w // 120)
    grey = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY).astype(np.float32)
    x0, y0 = int(max(0, u - 2 * r)), int(max(0, v - 2 * r))
    x1, y1 = int(min(w, u + 2 * r + 1)), int(min(h, v + 2 * r + 1))
    patch = grey[y0:y1, x0:x1]
    resp = cv2.cornerMinEigenVal(patch, 5, 3)
    yy, xx = np.mgrid[y0:y1, x0:x1]
    resp[(xx - u) ** 2 + (yy - v) ** 2 > r * r] = 0
    if resp.max() <= 1e-3 * max(1.0, float(patch.std())):
        return CornerRefinement((u, v), 0.0, False)
    iy, ix = np.unravel_index(int(np.argmax(resp)), resp.shape)
    start = np.array([[[ix + x0, iy + y0]]], np.float32)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 60, 1e-4)
    win = max(3, r // 2)
    ref = cv2.cornerSubPix(grey, start, (win, win), (-1, -1), crit)[0, 0]
    moved = float(np.hypot(ref[0] - u, ref[1] - v))
    if moved > r:
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
    disp = {name: [] for name in LASERS}
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
                                   code="E-NO-TARGET")
        strong = np.flatnonzero(score >= 0.6 * score.max())
        runs = np.split(strong, np.flatnonzero(np.diff(strong) > 2) + 1)
        run = max(runs, key=lambda r: score[r].sum())
        out[key] = int(frames[run[int(round(where * (len(run) - 1)))]])
    return out


def three_point_plane(intr: Intrinsics, rotation: np.ndarray, travel_mm: float,
                      pixels_lmn: np.ndarray, edges_rail: list[tuple[np.ndarray, np.ndarray]]
                      ) -> Plane:
    """The seed's method: rays through stripe pixels L, M, N that lie on three target edges,
    intersected with those 3D edges (rail frame, each given by two points), give three points;
    the plane through them in the camera-fixed ideal frame."""
    rays = intr.rays(np.asarray(pixels_lmn, float)) @ rotation.T
    pts = []
    for ray, (a, b) in zip(rays, edges_rail):
        a = np.asarray(a, float) - [0.0, travel_mm, 0.0]
        b = np.asarray(b, float) - [0.0, travel_mm, 0.0]
        e = b - a
        # closest point on the edge to the ray through the origin
        A = np.array([[ray @ ray, -(ray @ e)], [ray @ e, -(e @ e)]])
        rhs = np.array([ray @ a, e @ a])
        try:
            _, s = np.linalg.solve(A, rhs)
        except np.linalg.LinAlgError:
            raise CalibrationError("a pick ray is parallel to its target edge",
                                   code="E-PICKS") from None
        pts.append(a + s * e)
    p = np.array(pts)
    n = np.cross(p[1] - p[0], p[2] - p[1])
    spread = max(np.linalg.norm(p[1] - p[0]), np.linalg.norm(p[2] - p[0]), 1e-9)
    if np.linalg.norm(n) < 1e-6 * spread**2 or spread < 1e-6:
        raise CalibrationError("the three stripe points are collinear: the plane is "
                               "undetermined", code="E-PLANE-UNDETERMINED")
    n /= np.linalg.norm(n)
    if n[2] < 0:
        n = -n
    return Plane(n, float(n @ p[0]))
