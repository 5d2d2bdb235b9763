"""The stripe centre's sub-pixel estimates against the renderer's exact centres (issue 18).

For frames of cached scans (random rigs, the shoe preset), the simulator renders each laser's
exact stripe points again (``StripeTruth``: sub-pixel image rows per column); the decoded luma
around them is cut out of the video, and the detector's estimates are compared with the exact
row, column by column, where the stripe is continuous (no occlusion edge within 12 samples):

- ``half-max``: the centre of mass above half maximum, in the detector's window around the
  brightest row, re-centred once (``--subpixel half-max``);
- ``window``: that centre refined by ``stripes.window_refine`` (the default);
- ``uncapped``: the same without the cap on the window's half width (as first built).

Printed per scan and laser: the RMS error (px) and the swing of the mean error over the exact
centre's position within the pixel (eight bins: pixel locking); then median and worst.

Usage: .venv/bin/python benchmarks/bench_subpixel.py [--seeds 0,7,1,2,4,6]
       [--resolution 1920x1080] [--frames 10] [--shoe] [--cache-key KEY] [--folder SCAN ...]
(scans are taken from benchmarks/.cache and rendered there when missing)
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from common import CACHE

K = 14  # rows cut out either side of the exact centre
HALF = 6  # the detector's half window (StripeParams.half_window_px)


def columns(folder: Path, frames: int) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per laser: exact centres (rows, relative to the cut) and the luma cut ``(N, 2K+1)``."""
    from impress_gui.core.formats.video import open_video
    from impress_gui.sim.simulate import SimConfig, _make_renderer

    truth = json.loads((folder / "truth.json").read_text())
    renderer, _ = _make_renderer(SimConfig(**truth["config"]))
    n = truth["frame_count"]
    wanted = set(np.linspace(int(0.15 * n), int(0.85 * n), frames).astype(int).tolist())
    out: dict[str, list] = {}
    with open_video(folder / truth["video"]) as src:
        for k, planes in src.iter_planes(min(wanted), max(wanted) + 1):
            if k not in wanted:
                continue
            y = planes.y
            for laser in renderer.rig.lasers:
                uv = renderer.laser_points(laser, k).uv_px
                uv = uv[np.argsort(uv[:, 0])]
                for c in range(2, y.shape[1] - 2, 3):
                    i = int(np.searchsorted(uv[:, 0], c))
                    if i == 0 or i >= len(uv):
                        continue
                    u0, u1 = uv[i - 1, 0], uv[i, 0]
                    if u1 - u0 > 0.5 or abs(uv[i, 1] - uv[i - 1, 1]) > 0.5:
                        continue
                    if np.abs(np.diff(uv[max(i - 12, 0): i + 12, 1])).max() > 0.5:
                        continue  # near an occlusion edge
                    v = uv[i - 1, 1] + (c - u0) / max(u1 - u0, 1e-9) * (uv[i, 1] - uv[i - 1, 1])
                    if not K + 2 < v < y.shape[0] - K - 2:
                        continue
                    r0 = int(round(v)) - K
                    out.setdefault(laser.name, []).append((v - r0, y[r0:r0 + 2 * K + 1, c].copy()))
    return {name: (np.array([a for a, _ in d]), np.array([b for _, b in d]))
            for name, d in out.items()}


