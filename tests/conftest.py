import os

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
# the examiner's signing key of every test is made in a temporary folder, never in the home
import tempfile  # noqa: E402

os.environ.setdefault("IMPRESS_KEY_DIR", tempfile.mkdtemp(prefix="impress-test-keys-"))

import json  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402


def pytest_configure(config):
    # PySide6 6.12.0 loses a reference to True on every emit (the pinned 6.11.3 does not);
    # the guard only acts when that bug is present
    from impress_gui.ui.pyside_fix import guard

    guard()
    # numba's cache of the compiled kernels, filled once before any test (a window starts the
    # same compilation in a child process; a test would otherwise wait for it)
    import subprocess
    import sys

    subprocess.run([sys.executable, "-c", "import impress_gui.core.reconstruction.kernels"], check=True)


def _new_threads(before: set, ignore_dummy: bool) -> set:
    import threading

    left = set(threading.enumerate()) - before
    return {t for t in left if not (ignore_dummy and isinstance(t, threading._DummyThread))}


@pytest.fixture
def no_stray_threads():
    """The test leaves no thread running (modules opt in through ``pytestmark``)."""
    import threading

    before = set(threading.enumerate())
    yield
    assert _new_threads(before, ignore_dummy=False) == set()


@pytest.fixture
def no_stray_python_threads():
    """As :func:`no_stray_threads`, not counting the ``_DummyThread`` entries Python registers
    for a QThread that runs Python code (e.g. the reconstruction's decoder) and never
    unregisters: those are not threads; the workers' own state is checked by the tests."""
    import threading

    before = set(threading.enumerate())
    yield
    assert _new_threads(before, ignore_dummy=True) == set()


def _simulate(out: Path, **kw) -> Path:
    from impress_gui.sim.simulate import SimConfig, simulate

    simulate(SimConfig(**kw), out, workers=1)
    return out


@pytest.fixture(scope="session")
def flat_scan(tmp_path_factory) -> Path:
    """A short simulated scan of the flat preset at 640x360 (H.264), with its ground truth."""
    return _simulate(tmp_path_factory.mktemp("flat") / "scan", preset="flat", length_mm=100.0,
                     width=640, height=360)


@pytest.fixture(scope="session")
def flat_calibration(flat_scan, tmp_path_factory) -> Path:
    """The scene calibration of ``flat_scan`` from its exact picks."""
    from impress_gui.core.calibration.geometry import Intrinsics
    from impress_gui.core.calibration.picks import Picks
    from impress_gui.core.calibration.scene import calibrate_scene
    from impress_gui.core.calibration.target import TargetModel
    from impress_gui.core.formats.video import open_video

    truth = json.loads((flat_scan / "truth.json").read_text())
    with open_video(flat_scan / "scan.mp4") as v:
        cal = calibrate_scene(v, Intrinsics.load(flat_scan / "intrinsics.json"),
                              TargetModel.load(flat_scan / "target.json"),
                              Picks.load(flat_scan / "picks.json"), truth["speed_mm_s"])
    path = tmp_path_factory.mktemp("cal") / "calibration.json"
    cal.save(path)
    return path


from impress_gui.sim.truth import truth_on_grid  # noqa: E402,F401  (used by test modules)
