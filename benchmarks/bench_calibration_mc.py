"""Does the calibration's Monte Carlo state the calibration's own errors? (issue 22)

For each random rig (the cached simulator scans of bench_random_rigs.py at 640x360) and each of
``--draws`` click-noise draws: the scene is calibrated from the simulator's exact corner picks
plus normal noise of ``--noise-px`` (a real recalibration, as bench_uncertainty.py makes them),
and its Monte Carlo (impress_gui.core.calibration.uncertainty.calibration_ensemble, ``--trials``
trials) is computed. At ``--points`` random points per laser around the target (within 60 mm
across it, from 20 mm before to 120 mm after it along the scan, heights -10..+20 mm) the
calibration's true error is taken from the simulator's truth (the same camera ray through the
true calibration: map_points) and compared with the Monte Carlo's SD of the same quantity, for
each of ``--stripe-models`` (how the trials rebuild the stripes and draw their noise:
uncertainty.STRIPE_MODELS):

- ``h``: an absolute height;
- ``dz``: the height difference between two random points;
- ``xy``: the length in xy between two random points more than 10 mm apart.

Printed per calibration and over all: the RMS error, the median stated SD, the RMS of error /
SD (1 when the statement is right) and the share of errors within 2 SD (about 95 % then). Only
the calibration is judged here (no reconstruction, no surface noise): bench_uncertainty.py
judges whole budgets.

Usage: .venv/bin/python benchmarks/bench_calibration_mc.py [--seeds 0,1,3,4,5,6] [--draws 3]
       [--trials 12] [--noise-px 0.5] [--points 300] [--stripe-models conservative,measured]
"""

from __future__ import annotations

import argparse
import time

import common
import numpy as np

KINDS = ("h", "dz", "xy")


def one(seed: int, draw: int, noise_px: float, trials: int, n_points: int, models) -> dict:
    import impress_gui.core.calibration.uncertainty as CU
    from impress_gui.core.calibration.target import TargetModel
    from impress_gui.sim.truth import true_cal_params

    d = common.CACHE / f"random-{seed}-640x360-{common.SIM_KEY}"
    if not (d / "truth.json").exists():
        raise FileNotFoundError(f"{d}: not cached (bench_random_rigs.py --seeds {seed}, "
                                "renders it)")
    target = TargetModel.load(d / "target.json")
    t0 = time.perf_counter()
    cal = common.calibrate(d, noise_px=noise_px, seed=1000 * seed + draw + 1)
    nominal, true = CU.CalParams.of_calibration(cal), true_cal_params(d, cal)
    res = {"seed": seed, "draw": draw, "t_cal": time.perf_counter() - t0}
    for model in models:
        t1 = time.perf_counter()
        ens = CU.calibration_ensemble(cal, target, n=trials, stripe_model=model)
        res[model] = _compare(cal, ens, nominal, true, n_points, np.random.default_rng(
            10 * seed + draw))
        res[model]["t_mc"] = time.perf_counter() - t1
    return res


def _compare(cal, ens, nominal, true, n_points: int, rng) -> dict:
    import impress_gui.core.calibration.uncertainty as CU

    t_o = np.asarray(cal.target_translation_mm)
    out: dict = {k: ([], []) for k in KINDS}
    for laser in ("green", "red"):
        x = t_o[0] + rng.uniform(-60, 60, n_points)
        y = t_o[1] + rng.uniform(-20, 120, n_points)
        h = rng.uniform(-10, 20, n_points)
        tx, ty, th = (v[0] for v in CU.map_points(nominal, true, x, y, h, laser))
        dx, dy, dh = ens.deltas(x, y, h, laser)
        a, b = rng.integers(0, n_points, n_points), rng.integers(0, n_points, n_points)
        far = np.hypot(x[a] - x[b], y[a] - y[b]) > 10.0
        length = np.hypot(x[a] - x[b], y[a] - y[b])
        true_len = np.hypot(tx[a] - tx[b], ty[a] - ty[b])
        trial_len = np.hypot(x[a] + dx[:, a] - x[b] - dx[:, b], y[a] + dy[:, a] - y[b] - dy[:, b])
        for k, e, s in (("h", th - h, dh.std(axis=0, ddof=1)),
                        ("dz", (th[a] - th[b]) - (h[a] - h[b]),
                         (dh[:, a] - dh[:, b]).std(axis=0, ddof=1)),
                        ("xy", (true_len - length)[far], trial_len[:, far].std(axis=0, ddof=1))):
            ok = s > 0  # a pair of one point with itself has no spread
            out[k][0].append(e[ok])
            out[k][1].append(s[ok])
    return {k: (np.concatenate(v[0]), np.concatenate(v[1])) for k, v in out.items()}


def line(e: np.ndarray, s: np.ndarray) -> str:
    z = e / s
    return (f"RMS error {np.sqrt(np.mean(e ** 2)):.4f} mm, median SD {np.median(s):.4f} mm, "
            f"RMS error/SD {np.sqrt(np.mean(z ** 2)):.2f}, within 2 SD "
            f"{100 * np.mean(np.abs(z) <= 2):5.1f} %")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0,1,3,4,5,6")
    ap.add_argument("--draws", type=int, default=3)
    ap.add_argument("--trials", type=int, default=12)
    ap.add_argument("--noise-px", type=float, default=0.5)
    ap.add_argument("--points", type=int, default=300)
    ap.add_argument("--stripe-models", default="conservative,measured")
    args = ap.parse_args()
    models = [m for m in args.stripe_models.split(",") if m]
    seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    rows = []
    for seed in seeds:
        for draw in range(args.draws):
            try:
                r = one(seed, draw, args.noise_px, args.trials, args.points, models)
            except Exception as exc:  # noqa: BLE001 - a refused calibration is reported
                print(f"rig {seed:2d} draw {draw}: not measured ({exc})", flush=True)
                continue
            rows.append(r)
            print(f"rig {seed:2d} draw {draw} (calibration {r['t_cal']:.1f} s)", flush=True)
            for m in models:
                print(f"  {m} (Monte Carlo {r[m]['t_mc']:.1f} s)")
                for k in KINDS:
                    print(f"    {k:3s} {line(*r[m][k])}", flush=True)
    for m in models:
        print(f"\nall {len(rows)} calibrations, stripe model {m} ({args.trials} trials each, "
              f"click noise {args.noise_px} px):")
        for k in KINDS:
            if rows:
                e = np.concatenate([r[m][k][0] for r in rows])
                s = np.concatenate([r[m][k][1] for r in rows])
                print(f"    {k:3s} {line(e, s)}")


if __name__ == "__main__":
    main()
