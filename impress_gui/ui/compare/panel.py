"""A minimal Compare panel: choose A and B (reconstruction folders, X3P or PLY), register B onto
A (automatically, with mirror and height inversion available), see the residual RMS and the
overlap, the signed difference map (mm, diverging colours) with the regions beyond a threshold
outlined, the maps A and B (moved onto A), side by side with linked pan, zoom and cursor, an
overlay of B over A with adjustable opacity and a flicker toggle,
one depth profile across both maps on the same chart (two clicks on the map with "profile"
checked), point pairs for the coarse registration clicked on A and B side by side ("pick
pairs"), and write the whole comparison folder (``impress compare``'s files).

The work runs in the core (:mod:`impress_gui.core.compare`) on worker threads
(:class:`~impress_gui.ui.worker.Worker`); a threshold change re-outlines through
:class:`~impress_gui.ui.worker.LatestOnly`, so dragging it never queues stale work.
The map is drawn as seen from above (row 0 of A's grid at the top, as the viewer shows it).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt, QTimer, Signal
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QFileDialog,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QSlider,
    QVBoxLayout,
    QWidget,
)

from impress_gui.core.compare.difference import (
    DEFAULT_METRIC,
    METRICS,
    PairProfile,
    outline,
    pair_profile,
)
from impress_gui.core.compare.record import (
    DEFAULT_THRESHOLD_MM,
    CompareParams,
    Comparison,
    colour_range,
    compare,
    derive,
    diverging_lut,
    write_comparison,
)
from impress_gui.core.compare.register import RegistrationParams
from impress_gui.core.compare.surfaces import Surface, load_surface
from impress_gui.ui.worker import LatestOnly, Worker

VIEWS = ("difference A - B", "A", "B moved onto A", "B over A", "A | B side by side")
#: the difference's metric (core.compare.difference.METRICS) as the selector shows it
METRIC_LABELS = {"normal": "along A's surface normal", "vertical": "vertical (heights)"}
FLICKER_MS = 500


class ComparePanel(QWidget):
    """See the module's docstring. ``compared(Comparison)`` follows a finished comparison,
    ``outlined(int)`` a finished outlining (the number of regions), ``written(dict)`` a
    written folder (its record), ``failed(code, message)`` any error."""

    changed = Signal()  # the window's Tab protocol: nothing here goes into the project yet
    status = Signal(str)  # a line for the status bar
    compared = Signal(object)
    profiled = Signal(object)
    loaded = Signal()  # A and B read for picking pairs
    outlined = Signal(int)
    written = Signal(object)
    failed = Signal(str, str)

    def __init__(self, parent: QWidget | None = None, session=None) -> None:
        super().__init__(parent)
        self.session = session  # the window's Session: written comparisons go into its case
        self._writing_to: Path | None = None
        self.comparison: Comparison | None = None
        self._edges: np.ndarray | None = None
        self.profile: PairProfile | None = None
        self.surfaces: tuple[Surface, Surface] | None = None
        self.pairs: list[tuple[tuple[float, float], tuple[float, float]]] = []
        self._pending: dict[str, tuple[float, float]] = {}
        self._loader = Worker(parent=self, name="compare-load")
        self._loader.finished.connect(self._on_loaded)
        self._loader.failed.connect(self._on_failed)
        self._clicks: list[tuple[float, float]] = []
        self._worker = Worker(parent=self, name="compare")
        self._worker.finished.connect(self._on_compared)
        self._worker.failed.connect(self._on_failed)
        self._worker.progress.connect(lambda f, m: self.status_label.setText(f"{m} ({f:.0%})"))
        self._writer = Worker(parent=self, name="compare-write")
        self._writer.finished.connect(self._on_written)
        self._writer.failed.connect(self._on_failed)
        self._outliner = LatestOnly(self, "compare-outline")
        self._outliner.finished.connect(self._on_outlined)
        self._outliner.failed.connect(self._on_failed)
        self._remeasurer = LatestOnly(self, "compare-metric")
        self._remeasurer.finished.connect(self._on_remeasured)
        self._remeasurer.failed.connect(self._on_failed)

        self.a_edit, self.b_edit = QLineEdit(), QLineEdit()
        self.a_edit.setPlaceholderText("A: reconstruction folder, .x3p or .ply")
        self.b_edit.setPlaceholderText("B: reconstruction folder, .x3p or .ply")
        self.mirror_check = QCheckBox("mirror B (x → -x)")
        self.invert_check = QCheckBox("invert B's heights (z → -z)")
        self.threshold_spin = QDoubleSpinBox()
        self.threshold_spin.setRange(0.01, 20.0)
        self.threshold_spin.setDecimals(2)
        self.threshold_spin.setSingleStep(0.05)
        self.threshold_spin.setSuffix(" mm")
        self.threshold_spin.setValue(DEFAULT_THRESHOLD_MM)
        self.metric_combo = QComboBox()
        for m in METRICS:
            self.metric_combo.addItem(METRIC_LABELS[m], m)
        self.metric_combo.setCurrentIndex(METRICS.index(DEFAULT_METRIC))
        self.metric_combo.setToolTip(
            "along A's normal: the signed distance from B to A's surface, as deviation maps "
            "measure it (a tread wall's small lateral misplacement stays small); vertical: the "
            "difference of heights A - B")
        self.compare_button = QPushButton("Compare")
        self.pairs_check = QCheckBox("pick point pairs (A left, B right)")
        self.clear_pairs_button = QPushButton("Clear pairs")
        self.pairs_label = QLabel("no point pairs: the coarse registration is automatic")
        self.write_button = QPushButton("Write comparison folder…")
        self.write_button.setEnabled(False)
        self.view_combo = QComboBox()
        self.view_combo.addItems(VIEWS)
        self.opacity_slider = QSlider(Qt.Orientation.Horizontal)
        self.opacity_slider.setRange(0, 100)
        self.opacity_slider.setValue(50)
        self.profile_check = QCheckBox("profile: click its two ends on the map")
        self.flicker_check = QCheckBox("flicker")
        self.flicker_ticks = 0
        self._flicker = QTimer(self)
        self._flicker.setInterval(FLICKER_MS)
        self._flicker.timeout.connect(self._flick)
        self.status_label = QLabel("Choose A and B, then Compare.")
        self.status_label.setWordWrap(True)
        self.result_label = QLabel("")
        self.result_label.setWordWrap(True)
        self.result_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)

        form = QFormLayout()
        for label, edit in (("A", self.a_edit), ("B", self.b_edit)):
            row = QHBoxLayout()
            row.addWidget(edit)
            browse = QPushButton("Folder…")
            browse.clicked.connect(lambda _=False, e=edit: self._browse(e))
            row.addWidget(browse)
            form.addRow(label, row)
        flags = QHBoxLayout()
        flags.addWidget(self.mirror_check)
        flags.addWidget(self.invert_check)
        form.addRow("", flags)
        form.addRow("difference A - B", self.metric_combo)
        form.addRow("outline |A - B| above", self.threshold_spin)
        buttons = QHBoxLayout()
        buttons.addWidget(self.compare_button)
        buttons.addWidget(self.write_button)
        pairs_row = QHBoxLayout()
        pairs_row.addWidget(self.pairs_check)
        pairs_row.addWidget(self.clear_pairs_button)
        pairs_row.addWidget(self.pairs_label, 1)
        shown = QHBoxLayout()
        shown.addWidget(QLabel("show"))
        shown.addWidget(self.view_combo)
        shown.addWidget(QLabel("B opacity"))
        shown.addWidget(self.opacity_slider)
        shown.addWidget(self.flicker_check)
        shown.addWidget(self.profile_check)

        self.plot = pg.GraphicsLayoutWidget()
        self.view_box = self.plot.addViewBox(lockAspect=True, invertY=True, enableMenu=False)
        self.image = pg.ImageItem(axisOrder="row-major")
        self.overlay = pg.ImageItem(axisOrder="row-major")
        self.edges = pg.ImageItem(axisOrder="row-major")
        for item in (self.image, self.overlay, self.edges):
            self.view_box.addItem(item)
        self.line = pg.PlotDataItem(pen=pg.mkPen((255, 0, 255), width=2))
        self.view_box.addItem(self.line)
        # the second map of the side-by-side view, its pan and zoom linked to the first
        self.plot_b = pg.GraphicsLayoutWidget()
        self.view_box_b = self.plot_b.addViewBox(lockAspect=True, invertY=True,
                                                 enableMenu=False)
        self.image_b = pg.ImageItem(axisOrder="row-major")
        self.view_box_b.addItem(self.image_b)
        self.pair_marks = []
        for vb in (self.view_box, self.view_box_b):
            m = pg.ScatterPlotItem(size=12, symbol="o", pen=pg.mkPen((0, 220, 255), width=2),
                                   brush=None)
            vb.addItem(m)
            self.pair_marks.append(m)
        self.plot_b.scene().sigMouseClicked.connect(self._on_scene_click_b)
        self.view_box_b.setXLink(self.view_box)
        self.view_box_b.setYLink(self.view_box)
        self.plot_b.setVisible(False)
        # a linked cursor: the same cell marked in both maps
        self.cursors = []
        for vb in (self.view_box, self.view_box_b):
            c = pg.ScatterPlotItem(size=14, symbol="+", pen=pg.mkPen((255, 0, 255), width=2),
                                   brush=None)
            vb.addItem(c)
            self.cursors.append(c)
        self.plot.scene().sigMouseMoved.connect(
            lambda pos: self._hover(self.view_box, pos))
        self.plot_b.scene().sigMouseMoved.connect(
            lambda pos: self._hover(self.view_box_b, pos))
        self.profile_plot = pg.PlotWidget()
        self.profile_plot.setLabel("bottom", "distance along the line (mm)")
        self.profile_plot.setLabel("left", "height (mm)")
        self.profile_plot.addLegend()
        self.curve_a = self.profile_plot.plot(pen=pg.mkPen((40, 90, 220), width=2), name="A")
        self.curve_b = self.profile_plot.plot(pen=pg.mkPen((230, 120, 20), width=2),
                                              name="B moved onto A")
        self.plot.scene().sigMouseClicked.connect(self._on_scene_click)

        layout = QVBoxLayout(self)
        layout.addLayout(form)
        layout.addLayout(buttons)
        layout.addLayout(pairs_row)
        layout.addWidget(self.status_label)
        layout.addWidget(self.result_label)
        layout.addLayout(shown)
        maps = QHBoxLayout()
        maps.addWidget(self.plot, 1)
        maps.addWidget(self.plot_b, 1)
        layout.addLayout(maps, 3)
        layout.addWidget(self.profile_plot, 1)

        self.compare_button.clicked.connect(self.start_compare)
        self.write_button.clicked.connect(self._ask_write)
        self.pairs_check.toggled.connect(self._set_pairs_mode)
        self.clear_pairs_button.clicked.connect(self.clear_pairs)
        self.threshold_spin.valueChanged.connect(self._reoutline)
        self.metric_combo.currentIndexChanged.connect(self._remeasure)
        self.view_combo.currentIndexChanged.connect(self._show)
        self.opacity_slider.valueChanged.connect(self._show)
        self.flicker_check.toggled.connect(self._set_flicker)

    # ----- actions ---------------------------------------------------------------------------
    def params(self) -> CompareParams:
        pairs = tuple(self.pairs) if len(self.pairs) >= 3 else None
        reg = RegistrationParams(mirror=self.mirror_check.isChecked(),
                                 invert=self.invert_check.isChecked(), pairs=pairs)
        return CompareParams(registration=reg, threshold_mm=float(self.threshold_spin.value()),
                             metric=self.difference_metric())

    def difference_metric(self) -> str:
        """The difference's metric chosen (``normal`` or ``vertical``)."""
        return str(self.metric_combo.currentData())

    def start_compare(self) -> None:
        if self._worker.is_running():
            return
        a, b, params = self.a_edit.text().strip(), self.b_edit.text().strip(), self.params()

        def task(progress, cancel):
            sa = load_surface(a, params.ply_pixel_mm)
            sb = load_surface(b, params.ply_pixel_mm)
            return compare(sa, sb, params, progress, cancel)

        self.compare_button.setEnabled(False)
        self.status_label.setText("comparing…")
        self._worker.start(task)

    def write_to(self, folder: str | Path) -> None:
        """Write ``impress compare``'s folder for the current inputs and settings, with the
        report also as PDF (``report.pdf``: the format courts and case files take)."""
        if self._writer.is_running():
            return
        inputs = [self.a_edit.text().strip(), self.b_edit.text().strip()]
        params = self.params()
        self.status_label.setText(f"writing {folder}…")
        self._writing_to = Path(folder)
        from impress_gui import __version__
        from impress_gui.ui.pdf import html_to_pdf

        def pdf(html: str) -> bytes:
            return html_to_pdf(html, "IMPREsS comparison report",
                               f"IMPREsS workstation {__version__}")

        self._writer.start(lambda progress, cancel: write_comparison(
            inputs, folder, params, progress, cancel, pdf=pdf))

    def commit_to_project(self) -> None:
        """The window's Tab protocol: a written comparison is recorded in the case as soon as
        it is written (:meth:`_record_in_case`); nothing is pending here."""

    def is_dirty(self) -> bool:
        return False

    def _hover(self, vb, pos) -> None:
        p = vb.mapSceneToView(pos)
        self.set_cursor(float(p.x()), float(p.y()))

    def set_cursor(self, col: float, row: float) -> None:
        """Mark the same place (map columns, rows from the top) in both maps."""
        for c in self.cursors:
            c.setData([col], [row])

    def _set_flicker(self, on: bool) -> None:
        if on:
            self._flicker.start()
        else:
            self._flicker.stop()
            self._show()

    def _flick(self) -> None:
        """Flicker: the overlay of B shown and hidden in turn (the view switches to B over A)."""
        if self.comparison is None:
            return
        if self.view_combo.currentText() != VIEWS[3]:
            self.view_combo.setCurrentIndex(3)
        self.flicker_ticks += 1
        self.overlay.setOpacity(1.0 if self.flicker_ticks % 2 else 0.0)

    # ----- point pairs ------------------------------------------------------------------------
    def _set_pairs_mode(self, on: bool) -> None:
        if not on:
            self.view_box_b.setXLink(self.view_box)
            self.view_box_b.setYLink(self.view_box)
            self.plot_b.setVisible(False)
            self._show()
            return
        if self._loader.is_running():
            return
        a, b, px = self.a_edit.text().strip(), self.b_edit.text().strip(), self.params()
        self.status_label.setText("reading A and B for the point pairs…")
        self._loader.start(lambda progress, cancel: (load_surface(a, px.ply_pixel_mm),
                                                     load_surface(b, px.ply_pixel_mm)))

    def _on_loaded(self, surfaces) -> None:
        self.surfaces = surfaces
        a, b = surfaces
        self.view_box_b.setXLink(None)
        self.view_box_b.setYLink(None)
        for img, s in ((self.image, a), (self.image_b, b)):
            h = s.height_mm[::-1] if s.y_step_mm > 0 else s.height_mm
            fin = h[np.isfinite(h)]
            lo, hi = (np.percentile(fin, [1, 99]) if fin.size else (0.0, 1.0))
            img.setLookupTable(None)
            img.setImage(h, levels=(float(lo), float(hi)), autoLevels=False)
        self.overlay.setVisible(False)
        self.edges.setVisible(False)
        self.plot_b.setVisible(True)
        self.view_box.autoRange(padding=0.02)
        self.view_box_b.autoRange(padding=0.02)
        self.status_label.setText("click a point on A (left), then the same point on B (right)")
        self._mark_pairs()
        self.loaded.emit()

    def _on_scene_click_b(self, ev) -> None:
        if self.pairs_check.isChecked() and self.surfaces is not None \
                and ev.button() == Qt.MouseButton.LeftButton:
            p = self.view_box_b.mapSceneToView(ev.scenePos())
            self.add_pair_point("b", *_to_mm(self.surfaces[1], float(p.x()) - 0.5,
                                             float(p.y()) - 0.5))

    def add_pair_point(self, side: str, x_mm: float, y_mm: float) -> None:
        """One click of a pair: ``side`` "a" or "b", the point in that input's export frame."""
        self._pending[side] = (float(x_mm), float(y_mm))
        if "a" in self._pending and "b" in self._pending:
            self.pairs.append((self._pending.pop("a"), self._pending.pop("b")))
        self._mark_pairs()

    def clear_pairs(self) -> None:
        self.pairs, self._pending = [], {}
        self._mark_pairs()

    def _mark_pairs(self) -> None:
        n = len(self.pairs)
        self.pairs_label.setText(
            f"{n} point pair(s){': used by Compare' if n >= 3 else ' (3 needed)' if n else ''}"
            if n else "no point pairs: the coarse registration is automatic")
        if self.surfaces is None:
            return
        for k, (mark, s) in enumerate(zip(self.pair_marks, self.surfaces, strict=True)):
            pts = [p[k] for p in self.pairs] + ([self._pending[("a", "b")[k]]]
                                                if ("a", "b")[k] in self._pending else [])
            view = [_to_view(s, x, y) for x, y in pts]
            mark.setData([c + 0.5 for c, _ in view], [r + 0.5 for _, r in view])

    def shutdown(self) -> None:
        self._flicker.stop()
        self._loader.shutdown()
        self._worker.shutdown()
        self._writer.shutdown()
        self._outliner.shutdown()
        self._remeasurer.shutdown()

    def closeEvent(self, event) -> None:  # noqa: N802 - Qt override
        self.shutdown()
        super().closeEvent(event)

    def _browse(self, edit: QLineEdit) -> None:
        path = QFileDialog.getExistingDirectory(self, "Reconstruction folder", edit.text())
        if path:
            edit.setText(path)

    def _ask_write(self) -> None:
        path = QFileDialog.getExistingDirectory(self, "Comparison folder (new or empty)")
        if path:
            self.write_to(path)

    # ----- results ---------------------------------------------------------------------------
    def _on_compared(self, cmp: Comparison) -> None:
        self.comparison = cmp
        self.pairs_check.setChecked(False)
        self.view_box_b.setXLink(self.view_box)
        self.view_box_b.setYLink(self.view_box)
        self.compare_button.setEnabled(True)
        self.write_button.setEnabled(True)
        reg = cmp.registration
        self.status_label.setText("compared")
        self.status.emit(f"compared: residual RMS {reg.rms_mm:.4f} mm, overlap {reg.overlap:.3f}")
        self._describe(cmp)
        self._edges = cmp.outline
        self.profile, self._clicks = None, []
        self.curve_a.setData([], [])
        self.curve_b.setData([], [])
        self.line.setData([], [])
        self._show()
        self.view_box.autoRange(padding=0.02)
        self.compared.emit(cmp)

    def _describe(self, cmp: Comparison) -> None:
        reg, st = cmp.registration, cmp.stats
        self.result_label.setText(
            f"turn {reg.rotation_deg():.3f}°, residual RMS {reg.rms_mm:.4f} mm, overlap "
            f"{reg.overlap:.3f}; A - B {METRIC_LABELS[cmp.metric]} over {st.cells} cells: "
            f"median {st.median_mm:+.4f} mm, 95th percentile of |A - B| {st.p95_abs_mm:.4f} mm; "
            f"{len(cmp.regions)} region(s) above {self.threshold_spin.value():g} mm")

    def _remeasure(self) -> None:
        """The chosen metric applied to the current comparison (the registration and B's
        resampling kept; the figures and regions measured again)."""
        cmp = self.comparison
        if cmp is None or cmp.metric == self.difference_metric():
            return
        params = self.params()
        self._remeasurer.submit(
            lambda progress, cancel: derive(cmp.a, cmp.b_on_a, cmp.registration, params))

    def _on_remeasured(self, cmp: Comparison) -> None:
        if cmp.metric != self.difference_metric():
            return  # a later choice is on its way
        self.comparison = cmp
        self._edges = cmp.outline
        self._describe(cmp)
        self._show()
        self.compared.emit(cmp)

    def _reoutline(self) -> None:
        cmp = self.comparison
        if cmp is None:
            return
        t = float(self.threshold_spin.value())
        self._outliner.submit(lambda progress, cancel: (t, *outline(cmp.diff, cmp.a, t)))

    def _on_outlined(self, result) -> None:
        t, regions, edges = result
        self._edges = edges
        text = self.result_label.text()
        head = text.rsplit(";", 1)[0]
        self.result_label.setText(f"{head}; {len(regions)} region(s) above {t:g} mm")
        self._show()
        self.outlined.emit(len(regions))

    # ----- the profile ------------------------------------------------------------------------
    def view_to_mm(self, col: float, row: float) -> tuple[float, float]:
        """A point of the map as drawn (columns, rows from the top) in A's export frame."""
        assert self.comparison is not None
        return _to_mm(self.comparison.a, col, row)

    def mm_to_view(self, x: float, y: float) -> tuple[float, float]:
        assert self.comparison is not None
        return _to_view(self.comparison.a, x, y)

    def _on_scene_click(self, ev) -> None:
        if ev.button() != Qt.MouseButton.LeftButton:
            return
        p = self.view_box.mapSceneToView(ev.scenePos())
        if self.pairs_check.isChecked() and self.surfaces is not None:
            self.add_pair_point("a", *_to_mm(self.surfaces[0], float(p.x()) - 0.5,
                                             float(p.y()) - 0.5))
            return
        if self.comparison is None or not self.profile_check.isChecked():
            return
        # the image's pixel [r, c] covers [c, c + 1) x [r, r + 1) of the view
        self.add_profile_point(*self.view_to_mm(float(p.x()) - 0.5, float(p.y()) - 0.5))

    def add_profile_point(self, x_mm: float, y_mm: float) -> None:
        """One end of the profile (export frame, mm); the second draws it."""
        self._clicks.append((x_mm, y_mm))
        if len(self._clicks) == 2:
            self.set_profile(*self._clicks)
            self._clicks = []

    def set_profile(self, start_mm: tuple[float, float], end_mm: tuple[float, float]) -> None:
        """Draw both maps along the segment (export frame, mm) on one chart."""
        cmp = self.comparison
        if cmp is None:
            return
        prof = pair_profile(cmp.a, cmp.b_on_a, start_mm, end_mm)
        self.profile = prof
        self.curve_a.setData(prof.distance_mm, prof.a_mm, connect="finite")
        self.curve_b.setData(prof.distance_mm, prof.b_mm, connect="finite")
        (c0, r0), (c1, r1) = self.mm_to_view(*start_mm), self.mm_to_view(*end_mm)
        self.line.setData([c0 + 0.5, c1 + 0.5], [r0 + 0.5, r1 + 0.5])
        self.profiled.emit(prof)

    def _on_written(self, doc: dict) -> None:
        self._record_in_case(doc)
        self.status_label.setText("comparison folder written")
        self.status.emit("comparison folder written")
        self.written.emit(doc)

    def _record_in_case(self, doc: dict) -> None:
        """The case record (when a case is open): the comparison folder's record as an output
        (path, SHA-256) and a log entry naming the scans compared (with their hashes), the
        registration and every parameter."""
        project = getattr(self.session, "project", None)
        if project is None or self._writing_to is None:
            return
        from impress_gui.core.compare.record import RECORD_FILE

        record = self._writing_to / RECORD_FILE
        project.add_output(record, "comparison")
        reg = doc.get("registration") or {}
        project.log("comparison", {
            "folder": str(self._writing_to.resolve()),
            "inputs": doc.get("inputs"),
            "registration": {k: reg[k] for k in ("matrix_b_to_a", "mirror", "invert",
                                                 "rotation_about_z_deg", "residual_rms_mm",
                                                 "overlap") if k in reg},
            "parameters": doc.get("parameters"),
            "difference": {k: (doc.get("difference") or {}).get(k) for k in
                           ("metric", "definition", "median_mm", "p95_abs_mm", "rms_mm")},
        })
        self.changed.emit()

    def _on_failed(self, code: str, message: str) -> None:
        self.compare_button.setEnabled(True)
        self.status_label.setText(f"[{code}] {message}")
        self.failed.emit(code, message)

    def shown_image(self) -> np.ndarray | None:
        """The array the (first) map shows now (the difference, A or B on A)."""
        cmp = self.comparison
        if cmp is None:
            return None
        view = self.view_combo.currentText()
        if view == VIEWS[0]:
            return cmp.diff
        if view == VIEWS[2]:
            return cmp.b_on_a
        return cmp.a.height_mm  # A alone, under the overlay, or on the left side by side

    def _show(self) -> None:
        cmp = self.comparison
        if cmp is None:
            return
        flip = cmp.a.y_step_mm > 0  # row 0 at the top is the largest y

        def rows(a: np.ndarray) -> np.ndarray:
            return a[::-1] if flip else a

        view = self.view_combo.currentText()
        data = self.shown_image()
        assert data is not None
        self.plot_b.setVisible(view == VIEWS[4])
        if view == VIEWS[0]:
            r = colour_range(cmp.stats, float(self.threshold_spin.value()))
            self.image.setLookupTable(diverging_lut())
            self.image.setImage(rows(data), levels=(-r, r), autoLevels=False)
        else:
            finite = cmp.a.height_mm[np.isfinite(cmp.a.height_mm)]
            lo, hi = (np.percentile(finite, [1, 99]) if finite.size else (0.0, 1.0))
            self.image.setLookupTable(None)
            self.image.setImage(rows(cmp.a.height_mm if view in VIEWS[3:] else data),
                                levels=(float(lo), float(hi)), autoLevels=False)
            if view == VIEWS[4]:
                self.image_b.setImage(rows(cmp.b_on_a), levels=(float(lo), float(hi)),
                                      autoLevels=False)
        if view == VIEWS[3]:
            self.overlay.setImage(rows(cmp.b_on_a), levels=self.image.levels, autoLevels=False)
            self.overlay.setOpacity(self.opacity_slider.value() / 100.0)
            self.overlay.setVisible(True)
        else:
            self.overlay.setVisible(False)
        rgba = np.zeros((*cmp.outline.shape, 4), np.uint8)
        rgba[rows(self._edges if self._edges is not None else cmp.outline)] = (0, 200, 0, 255)
        self.edges.setImage(rgba, autoLevels=False)
        self.edges.setVisible(view == VIEWS[0])


def _to_mm(s: Surface, col: float, row: float) -> tuple[float, float]:
    """A point of a map as drawn (columns, rows from the top) in the surface's export frame."""
    r = s.shape[0] - 1 - row if s.y_step_mm > 0 else row
    x, y = s.xy(r, col)
    return float(x), float(y)


def _to_view(s: Surface, x: float, y: float) -> tuple[float, float]:
    fi, fj = s.cell(x, y)
    row = s.shape[0] - 1 - fi if s.y_step_mm > 0 else fi
    return float(fj), float(row)
