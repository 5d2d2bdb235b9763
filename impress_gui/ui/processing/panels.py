"""Widgets of the processing tab: the parameter form, the background lookup tables (thesis
figure 3.5) and the run panel (progress, frames/s, time remaining, cancel)."""

from __future__ import annotations

import re
import time

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QRectF, Signal
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QProgressBar,
    QPushButton,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from impress_gui.core.reconstruction.grid import GridSpec
from impress_gui.core.reconstruction.reconstruct import ProcessParams
from impress_gui.core.reconstruction.stripes import LASERS, METHODS
from impress_gui.ui.viewer.image import auto_levels
from impress_gui.ui.viewer.map import RAIL_TEXT, X_LABEL, Y_LABEL

METHOD_TEXT = {
    "combined": "combined (hue or lookup table)",
    "hue": "hue (HSV ranges)",
    "lut": "background lookup table",
}
_FRAME = re.compile(r"frame (\d+)/(\d+)")


def _dspin(lo, hi, value, step, decimals=2, suffix=" mm") -> QDoubleSpinBox:
    s = QDoubleSpinBox()
    s.setRange(lo, hi)
    s.setDecimals(decimals)
    s.setSingleStep(step)
    s.setValue(value)
    s.setSuffix(suffix)
    s.setKeyboardTracking(False)
    return s


def _ispin(lo, hi, value, prefix="") -> QSpinBox:
    s = QSpinBox()
    s.setRange(lo, hi)
    s.setValue(value)
    s.setPrefix(prefix)
    s.setKeyboardTracking(False)
    return s


