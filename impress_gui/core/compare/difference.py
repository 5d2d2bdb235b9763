"""The signed difference of two registered surfaces, its histogram and the regions beyond a
threshold.

B is resampled onto A's grid through the registration ``M`` (B -> A): for a cell of A at
``(x, y)`` the point of the moved surface of B above it is found by a fixed-point iteration
(``(x_B, y_B)`` = the xy of ``M^-1 (x, y, z)``, ``z`` = the z of ``M (x_B, y_B, h_B(x_B,
y_B))``, three rounds from A's own height: exact for a turn about the vertical, converging
fast for the small tilts between two scans); ``h_B`` is bilinear (NaN next to cells without
data).

The difference is signed, positive where A is higher, NaN where either has no data, in mm, by
one of two metrics (:data:`METRICS`):

- ``normal`` (the default): the distance from B's point above the cell to A's tangent plane
  there, along A's surface normal: ``(A - B) / sqrt(1 + |grad A|^2)``, A's gradient from its
  grid (central differences, one-sided next to cells without data). This is what deviation
  maps of inspection software measure (CloudCompare's cloud-to-mesh distance, GOM Inspect's
  surface comparison): on a flat it is ``A - B`` (to first order in the slope); on a steep
  wall a small lateral misplacement - or the grid's sampling of the wall - no longer turns
  into a large difference, since a lateral shift ``d`` of a wall changes the normal distance
  by at most ``d``;
- ``vertical``: ``A - B``, the difference of heights along z.

Regions: the 8-connected cells with ``|A - B| > threshold``; for each its area, its deepest
value (signed, and its magnitude), a robust depth (the 90th percentile of ``|A - B|``), its
centroid and its length along its principal axis (the extent of its cells' centres along that
axis plus one cell).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from impress_gui.core.base.progress import CancelToken, ProgressCallback, report
from impress_gui.core.compare.surfaces import Surface, bilinear

CHUNK_ROWS = 256
HISTOGRAM_HALF_RANGE_MM = 1.0
HISTOGRAM_BINS = 200
MAX_REGIONS = 200


def resample(a: Surface, b: Surface, matrix: np.ndarray, rounds: int = 3,
             progress: ProgressCallback | None = None,
             cancel: CancelToken | None = None) -> np.ndarray:
    """B's height (mm, A's frame) under every cell of A with data (float32, NaN elsewhere)."""
    m = np.asarray(matrix, np.float64)
    inv = np.linalg.inv(m)
    rows, cols = a.shape
    out = np.full(a.shape, np.nan, np.float32)
    jj = np.arange(cols)
    for r0 in range(0, rows, CHUNK_ROWS):
        if cancel is not None:
            cancel.check()
        r1 = min(rows, r0 + CHUNK_ROWS)
        ha = a.height_mm[r0:r1]
        ok = np.isfinite(ha)
        if not ok.any():
            continue
        ri, ci = np.nonzero(ok)
        x, y = a.xy(ri + r0, jj[ci])
        za = ha[ok].astype(np.float64)
        # the parts of M^-1 (x, y, z) that do not change from round to round
        bx = inv[0, 0] * x + inv[0, 1] * y + inv[0, 3]
        by = inv[1, 0] * x + inv[1, 1] * y + inv[1, 3]
        z = za
        for _ in range(rounds):
            zz = np.where(np.isfinite(z), z, za)
            xb = bx + inv[0, 2] * zz
            yb = by + inv[1, 2] * zz
            fi, fj = b.cell(xb, yb)
            hb = bilinear(b.height_mm, fi, fj)
            new = m[2, 0] * xb + m[2, 1] * yb + m[2, 2] * hb + m[2, 3]
            # a turn about the vertical needs one round; a tilt a few
            done = abs(inv[0, 2]) < 1e-12 and abs(inv[1, 2]) < 1e-12
            z = new
            if done:
                break
        zb = z
        block = np.full(ha.shape, np.nan, np.float32)
        block[ri, ci] = zb.astype(np.float32)
        out[r0:r1] = block
        report(progress, r1 / rows, f"resampling B onto A ({r1}/{rows} rows)")
    return out


METRICS = ("normal", "vertical")
DEFAULT_METRIC = "normal"
METRIC_TEXT = {
    "normal": "signed distance along A's surface normal: (A - B) / sqrt(1 + |grad A|^2), "
              "positive where A is higher",
    "vertical": "vertical difference A - B (along z), positive where A is higher",
}


def _axis_gradient(h: np.ndarray, step: float, axis: int) -> np.ndarray:
    """d h / d axis: central differences, one-sided where a neighbour has no data, NaN where
    both have none."""
    h = np.moveaxis(h, axis, 0)
    if h.shape[0] < 2:
        return np.moveaxis(np.zeros(h.shape), 0, axis)
    fwd = np.full(h.shape, np.nan)
    bwd = np.full(h.shape, np.nan)
    fwd[:-1] = (h[1:] - h[:-1]) / step
    bwd[1:] = fwd[:-1]
    with np.errstate(invalid="ignore"):
        central = (fwd + bwd) / 2
    g = np.where(np.isfinite(central), central, np.where(np.isfinite(fwd), fwd, bwd))
    return np.moveaxis(g, 0, axis)


def slope(a: Surface) -> np.ndarray:
    """``|grad A|`` (dimensionless, float64) on A's grid; NaN where A has no data or no
    neighbour with data."""
    h = np.asarray(a.height_mm, np.float64)
    gy = _axis_gradient(h, abs(a.y_step_mm), 0)
    gx = _axis_gradient(h, a.pixel_mm, 1)
    return np.hypot(gx, gy)


def normal_factor(a: Surface) -> np.ndarray:
    """``1 / sqrt(1 + |grad A|^2)`` (float64): the cosine of the angle between A's normal and
    the vertical; 1 (the vertical difference) where A's slope is unknown."""
    g = slope(a)
    return np.where(np.isfinite(g), 1.0 / np.sqrt(1.0 + np.nan_to_num(g) ** 2), 1.0)


