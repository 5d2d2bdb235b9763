"""Registration of surface B onto surface A: a rigid motion (no scale) in the export frame.

The result maps B's export-frame points onto A's: ``p_A = M p_B`` with the 4 x 4 matrix
``M = [R t; 0 1] F``; ``F = diag(sx, 1, sz, 1)`` is the optional pre-transform that compares an
impression with an outsole (``mirror``: x -> -x; ``invert``: z -> -z; both together are the
rotation by 180 degrees about y, as a cast is turned over).

1. **Coarse**: from three or more point pairs (least squares, Kabsch/Umeyama without scale), or
   automatically: each surface's ground plane (robust least squares), its *relief* (the cells
   more than ``relief_mm`` from the plane), the relief's centroid and principal axes; the
   candidate turns (the axes aligned, and turned by 180 degrees; every 45 degrees when the
   relief is nearly round) are each refined by a coarse ICP and the one matching most points
   is kept.
2. **Fine**: open3d point-to-plane ICP on the surfaces' points around the relief, with a Tukey
   robust kernel and a correspondence distance shrinking to ``max_distance_mm`` (outliers -
   walls seen differently, a cut, noise - do not pull).
3. **Residuals**: for every point of B (on its ICP sample) the point-to-plane distance to A at
   the cell beneath (A's normal from its grid); the RMS over the points within
   ``max_distance_mm`` and the overlap: the share of B's points with a partner in A within
   ``overlap_tolerance_mm``.

The matrix is rounded to 1e-9 (rotation) and 1e-7 mm (translation), so that the same inputs
give the same bytes although open3d sums in parallel.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from impress_gui.core.base import codes
from impress_gui.core.base.errors import InputError
from impress_gui.core.base.progress import CancelToken, ProgressCallback, report
from impress_gui.core.compare.surfaces import Surface

Pair = tuple[tuple[float, float], tuple[float, float]]


class RegistrationError(InputError):
    """The surfaces could not be registered."""

    code = codes.E_COMPARE_REGISTRATION


@dataclass(frozen=True)
class RegistrationParams:
    """Units mm. ``pairs``: ((x_A, y_A), (x_B, y_B)) in each input's export frame (B before the
    mirror and inversion), heights read from the surfaces; None: the automatic coarse step."""

    mirror: bool = False
    invert: bool = False
    pairs: tuple[Pair, ...] | None = None
    relief_mm: float = 1.0
    sample_mm: float = 0.5
    max_distance_mm: float = 0.3
    overlap_tolerance_mm: float = 0.1
    margin_mm: float = 10.0
    min_overlap: float = 0.2

    def check(self) -> None:
        for name in ("relief_mm", "sample_mm", "max_distance_mm", "overlap_tolerance_mm"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and 0 < v <= 100):
                raise InputError(f"{name} must be above 0 and at most 100 mm (got {v})",
                                 code=codes.E_COMPARE_OPTION)
        if not (math.isfinite(self.margin_mm) and 0 <= self.margin_mm <= 1000):
            raise InputError("margin_mm must be 0 to 1000 mm", code=codes.E_COMPARE_OPTION)
        if not 0 < self.min_overlap <= 1:
            raise InputError("min_overlap must be in (0, 1]", code=codes.E_COMPARE_OPTION)

    def pre_transform(self) -> np.ndarray:
        return np.diag([-1.0 if self.mirror else 1.0, 1.0, -1.0 if self.invert else 1.0, 1.0])

    def to_json(self) -> dict:
        return {"mirror": self.mirror, "invert": self.invert,
                "pairs": None if self.pairs is None else
                [{"a": list(a), "b": list(b)} for a, b in self.pairs],
                "relief_mm": self.relief_mm, "sample_mm": self.sample_mm,
                "max_distance_mm": self.max_distance_mm,
                "overlap_tolerance_mm": self.overlap_tolerance_mm,
                "margin_mm": self.margin_mm, "min_overlap": self.min_overlap}


@dataclass(frozen=True)
class Registration:
    """``matrix``: 4 x 4, B's export frame -> A's (the pre-transform included);
    ``rigid``: the same without the pre-transform (``matrix = rigid @ F``)."""

    matrix: np.ndarray
    rigid: np.ndarray
    params: RegistrationParams
    coarse: dict
    rms_mm: float
    overlap: float
    inliers: int
    points: int
    icp: list
    window_a: tuple[int, int, int, int]  # A's relief window: first row, stop row, first col, stop

    def window(self) -> tuple[slice, slice]:
        r0, r1, c0, c1 = self.window_a
        return slice(r0, r1), slice(c0, c1)

    def apply(self, pts: np.ndarray) -> np.ndarray:
        return pts @ self.matrix[:3, :3].T + self.matrix[:3, 3]

    def rotation_deg(self) -> float:
        """The rigid part's turn about z (degrees, counter-clockwise seen from above)."""
        return float(np.degrees(np.arctan2(self.rigid[1, 0], self.rigid[0, 0])))

    def to_json(self) -> dict:
        return {"matrix_b_to_a": [[float(v) for v in row] for row in self.matrix],
                "rigid": [[float(v) for v in row] for row in self.rigid],
                "mirror": self.params.mirror, "invert": self.params.invert,
                "pre_transform": [[float(v) for v in row] for row in self.params.pre_transform()],
                "rotation_about_z_deg": round(self.rotation_deg(), 6),
                "coarse": self.coarse,
                "icp": self.icp,
                "residual_rms_mm": round(self.rms_mm, 6),
                "overlap": round(self.overlap, 6),
                "residual_points": self.points, "residual_inliers": self.inliers,
                "window_a": {"rows": list(self.window_a[:2]), "cols": list(self.window_a[2:]),
                             "note": "A's relief (its largest connected piece standing "
                                     "relief_mm out of the ground plane) with margin_mm around, "
                                     "[first, stop) of A's grid: the region compared"},
                "convention": "p_A = matrix_b_to_a @ p_B (export frames, mm); matrix_b_to_a = "
                              "rigid @ pre_transform (mirror x -> -x, invert z -> -z)"}


