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
from impress_gui.core.calibration.planes import LaserPlaneFit, calibration_stripe_params
from impress_gui.core.calibration.target import CORNER_NAMES, TargetModel
from impress_gui.core.reconstruction.stripes import (
    LASERS,
    auto_rois,
    detect_band_blooming,
)


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


def _stripe_profiles(video, step: int, progress: ProgressCallback | None,
                     cancel: CancelToken) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Every ``step``-th frame's stripe rows per laser and column: ``(frames, {laser: (K, W)})``
    (NaN where a column has no stripe). Each laser's band of rows reaches from the other
    laser's band to the picture's edge, so that the stripe displaced by a tall target stays
    inside it; the stripe is detected with the calibration's fallback for a stripe blooming on
    the light target."""
    n = video.frame_count
    probe = [video.read(int(k)) for k in np.linspace(0, n - 1, 6).astype(int)]
    h = probe[0].shape[0]
    try:
        rois = auto_rois(probe, margin_px=max(12, h // 4))
        a, b = sorted(rois.values())
        if a[1] > b[0]:  # overlapping bands: one laser's light counted in the other's
            raise InputError("overlapping bands", code=codes.E_NO_STRIPE)
    except InputError:
        rois = _dim_rois(probe)
    # the bands reach the picture's edges on their outer sides (a tall target can displace a
    # stripe further than a margin); their inner sides stay apart
    lo, hi = sorted(LASERS, key=lambda name: rois[name][0])
    rois = {lo: (0, rois[lo][1]), hi: (rois[hi][0], h)}
    params = calibration_stripe_params(rois=rois)
    rows: dict[str, list] = {name: [] for name in LASERS}
    frames = []
    for k, rgb in video.iter_frames(0, n):
        if k % step:
            continue
        cancel.check()
        frames.append(k)
        for name in LASERS:
            # a laser saturates on the light target: the calibration's blooming fallback
            r0, r1 = params.rois[name]
            res = detect_band_blooming(name, rgb[r0:r1], r0, params)
            rows[name].append(np.asarray(res.rows, float))
        report(progress, k / n, f"scanning frame {k}")
    return np.array(frames), {name: np.array(v) for name, v in rows.items()}


def _dim_rois(probe: list[np.ndarray]) -> dict[str, tuple[int, int]]:
    """Bands of rows for the lasers when :func:`auto_rois` misses a dim one (unsaturated on
    the soil, too few bright pixels) or mixes them up: each laser's stripe searched in every
    row of the sample frames, its most frequent row (where both detectors find the same
    stripe, it is the one found more often's, and the other takes its next most frequent row
    elsewhere), the two bands split halfway between."""
    h = probe[0].shape[0]
    params = calibration_stripe_params()
    hists = {}
    for name in LASERS:
        found = np.concatenate([detect_band_blooming(name, f, 0, params).rows for f in probe])
        found = found[np.isfinite(found)]
        if found.size < 0.1 * probe[0].shape[1] * len(probe):
            raise InputError(f"the {name} laser's stripe is not visible in the sampled frames",
                             code=codes.E_NO_STRIPE)
        hists[name] = np.convolve(np.bincount(found.astype(int), minlength=h), np.ones(9),
                                  "same")[:h]
    peaks = {name: int(np.argmax(hist)) for name, hist in hists.items()}
    g, r = peaks["green"], peaks["red"]
    if abs(g - r) < 0.1 * h:
        keep = "green" if hists["green"][g] >= hists["red"][r] else "red"
        other = "red" if keep == "green" else "green"
        hist = hists[other].copy()
        hist[max(0, peaks[keep] - h // 10):peaks[keep] + h // 10 + 1] = 0
        if hist.max() <= 0:
            raise InputError("the two lasers' stripes cannot be told apart in the sampled "
                             "frames", code=codes.E_NO_STRIPE)
        peaks[other] = int(np.argmax(hist))
    lo, hi = sorted(LASERS, key=lambda n: peaks[n])
    cut = (peaks[lo] + peaks[hi]) // 2
    return {lo: (0, cut), hi: (cut, h)}


def _ground_rows(rows: np.ndarray, h: int) -> np.ndarray:
    """Per column the row of the stripe on the bare ground. The ground is flat and the rail
    parallel to it, so the stripe on it keeps its row while objects pass under it for a part
    of the scan: per column the most frequent row over the frames, weighted by how many frames
    agree with it (an impression under a column for most of the scan spreads its rows), then a
    smooth curve across the columns (a line bent by the lens) fitted with outliers dropped."""
    k, w = rows.shape
    mode = np.full(w, np.nan)
    weight = np.zeros(w)
    finite = np.isfinite(rows)
    for c in range(w):
        v = rows[finite[:, c], c]
        if v.size < max(5, 0.1 * k):
            continue
        hist = np.bincount(np.clip(v, 0, h - 1).astype(int), minlength=h).astype(float)
        hist = np.convolve(hist, [1.0, 1.0, 1.0], mode="same")
        m = int(np.argmax(hist))
        near = v[np.abs(v - (m + 0.5)) <= 1.5]
        mode[c] = float(np.median(near)) if near.size else m + 0.5
        weight[c] = near.size / k
    ok = np.flatnonzero(np.isfinite(mode))
    if len(ok) < 0.2 * w:
        return mode
    # the ground's curve has the most (and best agreeing) columns: a plate under the middle
    # columns for most of the scan moves their most frequent row, not the outer columns'
    x = (np.arange(w) - w / 2) / (w / 2)
    rng = np.random.default_rng(0)
    best, best_score = None, -1.0
    for _ in range(200):
        pick = np.sort(rng.choice(ok, 3, replace=False))
        if min(np.diff(pick)) < 0.05 * w:
            continue
        coef = np.polyfit(x[pick], mode[pick], 2)
        inl = ok[np.abs(mode[ok] - np.polyval(coef, x[ok])) <= 1.5]
        score = float(weight[inl].sum())
        if score > best_score:
            best, best_score = inl, score
    keep = best if best is not None and len(best) >= 10 else ok
    coef = np.polyfit(x[keep], mode[keep], 3, w=weight[keep] + 1e-3)
    return np.polyval(coef, x)


def _fill_gaps(e: np.ndarray, max_gap: int) -> np.ndarray:
    """``e`` with NaN runs of at most ``max_gap`` columns between finite values interpolated."""
    e = e.copy()
    bad = ~np.isfinite(e)
    if not bad.any() or bad.all():
        return e
    idx = np.flatnonzero(bad)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    good = np.flatnonzero(~bad)
    for r in runs:
        if len(r) <= max_gap and r[0] > 0 and r[-1] < len(e) - 1:
            e[r] = np.interp(r, good, e[good])
    return e


def _plateaus(e: np.ndarray, jump: float, min_len: int) -> list[tuple[int, int, float]]:
    """Flat runs ``(first, stop, level)`` of a profile: breaks at missing columns and at jumps
    larger than ``jump`` between neighbouring (median-filtered) columns."""
    from scipy.ndimage import median_filter

    finite = np.isfinite(e)
    m = median_filter(np.where(finite, e, -1e6), size=5, mode="nearest")
    m[~finite] = np.nan
    brk = ~np.isfinite(m)
    d = np.abs(np.diff(m))
    cut = np.flatnonzero(~(d <= jump)) + 1  # NaN differences cut too
    edges = np.unique(np.concatenate([[0], cut, [len(e)]]))
    out: list[tuple[int, int, float]] = []
    gap = max(6, int(0.03 * len(e)))
    for a, b in zip(edges[:-1], edges[1:]):
        if b - a < min_len or brk[a:b].any():
            continue
        level = float(np.median(m[a:b]))
        if out and a - out[-1][1] <= gap and abs(level - out[-1][2]) <= max(jump, 0.05 * abs(level)):
            # one plateau broken by a few columns without stripe (dropouts, speckle)
            a0, b0, l0 = out[-1]
            out[-1] = (a0, int(b), (l0 * (b0 - a0) + level * (b - a)) / (b0 - a0 + b - a))
            continue
        out.append((int(a), int(b), level))
    return out


def _l_profiles(e: np.ndarray, floor: float, w: int) -> dict | None:
    """The widest L of one frame's displacement profile ``e`` (positive = raised): two
    adjacent flat plateaus at two different raised levels, each at least a fifth of their
    width, with no raised plateau next to them (the target's two top faces; the accuracy
    plates and steps show one level or more than two)."""
    min_len = max(4, int(0.015 * w))
    gap = max(6, int(0.02 * w))
    segs = _plateaus(_fill_gaps(e, 3), max(1.0, 0.5 * floor), min_len)
    best = None
    chain: list = []

    def close(ch):
        nonlocal best
        if len(ch) != 2:
            return
        (a0, b0, l0), (a1, b1, l1) = ch
        lo, hi = sorted((l0, l1))
        width = b1 - a0
        if lo < floor or lo > 0.85 * hi or hi - lo < floor:
            return
        if min(b0 - a0, b1 - a1) < 0.2 * width:
            return
        if best is None or width > best["width"]:
            best = {"a": a0, "j0": b0, "j1": a1, "b": b1, "width": width, "low": lo,
                    "high": hi, "high_right": l1 > l0}

    for s in segs:
        raised = s[2] >= floor
        if raised and chain and s[0] - chain[-1][1] <= gap:
            chain.append(s)
            continue
        if chain:
            # a raised neighbour just beyond a gap, or a plateau of ground: the chain ends
            close(chain)
        chain = [s] if raised else []
    if chain:
        close(chain)
    return best


def _face_across(e: np.ndarray, span: tuple[float, float], level: float, floor: float,
                 min_len: int) -> tuple[int, int] | None:
    """The plateau of one frame's profile ``e`` at a top face's ``level`` that covers (nearly)
    the face's whole ``span`` of columns, or None."""
    c0, c1 = span
    for a0, b0, l0 in _plateaus(_fill_gaps(e, 3), max(1.0, 0.5 * floor), min_len):
        if abs(l0 - level) <= 0.1 * level + 1.0 and min(b0, c1) - max(a0, c0) >= 0.9 * (c1 - c0):
            return a0, b0
    return None


