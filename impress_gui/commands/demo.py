"""``impress demo``: make (or reuse) the cached sample case and open the workstation on it."""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cache", type=Path, default=Path(os.environ.get("IMPRESS_CACHE", "cache")),
                   help="cache folder for the sample (default ./cache or $IMPRESS_CACHE)")
    p.add_argument("--no-gui", action="store_true",
                   help="only build the sample and report what was written")


def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
                or os.environ.get("QT_QPA_PLATFORM") or sys.platform in ("win32", "darwin"))


def run(args: argparse.Namespace) -> int:
    from impress_gui.commands._progress import progress_printer
    from impress_gui.sim.sample import make_sample

    progress = progress_printer(3)

    t0 = time.perf_counter()
    project = make_sample(args.cache / "sample", progress=progress)
    recon = project / "reconstruction"
    print(f"sample project: {project} (ready in {time.perf_counter() - t0:.1f} s)")
    for name in ("project.json", "log.jsonl", "calibration.json"):
        print(f"  {name:<22s} {project / name}")
    for f in sorted(recon.iterdir()):
        print(f"  reconstruction/{f.name:<22s} {f.stat().st_size / 1e6:8.2f} MB")
    if args.no_gui:
        return 0
    if not _has_display():
        print("no display found (DISPLAY/WAYLAND_DISPLAY unset): not opening the window. "
              "Run `./run.sh` on a desktop, or `QT_QPA_PLATFORM=offscreen impress gui PROJECT "
              "--screenshot out.png --quit-after 1` for a picture.")
        return 0
    from impress_gui.cli import main as cli_main

    return cli_main(["gui", str(project), "--tab", "viewer"])
