"""Make the screenshots of docs/measuring-guide.md (processing and viewer tabs in use).

Runs the real window on the simulated `blocks` scan (640x360, 200 mm at 39.414 mm/s):
processing preview, a run in progress, the viewer with a ruler across the widest slot and its
profile, the heightmap and the texture side by side, hillshade with levelling, the 3D view
(axes and scale bar) and an exported figure. Use a virtual X server
so that the pictures are those of a real display:

    xvfb-run -s "-screen 0 1920x1080x24" .venv/bin/python docs/measuring_screenshots.py [--scan DIR]

``--scan`` is a folder with scan.mp4, cal.json and truth.json (else one is simulated, ~1 min).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
IMAGES = ROOT / "docs" / "images"
SPEED = "39.414"


def simulate(folder: Path) -> Path:
    run = [sys.executable, "-m", "impress_gui"]
    subprocess.run(
        [
            *run,
            "simulate",
            str(folder),
            "--preset",
            "blocks",
            "--length-mm",
            "200",
            "--speed",
            SPEED,
            "--resolution",
            "640x360",
            "--workers",
            "2",
        ],
        check=True,
    )
    subprocess.run(
        [
            *run,
            "calibrate",
            str(folder / "scan.mp4"),
            "--intrinsics",
            str(folder / "intrinsics.json"),
            "--picks",
            str(folder / "picks.json"),
            "--speed",
            SPEED,
            "-o",
            str(folder / "cal.json"),
        ],
        check=True,
    )
    return folder


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scan", type=Path)
    args = ap.parse_args()
    from PySide6.QtCore import QEventLoop, QRectF, QTimer

    from impress_gui.core.calibration.scene import SceneCalibration
    from impress_gui.core.project.project import Project
    from impress_gui.ui.app import build_main_window, create_app, grab, make_settings

    app = create_app()
    tmp = Path(tempfile.mkdtemp(prefix="impress-shots-"))
    scan = args.scan or simulate(tmp / "scan")
    truth = json.loads((scan / "truth.json").read_text())
    y_slot = 190.0 - truth["travel_mm"][truth["calibration_frames"]["t1"]]
    slot = next(f for f in truth["features"] if f["kind"] == "slot")
    left = slot["centre_a_mm"] - slot["width_mm"] / 2
    right = left + slot["width_mm"]
    start = next(k for k, s in enumerate(truth["travel_mm"]) if s >= 128.0)

    def wait(signal=None, ms: int = 120_000) -> None:
        loop = QEventLoop()
        if signal is not None:
            signal.connect(loop.quit)
        QTimer.singleShot(ms, loop.quit)
        loop.exec()
        if signal is not None:
            signal.disconnect(loop.quit)

    def shot(widget, name: str) -> None:
        wait(ms=400)
        grab(widget).save(str(IMAGES / name))
        print(f"wrote docs/images/{name}")

    win = build_main_window(make_settings(tmp / "settings.ini"), with_motor=False)
    win.resize(1920, 1080)
    win.move(0, 0)
    win.show()
    project = Project(
        case_id="2024-0117",
        evidence_id="E3 (cast area 2)",
        examiner="A. Analyst",
        notes="Accuracy blocks, simulated scan",
    )
    project.set_video(scan / "scan.mp4")
    project.set_calibration(SceneCalibration.load(scan / "cal.json"))
    project.save(tmp / "case")
    proc, viewer = win.extra_tabs["Processing"], win.extra_tabs["Viewer"]
    win.set_project(project)
    wait(proc.preview_ready, 30000)
    win.tabs.setCurrentWidget(proc)
    proc.params.frame_start.setValue(start)
    proc.params.frame_stop.setValue(len(truth["travel_mm"]))
    proc.lut_button.setChecked(True)
    proc.go_to_frame(start + 20)
    wait(proc.preview_ready, 30000)
    shot(win, "processing-preview.png")

    proc.run()
    while proc.run_panel.bar.value() < 450 and proc.is_running():
        wait(proc.worker.progress, 5000)
    shot(win, "processing-running.png")
    wait(viewer.loaded, 120000)
    v = viewer
    v.map.vb.setRange(QRectF(-70, y_slot - 38, 110, 76), padding=0)
    v.tools.width.setValue(10.0)
    v.tools.radius.setValue(1.0)
    v.set_mode("ruler")
    v.set_ruler((left - 5.0, y_slot), (right + 5.0, y_slot))
    wait(v.profile_changed, 10000)
    v.set_bands((1.0, 4.5), (5.6, 5.0 + slot["width_mm"] - 0.6))
    wait(ms=300)
    v.add_ruler_measurement("slot 1: width and depth")
    v.add_marker(28.5, y_slot + 10.0, "block top")
    v.add_marker(-55.0, y_slot - 35.0, "plate")
    v.show_readout(28.5, y_slot + 10.0)
    shot(win, "viewer-ruler-profile.png")

    # the heightmap and the texture side by side, the cursor's crosshair in both
    v.set_side_by_side(True)
    wait(ms=2500)
    v._on_hovered(28.5, y_slot + 10.0)
    shot(win, "viewer-side-by-side.png")
    v.set_side_by_side(False)

    v.display.set_layer("hillshade")
    wait(v.layer_shown, 20000)
    v.level_region((-75.0, 75.0), (y_slot - 55.0, y_slot - 25.0))
    wait(v.levelled_changed, 20000)
    wait(v.layer_shown, 20000)
    v.display.blend.setValue(35)
    v.map.vb.setRange(QRectF(-90, y_slot - 70, 180, 140), padding=0)
    v.show_readout(28.5, y_slot + 10.0)
    shot(win, "viewer-hillshade-levelled.png")

    v.display.set_layer("fused")
    wait(v.layer_shown, 20000)
    fig = v.actions.figure_maker()(max_px=1400)
    from impress_gui.core.base.fileio import atomic_write_bytes
    from impress_gui.core.formats.images import png_bytes

    atomic_write_bytes(IMAGES / "viewer-figure.png", png_bytes(fig))
    print("wrote docs/images/viewer-figure.png")
    w3 = v.actions.open_3d()
    w3.resize(900, 650)
    w3.move(100, 100)
    w3.azimuth, w3.elevation = 200.0, 35.0
    w3.exaggeration.setValue(2.0)
    wait(w3.rendered, 20000)
    shot(w3, "viewer-3d.png")
    w3.close()

    # the Compare tab: the simulator's true shoe relief against a copy turned by -12 deg,
    # shifted and given a cut 0.5 mm deep and 3 mm long, both as X3P files
    from impress_gui.core.formats.writers import x3p_bytes
    from impress_gui.sim.scenes import ShoeCut, shoe_relief

    pose = {"rotate_deg": -12.0, "shift_x_mm": -6.0, "shift_y_mm": 5.0}
    for name, scene in (("shoe-a", shoe_relief(0.2, 1)),
                        ("shoe-b", shoe_relief(0.2, 1, pose, ShoeCut()))):
        (tmp / f"{name}.x3p").write_bytes(
            x3p_bytes(scene, scene.height_mm, "2026-01-01T00:00:00Z"))
    c = win.compare_tab
    win.tabs.setCurrentWidget(c)
    c.a_edit.setText(str(tmp / "shoe-a.x3p"))
    c.b_edit.setText(str(tmp / "shoe-b.x3p"))
    c.threshold_spin.setValue(0.25)
    c.compare_button.click()
    wait(c.compared, 180000)
    wait(ms=1500)
    # zoomed on the one outlined region (the cut), with a profile drawn across it
    cut = c.comparison.regions[0]
    col, row = c.mm_to_view(*cut.centroid_mm)
    c.view_box.setRange(QRectF(col - 60, row - 40, 120, 80), padding=0)
    import math

    x, y = cut.centroid_mm
    across = math.radians(cut.axis_deg + 90.0)
    dx, dy = 4.0 * math.cos(across), 4.0 * math.sin(across)
    c.set_profile((x - dx, y - dy), (x + dx, y + dy))
    wait(ms=1500)
    shot(win, "compare-difference.png")
    c.view_box.autoRange()
    c.view_combo.setCurrentText("A | B side by side")
    wait(ms=1500)
    shot(win, "compare-side-by-side.png")
    win.shutdown()
    win.close()
    app.processEvents()
    shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