# ----- geometry ------------------------------------------------------------------------------
def kabsch(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """The proper rigid motion (4 x 4) taking ``src`` (N, 3) onto ``dst`` in least squares."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    h = (src - cs).T @ (dst - cd)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    m = np.eye(4)
    m[:3, :3] = r
    m[:3, 3] = cd - r @ cs
    return m


def _rz(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    return m


def _apply(m: np.ndarray, pts: np.ndarray) -> np.ndarray:
    return pts @ m[:3, :3].T + m[:3, 3]


def _step(surface: Surface, spacing_mm: float) -> int:
    return max(1, int(round(spacing_mm / surface.pixel_mm)))


def ground_plane(pts: np.ndarray) -> np.ndarray:
    """(a, b, c) of z = a x + b y + c fitted robustly (trimmed least squares) to ``pts``."""
    keep = np.ones(len(pts), bool)
    coef = np.zeros(3)
    for _ in range(5):
        p = pts[keep]
        if len(p) < 3:
            break
        a = np.column_stack([p[:, 0], p[:, 1], np.ones(len(p))])
        coef = np.linalg.lstsq(a, p[:, 2], rcond=None)[0]
        res = pts[:, 2] - (coef[0] * pts[:, 0] + coef[1] * pts[:, 1] + coef[2])
        mad = float(np.median(np.abs(res[keep] - np.median(res[keep])))) or 1e-3
        keep = np.abs(res) < max(3.0 * 1.4826 * mad, 0.05)
    return coef


@dataclass(frozen=True)
class _Relief:
    pts: np.ndarray  # the relief's points (after the pre-transform for B)
    plane: np.ndarray
    window: tuple[slice, slice]  # the cells of the relief's bounding box with a margin


def relief(surface: Surface, pre: np.ndarray, relief_mm: float, margin_mm: float) -> _Relief:
    """The cells standing out of the ground plane (1 mm sampling), and their window."""
    step = _step(surface, 1.0)
    rows, cols = surface.shape
    ii = np.arange(0, rows, step)
    jj = np.arange(0, cols, step)
    h = surface.height_mm[np.ix_(ii, jj)]
    ok = np.isfinite(h)
    if ok.sum() < 50:
        raise InputError(f"{surface.source.get('path', 'a surface')}: fewer than 50 cells with "
                         "data (at 1 mm): nothing to register", code=codes.E_COMPARE_NO_DATA)
    r, c = np.nonzero(ok)
    x, y = surface.xy(ii[r], jj[c])
    pts = _apply(pre, np.column_stack([x, y, h[ok].astype(np.float64)]))
    plane = ground_plane(pts)
    res = pts[:, 2] - (plane[0] * pts[:, 0] + plane[1] * pts[:, 1] + plane[2])
    sel = np.abs(res) > relief_mm
    if sel.sum() < 50:
        raise InputError(f"{surface.source.get('path', 'a surface')}: no relief (fewer than 50 "
                         f"cells at 1 mm lie more than {relief_mm:g} mm from the ground plane): "
                         "nothing to register", code=codes.E_COMPARE_NO_DATA)
    # the largest connected piece of relief (the impression, not a calibration target or a
    # stone beside it), on the 1 mm sampling grid
    from scipy import ndimage

    mask = np.zeros(h.shape, bool)
    mask[r[sel], c[sel]] = True
    mask = ndimage.binary_closing(mask, np.ones((3, 3), bool))
    labels, n = ndimage.label(mask, np.ones((3, 3), int))
    if n > 1:
        sizes = np.bincount(labels.ravel())[1:]
        biggest = int(np.argmax(sizes)) + 1
        sel = sel & (labels[r, c] == biggest)
    m = int(math.ceil(margin_mm / surface.pixel_mm))
    ri, ci = ii[r[sel]], jj[c[sel]]
    window = (slice(max(0, int(ri.min()) - m), min(rows, int(ri.max()) + m + 1)),
              slice(max(0, int(ci.min()) - m), min(cols, int(ci.max()) + m + 1)))
    return _Relief(pts[sel], plane, window)


def _axes(pts: np.ndarray) -> tuple[np.ndarray, float, float]:
    c = pts[:, :2].mean(axis=0)
    w, v = np.linalg.eigh(np.cov((pts[:, :2] - c).T))
    major = v[:, 1]
    return c, math.atan2(major[1], major[0]), float(w[1] / max(w[0], 1e-12))


# ----- open3d ICP ----------------------------------------------------------------------------
def _cloud(pts: np.ndarray, normals: bool, radius: float):
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(pts)))
    if normals:
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=radius, max_nn=30))
        pc.orient_normals_to_align_with_direction(np.array([0.0, 0.0, 1.0]))
    return pc


def _icp(src_pts: np.ndarray, dst_pts: np.ndarray, init: np.ndarray,
         stages: Sequence[tuple[float, int]], spacing: float) -> tuple[np.ndarray, list]:
    """Point-to-plane ICP (Tukey kernel) in stages of (max distance mm, iterations)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    src = _cloud(src_pts, False, 0.0)
    dst = _cloud(dst_pts, True, 3.0 * spacing)
    m = init.copy()
    log = []
    for dist, iters in stages:
        est = reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=dist))
        res = reg.registration_icp(src, dst, dist, m, est,
                                   reg.ICPConvergenceCriteria(1e-7, 1e-7, iters))
        m = np.asarray(res.transformation, np.float64).copy()
        log.append({"max_distance_mm": dist, "fitness": round(float(res.fitness), 6),
                    "inlier_rmse_mm": round(float(res.inlier_rmse), 6)})
    return m, log


