"""Short, weak stripe pieces (soil of the laser's hue found where the stripe is faint) are
dropped before they become wild points; the stripe itself is kept."""

import numpy as np
import pytest

from impress_gui.core.base.errors import InputError
from impress_gui.core.reconstruction.compiled import kernels
from impress_gui.core.reconstruction.reconstruct import (
    CONNECT_PX,
    ProcessParams,
    long_run_columns,
)
from impress_gui.core.reconstruction.stripes import prune_weak_runs_numpy


def _stripe(w=640, seed=0):
    """A long, strong stripe (a gentle curve) with faint gaps."""
    rng = np.random.default_rng(seed)
    cols = np.arange(w)
    rows = 300.0 + 20.0 * np.sin(cols / 90.0) + rng.normal(0, 0.05, w)
    strength = rng.uniform(70.0, 95.0, w).astype(np.float32)
    return rows, strength


def _both(rows, strength, long_cols, ratio=0.5):
    a_rows, a_str = rows.copy(), strength.copy()
    b_rows, b_str = rows.copy(), strength.copy()
    n_a = kernels().prune_weak_runs(a_rows, a_str, CONNECT_PX, long_cols, ratio,
                                    np.empty(len(rows), np.int64), np.empty(len(rows)))
    n_b = prune_weak_runs_numpy(b_rows, b_str, CONNECT_PX, long_cols, ratio)
    assert n_a == n_b
    np.testing.assert_array_equal(a_rows, b_rows)  # NaN in the same places
    np.testing.assert_array_equal(a_str, b_str)
    return a_rows, a_str, n_a


def test_a_short_weak_piece_far_from_the_stripe_is_dropped():
    rows, strength = _stripe()
    rows[200:210] = np.nan  # the stripe is faint here ...
    rows[202:205] = [720.0, 720.3, 720.5]  # ... and greenish soil 400 rows away is found
    strength[202:205] = 28.0
    out, _, n = _both(rows, strength, long_run_columns(640))
    assert n == 3
    assert np.isnan(out[202:205]).all()
    # everything else untouched
    keep = np.ones(640, bool)
    keep[200:210] = False
    np.testing.assert_array_equal(out[keep], rows[keep])


def test_strong_short_pieces_and_weak_long_pieces_are_kept():
    rows, strength = _stripe()
    # a short piece at another row but as strong as the stripe: a real step (a wall's top)
    rows[100:104] = 250.0 + np.arange(4) * 0.2
    strength[100:104] = 80.0
    rows[99] = rows[104] = np.nan
    # the stripe on a long dark patch: weak, but a long continuous curve
    strength[400:520] = 20.0
    out, _, n = _both(rows, strength, long_run_columns(640))
    assert n == 0
    np.testing.assert_array_equal(out, rows)


def test_nothing_is_dropped_without_a_long_piece_or_with_ratio_zero():
    rows = np.full(300, np.nan)
    rows[10:14] = 100.0
    rows[50:53] = 200.0
    strength = np.where(np.isfinite(rows), 30.0, 0.0).astype(np.float32)
    strength[50:53] = 90.0
    _, _, n = _both(rows, strength, long_run_columns(300))
    assert n == 0
    r2, s2 = _stripe()
    r2[5:8] = 900.0
    s2[5:8] = 10.0
    _, _, n = _both(r2, s2, long_run_columns(640), ratio=0.0)
    assert n == 0
    _, _, n = _both(r2, s2, long_run_columns(640), ratio=0.5)
    assert n == 3


def test_kernel_equals_numpy_on_random_stripes():
    rng = np.random.default_rng(5)
    for _trial in range(40):
        w = int(rng.integers(20, 700))
        rows = np.cumsum(rng.choice([0.0, 0.5, 1.0, 30.0], size=w, p=[0.5, 0.3, 0.15, 0.05]))
        rows[rng.random(w) < 0.1] = np.nan
        strength = rng.uniform(5, 100, w).astype(np.float32)
        _both(rows, strength, long_run_columns(w), ratio=float(rng.uniform(0.1, 0.9)))


