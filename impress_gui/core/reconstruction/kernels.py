"""Compiled per-frame kernels of the reconstruction (numba).

The frame loop must cost little beside decoding (issue 4: processing time <= 1.3 x decode-only
time). What numpy does as dozens of whole-array passes per frame, these kernels do in one pass
over the image columns. Each one states the numpy expression it replaces in its docstring; the
readable numpy reference of the stripe detector stays in :mod:`impress_gui.core.reconstruction.stripes` and the
tests check the two agree on simulated frames.

All kernels release the GIL (the decoder thread keeps running) and are deterministic: no
fast-math, no parallel reductions, a fixed order of accumulation.
"""

from __future__ import annotations

import math

import numpy as np

from impress_gui.core.reconstruction.jit import helper as _jit
from impress_gui.core.reconstruction.jit import kernel as _kernel

# a second candidate's score is compared with the scores this many rows off (even: the first
# pass reads every second row); ``stripes`` reads it from here
RIDGE_STEP = 6
# the sub-pixel refinement of the stripe's centre (``_window_refine``; numba freezes these at
# compile time, and its cache is keyed on this file: they live here, the numpy reference in
# ``stripes`` reads them from this module)
REFINE_FLOOR = 0.1  # luma above this share of the peak counts
REFINE_WIDTH = 0.9  # the window's half width: this many times the rows above half maximum
REFINE_MIN_HALF = 1.5  # rows: the narrowest half width
REFINE_MAX_HALF = 3.5  # rows: the widest (a broad profile's skirts, light beside the stripe,
# would otherwise pull the centre; measured against the renderer's exact centres) ...
REFINE_MAX_HALF_CLIPPED = 3.0  # ... and where the profile is clipped: at least
REFINE_PLATEAU_ROWS = 3  # rows within REFINE_PLATEAU of its maximum (a saturated core)
REFINE_PLATEAU = 0.96
# ... but never narrower than the profile's own core: the run of rows at or above REFINE_CORE
# of its maximum through the estimate, half its length plus REFINE_CORE_MARGIN rows (a wide,
# speckled blooming stripe whose top is wider than the cap: the window saw the top's speckle
# and not the flanks that carry the position; random rig 14's green at 1080p, 0.300 -> 0.200
# px RMS; light beside the stripe lies below that share and does not widen it)
REFINE_CORE = 0.85
REFINE_CORE_MARGIN = 0.5
REFINE_ITERATIONS = 4

# with the other laser's band known (the reconstruction), a column whose stripe row does not
# continue into a neighbour's (missed, or a piece of soil picked instead: issue 18, random rig
# 13, 8 % of the red stripe's columns on bright speckled soil) is searched again at the row its
# neighbours predict (``_guided``); ``stripes`` reads these from here
GUIDE_LINK = 2.0  # px: rows of neighbouring columns continuing into each other
GUIDE_REACH = 6  # columns searched either side for a continuing neighbour
GUIDE_DEV = 1.0  # px: the peak found there must lie this close to the row predicted
# ... and a short piece of continuing columns (at most GUIDE_SHORT) whose row the longer
# pieces on both sides (more than GUIDE_SHORT columns, within GUIDE_REACH) continue across
# but not into it is searched again the same way at their row (random rig 254 at 1080p: the
# red detector took 2-4 column pieces of reddish soil 10-370 px off the stripe, 7,300 of them
# over the scan, flanked by the stripe on both sides; they were dropped later as islands and
# left holes); the piece keeps its rows where no peak is found there
GUIDE_SHORT = 4
# the white-core rule's columns (stripes.StripeParams.white_core) stay only on a chain of
# found columns at least this share of which the colour tests accepted
WHITE_SHARE = 0.2
WHITE_HALF = 48  # columns either side (on the chain) over which that share is counted
# ... or over this many: a patch of bright soil where the stripe clips white can be 100-300
# columns wide (random rig 224 at 1080p, mottled soil of luma 225-235: 48 columns left the
# green stripe's middle out in every such patch); the near count alone keeps its columns
# where a long chain has colour only here and there (random rig 13's speckled red stripe)
WHITE_HALF_WIDE = 160
# a white core: this laser's channel and the luma at full scale (stripes.BLOOM_LEVEL); on a
# surface whose own channel is within WHITE_SOIL_DROP of full scale, the luma at most
# WHITE_LUMA_DROP under it: there the laser cannot lift its own channel, and a green laser
# clipped in green lifts red and blue to 235-254 only, luma 249 (random rig 224: (197, 246,
# 209) -> (235, 255, 254); with the luma at 250 the stripe was lost there, fill 98.25 %).
# Elsewhere the lower luma took white speckle for cores (random rig 13's red stripe).
WHITE_SOIL_DROP = 20.0
WHITE_LUMA_DROP = 10.0
# ... and may be weaker than min_peak, down to this share of it (a stripe clipped white on the
# brightest soil: 10-25 grey levels above it; random rig 13 at 1080p)
WEAK_SHARE = 0.4
# a faint stripe: a red laser on a light surface adds mostly red, which moves the luma by a
# third of it (a consumer camera's photograph: pinkish on white, 10-20 grey levels of luma
# where the red channel rises 20-40); a peak weaker than min_peak, down to FAINT_SHARE of it,
# is a peak when the laser's channel rises on average by at least FAINT_RISE x min_peak over
# the central three rows above the window's ends and the light added is of the laser's colour
# more than the surface is: each other channel's rise over the laser channel's at most
# FAINT_TINT x the surface's own ratio of those channels (a brighter speck of red soil adds
# light of the soil's colour)
# (``_faint``; ``stripes`` reads these from here)
# (FAINT_SHARE was 0.3: a red stripe on green soil moves the luma by 4-5 grey levels where its
# red rises by 11-16, random rig 214 at 1080p; the colour and clear-of-the-surface tests below
# are what refuse the soil's own variation)
FAINT_SHARE = 0.2
FAINT_RISE = 0.6
FAINT_TINT = 0.8
# ... and not where the other laser's channel is clipped (reaches FAINT_CLIP) on more of the
# window's rows than the laser's own: a clipped channel's rise is only a lower bound, and the
# core of the other laser's stripe, clipped on a light target, rises less in its own channel
# than in the one tested (random rig 22 at 1080p: the red stripe's core, (255, 250, 205) on a
# surface of (180, 158, 140), red clipped on 6 rows and green on 4, passed the green test). A
# stripe of this laser that clips everything on a light object clips its own channel at least
# as widely.
FAINT_CLIP = 250.0
# ... and reaches min_value, unless it rises by FAINT_DARK_RISE of the surface's own level or
# more: on dark soil a dim laser's channel never reaches min_value (random rig 214 at 1080p,
# soil of luma 30-60: the red stripe's red 45 -> 95, found in 53 % of the columns of a frame,
# the map's fill 82.8 %), while pixel noise of a dark picture rises far less over its level
FAINT_DARK_RISE = 0.5
# ... and by FAINT_DARK_CLEAR x the spread of that channel over the window's rows 3 or more
# from its centre, each of the three central rows above all of them: a stripe stands clear of
# the surface's own variation, pixel noise does not (independent noise of 40-90 grey levels in
# every pixel and channel: 10-17 columns of 960 pass with the first two limits alone, none
# with this one)
FAINT_DARK_CLEAR = 2.0
# ... "the window's rows FAINT_DARK_SIDE or more from its centre" with chroma at full
# resolution; with 4:2:0 chroma one row more: the laser's channel carries the chroma's rows,
# two image rows each and smeared once more by the encoder, so a stripe 1-2 px wide lifts it
# three rows from its centre (random rig 212: a red stripe over green soil, its red 14 -> 52,
# still 29 three rows off, refused by its own skirt)
FAINT_DARK_SIDE = 3
# ... and on that dark path the laser's channel need rise on average by only FAINT_DARK_MIN x
# min_peak (not FAINT_RISE x): the clear-of-the-surface test above is what tells a stripe from
# the surface's own variation there (random rig 214 at 1080p: a red stripe on green soil, red
# 17 -> 33, luma 4-5 grey levels: the red rise of the columns the detector lost there 11-15)
FAINT_DARK_MIN = 0.4

HSV_SHIFT = 12


def hsv_tables() -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's fixed-point division tables of its 8-bit RGB->HSV conversion (hue range 180)."""
    i = np.arange(256, dtype=np.float64)
    with np.errstate(divide="ignore"):
        sdiv = np.where(i > 0, np.rint((255 << HSV_SHIFT) / i), 0).astype(np.int64)
        hdiv = np.where(i > 0, np.rint((180 << HSV_SHIFT) / (6.0 * i)), 0).astype(np.int64)
    return sdiv, hdiv


@_jit
def _rgb(yv, cbv, crv):
    """BT.601 limited-range YCbCr -> RGB, clipped to 0..255 (as ``video.Planes.rgb``)."""
    yy = (yv - 16.0) * 1.164
    cbf = cbv - 128.0
    crf = crv - 128.0
    r = min(max(yy + 1.596 * crf, 0.0), 255.0)
    g = min(max(yy - 0.392 * cbf - 0.813 * crf, 0.0), 255.0)
    b = min(max(yy + 2.017 * cbf, 0.0), 255.0)
    return r, g, b


