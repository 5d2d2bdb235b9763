"""A stripe found in the other laser's band gives way to one in this laser's own rows nearer
the ground (``StripeParams.prefer_own_rows``; issue 18, random rig 102, 4 December 2026).

Rig 102 (seen by no one before that day): near-white soil, both lasers blooming and both
mounted behind the camera, so the red stripe on the ground lies inside the green laser's band,
where a green stripe on a surface 55-61 mm high would be. The two cores are the same white and
a thin stripe's 4:2:0 chroma is the soil's: no colour test can tell them apart, and the green
detector took the red stripe in 1.7 % of its map's cells (fused height error 0.61 mm at
1080p). Nothing in the green laser's own rows (its band outside the red one) can be the red
stripe, whatever the surface's height; so where the green stripe was found inside the red
band, a stripe in its own rows at least ``stripes.EXCLUSIVE_SHARE`` as strong and nearer the
row of the ground is taken instead."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from impress_gui.core.formats.video import Planes
from impress_gui.core.reconstruction.stripes import (
    StripeParams,
    detect_planes,
    detect_planes_numpy,
    own_regions,
)

# Frame 190 of random rig 102 at 1920x1080 (simulator key d323efdba0), cropped to the green
# band over the 256 columns where the detector took the red stripe most; ``green_rows``: the
# renderer's exact rows; ``ground``: the green stripe's row on a surface at height 0 (the
# calibration's). Made by tests/data/make_rig102_overlap.py.
RIG102 = Path(__file__).parent / "data" / "rig102_green_overlap.npz"
DETECTORS = (detect_planes, detect_planes_numpy)


def _rig102():
    z = np.load(RIG102)
    planes = Planes(z["y"], z["cb"], z["cr"], 2)
    band = (z["band_start"].astype(np.int64), int(z["band_height"]))
    other = (z["other_start"].astype(np.int64), int(z["other_height"]))
    return planes, band, other, z["green_rows"], z["ground"]


@pytest.mark.parametrize("fn", DETECTORS)
def test_the_green_stripe_is_not_taken_from_the_red_one(fn):
    planes, band, other, exact, ground = _rig102()
    before = fn("green", planes, *band, StripeParams(), None, other).rows
    after = fn("green", planes, *band, StripeParams(), None, other, ground).rows
    # measured: 60 of the 256 columns on the red stripe (> 20 px off the green one) before,
    # 0 after; every column on the green stripe (within 1 px of the renderer's rows) after
    assert (np.abs(before - exact) > 20).sum() >= 50
    assert (np.abs(after - exact) <= 1.0).all()
    # the columns already on the stripe keep their rows exactly
    on = np.abs(before - exact) <= 1.0
    assert np.array_equal(after[on], before[on])


def test_the_compiled_detector_and_the_numpy_reference_agree():
    planes, band, other, _, ground = _rig102()
    for g in (None, ground):
        a = detect_planes("green", planes, *band, StripeParams(), None, other, g).rows
        b = detect_planes_numpy("green", planes, *band, StripeParams(), None, other, g).rows
        assert np.array_equal(np.isfinite(a), np.isfinite(b))
        both = np.isfinite(a)
        assert np.abs(a[both] - b[both]).max() < 1e-6


def test_a_stripe_inside_the_other_band_on_the_ground_keeps_its_place():
    """The same frame with the ground moved to the red stripe's rows (as the red laser sees
    its own stripe there, on the ground, inside the green band): a stripe in the own rows is
    then farther from the ground and does not replace it."""
    planes, band, other, exact, ground = _rig102()
    before = detect_planes("green", planes, *band, StripeParams(), None, other).rows
    taken = np.abs(before - exact) > 20
    moved = np.where(taken, before, ground + 200.0)  # the red stripe's rows; elsewhere far
    after = detect_planes("green", planes, *band, StripeParams(), None, other, moved).rows
    assert np.array_equal(after[taken], before[taken])


def test_without_the_ground_or_with_the_rule_off_nothing_changes():
    planes, band, other, _, ground = _rig102()
    plain = detect_planes("green", planes, *band, StripeParams(), None, other).rows
    off = detect_planes("green", planes, *band, StripeParams(prefer_own_rows=False), None,
                        other, ground).rows
    assert np.array_equal(plain, off, equal_nan=True)


def test_own_regions_are_the_band_outside_the_other_one():
    start = np.array([10, 10, 10])
    parts = own_regions(start, 100, (np.array([50, 200, 0]), 40), k=6, image_height=500)
    (s1, h1, lo1, hi1), (s2, h2, lo2, hi2) = parts
    # before the other band: rows 10..43 (its start 50 less the half window); none where the
    # other band starts at row 0; the whole band where the other one starts beyond it
    assert list(lo1) == [10, 10, 10] and list(hi1) == [44, 110, 10] and h1 == 100
    # after it: from its end plus the half window to the band's end (empty in the second)
    assert list(lo2) == [96, 246, 46] and list(hi2) == [110, 246, 110] and h2 == 64
