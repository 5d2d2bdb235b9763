"""Frame renderer: ray casting of the heightfield from the camera and from each laser.

Every pixel's ray is intersected with the heightfield (camera occlusion); each laser's fan is
cast from its source (laser shadows), the lit points are kept only where the camera sees them,
and their exact projections are the stripe centres, which the renderer draws as a Gaussian
profile with speckle, saturating to white at the core.

Rays are cast by :class:`~impress_gui.sim.raycast.HeightfieldCaster` (a min/max pyramid walk,
exact at occluding edges); pixels beside depth steps average several rays over their area.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from impress_gui.sim.raycast import HeightfieldCaster, remap_points
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
    #: pixels next to a depth step of more than ``antialias_step_mm`` average
    #: ``antialias x antialias`` rays over their area (1 = one ray per pixel everywhere)
    antialias: int = 3
    antialias_step_mm: float = 4.0
    #: rolling shutter: the time (s) from one image row's exposure to the next (0: a global
    #: shutter, the whole frame at its time); row ``v`` of frame ``k`` shows the scene at
    #: ``k / fps + v * line_time_s``, the camera and its lasers moved on by then
    line_time_s: float = 0.0
    #: the stripe's light follows the soil row by row: each pixel of the stripe reflects the
    #: laser in proportion to the albedo of the surface point it sees (a real surface); off,
    #: each column's stripe is scaled by the albedo at its exact centre (renders before
    #: 2026-12-06, and still the default: docs/accuracy.md, "A stripe whose light follows
    #: the soil")
    stripe_follows_soil: bool = False


@dataclass
class StripeTruth:
    """Exact stripe centres of one laser in one frame: distorted pixel coordinates ``(N, 2)`` of
    the visible lit surface points (dense, about 6 per pixel column) and their rail positions."""

    uv_px: np.ndarray
    points_rail_mm: np.ndarray


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


def fold_radius(intr) -> float:
    """The normalized radius (tan of the angle off the optical axis) where the lens model's
    radial distortion stops growing: beyond it a point outside the view maps back into the
    picture. ``inf`` when it keeps growing up to a radius of 5 (85 deg off axis)."""
    d = np.zeros(8)
    d[: min(8, intr.dist_coeffs.size)] = intr.dist_coeffs[:8]
    k1, k2, _, _, k3, k4, k5, k6 = d
    r = np.linspace(0.0, 5.0, 50001)
    r2 = r * r
    rd = r * (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    turn = np.flatnonzero(np.diff(rd) <= 0)
    return float(r[turn[0]]) if len(turn) else float("inf")


class Renderer:
    def __init__(self, scene: Scene, rig: Rig, motion: Motion, options: RenderOptions):
        self.scene, self.rig, self.motion, self.opt = scene, rig, motion, options
        intr = rig.intrinsics
        w, h = intr.image_size
        self.width, self.height = w, h
        uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        rays = intr.rays(np.column_stack([uu.ravel(), vv.ravel()])) @ rig.rotation.T
        self.fold_radius = fold_radius(intr)
        self.ax = (rays[:, 0] / rays[:, 2]).astype(np.float32).reshape(h, w)
        self.ay = (rays[:, 1] / rays[:, 2]).astype(np.float32).reshape(h, w)
        del rays, uu, vv
        pix = scene.pixel_mm
        hm = scene.height_mm
        self.depth = np.ascontiguousarray(rig.standoff_mm - hm, dtype=np.float32)  # Z' of surface
        gx, gy = _minmod_slope(hm, 1, pix), _minmod_slope(hm, 0, pix)
        light = np.array([0.3, -0.35, 1.0])
        light /= np.linalg.norm(light)
        amb = options.ambient
        self.albedo = np.ascontiguousarray(scene.albedo)
        #: the albedo under ambient + diffuse light, grey levels (RGB uint8 on the scene grid)
        self.shaded = np.empty_like(self.albedo)
        # in bands of rows (the same values cell by cell: the float64 temporaries of a whole
        # scene are hundreds of megabytes, allocated and paged in afresh for every step)
        for r0 in range(0, hm.shape[0], 256):
            sx, sy = gx[r0:r0 + 256], gy[r0:r0 + 256]
            shade = (-sx * light[0] - sy * light[1] + light[2]) / np.sqrt(1.0 + sx * sx + sy * sy)
            factor = (amb + (1 - amb) * np.clip(shade, 0, 1)).astype(np.float32)
            alb, out = self.albedo[r0:r0 + 256], self.shaded[r0:r0 + 256]
            for c in range(3):
                out[..., c] = np.round(alb[..., c] * factor)
        del gx, gy
        self.row_max = self.depth.max(axis=1)  # deepest (lowest) surface of each grid row
        self.row_min = self.depth.min(axis=1)  # shallowest (highest)
        self.sigma_px = options.stripe_sigma_px or max(0.9, 1.4 * w / 1920.0)
        # camera rays in map units (cells per mm of depth); the origin moves along y only
        self._cam_dx = (self.ax / np.float32(pix)).ravel()
        self._cam_dy = (self.ay / np.float32(pix)).ravel()
        self.caster = HeightfieldCaster(self.depth, scene.x0_mm, scene.y0_mm, pix)
        self.bounds = self.caster.bounds
        # the camera rays' first bounds query covers the whole depth range: its level and
        # footprint centre relative to the moving optical centre never change
        self._cam_z = (np.float32(self.bounds.zmin - 0.01), np.float32(self.bounds.zmax + 0.01))
        zm = np.float32(0.5) * (self._cam_z[0] + self._cam_z[1])
        reach = np.maximum(np.abs(self._cam_dx), np.abs(self._cam_dy)) * (
            np.float32(0.5) * (self._cam_z[1] - self._cam_z[0])) + np.float32(1.0)
        self._cam_first = (self._cam_dx * zm, self._cam_dy * zm, self.bounds.level_table(reach))

    # ----- sampling helpers ------------------------------------------------------------
    def _sample(self, img, x, y, interp=cv2.INTER_LINEAR):
        """Sample a scene-grid image at rail positions ``x, y`` (mm, any equal shapes)."""
        return self.caster.sample(img, x, y, interp)

    def _depth_range(self, y_lo: float, y_hi: float) -> tuple[float, float]:
        s = self.scene
        i0 = int(np.clip((y_lo - s.y0_mm) / s.pixel_mm - 2, 0, len(self.row_min) - 1))
        i1 = int(np.clip((y_hi - s.y0_mm) / s.pixel_mm + 2, i0 + 1, len(self.row_min)))
        return float(self.row_min[i0:i1].min()), float(self.row_max[i0:i1].max())

    def march(self, ox, oy, oz, ax, ay, z_lo, z_hi, **options) -> np.ndarray:
        """First depth where rays meet the surface: see :meth:`HeightfieldCaster.march`."""
        return self.caster.march(ox, oy, oz, ax, ay, z_lo, z_hi, **options)

    # ----- one frame -------------------------------------------------------------------
    def travel(self, k: int) -> float:
        return float(self.motion.travel_mm(k / self.motion.fps))

    def row_travel(self, k: int, rows) -> np.ndarray:
        """The travel (mm) at which rows ``rows`` (pixel row coordinates) of frame ``k`` are
        exposed: the frame's own for a global shutter."""
        t = k / self.motion.fps + np.asarray(rows, float) * self.opt.line_time_s
        return np.asarray(self.motion.travel_mm(t), float)

    def _camera_depth(self, s: float, rays: slice = slice(None)) -> np.ndarray:
        """Depth of the surface seen by every pixel (or the pixels ``rays`` of the flattened
        image), ``(H*W,)`` float32."""
        sc = self.scene
        dx, dy = self._cam_dx[rays], self._cam_dy[rays]
        n = dx.shape[0]
        bx = np.float32(-sc.x0_mm / sc.pixel_mm)
        by = np.float32((s - sc.y0_mm) / sc.pixel_mm)
        zl = np.full(n, self._cam_z[0], np.float32)
        zh = np.full(n, self._cam_z[1], np.float32)
        cx, cy, table = self._cam_first
        first = self.bounds.query_at(bx + cx[rays], by + cy[rays],
                                     tuple(v[rays] for v in table))
        z = self.caster.cast(bx, by, dx, dy, zl, zh, refine=8, ftol=2e-3,
                       ztol=2e-3, first=first)
        return np.where(np.isfinite(z), z, zh)

    def _antialias(self, s: float, z: np.ndarray, rgb: np.ndarray, row0: int = 0) -> None:
        """Average ``n x n`` rays over the area of pixels beside depth steps (occluding edges:
        the sensor integrates over the pixel, so an edge falls between pixels as a blend).
        ``z`` and ``rgb`` may be a band of rows starting at image row ``row0``."""
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
        mv = (v[None, :] + row0 + dv[:, None]).astype(np.float32).ravel()
        sc = self.scene
        inv = np.float32(1.0 / sc.pixel_mm)
        dx = remap_points(self.ax, mu, mv) * inv  # ray slopes vary smoothly over a pixel
        dy = remap_points(self.ay, mu, mv) * inv
        bx = np.float32(-sc.x0_mm / sc.pixel_mm)
        by = np.float32((s - sc.y0_mm) / sc.pixel_mm)
        zl = np.full(dx.size, self.bounds.zmin - 0.01, np.float32)
        zh = np.full(dx.size, self.bounds.zmax + 0.01, np.float32)
        zs = self.caster.cast(bx, by, dx, dy, zl, zh, refine=8, ftol=2e-3, ztol=2e-3)
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
        """Cast the laser's fan from its source; keep lit points the camera can see (with a
        rolling shutter: each where the row that shows it was exposed)."""
        if self.opt.line_time_s <= 0:
            uv, p, keep = self._fan(laser, self.travel(k))
            return StripeTruth(uv[keep], p[keep])
        return self._fan_rolling(laser, k)

    def _fan_rolling(self, laser: Laser, k: int) -> StripeTruth:
        """The fan's lit points under a rolling shutter: the fan cast at the travel of the
        first and of the last row its stripe reaches, each ray's point taken between the two
        where its own row's time and travel agree (the carriage moves well under a
        millimetre during a frame's readout, so the point moves along a straight piece of
        surface; a ray whose point jumps between the two - an occluding edge - keeps the
        cast whose time is nearer its row's)."""
        s0 = self.travel(k)
        uv0, _, keep0 = self._fan(laser, s0)
        if not keep0.any():
            return StripeTruth(uv0[keep0], np.zeros((0, 3)))
        v_lo = float(np.clip(uv0[keep0, 1].min() - 2.0, 0.0, self.height - 1))
        v_hi = float(np.clip(uv0[keep0, 1].max() + 2.0, v_lo + 1.0, self.height + 1))
        sa, sb = (float(v) for v in self.row_travel(k, [v_lo, v_hi]))
        uva, pa, ka = self._fan(laser, sa)
        uvb, pb, kb = self._fan(laser, sb)
        ds = sb - sa
        both = ka & kb & (np.linalg.norm(pb - pa, axis=1) <= 3.0 * abs(ds) + 0.05)
        uv = np.where(ka[:, None], uva, uvb)
        p = np.where(ka[:, None], pa, pb)
        if abs(ds) > 1e-12:
            # the row as the travel changes (linear between the casts) against the travel
            # at which each row is exposed (linear in the row over the bracket): where they meet
            alpha = (uvb[both, 1] - uva[both, 1]) / ds
            beta = ds / (v_hi - v_lo)
            v = (uva[both, 1] - alpha * beta * v_lo) / (1.0 - alpha * beta)
            f = (self.row_travel(k, v) - sa) / ds
            uv[both] = uva[both] + f[:, None] * (uvb[both] - uva[both])
            p[both] = pa[both] + f[:, None] * (pb[both] - pa[both])
        one = (ka | kb) & ~both
        if one.any():
            # the cast whose travel is nearer the one its row was exposed at
            sv_a = self.row_travel(k, uva[one, 1])
            sv_b = self.row_travel(k, uvb[one, 1])
            use_b = ~ka[one] | (kb[one] & (np.abs(sv_b - sb) < np.abs(sv_a - sa)))
            idx = np.flatnonzero(one)[use_b]
            uv[idx], p[idx] = uvb[idx], pb[idx]
        keep = ka | kb
        return StripeTruth(uv[keep], p[keep])

    def _fan(self, laser: Laser, s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The laser's fan cast with the carriage at travel ``s``: every ray's image point
        ``(N, 2)``, rail point ``(N, 3)`` and whether the camera sees it lit ``(N,)`` (the
        same rays at any travel)."""
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
        # only points inside the lens model's field: beyond the radius where its distortion
        # polynomial turns back (a strong barrel lens, k1 and k2 both negative), points far
        # outside the view project back into the picture - a second, phantom stripe that
        # no camera shows (random rig 15: 65 rows from the real one at the image's edge)
        with np.errstate(invalid="ignore", divide="ignore"):
            r_n = np.hypot(pc[:, 0], pc[:, 1]) / pc[:, 2]
        inside = (uv[:, 0] > -2) & (uv[:, 0] < self.width + 1) & (uv[:, 1] > -2) & (
            uv[:, 1] < self.height + 1) & (pc[:, 2] > 0) & (r_n < self.fold_radius)
        keep = np.zeros(len(p), bool)
        keep[np.flatnonzero(vis)[inside]] = True
        uv_all = np.full((len(p), 2), np.nan)
        uv_all[vis] = uv
        return uv_all, p, keep

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
        follows = bool(self.opt.stripe_follows_soil)
        # following the soil: the albedo of each pixel's own surface point, on the band below
        alb = 1.0 if follows else (
            self._sample(self.albedo, p[:, 0], p[:, 1])[:, ch].astype(np.float64) / 255.0)
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
        sums = np.bincount((rows - r0) * w + cols, weights=wgt, minlength=(r1 - r0) * w)
        band = sums.reshape(r1 - r0, w).astype(np.float32)
        if follows:
            band *= self._band_albedo(s, r0, r1, ch)
        c = self.opt.speckle_contrast
        if c > 0:
            # granular multiplicative speckle (gamma-distributed, grain ~1 px), in the band only
            shape_k = 1.0 / (c * c)
            sp = rng.gamma(shape_k, 1.0 / shape_k, (r1 - r0, w)).astype(np.float32)
            sp = np.asarray(cv2.GaussianBlur(sp, (0, 0), 0.6), np.float32)
            sp /= sp.mean()
            band *= sp
        return r0, band

    def _band_albedo(self, s: float, r0: int, r1: int, ch: int) -> np.ndarray:
        """The albedo (0..1, channel ``ch``) of the surface point each pixel of image rows
        ``r0:r1`` sees with the camera at travel ``s``, ``(r1 - r0, W)`` float32."""
        sc, w = self.scene, self.width
        sl = slice(r0 * w, r1 * w)
        z = self._camera_depth(s, sl)
        mx = np.float32(-sc.x0_mm / sc.pixel_mm) + z * self._cam_dx[sl]
        my = np.float32((s - sc.y0_mm) / sc.pixel_mm) + z * self._cam_dy[sl]
        alb = remap_points(np.ascontiguousarray(self.albedo[..., ch]), mx, my)
        return (alb.reshape(r1 - r0, w) / np.float32(255.0)).astype(np.float32)

    def _rolling_background(self, k: int) -> np.ndarray:
        """The lit surface under a rolling shutter: bands of rows, each at the travel of its
        middle row (a band spans at most 0.005 mm of travel, or one row)."""
        h, w = self.height, self.width
        sc = self.scene
        per_row = max(self.motion.speed_mm_s * self.opt.line_time_s, 1e-12)
        rows = int(np.clip(np.floor(0.005 / per_row), 1, h))
        rgb = np.empty((h, w, 3), np.float32)
        for r0 in range(0, h, rows):
            r1 = min(h, r0 + rows)
            sb = float(self.row_travel(k, 0.5 * (r0 + r1 - 1)))
            sl = slice(r0 * w, r1 * w)
            z = self._camera_depth(sb, sl)
            mx = np.float32(-sc.x0_mm / sc.pixel_mm) + z * self._cam_dx[sl]
            my = np.float32((sb - sc.y0_mm) / sc.pixel_mm) + z * self._cam_dy[sl]
            band = remap_points(self.shaded, mx, my).reshape(r1 - r0, w, 3).astype(np.float32)
            self._antialias(sb, z.reshape(r1 - r0, w), band, row0=r0)
            rgb[r0:r1] = band
        return rgb

    def render(self, k: int) -> tuple[np.ndarray, dict[str, StripeTruth]]:
        """Frame ``k`` as RGB uint8 ``(H, W, 3)`` and the exact stripe centres of each laser."""
        rng = np.random.default_rng([self.opt.seed, k])
        s = self.travel(k)
        h, w = self.height, self.width
        sc = self.scene
        if self.opt.line_time_s <= 0:
            z = self._camera_depth(s)
            mx = np.float32(-sc.x0_mm / sc.pixel_mm) + z * self._cam_dx
            my = np.float32((s - sc.y0_mm) / sc.pixel_mm) + z * self._cam_dy
            rgb = remap_points(self.shaded, mx, my).reshape(h, w, 3).astype(np.float32)
            self._antialias(s, z.reshape(h, w), rgb)
        else:
            rgb = self._rolling_background(k)
        truths = {}
        for laser in self.rig.lasers:
            tr = self.laser_points(laser, k)
            truths[laser.name] = tr
            s_laser = s if self.opt.line_time_s <= 0 or not len(tr.uv_px) else float(
                self.row_travel(k, float(np.median(tr.uv_px[:, 1]))))
            r0, band = self._stripe_band(laser, tr, s_laser, rng)
            if band.size:
                gain = 255.0 * np.asarray(laser.rgb_response, np.float32)
                rgb[r0 : r0 + band.shape[0]] += band[..., None] * gain
        noise = np.empty_like(rgb)
        sd = float(self.opt.noise_sigma_dn)
        cv2.setRNGSeed(int(rng.integers(1, 2**31 - 1)))
        cv2.randn(noise, (0.0, 0.0, 0.0), (sd, sd, sd))  # type: ignore[call-overload]  # stub lacks scalar tuples
        # sum, round to nearest and saturate to 0..255 in one pass
        return cv2.add(rgb, noise, dtype=cv2.CV_8U), truths