@_jit
def _hsv8(r, g, b, sdiv, hdiv):
    """OpenCV's COLOR_RGB2HSV for one 8-bit pixel: (h 0..179, s, v)."""
    v = max(r, g, b)
    vmin = min(r, g, b)
    diff = v - vmin
    s = (diff * sdiv[v] + (1 << (HSV_SHIFT - 1))) >> HSV_SHIFT
    if v == r:
        h = g - b
    elif v == g:
        h = b - r + 2 * diff
    else:
        h = r - g + 4 * diff
    h = (h * hdiv[diff] + (1 << (HSV_SHIFT - 1))) >> HSV_SHIFT
    if h < 0:
        h += 180
    return h, s, v


@_jit
def _window(y, c, centre, k, rr, sig):
    """Fill ``rr``/``sig`` with the ``2k+1`` rows around ``centre`` of column ``c`` and the luma
    above the window's minimum; return (top, sum above half maximum, centre of mass)."""
    h = y.shape[0]
    n = 2 * k + 1
    lo = 1e9
    hi = -1e9
    for j in range(n):
        r = min(max(centre + j - k, 0), h - 1)
        rr[j] = r
        v = float(y[r, c])
        sig[j] = v
        lo = min(lo, v)
        hi = max(hi, v)
    top = hi - lo
    half = 0.5 * top
    wsum = 0.0
    acc = 0.0
    for j in range(n):
        sig[j] -= lo
        a = sig[j] - half
        if a > 0:
            wsum += a
            acc += a * rr[j]
    return top, wsum, (acc / wsum) if wsum > 0 else np.nan


@_jit
def _window_refine(rr, sig, n, top, centre):
    """``stripes.window_refine`` of one column: the centre of mass of the luma above a floor
    (a tenth of the maximum, or the row just outside the estimate's window on either side
    where that is brighter) in a window of fixed half width around the estimate
    (fractional end weights), iterated; ``centre`` unchanged where that window would leave the
    samples."""
    wc = 0
    plateau = 0
    for j in range(n):
        if sig[j] > 0.5 * top:
            wc += 1
        if sig[j] >= REFINE_PLATEAU * top:
            plateau += 1
    cap = REFINE_MAX_HALF_CLIPPED if plateau >= REFINE_PLATEAU_ROWS else REFINE_MAX_HALF
    if centre == centre:  # the core's run through the estimate's row (not NaN)
        i = int(np.floor(centre - rr[0] + 0.5))
        if 0 <= i < n and sig[i] >= REFINE_CORE * top:
            a = i
            while a > 0 and sig[a - 1] >= REFINE_CORE * top:
                a -= 1
            b = i
            while b < n - 1 and sig[b + 1] >= REFINE_CORE * top:
                b += 1
            cap = max(cap, 0.5 * (b - a + 1) + REFINE_CORE_MARGIN)
    hw = min(cap, max(REFINE_MIN_HALF, REFINE_WIDTH * wc))
    c = centre
    for _ in range(REFINE_ITERATIONS):
        if c - hw < rr[0] or c + hw > rr[n - 1]:
            return centre
        # the rows just outside the window on each side (the first with no weight)
        floor = REFINE_FLOOR * top
        for j in range(n):
            if rr[j] > c + hw + 0.5:
                floor = max(floor, sig[j])
                break
        for j in range(n - 1, -1, -1):
            if rr[j] < c - hw - 0.5:
                floor = max(floor, sig[j])
                break
        acc = 0.0
        ws = 0.0
        for j in range(n):
            wt = min(max(hw + 0.5 - abs(rr[j] - c), 0.0), 1.0)
            a = sig[j] - floor
            if a > 0 and wt > 0:
                ws += a * wt
                acc += a * wt * rr[j]
        if ws <= 0:
            return centre
        c = acc / ws
    return c


@_jit
def _headroom_lean(y, cb, cr, sh, c, cc, rr, n, ch):
    """``stripes.headroom_lean`` of column ``c``'s window of rows ``rr`` (``n`` rows); ``ch``
    is the laser's RGB channel (0 red, 1 green), the other laser's is ``1 - ch``. -inf when the
    other laser's channel is saturated (>= 250) in any of the window's rows."""
    a = _rgb(float(y[rr[0], c]), float(cb[rr[0] >> sh, cc]), float(cr[rr[0] >> sh, cc]))
    b = _rgb(float(y[rr[n - 1], c]), float(cb[rr[n - 1] >> sh, cc]),
             float(cr[rr[n - 1] >> sh, cc]))
    oc = 1 - ch
    bg_c = 0.5 * (a[ch] + b[ch])
    bg_o = 0.5 * (a[oc] + b[oc])
    hc = max(255.0 - bg_c, 8.0)
    ho = max(255.0 - bg_o, 8.0)
    if a[oc] >= 250.0 or b[oc] >= 250.0:
        return -np.inf
    total = 0.0
    for j in range(1, n - 1):
        r = rr[j]
        px = _rgb(float(y[r, c]), float(cb[r >> sh, cc]), float(cr[r >> sh, cc]))
        if px[oc] >= 250.0:
            return -np.inf
        total += (px[ch] - bg_c) / hc - (px[oc] - bg_o) / ho
    return total


@_jit
def _faint(y, cb, cr, sh, c, cc, rr, n, k, ch, o1, o2, min_peak, min_value):
    """Whether column ``c``'s window holds light of this laser's colour against the surface it
    falls on (``FAINT_RISE``, ``FAINT_TINT``): over the central three rows the laser's channel
    ``ch`` rises on average at least ``FAINT_RISE * min_peak`` above the surface (the mean of
    the window's two end rows on each side) and reaches ``min_value`` on one of them (or its
    rise is ``FAINT_DARK_RISE`` of the surface's level and ``FAINT_DARK_CLEAR`` x the spread of
    the window's rows ``FAINT_DARK_SIDE`` or more from its centre, one more with 4:2:0 chroma,
    each central row above them all: dark soil),
    and each other channel (``o1``, ``o2``) rises on average by at most ``FAINT_TINT`` x the
    laser channel's rise x the surface's ratio of that channel to the laser's; the other laser's
    channel (``1 - ch``) not clipped (``FAINT_CLIP``) on more of the window's rows than
    ``ch``."""
    bg0 = 0.0
    bg1 = 0.0
    bg2 = 0.0
    for j in (0, 1, n - 2, n - 1):
        r = rr[j]
        px = _rgb(float(y[r, c]), float(cb[r >> sh, cc]), float(cr[r >> sh, cc]))
        bg0 += 0.25 * px[0]
        bg1 += 0.25 * px[1]
        bg2 += 0.25 * px[2]
    m0 = 0.0
    m1 = 0.0
    m2 = 0.0
    top = 0.0
    low = np.inf
    for j in range(k - 1, k + 2):
        r = rr[j]
        px = _rgb(float(y[r, c]), float(cb[r >> sh, cc]), float(cr[r >> sh, cc]))
        m0 += px[0] / 3.0
        m1 += px[1] / 3.0
        m2 += px[2] / 3.0
        top = max(top, px[ch])
        low = min(low, px[ch])
    bg = (bg0, bg1, bg2)
    rise = (m0 - bg0, m1 - bg1, m2 - bg2)
    best = rise[ch]
    light = best >= FAINT_RISE * min_peak and top >= min_value
    if not (light or (best >= FAINT_DARK_MIN * min_peak and best >= FAINT_DARK_RISE * bg[ch])):
        return False
    if not light:
        # dark soil: the surface in this laser's channel, its darkest and brightest over every
        # row of the window FAINT_DARK_SIDE or more from its centre (one more with 4:2:0 chroma)
        lo = np.inf
        hi = -np.inf
        for j in range(n):
            if abs(j - k) >= FAINT_DARK_SIDE + sh:
                r = rr[j]
                v = _rgb(float(y[r, c]), float(cb[r >> sh, cc]), float(cr[r >> sh, cc]))[ch]
                lo = min(lo, v)
                hi = max(hi, v)
        if not (low > hi and best >= FAINT_DARK_CLEAR * (hi - lo)):
            return False
    bc = max(bg[ch], 1.0)
    for o in (o1, o2):
        if rise[o] * bc > FAINT_TINT * best * bg[o]:
            return False
    # last (the rarest to be reached): the clipped rows of the two lasers' channels
    clip_own = 0
    clip_other = 0
    for j in range(n):
        r = rr[j]
        px = _rgb(float(y[r, c]), float(cb[r >> sh, cc]), float(cr[r >> sh, cc]))
        clip_own += px[ch] >= FAINT_CLIP
        clip_other += px[1 - ch] >= FAINT_CLIP
    return clip_other <= clip_own


@_jit
def _score(y, cr, sh, c, r, sign):
    """The first pass's score of row ``r`` of column ``c``: its luma biased towards the
    laser's chroma."""
    return int(y[r, c]) + sign * (int(cr[r >> sh, c >> sh]) - 128)


@_jit
def _candidate(y, cr, sh, c, b0, band_height, r0, r1, sign, ex_lo, ex_hi, step):
    """Another candidate row of column ``c``'s band (every second row from ``r0``; the rows
    ``ex_lo .. ex_hi - 1`` skipped; first of equal maxima; -1 when there is none).

    ``step`` 0: the first pass's candidate again, the best :func:`_score`. ``step`` > 0: the
    row whose score rises most above the higher of the scores ``step`` rows above and below it
    (one side where the other is outside the band): a stripe, not a bright surface, which can
    outscore a stripe on darker ground."""
    lo = max(r0, b0 + ((b0 - r0) & 1))
    hi = min(r1, b0 + band_height)
    none = -(1 << 30)
    best = none
    row = -1
    for r in range(lo, hi, 2):
        if ex_lo <= r < ex_hi:
            continue
        v = _score(y, cr, sh, c, r, sign)
        if step > 0:
            m = none
            if r - step >= lo:
                m = _score(y, cr, sh, c, r - step, sign)
            if r + step < hi:
                m = max(m, _score(y, cr, sh, c, r + step, sign))
            if m == none:
                continue
            v -= m
        if v > best:
            best = v
            row = r
    return row


