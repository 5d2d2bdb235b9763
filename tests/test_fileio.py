import json

import numpy as np
import pytest

from impress_gui.core.base.errors import FormatError
from impress_gui.core.base.fileio import atomic_output, read_json, sha256_file, write_json
from impress_gui.core.calibration.geometry import Intrinsics


def test_atomic_output_keeps_previous_content_on_failure(tmp_path):
    target = tmp_path / "out.bin"
    target.write_bytes(b"good")
    with pytest.raises(RuntimeError):
        with atomic_output(target) as fh:
            fh.write(b"half")
            raise RuntimeError("power cut")
    assert target.read_bytes() == b"good"
    assert list(tmp_path.iterdir()) == [target]


def test_json_round_trip_and_damage(tmp_path):
    k = np.array([[1000.0, 0, 320], [0, 1000.0, 180], [0, 0, 1]])
    intr = Intrinsics(k, np.array([-0.1, 0.02, 0, 0, 0]), (640, 360), rms_px=0.2)
    p = tmp_path / "intr.json"
    intr.save(p)
    back = Intrinsics.load(p)
    assert np.array_equal(back.camera_matrix, k) and back.image_size == (640, 360)
    assert len(sha256_file(p)) == 64

    text = p.read_text()
    p.write_text(text[: len(text) // 2])
    with pytest.raises(FormatError, match="not valid JSON"):
        Intrinsics.load(p)
    doc = json.loads(text)
    doc["version"] = 99
    p.write_text(json.dumps(doc))
    with pytest.raises(FormatError, match="version 99"):
        Intrinsics.load(p)
    doc["version"] = 1
    doc["camera_matrix"][0][0] = "x"
    p.write_text(json.dumps(doc))
    with pytest.raises(FormatError, match="camera_matrix"):
        Intrinsics.load(p)
    p.write_text(text.replace("1000.0", "NaN", 1))
    with pytest.raises(FormatError):
        Intrinsics.load(p)
    write_json(tmp_path / "other.json", {"format": "impress.target", "version": 1})
    with pytest.raises(FormatError, match="not a impress.intrinsics file"):
        read_json(tmp_path / "other.json", "impress.intrinsics")
