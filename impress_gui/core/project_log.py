"""The hash-chained project log, the evidence hash and who/when stamps (Qt-free).

Each line of ``log.jsonl`` is ``{"seq", "time_utc", "user", "software", "action", "details",
"prev_sha256"}`` where ``prev_sha256`` is the SHA-256 of the previous line's exact bytes (64
zeros for the first). :func:`verify_log` re-checks the chain and raises
:class:`IntegrityError` ``E-LOG-TAMPERED`` when any line was edited, removed or reordered.
"""

from __future__ import annotations

import getpass
import hashlib
import json
import os
from datetime import datetime, timezone
from pathlib import Path

from impress_gui import __version__
from impress_gui.core.errors import IntegrityError
from impress_gui.core.progress import CancelToken, ProgressCallback, report

LOG_FILE = "log.jsonl"
GENESIS = "0" * 64


def utc_now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


def current_user() -> str:
    try:
        return getpass.getuser()
    except (KeyError, OSError, ImportError):
        return os.environ.get("USERNAME", "unknown")


def hash_file(
    path: str | os.PathLike,
    progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
    chunk: int = 4 << 20,
) -> str:
    """SHA-256 of a file read (never written) in chunks, with progress and cancel (a folder
    of frames: the hash of its manifest, see :func:`~impress_gui.core.fileio.sha256_path`)."""
    if os.path.isdir(path):
        from impress_gui.core.fileio import sha256_path

        return sha256_path(path)
    h = hashlib.sha256()
    total = max(1, os.path.getsize(path))
    done = 0
    with open(path, "rb") as fh:
        while block := fh.read(chunk):
            if cancel is not None:
                cancel.check()
            h.update(block)
            done += len(block)
            report(progress, done / total, "hashing the video")
    return h.hexdigest()


# ----- the log ------------------------------------------------------------------------------
def _line_hash(line: bytes) -> str:
    return hashlib.sha256(line).hexdigest()


def read_log(path: str | os.PathLike) -> list[dict]:
    """Entries of a log file, checking the hash chain (see :func:`verify_log`)."""
    return _check_chain(Path(path))[0]


def verify_log(path: str | os.PathLike, head: dict | None = None) -> int:
    """Check the hash chain of a log; return the number of entries. ``head`` is the
    ``{"entries", "sha256"}`` recorded in project.json at the last save (detects truncation)."""
    entries, last = _check_chain(Path(path))
    if head:
        n = int(head.get("entries", 0))
        if len(entries) < n:
            raise IntegrityError(
                f"{path}: the log has {len(entries)} entries but {n} were "
                "recorded at the last save (entries removed)",
                code="E-LOG-TAMPERED",
            )
        if n and _check_chain(Path(path), stop=n)[1] != head.get("sha256"):
            raise IntegrityError(
                f"{path}: log entry {n} differs from the one recorded at the last save",
                code="E-LOG-TAMPERED",
            )
    return len(entries)


def _check_chain(path: Path, stop: int | None = None) -> tuple[list[dict], str]:
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return [], GENESIS
    if data and not data.endswith(b"\n"):
        raise IntegrityError(f"{path}: the last log entry is incomplete", code="E-LOG-TAMPERED")
    prev = GENESIS
    entries: list[dict] = []
    for i, line in enumerate(data.splitlines(keepends=True)):
        if stop is not None and i >= stop:
            break
        try:
            entry = json.loads(line)
        except ValueError:
            raise IntegrityError(
                f"{path}: log line {i + 1} is not valid JSON", code="E-LOG-TAMPERED"
            ) from None
        if (
            not isinstance(entry, dict)
            or entry.get("prev_sha256") != prev
            or entry.get("seq") != i + 1
        ):
            raise IntegrityError(
                f"{path}: log entry {i + 1} does not follow entry {i} (the log was edited)",
                code="E-LOG-TAMPERED",
            )
        entries.append(entry)
        prev = _line_hash(line)
    return entries, prev


def append_log(
    path: str | os.PathLike,
    action: str,
    details: dict | None = None,
    user: str | None = None,
    time_utc: str | None = None,
) -> dict:
    """Append one entry to a log (chained to the last one) and fsync it."""
    path = Path(path)
    entries, prev = _check_chain(path)
    entry = {
        "seq": len(entries) + 1,
        "time_utc": time_utc or utc_now(),
        "user": user or current_user(),
        "software": f"impress {__version__}",
        "action": str(action),
        "details": details or {},
        "prev_sha256": prev,
    }
    line = (json.dumps(entry, sort_keys=True, allow_nan=False, default=str) + "\n").encode()
    with open(path, "ab") as fh:
        fh.write(line)
        fh.flush()
        os.fsync(fh.fileno())
    return entry


def log_tail(path: Path) -> tuple[int, str]:
    """Number of entries of a log and the hash of its last line (what a save records)."""
    entries, last = _check_chain(path)
    return len(entries), last
