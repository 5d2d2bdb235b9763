"""Screenshots of the motor panel for docs/technician-guide.md, taken under a real X server.

    xvfb-run -s "-screen 0 1920x1080x24" .venv/bin/python scripts/docs_screenshots.py [PROJECT]

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


def main(argv: list[str]) -> int:
    from impress_gui.ui.app import create_app, grab, make_settings
    from impress_gui.ui.main_window import MainWindow
    from impress_gui.ui.motor_panel import MotorPanel, MotorPanelSettings

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
