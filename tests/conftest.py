import os

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
# the examiner's signing key of every test is made in a temporary folder, never in the home
import tempfile  # noqa: E402

if "IMPRESS_KEY_DIR" not in os.environ:  # made here (a worker inherits it): removed at exit
    import atexit  # noqa: E402
    import shutil  # noqa: E402

    os.environ["IMPRESS_KEY_DIR"] = _keys = tempfile.mkdtemp(prefix="impress-test-keys-")
    atexit.register(shutil.rmtree, _keys, ignore_errors=True)

import json  # noqa: E402
from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def load_benchmark(name: str):
    """The module of ``benchmarks/<name>.py`` (not a package: loaded from its file, with the
    folder on the path while it imports its neighbour ``common``)."""
    import importlib.util
    import sys

    sys.path.insert(0, str(BENCHMARKS))
    try:
        spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(BENCHMARKS))
    return mod


@pytest.hookimpl(trylast=True)  # after the tmp_path and xdist plugins' own configuration
def pytest_configure(config):
    # PySide6 6.12.0 loses a reference to True on every emit (the pinned 6.11.3 does not);
    # the guard only acts when that bug is present
    from impress_gui.ui.pyside_fix import guard

    guard()
    # the flat scan most files share, rendered while the kernels below compile (on a clean
    # clone that takes the controller half a minute on one core, the workers not yet started)
    _prerender_flat_scan(config)
    # numba's cache of the compiled kernels, filled once before any test (a window starts the
    # same compilation in a child process; a test would otherwise wait for it): by the run's
    # first process (pytest-xdist's controller configures itself before it starts a worker)
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        _compile_kernels()


def _compile_kernels() -> None:
    """Fill numba's cache: ``kernels`` imported in a child process, and the grid's kernels in a
    second one meanwhile (``kernels`` imports them after its own - on a clean clone 9 of its
    35 s - and then finds them in the cache)."""
    import subprocess
    import sys

    grid = subprocess.Popen([sys.executable, "-c",
                             "import impress_gui.core.reconstruction.grid_kernels"])
    try:
        subprocess.run([sys.executable, "-c", "import impress_gui.core.reconstruction.kernels"],
                       check=True)
    finally:
        grid.wait()


def pytest_unconfigure(config):
    proc = _PRERENDER.pop("proc", None)
    if proc is not None and proc.poll() is None:  # the run ended before the scan was needed
        proc.terminate()
        proc.wait(timeout=60)


