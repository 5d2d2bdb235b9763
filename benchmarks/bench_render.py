"""Rendering cost of the scan simulator (issue 2's acceptance figure).

Prints the setup time (scene build, renderer set-up), single-process frames/s at 1920x1080 and
640x360 on the `shoe` preset, and the end-to-end time of the 30-second clip
``impress simulate --preset shoe --length-mm 400 --resolution 640x360`` (926 frames at
13.138 mm/s; two render processes) as a ratio to the 60 s budget. Wall times on a shared
machine depend on what else runs: the load average and the CPU time are printed beside them.

Usage: .venv/bin/python benchmarks/bench_render.py [--skip-clip]
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from impress_gui.core.calibration.target import default_target
from impress_gui.sim.render import Renderer, RenderOptions
from impress_gui.sim.scenes import build_scene
from impress_gui.sim.simulate import SimConfig, make_motion, make_rig, target_pose

BUDGET_S = 60.0
CLIP = ["--preset", "shoe", "--length-mm", "400", "--resolution", "640x360"]


def load() -> str:
    a, b, c = os.getloadavg()
    return f"load average {a:.1f} {b:.1f} {c:.1f}"


def frames_per_s(renderer: Renderer, frames: list[int]) -> tuple[float, float]:
    """Wall and CPU (all threads of this process) frames per second."""
    renderer.render(frames[0])  # warm caches
    w0, c0 = time.perf_counter(), time.process_time()
    for k in frames:
        renderer.render(k)
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    return len(frames) / wall, len(frames) / cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skip-clip", action="store_true", help="skip the end-to-end clip")
    args = ap.parse_args()
    print(f"IMPREsS simulator rendering benchmark ({os.cpu_count()} CPUs, {load()})")
    cfg = SimConfig(preset="shoe", length_mm=400.0)
    t0 = time.perf_counter()
    scene = build_scene(cfg.preset, cfg.scan_length_mm, cfg.grid_mm, cfg.seed, default_target(),
                        target_pose(cfg))
    t_scene = time.perf_counter() - t0
    print(f"scene build (shoe, 400 mm, {scene.shape[1]}x{scene.shape[0]} cells at "
          f"{scene.pixel_mm} mm): {t_scene:.1f} s")
    motion = make_motion(cfg)
    n = motion.frame_count
    for (w, h), count in (((1920, 1080), 8), ((640, 360), 40)):
        c = SimConfig(preset="shoe", length_mm=400.0, width=w, height=h)
        t0 = time.perf_counter()
        rend = Renderer(scene, make_rig(c), motion, RenderOptions(
            noise_sigma_dn=c.noise_dn, speckle_contrast=c.speckle, seed=c.seed,
            stripe_sigma_px=max(1.2, 1.6 * w / 1920.0), laser_peak=3.5))
        t_setup = time.perf_counter() - t0
        frames = [int(k) for k in np.linspace(0, n - 1, count)]
        fps, fps_cpu = frames_per_s(rend, frames)
        print(f"{w}x{h}: renderer set-up {t_setup:.2f} s; {fps:.2f} frames/s "
              f"({1000 / fps:.0f} ms/frame wall, {1000 / fps_cpu:.0f} ms CPU; "
              f"{count} frames over the scan, one process)")
        del rend
    if args.skip_clip:
        return
    del scene
    with tempfile.TemporaryDirectory() as tmp:
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        print(f"30-s clip: impress simulate {' '.join(CLIP)} ({load()}) ...", flush=True)
        t0 = time.perf_counter()
        res = subprocess.run([sys.executable, "-m", "impress_gui", "simulate",
                              str(Path(tmp) / "clip"), *CLIP], capture_output=True, text=True)
        wall = time.perf_counter() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        if res.returncode:
            print(res.stderr)
            raise SystemExit("the clip failed")
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        cores = os.cpu_count() or 1
        print(f"30-s clip ({n} frames): {wall:.1f} s wall = {wall / BUDGET_S:.2f} x the "
              f"{BUDGET_S:.0f} s budget; {cpu:.0f} s CPU over all processes (>= "
              f"{cpu / cores:.0f} s on {cores} idle cores); {load()}")


if __name__ == "__main__":
    main()
