"""The two lasers' agreement across the map: a check of the calibration without ground truth.

Both lasers sweep the same surface, so where both measured a cell their heights differ only by
noise, unless a laser plane is off. A plane turned about an axis in it across its stripe (a
"twist": the calibration's target and the ground beside it span a few centimetres of the
stripe, the map the whole picture) makes that laser read high on one side of the picture and
low on the other; a plane turned about the stripe scales its heights. The surface itself
cancels in the difference, so a straight fit of the difference against the map's x, y and
height shows each (random rigs 203 and 250 at 1080p: the red plane's twist, 0.020 and
-0.012 mm per 100 mm of x against the simulator's truth, shows as the lasers' difference;
docs/accuracy.md, "The lasers' agreement across the map").
"""

from __future__ import annotations

import numpy as np

from impress_gui.core.reconstruction.grid import GridSpec

#: the difference is sampled on every STEP-th row and column at least (the map's cells are
#: 0.1 mm; a fit of three slopes needs far fewer than all of them, and the difference of two
#: full maps would cost a map's memory), more sparsely on a map so large that more than
#: MAX_SAMPLES cells would be sampled (a tire track's 1.75 m)
STEP = 4
MAX_SAMPLES = 1_000_000
#: fewer cells where both lasers measured than this: no figures
MIN_CELLS = 500
#: a cell whose difference lies further than this from the fit (mm; and than 5 robust SDs) is
#: left out of the next round (an edge one laser saw and the other did not)
OUTLIER_MM = 0.05
#: the lasers' difference changing by more than this (mm) across the map's cells where both
#: measured, along x or with height, is warned of (W-LASERS-DIVERGE)
DIVERGE_MM = 0.05
#: a difference that reaches more than this (mm) over the cells the fit kept is not
#: reconciled: beyond a plane turned by a tenth of a degree (0.08 deg on the flat preset at
#: 640x360: 1.0 mm across 278 mm), the fit is more likely taken by something other than the
#: planes; the warning then stands alone
RECONCILE_MAX_MM = 2.0
#: rows of a map corrected at a time (the working memory is a block, not a map)
BLOCK_ROWS = 1024


def laser_agreement(green: np.ndarray, red: np.ndarray, spec: GridSpec) -> dict | None:
    """The green minus red height difference where both maps hold a value, fitted as
    ``a + b x + c y + e h`` (``h`` the lasers' mean height; x, y in mm about the cells'
    centre) with outliers left out: ``cells`` (sampled), ``offset_mm`` (a, at the centre),
    ``x_mm_per_100mm``, ``y_mm_per_100mm`` (b, c per 100 mm), ``height_pct`` (e in %),
    ``x_span_mm``, ``height_span_mm`` (the extents of the cells the fit kept), ``across_mm``,
    ``with_height_mm`` (the change the slopes make over those extents) and ``rms_mm`` (the
    difference about the fit). None when too few cells or too little extent."""
    step = max(STEP, int(np.ceil(np.sqrt(green.size / MAX_SAMPLES))))
    g = np.asarray(green[::step, ::step], np.float64)
    r = np.asarray(red[::step, ::step], np.float64)
    ok = np.isfinite(g) & np.isfinite(r)
    if ok.sum() < MIN_CELLS:
        return None
    i, j = np.nonzero(ok)
    x = spec.x0_mm + spec.pixel_mm * step * j
    y = spec.y0_mm + spec.pixel_mm * step * i
    d = (g - r)[ok]
    h = 0.5 * (g + r)[ok]
    x_span, h_span = float(np.ptp(x)), float(np.ptp(h))
    if x_span < 10.0:
        return None
    cols = [np.ones_like(d), x - x.mean(), y - y.mean()]
    use_h = h_span >= 1.0  # a flat map: the height's slope is not determined
    if use_h:
        cols.append(h - h.mean())
    a = np.column_stack(cols)
    keep = np.abs(d - np.median(d)) <= max(OUTLIER_MM, 5 * 1.4826 * _mad(d))
    coef = np.zeros(a.shape[1])
    for _ in range(3):
        if keep.sum() < MIN_CELLS:
            return None
        coef = np.linalg.lstsq(a[keep], d[keep], rcond=None)[0]
        res = d - a @ coef
        keep = np.abs(res) <= max(OUTLIER_MM, 5 * 1.4826 * _mad(res[keep]))
    res = (d - a @ coef)[keep]
    # the extents of the cells the fit kept (an edge one laser alone saw is not the surface)
    x_span, h_span = float(np.ptp(x[keep])), float(np.ptp(h[keep]))
    b, c = float(coef[1]), float(coef[2])
    e = float(coef[3]) if use_h else 0.0
    return {"cells": int(keep.sum()), "offset_mm": float(coef[0]),
            "x_mm_per_100mm": 100.0 * b, "y_mm_per_100mm": 100.0 * c,
            "height_pct": 100.0 * e, "x_span_mm": x_span,
            "height_span_mm": h_span, "across_mm": abs(b) * x_span,
            "with_height_mm": abs(e) * h_span, "rms_mm": float(np.sqrt(np.mean(res ** 2))),
            # where the fit is centred and the extents it holds over (the reconciliation
            # evaluates it there: :func:`reconcile`)
            "x_centre_mm": float(x.mean()), "height_centre_mm": float(h.mean()),
            "x_min_mm": float(x[keep].min()), "x_max_mm": float(x[keep].max()),
            "height_min_mm": float(h[keep].min()), "height_max_mm": float(h[keep].max())}


