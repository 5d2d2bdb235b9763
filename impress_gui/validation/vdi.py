"""Acceptance quantities of optical 3D measuring systems in the style of VDI/VDE 2634 part 2
(Qt-free): flatness of a plane and sphere size, form and centre-distance (spacing) errors,
measured on a reconstruction's heightmap (rail-frame mm, NaN = no data)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from impress_gui.core.base import codes
from impress_gui.core.base.errors import InputError
from impress_gui.core.measure import readings as M
from impress_gui.core.reconstruction.grid import GridSpec
from impress_gui.validation.protocol import _num, crop, stats


@dataclass(frozen=True)
class Flatness:
    """Plane fitted by least squares to a region that should be flat. ``flatness_mm`` is the
    range of the residuals after leaving out the 0.3 % most extreme cells (as VDI/VDE 2634-2
    permits), ``range_mm`` the range of all; ``offset_mm`` is the plane's height at the region's
    centre minus the expected height, ``tilt_deg`` its tilt."""

    flatness_mm: float
    range_mm: float
    rms_mm: float
    offset_mm: float
    tilt_deg: float
    n: int
    x_mm: tuple[float, float]
    y_mm: tuple[float, float]

    def to_json(self) -> dict[str, Any]:
        return {k: (_num(v) if isinstance(v, float) else v) for k, v in self.__dict__.items()}


def flatness(
    height: np.ndarray,
    spec: GridSpec,
    x_range: Sequence[float],
    y_range: Sequence[float],
    expected_mm: float = 0.0,
    trim: float = 0.003,
) -> Flatness:
    sub, sspec = crop(height, spec, x_range, y_range)
    plane = M.plane_from_region(sub, sspec, x_range, y_range)
    res = np.asarray(M.levelled(sub, sspec, plane), np.float64)
    res = res[np.isfinite(res)]
    lo, hi = np.quantile(res, [trim / 2, 1 - trim / 2])
    cx, cy = 0.5 * sum(x_range), 0.5 * sum(y_range)
    return Flatness(
        float(hi - lo),
        float(res.max() - res.min()),
        float(np.sqrt(np.mean(res**2))),
        float(plane.at(cx, cy) - expected_mm),
        plane.tilt_deg,
        int(res.size),
        (float(x_range[0]), float(x_range[1])),
        (float(y_range[0]), float(y_range[1])),
    )


@dataclass(frozen=True)
class SphereFit:
    centre_mm: tuple[float, float, float]  # x, y (rail) and height
    radius_mm: float
    form_mm: float  # range of radial residuals (0.3 % trimmed): VDI/VDE 2634-2 PF
    rms_mm: float
    n: int


def fit_sphere(points: np.ndarray, trim: float = 0.003) -> SphereFit:
    """Least-squares sphere through ``(N, 3)`` points: algebraic start, geometric refinement."""
    from scipy.optimize import least_squares

    p = np.asarray(points, np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 10:
        raise InputError("a sphere fit needs at least 10 points", code=codes.E_VAL_SPHERE)
    c0 = p.mean(0)
    q = p - c0
    a = np.column_stack([2 * q, np.ones(len(q))])
    sol, *_ = np.linalg.lstsq(a, (q**2).sum(1), rcond=None)
    centre, r0 = sol[:3], math.sqrt(max(sol[3] + sol[:3] @ sol[:3], 1e-12))

    def resid(v: np.ndarray) -> np.ndarray:
        return np.linalg.norm(q - v[:3], axis=1) - v[3]

    fit = least_squares(resid, np.r_[centre, r0], method="lm")
    d = resid(fit.x)
    lo, hi = np.quantile(d, [trim / 2, 1 - trim / 2])
    c = fit.x[:3] + c0
    return SphereFit(
        (float(c[0]), float(c[1]), float(c[2])),
        float(abs(fit.x[3])),
        float(hi - lo),
        float(np.sqrt(np.mean(d**2))),
        len(p),
    )


def sphere_points(
    height: np.ndarray,
    spec: GridSpec,
    x_mm: float,
    y_mm: float,
    radius_mm: float,
    fraction: float = 0.85,
) -> np.ndarray:
    """Cells with data within ``fraction * radius`` (horizontally) of a sphere's nominal centre,
    as ``(N, 3)`` points (x, y, height): the cap the scanner sees well."""
    r = fraction * radius_mm
    sub, sspec = crop(height, spec, (x_mm - r, x_mm + r), (y_mm - r, y_mm + r))
    xs, ys = np.meshgrid(sspec.xs(), sspec.ys())
    ok = np.isfinite(sub) & ((xs - x_mm) ** 2 + (ys - y_mm) ** 2 <= r * r)
    return np.column_stack([xs[ok], ys[ok], sub[ok].astype(np.float64)])


def sphere_errors(
    height: np.ndarray, spec: GridSpec, spheres: Sequence[tuple[float, float, float, float]]
) -> dict[str, Any]:
    """Fit each sphere ``(x, y, centre height, radius)`` (rail mm) and compare: diameter
    errors (PS), form (PF) and the distance errors of every pair of centres (SD)."""
    fits: list[SphereFit | None] = []
    rows: list[dict[str, Any]] = []
    for x, y, z, r in spheres:
        try:
            f = fit_sphere(sphere_points(height, spec, x, y, r))
        except InputError as exc:
            rows.append({"nominal": [x, y, z, r], "error": str(exc)})
            fits.append(None)
            continue
        fits.append(f)
        rows.append(
            {
                "nominal_centre_mm": [x, y, z],
                "nominal_diameter_mm": 2 * r,
                "centre_mm": [_num(v) for v in f.centre_mm],
                "diameter_mm": _num(2 * f.radius_mm),
                "diameter_error_mm": _num(2 * f.radius_mm - 2 * r),
                "form_mm": _num(f.form_mm),
                "rms_mm": _num(f.rms_mm),
                "n": f.n,
            }
        )
    dist: list[dict[str, Any]] = []
    sd: list[float] = []  # absolute spacing errors as recorded; NaN (failed) when not finite
    for i in range(len(spheres)):
        for j in range(i + 1, len(spheres)):
            fi, fj = fits[i], fits[j]
            if fi is None or fj is None:
                continue
            true = math.dist(spheres[i][:3], spheres[j][:3])
            meas = math.dist(fi.centre_mm, fj.centre_mm)
            err = _num(meas - true)
            dist.append(
                {
                    "pair": [i, j],
                    "nominal_mm": round(true, 4),
                    "measured_mm": _num(meas),
                    "error_mm": err,
                }
            )
            sd.append(math.nan if err is None else abs(err))
    d_err = [abs(2 * f.radius_mm - 2 * s[3]) for f, s in zip(fits, spheres) if f is not None]
    forms = [f.form_mm for f in fits if f is not None]
    return {
        "spheres": rows,
        "distances": dist,
        "diameter": stats(d_err).to_json(),
        "spacing": stats(sd).to_json(),
        "form_max_mm": _num(max(forms)) if forms else None,
        "failed": sum(f is None for f in fits),
    }
