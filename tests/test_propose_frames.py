""""Find t1 and t2" (aids.propose_calibration_frames) against the simulator's geometry (issue 21,
item 8).

t1 is the frame of the green laser's stripe and t2 the red one's, whichever reaches the target
first (picks.py). A frame is valid for a laser when the simulator's own test holds: its stripe
crosses both top faces of the L target inside their ends and all six corners are 3 % of the width
inside the image (simulate._calibration_frames, whose first green / last red frame the truth
records). Any frame of that range is an equally good proposal, so the proposal must lie inside
it (tolerance: 1 frame beyond its ends).

Random rig 2 at 320x180: the red laser reaches the target first (true t1 = 125 after t2 = 67).
Before the fix the proposal was t1 = 151, t2 = 176: the red stripe's frame far past its range
(the run with the largest displacement sum, not the target's)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

RIG, SIZE = 2, (320, 180)
TOL = 1  # frames beyond the valid range


@pytest.fixture(scope="module")
def rig_scan(tmp_path_factory) -> Path:
    from impress_gui.sim.simulate import SimConfig, simulate

    out = tmp_path_factory.mktemp("propose") / "scan"
    simulate(SimConfig.random(RIG, *SIZE), out, workers=1)
    return out


def _valid_frames(scan: Path) -> dict[str, np.ndarray]:
    """Per laser the frames the simulator would accept for it."""
    from impress_gui.sim import simulate as sim

    truth = json.loads((scan / "truth.json").read_text())
    cfg = sim.SimConfig(**truth["config"])
    rig, motion, target = sim.make_rig(cfg), sim.make_motion(cfg), sim.make_target(cfg)
    pose = sim.target_pose(cfg)
    corners = sim.target_world_corners(target, pose, rig.standoff_mm)
    w, h, m = cfg.width, cfg.height, 0.03 * cfg.width
    ok: dict[str, list[int]] = {"green": [], "red": []}
    for k, t in enumerate(motion.times_s()):
        if not motion.constant_speed(t):
            continue
        s = float(motion.travel_mm(t))
        uv = sim.project_rail(rig, corners, s)
        if not (np.all(uv > m) and np.all(uv[:, 0] < w - m) and np.all(uv[:, 1] < h - m)):
            continue
        for name in ok:
            if sim._stripe_on_faces(rig, name, target, pose, s):
                ok[name].append(k)
    # the truth's frames are the simulator's choice from these ranges
    frames = truth["calibration_frames"]
    assert frames["t1"] == ok["green"][0] and frames["t2"] == ok["red"][-1]
    return {name: np.array(v) for name, v in ok.items()}


def test_proposal_in_the_valid_ranges(rig_scan):
    from impress_gui.core.calibration.aids import propose_calibration_frames
    from impress_gui.core.formats.video import open_video

    valid = _valid_frames(rig_scan)
    with open_video(rig_scan / "scan.mp4") as video:
        got = propose_calibration_frames(video)
    truth = json.loads((rig_scan / "truth.json").read_text())["calibration_frames"]
    for key, name in (("t1", "green"), ("t2", "red")):
        lo, hi = int(valid[name].min()), int(valid[name].max())
        assert lo - TOL <= got[key] <= hi + TOL, (
            f"{key} ({name}) = {got[key]}: valid {lo}..{hi}, simulator's choice {truth[key]}")
    # the laser order follows the rig: here red reaches the target first
    assert (got["t1"] > got["t2"]) == (truth["t1"] > truth["t2"])
