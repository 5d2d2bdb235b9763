"""A 3D view of the coloured surface.

Where OpenGL works (PyOpenGL installed, a display with OpenGL >= 2.1: :func:`opengl_check`
creates a context to make sure), the window shows pyqtgraph's GLViewWidget: the surface,
decimated to a few hundred thousand vertices, as a shaded triangle mesh in the exported files'
frame (:func:`surface_mesh`, Qt-free), with the frame's axes and a millimetre grid; dragging
rotates, the wheel zooms. Remote desktops, virtual machines and the offscreen test platform
often lack OpenGL: there the surface is rendered in software - rotated, shaded and splatted into
a depth buffer (:func:`render_surface`, Qt-free) in a worker thread - and the window says why in
a plain sentence (the technical reason in its tooltip).
"""

from __future__ import annotations

import math
from typing import Any

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


#: Qt platforms without OpenGL windows
NO_GL_PLATFORMS = ("offscreen", "minimal", "vnc")
#: ``IMPRESS_3D_RENDERER=software`` forces the software view (a GL driver that misbehaves)
RENDERER_ENV = "IMPRESS_3D_RENDERER"
_gl_checked: dict[str, tuple[str, str]] = {}


def import_failure(exc: BaseException) -> tuple[str, str]:
    """Why pyqtgraph's OpenGL widgets cannot be imported, as ``(plain sentence, detail)``."""
    detail = f"{exc.__class__.__name__}: {exc}"
    name = getattr(exc, "name", None) or ""
    if isinstance(exc, ModuleNotFoundError) and name.split(".")[0] == "OpenGL":
        return "The OpenGL package for Python (PyOpenGL) is not installed.", detail
    return "The computer's OpenGL library could not be loaded.", detail


def _probe_context() -> tuple[str, str]:
    """Create an OpenGL context on an offscreen surface of the current display and make it
    current: ``("", "OpenGL <version>, <renderer>")`` when that works with OpenGL >= 2.1 (or
    OpenGL ES), else ``(plain sentence, detail)``."""
    from PySide6.QtGui import QOffscreenSurface, QOpenGLContext, QSurfaceFormat

    ctx = QOpenGLContext()
    ctx.setFormat(QSurfaceFormat.defaultFormat())
    if not ctx.create():
        return "OpenGL could not be started on this display.", "QOpenGLContext.create() failed"
    surface = QOffscreenSurface()
    surface.setFormat(ctx.format())
    surface.create()
    try:
        if not surface.isValid():
            return ("OpenGL could not be started on this display.",
                    "QOffscreenSurface.create() failed")
        if not ctx.makeCurrent(surface):
            return ("OpenGL could not be started on this display.",
                    "QOpenGLContext.makeCurrent() failed")
        try:
            from OpenGL import GL

            words = [GL.glGetString(GL.GL_VERSION), GL.glGetString(GL.GL_RENDERER)]
            about = ", ".join(w.decode(errors="replace") for w in words if w)
        except Exception as exc:  # noqa: BLE001 - any failure here means no usable GL
            ctx.doneCurrent()
            return "OpenGL could not be started on this display.", f"glGetString: {exc!r}"
        version = ctx.format().version()
        es = ctx.isOpenGLES()
        ctx.doneCurrent()
    finally:
        surface.destroy()
    if not es and tuple(version) < (2, 1):
        return (f"This display's OpenGL ({version[0]}.{version[1]}) is older than the 2.1 "
                "the 3D view needs.", about)
    return "", "OpenGL " + about


def opengl_check() -> tuple[str, str]:
    """Whether pyqtgraph's OpenGL 3D view can be used here: ``("", detail)`` when it can,
    else ``(reason, detail)``: a plain sentence for the user and the technical reason (the
    exception, the failing call) for a tooltip. Checked once per Qt platform: the platform
    has OpenGL windows, ``pyqtgraph.opengl`` (PyOpenGL) imports, and a context can be created
    and made current with OpenGL >= 2.1."""
    import os

    from PySide6.QtGui import QGuiApplication

    platform = QGuiApplication.platformName()
    if os.environ.get(RENDERER_ENV, "").strip().lower() == "software":
        return "OpenGL is switched off.", f"{RENDERER_ENV}=software"
    if platform in NO_GL_PLATFORMS:
        return "This display has no OpenGL.", f"Qt platform {platform!r} has no OpenGL windows"
    if platform not in _gl_checked:
        try:
            import pyqtgraph.opengl  # noqa: F401
        except Exception as exc:  # noqa: BLE001 - any failure means no GL
            _gl_checked[platform] = import_failure(exc)
        else:
            try:
                _gl_checked[platform] = _probe_context()
            except Exception as exc:  # noqa: BLE001
                _gl_checked[platform] = ("OpenGL could not be started on this display.",
                                         f"{exc.__class__.__name__}: {exc}")
    return _gl_checked[platform]


