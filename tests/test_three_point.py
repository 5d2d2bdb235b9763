"""The seed's three-point laser planes from explicit stripe picks (``impress calibrate --planes
three-point``), the picks' ``stripe_points`` field, the undetermined-plane error of the stripe
fit, and the proposed calibration frames - all against the simulator's ground truth."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from impress_gui.core.base.errors import CalibrationError, FormatError, ImpressError
from impress_gui.core.calibration.geometry import Intrinsics, Plane
from impress_gui.core.calibration.picks import LMN_EDGES, Picks, StripePoint, StripePoints
from impress_gui.core.calibration.planes import StripeObservations, fit_laser_plane
from impress_gui.core.calibration.scene import SceneCalibration, calibrate_scene
from impress_gui.core.calibration.target import default_target
from impress_gui.core.formats.video import open_video

# three exact stripe points, the pose from the corner picks alone (no tilt refinement by the
# stripes): measured on the flat scan 0.0xx deg and 0.0xx mm; stated with a margin
NORMAL_TOL_DEG = 0.1
OFFSET_TOL_MM = 0.3


def _truth(scan) -> dict:
    return json.loads((scan / "truth.json").read_text())


def _edge_hits(truth: dict, laser: str, frame: int, edges=LMN_EDGES):
    """Where the true laser plane crosses each target edge in ``frame``: the point's position
    along the edge (0..1) and its distorted pixel, from the simulator's truth."""
    intr = Intrinsics.from_json(truth["_intrinsics"])
    rot = np.array(truth["rotation_camera_to_ideal"])
    plane = Plane.from_json(truth["lasers"][laser]["plane"], laser)
    corners = {c: np.array(v) - [0.0, truth["travel_mm"][frame], 0.0]
               for c, v in truth["target"]["corners_rail_mm"].items()}
    lam, uv = [], []
    for a, b in ((corners[e[0]], corners[e[1]]) for e in edges):
        s = (plane.offset_mm - plane.normal @ a) / (plane.normal @ (b - a))
        lam.append(float(s))
        uv.append(intr.project((a + s * (b - a)) @ rot))
    return np.array(lam), np.array(uv)


def _with_truth_intrinsics(scan) -> dict:
    """truth.json with the simulator's (exact) intrinsics added as ``_intrinsics``."""
    t = _truth(scan)
    t["_intrinsics"] = json.loads((scan / "intrinsics.json").read_text())
    return t


def _stripe_picks(scan) -> Picks:
    """The scan's corner picks plus the exact L, M, N of each laser in its calibration frame."""
    truth = _with_truth_intrinsics(scan)
    picks = Picks.load(scan / "picks.json")
    sp = {}
    for laser, frame in (("green", picks.t1), ("red", picks.t2)):
        lam, uv = _edge_hits(truth, laser, frame)
        assert np.all((lam > 0.05) & (lam < 0.95)), (laser, lam)  # the stripe crosses each edge
        sp[laser] = StripePoints(frame, tuple(StripePoint(e, (float(u), float(v)))
                                              for e, (u, v) in zip(LMN_EDGES, uv)))
    return Picks(picks.video, picks.t1, picks.t2, picks.corners_t1, picks.corners_t2,
                 picks.video_sha256, picks.note, stripe_points=sp)


# ----- the picks format ---------------------------------------------------------------------------
def test_stripe_points_round_trip_and_old_files_still_read(flat_scan, tmp_path):
    old = json.loads((flat_scan / "picks.json").read_text())
    assert "stripe_points" not in old  # files without the field are written as before
    assert Picks.load(flat_scan / "picks.json").stripe_points == {}
    picks = _stripe_picks(flat_scan)
    doc = picks.to_json()
    assert doc["version"] == 1 and set(doc["stripe_points"]) == {"green", "red"}
    assert [p["edge"] for p in doc["stripe_points"]["green"]["points"]] == list(LMN_EDGES)
    p = tmp_path / "picks.json"
    picks.save(p)
    back = Picks.load(p)
    assert back.stripe_points == picks.stripe_points
    assert back.to_json() == doc
    # one laser only is a valid file (the check for both is the calibration's)
    doc1 = json.loads(json.dumps(doc))
    del doc1["stripe_points"]["red"]
    assert set(Picks.from_json(doc1).stripe_points) == {"green"}


