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
half of its maximum, in a window around the strongest laser pixel of the column; then (the
default ``subpixel="window"``) refined by :func:`window_refine`, which is far less locked to the
pixel grid (docs/accuracy.md; ``subpixel="half-max"`` keeps the first centre).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from impress_gui.core.base import codes
from impress_gui.core.base.errors import InputError
from impress_gui.core.formats.video import Planes

LASERS = ("green", "red")
METHODS = ("combined", "hue", "lut")
SUBPIXEL = ("window", "half-max")
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
    max_wrong_lean: float = 4.0  # chroma units: the halo leaning to the other laser's colour
    # ... unless the stripe used more of its own channel's headroom than of the other laser's
    # (summed shares over the window's rows; see headroom_lean); inf: never
    min_headroom_lean: float = 0.3
    # inside the other laser's band, when it is known (the reconstruction), the stripe's light
    # (its rows above a fifth of the peak, weighted by their light) must lean to this laser's
    # colour by more than this (chroma units), else the headroom test decides: the other
    # laser's stripe blooming white there leans to neither colour (issue 18, rig 1), and its
    # halo alone can be one row of textured ground (rig 23)
    min_lean_in_other_band: float = 0.0
    # with the other laser's band known (the reconstruction), a column whose candidate (the
    # brightest light leaning to this laser's chroma) was refused gets a second one: where it
    # lay in that band, the best more than two half windows away (the other stripe, brighter,
    # can hide this one: issue 18, rig 1, 38-46 % of the red stripe's columns at one end of the
    # image); where it was no peak (a light target face outscoring the stripe on dark ground:
    # rig 6), the row rising most above the scores RIDGE_STEP rows off, whose halo must then
    # lean to this laser's colour wherever it lies; where the first lay in that band and the
    # second is refused too, a third: the best of this laser's own rows, outside that band
    # (widened by the half window) - the second can be a light surface beside the other
    # laser's stripe, still in its band (issue 18, random rig 212: a white block under the
    # green stripe hid the red stripe on dark soil in 556 of a frame's columns)
    second_candidate: bool = True
    # with the other laser's band known, a column whose row does not continue into a
    # neighbour's is searched again at the row its continuing neighbours predict and takes the
    # peak found there if it lies within kernels.GUIDE_DEV of it (guided_prediction): on
    # bright, speckled soil a piece of soil outscored the stripe in 8 % of the red stripe's
    # columns (issue 18, random rig 13); there a peak the colour tests refuse is kept when its
    # halo does not lean to the other laser's colour by the white-core rule's limit (the
    # position vouches for it: rig 13's green stripe, gone grey on bright soil, 4.4 -> 3.3 %
    # of its columns missed at 1080p, none taken off the stripe). A short piece of continuing
    # columns (at most kernels.GUIDE_SHORT) off the row that longer pieces on both sides
    # continue across is searched again the same way (random rig 254's red stripe at 1080p:
    # 2-4 column pieces of reddish soil, later dropped as islands; fill 98.5 -> 99.1 %)
    guided: bool = True
    # with the other laser's band known, a peak the colour tests refuse is kept when its core
    # saturates this laser's channel and its light leans to this laser's colour (the
    # calibration's blooming test, blooming_lean): a red stripe blooming white on yellowish
    # soil, whose core has no red tint left (issue 18, rig 7), if its halo also leans to this
    # laser's colour by more than min_lean_in_other_band (the combined method only)
    blooming: bool = True
    # with the other laser's band known, outside that band (widened by the half window), a
    # peak the colour tests and the blooming test refuse is kept when its core is clipped
    # white (this laser's channel and the luma at full scale, BLOOM_LEVEL, the luma within
    # kernels.WHITE_LUMA_DROP of it on soil near full scale in that channel; bright soil of
    # this laser's colour saturates the channel, not the luma) and its halo does not lean to the
    # other laser's colour by
    # max_wrong_lean or more (a 4:2:0 halo a row or two wide often has no lean): on bright soil
    # both lasers' stripes saturate to the same near white, (255, 255, 230), and only their
    # faint halo is tinted; there the band tells the lasers apart (issue 18, random rig 13 at
    # 1920x1080: 43 % of the green stripe's columns refused by colour alone)
    white_core: bool = True
    # a peak weaker than min_peak in the luma (down to kernels.FAINT_SHARE of it) is a peak
    # when its light is of this laser's colour: the laser's channel rises by at least
    # kernels.FAINT_RISE x min_peak and the other channels, against the surface's own colour,
    # clearly less (kernels.FAINT_TINT; faint_light). A red laser on a light surface adds
    # mostly red, a third of which shows in the luma: on photographs of a pinkish stripe on a
    # white object the luma rose 10-20 grey levels and the stripe was found in none of the
    # columns where plain background subtraction finds it (issue 18, real laser light). On
    # dark soil the laser's channel need not reach min_value when it rises by
    # kernels.FAINT_DARK_RISE of the surface's level, clear of the surface's own variation
    # (random rig 214: a dim red laser on soil of luma 30-60, the map's fill 82.8 %)
    faint: bool = True
    # with the other laser's band and the stripe's row on the ground known (the
    # reconstruction), a column whose stripe was found inside that band (widened by the half
    # window) is searched again in this laser's own rows, outside it; a stripe found there at
    # least EXCLUSIVE_SHARE as strong and nearer the ground's row is taken instead. Nothing in
    # those rows can be the other laser's stripe (it lies in its band whatever the surface's
    # height), while the peak inside may be: on near-white soil with both lasers blooming and
    # both from behind, the two stripes' cores are the same white, the 4:2:0 chroma of a thin
    # stripe is the soil's, and the green stripe took the red one in 1.7 % of its cells, 55 mm
    # too high (issue 18, random rig 102, 2026-12-04)
    prefer_own_rows: bool = True
    max_width_px: int = 20
    # the centre's sub-pixel estimate: "window" (the centre of mass above half maximum refined
    # by window_refine: less locked to the pixel grid; docs/accuracy.md) or "half-max" (that
    # first centre)
    subpixel: str = "window"

    def validate(self, height: int | None = None) -> None:
        if self.method not in METHODS:
            raise InputError(f"unknown detection method {self.method!r}; use one of "
                             f"{', '.join(METHODS)}", code=codes.E_PARAM)
        for name, (a, b) in self.rois.items():
            if name not in LASERS:
                raise InputError(f"unknown laser {name!r} in regions of interest", code=codes.E_PARAM)
            if not (0 <= a < b) or (height is not None and b > height):
                raise InputError(f"region of interest of the {name} laser (rows {a}..{b}) is "
                                 f"outside the image", code=codes.E_PARAM)
        if self.subpixel not in SUBPIXEL:
            raise InputError(f"unknown sub-pixel estimate {self.subpixel!r}; use one of "
                             f"{', '.join(SUBPIXEL)}", code=codes.E_PARAM)
        if not 1 <= self.half_window_px <= 30 or self.min_peak <= 0:
            raise InputError("half_window_px must be 1..30 and min_peak positive", code=codes.E_PARAM)


class BackgroundLUT:
    """The seed's RGB lookup tables, one per laser, learned from pixels outside both ROIs."""

    def __init__(self) -> None:
        self.tables = {name: np.full((64, 64), -1, np.int16) for name in LASERS}
        self.samples = 0
        # the luma (BT.601 weights, 0-255) of the frames learned from: how much of the ground
        # is so bright that a stripe cannot rise above it (near_full_share)
        self.luma_hist = np.zeros(256, np.int64)

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
        # the whole picture's luma (the lasers' bands too: on some mountings they cover the
        # picture, and the stripes themselves are a few per cent of it)
        p32 = rgb[::step, ::step].reshape(-1, 3).astype(np.int32)
        luma = (77 * p32[:, 0] + 150 * p32[:, 1] + 29 * p32[:, 2] + 128) >> 8
        self.luma_hist += np.bincount(np.minimum(luma, 255), minlength=256)
        self.samples += len(px)

    def near_full_share(self, margin: float) -> float:
        """The share of the frames' pixels (the whole picture, sampled) whose luma lies
        within ``margin`` grey levels of full scale (NaN before any)."""
        n = int(self.luma_hist.sum())
        if n == 0:
            return float("nan")
        first = max(0, min(256, int(math.ceil(255 - margin))))
        return float(self.luma_hist[first:].sum()) / n

    def mask(self, name: str, rgb: np.ndarray, margin: int) -> np.ndarray:
        c = _CH[name]
        o1, o2 = _OTHERS[name]
        t = self.tables[name]
        lim = t[rgb[..., o1] >> LUT_SHIFT, rgb[..., o2] >> LUT_SHIFT]
        return rgb[..., c].astype(np.int16) > lim + margin


@dataclass
class StripeResult:
    """Per column: sub-pixel row (NaN where no stripe) and a confidence (peak above
    background, grey levels)."""

    rows: np.ndarray  # (W,) float64, full-image row coordinates
    strength: np.ndarray  # (W,) float32

    @property
    def found(self) -> np.ndarray:
        return np.isfinite(self.rows)

    def copy(self) -> StripeResult:
        return StripeResult(self.rows.copy(), self.strength.copy())


