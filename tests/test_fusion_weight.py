"""Where both lasers agree, the fused height weights each by how much height one pixel of
stripe shift means for it (issue 18, random rig 14: green's light plane meets the camera's rays
at 14 deg, red's at 35 deg; one row of detector noise is 1.67 mm of height for green and 0.67 mm
for red, and the plain mean let green's noise through: fused MAE 0.090 -> 0.085 mm at 640x360,
0.066 -> 0.057 mm at 1920x1080 measured offline with these weights)."""

from __future__ import annotations

import numpy as np
import pytest

from impress_gui.core.calibration.scene import SceneCalibration
from impress_gui.core.measure.readings import load_reconstruction
from impress_gui.core.measure.uncertainty import UncertaintyContext, fusion_weights_of
from impress_gui.core.reconstruction.grid import fuse
from impress_gui.core.reconstruction.reconstruct import fusion_weight, height_per_pixel


def test_agreeing_pairs_take_the_weighted_mean():
    g = np.array([[1.0, 2.0, np.nan, 5.0]], np.float32)
    r = np.array([[1.2, 3.0, 4.0, np.nan]], np.float32)
    fused, _, contrib = fuse(g, r, 0.5, weight_green=0.2)
    assert contrib[0, 0] == 3 and fused[0, 0] == pytest.approx(0.2 * 1.0 + 0.8 * 1.2, abs=1e-6)
    assert contrib[0, 1] == 4  # a conflict is decided as before, not weighted
    assert fused[0, 2] == 4.0 and fused[0, 3] == 5.0  # single lasers keep their heights
    plain, _, _ = fuse(g, r, 0.5)
    assert plain[0, 0] == pytest.approx(1.1, abs=1e-6)


def _triangulated_height_per_row(cal, name, u):
    """mm of height per image row at column ``u`` where the stripe lies on the reference
    surface: OpenCV's undistortion and a plain ray-plane intersection (not the product's
    projection code)."""
    import cv2

    w, h = cal.intrinsics.image_size
    plane = cal.planes[name].plane
    k = np.asarray(cal.intrinsics.camera_matrix, float)
    dist = np.asarray(cal.intrinsics.dist_coeffs, float)
    v = np.arange(0.0, h, 0.25)
    pts = np.column_stack([np.full_like(v, u), v]).reshape(-1, 1, 2)
    xn = cv2.undistortPoints(pts, k, dist).reshape(-1, 2)
    rays = np.column_stack([xn, np.ones(len(v))]) @ np.asarray(cal.rotation).T  # ideal frame
    t = plane.offset_mm / (rays @ plane.normal)
    p = rays * t[:, None]
    height = cal.reference_depth(p[:, 0], p[:, 1]) - p[:, 2]
    i = int(np.argmin(np.abs(height)))
    return abs(height[i + 4] - height[i - 4]) / 2.0  # over +-1 row


def test_height_per_pixel_matches_a_direct_triangulation(flat_calibration):
    cal = SceneCalibration.load(flat_calibration)
    size = tuple(cal.intrinsics.image_size)
    s = height_per_pixel(cal, size)
    for name in ("green", "red"):
        # the flat preset's stripes run nearly along the rows and the sensitivity hardly
        # changes across the picture: the centre column's is the median's within 3 %
        direct = _triangulated_height_per_row(cal, name, size[0] / 2)
        assert s[name] == pytest.approx(direct, rel=0.03), (name, s[name], direct)
    wg = fusion_weight(cal, size)
    assert wg == pytest.approx(s["red"] ** 2 / (s["green"] ** 2 + s["red"] ** 2))


def test_a_shallower_laser_weighs_less(flat_calibration):
    """A laser plane turned towards the camera's rays (a smaller triangulation angle; the same
    stripe on the reference surface) means more height per row, and its weight falls."""
    cal = SceneCalibration.load(flat_calibration)
    size = tuple(cal.intrinsics.image_size)
    s, wg = height_per_pixel(cal, size), fusion_weight(cal, size)
    for deg in (-8.0, 8.0):
        turned = _turned(cal, "green", deg)
        s2 = height_per_pixel(turned, size)
        angle0 = _triangulation_angle(cal, "green")
        angle2 = _triangulation_angle(turned, "green")
        if angle2 < angle0 - 1.0:  # shallower
            assert s2["green"] > 1.1 * s["green"] and fusion_weight(turned, size) < wg - 0.02
        elif angle2 > angle0 + 1.0:  # steeper
            assert s2["green"] < s["green"] / 1.1 and fusion_weight(turned, size) > wg + 0.02
        else:
            pytest.fail(f"turning by {deg} deg changed the angle by {angle2 - angle0:.2f} deg")


