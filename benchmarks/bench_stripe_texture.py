"""A stripe whose light follows the soil row by row (issue 18, real laser light).

The simulator draws each column of a laser stripe as one Gaussian in the image rows, scaled
by the soil's albedo at the stripe's exact point (``sim.render.Renderer._stripe_band``): the
light reflected a row above or below the centre is scaled by the centre's albedo, not by that
row's. On a real surface each image row shows its own bit of soil, which reflects the laser in
proportion to its own albedo: the stripe's profile is the beam's profile *times the soil's
texture*, and a grain brighter on one side pulls the centre towards it. The reconstruction
subtracts the soil seen unlit (``core/reconstruction/unlit.py``), which removes a texture that
adds to the stripe but not one that multiplies it; dividing the difference by the unlit soil
(normalised over the stripe's rows) would.

This benchmark measures the size of that effect on the random rigs' own soils, without
rendering: for each rig (its scene's albedo, ``truth_texture.png`` of the cached render; its
stripe width and its pixel's size on the ground, standoff / focal length) it builds columns of
luma: ambient light on the soil, plus a stripe of 40-160 grey levels (not clipped) at a random
sub-pixel centre, drawn (a) as the simulator draws it and (b) following the soil row by row;
sensor noise of 2 grey levels, and the unlit soil as five frames averaged. The detector's
window estimate (``bench_subpixel.estimates``: the brightest row, the window, re-centred once,
``stripes.window_refine``) is then taken on the luma minus the unlit soil (the product's
subtraction, all of the texture: no codec here) and on that difference divided by the unlit
soil. Printed per rig and laser: RMS error (px) of the four combinations; then median and worst.

``--grain S`` multiplies the soil by a grain finer than the scene's 0.1 mm grid (log-normal,
spread S, blurred to about a pixel): sand or grit whose grains a pixel resolves, which the
simulator's soils do not have.

Usage: .venv/bin/python benchmarks/bench_stripe_texture.py [--seeds 0,1,2] [--columns 3000]
       [--grain 0.2]
(the seeds' 1920x1080 renders are taken from benchmarks/.cache, rendered there when missing)
"""

from __future__ import annotations

import argparse
import json

import numpy as np

#: rows either side of the stripe's centre in a column (as bench_subpixel's cuts)
K = 14
#: the stripe's peak above the soil, grey levels (drawn uniformly; never clipped)
PEAK_RANGE = (40.0, 160.0)
#: ambient light on the soil (grey levels for albedo 1)
AMBIENT_DN = 140.0
NOISE_DN = 2.0
UNLIT_FRAMES = 5
#: rows around the centre whose mean unlit luma normalises the division
NORM_HALF = 3


def soil_columns(albedo: np.ndarray, grid_mm: float, pixel_mm: float, n: int,
                 rng: np.random.Generator) -> np.ndarray:
    """``n`` columns of ``2K+1`` rows of ``albedo`` (one channel, 0..1, on a grid of
    ``grid_mm``) sampled every ``pixel_mm`` along its rows' direction at random places."""
    import cv2

    h, w = albedo.shape
    span = (K + 1) * pixel_mm / grid_mm
    yc = rng.uniform(span + 1, h - span - 2, n)
    xc = rng.uniform(1, w - 2, n)
    rows = np.arange(-K, K + 1)[None, :] * (pixel_mm / grid_mm)
    yy = (yc[:, None] + rows).astype(np.float32)
    xx = np.broadcast_to(xc[:, None], yy.shape).astype(np.float32)
    return cv2.remap(np.ascontiguousarray(albedo, np.float32), xx, yy,
                     cv2.INTER_LINEAR).astype(np.float64)


