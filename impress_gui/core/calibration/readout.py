"""A rolling shutter's readout measured from a video of a flickering lamp.

A lamp on mains power flickers at twice the mains frequency (100 Hz on 50 Hz mains, 120 Hz on
60 Hz). A rolling-shutter camera reads its rows one after another, so a plain surface lit by
such a lamp and filmed with a short exposure shows horizontal bands: one flicker period passes
while ``p`` rows are read. The readout (first row to last) is then
``(height - 1) / (flicker_hz * p)``.

:func:`readout_from_flicker` finds ``p`` in the rows' mean brightness: every sampled frame is
fitted with a smooth shading (a quadratic in the row) plus one wave whose period all frames
share and whose phase and amplitude each frame has for itself (the bands drift from frame to
frame when the frame rate is not a multiple of the flicker): a sinusoid, with its harmonics
where two or more periods are in view. The period is the one with the least residual over all
frames; its SD combines the spread of the period fitted to each frame alone and the change a
freer (quartic) shading makes. At least 1.5 periods must be in view. A picture without clear
bands (a global shutter, a lamp that does not flicker, an exposure too long), bands a smooth
shading could take, or a search that ends at its bound, is refused with ``E-NO-FLICKER``
rather than given a readout.
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
#: the longest period searched, in picture heights (1.5 periods must be in view: with fewer,
#: a smooth shading takes part of a band and the period found is percent off while a freer
#: shading agrees with it)
MAX_PERIOD_HEIGHTS = 1.0 / 1.5
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


def _row_profiles(video, n_frames: int, progress=None, cancel=None) -> np.ndarray:
    """Each sampled frame's mean brightness per row (``(F, H)``, float64)."""
    count = int(video.frame_count)
    if count < 1:
        raise InputError("the flicker video has no frames", code=codes.E_NO_FLICKER)
    idx = np.unique(np.linspace(0, count - 1, min(n_frames, count)).round().astype(int))
    rows = []
    for i, k in enumerate(idx):
        if cancel is not None:
            cancel.check()
        if progress is not None:
            progress(0.7 * i / len(idx), f"reading frame {int(k)} of the lamp video")
        img = np.asarray(video.read(int(k)))
        rows.append(img.mean(axis=(1, 2) if img.ndim == 3 else 1, dtype=np.float64))
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
                 harmonics: int = 1, grid: bool = True) -> float:
    """The period in ``[lo, hi]`` with the least residual; refused (``E-NO-FLICKER``) when
    the search ends at either bound (the bands' period lies outside what was searched)."""
    from scipy.optimize import minimize_scalar

    def cost(f):
        return float(_residual(profiles, 1.0 / f, shading, harmonics).sum())

    a, b = 1.0 / hi, 1.0 / lo
    if grid:
        # a grid even in frequency, steps a tenth of a minimum's width (about one cycle per
        # picture height), then the best step refined
        h = profiles.shape[1]
        freqs = np.linspace(a, b, int(np.clip(10 * (b - a) * h, 50, 4000)))
        k = int(np.argmin([cost(f) for f in freqs]))
        a, b = freqs[max(k - 1, 0)], freqs[min(k + 1, len(freqs) - 1)]
    res = minimize_scalar(cost, bounds=(a, b), method="bounded", options={"xatol": 1e-9})
    f = float(res.x)
    if min(f - 1.0 / hi, 1.0 / lo - f) < 0.005 * f:
        raise InputError(f"the flicker bands' period ended the search at its bound "
                         f"({1.0 / f:.1f} rows, searched {lo:.1f}-{hi:.1f}): bands too close "
                         "or too far apart to measure in this picture",
                         code=codes.E_NO_FLICKER)
    return 1.0 / f


