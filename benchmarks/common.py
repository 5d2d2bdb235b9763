"""Shared helpers for the benchmarks: cached simulator scans and truth comparison."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from impress_gui.sim.truth import truth_on_grid  # noqa: F401  (re-exported for the benchmarks)

CACHE = Path(os.environ.get("IMPRESS_BENCH_CACHE", Path(__file__).parent / ".cache"))
ROOT = Path(__file__).resolve().parents[1]


def source_key(*parts: str) -> str:
    """Short hash of the source files (.py, .json) under ``parts`` (folders or files below the
    project root): a cached result is reused only while the code that made it is unchanged."""
    import hashlib

    h = hashlib.sha256()
    for part in parts:
        p = ROOT / part
        files = [f for f in p.rglob("*") if f.suffix in (".py", ".json")] if p.is_dir() else [p]
        for f in sorted(files):
            h.update(f.relative_to(ROOT).as_posix().encode())
            h.update(f.read_bytes())
    return h.hexdigest()[:10]


#: what the simulator's renders depend on: its package, every module of ours it imports
#: (tests/test_bench_keys.py checks the list against a fresh interpreter's imports; until 3
#: December 2026 the image writer, the pick files and core.base were left out, so a change
#: there kept serving renders an earlier state made) and the resources
SIM_SOURCES = ("impress_gui/sim", "impress_gui/__init__.py", "impress_gui/core/__init__.py",
               "impress_gui/core/base", "impress_gui/core/calibration/__init__.py",
               "impress_gui/core/calibration/target.py", "impress_gui/core/calibration/geometry.py",
               "impress_gui/core/calibration/picks.py", "impress_gui/core/formats/__init__.py",
               "impress_gui/core/formats/images.py", "resources")
SIM_KEY = source_key(*SIM_SOURCES)
CAL_KEY = source_key("impress_gui/core/calibration/scene.py", "impress_gui/core/calibration/solve.py",
                     "impress_gui/core/calibration/planes.py", "impress_gui/core/reconstruction/stripes.py",
                     "impress_gui/core/reconstruction/kernels.py", "impress_gui/core/calibration/geometry.py")


def scan(name: str, **cfg) -> Path:
    """Simulate (once per version of the simulator's code) and return the scan folder."""
    from impress_gui.sim.simulate import SimConfig, simulate

    out = CACHE / f"{name}-{SIM_KEY}"
    if not (out / "truth.json").exists():
        print(f"[simulating {name}: {cfg}]", flush=True)
        simulate(SimConfig(**cfg), out, workers=min(2, os.cpu_count() or 1))
    return out


def calibrate(scan_dir: Path, picks_file: str = "picks.json", noise_px: float = 0.0, seed: int = 0,
              speed_mm_s: float | None = None, readout: str = "given"):
    """Calibrate a cached scan from its picks (``noise_px``: normal click noise added, seeded)
    with its true intrinsics. ``readout``: ``"given"``, the rolling shutter's readout as the
    intrinsics carry it; ``"unknown"``, without it (as a lab that did not record it: the
    calibration estimates it from the picks, or takes the camera for a global shutter);
    ``"global"``, recorded as a global shutter (0: no estimate)."""
    from dataclasses import replace

    from impress_gui.core.calibration.geometry import Intrinsics
    from impress_gui.core.calibration.picks import Picks
    from impress_gui.core.calibration.scene import calibrate_scene
    from impress_gui.core.calibration.target import TargetModel
    from impress_gui.core.formats.video import open_video

    truth = json.loads((scan_dir / "truth.json").read_text())
    picks = Picks.load(scan_dir / picks_file)
    if noise_px:
        rng = np.random.default_rng(seed)
        noisy = {}
        for key in ("corners_t1", "corners_t2"):
            d = getattr(picks, key)
            noisy[key] = {c: tuple(np.add(v, rng.normal(0, noise_px, 2))) for c, v in d.items()}
        picks = Picks(picks.video, picks.t1, picks.t2, noisy["corners_t1"], noisy["corners_t2"])
    intr = Intrinsics.load(scan_dir / "intrinsics.json")
    if readout not in ("given", "unknown", "global"):
        raise ValueError(f"readout {readout!r}")
    if readout != "given":
        intr = replace(intr, readout_ms=None if readout == "unknown" else 0.0)
    with open_video(scan_dir / truth["video"]) as v:
        return calibrate_scene(v, intr,
                               TargetModel.load(scan_dir / "target.json"), picks,
                               truth["speed_mm_s"] if speed_mm_s is None else speed_mm_s)


def edge_mask(truth: np.ndarray, radius_cells: int = 5, jump_mm: float = 1.0) -> np.ndarray:
    from scipy.ndimage import maximum_filter, minimum_filter

    t0 = np.nan_to_num(truth)
    k = 2 * radius_cells + 1
    return (maximum_filter(t0, k) - minimum_filter(t0, k)) > jump_mm


def visible_mask(scan_dir: Path, spec, frames: tuple[int, int]) -> np.ndarray:
    """Cells of a reconstruction grid that at least one laser lights where the camera sees
    it, in the processed frames: the simulator's exact stripe points (laser shadows and camera
    occlusion included), gathered on the grid and closed along the scan over one frame's
    travel. This is 'the surface either laser can see' of issue 4's fill-rate target."""
    import cv2

    from impress_gui.sim.simulate import SimConfig, _make_renderer

    truth = json.loads((scan_dir / "truth.json").read_text())
    cfg = SimConfig(**truth["config"])
    renderer, _ = _make_renderer(cfg)
    s1 = truth["travel_mm"][truth["calibration_frames"]["t1"]]
    mask = np.zeros(spec.shape, np.uint8)
    for k in range(*frames):
        renderer.travel_cache = renderer.travel(k)
        for laser in renderer.rig.lasers:
            p = renderer.laser_points(laser, k).points_rail_mm
            j = np.rint((p[:, 0] - spec.x0_mm) / spec.pixel_mm).astype(int)
            i = np.rint((p[:, 1] - s1 - spec.y0_mm) / spec.pixel_mm).astype(int)
            ok = (i >= 0) & (i < spec.shape[0]) & (j >= 0) & (j < spec.shape[1])
            mask[i[ok], j[ok]] = 1
    step = np.median(np.diff(truth["travel_mm"][frames[0]:frames[1]]))
    n = int(np.ceil(step / spec.pixel_mm)) + 2
    mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, np.ones((n, 3), np.uint8))
    return mask.astype(bool)
