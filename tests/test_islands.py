"""Small islands of a laser's map - a few cells floating off the surface, where a detector
took soil or a reflection for its stripe - are dropped before fusion (issue 18: a point its
neighbours contradict is never fused); real surface pieces, however steep their sides, stay."""

import numpy as np
import pytest

from impress_gui.core.base.errors import InputError
from impress_gui.core.reconstruction.grid import drop_islands
from impress_gui.core.reconstruction.reconstruct import ProcessParams


def _surface(seed=3, rows=300, cols=260):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:rows, 0:cols].astype(np.float32)
    h = 0.002 * x + 0.3 * np.sin(y / 40.0) + rng.normal(0, 0.02, (rows, cols)).astype(np.float32)
    h = h.astype(np.float32)
    truth_islands = np.zeros(h.shape, bool)
    # a raised block 5 mm high, 20 x 20 cells (400 cells: a real feature, kept)
    h[40:60, 40:60] += 5.0
    # a narrow ridge 2 cells wide and 40 long, 3 mm high (80 cells, kept)
    h[100:140, 200:202] += 3.0
    # floating islands: 1, 7, 30 and 50 cells, 8-15 mm above (dropped)
    for (r, c, hh, ww, dz) in ((200, 30, 1, 1, 12.0), (210, 80, 1, 7, 8.0),
                               (220, 120, 5, 6, 15.0), (240, 160, 5, 10, 9.0)):
        h[r:r + hh, c:c + ww] += dz
        truth_islands[r:r + hh, c:c + ww] = True
    # an island of 51 cells: one more than the largest dropped (kept)
    h[270:273, 20:37] -= 6.0
    # a patch of 12 cells alone in a hole without data (nothing joins it: dropped)
    h[150:170, 100:130] = np.nan
    truth_islands[158:161, 110:114] = True
    h[158:161, 110:114] = 0.1
    return h, truth_islands


@pytest.mark.parametrize("block_rows", [1024, 37, 5])
def test_floating_islands_are_dropped_and_the_surface_kept(block_rows):
    h, islands = _surface()
    before = h.copy()
    n = drop_islands(h, 0.5, 50, block_rows=block_rows)
    assert n == int(islands.sum())
    assert np.all(np.isnan(h[islands]))
    keep = ~islands & np.isfinite(before)
    assert np.array_equal(h[keep], before[keep])  # nothing else touched, bit for bit
    assert np.isfinite(h[40:60, 40:60]).all() and np.isfinite(h[100:140, 200:202]).all()
    assert np.isfinite(h[270:273, 20:37]).all()


def test_blocks_give_the_whole_map_on_random_speckle():
    """Islands of every shape straddling block borders: blocks of 7 rows and the whole map at
    once drop the same cells."""
    rng = np.random.default_rng(11)
    h = rng.normal(0, 0.1, (400, 300)).astype(np.float32)
    spots = rng.random(h.shape) < 0.02
    h[spots] += rng.uniform(2, 20, int(spots.sum())).astype(np.float32)
    h[rng.random(h.shape) < 0.05] = np.nan
    a, b = h.copy(), h.copy()
    na = drop_islands(a, 0.5, 50, block_rows=7)
    nb = drop_islands(b, 0.5, 50, block_rows=10_000)
    assert na == nb > 1000
    assert np.array_equal(np.isnan(a), np.isnan(b))


def test_zero_keeps_everything_and_bad_parameters_are_refused():
    h, _ = _surface()
    before = h.copy()
    assert drop_islands(h, 0.5, 0) == 0
    assert np.array_equal(h, before, equal_nan=True)
    for kw in ({"island_max_cells": -1}, {"island_step_mm": 0.0}):
        with pytest.raises(InputError) as exc:
            ProcessParams(**kw).validate()
        assert exc.value.code == "E-PARAM"
