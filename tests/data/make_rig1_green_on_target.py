"""Makes rig1_green_on_target.npz (tests/test_other_band.py) from the benchmark's cached render
of random rig 1 at 640x360 (simulator key 95a603848f): the frame where the red detector with the
former lean rule took most of the green stripe, cropped around it, with the renderer's exact
stripe rows per column. Made with the detector of commit 9cab477; since the lean in the other
laser's band is the lean of all the stripe's light, ``min_lean_in_other_band=-4.0`` no longer
reproduces the former rule and this script finds no such frame.

Run from the repository: .venv/bin/python tests/data/make_rig1_green_on_target.py OUT.npz"""

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

KEY = "95a603848f"
common.SIM_KEY = R.SIM_KEY = KEY


def main(out: str) -> None:
    w, h = 640, 360
    d = R.scan_for(1, w, h)
    t = json.loads((d / "truth.json").read_text())
    renderer, _ = _make_renderer(SimConfig(**t["config"]))
    bands = column_bands(common.calibrate(d), (w, h), ProcessParams().height_range_mm)
    best = None
    with open_video(d / t["video"]) as src:
        for k, pl in src.iter_planes(90, 160):
            truth = {}
            for laser in renderer.rig.lasers:
                uv = renderer.laser_points(laser, k).uv_px
                v = np.full(w, np.nan)
                c = np.rint(uv[:, 0]).astype(int)
                ok = (c >= 0) & (c < w)
                v[c[ok]] = uv[ok, 1]
                truth[laser.name] = v
            old = detect_planes("red", pl, *bands["red"], StripeParams(min_lean_in_other_band=-4.0),
                                None, bands["green"]).rows
            taken = np.abs(old - truth["green"]) < 2
            if taken.sum() and (best is None or taken.sum() > best[0]):
                best = (taken.sum(), k, np.flatnonzero(taken), truth, pl, old)
    _, k, cols, truth, pl, old = best
    c0 = max(0, (cols.min() - 40) // 2 * 2)
    c1 = min(w, c0 + 240)
    r0 = (int(np.nanmedian(old[cols])) - 30) // 2 * 2
    r1 = r0 + 60
    np.savez_compressed(out, y=pl.y[r0:r1, c0:c1], cb=pl.cb[r0 // 2:r1 // 2, c0 // 2:c1 // 2],
                        cr=pl.cr[r0 // 2:r1 // 2, c0 // 2:c1 // 2],
                        green_rows=truth["green"][c0:c1] - r0, red_rows=truth["red"][c0:c1] - r0,
                        frame=k, origin=(r0, c0))
    print("frame", k, "rows", r0, r1, "columns", c0, c1)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "rig1_green_on_target.npz")
