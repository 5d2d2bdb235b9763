"""Laser planes fitted with the stripe on the ground beside the target (issue 18).

A plane fitted to the target's faces alone is turned by a sub-pixel bias that differs between
the two faces, and the turn is extrapolated down to the ground. The calibration adds the stripe
points on the target's base plane around it (height 0). Synthetic geometry with exact answers:
a camera 300 mm above the L target, one laser plane, its stripe points on the two faces and on
the ground; the faces' points biased in opposite directions."""

from __future__ import annotations

import numpy as np
import pytest

from impress_gui.core.calibration import planes as P
from impress_gui.core.calibration.geometry import Plane
from impress_gui.core.calibration.target import make_l_target

TARGET = make_l_target()
# object (x, y, z up) -> ideal frame (x, -y, depth): the camera 300 mm above the target's middle
R_O = np.diag([1.0, -1.0, -1.0])
T_O = np.array([-40.0, 35.0, 300.0])
SLOPE = 0.3  # the stripe's y moves 0.3 mm per mm of height (the laser's inclination)
TRUE = Plane(np.array([0.0, 1.0, -SLOPE]), -35.0 - SLOPE * 275.0)


def _stripe(xs, h, bias_y=0.0):
    """Ideal-frame points of the stripe at height ``h`` (object y shifted by ``bias_y``)."""
    y = 35.0 + SLOPE * (h - 25.0) + bias_y
    obj = np.column_stack([xs, np.full(len(xs), y), np.full(len(xs), h)])
    return obj @ R_O.T + T_O


def _observations(ground_lift_mm=0.0, face_bias_mm=0.03, seed=0):
    rng = np.random.default_rng(seed)
    faces = np.concatenate([_stripe(np.linspace(2, 38, 300), 10.0, +face_bias_mm),
                            _stripe(np.linspace(42, 78, 300), 40.0, -face_bias_mm)])
    xs = np.concatenate([np.linspace(-28, -4, 300), np.linspace(84, 108, 300)])
    ground = _stripe(xs, ground_lift_mm)  # soil heaped beside the target: lit higher up
    faces += rng.normal(0, 0.003, faces.shape)
    ground += rng.normal(0, 0.003, ground.shape)
    rays = {"green": [(0, 0.0, faces / faces[:, 2:])]}
    on_ground = {"green": [(0, 0.0, ground / ground[:, 2:])]}
    return P.StripeObservations(TARGET, 1.0, {"green": 0}, rays, ground=on_ground)


def test_ground_points_classified_beside_the_target_only():
    pts = np.array([
        [-10.0, 30.0, 0.0],   # ground beside the low side: kept
        [95.0, 30.0, 0.0],    # beyond the high side: kept
        [20.0, 30.0, 0.0],    # under the footprint: not ground
        [-1.0, 30.0, 0.0],    # within the 3 mm margin along the target
        [-50.0, 30.0, 0.0],   # outside the 30 mm ring
    ]) @ R_O.T + T_O
    got = P.points_on_ground(pts / pts[:, 2:], (R_O, T_O), TARGET, 0.0)
    np.testing.assert_allclose(got, pts[:2], atol=1e-9)
    # a ground point hidden from the camera by the high block (the camera low and far aside)
    far = np.array([[83.5 + 0.0, 30.0, 0.0]]) @ R_O.T + T_O
    cam_shift = np.array([-200.0, 0.0, 0.0])  # rays from a camera 200 mm to the side
    rays = far - cam_shift
    assert len(P.points_on_ground(rays / rays[:, 2:], (R_O, T_O + -cam_shift), TARGET, 0.0)) == 0


def test_the_ground_pins_a_plane_turned_by_biased_faces():
    obs = _observations()
    faces_only = obs.fit_planes(np.eye(3), (R_O, T_O))["green"][0]
    joint = obs.fit_planes(np.eye(3), (R_O, T_O), with_ground=True)["green"][0]
    err0 = faces_only.plane.angle_to_deg(TRUE.oriented_like(faces_only.plane))
    err1 = joint.plane.angle_to_deg(TRUE.oriented_like(joint.plane))
    assert err0 > 0.005  # the faces' opposite biases turn the plane
    assert err1 < err0 / 2, (err0, err1)
    # the ground beside the high block within 4-6 mm of it is hidden from the camera
    seen = P.points_on_ground(obs.ground["green"][0][2], (R_O, T_O), TARGET, 0.0)
    assert 500 <= len(seen) < 600
    assert joint.ground_points == len(seen) and "joined" in joint.ground_note
    assert joint.heights_mm == faces_only.heights_mm == (10.0, 40.0)
    # the height the plane gives on the ground beside the target: unbiased with the ground
    g = _stripe(np.array([-20.0, 100.0]), 0.0)
    assert np.abs(joint.plane.distance(g)).max() < np.abs(faces_only.plane.distance(g)).max() / 2