def readout_from_flicker(video, flicker_hz: float, n_frames: int = DEFAULT_FRAMES,
                         progress=None, cancel=None) -> FlickerReadout:
    """The readout of the camera that filmed ``video`` (an open
    :class:`~impress_gui.core.formats.video.VideoSource`: a plain surface lit by a lamp
    flickering at ``flicker_hz``, twice the mains frequency). Raises
    :class:`~impress_gui.core.base.errors.InputError` (``E-NO-FLICKER``) when the frames show
    no clear bands or the readout would be implausible. ``progress(fraction, message)`` and
    ``cancel`` (a :class:`~impress_gui.core.base.progress.CancelToken`) as the core's other
    long tasks."""
    if not (np.isfinite(flicker_hz) and 1.0 <= flicker_hz <= 10000.0) or flicker_hz in (50, 60):
        raise InputError(f"flicker frequency {flicker_hz} Hz: give the lamp's flicker, twice "
                         "the mains frequency (100 on 50 Hz mains, 120 on 60 Hz)",
                         code=codes.E_VALUE)
    # in logarithms: the picture's shading (vignetting, the light's fall-off) multiplies the
    # flicker, which the log turns into a sum of a smooth shading and the bands
    profiles = np.log(np.maximum(_row_profiles(video, n_frames, progress, cancel), 1.0))
    if progress is not None:
        progress(0.7, "fitting the bands")
    h = profiles.shape[1]
    if h < 32:
        raise InputError(f"the flicker video's pictures are {h} rows high: too few to see bands",
                         code=codes.E_NO_FLICKER)
    shading = _design(h)
    lo, hi = MIN_PERIOD_ROWS, MAX_PERIOD_HEIGHTS * h
    # the fundamental first, as the one sinusoid that explains most
    try:
        p0 = _best_period(profiles, shading, lo, hi)
    except InputError:
        raise InputError(
            f"no clear flicker bands in the video (no band period between {lo:.0f} and "
            f"{hi:.0f} rows, 1.5 periods in view, fits): film a plain light surface lit only by "
            "a mains lamp, with the shortest exposure; a global-shutter camera shows no bands, "
            "and a readout under about 1.5 flicker periods (15 ms at 100 Hz) cannot be "
            "measured this way", code=codes.E_NO_FLICKER) from None
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
    fps = float(getattr(video, "fps", 0.0) or 0.0)
    longest = min(MAX_READOUT_MS, 1000.0 / fps) if fps > 0 else MAX_READOUT_MS
    if not 0.0 < readout_ms <= longest * 1.05:
        raise InputError(f"the bands give a readout of {readout_ms:.1f} ms, longer than the "
                         f"{longest:.1f} ms accepted (a frame interval at most): check the "
                         "flicker frequency", code=codes.E_NO_FLICKER)
    # the spread: the period fitted to each frame alone (near the common one)
    per = []
    for prof in profiles:
        if cancel is not None:
            cancel.check()
        try:
            per.append(_best_period(prof[None], shading, period / 1.2, period * 1.2, harmonics,
                                    grid=False))
        except InputError:  # a frame whose own period leaves +-20 %: counted at that bound
            per.append(np.nan)
    if np.isnan(per).any():
        raise InputError(f"{int(np.isnan(per).sum())} of {len(per)} frames give a band period "
                         f"more than 20 % from the common {period:.1f} rows: the bands are not "
                         "steady (a lamp that does not flicker cleanly, light changing)",
                         code=codes.E_NO_FLICKER)
    ro = 1000.0 * (h - 1) / (flicker_hz * np.asarray(per))
    sd = float(np.std(ro, ddof=1)) if len(ro) > 1 else float("nan")
    # and what the shading model moves it by (within MAX_SHADING_CHANGE, above)
    if np.isfinite(sd):
        sd = float(np.hypot(sd, readout_ms * (period / alt - 1.0)))
    if progress is not None:
        progress(1.0, "readout measured")
    return FlickerReadout(float(readout_ms), float(period), sd, len(profiles), band_share,
                          float(flicker_hz))


def measure_readout_file(path, flicker_hz: float, size: tuple[int, int] | None = None,
                         progress=None, cancel=None) -> tuple[FlickerReadout, str]:
    """:func:`readout_from_flicker` on the lamp video at ``path`` (opened read-only), with the
    line that records where the readout came from (the video's name, its SHA-256 and the
    measurement), as the intrinsics' ``source`` keeps it. ``size``: the image size the
    intrinsics are for; a lamp video of another size is refused (``E-VALUE``) before anything
    is measured - the readout belongs to the recording mode. What ``impress calibrate-camera
    --readout-from-flicker`` and the intrinsics dialog both call."""
    from pathlib import Path

    from impress_gui.core.formats.video import open_video

    path = Path(path)
    with open_video(path) as lamp:
        if size is not None and tuple(lamp.size) != tuple(size):
            raise InputError(f"the lamp video is {lamp.size[0]}x{lamp.size[1]}, the camera's "
                             f"images {size[0]}x{size[1]}: film it in the scans' recording "
                             "mode", code=codes.E_VALUE)
        r = readout_from_flicker(lamp, flicker_hz, progress=progress, cancel=cancel)
        digest = lamp.sha256()
    return r, f"readout measured from {path.name} (SHA-256 {digest}): {r.summary()}"
