"""Across a step between two consecutive frames, each end's height reaches at most half the
carriage's travel between them: the higher surface is not drawn past its wall into a strip
that a shadow or a wrong far end made longer than a frame's travel (issue 18, random rig 13:
a red point 1.7 mm past the target's wall, 2.2 mm above its top, split at the middle drew the
top 8 cells too far)."""

from __future__ import annotations

import numpy as np
import pytest

from impress_gui.core.reconstruction import grid
from impress_gui.core.reconstruction.grid import GridSpec, HeightAccumulator

SPEC = GridSpec(0.0, 0.0, 0.1, (60, 10))
TRAVEL = 0.8  # mm per frame


def _column(frames, with_travel=True):
    """Feed profiles (10 points across, x 0..0.9 mm) given as (travel, y, height) per frame;
    return the map's column 5 (rows 0..59)."""
    acc = HeightAccumulator(SPEC, 2.2, 0.8)
    x = 0.1 * np.arange(10.0)
    for s, y, h in frames:
        kw = {"travel_mm": s} if with_travel else {}
        acc.add_profile(x, np.full(10, y), np.full(10, h), np.ones(10, bool), **kw)
    return acc.mean()[:, 5]


def test_a_step_longer_than_a_frame_leaves_its_middle_empty():
    # a 10 mm top sampled every frame up to y = 1.5 mm; the next frame's point 1.9 mm further
    # on (the ground past a shadow, or a wrong point)
    frames = [(0.0, 0.7, 10.0), (TRAVEL, 1.5, 10.0), (2 * TRAVEL, 3.4, 0.0)]
    col = _column(frames)
    top = np.flatnonzero(np.isfinite(col) & (col > 5))
    low = np.flatnonzero(np.isfinite(col) & (col < 5))
    # the top reaches half a frame's travel (0.4 mm, 4 cells) past its last point, not the
    # gap's middle (2.45 mm, cell 24)
    assert top.max() == 19
    # the far end reaches 0.4 mm back from 3.4 mm
    assert low.min() == 30 and low.max() == 34
    assert np.isnan(col[20:30]).all()


def test_a_step_within_a_frame_is_split_at_its_middle_as_before():
    frames = [(0.0, 0.7, 10.0), (TRAVEL, 1.5, 10.0), (2 * TRAVEL, 2.2, 0.0)]
    col = _column(frames)
    assert np.isfinite(col[7:23]).all()  # no cell left out
    # the middle, 1.85 mm: the cell of 1.8 mm takes samples of both ends
    assert np.flatnonzero(col > 5).max() in (17, 18)
    assert np.flatnonzero(col < 5).min() in (18, 19)


def test_without_the_travel_or_with_the_rule_off_the_strip_is_split_at_its_middle(monkeypatch):
    frames = [(0.0, 0.7, 10.0), (TRAVEL, 1.5, 10.0), (2 * TRAVEL, 3.4, 0.0)]
    for col in (_column(frames, with_travel=False),
                (monkeypatch.setattr(grid, "STEP_REACH", False), _column(frames))[1]):
        assert np.isfinite(col[7:35]).all()
        assert np.flatnonzero(col > 5).max() == 24


@pytest.mark.parametrize("h", [0.5, -0.7])
def test_continuous_surfaces_are_filled_whatever_the_gap(h):
    # a slope (not a step): the whole strip is filled, linear
    frames = [(0.0, 0.7, 0.0), (TRAVEL, 1.5, 0.0), (2 * TRAVEL, 3.4, h)]
    col = _column(frames)
    assert np.isfinite(col[7:35]).all()
    np.testing.assert_allclose(col[34], h, atol=0.03)
