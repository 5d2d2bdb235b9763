"""Reconstruction: scan video + scene calibration -> per-laser and fused heightmaps, registered
texture and point cloud on one rail-frame grid.

Streaming: a decoder thread feeds a bounded queue (it starts at once, while the run's tables
are prepared); each frame is reduced at once to two stripe profiles and one texture row, so
memory does not grow with the video's length (only the output grids, which grow with the
scanned area). Grid rows the lasers have left behind are finished - means, fusion, texture -
by a worker thread during the loop (:mod:`impress_gui.core.reconstruction.finish`).
"""

from __future__ import annotations

import importlib
import math
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass, field

import numpy as np

from impress_gui.core.base import codes
from impress_gui.core.base.errors import (
    ImpressError,
    InputError,
    ReconstructionError,
    VideoError,
)
from impress_gui.core.base.progress import CancelToken, ProgressCallback, report
from impress_gui.core.calibration.scene import SceneCalibration, check_plane_distances
from impress_gui.core.formats.video import VideoSource
from impress_gui.core.reconstruction.agreement import (
    agreement_warnings,
    laser_agreement,
    reconcile,
)
from impress_gui.core.reconstruction.compiled import kernels as _kernels
from impress_gui.core.reconstruction.finish import RowFinisher, TextureInputs, stripe_footprint
from impress_gui.core.reconstruction.grid import (
    ColorAccumulator,
    GridSpec,
    HeightAccumulator,
    drop_floating,
    drop_islands,
    drop_overreach,
    fuse_rows,
)
from impress_gui.core.reconstruction.stripes import (
    LASERS,
    METHODS,
    SUBPIXEL,
    BackgroundLUT,
    StripeDetector,
    StripeParams,
    StripeResult,
    shared_light,
)
from impress_gui.core.reconstruction.texture import (
    RowSpool,
    end_frame_indices,
    fill_texture_ends,
    reference_coeffs,
)
from impress_gui.core.reconstruction.unlit import UnlitSoil


@dataclass(frozen=True)
class ProcessParams:
    """Processing parameters (all recorded in the output's metadata)."""

    method: str = "combined"
    frame_start: int | None = None  # first frame (default: after the start ramp)
    frame_stop: int | None = None  # one past the last frame
    grid_mm: float = 0.1
    height_range_mm: tuple[float, float] = (-40.0, 60.0)  # for automatic regions of interest
    rois: dict[str, tuple[int, int]] = field(default_factory=dict)  # rows; empty = automatic
    min_peak: float = 25.0
    fuse_tolerance_mm: float = 0.5
    max_step_mm: float = 0.8  # larger jumps between neighbours are edges, not slopes
    texture: bool = True
    lut_frames: int = 12
    # a stripe piece shorter than LONG_RUN_FRACTION of the image width whose mean strength is
    # below this share of the frame's typical stripe strength is dropped (0: keep every piece)
    weak_run_ratio: float = 0.5
    # the stripe centre's sub-pixel estimate (stripes.SUBPIXEL): "window" (the centre of mass
    # above half maximum refined by stripes.window_refine; docs/accuracy.md) or "half-max"
    subpixel: str = "window"
    # islands of at most this many cells of a laser's map, cut off from their surroundings by
    # steps larger than island_step_mm (or by cells without data), are dropped before the
    # maps are fused: a false stripe's few cells float millimetres off the surface (grid.
    # drop_islands; 0 keeps them)
    island_max_cells: int = 50
    island_step_mm: float = 0.5
    # then floating pieces of at most floating_max_cells cells (joined as the islands are)
    # with at most floating_support of the cells within floating_radius_mm around them
    # holding data in either laser's map are dropped: where a laser's light is shadowed off
    # the ground its detector may take the soil's texture for the stripe (grid.
    # drop_floating; docs/accuracy.md, "Floating pieces in a laser's shadow"; 0 keeps them)
    floating_max_cells: int = 400
    floating_radius_mm: float = 2.0
    floating_support: float = 0.15
    # the soil under the stripe, seen unlit in earlier frames, subtracted from its profile
    # before the centre is estimated again (unlit.UnlitSoil; docs/accuracy.md, "Dim stripes
    # on grainy soil"): on by default since 2026-12-04 (0.7 of the unlit texture taken out:
    # better on 17 of 24 random rigs, worse on none)
    unlit_soil: bool = True
    # the part of the two lasers' difference that runs across the map (a laser plane turned
    # about an axis across its stripe) shared between their maps by the fusion's weights
    # (agreement.reconcile; docs/accuracy.md, "The lasers reconciled across the map"): on by
    # default since 2026-12-07
    reconcile_lasers: bool = True

    def validate(self) -> None:
        if self.method not in METHODS:
            raise InputError(f"unknown detection method {self.method!r} (use one of "
                             f"{', '.join(METHODS)})", code=codes.E_PARAM)
        if not 0.01 <= self.grid_mm <= 5.0:
            raise InputError("grid resolution must be between 0.01 and 5 mm", code=codes.E_PARAM)
        lo, hi = self.height_range_mm
        if not lo < hi:
            raise InputError("height range must be (low, high) with low < high", code=codes.E_PARAM)
        if self.frame_start is not None and self.frame_start < 0:
            raise InputError("the first frame must not be negative", code=codes.E_PARAM)
        if (self.frame_start is not None and self.frame_stop is not None
                and self.frame_stop <= self.frame_start):
            raise InputError("the frame range is empty", code=codes.E_PARAM)
        if self.subpixel not in SUBPIXEL:
            raise InputError(f"unknown sub-pixel estimate {self.subpixel!r} (use one of "
                             f"{', '.join(SUBPIXEL)})", code=codes.E_PARAM)
        if not 0.0 <= self.weak_run_ratio < 1.0:
            raise InputError("the weak-run ratio must be in 0..1 (0 keeps every stripe piece)",
                             code=codes.E_PARAM)
        if not 0 <= self.island_max_cells <= 10000:
            raise InputError("the largest island dropped must be 0 (none) to 10000 cells",
                             code=codes.E_PARAM)
        if not 0.01 <= self.island_step_mm <= 100.0:
            raise InputError("the step around a dropped island must be 0.01 to 100 mm",
                             code=codes.E_PARAM)
        if not 0 <= self.floating_max_cells <= 10000:
            raise InputError("the largest floating piece dropped must be 0 (none) to 10000 "
                             "cells", code=codes.E_PARAM)
        if not 0.0 < self.floating_radius_mm <= 50.0:
            raise InputError("the ring looked at around a floating piece must be wider than 0 "
                             "and at most 50 mm", code=codes.E_PARAM)
        if not 0.0 <= self.floating_support < 1.0:
            raise InputError("the share of data around a floating piece must be in 0..1",
                             code=codes.E_PARAM)

    def to_json(self) -> dict:
        d = asdict(self)
        d["height_range_mm"] = list(self.height_range_mm)
        d["rois"] = {k: list(v) for k, v in self.rois.items()}
        return d


@dataclass
class Reconstruction:
    """A finished reconstruction. ``stats`` mixes figures of the result (deterministic) and of
    the run (timings, how far the finishing got during the loop): :meth:`run_stats` and
    :meth:`result_stats` separate them."""

    spec: GridSpec
    height_mm: np.ndarray  # fused, float32, NaN = no data
    per_laser_mm: dict[str, np.ndarray]
    difference_mm: np.ndarray
    contribution: np.ndarray  # uint8 codes, see grid.fuse
    texture_rgb: np.ndarray | None
    frames: tuple[int, int]
    rois: dict[str, tuple[int, int]]
    stats: dict
    warnings: list[str]

    #: statistics that depend on the run (timing, machine load), not only on the inputs
    RUN_KEYS = ("frames_per_second", "rows_finished_in_loop", "finished_after_loop")

    def run_stats(self) -> dict:
        return {k: v for k, v in self.stats.items() if k.startswith("seconds")
                or k in self.RUN_KEYS}

    def result_stats(self) -> dict:
        run = self.run_stats()
        return {k: v for k, v in self.stats.items() if k not in run}


def _stripe_uv(cal: SceneCalibration, size: tuple[int, int], name: str, height_mm: float,
               n_points: int = 65) -> np.ndarray:
    """Image points ``(u, v)`` of the laser's line on a level surface ``height_mm`` above the
    reference, sampled across the view (the points inside the image's columns)."""
    w, _ = size
    uv = _line_uv(cal, name, height_mm, w / cal.intrinsics.fx, n_points)
    return uv[(uv[:, 0] >= 0) & (uv[:, 0] < w)]


