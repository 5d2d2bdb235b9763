"""The motion-compensated background of benchmarks/bench_subpixel.py (issue 18): a dim stripe on
textured soil is placed by the soil's texture as much as by its own light; the same soil seen
unlit, subtracted, leaves the stripe; a clipped core is left as the plateau it is."""

from __future__ import annotations

import numpy as np
from conftest import load_benchmark

bench = load_benchmark("bench_subpixel")


def _columns(n: int, amplitude: float, texture: float, rng) -> tuple:
    """``n`` columns of 2K+1 rows: soil of smooth random texture (features of 2-4 rows, the
    scale of a dim stripe) plus a Gaussian stripe (sigma 1.5 rows) at a known centre."""
    k = bench.K
    rows = np.arange(2 * k + 1, dtype=float)
    centre = k + rng.uniform(-0.5, 0.5, n)
    soil = rng.normal(0.0, 1.0, (n, 2 * k + 1))
    kernel = np.exp(-0.5 * (np.arange(-4, 5) / 1.5) ** 2)
    soil = np.array([np.convolve(s, kernel / kernel.sum(), mode="same") for s in soil])
    soil = 170.0 + texture * soil / soil.std()
    stripe = amplitude * np.exp(-0.5 * ((rows[None, :] - centre[:, None]) / 1.5) ** 2)
    return centre, soil, soil + stripe


def test_subtracting_the_soil_seen_unlit_places_a_dim_stripe_on_textured_soil():
    rng = np.random.default_rng(7)
    centre, soil, cut = _columns(400, 40.0, 12.0, rng)
    plain = bench.estimates(cut)["window"] - centre
    unlit = soil + rng.normal(0.0, 1.0, soil.shape) / np.sqrt(5)  # five frames' sensor noise
    sub = bench.estimates(bench.subtracted(cut, unlit))["window"] - centre
    rms = lambda e: float(np.sqrt(np.mean(e[np.isfinite(e)] ** 2)))  # noqa: E731
    assert rms(plain) > 0.25  # the texture moves the plain estimate by a quarter pixel or more
    assert rms(sub) < 0.08
    assert rms(sub) < rms(plain) / 4


def test_a_clipped_core_is_left_as_a_plateau():
    """Rows at or above CLIP keep the difference's top: the texture under a clipped core would
    otherwise come back into it, inverted. Clipped over 4.6 and 5.7 rows on average: no worse
    than the estimate on the luma itself, better than the plain difference."""
    rms = lambda e: float(np.sqrt(np.mean(e[np.isfinite(e)] ** 2)))  # noqa: E731
    for amplitude in (200.0, 400.0):
        rng = np.random.default_rng(3)
        centre, soil, cut = _columns(300, amplitude, 12.0, rng)
        cut = np.minimum(cut, 235.0)  # the core clipped over several rows
        assert (cut >= bench.CLIP).sum(axis=1).mean() > 4
        sub = rms(bench.estimates(bench.subtracted(cut, soil))["window"] - centre)
        plain = rms(bench.estimates(cut)["window"] - centre)
        raw = cut - soil
        naive = rms(bench.estimates(raw - raw.min(axis=1, keepdims=True))["window"] - centre)
        assert sub <= 1.05 * plain
        assert naive > 1.3 * sub


def test_a_share_of_the_texture_matches_a_video_that_kept_only_that_share():
    """When the frame under the stripe kept only 60 % of the soil's texture (compressed video),
    taking 0.6 of the unlit texture out beats taking all of it; the straight-line part of the
    unlit soil is taken out whole whatever the share."""
    rng = np.random.default_rng(11)
    centre, soil, _ = _columns(400, 40.0, 12.0, rng)
    k = bench.K
    rows = np.arange(2 * k + 1, dtype=float)
    slope = 1.5 * (rows - k)[None, :]  # shading across the cut: all of it in both frames
    stripe = 40.0 * np.exp(-0.5 * ((rows[None, :] - centre[:, None]) / 1.5) ** 2)
    kept = 170.0 + 0.6 * (soil - 170.0) + slope + stripe
    rms = lambda e: float(np.sqrt(np.mean(e[np.isfinite(e)] ** 2)))  # noqa: E731
    err = {w: rms(bench.estimates(bench.subtracted(kept, soil + slope, w))["window"] - centre)
           for w in (0.6, 1.0)}
    assert err[0.6] < 0.6 * err[1.0]
    assert err[0.6] < 0.08


def test_dividing_by_the_unlit_soil_places_a_stripe_that_follows_it():
    """``subtracted(..., divide=True)`` (``--divide``): a stripe whose light is the soil's
    albedo row by row times the beam is placed by the difference divided by the unlit soil;
    the plain difference leans towards the brighter grains."""
    rng = np.random.default_rng(11)
    centre, soil, _ = _columns(400, 40.0, 20.0, rng)
    soil -= 90.0  # darker soil (80 grey levels, grains of +-25 %): nothing near clipping
    rows = np.arange(soil.shape[1], dtype=float)
    beam = 60.0 * np.exp(-0.5 * ((rows[None, :] - centre[:, None]) / 1.5) ** 2)
    cut = soil + beam * soil / soil.mean(axis=1, keepdims=True)
    rms = lambda e: float(np.sqrt(np.mean(e[np.isfinite(e)] ** 2)))  # noqa: E731
    sub = rms(bench.estimates(bench.subtracted(cut, soil))["window"] - centre)
    div = rms(bench.estimates(bench.subtracted(cut, soil, divide=True))["window"] - centre)
    assert div < 0.03 and sub > 2 * div, (sub, div)
