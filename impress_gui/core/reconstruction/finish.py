"""Finishing the grid while the scan is still being read.

The camera moves one way along the rail, so the lasers leave grid rows behind that no later
frame can reach: a stripe point lies within fixed offsets (along Y) of the camera's travel,
known exactly from the per-run ray tables. :class:`RowFinisher` works through those rows in a
worker thread while the frame loop goes on - each laser's mean height, the fusion, then the
texture rows whose surface is final, and the texture's mean - so that after the last frame
only the tail of the scan is left to finish.

The result is identical to finishing everything after the loop (cells are independent, the
fusion's second pass only reads first-pass codes, texture rows are mapped in scan order).
The assumptions are checked: a stripe profile outside its laser's offsets, a texture sample
in a row already averaged or a height beyond the texture's reach sets :attr:`RowFinisher.broken`
and :meth:`RowFinisher.finish` redoes everything after the loop.
"""

from __future__ import annotations

import math
import threading

import numpy as np

from impress_gui.core.reconstruction.grid import (
    FUSE_RADIUS,
    ColorAccumulator,
    GridSpec,
    HeightAccumulator,
    fuse_rows,
)
from impress_gui.core.reconstruction.texture import (
    RowSpool,
    TextureMapper,
    map_texture,
    texture_reach,
)

#: heights beyond this (mm from the reference) could send texture rays past the reach
_HEIGHT_LIMIT_MM = 190.0


