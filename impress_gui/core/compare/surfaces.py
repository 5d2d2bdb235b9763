"""A surface to compare: a height grid in the right-handed export frame, in millimetres.

Every input becomes a :class:`Surface`: heights ``height_mm[i, j]`` (float32, NaN = no data) at
``x = x0_mm + j * pixel_mm``, ``y = y0_mm + i * y_step_mm`` of the export frame
(:data:`~impress_gui.core.formats.writers.EXPORT_FRAME`: x = rail X, y = -rail Y, z up).

- a reconstruction folder (``impress process``): its fused ``heightmap.tif`` on the grid of
  ``metadata.json``; row 0 has the largest y (``y_step_mm = -pixel_mm``), as the image shows it;
- an X3P (as ``impress process`` exports it: the export frame, y growing with the row);
- a PLY point cloud (x, y, z in mm in the export frame): binned onto a grid of ``pixel_mm``
  (the mean z of the points in each cell), row 0 at the largest y.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from impress_gui.core.base import codes
from impress_gui.core.base.errors import InputError

DEFAULT_PLY_PIXEL_MM = 0.2
MAX_PLY_CELLS = 100_000_000


@dataclass(frozen=True)
class Surface:
    """Heights (mm) on a regular grid of the export frame; see the module's docstring."""

    height_mm: np.ndarray
    x0_mm: float
    y0_mm: float
    pixel_mm: float
    y_step_mm: float
    source: Mapping = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, int]:
        rows, cols = self.height_mm.shape
        return int(rows), int(cols)

    def xy(self, rows, cols) -> tuple[np.ndarray, np.ndarray]:
        """Export-frame (x, y) in mm of cells (fractional rows and columns allowed)."""
        return (self.x0_mm + np.asarray(cols, np.float64) * self.pixel_mm,
                self.y0_mm + np.asarray(rows, np.float64) * self.y_step_mm)

    def cell(self, x, y) -> tuple[np.ndarray, np.ndarray]:
        """Fractional (row, col) of export-frame points."""
        return ((np.asarray(y, np.float64) - self.y0_mm) / self.y_step_mm,
                (np.asarray(x, np.float64) - self.x0_mm) / self.pixel_mm)

    def sample(self, x, y) -> np.ndarray:
        """Bilinear heights at export-frame points; NaN outside or where a corner has no data."""
        fi, fj = self.cell(x, y)
        return bilinear(self.height_mm, fi, fj)

    def points(self, step: int = 1, window: tuple[slice, slice] | None = None) -> np.ndarray:
        """``(N, 3)`` float64 points of the cells with data (every ``step``-th row and column of
        ``window``, default the whole grid)."""
        rs, cs = window or (slice(0, self.shape[0]), slice(0, self.shape[1]))
        ii = np.arange(rs.start, rs.stop, step)
        jj = np.arange(cs.start, cs.stop, step)
        h = self.height_mm[np.ix_(ii, jj)]
        ok = np.isfinite(h)
        r, c = np.nonzero(ok)
        x, y = self.xy(ii[r], jj[c])
        return np.column_stack([x, y, h[ok].astype(np.float64)])

    def crop(self, window: tuple[slice, slice]) -> Surface:
        """The cells of ``window`` (rows, cols) as a surface of their own (same frame)."""
        rs, cs = window
        x0, y0 = self.xy(rs.start, cs.start)
        return Surface(self.height_mm[rs, cs], float(x0), float(y0), self.pixel_mm,
                       self.y_step_mm, self.source)

    def bounds(self) -> dict:
        """Where the grid lies (export frame, mm)."""
        x_a, y_a = self.xy(0, 0)
        x_b, y_b = self.xy(self.shape[0] - 1, self.shape[1] - 1)
        return {"x_mm": [float(min(x_a, x_b)), float(max(x_a, x_b))],
                "y_mm": [float(min(y_a, y_b)), float(max(y_a, y_b))]}

    def grid_json(self) -> dict:
        return {"x0_mm": self.x0_mm, "y0_mm": self.y0_mm, "pixel_mm": self.pixel_mm,
                "y_step_mm": self.y_step_mm, "shape": list(self.shape),
                "convention": "cell [i, j] at export-frame x = x0 + j*pixel, y = y0 + i*y_step"}


