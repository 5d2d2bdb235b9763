"""The calibration's result fits a 1920x1080 screen without scrolling (issue 21, item 9): in
the window at that size, the result (warnings, the summary line, and with Details open every
value and the corners' residuals) is shown whole, not clipped by a scroll area, and the frame
keeps most of the height."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from gui_helpers import main_window
from PySide6.QtCore import QPoint, Qt
from PySide6.QtTest import QTest

from impress_gui.ui import pyside_fix

pyside_fix.guard()
pytestmark = pytest.mark.qt_log_ignore("propagateSizeHints")


def fake_calibration():
    """What the results panel reads of a SceneCalibration, with three long warnings."""
    plane = SimpleNamespace(rms_mm=0.041, n_points=18234, frames=list(range(40)),
                            heights_mm=[0.0, 10.0, 20.0, 30.0, 40.0])
    return SimpleNamespace(
        roll_deg=0.412, tilt_deg=-31.207, cross_tilt_deg=2.541, vanishing_point_px=np.array([912.3, -4410.2, 1.0]),
        reprojection_rms_px=0.388, speed_mm_s=2.0, implied_speed_mm_s=2.0093,
        planes={"green": plane, "red": SimpleNamespace(**{**vars(plane), "rms_mm": 0.262})},
        corner_residuals_mm=[0.05, 0.12, 0.61, 0.08, 0.02, 0.1],
        warnings=["the rail speed implied by the target differs from the entered one by more "
                  "than 0.4 %: check the speed", "the red laser plane fits worse than 0.2 mm",
                  "corner C is 0.61 mm from the target model: check its pick"],
    )


def shown_whole(widget, window) -> bool:
    """``widget`` visible, not clipped, inside the window, as tall as it asks to be."""
    if not widget.isVisible():
        return False
    clip = widget.visibleRegion().boundingRect()
    top = widget.mapTo(window, QPoint(0, 0))
    return (clip.size() == widget.size() and top.y() >= 0
            and top.y() + widget.height() <= window.height()
            and widget.height() >= needed_height(widget))


def needed_height(widget) -> int:
    """The height ``widget`` asks for at its width (wrapped text is taller when narrower)."""
    if widget.hasHeightForWidth():
        return widget.heightForWidth(widget.width())
    return widget.sizeHint().height()


def test_the_calibration_result_fits_1080_lines_without_scrolling(qtbot, tmp_path):
    with main_window(qtbot, tmp_path, (1920, 1080)) as w:
        tab = w.calibration_tab
        w.tabs.setCurrentWidget(tab)
        res = tab.results
        cal = fake_calibration()
        res.show_calibration(cal)
        qtbot.waitUntil(lambda: shown_whole(res, w), timeout=5000)
        assert "Roll +0.412°" in res.summary_label.text()
        assert f"motion axis {cal.cross_tilt_deg:+.3f}° (levelled)" in res.summary_label.text()
        assert "worst corner 0.610 mm" in res.summary_label.text()
        assert shown_whole(res.warnings_label, w)
        assert not res.details.isVisible()
        # every value and the residuals, with Details open
        QTest.mouseClick(res.details_button, Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: res.details.isVisible() and shown_whole(res, w), timeout=5000)
        for lab in res.values.values():
            assert shown_whole(lab, w) and lab.text() != "-"
        t = res.table  # every residual in the table's visible part
        assert t.visibleRegion().boundingRect().size() == t.size()
        for c in range(t.columnCount()):
            assert t.viewport().rect().contains(t.visualItemRect(t.item(0, c)))
        assert res.table.item(0, 2).text() == "0.610"
        assert tab.view.height() > 400  # the frame keeps most of the height
        QTest.mouseClick(res.details_button, Qt.MouseButton.LeftButton)
        assert not res.details.isVisible()