def reconcile(per: dict[str, np.ndarray], spec: GridSpec, agreement: dict | None,
              weight_green: float, block_rows: int = BLOCK_ROWS) -> dict | None:
    """Bring each laser's map, in place, to the two lasers' weighted consensus across the
    map: the part of their fitted difference (:func:`laser_agreement`) that runs along x,
    ``D = a + b (x - x0)``, is shared between the lasers in proportion to their expected
    error, green taking ``1 - weight_green`` of it and red ``weight_green`` (the fusion's
    inverse-variance weight, ``reconstruct.fusion_weight``): green ``-= (1 - w) D``, red
    ``+= w D``. Where both lasers measured, their weighted mean, the fused height, is
    unchanged; where one alone did (the scan's ends, its shadows), its height moves to what
    the pair would have read there. A laser plane turned about an axis across its stripe
    (the calibration's target spans a few centimetres of the picture: random rigs 203 and
    250 at 1080p, red 0.011 mm low on average) no longer makes the cells one laser saw alone
    read high on one side of the picture and low on the other.

    The difference's change with height and along y is not shared: the target's faces of
    known heights fix each plane's height scale, and that term of the fit also takes what
    the two lasers see differently on a surface's slopes (random rig 254: the fit's height
    term 0.05 % where the planes differ by 0.006 %); along y no plane error runs. x is held to
    the extent the fit kept (no extrapolation). Returns what was done (``green_share``;
    ``largest_mm``, the largest shift of either map over that extent) or None when there is
    no fit or the difference changes by more than :data:`RECONCILE_MAX_MM` over it."""
    if agreement is None:
        return None
    a = float(agreement["offset_mm"])
    b = float(agreement["x_mm_per_100mm"]) / 100.0
    x0 = float(agreement["x_centre_mm"])
    x_lo, x_hi = float(agreement["x_min_mm"]), float(agreement["x_max_mm"])
    largest = max(abs(a + b * (x_lo - x0)), abs(a + b * (x_hi - x0)))  # a straight line
    if not np.isfinite(largest) or largest > RECONCILE_MAX_MM:
        return None
    w = float(weight_green)
    # the difference per column (float32, as the maps)
    d = (a + b * (np.clip(spec.xs(), x_lo, x_hi) - x0)).astype(np.float32)
    for name, k in (("green", -(1.0 - w)), ("red", w)):
        m = per[name]
        step = (np.float32(k) * d)[None, :]
        for lo in range(0, m.shape[0], block_rows):
            m[lo:lo + block_rows] += step  # NaN stays NaN
    return {"green_share": round(1.0 - w, 5), "largest_mm": round(largest * max(w, 1.0 - w), 5)}


def _mad(v: np.ndarray) -> float:
    return float(np.median(np.abs(v - np.median(v)))) if v.size else 0.0


def agreement_warnings(agreement: dict | None) -> list[str]:
    """W-LASERS-DIVERGE when the lasers' difference changes by more than :data:`DIVERGE_MM`
    across the map or with height."""
    if agreement is None:
        return []
    out = []
    if agreement["across_mm"] > DIVERGE_MM:
        out.append(
            f"W-LASERS-DIVERGE: the green and red heights differ by "
            f"{agreement['across_mm']:.3f} mm more at one side of the map than at the other "
            f"({agreement['x_mm_per_100mm']:+.4f} mm per 100 mm across the scan, over "
            f"{agreement['x_span_mm']:.0f} mm): a laser plane of the calibration is turned "
            "(the target spans only part of the picture); heights far from where the target "
            "stood may be off by up to that much. Calibrate again with the target nearer the "
            "middle of the picture, or compare with a known object there")
    if agreement["with_height_mm"] > DIVERGE_MM:
        out.append(
            f"W-LASERS-DIVERGE: the green and red heights differ by "
            f"{agreement['with_height_mm']:.3f} mm more at the top of the surface than at its "
            f"bottom ({agreement['height_pct']:+.3f} % of the height, over "
            f"{agreement['height_span_mm']:.1f} mm): a laser plane's angle in the calibration "
            "is off; depths are scaled by up to that much")
    return out
