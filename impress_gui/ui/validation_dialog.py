"""The method-validation dialog: runs :mod:`impress_gui.validation.run` through the
window's worker adapter, shows the table in the thesis' layout beside the thesis' figures and
opens the HTML report. Simulated (quick or full) or from a real-scan spec file."""

from __future__ import annotations

from pathlib import Path

from PySide6.QtCore import Qt, QUrl, Signal
from PySide6.QtGui import QDesktopServices, QFont
from PySide6.QtWidgets import (
    QComboBox,
    QDialog,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QLineEdit,
    QPlainTextEdit,
    QProgressBar,
    QPushButton,
    QTableWidget,
    QTableWidgetItem,
    QVBoxLayout,
    QWidget,
)

from impress_gui.ui.worker import Worker

MODES = (
    "Simulator, quick (640x360, minutes)",
    "Simulator, full (1920x1080, about half an hour)",
    "Real scans (spec file)",
)
COLUMNS = (
    "Placement",
    "xy ME",
    "xy SD",
    "z ME",
    "z SD",
    "n xy/z",
    "thesis xy ME",
    "thesis xy SD",
    "thesis z ME",
    "thesis z SD",
)


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.3f}"


class ValidationDialog(QDialog):
    """Non-modal; ``finished_run(record)`` fires when a run has completed and its report is
    written."""

    finished_run = Signal(object)

    def __init__(
        self,
        messenger,
        dialogs,
        parent: QWidget | None = None,
        default_out: str | Path | None = None,
    ) -> None:
        super().__init__(parent)
        self.setWindowTitle("Method validation (thesis table 4.1)")
        self.messenger, self.dialogs = messenger, dialogs
        self.record: dict | None = None
        self.report_path: Path | None = None
        self.worker = Worker(parent=self, name="validation")
        self.worker.progress.connect(self._on_progress)
        self.worker.finished.connect(self._on_finished)
        self.worker.failed.connect(self._on_failed)
        self.worker.cancelled.connect(self._on_cancelled)

        form = QFormLayout()
        self.mode = QComboBox()
        self.mode.addItems(MODES)
        self.mode.currentIndexChanged.connect(self._refresh)
        form.addRow("Validate", self.mode)
        self.out_edit = QLineEdit(str(default_out or Path.home() / "impress-validation"))
        browse = QPushButton("Browse...")
        browse.clicked.connect(self._choose_out)
        row = QHBoxLayout()
        row.addWidget(self.out_edit, 1)
        row.addWidget(browse)
        form.addRow("Output folder", row)
        self.spec_edit = QLineEdit()
        self.spec_edit.setPlaceholderText(
            "impress.validation-spec JSON: known dimensions and measuring positions"
        )
        self.spec_browse = QPushButton("Browse...")
        self.spec_browse.clicked.connect(self._choose_spec)
        row = QHBoxLayout()
        row.addWidget(self.spec_edit, 1)
        row.addWidget(self.spec_browse)
        form.addRow("Spec file", row)

        self.run_button = QPushButton("Run")
        self.run_button.clicked.connect(self.run)
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.clicked.connect(self.worker.cancel)
        self.report_button = QPushButton("Open report")
        self.report_button.clicked.connect(self.open_report)
        buttons = QHBoxLayout()
        for b in (self.run_button, self.cancel_button, self.report_button):
            buttons.addWidget(b)
        buttons.addStretch(1)
        self.progress = QProgressBar()
        self.progress.setRange(0, 1000)
        self.status = QLabel("")
        self.table = QTableWidget(0, len(COLUMNS))
        self.table.setHorizontalHeaderLabels(COLUMNS)
        self.table.verticalHeader().hide()
        self.text = QPlainTextEdit()
        self.text.setReadOnly(True)
        self.text.setFont(QFont("monospace"))
        self.text.setMaximumHeight(130)
        lay = QVBoxLayout(self)
        lay.addLayout(form)
        lay.addLayout(buttons)
        lay.addWidget(self.progress)
        lay.addWidget(self.status)
        lay.addWidget(self.table, 1)
        lay.addWidget(self.text)
        self.resize(980, 560)
        self._refresh()

    # ----- inputs -------------------------------------------------------------------------------
    def _choose_out(self) -> None:
        d = self.dialogs.directory("Folder for the validation", self.out_edit.text())
        if d:
            self.out_edit.setText(d)

    def _choose_spec(self) -> None:
        f = self.dialogs.open_file("Validation spec", "JSON (*.json)", self.spec_edit.text())
        if f:
            self.spec_edit.setText(f)
            self.mode.setCurrentIndex(2)

    def _refresh(self) -> None:
        running = self.worker.is_running()
        real = self.mode.currentIndex() == 2
        self.spec_edit.setEnabled(real and not running)
        self.spec_browse.setEnabled(real and not running)
        self.run_button.setEnabled(not running)
        self.cancel_button.setEnabled(running)
        self.mode.setEnabled(not running)
        self.report_button.setEnabled(self.report_path is not None and not running)

    def task(self):
        """The core task for the selected mode: ``fn(progress, cancel) -> (record, paths)``."""
        from impress_gui.validation.report import write_report
        from impress_gui.validation.run import RunConfig, run_real, run_simulated

        out = Path(self.out_edit.text()).expanduser()
        idx = self.mode.currentIndex()
        spec = Path(self.spec_edit.text()).expanduser() if idx == 2 else None
        cfg = RunConfig.quick() if idx == 0 else RunConfig.full()

        def fn(progress, cancel):
            if spec is not None:
                record = run_real(spec, out, progress, cancel)
            else:
                record = run_simulated(cfg, out, progress, cancel)
            return record, write_report(record, out)

        return fn

    # ----- running ------------------------------------------------------------------------------
    def run(self) -> bool:
        if self.worker.is_running():
            return False
        if self.mode.currentIndex() == 2 and not self.spec_edit.text().strip():
            self.messenger.warning("Cannot run", "Choose the spec file of the real scans.")
            return False
        if not self.out_edit.text().strip():
            self.messenger.warning("Cannot run", "Choose an output folder.")
            return False
        self.progress.setValue(0)
        self.status.setText("Starting...")
        self.worker.start(self.task())
        self._refresh()
        return True

    def _on_progress(self, frac: float, msg: str) -> None:
        self.progress.setValue(int(round(1000 * frac)))
        self.status.setText(msg)

    def _on_finished(self, result) -> None:
        record, paths = result
        self.record, self.report_path = record, paths["report"]
        self.show_record(record)
        self.status.setText(f"Report written to {self.report_path}")
        self.progress.setValue(1000)
        self._refresh()
        self.finished_run.emit(record)

    def _on_failed(self, code: str, message: str) -> None:
        self.status.setText(f"Failed [{code}]")
        self._refresh()
        self.messenger.error("The validation failed", message, code)

    def _on_cancelled(self) -> None:
        self.status.setText("Cancelled")
        self._refresh()

    def show_record(self, record: dict) -> None:
        from impress_gui.validation.report import format_table, table_rows

        rows = table_rows(record)
        self.table.setRowCount(len(rows))
        for i, r in enumerate(rows):
            th = r["thesis"] or [None] * 4
            cells = [
                r["group"],
                _fmt(r["xy"]["mean_abs_mm"]),
                _fmt(r["xy"]["sd_mm"]),
                _fmt(r["z"]["mean_abs_mm"]),
                _fmt(r["z"]["sd_mm"]),
                f"{r['xy']['n']}/{r['z']['n']}",
                *[_fmt(v) for v in th],
            ]
            for j, c in enumerate(cells):
                item = QTableWidgetItem(c)
                if j:
                    item.setTextAlignment(
                        Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter
                    )
                self.table.setItem(i, j, item)
        self.table.resizeColumnsToContents()
        text = format_table(record)
        self.text.setPlainText(text[text.find("Acceptance") :] if "Acceptance" in text else text)

    def open_report(self) -> bool:
        if self.report_path is None:
            return False
        return QDesktopServices.openUrl(QUrl.fromLocalFile(str(self.report_path)))

    def shutdown(self) -> None:
        self.worker.shutdown()

    def closeEvent(self, event) -> None:  # noqa: N802 - Qt override
        if self.worker.is_running():
            self.worker.cancel()
        super().closeEvent(event)
