"""The cast's surface against the heightmap, vertically and along the normal (issue 20).

A 2 mm step wall running along y on flat ground, cast with a triangle cap that makes the mesh
sample every k-th cell: the surface between two samples cuts across the wall. Every cell's
expected distances come from plane geometry (the sampled surface is the polyline through the
sampled cells, extruded along y, since nothing changes along y): the vertical distance is the
absolute difference between the polyline's height there and the cell's; the normal distance is
the point's distance to the polyline. The record's figures (``surface_deviation`` and its ``normal``) must be those. At full
resolution both are float rounding."""

from __future__ import annotations

import json

import numpy as np
import pytest

from impress_gui.core.measure import cast as C
from impress_gui.core.reconstruction.grid import GridSpec

pytest.importorskip("open3d")

PIXEL_MM = 0.1
ROWS, COLS = 40, 61
WALL_COL = 31  # cells from this column on are 2 mm high
WALL_MM = 2.0
SPEC = GridSpec(-3.0, 10.0, PIXEL_MM, (ROWS, COLS))


def step_wall() -> np.ndarray:
    h = np.zeros((ROWS, COLS), np.float32)
    h[:, WALL_COL:] = WALL_MM
    return h


def polyline_distances(x: np.ndarray, z: np.ndarray, xs: np.ndarray, zs: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """For points (x, z): the vertical distance to the polyline through (xs, zs) (its linear
    interpolation at x) and the Euclidean distance to it (the nearest of its segments)."""
    vertical = np.abs(np.interp(x, xs, zs) - z)
    p = np.column_stack([x, z])[:, None, :]
    a = np.column_stack([xs[:-1], zs[:-1]])[None]
    b = np.column_stack([xs[1:], zs[1:]])[None]
    ab = b - a
    t = np.clip(np.sum((p - a) * ab, axis=2) / np.sum(ab * ab, axis=2), 0.0, 1.0)
    nearest = a + t[..., None] * ab
    return vertical, np.min(np.linalg.norm(p - nearest, axis=2), axis=1)


@pytest.mark.parametrize("positive", [False, True])
def test_sampled_cast_deviation_vertical_and_normal(positive):
    h = step_wall()
    cap = 700  # the full grid would need 2 * 39 * 60 + 6 * 99 = 5274 triangles
    mesh = C.make_cast(h, SPEC, C.CastParams(decimate="sample", positive=positive, max_triangles=cap))
    k = mesh.step
    assert k > 1 and len(mesh.triangles) <= cap
    cols = np.arange(0, COLS, k)
    cols = cols if cols[-1] == COLS - 1 else np.append(cols, COLS - 1)
    assert not np.isin([WALL_COL - 1, WALL_COL], cols).all()  # the wall falls between samples
    xs = SPEC.x0_mm + cols * PIXEL_MM
    x = SPEC.x0_mm + np.arange(COLS) * PIXEL_MM
    vertical, normal = polyline_distances(x, h[0].astype(np.float64), xs,
                                          h[0, cols].astype(np.float64))
    assert vertical.max() > 0.4 and normal.max() < vertical.max() / 2
    dev = C.surface_deviation(mesh, h, SPEC)
    assert dev["cells"] == ROWS * COLS and dev["missed"] == 0
    tol = 1e-4
    assert dev["max_mm"] == pytest.approx(vertical.max(), abs=tol)
    n = dev["normal"]
    assert n["max_mm"] == pytest.approx(normal.max(), abs=tol)
    # every row is the same: the shares are those of one row
    assert n["within_tolerance_fraction"] == pytest.approx(np.mean(normal <= 0.02), abs=1e-6)
    assert dev["within_tolerance_fraction"] == pytest.approx(np.mean(vertical <= 0.02),
                                                             abs=1e-6)
    assert n["rms_mm"] == pytest.approx(np.sqrt(np.mean(normal ** 2)), abs=tol)


def test_full_resolution_cast_is_on_the_heightmap_both_ways(tmp_path):
    """At full resolution every cell is a vertex: both distances are float rounding; the
    command's sidecar carries both."""
    import tifffile

    h = step_wall()
    folder = tmp_path / "recon"
    folder.mkdir()
    tifffile.imwrite(folder / "heightmap.tif", h)
    import hashlib

    sha = hashlib.sha256((folder / "heightmap.tif").read_bytes()).hexdigest()
    meta = {"format": "impress.reconstruction", "version": 1, "software": "test",
            "grid": {"x0_mm": SPEC.x0_mm, "y0_mm": SPEC.y0_mm, "pixel_mm": PIXEL_MM,
                     "shape": [ROWS, COLS]},
            "files": {"heightmap.tif": sha}}
    (folder / "metadata.json").write_text(json.dumps(meta))
    from impress_gui.cli import main

    out = tmp_path / "cast.stl"
    assert main(["cast", str(folder), "-o", str(out)]) == 0
    doc = json.loads((tmp_path / "cast.stl.json").read_text())
    dev = doc["surface_deviation"]
    assert dev["max_mm"] <= 1e-4 and dev["normal"]["max_mm"] <= 1e-4
    assert dev["normal"]["within_tolerance_fraction"] == 1.0
