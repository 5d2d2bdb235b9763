"""The viewer's levelling and its list of measurements.

:class:`Levelling` fits a reference plane (three clicked points or a region) and levels the
shown reconstruction by it; :class:`MeasurementList` keeps the rulers and annotations in the
session's project (each change logged there) and shows them in the list and on the map.
Numbers come from :mod:`impress_gui.core.measure.readings`."""

from __future__ import annotations

import weakref

from PySide6.QtCore import QObject, QRectF, Signal
from PySide6.QtGui import QUndoStack

from impress_gui.core.base.errors import Cancelled, ImpressError
from impress_gui.core.measure import readings as M
from impress_gui.core.measure import uncertainty as U
from impress_gui.core.project.project import Project
from impress_gui.session.session import Session
from impress_gui.ui.messages import Messenger
from impress_gui.ui.task_bar import TaskBar
from impress_gui.ui.viewer.image import auto_levels
from impress_gui.ui.viewer.layers import LayerDisplay
from impress_gui.ui.viewer.map import MapView
from impress_gui.ui.viewer.panels import MeasurementTable, ToolPanel
from impress_gui.ui.viewer.ruler import RulerProfile
from impress_gui.ui.viewer.undo import (
    AddMeasurement,
    ClearMeasurements,
    EditMeasurement,
    LevellingChange,
    RemoveMeasurement,
)
from impress_gui.ui.worker import LatestOnly
from impress_gui.validation.method import budget_validation


class Levelling(QObject):
    """Heights relative to a plane fitted to the reference surface (in the background, on
    ``tasks``). ``levelled`` fires once the plane is set or cleared (the heights changed)."""

    levelled = Signal()
    status = Signal(str)

    def __init__(
        self,
        layers: LayerDisplay,
        map_view: MapView,
        tools: ToolPanel,
        tasks: TaskBar,
        messenger: Messenger,
        parent: QObject | None = None,
        undo_stack: QUndoStack | None = None,
    ) -> None:
        super().__init__(parent)
        self.undo_stack = undo_stack if undo_stack is not None else QUndoStack(self)
        self.how = ""  # how the plane was fitted (three points, region)
        self.layers = layers
        self.map = map_view
        self.tools = tools
        self.tasks = tasks
        self.messenger = messenger
        self.points: list[tuple[float, float]] = []  # clicked in 'three points' mode
        tools.fit_region_button.clicked.connect(lambda: self.level_region())
        tools.clear_level_button.clicked.connect(self.clear)

    # ----- the reference surface as the user marks it -----------------------------------------
    def restart_points(self) -> None:
        self.points.clear()
        self.map.set_level_points([])

    def reset(self) -> None:
        """A new reconstruction: no points, no region, the text for its (absent) plane."""
        self.restart_points()
        self.how = ""
        self.map.show_region(None)
        self.show_text()

    def add_point(self, x: float, y: float) -> None:
        """A click in 'three points' mode; the third levels the map."""
        self.points.append((x, y))
        self.map.set_level_points(self.points)
        if len(self.points) == 3:
            self.level_three_points(self.points)

    def place_region(self, x: float, y: float) -> None:
        """A click in 'region' mode: a rectangle a fifth of the view, centred there."""
        r = self.map.vb.viewRect()
        w, h = r.width() / 5, r.height() / 5
        self.map.show_region(QRectF(x - w / 2, y - h / 2, w, h))

    # ----- fitting ----------------------------------------------------------------------------
    def level_three_points(self, pts) -> bool:
        data = self.layers.recon.data
        spec, h = data.spec, data.layers[self.layers.measure_key()]
        radius = self.tools.radius.value()
        xyz = [(x, y, M.readout(h, spec, x, y, radius).height_mm) for x, y in pts]
        return self._apply_plane(lambda: M.plane_from_points(xyz), "three points")

    def level_region(self, x_range=None, y_range=None) -> bool:
        if x_range is None:
            rect = self.map.region_rect()
            if rect is None:
                self.messenger.info(
                    "Levelling",
                    "Choose 'Level: region' and click on the "
                    "reference surface to place a rectangle first.",
                )
                return False
            x_range, y_range = rect
        self.map.show_region(
            QRectF(x_range[0], y_range[0], x_range[1] - x_range[0], y_range[1] - y_range[0])
        )
        data = self.layers.recon.data
        h, spec = data.layers[self.layers.measure_key()], data.spec
        return self._apply_plane(lambda: M.plane_from_region(h, spec, x_range, y_range), "region")

    def _apply_plane(self, fit, how: str) -> bool:
        recon = self.layers.recon
        data, key, target = recon.data, self.layers.measure_key(), recon.target_mm

        def task(progress, cancel):
            plane = fit()
            progress(0.5, "levelling the map")
            lev = M.levelled(data.layers[key], data.spec, plane)
            return plane, lev, auto_levels(lev, data.spec, target)

        def done(result) -> None:
            plane, lev, auto = result
            before = self.state()
            recon.set_plane(plane, key, lev, auto)
            self.how = how
            self.show_text(how)
            self.layers.refresh()
            self.status.emit(
                f"Levelled ({how}): tilt {plane.tilt_deg:.3f}°, fit RMS {plane.rms_mm:.3f} mm"
            )
            self.undo_stack.push(LevellingChange(self, before, self.state(), f"level ({how})"))
            self.levelled.emit()

        try:
            return self.tasks.run("Levelling", task, done, "Cannot level the map")
        except ImpressError as exc:
            self.messenger.exception("Cannot level the map", exc)
            return False

    def clear(self) -> None:
        """Heights relative to the calibration's ground again (undoable)."""
        before = self.state()
        self.layers.recon.clear_plane()
        self.how = ""
        self.restart_points()
        self.map.show_region(None)
        self.show_text()
        self.layers.refresh()
        if before[0] is not None:
            self.undo_stack.push(LevellingChange(self, before, self.state(), "clear levelling"))
        self.levelled.emit()

    # ----- undo and redo ------------------------------------------------------------------------
    def state(self) -> tuple:
        """The levelling as it is: the reconstruction's plane state and how it was fitted."""
        return self.layers.recon.plane_state(), self.how

    def restore(self, state: tuple, why: str) -> None:
        """Back to a levelling ``state`` (undo, redo): the plane and the heights levelled by
        it, the map and the text."""
        plane_state, how = state
        self.layers.recon.restore_plane(plane_state)
        self.how = how
        self.restart_points()
        self.show_text(how)
        self.layers.refresh()
        p = self.layers.recon.plane
        self.status.emit(f"Levelling {'off' if p is None else f'({how})'} ({why})")
        self.levelled.emit()

    def show_text(self, how: str = "") -> None:
        p = self.layers.recon.plane
        if p is None:
            self.tools.level_text.setText(
                "Levelling: off (heights relative to the calibration's ground)"
            )
        else:
            self.tools.level_text.setText(
                f"Levelled ({how}): heights relative to the plane z = {p.a:.5f} x + {p.b:.5f} y"
                f" + {p.c:.3f} mm; tilt {p.tilt_deg:.3f}°, fit RMS {p.rms_mm:.3f} mm "
                f"({p.n} cells)"
            )


