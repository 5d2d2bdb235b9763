"""The viewer shows every reading with its expanded uncertainty (issue 22), read off the real
widgets (pytest-qt, offscreen) on the flat 640x360 scan reconstructed with its calibration: the
ruler's readings and the step with "± U", the budget (with the calibration's Monte Carlo) in
their tooltips, the measurement list's value with "± U" and its budget one click away, and the
exported CSV's columns."""

from __future__ import annotations

import csv
import io
import json
import re

import pytest
from gui_helpers import FakeDialogs
from measure_scans import guard_pyside_none
from PySide6.QtCore import Qt
from PySide6.QtTest import QTest

from impress_gui.core.calibration.scene import SceneCalibration
from impress_gui.core.calibration.target import TargetModel
from impress_gui.core.measure import uncertainty as U
from impress_gui.core.project.project import Project
from impress_gui.ui import pyside_fix
from impress_gui.ui.messages import Messenger
from impress_gui.ui.viewer.tab import ViewerTab

pyside_fix.guard()
guard_pyside_none()
pytestmark = [pytest.mark.qt_log_ignore("propagateSizeHints"),
              pytest.mark.usefixtures("no_stray_python_threads")]


def _viewer(qtbot, flat_scan, flat_calibration, case_id, dialogs=None):
    """A shown viewer tab with the flat scan's calibration and target in its project."""
    project = Project(case_id=case_id)
    project.set_calibration(SceneCalibration.load(flat_calibration))
    project.set_target(TargetModel.load(flat_scan / "target.json"))
    v = ViewerTab(Messenger(None), dialogs or FakeDialogs())
    qtbot.addWidget(v)
    v.resize(1400, 900)
    v.show()
    qtbot.waitExposed(v)
    return v, project


def _ruler_across_the_middle(qtbot, v, half_mm=12.0):
    spec = v.data.spec
    xc = spec.x0_mm + spec.shape[1] * spec.pixel_mm / 2
    yc = spec.y0_mm + spec.shape[0] * spec.pixel_mm / 2
    with qtbot.waitSignal(v.profile_changed, timeout=20000):
        v.set_ruler((xc - half_mm, yc), (xc + half_mm, yc))
    return xc, yc


