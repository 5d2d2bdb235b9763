"""The 3D view on the GPU (issue 21, item 9): pyqtgraph's OpenGL view where an OpenGL context
can be created, the software view otherwise with a plain sentence why.

Offscreen (the other GUI tests' platform) the window falls back to the software view and says
so without an exception's text. The mesh the GPU draws is the exported files' right-handed
frame (x across the rail, y = -rail y, z up), never mirrored. On a virtual X display (Xvfb,
Qt's xcb platform, Mesa's llvmpipe) a subprocess opens the window: the GPU view is chosen,
draws a frame that is not blank, and a raised, red block in the map's upper left appears in
the upper left seen from straight above as the camera sees the ground, and in the lower right
seen from the other side (turned, not mirrored). Two windows in turn both draw (pyqtgraph's
shader programs belong to one GL context). Skipped only where Xvfb is not installed
(scripts/bootstrap.sh installs it with Mesa's GL libraries, so CI runs it).

Run as a script (``python tests/test_gui_view3d_gl.py OUTDIR``) it is that subprocess: it
writes the frames as PNG and what the windows said as ``result.json`` in OUTDIR.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from impress_gui.core.reconstruction.grid import GridSpec

SPEC = GridSpec(-20.0, 100.0, 0.2, (300, 200))  # 40 mm across (x), 60 mm along the rail
BLOCK = (slice(40, 120), slice(30, 90))  # rows 40-119 (the map's upper part), cols 30-89 (left)
RED = (220, 30, 30)
pytestmark = pytest.mark.qt_log_ignore("propagateSizeHints")


def scene() -> tuple[np.ndarray, np.ndarray]:
    """A flat surface with a 3 mm block in the map's upper left, red in the texture (grey
    elsewhere), and a hole."""
    h = np.zeros(SPEC.shape, np.float32)
    h[BLOCK] = 3.0
    h[250:260, 150:160] = np.nan
    tex = np.full(SPEC.shape + (3,), 170, np.uint8)
    tex[BLOCK] = RED
    return h, tex


# ----- offscreen ----------------------------------------------------------------------------------
def test_offscreen_falls_back_to_software_with_a_plain_sentence(qtbot):
    from impress_gui.ui.viewer.view3d import Surface3DWindow, opengl_check

    reason, detail = opengl_check()
    assert reason == "This display has no OpenGL." and "offscreen" in detail
    h, tex = scene()
    win = Surface3DWindow(h, SPEC, tex)
    qtbot.addWidget(win)
    assert win.renderer == "software" and win.gl is None
    text = win.message.text()
    assert text.startswith("This display has no OpenGL. Software rendering")
    for technical in ("Error", "Traceback", "ModuleNotFound", "No module", "("):
        assert technical not in text
    assert "offscreen" in win.message.toolTip()  # the technical reason, in the tooltip
    win.resize(600, 500)
    with qtbot.waitSignal(win.rendered, timeout=20000):
        win.show()
    assert win.view.pixmap() is not None and win.frames >= 1
    win.shutdown()


def test_the_reasons_are_plain_sentences():
    from impress_gui.ui.viewer.view3d import import_failure

    sentence, detail = import_failure(ModuleNotFoundError("No module named 'OpenGL'",
                                                          name="OpenGL"))
    assert sentence == "The OpenGL package for Python (PyOpenGL) is not installed."
    assert detail == "ModuleNotFoundError: No module named 'OpenGL'"
    sentence, detail = import_failure(ImportError("Unable to load OpenGL library"))
    assert sentence == "The computer's OpenGL library could not be loaded."
    assert "Unable to load" in detail


def test_the_software_view_can_be_chosen(monkeypatch, qtbot):
    from impress_gui.ui.viewer.view3d import RENDERER_ENV, Surface3DWindow, opengl_check

    monkeypatch.setenv(RENDERER_ENV, "software")
    assert opengl_check() == ("OpenGL is switched off.", f"{RENDERER_ENV}=software")
    h, tex = scene()
    win = Surface3DWindow(h, SPEC, tex)
    qtbot.addWidget(win)
    assert win.renderer == "software"
    assert win.message.text().startswith("OpenGL is switched off. Software rendering")
    assert win.message.toolTip() == f"{RENDERER_ENV}=software"
    monkeypatch.delenv(RENDERER_ENV)
    win2 = Surface3DWindow(h, SPEC, tex, renderer="software")
    qtbot.addWidget(win2)
    assert win2.renderer == "software" and win2.message.text().startswith("Software rendering")


def test_pyopengl_is_installed():
    """PyOpenGL is a runtime dependency: the GPU view's import works (a display is another
    matter)."""
    import pyqtgraph.opengl  # noqa: F401


# ----- the mesh the GPU draws (Qt-free) ----------------------------------------------------------
def test_the_mesh_is_the_export_frame_never_mirrored():
    from impress_gui.ui.viewer.view3d import surface_mesh

    h, tex = scene()
    m = surface_mesh(h, SPEC, tex)
    v, f, c = m["vertexes"], m["faces"], m["colors"]
    ok = np.isfinite(h)
    assert v.shape == (ok.sum(), 3) and c.shape == (ok.sum(), 4)
    # row-major over the finite cells: the first is cell (0, 0) at (x0, -y0)
    assert v[0] == pytest.approx([SPEC.x0_mm, -SPEC.y0_mm, 0.0])
    assert m["lows"] == pytest.approx((SPEC.x0_mm, -(SPEC.y0_mm + 299 * 0.2), 0.0), abs=1e-4)
    assert m["spans"] == pytest.approx((199 * 0.2, 299 * 0.2, 3.0), abs=1e-4)
    # the block: across the rail at the map's left, up the map (large frame y), 3 mm up
    top = v[:, 2] > 2.9
    assert v[top, 0].max() < SPEC.x0_mm + 90 * 0.2 < SPEC.x0_mm + 0.5 * 199 * 0.2 + 10
    assert v[top, 1].min() > -(SPEC.y0_mm + 120 * 0.2)
    assert v[top, 1].mean() > v[:, 1].mean()  # in the upper half of the map
    assert v[top, 0].mean() < v[:, 0].mean()  # in its left half
    red = (c[:, 0] > 2 * c[:, 1]) & (c[:, 0] > 2 * c[:, 2])
    assert np.array_equal(red, top)
    # every triangle anticlockwise seen from above (normals up): a turn, not a reflection
    a, b, d = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    cross_z = (b[:, 0] - a[:, 0]) * (d[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (d[:, 0] - a[:, 0])
    assert (cross_z > 0).all()
    # the hole has no triangles: each quad's two halves where their three cells have heights
    a_, b_, d_, e_ = ok[:-1, :-1], ok[:-1, 1:], ok[1:, :-1], ok[1:, 1:]
    assert len(f) == (a_ & d_ & b_).sum() + (b_ & d_ & e_).sum() < 2 * 299 * 199
    # the vertical exaggeration; without a texture, the colours follow the height
    m2 = surface_mesh(h, SPEC, None, exaggeration=2.0)
    assert m2["vertexes"][:, 2].max() == pytest.approx(6.0)
    c2 = m2["colors"]
    assert not np.allclose(c2[top].mean(axis=0), c2[~top].mean(axis=0), atol=0.1)


def test_the_cameras_azimuth():
    """This module's azimuth (where the eye stands, clockwise from the top of the map) as
    pyqtgraph's (anticlockwise from +x): 180, below the map's bottom edge, is -y (270)."""
    from impress_gui.ui.viewer.view3d import from_gl_azimuth, to_gl_azimuth

    assert [to_gl_azimuth(a) for a in (0.0, 90.0, 180.0, 270.0)] == [90.0, 0.0, 270.0, 180.0]
    for a in (0.0, 37.0, 200.0, 359.0):
        assert from_gl_azimuth(to_gl_azimuth(a)) == pytest.approx(a)


# ----- the GPU view on a virtual X display ---------------------------------------------------
# ``x_display`` (conftest.py): a fresh Xvfb, the test skipped where none is installed


VIEWS = (("above180", 180.0, 90.0), ("above0", 0.0, 90.0), ("oblique", 200.0, 40.0))


def gpu_main(out: Path) -> None:
    """The subprocess: two windows in turn (texture, then height colours), each drawn from
    the three :data:`VIEWS`; the frames as PNG and what the windows said in result.json."""
    from PySide6.QtWidgets import QApplication

    from impress_gui.ui.viewer.view3d import Surface3DWindow, opengl_check

    app = QApplication([sys.argv[0], "-platform", "xcb"])
    h, tex = scene()
    result: dict = {"platform": app.platformName(), "check": list(opengl_check()), "windows": []}

    def wait(cond, seconds: float = 30.0) -> bool:
        end = time.monotonic() + seconds
        while not cond() and time.monotonic() < end:
            app.processEvents()
            time.sleep(0.01)
        return bool(cond())

    for k, colours in enumerate((tex, None)):
        win = Surface3DWindow(h, SPEC, colours)
        win.resize(800, 700)
        win.show()
        drawn = wait(lambda w=win: w.frames > 0)
        about = {"renderer": win.renderer, "message": win.message.text(),
                 "tooltip": win.message.toolTip(), "drawn": drawn, "views": []}
        result["windows"].append(about)
        if win.renderer == "opengl":
            about["legend"] = win.legend.text()
            for name, azimuth, elevation in VIEWS:
                win.look(azimuth, elevation)
                img = win.gl.grabFramebuffer()
                img.save(str(out / f"{k}_{name}.png"))
                about["views"].append(name)
            win.grab().save(str(out / f"{k}_window.png"))
            if k == 0:  # drag turns the view, the wheel zooms
                about["interaction"] = interact(app, win)
        about["frames"] = win.frames
        win.close()
        win.deleteLater()
        app.processEvents()
    (out / "result.json").write_text(json.dumps(result, indent=1))


def interact(app, win) -> dict:
    """Drag across the OpenGL view and turn the wheel over it: the azimuth and the camera's
    distance before and after."""
    from PySide6.QtCore import QPoint, QPointF, Qt
    from PySide6.QtGui import QWheelEvent
    from PySide6.QtTest import QTest

    gl = win.gl
    before = {"azimuth": win.azimuth, "distance": gl.opts["distance"]}
    start = gl.rect().center()
    QTest.mousePress(gl, Qt.MouseButton.LeftButton, Qt.KeyboardModifier.NoModifier, start)
    for dx in range(10, 110, 10):
        QTest.mouseMove(gl, start + QPoint(dx, 0))
    QTest.mouseRelease(gl, Qt.MouseButton.LeftButton, Qt.KeyboardModifier.NoModifier,
                       start + QPoint(100, 0))
    frames = win.frames
    end = time.monotonic() + 10
    while win.frames == frames and time.monotonic() < end:
        app.processEvents()
    turned = {"azimuth": win.azimuth}
    pos = QPointF(start)
    wheel = QWheelEvent(pos, gl.mapToGlobal(pos), QPoint(0, 0), QPoint(0, 240),
                        Qt.MouseButton.NoButton, Qt.KeyboardModifier.NoModifier,
                        Qt.ScrollPhase.NoScrollPhase, False)
    app.sendEvent(gl, wheel)
    app.processEvents()
    return {"before": before, "turned": turned, "distance": gl.opts["distance"]}


def read_rgb(path: Path) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert img is not None, f"{path} is not a PNG"
    return img[:, :, ::-1].astype(int)


def test_the_gpu_view_under_xvfb(x_display, tmp_path):
    out = tmp_path / "frames"
    out.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith("QT_")}
    env |= {"QT_QPA_PLATFORM": "xcb", "DISPLAY": x_display, "HOME": str(tmp_path)}
    env.pop("IMPRESS_3D_RENDERER", None)
    res = subprocess.run([sys.executable, __file__, str(out)], env=env, capture_output=True,
                         text=True, timeout=240, cwd=tmp_path)
    assert res.returncode == 0, f"exit {res.returncode}\nstdout:\n{res.stdout}\nstderr:\n{res.stderr}"
    assert "Error while drawing" not in res.stderr, res.stderr
    result = json.loads((out / "result.json").read_text())
    assert result["platform"] == "xcb"
    assert result["check"][0] == "" and result["check"][1].startswith("OpenGL "), result
    for k, win in enumerate(result["windows"]):
        assert win["renderer"] == "opengl", win
        assert win["message"].startswith("OpenGL rendering: drag to rotate, wheel to zoom")
        assert win["drawn"] and win["frames"] >= 4 and win["views"] == [v[0] for v in VIEWS]
        assert "grid squares 5 mm" in win["legend"] and "x (red)" in win["legend"]
        for name, _az, _el in VIEWS:
            img = read_rgb(out / f"{k}_{name}.png")
            assert img.shape[0] > 300 and img.shape[1] > 300
            # not blank: the surface covers a good part of the frame, in more than one colour
            lit = np.abs(img - np.array([40, 40, 48])).sum(axis=2) > 30
            assert 0.15 < lit.mean() < 0.95, (k, name, lit.mean())
            assert img[lit].std(axis=0).max() > 10, (k, name)
    # dragging to the right turns the surface (the eye goes round it), the wheel zooms in
    moved = result["windows"][0]["interaction"]
    assert abs((moved["turned"]["azimuth"] - moved["before"]["azimuth"] + 180) % 360 - 180) > 20
    assert moved["distance"] < 0.9 * moved["before"]["distance"]
    # chirality: seen from straight above at azimuth 180 (the camera's view of the ground) the
    # red block is in the upper left; from azimuth 0 in the lower right. The camera looks at
    # the surface's centre (the frame's centre); the block's centre is 8 mm left of it (x) and
    # 14 mm up the map (y); the surface is 40 mm across and fills about 300 pixels
    for name, want in (("above180", [-1, -1]), ("above0", [1, 1])):
        img = read_rgb(out / f"0_{name}.png")
        red = (img[:, :, 0] > 120) & (img[:, :, 1] < 60) & (img[:, :, 2] < 60)
        assert red.sum() > 2000, name
        rows, cols = np.nonzero(red)
        h, w = img.shape[:2]
        offset = np.array([cols.mean() - (w - 1) / 2, rows.mean() - (h - 1) / 2])
        assert np.sign(offset).tolist() == want, (name, offset)
        assert (np.abs(offset) > 25).all(), (name, offset)
        assert abs(offset[1]) > abs(offset[0]), (name, offset)  # 14 mm against 8 mm

if __name__ == "__main__":
    gpu_main(Path(sys.argv[1]))
