"""Scene calibration against the simulator's ground truth."""

import json
import subprocess
import sys

import numpy as np
import pytest

from impress_gui.core.base.errors import CalibrationError, InputError
from impress_gui.core.calibration.geometry import Intrinsics, Plane
from impress_gui.core.calibration.picks import Picks
from impress_gui.core.calibration.scene import SceneCalibration, solve_pose, vanishing_point
from impress_gui.core.calibration.target import CORNER_NAMES, default_target
from impress_gui.sim.rig import default_rig
from impress_gui.sim.simulate import project_rail, target_world_corners


def synthetic_picks(roll, tilt, standoff=300.0, speed=13.138, yaw=3.0, noise_px=0.0, seed=0,
                    t1=40, t2=160, fps=30.0, width=1920, height=1080):
    """Exact (or noisy) corner picks of the default target for a given misalignment."""
    rig = default_rig(width, height, roll, tilt, standoff)
    target = default_target()
    travel1 = 30.0
    dt = (t2 - t1) / fps
    corners = target_world_corners(target, (-40.0, 70.0 + travel1 + 0.5 * speed * dt, yaw),
                                   standoff)
    rng = np.random.default_rng(seed)
    uv1 = project_rail(rig, corners, travel1)
    uv2 = project_rail(rig, corners, travel1 + speed * dt)
    uv1 = uv1 + rng.normal(0, noise_px, uv1.shape)
    uv2 = uv2 + rng.normal(0, noise_px, uv2.shape)
    picks = Picks("synthetic", t1, t2, dict(zip(CORNER_NAMES, map(tuple, uv1))),
                  dict(zip(CORNER_NAMES, map(tuple, uv2))))
    truth_corners = corners - [0.0, travel1, 0.0]
    return rig, target, picks, truth_corners, dt


@pytest.mark.parametrize("roll,tilt,standoff,speed", [
    (1.2, -1.8, 300.0, 13.138), (0.0, 0.0, 300.0, 13.138), (-3.0, 2.5, 260.0, 5.2552),
    (4.0, 0.0, 340.0, 1.3138), (0.0, -4.0, 300.0, 13.138)])
def test_pose_from_exact_picks_matches_truth(roll, tilt, standoff, speed):
    t2 = 160 if speed > 5 else (400 if speed > 2 else 1400)
    rig, target, picks, truth, dt = synthetic_picks(roll, tilt, standoff, speed, t2=t2)
    sol = solve_pose(rig.intrinsics, target, picks, speed, dt)
    assert abs(np.degrees(sol.roll_rad) - roll) < 0.05
    assert abs(np.degrees(sol.tilt_rad) - tilt) < 0.05
    assert np.max(np.linalg.norm(sol.corners_parallax_mm - truth, axis=1)) < 0.1
    assert np.max(sol.corner_residuals_mm) < 0.1
    assert abs(sol.implied_speed_mm_s / speed - 1) < 1e-4
    assert not sol.warnings


def test_vanishing_point_at_infinity_is_handled():
    # perfectly aligned camera: the tracks are parallel, the vanishing point is at infinity
    rig, target, picks, truth, dt = synthetic_picks(0.0, 0.0)
    n1 = rig.intrinsics.undistort_points(picks.array("t1"))
    n2 = rig.intrinsics.undistort_points(picks.array("t2"))
    v = vanishing_point(n1, n2)
    assert abs(v[2]) < 1e-9 and abs(abs(v[1]) - 1) < 1e-9


def test_click_noise_degradation_is_bounded():
    errs = []
    for seed in range(5):
        rig, target, picks, truth, dt = synthetic_picks(1.2, -1.8, noise_px=0.5, seed=seed)
        sol = solve_pose(rig.intrinsics, target, picks, 13.138, dt)
        errs.append((abs(np.degrees(sol.roll_rad) - 1.2), abs(np.degrees(sol.tilt_rad) + 1.8),
                     np.max(np.linalg.norm(sol.target_translation_mm -
                                           (truth[0] - sol.target_rotation @ target.corner_array()[0]))
                            , initial=0)))
    errs = np.array(errs)
    # with 0.5 px click noise at 1920x1080: roll stays within 0.1 deg; tilt (the motion's
    # component along the optical axis, seen only as a 1e-4 change of image scale over the
    # travel) within 0.5 deg - the benchmark reports the figures
    assert errs[:, 0].max() < 0.1 and errs[:, 1].max() < 0.5


