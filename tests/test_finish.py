"""Finishing the grid during the frame loop (core/reconstruction/finish.py): the same result as finishing
everything after the loop, bit for bit, and the fallback when an assumption fails."""

import time

import numpy as np
import pytest

from impress_gui.core.calibration.scene import SceneCalibration
from impress_gui.core.formats.video import open_video
from impress_gui.core.reconstruction import finish as fin
from impress_gui.core.reconstruction import reconstruct as rc
from impress_gui.core.reconstruction.grid import fuse, fuse_rows
from impress_gui.core.reconstruction.reconstruct import ProcessParams, reconstruct

pytestmark = pytest.mark.usefixtures("no_stray_threads")


def _maps(seed=7, shape=(90, 70)):
    rng = np.random.default_rng(seed)
    g = rng.normal(5.0, 0.1, shape).astype(np.float32)
    r = (g + rng.normal(0, 0.3, shape)).astype(np.float32)  # many disagreements
    g[rng.random(shape) < 0.2] = np.nan
    r[rng.random(shape) < 0.2] = np.nan
    return g, r


@pytest.mark.parametrize("direction", [1, -1])
def test_fusing_band_by_band_equals_fusing_at_once(direction):
    g, r = _maps()
    whole = fuse(g, r, 0.5)
    assert (whole[2] == 4).sum() > 100  # the consensus pass matters here
    out = [np.full(g.shape, 77, t) for t in (np.float32, np.float32, np.uint8)]
    h = g.shape[0]
    edges = [0, 5, 6, 31, 47, 80, h]
    bands = list(zip(edges[:-1], edges[1:]))
    if direction < 0:
        bands = [(h - b, h - a) for a, b in bands]
    done = 0  # rows whose first pass is complete, in band order
    resolved = 0
    for a, b in bands:
        fuse_rows(g, r, 0.5, *out, a, b, resolve=(0, 0))
        done += b - a
        ready = done - 3 if done < h else h  # conflicts need 3 rows beyond them
        lo, hi = (resolved, ready) if direction > 0 else (h - ready, h - resolved)
        if ready > resolved:
            fuse_rows(g, r, 0.5, *out, 0, 0, resolve=(lo, hi))
            resolved = ready
    for a, b in zip(whole, out):
        assert np.array_equal(a, b, equal_nan=True)


def _run(flat_scan, flat_calibration, monkeypatch, mode):
    if mode == "during the loop, in step":
        # the worker's share of rows depends on how busy the machine is; here each frame's
        # rows are finished before the next frame is read, so the share is the method's own
        def in_step(self, travel):
            if self._thread is not None:
                self._advance(travel)

        monkeypatch.setattr(fin.RowFinisher, "post", in_step)
    elif mode == "after the loop":
        monkeypatch.setattr(rc, "_direction", lambda travel: 0)
    elif mode == "offsets too narrow":
        real = fin.RowFinisher.__init__

        def narrow(self, spec, acc, tol, offsets, *a, **kw):  # as if all points lay on one line
            real(self, spec, acc, tol, {n: (0.5 * (lo + hi),) * 2
                                        for n, (lo, hi) in offsets.items()}, *a, **kw)

        monkeypatch.setattr(fin.RowFinisher, "__init__", narrow)
    elif mode == "texture reach too short":
        monkeypatch.setattr(fin, "texture_reach", lambda *a: -2.0)
    elif mode == "texture ring too small":
        monkeypatch.setattr(fin.RowFinisher, "_texture_ring", lambda self, travel: 16)
    cal = SceneCalibration.load(flat_calibration)
    with open_video(flat_scan / "scan.mp4") as v:
        rec = reconstruct(v, cal, ProcessParams())
    monkeypatch.undo()
    return rec


