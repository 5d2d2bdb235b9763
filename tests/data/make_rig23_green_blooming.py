"""Makes rig23_green_blooming.npz (tests/test_other_band.py) from the benchmark's cached render
of random rig 23 at 640x360 (simulator key 95a603848f): a green stripe blooming white (255, 255,
236) on warm soil, which the red detector took in a few columns of every frame when the two
lasers' regions of interest were no longer split and only the halo's lean was judged. Of frames
60-500 (every 10th), the frame where the red detector with the halo-only rule (as it still
applies where the other laser's band is unknown) takes most of the green stripe, cropped around
it (full rows 150-250), with the renderer's exact stripe rows per column.

Run from the repository: .venv/bin/python tests/data/make_rig23_green_blooming.py OUT.npz"""

from __future__ import annotations

import json
import sys

import numpy as np

sys.path.insert(0, "benchmarks")
import bench_random_rigs as R  # noqa: E402
import common  # noqa: E402

from impress_gui.core.formats.video import open_video  # noqa: E402
from impress_gui.core.reconstruction.stripes import StripeParams, detect_planes  # noqa: E402
from impress_gui.sim.simulate import SimConfig, _make_renderer  # noqa: E402

KEY = "95a603848f"
common.SIM_KEY = R.SIM_KEY = KEY
R0, R1 = 150, 250


def main(out: str) -> None:
    w, h = 640, 360
    d = R.scan_for(23, w, h)
    t = json.loads((d / "truth.json").read_text())
    renderer, _ = _make_renderer(SimConfig(**t["config"]))
    start = np.full(w, R0, np.int64)
    best = None
    with open_video(d / t["video"]) as src:
        for k, pl in src.iter_planes(60, 501):
            if k % 10:
                continue
            truth = {}
            for laser in renderer.rig.lasers:
                uv = renderer.laser_points(laser, k).uv_px
                v = np.full(w, np.nan)
                c = np.rint(uv[:, 0]).astype(int)
                ok = (c >= 0) & (c < w)
                v[c[ok]] = uv[ok, 1]
                truth[laser.name] = v
            old = detect_planes("red", pl, start, R1 - R0, StripeParams(), None, None).rows
            taken = np.abs(old - truth["green"]) < 2
            if taken.sum() and (best is None or taken.sum() > best[0]):
                best = (taken.sum(), k, np.flatnonzero(taken), truth, pl)
    n, k, cols, truth, pl = best
    c0 = max(0, (cols.min() - 20) // 2 * 2)
    c1 = min(w, c0 + 240)
    np.savez_compressed(out, y=pl.y[R0:R1, c0:c1], cb=pl.cb[R0 // 2:R1 // 2, c0 // 2:c1 // 2],
                        cr=pl.cr[R0 // 2:R1 // 2, c0 // 2:c1 // 2],
                        green_rows=truth["green"][c0:c1] - R0, red_rows=truth["red"][c0:c1] - R0,
                        frame=k, origin=(R0, c0))
    print("frame", k, "taken", n, "rows", R0, R1, "columns", c0, c1)


if __name__ == "__main__":
    main(sys.argv[1])
