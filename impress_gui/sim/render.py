"""Frame renderer: ray casting of the heightfield from the camera and from each laser.

Every pixel's ray is intersected with the heightfield (camera occlusion); each laser's fan is
cast from its source (laser shadows), the lit points are kept only where the camera sees them,
and their exact projections are the stripe centres, which the renderer draws as a Gaussian
profile with speckle, saturating to white at the core.

Speed: before marching, each ray's depth interval is narrowed with a pyramid of min/max depths
over squares of 2 mm tiles (:class:`DepthBounds`): the first hit lies between the shallowest and
the deepest surface under the ray's footprint, and the footprint shrinks with the interval. On
open ground the interval collapses to a few micrometres and a ray costs three surface samples;
only rays that pass close to steps are marched in steps. The bracket is then refined by the
Illinois variant of false position until the surface residual is below a tolerance.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from impress_gui.sim.rig import Laser, Motion, Rig
from impress_gui.sim.scenes import Scene

_REMAP_COLS = 1024  # cv2.remap takes at most 32767 destination columns: fold long lists


@dataclass(frozen=True)
class RenderOptions:
    noise_sigma_dn: float = 2.0
    speckle_contrast: float = 0.3
    stripe_sigma_px: float | None = None  # default: 1.4 px at 1920 wide, scaled, >= 0.9
    laser_peak: float = 4.0  # peak laser signal in multiples of the sensor's full scale
    ambient: float = 0.45
    seed: int = 0
    #: pixels next to a depth step of more than ``antialias_step_mm`` average
    #: ``antialias x antialias`` rays over their area (1 = one ray per pixel everywhere)
    antialias: int = 3
    antialias_step_mm: float = 4.0


@dataclass
class StripeTruth:
    """Exact stripe centres of one laser in one frame: distorted pixel coordinates ``(N, 2)`` of
    the visible lit surface points (dense, about 6 per pixel column) and their rail positions."""

    uv_px: np.ndarray
    points_rail_mm: np.ndarray


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


def _minmod_slope(h: np.ndarray, axis: int, step: float) -> np.ndarray:
    """Slope of ``h`` along ``axis``: the smaller of the one-sided differences, zero where they
    disagree in sign. A flat top stays flat up to its last cell (a central difference would
    shade the cells on both sides of a step as a slope and shift the edge seen in the image)."""
    h = np.asarray(h, np.float32)
    d = np.diff(h, axis=axis) / np.float32(step)
    pad = [(0, 0), (0, 0)]
    pad[axis] = (1, 0)
    back = np.pad(d, pad)  # h[i] - h[i-1]
    pad[axis] = (0, 1)
    fwd = np.pad(d, pad)  # h[i+1] - h[i]
    return np.where(back * fwd > 0, np.where(np.abs(back) < np.abs(fwd), back, fwd), 0.0).astype(
        np.float32)


def _at(b, d, z):
    return b + z * d


def _take(rays: tuple, sel: np.ndarray) -> tuple:
    """Subset of a ray tuple; scalar members are shared."""
    return tuple(v if np.ndim(v) == 0 else v[sel] for v in rays)


class Renderer:
    def __init__(self, scene: Scene, rig: Rig, motion: Motion, options: RenderOptions):
        self.scene, self.rig, self.motion, self.opt = scene, rig, motion, options
        intr = rig.intrinsics
        w, h = intr.image_size
        self.width, self.height = w, h
        uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        rays = intr.rays(np.column_stack([uu.ravel(), vv.ravel()])) @ rig.rotation.T
        self.ax = (rays[:, 0] / rays[:, 2]).astype(np.float32).reshape(h, w)
        self.ay = (rays[:, 1] / rays[:, 2]).astype(np.float32).reshape(h, w)
        del rays, uu, vv
        pix = scene.pixel_mm
        hm = scene.height_mm
        self.depth = np.ascontiguousarray(rig.standoff_mm - hm, dtype=np.float32)  # Z' of surface
        gx, gy = _minmod_slope(hm, 1, pix), _minmod_slope(hm, 0, pix)
        light = np.array([0.3, -0.35, 1.0])
        light /= np.linalg.norm(light)
        shade = (-gx * light[0] - gy * light[1] + light[2]) / np.sqrt(1.0 + gx * gx + gy * gy)
        del gx, gy
        amb = options.ambient
        factor = (amb + (1 - amb) * np.clip(shade, 0, 1)).astype(np.float32)
        del shade
        self.albedo = np.ascontiguousarray(scene.albedo)
        #: the albedo under ambient + diffuse light, grey levels (RGB uint8 on the scene grid)
        self.shaded = np.empty_like(self.albedo)
        for c in range(3):
            self.shaded[..., c] = np.round(self.albedo[..., c] * factor)
        del factor
        self.row_max = self.depth.max(axis=1)  # deepest (lowest) surface of each grid row
        self.row_min = self.depth.min(axis=1)  # shallowest (highest)
        self.sigma_px = options.stripe_sigma_px or max(0.9, 1.4 * w / 1920.0)
        # camera rays in map units (cells per mm of depth); the origin moves along y only
        self._cam_dx = (self.ax / np.float32(pix)).ravel()
        self._cam_dy = (self.ay / np.float32(pix)).ravel()
        span = float(self.depth.max() - self.depth.min()) + 2.0
        self.bounds = DepthBounds(self.depth, 4, 2.0 * span / pix)
        # the camera rays' first bounds query covers the whole depth range: its level and
        # footprint centre relative to the moving optical centre never change
        self._cam_z = (np.float32(self.bounds.zmin - 0.01), np.float32(self.bounds.zmax + 0.01))
        zm = np.float32(0.5) * (self._cam_z[0] + self._cam_z[1])
        reach = np.maximum(np.abs(self._cam_dx), np.abs(self._cam_dy)) * (
            np.float32(0.5) * (self._cam_z[1] - self._cam_z[0])) + np.float32(1.0)
        self._cam_first = (self._cam_dx * zm, self._cam_dy * zm, self.bounds.level_table(reach))

    # ----- sampling helpers ------------------------------------------------------------
    def _maps(self, x, y):
        s = self.scene
        return ((np.asarray(x) - s.x0_mm) / s.pixel_mm).astype(np.float32).ravel(), (
            (np.asarray(y) - s.y0_mm) / s.pixel_mm
        ).astype(np.float32).ravel()

    def _sample(self, img, x, y, interp=cv2.INTER_LINEAR):
        """Sample a scene-grid image at rail positions ``x, y`` (mm, any equal shapes)."""
        shape = np.shape(x)
        mx, my = self._maps(x, y)
        return remap_points(img, mx, my, interp).reshape(*shape, *img.shape[2:])

    def _depth_range(self, y_lo: float, y_hi: float) -> tuple[float, float]:
        s = self.scene
        i0 = int(np.clip((y_lo - s.y0_mm) / s.pixel_mm - 2, 0, len(self.row_min) - 1))
        i1 = int(np.clip((y_hi - s.y0_mm) / s.pixel_mm + 2, i0 + 1, len(self.row_min)))
        return float(self.row_min[i0:i1].min()), float(self.row_max[i0:i1].max())

    # ----- ray casting -------------------------------------------------------------------
    def _residual(self, rays, z):
        """``z - depth`` of the surface under the rays' points at depth ``z`` (``(N,)`` or
        ``(N, K)`` for K samples per ray)."""
        bx, by, dx, dy, _ = rays
        if z.ndim == 2:
            bx, by, dx, dy = (v if np.ndim(v) == 0 else v[:, None] for v in (bx, by, dx, dy))
        mx = np.asarray(bx + z * dx, np.float32).ravel()
        my = np.asarray(by + z * dy, np.float32).ravel()
        d = remap_points(self.depth, mx, my).reshape(z.shape)
        return z - d.astype(z.dtype, copy=False)

    def _cast(self, bx, by, dx, dy, zl, zh, refine: int, ftol: float, ztol: float = 0.0,
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
        for k in (2, 5, 17, None):
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
            f = self._residual(_take(rays, sel), zz)
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
            fc = self._residual(rays, c)
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
        s = self.scene
        ax = np.asarray(ax, np.float64)
        ay = np.asarray(ay, np.float64)
        n = ax.shape[0]
        inv = 1.0 / s.pixel_mm
        bx = (np.asarray(ox, np.float64) - np.asarray(oz, np.float64) * ax - s.x0_mm) * inv
        by = (np.asarray(oy, np.float64) - np.asarray(oz, np.float64) * ay - s.y0_mm) * inv
        zl = np.array(np.broadcast_to(np.asarray(z_lo, np.float64), (n,)))
        zh = np.array(np.broadcast_to(np.asarray(z_hi, np.float64), (n,)))
        return self._cast(bx, by, ax * inv, ay * inv, zl, zh, refine, ftol, ztol, pad=pad)

    # ----- one frame -------------------------------------------------------------------
    def travel(self, k: int) -> float:
        return float(self.motion.travel_mm(k / self.motion.fps))

    def _camera_depth(self, s: float) -> np.ndarray:
        """Depth of the surface seen by every pixel, ``(H*W,)`` float32."""
        sc = self.scene
        n = self._cam_dx.shape[0]
        bx = np.float32(-sc.x0_mm / sc.pixel_mm)
        by = np.float32((s - sc.y0_mm) / sc.pixel_mm)
        zl = np.full(n, self._cam_z[0], np.float32)
        zh = np.full(n, self._cam_z[1], np.float32)
        cx, cy, table = self._cam_first
        first = self.bounds.query_at(bx + cx, by + cy, table)
        z = self._cast(bx, by, self._cam_dx, self._cam_dy, zl, zh, refine=8, ftol=2e-3,
                       ztol=2e-3, first=first)
        return np.where(np.isfinite(z), z, zh)

    def _antialias(self, s: float, z: np.ndarray, rgb: np.ndarray) -> None:
        """Average ``n x n`` rays over the area of pixels beside depth steps (occluding edges:
        the sensor integrates over the pixel, so an edge falls between pixels as a blend)."""
        n = int(self.opt.antialias)
        if n <= 1:
            return
        step = self.opt.antialias_step_mm
        edge = np.zeros(z.shape, bool)
        jump = np.abs(np.diff(z, axis=1)) > step
        edge[:, 1:] |= jump
        edge[:, :-1] |= jump
        jump = np.abs(np.diff(z, axis=0)) > step
        edge[1:] |= jump
        edge[:-1] |= jump
        idx = np.flatnonzero(edge)
        if not idx.size:
            return
        v, u = np.divmod(idx, self.width)
        offs = (np.arange(n) + 0.5) / n - 0.5
        du, dv = (a.ravel() for a in np.meshgrid(offs, offs))
        other = np.abs(du) + np.abs(dv) > 1e-9  # the pixel centre is already rendered
        du, dv = du[other], dv[other]
        mu = (u[None, :] + du[:, None]).astype(np.float32).ravel()
        mv = (v[None, :] + dv[:, None]).astype(np.float32).ravel()
        sc = self.scene
        inv = np.float32(1.0 / sc.pixel_mm)
        dx = remap_points(self.ax, mu, mv) * inv  # ray slopes vary smoothly over a pixel
        dy = remap_points(self.ay, mu, mv) * inv
        bx = np.float32(-sc.x0_mm / sc.pixel_mm)
        by = np.float32((s - sc.y0_mm) / sc.pixel_mm)
        zl = np.full(dx.size, self.bounds.zmin - 0.01, np.float32)
        zh = np.full(dx.size, self.bounds.zmax + 0.01, np.float32)
        zs = self._cast(bx, by, dx, dy, zl, zh, refine=8, ftol=2e-3, ztol=2e-3)
        zs = np.where(np.isfinite(zs), zs, zh)
        col = remap_points(self.shaded, bx + zs * dx, by + zs * dy).astype(np.float32)
        total = col.reshape(du.size, idx.size, 3).sum(axis=0)
        if n % 2:
            total += rgb[v, u]
        rgb[v, u] = total / np.float32(n * n)

    def camera_surface(self, k: int):
        """Rail-frame surface point seen by every pixel of frame ``k`` (X, Y, Z) as (H, W)."""
        s = self.travel(k)
        zh = self._camera_depth(s).reshape(self.height, self.width)
        return self.ax * zh, np.float32(s) + self.ay * zh, zh

    def laser_points(self, laser: Laser, k: int) -> StripeTruth:
        """Cast the laser's fan from its source; keep lit points the camera can see."""
        s = self.travel(k)
        n_rays = 6 * self.width
        normal = laser.plane.normal
        down = laser.fan_dir_mm
        across = np.cross(down, normal)
        phi = np.linspace(-0.75, 0.75, n_rays)
        dirs = np.cos(phi)[:, None] * down + np.sin(phi)[:, None] * across
        dirs = dirs[dirs[:, 2] > 0.05]
        src = laser.source_mm + np.array([0.0, s, 0.0])
        ax, ay = dirs[:, 0] / dirs[:, 2], dirs[:, 1] / dirs[:, 2]
        zmin, zmax = self._depth_range(s - 250.0, s + 250.0)
        # on a flat piece of surface the depth bounds alone fix the hit to 0.2 um
        zh = self.march(src[0], src[1], src[2], ax, ay, zmin - 0.5, zmax + 0.5, ztol=2e-4,
                        pad=2e-4)
        good = np.isfinite(zh)
        p = np.column_stack([src[0] + (zh - src[2]) * ax, src[1] + (zh - src[2]) * ay, zh])
        # camera visibility: the camera ray towards p must not meet the surface before p
        cam = np.array([0.0, s, 0.0])
        rel = p - cam
        with np.errstate(invalid="ignore", divide="ignore"):
            cax, cay = rel[:, 0] / rel[:, 2], rel[:, 1] / rel[:, 2]
        vis = good.copy()
        g = np.flatnonzero(good)
        zc = self.march(0.0, s, 0.0, cax[g], cay[g], zmin - 0.5, p[g, 2] + 0.5, refine=10,
                        ftol=1e-4, ztol=1e-3)
        vis[g] = np.isfinite(zc) & (zc >= p[g, 2] - 0.08)
        pc = (rel[vis]) @ self.rig.rotation  # ideal -> camera frame (R^T applied to rows)
        uv = self.rig.intrinsics.project(pc)
        inside = (uv[:, 0] > -2) & (uv[:, 0] < self.width + 1) & (uv[:, 1] > -2) & (
            uv[:, 1] < self.height + 1)
        keep = np.flatnonzero(vis)[inside]
        return StripeTruth(uv[inside], p[keep])

    def _surface_normals(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Unit normals (x, y, up) of the height surface at rail points, ``(N, 3)``."""
        d = self.scene.pixel_mm
        xs = np.concatenate([x + d, x - d, x, x])
        ys = np.concatenate([y, y, y + d, y - d])
        dep = self._sample(self.depth, xs, ys).astype(np.float64).reshape(4, -1)
        gx = -(dep[0] - dep[1]) / (2 * d)  # slope of the height (up = -depth)
        gy = -(dep[2] - dep[3]) / (2 * d)
        nz = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
        return np.column_stack([-gx * nz, -gy * nz, nz])

    def _stripe_band(self, laser: Laser, truth: StripeTruth, s: float,
                     rng: np.random.Generator) -> tuple[int, np.ndarray]:
        """Laser signal (multiples of full scale) of one laser in a band of rows: ``(r0, band)``
        with ``band`` float32 ``(rows, W)``, zero outside it."""
        h, w = self.height, self.width
        uv, pts = truth.uv_px, truth.points_rail_mm
        empty = (0, np.zeros((0, w), np.float32))
        if len(uv) < 2:
            return empty
        # consecutive samples along the fan that lie on one continuous surface piece
        step3d = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        cont = step3d < 1.5
        u0, u1 = uv[:-1, 0], uv[1:, 0]
        v0, v1 = uv[:-1, 1], uv[1:, 1]
        lo, hi = np.minimum(u0, u1), np.maximum(u0, u1)
        col = np.ceil(lo)
        seg = cont & (col <= hi) & (hi - lo < 3.0)
        col, u0, u1, v0, v1 = col[seg], u0[seg], u1[seg], v0[seg], v1[seg]
        t = np.where(np.abs(u1 - u0) > 1e-9, (col - u0) / (u1 - u0 + 1e-300), 0.5)
        vc = v0 + t * (v1 - v0)
        # irradiance: incidence angle on the surface and surface albedo in the laser's colour
        p = pts[:-1][seg] + t[:, None] * (pts[1:][seg] - pts[:-1][seg])
        ch = int(np.argmax(laser.rgb_response))
        alb = self._sample(self.albedo, p[:, 0], p[:, 1])[:, ch].astype(np.float64) / 255.0
        nrm = self._surface_normals(p[:, 0], p[:, 1])
        d = p - (laser.source_mm + np.array([0, s, 0]))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        cos_inc = np.clip(-(nrm[:, 0] * d[:, 0] + nrm[:, 1] * d[:, 1]) + nrm[:, 2] * d[:, 2],
                          0.05, 1.0)
        amp = self.opt.laser_peak * (alb / 0.4) * (0.3 + 0.7 * cos_inc)
        kk = int(np.ceil(4 * self.sigma_px))
        rows = np.floor(vc).astype(np.int64)[:, None] + np.arange(-kk, kk + 1)[None, :]
        wgt = amp[:, None] * np.exp(-0.5 * ((rows - vc[:, None]) / self.sigma_px) ** 2)
        cols = np.broadcast_to(col.astype(np.int64)[:, None], rows.shape)
        ok = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
        rows, cols, wgt = rows[ok], cols[ok], wgt[ok]
        if not rows.size:
            return empty
        r0, r1 = int(rows.min()), int(rows.max()) + 1
        band = np.bincount((rows - r0) * w + cols, weights=wgt, minlength=(r1 - r0) * w)
        band = band.reshape(r1 - r0, w).astype(np.float32)
        c = self.opt.speckle_contrast
        if c > 0:
            # granular multiplicative speckle (gamma-distributed, grain ~1 px), in the band only
            shape_k = 1.0 / (c * c)
            sp = rng.gamma(shape_k, 1.0 / shape_k, (r1 - r0, w)).astype(np.float32)
            sp = cv2.GaussianBlur(sp, (0, 0), 0.6)
            sp /= sp.mean()
            band *= sp
        return r0, band

    def render(self, k: int) -> tuple[np.ndarray, dict[str, StripeTruth]]:
        """Frame ``k`` as RGB uint8 ``(H, W, 3)`` and the exact stripe centres of each laser."""
        rng = np.random.default_rng([self.opt.seed, k])
        s = self.travel(k)
        h, w = self.height, self.width
        sc = self.scene
        z = self._camera_depth(s)
        mx = np.float32(-sc.x0_mm / sc.pixel_mm) + z * self._cam_dx
        my = np.float32((s - sc.y0_mm) / sc.pixel_mm) + z * self._cam_dy
        rgb = remap_points(self.shaded, mx, my).reshape(h, w, 3).astype(np.float32)
        self._antialias(s, z.reshape(h, w), rgb)
        truths = {}
        for laser in self.rig.lasers:
            tr = self.laser_points(laser, k)
            truths[laser.name] = tr
            r0, band = self._stripe_band(laser, tr, s, rng)
            if band.size:
                gain = 255.0 * np.asarray(laser.rgb_response, np.float32)
                rgb[r0 : r0 + band.shape[0]] += band[..., None] * gain
        noise = np.empty_like(rgb)
        sd = float(self.opt.noise_sigma_dn)
        cv2.setRNGSeed(int(rng.integers(1, 2**31 - 1)))
        cv2.randn(noise, (0.0, 0.0, 0.0), (sd, sd, sd))
        # sum, round to nearest and saturate to 0..255 in one pass
        return cv2.add(rgb, noise, dtype=cv2.CV_8U), truths
