"""Ray casting of a heightfield sampled on a regular grid (bilinear between cell centres).

A ray is given in *map units*: its point at depth ``z`` (mm) lies at grid position
``(bx + z dx, by + z dy)`` in cells. :meth:`HeightfieldCaster.cast` finds the first depth where
a ray meets the surface. Each ray's depth interval is walked front to back with a min/max
pyramid of the depth map (:class:`DepthBounds`): the first hit lies between the shallowest and
the deepest surface under the footprint of the piece of ray being looked at, so a piece over
open ground collapses at once to the ground's depth, a piece above everything is skipped, and
only pieces close to the surface are sampled finely (no surface sliver wider than half a cell
is stepped over). Brackets are refined by the Illinois variant of false position.
"""

from __future__ import annotations

import cv2
import numpy as np

_REMAP_COLS = 1024  # cv2.remap takes at most 32767 destination columns: fold long lists


def remap_points(img: np.ndarray, mx: np.ndarray, my: np.ndarray,
                 interp: int = cv2.INTER_LINEAR) -> np.ndarray:
    """Sample ``img`` (H, W[, C]) at map coordinates ``(mx, my)`` (1-D float32, in cells) with
    replicated borders; return ``(N[, C])``."""
    n = mx.shape[0]
    q = n // _REMAP_COLS * _REMAP_COLS
    parts = []
    if q:
        parts.append(cv2.remap(img, mx[:q].reshape(-1, _REMAP_COLS),
                               my[:q].reshape(-1, _REMAP_COLS), interp,
                               borderMode=cv2.BORDER_REPLICATE))
    if n > q:
        parts.append(cv2.remap(img, mx[q:].reshape(1, -1), my[q:].reshape(1, -1), interp,
                               borderMode=cv2.BORDER_REPLICATE))
    if not parts:
        return np.zeros((0, *img.shape[2:]), img.dtype)
    out = parts[0].reshape(-1, *img.shape[2:])
    if len(parts) == 2:
        out = np.concatenate([out, parts[1].reshape(-1, *img.shape[2:])])
    return out