class UncertaintyProvider(QObject):
    """What the viewer's readings' uncertainty budgets are computed from
    (:class:`~impress_gui.core.measure.uncertainty.UncertaintyContext`): the heights measured,
    the lasers' contributions and per-laser height maps (read from the reconstruction's folder
    when they are not in memory: :func:`~impress_gui.core.measure.uncertainty.per_laser_maps`,
    once per reconstruction), the levelling plane, and the Monte Carlo of the project's scene
    calibration with its target model (the project's, or the built-in one), computed once per
    calibration in the background; ``ready`` fires when it is there. Until then (and without a
    calibration) budgets are made without the calibration component, and say so."""

    ready = Signal()
    status = Signal(str)
    #: a calibration whose Monte Carlo tilt spread (1 SD, degrees) exceeds this is called poor
    POOR_TILT_DEG = 0.25

    def __init__(self, session: Session, layers: LayerDisplay, parent: QObject | None = None,
                 trials: int | None = None) -> None:
        super().__init__(parent)
        self.session = session
        self.summary_text = ""  # what the last Monte Carlo says of the calibration
        self.layers = layers
        self.trials = trials
        self._ensembles: dict = {}  # calibration key -> ensemble, or the reason it failed
        self._running: object | None = None
        self._per_laser: tuple[weakref.ref, dict | None] | None = None  # (data, its maps)
        self.worker = LatestOnly(self, "uncertainty")
        self.worker.finished.connect(self._on_done)
        self.worker.failed.connect(lambda title, msg: self._on_done((self._running, msg)))

    def _calibration(self):
        from impress_gui.core.calibration.target import default_target

        p = self.session.project
        cal = p.calibration
        if cal is None:
            return None, None, None
        target = p.target if p.target is not None else default_target()
        return cal, target, (id(cal), id(target) if p.target is not None else "builtin")

    def _on_done(self, result) -> None:
        key, ens = result
        self._ensembles[key] = ens
        if self._running == key:
            self._running = None
        if isinstance(ens, tuple):  # ("unstable", why): no reading can be given a U
            self.summary_text = (f"Calibration uncertainty: POOR - {ens[1]}; readings carry no "
                                 "uncertainty - mark the corners again more precisely")
        elif isinstance(ens, str):
            self.summary_text = f"Calibration uncertainty not evaluated: {ens}"
        else:
            sm = ens.summary
            poor = sm["tilt_sd_deg"] > self.POOR_TILT_DEG
            self.summary_text = (
                f"Calibration uncertainty ({ens.n_trials} trials, clicks ± "
                f"{ens.click_sigma_px:.2f} px): tilt ± {sm['tilt_sd_deg']:.2f}°, roll ± "
                f"{sm['roll_sd_deg']:.2f}°, laser planes ± {sm['green_plane_angle_sd_deg']:.2f}° "
                f"/ ± {sm['red_plane_angle_sd_deg']:.2f}° (1 SD)"
                + ("; POOR: absolute heights far from the target are uncertain by millimetres - "
                   "mark the corners again more precisely" if poor else ""))
        self.status.emit(self.summary_text)
        self.ready.emit()

    def start(self) -> None:
        """Start the calibration's Monte Carlo when it is neither done nor running."""
        cal, target, key = self._calibration()
        if cal is None or key in self._ensembles or self._running == key:
            return
        from impress_gui.core.calibration import uncertainty as CU

        kw = {} if self.trials is None else {"n": self.trials}

        def task(_progress, cancel, cal=cal, target=target, key=key):
            try:
                return key, CU.calibration_ensemble(cal, target, cancel=cancel, **kw)
            except Cancelled:
                raise
            except CU.UnstableCalibration as exc:
                return key, ("unstable", str(exc))
            except Exception as exc:  # noqa: BLE001 - the component is left out, with why
                return key, f"{type(exc).__name__}: {exc}"

        self._running = key
        self.worker.submit(task)

    def is_busy(self) -> bool:
        return self.worker.is_running()

    def per_laser(self, data: M.ReconData) -> dict | None:
        """The per-laser height maps of ``data`` (None when its folder lacks them)."""
        if self._per_laser is None or self._per_laser[0]() is not data:
            self._per_laser = (weakref.ref(data), U.per_laser_maps(data))
        return self._per_laser[1]

    def context(self) -> U.UncertaintyContext | None:
        """The context for a reading now (None without a reconstruction)."""
        recon = self.layers.recon
        data = recon.data
        if data is None:
            return None
        key = self.layers.measure_key()
        cal, _target, ck = self._calibration()
        notes = []
        ens = None
        unstable = ""
        if cal is None:
            notes.append("no scene calibration in the project: the calibration component "
                          "is missing")
        else:
            got = self._ensembles.get(ck)
            if got is None:
                self.start()
                notes.append("the calibration's Monte Carlo is still running: the calibration "
                             "component is missing from this budget")
            elif isinstance(got, str):
                notes.append(f"calibration component not evaluated: {got}")
            elif isinstance(got, tuple):
                unstable = got[1]
            else:
                ens = got
        if recon.plane is not None:
            notes.append("levelled map: the levelling plane's own calibration error is not "
                         "subtracted (the calibration component is the unlevelled height's)")
        contribution = data.layers.get("contribution") if key == "fused" else None
        ctx = U.UncertaintyContext(
            self.layers.height(), data.spec, contribution, ens,
            None if cal is None else float(cal.speed_mm_s),
            None if cal is None else float(cal.implied_speed_mm_s),
            None, recon.plane, None, notes)
        ctx.validation = budget_validation(self.session.method_validation)
        ctx.unstable = unstable
        # both lasers' maps: the cells the fusion kept one laser of, and the reconstruction's
        # random error from their disagreement (U.agreement_noise, for every layer)
        ctx.per_laser = self.per_laser(data)
        if contribution is not None:
            ctx.fusion_weights = U.fusion_weights_of(data.metadata)
        if key in ("green", "red"):
            ctx.laser = key
        if cal is not None:
            ctx.sampling_mm = U.lateral_sampling(cal)
            ctx.per_px = U.method_sensitivity(cal, ctx.notes)
        return ctx

    def shutdown(self) -> None:
        self.worker.shutdown()


