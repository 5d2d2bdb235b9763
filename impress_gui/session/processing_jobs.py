"""The processing tab's background jobs (no Qt here): learning the background lookup tables
for the preview, and one reconstruction run into a project folder."""

from __future__ import annotations

import hashlib
import shutil
from datetime import datetime
from pathlib import Path

from impress_gui.core.base.fileio import atomic_write_bytes, dumps_json, sha256_file
from impress_gui.core.calibration.scene import SceneCalibration
from impress_gui.core.formats.provenance import input_record
from impress_gui.core.formats.recon_files import METADATA_FILE
from impress_gui.core.formats.video import open_video
from impress_gui.core.reconstruction.pipeline import CalibrationInput, run_reconstruction
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
    """Reconstruct ``video`` into ``out`` with the calibration in memory
    (:func:`~impress_gui.core.reconstruction.pipeline.run_reconstruction`) and return
    ``(metadata, SHA-256 of metadata.json)``. The calibration used is kept beside the output
    at ``cal_path``: the metadata records that file and its hash, and the viewer reads it.
    A cancelled or failed run leaves nothing behind."""

    raw = dumps_json(cal.to_json()).encode("utf-8")  # the bytes SceneCalibration.save writes
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(cal_path, raw)
    calibration = CalibrationInput(cal, input_record(cal_path, hashlib.sha256(raw).hexdigest()))
    written = False
    try:
        meta = run_reconstruction(
            video,
            calibration,
            out,
            params,
            fps=fps,
            progress=progress,
            cancel=cancel,
            expected_video_sha256=expected_video_sha256,
            preview=preview,
        )
        written = True
        sha = sha256_file(out / METADATA_FILE)
        # the one check of the cancel here (the reconstruction raises Cancelled itself when it
        # sees it): a cancel that came while the outputs were written is a cancelled run too,
        # and a cancelled run leaves nothing
        cancel.check()
    except BaseException:
        cal_path.unlink(missing_ok=True)
        if written:
            shutil.rmtree(out, ignore_errors=True)
        raise
    return meta, sha