def _off_face(e: np.ndarray, span: tuple[float, float], level: float) -> bool:
    """Does one frame's profile show the stripe over a face's columns, off the face's level?"""
    seg = e[int(span[0]):int(span[1])]
    seg = seg[np.isfinite(seg)]
    return seg.size >= 0.5 * (span[1] - span[0]) and abs(np.median(seg) - level) > 0.1 * level + 1


def _end_points(rows: np.ndarray, a0: int, b0: int) -> np.ndarray:
    """The stripe's two ends on a face: the mean column and median row of its first and last
    few columns found there (the outermost one may be missing), NaN when too few are found."""
    fin = a0 + np.flatnonzero(np.isfinite(rows[a0:b0]))
    n_in = max(2, (b0 - a0) // 8)
    if len(fin) < 2 * n_in:
        return np.full((2, 2), np.nan)
    return np.array([[fin[:n_in].mean() + 0.5, np.median(rows[fin[:n_in]])],
                     [fin[-n_in:].mean() + 0.5, np.median(rows[fin[-n_in:]])]])


def _l_runs(frames: np.ndarray, d: np.ndarray, floor: float, w: int) -> dict | None:
    """The longest and highest run of sampled frames showing the same L (either sign of the
    displacement): ``{"sign", "idx" (sample indices), "l" (their L's)}``."""
    best: dict | None = None
    for sign in (1.0, -1.0):
        found: list[dict] = [_l_profiles(sign * d[i], floor, w) or {} for i in range(len(frames))]
        # group consecutive samples with the same L (orientation, and levels within a tenth
        # of the run's: the top faces are level, the rail parallel to the ground; a stripe
        # sliding down a riser changes level from frame to frame) into runs
        runs: list[list[int]] = []
        for i, q in enumerate(found):
            if not q:
                continue
            if runs:
                hi = float(np.median([found[j]["high"] for j in runs[-1]]))
                lo = float(np.median([found[j]["low"] for j in runs[-1]]))
                if (i - runs[-1][-1] <= 3
                        and q["high_right"] == found[runs[-1][0]]["high_right"]
                        and abs(q["high"] - hi) <= 0.1 * hi + 1.0
                        and abs(q["low"] - lo) <= 0.15 * lo + 1.0):
                    runs[-1].append(i)
                    continue
            runs.append([i])
        for run in runs:
            if len(run) < 3:
                continue
            score = len(run) * float(np.median([found[i]["high"] for i in run]))
            if best is None or score > float(best["score"]):
                best = {"score": score, "sign": sign, "idx": run, "l": [found[i] for i in run]}
    return best


def _target_run(frames: np.ndarray, rows: np.ndarray, h: int, w: int) -> dict | None:
    """Where one laser's stripe lies on the L target, or None: the sampled frames in which it
    lies across both top faces, and per face the frames (and the stripe's ends) where the
    stripe enters and leaves it, with whether each is certain (the frames beyond show the
    stripe off the face) or open (at the video's first or last sample)."""
    base = _ground_rows(rows, h)
    if not np.isfinite(base).any():
        return None
    d = rows - base
    near = d[np.isfinite(d) & (np.abs(d) < 6.0)]
    noise = 1.4826 * float(np.median(np.abs(near))) if near.size else 1.0
    floor = max(1.5, 4.0 * noise)
    best = _l_runs(frames, d, floor, w)
    if best is None:
        return None
    widths = np.array([q["width"] for q in best["l"]])
    full = widths >= 0.85 * np.median(widths)
    idx = [i for i, f in zip(best["idx"], full) if f]
    ls = [q for q, f in zip(best["l"], full) if f]
    med = {key: float(np.median([q[key] for q in ls])) for key in ("a", "j0", "j1", "b")}
    right = ls[0]["high_right"]
    spans = {"low": (med["a"], med["j0"]) if right else (med["j1"], med["b"]),
             "high": (med["j1"], med["b"]) if right else (med["a"], med["j0"])}
    levels = {key: float(np.median([q[key] for q in ls])) for key in ("low", "high")}
    e = best["sign"] * d
    min_len = max(4, int(0.015 * w))
    n = len(frames)
    faces = {}
    for face, span in spans.items():
        # the frames in which the stripe lies across this face, contiguous with the L's run:
        # a face enters and leaves the stripe at its own time (the laser's plane is inclined)
        lvl = levels[face]
        first, last = idx[0], idx[-1]
        while first > 0 and _face_across(e[first - 1], span, lvl, floor, min_len):
            first -= 1
        while last < n - 1 and _face_across(e[last + 1], span, lvl, floor, min_len):
            last += 1
        ends = []
        for i in (first, last):
            a0, b0 = (_face_across(e[i], span, lvl, floor, min_len)
                      or (int(span[0]), int(span[1])))
            ends.append((int(frames[i]), _end_points(rows[i], a0, b0)))
        # an end shows where the target's edge is for certain when a frame just beyond it
        # shows the stripe at the face's columns off the face's level (not where the stripe
        # was not found)
        sure = (any(_off_face(e[i], span, lvl) for i in range(max(0, first - 4), first)),
                any(_off_face(e[i], span, lvl) for i in range(last + 1, min(n, last + 5))))
        faces[face] = {"ends": ends, "sure": sure, "open": (first == 0, last == n - 1)}
    return {"frames": frames[idx], "faces": faces, "sign": best["sign"],
            "low": levels["low"], "high": levels["high"]}


#: the rail accelerates and brakes at the ends of a scan: proposed frames keep this far (s)
#: from the video's first and last frame when they can (the calibration assumes the constant
#: speed between t1 and t2)
RAMP_GUARD_S = 0.6


def _choose_frames(runs: dict[str, dict], w: int, h: int,
                   usable: tuple[int, int] | None = None) -> dict[str, int]:
    """t1 (green) and t2 (red) inside their lasers' runs on the target: where the corners,
    predicted from the ends of each top face's stripe as the stripes enter and leave it, moved
    with the target's image velocity (from the delay between the two stripes), are well inside
    the picture and the stripe well inside the faces; of those the two frames furthest apart
    (the most parallax)."""
    g, r = runs["green"], runs["red"]
    # every observed edge of a face: (frame, its two corner points) per laser
    seen = []
    vel = []
    for face in ("low", "high"):
        for end in (0, 1):
            obs = [(run["faces"][face]["ends"][end], run["faces"][face]["sure"][end])
                   for run in (g, r) if not run["faces"][face]["open"][end]]
            obs = [((k, p), sure) for (k, p), sure in obs if np.isfinite(p).all()]
            seen += [o for o, _ in obs]
            if len(obs) == 2:
                (k0, p0), (k1, p1) = obs[0][0], obs[1][0]
                if abs(k1 - k0) >= 1:
                    vel.append(((p1 - p0).mean(axis=0) / float(k1 - k0),
                                obs[0][1] and obs[1][1]))
    # the velocity from edges seen on both sides (frames beyond them off the face) if any
    sure = [u for u, ok in vel if ok] or [u for u, _ in vel]
    v = np.median(sure, axis=0) if sure else None
    green_first = g["frames"][0] + g["frames"][-1] <= r["frames"][0] + r["frames"][-1]
    m_good = 0.08 * min(w, h)
    out = {}
    for key, run in (("t1", g), ("t2", r)):
        # the frames with the stripe across both faces (each over its whole width)
        f0 = max(int(run["frames"][0]), *(run["faces"][f]["ends"][0][0] for f in run["faces"]))
        f1 = min(int(run["frames"][-1]), *(run["faces"][f]["ends"][1][0] for f in run["faces"]))
        if f1 < f0:
            f0, f1 = int(run["frames"][0]), int(run["frames"][-1])
        ks = np.arange(f0, f1 + 1)
        frac = np.minimum(ks - f0, f1 - ks) / max(f1 - f0, 1)
        if v is None or not seen:
            score = np.minimum(frac / 0.3, 1.0)
        else:
            pts = np.concatenate([p[None] + (ks - k)[:, None, None] * v for k, p in seen],
                                 axis=1)
            margin = np.minimum.reduce([pts[..., 0].min(axis=1), w - pts[..., 0].max(axis=1),
                                        pts[..., 1].min(axis=1), h - pts[..., 1].max(axis=1)])
            score = np.minimum.reduce([margin / m_good, frac / 0.2, np.ones_like(frac)])
        if usable is not None:
            # frames in the rail's ramps only when nothing else shows the target
            score = np.where((ks >= usable[0]) & (ks <= usable[1]), score,
                             np.minimum(score, 0.0) - 1.0)
        top = np.flatnonzero(score >= score.max() - 1e-9)
        early = (key == "t1") == green_first
        out[key] = int(ks[top[0]] if early else ks[top[-1]])
    return out


def _propose_by_displacement(frames: np.ndarray, rows: dict[str, np.ndarray]) -> dict[str, int]:
    """The fallback when no L is recognised: the frames where each stripe is displaced furthest
    from its usual row (95th percentile per frame), a third and two thirds into their runs."""
    out = {}
    for key, name, where in (("t1", "green", 0.35), ("t2", "red", 0.65)):
        rr = rows[name]
        score = np.zeros(len(frames))
        for i, rw in enumerate(rr):
            if np.isfinite(rw).sum() >= 0.1 * len(rw):
                score[i] = float(np.nanpercentile(np.abs(rw - np.nanmedian(rw)), 95))
        if score.max() <= 2.0:
            raise CalibrationError(f"no frame shows the {name} stripe displaced by the target",
                                   code=codes.E_NO_TARGET)
        strong = np.flatnonzero(score >= 0.6 * score.max())
        runs = np.split(strong, np.flatnonzero(np.diff(strong) > 2) + 1)
        run = max(runs, key=lambda r: score[r].sum())
        out[key] = int(frames[run[int(round(where * (len(run) - 1)))]])
    return out


def propose_calibration_frames(video, sample_step: int | None = None,
                               progress: ProgressCallback | None = None,
                               cancel: CancelToken | None = None) -> dict[str, int]:
    """Frames where each laser's stripe lies across the L calibration target with all six
    corners in view: ``{"t1": green frame, "t2": red frame}``.

    Per sampled frame and laser, the stripe's displacement from its row on the bare ground
    (the most frequent row of each column over the scan) is cut into flat plateaus; the
    target's two top faces show as two adjacent plateaus at two raised levels and nothing
    raised beside them (the accuracy plates and steps show one level or more than two), and
    the run of frames showing that same L is where the stripe lies on the target. Where each
    stripe enters and leaves the target gives the image of the target's front and back edges,
    and the delay between the two stripes the target's motion in the picture (down or up,
    any roll), so the corners can be predicted in every frame: the frames are chosen where they
    are well inside the picture and the stripe well inside the faces, and as far apart as that
    allows (the leading stripe's frame is the earlier one). When no L is recognised, the frames
    where each stripe is displaced most are proposed. The user checks that all six corners are
    visible and adjusts."""
    cancel = cancel or CancelToken()
    n = video.frame_count
    step = sample_step or max(1, n // 400)
    frames, rows = _stripe_profiles(video, step, progress, cancel)
    h, w = video.read(0).shape[:2]
    guard = int(np.ceil(RAMP_GUARD_S * float(getattr(video, "fps", 0.0) or 30.0)))
    return propose_from_profiles(frames, rows, w, h, (guard, n - 1 - guard))


def propose_from_profiles(frames: np.ndarray, rows: dict[str, np.ndarray], w: int, h: int,
                          usable: tuple[int, int] | None = None) -> dict[str, int]:
    """:func:`propose_calibration_frames` from the stripes already found: ``rows[laser]`` is
    ``(len(frames), w)``, the stripe's row per sampled frame and column (NaN: none);
    ``usable``: the frames at constant speed (others only when nothing else will do)."""
    frames = np.asarray(frames)
    found = {name: _target_run(frames, np.asarray(rows[name], float), h, w) for name in LASERS}
    runs = {name: r for name, r in found.items() if r is not None}
    if len(runs) < len(LASERS):
        return _propose_by_displacement(frames, rows)
    return _choose_frames(runs, w, h, usable)


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
