"""Ed25519 signatures for the case record (Qt-free).

Each examiner (an operating-system user on one installation) has one signing key, made on
first use and kept in the user's configuration folder, readable by that user only:

* ``$IMPRESS_KEY_DIR`` when set (tests, portable installs), else
* ``$XDG_CONFIG_HOME/IMPREsS/keys`` (``~/.config/IMPREsS/keys`` when unset; ``%APPDATA%``
  on Windows), next to the window's settings.

The key file ``signing-key-ed25519.pem`` is an unencrypted PKCS#8 PEM file of mode 0600 in a
folder of mode 0700; a key file that is a link, not a regular file, owned by another user or
readable by other users is refused (``E-KEY``), as ssh refuses such keys.

What is signed (see :mod:`~impress_gui.core.project.project` and :mod:`~impress_gui.core.project.log`):
every log entry, and the project file's canonical content, which includes the log head (the
number of entries and the hash of the last one at the save). A signature is over a context
line naming what is signed, followed by the document's canonical JSON (sorted keys, no spaces,
UTF-8), so a signature of one kind can never pass for another.

A public key is written as the base64 of its 32 raw bytes; its fingerprint is
``SHA256:`` and the unpadded base64 of the key's SHA-256, as ssh prints them.

The checks of a loaded case record beyond its fields' types are here too: the head signature
(``E-PROJECT-TAMPERED``, ``E-SIGNATURE``), an unsigned file over a log that shows a signed save
(a downgrade), the evidence hash and outputs against the log, and recorded paths that lead out
of the project through links (``E-PROJECT-LINK``) or disagree (``E-PROJECT-PATH``).
"""

from __future__ import annotations

import base64
import binascii
import contextlib
import hashlib
import json
import os
import stat
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cryptography.exceptions import InvalidSignature
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric.ed25519 import (
    Ed25519PrivateKey,
    Ed25519PublicKey,
)

from impress_gui.core.base import codes
from impress_gui.core.base.errors import FormatError, IntegrityError

if TYPE_CHECKING:
    from impress_gui.core.project.log import LogState

ALGORITHM = "Ed25519"
KEY_DIR_ENV = "IMPRESS_KEY_DIR"
KEY_FILE = "signing-key-ed25519.pem"
ENTRY_CONTEXT = b"impress.project-log entry v2\n"
HEAD_CONTEXT = b"impress.project head v2\n"
MAX_KEY_BYTES = 16 * 1024
_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
_CLOEXEC = getattr(os, "O_CLOEXEC", 0)


def key_dir() -> Path:
    """The folder of this user's signing key (see the module's documentation)."""
    override = os.environ.get(KEY_DIR_ENV)
    if override:
        return Path(override)
    if sys.platform == "win32" and os.environ.get("APPDATA"):
        base = Path(os.environ["APPDATA"])
    else:
        xdg = os.environ.get("XDG_CONFIG_HOME", "")
        base = Path(xdg) if os.path.isabs(xdg) else Path.home() / ".config"
    return base / "IMPREsS" / "keys"


def canonical(doc: Any) -> bytes:
    """The canonical bytes of a JSON document: sorted keys, no spaces, UTF-8."""
    return json.dumps(
        doc, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False
    ).encode("utf-8")


def fingerprint_of(public_raw: bytes) -> str:
    digest = hashlib.sha256(public_raw).digest()
    return "SHA256:" + base64.b64encode(digest).decode("ascii").rstrip("=")


def public_key_bytes(public_key_b64: object) -> bytes | None:
    """The 32 raw bytes of a base64 public key, or None when it is not one."""
    if not isinstance(public_key_b64, str) or len(public_key_b64) > 64:
        return None
    try:
        raw = base64.b64decode(public_key_b64, validate=True)
    except (binascii.Error, ValueError):
        return None
    return raw if len(raw) == 32 else None


def fingerprint(public_key_b64: object) -> str | None:
    """The fingerprint of a base64 public key, or None when it is not one."""
    raw = public_key_bytes(public_key_b64)
    return None if raw is None else fingerprint_of(raw)


def verify(public_key_b64: object, signature_b64: object, context: bytes, doc: Any) -> bool:
    """True when ``signature_b64`` is ``public_key_b64``'s signature of ``context`` and the
    canonical form of ``doc``; False for a wrong signature or a malformed key or signature."""
    raw = public_key_bytes(public_key_b64)
    if raw is None or not isinstance(signature_b64, str) or len(signature_b64) > 128:
        return False
    try:
        sig = base64.b64decode(signature_b64, validate=True)
        Ed25519PublicKey.from_public_bytes(raw).verify(sig, context + canonical(doc))
    except (binascii.Error, ValueError, TypeError, InvalidSignature):
        return False
    return True


