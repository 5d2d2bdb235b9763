"""The reconstruction job as one call: a video and a scene calibration in, a written
reconstruction folder out.

:func:`run_reconstruction` is the job itself; it takes the calibration in memory with the
record of where it came from (:class:`CalibrationInput`), so the window hands over the
calibration it holds as it is. :func:`process_files` (``impress process``, ``impress batch``)
is a thin reader of files around it.
"""

from __future__ import annotations

import platform
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from impress_gui.core.base import codes
from impress_gui.core.base.errors import IntegrityError
from impress_gui.core.base.fileio import read_regular
from impress_gui.core.base.outdir import OutputFolder
from impress_gui.core.base.progress import report, sub_progress
from impress_gui.core.calibration.scene import SceneCalibration
from impress_gui.core.formats.provenance import (
    input_record,
    reconstruction_inputs,
    recorded_sha256,
)
from impress_gui.core.formats.recon_files import RECON_FILES
from impress_gui.core.formats.video import open_video
from impress_gui.core.formats.writers import build_metadata, input_dates, write_reconstruction
from impress_gui.core.reconstruction.reconstruct import reconstruct


@dataclass(frozen=True)
class CalibrationInput:
    """A scene calibration in memory and the record of its source written into the
    reconstruction's metadata (:func:`~impress_gui.core.formats.provenance.input_record`:
    the file it was read from or kept in, and the SHA-256 of that file's bytes, which are
    exactly the calibration used)."""

    calibration: SceneCalibration
    record: dict[str, str]

    @property
    def path(self) -> Path:
        return Path(self.record["path"])


def read_calibration(path: str | Path) -> CalibrationInput:
    """A scene calibration file read once: the hash recorded is of the bytes parsed."""
    import hashlib


    raw = read_regular(Path(path), "calibration", 50 << 20)
    cal = SceneCalibration.from_bytes(raw, path)
    return CalibrationInput(cal, input_record(path, hashlib.sha256(raw).hexdigest()))


def check_process_output(out_dir: Path, video_path: Path, calibration_path: Path | None):
    """The output folder checked (and its hidden work folder made) before any work: see
    :class:`~impress_gui.core.base.outdir.OutputFolder`."""

    return OutputFolder(
        out_dir, "reconstruction", inputs=(video_path, calibration_path), allowed=RECON_FILES
    )


def process_files(
    video_path: Path,
    calibration_path: Path,
    out_dir: Path,
    params,
    fps: float | None = None,
    progress=None,
    cancel=None,
    expected_video_sha256: str | None = None,
    preview=None,
) -> dict:
    """The job on files (the CLI's and the batch's): the output folder checked, the
    calibration file read, then :func:`run_reconstruction`; returns the metadata."""
    video_path, calibration_path = Path(video_path), Path(calibration_path)
    params.validate()
    folder = check_process_output(Path(out_dir), video_path, calibration_path)
    try:
        calibration = read_calibration(calibration_path)
    except BaseException:
        folder.abort()
        raise
    return run_reconstruction(
        video_path,
        calibration,
        folder,
        params,
        fps=fps,
        progress=progress,
        cancel=cancel,
        expected_video_sha256=expected_video_sha256,
        preview=preview,
    )


#: the relative difference of the frame rate read from the calibration's beyond which a
#: run is warned of (a video's own rate is measured from its timestamps to about 0.1 %)
FPS_TOLERANCE = 0.002


def frame_rate_warnings(video_fps: float, calibration_fps: float, given: float | None
                        ) -> list[str]:
    """``W-FPS-OTHER`` when the video is read at another frame rate than the calibration was
    made at: each frame's travel (time x speed), and with it the map's length along the scan
    and every height, follows the rate the video is read at."""
    if abs(video_fps - calibration_fps) <= FPS_TOLERANCE * calibration_fps:
        return []
    how = "the rate given (--fps)" if given is not None else "its own rate"
    return [f"W-FPS-OTHER: the video is read at {video_fps:.6g} frames/s ({how}) but the "
            f"calibration was made at {calibration_fps:.6g} frames/s: each frame's travel, "
            "the map's length along the scan and its heights follow the rate read"]


def run_reconstruction(
    video_path: Path,
    calibration: CalibrationInput,
    out_dir: Path | OutputFolder,
    params,
    fps: float | None = None,
    progress=None,
    cancel=None,
    expected_video_sha256: str | None = None,
    preview=None,
) -> dict:
    """Read the video, reconstruct with the calibration in memory, write; return metadata
    (with the run's record under ``run``).

    ``out_dir`` is a folder to check (with ``params``) before any work, or an
    :class:`~impress_gui.core.base.outdir.OutputFolder` checked already (nothing that is not a
    previous result of this product is ever replaced: ``E-OUTPUT-*`` errors). The video is
    opened once and the hash recorded is that of the open file that is decoded; a file written
    to during the run is refused (``E-EVIDENCE-CHANGED``). ``expected_video_sha256`` (the hash
    recorded when the evidence was added to a project): processing is refused with
    IntegrityError ``E-EVIDENCE-CHANGED`` when the video's hash differs. ``cancel`` is the
    core's token (the reconstruction raises Cancelled; nothing is written)."""


    video_path = Path(video_path)
    cal = calibration.calibration
    if isinstance(out_dir, OutputFolder):
        folder = out_dir
    else:
        params.validate()
        folder = check_process_output(Path(out_dir), video_path, calibration.path)
    try:
        t0 = time.perf_counter()
        with open_video(video_path, fps=fps) as video:
            video_sha = video.sha256()
            if expected_video_sha256 and video_sha != expected_video_sha256:
                raise IntegrityError(
                    f"the evidence video {video_path} has changed since it was added to the "
                    f"project (SHA-256 {video_sha[:12]}... instead of "
                    f"{expected_video_sha256[:12]}...); processing refused",
                    code=codes.E_EVIDENCE_CHANGED,
                )
            warnings = []
            recorded = recorded_sha256(cal.inputs, "video")
            if recorded and recorded != video_sha:
                warnings.append(
                    "W-CALIB-OTHER-VIDEO: the video differs from the one the "
                    "calibration was made on (SHA-256 mismatch)"
                )
            warnings += frame_rate_warnings(video.fps, cal.fps, fps)
            rec = reconstruct(
                video,
                cal,
                params,
                progress=sub_progress(progress, 0.0, 0.93),
                cancel=cancel,
                preview=preview,
            )
            video.check_unchanged()
            warnings += video.damage_warnings()
            dates = input_dates(video, calibration.path)
        rec.warnings[:0] = warnings
        inputs = reconstruction_inputs(input_record(video_path, video_sha), calibration.record)
        meta: dict[str, Any] = build_metadata(rec, cal, params, inputs)
        # the frame rate the video was read at, and the one given for it (``--fps``), if any
        meta["frame_rate"] = {"fps": float(video.fps),
                              "given_fps": None if fps is None else float(fps)}
        meta["dates"] = dates
        run = {
            "date_utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "host": platform.node(),
            "python": platform.python_version(),
            "timings": rec.run_stats(),
            "wall_seconds": round(time.perf_counter() - t0, 3),
        }
        report(progress, 0.93, "writing the outputs")
        meta["files"] = write_reconstruction(
            rec, folder, meta, run, dates=dates, progress=sub_progress(progress, 0.93, 1.0)
        )
    except BaseException:
        folder.abort()
        raise
    return meta | {"run": run}
