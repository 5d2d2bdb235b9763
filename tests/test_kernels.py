"""The compiled kernels against the readable numpy they replace."""

import numpy as np
import pytest

from impress_gui.core.calibration.scene import SceneCalibration
from impress_gui.core.formats.video import Planes, open_video
from impress_gui.core.reconstruction.grid import fuse
from impress_gui.core.reconstruction.reconstruct import column_bands, laser_rois
from impress_gui.core.reconstruction.stripes import (
    LASERS,
    METHODS,
    BackgroundLUT,
    StripeParams,
    detect_planes,
    detect_planes_numpy,
)


@pytest.fixture(scope="module")
def frames(flat_scan, flat_calibration):
    cal = SceneCalibration.load(flat_calibration)
    with open_video(flat_scan / "scan.mp4") as v:
        w, h = v.size
        rois = laser_rois(cal, (w, h), (-40.0, 60.0))
        bands = column_bands(cal, (w, h), (-40.0, 60.0), rois)
        lut = BackgroundLUT()
        for k in v.quick_frames(0, v.frame_count, 6):
            lut.learn(v.read(k), list(rois.values()))
        n = v.frame_count
        raw = list(v.iter_planes(n // 3, n // 3 + 4))
        # and frames converted from RGB (full-resolution chroma), as a frame folder gives
        rgb = [Planes.from_rgb(v.read(k)) for k in (n // 2, 2 * n // 3)]
    return rois, bands, lut, [p for _, p in raw] + rgb


@pytest.mark.parametrize("method", METHODS)
def test_detect_kernel_equals_numpy_reference(frames, method):
    rois, bands, lut, planes = frames
    params = StripeParams(method=method, rois=rois)
    found = 0
    for p in planes:
        for name in LASERS:
            b0, bh = bands[name]
            o0, oh = bands[next(m for m in LASERS if m != name)]
            # the other laser's band with one height, and with each column's own (as the
            # reconstruction passes it: reconstruct._own_band), here each column's cut by
            # up to a third of the band
            own = oh - (np.arange(len(o0)) * 7919) % (oh // 3)
            for other in ((o0, oh), (o0, own)):
                a = detect_planes(name, p, b0, bh, params, lut, other)
                b = detect_planes_numpy(name, p, b0, bh, params, lut, other)
                fa, fb = np.isfinite(a.rows), np.isfinite(b.rows)
                # the same columns found (a rare rounding tie in the colour tests may differ)
                assert (fa != fb).sum() <= 2
                both = fa & fb
                assert np.abs(a.rows[both] - b.rows[both]).max() < 1e-6
                assert np.allclose(a.strength[both], b.strength[both], atol=1e-3)
                found += both.sum()
    assert found > 0.5 * 2 * len(planes) * len(LASERS) * planes[0].y.shape[1]


def _profile_reference(rows, tri, max_step, k, min_cols, upsample):
    """The numpy steps the compiled ``stripe_profile`` replaces: connected columns, then
    (``tri`` triangulates) single-column spikes dropped, then the upsampled profile."""
    d = np.abs(np.diff(rows))
    link = np.isfinite(d) & (d <= 2.0)
    valid = np.zeros(rows.shape, bool)
    valid[:-1] |= link
    valid[1:] |= link
    if valid.sum() < min_cols:
        return valid, None
    x, y, h = tri(valid)
    a, b, c = h[:-2], h[1:-1], h[2:]
    med = np.maximum(np.minimum(a, b), np.minimum(np.maximum(a, b), c))
    hd = h.copy()
    hd[1:-1][(np.abs(b - med) > max_step) & np.isfinite(med)] = np.nan
    return valid, upsample(x, y, hd, valid & np.isfinite(hd), k, max_step)


def test_stripe_profile_kernel_equals_numpy_steps(frames, flat_calibration):
    """Connected columns, triangulation, despiking and upsampling in one compiled call give
    what the numpy steps give, bit for bit - on real stripes, and with spikes, gaps and
    isolated hits added."""
    from impress_gui.core.reconstruction.compiled import kernels
    from impress_gui.core.reconstruction.reconstruct import _band_rays
    from impress_gui.core.reconstruction.texture import reference_coeffs

    kern = kernels()
    cal = SceneCalibration.load(flat_calibration)
    rois, bands, lut, planes = frames
    params = StripeParams(method="combined", rois=rois)
    h_img, w = planes[0].y.shape
    ref = reference_coeffs(cal)
    rng = np.random.default_rng(3)
    k, max_step = 3, 0.8
    n_up = (w - 1) * k + 1
    checked = 0
    for p in planes[:3]:
        for name in LASERS:
            b0, bh = bands[name]
            rays = _band_rays(cal, bands[name], h_img)
            plane = cal.planes[name].plane
            rows = detect_planes(name, p, b0, bh, params, lut).rows.copy()
            variants = [rows]
            noisy = rows.copy()
            hit = rng.choice(w, 40, replace=False)
            noisy[hit] += rng.choice([-9.0, 9.0], 40)  # spikes
            noisy[rng.choice(w, 60, replace=False)] = np.nan  # gaps
            variants.append(noisy)
            sparse = np.full(w, np.nan)
            sparse[::7] = rows[::7]  # isolated hits only: no stripe
            variants.append(sparse)
            for r in variants:
                def tri(valid, r=r, b0=b0, rays=rays, plane=plane):
                    x, y, hh = np.empty(w), np.empty(w), np.empty(w)
                    kern.triangulate(r, valid, b0, rays, plane.normal, float(plane.offset_mm),
                                     12.5, 0.0, ref, x, y, hh)
                    return x, y, hh

                def ups(x, y, hh, ok, k_, step):
                    out = (np.empty(n_up), np.empty(n_up), np.empty(n_up), np.empty(n_up, bool))
                    kern.upsample(x, y, hh, ok, k_, step, *out)
                    return out

                min_cols = int(0.02 * w)
                want_valid, want = _profile_reference(r, tri, max_step, k, min_cols, ups)
                valid, x, y, hh = np.empty(w, bool), np.empty(w), np.empty(w), np.empty(w)
                got = (np.empty(n_up), np.empty(n_up), np.empty(n_up), np.empty(n_up, bool))
                y_range = np.empty(2)
                n_ok = kern.stripe_profile(r, 2.0, min_cols, b0, rays, plane.normal,
                                           float(plane.offset_mm), 12.5, 0.0, ref, max_step, k,
                                           valid, x, y, hh, *got, y_range)
                assert n_ok == want_valid.sum()
                assert np.array_equal(valid, want_valid)
                if want is None:
                    assert n_ok < min_cols and np.isnan(y_range).all()
                    continue
                for a_, b_ in zip(got, want):
                    assert np.array_equal(a_, b_, equal_nan=True)
                yv = want[1][want[3]]
                assert tuple(y_range) == (yv.min(), yv.max())
                checked += 1
    assert checked == 12  # two variants with a stripe, per laser and frame


def test_detect_kernel_refuses_lut_without_background(frames):
    rois, bands, _, planes = frames
    b0, bh = bands["red"]
    with pytest.raises(Exception, match="lookup-table"):
        detect_planes("red", planes[0], b0, bh, StripeParams(method="lut", rois=rois), None)


def _fuse_reference(g, r, tol):
    """The previous numpy implementation of grid.fuse."""
    from scipy.ndimage import uniform_filter

    g_ok, r_ok = np.isfinite(g), np.isfinite(r)
    diff = np.where(g_ok & r_ok, g - r, np.nan).astype(np.float32)
    fused = np.full(g.shape, np.nan, np.float32)
    contrib = np.zeros(g.shape, np.uint8)
    fused[g_ok & ~r_ok], contrib[g_ok & ~r_ok] = g[g_ok & ~r_ok], 1
    fused[r_ok & ~g_ok], contrib[r_ok & ~g_ok] = r[r_ok & ~g_ok], 2
    agree = g_ok & r_ok & (np.abs(diff) <= tol)
    fused[agree], contrib[agree] = 0.5 * (g[agree] + r[agree]), 3
    conflict = g_ok & r_ok & ~agree
    base = np.where(np.isfinite(fused), fused, 0.0)
    w = uniform_filter(np.isfinite(fused).astype(np.float64), 7)
    local = uniform_filter(base.astype(np.float64), 7) / np.maximum(w, 1e-9)
    pick_g = np.abs(g - local) <= np.abs(r - local)
    fused[conflict] = np.where(pick_g, g, r)[conflict]
    contrib[conflict] = 4
    return fused, diff, contrib


def test_fuse_codes_and_consensus():
    rng = np.random.default_rng(3)
    g = rng.normal(5.0, 0.1, (60, 80)).astype(np.float32)
    r = (g + rng.normal(0, 0.1, g.shape)).astype(np.float32)
    g[rng.random(g.shape) < 0.2] = np.nan
    r[rng.random(r.shape) < 0.2] = np.nan
    # outliers of either laser (a reflection, a shadow edge), also at the map's border
    for i, j in [(10, 10), (0, 0), (59, 79), (30, 0)]:
        g[i, j], r[i, j] = 5.0, 9.0
    for i, j in [(20, 40), (59, 3)]:
        g[i, j], r[i, j] = -3.0, 5.0
    fused, diff, contrib = fuse(g, r, 0.5)
    ref = _fuse_reference(g, r, 0.5)
    assert np.array_equal(contrib, ref[2])
    assert np.allclose(fused, ref[0], equal_nan=True, atol=1e-6)
    assert np.allclose(diff, ref[1], equal_nan=True)
    assert fused[10, 10] == 5.0 and fused[0, 0] == 5.0 and fused[20, 40] == 5.0
    assert contrib[10, 10] == 4
    assert set(np.unique(contrib)) == {0, 1, 2, 3, 4}


def _texture_inputs(n_rows=300, n_pts=600):
    from impress_gui.core.reconstruction.grid import ColorAccumulator, GridSpec
    from impress_gui.core.reconstruction.texture import RowSpool

    rng = np.random.default_rng(5)
    spool = RowSpool()
    for k in range(n_rows):
        spool.append(k, rng.uniform(0, 255, (n_pts, 3)))
    travel = 0.5 * np.arange(n_rows)
    xn = np.linspace(-0.3, 0.3, n_pts)
    rays = np.column_stack([xn, np.full(n_pts, 0.02), np.ones(n_pts)])
    spec = GridSpec(-130.0, -30.0, 0.25, (800, 1040))
    height = np.where(rng.random(spec.shape) < 0.7, rng.normal(5, 2, spec.shape), np.nan)

    ref = np.array([400.0, 0.0, 0.0])  # a flat reference 400 mm below the camera
    return spool, rays, travel, height.astype(np.float32), spec, ref, ColorAccumulator(spec, 1.6)


def test_texture_mapping_split_between_threads_equals_one_thread(monkeypatch):
    from impress_gui.core.reconstruction import kernels
    from impress_gui.core.reconstruction import texture as rc

    results = []
    for plan in ("auto", "single", "too tight"):
        spool, rays, travel, height, spec, ref, acc = _texture_inputs()
        ranges = set()

        def spy(*args, _real=kernels.texture_rows, _seen=ranges):
            _seen.add(args[-2:])
            return _real(*args)

        monkeypatch.setattr(kernels, "texture_rows", spy)
        if plan == "single":
            monkeypatch.setattr(rc, "texture_split", lambda *a, **k: None)
        elif plan == "too tight":  # no overlap: rows near the middle reach both halves
            i_mid = int(round((travel[150] - spec.y0_mm) / spec.pixel_mm))
            tight = (((0, 150), (0, 150), (0, i_mid)),
                     ((150, 300), (150, 300), (i_mid, spec.shape[0])))
            monkeypatch.setattr(rc, "texture_split", lambda *a, _plan=tight, **k: _plan)
        else:
            assert rc.texture_split(travel, rays[:, 0], rays[:, 1], np.array([400.0, 0, 0]),
                                     spec, 1.6) is not None
        tex = rc.map_texture(spool, rays, travel, height, spec, ref, acc, chunk=16)
        results.append((tex, acc.sum.copy(), acc.count.copy()))
        whole = (0, spec.shape[0])
        # split: two halves and no rerun; too tight: the halves, then one thread over all
        assert (whole in ranges) == (plan != "auto")
        assert (len(ranges - {whole, (0, 0)}) == 2) == (plan != "single")
        spool.close()
        monkeypatch.undo()
    for other in results[1:]:
        for a, b in zip(results[0], other):
            assert np.array_equal(a, b)
    tex, total, count = results[0]
    assert np.isfinite(total).all() and (count > 0).mean() > 0.4
