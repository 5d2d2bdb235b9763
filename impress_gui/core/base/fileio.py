"""Atomic writes, hashing and versioned JSON documents.

Every JSON document the product writes has a ``format`` name and an integer ``version``.
Readers check both and turn every failure (missing file, bad JSON, wrong kind, NaN, unknown
version) into a :class:`~impress_gui.core.base.errors.FormatError` naming the file and the problem.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import math
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from impress_gui.core.base import codes
from impress_gui.core.base.errors import FormatError
from impress_gui.core.base.progress import CancelToken, ProgressCallback, report

MAX_JSON_BYTES = 50 * 1024 * 1024
_UMASK = os.umask(0)
os.umask(_UMASK)


def sha256_file(path: str | os.PathLike | int, chunk: int = 1 << 20, *,
                progress: ProgressCallback | None = None, cancel: CancelToken | None = None,
                message: str = "hashing") -> str:
    """SHA-256 hex digest of a file, read (never written) in chunks: ``path``, or an open
    descriptor (read from its start with ``os.pread``: its position is left alone).
    ``cancel`` is checked and ``progress`` told the share read (with ``message``) after each
    chunk."""
    if isinstance(path, int):
        fd = path
        return _sha256_chunks(lambda done: os.pread(fd, chunk, done), os.fstat(fd).st_size,
                              progress, cancel, message)
    with open(path, "rb") as fh:
        return _sha256_chunks(lambda _done: fh.read(chunk), os.fstat(fh.fileno()).st_size,
                              progress, cancel, message)


def _sha256_chunks(read, size: int, progress: ProgressCallback | None,
                   cancel: CancelToken | None, message: str) -> str:
    h = hashlib.sha256()
    done = 0
    while block := read(done):
        if cancel is not None:
            cancel.check()
        h.update(block)
        done += len(block)
        if progress is not None:
            report(progress, done / max(1, size), message)
    return h.hexdigest()


def open_regular(path: str | os.PathLike, what: str, max_bytes: int, *,
                 follow_links: bool = True, allow_empty: bool = False) -> int:
    """Open ``path`` read-only after checking it is a regular, non-empty file of at most
    ``max_bytes``; return the descriptor. A FIFO, device, folder or socket is refused without
    blocking (FormatError ``E-NOT-A-FILE``), as are a missing (``E-FILE-MISSING``), empty
    (``E-FILE-EMPTY``), oversized (``E-TOO-LARGE``) or unreadable (``E-FILE-READ``) file."""
    import stat

    p = Path(path)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
    if not follow_links:
        flags |= getattr(os, "O_NOFOLLOW", 0)
    try:
        fd = os.open(p, flags)
    except FileNotFoundError:
        raise FormatError(f"{p}: no such {what} file", code=codes.E_FILE_MISSING) from None
    except IsADirectoryError:
        raise FormatError(f"{p} is a folder, not a {what} file", code=codes.E_NOT_A_FILE) from None
    except OSError as exc:
        raise FormatError(f"{p}: the {what} file cannot be read ({_os_reason(exc)})",
                          code=codes.E_FILE_READ) from None
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise FormatError(f"{p} is a folder, not a {what} file", code=codes.E_NOT_A_FILE)
        if not stat.S_ISREG(st.st_mode):
            raise FormatError(f"{p} is not a regular file (a device, pipe or socket): give a "
                              f"{what} file", code=codes.E_NOT_A_FILE)
        if st.st_size == 0 and not allow_empty:
            raise FormatError(f"{p}: the {what} file is empty", code=codes.E_FILE_EMPTY)
        if st.st_size > max_bytes:
            raise FormatError(f"{p}: {st.st_size} bytes is too large for a {what} file",
                              code=codes.E_TOO_LARGE)
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def _os_reason(exc: OSError) -> str:
    from impress_gui.core.base.outdir import reason

    return reason(exc)


def read_regular(path: str | os.PathLike, what: str, max_bytes: int) -> bytes:
    """The bytes of a regular file checked as in :func:`open_regular`."""
    fd = open_regular(path, what, max_bytes)
    with os.fdopen(fd, "rb") as fh:
        data = fh.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise FormatError(f"{path}: too large for a {what} file", code=codes.E_TOO_LARGE)
    return data


FRAME_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")


def sha256_path(path: str | os.PathLike) -> str:
    """SHA-256 of a video file, or of a folder of frames: the hash of its manifest - one line
    ``<sha256>  <name>`` per frame file (sorted by name), so renaming, removing, adding or
    changing any frame changes it."""
    p = Path(path)
    if not p.is_dir():
        return sha256_file(p)
    lines = [f"{sha256_file(f)}  {f.name}\n" for f in sorted(p.iterdir())
             if f.is_file() and f.suffix.lower() in FRAME_SUFFIXES]
    return hashlib.sha256("".join(lines).encode()).hexdigest()


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike, mode: str = "wb") -> Iterator[Any]:
    """Open a temporary file beside ``path``; on success fsync and rename it into place.

    On any exception the temporary file is removed and ``path`` keeps its previous content;
    an operating-system error (full disk, read-only folder, no permission) becomes
    :class:`~impress_gui.core.base.outdir.WriteError` ``E-WRITE`` naming ``path``."""
    from impress_gui.core.base import workfiles
    from impress_gui.core.base.outdir import write_error

    path = Path(path)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
        workfiles.note(tmp)
        with os.fdopen(fd, mode) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_UMASK)
        os.replace(tmp, path)
        workfiles.done(tmp)
    except OSError as exc:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            workfiles.done(tmp)
        raise write_error(path, exc) from None
    except BaseException:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
            workfiles.done(tmp)
        raise


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_output(path, "wb") as fh:
        fh.write(data)


def _check_finite(obj: Any, where: str = "$") -> None:
    if isinstance(obj, float) and not math.isfinite(obj):
        raise FormatError(f"non-finite number at {where}")
    if isinstance(obj, dict):
        for k, v in obj.items():
            _check_finite(v, f"{where}.{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            _check_finite(v, f"{where}[{i}]")


def dumps_json(doc: dict) -> str:
    _check_finite(doc)
    return json.dumps(doc, indent=2, sort_keys=False, allow_nan=False) + "\n"


def write_json(path: str | os.PathLike, doc: dict) -> None:
    """Write a JSON document atomically (finite numbers only)."""
    atomic_write_bytes(path, dumps_json(doc).encode("utf-8"))


def _reject_constant(name: str) -> None:
    raise ValueError(f"{name} is not allowed")


def read_json(path: str | os.PathLike, fmt: str, versions: tuple[int, ...] = (1,)) -> dict:
    """Read a versioned JSON document of kind ``fmt``; raise FormatError on any problem."""
    path = Path(path)
    return parse_json(read_regular(path, fmt, MAX_JSON_BYTES), path, fmt, versions)


def parse_json(raw: bytes, path: str | os.PathLike, fmt: str,
               versions: tuple[int, ...] = (1,)) -> dict:
    """As :func:`read_json`, from bytes already read (``path`` names them in messages)."""
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FormatError(f"{path}: not a text file (byte {exc.start} is not UTF-8)",
                          code=codes.E_JSON) from None
    try:
        doc = json.loads(text, parse_constant=_reject_constant)
    except json.JSONDecodeError as exc:
        raise FormatError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno}, column "
                          f"{exc.colno})", code=codes.E_JSON) from None
    except (ValueError, RecursionError):
        raise FormatError(f"{path}: not valid JSON (too deeply nested, or a number or "
                          "constant that is not allowed)", code=codes.E_JSON) from None
    if not isinstance(doc, dict):
        raise FormatError(f"{path}: expected a JSON object for a {fmt} file")
    got = doc.get("format")
    if got != fmt:
        raise FormatError(
            f"{path}: this is not a {fmt} file (its format field is {got!r})",
            code=codes.E_WRONG_FORMAT,
        )
    version = doc.get("version")
    if version not in versions:
        raise FormatError(
            f"{path}: {fmt} version {version!r} is not supported (this software reads "
            f"{', '.join(map(str, versions))})",
            code=codes.E_VERSION,
        )
    try:
        _check_finite(doc)
    except FormatError as exc:
        raise FormatError(f"{path}: {exc}") from None
    return doc


def require(doc: dict, key: str, kind: type | tuple[type, ...], where: str = "") -> Any:
    """Fetch ``doc[key]`` checking its type; raise FormatError naming the key otherwise."""
    if key not in doc:
        raise FormatError(f"{where}missing field {key!r}")
    value = doc[key]
    want = _KIND_WORDS.get(kind, "of another kind")
    if kind is float:
        kind = (int, float)
    if isinstance(value, bool) and kind is not bool:
        raise FormatError(f"{where}field {key!r} must be {want}, not true/false")
    if not isinstance(value, kind):
        raise FormatError(f"{where}field {key!r} must be {want}, not "
                          f"{_KIND_WORDS.get(type(value), 'something else')}")
    return value


_KIND_WORDS: dict = {float: "a number", int: "a whole number", str: "text", bool: "true or false",
                     dict: "an object", list: "a list", type(None): "null"}


def float_array(value: Any, shape: tuple[int, ...], name: str) -> Any:
    """Convert a JSON list to a float64 array of exactly ``shape`` with finite values."""
    import numpy as np

    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise FormatError(f"{name} must be numbers of shape {shape}") from None
    if arr.shape != shape:
        raise FormatError(f"{name} must have shape {shape}, not {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise FormatError(f"{name} contains NaN or infinity")
    if np.any(np.abs(arr) > 1e9):
        raise FormatError(f"{name} contains absurdly large values")
    return arr
