"""What the console shows, run as a user runs it (a fresh ``python -m impress_gui`` process):
one coded line per failure, never a library's warning lines with source code, and a Ctrl-C at
any moment - even while the command's modules are still loading - an interruption (exit 130),
never a traceback or an "internal error" (the audit of 4 December 2026 found all three)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LEAKS = ("Traceback", "Warning", ".py:", "tifffile", "E-INTERNAL")


def _default_sigint() -> None:
    # a shell starts background jobs (a test run in the background, CI) with Ctrl-C ignored,
    # and the child would inherit that: give it Ctrl-C as a terminal gives it
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _run(args, timeout=120, **kw):
    env = {k: v for k, v in os.environ.items() if k != "IMPRESS_DEBUG"}
    return subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout, env=env, preexec_fn=_default_sigint, **kw)


def test_a_degenerate_calibration_gives_its_code_and_no_library_warnings(flat_scan,
                                                                        flat_calibration,
                                                                        tmp_path):
    """A laser plane turned flat (normal along the optical axis): numpy divides by zero on
    the way to the refusal; the user sees the refusal's line alone."""
    doc = json.loads(Path(flat_calibration).read_text())
    doc["laser_planes"]["green"]["normal"] = [0, 0, 1]
    cal = tmp_path / "flat-green.json"
    cal.write_text(json.dumps(doc))
    r = _run(["-m", "impress_gui", "process", str(flat_scan / "scan.mp4"), "--calibration",
              str(cal), "-o", str(tmp_path / "out"), "--frames", "40:60", "--no-texture"])
    assert r.returncode == 2, r.stderr
    assert "[E-" in r.stderr
    for leak in LEAKS:
        assert leak not in r.stderr + r.stdout, r.stderr
    assert not (tmp_path / "out").exists()


def test_the_batch_workers_show_no_library_warnings_either(flat_scan, flat_calibration,
                                                           tmp_path):
    """A batch's scans run in worker processes, fresh interpreters that do not inherit the
    console's filter: the same degenerate calibration in two scans on two workers gives each
    scan's refusal in the summary and no library line on the console."""
    doc = json.loads(Path(flat_calibration).read_text())
    doc["laser_planes"]["green"]["normal"] = [0, 0, 1]
    cal = tmp_path / "flat-green.json"
    cal.write_text(json.dumps(doc))
    scans = [{"name": f"s{i}", "video": str(flat_scan / "scan.mp4"), "calibration": str(cal),
              "parameters": {"frame_start": 40, "frame_stop": 60, "texture": False}}
             for i in range(2)]
    manifest = tmp_path / "m.json"
    manifest.write_text(json.dumps({"format": "impress.batch", "version": 1, "scans": scans}))
    r = _run(["-m", "impress_gui", "batch", str(manifest), "-o", str(tmp_path / "b"),
              "--jobs", "2"], timeout=300)
    assert r.returncode == 1, r.stderr
    rows = json.loads((tmp_path / "b" / "summary.json").read_text())["scans"]
    assert [row["status"] for row in rows] == ["failed", "failed"], rows
    assert all(row["code"].startswith("E-") for row in rows), rows
    for leak in LEAKS:
        assert leak not in r.stderr + r.stdout, r.stderr


_INTERRUPT = r"""
import os, signal, sys
import impress_gui.cli as cli

how = sys.argv[1]
real = cli._load

def load(name):
    # Ctrl-C arrives while the command's module is being imported
    if how == "plain":
        os.kill(os.getpid(), signal.SIGINT)
    else:  # an import the interruption broke off surfaces as an ImportError (numpy does)
        try:
            os.kill(os.getpid(), signal.SIGINT)
        except KeyboardInterrupt:
            raise ImportError("partially initialized module") from None
    return real(name)

cli._load = load
sys.exit(cli.main(sys.argv[2:]))
"""


def test_ctrl_c_while_the_command_loads_is_an_interruption(tmp_path):
    for how in ("plain", "broken-import"):
        for argv in (["process", "v.mp4", "--calibration", "c.json", "-o", str(tmp_path / "o")],
                     ["calibrate", "--help"]):
            r = _run(["-c", _INTERRUPT, how, *argv], timeout=60)
            assert r.returncode == 130, (how, argv, r.returncode, r.stderr)
            assert "interrupted" in r.stderr
            for leak in LEAKS:
                assert leak not in r.stderr, (how, r.stderr)
    assert not (tmp_path / "o").exists()
