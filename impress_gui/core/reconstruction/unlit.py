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
averaged), its straight-line fit and ``kernels.UNLIT_TEXTURE_WEIGHT`` (0.7) of the rest (the
texture) subtracted - compressed video keeps only part of the soil's texture under a bright
stripe, so all of it taken out would put some back, inverted (on the renderer's uncompressed
frames all of it is best) - and the centre estimated again on the difference, with the detector's
own estimator (centre of mass above half maximum, re-centred once, then
:func:`~impress_gui.core.reconstruction.stripes.window_refine`). A wide stripe - the frame's
median column with ``kernels.GAUSS_MIN_ROWS`` (6) or more rows above half maximum, a blooming
laser - is then placed by a Gaussian fitted to each column's difference, its clipped rows left
out (:func:`wide_stripe`, :func:`~impress_gui.core.reconstruction.stripes.gauss_refine`): its
position is in the flanks, which the window, capped for narrower stripes, leaves out (random
rigs 14 and 71 at 1080p: the green laser's error 0.089 -> 0.054 and 0.090 -> 0.071 mm); on
narrower stripes the fit is less precise than the window and is not used. The run of clipped rows
through the stripe's row keeps the difference's top: under a clipped core there is no texture
to take out, and subtracting it there would put the texture back, inverted. A grain of bright
soil beside the stripe that reaches the clipping level is not the core: it keeps its
difference (taken as core, it pulled the centre up to 3 px on random rig 13's white soil).

Left as the detector found it: a column whose earlier place would leave the picture or lie
within reach of either laser's stripe in that frame, whose difference has no peak of
``kernels.UNLIT_MIN_PEAK`` grey levels, or whose new centre lies ``kernels.UNLIT_HALF - 1``
rows or more from the detector's; every column while the carriage has not yet moved
:data:`SHIFT_PX` pixels' worth (the start of a scan, a stop) and where a damaged frame is
among the five. The steps run in a compiled kernel (``kernels.unlit_refine``); its numpy
reference is :func:`refine_numpy`.

On by default (``ProcessParams.unlit_soil``; ``impress process --no-unlit-soil`` turns it
off): with 0.7 of the texture taken out, better on 17 of 24 random rigs and worse on none,
much better on grainy soil; on the test suite's white blocks the flat tops are 0.002 mm
worse and the edges beside a slot's walls closer to the truth (docs/accuracy.md, "Part of
the texture").
"""

from __future__ import annotations

import math

import numpy as np

from impress_gui.core.reconstruction.stripes import gauss_refine, run_through, window_refine

#: least shift (pixels, along the image) of the soil's place in the earlier frame from the
#: stripe's row: twice the detector's window and a stripe's width, so the stripe of that frame
#: stays out of the cut
SHIFT_PX = 24.0
#: earlier frames averaged on either side of the chosen one (five in all)
SIDE_FRAMES = 2
#: luma at or above which a row counts as clipped
CLIP = 225.0
#: frames of luma kept at most (a slow carriage at 1080p moves the soil 0.7 px a frame: 35
#: frames for :data:`SHIFT_PX`; 100 MB of luma at 1080p); fewer when the carriage's speed
#: needs fewer (:meth:`UnlitSoil.ring_size`)
RING_FRAMES = 48


def _k():
    from impress_gui.core.reconstruction.compiled import kernels

    return kernels()


class UnlitSoil:
    """The earlier frames' luma and stripe rows (a ring), and the re-estimate of a frame's
    stripe.

    ``rays``/``bands``: the frame loop's per-laser tables (rail-frame rays through every
    column's band rows, the band's first row per column); ``travel``: the camera's travel (mm)
    of every frame; ``rotation``: camera -> rail frame; ``intrinsics``: the calibrated lens;
    ``depth_mm``: the ground's depth (sizes the ring); ``compiled``: the kernel
    (``kernels.unlit_refine``) or its numpy reference (:func:`refine_numpy`);
    ``texture_weight``: the share of the unlit soil's texture taken out (by default
    ``kernels.UNLIT_TEXTURE_WEIGHT``, for compressed video)."""

    def __init__(self, intrinsics, rotation: np.ndarray, travel: np.ndarray,
                 rays: dict[str, np.ndarray], bands: dict[str, tuple[np.ndarray, int]],
                 planes: dict, size: tuple[int, int], depth_mm: float,
                 compiled: bool = True, texture_weight: float | None = None) -> None:
        self.intr = intrinsics
        self.rot = np.ascontiguousarray(rotation, np.float64)
        self.travel = np.asarray(travel, float)
        self.rays = rays
        self.bands = bands
        self.planes = planes
        self.names = list(rays)
        self.width, self.height = size
        self.compiled = compiled
        from impress_gui.core.reconstruction import kernels as kn

        self.texture_weight = float(kn.UNLIT_TEXTURE_WEIGHT if texture_weight is None
                                    else texture_weight)
        self.refined = dict.fromkeys(rays, 0)
        self.kmat = np.ascontiguousarray(intrinsics.camera_matrix, np.float64)
        dc = np.asarray(intrinsics.dist_coeffs, float).ravel()
        self.dist = np.zeros(8)
        self.dist[: min(dc.size, 8)] = dc[:8]
        self.rational = dc.size == 8
        self.n_ring = self.ring_size(depth_mm)
        self.ring: np.ndarray | None = None  # (n_ring, H, W) uint8, allocated on first use
        self.ring_rows = np.full((self.n_ring, len(self.names), self.width), np.nan)
        self.held = np.full(self.n_ring, -1, np.int64)  # the frame in each slot (-1: none)

    def ring_size(self, depth_mm: float) -> int:
        """Frames kept: enough for :data:`SHIFT_PX` at the scan's typical speed (the median
        travel per frame), its :data:`SIDE_FRAMES` and a margin; at most :data:`RING_FRAMES`."""
        steps = np.abs(np.diff(self.travel))
        step = float(np.median(steps[steps > 0])) if (steps > 0).any() else 0.0
        if step <= 0 or not depth_mm > 0:
            return RING_FRAMES
        j = math.ceil(SHIFT_PX * depth_mm / (float(self.intr.fx) * step))
        return int(min(RING_FRAMES, j + 2 * SIDE_FRAMES + 6))

    # ----- the ring of earlier frames ---------------------------------------------------
    def keep(self, k: int, luma: np.ndarray, rows: dict[str, np.ndarray]) -> None:
        """Frame ``k``'s luma and final stripe rows, for the frames after it."""
        if self.ring is None or self.ring.shape[1:] != luma.shape:
            self.ring = np.zeros((self.n_ring, *luma.shape), np.uint8)
            self.held[:] = -1
        s = k % self.n_ring
        self.ring[s] = luma
        for m, name in enumerate(self.names):
            self.ring_rows[s, m] = rows[name]
        self.held[s] = k

    def skip(self, k: int) -> None:
        """Frame ``k`` was not read whole (damaged): no frame after it uses it."""
        s = k % self.n_ring
        self.held[s] = -1
        self.ring_rows[s] = np.nan

    def _has(self, k: int) -> bool:
        return k >= 0 and bool(self.held[k % self.n_ring] == k)

    def _source(self, k: int, depth: float) -> int | None:
        """The earlier frame whose soil lies :data:`SHIFT_PX` or more from frame ``k``'s
        stripe (at ``depth`` mm), with its :data:`SIDE_FRAMES` neighbours all kept."""
        f = float(self.intr.fx)
        for j in range(1, self.n_ring):
            kk = k - j
            if not self._has(kk - SIDE_FRAMES):
                return None
            if f * abs(self.travel[k] - self.travel[kk]) / depth >= SHIFT_PX:
                if all(self._has(i) for i in range(kk - SIDE_FRAMES, kk + SIDE_FRAMES + 1)):
                    return kk
                return None
        return None

    # ----- one laser's stripe in one frame ----------------------------------------------
    def refine(self, name: str, k: int, luma: np.ndarray, rows: np.ndarray) -> int:
        """Re-estimate laser ``name``'s stripe ``rows`` (full-image rows per column, NaN where
        none) of frame ``k`` in place; returns the number of columns re-estimated."""
        if self.ring is None or self.ring.shape[1:] != luma.shape:
            return 0
        depth = self._depth(name, rows)
        src = self._source(k, depth) if depth > 0 else None
        if src is None:
            return 0
        frames = np.arange(src - SIDE_FRAMES, src + SIDE_FRAMES + 1)
        slots = (frames % self.n_ring).astype(np.int64)
        shifts = self.travel[k] - self.travel[frames]
        b0, _ = self.bands[name]
        pl = self.planes[name]
        args = (rows, np.ascontiguousarray(b0, np.int64), self.rays[name],
                np.ascontiguousarray(pl.normal, np.float64), float(pl.offset_mm), self.rot,
                self.kmat, self.dist, self.rational, luma, self.ring, slots, shifts,
                self.ring_rows, CLIP, self.texture_weight)
        n = int(_k().unlit_refine(*args) if self.compiled else refine_numpy(*args))
        self.refined[name] += n
        return n

    def _depth(self, name: str, rows: np.ndarray) -> float:
        """The camera depth (mm) of the stripe's lit points, median over every 16th column
        found (0 if none)."""
        cols = np.flatnonzero(np.isfinite(rows))[::16]
        if cols.size == 0:
            return 0.0
        p = _lit_points(rows[cols], cols, self.bands[name][0], self.rays[name],
                        self.planes[name])
        z = (p @ self.rot)[:, 2]
        z = z[np.isfinite(z) & (z > 0)]
        return float(np.median(z)) if z.size else 0.0


