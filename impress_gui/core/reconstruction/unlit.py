"""The soil under the stripe, seen unlit in earlier frames, taken out of the stripe's profile
before its centre is estimated (issue 18: dim stripes on grainy soil).

A dim stripe on light, grainy soil is a bump of a few tens of grey levels on a surface whose
luma changes as much over the same few rows: the soil's texture shapes the profile as much as
the laser's light does, and the centre of mass follows it (random rig 90 at 1080p: 0.60 px RMS,
16 % of the red stripe's columns more than a pixel off; docs/accuracy.md, "Dim stripes on grainy
soil"). The camera and the lasers ride the carriage together, so the surface point lit in frame
k was in view, unlit, a few frames earlier, moved along the motion. Its place there follows
from the stripe itself: the detected row's ray meets the laser plane at the lit point (its
depth, not the ground's: a 30 mm relief at 300 mm would be 10 % of the shift off), the
calibrated travel between the frames moves it, the calibrated lens projects it. The column of
rows around the stripe is cut there from five consecutive earlier frames (their sensor noise
averaged), subtracted, and the centre estimated again on the difference, with the detector's
own estimator (centre of mass above half maximum, re-centred once, then
:func:`~impress_gui.core.reconstruction.stripes.window_refine`). Rows whose luma is clipped
keep the difference's top: under a clipped core there is no texture to take out, and
subtracting it there would put the texture back, inverted.

Left as the detector found it: a column whose earlier place would leave the picture or lie
within reach of either laser's stripe in that frame, or whose difference has no peak of
:data:`MIN_PEAK` grey levels inside the window; every column while the carriage has not yet
moved :data:`SHIFT_PX` pixels' worth (the start of a scan, a stop).
"""

from __future__ import annotations

import cv2
import numpy as np

from impress_gui.core.reconstruction.stripes import window_refine

#: least shift (pixels, along the image) of the soil's place in the earlier frame from the
#: stripe's row: twice the detector's window and a stripe's width, so the stripe of that frame
#: stays out of the cut
SHIFT_PX = 24.0
#: earlier frames averaged on either side of the chosen one (five in all)
SIDE_FRAMES = 2
#: luma at or above which a row counts as clipped
CLIP = 225.0
#: rows either side of the stripe's row that are re-estimated (the detector's half window)
HALF = 6
#: the difference's least peak (grey levels) for a column to be re-estimated
MIN_PEAK = 8.0
#: frames of luma kept at most (a slow carriage at 1080p moves the soil 0.7 px a frame: 35
#: frames for :data:`SHIFT_PX`; 80 MB of luma at 1080p)
RING_FRAMES = 48