def test_frames_too_close_together_are_named_as_the_cause():
    """Picks in two frames only ~10 px of motion apart (3 frames at 1080p): half a pixel of
    click noise makes the corners' depths centimetres off and the pose is refused; the error
    says the frames are too close, not only that the target might be wrong. Far apart, the
    same noise passes (test_click_noise_degradation_is_bounded)."""
    from impress_gui.core.base import codes

    rig, target, picks, _, dt = synthetic_picks(1.2, -1.8, noise_px=1.0, seed=1, t1=40, t2=43)
    with pytest.raises(CalibrationError, match="does not match the picks") as e:
        solve_pose(rig.intrinsics, target, picks, 13.138, dt)
    assert e.value.code == codes.E_TARGET_MISMATCH
    assert "move only 11 px between the two frames" in str(e.value)
    assert "farther apart" in str(e.value)
    # a wrong target with frames far apart: no such hint
    rig, target, picks, _, dt = synthetic_picks(1.2, -1.8)
    swapped = dict(picks.corners_t1)
    swapped["A"], swapped["D"] = swapped["D"], swapped["A"]
    bad = Picks(picks.video, picks.t1, picks.t2, swapped,
                {**picks.corners_t2, "A": picks.corners_t2["D"], "D": picks.corners_t2["A"]})
    with pytest.raises(CalibrationError, match="does not match the picks|behind the camera") as e:
        solve_pose(rig.intrinsics, target, bad, 13.138, dt)
    assert "farther apart" not in str(e.value)


def test_wrong_speed_is_detected_by_the_target_size():
    rig, target, picks, truth, dt = synthetic_picks(1.2, -1.8)
    sol = solve_pose(rig.intrinsics, target, picks, 13.138 * 1.05, dt)
    assert abs(sol.implied_speed_mm_s / 13.138 - 1) < 1e-3
    assert any(w.startswith("W-SPEED-MISMATCH") and "implies a rail speed" in w
               for w in sol.warnings)  # coded (a hostile-input audit found it was not)


def test_scene_calibration_against_truth(flat_scan, flat_calibration):
    truth = json.loads((flat_scan / "truth.json").read_text())
    cal = SceneCalibration.load(flat_calibration)
    assert abs(cal.roll_deg - truth["roll_deg"]) < 0.05
    assert abs(cal.tilt_deg - truth["tilt_deg"]) < 0.05
    t1 = truth["calibration_frames"]["t1"]
    tc = np.array([truth["target"]["corners_rail_mm"][c] for c in CORNER_NAMES])
    tc -= [0.0, truth["travel_mm"][t1], 0.0]
    assert np.max(np.linalg.norm(cal.corners_parallax_mm - tc, axis=1)) < 0.1
    for name in ("green", "red"):
        true_plane = Plane.from_json(truth["lasers"][name]["plane"], name)
        fit = cal.planes[name]
        true_plane = true_plane.oriented_like(fit.plane)
        # at 640x360 (a pixel is 0.4 mm on the ground); benchmarks state the 1080p figures
        assert fit.plane.angle_to_deg(true_plane) < 0.15, name
        assert abs(fit.plane.offset_mm - true_plane.offset_mm) < 0.4, name
        assert fit.rms_mm < 0.05 and fit.n_points > 500 and len(fit.heights_mm) == 2


def test_calibration_file_round_trip_and_damage(flat_calibration, tmp_path):
    cal = SceneCalibration.load(flat_calibration)
    p = tmp_path / "c.json"
    cal.save(p)
    back = SceneCalibration.load(p)
    assert np.allclose(back.rotation, cal.rotation) and back.planes.keys() == cal.planes.keys()
    doc = json.loads(p.read_text())
    del doc["laser_planes"]["red"]
    p.write_text(json.dumps(doc))
    from impress_gui.core.base.errors import FormatError

    with pytest.raises(FormatError, match="red laser plane is missing"):
        SceneCalibration.load(p)


def _picks_with(picks: Picks, which: str, corner: str, uv) -> Picks:
    d = dict(picks.corners_t1 if which == "t1" else picks.corners_t2)
    d[corner] = uv
    if which == "t1":
        return Picks(picks.video, picks.t1, picks.t2, d, picks.corners_t2)
    return Picks(picks.video, picks.t1, picks.t2, picks.corners_t1, d)


