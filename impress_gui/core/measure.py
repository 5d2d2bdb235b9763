"""Measuring a reconstruction (Qt-free): every number the viewer shows comes from here.

Coordinates are rail-frame millimetres on the reconstruction's grid (:class:`GridSpec`): cell
``[i, j]`` is centred at ``x = x0_mm + j * pixel_mm``, ``y = y0_mm + i * pixel_mm``; heights
are float32 mm with NaN for no data. All functions work on the full-resolution arrays.

- :func:`load_reconstruction` - a reconstruction folder as an immutable :class:`ReconData`;
- :func:`readout` - the height at a point, averaged over a radius (NaN-aware);
- :func:`ruler` - xy and 3D distance and height difference between two points;
- :func:`line_profile` - heights along a segment, averaged across a width, bilinear sampling;
- :func:`step_height` - two reference bands on a profile: mean +- SD of each, and B - A;
- :func:`width_at_level` - a feature's width where the profile crosses a level;
- :func:`plane_from_points`, :func:`plane_from_region`, :func:`levelled` - levelling;
- :func:`hillshade` - an oblique virtual light;
- :func:`profile_csv`, :func:`measurements_csv` - CSV text.
"""

from __future__ import annotations

import csv
import io
import json
import math
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from types import MappingProxyType

import numpy as np

from impress_gui.core.errors import FormatError, InputError
from impress_gui.core.grid import GridSpec

RECON_FORMAT = "impress.reconstruction"
LAYER_FILES = {
    "fused": "heightmap.tif",
    "green": "height_green.tif",
    "red": "height_red.tif",
    "difference": "difference.tif",
    "contribution": "contribution.tif",
}
MIN_BILINEAR_WEIGHT = 0.5  # a sample is data when at least half its bilinear support is


def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a)
    a.setflags(write=False)
    return a


# ----- loading ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class ReconData:
    """A reconstruction in memory. Arrays are read-only, row-major ``(rows along y, cols
    along x)``; ``layers`` holds float32 mm maps ("fused", "green", "red", "difference") and the
    uint8 "contribution" codes; ``texture_rgb`` is ``(H, W, 3)`` uint8 or None."""

    spec: GridSpec
    layers: Mapping[str, np.ndarray]
    texture_rgb: np.ndarray | None = None
    metadata: Mapping = field(default_factory=dict)
    folder: Path | None = None

    @property
    def height_mm(self) -> np.ndarray:
        return self.layers["fused"]

    @classmethod
    def from_arrays(
        cls,
        spec: GridSpec,
        height_mm: np.ndarray,
        texture_rgb=None,
        metadata: Mapping | None = None,
        **layers: np.ndarray,
    ) -> ReconData:
        if tuple(height_mm.shape) != tuple(spec.shape):
            raise InputError(f"height map {height_mm.shape} does not match grid {spec.shape}")
        all_layers = {"fused": _frozen(np.asarray(height_mm, np.float32))}
        all_layers.update({k: _frozen(v) for k, v in layers.items()})
        tex = None if texture_rgb is None else _frozen(texture_rgb)
        return cls(spec, MappingProxyType(all_layers), tex, MappingProxyType(dict(metadata or {})))


