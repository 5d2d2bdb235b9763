"""Comparison acceptance (issue 20) on rendered scans, at a chosen resolution.

Three scans of the same shoe (the sole's nicks from one seed), each with its own pose, rig and
render seed, rendered, calibrated from the simulator's exact picks and reconstructed on the
0.1 mm grid (cached under benchmarks/.cache per version of the simulator and resolution;
remove a scan's ``recon`` folder to calibrate and process the kept render again, after a change
to the calibration or the reconstruction):

- A: the shoe as the preset places it (roll 1.2, tilt -1.8, standoff 300, seed 1);
- B: turned 20 deg and shifted (12, -8) mm (roll -0.5, tilt 1.0, standoff 320, seed 2);
- C: turned -12 deg and shifted (-6, 5) mm, with the cut 0.5 mm deep and 3 mm long (roll 0.8,
  tilt -1.0, standoff 290, seed 3).

Then ``impress compare``: A with B (residual RMS, 95th percentile of |A - B| over the overlap,
the recovered turn), A with C (the region at the cut: its depth and length against the truth),
and A with B's outsole (B's map inverted and mirrored, compared with --mirror --invert).

The difference is measured along A's surface normal (``impress compare``'s default); with
``--metric vertical`` as the height difference. For each pair the 95th percentile of |A - B| is
also split by A's slope (flats: |grad A| < 0.2; walls: |grad A| > 1).

Usage: .venv/bin/python benchmarks/bench_compare.py [--resolution 1920x1080] [--speed 13.138]
       [--metric normal|vertical] [--cache-key KEY]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from common import CACHE, ROOT, SIM_KEY

SCANS = {
    "a": ["--seed", "1"],
    "b": ["--seed", "2", "--sole-seed", "1", "--shoe-rotate", "20", "--shoe-shift-mm=12,-8",
          "--roll", "-0.5", "--tilt", "1.0", "--standoff-mm", "320"],
    "c": ["--seed", "3", "--sole-seed", "1", "--shoe-rotate", "-12", "--shoe-shift-mm=-6,5",
          "--cut", "--roll", "0.8", "--tilt", "-1.0", "--standoff-mm", "290"],
}
CUT = {"x_mm": 15.0, "y_mm": 230.0, "depth_mm": 0.5, "length_mm": 3.0}  # sim.scenes.ShoeCut()


def impress(*args: str) -> str:
    res = subprocess.run([sys.executable, "-m", "impress_gui", *args], capture_output=True,
                         text=True, cwd=ROOT)
    if res.returncode != 0:
        raise SystemExit(f"impress {' '.join(args)} failed:\n{res.stderr[-3000:]}")
    return res.stdout


def scan_and_recon(name: str, resolution: str, speed: str,
                   sim_key: str = SIM_KEY) -> tuple[Path, Path]:
    key = hashlib.sha256(" ".join([resolution, speed, *SCANS[name]]).encode()).hexdigest()[:8]
    folder = CACHE / f"compare-{name}-{resolution}-{sim_key}-{key}"
    scan, recon = folder / "scan", folder / "recon"
    if not (recon / "metadata.json").exists():
        t0 = time.perf_counter()
        if not (scan / "truth.json").exists():  # a kept render is only processed again
            print(f"[rendering {name} at {resolution}]", flush=True)
            impress("simulate", str(scan), "--resolution", resolution, "--speed", speed,
                    *SCANS[name])
        impress("calibrate", str(scan / "scan.mp4"), "--intrinsics",
                str(scan / "intrinsics.json"), "--picks", str(scan / "picks.json"), "--speed",
                speed, "-o", str(folder / "cal.json"))
        impress("process", str(scan / "scan.mp4"), "--calibration", str(folder / "cal.json"),
                "-o", str(recon))
        print(f"[{name}: {time.perf_counter() - t0:.0f} s]", flush=True)
    return scan, recon


def outsole_folder(recon: Path, out: Path) -> Path:
    """B's map inverted (z -> -z) and mirrored (x -> -x), as a reconstruction folder."""
    import tifffile

    meta = json.loads((recon / "metadata.json").read_text())
    h = tifffile.imread(recon / "heightmap.tif")
    g = dict(meta["grid"])
    g["x0_mm"] = -(g["x0_mm"] + (h.shape[1] - 1) * g["pixel_mm"])
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    tifffile.imwrite(out / "heightmap.tif", np.ascontiguousarray(-h[:, ::-1]))
    sha = hashlib.sha256((out / "heightmap.tif").read_bytes()).hexdigest()
    doc = {"format": "impress.reconstruction", "version": 1, "software": "bench_compare",
           "grid": g, "inputs": meta.get("inputs", {}), "files": {"heightmap.tif": sha}}
    (out / "metadata.json").write_text(json.dumps(doc, indent=2))
    return out


def compare(a: Path, b: Path, out: Path, *extra: str) -> tuple[dict, float]:
    t0 = time.perf_counter()
    impress("compare", str(a), str(b), "-o", str(out), *extra)
    return json.loads((out / "compare.json").read_text()), time.perf_counter() - t0


