"""A rolling shutter's readout measured from a video of a flickering lamp.

A lamp on mains power flickers at twice the mains frequency (100 Hz on 50 Hz mains, 120 Hz on
60 Hz). A rolling-shutter camera reads its rows one after another, so a plain surface lit by
such a lamp and filmed with a short exposure shows horizontal bands: one flicker period passes
while ``p`` rows are read. The readout (first row to last) is then
``(height - 1) / (flicker_hz * p)``.

:func:`readout_from_flicker` finds ``p`` in the rows' mean brightness: every sampled frame is
fitted with a smooth shading (a quadratic in the row) plus one sinusoid whose period all frames
share and whose phase and amplitude each frame has for itself (the bands drift from frame to
frame when the frame rate is not a multiple of the flicker). The period is the one with the
least residual over all frames; its spread is that of the period fitted to each frame alone.
A picture without clear bands (a global shutter, a lamp that does not flicker, an exposure
too long) is refused with ``E-NO-FLICKER`` rather than given a readout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from impress_gui.core.base import codes
from impress_gui.core.base.errors import InputError
from impress_gui.core.calibration.geometry import MAX_READOUT_MS

#: the bands must explain at least this share of the rows' brightness variation left after
#: the shading (median over the frames)
MIN_BAND_SHARE = 0.5
#: shortest band period searched (rows)
MIN_PERIOD_ROWS = 8.0
#: the longest period searched, in picture heights (at least one period must fit in view for
#: the shading not to take it)
MAX_PERIOD_HEIGHTS = 2.0
#: frames sampled, evenly spread over the video
DEFAULT_FRAMES = 30
#: the flicker's wave: its fundamental and harmonics up to this one, where at least
#: ``MIN_PERIODS_FOR_HARMONICS`` periods are in view (with fewer, a longer wave with harmonics
#: fits a period and a half as well)
HARMONICS = 4
MIN_PERIODS_FOR_HARMONICS = 2.0
#: the period found with a quartic shading may differ from the quadratic's by this much
#: (relative) before the bands are taken for shading
SHADING_CHECK_DEGREE = 4
MAX_SHADING_CHANGE = 0.02


@dataclass(frozen=True)
class FlickerReadout:
    """The readout measured (ms), the band period (rows), the standard deviation of the
    readout (ms: the spread of the period fitted to each of the ``frames`` alone, and the
    change a freer model of the picture's shading makes) and the share of the rows' variation
    the bands explain (median over the frames)."""

    readout_ms: float
    period_rows: float
    sd_ms: float
    frames: int
    band_share: float
    flicker_hz: float

    def summary(self) -> str:
        spread = (f"SD {self.sd_ms:.2f} ms: {self.frames} frames' spread and the shading"
                  if np.isfinite(self.sd_ms) else "one frame: no spread")
        return (f"readout {self.readout_ms:.2f} ms ({spread}): bands {self.period_rows:.1f} rows apart at {self.flicker_hz:g} Hz "
                f"of flicker, {100 * self.band_share:.0f} % of the rows' variation")


def _row_profiles(video, n_frames: int) -> np.ndarray:
    """Each sampled frame's mean brightness per row (``(F, H)``, float64)."""
    count = int(video.frame_count)
    if count < 1:
        raise InputError("the flicker video has no frames", code=codes.E_NO_FLICKER)
    idx = np.unique(np.linspace(0, count - 1, min(n_frames, count)).round().astype(int))
    rows = []
    for k in idx:
        rgb = np.asarray(video.read(int(k)), np.float64)
        rows.append(rgb.mean(axis=(1, 2)) if rgb.ndim == 3 else rgb.mean(axis=1))
    return np.array(rows)


def _design(h: int, degree: int = 2) -> np.ndarray:
    r = np.linspace(-1.0, 1.0, h)
    return np.column_stack([r**k for k in range(degree + 1)])


def _residual(profiles: np.ndarray, period: float, shading: np.ndarray,
              harmonics: int = 1) -> np.ndarray:
    """Each frame's residual sum of squares with the shading and a periodic wave of
    ``period``: a sinusoid and ``harmonics - 1`` of its harmonics (a lamp's flicker is seldom
    a pure sinusoid: a rectified sine, or a square wave of LED drivers)."""
    h = profiles.shape[1]
    w = 2.0 * np.pi * np.arange(h) / period
    waves = [f(k * w) for k in range(1, harmonics + 1) for f in (np.cos, np.sin)]
    a = np.column_stack([shading, *waves])
    coef, *_ = np.linalg.lstsq(a, profiles.T, rcond=None)
    return np.sum((profiles.T - a @ coef) ** 2, axis=0)


def _best_period(profiles: np.ndarray, shading: np.ndarray, lo: float, hi: float,
                 harmonics: int = 1) -> float:
    from scipy.optimize import minimize_scalar

    def cost(f):
        return float(_residual(profiles, 1.0 / f, shading, harmonics).sum())

    # a grid even in frequency (the residual's minima are about equally wide there), then the
    # best step refined
    freqs = np.linspace(1.0 / hi, 1.0 / lo, 400)
    k = int(np.argmin([cost(f) for f in freqs]))
    a, b = freqs[max(k - 1, 0)], freqs[min(k + 1, len(freqs) - 1)]
    res = minimize_scalar(cost, bounds=(a, b), method="bounded", options={"xatol": 1e-9})
    return 1.0 / float(res.x)


def readout_from_flicker(video, flicker_hz: float, n_frames: int = DEFAULT_FRAMES
                         ) -> FlickerReadout:
    """The readout of the camera that filmed ``video`` (an open
    :class:`~impress_gui.core.formats.video.VideoSource`: a plain surface lit by a lamp
    flickering at ``flicker_hz``, twice the mains frequency). Raises
    :class:`~impress_gui.core.base.errors.InputError` (``E-NO-FLICKER``) when the frames show
    no clear bands or the readout would be implausible."""
    if not (np.isfinite(flicker_hz) and 1.0 <= flicker_hz <= 10000.0):
        raise InputError(f"flicker frequency {flicker_hz} Hz: give the lamp's flicker, twice "
                         "the mains frequency (100 or 120)", code=codes.E_VALUE)
    profiles = _row_profiles(video, n_frames)
    h = profiles.shape[1]
    if h < 32:
        raise InputError(f"the flicker video's pictures are {h} rows high: too few to see bands",
                         code=codes.E_NO_FLICKER)
    shading = _design(h)
    lo, hi = MIN_PERIOD_ROWS, MAX_PERIOD_HEIGHTS * h
    # the fundamental first, as the one sinusoid that explains most
    p0 = _best_period(profiles, shading, lo, hi)
    harmonics = 1
    if h / p0 >= MIN_PERIODS_FOR_HARMONICS:
        # with several periods in view, the wave with its harmonics (a lamp's flicker is seldom
        # a pure sinusoid) within a factor 1.5 of the fundamental: never reaching half or twice
        # it (a wave of twice the period whose second harmonic is the flicker fits as well)
        harmonics = HARMONICS
        period = _best_period(profiles, shading, max(lo, p0 / 1.5), min(hi, p0 * 1.5),
                              harmonics)
    else:
        period = p0
    # the bands must not depend on how the picture's shading is modelled: with a period or
    # two in view a smooth shading can take part of a band
    alt = _best_period(profiles, _design(h, SHADING_CHECK_DEGREE), max(lo, period / 1.5),
                       min(hi, period * 1.5), harmonics)
    if abs(alt / period - 1.0) > MAX_SHADING_CHANGE:
        raise InputError(
            f"the flicker bands cannot be told from the picture's shading (about "
            f"{h / period:.1f} periods in view; a smoother or a freer shading gives "
            f"{period:.0f} or {alt:.0f} rows per period): light the surface evenly (no "
            "vignetting, no spot), or measure at a higher flicker frequency or from the data "
            "sheet", code=codes.E_NO_FLICKER)
    # how much of each frame's variation (after the shading) the bands explain
    coef, *_ = np.linalg.lstsq(shading, profiles.T, rcond=None)
    rss0 = np.sum((profiles.T - shading @ coef) ** 2, axis=0)
    rss1 = _residual(profiles, period, shading, harmonics)
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.where(rss0 > 0, 1.0 - rss1 / rss0, 0.0)
    band_share = float(np.median(share))
    if not band_share >= MIN_BAND_SHARE or not lo * 1.01 < period < hi * 0.99:
        raise InputError(
            f"no clear flicker bands in the video (the best period, {period:.1f} rows, explains "
            f"{100 * max(band_share, 0.0):.0f} % of the rows' brightness variation; at least "
            f"{100 * MIN_BAND_SHARE:.0f} % needed): film a plain light surface lit only by a "
            "mains lamp, with the shortest exposure; a global-shutter camera shows no bands",
            code=codes.E_NO_FLICKER)
    readout_ms = 1000.0 * (h - 1) / (flicker_hz * period)
    if not 0.0 < readout_ms <= MAX_READOUT_MS:
        raise InputError(f"the bands give a readout of {readout_ms:.1f} ms, above the "
                         f"{MAX_READOUT_MS:g} ms accepted: check the flicker frequency",
                         code=codes.E_NO_FLICKER)
    # the spread: the period fitted to each frame alone (near the common one)
    per = [_best_period(p[None], shading, period / 1.2, period * 1.2, harmonics)
           for p in profiles]
    ro = 1000.0 * (h - 1) / (flicker_hz * np.asarray(per))
    sd = float(np.std(ro, ddof=1)) if len(ro) > 1 else float("nan")
    # and what the shading model moves it by (within MAX_SHADING_CHANGE, above)
    sd = float(np.hypot(sd, readout_ms * (period / alt - 1.0)))
    return FlickerReadout(float(readout_ms), float(period), sd, len(profiles), band_share,
                          float(flicker_hz))
