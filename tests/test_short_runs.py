"""Stripe pieces too short to be a stripe (two columns at 1080p: in a laser's shadow, an edge
of the scene that two neighbouring columns agree on) are dropped; the stripe, its longer
pieces and the columns no piece holds are left as they were."""

import numpy as np
import pytest

from impress_gui.core.reconstruction.compiled import kernels
from impress_gui.core.reconstruction.reconstruct import CONNECT_PX, min_run_columns
from impress_gui.core.reconstruction.stripes import drop_short_runs_numpy


def _both(rows, strength, min_run):
    a_rows, a_str = rows.copy(), strength.copy()
    b_rows, b_str = rows.copy(), strength.copy()
    n_a = kernels().drop_short_runs(a_rows, a_str, CONNECT_PX, min_run)
    n_b = drop_short_runs_numpy(b_rows, b_str, CONNECT_PX, min_run)
    assert n_a == n_b
    np.testing.assert_array_equal(a_rows, b_rows)  # NaN in the same places
    np.testing.assert_array_equal(a_str, b_str)
    return a_rows, a_str, n_a


def _stripe(w=1920, seed=0):
    rng = np.random.default_rng(seed)
    cols = np.arange(w)
    rows = 500.0 + 30.0 * np.sin(cols / 200.0) + rng.normal(0, 0.05, w)
    return rows, rng.uniform(60.0, 90.0, w).astype(np.float32)


def test_a_two_column_piece_in_a_shadow_is_dropped_and_the_stripe_kept():
    rows, strength = _stripe()
    rows[900:940] = np.nan  # the laser's shadow past a wall ...
    rows[910:912] = [883.6, 883.3]  # ... where a block's edge in the picture gives a pair
    rows[920] = 1071.8  # and single columns are scattered candidates
    rows[925:928] = [871.3, 871.3, 871.9]  # a piece of three columns
    out, s, n = _both(rows, strength, 3)
    assert n == 2
    assert np.isnan(out[910:912]).all() and (s[910:912] == 0).all()
    keep = np.ones(len(rows), bool)
    keep[910:912] = False
    np.testing.assert_array_equal(out[keep], rows[keep])  # the rest untouched
    np.testing.assert_array_equal(s[keep], strength[keep])


def test_pieces_are_those_the_profile_links():
    rows, strength = _stripe(200)
    rows[50:52] = [300.0, 300.0 + CONNECT_PX]  # linked: a piece of two
    rows[49] = rows[52] = np.nan
    rows[80:83] = [300.0, 300.0 + 1.1 * CONNECT_PX, 300.0]  # not linked: three single columns
    rows[79] = rows[83] = np.nan
    out, _, n = _both(rows, strength, 3)
    assert n == 2 and np.isnan(out[50:52]).all()
    np.testing.assert_array_equal(out[80:83], rows[80:83])


@pytest.mark.parametrize("seed", range(6))
def test_kernel_agrees_with_the_reference_on_broken_stripes(seed):
    rng = np.random.default_rng(seed)
    rows, strength = _stripe(1920, seed)
    rows[rng.random(1920) < 0.15] = np.nan
    jump = rng.random(1920) < 0.1
    rows[jump] += rng.uniform(-40, 40, jump.sum())
    for min_run in (0, 2, 3, 4, 6):
        out, _, n = _both(rows, strength, min_run)
        if min_run <= 2:
            assert n == 0
            np.testing.assert_array_equal(out, rows)
        else:
            assert n > 0


def test_the_shortest_piece_kept_scales_with_the_width():
    assert min_run_columns(640) == 2  # at 640 and 1280 px a piece of two stays
    assert min_run_columns(1280) == 2
    assert min_run_columns(1920) == 3
    assert min_run_columns(3840) == 6