def estimates(cut: np.ndarray) -> dict[str, np.ndarray]:
    """The detector's steps on each cut column (brightest row near the middle, the window
    around it, re-centred once), then the estimates."""
    from impress_gui.core.reconstruction import kernels as kn
    from impress_gui.core.reconstruction.stripes import window_refine

    y = cut.astype(np.float64)
    idx = np.arange(len(y))[:, None]
    peak = K - 3 + y[:, K - 3:K + 4].argmax(axis=1)

    def window(p):
        rr = p[:, None] + np.arange(-HALF, HALF + 1)[None, :]
        sig = y[idx, rr]
        sig = sig - sig.min(axis=1, keepdims=True)
        top = sig.max(axis=1)
        above = np.clip(sig - 0.5 * top[:, None], 0, None)
        with np.errstate(invalid="ignore", divide="ignore"):
            centre = (above * rr).sum(axis=1) / above.sum(axis=1)
        return rr, sig, top, centre

    rr, sig, top, centre = window(peak)
    rr, sig, top, centre = window(np.rint(np.nan_to_num(centre, nan=K)).astype(int))
    out = {"half-max": centre, "window": window_refine(rr.T, sig.T, top, centre)}
    saved = kn.REFINE_MAX_HALF, kn.REFINE_MAX_HALF_CLIPPED
    try:
        kn.REFINE_MAX_HALF = kn.REFINE_MAX_HALF_CLIPPED = 1e9
        out["uncapped"] = window_refine(rr.T, sig.T, top, centre)
    finally:
        kn.REFINE_MAX_HALF, kn.REFINE_MAX_HALF_CLIPPED = saved
    out["_top"] = top
    return out


def figures(err: np.ndarray, v: np.ndarray) -> tuple[float, float]:
    ok = np.isfinite(err) & (np.abs(err) < 2)
    b = np.floor((v - np.floor(v)) * 8).astype(int)
    means = [err[ok & (b == i)].mean() for i in range(8) if (ok & (b == i)).any()]
    return float(np.sqrt(np.mean(err[ok] ** 2))), float(max(means) - min(means))


def main() -> None:
    import bench_random_rigs as R
    import common

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="0,7,1,2,4,6")
    ap.add_argument("--resolution", default="1920x1080")
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--shoe", action="store_true", help="also the shoe preset at 1080p "
                    "(bench_reconstruct.py's render for this simulator)")
    ap.add_argument("--cache-key", help="the simulator key of cached random-rig renders to use")
    ap.add_argument("--folder", action="append", default=[], type=Path,
                    help="another scan folder with truth.json (e.g. a test's cached render); "
                    "repeatable")
    args = ap.parse_args()
    shoe = CACHE / f"shoe-1080p-{common.SIM_KEY}"  # this simulator's render
    if args.cache_key:
        common.SIM_KEY = R.SIM_KEY = args.cache_key
    w, h = (int(v) for v in args.resolution.split("x"))
    scans = [(f"rig {s}", R.scan_for(int(s), w, h)) for s in args.seeds.split(",") if s]
    if args.shoe:
        scans.append(("shoe 1080p", shoe))
    scans += [(f.name[:12], f) for f in args.folder]
    names = ("half-max", "window", "uncapped")
    print(f"{'scan':12s} {'laser':6s} {'cols':>5s} " + " ".join(f"{n + ' rms':>13s}" for n in names)
          + "   " + " ".join(f"{n + ' lock':>14s}" for n in names))
    rms_all: dict[str, list[float]] = {n: [] for n in names}
    for label, folder in scans:
        if not (folder / "truth.json").exists():
            print(f"{label}: no render at {folder}")
            continue
        for laser, (v, cut) in sorted(columns(folder, args.frames).items()):
            est = estimates(cut)
            good = est["_top"] >= 25  # the detector's minimum peak
            rows = [figures((est[n] - v)[good], v[good]) for n in names]
            for n, (r, _) in zip(names, rows, strict=True):
                rms_all[n].append(r)
            print(f"{label:12s} {laser:6s} {int(good.sum()):5d} "
                  + " ".join(f"{r:13.3f}" for r, _ in rows) + "   "
                  + " ".join(f"{a:14.3f}" for _, a in rows), flush=True)
    for what, fn in (("median", np.median), ("worst", np.max)):
        print(f"{what:12s} {'':6s} {'':5s} " + " ".join(f"{fn(rms_all[n]):13.3f}" for n in names))


if __name__ == "__main__":
    main()
