"""Reconstruction against the simulator's ground truth, outputs, integrity and bad input."""

import hashlib
import json
import os
import shutil
import zipfile

import numpy as np
import pytest
import tifffile
from conftest import truth_on_grid
from scipy.ndimage import maximum_filter, minimum_filter

from impress_gui.core.base.errors import Cancelled, ReconstructionError, VideoError
from impress_gui.core.base.progress import CancelToken
from impress_gui.core.calibration.scene import SceneCalibration
from impress_gui.core.formats.video import open_video
from impress_gui.core.reconstruction.pipeline import process_files
from impress_gui.core.reconstruction.reconstruct import ProcessParams, reconstruct


@pytest.fixture(scope="module")
def recon(flat_scan, flat_calibration):
    cal = SceneCalibration.load(flat_calibration)
    with open_video(flat_scan / "scan.mp4") as v:
        return reconstruct(v, cal, ProcessParams())


def _errors(flat_scan, rec, height):
    truth = truth_on_grid(flat_scan, rec.spec)
    t0 = np.nan_to_num(truth)
    # exclude 0.5 mm around the target's vertical walls (a cell there straddles two heights)
    edge = (maximum_filter(t0, 11) - minimum_filter(t0, 11)) > 1.0
    err = height - truth
    return err[np.isfinite(err) & ~edge], truth, edge


def test_heights_match_truth(flat_scan, recon):
    err, truth, edge = _errors(flat_scan, recon, recon.height_mm)
    # at 640x360 one pixel of stripe shift is ~0.8 mm of height; benchmarks report 1080p
    assert err.size > 1e6
    assert np.mean(np.abs(err)) < 0.2
    assert abs(np.mean(err)) < 0.1
    assert np.percentile(np.abs(err), 99) < 0.8


def test_fusion_fills_more_than_either_laser(flat_scan, recon):
    g, r, f = (np.isfinite(recon.per_laser_mm["green"]), np.isfinite(recon.per_laser_mm["red"]),
               np.isfinite(recon.height_mm))
    assert f.sum() > g.sum() and f.sum() > r.sum()
    # where both lasers passed over the ground, away from the 40 mm target whose shadows only
    # one laser fills (and this short scan lets each laser see only one side of it)
    _, truth, edge = _errors(flat_scan, recon, recon.height_mm)
    both_rows = (g.mean(1) > 0.5) & (r.mean(1) > 0.5)
    target = maximum_filter(np.nan_to_num(truth) > 1.0, 301)  # 30 mm around the target
    cols = np.flatnonzero(g.any(0) & r.any(0))
    box = np.zeros_like(f)
    box[:, cols[20]:cols[-20]] = True
    box &= both_rows[:, None] & ~target
    assert box.sum() > 1.5e5  # 15 cm2 of ground
    assert f[box].mean() >= 0.99
    # contribution codes are consistent with the per-laser maps
    c = recon.contribution
    assert np.all((c == 1) == (g & ~r)) and np.all((c == 2) == (r & ~g))
    assert np.all(np.isin(c[g & r], (3, 4)))


def test_texture_registers_with_the_heightmap(flat_scan, recon):
    """The texture matches the simulator's albedo on the same grid (rough colour agreement
    where the shading is flat): the correlation of the luminance is high."""
    import cv2

    tex = recon.texture_rgb.astype(np.float32).mean(2)
    truth = json.loads((flat_scan / "truth.json").read_text())
    alb = cv2.imread(str(flat_scan / "truth_texture.png"))[..., ::-1].astype(np.float32).mean(2)
    hm = truth["heightmap"]
    s1 = truth["travel_mm"][truth["calibration_frames"]["t1"]]
    jj = np.rint((recon.spec.xs() - hm["x0_mm"]) / hm["pixel_mm"]).astype(int)
    ii = np.rint((recon.spec.ys() + s1 - hm["y0_mm"]) / hm["pixel_mm"]).astype(int)
    ok_i = (ii >= 0) & (ii < alb.shape[0])
    ok_j = (jj >= 0) & (jj < alb.shape[1])
    a = alb[np.ix_(ii[ok_i], jj[ok_j])][::5, ::5]
    t = tex[np.ix_(ok_i, ok_j)][::5, ::5]
    m = t > 0
    assert m.sum() > 50000  # 12 cm2 of texture (sampled every 0.5 mm)
    corr = np.corrcoef(a[m], t[m])[0, 1]
    assert corr > 0.8
    # a one-millimetre misregistration would cost most of that correlation
    shifted = np.corrcoef(np.roll(a, 2, axis=0)[m], t[m])[0, 1]
    assert shifted < corr


