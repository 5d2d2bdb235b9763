"""A digital cast (Qt-free): a closed triangle mesh of an impression, ready for a 3D printer.

:func:`make_cast` turns a reconstruction's fused heightmap into a watertight solid (closed,
2-manifold, every triangle wound counter-clockwise seen from outside): the surface on top, four
vertical walls along the region's edges and a flat base ``base_mm`` below the surface's lowest
point. :func:`cast_bytes` writes it as binary STL, PLY or OBJ; :func:`write_cast` does the whole
job for ``impress cast`` (checks, mesh, file and its JSON sidecar, written atomically).

Frame (see docs/formats.md, "Digital cast"): millimetres, right-handed, the export frame
(:data:`~impress_gui.core.formats.writers.EXPORT_FRAME`: ``x = rail X``, ``y = -rail Y``, ``z`` up).

- **negative** (the default): the impression as recorded. A surface vertex of cell ``[i, j]``
  lies at ``(x, y, h)``, ``(x, y) = export_xy(spec, i, j)``, ``h`` the heightmap's value; the
  solid is ``z_base <= z <= h(x, y)`` with ``z_base = min(h) - base_mm``.
- **positive**: the cast poured into the impression, turned over as a physical cast is, so that
  its relief faces up and shows the outsole's face as one looks at the sole. The poured solid
  ``h(x, y) <= z <= max(h) + base_mm`` is rotated by 180 degrees about the y axis,
  ``(x, y, z) -> (-x, y, -z)``: a proper rotation (determinant +1), never a reflection, so
  nothing is mirrored that a physical cast would not show mirrored. A surface vertex lies at
  ``(-x, y, -h)``, the base at ``-max(h) - base_mm``.

Holes (NaN cells) inside the region are filled smoothly (a multigrid harmonic fill: the
neighbours' mean, solved coarse to fine) and counted. Three ways to make the mesh smaller than
the grid (``decimate``), all at or under ``max_triangles``:

- ``"adaptive"`` (the default): a triangulated irregular network whose vertices lie exactly on
  cells, inserted where the surface is farthest from a cell (greedy insertion, Delaunay;
  Garland and Heckbert's method as implemented by hmm, through pydelatin) until every cell of
  the region, filled ones too, lies within ``tolerance_mm`` (0.02 mm) of the surface
  vertically, or the cap is reached (then the record's ``tolerance_met`` is false and the
  sidecar warns ``W-CAST-TOLERANCE``). Vertical walls under its boundary, a base fan.
- ``"sample"``: every ``step``-th cell (the region's last row and column always kept), the
  smallest step that fits. Surface vertices lie exactly on heightmap cells (float32); between
  them the surface cuts corners (a wall one cell wide is smeared over ``step`` cells).
- ``"quadric"``: the grid mesh at full resolution (or, above
  :data:`QUADRIC_INPUT_TRIANGLES`, at the finest sampling under it) simplified by open3d's
  quadric error metric decimation (Garland-Heckbert) to ``max_triangles``: flat ground gets few
  large triangles, walls and edges keep theirs. The result is checked closed and consistently
  oriented (outward) and falls back to sampling, said so in the record, if it is not.

:func:`write_cast` verifies the mesh it writes: numpy checks that every edge is shared by
exactly two triangles wound opposite ways (closed, edge-manifold, consistently oriented, hence
orientable) and that the volume is positive (outward); open3d checks that it is vertex-manifold
(and edge-manifold and orientable only when numpy's check fails: the same answer, far slower),
and that it does not intersect itself (the adaptive surface: exactly, from its projection in
integer cell indices; otherwise open3d's quadratic test, on small enough meshes); it then
measures how far the surface lies from the heightmap on the cells with data: vertically (rays
cast straight down) and along the normal (each cell's closest-point distance to the top
surface, what inspection software reports; a wall cut across between two samples is its height
off vertically, along the normal at most about the distance between samples: 0.54 mm on the
sample case sampled every 4th cell); all of it goes into the sidecar.

Measured on the sample case's whole region (557 x 281 mm, 15.7 million cells, 960x540): the
default (adaptive, 0.02 mm) needs 2.23 million triangles (112 MB of STL, 37 s, 1.5 GB) and keeps
every cell within 0.0200 mm; at a cap of 2 million it reaches 0.031 mm (98.96 % of the cells
within 0.02 mm), where sampling every 4th cell keeps 91.0 % and quadric decimation 94.7 %
(docs/measuring-guide.md). Everything is deterministic: the same inputs give the same bytes.
"""

from __future__ import annotations

import hashlib
import math
import struct
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from impress_gui import __version__
from impress_gui.core.base import codes
from impress_gui.core.base.errors import ImpressError, InputError
from impress_gui.core.base.progress import CancelToken, ProgressCallback, report, sub_progress
from impress_gui.core.reconstruction.grid import GridSpec

CAST_FORMAT = "impress.cast"
CAST_VERSION = 1
SUFFIXES = {".stl": "stl", ".ply": "ply", ".obj": "obj"}
DEFAULT_BASE_MM = 5.0
DEFAULT_MAX_TRIANGLES = 5_000_000
MIN_TRIANGLES = 20  # the smallest solid: 2x2 surface nodes, 4 walls, a base fan
DECIMATE_METHODS = ("adaptive", "sample", "quadric")
DEFAULT_DECIMATE = "adaptive"
#: the adaptive surface's default tolerance: the largest vertical distance allowed between the
#: mesh and any cell of the region (the issue's 0.02 mm)
DEFAULT_TOLERANCE_MM = 0.02
MIN_TOLERANCE_MM = 0.0
MAX_TOLERANCE_MM = 10.0
#: the quadric decimation's input: the full-resolution grid mesh, or the finest sampling with at
#: most this many triangles (memory and time: open3d keeps a quadric per vertex)
QUADRIC_INPUT_TRIANGLES = 4_000_000
#: regions up to this many cells are triangulated in the process itself (well under a second);
#: larger ones in a child process (:func:`adaptive_surface_apart`)
TIN_IN_PROCESS_CELLS = 1_000_000
#: open3d's self-intersection test is quadratic (about 45 s for 90 000 triangles on two cores)
SELF_INTERSECTION_MAX_TRIANGLES = 20_000
#: the surface deviation is measured on at most this many cells (every k-th row and column)
DEVIATION_MAX_RAYS = 2_000_000
SURFACE_TOLERANCE_MM = 0.02
MAX_BASE_MM = 1000.0
CHUNK = 1 << 20  # triangles handled at a time in float64
NEGATIVE_TRANSFORM = "identity: (x, y, z) -> (x, y, z)"
POSITIVE_TRANSFORM = (
    "rotation by 180 deg about the y axis: (x, y, z) -> (-x, y, -z) (determinant +1, a proper "
    "rigid motion: the poured cast turned over, relief up)"
)
CAST_FRAME = (
    "right-handed, in mm; before the transformation the export frame: x = rail X (the image's "
    "columns, to the right), y = -rail Y (the image's first row has the largest y), z = height "
    "up, towards the camera"
)