#: drop the cells a laser's chain end reaches across an edge (grid.drop_overreach; False only
#: to compare with the code before 2026-12-06's eighth session)
DROP_OVERREACH = True

#: leave out the points of a laser's line past the lens's fold radius (:meth:`Intrinsics.
#: fold_radius`) when projecting it (False only to compare with the code before 2026-12-06)
LENS_FOLD = True


def _line_uv(cal: SceneCalibration, name: str, height_mm: float, half_width: float,
             n_points: int) -> np.ndarray:
    """Image points ``(u, v)`` of laser ``name``'s line on a level surface ``height_mm``
    above the reference, sampled at ``n_points`` across ``+-half_width`` times the depth in
    the ideal frame's X, without the points a barrel lens folds back into the picture (past
    its fold radius: their projection lands among the real points')."""
    plane = cal.planes[name].plane
    # points of the plane at this height below the camera, across the image
    z = float(cal.reference_depth(np.array(0.0), np.array(0.0))) - height_mm
    # ideal-frame line: plane n.X = d with Z = z -> sample X across the view
    xs = np.linspace(-half_width * z, half_width * z, n_points)
    n, d = plane.normal, plane.offset_mm
    ys = (d - n[0] * xs - n[2] * z) / n[1]
    cam = np.column_stack([xs, ys, np.full_like(xs, z)]) @ cal.rotation
    if LENS_FOLD:
        rad = np.hypot(cam[:, 0], cam[:, 1]) / np.where(cam[:, 2] > 0, cam[:, 2], np.nan)
        keep = rad < cal.intrinsics.fold_radius()
        if keep.sum() >= 2:
            cam = cam[keep]
    return cal.intrinsics.project(cam)


def _stripe_rows(cal: SceneCalibration, size: tuple[int, int], name: str,
                 height_mm: float) -> np.ndarray:
    """Image rows of the laser's line on a level surface ``height_mm`` above the reference,
    sampled across the view (the points inside the image's columns)."""
    return _stripe_uv(cal, size, name, height_mm)[:, 1]


def height_per_pixel(cal: SceneCalibration, size: tuple[int, int]) -> dict[str, float]:
    """Per laser, the height (mm) one pixel of stripe shift means on the reference surface:
    where the surface rises by 1 mm the stripe moves across itself by ``d`` pixels (the shift
    along the image column times the cosine of the stripe's slope in the picture: the
    detector's noise is across the stripe's line); the median of ``1 / d`` over the stripe's
    points inside the picture (NaN where it has too few)."""
    w, h = size
    out = {}
    for name in LASERS:
        a, b = (uv[(uv[:, 1] >= 0) & (uv[:, 1] < h)]
                for uv in (_stripe_uv(cal, size, name, 0.0, 257),
                           _stripe_uv(cal, size, name, 1.0, 257)))
        if len(a) < 8 or len(b) < 8:
            out[name] = float("nan")
            continue
        lo, hi = max(a[:, 0].min(), b[:, 0].min()), min(a[:, 0].max(), b[:, 0].max())
        if hi - lo < 0.05 * w:
            out[name] = float("nan")
            continue
        cols = np.linspace(lo, hi, 65)
        oa, ob = np.argsort(a[:, 0]), np.argsort(b[:, 0])
        va = np.interp(cols, a[oa, 0], a[oa, 1])
        dv = np.abs(np.interp(cols, b[ob, 0], b[ob, 1]) - va)
        d = dv / np.sqrt(1.0 + np.gradient(va, cols) ** 2)
        med = float(np.median(d))
        out[name] = 1.0 / med if med > 0 else float("nan")
    return out


def fusion_weight(cal: SceneCalibration, size: tuple[int, int]) -> float:
    """The green laser's weight in the mean of two agreeing lasers (``grid.fuse``, code 3):
    inverse-variance weights for equal noise in image rows, ``s_r**2 / (s_g**2 + s_r**2)``
    with ``s`` each laser's :func:`height_per_pixel`. A laser whose light plane meets the
    camera's rays at a shallow angle turns the detector's row noise into more height noise:
    on random rig 14 (issue 18) green's 1.67 mm per pixel against red's 0.67. 0.5 when either
    is unknown."""
    s = height_per_pixel(cal, size)
    g, r = s["green"], s["red"]
    if not (np.isfinite(g) and np.isfinite(r)) or g + r <= 0:
        return 0.5
    return float(r * r / (g * g + r * r))


#: the rows of the regions of interest from the laser's line in every column, and their cut
#: kept CUT_CLEAR_PX rows clear of either stripe on the ground (False only to compare with
#: the code before 2026-12-06: sampled points, and random rig 201's red ground stripe cut 2
#: rows inside in its first 31 columns)
ROWS_DENSE = True
CUT_CLEAR_PX = 4


def laser_rois(cal: SceneCalibration, size: tuple[int, int], height_range_mm) -> dict:
    """Rows where each laser's stripe can appear for surfaces within the height range.

    Where the two bands overlap they are split halfway through the overlap, so that neither
    detector searches the rows where the other's stripe lies on the ground - unless that row
    crosses either stripe on the reference surface (height 0), or passes within
    ``CUT_CLEAR_PX`` rows of one (the stripe's own width; both taken from the line's row in
    every column, :func:`_column_rows`): a stripe running across the
    picture (a rolled camera) spans many rows, and the cut then lost part of it in every frame
    (random rig 8: the red stripe's left 80 columns, 2 % of the map; rig 7 at 1080p: the fill
    98.9 %). Then the bands are left overlapping: each column's band (:func:`column_bands`)
    limits the search, and in the other laser's band the detector's lean test keeps its light
    apart. Without any cut, rig 23's red detector took parts of a green stripe blooming on
    warm soil (wild points 0.16 %); a cut halfway between the two stripes on the ground lost
    the red stripe on its raised target."""
    w, h = size
    out = {name: _roi_rows(cal, size, name, height_range_mm) for name in LASERS}
    g, r = out["green"], out["red"]
    if g[0] < r[1] and r[0] < g[1]:  # overlapping bands
        lo, hi = sorted(LASERS, key=lambda n: sum(out[n]))
        cut = (out[lo][1] + out[hi][0]) // 2
        cut -= cut % 2
        ground = [_stripe_rows(cal, size, n, 0.0) for n in LASERS]
        clear = 0
        if ROWS_DENSE:
            ground = [np.concatenate([v, _column_rows(cal, n, w, 0.0)])
                      for v, n in zip(ground, LASERS, strict=True)]
            clear = CUT_CLEAR_PX
        if not any(len(v) and v.min() - clear <= cut <= v.max() + clear for v in ground):
            out[lo] = (out[lo][0], cut)
            out[hi] = (cut, out[hi][1])
    return out


def _roi_rows(cal: SceneCalibration, size: tuple[int, int], name: str,
              height_range_mm) -> tuple[int, int]:
    """The first row and the row after the last (even, within the picture) where laser
    ``name``'s stripe can fall on surfaces within the height range, 8 rows added on either
    side, before :func:`laser_rois` splits overlapping bands."""
    w, h = size
    rows = np.concatenate([_stripe_rows(cal, size, name, hgt) for hgt in height_range_mm])
    if not len(rows):
        raise ReconstructionError(f"the {name} laser's stripe falls outside the image",
                                  code=codes.E_NO_STRIPE)
    if ROWS_DENSE:
        # the line's rows in every column: its points sampled 30-60 columns apart missed up
        # to 14 rows of a slanted stripe at the picture's edge (random rig 8 at 1080p)
        rows = np.concatenate([rows] + [_column_rows(cal, name, w, float(hgt))
                                        for hgt in height_range_mm])
    a = int(np.floor(rows.min())) - 8
    b = int(np.ceil(rows.max())) + 9
    return max(0, a - a % 2), min(h, b + b % 2)


def column_bands(cal: SceneCalibration, size: tuple[int, int], height_range_mm,
                 rois: dict[str, tuple[int, int]] | None = None, margin_px: int = 8):
    """Per laser, the first row to search in every column and the band height: where the
    stripe can fall for surfaces within the height range (clipped to ``rois`` when given).
    The band height is the largest column's: in the other columns the band reaches beyond
    the height range (:func:`column_band_limits` has each column's own end)."""
    return {name: (start, int(max(1, (stop - start).max())))
            for name, (start, stop) in column_band_limits(cal, size, height_range_mm, rois,
                                                          margin_px, unfolded=False).items()}


