"""The viewer's tools have keys, listed in the window's Measure menu (issue 21, item 13)."""

from __future__ import annotations

import pytest
from PySide6.QtCore import Qt
from PySide6.QtTest import QTest
from PySide6.QtWidgets import QLineEdit

from impress_gui.ui import pyside_fix
from impress_gui.ui.app import build_main_window, make_settings

pyside_fix.guard()
pytestmark = pytest.mark.qt_log_ignore("propagateSizeHints")  # the offscreen platform


@pytest.fixture
def window(qtbot, tmp_path):
    w = build_main_window(make_settings(tmp_path / "settings.ini"), with_motor=False)
    qtbot.addWidget(w)
    w.show()
    qtbot.waitExposed(w)
    yield w
    w.shutdown()


def test_tool_keys_choose_the_viewer_tool_and_are_listed_in_the_menu(qtbot, window):
    menus = {a.text().replace("&", ""): a.menu() for a in window.menuBar().actions()}
    listed = {a.text().replace("&", ""): a.shortcut().toString()
              for a in menus["Measure"].actions() if not a.isSeparator()}
    assert listed == {"Pan": "P", "Ruler": "R", "Marker": "M", "Level: 3 points": "L",
                      "Level: region": "G", "Zoom to fit": "F"}
    viewer = window.viewer_tab
    window.tabs.setCurrentWidget(window.calibration_tab)
    for key, mode in ((Qt.Key.Key_R, "ruler"), (Qt.Key.Key_M, "marker"),
                      (Qt.Key.Key_L, "level3"), (Qt.Key.Key_G, "region"), (Qt.Key.Key_P, "pan")):
        QTest.keyClick(window.tabs.currentWidget(), key)
        qtbot.waitUntil(lambda mode=mode: viewer.mode == mode, timeout=2000)
        assert window.tabs.currentWidget() is viewer
        # the tool's button in the viewer shows it too
        assert viewer.tools.hint.text()


def test_a_text_field_keeps_its_letters(qtbot, window):
    edit = QLineEdit(window.calibration_tab)
    edit.show()
    edit.setFocus()
    qtbot.waitUntil(edit.hasFocus, timeout=2000)
    window.tabs.setCurrentWidget(window.calibration_tab)
    edit.setFocus()
    QTest.keyClicks(edit, "rml")
    assert edit.text() == "rml"
    assert window.tabs.currentWidget() is window.calibration_tab and window.viewer_tab.mode == "pan"
