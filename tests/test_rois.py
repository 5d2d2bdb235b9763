"""The automatic search bands keep each laser's whole stripe, also when the camera is rolled.

The automatic regions of interest (reconstruct.laser_rois) used to split two overlapping row
bands at one row; a stripe that runs across the image (a rolled camera) crosses every row, so
the cut lost part of one laser's stripe in every frame (random rig 8 at 640x360: the red
stripe's left 80 columns, 2 % of the map). The flat preset's calibration is turned about the
optical axis here, which tilts both stripes in the image as a rolled camera does. Where the
cut crosses neither stripe on the ground it is kept (random rig 23: without it the red detector
took parts of a green stripe blooming on warm soil).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from impress_gui.core.calibration.scene import SceneCalibration
from impress_gui.core.reconstruction.reconstruct import column_bands, laser_rois
from impress_gui.core.reconstruction.stripes import LASERS

HEIGHT_RANGE = (-40.0, 60.0)


def rolled(cal: SceneCalibration, deg: float) -> SceneCalibration:
    a = np.radians(deg)
    turn = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    return dataclasses.replace(cal, rotation=cal.rotation @ turn)


def stripe_pixels(cal: SceneCalibration, name: str, height_mm: float) -> np.ndarray:
    """Image points of the laser's line on a level surface ``height_mm`` above the reference
    (the plane cut at that depth, projected), inside the image."""
    w, h = cal.intrinsics.image_size
    z = float(cal.reference_depth(np.array(0.0), np.array(0.0))) - height_mm
    xs = np.linspace(-1.2 * z * w / cal.intrinsics.fx, 1.2 * z * w / cal.intrinsics.fx, 4001)
    plane = cal.planes[name].plane
    n, d = plane.normal, plane.offset_mm
    ys = (d - n[0] * xs - n[2] * z) / n[1]
    uv = cal.intrinsics.project(np.column_stack([xs, ys, np.full_like(xs, z)]) @ cal.rotation)
    ok = (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
    return uv[ok]


@pytest.mark.parametrize("roll_deg", [0.0, 15.0, 25.0])
def test_every_stripe_pixel_within_the_height_range_is_searched(flat_calibration, roll_deg):
    cal = rolled(SceneCalibration.load(flat_calibration), roll_deg)
    size = cal.intrinsics.image_size
    rois = laser_rois(cal, size, HEIGHT_RANGE)
    bands = column_bands(cal, size, HEIGHT_RANGE, rois)
    for name in LASERS:
        start, height = bands[name]
        for h_mm in (-30.0, -10.0, 0.0, 10.0, 30.0, 50.0):
            uv = stripe_pixels(cal, name, h_mm)
            assert len(uv) > 100
            cols = np.rint(uv[:, 0]).astype(int)
            inside = (uv[:, 1] >= start[cols]) & (uv[:, 1] < start[cols] + height)
            assert inside.all(), (name, h_mm, int((~inside).sum()), len(uv), rois)



def test_overlapping_bands_are_split_where_the_cut_crosses_no_stripe(flat_calibration):
    """The flat preset, not rolled: the two bands overlap over the height range, the cut
    halfway through the overlap lies between the two stripes on the ground, so it is kept."""
    cal = SceneCalibration.load(flat_calibration)
    size = cal.intrinsics.image_size
    rois = laser_rois(cal, size, HEIGHT_RANGE)
    (g0, g1), (r0, r1) = rois["green"], rois["red"]
    assert g1 == r0 or r1 == g0, rois  # split at one row
    for name, other in (("green", "red"), ("red", "green")):
        a, b = rois[name]
        theirs = stripe_pixels(cal, other, 0.0)[:, 1]
        assert not ((theirs >= a) & (theirs < b)).any(), (name, rois)
        own = stripe_pixels(cal, name, 0.0)[:, 1]
        assert ((own >= a) & (own < b)).all(), (name, rois)
