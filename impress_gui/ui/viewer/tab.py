"""The viewer tab: look at a reconstruction and measure it.

Layers (fused, per-laser, difference, contribution, texture, hillshade) with colour maps, a
colour bar in mm and the texture blended over; a cursor readout averaged over a radius; a
draggable ruler whose depth profile (averaging width, two reference bands -> step height as
mean +- SD) is computed by the core on the full-resolution map; levelling by three points or
a region; measurements and annotations kept in the project; exports.

The tab is a view over the working :class:`~impress_gui.session.session.Session`: it shows
the session's project (its measurements, its newest reconstruction) and opens each
reconstruction the session announces. It lays out the widgets and composes the objects that
do the work, each given what it uses: :class:`~impress_gui.ui.viewer.layers.LayerDisplay`
(layer, colour range, hill shading), :class:`~impress_gui.ui.viewer.ruler.RulerProfile`
(ruler, profile, step), :class:`~impress_gui.ui.viewer.measurements.Levelling`,
:class:`~impress_gui.ui.viewer.measurements.MeasurementList` and
:class:`~impress_gui.ui.viewer.actions.ViewerExports`.

Every number shown comes from :mod:`impress_gui.core.measure.readings`; the widgets only draw.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PySide6.QtCore import Qt, Signal
from PySide6.QtGui import QAction, QUndoStack
from PySide6.QtWidgets import (
    QHBoxLayout,
    QPushButton,
    QSplitter,
    QVBoxLayout,
    QWidget,
)

from impress_gui.core.base.errors import ImpressError
from impress_gui.core.formats.writers import contribution_png
from impress_gui.core.measure import readings as M
from impress_gui.core.measure import uncertainty as U
from impress_gui.core.project.project import Project
from impress_gui.session.session import Session
from impress_gui.ui.messages import Dialogs, Messenger
from impress_gui.ui.task_bar import TaskBar
from impress_gui.ui.viewer.actions import ViewerExports
from impress_gui.ui.viewer.image import auto_levels, target_footprint_mm
from impress_gui.ui.viewer.layers import (
    SCALAR_LAYERS,
    LayerDisplay,
    ShownReconstruction,
    core_azimuth,
)
from impress_gui.ui.viewer.map import RAIL_TEXT, MapView
from impress_gui.ui.viewer.measurements import Levelling, MeasurementList
from impress_gui.ui.viewer.panels import (
    DisplayPanel,
    ExportPanel,
    MeasurementTable,
    SidePanelScroll,
    ToolPanel,
)
from impress_gui.ui.viewer.profile import ProfilePlot
from impress_gui.ui.viewer.ruler import RulerProfile

HINTS = {
    "pan": "Drag to pan, wheel to zoom, right click to show everything.",
    "ruler": "Click the ruler's start, then its end; drag its ends or its line to adjust.",
    "marker": "Click to place a numbered marker (an annotation in the list).",
    "level3": "Click three points on the reference surface; heights become relative to it.",
    "region": "Click to place a rectangle on the reference surface, adjust it, then press "
    "'Fit plane to region'.",
}


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


class ViewerTab(QWidget):
    changed = Signal()  # something the project keeps changed (a measurement, an output)
    status = Signal(str)  # a line for the status bar
    loaded = Signal()  # a reconstruction is shown
    profile_changed = Signal()
    levelled_changed = Signal()
    layer_shown = Signal(str)
    side_by_side_changed = Signal(bool)

    def __init__(
        self,
        messenger: Messenger | None = None,
        dialogs: Dialogs | None = None,
        parent: QWidget | None = None,
        session: Session | None = None,
    ) -> None:
        super().__init__(parent)
        self.messenger = messenger or Messenger(self)
        self.dialogs = dialogs or Dialogs(self)
        self._own_session = session is None
        self.session = session if session is not None else Session()
        self.mode = "pan"
        self._pending: list[tuple[float, float]] = []  # the ruler's first click
        self._cursor: tuple[float, float] | None = None  # where the readout was read (mm)
        self.tasks = TaskBar(self.messenger, self, name="viewer-task")
        self.tasks.status.connect(self.status)
        self._build_ui()
        self.recon = ShownReconstruction()
        self.layers = LayerDisplay(self.recon, self.display, self.map, self)
        self.ruler = RulerProfile(self.layers, self.map, self.profile_plot, self.tools, self)
        # the viewer's edits (measurements, levelling), one stack per opened reconstruction
        self.undo_stack = QUndoStack(self)
        self.levelling = Levelling(
            self.layers, self.map, self.tools, self.tasks, self.messenger, self, self.undo_stack
        )
        self.measurements = MeasurementList(
            self.session,
            self.table,
            self.map,
            self.tools,
            self.layers,
            self.ruler,
            self.messenger,
            self,
            self.undo_stack,
        )
        self.actions = ViewerExports(
            self.session,
            self.layers,
            self.ruler,
            self.profile_plot,
            self.tasks,
            self.messenger,
            self.dialogs,
            self,
            view_rect=lambda: self.map.vb.viewRect(),
        )
        self._add_cast_action()
        self._connect()
        self.set_mode("pan")
        s = self.session
        s.project_changed.connect(self._on_project_changed)
        s.reconstruction_added.connect(self._on_reconstruction_added)
        self.refresh_measurements()

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
        # the texture beside the map (side by side), hidden until asked for
        self.texture_map = MapView()
        self.texture_map.direction_label.setText("Texture · " + RAIL_TEXT)
        self.texture_map.hide()
        # its colour bar is never seen (the texture has no heights) but takes the place of the
        # map's, so that both views are the same size and show the same ground
        self.texture_map.colour_bar.setOpacity(0.0)
        self.texture_map.colour_bar.setEnabled(False)
        self.maps_split = QSplitter(Qt.Orientation.Horizontal)
        self.maps_split.addWidget(self.map)
        self.maps_split.addWidget(self.texture_map)
        self.profile_plot = ProfilePlot()
        vsplit.addWidget(self.maps_split)
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
        # never narrower than the panels (no horizontal scrolling: a narrower viewport cut
        # off their right edge)
        self.side_scroll = scroll = SidePanelScroll(side)
        split.addWidget(scroll)
        split.setCollapsible(1, False)
        split.setStretchFactor(0, 3)
        split.setStretchFactor(1, 1)

    def _add_cast_action(self) -> None:
        """Export > Digital cast: an action (for a menu) and its button in the export panel,
        beside "3D view..."."""
        self.cast_action = QAction("Digital cast (STL/PLY/OBJ)...", self)
        self.cast_action.setStatusTip("A watertight mesh of the impression (or the outsole's "
                                      "positive) for a 3D printer")
        self.cast_action.triggered.connect(lambda _checked=False: self.actions.open_cast_dialog())
        button = QPushButton("Digital cast...")
        button.setToolTip(self.cast_action.statusTip())
        button.clicked.connect(lambda _checked=False: self.cast_action.trigger())
        n = len(self.exports.buttons)  # the panel's buttons fill two columns
        self.exports.buttons["cast"] = button
        self.exports.layout().addWidget(button, n // 2, n % 2)

    def _connect(self) -> None:
        """What the tab itself follows: modes, clicks and the cursor; the parts' signals."""
        self.tools.mode_changed.connect(self.set_mode)
        for view in (self.map, self.texture_map):
            view.hovered.connect(self._on_hovered)
            view.left_map.connect(self._on_left_map)
            view.clicked.connect(self._on_map_clicked)
        self.display.side_by_side.connect(self.set_side_by_side)
        self.layers.shown.connect(lambda _k: self._match_side_geometry())
        self.layers.shown.connect(self.layer_shown)
        self.layers.status.connect(self.status)
        self.ruler.profile_changed.connect(self.profile_changed)
        self.levelling.levelled.connect(self._on_levelled)
        self.levelling.status.connect(self.status)
        self.measurements.changed.connect(self._on_project_edited)
        self.measurements.status.connect(self.status)
        self.measurements.uncertainty.ready.connect(self._show_readout_again)
        self.actions.written.connect(self._on_project_edited)
        self.actions.status.connect(self.status)
        a, b = self.actions, self.exports.buttons
        b["tiff"].clicked.connect(lambda: a.export_tiff())
        b["x3p"].clicked.connect(lambda: a.export_x3p())
        b["ply"].clicked.connect(lambda: a.export_ply())
        b["png"].clicked.connect(lambda: a.export_png())
        b["profile_csv"].clicked.connect(lambda: a.export_profile_csv())
        b["profile_png"].clicked.connect(lambda: a.export_profile_png())
        b["report"].clicked.connect(lambda: a.export_report())
        b["report_pdf"].clicked.connect(lambda: a.export_report_pdf())
        b["view3d"].clicked.connect(lambda: a.open_3d())
        self.table.export_button.clicked.connect(lambda: a.export_measurements_csv())
        self.table.method_button.clicked.connect(lambda: self.attach_method_validation())

    # ----- the session ----------------------------------------------------------------------------
    @property
    def project(self) -> Project:
        return self.session.project

    def set_project(self, project: Project) -> None:
        """Open ``project`` in the session (the tab follows, as every view over it does)."""
        self.session.open_project(project)

    def _on_project_changed(self, project: Project) -> None:
        """The session opened ``project``: its measurements, and its newest reconstruction."""
        self.undo_stack.clear()  # the edits were another project's
        self.refresh_measurements()
        folder = latest_reconstruction(project)
        if folder is not None:
            self.open_reconstruction(folder)
        else:
            self.set_data(None)

    def _on_reconstruction_added(self, folder: Path) -> None:
        """A reconstruction made or opened in the session: show it."""
        self.open_reconstruction(folder)

    def _on_project_edited(self) -> None:
        self.changed.emit()
        self.session.mark_changed()

    def project_updated(self) -> None:
        self.refresh_measurements()

    def commit_to_project(self) -> None:
        """Measurements go into the project as they are made; nothing is held back."""

    def is_dirty(self) -> bool:
        return False

    def is_busy(self) -> bool:
        return (
            self.tasks.is_busy()
            or self.ruler.is_busy()
            or self.layers.is_busy()
            or self.map.is_busy()
            or self.texture_map.is_busy()
        )

    def shutdown(self) -> None:
        """Stop the tab's work and stop following the session (a session the tab made is
        closed; one it was given is its owner's to close). Safe twice."""
        self.tasks.shutdown()
        self.ruler.shutdown()
        self.layers.shutdown()
        self.map.shutdown()
        self.texture_map.shutdown()
        self.actions.shutdown()
        s = self.session
        s.project_changed.disconnect(self._on_project_changed)
        s.reconstruction_added.disconnect(self._on_reconstruction_added)
        if self._own_session:
            s.close()

    # ----- the reconstruction -----------------------------------------------------------------
    @property
    def data(self) -> M.ReconData | None:
        return self.recon.data

    @property
    def plane(self) -> M.Plane | None:
        return self.recon.plane

    @property
    def _hillshade(self) -> tuple[tuple, np.ndarray] | None:
        """The last hill shading: ``((layer, plane, azimuth, elevation), rgb)``."""
        return self.recon.hillshade

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
        self.recon.reset(data, contribution_rgb, auto)
        self.undo_stack.clear()  # undo works within one opened reconstruction
        self.levelling.reset()
        self.ruler.clear()
        self.layers.show_data()
        self._show_side_texture()
        if data is None:
            return
        self.refresh_measurements()
        n = data.spec.shape
        self.status.emit(
            f"Reconstruction {data.folder.name if data.folder else ''}: {n[1]} x "
            f"{n[0]} cells of {data.spec.pixel_mm} mm"
        )
        self.loaded.emit()

    # ----- heights and display (LayerDisplay) -----------------------------------------------------
    def measure_key(self) -> str:
        return self.layers.measure_key()

    def measure_height(self, key: str | None = None) -> np.ndarray:
        """The full-resolution heights measured on: the shown height layer (the fused map for
        other layers), relative to the levelling plane when there is one."""
        return self.layers.height(key)

    def typed_range(self, key: str | None = None) -> tuple[float, float] | None:
        """The colour range the user typed or dragged for a layer (None: automatic)."""
        return self.layers.typed_range(key)

    def auto_range(self) -> None:
        """Back to the automatic range (recomputed) for the shown layer."""
        self.layers.auto_range()

    # ----- side by side ----------------------------------------------------------------------------
    def is_side_by_side(self) -> bool:
        return self.display.side_button.isChecked()

    def set_side_by_side(self, on: bool) -> None:
        """Show the texture in a second view beside the map (``on``), panned and zoomed with
        it (the views' ranges are linked), the cursor's crosshair drawn in both."""
        b = self.display.side_button
        if b.isChecked() != on:
            b.blockSignals(True)
            b.setChecked(on)
            b.blockSignals(False)
        tm = self.texture_map
        if on:
            tm.show()
            half = max(self.maps_split.width() // 2, 1)
            self.maps_split.setSizes([half, half])
            self._show_side_texture()
            tm.vb.setXLink(self.map.vb)
            tm.vb.setYLink(self.map.vb)
        else:
            tm.vb.setXLink(None)
            tm.vb.setYLink(None)
            tm.hide()
            self._on_left_map()
        self.side_by_side_changed.emit(on)

    def _show_side_texture(self) -> None:
        """The texture of the open reconstruction in the second view (when it is shown)."""
        tm, data = self.texture_map, self.data
        if not self.display.side_button.isChecked():
            return
        tm.set_spec(None if data is None else data.spec, fit=False)
        if data is None or data.texture_rgb is None:
            tm.rgb.set_data(None, None)
            tm.direction_label.setText("This reconstruction has no texture")
            return
        tm.direction_label.setText("Texture · " + RAIL_TEXT)
        tm.show_rgb(data.texture_rgb)
        self._match_side_geometry()
        tm.vb.setRange(self.map.vb.viewRect(), padding=0)

    def _match_side_geometry(self) -> None:
        """The texture's view as large as the map's: an (unseen) colour bar where the map
        has one."""
        if self.display.side_button.isChecked():
            self.texture_map.colour_bar.setVisible(self.map.colour_bar.isVisible())

    def _on_hovered(self, x_mm: float, y_mm: float) -> None:
        """The cursor over either view: the readout, and the crosshair in both when side by
        side."""
        self.show_readout(x_mm, y_mm)
        if self.texture_map.isVisible():
            for view in (self.map, self.texture_map):
                view.set_crosshair(x_mm, y_mm)

    def _on_left_map(self) -> None:
        self._cursor = None
        self.tools.readout.setText("Cursor: outside the map")
        self.tools.readout.setToolTip("")
        for view in (self.map, self.texture_map):
            view.set_crosshair(None)

    # ----- cursor readout -------------------------------------------------------------------------
    def readout_at(self, x_mm: float, y_mm: float) -> M.Readout:
        return self.layers.readout(x_mm, y_mm, self.tools.radius.value())

    def readout_budget(self, r: M.Readout) -> U.Budget | None:
        """The uncertainty budget of the height read at the cursor (as a marker's there would
        be, :func:`~impress_gui.core.measure.uncertainty.height_budget`); None without data."""
        if not r.has_data:
            return None
        ctx = self.measurements.uncertainty.context()
        return None if ctx is None else U.height_budget(ctx, r)

    def show_readout(self, x_mm: float, y_mm: float) -> None:
        """The height under the cursor with its expanded uncertainty U (with its k), and the spread
        (SD) of the cells averaged, labelled as such; the budget in the tooltip."""
        if self.data is None:
            return
        self._cursor = (x_mm, y_mm)
        r = self.readout_at(x_mm, y_mm)
        where = f"x {x_mm:.2f} mm, y {y_mm:.2f} mm"
        budget = None
        if r.n_cells == 0:
            text = f"{where}: outside the map"
        elif not r.has_data:
            text = f"{where}: no data"
        else:
            budget = self.readout_budget(r)
            u = "" if budget is None else (
                f" ± {budget.U_mm:.3f} mm (U, {U.k_text([budget])})"
                if np.isfinite(budget.U_mm) else f" ± - (U, {U.k_text([budget])})")
            spread = f"spread SD {r.sd_mm:.3f} mm, " if r.n_valid > 1 else ""
            text = (f"{where}: height {r.height_mm:.3f} mm{u} ({spread}{r.n_valid} of "
                    f"{r.n_cells} cells)")
        if self.plane is not None:
            text += " [levelled]"
        self.tools.readout.setText(text)
        self.tools.readout.setToolTip("" if budget is None else budget.text())

    def attach_method_validation(self, path: str | Path | None = None) -> dict | None:
        """The method's bias and precision into every budget from now on (component 6), from
        an ``impress validate`` record chosen by the user (or ``path``); kept in the project.
        A file that is not such a record is refused with its code and changes nothing."""
        if path is None:
            start = str(self.session.project.root or "")
            path = self.dialogs.open_file("Method validation record (validation.json)",
                                          "Validation record (*.json)", start)
        if not path:
            return None
        try:
            rec = self.session.set_method_validation(path)
        except ImpressError as exc:
            self.messenger.exception("Cannot use the validation record", exc)
            return None
        if rec is None:
            return None
        z = rec["z"]
        self.table.method_button.setToolTip(
            f"Method validation: {Path(rec['file']).name}, height bias {z['bias_mm']:+.4f} mm, "
            f"SD {z['sd_mm']:.4f} mm ({z['n']} readings)")
        self.status.emit(f"Method validation from {Path(rec['file']).name}: height bias "
                         f"{z['bias_mm']:+.4f} mm, SD {z['sd_mm']:.4f} mm, in every budget")
        self.ruler.show_uncertainty()
        self._show_readout_again()
        return rec

    def _show_readout_again(self) -> None:
        """The calibration's Monte Carlo arrived: the cursor's reading again, with it."""
        if self._cursor is not None and self.data is not None:
            self.show_readout(*self._cursor)

    # ----- modes and clicks -----------------------------------------------------------------------
    def set_mode(self, mode: str) -> None:
        self.mode = mode
        self._pending.clear()
        self.tools.set_mode(mode)
        self.tools.hint.setText(HINTS[mode])
        for view in (self.map, self.texture_map):
            view.set_placing(mode != "pan")
        if mode == "level3":
            self.levelling.restart_points()

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
            self.levelling.add_point(x, y)
        elif self.mode == "region":
            self.levelling.place_region(x, y)

    # ----- ruler and profile (RulerProfile) -------------------------------------------------------
    @property
    def profile(self) -> M.Profile | None:
        return self.ruler.profile

    @property
    def step(self) -> M.StepHeight | None:
        return self.ruler.step

    def set_ruler(self, p0, p1) -> None:
        self.ruler.set(p0, p1)

    def ruler_points(self):
        return self.ruler.points()

    def clear_ruler(self) -> None:
        self.ruler.clear()

    def ruler_result(self) -> M.RulerResult | None:
        return self.ruler.result()

    def update_profile(self) -> None:
        """Recompute the profile along the ruler in the background (a newer request supersedes
        an older one); ``profile_changed`` follows."""
        self.ruler.update_profile()

    def set_bands(self, a: tuple[float, float], b: tuple[float, float]) -> None:
        """Reference bands as distances along the ruler (mm)."""
        self.ruler.set_bands(a, b)

    # ----- levelling (Levelling) ------------------------------------------------------------------
    @property
    def level_points(self) -> list[tuple[float, float]]:
        return self.levelling.points

    def level_three_points(self, pts) -> bool:
        return self.levelling.level_three_points(pts)

    def level_region(self, x_range=None, y_range=None) -> bool:
        return self.levelling.level_region(x_range, y_range)

    def _on_levelled(self) -> None:
        self.ruler.update_profile()
        self.levelled_changed.emit()

    # ----- measurements (MeasurementList) ---------------------------------------------------------
    def add_ruler_measurement(self, label: str = "") -> dict | None:
        return self.measurements.add_ruler_measurement(label)

    def add_marker(self, x: float, y: float, label: str = "") -> dict:
        return self.measurements.add_marker(x, y, label)

    def refresh_measurements(self, selected: int | None = None) -> None:
        self.measurements.refresh(selected)

    def show_selected(self) -> None:
        self.measurements.show_selected()

    def update_selected_from_ruler(self) -> None:
        self.measurements.update_selected_from_ruler()

    def delete_selected(self) -> None:
        self.measurements.delete_selected()


__all__ = ["ViewerTab", "core_azimuth", "latest_reconstruction"]