def stripe_footprint(rays: np.ndarray, normal: np.ndarray,
                     offset_mm: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """Ranges of ``x`` and of ``y - travel`` of a laser's stripe points: where the band's rays
    (a table from ``reconstruct._band_rays``) meet the laser plane; sub-pixel rows interpolate
    between neighbouring rays, so their points lie between these."""
    den = rays @ np.asarray(normal, np.float64)
    ok = np.abs(den) > 1e-12
    lam = offset_mm / den[ok]
    x = lam * rays[..., 0][ok]
    y = lam * rays[..., 1][ok]
    return (float(x.min()), float(x.max())), (float(y.min()), float(y.max()))


class TextureInputs:
    """What the texture mapping needs: the spooled rows, their rays and the camera travel."""

    def __init__(self, spool: RowSpool, rays: np.ndarray, travel: np.ndarray, ref: np.ndarray,
                 acc: ColorAccumulator) -> None:
        self.spool, self.rays, self.travel, self.ref, self.acc = spool, rays, travel, ref, acc


class RowFinisher:
    """Per-laser means, fused map and texture, finished row by row behind the scan.

    ``direction`` is +1 when the travel increases frame by frame, -1 when it decreases, 0 when
    it does not move one way (then everything is finished after the loop)."""

    def __init__(self, spec: GridSpec, acc: dict[str, HeightAccumulator], tol_mm: float,
                 offsets: dict[str, tuple[float, float]], direction: int,
                 texture: TextureInputs | None = None, weight_green: float = 0.5) -> None:
        self.spec, self.acc, self.tol, self.texture = spec, acc, tol_mm, texture
        self.weight_green = float(weight_green)  # in an agreeing pair's mean (grid.fuse)
        self.names = list(acc)
        self.offsets = offsets
        self.direction = direction
        self.per = {n: np.empty(spec.shape, np.float32) for n in self.names}
        # the texture's rays read the fused map near the rows already finished: the rest
        # must read as missing (at the reference), never as stale memory
        self.fused = np.full(spec.shape, np.nan, np.float32) if texture is not None else \
            np.empty(spec.shape, np.float32)
        self.diff = np.empty(spec.shape, np.float32)
        self.contrib = np.empty(spec.shape, np.uint8)
        self.tex: np.ndarray | None = None
        g = spec.pixel_mm
        # rows behind the camera's position (in scan order) that a stripe point can reach,
        # and the fill towards where a point was last found (up to the accumulators' largest
        # gap behind it)
        back = max(float(a.max_gap_mm) for a in acc.values())
        self._lag = (min(min(direction * a, direction * b) for a, b in offsets.values())
                     - back) / g
        self.broken: str | None = None
        self.n_mean = self.n_fused = self.n_tex = self.j_tex = 0  # rows done, in scan order
        self.rows_during_loop = 0
        self._mapper: TextureMapper | None = None
        self._reach = 0.0
        self._tex_acc: ColorAccumulator | None = None
        if texture is not None:
            rays = texture.rays
            self._reach = texture_reach(rays[:, 1] / rays[:, 2], texture.ref,
                                        float(texture.acc.max_gap_mm)) / g
            self.tex = np.empty((*spec.shape, 3), np.uint8)
            self._tex_acc = texture.acc
            ring = self._texture_ring(np.asarray(texture.travel, np.float64))
            if direction != 0 and ring < spec.shape[0]:
                # colour sums for the rows being mapped only, reused row after row: 14 bytes
                # per cell of the whole grid are never touched (texture.acc, the whole grid's
                # sums, is used only if everything has to be mapped again after the loop)
                self._tex_acc = ColorAccumulator(spec, float(texture.acc.max_gap_mm), ring)
        self._cond = threading.Condition()
        self._pending: float | None = None
        self._stop = False
        self.error: BaseException | None = None
        self._thread: threading.Thread | None = None
        if direction != 0:
            self._thread = threading.Thread(target=self._run, name="impress-finish", daemon=True)
            self._thread.start()

    #: texture rows mapped per call (between two averagings of the rows left behind)
    TEXTURE_CHUNK = 64

    def _texture_ring(self, travel: np.ndarray) -> int:
        """Rows of colour sums the mapping needs at once: from the oldest row not yet averaged
        (a reach behind the last row mapped) to the farthest a chunk of rows can reach, with a
        margin; as a power of two."""
        step = float(np.max(np.abs(np.diff(travel)))) / self.spec.pixel_mm if len(travel) > 1 \
            else 0.0
        need = 2 * self._reach + self.TEXTURE_CHUNK * step + 32
        return 1 << max(4, math.ceil(math.log2(need)))

    # ----- called by the frame loop ---------------------------------------------------------
    def check_range(self, name: str, travel: float, y_range: np.ndarray) -> None:
        """Note a profile whose valid points (least and greatest Y in ``y_range``, NaN when it
        has none) lie outside the laser's offsets (never expected)."""
        if self.direction == 0 or self.broken or not np.isfinite(y_range[0]):
            return
        lo, hi = self.offsets[name]
        if y_range[0] < travel + lo - 1e-6 or y_range[1] > travel + hi + 1e-6:
            self.broken = f"a {name} profile outside its offsets at travel {travel:.3f} mm"

    def post(self, travel: float) -> None:
        """The frame at ``travel`` has been added: rows behind it may be finished."""
        if self._thread is None:
            return
        if self.error is not None:
            raise self.error
        with self._cond:
            self._pending = travel
            self._cond.notify()

    def close(self) -> None:
        """Stop the worker (idempotent; the loop's ``finally``)."""
        if self._thread is None:
            return
        with self._cond:
            self._stop = True
            self._cond.notify()
        self._thread.join()
        self._thread = None

    def finish(self) -> None:
        """After the last frame: finish every remaining row (or all of them again if an
        assumption failed during the loop)."""
        self.close()
        if self.error is not None:
            raise self.error
        self.rows_during_loop = self.n_mean
        H = self.spec.shape[0]
        if self.broken or self.direction == 0:
            self._finish_all()
            return
        self._means(H)
        self._resolve(H)
        if self.texture is not None:
            self._map_texture(len(self.texture.spool), final=True)
            if self.broken:
                self._finish_all()
                return
            self._texture_means(H)

    def release(self) -> None:
        """Give back the accumulators' memory once :meth:`finish` has made every row: the
        per-laser sums and counts (6 bytes per cell and laser, a third of a run's grids) and the
        texture's. The maps the finish made (``per``, ``fused``, ``diff``, ``contrib``,
        ``tex``) stay. What runs after the finish (the islands, the texture's ends) then does
        not add its working memory on top of grids nothing reads any more (issue 19: the
        finish was the command's highest point)."""
        for a in self.acc.values():
            a.release()
        self._mapper = None
        self._tex_acc = None
        if self.texture is not None:
            self.texture.acc = None  # type: ignore[assignment]

    # ----- the worker -------------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            with self._cond:
                while self._pending is None and not self._stop:
                    self._cond.wait()
                travel, self._pending = self._pending, None
                if self._stop or travel is None:
                    return
            try:
                self._advance(travel)
            except BaseException as exc:  # noqa: BLE001 - raised in the loop by post()/finish()
                self.error = exc
                return

    def _q(self, y):
        """Position along the grid's rows in scan order (fractional row index)."""
        i = (np.asarray(y, np.float64) - self.spec.y0_mm) / self.spec.pixel_mm
        return i if self.direction > 0 else (self.spec.shape[0] - 1) - i

    def _rows(self, a: int, b: int) -> slice:
        """Scan-order rows ``a .. b - 1`` as a slice of the grid."""
        H = self.spec.shape[0]
        return slice(a, b) if self.direction > 0 else slice(H - b, H - a)

    def _advance(self, travel: float) -> None:
        if self.broken:
            return
        H = self.spec.shape[0]
        self._means(min(H, max(0, math.floor(float(self._q(travel)) + self._lag) - 2)))
        self._resolve(self.n_mean - FUSE_RADIUS if self.n_mean < H else H)
        if self.texture is not None and not self.broken:
            self._map_texture(len(self.texture.spool), final=False)

    def _means(self, target: int) -> None:
        if target <= self.n_mean:
            return
        sl = self._rows(self.n_mean, target)
        for n in self.names:
            self.acc[n].mean_rows(sl, self.per[n])
        # the fusion's first pass (conflicts wait until their neighbourhood is complete)
        fuse_rows(self.per[self.names[0]], self.per[self.names[1]], self.tol, self.fused,
                  self.diff, self.contrib, sl.start, sl.stop, resolve=(0, 0),
                  weight_green=self.weight_green)
        self.n_mean = target

    def _resolve(self, target: int) -> None:
        target = max(target, 0)
        if target <= self.n_fused:
            return
        sl = self._rows(self.n_fused, target)
        fuse_rows(self.per[self.names[0]], self.per[self.names[1]], self.tol, self.fused,
                  self.diff, self.contrib, 0, 0, resolve=(sl.start, sl.stop),
                  weight_green=self.weight_green)
        band = self.fused[sl]
        if (np.abs(band) > _HEIGHT_LIMIT_MM).any():
            self.broken = "heights beyond the texture's reach"
        self.n_fused = target

    def _map_texture(self, n_rows: int, final: bool) -> None:
        """Map spool rows whose surface is finished; average the texture rows no later row
        can reach."""
        tx = self.texture
        assert tx is not None
        if self.n_fused == 0 and not final:  # no row fused yet
            return
        acc = self._tex_acc
        assert acc is not None
        j0 = self.j_tex
        s = np.asarray(tx.travel, np.float64)[tx.spool.frames_between(j0, n_rows)]
        if not len(s):
            return
        if self._mapper is None:
            self._mapper = TextureMapper(tx.rays, tx.ref, self.spec, acc, self.fused)
            # rows before the first texture row's reach get no sample
            first = math.floor(float(self._q(s[0])) - self._reach) - 3
            self._texture_means(min(max(first, 0), self.n_fused))
        H = self.spec.shape[0]
        if final:
            j_end = n_rows
        else:
            ready = self._q(s) + self._reach + 3 < self.n_fused
            j_end = j0 + (int(np.argmin(ready)) if not ready.all() else len(ready))
        for a in range(j0, j_end, self.TEXTURE_CHUNK):
            if self._stop and not final:
                return
            b = min(j_end, a + self.TEXTURE_CHUNK)
            # the rows not yet averaged, as far as the sums hold them
            keep = self._rows(self.n_tex, min(H, self.n_tex + acc.rows))
            stray = self._mapper.map(s[a - j0 : b - j0], tx.spool.rows(a, b), keep.start,
                                     keep.stop)
            if stray:
                self.broken = f"{stray} texture samples in rows already averaged or beyond " \
                              f"the rows held"
                return
            self.j_tex = b
            # rows no later texture row can reach are final
            done = math.floor(float(self._q(s[b - 1 - j0])) - self._reach) - 3
            self._texture_means(min(max(done, 0), self.n_fused))

    def _texture_means(self, target: int) -> None:
        tx = self.texture
        assert tx is not None and self.tex is not None
        if target <= self.n_tex:
            return
        assert self._tex_acc is not None
        sl = self._rows(self.n_tex, target)
        self._tex_acc.take_rows(sl, self.tex)
        self.n_tex = target

    def _finish_all(self) -> None:
        """Everything after the loop, from the accumulators (the reference path)."""
        H = self.spec.shape[0]
        for n in self.names:
            self.acc[n].mean_rows(slice(0, H), self.per[n])
        fuse_rows(self.per[self.names[0]], self.per[self.names[1]], self.tol, self.fused,
                  self.diff, self.contrib, 0, H, weight_green=self.weight_green)
        self.n_mean = self.n_fused = H
        tx = self.texture
        if tx is not None:
            tx.acc.sum[:] = 0
            tx.acc.count[:] = 0
            self.tex = map_texture(tx.spool, tx.rays, tx.travel, self.fused, self.spec, tx.ref,
                                   tx.acc)