def test_the_ratio_is_a_recorded_checked_parameter():
    assert ProcessParams().to_json()["weak_run_ratio"] == 0.5
    with pytest.raises(InputError):
        ProcessParams(weak_run_ratio=1.5).validate()
    assert long_run_columns(1920) == 32 and long_run_columns(320) == 8


# ----- a stripe saturating its own channel on soil of its own colour ---------------------------
ORANGE_SOIL = (235, 183, 133)  # light orange soil under random rig 4's red stripe (frame 120)
GREENISH_SOIL = (150, 190, 90)
RED_LASER = (1.0, 0.118, 0.177)  # random rig 4's red laser: green/blue crosstalk
GREEN_LASER = (0.26, 1.0, 0.26)


def test_a_red_stripe_saturated_on_orange_soil_is_found_and_not_taken_for_green():
    from dataclasses import replace

    from test_calibration_blooming import _frame

    from impress_gui.core.reconstruction.stripes import StripeParams, detect_band

    rgb = _frame([(20.3, 0.05, 4.3, RED_LASER)], background=ORANGE_SOIL)
    assert rgb[20:23, 10, 0].min() >= 250  # red saturated in the core
    before = detect_band("red", rgb, 0, replace(StripeParams(), min_headroom_lean=np.inf), None)
    res = detect_band("red", rgb, 0, StripeParams(), None)
    # the chroma of the light it adds leans away from red: refused by the chroma test alone
    assert before.found.mean() < 0.1
    assert res.found.mean() > 0.9
    true_rows = 20.3 + 0.05 * np.arange(rgb.shape[1])
    assert np.nanmax(np.abs(res.rows - true_rows)) < 0.3
    # the rescue never makes a detector take the other laser's stripe: on this soil and on
    # greenish soil, dim to blooming, it finds no more of it than the chroma test alone (the
    # regions of interest keep the other stripe out of a laser's rows in the product)
    off = replace(StripeParams(), min_headroom_lean=np.inf)
    for soil in (ORANGE_SOIL, GREENISH_SOIL):
        for laser, colour in (("red", GREEN_LASER), ("green", RED_LASER)):
            for power in (0.5, 1.4, 4.3):
                f = _frame([(20.3, 0.05, power, colour)], background=soil)
                with_rescue = detect_band(laser, f, 0, StripeParams(), None).found.mean()
                without = detect_band(laser, f, 0, off, None).found.mean()
                assert with_rescue <= without + 0.02, (soil, laser, power)
    assert detect_band("green", rgb, 0, StripeParams(), None).found.mean() < 0.05


def test_a_faint_stripe_found_in_short_weak_pieces_is_kept_when_they_chain():
    # random rig 214 at 1080p: a dim red stripe on green soil found in pieces of a few
    # columns with gaps of one to three between them, each piece far weaker than the frame's
    # stripe on lighter soil; the pieces continue into each other across the gaps
    # (kernels.WEAK_CHAIN_GAP), a chain as long as a long piece: the stripe, kept
    rows, strength = _stripe()
    gaps = [201, 205, 206, 211, 214, 215, 216, 222, 226, 233, 236, 240, 241]
    strength[200:245] = 12.0
    rows[gaps] = np.nan
    out, _, n = _both(rows, strength, long_run_columns(640))
    assert n == 0
    np.testing.assert_array_equal(out, rows)
    # the same pieces with gaps of four columns do not chain: dropped as before
    rows2, strength2 = _stripe()
    strength2[300:350] = 12.0
    for c in range(300, 350, 7):
        rows2[c:c + 4] = np.nan
    out2, _, n2 = _both(rows2, strength2, long_run_columns(640))
    assert n2 == np.isfinite(rows2[300:350]).sum() and np.isnan(out2[300:350]).all()
    # and a weak piece beside the chain but off its rows is dropped
    rows3, strength3 = rows.copy(), strength.copy()
    rows3[207:210] = rows3[207:210] + 9.0
    strength3[207:210] = 12.0
    out3, _, n3 = _both(rows3, strength3, long_run_columns(640))
    assert n3 == 3 and np.isnan(out3[207:210]).all()