class DepthBounds:
    """Min/max pyramid of the depth map. :meth:`query` bounds the surface (bilinear
    interpolation included) under every point within ``reach`` cells of a map position.

    Level ``j`` has tiles of ``base * 2**j`` cells holding the min/max over the tile and its eight
    neighbours, so a query at a point covers everything within one tile size of it. The last
    level is the global min/max.
    """

    def __init__(self, depth: np.ndarray, base_cells: int = 4, max_reach_cells: float = 1e9):
        t = max(1, int(base_cells))
        h, w = depth.shape
        hh, ww = -(-h // t) * t, -(-w // t) * t
        pad = np.pad(depth, ((0, hh - h), (0, ww - w)), mode="edge").reshape(hh // t, t, ww // t, t)
        cur_min = np.ascontiguousarray(pad.min(axis=(1, 3)), dtype=np.float32)
        cur_max = np.ascontiguousarray(pad.max(axis=(1, 3)), dtype=np.float32)
        del pad
        k3 = np.ones((3, 3), np.uint8)
        mins, maxs, shapes, tiles = [], [], [], []
        tile = t
        while True:
            mins.append(cv2.erode(cur_min, k3, borderType=cv2.BORDER_REPLICATE).ravel())
            maxs.append(cv2.dilate(cur_max, k3, borderType=cv2.BORDER_REPLICATE).ravel())
            shapes.append(cur_min.shape)
            tiles.append(float(tile))
            if tile >= max_reach_cells or max(cur_min.shape) <= 3:
                break
            cur_min, cur_max = _pool2(cur_min, np.minimum), _pool2(cur_max, np.maximum)
            tile *= 2
        mins.append(np.array([min(float(v.min()) for v in mins)], np.float32))
        maxs.append(np.array([max(float(v.max()) for v in maxs)], np.float32))
        shapes.append((1, 1))
        tiles.append(1e30)
        self._min = np.concatenate(mins)
        self._max = np.concatenate(maxs)
        self._offset = np.cumsum([0] + [a * b for a, b in shapes[:-1]]).astype(np.int32)
        self._nx = np.array([s[1] for s in shapes], np.int32)
        self._xmax = np.array([s[1] - 1 for s in shapes], np.float32)
        self._ymax = np.array([s[0] - 1 for s in shapes], np.float32)
        self._tile = np.array(tiles, np.float32)
        self._inv_tile = np.array([1.0 / v for v in tiles], np.float32)
        self.base = t
        self.levels = len(tiles)
        self.zmin, self.zmax = float(self._min[-1]), float(self._max[-1])

    def query(self, mx: np.ndarray, my: np.ndarray, reach_cells: np.ndarray):
        """``(min, max)`` of the surface depth within ``reach_cells`` of ``(mx, my)``."""
        return self.query_at(mx, my, self.level_table(reach_cells))

    def level_table(self, reach_cells: np.ndarray) -> tuple[np.ndarray, ...]:
        """Per-point level constants for a reach (reusable while the reach stays the same)."""
        lev = np.searchsorted(self._tile, np.asarray(reach_cells, np.float32))
        return (self._inv_tile[lev], self._xmax[lev], self._ymax[lev], self._nx[lev],
                self._offset[lev])

    def query_at(self, mx: np.ndarray, my: np.ndarray, table: tuple[np.ndarray, ...]):
        inv, xmax, ymax, nx, offset = table
        # clipping to >= 0 first makes truncation a floor
        tx = np.minimum(np.maximum(mx * inv, 0), xmax).astype(np.int64)
        ty = np.minimum(np.maximum(my * inv, 0), ymax).astype(np.int64)
        flat = offset + ty * nx + tx
        return self._min[flat], self._max[flat]


def _pool2(a: np.ndarray, op) -> np.ndarray:
    h, w = a.shape
    if h % 2:
        a = np.vstack([a, a[-1:]])
    if w % 2:
        a = np.hstack([a, a[:, -1:]])
    return np.ascontiguousarray(op(op(a[0::2, 0::2], a[1::2, 0::2]), op(a[0::2, 1::2], a[1::2, 1::2])))


def _at(b, d, z):
    return b + z * d


def _take(rays: tuple, sel: np.ndarray) -> tuple:
    """Subset of a ray tuple; scalar members are shared."""
    return tuple(v if np.ndim(v) == 0 else v[sel] for v in rays)


class HeightfieldCaster:
    """First hits of rays with the depth map ``depth`` (``(rows, cols)`` float32, mm, cell
    ``[i, j]`` centred at ``(x0_mm + j pixel_mm, y0_mm + i pixel_mm)``)."""

    def __init__(self, depth: np.ndarray, x0_mm: float, y0_mm: float, pixel_mm: float,
                 max_slope: float = 2.0) -> None:
        self.depth = np.ascontiguousarray(depth, dtype=np.float32)
        self.x0_mm, self.y0_mm, self.pixel_mm = x0_mm, y0_mm, pixel_mm
        span = float(self.depth.max() - self.depth.min()) + 2.0
        self.bounds = DepthBounds(self.depth, 4, max_slope * span / pixel_mm)

    def maps(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Grid positions (cells, float32, flattened) of rail positions ``x, y`` (mm)."""
        return ((np.asarray(x) - self.x0_mm) / self.pixel_mm).astype(np.float32).ravel(), (
            (np.asarray(y) - self.y0_mm) / self.pixel_mm).astype(np.float32).ravel()

    def sample(self, img, x, y, interp=cv2.INTER_LINEAR) -> np.ndarray:
        """Sample a grid image (same grid as the depth) at rail positions ``x, y`` (mm)."""
        shape = np.shape(x)
        mx, my = self.maps(x, y)
        return remap_points(img, mx, my, interp).reshape(*shape, *img.shape[2:])

    def residual(self, rays, z):
        """``z - depth`` of the surface under the rays' points at depth ``z`` (``(N,)`` or
        ``(N, K)`` for K samples per ray)."""
        bx, by, dx, dy, _ = rays
        if z.ndim == 2:
            bx, by, dx, dy = (v if np.ndim(v) == 0 else v[:, None] for v in (bx, by, dx, dy))
        mx = np.asarray(bx + z * dx, np.float32).ravel()
        my = np.asarray(by + z * dy, np.float32).ravel()
        d = remap_points(self.depth, mx, my).reshape(z.shape)
        return z - d.astype(z.dtype, copy=False)

    def cast(self, bx, by, dx, dy, zl, zh, refine: int, ftol: float, ztol: float = 0.0,
              step_cells: float = 0.5, leaf_cells: float = 8.0, pad: float = 1e-3,
              first: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """First depth in ``[zl, zh]`` where each ray meets the surface, NaN where none.

        A ray's point at depth ``z`` has map position ``(bx + z dx, by + z dy)`` in cells;
        ``bx``/``by`` are scalars or arrays, the rest arrays of one dtype. The interval is
        walked front to back: a piece whose footprint's surface lies entirely below it is
        skipped, a piece that may hold the hit is clipped to the surface's depth range there
        (a range of at most ``2 ztol`` gives the hit directly) and halved until its footprint
        spans at most ``leaf_cells``; leaves are sampled every ``step_cells`` (no surface
        sliver wider than that is stepped over) and the first sign change is refined by
        Illinois false position to ``|z - depth| <= ftol`` mm. ``first`` is the ``(min, max)``
        surface depth under each ray's whole footprint when the caller knows it already.
        """
        dt = zl.dtype.type
        n = dx.shape[0]
        out = np.full(n, np.nan, zl.dtype)
        br = np.full((4, n), np.nan, zl.dtype)  # brackets: a, b, f(a), f(b)
        am = np.maximum(np.abs(dx), np.abs(dy)) + dt(1e-9)  # footprint cells per mm of depth
        rays = (bx, by, dx, dy, am)
        act = np.arange(n)
        z0, zend = zl.copy(), zh.copy()
        if first is not None:
            # the bounds of the whole interval are known: clip to them before walking
            lo, hi = (first[0] - dt(pad)).astype(zl.dtype), (first[1] + dt(pad)).astype(zl.dtype)
            sure = hi <= zh
            z0, zend = np.maximum(z0, lo), np.where(sure, hi, zh)
            found = sure & (zend - z0 <= dt(2 * ztol))
            out[found] = dt(0.5) * (z0[found] + zend[found])
            keep = np.flatnonzero(~found & (z0 < zend))
            act, z0, zend = act[keep], z0[keep], zend[keep]
            rays = _take(rays, keep)
        ln = zend - z0
        while act.size:
            zb = np.minimum(z0 + ln, zend)
            zm = dt(0.5) * (z0 + zb)
            m, mm = self.bounds.query(_at(rays[0], rays[2], zm), _at(rays[1], rays[3], zm),
                                      rays[4] * (dt(0.5) * (zb - z0)) + 1.0)
            lo, hi = (m - dt(pad)).astype(zl.dtype), (mm + dt(pad)).astype(zl.dtype)
            miss = lo > zb  # the surface is below this whole piece: skip it
            z0n = np.where(miss, zb, np.maximum(z0, lo))
            zbn = np.where(miss, zb, np.minimum(zb, hi))
            # f(hi) > 0 where hi lies in the piece: the hit is in [z0n, hi]
            sure = ~miss & (hi <= zb)
            zend = np.where(sure, hi, zend)
            found = sure & (zbn - z0n <= dt(2 * ztol))
            out[act[found]] = dt(0.5) * (z0n[found] + zbn[found])
            leaf = ~miss & ~found & (rays[4] * (zbn - z0n) <= leaf_cells)
            li = np.flatnonzero(leaf)
            if li.size:
                found[li] = self._leaf(_take(rays, li), act[li], z0n[li], zbn[li], step_cells,
                                       pad, out, br)
            # next piece: after a miss or an empty leaf continue behind it with a doubled
            # length; otherwise look again at the clipped piece, halved unless it shrank
            shrunk = (zbn - z0n) < dt(0.75) * (zb - z0)
            nxt = np.where(miss | leaf, zbn, z0n)
            ln = np.where(miss | leaf, dt(2) * np.maximum(zb - z0, dt(1e-3)),
                          np.where(shrunk, zbn - z0n, dt(0.5) * (zbn - z0n)))
            keep = np.flatnonzero(~found & (nxt < zend))
            act, z0, zend, ln = act[keep], nxt[keep], zend[keep], ln[keep]
            rays = _take(rays, keep)
        self._refine(bx, by, dx, dy, am, out, br, refine, ftol)
        return out

    def _leaf(self, rays, idx, z0, z1, step_cells, pad, out, br) -> np.ndarray:
        """Sample rays across short pieces ``[z0, z1]`` at once, at most ``step_cells`` apart
        sideways, plus just below ``z0`` (which is often a flat top's depth less ``pad``: a ray
        clipping such a top near its edge is caught however thin the sliver); store hits
        (``out``) or brackets (``br``) at ``idx``; return which rays found one."""
        dt = z0.dtype.type
        found = np.zeros(idx.size, bool)
        need = np.ceil(rays[4] * (z1 - z0) / dt(step_cells)).astype(np.int64) + 1
        lo_k = 0
        for k in (2, 5, 17, 0):  # 0: all that remain
            sel = np.flatnonzero((need > lo_k) & (need <= k) if k else need > lo_k)
            lo_k = k
            if not sel.size:
                continue
            kk = max(2, int(need[sel].max()))
            a, b = z0[sel], z1[sel]
            a2 = np.minimum(a + dt(2 * pad), b)
            zz = np.empty((sel.size, kk + 1), z0.dtype)
            zz[:, 0] = a
            zz[:, 1:] = a2[:, None] + (b - a2)[:, None] * np.linspace(0.0, 1.0, kk, dtype=z0.dtype)
            f = self.residual(_take(rays, sel), zz)
            pos = f >= 0
            first = np.argmax(pos, axis=1)
            hit = pos[np.arange(sel.size), first]
            found[sel[hit]] = True
            at0 = hit & (first == 0)  # z0 itself is the hit (a face reached exactly)
            out[idx[sel[at0]]] = a[at0]
            r = np.flatnonzero(hit & (first > 0))
            j = first[r]
            br[:, idx[sel[r]]] = zz[r, j - 1], zz[r, j], f[r, j - 1], f[r, j]
        return found

    def _refine(self, bx, by, dx, dy, am, out, br, refine: int, ftol: float) -> None:
        """Illinois false position on the brackets, dropping rays as they converge."""
        act = np.flatnonzero(np.isfinite(br[0]))
        a, b, fa, fb = br[:, act]
        rays = _take((bx, by, dx, dy, am), act)
        side = np.zeros(act.size, np.int8)
        for _ in range(refine):
            if not act.size:
                break
            c = np.clip(b - fb * (b - a) / (fb - fa), a, b)  # fa < 0 <= fb
            fc = self.residual(rays, c)
            done = np.abs(fc) <= ftol
            out[act[done]] = c[done]
            pos = fc >= 0
            fa = np.where(pos & (side == 1), fa * 0.5, fa)
            fb = np.where(~pos & (side == -1), fb * 0.5, fb)
            b, fb = np.where(pos, c, b), np.where(pos, fc, fb)
            a, fa = np.where(pos, a, c), np.where(pos, fa, fc)
            side = np.where(pos, 1, -1).astype(np.int8)
            keep = np.flatnonzero(~done)
            if keep.size < act.size:
                act, a, b, fa, fb, side = (act[keep], a[keep], b[keep], fa[keep], fb[keep],
                                           side[keep])
                rays = _take(rays, keep)
        if act.size:
            out[act] = np.clip(b - fb * (b - a) / (fb - fa), a, b)

    def march(self, ox, oy, oz, ax, ay, z_lo, z_hi, refine=16, ftol=1e-6, ztol=0.0, pad=1e-3):
        """First depth ``Z`` in ``[z_lo, z_hi]`` where the ray ``(ox + (Z-oz) ax, oy + (Z-oz) ay)``
        meets the surface; NaN where it does not. Arrays are 1-D of equal length (``ox``, ``oy``,
        ``oz`` may be scalars); ``z_lo`` and ``z_hi`` may be per-ray arrays. Float64 throughout."""
        ax = np.asarray(ax, np.float64)
        ay = np.asarray(ay, np.float64)
        n = ax.shape[0]
        inv = 1.0 / self.pixel_mm
        bx = (np.asarray(ox, np.float64) - np.asarray(oz, np.float64) * ax - self.x0_mm) * inv
        by = (np.asarray(oy, np.float64) - np.asarray(oz, np.float64) * ay - self.y0_mm) * inv
        zl = np.array(np.broadcast_to(np.asarray(z_lo, np.float64), (n,)))
        zh = np.array(np.broadcast_to(np.asarray(z_hi, np.float64), (n,)))
        return self.cast(bx, by, ax * inv, ay * inv, zl, zh, refine, ftol, ztol, pad=pad)