@_jit
def _peak_at(y, cb, cr, sh, c, coarse, b0, band, laser, peak, colour, hsv, rr, sig, strict,
             vouched):
    """Steps 2-4 of :func:`detect_stripe` for column ``c`` at candidate row ``coarse``:
    ``(row, strength, why)`` - the refined centre (NaN when a test refuses the peak), its
    strength, and why it was refused: 0 kept, or refused by colour outside the other laser's
    band; 1 refused in that band; 2 not a peak (too weak, at the band's edge, an edge, too
    wide). ``strict``: the lean test of the other laser's band applies everywhere.
    ``vouched``: the row was predicted by the stripe's continuing neighbours (the guided
    pass): a peak the colour tests refuse is kept (why 5) when its halo does not lean to the
    other laser's colour by the white-core rule's limit or more (inside the other laser's
    band the lean test above, or the headroom test, has already passed it); like a white
    core, it is kept only where its chain holds colour-accepted columns (_confirm_white)."""
    _, band_height, other_start, other_height = band
    sign, ch, o1, o2 = laser
    min_peak, k, max_width, max_wrong_lean, min_headroom_lean, refine, retry, bloom_level, \
        bloom_lean, light_lean, white_lean = peak
    use_hue, hue_lo, hue_hi, min_sat, min_value, use_tint, min_tint, lut, lut_margin = colour
    sdiv, hdiv = hsv
    h = y.shape[0]
    n = 2 * k + 1
    cc = c >> sh
    use_lut = lut.shape[0] > 0
    # fine: the brightest luma row within +-2 rows
    pk = -1
    bestv = -1
    for o in range(-2, 3):
        r = min(max(coarse + o, 0), h - 1)
        if int(y[r, c]) > bestv:
            bestv = int(y[r, c])
            pk = r
    # 2. centre of mass of the luma above half maximum, in a window re-centred once
    top, wsum, centre = _window(y, c, pk, k, rr, sig)
    if not math.isnan(centre) and int(np.rint(centre)) != pk:  # else: the same window
        pk = int(np.rint(centre))
        top, wsum, centre = _window(y, c, pk, k, rr, sig)
    ob0 = other_start[c]
    inside = strict or (pk + k >= ob0 and pk - k < ob0 + other_height[c])
    pi = pk - b0
    # a faint stripe (FAINT_SHARE): its light of this laser's colour makes it a peak
    faint = ((retry & 4) != 0 and top < min_peak and top >= FAINT_SHARE * min_peak and wsum > 0
             and pi >= k and pi < band_height - k
             and _faint(y, cb, cr, sh, c, cc, rr, n, k, ch, o1, o2, min_peak, min_value))
    # a weaker peak is tested further only for the white-core rule (WEAK_SHARE)
    weak = (top < min_peak and white_lean < np.inf and not inside
            and top >= WEAK_SHARE * min_peak and not faint)
    if not ((top >= min_peak or weak or faint) and wsum > 0 and pi >= k
            and pi < band_height - k):
        return np.nan, top, 2  # too weak (or at the band's edge)
    if not (sig[0] < 0.7 * top and sig[n - 1] < 0.7 * top):
        return np.nan, top, 2  # an edge, not a peak
    if n > max_width:  # else the window cannot hold a stripe wider than max_width
        width = 0
        for j in range(n):
            if sig[j] > 0.5 * top:
                width += 1
        if width > max_width:
            return np.nan, top, 2
    # 3. the halo leans to this laser's colour (judged against the window's ends)
    bg = 0.5 * (float(cr[rr[0] >> sh, cc]) + float(cr[rr[n - 1] >> sh, cc]))
    lean = 0.0
    nh = 0
    light = 0.0
    lsum = 0.0
    for j in range(n):
        if sig[j] > 0.2 * top:
            d = sign * (float(cr[rr[j] >> sh, cc]) - bg)
            light += float(sig[j]) * d
            lsum += float(sig[j])
            if sig[j] < 0.65 * top:
                lean += d
                nh += 1
    # in the other laser's band, when it is known, the lean of all the stripe's light (its
    # rows above a fifth of the peak, weighted by their light): the halo alone can be one row
    # of textured ground beside a sharp stripe (stripes.StripeParams.min_lean_in_other_band)
    in_lean = (light / lsum if lsum > 0 else 0.0) if light_lean else lean / max(nh, 1)
    # only where the other laser's stripe can lie (its band, widened by the half window)
    if in_lean <= -max_wrong_lean and inside:
        # a stripe saturating its own channel on a surface of its colour: the headroom
        # shares decide (stripes.headroom_lean)
        if not _headroom_lean(y, cb, cr, sh, c, cc, rr, n, ch) >= min_headroom_lean:
            return np.nan, top, 1
    # 4. the method's colour test on the central rows
    ok = False
    if weak:
        if lean / max(nh, 1) > -white_lean and _saturated_core(y, cb, cr, sh, c, cc, rr, k, ch,
                                                               bloom_level):
            # why 4: a weak peak kept by the white-core rule alone (if the chain test drops
            # it, the second candidate is tried as for a weak peak: detect_stripe)
            return (_window_refine(rr, sig, n, top, centre) if refine else centre), top, 4
        return np.nan, top, 2
    for j in range(k - 3, k + 4):
        r = rr[j]
        rgb = _rgb(float(y[r, c]), float(cb[r >> sh, cc]), float(cr[r >> sh, cc]))
        rf = rgb[ch]
        of = max(rgb[o1], rgb[o2])
        # the three tests are alternatives: the cheapest first
        if use_tint and rf - of >= min_tint and rf >= min_value:
            ok = True
            break
        if use_hue:
            hh, ss, vv = _hsv8(int(rgb[0]), int(rgb[1]), int(rgb[2]), sdiv, hdiv)
            if ss >= min_sat and vv >= min_value:
                for q in range(hue_lo.shape[0]):
                    if hue_lo[q] <= hh <= hue_hi[q]:
                        ok = True
        if use_lut:
            q0 = int(min(max(rgb[o1] + 0.5, 0.0), 255.0)) >> 2
            q1 = int(min(max(rgb[o2] + 0.5, 0.0), 255.0)) >> 2
            if int(min(max(rf + 0.5, 0.0), 255.0)) > lut[q0, q1] + lut_margin:
                ok = True
        if ok:
            break
    if not ok and (retry & 4) != 0 and (faint or _faint(y, cb, cr, sh, c, cc, rr, n, k, ch, o1,
                                                        o2, min_peak, min_value)):
        # the light the peak adds is of this laser's colour, against the surface's (_faint):
        # on a tinted light surface the laser's tint over the other channels can be under
        # min_tint and its saturation under min_sat
        ok = True
    if not ok and bloom_lean < np.inf and lean / max(nh, 1) > -max_wrong_lean:
        # (with the band known, -max_wrong_lean is the halo's least lean to this laser's
        # colour: a white line on yellow soil leans to neither and is refused)
        ok = _blooming(y, cb, cr, sh, c, cc, rr, n, k, ch, o1, o2, min_value, bloom_level,
                       bloom_lean)
    if not ok and white_lean < np.inf and not inside and lean / max(nh, 1) > -white_lean:
        # a white core (stripes.StripeParams.white_core): away from the other laser's band
        # the position says which laser it is; a core saturated in this laser's channel whose
        # halo does not clearly lean to the other laser's colour is the stripe
        if _saturated_core(y, cb, cr, sh, c, cc, rr, k, ch, bloom_level):
            # kept by this rule alone (why 3): confirmed by _confirm_white or dropped
            return (_window_refine(rr, sig, n, top, centre) if refine else centre), top, 3
    if not ok and vouched and white_lean < np.inf and lean / max(nh, 1) > -white_lean:
        return (_window_refine(rr, sig, n, top, centre) if refine else centre), top, 5
    if not ok:
        return np.nan, top, 1 if inside else 0
    return (_window_refine(rr, sig, n, top, centre) if refine else centre), top, 0


@_jit
def _saturated_core(y, cb, cr, sh, c, cc, rr, k, ch, level):
    """Whether column ``c``'s window has, within 2 rows of its centre, this laser's channel and
    the luma (0.299 R + 0.587 G + 0.114 B) at least ``level`` (``stripes.BLOOM_LEVEL``: at
    full scale): a core clipped white, not a bright piece of soil of this laser's colour. Where
    the surface (the window's two end rows on each side) is itself within ``WHITE_SOIL_DROP``
    of full scale in this laser's channel, the luma need only reach ``level -
    WHITE_LUMA_DROP``."""
    low = level
    bg = 0.0
    n = 2 * k + 1
    for j in (0, 1, n - 2, n - 1):
        r = rr[j]
        bg += 0.25 * _rgb(float(y[r, c]), float(cb[r >> sh, cc]), float(cr[r >> sh, cc]))[ch]
    if bg >= level - WHITE_SOIL_DROP:
        low = level - WHITE_LUMA_DROP
    chan = False
    white = False
    for j in range(k - 2, k + 3):
        r = rr[j]
        px = _rgb(float(y[r, c]), float(cb[r >> sh, cc]), float(cr[r >> sh, cc]))
        chan = chan or px[ch] >= level
        white = white or 0.299 * px[0] + 0.587 * px[1] + 0.114 * px[2] >= low
    return chan and white


