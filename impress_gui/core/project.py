"""The scan project: one case's work in one folder (Qt-free).

Folder layout::

    <project>/project.json   format "impress.project", version 1 (rewritten atomically on save)
    <project>/log.jsonl      append-only log, one JSON object per line, hash-chained

``project.json`` holds the case identifiers (``case_id``, ``evidence_id``, ``examiner``,
``notes``), the scan video as a *reference* (``video.path`` absolute, ``video.relative_path``
from the project folder, ``video.sha256`` and ``video.size_bytes`` recorded when it was added;
the evidence file is never copied, moved or written), and the work products as embedded
documents in their own formats: ``intrinsics`` (impress.intrinsics), ``target``
(impress.target), ``picks`` (impress.picks), ``calibration`` (impress.calibration), plus
``calibration_settings`` (e.g. the rail speed entered), free-form ``processing`` parameters, ``outputs`` (files written, with their SHA-256) and
``measurements``. ``log_head`` records how many log entries existed at the last save and the
hash of the last one, so a truncated log is detected too.

The log (its line format, the hash chain and :func:`verify_log`), the evidence hash and the
who/when stamps are in :mod:`~impress_gui.core.project_log`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from impress_gui import __version__
from impress_gui.core.calibration import SceneCalibration
from impress_gui.core.errors import FormatError, ImpressError, InputError, IntegrityError
from impress_gui.core.fileio import dumps_json, read_json, write_json
from impress_gui.core.geometry import Intrinsics
from impress_gui.core.picks import Picks
from impress_gui.core.progress import CancelToken, ProgressCallback
from impress_gui.core.project_log import (
    LOG_FILE,
    append_log,
    current_user,
    hash_file,
    log_tail,
    read_log,
    utc_now,
    verify_log,
)
from impress_gui.core.target import TargetModel

PROJECT_FORMAT = "impress.project"
PROJECT_FILE = "project.json"
CASE_FIELDS = ("case_id", "evidence_id", "examiner", "notes")
# re-exported: callers import the log functions from here
__all__ = [
    "CASE_FIELDS",
    "LOG_FILE",
    "PROJECT_FILE",
    "PROJECT_FORMAT",
    "Project",
    "VideoRef",
    "append_log",
    "create_project",
    "current_user",
    "hash_file",
    "read_log",
    "verify_log",
]


# ----- the project --------------------------------------------------------------------------
@dataclass(frozen=True)
class VideoRef:
    """The evidence video, referenced (never copied). ``path`` is absolute."""

    path: str
    sha256: str
    size_bytes: int
    added_utc: str
    relative_path: str | None = None

    def to_json(self) -> dict:
        return {
            "path": self.path,
            "relative_path": self.relative_path,
            "sha256": self.sha256,
            "size_bytes": self.size_bytes,
            "added_utc": self.added_utc,
        }

    @classmethod
    def from_json(cls, doc: dict, where: str) -> VideoRef:
        if not isinstance(doc, dict):
            raise FormatError(f"{where}video must be an object")
        sha = doc.get("sha256")
        if not isinstance(sha, str) or len(sha) != 64:
            raise FormatError(f"{where}video.sha256 must be a SHA-256 hex digest")
        path, size = doc.get("path"), doc.get("size_bytes")
        if not isinstance(path, str) or not path or not isinstance(size, int) or size < 0:
            raise FormatError(f"{where}video needs a path and size_bytes")
        rel = doc.get("relative_path")
        return cls(
            path, sha, size, str(doc.get("added_utc", "")), rel if isinstance(rel, str) else None
        )


@dataclass
class Project:
    """A scan project. ``root`` is None until the project is first saved; log entries made
    before that are kept and written on the first save."""

    root: Path | None = None
    case_id: str = ""
    evidence_id: str = ""
    examiner: str = ""
    notes: str = ""
    created_utc: str = field(default_factory=utc_now)
    video: VideoRef | None = None
    intrinsics: Intrinsics | None = None
    target: TargetModel | None = None
    picks: Picks | None = None
    calibration: SceneCalibration | None = None
    calibration_settings: dict = field(default_factory=dict)
    processing: dict = field(default_factory=dict)
    outputs: list[dict] = field(default_factory=list)
    measurements: list[dict] = field(default_factory=list)
    dirty: bool = False
    _pending_log: list[tuple[str, dict, str]] = field(default_factory=list, repr=False)
    _log_head: dict = field(default_factory=dict, repr=False)

    # ----- paths ------------------------------------------------------------------------------
    @property
    def project_file(self) -> Path | None:
        return None if self.root is None else self.root / PROJECT_FILE

    @property
    def log_file(self) -> Path | None:
        return None if self.root is None else self.root / LOG_FILE

    @property
    def title(self) -> str:
        name = self.root.name if self.root else "Untitled"
        return f"{name} ({self.case_id})" if self.case_id else name

    def video_path(self) -> Path | None:
        """The video's path: the recorded absolute path, else the one relative to the project
        folder (a project moved together with its evidence)."""
        if self.video is None:
            return None
        p = Path(self.video.path)
        if not p.exists() and self.root is not None and self.video.relative_path:
            rel = (self.root / self.video.relative_path).resolve()
            if rel.exists():
                return rel
        return p

    # ----- changes ----------------------------------------------------------------------------
    def log(self, action: str, details: dict | None = None) -> None:
        """Record an action in the log (buffered until the project has a folder)."""
        if self.log_file is None:
            self._pending_log.append((action, dict(details or {}), utc_now()))
        else:
            append_log(self.log_file, action, details)

    def set_case_info(self, **info: str) -> None:
        unknown = set(info) - set(CASE_FIELDS)
        if unknown:
            raise InputError(f"unknown case fields {sorted(unknown)}")
        changed = {k: str(v) for k, v in info.items() if getattr(self, k) != str(v)}
        if changed:
            for k, v in changed.items():
                setattr(self, k, v)
            self.dirty = True
            self.log("case information edited", changed)

    def set_video(
        self,
        path: str | os.PathLike,
        sha256: str | None = None,
        progress: ProgressCallback | None = None,
        cancel: CancelToken | None = None,
    ) -> VideoRef:
        """Register the evidence video by path and SHA-256 (hashed here unless given)."""
        p = Path(path).resolve()
        if not p.is_file():
            raise InputError(f"{p}: no such file", code="E-FILE-MISSING")
        digest = sha256 or hash_file(p, progress, cancel)
        self.video = VideoRef(str(p), digest, p.stat().st_size, utc_now(), self._relative(p))
        self.dirty = True
        self.log(
            "video added", {"path": str(p), "sha256": digest, "size_bytes": self.video.size_bytes}
        )
        return self.video

    def check_evidence(
        self, progress: ProgressCallback | None = None, cancel: CancelToken | None = None
    ) -> str:
        """Re-hash the video; raise IntegrityError if it changed or is missing."""
        if self.video is None:
            raise InputError("the project has no video", code="E-NO-VIDEO")
        p = self.video_path()
        if p is None or not p.is_file():
            raise IntegrityError(
                f"the evidence video {self.video.path} is missing", code="E-EVIDENCE-MISSING"
            )
        digest = hash_file(p, progress, cancel)
        if digest != self.video.sha256:
            raise IntegrityError(
                f"the evidence video {p} has changed since it was added to the project "
                f"(SHA-256 {digest[:12]}... instead of {self.video.sha256[:12]}...)",
                code="E-EVIDENCE-CHANGED",
            )
        return digest

    def set_intrinsics(self, intrinsics: Intrinsics | None) -> None:
        self.intrinsics = intrinsics
        self.dirty = True
        self.log("intrinsics set", {"source": intrinsics.source if intrinsics else None})

    def set_target(self, target: TargetModel | None) -> None:
        self.target = target
        self.dirty = True
        self.log("target model set", {"name": target.name if target else None})

    def set_picks(self, picks: Picks | None) -> None:
        if picks == self.picks:
            return
        self.picks = picks
        self.dirty = True
        self.log(
            "corner picks set",
            {}
            if picks is None
            else {
                "t1": picks.t1,
                "t2": picks.t2,
                "corners_t1": len(picks.corners_t1),
                "corners_t2": len(picks.corners_t2),
            },
        )

    def set_calibration(self, cal: SceneCalibration | None) -> None:
        self.calibration = cal
        self.dirty = True
        self.log(
            "calibration set",
            {}
            if cal is None
            else {
                "roll_deg": cal.roll_deg,
                "tilt_deg": cal.tilt_deg,
                "implied_speed_mm_s": cal.implied_speed_mm_s,
                "speed_mm_s": cal.speed_mm_s,
                "reprojection_rms_px": cal.reprojection_rms_px,
                "warnings": list(cal.warnings),
            },
        )

    def set_calibration_settings(self, settings: dict) -> None:
        """Inputs of the calibration kept between sessions (e.g. the entered rail speed)."""
        dumps_json(settings)
        if settings != self.calibration_settings:
            self.calibration_settings = dict(settings)
            self.dirty = True
            self.log("calibration settings set", dict(settings))

    def set_processing(self, params: dict) -> None:
        dumps_json(params)  # JSON-able, finite numbers only
        self.processing = dict(params)
        self.dirty = True
        self.log("processing parameters set", dict(params))

    def add_output(self, path: str | os.PathLike, kind: str, sha256: str | None = None) -> dict:
        p = Path(path).resolve()
        entry = {
            "path": str(p),
            "relative_path": self._relative(p),
            "kind": kind,
            "sha256": sha256 or hash_file(p),
            "created_utc": utc_now(),
        }
        self.outputs.append(entry)
        self.dirty = True
        self.log("output written", entry)
        return entry

    def add_measurement(self, measurement: dict) -> None:
        dumps_json(measurement)
        self.measurements.append(dict(measurement))
        self.dirty = True
        self.log("measurement added", dict(measurement))

    def _relative(self, p: Path) -> str | None:
        if self.root is None:
            return None
        try:
            return os.path.relpath(p, self.root)
        except ValueError:  # another drive (Windows)
            return None

    # ----- file format ------------------------------------------------------------------------
    def to_json(self) -> dict:
        return {
            "format": PROJECT_FORMAT,
            "version": 1,
            "software": f"impress {__version__}",
            "case_id": self.case_id,
            "evidence_id": self.evidence_id,
            "examiner": self.examiner,
            "notes": self.notes,
            "created_utc": self.created_utc,
            "saved_utc": utc_now(),
            "video": self.video.to_json() if self.video else None,
            "intrinsics": self.intrinsics.to_json() if self.intrinsics else None,
            "target": self.target.to_json() if self.target else None,
            "picks": self.picks.to_json() if self.picks else None,
            "calibration": self.calibration.to_json() if self.calibration else None,
            "calibration_settings": self.calibration_settings,
            "processing": self.processing,
            "outputs": self.outputs,
            "measurements": self.measurements,
            "log_head": self._log_head,
        }

    def save(self, folder: str | os.PathLike | None = None) -> Path:
        """Write project.json atomically (into ``folder`` when given: "save as")."""
        if folder is not None:
            new_root = Path(folder).resolve()
            if new_root != self.root and (new_root / PROJECT_FILE).exists():
                raise InputError(f"{new_root} already holds a project", code="E-PROJECT-EXISTS")
            new_root.mkdir(parents=True, exist_ok=True)
            first = self.root is None
            self.root = new_root
            if self.video is not None:
                self.video = VideoRef(
                    self.video.path,
                    self.video.sha256,
                    self.video.size_bytes,
                    self.video.added_utc,
                    self._relative(Path(self.video.path)),
                )
            if first:
                append_log(new_root / LOG_FILE, "project created", {"case_id": self.case_id})
                for action, details, when in self._pending_log:
                    append_log(new_root / LOG_FILE, action, details, time_utc=when)
                self._pending_log.clear()
        if self.root is None:
            raise InputError("choose a folder for the new project", code="E-NO-FOLDER")
        root = self.root
        self.log("project saved", {})
        n, head = log_tail(root / LOG_FILE)
        self._log_head = {"entries": n, "sha256": head}
        try:
            write_json(root / PROJECT_FILE, self.to_json())
        except (OSError, ImpressError) as exc:
            self.log("project save failed", {"error": str(exc)})
            raise
        self.dirty = False
        return root / PROJECT_FILE

    @classmethod
    def load(cls, path: str | os.PathLike, verify: bool = True) -> Project:
        """Open a project folder (or its project.json); FormatError when damaged,
        IntegrityError when its log was tampered with (``verify``)."""
        p = Path(path)
        file = p / PROJECT_FILE if p.is_dir() else p
        if p.is_dir() and not file.exists():
            raise FormatError(
                f"{p}: not a project folder (no {PROJECT_FILE})", code="E-FILE-MISSING"
            )
        doc = read_json(file, PROJECT_FORMAT)
        where = f"{file}: "
        proj = cls(root=file.parent.resolve())
        try:
            for key in CASE_FIELDS:
                value = doc.get(key, "")
                if not isinstance(value, str):
                    raise FormatError(f"{where}{key} must be text")
                setattr(proj, key, value)
            proj.created_utc = str(doc.get("created_utc", ""))
            if doc.get("video") is not None:
                proj.video = VideoRef.from_json(doc["video"], where)
            sections = (
                ("intrinsics", Intrinsics),
                ("target", TargetModel),
                ("picks", Picks),
                ("calibration", SceneCalibration),
            )
            for key, kind in sections:
                sub = doc.get(key)
                if sub is None:
                    continue
                if not isinstance(sub, dict):
                    raise FormatError(f"{where}{key} must be an object")
                setattr(proj, key, kind.from_json(sub, f"{where}{key}: "))
            proj.calibration_settings = _typed(doc, "calibration_settings", dict, where)
            proj.processing = _typed(doc, "processing", dict, where)
            proj.outputs = _typed(doc, "outputs", list, where)
            proj.measurements = _typed(doc, "measurements", list, where)
            proj._log_head = _typed(doc, "log_head", dict, where)
        except FormatError:
            raise
        except (ImpressError, TypeError, ValueError, KeyError, AttributeError) as exc:
            raise FormatError(f"{where}damaged project ({exc})") from None
        if verify:
            verify_log(file.parent.resolve() / LOG_FILE, proj._log_head)
            _check_video_against_log(proj)
        return proj


def _check_video_against_log(proj: Project) -> None:
    """project.json is not chained: its evidence hash must be the one the (chained) log
    recorded when the video was added, or a swapped video with an edited hash would pass."""
    if proj.video is None or proj.log_file is None:
        return
    added = [e for e in read_log(proj.log_file) if e.get("action") == "video added"]
    if added and added[-1].get("details", {}).get("sha256") != proj.video.sha256:
        raise IntegrityError(
            f"{proj.project_file}: the video's SHA-256 differs from the one the log recorded "
            "when the video was added (project.json was edited)",
            code="E-LOG-TAMPERED",
        )


def _typed(doc: dict, key: str, kind: type, where: str) -> Any:
    value = doc.get(key, kind())
    if not isinstance(value, kind):
        raise FormatError(f"{where}{key} must be a JSON {'object' if kind is dict else 'list'}")
    return value


def create_project(folder: str | os.PathLike, **case_info: str) -> Project:
    """Make a new project folder (refused when it already holds one) and save it."""
    proj = Project()
    unknown = set(case_info) - set(CASE_FIELDS)
    if unknown:
        raise InputError(f"unknown case fields {sorted(unknown)}")
    for k, v in case_info.items():
        setattr(proj, k, str(v))
    proj.save(folder)
    return proj
