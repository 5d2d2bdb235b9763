"""Corner picks (format ``impress.picks``): the two calibration frames and the raw (distorted)
pixel positions of corners A-F in each, as the user clicked them; optionally, per laser, three
stripe points on target edges (the seed's L, M, N) for the three-point laser planes."""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

from impress_gui.core.base.errors import FormatError
from impress_gui.core.base.fileio import read_json, require, write_json
from impress_gui.core.calibration.target import CORNER_NAMES

PICKS_FORMAT = "impress.picks"
LASER_NAMES = ("green", "red")
#: the thesis' L, M, N on the default L target: where the stripe crosses the low face's outer
#: edge (A-B), the riser's top edge (F-C) and the high face's outer edge (E-D)
LMN_EDGES = ("AB", "FC", "ED")


@dataclass(frozen=True)
class StripePoint:
    """A stripe pixel lying on a target edge, the edge named by its two corners (``"AB"``)."""

    edge: str
    uv_px: tuple[float, float]


@dataclass(frozen=True)
class StripePoints:
    """Three stripe points of one laser (L, M, N) on three target edges in one frame."""

    frame: int
    points: tuple[StripePoint, ...]

    def pixels(self) -> np.ndarray:
        return np.array([p.uv_px for p in self.points], dtype=float)

    def to_json(self) -> dict:
        return {"frame": self.frame,
                "points": [{"edge": p.edge, "px": list(p.uv_px)} for p in self.points]}

    @classmethod
    def from_json(cls, doc, where: str) -> StripePoints:
        if not isinstance(doc, dict):
            raise FormatError(f"{where} must be an object with 'frame' and 'points'")
        frame = require(doc, "frame", int, f"{where}: ")
        if frame < 0:
            raise FormatError(f"{where}.frame must not be negative")
        raw = require(doc, "points", list, f"{where}: ")
        if len(raw) != 3:
            raise FormatError(f"{where}.points must hold three points (L, M, N), not {len(raw)}")
        pts = []
        for i, pd in enumerate(raw):
            if not isinstance(pd, dict):
                raise FormatError(f"{where}.points[{i}] must be an object with 'edge' and 'px'")
            edge = require(pd, "edge", str, f"{where}.points[{i}]: ")
            if (len(edge) != 2 or edge[0] == edge[1]
                    or not all(c in CORNER_NAMES for c in edge)):
                raise FormatError(f"{where}.points[{i}].edge must name a target edge by two "
                                  f"different corners A-F (e.g. \"AB\"), not {edge!r}")
            pts.append(StripePoint(edge, _pixel(pd.get("px"), f"{where}.points[{i}].px")))
        if len({frozenset(p.edge) for p in pts}) != 3:
            raise FormatError(f"{where}.points must lie on three different edges")
        return cls(frame, tuple(pts))


def _pixel(v, what: str) -> tuple[float, float]:
    if (not isinstance(v, list) or len(v) != 2
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
            or max(abs(x) for x in v) > 1e6 or not all(np.isfinite(v))):
        raise FormatError(f"{what} must be [x, y] in pixels")
    return (float(v[0]), float(v[1]))


@dataclass(frozen=True)
class Picks:
    video: str
    t1: int  # frame index with the green stripe on the target
    t2: int  # frame index with the red stripe on the target
    corners_t1: dict[str, tuple[float, float]]
    corners_t2: dict[str, tuple[float, float]]
    video_sha256: str | None = None
    note: str = ""
    extra: dict = field(default_factory=dict)
    #: optional, per laser ("green", "red"): three stripe points for the three-point planes
    stripe_points: dict[str, StripePoints] = field(default_factory=dict)

    def array(self, which: str) -> np.ndarray:
        """``(6, 2)`` pixel positions of A-F in frame t1 or t2 (``which`` = "t1"/"t2")."""
        d = self.corners_t1 if which == "t1" else self.corners_t2
        return np.array([d[c] for c in CORNER_NAMES], dtype=float)

    def is_complete(self) -> bool:
        return all(c in self.corners_t1 and c in self.corners_t2 for c in CORNER_NAMES)

    def to_json(self) -> dict:
        doc = {
            "format": PICKS_FORMAT,
            "version": 1,
            "video": self.video,
            "video_sha256": self.video_sha256,
            "t1": self.t1,
            "t2": self.t2,
            "pixel_convention": "raw distorted image pixels; (0, 0) is the centre of the "
                                "top-left pixel; x to the right, y down",
            "corners_t1": {c: list(self.corners_t1[c]) for c in CORNER_NAMES if c in self.corners_t1},
            "corners_t2": {c: list(self.corners_t2[c]) for c in CORNER_NAMES if c in self.corners_t2},
            "note": self.note,
        }
        if self.stripe_points:  # written only when present: files without it stay as they were
            doc["stripe_points"] = {n: self.stripe_points[n].to_json()
                                    for n in LASER_NAMES if n in self.stripe_points}
        return doc

    @classmethod
    def from_json(cls, doc: dict, where: str = "") -> Picks:
        corners = {}
        for key in ("corners_t1", "corners_t2"):
            raw = require(doc, key, dict, where)
            unknown = set(raw) - set(CORNER_NAMES)
            if unknown:
                raise FormatError(f"{where}{key} has unknown corner names {sorted(unknown)}")
            corners[key] = {c: _pixel(v, f"{where}{key}.{c}") for c, v in raw.items()}
        t1, t2 = require(doc, "t1", int, where), require(doc, "t2", int, where)
        if t1 < 0 or t2 < 0:
            raise FormatError(f"{where}frame indices must not be negative")
        sha = doc.get("video_sha256")
        if sha is not None and not (isinstance(sha, str)
                                    and re.fullmatch(r"[0-9a-fA-F]{64}", sha) is not None):
            # anything else turned the check against the video (W-PICKS-OTHER-VIDEO) off
            raise FormatError(f"{where}video_sha256 must be a SHA-256 (64 hex digits) or "
                              f"absent, not {str(sha)[:40]!r}")
        sha = sha.lower() if isinstance(sha, str) else None
        stripes = {}
        if doc.get("stripe_points") is not None:  # optional (files before it have none)
            raw = require(doc, "stripe_points", dict, where)
            unknown = set(raw) - set(LASER_NAMES)
            if unknown:
                raise FormatError(f"{where}stripe_points has unknown lasers {sorted(unknown)} "
                                  f"(known: {', '.join(LASER_NAMES)})")
            stripes = {n: StripePoints.from_json(raw[n], f"{where}stripe_points.{n}")
                       for n in LASER_NAMES if n in raw}
        return cls(str(require(doc, "video", str, where)), t1, t2, corners["corners_t1"],
                   corners["corners_t2"], sha if isinstance(sha, str) else None,
                   str(doc.get("note", "")), stripe_points=stripes)

    def save(self, path) -> None:
        write_json(path, self.to_json())

    @classmethod
    def load(cls, path) -> Picks:
        return cls.from_json(read_json(path, PICKS_FORMAT), f"{path}: ")
