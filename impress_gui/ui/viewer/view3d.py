"""A 3D view of the coloured surface.

pyqtgraph's OpenGL widgets need PyOpenGL and a working GL context, which remote desktops,
virtual machines and the offscreen test platform often lack. This view therefore renders in
software: the surface, decimated to a few hundred thousand cells, is rotated, shaded and
splatted into a depth buffer (:func:`render_surface`, Qt-free) in a worker thread; dragging
rotates, the wheel zooms. When OpenGL is not available the window says so.
"""

from __future__ import annotations

import math

import numpy as np
from PySide6.QtCore import QPointF, Qt, Signal
from PySide6.QtGui import QImage, QPixmap
from PySide6.QtWidgets import (
    QDoubleSpinBox,
    QHBoxLayout,
    QLabel,
    QSizePolicy,
    QVBoxLayout,
    QWidget,
)

from impress_gui.core.reconstruction.grid import GridSpec
from impress_gui.ui.worker import LatestOnly

BACKGROUND = (40, 40, 48)


def render_surface(
    height: np.ndarray,
    spec: GridSpec,
    colours: np.ndarray | None,
    azimuth_deg: float,
    elevation_deg: float,
    size: tuple[int, int] = (800, 600),
    exaggeration: float = 1.0,
    zoom: float = 1.0,
    max_points: int = 300_000,
    axes: dict | None = None,
) -> np.ndarray:
    """An orthographic, Lambert-shaded view ``(H, W, 3)`` uint8 of the surface seen from
    ``azimuth_deg`` at ``elevation_deg`` above the horizon.

    The grid's y runs down the camera's image (the rail's motion), so (x, y, height) is a
    left-handed frame; the surface is drawn in the right-handed (x, -y, height), so that it
    is turned, never mirrored: seen from straight above at azimuth 180 it is the camera's view,
    as the viewer's map and ``texture.png`` (row 0 at the top, x to the right). The azimuth
    is where the eye stands, clockwise from the top of the map (-y): 180 is below the map's
    bottom edge, looking up the map.

    ``axes``, when given, receives where the frame's axes and a scale bar go on the image
    (:func:`axes_geometry`): the window draws them over it."""
    import cv2

    w_out, h_out = size
    step = max(1, int(math.ceil(math.sqrt(height.size / max_points))))
    z = np.asarray(height[::step, ::step], np.float32)
    col = None if colours is None else np.asarray(colours[::step, ::step, :3])
    ok = np.isfinite(z)
    img = np.empty((h_out, w_out, 3), np.uint8)
    img[:] = BACKGROUND
    if ok.sum() < 4:
        return img
    cell = spec.pixel_mm * step
    gy, gx = np.gradient(np.where(ok, z, np.nanmean(z)) * exaggeration, cell)
    ys, xs = np.nonzero(ok)
    x = xs * cell
    y = -ys * cell  # right-handed: x, up the map (-y), height
    zz = z[ok] * exaggeration
    nx, ny = -gx[ok], gy[ok]  # the surface's normal in that frame
    base = np.full((len(x), 3), 200.0, np.float32) if col is None else col[ok].astype(np.float32)
    # vertical walls: points from each cell down to its lowest neighbour where it steps down
    pad = np.pad(np.where(ok, z, np.nan), 1, constant_values=np.nan)
    low = np.fmin.reduce(
        np.stack([pad[:-2, 1:-1], pad[2:, 1:-1], pad[1:-1, :-2], pad[1:-1, 2:]]), axis=0
    )[ok]
    drop = np.nan_to_num((z[ok] - low) * exaggeration, nan=0.0)
    wall = np.nonzero(drop > 1.5 * cell)[0]
    if wall.size:
        n = np.minimum(np.ceil(drop[wall] / cell).astype(np.int64), 64)
        idx = np.repeat(wall, n - 1)
        k = np.arange(idx.size) - np.repeat(np.cumsum(n - 1) - (n - 1), n - 1) + 1
        frac = k / np.repeat(n, n - 1)
        x = np.concatenate([x, x[idx]])
        y = np.concatenate([y, y[idx]])
        zz = np.concatenate([zz, zz[idx] - frac * drop[idx]])
        # a wall faces the side of its lower neighbour: shade it as a steep, darker face
        nx = np.concatenate([nx, np.zeros(idx.size)])
        ny = np.concatenate([ny, np.zeros(idx.size)])
        base = np.concatenate([base, base[idx] * 0.55])
    lows = (x.min(), y.min(), zz.min())  # the surface's lowest corner in the frame (mm)
    spans = (np.ptp(x), np.ptp(y))
    mean = (x.mean(), y.mean(), zz.mean())
    x, y, zz = x - mean[0], y - mean[1], zz - mean[2]
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    # the screen frame: eye (from the surface towards the viewer), right, up = eye x right
    eye = np.array([math.sin(az) * math.cos(el), math.cos(az) * math.cos(el), math.sin(el)])
    right = np.array([-math.cos(az), math.sin(az), 0.0])
    up = np.cross(eye, right)
    u = x * right[0] + y * right[1]
    v = x * up[0] + y * up[1] + zz * up[2]
    depth = x * eye[0] + y * eye[1] + zz * eye[2]
    norm = np.sqrt(nx * nx + ny * ny + 1.0)
    light = eye + np.array([0.3, 0.3, 0.6])
    light /= np.linalg.norm(light)
    shade = np.clip((nx * light[0] + ny * light[1] + light[2]) / norm, 0, 1) * 0.7 + 0.3
    rgb = np.clip(base * shade[:, None], 0, 255).astype(np.uint8)
    span = max(np.ptp(u), np.ptp(v), 1e-6)
    scale = 0.92 * zoom * min(w_out, h_out) / span
    spacing = cell * scale  # screen pixels between neighbouring cells
    r = max(1.0, spacing / 0.8)  # neighbouring cells land on touching buffer pixels
    wb, hb = max(2, int(w_out / r)), max(2, int(h_out / r))
    sb = scale / r
    if axes is not None:

        def to_screen(p: tuple[float, float, float]) -> tuple[float, float]:
            """Output pixel of a point of the frame (mm, the height exaggerated)."""
            q = np.subtract(p, mean)
            pu, pv = q @ right, q @ up
            return ((pu * sb + wb / 2 + 0.5) * w_out / wb - 0.5,
                    (hb / 2 - pv * sb + 0.5) * h_out / hb - 0.5)

        axes.clear()
        axes.update(axes_geometry(to_screen, lows, spans, scale / r * w_out / wb,
                                  exaggeration, (w_out, h_out)))
    px = np.rint(u * sb + wb / 2).astype(np.int64)
    py = np.rint(hb / 2 - v * sb).astype(np.int64)
    inside = (px >= 0) & (px < wb) & (py >= 0) & (py < hb)
    px, py, depth, rgb = px[inside], py[inside], depth[inside], rgb[inside]
    flat = py * wb + px
    order = np.lexsort((depth, flat))  # by pixel, then from far to near
    last = np.ones(len(order), bool)
    last[:-1] = flat[order][1:] != flat[order][:-1]
    keep = order[last]
    buf = np.empty((hb, wb, 3), np.uint8)
    buf[:] = BACKGROUND
    filled = np.zeros((hb, wb), np.uint8)
    buf.reshape(-1, 3)[flat[keep]] = rgb[keep]
    filled.reshape(-1)[flat[keep]] = 255
    holes = (cv2.dilate(filled, np.ones((3, 3), np.uint8)) > 0) & (filled == 0)
    if holes.any():
        grown = cv2.dilate(buf, np.ones((3, 3), np.uint8))
        buf[holes] = grown[holes]
    return cv2.resize(buf, (w_out, h_out), interpolation=cv2.INTER_LINEAR)


