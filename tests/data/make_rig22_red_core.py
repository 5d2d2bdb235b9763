"""Makes rig22_red_core.npz (tests/test_faint_stripe.py) from the benchmark's cached render of
random rig 22 at 1920x1080 (simulator key c757d6f4f7): a crop of the frame where the
calibration, run with the faint rule of commit 1e5f195, took the red stripe's clipped core for
green light on the target's faces (the red channel clipped on 6 rows, green on 4; its tilt
refinement went 0.0045 -> 0.064 deg wrong), kept as decoded planes, with the renderer's exact
stripe rows per column.

Run from the repository: .venv/bin/python tests/data/make_rig22_red_core.py [FRAME] [OUT.npz]"""

from __future__ import annotations

import json
import sys

import numpy as np

sys.path.insert(0, "benchmarks")
import bench_random_rigs as R  # noqa: E402
import common  # noqa: E402

from impress_gui.core.formats.video import open_video  # noqa: E402
from impress_gui.sim.simulate import SimConfig, _make_renderer  # noqa: E402

KEY = "c757d6f4f7"
common.SIM_KEY = R.SIM_KEY = KEY
ROWS = (664, 744)
COLS = (580, 900)


def main(frame: int, out: str) -> None:
    w, h = 1920, 1080
    d = R.scan_for(22, w, h)
    t = json.loads((d / "truth.json").read_text())
    renderer, _ = _make_renderer(SimConfig(**t["config"]))
    (r0, r1), (c0, c1) = ROWS, COLS
    truth = {}
    for laser in renderer.rig.lasers:
        uv = renderer.laser_points(laser, frame).uv_px
        v = np.full(w, np.nan)
        c = np.rint(uv[:, 0]).astype(int)
        ok = (c >= 0) & (c < w) & (uv[:, 1] >= r0) & (uv[:, 1] < r1)
        v[c[ok]] = uv[ok, 1]
        truth[laser.name] = v[c0:c1] - r0
    with open_video(d / t["video"]) as src:
        (_, pl), = list(src.iter_planes(frame, frame + 1))
    np.savez_compressed(out, y=pl.y[r0:r1, c0:c1], cb=pl.cb[r0 // 2:r1 // 2, c0 // 2:c1 // 2],
                        cr=pl.cr[r0 // 2:r1 // 2, c0 // 2:c1 // 2], green_rows=truth["green"],
                        red_rows=truth["red"], frame=frame, origin=(r0, c0))


if __name__ == "__main__":
    main(int(sys.argv[1]), sys.argv[2] if len(sys.argv) > 2 else "rig22_red_core.npz")
