"""The registered texture: one row per frame through the principal point, mapped onto the
heightmap's grid after the heights are known.

During the frame loop each frame's row is sampled and spooled to a temporary file
(:class:`RowSpool`, memory stays flat). A :class:`TextureMapper` casts each row's rays onto the
fused surface and splats the colours into the grid, in scan order: during the loop for rows
whose surface is already final (:mod:`impress_gui.core.reconstruction.finish`), or all at once afterwards
(:func:`map_texture`, on two threads).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from impress_gui.core.calibration.scene import SceneCalibration
from impress_gui.core.reconstruction.compiled import kernels as _kernels
from impress_gui.core.reconstruction.grid import ColorAccumulator, GridSpec


def reference_coeffs(cal: SceneCalibration) -> np.ndarray:
    """``(c0, cx, cy)`` with ``reference_depth(x, y) = c0 + cx x + cy y`` (a plane)."""
    c0 = float(cal.reference_depth(np.array(0.0), np.array(0.0)))
    cx = float(cal.reference_depth(np.array(1.0), np.array(0.0))) - c0
    cy = float(cal.reference_depth(np.array(0.0), np.array(1.0))) - c0
    return np.array([c0, cx, cy])


class RowSpool:
    """Texture rows (uint8 RGB, one per frame) spooled to an anonymous temporary file, so
    memory stays flat however long the video is; read back in order for the mapping."""

    def __init__(self) -> None:
        import tempfile
        import threading

        self._fh = tempfile.TemporaryFile()
        self._lock = threading.Lock()
        self._frames: list[int] = []
        self._width = 0

    def append(self, k: int, colours: np.ndarray) -> None:
        """Spool frame ``k``'s row: ``(N, 3)`` uint8, or floats (rounded, clipped to 0..255)."""
        row = colours if colours.dtype == np.uint8 else \
            np.clip(colours + 0.5, 0, 255).astype(np.uint8)
        self._width = len(row)
        with self._lock:
            self._fh.seek(0, 2)
            self._fh.write(np.ascontiguousarray(row).data)
        self._frames.append(k)

    @property
    def frames(self) -> np.ndarray:
        return np.array(self._frames, np.int64)

    def frames_between(self, a: int, b: int) -> np.ndarray:
        """Frame indices of rows ``a .. b - 1`` (while rows are still being appended)."""
        return np.array(self._frames[a:b], np.int64)

    def __len__(self) -> int:
        return len(self._frames)

    def rows(self, a: int, b: int) -> np.ndarray:
        """Rows ``a .. b - 1`` as ``(b - a, width, 3)`` uint8 (safe from several threads)."""
        size = self._width * 3
        with self._lock:
            self._fh.seek(size * a)
            data = self._fh.read(size * (b - a))
        return np.frombuffer(bytearray(data), np.uint8).reshape(b - a, self._width, 3)

    def close(self) -> None:
        self._fh.close()


def texture_reach(ay: np.ndarray, ref: np.ndarray, max_gap: float) -> float:
    """How far (mm along Y) from its camera position a texture row's samples can land: the
    footprint of the row's rays at the deepest plausible surface (heights within +-200 mm of
    the reference, grid within 2 m of the origin) plus the fill towards the previous row."""
    z_far = abs(ref[0]) + 200.0 + abs(ref[1]) * 2000 + abs(ref[2]) * 2000
    return float(np.max(np.abs(ay))) * z_far + max_gap + 5.0


class TextureMapper:
    """Maps texture rows, in scan order, onto the grid: each row's rays meet the surface
    (fixed-point iteration on ``height``, the fused heightmap: float32, missing cells NaN and
    taken at the reference), then the colours are splatted, filling the strip towards the
    previous row (which the mapper remembers between calls)."""

    def __init__(self, rays: np.ndarray, ref: np.ndarray, spec: GridSpec,
                 acc: ColorAccumulator, height: np.ndarray) -> None:
        self.ax = np.ascontiguousarray(rays[:, 0] / rays[:, 2])
        self.ay = np.ascontiguousarray(rays[:, 1] / rays[:, 2])
        self.ref, self.spec, self.acc, self.height = ref, spec, acc, height
        n = len(self.ax)
        self.state = (np.zeros(n), np.zeros(n), np.zeros((n, 3)), np.zeros(1, np.bool_))

    def map(self, travels: np.ndarray, colours: np.ndarray, i_lo: int = 0,
            i_hi: int | None = None) -> int:
        """Map rows (camera travel ``travels``, colours ``(n, N, 3)`` uint8) onto grid rows
        ``i_lo .. i_hi - 1``; returns how many samples fell on other rows (not added).
        ``i_lo == i_hi`` only moves the remembered previous row."""
        sp, acc = self.spec, self.acc
        hi = sp.shape[0] if i_hi is None else i_hi
        return int(_kernels().texture_rows(self.ax, self.ay, np.ascontiguousarray(travels, np.float64),
                                           self.ref, self.height, sp.x0_mm, sp.y0_mm, sp.pixel_mm,
                                           colours, acc.sum, acc.count, acc.mask,
                                           float(acc.max_gap_mm), *self.state, i_lo, hi))


