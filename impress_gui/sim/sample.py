"""The sample case the README's run command opens: a simulated shoe-impression scan,
calibrated from the simulator's picks and processed, in a scan project. Made once and cached."""

from __future__ import annotations

import json
import os
from pathlib import Path

from impress_gui import __version__
from impress_gui.core.base.progress import CancelToken, ProgressCallback, report, sub_progress

SAMPLE_VERSION = 4  # bump when the sample's recipe changes, to rebuild caches
#: set to 1 (tests only) for a tiny, fast sample instead of the README's one
SMALL_ENV = "IMPRESS_SAMPLE_SMALL"


def small_requested() -> bool:
    return os.environ.get(SMALL_ENV, "").strip().lower() not in ("", "0", "no", "false")


def sample_config(small: bool = False):
    """The sample's simulation: the README's 960x540 shoe scan, or (``small``, for tests) a
    short 320x180, 15 frames/s one on a 0.5 mm grid that builds in seconds."""
    from impress_gui.sim.simulate import SimConfig

    if small:
        return SimConfig(preset="shoe", length_mm=200.0, width=320, height=180, fps=15.0,
                         grid_mm=0.5, seed=7, click_noise_px=0.0)
    return SimConfig(preset="shoe", width=960, height=540, seed=7, click_noise_px=0.0)


def make_sample(cache_dir: Path, workers: int = 2, progress: ProgressCallback | None = None,
                cancel: CancelToken | None = None, small: bool | None = None) -> Path:
    """Build (or reuse) the sample project under ``cache_dir``; return the project folder.

    ``small`` (default: ``$IMPRESS_SAMPLE_SMALL``) builds a tiny sample for tests; the cache
    records which one it holds, so neither is mistaken for the other."""
    from impress_gui.core.calibration.geometry import Intrinsics
    from impress_gui.core.calibration.picks import Picks
    from impress_gui.core.calibration.scene import calibrate_scene
    from impress_gui.core.calibration.target import TargetModel
    from impress_gui.core.formats.video import open_video
    from impress_gui.core.project.project import Project, create_project
    from impress_gui.core.reconstruction.pipeline import process_files
    from impress_gui.core.reconstruction.reconstruct import ProcessParams
    from impress_gui.sim.simulate import simulate

    if small is None:
        small = small_requested()
    cache_dir = Path(cache_dir)
    stamp = cache_dir / "sample.json"
    project_dir = cache_dir / "project"
    if stamp.exists():
        try:
            info = json.loads(stamp.read_text())
            if (info.get("sample_version") == SAMPLE_VERSION
                    and bool(info.get("small", False)) == small
                    and (project_dir / "project.json").exists()):
                return project_dir
        except (OSError, ValueError):
            pass
    cfg = sample_config(small)
    stamp.unlink(missing_ok=True)  # rebuilt: stale until the new sample is complete
    scan = cache_dir / "scan"
    report(progress, 0.0, "simulating the sample scan")
    simulate(cfg, scan, workers=workers, progress=sub_progress(progress, 0.0, 0.7), cancel=cancel)
    truth = json.loads((scan / "truth.json").read_text())
    intr = Intrinsics.load(scan / "intrinsics.json")
    target = TargetModel.load(scan / "target.json")
    picks = Picks.load(scan / "picks.json")
    report(progress, 0.72, "calibrating")
    with open_video(scan / truth["video"]) as video:
        cal = calibrate_scene(video, intr, target, picks, truth["speed_mm_s"], cancel=cancel)
    if project_dir.exists():
        import shutil

        shutil.rmtree(project_dir)
    proj: Project = create_project(project_dir, case_id="SAMPLE-0001", evidence_id="SIM-SHOE-1",
                                   examiner="demo",
                                   notes="Simulated shoe impression (impress simulate, seed 7); "
                                         "corner picks are the simulator's exact positions.")
    proj.set_video(scan / truth["video"], sha256=truth["video_sha256"])
    proj.set_intrinsics(intr)
    proj.set_target(target)
    proj.set_picks(picks)
    proj.set_calibration_settings({"speed_mm_s": truth["speed_mm_s"]})
    proj.set_calibration(cal)
    cal_path = project_dir / "calibration.json"
    cal.save(cal_path)
    params = ProcessParams(grid_mm=cfg.grid_mm) if small else ProcessParams()
    proj.set_processing(params.to_json())
    report(progress, 0.75, "processing")
    out = project_dir / "reconstruction"
    process_files(scan / truth["video"], cal_path, out, params,
                  progress=sub_progress(progress, 0.75, 1.0), cancel=cancel)
    proj.add_output(out / "metadata.json", "reconstruction")
    proj.save()
    stamp.write_text(json.dumps({"sample_version": SAMPLE_VERSION, "small": small,
                                      "software": __version__}))
    report(progress, 1.0, "sample ready")
    return project_dir
