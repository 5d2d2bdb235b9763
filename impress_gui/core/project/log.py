"""The hash-chained project log, the evidence hash and who/when stamps (Qt-free).

Each line of ``log.jsonl`` is ``{"seq", "time_utc", "user", "software", "action", "details",
"prev_sha256"}`` where ``prev_sha256`` is the SHA-256 of the previous line's exact bytes (64
zeros for the first). Since format version 2 of the project every entry is also signed:
``public_key`` (base64 Ed25519 key), ``key_fingerprint`` and ``signature`` (over the entry
without ``signature``; see :mod:`~impress_gui.core.project.signing`). Entries written before signing
existed may lead the log unsigned; an unsigned entry after a signed one is refused.

:func:`check_log` re-checks the chain and the signatures and raises :class:`IntegrityError`
``E-LOG-TAMPERED`` when any line was edited, removed or reordered, ``E-SIGNATURE`` for a
signature by a key the project does not list. The log is read and appended to only as a
regular file of its own: never through a symbolic or hard link (``E-PROJECT-LINK``).
"""

from __future__ import annotations

import getpass
import hashlib
import json
import os
import stat
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from impress_gui import __version__
from impress_gui.core.base import codes
from impress_gui.core.base.errors import FormatError, IntegrityError
from impress_gui.core.base.fileio import sha256_file, sha256_path
from impress_gui.core.base.progress import CancelToken, ProgressCallback
from impress_gui.core.project.signing import ENTRY_CONTEXT, SigningKey, fingerprint, verify

