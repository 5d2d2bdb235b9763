"""The stripe centre's sub-pixel estimates against the renderer's exact centres (issue 18).

For frames of cached scans (random rigs, the shoe preset), the simulator renders each laser's
exact stripe points again (``StripeTruth``: sub-pixel image rows per column); the decoded luma
around them is cut out of the video, and the detector's estimates are compared with the exact
row, column by column, where the stripe is continuous (no occlusion edge within 12 samples):

- ``half-max``: the centre of mass above half maximum, in the detector's window around the
  brightest row, re-centred once (``--subpixel half-max``);
- ``window``: that centre refined by ``stripes.window_refine`` (the default);
- ``uncapped``: the same without the cap on the window's half width (as first built);
- ``bg-sub`` (``--background``): the window estimate on the luma minus the *same soil seen
  without the stripe*: the camera and lasers move together, so the ground under the stripe in
  frame k was seen, unlit, a few frames earlier or later, shifted along the motion. Its place
  there is projected from the stripe's exact rail point (the renderer's truth, so this is an
  upper bound on what an estimate of the shift from the calibration could give), the column
  cut there, in five consecutive frames averaged, ``BG_SHIFT_PX`` or more from the stripe's row
  and on the side farther from the other laser's stripe; rows where the luma is clipped
  (>= ``CLIP``) are left at the difference's top (a clipped core has no texture to remove).
  With ``--texture-weights 0.5,0.7,1``, one ``bg-sub`` column per share of the unlit soil's
  texture taken out (its straight-line fit kept whole: ``unlit.texture_weighted``, the
  product's; the compressed video keeps only part of the texture under a stripe). With
  ``--divide``, also ``bg-div``: that difference divided by the unlit soil (normalised on its
  7 middle rows), for a stripe whose light follows the soil (``--stripe-follows-soil``: rigs
  rendered so, cached apart).

Printed per scan and laser: the RMS error (px; errors over 2 px left out, their share printed
with ``--background``) and the swing of the mean error over the exact
centre's position within the pixel (eight bins: pixel locking); then median and worst.

Usage: .venv/bin/python benchmarks/bench_subpixel.py [--seeds 0,7,1,2,4,6]
       [--resolution 1920x1080] [--frames 10] [--shoe] [--cache-key KEY] [--folder SCAN ...]
       [--background [--texture-weights 1] [--divide]] [--stripe-follows-soil]
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
BG_SHIFT_PX = 40.0  # least shift of the background's cut from the stripe's row (``--background``)
BG_FRAMES = 2  # frames either side of the background frame averaged with it
CLIP = 225.0  # luma at or above which a row counts as clipped (``--background``)


def columns(folder: Path, frames: int, background: bool = False) -> dict[str, tuple]:
    """Per laser: exact centres (rows, relative to the cut) and the luma cut ``(N, 2K+1)``;
    with ``background``, also the motion-compensated background cut ``(N, 2K+1)`` (NaN rows
    where it could not be cut)."""
    from impress_gui.core.formats.video import open_video
    from impress_gui.sim.simulate import SimConfig, _make_renderer

    truth = json.loads((folder / "truth.json").read_text())
    renderer, _ = _make_renderer(SimConfig(**truth["config"]))
    rig = renderer.rig
    n = truth["frame_count"]
    wanted = set(np.linspace(int(0.15 * n), int(0.85 * n), frames).astype(int).tolist())

    def project(p: np.ndarray, k: int) -> np.ndarray:  # rail points -> pixels of frame k
        pc = (p - np.array([0.0, renderer.travel(k), 0.0])) @ rig.rotation
        return rig.intrinsics.project(pc)

    j = 0
    need = set(wanted)
    if background:  # frames between the cuts: the shift of a ground point per frame
        k0 = min(wanted)
        p0 = np.nanmedian(renderer.laser_points(rig.lasers[0], k0).points_rail_mm, axis=0)
        flow = float(np.linalg.norm(project(p0[None], k0 + 1) - project(p0[None], k0)))
        j = int(np.ceil(BG_SHIFT_PX / max(flow, 1e-3)))
        for k in wanted:
            for sign in (-1, 1):
                need.update(range(k + sign * j - BG_FRAMES, k + sign * j + BG_FRAMES + 1))
        need = {k for k in need if 0 <= k < n}
    kept: dict[int, np.ndarray] = {}
    with open_video(folder / truth["video"]) as src:
        for k, planes in src.iter_planes(min(need), max(need) + 1):
            if k in need:
                kept[k] = planes.y.copy()
    out: dict[str, list] = {}
    for k in sorted(wanted):
        y = kept[k]
        fans = {laser.name: renderer.laser_points(laser, k) for laser in rig.lasers}
        for laser in rig.lasers:
            uv, pts = fans[laser.name].uv_px, fans[laser.name].points_rail_mm
            order = np.argsort(uv[:, 0])
            uv, pts = uv[order], pts[order]
            other = np.concatenate([fans[o.name].uv_px for o in rig.lasers
                                    if o.name != laser.name] or [np.zeros((0, 2))])
            for c in range(2, y.shape[1] - 2, 3):
                i = int(np.searchsorted(uv[:, 0], c))
                if i == 0 or i >= len(uv):
                    continue
                u0, u1 = uv[i - 1, 0], uv[i, 0]
                if u1 - u0 > 0.5 or abs(uv[i, 1] - uv[i - 1, 1]) > 0.5:
                    continue
                if np.abs(np.diff(uv[max(i - 12, 0): i + 12, 1])).max() > 0.5:
                    continue  # near an occlusion edge
                f = (c - u0) / max(u1 - u0, 1e-9)
                v = uv[i - 1, 1] + f * (uv[i, 1] - uv[i - 1, 1])
                if not K + 2 < v < y.shape[0] - K - 2:
                    continue
                r0 = int(round(v)) - K
                bg = (_background(kept, project, pts[i - 1] + f * (pts[i] - pts[i - 1]), k, j,
                                  v, r0, other) if background else None)
                out.setdefault(laser.name, []).append((v - r0, y[r0:r0 + 2 * K + 1, c].copy(),
                                                       bg))
    return {name: (np.array([a for a, _, _ in d]), np.array([b for _, b, _ in d]),
                   np.array([g if g is not None else np.full(2 * K + 1, np.nan)
                             for _, _, g in d]))
            for name, d in out.items()}


def _background(kept: dict, project, p: np.ndarray, k: int, j: int, v: float, r0: int,
                other: np.ndarray) -> np.ndarray | None:
    """The column cut (rows ``r0`` .. ``r0 + 2K``) of the soil under the stripe as frames
    ``k - j`` or ``k + j`` (and ``BG_FRAMES`` either side) saw it, bilinear, averaged; the side
    whose cut lies farther from the other laser's stripe; None where it leaves the picture."""
    import cv2

    clear = []
    for sign in (-1, 1):
        u, vb = project(p[None], k + sign * j)[0]
        near = other[np.abs(other[:, 0] - u) < 2.0, 1] if len(other) else np.zeros(0)
        clear.append(float(np.min(np.abs(near - vb))) if near.size else np.inf)
    at = k + (j if clear[1] > clear[0] else -j)
    cuts = []
    for kk in range(at - BG_FRAMES, at + BG_FRAMES + 1):
        if kk not in kept:
            continue
        y = kept[kk]
        u, vb = project(p[None], kk)[0]
        rows = (vb - v + np.arange(r0, r0 + 2 * K + 1)).astype(np.float32)
        if rows.min() < 1 or rows.max() > y.shape[0] - 2 or not 1 < u < y.shape[1] - 2:
            continue
        cols = np.full(rows.shape, u, np.float32)
        cuts.append(cv2.remap(y, cols[None, :], rows[None, :], cv2.INTER_LINEAR)[0].astype(float))
    return np.mean(cuts, axis=0) if cuts else None