@pytest.mark.parametrize("change, message", [
    (lambda sp: sp.update(blue=sp["green"]), "unknown lasers"),
    (lambda sp: sp["green"]["points"].pop(), "three points"),
    (lambda sp: sp["green"]["points"][0].update(edge="AX"), "edge"),
    (lambda sp: sp["green"]["points"][0].update(edge="AA"), "edge"),
    (lambda sp: sp["green"]["points"][1].update(edge="BA"), "three different edges"),
    (lambda sp: sp["green"]["points"][2].update(px=[1.0]), r"\[x, y\]"),
    (lambda sp: sp["green"].update(frame=-1), "negative"),
    (lambda sp: sp["green"].pop("frame"), "frame"),
    (lambda sp: sp.update(red=[1, 2]), "object"),
])
def test_bad_stripe_points_are_refused(flat_scan, change, message):
    doc = _stripe_picks(flat_scan).to_json()
    change(doc["stripe_points"])
    with pytest.raises(FormatError, match=message):
        Picks.from_json(doc, "picks.json: ")


def test_hostile_stripe_points_give_clean_errors(flat_scan, tmp_path):
    good = _stripe_picks(flat_scan).to_json()
    hostile = [None, True, -1, 1e300, "x", "", [], {}, [1, 2, 3], {"a": 1}, [[1, 2]] * 3]
    p = tmp_path / "p.json"

    def leaves(d, path=()):
        yield path
        if isinstance(d, dict):
            for k, v in d.items():
                yield from leaves(v, (*path, k))
        elif isinstance(d, list):
            for i, v in enumerate(d):
                yield from leaves(v, (*path, i))

    n = 0
    for path in leaves(good["stripe_points"], ("stripe_points",)):
        for value in hostile:
            doc = json.loads(json.dumps(good))
            cur = doc
            for k in path[:-1]:
                cur = cur[k]
            cur[path[-1]] = value
            p.write_text(json.dumps(doc))
            try:
                Picks.load(p)
            except ImpressError as exc:
                assert exc.code.startswith("E-") and str(p) in str(exc)
            n += 1
    assert n > 100


# ----- three-point planes against the truth -----------------------------------------------------
def test_three_point_planes_match_the_truth(flat_scan, flat_calibration):
    truth = _truth(flat_scan)
    picks = _stripe_picks(flat_scan)
    with open_video(flat_scan / "scan.mp4") as v:
        cal = calibrate_scene(v, Intrinsics.load(flat_scan / "intrinsics.json"),
                              default_target(), picks, truth["speed_mm_s"],
                              plane_method="three-point")
    fitted = SceneCalibration.load(flat_calibration)  # the default stripe fit, for comparison
    for laser in ("green", "red"):
        f = cal.planes[laser]
        true_plane = Plane.from_json(truth["lasers"][laser]["plane"], laser).oriented_like(f.plane)
        angle = f.plane.angle_to_deg(true_plane)
        offset = abs(f.plane.offset_mm - true_plane.offset_mm)
        print(f"{laser}: three-point {angle:.4f} deg, {offset:.4f} mm; stripe fit "
              f"{fitted.planes[laser].plane.angle_to_deg(true_plane):.4f} deg, "
              f"{abs(fitted.planes[laser].plane.offset_mm - true_plane.offset_mm):.4f} mm")
        assert angle < NORMAL_TOL_DEG and offset < OFFSET_TOL_MM
        assert f.method == "three-point" and f.n_points == 3
        assert f.frames == ((picks.t1,) if laser == "green" else (picks.t2,))
        assert len(f.heights_mm) == 2 and f.rms_mm < 0.1  # exact picks: rays meet their edges
    assert any("three-point" in w for w in cal.warnings)
    # the corner part is the same as without stripes (no tilt refinement)
    assert abs(cal.roll_deg - truth["roll_deg"]) < 0.05