def column_band_limits(cal: SceneCalibration, size: tuple[int, int], height_range_mm,
                       rois: dict[str, tuple[int, int]] | None = None, margin_px: int = 8,
                       unfolded: bool = True) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per laser, each column's first row and the row after its last where the stripe can
    fall for surfaces within the height range, ``margin_px`` rows added on either side
    (clipped to ``rois`` when given). ``unfolded=False``: as the search bands have been
    made since before 2026-12-06 (:func:`column_bands`; :func:`_column_rows`)."""
    w, h = size
    out = {}
    lo_h, hi_h = height_range_mm
    for name in LASERS:
        rmin = np.full(w, np.inf)
        rmax = np.full(w, -np.inf)
        for hgt in np.linspace(lo_h, hi_h, 9):
            # unfolded: the rows of the whole line as well (where the line's projection
            # turns back for another reason than the lens - a stripe running nearly along
            # the image columns - the unfolded stretch is short; rigs 23 and 66 lost 5 and
            # 3 % of a laser's map with it alone)
            for uf in {False, unfolded}:
                r = _column_rows(cal, name, w, float(hgt), uf)
                rmin, rmax = np.minimum(rmin, r), np.maximum(rmax, r)
        start = np.floor(rmin).astype(np.int64) - margin_px
        stop = np.ceil(rmax).astype(np.int64) + margin_px + 1
        if rois and name in rois:
            a, b = rois[name]
            start, stop = np.maximum(start, a), np.minimum(stop, b)
        start = np.clip(start, 0, h - 1)
        stop = np.clip(stop, start + 1, h)
        out[name] = (start, stop)
    return out


def _column_rows(cal: SceneCalibration, name: str, w: int, height_mm: float,
                 unfolded: bool = False) -> np.ndarray:
    """The row in each of ``w`` columns where laser ``name``'s stripe falls on a flat surface
    ``height_mm`` above the calibration's ground (level at the reference point).
    ``unfolded``: only the line's points up to where its projection turns back (a lens's
    barrel distortion folds points far outside the view back into the picture's edge
    columns, where they mix with the real ones; random rig 65: the ground's rows up to 135
    rows off in 178 of the picture's last 410 columns), as :func:`column_band_limits` needs
    them."""
    uv = _line_uv(cal, name, height_mm, 1.2 * w / cal.intrinsics.fx, 257)
    if unfolded:
        u = uv[:, 0]
        # the stretch around the point nearest the picture's centre column where u keeps
        # moving the same way
        mid = int(np.argmin(np.abs(u - 0.5 * w)))
        mid = min(mid, len(u) - 2)
        step = np.sign(np.diff(u))
        way = step[mid] if step[mid] != 0 else 1.0
        lo, hi = mid, mid + 1
        while lo > 0 and step[lo - 1] == way:
            lo -= 1
        while hi < len(u) - 1 and step[hi] == way:
            hi += 1
        uv = uv[lo:hi + 1]
    order = np.argsort(uv[:, 0])
    return np.interp(np.arange(w, dtype=np.float64), uv[order, 0], uv[order, 1])


def ground_rows(cal: SceneCalibration, size: tuple[int, int]) -> dict[str, np.ndarray]:
    """Per laser, the row in every column where its stripe falls on a surface at height 0
    (the calibration's ground)."""
    return {name: _column_rows(cal, name, size[0], 0.0) for name in LASERS}


class _Frames:
    """Decoded frames as ``(index, Planes)`` from a background thread, through a bounded
    queue."""

    def __init__(self, video, start: int, stop: int, cancel: CancelToken, depth: int = 6,
                 keep: tuple[int, ...] = ()):
        """Start decoding ``video`` (owned from now on: closed by :meth:`close`). ``keep``:
        frames also kept as RGB (:attr:`kept`, complete once the frames are consumed)."""
        self.q: queue.Queue = queue.Queue(maxsize=depth)
        self.video, self.start, self.stop, self.cancel = video, start, stop, cancel
        self.kept: dict[int, np.ndarray | None] = dict.fromkeys(keep)
        self.error: BaseException | None = None
        self._stop = False
        self.thread = threading.Thread(target=self._run, name="impress-decode", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            for k, frame in self.video.iter_planes(self.start, self.stop, self.kept):
                if self.cancel.cancelled or self._stop:
                    break
                self.q.put((k, frame))
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer
            self.error = exc
        finally:
            self.q.put(None)

    def __iter__(self):
        while True:
            item = self.q.get()
            if item is None:
                if self.error is not None:
                    raise self.error
                return
            yield item

    def limit(self, depth: int) -> None:
        """Hold at most ``depth`` decoded frames from now on."""
        with self.q.mutex:
            self.q.maxsize = depth

    def close(self) -> None:
        self._stop = True
        while self.thread.is_alive():
            try:
                self.q.get(timeout=0.1)
            except queue.Empty:
                pass
        self.thread.join()
        self.video.close()


def learn_background(video, start: int, stop: int, rois: dict, n_frames: int,
                     cancel: CancelToken | None = None, threads: int = 1) -> BackgroundLUT:
    """The background lookup tables from about ``n_frames`` frames spread over the range
    (keyframes: cheap to read, decoded on ``threads`` threads), outside the lasers' regions
    of interest."""
    lut = BackgroundLUT()
    ks = video.quick_frames(start, stop, n_frames)
    for a in range(0, len(ks), 4):  # a few at a time: a cancel is seen soon
        if cancel is not None:
            cancel.check()
        for rgb in video.read_many(ks[a : a + 4], threads):
            lut.learn(rgb, list(rois.values()))
    return lut


def _default_range(video, params: ProcessParams) -> tuple[int, int]:
    n = video.frame_count
    start = params.frame_start if params.frame_start is not None else min(n - 1, int(round(0.5 * video.fps)))
    stop = params.frame_stop if params.frame_stop is not None else max(start + 1, n - int(round(0.5 * video.fps)))
    if start >= n:
        raise InputError(f"the first frame {start} is beyond the video's {n} frames",
                         code=codes.E_FRAME_RANGE)
    return start, min(stop, n)


def reconstruct(video, cal: SceneCalibration, params: ProcessParams = ProcessParams(),
                progress: ProgressCallback | None = None, cancel: CancelToken | None = None,
                preview=None, preview_every_s: float | None = None) -> Reconstruction:
    """Run the whole reconstruction on an open video.

    ``preview``, if given, is called about every ``preview_every_s`` seconds (default
    :data:`PREVIEW_EVERY_S`) with a small
    (longest side <= 480 cells) float32 heightmap of what has been measured so far (mean of
    the two lasers, NaN where nothing yet) - for a display that grows during the run."""
    spool = RowSpool() if params.texture else None
    try:
        every = PREVIEW_EVERY_S if preview_every_s is None else preview_every_s
        return _reconstruct(video, cal, params, progress, cancel, spool, preview, every)
    finally:
        if spool is not None:
            spool.close()


PREVIEW_EVERY_S = 1.5


#: a stripe found in fewer of the picture's columns than this (on average over the frames in
#: which it is found at all) is reported: the method is losing most of the data
LOW_COLUMN_SHARE = 0.5


def _preview_step(shape) -> int:
    return max(1, int(np.ceil(max(shape) / 480)))


def _preview_spec(spec: GridSpec, preview: np.ndarray) -> GridSpec:
    """The grid of a decimated preview map (same origin, larger cells)."""
    step = _preview_step(spec.shape)
    return GridSpec(spec.x0_mm, spec.y0_mm, spec.pixel_mm * step, preview.shape)


def _preview_map(acc: dict) -> np.ndarray:
    """Decimated mean height over both lasers' accumulators so far."""
    shape = next(iter(acc.values())).sum.shape
    step = _preview_step(shape)
    total = sum(a.sum[::step, ::step].astype(np.float32) for a in acc.values())
    count = sum(a.count[::step, ::step].astype(np.float32) for a in acc.values())
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / count, np.nan).astype(np.float32)


def _reconstruct(video, cal, params, progress, cancel, spool, preview=None,
                 preview_every_s: float = 1.5) -> Reconstruction:
    params.validate()
    # a calibration whose plane passes through the camera (made before such planes were
    # refused, or edited) cannot triangulate that laser: refused before any work
    check_plane_distances(cal.planes)
    cancel = cancel or CancelToken()
    t_start = time.perf_counter()
    w, h = video.size
    cal.intrinsics.check_image_size(w, h)
    start, stop = _default_range(video, params)
    rois = dict(params.rois) or laser_rois(cal, (w, h), params.height_range_mm)
    sp = StripeParams(method=params.method, rois=rois, min_peak=params.min_peak,
                      subpixel=params.subpixel)
    sp.validate(h)
    # the background tables (the seed's LUT method) are learned from keyframes spread over
    # the range, through the caller's reader, beside everything else; decoding starts at once
    # on a second reader, into a deeper queue while the run's tables are prepared
    with ThreadPoolExecutor(1, thread_name_prefix="impress-lut") as pool:
        lut = pool.submit(learn_background, video, start, stop, rois, params.lut_frames,
                          cancel, 2) if params.method in ("lut", "combined") else None
        if params.texture:  # what colours the texture's ends, imported during the loop
            pool.submit(importlib.import_module, "scipy.ndimage")
        # the frames the texture's ends are coloured from are kept as they are decoded
        # (seeking them again after the loop took 2.7 s of a 3.2 s finish, without progress)
        ends = (end_frame_indices(cal, cal.travel_mm(video.times_s), start, stop)
                if params.texture else ([], []))
        frames = _Frames(video.clone(DECODE_THREADS), start, stop, cancel, SETUP_QUEUE_FRAMES,
                         keep=tuple(sorted({*ends[0], *ends[1]})))
        try:
            return _process(_Run(
                video=video, cal=cal, params=params, frames=frames, start=start, stop=stop,
                rois=rois, stripe_params=sp, lut_job=lut, progress=progress, cancel=cancel,
                spool=spool, preview=preview, preview_every_s=preview_every_s,
                t_start=t_start))
        finally:
            frames.close()


#: decoding threads of the main pass: frame threading with more threads than cores keeps both
#: cores busy (H.264 frames wait on their references; on this 2-core machine decoding alone
#: uses 1.6 cores with 2-4 threads, 1.9 with 8; docs/accuracy.md)
DECODE_THREADS = 8
#: frames decoded ahead while the run is being prepared (~3 MB each at 1080p), and after
SETUP_QUEUE_FRAMES = 24
LOOP_QUEUE_FRAMES = 8


@dataclass(frozen=True)
class _Run:
    """What one run works with once its decoder has started (fixed for the run)."""

    video: VideoSource
    cal: SceneCalibration
    params: ProcessParams
    frames: _Frames
    start: int
    stop: int  # one past the last frame
    rois: dict[str, tuple[int, int]]
    stripe_params: StripeParams
    lut_job: Future | None  # the background tables, being learned
    progress: ProgressCallback | None
    cancel: CancelToken
    spool: RowSpool | None  # the texture rows (None: no texture)
    preview: Callable | None
    preview_every_s: float
    t_start: float

    @property
    def n_frames(self) -> int:
        return self.stop - self.start


@dataclass(frozen=True)
class _Tables:
    """What the frame loop reads, prepared once per run from the calibration."""

    spec: GridSpec  # the output grid
    travel: np.ndarray  # camera travel (mm) of every frame of the video
    ref: np.ndarray  # the reference surface's depth coefficients
    bands: dict[str, tuple[np.ndarray, int]]  # per laser: first row per column, band height
    rays: dict[str, np.ndarray]  # per laser: rail-frame rays through its band
    k_up: int  # profile points per pixel step
    offsets: dict[str, tuple[float, float]]  # per laser: stripe points' y - travel range
    max_gap_mm: float  # profiles farther apart than this are not joined
    texture: _TextureRow | None
    #: a rolling shutter: the camera's travel (mm) from one image row's exposure to the next
    #: (0: a global shutter)
    row_mm: float = 0.0
    #: the texture row's travel per frame (its image row's, under a rolling shutter)
    texture_travel: np.ndarray | None = None
    #: per laser: each column's first row and the row after its last where its stripe can
    #: fall for surfaces within the height range (column_band_limits; the band searched, as
    #: high as its largest column's, reaches beyond it in the others)
    limits: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    #: per laser: its band column by column as the other laser's detector knows it (first
    #: row, rows; _own_band)
    others: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)


