"""Provenance of the viewer's exports (issue 8): what every exported file says about itself.

One dictionary, built by :func:`export_provenance`, is written into each export in that
format's own place (TIFF ImageDescription, PNG tEXt chunks, CSV ``# key: value`` lines, PLY
``comment`` lines, the X3P's Record2 comment)::

    {"software": "IMPREsS workstation 0.1.0", "version": "0.1.0", "export": "heightmap-tiff",
     "source": {"reconstruction": folder, "metadata_json_sha256": ..., "heightmap_sha256": ...,
                "video_sha256": ..., "calibration_sha256": ..., "reconstruction_software": ...},
     "grid": {"x0_mm", "y0_mm", "pixel_mm", "shape", "convention", "height"},
     "parameters": {"layer": ..., "levelling": plane or None, ...}}

Nothing time-dependent goes in: the same reconstruction and settings give the same bytes.

The records of a product's inputs (metadata.json's ``inputs``: the video and the calibration a
reconstruction was made from; a scene calibration's: the video, intrinsics, picks and target)
are built by :func:`input_record`, :func:`reconstruction_inputs` and
:func:`calibration_inputs` and read back by :func:`recorded_sha256`; nothing else builds them.
No Qt here.
"""

from __future__ import annotations

import hashlib
import json
import os
import struct
import zlib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from impress_gui import __version__
from impress_gui.core.formats.writers import HEIGHT_CONVENTION
from impress_gui.core.reconstruction.grid import GridSpec

SOFTWARE = f"IMPREsS workstation {__version__}"
GRID_CONVENTION = "cell [i, j] centred at rail (x0 + j*pixel, y0 + i*pixel) mm; row 0 = smallest y"
PNG_KEY = "IMPREsS provenance"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
METADATA_CHANGED = (
    "metadata.json changed on disk since the reconstruction was opened: its hash is not recorded"
)


# ----- the records of the inputs ----------------------------------------------------------------
def input_record(path: str | os.PathLike, sha256: str) -> dict[str, str]:
    """One input as a product records it: ``{"path": the path as given, "sha256": the hash of
    the bytes that were used}`` (the path is kept as the user or the project named it; a byte
    of a file name that is not UTF-8 is written as ``\\xNN``: as Python holds it, a lone
    surrogate, it is not Unicode, and a strict JSON reader refuses the file)."""
    return {"path": printable_path(path), "sha256": sha256}


def printable_path(path: str | os.PathLike) -> str:
    """``path`` as Unicode text: the bytes of a name that are not UTF-8 as ``\\xNN``."""
    text = os.fspath(path)
    if isinstance(text, bytes):
        text = os.fsdecode(text)
    return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


def reconstruction_inputs(video: Mapping, calibration: Mapping) -> dict[str, dict]:
    """metadata.json's ``inputs``: the records (:func:`input_record`) of the scan video and of
    the scene calibration a reconstruction was made from (the calibration first, as written
    since version 1)."""
    return {"calibration": dict(calibration), "video": dict(video)}


def calibration_inputs(video: Mapping, intrinsics: Mapping, *, picks: Mapping | None = None,
                       target: Mapping | None = None, video_last: bool = False) -> dict[str, dict]:
    """A scene calibration's ``inputs``: the record of the scan video (:func:`input_record`),
    of the intrinsics (an :func:`input_record` of their file, or ``{"source": ...}`` when the
    window had them from elsewhere), of the corner picks file when there is one and of the
    target model (its ``name``, with the record of its file or ``"builtin": true``) when
    recorded. In the order video, intrinsics, picks, target - or, with ``video_last``, the
    video after the others, as ``impress calibrate`` has written them since version 1."""
    records = {"intrinsics": intrinsics, "picks": picks, "target": target}
    out = {k: dict(v) for k, v in records.items() if v is not None}
    return out | {"video": dict(video)} if video_last else {"video": dict(video)} | out


def recorded_sha256(inputs: Mapping | None, name: str) -> str | None:
    """The SHA-256 that an ``inputs`` record (of a reconstruction's metadata or of a
    calibration) gives for the input ``name`` ("video", "calibration", ...); None if none."""
    record = (inputs or {}).get(name) or {}
    return record.get("sha256") if isinstance(record, Mapping) else None