def check_metric(metric: str) -> None:
    if metric not in METRICS:
        from impress_gui.core.base import codes
        from impress_gui.core.base.errors import InputError

        raise InputError(f"the metric must be one of {', '.join(METRICS)} (got {metric!r})",
                         code=codes.E_COMPARE_OPTION)


def difference(a: Surface, b_on_a: np.ndarray, metric: str = DEFAULT_METRIC) -> np.ndarray:
    """The signed difference (float32 mm, positive where A is higher), NaN where either has no
    data: along A's normal (``metric="normal"``) or vertical (``"vertical"``, ``A - B``); see
    the module's docstring."""
    check_metric(metric)
    with np.errstate(invalid="ignore"):
        d = a.height_mm.astype(np.float64) - np.asarray(b_on_a, np.float64)
        if metric == "normal":
            d = d * normal_factor(a)
    return d.astype(np.float32)


@dataclass(frozen=True)
class DiffStats:
    cells: int  # cells with both surfaces (the overlap)
    share_of_a: float  # of A's cells with data
    mean_mm: float
    median_mm: float
    rms_mm: float
    p95_abs_mm: float
    p99_abs_mm: float
    max_abs_mm: float
    histogram_edges_mm: list
    histogram_counts: list

    def to_json(self) -> dict:
        return {"overlap_cells": self.cells, "overlap_share_of_a": round(self.share_of_a, 6),
                "mean_mm": _r(self.mean_mm), "median_mm": _r(self.median_mm),
                "rms_mm": _r(self.rms_mm), "p95_abs_mm": _r(self.p95_abs_mm),
                "p99_abs_mm": _r(self.p99_abs_mm), "max_abs_mm": _r(self.max_abs_mm),
                "histogram": {"edges_mm": self.histogram_edges_mm,
                              "counts": self.histogram_counts,
                              "note": "signed A - B; the first and last bins also count "
                                      "everything beyond them"}}


def _r(v: float) -> float | None:
    return round(float(v), 6) if math.isfinite(v) else None


def statistics(diff: np.ndarray, a: Surface, half_range_mm: float = HISTOGRAM_HALF_RANGE_MM,
               bins: int = HISTOGRAM_BINS, mask: np.ndarray | None = None) -> DiffStats:
    """Figures of the difference over the overlap (or over ``mask`` & the overlap)."""
    ok = np.isfinite(diff) if mask is None else np.isfinite(diff) & mask
    v = diff[ok].astype(np.float64)
    n_a = int(np.isfinite(a.height_mm).sum())
    edges = np.linspace(-half_range_mm, half_range_mm, bins + 1)
    if v.size == 0:
        nan = float("nan")
        return DiffStats(0, 0.0, nan, nan, nan, nan, nan, nan,
                         [round(float(e), 6) for e in edges], [0] * bins)
    counts, _ = np.histogram(np.clip(v, -half_range_mm, half_range_mm), edges)
    av = np.abs(v)
    return DiffStats(int(v.size), v.size / max(1, n_a), float(v.mean()), float(np.median(v)),
                     float(np.sqrt(np.mean(v * v))), float(np.percentile(av, 95)),
                     float(np.percentile(av, 99)), float(av.max()),
                     [round(float(e), 6) for e in edges], [int(c) for c in counts])


@dataclass(frozen=True)
class Region:
    area_mm2: float
    cells: int
    deepest_mm: float  # signed A - B at the largest |A - B|
    max_depth_mm: float  # its magnitude
    depth_p90_mm: float
    length_mm: float
    width_mm: float
    axis_deg: float  # the principal axis, from +x towards +y (export frame)
    centroid_mm: tuple[float, float]

    def to_json(self) -> dict:
        return {"area_mm2": round(self.area_mm2, 6), "cells": self.cells,
                "deepest_mm": round(self.deepest_mm, 6),
                "max_depth_mm": round(self.max_depth_mm, 6),
                "depth_p90_mm": round(self.depth_p90_mm, 6),
                "length_mm": round(self.length_mm, 6), "width_mm": round(self.width_mm, 6),
                "axis_deg": round(self.axis_deg, 4),
                "centroid_mm": [round(v, 6) for v in self.centroid_mm]}


