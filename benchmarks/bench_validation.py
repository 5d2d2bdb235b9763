"""The method validation (issue 8's acceptance figure): the thesis' protocol (table 4.1) on
simulator scans of the six placements of plates A and B, plus the flat plane and the spheres.

Prints the table in the thesis' layout beside the thesis' figures, the acceptance verdict
(overall xy mean <= 0.12 mm, z mean <= 0.19 mm: five times better than the thesis) and the
wall time of each stage. Rendered scans are kept in the output folder and reused, so a second
run measures the reconstruction alone (rendering 1080p is the long part: about 20 minutes on two
cores). Wall times on a shared machine depend on what else runs: the load average is printed.

Usage: .venv/bin/python benchmarks/bench_validation.py [--quick] [--out DIR]
       [--resolution WxH] [--placements AB,BA,...]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from common import CACHE

from impress_gui.validation.report import format_table, write_report
from impress_gui.validation.run import RunConfig, run_simulated


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="640x360 at 3x the fast speed")
    ap.add_argument("--out", type=Path, default=CACHE / "validation")
    ap.add_argument("--resolution", default=None, help="WIDTHxHEIGHT (default: the mode's)")
    ap.add_argument("--placements", default=None, help="comma-separated subset")
    ap.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    args = ap.parse_args()
    kw: dict = {"workers": args.workers}
    if args.resolution:
        kw["width"], kw["height"] = (int(v) for v in args.resolution.lower().split("x"))
    if args.placements:
        kw["placements"] = tuple(args.placements.split(","))
    cfg = RunConfig.quick(**kw) if args.quick else RunConfig.full(**kw)
    a, b, c = os.getloadavg()
    print(
        f"IMPREsS validation benchmark: {cfg.mode} mode, {cfg.width}x{cfg.height}, "
        f"{cfg.speed_mm_s} mm/s, {os.cpu_count()} CPUs, load average {a:.1f} {b:.1f} {c:.1f}",
        flush=True,
    )
    last = [0.0]

    def progress(frac: float, msg: str) -> None:
        now = time.monotonic()
        if now - last[0] > 30 or frac >= 1.0:
            last[0] = now
            print(f"  {100 * frac:5.1f} %  {msg}", file=sys.stderr, flush=True)

    t0 = time.perf_counter()
    record = run_simulated(cfg, args.out, progress)
    paths = write_report(record, args.out)
    print(format_table(record))
    for s in record["scans"]:
        sec = s["seconds"]
        print(
            f"  {s['title']:42s} render {sec['render']:7.1f} s  calibration "
            f"{sec['calibration']:6.1f} s  processing {sec['processing']:7.1f} s"
        )
    print(f"total {time.perf_counter() - t0:.0f} s; report {paths['report']}")
    acc = record["acceptance"]
    return 0 if acc["xy_ok"] and acc["z_ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