def _window_points(surface: Surface, window, spacing: float, pre: np.ndarray | None = None
                   ) -> np.ndarray:
    pts = surface.points(_step(surface, spacing), window)
    return pts if pre is None else _apply(pre, pts)


# ----- residuals -----------------------------------------------------------------------------
def residuals(a: Surface, b_pts_in_a: np.ndarray) -> np.ndarray:
    """Point-to-plane distance (mm) of points (A's frame) to A at the cell beneath each: A's
    plane through that cell's centre, its normal from the central differences of the cell's
    four neighbours (one-sided at the grid's edges); NaN off A's data."""
    fi, fj = a.cell(b_pts_in_a[:, 0], b_pts_in_a[:, 1])
    i = np.rint(fi).astype(np.int64)
    j = np.rint(fj).astype(np.int64)
    rows, cols = a.shape
    ok = (i >= 0) & (i < rows) & (j >= 0) & (j < cols)
    out = np.full(len(b_pts_in_a), np.nan)
    if not ok.any():
        return out
    i, j = i[ok], j[ok]
    h = a.height_mm
    ip, im = np.minimum(i + 1, rows - 1), np.maximum(i - 1, 0)
    jp, jm = np.minimum(j + 1, cols - 1), np.maximum(j - 1, 0)
    dzdj = (h[i, jp].astype(np.float64) - h[i, jm]) / np.maximum(jp - jm, 1)
    dzdi = (h[ip, j].astype(np.float64) - h[im, j]) / np.maximum(ip - im, 1)
    gx, gy = dzdj / a.pixel_mm, dzdi / a.y_step_mm
    norm = np.sqrt(gx * gx + gy * gy + 1.0)
    qx, qy = a.xy(i, j)
    qz = h[i, j].astype(np.float64)
    p = b_pts_in_a[ok]
    out[ok] = (-gx * (p[:, 0] - qx) - gy * (p[:, 1] - qy) + (p[:, 2] - qz)) / norm
    return out