#: the test files that take longest on a clean clone (they render and reconstruct scans),
#: longest first. ``./test.sh`` hands whole files to its two workers in collection order
#: (``--dist loadfile --no-loadscope-reorder``): these start first, each on its own worker,
#: and the short files fill in at the end, so that neither worker is left with a long file
#: while the other is idle. The files sharing a session scan (``flat_scan``, ``letter_scan``)
#: come after the independent ones, so that the scan is ready when the second worker needs it;
#: of the four measuring the blocks scan (measure_scans.py) test_gui_viewer comes first, and
#: test_measure well after it (a worker that needs the scan while the other renders it waits).
#: Single-file times in the two-worker suite on the 2-core machine (3 December 2026, after the
#: calibration's Monte Carlo became 2-2.5x faster and validate's run uses 20 trials): compare
#: 187 s, tilt_refinement 127, uncertainty 118, bright_ground 79 (now ~45: its ordinary ground
#: is the shared flat reconstruction), gui_check 72, hostile_inputs 64, gui_viewer 60,
#: validate 59, simulator 58, cast 52, random_rig 44, cross_level 38, sim_outputs_safety 37.
#: On 6 December 2026 (the suite 11:52 on this machine): uncertainty 139, tilt_refinement 123,
#: compare 115, validate 86 (the others under 51 s); the calibration's Monte Carlo then became
#: about a fifth faster and test_uncertainty's ensembles went from 10 trials to 6, and
#: test_validate moved ahead of it. Later that day (the simulator's scenes built two to three
#: times faster, the same bytes): tilt_refinement 118, compare 114, uncertainty 82, simulator
#: 52, gui_viewer 51 s (validate 39 s with its renders cached locally, about 80 s on a clean
#: clone); the clean-clone suite 9:54-10:01. On 7 December 2026 (the suite 12:15-12:40 on a
#: clean clone) the flat scan came to be rendered while the kernels compile (conftest's
#: ``pytest_configure``), test_low_fill to read the blocks scan and test_sim_outputs_safety
#: to render a coarse scene (both seconds now), compare's scans at twice the speed, validate's
#: run with 10 trials; CPU seconds of single files then (their shared scans left out): tilt
#: 113, compare 90, ramp_motion 63, validate 62, gui_viewer 61 (rendering the blocks), batch
#: 61, cast 60 (rendering the letter), gui_check 50, simulator 45, random_rig 43, uncertainty
#: 41, gui_calibration 39, hostile_inputs 35, demo 34 (test_architecture's mypy ~30 s on a
#: clean clone, among the short files). The clean-clone suite then 10:09 on a quiet machine
#: (46 s before the first test; the two workers' last tests ended 5 s apart).
LONG_FILES = (
    "test_compare.py",
    "test_tilt_refinement.py",
    "test_validate.py",
    "test_ramp_motion.py",
    "test_gui_viewer.py",
    "test_cast.py",
    "test_batch.py",
    "test_uncertainty.py",
    "test_gui_check.py",
    "test_simulator.py",
    "test_random_rig.py",
    "test_hostile_inputs.py",
    "test_gui_calibration.py",
    "test_demo.py",
    "test_bright_ground.py",
    "test_cross_level.py",
    "test_calibration_blooming.py",
    "test_calibrate_camera.py",
    "test_cast_acceptance.py",
    "test_video.py",
    "test_gui_compare.py",
    "test_export_frame.py",
    "test_calibration.py",
    "test_reconstruct.py",
    "test_measure.py",
)


def pytest_collection_modifyitems(config, items):
    if os.environ.get("PYTEST_XDIST_WORKER"):
        rank = {name: i for i, name in enumerate(LONG_FILES)}
        items.sort(key=lambda item: rank.get(item.path.name, len(rank)))  # stable: files whole


_FILE_SECONDS: dict[str, float] = {}


def pytest_runtest_logreport(report):
    """Seconds spent in each test file (setup, call and teardown, module fixtures included)."""
    path = report.nodeid.split("::")[0]
    _FILE_SECONDS[path] = _FILE_SECONDS.get(path, 0.0) + report.duration


def pytest_terminal_summary(terminalreporter, config):
    if config.getoption("durations", None) is None or not _FILE_SECONDS:
        return
    terminalreporter.write_sep("=", "slowest files (all phases)")
    for path, s in sorted(_FILE_SECONDS.items(), key=lambda kv: -kv[1])[:25]:
        terminalreporter.write_line(f"{s:8.1f}s  {path}")


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


def shared_folder(tmp_path_factory, name: str, build) -> Path:
    """A folder made once per test run by ``build(folder)`` and shared by every module and
    every pytest-xdist worker of the run: the first to need it builds it (under a file lock),
    the others wait for it and reuse it. Not kept between runs (each run makes it afresh)."""
    import fcntl

    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # the run's folder, above each worker's own
    root = root / "shared"
    root.mkdir(exist_ok=True)
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        return _build_once(root, name, build)


def _build_once(root: Path, name: str, build) -> Path:
    """``root / name`` built by ``build`` unless it is complete (the caller holds its lock)."""
    import shutil

    final, done = root / name, root / f"{name}.complete"
    if not done.exists():
        shutil.rmtree(final, ignore_errors=True)
        build(final)
        done.write_text("ok\n")
    return final


#: the scan of the ``flat_scan`` fixture
FLAT_SCAN = dict(preset="flat", length_mm=100.0, width=640, height=360)
_PRERENDER: dict = {}


