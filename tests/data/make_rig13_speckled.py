"""Makes rig13_red_speckled.npz (tests/test_guided.py) from the benchmark's cached render of
random rig 13 at 640x360 (simulator key c757d6f4f7): bright, speckled, reddish soil on which a
piece of soil outscores the thin red stripe in about 8 % of its columns. Two frames, each
cropped to the red laser's band over the 256 columns where the detector without the guided
pass picked most rows more than 5 px off the stripe, with the renderer's exact red stripe rows
per column and both lasers' bands in crop rows.

Run from the repository: .venv/bin/python tests/data/make_rig13_speckled.py OUT.npz"""

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
FRAMES = (100, 200)
COLS = 256


def main(out: str) -> None:
    w, h = 640, 360
    d = R.scan_for(13, w, h)
    t = json.loads((d / "truth.json").read_text())
    renderer, _ = _make_renderer(SimConfig(**t["config"]))
    bands = column_bands(common.calibrate(d), (w, h), ProcessParams().height_range_mm)
    (rs, rh), (gs, gh) = bands["red"], bands["green"]
    arrays: dict[str, list] = {}
    with open_video(d / t["video"]) as src:
        for k, pl in src.iter_planes(min(FRAMES), max(FRAMES) + 1):
            if k not in FRAMES:
                continue
            laser = next(las for las in renderer.rig.lasers if las.name == "red")
            uv = renderer.laser_points(laser, k).uv_px
            uv = uv[np.argsort(uv[:, 0])]
            exact = np.interp(np.arange(w), uv[:, 0], uv[:, 1], left=np.nan, right=np.nan)
            rows = detect_planes("red", pl, rs, rh, StripeParams(guided=False), None,
                                 bands["green"]).rows
            gross = (np.abs(rows - exact) > 5).astype(float)
            c0 = int(np.argmax(np.convolve(gross, np.ones(COLS), "valid"))) // 2 * 2
            c1 = c0 + COLS
            r0 = int(rs[c0:c1].min()) // 2 * 2
            r1 = min(h, int(rs[c0:c1].max()) + rh + 1)
            r1 -= (r1 - r0) % 2
            arrays.setdefault("y", []).append(pl.y[r0:r1, c0:c1])
            arrays.setdefault("cb", []).append(pl.cb[r0 // 2:r1 // 2, c0 // 2:c1 // 2])
            arrays.setdefault("cr", []).append(pl.cr[r0 // 2:r1 // 2, c0 // 2:c1 // 2])
            arrays.setdefault("red_rows", []).append(exact[c0:c1] - r0)
            arrays.setdefault("band_start", []).append(rs[c0:c1] - r0)
            arrays.setdefault("other_start", []).append(gs[c0:c1] - r0)
            arrays.setdefault("origin", []).append((k, r0, c0))
            print("frame", k, "rows", r0, r1, "columns", c0, c1, "gross", int(gross[c0:c1].sum()))
    # one set of arrays per frame (the crops differ in height): y_0, cb_0, ... y_1, ...
    np.savez_compressed(out, **{f"{key}_{i}": np.asarray(a) for key, v in arrays.items()
                                for i, a in enumerate(v)},
                        band_height=rh, other_height=gh, n_frames=len(arrays["y"]))

if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "rig13_red_speckled.npz")