class UnlitSoil:
    """The earlier frames' luma and stripe rows, and the re-estimate of a frame's stripe.

    ``rays``/``bands``: the frame loop's per-laser tables (rail-frame rays through every
    column's band rows, the band's first row per column); ``travel``: the camera's travel (mm)
    of every frame; ``rotation``: camera -> rail frame; ``intrinsics``: the calibrated lens."""

    def __init__(self, intrinsics, rotation: np.ndarray, travel: np.ndarray,
                 rays: dict[str, np.ndarray], bands: dict[str, tuple[np.ndarray, int]],
                 planes: dict, size: tuple[int, int]) -> None:
        self.intr = intrinsics
        self.rot = np.asarray(rotation, float)
        self.travel = np.asarray(travel, float)
        self.rays = rays
        self.bands = bands
        self.planes = planes
        self.width, self.height = size
        self.luma: dict[int, np.ndarray] = {}
        self.rows: dict[int, dict[str, np.ndarray]] = {}
        self.refined = dict.fromkeys(rays, 0)
        self.offset = np.arange(-HALF - 2, HALF + 3, dtype=np.float64)  # rows cut (17)

    # ----- the ring of earlier frames ---------------------------------------------------
    def keep(self, k: int, luma: np.ndarray, rows: dict[str, np.ndarray]) -> None:
        """Frame ``k``'s luma and final stripe rows, for the frames after it."""
        self.luma[k] = np.array(luma, copy=True)
        self.rows[k] = {n: np.array(r, copy=True) for n, r in rows.items()}
        for old in [i for i in self.luma if i <= k - RING_FRAMES]:
            del self.luma[old], self.rows[old]

    def skip(self, k: int) -> None:
        """Frame ``k`` was not read whole (damaged): no frame after it uses it."""
        self.luma.pop(k, None)
        self.rows.pop(k, None)

    def _source(self, k: int, depth: float) -> int | None:
        """The earlier frame whose soil lies :data:`SHIFT_PX` or more from frame ``k``'s
        stripe (at ``depth`` mm), with its :data:`SIDE_FRAMES` neighbours all kept."""
        f = float(self.intr.fx)
        for j in range(1, RING_FRAMES - SIDE_FRAMES):
            kk = k - j
            if kk - SIDE_FRAMES not in self.luma:
                return None
            if f * abs(self.travel[k] - self.travel[kk]) / depth >= SHIFT_PX:
                if all(i in self.luma for i in range(kk - SIDE_FRAMES, kk + SIDE_FRAMES + 1)):
                    return kk
                return None
        return None

    # ----- one laser's stripe in one frame ----------------------------------------------
    def refine(self, name: str, k: int, luma: np.ndarray, rows: np.ndarray) -> int:
        """Re-estimate laser ``name``'s stripe ``rows`` (full-image rows per column, NaN where
        none) of frame ``k`` in place; returns the number of columns re-estimated."""
        cols = np.flatnonzero(np.isfinite(rows))
        if cols.size == 0:
            return 0
        r = rows[cols]
        b0, _ = self.bands[name]
        rays = self.rays[name]
        t = r - b0[cols]
        j = np.clip(np.floor(t).astype(np.int64), 0, rays.shape[1] - 2)
        f = (t - j)[:, None]
        d = rays[cols, j] + f * (rays[cols, j + 1] - rays[cols, j])
        pl = self.planes[name]
        den = d @ np.asarray(pl.normal, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = float(pl.offset_mm) / den
        p = lam[:, None] * d  # the lit points, rail frame, relative to the camera
        ok = np.isfinite(p).all(axis=1) & (p[:, 2] > 0)
        if not ok.any():
            return 0
        depth = float(np.median((p[ok] @ self.rot)[:, 2]))
        src = self._source(k, depth) if depth > 0 else None
        if src is None:
            return 0
        h, w = luma.shape
        r0 = np.rint(r).astype(np.int64)
        ok &= (r0 - HALF - 2 >= 0) & (r0 + HALF + 2 <= h - 1)
        rows_cut = r0[:, None] + self.offset[None, :].astype(np.int64)  # (n, 17)
        rel = rows_cut - r[:, None]  # the cut's rows relative to the stripe's sub-pixel row
        bg = np.zeros(rows_cut.shape, np.float64)
        for kk in range(src - SIDE_FRAMES, src + SIDE_FRAMES + 1):
            moved = p.copy()
            moved[:, 1] += self.travel[k] - self.travel[kk]
            cam = moved @ self.rot
            with np.errstate(divide="ignore", invalid="ignore"):
                u, v = self.intr.distort_normalized(cam[:, 0] / cam[:, 2], cam[:, 1] / cam[:, 2])
            ok &= np.isfinite(u) & np.isfinite(v) & (cam[:, 2] > 0)
            ok &= (u >= 0) & (u <= w - 1) & (v - HALF - 3 >= 0) & (v + HALF + 3 <= h - 1)
            ok &= self._clear(kk, u, v)
            mx = np.broadcast_to(np.nan_to_num(u)[:, None], rel.shape).astype(np.float32)
            my = (np.nan_to_num(v)[:, None] + rel).astype(np.float32)
            bg += cv2.remap(self.luma[kk], mx, my, cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_REPLICATE).astype(np.float64)
        bg /= 2 * SIDE_FRAMES + 1
        if not ok.any():
            return 0
        sel = np.flatnonzero(ok)
        cut = luma[rows_cut[sel], cols[sel, None]].astype(np.float64)
        new = _estimate(cut, bg[sel], rows_cut[sel].astype(np.float64))
        good = np.isfinite(new) & (np.abs(new - r[sel]) <= HALF - 1)
        rows[cols[sel[good]]] = new[good]
        n = int(good.sum())
        self.refined[name] += n
        return n

    def _clear(self, kk: int, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Where the cut around ``(u, v)`` in frame ``kk`` keeps clear of both lasers'
        stripes of that frame (their rows in the nearest column; a column where a laser's
        stripe was not found counts as clear)."""
        c = np.clip(np.rint(np.nan_to_num(u)).astype(np.int64), 0, self.width - 1)
        clear = np.ones(u.shape, bool)
        reach = HALF + 3 + 3.0  # the cut's half height, and a stripe's half width
        for rows in self.rows[kk].values():
            rr = rows[c]
            clear &= ~(np.abs(rr - v) <= reach)
        return clear


def _estimate(cut: np.ndarray, bg: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """The detector's estimate on the luma ``cut`` ``(n, 17)`` less the unlit soil ``bg``:
    clipped rows at the difference's top; the centre of mass above half maximum in the window
    of :data:`HALF` rows around the middle, then around its own row, refined. NaN where the
    difference has no peak of :data:`MIN_PEAK`."""
    diff = cut - bg
    top_all = diff.max(axis=1, keepdims=True)
    diff = np.where(cut >= CLIP, top_all, diff)
    n = diff.shape[0]
    idx = np.arange(n)[:, None]
    mid = HALF + 2

    def window(at: np.ndarray):
        ii = at[:, None] + np.arange(-HALF, HALF + 1)[None, :]
        sig = diff[idx, ii]
        sig = sig - sig.min(axis=1, keepdims=True)
        top = sig.max(axis=1)
        above = np.clip(sig - 0.5 * top[:, None], 0.0, None)
        rr = rows[idx, ii]
        with np.errstate(invalid="ignore", divide="ignore"):
            centre = (above * rr).sum(axis=1) / above.sum(axis=1)
        return rr, sig, top, centre

    rr, sig, top, centre = window(np.full(n, mid))
    shift = np.rint(np.nan_to_num(centre - rows[:, mid])).astype(np.int64)
    at = np.clip(mid + shift, HALF, 2 * mid - HALF)
    rr, sig, top, centre = window(at)
    out = window_refine(rr.T, sig.T, top, centre)
    return np.where((top >= MIN_PEAK) & np.isfinite(out), out, np.nan)