def load_reconstruction(
    folder: str | Path, layers: Sequence[str] = tuple(LAYER_FILES)
) -> ReconData:
    """Read a reconstruction folder written by :func:`impress_gui.core.pipeline.process_files`.

    Raises FormatError for a missing/damaged metadata.json, an unknown format or version, or a
    map whose shape is not the grid's."""
    import tifffile

    folder = Path(folder)
    meta_path = folder / "metadata.json"
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise FormatError(
            f"{folder}: not a reconstruction (no metadata.json)", code="E-FILE-MISSING"
        ) from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise FormatError(f"{meta_path}: damaged ({exc})") from None
    if not isinstance(meta, dict) or meta.get("format") != RECON_FORMAT:
        raise FormatError(f"{meta_path}: not an {RECON_FORMAT} document")
    if meta.get("version") != 1:
        raise FormatError(f"{meta_path}: unknown version {meta.get('version')!r}")
    try:
        g = meta["grid"]
        spec = GridSpec(
            float(g["x0_mm"]),
            float(g["y0_mm"]),
            float(g["pixel_mm"]),
            (int(g["shape"][0]), int(g["shape"][1])),
        )
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise FormatError(f"{meta_path}: bad grid description ({exc})") from None
    if spec.pixel_mm <= 0 or min(spec.shape) < 1:
        raise FormatError(f"{meta_path}: bad grid description")
    out: dict[str, np.ndarray] = {}
    for name in ("fused", *[n for n in layers if n != "fused"]):
        if name not in LAYER_FILES:
            raise InputError(f"unknown layer {name!r}")
        path = folder / LAYER_FILES[name]
        if not path.exists():
            if name == "fused":
                raise FormatError(f"{path}: missing", code="E-FILE-MISSING")
            continue
        try:
            arr = tifffile.imread(path, maxworkers=1)
        except Exception as exc:  # noqa: BLE001 - tifffile raises many kinds
            raise FormatError(f"{path}: damaged ({exc})") from None
        if arr.shape != spec.shape:
            raise FormatError(f"{path}: shape {arr.shape} is not the grid's {spec.shape}")
        out[name] = _frozen(arr if name == "contribution" else arr.astype(np.float32, copy=False))
    tex = None
    if (folder / "texture.png").exists():
        import cv2

        bgr = cv2.imread(str(folder / "texture.png"), cv2.IMREAD_COLOR)
        if bgr is not None and bgr.shape[:2] == spec.shape:
            tex = _frozen(np.ascontiguousarray(bgr[..., ::-1]))
    return ReconData(spec, MappingProxyType(out), tex, MappingProxyType(meta), folder.resolve())


# ----- point readout and ruler ---------------------------------------------------------------
@dataclass(frozen=True)
class Readout:
    """Height at ``(x_mm, y_mm)``: mean and SD of the cells within ``radius_mm`` (the nearest
    cell when the radius is smaller than half a cell). ``height_mm`` is NaN when none of them
    has data; ``n_cells`` is 0 outside the grid."""

    x_mm: float
    y_mm: float
    height_mm: float
    sd_mm: float
    n_valid: int
    n_cells: int
    radius_mm: float

    @property
    def has_data(self) -> bool:
        return self.n_valid > 0


def readout(
    height: np.ndarray, spec: GridSpec, x_mm: float, y_mm: float, radius_mm: float = 0.0
) -> Readout:
    p = spec.pixel_mm
    fi, fj = (y_mm - spec.y0_mm) / p, (x_mm - spec.x0_mm) / p
    r = max(0.0, float(radius_mm)) / p
    if r < 0.5:
        i, j = int(round(fi)), int(round(fj))
        inside = 0 <= i < spec.shape[0] and 0 <= j < spec.shape[1]
        v = np.array([height[i, j]], np.float64) if inside else np.zeros(0)
    else:
        i0, i1 = max(0, math.ceil(fi - r)), min(spec.shape[0] - 1, math.floor(fi + r))
        j0, j1 = max(0, math.ceil(fj - r)), min(spec.shape[1] - 1, math.floor(fj + r))
        if i0 > i1 or j0 > j1:
            v = np.zeros(0)
        else:
            ii, jj = np.mgrid[i0 : i1 + 1, j0 : j1 + 1]
            disk = (ii - fi) ** 2 + (jj - fj) ** 2 <= r * r
            v = height[i0 : i1 + 1, j0 : j1 + 1][disk].astype(np.float64)
    ok = v[np.isfinite(v)]
    mean = float(ok.mean()) if ok.size else math.nan
    sd = float(ok.std(ddof=1)) if ok.size > 1 else (0.0 if ok.size else math.nan)
    return Readout(float(x_mm), float(y_mm), mean, sd, int(ok.size), int(v.size), float(radius_mm))


@dataclass(frozen=True)
class RulerResult:
    start: Readout
    end: Readout
    xy_mm: float  # distance in the xy plane
    d3_mm: float  # 3D distance (NaN when an end has no data)
    dz_mm: float  # height of the end minus height of the start (NaN when missing)


def ruler(
    height: np.ndarray,
    spec: GridSpec,
    p0: Sequence[float],
    p1: Sequence[float],
    radius_mm: float = 0.0,
) -> RulerResult:
    a = readout(height, spec, p0[0], p0[1], radius_mm)
    b = readout(height, spec, p1[0], p1[1], radius_mm)
    xy = math.hypot(b.x_mm - a.x_mm, b.y_mm - a.y_mm)
    dz = b.height_mm - a.height_mm
    return RulerResult(a, b, xy, math.hypot(xy, dz), dz)