@_jit
def _blooming(y, cb, cr, sh, c, cc, rr, n, k, ch, o1, o2, min_value, level, min_lean):
    """``stripes.blooming_lean``'s test for column ``c``'s window: the core saturated in the
    laser's channel (at least ``level`` within 2 rows of the centre), the laser's channel the
    largest on a central row (the tint test at 0), and the light leaning to this laser's colour
    by at least ``min_lean`` (headroom shares summed over the inner rows, this laser's channel
    minus the other laser's, ``1 - ch``)."""
    sat = False
    tint0 = False
    for j in range(k - 3, k + 4):
        r = rr[j]
        px = _rgb(float(y[r, c]), float(cb[r >> sh, cc]), float(cr[r >> sh, cc]))
        if abs(j - k) <= 2 and px[ch] >= level:
            sat = True
        if px[ch] - max(px[o1], px[o2]) >= 0.0 and px[ch] >= min_value:
            tint0 = True
    if not (sat and tint0):
        return False
    oc = 1 - ch
    a = _rgb(float(y[rr[0], c]), float(cb[rr[0] >> sh, cc]), float(cr[rr[0] >> sh, cc]))
    b = _rgb(float(y[rr[n - 1], c]), float(cb[rr[n - 1] >> sh, cc]),
             float(cr[rr[n - 1] >> sh, cc]))
    bg_c = 0.5 * (a[ch] + b[ch])
    bg_o = 0.5 * (a[oc] + b[oc])
    hc = max(255.0 - bg_c, 8.0)
    ho = max(255.0 - bg_o, 8.0)
    total = 0.0
    for j in range(1, n - 1):
        r = rr[j]
        px = _rgb(float(y[r, c]), float(cb[r >> sh, cc]), float(cr[r >> sh, cc]))
        total += (px[ch] - bg_c) / hc - (px[oc] - bg_o) / ho
    return total >= min_lean


@_jit
def _guided(y, cb, cr, sh, band, laser, peak, colour, hsv, rr, sig, rows, strength, linked,
            pred, white, weak):
    """The guided pass of :func:`detect_stripe` (``stripes.guided_prediction`` and
    ``detect_planes_numpy``): every column whose row does not continue into a neighbour's
    (within ``GUIDE_LINK``) and has columns that do within ``GUIDE_REACH`` on both sides,
    whose rows are continuous across it, is tested again at the row interpolated between them;
    the peak found is kept if it lies within ``GUIDE_DEV`` of that row. So is each column of a
    short piece (at most ``GUIDE_SHORT`` continuing columns) between longer pieces within
    ``GUIDE_REACH`` of its ends whose rows are continuous across it and predict a row more than
    ``GUIDE_LINK`` from the piece's. The predictions come from the first pass's rows only."""
    band_start, band_height = band[0], band[1]
    w = rows.shape[0]
    for c in range(w):
        linked[c] = False
    for c in range(w - 1):
        if abs(rows[c + 1] - rows[c]) <= GUIDE_LINK:  # NaN never links
            linked[c] = True
            linked[c + 1] = True
    for c in range(w):
        pred[c] = np.nan
        if linked[c]:
            continue
        left = -1
        for j in range(c - 1, max(c - GUIDE_REACH, 0) - 1, -1):
            if linked[j]:
                left = j
                break
        right = -1
        for j in range(c + 1, min(c + GUIDE_REACH, w - 1) + 1):
            if linked[j]:
                right = j
                break
        if left < 0 or right < 0 or abs(rows[right] - rows[left]) > GUIDE_LINK * (right - left):
            continue
        pred[c] = rows[left] + (rows[right] - rows[left]) * (c - left) / (right - left)
    # short pieces between longer ones: each column's piece length, then the short pieces'
    # columns' predictions
    length = np.empty(w, np.int64)
    c = 0
    while c < w:
        d = c
        while d + 1 < w and abs(rows[d + 1] - rows[d]) <= GUIDE_LINK:
            d += 1
        for i in range(c, d + 1):
            length[i] = d - c + 1
        c = d + 1
    c = 0
    while c < w:
        d = c + length[c] - 1
        if linked[c] and length[c] <= GUIDE_SHORT:
            left = -1
            for j in range(c - 1, max(c - GUIDE_REACH, 0) - 1, -1):
                if length[j] > GUIDE_SHORT:
                    left = j
                    break
            right = -1
            for j in range(d + 1, min(d + GUIDE_REACH, w - 1) + 1):
                if length[j] > GUIDE_SHORT:
                    right = j
                    break
            if left >= 0 and right >= 0 and \
                    abs(rows[right] - rows[left]) <= GUIDE_LINK * (right - left):
                for i in range(c, d + 1):
                    p = rows[left] + (rows[right] - rows[left]) * (i - left) / (right - left)
                    if abs(rows[i] - p) > GUIDE_LINK:
                        pred[i] = p
        c = d + 1
    for c in range(w):
        p = pred[c]
        if math.isnan(p):
            continue
        coarse = int(np.rint(p))
        b0 = band_start[c]
        if coarse < b0 or coarse >= b0 + band_height:
            continue
        row, top, why = _peak_at(y, cb, cr, sh, c, coarse, b0, band, laser, peak, colour, hsv,
                                 rr, sig, False, True)
        if not math.isnan(row) and abs(row - p) <= GUIDE_DEV:
            rows[c] = row
            strength[c] = top
            # 1: kept by the white-core rule alone; 2: vouched for by its position (why 5),
            # confirmed like a white core by its chain's colour-accepted columns, and counted
            # neither as one of those nor against them (_confirm_white): a white line whose
            # unsaturated columns the position vouches for is still a white line
            white[c] = 2 if why == 5 else (1 if why >= 3 else 0)
            weak[c] = False


@_jit
def _drop_white(rows, strength, white, start, last):
    """For :func:`_confirm_white`: in the chain of found columns ``start..last``, drop each
    white or vouched column (``white`` 1 or 2) with less than ``WHITE_SHARE`` of the found
    columns within ``WHITE_HALF`` columns of it, and within ``WHITE_HALF_WIDE``, (in the chain;
    vouched ones not counted) accepted by the colour tests."""
    keep = np.empty(last - start + 1, np.bool_)
    for j in range(start, last + 1):
        keep[j - start] = True
        if white[j] == 0:
            continue
        found = 0
        coloured = 0
        near_found = 0
        near_coloured = 0
        for i in range(max(start, j - WHITE_HALF_WIDE), min(last, j + WHITE_HALF_WIDE) + 1):
            if not math.isnan(rows[i]) and white[i] != 2:
                found += 1
                coloured += white[i] == 0
                if abs(i - j) <= WHITE_HALF:
                    near_found += 1
                    near_coloured += white[i] == 0
        keep[j - start] = ((near_found > 0 and near_coloured >= WHITE_SHARE * near_found)
                           or (found > 0 and coloured >= WHITE_SHARE * found))
    for j in range(start, last + 1):
        if not keep[j - start]:
            rows[j] = np.nan
            strength[j] = 0.0


@_jit
def _confirm_white(rows, strength, white):
    """Drop the columns kept by the white-core rule alone (``white``) where, on their chain
    of found columns and within ``WHITE_HALF`` columns, less than ``WHITE_SHARE`` of the found
    columns were accepted by the colour tests (``stripes.confirmed_by_colour``, the numpy
    reference): a chain continues to the next found column within ``GUIDE_REACH`` columns
    whose row differs by at most ``GUIDE_LINK`` per column."""
    w = rows.shape[0]
    start = -1  # first found column of the current chain
    last = -1  # last found column
    coloured = 0
    total = 0
    for c in range(w + 1):
        found = c < w and not math.isnan(rows[c])
        if c < w and not found:
            continue
        cont = found and last >= 0 and c - last <= GUIDE_REACH and \
            abs(rows[c] - rows[last]) <= GUIDE_LINK * (c - last)
        if not cont and start >= 0:
            if coloured < total:  # the chain ends: judge its white columns
                _drop_white(rows, strength, white, start, last)
            start = -1
        if not found:
            break
        if start < 0:
            start = c
            coloured = 0
            total = 0
        coloured += white[c] == 0
        total += 1
        last = c