LOG_FILE = "log.jsonl"
GENESIS = "0" * 64
MAX_LOG_BYTES = 256 * 1024 * 1024
FIELD_TYPES: dict[str, type] = {
    "time_utc": str,
    "user": str,
    "software": str,
    "action": str,
    "details": dict,
    "prev_sha256": str,
}
SIGNATURE_FIELDS = ("public_key", "key_fingerprint", "signature")
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
_CLOEXEC = getattr(os, "O_CLOEXEC", 0)


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
    of frames: the hash of its manifest, see :func:`~impress_gui.core.base.fileio.sha256_path`)."""
    if os.path.isdir(path):
        return sha256_path(path)
    return sha256_file(path, chunk, progress=progress, cancel=cancel, message="hashing the video")


# ----- reading and writing project files without following links ------------------------------
def read_no_follow(path: Path, what: str, max_bytes: int, missing_ok: bool = False) -> bytes | None:
    """The bytes of a project file that must be a regular file of its own: a symbolic link is
    refused (IntegrityError ``E-PROJECT-LINK``) and never followed, as are a folder, pipe or
    device (``E-NOT-A-FILE``), a file over ``max_bytes`` (``E-TOO-LARGE``) and an unreadable
    one (``E-FILE-READ``). A missing file gives None when ``missing_ok``."""
    from impress_gui.core.base.fileio import open_regular
    from impress_gui.core.base.outdir import reason

    try:
        fd = open_regular(path, what, max_bytes, follow_links=False, allow_empty=True)
    except FormatError as exc:
        if os.path.islink(path):
            raise _link_error(path) from None
        if exc.code == codes.E_FILE_MISSING and missing_ok:
            return None
        raise
    with os.fdopen(fd, "rb") as fh:
        try:
            data = fh.read(max_bytes + 1)
        except OSError as exc:
            raise FormatError(
                f"{path}: the {what} file cannot be read ({reason(exc)})", code=codes.E_FILE_READ
            ) from None
    if len(data) > max_bytes:
        raise FormatError(f"{path}: too large for a {what} file", code=codes.E_TOO_LARGE)
    return data


def _link_error(path: Path) -> IntegrityError:
    return IntegrityError(
        f"{path} is a symbolic link: a project's files must be files of their own inside the "
        "project folder (someone may have pointed it elsewhere)",
        code=codes.E_PROJECT_LINK,
    )


def _open_for_append(path: Path) -> int:
    """A descriptor to append to the log: never through a symbolic or hard link, never to a
    pipe or device (nothing is written anywhere but the project's own log file)."""
    from impress_gui.core.base.outdir import write_error

    flags = os.O_WRONLY | os.O_APPEND | os.O_CREAT | _NOFOLLOW | _CLOEXEC
    try:
        fd = os.open(path, flags | getattr(os, "O_NONBLOCK", 0), 0o666)
    except OSError as exc:
        if os.path.islink(path):
            raise _link_error(path) from None
        raise write_error(path, exc) from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise FormatError(
                f"{path} is not a regular file: the log cannot be written", code=codes.E_NOT_A_FILE
            )
        if st.st_nlink > 1:
            raise IntegrityError(
                f"{path} is a hard link shared with another file: the log is not written "
                "(copy the project folder to make its files its own)",
                code=codes.E_PROJECT_LINK,
            )
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


# ----- the log ------------------------------------------------------------------------------
@dataclass(frozen=True)
class LogState:
    """A checked log: its entries, the SHA-256 of each line, and the fingerprint of the key
    that signed each entry (None: unsigned, written before signing existed)."""

    entries: list[dict]
    hashes: list[str]
    signers: list[str | None]

    @property
    def last(self) -> str:
        return self.hashes[-1] if self.hashes else GENESIS

    @property
    def unsigned(self) -> int:
        return sum(1 for s in self.signers if s is None)

    def signer_runs(self) -> list[dict]:
        """Consecutive entries by one key: ``[{"from_seq", "to_seq", "key_fingerprint"}]``;
        a change of key part-way through the log starts a new run."""
        runs: list[dict] = []
        for i, fp in enumerate(self.signers, start=1):
            if runs and runs[-1]["key_fingerprint"] == fp:
                runs[-1]["to_seq"] = i
            else:
                runs.append({"from_seq": i, "to_seq": i, "key_fingerprint": fp})
        return runs


def _tampered(path: Path, text: str) -> IntegrityError:
    return IntegrityError(f"{path}: {text}", code=codes.E_LOG_TAMPERED)


def _check_entry(path: Path, i: int, entry: object, prev: str) -> dict:
    n = i + 1
    if not isinstance(entry, dict):
        raise _tampered(path, f"log line {n} is not a log entry (the log was edited)")
    seq = entry.get("seq")
    if type(seq) is not int or seq != n or entry.get("prev_sha256") != prev:
        raise _tampered(path, f"log entry {n} does not follow entry {i} (the log was edited)")
    for key, kind in FIELD_TYPES.items():
        if not isinstance(entry.get(key), kind):
            raise _tampered(path, f"log entry {n} is malformed ({key}; the log was edited)")
    return entry


def _check_signature(path: Path, n: int, entry: dict) -> str | None:
    """The signer's fingerprint of a verified entry; None for an unsigned one."""
    present = [k for k in SIGNATURE_FIELDS if k in entry]
    if not present:
        return None
    if len(present) != len(SIGNATURE_FIELDS):
        raise IntegrityError(f"{path}: log entry {n} has an incomplete signature",
                             code=codes.E_SIGNATURE)
    fp = fingerprint(entry["public_key"])
    if fp is None or fp != entry["key_fingerprint"]:
        raise IntegrityError(
            f"{path}: log entry {n} names a key that does not match its fingerprint",
            code=codes.E_SIGNATURE,
        )
    body = {k: v for k, v in entry.items() if k != "signature"}
    if not verify(entry["public_key"], entry["signature"], ENTRY_CONTEXT, body):
        raise _tampered(path, f"log entry {n} was changed after it was signed")
    return fp


def scan_log(path: str | os.PathLike, signatures: bool = True) -> LogState:
    """Read a log checking its hash chain (and every signature when ``signatures``); an
    unsigned entry after a signed one is refused. A missing log is an empty one."""
    path = Path(path)
    data = read_no_follow(path, "project log", MAX_LOG_BYTES, missing_ok=True)
    if not data:
        return LogState([], [], [])
    if not data.endswith(b"\n"):
        raise _tampered(path, "the last log entry is incomplete")
    prev = GENESIS
    entries: list[dict] = []
    hashes: list[str] = []
    signers: list[str | None] = []
    for i, line in enumerate(data.splitlines(keepends=True)):
        try:
            raw = json.loads(line)
        except (ValueError, RecursionError):
            raise _tampered(path, f"log line {i + 1} is not valid JSON") from None
        entry = _check_entry(path, i, raw, prev)
        if signatures:
            signer = _check_signature(path, i + 1, entry)
        else:
            signer = entry.get("key_fingerprint") if "signature" in entry else None
        if signer is None and signers and signers[-1] is not None:
            raise _tampered(path, f"log entry {i + 1} is unsigned but follows signed entries")
        entries.append(entry)
        prev = hashlib.sha256(line).hexdigest()
        hashes.append(prev)
        signers.append(signer)
    return LogState(entries, hashes, signers)


def read_log(path: str | os.PathLike) -> list[dict]:
    """Entries of a log file, checking the hash chain and the signatures."""
    return scan_log(path).entries


def check_log(
    path: str | os.PathLike,
    head: dict | None = None,
    keys: dict[str, str] | None = None,
    unsigned_entries: int | None = None,
) -> LogState:
    """Check a log completely: chain and signatures (:func:`scan_log`); with ``head`` (the
    ``{"entries", "sha256"}`` a save recorded) that no entry was removed or rewritten up to
    the save; with ``keys`` (fingerprint: base64 public key, the keys the signed project
    lists) that every signature is by one of them (``E-SIGNATURE``); with
    ``unsigned_entries`` that exactly that many leading entries are unsigned."""
    path = Path(path)
    state = scan_log(path)
    if head:
        n, sha = head.get("entries"), head.get("sha256")
        if type(n) is not int or n < 0 or not isinstance(sha, str):
            raise FormatError(f"{path}: the recorded log head is malformed")
        if n and not state.entries:
            raise _tampered(path, f"the log is missing or empty but {n} entries were recorded "
                            "at the last save (the log was deleted)")
        if len(state.entries) < n:
            raise _tampered(path, f"the log has {len(state.entries)} entries but {n} were "
                            "recorded at the last save (entries removed)")
        if n and state.hashes[n - 1] != sha:
            raise _tampered(path, f"log entry {n} differs from the one recorded at the last save")
    if unsigned_entries is not None and state.unsigned != unsigned_entries:
        raise _tampered(path, f"{state.unsigned} log entries are unsigned, but the signed "
                        f"project file records {unsigned_entries}")
    if keys is not None:
        for i, (entry, fp) in enumerate(zip(state.entries, state.signers, strict=True)):
            if fp is not None and keys.get(fp) != entry.get("public_key"):
                raise IntegrityError(
                    f"{path}: log entry {i + 1} is signed by key {fp}, which this project "
                    "does not list (an unknown key)",
                    code=codes.E_SIGNATURE,
                )
    return state


def verify_log(
    path: str | os.PathLike,
    head: dict | None = None,
    keys: dict[str, str] | None = None,
    unsigned_entries: int | None = None,
) -> int:
    """:func:`check_log`; the number of entries."""
    return len(check_log(path, head, keys, unsigned_entries).entries)


def append_log(
    path: str | os.PathLike,
    action: str,
    details: dict | None = None,
    user: str | None = None,
    time_utc: str | None = None,
    key: SigningKey | None = None,
) -> dict:
    """Append one entry to a log (chained to the last one, signed with ``key`` when given)
    and fsync it. Never written through a link; refused after signed entries without a key."""
    path = Path(path)
    state = scan_log(path, signatures=False)
    if key is None and state.signers and state.signers[-1] is not None:
        raise IntegrityError(f"{path}: this log is signed; an entry needs a signing key",
                             code=codes.E_SIGNATURE)
    entry: dict = {
        "seq": len(state.entries) + 1,
        "time_utc": time_utc or utc_now(),
        "user": user or current_user(),
        "software": f"impress {__version__}",
        "action": str(action),
        "details": details or {},
        "prev_sha256": state.last,
    }
    # what is signed is exactly what a reader parses back
    entry = json.loads(json.dumps(entry, allow_nan=False, default=str))
    if key is not None:
        entry["public_key"] = key.public_key
        entry["key_fingerprint"] = key.fingerprint
        entry["signature"] = key.sign(ENTRY_CONTEXT, entry)
    line = (json.dumps(entry, sort_keys=True, allow_nan=False) + "\n").encode()
    fd = _open_for_append(path)
    with os.fdopen(fd, "ab") as fh:
        fh.write(line)
        fh.flush()
        os.fsync(fh.fileno())
    return entry


def log_tail(path: Path) -> tuple[int, str]:
    """Number of entries of a log and the hash of its last line (what a save records)."""
    state = scan_log(path, signatures=False)
    return len(state.entries), state.last
