"""Exported geometry is right-handed: a raised letter F, scanned by the simulator, reads as an F
(never its mirror image) in the PLY and the X3P, read back by readers not written here
(plyfile, open3d, surfalize), compared with the truth under a translation only.

The truth is seen from above (+z towards the viewer) in a right-handed frame: x along the
image's columns, y = -rail Y (so that the image's first rows have the largest y)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from impress_gui.core.reconstruction.grid import GridSpec

pytestmark = pytest.mark.slow

RASTER_MM = 1.0
BAND_MM = (3.0, 8.5)  # the letter is 6 mm high; the target's faces are 11 and 40 mm


# ``letter_scan`` (conftest.py): the scan of the letter preset and its reconstruction, made
# once a run (test_cast.py uses the same)


def _truth_points(scan, out) -> np.ndarray:
    """The letter's true cells as (x, y) in the right-handed export frame, mm."""
    from impress_gui.sim.truth import truth_on_grid

    meta = json.loads((out / "metadata.json").read_text())
    g = meta["grid"]
    spec = GridSpec(g["x0_mm"], g["y0_mm"], g["pixel_mm"], tuple(g["shape"]))
    th = truth_on_grid(scan, spec)
    ii, jj = np.nonzero((th > BAND_MM[0]) & (th < BAND_MM[1]))
    return np.column_stack([spec.x0_mm + jj * spec.pixel_mm,
                            -(spec.y0_mm + ii * spec.pixel_mm)])


def _letter_only(pts: np.ndarray, truth: np.ndarray, margin: float = 15.0) -> np.ndarray:
    """Points within the letter's neighbourhood, found from the points' own cluster: the
    densest 1 mm cells in the height band, around the median (translation-free)."""
    c = np.median(pts, axis=0)
    half = (truth.max(axis=0) - truth.min(axis=0)) / 2 + margin
    keep = np.all(np.abs(pts - c) <= half, axis=1)
    return pts[keep]


def _mask(pts: np.ndarray, centre: np.ndarray, half: float = 70.0) -> np.ndarray:
    n = int(2 * half / RASTER_MM)
    ij = np.floor((pts - centre + half) / RASTER_MM).astype(int)
    ok = np.all((ij >= 0) & (ij < n), axis=1)
    m = np.zeros((n, n), bool)
    m[ij[ok, 1], ij[ok, 0]] = True
    return m


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


def _chirality(points_xy: np.ndarray, truth_xy: np.ndarray) -> dict[str, float]:
    """IoU of the exported letter with the truth, after matching centroids (a translation),
    as it is and under the two mirror images."""
    pts = _letter_only(points_xy, truth_xy)
    cp, ct = pts.mean(axis=0), truth_xy.mean(axis=0)
    p = _mask(pts, cp)
    out = {}
    for name, flip in (("as is", (1, 1)), ("mirror x", (-1, 1)), ("mirror y", (1, -1))):
        t = (truth_xy - ct) * np.array(flip) + ct
        out[name] = _iou(p, _mask(t, ct))
    return out


def _check(scores: dict[str, float]) -> None:
    assert scores["as is"] > 0.8, scores
    assert scores["mirror x"] < 0.6 and scores["mirror y"] < 0.6, scores


def _band(xyz: np.ndarray) -> np.ndarray:
    z = xyz[:, 2]
    return xyz[(z > BAND_MM[0]) & (z < BAND_MM[1]), :2]


def test_ply_read_by_plyfile_is_not_mirrored(letter_scan):
    from plyfile import PlyData

    scan, out = letter_scan
    ply = PlyData.read(str(out / "pointcloud.ply"))
    v = ply["vertex"]
    xyz = np.column_stack([v["x"], v["y"], v["z"]]).astype(float)
    assert any("right-handed" in c for c in ply.comments)
    _check(_chirality(_band(xyz), _truth_points(scan, out)))


def test_ply_read_by_open3d_is_not_mirrored(letter_scan):
    import open3d as o3d

    scan, out = letter_scan
    xyz = np.asarray(o3d.io.read_point_cloud(str(out / "pointcloud.ply")).points)
    _check(_chirality(_band(xyz), _truth_points(scan, out)))


def test_x3p_read_by_surfalize_is_not_mirrored(letter_scan):
    from surfalize import Surface

    scan, out = letter_scan
    s = Surface.load(str(out / "heightmap.x3p"))
    z_mm = np.asarray(s.data, float) * 1e-3  # surfalize: micrometres
    ii, jj = np.nonzero(np.isfinite(z_mm))
    # an X3P's point k of row i lies at x = k * step_x, y = i * step_y (plus offsets)
    xyz = np.column_stack([jj * s.step_x * 1e-3, ii * s.step_y * 1e-3, z_mm[ii, jj]])
    _check(_chirality(_band(xyz), _truth_points(scan, out)))


