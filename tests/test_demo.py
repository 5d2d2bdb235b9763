"""The README's main command (``./run.sh`` -> ``impress demo``): the sample project it builds
and caches, on the tiny test configuration (``small=True`` / ``IMPRESS_SAMPLE_SMALL=1``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from impress_gui.core.measure import readings as M
from impress_gui.core.project.project import PROJECT_FILE, Project
from impress_gui.sim import sample


def check_sample_project(project_dir: Path) -> None:
    """A complete sample project: it opens (evidence verified), is calibrated, and its newest
    output is a reconstruction with a heightmap that covers the scene."""
    proj = Project.load(project_dir)
    assert proj.case_id == "SAMPLE-0001"
    assert proj.calibration is not None
    assert (project_dir / "calibration.json").exists()
    recon = project_dir / "reconstruction"
    assert [o["kind"] for o in proj.outputs][-1] == "reconstruction"
    data = M.load_reconstruction(recon)
    fused = data.layers["fused"]
    assert np.isfinite(fused).mean() > 0.2
    for name in ("metadata.json", "heightmap.tif", "heightmap.x3p", "pointcloud.ply"):
        assert (recon / name).stat().st_size > 0, name


def test_make_sample_builds_a_complete_project_and_reuses_the_cache(tmp_path, monkeypatch):
    cache = tmp_path / "sample"
    steps: list[str] = []
    project_dir = sample.make_sample(cache, workers=1, small=True,
                                     progress=lambda f, msg: steps.append(msg))
    assert project_dir == cache / "project"
    check_sample_project(project_dir)
    assert steps[-1] == "sample ready" and "calibrating" in steps and "processing" in steps
    stamp = json.loads((cache / "sample.json").read_text())
    assert stamp["sample_version"] == sample.SAMPLE_VERSION and stamp["small"] is True

    # the second call reuses the cache: nothing is simulated again, nothing rewritten
    import impress_gui.sim.simulate as simulate_mod

    def no_rebuild(*a, **k):
        raise AssertionError("the cached sample was rebuilt")

    monkeypatch.setattr(simulate_mod, "simulate", no_rebuild)
    mtime = (project_dir / PROJECT_FILE).stat().st_mtime_ns
    assert sample.make_sample(cache, small=True) == project_dir
    assert (project_dir / PROJECT_FILE).stat().st_mtime_ns == mtime
    monkeypatch.setenv(sample.SMALL_ENV, "1")
    assert sample.make_sample(cache) == project_dir  # the variable chooses the small one too

    # ... but a small sample is never taken for the README's full one
    monkeypatch.delenv(sample.SMALL_ENV)
    with pytest.raises(AssertionError, match="rebuilt"):
        sample.make_sample(cache)


def test_the_default_sample_is_the_readme_one(monkeypatch):
    monkeypatch.delenv(sample.SMALL_ENV, raising=False)
    assert not sample.small_requested()
    cfg = sample.sample_config()
    assert (cfg.preset, cfg.width, cfg.height, cfg.seed) == ("shoe", 960, 540, 7)
    assert cfg.length_mm is None and cfg.fps == 30.0
    monkeypatch.setenv(sample.SMALL_ENV, "0")
    assert not sample.small_requested()
    monkeypatch.setenv(sample.SMALL_ENV, "1")
    assert sample.small_requested()


def test_impress_demo_no_gui_builds_the_sample(tmp_path):
    """The command itself (as ``./run.sh`` runs it, but without the window)."""
    env = {**os.environ, sample.SMALL_ENV: "1", "HOME": str(tmp_path)}
    env.pop("IMPRESS_CACHE", None)
    cmd = [sys.executable, "-m", "impress_gui", "demo", "--no-gui", "--cache",
           str(tmp_path / "cache")]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=env)
    assert res.returncode == 0, res.stderr
    assert "Traceback" not in res.stderr
    project_dir = tmp_path / "cache" / "sample" / "project"
    assert f"sample project: {project_dir} (ready in" in res.stdout
    assert "reconstruction/heightmap.tif" in res.stdout
    check_sample_project(project_dir)
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=60, env=env)
    assert again.returncode == 0, again.stderr
    assert "simulating" not in again.stderr  # reused, not rebuilt
