"""Picks with t1 and t2 swapped (t1 must be the frame with the green stripe on both top faces,
t2 the one with the red): found by the audit of 4 December 2026 on a short flat scan, where
the calibration put the red laser's plane through the camera's centre without a warning and
processing then lost the red laser silently. Now the calibration refuses such a plane (and
says to check t1 and t2), processing with a calibration holding one is refused (the file, and
a project holding it, still open), and a reconstruction in which one laser's stripe is found
but gives no heights says so."""

from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import simulate_scan

from impress_gui.core.base.errors import CalibrationError
from impress_gui.core.calibration.geometry import Plane
from impress_gui.core.calibration.scene import (
    PLANE_MIN_DISTANCE_MM,
    LaserPlaneFit,
    check_plane_distances,
)
from impress_gui.core.reconstruction.reconstruct import _lost_laser_warnings, _Tally


def _fit(name: str, offset_mm: float) -> LaserPlaneFit:
    return LaserPlaneFit(name, Plane(np.array([0.0, -0.99, 0.12]) / np.hypot(0.99, 0.12),
                                     offset_mm), 0.05, 500, (), ())


def test_a_plane_through_the_camera_is_refused():
    check_plane_distances({"green": _fit("green", 115.0), "red": _fit("red", -60.0)})
    for off in (0.0, -0.0076, PLANE_MIN_DISTANCE_MM - 0.1):
        with pytest.raises(CalibrationError) as e:
            check_plane_distances({"green": _fit("green", 115.0), "red": _fit("red", off)})
        assert e.value.code == "E-CALIB" and "t1 and t2 swapped" in str(e.value)


def test_swapped_picks_are_refused_with_the_hint(tmp_path):
    """The audit's scan (flat preset, 60 mm, 320x180) and its picks file with the numbers t1
    and t2 swapped (the corners left as clicked, so each frame gets the other's corners):
    refused, naming the red plane and the swap; the picks as made calibrate. (Swapping the
    frames together with their corners is another choice of frames, valid where both stripes
    cross the target in both - this scan calibrates so - and refused as E-PLANE-UNDETERMINED
    where they do not.) The scene on a 0.5 mm grid: the frames and picks decide, not the
    soil's fine relief (measured 7 December 2026 on it and on the default 0.1 mm grid alike:
    the planes as picked 115 mm from the camera, swapped the red one 0.0 mm and refused;
    without the refusal that calibration passes with a red plane 0.05 mm from the camera;
    the render 5 s instead of 12)."""
    from impress_gui.core.calibration.geometry import Intrinsics
    from impress_gui.core.calibration.picks import Picks
    from impress_gui.core.calibration.scene import calibrate_scene
    from impress_gui.core.calibration.target import TargetModel
    from impress_gui.core.formats.video import open_video

    scan = simulate_scan(tmp_path / "scan", preset="flat", length_mm=60.0, width=320,
                         height=180, grid_mm=0.5)
    truth = json.loads((scan / "truth.json").read_text())
    p = Picks.load(scan / "picks.json")

    def calibrate(picks):
        with open_video(scan / "scan.mp4") as v:
            return calibrate_scene(v, Intrinsics.load(scan / "intrinsics.json"),
                                   TargetModel.load(scan / "target.json"), picks,
                                   truth["speed_mm_s"])

    cal = calibrate(p)
    assert min(abs(float(f.plane.distance(np.zeros(3)))) for f in cal.planes.values()) > 50
    with pytest.raises(CalibrationError) as e:
        calibrate(Picks(p.video, p.t2, p.t1, p.corners_t1, p.corners_t2))
    assert e.value.code == "E-CALIB" and "swapped" in str(e.value)


def test_a_laser_found_but_without_heights_is_reported():
    tally = _Tally({"green": 45, "red": 45}, {"green": 9000, "red": 9000})
    stats = {"cells_green": 502829, "cells_red": 0}
    (w,) = _lost_laser_warnings(tally, stats)
    assert w.startswith("W-LASER-NO-HEIGHTS") and "red" in w and "t1" in w
    assert _lost_laser_warnings(tally, {"cells_green": 502829, "cells_red": 250000}) == []
    # a stripe never found is E-NO-STRIPE's, not this warning's
    assert _lost_laser_warnings(_Tally({"green": 45, "red": 0}, {"green": 9000, "red": 0}),
                                stats) == []


def test_a_calibration_with_such_a_plane_opens_but_is_not_processed(flat_scan,
                                                                    flat_calibration,
                                                                    tmp_path):
    """Made before such planes were refused (or edited): the file reads (a case holding it
    still opens), processing refuses it before any work, and no output is made."""
    from impress_gui.core.calibration.scene import SceneCalibration
    from impress_gui.core.reconstruction.pipeline import process_files
    from impress_gui.core.reconstruction.reconstruct import ProcessParams

    doc = json.loads(flat_calibration.read_text())
    doc["laser_planes"]["red"].update(normal=[-0.0346, -0.9918, 0.1233], offset_mm=-0.0076)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(doc))
    cal = SceneCalibration.load(bad)
    assert abs(cal.planes["red"].plane.distance(np.zeros(3))) < 0.01
    with pytest.raises(CalibrationError) as e:
        process_files(flat_scan / "scan.mp4", bad, tmp_path / "out",
                      ProcessParams(frame_start=40, frame_stop=50, texture=False))
    assert e.value.code == "E-CALIB" and "red" in str(e.value)
    assert not (tmp_path / "out").exists()