def test_the_mirrored_convention_would_be_caught(letter_scan):
    """The check itself can fail: the old left-handed PLY (y = +rail Y) is a mirror image."""
    from plyfile import PlyData

    scan, out = letter_scan
    v = PlyData.read(str(out / "pointcloud.ply"))["vertex"]
    xyz = np.column_stack([v["x"], -np.asarray(v["y"]), v["z"]]).astype(float)
    scores = _chirality(_band(xyz), _truth_points(scan, out))
    assert scores["as is"] < 0.6 and scores["mirror y"] > 0.8, scores


def test_every_tiff_carries_its_cell_size_and_sources(letter_scan):
    """Issue 21 item 11: the TIFFs of `impress process` state their pixel size (read back by
    tifffile) and name their inputs' hashes."""
    import tifffile

    _scan, out = letter_scan
    meta = json.loads((out / "metadata.json").read_text())
    for name in ("heightmap.tif", "height_green.tif", "height_red.tif", "difference.tif",
                 "contribution.tif"):
        with tifffile.TiffFile(out / name) as tf:
            page = tf.pages[0]
            num, den = page.tags["XResolution"].value
            assert page.tags["ResolutionUnit"].value == 3  # centimetre
            assert 10.0 / (num / den) == pytest.approx(meta["grid"]["pixel_mm"])
            assert meta["inputs"]["video"]["sha256"] in page.description


def test_tiffs_read_back_equal_by_pillow_and_tifffile(letter_scan):
    """Issue 19: the float maps are deflate TIFFs with the floating-point predictor (chosen for
    size: 16 % smaller at the same speed); Pillow (libtiff, not written here) and tifffile read
    every one back to the same values, NaN cells included, and the PNG views agree with them."""
    import tifffile
    from PIL import Image

    _scan, out = letter_scan
    fused = None
    for name in ("heightmap.tif", "height_green.tif", "height_red.tif", "difference.tif",
                 "contribution.tif"):
        a = tifffile.imread(out / name)
        with tifffile.TiffFile(out / name) as tf:
            assert tf.pages[0].compression == 8  # Adobe deflate
            assert tf.pages[0].predictor == (3 if a.dtype == np.float32 else 1)
        with Image.open(out / name) as im:
            b = np.asarray(im)
        assert b.dtype == a.dtype and b.shape == a.shape
        assert np.array_equal(a, b, equal_nan=True), name
        fused = a if name == "heightmap.tif" else fused
    assert fused is not None and np.isfinite(fused).mean() > 0.5
    with Image.open(out / "heightmap_8bit.png") as im:
        grey = np.asarray(im).astype(int)
    ok = np.isfinite(fused)
    expect = np.clip(np.rint(fused[ok] / 0.1) + 128, 0, 255)
    assert np.abs(grey[ok] - expect).max() <= 1  # float32 file against float64 at writing
    assert (grey[~ok] == 0).all()


def test_writing_reports_progress_within_files(letter_scan, tmp_path):
    """Issue 19: while the outputs are written the progress moves inside the slowest file (the
    X3P, by pieces of rows), not only when a file is finished, and never goes back."""
    from impress_gui.core.formats import writers
    from impress_gui.core.measure.readings import load_reconstruction

    _scan, out = letter_scan
    data = load_reconstruction(out)
    rec = _FakeRec(data)
    seen: list[tuple[float, str]] = []
    writers.write_reconstruction(rec, tmp_path / "again", {"inputs": {}}, {},
                                 progress=lambda f, m: seen.append((f, m)))
    fractions = [f for f, _ in seen]
    assert fractions == sorted(fractions) and fractions[-1] == 1.0
    assert all(" of 11 files)" in m for _, m in seen[:-1])
    # the X3P reports its pieces of rows: its checksum pass, then every piece written
    done: list[float] = []
    rows = 3 * writers.X3P_ROWS_PER_CHUNK + 5
    writers.x3p_bytes(rec.spec, np.zeros((rows, 7)), "2026-01-01T00:00:00Z", done=done.append)
    assert done == sorted(done) and done[-1] == 1.0 and len(done) == 8
    assert done[3] == pytest.approx(0.1)


class _FakeRec:
    """A reconstruction's arrays as read back from its folder (what the writer needs)."""

    def __init__(self, data) -> None:
        self.spec = data.spec
        self.height_mm = data.layers["fused"].astype(np.float64)
        self.per_laser_mm = {k: data.layers[k] for k in ("green", "red")}
        self.difference_mm = data.layers["difference"]
        self.contribution = data.layers["contribution"]
        self.texture_rgb = data.texture_rgb
