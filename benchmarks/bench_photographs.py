"""The stripe detector on photographs of a line laser drawn like a consumer camera's (issue 18,
real laser light).

Issue 18 reports a real photograph of a red line laser on a light object (a consumer camera,
the stripe not saturated, pinkish on white) on which the detector found the stripe in 31 % of
the columns where plain background subtraction found it. Such light is not what the scan
simulator draws (a video frame of a rig), so here still photographs are drawn in linear light
and put through what a consumer camera does: the laser's light leaking into the other colour
channels (sensor crosstalk), a shaded, textured object of any light-to-mid colour, noise, the
sRGB tone curve, JPEG. Each draw (``--draws``, seeded) takes the laser (red or green), its
power (0.15-1.2 full scales, log-uniform: dim and pinkish to clipped), the crosstalk (0.1-0.4),
the stripe's width (sigma 1-3 px), the object's grey level (0.3-0.9) and tint, its texture,
the noise and the JPEG quality (70-95) at random.

Printed per draw and as median / 10th percentile / worst: of the columns where plain
background subtraction finds the stripe (the laser's channel minus its 31 x 31 median rises
at least 12 grey levels within 3 rows of the stripe), the share the detector finds on the
stripe (within 1.5 px of its row), with the faint rule (``StripeParams.faint``, the default)
and without it; and the columns it finds off the stripe (more than 3 px). Then control
photographs without a laser (red, orange, white and grey objects, coarse texture; images of
independent pixel noise, dark and light): the columns found at all.

Usage: .venv/bin/python benchmarks/bench_photographs.py [--draws 40] [--seed 0]
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

H, W = 540, 960


def _srgb(lin: np.ndarray) -> np.ndarray:
    lin = np.clip(lin, 0.0, 1.0)
    return np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * lin ** (1 / 2.4) - 0.055)


def photograph(laser: str | None, power: float, albedo: tuple[float, float, float], *,
               seed: int = 1, size: tuple[int, int] = (W, H), texture: float = 0.04,
               crosstalk: float = 0.25, sigma_px: float = 2.0, noise: float = 0.01,
               jpeg_quality: int = 85) -> tuple[np.ndarray, np.ndarray]:
    """An RGB photograph (``uint8``, after JPEG) of a shaded, textured object of linear
    ``albedo`` with a line laser's stripe along a wavy row (``power``: its peak in linear full
    scales on an object of albedo 1; Gaussian across the row, ``sigma_px``), and that row per
    column. ``laser`` None: no stripe. The laser's light reaches the other channels by
    ``crosstalk`` (blue 1.2 x that)."""
    w, h = size
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    shade = 0.85 + 0.15 * np.sin(xx / (0.2 * w) + seed) * np.cos(yy / (0.4 * h))
    tex = cv2.GaussianBlur(rng.normal(0, texture, (h, w)).astype(np.float32), (0, 0), 1.5)
    base = shade * (1 + tex)
    lin = np.stack([base * a for a in albedo], axis=-1)
    row = (h / 2 + 0.11 * h * np.sin(np.arange(w) / (0.13 * w) + seed)
           + 0.03 * h * np.sin(np.arange(w) / 29))
    if laser is not None:
        prof = power * shade * np.exp(-0.5 * ((yy - row[None, :]) / sigma_px) ** 2)
        c = 0 if laser == "red" else 1
        gain = [crosstalk, crosstalk, 1.2 * crosstalk]
        gain[c] = 1.0
        for j in range(3):
            lin[..., j] += gain[j] * prof * albedo[j] / max(albedo)
    lin += rng.normal(0, noise, lin.shape)
    img = np.rint(_srgb(lin) * 255).astype(np.uint8)
    ok, enc = cv2.imencode(".jpg", np.ascontiguousarray(img[..., ::-1]),
                           [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return np.ascontiguousarray(cv2.imdecode(enc, cv2.IMREAD_COLOR)[..., ::-1]), row


def plain_subtraction(img: np.ndarray, laser: str, row: np.ndarray) -> np.ndarray:
    """Columns where plain background subtraction finds the stripe: the laser's channel minus
    its median over 31 x 31 pixels peaks at least 12 grey levels, within 3 rows of
    ``row``."""
    ch = np.ascontiguousarray(img[..., 0 if laser == "red" else 1])
    d = ch.astype(np.float32) - cv2.medianBlur(ch, 31).astype(np.float32)
    return (d.max(axis=0) >= 12) & (np.abs(d.argmax(axis=0) - row) <= 3)


def detected(laser: str, img: np.ndarray, faint: bool = True) -> np.ndarray:
    """The detector's row per column (NaN: none) on a whole photograph (no regions of
    interest, the other laser's band unknown: as the calibration tab's overlay runs it)."""
    from impress_gui.core.formats.video import Planes
    from impress_gui.core.reconstruction.stripes import StripeParams, detect_planes

    h, w = img.shape[:2]
    return detect_planes(laser, Planes.from_rgb(img), np.zeros(w, np.int64), h,
                         StripeParams(faint=faint), None).rows


def draw(rng: np.random.Generator) -> dict:
    """One photograph's settings from the family described above."""
    grey = rng.uniform(0.3, 0.9)
    tint = rng.uniform(0.8, 1.0, 3)
    return {"laser": str(rng.choice(["red", "green"])),
            "power": float(np.exp(rng.uniform(np.log(0.15), np.log(1.2)))),
            "albedo": tuple(float(v) for v in grey * tint / tint.max()),
            "crosstalk": float(rng.uniform(0.1, 0.4)),
            "sigma_px": float(rng.uniform(1.0, 3.0)),
            "texture": float(rng.uniform(0.01, 0.08)),
            "noise": float(rng.uniform(0.005, 0.02)),
            "jpeg_quality": int(rng.integers(70, 96)),
            "seed": int(rng.integers(0, 2**31))}


