"""Reading a simulated scan's ground truth back, for comparisons with reconstructions."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def truth_on_grid(scan_dir: Path, spec) -> np.ndarray:
    """The true heightmap (mm) resampled (nearest cell) onto a reconstruction grid ``spec``.

    The truth's rail frame has its origin at the camera of frame 0, a reconstruction's at the
    camera of calibration frame t1: ``y_truth = y_reconstruction + travel_mm[t1]``."""
    import tifffile

    scan_dir = Path(scan_dir)
    truth = json.loads((scan_dir / "truth.json").read_text())
    th = tifffile.imread(scan_dir / truth["heightmap"]["file"])
    hm = truth["heightmap"]
    s1 = truth["travel_mm"][truth["calibration_frames"]["t1"]]
    jj = np.rint((spec.xs() - hm["x0_mm"]) / hm["pixel_mm"]).astype(int)
    ii = np.rint((spec.ys() + s1 - hm["y0_mm"]) / hm["pixel_mm"]).astype(int)
    okj = (jj >= 0) & (jj < th.shape[1])
    oki = (ii >= 0) & (ii < th.shape[0])
    out = np.full(spec.shape, np.nan, np.float32)
    out[np.ix_(oki, okj)] = th[np.ix_(ii[oki], jj[okj])]
    return out


def _turn_ideal_to_rail(truth: dict) -> np.ndarray:
    """The rotation from the calibration's ideal frame to the simulator's rail frame (the
    identity unless a random rig turned the camera about the motion axis)."""
    rr = truth.get("random_rig")
    if not rr:
        return np.eye(3)
    to_rail = np.asarray(rr["rotation_camera_to_rail"], float)
    to_ideal = np.asarray(truth["rotation_camera_to_ideal"], float)
    return to_rail @ to_ideal.T


def truth_for_reconstruction(scan_dir: Path, spec, height_mm: np.ndarray,
                             reference_depth) -> np.ndarray:
    """The true height (mm, nearest truth cell) under each reconstructed point.

    A cell ``(X', Y')`` with height ``h`` is the point ``(X', Y', reference_depth(X', Y') - h)``
    of the calibration's rail frame; turned into the simulator's frame it lands at some world
    ``(x, y)``, where the truth is read. With no rotation about the motion axis this is
    :func:`truth_on_grid` (the world ``(x, y)`` is the cell's own); with one, the map's axes are
    not the ground's and the truth is looked up where each point really is. NaN where ``h`` is.
    """
    import tifffile

    scan_dir = Path(scan_dir)
    truth = json.loads((scan_dir / "truth.json").read_text())
    turn = _turn_ideal_to_rail(truth)
    if np.allclose(turn, np.eye(3), atol=0):
        out = truth_on_grid(scan_dir, spec)
        return np.where(np.isfinite(height_mm), out, np.nan).astype(np.float32)
    th = tifffile.imread(scan_dir / truth["heightmap"]["file"])
    hm = truth["heightmap"]
    s1 = truth["travel_mm"][truth["calibration_frames"]["t1"]]
    out = np.full(spec.shape, np.nan, np.float32)
    ii, jj = np.nonzero(np.isfinite(height_mm))
    x = spec.xs()[jj]
    y = spec.ys()[ii]
    z = reference_depth(x, y) - height_mm[ii, jj]
    p = np.column_stack([x, y, z]) @ turn.T
    ci = np.rint((p[:, 1] + s1 - hm["y0_mm"]) / hm["pixel_mm"]).astype(int)
    cj = np.rint((p[:, 0] - hm["x0_mm"]) / hm["pixel_mm"]).astype(int)
    ok = (ci >= 0) & (ci < th.shape[0]) & (cj >= 0) & (cj < th.shape[1])
    out[ii[ok], jj[ok]] = th[ci[ok], cj[ok]]
    return out


def rail_to_reconstruction(scan_dir: Path, points_rail_mm: np.ndarray) -> np.ndarray:
    """Simulator rail-frame points ``(N, 3)`` in the reconstruction's frame (ideal axes, origin
    at the camera of calibration frame t1), e.g. the exact stripe points for a fill mask."""
    truth = json.loads((Path(scan_dir) / "truth.json").read_text())
    s1 = truth["travel_mm"][truth["calibration_frames"]["t1"]]
    rel = np.asarray(points_rail_mm, float) - np.array([0.0, s1, 0.0])
    return rel @ _turn_ideal_to_rail(truth)