@_kernel(
    "void(Tuple((uint8[:, :], uint8[:, :], uint8[:, :], int64)), "
    "Tuple((int64[:], int64, int64[:], int64[:])), "
    "UniTuple(int64, 4), "
    "Tuple((float64, int64, int64, float64, float64, int64, int64, float64, float64, boolean, float64)), "
    "Tuple((boolean, int64[:], int64[:], int64, int64, boolean, float64, int16[:, :], int64)), "
    "UniTuple(int64[:], 2), Tuple((float64[:], float32[:])))"
)
def detect_stripe(frame, band, laser, peak, colour, hsv, out):
    """One laser's stripe in every column: the compiled form of ``stripes.detect_planes_numpy``
    (same steps, same thresholds). The arguments, grouped (tuples cost nothing inside a
    kernel, and as little as separate arguments to call with):

    * ``frame = (y, cb, cr, chroma_step)``: the frame's planes (:class:`video.Planes`);
    * ``band = (band_start, band_height, other_start, other_height)``: rows searched in each
      column, and the rows where the other laser's stripe can lie, per column (the lean test
      refuses a peak only there);
    * ``laser = (sign, ch, o1, o2)``: +1 red / -1 green (the chroma lean), the laser's RGB
      channel and the other two;
    * ``peak = (min_peak, k, max_width, max_wrong_lean, min_headroom_lean, refine, retry,
      bloom_level, bloom_lean, light_lean)``: the peak tests (``k``: the half window; a peak
      whose lean to this laser's colour is at most ``-max_wrong_lean`` is refused in the
      other band unless the headroom test keeps it: ``stripes._wrong_lean``), whether the
      centre is refined (``stripes.SUBPIXEL``: 1 ``window``, 0 ``half-max``), ``retry``: bit 1
      a refused candidate gets a second one, bit 2 the guided pass (:func:`_guided`) runs,
      bit 4 a faint peak of this laser's colour counts (:func:`_faint`); the blooming test's level and lean
      (``stripes.BLOOM_LEVEL``, ``BLOOM_LEAN``; inf: no test), and whether that lean is the
      lean of all the stripe's light rather than of its halo, the last four only when the
      other laser's band is known; ``white_lean``: outside the other laser's band a peak the
      colour tests refuse is kept when its core saturates the laser's channel and its halo
      leans to the other laser's colour by less than this (``StripeParams.white_core``; inf:
      no such rule);
    * ``colour = (use_hue, hue_lo, hue_hi, min_sat, min_value, use_tint, min_tint, lut,
      lut_margin)``: the method's colour tests; ``lut`` is a (64, 64) table or an empty
      (0, 0) array;
    * ``hsv = (sdiv, hdiv)``: :func:`hsv_tables`;
    * ``out = (rows, strength)``: the result per column (NaN / 0 where no stripe)."""
    y, cb, cr, s = frame
    band_start, band_height = band[0], band[1]
    sign = laser[0]
    k = peak[1]
    retry = peak[6]
    rows_out, strength_out = out
    h, w = y.shape
    sh = 1 if s == 2 else 0  # chroma subsampling as a shift (4:2:0 or full resolution)
    r0 = band_start.min()
    r0 -= r0 % 2
    r1 = min(h, band_start.max() + band_height)
    n = 2 * k + 1
    rr = np.empty(n, np.int64)
    sig = np.empty(n, np.float64)
    # 1. candidate: per column the brightest luma biased towards the laser's chroma, at every
    # second row of the column's band (row-major: memory is read in order)
    # the score and (4095 - the row's index) packed in one integer: a plain running maximum,
    # which compiles to vector instructions, picks the first row of equal maxima
    # rows inside every column's band skip the per-column band test
    best = np.full(w, np.int32(-(1 << 30)), np.int32)
    white = np.zeros(w, np.uint8)  # 1: kept by the white-core rule alone; 2: vouched for
    weak = np.zeros(w, np.bool_)  # ... from a weak first candidate
    first = np.zeros(w, np.int64)  # the first candidate's row
    crx = np.empty(w, np.int32)
    lo = band_start.astype(np.int32)
    hi = lo + np.int32(band_height)
    sg = np.int32(sign)
    all_lo = band_start.max()
    all_hi = band_start.min() + band_height
    for i, r in enumerate(range(r0, r1, 2)):
        yr = y[r]
        crr = cr[r >> sh]
        if sh:  # 4:2:0: one chroma sample for two columns
            for c in range(w >> 1):
                q = sg * (np.int32(crr[c]) - np.int32(128))
                crx[2 * c] = q
                crx[2 * c + 1] = q
            if w & 1:
                crx[w - 1] = sg * (np.int32(crr[(w - 1) >> 1]) - np.int32(128))
        else:
            for c in range(w):
                crx[c] = sg * (np.int32(crr[c]) - np.int32(128))
        r32 = np.int32(r)
        tag = np.int32(4095 - i)
        if all_lo <= r < all_hi:
            for c in range(w):
                v = np.int32(yr[c]) + crx[c]
                best[c] = max(best[c], v * np.int32(4096) + tag)
        else:
            for c in range(w):
                v = np.int32(yr[c]) + crx[c]
                v = v if (r32 >= lo[c]) & (r32 < hi[c]) else np.int32(-1000)
                best[c] = max(best[c], v * np.int32(4096) + tag)
    for c in range(w):
        rows_out[c] = np.nan
        strength_out[c] = 0.0
        if (best[c] >> 12) <= -1000:
            continue  # no row of the column's band was searched
        coarse = r0 + 2 * (4095 - (best[c] & 4095))
        row, top, why = _peak_at(y, cb, cr, sh, c, coarse, band_start[c], band, laser, peak,
                                 colour, hsv, rr, sig, False, False)
        w4 = why == 4
        if math.isnan(row) and why and retry & 1:
            why0 = why
            if why == 1:
                # refused where the other laser's stripe can lie: that stripe, brighter, can
                # hide this laser's in the column; the best candidate of the band away from it
                # (more than 2k rows) is tested the same way
                second = _candidate(y, cr, sh, c, band_start[c], band_height, r0, r1, sign,
                                    coarse - 2 * k, coarse + 2 * k + 1, 0)
            else:
                # not a peak: a bright surface (a light target face) can outscore the stripe
                # on darker ground; the row rising most above its surroundings is tested,
                # its halo required to lean to this laser's colour everywhere
                second = _candidate(y, cr, sh, c, band_start[c], band_height, r0, r1, sign,
                                    coarse - k, coarse + k + 1, RIDGE_STEP)
            if second >= 0:
                row, top, why = _peak_at(y, cb, cr, sh, c, second, band_start[c], band, laser,
                                         peak, colour, hsv, rr, sig, why0 == 2, False)
            if math.isnan(row) and why0 == 1:
                # refused again: the second candidate can be a light surface beside the other
                # laser's stripe, still in that laser's band (a white block under it: random
                # rig 212); the best candidate of this laser's own rows, outside that band
                # (widened by the half window), is tested the same way
                third = _candidate(y, cr, sh, c, band_start[c], band_height, r0, r1, sign,
                                   band[2][c] - k, band[2][c] + band[3][c] + k, 0)
                if third >= 0:
                    row, top, why = _peak_at(y, cb, cr, sh, c, third, band_start[c], band,
                                             laser, peak, colour, hsv, rr, sig, False, False)
        white[c] = 0
        weak[c] = False
        if not math.isnan(row):
            rows_out[c] = row
            strength_out[c] = top
            white[c] = 1 if why >= 3 else 0
            weak[c] = w4  # (from the first candidate: a retried column has no row then)
            first[c] = coarse
    if retry & 2:
        _guided(y, cb, cr, sh, band, laser, peak, colour, hsv, rr, sig, rows_out, strength_out,
                np.empty(w, np.bool_), np.empty(w, np.float64), white, weak)
    _confirm_white(rows_out, strength_out, white)
    if retry & 1:
        # a weak peak the chain test dropped gets the second candidate a weak peak got before
        # the white-core rule (a light face clipped white above the stripe)
        for c in range(w):
            if weak[c] and math.isnan(rows_out[c]):
                second = _candidate(y, cr, sh, c, band_start[c], band_height, r0, r1, sign,
                                    first[c] - k, first[c] + k + 1, RIDGE_STEP)
                if second >= 0:
                    row, top, _ = _peak_at(y, cb, cr, sh, c, second, band_start[c], band,
                                           laser, peak, colour, hsv, rr, sig, True, False)
                    if not math.isnan(row):
                        rows_out[c] = row
                        strength_out[c] = top


@_jit
def _lit_point(t, rays, c, normal, offset):
    """Where the ray through column ``c`` at band row ``t`` (sub-pixel: linear between the rows
    of ``rays[c]`` around it) meets the plane ``normal . p = offset``: the rail-frame point
    relative to the camera, ``(x, y, z)``; NaNs where the ray runs parallel to the plane."""
    nt = rays.shape[1]
    j = min(max(int(math.floor(t)), 0), nt - 2)
    f = t - j
    d0 = rays[c, j, 0] + f * (rays[c, j + 1, 0] - rays[c, j, 0])
    d1 = rays[c, j, 1] + f * (rays[c, j + 1, 1] - rays[c, j, 1])
    d2 = rays[c, j, 2] + f * (rays[c, j + 1, 2] - rays[c, j, 2])
    den = d0 * normal[0] + d1 * normal[1] + d2 * normal[2]
    if abs(den) <= 1e-12:
        return np.nan, np.nan, np.nan
    lam = offset / den
    return lam * d0, lam * d1, lam * d2


@_kernel(
    "void(float64[:], boolean[:], int64[:], float64[:, :, :], float64[:], float64, float64, float64, float64[:], float64[:], float64[:], float64[:])"
)
def triangulate(rows, valid, band_start, rays, normal, offset, travel, row_mm, ref, x_out,
                y_out, h_out):
    """Stripe rows -> rail-frame points on the laser plane and their heights.

    ``rays[c, j]`` is the rail-frame ray direction through column ``c`` at image row
    ``band_start[c] + j`` (lens distortion undone once, before the loop); a sub-pixel row
    interpolates linearly between the two rows around it. ``ref = (c0, cx, cy)``: the
    reference surface depth ``c0 + cx x + cy y`` (height = reference depth - depth). Travel is
    added to y, and under a rolling shutter ``row_mm`` per image row (the camera's travel
    while the rows above were read; 0 for a global shutter). NaN where not ``valid`` or where
    the ray runs parallel to the plane."""
    for c in range(rows.shape[0]):
        x_out[c] = np.nan
        y_out[c] = np.nan
        h_out[c] = np.nan
        if not valid[c]:
            continue
        x, yy, z = _lit_point(rows[c] - band_start[c], rays, c, normal, offset)
        if math.isnan(x):
            continue
        yy += travel
        if row_mm != 0.0:
            yy += row_mm * rows[c]
        x_out[c] = x
        y_out[c] = yy
        h_out[c] = ref[0] + ref[1] * x + ref[2] * yy - z