def bilinear(height: np.ndarray, fi: np.ndarray, fj: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of ``height`` at fractional cells; NaN when outside the grid or
    when one of the four cells around has no data (float64)."""
    fi = np.asarray(fi, np.float64)
    fj = np.asarray(fj, np.float64)
    rows, cols = height.shape
    out = np.full(fi.shape, np.nan)
    ok = np.isfinite(fi) & np.isfinite(fj) & (fi >= 0) & (fj >= 0) & (fi <= rows - 1) \
        & (fj <= cols - 1)
    if not ok.any():
        return out
    i, j = fi[ok], fj[ok]
    i0 = np.minimum(np.floor(i).astype(np.int64), rows - 2) if rows > 1 else np.zeros(i.shape,
                                                                                       np.int64)
    j0 = np.minimum(np.floor(j).astype(np.int64), cols - 2) if cols > 1 else np.zeros(j.shape,
                                                                                       np.int64)
    ti, tj = i - i0, j - j0
    i1 = np.minimum(i0 + 1, rows - 1)
    j1 = np.minimum(j0 + 1, cols - 1)
    h = height
    v = ((1 - ti) * ((1 - tj) * h[i0, j0] + tj * h[i0, j1])
         + ti * ((1 - tj) * h[i1, j0] + tj * h[i1, j1]))
    out[ok] = v
    return out


# ----- loading -------------------------------------------------------------------------------
def _sha(path: Path) -> str:
    from impress_gui.core.base.fileio import sha256_file

    return sha256_file(path)


def load_surface(path: str | Path, ply_pixel_mm: float = DEFAULT_PLY_PIXEL_MM) -> Surface:
    """A surface from a reconstruction folder, a ``.x3p`` or a ``.ply`` (see the module)."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such reconstruction folder or file",
                         code=codes.E_COMPARE_INPUT)
    if p.is_dir():
        return _from_reconstruction(p)
    suffix = p.suffix.lower()
    if suffix == ".x3p":
        return _from_x3p(p)
    if suffix == ".ply":
        return _from_ply(p, ply_pixel_mm)
    raise InputError(f"{p}: not a reconstruction folder, .x3p or .ply (nothing else is "
                     "compared)", code=codes.E_COMPARE_INPUT)


def _from_reconstruction(folder: Path) -> Surface:
    from impress_gui.core.formats.recon_files import HEIGHTMAP_FILE, METADATA_FILE
    from impress_gui.core.measure.readings import load_reconstruction, verified_heightmap_sha256

    data = load_reconstruction(folder, layers=("fused",))
    tif_sha = verified_heightmap_sha256(folder, data.metadata, codes.E_COMPARE_HASH,
                                        "never compare a changed map")
    spec = data.spec
    inputs = data.metadata.get("inputs") or {}
    source = {"kind": "reconstruction", "path": str(folder),
              "files": {HEIGHTMAP_FILE: tif_sha, METADATA_FILE: _sha(folder / METADATA_FILE)},
              "video_sha256": (inputs.get("video") or {}).get("sha256"),
              "calibration_sha256": (inputs.get("calibration") or {}).get("sha256")}
    return Surface(np.asarray(data.height_mm, np.float32), float(spec.x0_mm),
                   float(-spec.y0_mm), float(spec.pixel_mm), float(-spec.pixel_mm), source)


def _from_x3p(path: Path) -> Surface:
    from impress_gui.core.formats.readers import read_x3p

    d = read_x3p(path)
    spec = d.spec
    return Surface(np.asarray(d.height_mm, np.float32), float(spec.x0_mm), float(spec.y0_mm),
                   float(spec.pixel_mm), float(spec.pixel_mm),
                   {"kind": "x3p", "path": str(path), "files": {path.name: _sha(path)}})


def _from_ply(path: Path, pixel_mm: float) -> Surface:
    from impress_gui.core.formats.readers import read_ply

    if not (np.isfinite(pixel_mm) and 0.01 <= pixel_mm <= 10.0):
        raise InputError(f"the PLY grid must be 0.01 to 10 mm (got {pixel_mm})",
                         code=codes.E_COMPARE_OPTION)
    pts = read_ply(path).points_mm
    pts = pts[np.all(np.isfinite(pts), axis=1)]
    if len(pts) < 3:
        raise InputError(f"{path}: fewer than 3 points", code=codes.E_COMPARE_NO_DATA)
    return grid_points(pts, pixel_mm, {"kind": "ply", "path": str(path),
                                       "files": {path.name: _sha(path)},
                                       "gridded_pixel_mm": pixel_mm})


def grid_points(pts: np.ndarray, pixel_mm: float, source: Mapping | None = None) -> Surface:
    """Points ``(N, 3)`` (export frame, mm) binned onto a grid of ``pixel_mm`` (row 0 at the
    largest y): the mean z of each cell's points, NaN where none fell."""
    x0 = float(np.floor(pts[:, 0].min() / pixel_mm) * pixel_mm)
    y_top = float(np.ceil(pts[:, 1].max() / pixel_mm) * pixel_mm)
    cols = int(np.rint((pts[:, 0].max() - x0) / pixel_mm)) + 1
    rows = int(np.rint((y_top - pts[:, 1].min()) / pixel_mm)) + 1
    if rows * cols > MAX_PLY_CELLS:
        raise InputError(f"the points span {rows} x {cols} cells of {pixel_mm} mm: too many; "
                         "choose a coarser grid", code=codes.E_COMPARE_OPTION)
    j = np.clip(np.rint((pts[:, 0] - x0) / pixel_mm).astype(np.int64), 0, cols - 1)
    i = np.clip(np.rint((y_top - pts[:, 1]) / pixel_mm).astype(np.int64), 0, rows - 1)
    flat = i * cols + j
    total = np.bincount(flat, weights=pts[:, 2], minlength=rows * cols)
    count = np.bincount(flat, minlength=rows * cols)
    with np.errstate(invalid="ignore", divide="ignore"):
        h = np.where(count > 0, total / np.maximum(count, 1), np.nan)
    return Surface(h.reshape(rows, cols).astype(np.float32), x0, y_top, float(pixel_mm),
                   -float(pixel_mm), dict(source or {}))
