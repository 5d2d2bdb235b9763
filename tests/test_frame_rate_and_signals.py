"""A hostile-input audit (6 December 2026): ``process --fps`` was recorded nowhere and never
warned of, and a terminate signal (SIGTERM) left the output being written behind as a hidden
half-made folder. Now the frame rate read and the one given are in the metadata, a rate other
than the calibration's is warned of (``W-FPS-OTHER``), and SIGTERM ends a command as Ctrl-C
does: exit 143, one line, nothing half-written kept."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

from impress_gui.core.reconstruction.pipeline import process_files
from impress_gui.core.reconstruction.reconstruct import ProcessParams

PARAMS = dict(frame_start=40, frame_stop=70, texture=False, grid_mm=0.5)


def test_the_frame_rate_is_recorded_and_another_than_the_calibrations_warned(
        flat_scan, flat_calibration, tmp_path):
    cal_fps = json.loads(flat_calibration.read_text())["fps"]
    own = process_files(flat_scan / "scan.mp4", flat_calibration, tmp_path / "own",
                        ProcessParams(**PARAMS))
    given = process_files(flat_scan / "scan.mp4", flat_calibration, tmp_path / "given",
                          ProcessParams(**PARAMS), fps=2 * cal_fps)
    assert own["frame_rate"]["given_fps"] is None
    assert abs(own["frame_rate"]["fps"] - cal_fps) < 1e-3 * cal_fps
    assert not [w for w in own["warnings"] if w.startswith("W-FPS-OTHER")]
    assert given["frame_rate"] == {"fps": 2 * cal_fps, "given_fps": 2 * cal_fps}
    [warning] = [w for w in given["warnings"] if w.startswith("W-FPS-OTHER")]
    assert "(--fps)" in warning and f"{cal_fps:.6g}" in warning
    # the files say so too (an examiner reads the folder, not the return value)
    saved = json.loads((tmp_path / "given" / "metadata.json").read_text())
    assert saved["frame_rate"] == given["frame_rate"] and warning in saved["warnings"]


def test_sigterm_keeps_nothing_half_written(flat_scan, flat_calibration, tmp_path):
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "impress_gui", "process", str(flat_scan / "scan.mp4"),
         "--calibration", str(flat_calibration), "-o", str(out), "--grid-mm", "0.2"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        # the signal is sent once the output is being written (its hidden folder exists)
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and proc.poll() is None:
            if list(tmp_path.glob(".out.partial-*")):
                break
            time.sleep(0.02)
        assert proc.poll() is None, proc.communicate()
        os.kill(proc.pid, signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 128 + signal.SIGTERM, err
    assert "stopped by SIGTERM" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []  # neither the output nor a half-made one


def test_a_few_frames_are_not_taken_for_a_scan(flat_scan, flat_calibration, tmp_path):
    """The audit: a one-frame video (or ``--frames 0:1``) gave a map with no warning."""
    few = process_files(flat_scan / "scan.mp4", flat_calibration, tmp_path / "few",
                        ProcessParams(**{**PARAMS, "frame_stop": 44}))
    [warning] = [w for w in few["warnings"] if w.startswith("W-FEW-FRAMES")]
    assert "only 4 frame(s)" in warning and "frames 40..43" in warning
    enough = process_files(flat_scan / "scan.mp4", flat_calibration, tmp_path / "enough",
                           ProcessParams(**{**PARAMS, "frame_stop": 50}))
    assert not [w for w in enough["warnings"] if w.startswith("W-FEW-FRAMES")]


def test_a_signal_inside_the_writability_probe_leaves_no_folder(tmp_path, monkeypatch):
    """The probe makes the hidden work folder, writes its mark and removes it; a terminate
    signal landing between (its exception raised there) left the folder behind while the
    command said nothing half-written was kept (found by polling for the folder)."""
    from impress_gui import cli
    from impress_gui.core.base import outdir, workfiles

    def interrupted(kind):
        raise cli.Terminated(signal.SIGTERM)

    monkeypatch.setattr(outdir, "mark_bytes", interrupted)
    try:
        outdir.OutputFolder(tmp_path / "out", "reconstruction")
    except cli.Terminated:
        pass
    else:
        raise AssertionError("the probe's interruption did not reach the caller")
    assert list(tmp_path.iterdir()) == [] and workfiles.open_paths() == []


def test_an_interruption_removes_what_this_process_left_half_written(tmp_path):
    """Whatever the clean-up of an interruption missed (noted, never done) is removed before
    the command says nothing half-written was kept."""
    from impress_gui import cli
    from impress_gui.core.base import workfiles

    left = tmp_path / ".out.partial-1"
    left.mkdir()
    (left / "part.bin").write_bytes(b"x")
    workfiles.note(left)
    line, status = cli._interrupted_line("impress process", cli.Terminated(signal.SIGTERM))
    assert "nothing half-written was kept" in line and status == 128 + signal.SIGTERM
    assert not left.exists() and workfiles.open_paths() == []
