"""Every reader against damaged and hostile input (issue 8): video, intrinsics, target, picks,
calibration, project, validation spec, X3P and PLY. Each bad file must give an
:class:`ImpressError` with a code - never another exception, never a crash, never a write.

Besides hand-made cases (truncated, wrong types, NaN/inf, huge numbers, wrong versions, zip
traversal and absurd sizes) two seeded fuzzers run over every format: a structural one that
replaces each leaf of a valid JSON document with hostile values, and a byte-level one that
flips, deletes, inserts and truncates bytes of a valid file.
"""

from __future__ import annotations

import io
import json
import random
import struct
import zipfile
from pathlib import Path

import numpy as np
import pytest

from impress_gui.core.base.errors import ImpressError
from impress_gui.core.calibration.geometry import Intrinsics, Plane, ideal_rotation
from impress_gui.core.calibration.picks import Picks
from impress_gui.core.calibration.scene import LaserPlaneFit, SceneCalibration
from impress_gui.core.calibration.target import CORNER_NAMES, TargetModel, default_target
from impress_gui.core.formats.readers import read_export, read_ply, read_x3p
from impress_gui.core.formats.writers import ply_bytes, x3p_bytes
from impress_gui.core.project.project import Project, create_project
from impress_gui.core.reconstruction.grid import GridSpec
from impress_gui.sim.rig import default_intrinsics, default_rig
from impress_gui.validation.spec import load_spec

HOSTILE = [
    None,
    True,
    "",
    "x" * 5000,
    -1,
    0,
    1e308,
    -1e308,
    10**400,
    [],
    {},
    [[1, 2], 3],
    {"a": None},
    "NaN",
]


# ----- valid documents --------------------------------------------------------------------------
def _intrinsics() -> Intrinsics:
    return default_intrinsics(640, 360)


def _picks() -> Picks:
    c1 = {c: (100.0 + 30 * i, 120.0 + 9 * i) for i, c in enumerate(CORNER_NAMES)}
    return Picks(
        "scan.mp4", 31, 86, c1, {c: (x, y - 60) for c, (x, y) in c1.items()}, video_sha256="ab" * 32
    )


def _calibration() -> SceneCalibration:
    rig = default_rig(640, 360)
    planes = {
        la.name: LaserPlaneFit(
            la.name, Plane(la.plane.normal, la.plane.offset_mm), 0.02, 500, (30, 31), (15.0, 35.0)
        )
        for la in rig.lasers
    }
    rot = ideal_rotation(np.radians(1.2), np.radians(-1.8))
    return SceneCalibration(
        intrinsics=_intrinsics(),
        speed_mm_s=13.138,
        fps=30.0,
        t1=31,
        t2=86,
        t_ref_s=1.03,
        motion_dir_cam=rot.T @ np.array([0.0, 1.0, 0.0]),
        vanishing_point_px=np.array([1.0, 2.0, 0.0]),
        roll_deg=1.2,
        tilt_deg=-1.8,
        rotation=rot,
        corners_parallax_mm=np.arange(18.0).reshape(6, 3),
        corner_residuals_mm=np.zeros(6),
        target_rotation=np.eye(3),
        target_translation_mm=np.array([-40.0, 50.0, 300.0]),
        implied_speed_mm_s=13.14,
        reprojection_rms_px=0.1,
        planes=planes,
    )


def _spec(tmp: Path) -> dict:
    m = {
        "id": "w",
        "kind": "width",
        "nominal_mm": 6.35,
        "start_mm": [0, 0],
        "end_mm": [20, 0],
        "band_a_mm": [1, 4],
        "band_b_mm": [6, 9],
        "around_mm": 7.5,
        "level_region": {
            "x_mm": [-5, 25],
            "y_mm": [-5, 5],
            "exclude": [{"x_mm": [0, 20], "y_mm": [-2, 2]}],
        },
    }
    e = {
        "id": "e",
        "kind": "edge_distance",
        "nominal_mm": 6.35,
        "start_mm": [0, 0],
        "end_mm": [20, 0],
        "edges": [{"band_low_mm": [1, 2], "band_high_mm": [3, 4], "near_mm": 2.5}] * 2,
    }
    return {
        "format": "impress.validation-spec",
        "version": 1,
        "name": "t",
        "scans": [{"name": "AB", "reconstruction": "recon", "measurements": [m, e]}],
    }


