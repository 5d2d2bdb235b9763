"""Makes rig102_green_overlap.npz (tests/test_own_rows.py) from the benchmark's cached render
of random rig 102 at 1920x1080 (simulator key d323efdba0): near-white soil, both lasers
blooming and both mounted behind the camera, so the red stripe on the ground lies inside the
green laser's band (where a green stripe on a surface 55-61 mm high would be). Their cores are
the same white and the chroma of a thin stripe is the soil's: the green detector took the red
stripe in part of its columns. One frame (the one where it did so most, among every fifth),
cropped to the green band over the 256 columns where it did so most, with the renderer's exact
green rows, both lasers' bands and the green stripe's row on the ground, in crop rows.

Run from the repository: .venv/bin/python tests/data/make_rig102_overlap.py OUT.npz"""

from __future__ import annotations

import json
import sys

import numpy as np

sys.path.insert(0, "benchmarks")
import bench_random_rigs as R  # noqa: E402
import common  # noqa: E402

from impress_gui.core.formats.video import open_video  # noqa: E402
from impress_gui.core.reconstruction.reconstruct import (  # noqa: E402
    ProcessParams,
    column_bands,
    ground_rows,
)
from impress_gui.core.reconstruction.stripes import StripeParams, detect_planes  # noqa: E402
from impress_gui.sim.simulate import SimConfig, _make_renderer  # noqa: E402

KEY = "d323efdba0"
common.SIM_KEY = R.SIM_KEY = KEY
COLS = 256


def main(out: str) -> None:
    w, h = 1920, 1080
    d = R.scan_for(102, w, h)
    t = json.loads((d / "truth.json").read_text())
    renderer, _ = _make_renderer(SimConfig(**t["config"]))
    cal = common.calibrate(d)
    bands = column_bands(cal, (w, h), ProcessParams().height_range_mm)
    ground = ground_rows(cal, (w, h))["green"]
    (gs, gh), (rs, rh) = bands["green"], bands["red"]
    laser = next(las for las in renderer.rig.lasers if las.name == "green")
    best = (-1, None)
    with open_video(d / t["video"]) as src:
        for k, pl in src.iter_planes(0, src.frame_count):
            if k % 5:
                continue
            uv = renderer.laser_points(laser, k).uv_px
            if len(uv) < 2:
                continue
            uv = uv[np.argsort(uv[:, 0])]
            exact = np.interp(np.arange(w), uv[:, 0], uv[:, 1], left=np.nan, right=np.nan)
            rows = detect_planes("green", pl, gs, gh, StripeParams(), None, bands["red"]).rows
            wrong = (np.isfinite(exact) & (np.abs(rows - exact) > 20)).astype(float)
            run = np.convolve(wrong, np.ones(COLS), "valid")
            c0 = int(np.argmax(run)) // 2 * 2
            if run[c0] > best[0]:
                best = (run[c0], (k, pl, exact, c0))
    n, (k, pl, exact, c0) = best
    c1 = c0 + COLS
    r0 = int(gs[c0:c1].min()) // 2 * 2
    r1 = min(h, int(gs[c0:c1].max()) + gh + 1)
    r1 -= (r1 - r0) % 2
    np.savez_compressed(
        out, y=pl.y[r0:r1, c0:c1], cb=pl.cb[r0 // 2:r1 // 2, c0 // 2:c1 // 2],
        cr=pl.cr[r0 // 2:r1 // 2, c0 // 2:c1 // 2], green_rows=exact[c0:c1] - r0,
        band_start=gs[c0:c1] - r0, band_height=gh, other_start=rs[c0:c1] - r0,
        other_height=rh, ground=ground[c0:c1] - r0, origin=(k, r0, c0))
    print("frame", k, "rows", r0, r1, "columns", c0, c1, "taken off the stripe", int(n))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "rig102_green_overlap.npz")