class ParamsPanel(QGroupBox):
    """Every :class:`ProcessParams` field the analyst may change; ``changed`` on any edit."""

    changed = Signal()

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__("Parameters", parent)
        g = QGridLayout(self)
        d = ProcessParams()
        # not shown: the largest floating piece dropped (ProcessParams.floating_max_cells),
        # kept as a reopened project was processed
        self.floating_cells = d.floating_max_cells
        self.method = QComboBox()
        for m in METHODS:
            self.method.addItem(METHOD_TEXT.get(m, m), m)
        self.min_peak = _dspin(1, 255, d.min_peak, 1, 0, " grey levels")
        self.min_peak.setToolTip("Minimum stripe peak above the column's local background")
        self.frame_start = _ispin(0, 10**7, 0, "from ")
        self.frame_stop = _ispin(1, 10**7, 1, "to ")
        self.frame_stop.setToolTip("One past the last frame processed")
        self.default_frames = QPushButton("Default")
        self.default_frames.setToolTip("Skip 0.5 s at each end (the motor's ramps)")
        self.grid_mm = _dspin(0.01, 5.0, d.grid_mm, 0.05, 3)
        self.fuse_tol = _dspin(0.05, 10.0, d.fuse_tolerance_mm, 0.1)
        self.fuse_tol.setToolTip("Green and red heights closer than this are averaged")
        self.max_step = _dspin(0.05, 20.0, d.max_step_mm, 0.1)
        self.max_step.setToolTip("Larger jumps between neighbouring points are edges")
        self.weak_ratio = _dspin(0.0, 0.95, d.weak_run_ratio, 0.05, 2, suffix="")  # a share
        self.weak_ratio.setToolTip(
            "Short stripe pieces weaker than this share of the frame's stripe are dropped "
            "(soil of the laser's colour is not the stripe), unless they continue a longer "
            "piece across gaps of a few columns (a faint stripe found in pieces); 0 keeps "
            "every piece")
        self.texture = QCheckBox("Registered texture")
        self.texture.setChecked(d.texture)
        self.unlit_soil = QCheckBox("Subtract the soil seen unlit")
        self.unlit_soil.setChecked(d.unlit_soil)
        self.unlit_soil.setToolTip(
            "Before the stripe's centre is estimated, take out the soil under it as earlier "
            "frames saw it, unlit: grainy soil no longer moves a dim stripe's centre")
        self.reconcile = QCheckBox("Reconcile the two lasers across the map")
        self.reconcile.setChecked(d.reconcile_lasers)
        self.reconcile.setToolTip(
            "Share the part of the green and red heights' difference that runs across the "
            "map between the two lasers' maps: the scan's ends one laser saw alone read "
            "what the pair reads where both measured")
        self.auto_rois = QCheckBox("Automatic regions of interest (from the calibration)")
        self.auto_rois.setChecked(True)
        self.h_lo = _dspin(-200, 200, d.height_range_mm[0], 5, 0)
        self.h_hi = _dspin(-200, 400, d.height_range_mm[1], 5, 0)
        self.roi: dict[str, tuple[QSpinBox, QSpinBox]] = {}
        row = 0
        for text, w in (("Detection", self.method), ("Minimum peak", self.min_peak)):
            g.addWidget(QLabel(text), row, 0)
            g.addWidget(w, row, 1, 1, 3)
            row += 1
        g.addWidget(QLabel("Frames"), row, 0)
        g.addWidget(self.frame_start, row, 1)
        g.addWidget(self.frame_stop, row, 2)
        g.addWidget(self.default_frames, row, 3)
        row += 1
        for text, w in (
            ("Grid", self.grid_mm),
            ("Fusion tolerance", self.fuse_tol),
            ("Edge step", self.max_step),
            ("Weak pieces", self.weak_ratio),
        ):
            g.addWidget(QLabel(text), row, 0)
            g.addWidget(w, row, 1, 1, 3)
            row += 1
        g.addWidget(self.texture, row, 0, 1, 4)
        row += 1
        g.addWidget(self.unlit_soil, row, 0, 1, 4)
        row += 1
        g.addWidget(self.reconcile, row, 0, 1, 4)
        row += 1
        g.addWidget(self.auto_rois, row, 0, 1, 4)
        row += 1
        g.addWidget(QLabel("Heights for the regions"), row, 0)
        g.addWidget(self.h_lo, row, 1)
        g.addWidget(self.h_hi, row, 2)
        row += 1
        for name in LASERS:
            a, b = _ispin(0, 100000, 0, "rows "), _ispin(1, 100000, 1, "to ")
            self.roi[name] = (a, b)
            g.addWidget(QLabel(f"{name.capitalize()} region"), row, 0)
            g.addWidget(a, row, 1)
            g.addWidget(b, row, 2)
            row += 1
        for w in (self.method,):
            w.currentIndexChanged.connect(lambda _i: self.changed.emit())
        for w in (
            self.min_peak,
            self.frame_start,
            self.frame_stop,
            self.grid_mm,
            self.fuse_tol,
            self.max_step,
            self.weak_ratio,
            self.h_lo,
            self.h_hi,
            *[s for ab in self.roi.values() for s in ab],
        ):
            w.valueChanged.connect(lambda _v: self.changed.emit())
        for w in (self.texture, self.unlit_soil, self.reconcile, self.auto_rois):
            w.toggled.connect(lambda _on: self.changed.emit())
        self.auto_rois.toggled.connect(self._enable_rois)
        self._enable_rois(True)

    def _enable_rois(self, auto: bool) -> None:
        for a, b in self.roi.values():
            a.setEnabled(not auto)
            b.setEnabled(not auto)

    def set_frame_count(self, n: int) -> None:
        for s in (self.frame_start, self.frame_stop):
            s.blockSignals(True)
        self.frame_start.setRange(0, max(0, n - 1))
        self.frame_stop.setRange(1, max(1, n))
        for s in (self.frame_start, self.frame_stop):
            s.blockSignals(False)

    def set_image_height(self, h: int) -> None:
        for a, b in self.roi.values():
            a.setRange(0, max(0, h - 1))
            b.setRange(1, max(1, h))

    def rois(self) -> dict[str, tuple[int, int]]:
        return {n: (a.value(), b.value()) for n, (a, b) in self.roi.items()}

    def show_rois(self, rois: dict[str, tuple[int, int]]) -> None:
        self.blockSignals(True)
        for n, (a, b) in rois.items():
            if n in self.roi:
                self.roi[n][0].setValue(int(a))
                self.roi[n][1].setValue(int(b))
        self.blockSignals(False)

    def params(self) -> ProcessParams:
        return ProcessParams(
            method=str(self.method.currentData()),
            frame_start=self.frame_start.value(),
            frame_stop=self.frame_stop.value(),
            grid_mm=self.grid_mm.value(),
            height_range_mm=(self.h_lo.value(), self.h_hi.value()),
            rois={} if self.auto_rois.isChecked() else self.rois(),
            min_peak=self.min_peak.value(),
            fuse_tolerance_mm=self.fuse_tol.value(),
            max_step_mm=self.max_step.value(),
            weak_run_ratio=self.weak_ratio.value(),
            texture=self.texture.isChecked(),
            unlit_soil=self.unlit_soil.isChecked(),
            reconcile_lasers=self.reconcile.isChecked(),
            floating_max_cells=self.floating_cells,
        )

    def set_params(self, doc: dict) -> None:
        """Restore from a project's ``processing`` section (unknown keys are ignored)."""
        self.blockSignals(True)
        if doc.get("method") in METHODS:
            self.method.setCurrentIndex(self.method.findData(doc["method"]))
        for key, w in (
            ("min_peak", self.min_peak),
            ("grid_mm", self.grid_mm),
            ("fuse_tolerance_mm", self.fuse_tol),
            ("max_step_mm", self.max_step),
            ("weak_run_ratio", self.weak_ratio),
        ):
            if isinstance(doc.get(key), (int, float)):
                w.setValue(float(doc[key]))
        for key, w in (("frame_start", self.frame_start), ("frame_stop", self.frame_stop)):
            if isinstance(doc.get(key), int):
                w.setValue(doc[key])
        if isinstance(doc.get("texture"), bool):
            self.texture.setChecked(doc["texture"])
        # a project saved before the option existed was processed without it
        self.unlit_soil.setChecked(doc.get("unlit_soil") is True)
        # and without reconciling the lasers (2026-12-07)
        self.reconcile.setChecked(doc.get("reconcile_lasers") is True)
        # and without dropping floating pieces (2026-12-06)
        fc = doc.get("floating_max_cells")
        self.floating_cells = fc if type(fc) is int and 0 <= fc <= 10000 else 0
        hr = doc.get("height_range_mm")
        if isinstance(hr, list) and len(hr) == 2:
            self.h_lo.setValue(float(hr[0]))
            self.h_hi.setValue(float(hr[1]))
        rois = doc.get("rois")
        if isinstance(rois, dict) and rois:
            self.auto_rois.setChecked(False)
            self.show_rois({k: tuple(v) for k, v in rois.items()})
        self.blockSignals(False)