def map_texture(rows, rays, travel, height, spec: GridSpec, ref: np.ndarray,
                acc: ColorAccumulator, chunk: int = 128) -> np.ndarray:
    """Each texture row's rays meet the reconstructed surface (fixed-point iteration on the
    fused heightmap, missing cells taken at the reference); colours are splatted there.

    The decoder has finished, so two threads share the work: one owns the grid rows before
    the middle of the scan, the other the rest, and each maps the texture rows that can reach
    its part. A cell's samples thus arrive in the same order as with one thread (the result
    does not depend on the split); each thread counts samples of rows only it mapped that
    fell in the other's part, and if there are any, the split was too tight and the mapping
    is redone in one thread."""
    from concurrent.futures import ThreadPoolExecutor

    height = np.ascontiguousarray(height, np.float32)
    frames = rows.frames
    s = np.asarray(travel, np.float64)[frames]
    n_rows = len(frames)

    def run(lo: int, hi: int, i_lo: int, i_hi: int, exclusive: tuple[int, int]) -> int:
        """Map spool rows lo..hi-1 (after one unsplatted row to start the fill) onto grid
        rows i_lo..i_hi-1; return samples of the ``exclusive`` rows that fell elsewhere."""
        mapper = TextureMapper(rays, ref, spec, acc, height)
        if lo > 0:
            mapper.map(s[lo - 1 : lo], rows.rows(lo - 1, lo), 0, 0)
        stray = 0
        for a in range(lo, hi, chunk):
            b = min(hi, a + chunk)
            for c0, c1 in _split(a, b, exclusive):
                miss = mapper.map(s[c0:c1], rows.rows(c0, c1), i_lo, i_hi)
                if exclusive[0] <= c0 and c1 <= exclusive[1]:
                    stray += miss
        return stray

    ax, ay = rays[:, 0] / rays[:, 2], rays[:, 1] / rays[:, 2]
    plan = texture_split(s, ax, ay, ref, spec, float(acc.max_gap_mm)) if n_rows > 4 * chunk \
        else None
    if plan is not None:
        (a_rows, a_excl, a_cells), (b_rows, b_excl, b_cells) = plan
        with ThreadPoolExecutor(2, thread_name_prefix="impress-texture") as pool:
            fa = pool.submit(run, a_rows[0], a_rows[1], a_cells[0], a_cells[1], a_excl)
            fb = pool.submit(run, b_rows[0], b_rows[1], b_cells[0], b_cells[1], b_excl)
            stray = fa.result() + fb.result()
        if stray == 0:
            return acc.mean()
        acc.sum[:] = 0
        acc.count[:] = 0
    run(0, n_rows, 0, spec.shape[0], (0, 0))
    return acc.mean()


def _split(a: int, b: int, cut: tuple[int, int]):
    """``a..b`` cut at the ends of ``cut`` (so no piece straddles them)."""
    edges = sorted({a, b, *[c for c in cut if a < c < b]})
    return list(zip(edges[:-1], edges[1:]))


def texture_split(s, ax, ay, ref, spec: GridSpec, max_gap: float):
    """Two halves of the texture mapping: ``((rows, exclusive rows, grid rows), ...)`` or
    None when the camera's travel is not monotonic. A texture row's samples lie within
    :func:`texture_reach` of its camera position; generous, and checked by the caller."""
    d = np.diff(s)
    if not (np.all(d > 0) or np.all(d < 0)):
        return None
    reach = texture_reach(ay, ref, max_gap)
    n = len(s)
    mid = n // 2
    i_mid = int(np.clip(np.rint((s[mid] - spec.y0_mm) / spec.pixel_mm), 1, spec.shape[0] - 1))
    y_mid = spec.y0_mm + (i_mid - 0.5) * spec.pixel_mm  # the boundary between the two parts
    below = s - reach < y_mid  # rows that may reach the grid rows before i_mid
    above = s + reach >= y_mid
    lo_rows, hi_rows = (below, above) if d[0] > 0 else (above, below)
    # with monotonic travel both sets are runs: one from the first row, one to the last
    a_end = int(np.argmin(lo_rows)) if not lo_rows.all() else n
    b_start = int(np.argmax(hi_rows))
    if not (lo_rows[:a_end].all() and hi_rows[b_start:].all()) or b_start == 0 or a_end == n:
        return None
    cells_first, cells_second = (0, i_mid), (i_mid, spec.shape[0])
    if d[0] < 0:
        cells_first, cells_second = cells_second, cells_first
    return ((0, a_end), (0, b_start), cells_first), ((b_start, n), (a_end, n), cells_second)


