"""``propose_calibration_frames`` (Find t1 and t2, issue 21 item 8): in the proposed t1 the
green stripe lies across both top faces of the L target and in t2 the red one, with all six
corners inside the picture in both - on a rendered random rig whose motion runs up the image,
and on synthetic stripe profiles with accuracy plates taller than the target, either laser
leading and the motion down or up the picture."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from impress_gui.core.calibration.aids import propose_calibration_frames, propose_from_profiles


# ----- a rendered random rig ----------------------------------------------------------------
@pytest.fixture(scope="module")
def up_rig_scan(tmp_path_factory) -> Path:
    """Random rig 1 at 256x144 (coarse scene grid: fast): the camera rolled by 168 degrees,
    so the motion runs up the image; a 50 mm L target with a 12 and a 25 mm face."""
    from impress_gui.sim.simulate import SimConfig, simulate

    out = tmp_path_factory.mktemp("propose") / "rr1"
    simulate(SimConfig.random(1, 256, 144, grid_mm=1.0), out, workers=1)
    return out


def _sim_geometry(scan: Path):
    from impress_gui.sim.simulate import SimConfig, make_rig, make_target, target_pose

    truth = json.loads((scan / "truth.json").read_text())
    fields = SimConfig.__dataclass_fields__
    cfg = SimConfig(**{k: v for k, v in truth["config"].items() if k in fields})
    return truth, cfg, make_rig(cfg), make_target(cfg), target_pose(cfg)


def test_proposed_frames_show_the_target_on_a_rig_moving_up_the_image(up_rig_scan):
    from impress_gui.core.formats.video import open_video
    from impress_gui.sim.simulate import (
        _stripe_on_faces,
        make_motion,
        project_rail,
        target_world_corners,
    )

    truth, cfg, rig, target, pose = _sim_geometry(up_rig_scan)
    assert abs(abs(truth["random_rig"]["roll_deg"]) - 180) < 15  # the motion runs up the image
    with open_video(up_rig_scan / "scan.mp4") as v:
        prop = propose_calibration_frames(v)
    corners = target_world_corners(target, pose, rig.standoff_mm)
    for key, laser in (("t1", "green"), ("t2", "red")):
        k = prop[key]
        travel = float(truth["travel_mm"][k])
        uv = project_rail(rig, corners, travel)
        # all six corners inside the picture (the old proposal put t2 where C, D had left it)
        assert np.all((uv > 1.0) & (uv < [cfg.width - 1.0, cfg.height - 1.0])), (key, k, uv)
        # the stripe across both top faces, clear of their ends
        assert _stripe_on_faces(rig, laser, target, pose, travel, 2.0), (key, k)
        # at the rail's constant speed (not in its ramps)
        assert make_motion(cfg).constant_speed(truth["frame_times_s"][k]), (key, k)
    sim = truth["calibration_frames"]
    assert prop["t1"] < prop["t2"]  # green leads on this rig, as in the simulator's frames
    # far enough apart for parallax: at least half the simulator's own spacing
    assert prop["t2"] - prop["t1"] >= 0.5 * (sim["t2"] - sim["t1"]), (prop, sim)


# ----- synthetic stripe profiles --------------------------------------------------------------
W, H = 320, 180
SCALE = 1.2  # px per mm on the ground
STEP_MM = 0.5  # travel per frame
N_FRAMES = 1000


def _heights(x, y, plates_first: bool):
    """The scene: an L target (low face 10 mm at x -40..0, high face 30 mm at x 0..40, 60 mm
    long) and an accuracy plate with a raised block taller than the target (a T across the
    stripe: 12 mm at x -70..70, 38 mm at x -20..20, 150 mm long), after the target or before
    it."""
    yt, yp = (330.0, 140.0) if plates_first else (160.0, 260.0)
    h = np.zeros(np.broadcast(x, y).shape)
    on_t = (y >= yt) & (y <= yt + 60)
    h = np.where(on_t & (x >= -40) & (x < 0), 10.0, h)
    h = np.where(on_t & (x >= 0) & (x <= 40), 30.0, h)
    on_p = (y >= yp) & (y <= yp + 150)
    h = np.where(on_p & (np.abs(x) <= 70), 12.0, h)
    h = np.where(on_p & (np.abs(x) <= 20), 38.0, h)
    return h, yt


def _slopes(green_leads: bool) -> dict[str, float]:
    """mm along y per mm of height of each laser's plane: both lean towards the camera's
    centre (the leading one back, the trailing one forward), like a rig's lasers aimed at
    the middle of the picture."""
    return {"green": -0.5 if green_leads else 0.45, "red": 0.45 if green_leads else -0.5}


def _profiles(up: bool, green_leads: bool, plates_first: bool):
    """Stripe rows of both lasers per frame and column, seen from straight above (no
    perspective): the camera travels STEP_MM per frame along +y and images ground point y in
    frame k at row 90 -+ (y - travel - 60) * SCALE (``up``: the scene moves up the image).
    The leading stripe meets the scene first. Each laser's plane is inclined (opposite ways):
    it lies on the ground at y0 (relative to the camera) and at height z at y0 + z * slope, so
    a raised face shows its stripe displaced; the ground rows are slightly tilted and bent."""
    n = N_FRAMES
    frames = np.arange(n)
    cols = np.arange(W)
    x = (cols + 0.5 - W / 2) / SCALE
    sgn = -1.0 if up else 1.0
    ahead, behind = 60.0 + 55.0, 60.0 - 55.0
    stripe_y = {"green": ahead if green_leads else behind, "red": behind if green_leads else ahead}
    slope = _slopes(green_leads)
    rng = np.random.default_rng(3)
    rows = {}
    for name in ("green", "red"):
        bend = 0.03 * (cols - W / 2) + 4e-5 * (cols - W / 2) ** 2
        travel = frames[:, None] * STEP_MM
        y = np.zeros((n, W))
        hit = np.full((n, W), -1.0)
        for z in (0.0, 10.0, 12.0, 30.0, 38.0):  # the light stops on the highest surface
            yz = travel + stripe_y[name] + z * slope[name]
            hz, _ = _heights(x[None, :], yz, plates_first)
            take = np.isclose(hz, z) & (z > hit)
            hit = np.where(take, z, hit)
            y = np.where(take, yz, y)
        r = 90 + sgn * (y - travel - 60.0) * SCALE + bend[None, :]
        r = np.where(hit >= 0, r, np.nan) + rng.normal(0, 0.1, (n, W))
        r[rng.random((n, W)) < 0.03] = np.nan  # dropouts
        rows[name] = r
    _, yt = _heights(np.zeros(1), np.zeros(1), plates_first)
    return frames, rows, yt, sgn


def _truth_windows(yt: float, sgn: float, green_leads: bool):
    """Per laser the frames in which its stripe lies across both faces of the target (3 mm
    inside their ends), and per frame whether the target's corners are inside the picture."""
    k = np.arange(N_FRAMES)
    travel = k * STEP_MM
    rows_front = 90 + sgn * (yt - travel - 60) * SCALE
    rows_back = 90 + sgn * (yt + 60 - travel - 60) * SCALE
    in_view = (np.minimum(rows_front, rows_back) > 0) & (np.maximum(rows_front, rows_back) < H)
    on = {}
    slope = _slopes(green_leads)
    for name, ahead in (("green", green_leads), ("red", not green_leads)):
        ok = np.ones(N_FRAMES, bool)
        for z in (10.0, 30.0):
            y = travel + (115.0 if ahead else 5.0) + z * slope[name]
            ok &= (y >= yt + 3) & (y <= yt + 57)
        on[name] = ok
    return on, in_view


@pytest.mark.parametrize("up, green_leads, plates_first", [
    (False, True, False), (True, True, True), (False, False, True), (True, False, False)])
def test_proposal_on_synthetic_profiles(up, green_leads, plates_first):
    frames, rows, yt, sgn = _profiles(up, green_leads, plates_first)
    prop = propose_from_profiles(frames, rows, W, H)
    on, in_view = _truth_windows(yt, sgn, green_leads)
    for key, laser in (("t1", "green"), ("t2", "red")):
        k = prop[key]
        assert on[laser][k] and in_view[k], (key, k, np.flatnonzero(on[laser] & in_view)[[0, -1]])
    # the leading stripe's frame comes first, and the two are far apart
    assert (prop["t1"] < prop["t2"]) == green_leads
    both = [np.flatnonzero(on[n] & in_view) for n in ("green", "red")]
    widest = max(abs(both[1][-1] - both[0][0]), abs(both[0][-1] - both[1][0]))
    assert abs(prop["t2"] - prop["t1"]) >= 0.6 * widest, (prop, widest)
