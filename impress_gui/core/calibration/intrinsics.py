"""Camera intrinsics from checkerboard views (a video or a folder of images).

The board is given by its *inner* corner count ``(cols, rows)`` (OpenCV's pattern size: a 9x6
board has 10 x 7 squares) and its square size in mm. Corners are found with OpenCV's
checkerboard detector and refined to sub-pixel accuracy; the sector-based detector is the
fall-back for views the classic one misses. ``cv2.calibrateCamera`` then fits the pinhole
model with distortion ``(k1, k2, p1, p2, k3)``; ``k3`` stays 0 unless asked for (with a few
dozen views it mostly trades off against ``k2`` and extrapolates badly into the corners).
Views whose reprojection error is far above the others' (a mis-detected board, motion blur)
are dropped once and the fit repeated.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from impress_gui.core.base import codes
from impress_gui.core.base.errors import CalibrationError, InputError
from impress_gui.core.base.progress import CancelToken, ProgressCallback, report
from impress_gui.core.calibration.geometry import Intrinsics

MIN_BOARDS = 8
MAX_FRAMES = 80
#: a board must move this much (mean corner shift, px) to count as another view
MIN_MOTION_PX = 4.0


@dataclass(frozen=True)
class BoardView:
    """Sub-pixel inner corners ``(N, 2)`` (OpenCV order) of the board found in frame ``frame``."""

    frame: int
    corners_px: np.ndarray


@dataclass(frozen=True)
class CameraCalibration:
    """What a checkerboard calibration found and how well the model fits it."""

    intrinsics: Intrinsics
    views: tuple[BoardView, ...]  # the views used
    view_rms_px: tuple[float, ...]  # reprojection RMS per used view
    frames_examined: int
    boards_found: int
    rejected_frames: tuple[int, ...]  # found but dropped as outliers


def parse_board(text: str) -> tuple[int, int]:
    """``"9x6"`` -> ``(9, 6)`` inner corners; raise InputError naming the problem."""
    try:
        cols, rows = (int(v) for v in text.lower().replace(" ", "").split("x"))
    except ValueError:
        raise InputError(f"board {text!r} is not COLSxROWS inner corners, e.g. 9x6",
                         code=codes.E_BOARD) from None
    check_board((cols, rows))
    return cols, rows


def check_board(board: tuple[int, int]) -> None:
    cols, rows = board
    if not (3 <= cols <= 60 and 3 <= rows <= 60):
        raise InputError(f"board {cols}x{rows}: give the inner corners, 3 to 60 each way "
                         "(a board of 10 x 7 squares is 9x6)", code=codes.E_BOARD)


def find_board(gray: np.ndarray, board: tuple[int, int]) -> np.ndarray | None:
    """Sub-pixel inner corners ``(cols * rows, 2)`` of the board in a grey image, or None."""
    import cv2

    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    scale = 1.0
    small = gray
    if max(gray.shape) > 1400:  # find at half size, refine at full size
        scale = 2.0
        small = cv2.resize(gray, (gray.shape[1] // 2, gray.shape[0] // 2),
                           interpolation=cv2.INTER_AREA)
    ok, corners = cv2.findChessboardCorners(small, board, flags=flags)
    if not ok:
        ok, corners = cv2.findChessboardCornersSB(small, board, flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
        if not ok:
            return None
    corners = corners.reshape(-1, 2).astype(np.float32)
    if scale != 1.0:
        corners = (corners + 0.5) * scale - 0.5
    grid = corners.reshape(board[1], board[0], 2)
    side = min(np.median(np.linalg.norm(np.diff(grid, axis=1), axis=2)),
               np.median(np.linalg.norm(np.diff(grid, axis=0), axis=2)))
    half = int(np.clip(side * 0.35, 2, 11))
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 60, 1e-3)
    refined = cv2.cornerSubPix(gray, corners.reshape(-1, 1, 2), (half, half), (-1, -1), crit)
    return refined.reshape(-1, 2).astype(np.float64)


def _frames_to_examine(count: int, max_frames: int) -> list[int]:
    if count <= max_frames:
        return list(range(count))
    return sorted({int(round(v)) for v in np.linspace(0, count - 1, max_frames)})


def detect_boards(video, board: tuple[int, int], progress: ProgressCallback | None = None,
                  cancel: CancelToken | None = None, max_frames: int = MAX_FRAMES,
                  min_motion_px: float = MIN_MOTION_PX) -> tuple[list[BoardView], int]:
    """Find the board in up to ``max_frames`` evenly spread frames of an open video source;
    views that barely moved since the last kept one are skipped. Return the views and the
    number of frames examined."""
    import cv2

    cancel = cancel or CancelToken()
    frames = _frames_to_examine(video.frame_count, max_frames)
    views: list[BoardView] = []
    for i, k in enumerate(frames):
        cancel.check()
        gray = cv2.cvtColor(video.read(k), cv2.COLOR_RGB2GRAY)
        corners = find_board(gray, board)
        # a board held still in a video gives the same view again: keep it once
        if corners is not None and (not views or np.mean(
                np.linalg.norm(corners - views[-1].corners_px, axis=1)) >= min_motion_px):
            views.append(BoardView(k, corners))
        report(progress, 0.9 * (i + 1) / len(frames),
               f"frame {k}: {len(views)} board view(s) so far")
    return views, len(frames)


def _fit(views, obj, size, flags):
    import cv2

    img = [v.corners_px.astype(np.float32).reshape(-1, 1, 2) for v in views]
    objs = [obj] * len(views)
    # one thread: OpenCV's parallel sums make the fit differ in the last digits from run to
    # run (the same views gave camera matrices 1e-10 apart), and the same input must give the
    # same file
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        rms, k, dist, rvecs, tvecs = cv2.calibrateCamera(objs, img, size, None, None,
                                                         flags=flags)
    finally:
        cv2.setNumThreads(threads)
    errs = []
    for v, r, t in zip(views, rvecs, tvecs, strict=True):
        proj, _ = cv2.projectPoints(obj, r, t, k, dist)
        errs.append(float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - v.corners_px) ** 2,
                                                 axis=1)))))
    return float(rms), k, dist.ravel(), errs


def calibrate_views(views: list[BoardView], board: tuple[int, int], square_mm: float,
                    image_size: tuple[int, int], fix_k3: bool = True,
                    min_boards: int = MIN_BOARDS) -> tuple[Intrinsics, list[BoardView],
                                                           list[float], list[int]]:
    """Fit the intrinsics to board views; drop outlier views once. Return the intrinsics, the
    views kept, their RMS errors and the rejected frames."""
    import cv2

    cols, rows = board
    c, r = np.meshgrid(np.arange(cols), np.arange(rows))
    obj = (np.column_stack([c.ravel(), r.ravel(), np.zeros(c.size)]) * square_mm).astype(
        np.float32)
    flags = cv2.CALIB_FIX_K3 if fix_k3 else 0
    rms, k, dist, errs = _fit(views, obj, image_size, flags)
    limit = max(3.0 * float(np.median(errs)), 0.5)
    keep = [i for i, e in enumerate(errs) if e <= limit]
    rejected = [views[i].frame for i in range(len(views)) if i not in keep]
    if rejected and len(keep) >= min_boards:
        views = [views[i] for i in keep]
        rms, k, dist, errs = _fit(views, obj, image_size, flags)
    else:
        rejected = []
    w, h = image_size
    if (not np.all(np.isfinite(k)) or not np.all(np.isfinite(dist)) or k[0, 0] <= 0
            or k[1, 1] <= 0 or not (0 < k[0, 2] < w and 0 < k[1, 2] < h)):
        raise CalibrationError("the fit did not converge to a usable camera (focal length or "
                               "principal point out of range); use views with the board "
                               "tilted and in all parts of the image", code=codes.E_CALIB_DEGENERATE)
    intr = Intrinsics(k, dist[:5], image_size, rms_px=rms,
                      frames_used=tuple(v.frame for v in views))
    return intr, views, errs, rejected


def run_camera_calibration(source, board: tuple[int, int] = (9, 6), square_mm: float = 25.0,
                           progress: ProgressCallback | None = None,
                           cancel: CancelToken | None = None, *, min_boards: int = MIN_BOARDS,
                           max_frames: int = MAX_FRAMES, fix_k3: bool = True) -> CameraCalibration:
    """Calibrate from ``source``: a video file, a folder of images, or an open
    :class:`~impress_gui.core.formats.video.VideoSource`. Raise CalibrationError
    ``E-TOO-FEW-BOARDS`` when the board is found in fewer than ``min_boards`` distinct views."""
    from impress_gui.core.formats.video import open_video

    check_board(board)
    if not (np.isfinite(square_mm) and 0.1 <= square_mm <= 1000.0):
        raise InputError("the square size must be between 0.1 and 1000 mm", code=codes.E_BOARD)
    if min_boards < 3:
        raise InputError("at least 3 board views are needed for a calibration", code=codes.E_BOARD)
    own = isinstance(source, (str, Path))
    video = open_video(source) if own else source
    try:
        report(progress, 0.0, "looking for the checkerboard")
        views, examined = detect_boards(video, board, progress, cancel, max_frames)
        name = Path(getattr(video, "path", "") or "").name
        size = tuple(video.size)
    finally:
        if own:
            video.close()
    if len(views) < min_boards:
        raise CalibrationError(
            f"found the {board[0]}x{board[1]} board (inner corners) in {len(views)} distinct "
            f"view(s) of the {examined} frames examined; at least {min_boards} are needed. Check "
            "the board size (count inner corners, e.g. 9x6 for 10 x 7 squares), that the whole "
            "board is in view, lit evenly and sharp, and move it between views",
            code=codes.E_TOO_FEW_BOARDS)
    report(progress, 0.92, f"fitting the camera model to {len(views)} views")
    intr, used, errs, rejected = calibrate_views(views, board, square_mm, size, fix_k3,
                                                 min_boards)
    intr = Intrinsics(intr.camera_matrix, intr.dist_coeffs, intr.image_size, intr.rms_px,
                      intr.frames_used, f"checkerboard {board[0]}x{board[1]} inner corners, "
                      f"{square_mm:g} mm squares, {len(used)} views of {name or 'the video'}")
    report(progress, 1.0, f"RMS reprojection error {intr.rms_px:.3f} px")
    return CameraCalibration(intr, tuple(used), tuple(errs), examined, len(views),
                             tuple(rejected))


def calibrate_camera(source, board: tuple[int, int] = (9, 6), square_mm: float = 25.0,
                     progress: ProgressCallback | None = None,
                     cancel: CancelToken | None = None, **options) -> Intrinsics:
    """Intrinsics (with ``rms_px`` and ``frames_used``) from checkerboard views; see
    :func:`run_camera_calibration` for the sources and options."""
    return run_camera_calibration(source, board, square_mm, progress, cancel, **options).intrinsics
