"""Undo and redo of the viewer's edits through the window's Edit menu and its keys (issue 21,
item 13), driven through the real widgets (pytest-qt, offscreen) on a small synthetic map:

- two measurements added (a ruler, a marker), the last undone and redone: the list, the
  measurements CSV and the case report follow, the Edit menu names the step;
- a deleted and a cleared list come back with one undo each, an edited label goes back;
- a levelling applied then undone shows the heights it had before, on the map too;
- the stack is the opened reconstruction's: opening another one empties it.
"""

from __future__ import annotations

import numpy as np
import pytest
from gui_helpers import FakeDialogs
from PySide6.QtCore import Qt
from PySide6.QtGui import QKeySequence
from PySide6.QtTest import QTest
from PySide6.QtWidgets import QApplication
from recon_data import recon_data_from_arrays

from impress_gui.core.reconstruction.grid import GridSpec
from impress_gui.ui import pyside_fix
from impress_gui.ui.app import build_main_window, make_settings

pyside_fix.guard()
pytestmark = [pytest.mark.qt_log_ignore("propagateSizeHints"),
              pytest.mark.usefixtures("no_stray_python_threads")]


def tilted_map():
    """60 x 40 mm, 0.1 mm cells: a plane rising 0.05 mm/mm in x with a 2 mm deep hollow."""
    spec = GridSpec(0.0, 0.0, 0.1, (400, 600))
    x = spec.xs()[None, :].astype(np.float32)
    h = np.repeat(0.05 * x, spec.shape[0], axis=0)
    h[150:250, 250:350] -= 2.0
    return recon_data_from_arrays(spec, h)


@pytest.fixture
def window(qtbot, tmp_path):
    w = build_main_window(make_settings(tmp_path / "settings.ini"), with_motor=False)
    w.resize(1600, 1000)
    w.show()
    qtbot.waitExposed(w)
    w.activateWindow()  # the Edit menu's keys work in the active window
    qtbot.waitUntil(lambda: QApplication.activeWindow() is w, timeout=5000)
    v = w.viewer_tab
    v.actions.dialogs = FakeDialogs()
    w.tabs.setCurrentWidget(v)
    with qtbot.waitSignal(v.loaded, timeout=20000):
        v.set_data(tilted_map())
    qtbot.waitUntil(lambda: not v.is_busy(), timeout=20000)
    yield w
    w.shutdown()  # the project holds unsaved measurements: closed without asking
    w.close()
    w.deleteLater()


def click_map(v, x_mm: float, y_mm: float) -> None:
    QTest.mouseClick(v.map.viewport(), Qt.MouseButton.LeftButton,
                     Qt.KeyboardModifier.NoModifier, v.map.map_to_viewport(x_mm, y_mm))


def key(w, seq: QKeySequence.StandardKey) -> None:
    """The key of a standard action, pressed with the viewer's map focused."""
    combo = QKeySequence(seq)[0]
    w.viewer_tab.map.setFocus()
    QTest.keyClick(w.viewer_tab.map, combo.key(), combo.keyboardModifiers())


def table_rows(v) -> list[list[str]]:
    t = v.table.table
    return [[t.item(r, c).text() for c in range(t.columnCount())] for r in range(t.rowCount())]


def csv_rows(qtbot, v, path) -> list[str]:
    v.actions.dialogs.answer = str(path)
    with qtbot.waitSignal(v.tasks.done, timeout=10000):
        QTest.mouseClick(v.table.export_button, Qt.MouseButton.LeftButton)
    return [r for r in path.read_text().splitlines() if r and not r.startswith("#")]


