"""The viewer's side panels: display (layer, colours, range, blend, light), tools (mode,
readout, ruler, levelling), the measurement list and the export buttons. They only gather
inputs and show results; :class:`~impress_gui.ui.viewer.tab.ViewerTab` does the work."""

from __future__ import annotations

import math

from PySide6.QtCore import Qt, Signal
from PySide6.QtWidgets import (
    QAbstractItemView,
    QButtonGroup,
    QComboBox,
    QDialog,
    QDoubleSpinBox,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QPlainTextEdit,
    QPushButton,
    QSizePolicy,
    QSlider,
    QTableWidget,
    QTableWidgetItem,
    QToolButton,
    QVBoxLayout,
    QWidget,
)

from impress_gui.core.measure.uncertainty import budgets_text, k_text
from impress_gui.ui.common_widgets import SidePanelScroll  # noqa: F401 - its former home
from impress_gui.ui.viewer.map import legend_html

LAYERS = (
    ("fused", "Heightmap (fused)"),
    ("green", "Green laser heightmap"),
    ("red", "Red laser heightmap"),
    ("difference", "Difference green - red"),
    ("contribution", "Contribution (which laser)"),
    ("texture", "Texture"),
    ("hillshade", "Hillshade"),
)
COLOUR_MAPS = ("turbo", "viridis", "CET-L1", "magma", "cividis", "CET-D1")
MODES = (
    ("pan", "Pan"),
    ("ruler", "Ruler"),
    ("marker", "Marker"),
    ("level3", "Level: 3 points"),
    ("region", "Level: region"),
)


def _spin(
    lo: float, hi: float, value: float, step: float, decimals: int = 2, suffix: str = " mm"
) -> QDoubleSpinBox:
    s = QDoubleSpinBox()
    s.setRange(lo, hi)
    s.setDecimals(decimals)
    s.setSingleStep(step)
    s.setValue(value)
    s.setSuffix(suffix)
    s.setKeyboardTracking(False)
    return s


class DisplayPanel(QGroupBox):
    layer_changed = Signal(str)
    cmap_changed = Signal(str)
    range_changed = Signal(float, float)
    auto_range = Signal()
    blend_changed = Signal(float)
    light_changed = Signal(float, float)
    side_by_side = Signal(bool)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__("Display", parent)
        g = QGridLayout(self)
        self.layer = QComboBox()
        for key, text in LAYERS:
            self.layer.addItem(text, key)
        self.layer.currentIndexChanged.connect(lambda _i: self.layer_changed.emit(self.layer_key()))
        self.cmap = QComboBox()
        self.cmap.addItems(COLOUR_MAPS)
        self.cmap.currentTextChanged.connect(self.cmap_changed)
        self.lo = _spin(-1000, 1000, 0, 0.1)
        self.hi = _spin(-1000, 1000, 1, 0.1)
        for s in (self.lo, self.hi):
            s.valueChanged.connect(
                lambda _v: self.range_changed.emit(self.lo.value(), self.hi.value())
            )
        self.auto_button = QPushButton("Auto")
        self.auto_button.setToolTip(
            "Automatic colour range: the 1 and 99 percentiles of the heights of the evidence "
            "area (the calibration target left out when the reconstruction knows where it "
            "is). A range you type or drag stays until you press Auto."
        )
        self.auto_button.clicked.connect(self.auto_range)
        self.blend = QSlider(Qt.Orientation.Horizontal)
        self.blend.setRange(0, 100)
        self.blend.setToolTip("0: the layer only; 100: the registered texture only")
        self.blend.valueChanged.connect(lambda v: self.blend_changed.emit(v / 100.0))
        self.azimuth = _spin(0, 360, 315, 15, 0, " °")
        self.azimuth.setWrapping(True)
        self.azimuth.setToolTip(
            "Where the light comes from, in degrees clockwise from the top of the screen "
            "(315: upper left, under which a hollow looks hollow)"
        )
        self.elevation = _spin(1, 90, 35, 5, 0, " °")
        self.elevation.setToolTip("The light's height above the ground, in degrees")
        for s in (self.azimuth, self.elevation):
            s.valueChanged.connect(
                lambda _v: self.light_changed.emit(self.azimuth.value(), self.elevation.value())
            )
        # the spin boxes may be narrower than their preferred width (their minimum shows a
        # value with its unit): the panel then fits the side panel's 430 px
        for s in (self.lo, self.hi, self.azimuth, self.elevation):
            s.setSizePolicy(QSizePolicy.Policy.Preferred, QSizePolicy.Policy.Fixed)
        rows = (("Layer", self.layer), ("Colours", self.cmap))
        for r, (text, w) in enumerate(rows):
            g.addWidget(QLabel(text), r, 0)
            g.addWidget(w, r, 1, 1, 3)
        g.addWidget(QLabel("Range"), 2, 0)
        g.addWidget(self.lo, 2, 1)
        g.addWidget(self.hi, 2, 2)
        g.addWidget(self.auto_button, 2, 3)
        g.addWidget(QLabel("Texture blend"), 3, 0)
        g.addWidget(self.blend, 3, 1, 1, 3)
        g.addWidget(QLabel("Light az/elev"), 4, 0)
        g.addWidget(self.azimuth, 4, 1)
        g.addWidget(self.elevation, 4, 2)
        # the heightmap and the texture in two views, panned and zoomed together
        self.side_button = QPushButton("Side by side: layer | texture")
        self.side_button.setCheckable(True)
        self.side_button.setToolTip(
            "Show the texture in a second view beside the map, with the same pan and zoom "
            "and the cursor's crosshair in both; the readout gives the height under the "
            "cursor in either (View menu, key S)"
        )
        self.side_button.toggled.connect(self.side_by_side)
        g.addWidget(self.side_button, 6, 0, 1, 4)
        # the contribution layer's legend: which laser each colour stands for
        self.legend = QLabel(legend_html())
        self.legend.setTextFormat(Qt.TextFormat.RichText)
        self.legend.setWordWrap(True)
        self.legend.setVisible(False)
        g.addWidget(self.legend, 5, 0, 1, 4)
        self.layer_changed.connect(lambda key: self.legend.setVisible(key == "contribution"))

    def layer_key(self) -> str:
        return str(self.layer.currentData())

    def set_layer(self, key: str) -> None:
        self.layer.setCurrentIndex(self.layer.findData(key))

    def show_range(self, lo: float, hi: float) -> None:
        for s, v in ((self.lo, lo), (self.hi, hi)):
            s.blockSignals(True)
            s.setValue(v)
            s.blockSignals(False)


