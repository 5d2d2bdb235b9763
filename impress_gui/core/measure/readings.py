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

Levelling and hillshade live in :mod:`~impress_gui.core.measure.surface`, records and CSV in
:mod:`~impress_gui.core.measure.records`; both are re-exported here.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

import numpy as np

from impress_gui.core.base import codes
from impress_gui.core.base.errors import FormatError, InputError
from impress_gui.core.formats.recon_files import (
    HEIGHTMAP_FILE,
    LAYER_FILES,
    METADATA_FILE,
    RECON_FORMAT,
    RECON_VERSION,
    TEXTURE_FILE,
)
from impress_gui.core.reconstruction.grid import GridSpec

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


def verified_heightmap_sha256(folder: str | Path, metadata: Mapping, code: str,
                              advice: str = "process the scan again") -> str:
    """The SHA-256 of ``folder``'s heightmap.tif, checked against the one its metadata.json
    records (``metadata``: as read with it); FormatError ``code`` when they differ (the map
    changed after processing: never measured, cast or compared under the old hash)."""
    from impress_gui.core.base.fileio import sha256_file

    tif = Path(folder) / HEIGHTMAP_FILE
    actual = sha256_file(tif)
    recorded = (metadata.get("files") or {}).get(HEIGHTMAP_FILE)
    if recorded is not None and recorded != actual:
        raise FormatError(f"{tif} is not the heightmap metadata.json records (its SHA-256 "
                          f"differs): it changed after processing; {advice}", code=code)
    return actual


def load_reconstruction(
    folder: str | Path, layers: Sequence[str] = tuple(LAYER_FILES)
) -> ReconData:
    """Read a reconstruction folder written by :func:`impress_gui.core.reconstruction.pipeline.process_files`.

    Raises FormatError for a missing/damaged metadata.json, an unknown format or version, or a
    map whose shape is not the grid's."""
    import tifffile

    folder = Path(folder)
    from impress_gui.core.base.fileio import open_regular, read_regular

    meta_path = folder / METADATA_FILE
    if not folder.is_dir():
        raise FormatError(f"{folder}: not a reconstruction folder", code=codes.E_NOT_A_FILE
                          if folder.exists() else codes.E_FILE_MISSING)
    try:
        if not meta_path.exists():
            raise FileNotFoundError
        # a regular file of sane size (never a FIFO or device, which would hang the reader)
        meta = json.loads(read_regular(meta_path, "reconstruction metadata", 50 << 20)
                          .decode("utf-8"))
    except FileNotFoundError:
        raise FormatError(
            f"{folder}: not a reconstruction (no metadata.json)", code=codes.E_FILE_MISSING
        ) from None
    except (ValueError, UnicodeDecodeError, RecursionError):
        raise FormatError(f"{meta_path}: damaged (not valid JSON text)") from None
    if not isinstance(meta, dict) or meta.get("format") != RECON_FORMAT:
        raise FormatError(f"{meta_path}: not an {RECON_FORMAT} document")
    if meta.get("version") != RECON_VERSION:
        raise FormatError(f"{meta_path}: unknown version {meta.get('version')!r}")
    try:
        g = meta["grid"]
        spec = GridSpec(
            float(g["x0_mm"]),
            float(g["y0_mm"]),
            float(g["pixel_mm"]),
            (int(g["shape"][0]), int(g["shape"][1])),
        )
    except (KeyError, TypeError, ValueError, IndexError, OverflowError):
        raise FormatError(f"{meta_path}: bad grid description (a field is missing or of the "
                          "wrong kind)") from None
    if spec.pixel_mm <= 0 or min(spec.shape) < 1:
        raise FormatError(f"{meta_path}: bad grid description")
    out: dict[str, np.ndarray] = {}
    for name in ("fused", *[n for n in layers if n != "fused"]):
        if name not in LAYER_FILES:
            raise InputError(f"unknown layer {name!r}")
        path = folder / LAYER_FILES[name]
        if not path.exists():
            if name == "fused":
                raise FormatError(f"{path}: missing", code=codes.E_FILE_MISSING)
            continue
        os.close(open_regular(path, "heightmap", 8 << 30))  # a regular file, not a FIFO
        try:
            arr = tifffile.imread(path, maxworkers=1)
        except Exception:  # noqa: BLE001 - tifffile raises many kinds
            raise FormatError(f"{path}: damaged (not a readable TIFF image)") from None
        if arr.shape != spec.shape:
            raise FormatError(f"{path}: shape {arr.shape} is not the grid's {spec.shape}")
        out[name] = _frozen(arr if name == "contribution" else arr.astype(np.float32, copy=False))
    tex = None
    texture = folder / TEXTURE_FILE
    if texture.exists():
        import cv2

        os.close(open_regular(texture, "texture", 8 << 30))
        bgr = cv2.imread(str(texture), cv2.IMREAD_COLOR)
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


# the rest of the measuring API, in one namespace (imported last: records use the types above)
from impress_gui.core.measure.records import (  # noqa: E402
    MEASUREMENT_KINDS,
    measurements_csv,
    new_measurement,
    profile_csv,
    read_profile_csv,
    ruler_values,
    step_values,
)
from impress_gui.core.measure.surface import (  # noqa: E402
    Plane,
    hillshade,
    levelled,
    plane_from_points,
    plane_from_region,
)

__all__ = [
    "LAYER_FILES",
    "MEASUREMENT_KINDS",
    "BandStats",
    "Plane",
    "Profile",
    "Readout",
    "ReconData",
    "RulerResult",
    "StepHeight",
    "Width",
    "band_stats",
    "hillshade",
    "level_crossings",
    "levelled",
    "line_profile",
    "load_reconstruction",
    "measurements_csv",
    "new_measurement",
    "plane_from_points",
    "plane_from_region",
    "profile_csv",
    "read_profile_csv",
    "readout",
    "ruler",
    "ruler_values",
    "sample_bilinear",
    "step_height",
    "step_values",
    "width_at_level",
]