def subtracted(cut: np.ndarray, bg: np.ndarray, weight: float = 1.0,
               divide: bool = False) -> np.ndarray:
    """The luma minus the background (``weight`` of its texture, as the product's
    ``unlit.texture_weighted``), the clipped core (the run of rows >= ``CLIP`` through the
    middle row, as the product's ``unlit.clipped_core``) at the difference's top.
    ``divide``: the difference also divided by the background (all of it) over its mean on
    the 7 middle rows, at least 0.2: a stripe whose light follows the soil's albedo row by
    row (``--divide``; not the product's)."""
    from impress_gui.core.reconstruction.unlit import clipped_core, texture_weighted

    full = bg
    if weight != 1.0:
        bg = texture_weighted(bg, weight)
    d = cut.astype(float) - bg
    if divide:
        m = full.shape[1] // 2
        with np.errstate(invalid="ignore", divide="ignore"):  # a cut with no soil: NaN
            norm = full / np.mean(full[:, m - 3:m + 4], axis=1, keepdims=True)
        d = d / np.maximum(norm, 0.2)
    top = np.nanmax(d, axis=1, keepdims=True)
    d = np.where(clipped_core(cut, cut.shape[1] // 2, CLIP), top, d)
    return d - np.nanmin(d, axis=1, keepdims=True)


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
    ap.add_argument("--background", action="store_true",
                    help="also the window estimate on the luma minus the motion-compensated "
                    "background (the soil under the stripe seen unlit in other frames)")
    ap.add_argument("--texture-weights", default="1",
                    help="with --background: the shares of the unlit soil's texture taken out, "
                    "comma-separated (one bg-sub column each)")
    ap.add_argument("--divide", action="store_true",
                    help="with --background: also each bg-sub estimate with the difference "
                    "divided by the unlit soil (a stripe whose light follows the soil)")
    ap.add_argument("--folder", action="append", default=[], type=Path,
                    help="another scan folder with truth.json (e.g. a test's cached render); "
                    "repeatable")
    ap.add_argument("--stripe-follows-soil", action="store_true",
                    help="rigs rendered with each stripe pixel's light following the soil it "
                    "sees (impress simulate --stripe-follows-soil; cached apart)")
    args = ap.parse_args()
    shoe = CACHE / f"shoe-1080p-{common.SIM_KEY}"  # this simulator's render
    if args.cache_key:
        common.SIM_KEY = R.SIM_KEY = args.cache_key
    R.STRIPE_FOLLOWS_SOIL = args.stripe_follows_soil
    w, h = (int(v) for v in args.resolution.split("x"))
    scans = [(f"rig {s}", R.scan_for(int(s), w, h)) for s in args.seeds.split(",") if s]
    if args.shoe:
        scans.append(("shoe 1080p", shoe))
    scans += [(f.name[:12], f) for f in args.folder]
    weights = [float(x) for x in args.texture_weights.split(",") if x]
    subs = {(f"bg-sub {wt:g}" if len(weights) > 1 else "bg-sub"): (wt, False) for wt in weights}
    if args.divide:
        subs.update({(f"bg-div {wt:g}" if len(weights) > 1 else "bg-div"): (wt, True)
                     for wt in weights})
    names = ("half-max", "window", "uncapped") + (tuple(subs) if args.background else ())
    print(f"{'scan':12s} {'laser':6s} {'cols':>5s} " + " ".join(f"{n + ' rms':>13s}" for n in names)
          + "   " + " ".join(f"{n + ' lock':>14s}" for n in names)
          + ("   window >1px " + " ".join(f"{n + ' >1px':>12s}" for n in subs)
             if args.background else ""))
    rms_all: dict[str, list[float]] = {n: [] for n in names}
    for label, folder in scans:
        if not (folder / "truth.json").exists():
            print(f"{label}: no render at {folder}")
            continue
        for laser, (v, cut, bg) in sorted(columns(folder, args.frames, args.background).items()):
            est = estimates(cut)
            good = est["_top"] >= 25  # the detector's minimum peak
            extra = ""
            if args.background:
                good &= np.isfinite(bg).all(axis=1)
                for n, (wt, div) in subs.items():
                    est[n] = estimates(subtracted(cut, np.nan_to_num(bg), wt, div))["window"]
                extra = "   " + " ".join(
                    f"{100 * np.mean(np.abs(est[n] - v)[good] > 1):10.1f} %"
                    for n in ("window", *subs))
            rows = [figures((est[n] - v)[good], v[good]) for n in names]
            for n, (r, _) in zip(names, rows, strict=True):
                rms_all[n].append(r)
            print(f"{label:12s} {laser:6s} {int(good.sum()):5d} "
                  + " ".join(f"{r:13.3f}" for r, _ in rows) + "   "
                  + " ".join(f"{a:14.3f}" for _, a in rows) + extra, flush=True)
    for what, fn in (("median", np.median), ("worst", np.max)):
        print(f"{what:12s} {'':6s} {'':5s} " + " ".join(f"{fn(rms_all[n]):13.3f}" for n in names))


if __name__ == "__main__":
    main()
