"""Large maps on screen: a multi-resolution pyramid and a view-sized crop.

A 1.75 m scan at 0.1 mm is about 17,500 x 2,700 cells. Letting pyqtgraph downsample the whole
array at every zoom step costs hundreds of milliseconds, so :class:`LodImage` keeps a pyramid
(each level the 2 x 2 mean of the one below, NaN-aware) and gives its ImageItem only the part
of the level closest to the screen's resolution that covers the view plus a margin. Panning
inside the margin costs nothing; a new crop costs a few tens of milliseconds whatever the map's
size. This is display only: every measurement reads the full-resolution arrays.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QObject, QRectF, QTimer

from impress_gui.core.reconstruction.grid import GridSpec
from impress_gui.ui.worker import Worker

MIN_LEVEL_SIZE = 512
MARGIN = 0.2  # of the view's size, on each side


def reduce2(a: np.ndarray, nearest: bool = False) -> np.ndarray:
    """One pyramid step: 2 x 2 blocks -> one cell (mean of the cells with data for floats,
    mean for RGB bytes, the top-left cell for categorical maps). Odd last rows/columns drop."""
    h, w = (a.shape[0] // 2) * 2, (a.shape[1] // 2) * 2
    if nearest:
        return np.ascontiguousarray(a[0:h:2, 0:w:2])
    if a.dtype == np.uint8:
        q = a[:h, :w].astype(np.uint16)
        s = q[0::2, 0::2] + q[1::2, 0::2] + q[0::2, 1::2] + q[1::2, 1::2]
        return ((s + 2) // 4).astype(np.uint8)
    out = np.empty((h // 2, w // 2), np.float32)
    for r0 in range(0, h, 4096):  # bounded temporaries
        b = a[r0 : min(h, r0 + 4096), :w]
        ok = np.isfinite(b)
        z = np.where(ok, b, 0).astype(np.float32)
        s = z[0::2, 0::2] + z[1::2, 0::2] + z[0::2, 1::2] + z[1::2, 1::2]
        n = ok[0::2, 0::2].astype(np.uint8) + ok[1::2, 0::2] + ok[0::2, 1::2] + ok[1::2, 1::2]
        with np.errstate(invalid="ignore", divide="ignore"):
            out[r0 // 2 : (r0 + b.shape[0]) // 2] = np.where(n > 0, s / n, np.nan)
    return out


def pyramid(
    a: np.ndarray, nearest: bool = False, min_size: int = MIN_LEVEL_SIZE, cancel=None
) -> list[np.ndarray]:
    levels = [a]
    while max(levels[-1].shape[:2]) > min_size and min(levels[-1].shape[:2]) >= 4:
        if cancel is not None:
            cancel.check()
        levels.append(reduce2(levels[-1], nearest))
    return levels


def strided_pyramid(a: np.ndarray, min_size: int = MIN_LEVEL_SIZE) -> list[np.ndarray]:
    """Instant stand-in levels (views, no copies) until the mean pyramid is ready."""
    levels, k = [a], 1
    while max(a.shape[:2]) // (2**k) >= min_size // 2 and min(a.shape[:2]) // 2**k >= 2:
        s = 2**k
        h, w = (a.shape[0] // s) * s, (a.shape[1] // s) * s
        levels.append(a[0:h:s, 0:w:s])
        if max(levels[-1].shape[:2]) <= min_size:
            break
        k += 1
    return levels


#: the automatic colour range: these percentiles of the evidence area's cells with data
AUTO_PERCENTILES = (1.0, 99.0)
#: cells this far around the calibration target's corners are not evidence
TARGET_MARGIN_MM = 5.0
Footprint = tuple[float, float, float, float]  # x_min, x_max, y_min, y_max (mm)


def target_footprint_mm(metadata, folder: Path | None = None) -> Footprint | None:
    """Where the calibration target lies on the grid (rail mm, its corners' box), if the
    reconstruction knows: its metadata names the calibration file (``inputs.calibration``)
    and that file, still the same (SHA-256), holds the target's corners in the rail frame
    (``corners_parallax_mm``), the frame of the grid. None otherwise."""
    try:
        ref = (metadata or {}).get("inputs", {}).get("calibration", {}) or {}
        path = Path(str(ref.get("path") or ""))
    except AttributeError:
        return None
    if not ref.get("path"):
        return None
    cands = [path] + ([folder / path.name, folder.parent / path.name] if folder else [])
    for p in cands:
        try:
            raw = p.read_bytes()
        except OSError:
            continue
        if ref.get("sha256") and hashlib.sha256(raw).hexdigest() != ref["sha256"]:
            continue
        try:
            corners = json.loads(raw)["corners_parallax_mm"]
            xy = np.array([[float(c[0]), float(c[1])] for c in corners.values()])
        except (ValueError, KeyError, TypeError, IndexError, AttributeError):
            return None
        if xy.shape[0] < 3 or not np.isfinite(xy).all():
            return None
        return (
            float(xy[:, 0].min()),
            float(xy[:, 0].max()),
            float(xy[:, 1].min()),
            float(xy[:, 1].max()),
        )
    return None


def auto_levels(
    arr: np.ndarray,
    spec: GridSpec | None = None,
    target_mm: Footprint | None = None,
    samples: float = 250_000,
) -> tuple[float, float]:
    """The automatic colour range of a height map: the 1 and 99 percentiles
    (:data:`AUTO_PERCENTILES`) of the evidence area's cells with data, on a regular
    subsample. The evidence area is the map less the calibration target (``target_mm``,
    from :func:`target_footprint_mm`, widened by :data:`TARGET_MARGIN_MM`) when its place
    is known: the 40 mm target would otherwise stretch the range and leave the impression
    a narrow band of one colour. Without it the percentiles alone keep a small target out."""
    step = max(1, int(math.sqrt(arr.size / samples)))
    v = arr[::step, ::step]
    ok = np.isfinite(v)
    if target_mm is not None and spec is not None:
        x0, x1, y0, y1 = target_mm
        m = TARGET_MARGIN_MM
        xs = spec.x0_mm + spec.pixel_mm * step * np.arange(v.shape[1])
        ys = spec.y0_mm + spec.pixel_mm * step * np.arange(v.shape[0])
        on_target = ((ys >= y0 - m) & (ys <= y1 + m))[:, None] & ((xs >= x0 - m) & (xs <= x1 + m))[
            None, :
        ]
        if (ok & ~on_target).sum() >= 100:  # else the map is (nearly) all target
            ok &= ~on_target
    v = v[ok]
    if v.size == 0:
        return (-1.0, 1.0)
    lo, hi = np.percentile(v, AUTO_PERCENTILES)
    if hi - lo < 0.1:
        lo, hi = lo - 0.05, hi + 0.05
    return float(round(lo, 2)), float(round(hi, 2))


class LodImage(QObject):
    """Shows a map in ``item`` (inside ``view_box``) at the resolution the view needs."""

    def __init__(
        self, item: pg.ImageItem, view_box: pg.ViewBox, name: str = "map", delay_ms: int = 150
    ) -> None:
        """``delay_ms``: the pyramid is started that long after new data is shown, so that the
        first picture is painted without worker threads competing for the interpreter."""
        super().__init__(view_box)
        self.item, self.vb = item, view_box
        self.name = name
        self.item.setAutoDownsample(False)
        self.levels: list[np.ndarray] = []
        self.spec: GridSpec | None = None
        self.colour_levels: tuple[float, float] | None = None
        self.shown: tuple[int, int, int, int, int] | None = None  # level, i0, i1, j0, j1
        self._builder = Worker(parent=self, name=f"pyramid-{name}")
        self._builder.finished.connect(self._on_pyramid)
        self._start_timer = QTimer(self, singleShot=True, interval=delay_ms)
        self._start_timer.timeout.connect(self._start_pyramid)
        self._pending: tuple[int, np.ndarray] | None = None
        self._token = 0
        self.crops = 0  # how many crops were uploaded (benchmarks, tests)
        view_box.sigRangeChanged.connect(lambda *_: self.update_view())
        view_box.sigResized.connect(lambda *_: self.update_view())

    # ----- content ----------------------------------------------------------------------------
    def set_data(
        self,
        arr: np.ndarray | None,
        spec: GridSpec | None,
        colour_levels: tuple[float, float] | None = None,
        nearest: bool = False,
    ) -> None:
        """Show ``arr`` (H x W floats, or H x W x 3 bytes) on ``spec``'s grid; the mean pyramid
        is built in the background, strided levels stand in meanwhile."""
        self._builder.shutdown()
        self._start_timer.stop()
        self._pending = None
        self._token += 1
        self.spec = spec
        self.colour_levels = colour_levels
        self.shown = None
        if arr is None or spec is None:
            self.levels = []
            self.item.clear()
            return
        self.levels = strided_pyramid(arr)
        self.update_view()
        if len(self.levels) > 1 and not nearest:
            token = self._token
            self._pending = (token, arr)
            self._start_timer.start()

    def _start_pyramid(self) -> None:
        if self._pending is None or self._pending[0] != self._token:
            return
        token, arr = self._pending
        self._pending = None
        self._builder.start(lambda _p, cancel: (token, pyramid(arr, cancel=cancel)))

    def set_colour_levels(self, levels: tuple[float, float] | None) -> None:
        self.colour_levels = levels
        if levels is not None and self.shown is not None:
            self.item.setLevels(levels)

    def is_building(self) -> bool:
        return self._builder.is_running() or self._pending is not None

    def shutdown(self) -> None:
        self._start_timer.stop()
        self._pending = None
        self._builder.shutdown()

    def _on_pyramid(self, result) -> None:
        token, levels = result
        if token != self._token:
            return
        self.levels = levels
        self.shown = None
        self.update_view()

    # ----- view -------------------------------------------------------------------------------
    def level_for_view(self) -> int:
        if not self.levels or self.spec is None:
            return 0
        px = self.vb.viewPixelSize()
        per_px = max(min(px[0], px[1]), 1e-12) / self.spec.pixel_mm  # cells per screen pixel
        k = int(math.floor(math.log2(per_px) + 0.5)) if per_px > 0 else 0
        return max(0, min(len(self.levels) - 1, k))

    def update_view(self) -> None:
        if not self.levels or self.spec is None:
            return
        s = self.spec
        k = self.level_for_view()
        lev = self.levels[k]
        cell = s.pixel_mm * 2**k
        left, bottom = s.x0_mm - s.pixel_mm / 2, s.y0_mm - s.pixel_mm / 2
        r = self.vb.viewRect()
        h, w = lev.shape[:2]

        def idx(v0, v1, origin, n):
            a = int(math.floor((v0 - origin) / cell))
            b = int(math.ceil((v1 - origin) / cell))
            return max(0, min(n, a)), max(0, min(n, b))

        vi0, vi1 = idx(r.top(), r.bottom(), bottom, h)  # QRectF top() is the smaller y
        vj0, vj1 = idx(r.left(), r.right(), left, w)
        if self.shown is not None:
            k0, i0, i1, j0, j1 = self.shown
            if k0 == k and i0 <= vi0 and vi1 <= i1 and j0 <= vj0 and vj1 <= j1:
                return  # the view is still inside the crop
        mi = int(math.ceil(MARGIN * (r.height() / cell))) + 1
        mj = int(math.ceil(MARGIN * (r.width() / cell))) + 1
        i0, i1 = max(0, vi0 - mi), min(h, vi1 + mi)
        j0, j1 = max(0, vj0 - mj), min(w, vj1 + mj)
        if i1 <= i0 or j1 <= j0:
            self.item.clear()
            self.shown = (k, i0, i1, j0, j1)
            return
        crop = lev[i0:i1, j0:j1]
        if self.colour_levels is not None and crop.ndim == 2:
            self.item.setImage(crop, autoLevels=False, levels=self.colour_levels)
        else:
            self.item.setImage(crop, autoLevels=False, levels=(0, 255))
        self.item.setRect(
            QRectF(left + j0 * cell, bottom + i0 * cell, (j1 - j0) * cell, (i1 - i0) * cell)
        )
        self.shown = (k, i0, i1, j0, j1)
        self.crops += 1