#: an end frame: ``(camera travel in mm, RGB frame)``
EndFrame = tuple[float, np.ndarray]


def _stripe_half_px(h: int) -> int:
    """Half the height (image rows) of the band masked around a laser's stripe."""
    return max(3, int(round(0.012 * h)))


def _stripe_mask(rgb: np.ndarray) -> np.ndarray:
    """The pixels of a frame on or near either laser's stripe (each stripe found in every row
    of the frame, widened by its halo)."""
    from impress_gui.core.reconstruction.stripes import LASERS, StripeParams, detect_band_blooming

    h, w = rgb.shape[:2]
    params = StripeParams()
    half = _stripe_half_px(h)
    mask = np.zeros((h, w), bool)
    cols = np.arange(w)
    for name in LASERS:
        rows = detect_band_blooming(name, rgb, 0, params).rows
        ok = np.isfinite(rows)
        for d in range(-half, half + 1):
            r = np.clip(np.rint(rows[ok]).astype(int) + d, 0, h - 1)
            mask[r, cols[ok]] = True
    return mask


def stripe_clear_travel(cal: SceneCalibration, travel_mm: float) -> float:
    """How far (mm) the camera must travel from ``travel_mm`` before the laser stripes of its
    frame have moved off the ground they covered there: the masked band around a stripe
    (:func:`_stripe_mask`) on the reference surface below the picture's centre, 1.5 times.
    The cells under an end frame's stripes are coloured from a frame that far into the scan
    (:func:`fill_texture_ends`)."""
    h = int(cal.intrinsics.image_size[1])
    band_px = 2 * _stripe_half_px(h) + 1
    y = float(travel_mm)
    z = float(cal.reference_depth(np.array(0.0), np.array(y)))
    uv = cal.project_rail(np.array([[0.0, y, z], [0.0, y + 1.0, z]]), y)
    px_per_mm = float(np.hypot(*(uv[1] - uv[0])))
    if not np.isfinite(px_per_mm) or px_per_mm <= 0:
        return float("nan")
    return 1.5 * band_px / px_per_mm


def end_frame_indices(cal: SceneCalibration, travel: np.ndarray, start: int, stop: int
                      ) -> tuple[list[int], list[int]]:
    """The frames :func:`fill_texture_ends` samples at each end of frames ``start .. stop -
    1`` (``travel``: the camera travel of every frame, mm): the end frame itself, then the
    nearest frame inside the run whose laser stripes have moved off the ground under the end
    frame's (:func:`stripe_clear_travel`), when there is one."""

    def picks(k: int, inward: range) -> list[int]:
        clear = stripe_clear_travel(cal, float(travel[k]))
        if np.isfinite(clear):
            for kk in inward:
                if abs(float(travel[kk]) - float(travel[k])) >= clear:
                    return [k, kk]
        return [k]

    last = stop - 1
    return picks(start, range(start + 1, stop)), picks(last, range(last - 1, start - 1, -1))


def _end_frames(end) -> list[EndFrame]:
    """An end's frames, in the order they are tried: one ``(travel, frame)`` or a sequence."""
    if isinstance(end, tuple) and len(end) == 2 and np.ndim(end[1]) == 3:
        return [(float(end[0]), end[1])]
    return [(float(t), img) for t, img in end]


#: cells projected at a time by :func:`fill_texture_ends`
_BLOCK = 1 << 18


