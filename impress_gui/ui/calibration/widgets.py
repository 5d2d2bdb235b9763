"""Building blocks of the calibration tab: frame navigation, the pick-frame rows and the corner
panel (target diagram, loupe, instruction, snap and undo controls)."""

from __future__ import annotations

from PySide6.QtCore import Qt, QTimer, Signal
from PySide6.QtWidgets import (
    QCheckBox,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QScrollArea,
    QSlider,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from impress_gui.core.calibration.pick_editor import FRAMES, PickEditor
from impress_gui.core.calibration.target import CORNER_NAMES
from impress_gui.ui.calibration.target_diagram import TargetDiagram
from impress_gui.ui.frame_view import Loupe

ROLE = {"t1": "t1 (green stripe on the target)", "t2": "t2 (red stripe on the target)"}


class FrameNavigator(QWidget):
    """Slider, frame number and time. ``frame_requested`` follows the user's scrubbing
    (debounced, so a fast drag decodes only the frame it stops on)."""

    frame_requested = Signal(int)
    fit_requested = Signal()

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        row = QHBoxLayout(self)
        row.setContentsMargins(0, 0, 0, 0)
        self.fit_button = QPushButton("Fit")
        self.fit_button.setToolTip(
            "Show the whole frame (also: right click). Wheel: zoom; drag the background: pan."
        )
        self.fit_button.clicked.connect(self.fit_requested)
        self.slider = QSlider(Qt.Orientation.Horizontal)
        self.slider.setMinimumWidth(80)  # on a narrow window the labels give way, not it
        self.spin = QSpinBox()
        self.spin.setPrefix("frame ")
        self.time_label = QLabel("")
        self.role_label = QLabel("")
        self.role_label.setMinimumWidth(60)
        self.role_label.setStyleSheet("font-weight: bold")
        for w in (self.fit_button, self.slider, self.spin, self.time_label, self.role_label):
            row.addWidget(w, 1 if w is self.slider else 0)
        self._timer = QTimer(self, singleShot=True, interval=25)
        self._timer.timeout.connect(lambda: self.frame_requested.emit(self.slider.value()))
        self.slider.valueChanged.connect(lambda k: self._follow(self.spin, k))
        self.spin.valueChanged.connect(lambda k: self._follow(self.slider, k))

    def _follow(self, other: QSlider | QSpinBox, k: int) -> None:
        other.blockSignals(True)
        other.setValue(k)
        other.blockSignals(False)
        self._timer.start()

    def set_range(self, count: int) -> None:
        for w in (self.slider, self.spin):
            w.blockSignals(True)
            w.setRange(0, max(0, count - 1))
            w.blockSignals(False)

    def set_frame(self, k: int) -> None:
        """Show ``k`` without requesting it (the caller shows the frame)."""
        self._timer.stop()
        for w in (self.slider, self.spin):
            w.blockSignals(True)
            w.setValue(k)
            w.blockSignals(False)


class PickFrames(QGroupBox):
    """Find t1/t2, and per pick frame: its number, Go to, Use this frame."""

    go_requested = Signal(str)
    use_requested = Signal(str)

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__("Calibration frames", parent)
        grid = QGridLayout(self)
        self.find_button = QPushButton("Find t1 and t2")
        self.find_button.setToolTip(
            "Scan the video for the frames where each stripe lies on the target"
        )
        self.proposal_label = QLabel("")
        grid.addWidget(self.find_button, 0, 0)
        grid.addWidget(self.proposal_label, 0, 1, 1, 2)
        self.labels: dict[str, QLabel] = {}
        self.go_buttons: dict[str, QPushButton] = {}
        self.use_buttons: dict[str, QPushButton] = {}
        for row, which in enumerate(FRAMES, start=1):
            self.labels[which] = QLabel()
            self.labels[which].setToolTip(ROLE[which])
            self.go_buttons[which] = QPushButton(f"Go to {which}")
            self.go_buttons[which].clicked.connect(
                lambda _=False, w=which: self.go_requested.emit(w)
            )
            self.use_buttons[which] = QPushButton("Use this frame")
            self.use_buttons[which].setToolTip(f"Make the frame shown {ROLE[which]}")
            self.use_buttons[which].clicked.connect(
                lambda _=False, w=which: self.use_requested.emit(w)
            )
            grid.addWidget(self.labels[which], row, 0)
            grid.addWidget(self.go_buttons[which], row, 1)
            grid.addWidget(self.use_buttons[which], row, 2)

    def show_frames(self, frames: dict[str, int | None], has_video: bool, busy: bool) -> None:
        for which, k in frames.items():
            self.labels[which].setText(f"{which}: {'-' if k is None else k}")
            self.go_buttons[which].setEnabled(has_video and k is not None)
            self.use_buttons[which].setEnabled(has_video and not busy)
        self.find_button.setEnabled(has_video and not busy)


class CornerPanel(QGroupBox):
    """The order of the corners, the loupe, what to click next, snapping and undo."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__("Corners A-F", parent)
        grid = QGridLayout(self)
        self.diagram = TargetDiagram()
        self.loupe = Loupe()
        grid.addWidget(self.diagram, 0, 0)
        grid.addWidget(self.loupe, 0, 1)
        self.instruction = QLabel("")
        self.instruction.setWordWrap(True)
        self.instruction.setStyleSheet("font-size: 12pt; font-weight: bold; color: #8a0080")
        grid.addWidget(self.instruction, 1, 0, 1, 2)
        self.counts_label = QLabel("")
        grid.addWidget(self.counts_label, 2, 0, 1, 2)
        self.snap_check = QCheckBox("Snap clicks to the corner")
        self.snap_check.setChecked(True)
        self.snap_check.setToolTip(
            "Move each click to the sub-pixel corner nearby; the click is "
            "shown as a white x and Undo snap puts the corner back there"
        )
        grid.addWidget(self.snap_check, 3, 0, 1, 2)
        row = QHBoxLayout()
        self.undo_snap_button = QPushButton("Undo snap")
        self.undo_button = QPushButton("Undo")
        self.redo_button = QPushButton("Redo")
        self.clear_button = QPushButton("Clear frame")
        self.clear_button.setToolTip(
            "Remove the corners of the frame shown (Undo brings them back)"
        )
        for b in (self.undo_snap_button, self.undo_button, self.redo_button, self.clear_button):
            row.addWidget(b)
        grid.addLayout(row, 4, 0, 1, 2)
        row = QHBoxLayout()
        self.import_button = QPushButton("Import picks...")
        self.export_button = QPushButton("Export picks...")
        row.addWidget(self.import_button)
        row.addWidget(self.export_button)
        grid.addLayout(row, 5, 0, 1, 2)

    def show_state(self, editor: PickEditor, which: str | None, has_video: bool) -> None:
        """Show what is marked in the pick frame on screen (``which``) and what comes next."""
        s = editor.state
        corners = s.corners(which) if which else {}
        nxt = editor.next_corner(which) if which else None
        free = next((f for f in FRAMES if s.frame(f) is None), None)
        self.loupe.set_marks(corners, s.raw(which) if which else {})
        # a frame that is neither t1 nor t2 becomes the free one with a click on corner A
        ring = nxt if which else (CORNER_NAMES[0] if has_video and free else None)
        self.diagram.set_state(set(corners), ring)
        if not has_video:
            text = "Load the scan video."
        elif which is None:
            text = (
                f"Click corner A to make this frame {free}, or use Find t1 and t2."
                if free
                else "Go to t1 or t2 to mark corners."
            )
        elif nxt is None:
            text = f"All six corners marked in {which}."
        else:
            text = f"{which}: click corner {nxt}."
        self.instruction.setText(text)
        self.counts_label.setText(
            "   ".join(f"{f}: {editor.count(f)}/{len(CORNER_NAMES)}" for f in FRAMES)
        )
        self.undo_snap_button.setEnabled(editor.undo_label.startswith("snap"))
        self.undo_button.setEnabled(editor.can_undo())
        self.undo_button.setToolTip(f"Undo: {editor.undo_label}")
        self.redo_button.setEnabled(editor.can_redo())
        self.clear_button.setEnabled(bool(corners))


class CalibrationSidebar(QScrollArea):
    """The tab's right-hand column: video, calibration frames, corners, inputs, Calibrate and
    the result. It only lays the widgets out; the tab connects them."""

    def __init__(self, setup: QWidget, results: QWidget, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        side = QWidget()
        box = QVBoxLayout(side)
        video = QGroupBox("Scan video")
        vl = QVBoxLayout(video)
        self.video_label = QLabel("No video loaded.")
        self.video_label.setWordWrap(True)
        self.video_label.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        self.load_video_button = QPushButton("Load video...")
        vl.addWidget(self.video_label)
        vl.addWidget(self.load_video_button)
        box.addWidget(video)
        self.frames = PickFrames()
        box.addWidget(self.frames)
        self.corners = CornerPanel()
        box.addWidget(self.corners)
        box.addWidget(setup)
        run = QGroupBox("Calibrate")
        grid = QGridLayout(run)
        self.calibrate_button = QPushButton("Calibrate")
        self.calibrate_button.setStyleSheet("font-weight: bold; padding: 6px")
        self.export_cal_button = QPushButton("Export calibration...")
        self.overlay_target = QCheckBox("Show the fitted target")
        self.overlay_target.setToolTip(
            "The target model, placed by the calibration, drawn "
            "over the frame (magenta): it should sit on the corners"
        )
        self.overlay_stripes = QCheckBox("Show detected stripes")
        for check in (self.overlay_target, self.overlay_stripes):
            check.setChecked(True)
        grid.addWidget(self.calibrate_button, 0, 0)
        grid.addWidget(self.export_cal_button, 0, 1)
        grid.addWidget(self.overlay_target, 1, 0)
        grid.addWidget(self.overlay_stripes, 1, 1)
        box.addWidget(run)
        box.addWidget(results)
        box.addStretch(1)
        self.setWidget(side)
        self.setWidgetResizable(True)
        self.setHorizontalScrollBarPolicy(Qt.ScrollBarPolicy.ScrollBarAlwaysOff)
        self.setMinimumWidth(480)
