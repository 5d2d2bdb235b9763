"""Screenshots of the motor panel for docs/technician-guide.md, taken under a real X server.

    xvfb-run -s "-screen 0 1920x1080x24" .venv/bin/python scripts/docs_screenshots.py [PROJECT]
    xvfb-run -s "-screen 0 1920x1080x24" .venv/bin/python scripts/docs_screenshots.py \
        --calibration SCAN

With ``--calibration``, the calibration tab's pictures for docs/calibration-guide.md instead
(docs/images/calibration-marking.png, -result.png, -warning.png) from SCAN, a folder written by
``impress simulate SCAN --preset shoe --length-mm 220 --resolution 960x540``: its video is
opened in a new project, corners are clicked a pixel or two off the simulator's true corners
with snapping on, and the scan is calibrated with the right and with a 3 % wrong speed.

Writes docs/images/motor-panel-scan.png (the panel connected to the simulated motor during a
short scan) and docs/images/technician-window.png (the whole window at 1920x1080 with that
panel docked; with PROJECT, that project opened in it). Under QT_QPA_PLATFORM=offscreen it works
too, with Qt's offscreen fonts.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
IMAGES = ROOT / "docs" / "images"


def wait(app, seconds: float, until=None) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        app.processEvents()
        if until is not None and until():
            return
        time.sleep(0.02)


CASE = {"case_id": "2024-00117", "evidence_id": "EV-3", "examiner": "J. Doe", "notes": "left shoe"}
#: where each corner is clicked, px from the true corner (a careful click, zoomed in; snapping
#: finds the corner or keeps the click)
CLICK_OFFSETS = [(0.5, -0.4), (-0.4, 0.5), (0.45, 0.4), (-0.5, -0.3), (0.4, -0.45), (-0.3, 0.5)]


def calibration_shots(scan: Path) -> int:
    import json
    import shutil

    from PySide6.QtCore import QRectF

    from impress_gui.core.calibration.target import CORNER_NAMES
    from impress_gui.ui.app import create_app, grab, make_settings
    from impress_gui.ui.main_window import MainWindow
    from impress_gui.ui.motor.panel import MotorPanel

    app = create_app()
    picks = json.loads((scan / "picks.json").read_text())
    truth = json.loads((scan / "truth.json").read_text())
    with tempfile.TemporaryDirectory() as tmp:
        evidence = Path(tmp) / "evidence" / CASE["case_id"] / "scan.mp4"
        evidence.parent.mkdir(parents=True)
        shutil.copy(scan / "scan.mp4", evidence)
        settings = make_settings(Path(tmp) / "settings.ini")
        panel = MotorPanel(port_lister=lambda: [("/dev/ttyUSB0", "FT232R USB UART")])
        window = MainWindow(settings, motor_panel=panel)
        window.resize(1920, 1080)
        window.show()
        window.new_project(dict(CASE))
        tab = window.calibration_tab
        tab.status.connect(lambda line: print("  " + line))
        wait(app, 1.0)
        tab.load_video(evidence)
        wait(app, 60.0, lambda: tab.video is not None and not tab.is_busy())
        tab.setup.load_intrinsics_file(str(scan / "intrinsics.json"))
        tab.setup.set_speed(truth["speed_mm_s"])
        assert tab.corners.snap_check.isChecked()

        def show_target(which: str) -> None:
            tab.go_to_frame(picks[which])
            uv = [picks[f"corners_{which}"][c] for c in CORNER_NAMES]
            us, vs = [p[0] for p in uv], [p[1] for p in uv]
            pad = 0.12 * (max(us) - min(us))
            rect = QRectF(min(us) - pad, min(vs) - pad, max(us) - min(us) + 2 * pad, 0)
            rect.setHeight(max(vs) - min(vs) + 2 * pad)
            tab.view.vb.setRange(rect, padding=0)
            wait(app, 2.0)  # the stripe overlay is detected in the background

        def mark(which: str, names) -> None:
            for name in names:
                u, v = picks[f"corners_{which}"][name]
                du, dv = CLICK_OFFSETS[CORNER_NAMES.index(name)]
                tab.on_view_clicked(u + du, v + dv)

        def calibrate(speed: float) -> None:
            tab.setup.set_speed(speed)
            tab.calibrate()
            wait(app, 60.0, lambda: not tab.is_busy())
            show_target("t2")
            tab.loupe.set_centre(tuple(picks["corners_t2"]["F"]))
            tab.sidebar.verticalScrollBar().setValue(tab.sidebar.verticalScrollBar().maximum())
            wait(app, 1.0)

        IMAGES.mkdir(parents=True, exist_ok=True)
        show_target("t1")
        mark("t1", CORNER_NAMES[:3])
        u, v = picks["corners_t1"]["D"]
        tab.loupe.set_centre((u + 0.3, v - 0.2))  # the cursor on the next corner
        wait(app, 1.0)
        shots = [IMAGES / f"calibration-{n}.png" for n in ("marking", "result", "warning")]
        ok = grab(window).save(str(shots[0]))
        mark("t1", CORNER_NAMES[3:])
        tab.go_to_frame(picks["t2"])
        mark("t2", CORNER_NAMES)
        calibrate(truth["speed_mm_s"])
        ok = ok and tab.calibration is not None and grab(window).save(str(shots[1]))
        calibrate(round(truth["speed_mm_s"] * 1.03, 3))  # 3 % too fast: a warning
        ok = ok and bool(tab.calibration.warnings) and grab(window).save(str(shots[2]))
        window.messenger.close_all()
        window.shutdown()  # not closed: that would ask to save the project
    if not ok:
        print("the calibration screenshots were not made", file=sys.stderr)
        return 1
    print("wrote " + ", ".join(str(p) for p in shots))
    return 0


def main(argv: list[str]) -> int:
    if len(argv) > 2 and argv[1] == "--calibration":
        return calibration_shots(Path(argv[2]))
    from impress_gui.ui.app import create_app, grab, make_settings
    from impress_gui.ui.main_window import MainWindow
    from impress_gui.ui.motor.panel import MotorPanel, MotorPanelSettings

    app = create_app()
    with tempfile.TemporaryDirectory() as tmp:
        settings = make_settings(Path(tmp) / "settings.ini")
        # the simulated motor at its real speed; USB adapters listed as a lab laptop shows them
        panel = MotorPanel(
            settings=MotorPanelSettings(speed_mm_s=13.138, start_mm=0.0),
            port_lister=lambda: [("/dev/ttyUSB0", "FT232R USB UART")],
        )
        window = MainWindow(settings, motor_panel=panel)
        window.resize(1920, 1080)
        window.show()
        if len(argv) > 1:
            window.open_path(Path(argv[1]))
        wait(app, 1.0)
        panel.port_combo.setCurrentIndex(0)  # Simulated motor
        panel.connect_motor()
        wait(app, 5.0, lambda: panel.is_connected)
        if not panel.is_connected:
            print("the simulated motor did not connect", file=sys.stderr)
            return 1
        panel.home()
        wait(app, 10.0, lambda: not panel.is_busy)
        panel.scan(panel.settings.short_scan_mm)
        wait(app, 6.0)  # a few seconds into the run: moving at the scan speed
        IMAGES.mkdir(parents=True, exist_ok=True)
        dock = window.motor_dock
        dock_png = IMAGES / "motor-panel-scan.png"
        if not dock.grab().save(str(dock_png)):
            return 1
        win_png = IMAGES / "technician-window.png"
        if not grab(window).save(str(win_png)):
            return 1
        print(f"wrote {dock_png} and {win_png}")
        panel.stop()
        wait(app, 1.0)
        window.shutdown()
        window.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv))
