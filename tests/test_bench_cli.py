"""benchmarks/bench_cli.py's bookkeeping (no timing): run.json parsing and the stages' sums."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_cli.py"
_spec = importlib.util.spec_from_file_location("bench_cli", _PATH)
bench_cli = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench_cli)


def _fake_output(folder: Path) -> Path:
    folder.mkdir()
    (folder / "run.json").write_text(json.dumps({
        "date_utc": "2025-01-01T00:00:00Z", "host": "x", "python": "3.12",
        "timings": {"seconds_total": 6.0, "seconds_setup": 1.0, "seconds_frame_loop": 4.5,
                    "seconds_finish": 0.4, "seconds_spool": 0.05, "frames_per_second": 200.0,
                    "rows_finished_in_loop": 0.77},
        "wall_seconds": 6.5}))
    (folder / "metadata.json").write_text(json.dumps({
        "grid": {"x0_mm": -150.0, "y0_mm": -20.0, "pixel_mm": 0.1, "shape": [4000, 3000]},
        "frames": {"start": 15, "stop": 915}}))
    return folder


def test_read_run(tmp_path):
    r = bench_cli.read_run(_fake_output(tmp_path / "out"))
    assert (r["setup"], r["frame_loop"], r["finish"], r["reconstruct"]) == (1.0, 4.5, 0.4, 6.0)
    assert (r["wall"], r["fps"], r["rows_in_loop"]) == (6.5, 200.0, 0.77)
    assert r["other_seconds"] == {"spool": 0.05}
    assert r["width_mm"] == pytest.approx(300.0) and r["length_mm"] == pytest.approx(400.0)
    assert (r["cells"], r["frames"]) == (12_000_000, 900)


def test_read_run_without_metadata(tmp_path):
    out = _fake_output(tmp_path / "out")
    (out / "metadata.json").unlink()
    r = bench_cli.read_run(out)
    assert r["setup"] == 1.0 and r["width_mm"] is None and r["frames"] is None


def _child(with_wraps: bool) -> dict:
    t = {"python": 100.1, "cli_imported": 100.3, "process_files_start": 100.6,
         "process_files_end": 110.0, "main_end": 110.1}
    if with_wraps:
        t |= {"reconstruct_start": 100.9, "reconstruct_end": 107.0, "write_start": 107.1,
              "write_end": 109.9}
    mem = {k: {"VmRSS": 1000, "VmHWM": 1000} for k in t}
    mem["process_files_start"] = {"VmRSS": 50_000, "VmHWM": 50_000}
    cpu = {k: 2.0 * (v - 100.0) for k, v in t.items()}  # two busy cores
    return {"t": t, "mem": mem, "cpu": cpu, "cpu_s": 21.5, "spawn": 100.0, "exit": 110.5,
            "samples": [(102.0, 900_000), (108.0, 1_500_000)],
            "events": [(100.7, 0.0, "reading"), (101.0, 0.1, "frame 25"), (107.1, 0.93, "writing"),
                       (109.9, 1.0, "outputs written")]}


def test_stages_add_up_to_the_whole_command(tmp_path):
    run = bench_cli.read_run(_fake_output(tmp_path / "out"))
    for wraps in (True, False):
        s, estimated = bench_cli.stages(_child(wraps), run)
        assert sum(s[k] for k in bench_cli.STAGES) == pytest.approx(s["total"])
        assert s["total"] == pytest.approx(10.5)
        assert s["interpreter"] == pytest.approx(0.1) and s["imports"] == pytest.approx(0.5)
        assert (s["setup"], s["frame_loop"], s["finish"]) == (1.0, 4.5, 0.4)
        assert s["exit"] == pytest.approx(0.4)
        if wraps:
            assert not estimated
            assert s["open"] == pytest.approx(0.3) and s["writing"] == pytest.approx(2.8)
            assert s["reconstruct_other"] == pytest.approx(0.2)
        else:  # boundaries from run.json's wall seconds (video opened to writing)
            assert {"open", "writing"} <= estimated
            assert s["open"] + s["reconstruct_other"] + 5.9 == pytest.approx(6.5)
            assert s["writing"] == pytest.approx(110.0 - 107.1)


def test_peaks_and_silence(tmp_path):
    child = _child(True)
    run = bench_cli.read_run(_fake_output(tmp_path / "out"))
    s, _ = bench_cli.stages(child, run)
    w = bench_cli.stage_windows(child, s)
    assert bench_cli.peak_mb(child, *w["start-up"]) == pytest.approx(50_000 / 1024)
    assert bench_cli.peak_mb(child, *w["writing"]) == pytest.approx(1_500_000 / 1024)
    cpu = bench_cli.cpu_stages(child)
    assert cpu["writing"] == pytest.approx(5.6) and cpu["exit"] == pytest.approx(1.3)
    assert sum(v for k, v in cpu.items() if k != "total") == pytest.approx(21.5)
    gap, msg = bench_cli.longest_silence(child)
    assert gap == pytest.approx(6.1) and msg == "frame 25"
