"""The viewer's Export > Digital cast driven through the real widgets (pytest-qt, offscreen) in
the main window: the export panel's button opens the dialog, the choices are made in its
widgets, the file is chosen, the cast is written in the background by ``write_cast`` (the
command line's code) and recorded in the project; trimesh reads it back watertight with a
positive volume. Cancelling the dialog, the file chooser or the running task writes nothing;
a bad file name gives a coded message, not a traceback."""

from __future__ import annotations

import hashlib
import json
import time

import numpy as np
import pytest
from gui_helpers import main_window, open_in_viewer
from PySide6.QtCore import QRectF, Qt
from test_cast import SPEC

from impress_gui.core.measure import cast as C
from impress_gui.ui import pyside_fix

pyside_fix.guard()
trimesh = pytest.importorskip("trimesh")
pytest.importorskip("open3d")
pytestmark = [pytest.mark.qt_log_ignore("propagateSizeHints"),
              pytest.mark.usefixtures("no_stray_python_threads")]


@pytest.fixture
def window(qtbot, tmp_path, cast_recon):
    with main_window(qtbot, tmp_path, (1100, 700)) as w:
        open_in_viewer(qtbot, w, cast_recon)
        yield w


def open_dialog(qtbot, v):
    qtbot.mouseClick(v.exports.buttons["cast"], Qt.MouseButton.LeftButton)
    dlg = v.actions.cast_dialog
    assert dlg is not None
    qtbot.waitExposed(dlg)
    return dlg


def files(folder) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def test_digital_cast_from_the_viewer(qtbot, window, tmp_path, cast_recon):
    v = window.viewer_tab
    assert v.cast_action.text() == "Digital cast (STL/PLY/OBJ)..."
    assert v.exports.buttons["cast"].isVisible()
    # zoom the map on the letter F's region (rail frame: y = -export y)
    v.map.vb.setRange(QRectF(110.0, 60.0, 30.0, 25.0), padding=0)
    qtbot.waitUntil(lambda: v.map.vb.viewRect().width() < 60, timeout=5000)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    v.actions.dialogs.answer = str(out_dir / "outsole")  # no suffix: STL
    dlg = open_dialog(qtbot, v)
    assert dlg.mode_combo.currentData() == "negative" and dlg.base_spin.value() == 5.0
    dlg.mode_combo.setCurrentIndex(1)
    dlg.base_spin.clear()
    qtbot.keyClicks(dlg.base_spin, "3.5")
    dlg.triangles_spin.clear()
    qtbot.keyClicks(dlg.triangles_spin, "30000")
    assert dlg.decimate_combo.currentData() == "adaptive" and dlg.tolerance_spin.isEnabled()
    assert dlg.tolerance_spin.value() == 0.02
    dlg.tolerance_spin.clear()
    qtbot.keyClicks(dlg.tolerance_spin, "0.05")
    dlg.region_combo.setCurrentIndex(1)  # the visible region
    r = v.map.vb.viewRect()
    assert dlg.visible_crop == pytest.approx((r.left(), -r.bottom(), r.right(), -r.top()))
    said: list[str] = []
    v.actions.status.connect(said.append)
    with qtbot.waitSignal(v.tasks.done, timeout=120000) as done:
        qtbot.mouseClick(dlg.ok_button, Qt.MouseButton.LeftButton)
    assert done.args == ["Writing the digital cast", "finished"]
    assert "Mesh (*.stl *.ply *.obj)" in v.actions.dialogs.filters[-1]
    stl = out_dir / "outsole.stl"
    assert files(out_dir) == ["outsole.stl", "outsole.stl.json"]
    mesh = trimesh.load(str(stl), force="mesh")
    mesh.merge_vertices()
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    doc = json.loads((out_dir / "outsole.stl.json").read_text())
    assert doc["parameters"]["mode"] == "positive"
    assert doc["parameters"]["base_mm"] == 3.5 and doc["parameters"]["max_triangles"] == 30000
    assert doc["parameters"]["decimate"] == "adaptive" and doc["parameters"]["tolerance_mm"] == 0.05
    assert doc["mesh"]["decimation"]["max_vertical_error_mm"] <= 0.05
    assert doc["parameters"]["crop_mm"] == pytest.approx(list(dlg.visible_crop), abs=1e-3)
    assert len(mesh.faces) == doc["mesh"]["triangles"] <= 30000
    assert mesh.volume == pytest.approx(doc["mesh"]["volume_mm3"], rel=1e-5)
    # the mesh covers the visible region only (turned over: x -> -x)
    x0, y0, x1, y1 = dlg.visible_crop
    lo, hi = mesh.bounds
    assert -x1 - SPEC.pixel_mm <= lo[0] and hi[0] <= -x0 + SPEC.pixel_mm
    assert y0 - SPEC.pixel_mm <= lo[1] and hi[1] <= y1 + SPEC.pixel_mm
    assert doc["checks"]["ok"] and doc["export"]["by"] == "the viewer's export"
    assert doc["inputs"]["reconstruction"]["heightmap_tif_sha256"] == hashlib.sha256(
        (cast_recon / "heightmap.tif").read_bytes()).hexdigest()
    # the same file the command line writes with the same parameters (the record differs by
    # the viewer's context only)
    cli = tmp_path / "cli" / "outsole.stl"
    C.write_cast(cast_recon, cli, C.CastParams(positive=True, base_mm=3.5, max_triangles=30000,
                                          crop_mm=tuple(doc["parameters"]["crop_mm"]),
                                          tolerance_mm=0.05))
    assert cli.read_bytes() == stl.read_bytes()
    # recorded in the case record: the mesh with its hash, and its record
    outs = v.project.outputs[-2:]
    assert [o["kind"] for o in outs] == ["cast-stl", "cast-record"]
    assert outs[0]["sha256"] == hashlib.sha256(stl.read_bytes()).hexdigest()
    assert outs[1]["path"].endswith("outsole.stl.json")
    assert any(t.startswith(f"Digital cast written to {stl}") and "surface within" in t
               for t in said)