@dataclass(frozen=True)
class SigningKey:
    """An examiner's private key and what is recorded about it."""

    private: Ed25519PrivateKey
    public_key: str  # base64 of the 32 raw bytes
    fingerprint: str
    path: Path | None = None

    @classmethod
    def from_private(cls, private: Ed25519PrivateKey, path: Path | None = None) -> SigningKey:
        raw = private.public_key().public_bytes(
            serialization.Encoding.Raw, serialization.PublicFormat.Raw
        )
        return cls(private, base64.b64encode(raw).decode("ascii"), fingerprint_of(raw), path)

    @classmethod
    def generate(cls) -> SigningKey:
        """A fresh key that is not stored anywhere (tests, a second examiner)."""
        return cls.from_private(Ed25519PrivateKey.generate())

    def sign(self, context: bytes, doc: Any) -> str:
        return base64.b64encode(self.private.sign(context + canonical(doc))).decode("ascii")


def _key_error(path: Path, problem: str) -> IntegrityError:
    return IntegrityError(f"the signing key {path} {problem}", code=codes.E_KEY)


def _read_key(path: Path) -> SigningKey | None:
    """The key stored at ``path``; None when there is none."""
    try:
        fd = os.open(path, os.O_RDONLY | _NOFOLLOW | _CLOEXEC | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        if os.path.islink(path):
            raise _key_error(path, "is a symbolic link to nothing: remove it") from None
        return None
    except OSError:
        if os.path.islink(path):
            raise _key_error(path, "is a symbolic link: a key must be a file of its own") from None
        raise _key_error(path, "cannot be read (check its permissions)") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise _key_error(path, "is not a regular file")
        if hasattr(os, "getuid"):
            if st.st_uid != os.getuid():
                raise _key_error(path, "belongs to another user")
            if st.st_mode & 0o077:
                raise _key_error(
                    path,
                    "can be read by other users: make it readable by you only "
                    f"(chmod 600 {path}) or remove it to make a new key",
                )
    except BaseException:
        os.close(fd)
        raise
    with os.fdopen(fd, "rb") as fh:
        try:
            data = fh.read(MAX_KEY_BYTES + 1)
        except OSError:
            raise _key_error(path, "cannot be read") from None
    try:
        private = serialization.load_pem_private_key(data, password=None)
    except (ValueError, TypeError):
        private = None
    if not isinstance(private, Ed25519PrivateKey):
        raise _key_error(path, "is damaged or not an Ed25519 key: restore it from a backup")
    return SigningKey.from_private(private, path)


def load_or_create_key(directory: str | os.PathLike | None = None) -> SigningKey:
    """This examiner's signing key, made (mode 0600, folder 0700) on first use."""
    folder = Path(directory) if directory is not None else key_dir()
    path = folder / KEY_FILE
    key = _read_key(path)
    if key is not None:
        return key
    try:
        folder.mkdir(mode=0o700, parents=True, exist_ok=True)
    except OSError:
        raise _key_error(path, "cannot be made: its folder cannot be created") from None
    key = SigningKey.generate()
    pem = key.private.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )
    tmp = None
    try:
        fd, tmp = tempfile.mkstemp(prefix=".signing-key.", suffix=".partial", dir=folder)
        with os.fdopen(fd, "wb") as fh:  # mkstemp makes it 0600
            fh.write(pem)
            fh.flush()
            os.fsync(fh.fileno())
        try:
            os.link(tmp, path)  # never replaces a key another process made meanwhile
        except FileExistsError:
            pass
        except OSError:  # no hard links on this file system
            if not os.path.lexists(path):
                os.replace(tmp, path)
                tmp = None
    except OSError:
        raise _key_error(path, "cannot be written (check the folder's permissions)") from None
    finally:
        if tmp is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
    stored = _read_key(path)
    if stored is None:
        raise _key_error(path, "disappeared while it was made")
    return stored


def local_fingerprint(directory: str | os.PathLike | None = None) -> str | None:
    """The fingerprint of this examiner's key if there is a usable one (none is made)."""
    try:
        key = _read_key((Path(directory) if directory is not None else key_dir()) / KEY_FILE)
    except IntegrityError:
        return None
    return None if key is None else key.fingerprint


