"""Levelling and shading of a heightmap (Qt-free): a reference plane from three points or from
a region (least squares), heights relative to it, and a hillshade under an oblique light.
Re-exported by :mod:`impress_gui.core.measure.readings`."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from impress_gui.core.base import codes
from impress_gui.core.base.errors import InputError
from impress_gui.core.reconstruction.grid import GridSpec


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a)
    a.setflags(write=False)
    return a


# ----- levelling -----------------------------------------------------------------------------
@dataclass(frozen=True)
class Plane:
    """Reference plane ``z = a*x + b*y + c`` (mm); ``rms_mm`` of the fit residuals."""

    a: float
    b: float
    c: float
    rms_mm: float = 0.0
    n: int = 3

    def at(self, x_mm, y_mm):
        return self.a * np.asarray(x_mm) + self.b * np.asarray(y_mm) + self.c

    @property
    def tilt_deg(self) -> float:
        return math.degrees(math.atan(math.hypot(self.a, self.b)))

    def to_json(self) -> dict:
        return {"a": self.a, "b": self.b, "c": self.c, "rms_mm": self.rms_mm, "n": self.n}


def plane_from_points(points: Sequence[Sequence[float]]) -> Plane:
    """The plane through three ``(x, y, z)`` points; InputError when they are collinear or
    a height is missing."""
    pts = np.asarray(points, np.float64)
    if pts.shape != (3, 3) or not np.isfinite(pts).all():
        raise InputError("levelling needs three points with data", code=codes.E_LEVEL)
    m = np.column_stack([pts[:, 0], pts[:, 1], np.ones(3)])
    if abs(np.linalg.det(m)) < 1e-6:
        raise InputError("the three levelling points are on one line", code=codes.E_LEVEL)
    a, b, c = np.linalg.solve(m, pts[:, 2])
    return Plane(float(a), float(b), float(c), 0.0, 3)


def plane_from_region(
    height: np.ndarray,
    spec: GridSpec,
    x_range: Sequence[float],
    y_range: Sequence[float],
    mask: np.ndarray | None = None,
) -> Plane:
    """Least-squares plane through every cell with data in a rectangle (and ``mask``)."""
    (xa, xb), (ya, yb) = sorted(x_range), sorted(y_range)
    p = spec.pixel_mm
    j0 = max(0, math.ceil((xa - spec.x0_mm) / p))
    j1 = min(spec.shape[1], math.floor((xb - spec.x0_mm) / p) + 1)
    i0 = max(0, math.ceil((ya - spec.y0_mm) / p))
    i1 = min(spec.shape[0], math.floor((yb - spec.y0_mm) / p) + 1)
    sub = height[i0:i1, j0:j1] if i1 > i0 and j1 > j0 else np.zeros((0, 0), np.float32)
    ok = np.isfinite(sub)
    if mask is not None and sub.size:
        ok &= mask[i0:i1, j0:j1]
    ii, jj = np.nonzero(ok)
    if ii.size < 3:
        raise InputError(
            "the levelling region has fewer than three cells with data", code=codes.E_LEVEL
        )
    # centred coordinates keep the normal equations well conditioned
    x = (jj + j0) * p + spec.x0_mm
    y = (ii + i0) * p + spec.y0_mm
    z = sub[ok].astype(np.float64)
    xm, ym, zm = x.mean(), y.mean(), z.mean()
    m = np.column_stack([x - xm, y - ym])
    if np.linalg.matrix_rank(m.T @ m) < 2:
        raise InputError("the levelling region is a line; draw an area", code=codes.E_LEVEL)
    (a, b), *_ = np.linalg.lstsq(m, z - zm, rcond=None)
    res = z - zm - m @ np.array([a, b])
    return Plane(
        float(a),
        float(b),
        float(zm - a * xm - b * ym),
        float(np.sqrt(np.mean(res**2))),
        int(z.size),
    )


def levelled(height: np.ndarray, spec: GridSpec, plane: Plane | None) -> np.ndarray:
    """Heights relative to ``plane`` (float32, NaN kept); the input itself when None."""
    if plane is None:
        return height
    xs = spec.xs().astype(np.float32)
    out = np.empty(height.shape, np.float32)
    for r0 in range(0, height.shape[0], 2048):
        r1 = min(height.shape[0], r0 + 2048)
        ys = (spec.ys()[r0:r1]).astype(np.float64)
        ref = (plane.a * xs)[None, :] + (plane.b * ys + plane.c).astype(np.float32)[:, None]
        np.subtract(height[r0:r1], ref, out=out[r0:r1])
    return _frozen(out)


# ----- hillshade -----------------------------------------------------------------------------
def hillshade(
    height: np.ndarray,
    pixel_mm: float,
    azimuth_deg: float = 315.0,
    elevation_deg: float = 45.0,
    z_factor: float = 1.0,
    chunk_rows: int = 1024,
) -> np.ndarray:
    """Lambertian shading in [0, 1] (float32, NaN where no data) under a light from
    ``azimuth_deg`` (clockwise from +y) at ``elevation_deg`` above the surface. Slopes use
    central differences, one-sided next to missing data."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    light = np.array(
        [math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)], np.float32
    )
    h, w = height.shape
    out = np.empty((h, w), np.float32)
    for r0 in range(0, h, chunk_rows):
        r1 = min(h, r0 + chunk_rows)
        a, b = max(0, r0 - 1), min(h, r1 + 1)
        z = np.asarray(height[a:b], np.float32) * np.float32(z_factor)
        gx = _gradient(z, 1, pixel_mm)
        gy = _gradient(z, 0, pixel_mm)
        norm = np.sqrt(gx * gx + gy * gy + 1.0)
        shade = (-gx * light[0] - gy * light[1] + light[2]) / norm
        np.clip(shade, 0.0, 1.0, out=shade)
        shade[~np.isfinite(z)] = np.nan
        out[r0:r1] = shade[r0 - a : r0 - a + (r1 - r0)]
    return out


def _gradient(z: np.ndarray, axis: int, step: float) -> np.ndarray:
    zp = np.swapaxes(z, 0, axis)
    lo = np.empty_like(zp)
    hi = np.empty_like(zp)
    lo[1:], lo[0] = zp[:-1], np.nan
    hi[:-1], hi[-1] = zp[1:], np.nan
    lo_ok, hi_ok = np.isfinite(lo), np.isfinite(hi)
    lo = np.where(lo_ok, lo, zp)
    hi = np.where(hi_ok, hi, zp)
    span = (lo_ok.astype(np.float32) + hi_ok.astype(np.float32)) * np.float32(step)
    with np.errstate(invalid="ignore", divide="ignore"):
        g = np.where(span > 0, (hi - lo) / span, 0.0).astype(np.float32)
    g[~np.isfinite(g)] = 0.0
    return np.swapaxes(g, 0, axis)
