"""Calibration alone on random rigs, exact and noisy picks (issue 18): what the calibration's
parameters do to heights, without the detector in the way.

For each random rig (the cached simulator scans of bench_random_rigs.py, 640x360 by default)
the scene is calibrated from the simulator's exact corner picks (draw "exact") and from
``--draws`` draws of picks with normal noise of ``--noise-px`` per coordinate (seed
1000 * rig + draw + 1, as bench_uncertainty.py). Per calibration:

- ``dtilt``, ``droll``: the tilt and roll errors (deg);
- ``h med``, ``h max``: the height error the calibration's parameters alone make: 400 points
  (a 20 x 20 grid over x -60..60 mm across and y 0..120 mm along the scan from the camera at
  t1, heights cycling over -10..+20 mm, in the calibration's frame) reconstructed by the calibration from one laser are taken, by their
  camera ray at their time, through the simulator's TRUE calibration
  (core.calibration.uncertainty.map_points; sim.truth.true_cal_params); the height
  difference, median and largest of |error| over the points, the worse laser;
- a calibration the product refuses is listed with its error code (a result, not a crash).

Then median, 90th percentile and worst over the calibrations, exact and noisy apart.

Usage: .venv/bin/python benchmarks/bench_calibration_rigs.py [--seeds 24 | --seeds 3,7,11]
       [--draws 3] [--noise-px 0.5] [--resolution 640x360] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import bench_random_rigs as R
import common
import numpy as np

from impress_gui.core.base.errors import ImpressError
from impress_gui.sim.truth import true_cal_params as true_params

#: the fixed points (calibration frame, mm): 20 across x 20 along, heights cycling -10..+20 mm
_X, _Y = np.meshgrid(np.linspace(-60.0, 60.0, 20), np.linspace(0.0, 120.0, 20))
POINTS_X, POINTS_Y = _X.ravel(), _Y.ravel()
POINTS_H = np.resize(np.linspace(-10.0, 20.0, 7), POINTS_X.size)


def height_errors(scan_dir: Path, cal) -> tuple[float, float]:
    """Median and largest |height error| (mm) over the fixed points, the worse laser."""
    from impress_gui.core.calibration.uncertainty import CalParams, map_points

    nominal, true = CalParams.of_calibration(cal), true_params(scan_dir, cal)
    med, worst = 0.0, 0.0
    for laser in ("green", "red"):
        _, _, h = map_points(nominal, true, POINTS_X, POINTS_Y, POINTS_H, laser)
        e = np.abs(h[0] - POINTS_H)
        med, worst = max(med, float(np.nanmedian(e))), max(worst, float(np.nanmax(e)))
    return med, worst


def measure(seed: int, draw: int, noise_px: float, width: int, height: int) -> dict:
    d = R.scan_for(seed, width, height)
    truth = json.loads((d / "truth.json").read_text())
    row: dict = {"seed": seed, "draw": draw, "preset": truth["config"]["preset"]}
    t0 = time.perf_counter()
    try:
        cal = (common.calibrate(d) if draw < 0
               else common.calibrate(d, noise_px=noise_px, seed=1000 * seed + draw + 1))
    except ImpressError as exc:
        row.update(error=exc.code, seconds=time.perf_counter() - t0)
        return row
    row["seconds"] = time.perf_counter() - t0
    row["tilt_err"] = abs(cal.tilt_deg - truth["tilt_deg"])
    row["roll_err"] = abs((cal.roll_deg - truth["roll_deg"] + 180) % 360 - 180)
    row["h_med"], row["h_max"] = height_errors(d, cal)
    return row


def summary(rows: list[dict], label: str) -> None:
    ok = [r for r in rows if "error" not in r]
    refused = [f"{r['seed']}/{r['draw']}" for r in rows if "error" in r]
    print(f"{label}: {len(ok)} calibrated, {len(refused)} refused "
          f"{' '.join(refused) if refused else ''}")
    if not ok:
        return
    for key, name in (("tilt_err", "dtilt deg"), ("roll_err", "droll deg"),
                      ("h_med", "h med mm"), ("h_max", "h max mm")):
        a = np.array([r[key] for r in ok])
        print(f"  {name:>10s}: median {np.median(a):.4f}  p90 {np.percentile(a, 90):.4f}  "
              f"worst {a.max():.4f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="24", help="how many seeds (0..N-1) or a comma list")
    ap.add_argument("--draws", type=int, default=3, help="click-noise draws per rig")
    ap.add_argument("--noise-px", type=float, default=0.5, help="pick noise, px (1 sigma)")
    ap.add_argument("--resolution", default="640x360")
    ap.add_argument("--json", type=Path, default=None, help="also write the rows here")
    args = ap.parse_args()
    seeds = ([int(s) for s in args.seeds.split(",") if s] if "," in args.seeds
             else list(range(int(args.seeds))))
    w, h = (int(v) for v in args.resolution.lower().split("x"))
    print(f"cache: {common.CACHE}; random rigs {seeds} at {w}x{h}; exact picks and "
          f"{args.draws} draws of {args.noise_px} px click noise")
    print(" rig draw   scene   dtilt   droll   h med   h max     s")
    rows = []
    for s in seeds:
        for k in range(-1, args.draws):
            r = measure(s, k, args.noise_px, w, h)
            rows.append(r)
            tag = "exact" if k < 0 else f"{k:5d}"
            if "error" in r:
                print(f"{s:4d} {tag} {r['preset']:>7s}  refused: {r['error']}", flush=True)
            else:
                print(f"{s:4d} {tag} {r['preset']:>7s} {r['tilt_err']:7.3f} {r['roll_err']:7.3f} "
                      f"{r['h_med']:7.4f} {r['h_max']:7.4f} {r['seconds']:5.1f}", flush=True)
            if args.json:
                args.json.write_text(json.dumps(rows, indent=1))
    summary([r for r in rows if r["draw"] < 0], "exact picks")
    summary([r for r in rows if r["draw"] >= 0], f"{args.noise_px} px click noise")


if __name__ == "__main__":
    main()