class LutView(pg.GraphicsLayoutWidget):
    """The background lookup tables: for each laser, the largest laser-channel value seen in
    the background for each pair of the other two channels (black: never seen). The axes start
    at 0 (a channel value / 4 is never negative); the colour bar gives the values' scale."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setMinimumHeight(220)
        self.items: dict[str, pg.ImageItem] = {}
        self.plots: dict[str, pg.PlotItem] = {}
        axes = {"green": ("red", "blue"), "red": ("green", "blue")}
        cmap = pg.colormap.get("inferno")
        for name in LASERS:
            p = self.addPlot(
                title=f"{name}: max {name[0].upper()} over ({axes[name][0][0].upper()}"
                f", {axes[name][1][0].upper()})"
            )
            p.setLabel("bottom", f"{axes[name][1]} / 4")
            p.setLabel("left", f"{axes[name][0]} / 4")
            # not aspect-locked: the view is exactly the table, 0 at the axes' origin
            p.setMenuEnabled(False)
            item = pg.ImageItem(axisOrder="row-major")
            item.setLookupTable(cmap.getLookupTable(nPts=256))
            item.setLevels((0, 255))
            p.addItem(item)
            self.items[name] = item
            self.plots[name] = p
        self.colour_bar = pg.ColorBarItem(
            values=(0, 255),
            colorMap=cmap,
            label="max laser-channel value (0-255)",
            interactive=False,
        )
        self.colour_bar.setImageItem(list(self.items.values()))
        self.addItem(self.colour_bar)
        self._fit((64, 64))

    def _fit(self, shape: tuple[int, int]) -> None:
        """Show the tables from 0 to their size on both axes, no negative range."""
        h, w = int(shape[0]), int(shape[1])
        for p in self.plots.values():
            p.getViewBox().setLimits(xMin=0, yMin=0, xMax=max(1, w), yMax=max(1, h))
            p.setRange(xRange=(0, max(1, w)), yRange=(0, max(1, h)), padding=0)

    def set_tables(self, tables: dict[str, np.ndarray]) -> None:
        shape = None
        for name, t in tables.items():
            img = np.where(t < 0, 0, t).astype(np.float32)
            self.items[name].setImage(img, autoLevels=False, levels=(0, 255))
            shape = img.shape[:2]
        if shape is not None:
            self._fit(shape)


class GrowingMap(pg.PlotWidget):
    """The partial heightmap of a running reconstruction, oriented as the viewer shows maps
    (as the camera sees the ground from above, as ``texture.png`` is stored): grid row 0 at
    the top, y - the rail's direction of motion - increasing downwards, x to the right.

    With the preview's grid (:meth:`set_grid`, the decimated grid's :class:`GridSpec`) the
    axes are rail millimetres; without it, cells of the preview."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent, background="k")
        self.setMinimumHeight(180)
        pi = self.getPlotItem()
        pi.setTitle(RAIL_TEXT, size="9pt", color=(230, 230, 230))
        pi.getViewBox().invertY(True)
        pi.getViewBox().setAspectLocked(True)
        pi.setMenuEnabled(False)
        self.item = pg.ImageItem(axisOrder="row-major")
        self.item.setLookupTable(pg.colormap.get("turbo").getLookupTable(nPts=256))
        pi.addItem(self.item)
        self.spec: GridSpec | None = None
        self.target_mm: tuple[float, float, float, float] | None = None
        self.levels: tuple[float, float] | None = None
        self._set_labels()

    def _set_labels(self) -> None:
        pi = self.getPlotItem()
        if self.spec is None:
            pi.setLabel("bottom", "x (preview cells)")
            pi.setLabel("left", "y (preview cells), down: rail motion")
        else:
            pi.setLabel("bottom", X_LABEL)
            pi.setLabel("left", Y_LABEL)

    def set_grid(self, spec: GridSpec | None) -> None:
        """The preview's grid: cell ``[i, j]`` centred at rail ``(x0 + j p, y0 + i p)`` mm."""
        self.spec = spec
        self._set_labels()

    def set_target(self, target_mm: tuple[float, float, float, float] | None) -> None:
        """The calibration target's box (rail mm), left out of the colour range."""
        self.target_mm = target_mm

    def show_map(self, height: np.ndarray, fit: bool = True) -> None:
        """Heights in the viewer's automatic colour range (:func:`auto_levels`: the 1..99
        percentiles, the target left out when the grid and its place are known)."""
        h, w = height.shape[:2]
        s = self.spec if self.spec is not None and tuple(self.spec.shape) == (h, w) else None
        self.levels = auto_levels(height, s, self.target_mm)
        lo = self.levels[0]
        self.item.setImage(np.nan_to_num(height, nan=lo), autoLevels=False, levels=self.levels)
        if s is not None:
            rect = QRectF(s.x0_mm - s.pixel_mm / 2, s.y0_mm - s.pixel_mm / 2, w * s.pixel_mm,
                          h * s.pixel_mm)
        else:
            rect = QRectF(-0.5, -0.5, w, h)
        self.item.setRect(rect)
        if fit:
            self.getPlotItem().getViewBox().setRange(rect, padding=0.02)


