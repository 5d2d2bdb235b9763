"""Makes rig237_green_narrow.npz (tests/test_narrowed_look.py) from the benchmark's cached
render of random rig 237 at 1920x1080 (simulator key 02bad946fa): a rolled camera (roll 170
deg) whose slanted stripes make the red laser's band 612 rows high over the picture's first
columns, where the green stripe, blooming nearly white on greenish soil, lies 380 rows below
red's own stripe. One frame, cropped to rows 540-699 (a band of 160 rows holding the green
stripe) over the first 320 columns, with the renderer's exact green and red stripe rows per
column and the red laser's band, all in crop rows.

Run from the repository: .venv/bin/python tests/data/make_rig237_narrow.py OUT.npz"""

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
    column_band_limits,
    laser_rois,
)
from impress_gui.sim.simulate import SimConfig, _make_renderer  # noqa: E402

KEY = "02bad946fa"
common.SIM_KEY = R.SIM_KEY = KEY
FRAME = 100
COLS = 320
ROWS = (540, 700)


def main(out: str) -> None:
    w, h = 1920, 1080
    d = R.scan_for(237, w, h)
    t = json.loads((d / "truth.json").read_text())
    renderer, _ = _make_renderer(SimConfig(**t["config"]))
    cal = common.calibrate(d)
    # the red laser's band as the green detector knows it (reconstruct._own_band)
    hr = ProcessParams().height_range_mm
    lean = column_band_limits(cal, (w, h), hr, laser_rois(cal, (w, h), hr), unfolded=False)
    r_lo, r_hi = lean["red"]
    r0, r1 = ROWS
    exact = {}
    with open_video(d / t["video"]) as src:
        for k, pl in src.iter_planes(FRAME, FRAME + 1):
            for laser in renderer.rig.lasers:
                uv = renderer.laser_points(laser, k).uv_px
                uv = uv[np.argsort(uv[:, 0])]
                exact[laser.name] = np.interp(np.arange(w), uv[:, 0], uv[:, 1], left=np.nan,
                                              right=np.nan)
            np.savez_compressed(
                out, y=pl.y[r0:r1, :COLS], cb=pl.cb[r0 // 2:r1 // 2, :COLS // 2],
                cr=pl.cr[r0 // 2:r1 // 2, :COLS // 2],
                green_rows=exact["green"][:COLS] - r0, red_rows=exact["red"][:COLS] - r0,
                other_start=r_lo[:COLS] - r0, other_height=(r_hi - r_lo)[:COLS],
                origin=(k, r0, 0))
            print("frame", k, "rows", r0, r1, "columns", 0, COLS)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "rig237_green_narrow.npz")