def opengl_status() -> str:
    """Empty when pyqtgraph's OpenGL widgets can be used, else the reason they cannot (a plain
    sentence; :func:`opengl_check` gives the technical detail too)."""
    return opengl_check()[0]


#: the light of the OpenGL view's shading, fixed to the surface: from the top left of the map
#: (north-west, as the hillshade's default) 50 degrees above the horizon
GL_LIGHT = np.array([-0.4545, 0.4545, 0.766])


def surface_mesh(
    height: np.ndarray,
    spec: GridSpec,
    colours: np.ndarray | None,
    exaggeration: float = 1.0,
    max_points: int = 300_000,
) -> dict:
    """The surface, decimated to at most about ``max_points`` vertices, as a triangle mesh in
    the exported files' right-handed frame: x = the grid's x (across the rail), y = minus the
    grid's y (up the map), z = height times ``exaggeration``, in mm; never mirrored. Cells
    without a height are holes. Each vertex is coloured by ``colours`` (``(H, W, 3)`` uint8,
    the texture or the map's colours) or, without them, by its height, and Lambert-shaded
    under :data:`GL_LIGHT`.

    Returns ``{"vertexes": (N, 3) float32, "faces": (M, 3) uint32, "colors": (N, 4) float32,
    "lows": (x, y, z) of the lowest corner, "spans": (x, y, z) extents, "centre": (x, y, z),
    "cell_mm"}``; triangles are wound anticlockwise seen from above (normals up)."""
    step = max(1, int(math.ceil(math.sqrt(height.size / max_points))))
    z = np.asarray(height[::step, ::step], np.float32)
    ok = np.isfinite(z)
    cell = spec.pixel_mm * step
    rows, cols = z.shape
    xs = spec.x0_mm + cell * np.arange(cols)
    ys = -(spec.y0_mm + cell * np.arange(rows))  # up the map
    r, c = np.nonzero(ok)
    zz = z[ok] * np.float32(exaggeration)
    vertexes = np.column_stack([xs[c], ys[r], zz]).astype(np.float32)
    index = np.full(z.shape, -1, np.int64)
    index[ok] = np.arange(r.size)
    a, b = index[:-1, :-1], index[:-1, 1:]  # a cell, its right neighbour,
    d, e = index[1:, :-1], index[1:, 1:]  # the cell below it (down the map) and its right one
    tris = []
    for t in ((a, d, b), (b, d, e)):  # anticlockwise from above in (x, up the map)
        good = (t[0] >= 0) & (t[1] >= 0) & (t[2] >= 0)
        tris.append(np.column_stack([q[good] for q in t]))
    faces = np.concatenate(tris).astype(np.uint32)
    # colours: the texture or the map's, else the height through a colour map
    if colours is not None:
        base = np.asarray(colours[::step, ::step, :3])[ok].astype(np.float32) / 255.0
    else:
        import pyqtgraph as pg

        lut = pg.colormap.get("viridis").getLookupTable(nPts=256).astype(np.float32) / 255.0
        lo, hi = (np.percentile(zz, (1, 99)) if zz.size else (0.0, 1.0))
        k = np.clip((zz - lo) / max(hi - lo, 1e-6) * 255, 0, 255).astype(np.int64)
        base = lut[k, :3]
    filled = np.where(ok, z, np.nanmean(z) if ok.any() else 0.0) * exaggeration
    g_row = g_col = np.zeros_like(filled)
    if min(z.shape) > 1:
        grads = np.gradient(filled, cell)
        g_row, g_col = grads[0], grads[1]
    nx, ny = -g_col[ok], g_row[ok]  # (x, up the map): the grid's rows run down the map
    shade = (nx * GL_LIGHT[0] + ny * GL_LIGHT[1] + GL_LIGHT[2]) / np.sqrt(nx * nx + ny * ny + 1)
    shade = 0.35 + 0.65 * np.clip(shade, 0.0, 1.0)
    colors = np.ones((r.size, 4), np.float32)
    colors[:, :3] = base * shade[:, None]
    if r.size:
        lows = tuple(float(v) for v in vertexes.min(axis=0))
        highs = vertexes.max(axis=0)
    else:
        lows, highs = (0.0, 0.0, 0.0), np.zeros(3)
    spans = tuple(float(h - lo) for h, lo in zip(highs, lows))
    centre = tuple(float(lo + s / 2) for lo, s in zip(lows, spans))
    return {"vertexes": vertexes, "faces": faces, "colors": colors, "lows": lows,
            "spans": spans, "centre": centre, "cell_mm": cell}