@dataclass(frozen=True)
class CastParams:
    """``crop_mm``: ``(x0, y0, x1, y1)`` in the export frame (mm, corners in any order), None
    for the cells with data; ``base_mm`` > 0: the base's thickness below the lowest point."""

    positive: bool = False
    base_mm: float = DEFAULT_BASE_MM
    crop_mm: tuple[float, float, float, float] | None = None
    max_triangles: int = DEFAULT_MAX_TRIANGLES
    decimate: str = DEFAULT_DECIMATE
    tolerance_mm: float = DEFAULT_TOLERANCE_MM

    def check(self) -> None:
        b = self.base_mm
        if not isinstance(b, (int, float)) or not math.isfinite(b) or not 0 < b <= MAX_BASE_MM:
            raise InputError(f"the base thickness must be a number of mm above 0 and at most "
                             f"{MAX_BASE_MM:g} (got {b})", code=codes.E_CAST_BASE)
        if isinstance(self.max_triangles, bool) or not isinstance(self.max_triangles, int) \
                or self.max_triangles < MIN_TRIANGLES:
            raise InputError(f"the triangle cap must be a whole number of at least "
                             f"{MIN_TRIANGLES} (got {self.max_triangles})",
                             code=codes.E_CAST_TRIANGLES)
        if self.crop_mm is not None:
            c = self.crop_mm
            if len(c) != 4 or not all(isinstance(v, (int, float)) and math.isfinite(v)
                                      for v in c):
                raise InputError("the crop must be four finite numbers x0,y0,x1,y1 (mm)",
                                 code=codes.E_CAST_CROP)
            if c[0] == c[2] or c[1] == c[3]:
                raise InputError("the crop has no area: x0 = x1 or y0 = y1", code=codes.E_CAST_CROP)
        if self.decimate not in DECIMATE_METHODS:
            raise InputError(f"unknown decimation {self.decimate!r}: use one of "
                             f"{', '.join(DECIMATE_METHODS)}", code=codes.E_CAST_TRIANGLES)
        t = self.tolerance_mm
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) \
                or not MIN_TOLERANCE_MM <= t <= MAX_TOLERANCE_MM:
            raise InputError(f"the surface tolerance must be a number of mm from "
                             f"{MIN_TOLERANCE_MM:g} to {MAX_TOLERANCE_MM:g} (got {t})",
                             code=codes.E_CAST_TOLERANCE)

    def to_json(self) -> dict:
        return {"mode": "positive" if self.positive else "negative",
                "base_mm": float(self.base_mm),
                "crop_mm": None if self.crop_mm is None else [float(v) for v in self.crop_mm],
                "max_triangles": int(self.max_triangles),
                "decimate": self.decimate,
                **({"tolerance_mm": float(self.tolerance_mm)}
                   if self.decimate == "adaptive" else {})}


@dataclass(frozen=True)
class CastMesh:
    """A closed, outward-oriented triangle mesh. ``vertices`` ``(N, 3)`` float32 mm;
    ``triangles`` ``(M, 3)`` int64 indices, counter-clockwise seen from outside."""

    vertices: np.ndarray
    triangles: np.ndarray
    params: CastParams
    region: dict  # the cells used: rows/cols (first, stop), the crop in the export frame
    step: int  # every step-th cell was sampled
    filled_cells: int  # cells of the region without data, filled (full resolution)
    filled_vertices: int  # surface vertices on filled cells
    surface_shape: tuple[int, int]  # (rows, cols) of surface vertices
    base_z_mm: float
    volume_mm3: float
    decimation: dict | None = None  # how the triangle cap was met (the sidecar's record)

    def bounding_box(self) -> dict:
        lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
        return {"min_mm": [round(float(v), 6) for v in lo],
                "max_mm": [round(float(v), 6) for v in hi]}


# ----- region and hole filling ---------------------------------------------------------------
def crop_region(spec: GridSpec, height: np.ndarray,
                crop_mm: tuple[float, float, float, float] | None) -> tuple[slice, slice]:
    """The rows and columns of the region: the cells whose centres lie in ``crop_mm`` (export
    frame, clipped to the grid), or the bounding box of the cells with data."""
    ok = np.isfinite(height)
    if not ok.any():
        raise InputError("the heightmap has no data (every cell is NaN): nothing to cast",
                         code=codes.E_CAST_NO_DATA)
    if crop_mm is None:
        rows, cols = np.nonzero(ok.any(axis=1))[0], np.nonzero(ok.any(axis=0))[0]
        r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    else:
        p = spec.pixel_mm
        # each bound clipped to a cell beyond the grid first: the rounding allowance below is
        # relative to the values, and a bound of 1e12 mm widened the other axis by cells
        gx = (spec.x0_mm - p, spec.x0_mm + spec.shape[1] * p)
        gy = (-(spec.y0_mm + spec.shape[0] * p), -spec.y0_mm + p)
        x0, x1 = (min(max(v, gx[0]), gx[1]) for v in (crop_mm[0], crop_mm[2]))
        y0, y1 = (min(max(v, gy[0]), gy[1]) for v in (crop_mm[1], crop_mm[3]))
        eps = 1e-9 * max(1.0, abs(x0), abs(x1), abs(y0), abs(y1))
        # export x = x0_mm + j p; export y = -(y0_mm + i p)
        c0 = max(0, math.ceil((min(x0, x1) - spec.x0_mm) / p - eps))
        c1 = min(spec.shape[1], math.floor((max(x0, x1) - spec.x0_mm) / p + eps) + 1)
        r0 = max(0, math.ceil((-max(y0, y1) - spec.y0_mm) / p - eps))
        r1 = min(spec.shape[0], math.floor((-min(y0, y1) - spec.y0_mm) / p + eps) + 1)
        if r1 - r0 < 2 or c1 - c0 < 2:
            raise InputError(
                f"the crop {','.join(f'{v:g}' for v in crop_mm)} mm holds fewer than 2 x 2 "
                "cells of the "
                f"grid (x {spec.x0_mm:g} to {spec.x0_mm + (spec.shape[1] - 1) * p:g} mm, y "
                f"{-(spec.y0_mm + (spec.shape[0] - 1) * p):g} to {-spec.y0_mm:g} mm in the "
                "export frame)", code=codes.E_CAST_CROP)
        if not ok[r0:r1, c0:c1].any():
            raise InputError("the crop holds no cell with data: nothing to cast",
                             code=codes.E_CAST_NO_DATA)
    if r1 - r0 < 2 or c1 - c0 < 2:
        raise InputError("the cells with data span fewer than 2 x 2 cells: too small to cast",
                         code=codes.E_CAST_NO_DATA)
    return slice(r0, r1), slice(c0, c1)


def _relax(out: np.ndarray, unknown: np.ndarray, iterations: int) -> None:
    """Jacobi steps of the neighbours' mean on the unknown cells (edges replicated)."""
    for _ in range(iterations):
        p = np.pad(out, 1, mode="edge")
        mean = 0.25 * (p[:-2, 1:-1] + p[2:, 1:-1] + p[1:-1, :-2] + p[1:-1, 2:])
        out[unknown] = mean[unknown]


def fill_holes(height: np.ndarray, iterations: int = 6) -> np.ndarray:
    """``height`` (2D, NaN = unknown, at least one known cell) with every NaN replaced by a
    smooth harmonic fill (each filled cell the mean of its four neighbours), solved coarse to
    fine: the NaN-aware 2 x 2 mean gives the next coarser level, its fill seeds the finer one,
    a few Jacobi steps smooth it. Known cells are returned unchanged. float64."""
    h = np.asarray(height, np.float64)
    known = np.isfinite(h)
    if known.all():
        return h.copy()
    if not known.any():
        raise InputError("no cell with data to fill from", code=codes.E_CAST_NO_DATA)
    rows, cols = h.shape
    if rows == 1 and cols == 1:
        return h.copy()
    pr, pc = rows % 2, cols % 2
    v = np.pad(np.where(known, h, 0.0), ((0, pr), (0, pc)))
    w = np.pad(known.astype(np.float64), ((0, pr), (0, pc)))
    vs = v[0::2, 0::2] + v[1::2, 0::2] + v[0::2, 1::2] + v[1::2, 1::2]
    ws = w[0::2, 0::2] + w[1::2, 0::2] + w[0::2, 1::2] + w[1::2, 1::2]
    with np.errstate(invalid="ignore", divide="ignore"):
        coarse = np.where(ws > 0, vs / np.maximum(ws, 1e-300), np.nan)
    coarse = fill_holes(coarse, iterations)
    seed = np.repeat(np.repeat(coarse, 2, axis=0), 2, axis=1)[:rows, :cols]
    out = np.where(known, h, seed)
    _relax(out, ~known, iterations)
    return out