def _round(m: np.ndarray) -> np.ndarray:
    out = m.copy()
    out[:3, :3] = np.round(out[:3, :3], 9)
    out[:3, 3] = np.round(out[:3, 3], 7)
    out[3] = [0.0, 0.0, 0.0, 1.0]
    return out + 0.0  # no negative zeros


# ----- coarse --------------------------------------------------------------------------------
def coarse_from_pairs(a: Surface, b: Surface, pairs: Sequence[Pair], pre: np.ndarray
                      ) -> np.ndarray:
    """The rigid motion (4 x 4, after ``pre``) fitting the pairs; heights read bilinearly."""
    if len(pairs) < 3:
        raise InputError(f"{len(pairs)} point pair(s): at least 3 are needed",
                         code=codes.E_COMPARE_PAIRS)
    pa = np.array([[p[0][0], p[0][1]] for p in pairs], np.float64)
    pb = np.array([[p[1][0], p[1][1]] for p in pairs], np.float64)
    za, zb = a.sample(pa[:, 0], pa[:, 1]), b.sample(pb[:, 0], pb[:, 1])
    bad = [k + 1 for k in range(len(pairs)) if not (np.isfinite(za[k]) and np.isfinite(zb[k]))]
    if bad:
        raise InputError(f"point pair(s) {', '.join(map(str, bad))} lie outside the data of A "
                         "or B", code=codes.E_COMPARE_PAIRS)
    qa = np.column_stack([pa, za])
    qb = _apply(pre, np.column_stack([pb, zb]))
    for q, name in ((qa, "A"), (qb, "B")):
        s = np.linalg.svd(q[:, :2] - q[:, :2].mean(axis=0), compute_uv=False)
        if len(s) < 2 or s[1] < 1.0:  # the points span less than ~1 mm across their line
            raise InputError(f"the pairs' points on {name} lie (nearly) in a line: give points "
                             "spread over the impression", code=codes.E_COMPARE_PAIRS)
    return kabsch(qb, qa)


def coarse_auto(a: Surface, b: Surface, params: RegistrationParams, ra: _Relief, rb: _Relief,
                cancel: CancelToken | None = None) -> tuple[np.ndarray, dict]:
    """Principal axes and centroids of the reliefs, every candidate turn refined by a coarse
    ICP; the candidate matching the most points wins."""
    ca, phi_a, ratio_a = _axes(ra.pts)
    cb, phi_b, ratio_b = _axes(rb.pts)
    base = phi_a - phi_b
    if min(ratio_a, ratio_b) < 1.5:
        turns = [base + k * math.pi / 4 for k in range(8)]
    else:
        turns = [base, base + math.pi]
    spacing = 1.5
    dst = _window_points(a, ra.window, spacing)
    src = _window_points(b, rb.window, 2 * spacing, params.pre_transform())
    za = ra.plane[0] * ca[0] + ra.plane[1] * ca[1] + ra.plane[2]
    zb = rb.plane[0] * cb[0] + rb.plane[1] * cb[1] + rb.plane[2]
    tried = []
    best = None
    for theta in turns:
        if cancel is not None:
            cancel.check()
        m = _rz(theta)
        rc = m[:2, :2] @ cb
        m[:3, 3] = [ca[0] - rc[0], ca[1] - rc[1], za - zb]
        m, _ = _icp(src, dst, m, [(8.0, 30), (3.0, 30), (1.5, 30)], spacing)
        score = _score(dst, src, m, 1.0)
        tried.append({"turn_deg": round(math.degrees(theta) % 360.0, 4),
                      "matched": round(score, 6)})
        if best is None or score > best[0] + 1e-9:
            best = (score, m)
    assert best is not None
    return best[1], {"method": "principal axes of the relief + coarse ICP per candidate turn",
                     "candidates": tried,
                     "relief_cells_a": int(len(ra.pts)), "relief_cells_b": int(len(rb.pts)),
                     "axis_ratio_a": round(ratio_a, 4), "axis_ratio_b": round(ratio_b, 4)}