# ----- the signed project file -------------------------------------------------------------
def sign_head(doc: dict, key: SigningKey) -> dict:
    """``doc`` as a reader parses it back, with its head signature by ``key``."""
    body = json.loads(json.dumps(doc, allow_nan=False))
    body.pop("head_signature", None)
    return body | {
        "head_signature": {
            "key_fingerprint": key.fingerprint,
            "signature": key.sign(HEAD_CONTEXT, body),
        }
    }


def lists_key(doc: dict, key: SigningKey) -> bool:
    """True when the project document ``doc`` lists ``key``."""
    keys = doc.get("signing", {}).get("keys", [])
    return any(
        k.get("fingerprint") == key.fingerprint and k.get("public_key") == key.public_key
        for k in keys
    )


def read_signing(doc: dict, where: str) -> tuple[list[dict], int, dict]:
    """The keys, the count of unsigned log entries and the head signature of version 2."""
    sig = doc.get("signing")
    if not isinstance(sig, dict):
        raise IntegrityError(f"{where}the project's signing section is missing or damaged",
                             code=codes.E_SIGNATURE)
    if sig.get("algorithm") != ALGORITHM:
        raise IntegrityError(f"{where}the project is signed by an unknown method",
                             code=codes.E_SIGNATURE)
    keys = sig.get("keys")
    if not isinstance(keys, list) or not keys:
        raise IntegrityError(f"{where}the project lists no signing keys", code=codes.E_SIGNATURE)
    records = []
    for i, k in enumerate(keys):
        fields = ("public_key", "fingerprint", "user", "added_utc")
        if not isinstance(k, dict) or not all(isinstance(k.get(f), str) for f in fields):
            raise FormatError(f"{where}signing.keys[{i}] is malformed")
        if fingerprint(k["public_key"]) != k["fingerprint"]:
            raise IntegrityError(f"{where}signing key {i + 1} does not match its fingerprint",
                                 code=codes.E_SIGNATURE)
        records.append(dict(k))
    unsigned = sig.get("unsigned_log_entries")
    if type(unsigned) is not int or unsigned < 0:
        raise FormatError(f"{where}signing.unsigned_log_entries must be a count")
    hs = doc.get("head_signature")
    if not (isinstance(hs, dict) and isinstance(hs.get("key_fingerprint"), str)
            and isinstance(hs.get("signature"), str)):
        raise IntegrityError(f"{where}the project file's signature is missing or damaged",
                             code=codes.E_SIGNATURE)
    return records, unsigned, {"key_fingerprint": hs["key_fingerprint"],
                               "signature": hs["signature"]}


def check_head_signature(doc: dict, keys: dict[str, str], head: dict, file: Path) -> None:
    fp = head["key_fingerprint"]
    if fp not in keys:
        raise IntegrityError(
            f"{file}: the project file is signed by key {fp}, which the project does not "
            "list (an unknown key)",
            code=codes.E_SIGNATURE,
        )
    body = {k: v for k, v in doc.items() if k != "head_signature"}
    if not verify(keys[fp], head["signature"], HEAD_CONTEXT, body):
        raise IntegrityError(
            f"{file}: the project file was changed after it was signed at its last save "
            "(an edited field: case details, video, outputs, measurements or the log head)",
            code=codes.E_PROJECT_TAMPERED,
        )


def check_not_downgraded(state: LogState, head: dict, file: Path) -> None:
    """An unsigned (version 1) project file over a log that shows a signed save: the signed
    file was replaced by an unsigned one (to hide an edit)."""
    covered = head.get("entries", len(state.entries)) if head else len(state.entries)
    signed_saves = [
        i for i, (e, fp) in enumerate(zip(state.entries, state.signers, strict=True))
        if fp is not None and e.get("action") == "project saved"
        and not (i + 1 < len(state.entries)
                 and state.entries[i + 1].get("action") == "project save failed")
    ]
    if any(fp is not None for fp in state.signers[:covered]) or signed_saves:
        raise IntegrityError(
            f"{file}: the project file is unsigned, but its log shows it was saved signed: "
            "the signed project file was replaced by an unsigned one",
            code=codes.E_PROJECT_TAMPERED,
        )


def check_video_against_log(video_sha256: str | None, state: LogState, file: Path) -> None:
    """The evidence hash must be the one the (chained, signed) log recorded when the video was
    added, or a swapped video with an edited hash would pass."""
    if video_sha256 is None:
        return
    added = [e for e in state.entries if e.get("action") == "video added"]
    if added and added[-1]["details"].get("sha256") != video_sha256:
        raise IntegrityError(
            f"{file}: the video's SHA-256 differs from the one the log recorded "
            "when the video was added (project.json was edited)",
            code=codes.E_LOG_TAMPERED,
        )