def test_heaped_soil_beside_the_target_is_left_out():
    obs = _observations(ground_lift_mm=1.5)
    faces_only = obs.fit_planes(np.eye(3), (R_O, T_O))["green"][0]
    joint = obs.fit_planes(np.eye(3), (R_O, T_O), with_ground=True)["green"][0]
    assert joint.ground_points == 0 and "not used" in joint.ground_note
    np.testing.assert_allclose(joint.plane.normal, faces_only.plane.normal)
    assert joint.plane.offset_mm == pytest.approx(faces_only.plane.offset_mm)


def test_a_real_calibration_uses_the_flat_ground_and_records_it(flat_scan, flat_calibration,
                                                                tmp_path):
    """The flat preset's calibration (640x360, exact picks): both planes take stripe points on
    the ground beside the target, the file records how many and why, and both planes lie
    within 0.05 deg of the simulator's."""
    import json

    from impress_gui.core.calibration.scene import SceneCalibration

    cal = SceneCalibration.load(flat_calibration)
    truth = json.loads((flat_scan / "truth.json").read_text())
    doc = json.loads(flat_calibration.read_text())
    for name in ("green", "red"):
        fit = cal.planes[name]
        assert fit.ground_points >= P.GROUND_MIN_POINTS, fit.ground_note
        assert doc["laser_planes"][name]["ground_points"] == fit.ground_points
        assert "joined" in doc["laser_planes"][name]["ground_note"]
        tp = Plane.from_json(truth["lasers"][name]["plane"], name).oriented_like(fit.plane)
        assert fit.plane.angle_to_deg(tp) < 0.05
    cal.save(tmp_path / "again.json")
    back = SceneCalibration.load(tmp_path / "again.json").planes
    for name, fit in cal.planes.items():
        assert (back[name].ground_points, back[name].ground_note) == (
            fit.ground_points, fit.ground_note)
        np.testing.assert_allclose(back[name].plane.normal, fit.plane.normal)


def test_a_plane_from_a_narrow_range_of_heights_is_warned_about():
    """Faces 4 mm apart and no usable ground: the calibration warns that the plane is
    extrapolated; the ground's points (height 0) widen the span and the warning goes."""
    from dataclasses import replace

    from impress_gui.core.calibration.scene import plane_span_warnings

    narrow = P.LaserPlaneFit("green", TRUE, 0.01, 600, (0,), (10.0, 14.0))
    wide = P.LaserPlaneFit("red", TRUE, 0.01, 600, (0,), (10.0, 40.0))
    (w,) = plane_span_warnings({"green": narrow, "red": wide})
    assert "green" in w and "spanning only 4 mm" in w and "10, 14 mm" in w
    assert plane_span_warnings({"green": replace(narrow, ground_points=500)}) == []


def test_the_other_lasers_light_on_the_ground_is_left_out():
    """Random rig 28: green's blooming stripe taken for red on the ground beside the target
    (60 % of red's ground points, on green's plane). Red's ground is still used - its own
    points on it are flat - and the note says what was left out; counted as red's (before),
    they made the ground look uneven and it was not used."""
    rng = np.random.default_rng(1)

    def stripe(xs, h, slope, y0):
        y = y0 + slope * (h - 25.0)
        obj = np.column_stack([xs, np.full(len(xs), y), np.full(len(xs), h)])
        return obj @ R_O.T + T_O + rng.normal(0, 0.003, (len(xs), 3))

    def faces(slope, y0):
        return np.concatenate([stripe(np.linspace(2, 38, 300), 10.0, slope, y0),
                               stripe(np.linspace(42, 78, 300), 40.0, slope, y0)])

    xs = np.concatenate([np.linspace(-28, -4, 300), np.linspace(84, 108, 300)])
    g_green = stripe(xs, 0.0, SLOPE, 35.0)
    g_red = stripe(xs, 0.0, -SLOPE, 45.0)
    red_ground = np.concatenate([g_red[::2], g_green[: 450]])  # 300 red's, 450 green's
    rays = {"green": [(0, 0.0, (p := faces(SLOPE, 35.0)) / p[:, 2:])],
            "red": [(0, 0.0, (q := faces(-SLOPE, 45.0)) / q[:, 2:])]}
    ground = {"green": [(0, 0.0, g_green / g_green[:, 2:])],
              "red": [(0, 0.0, red_ground / red_ground[:, 2:])]}
    obs = P.StripeObservations(TARGET, 1.0, {"green": 0, "red": 0}, rays, ground=ground)
    red = obs.fit_planes(np.eye(3), (R_O, T_O), with_ground=True)["red"][0]
    seen = len(P.points_on_ground(g_red[::2] / g_red[::2, 2:], (R_O, T_O), TARGET, 0.0))
    assert red.ground_points == seen > 200
    assert "other laser's plane" in red.ground_note
    # the former rule: every point on the ground counted as red's -> the ground not used
    alone = P.StripeObservations(TARGET, 1.0, {"red": 0}, {"red": rays["red"]},
                                 ground={"red": ground["red"]})
    before = alone.fit_planes(np.eye(3), (R_O, T_O), with_ground=True)["red"][0]
    assert before.ground_points == 0 and "not used" in before.ground_note
