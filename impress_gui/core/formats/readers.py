"""Reading the product's exports back: X3P (ISO 25178-72) and binary PLY point clouds.

Both readers treat the file as hostile. Nothing is ever extracted to disk; every size is
checked before memory is committed to it, and every failure is a
:class:`~impress_gui.core.base.errors.FormatError` with a stable code:

============================  =================================================================
``E-FILE-MISSING``            no such file
``E-TOO-LARGE``               the file (or a declared size) is beyond the reader's limits
``E-X3P-ZIP``                 not a readable zip archive / a member's CRC does not match
``E-ZIP-TRAVERSAL``           a member name that would escape a folder (``..``, absolute, ``\\``)
``E-ZIP-BOMB``                declared sizes or compression ratios that no real export has
``E-X3P-XML``                 main.xml missing, not XML, with a DTD/entities, or incomplete
``E-X3P-CHECKSUM``            an MD5 checksum in the container does not match
``E-X3P-DATA``                the point data's size or type does not match main.xml
``E-VERSION``                 an X3P revision or PLY format version this reader does not know
``E-PLY-HEADER``              a damaged or unsupported PLY header
``E-PLY-TRUNCATED``           fewer bytes than the header declares
``E-VALUE``                   NaN/infinity where not allowed, absurdly large numbers
============================  =================================================================

:data:`READERS` maps a suffix to its reader; :func:`read_export` dispatches on it.
"""

from __future__ import annotations

import hashlib
import io
import math
import os
import re
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import numpy as np
import plyfile

from impress_gui.core.base import codes
from impress_gui.core.base.errors import FormatError
from impress_gui.core.reconstruction.grid import GridSpec

MAX_FILE_BYTES = 4 << 30  # 4 GiB on disk
MAX_MEMBER_BYTES = 4 << 30  # one inflated zip member
MAX_XML_BYTES = 1 << 20  # main.xml of an X3P
MAX_RATIO = 1100  # deflate cannot exceed ~1032:1
MAX_CELLS = 400_000_000  # the reconstruction's own limit
MAX_POINTS = 500_000_000
MAX_ABS_MM = 1e7  # 10 km: anything larger is not a scan
PLY_HEADER_MAX = 64 * 1024


def _err(path: Path, msg: str, code: str) -> FormatError:
    return FormatError(f"{path}: {msg}", code=code)


def _check_file(path: Path, limit: int = MAX_FILE_BYTES) -> int:
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise _err(path, "file not found", codes.E_FILE_MISSING) from None
    except OSError as exc:
        raise _err(path, f"cannot read ({exc.strerror})", codes.E_FORMAT) from None
    if not path.is_file():
        raise _err(path, "not a file", codes.E_FORMAT)
    if size > limit:
        raise _err(path, f"{size} bytes is too large", codes.E_TOO_LARGE)
    return size


# ----- zip safety ------------------------------------------------------------------------------
_DRIVE = re.compile(r"^[A-Za-z]:")


def safe_member_name(name: str) -> bool:
    """A relative POSIX name that stays inside the archive's folder."""
    if not name or "\\" in name or "\x00" in name or name.startswith("/") or _DRIVE.match(name):
        return False
    return ".." not in PurePosixPath(name).parts


def check_zip(
    zf: zipfile.ZipFile,
    path: Path,
    member_limit: int = MAX_MEMBER_BYTES,
    total_limit: int = MAX_MEMBER_BYTES,
) -> None:
    """Refuse traversal names, absurd declared sizes and compression ratios - before any
    member is inflated."""
    total = 0
    infos = zf.infolist()
    if len(infos) > 1000:
        raise _err(path, f"{len(infos)} members: not an export of this software", codes.E_ZIP_BOMB)
    for info in infos:
        if not safe_member_name(info.filename):
            raise _err(
                path,
                f"member name {info.filename!r} would leave the archive's folder",
                codes.E_ZIP_TRAVERSAL,
            )
        if info.file_size > member_limit:
            raise _err(
                path, f"member {info.filename!r} declares {info.file_size} bytes", codes.E_ZIP_BOMB
            )
        if info.file_size > MAX_RATIO * max(info.compress_size, 1) and info.file_size > 1 << 20:
            raise _err(
                path,
                f"member {info.filename!r} declares a compression ratio of "
                f"{info.file_size / max(info.compress_size, 1):.0f}:1",
                codes.E_ZIP_BOMB,
            )
        total += info.file_size
        if total > total_limit:
            raise _err(path, "the members' declared sizes add up to too much", codes.E_ZIP_BOMB)