@_kernel(
    "void(float64[:], float64[:], float64[:], boolean[:], int64, float64, float64[:], float64[:], float64[:], boolean[:])"
)
def upsample(x, y, h, valid, k, max_step, xo, yo, ho, vo):
    """``k - 1`` points between neighbouring columns of a profile (``grid.upsample_profile``):
    linear where the surface is continuous, the nearer neighbour across a step."""
    n = x.shape[0]
    for i in range(n - 1):
        both = valid[i] and valid[i + 1]
        step = abs(h[i + 1] - h[i]) > max_step
        o = i * k
        xo[o], yo[o], ho[o], vo[o] = x[i], y[i], h[i], valid[i]
        for j in range(1, k):
            t = j / k
            if step:
                a = i if t < 0.5 else i + 1
                xo[o + j], yo[o + j], ho[o + j] = x[a], y[a], h[a]
            else:
                xo[o + j] = x[i] + t * (x[i + 1] - x[i])
                yo[o + j] = y[i] + t * (y[i + 1] - y[i])
                ho[o + j] = h[i] + t * (h[i + 1] - h[i])
            vo[o + j] = both
    o = (n - 1) * k
    xo[o], yo[o], ho[o], vo[o] = x[n - 1], y[n - 1], h[n - 1], valid[n - 1]


@_jit
def _nanmin(a, b):
    return np.nan if (math.isnan(a) or math.isnan(b)) else min(a, b)


@_jit
def _nanmax(a, b):
    return np.nan if (math.isnan(a) or math.isnan(b)) else max(a, b)


@_kernel(
    "int64(float64[:], float64, int64, int64[:], float64[:, :, :], float64[:], float64, float64, float64, float64[:], float64, int64, boolean[:], float64[:], float64[:], float64[:], float64[:], float64[:], float64[:], boolean[:], float64[:])"
)
def stripe_profile(rows, tol_px, min_cols, band_start, rays, normal, offset, travel, row_mm,
                   ref, max_step, k, valid, x, y, h, xo, yo, ho, vo, y_range):
    """One laser's stripe rows -> the upsampled profile to add to its heightmap, in one call:

    * ``valid``: columns whose row continues into a neighbouring column within ``tol_px``
      (a stripe is a curve, isolated hits are noise); fewer than ``min_cols`` of them: no
      stripe in this frame, nothing else is done;
    * :func:`triangulate` into ``x``/``y``/``h``; single-column spikes dropped (a height farther
      than ``max_step`` from the median of itself and its two neighbours: steps survive, at a
      step the median follows one side);
    * :func:`upsample` into ``xo``/``yo``/``ho``/``vo``, and ``y_range`` = the least and
      greatest Y of the valid upsampled points (NaN if none).

    Returns the number of connected columns."""
    n = rows.shape[0]
    for c in range(n):
        valid[c] = False
    for c in range(n - 1):
        d = abs(rows[c + 1] - rows[c])
        if not math.isnan(d) and d <= tol_px:  # NaN rows never link
            valid[c] = True
            valid[c + 1] = True
    n_ok = 0
    for c in range(n):
        if valid[c]:
            n_ok += 1
    y_range[0] = np.nan
    y_range[1] = np.nan
    if n_ok < min_cols:
        return n_ok
    triangulate(rows, valid, band_start, rays, normal, offset, travel, row_mm, ref, x, y, h)
    # despiked heights; the columns kept are those with a finite one
    hd = np.empty(n)
    for c in range(n):
        hd[c] = h[c]
    for c in range(1, n - 1):
        a, b, e = h[c - 1], h[c], h[c + 1]
        med = _nanmax(_nanmin(a, b), _nanmin(_nanmax(a, b), e))
        if not math.isnan(med) and abs(b - med) > max_step:
            hd[c] = np.nan
    ok = np.empty(n, np.bool_)
    for c in range(n):
        ok[c] = valid[c] and not math.isnan(hd[c])
    upsample(x, y, hd, ok, k, max_step, xo, yo, ho, vo)
    lo = np.inf
    hi = -np.inf
    for i in range(vo.shape[0]):
        if vo[i]:
            lo = min(lo, yo[i])
            hi = max(hi, yo[i])
    if lo <= hi:
        y_range[0] = lo
        y_range[1] = hi
    return n_ok


# a weak stripe piece is kept where it lies on a chain of at least the long pieces' length:
# columns joined across gaps of at most this many missing columns, the rows either side within
# the pieces' own link (random rig 214 at 1080p: a dim red stripe on green soil, found in 95 %
# of its columns but in pieces of a few columns each, all dropped as weak: the map's largest
# hole, 1.6 % of the red map)
WEAK_CHAIN_GAP = 3


@_kernel("int64(float64[:], float32[:], float64, int64, float64, int64[:], float64[:])")
def prune_weak_runs(rows, strength, tol_px, long_cols, ratio, run_id, scratch):
    """Drop the short, weak pieces of a detected stripe (in place; returns the columns dropped).

    A *run* is a maximal set of consecutive columns whose rows continue into each other within
    ``tol_px`` (as :func:`stripe_profile` links them). The frame's typical stripe strength is
    the median strength over the runs at least ``long_cols`` long; a run shorter than that
    whose mean strength is below ``ratio`` times it is dropped (rows NaN, strength 0). With no
    long run nothing is dropped, nor a run on a *chain* of at least ``long_cols`` found columns
    (consecutive found columns joined across gaps of at most ``WEAK_CHAIN_GAP`` missing columns
    where their rows lie within ``tol_px``: the stripe, broken where it is faint). ``run_id``
    and ``scratch`` are work arrays as long as ``rows``.
    The numpy reference: :func:`impress_gui.core.reconstruction.stripes.prune_weak_runs_numpy`."""
    n = rows.shape[0]
    if n == 0 or ratio <= 0.0:
        return 0
    r = 0
    run_id[0] = 0
    for c in range(1, n):
        d = abs(rows[c] - rows[c - 1])
        if not (d <= tol_px):  # NaN on either side breaks the run
            r += 1
        run_id[c] = r
    n_runs = r + 1
    # runs in column order: [a, b) with their length, finite count and strength sum
    m = 0
    a = 0
    for c in range(1, n + 1):
        if c == n or run_id[c] != run_id[a]:
            if c - a >= long_cols:
                for q in range(a, c):
                    if not math.isnan(rows[q]):
                        scratch[m] = strength[q]
                        m += 1
            a = c
    if m == 0 or n_runs == 1:
        return 0
    ref = np.median(scratch[:m])
    # chains: the finite columns joined across gaps of at most WEAK_CHAIN_GAP missing columns
    # where the rows either side lie within tol_px; a run on a chain of at least long_cols
    # finite columns is kept
    chain = np.full(n, -1, np.int64)
    size = np.zeros(n, np.int64)
    last = -1
    cid = -1
    for c in range(n):
        if math.isnan(rows[c]):
            continue
        if not (last >= 0 and c - last <= WEAK_CHAIN_GAP + 1
                and abs(rows[c] - rows[last]) <= tol_px):
            cid += 1
        chain[c] = cid
        size[cid] += 1
        last = c
    dropped = 0
    a = 0
    for c in range(1, n + 1):
        if c == n or run_id[c] != run_id[a]:
            on_long = False
            for q in range(a, c):
                if chain[q] >= 0 and size[chain[q]] >= long_cols:
                    on_long = True
            if c - a < long_cols and not on_long:
                total = 0.0
                count = 0
                for q in range(a, c):
                    if not math.isnan(rows[q]):
                        total += strength[q]
                        count += 1
                if count > 0 and total < ratio * ref * count:
                    for q in range(a, c):
                        if not math.isnan(rows[q]):
                            rows[q] = np.nan
                            strength[q] = 0.0
                            dropped += 1
            a = c
    return dropped


@_kernel("int64(float64[:], float32[:], float64, int64)")
def drop_short_runs(rows, strength, tol_px, min_run):
    """Drop the stripe pieces shorter than ``min_run`` columns (in place: rows NaN, strength
    0; returns the columns dropped). A piece is a maximal run of consecutive columns whose rows
    continue into each other within ``tol_px``; single columns are left (:func:`stripe_profile`
    never takes them). The numpy reference:
    :func:`impress_gui.core.reconstruction.stripes.drop_short_runs_numpy`."""
    n = rows.shape[0]
    if min_run <= 2 or n == 0:
        return 0
    dropped = 0
    a = 0
    for c in range(1, n + 1):
        if c == n or not (abs(rows[c] - rows[c - 1]) <= tol_px):  # NaN breaks the run
            if 2 <= c - a < min_run:
                for q in range(a, c):
                    rows[q] = np.nan
                    strength[q] = 0.0
                    dropped += 1
            a = c
    return dropped


@_jit
def _add(total, count, x0, y0, g, x, y, v):
    j = int(np.rint((x - x0) / g))
    i = int(np.rint((y - y0) / g))
    if 0 <= i < count.shape[0] and 0 <= j < count.shape[1] and count[i, j] < 65535:
        total[i, j] += v
        count[i, j] += 1