class RunPanel(QGroupBox):
    """Run/Cancel, progress bar, frames per second and time remaining (from the core's
    ``frame i/n`` progress messages)."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__("Reconstruction", parent)
        v = QVBoxLayout(self)
        self.output_label = QLabel("Output: -")
        self.output_label.setWordWrap(True)
        v.addWidget(self.output_label)
        row = QHBoxLayout()
        self.run_button = QPushButton("Run")
        self.run_button.setStyleSheet("font-weight: bold; padding: 6px")
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.setEnabled(False)
        row.addWidget(self.run_button)
        row.addWidget(self.cancel_button)
        v.addLayout(row)
        self.bar = QProgressBar()
        self.bar.setRange(0, 1000)
        v.addWidget(self.bar)
        self.rate = QLabel("")
        self.message = QLabel("")
        self.message.setWordWrap(True)
        v.addWidget(self.rate)
        v.addWidget(self.message)
        # the heightmap as it grows during the run (decimated; heights in a turbo colour map)
        self.growing = GrowingMap()
        self.growing.hide()
        v.addWidget(self.growing)
        self.growing_updates = 0
        self._t0 = 0.0
        self._first: tuple[float, int] | None = None
        self.frames_per_second = 0.0
        self.remaining_s: float | None = None

    def show_growing(self, height: np.ndarray) -> None:
        """Show the partial heightmap (rows along the scan) sent by the running job."""
        if not np.isfinite(height).any():
            return
        self.growing.show_map(height, fit=self.growing_updates == 0)
        self.growing.show()
        self.growing_updates += 1

    def start(self) -> None:
        self.growing_updates = 0
        self._t0 = time.monotonic()
        self._first = None
        self.frames_per_second, self.remaining_s = 0.0, None
        self.bar.setValue(0)
        self.rate.setText("starting...")
        self.message.setText("")
        self.run_button.setEnabled(False)
        self.cancel_button.setEnabled(True)

    def progress(self, fraction: float, message: str) -> None:
        self.bar.setValue(int(1000 * max(0.0, min(1.0, fraction))))
        self.message.setText(message)
        m = _FRAME.search(message)
        now = time.monotonic()
        if m:
            i, n = int(m.group(1)), int(m.group(2))
            if self._first is None:
                self._first = (now, i)
            t1, i1 = self._first
            if i > i1 and now > t1:
                self.frames_per_second = (i - i1) / (now - t1)
                # the frame loop is 85 % of the run; the rest scales with it
                self.remaining_s = (n - i) / self.frames_per_second + 0.15 * (now - self._t0)
        elapsed = now - self._t0
        rem = "-" if self.remaining_s is None else f"{self.remaining_s:.0f} s"
        self.rate.setText(
            f"{self.frames_per_second:.1f} frames/s, elapsed {elapsed:.0f} s, about {rem} remaining"
        )

    def stop(self, outcome: str, frames_per_second: float | None = None) -> None:
        """The run ended; ``frames_per_second``, when known, replaces the running estimate."""
        if frames_per_second:
            self.frames_per_second = float(frames_per_second)
        self.run_button.setEnabled(True)
        self.cancel_button.setEnabled(False)
        self.rate.setText(
            f"{outcome} after {time.monotonic() - self._t0:.1f} s"
            + (f" ({self.frames_per_second:.1f} frames/s)" if self.frames_per_second else "")
        )
        if outcome != "finished":
            self.bar.setValue(0)