def read_member(zf: zipfile.ZipFile, name: str, path: Path, limit: int) -> bytes:
    """A member's bytes, never more than ``limit`` inflated, and exactly its declared size."""
    try:
        info = zf.getinfo(name)
    except KeyError:
        raise _err(path, f"member {name!r} is missing", codes.E_X3P_DATA) from None
    if info.file_size > limit:
        raise _err(
            path, f"member {name!r} declares {info.file_size} bytes (limit {limit})", codes.E_ZIP_BOMB
        )
    try:
        with zf.open(info) as fh:
            data = fh.read(limit + 1)
    except (
        zipfile.BadZipFile,
        zipfile.LargeZipFile,
        OSError,
        EOFError,
        ValueError,
        NotImplementedError,
        RuntimeError,
    ) as exc:
        # zlib.error is not an OSError; it arrives wrapped or as itself
        raise _err(path, f"member {name!r} is damaged ({exc})", codes.E_X3P_ZIP) from None
    except Exception as exc:  # noqa: BLE001 - zlib.error and friends
        raise _err(path, f"member {name!r} is damaged ({exc})", codes.E_X3P_ZIP) from None
    if len(data) != info.file_size:
        raise _err(
            path,
            f"member {name!r} inflates to {len(data)} bytes, not the {info.file_size} declared",
            codes.E_ZIP_BOMB,
        )
    return data


# ----- X3P ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class X3PData:
    """An areal surface: heights in mm (float64, NaN = invalid point) on a regular grid
    (cell ``[i, j]`` at ``x0 + j * pixel``, ``y0 + i * pixel``)."""

    spec: GridSpec
    height_mm: np.ndarray
    info: dict = field(default_factory=dict)


_DTYPES = {"D": "<f8", "F": "<f4"}


def _xml_text(root, path_: str, ns: dict, path: Path, required: bool = True) -> str | None:
    el = root.find(path_, ns)
    if el is None or el.text is None:
        if required:
            raise _err(path, f"main.xml lacks {path_.replace('p:', '')}", codes.E_X3P_XML)
        return None
    return el.text.strip()


#: the cell sizes an X3P surface is read with (metres): 0.1 um to 10 mm
MIN_INCREMENT_M = 1e-7
MAX_INCREMENT_M = 1e-2


def _finite(text: str | None, what: str, path: Path, positive: bool = False) -> float:
    try:
        v = float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise _err(path, f"{what} is not a number ({text!r})", codes.E_X3P_XML) from None
    if not math.isfinite(v) or abs(v) > MAX_ABS_MM * 1e-3:
        raise _err(path, f"{what} is not a finite length ({text!r})", codes.E_VALUE)
    if positive and v <= 0:
        raise _err(path, f"{what} must be positive", codes.E_VALUE)
    return v


def _count(text: str | None, what: str, path: Path) -> int:
    if text is None or not re.fullmatch(r"\d{1,10}", text):
        raise _err(path, f"{what} must be a positive integer ({text!r})", codes.E_X3P_XML)
    v = int(text)
    if v < 1:
        raise _err(path, f"{what} must be positive", codes.E_X3P_XML)
    return v