def _hue_ok(name: str, rgb: np.ndarray, params: StripeParams) -> np.ndarray:
    import cv2

    flat = np.ascontiguousarray(rgb.reshape(1, -1, 3).astype(np.uint8))
    hsv = cv2.cvtColor(flat, cv2.COLOR_RGB2HSV).reshape(*rgb.shape)
    h, s, v = hsv[..., 0], hsv[..., 1], hsv[..., 2]
    m = np.zeros(h.shape, bool)
    for lo, hi in params.hue_ranges[name]:
        m |= (h >= lo) & (h <= hi)
    return m & (s >= params.min_saturation) & (v >= params.min_value)


#: (first row per column, rows: one height for every column or each column's own)
Band = tuple[np.ndarray, int | np.ndarray]


def detect_planes(name: str, planes: Planes, band_start: np.ndarray, band_height: int,
                  params: StripeParams, lut: BackgroundLUT | None,
                  other: Band | None = None, ground: np.ndarray | None = None) -> StripeResult:
    """Detect one laser's stripe; column ``c`` is searched in rows
    ``band_start[c] .. band_start[c] + band_height``. ``other``: the other laser's band (where
    its stripe can lie, from the calibration and the height range): a peak whose halo leans to
    the other laser's colour is refused only within it (widened by the half window), and there
    a halo must lean to this laser's colour (``StripeParams.min_lean_in_other_band``) unless
    the headroom test keeps it; without it, a lean to the other colour is refused everywhere. The compiled kernel
    (:func:`impress_gui.core.reconstruction.kernels.detect_stripe`) of :func:`detect_planes_numpy`."""
    return StripeDetector(name, band_start, band_height, params, lut, other,
                          ground)(planes).copy()


def _other_band(other: Band | None, w: int) -> tuple[np.ndarray, np.ndarray]:
    """The other laser's band per column: first row and rows (one height for every column,
    or each column's own); every row (``-2**40`` on, ``2**41`` rows) when unknown."""
    if other is None:
        return np.full(w, -(1 << 40), np.int64), np.full(w, 1 << 41, np.int64)
    start, height = other
    if len(start) != w or (np.ndim(height) and np.size(height) != w):
        raise InputError(f"the other laser's band has {len(start)} columns, the frame {w}",
                         code=codes.E_SIZE_MISMATCH)
    rows = np.asarray(height, np.int64)
    # copies: a detector may narrow its own per frame (StripeDetector.narrow_other)
    return (np.array(start, dtype=np.int64),
            np.full(w, int(rows), np.int64) if rows.ndim == 0 else np.array(rows, np.int64))


def _bloom_lean(params: StripeParams, other: Band | None) -> float:
    """The blooming test's minimum lean where the colour tests refuse a peak (inf: none):
    ``BLOOM_LEAN`` when the other laser's band is known, ``params.blooming`` and the method is
    the combined one (``hue`` and ``lut`` stay the seed's methods)."""
    on = params.blooming and other is not None and params.method == "combined"
    return BLOOM_LEAN if on else float("inf")


def _white_lean(params: StripeParams, other: Band | None) -> float:
    """The white-core rule's largest lean to the other laser's colour (chroma units, negated;
    inf: no rule): ``max_wrong_lean`` with the other laser's band known, the combined method
    and ``params.white_core`` (``StripeParams.white_core``)."""
    on = params.white_core and other is not None and params.method == "combined"
    return float(params.max_wrong_lean) if on else float("inf")


def _wrong_lean(params: StripeParams, other: Band | None) -> float:
    """The lean to the other laser's colour (chroma units, negated) at or beyond which a peak
    in the other laser's band is refused unless the headroom test keeps it: ``max_wrong_lean``
    without a known band (the test then applies everywhere), ``-min_lean_in_other_band`` with
    one (a halo that does not lean to this laser's colour is not enough there)."""
    if other is None:
        return float(params.max_wrong_lean)
    return -float(params.min_lean_in_other_band)


#: a stripe in this laser's own rows replaces one found in the other laser's band when it is
#: at least this share of that one's strength (StripeParams.prefer_own_rows)
EXCLUSIVE_SHARE = 0.7


def own_regions(band_start: np.ndarray, band_height: int, other: Band, k: int,
                image_height: int) -> list[tuple[np.ndarray, int, np.ndarray, np.ndarray]]:
    """This laser's rows outside the other laser's band (widened by ``k`` rows), per column:
    the part of the band before it and the part after it. Each as ``(start, height, lo, hi)``:
    a band (first row per column, one height: the largest part's) to search, and the rows
    ``lo[c] .. hi[c] - 1`` of column ``c`` that are really outside (a search band reaching
    into the other laser's band is cut back to them afterwards). Parts no column has (fewer
    than ``2 k + 1`` rows) are left out."""
    b0 = np.asarray(band_start, np.int64)
    b1 = b0 + int(band_height)
    o0, oh = other
    o0 = np.asarray(o0, np.int64)
    out = []
    oh = np.asarray(oh, np.int64)
    for lo, hi in ((b0, np.minimum(o0 - k, b1)), (np.maximum(o0 + oh + k, b0), b1)):
        lo = np.clip(lo, 0, image_height - 1)
        hi = np.maximum(np.clip(hi, 0, image_height), lo)  # empty where lo >= hi
        height = int((hi - lo).max(initial=0))
        if height >= 2 * k + 1:
            out.append((lo, height, lo, hi))
    return out


def prefer_own_rows(rows: np.ndarray, strength: np.ndarray, other: Band, k: int,
                    found: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]],
                    ground: np.ndarray) -> int:
    """In place: where ``rows`` lie inside the other laser's band (widened by ``k``), take the
    stripe found in this laser's own rows instead (``found``: per part of
    :func:`own_regions`, its rows, strengths and the part's ``lo``/``hi``), if it lies
    within the part, is at least :data:`EXCLUSIVE_SHARE` as strong and nearer the row where
    the stripe falls on the ground (``ground``, per column: a surface at height 0): the
    other laser's stripe, taken for this one's, reads heights far from the ground (rig 102:
    55-61 mm), while this laser's own stripe inside that band on the ground must not give way
    to a piece of bright soil in its own rows. Returns how many columns changed."""
    o0, oh = other
    inside = np.isfinite(rows) & (rows + k >= o0) & (rows - k < np.asarray(o0) + oh)
    changed = 0
    for r2, s2, lo, hi in found:
        take = (inside & np.isfinite(r2) & (r2 >= lo) & (r2 < hi)
                & (s2 >= EXCLUSIVE_SHARE * strength)
                & (np.abs(r2 - ground) < np.abs(rows - ground)))
        if take.any():
            rows[take] = r2[take]
            strength[take] = s2[take]
            inside &= ~take
            changed += int(take.sum())
    return changed


class StripeDetector:
    """:func:`detect_planes` for one laser, frame after frame: the kernel's arguments are
    prepared once, and each call's result is in arrays the next call overwrites."""

    def __init__(self, name: str, band_start: np.ndarray, band_height: int,
                 params: StripeParams, lut: BackgroundLUT | None,
                 other: Band | None = None, ground: np.ndarray | None = None) -> None:
        from impress_gui.core.reconstruction.compiled import kernels

        method = params.method
        if method == "lut" and lut is None:
            raise InputError("the lookup-table method needs a learned background",
                             code=codes.E_PARAM)
        w = len(band_start)
        ranges = params.hue_ranges[name]
        table = lut.tables[name] if (lut is not None and method in ("lut", "combined")) else \
            np.zeros((0, 0), np.int16)
        sdiv, hdiv = _hsv_tables()
        o1, o2 = _OTHERS[name]
        self.result = StripeResult(np.empty(w, np.float64), np.empty(w, np.float32))
        self._kernel = kernels().detect_stripe
        self._args = (
            (np.ascontiguousarray(band_start, dtype=np.int64), int(band_height),
             *_other_band(other, w)),
            (1 if name == "red" else -1, _CH[name], o1, o2),
            (float(params.min_peak), int(params.half_window_px), int(params.max_width_px),
             _wrong_lean(params, other), float(params.min_headroom_lean),
             int(params.subpixel == "window"),
             int(params.second_candidate and other is not None)
             | 2 * int(params.guided and other is not None) | 4 * int(params.faint),
             float(BLOOM_LEVEL), _bloom_lean(params, other), other is not None,
             _white_lean(params, other)),
            (method in ("hue", "combined"), np.array([a for a, _ in ranges], np.int64),
             np.array([b for _, b in ranges], np.int64), int(params.min_saturation),
             int(params.min_value), method == "combined", float(params.min_tint), table,
             int(params.lut_margin)),
            (sdiv, hdiv), (self.result.rows, self.result.strength))
        # this laser's own rows, searched again where the stripe was found in the other
        # laser's band (StripeParams.prefer_own_rows)
        self._other, self._ground = other, ground
        self._own: list = []
        self.own_rows_taken = 0  # columns changed by prefer_own_rows, over all calls
        # the other laser's band as the kernel reads it (narrow_other may rewrite it per frame)
        # and as it was given
        self._o_band = self._args[0][2:4]
        self._o_given = (self._o_band[0].copy(), self._o_band[1].copy())
        if params.prefer_own_rows and other is not None and ground is not None \
                and len(band_start):
            import dataclasses

            alone = dataclasses.replace(params, prefer_own_rows=False)
            # the image's height is not known before the first frame: the band's end bounds it
            for start, height, lo, hi in own_regions(band_start, band_height, other,
                                                     int(params.half_window_px),
                                                     int(np.max(band_start)) + band_height):
                self._own.append((StripeDetector(name, start, height, alone, lut, other), lo, hi))

    def narrow_other(self, other_rows: np.ndarray, margin: int) -> None:
        """Where the other laser's stripe was found in this frame (``other_rows``, NaN where
        not), its band becomes the rows within ``margin`` of it; elsewhere the band given.
        For a detector of its own (the kernel reads the band from these arrays)."""
        start, height = self._o_band
        found = np.isfinite(other_rows)
        np.copyto(start, self._o_given[0])
        np.copyto(height, self._o_given[1])
        start[found] = np.floor(other_rows[found]).astype(np.int64) - margin
        height[found] = 2 * margin + 2

    def __call__(self, planes: Planes) -> StripeResult:
        if planes.y.shape[1] != len(self.result.rows):
            raise InputError(f"a frame {planes.y.shape[1]} pixels wide, bands for "
                             f"{len(self.result.rows)}", code=codes.E_SIZE_MISMATCH)
        self._kernel((planes.y, planes.cb, planes.cr, planes.chroma_step), *self._args)
        if self._own and self._other is not None and self._ground is not None:
            res, k = self.result, int(self._args[2][1])
            o0, oh = self._other
            if (np.isfinite(res.rows) & (res.rows + k >= o0) & (res.rows - k < o0 + oh)).any():
                found = []
                for det, lo, hi in self._own:
                    r = det(planes)
                    found.append((r.rows.copy(), r.strength.copy(), lo, hi))
                self.own_rows_taken += prefer_own_rows(res.rows, res.strength, self._other, k,
                                                       found, self._ground)
        return self.result