def test_three_point_cli(flat_scan, tmp_path):
    picks_path = tmp_path / "picks.json"
    _stripe_picks(flat_scan).save(picks_path)
    base = [sys.executable, "-m", "impress_gui", "calibrate", str(flat_scan / "scan.mp4"),
            "--intrinsics", str(flat_scan / "intrinsics.json"), "--speed", "fast",
            "--planes", "three-point"]
    out = tmp_path / "cal.json"
    res = subprocess.run([*base, "--picks", str(picks_path), "-o", str(out)],
                         capture_output=True, text=True)
    assert res.returncode == 0, res.stderr
    assert "three points (L, M, N)" in res.stdout
    doc = json.loads(out.read_text())
    assert {p["method"] for p in doc["laser_planes"].values()} == {"three-point"}
    assert any("three-point" in w for w in doc["warnings"])
    # picks without stripe points: a clear error with its code, nothing written
    bad = subprocess.run([*base, "--picks", str(flat_scan / "picks.json"), "-o",
                          str(tmp_path / "x.json")], capture_output=True, text=True)
    assert bad.returncode == 2 and "[E-PICKS-STRIPE]" in bad.stderr
    assert "green and red" in bad.stderr
    assert not (tmp_path / "x.json").exists()


def test_three_point_refuses_bad_stripe_points(flat_scan):
    truth = _with_truth_intrinsics(flat_scan)
    picks = _stripe_picks(flat_scan)
    intr = Intrinsics.load(flat_scan / "intrinsics.json")

    def run(sp):
        p = Picks(picks.video, picks.t1, picks.t2, picks.corners_t1, picks.corners_t2,
                  stripe_points=sp)
        with open_video(flat_scan / "scan.mp4") as v:
            calibrate_scene(v, intr, default_target(), p, truth["speed_mm_s"],
                            plane_method="three-point")

    green, red = picks.stripe_points["green"], picks.stripe_points["red"]
    with pytest.raises(CalibrationError, match="no stripe points .* red") as err:
        run({"green": green})
    assert err.value.code == "E-PICKS-STRIPE"
    with pytest.raises(CalibrationError, match="outside the video") as err:
        run({"green": green, "red": StripePoints(10**6, red.points)})
    assert err.value.code == "E-FRAME-RANGE"
    off = StripePoint("AB", (-50.0, 10.0))
    with pytest.raises(CalibrationError, match="outside the 640x360") as err:
        run({"green": StripePoints(green.frame, (off, *green.points[1:])), "red": red})
    assert err.value.code == "E-PICKS"
    # points named on the wrong edge: M on C-D (the high face's back edge), L on E-F
    wrong = StripePoint("CD", green.points[1].uv_px)
    with pytest.raises(CalibrationError, match=r"M is \d+\.\d px off target edge C-D") as err:
        run({"green": StripePoints(green.frame, (green.points[0], wrong, green.points[2])),
             "red": red})
    assert err.value.code == "E-PICKS"
    wrong = StripePoint("EF", green.points[0].uv_px)
    with pytest.raises(CalibrationError, match="L is beyond the ends of target edge E-F") as err:
        run({"green": StripePoints(green.frame, (wrong, *green.points[1:])), "red": red})
    assert err.value.code == "E-PICKS"
    # three points at one height (the high face's edges F-C, E-D and E-F): no plane
    lam, uv = _edge_hits(truth, "green", green.frame, ("FC", "ED"))
    pts = truth["target"]["corners_rail_mm"]
    mid = (np.array(pts["E"]) + pts["F"]) / 2 - [0.0, truth["travel_mm"][green.frame], 0.0]
    uv_ef = intr.project(mid @ np.array(truth["rotation_camera_to_ideal"]))
    flat = StripePoints(green.frame, (StripePoint("FC", tuple(uv[0])),
                                      StripePoint("ED", tuple(uv[1])),
                                      StripePoint("EF", tuple(uv_ef))))
    with pytest.raises(CalibrationError, match="one height") as err:
        run({"green": flat, "red": red})
    assert err.value.code == "E-PLANE-UNDETERMINED"
    with pytest.raises(CalibrationError, match="unknown laser plane method"):
        calibrate_scene(None, intr, default_target(), picks, 13.0, plane_method="svd")


# ----- the stripe fit's undetermined plane ---------------------------------------------------------
def _face_rays(cal: SceneCalibration, faces: list[tuple[float, float, float]], y_mm=30.0):
    """Camera-frame rays towards points across the target's faces at ``y_mm`` along it (object
    frame): ``faces`` lists (x from, x to, height) of each face crossed."""
    obj = np.concatenate([np.column_stack([np.linspace(x0 + 2, x1 - 2, 40), np.full(40, y_mm),
                                           np.full(40, z)]) for x0, x1, z in faces])
    rail = obj @ cal.target_rotation.T + cal.target_translation_mm
    return rail @ cal.rotation  # ideal -> camera (rows R^T P); frame t1: no travel


