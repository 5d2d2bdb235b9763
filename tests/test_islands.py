"""Small islands of a laser's map - a few cells floating off the surface, where a detector
took soil or a reflection for its stripe - are dropped before fusion (issue 18: a point its
neighbours contradict is never fused); real surface pieces, however steep their sides, stay."""

import numpy as np
import pytest

from impress_gui.core.base.errors import InputError
from impress_gui.core.reconstruction.grid import drop_floating, drop_islands
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


def _shadowed(seed=5, rows=260, cols=240):
    """A ground with a hole no laser measured (a shadow, rows 60-160, columns 60-180) holding
    pieces of the laser's map 30-50 mm up, and real pieces among data."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:rows, 0:cols].astype(np.float32)
    g = (0.001 * x + 0.2 * np.sin(y / 30.0)
         + rng.normal(0, 0.02, (rows, cols))).astype(np.float32)
    g[60:160, 60:180] = np.nan
    r = g.copy()
    floating = np.zeros(g.shape, bool)
    # in the hole: pieces of 12, 120 and 300 cells, far from anything measured (dropped)
    for (r0, c0, hh, ww, dz) in ((80, 80, 3, 4, 40.0), (100, 120, 10, 12, 50.0),
                                 (125, 75, 15, 20, 30.0)):
        r[r0:r0 + hh, c0:c0 + ww] = dz + rng.normal(0, 0.02, (hh, ww))
        floating[r0:r0 + hh, c0:c0 + ww] = True
    # a piece of 441 cells in the hole: larger than the largest dropped (kept)
    r[66:87, 150:171] = 45.0
    # a ridge of 150 cells 3 mm up among the ground's data (kept: the ground surrounds it)
    r[200:250, 30:33] += 3.0
    return g, r, floating


@pytest.mark.parametrize("block_rows", [1024, 41, 7])
def test_pieces_floating_in_a_shadow_are_dropped(block_rows):
    g, r, floating = _shadowed()
    g0, r0 = g.copy(), r.copy()
    n = drop_floating([g, r], 0.5, 400, 20, 0.15, block_rows=block_rows)
    assert n == [0, int(floating.sum())]
    assert np.all(np.isnan(r[floating]))
    keep = ~floating & np.isfinite(r0)
    assert np.array_equal(r[keep], r0[keep])  # nothing else touched, bit for bit
    assert np.array_equal(g, g0, equal_nan=True)
    assert np.isfinite(r[66:87, 150:171]).all() and np.isfinite(r[200:250, 30:33]).all()


def test_the_other_lasers_data_around_a_piece_keeps_it():
    """Where the other laser measured around the piece, the piece is not alone: fusion
    weighs the two (the piece is not dropped here)."""
    g, r, floating = _shadowed()
    g[95:125, 110:145] = 0.1  # the green laser saw the ground around the 120-cell piece
    n = drop_floating([g, r], 0.5, 400, 20, 0.15)
    assert n[1] == int(floating.sum()) - 120
    assert np.isfinite(r[100:110, 120:132]).all()
    # the maps' order does not matter
    g2, r2, _ = _shadowed()
    g2[95:125, 110:145] = 0.1
    assert drop_floating([r2, g2], 0.5, 400, 20, 0.15) == n[::-1]
    assert np.array_equal(r2, r, equal_nan=True)


def test_floating_blocks_give_the_whole_map_on_random_speckle():
    rng = np.random.default_rng(12)
    h = rng.normal(0, 0.1, (500, 300)).astype(np.float32)
    spots = rng.random(h.shape) < 0.02
    h[spots] += rng.uniform(2, 20, int(spots.sum())).astype(np.float32)
    h[rng.random(h.shape) < 0.55] = np.nan  # mostly holes: many pieces with little around
    o = np.where(rng.random(h.shape) < 0.1, np.float32(0.0), np.float32(np.nan))
    a, b = [h.copy(), o.copy()], [h.copy(), o.copy()]
    na = drop_floating(a, 0.5, 40, 4, 0.5, block_rows=9)
    nb = drop_floating(b, 0.5, 40, 4, 0.5, block_rows=10_000)
    assert na == nb and na[0] > 1000
    assert all(np.array_equal(np.isnan(x), np.isnan(y)) for x, y in zip(a, b))


def test_floating_zero_keeps_everything_and_bad_parameters_are_refused():
    g, r, _ = _shadowed()
    r0 = r.copy()
    assert drop_floating([g, r], 0.5, 0, 20, 0.15) == [0, 0]
    assert np.array_equal(r, r0, equal_nan=True)
    for kw in ({"floating_max_cells": -1}, {"floating_radius_mm": 0.0},
               {"floating_support": 1.0}):
        with pytest.raises(InputError) as exc:
            ProcessParams(**kw).validate()
        assert exc.value.code == "E-PARAM"
