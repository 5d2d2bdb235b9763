"""The reconstruction job as one call: read the inputs, reconstruct, write the outputs.

Shared by ``impress process`` and the GUI's processing tab.
"""

from __future__ import annotations

import time
from pathlib import Path


def check_process_output(out_dir: Path, video_path: Path, calibration_path: Path):
    """The output folder checked (and its hidden work folder made) before any work: see
    :class:`~impress_gui.core.base.outdir.OutputFolder`."""
    from impress_gui.core.base.outdir import OutputFolder
    from impress_gui.core.formats.writers import RECON_FILES

    return OutputFolder(out_dir, "reconstruction", inputs=(video_path, calibration_path),
                        allowed=RECON_FILES)


def process_files(video_path: Path, calibration_path: Path, out_dir: Path, params,
                  fps: float | None = None, progress=None, cancel=None,
                  expected_video_sha256: str | None = None, preview=None) -> dict:
    """Core entry shared by the CLI and the GUI: read, reconstruct, write; return metadata.

    The output folder is checked before any work (nothing that is not a previous result of
    this product is ever replaced: ``E-OUTPUT-*`` errors). The video is opened once and the
    hash recorded is that of the open file that is decoded; a file written to during the run
    is refused (``E-EVIDENCE-CHANGED``). ``expected_video_sha256`` (the hash recorded when the
    evidence was added to a project): processing is refused with IntegrityError
    ``E-EVIDENCE-CHANGED`` when the video's hash differs."""
    import hashlib
    import platform
    from datetime import datetime, timezone

    from impress_gui.core.base.errors import IntegrityError
    from impress_gui.core.base.fileio import read_regular
    from impress_gui.core.base.progress import report, sub_progress
    from impress_gui.core.calibration.scene import SceneCalibration
    from impress_gui.core.formats.video import open_video
    from impress_gui.core.formats.writers import build_metadata, input_dates, write_reconstruction
    from impress_gui.core.reconstruction.reconstruct import reconstruct

    video_path, calibration_path = Path(video_path), Path(calibration_path)
    params.validate()
    folder = check_process_output(Path(out_dir), video_path, calibration_path)
    try:
        # the calibration's bytes are read once: the hash recorded is of what is parsed
        cal_bytes = read_regular(calibration_path, "calibration", 50 << 20)
        cal = SceneCalibration.from_bytes(cal_bytes, calibration_path)
        inputs: dict[str, dict[str, str | None]] = {"calibration": {
            "path": str(calibration_path), "sha256": hashlib.sha256(cal_bytes).hexdigest()}}
        t0 = time.perf_counter()
        with open_video(video_path, fps=fps) as video:
            video_sha = video.sha256()
            inputs["video"] = {"path": str(video_path), "sha256": video_sha}
            if expected_video_sha256 and video_sha != expected_video_sha256:
                raise IntegrityError(
                    f"the evidence video {video_path} has changed since it was added to the "
                    f"project (SHA-256 {video_sha[:12]}... instead of "
                    f"{expected_video_sha256[:12]}...); processing refused",
                    code="E-EVIDENCE-CHANGED")
            warnings = []
            recorded = cal.inputs.get("video", {}).get("sha256") if cal.inputs else None
            if recorded and recorded != video_sha:
                warnings.append("W-CALIB-OTHER-VIDEO: the video differs from the one the "
                                "calibration was made on (SHA-256 mismatch)")
            rec = reconstruct(video, cal, params, progress=sub_progress(progress, 0.0, 0.93),
                              cancel=cancel, preview=preview)
            video.check_unchanged()
            warnings += video.damage_warnings()
            dates = input_dates(video, calibration_path)
        rec.warnings[:0] = warnings
        meta = build_metadata(rec, cal, params, inputs)
        meta["dates"] = dates
        run = {"date_utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
               "host": platform.node(), "python": platform.python_version(),
               "timings": rec.run_stats(),
               "wall_seconds": round(time.perf_counter() - t0, 3)}
        report(progress, 0.93, "writing the outputs")
        meta["files"] = write_reconstruction(rec, folder, meta, run, dates=dates,
                                             progress=sub_progress(progress, 0.93, 1.0))
    except BaseException:
        folder.abort()
        raise
    return meta | {"run": run}