def _sample_end_cells(tex: np.ndarray, filled: np.ndarray, height_mm: np.ndarray,
                      spec: GridSpec, cal: SceneCalibration, ii: np.ndarray, jj: np.ndarray,
                      todo: np.ndarray, travel: float, near: np.ndarray,
                      planes: list[np.ndarray]) -> np.ndarray:
    """Colour the cells ``(ii, jj)[todo]`` that fall inside the frame seen from ``travel`` and
    off its stripes (``near``) from its colour planes; return the others."""
    from scipy.ndimage import map_coordinates

    ci, cj = ii[todo], jj[todo]
    x = spec.x0_mm + cj * spec.pixel_mm
    y = spec.y0_mm + ci * spec.pixel_mm
    hv = height_mm[ci, cj]
    z = cal.reference_depth(x, y) - np.where(np.isfinite(hv), hv, 0.0)
    uv = _project(cal, np.column_stack([x, y, z]), travel)
    h, w = near.shape
    ok = np.all(np.isfinite(uv), axis=1) & (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) \
        & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)
    ok &= ~near[np.clip(np.rint(uv[:, 1]), 0, h - 1).astype(int),
                np.clip(np.rint(uv[:, 0]), 0, w - 1).astype(int)]
    if ok.any():
        coords = [uv[ok, 1], uv[ok, 0]]
        cols = np.stack([map_coordinates(pl, coords, order=1) for pl in planes], axis=1)
        ti, tj = ci[ok], cj[ok]
        tex[ti, tj] = np.clip(cols + 0.5, 0, 255).astype(tex.dtype)
        filled[ti, tj] = True
    return todo[~ok]


def _project(cal: SceneCalibration, pts_rail: np.ndarray, travel_mm: float) -> np.ndarray:
    """:meth:`SceneCalibration.project_rail` for millions of points, the product with the
    rotation written out per axis: ``@`` hands an (N, 3) by (3, 3) product to the BLAS
    library, whose threads wait on each other when another process holds a core (0.01 s on
    a quiet machine, 0.2-0.9 s for 1.3 million points beside a running job here) and whose
    kernels' rounding depends on the processor; products and sums of numpy's ufuncs give
    the same bits everywhere."""
    rel = pts_rail - np.array([0.0, travel_mm, 0.0])
    r = np.asarray(cal.rotation, float)
    cam = rel[:, 0:1] * r[0] + rel[:, 1:2] * r[1] + rel[:, 2:3] * r[2]
    return cal.intrinsics.project(cam)


def _runs(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rows, columns) of the cells with ``lo[j] <= row < hi[j]`` in each column ``j``, in row
    order (then column), as ``np.nonzero`` lists a mask's: only the rows the runs span are
    looked at."""
    ok = hi > lo
    if not ok.any():
        empty = np.zeros(0, np.int32)
        return empty, empty
    r0, r1 = int(lo[ok].min()), int(hi[ok].max())
    # by blocks of rows: a column whose run starts far from the others' would otherwise make
    # masks of (rows spanned) x (columns) cells, hundreds of MB on the whole rail
    out_i, out_j = [], []
    for a in range(r0, r1, _ROWS_BLOCK):
        rows = np.arange(a, min(r1, a + _ROWS_BLOCK))[:, None]
        ii, jj = np.nonzero((rows >= lo[None, :]) & (rows < hi[None, :]))
        out_i.append((ii + a).astype(np.int32))
        out_j.append(jj.astype(np.int32))
    return np.concatenate(out_i), np.concatenate(out_j)


#: rows looked at together when the first and last rows of a grid's columns are found
_ROWS_BLOCK = 512


def _first_last_rows(n_rows: int, mask_rows: Callable[[int, int], np.ndarray]
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Per column, the first and the last row where ``mask_rows(a, b)`` (the boolean mask of
    rows ``a .. b - 1``) is true: ``n_rows`` and -1 where it never is. Worked through by
    blocks of :data:`_ROWS_BLOCK` rows from each end, stopping when every column is found: no
    grid-sized mask (20 M cells: 20 MB for the mask, more for the temporaries that make it)."""
    first = last = None
    for a in range(0, n_rows, _ROWS_BLOCK):
        m = mask_rows(a, min(n_rows, a + _ROWS_BLOCK))
        if first is None:
            first = np.full(m.shape[1], n_rows, np.intp)
        hit = m.any(axis=0) & (first == n_rows)
        first[hit] = a + m.argmax(axis=0)[hit]
        if (first < n_rows).all():
            break
    for b in range(n_rows, 0, -_ROWS_BLOCK):
        a = max(0, b - _ROWS_BLOCK)
        m = mask_rows(a, b)[::-1]
        if last is None:
            last = np.full(m.shape[1], -1, np.intp)
        hit = m.any(axis=0) & (last == -1)
        last[hit] = b - 1 - m.argmax(axis=0)[hit]
        if (last >= 0).all():
            break
    assert first is not None and last is not None
    return first, last


