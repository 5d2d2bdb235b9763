"""The rail's ramps found in the picture's motion (:mod:`impress_gui.core.calibration.motion`),
and the stripe frames kept out of them (:func:`~impress_gui.core.calibration.planes.stripe_window`).

Synthetic videos: a textured ground translated with a known profile of rest, constant
acceleration, constant speed and deceleration (sub-pixel, by an affine warp), with a green
laser line that stands still in the picture as a real stripe does."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from impress_gui.core.calibration import motion
from impress_gui.core.calibration.planes import stripe_window
from impress_gui.core.formats.video import VideoSource

W, H, FPS = 640, 360, 25.0


def _travel(t: np.ndarray, rest: float, ramp: float, speed: float, total: float) -> np.ndarray:
    """Position (px) at frame times ``t``: at rest until ``rest``, a ramp of ``ramp`` frames
    up to ``speed`` px/frame, constant speed, and the mirror ramp ending at ``total``."""
    def up(tt):
        tt = np.asarray(tt, float) - rest
        return np.where(tt < 0, 0.0, np.where(tt < ramp, speed * tt**2 / (2 * ramp),
                                              speed * (ramp / 2 + tt - ramp)))
    end = total - rest  # the deceleration mirrors the start about the middle
    return np.where(t <= (rest + end) / 2, up(t), 2 * up((rest + end) / 2) - up(rest + end - t))


class _Synthetic(VideoSource):
    def __init__(self, positions: np.ndarray, stripe: bool = True, seed: int = 3):
        rng = np.random.default_rng(seed)
        span = int(np.ceil(positions.max())) + H + 8
        ground = cv2.GaussianBlur(rng.uniform(40, 200, (span, W + 16)).astype(np.float32),
                                  (0, 0), 1.6)
        self.ground, self.positions, self.stripe = ground, positions, stripe
        self.size, self.fps = (W, H), FPS
        self.times_s = np.arange(len(positions)) / FPS

    def read(self, k: int) -> np.ndarray:
        m = np.float32([[1, 0, -8], [0, 1, -4 - self.positions[k]]])
        g = cv2.warpAffine(self.ground, m, (W, H), flags=cv2.INTER_CUBIC)
        rgb = np.repeat(np.clip(g, 0, 255)[..., None], 3, axis=2).astype(np.uint8)
        if self.stripe:
            rgb[178:183, :] = (30, 250, 40)  # a laser line, still in the picture
        return rgb

    def iter_frames(self, start: int = 0, stop: int | None = None):
        for k in range(start, len(self.positions) if stop is None else stop):
            yield k, self.read(k)


@pytest.mark.parametrize("rest, ramp, speed", [(0.0, 9.6, 1.6), (4.0, 6.3, 3.1),
                                               (0.0, 11.2, 0.9)])
def test_the_ramps_are_found_where_they_are(rest, ramp, speed):
    n = 150
    t = np.arange(n, dtype=float)
    truth = _travel(t, rest, ramp, speed, n - 1.0)
    ramps = motion.measure_ramps(_Synthetic(truth), FPS)
    assert ramps.constant_from == pytest.approx(rest + ramp, abs=2.0)
    assert ramps.constant_until == pytest.approx((n - 1.0) - rest - ramp, abs=2.0)
    # each frame's travel at constant speed: the true travel within half a frame's worth of
    # travel in every moving frame, ramps included (measured 0.22-0.42 on these small
    # synthetic pictures; uncorrected: 2.2-5.6 frames' worth)
    eff = ramps.travel_frames()
    k0 = int(np.ceil(rest + ramp)) + 1
    line = truth[k0] + speed * (eff - k0)  # the travel the corrected frame numbers imply
    moving = (t > rest + 0.5) & (t < n - 1 - rest - 0.5)
    assert np.max(np.abs(line - truth)[moving]) < 0.5 * speed
    assert np.max(np.abs(truth[k0] + speed * (t - k0) - truth)[moving]) > 2.0 * speed
    assert np.array_equal(eff[k0 + 2 : n - k0 - 2], t[k0 + 2 : n - k0 - 2])


def test_the_still_stripe_does_not_change_the_ramp():
    """The stripe is blanked: the same frames with and without a stripe give the same ramp."""
    n = 120
    pos = _travel(np.arange(n, dtype=float), 0.0, 8.0, 2.0, n - 1.0)
    with_line = motion.measure_ramps(_Synthetic(pos, stripe=True), FPS)
    without = motion.measure_ramps(_Synthetic(pos, stripe=False), FPS)
    assert with_line.constant_from == pytest.approx(without.constant_from, abs=0.7)


def test_no_motion_or_only_ramp_leaves_the_times_as_they_are():
    n = 120
    times = np.arange(n) / FPS
    still = motion.measure_ramps(_Synthetic(np.zeros(n)), FPS)
    assert still.start is None and still.end is None
    assert np.array_equal(still.travel_times(times, FPS), times)
    # accelerating through the whole search window: no constant speed seen, nothing moved
    t = np.arange(n, dtype=float)
    slow = motion.measure_ramps(_Synthetic(_travel(t, 0.0, 59.0, 1.5, n - 1.0)), FPS)
    assert slow.start is None and slow.constant_from == 0.0


def test_only_the_ends_asked_for_are_measured():
    n = 120
    pos = _travel(np.arange(n, dtype=float), 0.0, 8.0, 2.0, n - 1.0)
    ramps = motion.measure_ramps(_Synthetic(pos), FPS, ends=(True, False))
    assert ramps.start is not None and ramps.end is None
    assert ramps.constant_until == n - 1
    eff = ramps.travel_frames()
    assert np.array_equal(eff[60:], np.arange(60, n))


def test_failed_matches_do_not_make_the_carriage_rest():
    """Random rig 0 at 1080p (a 20.4-frame ramp from rest at frame 0, a 10-frame lag): 13 of
    the first 25 lags matched something still in the picture - about 1 px across the motion
    and nothing along it - and one more gave 0.2 px along for 3.5. The fit took the carriage
    for resting 20 frames and ramping 9 (calibration frame 21's travel 1.6 mm off, the
    implied speed 1.9 % high, corner residuals 0.97 mm). Shifts across the motion are left
    out and no residual counts for more than 1 px: the ramp is found where it is."""
    lag, ramp, speed = 10, 20.4, 1.215  # px per frame at constant speed, at half size
    k = np.arange(76, dtype=float)
    along = speed * (motion._ramp_curve(k + lag, 0.0, ramp) - motion._ramp_curve(k, 0.0, ramp))
    shifts = np.column_stack([np.random.default_rng(1).normal(0, 0.04, k.size), along])
    failed = [7, 9, 10, 11, 12, 13, 14, 15, 16, 17, 21, 22, 24]
    shifts[failed] = np.column_stack([np.linspace(-0.7, -1.2, len(failed)),
                                      np.full(len(failed), 0.05)])
    shifts[1] = (-0.245, 0.222)  # along the motion's direction enough to pass the test
    a, b = motion._ramp_fit(shifts, lag)
    assert a == pytest.approx(0.0, abs=0.5) and a + b == pytest.approx(ramp, abs=0.5)
    # without the failed matches the same ramp (the tests above: the fit is unchanged there)
    clean = np.column_stack([np.zeros(k.size), along])
    a0, b0 = motion._ramp_fit(clean, lag)
    assert (a0, a0 + b0) == pytest.approx((0.0, ramp), abs=0.1)


def test_the_stripe_window():
    # 25 mm at 20 mm/s and 25 fps: 31 frames either side, within the video
    assert stripe_window(11, 20.0, 25.0, 300, 25.0, 300) == (0, 43)
    assert stripe_window(100, 20.0, 25.0, 300, 25.0, 300) == (69, 132)
    assert stripe_window(100, 20.0, 25.0, 10, 25.0, 300) == (90, 111)


@pytest.fixture(scope="module")
def rig229_pick_in_ramp(tmp_path_factory):
    """Random rig 229 at 640x360 (a 0.42 s ramp: frames 0-10.6) with green's calibration frame
    at frame 5, inside the ramp, and the simulator's exact picks there."""
    from impress_gui.sim import simulate as SIM

    out = tmp_path_factory.mktemp("rig229") / "scan"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(SIM, "calibration_frames", lambda *a: (5, 96))
        SIM.simulate(SIM.SimConfig.random(229, 640, 360, grid_mm=0.2), out, workers=1)
    return out