# ----- profiles --------------------------------------------------------------------------------
def sample_bilinear(
    height: np.ndarray, spec: GridSpec, x_mm: np.ndarray, y_mm: np.ndarray
) -> np.ndarray:
    """Bilinear heights at arbitrary points; missing corners are left out and the others
    re-weighted, and a point is NaN when less than half of its support has data."""
    p = spec.pixel_mm
    fi = (np.asarray(y_mm, np.float64) - spec.y0_mm) / p
    fj = (np.asarray(x_mm, np.float64) - spec.x0_mm) / p
    i0, j0 = np.floor(fi).astype(np.int64), np.floor(fj).astype(np.int64)
    ti, tj = fi - i0, fj - j0
    num = np.zeros(fi.shape)
    den = np.zeros(fi.shape)
    h, w = spec.shape
    for di, dj in ((0, 0), (0, 1), (1, 0), (1, 1)):
        ii, jj = i0 + di, j0 + dj
        wgt = (ti if di else 1 - ti) * (tj if dj else 1 - tj)
        inside = (ii >= 0) & (ii < h) & (jj >= 0) & (jj < w)
        v = np.full(fi.shape, np.nan)
        v[inside] = height[ii[inside], jj[inside]]
        ok = np.isfinite(v)
        num += np.where(ok, wgt * np.where(ok, v, 0.0), 0.0)
        den += np.where(ok, wgt, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den >= MIN_BILINEAR_WEIGHT - 1e-9, num / den, np.nan)


@dataclass(frozen=True)
class Profile:
    """Heights along a segment (silx-style immutable record). ``distance_mm`` runs from 0 at
    ``start`` to the segment's length; ``height_mm`` is the mean across ``width_mm`` of the
    bilinear samples with data (NaN where none); ``n_valid`` counts them per sample."""

    start: tuple[float, float]
    end: tuple[float, float]
    width_mm: float
    distance_mm: np.ndarray
    height_mm: np.ndarray
    x_mm: np.ndarray
    y_mm: np.ndarray
    n_valid: np.ndarray
    n_lines: int

    @property
    def length_mm(self) -> float:
        return math.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1])


def line_profile(
    height: np.ndarray,
    spec: GridSpec,
    p0: Sequence[float],
    p1: Sequence[float],
    width_mm: float = 0.0,
    step_mm: float | None = None,
) -> Profile:
    """Profile from ``p0`` to ``p1`` (mm), one sample per ``step_mm`` (default: one cell),
    averaged over parallel lines spaced at most a cell apart across ``width_mm``."""
    x0, y0 = float(p0[0]), float(p0[1])
    x1, y1 = float(p1[0]), float(p1[1])
    length = math.hypot(x1 - x0, y1 - y0)
    step = float(step_mm or spec.pixel_mm)
    if step <= 0:
        raise InputError("the profile step must be positive")
    n = max(2, int(round(length / step)) + 1)
    d = np.linspace(0.0, length, n)
    if length > 0:
        ux, uy = (x1 - x0) / length, (y1 - y0) / length
    else:
        ux, uy = 1.0, 0.0
    width = max(0.0, float(width_mm))
    k = int(math.ceil(width / spec.pixel_mm)) + 1 if width > 0 else 1
    offs = np.linspace(-width / 2, width / 2, k) if k > 1 else np.zeros(1)
    xs = x0 + d[None, :] * ux - offs[:, None] * uy
    ys = y0 + d[None, :] * uy + offs[:, None] * ux
    vals = sample_bilinear(height, spec, xs, ys)
    ok = np.isfinite(vals)
    cnt = ok.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(cnt > 0, np.where(ok, vals, 0.0).sum(axis=0) / cnt, np.nan)
    return Profile(
        (x0, y0),
        (x1, y1),
        width,
        _frozen(d),
        _frozen(mean),
        _frozen(x0 + d * ux),
        _frozen(y0 + d * uy),
        _frozen(cnt.astype(np.int32)),
        k,
    )


@dataclass(frozen=True)
class BandStats:
    start_mm: float
    end_mm: float
    mean_mm: float
    sd_mm: float
    n: int


@dataclass(frozen=True)
class StepHeight:
    """Two reference bands on a profile; ``difference_mm`` = mean of B - mean of A and
    ``sd_mm`` = the two SDs combined in quadrature."""

    a: BandStats
    b: BandStats
    difference_mm: float
    sd_mm: float


