"""The tilt refinement by the stripes (issue 18): stray light on the target does not turn it."""

from dataclasses import replace

import numpy as np
import pytest

from impress_gui.core.calibration import planes as P
from impress_gui.core.calibration import uncertainty as CU
from impress_gui.core.calibration.geometry import ideal_rotation
from impress_gui.core.calibration.scene import SceneCalibration
from impress_gui.core.calibration.solve import solve_pose
from impress_gui.core.calibration.target import TargetModel
from impress_gui.sim import simulate as SIM

#: the picks' tilt is started this far off (deg): 0.5 px of click noise does this on random rigs
START_OFF_DEG = 3.0
#: share of the red stripe's rays replaced by stray light, and how far (px) it lies off the stripe
STRAY_SHARE, STRAY_PX = 0.08, 12.0


def _with_stray_light(obs: P.StripeObservations, rng) -> P.StripeObservations:
    """The red stripe with a share of its rays moved a dozen rows off (light of another object
    or a reflection beside the stripe: points on the faces far from the laser plane)."""
    rays = dict(obs.rays)
    moved = []
    for k, dt, r in rays["red"]:
        r = r.copy()
        pick = rng.random(len(r)) < STRAY_SHARE
        r[pick, 1] += STRAY_PX / 500.0 * rng.choice([-1.0, 1.0], pick.sum())
        moved.append((k, dt, r))
    rays["red"] = moved
    return replace(obs, rays=rays)


@pytest.fixture(scope="module")
def setup(flat_scan, flat_calibration):
    cal = SceneCalibration.load(flat_calibration)
    target = TargetModel.load(flat_scan / "target.json")
    picks = CU.model_picks(cal, target)
    # 15 of the calibration's frames per laser, as the calibration took before 2026-12-05
    # (more frames average the stray light down: with 45 the plain fit is turned 0.0013 deg)
    segs = {}
    for la in CU.LASERS:
        frames = sorted(cal.planes[la].frames)
        kept = {frames[i] for i in np.linspace(0, len(frames) - 1, 15).round().astype(int)}
        segs[la] = [s for s in CU._segments(cal, target, la) if s[0] in kept]
    rng = np.random.default_rng(18)
    clean = CU._observations(cal, target, segs, rng, {la: 0.02 for la in CU.LASERS},
                             model="conservative")  # 0.02 mm per point, no face offsets
    dt = (cal.t2 - cal.t1) / cal.fps
    pose = solve_pose(cal.intrinsics, target, picks, cal.speed_mm_s, dt)
    return cal, target, picks, clean, _with_stray_light(clean, rng), pose, dt


def _refined_tilt(setup, obs) -> float:
    cal, target, picks, _, _, pose, dt = setup
    tilt0 = pose.tilt_rad + np.radians(START_OFF_DEG)
    start = replace(pose, tilt_rad=tilt0, rotation=ideal_rotation(pose.roll_rad, tilt0))
    fits = obs.fit_planes(start.rotation, (start.target_rotation, start.target_translation_mm))
    out = P.refine_tilt(obs, fits, cal.intrinsics, target, picks, start, cal.speed_mm_s, dt, 0.3)
    return float(np.degrees(out.tilt_rad))


def test_stray_light_on_the_target_does_not_turn_the_tilt(setup, monkeypatch):
    """From a start 3 deg off, the tilt found with 8 % of the red stripe's points a dozen rows
    off is within 0.003 deg of the tilt found without them; the plain plane fit the refinement
    used before (every point in the plane) is turned by them more than twice as far (measured
    0.0002 against 0.021 deg; 0.0007 against 0.014 deg since 2026-12-05, the calibration's
    frames chosen from 45)."""
    reference = _refined_tilt(setup, setup[3])
    assert abs(reference - np.degrees(setup[5].tilt_rad)) < 0.05  # the clean stripes find it
    robust = abs(_refined_tilt(setup, setup[4]) - reference)
    monkeypatch.setattr(P, "GROSS_OUTLIER_MM", np.inf)  # every point kept: the former fit
    plain = abs(_refined_tilt(setup, setup[4]) - reference)
    print(f"tilt off by the stray light: robust {robust:.4f}, plain {plain:.4f} deg")
    assert robust < 0.003
    assert plain > 0.008


