"""Every export of the viewer carries its provenance (issue 8): the software version, the
SHA-256 of the reconstruction's metadata.json and the input hashes it records, the grid and
the parameters (layer, levelling plane, profile width...), each in its format's own place -
read back here from every file. PNG text chunks leave the pixels alone; exports are
deterministic (no time inside but the X3P's date)."""

from __future__ import annotations

import hashlib
import io
import json

import cv2
import numpy as np
import pytest
import tifffile

from impress_gui import __version__
from impress_gui.core.formats import provenance as P
from impress_gui.core.formats.readers import read_ply, read_x3p
from impress_gui.core.formats.writers import HEIGHT_CONVENTION, RECON_FORMAT
from impress_gui.core.measure import readings as M
from impress_gui.core.reconstruction.grid import GridSpec

pytestmark = [pytest.mark.qt_log_ignore("propagateSizeHints"),
              pytest.mark.usefixtures("no_stray_python_threads")]
SPEC = GridSpec(-8.0, 20.0, 0.1, (120, 160))
VIDEO_SHA = "a" * 64
CAL_SHA = "b" * 64


def _heights() -> np.ndarray:
    x, y = np.meshgrid(SPEC.xs(), SPEC.ys())
    h = (0.02 * x - 0.01 * y + 1.5).astype(np.float32)
    h[:, 70:90] -= 2.0  # a slot
    h[5:8, 5:8] = np.nan
    return h


def make_recon(folder) -> dict:
    folder.mkdir(parents=True)
    buf = io.BytesIO()
    tifffile.imwrite(buf, _heights(), compression="zlib", metadata=None)
    (folder / "heightmap.tif").write_bytes(buf.getvalue())
    meta = {
        "format": RECON_FORMAT,
        "version": 1,
        "software": f"impress {__version__}",
        "inputs": {
            "video": {"path": "scan.mp4", "sha256": VIDEO_SHA},
            "calibration": {"path": "calibration.json", "sha256": CAL_SHA},
        },
        "grid": SPEC.to_json(),
        "height": HEIGHT_CONVENTION,
        "files": {"heightmap.tif": hashlib.sha256(buf.getvalue()).hexdigest()},
    }
    (folder / "metadata.json").write_text(json.dumps(meta, indent=1))
    return meta


def _sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ----- the core helpers --------------------------------------------------------------------------
def test_png_text_chunks_keep_the_pixels():
    rng = np.random.default_rng(3)
    img = rng.integers(0, 255, (50, 70, 3), np.uint8)
    ok, enc = cv2.imencode(".png", img)
    assert ok
    text = {"Software": P.SOFTWARE, "Note": "café", "Unicode": "Ω 0.1 mm"}
    out = P.png_with_text(enc.tobytes(), text)
    assert out == P.png_with_text(enc.tobytes(), text)  # deterministic
    assert out[:33] == enc.tobytes()[:33]  # signature and IHDR untouched, chunks right after
    np.testing.assert_array_equal(cv2.imdecode(np.frombuffer(out, np.uint8), cv2.IMREAD_COLOR), img)
    assert P.read_png_text(out) == text
    assert b"iTXt" in out and b"tEXt" in out  # Latin-1 as tEXt, the rest as iTXt
    with pytest.raises(ValueError):
        P.png_with_text(b"GIF89a....", text)
    bad = bytearray(out)
    bad[40] ^= 0xFF  # inside the first text chunk
    with pytest.raises(ValueError, match="CRC"):
        P.read_png_text(bytes(bad))


def test_the_source_is_the_metadata_json_that_was_loaded(tmp_path):
    folder = tmp_path / "recon"
    meta = make_recon(folder)
    src = P.reconstruction_source(meta, folder)
    assert src["metadata_json_sha256"] == _sha(folder / "metadata.json")
    assert src["heightmap_sha256"] == meta["files"]["heightmap.tif"]
    assert (src["video_sha256"], src["calibration_sha256"]) == (VIDEO_SHA, CAL_SHA)
    # a metadata.json replaced on disk after loading is not vouched for
    (folder / "metadata.json").write_text(json.dumps(meta | {"software": "impress 9"}))
    src = P.reconstruction_source(meta, folder)
    assert src["metadata_json_sha256"] is None and "changed" in src["note"]
    assert P.reconstruction_source(meta, None)["metadata_json_sha256"] is None