def band_stats(profile: Profile, band: Sequence[float]) -> BandStats:
    lo, hi = sorted((float(band[0]), float(band[1])))
    sel = (profile.distance_mm >= lo) & (profile.distance_mm <= hi)
    v = profile.height_mm[sel]
    v = v[np.isfinite(v)].astype(np.float64)
    mean = float(v.mean()) if v.size else math.nan
    sd = float(v.std(ddof=1)) if v.size > 1 else math.nan
    return BandStats(lo, hi, mean, sd, int(v.size))


def step_height(profile: Profile, band_a: Sequence[float], band_b: Sequence[float]) -> StepHeight:
    """Band A (e.g. tread top) and band B (e.g. groove floor), given as distance ranges."""
    a, b = band_stats(profile, band_a), band_stats(profile, band_b)
    return StepHeight(a, b, b.mean_mm - a.mean_mm, math.hypot(a.sd_mm, b.sd_mm))


def level_crossings(profile: Profile, level_mm: float, max_gap_mm: float = 2.0) -> np.ndarray:
    """Distances where the profile crosses ``level_mm``, linear between consecutive samples
    with data. Across a gap of missing data (at most ``max_gap_mm``: an occluded or shadowed
    wall foot) the edge is put at the last sample of the higher side: a wall hides or
    shadows the lower surface beside it, never its own top."""
    h, d = profile.height_mm, profile.distance_mm
    valid = np.nonzero(np.isfinite(h))[0]
    if valid.size < 2:
        return np.zeros(0)
    i0, i1 = valid[:-1], valid[1:]
    s0, s1 = h[i0] - level_mm, h[i1] - level_mm
    cross = ((s0 < 0) != (s1 < 0)) & (d[i1] - d[i0] <= max_gap_mm + 1e-9)
    i0, i1, s0, s1 = i0[cross], i1[cross], s0[cross], s1[cross]
    adjacent = i1 - i0 == 1
    t = s0 / (s0 - s1)
    lin = d[i0] + t * (d[i1] - d[i0])
    high_side = np.where(s0 > s1, d[i0], d[i1])
    return np.where(adjacent, lin, high_side)


@dataclass(frozen=True)
class Width:
    left_mm: float
    right_mm: float
    width_mm: float
    level_mm: float


def width_at_level(profile: Profile, level_mm: float, around_mm: float) -> Width:
    """The feature containing distance ``around_mm``: the nearest crossings of ``level_mm``
    before and after it (e.g. a slot's width at half its depth). NaN when one is missing."""
    c = level_crossings(profile, level_mm)
    left = c[c <= around_mm]
    right = c[c > around_mm]
    lo = float(left.max()) if left.size else math.nan
    hi = float(right.min()) if right.size else math.nan
    return Width(lo, hi, hi - lo, float(level_mm))


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
        raise InputError("levelling needs three points with data", code="E-LEVEL")
    m = np.column_stack([pts[:, 0], pts[:, 1], np.ones(3)])
    if abs(np.linalg.det(m)) < 1e-6:
        raise InputError("the three levelling points are on one line", code="E-LEVEL")
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
            "the levelling region has fewer than three cells with data", code="E-LEVEL"
        )
    # centred coordinates keep the normal equations well conditioned
    x = (jj + j0) * p + spec.x0_mm
    y = (ii + i0) * p + spec.y0_mm
    z = sub[ok].astype(np.float64)
    xm, ym, zm = x.mean(), y.mean(), z.mean()
    m = np.column_stack([x - xm, y - ym])
    if np.linalg.matrix_rank(m.T @ m) < 2:
        raise InputError("the levelling region is a line; draw an area", code="E-LEVEL")
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


# ----- measurement records and CSV ------------------------------------------------------------
MEASUREMENT_KINDS = ("point", "ruler", "profile", "annotation", "plane")


