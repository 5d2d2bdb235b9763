"""The calibration's sub-pixel row estimators (issue 18): on sampled Gaussian stripes the
half-maximum midpoint's error as the stripe's phase within the pixel changes is several times
smaller than the centre of mass above half maximum, which the reconstruction uses (pixel
locking), and a Gaussian fitted to the profile's unclipped rows smaller again; their columns
and fallbacks."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import erf

from impress_gui.core.reconstruction.stripes import gauss_rows, half_max_midpoints

N_ROWS = 31
CENTRE = 15.0


def _columns(sigma: float, amplitude: float, phases: np.ndarray, bg: float = 20.0):
    """One column per phase: a pixel-integrated Gaussian stripe centred at CENTRE + phase,
    8-bit (rounded, clipped at 255: dim to saturated)."""
    r = np.arange(N_ROWS)[:, None]
    mu = CENTRE + phases[None, :]
    f = 0.5 * (erf((r + 0.5 - mu) / (sigma * np.sqrt(2))) - erf((r - 0.5 - mu) / (sigma * np.sqrt(2))))
    return np.minimum(np.round(bg + amplitude * f * np.sqrt(2 * np.pi) * sigma), 255)


def _centre_of_mass(col: np.ndarray) -> float:
    s = col - col.min()
    a = s - 0.5 * s.max()
    m = a > 0
    return float((a[m] * np.arange(len(col))[m]).sum() / a[m].sum())


@pytest.mark.parametrize("sigma,amplitude", [(0.7, 60), (0.7, 2000), (1.6, 200), (1.6, 2000),
                                             (2.4, 200)])
def test_less_pixel_locking_than_the_centre_of_mass(sigma, amplitude):
    phases = np.linspace(0.0, 1.0, 41)
    luma = _columns(sigma, amplitude, phases)
    rough = CENTRE + np.round(phases)  # the detector's row, within half a pixel
    mid = half_max_midpoints(luma, rough, 6) - (CENTRE + phases)
    com = np.array([_centre_of_mass(luma[:, j]) for j in range(len(phases))]) - (CENTRE + phases)
    assert np.abs(mid).max() <= 0.05  # px: the stated locking of the midpoint
    assert np.ptp(mid) < 0.6 * np.ptp(com)


def test_columns_without_a_stripe_or_both_crossings_keep_their_row():
    luma = _columns(1.2, 300, np.zeros(4))
    luma[:, 2] = 50  # flat: no crossing on either side
    luma[:, 3] = np.linspace(20, 250, N_ROWS)  # an edge, not a peak
    rows = np.array([CENTRE, np.nan, 14.6, 14.4])
    out = half_max_midpoints(luma, rows, 6)
    assert out[0] == pytest.approx(CENTRE, abs=0.02)
    assert np.isnan(out[1])
    assert out[2] == 14.6 and out[3] == 14.4


def test_window_at_the_band_edge_keeps_the_row():
    luma = _columns(1.0, 300, np.zeros(1))
    out = half_max_midpoints(luma[10:], np.array([CENTRE - 10 - 0.3]), 6)
    assert out[0] == CENTRE - 10 - 0.3  # the window would leave the band: unchanged


@pytest.mark.parametrize("sigma,amplitude", [(0.7, 60), (0.7, 2000), (0.9, 300), (1.2, 2000),
                                             (1.6, 200), (1.6, 2000), (2.4, 200)])
def test_gaussian_fit_locks_no_more_than_the_midpoint(sigma, amplitude):
    """Started from the midpoints (and left there where too few unclipped rows remain), the
    Gaussian fit is never worse than them, and on a clipped or wide stripe several times
    better."""
    phases = np.linspace(0.0, 1.0, 41)
    luma = _columns(sigma, amplitude, phases)
    mid_rows = half_max_midpoints(luma, CENTRE + np.round(phases), 6)
    fit = gauss_rows(luma, mid_rows, 6) - (CENTRE + phases)
    mid = mid_rows - (CENTRE + phases)
    assert np.abs(fit).max() <= 0.045  # px
    assert np.ptp(fit) <= np.ptp(mid) + 0.002
    if amplitude == 2000 and sigma >= 1.2:  # a clipped core: its flanks decide
        assert np.ptp(fit) < 0.4 * np.ptp(mid)


def test_gaussian_fit_keeps_the_rows_it_cannot_fit():
    luma = _columns(1.2, 300, np.zeros(3))
    luma[:, 1] = 50  # flat: nothing to fit
    rows = np.array([CENTRE + 0.3, 14.6, np.nan])
    out = gauss_rows(luma, rows, 6)
    assert out[0] == pytest.approx(CENTRE, abs=0.02)  # moved to the stripe's centre
    assert out[1] == 14.6 and np.isnan(out[2])
    # 3 rows from the band's edge: the window stays inside the band; fitted or kept
    start = np.array([CENTRE - 12 + 0.2, CENTRE - 12 + 0.2, np.nan])
    near = gauss_rows(luma[12:], start, 6)
    assert near[0] == pytest.approx(CENTRE - 12, abs=0.02)
    assert near[1] == start[1]  # the flat column: kept