class ToolPanel(QGroupBox):
    """Mode buttons, cursor readout, ruler/profile settings and levelling."""

    mode_changed = Signal(str)
    settings_changed = Signal()

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__("Measure", parent)
        v = QVBoxLayout(self)
        row = QHBoxLayout()
        self.mode_group = QButtonGroup(self)
        self.mode_buttons: dict[str, QToolButton] = {}
        for key, text in MODES:
            b = QToolButton()
            b.setText(text)
            b.setCheckable(True)
            b.clicked.connect(lambda _c, k=key: self.mode_changed.emit(k))
            self.mode_group.addButton(b)
            self.mode_buttons[key] = b
            row.addWidget(b)
        self.mode_buttons["pan"].setChecked(True)
        v.addLayout(row)
        self.hint = QLabel("")
        self.hint.setWordWrap(True)
        self.hint.setStyleSheet("color: #666")
        v.addWidget(self.hint)
        g = QGridLayout()
        self.radius = _spin(0, 20, 0.5, 0.1)
        self.radius.setToolTip("Heights are averaged over the cells within this radius")
        self.width = _spin(0, 50, 1.0, 0.1)
        self.width.setToolTip(
            "The profile is averaged across this width (perpendicular to the ruler)"
        )
        for s in (self.radius, self.width):
            s.valueChanged.connect(lambda _v: self.settings_changed.emit())
        g.addWidget(QLabel("Averaging radius"), 0, 0)
        g.addWidget(self.radius, 0, 1)
        g.addWidget(QLabel("Profile width"), 1, 0)
        g.addWidget(self.width, 1, 1)
        v.addLayout(g)
        self.readout = WrapLabel("Cursor: -")
        self.readout.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.ruler_text = WrapLabel("Ruler: choose Ruler and click two points")
        self.step_text = WrapLabel("Step (B - A): -")
        for lab in (self.readout, self.ruler_text, self.step_text):
            lab.setWordWrap(True)
            lab.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
            v.addWidget(lab)
        row = QHBoxLayout()
        self.add_ruler_button = QPushButton("Add ruler to measurements")
        self.clear_ruler_button = QPushButton("Clear ruler")
        row.addWidget(self.add_ruler_button)
        row.addWidget(self.clear_ruler_button)
        v.addLayout(row)
        self.level_text = QLabel("Levelling: off (heights relative to the calibration's ground)")
        self.level_text.setWordWrap(True)
        v.addWidget(self.level_text)
        row = QHBoxLayout()
        self.fit_region_button = QPushButton("Fit plane to region")
        self.clear_level_button = QPushButton("Clear levelling")
        row.addWidget(self.fit_region_button)
        row.addWidget(self.clear_level_button)
        v.addLayout(row)

    def set_mode(self, key: str) -> None:
        self.mode_buttons[key].setChecked(True)


