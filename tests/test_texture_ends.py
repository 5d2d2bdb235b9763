"""The texture at the scan's ends (``fill_texture_ends``): the texture row through the image's
centre leaves the ends of the heightmap without colour (the lasers lead and trail it); the
first and last frames see them. On a small simulated scan: after the fill the texture reaches
as far as the heights at both ends, its colours agree with what the texture row itself sees
where both exist, and with the simulator's albedo."""

from __future__ import annotations

import json

import numpy as np
import pytest


@pytest.fixture(scope="module")
def flat_recon(tmp_path_factory):
    """A 100 mm flat-preset scan at 320x180 (the L target at its start), calibrated from the
    simulator's picks and reconstructed on a 0.5 mm grid, with its first and last frames."""
    from impress_gui.core.calibration.geometry import Intrinsics
    from impress_gui.core.calibration.picks import Picks
    from impress_gui.core.calibration.scene import calibrate_scene
    from impress_gui.core.calibration.target import TargetModel
    from impress_gui.core.formats.video import open_video
    from impress_gui.core.reconstruction.reconstruct import ProcessParams, reconstruct
    from impress_gui.core.reconstruction.texture import end_frame_indices
    from impress_gui.sim.simulate import SimConfig, simulate

    scan = tmp_path_factory.mktemp("texends") / "flat"
    simulate(SimConfig(preset="flat", length_mm=100.0, width=320, height=180, grid_mm=0.5),
             scan, workers=1)
    truth = json.loads((scan / "truth.json").read_text())
    with open_video(scan / "scan.mp4") as v:
        cal = calibrate_scene(v, Intrinsics.load(scan / "intrinsics.json"),
                              TargetModel.load(scan / "target.json"),
                              Picks.load(scan / "picks.json"), truth["speed_mm_s"])
        rec = reconstruct(v, cal, ProcessParams(grid_mm=0.5))
        travel = cal.travel_mm(np.asarray(v.times_s))
        # the frames reconstruct samples at each end: the first (last) processed frame and
        # one a little further in, whose stripes have left the ground under the end frame's
        picks = end_frame_indices(cal, travel, *rec.frames)
        assert picks[0][0] == rec.frames[0] and picks[1][0] == rec.frames[1] - 1
        assert len(picks[0]) == len(picks[1]) == 2
        ends = [[(float(travel[k]), v.read(int(k))) for k in p] for p in picks]
        # the same run with the texture row's colours only (the ends' fill left out)
        import impress_gui.core.reconstruction.reconstruct as R

        fill = R._texture_ends
        R._texture_ends = lambda *_a: 0
        try:
            row_only = reconstruct(v, cal, ProcessParams(grid_mm=0.5))
        finally:
            R._texture_ends = fill
    rec.row_only_texture = row_only.texture_rgb  # type: ignore[attr-defined]
    return scan, truth, cal, rec, ends


def _extent(mask: np.ndarray) -> tuple[int, int]:
    """First and last grid row where at least a fifth of the columns are set."""
    rows = np.flatnonzero(mask.mean(axis=1) >= 0.2)
    return int(rows[0]), int(rows[-1])


def _lum(rgb):
    return np.asarray(rgb, float) @ [0.299, 0.587, 0.114]


