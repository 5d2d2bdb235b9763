"""The tilt's refinement by the stripes weighs the corner picks by the noise their own pose fit
shows (scene.picks_sigma_px): exact picks hold the tilt, clicks as users make them leave it to
the stripes, as before."""
import json
import math

import numpy as np
import pytest

from impress_gui.core.base.errors import FormatError
from impress_gui.core.calibration import scene as S
from impress_gui.core.calibration.geometry import Intrinsics
from impress_gui.core.calibration.picks import Picks
from impress_gui.core.calibration.scene import SceneCalibration, calibrate_scene
from impress_gui.core.calibration.target import TargetModel
from impress_gui.core.formats.video import open_video


def test_the_picks_noise_is_their_fits_within_its_bounds():
    assert S.picks_sigma_px(0.0) == S.PICKS_SIGMA_FLOOR_PX
    assert S.picks_sigma_px(0.1) == pytest.approx(0.1 * math.sqrt(24 / 15))
    assert S.picks_sigma_px(2.0) == S.CLICK_SIGMA_PX
    assert S.picks_sigma_px(float("nan")) == S.CLICK_SIGMA_PX


def _calibrate(scan, picks, **kw):
    truth = json.loads((scan / "truth.json").read_text())
    with open_video(scan / "scan.mp4") as v:
        return calibrate_scene(v, Intrinsics.load(scan / "intrinsics.json"),
                               TargetModel.load(scan / "target.json"), picks,
                               truth["speed_mm_s"], **kw), truth


def _noisy(picks: Picks, px: float, seed: int) -> Picks:
    rng = np.random.default_rng(seed)
    return Picks(picks.video, picks.t1, picks.t2,
                 *({c: tuple(np.add(v, rng.normal(0, px, 2))) for c, v in d.items()}
                   for d in (picks.corners_t1, picks.corners_t2)))


def test_exact_picks_hold_the_tilt_the_stripes_would_turn(flat_scan, flat_calibration, tmp_path):
    """The flat preset at 640x360 (H.264), the simulator's exact picks: weighed as a user's
    clicks (0.5 px) the stripes set the tilt 0.0034 deg off; weighed by their own fit
    (consistent to 1e-5 px) the tilt is the picks' and within 0.0005 deg."""
    cal = SceneCalibration.load(flat_calibration)  # made with the defaults
    truth = json.loads((flat_scan / "truth.json").read_text())
    assert cal.tilt_click_sigma_px == S.PICKS_SIGMA_FLOOR_PX
    assert abs(cal.tilt_deg - truth["tilt_deg"]) < 0.0005
    as_clicks, _ = _calibrate(flat_scan, Picks.load(flat_scan / "picks.json"),
                              click_sigma_px=0.5)
    assert as_clicks.tilt_click_sigma_px == 0.5
    assert abs(as_clicks.tilt_deg - truth["tilt_deg"]) > 0.002
    # recorded in the file, read back; a damaged value is refused
    p = tmp_path / "c.json"
    cal.save(p)
    doc = json.loads(p.read_text())
    assert doc["tilt_click_sigma_px"] == S.PICKS_SIGMA_FLOOR_PX
    assert SceneCalibration.load(p).tilt_click_sigma_px == S.PICKS_SIGMA_FLOOR_PX
    doc["tilt_click_sigma_px"] = -1.0
    p.write_text(json.dumps(doc))
    with pytest.raises(FormatError, match="tilt_click_sigma_px"):
        SceneCalibration.load(p)


def test_clicks_with_noise_are_weighed_as_clicks(flat_scan):
    """0.5 px of click noise: the picks' fit shows it (0.25-0.5 px assumed) and the stripes
    set the tilt as they did with the fixed 0.5 px: the same tilt to 0.01 deg."""
    picks = _noisy(Picks.load(flat_scan / "picks.json"), 0.5, 4)
    own, truth = _calibrate(flat_scan, picks)
    fixed, _ = _calibrate(flat_scan, picks, click_sigma_px=0.5)
    assert 0.25 <= own.tilt_click_sigma_px <= 0.5
    assert abs(own.tilt_deg - fixed.tilt_deg) < 0.01
