"""The viewer's ruler and its depth profile: a draggable ruler on the map, its readings, the
profile along it (averaging width) computed in the background on the full-resolution heights,
and the step height between two reference bands the user places on the profile. Each reading
is shown with its expanded uncertainty (about 95 %, with its k); its budget is the label's tooltip."""

from __future__ import annotations

import math

from PySide6.QtCore import QObject, Signal

from impress_gui.core.measure import readings as M
from impress_gui.core.measure import uncertainty as U
from impress_gui.ui.viewer.layers import LayerDisplay
from impress_gui.ui.viewer.map import MapView
from impress_gui.ui.viewer.panels import ToolPanel
from impress_gui.ui.viewer.profile import ProfilePlot
from impress_gui.ui.worker import LatestOnly

Point = tuple[float, float]


def _pm_mm(u: float) -> str:
    """``± 0.123 mm`` (``± -`` when not finite)."""
    return f"± {u:.3f} mm" if math.isfinite(u) else "± -"


class RulerProfile(QObject):
    """The ruler on ``map_view``, measured on ``layers``' heights with the tool panel's radius
    and width; its profile in ``plot``. ``profile_changed`` fires when the profile or the step
    between the bands changed."""

    profile_changed = Signal()

    def __init__(
        self,
        layers: LayerDisplay,
        map_view: MapView,
        plot: ProfilePlot,
        tools: ToolPanel,
        parent: QObject | None = None,
    ) -> None:
        super().__init__(parent)
        self.layers = layers
        self.map = map_view
        self.plot = plot
        self.tools = tools
        self.profile: M.Profile | None = None
        self.step: M.StepHeight | None = None
        #: where the budgets' context comes from (an UncertaintyProvider; None: no budgets)
        self.uncertainty = None
        self.step_budget: U.Budget | None = None
        self.profiler = LatestOnly(self, "profile")
        self.profiler.finished.connect(self._on_profile)
        tools.settings_changed.connect(self.update_profile)
        tools.clear_ruler_button.clicked.connect(self.clear)
        map_view.ruler_moved.connect(self.show_reading)
        map_view.ruler_finished.connect(self.update_profile)
        plot.bands_changed.connect(self.update_step)

    def set(self, p0, p1) -> None:
        self.map.set_ruler(tuple(map(float, p0)), tuple(map(float, p1)))

    def points(self) -> tuple[Point, Point] | None:
        return self.map.ruler_points()

    def clear(self) -> None:
        self.map.clear_ruler()
        self.profile = self.step = None
        self.step_budget = None
        self.tools.ruler_text.setToolTip("")
        self.tools.step_text.setToolTip("")
        self.plot.set_profile(None)
        self.plot.show_step(None)
        self.tools.ruler_text.setText("Ruler: choose Ruler and click two points")
        self.tools.step_text.setText("Step (B - A): -")
        self.tools.step_text.setStyleSheet("")

    def result(self) -> M.RulerResult | None:
        pts = self.points()
        if pts is None or self.layers.recon.data is None:
            return None
        return M.ruler(
            self.layers.height(),
            self.layers.recon.data.spec,
            pts[0],
            pts[1],
            self.tools.radius.value(),
        )

    def ruler_budgets(self, r: M.RulerResult | None = None) -> dict[str, U.Budget]:
        """The budgets of the ruler's readings (``xy``, ``3d``, ``dz``); {} without a context."""
        r = r or self.result()
        ctx = None if self.uncertainty is None or r is None else self.uncertainty.context()
        return {} if ctx is None else U.ruler_budgets(ctx, r)

    def budgets(self) -> dict[str, U.Budget]:
        """Every reading's budget as it is shown: the ruler's, and the step's when placed."""
        out = self.ruler_budgets()
        if self.step is not None and self.step_budget is not None:
            out["step"] = self.step_budget
        return out

    def show_uncertainty(self) -> None:
        """The calibration's Monte Carlo arrived: the readings again, with it."""
        if self.step is not None:
            self.update_step(emit=False)
        else:
            self.show_reading()

    def show_reading(self) -> None:
        """The ruler's length, 3D length and height difference beside it and in the panel,
        each with its expanded uncertainty U (about 95 %, with its k); the budgets in the tooltip."""
        r = self.result()
        if r is None:
            return
        b = self.ruler_budgets(r)

        def pm(key: str) -> str:
            if key in b and b[key].incomplete:
                return " (± -)"
            return f" (± {b[key].U_mm:.3f})" if key in b and math.isfinite(b[key].U_mm) else ""

        dz = "no data" if math.isnan(r.dz_mm) else f"{r.dz_mm:+.3f} mm{pm('dz')}"
        d3 = "-" if math.isnan(r.d3_mm) else f"{r.d3_mm:.3f} mm{pm('3d')}"
        text = f"xy {r.xy_mm:.3f} mm{pm('xy')} | 3D {d3} | dz {dz}"
        why = next((x.incomplete for x in b.values() if x.incomplete), "")
        self.tools.ruler_text.setText(f"Ruler: {text}" + (
            f" [no U: {why}]" if why else f" [± U, {U.k_text(b.values())}]" if b else ""))
        self.tools.ruler_text.setToolTip("\n\n".join(x.text() for x in b.values()))
        self.map.decorate_ruler(
            text,
            self.tools.width.value(),
            self.plot.placed_bands() if self.profile else None,
        )

    def update_profile(self) -> None:
        """Recompute the profile along the ruler in the background (a newer request supersedes
        an older one); ``profile_changed`` follows."""
        pts = self.points()
        if pts is None or self.layers.recon.data is None:
            return
        self.show_reading()
        h, spec = self.layers.height(), self.layers.recon.data.spec
        width = self.tools.width.value()
        self.profiler.submit(lambda _p, _c: M.line_profile(h, spec, pts[0], pts[1], width))

    def _on_profile(self, profile: M.Profile) -> None:
        keep = self.profile is not None and abs(profile.length_mm - self.profile.length_mm) < 1e-6
        self.profile = profile
        self.plot.set_profile(profile, keep_bands=keep)
        self.update_step(emit=False)
        self.profile_changed.emit()

    def bands(self) -> dict[str, tuple[float, float]]:
        """The reference bands A and B as distances along the ruler (mm)."""
        return self.plot.bands()

    def set_bands(self, a: tuple[float, float], b: tuple[float, float], emit: bool = True) -> None:
        """Reference bands as distances along the ruler (mm); ``emit``: recompute the step."""
        self.plot.set_bands(a, b, emit=emit)

    def update_step(self, emit: bool = True) -> None:
        """The step between the two reference bands, once the user has placed both; until
        then nothing is computed or shown (default bands would give a meaningless number)."""
        if self.profile is None:
            return
        if not self.plot.bands_placed():
            self.step = None
            self.step_budget = None
            self.tools.step_text.setToolTip("")
            self.plot.show_step(None)
            todo = " and ".join(n for n in ("A", "B") if n not in self.plot.placed)
            self.tools.step_text.setText(
                f"Step (B - A): drag band {todo} in the profile onto the surface to compare"
            )
            self.tools.step_text.setStyleSheet("")
            self.show_reading()
            if emit:
                self.profile_changed.emit()
            return
        bands = self.plot.bands()
        self.step = M.step_height(self.profile, bands["A"], bands["B"])
        s = self.step
        ctx = None if self.uncertainty is None else self.uncertainty.context()
        self.step_budget = (None if ctx is None or not math.isfinite(s.difference_mm)
                            else U.step_budget(ctx, self.profile, s, bands["A"], bands["B"]))
        self.plot.show_step(s, self.step_budget)
        self.tools.step_text.setStyleSheet("font-weight: bold")
        sb = self.step_budget
        unc = ("" if sb is None else
               f"\nStep uncertainty: none stated - {sb.incomplete}" if sb.incomplete else
               f"\nStep uncertainty U ({U.k_text([sb])}): {_pm_mm(sb.U_mm)}"
               + (f" (u_c {sb.u_c_mm:.3f} mm)" if math.isfinite(sb.u_c_mm) else ""))
        # the bands' SD is the spread of the surface in them, not an uncertainty: never "±"
        self.tools.step_text.setText(
            f"A {s.a.mean_mm:.3f} mm (SD {s.a.sd_mm:.3f}, n {s.a.n}), B {s.b.mean_mm:.3f} mm "
            f"(SD {s.b.sd_mm:.3f}, n {s.b.n})\nStep B - A: {s.difference_mm:+.3f} mm "
            f"(SD {s.sd_mm:.3f})" + unc
        )
        self.tools.step_text.setToolTip("" if self.step_budget is None
                                        else self.step_budget.text())
        self.show_reading()
        if emit:
            self.profile_changed.emit()

    def is_busy(self) -> bool:
        """The profile is being computed (the calibration's Monte Carlo, which can take a
        minute, is not waited for: the readings are shown again when it arrives)."""
        return self.profiler.is_running()

    def shutdown(self) -> None:
        self.profiler.shutdown()
        if self.uncertainty is not None:
            self.uncertainty.shutdown()
