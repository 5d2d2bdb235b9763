"""Where outputs may go: checked before any work starts, so evidence is never touched.

An output *folder* (a reconstruction, a simulation, a validation run) is made by the product and
marked as its own with :data:`MARK_FILE`. An existing folder is replaced only when it carries the
mark of the same kind and holds nothing but files the product writes for that kind; an empty
folder is used as it is. Everything else is refused with a coded error before any work:
a file, a symbolic link, the current folder or one of its parents, a folder holding (or inside)
one of the run's inputs, and any other non-empty folder.

An output *file* (a calibration, intrinsics) may replace only a file of the same kind written by
the product, never an input, a folder, a link or a file of another kind.

Write failures (full disk, read-only folder, permissions) become :class:`WriteError`
``E-WRITE`` naming the path and the reason in words.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from impress_gui.core.base import codes, workfiles
from impress_gui.core.base.errors import ImpressError

MARK_FILE = ".impress-output.json"
MARK_FORMAT = "impress.output-folder"


class OutputError(ImpressError):
    """The output the user named cannot be used (it holds evidence, is a link, ...)."""

    code = codes.E_OUTPUT


class WriteError(ImpressError):
    """Writing an output failed (disk full, read-only, no permission)."""

    code = codes.E_WRITE


_REASONS = {
    errno.ENOSPC: "the disk is full",
    errno.EDQUOT: "the disk quota is exhausted",
    errno.EROFS: "the file system is read-only",
    errno.EACCES: "permission denied",
    errno.EPERM: "the operation is not permitted",
    errno.ENOENT: "a folder on the way does not exist",
    errno.ENOTDIR: "a part of the path is a file, not a folder",
    errno.EISDIR: "it is a folder",
    errno.EEXIST: "something of that name is already there",
    errno.ENOTEMPTY: "the folder is not empty",
    errno.EBUSY: "it is in use (a mount point or the current folder)",
    errno.ENAMETOOLONG: "the name is too long",
    errno.EXDEV: "it is on another file system",
    errno.EIO: "the disk reported an input/output error",
    errno.EMFILE: "too many files are open",
    errno.ELOOP: "too many symbolic links on the way",
    errno.EFBIG: "the file is too large for the file system",
}


def reason(exc: OSError) -> str:
    """A plain-words reason for an OS error (no errno numbers, no Python names)."""
    return _REASONS.get(exc.errno or -1, "the operating system refused it")


def write_error(path: str | os.PathLike, exc: OSError, what: str = "write") -> WriteError:
    return WriteError(f"cannot {what} {path}: {reason(exc)}")


@contextlib.contextmanager
def writing(path: str | os.PathLike, what: str = "write") -> Iterator[None]:
    """Turn any ``OSError`` inside the block into :class:`WriteError` naming ``path``."""
    try:
        yield
    except ImpressError:
        raise
    except OSError as exc:
        raise write_error(path, exc, what) from None


def _resolved(p: str | os.PathLike) -> Path:
    return Path(os.path.abspath(os.path.realpath(p)))


def _is_within(child: Path, parent: Path) -> bool:
    return child == parent or parent in child.parents


def _check_not_special(out: Path, inputs: Iterable[str | os.PathLike]) -> Path:
    """Refusals common to files and folders; returns the resolved output path."""
    if str(out).strip() == "":
        raise OutputError("no output was named", code=codes.E_OUTPUT_UNSAFE)
    if out.is_symlink():
        raise OutputError(f"{out} is a symbolic link: name the real place to write to",
                          code=codes.E_OUTPUT_LINK)
    real = _resolved(out)
    cwd = _resolved(os.getcwd())
    home = _resolved(Path.home())
    if real == Path(real.anchor) or _is_within(cwd, real) or real == home:
        raise OutputError(f"{out} is the current folder, one of its parents, the home folder "
                          "or the root: name a new folder for the output", code=codes.E_OUTPUT_UNSAFE)
    for item in inputs:
        if item is None:
            continue
        src = _resolved(item)
        if _is_within(src, real) or _is_within(real, src):
            raise OutputError(f"{out} holds or is one of this run's inputs ({item}): the "
                              "output must be a separate folder", code=codes.E_OUTPUT_HOLDS_INPUT)
    return real


def _check_parent_writable(real: Path) -> None:
    parent = real.parent
    probe = parent
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"cannot create {real}: {probe} is a file, not a folder",
                          code=codes.E_OUTPUT_NOT_FOLDER)
    if not os.access(probe, os.W_OK | os.X_OK):
        raise WriteError(f"cannot write into {probe}: permission denied or read-only")
    # os.access says yes to root everywhere, and knows nothing of read-only or pseudo file
    # systems (/proc, a write-protected card): create and remove an empty file to be sure
    # before any work is done (the output is made in this folder anyway)
    try:
        fd, name = tempfile.mkstemp(prefix=".impress-write-check-", dir=probe)
    except OSError as exc:
        raise WriteError(f"cannot write into {probe}: {exc.strerror or exc}") from None
    os.close(fd)
    os.unlink(name)


def read_mark(folder: Path) -> dict | None:
    """The product's mark in ``folder`` (None when absent or unreadable)."""
    mark = folder / MARK_FILE
    try:
        if mark.is_symlink() or not mark.is_file() or mark.stat().st_size > 65536:
            return None
        doc = json.loads(mark.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or doc.get("format") != MARK_FORMAT:
        return None
    return doc


def mark_bytes(kind: str) -> bytes:
    """The mark's content: the same for every folder of a kind (outputs stay reproducible)."""
    doc = {"format": MARK_FORMAT, "version": 1, "kind": kind,
           "note": "made by IMPREsS workstation; replaced as a whole by a new run into it"}
    return (json.dumps(doc, indent=2) + "\n").encode("utf-8")


def check_output_dir(out_dir: str | os.PathLike, kind: str, inputs: Iterable = (),
                     allowed: Iterable[str] | None = None) -> Path:
    """Check that ``out_dir`` may receive an output folder of ``kind``; raise OutputError
    (before any work) otherwise. ``allowed``: the names a complete folder of that kind may
    hold (None: any name, as long as the folder carries the mark of ``kind``)."""
    out = Path(out_dir)
    real = _check_not_special(out, inputs)
    if out.exists() or real.exists():
        if not real.is_dir():
            raise OutputError(f"{out} exists and is not a folder: name a folder for the output",
                              code=codes.E_OUTPUT_NOT_FOLDER)
        try:
            entries = [p for p in real.iterdir()]
        except OSError as exc:
            raise OutputError(f"cannot look into {out}: {reason(exc)}",
                              code=codes.E_OUTPUT_NOT_FOLDER) from None
        if entries:
            mark = read_mark(real)
            if mark is None or mark.get("kind") != kind:
                raise OutputError(
                    f"{out} is not empty and was not made by a previous {kind} run: nothing "
                    "is replaced; name a new or empty folder", code=codes.E_OUTPUT_NOT_EMPTY)
            if allowed is not None:
                names = set(allowed) | {MARK_FILE}
                foreign = sorted(p.name for p in entries if p.name not in names
                                 or p.is_symlink())
                if foreign:
                    raise OutputError(
                        f"{out} holds files a {kind} run did not write ({', '.join(foreign[:5])}"
                        f"{' ...' if len(foreign) > 5 else ''}): nothing is replaced; move them "
                        "or name another folder", code=codes.E_OUTPUT_NOT_EMPTY)
    _check_parent_writable(real)
    return real


def check_output_file(path: str | os.PathLike, inputs: Iterable = (),
                      formats: Iterable[str] | None = ()) -> Path:
    """Check that a single output file may be written at ``path``: not a link, a folder or an
    input; an existing file is replaced only when it is a JSON document whose ``format`` is
    one of ``formats`` (``None``: any regular file the user chose to replace, as a save
    dialog that has asked)."""
    out = Path(path)
    real = _check_not_special(out, inputs)
    if real.exists():
        if real.is_dir():
            raise OutputError(f"{out} is a folder: name the file to write",
                              code=codes.E_OUTPUT_NOT_FILE)
        if not real.is_file():
            raise OutputError(f"{out} is not a regular file", code=codes.E_OUTPUT_NOT_FILE)
        if formats is None:
            _check_parent_writable(real)
            return real
        fmt = None
        try:
            if real.stat().st_size < (50 << 20):
                doc = json.loads(real.read_bytes().decode("utf-8"))
                fmt = doc.get("format") if isinstance(doc, dict) else None
        except (OSError, ValueError):
            fmt = None
        if fmt not in set(formats):
            raise OutputError(f"{out} exists and is not a file this command writes: it is not "
                              "replaced; name a new file", code=codes.E_OUTPUT_EXISTS)
    _check_parent_writable(real)
    return real


class OutputFolder:
    """A folder being written: files go into a hidden sibling, which replaces ``final`` at
    :meth:`commit` (after the checks are made again). Use as a context manager; on an error
    the partial folder is removed and ``final`` is untouched."""

    def __init__(self, final: str | os.PathLike, kind: str, inputs: Iterable = (),
                 allowed: Iterable[str] | None = None) -> None:
        self.kind = kind
        self.inputs = [i for i in inputs if i is not None]
        self.allowed = None if allowed is None else set(allowed)
        self.final = check_output_dir(final, kind, self.inputs, self.allowed)
        with writing(self.final.parent, "create the folder"):
            self.final.parent.mkdir(parents=True, exist_ok=True)
            recover_interrupted(self.final, marker=MARK_FILE)
            self.tmp = self.final.parent / f".{self.final.name}.partial-{os.getpid()}"
            _clear_work_folder(self.tmp)
            # a writability probe now (the work folder is made and removed): a read-only or
            # full place fails before any work, and a run killed before writing leaves nothing
            workfiles.note(self.tmp)
            try:
                self.tmp.mkdir()
                (self.tmp / MARK_FILE).write_bytes(mark_bytes(kind))
                shutil.rmtree(self.tmp)
            except BaseException:  # a failure, or a signal landing inside the probe
                shutil.rmtree(self.tmp, ignore_errors=True)
                raise
            finally:
                workfiles.done(self.tmp)
        self._begun = False

    def begin(self) -> Path:
        """Make the hidden work folder (with the mark) if not yet made; return it."""
        if not self._begun:
            with writing(self.final.parent, "create the folder"):
                _clear_work_folder(self.tmp)
                workfiles.note(self.tmp)
                self.tmp.mkdir()
                (self.tmp / MARK_FILE).write_bytes(mark_bytes(self.kind))
            self._begun = True
        return self.tmp

    def __enter__(self) -> OutputFolder:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self.abort()

    def path(self, name: str) -> Path:
        return self.begin() / name

    def abort(self) -> None:
        shutil.rmtree(self.tmp, ignore_errors=True)
        workfiles.done(self.tmp)

    def commit(self) -> Path:
        """Mark, fsync and swap the finished folder into place; return the final path."""
        self.begin()
        with writing(self.final):
            for p in self.tmp.iterdir():
                if p.is_file():
                    with open(p, "rb") as fh:
                        os.fsync(fh.fileno())
            # the folder may have changed while we worked: check again just before replacing
            check_output_dir(self.final, self.kind, self.inputs, self.allowed)
            old = None
            if self.final.exists():
                if any(self.final.iterdir()):
                    old = self.final.parent / f".{self.final.name}.old-{os.getpid()}"
                    self.final.rename(old)
                else:
                    self.final.rmdir()
            self.tmp.rename(self.final)
            workfiles.done(self.tmp)
            if old is not None:
                shutil.rmtree(old)
        return self.final


def _ours_or_empty(folder: Path) -> bool:
    """``folder`` carries the product's mark or is empty (one that cannot be read is
    neither: left alone)."""
    if read_mark(folder) is not None:
        return True
    try:
        return not any(folder.iterdir())
    except OSError:
        return False


def _clear_work_folder(tmp: Path) -> None:
    """Remove this process's own earlier work folder ``tmp``; refuse (OutputError) when
    something the product did not make has its name (it is never deleted)."""
    if not (tmp.exists() or tmp.is_symlink()):
        return
    if tmp.is_symlink() or not tmp.is_dir() or read_mark(tmp) is None:
        raise OutputError(f"{tmp} is in the way of the output's work folder and was not made "
                          "by impress: nothing is replaced; move it or name another output",
                          code=codes.E_OUTPUT_NOT_EMPTY)
    shutil.rmtree(tmp)


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return False  # our own leftovers are stale by definition
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError):
        return True  # exists (another user's) or unknown: leave it alone
    return True


