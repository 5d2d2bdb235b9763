"""``impress batch``: the same result folders as separate ``impress process`` runs, locally
(a process pool) and through a Dask LocalCluster; a summary; resumption; refusals."""

from __future__ import annotations

import csv
import hashlib
import json
from pathlib import Path

import pytest

from impress_gui import cli
from impress_gui.core.reconstruction.pipeline import process_files
from impress_gui.core.reconstruction.reconstruct import ProcessParams
from impress_gui.session.batch import load_manifest, run_batch

RANGES = {"a": (40, 70), "b": (50, 80), "c": (60, 90)}


def _manifest(tmp_path: Path, flat_scan: Path, flat_calibration: Path) -> Path:
    doc = {"format": "impress.batch", "version": 1, "scans": [
        {"name": n, "video": str(flat_scan / "scan.mp4"), "calibration": str(flat_calibration),
         "parameters": {"frame_start": a, "frame_stop": b, "texture": False}}
        for n, (a, b) in RANGES.items()]}
    p = tmp_path / "manifest.json"
    p.write_text(json.dumps(doc))
    return p


def _files(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir() if p.name != "run.json"}


@pytest.fixture(scope="module")
def separate(flat_scan, flat_calibration, tmp_path_factory) -> dict[str, dict[str, bytes]]:
    """The three scans processed one by one, as `impress process` does."""
    base = tmp_path_factory.mktemp("separate")
    out = {}
    for n, (a, b) in RANGES.items():
        process_files(flat_scan / "scan.mp4", flat_calibration, base / n,
                      ProcessParams(frame_start=a, frame_stop=b, texture=False))
        out[n] = _files(base / n)
    return out


