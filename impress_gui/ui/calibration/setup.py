"""The calibration inputs besides the picks: camera intrinsics, target model, rail speed."""

from __future__ import annotations

import importlib.util

import numpy as np
from PySide6.QtCore import Signal
from PySide6.QtWidgets import (
    QComboBox,
    QDialog,
    QDialogButtonBox,
    QDoubleSpinBox,
    QFormLayout,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QSpinBox,
    QWidget,
)

from impress_gui.core.base.errors import ImpressError, InputError
from impress_gui.core.calibration.geometry import MAX_READOUT_MS, Intrinsics
from impress_gui.core.calibration.target import TargetModel, default_target
from impress_gui.hardware.rail import SPEED_PRESETS_MM_S as SPEED_PRESETS
from impress_gui.ui.messages import Dialogs, Messenger

JSON_FILTER = "JSON files (*.json);;All files (*)"
MEASURE_TEXT = "Measure from a lamp video..."
SHUTTER_NOT_GIVEN, SHUTTER_GLOBAL, SHUTTER_ROLLING = "not given", "global", "rolling"
#: the readout field's value before one is entered or measured (a typical CMOS camcorder's)
DEFAULT_READOUT_MS = 20.0
LOAD_TARGET = "Load a target file..."


def checkerboard_available() -> bool:
    """The colleague's checkerboard calibration (impress_gui.core.calibration.intrinsics) is installed."""
    try:
        return importlib.util.find_spec("impress_gui.core.calibration.intrinsics") is not None
    except (ImportError, ValueError):
        return False


def describe_intrinsics(intr: Intrinsics | None) -> str:
    if intr is None:
        return "none - load a file, enter the values, or calibrate from a checkerboard"
    w, h = intr.image_size
    k1 = intr.dist_coeffs[0]
    rms = f", RMS {intr.rms_px:.2f} px" if intr.rms_px is not None else ""
    src = f" ({intr.source})" if intr.source else ""
    shutter = (f", rolling shutter {intr.readout_ms:g} ms" if intr.readout_ms
               else ", global shutter" if intr.readout_ms == 0 else "")
    return (f"{w}x{h}, f = {intr.fx:.1f} px, centre ({intr.cx:.1f}, {intr.cy:.1f}), "
            f"k1 {k1:+.3f}{rms}{shutter}{src}")


