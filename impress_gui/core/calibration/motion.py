"""The rail's ramps, seen in the picture itself: each frame's travel where the speed is not
yet (or no longer) constant.

The calibration takes the travel of frame ``k`` as the speed times its time from the
calibration frame. In the motor's acceleration ramp at the start of a scan (and its
deceleration at the end), and while the carriage still stands, that travel is wrong by up to
half the ramp's length: random rig 231 (a 0.43 s ramp at 28 mm/s) has frame 0 placed 6.0 mm
off. Calibration frames are often picked just after the ramp (the simulator's are, as a lab's
may be: the target at the start of the scan), and the stripe frames gathered around a pick
reach into it; a calibration frame picked inside the ramp puts every travel off.

The whole picture moves with the carriage, so its shift over a fixed lag (about 0.2 s,
longer where the picture moves slowly) measures the carriage's travel over that lag up to a
scale: the luma at half resolution (the laser stripes, which stand still in the picture,
blanked by their colour) is matched by phase correlation between each frame and the one a
lag later. Each shift is measured on its own (no chaining: nothing adds up), and a model of
rest, constant acceleration and constant speed fitted to them, with the shifts that disagree
left out, gives the ramp's start and length (its mirror at the end). Each frame then gets the
time at which a carriage at constant speed throughout would have the same travel
(:meth:`Ramps.travel_times`); frames at constant speed keep their own. A fit that does not
explain the shifts leaves that end as before.

On 22 random rigs at 1080p (44 ends), 42 ramps were measured; in 39 of them every frame's
corrected travel is within 0.1 mm of the truth, in the other three within 0.18 mm (rigs 217,
231, 236), where uncorrected it was 1.1-6.0 mm off. Two ends were left as before (rig 9's
last frames: no fit; rig 212's: a ramp too short to be one, :data:`MIN_RAMP_FRAMES`).
Shifts across the motion (failed matches) are left out of the fit and no residual counts for
more than :data:`RESIDUAL_CAP_PX` (random rig 0's start: frame 0's travel 6.4 -> 0.06 mm off;
the 36 other rigs cached at 1080p measured the same ramps as before, to 0.1 frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from impress_gui.core.base.progress import CancelToken

#: how much of each end of the video is searched for a ramp (s; the simulator's ramps last
#: 0.15-0.45 s, and the window must hold some constant speed after the ramp to fit it)
SEARCH_S = 1.5
#: the lag between the frames matched (s; at least two frames)
LAG_S = 0.2
#: the shift at constant speed over the lag (px at half size) below which the lag is
#: lengthened to reach it
MIN_SHIFT_PX = 6.0
#: colour saturation (CbCr distance from grey) above which a pixel is taken as a laser
#: stripe's light and blanked before matching (the stripes stand still in the picture)
STRIPE_SATURATION = 40.0
#: the model must explain this share of the positions' variance to be believed
MIN_R2 = 0.9
#: and the carriage must move at least this much per frame in the picture (px at half size)
MIN_SPEED_PX = 0.25
#: a frame whose travel the ramp's model moves by less than this (frames) keeps its own: the
#: model's error near the ramp's end is as large (random rig 236: frame 6, just past the
#: ramp's end at 5.04, would have moved 0.055 frame and the exact picks there 0.02 px)
MIN_CORRECTION = 0.1
#: a fitted ramp shorter than this (frames) is no ramp a motor makes but a picture that stops
#: showing the motion (random rig 212's last frames: soil streaked along the scan, read as a
#: carriage at rest for 22 frames); its travel would be off by more than the ramp's own
MIN_RAMP_FRAMES = 2.0
#: a shift more than this (px at half size) across the motion's direction is a failed match,
#: left out of the fit: the picture moves along the motion only (random rig 0: 15 of the first
#: 25 lags matched something still, about 1 px across and nothing along, and the fit took the
#: carriage for resting 20 frames; the matches that held lie within 0.25 px of the direction)
MAX_ACROSS_PX = 0.5
#: the ramp's fit counts no shift's residual as more than this (px at half size)
RESIDUAL_CAP_PX = 1.0


@dataclass(frozen=True)
class Ramps:
    """The ramps measured at the video's ends: ``start`` = (a, b), the carriage at rest until
    frame ``a`` and accelerating until ``a + b``; ``end`` the same counted backwards from the
    last frame (None: that end not measured or no believable ramp there)."""

    frame_count: int
    start: tuple[float, float] | None = None
    end: tuple[float, float] | None = None

    @property
    def constant_from(self) -> float:
        """The first moment (frames) of constant speed."""
        return 0.0 if self.start is None else max(0.0, self.start[0] + self.start[1])

    @property
    def constant_until(self) -> float:
        """The last moment (frames) of constant speed."""
        last = self.frame_count - 1.0
        return last if self.end is None else last - max(0.0, self.end[0] + self.end[1])

    def at_constant_speed(self, k: int) -> bool:
        """Frame ``k``'s travel is the constant speed's (within :data:`MIN_CORRECTION`)."""
        return bool(self.travel_frames()[k] == k)

    def travel_frames(self) -> np.ndarray:
        """Per frame, the frame number a carriage at constant speed throughout would have at
        the same travel (the frame's own number at constant speed, and where the ramp's
        model moves it by less than :data:`MIN_CORRECTION` of a frame: near the ramp's end
        the model's own error is as large)."""
        k = np.arange(self.frame_count, dtype=float)
        eff = k.copy()
        if self.start is not None:
            a, b = self.start
            # at constant speed _ramp_curve(k) = k - a - b/2
            eff = np.where(k < a + b, _ramp_curve(k, a, b) + a + b / 2, eff)
        if self.end is not None:
            a, b = self.end
            kb = (self.frame_count - 1.0) - k
            eff = np.where(kb < a + b, k + (kb - (_ramp_curve(kb, a, b) + a + b / 2)), eff)
        return np.where(np.abs(eff - k) >= MIN_CORRECTION, eff, k)

    def travel_times(self, times_s: np.ndarray, fps: float) -> np.ndarray:
        """``times_s`` with each frame in a ramp moved to the time of its travel at constant
        speed (frames at constant speed unchanged)."""
        times = np.asarray(times_s, float)
        return times + (self.travel_frames() - np.arange(len(times))) / float(fps)


def _luma(planes) -> np.ndarray:
    """The frame's luma at half size with the laser stripes' pixels (strongly coloured,
    dilated and softened) set to the frame's median: what moves with the carriage."""
    import cv2

    y = np.asarray(planes.y, np.float32)
    size = (y.shape[1] // 2, y.shape[0] // 2)
    g = cv2.resize(y, size, interpolation=cv2.INTER_AREA)
    chroma = []
    for c in (planes.cb, planes.cr):
        c = np.asarray(c, np.float32)
        chroma.append(c if c.shape[:2] == g.shape
                      else np.asarray(cv2.resize(c, size, interpolation=cv2.INTER_AREA)))
    stripe = (np.hypot(chroma[0] - 128, chroma[1] - 128) > STRIPE_SATURATION)
    soft = np.asarray(cv2.GaussianBlur(
        cv2.dilate(stripe.astype(np.float32), np.ones((7, 7), np.uint8)), (0, 0), 3))
    return np.asarray(g * (1 - soft) + float(np.median(g)) * soft, np.float32)


def lag_shifts(video, start: int, stop: int, lag: int,
               cancel: CancelToken | None = None) -> np.ndarray:
    """The picture's shift (px at half size, ``(n, 2)``) from frame ``k`` to ``k + lag``
    for ``k = start .. stop - 1 - lag``."""
    import cv2

    cancel = cancel or CancelToken()
    window = None
    held: list[np.ndarray] = []
    out = []
    for _, planes in video.iter_planes(start, stop):
        cancel.check()
        g = _luma(planes)
        if window is None:
            window = cv2.createHanningWindow((g.shape[1], g.shape[0]), cv2.CV_32F)
        held.append(g)
        if len(held) > lag:
            (dx, dy), _ = cv2.phaseCorrelate(held.pop(0), g, window)
            out.append((dx, dy))
    return np.array(out, float).reshape(-1, 2)


def _ramp_curve(t: np.ndarray, a: np.ndarray | float, b: np.ndarray | float) -> np.ndarray:
    """Position at times ``t`` (frames) of a carriage at rest until ``a``, accelerating
    uniformly until ``a + b`` and at unit speed after (``a``, ``b`` broadcast)."""
    tt = t - a
    bb = np.maximum(b, 1e-9)
    return np.where(tt < 0, 0.0, np.where(tt < b, tt**2 / (2 * bb), b / 2 + (tt - b)))


def _fit_ramp(d: np.ndarray, lag: int, valid: np.ndarray | None = None
              ) -> tuple[float, float, float, float]:
    """Fit the shifts ``d[k] ~ v * (G(k + lag) - G(k))``, ``G = _ramp_curve(., a, b)``,
    leaving out the shifts far off the fit (twice refitted) and those not ``valid``:
    ``(a, b, v, r2)``."""
    k = len(d)
    t = np.arange(k, dtype=float)
    valid = np.ones(k, bool) if valid is None else np.asarray(valid, bool)
    keep = valid.copy()

    def search(a_vals, b_vals):
        a, b = np.meshgrid(a_vals, b_vals, indexing="ij")
        h = (_ramp_curve(t + lag, a[..., None], b[..., None])
             - _ramp_curve(t, a[..., None], b[..., None]))
        hh = (h * h * keep).sum(axis=-1)
        v = (h * d * keep).sum(axis=-1) / np.maximum(hh, 1e-12)
        # each shift's square residual capped: one failed match the across-test let through
        # (rig 0's second lag, 0.2 px for 3.5) must not outweigh the ramp's shifts
        cost = (np.minimum((d - v[..., None] * h) ** 2, RESIDUAL_CAP_PX**2)
                * keep).sum(axis=-1)
        cost = np.where(v > 0, cost, np.inf)
        i = np.unravel_index(int(np.argmin(cost)), cost.shape)
        return float(a[i]), float(b[i]), float(v[i]), float(cost[i])

    for fit in range(3):
        a, b, _, _ = search(np.arange(-3.0, k, 0.25), np.arange(0.0, k, 0.25))
        a, b, v, cost = search(np.arange(a - 0.3, a + 0.31, 0.02),
                               np.arange(max(0.0, b - 0.3), b + 0.31, 0.02))
        if fit == 2:
            break  # the share explained below is of the shifts this fit used
        res = d - v * (_ramp_curve(t + lag, a, b) - _ramp_curve(t, a, b))
        spread = 1.4826 * float(np.median(np.abs(res[keep]))) + 1e-6
        keep = valid & (np.abs(res) <= max(4 * spread, 0.2))
    total = float(((d[keep] - d[keep].mean()) ** 2).sum())
    return a, b, v, (1.0 - cost / total) if total > 0 else 0.0


def _ramp_fit(shifts: np.ndarray, lag: int) -> tuple[float, float] | None:
    """The ramp ``(a, b)`` (frames from the first shift's first frame), or None when the
    shifts show no believable ramp and run (no motion, no texture, no fit)."""
    if len(shifts) < 8:
        return None
    mag = np.hypot(shifts[:, 0], shifts[:, 1])
    direction = np.median(shifts[np.argsort(-mag)[:5]], axis=0)
    if np.hypot(*direction) < 0.5:
        return None
    u = direction / np.hypot(*direction)
    d = shifts @ u
    valid = np.abs(shifts @ np.array([-u[1], u[0]])) <= MAX_ACROSS_PX
    if valid.sum() < 8:
        return None
    a, b, v, r2 = _fit_ramp(d, lag, valid)
    if r2 < MIN_R2 or v < MIN_SPEED_PX or a + b > len(d) - 5 or b < MIN_RAMP_FRAMES:
        return None
    return a, b


def measure_ramps(video, fps: float, cancel: CancelToken | None = None,
                  ends: tuple[bool, bool] = (True, True)) -> Ramps:
    """The ramps at the ends of ``video`` (``ends``: which to measure), from the picture's
    motion in the first and last :data:`SEARCH_S` seconds."""
    n = video.frame_count
    k = int(min(np.ceil(SEARCH_S * fps), n // 3))
    lag = max(2, int(round(LAG_S * fps)))

    def measure(a: int, b: int, backwards: bool) -> tuple[float, float] | None:
        d = lag_shifts(video, a, b, lag, cancel)
        # a slow picture is matched over a longer lag: shifts of a few pixels lock towards
        # whole pixels (judged by the constant speed at the window's far end)
        tail = np.hypot(*(d[:5] if backwards else d[-5:]).T)
        shift = float(np.median(tail)) if len(tail) else 0.0
        used = lag
        if 0 < shift < MIN_SHIFT_PX:
            longer = min(int(np.ceil(lag * MIN_SHIFT_PX / shift)), (b - a - 8) // 2)
            if longer > lag:
                d, used = lag_shifts(video, a, b, longer, cancel), longer
        # the end read forwards, its shifts taken backwards: a start ramp in reversed time
        return _ramp_fit(d[::-1] if backwards else d, used)

    start = measure(0, k + 1, False) if ends[0] and k >= 8 + lag else None
    end = measure(n - 1 - k, n, True) if ends[1] and k >= 8 + lag else None
    ramps = Ramps(n, start, end)
    if ramps.constant_until < ramps.constant_from:
        return Ramps(n)
    return ramps
