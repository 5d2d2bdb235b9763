"""``impress compare`` against the simulator's ground truth.

- The shoe's true relief (``sim.scenes.shoe_relief``, the same heights the shoe preset renders)
  in two poses at 0.1 mm: the registration recovers the pose (compared with the poses' own
  matrices), residual RMS <= 0.03 mm and the difference's 95th percentile <= 0.06 mm over the
  overlap (the issue's acceptance, on the surfaces themselves: what registration and
  resampling add);
- a copy with the 0.5 mm x 3 mm cut: outlined by the threshold, its depth within 0.05 mm and
  its length within 0.2 mm of the truth;
- the impression against its outsole (inverted and mirrored) registers the same;
- a mean track of three registered copies: the mean is the truth, the deviation small except at
  the cut;
- two rendered scans (320x180, different pose, roll, tilt, standoff and render seed) reconstructed
  and compared: the pose is recovered; the residuals at that resolution are stated below (the
  full-resolution figures come from benchmarks/bench_compare.py);
- the command: files read back with tifffile and json, byte-identical runs, coded errors.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from impress_gui.cli import main
from impress_gui.core.base.errors import InputError
from impress_gui.core.compare.mean import mean_track
from impress_gui.core.compare.record import CompareParams, compare
from impress_gui.core.compare.register import RegistrationParams, kabsch, register
from impress_gui.core.compare.surfaces import Surface, load_surface
from impress_gui.sim.scenes import ShoeCut, ShoePose, shoe_relief

pytest.importorskip("open3d")

ROOT = Path(__file__).resolve().parents[1]
PIXEL_MM = 0.1
POSE_B = {"rotate_deg": 20.0, "shift_x_mm": 12.0, "shift_y_mm": -8.0}
POSE_C = {"rotate_deg": -12.0, "shift_x_mm": -6.0, "shift_y_mm": 5.0}
CUT = ShoeCut()  # 0.5 mm deep, 3 mm long, 0.6 mm wide at (15, 230) of the shoe's frame
# the acceptance (issue 20), on the true surfaces
RMS_MM, P95_MM = 0.03, 0.06
POSE_TOL_MM = 0.02  # the recovered motion vs the truth, at points over the sole
CUT_DEPTH_TOL_MM, CUT_LENGTH_TOL_MM = 0.05, 0.2


def truth_surface(scene) -> Surface:
    """A simulator scene (rail frame: cell [i, j] at X = x0 + j p, Y = y0 + i p) as a surface
    in the export frame (x = X, y = -Y): documented conventions, not the code under test."""
    p = scene.pixel_mm
    return Surface(scene.height_mm, scene.x0_mm, -scene.y0_mm, p, -p, {"kind": "truth"})


@pytest.fixture(scope="module")
def truths():
    return {"a": truth_surface(shoe_relief(PIXEL_MM, 1)),
            "b": truth_surface(shoe_relief(PIXEL_MM, 1, POSE_B)),
            "c": truth_surface(shoe_relief(PIXEL_MM, 1, POSE_C, CUT))}


@pytest.fixture(scope="module")
def cmp_ab(truths):
    return compare(truths["a"], truths["b"])


@pytest.fixture(scope="module")
def cmp_ac(truths):
    return compare(truths["a"], truths["c"])


def sole_points(pose: dict | None) -> np.ndarray:
    """Points over the sole (shoe frame u across, v along) at 3 mm depth, in the export frame
    of a scan of the shoe in ``pose``."""
    u, v = np.meshgrid(np.linspace(-40, 40, 5), np.linspace(150, 400, 6))
    x, y = ShoePose.of(pose).to_rail(u.ravel(), v.ravel())
    return np.column_stack([x, -y, np.full(x.size, -3.0)])


def pose_error_mm(matrix: np.ndarray, pose_b: dict | None, pose_a: dict | None = None,
                  s1_a: float = 0.0, s1_b: float = 0.0, xy_only: bool = False) -> float:
    """Largest distance between where the registration puts points of B and where they truly
    are in A (export frames; ``s1``: a reconstruction's frame starts at rail Y = s1;
    ``xy_only``: the distance across the ground only)."""
    pts = sole_points(pose_b)
    pts[:, 1] += s1_b
    got = pts @ matrix[:3, :3].T + matrix[:3, 3]
    sx, sy = ShoePose.of(pose_b).to_shoe(pts[:, 0], -(pts[:, 1] - s1_b))
    x, y = ShoePose.of(pose_a).to_rail(sx, sy)
    want = np.column_stack([x, -y + s1_a, np.full(len(x), -3.0)])
    if xy_only:
        got, want = got[:, :2], want[:, :2]
    return float(np.max(np.linalg.norm(got - want, axis=1)))


# ----- geometry on the true surfaces -----------------------------------------------------------
def test_kabsch_recovers_a_rigid_motion():
    rng = np.random.default_rng(3)
    src = rng.uniform(-50, 50, (7, 3))
    c, s = np.cos(0.4), np.sin(0.4)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]) @ np.array(
        [[1, 0, 0], [0, np.cos(0.02), -np.sin(0.02)], [0, np.sin(0.02), np.cos(0.02)]])
    dst = src @ rot.T + [3.0, -7.0, 0.5]
    m = kabsch(src, dst)
    assert np.allclose(m[:3, :3], rot, atol=1e-12) and np.allclose(m[:3, 3], [3, -7, 0.5])


def test_registration_recovers_the_pose(cmp_ab):
    reg = cmp_ab.registration
    turn = reg.rotation_deg()
    # +20 deg in the rail frame (X towards Y) is -20 deg seen from above in the export frame
    # (y = -Y); B -> A undoes it: +20 deg
    assert abs(turn - 20.0) < 0.01, turn
    assert pose_error_mm(reg.matrix, POSE_B) < POSE_TOL_MM
    assert reg.rms_mm <= RMS_MM, reg.rms_mm
    assert reg.overlap > 0.95
    assert cmp_ab.stats.p95_abs_mm <= P95_MM, cmp_ab.stats.p95_abs_mm
    assert abs(cmp_ab.stats.median_mm) < 0.005


def test_point_pairs_register_the_same(truths, cmp_ab):
    a, b = truths["a"], truths["b"]
    shoe = np.array([[0.0, 180.0], [30.0, 330.0], [-30.0, 380.0]])
    xa, ya = ShoePose.of(None).to_rail(shoe[:, 0], shoe[:, 1])
    xb, yb = ShoePose.of(POSE_B).to_rail(shoe[:, 0], shoe[:, 1])
    # clicks 0.3 mm off: the ICP refines them away
    pairs = tuple(((float(xa[k]) + 0.3, float(-ya[k])), (float(xb[k]), float(-yb[k]) - 0.3))
                  for k in range(3))
    reg = register(a, b, RegistrationParams(pairs=pairs))
    assert reg.coarse["method"].startswith("point pairs")
    assert pose_error_mm(reg.matrix, POSE_B) < POSE_TOL_MM
    assert np.allclose(reg.matrix, cmp_ab.registration.matrix, atol=1e-3)
    line = tuple(((float(xa[0]) + k, float(-ya[0])), (float(xb[0]) + k, float(-yb[0])))
                 for k in range(3))
    with pytest.raises(InputError) as err:
        register(a, b, RegistrationParams(pairs=line))
    assert err.value.code == "E-COMPARE-PAIRS"


def cut_in_a() -> tuple[float, float]:
    x, y = ShoePose.of(None).to_rail(CUT.x_mm, CUT.y_mm)
    return float(x), float(-y)


def test_the_cut_is_outlined_and_measured(cmp_ac):
    reg = cmp_ac.registration
    assert pose_error_mm(reg.matrix, POSE_C) < POSE_TOL_MM
    assert reg.rms_mm <= RMS_MM and cmp_ac.stats.p95_abs_mm <= P95_MM
    cx, cy = cut_in_a()
    near = [r for r in cmp_ac.regions
            if np.hypot(r.centroid_mm[0] - cx, r.centroid_mm[1] - cy) < 1.0]
    assert len(near) == 1, [r.to_json() for r in cmp_ac.regions[:10]]
    cut = near[0]
    # the copy (B) has the ridge the cut leaves: A - B is negative there
    assert cut.deepest_mm < 0
    assert abs(cut.max_depth_mm - CUT.depth_mm) <= CUT_DEPTH_TOL_MM, cut.to_json()
    assert abs(cut.length_mm - CUT.length_mm) <= CUT_LENGTH_TOL_MM, cut.to_json()
    # along the cut's direction in A (the shoe's frame is A's rail frame; y flips)
    assert abs((cut.axis_deg + CUT.angle_deg) % 180.0) < 3.0 or \
        abs(((cut.axis_deg + CUT.angle_deg) % 180.0) - 180.0) < 3.0, cut.axis_deg
    # it stands out: the outline's cells are at the cut
    rr, cc = np.nonzero(cmp_ac.outline)
    x, y = cmp_ac.a.xy(rr, cc)
    assert np.any(np.hypot(x - cx, y - cy) < 1.0)


def outsole_of(s: Surface) -> Surface:
    """The outsole's surface from an impression: heights inverted (z -> -z) and mirrored
    (x -> -x): the grid's columns reversed, x0 the mirrored last column."""
    cols = s.shape[1]
    return Surface(np.ascontiguousarray(-s.height_mm[:, ::-1]),
                   -(s.x0_mm + (cols - 1) * s.pixel_mm), s.y0_mm, s.pixel_mm, s.y_step_mm,
                   {"kind": "outsole"})


