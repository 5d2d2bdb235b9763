"""What the viewer shows of the open reconstruction: the layer, its colour range and the hill
shading.

:class:`ShownReconstruction` holds the reconstruction and what is derived from it (levelling
plane, levelled heights, colour ranges typed or automatic, the coloured contribution map, the
last hill shading); :class:`LayerDisplay` draws the chosen layer on the map from it, follows the
display panel and computes the hill shading in the background. Every number comes from
:mod:`impress_gui.core.measure.readings`.
"""

from __future__ import annotations

import numpy as np
from PySide6.QtCore import QObject, Signal

from impress_gui.core.formats.writers import contribution_png
from impress_gui.core.measure import readings as M
from impress_gui.ui.viewer.image import Footprint, auto_levels, target_footprint_mm
from impress_gui.ui.viewer.map import MapView
from impress_gui.ui.viewer.panels import DisplayPanel
from impress_gui.ui.worker import LatestOnly

HEIGHT_LAYERS = ("fused", "green", "red")
SCALAR_LAYERS = HEIGHT_LAYERS + ("difference",)


def core_azimuth(screen_azimuth_deg: float) -> float:
    """The light's azimuth for :func:`impress_gui.core.measure.readings.hillshade` (clockwise from +y
    in the grid) from the one the user sets: clockwise from the top of the screen. The map
    shows +y downwards, so the top of the screen is -y: 315 (upper left, the usual light of
    a relief map, under which a hollow looks hollow) is 225 in the grid."""
    return (180.0 - screen_azimuth_deg) % 360.0


class ShownReconstruction:
    """The open reconstruction (``data``) and what is derived from it: the levelling
    ``plane`` and the levelled heights, the colour ranges (typed or dragged by the user, per
    layer, kept through zoom, layer changes and levelling until Auto; automatic, per layer and
    levelling), the calibration target's place (``target_mm``, left out of automatic ranges),
    the coloured contribution map and the last hill shading (``(params, rgb)``)."""

    def __init__(self) -> None:
        self.data: M.ReconData | None = None
        self.plane: M.Plane | None = None
        self.contribution_rgb: np.ndarray | None = None
        self.target_mm: Footprint | None = None
        self.hillshade: tuple[tuple, np.ndarray] | None = None
        self._levelled: dict[str, np.ndarray] = {}
        self._ranges: dict[str, tuple[float, float]] = {}
        self._auto: dict[str, tuple[float, float]] = {}

    def reset(
        self,
        data: M.ReconData | None,
        contribution_rgb: np.ndarray | None = None,
        auto: dict[str, tuple[float, float]] | None = None,
    ) -> None:
        """Show ``data`` (``contribution_rgb`` is computed here when not given): no levelling,
        no typed range, the ``auto`` ranges per layer."""
        self.data = data
        self.plane = None
        self._levelled.clear()
        self._ranges.clear()
        self._auto = dict(auto or {})
        self.hillshade = None
        self.contribution_rgb = contribution_rgb
        self.target_mm = None if data is None else target_footprint_mm(data.metadata, data.folder)
        if data is not None and contribution_rgb is None and "contribution" in data.layers:
            self.contribution_rgb = contribution_png(data.layers["contribution"])

    # ----- heights ------------------------------------------------------------------------------
    def height_key(self, shown: str) -> str:
        """The height layer measured on when ``shown`` is on the map (the fused map for layers
        that are not heights)."""
        d = self.data
        return shown if shown in HEIGHT_LAYERS and d and shown in d.layers else "fused"

    def height(self, key: str) -> np.ndarray:
        """The full-resolution heights of layer ``key``, relative to the levelling plane when
        there is one."""
        if self.plane is None:
            return self.data.layers[key]
        if key not in self._levelled:
            self._levelled[key] = M.levelled(self.data.layers[key], self.data.spec, self.plane)
        return self._levelled[key]

    def set_plane(
        self, plane: M.Plane, key: str, levelled: np.ndarray, auto: tuple[float, float]
    ) -> None:
        """Level by ``plane``: layer ``key`` levelled is ``levelled`` with the automatic range
        ``auto``; the other levelled layers' automatic ranges are recomputed when shown (a
        range the user typed stays)."""
        self.plane = plane
        self._levelled = {key: levelled}
        for k in [k for k in self._auto if k.endswith("/levelled")]:
            del self._auto[k]
        self._auto[f"{key}/levelled"] = auto

    def clear_plane(self) -> None:
        self.plane = None
        self._levelled.clear()

    def plane_state(self) -> tuple:
        """The levelling as it is (plane, levelled heights, their automatic ranges), for
        :meth:`restore_plane` (undo and redo)."""
        autos = {k: v for k, v in self._auto.items() if k.endswith("/levelled")}
        return self.plane, dict(self._levelled), autos

    def restore_plane(self, state: tuple) -> None:
        plane, levelled, autos = state
        self.plane = plane
        self._levelled = dict(levelled)
        for k in [k for k in self._auto if k.endswith("/levelled")]:
            del self._auto[k]
        self._auto.update(autos)

    # ----- colour ranges ----------------------------------------------------------------------
    def _range_key(self, key: str) -> str:
        return f"{key}/levelled" if self.plane is not None and key != "difference" else key

    def auto_levels(self, key: str, arr: np.ndarray) -> tuple[float, float]:
        """The automatic range of a layer (robust percentiles of the evidence area, the
        calibration target left out when its place is known), computed once per layer and
        levelling."""
        rk = self._range_key(key)
        if rk not in self._auto:
            self._auto[rk] = auto_levels(arr, self.data.spec, self.target_mm)
        return self._auto[rk]

    def typed_range(self, key: str) -> tuple[float, float] | None:
        """The colour range the user typed or dragged for a layer (None: automatic)."""
        return self._ranges.get(key)

    def set_typed_range(self, key: str, lo: float, hi: float) -> None:
        self._ranges[key] = (lo, hi)

    def forget_range(self, key: str) -> None:
        """Back to the automatic range for layer ``key`` (recomputed when next shown)."""
        self._ranges.pop(key, None)
        self._auto.pop(self._range_key(key), None)