def test_undo_and_redo_of_measurements_follow_the_list_the_csv_and_report(qtbot, window,
                                                                          tmp_path):
    w, v = window, window.viewer_tab
    assert not w.undo_action.isEnabled() and w.undo_action.text() == "&Undo"
    # a ruler by two clicks, added to the list by its button
    QTest.mouseClick(v.tools.mode_buttons["ruler"], Qt.MouseButton.LeftButton)
    click_map(v, 10.0, 20.0)
    with qtbot.waitSignal(v.profile_changed, timeout=10000):
        click_map(v, 50.0, 20.0)
    QTest.mouseClick(v.tools.add_ruler_button, Qt.MouseButton.LeftButton)
    assert w.undo_action.isEnabled() and w.undo_action.text() == "&Undo add ruler"
    # a marker by a click
    QTest.mouseClick(v.tools.mode_buttons["marker"], Qt.MouseButton.LeftButton)
    click_map(v, 30.0, 10.0)
    two = table_rows(v)
    assert [r[1:3] for r in two] == [["ruler", ""], ["annotation", "mark 1"]]
    assert w.undo_action.text() == "&Undo add marker 'mark 1'"
    assert len(csv_rows(qtbot, v, tmp_path / "two.csv")) == 3  # header and two rows

    key(w, QKeySequence.StandardKey.Undo)
    assert table_rows(v) == two[:1]
    assert [m["kind"] for m in v.project.measurements] == ["ruler"]
    assert w.undo_action.text() == "&Undo add ruler"
    assert w.redo_action.isEnabled() and w.redo_action.text() == "&Redo add marker 'mark 1'"
    rows = csv_rows(qtbot, v, tmp_path / "one.csv")
    assert len(rows) == 2 and "mark 1" not in "".join(rows)
    assert "mark 1" not in v.actions._report_maker()()
    # the map drops the marker's label too
    assert not any(getattr(i, "toPlainText", lambda: "")() == "2: mark 1"
                   for i in v.map.saved_items)

    key(w, QKeySequence.StandardKey.Redo)
    assert table_rows(v) == two
    rows = csv_rows(qtbot, v, tmp_path / "again.csv")
    assert len(rows) == 3 and "mark 1" in rows[2]
    assert "mark 1" in v.actions._report_maker()()
    assert not w.redo_action.isEnabled() and w.redo_action.text() == "&Redo"

    # an edited label, a deleted row, a cleared list: one undo each
    v.table.table.item(0, 2).setText("heel")
    assert v.project.measurements[0]["label"] == "heel"
    assert w.undo_action.text() == "&Undo edit label of ruler"
    w.undo_action.trigger()
    assert v.project.measurements[0]["label"] == "" and table_rows(v) == two
    v.table.table.selectRow(0)
    QTest.mouseClick(v.table.delete_button, Qt.MouseButton.LeftButton)
    assert [r[2] for r in table_rows(v)] == ["mark 1"]
    assert w.undo_action.text() == "&Undo delete ruler"
    w.undo_action.trigger()
    assert table_rows(v) == two
    QTest.mouseClick(v.table.clear_button, Qt.MouseButton.LeftButton)
    assert table_rows(v) == [] and v.project.measurements == []
    assert w.undo_action.text() == "&Undo clear 2 measurements"
    w.undo_action.trigger()
    assert table_rows(v) == two
    # every change is in the project's log, the undone ones too
    actions = [a for a, _d, _t in v.project._pending_log]
    assert "measurement removed (undo)" in actions and "measurement restored (undo)" in actions

    # the Edit menu lists both with their standard keys; another tab has no viewer undo
    menus = {a.text().replace("&", ""): a.menu() for a in w.menuBar().actions()}
    assert {a.shortcut() for a in menus["Edit"].actions()} == {
        QKeySequence(QKeySequence.StandardKey.Undo), QKeySequence(QKeySequence.StandardKey.Redo)}
    w.tabs.setCurrentWidget(w.calibration_tab)
    assert not w.undo_action.isEnabled()
    w.tabs.setCurrentWidget(v)
    assert w.undo_action.isEnabled()

    # another reconstruction opened: nothing to undo
    with qtbot.waitSignal(v.loaded, timeout=20000):
        v.set_data(tilted_map())
    qtbot.waitUntil(lambda: not v.is_busy(), timeout=20000)
    assert v.undo_stack.count() == 0 and not w.undo_action.isEnabled()


def test_undoing_a_levelling_shows_the_heights_from_before(qtbot, window):
    w, v = window, window.viewer_tab
    raw = np.array(v.measure_height())
    shown = v.map.scalar.levels[0]
    assert np.array_equal(shown, raw, equal_nan=True)
    with qtbot.waitSignal(v.levelled_changed, timeout=20000):
        v.level_region((2.0, 20.0), (2.0, 38.0))  # the plane beside the hollow
    levelled = np.array(v.measure_height())
    assert abs(float(np.nanmean(levelled[20:380, 20:200]))) < 1e-3  # the plane is 0 now
    assert np.array_equal(v.map.scalar.levels[0], levelled, equal_nan=True)
    assert "Levelled (region)" in v.tools.level_text.text()
    assert w.undo_action.text() == "&Undo level (region)"

    with qtbot.waitSignal(v.levelled_changed, timeout=5000):
        key(w, QKeySequence.StandardKey.Undo)
    assert v.plane is None and "Levelling: off" in v.tools.level_text.text()
    assert np.array_equal(v.measure_height(), raw, equal_nan=True)
    assert np.array_equal(v.map.scalar.levels[0], raw, equal_nan=True)
    v.show_readout(55.0, 5.0)
    assert "height 2.750 mm" in v.tools.readout.text()  # 0.05 mm/mm x 55 mm, not levelled

    with qtbot.waitSignal(v.levelled_changed, timeout=5000):
        key(w, QKeySequence.StandardKey.Redo)
    assert v.plane is not None and "Levelled (region)" in v.tools.level_text.text()
    assert np.array_equal(v.map.scalar.levels[0], levelled, equal_nan=True)

    # clearing the levelling is a step too
    QTest.mouseClick(v.tools.clear_level_button, Qt.MouseButton.LeftButton)
    assert v.plane is None and w.undo_action.text() == "&Undo clear levelling"
    with qtbot.waitSignal(v.levelled_changed, timeout=5000):
        w.undo_action.trigger()
    assert v.plane is not None
    assert np.array_equal(v.measure_height(), levelled, equal_nan=True)