class WrapLabel(QLabel):
    """A word-wrapped label that is always as tall as its text needs at its width: a
    QLabel's height-for-width is not honoured by every layout above it (the step's
    uncertainty line was cut off below in the side panel at 1920x1080, one wrapped line
    short)."""

    def __init__(self, text: str = "", parent: QWidget | None = None) -> None:
        super().__init__(text, parent)
        self.setWordWrap(True)

    def _fit(self) -> None:
        # a style sheet set just before the text (the step's bold) is applied when the
        # widget is polished: measure with the font it will be drawn in
        self.ensurePolished()
        if self.width() > 0:
            self.setMinimumHeight(max(self.heightForWidth(self.width()), 0))

    def setStyleSheet(self, sheet: str) -> None:  # noqa: N802 - Qt's name
        super().setStyleSheet(sheet)
        self._fit()

    def setText(self, text: str) -> None:  # noqa: N802 - Qt's name
        super().setText(text)
        self._fit()

    def resizeEvent(self, event) -> None:  # noqa: N802 - Qt's name
        super().resizeEvent(event)
        self._fit()


class MeasurementTable(QGroupBox):
    """The project's measurements: number, kind, label (editable), value, note (editable)."""

    edited = Signal(int, str, str)  # row, field ("label" | "note"), text
    COLUMNS = ("#", "Kind", "Label", "Value", "Note")

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__("Measurements and annotations", parent)
        v = QVBoxLayout(self)
        self.table = QTableWidget(0, len(self.COLUMNS))
        self.table.setHorizontalHeaderLabels(self.COLUMNS)
        self.table.setSelectionBehavior(QAbstractItemView.SelectionBehavior.SelectRows)
        self.table.setSelectionMode(QAbstractItemView.SelectionMode.SingleSelection)
        self.table.verticalHeader().hide()
        self.table.horizontalHeader().setStretchLastSection(True)
        self.table.itemChanged.connect(self._on_item_changed)
        v.addWidget(self.table)
        row = QHBoxLayout()
        self.show_button = QPushButton("Show")
        self.show_button.setToolTip("Put the ruler (or view) on the selected measurement")
        self.update_button = QPushButton("Update from ruler")
        self.delete_button = QPushButton("Delete")
        self.clear_button = QPushButton("Clear all")
        self.clear_button.setToolTip("Delete every measurement (Edit > Undo brings them back)")
        self.export_button = QPushButton("Export CSV...")
        self.details_button = QPushButton("Uncertainty...")
        self.details_button.setToolTip("The selected measurement's uncertainty budget: each "
                                       "component, its standard uncertainty and sensitivity")
        for b in (self.show_button, self.update_button, self.delete_button):
            row.addWidget(b)
        v.addLayout(row)
        row = QHBoxLayout()  # a second row: the panel stays narrow enough to show them all
        self.method_button = QPushButton("Method validation...")
        self.method_button.setToolTip("Take the method's bias and precision from an impress "
                                      "validate record (validation.json) into every budget")
        for b in (self.details_button, self.method_button, self.clear_button, self.export_button):
            row.addWidget(b)
        v.addLayout(row)
        self._filling = False
        self.details_dialog: QDialog | None = None

    def fill(self, measurements: list[dict]) -> None:
        self._filling = True
        self.table.setRowCount(len(measurements))
        for r, m in enumerate(measurements):
            cells = (
                str(r + 1),
                m.get("kind", ""),
                m.get("label", ""),
                summary(m),
                m.get("note", ""),
            )
            for c, text in enumerate(cells):
                item = QTableWidgetItem(text)
                flags = Qt.ItemFlag.ItemIsSelectable | Qt.ItemFlag.ItemIsEnabled
                if c in (2, 4):
                    flags |= Qt.ItemFlag.ItemIsEditable
                item.setFlags(flags)
                if c == 3 and m.get("uncertainty"):
                    item.setToolTip(budgets_text(m["uncertainty"]))
                self.table.setItem(r, c, item)
        self.table.resizeColumnsToContents()
        self._filling = False

    def show_details(self, m: dict, number: int) -> QDialog:
        """A window with measurement ``number``'s uncertainty budgets (``m``'s record)."""
        if self.details_dialog is not None:
            self.details_dialog.close()
        d = QDialog(self)
        d.setWindowTitle(f"Uncertainty budget of measurement {number}")
        lay = QVBoxLayout(d)
        text = QPlainTextEdit(d)
        text.setReadOnly(True)
        budgets = m.get("uncertainty")
        text.setPlainText(budgets_text(budgets) if budgets else
                          "This measurement was recorded without an uncertainty budget.")
        lay.addWidget(text)
        close = QPushButton("Close", d)
        close.clicked.connect(d.close)
        lay.addWidget(close)
        d.resize(720, 360)
        d.text = text
        self.details_dialog = d
        d.show()
        return d

    def selected_row(self) -> int | None:
        rows = self.table.selectionModel().selectedRows()
        return rows[0].row() if rows else None

    def _on_item_changed(self, item: QTableWidgetItem) -> None:
        if self._filling:
            return
        fields = {2: "label", 4: "note"}
        if item.column() in fields:
            self.edited.emit(item.row(), fields[item.column()], item.text())