class IntrinsicsDialog(QDialog):
    """Type the camera matrix and distortion in by hand (e.g. from the camera's data sheet)."""

    def __init__(
        self, intr: Intrinsics | None, size: tuple[int, int] | None, parent: QWidget | None = None,
        dialogs: Dialogs | None = None,
    ) -> None:
        super().__init__(parent)
        self.dialogs = dialogs or Dialogs(self)
        self.setWindowTitle("Camera intrinsics")
        form = QFormLayout(self)
        w, h = intr.image_size if intr else (size or (1920, 1080))
        self.width_spin, self.height_spin = QSpinBox(), QSpinBox()
        for spin, v in ((self.width_spin, w), (self.height_spin, h)):
            spin.setRange(16, 20000)
            spin.setValue(v)
            spin.setSuffix(" px")
        row = QHBoxLayout()
        row.addWidget(self.width_spin)
        row.addWidget(QLabel("x"))
        row.addWidget(self.height_spin)
        form.addRow("Image size", row)
        vals = {
            "fx": intr.fx if intr else 1.1 * w,
            "fy": intr.fy if intr else 1.1 * w,
            "cx": intr.cx if intr else (w - 1) / 2,
            "cy": intr.cy if intr else (h - 1) / 2,
        }
        dist = intr.dist_coeffs[:5] if intr else np.zeros(5)
        vals.update(zip(("k1", "k2", "p1", "p2", "k3"), dist))
        self.fields: dict[str, QDoubleSpinBox] = {}
        for name, v in vals.items():
            spin = QDoubleSpinBox()
            px = name in ("fx", "fy", "cx", "cy")
            spin.setRange(0.0 if px else -10.0, 100000.0 if px else 10.0)
            spin.setDecimals(3 if px else 6)
            spin.setValue(float(v))
            if px:
                spin.setSuffix(" px")
            form.addRow(name, spin)
            self.fields[name] = spin
        # the shutter: not given (the scene calibration estimates a readout from the picks),
        # a global shutter (readout 0, recorded as such) or a rolling shutter's readout
        self.shutter_combo = QComboBox()
        for text, kind in (("not given: estimated from the picks", SHUTTER_NOT_GIVEN),
                           ("global shutter", SHUTTER_GLOBAL),
                           ("rolling shutter, readout", SHUTTER_ROLLING)):
            self.shutter_combo.addItem(text, kind)
        self.shutter_combo.setToolTip(
            "A CMOS camcorder has a rolling shutter: its rows are exposed one after another "
            "while the carriage moves, and each row is placed where the camera was when it was "
            "exposed. Global shutter: every row at once (recorded as readout 0). Not given: "
            "the scene calibration estimates a readout from the corner picks and uses it when "
            "they clearly show one.")
        self.readout_spin = QDoubleSpinBox()
        self.readout_spin.setRange(0.01, MAX_READOUT_MS)
        self.readout_spin.setDecimals(2)
        self.readout_spin.setSuffix(" ms")
        self.readout_spin.setValue(float(intr.readout_ms) if intr and intr.readout_ms
                                   else DEFAULT_READOUT_MS)
        self.readout_spin.setToolTip(
            "A rolling shutter's readout: the time from the exposure of the first image row to "
            "the last (a CMOS camcorder's, from its data sheet or measured; often 15-30 ms).")
        kind = (SHUTTER_NOT_GIVEN if intr is None or intr.readout_ms is None
                else SHUTTER_GLOBAL if intr.readout_ms == 0 else SHUTTER_ROLLING)
        self.shutter_combo.setCurrentIndex(self.shutter_combo.findData(kind))
        self.shutter_combo.currentIndexChanged.connect(self._shutter_changed)
        self._shutter_changed()
        self.flicker_combo = QComboBox()
        for hz, text in ((100.0, "lamp flicker 100 Hz (50 Hz mains)"),
                         (120.0, "lamp flicker 120 Hz (60 Hz mains)")):
            self.flicker_combo.addItem(text, hz)
        self.measure_button = QPushButton(MEASURE_TEXT)
        self.measure_button.setToolTip(
            "A video, in the scans' recording mode, of a plain light surface lit only by a mains "
            "lamp, with the shortest exposure: the rolling shutter draws the lamp's flicker as "
            "bands whose spacing gives the readout (docs/camera-calibration.md).")
        self.measure_button.clicked.connect(lambda: self.measure_readout())
        self.readout_note = QLabel("")
        self.readout_note.setWordWrap(True)
        from impress_gui.ui.worker import Worker

        self._flicker = Worker(parent=self, name="flicker-readout")
        self._measured: tuple[float, str] | None = None
        self._flicker.progress.connect(self._flicker_progress)
        self._flicker.finished.connect(self._flicker_done)
        self._flicker.failed.connect(self._flicker_failed)
        self._flicker.cancelled.connect(self._flicker_cancelled)
        ro = QGridLayout()
        ro.addWidget(self.shutter_combo, 0, 0)
        ro.addWidget(self.readout_spin, 0, 1)
        ro.addWidget(self.flicker_combo, 1, 0)
        ro.addWidget(self.measure_button, 1, 1)
        ro.addWidget(self.readout_note, 2, 0, 1, 2)
        form.addRow("Shutter", ro)
        buttons = QDialogButtonBox(
            QDialogButtonBox.StandardButton.Ok | QDialogButtonBox.StandardButton.Cancel
        )
        buttons.accepted.connect(self.accept)
        buttons.rejected.connect(self.reject)
        form.addRow(buttons)

    def shutter(self) -> str:
        """``SHUTTER_NOT_GIVEN``, ``SHUTTER_GLOBAL`` or ``SHUTTER_ROLLING``."""
        return str(self.shutter_combo.currentData())

    def _shutter_changed(self) -> None:
        self.readout_spin.setEnabled(self.shutter() == SHUTTER_ROLLING)

    def measure_readout(self, path: str | None = None) -> bool:
        """Measure the readout from a video of a flickering lamp in the background
        (:func:`~impress_gui.core.calibration.readout.readout_from_flicker`, as
        ``impress calibrate-camera --readout-from-flicker``); the button cancels while it runs.
        The readout goes into the field when done; the result or the reason for a refusal is
        shown under it. Returns whether a measurement was started."""
        from impress_gui.ui.calibration.checkerboard_dialog import VIDEO_FILTER

        if self._flicker.is_running():
            self._flicker.cancel()
            return False
        path = path or self.dialogs.open_file("Video of a flickering lamp", VIDEO_FILTER)
        if not path:
            return False
        hz = float(self.flicker_combo.currentData())
        size = (self.width_spin.value(), self.height_spin.value())

        def task(progress, cancel):
            from impress_gui.core.calibration.readout import measure_readout_file

            return measure_readout_file(path, hz, size=size, progress=progress, cancel=cancel)

        self.measure_button.setText("Cancel measuring")
        self.readout_note.setText("Measuring...")
        self._flicker.start(task)
        return True

    def _flicker_progress(self, fraction: float, message: str) -> None:
        self.readout_note.setText(f"Measuring: {message} ({100 * fraction:.0f} %)")

    def _flicker_done(self, result) -> None:
        r, source = result
        self.measure_button.setText(MEASURE_TEXT)
        self.shutter_combo.setCurrentIndex(self.shutter_combo.findData(SHUTTER_ROLLING))
        self.readout_spin.setValue(round(r.readout_ms, 2))
        self.readout_note.setText(f"Measured: {r.summary()}")
        # where the readout came from, kept with the intrinsics while the field holds it
        self._measured = (self.readout_spin.value(), source)

    def _flicker_failed(self, code: str, message: str) -> None:
        self.measure_button.setText(MEASURE_TEXT)
        self.readout_note.setText(f"Not measured ({code}): {message}")

    def _flicker_cancelled(self) -> None:
        self.measure_button.setText(MEASURE_TEXT)
        self.readout_note.setText("Measuring cancelled; the readout is as it was.")

    def done(self, result: int) -> None:  # accept, reject, close: no thread left running
        self._flicker.shutdown()
        super().done(result)

    def intrinsics(self) -> Intrinsics:
        f = {k: s.value() for k, s in self.fields.items()}
        k = np.array([[f["fx"], 0.0, f["cx"]], [0.0, f["fy"], f["cy"]], [0.0, 0.0, 1.0]])
        d = np.array([f["k1"], f["k2"], f["p1"], f["p2"], f["k3"]])
        source = "entered by hand"
        shutter = self.shutter()
        readout = (None if shutter == SHUTTER_NOT_GIVEN else 0.0 if shutter == SHUTTER_GLOBAL
                   else float(self.readout_spin.value()))
        if (self._measured is not None and shutter == SHUTTER_ROLLING
                and self._measured[0] == self.readout_spin.value()):
            source += f"; {self._measured[1]}"
        return Intrinsics(
            k, d, (self.width_spin.value(), self.height_spin.value()), source=source,
            readout_ms=readout,
        )


