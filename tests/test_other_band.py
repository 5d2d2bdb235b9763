"""A stripe whose light leans to the other laser's colour is refused only where the other
laser's stripe can lie (issue 18, random rig 4).

On soil whose red channel is nearly saturated, a red laser with strong green and blue crosstalk
can add almost only green and blue: the halo's chroma leans to green and the headroom shares
do not save it, so the red detector refused 24 % of the red stripe's columns on rig 4 (fill
89.9 %). The reconstruction knows from the calibration and the height range which rows each
laser's stripe can reach (its band); the lean refuses a peak only inside the other laser's
band, so the other laser's light is still refused where it can be and a laser's own light is
kept where only it can be."""

from __future__ import annotations

import numpy as np
import pytest
from test_calibration_blooming import _frame

from impress_gui.core.base.errors import InputError
from impress_gui.core.formats.video import Planes
from impress_gui.core.reconstruction.stripes import StripeParams, detect_planes, detect_planes_numpy

SOIL = (249, 170, 121)  # rig 4's orange soil where the red stripe was refused (frame 20 %)
RED = (1.0, 0.5, 0.7)  # a red laser with strong green/blue crosstalk
GREEN = (0.26, 1.0, 0.26)


def _detect(rgb, name, other, numpy_reference=False):
    planes = Planes.from_rgb(rgb)
    h, w = rgb.shape[:2]
    fn = detect_planes_numpy if numpy_reference else detect_planes
    return fn(name, planes, np.zeros(w, np.int64), h, StripeParams(), None, other).rows


@pytest.mark.parametrize("numpy_reference", [False, True])
def test_own_light_outside_the_other_band_is_kept(numpy_reference):
    rgb = _frame([(20.3, 0.05, 1.4, RED)], background=SOIL)
    w = rgb.shape[1]
    true_rows = 20.3 + 0.05 * np.arange(w)
    far = (np.full(w, 300, np.int64), 50)  # the green stripe cannot reach these rows
    over = (np.full(w, 5, np.int64), 40)  # ... or it can
    # without a band, or with the other band over the stripe: refused (the chroma leans green)
    assert np.isfinite(_detect(rgb, "red", None, numpy_reference)).mean() < 0.05
    assert np.isfinite(_detect(rgb, "red", over, numpy_reference)).mean() < 0.05
    rows = _detect(rgb, "red", far, numpy_reference)
    assert np.isfinite(rows).mean() > 0.95
    assert np.nanmax(np.abs(rows - true_rows)) < 0.3


@pytest.mark.parametrize("soil", [SOIL, (150, 190, 90), (120, 110, 100)])
def test_the_other_lasers_light_in_its_band_is_still_refused(soil):
    """The green stripe where green can lie: the red detector finds no more of it with the
    band than without one (dim to blooming)."""
    for power in (0.5, 1.4, 4.3):
        rgb = _frame([(20.3, 0.05, power, GREEN)], background=soil)
        w = rgb.shape[1]
        green_band = (np.full(w, 5, np.int64), 40)
        with_band = np.isfinite(_detect(rgb, "red", green_band)).mean()
        without = np.isfinite(_detect(rgb, "red", None)).mean()
        assert with_band <= without + 1e-9, (soil, power)


def test_a_band_of_the_wrong_width_is_refused():
    rgb = _frame([(20.3, 0.05, 1.4, RED)], background=SOIL)
    with pytest.raises(InputError):
        _detect(rgb, "red", (np.zeros(5, np.int64), 10))