# ----- the solid -----------------------------------------------------------------------------
def _samples(n: int, step: int) -> np.ndarray:
    idx = np.arange(0, n, step)
    return idx if idx[-1] == n - 1 else np.append(idx, n - 1)


def triangle_count(rows: int, cols: int) -> int:
    """Triangles of a solid on ``rows x cols`` surface nodes: the surface, walls and base fan."""
    return 2 * (rows - 1) * (cols - 1) + 6 * (rows - 1 + cols - 1)


def choose_step(rows: int, cols: int, max_triangles: int) -> int:
    """The smallest sampling step whose solid has at most ``max_triangles`` triangles."""
    step = max(1, math.floor(math.sqrt(2 * rows * cols / max_triangles)))
    while True:
        nr, nc = len(_samples(rows, step)), len(_samples(cols, step))
        if triangle_count(nr, nc) <= max_triangles:
            break
        step += 1
    while step > 1:
        nr, nc = len(_samples(rows, step - 1)), len(_samples(cols, step - 1))
        if triangle_count(nr, nc) > max_triangles:
            break
        step -= 1
    return step


def _boundary_loop(nr: int, nc: int) -> np.ndarray:
    """Indices of the ``nr x nc`` node grid's boundary, once around (row 0 first)."""
    grid = np.arange(nr * nc).reshape(nr, nc)
    return np.concatenate([grid[0, :], grid[1:, -1], grid[-1, -2::-1], grid[-2:0:-1, 0]])


def signed_volume(verts: np.ndarray, tris: np.ndarray) -> float:
    """The signed volume (mm^3) enclosed by a closed mesh: positive for outward normals."""
    volume = 0.0
    for k in range(0, len(tris), CHUNK):  # in pieces: float64 temporaries stay small
        p = verts[tris[k : k + CHUNK]].astype(np.float64)
        volume += float(np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum())
    return volume / 6.0


def closed_and_oriented(tris: np.ndarray) -> bool:
    """Every directed edge occurs once and its reverse once too: each edge is shared by
    exactly two triangles that traverse it in opposite directions (a closed, edge-manifold,
    consistently wound surface)."""
    t = np.asarray(tris, np.int64)
    if len(t) == 0:
        return False
    n = int(t.max()) + 1
    a = np.concatenate([t[:, 0], t[:, 1], t[:, 2]])
    b = np.concatenate([t[:, 1], t[:, 2], t[:, 0]])
    key = np.sort(a * n + b)
    if len(key) > 1 and bool(np.any(key[1:] == key[:-1])):
        return False
    rev = np.sort(b * n + a)
    return bool(np.array_equal(key, rev))


def _degenerate(tris: np.ndarray) -> bool:
    """Whether any triangle names a vertex twice."""
    t = np.asarray(tris)
    return bool(np.any((t[:, 0] == t[:, 1]) | (t[:, 1] == t[:, 2]) | (t[:, 2] == t[:, 0])))


def quadric_decimate(verts: np.ndarray, tris: np.ndarray, target: int
                     ) -> tuple[np.ndarray, np.ndarray]:
    """open3d's quadric error decimation of a closed mesh to ``target`` triangles (float32
    vertices, int64 triangles; unreferenced vertices removed). Deterministic (one thread)."""
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(verts.astype(np.float64)),
                                     o3d.utility.Vector3iVector(tris.astype(np.int32)))
    out = mesh.simplify_quadric_decimation(target_number_of_triangles=int(target))
    out.remove_unreferenced_vertices()
    return (np.asarray(out.vertices).astype(np.float32),
            np.ascontiguousarray(np.asarray(out.triangles).astype(np.int64)))


