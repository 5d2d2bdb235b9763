"""A barrel lens folds rays from far outside the view back into the picture: the rows where a
laser's line falls, projected from the calibration, must leave those points out (issue 18,
random rig 65: the ground's rows up to 135 rows off in its edge columns)."""

from dataclasses import replace

import numpy as np
import pytest

from impress_gui.core.calibration.geometry import Intrinsics
from impress_gui.core.calibration.scene import SceneCalibration
from impress_gui.core.reconstruction import reconstruct as R


def _barrel(intr: Intrinsics, k1: float, focal: float | None = None) -> Intrinsics:
    """``intr`` with radial distortion ``k1`` alone (and the focal length ``focal`` times the
    picture's width, when given)."""
    d = np.zeros(5)
    d[0] = k1
    k = intr.camera_matrix.copy()
    if focal is not None:
        k[0, 0] = k[1, 1] = focal * intr.image_size[0]
    return replace(intr, camera_matrix=k, dist_coeffs=d)


def test_the_fold_radius_is_where_the_radial_projection_turns_back():
    k = np.array([[1000.0, 0, 320], [0, 1000.0, 180], [0, 0, 1]])
    intr = Intrinsics(k, np.zeros(5), (640, 360))
    assert intr.fold_radius() == np.inf
    # r (1 + k1 r^2) stops growing at r = 1 / sqrt(-3 k1)
    for k1 in (-0.25, -0.1):
        assert _barrel(intr, k1).fold_radius() == pytest.approx(1 / np.sqrt(-3 * k1), abs=2e-4)
    assert _barrel(intr, 0.08).fold_radius() == np.inf


def _rows_from_rays(cal: SceneCalibration, name: str, w: int, h: int, height_mm: float):
    """Each column's row of the laser's line on a level surface, found the other way round:
    the pixel rays of the column (undistorted by iteration, which gives the ray inside the
    view) met with that surface, the row where the point lies on the laser's plane."""
    z = float(cal.reference_depth(np.array(0.0), np.array(0.0))) - height_mm
    plane = cal.planes[name].plane
    vs = np.arange(0.0, h, 0.1)
    out = np.full(w, np.nan)
    for u in range(0, w, 7):
        rays = cal.intrinsics.rays(np.column_stack([np.full_like(vs, u), vs]))
        ideal = rays @ cal.rotation.T
        pts = ideal * (z / ideal[:, 2])[:, None]
        f = pts @ plane.normal - plane.offset_mm
        k = np.flatnonzero(np.sign(f[:-1]) != np.sign(f[1:]))
        if len(k) == 1:
            a = k[0]
            out[u] = vs[a] + 0.1 * f[a] / (f[a] - f[a + 1])
    return out


def test_a_lines_rows_leave_out_what_a_barrel_lens_folds_in(flat_calibration, monkeypatch):
    cal = SceneCalibration.load(flat_calibration)
    w, h = cal.intrinsics.image_size
    # a wide view (1440 px at 1920) through a strong barrel lens: the line's points past the
    # fold radius land 14-37 rows off the real ones in part of the picture
    cal = replace(cal, intrinsics=_barrel(cal.intrinsics, -0.25, focal=0.75))
    for name in ("green", "red"):
        truth = _rows_from_rays(cal, name, w, h, 0.0)
        seen = np.isfinite(truth)
        assert seen.sum() > 60
        rows = R.ground_rows(cal, (w, h))[name]
        assert np.max(np.abs(rows[seen] - truth[seen])) < 0.05
        # the same rows with the folded points mixed in, as before 2026-12-06
        monkeypatch.setattr(R, "LENS_FOLD", False)
        old = R.ground_rows(cal, (w, h))[name]
        monkeypatch.setattr(R, "LENS_FOLD", True)
        assert np.max(np.abs(old[seen] - truth[seen])) > 5


def _rolled(cal: SceneCalibration, deg: float) -> SceneCalibration:
    """``cal`` with its camera turned by ``deg`` about its optical axis: the stripes run
    slanted across the picture."""
    t = np.radians(deg)
    rz = np.array([[np.cos(t), -np.sin(t), 0.0], [np.sin(t), np.cos(t), 0.0], [0.0, 0.0, 1.0]])
    return replace(cal, rotation=cal.rotation @ rz.T)


def test_the_regions_of_interest_hold_a_slanted_stripe_to_the_pictures_edge(
        flat_calibration, monkeypatch):
    """Each laser's rows of interest reach 8 rows past every column's row of its line on
    surfaces at the ends of the height range; from points sampled 20 columns apart a stripe
    slanted at 30 deg lost up to 12 rows at the picture's edge."""
    from impress_gui.core.reconstruction.reconstruct import ProcessParams

    cal = _rolled(SceneCalibration.load(flat_calibration), 30.0)
    w, h = cal.intrinsics.image_size
    hr = ProcessParams().height_range_mm

    def short_of_margin(name: str) -> float:
        a, b = R._roi_rows(cal, (w, h), name, hr)
        rows = np.concatenate([_rows_from_rays(cal, name, w, h, hgt) for hgt in hr])
        rows = rows[np.isfinite(rows)]
        assert len(rows) > 60
        # rows the picture holds must lie 8 rows inside the region (or it reaches the edge)
        return max(0.0 if a == 0 else (a + 8) - rows.min(),
                   0.0 if b == h else rows.max() - (b - 9))

    for name in ("green", "red"):
        assert short_of_margin(name) <= 1e-6
    monkeypatch.setattr(R, "ROWS_DENSE", False)
    assert max(short_of_margin(n) for n in ("green", "red")) > 3


def test_the_cut_between_two_bands_keeps_clear_of_either_stripe_on_the_ground(
        flat_calibration, monkeypatch):
    """Where the two lasers' bands overlap they are cut apart only where the cut keeps
    ``CUT_CLEAR_PX`` rows clear of both stripes on the ground (found here from the pixel
    rays): as the camera rolls from 14 to 19 deg the cut nears the stripes' ends; from
    sampled points it cut 0.6 rows inside one at 17.5 deg."""
    cal0 = SceneCalibration.load(flat_calibration)
    w, h = cal0.intrinsics.image_size
    from impress_gui.core.reconstruction.reconstruct import ProcessParams

    hr = ProcessParams().height_range_mm

    def closest_cut() -> float:
        out = np.inf
        for deg in np.arange(14.0, 19.01, 0.5):
            cal = _rolled(cal0, float(deg))
            rois = R.laser_rois(cal, (w, h), hr)
            (a0, a1), (b0, b1) = rois["green"], rois["red"]
            if a0 < b1 and b0 < a1:
                continue  # left overlapping: no cut
            cut = a1 if a1 == b0 else a0
            for name in ("green", "red"):
                rows = _rows_from_rays(cal, name, w, h, 0.0)
                rows = rows[np.isfinite(rows)]
                lo, hi = rows.min(), rows.max()
                out = min(out, 0.0 if lo <= cut <= hi else min(abs(cut - lo), abs(cut - hi)))
        return out

    assert closest_cut() >= R.CUT_CLEAR_PX - 0.5  # the dense rows of the line are exact to 0.5
    monkeypatch.setattr(R, "ROWS_DENSE", False)
    assert closest_cut() == 0.0
