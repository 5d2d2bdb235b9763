"""Viewer responsiveness on a full 1.75 m scan at 0.1 mm (issue 6's acceptance figures).

A synthetic tire-track heightmap of 17,500 x 2,700 float32 cells (ribs, grooves, sipes, noise
and holes without data) with a registered texture is

1. written as a reconstruction folder and opened in the viewer tab: time until the map is on
   screen, and until the display pyramid is complete;
2. panned and zoomed through a fixed sequence of views, each painted synchronously: frame
   times (median, 95th percentile, worst) of the viewer's pyramid display against a plain
   pyqtgraph ``ImageItem`` with ``autoDownsample`` showing the same array, in the same run;
3. measured: a profile along the whole 1.75 m (5 mm wide average) and a 2 mm readout, on the
   full-resolution array.

Runs offscreen by default (QT_QPA_PLATFORM=offscreen); wall times on a shared machine depend
on what else runs, so the load average is printed.

Usage: .venv/bin/python benchmarks/bench_viewer.py [--rows 17500] [--cols 2700]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")


def load() -> str:
    a, b, c = os.getloadavg()
    return f"load average {a:.1f} {b:.1f} {c:.1f}"


def synthetic(rows: int, cols: int, pixel_mm: float = 0.1):
    """A tire track along y: 8.5 mm deep tread blocks, 4 grooves, chevron sipes, noise, holes."""
    rng = np.random.default_rng(7)
    x = (np.arange(cols, dtype=np.float32) - cols / 2) * pixel_mm
    h = np.empty((rows, cols), np.float32)
    grooves = np.zeros(cols, bool)
    for gx in (-55.0, -18.0, 18.0, 55.0):
        grooves |= np.abs(x - gx) <= 5.0
    for r0 in range(0, rows, 2048):
        y = (np.arange(r0, min(rows, r0 + 2048), dtype=np.float32) * pixel_mm)[:, None]
        chevron = np.mod(y + 0.35 * np.abs(x)[None, :], 28.0) < 6.0
        tread = ~grooves[None, :] & ~(chevron & (np.abs(x) > 60.0)[None, :])
        band = np.where(tread, -13.5, -5.0).astype(np.float32)
        band += 0.02 * rng.standard_normal(band.shape).astype(np.float32)
        h[r0 : r0 + band.shape[0]] = band
    for _ in range(400):  # holes without data (occlusions, dropouts)
        i, j = rng.integers(0, rows), rng.integers(0, cols)
        h[max(0, i - 20) : i + 20, max(0, j - 15) : j + 15] = np.nan
    tex = np.empty((rows, cols, 3), np.uint8)
    tex[...] = np.clip(120 + 8 * np.nan_to_num(h, nan=-5.0)[..., None], 0, 255).astype(np.uint8)
    return h, tex


def write_folder(folder: Path, h: np.ndarray, tex: np.ndarray) -> None:
    import cv2
    import tifffile

    folder.mkdir(parents=True, exist_ok=True)
    tifffile.imwrite(folder / "heightmap.tif", h, compression="zlib")
    cv2.imwrite(str(folder / "texture.png"), tex[..., ::-1])
    meta = {
        "format": "impress.reconstruction",
        "version": 1,
        "software": "bench",
        "grid": {
            "x0_mm": -h.shape[1] * 0.05,
            "y0_mm": 0.0,
            "pixel_mm": 0.1,
            "shape": list(h.shape),
        },
        "files": {},
    }
    (folder / "metadata.json").write_text(json.dumps(meta))


def views(full):
    """Zoom from the whole scan to 20 mm, with pans at each zoom, and back out."""
    from PySide6.QtCore import QRectF

    cx, cy = full.center().x(), full.center().y()
    out = []
    for frac in (1.0, 0.5, 0.25, 0.12, 0.06, 0.03, 0.015, 0.008):
        w, hh = full.width() * max(frac, 0.0075), full.height() * frac
        for k in range(4):
            dx, dy = (k - 1.5) * 0.1 * w, (k - 1.5) * 0.15 * hh
            out.append(QRectF(cx - w / 2 + dx, cy - hh / 2 + dy, w, hh))
    return out + list(reversed(out[:8]))


def frame_times(widget, view_box, rects) -> np.ndarray:
    """Per view: set the range and render the whole widget (``grab`` paints synchronously)."""
    times = []
    widget.grab()
    for r in rects:
        t = time.perf_counter()
        view_box.setRange(r, padding=0)
        widget.grab()
        times.append(time.perf_counter() - t)
    return np.array(times) * 1000


def stats(ms: np.ndarray) -> str:
    return (
        f"median {np.median(ms):6.1f} ms, 95th percentile {np.percentile(ms, 95):6.1f} ms, "
        f"worst {ms.max():6.1f} ms"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=17500)
    ap.add_argument("--cols", type=int, default=2700)
    args = ap.parse_args()
    import pyqtgraph as pg
    from PySide6.QtCore import QEventLoop, QTimer
    from PySide6.QtWidgets import QApplication

    app = QApplication.instance() or QApplication(sys.argv[:1])
    pg.setConfigOptions(imageAxisOrder="row-major")
    from impress_gui.ui import pyside_fix

    pyside_fix.guard()
    from impress_gui.core.measure import readings as M
    from impress_gui.ui.viewer.tab import ViewerTab

    print(
        f"IMPREsS viewer benchmark ({os.cpu_count()} CPUs, {load()}, "
        f"Qt platform {app.platformName()})"
    )
    t = time.perf_counter()
    h, tex = synthetic(args.rows, args.cols)
    print(
        f"synthetic map {args.rows} x {args.cols} cells ({h.nbytes / 1e6:.0f} MB float32, "
        f"texture {tex.nbytes / 1e6:.0f} MB): made in {time.perf_counter() - t:.1f} s"
    )

    def wait(signal, timeout_ms: int = 120_000) -> None:
        loop = QEventLoop()
        signal.connect(loop.quit)
        QTimer.singleShot(timeout_ms, loop.quit)
        loop.exec()
        signal.disconnect(loop.quit)

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "recon"
        t = time.perf_counter()
        write_folder(folder, h, tex)
        print(f"reconstruction folder written in {time.perf_counter() - t:.1f} s")
        v = ViewerTab()
        v.resize(1600, 1000)
        v.show()
        app.processEvents()
        gaps, last = [0.0], [time.perf_counter()]

        def tick() -> None:
            now = time.perf_counter()
            gaps.append(now - last[0])
            last[0] = now

        ticker = QTimer()
        ticker.timeout.connect(tick)
        ticker.start(10)
        t0 = last[0] = time.perf_counter()
        v.open_reconstruction(folder)
        wait(v.loaded)
        v.map.grab()
        t_shown = time.perf_counter() - t0
        while v.map.is_busy():
            loop = QEventLoop()
            QTimer.singleShot(20, loop.quit)
            loop.exec()
        t_pyramid = time.perf_counter() - t0
        ticker.stop()
        print(
            f"open and display the full map: {t_shown:.2f} s until on screen, {t_pyramid:.2f} "
            f"s until the display pyramid is complete ({len(v.map.scalar.levels)} levels); "
            f"longest event-loop stall meanwhile {max(gaps) * 1000:.0f} ms (files are read "
            f"and the pyramid built in worker threads)"
        )
        full = v.map.full_rect()
        rects = views(full)
        v.map.texture_item.setOpacity(0.0)
        ours = frame_times(v.map, v.map.vb, rects)
        print(f"pan/zoom, viewer (pyramid + view crop), {len(rects)} views: {stats(ours)}")
        v.map.set_texture_opacity(0.5)
        blended = frame_times(v.map, v.map.vb, rects)
        print(f"pan/zoom, viewer with the texture blended at 50 %:     {stats(blended)}")

        plain = pg.PlotWidget()
        plain.resize(1600, 1000)
        plain.show()
        app.processEvents()
        item = pg.ImageItem(axisOrder="row-major")
        item.setAutoDownsample(True)
        plain.addItem(item)
        plain.getViewBox().setAspectLocked(True)
        item.setImage(v.data.height_mm, autoLevels=False, levels=v.map.levels())
        item.setLookupTable(pg.colormap.get("turbo").getLookupTable(nPts=256))
        item.setRect(full)
        naive = frame_times(plain, plain.getViewBox(), rects)
        print(f"pan/zoom, plain ImageItem(autoDownsample) same map:    {stats(naive)}")
        print(
            f"  ratio plain/viewer: median {np.median(naive) / np.median(ours):.1f}x, "
            f"worst {naive.max() / ours.max():.1f}x"
        )

        spec = v.data.spec
        p0 = (spec.x0_mm + 20.0, spec.y0_mm + 5.0)
        p1 = (spec.x0_mm + 200.0, spec.y0_mm + spec.shape[0] * spec.pixel_mm - 5.0)
        t = time.perf_counter()
        prof = M.line_profile(v.data.height_mm, spec, p0, p1, width_mm=5.0)
        t_prof = time.perf_counter() - t
        t = time.perf_counter()
        for _ in range(100):
            M.readout(v.data.height_mm, spec, 100.0 + spec.x0_mm, 800.0, 2.0)
        t_read = (time.perf_counter() - t) / 100
        print(
            f"profile over {prof.length_mm:.0f} mm, 5 mm wide ({prof.n_lines} lines, "
            f"{len(prof.distance_mm)} samples, full resolution): {t_prof * 1000:.0f} ms "
            f"(in the background while dragging); readout over 2 mm: {t_read * 1000:.2f} ms"
        )
        v.shutdown()
        plain.close()


if __name__ == "__main__":
    main()
