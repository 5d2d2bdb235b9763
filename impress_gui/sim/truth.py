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


def _angle_deg(r: np.ndarray) -> float:
    """The angle (deg) of a rotation matrix."""
    return float(np.degrees(np.arccos(np.clip((np.trace(r) - 1.0) / 2.0, -1.0, 1.0))))


def _turn_ideal_to_rail(truth: dict, rotation: np.ndarray | None = None) -> np.ndarray:
    """The rotation from a reconstruction's frame to the simulator's rail frame.

    The simulator's rail frame is the ideal frame (the camera turned by roll and tilt, the
    motion on +Y) turned by a random rig's cross tilt about the motion axis, which levels the
    ground. A calibration levels its frame the same way (scene.calibrate_scene: the target's
    base level across the scan), so its frame is nominally the rail frame itself; one made
    before the levelling is in the ideal frame. ``rotation`` (camera -> the calibration's
    frame) tells which: the nominal frame nearer to it is taken, and the exact nominal turn
    returned (identity, or the rig's turn about Y), so that the calibration's own rotation
    errors still show as errors. ``rotation`` None: the simulator's ideal frame (e.g. a true
    parameter set built from truth.json's ideal-frame planes and rotation)."""
    rr = truth.get("random_rig")
    if not rr:
        return np.eye(3)
    to_rail = np.asarray(rr["rotation_camera_to_rail"], float)
    to_ideal = np.asarray(truth["rotation_camera_to_ideal"], float)
    turn = to_rail @ to_ideal.T
    if rotation is None:
        return turn
    rot = np.asarray(rotation, float)
    if _angle_deg(to_rail @ rot.T) <= _angle_deg(to_ideal @ rot.T):
        return np.eye(3)
    return turn


def truth_for_reconstruction(scan_dir: Path, spec, height_mm: np.ndarray,
                             reference_depth, rotation: np.ndarray | None = None) -> np.ndarray:
    """The true height (mm, nearest truth cell) under each reconstructed point.

    A cell ``(X', Y')`` with height ``h`` is the point ``(X', Y', reference_depth(X', Y') - h)``
    of the calibration's rail frame; turned into the simulator's frame it lands at some world
    ``(x, y)``, where the truth is read. When the calibration's frame is the simulator's rail
    frame (a levelled calibration: ``rotation``, the calibration's camera -> frame rotation,
    says which, see :func:`_turn_ideal_to_rail`) this is :func:`truth_on_grid` (the world
    ``(x, y)`` is the cell's own); in the ideal frame of a rig turned about the motion axis,
    the map's axes are not the ground's and the truth is looked up where each point really is.
    NaN where ``h`` is.
    """
    import tifffile

    scan_dir = Path(scan_dir)
    truth = json.loads((scan_dir / "truth.json").read_text())
    turn = _turn_ideal_to_rail(truth, rotation)
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


def rail_to_reconstruction(scan_dir: Path, points_rail_mm: np.ndarray,
                           rotation: np.ndarray | None = None) -> np.ndarray:
    """Simulator rail-frame points ``(N, 3)`` in the reconstruction's frame (origin at the
    camera of calibration frame t1; axes those of the calibration whose camera -> frame
    rotation is ``rotation``, see :func:`_turn_ideal_to_rail`; None: the ideal frame), e.g.
    the exact stripe points for a fill mask."""
    truth = json.loads((Path(scan_dir) / "truth.json").read_text())
    s1 = truth["travel_mm"][truth["calibration_frames"]["t1"]]
    rel = np.asarray(points_rail_mm, float) - np.array([0.0, s1, 0.0])
    return rel @ _turn_ideal_to_rail(truth, rotation)


def true_laser_plane(truth: dict, name: str, rotation: np.ndarray | None = None):
    """The simulator's laser plane ``name`` in the frame of a calibration whose camera -> frame
    rotation is ``rotation`` (see :func:`_turn_ideal_to_rail`; None: the ideal frame), as a
    :class:`~impress_gui.core.calibration.geometry.Plane` through the camera's origin's frame
    (a turn about the origin keeps the offset)."""
    from impress_gui.core.calibration.geometry import Plane

    la = truth["lasers"][name]
    if "plane_rail" not in la:  # no turn about the motion axis: the ideal frame is the rail's
        return Plane.from_json(la["plane"], name)
    rail = Plane.from_json(la["plane_rail"], name)
    turn = _turn_ideal_to_rail(truth, rotation)
    return Plane(turn.T @ rail.normal, rail.offset_mm)


def true_cal_params(scan_dir: Path, cal):
    """The simulator's true calibration as a CalParams, in the frame convention of ``cal``
    (origin at the camera at frame t1; axes levelled across the scan as the calibration levels
    its own, i.e. the simulator's rail frame, or the ideal frame for a calibration that was
    not levelled: sim.truth._turn_ideal_to_rail picks the nominal frame nearer to ``cal``'s).
    The true ideal frame of a rig turned about the motion axis is not the levelled one: a
    length in the map's plane measured there differs by the turn (up to 2 % at 5.7 deg)."""
    from impress_gui.core.calibration.solve import umeyama
    from impress_gui.core.calibration.target import CORNER_NAMES, TargetModel
    from impress_gui.core.calibration.uncertainty import CalParams, reference_coeffs

    truth = json.loads((scan_dir / "truth.json").read_text())
    target = TargetModel.load(scan_dir / "target.json")
    tc = np.array([truth["target"]["corners_rail_mm"][c] for c in CORNER_NAMES])
    corners = rail_to_reconstruction(scan_dir, tc, cal.rotation)
    _, r_o, t_o = umeyama(target.corner_array(), corners, with_scale=False)
    normals, offsets = {}, {}
    for name in ("green", "red"):
        tp = true_laser_plane(truth, name, cal.rotation).oriented_like(cal.planes[name].plane)
        normals[name] = np.asarray(tp.normal, float)[None]
        offsets[name] = np.array([float(tp.offset_mm)])
    # camera -> the calibration's nominal frame: camera -> ideal, then ideal -> that frame
    rot = (_turn_ideal_to_rail(truth, cal.rotation).T @ _turn_ideal_to_rail(truth)
           @ np.asarray(truth["rotation_camera_to_ideal"], float))
    return CalParams(rot[None], normals, offsets, reference_coeffs(r_o, t_o)[None], np.ones(1))