def _score(dst: np.ndarray, src: np.ndarray, m: np.ndarray, tol: float) -> float:
    from scipy.spatial import cKDTree

    d, _ = cKDTree(dst).query(_apply(m, src), k=1, distance_upper_bound=tol)
    return float(np.mean(np.isfinite(d)))


# ----- the whole registration ----------------------------------------------------------------
def register(a: Surface, b: Surface, params: RegistrationParams = RegistrationParams(),
             progress: ProgressCallback | None = None,
             cancel: CancelToken | None = None) -> Registration:
    """Register ``b`` onto ``a`` (see the module's docstring)."""
    params.check()
    pre = params.pre_transform()
    report(progress, 0.0, "finding the relief")
    ra = relief(a, np.eye(4), params.relief_mm, params.margin_mm)
    rb = relief(b, pre, params.relief_mm, params.margin_mm)
    if params.pairs is not None:
        init = coarse_from_pairs(a, b, params.pairs, pre)
        coarse = {"method": "point pairs (least squares, Kabsch without scale)",
                  "pairs": len(params.pairs)}
        fit = _apply(init, _apply(pre, _pair_points(b, params.pairs)))
        coarse["pairs_rms_mm"] = round(float(np.sqrt(np.mean(np.sum(
            (fit - _pair_points(a, params.pairs, first=True)) ** 2, axis=1)))), 6)
    else:
        report(progress, 0.1, "coarse alignment (principal axes, candidate turns)")
        init, coarse = coarse_auto(a, b, params, ra, rb, cancel)
    coarse["matrix"] = [[round(float(v), 9) for v in row] for row in init]
    if cancel is not None:
        cancel.check()
    report(progress, 0.5, "refining (point-to-plane ICP)")
    s = params.sample_mm
    dst = _window_points(a, ra.window, s)
    src = _window_points(b, rb.window, 2 * s, pre)
    d = params.max_distance_mm
    stages = [(max(4 * d, 2.0), 10), (max(2 * d, 1.0), 10), (d, 30)]
    m, log = _icp(src, dst, init, stages, s)
    m = _round(m)
    report(progress, 0.9, "residuals")
    pts = _apply(m, src)
    r = residuals(a, pts)
    fin = np.isfinite(r)
    inl = fin & (np.abs(r) <= d)
    n_pts = int(len(src))
    if inl.sum() < max(20, params.min_overlap * 0.1 * n_pts):
        raise RegistrationError(f"the registration failed: {int(inl.sum())} of {n_pts} points "
                                f"of B lie within {d:g} mm of A after ICP; give point pairs or "
                                "check --mirror/--invert")
    rms = float(np.sqrt(np.mean(r[inl] ** 2)))
    overlap = float(np.sum(fin & (np.abs(r) <= params.overlap_tolerance_mm)) / max(1, n_pts))
    if overlap < params.min_overlap:
        raise RegistrationError(f"the registration failed: only {overlap:.0%} of B's points "
                                f"have a partner on A within {params.overlap_tolerance_mm:g} mm "
                                f"(at least {params.min_overlap:.0%} needed)")
    report(progress, 1.0, "registered")
    win = (ra.window[0].start, ra.window[0].stop, ra.window[1].start, ra.window[1].stop)
    return Registration(m @ pre, m, params, coarse, rms, overlap, int(inl.sum()), n_pts, log,
                        win)


def _pair_points(s: Surface, pairs: Sequence[Pair], first: bool = False) -> np.ndarray:
    xy = np.array([p[0] if first else p[1] for p in pairs], np.float64)
    return np.column_stack([xy, s.sample(xy[:, 0], xy[:, 1])])
