"""Accumulating scattered stripe profiles into a regular heightmap grid.

Grid convention (shared with the simulator's truth): cell ``[i, j]`` is centred at rail
coordinates ``x = x0_mm + j * pixel_mm``, ``y = y0_mm + i * pixel_mm``; arrays are row-major.
Consecutive stripe profiles are filled in between (linear where the surface is continuous,
nearest where it steps), so a scan at any speed gives a gap-free map where a laser saw the
surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class GridSpec:
    x0_mm: float
    y0_mm: float
    pixel_mm: float
    shape: tuple[int, int]  # (rows along Y, cols along X)

    @classmethod
    def covering(cls, x_range, y_range, pixel_mm: float) -> GridSpec:
        x0 = np.floor(x_range[0] / pixel_mm) * pixel_mm
        y0 = np.floor(y_range[0] / pixel_mm) * pixel_mm
        w = int(np.ceil((x_range[1] - x0) / pixel_mm)) + 1
        h = int(np.ceil((y_range[1] - y0) / pixel_mm)) + 1
        return cls(float(x0), float(y0), float(pixel_mm), (h, w))

    def xs(self) -> np.ndarray:
        return self.x0_mm + self.pixel_mm * np.arange(self.shape[1])

    def ys(self) -> np.ndarray:
        return self.y0_mm + self.pixel_mm * np.arange(self.shape[0])

    def to_json(self) -> dict:
        return {"x0_mm": self.x0_mm, "y0_mm": self.y0_mm, "pixel_mm": self.pixel_mm,
                "shape": list(self.shape)}


def upsample_profile(x, y, h, valid, pixel_mm: float, k: int, max_step_mm: float):
    """Insert ``k - 1`` points between neighbouring columns of one stripe profile.

    Returns arrays of length ``(n - 1) * k + 1``, index-aligned across frames (so consecutive
    profiles can be paired point by point). Across a height jump larger than ``max_step_mm``
    the inserted points take the nearer neighbour's values (the edge lands midway)."""
    t = (np.arange(k) / k)[None, :]
    a_ok = valid[:-1] & valid[1:]
    step = np.abs(h[1:] - h[:-1]) > max_step_mm
    def interp(v):
        lin = v[:-1, None] + t * (v[1:, None] - v[:-1, None])
        near = np.where(t < 0.5, v[:-1, None], v[1:, None])
        return np.where(step[:, None], near, lin)
    xo, yo, ho = interp(x), interp(y), interp(h)
    vo = np.repeat(a_ok[:, None], k, axis=1)
    vo[:, 0] = valid[:-1]
    # keep the left column's own sample even where the right neighbour is missing
    xo[:, 0], yo[:, 0], ho[:, 0] = x[:-1], y[:-1], h[:-1]
    out = [a.reshape(-1) for a in (xo, yo, ho, vo)]
    return tuple(np.concatenate([o, [last]]) for o, last in zip(out, (x[-1], y[-1], h[-1], valid[-1])))