JSON_READERS = {
    "intrinsics": (lambda: _intrinsics().to_json(), Intrinsics.load),
    "target": (lambda: default_target().to_json(), TargetModel.load),
    "picks": (lambda: _picks().to_json(), Picks.load),
    "calibration": (lambda: _calibration().to_json(), SceneCalibration.load),
    "spec": (lambda: _spec(Path(".")), load_spec),
}


def _leaves(doc, path=()):
    """Every position in a JSON document: (path, value), dict keys and list items."""
    yield path, doc
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _leaves(v, (*path, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _leaves(v, (*path, i))


def _replaced(doc, path, value):
    doc = json.loads(json.dumps(doc))
    if not path:
        return value
    cur = doc
    for k in path[:-1]:
        cur = cur[k]
    cur[path[-1]] = value
    return doc


def _expect_clean(load, path: Path) -> None:
    """Loading succeeds or raises an ImpressError with a code; nothing else."""
    try:
        load(path)
    except ImpressError as exc:
        assert exc.code.startswith("E-") and str(exc)


@pytest.mark.parametrize("kind", sorted(JSON_READERS))
def test_json_readers_round_trip_and_refuse_damage(kind, tmp_path):
    make, load = JSON_READERS[kind]
    good = make()
    p = tmp_path / f"{kind}.json"
    p.write_text(json.dumps(good))
    load(p)  # the valid document loads
    raw = json.dumps(good).encode()
    cases = {
        "missing": None,
        "empty": b"",
        "truncated": raw[: len(raw) // 2],
        "not utf-8": b"\xff\xfe" + raw,
        "a list": b"[1, 2, 3]",
        "wrong format": json.dumps(good | {"format": "impress.other"}).encode(),
        "version 2": json.dumps(good | {"version": 2}).encode(),
        "version text": json.dumps(good | {"version": "1"}).encode(),
        "NaN": raw.replace(b"}", b', "extra": NaN}', 1),
        "Infinity": raw.replace(b"}", b', "extra": -Infinity}', 1),
        "1e400": raw.replace(b"}", b', "extra": 1e400}', 1),
        "deep nesting": b"[" * 100_000 + b"]" * 100_000,
        "huge integer": raw.replace(b"}", b', "extra": ' + b"9" * 5000 + b"}", 1),
    }
    for name, data in cases.items():
        q = tmp_path / f"{kind}-{name}.json"
        if data is not None:
            q.write_bytes(data)
        with pytest.raises(ImpressError) as err:
            load(q)
        assert err.value.code.startswith("E-"), name
        assert str(q) in str(err.value), name


@pytest.mark.parametrize("kind", sorted(JSON_READERS))
def test_structural_fuzz_of_json_readers(kind, tmp_path):
    """Every leaf and every subtree replaced by each hostile value."""
    make, load = JSON_READERS[kind]
    good = make()
    p = tmp_path / "doc.json"
    n = 0
    for path, _ in _leaves(good):
        if path in (("format",), ("version",)):
            continue
        for value in HOSTILE:
            p.write_text(json.dumps(_replaced(good, path, value)))
            _expect_clean(load, p)
            n += 1
    assert n > 50


def _byte_fuzz(data: bytes, load, path: Path, seed: int, n: int = 150) -> None:
    rng = random.Random(seed)
    for _ in range(n):
        b = bytearray(data)
        for _ in range(rng.randint(1, 6)):
            op = rng.random()
            i = rng.randrange(len(b)) if b else 0
            if op < 0.4 and b:
                b[i] = rng.randrange(256)
            elif op < 0.6 and b:
                del b[i : i + rng.randint(1, 64)]
            elif op < 0.8:
                b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 16)))
            else:
                b = b[: rng.randrange(len(b) + 1)]
        path.write_bytes(bytes(b))
        _expect_clean(load, path)


@pytest.mark.parametrize("kind", sorted(JSON_READERS))
def test_byte_fuzz_of_json_readers(kind, tmp_path):
    make, load = JSON_READERS[kind]
    _byte_fuzz(json.dumps(make(), indent=1).encode(), load, tmp_path / "f.json", seed=len(kind))


