"""Camera intrinsics calibration against the simulator's known camera.

The checkerboard views are rendered through the simulator's intrinsics (radial and tangential
distortion) with supersampled pixels, lens blur and sensor noise; the recovered intrinsics are
compared with those, never with a previous run.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from impress_gui.core.base.errors import CalibrationError, Cancelled, InputError
from impress_gui.core.base.progress import CancelToken
from impress_gui.core.calibration.geometry import Intrinsics
from impress_gui.core.calibration.intrinsics import (
    BoardView,
    calibrate_camera,
    calibrate_views,
    detect_boards,
    find_board,
    parse_board,
    run_camera_calibration,
)
from impress_gui.core.formats.video import open_video
from impress_gui.sim.checkerboard import Board, BoardPose, write_views
from impress_gui.sim.rig import default_intrinsics

W, H = 640, 360
BOARD = Board(9, 6, 25.0)

# tolerances against the true camera (640x360, f = 703 px); "seen" = over several seeds
CORNER_RMS_PX, CORNER_MAX_PX = 0.1, 0.35  # detected vs projected corners (seen 0.06 / 0.22)
F_REL = 0.002  # focal length, relative (seen <= 0.05 %)
PP_PX = 1.5  # principal point (seen <= 0.75 px)
DIST_PX = 0.4  # distortion: largest difference of the lens' displacement over the image,
#                 worst in the corners the boards reach least (seen 0.11-0.26 px)
# 16 views through H.264 at ~2.4 Mbit/s (seen: f <= 0.07 %, principal point <= 1.0 px,
# distortion <= 0.33 px)
F_REL_VIDEO, PP_PX_VIDEO, DIST_PX_VIDEO = 0.003, 2.0, 0.6


@pytest.fixture(scope="module")
def truth() -> Intrinsics:
    return default_intrinsics(W, H)


@pytest.fixture(scope="module")
def frames_dir(board_views):
    """20 views of BOARD through the true camera (seed 7): conftest's ``board_views``, made
    once per run (the calibration tab's test reads the same set)."""
    assert BOARD == Board(9, 6, 25.0) and (W, H) == (640, 360)  # the views' board and camera
    return board_views


@pytest.fixture(scope="module")
def board_truth(frames_dir):
    return json.loads((frames_dir.parent / "board_truth.json").read_text())


def distortion_difference_px(est: Intrinsics, truth: Intrinsics) -> float:
    """Largest difference (px) between the two lens distortions over the image, with the true
    camera matrix (so focal length and principal point errors do not count twice)."""
    uu, vv = np.meshgrid(np.linspace(0, W - 1, 41), np.linspace(0, H - 1, 23))
    xn, yn = truth.undistort_points(np.column_stack([uu.ravel(), vv.ravel()])).T
    other = Intrinsics(truth.camera_matrix, est.dist_coeffs, truth.image_size)
    a = np.column_stack(truth.distort_normalized(xn, yn))
    b = np.column_stack(other.distort_normalized(xn, yn))
    return float(np.max(np.linalg.norm(a - b, axis=1)))


def check_against_truth(est: Intrinsics, truth: Intrinsics, f_rel, pp_px, dist_px) -> None:
    assert est.image_size == truth.image_size
    assert abs(est.fx / truth.fx - 1) < f_rel, (est.fx, truth.fx)
    assert abs(est.fy / truth.fy - 1) < f_rel, (est.fy, truth.fy)
    assert abs(est.cx - truth.cx) < pp_px and abs(est.cy - truth.cy) < pp_px, (
        (est.cx, est.cy), (truth.cx, truth.cy))
    assert distortion_difference_px(est, truth) < dist_px, (est.dist_coeffs, truth.dist_coeffs)
    assert abs(est.dist_coeffs[0] - truth.dist_coeffs[0]) < 0.01  # k1 itself is well determined


def test_rendered_corners_are_where_the_camera_projects_them(frames_dir, board_truth, truth):
    """The renderer and the detector agree with geometry: corners found in each view lie at
    the projections of the board's corners through the true intrinsics."""
    import cv2

    files = sorted(frames_dir.glob("*.png"))
    assert len(files) == len(board_truth["views"]) == 20
    errors = []
    for f, view in zip(files, board_truth["views"], strict=True):
        gray = cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2GRAY)
        found = find_board(gray, (9, 6))
        assert found is not None, f.name
        pose = BoardPose(np.array(view["rotation"]), np.array(view["translation_mm"]))
        expected = truth.project(pose.to_camera(BOARD.corners_mm()))
        # the detector may start counting from either end of the board
        nearest = np.argmin(np.linalg.norm(found[:, None] - expected[None], axis=2), axis=1)
        assert len(set(nearest)) == len(found)
        errors.append(np.linalg.norm(found - expected[nearest], axis=1))
    e = np.concatenate(errors)
    assert np.sqrt(np.mean(e**2)) < CORNER_RMS_PX and e.max() < CORNER_MAX_PX, (
        np.sqrt(np.mean(e**2)), e.max())


def test_intrinsics_from_image_folder(frames_dir, truth):
    est = calibrate_camera(frames_dir, board=(9, 6), square_mm=25.0)
    check_against_truth(est, truth, F_REL, PP_PX, DIST_PX)
    assert est.rms_px is not None and 0 < est.rms_px < 0.15
    assert len(est.frames_used) >= 18 and set(est.frames_used) <= set(range(20))
    assert est.dist_coeffs[4] == 0.0  # k3 fixed unless asked for
    assert "9x6" in est.source and "25 mm" in est.source


