"""Makes rig214_red_dark.npz (tests/test_faint_stripe.py) from the benchmark's cached render of
random rig 214 at 1920x1080 (simulator key 190eb977a3): a crop of frame 200 around the red
stripe, a dim laser (power 0.72, a stripe 0.9 px wide) on dark, mottled soil (luma 30-60),
where the red channel rises from about 45 to 95 and never reaches the colour tests'
``min_value`` (the map's fill was 82.8 %), kept as decoded planes, with the renderer's exact
stripe rows per column.

Run from the repository: .venv/bin/python tests/data/make_rig214_dark.py [FRAME] [OUT.npz]"""

from __future__ import annotations

import json
import sys

import numpy as np

sys.path.insert(0, "benchmarks")
import bench_random_rigs as R  # noqa: E402
import common  # noqa: E402

from impress_gui.core.formats.video import open_video  # noqa: E402
from impress_gui.sim.simulate import SimConfig, _make_renderer  # noqa: E402

KEY = "190eb977a3"
COLS = (0, 960)


def main(frame: int, out: str, key: str = KEY, cols: tuple[int, int] = COLS) -> None:
    """Crop frame ``frame`` of rig 214's cached render (simulator key ``key``), image
    columns ``cols`` (even), around the red stripe; write ``out``."""
    common.SIM_KEY = R.SIM_KEY = key
    w, h = 1920, 1080
    d = R.scan_for(214, w, h)
    t = json.loads((d / "truth.json").read_text())
    renderer, _ = _make_renderer(SimConfig(**t["config"]))
    c0, c1 = cols
    truth = {}
    for laser in renderer.rig.lasers:
        uv = renderer.laser_points(laser, frame).uv_px
        v = np.full(w, np.nan)
        c = np.rint(uv[:, 0]).astype(int)
        ok = (c >= 0) & (c < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        v[c[ok]] = uv[ok, 1]
        truth[laser.name] = v[c0:c1]
    red = truth["red"][np.isfinite(truth["red"])]
    r0 = int(np.floor(red.min())) - 24
    r0 -= r0 % 2
    r1 = int(np.ceil(red.max())) + 26
    r1 += r1 % 2
    with open_video(d / t["video"]) as src:
        (_, pl), = list(src.iter_planes(frame, frame + 1))
    green = truth["green"] - r0
    green[(green < 0) | (green >= r1 - r0)] = np.nan
    np.savez_compressed(out, y=pl.y[r0:r1, c0:c1], cb=pl.cb[r0 // 2:r1 // 2, c0 // 2:c1 // 2],
                        cr=pl.cr[r0 // 2:r1 // 2, c0 // 2:c1 // 2], green_rows=green,
                        red_rows=truth["red"] - r0, frame=frame, origin=(r0, c0))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 200,
         sys.argv[2] if len(sys.argv) > 2 else "rig214_red_dark.npz")
