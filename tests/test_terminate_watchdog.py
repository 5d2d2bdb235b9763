"""A terminate signal always ends the command, and leaves nothing half-written, even when the
clean-up it starts cannot finish (a lock left held by the signal's exception, a worker that
never returns): the watchdog of :func:`impress_gui.cli._on_terminate`."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from impress_gui.core.base import workfiles
from impress_gui.core.base.fileio import atomic_output
from impress_gui.core.base.outdir import OutputFolder

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")

# a command whose clean-up hangs: the main thread, interrupted, joins a worker that never ends
STUCK = textwrap.dedent("""
    import sys, threading, time
    from impress_gui import cli
    from impress_gui.core.base.fileio import atomic_output
    from impress_gui.core.base.outdir import OutputFolder

    cli.TERMINATE_GRACE_S = float(sys.argv[2])
    cli._watch_interrupts()
    folder = OutputFolder(sys.argv[1] + "/out", "reconstruction")
    folder.path("heightmap.tif").write_bytes(b"half")
    forever = threading.Event()
    worker = threading.Thread(target=forever.wait)
    worker.start()
    try:  # as the command's main() does: an interruption prints no traceback
        with atomic_output(sys.argv[1] + "/calibration.json") as fh:
            fh.write(b"half")
            try:  # the signal may come as soon as "ready" is out
                print("ready", flush=True)
                time.sleep(120)
            finally:
                worker.join()  # the stuck clean-up
    except KeyboardInterrupt:
        pass
""")


def _run_stuck(tmp_path, grace: float):
    work = tmp_path / "work"
    work.mkdir()
    proc = subprocess.Popen([sys.executable, "-c", STUCK, str(work), str(grace)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        assert proc.stdout.readline().strip() == "ready", proc.communicate()
        # both half-written things exist while the command runs
        names = sorted(p.name for p in work.iterdir())
        assert any(n.startswith(".out.partial-") for n in names), names
        assert any(n.startswith(".calibration.json.") for n in names), names
        t0 = time.monotonic()
        os.kill(proc.pid, signal.SIGTERM)
        _, err = proc.communicate(timeout=grace + 60)
        waited = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return proc.returncode, err, work, waited


def test_a_stuck_clean_up_is_forced_after_the_grace(tmp_path):
    status, err, work, waited = _run_stuck(tmp_path, grace=1.0)
    assert status == 128 + signal.SIGTERM, err
    assert "stopped by SIGTERM" in err and "did not finish within 1 s" in err
    assert "Traceback" not in err
    assert list(work.iterdir()) == []  # neither the work folder nor the temporary file
    assert waited >= 1.0  # not before the grace: the normal clean-up gets its chance


def test_the_registry_follows_what_exists(tmp_path):
    before = set(workfiles.open_paths())
    folder = OutputFolder(tmp_path / "out", "reconstruction")
    assert set(workfiles.open_paths()) == before  # the writability probe is gone again
    folder.path("a.txt").write_text("x")
    assert folder.tmp in workfiles.open_paths()
    folder.commit()
    assert set(workfiles.open_paths()) == before and (tmp_path / "out" / "a.txt").exists()

    with atomic_output(tmp_path / "f.json") as fh:
        fh.write(b"{}")
        [tmp] = set(workfiles.open_paths()) - before
        assert tmp.parent == tmp_path and tmp.exists()
    assert set(workfiles.open_paths()) == before and not tmp.exists()

    with pytest.raises(RuntimeError), atomic_output(tmp_path / "g.json") as fh:
        raise RuntimeError("boom")
    assert set(workfiles.open_paths()) == before

    other = OutputFolder(tmp_path / "other", "reconstruction")
    other.path("b.txt").write_text("y")
    other.abort()
    assert set(workfiles.open_paths()) == before and not other.tmp.exists()


def test_remove_all_removes_folders_and_files(tmp_path):
    folder = OutputFolder(tmp_path / "out", "reconstruction")
    folder.path("a.txt").write_text("x")
    stray = tmp_path / ".x.partial"
    stray.write_bytes(b"1")
    workfiles.note(stray)
    workfiles.remove_all()
    assert not folder.tmp.exists() and not stray.exists()
    assert folder.tmp not in workfiles.open_paths() and stray not in workfiles.open_paths()
    assert not (tmp_path / "out").exists()  # the final output was never made