@dataclass(frozen=True)
class _TextureRow:
    """The texture's source: the row through the principal point after undistortion, sampled
    in every frame into the spool."""

    spool: RowSpool  # the rows sampled so far
    rays: np.ndarray  # rail-frame rays of the samples
    sample: tuple  # bilinear sampling positions: (u0, v0, fu, fv)
    colours: np.ndarray  # one frame's samples (reused frame after frame)


def _tables(run: _Run) -> _Tables:
    """The grid's extent and sampling, the lasers' bands and rays, the texture row's
    sampling."""
    cal, params, (start, stop) = run.cal, run.params, (run.start, run.stop)
    w, h = run.video.size
    travel = cal.travel_mm(run.video.times_s)
    intr, rot = cal.intrinsics, cal.rotation
    per_frame_travel = float(np.median(np.abs(np.diff(travel[start:stop])))) if stop - start > 1 else 0.1
    z_ref0 = float(cal.reference_depth(np.array(0.0), np.array(0.0)))
    # the deepest surface of the height range: where neighbouring pixels lie farthest apart
    z_deep = z_ref0 - min(params.height_range_mm[0], 0.0)
    bands = column_bands(cal, (w, h), params.height_range_mm, run.rois)
    # each column's own rows for the height range, regions of interest aside: the automatic
    # ones cut overlapping bands halfway, and the band searched, as high as its largest
    # column's, reaches past that cut where a column needs it (rig 201: red's stripe on the
    # ground 2 rows past the cut in its first 31 columns)
    limits = column_band_limits(cal, (w, h), params.height_range_mm)
    # the other laser's band for the lean test: its rows for the height range column by
    # column, clipped to the regions of interest like the band searched (without the clip
    # the automatic cut between overlapping bands is undone, and the lean test refuses a
    # laser's stripe in the other's rows again: rigs 23 and 66 lost 5 and 3 % of a map)
    lean = column_band_limits(cal, (w, h), params.height_range_mm, run.rois, unfolded=False)
    others = {n: (a, b - a) for n, (a, b) in lean.items()}
    rays = {n: _band_rays(cal, bands[n], h) for n in LASERS}
    k_up = max(upsampling(rays[n], z_deep, params.grid_mm) for n in LASERS)
    # grid extent: wherever a stripe point can land (the bands' rays on the laser planes,
    # along the travel of the frame range), and 2 mm more
    foot = [stripe_footprint(rays[n], cal.planes[n].plane.normal,
                             float(cal.planes[n].plane.offset_mm)) for n in LASERS]
    # a rolling shutter: row v of a frame was exposed row_mm * v further along the rail
    row_mm = float(cal.speed_mm_s * intr.line_time_s)
    if row_mm:
        reach = (min(0.0, row_mm * (h - 1)), max(0.0, row_mm * (h - 1)))
        foot = [(f[0], (f[1][0] + reach[0], f[1][1] + reach[1])) for f in foot]
    x_rng = (min(f[0][0] for f in foot) - 2, max(f[0][1] for f in foot) + 2)
    t0, t1 = travel[start], travel[stop - 1]
    y_rng = (min(t0, t1) + min(f[1][0] for f in foot) - 2,
             max(t0, t1) + max(f[1][1] for f in foot) + 2)
    spec = GridSpec.covering(x_rng, y_rng, params.grid_mm)
    if spec.shape[0] * spec.shape[1] > 400e6:
        raise InputError("the output grid would exceed 400 million cells; use a coarser grid",
                         code=codes.E_PARAM)
    max_gap = 2.5 * per_frame_travel + 2 * params.grid_mm + 0.1
    texture = None
    texture_travel = None
    if params.texture and run.spool is not None:
        x_px = (np.arange(w) - intr.cx) / intr.fx
        px_rays = np.column_stack([x_px, np.zeros(w), np.ones(w)]) @ rot.T
        k_tex = upsampling(px_rays[:, None, :], z_deep, params.grid_mm)
        xn = np.linspace(-(intr.cx) / intr.fx, (w - 1 - intr.cx) / intr.fx, w * k_tex)
        tu, tv = intr.distort_normalized(xn, np.zeros_like(xn))
        tex_ok = (tu >= 0) & (tu <= w - 1) & (tv >= 0) & (tv <= h - 1)
        tu, tv = tu[tex_ok], tv[tex_ok]
        tex_rays = (np.column_stack([xn, np.zeros_like(xn), np.ones_like(xn)]) @ rot.T)[tex_ok]
        u0 = np.clip(np.floor(tu).astype(np.int64), 0, w - 2)
        v0 = np.clip(np.floor(tv).astype(np.int64), 0, h - 2)
        texture = _TextureRow(run.spool, tex_rays, (u0, v0, tu - u0, tv - v0),
                              np.empty((len(tu), 3), np.uint8))
        texture_travel = travel + row_mm * float(np.median(tv)) if row_mm else travel
    return _Tables(spec, travel, reference_coeffs(cal), bands, rays, k_up,
                   dict(zip(LASERS, (f[1] for f in foot))), max_gap, texture, row_mm,
                   texture_travel, limits, others)


