"""The laser plane's robust fit (core.calibration.planes.fit_laser_plane) against a known plane."""

from __future__ import annotations

import numpy as np

from impress_gui.core.calibration.planes import fit_laser_plane, frame_groups


def _stripes(rng, wrong_frames: int):
    """A laser plane's stripe on a low and a high face over 42 frames, as a calibration sees
    it: more points on the high face than on the low one, 0.005 mm of noise along the plane's
    normal; in the first ``wrong_frames`` frames the few low-face points are another light's,
    49.5 mm off the plane (random rig 15's red stripe at 1080p)."""
    n = np.array([0.0, 1.0, -0.4])
    n /= np.linalg.norm(n)
    a = np.array([1.0, 0.0, 0.0])  # along the stripe
    b = np.cross(n, a)  # in the plane, across the faces
    p0 = 250.0 * np.array([0.0, 0.4, 1.0]) / np.linalg.norm([0.0, 0.4, 1.0])
    pts, hts = [], []
    for k in range(42):
        wrong = k < wrong_frames
        n_hi, n_lo = (90, 20) if wrong else (256, 187)
        hi = p0 + rng.uniform(-40, 40, n_hi)[:, None] * a
        lo = p0 + rng.uniform(-30, 30, n_lo)[:, None] * a + 10.4 * b
        if wrong:
            lo = lo + 49.5 * n
        p = np.concatenate([hi, lo])
        p = p + rng.normal(0.0, 0.005, len(p))[:, None] * n
        pts.append(p)
        hts.append(np.concatenate([np.full(n_hi, 21.355), np.full(n_lo, 10.936)]))
    return n, float(p0 @ n), pts, hts


def test_a_few_frames_of_another_light_on_the_smaller_face_do_not_turn_the_plane():
    rng = np.random.default_rng(15)
    n, d, pts, hts = _stripes(rng, 3)
    fit = fit_laser_plane("red", np.concatenate(pts), np.concatenate(hts), list(range(42)),
                          groups=frame_groups(pts))
    cos = abs(float(fit.plane.normal @ n))
    angle = np.degrees(np.arccos(min(1.0, cos)))
    assert angle < 0.01, angle
    # every good point kept: 39 frames x 443, the wrong frames' 3 x 90 high-face points
    assert fit.n_points >= 0.99 * (39 * 443 + 3 * 90)
    assert fit.rms_mm < 0.01


def test_without_the_other_light_the_plane_is_the_same():
    rng = np.random.default_rng(15)
    n, _, pts, hts = _stripes(rng, 0)
    fit = fit_laser_plane("red", np.concatenate(pts), np.concatenate(hts), list(range(42)),
                          groups=frame_groups(pts))
    assert np.degrees(np.arccos(min(1.0, abs(float(fit.plane.normal @ n))))) < 0.01
    assert fit.n_points >= 0.99 * 42 * 443


def test_the_command_fits_as_many_frames_per_plane_as_the_window():
    """``impress calibrate``'s --plane-frames default is the calibration's own (the window's)."""
    from impress_gui.cli import build_parser
    from impress_gui.core.calibration.scene import DEFAULT_PLANE_FRAMES

    args = build_parser("calibrate").parse_args(
        ["calibrate", "scan.mp4", "--intrinsics", "i.json", "--picks", "p.json",
         "--speed", "13", "-o", "cal.json"])
    assert args.plane_frames == DEFAULT_PLANE_FRAMES


class _Observed:
    """Stripe points given per frame, as StripeObservations.points returns them."""

    def __init__(self, name, pts, hts):
        self.rays = {name: pts}
        self._p = (pts, hts, list(range(len(pts))))

    def points(self, name, rot, pose_rt):
        return self._p


def test_a_plane_that_most_points_on_a_face_do_not_lie_on_is_warned_of():
    """The plane the fit chose before its start was judged face by face (through the high
    face's line and three frames' wrong light) warns; the right plane does not."""
    from impress_gui.core.calibration.geometry import Plane
    from impress_gui.core.calibration.planes import LaserPlaneFit
    from impress_gui.core.calibration.scene import face_agreement_warnings

    rng = np.random.default_rng(15)
    _, _, pts, hts = _stripes(rng, 3)
    obs = _Observed("red", pts, hts)
    right = fit_laser_plane("red", np.concatenate(pts), np.concatenate(hts), list(range(42)),
                            groups=frame_groups(pts))
    assert face_agreement_warnings(obs, {"red": right}, np.eye(3), None) == []
    # the plane through the wrong frames' points alone (their high face and the other light)
    wrong_pts = np.concatenate(pts[:3])
    c = wrong_pts.mean(0)
    normal = np.linalg.svd(wrong_pts - c)[2][2]
    wrong = LaserPlaneFit("red", Plane(normal, float(normal @ c)), 0.005, len(wrong_pts),
                          tuple(range(42)), (10.936, 21.355))
    msgs = face_agreement_warnings(obs, {"red": wrong}, np.eye(3), None)
    assert len(msgs) == 1 and "face at 10.9 mm" in msgs[0], msgs
    # only the frames the fit kept are judged: the three wrong frames alone lie on it
    kept_three = LaserPlaneFit("red", wrong.plane, 0.005, len(wrong_pts), (0, 1, 2),
                               (10.936, 21.355))
    assert face_agreement_warnings(obs, {"red": kept_three}, np.eye(3), None) == []


def test_the_median_leaving_out_one_group_equals_the_masked_median():
    """planes._median_excluding: each column's median of the rows outside its group, the
    groups' rows in any order (even counts left out: exact; odd: within half a rank)."""
    from impress_gui.core.calibration.planes import _median_excluding

    rng = np.random.default_rng(3)
    for _ in range(50):
        n = int(rng.integers(20, 200))
        group = rng.integers(0, 6, n)  # interleaved, not consecutive
        cols = np.unique(group)
        dist = rng.random((n, len(cols)))
        others = group[:, None] != cols[None, :]
        got = _median_excluding(dist, others, group)
        for c in range(len(cols)):
            kept = np.sort(dist[others[:, c], c])
            if (~others[:, c]).sum() % 2 == 0:
                assert np.isclose(got[c], np.median(kept))
            else:  # half a rank off: within the median's neighbours
                m = len(kept)
                lo, hi = kept[max((m - 1) // 2 - 1, 0)], kept[min(m // 2 + 1, m - 1)]
                assert lo - 1e-12 <= got[c] <= hi + 1e-12
