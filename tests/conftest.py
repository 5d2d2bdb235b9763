import os

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")

import json  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402


def pytest_configure(config):
    # PySide6 6.12.0 loses a reference to True on every emit (the pinned 6.11.3 does not);
    # the guard only acts when that bug is present
    from impress_gui.ui.pyside_fix import guard

    guard()


def _simulate(out: Path, **kw) -> Path:
    from impress_gui.sim.simulate import SimConfig, simulate

    simulate(SimConfig(**kw), out, workers=1)
    return out


@pytest.fixture(scope="session")
def flat_scan(tmp_path_factory) -> Path:
    """A short simulated scan of the flat preset at 640x360 (H.264), with its ground truth."""
    return _simulate(tmp_path_factory.mktemp("flat") / "scan", preset="flat", length_mm=100.0,
                     width=640, height=360)


@pytest.fixture(scope="session")
def flat_calibration(flat_scan, tmp_path_factory) -> Path:
    """The scene calibration of ``flat_scan`` from its exact picks."""
    from impress_gui.core.calibration import calibrate_scene
    from impress_gui.core.geometry import Intrinsics
    from impress_gui.core.picks import Picks
    from impress_gui.core.target import TargetModel
    from impress_gui.core.video import open_video

    truth = json.loads((flat_scan / "truth.json").read_text())
    with open_video(flat_scan / "scan.mp4") as v:
        cal = calibrate_scene(v, Intrinsics.load(flat_scan / "intrinsics.json"),
                              TargetModel.load(flat_scan / "target.json"),
                              Picks.load(flat_scan / "picks.json"), truth["speed_mm_s"])
    path = tmp_path_factory.mktemp("cal") / "calibration.json"
    cal.save(path)
    return path


def truth_on_grid(scan_dir: Path, spec) -> "object":
    """The simulator's true heightmap resampled (nearest) onto a reconstruction grid."""
    import numpy as np
    import tifffile

    truth = json.loads((scan_dir / "truth.json").read_text())
    th = tifffile.imread(scan_dir / "truth_height.tif")
    hm = truth["heightmap"]
    s1 = truth["travel_mm"][truth["calibration_frames"]["t1"]]
    jj = np.rint((spec.xs() - hm["x0_mm"]) / hm["pixel_mm"]).astype(int)
    ii = np.rint((spec.ys() + s1 - hm["y0_mm"]) / hm["pixel_mm"]).astype(int)
    okj = (jj >= 0) & (jj < th.shape[1])
    oki = (ii >= 0) & (ii < th.shape[0])
    out = np.full(spec.shape, np.nan, np.float32)
    out[np.ix_(oki, okj)] = th[np.ix_(ii[oki], jj[okj])]
    return out
