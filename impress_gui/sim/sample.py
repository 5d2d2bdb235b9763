"""The sample case the README's run command opens: a simulated shoe-impression scan,
calibrated from the simulator's picks and processed, in a scan project. Made once and cached."""

from __future__ import annotations

import json
import os
from pathlib import Path

from impress_gui import __version__
from impress_gui.core.base.progress import CancelToken, ProgressCallback, report, sub_progress

SAMPLE_VERSION = 5  # bump when the sample's recipe changes, to rebuild caches (5: the calibration's Gaussian row estimate)
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


#: what a sample cache folder and its project hold (anything else is not replaced)
CACHE_NAMES = {"sample.json", "project", "scan"}
PROJECT_NAMES = {"project.json", "calibration.json", "log.jsonl", "reconstruction"}
SAMPLE_CASE = "SAMPLE-0001"


def _check_cache(cache_dir: Path) -> None:
    """Refuse (E-OUTPUT-NOT-EMPTY, before anything is removed) to rebuild the sample in a
    folder that holds anything the sample did not write: its ``sample.json`` must be the
    sample's stamp and its project the sample's case, with nothing added (an examiner's notes
    there are never deleted)."""
    from impress_gui.core.base import codes
    from impress_gui.core.base.outdir import OutputError

    def refuse(what: str) -> None:
        raise OutputError(f"{cache_dir} {what}: it is not a sample this command made, and "
                          "nothing there is replaced; name another --cache folder",
                          code=codes.E_OUTPUT_NOT_EMPTY)

    if not cache_dir.exists():
        return
    if cache_dir.is_symlink() or not cache_dir.is_dir():
        refuse("is not a folder")
    foreign = sorted(p.name for p in cache_dir.iterdir()
                     if p.name not in CACHE_NAMES and not p.name.startswith("."))
    if foreign:
        refuse(f"holds {', '.join(foreign[:5])}")
    stamp = cache_dir / "sample.json"
    if stamp.exists():
        try:
            ok = "sample_version" in json.loads(stamp.read_text(encoding="utf-8"))
        except (OSError, ValueError, TypeError):
            ok = False
        if not ok:
            refuse("holds a sample.json that is not the sample's")
    project = cache_dir / "project"
    if project.exists():
        if project.is_symlink() or not project.is_dir():
            refuse("holds a 'project' that is not a folder")
        extra = sorted(p.name for p in project.iterdir() if p.name not in PROJECT_NAMES)
        if extra:
            refuse(f"holds a project with {', '.join(extra[:5])} added")
        try:
            doc = json.loads((project / "project.json").read_text(encoding="utf-8"))
            case = doc.get("case_id")
        except (OSError, ValueError, AttributeError):
            case = None
        if case != SAMPLE_CASE and (project / "project.json").exists():
            refuse("holds a project that is not the sample's case")


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
    _check_cache(cache_dir)
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
    proj: Project = create_project(project_dir, case_id=SAMPLE_CASE, evidence_id="SIM-SHOE-1",
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