def test_bad_picks_are_clear_errors(flat_scan):
    from impress_gui.core.calibration.scene import calibrate_scene
    from impress_gui.core.formats.video import open_video

    intr = Intrinsics.load(flat_scan / "intrinsics.json")
    picks = Picks.load(flat_scan / "picks.json")
    target = default_target()
    with open_video(flat_scan / "scan.mp4") as v:
        def run(p, intrinsics=intr, tgt=target):
            return calibrate_scene(v, intrinsics, tgt, p, 13.138)

        with pytest.raises(CalibrationError, match="outside the 640x360 image"):
            run(_picks_with(picks, "t1", "C", (700.0, 10.0)))
        with pytest.raises(CalibrationError, match="at the same place"):
            run(_picks_with(picks, "t2", "B", picks.corners_t2["A"]))
        line = {c: (100.0 + 40 * i, 100.0 + 20 * i) for i, c in enumerate(CORNER_NAMES)}
        with pytest.raises(CalibrationError, match="collinear"):
            run(Picks(picks.video, picks.t1, picks.t2, line, picks.corners_t2))
        with pytest.raises(CalibrationError, match="outside the video"):
            run(Picks(picks.video, picks.t1, 99999, picks.corners_t1, picks.corners_t2))
        five = {c: v for c, v in picks.corners_t1.items() if c != "F"}
        with pytest.raises(CalibrationError, match="F are not marked"):
            run(Picks(picks.video, picks.t1, picks.t2, five, picks.corners_t2))
        swapped = dict(picks.corners_t1)
        swapped["A"], swapped["D"] = swapped["D"], swapped["A"]
        with pytest.raises(CalibrationError, match="does not match the picks|behind the camera"):
            run(Picks(picks.video, picks.t1, picks.t2, swapped,
                      {**picks.corners_t2, "A": picks.corners_t2["D"],
                       "D": picks.corners_t2["A"]}))
        other = Intrinsics(intr.camera_matrix * [[3, 1, 3], [1, 3, 3], [1, 1, 1]],
                           intr.dist_coeffs, (1920, 1080))
        with pytest.raises(InputError, match="1920x1080"):
            run(picks, intrinsics=other)


def test_cli_round_trip(flat_scan, tmp_path):
    out = tmp_path / "cal.json"
    res = subprocess.run(
        [sys.executable, "-m", "impress_gui", "calibrate", str(flat_scan / "scan.mp4"),
         "--intrinsics", str(flat_scan / "intrinsics.json"), "--picks",
         str(flat_scan / "picks.json"), "--speed", "fast", "-o", str(out)],
        capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    truth = json.loads((flat_scan / "truth.json").read_text())
    cal = SceneCalibration.load(out)
    assert abs(cal.roll_deg - truth["roll_deg"]) < 0.05
    assert cal.inputs["video"]["sha256"] == truth["video_sha256"]
    bad = subprocess.run(
        [sys.executable, "-m", "impress_gui", "calibrate", str(flat_scan / "scan.mp4"),
         "--intrinsics", str(flat_scan / "picks.json"), "--picks",
         str(flat_scan / "picks.json"), "--speed", "fast", "-o", str(tmp_path / "x.json")],
        capture_output=True, text=True)
    assert bad.returncode == 2 and "not a impress.intrinsics file" in bad.stderr
    assert not (tmp_path / "x.json").exists()


def test_three_point_fallback_recovers_the_plane(flat_scan, flat_calibration):
    """The seed's L, M, N method: stripe pixels on three target edges, rays met with the
    edges, the plane through the three points - from the true stripe positions."""
    from impress_gui.core.calibration.aids import three_point_plane
    from impress_gui.sim.simulate import SimConfig, _make_renderer

    truth = json.loads((flat_scan / "truth.json").read_text())
    cal = SceneCalibration.load(flat_calibration)
    target = default_target()
    renderer, _ = _make_renderer(SimConfig(**truth["config"]))
    t1 = truth["calibration_frames"]["t1"]
    stripe = renderer.laser_points(renderer.rig.laser("green"), t1)
    corners = cal.corners_fit_mm(target)  # rail frame, origin at the camera at t1
    idx = {c: i for i, c in enumerate(CORNER_NAMES)}
    # edges A-B (low top, outer), F-C (top of the riser), E-D (high top, outer)
    edges = [(corners[idx["A"]], corners[idx["B"]]), (corners[idx["F"]], corners[idx["C"]]),
             (corners[idx["E"]], corners[idx["D"]])]
    # the true stripe pixel nearest to each edge (world points from the simulator)
    s1 = truth["travel_mm"][t1]
    pts = stripe.points_rail_mm - [0.0, s1, 0.0]
    picks = []
    for a, b in edges:
        e = (b - a) / np.linalg.norm(b - a)
        d = np.linalg.norm(np.cross(pts - a, e), axis=1)
        picks.append(stripe.uv_px[np.argmin(d)])
    plane = three_point_plane(cal.intrinsics, cal.rotation, 0.0, np.array(picks), edges)
    true_plane = Plane.from_json(truth["lasers"]["green"]["plane"], "green").oriented_like(plane)
    # three points only, each within a stripe sample of its edge: a coarse plane
    assert plane.angle_to_deg(true_plane) < 1.0
    assert abs(plane.offset_mm - true_plane.offset_mm) < 3.0
    with pytest.raises(CalibrationError, match="collinear|parallel"):
        three_point_plane(cal.intrinsics, cal.rotation, 0.0, np.array([picks[0]] * 3),
                          [edges[0]] * 3)