class SetupPanel(QGroupBox):
    """Intrinsics, target model and rail speed. ``changed`` fires when any of them changes;
    ``checkerboard_requested`` asks the tab to run the checkerboard calibration."""

    changed = Signal()
    checkerboard_requested = Signal()

    def __init__(
        self, messenger: Messenger, dialogs: Dialogs, parent: QWidget | None = None
    ) -> None:
        super().__init__("Camera, target and speed", parent)
        self.messenger, self.dialogs = messenger, dialogs
        self.intrinsics: Intrinsics | None = None
        self.video_size: tuple[int, int] | None = None
        self._targets: list[TargetModel] = []
        self._target_index = 0
        grid = QGridLayout(self)

        grid.addWidget(QLabel("Intrinsics"), 0, 0)
        self.intrinsics_label = QLabel(describe_intrinsics(None))
        self.intrinsics_label.setWordWrap(True)
        grid.addWidget(self.intrinsics_label, 0, 1, 1, 3)
        self.load_intrinsics_button = QPushButton("Load...")
        self.enter_intrinsics_button = QPushButton("Enter...")
        self.checkerboard_button = QPushButton("From checkerboard...")
        if not checkerboard_available():
            self.checkerboard_button.setEnabled(False)
            self.checkerboard_button.setToolTip("checkerboard calibration is not installed")
        else:
            self.checkerboard_button.setToolTip(
                "Calibrate the camera from a video or a folder of "
                "images of a 9x6 checkerboard with 25 mm squares"
            )
        self.load_intrinsics_button.clicked.connect(self.load_intrinsics_file)
        self.enter_intrinsics_button.clicked.connect(self.enter_intrinsics)
        self.checkerboard_button.clicked.connect(self.checkerboard_requested)
        for i, b in enumerate(
            (self.load_intrinsics_button, self.enter_intrinsics_button, self.checkerboard_button)
        ):
            grid.addWidget(b, 1, 1 + i)

        grid.addWidget(QLabel("Target"), 2, 0)
        self.target_combo = QComboBox()
        self.target_combo.activated.connect(self._on_target_chosen)
        grid.addWidget(self.target_combo, 2, 1, 1, 3)
        self.add_target(default_target(), select=True)

        grid.addWidget(QLabel("Rail speed"), 3, 0)
        self.speed_spin = QDoubleSpinBox()
        self.speed_spin.setRange(0.0, 1000.0)
        self.speed_spin.setDecimals(4)
        self.speed_spin.setSuffix(" mm/s")
        self.speed_spin.setSpecialValueText("enter the speed")
        self.speed_spin.setToolTip(
            "The rail speed of this scan, as set on the motor. Heights and "
            "lengths along the scan scale with it."
        )
        self.speed_spin.valueChanged.connect(lambda _v: self.changed.emit())
        grid.addWidget(self.speed_spin, 3, 1)
        self.preset_combo = QComboBox()
        self.preset_combo.addItem("preset...")
        for name, v in SPEED_PRESETS.items():
            self.preset_combo.addItem(f"{name} ({v:g} mm/s)", v)
        self.preset_combo.activated.connect(self._on_preset)
        grid.addWidget(self.preset_combo, 3, 2, 1, 2)
        grid.setColumnStretch(1, 1)

    # ----- values ---------------------------------------------------------------------------
    @property
    def target(self) -> TargetModel | None:
        i = self.target_combo.currentIndex()
        return self._targets[i] if 0 <= i < len(self._targets) else None

    def speed_mm_s(self) -> float:
        return float(self.speed_spin.value())

    def set_speed(self, value: float | None) -> None:
        self.speed_spin.setValue(float(value or 0.0))

    def set_intrinsics(self, intr: Intrinsics | None, announce: bool = True) -> None:
        self.intrinsics = intr
        self.intrinsics_label.setText(describe_intrinsics(intr))
        self.check_size()
        if announce:
            self.changed.emit()

    def set_video_size(self, size: tuple[int, int] | None) -> None:
        self.video_size = size
        self.check_size()

    def check_size(self) -> bool:
        """Flag intrinsics made for another image size than the video's."""
        if self.intrinsics is None or self.video_size is None:
            self.intrinsics_label.setStyleSheet("")
            return True
        try:
            self.intrinsics.check_image_size(*self.video_size)
        except InputError as exc:
            self.intrinsics_label.setText(f"{describe_intrinsics(self.intrinsics)}\n{exc}")
            self.intrinsics_label.setStyleSheet("color: #b00000; font-weight: bold")
            return False
        self.intrinsics_label.setStyleSheet("")
        return True

    def add_target(self, target: TargetModel, select: bool = True) -> None:
        names = [t.name for t in self._targets]
        if target.name in names:
            i = names.index(target.name)
            self._targets[i] = target
        else:
            i = len(self._targets)
            self._targets.append(target)
            self.target_combo.insertItem(i, target.name)
            self.target_combo.setItemData(i, target.description, 3)  # tooltip role
        if self.target_combo.findText(LOAD_TARGET) < 0:
            self.target_combo.addItem(LOAD_TARGET)
        if select:
            self.target_combo.setCurrentIndex(i)
            self._target_index = i

    # ----- actions --------------------------------------------------------------------------
    def load_intrinsics_file(self, path: str | None = None) -> bool:
        path = path or self.dialogs.open_file("Load camera intrinsics", JSON_FILTER)
        if not path:
            return False
        try:
            intr = Intrinsics.load(path)
        except ImpressError as exc:
            self.messenger.exception("Cannot load the intrinsics", exc)
            return False
        self.set_intrinsics(intr)
        return True

    def enter_intrinsics(self) -> None:
        dlg = IntrinsicsDialog(self.intrinsics, self.video_size, self, self.dialogs)
        if dlg.exec() != QDialog.DialogCode.Accepted:
            return
        try:
            self.set_intrinsics(dlg.intrinsics())
        except ImpressError as exc:
            self.messenger.exception("These intrinsics are not usable", exc)

    def load_target_file(self, path: str | None = None) -> bool:
        path = path or self.dialogs.open_file("Load a target model", JSON_FILTER)
        if not path:
            return False
        try:
            target = TargetModel.load(path)
        except ImpressError as exc:
            self.messenger.exception("Cannot load the target model", exc)
            return False
        self.add_target(target, select=True)
        self.changed.emit()
        return True

    def _on_target_chosen(self, index: int) -> None:
        if self.target_combo.itemText(index) == LOAD_TARGET:
            if not self.load_target_file():
                self.target_combo.setCurrentIndex(self._target_index)
            return
        self._target_index = index
        self.changed.emit()

    def _on_preset(self, index: int) -> None:
        v = self.preset_combo.itemData(index)
        if v is not None:
            self.speed_spin.setValue(float(v))
        self.preset_combo.setCurrentIndex(0)