def fill_texture_ends(texture_rgb: np.ndarray, height_mm: np.ndarray, spec: GridSpec,
                      cal: SceneCalibration, first, last, inplace: bool = False,
                      progress: Callable[[str], None] | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The texture at the scan's ends, where the heightmap reaches further than the texture
    row (the lasers lead and trail the image's centre): each cell without colour before the
    texture's first row or after its last (per column of the grid) is projected into the
    first (``first``) or last (``last``) processed frame, ``(camera travel in mm, RGB frame)``,
    and its colour sampled there (bilinear, on the distorted frame as the texture row is).
    Cells with a height are projected at their height; cells without one that lie between
    the heights' end and the texture's (a laser's shadow, e.g. before the L target's high
    face) at the reference, as the texture row maps them inside the scan.

    ``first`` and ``last`` may each be a sequence of frames, tried in order: a cell that falls
    on a frame's laser stripes (or outside it) is sampled in the next one. The stripes of the
    very first frame lie on the first cells with heights, so reconstruct passes a second
    frame a little further into the scan (:func:`stripe_clear_travel`); cells on the stripes
    of every frame given are left without colour, as are interior cells without colour
    (shadows). ``progress(message)`` is called before each frame is sampled. Returns the
    texture (a copy, or ``texture_rgb`` itself filled when ``inplace``) and the cells
    filled. Deterministic; occlusion is not checked (at the ends
    the surface is seen from close to straight above). Memory: a few boolean grids, no
    integer grid."""

    tex = texture_rgb if inplace else np.array(texture_rgb, copy=True)
    filled = np.zeros(tex.shape[:2], bool)
    # per column the texture's first and last row (the row's footprint may cross the grid
    # obliquely): cells before the first or after the last are at the scan's ends (one pass
    # per channel: tex.any(axis=2) takes ten times as long on a grid of pixels)
    n_rows = tex.shape[0]
    first_row, last_row = _first_last_rows(
        n_rows, lambda a, b: (tex[a:b, :, 0] | tex[a:b, :, 1] | tex[a:b, :, 2]) != 0)
    has_col = last_row >= 0
    if not has_col.any():
        return tex, filled
    # and the heights' first and last row: cells without a height between them and the
    # texture's are inside the scan
    h_first, h_last = _first_last_rows(n_rows, lambda a, b: np.isfinite(height_mm[a:b]))
    # the cells to colour at the first end are rows h_first .. first_row - 1 of each column
    # (no height lies before h_first, no colour before first_row), at the last end rows
    # last_row + 1 .. h_last: per end one run of rows per column, found in the few rows the
    # ends span rather than in grid-sized masks (20 M cells: 0.4 GB and 0.8 s of masks)
    lo_b, hi_b = np.where(has_col, h_first, n_rows), np.where(has_col, first_row, 0)
    lo_a, hi_a = np.where(has_col, last_row + 1, n_rows), np.where(has_col, h_last + 1, 0)
    parts = [_runs(lo_b, hi_b), _runs(lo_a, hi_a)]
    n_start = len(parts[0][0])
    # 32-bit indices: half the memory of nonzero's for the millions of cells at the ends
    ii = np.concatenate([parts[0][0], parts[1][0]]).astype(np.int32)
    jj = np.concatenate([parts[0][1], parts[1][1]]).astype(np.int32)
    del parts
    if not len(ii):
        return tex, filled
    ends = sorted([_end_frames(first), _end_frames(last)], key=lambda e: e[0][0])
    # cells before the texture's first row (lower Y) lie towards the frames of lower travel
    n_frames = len(ends[0]) + len(ends[1])
    done = 0
    for todo, frames in ((np.arange(n_start, dtype=np.int32), ends[0]),
                         (np.arange(n_start, len(ii), dtype=np.int32), ends[1])):
        for travel, img in frames:
            if not len(todo):
                break
            done += 1
            if progress is not None:
                progress(f"colouring the texture's ends: frame {done} of {n_frames} "
                         f"({len(todo)} cells)")
            # not on the frame's laser stripes (the stripes lie at the ends of the heights)
            near = _stripe_mask(img)
            planes = [img[..., c].astype(np.float32) for c in range(3)]
            # by blocks of cells: every step is per cell, so the result is the same as in one
            # go, without arrays of millions of points (each a fresh allocation, 3 times the
            # time when the process is large)
            left = [_sample_end_cells(tex, filled, height_mm, spec, cal, ii, jj, todo[k:k + _BLOCK],
                                      float(travel), near, planes)
                    for k in range(0, len(todo), _BLOCK)]
            todo = np.concatenate(left)
    return tex, filled