def _lit_points(r: np.ndarray, cols: np.ndarray, b0: np.ndarray, rays: np.ndarray, plane):
    """Rail-frame points (relative to the camera) where the rays through rows ``r`` of
    columns ``cols`` meet the laser plane (NaN where parallel)."""
    t = r - b0[cols]
    j = np.clip(np.floor(t).astype(np.int64), 0, rays.shape[1] - 2)
    f = (t - j)[:, None]
    d = rays[cols, j] + f * (rays[cols, j + 1] - rays[cols, j])
    den = d @ np.asarray(plane.normal, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = np.where(np.abs(den) > 1e-12, float(plane.offset_mm) / den, np.nan)
    return lam[:, None] * d


def refine_numpy(rows, band_start, rays, normal, offset, rot, kmat, dist, rational, y, ring,
                 slots, shifts, ring_rows, clip, weight) -> int:
    """The readable numpy reference of ``kernels.unlit_refine`` (same arguments, same steps;
    the tests check the two agree)."""
    from impress_gui.core.calibration.geometry import Plane
    from impress_gui.core.reconstruction import kernels as kn

    half = kn.UNLIT_HALF
    cols = np.flatnonzero(np.isfinite(rows))
    if cols.size == 0:
        return 0
    h, w = y.shape
    r = rows[cols]
    p = _lit_points(r, cols, band_start, rays, Plane(normal, offset))
    r0 = np.floor(r + 0.5).astype(np.int64)
    mid = half + 2
    ok = np.isfinite(p).all(axis=1) & (r0 - mid >= 0) & (r0 + mid <= h - 1)
    crow = r0[:, None] + np.arange(-mid, mid + 1)[None, :]
    bg = np.zeros(crow.shape)
    for s, shift in zip(slots, shifts, strict=True):
        moved = p.copy()
        moved[:, 1] += shift
        cam = moved @ rot
        with np.errstate(divide="ignore", invalid="ignore"):
            xn, yn = cam[:, 0] / cam[:, 2], cam[:, 1] / cam[:, 2]
        k1, k2, p1, p2, k3, k4, k5, k6 = dist
        r2 = xn * xn + yn * yn
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        if rational:
            radial = radial / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xd = xn * radial + 2 * p1 * xn * yn + p2 * (r2 + 2 * xn * xn)
        yd = yn * radial + p1 * (r2 + 2 * yn * yn) + 2 * p2 * xn * yn
        u = kmat[0, 0] * xd + kmat[0, 1] * yd + kmat[0, 2]
        v = kmat[1, 1] * yd + kmat[1, 2]
        ok &= (cam[:, 2] > 0) & (u >= 0) & (u <= w - 1) & (v - half - 3 >= 0) & (
            v + half + 3 <= h - 1)
        u, v = np.nan_to_num(u), np.nan_to_num(v)
        cu = np.clip(np.floor(u + 0.5).astype(np.int64), 0, w - 1)
        near = np.abs(ring_rows[s][:, cu] - v[None, :]) <= kn.UNLIT_REACH
        ok &= ~near.any(axis=0)
        u0 = np.minimum(np.floor(u).astype(np.int64), w - 2)
        fu = (u - u0)[:, None]
        yy = v[:, None] + crow - r[:, None]
        v0 = np.clip(np.floor(yy).astype(np.int64), 0, h - 2)
        fv = yy - v0
        u0 = np.clip(u0, 0, w - 2)[:, None]
        img = ring[s].astype(np.float64)
        a = img[v0, u0] * (1 - fu) + img[v0, u0 + 1] * fu
        b = img[v0 + 1, u0] * (1 - fu) + img[v0 + 1, u0 + 1] * fu
        bg += a * (1 - fv) + b * fv
    sel = np.flatnonzero(ok)
    if sel.size == 0:
        return 0
    cut = y[crow[sel], cols[sel, None]].astype(np.float64)
    new, rr, sig, top, clipped = _estimate(cut, texture_weighted(bg[sel] / len(slots), weight),
                                           crow[sel].astype(np.float64), clip)
    good = np.isfinite(new) & (np.abs(new - r[sel]) <= half - 1)
    fit = wide_stripe(new[good], rr[good], sig[good], top[good], clipped[good])
    fit = np.where(np.abs(fit - r[sel[good]]) <= half - 1, fit, new[good])
    rows[cols[sel[good]]] = fit
    return int(good.sum())


def texture_weighted(bg: np.ndarray, weight: float) -> np.ndarray:
    """The unlit cuts ``bg`` ``(n, rows)`` with only ``weight`` of their texture: each cut's
    straight-line fit plus that share of the rest."""
    q = np.arange(bg.shape[1], dtype=np.float64)
    design = np.stack([np.ones_like(q), q], axis=1)
    coef = np.linalg.lstsq(design, bg.T, rcond=None)[0]
    line = (design @ coef).T
    return line + weight * (bg - line)


def clipped_core(cut: np.ndarray, mid: int, clip: float = CLIP) -> np.ndarray:
    """Per cut ``(n, rows)``: the run of rows at or above ``clip`` through row ``mid`` (the
    stripe's), not a grain of bright soil beside it that reaches ``clip`` too."""
    return run_through((cut >= clip).T, np.full(len(cut), mid)).T


def estimate(cut: np.ndarray, bg: np.ndarray, rows: np.ndarray, clip: float = CLIP) -> np.ndarray:
    """The detector's estimate on the luma ``cut`` ``(n, 17)`` less the unlit soil ``bg``:
    the clipped core (:func:`clipped_core`) at the difference's top; the centre of mass above half maximum in the window
    of ``UNLIT_HALF`` rows around the middle, then around its own row, refined. NaN where the
    difference has no peak of ``UNLIT_MIN_PEAK``."""
    return _estimate(cut, bg, rows, clip)[0]


def _estimate(cut: np.ndarray, bg: np.ndarray, rows: np.ndarray, clip: float):
    """:func:`estimate`, and the windows it ended on: their rows ``(n, 2 UNLIT_HALF + 1)``,
    the difference above their minimum, its top, which of their rows are clipped."""
    from impress_gui.core.reconstruction import kernels as kn

    half = kn.UNLIT_HALF
    diff = cut - bg
    top_all = diff.max(axis=1, keepdims=True)
    mid = half + 2
    diff = np.where(clipped_core(cut, mid, clip), top_all, diff)
    n = diff.shape[0]
    idx = np.arange(n)[:, None]

    def window(at: np.ndarray):
        ii = at[:, None] + np.arange(-half, half + 1)[None, :]
        sig = diff[idx, ii]
        sig = sig - sig.min(axis=1, keepdims=True)
        top = sig.max(axis=1)
        above = np.clip(sig - 0.5 * top[:, None], 0.0, None)
        rr = rows[idx, ii]
        with np.errstate(invalid="ignore", divide="ignore"):
            centre = (above * rr).sum(axis=1) / above.sum(axis=1)
        return rr, sig, top, centre

    rr, sig, top, centre = window(np.full(n, mid))
    shift = np.floor(np.nan_to_num(centre - rows[:, mid]) + 0.5).astype(np.int64)
    at = np.clip(mid + shift, half, 2 * mid - half)
    rr, sig, top, centre = window(at)
    out = window_refine(rr.T, sig.T, top, centre)
    ii = at[:, None] + np.arange(-half, half + 1)[None, :]
    return (np.where((top >= kn.UNLIT_MIN_PEAK) & np.isfinite(out), out, np.nan), rr, sig, top,
            cut[idx, ii] >= clip)


def wide_stripe(new: np.ndarray, rr: np.ndarray, sig: np.ndarray, top: np.ndarray,
                clipped: np.ndarray) -> np.ndarray:
    """The centres ``new`` of one frame's refined columns (their windows ``rr``, ``sig``,
    ``top``, ``clipped`` as :func:`_estimate` gives them), from a Gaussian fitted to each
    profile (:func:`~impress_gui.core.reconstruction.stripes.gauss_refine`) where the median
    column has at least ``kernels.GAUSS_MIN_ROWS`` rows above half maximum: a wide stripe;
    ``new`` itself otherwise, and for a column whose fit fails."""
    from impress_gui.core.reconstruction import kernels as kn

    if not new.size or np.median((sig > 0.5 * top[:, None]).sum(axis=1)) < kn.GAUSS_MIN_ROWS:
        return new
    fit, width = gauss_refine(rr.T, sig.T, new, clipped.T)
    return np.where(width > 0, fit, new)