def test_the_texture_reaches_the_heights_ends(flat_recon):
    """The reconstruction's texture reaches within 3 mm of the heights at both ends (the
    texture row alone left centimetres black: the cells the fill coloured are counted in the
    run's statistics); the fill itself is deterministic and only colours cells without one."""
    from impress_gui.core.reconstruction.texture import fill_texture_ends

    _, _, cal, rec, ends = flat_recon
    p = rec.spec.pixel_mm
    h0, h1 = _extent(np.isfinite(rec.height_mm))
    f0, f1 = _extent(rec.texture_rgb.any(axis=2))
    assert (f0 - h0) * p <= 3.0 and (h1 - f1) * p <= 3.0, ((h0, h1), (f0, f1))
    # the texture row alone left centimetres without colour; the fill coloured those cells,
    # and only those, and the run counted them
    t0, t1 = _extent(rec.row_only_texture.any(axis=2))
    assert (t0 - h0) * p > 10 and (h1 - t1) * p > 10, ((h0, h1), (t0, t1))
    tex, filled = fill_texture_ends(rec.row_only_texture, rec.height_mm, rec.spec, cal, *ends)
    assert np.array_equal(tex, rec.texture_rgb)
    assert int(filled.sum()) == rec.stats["texture_end_cells_filled"] > 0
    assert not (filled & rec.row_only_texture.any(axis=2)).any()
    # deterministic, and a filled texture gets nothing more
    tex2, filled2 = fill_texture_ends(rec.row_only_texture, rec.height_mm, rec.spec, cal, *ends)
    assert np.array_equal(tex, tex2) and np.array_equal(filled, filled2)
    tex3, filled3 = fill_texture_ends(rec.texture_rgb, rec.height_mm, rec.spec, cal, *ends)
    assert np.array_equal(tex3, rec.texture_rgb) and not filled3.any()


def test_the_fill_by_small_blocks_of_cells_gives_the_same_texture(flat_recon, monkeypatch):
    """The end cells are projected by blocks (no arrays of millions of points): blocks of 997
    cells (hundreds of blocks here, the last one partial) colour the same cells the same."""
    import impress_gui.core.reconstruction.texture as texture

    _, _, cal, rec, ends = flat_recon
    assert rec.stats["texture_end_cells_filled"] > 50 * 997
    monkeypatch.setattr(texture, "_BLOCK", 997)
    tex, filled = texture.fill_texture_ends(rec.row_only_texture, rec.height_mm, rec.spec, cal,
                                            *ends)
    assert np.array_equal(tex, rec.texture_rgb)
    assert int(filled.sum()) == rec.stats["texture_end_cells_filled"]


def test_the_fill_by_small_blocks_of_rows_gives_the_same_texture(flat_recon, monkeypatch):
    """The first and last rows of the columns are found by blocks of rows from each end: rows
    of 7 (the last block partial) colour the same cells the same."""
    import impress_gui.core.reconstruction.texture as texture

    _, _, cal, rec, ends = flat_recon
    monkeypatch.setattr(texture, "_ROWS_BLOCK", 7)
    tex, filled = texture.fill_texture_ends(rec.row_only_texture, rec.height_mm, rec.spec, cal,
                                            *ends)
    assert np.array_equal(tex, rec.texture_rgb)
    assert int(filled.sum()) == rec.stats["texture_end_cells_filled"]


@pytest.mark.parametrize("block", [1, 3, 512])
def test_first_and_last_rows_by_blocks(block, monkeypatch):
    """Against argmax over the whole mask: columns hit in the first or last row, in one row
    only, on a block's edge, never."""
    import impress_gui.core.reconstruction.texture as texture

    monkeypatch.setattr(texture, "_ROWS_BLOCK", block)
    rng = np.random.default_rng(3)
    mask = rng.random((23, 40)) < 0.02
    mask[:, 0] = False  # never
    mask[0, 1] = mask[22, 2] = True  # first row, last row
    mask[:, 3] = False
    mask[9, 3] = True  # one row only
    first, last = texture._first_last_rows(23, lambda a, b: mask[a:b])
    has = mask.any(axis=0)
    assert np.array_equal(first, np.where(has, mask.argmax(axis=0), 23))
    assert np.array_equal(last, np.where(has, 22 - mask[::-1].argmax(axis=0), -1))