def test_csv_exports_lead_with_provenance_lines_and_still_read_back(tmp_path):
    folder = tmp_path / "recon"
    meta = make_recon(folder)
    plane = {"a": 0.02, "b": -0.01, "c": 1.5, "rms_mm": 0.0, "n": 3}
    prov = P.export_provenance(
        "profile-csv",
        P.reconstruction_source(meta, folder),
        spec=SPEC,
        plane=plane,
        parameters={"layer": "fused", "width_mm": 0.5},
    )
    h = M.levelled(_heights(), SPEC, M.Plane(0.02, -0.01, 1.5))
    p = M.line_profile(h, SPEC, (-6.0, 25.0), (6.0, 25.0), width_mm=0.5)
    text = M.profile_csv(p, M.step_height(p, (0, 2), (8, 10)), prov)
    assert text.startswith("# IMPREsS profile")
    d, z = M.read_profile_csv(text)
    np.testing.assert_allclose(d, p.distance_mm, atol=1e-4)
    got = P.parse_comment_lines(text.splitlines())
    assert got["version"] == __version__ and got["software"] == P.SOFTWARE
    assert got["source.metadata_json_sha256"] == _sha(folder / "metadata.json")
    assert got["source.video_sha256"] == VIDEO_SHA
    assert got["grid.pixel_mm"] == "0.1" and got["grid.x0_mm"] == "-8.0"
    assert got["parameters.levelling.a"] == "0.02" and got["parameters.width_mm"] == "0.5"
    assert "levelling plane" in got["grid.height"]
    m = M.new_measurement(
        "ruler",
        [(0, 25), (3, 25)],
        {"xy_mm": 3.0},
        params={"layer": "fused", "heightmap_sha256": meta["files"]["heightmap.tif"]},
    )
    rows = M.measurements_csv([m], prov).splitlines()
    body = [r for r in rows if not r.startswith("#")]
    assert len(body) == 2 and body[0].endswith(",layer,heightmap_sha256")
    assert body[1].endswith(f",fused,{meta['files']['heightmap.tif']}")
    assert P.parse_comment_lines(rows)["source.heightmap_sha256"] == meta["files"]["heightmap.tif"]


# ----- every viewer export, read back ------------------------------------------------------------
@pytest.fixture
def viewer(qtbot, tmp_path):
    from test_gui_viewer import make_viewer  # guards PySide as that module does

    folder = tmp_path / "recon"
    make_recon(folder)
    v = make_viewer(qtbot)
    with qtbot.waitSignal(v.loaded, timeout=30000):
        v.open_reconstruction(folder)
    yield v
    v.shutdown()
    v.messenger.close_all()


def _export(qtbot, v, action, path) -> bytes:
    with qtbot.waitSignal(
        v.tasks.done, timeout=60000, check_params_cb=lambda _w, outcome: outcome == "finished"
    ):
        assert action(path)
    return path.read_bytes()


def _check(prov: dict, v, export: str, grid: bool = True) -> None:
    folder = v.data.folder
    assert prov["version"] == __version__ and prov["software"] == P.SOFTWARE
    assert prov["export"] == export
    src = prov["source"]
    assert src["metadata_json_sha256"] == _sha(folder / "metadata.json")
    assert src["heightmap_sha256"] == _sha(folder / "heightmap.tif")
    assert (src["video_sha256"], src["calibration_sha256"]) == (VIDEO_SHA, CAL_SHA)
    assert prov["parameters"]["levelling"] == pytest.approx(v.plane.to_json())
    if grid:
        assert prov["grid"]["pixel_mm"] == SPEC.pixel_mm
        assert (prov["grid"]["x0_mm"], prov["grid"]["y0_mm"]) == (SPEC.x0_mm, SPEC.y0_mm)
        assert "levelling plane" in prov["grid"]["height"]