def test_intrinsics_from_h264_video(tmp_path, truth):
    """Each view held for three frames of an H.264 video: stills are counted once."""
    video = write_views(tmp_path, truth, BOARD, n_views=16, seed=8, video_format="mp4",
                        hold_frames=3)
    res = run_camera_calibration(video, (9, 6), 25.0)
    assert res.frames_examined == 48 and res.boards_found == 16
    check_against_truth(res.intrinsics, truth, F_REL_VIDEO, PP_PX_VIDEO, DIST_PX_VIDEO)
    assert res.intrinsics.rms_px < 0.3
    # the view of a still board is the first of its frames
    assert all(k % 3 == 0 for k in res.intrinsics.frames_used)


def test_scale_of_the_board_does_not_change_the_intrinsics(frames_dir):
    """Square size only scales the poses; a 10 % wrong size leaves the camera unchanged."""
    a = calibrate_camera(frames_dir, (9, 6), 25.0)
    b = calibrate_camera(frames_dir, (9, 6), 27.5)
    assert np.allclose(a.camera_matrix, b.camera_matrix, rtol=1e-6, atol=1e-6)


def test_outlier_view_is_dropped(frames_dir, truth):
    with open_video(frames_dir) as video:
        views, _ = detect_boards(video, (9, 6))
    rng = np.random.default_rng(1)
    bad = BoardView(views[3].frame, views[3].corners_px + rng.normal(0, 2.5, (54, 2)))
    views = views[:3] + [bad] + views[4:]
    est, used, errs, rejected = calibrate_views(views, (9, 6), 25.0, (W, H))
    assert rejected == [bad.frame] and bad.frame not in est.frames_used
    assert len(used) == len(errs) == 19
    check_against_truth(est, truth, F_REL, PP_PX, DIST_PX)


def test_too_few_boards_is_refused(tmp_path, frames_dir):
    few = tmp_path / "few"
    few.mkdir()
    for f in sorted(frames_dir.glob("*.png"))[:5]:
        shutil.copy(f, few / f.name)
    with pytest.raises(CalibrationError) as err:
        calibrate_camera(few)
    assert err.value.code == "E-TOO-FEW-BOARDS"
    assert "5 distinct view(s)" in str(err.value) and "at least 8" in str(err.value)
    # the wrong board size finds nothing
    with pytest.raises(CalibrationError) as err:
        calibrate_camera(frames_dir, board=(8, 6), max_frames=6)
    assert err.value.code == "E-TOO-FEW-BOARDS" and "8x6" in str(err.value)


def test_progress_and_cancel(frames_dir):
    seen = []
    calibrate_camera(frames_dir, progress=lambda f, m: seen.append(f))
    assert seen[0] == 0.0 and seen[-1] == 1.0 and seen == sorted(seen)
    token = CancelToken()

    def cancel_soon(frac, msg):
        if frac > 0.2:
            token.cancel()

    with pytest.raises(Cancelled):
        calibrate_camera(frames_dir, progress=cancel_soon, cancel=token)


def test_board_option_parsing():
    assert parse_board("9x6") == (9, 6) and parse_board("7X5") == (7, 5)
    for bad in ("9by6", "9x", "2x6", "9x100"):
        with pytest.raises(InputError):
            parse_board(bad)


def test_cli_writes_an_intrinsics_file(tmp_path, frames_dir, truth, capsys):
    from impress_gui.cli import main

    out = tmp_path / "intrinsics.json"
    code = main(["calibrate-camera", str(frames_dir), "--board", "9x6", "--square-mm", "25",
                 "-o", str(out), "--quiet"])
    text = capsys.readouterr().out
    assert code == 0, text
    est = Intrinsics.load(out)
    check_against_truth(est, truth, F_REL, PP_PX, DIST_PX)
    doc = json.loads(out.read_text())
    assert doc["rms_px"] > 0 and len(doc["frames_used"]) >= 18
    assert "RMS reprojection error" in text and str(out) in text
    assert "readout_ms" not in doc and "shutter          not given" in text
    # a rolling-shutter camera: its readout is recorded with the lens
    out2 = tmp_path / "rolling.json"
    code = main(["calibrate-camera", str(frames_dir), "--board", "9x6", "--square-mm", "25",
                 "-o", str(out2), "--quiet", "--readout-ms", "27.5"])
    text = capsys.readouterr().out
    assert code == 0, text
    assert Intrinsics.load(out2).readout_ms == 27.5 and "readout 27.5 ms" in text
    assert np.array_equal(Intrinsics.load(out2).camera_matrix, est.camera_matrix)


@pytest.mark.parametrize("args, message", [
    (["--board", "9by6"], "E-BOARD"),
    (["--board", "8x5"], "E-TOO-FEW-BOARDS"),
    (["--square-mm", "0"], "square size"),
    (["-o", "intrinsics.txt"], "--output"),
    (["--readout-ms", "-3"], "E-VALUE"),
    (["--readout-ms", "500"], "--readout-ms"),
])
def test_cli_errors_are_clear(tmp_path, frames_dir, capsys, args, message):
    from impress_gui.cli import main

    argv = ["calibrate-camera", str(frames_dir), "--max-frames", "5", "--quiet"]
    if "-o" not in args:
        argv += ["-o", str(tmp_path / "i.json")]
    code = main(argv + args)
    err = capsys.readouterr().err
    assert code == 2 and message in err, err
    assert not (tmp_path / "i.json").exists()


def test_cli_missing_input(tmp_path, capsys):
    from impress_gui.cli import main

    code = main(["calibrate-camera", str(tmp_path / "nothing.mp4"), "-o", str(tmp_path / "i.json")])
    assert code == 2 and "no such file" in capsys.readouterr().err
