"""The viewer's edits as undoable commands on a :class:`QUndoStack` (one per opened
reconstruction, cleared when another is opened): measurements and annotations added, edited,
deleted or cleared in the project's list, and the levelling plane applied or cleared.

Each command holds what it needs to go both ways (the measurement records, the levelling state
before and after) and asks its owner to do the change; the owner logs every change in the
project, undo and redo included. A levelling is computed in the background, so its command is
pushed once the plane is applied (its first ``redo`` does nothing)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from PySide6.QtGui import QUndoCommand

if TYPE_CHECKING:  # pragma: no cover - typing only
    from impress_gui.ui.viewer.measurements import Levelling, MeasurementList

KIND_NAMES = {"ruler": "ruler", "annotation": "marker", "point": "point", "plane": "plane"}


def describe(m: dict) -> str:
    """A measurement as named in the Edit menu: its kind and label (``ruler 'slot'``)."""
    name = KIND_NAMES.get(str(m.get("kind", "")), str(m.get("kind", "measurement")))
    label = str(m.get("label") or "")
    return f"{name} '{label}'" if label else name


class AddMeasurement(QUndoCommand):
    """A measurement added at ``row`` of the list."""

    def __init__(self, owner: MeasurementList, row: int, m: dict) -> None:
        super().__init__(f"add {describe(m)}")
        self.owner, self.row, self.m = owner, row, dict(m)

    def redo(self) -> None:
        self.owner.insert_record(self.row, self.m, "measurement added")

    def undo(self) -> None:
        self.owner.remove_record(self.row, self.m, "measurement removed (undo)")


class RemoveMeasurement(QUndoCommand):
    """The measurement at ``row`` deleted."""

    def __init__(self, owner: MeasurementList, row: int, m: dict) -> None:
        super().__init__(f"delete {describe(m)}")
        self.owner, self.row, self.m = owner, row, dict(m)

    def redo(self) -> None:
        self.owner.remove_record(self.row, self.m, "measurement deleted")

    def undo(self) -> None:
        self.owner.insert_record(self.row, self.m, "measurement restored (undo)")


class ClearMeasurements(QUndoCommand):
    """Every measurement of the list deleted."""

    def __init__(self, owner: MeasurementList, ms: list[dict]) -> None:
        super().__init__(f"clear {len(ms)} measurement{'s' if len(ms) != 1 else ''}")
        self.owner, self.ms = owner, [dict(m) for m in ms]

    def redo(self) -> None:
        for row in reversed(range(len(self.ms))):
            self.owner.remove_record(row, self.ms[row], "measurement deleted (clear all)",
                                     refresh=row == 0)

    def undo(self) -> None:
        for row, m in enumerate(self.ms):
            self.owner.insert_record(row, m, "measurement restored (undo)",
                                     refresh=row == len(self.ms) - 1)


class EditMeasurement(QUndoCommand):
    """The measurement at ``row`` changed from ``before`` to ``after`` (its label, note, or
    its ruler, values and parameters)."""

    def __init__(self, owner: MeasurementList, row: int, before: dict, after: dict,
                 what: str) -> None:
        super().__init__(f"{what} of {describe(before)}")
        self.owner, self.row = owner, row
        self.before, self.after = dict(before), dict(after)

    def redo(self) -> None:
        self.owner.replace_record(self.row, self.before, self.after, "measurement edited")

    def undo(self) -> None:
        self.owner.replace_record(self.row, self.after, self.before,
                                  "measurement edited (undo)")


class LevellingChange(QUndoCommand):
    """The levelling changed from state ``before`` to ``after`` (see
    :meth:`~impress_gui.ui.viewer.measurements.Levelling.state`); made after the change was
    applied, so the first ``redo`` does nothing."""

    def __init__(self, owner: Levelling, before, after, text: str) -> None:
        super().__init__(text)
        self.owner, self.before, self.after = owner, before, after
        self._applied = True

    def redo(self) -> None:
        if self._applied:
            self._applied = False
            return
        self.owner.restore(self.after, "redo")

    def undo(self) -> None:
        self.owner.restore(self.before, "undo")