def test_project_reader_fuzz(tmp_path):
    proj = create_project(tmp_path / "p", case_id="R-1")
    proj.set_intrinsics(_intrinsics())
    proj.set_picks(_picks())
    proj.set_calibration(_calibration())
    proj.save()
    Project.load(tmp_path / "p")
    good = json.loads((tmp_path / "p" / "project.json").read_text())
    target = tmp_path / "q"
    target.mkdir()
    (target / "log.jsonl").write_bytes((tmp_path / "p" / "log.jsonl").read_bytes())
    pf = target / "project.json"
    rng = random.Random(5)
    leaves = [p for p, _ in _leaves(good) if p not in (("format",), ("version",))]
    for path in rng.sample(leaves, min(150, len(leaves))):
        pf.write_text(json.dumps(_replaced(good, path, rng.choice(HOSTILE))))
        _expect_clean(Project.load, target)
    _byte_fuzz(json.dumps(good).encode(), Project.load, pf, seed=11, n=100)
    # the log too: damaged lines are an integrity error, never a crash
    log = tmp_path / "p" / "log.jsonl"
    _byte_fuzz(log.read_bytes(), lambda _p: Project.load(tmp_path / "p"), log, seed=12, n=60)


# ----- video ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def tiny_video(tmp_path_factory) -> Path:
    from impress_gui.sim.video_out import VideoSink

    p = tmp_path_factory.mktemp("video") / "tiny.mp4"
    sink = VideoSink(p, 64, 36, 30.0, None)
    rng = np.random.default_rng(0)
    for _ in range(12):
        sink.write(rng.integers(0, 255, (36, 64, 3), np.uint8))
    sink.close()
    return p


def _video_load(path: Path) -> None:
    from impress_gui.core.formats.video import open_video

    with open_video(path) as v:
        for _k, _f in v.iter_frames(0, v.frame_count):
            pass