def _cell_index(spec: GridSpec, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Flat cell index of each point (nearest cell), -1 outside the grid."""
    j = np.rint((x - spec.x0_mm) / spec.pixel_mm).astype(np.int64)
    i = np.rint((y - spec.y0_mm) / spec.pixel_mm).astype(np.int64)
    ok = (i >= 0) & (i < spec.shape[0]) & (j >= 0) & (j < spec.shape[1])
    return np.where(ok, i * spec.shape[1] + j, -1)


def _accumulate(target: np.ndarray, idx: np.ndarray, values: np.ndarray | None) -> None:
    """``target[idx] += values`` (or ``+= 1``) with repeated indices, via a bincount over the
    small span of cells one frame touches (much faster than ``np.add.at``)."""
    if idx.size == 0:
        return
    lo, hi = int(idx.min()), int(idx.max()) + 1
    add = np.bincount(idx - lo, weights=values, minlength=hi - lo)
    view = target[lo:hi]
    view += add.astype(view.dtype) if values is not None else add.astype(view.dtype)


class HeightAccumulator:
    """Sum and count of heights per cell, filled between consecutive profiles."""

    def __init__(self, spec: GridSpec, max_gap_mm: float, max_step_mm: float) -> None:
        self.spec = spec
        # float32 sums: heights within +-1 m summed over a cell's few hundred samples keep
        # micrometre precision; uint16 counts (a cell gets at most a few hundred samples)
        self.sum = np.zeros(spec.shape, np.float32)
        self.count = np.zeros(spec.shape, np.uint16)
        self.max_gap_mm = max_gap_mm
        self.max_step_mm = max_step_mm
        self._prev = None

    def reset_chain(self) -> None:
        self._prev = None

    def _splat(self, x, y, h) -> None:
        idx = _cell_index(self.spec, x, y)
        ok = idx >= 0
        _accumulate(self.sum.reshape(-1), idx[ok], h[ok])
        _accumulate(self.count.reshape(-1), idx[ok], None)

    def add_profile(self, x, y, h, valid) -> None:
        """Add one frame's (upsampled) profile; fill towards the previous one."""
        prev = self._prev
        self._prev = (x, y, h, valid)
        if prev is None:
            self._splat(x[valid], y[valid], h[valid])
            return
        px, py, ph, pv = prev
        g = self.spec.pixel_mm
        both = valid & pv
        dy = y - py
        dx = x - px
        gap = np.hypot(dx, dy)
        pair = both & (gap <= self.max_gap_mm)
        # single points where the chain is broken
        lone = valid & ~pair
        if lone.any():
            self._splat(x[lone], y[lone], h[lone])
        if not pair.any():
            return
        n = int(np.ceil(gap[pair].max() / (0.7 * g))) + 1
        t = (np.arange(1, n + 1) / n)[None, :]  # exclude the previous endpoint (already added)
        X0, Y0, H0 = px[pair, None], py[pair, None], ph[pair, None]
        X1, Y1, H1 = x[pair, None], y[pair, None], h[pair, None]
        step = np.abs(H1 - H0) > self.max_step_mm
        hx = X0 + t * (X1 - X0)
        hy = Y0 + t * (Y1 - Y0)
        hh = np.where(step, np.where(t < 0.5, H0, H1), H0 + t * (H1 - H0))
        self._splat(hx.ravel(), hy.ravel(), hh.ravel())

    def mean(self) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            out = (self.sum / self.count).astype(np.float32)
        out[self.count == 0] = np.nan
        return out


class ColorAccumulator:
    """Mean RGB per cell (the registered texture)."""

    def __init__(self, spec: GridSpec, max_gap_mm: float) -> None:
        self.spec = spec
        self.sum = np.zeros((*spec.shape, 3), np.float32)
        self.count = np.zeros(spec.shape, np.uint16)
        self.max_gap_mm = max_gap_mm
        self._prev = None

    def add_row(self, x, y, rgb, valid) -> None:
        s = self.spec
        prev = self._prev
        self._prev = (x, y, rgb, valid)
        pts = [(x[valid], y[valid], rgb[valid])]
        if prev is not None:
            px, py, prgb, pv = prev
            pair = valid & pv & (np.hypot(x - px, y - py) <= self.max_gap_mm)
            if pair.any():
                gap = np.hypot(x - px, y - py)[pair].max()
                n = int(np.ceil(gap / (0.7 * s.pixel_mm)))
                for k in range(1, n):
                    t = k / n
                    pts.append((px[pair] + t * (x[pair] - px[pair]),
                                py[pair] + t * (y[pair] - py[pair]),
                                prgb[pair] + t * (rgb[pair] - prgb[pair])))
        X = np.concatenate([p[0] for p in pts])
        Y = np.concatenate([p[1] for p in pts])
        C = np.concatenate([p[2] for p in pts]).astype(np.float32)
        idx = _cell_index(s, X, Y)
        ok = idx >= 0
        flat = self.sum.reshape(-1, 3)
        for c in range(3):
            _accumulate(flat[:, c], idx[ok], C[ok, c])
        _accumulate(self.count.reshape(-1), idx[ok], None)

    def mean(self) -> np.ndarray:
        with np.errstate(invalid="ignore", divide="ignore"):
            out = self.sum / np.maximum(self.count, 1)[..., None]
        return np.clip(out + 0.5, 0, 255).astype(np.uint8)


def fuse(h_green: np.ndarray, h_red: np.ndarray, tol_mm: float):
    """Fuse two per-laser maps. Returns (fused, difference green - red, contribution) where
    contribution is 0 none, 1 green only, 2 red only, 3 both agreeing (mean), 4 both
    disagreeing (the value nearer the local consensus)."""
    g_ok, r_ok = np.isfinite(h_green), np.isfinite(h_red)
    diff = np.where(g_ok & r_ok, h_green - h_red, np.nan).astype(np.float32)
    fused = np.full(h_green.shape, np.nan, np.float32)
    contrib = np.zeros(h_green.shape, np.uint8)
    only_g, only_r = g_ok & ~r_ok, r_ok & ~g_ok
    fused[only_g], contrib[only_g] = h_green[only_g], 1
    fused[only_r], contrib[only_r] = h_red[only_r], 2
    both = g_ok & r_ok
    agree = both & (np.abs(diff) <= tol_mm)
    fused[agree] = 0.5 * (h_green[agree] + h_red[agree])
    contrib[agree] = 3
    conflict = both & ~agree
    if conflict.any():
        from scipy.ndimage import uniform_filter

        base = np.where(np.isfinite(fused), fused, 0.0)
        w = uniform_filter(np.isfinite(fused).astype(np.float32), 7)
        local = uniform_filter(base.astype(np.float32), 7) / np.maximum(w, 1e-6)
        pick_g = np.abs(h_green - local) <= np.abs(h_red - local)
        fused[conflict] = np.where(pick_g, h_green, h_red)[conflict]
        contrib[conflict] = 4
    return fused, diff, contrib
