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
from impress_gui.core.measure.uncertainty import UncertaintyContext, fusion_weights_for
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


def test_weights_follow_each_lasers_height_per_pixel(flat_calibration):
    cal = SceneCalibration.load(flat_calibration)
    size = tuple(cal.intrinsics.image_size)
    s = height_per_pixel(cal, size)
    # the flat preset: both lasers at moderate angles, a fraction of a millimetre per row
    assert all(0.05 < v < 2.0 for v in s.values()), s
    wg = fusion_weight(cal, size)
    assert wg == pytest.approx(s["red"] ** 2 / (s["green"] ** 2 + s["red"] ** 2))
    # the laser with fewer mm per row weighs more
    assert (wg > 0.5) == (s["green"] < s["red"])
    # a laser plane turned towards the camera's rays (a shallower triangulation angle) means
    # more height per row, and loses weight
    steeper = _turned(cal, "green", 6.0)
    s2 = height_per_pixel(steeper, size)
    assert s2["green"] != pytest.approx(s["green"], rel=0.05)
    assert (fusion_weight(steeper, size) > wg) == (s2["green"] < s["green"])


def _turned(cal, name, deg):
    """``cal`` with one laser plane turned by ``deg`` about the camera's x axis through its
    stripe on the reference surface (the same line on the ground, another angle)."""
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
    stats = data.metadata["stats"]
    assert stats["fusion_weights"]["green"] == pytest.approx(wg, abs=1e-6)
    assert stats["fusion_weights"]["red"] == pytest.approx(1 - wg, abs=1e-6)
    c = data.layers["contribution"] == 3
    g, r, f = (data.layers[k][c].astype(np.float64) for k in ("green", "red", "fused"))
    assert c.sum() > 1000
    assert np.abs(f - (wg * g + (1 - wg) * r)).max() < 1e-4
    # the uncertainty budget moves such a cell with the same weights
    ctx = UncertaintyContext.for_calibration(data.height_mm, data.spec, cal, None,
                                             data.layers["contribution"])
    assert ctx.fusion_weights == fusion_weights_for(cal)
    i, j = np.argwhere(c)[0]
    x = data.spec.x0_mm + j * data.spec.pixel_mm
    y = data.spec.y0_mm + i * data.spec.pixel_mm
    assert dict(ctx.lasers_at(x, y)) == pytest.approx({"green": wg, "red": 1 - wg})