def test_finishing_during_the_loop_equals_finishing_after_it(flat_scan, flat_calibration,
                                                              monkeypatch):
    runs = {m: _run(flat_scan, flat_calibration, monkeypatch, m)
            for m in ("during the loop", "during the loop, in step", "after the loop",
                      "offsets too narrow", "texture reach too short", "texture ring too small")}
    streamed = runs["during the loop"]
    # most of the grid can be finished while frames are still being read (how much the worker
    # thread gets done meanwhile depends on the machine's load, so it is counted in step)
    assert runs["during the loop, in step"].stats["rows_finished_in_loop"] > 0.3
    assert "finished_after_loop" not in streamed.stats
    assert runs["after the loop"].stats["rows_finished_in_loop"] == 0
    # a profile outside its laser's offsets is noticed, and everything is redone afterwards
    assert "outside its offsets" in runs["offsets too narrow"].stats["finished_after_loop"]
    # texture rows averaged too early get late samples: noticed, and redone afterwards
    assert "texture samples" in runs["texture reach too short"].stats["finished_after_loop"]
    # colour sums held for too few rows: samples beyond them are noticed, everything redone
    assert "beyond the rows held" in runs["texture ring too small"].stats["finished_after_loop"]
    for other in ("during the loop, in step", "after the loop", "offsets too narrow", "texture reach too short",
                  "texture ring too small"):
        rec = runs[other]
        for a, b in [(streamed.height_mm, rec.height_mm), (streamed.difference_mm, rec.difference_mm),
                     (streamed.contribution, rec.contribution), (streamed.texture_rgb, rec.texture_rgb),
                     *[(streamed.per_laser_mm[n], rec.per_laser_mm[n]) for n in rc.LASERS]]:
            assert np.array_equal(a, b, equal_nan=True), other
    assert np.isfinite(streamed.height_mm).mean() > 0.3
    assert streamed.texture_rgb.any()


def test_stripe_offsets_bound_every_triangulated_point(flat_scan, flat_calibration):
    """The offsets from the ray tables contain every stripe point the loop produced."""
    cal = SceneCalibration.load(flat_calibration)
    seen = {}
    real = fin.RowFinisher.check_range

    def spy(self, name, travel, y_range):
        if np.isfinite(y_range[0]):
            lo, hi = seen.get(name, (np.inf, -np.inf))
            seen[name] = (min(lo, y_range[0] - travel), max(hi, y_range[1] - travel))
        return real(self, name, travel, y_range)

    mp = pytest.MonkeyPatch()
    mp.setattr(fin.RowFinisher, "check_range", spy)
    captured = {}
    real_init = fin.RowFinisher.__init__

    def init(self, spec, acc, tol, offsets, direction, texture=None, **kw):
        captured.update(offsets)
        real_init(self, spec, acc, tol, offsets, direction, texture, **kw)

    mp.setattr(fin.RowFinisher, "__init__", init)
    try:
        with open_video(flat_scan / "scan.mp4") as v:
            reconstruct(v, cal, ProcessParams(texture=False))
    finally:
        mp.undo()
    for name, (lo, hi) in seen.items():
        off_lo, off_hi = captured[name]
        assert off_lo <= lo and hi <= off_hi
        # and the bound is tight enough to be useful (within a few cm of what was seen)
        assert (lo - off_lo) + (off_hi - hi) < 60.0


