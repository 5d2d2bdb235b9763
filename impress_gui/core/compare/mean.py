"""A mean track: several registered impressions of one shoe averaged on the reference's grid.

Each map is resampled onto the reference's grid through its registration (see
:func:`~impress_gui.core.compare.difference.resample`); per cell the mean of the maps with data
there, their standard deviation (population, ``ddof = 0``: the spread of these impressions) and
their count. What stays from step to step has a small deviation; what changes (a stone, a
smear, a feature only one impression shows) stands out in it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from impress_gui.core.base import codes
from impress_gui.core.base.errors import InputError
from impress_gui.core.base.progress import CancelToken, ProgressCallback, report, sub_progress
from impress_gui.core.compare.difference import resample
from impress_gui.core.compare.surfaces import Surface


@dataclass(frozen=True)
class MeanTrack:
    """On ``grid`` (the reference's cells): ``mean_mm`` and ``std_mm`` float32 (NaN where no
    map has data), ``count`` uint8 (maps with data per cell)."""

    grid: Surface
    mean_mm: np.ndarray
    std_mm: np.ndarray
    count: np.ndarray

    def summary(self) -> dict:
        ok = self.count > 0
        full = self.count == self.count.max() if ok.any() else ok
        std = self.std_mm[full]
        std = std[np.isfinite(std)]
        return {"maps": int(self.count.max()) if ok.any() else 0,
                "cells_with_data": int(ok.sum()), "cells_in_every_map": int(full.sum()),
                "std_median_mm": round(float(np.median(std)), 6) if std.size else None,
                "std_p95_mm": round(float(np.percentile(std, 95)), 6) if std.size else None,
                "std_note": "population standard deviation (ddof 0) over the maps with data"}


def mean_track(reference: Surface, others: Sequence[tuple[Surface, np.ndarray]],
               progress: ProgressCallback | None = None,
               cancel: CancelToken | None = None) -> MeanTrack:
    """The mean track of ``reference`` and ``others`` (each with its 4 x 4 matrix onto the
    reference, from :func:`~impress_gui.core.compare.register.register`)."""
    if not others:
        raise InputError("a mean track needs at least two maps", code=codes.E_COMPARE_OPTION)
    if len(others) + 1 > 255:
        raise InputError("a mean track takes at most 255 maps", code=codes.E_COMPARE_OPTION)
    total = np.where(np.isfinite(reference.height_mm), reference.height_mm, 0.0).astype(
        np.float64)
    count = np.isfinite(reference.height_mm).astype(np.int32)
    maps = [reference.height_mm.astype(np.float32)]
    for k, (surface, matrix) in enumerate(others):
        part = sub_progress(progress, k / len(others), (k + 1) / len(others))
        report(part, 0.0, f"resampling map {k + 2} of {len(others) + 1}")
        # every cell of the reference's grid, also where the reference has no data (the
        # reference's height, else 0, is only the resampling's first guess)
        guess = np.where(np.isfinite(reference.height_mm), reference.height_mm, 0.0)
        filled = Surface(guess.astype(np.float32), reference.x0_mm, reference.y0_mm,
                         reference.pixel_mm, reference.y_step_mm)
        on = resample(filled, surface, matrix, cancel=cancel)
        ok = np.isfinite(on)
        total += np.where(ok, on, 0.0)
        count += ok
        maps.append(on)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / np.maximum(count, 1), np.nan)
        sq = np.zeros(reference.shape, np.float64)
        for m in maps:
            ok = np.isfinite(m)
            sq += np.where(ok, (np.where(ok, m, 0.0) - mean) ** 2, 0.0)
        std = np.where(count > 0, np.sqrt(sq / np.maximum(count, 1)), np.nan)
    report(progress, 1.0, "mean track ready")
    return MeanTrack(reference, mean.astype(np.float32), std.astype(np.float32),
                     count.astype(np.uint8))
