"""The scan project: one case's work in one folder (Qt-free).

Folder layout::

    <project>/project.json   format "impress.project", version 2 (rewritten atomically on save)
    <project>/log.jsonl      append-only log, one JSON object per line, hash-chained, signed

``project.json`` holds the case identifiers (``case_id``, ``evidence_id``, ``examiner``,
``notes``), the scan video as a *reference* (``video.path`` absolute, ``video.relative_path``
from the project folder, ``video.sha256`` and ``video.size_bytes`` recorded when it was added;
the evidence file is never copied, moved or written), and the work products as embedded
documents in their own formats: ``intrinsics`` (impress.intrinsics), ``target``
(impress.target), ``picks`` (impress.picks), ``calibration`` (impress.calibration), plus
``calibration_settings`` (e.g. the rail speed entered), free-form ``processing`` parameters,
``outputs`` (files written, with their SHA-256) and ``measurements``. ``log_head`` records how
many log entries existed at the last save and the hash of the last one, so a truncated log is
detected too.

Version 2 is signed (:mod:`~impress_gui.core.project.signing`): ``signing`` lists the examiners' public
keys (``keys``) and how many leading log entries predate signing (``unsigned_log_entries``);
``head_signature`` is the Ed25519 signature, by one of those keys, of the canonical content of
everything else (so of the log head too). Every log entry is signed as well. Loading checks
the types of every field (FormatError, never a crash), the signatures, the log against the
head, and that no file or recorded path leads out of the project through a link
(:class:`IntegrityError`: ``E-PROJECT-TAMPERED``, ``E-LOG-TAMPERED``, ``E-SIGNATURE``,
``E-PROJECT-LINK``, ``E-PROJECT-PATH``). A version 1 project (unsigned) is opened with a
warning in :attr:`Project.warnings`; saving it writes version 2, signed from then on.

The log (its line format, the hash chain and :func:`verify_log`), the evidence hash and the
who/when stamps are in :mod:`~impress_gui.core.project.log`.
"""

from __future__ import annotations

import copy
import os
import re
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeGuard

from impress_gui import __version__
from impress_gui.core.base import codes
from impress_gui.core.base.errors import FormatError, ImpressError, InputError, IntegrityError
from impress_gui.core.base.fileio import MAX_JSON_BYTES, dumps_json, parse_json, write_json
from impress_gui.core.base.progress import CancelToken, ProgressCallback
from impress_gui.core.calibration.geometry import Intrinsics
from impress_gui.core.calibration.picks import Picks
from impress_gui.core.calibration.scene import SceneCalibration
from impress_gui.core.calibration.target import TargetModel
from impress_gui.core.project.log import (
    LOG_FILE,
    LogState,
    append_log,
    check_log,
    current_user,
    hash_file,
    log_tail,
    read_log,
    read_no_follow,
    scan_log,
    utc_now,
    verify_log,
)
from impress_gui.core.project.signing import (
    ALGORITHM,
    SigningKey,
    check_head_signature,
    check_not_downgraded,
    check_outputs_against_log,
    check_recorded_paths,
    check_video_against_log,
    describe_signatures,
    lists_key,
    load_or_create_key,
    local_fingerprint,
    read_signing,
    sign_head,
)