@_kernel(
    "void(float32[:, :], uint16[:, :], float64, float64, float64, float64[:], float64[:], float64[:], boolean[:], float64[:], float64[:], float64[:], boolean[:], boolean, float64, float64, float64)"
)
def splat_heights(total, count, x0, y0, g, x, y, h, v, px, py, ph, pv, has_prev, max_gap,
                  max_step, reach):
    """Add one upsampled profile to the per-cell sums and counts, filling the strip towards
    the previous profile: each point pairs with the same point of the previous profile (the
    accumulator passes where each point was last found) when both are valid and closer than
    ``max_gap``; the segment between them is sampled at most one
    cell apart along each axis, so it leaves no cell out (linear heights, or the nearer end's
    across a step). Across a step each end's height reaches at most ``reach`` (mm) along the
    segment when ``reach`` is positive: the middle of a longer strip is left empty. Unpaired
    points are added alone."""
    hgt, wid = count.shape
    ig = 1.0 / g
    for i in range(x.shape[0]):
        if not v[i]:
            continue
        dx = x[i] - px[i] if has_prev else 0.0
        dy = y[i] - py[i] if has_prev else 0.0
        gap = math.hypot(dx, dy)
        if not (has_prev and pv[i] and gap <= max_gap):
            _add(total, count, x0, y0, g, x[i], y[i], h[i])
            continue
        n = max(1, int(math.ceil(max(abs(dx), abs(dy)) * ig)))
        step = abs(h[i] - ph[i]) > max_step
        # in cells: the previous end, and the step towards this point
        fx, fy = (px[i] - x0) * ig, (py[i] - y0) * ig
        sx, sy = dx * ig / n, dy * ig / n
        for m in range(1, n + 1):  # the previous end was added with the previous frame
            jj = int(np.rint(fx + m * sx))
            ii = int(np.rint(fy + m * sy))
            if not (0 <= ii < hgt and 0 <= jj < wid) or count[ii, jj] == 65535:
                continue
            t = m / n
            if step:
                if reach > 0.0 and min(t, 1.0 - t) * gap > reach:
                    continue  # farther than a frame's half travel from either end
                hv = ph[i] if t < 0.5 else h[i]
            else:
                hv = ph[i] + t * (h[i] - ph[i])
            total[ii, jj] += hv
            count[ii, jj] += 1


@_kernel(
    "void(uint8[:, :], uint8[:, :], uint8[:, :], int64, int64[:], int64[:], float64[:], float64[:], uint8[:, :])"
)
def sample_rgb(y, cb, cr, s, u0, v0, fu, fv, out):
    """Bilinear RGB of a frame's YCbCr planes at fixed sub-pixel positions (the texture row):
    ``u0``/``v0`` the top-left pixel, ``fu``/``fv`` the fractions; rounded to 8 bits."""
    sh = 1 if s == 2 else 0
    acc = np.empty(3)
    for i in range(u0.shape[0]):
        a, b = u0[i], v0[i]
        wu, wv = fu[i], fv[i]
        for q in range(3):
            acc[q] = 0.0
        for dv in range(2):
            for du in range(2):
                wgt = (wu if du else 1.0 - wu) * (wv if dv else 1.0 - wv)
                r, c = b + dv, a + du
                rgb = _rgb(float(y[r, c]), float(cb[r >> sh, c >> sh]), float(cr[r >> sh, c >> sh]))
                for q in range(3):
                    acc[q] += wgt * rgb[q]
        for q in range(3):  # as np.clip(acc + 0.5, 0, 255).astype(np.uint8)
            out[i, q] = np.uint8(min(max(acc[q] + 0.5, 0.0), 255.0))


# the grid's kernels
from impress_gui.core.reconstruction.grid_kernels import (  # noqa: E402
    band_rays,
    fuse_rows,
    mean_colours,
    mean_heights,
    resolve_conflicts,
    texture_rows,
)

__all__ = ["drop_short_runs", "detect_stripe", "triangulate", "upsample", "stripe_profile", "splat_heights", "sample_rgb",
           "hsv_tables", "fuse_rows", "mean_colours", "mean_heights", "resolve_conflicts",
           "texture_rows", "band_rays"]


# the soil seen unlit (``unlit.UnlitSoil``; its numpy reference ``unlit.refine_numpy``):
UNLIT_HALF = 6  # rows either side of the stripe re-estimated (the detector's half window)
UNLIT_REACH = 12.0  # px: a cut this close to either laser's stripe in the earlier frame is left
UNLIT_MIN_PEAK = 8.0  # grey levels: the difference's least peak
#: share of the unlit soil's texture (its cut less a straight line fitted to it) subtracted by
#: default: compressed video keeps only part of the soil's texture under a stripe (on the
#: renderer's uncompressed frames all of it is best), so taking all of it out puts some back,
#: inverted (docs/accuracy.md)
UNLIT_TEXTURE_WEIGHT = 0.7

# a wide stripe (issue 18, random rigs 14 and 71 at 1080p: a blooming green stripe whose
# profile has 8 rows above half maximum) carries its position in its flanks, beyond the
# window that :func:`_window_refine` may take without pulling in light beside narrower
# stripes: where the median column of a frame's refined stripe has at least GAUSS_MIN_ROWS rows
# above half maximum, each column's centre comes from a Gaussian on a constant floor fitted to
# the rows within GAUSS_HALF of its widths (clipped rows left out: :func:`_gauss_refine`); on
# narrower stripes the fit is less precise than the window (random rigs 0, 2, 7, 68)
GAUSS_MIN_ROWS = 6.0
GAUSS_HALF = 2.2
GAUSS_ITERATIONS = 40  # Levenberg-Marquardt steps at most ...
GAUSS_TOL = 1e-4  # ... ending when a step moves the centre less than this (rows)


@_jit
def _solve4(a, b, m):
    """Solve the ``m`` x ``m`` system ``a x = b`` in place (Gaussian elimination, partial
    pivoting); returns False where it is singular."""
    for i in range(m):
        piv = i
        for r in range(i + 1, m):
            if abs(a[r, i]) > abs(a[piv, i]):
                piv = r
        if abs(a[piv, i]) < 1e-12:
            return False
        if piv != i:
            for q in range(m):
                t = a[i, q]
                a[i, q] = a[piv, q]
                a[piv, q] = t
            t = b[i]
            b[i] = b[piv]
            b[piv] = t
        for r in range(i + 1, m):
            f = a[r, i] / a[i, i]
            for q in range(i, m):
                a[r, q] -= f * a[i, q]
            b[r] -= f * b[i]
    for i in range(m - 1, -1, -1):
        acc = b[i]
        for q in range(i + 1, m):
            acc -= a[i, q] * b[q]
        b[i] = acc / a[i, i]
    return True


@_jit
def _gauss_cost(rr, sig, n, use, a, c, s, b, e):
    """Sum of squared residuals of ``a exp(-(r - c)^2 / 2 s^2) + b`` over the rows ``use``;
    the exponentials into ``e``."""
    cost = 0.0
    for j in range(n):
        if use[j]:
            d = rr[j] - c
            e[j] = math.exp(-0.5 * d * d / (s * s))
            res = sig[j] - (a * e[j] + b)
            cost += res * res
    return cost


@_jit
def _gauss_refine(rr, sig, n, centre, clipped):
    """``stripes.gauss_refine`` of one column: a Gaussian on a constant floor fitted
    (Levenberg-Marquardt, a step taken only where it lowers the squared residuals) to the rows
    within ``GAUSS_HALF`` widths of ``centre``, clipped rows left out. Returns (centre,
    width); (``centre``, 0) where fewer than five rows are left or the fit fails."""
    if centre != centre:
        return centre, 0.0
    top = -1e300
    lo = 1e300
    for j in range(n):
        top = max(top, sig[j])
        lo = min(lo, sig[j])
    wc = 0
    for j in range(n):
        if sig[j] - lo > 0.5 * (top - lo):
            wc += 1
    s = min(max(wc / 2.355, 0.5), 4.0)
    hw = min(max(GAUSS_HALF * s, 2.5), 8.0)
    use = np.zeros(n, np.bool_)
    used = 0
    amp = -1e300
    b = 1e300
    for j in range(n):
        if abs(rr[j] - centre) <= hw and not clipped[j]:
            use[j] = True
            used += 1
            amp = max(amp, sig[j])
            b = min(b, sig[j])
    if used < 5:
        return centre, 0.0
    a = amp - b
    c = centre
    jt = np.empty((4, 4))
    m = np.empty((4, 4))
    rhs = np.empty(4)
    step = np.empty(4)
    e = np.zeros(n)
    e1 = np.zeros(n)
    cost = _gauss_cost(rr, sig, n, use, a, c, s, b, e)
    lam = 1e-3
    for _ in range(GAUSS_ITERATIONS):
        for p in range(4):
            rhs[p] = 0.0
            for q in range(4):
                jt[p, q] = 0.0
        for j in range(n):
            if not use[j]:
                continue
            d = rr[j] - c
            g = (e[j], a * e[j] * d / (s * s), a * e[j] * d * d / (s * s * s), 1.0)
            res = sig[j] - (a * e[j] + b)
            for p in range(4):
                rhs[p] += g[p] * res
                for q in range(4):
                    jt[p, q] += g[p] * g[q]
        for p in range(4):
            step[p] = rhs[p]
            for q in range(4):
                m[p, q] = jt[p, q]
            m[p, p] += lam * jt[p, p]
        if not _solve4(m, step, 4):
            return centre, 0.0
        a1 = a + step[0]
        c1 = c + min(max(step[1], -0.5), 0.5)
        s1 = min(max(s + min(max(step[2], -0.3), 0.3), 0.3), 6.0)
        b1 = b + step[3]
        cost1 = _gauss_cost(rr, sig, n, use, a1, c1, s1, b1, e1)
        if cost1 < cost:
            # converged: a step hardly damped that moves the centre less than GAUSS_TOL (a
            # heavily damped step is short however far the optimum)
            done = abs(c1 - c) < GAUSS_TOL and lam <= 1e-3
            a, c, s, b, cost = a1, c1, s1, b1, cost1
            for j in range(n):
                e[j] = e1[j]
            lam = max(lam * 0.1, 1e-7)
            if done:
                break
        else:
            lam *= 10.0
    if not (a > 0) or abs(c - centre) > 1.0 or c != c:
        return centre, 0.0
    return c, s