def stripe_columns(albedo: np.ndarray, sigma_px: float, rng: np.random.Generator,
                   follows_soil: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(lit, unlit, centres)``: luma columns ``(n, 2K+1)`` with the stripe at ``centres``
    (rows from the middle), and the same soil unlit (``UNLIT_FRAMES`` averaged)."""
    n = len(albedo)
    centre = rng.uniform(-0.5, 0.5, n)
    rows = np.arange(-K, K + 1)[None, :].astype(np.float64)
    beam = np.exp(-0.5 * ((rows - centre[:, None]) / sigma_px) ** 2)
    peak = rng.uniform(*PEAK_RANGE, n)[:, None]
    mid = albedo[:, K][:, None]
    gain = albedo / np.maximum(mid, 1e-3) if follows_soil else 1.0
    soil = AMBIENT_DN * albedo
    lit = soil + peak * gain * beam + rng.normal(0.0, NOISE_DN, beam.shape)
    unlit = soil + rng.normal(0.0, NOISE_DN / np.sqrt(UNLIT_FRAMES), beam.shape)
    return np.clip(lit, 0, 255), unlit, centre


def errors(lit: np.ndarray, unlit: np.ndarray, centre: np.ndarray) -> dict[str, float]:
    """RMS error (px) of the window estimate on the difference and on the ratio."""
    from bench_subpixel import estimates

    diff = lit - unlit
    norm = unlit / unlit[:, K - NORM_HALF:K + NORM_HALF + 1].mean(axis=1, keepdims=True)
    out = {}
    for name, cut in (("subtracted", diff), ("divided", diff / np.maximum(norm, 0.2))):
        cut = cut - cut.min(axis=1, keepdims=True)
        err = estimates(cut)["window"] - K - centre
        ok = np.isfinite(err) & (np.abs(err) < 2)
        out[name] = float(np.sqrt(np.mean(err[ok] ** 2)))
    return out


def measure(scan_dir, columns: int, seed: int, grain: float = 0.0) -> list[dict]:
    import cv2

    truth = json.loads((scan_dir / "truth.json").read_text())
    rig = truth["random_rig"]
    grid = float(truth["heightmap"]["pixel_mm"]) if "pixel_mm" in truth["heightmap"] else 0.1
    pixel_mm = float(rig["standoff_mm"]) / float(rig["focal_px_1080p"])
    sigma = float(rig["stripe_sigma_px_1080p"])
    tex = cv2.imread(str(scan_dir / "truth_texture.png"), cv2.IMREAD_COLOR)[..., ::-1]
    rows = []
    for name, ch in (("green", 1), ("red", 0)):
        rng = np.random.default_rng([seed, ch])
        alb = soil_columns(tex[..., ch] / 255.0, grid, pixel_mm, columns, rng)
        if grain > 0:  # soil finer than the scene's grid: grains about a pixel across
            g = rng.lognormal(0.0, grain, alb.shape).astype(np.float32)
            alb = alb * np.asarray(cv2.GaussianBlur(g, (0, 0), 0.5), np.float64)
        row = {"seed": seed, "laser": name, "sigma_px": sigma, "pixel_mm": pixel_mm,
               "grain": float(np.median(np.std(alb[:, K - NORM_HALF:K + NORM_HALF + 1], axis=1)
                                        / alb[:, K - NORM_HALF:K + NORM_HALF + 1].mean(axis=1)))}
        for follows in (False, True):
            e = errors(*stripe_columns(alb, sigma, rng, follows))
            key = "follows" if follows else "drawn"
            row[f"{key}_subtracted"], row[f"{key}_divided"] = e["subtracted"], e["divided"]
        rows.append(row)
    return rows


COLS = ("drawn_subtracted", "drawn_divided", "follows_subtracted", "follows_divided")


def main() -> None:
    import bench_random_rigs as R

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="0,1,2,3", help="comma list of random rigs")
    ap.add_argument("--columns", type=int, default=3000, help="columns per rig and laser")
    ap.add_argument("--grain", type=float, default=0.0,
                    help="soil finer than the scene's 0.1 mm grid: the albedo times a log-normal "
                         "grain of this spread, about a pixel across (0: the scene's soil alone)")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    extra = f", soil grain {args.grain:g} added" if args.grain else ""
    print(f"random rigs {seeds}{extra}: the window estimate's RMS error (px) on {args.columns} columns "
          "per laser; stripe drawn as the simulator draws it / following the soil row by row; "
          "the unlit soil subtracted / also divided out")
    rows = []
    for seed in seeds:
        for r in measure(R.scan_for(seed, 1920, 1080), args.columns, seed, args.grain):
            rows.append(r)
            print(f"  rig {seed:3d} {r['laser']:5s} (sigma {r['sigma_px']:.2f} px, pixel "
                  f"{r['pixel_mm']:.3f} mm, grain {100 * r['grain']:.1f} %): drawn "
                  f"{r['drawn_subtracted']:.3f} / {r['drawn_divided']:.3f}; follows the soil "
                  f"{r['follows_subtracted']:.3f} / {r['follows_divided']:.3f}", flush=True)
    a = np.array([[r[c] for c in COLS] for r in rows])
    for label, v in (("median", np.median(a, axis=0)), ("worst", a.max(axis=0))):
        print(f"{label}: drawn {v[0]:.3f} / {v[1]:.3f}; follows the soil {v[2]:.3f} / {v[3]:.3f}")


if __name__ == "__main__":
    main()