def read_x3p(path: str | os.PathLike, max_cells: int = MAX_CELLS) -> X3PData:
    """Read an X3P areal surface written by this software (or any X3P with incremental x/y
    axes and float z in one binary member)."""
    import xml.etree.ElementTree as ET

    path = Path(path)
    _check_file(path)
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, EOFError, ValueError) as exc:
        raise _err(path, f"not a readable X3P (zip) file ({exc})", codes.E_X3P_ZIP) from None
    with zf:
        check_zip(zf, path)
        xml_b = read_member(zf, "main.xml", path, MAX_XML_BYTES)
        head = xml_b[:4096].upper()
        if b"<!DOCTYPE" in head or b"<!ENTITY" in xml_b.upper():
            raise _err(path, "main.xml declares a DTD or entities (refused)", codes.E_X3P_XML)
        try:
            root = ET.fromstring(xml_b)
        except ET.ParseError as exc:
            raise _err(path, f"main.xml is not valid XML ({exc})", codes.E_X3P_XML) from None
        if not root.tag.endswith("ISO5436_2"):
            raise _err(path, f"main.xml is not an ISO5436_2 document ({root.tag!r})", codes.E_X3P_XML)

        def t(p_: str, required: bool = True) -> str | None:
            # the records are unqualified children of the namespaced root
            return _xml_text(root, p_, {}, path, required)

        revision = t("Record1/Revision")
        if not revision or not revision.startswith("ISO5436"):
            raise _err(path, f"unknown X3P revision {revision!r}", codes.E_VERSION)
        if t("Record1/FeatureType") != "SUR":
            raise _err(path, "only areal surfaces (FeatureType SUR) are read", codes.E_X3P_DATA)
        axes = {}
        for ax in ("CX", "CY"):
            if t(f"Record1/Axes/{ax}/AxisType") != "I":
                raise _err(path, f"axis {ax} must be incremental", codes.E_X3P_DATA)
            axes[ax] = (
                _finite(t(f"Record1/Axes/{ax}/Increment"), f"{ax} increment", path, positive=True),
                _finite(t(f"Record1/Axes/{ax}/Offset", False) or "0", f"{ax} offset", path),
            )
        if not MIN_INCREMENT_M <= axes["CX"][0] <= MAX_INCREMENT_M:
            # a cell of 1e-300 m left the registration without a single sample
            raise _err(path, f"a cell of {axes['CX'][0]:g} m is not a surface scan's (give "
                       f"{MIN_INCREMENT_M:g} to {MAX_INCREMENT_M:g} m)", codes.E_VALUE)
        if abs(axes["CX"][0] - axes["CY"][0]) > 1e-9 * max(axes["CX"][0], 1e-12):
            raise _err(path, "x and y increments differ (only square cells are read)", codes.E_X3P_DATA)
        ztype = t("Record1/Axes/CZ/DataType")
        if ztype not in _DTYPES:
            raise _err(path, f"z data type {ztype!r} is not supported (D or F)", codes.E_X3P_DATA)
        nx = _count(t("Record3/MatrixDimension/SizeX"), "SizeX", path)
        ny = _count(t("Record3/MatrixDimension/SizeY"), "SizeY", path)
        nz = _count(t("Record3/MatrixDimension/SizeZ"), "SizeZ", path)
        if nz != 1:
            raise _err(path, "only one layer (SizeZ 1) is read", codes.E_X3P_DATA)
        if nx * ny > max_cells:
            raise _err(path, f"{nx} x {ny} points is too large", codes.E_TOO_LARGE)
        link = t("Record3/DataLink/PointDataLink")
        if not safe_member_name(link or ""):
            raise _err(path, f"point data link {link!r} would leave the archive", codes.E_ZIP_TRAVERSAL)
        itemsize = np.dtype(_DTYPES[ztype]).itemsize
        data = read_member(zf, link or "", path, nx * ny * itemsize)
        if len(data) != nx * ny * itemsize:
            raise _err(
                path, f"point data has {len(data)} bytes, not {nx * ny * itemsize}", codes.E_X3P_DATA
            )
        md5 = t("Record3/DataLink/MD5ChecksumPointData", False)
        if md5 and md5.lower() != hashlib.md5(data).hexdigest():
            raise _err(path, "the point data's MD5 checksum does not match", codes.E_X3P_CHECKSUM)
        if "md5checksum.hex" in zf.namelist():
            line = read_member(zf, "md5checksum.hex", path, 4096).decode("ascii", "replace")
            if line.split() and line.split()[0].lower() != hashlib.md5(xml_b).hexdigest():
                raise _err(path, "main.xml's MD5 checksum does not match", codes.E_X3P_CHECKSUM)
    with np.errstate(invalid="ignore"):  # signalling NaNs become quiet ones (invalid points)
        z = np.frombuffer(data, _DTYPES[ztype]).astype(np.float64).reshape(ny, nx) * 1e3
    if np.isinf(z).any():
        raise _err(path, "heights contain infinity", codes.E_VALUE)
    if np.nanmax(np.abs(z), initial=0.0) > MAX_ABS_MM:
        raise _err(path, "heights are absurdly large", codes.E_VALUE)
    inc = axes["CX"][0] * 1e3
    spec = GridSpec(axes["CX"][1] * 1e3, axes["CY"][1] * 1e3, inc, (ny, nx))
    info = {
        "revision": revision,
        "version": t("Record2/Instrument/Version", False),
        "date": t("Record2/Date", False),
        "comment": t("Record2/Comment", False),
    }
    return X3PData(spec, z, info)


# ----- PLY ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlyData:
    """Vertices in mm (``(N, 3)`` float64) and colours (``(N, 3)`` uint8 or None)."""

    points_mm: np.ndarray
    colours: np.ndarray | None
    comments: tuple[str, ...] = ()