# ----- the dictionary -------------------------------------------------------------------------
def reconstruction_source(metadata: Mapping, folder: str | Path | None) -> dict:
    """What an export was made from: the reconstruction folder, the SHA-256 of its
    metadata.json (read now, and recorded only if it still holds what was loaded), and the
    hashes that metadata.json records for the fused heightmap, the video and the calibration."""
    files = metadata.get("files") or {}
    inputs = metadata.get("inputs")
    out: dict[str, Any] = {
        "reconstruction": None if folder is None else str(folder),
        "metadata_json_sha256": None,
        "heightmap_sha256": files.get("heightmap.tif"),
        "video_sha256": recorded_sha256(inputs, "video"),
        "calibration_sha256": recorded_sha256(inputs, "calibration"),
        "reconstruction_software": metadata.get("software"),
    }
    if folder is not None:
        try:
            raw = (Path(folder) / "metadata.json").read_bytes()
        except OSError:
            raw = None
        if raw is not None:
            try:
                same = json.loads(raw) == json.loads(json.dumps(dict(metadata)))
            except (ValueError, TypeError, RecursionError):
                same = False
            if same:
                out["metadata_json_sha256"] = hashlib.sha256(raw).hexdigest()
            else:
                out["note"] = METADATA_CHANGED
    return out


def grid_info(spec: GridSpec, plane: Mapping | None = None) -> dict:
    """The grid and what a height means (relative to the levelling plane when there is one)."""
    height = HEIGHT_CONVENTION
    if plane is not None:
        height = (
            f"height in mm relative to the levelling plane z = {plane['a']:.6g} x + "
            f"{plane['b']:.6g} y + {plane['c']:.6g} mm (height minus plane), up = towards the "
            "camera; NaN = no data"
        )
    return spec.to_json() | {"convention": GRID_CONVENTION, "height": height}


def export_provenance(
    export: str,
    source: Mapping | None,
    *,
    spec: GridSpec | None = None,
    plane: Mapping | None = None,
    parameters: Mapping | None = None,
) -> dict:
    """The provenance dictionary of one export (see the module's docstring). ``plane`` is the
    levelling plane's JSON (``Plane.to_json()``) or None; it is also put in the parameters."""
    params: dict[str, Any] = {"levelling": None if plane is None else dict(plane)}
    params.update(parameters or {})
    return {
        "software": SOFTWARE,
        "version": __version__,
        "export": export,
        "source": dict(source) if source is not None else None,
        "grid": None if spec is None else grid_info(spec, plane),
        "parameters": params,
    }


def to_json(prov: Mapping) -> str:
    """Compact, key-sorted, ASCII-only JSON (safe in TIFF, PNG tEXt and PLY headers)."""
    return json.dumps(
        prov, sort_keys=True, separators=(",", ":"), ensure_ascii=True, default=_default
    )


def _default(obj):
    try:
        return float(obj)
    except (TypeError, ValueError):
        return str(obj)


def _flatten(prefix: str, value, out: list[tuple[str, str]]) -> None:
    if isinstance(value, Mapping):
        for k in value:
            _flatten(f"{prefix}.{k}" if prefix else str(k), value[k], out)
        return
    if value is None:
        text = "-"
    elif isinstance(value, str):
        text = value
    else:
        text = json.dumps(value, default=_default)
    out.append((prefix, " ".join(text.split())))


def comment_lines(prov: Mapping) -> list[str]:
    """``key: value`` lines (nested keys joined with dots, single lines, '-' for none), in
    the dictionary's order: for CSV ``#`` lines and PLY ``comment`` lines."""
    pairs: list[tuple[str, str]] = []
    _flatten("", prov, pairs)
    return [f"{k}: {v}" for k, v in pairs]


def parse_comment_lines(lines: Sequence[str]) -> dict[str, str]:
    """``{key: value}`` back from :func:`comment_lines` output (``#`` or ``comment`` prefixes
    stripped; other lines ignored)."""
    out: dict[str, str] = {}
    for line in lines:
        s = line.strip()
        for prefix in ("#", "comment "):
            if s.startswith(prefix):
                s = s[len(prefix) :].strip()
        key, sep, value = s.partition(": ")
        if sep and key and " " not in key:
            out[key] = value
    return out