def new_measurement(
    kind: str,
    points_mm: Sequence[Sequence[float]],
    values: Mapping,
    label: str = "",
    note: str = "",
    params: Mapping | None = None,
) -> dict:
    """A JSON-able measurement record as kept in the project's ``measurements`` list:
    ``{"id", "kind", "label", "note", "points_mm", "params", "values", "created_utc"}``
    (non-finite values are stored as None)."""
    if kind not in MEASUREMENT_KINDS:
        raise InputError(f"unknown measurement kind {kind!r}")
    return {
        "id": uuid.uuid4().hex[:8],
        "kind": kind,
        "label": str(label),
        "note": str(note),
        "points_mm": [[round(float(c), 4) for c in p] for p in points_mm],
        "params": _jsonable(dict(params or {})),
        "values": _jsonable(dict(values)),
        "created_utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
    }


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return round(float(obj), 5) if math.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def ruler_values(r: RulerResult) -> dict:
    return {
        "xy_mm": r.xy_mm,
        "d3_mm": r.d3_mm,
        "dz_mm": r.dz_mm,
        "z_start_mm": r.start.height_mm,
        "z_end_mm": r.end.height_mm,
    }


def step_values(s: StepHeight) -> dict:
    return {
        "band_a_mean_mm": s.a.mean_mm,
        "band_a_sd_mm": s.a.sd_mm,
        "band_a_n": s.a.n,
        "band_b_mean_mm": s.b.mean_mm,
        "band_b_sd_mm": s.b.sd_mm,
        "band_b_n": s.b.n,
        "step_mm": s.difference_mm,
        "step_sd_mm": s.sd_mm,
    }


def _fmt(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if not math.isfinite(v) else f"{v:.4f}"
    return str(v)


def profile_csv(profile: Profile, step: StepHeight | None = None) -> str:
    """Comment header (segment, width, bands) then ``distance_mm,x_mm,y_mm,height_mm,n_valid``
    rows; missing heights are empty fields."""
    buf = io.StringIO()
    buf.write(
        f"# IMPREsS profile; start ({profile.start[0]:.4f}, {profile.start[1]:.4f}) mm; "
        f"end ({profile.end[0]:.4f}, {profile.end[1]:.4f}) mm; length "
        f"{profile.length_mm:.4f} mm; averaging width {profile.width_mm:.4f} mm\n"
    )
    if step is not None:
        for name, b in (("A", step.a), ("B", step.b)):
            buf.write(
                f"# band {name} {b.start_mm:.4f}..{b.end_mm:.4f} mm: mean "
                f"{_fmt(b.mean_mm)} mm, SD {_fmt(b.sd_mm)} mm, n {b.n}\n"
            )
        buf.write(f"# step B - A: {_fmt(step.difference_mm)} mm, SD {_fmt(step.sd_mm)} mm\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["distance_mm", "x_mm", "y_mm", "height_mm", "n_valid"])
    for d, x, y, h, n in zip(
        profile.distance_mm, profile.x_mm, profile.y_mm, profile.height_mm, profile.n_valid
    ):
        w.writerow([f"{d:.4f}", f"{x:.4f}", f"{y:.4f}", _fmt(float(h)), int(n)])
    return buf.getvalue()


def read_profile_csv(text: str) -> tuple[np.ndarray, np.ndarray]:
    """``(distance_mm, height_mm)`` back from :func:`profile_csv` text (NaN for empty)."""
    rows = [
        r
        for r in csv.reader(line for line in text.splitlines() if line and not line.startswith("#"))
    ]
    body = rows[1:]
    d = np.array([float(r[0]) for r in body])
    h = np.array([float(r[3]) if r[3] else np.nan for r in body])
    return d, h


def measurements_csv(measurements: Sequence[Mapping]) -> str:
    """One row per measurement: number, id, kind, label, note, points and every value."""
    value_keys: list[str] = []
    n_pts = 0
    for m in measurements:
        n_pts = max(n_pts, len(m.get("points_mm", [])))
        for k in m.get("values", {}):
            if k not in value_keys:
                value_keys.append(k)
    head = ["number", "id", "kind", "label", "note"]
    for i in range(n_pts):
        head += [f"x{i + 1}_mm", f"y{i + 1}_mm"]
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(head + value_keys)
    for k, m in enumerate(measurements, 1):
        row = [k, m.get("id", ""), m.get("kind", ""), m.get("label", ""), m.get("note", "")]
        pts = list(m.get("points_mm", []))
        for i in range(n_pts):
            row += [_fmt(float(pts[i][0])), _fmt(float(pts[i][1]))] if i < len(pts) else ["", ""]
        vals = m.get("values", {})
        row += [_fmt(vals.get(key)) for key in value_keys]
        w.writerow(row)
    return buf.getvalue()