def adaptive_surface(z: np.ndarray, tolerance_mm: float, max_triangles: int | None
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """A triangulated irregular network over the ``(rows, cols)`` height field ``z`` (float32
    mm, no NaN) whose surface lies within ``tolerance_mm`` of every cell, vertically (greedy
    insertion with Delaunay triangulation, Garland and Heckbert's method as implemented by
    Fogleman's hmm, through pydelatin): each step inserts the cell farthest from the current
    surface until none is farther than the tolerance or ``max_triangles`` triangles are made.
    Vertices lie exactly on cells. Returns the vertices' rows and columns (int64), the
    triangles (int64, counter-clockwise seen from above with rows running down the picture,
    i.e. in (column, -row)) and the largest vertical distance of any cell from the surface
    (mm). Deterministic."""
    from pydelatin import Delatin

    rows = z.shape[0]
    tin = Delatin(np.ascontiguousarray(z, np.float32), max_error=float(tolerance_mm),
                  max_triangles=None if max_triangles is None else int(max_triangles))
    v = np.asarray(tin.vertices)
    cols_ = v[:, 0].astype(np.int64)
    rows_ = (rows - 1) - v[:, 1].astype(np.int64)  # hmm's y runs up the picture
    tris = np.ascontiguousarray(np.asarray(tin.triangles).astype(np.int64))
    return rows_, cols_, tris, float(tin.error)


def _tin_child(conn, z: np.ndarray, tolerance_mm: float, max_triangles: int | None) -> None:
    """:func:`adaptive_surface` in a child process; its result (or error) sent on ``conn``."""
    try:
        conn.send(("ok", adaptive_surface(z, tolerance_mm, max_triangles)))
    except BaseException as exc:  # reported to the parent, which raises it
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
    finally:
        conn.close()


def adaptive_surface_apart(z: np.ndarray, tolerance_mm: float, max_triangles: int | None,
                           progress: ProgressCallback | None = None,
                           cancel: CancelToken | None = None
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """:func:`adaptive_surface`, run in a child process when the region has more than
    :data:`TIN_IN_PROCESS_CELLS` cells: the triangulation is one long call that holds the
    interpreter's lock (15-20 s for a whole shoe), so in-process it would freeze the window
    and leave Cancel unanswered. Here the caller reports progress every half second and a
    cancellation ends the child at once. The same result either way (the same code on the
    same bytes)."""
    if z.size <= TIN_IN_PROCESS_CELLS:
        return adaptive_surface(z, tolerance_mm, max_triangles)
    import multiprocessing as mp
    import time

    ctx = mp.get_context("spawn")
    receiver, sender = ctx.Pipe(duplex=False)
    from impress_gui.core.base.quiet import child_initializer, run_quietly

    child = ctx.Process(target=run_quietly,
                        args=(child_initializer() is not None, _tin_child, sender, z,
                              tolerance_mm, max_triangles),
                        daemon=True, name="impress-cast-surface")
    child.start()
    sender.close()
    start = time.monotonic()
    try:
        while not receiver.poll(0.25):
            if cancel is not None:
                cancel.check()
            if not child.is_alive() and not receiver.poll(0):
                raise ImpressError(f"the adaptive surface's process stopped (exit code "
                                   f"{child.exitcode}) without a result: please report this",
                                   code=codes.E_INTERNAL)
            report(progress, 0.0, f"building the adaptive surface: "
                                  f"{time.monotonic() - start:.0f} s")
        try:
            status, payload = receiver.recv()
        except EOFError:
            raise ImpressError("the adaptive surface's process stopped without a result: "
                               "please report this", code=codes.E_INTERNAL) from None
    finally:
        receiver.close()
        if child.is_alive():
            child.terminate()
        child.join()
    if status != "ok":
        raise ImpressError(f"the adaptive surface failed ({payload}): please report this",
                           code=codes.E_INTERNAL)
    return payload


def solid_from_tin(x: np.ndarray, y: np.ndarray, z: np.ndarray, tris: np.ndarray,
                   base_z: float) -> tuple[np.ndarray, np.ndarray, float]:
    """A closed solid between a triangulated surface over a rectangle (vertices ``x, y, z``,
    ``tris`` its triangles) and the plane ``z = base_z`` below it: the surface's triangles
    wound counter-clockwise seen from above, a vertical wall (two triangles) under each of
    its boundary edges, the base a fan around the rectangle's centre. Returns float32
    vertices, int64 triangles wound counter-clockwise seen from outside, and the volume in
    mm^3."""
    t = np.asarray(tris, np.int64).copy()
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    cross = (x[b] - x[a]) * (y[c] - y[a]) - (y[b] - y[a]) * (x[c] - x[a])
    flip = cross < 0
    t[flip] = t[flip][:, [0, 2, 1]]
    n_top = len(x)
    # the boundary: the directed edges whose reverse no triangle has
    src = np.concatenate([t[:, 0], t[:, 1], t[:, 2]])
    dst = np.concatenate([t[:, 1], t[:, 2], t[:, 0]])
    key = src * n_top + dst
    rev = np.sort(dst * n_top + src)
    pos = np.searchsorted(rev, key)
    inner = (pos < len(rev)) & (rev[np.minimum(pos, len(rev) - 1)] == key)
    bs, bd = src[~inner], dst[~inner]
    nxt = np.full(n_top, -1, np.int64)
    nxt[bs] = bd
    start = int(bs.min())  # one loop around the rectangle, from a fixed vertex
    loop = [start]
    cur = int(nxt[start])
    while cur != start:
        if cur < 0 or len(loop) > len(bs):
            raise ImpressError("the adaptive surface's boundary is not one loop: please "
                               "report this", code=codes.E_INTERNAL)
        loop.append(cur)
        cur = int(nxt[cur])
    if len(loop) != len(bs):
        raise ImpressError("the adaptive surface's boundary is not one loop: please report "
                           "this", code=codes.E_INTERNAL)
    ta = np.asarray(loop, np.int64)  # the surface runs ta[k] -> ta[k + 1] along its boundary
    tb = np.roll(ta, -1)
    n_loop = len(ta)
    ba = n_top + np.arange(n_loop)  # the base vertex under ta[k]
    bb = np.roll(ba, -1)
    centre_i = n_top + n_loop
    top = np.column_stack([x, y, z])
    bottom = np.column_stack([x[ta], y[ta], np.full(n_loop, base_z)])
    centre = np.array([[0.5 * (x.min() + x.max()), 0.5 * (y.min() + y.max()), base_z]])
    verts = np.concatenate([top, bottom, centre]).astype(np.float32)
    # each wall runs its top edge the other way (tb -> ta), the base its bottom edge (bb -> ba)
    walls = np.concatenate([np.column_stack([tb, ta, ba]), np.column_stack([tb, ba, bb])])
    fan = np.column_stack([np.full(n_loop, centre_i), bb, ba])
    out = np.ascontiguousarray(np.concatenate([t, walls, fan]).astype(np.int64))
    volume = signed_volume(verts, out)
    if volume < 0:  # never for a surface above its base; kept outward all the same
        out = np.ascontiguousarray(out[:, [0, 2, 1]])
        volume = -volume
    return verts, out, volume


def _adaptive_solid(filled: np.ndarray, rs: slice, cs: slice, spec: GridSpec,
                    params: CastParams, base_mm: float,
                    progress: ProgressCallback | None = None,
                    cancel: CancelToken | None = None
                    ) -> tuple[np.ndarray, np.ndarray, float, float, dict, np.ndarray]:
    """The adaptive cast of the region ``filled`` (float64 with the float32 values, no NaN):
    the surface within the tolerance (:func:`adaptive_surface`), at most ``max_triangles``
    triangles in all (surface, walls and base; when the tolerance needs more, the cap wins and
    the record says how far the surface then lies). Returns vertices, triangles, volume, the
    base's height, the decimation record and the surface vertices' (rows, cols) in the
    region."""
    from impress_gui.core.formats.writers import export_xy

    rows, cols = filled.shape
    z32 = filled.astype(np.float32)
    cap = params.max_triangles
    tol = float(params.tolerance_mm)
    # walls and base: three triangles per boundary edge; at most 2 (rows + cols - 2) edges.
    # Where the whole grid does not fit, the surface first gets the cap less the walls of its
    # four corners, then (if its boundary took more) the cap less its own boundary's walls.
    # (Reserving the walls of the whole grid's boundary first left a long strip's surface
    # nothing: 2 triangles under a cap of 20000 for a 381 x 7650-cell region, 4 December 2026)
    edges_max = 2 * (rows + cols - 2)
    surface_cap = cap - 3 * edges_max
    runs = 0
    limit: int | None = None if surface_cap >= 2 * (rows - 1) * (cols - 1) else max(2, cap - 12)
    while True:
        runs += 1
        r, c, tris, err = adaptive_surface_apart(z32, tol, limit, progress, cancel)
        # a triangulation of the rectangle has as many boundary edges as vertices on its sides
        edges = int(np.count_nonzero((r == 0) | (r == rows - 1) | (c == 0) | (c == cols - 1)))
        total = len(tris) + 3 * edges
        if total <= cap or runs >= 6:
            break
        # greedy insertion stopped earlier is a prefix of the same insertions: the boundary
        # can only lose vertices, so this cap holds after at most a few rounds (one less:
        # the insertion stops at the first count at or above its limit, which an insertion
        # of 2 or 3 triangles can pass by one)
        limit = max(2, cap - 3 * edges - 1)
    if total > cap:
        raise ImpressError("the adaptive surface does not fit the triangle cap: please report "
                           "this", code=codes.E_INTERNAL)
    # the surface's projection, exactly (integer cell indices): every triangle turning the same
    # way with a non-zero area, and the areas adding up to the rectangle's, is a triangulation
    # of the rectangle without overlaps; over a base below its lowest point and with vertical
    # walls under its boundary, the solid cannot intersect itself
    a, b, cc = tris[:, 0], tris[:, 1], tris[:, 2]
    twice = (c[b] - c[a]) * (r[a] - r[cc]) - (r[a] - r[b]) * (c[cc] - c[a])  # in (col, -row)
    projection = {"triangles_one_way": bool(np.all(twice > 0) or np.all(twice < 0)),
                  "area_cells": int(abs(int(twice.sum()))) / 2,
                  "rectangle_cells": (rows - 1) * (cols - 1)}
    projection["no_overlap"] = bool(projection["triangles_one_way"]
                                    and projection["area_cells"] == projection["rectangle_cells"])
    x, y = export_xy(spec, (rs.start + r).astype(np.float64), (cs.start + c).astype(np.float64))
    z = z32[r, c].astype(np.float64)
    if params.positive:
        x, z = -x, -z  # the rotation by 180 deg about y
    base_z = float(np.float32(z.min() - base_mm))
    verts, out, volume = solid_from_tin(x, y, z, tris, base_z)
    met = err <= tol
    record = {"method": "adaptive", "tolerance_mm": tol,
              "max_vertical_error_mm": round(err, 6),
              "tolerance_met": bool(met),
              "surface_triangles": int(len(tris)), "surface_vertices": int(len(r)),
              "cells": int(rows * cols), "projection": projection,
              "algorithm": "greedy insertion of the cell farthest from the surface, Delaunay "
                           "triangulation (Garland-Heckbert; hmm through pydelatin), until "
                           "every cell of the region lies within the tolerance vertically"}
    if not met:
        record["note"] = (f"the triangle cap ({cap}) was reached before the tolerance: the "
                          f"surface lies up to {err:.4f} mm from a cell (tolerance {tol:g} mm)")
    return verts, out, volume, base_z, record, np.column_stack([r, c])


def solid_from_grid(x: np.ndarray, y: np.ndarray, z: np.ndarray, base_z: float
                    ) -> tuple[np.ndarray, np.ndarray, float]:
    """A closed solid between a height field and the plane ``z = base_z`` below it.

    ``x``, ``y``, ``z``: ``(nr, nc)`` node coordinates (mm) of a grid that is a rectangle in
    xy (any orientation, possibly mirrored). Returns float32 vertices, int64 triangles wound
    counter-clockwise seen from outside (the winding is consistent by construction; its sense
    is set by the signed volume), and the volume in mm^3."""
    nr, nc = z.shape
    top = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    loop = _boundary_loop(nr, nc)
    n_top, n_loop = nr * nc, len(loop)
    bottom = np.column_stack([top[loop, 0], top[loop, 1], np.full(n_loop, base_z)])
    centre = np.array([[0.5 * (x.min() + x.max()), 0.5 * (y.min() + y.max()), base_z]])
    verts = np.concatenate([top, bottom, centre]).astype(np.float32)
    g = np.arange(n_top).reshape(nr, nc)
    a, b, c, d = g[:-1, :-1].ravel(), g[:-1, 1:].ravel(), g[1:, :-1].ravel(), g[1:, 1:].ravel()
    surface = np.concatenate([np.column_stack([a, c, d]), np.column_stack([a, d, b])])
    t0, t1 = loop, np.roll(loop, -1)
    b0 = n_top + np.arange(n_loop)
    b1 = np.roll(b0, -1)
    walls = np.concatenate([np.column_stack([t0, t1, b1]), np.column_stack([t0, b1, b0])])
    fan = np.column_stack([np.full(n_loop, n_top + n_loop), b0, b1])
    tris = np.concatenate([surface, walls, fan]).astype(np.int64)
    volume = signed_volume(verts, tris)
    if volume < 0:
        tris = tris[:, [0, 2, 1]]
        volume = -volume
    return verts, np.ascontiguousarray(tris), volume


def make_cast(height: np.ndarray, spec: GridSpec, params: CastParams,
              progress: ProgressCallback | None = None,
              cancel: CancelToken | None = None) -> CastMesh:
    """The cast of ``height`` (float32 mm on ``spec``, NaN = no data); see the module's
    docstring for the frame and the two modes."""
    params.check()
    if tuple(height.shape) != tuple(spec.shape):
        raise InputError(f"height map {height.shape} does not match the grid {spec.shape}")
    report(progress, 0.0, "choosing the region")
    rs, cs = crop_region(spec, height, params.crop_mm)
    region = np.asarray(height[rs, cs], np.float64)
    missing = ~np.isfinite(region)
    if cancel is not None:
        cancel.check()
    report(progress, 0.1, f"filling {int(missing.sum())} cells without data")
    filled = fill_holes(region) if missing.any() else region
    if cancel is not None:
        cancel.check()
    rows, cols = region.shape
    if params.decimate == "adaptive":
        report(progress, 0.3, f"building the adaptive surface (within {params.tolerance_mm:g} "
                              f"mm of every cell)")
        verts, tris, volume, base_z, adaptive, rc = _adaptive_solid(
            filled, rs, cs, spec, params, params.base_mm, sub_progress(progress, 0.3, 0.9),
            cancel)
        if cancel is not None:
            cancel.check()
        report(progress, 1.0, "mesh ready")
        return CastMesh(verts, tris, params, _region_doc(spec, rs, cs, rows, cols), 1,
                        int(missing.sum()), int(missing[rc[:, 0], rc[:, 1]].sum()),
                        (rows, cols), base_z, volume, adaptive)
    quadric = params.decimate == "quadric"
    cap = max(params.max_triangles, QUADRIC_INPUT_TRIANGLES) if quadric else params.max_triangles
    step = choose_step(rows, cols, cap)
    ri, ci = _samples(rows, step), _samples(cols, step)
    report(progress, 0.3, f"building the mesh (every {step} cell(s))")
    jj, ii = np.meshgrid(cs.start + ci, rs.start + ri)
    from impress_gui.core.formats.writers import export_xy

    x, y = export_xy(spec, ii.astype(np.float64), jj.astype(np.float64))
    # the heights the file will hold: the heightmap's float32 values, exactly
    z = filled[np.ix_(ri, ci)].astype(np.float32).astype(np.float64)
    if params.positive:
        x, z = -x, -z  # the rotation by 180 deg about y (the y coordinate is unchanged)
    base_z = float(np.float32(z.min() - params.base_mm))
    verts, tris, volume = solid_from_grid(x, y, z, base_z)
    if cancel is not None:
        cancel.check()
    decimation: dict = {"method": "sample", "step_cells": step}
    if quadric:
        decimation = {"method": "quadric", "requested": "quadric",
                      "input_step_cells": step, "input_triangles": int(len(tris))}
        if len(tris) <= params.max_triangles:
            decimation["note"] = "the grid mesh already fits the triangle cap: not decimated"
        else:
            report(progress, 0.5, f"quadric decimation of {len(tris)} triangles to "
                                  f"{params.max_triangles}")
            qv, qt = quadric_decimate(verts, tris, params.max_triangles)
            qvol = signed_volume(qv, qt) if len(qt) else 0.0
            if len(qt) and closed_and_oriented(qt) and qvol > 0:
                verts, tris, volume = qv, qt, qvol
            else:  # never seen; a mesh that is not a closed outward solid is not written
                step = choose_step(rows, cols, params.max_triangles)
                ri, ci = _samples(rows, step), _samples(cols, step)
                jj, ii = np.meshgrid(cs.start + ci, rs.start + ri)
                x, y = export_xy(spec, ii.astype(np.float64), jj.astype(np.float64))
                z = filled[np.ix_(ri, ci)].astype(np.float32).astype(np.float64)
                if params.positive:
                    x, z = -x, -z
                verts, tris, volume = solid_from_grid(x, y, z, base_z)
                decimation = {"method": "sample", "requested": "quadric", "step_cells": step,
                              "note": "the quadric decimation's result was not a closed, "
                                      "outward solid: every step-th cell sampled instead"}
        if cancel is not None:
            cancel.check()
    report(progress, 1.0, "mesh ready")
    return CastMesh(verts, tris, params, _region_doc(spec, rs, cs, rows, cols), step, int(missing.sum()),
                    int(missing[np.ix_(ri, ci)].sum()), (len(ri), len(ci)), base_z, volume,
                    decimation)


def _region_doc(spec: GridSpec, rs: slice, cs: slice, rows: int, cols: int) -> dict:
    p = spec.pixel_mm
    crop_export = [spec.x0_mm + cs.start * p, -(spec.y0_mm + (rs.stop - 1) * p),
                   spec.x0_mm + (cs.stop - 1) * p, -(spec.y0_mm + rs.start * p)]
    return {"rows": [rs.start, rs.stop], "cols": [cs.start, cs.stop],
            "cells": [rows, cols],
            "crop_mm": [round(v, 9) for v in crop_export],
            "note": "cell rows/cols are [first, stop) of the reconstruction's grid; "
                    "crop_mm is x0,y0,x1,y1 of the cell centres in the export frame"}


# ----- verification --------------------------------------------------------------------------
def verify_mesh(mesh: CastMesh, cancel: CancelToken | None = None) -> dict:
    """The checks of the mesh as it will be written (the same float32 vertices and
    triangles): numpy's (closed and consistently wound, which implies edge-manifold and
    orientable; positive volume) and open3d's (vertex-manifold; edge-manifold and orientable
    only when numpy's check does not imply them; self-intersection up to
    :data:`SELF_INTERSECTION_MAX_TRIANGLES`). The values are open3d's own either way
    (tests/test_cast_checks.py). Returns the sidecar's ``checks``; ``ok`` is False when any
    check failed."""
    import open3d as o3d

    v, t = mesh.vertices, mesh.triangles
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(v.astype(np.float64)),
                                  o3d.utility.Vector3iVector(t.astype(np.int32)))
    out: dict = {"by": f"open3d {o3d.__version__} and numpy"}
    # numpy's edge check first (a fraction of a second where open3d's edge-manifold and
    # orientability tests take 27 s on 1.7 million triangles): when every directed edge occurs
    # once and its reverse once, and no triangle repeats a vertex, every edge has exactly two
    # triangles (edge-manifold without boundary) and the winding itself is a consistent
    # orientation (orientable); open3d's tests are run only when that does not hold
    closed = closed_and_oriented(t)
    implied = closed and not _degenerate(t)
    out["edge_manifold"] = True if implied else bool(
        m.is_edge_manifold(allow_boundary_edges=False))
    if cancel is not None:
        cancel.check()
    out["vertex_manifold"] = bool(m.is_vertex_manifold())
    if cancel is not None:
        cancel.check()
    out["orientable"] = True if implied else bool(m.is_orientable())
    if cancel is not None:
        cancel.check()
    out["closed_consistently_wound"] = closed
    out["volume_positive"] = bool(signed_volume(v, t) > 0)
    projection = (mesh.decimation or {}).get("projection")
    if projection is not None:
        # the adaptive surface: open3d's test flags coplanar long thin triangles that only
        # touch (a false alarm on flat ground); the exact check of the projection decides
        si = not projection["no_overlap"]
        out["self_intersection"] = {
            "tested": True, "self_intersecting": si,
            "method": "exact, in integer cell indices: the surface's triangles projected on "
                      "the base all turn the same way and their areas add up to the region's "
                      "rectangle (a triangulation without overlaps); the walls are vertical "
                      "under its boundary and the base lies below its lowest point"}
        out["watertight"] = bool(out["edge_manifold"] and out["vertex_manifold"] and not si)
    elif len(t) <= SELF_INTERSECTION_MAX_TRIANGLES:
        si = bool(m.is_self_intersecting())
        out["self_intersection"] = {"tested": True, "self_intersecting": si}
        # open3d's is_watertight(): edge- and vertex-manifold and not self-intersecting, each
        # found above (calling it ran the quadratic self-intersection test a second time)
        out["watertight"] = bool(out["edge_manifold"] and out["vertex_manifold"] and not si)
    else:
        out["self_intersection"] = {
            "tested": False,
            "reason": f"open3d's test is quadratic in the triangles (about 45 s for 90 000 "
                      f"on two cores); run up to {SELF_INTERSECTION_MAX_TRIANGLES}"}
        if (mesh.decimation or {}).get("method", "sample") == "sample":
            out["self_intersection"]["by_construction"] = (
                "a height field over a rectangle of the grid, every surface vertex above a flat "
                "base, vertical walls: no two triangles can cross")
        out["watertight"] = None
    checked = [out[k] for k in ("edge_manifold", "vertex_manifold", "orientable",
                                "closed_consistently_wound", "volume_positive")]
    if out["self_intersection"]["tested"]:
        checked.append(not out["self_intersection"]["self_intersecting"])
    out["ok"] = all(checked)
    return out


def surface_triangles(mesh: CastMesh) -> np.ndarray:
    """A mask of the mesh's top-surface triangles: those with an area seen from above (the
    side walls are vertical) and not lying in the base's plane."""
    v = mesh.vertices.astype(np.float64)
    t = mesh.triangles
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    area_xy = 0.5 * np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
                           - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
    base = float(np.float32(mesh.base_z_mm))
    on_base = (a[:, 2] == base) & (b[:, 2] == base) & (c[:, 2] == base)
    return (area_xy > 1e-12) & ~on_base


def surface_deviation(mesh: CastMesh, height: np.ndarray, spec: GridSpec) -> dict:
    """How far the mesh's top surface lies from the heightmap: a ray cast straight down (open3d)
    at every cell with data of the region (the vertical distance; and, under ``normal``, the
    same cells' closest-point distance to the mesh, which a wall between two samples does not
    turn into the wall's height) (every ``stride``-th row and column above
    :data:`DEVIATION_MAX_RAYS` cells, ``stride`` prime to the mesh's sampling step so that the
    cells between the samples count too), the hit's height against the cell's float32 value (in
    the cast's frame: ``(-x, y, -h)`` for the positive). Rays on the region's outer edge are
    moved 0.001 cell inwards (a ray along a boundary edge may miss)."""
    import open3d as o3d

    (r0, r1), (c0, c1) = mesh.region["rows"], mesh.region["cols"]
    n = (r1 - r0) * (c1 - c0)
    stride = max(1, math.ceil(math.sqrt(n / DEVIATION_MAX_RAYS)))
    while stride > 1 and math.gcd(stride, mesh.step) != 1:
        stride += 1  # never only the sampled cells (where a sampled surface is exact)
    ii, jj = np.mgrid[r0:r1:stride, c0:c1:stride]
    h = np.asarray(height[ii, jj], np.float32).astype(np.float64)
    ok = np.isfinite(h)
    from impress_gui.core.formats.writers import export_xy

    x, y = export_xy(spec, ii[ok].astype(np.float64), jj[ok].astype(np.float64))
    h = h[ok]
    eps = 1e-3 * spec.pixel_mm
    xa, ya = export_xy(spec, np.array([r0, r1 - 1], np.float64), np.array([c0, c1 - 1],
                                                                         np.float64))
    xe, ye = x, y  # the cells' own positions
    x = np.clip(x, xa.min() + eps, xa.max() - eps)
    y = np.clip(y, ya.min() + eps, ya.max() - eps)
    if mesh.params.positive:
        x, h, xe = -x, -h, -xe
    doc: dict = {"method": "rays cast straight down (open3d RaycastingScene) at the cells with "
                           "data, the absolute difference between the hit's height and the "
                           "cell's height (unsigned)",
                 "stride_cells": stride, "cells": int(h.size)}
    if h.size == 0:
        return doc | {"missed": 0}
    scene = o3d.t.geometry.RaycastingScene()
    tensor = o3d.core.Tensor.from_numpy
    scene.add_triangles(tensor(np.ascontiguousarray(mesh.vertices, np.float32)),
                        tensor(np.ascontiguousarray(mesh.triangles, np.uint32)))
    z0 = float(mesh.vertices[:, 2].max()) + 1.0
    rays = np.zeros((h.size, 6), np.float32)
    rays[:, 0], rays[:, 1], rays[:, 2], rays[:, 5] = x, y, z0, -1.0
    cast = scene.cast_rays(tensor(rays))
    t = cast["t_hit"].numpy().astype(np.float64)
    hit = np.isfinite(t)
    # the height of the triangle hit, at the cell's own (x, y), in float64 (the ray's float32
    # hit, and the ray moved inwards on the region's edge, are off by up to a few 0.0001 mm on
    # steep walls)
    surface_z = _plane_height(mesh, cast["primitive_ids"].numpy()[hit].astype(np.int64),
                              xe[hit], ye[hit])
    d = np.abs(np.where(np.isfinite(surface_z), surface_z, z0 - t[hit]) - h[hit])
    # the same cells' distance to the top surface itself (its closest point: along the
    # normal); the solid's side walls and base are left out, or a cell on the region's edge
    # would find the side wall beside it
    top = surface_triangles(mesh)
    surface = o3d.t.geometry.RaycastingScene()
    surface.add_triangles(tensor(np.ascontiguousarray(mesh.vertices, np.float32)),
                          tensor(np.ascontiguousarray(mesh.triangles[top], np.uint32)))
    pts = np.ascontiguousarray(np.column_stack([x, y, h]), np.float32)
    dn = surface.compute_distance(tensor(pts)).numpy().astype(np.float64)
    # the vertical distance bounds the closest-point one (the vertical through the cell meets
    # the surface); open3d's float32 closest-point query over-states it near long, thin
    # triangles (0.044 mm for a true 0.006 mm beside a 60 x 0.1 mm boundary triangle)
    dn[hit] = np.minimum(dn[hit], d)
    doc["normal"] = {
        "method": "closest-point distance from each cell's point (x, y, h) to the mesh "
                  "(open3d RaycastingScene.compute_distance): the distance along the surface's "
                  "normal, as inspection software measures a mesh against a point cloud",
        "max_mm": round(float(dn.max()), 6),
        "rms_mm": round(float(np.sqrt(np.mean(dn * dn))), 6),
        "p99_mm": round(float(np.quantile(dn, 0.99)), 6),
        "within_tolerance_fraction": round(float(np.mean(dn <= SURFACE_TOLERANCE_MM)), 6),
    }
    if d.size == 0:
        return doc | {"missed": int((~hit).sum())}
    return doc | {
        "missed": int((~hit).sum()),
        "max_mm": round(float(d.max()), 6),
        "rms_mm": round(float(np.sqrt(np.mean(d * d))), 6),
        "p99_mm": round(float(np.quantile(d, 0.99)), 6),
        "within_tolerance_fraction": round(float(np.mean(d <= SURFACE_TOLERANCE_MM)), 6),
        "tolerance_mm": SURFACE_TOLERANCE_MM,
    }


def _plane_height(mesh: CastMesh, tri: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The height at ``(x, y)`` of the plane through each triangle ``tri`` (float64)."""
    v = mesh.vertices.astype(np.float64)
    t = mesh.triangles[tri]
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    ux, uy, uz = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1], b[:, 2] - a[:, 2]
    wx, wy, wz = c[:, 0] - a[:, 0], c[:, 1] - a[:, 1], c[:, 2] - a[:, 2]
    det = ux * wy - uy * wx
    px, py = x - a[:, 0], y - a[:, 1]
    with np.errstate(invalid="ignore", divide="ignore"):
        s = (px * wy - py * wx) / det
        r = (ux * py - uy * px) / det
    z = a[:, 2] + s * uz + r * wz
    return np.where(det != 0, z, np.nan)


# ----- files ---------------------------------------------------------------------------------
def transform_matrix(positive: bool) -> list[list[float]]:
    """The 4 x 4 matrix taking export-frame points to the cast's coordinates."""
    s = -1.0 if positive else 1.0
    return [[s, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, s, 0.0], [0.0, 0.0, 0.0, 1.0]]


def _g(v: float) -> str:
    return f"{v:g}"


def stl_header(mesh: CastMesh, metadata_sha256: str | None) -> bytes:
    """80 ASCII bytes: software, mode, base, triangle cap, crop and as much of the
    reconstruction's metadata.json SHA-256 as fits (the sidecar has everything)."""
    p = mesh.params
    crop = "data" if p.crop_mm is None else ",".join(_g(v) for v in p.crop_mm)
    head = (f"IMPREsS {__version__} cast {'pos' if p.positive else 'neg'} b={_g(p.base_mm)} "
            f"t={p.max_triangles} c={crop} md=")
    room = 80 - len(head)
    if room < 12:  # a long crop gives way to the hash's first 12 digits
        head = head[: 80 - 12 - 4] + "~ md="
        room = 80 - len(head)
    text = head + (metadata_sha256 or "none")[:room]
    return text.encode("ascii", "replace").ljust(80, b" ")[:80]


def stl_bytes(mesh: CastMesh, header: bytes) -> bytes:
    """Binary STL: the header, the triangle count, per triangle its unit normal and corners."""
    v = mesh.vertices
    t = mesh.triangles
    rec = np.zeros(len(t), dtype=[("n", "<f4", (3,)), ("v", "<f4", (3, 3)), ("a", "<u2")])
    for k in range(0, len(t), CHUNK):
        corners = v[t[k : k + CHUNK]]  # (m, 3, 3) float32
        p = corners.astype(np.float64)
        n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        norm = np.linalg.norm(n, axis=1, keepdims=True)
        rec["n"][k : k + CHUNK] = np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)
        rec["v"][k : k + CHUNK] = corners
    return header[:80].ljust(80, b" ") + struct.pack("<I", len(t)) + rec.tobytes()


def ply_mesh_bytes(mesh: CastMesh, comments: list[str]) -> bytes:
    """Binary little-endian PLY: float32 x, y, z vertices and triangles (uchar count, int
    indices); each of ``comments`` is one header comment line."""
    faces = np.zeros(len(mesh.triangles), dtype=[("k", "u1"), ("i", "<i4", (3,))])
    faces["k"] = 3
    faces["i"] = mesh.triangles
    lines = "".join(f"comment {' '.join(str(c).split())}\n" for c in comments)
    header = ("ply\nformat binary_little_endian 1.0\n" + lines +
              f"element vertex {len(mesh.vertices)}\nproperty float x\nproperty float y\n"
              f"property float z\nelement face {len(mesh.triangles)}\n"
              "property list uchar int vertex_indices\nend_header\n")
    return (header.encode("ascii", "backslashreplace")
            + np.ascontiguousarray(mesh.vertices, "<f4").tobytes() + faces.tobytes())


def obj_bytes(mesh: CastMesh, comments: list[str]) -> bytes:
    """Wavefront OBJ: ``#`` comment lines, ``v x y z`` (the float32 values exactly, 9
    significant digits), ``f a b c`` (1-based)."""
    import io

    buf = io.BytesIO()
    for c in comments:
        buf.write(f"# {' '.join(str(c).split())}\n".encode("ascii", "backslashreplace"))
    np.savetxt(buf, mesh.vertices.astype(np.float64), fmt="v %.9g %.9g %.9g")
    np.savetxt(buf, mesh.triangles + 1, fmt="f %d %d %d")
    return buf.getvalue()


def cast_bytes(mesh: CastMesh, fmt: str, provenance: Mapping) -> bytes:
    """The mesh as ``fmt`` ("stl", "ply" or "obj") carrying ``provenance`` (the sidecar's
    document without the mesh file's own hash): in the STL header (short), as PLY/OBJ
    comments (in full)."""
    if fmt == "stl":
        src = (provenance.get("inputs") or {}).get("reconstruction") or {}
        return stl_bytes(mesh, stl_header(mesh, src.get("metadata_json_sha256")))
    from impress_gui.core.formats.provenance import comment_lines

    lines = [f"IMPREsS workstation {__version__} digital cast; units mm",
             *comment_lines(provenance)]
    if fmt == "ply":
        return ply_mesh_bytes(mesh, lines)
    if fmt == "obj":
        return obj_bytes(mesh, lines)
    raise InputError(f"unknown mesh format {fmt!r}: use .stl, .ply or .obj",
                     code=codes.E_CAST_SUFFIX)


def cast_document(mesh: CastMesh, spec: GridSpec, source: Mapping, heightmap_sha256: str,
                  fmt: str) -> dict:
    """The sidecar's record (without the mesh file's name, size and hash)."""
    p = mesh.params
    return {
        "format": CAST_FORMAT,
        "version": CAST_VERSION,
        "software": f"IMPREsS workstation {__version__}",
        "inputs": {"reconstruction": {
            "folder": source.get("reconstruction"),
            "metadata_json_sha256": source.get("metadata_json_sha256"),
            "heightmap_tif_sha256": heightmap_sha256,
            "video_sha256": source.get("video_sha256"),
            "calibration_sha256": source.get("calibration_sha256"),
            "reconstruction_software": source.get("reconstruction_software"),
            **({"note": source["note"]} if source.get("note") else {}),
        }},
        "parameters": p.to_json(),
        "frame": {
            "units": "mm",
            "handedness": "right",
            "description": CAST_FRAME,
            "transformation": POSITIVE_TRANSFORM if p.positive else NEGATIVE_TRANSFORM,
            "matrix": transform_matrix(p.positive),
            "surface": ("the impression as recorded: a vertex of cell [i, j] at (x, y, h)"
                        if not p.positive else
                        "the outsole's positive, relief up: a vertex of cell [i, j] at "
                        "(-x, y, -h)"),
        },
        "grid": spec.to_json(),
        "region": mesh.region,
        "holes": {"filled_cells": mesh.filled_cells, "filled_vertices": mesh.filled_vertices,
                  "method": "harmonic fill (each cell the mean of its 4 neighbours), solved "
                            "coarse to fine"},
        "mesh": {
            "format": fmt,
            "triangles": int(len(mesh.triangles)),
            "vertices": int(len(mesh.vertices)),
            "surface_vertices": (int((mesh.decimation or {})["surface_vertices"])
                                 if (mesh.decimation or {}).get("method") == "adaptive"
                                 else list(mesh.surface_shape)),
            "step_cells": mesh.step,
            "vertex_spacing_mm": round(mesh.step * spec.pixel_mm, 9),
            "decimation": mesh.decimation or {"method": "sample", "step_cells": mesh.step},
            "closed": True,
            "orientation": "counter-clockwise seen from outside (outward normals)",
            "base_z_mm": round(mesh.base_z_mm, 6),
            "volume_mm3": round(mesh.volume_mm3, 3),
            "bounding_box": mesh.bounding_box(),
        },
    }


def write_cast(recon: str | Path, output: str | Path, params: CastParams,
               progress: ProgressCallback | None = None,
               cancel: CancelToken | None = None, context: Mapping | None = None,
               replace: bool = False) -> dict:
    """Make the cast of a reconstruction folder and write it to ``output`` (.stl, .ply or
    .obj) with its sidecar ``output + ".json"``; both atomically. Returns the sidecar's
    document. Every check (folder, output, parameters) is made before any work; the mesh is
    verified (:func:`verify_mesh`, recorded as ``checks``; a failure writes nothing) and its
    surface measured against the heightmap (``surface_deviation``). ``context`` (e.g. the
    viewer's case and its signature) is recorded as ``export``. An existing file at
    ``output`` is replaced only when it is an earlier cast (its sidecar a cast document) or
    ``replace`` (a save dialog that has asked); otherwise E-OUTPUT-EXISTS, before any work."""
    from impress_gui.core.base.fileio import atomic_write_bytes, dumps_json
    from impress_gui.core.base.outdir import OutputError, check_output_file
    from impress_gui.core.base.progress import sub_progress
    from impress_gui.core.formats.provenance import reconstruction_source
    from impress_gui.core.measure.readings import load_reconstruction, verified_heightmap_sha256

    folder = Path(recon)
    if not folder.exists():
        raise InputError(f"{folder}: no such reconstruction folder", code=codes.E_CAST_NO_RECON)
    if not folder.is_dir():
        raise InputError(f"{folder} is a file, not a reconstruction folder (give the folder "
                         "impress process wrote)", code=codes.E_CAST_NOT_FOLDER)
    out = check_output_file(output, inputs=(folder,), formats=None)
    fmt = SUFFIXES.get(out.suffix.lower())
    if fmt is None:
        raise InputError(f"{output}: the name must end in .stl, .ply or .obj (the mesh's "
                         "format)", code=codes.E_CAST_SUFFIX)
    sidecar = check_output_file(out.with_name(out.name + ".json"), inputs=(folder,),
                                formats=(CAST_FORMAT,))
    if out.exists() and not replace and not sidecar.is_file():
        # another file of that name (a point cloud, a video renamed) is not a cast to replace
        raise OutputError(f"{output} exists and is not a cast this command wrote (no "
                          f"{sidecar.name} beside it): it is not replaced; name a new file",
                          code=codes.E_OUTPUT_EXISTS)
    params.check()
    report(progress, 0.0, f"reading {folder}")
    data = load_reconstruction(folder, layers=("fused",))
    source = reconstruction_source(data.metadata, data.folder)
    tif_sha = verified_heightmap_sha256(folder, data.metadata, codes.E_CAST_HASH)
    mesh = make_cast(data.height_mm, data.spec, params, sub_progress(progress, 0.1, 0.6),
                     cancel)
    report(progress, 0.6, "checking the mesh (open3d)")
    checks = verify_mesh(mesh, cancel)
    if not checks["ok"]:
        failed = [k for k, v in checks.items() if v is False] or ["self-intersection"]
        raise ImpressError(f"the cast failed its checks ({', '.join(failed)}): nothing was "
                           "written; please report this", code=codes.E_INTERNAL)
    report(progress, 0.8, "measuring the surface against the heightmap")
    deviation = surface_deviation(mesh, data.height_mm, data.spec)
    if cancel is not None:
        cancel.check()
    doc = cast_document(mesh, data.spec, source, tif_sha, fmt)
    doc["checks"] = checks
    doc["surface_deviation"] = deviation
    dec = mesh.decimation or {}
    if dec.get("method") == "adaptive" and not dec.get("tolerance_met", True):
        doc["warnings"] = [
            f"W-CAST-TOLERANCE: the triangle cap ({params.max_triangles}) was reached before "
            f"the tolerance: the surface lies up to {dec['max_vertical_error_mm']:.4f} mm from a "
            f"cell (tolerance {params.tolerance_mm:g} mm); raise the cap or crop the region"]
    if context:
        doc["export"] = dict(context)
    report(progress, 0.9, f"writing {out.name}")
    payload = cast_bytes(mesh, fmt, doc)
    if cancel is not None:
        cancel.check()
    atomic_write_bytes(out, payload)
    doc["mesh"] = {"file": out.name, "bytes": len(payload),
                   "sha256": hashlib.sha256(payload).hexdigest(), **doc["mesh"]}
    atomic_write_bytes(sidecar, dumps_json(doc).encode("utf-8"))
    report(progress, 1.0, "done")
    return doc


def read_cast_document(path: str | Path) -> dict:
    """A cast sidecar (``impress.cast`` v1), checked."""
    from impress_gui.core.base.fileio import read_json

    return read_json(path, CAST_FORMAT, (CAST_VERSION,))
