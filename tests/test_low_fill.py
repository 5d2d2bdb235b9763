"""Issue 21 item 7: a detection method that drops most of the data says so.

On compressed low-resolution video of the blocks (MTS, 640x360) the hue method finds the
stripes in about a tenth of the picture's columns and fills ~10 % of the cells the combined
method fills; the result carries W-LOW-FILL, while the combined method's does not."""

from __future__ import annotations

import json

import pytest

from impress_gui.core.reconstruction.pipeline import process_files
from impress_gui.core.reconstruction.reconstruct import LOW_COLUMN_SHARE, ProcessParams

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def blocks_mts(tmp_path_factory):
    from impress_gui.core.calibration.geometry import Intrinsics
    from impress_gui.core.calibration.picks import Picks
    from impress_gui.core.calibration.scene import calibrate_scene
    from impress_gui.core.calibration.target import TargetModel
    from impress_gui.core.formats.video import open_video
    from impress_gui.sim.simulate import SimConfig, simulate

    base = tmp_path_factory.mktemp("blocks")
    scan = base / "scan"
    simulate(SimConfig(preset="blocks", length_mm=200.0, width=640, height=360, fps=10.0,
                       video_format="mts"), scan, workers=1)
    truth = json.loads((scan / "truth.json").read_text())
    with open_video(scan / "scan.mts") as v:
        cal = calibrate_scene(v, Intrinsics.load(scan / "intrinsics.json"),
                              TargetModel.load(scan / "target.json"),
                              Picks.load(scan / "picks.json"), truth["speed_mm_s"])
    cal.save(base / "cal.json")
    return scan / "scan.mts", base / "cal.json"


def _run(blocks_mts, tmp_path, method: str) -> dict:
    video, cal = blocks_mts
    return process_files(video, cal, tmp_path / method,
                         ProcessParams(method=method, texture=False, grid_mm=0.2))


def test_hue_on_compressed_low_resolution_video_warns(blocks_mts, tmp_path):
    hue = _run(blocks_mts, tmp_path, "hue")
    combined = _run(blocks_mts, tmp_path, "combined")
    share = hue["stats"]["stripe_column_share"]
    assert min(share.values()) < LOW_COLUMN_SHARE
    assert hue["stats"]["cells_fused"] < 0.5 * combined["stats"]["cells_fused"]
    low = [w for w in hue["warnings"] if w.startswith("W-LOW-FILL")]
    assert low and "hue" in low[0]
    assert min(combined["stats"]["stripe_column_share"].values()) > 0.9
    assert not [w for w in combined["warnings"] if w.startswith("W-LOW-FILL")]
