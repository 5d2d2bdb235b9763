"""A rolling shutter (issue 18): a CMOS camcorder exposes its image rows one after another, so
while the carriage moves, each row shows the scene from a camera a little further along the
rail. The simulator renders it (``impress simulate --readout-ms``), the camera's readout is
part of its intrinsics, and the calibration places each pick at its row's travel."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from impress_gui.core.base.errors import FormatError, InputError
from impress_gui.core.calibration.geometry import Intrinsics
from impress_gui.core.calibration.picks import Picks
from impress_gui.core.calibration.solve import solve_pose
from impress_gui.core.calibration.target import CORNER_NAMES
from impress_gui.sim.simulate import (
    SimConfig,
    _make_renderer,
    calibration_frames,
    make_motion,
    make_rig,
    make_target,
    project_rail,
    project_rail_rolling,
    target_pose,
    target_world_corners,
)

READOUT_MS = 30.0


def _scene(seed: int, readout_ms: float, size=(1920, 1080)):
    cfg = SimConfig.random(seed, *size, readout_ms=readout_ms)
    rig, motion, target = make_rig(cfg), make_motion(cfg), make_target(cfg)
    return cfg, rig, motion, target


def _picks(cfg, rig, motion, target) -> Picks:
    t1, t2 = calibration_frames(cfg, rig, motion, target)
    corners = target_world_corners(target, target_pose(cfg), cfg.standoff_mm)
    uv = {k: project_rail_rolling(rig, motion, corners, t, cfg.line_time_s)
          for k, t in (("t1", t1), ("t2", t2))}
    return Picks(video="scan.mp4", t1=t1, t2=t2,
                 corners_t1={c: tuple(uv["t1"][i]) for i, c in enumerate(CORNER_NAMES)},
                 corners_t2={c: tuple(uv["t2"][i]) for i, c in enumerate(CORNER_NAMES)})


def test_the_readout_is_part_of_the_camera_and_its_file():
    cfg, rig, _, _ = _scene(3, READOUT_MS)
    intr = dataclasses.replace(rig.intrinsics, readout_ms=READOUT_MS)
    assert intr.line_time_s == pytest.approx(0.030 / 1079)
    doc = intr.to_json()
    assert doc["readout_ms"] == READOUT_MS
    assert Intrinsics.from_json(doc).readout_ms == READOUT_MS
    # not given: a file as it always was (no key), read back as not given (line time 0)
    assert "readout_ms" not in rig.intrinsics.to_json()
    back = Intrinsics.from_json(rig.intrinsics.to_json())
    assert back.readout_ms is None and back.line_time_s == 0.0
    zero = dataclasses.replace(rig.intrinsics, readout_ms=0.0)  # a global shutter, given
    assert Intrinsics.from_json(zero.to_json()).readout_ms == 0.0
    for bad in (-1.0, 1e9, float("nan")):
        with pytest.raises(InputError):
            dataclasses.replace(rig.intrinsics, readout_ms=bad)
    with pytest.raises(FormatError):
        Intrinsics.from_json({**doc, "readout_ms": "fast"})


def test_rolling_picks_lie_where_each_rows_camera_was():
    cfg, rig, motion, target = _scene(3, READOUT_MS)
    corners = target_world_corners(target, target_pose(cfg), cfg.standoff_mm)
    t1, _ = calibration_frames(cfg, rig, motion, target)
    uv = project_rail_rolling(rig, motion, corners, t1, cfg.line_time_s)
    travel = motion.travel_mm(t1 / cfg.fps + uv[:, 1] * cfg.line_time_s)
    assert np.abs(project_rail(rig, corners, travel) - uv).max() < 1e-6
    still = project_rail(rig, corners, float(motion.travel_mm(t1 / cfg.fps)))
    # the rows lower in the picture were exposed later, the camera further on: the corners
    # move by up to a few pixels against a global shutter's
    shift = np.abs(uv - still).max()
    assert 0.3 < shift < 20


@pytest.mark.parametrize("seed", [3, 7, 12])
def test_the_calibration_fits_rolling_picks_exactly_when_it_knows_the_readout(seed):
    cfg, rig, motion, target = _scene(seed, READOUT_MS)
    picks = _picks(cfg, rig, motion, target)
    dt = (picks.t2 - picks.t1) / cfg.fps
    rolling = dataclasses.replace(rig.intrinsics, readout_ms=READOUT_MS)
    known = solve_pose(rolling, target, picks, cfg.speed_mm_s, dt)
    # taken for a global shutter (readout 0 given)
    unknown = solve_pose(dataclasses.replace(rig.intrinsics, readout_ms=0.0), target, picks,
                         cfg.speed_mm_s, dt)
    # the exact picks of a rolling shutter fit a rigid pose only with each row at its travel
    assert known.reprojection_rms_px < 0.002
    assert unknown.reprojection_rms_px > 10 * known.reprojection_rms_px
    assert abs(known.implied_speed_mm_s / cfg.speed_mm_s - 1) < 1e-5
    assert abs(unknown.implied_speed_mm_s / cfg.speed_mm_s - 1) > 1e-4


def test_a_global_shutters_render_is_unchanged_by_the_rolling_code():
    """readout 0 renders through the global shutter's path: the same frame as a rolling
    shutter of a vanishing readout, and the rolling render differs where rows were late.
    (Both scenes on a 0.2 mm grid: the shutter's path is checked, not the scene; building the
    default 0.1 mm scene twice took 8 of this test's 9.5 s. Measured on either grid: 85-86 %
    of the values differ, the stripe points within 3e-14 px of their rows' travel.)"""
    cfg0 = SimConfig.random(5, 320, 180, grid_mm=0.2)
    r0, _ = _make_renderer(cfg0)
    rgb0, tr0 = r0.render(40)
    cfg1 = SimConfig.random(5, 320, 180, readout_ms=READOUT_MS, grid_mm=0.2)
    r1, _ = _make_renderer(cfg1)
    rgb1, tr1 = r1.render(40)
    assert rgb0.shape == rgb1.shape
    assert np.mean(rgb0 != rgb1) > 0.01  # the rows moved on
    for st in tr1.values():
        s = r1.row_travel(40, st.uv_px[:, 1])
        assert np.abs(project_rail(r1.rig, st.points_rail_mm, s) - st.uv_px).max() < 0.2
        assert s.max() > r1.travel(40)  # later rows: further along
    assert r0.opt.line_time_s == 0.0 and r1.opt.line_time_s == pytest.approx(0.030 / 179)


@pytest.mark.parametrize("seed", [3, 9, 12])
def test_a_readout_not_given_is_estimated_from_exact_picks(seed):
    """The intrinsics give no readout (a lab's camera calibration): exact picks of a rolling
    shutter show it plainly and the calibration estimates it; picks of a global shutter, and
    the same picks with 0.5 px of click noise, show none (the pose stays the rigid one)."""
    cfg, rig, motion, target = _scene(seed, READOUT_MS)
    picks = _picks(cfg, rig, motion, target)
    dt = (picks.t2 - picks.t1) / cfg.fps
    assert rig.intrinsics.readout_ms is None
    pose = solve_pose(rig.intrinsics, target, picks, cfg.speed_mm_s, dt)
    assert pose.readout_ms_estimated == pytest.approx(READOUT_MS, rel=1e-3)
    assert pose.reprojection_rms_px < 0.002
    assert any("rolling shutter" in w for w in pose.warnings)
    # a global shutter: nothing to estimate
    cfg0, rig0, motion0, target0 = _scene(seed, 0.0)
    picks0 = _picks(cfg0, rig0, motion0, target0)
    pose0 = solve_pose(rig0.intrinsics, target0, picks0, cfg0.speed_mm_s, dt)
    assert pose0.readout_ms_estimated is None
    rng = np.random.default_rng(seed)
    for _ in range(10):
        noisy = Picks(video="scan.mp4", t1=picks0.t1, t2=picks0.t2,
                      corners_t1={c: tuple(np.add(v, rng.normal(0, 0.5, 2)))
                                  for c, v in picks0.corners_t1.items()},
                      corners_t2={c: tuple(np.add(v, rng.normal(0, 0.5, 2)))
                                  for c, v in picks0.corners_t2.items()})
        assert solve_pose(rig0.intrinsics, target0, noisy, cfg0.speed_mm_s,
                          dt).readout_ms_estimated is None
    # given as 0 (a global shutter, known): never estimated, even from rolling picks
    known_global = dataclasses.replace(rig.intrinsics, readout_ms=0.0)
    assert solve_pose(known_global, target, picks, cfg.speed_mm_s,
                      dt).readout_ms_estimated is None
