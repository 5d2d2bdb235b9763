"""bench_stripe_texture (issue 18, real laser light): a stripe whose light follows the soil row
by row is placed off by the soil's grain when the unlit soil is only subtracted, and back on
when it is also divided out; a stripe drawn as the simulator draws it (one albedo per column)
is the other way round."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

ROOT_BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture
def bench(monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT_BENCH))
    import bench_stripe_texture

    return bench_stripe_texture


def _grainy_soil(bench, n: int, spread: float, seed: int) -> np.ndarray:
    """Columns of soil albedo with a grain about a pixel across (mean 0.5)."""
    rng = np.random.default_rng(seed)
    g = rng.lognormal(0.0, spread, (n, 2 * bench.K + 1))
    g = 0.25 * (g + np.roll(g, 1, axis=1))
    return np.clip(g, 0.05, 1.0)


def test_division_undoes_a_stripe_that_follows_the_soil(bench):
    alb = _grainy_soil(bench, 1500, 0.25, 1)
    rng = np.random.default_rng(2)
    follows = bench.errors(*bench.stripe_columns(alb, 1.0, rng, follows_soil=True))
    drawn = bench.errors(*bench.stripe_columns(alb, 1.0, rng, follows_soil=False))
    # the grain pulls the centre: subtraction leaves it, division takes it out
    assert follows["subtracted"] > 1.3 * follows["divided"], follows
    # the simulator's stripe: subtraction leaves the beam alone, division distorts it
    assert drawn["divided"] > 1.3 * drawn["subtracted"], drawn
    # both leave a smooth soil's stripe alike (sensor noise alone)
    smooth = np.full_like(alb, 0.5)
    plain = bench.errors(*bench.stripe_columns(smooth, 1.0, rng, follows_soil=True))
    assert abs(plain["subtracted"] - plain["divided"]) < 0.01 and plain["subtracted"] < 0.06


def test_soil_columns_sample_the_albedo_along_its_rows(bench):
    """A ramp along the grid's rows, sampled every 0.2 mm on a 0.1 mm grid: each column rises
    by two cells' worth per row."""
    ramp = np.repeat(np.arange(400.0)[:, None] / 400.0, 50, axis=1)
    cols = bench.soil_columns(ramp, 0.1, 0.2, 20, np.random.default_rng(0))
    assert cols.shape == (20, 2 * bench.K + 1)
    np.testing.assert_allclose(np.diff(cols, axis=1), 2 / 400.0, atol=1e-6)