@pytest.mark.parametrize("method,mae_mm", [("hue", 0.5), ("lut", 0.3)])
def test_other_detection_methods_work(flat_scan, flat_calibration, method, mae_mm):
    """The seed's two methods, selectable; less accurate than the default combined one."""
    cal = SceneCalibration.load(flat_calibration)
    with open_video(flat_scan / "scan.mp4") as v:
        rec = reconstruct(v, cal, ProcessParams(method=method, texture=False, frame_start=60,
                                                frame_stop=140))
    err, _, _ = _errors(flat_scan, rec, rec.height_mm)
    assert err.size > 1e5 and np.mean(np.abs(err)) < mae_mm


def test_outputs_are_complete_deterministic_and_readable(flat_scan, flat_calibration, tmp_path):
    params = ProcessParams(frame_start=40, frame_stop=160)
    a = process_files(flat_scan / "scan.mp4", flat_calibration, tmp_path / "a", params)
    b = process_files(flat_scan / "scan.mp4", flat_calibration, tmp_path / "b", params)
    # every file but run.json is byte-identical (the X3P's dates come from the inputs)
    assert a["files"] == b["files"]
    names = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert names == sorted(p.name for p in (tmp_path / "b").iterdir())
    for name in names:
        if name != "run.json":
            assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    meta = json.loads((tmp_path / "a" / "metadata.json").read_text())
    truth = json.loads((flat_scan / "truth.json").read_text())
    assert meta["inputs"]["video"]["sha256"] == truth["video_sha256"]
    assert meta["parameters"]["frame_start"] == 40
    for name, sha in meta["files"].items():
        assert hashlib.sha256((tmp_path / "a" / name).read_bytes()).hexdigest() == sha
    hm = tifffile.imread(tmp_path / "a" / "heightmap.tif")
    assert hm.dtype == np.float32 and np.isnan(hm).any() and np.isfinite(hm).any()
    import open3d as o3d

    pc = o3d.io.read_point_cloud(str(tmp_path / "a" / "pointcloud.ply"))
    pts = np.asarray(pc.points)
    assert pc.has_colors()
    sub = hm[::2, ::2]  # the point cloud keeps every second cell (0.2 mm)
    assert len(pts) == np.isfinite(sub).sum() > 1000
    assert np.max(pts[:, 2]) == pytest.approx(np.nanmax(sub), abs=1e-4)
    with zipfile.ZipFile(tmp_path / "a" / "heightmap.x3p") as z:
        xml = z.read("main.xml").decode()
        data = z.read("bindata/data.bin")
        assert hashlib.md5(data).hexdigest() in xml
        assert hashlib.md5(z.read("main.xml")).hexdigest() in z.read("md5checksum.hex").decode()
    # the X3P is in the right-handed export frame: y = -rail Y, so its rows run last first
    z = np.frombuffer(data, "<f8").reshape(hm.shape)
    assert np.allclose(z[::-1] * 1e3, hm, equal_nan=True, atol=1e-4)
    # every view carries its provenance too (read by Pillow): the video's and the
    # calibration's SHA-256, the grid; the point cloud its sampling (the audit of 4 December
    # 2026 found the PNG views bare)
    from PIL import Image

    video_sha = meta["inputs"]["video"]["sha256"]
    for name in ("heightmap_8bit.png", "heightmap_color.png", "contribution.png"):
        with Image.open(tmp_path / "a" / name) as im:
            assert video_sha in im.text["Description"], name
            assert meta["inputs"]["calibration"]["sha256"] in im.text["Description"]
            assert im.text["Software"].startswith("IMPREsS workstation")
    head = (tmp_path / "a" / "pointcloud.ply").read_bytes().split(b"end_header")[0]
    assert b"every 2 cell(s) of the 0.1 mm grid" in head and video_sha.encode() in head


