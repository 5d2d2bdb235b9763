"""The case details of a project: case and evidence identifiers, examiner, notes, and who
signed the case record (read-only)."""

from __future__ import annotations

from PySide6.QtCore import Qt
from PySide6.QtWidgets import (
    QDialog,
    QDialogButtonBox,
    QFormLayout,
    QLabel,
    QLineEdit,
    QPlainTextEdit,
    QWidget,
)

from impress_gui.core.project.project import Project, current_user, describe_signatures
from impress_gui.core.project.signing import local_fingerprint


class CaseDialog(QDialog):
    def __init__(
        self,
        project: Project | None = None,
        parent: QWidget | None = None,
        title: str = "Case details",
    ) -> None:
        super().__init__(parent)
        self.setWindowTitle(title)
        form = QFormLayout(self)
        self.case_id = QLineEdit(project.case_id if project else "")
        self.case_id.setPlaceholderText("e.g. 2024-00117")
        self.evidence_id = QLineEdit(project.evidence_id if project else "")
        self.evidence_id.setPlaceholderText("item number of the impression")
        self.examiner = QLineEdit(
            project.examiner if project and project.examiner else current_user()
        )
        self.notes = QPlainTextEdit(project.notes if project else "")
        self.notes.setPlaceholderText("scene, substrate, conditions...")
        form.addRow("Case", self.case_id)
        form.addRow("Evidence item", self.evidence_id)
        form.addRow("Examiner", self.examiner)
        form.addRow("Notes", self.notes)
        self.signature = QLabel(signature_text(project))
        self.signature.setWordWrap(True)
        self.signature.setTextInteractionFlags(Qt.TextInteractionFlag.TextSelectableByMouse)
        form.addRow("Signature", self.signature)
        buttons = QDialogButtonBox(
            QDialogButtonBox.StandardButton.Ok | QDialogButtonBox.StandardButton.Cancel
        )
        buttons.accepted.connect(self.accept)
        buttons.rejected.connect(self.reject)
        form.addRow(buttons)
        self.resize(460, 320)

    def values(self) -> dict[str, str]:
        return {
            "case_id": self.case_id.text().strip(),
            "evidence_id": self.evidence_id.text().strip(),
            "examiner": self.examiner.text().strip(),
            "notes": self.notes.toPlainText().strip(),
        }


def signature_text(project: Project | None) -> str:
    """Who signed the saved case record, or which key will sign it (no key is made here)."""
    if project is not None and project.root is not None:
        return describe_signatures(project.signature_info())
    mine = local_fingerprint()
    return (
        f"Signed with your key {mine} when saved."
        if mine
        else "Signed when saved, with a key made for you on the first save."
    )