def by_slope(out: Path) -> None:
    """The 95th percentile of |A - B| on A's flats and walls, and the walls' share of the
    cells above the whole map's 95th percentile."""
    import tifffile

    from impress_gui.core.compare.difference import slope
    from impress_gui.core.compare.surfaces import Surface

    a = tifffile.imread(out / "a.tif")
    v = np.abs(tifffile.imread(out / "difference.tif").astype(np.float64))
    px = json.loads((out / "compare.json").read_text())["grid"]["pixel_mm"]
    g = slope(Surface(a, 0.0, 0.0, px, -px))
    ok = np.isfinite(v) & np.isfinite(g)
    v, g = v[ok], g[ok]
    p95 = np.percentile(v, 95)
    flat, wall = g < 0.2, g > 1.0
    print(f"{'':<22s} flats ({flat.mean():.0%} of cells) p95 {np.percentile(v[flat], 95):.4f}, "
          f"walls ({wall.mean():.0%}) p95 {np.percentile(v[wall], 95):.4f}; the walls hold "
          f"{(wall & (v > p95)).sum() / max(1, (v > p95).sum()):.0%} of the cells above the p95")


def s1(scan: Path) -> float:
    t = json.loads((scan / "truth.json").read_text())
    return t["travel_mm"][t["calibration_frames"]["t1"]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--resolution", default="1920x1080")
    ap.add_argument("--speed", default="13.138")
    ap.add_argument("--metric", default="normal", choices=("normal", "vertical"))
    ap.add_argument("--cache-key", default=SIM_KEY,
                    help="the simulator key of cached renders to use (default: this simulator's)")
    args = ap.parse_args()
    runs = {n: scan_and_recon(n, args.resolution, args.speed, args.cache_key) for n in SCANS}
    work = CACHE / f"compare-out-{args.resolution}" / args.metric
    work.mkdir(parents=True, exist_ok=True)
    (scan_a, rec_a), (_, rec_b), (_, rec_c) = runs["a"], runs["b"], runs["c"]
    print(f"\nimpress compare at {args.resolution}, speed {args.speed} mm/s, grid 0.1 mm, "
          f"--metric {args.metric}")
    print(f"{'pair':<22s} {'turn deg':>9s} {'RMS mm':>8s} {'p95 mm':>8s} {'overlap':>8s} "
          f"{'time s':>7s}")
    rows = [("A-B", rec_b, (), 20.0), ("A-C (cut)", rec_c, (), -12.0),
            ("A-outsole(B) mir+inv", outsole_folder(rec_b, work / "outsole-b"),
             ("--mirror", "--invert"), 20.0)]
    docs = {}
    for label, other, extra, turn in rows:
        doc, dt = compare(rec_a, other, work / label.split()[0].replace("(", ""), *extra,
                          "--metric", args.metric)
        docs[label] = doc
        r, d = doc["registration"], doc["difference"]
        print(f"{label:<22s} {r['rotation_about_z_deg']:9.4f} {r['residual_rms_mm']:8.4f} "
              f"{d['p95_abs_mm']:8.4f} {r['overlap']:8.3f} {dt:7.1f}   (true turn {turn:+g})")
        by_slope(work / label.split()[0].replace("(", ""))
    # the cut: in A's export frame (A is unposed: the shoe's frame is A's rail frame)
    cx, cy = CUT["x_mm"], -(CUT["y_mm"] - s1(scan_a))
    items = docs["A-C (cut)"]["regions"]["items"]
    near = sorted(items, key=lambda r: np.hypot(r["centroid_mm"][0] - cx,
                                                 r["centroid_mm"][1] - cy))
    if near and np.hypot(near[0]["centroid_mm"][0] - cx, near[0]["centroid_mm"][1] - cy) < 2.0:
        c = near[0]
        print(f"\ncut: region at ({c['centroid_mm'][0]:.2f}, {c['centroid_mm'][1]:.2f}) "
              f"(truth ({cx:.2f}, {cy:.2f})): depth {c['max_depth_mm']:.3f} mm (error "
              f"{c['max_depth_mm'] - CUT['depth_mm']:+.3f}), p90 depth {c['depth_p90_mm']:.3f}, "
              f"length {c['length_mm']:.2f} mm (error {c['length_mm'] - CUT['length_mm']:+.2f}), "
              f"area {c['area_mm2']:.2f} mm2")
    else:
        print(f"\ncut: no region beyond the threshold within 2 mm of ({cx:.2f}, {cy:.2f})")
    # the difference itself around the cut, whatever the threshold
    import tifffile

    out = work / "A-C"
    g = docs["A-C (cut)"]["grid"]
    diff = tifffile.imread(out / "difference.tif")
    ii, jj = np.nonzero(np.isfinite(diff))
    x = g["x0_mm"] + jj * g["pixel_mm"]
    y = g["y0_mm"] + ii * g["y_step_mm"]
    near_cut = np.hypot(x - cx, y - cy) <= CUT["length_mm"] / 2 + 0.5
    if near_cut.any():
        v = diff[ii[near_cut], jj[near_cut]]
        print(f"cut: the most negative A - B within {CUT['length_mm'] / 2 + 0.5:g} mm of its "
              f"centre {v.min():+.3f} mm (truth {-CUT['depth_mm']:+.3f}: B has the ridge)")
    print("acceptance (issue 20): RMS <= 0.03 mm, p95 <= 0.06 mm; cut depth within 0.05 mm, "
          "length within 0.2 mm")


if __name__ == "__main__":
    main()