@_jit
def _unlit_window(diff, at, rows, rr, sig):
    """The ``2 UNLIT_HALF + 1`` values of ``diff`` around index ``at`` above their minimum into
    ``sig``, their image rows into ``rr``; returns (top, centre of mass above half maximum)."""
    n = 2 * UNLIT_HALF + 1
    lo = 1e300
    hi = -1e300
    for j in range(n):
        v = diff[at - UNLIT_HALF + j]
        sig[j] = v
        rr[j] = rows[at - UNLIT_HALF + j]
        lo = min(lo, v)
        hi = max(hi, v)
    top = hi - lo
    acc = 0.0
    ws = 0.0
    for j in range(n):
        sig[j] -= lo
        a = sig[j] - 0.5 * top
        if a > 0:
            ws += a
            acc += a * rr[j]
    return top, (acc / ws) if ws > 0 else np.nan


@_jit
def _texture_weighted(bg, nf, weight):
    """``bg`` (sums over ``nf`` frames) in place to its mean's straight-line fit plus
    ``weight`` times the rest."""
    n = bg.shape[0]
    sq = 0.0
    sqq = 0.0
    sb = 0.0
    sqb = 0.0
    for q in range(n):
        b = bg[q] / nf
        bg[q] = b
        sq += q
        sqq += q * q
        sb += b
        sqb += q * b
    slope = (n * sqb - sq * sb) / (n * sqq - sq * sq)
    icpt = (sb - slope * sq) / n
    for q in range(n):
        line = icpt + slope * q
        bg[q] = line + weight * (bg[q] - line)


@_kernel(
    "int64(float64[:], int64[:], float64[:, :, :], float64[:], float64, float64[:, :], "
    "float64[:, :], float64[:], boolean, uint8[:, :], uint8[:, :, :], int64[:], float64[:], "
    "float64[:, :, :], float64, float64)"
)
def unlit_refine(rows, band_start, rays, normal, offset, rot, kmat, dist, rational, y, ring,
                 slots, shifts, ring_rows, clip, weight):
    """``unlit.refine_numpy`` of one laser's stripe ``rows`` (full-image rows, NaN where none;
    re-estimated in place): per column, the ray through the row (``rays`` as in
    :func:`triangulate`) meets the laser plane; that point moved by ``shifts[i]`` along the
    rail's y (the travel from each earlier frame to this one) and projected (``rot``: camera ->
    rail, row vectors times ``rot``; ``kmat``/``dist``: the lens, ``rational`` for 8
    coefficients) gives its place in ring frame ``slots[i]``; the 17 rows around the stripe are
    sampled there (bilinear) and averaged over the frames, ``weight`` of its texture kept
    (:func:`_texture_weighted`), subtracted from this frame's, the run of rows at or above
    ``clip`` through the stripe's row set to the difference's top, and the centre estimated again (centre of
    mass above half maximum around the row, then around its own row, then
    :func:`_window_refine`). A column is left where a cut leaves the picture or lies within
    ``UNLIT_REACH`` of a stripe row of that frame (``ring_rows[slot, laser, column]``), where
    the difference's peak is under ``UNLIT_MIN_PEAK``, or where the new centre lies
    ``UNLIT_HALF - 1`` rows or more from the old. Returns the columns re-estimated."""
    h = y.shape[0]
    w = y.shape[1]
    nf = slots.shape[0]
    nc = 2 * UNLIT_HALF + 5
    mid = UNLIT_HALF + 2
    bg = np.empty(nc)
    diff = np.empty(nc)
    crow = np.empty(nc)
    rr = np.empty(2 * UNLIT_HALF + 1)
    sig = np.empty(2 * UNLIT_HALF + 1)
    kept_sig = np.empty((rows.shape[0], 2 * UNLIT_HALF + 1))
    kept_clip = np.zeros((rows.shape[0], 2 * UNLIT_HALF + 1), np.bool_)
    kept_rr0 = np.empty(rows.shape[0])
    kept_col = np.empty(rows.shape[0], np.int64)
    kept_wc = np.empty(rows.shape[0])
    kept_old = np.empty(rows.shape[0])
    k1, k2, p1, p2, k3 = dist[0], dist[1], dist[2], dist[3], dist[4]
    k4, k5, k6 = dist[5], dist[6], dist[7]
    count = 0
    for c in range(rows.shape[0]):
        r = rows[c]
        if math.isnan(r):
            continue
        px, py, pz = _lit_point(r - band_start[c], rays, c, normal, offset)
        if math.isnan(px):
            continue
        r0 = int(math.floor(r + 0.5))
        if r0 - mid < 0 or r0 + mid > h - 1:
            continue
        for q in range(nc):
            bg[q] = 0.0
            crow[q] = r0 - mid + q
        ok = True
        for i in range(nf):
            s = slots[i]
            qy = py + shifts[i]
            cx = px * rot[0, 0] + qy * rot[1, 0] + pz * rot[2, 0]
            cy = px * rot[0, 1] + qy * rot[1, 1] + pz * rot[2, 1]
            cz = px * rot[0, 2] + qy * rot[1, 2] + pz * rot[2, 2]
            if not cz > 0:
                ok = False
                break
            xn = cx / cz
            yn = cy / cz
            r2 = xn * xn + yn * yn
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            if rational:
                radial = radial / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
            xd = xn * radial + 2.0 * p1 * xn * yn + p2 * (r2 + 2.0 * xn * xn)
            yd = yn * radial + p1 * (r2 + 2.0 * yn * yn) + 2.0 * p2 * xn * yn
            u = kmat[0, 0] * xd + kmat[0, 1] * yd + kmat[0, 2]
            v = kmat[1, 1] * yd + kmat[1, 2]
            if not (u >= 0.0 and u <= w - 1 and v - UNLIT_HALF - 3 >= 0.0
                    and v + UNLIT_HALF + 3 <= h - 1):
                ok = False
                break
            cu = min(max(int(math.floor(u + 0.5)), 0), w - 1)
            for m in range(ring_rows.shape[1]):
                other = ring_rows[s, m, cu]
                if not math.isnan(other) and abs(other - v) <= UNLIT_REACH:
                    ok = False
            if not ok:
                break
            u0 = min(int(math.floor(u)), w - 2)
            fu = u - u0
            for q in range(nc):
                yy = v + crow[q] - r
                v0 = min(max(int(math.floor(yy)), 0), h - 2)
                fv = yy - v0
                a = ring[s, v0, u0] * (1.0 - fu) + ring[s, v0, u0 + 1] * fu
                b = ring[s, v0 + 1, u0] * (1.0 - fu) + ring[s, v0 + 1, u0 + 1] * fu
                bg[q] += a * (1.0 - fv) + b * fv
        if not ok:
            continue
        _texture_weighted(bg, nf, weight)
        top_all = -1e300
        for q in range(nc):
            diff[q] = y[r0 - mid + q, c] - bg[q]
            top_all = max(top_all, diff[q])
        # the clipped core: the run of rows at or above ``clip`` through the detector's row
        # (a grain of bright soil beside the stripe may reach ``clip`` too: not the core)
        if y[r0, c] >= clip:
            lo = mid
            while lo > 0 and y[r0 - mid + lo - 1, c] >= clip:
                lo -= 1
            hi = mid
            while hi < nc - 1 and y[r0 - mid + hi + 1, c] >= clip:
                hi += 1
            for q in range(lo, hi + 1):
                diff[q] = top_all
        top, centre = _unlit_window(diff, mid, crow, rr, sig)
        at = mid
        if not math.isnan(centre):
            at = min(max(mid + int(math.floor(centre - crow[mid] + 0.5)), UNLIT_HALF),
                     nc - 1 - UNLIT_HALF)
        top, centre = _unlit_window(diff, at, crow, rr, sig)
        if not (top >= UNLIT_MIN_PEAK) or math.isnan(centre):
            continue
        new = _window_refine(rr, sig, 2 * UNLIT_HALF + 1, top, centre)
        if math.isnan(new) or abs(new - r) > UNLIT_HALF - 1:
            continue
        # kept for the fit of a wide stripe: the window, its clipped rows, its rows above
        # half maximum
        nwc = 0
        for j in range(2 * UNLIT_HALF + 1):
            kept_sig[count, j] = sig[j]
            kept_clip[count, j] = y[int(rr[j]), c] >= clip
            if sig[j] > 0.5 * top:
                nwc += 1
        kept_rr0[count] = rr[0]
        kept_col[count] = c
        kept_wc[count] = nwc
        kept_old[count] = r
        rows[c] = new
        count += 1
    if count > 0 and np.median(kept_wc[:count]) >= GAUSS_MIN_ROWS:
        for i in range(count):
            c = kept_col[i]
            for j in range(2 * UNLIT_HALF + 1):
                rr[j] = kept_rr0[i] + j
            fit, width = _gauss_refine(rr, kept_sig[i], 2 * UNLIT_HALF + 1, rows[c],
                                       kept_clip[i])
            if width > 0 and abs(fit - kept_old[i]) <= UNLIT_HALF - 1:
                rows[c] = fit
    return count