def test_stripes_gathered_again_after_a_large_tilt_change_progress_runs_forward(flat_scan):
    """With 1 px clicks the picks' tilt is degrees off; the refinement moves it by more than
    REGATHER_TILT_DEG, the stripes are gathered again with the refined pose (said in the
    progress), and the progress never runs backwards while they are."""
    import json

    from impress_gui.core.calibration.geometry import Intrinsics
    from impress_gui.core.calibration.picks import Picks
    from impress_gui.core.calibration.scene import calibrate_scene
    from impress_gui.core.formats.video import open_video

    truth = json.loads((flat_scan / "truth.json").read_text())
    picks = Picks.load(flat_scan / "picks.json")
    rng = np.random.default_rng(0)
    noisy = [{c: tuple(np.add(p, rng.normal(0, 1.0, 2))) for c, p in d.items()}
             for d in (picks.corners_t1, picks.corners_t2)]
    picks = Picks(picks.video, picks.t1, picks.t2, *noisy)
    seen: list[tuple[float, str]] = []
    with open_video(flat_scan / "scan.mp4") as v:
        cal = calibrate_scene(v, Intrinsics.load(flat_scan / "intrinsics.json"),
                              TargetModel.load(flat_scan / "target.json"), picks,
                              truth["speed_mm_s"], progress=lambda f, m: seen.append((f, m)))
    assert any("gathered again" in m for _, m in seen)
    fractions = [f for f, _ in seen]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    # measured 0.21 deg (the picks' target pose carries the clicks' error; docs/accuracy.md)
    assert abs(cal.tilt_deg - truth["tilt_deg"]) < 0.5


#: the calibration frames (t1, t2) the simulator chose for rigs 21 and 28 before 2026-12-04
#: (green's first and red's last frame on the target also where red leads: the closest pair,
#: not the farthest): the cases below were found, and are kept, with these picks (rig 28's red
#: frames around 71 include frame 84, where the red detector takes green's light)
FORMER_FRAMES = {21: (91, 106), 28: (97, 71)}

#: random rig 21 at 640x360 with 0.5 px clicks (the benchmarks' draw 2, noise seed 21003): the
#: red stripe's points on the target include gross outliers (plain plane RMS 2.1-2.7 mm). The
#: two random rigs here are rendered on a 0.2 mm scene grid (the benchmarks' 0.1 mm: twice the
#: render time); each case was checked to reproduce on it (figures in the tests' docstrings)
RIG, DRAW_SEED, CLICK_PX = 21, 21003, 0.5


@pytest.fixture(scope="module")
def rig21(tmp_path_factory):
    from impress_gui.sim.simulate import SimConfig, simulate

    out = tmp_path_factory.mktemp("rig21") / "scan"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(SIM, "calibration_frames", lambda *a: FORMER_FRAMES[RIG])
        simulate(SimConfig.random(RIG, 640, 360, grid_mm=0.2), out, workers=1)
    return out


def _calibrate_noisy(scan, click_px: float = CLICK_PX):
    """The scan calibrated from its exact picks plus ``click_px`` of click noise (0: exact)."""
    import json

    from impress_gui.core.calibration.geometry import Intrinsics
    from impress_gui.core.calibration.picks import Picks
    from impress_gui.core.calibration.scene import calibrate_scene
    from impress_gui.core.formats.video import open_video

    truth = json.loads((scan / "truth.json").read_text())
    picks = Picks.load(scan / "picks.json")
    rng = np.random.default_rng(DRAW_SEED)  # as benchmarks/common.calibrate draws them
    noisy = [{c: tuple(np.add(v, rng.normal(0, click_px, 2))) for c, v in d.items()}
             for d in (picks.corners_t1, picks.corners_t2)]
    with open_video(scan / "scan.mp4") as v:
        cal = calibrate_scene(v, Intrinsics.load(scan / "intrinsics.json"),
                              TargetModel.load(scan / "target.json"),
                              Picks(picks.video, picks.t1, picks.t2, *noisy),
                              truth["speed_mm_s"])
    return cal, truth