class MeasurementList(QObject):
    """The project's measurements (rulers and annotations): made from the ruler and clicks,
    shown in ``table`` and on the map, edited and deleted there. Each change is in the
    session's project at once (and in its log); ``changed`` fires after it."""

    changed = Signal()
    status = Signal(str)

    def __init__(
        self,
        session: Session,
        table: MeasurementTable,
        map_view: MapView,
        tools: ToolPanel,
        layers: LayerDisplay,
        ruler: RulerProfile,
        messenger: Messenger,
        parent: QObject | None = None,
        undo_stack: QUndoStack | None = None,
    ) -> None:
        super().__init__(parent)
        self.undo_stack = undo_stack if undo_stack is not None else QUndoStack(self)
        self.session = session
        self.table = table
        self.map = map_view
        self.tools = tools
        self.layers = layers
        self.ruler = ruler
        self.messenger = messenger
        self.uncertainty = UncertaintyProvider(session, layers, self)
        self.uncertainty.status.connect(self.status)
        ruler.uncertainty = self.uncertainty
        self.uncertainty.ready.connect(ruler.show_uncertainty)
        table.details_button.clicked.connect(self.show_details)
        tools.add_ruler_button.clicked.connect(lambda: self.add_ruler_measurement())
        table.edited.connect(self._on_table_edited)
        table.show_button.clicked.connect(self.show_selected)
        table.update_button.clicked.connect(self.update_selected_from_ruler)
        table.delete_button.clicked.connect(self.delete_selected)
        table.clear_button.clicked.connect(self.clear_all)

    @property
    def project(self) -> Project:
        return self.session.project

    # ----- new measurements -------------------------------------------------------------------
    def params(self) -> dict:
        """How a measurement is made: layer, averaging radius, levelling plane, source."""
        recon = self.layers.recon
        d = recon.data
        return {
            "layer": self.layers.measure_key(),
            "radius_mm": self.tools.radius.value(),
            "plane": None if recon.plane is None else recon.plane.to_json(),
            "reconstruction": None if d is None or d.folder is None else str(d.folder),
            "heightmap_sha256": (d.metadata.get("files", {}) or {}).get("heightmap.tif")
            if d is not None
            else None,
        }

    def ruler_record(self, label: str = "") -> dict | None:
        """A ruler measurement of the ruler as it is (with the step, when both bands are
        placed); None without a ruler."""
        r = self.ruler.result()
        if r is None:
            return None
        values = M.ruler_values(r)
        params = self.params() | {"width_mm": self.tools.width.value()}
        if self.ruler.step is not None and self.ruler.profile is not None:
            values |= M.step_values(self.ruler.step)
            params["bands_mm"] = self.ruler.bands()
        budgets = self.ruler.budgets()
        values = U.with_uncertainty(values, budgets)
        return M.new_measurement(
            "ruler", self.ruler.points(), values, label=label, params=params,
            uncertainty=U.budgets_json(budgets),
        )

    def add_ruler_measurement(self, label: str = "") -> dict | None:
        m = self.ruler_record(label)
        if m is None:
            self.messenger.info("Ruler", "Place the ruler first (Ruler, then two clicks).")
            return None
        self.add(m)
        return m

    def add_marker(self, x: float, y: float, label: str = "") -> dict:
        r = self.layers.readout(x, y, self.tools.radius.value())
        n = sum(1 for m in self.project.measurements if m.get("kind") == "annotation") + 1
        ctx = self.uncertainty.context()
        budgets = {} if ctx is None or not r.has_data else {"": U.height_budget(ctx, r)}
        m = M.new_measurement(
            "annotation",
            [(x, y)],
            U.with_uncertainty({"height_mm": r.height_mm}, budgets),
            label=label or f"mark {n}",
            params=self.params(),
            uncertainty=U.budgets_json(budgets),
        )
        self.add(m)
        return m

    def add(self, m: dict) -> None:
        """Add ``m`` at the end of the list (undoable)."""
        self.undo_stack.push(AddMeasurement(self, len(self.project.measurements), m))
        self.status.emit(f"Measurement {len(self.project.measurements)} added")

    # ----- the changes the undo stack's commands make (each logged in the project) ------------
    def _row_of(self, row: int, m: dict) -> int | None:
        """Where ``m`` is in the list: at ``row`` normally, else found by its id."""
        ms = self.project.measurements
        if 0 <= row < len(ms) and ms[row].get("id") == m.get("id"):
            return row
        return next((k for k, x in enumerate(ms) if x.get("id") == m.get("id")), None)

    def _done(self, refresh: bool, selected: int | None = None) -> None:
        if refresh:
            self.refresh(selected)
            self.changed.emit()

    def insert_record(self, row: int, m: dict, action: str, refresh: bool = True) -> None:
        p = self.project
        row = min(max(row, 0), len(p.measurements))
        if row == len(p.measurements) and action == "measurement added":
            p.add_measurement(m)
        else:
            p.measurements.insert(row, dict(m))
            p.dirty = True
            p.log(action, {"number": row + 1, **dict(m)})
        self._done(refresh)

    def remove_record(self, row: int, m: dict, action: str, refresh: bool = True) -> None:
        p = self.project
        found = self._row_of(row, m)
        if found is None:
            return
        gone = p.measurements.pop(found)
        p.dirty = True
        p.log(action, {"number": found + 1, "id": gone.get("id")})
        self._done(refresh)

    def replace_record(self, row: int, old: dict, new: dict, action: str) -> None:
        p = self.project
        found = self._row_of(row, old)
        if found is None:
            return
        changes = {k: v for k, v in new.items() if old.get(k) != v}
        p.measurements[found] = dict(new)
        p.dirty = True
        p.log(action, {"number": found + 1, "id": new.get("id"), **changes})
        self._done(True, found)

    # ----- the list -----------------------------------------------------------------------------
    def refresh(self, selected: int | None = None) -> None:
        ms = self.project.measurements
        self.table.fill(ms)
        self.map.show_measurements(ms if self.layers.recon.data is not None else [], selected)

    def edit(self, row: int, **changes) -> None:
        """Change a measurement's fields (label, note, points_mm, values, params; undoable)."""
        before = dict(self.project.measurements[row])
        after = {**before, **changes}
        what = "edit " + " and ".join(sorted(k.replace("_mm", "") for k in changes))
        self.undo_stack.push(EditMeasurement(self, row, before, after, what))

    def delete(self, row: int) -> None:
        """Delete the measurement at ``row`` (undoable)."""
        m = self.project.measurements[row]
        self.undo_stack.push(RemoveMeasurement(self, row, m))

    def clear_all(self) -> None:
        """Delete every measurement of the list (undoable: one step brings them all back)."""
        ms = self.project.measurements
        if ms:
            self.undo_stack.push(ClearMeasurements(self, list(ms)))
            self.status.emit("Measurements cleared (Edit > Undo brings them back)")

    def _on_table_edited(self, row: int, field: str, text: str) -> None:
        if self.project.measurements[row].get(field, "") != text:
            self.edit(row, **{field: text})

    def show_selected(self) -> None:
        """Put the ruler on the selected ruler measurement (with its width and bands), or
        centre the view on the selected annotation."""
        row = self.table.selected_row()
        if row is None:
            return
        m = self.project.measurements[row]
        pts = m.get("points_mm") or []
        if m.get("kind") == "ruler" and len(pts) == 2:
            self.tools.width.setValue(float(m.get("params", {}).get("width_mm", 0.0)))
            self.ruler.set(pts[0], pts[1])
            bands = m.get("params", {}).get("bands_mm")
            if bands:
                self.ruler.set_bands(tuple(bands["A"]), tuple(bands["B"]), emit=False)
        elif pts:
            r = self.map.vb.viewRect()
            self.map.vb.setRange(
                QRectF(
                    pts[0][0] - r.width() / 2, pts[0][1] - r.height() / 2, r.width(), r.height()
                ),
                padding=0,
            )
        self.refresh(row)

    def update_selected_from_ruler(self) -> None:
        row = self.table.selected_row()
        if row is None or self.project.measurements[row].get("kind") != "ruler":
            self.messenger.info("Update", "Select a ruler measurement in the list first.")
            return
        new = self.ruler_record()
        if new is not None:
            self.edit(row, points_mm=new["points_mm"], values=new["values"], params=new["params"])

    def show_details(self) -> None:
        """The selected measurement's uncertainty budgets in a window of their own."""
        row = self.table.selected_row()
        if row is None:
            self.messenger.info("Uncertainty", "Select a measurement in the list first.")
            return
        self.table.show_details(self.project.measurements[row], row + 1)

    def delete_selected(self) -> None:
        row = self.table.selected_row()
        if row is not None:
            self.delete(row)