def test_impression_against_its_outsole(truths):
    outsole = outsole_of(truths["b"])
    cmp = compare(truths["a"], outsole,
                  CompareParams(RegistrationParams(mirror=True, invert=True)))
    reg = cmp.registration
    # the outsole's points mirrored and inverted back are B's: the same motion as B -> A
    flip = np.diag([-1.0, 1.0, -1.0, 1.0])
    assert pose_error_mm(reg.matrix @ flip, POSE_B) < POSE_TOL_MM
    assert reg.rms_mm <= RMS_MM and cmp.stats.p95_abs_mm <= P95_MM
    assert np.linalg.det(reg.rigid[:3, :3]) > 0.999


def test_mean_track_of_three_copies(truths, cmp_ab, cmp_ac):
    win = cmp_ab.a
    track = mean_track(win, [(truths["b"], cmp_ab.registration.matrix),
                             (truths["c"], cmp_ac.registration.matrix)])
    assert track.count.max() == 3
    full = track.count == 3
    truth = win.height_mm
    cx, cy = cut_in_a()
    ii, jj = np.mgrid[0 : win.shape[0], 0 : win.shape[1]]
    x, y = win.xy(ii, jj)
    at_cut = np.hypot(x - cx, y - cy) < 0.2
    away = full & (np.hypot(x - cx, y - cy) > 3.0)
    err = np.abs(track.mean_mm - truth)[away]
    assert np.percentile(err, 95) < 0.03 and np.median(err) < 0.001
    assert np.percentile(track.std_mm[away], 95) < 0.03
    # at the cut one of three maps is 0.5 mm higher: mean +1/6, deviation 0.5 sqrt(2)/3
    assert np.allclose(track.mean_mm[at_cut] - truth[at_cut], CUT.depth_mm / 3, atol=0.02)
    assert np.allclose(track.std_mm[at_cut], CUT.depth_mm * np.sqrt(2) / 3, atol=0.02)


