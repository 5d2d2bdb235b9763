"""Laser-stripe detection: per frame, per laser, a sub-pixel row for every image column.

Three methods share one sub-pixel stage:

- ``hue``: the seed's HSV method - hue inside the laser's range with saturation/value floors,
  dilated vertically so the saturated (white) core joins its coloured halo;
- ``lut``: the seed's background model - a table ``Cmax[a, b]`` of the largest laser-channel
  value seen in the background for each pair of the other two channels; a pixel is laser light
  when its laser channel exceeds that (a saturated white core does: the background never shows
  white with both other channels at full scale);
- ``combined`` (default): a pixel is laser light when either test says so.

The peak is decided by colour but located on the sharpest signal, the luma (in 4:2:0 video the
colour has half the vertical resolution): centre of mass of the background-subtracted luma above
half of its maximum, in a window around the strongest laser pixel of the column.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from impress_gui.core.errors import InputError

LASERS = ("green", "red")
METHODS = ("combined", "hue", "lut")
_CH = {"red": 0, "green": 1}  # laser channel in RGB
_OTHERS = {"red": (1, 2), "green": (0, 2)}
LUT_SHIFT = 2  # tables are 64 x 64 (channel values >> 2)


@dataclass(frozen=True)
class StripeParams:
    """Detection parameters. ``rois`` maps a laser to its band of rows ``(first, stop)``."""

    method: str = "combined"
    rois: dict[str, tuple[int, int]] = field(default_factory=dict)
    min_peak: float = 25.0  # luma above the column's local background, grey levels
    half_window_px: int = 6
    hue_ranges: dict[str, tuple[tuple[int, int], ...]] = field(
        default_factory=lambda: {"green": ((40, 90),), "red": ((0, 10), (165, 180))}
    )
    min_saturation: int = 60
    min_value: int = 120
    lut_margin: int = 6
    min_tint: int = 12
    max_width_px: int = 20

    def validate(self, height: int | None = None) -> None:
        if self.method not in METHODS:
            raise InputError(f"unknown detection method {self.method!r}; use one of "
                             f"{', '.join(METHODS)}", code="E-PARAM")
        for name, (a, b) in self.rois.items():
            if name not in LASERS:
                raise InputError(f"unknown laser {name!r} in regions of interest", code="E-PARAM")
            if not (0 <= a < b) or (height is not None and b > height):
                raise InputError(f"region of interest of the {name} laser (rows {a}..{b}) is "
                                 f"outside the image", code="E-PARAM")
        if not 1 <= self.half_window_px <= 30 or self.min_peak <= 0:
            raise InputError("half_window_px must be 1..30 and min_peak positive", code="E-PARAM")


def luma(rgb: np.ndarray) -> np.ndarray:
    """BT.601 luma of an RGB band as float32 (what H.264 stores at full resolution)."""
    rgb = rgb.astype(np.float32, copy=False)
    return 0.299 * rgb[..., 0] + 0.587 * rgb[..., 1] + 0.114 * rgb[..., 2]


class BackgroundLUT:
    """The seed's RGB lookup tables, one per laser, learned from pixels outside both ROIs."""

    def __init__(self) -> None:
        self.tables = {name: np.full((64, 64), -1, np.int16) for name in LASERS}
        self.samples = 0

    def learn(self, rgb: np.ndarray, exclude_rows: list[tuple[int, int]], step: int = 2) -> None:
        keep = np.ones(rgb.shape[0], bool)
        for a, b in exclude_rows:
            keep[max(0, a - 10) : b + 10] = False
        px = rgb[keep][::step, ::step].reshape(-1, 3)
        q = (px >> LUT_SHIFT).astype(np.intp)
        for name in LASERS:
            c = _CH[name]
            o1, o2 = _OTHERS[name]
            t = self.tables[name]
            np.maximum.at(t, (q[:, o1], q[:, o2]), px[:, c].astype(np.int16))
        self.samples += len(px)

    def mask(self, name: str, rgb: np.ndarray, margin: int) -> np.ndarray:
        c = _CH[name]
        o1, o2 = _OTHERS[name]
        t = self.tables[name]
        lim = t[rgb[..., o1] >> LUT_SHIFT, rgb[..., o2] >> LUT_SHIFT]
        return rgb[..., c].astype(np.int16) > lim + margin


def hue_mask(name: str, rgb: np.ndarray, params: StripeParams) -> np.ndarray:
    import cv2

    hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV)
    h, s, v = hsv[..., 0], hsv[..., 1], hsv[..., 2]
    m = np.zeros(h.shape, bool)
    for lo, hi in params.hue_ranges[name]:
        m |= (h >= lo) & (h <= hi)
    m &= (s >= params.min_saturation) & (v >= params.min_value)
    return m


def tint_mask(name: str, rgb: np.ndarray, params: StripeParams) -> np.ndarray:
    """Bright pixels tinted towards the laser's colour: the halo of a stripe that saturates
    to white on a bright surface, where hue and saturation tests fail."""
    c = _CH[name]
    o1, o2 = _OTHERS[name]
    ch = rgb[..., c].astype(np.int16)
    excess = ch - np.maximum(rgb[..., o1], rgb[..., o2]).astype(np.int16)
    return (excess >= params.min_tint) & (ch >= params.min_value)


@dataclass
class StripeResult:
    """Per column: sub-pixel row (NaN where no stripe) and a confidence (peak above
    background, grey levels)."""

    rows: np.ndarray  # (W,) float64, full-image row coordinates
    strength: np.ndarray  # (W,) float32

    @property
    def found(self) -> np.ndarray:
        return np.isfinite(self.rows)