@pytest.mark.parametrize("direction", [1, -1])
def test_finisher_in_either_direction_equals_finishing_at_once(direction):
    """Synthetic accumulators already holding every sample; the finisher is told the camera's
    travel frame by frame (forwards or backwards) and must end with what finishing everything
    at once gives, having done most rows before the end."""
    from impress_gui.core.reconstruction.grid import ColorAccumulator, GridSpec, HeightAccumulator
    from impress_gui.core.reconstruction.texture import RowSpool

    rng = np.random.default_rng(11)
    spec = GridSpec(-60.0, -40.0, 0.25, (1200, 480))
    n_frames = 500
    travel = np.arange(n_frames) * 0.5
    if direction < 0:
        travel = travel[::-1].copy()
    results = []
    for streamed in (True, False):
        rng = np.random.default_rng(11)
        acc = {n: HeightAccumulator(spec, 1.6, 2.0) for n in rc.LASERS}
        for a in acc.values():
            a.count[:] = rng.integers(0, 3, spec.shape)
            a.sum[:] = a.count * rng.normal(5, 0.4, spec.shape)
        spool = RowSpool()
        n_pts = 300
        for k in range(n_frames):
            spool.append(k, rng.uniform(0, 255, (n_pts, 3)))
        xn = np.linspace(-0.1, 0.1, n_pts)
        rays = np.column_stack([xn, np.full(n_pts, 0.01), np.ones(n_pts)])
        tex = fin.TextureInputs(spool, rays, travel, np.array([300.0, 0.0, 0.0]),
                                ColorAccumulator(spec, 1.6))
        f = fin.RowFinisher(spec, acc, 0.5, {"green": (-30.0, -10.0), "red": (10.0, 30.0)},
                            direction if streamed else 0, tex)
        try:
            for k in range(n_frames):
                f.post(float(travel[k]))
                while streamed and k % 25 == 0 and f._pending is not None:  # step by step
                    time.sleep(0.001)
            deadline = time.monotonic() + 120  # generous: the worker shares a busy machine
            while streamed and f.n_mean < 0.5 * spec.shape[0] and time.monotonic() < deadline:
                time.sleep(0.01)
            f.finish()
        finally:
            f.close()
            spool.close()
        assert f.broken is None
        if streamed:
            assert f.rows_during_loop > 0.5 * spec.shape[0]
            # the colour sums were held for a few hundred rows at a time, not the whole grid
            assert f._tex_acc is not None and f._tex_acc.rows < spec.shape[0] // 2
        results.append((f.per["green"], f.per["red"], f.fused, f.diff, f.contrib, f.tex))
    for a, b in zip(*results):
        assert np.array_equal(a, b, equal_nan=True)
    assert (results[0][4] == 4).any() and np.isfinite(results[0][2]).mean() > 0.5
    assert (results[0][5] > 0).mean() > 0.3  # a texture was mapped


@pytest.mark.parametrize("direction", [1, -1])
def test_bridged_misses_are_added_before_their_rows_are_finished(direction):
    """Profiles added frame by frame while the finisher works behind them; some columns are
    missed in single frames, so the accumulator fills them from the frame before the miss,
    reaching behind the previous frame: the finisher's lag must leave those rows open (the
    maps equal finishing everything after the loop)."""
    from impress_gui.core.reconstruction.grid import GridSpec, HeightAccumulator

    spec = GridSpec(-10.0, -10.0, 0.1, (800, 200))
    n_frames, step = 60, 1.0
    travel = np.arange(n_frames) * step
    if direction < 0:
        travel = travel[::-1].copy()
    offsets = {"green": (-5.2, -4.8), "red": (4.8, 5.2)}  # tight: the points span them
    x = np.linspace(-9.0, 9.0, 181)
    rng = np.random.default_rng(5)
    miss = {k: rng.choice(181, 6, replace=False) for k in range(n_frames) if k % 3 == 1}
    results = []
    for streamed in (True, False):
        acc = {n: HeightAccumulator(spec, 2.5 * step + 0.3, 0.8, 4) for n in rc.LASERS}
        f = fin.RowFinisher(spec, acc, 0.5, offsets, direction if streamed else 0)
        try:
            for k, t in enumerate(travel):
                for n, (lo, hi) in offsets.items():
                    valid = np.ones(len(x), bool)
                    valid[miss.get(k, [])] = False
                    y = t + 0.5 * (lo + hi) + 0.2 * np.sin(x)
                    acc[n].add_profile(x, y, 1.0 + 0.01 * x, valid)
                f.post(float(t))
                while streamed and f._pending is not None:  # one step at a time
                    time.sleep(0.0005)
            f.finish()
        finally:
            f.close()
        assert f.broken is None
        if streamed:
            assert f.rows_during_loop > 0.3 * spec.shape[0]
        results.append((f.per["green"].copy(), f.per["red"].copy(), f.fused.copy()))
    for a, b in zip(*results):
        assert np.array_equal(a, b, equal_nan=True)
    # the misses were bridged: no hole where a column was missed in one frame
    assert np.isfinite(results[1][0][:, 20:180]).mean() > 0.5