def test_readings_show_their_uncertainty_and_budget(qtbot, flat_scan, flat_calibration,
                                                    flat_recon, tmp_path):
    v, project = _viewer(qtbot, flat_scan, flat_calibration, "U-1")
    try:
        v.measurements.uncertainty.trials = 8  # a quick Monte Carlo for the test
        v.set_project(project)
        with qtbot.waitSignal(v.loaded, timeout=60000):
            v.open_reconstruction(flat_recon)
        spec = v.data.spec
        xc = spec.x0_mm + spec.shape[1] * spec.pixel_mm / 2
        yc = spec.y0_mm + spec.shape[0] * spec.pixel_mm / 2
        v.tools.radius.setValue(0.5)
        v.tools.width.setValue(1.0)
        with qtbot.waitSignal(v.profile_changed, timeout=20000):
            v.set_ruler((xc - 12.0, yc), (xc + 12.0, yc))
        # the Monte Carlo runs in the background, then the readings are shown again with it
        qtbot.waitUntil(lambda: "calibration |" in v.tools.ruler_text.toolTip(), timeout=180000)
        # what the Monte Carlo says of the calibration, in the status line
        assert v.measurements.uncertainty.summary_text.startswith("Calibration uncertainty (8 ")
        assert "tilt ±" in v.measurements.uncertainty.summary_text
        text = v.tools.ruler_text.text()
        budgets = v.ruler.budgets()
        r = v.ruler_result()
        assert f"xy {r.xy_mm:.3f} mm (± {budgets['xy'].U_mm:.3f})" in text
        ks = U.k_text([budgets[k] for k in ("xy", "3d", "dz") if k in budgets])
        assert f"(± {budgets['dz'].U_mm:.3f})" in text and f"[± U, {ks}]" in text
        u_xy = float(re.search(r"xy [\d.]+ mm \(± ([\d.]+)\)", text).group(1))
        assert 0 < u_xy < 2.0
        tip = v.tools.ruler_text.toolTip()
        for name in ("calibration", "rail speed", "grid resolution", "surface noise"):
            assert name in tip
        # the step between two bands, with its U
        with qtbot.waitSignal(v.profile_changed, timeout=20000):
            v.set_bands((2.0, 6.0), (16.0, 20.0))
        st = v.tools.step_text.text()
        m = re.search(r"Step uncertainty U \(k=([\d.]+)\): ± ([\d.]+) mm", st)
        assert m and float(m.group(2)) == pytest.approx(v.ruler.step_budget.U_mm, abs=1e-3)
        assert float(m.group(1)) == v.ruler.step_budget.k
        assert "calibration" in v.tools.step_text.toolTip()
        assert f"k={v.ruler.step_budget.k:g}" in v.profile_plot.plotItem.titleLabel.text
        # the exported profile figure (and the report's) states U, not the bands' SD, as the
        # step's and the ruler's uncertainty
        lines, _ = v.actions.profile_lines()
        step_line = next(x for x in lines if x.startswith("Band A"))
        assert (f"± {v.ruler.step_budget.U_mm:.3f} mm (U, k = {v.ruler.step_budget.k:g})"
                in step_line)
        ruler_line = next(x for x in lines if x.startswith("Ruler xy"))
        assert f"{budgets['xy'].U_mm:.3f} mm" in ruler_line
        # the measurement list: value with ± U, the budget in the tooltip and one click away
        rec = v.add_ruler_measurement("across")
        assert rec["values"]["U_k2_xy_mm"] == pytest.approx(budgets["xy"].U_mm, abs=1e-4)
        cell = v.table.table.item(0, 3)
        assert f"(± {rec['values']['U_k2_xy_mm']:.3f})" in cell.text()
        assert "U " in cell.text() and "calibration" in cell.toolTip()
        v.table.table.selectRow(0)
        QTest.mouseClick(v.table.details_button, Qt.MouseButton.LeftButton)
        dlg = v.table.details_dialog
        assert dlg is not None and dlg.isVisible()
        body = dlg.text.toPlainText()
        assert "ruler xy" in body and "step height B - A" in body and "U = 2 u_c" in body
        dlg.close()
        # a marker: its height with U
        mk = v.add_marker(xc, yc + 5.0)
        assert mk["values"]["U_k2_mm"] > 0 and "(± " in v.table.table.item(1, 3).text()
        # no validation record chosen: the method's own component is the product's figure,
        # the stripe error times the height per pixel of the laser(s) there
        comps = {c["name"]: c for c in mk["uncertainty"][""]["components"]}
        assert "method (product)" in comps and comps["method (product)"]["u_mm"] > 0
        assert "method (product)" in v.tools.step_text.toolTip()
        assert "method (product)" in v.tools.ruler_text.toolTip()  # dz and 3D list it
        # the surface noise weighs the two lasers' disagreement at the marker's scale (the
        # viewer gives the budget both lasers' maps)
        assert "disagreement" in comps["surface noise"]["note"]
        # the CSV carries u_c, U and the budget
        path = tmp_path / "m.csv"
        with qtbot.waitSignal(v.tasks.done, timeout=60000,
                              check_params_cb=lambda _w, outcome: outcome == "finished"):
            assert v.actions.export_measurements_csv(path)
        rows = list(csv.DictReader(io.StringIO("\n".join(
            line for line in path.read_text().splitlines() if not line.startswith("#")))))
        assert float(rows[0]["U_k2_xy_mm"]) == pytest.approx(rec["values"]["U_k2_xy_mm"],
                                                             abs=1e-4)
        assert float(rows[0]["u_c_step_mm"]) > 0 and float(rows[1]["U_k2_mm"]) > 0
        doc = json.loads(rows[0]["uncertainty_budget"])
        assert "calibration" in {c["name"] for c in doc["xy"]["components"]}
        assert rows[0]["heightmap_sha256"]  # still the last column
    finally:
        v.shutdown()
        v.messenger.close_all()