def _dilate_rows(mask: np.ndarray, k: int) -> np.ndarray:
    import cv2

    kernel = np.ones((2 * k + 1, 1), np.uint8)
    return cv2.dilate(mask.view(np.uint8), kernel).astype(bool)


def detect_band(name: str, rgb_band: np.ndarray, y_band: np.ndarray | None, row0: int,
                params: StripeParams, lut: BackgroundLUT | None) -> StripeResult:
    """Detect one laser's stripe in a band of rows starting at image row ``row0``."""
    h, w = rgb_band.shape[:2]
    y = luma(rgb_band) if y_band is None else y_band.astype(np.float32, copy=False)
    method = params.method
    if method == "lut" and lut is None:
        raise InputError("the lookup-table method needs a learned background", code="E-PARAM")
    if method in ("hue", "combined"):
        m = hue_mask(name, rgb_band, params)
        if method == "combined":
            m |= tint_mask(name, rgb_band, params)
        m = _dilate_rows(m, 3)  # join the white core to its coloured halo
    else:
        m = np.zeros((h, w), bool)
    if method in ("lut", "combined") and lut is not None:
        m |= lut.mask(name, rgb_band, params.lut_margin)
    # strongest laser pixel per column (the laser channel breaks ties inside the white core)
    score = np.where(m, y + 0.01 * rgb_band[..., _CH[name]], -1.0)
    peak = score.argmax(axis=0)
    cols = np.arange(w)
    has = score[peak, cols] >= 0
    k = params.half_window_px
    offs = np.arange(-k, k + 1)
    rr = np.clip(peak[None, :] + offs[:, None], 0, h - 1)
    win = y[rr, cols[None, :]]  # (2k+1, W)
    base = win.min(axis=0)
    sig = win - base
    top = sig.max(axis=0)
    above = np.clip(sig - 0.5 * top, 0, None)
    wsum = above.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        centre = (above * rr).sum(axis=0) / wsum
    width = (sig > 0.5 * top).sum(axis=0)
    ok = has & (top >= params.min_peak) & (wsum > 0) & (width <= params.max_width_px)
    # which laser: the stripe's light (core and halo) must lean towards this laser's colour;
    # a white core alone says nothing, so the other laser's stripe entering the band is refused
    other = _CH["red" if name == "green" else "green"]
    lean = (rgb_band[rr, cols[None, :], _CH[name]].astype(np.float32)
            - rgb_band[rr, cols[None, :], other])
    ok &= (lean * (sig > 0.25 * top)).sum(axis=0) > 0
    # a stripe is a peak: the light falls below half its height on both sides of the window
    # (a bright edge, e.g. where a light object meets dark soil, does not)
    ok &= (sig[0] < 0.7 * top) & (sig[-1] < 0.7 * top)
    # a window cut by the band edge is not trusted
    ok &= (peak >= k) & (peak < h - k)
    rows = np.where(ok, centre + row0, np.nan)
    return StripeResult(rows, np.where(ok, top, 0).astype(np.float32))


def detect(rgb: np.ndarray, params: StripeParams, lut: BackgroundLUT | None = None,
           lasers=LASERS) -> dict[str, StripeResult]:
    """Detect every laser's stripe in a full RGB frame inside its region of interest."""
    out = {}
    for name in lasers:
        a, b = params.rois.get(name, (0, rgb.shape[0]))
        out[name] = detect_band(name, rgb[a:b], None, a, params, lut)
    return out


def auto_rois(frames: list[np.ndarray], margin_px: int | None = None) -> dict[str, tuple[int, int]]:
    """Default regions of interest: around the band of rows where each laser's colour is
    strongest in sample frames, widened by ``margin_px`` (default 1/12 of the image height)
    and never overlapping the other laser's band. Raise when a laser is never seen."""
    h = frames[0].shape[0]
    margin = margin_px if margin_px is not None else max(12, h // 12)
    runs, peaks = {}, {}
    for name in LASERS:
        counts = np.zeros(h)
        c = _CH[name]
        o1, o2 = _OTHERS[name]
        for f in frames:
            f16 = f.astype(np.int16)
            excess = f16[..., c] - np.maximum(f16[..., o1], f16[..., o2])
            counts += ((excess > 25) & (f16[..., c] > 200)).sum(axis=1)
        if counts.sum() < 0.2 * frames[0].shape[1] * len(frames):
            raise InputError(f"the {name} laser's stripe is not visible in the sampled frames",
                             code="E-NO-STRIPE")
        smooth = np.convolve(counts, np.ones(5) / 5, mode="same")
        pk = int(np.argmax(smooth))
        strong = smooth > 0.1 * smooth[pk]
        a = pk
        while a > 0 and strong[a - 1]:
            a -= 1
        b = pk
        while b < h - 1 and strong[b + 1]:
            b += 1
        runs[name], peaks[name] = (a, b + 1), pk
    rois = {n: (max(0, a - margin), min(h, b + margin)) for n, (a, b) in runs.items()}
    lo, hi = sorted(LASERS, key=lambda n: peaks[n])
    if rois[lo][1] > rois[hi][0]:
        cut = (runs[lo][1] + runs[hi][0]) // 2
        rois[lo] = (rois[lo][0], max(runs[lo][1], cut))
        rois[hi] = (min(runs[hi][0], cut), rois[hi][1])
    return rois
