"""What the checkerboard calibration needs, asked in one small dialog: the views (a video file
or a folder of images), the board's inner corners (columns x rows, as OpenCV counts them) and
the side of one square in mm. The answers are remembered in the settings for next time.

The dialog only gathers and checks the answers; :class:`CheckerboardAction` (the calibration
tab's) runs :func:`~impress_gui.core.calibration.intrinsics.calibrate_camera` with them in the
tab's worker."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from PySide6.QtCore import QSettings
from PySide6.QtWidgets import (
    QButtonGroup,
    QDialog,
    QDialogButtonBox,
    QDoubleSpinBox,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPushButton,
    QRadioButton,
    QSpinBox,
    QWidget,
)

from impress_gui.core.formats.video import VIDEO_SUFFIXES
from impress_gui.session.calibration_jobs import checkerboard_task as _checkerboard_task
from impress_gui.session.session import Session
from impress_gui.ui.calibration.setup import SetupPanel
from impress_gui.ui.messages import Dialogs, Messenger
from impress_gui.ui.task_bar import TaskBar

VIDEO_FILTER = "Videos (" + " ".join(f"*{s}" for s in VIDEO_SUFFIXES) + ");;All files (*)"
KEY = "checkerboard/"
DEFAULTS = {"kind": "video", "source": "", "cols": 9, "rows": 6, "square_mm": 25.0}


@dataclass(frozen=True)
class CheckerboardRequest:
    source: Path
    board: tuple[int, int]  # inner corners (columns, rows)
    square_mm: float

    def describe(self) -> str:
        return f"{self.board[0]}x{self.board[1]} inner corners, {self.square_mm:g} mm squares"


def _setting(settings: QSettings | None, name: str):
    """A remembered answer (INI files give strings back), or the default."""
    default = DEFAULTS[name]
    if settings is None:
        return default
    value = settings.value(KEY + name, default)
    try:
        return type(default)(value)
    except (TypeError, ValueError):
        return default


class CheckerboardDialog(QDialog):
    """Source, board and square size. ``request()`` holds the answers once accepted."""

    def __init__(
        self, dialogs: Dialogs, settings: QSettings | None = None, parent: QWidget | None = None
    ) -> None:
        super().__init__(parent)
        self.dialogs, self.settings = dialogs, settings
        self.setWindowTitle("Camera intrinsics from a checkerboard")
        form = QFormLayout(self)
        intro = QLabel(
            "Views of a flat printed checkerboard, recorded with the scan's camera at the same "
            "zoom, focus and resolution: the whole board in every view, tilted, in all parts "
            "of the image; at least 8 distinct views."
        )
        intro.setWordWrap(True)
        form.addRow(intro)

        self.video_radio = QRadioButton("Video file")
        self.folder_radio = QRadioButton("Folder of images")
        self.kind_group = QButtonGroup(self)
        kinds = QHBoxLayout()
        for b in (self.video_radio, self.folder_radio):
            self.kind_group.addButton(b)
            kinds.addWidget(b)
        kinds.addStretch(1)
        form.addRow("Views from", kinds)
        (
            self.folder_radio if _setting(settings, "kind") == "folder" else self.video_radio
        ).setChecked(True)
        self.path_edit = QLineEdit(_setting(settings, "source"))
        self.path_edit.setMinimumWidth(360)
        self.browse_button = QPushButton("Browse...")
        self.browse_button.clicked.connect(self.browse)
        row = QHBoxLayout()
        row.addWidget(self.path_edit, 1)
        row.addWidget(self.browse_button)
        form.addRow("Source", row)

        self.cols_spin, self.rows_spin = QSpinBox(), QSpinBox()
        for spin, name in ((self.cols_spin, "cols"), (self.rows_spin, "rows")):
            spin.setRange(3, 60)
            spin.setValue(min(60, max(3, _setting(settings, name))))
            spin.valueChanged.connect(self._show_squares)
        board = QHBoxLayout()
        board.addWidget(self.cols_spin)
        board.addWidget(QLabel("x"))
        board.addWidget(self.rows_spin)
        self.squares_label = QLabel("")
        board.addWidget(self.squares_label, 1)
        form.addRow("Inner corners", board)
        self.square_spin = QDoubleSpinBox()
        self.square_spin.setRange(0.1, 1000.0)
        self.square_spin.setDecimals(2)
        self.square_spin.setSuffix(" mm")
        self.square_spin.setValue(min(1000.0, max(0.1, _setting(settings, "square_mm"))))
        self.square_spin.setToolTip("The side of one square, measured on the print with a ruler")
        form.addRow("Square size", self.square_spin)

        self.error_label = QLabel("")
        self.error_label.setWordWrap(True)
        self.error_label.setStyleSheet("color: #b00000; font-weight: bold")
        self.error_label.hide()
        form.addRow(self.error_label)
        self.buttons = QDialogButtonBox(
            QDialogButtonBox.StandardButton.Ok | QDialogButtonBox.StandardButton.Cancel
        )
        self.ok_button = self.buttons.button(QDialogButtonBox.StandardButton.Ok)
        self.ok_button.setText("Calibrate")
        self.buttons.accepted.connect(self.accept)
        self.buttons.rejected.connect(self.reject)
        form.addRow(self.buttons)
        self._show_squares()

    # ----- answers --------------------------------------------------------------------------
    @property
    def kind(self) -> str:
        return "folder" if self.folder_radio.isChecked() else "video"

    def request(self) -> CheckerboardRequest:
        return CheckerboardRequest(
            Path(self.path_edit.text().strip()).expanduser(),
            (self.cols_spin.value(), self.rows_spin.value()),
            float(self.square_spin.value()),
        )

    def problem(self) -> str | None:
        """Why the answers cannot be used yet (None when they can)."""
        text = self.path_edit.text().strip()
        if not text:
            return "Choose the checkerboard video or the folder of images."
        path = Path(text).expanduser()
        if not path.exists():
            return f"{path} does not exist."
        if self.kind == "video" and path.is_dir():
            return f"{path} is a folder: choose 'Folder of images', or a video file."
        if self.kind == "folder" and not path.is_dir():
            return f"{path} is a file: choose 'Video file', or a folder of images."
        return None

    # ----- actions --------------------------------------------------------------------------
    def browse(self) -> None:
        start = self.path_edit.text().strip()
        if self.kind == "folder":
            path = self.dialogs.directory("Folder of checkerboard images", start)
        else:
            path = self.dialogs.open_file("Checkerboard video", VIDEO_FILTER, start)
        if path:
            self.path_edit.setText(str(path))
            self.error_label.hide()

    def accept(self) -> None:
        problem = self.problem()
        if problem:
            self.error_label.setText(problem)
            self.error_label.show()
            return
        self.error_label.hide()
        if self.settings is not None:
            req = self.request()
            for name, value in (
                ("kind", self.kind),
                ("source", str(req.source)),
                ("cols", req.board[0]),
                ("rows", req.board[1]),
                ("square_mm", req.square_mm),
            ):
                self.settings.setValue(KEY + name, value)
            self.settings.sync()
        super().accept()

    def _show_squares(self) -> None:
        c, r = self.cols_spin.value(), self.rows_spin.value()
        self.squares_label.setText(f"(a board of {c + 1} x {r + 1} squares)")


class CheckerboardAction:
    """The checkerboard calibration of the camera: ask (``calibrate_camera``), run the job
    through ``tasks``, give the intrinsics to ``setup`` and log them in the session's project.
    ``settings`` keeps the dialog's answers (None: nothing is remembered); ``parent`` is the
    widget the dialog is modal to; ``status`` takes a line for the status bar."""

    def __init__(
        self,
        messenger: Messenger,
        dialogs: Dialogs,
        settings: QSettings | None,
        session: Session,
        setup: SetupPanel,
        tasks: TaskBar,
        status: Callable[[str], object],
        parent: QWidget | None = None,
    ) -> None:
        self.messenger, self.dialogs, self.settings = messenger, dialogs, settings
        self.session, self.setup, self.tasks, self.status = session, setup, tasks, status
        self.parent = parent
        self.dialog: CheckerboardDialog | None = None

    def calibrate_camera(self) -> CheckerboardDialog | None:
        """Ask for the checkerboard views, board and square size (a window-modal dialog that
        does not block); on OK, calibrate the camera in the worker."""
        if self.tasks.is_busy():
            self.messenger.info("Busy", f"Wait for '{self.tasks.what}' to finish, or cancel it.")
            return None
        if self.dialog is not None:
            self.dialog.deleteLater()
        self.dialog = dlg = CheckerboardDialog(self.dialogs, self.settings, self.parent)
        dlg.accepted.connect(lambda: self.run_checkerboard(dlg.request()))
        dlg.open()
        return dlg

    def run_checkerboard(self, req: CheckerboardRequest) -> bool:
        return self.tasks.run(
            f"Calibrating the camera ({req.describe()})",
            _checkerboard_task(req.source, req.board, req.square_mm),
            lambda intr: self._on_camera_calibrated(intr, req),
            "Checkerboard calibration failed",
        )

    def _on_camera_calibrated(self, intr, req: CheckerboardRequest) -> None:
        self.setup.set_intrinsics(intr)
        self.session.log(
            "camera calibrated from a checkerboard",
            {
                "source": str(req.source),
                "board": list(req.board),
                "square_mm": req.square_mm,
                "rms_px": intr.rms_px,
                "frames_used": list(intr.frames_used or ()),
            },
        )
        self.status(
            f"Camera calibrated from {len(intr.frames_used or ())} board views: "
            f"f = {intr.fx:.1f} px, RMS {intr.rms_px:.3f} px"
        )