def steep_walls(a: Surface, threshold_mm: float) -> np.ndarray:
    """A's cells on walls so steep that one cell of lateral misplacement changes the height by
    more than ``threshold_mm`` (``|grad A| * pixel > threshold``): there the difference of two
    scans of the same surface exceeds the threshold from resampling and the lateral
    registration residual alone, whatever the surfaces' own agreement."""
    h = np.asarray(a.height_mm, np.float64)
    with np.errstate(invalid="ignore"):
        gy, gx = np.gradient(h, a.pixel_mm)
        steep = np.hypot(gx, gy) * a.pixel_mm > threshold_mm
    return steep & np.isfinite(h)


def outline(diff: np.ndarray, a: Surface, threshold_mm: float, min_area_mm2: float = 0.1,
            max_regions: int = MAX_REGIONS,
            walls: bool = False) -> tuple[list[Region], np.ndarray]:
    """The regions where ``|A - B| > threshold_mm`` (8-connected, at least ``min_area_mm2``),
    largest first, and their outline mask (the regions' border cells). Cells on A's
    :func:`steep_walls` are left out unless ``walls``: every tread wall would otherwise be
    outlined, hiding the differences an examiner looks for."""
    from scipy import ndimage

    with np.errstate(invalid="ignore"):
        mask = np.abs(diff) > threshold_mm
    if not walls:
        mask &= ~steep_walls(a, threshold_mm)
    labels, n = ndimage.label(mask, np.ones((3, 3), int))
    edge = np.zeros(diff.shape, bool)
    if n == 0:
        return [], edge
    cell_area = a.pixel_mm * a.pixel_mm
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    keep = np.nonzero(sizes[1:] * cell_area >= min_area_mm2)[0] + 1
    order = sorted(keep.tolist(), key=lambda k: (-int(sizes[k]), k))[:max_regions]
    objects = ndimage.find_objects(labels)
    regions = []
    kept = np.zeros(n + 1, bool)
    for k in order:
        kept[k] = True
        sl = objects[k - 1]
        sub = labels[sl] == k
        ri, ci = np.nonzero(sub)
        ri = ri + sl[0].start
        ci = ci + sl[1].start
        vals = diff[ri, ci].astype(np.float64)
        x, y = a.xy(ri, ci)
        cx, cy = float(x.mean()), float(y.mean())
        if len(x) >= 2:
            w, v = np.linalg.eigh(np.cov(np.vstack([x - cx, y - cy])))
            major = v[:, 1]
        else:
            major = np.array([1.0, 0.0])
        along = (x - cx) * major[0] + (y - cy) * major[1]
        across = -(x - cx) * major[1] + (y - cy) * major[0]
        deepest = int(np.argmax(np.abs(vals)))
        regions.append(Region(
            float(len(x) * cell_area), int(len(x)), float(vals[deepest]),
            float(abs(vals[deepest])), float(np.percentile(np.abs(vals), 90)),
            float(along.max() - along.min() + a.pixel_mm),
            float(across.max() - across.min() + a.pixel_mm),
            float(math.degrees(math.atan2(major[1], major[0])) % 180.0), (cx, cy)))
    sel = kept[labels]
    edge = sel & ~ndimage.binary_erosion(sel, np.ones((3, 3), bool))
    return regions, edge


@dataclass(frozen=True)
class PairProfile:
    """Both maps along one line: ``distance_mm`` from the start, ``a_mm`` and ``b_mm`` (B moved
    onto A) bilinear on A's grid, NaN where a map has no data."""

    start_mm: tuple[float, float]
    end_mm: tuple[float, float]
    distance_mm: np.ndarray
    a_mm: np.ndarray
    b_mm: np.ndarray

    @property
    def difference_mm(self) -> np.ndarray:
        return self.a_mm - self.b_mm


def pair_profile(a: Surface, b_on_a: np.ndarray, start_mm: tuple[float, float],
                 end_mm: tuple[float, float], step_mm: float | None = None) -> PairProfile:
    """A's heights and B's (resampled on A's grid) along the segment ``start_mm`` ->
    ``end_mm`` (export frame), every ``step_mm`` (default: half a cell)."""
    step = step_mm or a.pixel_mm / 2
    (x0, y0), (x1, y1) = start_mm, end_mm
    length = math.hypot(x1 - x0, y1 - y0)
    n = max(2, int(math.ceil(length / step)) + 1)
    t = np.linspace(0.0, 1.0, n)
    x, y = x0 + t * (x1 - x0), y0 + t * (y1 - y0)
    fi, fj = a.cell(x, y)
    return PairProfile((float(x0), float(y0)), (float(x1), float(y1)), t * length,
                       bilinear(a.height_mm, fi, fj), bilinear(b_on_a, fi, fj))