def test_every_viewer_export_records_version_source_grid_and_parameters(qtbot, viewer, tmp_path):
    v = viewer
    with qtbot.waitSignal(v.levelled_changed, timeout=20000):
        assert v.level_region((-7.0, -2.0), (21.0, 30.0))
    with qtbot.waitSignal(v.profile_changed, timeout=10000):
        v.set_ruler((-6.0, 25.0), (6.0, 25.0))
    v.add_ruler_measurement("slot")
    a = v.actions

    raw = _export(qtbot, v, a.export_tiff, tmp_path / "h.tif")
    with tifffile.TiffFile(tmp_path / "h.tif") as tif:
        page = tif.pages[0]
        _check(json.loads(page.description.split("provenance ", 1)[1]), v, "heightmap-tiff")
        assert page.software == P.SOFTWARE
        assert page.tags["XResolution"].value == (100, 1)  # 100 cells per cm: 0.1 mm
        assert page.tags["ResolutionUnit"].value == 3  # centimetre
        np.testing.assert_array_equal(page.asarray(), v.measure_height())
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "h.tif"), v.measure_height())
    assert _export(qtbot, v, a.export_tiff, tmp_path / "h2.tif") == raw  # deterministic

    _export(qtbot, v, a.export_x3p, tmp_path / "h.x3p")
    x3p = read_x3p(tmp_path / "h.x3p")
    assert x3p.info["version"] == __version__
    _check(json.loads(x3p.info["comment"].split("provenance ", 1)[1]), v, "x3p")

    _export(qtbot, v, a.export_ply, tmp_path / "p.ply")
    got = P.parse_comment_lines(read_ply(tmp_path / "p.ply").comments)
    assert got["version"] == __version__ and got["parameters.layer"] == "fused"
    assert got["source.metadata_json_sha256"] == _sha(v.data.folder / "metadata.json")
    assert got["grid.pixel_mm"] == "0.1" and got["parameters.levelling.a"] != "-"

    for name, action, export in (
        ("fig.png", a.export_png, "figure-png"),
        ("profile.png", a.export_profile_png, "profile-png"),
    ):
        png = _export(qtbot, v, action, tmp_path / name)
        text = P.read_png_text(png)
        assert text["Software"] == P.SOFTWARE
        prov = json.loads(text[P.PNG_KEY])
        _check(prov, v, export)
        img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
        assert img is not None and img.shape[0] > 50
    assert json.loads(P.read_png_text((tmp_path / "profile.png").read_bytes())[P.PNG_KEY])[
        "parameters"
    ]["width_mm"] == pytest.approx(v.profile.width_mm)

    text = _export(qtbot, v, a.export_profile_csv, tmp_path / "profile.csv").decode()
    got = P.parse_comment_lines(text.splitlines())
    assert got["version"] == __version__ and got["export"] == "profile-csv"
    assert got["source.metadata_json_sha256"] == _sha(v.data.folder / "metadata.json")
    assert float(got["parameters.width_mm"]) == pytest.approx(v.profile.width_mm)
    d, _z = M.read_profile_csv(text)
    np.testing.assert_allclose(d, v.profile.distance_mm, atol=1e-4)

    text = _export(qtbot, v, a.export_measurements_csv, tmp_path / "m.csv").decode()
    got = P.parse_comment_lines(text.splitlines())
    assert got["version"] == __version__ and got["source.video_sha256"] == VIDEO_SHA
    body = [r for r in text.splitlines() if not r.startswith("#")]
    assert len(body) == 2 and body[1].endswith(v.data.metadata["files"]["heightmap.tif"])


def test_a_file_name_that_is_not_utf8_is_recorded_as_unicode_text():
    """A hostile-input audit: a path with a byte that is not UTF-8 went into metadata.json as a
    lone surrogate (``\\udcff``), which is not Unicode: a strict reader refuses the file."""
    import os

    from impress_gui.core.formats.provenance import input_record

    rec = input_record(os.fsdecode(b"/evidence/case\xff7/scan.mp4"), "0" * 64)
    assert rec["path"] == "/evidence/case\\xff7/scan.mp4"
    json.dumps(rec, ensure_ascii=False).encode("utf-8")  # strict UTF-8: no surrogate left
    assert input_record("/evidence/fall-ü/scan.mp4", "0" * 64)["path"] == "/evidence/fall-ü/scan.mp4"