def _render_flat_scan(out: Path) -> Path:
    return simulate_scan(out, **FLAT_SCAN)


def _prerender_flat_scan(config) -> None:
    """In the controller of a whole-suite run on pytest-xdist workers: render ``flat_scan``
    into the run's shared folder in a child process, which holds the folder's lock (taken here,
    before any worker starts) until the scan is complete; a worker asking for it waits there,
    or builds it itself should the child have failed (its output: ``flat-scan.prerender.log``).
    The render needs no compiled kernel: it runs beside their compilation."""
    import fcntl
    import subprocess
    import sys

    if (os.environ.get("PYTEST_XDIST_WORKER") or not config.pluginmanager.has_plugin("dsession")
            or config.args_source is not pytest.Config.ArgsSource.TESTPATHS):
        return
    root = config._tmp_path_factory.getbasetemp() / "shared"
    root.mkdir(exist_ok=True)
    code = ("import sys; from pathlib import Path; sys.path.insert(0, sys.argv[1]); "
            "import conftest; conftest._build_once(Path(sys.argv[2]), 'flat-scan', "
            "conftest._render_flat_scan)")
    with open(root / "flat-scan.lock", "w") as lock, \
            open(root / "flat-scan.prerender.log", "w") as log:
        fcntl.flock(lock, fcntl.LOCK_EX)  # the child's copy keeps it until the child ends
        _PRERENDER["proc"] = subprocess.Popen(
            [sys.executable, "-c", code, str(Path(__file__).parent), str(root)],
            pass_fds=(lock.fileno(),), stdin=subprocess.DEVNULL, stdout=log,
            stderr=subprocess.STDOUT)


def simulate_scan(out: Path, **kw) -> Path:
    """Render ``SimConfig(**kw)`` into ``out`` (one worker process)."""
    from impress_gui.sim.simulate import SimConfig, simulate

    simulate(SimConfig(**kw), out, workers=1)
    return out


def calibrate_scan(scan: Path, out: Path, video: Path | None = None) -> Path:
    """The scene calibration of a simulated ``scan`` (of ``video``: by default the scan's own)
    from its exact picks, saved as ``out``."""
    from impress_gui.core.calibration.geometry import Intrinsics
    from impress_gui.core.calibration.picks import Picks
    from impress_gui.core.calibration.scene import calibrate_scene
    from impress_gui.core.calibration.target import TargetModel
    from impress_gui.core.formats.video import open_video

    truth = json.loads((scan / "truth.json").read_text())
    with open_video(video or scan / truth["video"]) as v:
        cal = calibrate_scene(v, Intrinsics.load(scan / "intrinsics.json"),
                              TargetModel.load(scan / "target.json"),
                              Picks.load(scan / "picks.json"), truth["speed_mm_s"])
    out.parent.mkdir(parents=True, exist_ok=True)
    cal.save(out)
    return out


@pytest.fixture(scope="session")
def flat_scan(tmp_path_factory) -> Path:
    """A short simulated scan of the flat preset at 640x360 (H.264), with its ground truth
    (rendered once per run, shared by the workers)."""
    return shared_folder(tmp_path_factory, "flat-scan", _render_flat_scan)


@pytest.fixture(scope="session")
def flat_calibration(flat_scan, tmp_path_factory) -> Path:
    """The scene calibration of ``flat_scan`` from its exact picks."""
    folder = shared_folder(tmp_path_factory, "flat-cal",
                           lambda out: calibrate_scan(flat_scan, out / "calibration.json"))
    return folder / "calibration.json"


@pytest.fixture(scope="session")
def flat_recon(flat_scan, flat_calibration, tmp_path_factory) -> Path:
    """``flat_scan`` reconstructed with the default parameters (a folder, as ``impress
    process`` writes it)."""
    def build(out: Path) -> None:
        from impress_gui.core.reconstruction.pipeline import process_files
        from impress_gui.core.reconstruction.reconstruct import ProcessParams

        process_files(flat_scan / "scan.mp4", flat_calibration, out, ProcessParams())

    return shared_folder(tmp_path_factory, "flat-recon", build)