def nice_length(mm: float) -> float:
    """The round length (1, 2 or 5 times a power of ten, mm) at most ``mm``."""
    if not mm > 0:
        return 1.0
    e = 10.0 ** math.floor(math.log10(mm))
    return max(k * e for k in (1.0, 2.0, 5.0) if k * e <= mm)


AXIS_COLOURS = {"x": (255, 80, 80), "y": (80, 220, 80), "z": (90, 150, 255)}
#: what the axes are (the right-handed export frame)
FRAME_TEXT = "x across the rail, y = -rail y (up the map), z up; mm"


def axes_geometry(to_screen, lows, spans, px_per_mm: float, exaggeration: float,
                  size: tuple[int, int]) -> dict:
    """Where the axes of the right-handed export frame (x across the rail, y = -rail y, z up)
    and a scale bar go on an image of ``size`` (W, H): ``to_screen`` maps a frame point (mm,
    height exaggerated) to the image, ``lows`` is the surface's lowest corner, ``spans`` its
    extent in x and y (mm), ``px_per_mm`` the image's scale (orthographic: the same for every
    length parallel to the screen).

    Returns ``{"origin": (u, v), "ends": {"x"|"y"|"z": (u, v)}, "labels": {axis: text},
    "length_mm", "scale_bar": {"mm", "px", "at": (u, v)}, "frame": text}``."""
    length = nice_length(0.3 * max(spans))
    x0, y0, z0 = lows
    origin = to_screen((x0, y0, z0))
    ends = {
        "x": to_screen((x0 + length, y0, z0)),
        "y": to_screen((x0, y0 + length, z0)),
        "z": to_screen((x0, y0, z0 + length * exaggeration)),
    }
    num = f"{length:g} mm"
    labels = {"x": f"x {num}", "y": f"y {num}",
              "z": f"z {num}" + (f" (x{exaggeration:g})" if exaggeration != 1 else "")}
    w, h = size
    bar_mm = nice_length(0.25 * w / max(px_per_mm, 1e-9))
    return {
        "origin": origin,
        "ends": ends,
        "labels": labels,
        "length_mm": length,
        "scale_bar": {"mm": bar_mm, "px": bar_mm * px_per_mm, "at": (16.0, h - 18.0)},
        "frame": FRAME_TEXT,
    }


