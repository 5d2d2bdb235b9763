"""Corner picks (format ``impress.picks``): the two calibration frames and the raw (distorted)
pixel positions of corners A-F in each, as the user clicked them."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from impress_gui.core.errors import FormatError
from impress_gui.core.fileio import read_json, require, write_json
from impress_gui.core.target import CORNER_NAMES

PICKS_FORMAT = "impress.picks"


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

    def array(self, which: str) -> np.ndarray:
        """``(6, 2)`` pixel positions of A-F in frame t1 or t2 (``which`` = "t1"/"t2")."""
        d = self.corners_t1 if which == "t1" else self.corners_t2
        return np.array([d[c] for c in CORNER_NAMES], dtype=float)

    def is_complete(self) -> bool:
        return all(c in self.corners_t1 and c in self.corners_t2 for c in CORNER_NAMES)

    def to_json(self) -> dict:
        return {
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

    @classmethod
    def from_json(cls, doc: dict, where: str = "") -> Picks:
        corners = {}
        for key in ("corners_t1", "corners_t2"):
            raw = require(doc, key, dict, where)
            unknown = set(raw) - set(CORNER_NAMES)
            if unknown:
                raise FormatError(f"{where}{key} has unknown corner names {sorted(unknown)}")
            out = {}
            for c, v in raw.items():
                if (not isinstance(v, list) or len(v) != 2
                        or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                   for x in v)
                        or max(abs(x) for x in v) > 1e6 or not all(np.isfinite(v))):
                    raise FormatError(f"{where}{key}.{c} must be [x, y] in pixels")
                out[c] = (float(v[0]), float(v[1]))
            corners[key] = out
        t1, t2 = require(doc, "t1", int, where), require(doc, "t2", int, where)
        if t1 < 0 or t2 < 0:
            raise FormatError(f"{where}frame indices must not be negative")
        sha = doc.get("video_sha256")
        return cls(str(require(doc, "video", str, where)), t1, t2, corners["corners_t1"],
                   corners["corners_t2"], sha if isinstance(sha, str) else None,
                   str(doc.get("note", "")))

    def save(self, path) -> None:
        write_json(path, self.to_json())

    @classmethod
    def load(cls, path) -> Picks:
        return cls.from_json(read_json(path, PICKS_FORMAT), f"{path}: ")