def test_the_filled_colours_are_registered(flat_recon):
    """Blank each column's first and last 15 mm of the texture row's colours and fill them
    from the end frames: they come back as the texture row saw them."""
    from impress_gui.core.reconstruction.texture import fill_texture_ends

    _, _, cal, rec, ends = flat_recon
    tex0 = rec.row_only_texture
    cov = tex0.any(axis=2)
    n = int(15 / rec.spec.pixel_mm)
    idx = np.arange(cov.shape[0])[:, None]
    first = np.where(cov, idx, cov.shape[0]).min(axis=0)
    last = np.where(cov, idx, -1).max(axis=0)
    for zone in ((idx < first + n) & cov, (idx > last - n) & cov):
        blank = tex0.copy()
        blank[zone] = 0
        tex, filled = fill_texture_ends(blank, rec.height_mm, rec.spec, cal, *ends)
        m = filled & zone
        assert m.sum() > 0.6 * zone.sum()
        a, b = _lum(tex[m]), _lum(tex0[m])
        assert np.corrcoef(a, b)[0, 1] > 0.9 and np.abs(a - b).mean() < 6.0


def test_the_filled_colours_match_the_albedo(flat_recon):
    """Against the simulator's albedo in 5 mm blocks (the soil's grain is finer than the
    320x180 camera resolves): the filled ends show its pattern, at its brightness and in its
    place along the scan."""
    import cv2

    from impress_gui.core.reconstruction.texture import fill_texture_ends

    scan, truth, cal, rec, ends = flat_recon
    tex, filled = fill_texture_ends(rec.row_only_texture, rec.height_mm, rec.spec, cal, *ends)
    albedo = cv2.cvtColor(cv2.imread(str(scan / "truth_texture.png")), cv2.COLOR_BGR2RGB)
    hm = truth["heightmap"]
    sp = rec.spec
    ii, jj = np.nonzero(tex.any(axis=2))
    # the reconstruction's rail frame starts at frame t1, the simulator's at frame 0
    y = sp.y0_mm + ii * sp.pixel_mm + float(truth["travel_mm"][cal.t1])
    x = sp.x0_mm + jj * sp.pixel_mm
    ti = np.rint((y - hm["y0_mm"]) / hm["pixel_mm"]).astype(int)
    tj = np.rint((x - hm["x0_mm"]) / hm["pixel_mm"]).astype(int)
    ok = (ti >= 0) & (ti < albedo.shape[0]) & (tj >= 0) & (tj < albedo.shape[1])
    ii, jj, ti, tj = ii[ok], jj[ok], ti[ok], tj[ok]
    block = int(5 / sp.pixel_mm)

    def corr(sel, shift_mm=0.0):
        ti_s = np.clip(ti + int(round(shift_mm / hm["pixel_mm"])), 0, albedo.shape[0] - 1)
        key = (ii[sel] // block) * 10_000 + jj[sel] // block
        _, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
        a = np.bincount(inv, _lum(tex[ii[sel], jj[sel]])) / cnt
        b = np.bincount(inv, _lum(albedo[ti_s[sel], tj[sel]])) / cnt
        full = cnt >= 0.5 * block * block
        return float(np.corrcoef(a[full], b[full])[0, 1]), float(np.mean(a[full] - b[full]))

    row, _ = corr(~filled[ii, jj])
    assert row > 0.9, row
    mid = tex.shape[0] // 2
    for sel in (filled[ii, jj] & (ii < mid), filled[ii, jj] & (ii > mid)):
        c0, bias = corr(sel)
        # the albedo's pattern is there (measured 0.58 and 0.40 at 320x180 from the first
        # and last processed frames: the ends are seen at the picture's edges, near the
        # stripes' halo, a few pixels per 5 mm block; the texture row itself: 0.95), at the
        # albedo's brightness ...
        assert c0 > 0.3 and abs(bias) < 10, (c0, bias)
        # ... and in its place: no shift along the scan agrees better
        assert c0 >= max(corr(sel, d)[0] for d in (-3.0, -2.0, 2.0, 3.0)) - 0.02


def _end_zones(row_only: np.ndarray, height: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cells at the scan's ends the texture row never reached (per column of the grid,
    before its first row or after its last): those with a height, and those without one that
    lie between the heights' end and the texture's (the lasers' shadow of a tall face)."""
    cov = row_only.any(axis=2)
    fin = np.isfinite(height)
    n = cov.shape[0]
    idx = np.arange(n)[:, None]
    has = cov.any(axis=0)[None, :]
    first = np.where(cov, idx, n).min(axis=0)[None, :]
    last = np.where(cov, idx, -1).max(axis=0)[None, :]
    h_first = np.where(fin, idx, n).min(axis=0)[None, :]
    h_last = np.where(fin, idx, -1).max(axis=0)[None, :]
    before, after = idx < first, idx > last
    ends = has & (before | after)
    shadow = ends & ~fin & ((before & (idx >= h_first)) | (after & (idx <= h_last)))
    return ends & fin, shadow


def _block_albedo(scan, truth, cal, rec, tex, sel, block_mm=5.0):
    """Mean luminance of ``tex`` and of the simulator's albedo over the cells ``sel`` in
    ``block_mm`` blocks (blocks at least half covered): their correlation and mean bias."""
    import cv2

    albedo = cv2.cvtColor(cv2.imread(str(scan / "truth_texture.png")), cv2.COLOR_BGR2RGB)
    hm, sp = truth["heightmap"], rec.spec
    ii, jj = np.nonzero(sel)
    y = sp.y0_mm + ii * sp.pixel_mm + float(truth["travel_mm"][cal.t1])
    x = sp.x0_mm + jj * sp.pixel_mm
    ti = np.rint((y - hm["y0_mm"]) / hm["pixel_mm"]).astype(int)
    tj = np.rint((x - hm["x0_mm"]) / hm["pixel_mm"]).astype(int)
    ok = (ti >= 0) & (ti < albedo.shape[0]) & (tj >= 0) & (tj < albedo.shape[1])
    ii, jj, ti, tj = ii[ok], jj[ok], ti[ok], tj[ok]
    block = int(block_mm / sp.pixel_mm)
    key = (ii // block) * 10_000 + jj // block
    _, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
    a = np.bincount(inv, _lum(tex[ii, jj])) / cnt
    b = np.bincount(inv, _lum(albedo[ti, tj])) / cnt
    full = cnt >= 0.5 * block * block
    return float(np.corrcoef(a[full], b[full])[0, 1]), float(np.mean(a[full] - b[full])), \
        int(full.sum())


def test_no_black_under_the_end_frames_stripes_or_in_the_targets_shadow(flat_recon):
    """The black patches at the scan's start (issue 21): the first frame's laser stripes lie
    on the first cells with heights, which its stripe mask left black; and the ground the
    lasers cannot see before and after the L target's high face (no heights) stayed black
    though the camera sees it. Now the cells under the end frame's stripes are sampled in a
    frame a little further in, the shadow at the reference as the texture row maps it inside
    the scan: next to nothing stays black at the ends, and the colours are the albedo's."""
    from impress_gui.core.reconstruction.texture import fill_texture_ends

    scan, truth, cal, rec, ends = flat_recon
    with_h, shadow = _end_zones(rec.row_only_texture, rec.height_mm)
    black = ~rec.texture_rgb.any(axis=2)
    # with one frame per end (before): the cells under its stripes stay black
    one, _ = fill_texture_ends(rec.row_only_texture, rec.height_mm, rec.spec, cal,
                               ends[0][:1], ends[1][:1])
    black_one = ~one.any(axis=2)
    # measured on this scan: 78528 end cells with heights, none black (one frame per end:
    # 4743 black, 6 %); 4399 cells of shadow, none black (before: all)
    assert with_h.sum() > 1000 and black[with_h].mean() < 0.005, black[with_h].sum()
    assert black_one[with_h].mean() > 0.02  # the stripes' cells: the second frame filled them
    assert shadow.sum() > 500 and black[shadow].mean() < 0.02, black[shadow].sum()
    # the shadow's colours are the ground's albedo (measured: correlation 0.99 over 45 blocks
    # of 5 mm, 6 grey levels darker)
    c, bias, n = _block_albedo(scan, truth, cal, rec, rec.texture_rgb, shadow)
    assert n >= 10 and c > 0.8 and abs(bias) < 10, (c, bias, n)
