"""Accumulating scattered stripe profiles into a regular heightmap grid.

Grid convention (shared with the simulator's truth): cell ``[i, j]`` is centred at rail
coordinates ``x = x0_mm + j * pixel_mm``, ``y = y0_mm + i * pixel_mm``; arrays are row-major.
Consecutive stripe profiles are filled in between (linear where the surface is continuous,
nearest where it steps), so a scan at any speed gives a gap-free map where a laser saw the
surface.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class GridSpec:
    x0_mm: float
    y0_mm: float
    pixel_mm: float
    shape: tuple[int, int]  # (rows along Y, cols along X)

    @classmethod
    def covering(cls, x_range, y_range, pixel_mm: float) -> GridSpec:
        x0 = np.floor(x_range[0] / pixel_mm) * pixel_mm
        y0 = np.floor(y_range[0] / pixel_mm) * pixel_mm
        w = int(np.ceil((x_range[1] - x0) / pixel_mm)) + 1
        h = int(np.ceil((y_range[1] - y0) / pixel_mm)) + 1
        return cls(float(x0), float(y0), float(pixel_mm), (h, w))

    def xs(self) -> np.ndarray:
        return self.x0_mm + self.pixel_mm * np.arange(self.shape[1])

    def ys(self) -> np.ndarray:
        return self.y0_mm + self.pixel_mm * np.arange(self.shape[0])

    def to_json(self) -> dict:
        return {"x0_mm": self.x0_mm, "y0_mm": self.y0_mm, "pixel_mm": self.pixel_mm,
                "shape": list(self.shape)}


def short_runs(flags: np.ndarray, max_len: int) -> np.ndarray:
    """The elements of ``flags`` (bool) in runs of True of at most ``max_len`` elements with
    False on both sides (a run touching either end of the array is not short)."""
    f = np.asarray(flags, bool)
    if not f.any():
        return np.zeros(f.shape, bool)
    d = np.diff(np.concatenate([[0], f.view(np.int8), [0]]))
    starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    ok = (stops - starts <= max_len) & (starts > 0) & (stops < len(f))
    marks = np.zeros(len(f) + 1, np.int64)
    np.add.at(marks, starts[ok], 1)
    np.add.at(marks, stops[ok], -1)
    return np.cumsum(marks[:-1]) > 0


#: across a step between two consecutive frames, fill each end's height at most half the
#: carriage's travel between them towards the other end (off only to compare with the code
#: before, which split the strip at its middle however long): a surface's last point lies
#: within one frame's travel of its edge, so its half is the edge's best place; a strip longer
#: than a frame's travel is a shadow or a wrong far end, and its middle is left to the other
#: laser or empty
STEP_REACH = True


class HeightAccumulator:
    """Sum and count of heights per cell, filled between consecutive profiles.

    Each point of a profile (one image column's upsampled point) is filled towards the same
    point of the previous profile; where the detector missed a few columns of the previous
    profile (a run of at most ``bridge_points`` points with found points on both sides), towards
    where the point was found in the profile before that, if within ``max_gap_mm``. On a
    speckled, noisy stripe the detector misses a few per cent of the columns in every frame,
    and each miss left a hole two frames long in that laser's map (issue 18, random rig 13: the
    fused fill 88.7 -> 96.5 % at 640x360 with the detector's guided pass). Only one missed
    profile is bridged, and never a long run of missed points: a laser shadow or a hidden
    groove floor spans many columns, and is left a hole rather than covered with a lid.

    Nor is a step bridged (a height change beyond ``max_step_mm``). Between consecutive
    profiles, a step's strip is split between its two ends, each reaching at most half the
    carriage's travel between the two frames when it is given (:data:`STEP_REACH`). Across a missed profile that guess
    would span two frames' travel. At an edge, the missed frame is where the stripe left the
    higher surface, and the point after it is often wrong: bridged, it drew the higher surface
    up to a millimetre past the edge (issue 18, random rig 13 at 1080p: the edge error
    0.20 -> 0.10 mm)."""

    def __init__(self, spec: GridSpec, max_gap_mm: float, max_step_mm: float,
                 bridge_points: int = 0) -> None:
        self.spec = spec
        # float32 sums: heights within +-1 m summed over a cell's few hundred samples keep
        # micrometre precision; uint16 counts (a cell gets at most a few hundred samples)
        self.sum = np.zeros(spec.shape, np.float32)
        self.count = np.zeros(spec.shape, np.uint16)
        self.max_gap_mm = max_gap_mm
        self.max_step_mm = max_step_mm
        self.bridge_points = int(bridge_points)
        # per point of the profile: where it was last found (x, y, height), whether it was
        # found since the chain began, and how many profiles ago
        self._last: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        self._age = np.zeros(0, np.int64)
        self._prev_valid = np.zeros(0, bool)
        self._pair = np.zeros(0, bool)
        self._chain = False
        self._splat: Any = None  # the compiled kernel, looked up on first use
        # a chain's ends (a point found with nothing joined to it on one side along the
        # scan): the cell each end was added to, and on which side of the point that cell's
        # centre lies (:meth:`chain_ends`, :func:`drop_overreach`)
        self._ends: list[np.ndarray] = []
        self._travel = 0.0  # sum of the joined points' moves along the grid's rows
        self._last_travel = math.nan  # the carriage's travel at the previous profile (mm)

    def reset_chain(self) -> None:
        """The next profile is filled towards nothing before it (a frame without a stripe, a
        damaged frame)."""
        self._chain = False

    def add_profile(self, x, y, h, valid, travel_mm: float = math.nan) -> None:
        """Add one frame's (upsampled) profile; fill towards the previous profile (see the
        class and :func:`impress_gui.core.reconstruction.kernels.splat_heights`). With the
        carriage's travel of this frame (``travel_mm``, and of the previous profile's frame
        given the same way), a step's strip is filled at most half the travel between the two
        frames from either end (:data:`STEP_REACH`)."""
        if self._splat is None:
            from impress_gui.core.reconstruction.compiled import kernels

            self._splat = kernels().splat_heights
        last = self._last
        n = np.shape(x)
        if last is None or last[0].shape != n:
            last = self._last = (np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n, bool))
            self._age = np.zeros(n, np.int64)
            self._prev_valid = np.zeros(n, bool)
            self._pair = np.zeros(n, bool)
            self._chain = False
        lx, ly, lh, lv = last
        if not self._chain:
            lv[:] = False
        self._age += 1
        pair = self._pair
        np.logical_and(lv, self._age == 1, out=pair)  # found in the previous profile
        if self.bridge_points > 0:
            bridge = lv & (self._age == 2) & short_runs(~self._prev_valid, self.bridge_points)
            with np.errstate(invalid="ignore"):
                bridge &= np.abs(h - lh) <= self.max_step_mm  # never across a step
            pair |= bridge
        s = self.spec
        self._record_ends(x, y, valid, pair)
        reach = 0.5 * abs(travel_mm - self._last_travel) if STEP_REACH else math.nan
        self._splat(self.sum, self.count, s.x0_mm, s.y0_mm, s.pixel_mm, x, y, h, valid,
                    lx, ly, lh, pair, self._chain, float(self.max_gap_mm), float(self.max_step_mm),
                    reach if reach > 0 else -1.0)
        self._last_travel = travel_mm
        np.copyto(lx, x, where=valid)
        np.copyto(ly, y, where=valid)
        np.copyto(lh, h, where=valid)
        lv |= valid
        self._age[valid] = 0
        self._prev_valid[:] = valid
        self._chain = True

    def _record_ends(self, x, y, valid, pair) -> None:
        """Note the chains that end with the previous profile (its points this profile does
        not join, as :func:`~impress_gui.core.reconstruction.kernels.splat_heights` decides)
        and those that start with this one (its points joined to nothing before)."""
        lx, ly = self._last[0], self._last[1]  # type: ignore[index]
        with np.errstate(invalid="ignore"):
            near = np.hypot(x - lx, y - ly) <= self.max_gap_mm
        joined = (valid & pair & near) if self._chain else np.zeros(np.shape(x), bool)
        if joined.any():
            self._travel += float(np.sum(y[joined] - ly[joined]))
        ends = self._prev_valid & ~(joined & (self._age == 1))
        starts = valid & ~joined
        self._note(ends, lx, ly, 1)
        self._note(starts, x, y, -1)

    def _note(self, sel, px, py, kind: int) -> None:
        if not sel.any():
            return
        g = self.spec.pixel_mm
        yi = (py[sel] - self.spec.y0_mm) / g
        ci = np.rint(yi)
        cj = np.rint((px[sel] - self.spec.x0_mm) / g)
        side = np.sign(ci - yi)
        d = np.sign(self._travel)
        if d:  # only the cells past a chain's end in the direction the scan runs are needed
            keep = side == kind * d
            ci, cj, side = ci[keep], cj[keep], side[keep]
        self._ends.append(np.stack([ci, cj, side, np.full(ci.shape, kind)]).astype(np.int32))

    def chain_ends(self) -> tuple[np.ndarray, int]:
        """The chains' ends, ``(4, n)``: cell row, cell column, the side (+1 / -1 / 0) along
        the grid's rows on which the cell's centre lies from the point, and +1 for a chain's
        last point, -1 for its first; and the direction (+1 / -1 / 0) in which joined points
        moved along the rows, overall. The last profile's points count as ends (the scan
        ends there)."""
        parts = list(self._ends)
        if self._last is not None:
            parts.append(self._final_ends())
        e = np.concatenate(parts, axis=1) if parts else np.zeros((4, 0), np.int32)
        return e, int(np.sign(self._travel))

    def _final_ends(self) -> np.ndarray:
        n = len(self._ends)
        self._note(self._prev_valid, self._last[0], self._last[1], 1)  # type: ignore[index]
        return self._ends.pop() if len(self._ends) > n else np.zeros((4, 0), np.int32)

    def release(self) -> None:
        """Free the sums and counts (after the maps were made from them): nothing may be
        added or averaged afterwards."""
        if self._last is not None:  # the chains that end with the scan
            self._ends.append(self._final_ends())
        self.sum = np.zeros((0, self.spec.shape[1]), np.float32)
        self.count = np.zeros((0, self.spec.shape[1]), np.uint16)
        self._last = None

    def mean(self) -> np.ndarray:
        from impress_gui.core.reconstruction.compiled import kernels

        out = np.empty(self.spec.shape, np.float32)
        kernels().mean_heights(self.sum, self.count, out)
        return out

    def mean_rows(self, rows: slice, out: np.ndarray) -> None:
        """:meth:`mean` of grid rows ``rows`` into the same rows of ``out``."""
        from impress_gui.core.reconstruction.compiled import kernels

        kernels().mean_heights(self.sum[rows], self.count[rows], out[rows])


class ColorAccumulator:
    """Sum and count of colours per cell (the registered texture); filled by
    :func:`impress_gui.core.reconstruction.kernels.texture_rows`.

    With ``ring_rows`` (a power of two) the sums hold only that many grid rows at a time:
    grid row ``i`` in row ``i & mask``. Rows are then taken out in scan order
    (:meth:`take_rows`), which frees theirs for the rows that follow; the caller keeps every
    row it still adds to within one ring."""

    def __init__(self, spec: GridSpec, max_gap_mm: float, ring_rows: int | None = None) -> None:
        self.spec = spec
        rows = spec.shape[0] if ring_rows is None else ring_rows
        if ring_rows is not None and (ring_rows <= 0 or ring_rows & (ring_rows - 1)):
            raise ValueError("ring_rows must be a power of two")
        self.rows = rows
        self.mask = -1 if ring_rows is None else ring_rows - 1
        self.sum = np.zeros((rows, spec.shape[1], 3), np.float32)
        self.count = np.zeros((rows, spec.shape[1]), np.uint16)
        self.max_gap_mm = max_gap_mm

    def mean(self) -> np.ndarray:
        from impress_gui.core.reconstruction.compiled import kernels

        assert self.mask == -1, "a ring's rows are taken out with take_rows"
        out = np.empty((*self.spec.shape, 3), np.uint8)
        kernels().mean_colours(self.sum, self.count, out)
        return out

    def mean_rows(self, rows: slice, out: np.ndarray) -> None:
        """:meth:`mean` of grid rows ``rows`` into the same rows of ``out`` (whole-grid sums)."""
        from impress_gui.core.reconstruction.compiled import kernels

        assert self.mask == -1, "a ring's rows are taken out with take_rows"
        kernels().mean_colours(self.sum[rows], self.count[rows], out[rows])

    def take_rows(self, rows: slice, out: np.ndarray) -> None:
        """The mean colours of grid rows ``rows`` into the same rows of ``out``; in a ring,
        their sums are then cleared for the rows that follow."""
        from impress_gui.core.reconstruction.compiled import kernels

        if self.mask == -1:
            self.mean_rows(rows, out)
            return
        a = rows.start
        while a < rows.stop:
            r = a & self.mask
            n = min(rows.stop - a, self.rows - r)
            kernels().mean_colours(self.sum[r : r + n], self.count[r : r + n], out[a : a + n])
            self.sum[r : r + n] = 0
            self.count[r : r + n] = 0
            a += n


def fuse(h_green: np.ndarray, h_red: np.ndarray, tol_mm: float, weight_green: float = 0.5):
    """Fuse two per-laser maps. Returns (fused, difference green - red, contribution) where
    contribution is 0 none, 1 green only, 2 red only, 3 both agreeing (their mean, green
    weighted by ``weight_green``: see ``reconstruct.fusion_weight``), 4 both disagreeing (the
    value nearer the local consensus: the mean of the cells fused from agreeing or single
    lasers in the 7 x 7 square around it)."""
    fused = np.empty(h_green.shape, np.float32)
    diff = np.empty(h_green.shape, np.float32)
    contrib = np.empty(h_green.shape, np.uint8)
    fuse_rows(np.ascontiguousarray(h_green, np.float32), np.ascontiguousarray(h_red, np.float32),
              tol_mm, fused, diff, contrib, 0, h_green.shape[0], weight_green=weight_green)
    return fused, diff, contrib


#: half size of the square whose consensus decides between disagreeing lasers
FUSE_RADIUS = 3


def fuse_rows(h_green, h_red, tol_mm: float, fused, diff, contrib, lo: int, hi: int,
              resolve: tuple[int, int] | None = None, weight_green: float = 0.5) -> None:
    """:func:`fuse` on rows ``lo .. hi - 1`` of preallocated maps, then the conflicts of rows
    ``resolve`` (default the same rows; they need the first pass :data:`FUSE_RADIUS` rows
    beyond them). Fusing a map band by band gives the same result as all at once."""
    from impress_gui.core.reconstruction.compiled import kernels

    k = kernels()
    conflicts = k.fuse_rows(h_green, h_red, float(tol_mm), fused, diff, contrib, lo, hi,
                            float(weight_green)) if hi > lo else 0
    a, b = resolve if resolve is not None else (lo, hi)
    if b > a and (conflicts or resolve is not None):
        k.resolve_conflicts(h_green, h_red, FUSE_RADIUS, fused, contrib, a, b)


#: rows of a map looked at together by :func:`drop_islands` (its working memory is about 11
#: bytes per cell of a block, instead of per cell of the map)
ISLAND_BLOCK_ROWS = 1024


def _small_pieces(win: np.ndarray, valid: np.ndarray, step_mm: float, max_cells: int
                  ) -> np.ndarray:
    """The cells of ``win`` (float32, NaN without data) in pieces of at most ``max_cells``
    cells: cells joined to their 4 neighbours where the heights differ by at most
    ``step_mm``. Heights compared in hundredths of a millimetre (OpenCV's ``filterSpeckles``
    on 16-bit cells; beyond +-320 mm they are clipped)."""
    import cv2

    diff = max(0, int(round(step_mm * 100)))
    # hundredths of a millimetre, in place in one float32 block (NaN stays NaN and is not
    # copied): the same values as rint/clip/astype on the valid cells alone, with a third
    # of the temporaries
    t = np.multiply(win, 100.0, dtype=np.float32)
    np.rint(t, out=t)
    np.clip(t, -32000, 32000, out=t)
    img = np.full(win.shape, -32768, np.int16)
    np.copyto(img, t, where=valid, casting="unsafe")
    del t
    cv2.filterSpeckles(img, -32768, int(max_cells), diff)
    return valid & (img == -32768)


def drop_islands(h: np.ndarray, step_mm: float, max_cells: int,
                 block_rows: int = ISLAND_BLOCK_ROWS, progress=None) -> int:
    """Set to NaN, in place, every island of at most ``max_cells`` cells of the float32 map
    ``h``: cells joined to their 4 neighbours where the heights differ by at most
    ``step_mm``, cut off from the rest by larger steps or by cells without data. Returns the
    cells dropped. A detector's false stripe (soil of the laser's colour, a reflection)
    gives a few cells floating millimetres off the surface, never joined to it; a real
    surface is one piece of thousands of cells. The map is worked through in blocks of
    ``block_rows`` rows with ``max_cells + 1`` rows of margin on each side: an island of at
    most ``max_cells`` cells spans no more rows than that, and a larger piece reaches beyond
    the margin, so the result is that of the whole map at once. ``progress(fraction)`` is
    called after each block."""
    if max_cells <= 0:
        return 0
    rows = h.shape[0]
    margin = int(max_cells) + 1
    drops = []
    for a in range(0, rows, block_rows):
        b = min(rows, a + block_rows)
        lo, hi = max(0, a - margin), min(rows, b + margin)
        win = h[lo:hi]
        gone = _small_pieces(win, np.isfinite(win), step_mm, max_cells)[a - lo:b - lo]
        # the cells' flat indices, applied after every block is read (islands are few)
        drops.append(np.flatnonzero(gone) + a * h.shape[1])
        if progress is not None:
            progress(b / rows)
    idx = np.concatenate(drops) if drops else np.zeros(0, np.intp)
    h[np.unravel_index(idx, h.shape)] = np.nan
    return int(idx.size)


def drop_floating(maps: list[np.ndarray], step_mm: float, max_cells: int, radius: int,
                  max_support: float, block_rows: int = ISLAND_BLOCK_ROWS,
                  progress=None) -> list[int]:
    """Set to NaN, in place, the floating pieces of each laser's float32 map in ``maps``
    (all of one shape): pieces of at most ``max_cells`` cells (joined as in
    :func:`drop_islands`; pieces that touch are taken together) around which, within
    ``radius`` cells (a square ring), at most a share ``max_support`` of the cells hold
    data in any of the maps. Returns the cells dropped per map.

    Where one laser's light is shadowed off the ground, its detector may take the soil's
    texture for the stripe and give pieces of tens to hundreds of cells floating
    millimetres up, in a hole neither laser measured (docs/accuracy.md, "Floating pieces in
    a laser's shadow"); a real piece of surface that small stands among data, of its own
    laser or the other's. Every map is judged on the maps as given (the drops are applied
    after every piece is judged), so the order of the maps does not matter. Blocks of
    ``block_rows`` rows with ``max_cells + radius + 1`` rows of margin: a piece is judged
    in the block holding its first row, and a piece (or group of touching pieces) spanning
    more than ``max_cells`` rows or columns is kept, so the result is that of the whole
    map at once. ``progress(fraction)`` is called after each block."""
    import cv2
    from scipy import ndimage

    if max_cells <= 0 or not maps:
        return [0] * len(maps)
    rows, cols = maps[0].shape
    r = max(0, int(radius))
    margin = int(max_cells) + r + 1
    kernel = np.ones((2 * r + 1, 2 * r + 1), np.uint8)
    drops: list[list[np.ndarray]] = [[] for _ in maps]
    for a in range(0, rows, block_rows):
        b = min(rows, a + block_rows)
        lo, hi = max(0, a - margin), min(rows, b + margin)
        valids = [np.isfinite(h[lo:hi]) for h in maps]
        seen = np.logical_or.reduce(valids)
        for k, h in enumerate(maps):
            small = _small_pieces(h[lo:hi], valids[k], step_mm, max_cells)
            if not small.any():
                continue
            lab, _n = ndimage.label(small)
            for i, sl in enumerate(ndimage.find_objects(lab), 1):
                if sl is None:
                    continue
                (r0, r1), (c0, c1) = (sl[0].start, sl[0].stop), (sl[1].start, sl[1].stop)
                if not a <= r0 + lo < b or r1 - r0 > max_cells or c1 - c0 > max_cells:
                    continue
                br = slice(max(0, r0 - r), min(hi - lo, r1 + r))
                bc = slice(max(0, c0 - r), min(cols, c1 + r))
                piece = lab[br, bc] == i
                ring = cv2.dilate(piece.view(np.uint8), kernel).view(bool) & ~piece
                n_ring = int(ring.sum())
                if n_ring and np.count_nonzero(seen[br, bc] & ring) > max_support * n_ring:
                    continue
                pr, pc = np.nonzero(piece)
                drops[k].append((pr + br.start + lo) * cols + (pc + bc.start))
        if progress is not None:
            progress(b / rows)
    out = []
    for h, d in zip(maps, drops):
        idx = np.concatenate(d) if d else np.zeros(0, np.intp)
        h[np.unravel_index(idx, h.shape)] = np.nan
        out.append(int(idx.size))
    return out


def drop_overreach(maps: dict[str, np.ndarray], ends: dict[str, tuple[np.ndarray, int]],
                   step_mm: float) -> dict[str, int]:
    """Set to NaN, in place, each laser's cells that hold a chain's end reaching across an
    edge; the cells dropped per laser.

    A point adds its height to its nearest cell, so where a laser's data end (the stripe
    leaves a surface into its shadow, or enters it from one) the last cell can have its
    centre up to half a cell beyond the last point. On open ground that is harmless; at an
    edge the point is on the higher surface and the cell's centre past the edge, on the
    lower one: the map held the higher surface a cell too far (issue 18, random rig 200: a
    block's top 30.7 mm where its ground is, the edges across the scan a cell late on every
    rig that has them). Such a cell is dropped when its centre lies beyond the chain's end
    (after a chain's last point along the direction its points moved in, before its first
    one against it), this laser has nothing in the next cell on that side, the other laser
    has there a height more than ``step_mm`` from the cell's, and the other laser has nothing
    in the cell itself (where it has, the two agree, or they disagree and the fusion takes
    the one nearer the local consensus: at random rig 212's walls this laser's height was the
    right one there, the other's a wall face's). ``ends``: per laser,
    :meth:`HeightAccumulator.chain_ends`."""
    out = dict.fromkeys(maps, 0)
    drops = {}  # decided on the maps as given, then applied (no copy of the maps)
    for n, (e, direction) in ends.items():
        h = maps[n]
        if direction == 0 or e.shape[1] == 0 or len(maps) < 2:
            continue
        ci, cj, side, kind = e
        beyond = (side != 0) & (side == kind * direction)
        ci, cj, side = ci[beyond].astype(np.int64), cj[beyond].astype(np.int64), \
            side[beyond].astype(np.int64)
        nb = ci + side
        rows, cols = h.shape
        ok = (ci >= 0) & (ci < rows) & (cj >= 0) & (cj < cols) & (nb >= 0) & (nb < rows)
        ci, cj, nb = np.unique(np.stack([ci[ok], cj[ok], nb[ok]]), axis=1)
        v = h[ci, cj]
        hit = np.isfinite(v) & ~np.isfinite(h[nb, cj])
        for m, other in maps.items():
            if m == n:
                continue
            o, here = other[nb, cj], other[ci, cj]
            with np.errstate(invalid="ignore"):
                # the other laser's height beyond is a step away, and it has nothing in this
                # cell (where it has, the two agree or the fusion's local consensus decides)
                hit &= np.isfinite(o) & (np.abs(v - o) > step_mm) & ~np.isfinite(here)
        drops[n] = (ci[hit], cj[hit])
    for n, sel in drops.items():
        out[n] = int(sel[0].size)
        maps[n][sel] = np.nan
    return out
