"""An output that cannot be written is refused before any work, also where os.access says
yes: for root (CI, some lab PCs) os.access grants everything, and it knows nothing of pseudo
or read-only file systems. Found in issue 21's audit: `impress calibrate ... -o
/proc/x/cal.json` ran the whole calibration (23 s) before failing."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from impress_gui.core.base.errors import ImpressError
from impress_gui.core.base.outdir import check_output_dir, check_output_file

pytestmark = pytest.mark.skipif(not Path("/proc/self").is_dir(), reason="needs Linux /proc")


def test_a_folder_os_access_allows_but_cannot_hold_a_file_is_refused(monkeypatch):
    monkeypatch.setattr(os, "access", lambda *a, **k: True)  # as for root
    for check in (lambda p: check_output_dir(p, "reconstruction"), check_output_file):
        with pytest.raises(ImpressError) as err:
            check("/proc/impress-write-check/out")
        assert err.value.code == "E-WRITE" and "/proc" in str(err.value)


def test_the_check_leaves_nothing_behind(tmp_path):
    check_output_dir(tmp_path / "new" / "out", "reconstruction")
    assert list(tmp_path.iterdir()) == []  # no probe left, nothing created


def test_a_command_refuses_before_its_work(flat_scan):
    """The speed given is wrong on purpose: had the calibration run, it would have stopped
    with E-TARGET-MISMATCH; the refusal to write comes first."""
    res = subprocess.run(
        [sys.executable, "-m", "impress_gui", "calibrate", str(flat_scan / "scan.mp4"),
         "--intrinsics", str(flat_scan / "intrinsics.json"), "--picks",
         str(flat_scan / "picks.json"), "--target", str(flat_scan / "target.json"),
         "--speed", "20", "-o", "/proc/impress-write-check/cal.json"],
        capture_output=True, text=True, timeout=120)
    assert res.returncode != 0 and "[E-WRITE]" in res.stderr, res.stderr
    assert "Traceback" not in res.stderr and "E-TARGET-MISMATCH" not in res.stderr