def opengl_status() -> str:
    """Empty when pyqtgraph's OpenGL widgets can be used, else the reason they cannot."""
    try:
        import pyqtgraph.opengl  # noqa: F401
    except Exception as exc:  # noqa: BLE001 - any failure means no GL
        return f"OpenGL 3D is not available ({exc.__class__.__name__}: {exc})"
    from PySide6.QtGui import QGuiApplication

    if QGuiApplication.platformName() in ("offscreen", "minimal"):
        return "OpenGL 3D is not available on this display"
    return ""


class AxesOverlay(QWidget):
    """Draws the axes (x red, y green, z blue, labelled in mm), the frame's description and
    a scale bar over the rendered image centred in its parent (mouse events go through)."""

    def __init__(self, parent: QWidget) -> None:
        super().__init__(parent)
        self.setAttribute(Qt.WidgetAttribute.WA_TransparentForMouseEvents)
        self.axes: dict = {}
        self.image_size = (0, 0)

    def set_axes(self, axes: dict, image_size: tuple[int, int]) -> None:
        self.axes, self.image_size = axes, image_size
        self.resize(self.parentWidget().size())
        self.update()

    def offset(self) -> QPointF:
        """Where the image's top left corner is in this widget (the image is centred)."""
        w, h = self.image_size
        return QPointF((self.width() - w) / 2, (self.height() - h) / 2)

    def to_widget(self, p: tuple[float, float]) -> QPointF:
        return QPointF(p[0], p[1]) + self.offset()

    def paintEvent(self, _ev) -> None:  # noqa: N802 - Qt override
        from PySide6.QtGui import QColor, QPainter, QPen

        a = self.axes
        if not a:
            return
        qp = QPainter(self)
        qp.setRenderHint(QPainter.RenderHint.Antialiasing)
        shadow = QColor(0, 0, 0, 200)

        def text(at: QPointF, words: str, colour: QColor) -> None:
            """Text with a dark shadow, readable over a light surface too."""
            qp.setPen(QPen(shadow, 1))
            for d in ((1, 1), (-1, 1), (1, -1), (-1, -1)):
                qp.drawText(at + QPointF(*d), words)
            qp.setPen(QPen(colour, 1))
            qp.drawText(at, words)

        o = self.to_widget(a["origin"])
        for name, end in a["ends"].items():
            colour = QColor(*AXIS_COLOURS[name])
            qp.setPen(QPen(colour, 2))
            e = self.to_widget(end)
            qp.drawLine(o, e)
            text(e + QPointF(4, -4), a["labels"][name], colour)
        white = QColor(235, 235, 235)
        qp.setPen(QPen(white, 3))
        bar = a["scale_bar"]
        at = self.to_widget(bar["at"])
        qp.drawLine(at, at + QPointF(bar["px"], 0))
        text(at + QPointF(0, -6), f"{bar['mm']:g} mm", white)
        text(self.to_widget((8.0, 16.0)), a["frame"], white)
        qp.end()