@pytest.fixture(scope="session")
def board_views(tmp_path_factory) -> Path:
    """20 views of a 9x6 board with 25 mm squares through the simulator's 640x360 camera
    (seed 7), as ``sim.checkerboard.write_views`` writes them: the folder of the views (PNG
    frames; ``board_truth.json`` beside it). Made once per run for test_calibrate_camera and
    the calibration tab's checkerboard dialog (test_gui_calibration); they only read it."""
    def build(out: Path) -> None:
        from impress_gui.sim.checkerboard import Board, write_views
        from impress_gui.sim.rig import default_intrinsics

        write_views(out, default_intrinsics(640, 360), Board(9, 6, 25.0), n_views=20, seed=7)

    return shared_folder(tmp_path_factory, "board-views", build) / "frames"


@pytest.fixture(scope="session")
def cast_recon(tmp_path_factory) -> Path:
    """A reconstruction folder (heightmap and metadata) of test_cast's synthetic letter F on a
    wavy ground, for the digital cast's tests; they only read it."""
    from test_cast import synthetic_height, write_recon

    return write_recon(tmp_path_factory.mktemp("cast") / "recon", synthetic_height())


@pytest.fixture(scope="session")
def letter_scan(tmp_path_factory) -> tuple[Path, Path]:
    """(scan folder, reconstruction folder) of the simulator's raised letter F, small and
    quick (640x360 at 10 frames/s; the reconstruction on a 0.5 mm grid)."""
    def build(base: Path) -> None:
        from impress_gui.core.reconstruction.pipeline import process_files
        from impress_gui.core.reconstruction.reconstruct import ProcessParams

        scan = simulate_scan(base / "scan", preset="letter", length_mm=190.0, width=640,
                             height=360, fps=10.0, grid_mm=0.2)
        calibrate_scan(scan, base / "calibration.json")
        process_files(scan / "scan.mp4", base / "calibration.json", base / "recon",
                      ProcessParams(grid_mm=0.5))

    base = shared_folder(tmp_path_factory, "letter", build)
    return base / "scan", base / "recon"

XVFB_SCREEN = (1280, 800)


@pytest.fixture
def x_display(tmp_path):
    """A fresh virtual X server (Xvfb, a 1280x800 screen) on a display number it picks itself
    (``-displayfd``): ``":N"``. Skipped where Xvfb is not installed."""
    import select
    import shutil
    import subprocess
    import time

    xvfb = shutil.which("Xvfb")
    if xvfb is None:
        pytest.skip("Xvfb is not installed (scripts/bootstrap.sh installs it: apt-get install xvfb)")
    log = tmp_path / "xvfb.log"
    r, w = os.pipe()
    with log.open("wb") as log_file:
        proc = subprocess.Popen(
            [xvfb, "-displayfd", str(w), "-screen", "0", f"{XVFB_SCREEN[0]}x{XVFB_SCREEN[1]}x24",
             "-nolisten", "tcp", "-noreset"],
            pass_fds=(w,),
            stdout=subprocess.DEVNULL,
            stderr=log_file,
        )
    os.close(w)
    try:
        text = b""
        deadline = time.monotonic() + 30
        while not text.endswith(b"\n") and time.monotonic() < deadline:
            ready, _, _ = select.select([r], [], [], deadline - time.monotonic())
            if not ready:
                break
            chunk = os.read(r, 64)
            if not chunk:  # Xvfb closed the pipe: it did not start
                break
            text += chunk
        if not text.strip().isdigit():
            proc.kill()
            proc.wait(timeout=10)
            pytest.fail(f"Xvfb did not start: {log.read_text(errors='replace')[-2000:]}")
        yield f":{int(text)}"
    finally:
        os.close(r)
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)


from impress_gui.sim.truth import truth_on_grid  # noqa: E402,F401  (used by test modules)