def _mm(v) -> str:
    return "-" if v is None else f"{v:.3f} mm"


def _u(v: dict, key: str, no_u: bool = False) -> str:
    """`` (± U)`` of a value whose expanded uncertainty is recorded as ``key``; `` (± -)``
    where it is recorded without a figure because no U is stated (``no_u``)."""
    u = v.get(key)
    if u is None or not math.isfinite(u):
        return " (± -)" if no_u and key in v else ""
    return f" (± {u:.3f})"


def _no_u(m: dict) -> str:
    """`` [no U: why]`` when a budget of the measurement states no uncertainty (e.g. the
    calibration is unstable), else ""."""
    why = next((b.get("incomplete") for b in (m.get("uncertainty") or {}).values()
                if isinstance(b, dict) and b.get("incomplete")), "")
    return f" [no U: {why}]" if why else ""


def _k_of(v: dict) -> str:
    """``k=2`` / ``k=1.93-2``: the coverage factors recorded beside a measurement's U values
    (``k``, ``k_<name>``; a record from before they were recorded: k = 2)."""
    ks = [float(x) for key, x in v.items()
          if (key == "k" or (key.startswith("k_") and f"U_k2_{key[2:]}_mm" in v))
          and isinstance(x, (int, float)) and math.isfinite(x)]
    return k_text(ks or [2.0])


def summary(m: dict) -> str:
    """One line of a measurement's main values, each with its expanded uncertainty (about
    95 %, its coverage factor said once: ``[U: k=2]``) in brackets when it was measured with
    one."""
    v = m.get("values", {})
    kind = m.get("kind")
    no_u = bool(_no_u(m))
    if kind == "ruler":
        text = (f"xy {_mm(v.get('xy_mm'))}{_u(v, 'U_k2_xy_mm', no_u)}, 3D "
                f"{_mm(v.get('d3_mm'))}{_u(v, 'U_k2_3d_mm', no_u)}, dz "
                f"{_mm(v.get('dz_mm'))}{_u(v, 'U_k2_dz_mm', no_u)}")
        if "step_mm" in v:
            sd = v.get("step_sd_mm")
            text += f"; step {_mm(v.get('step_mm'))}" + ("" if sd is None else f" (SD {sd:.3f})")
            text += "" if v.get("U_k2_step_mm") is None else \
                f" (U {v['U_k2_step_mm']:.3f} mm)"
        if _no_u(m):
            return text + _no_u(m)
        if any(k.startswith("U_k2") for k in v):
            text += f" [U: {_k_of(v)}]"
        return text
    if kind in ("point", "annotation"):
        return f"height {_mm(v.get('height_mm'))}{_u(v, 'U_k2_mm', no_u)}" + (
            _no_u(m) or (f" [U: {_k_of(v)}]" if v.get("U_k2_mm") is not None else ""))
    if kind == "plane":
        return f"tilt {v.get('tilt_deg', 0):.3f}°, RMS {_mm(v.get('rms_mm'))}"
    return ""


class ExportPanel(QGroupBox):
    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__("Export", parent)
        g = QGridLayout(self)
        self.buttons: dict[str, QPushButton] = {}
        items = (
            ("tiff", "Heightmap TIFF..."),
            ("x3p", "X3P..."),
            ("ply", "PLY..."),
            ("png", "Figure PNG..."),
            ("profile_csv", "Profile CSV..."),
            ("profile_png", "Profile PNG..."),
            ("report", "Report (HTML)..."),
            ("report_pdf", "Report (PDF)..."),
            ("view3d", "3D view..."),
        )
        for k, (key, text) in enumerate(items):
            b = QPushButton(text)
            self.buttons[key] = b
            g.addWidget(b, k // 2, k % 2)