def test_stripe_on_one_face_only_is_undetermined(flat_calibration):
    cal = SceneCalibration.load(flat_calibration)
    target = default_target()
    pose = (cal.target_rotation, cal.target_translation_mm)
    tops = {f.name: f.vertices_mm for f in target.top_faces()}
    low = (float(tops["low top"][:, 0].min()), float(tops["low top"][:, 0].max()),
           float(tops["low top"][0, 2]))
    high = (float(tops["high top"][:, 0].min()), float(tops["high top"][:, 0].max()),
            float(tops["high top"][0, 2]))

    def obs(faces):
        return StripeObservations(target, cal.speed_mm_s, {"green": cal.t1},
                                  {"green": [(cal.t1, 0.0, _face_rays(cal, faces))]})

    # across both faces: a plane (the vertical plane through the points, y = 30 mm on the target)
    fit, _ = obs([low, high]).fit_planes(cal.rotation, pose)["green"]
    assert fit.rms_mm < 1e-6 and fit.heights_mm == (low[2], high[2])
    assert abs(abs(fit.plane.normal @ (cal.target_rotation @ [0.0, 1.0, 0.0])) - 1) < 1e-9
    # on the low face only (the stripe misses the high step): refused, not a plane
    for faces in ([low], [high]):
        with pytest.raises(CalibrationError, match="not found on two target faces") as err:
            obs(faces).fit_planes(cal.rotation, pose)
        assert err.value.code == "E-PLANE-UNDETERMINED"
    # the fit itself refuses points at one height, naming it
    pts = np.random.default_rng(1).normal(size=(50, 3)) * [20, 1, 0] + [0, 0, 300]
    with pytest.raises(CalibrationError, match="two different heights.*15 mm") as err:
        fit_laser_plane("red", pts, np.full(50, 15.0), [7])
    assert err.value.code == "E-PLANE-UNDETERMINED"


# ----- proposed calibration frames -------------------------------------------------------------
def test_proposed_frames_have_each_stripe_on_the_target(flat_scan):
    """``propose_calibration_frames`` against the truth: in the proposed t1 the true green
    laser plane crosses the target's three L, M, N edges (so its stripe lies across both
    faces), in t2 the red one; and the frames are near the simulator's own choice."""
    from impress_gui.core.calibration.aids import propose_calibration_frames

    truth = _with_truth_intrinsics(flat_scan)
    with open_video(flat_scan / "scan.mp4") as v:
        prop = propose_calibration_frames(v)
    intr = Intrinsics.from_json(truth["_intrinsics"])
    rot = np.array(truth["rotation_camera_to_ideal"])
    w, h = intr.image_size
    for key, laser in (("t1", "green"), ("t2", "red")):
        k = prop[key]
        lam, _ = _edge_hits(truth, laser, k)
        assert np.all((lam > 0.05) & (lam < 0.95)), (key, k, lam)
        # all six corners in view, so they can be clicked
        corners = np.array(list(truth["target"]["corners_rail_mm"].values()))
        uv = intr.project((corners - [0.0, truth["travel_mm"][k], 0.0]) @ rot)
        assert np.all((uv >= 0) & (uv < [w, h])), (key, uv)
    assert prop["t1"] < prop["t2"]
    # within a quarter of the target's run past each stripe of the simulator's frames
    sim = truth["calibration_frames"]
    fps = truth["config"].get("fps", 30)
    run_frames = 70.0 / truth["speed_mm_s"] * fps
    for key in ("t1", "t2"):
        assert abs(prop[key] - sim[key]) < 0.5 * run_frames, (key, prop, sim)


def test_the_windows_pick_editor_keeps_the_stripe_points(flat_scan):
    """Picks imported into the calibration tab's editor and exported again keep the
    three-point stripe points (the window never drops what a file holds)."""
    from impress_gui.core.calibration.pick_editor import PickEditor

    picks = _stripe_picks(flat_scan)
    assert picks.stripe_points
    editor = PickEditor()
    editor.import_picks(picks)
    out = editor.to_picks(picks.video, picks.video_sha256)
    assert out is not None and out.stripe_points == picks.stripe_points
    editor.undo()  # back to the empty state: no stray stripe points either
    assert editor.state.stripe_points == {}