def test_cancel_leaves_the_previous_result(flat_scan, flat_calibration, tmp_path):
    out = tmp_path / "out"
    process_files(flat_scan / "scan.mp4", flat_calibration, out,
                  ProcessParams(frame_start=40, frame_stop=80, texture=False))
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    token = CancelToken()

    def progress(frac, msg):
        if frac > 0.2:
            token.cancel()

    with pytest.raises(Cancelled):
        process_files(flat_scan / "scan.mp4", flat_calibration, out, ProcessParams(),
                      progress=progress, cancel=token)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_truncated_video_is_a_clear_error(flat_scan, flat_calibration, tmp_path):
    data = (flat_scan / "scan.mp4").read_bytes()
    bad = tmp_path / "truncated.mp4"
    bad.write_bytes(data[: len(data) // 2])
    with pytest.raises(VideoError) as exc:
        process_files(bad, flat_calibration, tmp_path / "out", ProcessParams(texture=False))
    assert exc.value.code in ("E-VIDEO-TRUNCATED", "E-VIDEO-OPEN")
    assert not (tmp_path / "out").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["truncated.mp4"]


def test_wrong_file_and_size_mismatch(flat_scan, flat_calibration, tmp_path):
    notvideo = tmp_path / "notes.mp4"
    notvideo.write_text("this is not a video")
    with pytest.raises(VideoError, match="not a readable video"):
        process_files(notvideo, flat_calibration, tmp_path / "o1", ProcessParams())
    frames = tmp_path / "frames"
    frames.mkdir()
    import cv2

    for k in range(3):
        cv2.imwrite(str(frames / f"f{k}.png"), np.zeros((180, 320, 3), np.uint8))
    from impress_gui.core.base.errors import InputError

    with pytest.raises(InputError, match="640x360"):
        process_files(frames, flat_calibration, tmp_path / "o2", ProcessParams())


def test_no_stripe_is_reported_with_laser_and_frames(flat_calibration, tmp_path):
    import cv2

    frames = tmp_path / "dark"
    frames.mkdir()
    rng = np.random.default_rng(0)
    for k in range(20):
        cv2.imwrite(str(frames / f"f{k:03d}.png"), rng.integers(40, 90, (360, 640, 3), np.uint8))
    with pytest.raises(ReconstructionError, match="stripe was never found in frames"):
        process_files(frames, flat_calibration, tmp_path / "out",
                      ProcessParams(frame_start=0, frame_stop=20, texture=False))
    assert not (tmp_path / "out").exists()
    shutil.rmtree(frames)


def test_upsampling_puts_neighbouring_points_at_most_one_cell_apart(flat_calibration):
    """The points per pixel step are the fewest that keep neighbouring profile points within
    one cell along each axis on the deepest surface of the height range."""
    from impress_gui.core.reconstruction.reconstruct import (
        _band_rays,
        column_bands,
        laser_rois,
        upsampling,
    )

    cal = SceneCalibration.load(flat_calibration)
    w, h = cal.intrinsics.image_size
    rois = laser_rois(cal, (w, h), (-40.0, 60.0))
    rays = _band_rays(cal, column_bands(cal, (w, h), (-40.0, 60.0), rois)["red"], h)
    depth = float(cal.reference_depth(np.array(0.0), np.array(0.0))) + 40.0
    plan = rays[..., :2] / rays[..., 2:3] * depth
    widest = np.abs(np.diff(plan, axis=0)).max()
    for grid in (0.05, 0.1, 0.25):
        k = upsampling(rays, depth, grid)
        assert widest / k <= grid < widest / max(k - 1, 1e-9)
    # a coarse grid needs no upsampling
    assert upsampling(rays, depth, 10.0) == 1


def test_band_rays_kernel_equals_numpy_rays(flat_calibration):
    """The per-run ray tables (one compiled pass: undistortion from the neighbour's correction,
    then the rotation) agree with the numpy undistortion of every band pixel to 1e-12."""
    from impress_gui.core.reconstruction.reconstruct import _band_rays, column_bands, laser_rois

    cal = SceneCalibration.load(flat_calibration)
    w, h = cal.intrinsics.image_size
    assert np.abs(cal.intrinsics.dist_coeffs).max() > 1e-3  # a lens that does distort
    rois = laser_rois(cal, (w, h), (-40.0, 60.0))
    for name, (b0, bh) in column_bands(cal, (w, h), (-40.0, 60.0), rois).items():
        rays = _band_rays(cal, (b0, bh), h)
        assert rays.shape == (w, bh + 1, 3)
        cols = np.arange(0, w, 37)
        rows = np.minimum(b0[cols, None] + np.arange(bh + 1)[None, :], h - 1)
        uv = np.column_stack([np.repeat(cols, bh + 1), rows.ravel()]).astype(float)
        want = (cal.intrinsics.rays(uv) @ cal.rotation.T).reshape(len(cols), bh + 1, 3)
        np.testing.assert_allclose(rays[cols], want, rtol=0, atol=1e-12, err_msg=name)


def test_the_video_files_time_does_not_change_the_outputs(flat_scan, flat_calibration,
                                                         tmp_path):
    """The same video bytes give the same files whatever the file's modification time (a
    copy of the evidence): the X3P's dates come from the inputs' contents, and a video that
    states no recording date (the simulator's) gets the date that stands for unknown, said so
    in metadata.json (the audit of 4 December 2026: the X3P took the file's time)."""
    video = tmp_path / "scan.mp4"
    shutil.copyfile(flat_scan / "scan.mp4", video)
    outs = []
    for k, when in enumerate((1577836800, 1767225600)):  # 2020-01-01, 2026-01-01
        os.utime(video, (when, when))
        process_files(video, flat_calibration, tmp_path / f"out{k}",
                      ProcessParams(frame_start=40, frame_stop=50, texture=False))
        outs.append({p.name: p.read_bytes() for p in (tmp_path / f"out{k}").iterdir()
                     if p.name != "run.json"})
    assert outs[0] == outs[1]
    meta = json.loads(outs[0]["metadata.json"])
    assert meta["dates"]["measured"] == "1970-01-01T00:00:00Z"
    assert "not stated" in meta["dates"]["source"]
