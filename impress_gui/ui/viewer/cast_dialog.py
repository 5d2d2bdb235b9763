"""The viewer's "Digital cast" dialog: the choices of ``impress cast`` (negative or positive,
base thickness, how the mesh is made smaller than the grid (the adaptive surface's tolerance,
the triangle cap), the whole data or the visible region) before
the file is chosen. The cast itself is :func:`impress_gui.core.measure.cast.write_cast`, the
command line's code, run by :class:`~impress_gui.ui.viewer.actions.ViewerExports`."""

from __future__ import annotations

from PySide6.QtWidgets import (
    QComboBox,
    QDialog,
    QDialogButtonBox,
    QDoubleSpinBox,
    QFormLayout,
    QLabel,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from impress_gui.core.measure.cast import (
    DEFAULT_BASE_MM,
    DEFAULT_MAX_TRIANGLES,
    DEFAULT_TOLERANCE_MM,
    MAX_BASE_MM,
    MAX_TOLERANCE_MM,
    MIN_TOLERANCE_MM,
    MIN_TRIANGLES,
    CastParams,
)

MODES = (
    ("negative", "Negative: the impression as recorded"),
    ("positive", "Positive: the outsole (the poured cast, turned over)"),
)
DECIMATIONS = (
    ("adaptive", "Adaptive: every cell within the tolerance (small triangles where the relief "
                 "needs them)"),
    ("sample", "Every k-th cell (vertices on the heightmap's cells)"),
    ("quadric", "Quadric decimation (open3d: walls and edges kept; slower)"),
)
MAX_TRIANGLES_LIMIT = 100_000_000
NOTE = (
    "The cast is made from the reconstruction's fused heightmap as recorded: the layer shown "
    "and any levelling do not apply. Holes are filled smoothly. The mesh is in millimetres in "
    "the right-handed export frame; a record NAME.json (inputs, parameters, open3d's checks and "
    "the surface's deviation from the heightmap) is written beside it. The format follows the "
    "name: .stl, .ply or .obj."
)


def crop_text(crop: tuple[float, float, float, float]) -> str:
    x0, y0, x1, y1 = crop
    return (f"x {min(x0, x1):.1f} to {max(x0, x1):.1f} mm, y {min(y0, y1):.1f} to "
            f"{max(y0, y1):.1f} mm (export frame)")


class CastDialog(QDialog):
    """The cast's options. ``visible_crop``: the view's visible region in the export frame
    (x0, y0, x1, y1 mm), offered as the region to cast; None: only the whole data."""

    def __init__(self, visible_crop: tuple[float, float, float, float] | None = None,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setWindowTitle("Export a digital cast")
        self.visible_crop = visible_crop
        form = QFormLayout()
        self.mode_combo = QComboBox()
        for key, text in MODES:
            self.mode_combo.addItem(text, key)
        self.mode_combo.setToolTip(
            "Positive: the cast poured into the impression and turned over (rotated 180 deg "
            "about y), relief up, as the outsole is seen from below; never mirrored")
        form.addRow("Mesh", self.mode_combo)
        self.base_spin = QDoubleSpinBox()
        self.base_spin.setRange(0.1, MAX_BASE_MM)
        self.base_spin.setDecimals(2)
        self.base_spin.setSingleStep(0.5)
        self.base_spin.setSuffix(" mm")
        self.base_spin.setValue(DEFAULT_BASE_MM)
        self.base_spin.setToolTip("The base's thickness below the surface's lowest point")
        form.addRow("Base thickness", self.base_spin)
        self.decimate_combo = QComboBox()
        for key, text in DECIMATIONS:
            self.decimate_combo.addItem(text, key)
        form.addRow("Fewer triangles by", self.decimate_combo)
        self.tolerance_spin = QDoubleSpinBox()
        self.tolerance_spin.setRange(MIN_TOLERANCE_MM, MAX_TOLERANCE_MM)
        self.tolerance_spin.setDecimals(3)
        self.tolerance_spin.setSingleStep(0.005)
        self.tolerance_spin.setSuffix(" mm")
        self.tolerance_spin.setValue(DEFAULT_TOLERANCE_MM)
        self.tolerance_spin.setToolTip(
            "Adaptive: the largest vertical distance between the mesh and any cell of the "
            "heightmap; the triangle cap wins if it is reached first (the record says so)")
        form.addRow("Surface tolerance", self.tolerance_spin)
        self.triangles_spin = QSpinBox()
        self.triangles_spin.setRange(MIN_TRIANGLES, MAX_TRIANGLES_LIMIT)
        self.triangles_spin.setSingleStep(100_000)
        self.triangles_spin.setGroupSeparatorShown(True)
        self.triangles_spin.setValue(DEFAULT_MAX_TRIANGLES)
        self.triangles_spin.setToolTip("At most this many triangles (the file's size: 50 bytes "
                                       "each in STL)")
        form.addRow("Max triangles", self.triangles_spin)
        self.decimate_combo.currentIndexChanged.connect(self._method_changed)
        self.region_combo = QComboBox()
        self.region_combo.addItem("All the data (the rectangle around the cells with data)",
                                  "data")
        if visible_crop is not None:
            self.region_combo.addItem(f"The visible region: {crop_text(visible_crop)}",
                                      "visible")
        form.addRow("Region", self.region_combo)
        note = QLabel(NOTE)
        note.setWordWrap(True)
        self.buttons = QDialogButtonBox(
            QDialogButtonBox.StandardButton.Ok | QDialogButtonBox.StandardButton.Cancel)
        self.buttons.button(QDialogButtonBox.StandardButton.Ok).setText("Choose the file...")
        self.buttons.accepted.connect(self.accept)
        self.buttons.rejected.connect(self.reject)
        lay = QVBoxLayout(self)
        lay.addLayout(form)
        lay.addWidget(note)
        lay.addWidget(self.buttons)

    def _method_changed(self) -> None:
        self.tolerance_spin.setEnabled(self.decimate_combo.currentData() == "adaptive")

    @property
    def ok_button(self):
        return self.buttons.button(QDialogButtonBox.StandardButton.Ok)

    @property
    def cancel_button(self):
        return self.buttons.button(QDialogButtonBox.StandardButton.Cancel)

    def params(self) -> CastParams:
        """The cast's parameters as chosen."""
        crop = self.visible_crop if self.region_combo.currentData() == "visible" else None
        return CastParams(
            positive=self.mode_combo.currentData() == "positive",
            base_mm=round(float(self.base_spin.value()), 6),
            crop_mm=None if crop is None else tuple(round(float(v), 3) for v in crop),
            max_triangles=int(self.triangles_spin.value()),
            decimate=str(self.decimate_combo.currentData()),
            tolerance_mm=round(float(self.tolerance_spin.value()), 6),
        )
