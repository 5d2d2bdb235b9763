"""The viewer tab: look at a reconstruction and measure it.

Layers (fused, per-laser, difference, contribution, texture, hillshade) with colour maps, a
colour bar in mm and the texture blended over; a cursor readout averaged over a radius; a
draggable ruler whose depth profile (averaging width, two reference bands -> step height as
mean +- SD) is computed by the core on the full-resolution map; levelling by three points or
a region; measurements and annotations kept in the project; exports (see viewer_actions).

Every number shown comes from :mod:`impress_gui.core.measure.readings`; the widgets only draw.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from PySide6.QtCore import QRectF, Qt, Signal
from PySide6.QtWidgets import QHBoxLayout, QScrollArea, QSplitter, QVBoxLayout, QWidget

from impress_gui.core.formats.writers import contribution_png
from impress_gui.core.measure import readings as M
from impress_gui.core.project.project import Project
from impress_gui.ui.messages import Dialogs, Messenger
from impress_gui.ui.task_bar import TaskBar
from impress_gui.ui.viewer.actions import ViewerActions
from impress_gui.ui.viewer.image import auto_levels, target_footprint_mm
from impress_gui.ui.viewer.map import MapView
from impress_gui.ui.viewer.measurements import LevellingMixin, MeasurementsMixin
from impress_gui.ui.viewer.panels import DisplayPanel, ExportPanel, MeasurementTable, ToolPanel
from impress_gui.ui.viewer.profile import ProfilePlot
from impress_gui.ui.worker import LatestOnly

HEIGHT_LAYERS = ("fused", "green", "red")
SCALAR_LAYERS = HEIGHT_LAYERS + ("difference",)
HINTS = {
    "pan": "Drag to pan, wheel to zoom, right click to show everything.",
    "ruler": "Click the ruler's start, then its end; drag its ends or its line to adjust.",
    "marker": "Click to place a numbered marker (an annotation in the list).",
    "level3": "Click three points on the reference surface; heights become relative to it.",
    "region": "Click to place a rectangle on the reference surface, adjust it, then press "
    "'Fit plane to region'.",
}


def core_azimuth(screen_azimuth_deg: float) -> float:
    """The light's azimuth for :func:`impress_gui.core.measure.readings.hillshade` (clockwise from +y
    in the grid) from the one the user sets: clockwise from the top of the screen. The map
    shows +y downwards, so the top of the screen is -y: 315 (upper left, the usual light of
    a relief map, under which a hollow looks hollow) is 225 in the grid."""
    return (180.0 - screen_azimuth_deg) % 360.0


def latest_reconstruction(project: Project) -> Path | None:
    """The folder of the project's newest reconstruction output, if it still exists."""
    for entry in reversed(project.outputs):
        if entry.get("kind") != "reconstruction":
            continue
        cands = [Path(entry.get("path", ""))]
        if project.root is not None and entry.get("relative_path"):
            cands.append(project.root / entry["relative_path"])
        for p in cands:
            folder = p if p.is_dir() else p.parent
            if (folder / "metadata.json").exists():
                return folder
    return None