def recover_interrupted(out_dir: Path, marker: str = "metadata.json") -> list[str]:
    """Clean up after a run that was killed while writing ``out_dir``: remove its hidden
    ``.NAME.partial-PID`` folders, and its ``.NAME.old-PID`` folders - after putting the newest
    back in place if the kill came between the two renames of the swap (``out_dir`` missing;
    a folder counts as complete when it holds ``marker``).
    Only folders that carry the product's mark (:data:`MARK_FILE`: every work folder and every
    folder the swap sets aside has it; an empty one holds nothing to lose) are touched: a
    folder of that name the product did not make, or a link, is left alone. Folders of a process still alive are left alone. Returns
    what was done."""
    out_dir = Path(out_dir)
    done: list[str] = []
    if not out_dir.parent.is_dir():
        return done
    stale = []
    for p in out_dir.parent.iterdir():
        for kind in ("partial", "old"):
            prefix = f".{out_dir.name}.{kind}-"
            if (p.name.startswith(prefix) and p.name[len(prefix):].isdigit()
                    and not p.is_symlink() and p.is_dir() and _ours_or_empty(p)):
                if not _pid_alive(int(p.name[len(prefix):])):
                    stale.append((kind, p))
    olds = sorted((p for k, p in stale if k == "old"), key=lambda p: p.stat().st_mtime)
    if olds and not out_dir.exists() and (olds[-1] / marker).is_file():
        olds[-1].rename(out_dir)
        done.append(f"restored {out_dir} from {olds[-1].name}")
        stale = [(k, p) for k, p in stale if p != olds[-1]]
    for _, p in stale:
        shutil.rmtree(p, ignore_errors=True)
        done.append(f"removed {p.name}")
    return done