def _height_errors(scan, cal) -> float:
    """Median |height error| (mm) of a grid of points (x -60..60, y 0..120, h -10..+20 mm)
    reconstructed by ``cal`` from either laser and taken through the simulator's true
    calibration (the worse laser)."""
    from impress_gui.core.calibration.uncertainty import CalParams, map_points
    from impress_gui.sim.truth import true_cal_params

    x, y = (a.ravel() for a in np.meshgrid(np.linspace(-60, 60, 20), np.linspace(0, 120, 20)))
    h = np.resize(np.linspace(-10.0, 20.0, 7), x.size)
    nominal, true = CalParams.of_calibration(cal), true_cal_params(scan, cal)
    return max(float(np.nanmedian(np.abs(map_points(nominal, true, x, y, h, la)[2][0] - h)))
               for la in ("green", "red"))


def test_stray_stripe_light_on_a_random_rig_does_not_spoil_the_heights(rig21, monkeypatch):
    """Rig 21, 0.5 px clicks: the heights from the calibration are within 0.1 mm (measured
    0.044 mm, tilt 0.58 deg off, on the 0.1 mm scene grid; 0.019 mm, tilt 0.60 deg off, on this
    test's 0.2 mm grid); with every stripe point in the refinement's planes and no second
    gathering (the former refinement) they were millimetres off (3.5 mm, tilt 2.6 deg off)."""
    cal, truth = _calibrate_noisy(rig21)
    now = _height_errors(rig21, cal)
    tilt_now = abs(cal.tilt_deg - truth["tilt_deg"])
    from impress_gui.core.calibration import scene as S

    monkeypatch.setattr(P, "GROSS_OUTLIER_MM", np.inf)
    monkeypatch.setattr(S, "REGATHER_TILT_DEG", np.inf)
    before_cal, _ = _calibrate_noisy(rig21)
    before = _height_errors(rig21, before_cal)
    print(f"rig 21 draw 2: median height error {now:.4f} mm (tilt {tilt_now:.3f} deg); "
          f"former refinement {before:.4f} mm "
          f"(tilt {abs(before_cal.tilt_deg - truth['tilt_deg']):.3f} deg)")
    assert now < 0.1 and tilt_now < 1.0
    assert before > 0.5



@pytest.fixture(scope="module")
def rig28(tmp_path_factory):
    from impress_gui.sim.simulate import SimConfig, simulate

    out = tmp_path_factory.mktemp("rig28") / "scan"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(SIM, "calibration_frames", lambda *a: FORMER_FRAMES[28])
        simulate(SimConfig.random(28, 640, 360, grid_mm=0.2), out, workers=1)
    return out


def test_the_other_lasers_light_in_one_frame_does_not_turn_a_plane(rig28, monkeypatch):
    """Random rig 28 at 640x360, exact picks (a rig no benchmark had rendered before it was
    tried): the green stripe blooms, and in one of the red frames (frame 84) the red detector
    takes green's light on the high face for red - 18 of its 32 points lie 70 mm off the red
    plane. They turned the plain plane fit (the red plane 64 deg off, RMS 5.9 mm; the tilt
    refined 2.8 deg off, fused heights 9 mm off, no warning). The robust fit starts from the
    frame whose own plane leaves the other frames' points nearest (FRAME_START_GAIN), and
    green's light on the ground is left out of red's: plane RMS 0.038 / 0.043 mm, tilt 0.032
    deg off, median height error 0.086 mm (measured on the 0.1 mm scene grid; on this test's
    0.2 mm grid 0.040 / 0.041 mm, 0.006 deg, 0.045 mm). Without that start the calibration now
    refuses (E-CALIB: a plane's RMS above PLANE_REFUSE_MM) rather than pass it silently."""
    from impress_gui.core.base.errors import CalibrationError

    def calibrate():
        return _calibrate_noisy(rig28, click_px=0.0)

    cal, truth = calibrate()
    err = _height_errors(rig28, cal)
    tilt = abs(cal.tilt_deg - truth["tilt_deg"])
    rms = [round(cal.planes[la].rms_mm, 4) for la in ("green", "red")]
    print(f"rig 28: tilt {tilt:.4f} deg off; plane RMS {rms} mm; median height error "
          f"{err:.4f} mm")
    assert tilt < 0.1 and max(rms) < 0.06 and err < 0.1
    assert not any("mm (RMS) from their plane" in w for w in cal.warnings)
    monkeypatch.setattr(P, "FRAME_START_GAIN", np.inf)
    with pytest.raises(CalibrationError) as e:
        calibrate()
    assert e.value.code == "E-CALIB" and "from the plane fitted to them" in str(e.value)