def _ply_header(path: Path, lines: list[str]) -> tuple[plyfile.PlyData, list[int]]:
    """The header's lines (after ``ply``, without ``end_header``) parsed by plyfile, and the
    elements' counts. The version, the counts and a premature ``end_header`` are checked here
    first; plyfile parses a copy with every count 0, so that it reads no data (it would read
    every element, a mesh's faces row by row, into arrays sized by the untrusted header)."""
    text, counts = ["ply"], []
    for ln in lines:
        parts = ln.split()
        if not parts:  # plyfile takes an empty line for the end of the file
            ln = " "
        elif parts[0] == "format":
            if len(parts) != 3:
                raise _err(path, f"bad format line {ln!r}", codes.E_PLY_HEADER)
            if parts[2] != "1.0":
                raise _err(path, f"PLY version {parts[2]!r} is not supported", codes.E_VERSION)
        elif parts[0] == "element":
            if len(parts) != 3 or not re.fullmatch(r"\d{1,12}", parts[2]):
                raise _err(path, f"bad element line {ln!r}", codes.E_PLY_HEADER)
            counts.append(int(parts[2]))
            ln = f"element {parts[1]} 0"
        elif parts[0] == "end_header":
            raise _err(path, f"unknown header line {ln!r}", codes.E_PLY_HEADER)
        text.append(ln)
    text += ["end_header", ""]
    try:
        header = plyfile.PlyData.read(io.BytesIO("\n".join(text).encode("ascii")), mmap=False)
    except (plyfile.PlyParseError, ValueError) as exc:
        raise _err(path, f"damaged PLY header ({exc})", codes.E_PLY_HEADER) from None
    return header, counts


def read_ply(path: str | os.PathLike, max_points: int = MAX_POINTS) -> PlyData:
    """Read a binary PLY point cloud: its first element must be ``vertex`` with scalar
    properties including x, y, z (optional uchar red, green, blue); later elements (a mesh's
    faces) are ignored. plyfile parses the header; the vertices are read here with its dtype
    once the size the header declares has been checked against the file."""
    path = Path(path)
    size = _check_file(path)
    with open(path, "rb") as fh:
        head = fh.read(PLY_HEADER_MAX)
        end = head.find(b"end_header\n")
        if not head.startswith(b"ply\n") and not head.startswith(b"ply\r\n"):
            raise _err(path, "not a PLY file", codes.E_PLY_HEADER)
        if end < 0:
            raise _err(path, "the PLY header never ends (no end_header)", codes.E_PLY_HEADER)
        try:
            lines = head[:end].decode("ascii").splitlines()
        except UnicodeDecodeError:
            raise _err(path, "the PLY header is not ASCII", codes.E_PLY_HEADER) from None
        body = end + len(b"end_header\n")
        header, counts = _ply_header(path, lines[1:])
        if header.text:
            raise _err(path, "format 'ascii' is not supported (binary PLY only)", codes.E_PLY_HEADER)
        if not header.elements or header.elements[0].name != "vertex":
            raise _err(path, "the first element must be vertex", codes.E_PLY_HEADER)
        vertex, n = header.elements[0], counts[0]
        names = {p.name for p in vertex.properties}  # distinct: plyfile refuses repeated names
        if any(isinstance(p, plyfile.PlyListProperty) for p in vertex.properties):
            raise _err(path, "vertex properties must be scalars, not lists", codes.E_PLY_HEADER)
        if not {"x", "y", "z"} <= names:
            raise _err(path, "vertices need x, y and z", codes.E_PLY_HEADER)
        if n > max_points:
            raise _err(path, f"{n} vertices is too many", codes.E_TOO_LARGE)
        rgb = {"red", "green", "blue"} <= names
        if rgb and any(vertex.ply_property(c).val_dtype != "u1" for c in ("red", "green", "blue")):
            raise _err(path, "colours must be uchar", codes.E_PLY_HEADER)
        dt = vertex.dtype(header.byte_order)
        need = n * dt.itemsize
        if size - body < need:
            raise _err(
                path,
                f"{size - body} bytes of vertex data, the header declares {need}",
                codes.E_PLY_TRUNCATED,
            )
        fh.seek(body)
        raw = fh.read(need)
    if len(raw) != need:
        raise _err(path, "the file shrank while it was read", codes.E_PLY_TRUNCATED)
    v = np.frombuffer(raw, dt)
    with np.errstate(invalid="ignore"):  # a signalling NaN raises the flag; refused below
        pts = np.column_stack([v[c].astype(np.float64) for c in ("x", "y", "z")])
    if not np.isfinite(pts).all():
        raise _err(path, "coordinates contain NaN or infinity", codes.E_VALUE)
    if n and np.abs(pts).max() > MAX_ABS_MM:
        raise _err(path, "coordinates are absurdly large", codes.E_VALUE)
    colours = None
    if rgb:
        colours = np.column_stack([v["red"], v["green"], v["blue"]]).astype(np.uint8)
    comments = (*header.comments, *header.obj_info,
                *(c for e in header.elements for c in e.comments))
    return PlyData(pts, colours, comments)


READERS: dict[str, Callable] = {".x3p": read_x3p, ".ply": read_ply}


def read_export(path: str | os.PathLike):
    """Read an exported file by its suffix (:data:`READERS`)."""
    p = Path(path)
    reader = READERS.get(p.suffix.lower())
    if reader is None:
        raise _err(p, f"no reader for {p.suffix!r} files ({', '.join(READERS)})", codes.E_FORMAT)
    return reader(p)
