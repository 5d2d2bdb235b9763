"""The viewer tab's levelling and measurement list, as mixins of
:class:`~impress_gui.ui.viewer.tab.ViewerTab` (they use its map, panels, task bar and
project). Numbers come from :mod:`impress_gui.core.measure.readings`."""

from __future__ import annotations

from PySide6.QtCore import QRectF

from impress_gui.core.base.errors import ImpressError
from impress_gui.core.measure import readings as M
from impress_gui.ui.viewer.image import auto_levels


class LevellingMixin:
    # ----- levelling ------------------------------------------------------------------------------
    def level_three_points(self, pts) -> bool:
        spec, h = self.data.spec, self.data.layers[self.measure_key()]
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
        h, spec = self.data.layers[self.measure_key()], self.data.spec
        return self._apply_plane(lambda: M.plane_from_region(h, spec, x_range, y_range), "region")

    def _apply_plane(self, fit, how: str) -> bool:
        data, key, target = self.data, self.measure_key(), self._target_mm

        def task(progress, cancel):
            plane = fit()
            progress(0.5, "levelling the map")
            lev = M.levelled(data.layers[key], data.spec, plane)
            return plane, lev, auto_levels(lev, data.spec, target)

        def done(result) -> None:
            plane, lev, auto = result
            self.plane = plane
            self._levelled = {key: lev}
            # new automatic ranges for the new heights; a range the user typed stays
            for k in [k for k in self._auto if k.endswith("/levelled")]:
                del self._auto[k]
            self._auto[f"{key}/levelled"] = auto
            self._update_level_text(how)
            self.refresh_layer()
            self.update_profile()
            self.status.emit(
                f"Levelled ({how}): tilt {plane.tilt_deg:.3f}°, fit RMS {plane.rms_mm:.3f} mm"
            )
            self.levelled_changed.emit()

        try:
            return self.tasks.run("Levelling", task, done, "Cannot level the map")
        except ImpressError as exc:
            self.messenger.exception("Cannot level the map", exc)
            return False

    def clear_levelling(self) -> None:
        self.plane = None
        self._levelled.clear()
        self.level_points.clear()
        self.map.set_level_points([])
        self.map.show_region(None)
        self._update_level_text()
        self.refresh_layer()
        self.update_profile()
        self.levelled_changed.emit()

    def _update_level_text(self, how: str = "") -> None:
        p = self.plane
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


class MeasurementsMixin:
    # ----- measurements ------------------------------------------------------------------------------
    def _params(self) -> dict:
        d = self.data
        return {
            "layer": self.measure_key(),
            "radius_mm": self.tools.radius.value(),
            "plane": None if self.plane is None else self.plane.to_json(),
            "reconstruction": None if d is None or d.folder is None else str(d.folder),
            "heightmap_sha256": (d.metadata.get("files", {}) or {}).get("heightmap.tif")
            if d is not None
            else None,
        }

    def _ruler_record(self, label: str = "") -> dict | None:
        r = self.ruler_result()
        if r is None:
            return None
        values = M.ruler_values(r)
        params = self._params() | {"width_mm": self.tools.width.value()}
        if self.step is not None and self.profile is not None:
            values |= M.step_values(self.step)
            params["bands_mm"] = self.profile_plot.bands()
        return M.new_measurement("ruler", self.ruler_points(), values, label=label, params=params)

    def add_ruler_measurement(self, label: str = "") -> dict | None:
        m = self._ruler_record(label)
        if m is None:
            self.messenger.info("Ruler", "Place the ruler first (Ruler, then two clicks).")
            return None
        self._add(m)
        return m

    def add_marker(self, x: float, y: float, label: str = "") -> dict:
        r = self.readout_at(x, y)
        n = sum(1 for m in self.project.measurements if m.get("kind") == "annotation") + 1
        m = M.new_measurement(
            "annotation",
            [(x, y)],
            {"height_mm": r.height_mm},
            label=label or f"mark {n}",
            params=self._params(),
        )
        self._add(m)
        return m

    def _add(self, m: dict) -> None:
        self.project.add_measurement(m)
        self.refresh_measurements()
        self.changed.emit()
        self.status.emit(f"Measurement {len(self.project.measurements)} added")

    def refresh_measurements(self, selected: int | None = None) -> None:
        ms = self.project.measurements
        self.table.fill(ms)
        self.map.show_measurements(ms if self.data is not None else [], selected)

    def edit_measurement(self, row: int, **changes) -> None:
        """Change a measurement's fields (label, note, points_mm, values, params)."""
        p = self.project
        if hasattr(p, "update_measurement"):
            p.update_measurement(row, changes)
        else:  # the project's list is public; record the edit in its log
            p.measurements[row] = {**p.measurements[row], **changes}
            p.dirty = True
            p.log(
                "measurement edited",
                {"number": row + 1, "id": p.measurements[row].get("id"), **changes},
            )
        self.refresh_measurements(row)
        self.changed.emit()

    def delete_measurement(self, row: int) -> None:
        p = self.project
        if hasattr(p, "remove_measurement"):
            p.remove_measurement(row)
        else:
            gone = p.measurements.pop(row)
            p.dirty = True
            p.log("measurement deleted", {"number": row + 1, "id": gone.get("id")})
        self.refresh_measurements()
        self.changed.emit()

    def _on_table_edited(self, row: int, field: str, text: str) -> None:
        if self.project.measurements[row].get(field, "") != text:
            self.edit_measurement(row, **{field: text})

    def show_selected(self) -> None:
        row = self.table.selected_row()
        if row is None:
            return
        m = self.project.measurements[row]
        pts = m.get("points_mm") or []
        if m.get("kind") == "ruler" and len(pts) == 2:
            self.tools.width.setValue(float(m.get("params", {}).get("width_mm", 0.0)))
            self.set_ruler(pts[0], pts[1])
            bands = m.get("params", {}).get("bands_mm")
            if bands:
                self.profile_plot.set_bands(tuple(bands["A"]), tuple(bands["B"]), emit=False)
        elif pts:
            r = self.map.vb.viewRect()
            self.map.vb.setRange(
                QRectF(
                    pts[0][0] - r.width() / 2, pts[0][1] - r.height() / 2, r.width(), r.height()
                ),
                padding=0,
            )
        self.refresh_measurements(row)

    def update_selected_from_ruler(self) -> None:
        row = self.table.selected_row()
        if row is None or self.project.measurements[row].get("kind") != "ruler":
            self.messenger.info("Update", "Select a ruler measurement in the list first.")
            return
        new = self._ruler_record()
        if new is not None:
            self.edit_measurement(
                row, points_mm=new["points_mm"], values=new["values"], params=new["params"]
            )

    def delete_selected(self) -> None:
        row = self.table.selected_row()
        if row is not None:
            self.delete_measurement(row)