def _found(img: np.ndarray) -> str:
    """Columns found per laser, with the faint rule and without it."""
    out = []
    for laser in ("red", "green"):
        n = [int(np.isfinite(detected(laser, img, faint=f)).sum()) for f in (True, False)]
        out.append(f"{laser} {n[0]} (without the faint rule {n[1]})")
    return ", ".join(out) + f" of {img.shape[1]}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--draws", type=int, default=40, help="photographs with a laser")
    ap.add_argument("--seed", type=int, default=0, help="the family's random seed")
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    print(f"{'draw':>4s} {'laser':5s} {'power':>5s} {'albedo':>16s} {'xtalk':>5s} {'sigma':>5s} "
          f"{'jpeg':>4s} {'plain %':>7s} {'found %':>7s} {'no faint %':>10s} {'off':>4s}")
    share, share0, off_total = [], [], 0
    for i in range(args.draws):
        d = draw(rng)
        laser = d.pop("laser")
        power, albedo = d.pop("power"), d.pop("albedo")
        img, row = photograph(laser, power, albedo, **d)
        plain = plain_subtraction(img, laser, row)
        rows = detected(laser, img)
        rows0 = detected(laser, img, faint=False)
        on = np.abs(rows - row) <= 1.5
        on0 = np.abs(rows0 - row) <= 1.5
        off = int((np.isfinite(rows) & (np.abs(rows - row) > 3)).sum())
        off_total += off
        if plain.any():
            share.append(100 * on[plain].mean())
            share0.append(100 * on0[plain].mean())
        print(f"{i:4d} {laser:5s} {power:5.2f} {'/'.join(f'{a:.2f}' for a in albedo):>16s} "
              f"{d['crosstalk']:5.2f} {d['sigma_px']:5.2f} {d['jpeg_quality']:4d} "
              f"{100 * plain.mean():7.1f} "
              + (f"{share[-1]:7.1f} {share0[-1]:10.1f}" if plain.any() else f"{'-':>7s} {'-':>10s}")
              + f" {off:4d}", flush=True)
    for label, fn in (("median", np.median), ("10th pct", lambda v: np.percentile(v, 10)),
                      ("worst", np.min)):
        print(f"{label}: found {fn(share):.1f} % of the columns plain subtraction finds "
              f"(without the faint rule {fn(share0):.1f} %)")
    print(f"columns found off the stripe (> 3 px), all draws: {off_total}")
    control = {"red soil": (0.5, 0.22, 0.12), "orange": (0.7, 0.4, 0.15),
               "white": (0.85, 0.85, 0.85), "grey": (0.4, 0.4, 0.4)}
    for name, albedo in control.items():
        img, _ = photograph(None, 0.0, albedo, texture=0.12, seed=args.seed + 7)
        print(f"no laser, {name} object (coarse texture): columns found {_found(img)}")
    noise = np.random.default_rng(args.seed + 11)
    for lo, hi in ((40, 90), (150, 230)):
        img = noise.integers(lo, hi, (H, W, 3), np.uint8)
        print(f"no laser, independent pixel noise {lo}-{hi}: columns found {_found(img)}")


if __name__ == "__main__":
    main()