def test_local_pool_gives_the_same_folders_and_a_summary(flat_scan, flat_calibration,
                                                         separate, tmp_path, capsys):
    manifest = _manifest(tmp_path, flat_scan, flat_calibration)
    code = cli.main(["batch", str(manifest), "-o", str(tmp_path / "batch"), "--jobs", "2"])
    assert code == 0, capsys.readouterr()
    for n in RANGES:
        assert _files(tmp_path / "batch" / n) == separate[n]
    with open(tmp_path / "batch" / "summary.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["name"] for r in rows] == list(RANGES)
    assert all(r["status"] == "processed" and int(r["cells_fused"]) > 1000 for r in rows)
    # the summaries name each scan's folder within the batch folder (they do not depend on
    # where it is), and the JSON records the manifest's hash
    assert [r["folder"] for r in rows] == list(RANGES)
    doc = json.loads((tmp_path / "batch" / "summary.json").read_text())
    assert doc["manifest"]["sha256"] == hashlib.sha256(manifest.read_bytes()).hexdigest()
    # run again: every scan is recognised as done, nothing is processed anew
    before = {n: (tmp_path / "batch" / n / "run.json").read_bytes() for n in RANGES}
    rows = run_batch(load_manifest(manifest), tmp_path / "batch", jobs=1)
    assert [r["status"] for r in rows] == ["done earlier"] * 3
    assert {n: (tmp_path / "batch" / n / "run.json").read_bytes() for n in RANGES} == before


def test_a_result_changed_afterwards_is_not_taken_as_done(flat_scan, flat_calibration,
                                                          tmp_path):
    """A hostile-input audit: a result folder whose heightmap was changed, or which gained a
    file, after it was written, or made with another frame rate than the manifest now asks,
    was reported "done earlier". Now the changed one and the other rate are processed again,
    and the folder with a file no run wrote is refused (nothing in it is replaced)."""
    manifest = _manifest(tmp_path, flat_scan, flat_calibration)
    items = load_manifest(manifest)
    out = tmp_path / "batch"
    assert [r["status"] for r in run_batch(items, out, jobs=1)] == ["processed"] * 3
    with (out / "a" / "heightmap.tif").open("r+b") as fh:  # one byte of the pixels
        fh.seek(-10, 2)
        last = fh.read(1)
        fh.seek(-10, 2)
        fh.write(bytes([last[0] ^ 1]))
    (out / "b" / "notes.txt").write_text("the examiner's note\n")
    doc = json.loads(manifest.read_text())
    doc["scans"][2]["parameters"]["fps"] = 29.0
    manifest.write_text(json.dumps(doc))
    rows = run_batch(load_manifest(manifest), out, jobs=1)
    assert [r["status"] for r in rows] == ["processed", "failed", "processed"], rows
    assert rows[1]["code"] == "E-OUTPUT-NOT-EMPTY"
    assert (out / "b" / "notes.txt").read_text() == "the examiner's note\n"
    meta = json.loads((out / "c" / "metadata.json").read_text())
    assert meta["frame_rate"]["given_fps"] == 29.0
    assert any(w.startswith("W-FPS-OTHER") for w in meta["warnings"])


def test_resumes_after_an_interruption(flat_scan, flat_calibration, separate, tmp_path):
    manifest = _manifest(tmp_path, flat_scan, flat_calibration)
    items = load_manifest(manifest)
    run_batch(items[:1], tmp_path / "batch", jobs=1)  # "interrupted" after the first scan
    rows = run_batch(items, tmp_path / "batch", jobs=1)
    assert [r["status"] for r in rows] == ["done earlier", "processed", "processed"]
    for n in RANGES:
        assert _files(tmp_path / "batch" / n) == separate[n]


def test_dask_local_cluster_gives_the_same_folders(flat_scan, flat_calibration, separate,
                                                  tmp_path):
    distributed = pytest.importorskip("distributed")
    manifest = _manifest(tmp_path, flat_scan, flat_calibration)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        rows = run_batch(load_manifest(manifest), tmp_path / "batch", scheduler=client)
    assert [r["status"] for r in rows] == ["processed"] * 3
    for n in RANGES:
        assert _files(tmp_path / "batch" / n) == separate[n]


def test_a_failing_scan_is_reported_and_the_others_finish(flat_scan, flat_calibration,
                                                          tmp_path, capsys):
    doc = {"format": "impress.batch", "version": 1, "scans": [
        {"name": "good", "video": str(flat_scan / "scan.mp4"),
         "calibration": str(flat_calibration),
         "parameters": {"frame_start": 40, "frame_stop": 60, "texture": False}},
        {"name": "missing", "video": "nowhere.mp4", "calibration": str(flat_calibration)}]}
    manifest = tmp_path / "m.json"
    manifest.write_text(json.dumps(doc))
    code = cli.main(["batch", str(manifest), "-o", str(tmp_path / "out"), "--jobs", "1"])
    text = capsys.readouterr().out
    assert code == 1
    assert "E-FILE-MISSING" in text and "processed" in text


def test_the_summary_is_safe_to_open_in_a_spreadsheet(flat_scan, flat_calibration, tmp_path):
    """A scan name or a path that a spreadsheet would run as a formula (``=``, ``+``, ``-``,
    ``@``) is written to summary.csv as text (a leading apostrophe), and exactly as given in
    summary.json (the audit of 4 December 2026 found ``=HYPERLINK(...)`` written as is). The
    name holds none of the characters a Windows folder name cannot (refused since the audit of
    6 December)."""
    evil = "=HYPERLINK('http' & 'evil';'x')"
    doc = {"format": "impress.batch", "version": 1, "scans": [
        {"name": evil, "video": str(flat_scan / "scan.mp4"),
         "calibration": str(flat_calibration),
         "parameters": {"frame_start": 40, "frame_stop": 46, "texture": False}},
        {"name": "b", "video": "=1+1.mp4", "calibration": str(flat_calibration)}]}
    manifest = tmp_path / "m.json"
    manifest.write_text(json.dumps(doc))
    assert cli.main(["batch", str(manifest), "-o", str(tmp_path / "out"), "--jobs", "1"]) == 1
    with open(tmp_path / "out" / "summary.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["name"] for r in rows] == ["'" + evil, "b"]
    assert rows[1]["video"].endswith("=1+1.mp4") and rows[1]["code"] == "E-FILE-MISSING"
    assert not any(v.startswith(("=", "+", "-", "@")) for r in rows for v in r.values())
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert [s["name"] for s in summary["scans"]] == [evil, "b"]
    assert summary["scans"][1]["video"].endswith("/=1+1.mp4")


def test_a_manifest_names_the_estimate_and_switches_the_unlit_soil(tmp_path):
    from impress_gui.session.batch import _params

    manifest = tmp_path / "m.json"
    manifest.write_text(json.dumps({"format": "impress.batch", "version": 1, "scans": [
        {"name": "a", "video": "v.mp4", "calibration": "c.json",
         "parameters": {"subpixel": "half-max", "unlit_soil": False,
                        "reconcile_lasers": False}}]}))
    params = _params(load_manifest(manifest)[0])
    assert params.subpixel == "half-max" and params.unlit_soil is False  # (on by default)
    assert params.reconcile_lasers is False  # (on by default)


@pytest.mark.parametrize("scans, code", [
    ([], "E-BATCH"),
    ([{"name": "../x", "video": "v.mp4", "calibration": "c.json"}], "E-BATCH"),
    ([{"name": "a", "video": "v.mp4"}], "E-BATCH"),
    ([{"name": "a", "video": "v.mp4", "calibration": "c.json"},
      {"name": "a", "video": "w.mp4", "calibration": "c.json"}], "E-BATCH"),
    # one folder on a case-insensitive disk
    ([{"name": "X1", "video": "v.mp4", "calibration": "c.json"},
      {"name": "x1", "video": "w.mp4", "calibration": "c.json"}], "E-BATCH"),
    ([{"name": "a", "video": "v.mp4", "calibration": "c.json",
       "parameters": {"rm": "-rf"}}], "E-BATCH"),
    # a hostile-input audit: a NUL in a name or a path was an internal error (and left an
    # empty batch folder); a string for a switch was stored as given
    ([{"name": "a\u0000b", "video": "v.mp4", "calibration": "c.json"}], "E-BATCH"),
    ([{"name": "a", "video": "v\u0000.mp4", "calibration": "c.json"}], "E-BATCH"),
    # a second audit: names Windows cannot make a folder of (a batch folder is copied between
    # machines)
    ([{"name": "CON", "video": "v.mp4", "calibration": "c.json"}], "E-BATCH"),
    ([{"name": "com1.scan", "video": "v.mp4", "calibration": "c.json"}], "E-BATCH"),
    ([{"name": "a:b", "video": "v.mp4", "calibration": "c.json"}], "E-BATCH"),
    ([{"name": "a.", "video": "v.mp4", "calibration": "c.json"}], "E-BATCH"),
    ([{"name": "a\nb", "video": "v.mp4", "calibration": "c.json"}], "E-BATCH"),
    ([{"name": "a", "video": 7, "calibration": "c.json"}], "E-BATCH"),
    ([{"name": "a", "video": "v.mp4", "calibration": "c.json",
       "parameters": {"texture": "no"}}], "E-BATCH"),
    ([{"name": "a", "video": "v.mp4", "calibration": "c.json",
       "parameters": {"grid_mm": True}}], "E-BATCH"),
    # the sub-pixel estimate is named, not switched (a switch was taken, then refused by
    # the processing parameters at run time)
    ([{"name": "a", "video": "v.mp4", "calibration": "c.json",
       "parameters": {"subpixel": True}}], "E-BATCH"),
    ([{"name": "a", "video": "v.mp4", "calibration": "c.json",
       "parameters": {"unlit_soil": "yes"}}], "E-BATCH"),
    ([{"name": "a", "video": "v.mp4", "calibration": "c.json",
       "parameters": {"reconcile_lasers": 1}}], "E-BATCH"),
])
def test_bad_manifests_are_refused(scans, code, tmp_path, capsys):
    manifest = tmp_path / "m.json"
    manifest.write_text(json.dumps({"format": "impress.batch", "version": 1, "scans": scans}))
    assert cli.main(["batch", str(manifest), "-o", str(tmp_path / "out")]) == 2
    assert f"[{code}]" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_foreign_batch_folder_is_refused(flat_scan, flat_calibration, tmp_path, capsys):
    manifest = _manifest(tmp_path, flat_scan, flat_calibration)
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "IMG_1.JPG").write_bytes(b"photo")
    assert cli.main(["batch", str(manifest), "-o", str(tmp_path / "photos")]) == 2
    assert "[E-OUTPUT-NOT-EMPTY]" in capsys.readouterr().err
    assert [p.name for p in (tmp_path / "photos").iterdir()] == ["IMG_1.JPG"]


@pytest.mark.parametrize("stop", ["SIGINT", "SIGTERM"])
def test_ctrl_c_stops_the_batch_and_keeps_what_is_done(flat_scan, flat_calibration, tmp_path,
                                                       stop):
    # a hostile-input audit: Ctrl-C at 4 s let a 10-scan batch run on through 8 more scans
    # and end without a summary; a second audit: SIGTERM (to the command alone, as a service
    # manager or `kill` sends it) ended it at once with no summary, and its workers ran on
    import os
    import signal
    import subprocess
    import sys
    import time

    n, jobs = 10, 2
    doc = {"format": "impress.batch", "version": 1, "scans": [
        {"name": f"s{k}", "video": str(flat_scan / "scan.mp4"),
         "calibration": str(flat_calibration),
         "parameters": {"frame_start": 40, "frame_stop": 70, "texture": False}}
        for k in range(n)]}
    manifest = tmp_path / "manifest.json"
    manifest.write_text(json.dumps(doc))
    out = tmp_path / "batch"

    def finished() -> set[str]:
        return {f"s{k}" for k in range(n) if (out / f"s{k}" / "metadata.json").exists()}

    # SIGINT as a terminal's: a suite started in the background (nohup, &) passes it on
    # ignored, and Python then leaves it ignored in the child. In a process group of its own
    # (with its workers), so that the test can hold the whole batch still while it looks.
    proc = subprocess.Popen([sys.executable, "-m", "impress_gui", "batch", str(manifest), "-o",
                             str(out), "--jobs", str(jobs)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        # the batch is stopped (SIGSTOP) while the finished scans are counted and the Ctrl-C
        # is sent: what was done when it was interrupted is known exactly, however late a
        # busy machine lets the test look
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and proc.poll() is None:
            os.killpg(proc.pid, signal.SIGSTOP)
            done = finished()
            if done:
                break
            os.killpg(proc.pid, signal.SIGCONT)
            time.sleep(0.05)
        assert proc.poll() is None, proc.communicate()
        assert done and len(done) + jobs < n, done  # scans were left to start
        os.kill(proc.pid, getattr(signal, stop))
        os.killpg(proc.pid, signal.SIGCONT)
        _, err = proc.communicate(timeout=120)
        # the workers are gone with the command (stopped, not left running on their own):
        # the process group empties within seconds
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            try:
                os.killpg(proc.pid, 0)
            except ProcessLookupError:
                break
            time.sleep(0.1)
        else:
            raise AssertionError("the batch's workers outlived it")
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        if proc.poll() is None:
            proc.communicate()
    assert "Traceback" not in err
    if stop == "SIGINT":
        assert proc.returncode == 130 and "interrupted" in err, err
    else:
        assert proc.returncode == 128 + signal.SIGTERM and "stopped by SIGTERM" in err, err
    with open(out / "summary.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["name"] for r in rows] == [f"s{k}" for k in range(n)]
    processed = {r["name"] for r in rows if r["status"] == "processed"}
    # what was done is kept; beyond it, at most the scans in progress at the Ctrl-C may have
    # finished; no other scan was started, and every one not done is marked
    assert done <= processed and len(processed) <= len(done) + jobs, (done, processed)
    assert all(r["status"] == "not run (interrupted)" for r in rows if r["name"] not in processed)
    for r in rows:
        if r["status"] == "processed":
            assert (out / r["name"] / "heightmap.tif").is_file()
        else:
            assert not (out / r["name"]).exists()