def to_gl_azimuth(azimuth_deg: float) -> float:
    """pyqtgraph's camera azimuth (anticlockwise from +x) of this module's azimuth (where the
    eye stands, clockwise from the top of the map, +y of the frame)."""
    return (90.0 - azimuth_deg) % 360.0


def from_gl_azimuth(gl_azimuth_deg: float) -> float:
    return (90.0 - gl_azimuth_deg) % 360.0


_gl_view_class = None


def gl_view_class():
    """pyqtgraph's GLViewWidget with a ``painted`` signal after each frame (imported on first
    use: pyqtgraph.opengl needs PyOpenGL)."""
    global _gl_view_class
    if _gl_view_class is None:
        import pyqtgraph.opengl as gl
        from pyqtgraph.opengl import shaders
        from pyqtgraph.opengl.items.GLLinePlotItem import GLLinePlotItem

        class SurfaceGLView(gl.GLViewWidget):
            """pyqtgraph caches its compiled shader programs globally, valid only in the GL
            context that compiled them: a second window (its own context) would draw
            nothing. Each view keeps its own programs and puts them in place while it paints."""

            painted = Signal()

            def __init__(self, *args, **kwargs) -> None:
                super().__init__(*args, **kwargs)
                self._programs: dict = {}

            def paint(self, **kwargs) -> None:
                programs = list(shaders.ShaderProgram.names.values())
                for p in programs:
                    p.prog = self._programs.get(id(p))
                GLLinePlotItem._shaderProgram = self._programs.get("lines")
                try:
                    super().paint(**kwargs)
                finally:
                    for p in programs:
                        self._programs[id(p)], p.prog = p.prog, None
                    self._programs["lines"] = GLLinePlotItem._shaderProgram
                    GLLinePlotItem._shaderProgram = None

            def paintGL(self) -> None:  # noqa: N802 - Qt override
                super().paintGL()
                self.painted.emit()

        _gl_view_class = SurfaceGLView
    return _gl_view_class


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
    """A window with the 3D view: pyqtgraph's OpenGL view when :func:`opengl_check` finds
    OpenGL usable, else the software-rendered view; the first line says which and why (the
    technical reason in its tooltip). ``rendered`` fires with each new frame; ``renderer`` is
    ``"opengl"`` or ``"software"`` (``renderer="software"`` forces the software view)."""

    rendered = Signal()

    def __init__(
        self,
        height: np.ndarray,
        spec: GridSpec,
        colours: np.ndarray | None,
        title: str = "3D view",
        parent: QWidget | None = None,
        renderer: str = "auto",
    ) -> None:
        super().__init__(parent, Qt.WindowType.Window)
        self.setWindowTitle(title)
        self.resize(900, 700)
        self.height_mm, self.spec, self.colours = height, spec, colours
        # from below the map's bottom edge, a little to the left: the map as on screen, tilted
        self.azimuth, self.elevation, self.zoom = 200.0, 40.0, 1.0
        self.frames = 0
        self.worker: Any = None  # the software view's LatestOnly
        self.gl: Any = None  # the OpenGL view (a GLViewWidget)
        self.view: Any = None  # the widget showing the surface (a QLabel or self.gl)
        self.mesh: dict = {}
        self._placed = False
        v = QVBoxLayout(self)
        if renderer == "software":
            reason, detail = "", ""
        else:
            reason, detail = opengl_check()
        self.renderer = "software" if renderer == "software" or reason else "opengl"
        self.message = QLabel()
        self.message.setWordWrap(True)
        self.message.setToolTip(detail)
        v.addWidget(self.message)
        if self.renderer == "opengl":
            self.message.setText("OpenGL rendering: drag to rotate, wheel to zoom, "
                                 "Ctrl+drag or the middle button to pan.")
            self._build_gl(v)
        else:
            self.message.setText((reason + " " if reason else "")
                                 + "Software rendering: drag to rotate, wheel to zoom.")
            self._build_software(v)
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
        if self.renderer == "opengl":
            self._update_gl_scene()

    # ----- the software view -------------------------------------------------------------------
    def _build_software(self, v: QVBoxLayout) -> None:
        self.view = QLabel()
        self.view.setAlignment(Qt.AlignmentFlag.AlignCenter)
        self.view.setSizePolicy(QSizePolicy.Policy.Ignored, QSizePolicy.Policy.Ignored)
        self.view.setMinimumSize(320, 240)
        self.view.setStyleSheet("background: rgb(40, 40, 48)")
        v.addWidget(self.view, 1)
        # the export frame's axes and a scale bar, drawn over the surface
        self.axes: dict = {}
        self.overlay = AxesOverlay(self.view)
        self.worker = LatestOnly(self, "render-3d")
        self.worker.finished.connect(self._show)
        self._drag: QPointF | None = None
        self.view.installEventFilter(self)

    # ----- the OpenGL view ---------------------------------------------------------------------
    def _build_gl(self, v: QVBoxLayout) -> None:
        import pyqtgraph.opengl as gl

        self.gl = gl_view_class()(self)
        self.gl.setMinimumSize(320, 240)
        self.gl.setBackgroundColor(BACKGROUND)
        self.gl.opts["fov"] = 40.0  # degrees: less perspective distortion than 60
        self.gl.painted.connect(self._painted)
        self.gl.installEventFilter(self)
        self._placed_by_user = False
        self.view = self.gl
        v.addWidget(self.gl, 1)
        # what the axes and the grid are: the scale of a perspective view is the grid
        self.legend = QLabel()
        self.legend.setWordWrap(True)
        v.addWidget(self.legend)
        self.surface_item = gl.GLMeshItem(smooth=True, computeNormals=False, shader=None,
                                          glOptions="opaque")
        self.grid_item = gl.GLLinePlotItem(mode="lines", width=1.0, antialias=True,
                                           glOptions="translucent")
        from OpenGL import GL

        # the axes over everything, as in the software view (they start at the surface's lowest
        # corner, often under the surface)
        self.axes_item = gl.GLLinePlotItem(
            mode="lines", width=3.0, antialias=False,
            glOptions={GL.GL_DEPTH_TEST: False, GL.GL_BLEND: False, GL.GL_CULL_FACE: False})
        from PySide6.QtGui import QColor, QFont

        font = QFont()
        font.setPointSize(10)
        self.axis_labels = {
            k: gl.GLTextItem(text="", color=QColor(*AXIS_COLOURS[k]), font=font) for k in "xyz"
        }
        for item in (self.grid_item, self.surface_item, self.axes_item,
                     *self.axis_labels.values()):
            self.gl.addItem(item)

    def _update_gl_scene(self) -> None:
        """(Re)build the mesh, the grid and the axes at the current exaggeration."""
        e = self.exaggeration.value()
        m = surface_mesh(self.height_mm, self.spec, self.colours, e)
        self.mesh = m
        if len(m["faces"]):
            self.surface_item.setMeshData(vertexes=m["vertexes"], faces=m["faces"],
                                          vertexColors=m["colors"])
        self.surface_item.setVisible(bool(len(m["faces"])))  # no heights: nothing to draw
        (x0, y0, z0), (sx, sy, _sz) = m["lows"], m["spans"]
        length = nice_length(0.3 * max(sx, sy))
        spacing = nice_length(max(sx, sy) / 8)
        # the grid: a floor of ``spacing`` squares a little under the surface, lined up with
        # the axes' origin and one square wider on each side, so that it shows around it
        floor = z0 - 0.03 * max(sx, sy)
        gx = x0 + spacing * np.arange(-1, int(math.ceil(sx / spacing - 1e-6)) + 2)
        gy = y0 + spacing * np.arange(-1, int(math.ceil(sy / spacing - 1e-6)) + 2)
        lines = ([((x, gy[0], floor), (x, gy[-1], floor)) for x in gx]
                 + [((gx[0], y, floor), (gx[-1], y, floor)) for y in gy])
        self.grid_item.setData(pos=np.asarray(lines, np.float32).reshape(-1, 3),
                               color=(0.85, 0.85, 0.85, 0.45))
        ends = {"x": (x0 + length, y0, z0), "y": (x0, y0 + length, z0),
                "z": (x0, y0, z0 + length * e)}
        pos, col = [], []
        for k, end in ends.items():
            rgba = [c / 255.0 for c in AXIS_COLOURS[k]] + [1.0]
            pos += [(x0, y0, z0), end]
            col += [rgba, rgba]
        self.axes_item.setData(pos=np.asarray(pos, np.float32), color=np.asarray(col, np.float32))
        num = f"{length:g} mm"
        labels = {"x": f"x {num}", "y": f"y {num}",
                  "z": f"z {num}" + (f" (x{e:g})" if e != 1 else "")}
        for k, item in self.axis_labels.items():
            item.setData(pos=np.asarray(ends[k], float), text=labels[k])
        self.axes = {"origin": (x0, y0, z0), "ends": ends, "labels": labels,
                     "length_mm": length, "grid_mm": spacing, "frame": FRAME_TEXT}
        self.legend.setText(f"Axes x (red), y (green), z (blue): {num} each; grid squares "
                            f"{spacing:g} mm. Frame: {FRAME_TEXT}.")
        if not self._placed or not self._placed_by_user:
            self._placed = True
            self._place_camera()  # the whole surface, also at a new exaggeration
        self.gl.update()

    def _place_camera(self) -> None:
        from PySide6.QtGui import QVector3D

        m = self.mesh
        sx, sy, sz = m["spans"]
        # the whole surface (its bounding sphere) in the narrower side of the field of view
        # (pyqtgraph's fov is the horizontal one)
        radius = 0.5 * max(math.sqrt(sx * sx + sy * sy + sz * sz), 1.0)
        w, h = self.gl.width(), self.gl.height()
        aspect = h / w if w > 50 and h > 50 else 0.75
        half = math.atan(math.tan(math.radians(self.gl.opts["fov"]) / 2) * min(1.0, aspect))
        fit = radius / math.sin(half)
        self.gl.opts["center"] = QVector3D(*m["centre"])
        self.gl.setCameraPosition(distance=1.05 * fit / self.zoom, elevation=self.elevation,
                                  azimuth=to_gl_azimuth(self.azimuth))

    def _painted(self) -> None:
        self.azimuth = from_gl_azimuth(self.gl.opts["azimuth"])
        self.elevation = float(self.gl.opts["elevation"])
        self.frames += 1
        self.rendered.emit()

    def look(self, azimuth: float | None = None, elevation: float | None = None,
             zoom: float | None = None) -> None:
        """Set the view (azimuth clockwise from the top of the map, elevation above the
        horizon, zoom 1 = the whole surface) and draw it again."""
        if azimuth is not None:
            self.azimuth = azimuth % 360
        if elevation is not None:
            self.elevation = elevation
        if zoom is not None:
            self.zoom = zoom
        if self.renderer == "opengl":
            self._place_camera()
            self.gl.update()
        else:
            self.request()

    def request(self) -> None:
        if self.renderer == "opengl":
            self._update_gl_scene()
            return
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
        if self.renderer == "opengl":
            self.look(self.azimuth + d_azimuth, min(90.0, max(-90.0,
                                                              self.elevation + d_elevation)))
            return
        self.azimuth = (self.azimuth + d_azimuth) % 360
        self.elevation = min(90.0, max(5.0, self.elevation + d_elevation))
        self.request()

    def eventFilter(self, obj, ev) -> bool:  # noqa: N802 - Qt override
        from PySide6.QtCore import QEvent

        t = ev.type()
        if self.renderer == "opengl":  # GLViewWidget turns and zooms by itself
            if t in (QEvent.Type.MouseButtonPress, QEvent.Type.Wheel, QEvent.Type.KeyPress):
                self._placed_by_user = True
            elif t == QEvent.Type.Resize and not self._placed_by_user:
                self._place_camera()  # the whole surface in the new shape
            return super().eventFilter(obj, ev)
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
        if self.renderer == "software":
            self.request()

    def closeEvent(self, ev) -> None:  # noqa: N802 - Qt override
        self.shutdown()
        super().closeEvent(ev)

    def shutdown(self) -> None:
        if self.worker is not None:
            self.worker.shutdown()
