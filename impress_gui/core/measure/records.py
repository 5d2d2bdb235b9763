"""Measurement records kept in the project, and CSV text of profiles and measurements
(Qt-free). Re-exported by :mod:`impress_gui.core.measure.readings`."""

from __future__ import annotations

import csv
import io
import json
import math
import uuid
from collections.abc import Mapping, Sequence
from datetime import datetime, timezone

import numpy as np

from impress_gui.core.base.errors import InputError
from impress_gui.core.formats.provenance import csv_header, csv_text
from impress_gui.core.measure.readings import Profile, RulerResult, StepHeight

# ----- measurement records and CSV ------------------------------------------------------------
MEASUREMENT_KINDS = ("point", "ruler", "profile", "annotation", "plane")


def new_measurement(
    kind: str,
    points_mm: Sequence[Sequence[float]],
    values: Mapping,
    label: str = "",
    note: str = "",
    params: Mapping | None = None,
    uncertainty: Mapping | None = None,
) -> dict:
    """A JSON-able measurement record as kept in the project's ``measurements`` list:
    ``{"id", "kind", "label", "note", "points_mm", "params", "values", "created_utc"}``
    (non-finite values are stored as None), and ``"uncertainty"`` when given: the budgets of
    its readings by name (:func:`impress_gui.core.measure.uncertainty.budgets_json`), whose
    ``u_c_*_mm``, ``U_k2_*_mm`` and ``k_*`` (``k``: the coverage factor) are also among the
    values."""
    if kind not in MEASUREMENT_KINDS:
        raise InputError(f"unknown measurement kind {kind!r}")
    extra = {} if not uncertainty else {"uncertainty": _jsonable(dict(uncertainty))}
    return {
        "id": uuid.uuid4().hex[:8],
        "kind": kind,
        "label": str(label),
        "note": str(note),
        "points_mm": [[round(float(c), 4) for c in p] for p in points_mm],
        "params": _jsonable(dict(params or {})),
        "values": _jsonable(dict(values)),
        "created_utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
    } | extra


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return round(float(obj), 5) if math.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def ruler_values(r: RulerResult) -> dict:
    return {
        "xy_mm": r.xy_mm,
        "d3_mm": r.d3_mm,
        "dz_mm": r.dz_mm,
        "z_start_mm": r.start.height_mm,
        "z_end_mm": r.end.height_mm,
    }


def step_values(s: StepHeight) -> dict:
    return {
        "band_a_mean_mm": s.a.mean_mm,
        "band_a_sd_mm": s.a.sd_mm,
        "band_a_n": s.a.n,
        "band_b_mean_mm": s.b.mean_mm,
        "band_b_sd_mm": s.b.sd_mm,
        "band_b_n": s.b.n,
        "step_mm": s.difference_mm,
        "step_sd_mm": s.sd_mm,
    }


def _fmt(v) -> str:
    """A value cell: a number formatted, anything else as text safe for spreadsheets."""
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if not math.isfinite(v) else f"{v:.4f}"
    if isinstance(v, int) and not isinstance(v, bool):
        return str(v)
    return csv_text(v)


def profile_csv(
    profile: Profile, step: StepHeight | None = None, provenance: Mapping | None = None
) -> str:
    """Comment header (segment, width, bands, then the ``# key: value`` lines of
    ``provenance``: software version, source hashes, grid, parameters) then
    ``distance_mm,x_mm,y_mm,height_mm,n_valid`` rows; missing heights are empty fields."""
    buf = io.StringIO()
    buf.write(
        f"# IMPREsS profile; start ({profile.start[0]:.4f}, {profile.start[1]:.4f}) mm; "
        f"end ({profile.end[0]:.4f}, {profile.end[1]:.4f}) mm; length "
        f"{profile.length_mm:.4f} mm; averaging width {profile.width_mm:.4f} mm\n"
    )
    if step is not None:
        for name, b in (("A", step.a), ("B", step.b)):
            buf.write(
                f"# band {name} {b.start_mm:.4f}..{b.end_mm:.4f} mm: mean "
                f"{_fmt(b.mean_mm)} mm, SD {_fmt(b.sd_mm)} mm, n {b.n}\n"
            )
        buf.write(f"# step B - A: {_fmt(step.difference_mm)} mm, SD {_fmt(step.sd_mm)} mm\n")
    buf.write(csv_header(provenance))
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["distance_mm", "x_mm", "y_mm", "height_mm", "n_valid"])
    for d, x, y, h, n in zip(
        profile.distance_mm, profile.x_mm, profile.y_mm, profile.height_mm, profile.n_valid
    ):
        w.writerow([f"{d:.4f}", f"{x:.4f}", f"{y:.4f}", _fmt(float(h)), int(n)])
    return buf.getvalue()


def read_profile_csv(text: str) -> tuple[np.ndarray, np.ndarray]:
    """``(distance_mm, height_mm)`` back from :func:`profile_csv` text (NaN for empty)."""
    rows = [
        r
        for r in csv.reader(line for line in text.splitlines() if line and not line.startswith("#"))
    ]
    body = rows[1:]
    d = np.array([float(r[0]) for r in body])
    h = np.array([float(r[3]) if r[3] else np.nan for r in body])
    return d, h


def measurements_csv(measurements: Sequence[Mapping], provenance: Mapping | None = None) -> str:
    """Leading ``# key: value`` lines of ``provenance`` (software version, the open
    reconstruction's hashes), then one row per measurement: number, id, kind, label, note,
    points, every value (with the uncertainties ``u_c_*_mm``, ``U_k2_*_mm`` and ``k_*`` when measured
    with them), the budgets as JSON in a column ``uncertainty_budget`` (only when a measurement
    has one), and the layer and heightmap SHA-256 it was measured on."""
    value_keys: list[str] = []
    n_pts = 0
    for m in measurements:
        n_pts = max(n_pts, len(m.get("points_mm", [])))
        for k in m.get("values", {}):
            if k not in value_keys:
                value_keys.append(k)
    head = ["number", "id", "kind", "label", "note"]
    for i in range(n_pts):
        head += [f"x{i + 1}_mm", f"y{i + 1}_mm"]
    buf = io.StringIO()
    buf.write(csv_header(provenance))
    w = csv.writer(buf, lineterminator="\n")
    with_budget = any(m.get("uncertainty") for m in measurements)
    w.writerow(head + [csv_text(k) for k in value_keys]
               + (["uncertainty_budget"] if with_budget else []) + ["layer", "heightmap_sha256"])
    for k, m in enumerate(measurements, 1):
        row = [k, *(csv_text(m.get(key, "")) for key in ("id", "kind", "label", "note"))]
        pts = list(m.get("points_mm", []))
        for i in range(n_pts):
            row += [_fmt(float(pts[i][0])), _fmt(float(pts[i][1]))] if i < len(pts) else ["", ""]
        vals = m.get("values", {})
        row += [_fmt(vals.get(key)) for key in value_keys]
        params = m.get("params") or {}
        if with_budget:
            b = m.get("uncertainty")
            row.append(json.dumps(b, separators=(",", ":"), sort_keys=True) if b else "")
        row += [csv_text(params.get("layer") or ""), csv_text(params.get("heightmap_sha256") or "")]
        w.writerow(row)
    return buf.getvalue()
