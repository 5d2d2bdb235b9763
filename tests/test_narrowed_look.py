"""A second look where the other laser's band is tall but its stripe lies elsewhere (issue 18,
random rig 237 at 1920x1080).

A rolled camera's slanted stripes make each laser's band (the rows its stripe can reach for
the height range) hundreds of rows high. Inside the other laser's band a stripe must show
this laser's colour, and the white-core rule is refused there. On rig 237 the green stripe,
blooming nearly white on greenish soil, lies inside the red laser's 612-row band over the
picture's first columns, 380 rows below red's own stripe: a third of those columns were
refused in frames 34-165, and the green-only corner of the map was missing (fill 98.98 %).
Where the other laser's stripe was found in the frame, its light is there, not in the rest of
its band: the detector looks again with that band narrowed to the rows around it
(``reconstruct._narrowed_look``), and keeps what it finds only where it continues this
laser's stripe as first found."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from impress_gui.core.formats.video import Planes
from impress_gui.core.reconstruction import reconstruct as rc
from impress_gui.core.reconstruction.stripes import StripeDetector, StripeParams

# Frame 100 of random rig 237 at 1920x1080 (simulator key 02bad946fa), rows 540-699 of the
# first 320 columns, with the renderer's exact rows of both stripes and red's band (crop
# rows). Made by tests/data/make_rig237_narrow.py.
RIG237 = Path(__file__).parent / "data" / "rig237_green_narrow.npz"


def _rig237():
    z = np.load(RIG237)
    planes = Planes(z["y"], z["cb"], z["cr"], 2)
    w = z["y"].shape[1]
    band = (np.zeros(w, np.int64), z["y"].shape[0])
    other = (z["other_start"].astype(np.int64), z["other_height"].astype(np.int64))
    return planes, band, other, z["green_rows"], z["red_rows"]


def _first_look(planes, band, other):
    det = StripeDetector("green", *band, StripeParams(), None, other=other)
    res = det(planes)
    return type(res)(res.rows.copy(), res.strength.copy())


def _second(band, other):
    return StripeDetector("green", *band, StripeParams(), None, other=other)


def test_the_green_stripe_in_reds_tall_band_is_found_on_a_second_look():
    planes, band, other, green, red = _rig237()
    w = len(green)
    on = np.isfinite(green)
    # the setting: the green stripe lies in red's band (widened by the half window) in every
    # column, and red's own stripe far above it
    k = StripeParams().half_window_px
    assert ((green + k >= other[0]) & (green - k < other[0] + other[1])).all()
    assert np.nanmin(np.abs(green - red)) > 300
    res = _first_look(planes, band, other)
    before = np.abs(res.rows - green) <= 1.0
    # measured: 233 of the 320 columns on the stripe at the first look
    assert before.sum() < 0.8 * on.sum()
    rows0 = res.rows.copy()
    overlap = np.ones(w, bool)
    n = rc._narrowed_look(planes, res, _second(band, other), overlap, red, np.full(w, 1e9))
    after = np.abs(res.rows - green) <= 1.0
    added = np.isfinite(res.rows) & np.isnan(rows0)
    assert n == added.sum() > 0.1 * w
    # every column it adds lies on the green stripe; none found first changes
    assert after[added].all()
    kept = np.isfinite(rows0)
    assert np.array_equal(res.rows[kept], rows0[kept])
    # measured: all 320 (87 added)
    assert after.sum() > 0.95 * on.sum()


def test_nothing_changes_without_a_reason_to_look_again():
    planes, band, other, green, red = _rig237()
    w = len(green)
    last = np.full(w, 1e9)
    # the other laser's stripe not found: its whole band stands, nothing is looked at again
    res = _first_look(planes, band, other)
    rows0 = res.rows.copy()
    nan = np.full(w, np.nan)
    assert rc._narrowed_look(planes, res, _second(band, other), np.ones(w, bool), nan, last) == 0
    assert np.array_equal(res.rows, rows0, equal_nan=True)
    # columns where the two bands do not overlap are not looked at again
    assert rc._narrowed_look(planes, res, _second(band, other), np.zeros(w, bool), red, last) == 0
    # new columns continuing a short piece found at the first look (under
    # reconstruct.long_run_columns: 8 of these 320 columns) are not taken: the piece can be
    # the other laser's light on a second surface of the column (a wall's foot) ...
    piece = np.arange(200, 206)  # within the crop's longest piece found (columns 134-291)
    assert (np.abs(rows0[piece] - green[piece]) <= 1.0).all()
    assert len(piece) < rc.long_run_columns(w)
    res.rows[:] = np.nan
    res.rows[piece] = rows0[piece]
    assert rc._narrowed_look(planes, res, _second(band, other), np.ones(w, bool), red, last) == 0
    # ... and continuing a long one they are
    longer = np.arange(200, 212)
    assert (np.abs(rows0[longer] - green[longer]) <= 1.0).all()
    assert len(longer) >= rc.long_run_columns(w)
    res.rows[longer] = rows0[longer]
    assert rc._narrowed_look(planes, res, _second(band, other), np.ones(w, bool), red, last) > 0
    # a run of new columns with no column found at the first look is not taken
    res.rows[:] = np.nan
    res.strength[:] = 0
    assert rc._narrowed_look(planes, res, _second(band, other), np.ones(w, bool), red, last) == 0
    assert np.isnan(res.rows).all()


def test_a_column_found_near_the_other_laser_or_beyond_the_range_is_not_taken():
    planes, band, other, green, red = _rig237()
    w = len(green)
    res = _first_look(planes, band, other)
    rows0 = res.rows.copy()
    # the other laser's stripe said to lie on green's own rows: nothing there is taken
    n = rc._narrowed_look(planes, res, _second(band, other), np.ones(w, bool), green,
                          np.full(w, 1e9))
    assert n == 0 and np.array_equal(res.rows, rows0, equal_nan=True)
    # rows past the column's end of the band (the height range) are not taken
    n = rc._narrowed_look(planes, res, _second(band, other), np.ones(w, bool), red,
                          np.full(w, 10.0))
    assert n == 0
