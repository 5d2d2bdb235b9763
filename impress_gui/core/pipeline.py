"""The reconstruction job as one call: read the inputs, reconstruct, write the outputs.

Shared by ``impress process`` and the GUI's processing tab.
"""

from __future__ import annotations

import time
from pathlib import Path


def process_files(video_path: Path, calibration_path: Path, out_dir: Path, params,
                  fps: float | None = None, progress=None, cancel=None,
                  expected_video_sha256: str | None = None, preview=None) -> dict:
    """Core entry shared by the CLI and the GUI: read, reconstruct, write; return metadata.

    ``expected_video_sha256`` (the hash recorded when the evidence was added to a project):
    processing is refused with IntegrityError ``E-EVIDENCE-CHANGED`` when the video's hash
    differs."""
    import platform
    from datetime import datetime, timezone

    from impress_gui.core.calibration import SceneCalibration
    from impress_gui.core.fileio import sha256_file, sha256_path
    from impress_gui.core.outputs import build_metadata, write_reconstruction
    from impress_gui.core.reconstruct import reconstruct
    from impress_gui.core.video import open_video

    cal = SceneCalibration.load(calibration_path)
    inputs: dict[str, dict[str, str | None]] = {"calibration": {"path": str(calibration_path),
                              "sha256": sha256_file(calibration_path)}}
    # a frame folder: the hash of its manifest; a missing file: open_video says so below
    video_sha = sha256_path(video_path) if Path(video_path).exists() else None
    inputs["video"] = {"path": str(video_path), "sha256": video_sha}
    if expected_video_sha256 and video_sha != expected_video_sha256:
        from impress_gui.core.errors import IntegrityError

        raise IntegrityError(
            f"the evidence video {video_path} has changed since it was added to the project "
            f"(SHA-256 {str(video_sha)[:12]}... instead of {expected_video_sha256[:12]}...); "
            "processing refused", code="E-EVIDENCE-CHANGED")
    warnings = []
    recorded = cal.inputs.get("video", {}).get("sha256") if cal.inputs else None
    if recorded and video_sha and recorded != video_sha:
        warnings.append("the video differs from the one the calibration was made on "
                        "(SHA-256 mismatch)")
    t0 = time.perf_counter()
    with open_video(video_path, fps=fps) as video:
        rec = reconstruct(video, cal, params, progress=progress, cancel=cancel,
                          preview=preview)
    rec.warnings[:0] = warnings
    meta = build_metadata(rec, cal, params, inputs)
    run = {"date_utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
           "host": platform.node(), "python": platform.python_version(),
           "timings": rec.run_stats(),
           "wall_seconds": round(time.perf_counter() - t0, 3)}
    meta["files"] = write_reconstruction(rec, out_dir, meta, run)
    return meta | {"run": run}