class LayerDisplay(QObject):
    """Draws the layer chosen in the display panel on the map, from a
    :class:`ShownReconstruction`; ``shown`` fires with the layer's key once it is on the map."""

    shown = Signal(str)
    status = Signal(str)

    def __init__(
        self,
        recon: ShownReconstruction,
        panel: DisplayPanel,
        map_view: MapView,
        parent: QObject | None = None,
    ) -> None:
        super().__init__(parent)
        self.recon = recon
        self.panel = panel
        self.map = map_view
        self.shader = LatestOnly(self, "hillshade")
        self.shader.finished.connect(self._on_hillshade)
        panel.layer_changed.connect(lambda _k: self.refresh())
        panel.cmap_changed.connect(lambda _c: self.refresh())
        panel.range_changed.connect(self._on_range_entered)
        panel.auto_range.connect(self.auto_range)
        panel.blend_changed.connect(map_view.set_texture_opacity)
        panel.light_changed.connect(
            lambda _a, _e: self.refresh() if panel.layer_key() == "hillshade" else None
        )
        map_view.colour_bar.sigLevelsChangeFinished.connect(self._on_bar_dragged)

    # ----- what is shown ------------------------------------------------------------------------
    def shown_key(self) -> str:
        return self.panel.layer_key()

    def layer_title(self) -> str:
        return self.panel.layer.currentText()

    def colour_map(self) -> str:
        return self.panel.cmap.currentText()

    def levels(self) -> tuple[float, float]:
        """The colour range on the map now."""
        return self.map.levels()

    def measure_key(self) -> str:
        return self.recon.height_key(self.shown_key())

    def height(self, key: str | None = None) -> np.ndarray:
        """The full-resolution heights measured on: the shown height layer (the fused map for
        other layers), relative to the levelling plane when there is one."""
        return self.recon.height(key or self.measure_key())

    def readout(self, x_mm: float, y_mm: float, radius_mm: float) -> M.Readout:
        return M.readout(self.height(), self.recon.data.spec, x_mm, y_mm, radius_mm)

    # ----- drawing ------------------------------------------------------------------------------
    def show_data(self) -> None:
        """Put the reconstruction (or nothing) on the map, fitted to the view."""
        data = self.recon.data
        self.map.set_spec(None if data is None else data.spec)
        if data is None:
            self.map.scalar.set_data(None, None)
            self.map.rgb.set_data(None, None)
            self.map.set_texture(None, 0)
            return
        self.map.set_texture(data.texture_rgb, self.panel.blend.value() / 100)
        self.refresh()

    def refresh(self) -> None:
        data = self.recon.data
        if data is None:
            return
        key = self.shown_key()
        if key in SCALAR_LAYERS and key in data.layers:
            arr = self.height(key) if key != "difference" else data.layers[key]
            levels = self.recon.typed_range(key) or self.recon.auto_levels(key, arr)
            label = "green - red (mm)" if key == "difference" else "height (mm)"
            self.map.show_scalar(arr, levels, self.colour_map(), label)
            self.panel.show_range(*levels)
        elif key == "contribution" and self.recon.contribution_rgb is not None:
            self.map.show_rgb(self.recon.contribution_rgb, nearest=True)
        elif key == "texture" and data.texture_rgb is not None:
            self.map.show_rgb(data.texture_rgb)
        elif key == "hillshade":
            self._show_hillshade()
            return
        else:
            self.status.emit(f"This reconstruction has no {key} layer")
            return
        self.shown.emit(key)

    def typed_range(self, key: str | None = None) -> tuple[float, float] | None:
        """The colour range the user typed or dragged for a layer (None: automatic)."""
        return self.recon.typed_range(key or self.shown_key())

    def auto_range(self) -> None:
        """Back to the automatic range (recomputed) for the shown layer."""
        key = self.shown_key()
        if self.recon.data is None or key not in SCALAR_LAYERS:
            return
        self.recon.forget_range(key)
        self.refresh()

    def _on_range_entered(self, lo: float, hi: float) -> None:
        key = self.shown_key()
        if hi <= lo or key not in SCALAR_LAYERS:
            return
        self.recon.set_typed_range(key, lo, hi)
        self.map.set_levels((lo, hi))

    def _on_bar_dragged(self, *_args) -> None:
        lo, hi = self.map.levels()
        self.recon.set_typed_range(self.shown_key(), lo, hi)
        self.panel.show_range(lo, hi)

    # ----- hill shading -------------------------------------------------------------------------
    def _show_hillshade(self) -> None:
        az, el = self.panel.azimuth.value(), self.panel.elevation.value()
        params = (self.measure_key(), self.recon.plane, az, el)
        done = self.recon.hillshade
        if done is not None and done[0] == params:
            self.map.show_rgb(done[1])
            self.shown.emit("hillshade")
            return
        h, p = self.height(), self.recon.data.spec.pixel_mm

        def task(_progress, _cancel):
            hs = M.hillshade(h, p, core_azimuth(az), el)
            grey = np.nan_to_num(hs * 255.0, nan=0.0).astype(np.uint8)
            return params, np.repeat(grey[..., None], 3, axis=2)

        self.shader.submit(task)

    def _on_hillshade(self, result) -> None:
        self.recon.hillshade = result
        if self.shown_key() == "hillshade" and result[0][1] is self.recon.plane:
            self.map.show_rgb(result[1])
            self.shown.emit("hillshade")

    def is_busy(self) -> bool:
        return self.shader.is_running()

    def shutdown(self) -> None:
        self.shader.shutdown()