# ----- the command -----------------------------------------------------------------------------
def write_recon(folder: Path, s: Surface, step: int = 2) -> Path:
    """A reconstruction folder as impress process writes it (the parts compare reads), from a
    surface in the export frame with row 0 at the largest y (every ``step``-th cell)."""
    import tifffile

    h = np.ascontiguousarray(s.height_mm[::step, ::step], np.float32)
    p = s.pixel_mm * step
    folder.mkdir(parents=True)
    tifffile.imwrite(folder / "heightmap.tif", h)
    sha = hashlib.sha256((folder / "heightmap.tif").read_bytes()).hexdigest()
    grid = {"x0_mm": s.x0_mm, "y0_mm": -s.y0_mm, "pixel_mm": p, "shape": list(h.shape)}
    meta = {"format": "impress.reconstruction", "version": 1, "software": "test", "grid": grid,
            "inputs": {"video": {"sha256": "v" * 64}, "calibration": {"sha256": "c" * 64}},
            "files": {"heightmap.tif": sha}}
    (folder / "metadata.json").write_text(json.dumps(meta, indent=2))
    return folder


def write_ply(path: Path, s: Surface, step: int = 2) -> Path:
    """Points x, y, z (float32, export frame) as a binary PLY, written with plyfile."""
    from plyfile import PlyData, PlyElement

    pts = s.points(step)
    v = np.zeros(len(pts), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
    v["x"], v["y"], v["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    PlyData([PlyElement.describe(v, "vertex")]).write(str(path))
    return path


@pytest.fixture(scope="module")
def recons(truths, tmp_path_factory):
    root = tmp_path_factory.mktemp("compare-inputs")
    return {"a": write_recon(root / "a", truths["a"]), "c": write_recon(root / "c", truths["c"]),
            "b_ply": write_ply(root / "b.ply", truths["b"])}


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_command_writes_files_independent_readers_read(recons, tmp_path, capsys):
    import tifffile

    out1, out2 = tmp_path / "one", tmp_path / "two"
    argv = ["compare", str(recons["a"]), str(recons["c"]), "--threshold-mm", "0.25"]
    assert main([*argv, "-o", str(out1)]) == 0
    assert "comparison written" in capsys.readouterr().out
    assert main([*argv, "-o", str(out2)]) == 0
    names = sorted(p.name for p in out1.iterdir())
    assert names == sorted(p.name for p in out2.iterdir())
    for name in names:  # the same input gives the same bytes
        assert (out1 / name).read_bytes() == (out2 / name).read_bytes(), name
    doc = json.loads((out1 / "compare.json").read_text())
    assert doc["format"] == "impress.compare" and doc["version"] == 1
    for name, sha in doc["files"].items():
        assert _sha(out1 / name) == sha, name
    assert doc["inputs"]["a"]["files"]["heightmap.tif"] == _sha(recons["a"] / "heightmap.tif")
    assert doc["inputs"]["b"]["files"]["metadata.json"] == _sha(recons["c"] / "metadata.json")
    assert doc["inputs"]["a"]["video_sha256"] == "v" * 64
    assert doc["parameters"]["threshold_mm"] == 0.25
    m = np.array(doc["registration"]["matrix_b_to_a"])
    assert m.shape == (4, 4) and pose_error_mm(m, POSE_C) < 0.05
    diff = tifffile.imread(out1 / "difference.tif")
    a_win = tifffile.imread(out1 / "a.tif")
    b_on = tifffile.imread(out1 / "b_on_a.tif")
    assert diff.dtype == np.float32 and diff.shape == tuple(doc["grid"]["shape"])
    ok = np.isfinite(diff)
    # the default metric: along A's normal, (A - B) / sqrt(1 + |grad A|^2); checked with
    # numpy's central differences where a cell's four neighbours have data
    assert doc["difference"]["metric"] == doc["parameters"]["metric"] == "normal"
    assert "normal" in doc["difference"]["definition"]
    gy, gx = np.gradient(a_win.astype(np.float64), doc["grid"]["pixel_mm"])
    inner = ok & np.isfinite(gx) & np.isfinite(gy)
    want = (a_win.astype(np.float64) - b_on) / np.sqrt(1 + gx * gx + gy * gy)
    assert inner.sum() > 0.9 * ok.sum()
    assert np.allclose(diff[inner], want[inner], atol=1e-6, rtol=1e-5)
    assert np.all(np.abs(diff[ok]) <= np.abs(a_win - b_on)[ok] + 1e-6)
    assert np.percentile(np.abs(diff[ok]), 50) < 0.01
    # the difference's grid is A's: its cell [0, 0] lies on one of A's cells
    g = doc["grid"]
    col = (g["x0_mm"] - (-125.0)) / g["pixel_mm"]
    assert abs(col - round(col)) < 1e-6
    cx, cy = cut_in_a()
    near = [r for r in doc["regions"]["items"]
            if np.hypot(r["centroid_mm"][0] - cx, r["centroid_mm"][1] - cy) < 1.5]
    assert len(near) == 1 and near[0]["deepest_mm"] < -0.3
    html = (out1 / "report.html").read_text()
    assert _sha(recons["a"] / "heightmap.tif") in html and "residual RMS" in html
    assert "Signed distance along A&#39;s surface normal" in html
    # the maps and figures name the compared inputs' SHA-256 themselves (read by tifffile
    # and Pillow; the audit of 4 December 2026 found only "grid in compare.json")
    from PIL import Image

    for name in ("difference.tif", "a.tif", "b_on_a.tif"):
        with tifffile.TiffFile(out1 / name) as tf:
            text = tf.pages[0].description
        assert _sha(recons["a"] / "heightmap.tif") in text, name
        assert _sha(recons["c"] / "heightmap.tif") in text and "compare.json" in text, name
    for name in ("difference.png", "histogram.png"):
        with Image.open(out1 / name) as im:
            assert _sha(recons["c"] / "heightmap.tif") in im.text["Description"], name


def test_command_vertical_metric(recons, tmp_path, capsys):
    """``--metric vertical``: the difference is A - B itself, and the record says so; over the
    overlap its 95th percentile is above the normal one (the walls)."""
    import tifffile

    out_v, out_n = tmp_path / "vertical", tmp_path / "normal"
    assert main(["compare", str(recons["a"]), str(recons["c"]), "--metric", "vertical", "-o",
                 str(out_v)]) == 0
    assert "(vertical)" in capsys.readouterr().out
    assert main(["compare", str(recons["a"]), str(recons["c"]), "-o", str(out_n)]) == 0
    doc_v = json.loads((out_v / "compare.json").read_text())
    doc_n = json.loads((out_n / "compare.json").read_text())
    assert doc_v["difference"]["metric"] == doc_v["parameters"]["metric"] == "vertical"
    diff = tifffile.imread(out_v / "difference.tif")
    a_win, b_on = tifffile.imread(out_v / "a.tif"), tifffile.imread(out_v / "b_on_a.tif")
    ok = np.isfinite(diff)
    assert np.array_equal(diff[ok], (a_win - b_on)[ok])
    assert doc_v["registration"]["matrix_b_to_a"] == doc_n["registration"]["matrix_b_to_a"]
    assert doc_n["difference"]["p95_abs_mm"] < doc_v["difference"]["p95_abs_mm"]
    assert "Vertical difference A - B" in (out_v / "report.html").read_text()
    with pytest.raises(SystemExit) as exit_:
        main(["compare", str(recons["a"]), str(recons["c"]), "--metric", "sideways", "-o",
              str(tmp_path / "no")])
    assert exit_.value.code == 2 and "[E-USAGE]" in capsys.readouterr().err
    assert not (tmp_path / "no").exists()
    with pytest.raises(InputError) as err:
        compare(load_surface(recons["a"]), load_surface(recons["c"]),
                CompareParams(metric="sideways"))
    assert err.value.code == "E-COMPARE-OPTION"


def test_command_reads_a_point_cloud_and_makes_a_mean(recons, tmp_path):
    out = tmp_path / "mean"
    assert main(["compare", str(recons["a"]), str(recons["b_ply"]), str(recons["c"]),
                 "--mean", "-o", str(out)]) == 0
    import tifffile

    doc = json.loads((out / "compare.json").read_text())
    assert doc["inputs"]["b"]["kind"] == "ply" and doc["inputs"]["input_3"]["kind"] == \
        "reconstruction"
    assert pose_error_mm(np.array(doc["registration"]["matrix_b_to_a"]), POSE_B) < 0.1
    count = tifffile.imread(out / "count.tif")
    std = tifffile.imread(out / "std.tif")
    assert count.max() == 3 and doc["mean_track"]["maps"] == 3
    assert np.nanmedian(std[count == 3]) < 0.02


def test_command_takes_point_pairs(recons, tmp_path):
    """Three pairs (shoe points as each input's export frame has them, 0.5 mm off) make the
    coarse step; the record keeps them."""
    shoe = [(0.0, 180.0), (30.0, 330.0), (-30.0, 380.0)]
    pairs = []
    for u, v in shoe:
        xa, ya = ShoePose.of(None).to_rail(u, v)
        xc, yc = ShoePose.of(POSE_C).to_rail(u, v)
        pairs.append({"a": [float(xa) + 0.5, float(-ya)], "b": [float(xc), float(-yc) + 0.5]})
    (tmp_path / "pairs.json").write_text(json.dumps({"pairs": pairs}))
    out = tmp_path / "paired"
    assert main(["compare", str(recons["a"]), str(recons["c"]), "--pairs",
                 str(tmp_path / "pairs.json"), "-o", str(out)]) == 0
    doc = json.loads((out / "compare.json").read_text())
    reg = doc["registration"]
    assert reg["coarse"]["method"].startswith("point pairs") and reg["coarse"]["pairs"] == 3
    assert doc["parameters"]["registration"]["pairs"][0]["a"] == pairs[0]["a"]
    assert pose_error_mm(np.array(reg["matrix_b_to_a"]), POSE_C) < 0.05


def _fails(capsys, argv, code: str, out: Path) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"[{code}]" in err and "Traceback" not in err, err
    assert not out.exists()
    assert not [p for p in out.parent.iterdir() if p.name.startswith(f".{out.name}")]


def test_bad_inputs_give_their_codes(recons, tmp_path, capsys):
    out = tmp_path / "out"
    a, c = str(recons["a"]), str(recons["c"])
    _fails(capsys, ["compare", a, str(tmp_path / "nowhere"), "-o", str(out)],
           "E-COMPARE-INPUT", out)
    (tmp_path / "notes.txt").write_text("hello")
    _fails(capsys, ["compare", a, str(tmp_path / "notes.txt"), "-o", str(out)],
           "E-COMPARE-INPUT", out)
    (tmp_path / "empty").mkdir()
    _fails(capsys, ["compare", a, str(tmp_path / "empty"), "-o", str(out)], "E-FILE-MISSING",
           out)
    (tmp_path / "bad.x3p").write_bytes(b"not a zip")
    _fails(capsys, ["compare", a, str(tmp_path / "bad.x3p"), "-o", str(out)], "E-X3P-ZIP", out)
    flat = Surface(np.zeros((400, 300), np.float32), 0.0, 0.0, 0.2, -0.2)
    flat_dir = write_recon(tmp_path / "flat", flat, step=1)
    _fails(capsys, ["compare", a, str(flat_dir), "-o", str(out)], "E-COMPARE-NO-DATA", out)
    # ripples everywhere: relief, but nothing of the shoe
    yy, xx = np.mgrid[0:1500, 0:1000] * 0.2
    ripples = Surface((3.0 * np.sin(xx / 3.0) * np.cos(yy / 5.0)).astype(np.float32), -100.0,
                      -150.0, 0.2, -0.2)
    _fails(capsys, ["compare", a, str(write_recon(tmp_path / "ripples", ripples, step=1)),
                    "-o", str(out)], "E-COMPARE-REGISTRATION", out)
    (tmp_path / "pairs.json").write_text(json.dumps({"pairs": [{"a": [0, 0], "b": [0, 0]}]}))
    _fails(capsys, ["compare", a, c, "--pairs", str(tmp_path / "pairs.json"), "-o", str(out)],
           "E-COMPARE-PAIRS", out)
    _fails(capsys, ["compare", a, c, "--threshold-mm", "0", "-o", str(out)],
           "E-COMPARE-OPTION", out)
    _fails(capsys, ["compare", a, c, a, "-o", str(out)], "E-COMPARE-OPTION", out)
    _fails(capsys, ["compare", a, "-o", str(out)], "E-COMPARE-OPTION", out)
    # a changed heightmap is refused
    changed = tmp_path / "changed"
    shutil.copytree(recons["c"], changed)
    import tifffile

    h = tifffile.imread(changed / "heightmap.tif")
    tifffile.imwrite(changed / "heightmap.tif", h + np.float32(0.01))
    _fails(capsys, ["compare", a, str(changed), "-o", str(out)], "E-COMPARE-HASH", out)
    # the output may not hold an input, nor replace a folder that is not a comparison
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "keep.txt").write_text("mine")
    assert main(["compare", a, c, "-o", str(busy)]) == 2
    assert "[E-OUTPUT-NOT-EMPTY]" in capsys.readouterr().err
    assert (busy / "keep.txt").read_text() == "mine"
    assert main(["compare", a, c, "-o", str(recons["a"] / "cmp")]) == 2
    assert "[E-OUTPUT-HOLDS-INPUT]" in capsys.readouterr().err


def test_surfaces_from_x3p_and_reconstruction_agree(recons, tmp_path):
    """An X3P written by the product's writer (export frame, y growing with the row) gives
    the same surface as the folder it came from."""
    import tifffile

    from impress_gui.core.formats.writers import x3p_bytes
    from impress_gui.core.reconstruction.grid import GridSpec

    meta = json.loads((recons["a"] / "metadata.json").read_text())
    g = meta["grid"]
    spec = GridSpec(g["x0_mm"], g["y0_mm"], g["pixel_mm"], tuple(g["shape"]))
    h = tifffile.imread(recons["a"] / "heightmap.tif")
    (tmp_path / "a.x3p").write_bytes(x3p_bytes(spec, h, "2026-01-01T00:00:00"))
    s_dir = load_surface(recons["a"])
    s_x3p = load_surface(tmp_path / "a.x3p")
    pts = s_dir.points(50)
    assert np.allclose(s_x3p.sample(pts[:, 0], pts[:, 1]), pts[:, 2], atol=1e-6)


# ----- rendered scans --------------------------------------------------------------------------
SPEED = "52.552"  # four times the fast rail speed: a quarter of the frames (287 a scan)
SCANS = {
    "a": ["--seed", "1", "--grid-mm", "0.2"],
    "b": ["--seed", "2", "--sole-seed", "1", "--shoe-rotate", "20", "--shoe-shift-mm=12,-8",
          "--roll", "-0.5", "--tilt", "1.0", "--standoff-mm", "320", "--grid-mm", "0.2"],
}
RESOLUTION = "320x180"
# measured at 320x180 with this test's scans (docs/comparison.md); the acceptance figures at
# full resolution come from benchmarks/bench_compare.py
#: the scenes on a 0.2 mm grid (a pixel is about 1 mm at 320x180; the 0.1 mm default took
#: 1.8 times as long to render: 47 s against 27 s per scan). Measured with them
#: (2026-12-04): pose 0.064 mm, turn 19.986 deg, residual RMS 0.118 mm, p95 0.418 mm along the normal; with 0.1 mm scenes 0.40-0.54 mm,
#: 19.97-20.04 deg, 0.153-0.159 mm, 0.499 mm (the limits were set then and are kept).
#: On 2026-12-07 at twice the fast rail speed (26.276 mm/s, 561 frames a scan): 0.082 mm,
#: 20.013 deg, 0.116 mm, 0.298 mm; since then at four times it (52.552 mm/s, 1.75 mm of
#: travel a frame, 287 frames, about 35 % less time for the renders, calibrations and
#: reconstructions): 0.165 mm, 19.990 deg, 0.119 mm, 0.396 mm
RECON_POSE_TOL_MM = 0.6
RECON_TURN_TOL_DEG = 0.1
RECON_RMS_MM = 0.25
RECON_P95_MM = 1.0
#: rendering and calibrating the two scans takes about 30 s on a quiet 2-core machine the first
#: time (cached afterwards); a machine shared with other work can take several times that
RENDER_TIMEOUT_S = 1200


def _run(*args: str) -> None:
    r = subprocess.run([sys.executable, "-m", "impress_gui", *args], capture_output=True,
                       timeout=RENDER_TIMEOUT_S, cwd=ROOT)
    # the command's own coded line, not only its exit status, when it fails
    assert r.returncode == 0, (f"impress {args[0]} exited {r.returncode}: "
                               f"{r.stderr.decode(errors='replace')[-2000:]}")


def _source_key(args: list[str], *, calibration: bool = False) -> str:
    """The cache key of a rendered scan (the simulator's source; the calibration's, whose
    target and picks the simulator uses) or, ``calibration``, of its calibration (also the
    stripe detector's source: the calibration finds the stripe with the reconstruction's
    detector)."""
    h = hashlib.sha256(" ".join([RESOLUTION, SPEED, *args]).encode())
    files = sorted((ROOT / "impress_gui" / "sim").glob("*.py"))
    files += sorted((ROOT / "impress_gui" / "core" / "calibration").glob("*.py"))
    if calibration:
        files += [ROOT / "impress_gui" / "core" / "reconstruction" / n
                  for n in ("stripes.py", "kernels.py")]
    for f in files:
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def rendered_scan(config, factory, name: str) -> tuple[Path, Path]:
    """``(scan folder, its calibration)``, kept in pytest's cache between runs: the scan keyed
    by the simulator's and the calibration's source, its calibration also by the stripe
    detector's (a change to the detector calibrates the cached scan again, without rendering
    it again)."""
    args = SCANS[name]
    cache = Path(config.cache.mkdir(f"impress-compare-scan-{name}"))
    final = cache / _source_key(args)
    if not (final / "complete").exists():
        work = factory.mktemp(f"scan-{name}") / "scan"
        # one process: with more, each worker builds the 0.1 mm scene again (~12 s each) and
        # the test suite's other worker already has the second core (the frames are the same)
        _run("simulate", str(work), "--resolution", RESOLUTION, "--speed", SPEED,
             "--workers", "1", *args)
        (work / "complete").write_text("ok\n")
        for old in cache.iterdir():
            shutil.rmtree(old, ignore_errors=True)
        tmp = cache / f".{final.name}.{os.getpid()}"
        shutil.copytree(work, tmp)
        try:
            tmp.rename(final)
        except OSError:
            shutil.rmtree(tmp, ignore_errors=True)
    cal = final / f"cal-{_source_key(args, calibration=True)}.json"
    if not cal.is_file():
        tmp_cal = factory.mktemp(f"cal-{name}") / "cal.json"
        _run("calibrate", str(final / "scan.mp4"), "--intrinsics",
             str(final / "intrinsics.json"), "--picks", str(final / "picks.json"), "--speed",
             SPEED, "-o", str(tmp_cal))
        for old in final.glob("cal-*.json"):
            old.unlink(missing_ok=True)
        part = final / f".{cal.name}.{os.getpid()}"
        shutil.copyfile(tmp_cal, part)
        os.replace(part, cal)
    return final, cal


@pytest.fixture(scope="module")
def scans(request, tmp_path_factory):
    from impress_gui.core.reconstruction.pipeline import process_files
    from impress_gui.core.reconstruction.reconstruct import ProcessParams

    out = {}
    for name in SCANS:
        scan, cal = rendered_scan(request.config, tmp_path_factory, name)
        recon = tmp_path_factory.mktemp(f"recon-{name}") / "recon"
        process_files(scan / "scan.mp4", cal, recon, ProcessParams(grid_mm=0.2))
        out[name] = (scan, recon)
    return out


@pytest.mark.timeout(RENDER_TIMEOUT_S)
def test_rendered_scans_register(scans, tmp_path):
    (scan_a, recon_a), (scan_b, recon_b) = scans["a"], scans["b"]
    out = tmp_path / "ab"
    assert main(["compare", str(recon_a), str(recon_b), "-o", str(out)]) == 0
    doc = json.loads((out / "compare.json").read_text())
    reg = doc["registration"]

    def s1(scan: Path) -> float:
        t = json.loads((scan / "truth.json").read_text())
        return t["travel_mm"][t["calibration_frames"]["t1"]]

    # across the ground only: each reconstruction's own ground plane is tilted by ~0.001 rad
    # at this resolution (each against its own truth), which the registration rightly follows
    err = pose_error_mm(np.array(reg["matrix_b_to_a"]), POSE_B, None, s1(scan_a), s1(scan_b),
                        xy_only=True)
    assert err < RECON_POSE_TOL_MM, err
    assert abs(reg["rotation_about_z_deg"] - 20.0) < RECON_TURN_TOL_DEG
    assert reg["residual_rms_mm"] <= RECON_RMS_MM, reg["residual_rms_mm"]
    assert doc["difference"]["p95_abs_mm"] <= RECON_P95_MM, doc["difference"]["p95_abs_mm"]
    print(f"320x180: pose error {err:.3f} mm, turn {reg['rotation_about_z_deg']:.4f} deg, "
          f"residual RMS {reg['residual_rms_mm']:.4f} mm, p95 "
          f"{doc['difference']['p95_abs_mm']:.4f} mm")


def test_one_profile_across_both_maps(cmp_ac):
    """Across the cut: B (with its ridge) 0.5 mm above A over the cut's width, equal beside."""
    from impress_gui.core.compare.difference import pair_profile

    cx, cy = cut_in_a()
    across = np.array([np.sin(np.radians(CUT.angle_deg)), np.cos(np.radians(CUT.angle_deg))])
    start, end = np.array([cx, cy]) - 2.0 * across, np.array([cx, cy]) + 2.0 * across
    prof = pair_profile(cmp_ac.a, cmp_ac.b_on_a, tuple(start), tuple(end))
    assert prof.distance_mm[-1] == pytest.approx(4.0)
    rise = -prof.difference_mm
    on = np.abs(prof.distance_mm - 2.0) < CUT.width_mm / 2 - 0.1
    off = np.abs(prof.distance_mm - 2.0) > CUT.width_mm / 2 + 0.2
    assert np.allclose(rise[on], CUT.depth_mm, atol=0.02)
    assert np.all(np.abs(rise[off]) < 0.02)


def test_steep_walls_are_not_outlined_unless_asked():
    """On a 0.2 mm grid every tread wall differs vertically by more than 0.25 mm after
    resampling (one cell of lateral misplacement there is more than that): outlined, they hide
    the cut among ~200 regions. Left out (the default), the cut is the one region, its depth
    and length read within the acceptance's 0.05 and 0.2 mm. Along A's normal (the default
    metric) a lateral misplacement moves the wall by at most itself: outlining the walls too
    adds at most a few small regions (measured: one, 0.28 mm, on a wall), and the cut reads
    the same."""
    from impress_gui.core.compare.difference import outline, steep_walls

    a = truth_surface(shoe_relief(0.2, 1))
    c = truth_surface(shoe_relief(0.2, 1, POSE_C, CUT))
    cmp = compare(a, c, CompareParams(metric="vertical"))
    everything, _ = outline(cmp.diff, cmp.a, 0.25, walls=True)
    regions, edge = outline(cmp.diff, cmp.a, 0.25)
    assert len(everything) > 50
    assert len(regions) == 1
    cut = regions[0]
    assert abs(cut.max_depth_mm - CUT.depth_mm) <= 0.05
    assert abs(cut.length_mm - CUT.length_mm) <= 0.2
    assert edge.any() and not (edge & steep_walls(cmp.a, 0.25)).any()
    normal = compare(a, c)
    with_walls, _ = outline(normal.diff, normal.a, 0.25, walls=True)
    assert 1 <= len(with_walls) <= 3, [r.to_json() for r in with_walls]
    cut_n = with_walls[0]  # the largest
    assert np.hypot(cut_n.centroid_mm[0] - cut.centroid_mm[0],
                    cut_n.centroid_mm[1] - cut.centroid_mm[1]) < 0.5
    assert abs(cut_n.max_depth_mm - CUT.depth_mm) <= 0.05
    assert abs(cut_n.length_mm - CUT.length_mm) <= 0.2
    assert all(r.area_mm2 < 0.2 * cut_n.area_mm2 for r in with_walls[1:])


def plane(sx: float, sy: float, dz: float = 0.0, dx: float = 0.0, n: int = 60) -> Surface:
    """The plane z = sx (x - dx) + sy y + dz on an n x n grid of 0.1 mm (row 0 at y = 0, y
    falling with the row)."""
    p = 0.1
    ii, jj = np.mgrid[0:n, 0:n]
    x, y = jj * p, -ii * p
    return Surface((sx * (x - dx) + sy * y + dz).astype(np.float64), 0.0, 0.0, p, -p)


@pytest.mark.parametrize("sx, sy", [(0.3, 0.0), (3.0, 0.0), (2.0, -1.5), (0.0, 8.0)])
def test_normal_metric_on_planes(sx, sy):
    """Two parallel planes: the normal metric is their distance (geometry, not the code's
    formula): B 0.1 mm lower gives 0.1 cos(angle); B moved 0.05 mm along x gives
    0.05 sx / sqrt(1 + sx^2 + sy^2); the vertical metric gives 0.1 and 0.05 sx."""
    from impress_gui.core.compare.difference import difference, resample

    a = plane(sx, sy)
    tilt = math.atan(math.hypot(sx, sy))
    for b, vertical, distance in (
            (plane(sx, sy, dz=-0.1), 0.1, 0.1 * math.cos(tilt)),
            (plane(sx, sy, dx=0.05), 0.05 * sx,
             0.05 * abs(sx) / math.sqrt(1 + sx * sx + sy * sy))):
        b_on = resample(a, b, np.eye(4))
        ok = np.isfinite(b_on)
        assert ok.all()
        d_n, d_v = difference(a, b_on), difference(a, b_on, "vertical")
        assert np.allclose(d_v[ok], vertical, atol=2e-6)
        assert np.allclose(d_n[ok], distance, atol=2e-6)


def test_normal_metric_is_the_distance_to_a_on_walls(truths):
    """The true relief and the same relief moved 0.05 mm across and 0.03 mm along (every point
    moves by 0.058 mm): the normal metric agrees with the exact distance from B's points to
    A's triangulated surface (open3d) and stays near 0.058 mm on the tread walls, where the
    vertical difference reaches 0.3 mm and more."""
    import open3d as o3d

    from impress_gui.core.compare.difference import difference, resample, slope

    a = truths["a"]
    win = a.crop((slice(1500, 2300), slice(500, 1300)))  # the tread, 80 x 80 mm
    moved = Surface(a.height_mm, a.x0_mm + 0.05, a.y0_mm - 0.03, a.pixel_mm, a.y_step_mm)
    b_on = resample(win, moved, np.eye(4))
    h = win.height_mm.astype(np.float64)
    rows, cols = h.shape
    ii, jj = np.mgrid[0:rows, 0:cols]
    x, y = win.xy(ii, jj)
    idx = np.arange(rows * cols).reshape(rows, cols)
    q0, q1 = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    q2, q3 = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    tris = np.vstack([np.column_stack([q0, q2, q1]), np.column_stack([q1, q2, q3])])
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor(np.column_stack([x.ravel(), y.ravel(), h.ravel()]).astype(np.float32)),
        o3d.core.Tensor(tris.astype(np.uint32)))
    ok = np.isfinite(b_on)
    ok[:2], ok[-2:], ok[:, :2], ok[:, -2:] = False, False, False, False
    exact = scene.compute_distance(o3d.core.Tensor(
        np.column_stack([x[ok], y[ok], b_on[ok]]).astype(np.float32))).numpy()
    normal = np.abs(difference(win, b_on))[ok]
    vertical = np.abs(difference(win, b_on, "vertical"))[ok]
    walls = slope(win)[ok] > 1.0
    assert 0.05 < walls.mean() < 0.2
    err = normal - exact
    assert abs(np.median(err)) < 1e-4 and np.percentile(np.abs(err), 99) < 0.02
    assert np.percentile(np.abs(err[walls]), 99) < 0.025
    assert np.percentile(normal[walls], 99) < 0.1 < np.percentile(vertical[walls], 95)
    assert np.percentile(vertical, 95) > 2.5 * np.percentile(normal, 95)
    flat = slope(win)[ok] < 0.05
    assert np.allclose(normal[flat], vertical[flat], rtol=0.002, atol=1e-6)


def test_point_pairs_out_of_range_are_refused(tmp_path):
    # a hostile-input audit: a coordinate of 1e308 overflowed in numpy (a warning on stderr)
    # and three coordinates were accepted
    from impress_gui.core.base.errors import InputError
    from impress_gui.core.compare.record import load_pairs

    ok = [{"a": [0.0, 0.0], "b": [1.0, 1.0]}, {"a": [5.0, 0.0], "b": [6.0, 1.0]},
          {"a": [0.0, 5.0], "b": [1.0, 6.0]}]
    for bad in ({"a": [1e308, 0.0], "b": [0.0, 0.0]}, {"a": [0.0, 0.0, 1.0], "b": [0.0, 0.0]},
                {"a": [0.0, 0.0], "b": [2e6, 0.0]}):
        (tmp_path / "p.json").write_text(json.dumps({"pairs": [*ok, bad]}))
        with pytest.raises(InputError) as e:
            load_pairs(tmp_path / "p.json")
        assert e.value.code == "E-COMPARE-PAIRS"
    (tmp_path / "p.json").write_text(json.dumps({"pairs": ok}))
    assert len(load_pairs(tmp_path / "p.json")) == 3