def check_outputs_against_log(outputs: list[dict], state: LogState, file: Path) -> None:
    """Unsigned projects: every output must be one the log recorded as written."""
    written = set()
    for e in state.entries:
        d = e["details"]
        if e.get("action") == "output written" and isinstance(d.get("path"), str):
            written.add((d["path"], d.get("sha256")))
    for out in outputs:
        if (out["path"], out["sha256"]) not in written:
            raise IntegrityError(
                f"{file}: the output {out['path']} is not one the log recorded as written "
                "(project.json was edited)",
                code=codes.E_PROJECT_TAMPERED,
            )


def _within(path: str, folder: str) -> bool:
    return path == folder or path.startswith(folder.rstrip(os.sep) + os.sep)


def _path_error(where: str, text: str) -> IntegrityError:
    return IntegrityError(f"{where}: {text}", code=codes.E_PROJECT_PATH)


def _link_error(where: str, text: str) -> IntegrityError:
    return IntegrityError(f"{where}: {text}", code=codes.E_PROJECT_LINK)


def check_recorded_paths(
    root_path: Path, outputs: list[dict], video: dict | None, file: Path
) -> None:
    """Recorded paths lead where they should: an output inside the project folder stays
    inside it (no link out of it, both of its paths agree), an output outside it and the
    evidence video are not links, and the video's two paths name the same file."""
    root, real_root = str(root_path), os.path.realpath(root_path)
    for i, out in enumerate(outputs):
        where = f"{file}: output {i + 1} ({out['path']})"
        path, rel = out["path"], out.get("relative_path")
        if os.path.normpath(path) != path or (rel is not None and os.path.normpath(rel) != rel):
            raise _path_error(where, "its recorded path is not a plain path")
        if _within(path, root) and rel != os.path.relpath(path, root):
            raise _path_error(where, "its two recorded paths disagree (project.json was edited)")
        escapes = rel is None or rel == os.pardir or rel.startswith(os.pardir + os.sep)
        inside = [root_path / rel] if not escapes and rel is not None else []
        if _within(path, root):
            inside.append(Path(path))
        for p in inside:
            if not _within(os.path.realpath(p), real_root):
                raise _link_error(where, "it leads out of the project folder through a "
                                  "symbolic link")
        if not inside and os.path.islink(path):
            raise _link_error(where, "it is now a symbolic link")
    if video is None:
        return
    where = f"{file}: the evidence video ({video['path']})"
    if os.path.normpath(video["path"]) != video["path"]:
        raise _path_error(where, "its recorded path is not a plain path")
    rel = video.get("relative_path")
    if rel is not None and (os.path.normpath(rel) != rel
                            or os.path.basename(rel) != os.path.basename(video["path"])):
        raise _path_error(where, "its two recorded paths name different files "
                          "(project.json was edited)")
    for p in (video["path"], None if rel is None else os.path.join(root, rel)):
        if p is not None and os.path.islink(p):
            raise _link_error(where, f"{p} is now a symbolic link")


def describe_signatures(info: dict) -> str:
    """Plain words for :meth:`~impress_gui.core.project.project.Project.signature_info`: who signed, and where the log's key
    changes (for the window's status and integrity check)."""
    if not info.get("signed"):
        return "Not signed (a project of an older version): changes cannot be proven absent."

    def who(fp: str | None) -> str:
        if fp is None:
            return "unsigned (written before signing)"
        k = next((k for k in info["keys"] if k["fingerprint"] == fp), None)
        mine = " - this installation's key" if fp == info.get("this_installation_key") else ""
        user = f" (user {k['user']})" if k and k.get("user") else ""
        return f"key {fp}{user}{mine}"

    lines = [f"Project file signed by {who(info['key_fingerprint'])}."]
    runs = info.get("log_signers") or []
    for r in runs:
        span = f"entry {r['from_seq']}" if r["from_seq"] == r["to_seq"] else (
            f"entries {r['from_seq']}-{r['to_seq']}")
        lines.append(f"Log {span}: {who(r['key_fingerprint'])}.")
    changes = [r["from_seq"] for r in runs[1:] if r["key_fingerprint"] is not None]
    if changes:
        lines.append("The signing key changes at log entr" + ("y " if len(changes) == 1 else
                     "ies ") + ", ".join(map(str, changes)) + ".")
    return "\n".join(lines)


