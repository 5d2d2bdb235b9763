"""The cursor's height readout states its expanded uncertainty U (k = 2) like every other
reading (issues 21, 22), read off the real widget while the mouse hovers over the map
(pytest-qt, offscreen, the main window): "height h mm ± U mm (U, k=2)", the cells' SD shown as
their spread (not as a "±"), the budget in the tooltip; U is the one a marker placed there
records, and it grows when fewer cells are averaged on a noisy surface."""

from __future__ import annotations

import math
import re

import pytest
from PySide6.QtTest import QTest
from test_gui_21_side_panel import NOISE_MM, SPEC, STEP_MM, window  # noqa: F401  (the fixture)

from impress_gui.core.measure import readings as M

pytestmark = [pytest.mark.qt_log_ignore("propagateSizeHints"),
              pytest.mark.usefixtures("no_stray_python_threads")]

READOUT = re.compile(r"x (-?[\d.]+) mm, y (-?[\d.]+) mm: height (-?[\d.]+) mm ± ([\d.]+) mm "
                     r"\(U, k=[\d.]+\) \(spread SD ([\d.]+) mm, (\d+) of (\d+) cells\)")


def hover(qtbot, v, x_mm: float, y_mm: float) -> re.Match:
    """Move the mouse over the map at ``(x_mm, y_mm)``; the readout's numbers."""
    QTest.mouseMove(v.map.viewport(), v.map.map_to_viewport(x_mm, y_mm))
    qtbot.waitUntil(lambda: READOUT.match(v.tools.readout.text()) is not None, timeout=5000)
    return READOUT.match(v.tools.readout.text())


def test_the_cursor_readout_shows_U_k2_and_the_spread_apart(qtbot, window):  # noqa: F811
    v = window.viewer_tab
    yc = SPEC.y0_mm + SPEC.shape[0] * SPEC.pixel_mm / 2
    x_hi = SPEC.x0_mm + 0.75 * SPEC.shape[1] * SPEC.pixel_mm  # on the step's top, 2 mm up
    v.tools.radius.setValue(2.0)
    got = hover(qtbot, v, x_hi, yc)
    x, y, h, u, sd = (float(g) for g in got.groups()[:5])
    n_valid, n_cells = int(got.group(6)), int(got.group(7))
    core = M.readout(v.data.height_mm, v.data.spec, x, y, 2.0)
    assert h == pytest.approx(core.height_mm, abs=0.002) and h == pytest.approx(STEP_MM, abs=0.05)
    assert sd == pytest.approx(core.sd_mm, abs=0.002) and n_valid == core.n_valid == n_cells
    # the spread is the surface's (the map's noise), not the reading's uncertainty
    assert sd == pytest.approx(NOISE_MM, rel=0.2)
    assert "SD" not in v.tools.readout.text().split("(U, k=")[0]
    # U is the budget's, which is in the tooltip, and the same a marker there records
    tip = v.tools.readout.toolTip()
    assert "surface noise" in tip and re.search(r"U = [\d.]+ u_c", tip)
    mark = v.add_marker(x, y)
    assert mark["values"]["U_k2_mm"] == pytest.approx(u, abs=0.0006)
    # the mean of n cells of the noise: U about 2 SD / sqrt(n) (no calibration here)
    assert u == pytest.approx(2 * NOISE_MM / math.sqrt(n_valid), rel=0.5)
    # fewer cells averaged on the noisy surface: a larger U (the standard error grows)
    v.tools.radius.setValue(0.6)
    v.map.hovered.emit(x, y)
    got = READOUT.match(v.tools.readout.text())
    assert got and int(got.group(6)) < n_valid / 4
    assert float(got.group(4)) > 1.5 * u
    # off the map the readout says so, without a budget
    v.map.hovered.emit(SPEC.x0_mm - 50.0, yc)
    assert "outside the map" in v.tools.readout.text() and v.tools.readout.toolTip() == ""
