"""Frame renderer: ray casting of the heightfield from the camera and from each laser.

Every pixel's ray is intersected with the heightfield (camera occlusion); each laser's fan is
cast from its source (laser shadows), the lit points are kept only where the camera sees them,
and their exact projections are the stripe centres, which the renderer draws as a Gaussian
profile with speckle, saturating to white at the core.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from impress_gui.sim.rig import Laser, Motion, Rig
from impress_gui.sim.scenes import Scene


@dataclass(frozen=True)
class RenderOptions:
    noise_sigma_dn: float = 2.0
    speckle_contrast: float = 0.3
    stripe_sigma_px: float | None = None  # default: 1.4 px at 1920 wide, scaled, >= 0.9
    laser_peak: float = 4.0  # peak laser signal in multiples of the sensor's full scale
    ambient: float = 0.45
    seed: int = 0


@dataclass
class StripeTruth:
    """Exact stripe centres of one laser in one frame: distorted pixel coordinates ``(N, 2)`` of
    the visible lit surface points (dense, about 6 per pixel column) and their rail positions."""

    uv_px: np.ndarray
    points_rail_mm: np.ndarray


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
        hm = scene.height_mm
        self.depth = (rig.standoff_mm - hm).astype(np.float32)  # Z' of the surface
        gy, gx = np.gradient(hm.astype(np.float32), scene.pixel_mm)
        nz = 1.0 / np.sqrt(1.0 + gx * gx + gy * gy)
        light = np.array([0.3, -0.35, 1.0])
        light /= np.linalg.norm(light)
        shade = np.clip((-gx * light[0] - gy * light[1] + light[2]) * nz, 0, 1)
        alb = scene.albedo.astype(np.float32) / 255.0
        self.base = np.ascontiguousarray(
            alb * (options.ambient + (1 - options.ambient) * shade)[..., None]
        )
        self.albedo_ch = [np.ascontiguousarray(alb[..., c]) for c in range(3)]
        self.nx, self.ny, self.nz = (-gx * nz).astype(np.float32), (-gy * nz).astype(np.float32), nz
        self.row_max = self.depth.max(axis=1)  # deepest (lowest) surface of each grid row
        self.row_min = self.depth.min(axis=1)  # shallowest (highest)
        self.sigma_px = options.stripe_sigma_px or max(0.9, 1.4 * w / 1920.0)
        self._prepare_tiles()

    # ----- sampling helpers ------------------------------------------------------------
    def _maps(self, x, y):
        s = self.scene
        return ((x - s.x0_mm) / s.pixel_mm).astype(np.float32), (
            (y - s.y0_mm) / s.pixel_mm
        ).astype(np.float32)

    def _sample(self, img, x, y, interp=cv2.INTER_LINEAR):
        mx, my = self._maps(x, y)
        shape = mx.shape
        mx, my = mx.reshape(1, -1), my.reshape(1, -1)
        out = []
        # cv2.remap handles at most 32767 destination columns per call
        for i in range(0, mx.shape[1], 32000):
            out.append(cv2.remap(img, mx[:, i : i + 32000], my[:, i : i + 32000], interp,
                                 borderMode=cv2.BORDER_REPLICATE))
        res = np.concatenate(out, axis=1)
        return res.reshape(*shape, *img.shape[2:])

    def _depth_range(self, y_lo: float, y_hi: float) -> tuple[float, float]:
        s = self.scene
        i0 = int(np.clip((y_lo - s.y0_mm) / s.pixel_mm - 2, 0, len(self.row_min) - 1))
        i1 = int(np.clip((y_hi - s.y0_mm) / s.pixel_mm + 2, i0 + 1, len(self.row_min)))
        return float(self.row_min[i0:i1].min()), float(self.row_max[i0:i1].max())

    def march(self, ox, oy, oz, ax, ay, z_lo, z_hi, step=0.8, refine=8):
        """First depth ``Z`` in ``[z_lo, z_hi]`` where the ray ``(ox + (Z-oz) ax, oy + (Z-oz) ay)``
        meets the surface; NaN where it does not. Arrays are 1-D of equal length; ``z_lo`` and
        ``z_hi`` may be per-ray arrays. The bracket found by marching is refined by the
        Illinois variant of false position."""
        n = ox.shape[0]
        z_lo = np.broadcast_to(np.asarray(z_lo, np.float64), (n,))
        z_hi = np.broadcast_to(np.asarray(z_hi, np.float64), (n,))
        lo = np.full(n, np.nan)
        hi = np.full(n, np.nan)
        f_lo = np.full(n, np.nan)
        f_hi = np.full(n, np.nan)

        def f(idx, z):
            x = ox[idx] + (z - oz[idx]) * ax[idx]
            y = oy[idx] + (z - oz[idx]) * ay[idx]
            return z - self._sample(self.depth, x, y)

        idx = np.arange(n)
        prev_z = z_lo.copy()
        prev_f = f(idx, prev_z)
        inside = prev_f >= 0  # already below the surface at the start: hit at z_lo
        lo[inside] = hi[inside] = z_lo[inside]
        f_lo[inside] = f_hi[inside] = 0.0
        idx = idx[~inside]
        pz, pf = prev_z[~inside], prev_f[~inside]
        while idx.size:
            z = np.minimum(pz + step, z_hi[idx])
            fz = f(idx, z)
            below = fz >= 0
            hit = idx[below]
            lo[hit], hi[hit], f_lo[hit], f_hi[hit] = pz[below], z[below], pf[below], fz[below]
            going = ~below & (z < z_hi[idx])
            idx, pz, pf = idx[going], z[going], fz[going]
        ok = np.flatnonzero(np.isfinite(lo) & (hi > lo))
        a, b, fa, fb = lo[ok], hi[ok], f_lo[ok], f_hi[ok]
        side = np.zeros(ok.size, np.int8)
        for _ in range(refine):
            c = b - fb * (b - a) / np.where(fb - fa != 0, fb - fa, 1.0)
            c = np.clip(c, np.minimum(a, b), np.maximum(a, b))
            fc = f(ok, c)
            pos = fc >= 0
            # Illinois: halve the stale end's value when the same side is kept twice
            fa = np.where(pos & (side == 1), fa * 0.5, fa)
            fb = np.where(~pos & (side == -1), fb * 0.5, fb)
            b, fb = np.where(pos, c, b), np.where(pos, fc, fb)
            a, fa = np.where(pos, a, c), np.where(pos, fa, fc)
            side = np.where(pos, 1, -1).astype(np.int8)
        out = np.where(np.isfinite(lo) & (hi == lo), lo, np.nan)
        out[ok] = b - fb * (b - a) / np.where(fb - fa != 0, fb - fa, 1.0)
        out[ok] = np.clip(out[ok], a, b)
        return out

    def _ray_bounds(self, s: float):
        """Per-pixel conservative depth bounds from a coarse min/max map dilated by the
        rays' largest sideways excursion over the scene's depth range."""
        x = self.ax * np.float32(self.rig.standoff_mm)
        y = np.float32(s) + self.ay * np.float32(self.rig.standoff_mm)
        t = self._tile_mm
        tx = ((x - self._tile_x0) / t).astype(np.float32)
        ty = ((y - self._tile_y0) / t).astype(np.float32)
        zlo = cv2.remap(self._tile_min, tx, ty, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        zhi = cv2.remap(self._tile_max, tx, ty, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        return zlo - 0.3, zhi + 0.3

    def _prepare_tiles(self) -> None:
        s = self.scene
        cells = max(1, int(round(2.0 / s.pixel_mm)))
        h, w = self.depth.shape
        hh, ww = (h + cells - 1) // cells * cells, (w + cells - 1) // cells * cells
        pad = np.pad(self.depth, ((0, hh - h), (0, ww - w)), mode="edge")
        blocks = pad.reshape(hh // cells, cells, ww // cells, cells)
        tmin, tmax = blocks.min(axis=(1, 3)), blocks.max(axis=(1, 3))
        self._tile_mm = cells * s.pixel_mm
        self._tile_x0 = s.x0_mm + 0.5 * (cells - 1) * s.pixel_mm - 0.5 * s.pixel_mm
        self._tile_y0 = s.y0_mm + 0.5 * (cells - 1) * s.pixel_mm - 0.5 * s.pixel_mm
        self._tile_x0 = s.x0_mm
        self._tile_y0 = s.y0_mm
        span = float(self.depth.max() - self.depth.min()) + 1.0
        slope = float(max(np.abs(self.ax).max(), np.abs(self.ay).max()))
        r = int(np.ceil(slope * span / self._tile_mm)) + 2
        k = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
        self._tile_min = cv2.erode(tmin.astype(np.float32), k, borderType=cv2.BORDER_REPLICATE)
        self._tile_max = cv2.dilate(tmax.astype(np.float32), k, borderType=cv2.BORDER_REPLICATE)
        # tile (i, j) covers cells [i*cells, (i+1)*cells): map coordinates use tile index floor
        self._tile_x0 -= 0.5 * self._tile_mm - 0.5 * s.pixel_mm
        self._tile_y0 -= 0.5 * self._tile_mm - 0.5 * s.pixel_mm

    # ----- one frame -------------------------------------------------------------------
    def travel(self, k: int) -> float:
        return float(self.motion.travel_mm(k / self.motion.fps))

    def camera_surface(self, k: int):
        """Rail-frame surface point seen by every pixel of frame ``k`` (X, Y, Z) as (H, W)."""
        s = self.travel(k)
        h, w = self.height, self.width
        zlo, zhi = self._ray_bounds(s)
        n = h * w
        zero = np.zeros(n, np.float32)
        zh = self.march(zero, zero + np.float32(s), zero, self.ax.ravel(), self.ay.ravel(),
                        zlo.ravel(), zhi.ravel(), step=1.5, refine=6)
        zh = np.where(np.isfinite(zh), zh, zhi.ravel()).reshape(h, w)
        return self.ax * zh, s + self.ay * zh, zh

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
        m = len(dirs)
        ox = np.full(m, src[0]); oy = np.full(m, src[1]); oz = np.full(m, src[2])
        zh = self.march(ox, oy, oz, ax, ay, zmin - 0.5, zmax + 0.5, step=0.7, refine=12)
        good = np.isfinite(zh)
        p = np.column_stack([src[0] + (zh - src[2]) * ax, src[1] + (zh - src[2]) * ay, zh])
        # camera visibility: the camera ray towards p must not meet the surface before p
        cam = np.array([0.0, s, 0.0])
        rel = p - cam
        with np.errstate(invalid="ignore", divide="ignore"):
            cax, cay = rel[:, 0] / rel[:, 2], rel[:, 1] / rel[:, 2]
        vis = good.copy()
        g = np.flatnonzero(good)
        zc = self.march(np.zeros(g.size), np.full(g.size, s), np.zeros(g.size), cax[g], cay[g],
                        zmin - 0.5, float(np.nanmax(zh)) + 0.5, step=0.7, refine=10)
        vis[g] = np.isfinite(zc) & (zc >= p[g, 2] - 0.08)
        pc = (rel[vis]) @ self.rig.rotation  # ideal -> camera frame (R^T applied to rows)
        uv = self.rig.intrinsics.project(pc)
        inside = (uv[:, 0] > -2) & (uv[:, 0] < self.width + 1) & (uv[:, 1] > -2) & (
            uv[:, 1] < self.height + 1)
        keep = np.flatnonzero(vis)[inside]
        order_pts = p[keep]
        return StripeTruth(uv[inside], order_pts)

    def _stripe_image(self, laser: Laser, truth: StripeTruth, rng: np.random.Generator):
        """Laser signal per pixel (multiples of full scale) for one laser."""
        h, w = self.height, self.width
        uv, pts = truth.uv_px, truth.points_rail_mm
        img = np.zeros(h * w, np.float64)
        if len(uv) < 2:
            return img.reshape(h, w)
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
        alb = self._sample(self.albedo_ch[ch], p[:, 0], p[:, 1])
        nx = self._sample(self.nx, p[:, 0], p[:, 1])
        ny = self._sample(self.ny, p[:, 0], p[:, 1])
        nz = self._sample(self.nz, p[:, 0], p[:, 1])
        d = p - (laser.source_mm + np.array([0, self.travel_cache, 0]))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        cos_inc = np.clip(-(nx * d[:, 0] + ny * d[:, 1]) + nz * d[:, 2], 0.05, 1.0)
        amp = self.opt.laser_peak * (alb / 0.4) * (0.3 + 0.7 * cos_inc)
        kk = int(np.ceil(4 * self.sigma_px))
        rows = np.floor(vc).astype(np.int64)[:, None] + np.arange(-kk, kk + 1)[None, :]
        wgt = amp[:, None] * np.exp(-0.5 * ((rows - vc[:, None]) / self.sigma_px) ** 2)
        cols = np.broadcast_to(col.astype(np.int64)[:, None], rows.shape)
        ok = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
        img += np.bincount((rows[ok] * w + cols[ok]), weights=wgt[ok], minlength=h * w)
        img = img.reshape(h, w)
        c = self.opt.speckle_contrast
        if c > 0 and rows[ok].size:
            # granular multiplicative speckle (gamma-distributed, grain ~1 px), in the band only
            r0, r1 = int(rows[ok].min()), int(rows[ok].max()) + 1
            shape_k = 1.0 / (c * c)
            sp = rng.gamma(shape_k, 1.0 / shape_k, (r1 - r0, w)).astype(np.float32)
            sp = cv2.GaussianBlur(sp, (0, 0), 0.6)
            sp /= sp.mean()
            img[r0:r1] *= sp
        return img

    def render(self, k: int) -> tuple[np.ndarray, dict[str, StripeTruth]]:
        """Frame ``k`` as RGB uint8 ``(H, W, 3)`` and the exact stripe centres of each laser."""
        rng = np.random.default_rng([self.opt.seed, k])
        self.travel_cache = self.travel(k)
        X, Y, _ = self.camera_surface(k)
        rgb = self._sample(self.base, X, Y) * 255.0  # (H, W, 3)
        truths = {}
        for laser in self.rig.lasers:
            tr = self.laser_points(laser, k)
            truths[laser.name] = tr
            sig = self._stripe_image(laser, tr, rng)
            for c in range(3):
                rgb[..., c] += 255.0 * laser.rgb_response[c] * sig
        rgb += rng.normal(0.0, self.opt.noise_sigma_dn, rgb.shape)
        return np.clip(rgb + 0.5, 0, 255).astype(np.uint8), truths