@dataclass
class _Tally:
    """What the frame loop counted."""

    found_frames: dict[str, int]  # frames in which each laser's stripe was found
    found_cols: dict[str, int]  # stripe columns found, summed over frames
    weak_cols: dict[str, int] = field(default_factory=dict)  # columns of weak pieces dropped
    shared_cols: dict[str, int] = field(default_factory=dict)  # the other laser's light dropped
    beyond_cols: dict[str, int] = field(default_factory=dict)  # rows beyond the height range
    narrow_cols: dict[str, int] = field(default_factory=dict)  # found by the narrowed look
    short_cols: dict[str, int] = field(default_factory=dict)  # pieces too short dropped
    own_rows: dict[str, int] = field(default_factory=dict)  # columns taken from own rows
    unlit: dict[str, int] = field(default_factory=dict)  # columns re-estimated, soil subtracted
    seen: int = 0  # frames read
    skipped: int = 0  # frames the decoder reported as damaged
    t_loop: float = 0.0  # when the loop started (perf_counter)


def _process(run: _Run) -> Reconstruction:
    """The run after the decoder has started: tables, the frame loop, the finish."""
    params = run.params
    kern = _kernels()  # loaded (or waited for) before the tables that use them
    tab = _tables(run)
    # a run of up to BRIDGE_COLUMNS columns missed in one frame is filled across (grid.
    # HeightAccumulator): m missed columns are (m + 1) k - 1 upsampled points
    acc = {n: HeightAccumulator(tab.spec, tab.max_gap_mm, params.max_step_mm,
                                (BRIDGE_COLUMNS + 1) * tab.k_up - 1) for n in LASERS}
    tex = tab.texture
    finisher = RowFinisher(tab.spec, acc, params.fuse_tolerance_mm, tab.offsets,
                           _direction(tab.travel[run.start:run.stop]),
                           TextureInputs(tex.spool, tex.rays, tab.travel
                                         if tab.texture_travel is None else tab.texture_travel,
                                         tab.ref,
                                         ColorAccumulator(tab.spec, tab.max_gap_mm))
                           if tex is not None else None,
                           weight_green=fusion_weight(run.cal, run.video.size))
    try:
        lut = run.lut_job.result() if run.lut_job is not None else None
        # each laser's detector knows where the other's stripe can lie: light leaning to the
        # other laser's colour is refused only there
        ground = ground_rows(run.cal, run.video.size)
        detect = {n: StripeDetector(n, tab.bands[n][0], tab.bands[n][1], run.stripe_params, lut,
                                    other=_own_band(tab, next(m for m in LASERS if m != n)),
                                    ground=ground[n])
                  for n in LASERS}
        # a second look, where a laser's stripe was refused in columns the other laser's band
        # covers but that laser's stripe was found elsewhere (NARROW_OTHER)
        narrow = ({n: StripeDetector(n, tab.bands[n][0], tab.bands[n][1], run.stripe_params,
                                     lut, other=_own_band(tab, next(m for m in LASERS if m != n)))
                   for n in LASERS} if NARROW_OTHER else None)
        report(run.progress, 0.03, "background learned")
        tally = _frame_loop(run, tab, kern, acc, detect, finisher, narrow)
        tally.own_rows = {n: detect[n].own_rows_taken for n in LASERS}
    finally:
        run.frames.close()
        finisher.close()
    run.cancel.check()  # the reader stops early on cancel: never take that as a finished run
    if tally.seen < run.n_frames:
        raise VideoError(f"the video ended at frame {run.start + tally.seen} before frame "
                         f"{run.stop - 1}", code=codes.E_VIDEO_TRUNCATED)
    loop_s = time.perf_counter() - tally.t_loop
    warnings = _stripe_warnings(run, tally)
    asked = run.params.frame_stop
    if asked is not None and asked > run.stop:  # the range asked runs past the video's end
        warnings.append(f"W-FRAME-RANGE: frames up to {asked - 1} were asked for; the video "
                        f"ends at frame {run.stop - 1}, so frames {run.start}..{run.stop - 1} "
                        "were processed")
    bright = _bright_ground(run, warnings)
    t_finish = time.perf_counter()
    report(run.progress, 0.93, "finishing the maps and the texture")
    finisher.finish()
    finisher.release()  # the accumulators' memory, before the steps below add theirs
    islands, floating, overreach = _drop_islands(run, finisher)
    # the lasers' difference across the map: a plane turned in the calibration shows there;
    # each laser's map is then brought to the pair's weighted consensus
    agreement = laser_agreement(finisher.per["green"], finisher.per["red"], tab.spec)
    reconciled = (reconcile(finisher.per, tab.spec, agreement, finisher.weight_green)
                  if params.reconcile_lasers else None)
    if reconciled is not None:
        _fuse_again(run, finisher, "with the lasers reconciled")
    elif any(islands.values()) or any(floating.values()) or any(overreach.values()):
        _fuse_again(run, finisher, "without the islands")
    end_cells = _texture_ends(run, tab, finisher, warnings)
    stats = _stats(run, tab, tally, finisher, loop_s, t_finish)
    warnings += _lost_laser_warnings(tally, stats)
    stats["laser_agreement"] = (None if agreement is None
                                else {k: round(v, 5) for k, v in agreement.items()})
    stats["lasers_reconciled"] = reconciled
    warnings += agreement_warnings(agreement)
    stats["texture_end_cells_filled"] = end_cells
    stats["island_cells_dropped"] = islands
    stats["floating_cells_dropped"] = floating
    stats["overreach_cells_dropped"] = overreach
    if bright is not None:
        stats["ground_near_full_share"] = round(bright, 4)
    report(run.progress, 1.0, "done")
    if finisher.broken:
        stats["finished_after_loop"] = finisher.broken
    return Reconstruction(tab.spec, finisher.fused, finisher.per, finisher.diff,
                          finisher.contrib, finisher.tex, (run.start, run.stop), run.rois,
                          stats, warnings)


