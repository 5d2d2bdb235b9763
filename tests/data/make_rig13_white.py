"""Makes rig13_green_white.npz (tests/test_white_core.py) from the benchmark's cached render of
random rig 13 at 1920x1080 (simulator key c757d6f4f7): bright, speckled soil on which both
stripes saturate to nearly the same white, (255, 255, 230), and only their faint halo is
tinted. One frame, cropped to the green laser's band over the 256 columns where the detector
without the white-core rule missed most columns, with the renderer's exact green stripe rows
per column and both lasers' bands in crop rows.

Run from the repository: .venv/bin/python tests/data/make_rig13_white.py OUT.npz"""

from __future__ import annotations

import json
import sys

import numpy as np

sys.path.insert(0, "benchmarks")
import bench_random_rigs as R  # noqa: E402
import common  # noqa: E402

from impress_gui.core.formats.video import open_video  # noqa: E402
from impress_gui.core.reconstruction.reconstruct import ProcessParams, column_bands  # noqa: E402
from impress_gui.core.reconstruction.stripes import StripeParams, detect_planes  # noqa: E402
from impress_gui.sim.simulate import SimConfig, _make_renderer  # noqa: E402

KEY = "c757d6f4f7"
common.SIM_KEY = R.SIM_KEY = KEY
FRAME = 150
COLS = 256


def main(out: str) -> None:
    w, h = 1920, 1080
    d = R.scan_for(13, w, h)
    t = json.loads((d / "truth.json").read_text())
    renderer, _ = _make_renderer(SimConfig(**t["config"]))
    bands = column_bands(common.calibrate(d), (w, h), ProcessParams().height_range_mm)
    (gs, gh), (rs, rh) = bands["green"], bands["red"]
    with open_video(d / t["video"]) as src:
        for k, pl in src.iter_planes(FRAME, FRAME + 1):
            laser = next(las for las in renderer.rig.lasers if las.name == "green")
            uv = renderer.laser_points(laser, k).uv_px
            uv = uv[np.argsort(uv[:, 0])]
            exact = np.interp(np.arange(w), uv[:, 0], uv[:, 1], left=np.nan, right=np.nan)
            rows = detect_planes("green", pl, gs, gh, StripeParams(white_core=False), None,
                                 bands["red"]).rows
            missed = (np.isfinite(exact) & ~(np.abs(rows - exact) <= 1.0)).astype(float)
            c0 = int(np.argmax(np.convolve(missed, np.ones(COLS), "valid"))) // 2 * 2
            c1 = c0 + COLS
            r0 = int(gs[c0:c1].min()) // 2 * 2
            r1 = min(h, int(gs[c0:c1].max()) + gh + 1)
            r1 -= (r1 - r0) % 2
            np.savez_compressed(
                out, y=pl.y[r0:r1, c0:c1], cb=pl.cb[r0 // 2:r1 // 2, c0 // 2:c1 // 2],
                cr=pl.cr[r0 // 2:r1 // 2, c0 // 2:c1 // 2], green_rows=exact[c0:c1] - r0,
                band_start=gs[c0:c1] - r0, band_height=gh, other_start=rs[c0:c1] - r0,
                other_height=rh, origin=(k, r0, c0))
            print("frame", k, "rows", r0, r1, "columns", c0, c1, "missed",
                  int(missed[c0:c1].sum()))


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "rig13_green_white.npz")