def test_cancel_writes_nothing(qtbot, window, tmp_path, monkeypatch):
    v = window.viewer_tab
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    n_outputs = len(v.project.outputs)
    # 1. the dialog's Cancel: no file is asked for
    dlg = open_dialog(qtbot, v)
    qtbot.mouseClick(dlg.cancel_button, Qt.MouseButton.LeftButton)
    qtbot.waitUntil(lambda: not dlg.isVisible(), timeout=5000)
    assert v.actions.dialogs.asked == [] and not v.tasks.is_busy()
    # 2. the file chooser cancelled
    v.actions.dialogs.answer = ""
    dlg = open_dialog(qtbot, v)
    qtbot.mouseClick(dlg.ok_button, Qt.MouseButton.LeftButton)
    assert len(v.actions.dialogs.asked) == 1 and not v.tasks.is_busy()
    # 3. the task bar's Cancel while the cast is being made
    real = C.make_cast

    def slow(height, spec, params, progress=None, cancel=None):
        t0 = time.monotonic()
        while not cancel.cancelled and time.monotonic() - t0 < 60:
            time.sleep(0.01)
        return real(height, spec, params, progress, cancel)

    monkeypatch.setattr(C, "make_cast", slow)
    v.actions.dialogs.answer = str(out_dir / "cast.ply")
    dlg = open_dialog(qtbot, v)
    qtbot.mouseClick(dlg.ok_button, Qt.MouseButton.LeftButton)
    assert v.tasks.is_busy() and v.tasks.cancel_button.isVisible()
    with qtbot.waitSignal(v.tasks.done, timeout=60000) as done:
        qtbot.mouseClick(v.tasks.cancel_button, Qt.MouseButton.LeftButton)
    assert done.args == ["Writing the digital cast", "cancelled"]
    monkeypatch.setattr(C, "make_cast", real)
    assert files(out_dir) == [] and len(v.project.outputs) == n_outputs
    assert not list(tmp_path.rglob("*.stl")) and not list(tmp_path.rglob("*.ply"))


def test_a_bad_name_gives_a_coded_message(qtbot, window, tmp_path):
    v = window.viewer_tab
    n_outputs = len(v.project.outputs)
    v.actions.dialogs.answer = str(tmp_path / "cast.step")
    dlg = open_dialog(qtbot, v)
    with qtbot.waitSignal(v.tasks.done, timeout=60000) as done:
        qtbot.mouseClick(dlg.ok_button, Qt.MouseButton.LeftButton)
    assert done.args[1] == "failed"
    text = window.messenger.last_text
    assert "Cannot write the digital cast" in text and "[E-CAST-SUFFIX]" in text
    assert "Traceback" not in text and not window.messenger.last_box.detailedText()
    assert not (tmp_path / "cast.step").exists() and len(v.project.outputs) == n_outputs
    assert np.isfinite(v.data.layers["fused"]).any()  # the viewer still shows its data


def test_the_file_menu_exports_the_cast(qtbot, window):
    """File > Export > Digital cast is the viewer's own action (it opens the same dialog)."""
    file_menu = next(a.menu() for a in window.menuBar().actions() if a.text() == "&File")
    export = next(a.menu() for a in file_menu.actions() if a.text() == "&Export")
    assert window.viewer_tab.cast_action in export.actions()
    export.actions()[0].trigger()
    dlg = window.viewer_tab.actions.cast_dialog
    assert dlg is not None
    qtbot.waitExposed(dlg)
    dlg.reject()


def test_the_tolerance_follows_the_method(qtbot, window):
    """The tolerance applies to the adaptive surface only: disabled for the other methods."""
    dlg = open_dialog(qtbot, window.viewer_tab)
    keys = [dlg.decimate_combo.itemData(i) for i in range(dlg.decimate_combo.count())]
    assert keys == ["adaptive", "sample", "quadric"]
    dlg.decimate_combo.setCurrentIndex(1)
    assert not dlg.tolerance_spin.isEnabled() and dlg.params().decimate == "sample"
    dlg.decimate_combo.setCurrentIndex(0)
    assert dlg.tolerance_spin.isEnabled() and dlg.params().tolerance_mm == 0.02
    dlg.reject()