PROJECT_FORMAT = "impress.project"
PROJECT_FILE = "project.json"
FORMAT_VERSION = 2
CASE_FIELDS = ("case_id", "evidence_id", "examiner", "notes")
SECTIONS = (
    ("intrinsics", Intrinsics),
    ("target", TargetModel),
    ("picks", Picks),
    ("calibration", SceneCalibration),
)
UNSIGNED_CODE = codes.E_PROJECT_UNSIGNED  # a warning's code: the project opens
UNSIGNED_WARNING = (
    "{file} was written by an older version of the software and is not signed "
    "[{code}]: its hash-chained log is checked, but an edit of the project file "
    "itself (case details, measurements, outputs, the video) cannot be detected. Saving it "
    "signs the project with your key from now on; its {n} earlier log entries stay unsigned."
)
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
    "describe_signatures",
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
    def from_json(cls, doc: object, where: str) -> VideoRef:
        if not isinstance(doc, dict):
            raise FormatError(f"{where}video must be an object")
        sha = doc.get("sha256")
        if not _is_sha256(sha):
            raise FormatError(f"{where}video.sha256 must be a SHA-256 hex digest")
        path, size = doc.get("path"), doc.get("size_bytes")
        if not _is_path(path) or type(size) is not int or size < 0:
            raise FormatError(f"{where}video needs a path and size_bytes")
        if not os.path.isabs(path):
            raise FormatError(f"{where}video.path must be an absolute path")
        rel = doc.get("relative_path")
        if rel is not None and (not _is_path(rel) or os.path.isabs(rel)):
            raise FormatError(f"{where}video.relative_path must be relative to the project folder")
        added = doc.get("added_utc", "")
        if not isinstance(added, str):
            raise FormatError(f"{where}video.added_utc must be text")
        return cls(path, sha, size, added, rel)


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
    #: what a load found worth telling the user (an unsigned project); never errors
    warnings: list[str] = field(default_factory=list, repr=False, compare=False)
    #: this examiner's key (loaded, or made, from the user's configuration on first use)
    signing_key: SigningKey | None = field(default=None, repr=False, compare=False)
    _pending_log: list[tuple[str, dict, str]] = field(default_factory=list, repr=False)
    _log_head: dict = field(default_factory=dict, repr=False)
    _format_version: int = field(default=FORMAT_VERSION, repr=False)
    _keys: list[dict] = field(default_factory=list, repr=False)  # signing.keys
    _unsigned: int = field(default=0, repr=False)  # signing.unsigned_log_entries
    _head_signature: dict = field(default_factory=dict, repr=False)
    _saved_doc: dict | None = field(default=None, repr=False, compare=False)
    _log_state: LogState | None = field(default=None, repr=False, compare=False)

    # ----- paths ------------------------------------------------------------------------------
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
            rel = self.root / self.video.relative_path
            if not os.path.islink(rel) and rel.exists():  # never through a link
                return rel.resolve()
        return p

    # ----- changes ----------------------------------------------------------------------------
    def log(self, action: str, details: dict | None = None) -> None:
        """Record an action in the log (buffered until the project has a folder)."""
        if self.log_file is None:
            self._pending_log.append((action, dict(details or {}), utc_now()))
            return
        key = self._signer()
        self._check_root()
        if self._saved_doc is not None and not lists_key(self._saved_doc, key):
            self._adopt_key(key)
        append_log(self.log_file, action, details, key=key)

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
            raise InputError(f"{p}: no such file", code=codes.E_FILE_MISSING)
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
            raise InputError("the project has no video", code=codes.E_NO_VIDEO)
        p = self.video_path()
        if p is None or not p.is_file():
            raise IntegrityError(
                f"the evidence video {self.video.path} is missing", code=codes.E_EVIDENCE_MISSING
            )
        digest = hash_file(p, progress, cancel)
        if digest != self.video.sha256:
            raise IntegrityError(
                f"the evidence video {p} has changed since it was added to the project "
                f"(SHA-256 {digest[:12]}... instead of {self.video.sha256[:12]}...)",
                code=codes.E_EVIDENCE_CHANGED,
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

    def discard_unsaved(self) -> list[str]:
        """The user discarded the changes since the last save: the reconstructions made since
        then (in the project's ``reconstructions/`` folder, not in the saved record) are
        removed with the calibration kept beside each, and the log says so. The log itself is
        never rewritten: what was done stays recorded, followed by this entry. Returns the
        removed paths, relative to the project folder."""
        if self.root is None:
            return []
        saved = {o.get("relative_path") for o in (self._saved_doc or {}).get("outputs", [])}
        base = (self.root / "reconstructions").resolve()
        removed: list[str] = []
        for entry in list(self.outputs):
            if entry.get("kind") != "reconstruction" or entry.get("relative_path") in saved:
                continue
            folder = Path(entry["path"]).parent
            if folder.parent != base or folder.is_symlink() or not folder.is_dir():
                continue
            shutil.rmtree(folder)
            removed.append(str(self._relative(folder) or folder))
            cal = folder.with_name(folder.name + ".calibration.json")
            if cal.is_file() and not cal.is_symlink():
                cal.unlink()
                removed.append(str(self._relative(cal) or cal))
        self.log("unsaved changes discarded", {"removed": removed})
        self.dirty = False
        return removed

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


    # ----- signing ------------------------------------------------------------------------------
    def _signer(self) -> SigningKey:
        if self.signing_key is None:
            self.signing_key = load_or_create_key()
        return self.signing_key

    def _check_root(self) -> None:
        """Nothing is written through a project folder that became a link after it opened."""
        if self.root is not None and os.path.realpath(self.root) != str(self.root):
            raise IntegrityError(
                f"{self.root}: the project folder is now a symbolic link or was moved; "
                "nothing was written (open the project again)",
                code=codes.E_PROJECT_LINK,
            )

    def _key_map(self) -> dict[str, str]:
        return {k["fingerprint"]: k["public_key"] for k in self._keys}

    def _adopt_key(self, key: SigningKey) -> None:
        """Before a key the signed project file does not list signs anything in it (another
        examiner opening the case), record it there: the file as last saved, checked again,
        with the key added and the log head moved to now, signed by that key. Nothing else
        of the file changes (unsaved edits stay unsaved)."""
        assert self.root is not None
        on_disk = Project.load(self.root)  # never sign over a record changed meanwhile
        doc = copy.deepcopy(on_disk._saved_doc)
        if doc is None or lists_key(doc, key):  # recorded meanwhile (another window)
            self._saved_doc = doc
            return
        record = _key_record(key)
        doc.pop("head_signature", None)
        doc["signing"]["keys"].append(record)
        n, last = log_tail(self.root / LOG_FILE)
        doc["log_head"] = {"entries": n, "sha256": last}
        doc = sign_head(doc, key)
        write_json(self.root / PROJECT_FILE, doc)
        self._saved_doc = doc
        self._head_signature = doc["head_signature"]
        if key.fingerprint not in self._key_map():
            self._keys.append(dict(record))
        append_log(
            self.root / LOG_FILE,
            "signing key added",
            {"key_fingerprint": key.fingerprint, "user": record["user"]},
            key=key,
        )

    def signature_info(self) -> dict:
        """What a report or export should carry to tie itself to this case record, as of the
        last save or check: ``signed`` (a version 2 project file with a head signature),
        ``algorithm``, ``key_fingerprint`` / ``public_key`` / ``user`` of the key that made
        ``head_signature`` (base64), ``log_head`` (entries, SHA-256 of the last one),
        ``keys`` (every key the project lists, ``this_installation`` marking this examiner's),
        ``log_signers`` (runs of consecutive log entries by one key: a change of key part-way
        shows as a new run; ``key_fingerprint`` None for entries written before signing),
        ``unsigned_log_entries``, ``this_installation_key`` and ``unsaved_changes``."""
        local = local_fingerprint()
        head_fp = self._head_signature.get("key_fingerprint")
        signer = next((k for k in self._keys if k["fingerprint"] == head_fp), None)
        signed = self._format_version >= FORMAT_VERSION and bool(self._head_signature)
        return {
            "signed": signed,
            "format_version": self._format_version,
            "algorithm": ALGORITHM,
            "key_fingerprint": head_fp,
            "public_key": signer["public_key"] if signer else None,
            "user": signer.get("user") if signer else None,
            "head_signature": self._head_signature.get("signature"),
            "log_head": dict(self._log_head),
            "keys": [
                {
                    "fingerprint": k["fingerprint"],
                    "public_key": k["public_key"],
                    "user": k.get("user", ""),
                    "added_utc": k.get("added_utc", ""),
                    "this_installation": k["fingerprint"] == local,
                }
                for k in self._keys
            ],
            "log_signers": self._log_state.signer_runs() if self._log_state else [],
            "unsigned_log_entries": self._unsigned if signed else None,
            "this_installation_key": local,
            "unsaved_changes": self.dirty,
        }

    def verify(self) -> dict:
        """Check the saved record again as a load does (signatures, log, links, paths);
        :meth:`signature_info` of what is on disk. IntegrityError/FormatError if changed."""
        if self.root is None:
            raise InputError("the project has not been saved yet", code=codes.E_NO_FOLDER)
        fresh = Project.load(self.root)
        self._log_state = fresh._log_state
        return fresh.signature_info() | {"unsaved_changes": self.dirty}

    # ----- file format ------------------------------------------------------------------------
    def to_json(self) -> dict:
        """The project file's content, without its head signature."""
        return {
            "format": PROJECT_FORMAT,
            "version": FORMAT_VERSION,
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
            "signing": {
                "algorithm": ALGORITHM,
                "keys": self._keys,
                "unsigned_log_entries": self._unsigned,
            },
        }

    def save(self, folder: str | os.PathLike | None = None) -> Path:
        """Write project.json atomically and signed (into ``folder`` when given: "save as").
        The record on disk is checked first: a save never signs over a changed log or file."""
        key = self._signer()  # E-KEY before anything is written
        if folder is not None:
            self._move_to(Path(folder).resolve(), key)
        if self.root is None:
            raise InputError("choose a folder for the new project", code=codes.E_NO_FOLDER)
        root = self.root
        self._check_root()
        if os.path.lexists(root / PROJECT_FILE):
            state = Project.load(root)._log_state or LogState([], [], [])
        else:
            state = check_log(root / LOG_FILE)
        if self._saved_doc is not None and not lists_key(self._saved_doc, key):
            self._adopt_key(key)
        known = self._key_map()
        if key.fingerprint not in known:
            self._keys.append(_key_record(key))
        for entry, fp in zip(state.entries, state.signers, strict=True):
            if fp is not None and fp not in known and fp != key.fingerprint:
                # signed entries of an unsigned (version 1) project, kept through the migration
                self._keys.append({**_key_record(None), "public_key": entry["public_key"],
                                   "fingerprint": fp, "user": entry.get("user", "")})
                known[fp] = entry["public_key"]
        self._unsigned = state.unsigned
        if self._format_version < FORMAT_VERSION:
            self._format_version = FORMAT_VERSION
            self.log(
                "project signed",
                {"from_format_version": 1, "unsigned_log_entries": state.unsigned,
                 "key_fingerprint": key.fingerprint},
            )
        self.log("project saved", {})
        n, head = log_tail(root / LOG_FILE)
        self._log_head = {"entries": n, "sha256": head}
        try:
            doc = sign_head(self.to_json(), key)
            write_json(root / PROJECT_FILE, doc)
        except (OSError, ImpressError) as exc:
            self.log("project save failed", {"error": str(exc)})
            raise
        self._saved_doc = doc
        self._head_signature = doc["head_signature"]
        self._log_state = scan_log(root / LOG_FILE, signatures=False)  # checked just before
        self.warnings = []
        self.dirty = False
        return root / PROJECT_FILE

    def _move_to(self, new_root: Path, key: SigningKey) -> None:
        """Give the project a (new) folder: refused when the folder holds a project."""
        if new_root == self.root:
            return
        if os.path.lexists(new_root / PROJECT_FILE) or os.path.lexists(new_root / LOG_FILE):
            raise InputError(f"{new_root} already holds a project", code=codes.E_PROJECT_EXISTS)
        try:
            new_root.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            from impress_gui.core.base.outdir import write_error

            raise write_error(new_root, exc, "make the folder") from None
        first = self.root is None
        self.root = new_root
        self._saved_doc, self._head_signature, self._log_head = None, {}, {}
        self._format_version = FORMAT_VERSION  # the new folder's log is signed from its start
        if self.video is not None:
            self.video = VideoRef(
                self.video.path,
                self.video.sha256,
                self.video.size_bytes,
                self.video.added_utc,
                self._relative(Path(self.video.path)),
            )
        if first:
            append_log(new_root / LOG_FILE, "project created", {"case_id": self.case_id}, key=key)
            for action, details, when in self._pending_log:
                append_log(new_root / LOG_FILE, action, details, time_utc=when, key=key)
            self._pending_log.clear()

    @classmethod
    def load(cls, path: str | os.PathLike, verify: bool = True) -> Project:
        """Open a project folder (or its project.json). Every field is type-checked
        (FormatError with a code, never another exception); with ``verify`` the signatures,
        the log and every recorded path are checked (IntegrityError: see the module)."""
        file = _project_file(Path(path))
        raw = read_no_follow(file, PROJECT_FORMAT, MAX_JSON_BYTES)
        doc = parse_json(raw or b"", file, PROJECT_FORMAT, versions=(1, FORMAT_VERSION))
        where = f"{file}: "
        proj = cls(root=file.parent)
        proj._format_version = doc["version"]
        if proj._format_version >= FORMAT_VERSION:
            # a signed file: any edit is tampering, whatever it did to the fields' types
            proj._keys, proj._unsigned, proj._head_signature = read_signing(doc, where)
            if verify:
                check_head_signature(doc, proj._key_map(), proj._head_signature, file)
            proj._saved_doc = copy.deepcopy(doc)
        proj._read(doc, where)
        if verify:
            proj._verify_record(file)
        return proj

    def _read(self, doc: dict, where: str) -> None:
        for key in CASE_FIELDS:
            setattr(self, key, _text(doc, key, where))
        self.created_utc = _text(doc, "created_utc", where)
        _text(doc, "software", where)
        _text(doc, "saved_utc", where)
        if doc.get("video") is not None:
            self.video = VideoRef.from_json(doc["video"], where)
        for key, kind in SECTIONS:
            sub = doc.get(key)
            if sub is None:
                continue
            if not isinstance(sub, dict):
                raise FormatError(f"{where}{key} must be an object")
            try:
                setattr(self, key, kind.from_json(sub, f"{where}{key}: "))
            except ImpressError as exc:
                raise FormatError(_plain(str(exc)), code=exc.code) from None
            except (ArithmeticError, LookupError, TypeError, ValueError, AttributeError,
                    RecursionError):
                raise FormatError(f"{where}the {key} section is damaged") from None
        self.calibration_settings = _settings(_typed(doc, "calibration_settings", dict, where),
                                              where)
        self.processing = _processing(_typed(doc, "processing", dict, where), where)
        outputs = _typed(doc, "outputs", list, where)
        self.outputs = [_output(o, f"{where}outputs[{i}]") for i, o in enumerate(outputs)]
        found = _typed(doc, "measurements", list, where)
        self.measurements = [_measurement(m, f"{where}measurements[{i}]")
                             for i, m in enumerate(found)]
        self._log_head = _log_head(doc, where, self._format_version)

    def _verify_record(self, file: Path) -> None:
        assert self.root is not None
        log = self.root / LOG_FILE
        if self._format_version >= FORMAT_VERSION:
            state = check_log(log, self._log_head, self._key_map(), self._unsigned)
        else:
            state = check_log(log, self._log_head or None)
            check_not_downgraded(state, self._log_head, file)
            check_outputs_against_log(self.outputs, state, file)
            self.warnings.append(
                UNSIGNED_WARNING.format(file=file, n=len(state.entries), code=UNSIGNED_CODE)
            )
        if not state.entries:
            raise IntegrityError(
                f"{log}: the project's log is missing or empty; a saved project always has "
                "one (it was deleted)",
                code=codes.E_LOG_TAMPERED,
            )
        check_video_against_log(self.video.sha256 if self.video else None, state, file)
        check_recorded_paths(
            self.root, self.outputs, self.video.to_json() if self.video else None, file
        )
        self._log_state = state


# ----- what a loaded record must be -------------------------------------------------------------
def _project_file(p: Path) -> Path:
    """project.json of a folder (a folder given through a link is fine: it is the user's
    choice), or the file given, which must not itself be a link."""
    if os.path.isdir(p):
        file = p.resolve() / PROJECT_FILE
        if not os.path.lexists(file):
            raise FormatError(
                f"{p}: not a project folder (no {PROJECT_FILE})", code=codes.E_FILE_MISSING
            )
        return file
    return p.parent.resolve() / p.name


_HEX = re.compile(r"[0-9a-fA-F]{64}")
_PLAIN = {"str": "text", "int": "a whole number", "float": "a number", "bool": "true or false",
          "list": "a list", "dict": "an object", "NoneType": "null"}


def _plain(text: str) -> str:
    """Messages of the embedded documents' readers without Python's names for types."""
    text = re.sub(r"\(<class 'int'>, <class 'float'>\)", "a number", text)
    text = re.sub(r"has the wrong type \((\w+)\)",
                  lambda m: f"has the wrong type (it is {_PLAIN.get(m[1], 'something else')})",
                  text)
    return re.sub(r"must be (str|int|float|bool|list|dict)\b", lambda m: f"must be {_PLAIN[m[1]]}",
                  text)


def _is_sha256(value: object) -> TypeGuard[str]:
    return isinstance(value, str) and _HEX.fullmatch(value) is not None


def _is_path(value: object) -> TypeGuard[str]:
    return isinstance(value, str) and 0 < len(value) < 4096 and "\x00" not in value


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _text(doc: dict, key: str, where: str) -> str:
    value = doc.get(key, "")
    if not isinstance(value, str):
        raise FormatError(f"{where}{key} must be text")
    return value


def _typed(doc: dict, key: str, kind: type, where: str) -> Any:
    value = doc.get(key, kind())
    if not isinstance(value, kind):
        raise FormatError(f"{where}{key} must be a JSON {'object' if kind is dict else 'list'}")
    return copy.deepcopy(value)


def _settings(doc: dict, where: str) -> dict:
    speed = doc.get("speed_mm_s")
    if speed is not None and (not _is_number(speed) or speed <= 0):
        raise FormatError(f"{where}calibration_settings.speed_mm_s must be a positive number")
    return doc


def _processing(doc: dict, where: str) -> dict:
    hr = doc.get("height_range_mm")
    if hr is not None and not (isinstance(hr, list) and len(hr) == 2
                               and all(_is_number(v) for v in hr)):
        raise FormatError(f"{where}processing.height_range_mm must be two numbers")
    rois = doc.get("rois")
    if rois is not None and not (isinstance(rois, dict) and all(
            isinstance(v, list) and all(_is_number(c) for c in v) for v in rois.values())):
        raise FormatError(f"{where}processing.rois must map names to lists of numbers")
    return doc


def _output(o: object, where: str) -> dict:
    if not isinstance(o, dict):
        raise FormatError(f"{where} must be an object")
    if not _is_path(o.get("path")) or not os.path.isabs(o["path"]):
        raise FormatError(f"{where}.path must be an absolute path")
    rel = o.get("relative_path")
    if rel is not None and (not _is_path(rel) or os.path.isabs(rel)):
        raise FormatError(f"{where}.relative_path must be relative to the project folder")
    if not isinstance(o.get("kind"), str):
        raise FormatError(f"{where}.kind must be text")
    if not _is_sha256(o.get("sha256")):
        raise FormatError(f"{where}.sha256 must be a SHA-256 hex digest")
    if not isinstance(o.get("created_utc", ""), str):
        raise FormatError(f"{where}.created_utc must be text")
    return o


def _measurement(m: object, where: str) -> dict:
    if not isinstance(m, dict):
        raise FormatError(f"{where} must be an object")
    for key in ("id", "kind", "label", "note", "created_utc"):
        if key in m and not isinstance(m[key], str):
            raise FormatError(f"{where}.{key} must be text")
    pts = m.get("points_mm", [])
    if not isinstance(pts, list) or not all(
        isinstance(p, list) and 2 <= len(p) <= 3 and all(_is_number(c) for c in p) for p in pts
    ):
        raise FormatError(f"{where}.points_mm must be a list of [x, y] points in mm")
    for key in ("params", "values"):
        if key in m and not isinstance(m[key], dict):
            raise FormatError(f"{where}.{key} must be an object")
    width = m.get("params", {}).get("width_mm")
    if width is not None and not _is_number(width):
        raise FormatError(f"{where}.params.width_mm must be a number")
    return m


def _log_head(doc: dict, where: str, version: int) -> dict:
    head = doc.get("log_head", {})
    if not isinstance(head, dict):
        raise FormatError(f"{where}log_head must be an object")
    if not head and version < FORMAT_VERSION:
        return {}
    n, sha = head.get("entries"), head.get("sha256")
    if type(n) is not int or n < (1 if version >= FORMAT_VERSION else 0):
        raise FormatError(f"{where}log_head.entries must be a count of log entries")
    if not _is_sha256(sha):
        raise FormatError(f"{where}log_head.sha256 must be a SHA-256 hex digest")
    return {"entries": n, "sha256": sha}


def _key_record(key: SigningKey | None) -> dict:
    return {
        "public_key": key.public_key if key else "",
        "fingerprint": key.fingerprint if key else "",
        "user": current_user(),
        "added_utc": utc_now(),
    }


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