def test_a_validation_record_enters_every_budget(qtbot, flat_recon, tmp_path):
    """Component 6 through the real widgets: "Method validation..." in the measurement panel
    takes an impress validate record (chosen in the file dialog); the ruler's budgets then
    carry "method (validation)" with u = sqrt(bias^2 + SD^2) of the record's height errors and
    a larger U; a file that is not a record is refused with its code and changes nothing."""
    import math

    import numpy as np

    errors = [0.012, -0.004, 0.020, 0.007, 0.015]  # the record's height readings' errors
    record = tmp_path / "validation.json"
    record.write_text(json.dumps({
        "format": "impress.validation", "version": 1, "kind": "real",
        "date_utc": "2026-11-28T10:00:00Z",
        "readings": [{"axis": "z", "error_mm": e} for e in errors]
        + [{"axis": "xy", "error_mm": 0.3}]}))
    expected_u = math.hypot(np.mean(errors), np.std(errors, ddof=1))
    dialogs = FakeDialogs()
    v = ViewerTab(Messenger(None), dialogs)
    qtbot.addWidget(v)
    v.resize(1400, 900)
    v.show()
    qtbot.waitExposed(v)
    try:
        v.set_project(Project(case_id="U-6"))
        with qtbot.waitSignal(v.loaded, timeout=60000):
            v.open_reconstruction(flat_recon)
        xc, yc = _ruler_across_the_middle(qtbot, v)
        before = v.ruler.budgets()["dz"]
        assert "method (validation)" not in v.tools.ruler_text.toolTip()
        # no calibration in this project: no product figure either (its sensitivity is the
        # calibration's), and the budget says the method is not included
        assert not any(c.name.startswith("method") for c in before.components)
        assert any("not included" in n for n in before.notes)
        # not a record: refused, with its code, nothing changes
        wrong = tmp_path / "picks.json"
        wrong.write_text(json.dumps({"format": "impress.picks", "version": 1}))
        dialogs.answer = str(wrong)
        QTest.mouseClick(v.table.method_button, Qt.MouseButton.LeftButton)
        assert v.session.method_validation is None
        assert "E-WRONG-FORMAT" in v.messenger.last_text
        # the record
        dialogs.answer = str(record)
        QTest.mouseClick(v.table.method_button, Qt.MouseButton.LeftButton)
        assert v.session.method_validation["z"]["n"] == len(errors)
        assert "method (validation)" in v.tools.ruler_text.toolTip()
        after = v.ruler.budgets()["dz"]
        comp = next(c for c in after.components if c.name == "method (validation)")
        assert comp.u_mm == pytest.approx(expected_u * comp.sensitivity, rel=1e-6)
        without = math.sqrt(sum(c.u_mm ** 2 for c in before.components
                                if not c.name.startswith("method")))
        assert after.u_c_mm == pytest.approx(math.hypot(without, comp.u_mm), rel=1e-6)
        assert "validation.json" in v.table.method_button.toolTip()
        # a marker made now carries it in its stored budget
        mk = v.add_marker(xc, yc + 5.0)
        names = {c["name"] for c in mk["uncertainty"][""]["components"]}
        assert "method (validation)" in names
    finally:
        v.shutdown()
        v.messenger.close_all()


def test_an_unstable_calibration_is_called_poor_and_readings_carry_no_u(
        qtbot, flat_scan, flat_calibration, flat_recon, monkeypatch):
    """A calibration whose Monte Carlo fails in most trials: the status line calls it POOR
    before anyone measures, and the readings are shown without a U (their budgets say why),
    not with a U that lacks the calibration's component."""
    from impress_gui.core.calibration import uncertainty as CU

    def refuse(*_a, **_k):
        raise CU.UnstableCalibration("the calibration's Monte Carlo failed in most trials "
                                     "(7 of 8 re-solved calibrations refused)")

    monkeypatch.setattr(CU, "calibration_ensemble", refuse)
    v, project = _viewer(qtbot, flat_scan, flat_calibration, "U-2")
    try:
        statuses = []
        v.status.connect(statuses.append)
        v.set_project(project)
        with qtbot.waitSignal(v.loaded, timeout=60000):
            v.open_reconstruction(flat_recon)
        xc, yc = _ruler_across_the_middle(qtbot, v)
        qtbot.waitUntil(lambda: "POOR" in v.measurements.uncertainty.summary_text,
                        timeout=60000)
        assert "7 of 8" in v.measurements.uncertainty.summary_text
        qtbot.waitUntil(lambda: any("POOR" in s for s in statuses), timeout=10000)
        qtbot.waitUntil(lambda: "no uncertainty stated" in v.tools.ruler_text.toolTip(),
                        timeout=20000)
        text = v.tools.ruler_text.text()
        assert "xy " in text and "(± -)" in text and "[no U: the calibration is unstable" \
            in text and "± U" not in text and "nan" not in text
        assert "nan" not in v.tools.ruler_text.toolTip()
        # the exported profile figure's lines say so too, not "(± U, k = 2)"
        lines, _ = v.actions.profile_lines()
        ruler_line = next(x for x in lines if x.startswith("Ruler xy"))
        assert "no U stated" in ruler_line and "± U" not in ruler_line
        mk = v.add_marker(xc, yc + 5.0)
        cell = v.table.table.item(0, 3).text()
        assert "(± -)" in cell and "[no U: the calibration is unstable" in cell
        assert "[U: k=" not in cell and "nan" not in cell
        assert "unstable" in mk["uncertainty"][""]["incomplete"]
    finally:
        v.shutdown()
        v.messenger.close_all()
