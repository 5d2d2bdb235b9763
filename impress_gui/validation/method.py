"""The method's bias and precision from an ``impress validate`` record (issue 22, component 6
of the uncertainty budget; Qt-free).

A validation record (``validation.json``, format ``impress.validation``) lists every reading
of the protocol with its signed error against the known value and its axis (``z``: heights
and steps; ``xy``: lengths in the map's plane). Per axis, the errors' mean is the method's
bias and their standard deviation its precision; the budget takes them as a Type B component
``u = sqrt(bias^2 + SD^2)`` (an uncorrected bias counted as an uncertainty, JCGM 100 F.2.4.5).
The record kept in the project (``calibration_settings["method_validation"]``) names the file
with its SHA-256, so a budget says which validation it used.
"""

from __future__ import annotations

import hashlib
import math
import os
from pathlib import Path
from typing import Any

import numpy as np

from impress_gui.core.base import codes
from impress_gui.core.base.errors import FormatError
from impress_gui.core.base.fileio import MAX_JSON_BYTES, parse_json, read_regular
from impress_gui.validation.run import RECORD_FORMAT

#: where the project keeps the record (in its calibration settings: a property of the rig and
#: method, kept between sessions like the rail speed)
SETTINGS_KEY = "method_validation"
#: fewer readings than this on an axis give no figure for it
MIN_READINGS = 3


def _axis_stats(readings: list, axis: str) -> dict[str, Any]:
    e = np.array([r["error_mm"] for r in readings
                  if isinstance(r, dict) and r.get("axis") == axis
                  and isinstance(r.get("error_mm"), (int, float))
                  and not isinstance(r.get("error_mm"), bool)
                  and math.isfinite(r["error_mm"])], float)
    if len(e) < MIN_READINGS:
        return {"n": int(len(e)), "bias_mm": None, "sd_mm": None}
    return {"n": int(len(e)), "bias_mm": float(e.mean()), "sd_mm": float(e.std(ddof=1))}


def method_record(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The method's figures from the validation record at ``path``: per axis ``n``,
    ``bias_mm`` and ``sd_mm``, and the file's name, SHA-256, date and kind. FormatError (coded)
    when the file is not a validation record or holds fewer than three height readings."""
    path = Path(path)
    raw = read_regular(path, RECORD_FORMAT, MAX_JSON_BYTES)  # read once: parsed and hashed
    doc = parse_json(raw, path, RECORD_FORMAT)
    readings = doc.get("readings")
    if not isinstance(readings, list):
        raise FormatError(f"{path}: a validation record without readings", code=codes.E_FORMAT)
    z, xy = _axis_stats(readings, "z"), _axis_stats(readings, "xy")
    if z["bias_mm"] is None:
        raise FormatError(f"{path}: the validation holds {z['n']} height readings with an error; "
                          f"at least {MIN_READINGS} are needed for the method's bias and "
                          "precision", code=codes.E_FORMAT)
    return {"file": str(path.resolve()), "sha256": hashlib.sha256(raw).hexdigest(),
            "date_utc": str(doc.get("date_utc", "")), "kind": str(doc.get("kind", "")),
            "software": str(doc.get("software", "")), "z": z, "xy": xy}


def budget_validation(record: dict[str, Any] | None) -> dict[str, Any] | None:
    """What :class:`~impress_gui.core.measure.uncertainty.UncertaintyContext` takes as its
    ``validation``: the height axis' bias and SD and where they come from (None without a
    record)."""
    if not record:
        return None
    z = record.get("z") or {}
    if z.get("bias_mm") is None or z.get("sd_mm") is None:
        return None
    return {"bias_mm": float(z["bias_mm"]), "sd_mm": float(z["sd_mm"]),
            "source": f"{Path(record.get('file', 'validation.json')).name} "
                      f"({record.get('kind', '')} validation of {record.get('date_utc', '?')}, "
                      f"{z.get('n')} height readings, SHA-256 "
                      f"{str(record.get('sha256', ''))[:12]})"}
