"""The calibration jobs (Qt-free, each following the ``(progress, cancel)`` contract): open and
fingerprint the evidence video, propose the calibration frames, calibrate the scene from the
picks, calibrate the camera from checkerboard views. Each opens its own reader on the video."""

from __future__ import annotations

from pathlib import Path

from impress_gui.core.base import codes
from impress_gui.core.base.errors import InputError
from impress_gui.core.base.progress import CancelToken, ProgressCallback, sub_progress
from impress_gui.core.calibration.aids import propose_calibration_frames
from impress_gui.core.calibration.picks import Picks
from impress_gui.core.calibration.scene import calibrate_scene
from impress_gui.core.formats.video import VideoSource, open_video
from impress_gui.core.project.project import Project, hash_file


def open_evidence(
    path: Path, progress: ProgressCallback, cancel: CancelToken, project: Project | None = None
) -> tuple[VideoSource, str]:
    """Open the scan video and fingerprint it (worker thread). With ``project``, check the
    video against the SHA-256 recorded there first (IntegrityError when it changed)."""
    path = Path(path)
    if path.is_dir():
        raise InputError(
            f"{path} is a folder; open the scan's video file (its SHA-256 is recorded as evidence)",
            code=codes.E_VIDEO_OPEN,
        )
    if project is not None:
        digest = project.check_evidence(sub_progress(progress, 0.0, 0.9), cancel)
        return open_video(path), digest
    video = open_video(path)
    try:
        return video, hash_file(path, sub_progress(progress, 0.05, 1.0), cancel)
    except BaseException:
        video.close()
        raise


def propose_task(path: Path):
    def task(progress: ProgressCallback, cancel: CancelToken) -> dict[str, int]:
        with open_video(path) as video:
            return propose_calibration_frames(video, progress=progress, cancel=cancel)

    return task


def calibrate_task(path: Path, intr, target, picks: Picks, speed_mm_s: float, inputs: dict):
    def task(progress: ProgressCallback, cancel: CancelToken):
        with open_video(path) as video:
            return calibrate_scene(
                video,
                intr,
                target,
                picks,
                speed_mm_s,
                progress=progress,
                cancel=cancel,
                inputs=inputs,
            )

    return task


def checkerboard_task(source: Path, board: tuple[int, int] = (9, 6), square_mm: float = 25.0):
    """Camera intrinsics from checkerboard views: ``source`` is a video file or a folder of
    images, ``board`` the inner corners (columns, rows)."""

    def task(progress: ProgressCallback, cancel: CancelToken):
        from impress_gui.core.calibration.intrinsics import calibrate_camera

        return calibrate_camera(Path(source), board, square_mm, progress=progress, cancel=cancel)

    return task