def _triangulation_angle(cal, name):
    """Degrees between the laser plane and the camera's optical axis (0: the plane seen
    edge-on, no triangulation)."""
    plane = cal.planes[name].plane
    ray = np.asarray(cal.rotation) @ np.array([0.0, 0.0, 1.0])
    return float(np.degrees(np.arcsin(abs(ray @ plane.normal) / np.linalg.norm(ray))))


def _turned(cal, name, deg):
    """``cal`` with one laser plane turned by ``deg`` about the ideal frame's x axis through
    its stripe on the reference surface below the camera (the same stripe line there,
    another angle)."""
    import dataclasses

    from impress_gui.core.calibration.geometry import Plane

    fit = cal.planes[name]
    n, d = fit.plane.normal, fit.plane.offset_mm
    z = float(cal.reference_depth(np.array(0.0), np.array(0.0)))
    p0 = np.array([0.0, (d - n[2] * z) / n[1], z])  # on the plane at the reference depth
    a = np.radians(deg)
    rot = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    n2 = rot @ n
    plane = Plane(n2, float(n2 @ p0))
    planes = dict(cal.planes)
    planes[name] = dataclasses.replace(fit, plane=plane)
    return dataclasses.replace(cal, planes=planes)


def test_the_reconstruction_fuses_and_records_with_these_weights(flat_recon, flat_calibration):
    data = load_reconstruction(flat_recon)
    cal = SceneCalibration.load(flat_calibration)
    wg = fusion_weight(cal, tuple(cal.intrinsics.image_size))
    assert abs(wg - 0.5) > 0.005  # else the check below could not tell the weights apart
    recorded = fusion_weights_of(data.metadata)
    assert recorded == pytest.approx({"green": wg, "red": 1 - wg}, abs=1e-6)
    c = data.layers["contribution"] == 3
    g, r, f = (data.layers[k][c].astype(np.float64) for k in ("green", "red", "fused"))
    assert c.sum() > 1000
    assert np.abs(f - (wg * g + (1 - wg) * r)).max() < 1e-4
    assert np.abs(f - 0.5 * (g + r)).max() > 1e-3  # ... which is not the plain mean
    # the record says how much of the map each laser made alone, and each laser's precision
    stats = data.metadata["stats"]
    fused = np.isfinite(data.layers["fused"])
    for code, name in ((1, "green"), (2, "red")):
        alone = fused & (data.layers["contribution"] == code)
        assert stats["cells_one_laser"][name] == int(alone.sum())
        assert np.isfinite(data.layers[name][alone]).all()
    assert 0 < sum(stats["cells_one_laser"].values()) < int(fused.sum())
    assert stats["height_per_stripe_pixel_mm"] == pytest.approx(
        height_per_pixel(cal, tuple(cal.intrinsics.image_size)), abs=1e-4)
    # the uncertainty budget moves such a cell with the recorded weights
    ctx = UncertaintyContext.for_calibration(data.height_mm, data.spec, cal, None,
                                             data.layers["contribution"],
                                             fusion_weights=recorded)
    i, j = np.argwhere(c)[0]
    x = data.spec.x0_mm + j * data.spec.pixel_mm
    y = data.spec.y0_mm + i * data.spec.pixel_mm
    assert dict(ctx.lasers_at(x, y)) == pytest.approx({"green": wg, "red": 1 - wg})
    # a result made before the weights were recorded was fused half and half
    old = {k: v for k, v in data.metadata.items() if k != "stats"}
    assert fusion_weights_of(old) is None
    ctx.fusion_weights = fusion_weights_of(old)
    assert dict(ctx.lasers_at(x, y)) == pytest.approx({"green": 0.5, "red": 0.5})
