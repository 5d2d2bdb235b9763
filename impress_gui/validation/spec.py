"""The real-scan validation spec (format ``impress.validation-spec``, version 1; Qt-free):
the known dimensions of physical artefacts and where to measure them on their reconstructions.
See docs/validation.md for the format; :func:`spec_to_json` writes one from
:class:`~impress_gui.validation.protocol.Reading` s (the simulator run writes its readings this way,
a template for real scans)."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from impress_gui.core.base import codes
from impress_gui.core.base.errors import FormatError
from impress_gui.validation.protocol import (
    KINDS,
    PROFILE_WIDTH_MM,
    SPEC_FORMAT,
    Edge,
    LevelRegion,
    Reading,
)


def _pair(v: object, name: str, where: str) -> tuple[float, float]:
    if (
        not isinstance(v, list)
        or len(v) != 2
        or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
        or not all(abs(x) < 1e6 and math.isfinite(x) for x in v)
    ):
        raise FormatError(
            f"{where}{name} must be two finite numbers [a, b] in mm", code=codes.E_VAL_SPEC
        )
    return (float(v[0]), float(v[1]))


def _number(
    doc: Mapping[str, object],
    key: str,
    where: str,
    lo: float,
    hi: float,
    default: float | None = None,
) -> float:
    v = doc.get(key, default)
    if (
        not isinstance(v, (int, float))
        or isinstance(v, bool)
        or not lo <= v <= hi  # False for NaN; no float conversion of a huge integer
    ):
        raise FormatError(
            f"{where}{key} must be a number between {lo:g} and {hi:g}", code=codes.E_VAL_SPEC
        )
    return float(v)


def _reading_from_json(doc: object, group: str, default_width: float, where: str) -> Reading:
    if not isinstance(doc, dict):
        raise FormatError(f"{where}a measurement must be an object", code=codes.E_VAL_SPEC)
    kind = doc.get("kind")
    if kind not in KINDS:
        raise FormatError(f"{where}kind must be one of {', '.join(KINDS)}", code=codes.E_VAL_SPEC)
    rid = doc.get("id")
    if not isinstance(rid, str) or not rid or len(rid) > 200:
        raise FormatError(f"{where}id must be a short text", code=codes.E_VAL_SPEC)
    lvl: LevelRegion | None = None
    if doc.get("level_region") is not None:
        lr = doc["level_region"]
        if not isinstance(lr, dict) or not isinstance(lr.get("exclude", []), list):
            raise FormatError(f"{where}level_region must be an object", code=codes.E_VAL_SPEC)
        ex = tuple(
            (
                _pair(e.get("x_mm") if isinstance(e, dict) else None, "exclude x_mm", where),
                _pair(e.get("y_mm") if isinstance(e, dict) else None, "exclude y_mm", where),
            )
            for e in lr.get("exclude", [])
        )
        lvl = LevelRegion(
            _pair(lr.get("x_mm"), "level_region.x_mm", where),
            _pair(lr.get("y_mm"), "level_region.y_mm", where),
            ex,
        )
    # checked in this order: the first problem is the one reported
    nominal = _number(doc, "nominal_mm", where, 0.0, 1e4)
    start = _pair(doc.get("start_mm"), "start_mm", where)
    end = _pair(doc.get("end_mm"), "end_mm", where)
    width = _number(doc, "profile_width_mm", where, 0.0, 100.0, default_width)
    band_a: tuple[float, float] | None = None
    band_b: tuple[float, float] | None = None
    if kind in ("width", "step"):
        band_a = _pair(doc.get("band_a_mm"), "band_a_mm", where)
        band_b = _pair(doc.get("band_b_mm"), "band_b_mm", where)
    around = _number(doc, "around_mm", where, -1e6, 1e6) if kind == "width" else None
    edges: tuple[Edge, ...] = ()
    if kind == "edge_distance":
        docs = doc.get("edges")
        if (
            not isinstance(docs, list)
            or len(docs) != 2
            or not all(isinstance(e, dict) for e in docs)
        ):
            raise FormatError(f"{where}edges must be a list of two edge objects", code=codes.E_VAL_SPEC)
        edges = tuple(
            Edge(
                _pair(e.get("band_low_mm"), "band_low_mm", where),
                _pair(e.get("band_high_mm"), "band_high_mm", where),
                _number(e, "near_mm", where, -1e6, 1e6),
                _number(e, "max_offset_mm", where, 0.0, 1e6)
                if e.get("max_offset_mm") is not None
                else None,
            )
            for e in docs
        )
    return Reading(
        id=rid,
        group=group,
        target=str(doc.get("target", "")),
        kind=kind,
        nominal_mm=nominal,
        start_mm=start,
        end_mm=end,
        profile_width_mm=width,
        band_a_mm=band_a,
        band_b_mm=band_b,
        around_mm=around,
        edges=edges,
        level=lvl,
        label=str(doc.get("label", rid)),
    )


@dataclass(frozen=True)
class ScanSpec:
    """One reconstruction (a folder, relative to the spec file) and its readings."""

    name: str
    reconstruction: Path
    readings: tuple[Reading, ...]


def load_spec(path: str | os.PathLike[str]) -> tuple[str, tuple[ScanSpec, ...]]:
    """Read a real-scan validation spec (format :data:`SPEC_FORMAT`): ``(name, scans)``."""
    from impress_gui.core.base.fileio import read_json

    path = Path(path)
    doc = read_json(path, SPEC_FORMAT)
    where = f"{path}: "
    scans = doc.get("scans")
    if not isinstance(scans, list) or not scans or len(scans) > 1000:
        raise FormatError(f"{where}scans must be a non-empty list", code=codes.E_VAL_SPEC)
    width = _number(doc, "profile_width_mm", where, 0.0, 100.0, PROFILE_WIDTH_MM)
    out: list[ScanSpec] = []
    for i, s in enumerate(scans):
        w = f"{where}scans[{i}]: "
        if (
            not isinstance(s, dict)
            or not isinstance(s.get("name"), str)
            or not isinstance(s.get("reconstruction"), str)
            or not isinstance(s.get("measurements"), list)
        ):
            raise FormatError(
                f"{w}needs name, reconstruction (a folder) and measurements", code=codes.E_VAL_SPEC
            )
        if len(s["measurements"]) > 10000:
            raise FormatError(f"{w}too many measurements", code=codes.E_VAL_SPEC)
        readings = tuple(
            _reading_from_json(m, s["name"], width, f"{w}measurements[{j}]: ")
            for j, m in enumerate(s["measurements"])
        )
        ids = [r.id for r in readings]
        if len(set(ids)) != len(ids):
            raise FormatError(f"{w}measurement ids must be unique", code=codes.E_VAL_SPEC)
        out.append(ScanSpec(s["name"], (path.parent / s["reconstruction"]), readings))
    return str(doc.get("name", path.stem)), tuple(out)


def reading_to_json(r: Reading) -> dict[str, Any]:
    d: dict[str, Any] = {
        "id": r.id,
        "target": r.target,
        "label": r.label,
        "kind": r.kind,
        "nominal_mm": r.nominal_mm,
        "start_mm": list(r.start_mm),
        "end_mm": list(r.end_mm),
        "profile_width_mm": r.profile_width_mm,
    }
    if r.band_a_mm is not None:
        d["band_a_mm"] = list(r.band_a_mm)
    if r.band_b_mm is not None:
        d["band_b_mm"] = list(r.band_b_mm)
    if r.around_mm is not None:
        d["around_mm"] = r.around_mm
    if r.edges:
        d["edges"] = [
            {
                "band_low_mm": list(e.band_low_mm),
                "band_high_mm": list(e.band_high_mm),
                "near_mm": e.near_mm,
                "max_offset_mm": e.max_offset_mm,
            }
            for e in r.edges
        ]
    if r.level is not None:
        d["level_region"] = {
            "x_mm": list(r.level.x_mm),
            "y_mm": list(r.level.y_mm),
            "exclude": [{"x_mm": list(x), "y_mm": list(y)} for x, y in r.level.exclude],
        }
    return d


def spec_to_json(name: str, scans: Sequence[tuple[str, str, Sequence[Reading]]]) -> dict[str, Any]:
    """A spec document from ``(scan name, reconstruction folder, readings)`` triples."""
    return {
        "format": SPEC_FORMAT,
        "version": 1,
        "name": name,
        "profile_width_mm": PROFILE_WIDTH_MM,
        "scans": [
            {"name": n, "reconstruction": rec, "measurements": [reading_to_json(r) for r in rs]}
            for n, rec, rs in scans
        ],
    }
