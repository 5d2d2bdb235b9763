"""A picture whose ground is nearly white leaves the stripes no room to rise above it: the
reconstruction says so (W-BRIGHT-GROUND) instead of passing its noisy heights silently
(issue 18: random rig 34, white soil under bright ambient light, 2.5 % wild points at
640x360). The share is of the background tables' frames whose luma is within the detector's
minimum peak of full scale."""

from __future__ import annotations

import json

import numpy as np
import pytest

from impress_gui.core.reconstruction.reconstruct import BRIGHT_GROUND_SHARE
from impress_gui.core.reconstruction.stripes import BackgroundLUT


def test_the_share_of_the_picture_near_full_scale():
    rgb = np.full((100, 200, 3), 120, np.uint8)
    rgb[:30] = (250, 245, 220)  # luma 244: within 25 of full scale
    rgb[30:40] = (235, 230, 200)  # luma 229: not within 25
    lut = BackgroundLUT()
    assert np.isnan(lut.near_full_share(25.0))
    lut.learn(rgb, [(45, 60)])
    assert lut.near_full_share(25.0) == pytest.approx(0.30, abs=0.011)
    assert lut.near_full_share(40.0) == pytest.approx(0.40, abs=0.011)
    # the lasers' bands count too (on some mountings they cover the whole picture)
    lut2 = BackgroundLUT()
    lut2.learn(rgb, [(0, 100)])
    assert lut2.near_full_share(25.0) == pytest.approx(0.30, abs=0.011)


def _reconstruct(seed, out):
    from impress_gui.core.calibration.geometry import Intrinsics
    from impress_gui.core.calibration.picks import Picks
    from impress_gui.core.calibration.scene import calibrate_scene
    from impress_gui.core.calibration.target import TargetModel
    from impress_gui.core.formats.video import open_video
    from impress_gui.core.reconstruction.reconstruct import ProcessParams, reconstruct
    from impress_gui.sim.simulate import SimConfig, simulate

    simulate(SimConfig.random(seed, 320, 180, grid_mm=0.5), out)  # the picture, not the heights
    truth = json.loads((out / "truth.json").read_text())
    with open_video(out / "scan.mp4") as v:
        cal = calibrate_scene(v, Intrinsics.load(out / "intrinsics.json"),
                              TargetModel.load(out / "target.json"),
                              Picks.load(out / "picks.json"), truth["speed_mm_s"])
        rec = reconstruct(v, cal, ProcessParams(texture=False))
    return truth, rec


@pytest.mark.slow
def test_white_ground_is_warned_of_and_ordinary_ground_is_not(tmp_path, flat_recon):
    truth, rec = _reconstruct(34, tmp_path / "white")
    assert truth["random_rig"]["soil_brightness"] > 0.8
    share = rec.stats["ground_near_full_share"]
    assert share > BRIGHT_GROUND_SHARE
    (w,) = [w for w in rec.warnings if w.startswith("W-BRIGHT-GROUND")]
    assert f"{100 * share:.0f} %" in w and "exposure" in w
    # ordinary ground: the flat preset's scan the suite reconstructs once for several files
    # (as `impress process` wrote it: the share and the warnings in its metadata)
    meta = json.loads((flat_recon / "metadata.json").read_text())
    assert meta["stats"]["ground_near_full_share"] < 0.5 * BRIGHT_GROUND_SHARE
    assert not [w for w in meta["warnings"] if w.startswith("W-BRIGHT-GROUND")]
