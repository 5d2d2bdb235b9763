"""The simulated `blocks` scan shared by the measuring tests (core, processing tab, viewer).

640x360, 200 mm of travel at three times the "fast" rail speed (the slotted block A lies at
world y 168..212 mm and is swept by the green laser near the end of the scan). Rendering takes
tens of seconds, so the scan and its calibration are made once per session and kept in
pytest's cache folder between runs, under a key made from the simulator's source (a changed
simulator renders again). Reconstructions are always made afresh, once per session.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SPEED_MM_S = 39.414
ARGS = [
    "--preset",
    "blocks",
    "--length-mm",
    "200",
    "--speed",
    str(SPEED_MM_S),
    "--resolution",
    "640x360",
]
_SESSION: dict[str, Path] = {}


def _source_key() -> str:
    h = hashlib.sha256(" ".join(ARGS).encode())
    files = sorted((ROOT / "impress_gui" / "sim").glob("*.py"))
    files += [
        ROOT / "impress_gui" / "core" / "calibration" / n
        for n in ("target.py", "geometry.py", "scene.py", "solve.py", "planes.py", "picks.py")
    ]
    # the calibration finds the stripe with the reconstruction's detector
    files += [ROOT / "impress_gui" / "core" / "reconstruction" / n
              for n in ("stripes.py", "kernels.py")]
    for f in files:
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def _run(*args: str) -> None:
    subprocess.run(
        [sys.executable, "-m", "impress_gui", *args],
        check=True,
        capture_output=True,
        timeout=240,
        cwd=ROOT,
    )


def blocks_scan(config, factory) -> Path:
    """Folder with scan.mp4, truth.json, intrinsics.json, picks.json and cal.json."""
    if "scan" in _SESSION:
        return _SESSION["scan"]
    import fcntl

    cache = Path(config.cache.mkdir("impress-blocks-scan"))
    final = cache / _source_key()
    # one render for the run: the test suite's other worker (another file of the four that
    # measure this scan) waits for it here instead of rendering it too
    with open(cache.parent / "impress-blocks-scan.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (final / "complete").exists():
            _render_blocks(factory, cache, final)
    _SESSION["scan"] = final
    return final


def _render_blocks(factory, cache: Path, final: Path) -> None:
    """Render and calibrate the scan into ``final`` (under ``cache``)."""
    work = factory.mktemp("blocks-render") / "scan"
    # one process: with more, each worker builds the scene again, and the test suite's
    # other worker already has the second core (the frames are the same)
    _run("simulate", str(work), *ARGS, "--workers", "1")
    _run(
        "calibrate",
        str(work / "scan.mp4"),
        "--intrinsics",
        str(work / "intrinsics.json"),
        "--picks",
        str(work / "picks.json"),
        "--speed",
        str(SPEED_MM_S),
        "-o",
        str(work / "cal.json"),
    )
    (work / "complete").write_text("ok\n")
    for old in cache.iterdir():
        shutil.rmtree(old, ignore_errors=True)
    tmp = cache / f".{final.name}.{os.getpid()}"
    shutil.copytree(work, tmp)
    try:
        tmp.rename(final)
    except OSError:  # another session got there first
        shutil.rmtree(tmp, ignore_errors=True)


def truth(scan: Path) -> dict:
    return json.loads((scan / "truth.json").read_text())


def block_a_frames(scan: Path) -> tuple[int, int]:
    """Frames in which the green stripe sweeps the slotted block A (travel >= 128 mm)."""
    t = truth(scan)
    travel = t["travel_mm"]
    start = next(k for k, s in enumerate(travel) if s >= 128.0)
    return start, len(travel)


def rail_y(scan: Path, world_y_mm: float) -> float:
    """The reconstruction's y of a truth (world) y: the rail frame starts at frame t1."""
    t = truth(scan)
    return world_y_mm - t["travel_mm"][t["calibration_frames"]["t1"]]


def blocks_recon(config, factory) -> Path:
    """Block A reconstructed from the scan (core pipeline), once per run: shared by the
    test suite's workers (conftest.shared_folder), as test_measure and test_gui_viewer may
    run on different ones."""
    if "recon" in _SESSION:
        return _SESSION["recon"]
    from conftest import shared_folder

    from impress_gui.core.reconstruction.pipeline import process_files
    from impress_gui.core.reconstruction.reconstruct import ProcessParams

    scan = blocks_scan(config, factory)
    start, stop = block_a_frames(scan)

    def build(base: Path) -> None:
        base.mkdir(parents=True)
        process_files(scan / "scan.mp4", scan / "cal.json", base / "recon",
                      ProcessParams(frame_start=start, frame_stop=stop))

    out = shared_folder(factory, f"blocks-recon-{scan.name}", build) / "recon"
    _SESSION["recon"] = out
    return out


def guard_pyside_none() -> bool:
    """PySide6 6.12 on CPython 3.11 takes one reference away from ``None`` at every call of a
    method returning void (``widget.update()``, ``QTest.qWait``, ``processEvents``...), as it
    does from ``True`` at every ``emit`` (see ``impress_gui.ui.pyside_fix``): a session of a
    few thousand calls aborts with "Fatal Python error: none_dealloc". Same workaround: when
    the loss is detected, give ``None`` a reference count no session can use up."""
    import ctypes

    from PySide6.QtCore import QObject

    if sys.version_info >= (3, 12) or sys.implementation.name != "cpython":
        return False
    probe = QObject()
    before = sys.getrefcount(None)
    for _ in range(8):
        probe.setObjectName("probe")
    if before - sys.getrefcount(None) >= 8:
        ctypes.c_ssize_t.from_address(id(None)).value += 1 << 40
        return True
    return False
