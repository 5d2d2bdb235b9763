"""The processing tab's background jobs (no Qt here): learning the background lookup tables
for the preview, and one reconstruction run into a project folder."""

from __future__ import annotations

import hashlib
import shutil
from datetime import datetime
from pathlib import Path

from impress_gui.core.base.errors import Cancelled, ImpressError
from impress_gui.core.calibration.scene import SceneCalibration
from impress_gui.core.formats.video import open_video
from impress_gui.core.reconstruction.reconstruct import ProcessParams, learn_background
from impress_gui.core.reconstruction.stripes import BackgroundLUT


def learn_lut(
    video_path: Path, start: int, stop: int, rois, n_frames: int, cancel
) -> BackgroundLUT:
    """The background tables as the reconstruction learns them, read through a video handle
    of its own (the GUI's is not shared between threads)."""
    with open_video(video_path) as video:
        return learn_background(video, start, stop, rois, n_frames, cancel)


def new_output_folder(base: Path) -> Path:
    """A fresh ``base/recon-<date-time>`` folder name (not created)."""
    stamp = datetime.now().strftime("%Y%m%d-%H%M%S")
    out, k = base / f"recon-{stamp}", 1
    while out.exists():
        k += 1
        out = base / f"recon-{stamp}-{k}"
    return out


def reconstruct_into(
    video: Path,
    cal: SceneCalibration,
    cal_path: Path,
    out: Path,
    params: ProcessParams,
    fps: float | None,
    progress,
    cancel,
    expected_video_sha256: str | None = None,
    preview=None,
) -> tuple[dict, str]:
    """Save the calibration used beside the output (the reconstruction's metadata records its
    path and hash), run :func:`~impress_gui.core.reconstruction.pipeline.process_files` into ``out`` and
    return ``(metadata, SHA-256 of metadata.json)``. A cancelled run leaves nothing behind."""
    from impress_gui.core.reconstruction.pipeline import process_files

    out.parent.mkdir(parents=True, exist_ok=True)
    cal.save(cal_path)
    try:
        meta = process_files(
            video,
            cal_path,
            out,
            params,
            fps=fps,
            progress=progress,
            cancel=cancel,
            expected_video_sha256=expected_video_sha256,
            preview=preview,
        )
        # The reconstruction's frame reader stops at a cancel and the frame loop can end
        # without noticing: a result (or an error) then stems from a truncated run.
        if cancel.cancelled:
            shutil.rmtree(out, ignore_errors=True)
            raise Cancelled("cancelled by the user")
    except ImpressError:
        cal_path.unlink(missing_ok=True)
        if cancel.cancelled:
            raise Cancelled("cancelled by the user") from None
        raise
    except BaseException:
        cal_path.unlink(missing_ok=True)
        raise
    return meta, hashlib.sha256((out / "metadata.json").read_bytes()).hexdigest()