_HSV_TABLES: tuple | None = None


def _hsv_tables():
    global _HSV_TABLES
    if _HSV_TABLES is None:
        from impress_gui.core.reconstruction.compiled import kernels

        _HSV_TABLES = kernels().hsv_tables()
    return _HSV_TABLES


def detect_planes_numpy(name: str, planes: Planes, band_start: np.ndarray, band_height: int,
                        params: StripeParams, lut: BackgroundLUT | None,
                        other: Band | None = None,
                        ground: np.ndarray | None = None) -> StripeResult:
    """The readable numpy reference of :func:`detect_planes` (the tests check they agree).

    1. candidate: per column the brightest pixel of luma biased towards the laser's chroma;
    2. the method's colour test (hue, background table, tint) on the pixels around it;
    3. centre of mass of the background-subtracted luma above half maximum, with checks that
       it is a peak (not an edge) leaning to this laser's colour;
    4. with the other laser's band known, a refused candidate gets a second one
       (``StripeParams.second_candidate``)."""
    method = params.method
    if method == "lut" and lut is None:
        raise InputError("the lookup-table method needs a learned background", code=codes.E_PARAM)
    h, w = planes.y.shape
    cols = np.arange(w)
    s = planes.chroma_step
    # one rectangular slice covering every column's band (views, no gathering), searched at
    # every second row (a stripe is several rows wide) with the rows outside a column's own
    # band pushed out; chroma rows match the even luma rows of 4:2:0 video
    r0 = int(band_start.min())
    r0 -= r0 % 2
    r1 = int(min(h, (band_start + band_height).max()))
    yb = planes.y[r0:r1:2].astype(np.int16)
    crb = planes.cr[r0 // s : r0 // s + yb.shape[0] * 2 // s : 2 // s if s < 2 else 1]
    if s > 1:
        import cv2

        crb = cv2.resize(crb, (crb.shape[1] * s, crb.shape[0]), interpolation=cv2.INTER_NEAREST)
    crb = crb[: yb.shape[0], :w]
    score = yb + (crb.astype(np.int16) - 128) * (1 if name == "red" else -1)
    rows_c = r0 + 2 * np.arange(yb.shape[0])
    rel = rows_c[:, None] - band_start[None, :]
    score[(rel < 0) | (rel >= band_height)] = -1000
    # argmax along axis 0 is slow in numpy; a max over (score, reversed row) pairs packed in
    # one integer is fast and picks the same row (the first of equal maxima)
    nr = yb.shape[0]
    packed = score.astype(np.int32) * 4096 + (4095 - np.arange(nr, dtype=np.int32))[:, None]
    coarse = r0 + 2 * (4095 - (packed.max(axis=0) & 4095))
    searched = (packed.max(axis=0) >> 12) > -1000  # else no row of the column's band

    def attempt(coarse, strict=False, vouched=False):
        """Steps 2-4 at the candidate rows ``coarse``: (kept, centre, strength, why) - why a
        column was refused: 0 not (or by colour outside the other laser's band), 1 in that
        band, 2 not a peak (too weak, at the band's edge, an edge, too wide). ``strict`` (per
        column): the lean test of the other laser's band applies everywhere. ``vouched`` (per
        column): rows predicted by the stripe's continuing neighbours (the guided pass), where
        a peak the colour tests refuse is kept (why 5) if its halo does not lean to the other
        laser's colour by the white-core rule's limit or more; like a white core it must then
        be confirmed by its chain (confirmed_by_colour)."""
        # fine: the brightest luma row within +-2 rows of the coarse candidate
        fine_offs = np.arange(-2, 3)
        fr = np.clip(coarse[None, :] + fine_offs[:, None], 0, h - 1)
        peak = fr[planes.y[fr, cols[None, :]].argmax(axis=0), cols]
        peak_i = peak - band_start
        sign = 1 if name == "red" else -1
        k = params.half_window_px
        offs = np.arange(-k, k + 1)

        def window(centre_rows):
            rr = np.clip(centre_rows[None, :] + offs[:, None], 0, h - 1)  # (2k+1, W) image rows
            win = planes.y[rr, cols[None, :]].astype(np.float32)
            sig = win - win.min(axis=0)
            top = sig.max(axis=0)
            above = np.clip(sig - 0.5 * top, 0, None)
            wsum = above.sum(axis=0)
            with np.errstate(invalid="ignore", divide="ignore"):
                centre = (above * rr).sum(axis=0) / wsum
            return rr, sig, top, wsum, centre

        # the brightest row may sit at one edge of a saturated core: centre the window on the
        # first estimate and measure again
        rr, sig, top, wsum, centre = window(peak)
        peak = np.where(np.isfinite(centre), np.rint(np.nan_to_num(centre)), peak).astype(np.int64)
        rr, sig, top, wsum, centre = window(peak)
        peak_i = peak - band_start
        width = (sig > 0.5 * top).sum(axis=0)
        # a peak weaker than min_peak (down to kernels.WEAK_SHARE of it) is tested further
        # only for the white-core rule, away from the other laser's band: a stripe clipped
        # white on the brightest soil stands only 10-25 grey levels above it
        inside0 = (peak + k >= o_start) & (peak - k < o_start + o_height) | strict
        # a faint stripe (kernels.FAINT_SHARE): its light of this laser's colour makes it a peak
        placed = (wsum > 0) & (peak_i >= k) & (peak_i < band_height - k)
        faint = ((top < params.min_peak) & (top >= _guide()["faint"][0] * params.min_peak)
                 & placed & params.faint)
        if faint.any():
            faint[faint] = faint_light(name, planes, rr[:, faint], cols[faint],
                                       params.min_peak, params.min_value)
        weak = ((top < params.min_peak) & (_white_lean(params, other) < np.inf) & ~inside0
                & (top >= _guide()["weak"] * params.min_peak) & ~faint)
        ok = ((top >= params.min_peak) | weak | faint) & placed
        ok &= width <= params.max_width_px
        ok &= (sig[0] < 0.7 * top) & (sig[-1] < 0.7 * top)
        peakish = ok.copy()
        # which laser: the stripe's halo (not its white core) shifts the chroma of the surface it
        # falls on towards this laser's colour - judged against the background at the window's
        # ends, so red or green soil does not decide it; the other laser's stripe is refused
        crw = planes.cr[rr // s, (cols // s)[None, :]].astype(np.float32)
        cr_bg = 0.5 * (crw[0] + crw[-1])
        halo = (sig > 0.2 * top) & (sig < 0.65 * top)
        lean = (sign * (crw - cr_bg) * halo).sum(axis=0) / np.maximum(halo.sum(axis=0), 1)
        # ... except when the stripe saturates its own channel on a surface of its own colour (a
        # red stripe on orange soil): it can only add the other channels there, which shifts the
        # chroma away from its colour. Then the share of each channel's headroom the stripe used
        # decides (:func:`headroom_lean`): its own channel's share must exceed the other laser's.
        # ... and only where the other laser's stripe can lie (its band, widened by the window);
        # with that band known, a halo there must lean to this laser's colour (_wrong_lean)
        inside = (peak + k >= o_start) & (peak - k < o_start + o_height) | strict
        if other is not None:
            # there, the lean of all the stripe's light (rows above a fifth of the peak,
            # weighted by their light): the halo alone can be a single row of textured ground
            # beside a sharp stripe, and a green stripe blooming white on warm soil passed it
            # as red (random rig 23) while its whole light leaned clearly green
            lit = np.where(sig > 0.2 * top, sig, 0).astype(np.float64)
            dcr = sign * (crw.astype(np.float64) - cr_bg.astype(np.float64))
            lsum = lit.sum(axis=0)
            with np.errstate(invalid="ignore", divide="ignore"):
                in_lean = np.where(lsum > 0, (dcr * lit).sum(axis=0) / lsum, 0.0)
        else:
            in_lean = lean
        wrong = (in_lean <= -_wrong_lean(params, other)) & inside
        if wrong.any():
            hl = headroom_lean(name, planes.rgb(rr[:, wrong], cols[None, wrong]))
            wrong[wrong] = hl < params.min_headroom_lean
        ok &= ~wrong  # only a clear lean to the other colour refuses
        # the method's colour test on the central rows (a white core sits between coloured halo)
        core = slice(k - 3, k + 4)
        rgb = planes.rgb(rr[core], cols[None, :])  # (7, W, 3)
        colour = np.zeros(rgb.shape[:2], bool)
        if method in ("hue", "combined"):
            colour |= _hue_ok(name, rgb, params)
        if method == "combined":
            c, (o1, o2) = _CH[name], _OTHERS[name]
            colour |= ((rgb[..., c] - np.maximum(rgb[..., o1], rgb[..., o2]) >= params.min_tint)
                       & (rgb[..., c] >= params.min_value))
        if method in ("lut", "combined") and lut is not None:
            colour |= lut.mask(name, np.clip(rgb + 0.5, 0, 255).astype(np.uint8), params.lut_margin)
        colour = colour.any(axis=0)
        if params.faint:
            # the light the peak adds is of this laser's colour, against the surface's
            # (faint_light): on a tinted light surface the laser's tint over the other
            # channels can be under min_tint and its saturation under min_sat
            need = ok & ~colour & ~faint
            if need.any():
                colour[need] = faint_light(name, planes, rr[:, need], cols[need],
                                           params.min_peak, params.min_value)
            colour |= ok & faint
        if _bloom_lean(params, other) < np.inf and (ok & ~colour).any():
            # the blooming test (blooming_lean) where the colour tests refuse
            c, (o1, o2) = _CH[name], _OTHERS[name]
            tint0 = ((rgb[..., c] - np.maximum(rgb[..., o1], rgb[..., o2]) >= 0)
                     & (rgb[..., c] >= params.min_value)).any(axis=0)
            sat = (rgb[1:6, :, c] >= BLOOM_LEVEL).any(axis=0)
            win = planes.rgb(rr, cols[None, :]).astype(np.float64)  # (2k+1, W, 3)
            o = _CH["red" if name == "green" else "green"]
            bg = 0.5 * (win[0] + win[-1])
            share = (win[1:-1] - bg) / np.maximum(255.0 - bg, 8.0)
            bloom = (share[..., c] - share[..., o]).sum(axis=0) >= BLOOM_LEAN
            # and the halo leaning to this laser's colour (a white line on yellow soil does not)
            colour |= ~colour & sat & tint0 & bloom & (lean > -_wrong_lean(params, other))
        colour &= ~weak  # a weak peak passes only the white-core rule
        by_colour = colour.copy()
        if _white_lean(params, other) < np.inf and (ok & ~colour & ~inside).any():
            # away from the other laser's band, a core saturated in this laser's channel whose
            # halo does not clearly lean to the other laser's colour (StripeParams.white_core)
            from impress_gui.core.reconstruction.compiled import kernels as compiled

            core5 = rgb[1:6]
            luma = 0.299 * core5[..., 0] + 0.587 * core5[..., 1] + 0.114 * core5[..., 2]
            # on a surface near full scale in this laser's channel, a lower luma
            ends = planes.rgb(rr[[0, 1, -2, -1]], cols[None, :], np.float64)[..., _CH[name]]
            low = np.where(0.25 * ends.sum(axis=0) >= BLOOM_LEVEL - compiled().WHITE_SOIL_DROP,
                           BLOOM_LEVEL - compiled().WHITE_LUMA_DROP, BLOOM_LEVEL)
            sat = ((core5[..., _CH[name]] >= BLOOM_LEVEL).any(axis=0)
                   & (luma >= low).any(axis=0))
            colour |= ~colour & sat & ~inside & (lean > -_white_lean(params, other))
        wl = _white_lean(params, other)
        vouch = vouched & ~colour & ~weak & (lean > -wl) & (wl < np.inf)
        colour |= vouch
        ok &= colour
        if params.subpixel == "window":
            centre = window_refine(rr, sig, top, centre)
        why = np.where(~peakish | (weak & ~ok), 2, np.where(wrong | (~ok & inside), 1, 0))
        # 3: kept by the white-core rule alone (confirmed or dropped by confirmed_by_colour);
        # 4: the same for a weak peak (if dropped, its second candidate is tried)
        kept = np.where(by_colour, 0, np.where(weak, 4, np.where(vouch, 5, 3)))
        return ok, centre, top, np.where(ok, kept, why)

    o_start, o_height = _other_band(other, w)
    ok, centre, top, why = attempt(coarse)
    white = ok & (why >= 3)  # kept by the white-core rule alone
    weak = ok & (why == 4)  # ... from a weak first candidate
    vouched_cols = np.zeros(w, bool)  # kept by the guided pass for their position alone
    why = np.where(searched & ~ok, why, 0)
    retry = params.second_candidate and other is not None
    none = np.iinfo(np.int32).min
    tags = (4095 - np.arange(nr, dtype=np.int32))[:, None]
    k = params.half_window_px

    def ridge_best():
        """Not a peak: a bright surface can outscore the stripe on darker ground; the row
        rising most above the higher of the scores RIDGE_STEP rows off (one side at the band's
        ends), more than k rows from the first candidate, per column (packed as ``packed``)."""
        from impress_gui.core.reconstruction.compiled import kernels

        q = kernels().RIDGE_STEP // 2
        sc = score.astype(np.int32)
        up = np.full_like(sc, -1000)
        dn = np.full_like(sc, -1000)
        up[q:] = sc[:-q]
        dn[:-q] = sc[q:]
        m = np.maximum(up, dn)
        near = np.abs(rows_c[:, None] - coarse[None, :]) > k
        ridge = np.where(near & (sc > -1000) & (m > -1000), (sc - m) * 4096 + tags, none)
        return ridge.max(axis=0)

    if retry and why.any():
        # refused where the other laser's stripe can lie: that stripe, brighter, can hide
        # this laser's in the column; the best candidate of the band away from it (more than
        # 2k rows) is tested the same way
        far = np.abs(rows_c[:, None] - coarse[None, :]) > 2 * k
        best1 = np.where(far & (score > -1000), packed, none).max(axis=0)
        # not a peak: the ridge candidate, its halo required to lean to this laser's colour
        # everywhere
        cand = np.where(why == 1, best1, np.where(why == 2, ridge_best(), none))
        has2 = cand > none
        coarse2 = np.where(has2, r0 + 2 * (4095 - (cand & 4095)), coarse)
        ok2, centre2, top2, why2 = attempt(coarse2, why == 2)
        take = has2 & ok2
        ok, centre, top = ok | take, np.where(take, centre2, centre), np.where(take, top2, top)
        white = np.where(take, why2 >= 3, white)
        # refused again after a refusal in the other laser's band: the second candidate can
        # be a light surface beside that laser's stripe, still in its band (a white block
        # under it: random rig 212); the best candidate of this laser's own rows, outside
        # that band (widened by the half window), is tested the same way
        third = (why == 1) & ~ok
        if third.any():
            rc = rows_c[:, None]
            own = (rc < (o_start - k)[None, :]) | (rc >= (o_start + o_height + k)[None, :])
            best3 = np.where(own & (score > -1000), packed, none).max(axis=0)
            has3 = third & (best3 > none)
            if has3.any():
                coarse3 = np.where(has3, r0 + 2 * (4095 - (best3 & 4095)), coarse)
                ok3, centre3, top3, why3 = attempt(coarse3)
                take = has3 & ok3
                ok = ok | take
                centre, top = np.where(take, centre3, centre), np.where(take, top3, top)
                white = np.where(take, why3 >= 3, white)
    out_rows = np.where(ok, centre, np.nan)
    strength = np.where(ok, top, 0).astype(np.float32)
    if params.guided and other is not None:
        pred = guided_prediction(out_rows)
        b0 = np.asarray(band_start, np.int64)
        coarse3 = np.rint(np.nan_to_num(pred, nan=-1.0)).astype(np.int64)
        want = np.isfinite(pred) & (coarse3 >= b0) & (coarse3 < b0 + band_height)
        if want.any():
            ok3, centre3, top3, why3 = attempt(np.where(want, coarse3, coarse), False, want)
            with np.errstate(invalid="ignore"):
                take = want & ok3 & (np.abs(centre3 - pred) <= _guide()["dev"])
            out_rows = np.where(take, centre3, out_rows)
            strength = np.where(take, top3, strength).astype(np.float32)
            white = np.where(take, why3 >= 3, white)  # vouched (5): confirmed like a white core
            vouched_cols = take & (why3 == 5)
            weak &= ~take
    if white.any():
        drop = white & ~confirmed_by_colour(out_rows, white, vouched_cols)
        out_rows = np.where(drop, np.nan, out_rows)
        strength = np.where(drop, 0, strength).astype(np.float32)
        redo = drop & weak
        if retry and redo.any():
            # a weak peak the chain test dropped gets the second candidate a weak peak got
            # before the white-core rule (a light face clipped white above the stripe)
            cand = np.where(redo, ridge_best(), none)
            has4 = cand > none
            coarse4 = np.where(has4, r0 + 2 * (4095 - (cand & 4095)), coarse)
            ok4, centre4, top4, _ = attempt(coarse4, has4)
            take = has4 & ok4
            out_rows = np.where(take, centre4, out_rows)
            strength = np.where(take, top4, strength).astype(np.float32)
    if params.prefer_own_rows and other is not None and ground is not None:
        # this laser's own rows, searched again where the stripe lies in the other's band
        import dataclasses

        k = int(params.half_window_px)
        o0, oh = other
        if (np.isfinite(out_rows) & (out_rows + k >= o0) & (out_rows - k < o0 + oh)).any():
            alone = dataclasses.replace(params, prefer_own_rows=False)
            found = []
            for start, height, lo, hi in own_regions(band_start, band_height, other, k,
                                                     int(np.max(band_start)) + band_height):
                r = detect_planes_numpy(name, planes, start, height, alone, lut, other)
                found.append((r.rows, r.strength, lo, hi))
            out_rows = np.array(out_rows, np.float64)
            strength = np.array(strength, np.float32)
            prefer_own_rows(out_rows, strength, other, k, found, ground)
    return StripeResult(out_rows, strength)


def confirmed_by_colour(rows: np.ndarray, white: np.ndarray,
                        vouched: np.ndarray | None = None) -> np.ndarray:
    """Per column: whether, on its chain of found columns and within ``kernels.WHITE_HALF``
    columns of it (or within ``kernels.WHITE_HALF_WIDE``), at least ``kernels.WHITE_SHARE`` of
    the found columns were accepted by the colour tests (``~white``). A chain continues
    from one found column to the next when they are at most ``kernels.GUIDE_REACH`` columns
    apart and their rows differ by at most ``kernels.GUIDE_LINK`` per column between them. The
    white-core rule's columns (``StripeParams.white_core``) are kept only where this holds: a
    white line (a highlight, a white edge) has no or few coloured columns on its chain (a
    neutral white line on yellow soil: 4 % of its columns pass the blooming test as green;
    random rig 13's green stripe at 1080p: 40-57 % pass the colour tests). The numpy reference
    of the compiled ``kernels._confirm_white``. ``vouched`` columns (the guided pass's peaks
    kept for their position alone, also ``white``) link chains but count neither as found nor
    as accepted."""
    g = _guide()
    link, reach = g["link"], g["reach"]
    cols = np.flatnonzero(np.isfinite(rows))
    out = np.zeros(len(rows), bool)
    if not len(cols):
        return out
    gap = np.diff(cols)
    cont = (gap <= reach) & (np.abs(np.diff(rows[cols])) <= link * gap)
    chain = np.concatenate([[0], np.cumsum(~cont)])
    from impress_gui.core.reconstruction.compiled import kernels

    share = kernels().WHITE_SHARE
    w = len(rows)
    found = np.isfinite(rows)
    counted = found if vouched is None else found & ~vouched
    pf = np.concatenate([[0], np.cumsum(counted)])
    pc = np.concatenate([[0], np.cumsum(counted & ~white)])
    # each found column's chain runs from its first to its last column
    breaks = np.flatnonzero(~cont)
    first = cols[np.concatenate([[0], breaks + 1])]
    last = cols[np.concatenate([breaks, [len(cols) - 1]])]
    for half in (kernels().WHITE_HALF, kernels().WHITE_HALF_WIDE):  # near, or wide
        lo = np.maximum(first[chain], cols - half)
        hi = np.minimum(last[chain], cols + half) + 1
        hi = np.minimum(hi, w)
        n = pf[hi] - pf[lo]
        out[cols] |= (n > 0) & ((pc[hi] - pc[lo]) >= share * n)
    return out


def _guide() -> dict:
    """The guided pass's constants (they live with the compiled kernels, which numba freezes)."""
    from impress_gui.core.reconstruction.compiled import kernels

    k = kernels()
    return {"link": k.GUIDE_LINK, "reach": k.GUIDE_REACH, "dev": k.GUIDE_DEV,
            "short": k.GUIDE_SHORT,
            "weak": k.WEAK_SHARE, "faint": (k.FAINT_SHARE, k.FAINT_RISE, k.FAINT_TINT, k.FAINT_CLIP,
                                            k.FAINT_DARK_RISE, k.FAINT_DARK_CLEAR,
                                            k.FAINT_DARK_SIDE, k.FAINT_DARK_MIN)}


def faint_light(name: str, planes: Planes, rr: np.ndarray, cols: np.ndarray,
                min_peak: float, min_value: float) -> np.ndarray:
    """Whether each column's window of rows ``rr`` (``(2k+1, N)``) holds light of laser
    ``name``'s colour against the surface it falls on: over the central three rows the
    laser's channel rises on average at least ``kernels.FAINT_RISE * min_peak`` above the
    surface (the mean of the window's two end rows on each side) and reaches ``min_value`` on
    one of them (or rises by ``kernels.FAINT_DARK_RISE`` of the surface's level and
    ``kernels.FAINT_DARK_CLEAR`` x the spread of the window's rows ``kernels.FAINT_DARK_SIDE``
    or more from its centre, one more with 4:2:0 chroma, each central row above them all: a dim
    laser on dark soil), and each other channel rises on average by at most ``kernels.FAINT_TINT`` x
    the laser channel's rise x the surface's ratio of that channel to the laser's (a brighter
    speck of red soil adds light of the soil's own colour); the other laser's channel is not
    clipped (``kernels.FAINT_CLIP``) on more of the window's rows than the laser's own (a
    clipped channel's rise is only a lower bound: the other laser's stripe clipped on a light
    target). A red laser on a light surface
    adds mostly red, which moves the luma by a third of it: a consumer camera's photograph of
    one, pinkish on white, shows 10-20 grey levels of luma where the red channel rises by
    20-40. The numpy reference of the compiled ``kernels._faint``."""
    _, rise, tint, clip, dark, clear, side_rows, dark_min = _guide()["faint"]
    n = rr.shape[0]
    k = n // 2
    c, (o1, o2) = _CH[name], _OTHERS[name]

    def rgb(rows):
        return planes.rgb(rows, cols, np.float64)

    bg = 0.25 * rgb(rr[0]) + 0.25 * rgb(rr[1]) + 0.25 * rgb(rr[n - 2]) + 0.25 * rgb(rr[n - 1])
    mid = rgb(rr[k - 1:k + 2])  # (3, N, 3)
    up = mid[0] / 3.0 + mid[1] / 3.0 + mid[2] / 3.0 - bg
    best = up[:, c]
    bc = np.maximum(bg[:, c], 1.0)
    # the rows FAINT_DARK_SIDE or more from the centre, one more with subsampled chroma
    reach = side_rows + (1 if planes.chroma_step > 1 else 0)
    side = np.stack([rgb(rr[j])[:, c] for j in range(n) if abs(j - k) >= reach])
    lo, hi = side.min(axis=0), side.max(axis=0)
    ok = ((best >= rise * min_peak) & (mid[..., c].max(axis=0) >= min_value)) | (
        (best >= dark_min * min_peak) & (best >= dark * bg[:, c]) & (best >= clear * (hi - lo))
        & (mid[..., c].min(axis=0) > hi))
    for o in (o1, o2):
        ok &= ~(up[:, o] * bc > tint * best * bg[:, o])
    win = rgb(rr)  # (n, N, 3)
    ok &= (win[..., 1 - c] >= clip).sum(axis=0) <= (win[..., c] >= clip).sum(axis=0)
    return ok


def guided_prediction(rows: np.ndarray) -> np.ndarray:
    """The rows the guided pass tests (NaN: none): for each column whose row does not continue
    into a neighbour's within ``kernels.GUIDE_LINK``, the row interpolated between the nearest
    columns that do, within ``kernels.GUIDE_REACH`` on either side, when their rows are
    continuous across it (at most ``GUIDE_LINK`` per column); and for each column of a short
    piece of continuing columns (at most ``kernels.GUIDE_SHORT``) the row interpolated
    between the nearest columns of longer pieces within ``GUIDE_REACH`` of its ends, when
    their rows are continuous across it and that row lies more than ``GUIDE_LINK`` from the
    column's. The numpy reference of the compiled ``kernels._guided``."""
    g = _guide()
    link, reach, short = g["link"], g["reach"], g["short"]
    w = len(rows)
    with np.errstate(invalid="ignore"):
        near = np.abs(np.diff(rows)) <= link
    linked = np.zeros(w, bool)
    linked[:-1] |= near
    linked[1:] |= near
    idx = np.arange(w)
    # the nearest linked column at or before / at or after each column
    left = np.maximum.accumulate(np.where(linked, idx, -1))
    right = np.minimum.accumulate(np.where(linked, idx, w)[::-1])[::-1]
    lft = np.concatenate([[-1], left[:-1]])  # strictly before
    rgt = np.concatenate([right[1:], [w]])  # strictly after
    ok = ~linked & (lft >= 0) & (idx - lft <= reach) & (rgt < w) & (rgt - idx <= reach)
    li, ri = np.where(ok, lft, 0), np.where(ok, rgt, 0)
    rl, rr = rows[li], rows[ri]
    with np.errstate(invalid="ignore", divide="ignore"):
        ok &= np.abs(rr - rl) <= link * (ri - li)
        pred = np.where(ok, rl + (rr - rl) * (idx - li) / np.where(ok, ri - li, 1), np.nan)
    # pieces of continuing columns: each column's piece, its first and last column and length
    start = np.ones(w, bool)
    start[1:] = ~near
    piece = np.cumsum(start) - 1
    first = np.flatnonzero(start)
    last = np.concatenate([first[1:] - 1, [w - 1]])
    length = (last - first + 1)[piece]
    anchor = linked & (length > short)
    sp = linked & (length <= short)
    la = np.maximum.accumulate(np.where(anchor, idx, -1))  # at or before (a short one is not)
    ra = np.minimum.accumulate(np.where(anchor, idx, w)[::-1])[::-1]
    c0, d0 = first[piece], last[piece]
    ok2 = sp & (la >= 0) & (la >= c0 - reach) & (ra < w) & (ra <= d0 + reach)
    li, ri = np.where(ok2, la, 0), np.where(ok2, ra, 0)
    rl, rr = rows[li], rows[ri]
    with np.errstate(invalid="ignore", divide="ignore"):
        ok2 &= np.abs(rr - rl) <= link * (ri - li)
        p2 = rl + (rr - rl) * (idx - li) / np.where(ok2, ri - li, 1)
        ok2 &= np.abs(rows - p2) > link
    return np.where(ok2, p2, pred)


def run_through(over: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Per column of ``over`` (``(rows, W)`` booleans): the run of True rows through row
    ``at`` (per column; a column whose ``at`` lies outside the rows has none), as a mask."""
    n = over.shape[0]
    at = np.asarray(at)
    inside = (at >= 0) & (at <= n - 1)
    rows = np.arange(n)[:, None]
    run = np.zeros_like(over)
    run[np.clip(at, 0, n - 1), np.arange(over.shape[1])] = inside
    run &= over
    for q in range(1, n):  # down from the row, then up to it
        run[q] |= run[q - 1] & over[q] & (rows[q] > at)
    for q in range(n - 2, -1, -1):
        run[q] |= run[q + 1] & over[q] & (rows[q] < at)
    return run


def _core_run(sig: np.ndarray, rr: np.ndarray, top: np.ndarray, centre: np.ndarray,
              share: float) -> np.ndarray:
    """Per column of ``sig`` (``(2k+1, W)``, rows ``rr``): the length of the run of rows at or
    above ``share`` of ``top`` through the row nearest ``centre`` (0 where that row is below
    it or the centre is NaN)."""
    with np.errstate(invalid="ignore"):
        pos = np.floor(np.where(np.isfinite(centre), centre - rr[0] + 0.5, -1.0))
    return run_through(sig >= share * top, pos.astype(int)).sum(axis=0).astype(np.float64)


def window_refine(rr: np.ndarray, sig: np.ndarray, top: np.ndarray,
                  centre: np.ndarray) -> np.ndarray:
    """The stripe's centre refined per column (``rr``, ``sig``: ``(2k+1, W)`` rows and luma
    above the window's minimum; ``top`` its maximum; ``centre`` the centre of mass above half
    maximum): the centre of mass of the luma above a floor, weighted by a window of fixed half
    width (0.9 x the rows above half maximum, at least 1.5, at most 3.5, or 3 where the profile
    is clipped: three rows within 4 % of its maximum; never narrower than half the run of
    rows at or above 0.85 of the maximum through the estimate plus half a row, a wide
    saturated core) centred on the estimate, with
    fractional weights at its ends, iterated 4 times. The floor is a tenth of the maximum, or
    the row just outside that window on either side where it is brighter (a brighter surface
    beside the stripe would otherwise pull the centre towards it). Measured against the
    renderer's exact centres on six random rigs at 1080p (video decoded): the error's
    dependence on the centre's sub-pixel position falls from 0.03-0.33 px (peak to peak,
    median 0.1) to 0.01-0.09 px (median 0.04); that position is the same along a stripe that
    runs along the rows, so the locking was a height bias on flat ground. A column whose window
    would reach past the samples (a stripe wider than about 6 rows) keeps its first centre."""
    from impress_gui.core.reconstruction.compiled import kernels

    kn = kernels()
    sig = sig.astype(np.float64)
    rr = rr.astype(np.float64)
    wc = (sig > 0.5 * top).sum(axis=0)
    clipped = (sig >= kn.REFINE_PLATEAU * top).sum(axis=0) >= kn.REFINE_PLATEAU_ROWS
    cap = np.where(clipped, kn.REFINE_MAX_HALF_CLIPPED, kn.REFINE_MAX_HALF)
    # never narrower than the profile's own core (the run of rows >= REFINE_CORE of its
    # maximum through the estimate's row): half its length plus REFINE_CORE_MARGIN
    cap = np.maximum(cap, 0.5 * _core_run(sig, rr, top, centre, kn.REFINE_CORE)
                     + kn.REFINE_CORE_MARGIN)
    hw = np.minimum(cap, np.maximum(kn.REFINE_MIN_HALF, kn.REFINE_WIDTH * wc))
    c = centre.astype(np.float64)
    keep = ~np.isfinite(c)
    n = sig.shape[0]
    cols = np.arange(sig.shape[1])
    for _ in range(kn.REFINE_ITERATIONS):
        keep |= (c - hw < rr[0]) | (c + hw > rr[-1])
        dist = np.abs(rr - c)
        # the rows just outside the window on each side (the first with no weight)
        below = rr < c - hw - 0.5
        after = rr > c + hw + 0.5
        j_lo = np.where(below.any(axis=0), n - 1 - below[::-1].argmax(axis=0), -1)
        j_hi = np.where(after.any(axis=0), after.argmax(axis=0), -1)
        outer = np.maximum(np.where(j_lo >= 0, sig[np.maximum(j_lo, 0), cols], -np.inf),
                           np.where(j_hi >= 0, sig[np.maximum(j_hi, 0), cols], -np.inf))
        above = sig - np.maximum(kn.REFINE_FLOOR * top, outer)
        wt = np.clip(hw + 0.5 - dist, 0.0, 1.0)
        a = np.where((above > 0) & (wt > 0), above * wt, 0.0)
        ws = a.sum(axis=0)
        keep |= ~(ws > 0)
        with np.errstate(invalid="ignore", divide="ignore"):
            c = np.where(keep, c, (a * rr).sum(axis=0) / ws)
    return np.where(keep, centre, c)


def gauss_refine(rr: np.ndarray, sig: np.ndarray, centre: np.ndarray,
                 clipped: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The stripe's centre per column from a Gaussian on a constant floor fitted to its
    profile (``rr``, ``sig``: ``(2k+1, W)`` rows and luma above the window's minimum;
    ``clipped``: rows at the clipping level, left out - a saturated core says nothing of where
    the profile peaks, its flanks do), over the rows within ``kernels.GAUSS_HALF`` widths of
    ``centre`` (the width first taken from the rows above half maximum; 2.5-8 rows);
    Levenberg-Marquardt from ``centre``, a step taken only where it lowers the squared
    residuals, until a step of nearly Gauss-Newton's own size (damping at most 1e-3) moves
    the centre less than ``kernels.GAUSS_TOL`` rows or after
    ``kernels.GAUSS_ITERATIONS`` steps. Returns (centre, width); ``centre`` and a width of 0
    where fewer than five rows are left, the fit fails or moves the centre more than a row.
    The numpy reference of ``kernels._gauss_refine``."""
    from impress_gui.core.reconstruction import kernels as kn

    sig = np.asarray(sig, np.float64)
    rr = np.asarray(rr, np.float64)
    c0 = np.asarray(centre, np.float64)
    w = sig.shape[1]
    top = sig.max(axis=0)
    lo = sig.min(axis=0)
    wc = (sig - lo > 0.5 * (top - lo)).sum(axis=0)
    s = np.clip(wc / 2.355, 0.5, 4.0)
    hw = np.clip(kn.GAUSS_HALF * s, 2.5, 8.0)
    with np.errstate(invalid="ignore"):
        use = (np.abs(rr - c0) <= hw) & ~clipped
    amp = np.where(use, sig, -np.inf).max(axis=0)
    b = np.where(use, sig, np.inf).min(axis=0)
    a = amp - b
    c = c0.copy()
    ok = np.isfinite(c0) & (use.sum(axis=0) >= 5)
    live = ok.copy()

    def cost(a, c, s, b):
        e = np.exp(-0.5 * (rr - c) ** 2 / (s * s))
        return (np.where(use, sig - (a * e + b), 0.0) ** 2).sum(axis=0)

    with np.errstate(invalid="ignore", over="ignore"):
        now = cost(a, c, s, b)
    lam = np.full(w, 1e-3)
    for _ in range(kn.GAUSS_ITERATIONS):
        if not live.any():
            break
        d = rr - c
        e = np.exp(-0.5 * d * d / (s * s))
        g = np.stack([e, a * e * d / (s * s), a * e * d * d / (s * s * s), np.ones_like(e)])
        g = np.where(use & live, g, 0.0)  # (4, n, W)
        res = np.where(use & live, sig - (a * e + b), 0.0)
        jt = np.einsum("pnw,qnw->wpq", g, g)
        rhs = np.einsum("pnw,nw->wp", g, res)
        m = jt + lam[:, None, None] * jt * np.eye(4)[None]
        solvable = live & (np.abs(np.linalg.det(m)) > 0)
        step = np.zeros((w, 4))
        if solvable.any():
            step[solvable] = np.linalg.solve(m[solvable], rhs[solvable][..., None])[..., 0]
        ok &= solvable | ~live
        live &= solvable
        a1 = a + step[:, 0]
        c1 = c + np.clip(step[:, 1], -0.5, 0.5)
        s1 = np.clip(s + np.clip(step[:, 2], -0.3, 0.3), 0.3, 6.0)
        b1 = b + step[:, 3]
        with np.errstate(invalid="ignore", over="ignore"):
            trial = cost(a1, c1, s1, b1)
        better = live & (trial < now)
        done = better & (np.abs(c1 - c) < kn.GAUSS_TOL) & (lam <= 1e-3)
        a, c, s, b = (np.where(better, x1, x) for x1, x in ((a1, a), (c1, c), (s1, s), (b1, b)))
        now = np.where(better, trial, now)
        lam = np.where(better, np.maximum(lam * 0.1, 1e-7), np.where(live, lam * 10.0, lam))
        live &= ~done
    with np.errstate(invalid="ignore"):
        ok &= (a > 0) & (np.abs(c - c0) <= 1.0) & np.isfinite(c)
    return np.where(ok, c, c0), np.where(ok, s, 0.0)


def headroom_lean(name: str, win_rgb: np.ndarray) -> np.ndarray:
    """How far the light in windows of rows leans to laser ``name``'s colour, whatever the
    surface's own colour: ``win_rgb`` is ``(2k+1, N, 3)`` (rows of each column's window); the
    background is the mean of the two end rows; over the inner rows, the share of each
    channel's headroom above the background (255 - background, at least 8) that the light
    used, this laser's channel minus the other laser's, summed; -inf where the other laser's
    channel is saturated (>= 250) in any row: light that saturates both channels cannot be
    told apart (a green laser with red crosstalk saturates red on orange soil too)."""
    c, o = _CH[name], _CH["red" if name == "green" else "green"]
    win = np.asarray(win_rgb, np.float64)
    bg = 0.5 * (win[0] + win[-1])
    share = (win[1:-1] - bg) / np.maximum(255.0 - bg, 8.0)
    lean = (share[..., c] - share[..., o]).sum(axis=0)
    return np.where((win[..., o] >= 250.0).any(axis=0), -np.inf, lean)


def detect_band(name: str, rgb_band: np.ndarray, row0: int, params: StripeParams,
                lut: BackgroundLUT | None) -> StripeResult:
    """Detect one laser's stripe in an RGB band of rows starting at image row ``row0``."""
    planes = Planes.from_rgb(rgb_band)
    h, w = rgb_band.shape[:2]
    res = detect_planes(name, planes, np.zeros(w, np.int64), h, params, lut)
    return StripeResult(res.rows + row0, res.strength)


def prune_weak_runs_numpy(rows: np.ndarray, strength: np.ndarray, tol_px: float,
                         long_cols: int, ratio: float) -> int:
    """The readable numpy reference of the compiled
    :func:`~impress_gui.core.reconstruction.kernels.prune_weak_runs` (the tests check they
    agree): short stripe pieces much weaker than the frame's long pieces are dropped in place,
    unless they lie on a chain of found columns at least ``long_cols`` long (joined across gaps
    of at most ``kernels.WEAK_CHAIN_GAP`` columns, rows within ``tol_px``: a faint stripe found
    in pieces).

    Why: where a laser's stripe is faint or broken, the strongest laser-coloured pixel of a
    column can be a patch of soil of the laser's hue, a few columns wide and hundreds of rows
    away from the stripe; its heights float far above the surface (wild points). The stripe
    itself is a long curve and clearly stronger."""
    n = len(rows)
    if n == 0 or ratio <= 0:
        return 0
    link = np.abs(np.diff(rows)) <= tol_px  # NaN never links
    run_id = np.concatenate([[0], np.cumsum(~link)])
    finite = np.isfinite(rows)
    length = np.bincount(run_id)
    count = np.bincount(run_id, weights=finite)
    total = np.bincount(run_id, weights=np.where(finite, strength, 0.0))
    long_run = (length >= long_cols)[run_id] & finite
    if not long_run.any() or len(length) == 1:
        return 0
    ref = np.median(strength[long_run].astype(np.float64))
    # chains: found columns joined across gaps of at most WEAK_CHAIN_GAP missing columns, their
    # rows within tol_px - the stripe broken where it is faint; a run on a long chain is kept
    from impress_gui.core.reconstruction.compiled import kernels

    cols = np.flatnonzero(finite)
    joined = (np.diff(cols) <= kernels().WEAK_CHAIN_GAP + 1) & (
        np.abs(np.diff(rows[cols])) <= tol_px)
    chain = np.concatenate([[0], np.cumsum(~joined)]) if cols.size else np.zeros(0, np.int64)
    on_long = np.zeros(n, bool)
    on_long[cols] = (np.bincount(chain) >= long_cols)[chain]
    run_on_long = np.bincount(run_id, weights=on_long) > 0
    weak = (length < long_cols) & (count > 0) & (total < ratio * ref * count) & ~run_on_long
    drop = weak[run_id] & finite
    rows[drop] = np.nan
    strength[drop] = 0.0
    return int(drop.sum())


def drop_short_runs_numpy(rows: np.ndarray, strength: np.ndarray, tol_px: float,
                          min_run: int) -> int:
    """The readable numpy reference of the compiled
    :func:`~impress_gui.core.reconstruction.kernels.drop_short_runs` (the tests check they
    agree): stripe pieces of two to ``min_run - 1`` columns are dropped in place.

    Why: in a laser's shadow (past a wall, where its light lands out of the camera's view)
    the detector still reports each column's best candidate; most are scattered, but an edge
    of the scene - a block's top edge in the picture, moving with the carriage - gives two
    neighbouring columns that agree. Next to the stripe's last true row such a pair joins the
    chain on the block's top and draws the top past its wall (random rig 13 at 1080p: a pair
    2.4 px from the stripe's row in the frame after the stripe left the top, read 0.8 mm
    above it and 0.5 mm past the wall). A stripe is a curve: at 1080p a true piece that short
    is rare, and its cells are filled from the neighbouring frames."""
    n = len(rows)
    if n == 0 or min_run <= 2:
        return 0
    link = np.abs(np.diff(rows)) <= tol_px  # NaN never links
    run_id = np.concatenate([[0], np.cumsum(~link)])
    length = np.bincount(run_id)[run_id]
    drop = (length >= 2) & (length < min_run)
    rows[drop] = np.nan
    strength[drop] = 0.0
    return int(drop.sum())


def shared_light(rows_a: np.ndarray, rows_b: np.ndarray, conflict: np.ndarray,
                 tol_px: float) -> tuple[np.ndarray, np.ndarray]:
    """Where the two lasers' detectors took the same light, which of them took the other's:
    the columns to drop from each laser's rows (boolean masks).

    ``conflict`` marks the columns where both found a stripe at (nearly) the same row but
    the two points it gives through the two lasers' planes lie apart (only on the line where
    the planes meet do both lasers light the same pixel). There one laser's detector took the
    other's stripe (in rig 205 of the random rigs the red detector took the green stripe on
    the ground, 350 rows from red's own, in runs of 4-8 columns, frame after frame: pieces of
    the red map 60 mm up). Each laser's stripe falls into *runs*: columns whose rows continue
    into each other within ``tol_px`` (as :func:`prune_weak_runs_numpy` has them). A laser
    whose run lies on the other's light over a larger share of its columns than the other's
    run does loses the column (the impostor's run is a short piece of the other's stripe; the
    real stripe runs on beyond it); where the shares are equal both lose it. A run that loses
    a column and lies on the other's light over at least half of its columns is dropped
    whole."""
    n = len(rows_a)
    drops = []
    shares = []
    ids = []
    for rows in (rows_a, rows_b):
        link = np.abs(np.diff(rows)) <= tol_px  # NaN never links
        run_id = np.concatenate([[0], np.cumsum(~link)]) if n else np.zeros(0, np.int64)
        finite = np.isfinite(rows)
        count = np.bincount(run_id, weights=finite)
        on_other = np.bincount(run_id, weights=conflict & finite)
        share = np.divide(on_other, count, out=np.zeros_like(count), where=count > 0)
        ids.append(run_id)
        shares.append(share)
    sa, sb = shares[0][ids[0]], shares[1][ids[1]]
    for k, (lose, rows) in enumerate(((conflict & (sa >= sb), rows_a),
                                      (conflict & (sb >= sa), rows_b))):
        run_id, share = ids[k], shares[k]
        whole = np.zeros(len(share), bool)
        whole[run_id[lose]] = True
        whole &= share >= 0.5
        drops.append((lose | whole[run_id]) & np.isfinite(rows))
    return drops[0], drops[1]


def half_max_midpoints(luma: np.ndarray, rows: np.ndarray, half_window: int) -> np.ndarray:
    """Each found column's stripe row re-estimated as the midpoint of the two half-maximum
    crossings of the luma profile (linearly interpolated), in a window of ``2 * half_window
    + 1`` rows around the row found (``rows``: sub-pixel, NaN = none; band-relative).

    The centre of mass above half maximum is pulled towards whole pixels by up to 0.1-0.2 px
    as the stripe's phase within the pixel changes (pixel locking); the crossings' midpoint
    moves 2-5 times less (0.01-0.05 px on Gaussian stripes of sigma 0.7-2.4 px, dim or
    saturated). Columns whose profile does not fall below half maximum on both sides inside
    the window keep their row."""
    out = np.array(rows, np.float64)
    cols = np.flatnonzero(np.isfinite(out))
    if not len(cols):
        return out
    h = luma.shape[0]
    k = int(half_window)
    centre = np.clip(np.rint(out[cols]).astype(np.int64), 0, h - 1)
    rr = centre[None, :] + np.arange(-k, k + 1)[:, None]
    inside = (rr[0] >= 0) & (rr[-1] < h)
    win = luma[np.clip(rr, 0, h - 1), cols[None, :]].astype(np.float64)  # (2k+1, n)
    win -= win.min(axis=0)
    half = 0.5 * win.max(axis=0)
    above = win > half
    peak = np.argmax(win, axis=0)
    idx = np.arange(2 * k + 1)[:, None]
    # the run of rows above half maximum that holds the peak
    below_up = ~above & (idx < peak)
    below_dn = ~above & (idx > peak)
    lo = np.where(below_up.any(axis=0), 2 * k - np.argmax(below_up[::-1], axis=0), -1)
    hi = np.where(below_dn.any(axis=0), np.argmax(below_dn, axis=0), -1)
    ok = inside & (lo >= 0) & (hi >= 0)
    n = np.arange(len(cols))
    lo_c, hi_c = np.clip(lo, 0, 2 * k), np.clip(hi, 0, 2 * k)
    a0, a1 = win[lo_c, n], win[np.clip(lo_c + 1, 0, 2 * k), n]
    b0, b1 = win[np.clip(hi_c - 1, 0, 2 * k), n], win[hi_c, n]
    with np.errstate(divide="ignore", invalid="ignore"):
        x_up = lo_c + (half - a0) / (a1 - a0)
        x_dn = hi_c - 1 + (b0 - half) / (b0 - b1)
    mid = 0.5 * (x_up + x_dn) + centre - k
    ok &= np.isfinite(mid) & (np.abs(mid - out[cols]) < 1.0)
    out[cols[ok]] = mid[ok]
    return out


def gauss_rows(luma: np.ndarray, rows: np.ndarray, half_window: int,
               clip_level: float | None = None) -> np.ndarray:
    """Each found column's stripe row re-estimated by a Gaussian on a constant floor fitted to
    the luma profile (:func:`gauss_refine`) in a window of ``2 * half_window + 1`` rows around
    the row found (``rows``: sub-pixel, NaN = none; band-relative); rows at ``clip_level``
    (default :data:`BLOOM_LEVEL`) or above are left out of the fit (a clipped core says nothing
    of where the profile peaks).

    A stripe's profile is nearly Gaussian: the fit follows its phase within the pixel where
    the centre of mass and the half-maximum crossings lock to whole pixels (on a narrow stripe
    - the 960x540 sample case - by 0.1-0.2 px). Noise, speckle and compression move it more
    per column than the others, so the calibration takes it only where its points lie better
    on one plane. Columns where the fit fails keep their row."""
    out = np.array(rows, np.float64)
    cols = np.flatnonzero(np.isfinite(out))
    h = luma.shape[0]
    k = int(half_window)
    if not len(cols) or h < 2 * k + 1:
        return out
    centre = np.clip(np.rint(out[cols]).astype(np.int64), k, h - 1 - k)
    rr = centre[None, :] + np.arange(-k, k + 1)[:, None]
    win = luma[rr, cols[None, :]].astype(np.float64)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        clipped = win >= (BLOOM_LEVEL if clip_level is None else clip_level)
        fit, width = gauss_refine(rr.astype(np.float64), win, out[cols], clipped)
    ok = (width > 0) & np.isfinite(fit)
    out[cols[ok]] = fit[ok]
    return out


BLOOM_LEVEL = 250  # a laser channel at least this high in the stripe's core is at full scale
BLOOM_LEAN = 0.1  # headroom shares, summed over the window's rows (see blooming_lean)


def blooming_lean(name: str, rgb_band: np.ndarray, rows: np.ndarray, half_window: int):
    """For a stripe found at (band-relative, sub-pixel) ``rows`` in every column of an RGB band:
    whether its core is saturated in this laser's channel, and how far its light leans to this
    laser's colour rather than the other laser's.

    A blooming stripe saturates every channel in its core (a green laser with a red crosstalk
    of a third, five times full scale, is (255, 255, 230) on a light target), so the core's
    colour says little, and 4:2:0 chroma smears the flanks' colour over it. What survives is
    the colour the stripe adds to the surface, summed over its rows: the lean is the sum, over
    the window's inner rows, of the share of each channel's headroom above the background
    (the window's two end rows) that the stripe used, this laser's channel minus the other
    laser's. Measured against the headroom, a saturated core counts the same in both channels
    whatever the surface's own tint; the flanks, where one channel saturates before the
    other, decide. Returns ``(saturated (W,) bool, lean (W,) float)``; NaN rows give False/NaN.
    """
    h, w = rgb_band.shape[:2]
    found = np.isfinite(rows)
    sat = np.zeros(w, bool)
    lean = np.full(w, np.nan)
    cols = np.flatnonzero(found)
    if not len(cols):
        return sat, lean
    c, o = _CH[name], _CH["red" if name == "green" else "green"]
    k = int(half_window)
    rr = np.clip(np.rint(rows[cols]).astype(np.int64)[None, :] + np.arange(-k, k + 1)[:, None],
                 0, h - 1)
    win = rgb_band[rr, cols[None, :]].astype(np.float64)  # (2k+1, n, 3)
    bg = 0.5 * (win[0] + win[-1])
    share = (win[1:-1] - bg) / np.maximum(255.0 - bg, 8.0)
    lean[cols] = (share[..., c] - share[..., o]).sum(axis=0)
    sat[cols] = win[k - 2 : k + 3, :, c].max(axis=0) >= BLOOM_LEVEL
    return sat, lean


def detect_band_blooming(name: str, rgb_band: np.ndarray, row0: int,
                         params: StripeParams) -> StripeResult:
    """:func:`detect_band` (no background table) for a blooming stripe, the calibration's
    fallback when the colour tests miss most of a stripe on its light target: every column the
    strict tests accept, and the columns where the stripe passes the same peak tests with the
    tint threshold at 0 (the laser's channel the largest) whose core is saturated in the laser's
    channel and whose light leans to this laser's colour by at least ``BLOOM_LEAN``
    (:func:`blooming_lean`): a saturated neutral highlight does not lean, the other laser's
    blooming stripe leans the other way, and an edge is not a peak. The rows are the strict
    detector's (the colour tests only accept or refuse a column)."""
    from dataclasses import replace

    strict = detect_band(name, rgb_band, row0, params, None)
    relaxed = detect_band(name, rgb_band, row0, replace(params, min_tint=0), None)
    extra = relaxed.found & ~strict.found
    sat, lean = blooming_lean(name, rgb_band, np.where(extra, relaxed.rows - row0, np.nan),
                              params.half_window_px)
    take = extra & sat & (np.nan_to_num(lean, nan=-np.inf) >= BLOOM_LEAN)
    rows = np.where(strict.found, strict.rows, np.where(take, relaxed.rows, np.nan))
    strength = np.where(strict.found, strict.strength, np.where(take, relaxed.strength, 0))
    return StripeResult(rows, strength.astype(np.float32))


def detect(rgb: np.ndarray, params: StripeParams, lut: BackgroundLUT | None = None,
           lasers=LASERS) -> dict[str, StripeResult]:
    """Detect every laser's stripe in a full RGB frame inside its region of interest."""
    out = {}
    for name in lasers:
        a, b = params.rois.get(name, (0, rgb.shape[0]))
        out[name] = detect_band(name, rgb[a:b], a, params, lut)
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
                             code=codes.E_NO_STRIPE)
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