def test_video_reader_refuses_damage(tiny_video, tmp_path):
    import cv2

    _video_load(tiny_video)
    data = tiny_video.read_bytes()
    cases = {
        "empty.mp4": b"",
        "text.mp4": b"not a video at all",
        "half.mp4": data[: len(data) // 2],
        "head.mp4": data[:64],
        "noise.mp4": bytes(random.Random(1).randrange(256) for _ in range(5000)),
    }
    for name, payload in cases.items():
        (tmp_path / name).write_bytes(payload)
        with pytest.raises(ImpressError) as err:
            _video_load(tmp_path / name)
        assert err.value.code.startswith("E-VIDEO"), name
    with pytest.raises(ImpressError):
        _video_load(tmp_path / "missing.mp4")
    # frame folders: empty, non-images, mixed sizes, a PNG declaring 100000 x 100000 pixels
    empty = tmp_path / "empty-frames"
    empty.mkdir()
    junk = tmp_path / "junk-frames"
    junk.mkdir()
    (junk / "a.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    mixed = tmp_path / "mixed-frames"
    mixed.mkdir()
    cv2.imwrite(str(mixed / "f0.png"), np.zeros((36, 64, 3), np.uint8))
    cv2.imwrite(str(mixed / "f1.png"), np.zeros((40, 64, 3), np.uint8))
    bomb = tmp_path / "bomb-frames"
    bomb.mkdir()
    png = bytearray(cv2.imencode(".png", np.zeros((8, 8, 3), np.uint8))[1].tobytes())
    png[16:24] = struct.pack(">II", 100_000, 100_000)  # IHDR width/height (CRC now wrong)
    (bomb / "f0.png").write_bytes(bytes(png))
    for folder in (empty, junk, mixed, bomb):
        _expect_clean(_video_load, folder)
        with pytest.raises(ImpressError):
            _video_load(folder)


def test_video_byte_fuzz(tiny_video, tmp_path):
    _byte_fuzz(tiny_video.read_bytes(), _video_load, tmp_path / "f.mp4", seed=3, n=40)


# ----- X3P ----------------------------------------------------------------------------------------
SPEC = GridSpec(-2.0, 3.0, 0.1, (20, 30))


def _height() -> np.ndarray:
    h = np.linspace(0, 5, 600, dtype=np.float32).reshape(20, 30)
    h[3, 4] = np.nan
    return h


def _x3p(tmp_path: Path, name: str = "h.x3p", xml_edit=None, members=None, data=None) -> Path:
    """An X3P from the product's writer, optionally with main.xml edited, members added or
    the point data replaced (checksums then recomputed so only the intended damage remains)."""
    import hashlib

    src = zipfile.ZipFile(io.BytesIO(x3p_bytes(SPEC, _height(), "2024-01-01T00:00:00Z")))
    xml = src.read("main.xml").decode()
    payload = src.read("bindata/data.bin") if data is None else data
    xml = xml.replace(
        hashlib.md5(src.read("bindata/data.bin")).hexdigest(), hashlib.md5(payload).hexdigest()
    )
    if xml_edit:
        xml = xml_edit(xml)
    xb = xml.encode()
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("main.xml", xb)
        zf.writestr("md5checksum.hex", f"{hashlib.md5(xb).hexdigest()} *main.xml\n")
        zf.writestr("bindata/data.bin", payload)
        for n, b in (members or {}).items():
            zf.writestr(n, b)
    p = tmp_path / name
    p.write_bytes(buf.getvalue())
    return p


def _code(fn, path) -> str:
    with pytest.raises(ImpressError) as err:
        fn(path)
    assert str(path) in str(err.value)
    return err.value.code


def test_x3p_round_trip(tmp_path):
    p = tmp_path / "h.x3p"
    p.write_bytes(x3p_bytes(SPEC, _height(), "2024-01-01T00:00:00Z"))
    d = read_export(p)
    # stored in the right-handed export frame (y = -rail Y): the grid's rows last first
    np.testing.assert_allclose(d.height_mm, _height()[::-1], atol=1e-5, equal_nan=True)
    assert d.spec.shape == SPEC.shape and d.spec.pixel_mm == pytest.approx(0.1)
    ny = SPEC.shape[0]
    assert (d.spec.x0_mm, d.spec.y0_mm) == pytest.approx((-2.0, -(3.0 + (ny - 1) * 0.1)))


def test_x3p_zip_traversal_and_bombs(tmp_path):
    for name in ("../evil.txt", "/etc/passwd", "a/../../b", "..\\win.txt", "C:/x"):
        p = _x3p(tmp_path, members={name: b"x"})
        assert _code(read_x3p, p) == "E-ZIP-TRAVERSAL", name
    p = _x3p(tmp_path, xml_edit=lambda x: x.replace("bindata/data.bin", "../../data.bin"))
    assert _code(read_x3p, p) == "E-ZIP-TRAVERSAL"
    # a declared size of 16 TB: refused from the directory, nothing inflated
    good = _x3p(tmp_path).read_bytes()
    cd = good.rfind(b"PK\x01\x02" + good[good.rfind(b"PK\x01\x02") + 4 :][:0])
    patched = bytearray(good)
    for off in _central_entries(good):
        if good[off + 46 : off + 46 + 16] == b"bindata/data.bin":
            patched[off + 24 : off + 28] = struct.pack("<I", 0xFFFFFFFE)
    assert cd > 0
    p = tmp_path / "declared.x3p"
    p.write_bytes(bytes(patched))
    assert _code(read_x3p, p) == "E-ZIP-BOMB"
    # a real deflate bomb: 64 MB of zeros where main.xml expects 4.8 kB of data
    p = _x3p(tmp_path, data=b"\0" * (64 << 20), name="bomb.x3p")
    assert p.stat().st_size < 200_000
    assert _code(read_x3p, p) == "E-ZIP-BOMB"
    # thousands of members
    p = _x3p(tmp_path, members={f"m{i}": b"" for i in range(1500)}, name="many.x3p")
    assert _code(read_x3p, p) == "E-ZIP-BOMB"


def _central_entries(data: bytes):
    off = data.find(b"PK\x01\x02")
    while off >= 0:
        yield off
        off = data.find(b"PK\x01\x02", off + 4)


@pytest.mark.parametrize(
    "edit, code",
    [
        (lambda x: x.replace("ISO5436 - 2000", "ISO9999 - 2042"), "E-VERSION"),
        (lambda x: x.replace("<SizeX>30</SizeX>", "<SizeX>-30</SizeX>"), "E-X3P-XML"),
        (lambda x: x.replace("<SizeX>30</SizeX>", "<SizeX>abc</SizeX>"), "E-X3P-XML"),
        (lambda x: x.replace("<SizeX>30</SizeX>", "<SizeX>99999999999</SizeX>"), "E-X3P-XML"),
        (
            lambda x: x.replace("<SizeX>30</SizeX>", "<SizeX>400000</SizeX>").replace(
                "<SizeY>20</SizeY>", "<SizeY>400000</SizeY>"
            ),
            "E-TOO-LARGE",
        ),
        (lambda x: x.replace("<SizeX>30</SizeX>", "<SizeX>31</SizeX>"), "E-X3P-DATA"),
        (
            lambda x: x.replace("<Increment>0.0001</Increment>", "<Increment>nan</Increment>", 1),
            "E-VALUE",
        ),
        (
            lambda x: x.replace("<Increment>0.0001</Increment>", "<Increment>1e300</Increment>", 1),
            "E-VALUE",
        ),
        (
            lambda x: x.replace("<Increment>0.0001</Increment>", "<Increment>0</Increment>", 1),
            "E-VALUE",
        ),
        (  # both axes of 1e-300 m: square, positive, finite - and no surface's cell
            lambda x: x.replace("<Increment>0.0001</Increment>", "<Increment>1e-300</Increment>"),
            "E-VALUE",
        ),
        (
            lambda x: x.replace("<DataType>D</DataType></CZ>", "<DataType>Q</DataType></CZ>"),
            "E-X3P-DATA",
        ),
        (
            lambda x: x.replace("<FeatureType>SUR</FeatureType>", "<FeatureType>PRF</FeatureType>"),
            "E-X3P-DATA",
        ),
        (lambda x: x[: len(x) // 2], "E-X3P-XML"),
        (lambda x: x.replace("<Record3>", "<Record3><Junk>"), "E-X3P-XML"),
        (
            lambda x: (
                '<?xml version="1.0"?><!DOCTYPE lol [<!ENTITY a "aaaa">'
                '<!ENTITY b "&a;&a;&a;&a;">]>' + x.split("?>", 1)[1]
            ),
            "E-X3P-XML",
        ),
    ],
)
def test_x3p_damaged_main_xml(tmp_path, edit, code):
    assert _code(read_x3p, _x3p(tmp_path, xml_edit=edit)) == code


def test_x3p_damaged_data_and_container(tmp_path):
    good = _x3p(tmp_path).read_bytes()
    cases = {
        "empty.x3p": b"",
        "text.x3p": b"hello",
        "half.x3p": good[: len(good) // 2],
        "tail.x3p": good[:-30],
    }
    for name, payload in cases.items():
        (tmp_path / name).write_bytes(payload)
        assert _code(read_x3p, tmp_path / name) == "E-X3P-ZIP", name
    assert _code(read_x3p, tmp_path / "none.x3p") == "E-FILE-MISSING"
    z = np.zeros(600)
    z[5] = np.inf
    assert _code(read_x3p, _x3p(tmp_path, data=z.astype("<f8").tobytes())) == "E-VALUE"
    z[5] = 1e30
    assert _code(read_x3p, _x3p(tmp_path, data=z.astype("<f8").tobytes())) == "E-VALUE"
    assert _code(read_x3p, _x3p(tmp_path, data=b"\0" * 4000)) == "E-X3P-DATA"  # truncated
    # a checksum that does not match the data
    src = zipfile.ZipFile(io.BytesIO(good))
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for n in src.namelist():
            b = src.read(n)
            zf.writestr(n, b[:-8] + b"\x00" * 8 if n == "bindata/data.bin" else b)
    (tmp_path / "md5.x3p").write_bytes(buf.getvalue())
    assert _code(read_x3p, tmp_path / "md5.x3p") == "E-X3P-CHECKSUM"
    # a member whose bytes do not match its CRC
    bad = bytearray(good)
    i = bad.find(b"PK\x03\x04")
    j = bad.find(b"PK\x03\x04", i + 4)  # second local header: the checksum file
    bad[j - 5] ^= 0xFF  # a byte of the first member's compressed data
    (tmp_path / "crc.x3p").write_bytes(bytes(bad))
    _expect_clean(read_x3p, tmp_path / "crc.x3p")
    with pytest.raises(ImpressError):
        read_x3p(tmp_path / "crc.x3p")


def test_x3p_byte_fuzz(tmp_path):
    _byte_fuzz(_x3p(tmp_path).read_bytes(), read_x3p, tmp_path / "f.x3p", seed=7, n=200)


# ----- PLY ----------------------------------------------------------------------------------------
def _ply() -> bytes:
    return ply_bytes(SPEC, _height(), None, 1)


def test_ply_round_trip(tmp_path):
    p = tmp_path / "c.ply"
    p.write_bytes(_ply())
    d = read_export(p)
    h = _height()
    assert len(d.points_mm) == np.isfinite(h).sum() and d.colours is not None
    assert d.points_mm[:, 2].max() == pytest.approx(np.nanmax(h), abs=1e-5)


def _ply_with(header_edit=None, body=None) -> bytes:
    raw = _ply()
    i = raw.index(b"end_header\n") + len(b"end_header\n")
    head, rest = raw[:i].decode(), raw[i:]
    if header_edit:
        head = header_edit(head)
    return head.encode() + (rest if body is None else body)


@pytest.mark.parametrize(
    "payload, code",
    [
        (b"", "E-PLY-HEADER"),
        (b"PLY junk", "E-PLY-HEADER"),
        (b"ply\nformat binary_little_endian 1.0\n" + b"comment x\n" * 10000, "E-PLY-HEADER"),
        (_ply_with(lambda h: h.replace("binary_little_endian 1.0", "ascii 1.0")), "E-PLY-HEADER"),
        (
            _ply_with(lambda h: h.replace("binary_little_endian 1.0", "binary_little_endian 2.0")),
            "E-VERSION",
        ),
        (
            _ply_with(lambda h: h.replace("element vertex 599", "element vertex 999999999999")),
            "E-TOO-LARGE",
        ),
        (_ply_with(lambda h: h.replace("element vertex 599", "element vertex -5")), "E-PLY-HEADER"),
        (
            _ply_with(lambda h: h.replace("element vertex 599", "element vertex 600")),
            "E-PLY-TRUNCATED",
        ),
        (_ply()[:-100], "E-PLY-TRUNCATED"),
        (_ply_with(lambda h: h.replace("property float z\n", "")), "E-PLY-HEADER"),
        (
            _ply_with(lambda h: h.replace("property float z", "property list uchar int z")),
            "E-PLY-HEADER",
        ),
        (
            _ply_with(lambda h: h.replace("property float z", "property quaternion z")),
            "E-PLY-HEADER",
        ),
        (_ply_with(lambda h: h.replace("element vertex", "element face")), "E-PLY-HEADER"),
        (
            _ply_with(lambda h: h.replace("property uchar red", "property float red")),
            "E-PLY-HEADER",
        ),
    ],
)
def test_ply_damaged(tmp_path, payload, code):
    p = tmp_path / "c.ply"
    p.write_bytes(payload)
    assert _code(read_ply, p) == code


def test_ply_values(tmp_path):
    raw = bytearray(_ply())
    body = raw.index(b"end_header\n") + len(b"end_header\n")
    for value in (np.nan, np.inf, 1e30):
        b = bytearray(raw)
        b[body + 8 : body + 12] = np.float32(value).tobytes()  # the first vertex's z
        (tmp_path / "v.ply").write_bytes(bytes(b))
        assert _code(read_ply, tmp_path / "v.ply") == "E-VALUE"
    assert _code(read_ply, tmp_path / "none.ply") == "E-FILE-MISSING"
    assert _code(read_export, tmp_path / "v.stl") == "E-FORMAT"


def test_ply_byte_fuzz(tmp_path):
    _byte_fuzz(_ply(), read_ply, tmp_path / "f.ply", seed=9, n=200)


# ----- in the window: a message, not a crash ------------------------------------------------------
@pytest.mark.qt_log_ignore("propagateSizeHints")
def test_the_window_reports_hostile_files_with_a_message(qtbot, tmp_path):
    from measure_scans import guard_pyside_none

    from impress_gui.ui.messages import Messenger
    from impress_gui.ui.processing.tab import ProcessingTab

    guard_pyside_none()

    class Dialogs:
        def open_file(self, *a, **k):
            return ""

        directory = open_file

    tab = ProcessingTab(Messenger(None), Dialogs())
    qtbot.addWidget(tab)
    try:
        cal = _calibration().to_json()
        cal["speed_mm_s"] = 10**400
        bad = tmp_path / "cal.json"
        bad.write_text(json.dumps(cal))
        assert not tab.load_calibration(bad)
        assert "[E-" in tab.messenger.last_text
        (tmp_path / "v.mp4").write_bytes(b"\0" * 100)
        tab.open_video(tmp_path / "v.mp4")
        assert tab.video is None and "[E-VIDEO" in tab.messenger.last_text
        assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.json", "v.mp4"]
    finally:
        tab.messenger.close_all()
        tab.shutdown()