def _frame_loop(run: _Run, tab: _Tables, kern, acc: dict[str, HeightAccumulator],
                detect: dict[str, StripeDetector], finisher: RowFinisher,
                narrow: dict[str, StripeDetector] | None = None) -> _Tally:
    """Every frame: each laser's stripe -> its profile -> its heightmap, the texture row
    spooled, the rows left behind handed to the finisher, progress and previews."""
    params, frames = run.params, run.frames
    w = run.video.size[0]
    profile = {n: _Profile(w, tab.k_up) for n in LASERS}
    min_cols = max(2, int(0.02 * w))
    plane = {n: run.cal.planes[n].plane for n in LASERS}
    tex = tab.texture
    tally = _Tally(dict.fromkeys(LASERS, 0), dict.fromkeys(LASERS, 0), dict.fromkeys(LASERS, 0))
    tally.shared_cols = dict.fromkeys(LASERS, 0)
    tally.beyond_cols = dict.fromkeys(LASERS, 0)
    tally.narrow_cols = dict.fromkeys(LASERS, 0)
    tally.short_cols = dict.fromkeys(LASERS, 0)
    min_run = min_run_columns(w) if DROP_SHORT_RUNS else 0
    overlap = {n: _bands_overlap(tab, n) for n in LASERS}
    long_cols = long_run_columns(w)
    run_id, scratch = np.empty(w, np.int64), np.empty(w)
    shared = {n: (np.empty(w), np.empty(w), np.empty(w)) for n in LASERS}
    beyond = np.empty(w, bool)
    last_row = {n: (b - 1 + BEYOND_RANGE_PX).astype(np.float64) for n, (_a, b) in tab.limits.items()}
    ratio = float(params.weak_run_ratio)
    frames.limit(LOOP_QUEUE_FRAMES)
    last_preview = time.perf_counter()
    n_total = run.n_frames
    tally.t_loop = time.perf_counter()
    # frames the decoder reports as damaged (filled in by the decoding thread before a frame
    # is queued) give no stripe points: their rows are left to the neighbouring frames
    damage = getattr(frames.video, "damage", {})
    unlit = (UnlitSoil(run.cal.intrinsics, run.cal.rotation, tab.travel,
                       tab.rays, tab.bands, plane, (w, run.video.size[1]),
                       float(run.cal.reference_depth(np.array(0.0), np.array(0.0))))
             if params.unlit_soil else None)
    for k, planes in frames:
        run.cancel.check()
        tally.seen += 1
        s_k = float(tab.travel[k])
        bad = k in damage
        tally.skipped += bad
        if not bad:
            for name in LASERS:
                res = detect[name](planes)
                # rows below the column's own end of the band: a surface beyond the height
                # range, which the band only reaches because another column's is longer -
                # in practice the other laser's stripe (rig 208: green took red's, 90 mm down)
                np.greater(res.rows, last_row[name], out=beyond)
                if beyond.any():
                    res.rows[beyond] = np.nan
                    res.strength[beyond] = 0.0
                    tally.beyond_cols[name] += int(np.count_nonzero(beyond))
            if narrow is not None:
                first = {n: detect[n].result.rows.copy() for n in LASERS}
                for name in LASERS:
                    tally.narrow_cols[name] += _narrowed_look(
                        planes, detect[name].result, narrow[name], overlap[name],
                        first[next(m for m in LASERS if m != name)], last_row[name])
            for name in LASERS:
                res = detect[name].result
                tally.weak_cols[name] += kern.prune_weak_runs(res.rows, res.strength,
                                                              CONNECT_PX, long_cols, ratio,
                                                              run_id, scratch)
                tally.short_cols[name] += kern.drop_short_runs(res.rows, res.strength,
                                                               CONNECT_PX, min_run)
            for name, n in _drop_shared_light(kern, detect, tab, plane, s_k, shared).items():
                tally.shared_cols[name] += n
        for name in LASERS:
            if bad:
                profile[name].next()
                acc[name].reset_chain()
                continue
            res = detect[name].result
            if unlit is not None:
                unlit.refine(name, k, planes.y, res.rows)
            pr = profile[name]
            up = pr.next()
            pl = plane[name]
            n_ok = kern.stripe_profile(
                res.rows, CONNECT_PX, min_cols, tab.bands[name][0], tab.rays[name], pl.normal,
                float(pl.offset_mm), s_k, tab.row_mm, tab.ref, params.max_step_mm, pr.k,
                pr.valid,
                pr.x, pr.y, pr.h, *up, pr.y_range)
            if n_ok < min_cols:  # a few isolated hits are not a stripe
                acc[name].reset_chain()
                continue
            tally.found_frames[name] += 1
            tally.found_cols[name] += int(n_ok)
            pr.used()
            acc[name].add_profile(up[0], up[1], up[2], up[3], travel_mm=s_k)
            finisher.check_range(name, s_k, pr.y_range)
        if unlit is not None:
            if bad:
                unlit.skip(k)
            else:
                unlit.keep(k, planes.y, {n: detect[n].result.rows for n in LASERS})
        if tex is not None:
            kern.sample_rgb(planes.y, planes.cb, planes.cr, planes.chroma_step, *tex.sample,
                            tex.colours)
            tex.spool.append(k, tex.colours)
        i = k - run.start + 1
        if i % 8 == 0:
            finisher.post(s_k)
        if run.preview is not None and time.perf_counter() - last_preview > run.preview_every_s:
            last_preview = time.perf_counter()
            pm = _preview_map(acc)
            run.preview(pm, spec=_preview_spec(tab.spec, pm))
        if i % 25 == 0 or i == n_total:
            el = time.perf_counter() - tally.t_loop
            report(run.progress, 0.05 + 0.85 * i / n_total,
                   f"frame {i}/{n_total} ({i / max(el, 1e-9):.1f} frames/s)")
    tally.unlit = dict(unlit.refined) if unlit is not None else dict.fromkeys(LASERS, 0)
    return tally


#: the second look where the other laser's stripe lies elsewhere in the column (on);
#: False only to compare with the code before
NARROW_OTHER = True
#: ... its band narrowed to this many rows on each side of its stripe
NARROW_MARGIN_PX = 8


def _bands_overlap(tab: _Tables, name: str) -> np.ndarray:
    """Columns where laser ``name``'s search band and the other laser's band share rows."""
    start, height = tab.bands[name]
    o0, oh = _own_band(tab, next(m for m in LASERS if m != name))
    o0 = np.asarray(o0, np.int64)
    return (start < o0 + np.asarray(oh, np.int64)) & (o0 < start + int(height))


def _narrowed_look(planes, res: StripeResult, det: StripeDetector, overlap: np.ndarray,
                   other_rows: np.ndarray, last_row: np.ndarray) -> int:
    """In place: where this laser's stripe was not found in a column its band shares with
    the other laser's, but the other laser's stripe was found there (``other_rows``), look
    again with the other laser's band narrowed to the rows around that stripe
    (:data:`NARROW_MARGIN_PX`): its light is there, not in the rest of its band, so the tests
    of the other laser's band (a light of this laser's colour required, the white-core rule
    refused) need not hold in the rest. A rolled camera's slanted stripes make the bands tall
    (rig 237: red's band 612 rows high over columns where green's stripe lay 380 rows from
    red's, white on greenish soil: 30 % of those columns were missing). Returns the columns
    taken."""
    need = overlap & ~np.isfinite(res.rows) & np.isfinite(other_rows)
    if not need.any():
        return 0
    det.narrow_other(other_rows, NARROW_MARGIN_PX)
    r2 = det(planes)
    with np.errstate(invalid="ignore"):
        take = (need & np.isfinite(r2.rows) & (r2.rows <= last_row)
                & (np.abs(r2.rows - other_rows) > NARROW_MARGIN_PX))
    if not take.any():
        return 0
    # only where the new columns continue a long piece of this laser's stripe as first found:
    # each run of columns whose rows continue into each other (CONNECT_PX) must hold
    # long_run_columns found at the first look. A run of new columns alone, or one continuing
    # a short piece, can be the other laser's light on a second surface of the column (rig
    # 237: red's stripe on a grooved block's tops and walls, 17 columns of it taken for green
    # at the first look; continued, 461 more cells of green's map 45 mm off)
    rows = np.where(take, r2.rows, res.rows)
    with np.errstate(invalid="ignore"):
        link = np.abs(np.diff(rows)) <= CONNECT_PX
    run = np.concatenate([[0], np.cumsum(~link)])
    old = np.isfinite(res.rows)
    has_old = (np.bincount(run, weights=old, minlength=run[-1] + 1)
               >= long_run_columns(len(rows)))
    take &= has_old[run]
    n = int(np.count_nonzero(take))
    if n:
        res.rows[take] = r2.rows[take]
        res.strength[take] = r2.strength[take]
    return n


