"""The depth profile along the ruler: height in mm against distance in mm, with two draggable
reference bands (A, B) whose mean +- SD and difference are computed by
:func:`impress_gui.core.measure.readings.step_height` on the full-resolution profile.

A new profile offers the bands at default places, faint and marked "drag"; they count as
placed - and a step is computed and shown - only once the user has put each of them
somewhere (dragged it, or restored it from a saved measurement)."""

from __future__ import annotations

import math

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Signal
from PySide6.QtWidgets import QWidget

from impress_gui.core.measure.readings import Profile, StepHeight
from impress_gui.ui.viewer.map import BAND_COLOURS


class ProfilePlot(pg.PlotWidget):
    bands_changed = Signal()

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent, background="w")
        self.setMinimumHeight(170)
        pi = self.getPlotItem()
        pi.setLabel("bottom", "distance along the ruler (mm)")
        pi.setLabel("left", "height (mm)")
        pi.showGrid(x=True, y=True, alpha=0.25)
        self.curve = pg.PlotDataItem(pen=pg.mkPen((20, 20, 20), width=1.5), connect="finite")
        self.addItem(self.curve)
        self.regions: dict[str, pg.LinearRegionItem] = {}
        self.labels: dict[str, pg.TextItem] = {}
        self.means: dict[str, pg.InfiniteLine] = {}
        self.hints: dict[str, pg.TextItem] = {}
        for name, colour in BAND_COLOURS.items():
            r = pg.LinearRegionItem(
                values=(0, 1), brush=pg.mkBrush(*colour, 50), pen=pg.mkPen(colour, width=1.5)
            )
            # above the view box (a drag inside a band moves it; below, the view box took the
            # drag and panned), translucent over the curve
            r.setZValue(5)
            r.sigRegionChangeFinished.connect(lambda *_, n=name: self._on_band_moved(n))
            r.hide()
            self.addItem(r)
            self.regions[name] = r
            t = pg.TextItem(color=colour, anchor=(0.5, 1.0), fill=(255, 255, 255, 200))
            t.hide()
            self.addItem(t)
            self.labels[name] = t
            line = pg.InfiniteLine(
                angle=0, pen=pg.mkPen(colour, width=1.5, style=pg.QtCore.Qt.PenStyle.DashLine)
            )
            line.hide()
            self.addItem(line)
            self.means[name] = line
            hint = pg.TextItem(
                f"drag {name}", color=colour, anchor=(0.5, 1.0), fill=(255, 255, 255, 200)
            )
            hint.hide()
            self.addItem(hint)
            self.hints[name] = hint
        self.profile: Profile | None = None
        self.placed: set[str] = set()  # bands the user has put somewhere

    def _on_band_moved(self, name: str) -> None:
        self.placed.add(name)
        self._style_bands()
        self.bands_changed.emit()

    def bands_placed(self) -> bool:
        """Both bands are where the user put them (a step between them means something)."""
        return self.placed >= {"A", "B"}

    def placed_bands(self) -> dict[str, tuple[float, float]]:
        return {k: v for k, v in self.bands().items() if k in self.placed}

    def _style_bands(self) -> None:
        """Placed bands solid; offered ones faint, with a 'drag' hint at their middle."""
        for name, colour in BAND_COLOURS.items():
            r, hint = self.regions[name], self.hints[name]
            placed = name in self.placed
            r.setBrush(pg.mkBrush(*colour, 50 if placed else 18))
            for line in r.lines:
                line.setPen(
                    pg.mkPen(
                        colour,
                        width=1.5,
                        style=pg.QtCore.Qt.PenStyle.SolidLine
                        if placed
                        else pg.QtCore.Qt.PenStyle.DotLine,
                    )
                )
            if placed or self.profile is None or not r.isVisible():
                hint.hide()
                continue
            lo, hi = r.getRegion()
            z = np.asarray(self.profile.height_mm, float)
            z = z[np.isfinite(z)]
            hint.setPos((lo + hi) / 2, float(z.max()) if z.size else 0.0)
            hint.show()

    def set_profile(self, profile: Profile | None, keep_bands: bool = True) -> None:
        first = self.profile is None or not self.bands_shown()
        self.profile = profile
        if profile is None:
            self.curve.setData([], [])
            self.placed.clear()
            for name in self.regions:
                self.regions[name].hide()
                self.labels[name].hide()
                self.means[name].hide()
                self.hints[name].hide()
            return
        self.curve.setData(np.asarray(profile.distance_mm), np.asarray(profile.height_mm))
        length = profile.length_mm
        for r in self.regions.values():
            r.setBounds((0.0, max(length, 1e-6)))
        if first or not keep_bands:
            self._offer_bands((0.1 * length, 0.3 * length), (0.45 * length, 0.55 * length))
        for r in self.regions.values():
            r.show()
        self.getPlotItem().enableAutoRange()
        self._style_bands()

    def _offer_bands(self, a: tuple[float, float], b: tuple[float, float]) -> None:
        """Default places for the bands, not yet placed by the user."""
        self.set_bands(a, b, emit=False)
        self.placed.clear()
        self._style_bands()

    def bands_shown(self) -> bool:
        return all(r.isVisible() for r in self.regions.values())

    def set_bands(self, a: tuple[float, float], b: tuple[float, float], emit: bool = True) -> None:
        """Put both bands (distances along the ruler, mm): they count as placed."""
        for name, band in (("A", a), ("B", b)):
            r = self.regions[name]
            r.blockSignals(True)
            r.setRegion(band)
            r.blockSignals(False)
            r.show()
        self.placed = {"A", "B"}
        self._style_bands()
        if emit:
            self.bands_changed.emit()

    def bands(self) -> dict[str, tuple[float, float]]:
        return {name: tuple(float(v) for v in r.getRegion()) for name, r in self.regions.items()}

    def show_step(self, step: StepHeight | None, budget=None) -> None:
        """The bands' means (and their SD) on the plot; with the step's uncertainty ``budget``
        the plot's title states the step ± U (with its k) and its tooltip the budget."""
        if step is None or budget is None or not math.isfinite(step.difference_mm):
            self.setTitle(None)
            self.setToolTip("")
        else:
            self.setTitle(f"step B - A {step.difference_mm:+.3f} mm {budget.short()}",
                          size="9pt")
            self.setToolTip(budget.text())
        for name in ("A", "B"):
            stats = None if step is None else (step.a if name == "A" else step.b)
            label, line = self.labels[name], self.means[name]
            if stats is None or not math.isfinite(stats.mean_mm):
                label.hide()
                line.hide()
                continue
            label.setText(f"{name}: {stats.mean_mm:.3f} mm (SD {stats.sd_mm:.3f})")
            label.setPos((stats.start_mm + stats.end_mm) / 2, stats.mean_mm)
            label.show()
            line.setValue(stats.mean_mm)
            line.show()