class ViewerTab(LevellingMixin, MeasurementsMixin, QWidget):
    changed = Signal()
    status = Signal(str)
    loaded = Signal()
    profile_changed = Signal()
    levelled_changed = Signal()
    layer_shown = Signal(str)

    def __init__(
        self,
        messenger: Messenger | None = None,
        dialogs: Dialogs | None = None,
        parent: QWidget | None = None,
    ) -> None:
        super().__init__(parent)
        self.messenger = messenger or Messenger(self)
        self.dialogs = dialogs or Dialogs(self)
        self.project = Project()
        self.data: M.ReconData | None = None
        self.plane: M.Plane | None = None
        self._levelled: dict[str, np.ndarray] = {}
        # colour ranges: typed or dragged by the user, per layer (kept through zoom, layer
        # changes and levelling until Auto); automatic, per layer and levelling
        self._ranges: dict[str, tuple[float, float]] = {}
        self._auto: dict[str, tuple[float, float]] = {}
        self._target_mm: tuple[float, float, float, float] | None = None
        self._hillshade: tuple[tuple, np.ndarray] | None = None
        self._contribution_rgb: np.ndarray | None = None
        self.profile: M.Profile | None = None
        self.step: M.StepHeight | None = None
        self.mode = "pan"
        self._pending: list[tuple[float, float]] = []
        self.level_points: list[tuple[float, float]] = []
        self.tasks = TaskBar(self.messenger, self, name="viewer-task")
        self.tasks.status.connect(self.status)
        self.profiler = LatestOnly(self, "profile")
        self.profiler.finished.connect(self._on_profile)
        self.shader = LatestOnly(self, "hillshade")
        self.shader.finished.connect(self._on_hillshade)
        self._build_ui()
        self.actions = ViewerActions(self)

    # ----- layout -----------------------------------------------------------------------------
    def _build_ui(self) -> None:
        outer = QHBoxLayout(self)
        split = QSplitter(Qt.Orientation.Horizontal)
        outer.addWidget(split)
        left = QWidget()
        lv = QVBoxLayout(left)
        lv.setContentsMargins(0, 0, 0, 0)
        vsplit = QSplitter(Qt.Orientation.Vertical)
        self.map = MapView()
        self.profile_plot = ProfilePlot()
        vsplit.addWidget(self.map)
        vsplit.addWidget(self.profile_plot)
        vsplit.setStretchFactor(0, 3)
        vsplit.setStretchFactor(1, 1)
        lv.addWidget(vsplit, 1)
        lv.addWidget(self.tasks)
        split.addWidget(left)
        side = QWidget()
        sv = QVBoxLayout(side)
        self.display = DisplayPanel()
        self.tools = ToolPanel()
        self.table = MeasurementTable()
        self.exports = ExportPanel()
        for w in (self.display, self.tools, self.table, self.exports):
            sv.addWidget(w)
        scroll = QScrollArea()
        scroll.setWidget(side)
        scroll.setWidgetResizable(True)
        scroll.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        scroll.setMinimumWidth(430)
        split.addWidget(scroll)
        split.setStretchFactor(0, 3)
        split.setStretchFactor(1, 1)
        d, t = self.display, self.tools
        d.layer_changed.connect(lambda _k: self.refresh_layer())
        d.cmap_changed.connect(lambda _c: self.refresh_layer())
        d.range_changed.connect(self._on_range_entered)
        d.auto_range.connect(self.auto_range)
        d.blend_changed.connect(self.map.set_texture_opacity)
        d.light_changed.connect(
            lambda _a, _e: self.refresh_layer() if d.layer_key() == "hillshade" else None
        )
        self.map.colour_bar.sigLevelsChangeFinished.connect(self._on_bar_dragged)
        t.mode_changed.connect(self.set_mode)
        t.settings_changed.connect(self.update_profile)
        t.add_ruler_button.clicked.connect(lambda: self.add_ruler_measurement())
        t.clear_ruler_button.clicked.connect(self.clear_ruler)
        t.fit_region_button.clicked.connect(lambda: self.level_region())
        t.clear_level_button.clicked.connect(self.clear_levelling)
        self.map.hovered.connect(self.show_readout)
        self.map.left_map.connect(lambda: self.tools.readout.setText("Cursor: outside the map"))
        self.map.clicked.connect(self._on_map_clicked)
        self.map.ruler_moved.connect(self._on_ruler_moved)
        self.map.ruler_finished.connect(self.update_profile)
        self.profile_plot.bands_changed.connect(self._update_step)
        self.table.edited.connect(self._on_table_edited)
        self.table.show_button.clicked.connect(self.show_selected)
        self.table.update_button.clicked.connect(self.update_selected_from_ruler)
        self.table.delete_button.clicked.connect(self.delete_selected)
        self.set_mode("pan")

    # ----- project and data ---------------------------------------------------------------------
    def set_project(self, project: Project) -> None:
        self.project = project
        self.refresh_measurements()
        folder = latest_reconstruction(project)
        if folder is not None:
            self.open_reconstruction(folder)
        else:
            self.set_data(None)

    def project_updated(self) -> None:
        self.refresh_measurements()

    def commit_to_project(self) -> None:
        """Measurements go into the project as they are made; nothing is held back."""

    def is_dirty(self) -> bool:
        return False

    def is_busy(self) -> bool:
        return (
            self.tasks.is_busy()
            or self.profiler.is_running()
            or self.shader.is_running()
            or self.map.is_busy()
        )

    def shutdown(self) -> None:
        self.tasks.shutdown()
        self.profiler.shutdown()
        self.shader.shutdown()
        self.map.shutdown()
        self.actions.shutdown()

    def open_reconstruction(self, folder: str | Path) -> bool:
        """Load a reconstruction folder in the background; ``loaded`` fires when it is shown."""
        folder = Path(folder)

        def task(progress, cancel):
            progress(0.1, "reading the maps")
            data = M.load_reconstruction(folder)
            cancel.check()
            progress(0.7, "colouring the contribution map")
            contrib = None
            if "contribution" in data.layers:
                contrib = contribution_png(data.layers["contribution"])
            target = target_footprint_mm(data.metadata, folder)
            auto = {
                k: auto_levels(data.layers[k], data.spec, target)
                for k in SCALAR_LAYERS
                if k in data.layers
            }
            return data, contrib, auto

        return self.tasks.run(
            f"Opening {folder.name}",
            task,
            lambda r: self.set_data(*r),
            "Cannot open the reconstruction",
        )

    def set_data(
        self,
        data: M.ReconData | None,
        contribution_rgb: np.ndarray | None = None,
        auto: dict[str, tuple[float, float]] | None = None,
    ) -> None:
        """Show a reconstruction (``contribution_rgb`` and the ``auto`` colour ranges per
        layer are computed here when not given)."""
        self.data = data
        self.plane = None
        self._levelled.clear()
        self._ranges.clear()
        self._auto = dict(auto or {})
        self._hillshade = None
        self._contribution_rgb = contribution_rgb
        self._target_mm = None if data is None else target_footprint_mm(data.metadata, data.folder)
        if data is not None and contribution_rgb is None and "contribution" in data.layers:
            self._contribution_rgb = contribution_png(data.layers["contribution"])
        self.level_points.clear()
        self.map.set_level_points([])
        self.map.show_region(None)
        self.clear_ruler()
        self.map.set_spec(None if data is None else data.spec)
        self._update_level_text()
        if data is None:
            self.map.scalar.set_data(None, None)
            self.map.rgb.set_data(None, None)
            self.map.set_texture(None, 0)
            return
        self.map.set_texture(data.texture_rgb, self.display.blend.value() / 100)
        self.refresh_layer()
        self.refresh_measurements()
        n = data.spec.shape
        self.status.emit(
            f"Reconstruction {data.folder.name if data.folder else ''}: {n[1]} x "
            f"{n[0]} cells of {data.spec.pixel_mm} mm"
        )
        self.loaded.emit()

    # ----- heights ------------------------------------------------------------------------------
    def measure_key(self) -> str:
        key = self.display.layer_key()
        return key if key in HEIGHT_LAYERS and self.data and key in self.data.layers else "fused"

    def measure_height(self, key: str | None = None) -> np.ndarray:
        """The full-resolution heights measured on: the shown height layer (the fused map for
        other layers), relative to the levelling plane when there is one."""
        key = key or self.measure_key()
        if self.plane is None:
            return self.data.layers[key]
        if key not in self._levelled:
            self._levelled[key] = M.levelled(self.data.layers[key], self.data.spec, self.plane)
        return self._levelled[key]

    # ----- display ------------------------------------------------------------------------------
    def refresh_layer(self) -> None:
        if self.data is None:
            return
        key = self.display.layer_key()
        cmap = self.display.cmap.currentText()
        if key in HEIGHT_LAYERS + ("difference",) and key in self.data.layers:
            arr = self.measure_height(key) if key != "difference" else self.data.layers[key]
            levels = self._ranges.get(key) or self._auto_levels(key, arr)
            label = "green - red (mm)" if key == "difference" else "height (mm)"
            self.map.show_scalar(arr, levels, cmap, label)
            self.display.show_range(*levels)
        elif key == "contribution" and self._contribution_rgb is not None:
            self.map.show_rgb(self._contribution_rgb, nearest=True)
        elif key == "texture" and self.data.texture_rgb is not None:
            self.map.show_rgb(self.data.texture_rgb)
        elif key == "hillshade":
            self._show_hillshade()
            return
        else:
            self.status.emit(f"This reconstruction has no {key} layer")
            return
        self.layer_shown.emit(key)

    def _range_key(self, key: str) -> str:
        return f"{key}/levelled" if self.plane is not None and key != "difference" else key

    def _auto_levels(self, key: str, arr: np.ndarray) -> tuple[float, float]:
        """The automatic range of a layer (robust percentiles of the evidence area, the
        calibration target left out when its place is known), computed once per layer and
        levelling."""
        rk = self._range_key(key)
        if rk not in self._auto:
            self._auto[rk] = auto_levels(arr, self.data.spec, self._target_mm)
        return self._auto[rk]

    def typed_range(self, key: str | None = None) -> tuple[float, float] | None:
        """The colour range the user typed or dragged for a layer (None: automatic)."""
        return self._ranges.get(key or self.display.layer_key())

    def auto_range(self) -> None:
        """Back to the automatic range (recomputed) for the shown layer."""
        key = self.display.layer_key()
        if self.data is None or key not in HEIGHT_LAYERS + ("difference",):
            return
        self._ranges.pop(key, None)
        self._auto.pop(self._range_key(key), None)
        self.refresh_layer()

    def _on_range_entered(self, lo: float, hi: float) -> None:
        key = self.display.layer_key()
        if hi <= lo or key not in HEIGHT_LAYERS + ("difference",):
            return
        self._ranges[key] = (lo, hi)
        self.map.set_levels((lo, hi))

    def _on_bar_dragged(self, *_args) -> None:
        key = self.display.layer_key()
        lo, hi = self.map.levels()
        self._ranges[key] = (lo, hi)
        self.display.show_range(lo, hi)

    def _show_hillshade(self) -> None:
        az, el = self.display.azimuth.value(), self.display.elevation.value()
        params = (self.measure_key(), self.plane, az, el)
        if self._hillshade is not None and self._hillshade[0] == params:
            self.map.show_rgb(self._hillshade[1])
            self.layer_shown.emit("hillshade")
            return
        h, p = self.measure_height(), self.data.spec.pixel_mm

        def task(_progress, _cancel):
            hs = M.hillshade(h, p, core_azimuth(az), el)
            grey = np.nan_to_num(hs * 255.0, nan=0.0).astype(np.uint8)
            return params, np.repeat(grey[..., None], 3, axis=2)

        self.shader.submit(task)

    def _on_hillshade(self, result) -> None:
        self._hillshade = result
        if self.display.layer_key() == "hillshade" and result[0][1] is self.plane:
            self.map.show_rgb(result[1])
            self.layer_shown.emit("hillshade")

    # ----- cursor readout -------------------------------------------------------------------------
    def readout_at(self, x_mm: float, y_mm: float) -> M.Readout:
        return M.readout(
            self.measure_height(), self.data.spec, x_mm, y_mm, self.tools.radius.value()
        )

    def show_readout(self, x_mm: float, y_mm: float) -> None:
        if self.data is None:
            return
        r = self.readout_at(x_mm, y_mm)
        where = f"x {x_mm:.2f} mm, y {y_mm:.2f} mm"
        if r.n_cells == 0:
            text = f"{where}: outside the map"
        elif not r.has_data:
            text = f"{where}: no data"
        else:
            text = (
                f"{where}: height {r.height_mm:.3f} mm (SD {r.sd_mm:.3f}, {r.n_valid} of "
                f"{r.n_cells} cells)"
            )
        if self.plane is not None:
            text += " [levelled]"
        self.tools.readout.setText(text)

    # ----- modes and clicks -----------------------------------------------------------------------
    def set_mode(self, mode: str) -> None:
        self.mode = mode
        self._pending.clear()
        self.tools.set_mode(mode)
        self.tools.hint.setText(HINTS[mode])
        self.map.set_placing(mode != "pan")
        if mode == "level3":
            self.level_points.clear()
            self.map.set_level_points([])

    def _on_map_clicked(self, x: float, y: float) -> None:
        if self.data is None:
            return
        if self.mode == "ruler":
            self._pending.append((x, y))
            if len(self._pending) == 2:
                self.set_ruler(*self._pending)
                self._pending.clear()
        elif self.mode == "marker":
            self.add_marker(x, y)
        elif self.mode == "level3":
            self.level_points.append((x, y))
            self.map.set_level_points(self.level_points)
            if len(self.level_points) == 3:
                self.level_three_points(self.level_points)
        elif self.mode == "region":
            r = self.map.vb.viewRect()
            w, h = r.width() / 5, r.height() / 5
            self.map.show_region(QRectF(x - w / 2, y - h / 2, w, h))

    # ----- ruler and profile ------------------------------------------------------------------------
    def set_ruler(self, p0, p1) -> None:
        self.map.set_ruler(tuple(map(float, p0)), tuple(map(float, p1)))

    def ruler_points(self):
        return self.map.ruler_points()

    def clear_ruler(self) -> None:
        self.map.clear_ruler()
        self.profile = self.step = None
        self.profile_plot.set_profile(None)
        self.profile_plot.show_step(None)
        self.tools.ruler_text.setText("Ruler: choose Ruler and click two points")
        self.tools.step_text.setText("Step (B - A): -")
        self.tools.step_text.setStyleSheet("")

    def ruler_result(self) -> M.RulerResult | None:
        pts = self.ruler_points()
        if pts is None or self.data is None:
            return None
        return M.ruler(
            self.measure_height(), self.data.spec, pts[0], pts[1], self.tools.radius.value()
        )

    def _on_ruler_moved(self) -> None:
        r = self.ruler_result()
        if r is None:
            return
        dz = "no data" if math.isnan(r.dz_mm) else f"{r.dz_mm:+.3f} mm"
        d3 = "-" if math.isnan(r.d3_mm) else f"{r.d3_mm:.3f} mm"
        text = f"xy {r.xy_mm:.3f} mm | 3D {d3} | dz {dz}"
        self.tools.ruler_text.setText(f"Ruler: {text}")
        self.map.decorate_ruler(
            text,
            self.tools.width.value(),
            self.profile_plot.placed_bands() if self.profile else None,
        )

    def update_profile(self) -> None:
        """Recompute the profile along the ruler in the background (a newer request supersedes
        an older one); ``profile_changed`` follows."""
        pts = self.ruler_points()
        if pts is None or self.data is None:
            return
        self._on_ruler_moved()
        h, spec, width = self.measure_height(), self.data.spec, self.tools.width.value()
        self.profiler.submit(lambda _p, _c: M.line_profile(h, spec, pts[0], pts[1], width))

    def _on_profile(self, profile: M.Profile) -> None:
        keep = self.profile is not None and abs(profile.length_mm - self.profile.length_mm) < 1e-6
        self.profile = profile
        self.profile_plot.set_profile(profile, keep_bands=keep)
        self._update_step(emit=False)
        self.profile_changed.emit()

    def set_bands(self, a: tuple[float, float], b: tuple[float, float]) -> None:
        """Reference bands as distances along the ruler (mm)."""
        self.profile_plot.set_bands(a, b)

    def _update_step(self, emit: bool = True) -> None:
        """The step between the two reference bands, once the user has placed both; until
        then nothing is computed or shown (default bands would give a meaningless number)."""
        if self.profile is None:
            return
        if not self.profile_plot.bands_placed():
            self.step = None
            self.profile_plot.show_step(None)
            todo = " and ".join(n for n in ("A", "B") if n not in self.profile_plot.placed)
            self.tools.step_text.setText(
                f"Step (B - A): drag band {todo} in the profile onto the surface to compare"
            )
            self.tools.step_text.setStyleSheet("")
            self._on_ruler_moved()
            if emit:
                self.profile_changed.emit()
            return
        bands = self.profile_plot.bands()
        self.step = M.step_height(self.profile, bands["A"], bands["B"])
        s = self.step
        self.profile_plot.show_step(s)
        self.tools.step_text.setStyleSheet("font-weight: bold")
        self.tools.step_text.setText(
            f"A {s.a.mean_mm:.3f} ± {s.a.sd_mm:.3f} mm (n {s.a.n}), B {s.b.mean_mm:.3f} ± "
            f"{s.b.sd_mm:.3f} mm (n {s.b.n})\nStep B - A: {s.difference_mm:+.3f} ± "
            f"{s.sd_mm:.3f} mm"
        )
        self._on_ruler_moved()
        if emit:
            self.profile_changed.emit()


__all__ = ["ViewerTab", "core_azimuth", "latest_reconstruction"]
