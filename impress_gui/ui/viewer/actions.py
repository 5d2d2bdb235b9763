"""The viewer's exports: heightmap TIFF, X3P, PLY, figure PNG, profile CSV/PNG, the HTML
report, the digital cast (STL/PLY/OBJ) and the 3D view. Files are written atomically in the
background and recorded in the session's project (outputs, with their SHA-256, and log)."""

from __future__ import annotations

import hashlib
import platform
from collections.abc import Callable
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import QObject, QRectF, Signal
from PySide6.QtWidgets import QWidget

from impress_gui.core.base.fileio import atomic_write_bytes
from impress_gui.core.formats import images
from impress_gui.core.formats import provenance as P
from impress_gui.core.formats.figures import (
    colourise,
    figure,
    png_bytes,
    profile_figure,
    report_html,
)
from impress_gui.core.formats.writers import ply_bytes, x3p_bytes
from impress_gui.core.measure import readings as M
from impress_gui.core.measure import uncertainty as U
from impress_gui.core.reconstruction.grid import GridSpec
from impress_gui.session.session import Session
from impress_gui.ui.messages import Dialogs, Messenger
from impress_gui.ui.task_bar import TaskBar
from impress_gui.ui.viewer.image import auto_levels
from impress_gui.ui.viewer.layers import SCALAR_LAYERS, LayerDisplay
from impress_gui.ui.viewer.map import CONTRIBUTION_LEGEND
from impress_gui.ui.viewer.ruler import RulerProfile
from impress_gui.ui.viewer.view3d import Surface3DWindow

MAX_PLY_POINTS = 10_000_000
FILTERS = {
    "tiff": "TIFF (*.tif *.tiff)",
    "x3p": "X3P (*.x3p)",
    "ply": "PLY point cloud (*.ply)",
    "png": "PNG image (*.png)",
    "csv": "CSV (*.csv)",
    "html": "HTML report (*.html)",
    "pdf": "PDF report (*.pdf)",
    "mesh": "Mesh (*.stl *.ply *.obj);;STL (*.stl);;PLY mesh (*.ply);;OBJ (*.obj)",
}


def _case_signature(proj) -> dict | None:
    """The signed case record's key and head signature (None for an unsaved project)."""
    if getattr(proj, "root", None) is None or not hasattr(proj, "signature_info"):
        return None
    try:
        info = proj.signature_info()
    except Exception:  # noqa: BLE001 - an export never fails for want of a signature
        return None
    return {k: info.get(k) for k in ("signed", "algorithm", "key_fingerprint", "public_key",
                                     "user", "head_signature", "log_head")}


def _now() -> str:
    return datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def _tiff_bytes(arr: np.ndarray, prov: dict | None = None, spec: GridSpec | None = None) -> bytes:
    """Float32 TIFF; with ``prov`` its ImageDescription is ``... provenance {JSON}``, Software
    names the version; with ``spec`` the resolution tags give the cell size (pixels per cm)."""
    return images.tiff_bytes(
        arr,
        pixel_mm=None if spec is None else spec.pixel_mm,
        # a description starting with "{" is taken by tifffile for its own shaped metadata
        description=f"{P.SOFTWARE} heightmap; provenance {P.to_json(prov)}" if prov else None,
        software=P.SOFTWARE if prov is not None else None,
    )


