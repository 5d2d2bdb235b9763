"""The window on a real X display: ``impress gui`` started in a subprocess with Qt's xcb
platform on a virtual X server (Xvfb), not the offscreen platform the other GUI tests use.

On a machine missing one of the libraries Qt's xcb plugin links (libxcb-icccm4 and
libxcb-keysyms1 were missing on a fresh install before scripts/bootstrap.sh installed them),
Qt prints "Could not load the Qt platform plugin "xcb"" and aborts: this test fails. It is
skipped only where Xvfb is not installed (scripts/bootstrap.sh installs it, so CI runs it).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

SIZE = (1280, 800)  # the screen conftest.x_display makes


# ``x_display`` (conftest.py): a fresh Xvfb of 1280x800 pixels, skipped where none is installed


def read_png(path: Path) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert img is not None, f"{path} is not a PNG"
    return img


def test_the_window_opens_on_the_xcb_platform_under_xvfb(x_display, tmp_path):
    shot = tmp_path / "window.png"
    env = {k: v for k, v in os.environ.items() if not k.startswith("QT_")}
    env |= {"QT_QPA_PLATFORM": "xcb", "DISPLAY": x_display, "HOME": str(tmp_path)}
    cmd = [sys.executable, "-m", "impress_gui", "gui", "--check", "--no-motor",
           "--settings", str(tmp_path / "settings.ini"), "--size", f"{SIZE[0]}x{SIZE[1]}",
           "--screenshot", str(shot)]
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=180,
                         cwd=tmp_path)
    err = res.stderr
    assert res.returncode == 0, f"exit {res.returncode}\nstdout:\n{res.stdout}\nstderr:\n{err}"
    for bad in ("platform plugin", "xcb-cursor", "libxcb", "could not connect to display",
                "This application failed to start"):
        assert bad.lower() not in err.lower(), err
    assert "check passed: the window started" in res.stdout
    # the picture comes from the X server's framebuffer (app.grab on xcb): the window is there,
    # drawn (menu bar, tabs, panels), not a blank or black rectangle
    img = read_png(shot)
    assert img.shape[0] >= 400 and img.shape[1] >= 600
    grey = img.mean(axis=2)
    assert grey.std() > 20 and (grey > 200).mean() > 0.2 and (grey < 60).mean() > 0.05


def test_without_a_display_the_window_refuses_with_a_coded_error(tmp_path):
    """No display at all, and one named that no X server answers: Qt's xcb platform cannot
    start. Qt would abort (exit 134, a core dump); the user gets one coded line (E-DISPLAY)
    naming Qt's reason and what to do, exit status 2, and nothing is written."""
    base = {k: v for k, v in os.environ.items()
            if not k.startswith("QT_") and k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    for extra in ({}, {"DISPLAY": ":97"}):
        home = tmp_path / f"home{len(extra)}"
        home.mkdir()
        env = base | extra | {"HOME": str(home), "XDG_CONFIG_HOME": str(home / ".config")}
        res = subprocess.run([sys.executable, "-m", "impress_gui", "gui", "--no-motor"],
                             env=env, capture_output=True, text=True, timeout=120, cwd=home)
        assert res.returncode == 2, f"exit {res.returncode}\n{res.stderr}"
        assert "error [E-DISPLAY]" in res.stderr and "could not connect to display" in res.stderr
        assert "QT_QPA_PLATFORM=offscreen" in res.stderr and "Traceback" not in res.stderr
        assert list(home.rglob("*")) == []


def _open(x_display, tmp_path, *extra):
    shot = tmp_path / "window.png"
    shot.unlink(missing_ok=True)
    env = {k: v for k, v in os.environ.items() if not k.startswith("QT_")}
    env |= {"QT_QPA_PLATFORM": "xcb", "DISPLAY": x_display, "HOME": str(tmp_path)}
    res = subprocess.run([sys.executable, "-m", "impress_gui", "gui", "--check",
                          "--settings", str(tmp_path / "settings.ini"), "--screenshot",
                          str(shot), *extra], env=env, capture_output=True, text=True,
                         timeout=180, cwd=tmp_path)
    assert res.returncode == 0, f"exit {res.returncode}\n{res.stdout}\n{res.stderr}"
    return read_png(shot).shape[:2]


def test_the_window_fits_a_small_screen_and_reopens_as_it_was_left(x_display, tmp_path):
    """On a screen smaller than the default 1920x1080 (here 1280x800, a laptop's size) the
    window, motor panel included, opens within the screen (it was 1920x1080, and the motor
    panel alone asked for 743 rows); closed at another size, it reopens at that size."""
    h, w = _open(x_display, tmp_path)
    assert w <= SIZE[0] and h <= SIZE[1], (w, h)
    assert w >= 0.9 * SIZE[0] and h >= 0.9 * SIZE[1], (w, h)  # and uses it
    assert _open(x_display, tmp_path, "--size", "1270x720") == (720, 1270)
    assert _open(x_display, tmp_path) == (720, 1270)