class Surface3DWindow(QWidget):
    """A window with the software-rendered 3D view; ``rendered`` fires with each new frame."""

    rendered = Signal()

    def __init__(
        self,
        height: np.ndarray,
        spec: GridSpec,
        colours: np.ndarray | None,
        title: str = "3D view",
        parent: QWidget | None = None,
    ) -> None:
        super().__init__(parent, Qt.WindowType.Window)
        self.setWindowTitle(title)
        self.resize(900, 700)
        self.height_mm, self.spec, self.colours = height, spec, colours
        # from below the map's bottom edge, a little to the left: the map as on screen, tilted
        self.azimuth, self.elevation, self.zoom = 200.0, 40.0, 1.0
        self.frames = 0
        v = QVBoxLayout(self)
        status = opengl_status()
        self.message = QLabel(
            (status + ". " if status else "") + "Software rendering: drag to rotate, wheel to zoom."
        )
        self.message.setWordWrap(True)
        v.addWidget(self.message)
        self.view = QLabel()
        self.view.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.view.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Ignored)
        self.view.setMinimumSize(320, 240)
        self.view.setStyleSheet("background: rgb(40, 40, 48)")
        v.addWidget(self.view, 1)
        # the export frame's axes and a scale bar, drawn over the surface
        self.axes: dict = {}
        self.overlay = AxesOverlay(self.view)
        row = QHBoxLayout()
        row.addWidget(QLabel("Vertical exaggeration"))
        self.exaggeration = QDoubleSpinBox()
        self.exaggeration.setRange(0.1, 20)
        self.exaggeration.setValue(1.0)
        self.exaggeration.setSuffix(" x")
        self.exaggeration.valueChanged.connect(lambda _v: self.request())
        row.addWidget(self.exaggeration)
        row.addStretch(1)
        v.addLayout(row)
        self.worker = LatestOnly(self, "render-3d")
        self.worker.finished.connect(self._show)
        self._drag: QPointF | None = None
        self.view.installEventFilter(self)

    def request(self) -> None:
        size = (max(64, self.view.width()), max(64, self.view.height()))
        args = (
            self.height_mm,
            self.spec,
            self.colours,
            self.azimuth,
            self.elevation,
            size,
            self.exaggeration.value(),
            self.zoom,
        )
        def task(_p, _c):
            axes: dict = {}
            return render_surface(*args, axes=axes), axes

        self.worker.submit(task)

    def _show(self, result) -> None:
        rgb, self.axes = result
        self.overlay.set_axes(self.axes, (rgb.shape[1], rgb.shape[0]))
        self._rgb = np.ascontiguousarray(rgb)
        h, w = rgb.shape[:2]
        img = QImage(self._rgb.data, w, h, 3 * w, QImage.Format.Format_RGB888)
        self.view.setPixmap(QPixmap.fromImage(img.copy()))
        self.frames += 1
        self.rendered.emit()

    def rotate(self, d_azimuth: float, d_elevation: float) -> None:
        self.azimuth = (self.azimuth + d_azimuth) % 360
        self.elevation = min(90.0, max(5.0, self.elevation + d_elevation))
        self.request()

    def eventFilter(self, obj, ev) -> bool:  # noqa: N802 - Qt override
        from PySide6.QtCore import QEvent

        t = ev.type()
        if t == QEvent.Type.MouseButtonPress:
            self._drag = ev.position()
            return True
        if t == QEvent.Type.MouseMove and self._drag is not None:
            d = ev.position() - self._drag
            self._drag = ev.position()
            self.rotate(0.4 * d.x(), 0.3 * d.y())
            return True
        if t == QEvent.Type.MouseButtonRelease:
            self._drag = None
            return True
        if t == QEvent.Type.Wheel:
            self.zoom = min(
                20.0, max(0.2, self.zoom * (1.15 if ev.angleDelta().y() > 0 else 1 / 1.15))
            )
            self.request()
            return True
        if t == QEvent.Type.Resize:
            self.overlay.resize(self.view.size())
            self.request()
        return super().eventFilter(obj, ev)

    def showEvent(self, ev) -> None:  # noqa: N802 - Qt override
        super().showEvent(ev)
        self.request()

    def closeEvent(self, ev) -> None:  # noqa: N802 - Qt override
        self.worker.shutdown()
        super().closeEvent(ev)

    def shutdown(self) -> None:
        self.worker.shutdown()