#: what a spreadsheet takes for the start of a formula in a cell (OWASP "CSV injection")
_FORMULA_START = ("=", "+", "-", "@", "\t", "\r", "\n")


def csv_text(value) -> str:
    """A text cell (a name, a label, a note, a path, a message) safe to open in a spreadsheet:
    text that a spreadsheet would run as a formula (starting with ``= + - @``, a tab or a line
    break) gets a leading apostrophe, which spreadsheets show as text and do not evaluate.
    Numbers are written by their own formatting, never through this (a negative number
    stays a number). None becomes an empty cell."""
    text = "" if value is None else str(value)
    return "'" + text if text.startswith(_FORMULA_START) else text


def csv_header(prov: Mapping | None) -> str:
    return "" if prov is None else "".join(f"# {line}\n" for line in comment_lines(prov))


# ----- PNG text chunks --------------------------------------------------------------------------
def _chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _text_chunk(key: str, value: str) -> bytes:
    k = key.encode("latin-1")
    if not 1 <= len(k) <= 79 or k != k.strip() or b"\0" in k:
        raise ValueError(f"bad PNG text keyword {key!r}")
    try:
        return _chunk(b"tEXt", k + b"\0" + value.encode("latin-1"))
    except UnicodeEncodeError:  # iTXt: uncompressed UTF-8, no language tag
        return _chunk(b"iTXt", k + b"\0\0\0\0\0" + value.encode("utf-8"))


def png_with_text(png: bytes, text: Mapping[str, str]) -> bytes:
    """``png`` with a tEXt chunk (iTXt if not Latin-1) per item inserted right after IHDR;
    the image data are untouched."""
    if png[:8] != PNG_SIGNATURE or png[12:16] != b"IHDR":
        raise ValueError("not a PNG stream")
    (n,) = struct.unpack(">I", png[8:12])
    end = 8 + 12 + n  # signature, then length + type + data + CRC of IHDR
    chunks = b"".join(_text_chunk(k, v) for k, v in text.items())
    return png[:end] + chunks + png[end:]


def png_provenance_text(prov: Mapping) -> dict[str, str]:
    """The PNG text items of an export: Software, Source (a one-line summary) and the full
    provenance as JSON under the keyword 'IMPREsS provenance'."""
    src = prov.get("source") or {}
    summary = "; ".join(
        f"{k} {src[k]}"
        for k in ("metadata_json_sha256", "heightmap_sha256", "video_sha256")
        if src.get(k)
    )
    return {"Software": SOFTWARE, "Source": summary or "-", PNG_KEY: to_json(prov)}


def read_png_text(png: bytes) -> dict[str, str]:
    """The tEXt and iTXt (uncompressed) items of a PNG stream; checks each chunk's CRC."""
    if png[:8] != PNG_SIGNATURE:
        raise ValueError("not a PNG stream")
    out: dict[str, str] = {}
    pos = 8
    while pos + 12 <= len(png):
        (n,) = struct.unpack(">I", png[pos : pos + 4])
        kind, data = png[pos + 4 : pos + 8], png[pos + 8 : pos + 8 + n]
        (crc,) = struct.unpack(">I", png[pos + 8 + n : pos + 12 + n])
        if zlib.crc32(kind + data) != crc:
            raise ValueError(f"bad CRC in the {kind!r} chunk")
        if kind == b"tEXt":
            k, _, v = data.partition(b"\0")
            out[k.decode("latin-1")] = v.decode("latin-1")
        elif kind == b"iTXt":
            k, _, rest = data.partition(b"\0")
            if rest[:1] == b"\0":  # not compressed
                _lang, _, rest = rest[2:].partition(b"\0")
                _tkey, _, v = rest.partition(b"\0")
                out[k.decode("latin-1")] = v.decode("utf-8")
        if kind == b"IEND":
            break
        pos += 12 + n
    return out


__all__ = [
    "SOFTWARE",
    "calibration_inputs",
    "comment_lines",
    "csv_header",
    "export_provenance",
    "grid_info",
    "input_record",
    "parse_comment_lines",
    "png_provenance_text",
    "png_with_text",
    "read_png_text",
    "reconstruction_inputs",
    "reconstruction_source",
    "recorded_sha256",
    "to_json",
]
