"""A read-only output folder (issue 21 item 5): ``simulate``, ``calibrate``,
``calibrate-camera`` and ``process`` refuse it with a coded error (E-WRITE) on one line, no
traceback, before any work (``process`` used to fail after the whole reconstruction). The
folder is read-only as a user without root sees it: the test may run as root (who may write
anywhere), so the check's ``os.access`` is told the folder is not writable; the work
functions fail the test if they are reached."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from impress_gui.cli import main

READ_ONLY: list[Path] = []


@pytest.fixture
def read_only(tmp_path, monkeypatch):
    """A folder that ``os.access`` says cannot be written (as for a user on a read-only
    folder; more can be added to ``READ_ONLY``), with the work functions of the four
    commands made to fail if reached."""
    ro = tmp_path / "ro"
    ro.mkdir()
    READ_ONLY[:] = [ro.resolve()]
    real_access = os.access

    def access(path, mode, *a, **kw):
        if mode & os.W_OK and Path(path).resolve() in READ_ONLY:
            return False
        return real_access(path, mode, *a, **kw)

    monkeypatch.setattr(os, "access", access)

    def started(*_a, **_kw):
        raise AssertionError("the work started before the output was checked")

    import impress_gui.core.calibration.intrinsics as intrinsics
    import impress_gui.core.calibration.scene as scene
    import impress_gui.core.reconstruction.pipeline as pipeline
    import impress_gui.sim.simulate as sim

    monkeypatch.setattr(sim, "_simulate_into", started)
    monkeypatch.setattr(scene, "calibrate_scene", started)
    monkeypatch.setattr(intrinsics, "run_camera_calibration", started)
    monkeypatch.setattr(pipeline, "reconstruct", started)
    return ro


def _refused(capsys, argv: list[str]) -> str:
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "[E-WRITE]" in err and "Traceback" not in err, err
    return err


def test_every_command_refuses_a_read_only_output_before_working(read_only, capsys,
                                                                   flat_scan,
                                                                   flat_calibration):
    ro = read_only
    err = _refused(capsys, ["simulate", ro / "scan", "--preset", "flat", "--resolution",
                            "320x180", "--length-mm", "100"])
    assert str(ro) in err
    _refused(capsys, ["calibrate", flat_scan / "scan.mp4", "--intrinsics",
                      flat_scan / "intrinsics.json", "--picks", flat_scan / "picks.json",
                      "--speed", "fast", "-o", ro / "calibration.json"])
    _refused(capsys, ["calibrate-camera", flat_scan / "scan.mp4", "--board", "9x6",
                      "--square-mm", "25", "-o", ro / "intrinsics.json"])
    _refused(capsys, ["process", flat_scan / "scan.mp4", "--calibration", flat_calibration,
                      "-o", ro / "recon"])
    assert list(ro.iterdir()) == []  # nothing written


def test_a_writable_folder_passes_the_same_check(read_only, capsys, flat_scan, tmp_path):
    """The check itself is not what refuses: the same command into a writable folder gets
    past it (and reaches the work, which the fixture stops; the command line reports that as an
    internal error)."""
    code = main([str(a) for a in ["calibrate", flat_scan / "scan.mp4", "--intrinsics",
                                  flat_scan / "intrinsics.json", "--picks",
                                  flat_scan / "picks.json", "--speed", "fast", "-o",
                                  tmp_path / "calibration.json"]])
    err = capsys.readouterr().err
    # the command line reports the stopped work as an internal error (never a traceback)
    assert code == 3 and "[E-INTERNAL]" in err and "[E-WRITE]" not in err, err


@pytest.mark.qt_log_ignore("propagateSizeHints")
def test_the_window_says_the_case_folder_is_read_only(qtbot, read_only, request,
                                                      tmp_path_factory, tmp_path):
    """The processing tab's Run on a case whose folder cannot be written: the window's
    message is the coded write error (it said "internal error ... [E-INTERNAL]"), and no
    reconstruction starts."""
    from gui_helpers import FakeDialogs
    from measure_scans import block_a_frames, blocks_scan
    from PySide6.QtCore import Qt
    from PySide6.QtTest import QTest

    from impress_gui.core.calibration.scene import SceneCalibration
    from impress_gui.core.project.project import Project
    from impress_gui.ui.messages import Messenger
    from impress_gui.ui.processing.tab import ProcessingTab

    scan = blocks_scan(request.config, tmp_path_factory)
    project = Project(case_id="T-21")
    project.set_video(scan / "scan.mp4")
    project.set_calibration(SceneCalibration.load(scan / "cal.json"))
    project.save(tmp_path / "case")
    READ_ONLY.extend([project.root.resolve(), (project.root / "reconstructions").resolve()])
    messenger = Messenger(None)
    tab = ProcessingTab(messenger, FakeDialogs())
    qtbot.addWidget(tab)
    tab.resize(1500, 950)
    tab.show()
    qtbot.waitExposed(tab)
    try:
        with qtbot.waitSignal(tab.preview_ready, timeout=20000):
            tab.set_project(project)
        start, _stop = block_a_frames(scan)
        tab.params.frame_start.setValue(start)
        tab.params.frame_stop.setValue(start + 10)
        QTest.mouseClick(tab.run_panel.run_button, Qt.MouseButton.LeftButton)
        qtbot.waitUntil(lambda: "[E-" in (messenger.last_text or ""), timeout=30000)
        qtbot.waitUntil(lambda: not tab.is_running(), timeout=30000)
        text = messenger.last_text
        assert "[E-WRITE]" in text and "[E-INTERNAL]" not in text, text
        assert tab.last_output is None
        folder = project.root / "reconstructions"
        assert not folder.exists() or list(folder.iterdir()) == []
    finally:
        tab.shutdown()
        messenger.close_all()
