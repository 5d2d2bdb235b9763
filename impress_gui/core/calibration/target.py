"""The L-shaped calibration target model (format ``impress.target``).

Corners A-F and faces are given in the object's own frame in mm: x across the scan,
y along the scan, z up from the target's base (the ground it stands on).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from impress_gui.core.base.errors import FormatError
from impress_gui.core.base.fileio import float_array, read_json, require, write_json

TARGET_FORMAT = "impress.target"
CORNER_NAMES = ("A", "B", "C", "D", "E", "F")


#: the most faces a target file may describe, and vertices per face (the L target has 7
#: faces of 4 vertices; a lab's own target a few more)
MAX_FACES = 64
MAX_FACE_VERTICES = 64


@dataclass(frozen=True)
class Face:
    """A planar convex polygon of the target; ``vertices_mm`` is ``(N, 3)`` counter-clockwise
    seen from outside, so the outward normal is ``(v1 - v0) x (v2 - v0)``."""

    name: str
    vertices_mm: np.ndarray

    @property
    def normal(self) -> np.ndarray:
        v = self.vertices_mm
        n = np.cross(v[1] - v[0], v[2] - v[0])
        return n / np.linalg.norm(n)

    @property
    def is_horizontal(self) -> bool:
        return abs(self.normal[2]) > 0.999


@dataclass(frozen=True)
class TargetModel:
    name: str
    corners_mm: dict[str, np.ndarray]
    faces: tuple[Face, ...]
    description: str = ""

    def corner_array(self) -> np.ndarray:
        """Corners as ``(6, 3)`` in the order A-F."""
        return np.array([self.corners_mm[c] for c in CORNER_NAMES])

    def top_faces(self) -> tuple[Face, ...]:
        return self._top_faces

    @functools.cached_property
    def _top_faces(self) -> tuple[Face, ...]:
        # computed once per model (the calibration's tilt refinement asks thousands of times)
        return tuple(f for f in self.faces if f.is_horizontal and f.normal[2] > 0)

    def size_mm(self) -> float:
        """RMS distance of the corners from their centroid (the scale the fit compares)."""
        c = self.corner_array()
        return float(np.sqrt(np.mean(np.sum((c - c.mean(0)) ** 2, axis=1))))

    def heightfield(self, x_mm: np.ndarray, y_mm: np.ndarray, grow_mm: float = 0.0) -> np.ndarray:
        """Height of the target's top surface at object-frame points (NaN off the target).

        ``grow_mm`` widens each top face by that much in x and y (a grid sampled at cell
        centres puts a face's edge half a cell further out)."""
        h = np.full(np.broadcast(x_mm, y_mm).shape, np.nan)
        for face in self.top_faces():
            v = face.vertices_mm[:, :2]
            if grow_mm:
                v = v + grow_mm * np.sign(v - v.mean(0))
            inside = _inside_convex(v, x_mm, y_mm)
            h = np.where(inside, np.fmax(h, face.vertices_mm[0, 2]), h)
        return h

    def to_json(self) -> dict:
        return {
            "format": TARGET_FORMAT,
            "version": 1,
            "name": self.name,
            "description": self.description,
            "units": "mm",
            "frame": "x across the scan, y along the scan, z up from the base",
            "corners_mm": {k: self.corners_mm[k].tolist() for k in CORNER_NAMES},
            "faces": [{"name": f.name, "vertices_mm": f.vertices_mm.tolist()} for f in self.faces],
        }

    @classmethod
    def from_json(cls, doc: dict, where: str = "") -> TargetModel:
        corners_doc = require(doc, "corners_mm", dict, where)
        missing = [c for c in CORNER_NAMES if c not in corners_doc]
        if missing:
            raise FormatError(f"{where}target corners {', '.join(missing)} are missing")
        corners = {c: float_array(corners_doc[c], (3,), f"corner {c}") for c in CORNER_NAMES}
        arr = np.array(list(corners.values()))
        if np.linalg.matrix_rank(arr - arr.mean(0), tol=1e-6) < 3:
            raise FormatError(f"{where}target corners are coplanar; heights must differ")
        if min(np.linalg.norm(arr[i] - arr[j]) for i in range(6) for j in range(i)) < 1.0:
            raise FormatError(f"{where}two target corners coincide")
        faces = []
        face_docs = require(doc, "faces", list, where)
        if len(face_docs) > MAX_FACES:
            # every face is projected and searched for stripe points in every plane frame:
            # a thousand faces made the calibration run for minutes
            raise FormatError(f"{where}{len(face_docs)} faces: a target has at most "
                              f"{MAX_FACES}")
        for i, fd in enumerate(face_docs):
            if not isinstance(fd, dict):
                raise FormatError(f"{where}face {i} must be an object")
            verts = require(fd, "vertices_mm", list, where)
            v = float_array(verts, (len(verts), 3), f"face {i} vertices")
            if not 3 <= len(v) <= MAX_FACE_VERTICES:
                raise FormatError(f"{where}face {i} needs 3 to {MAX_FACE_VERTICES} vertices")
            if not np.linalg.norm(np.cross(v[1] - v[0], v[2] - v[0])) > 1e-9:
                raise FormatError(f"{where}face {i} is degenerate (its first vertices are on "
                                  "one line)")
            faces.append(Face(str(fd.get("name", f"face{i}")), v))
        if not any(f.is_horizontal for f in faces):
            raise FormatError(f"{where}the target has no horizontal face for the lasers")
        return cls(str(require(doc, "name", str, where)), corners, tuple(faces),
                   str(doc.get("description", "")))

    def save(self, path) -> None:
        write_json(path, self.to_json())

    @classmethod
    def load(cls, path) -> TargetModel:
        return cls.from_json(read_json(path, TARGET_FORMAT), f"{path}: ")


def _inside_convex(poly_xy: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Points inside a convex polygon (either orientation), edges included."""
    n = len(poly_xy)
    signs = []
    for i in range(n):
        x0, y0 = poly_xy[i]
        x1, y1 = poly_xy[(i + 1) % n]
        signs.append((x1 - x0) * (y - y0) - (y1 - y0) * (x - x0))
    s = np.stack(signs)
    return np.all(s >= -1e-9, axis=0) | np.all(s <= 1e-9, axis=0)


def resources_dir() -> Path:
    """The product's ``resources/`` folder (source tree or installed bundle)."""
    here = Path(__file__).resolve()
    for cand in (here.parents[3] / "resources", here.parents[2] / "resources"):
        if cand.is_dir():
            return cand
    raise FileNotFoundError("the resources folder of impress_gui is missing")


def default_target() -> TargetModel:
    return TargetModel.load(resources_dir() / "targets" / "l_target_v1.json")


def make_l_target(low_h=10.0, high_h=40.0, low_w=40.0, high_w=40.0, length=70.0) -> TargetModel:
    """The default L target: a low step beside a high step, ``length`` mm along the scan."""
    x1, x2, L = low_w, low_w + high_w, length
    corners = {
        "A": [0, 0, low_h], "B": [0, L, low_h],
        "C": [x1, L, high_h], "D": [x2, L, high_h],
        "E": [x2, 0, high_h], "F": [x1, 0, high_h],
    }
    faces = [
        ("low top", [[0, 0, low_h], [x1, 0, low_h], [x1, L, low_h], [0, L, low_h]]),
        ("high top", [[x1, 0, high_h], [x2, 0, high_h], [x2, L, high_h], [x1, L, high_h]]),
        ("riser", [[x1, 0, low_h], [x1, 0, high_h], [x1, L, high_h], [x1, L, low_h]]),
        ("low side", [[0, 0, 0], [0, 0, low_h], [0, L, low_h], [0, L, 0]]),
        ("high side", [[x2, 0, 0], [x2, L, 0], [x2, L, high_h], [x2, 0, high_h]]),
    ]
    return TargetModel(
        "IMPREsS L target v1",
        {k: np.array(v, float) for k, v in corners.items()},
        tuple(Face(n, np.array(v, float)) for n, v in faces),
        f"L-shaped block: low step {low_h:g} mm high, {low_w:g} mm wide; high step {high_h:g} mm "
        f"high, {high_w:g} mm wide; {L:g} mm long along the scan.",
    )
