"""Reading a simulated scan's ground truth back, for comparisons with reconstructions."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def truth_on_grid(scan_dir: Path, spec) -> np.ndarray:
    """The true heightmap (mm) resampled (nearest cell) onto a reconstruction grid ``spec``.

    The truth's rail frame has its origin at the camera of frame 0, a reconstruction's at the
    camera of calibration frame t1: ``y_truth = y_reconstruction + travel_mm[t1]``."""
    import tifffile

    scan_dir = Path(scan_dir)
    truth = json.loads((scan_dir / "truth.json").read_text())
    th = tifffile.imread(scan_dir / truth["heightmap"]["file"])
    hm = truth["heightmap"]
    s1 = truth["travel_mm"][truth["calibration_frames"]["t1"]]
    jj = np.rint((spec.xs() - hm["x0_mm"]) / hm["pixel_mm"]).astype(int)
    ii = np.rint((spec.ys() + s1 - hm["y0_mm"]) / hm["pixel_mm"]).astype(int)
    okj = (jj >= 0) & (jj < th.shape[1])
    oki = (ii >= 0) & (ii < th.shape[0])
    out = np.full(spec.shape, np.nan, np.float32)
    out[np.ix_(oki, okj)] = th[np.ix_(ii[oki], jj[okj])]
    return out