def _calibrate(scan):
    import json

    from impress_gui.core.calibration.geometry import Intrinsics
    from impress_gui.core.calibration.picks import Picks
    from impress_gui.core.calibration.scene import calibrate_scene
    from impress_gui.core.calibration.target import TargetModel
    from impress_gui.core.formats.video import open_video

    truth = json.loads((scan / "truth.json").read_text())
    with open_video(scan / "scan.mp4") as v:
        cal = calibrate_scene(v, Intrinsics.load(scan / "intrinsics.json"),
                              TargetModel.load(scan / "target.json"),
                              Picks.load(scan / "picks.json"), truth["speed_mm_s"])
    return cal, truth


def test_a_calibration_frame_in_the_ramp_gets_its_travel_from_the_picture(
        rig229_pick_in_ramp, monkeypatch):
    """Frame 5 is 2.3 mm short of where the constant speed would put it: with its travel from
    the picture's motion the target's two views imply the true speed (measured 20.631 mm/s,
    truth 20.624) and the user is told the frame lies in the ramp; taken at constant speed
    (the former calibration) they implied 20.288 mm/s, 1.6 % off, and the user was told to
    check a speed setting that was right."""
    cal, truth = _calibrate(rig229_pick_in_ramp)
    assert cal.implied_speed_mm_s == pytest.approx(truth["speed_mm_s"], rel=0.002)
    assert any(w.startswith("W-PICK-IN-RAMP: calibration frame 5 (t1)") for w in cal.warnings)
    assert not any(w.startswith("W-SPEED-MISMATCH") for w in cal.warnings)
    assert cal.t_ref_s > 5 / truth["fps"]  # frame 5's travel lies later at constant speed

    monkeypatch.setattr(motion, "measure_ramps",
                        lambda video, fps, cancel=None, ends=(True, True):
                        motion.Ramps(video.frame_count))
    former, _ = _calibrate(rig229_pick_in_ramp)
    assert abs(former.implied_speed_mm_s / truth["speed_mm_s"] - 1) > 0.01
    assert any(w.startswith("W-SPEED-MISMATCH") for w in former.warnings)