def _own_band(tab: _Tables, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Laser ``name``'s rows per column as the other laser's detector should know them: each
    column's own (the band searched is as high as its largest column's; where the stripe
    runs slanted across a rolled camera's picture that reaches hundreds of rows beyond the
    height range in the other columns, and over the other laser's own stripe there: rig 208,
    whose red stripe blooming white was refused by the lean test of green's band in a third
    of the columns)."""
    return tab.others[name]


#: rows found more than this below a column's own end of its band (the height range and the
#: band's margin) are dropped (a surface beyond the height range: in practice the other
#: laser's stripe)
BEYOND_RANGE_PX = 0.0

#: two lasers' stripe rows this close in one column are the same light ...
SHARED_ROW_PX = 1.0
#: ... and when the points they give through the two planes lie farther apart than this (in
#: x, y or height), one laser's detector took the other's stripe (stripes.shared_light)
SHARED_APART_MM = 1.0


def _drop_shared_light(kern, detect: dict[str, StripeDetector], tab: _Tables, plane: dict,
                       s_k: float, buf: dict) -> dict[str, int]:
    """Where both lasers' detectors found a stripe at the same row of a column, but the two
    points it gives lie apart, one of them took the other's light: the columns
    :func:`~impress_gui.core.reconstruction.stripes.shared_light` names are dropped from
    that laser's rows (in place). Only on the line where the two planes meet can both lasers
    light one pixel, and there the two points agree. Returns the columns dropped per laser."""
    rows = {n: detect[n].result.rows for n in LASERS}
    g, r = (rows[n] for n in LASERS)
    close = np.abs(g - r) <= SHARED_ROW_PX  # NaN is never close
    if not close.any():
        return dict.fromkeys(LASERS, 0)
    for n in LASERS:
        pl = plane[n]
        kern.triangulate(rows[n], close, tab.bands[n][0], tab.rays[n], pl.normal,
                         float(pl.offset_mm), s_k, tab.row_mm, tab.ref, *buf[n])
    (xg, yg, hg), (xr, yr, hr) = (buf[n] for n in LASERS)
    with np.errstate(invalid="ignore"):
        apart = close & ((np.abs(xg - xr) > SHARED_APART_MM) | (np.abs(yg - yr) > SHARED_APART_MM)
                         | (np.abs(hg - hr) > SHARED_APART_MM))
    if not apart.any():
        return dict.fromkeys(LASERS, 0)
    out = {}
    for n, drop in zip(LASERS, shared_light(g, r, apart, CONNECT_PX)):
        rows[n][drop] = np.nan
        detect[n].result.strength[drop] = 0.0
        out[n] = int(drop.sum())
    return out


def _drop_islands(run: _Run, finisher: RowFinisher
                  ) -> tuple[dict[str, int], dict[str, int], dict[str, int]]:
    """Drop the small islands of each laser's map (:func:`~impress_gui.core.reconstruction.
    grid.drop_islands`), then the floating pieces (:func:`~impress_gui.core.reconstruction.
    grid.drop_floating`), then the cells a chain's end reaches across an edge
    (:func:`~impress_gui.core.reconstruction.grid.drop_overreach`); the cells dropped per
    laser by each step (the caller fuses the maps again if any were found). (The texture was sampled during the loop at the fused heights then:
    a dropped piece's cells keep the colour sampled at its height.)"""
    p = run.params
    names = finisher.names
    islands = dict.fromkeys(names, 0)
    floating = dict.fromkeys(names, 0)
    if p.island_max_cells <= 0 and p.floating_max_cells <= 0 and not DROP_OVERREACH:
        return islands, floating, dict.fromkeys(names, 0)
    report(run.progress, 0.94, "dropping small islands of heights")
    last = [time.perf_counter()]

    def step(what: str, fraction: float) -> None:
        # a long scan's maps take seconds: progress at least every half second
        if time.perf_counter() - last[0] >= 0.5:
            last[0] = time.perf_counter()
            report(run.progress, 0.94, f"dropping {what} ({100 * fraction:.0f} %)")

    for n in names:
        islands[n] = drop_islands(finisher.per[n], p.island_step_mm, p.island_max_cells,
                                  progress=lambda f, n=n: step(f"small islands of heights, "
                                                               f"{n} laser", f))
    if p.floating_max_cells > 0:
        radius = max(1, int(round(p.floating_radius_mm / p.grid_mm)))
        dropped = drop_floating([finisher.per[n] for n in names], p.island_step_mm,
                                p.floating_max_cells, radius, p.floating_support,
                                progress=lambda f: step("floating pieces of heights", f))
        floating = dict(zip(names, dropped))
    # after the islands: the other laser's heights beside a chain's end are the final ones
    # (only where the camera moved one way: with the travel going back and forth a chain's
    # "past its end" has no one direction)
    over = drop_overreach(finisher.per, {n: finisher.acc[n].chain_ends() for n in names},
                          p.max_step_mm) if DROP_OVERREACH and finisher.direction \
        else dict.fromkeys(names, 0)
    return islands, floating, over


def _fuse_again(run: _Run, finisher: RowFinisher, what: str) -> None:
    """Fuse the two lasers' maps again after they were changed (islands dropped, the lasers
    reconciled)."""
    report(run.progress, 0.945, f"fusing the maps again {what}")
    g, r = (finisher.per[n] for n in finisher.names)
    fuse_rows(g, r, finisher.tol, finisher.fused, finisher.diff, finisher.contrib, 0,
              g.shape[0], weight_green=finisher.weight_green)


def _texture_ends(run: _Run, tab: _Tables, finisher: RowFinisher, warnings: list[str]) -> int:
    """Colour the cells at the scan's ends that the texture row never passed over (the lasers
    lead and trail the image's centre) from the first and last processed frames, and for the
    cells under those frames' laser stripes from a frame a little further into the scan
    (:func:`~impress_gui.core.reconstruction.texture.fill_texture_ends`, in place). Returns
    the cells filled; a frame that cannot be read leaves them black, with a warning."""
    if finisher.tex is None:
        return 0
    report(run.progress, 0.95, "colouring the texture's ends")
    ends: list[list[tuple[float, np.ndarray]]] = []
    kk = run.start
    try:
        for picks in end_frame_indices(run.cal, tab.travel, run.start, run.stop):
            frames = []
            for kk in picks:
                rgb = run.frames.kept.get(int(kk))
                frames.append((float(tab.travel[kk]),
                               rgb if rgb is not None else run.video.read(int(kk))))
            ends.append(frames)
    except ImpressError as exc:
        warnings.append(f"W-TEXTURE-ENDS: the texture's ends were left without colour: frame "
                        f"{kk} could not "
                        f"be read again ({exc.code})")
        return 0
    _, filled = fill_texture_ends(finisher.tex, finisher.fused, tab.spec, run.cal, ends[0],
                                  ends[1], inplace=True,
                                  progress=lambda m: report(run.progress, 0.96, m))
    return int(filled.sum())


#: W-BRIGHT-GROUND when more than this share of the picture (the background tables' frames) is
#: within the detector's minimum peak (min_peak) of full scale. Random rigs 0-47 at 640x360
#: (the renders of benchmarks/bench_robustness.py; docs/accuracy.md): rig 34 (white soil,
#: bright ambient light: fused error 0.27 mm, 2.5 % wild points) 24 %, rig 13 (bright speckled
#: soil) 14 %, every other rig 6 % or less
BRIGHT_GROUND_SHARE = 0.10


def _bright_ground(run: _Run, warnings: list[str]) -> float | None:
    """The share of the picture (the background tables' frames, stripes included: a few per
    cent) too bright for a stripe to rise above it by the detector's minimum peak,
    with a warning (``W-BRIGHT-GROUND``) when it exceeds :data:`BRIGHT_GROUND_SHARE`. None
    without background tables (the hue method)."""
    if run.lut_job is None:
        return None
    share = run.lut_job.result().near_full_share(run.params.min_peak)
    if not math.isfinite(share):
        return None
    if share > BRIGHT_GROUND_SHARE:
        warnings.append(
            f"W-BRIGHT-GROUND: {100 * share:.0f} % of the picture is within "
            f"{run.params.min_peak:g} grey levels of full scale: a stripe there barely rises "
            "above the ground, and the heights are noisy and may have wild points; lower the "
            "camera's exposure (or the ambient light) so the ground is not near white")
    return share


#: a laser whose stripe was found but whose map holds fewer cells than this share of the
#: other's is reported (the two lasers sweep the same ground: on the simulator's random rigs
#: their maps differ by at most a factor of about 2)
LOST_LASER_SHARE = 0.02


def _lost_laser_warnings(tally: _Tally, stats: dict) -> list[str]:
    """A warning for a laser whose stripe was found in the frames but that gave (almost) no
    heights: its plane in the calibration does not meet the stripe (a calibration made with
    t1 and t2 swapped, or the two stripes' colours taken for each other)."""
    out = []
    for name in LASERS:
        other = next(m for m in LASERS if m != name)
        cells, theirs = stats[f"cells_{name}"], stats[f"cells_{other}"]
        if tally.found_frames[name] and cells < LOST_LASER_SHARE * theirs:
            out.append(
                f"W-LASER-NO-HEIGHTS: the {name} stripe was found in "
                f"{tally.found_frames[name]} frames but gave heights in only {cells} cells "
                f"({theirs} from the {other} laser): the map is the {other} laser's alone. "
                f"Check the calibration's {name} plane (t1 must show the green stripe on the "
                "target, t2 the red one)")
    return out


#: fewer frames processed than this are warned of (W-FEW-FRAMES): a one-frame "scan" gave a
#: map of one stripe's profile without a word (a hostile-input audit)
FEW_FRAMES = 10


def _stripe_warnings(run: _Run, tally: _Tally) -> list[str]:
    """Warnings about stripes found in few frames or few columns; a stripe never found is an
    error (``E-NO-STRIPE``)."""
    w, n_total = run.video.size[0], run.n_frames
    warnings = []
    if n_total < FEW_FRAMES:
        warnings.append(f"W-FEW-FRAMES: only {n_total} frame(s) were processed (frames "
                        f"{run.start}..{run.stop - 1}): a map is made of the stripes of many "
                        "frames along the scan; this is not a scan of a surface")
    for name in LASERS:
        found = tally.found_frames[name]
        if found == 0:
            raise ReconstructionError(f"the {name} laser's stripe was never found in frames "
                                      f"{run.start}..{run.stop - 1} (rows {run.rois[name]})",
                                      code=codes.E_NO_STRIPE)
        if found < 0.5 * n_total:
            warnings.append(f"W-FEW-STRIPE-FRAMES: the {name} stripe was found in only "
                            f"{found} of {n_total} frames")
        # a stripe crosses the whole picture: a method that finds it in few columns of the
        # frames where it sees it at all drops most of the data (e.g. hue on compressed video)
        share = tally.found_cols[name] / max(1, found * w)
        if found and share < LOW_COLUMN_SHARE:
            warnings.append(
                f"W-LOW-FILL: the {name} stripe was found in only {100 * share:.0f} % of the "
                f"image columns on average (method {run.params.method}): most of the surface "
                "has no data; the combined method usually finds far more")
    return warnings


def _stats(run: _Run, tab: _Tables, tally: _Tally, finisher: RowFinisher, loop_s: float,
           t_finish: float) -> dict:
    """The run's statistics: of the result (cells, stripes found) and of the run (timings)."""
    per, fused = finisher.per, finisher.fused
    w, n_total = run.video.size[0], run.n_frames
    total_s = time.perf_counter() - run.t_start
    return {
        "frames_processed": n_total,
        "stripe_frames": tally.found_frames,
        "cells": int(fused.size),
        "cells_fused": int(np.isfinite(fused).sum()),
        "cells_green": int(np.isfinite(per["green"]).sum()),
        "cells_red": int(np.isfinite(per["red"]).sum()),
        "seconds_total": round(total_s, 3),
        "seconds_setup": round(tally.t_loop - run.t_start, 3),
        "seconds_frame_loop": round(loop_s, 3),
        "seconds_finish": round(time.perf_counter() - t_finish, 3),
        "rows_finished_in_loop": round(finisher.rows_during_loop / tab.spec.shape[0], 3),
        "frames_per_second": round(n_total / max(loop_s, 1e-9), 2),
        "frames_damaged_skipped": tally.skipped,
        "stripe_column_share": {
            n: round(tally.found_cols[n] / max(1, tally.found_frames[n] * w), 3) for n in LASERS},
        "weak_stripe_columns_dropped": tally.weak_cols,
        "stripe_columns_other_laser_dropped": tally.shared_cols,
        "stripe_columns_beyond_height_range": tally.beyond_cols,
        # columns found by a second look with the other laser's band narrowed to its stripe
        # (NARROW_OTHER)
        "stripe_columns_other_band_narrowed": tally.narrow_cols,
        # columns of stripe pieces too short to be a stripe (min_run_columns), dropped
        "stripe_columns_short_pieces_dropped": tally.short_cols,
        # columns whose stripe, found in the other laser's band, gave way to one in the
        # laser's own rows nearer the ground (stripes.StripeParams.prefer_own_rows)
        "stripe_columns_from_own_rows": tally.own_rows,
        # columns whose centre was estimated again with the soil seen unlit in earlier frames
        # subtracted (ProcessParams.unlit_soil)
        "stripe_columns_unlit_soil": tally.unlit,
        # where both lasers agree, the fused height is their mean with these weights
        # (fusion_weight)
        "fusion_weights": {"green": round(finisher.weight_green, 6),
                           "red": round(1.0 - finisher.weight_green, 6)},
        # where one laser alone measured (the scan's ends, where the other's stripe has not
        # reached the surface or has left it, and occlusions), the map is that laser's alone,
        # with its own precision: the height one pixel of stripe shift means for each
        # (docs/accuracy.md, "Where the fused error comes from")
        "cells_one_laser": _one_laser_cells(finisher.contrib, fused),
        "height_per_stripe_pixel_mm": {
            n: (round(v, 4) if np.isfinite(v) else None)
            for n, v in height_per_pixel(run.cal, run.video.size).items()},
    }


def _one_laser_cells(contrib: np.ndarray, fused: np.ndarray) -> dict[str, int]:
    """Cells of the fused map each laser alone made (contribution codes 1 and 2)."""
    counts = np.bincount(contrib[np.isfinite(fused)].ravel(), minlength=5)
    return {"green": int(counts[1]), "red": int(counts[2])}


def _direction(travel: np.ndarray) -> int:
    """+1 / -1 when the camera moves one way frame by frame, else 0."""
    d = np.diff(travel)
    if len(d) and (d > 0).all():
        return 1
    if len(d) and (d < 0).all():
        return -1
    return 0


def upsampling(rays: np.ndarray, depth_mm: float, grid_mm: float) -> int:
    """Points per pixel step (``k``) that put neighbouring points of a profile at most one grid
    cell apart along each axis, for a surface ``depth_mm`` deep: ``rays`` ``(W, n, 3)`` are
    rail-frame directions through neighbouring columns (axis 0). One cell apart along each axis
    leaves no cell of a row out, and the fill towards the previous row (at most one cell per
    step too) then covers the strip between two rows."""
    plan = rays[..., :2] / rays[..., 2:3]
    step = float(np.abs(np.diff(plan, axis=0)).max()) * depth_mm
    return max(1, int(np.ceil(step / grid_mm)))


def _band_rays(cal: SceneCalibration, band: tuple[np.ndarray, int], height: int) -> np.ndarray:
    """Rail-frame ray directions ``(W, band height + 1, 3)`` through every column at the
    integer rows of its band (lens distortion undone once here, not per frame)."""
    b0, bh = band
    intr = cal.intrinsics
    coeffs = np.zeros(8)
    coeffs[: intr.dist_coeffs.size] = intr.dist_coeffs[:8]
    rays = np.empty((len(b0), bh + 1, 3))
    _kernels().band_rays(np.ascontiguousarray(b0, np.int64), int(height),
                         np.ascontiguousarray(intr.camera_matrix, np.float64), coeffs,
                         intr.dist_coeffs.size == 8,
                         np.ascontiguousarray(cal.rotation, np.float64), rays)
    return rays


#: stripe rows of neighbouring columns closer than this (pixels) belong to one curve
CONNECT_PX = 2.0
#: the longest run of a stripe's columns missed in one frame (with the columns either side
#: found) that the heightmap is filled across, from the frames before and after
BRIDGE_COLUMNS = 8
#: a stripe piece at least this share of the image width long sets the frame's typical strength
#: (see :func:`~impress_gui.core.reconstruction.kernels.prune_weak_runs`); shorter pieces must
#: be at least ``ProcessParams.weak_run_ratio`` as strong
LONG_RUN_FRACTION = 1.0 / 60.0
MIN_LONG_RUN = 8


#: the shortest stripe piece kept, in columns at 1920 px (:func:`min_run_columns`;
#: :func:`~impress_gui.core.reconstruction.kernels.drop_short_runs`)
MIN_RUN_1920 = 3
#: drop the pieces shorter than :func:`min_run_columns` (off only to compare with the code
#: before)
DROP_SHORT_RUNS = True


def min_run_columns(width: int) -> int:
    """The shortest stripe piece kept in an image ``width`` pixels wide: ``MIN_RUN_1920``
    scaled to the width, never below the two columns a piece has at least (so at 1280 px and
    below nothing more is dropped)."""
    return max(2, math.ceil(MIN_RUN_1920 * width / 1920))


def long_run_columns(width: int) -> int:
    """Columns a stripe piece needs to count as long in an image ``width`` pixels wide."""
    return max(MIN_LONG_RUN, int(width * LONG_RUN_FRACTION))


class _Profile:
    """Per-laser arrays of one frame's profile, reused from frame to frame: the upsampled
    profile alternates between two sets (the accumulator copies what it keeps of a profile,
    so one would do; two cost a few kilobytes)."""

    def __init__(self, w: int, k_up: int) -> None:
        self.x, self.y, self.h = (np.empty(w) for _ in range(3))
        self.valid = np.empty(w, bool)
        self.y_range = np.empty(2)
        self.k = k_up
        n = (w - 1) * k_up + 1
        self._sets = [(np.empty(n), np.empty(n), np.empty(n), np.empty(n, bool))
                      for _ in range(2)]
        self._i = 0

    def next(self):
        """The set to fill with this frame's upsampled profile (x, y, height, valid)."""
        return self._sets[self._i]

    def used(self) -> None:
        """The set was handed to the accumulator: the next frame fills the other one."""
        self._i ^= 1