class ViewerExports(QObject):
    """The exports of what ``layers`` shows (with ``ruler``'s profile, the plot
    ``profile_view``), written on ``tasks`` and recorded in ``session``'s project; ``written``
    fires after each is recorded, ``status`` says where it went."""

    written = Signal()
    status = Signal(str)

    def __init__(
        self,
        session: Session,
        layers: LayerDisplay,
        ruler: RulerProfile,
        profile_view: QWidget,
        tasks: TaskBar,
        messenger: Messenger,
        dialogs: Dialogs,
        parent: QObject | None = None,
        view_rect: Callable[[], QRectF] | None = None,
    ) -> None:
        super().__init__(parent)
        self.view_rect = view_rect  # the map's visible region (rail frame, mm)
        self.cast_dialog = None
        self.session = session
        self.layers = layers
        self.recon = layers.recon
        self.ruler = ruler
        self.profile_view = profile_view
        self.tasks = tasks
        self.messenger = messenger
        self.dialogs = dialogs
        self.windows: list[Surface3DWindow] = []

    # ----- helpers -----------------------------------------------------------------------------
    def _path(self, path, title: str, filt: str, suffix: str) -> Path | None:
        if path is None:
            start = str(self.session.project.root or "")
            path = self.dialogs.save_file(title, FILTERS[filt], start)
        if not path:
            return None
        p = Path(path)
        return p if p.suffix else p.with_suffix(suffix)

    def _need_data(self) -> bool:
        if self.recon.data is None:
            self.messenger.info("Export", "Open a reconstruction first.")
            return False
        return True

    def _inputs(self) -> list:
        """The evidence and the reconstruction's files: an export may not replace them."""
        proj = self.session.project
        out = []
        try:
            if proj.video_path() is not None:
                out.append(proj.video_path())
        except Exception:  # noqa: BLE001 - a project without a usable video path
            pass
        return out

    def _write(self, what: str, path: Path, kind: str, make_bytes) -> bool:
        """Render ``make_bytes()`` in the background, write atomically, record the output."""

        from impress_gui.core.base.outdir import check_output_file

        def task(progress, cancel):
            # never over the evidence, a folder or a link; an existing export of ours is
            # replaced (the file dialog has asked)
            check_output_file(path, inputs=self._inputs(), formats=None)
            data = make_bytes()
            cancel.check()
            atomic_write_bytes(path, data)
            return hashlib.sha256(data).hexdigest()

        def done(sha: str) -> None:
            self.session.project.add_output(path, kind, sha256=sha)
            self.written.emit()
            self.status.emit(f"{what} written to {path}")

        return self.tasks.run(f"Writing {what}", task, done, f"Cannot write the {what}")

    def _height_for_export(self) -> tuple[np.ndarray, str]:
        note = f"layer {self.layers.measure_key()}" + (
            "; levelled" if self.recon.plane is not None else ""
        )
        return self.layers.height(), note

    def provenance(self, export: str, parameters: dict | None = None, grid: bool = True) -> dict:
        """The provenance dictionary of an export of the open reconstruction (built here, on
        the GUI thread): version, source hashes, grid, levelling plane and ``parameters``."""
        data, plane_ = self.recon.data, self.recon.plane
        source = None if data is None else P.reconstruction_source(data.metadata, data.folder)
        plane = None if plane_ is None else plane_.to_json()
        prov = P.export_provenance(
            export,
            source,
            spec=data.spec if grid and data is not None else None,
            plane=plane,
            parameters=parameters,
        )
        # the case record's signer and head signature tie the export to the signed case
        prov["case_record"] = _case_signature(self.session.project)
        return prov

    # ----- map exports ---------------------------------------------------------------------------
    def export_tiff(self, path=None) -> bool:
        if not self._need_data() or not (
            p := self._path(path, "Export the heightmap", "tiff", ".tif")
        ):
            return False
        h, _note = self._height_for_export()
        spec = self.recon.data.spec
        prov = self.provenance(
            "heightmap-tiff", {"layer": self.layers.measure_key(), "dtype": "float32, mm"}
        )
        return self._write(
            "heightmap TIFF",
            p,
            "heightmap-tiff",
            lambda: _tiff_bytes(np.asarray(h, np.float32), prov, spec),
        )

    def export_x3p(self, path=None) -> bool:
        if not self._need_data() or not (p := self._path(path, "Export X3P", "x3p", ".x3p")):
            return False
        h, note = self._height_for_export()
        spec = self.recon.data.spec
        prov = self.provenance("x3p", {"layer": self.layers.measure_key()})
        comment = f"IMPREsS viewer export; {note}; provenance {P.to_json(prov)}"
        # the dates of the scan and its calibration (recorded with the reconstruction), so that
        # the same data exported twice gives the same file; the export's time for older data
        dates = dict(self.recon.data.metadata.get("dates") or {})
        measured = str(dates.get("measured") or _now())
        calibrated = str(dates.get("calibrated") or measured)
        return self._write("X3P", p, "x3p",
                           lambda: x3p_bytes(spec, h, measured, comment, calibrated=calibrated))

    def export_ply(self, path=None) -> bool:
        if not self._need_data() or not (p := self._path(path, "Export PLY", "ply", ".ply")):
            return False
        h, _note = self._height_for_export()
        data = self.recon.data
        step = max(1, int(np.ceil(np.sqrt(h.size / MAX_PLY_POINTS))))
        prov = self.provenance(
            "ply",
            {
                "layer": self.layers.measure_key(),
                "step_cells": step,
                "colours": "texture" if data.texture_rgb is not None else "grey",
            },
        )
        lines = P.comment_lines(prov)
        return self._write(
            "PLY", p, "ply", lambda: ply_bytes(data.spec, h, data.texture_rgb, step, lines)
        )

    def figure_maker(self):
        """A function ``(max_px) -> RGB figure`` of the shown layer (title, measurements, scale
        bar, colour bar), with everything it needs captured here on the GUI thread so that
        it can run in a worker."""
        return self._figure()[0]

    def _figure(self):
        """``(figure_maker, parameters)``: the maker and what shaped the figure (layer, colour
        map, range, levelling) for its provenance."""
        layers, recon = self.layers, self.recon
        data, levelled = recon.data, recon.plane is not None
        key = layers.shown_key()
        proj = self.session.project
        title = (
            f"Case {proj.case_id or '-'}, evidence {proj.evidence_id or '-'}: "
            f"{layers.layer_title()}" + (" (levelled)" if levelled else "")
        )
        spec, ms = data.spec, [dict(m) for m in proj.measurements]
        if key in SCALAR_LAYERS and key in data.layers:
            arr = layers.height(key) if key != "difference" else data.layers[key]
            lut = pg.colormap.get(layers.colour_map()).getLookupTable(nPts=256)
            vrange = layers.levels()
            unit = "green-red (mm)" if key == "difference" else "height (mm)"
            params = {
                "layer": key,
                "colour_map": layers.colour_map(),
                "range_mm": [float(v) for v in vrange],
                "levelled": levelled and key != "difference",
            }
            return lambda max_px=6000: figure(
                spec,
                height=arr,
                lut=lut,
                vrange=vrange,
                title=title,
                measurements=ms,
                max_px=max_px,
                unit_label=unit,
            ), params
        rgb = {"texture": data.texture_rgb, "contribution": recon.contribution_rgb}.get(key)
        if key == "hillshade" and recon.hillshade is not None:
            rgb = recon.hillshade[1]
        if rgb is None:  # fall back to the fused heights
            arr = layers.height("fused")
            lut = pg.colormap.get("turbo").getLookupTable(nPts=256)
            vrange = auto_levels(arr, data.spec, recon.target_mm)
            params = {
                "layer": "fused",
                "colour_map": "turbo",
                "range_mm": [float(v) for v in vrange],
                "levelled": levelled,
            }
            return lambda max_px=6000: figure(
                spec,
                height=arr,
                lut=lut,
                vrange=vrange,
                title=title,
                measurements=ms,
                max_px=max_px,
            ), params
        legend = CONTRIBUTION_LEGEND if key == "contribution" else ()
        heading = "Which laser measured the cell" if legend else ""
        return (
            lambda max_px=6000: figure(
                spec,
                rgb=rgb,
                title=title,
                measurements=ms,
                max_px=max_px,
                legend=legend,
                legend_title=heading,
            )
        ), {"layer": key}

    def export_png(self, path=None) -> bool:
        if not self._need_data() or not (p := self._path(path, "Export a figure", "png", ".png")):
            return False
        fig, params = self._figure()
        prov = self.provenance(
            "figure-png",
            params | {"measurements": len(self.session.project.measurements), "max_px": 6000},
        )
        return self._write("figure", p, "figure-png", lambda: png_bytes(fig(), prov))

    # ----- profile -------------------------------------------------------------------------------
    def export_profile_csv(self, path=None) -> bool:
        ruler = self.ruler
        if ruler.profile is None:
            self.messenger.info("Profile", "Place the ruler first: its profile is exported.")
            return False
        if not (p := self._path(path, "Export the profile", "csv", ".csv")):
            return False
        text = M.profile_csv(ruler.profile, ruler.step, self._profile_provenance("profile-csv"))
        return self._write("profile CSV", p, "profile-csv", lambda: text.encode("utf-8"))

    def _profile_provenance(self, export: str) -> dict:
        pr = self.ruler.profile
        params: dict = {"layer": self.layers.measure_key()}
        if pr is not None:
            params |= {
                "start_mm": [float(v) for v in pr.start],
                "end_mm": [float(v) for v in pr.end],
                "width_mm": float(pr.width_mm),
            }
        return self.provenance(export, params)

    def profile_lines(self) -> tuple[list[str], dict]:
        """The profile figure's text lines (case, reconstruction, ruler; the ruler's readings and
        the bands' step with their expanded uncertainty U and its k, when a budget exists) and the
        placed bands; ([], {}) without a profile."""
        pr, ruler = self.ruler.profile, self.ruler
        if pr is None:
            return [], {}
        proj, data = self.session.project, self.recon.data
        levelled = self.recon.plane is not None
        folder = "-" if data is None or data.folder is None else str(data.folder)
        layer = self.layers.measure_key()
        lines = [
            f"Case {proj.case_id or '-'}, evidence {proj.evidence_id or '-'}"
            + (f", examiner {proj.examiner}" if getattr(proj, "examiner", "") else ""),
            f"Reconstruction: {folder}",
            f"Layer {layer}" + (" (levelled)" if levelled else "")
            + f"; ruler from ({pr.start[0]:.2f}, {pr.start[1]:.2f}) to ({pr.end[0]:.2f}, "
            f"{pr.end[1]:.2f}) mm, {pr.length_mm:.2f} mm long, averaged over "
            f"{pr.width_mm:.2f} mm",
        ]
        budgets = ruler.budgets()

        def pm(key: str) -> str:
            b = budgets.get(key)
            if b is not None and b.incomplete:
                return " ± -"
            return "" if b is None or not np.isfinite(b.U_mm) else f" ± {b.U_mm:.3f}"

        # no U stated (an unstable calibration): said in place of "(± U, k = ...)"
        why = next((b.incomplete for b in budgets.values() if b.incomplete), "")
        ruler_ks = [b for key, b in budgets.items() if key != "step"]
        how = f"(no U stated: {why})" if why else f"(± U, {U.k_text(ruler_ks, spaced=True)})"
        r = ruler.result()
        if r is not None and budgets:
            dz = "no data" if np.isnan(r.dz_mm) else f"{r.dz_mm:+.3f}{pm('dz')} mm"
            lines.append(f"Ruler xy {r.xy_mm:.3f}{pm('xy')} mm, dz {dz} {how}")
        bands = dict(ruler.plot.placed_bands()) if ruler.plot.bands_placed() else {}
        s = ruler.step
        if bands and s is not None:
            unc = ((f"{pm('step')} mm "
                    + (f"(U, {U.k_text([budgets['step']], spaced=True)})" if not why else how))
                   if "step" in budgets else " mm")
            lines.append(
                f"Band A {s.a.mean_mm:.3f} mm (SD {s.a.sd_mm:.3f}, n {s.a.n}), band B "
                f"{s.b.mean_mm:.3f} mm (SD {s.b.sd_mm:.3f}, n {s.b.n}); step B - A "
                f"{s.difference_mm:+.3f}{unc}"
            )
        return lines, bands

    def profile_maker(self):
        """A function ``() -> RGB figure`` of the ruler's profile (title, case and evidence,
        the reconstruction, the ruler's ends and width, axes in mm, the placed bands and their
        step with U: :meth:`profile_lines`), everything captured here on the GUI thread; None
        without a profile."""
        pr, ruler = self.ruler.profile, self.ruler
        if pr is None:
            return None
        lines, bands = self.profile_lines()
        s = ruler.step
        means = {"A": s.a.mean_mm, "B": s.b.mean_mm} if bands and s is not None else {}
        d, z = np.array(pr.distance_mm), np.array(pr.height_mm)
        return lambda: profile_figure(
            d, z, title="Depth profile along the ruler", lines=lines, bands=bands,
            band_means=means,
        )

    def profile_png_bytes(self, provenance: dict | None = None) -> bytes | None:
        """The profile figure as PNG (with ``provenance``'s text chunks); None without one."""
        make = self.profile_maker()
        return None if make is None else png_bytes(make(), provenance)

    def export_profile_png(self, path=None) -> bool:
        if self.ruler.profile is None:
            self.messenger.info("Profile", "Place the ruler first: its profile is exported.")
            return False
        if not (p := self._path(path, "Export the profile plot", "png", ".png")):
            return False
        make, prov = self.profile_maker(), self._profile_provenance("profile-png")
        return self._write("profile PNG", p, "profile-png", lambda: png_bytes(make(), prov))

    def export_measurements_csv(self, path=None) -> bool:
        if not (p := self._path(path, "Export the measurements", "csv", ".csv")):
            return False
        prov = self.provenance("measurements-csv", grid=False)
        text = M.measurements_csv(self.session.project.measurements, prov)
        return self._write("measurements CSV", p, "measurements-csv", lambda: text.encode("utf-8"))

    # ----- report --------------------------------------------------------------------------------
    def export_report(self, path=None) -> bool:
        """The case report as one self-contained HTML file."""
        if not self._need_data() or not (
            p := self._path(path, "Write the report", "html", ".html")
        ):
            return False
        make = self._report_maker()
        return self._write("report", p, "report-html", lambda: make().encode("utf-8"))

    def export_report_pdf(self, path=None) -> bool:
        """The same case report as an A4 PDF (text and figures; courts and case files)."""
        if not self._need_data() or not (
            p := self._path(path, "Write the report as PDF", "pdf", ".pdf")
        ):
            return False
        from impress_gui.ui.pdf import html_to_pdf

        make = self._report_maker()
        title = f"IMPREsS report {self.session.project.case_id or ''}".strip()
        return self._write("report", p, "report-pdf",
                           lambda: html_to_pdf(make(), title, P.SOFTWARE))

    def _report_maker(self):
        """What the report shows, gathered now (GUI thread); returns the function that renders
        its HTML (in the worker)."""
        proj, data, plane = self.session.project, self.recon.data, self.recon.plane
        meta = dict(data.metadata)
        cal = proj.calibration
        cal_info = None
        if cal is not None:
            cal_info = {
                "roll (deg)": cal.roll_deg,
                "tilt (deg)": cal.tilt_deg,
                "rail speed (mm/s)": cal.speed_mm_s,
                "speed implied by the target (mm/s)": cal.implied_speed_mm_s,
                "corner reprojection RMS (px)": cal.reprojection_rms_px,
            }
            for name, f in cal.planes.items():
                cal_info[f"{name} laser plane fit RMS (mm)"] = f.rms_mm
                cal_info[f"{name} laser plane points"] = f.n_points
            cal_info["warnings"] = "; ".join(cal.warnings) or "none"
        elif "calibration" in meta:
            cal_info = {k: v for k, v in meta["calibration"].items()}
        inputs = dict(meta.get("inputs", {}))
        if proj.video is not None:
            inputs["evidence video (project)"] = {
                "path": proj.video.path,
                "sha256": proj.video.sha256,
            }
        files = meta.get("files", {})
        for name in ("heightmap.tif", "texture.png"):
            if name in files:
                inputs[f"reconstruction {name}"] = {
                    "path": str(data.folder / name) if data.folder else name,
                    "sha256": files[name],
                }
        g = data.spec
        recon = {
            "folder": str(data.folder or ""),
            "software": meta.get("software", ""),
            "grid": f"{g.shape[1]} x {g.shape[0]} cells of {g.pixel_mm} mm, origin "
            f"({g.x0_mm:.2f}, {g.y0_mm:.2f}) mm",
            "frames": meta.get("frames", ""),
            "parameters": meta.get("parameters", ""),
            "height convention": meta.get("height", ""),
            "warnings": "; ".join(meta.get("warnings", [])) or "none",
            "host": platform.node(),
        }
        level = (
            None
            if plane is None
            else {
                "plane": f"z = {plane.a:.6f} x + {plane.b:.6f} y + {plane.c:.4f} mm",
                "tilt (deg)": plane.tilt_deg,
                "fit RMS (mm)": plane.rms_mm,
                "cells": plane.n,
            }
        )
        case = {
            "case_id": proj.case_id,
            "evidence_id": proj.evidence_id,
            "examiner": proj.examiner,
            "notes": proj.notes,
            "project": str(proj.root or "not saved"),
            "signature": _case_signature(proj),
        }
        profile_fig = self.profile_maker()
        measurements = [dict(m) for m in proj.measurements]
        fig = self.figure_maker()

        def make() -> str:
            images = [
                (
                    "Map with the measurements (scale bar and colour bar in mm)",
                    png_bytes(fig(max_px=2400)),
                )
            ]
            if profile_fig is not None:
                images.append(("Depth profile along the ruler", png_bytes(profile_fig())))
            return report_html(
                case=case,
                reconstruction=recon,
                calibration=cal_info,
                measurements=measurements,
                images=images,
                inputs=inputs,
                created_utc=_now(),
                levelling=level,
            )

        return make

    # ----- digital cast --------------------------------------------------------------------------
    def visible_crop(self) -> tuple[float, float, float, float] | None:
        """The map's visible region in the export frame (x0, y0, x1, y1 mm; y = -rail Y)."""
        if self.view_rect is None:
            return None
        r = self.view_rect()
        if r.width() <= 0 or r.height() <= 0:
            return None
        x0, x1 = sorted((r.left(), r.right()))
        y0, y1 = sorted((r.top(), r.bottom()))
        return float(x0), float(-y1), float(x1), float(-y0)

    def open_cast_dialog(self):
        """Show the digital cast's options (not blocking); Choose the file... asks for the file
        and writes the cast (:meth:`export_cast`). Returns the dialog (None without data)."""
        from impress_gui.ui.viewer.cast_dialog import CastDialog

        if not self._need_data():
            return None
        if self.recon.data.folder is None:
            self.messenger.info("Digital cast", "The cast is made from a reconstruction folder "
                                "and this map has none: open the reconstruction's folder.")
            return None
        if self.cast_dialog is not None:
            self.cast_dialog.close()
            self.cast_dialog.deleteLater()
        parent = self.parent() if isinstance(self.parent(), QWidget) else None
        dlg = CastDialog(self.visible_crop(), parent)
        dlg.accepted.connect(lambda: self.export_cast(params=dlg.params()))
        self.cast_dialog = dlg
        dlg.open()
        return dlg

    def export_cast(self, path=None, params=None) -> bool:
        """Write the digital cast of the open reconstruction (``params``: a
        :class:`~impress_gui.core.measure.cast.CastParams`, the defaults if None) with
        ``write_cast``, the code of ``impress cast``, in the background; the mesh and its
        record go into the project's outputs."""
        from impress_gui.core.base.outdir import check_output_file
        from impress_gui.core.measure.cast import SUFFIXES, CastParams, write_cast

        if not self._need_data():
            return False
        folder = self.recon.data.folder
        if folder is None:
            self.messenger.info("Digital cast", "The cast is made from a reconstruction folder "
                                "and this map has none.")
            return False
        if not (p := self._path(path, "Export a digital cast", "mesh", ".stl")):
            return False
        params = params or CastParams()
        proj = self.session.project
        context = {"by": "the viewer's export", "case_id": proj.case_id or None,
                   "evidence_id": proj.evidence_id or None,
                   "case_record": _case_signature(proj)}
        inputs = self._inputs()

        def task(progress, cancel):
            # never over the evidence (the folder's own files are checked by write_cast)
            check_output_file(p, inputs=inputs, formats=None)
            return write_cast(folder, p, params, progress, cancel, context, replace=True)

        def done(doc: dict) -> None:
            fmt = SUFFIXES.get(p.suffix.lower(), "mesh")
            proj.add_output(p, f"cast-{fmt}", sha256=doc["mesh"]["sha256"])
            proj.add_output(p.with_name(p.name + ".json"), "cast-record")
            self.written.emit()
            m, dev = doc["mesh"], doc.get("surface_deviation") or {}
            text = f"Digital cast written to {p} ({m['triangles']} triangles"
            if "max_mm" in dev:
                text += f"; surface within {dev['max_mm']:.3f} mm of the heightmap"
            self.status.emit(text + ")")
            if doc.get("warnings"):
                self.messenger.warning("Digital cast", "\n".join(doc["warnings"]))

        return self.tasks.run("Writing the digital cast", task, done,
                              "Cannot write the digital cast")

    # ----- 3D ------------------------------------------------------------------------------------
    def open_3d(self) -> Surface3DWindow | None:
        if not self._need_data():
            return None
        data = self.recon.data
        h, spec = self.layers.height(), data.spec
        step = max(1, int(np.ceil(np.sqrt(h.size / 300_000))))
        small = np.ascontiguousarray(h[::step, ::step])
        small_spec = GridSpec(spec.x0_mm, spec.y0_mm, spec.pixel_mm * step, small.shape)
        if self.layers.shown_key() == "texture" and data.texture_rgb is not None:
            colours = np.ascontiguousarray(data.texture_rgb[::step, ::step])
        else:
            lut = pg.colormap.get(self.layers.colour_map()).getLookupTable(nPts=256)
            colours = colourise(small, lut, self.layers.levels())
        win = Surface3DWindow(small, small_spec, colours, "3D view - IMPREsS")
        self.windows.append(win)
        win.show()
        return win

    def shutdown(self) -> None:
        if self.cast_dialog is not None:
            self.cast_dialog.close()
            self.cast_dialog = None
        for w in self.windows:
            w.shutdown()
            w.close()
        self.windows.clear()
