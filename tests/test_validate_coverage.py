"""`impress validate` states whether the uncertainties cover the true errors (issue 22): every
validation reading carries the U (k = 2) the viewer would state for it, and the record counts
the share of readings whose true error lies within it, per reading kind.

Synthetic slotted surfaces with known geometry and known noise: without a calibration the
budget holds the surface noise, the grid and (widths) the crossings' positions, so a reading on
a noisy surface must be covered about 95 % of the time, and a reading with a deliberate error
well beyond its U must not be."""

from __future__ import annotations

import math

import numpy as np
import pytest

from impress_gui.core.measure.uncertainty import UncertaintyContext
from impress_gui.core.reconstruction.grid import GridSpec
from impress_gui.validation import protocol as V
from impress_gui.validation.report import format_table

SPEC = GridSpec(0.0, 0.0, 0.1, (120, 400))


def _context(h, sspec, plane):
    return UncertaintyContext(h, sspec, level_plane=plane)


def _slot_surface(noise_mm: float, seed: int) -> np.ndarray:
    """A plate at 20 mm with a slot 4 mm wide and 6 mm deep at x = 15-19 mm, white noise."""
    xs = SPEC.xs()
    h = np.full(SPEC.shape, 20.0)
    h[:, (xs >= 15.0) & (xs < 19.0)] = 14.0
    rng = np.random.default_rng(seed)
    return (h + rng.normal(0.0, noise_mm, h.shape)).astype(np.float32)


def _readings(depth_nominal: float = 6.0) -> list[V.Reading]:
    top, floor = (9.0, 14.0), (15.8, 18.2)
    walls = (V.Edge(floor, top, 15.0, 1.5), V.Edge(floor, (19.8, 25.0), 19.0, 1.5))
    line = dict(group="g", target="A", start_mm=(0.0, 6.0), end_mm=(39.0, 6.0))
    return [
        V.Reading("w", kind="edge_distance", nominal_mm=4.0, edges=walls, **line),
        V.Reading("d", kind="step", nominal_mm=depth_nominal, band_a_mm=floor, band_b_mm=top,
                  **line),
    ]


def test_every_reading_carries_its_U_and_whether_it_covers_the_error():
    h = _slot_surface(0.02, 1)
    res = V.measure_all(h, SPEC, _readings(), _context)
    for r in res:
        assert math.isfinite(r.U_mm) and r.U_mm > 0 and r.U_mm == pytest.approx(2 * r.u_c_mm)
        doc = r.to_json()
        assert doc["U_k2_mm"] == pytest.approx(r.U_mm, abs=1e-5)
        assert doc["covered"] is (abs(r.error_mm) <= r.U_mm)
    # without a context no U is stated and nothing is claimed
    bare = V.measure_all(h, SPEC, _readings())
    assert all(math.isnan(r.U_mm) and r.covered is None for r in bare)
    assert V.coverage(bare) == {}


def test_coverage_is_near_95_percent_on_honest_noise_and_fails_a_biased_reading():
    """Depth readings on 200 noise draws: their true errors lie within U about 95 % of the time
    (the budget is neither far too large nor too small). A nominal 0.3 mm off (a reading whose
    true error is ten times its U) is never covered."""
    results = []
    for seed in range(200):
        results += V.measure_all(_slot_surface(0.05, seed), SPEC, _readings()[1:], _context)
    cov = V.coverage(results)
    assert cov["step"]["n"] == 200 and cov["all"]["n"] == 200
    assert 0.88 <= cov["step"]["share"] <= 0.995, cov
    biased = V.measure_all(_slot_surface(0.05, 7), SPEC, _readings(6.3)[1:], _context)
    assert biased[0].U_mm < 0.1 and biased[0].covered is False
    assert V.coverage(biased)["step"]["share"] == 0.0


def test_the_table_states_the_coverage():
    res = V.measure_all(_slot_surface(0.02, 3), SPEC, _readings(), _context)
    record = {"uncertainty_coverage": V.coverage(res)}
    text = format_table(record)
    line = next(x for x in text.splitlines() if x.startswith("Stated uncertainty"))
    n_in = sum(bool(r.covered) for r in res)
    assert f"all {n_in}/2" in line and "edge distance" in line and "step" in line


def test_readings_of_an_unstable_calibration_are_counted_apart_not_as_missed():
    """A context whose calibration is unstable (its Monte Carlo failed in most trials) gives
    budgets with no U: the readings say why, are neither covered nor missed, are counted as
    no_U per kind, and the table says so instead of a coverage it cannot give."""
    import dataclasses

    def unstable(h, sspec, plane):
        return dataclasses.replace(_context(h, sspec, plane),
                                   unstable="the Monte Carlo failed in 9 of 10 trials")

    res = V.measure_all(_slot_surface(0.02, 3), SPEC, _readings(), unstable)
    assert all(math.isnan(r.U_mm) and r.covered is None and "unstable" in r.no_u for r in res)
    doc = res[0].to_json()
    assert doc["U_k2_mm"] is None and doc["covered"] is None and "9 of 10" in doc["no_U"]
    cov = V.coverage(res)
    assert cov["all"] == {"n": 0, "covered": 0, "share": None, "no_U": 2}
    assert cov["step"]["no_U"] == 1 and cov["edge_distance"]["no_U"] == 1
    text = format_table({"uncertainty_coverage": cov})
    assert not any(x.startswith("Stated uncertainty") for x in text.splitlines())
    assert "No uncertainty stated for 2 reading(s): the calibration is unstable" in text
    # mixed with a stable run: the coverage of the stable readings, the others apart
    both = res + V.measure_all(_slot_surface(0.02, 3), SPEC, _readings(), _context)
    cov = V.coverage(both)
    assert cov["all"]["n"] == 2 and cov["all"]["no_U"] == 2
    assert "no_U" not in V.coverage(both[2:])["all"]
    assert "no_U" not in both[2].to_json()


def test_validation_contexts_carry_the_per_laser_maps_cropped_like_the_heights(tmp_path):
    """Where the lasers disagreed (code 4) a validation reading's budget moves the cell as the
    laser the fusion kept, as the viewer's does: the per-laser maps (here read from the result
    folder, as they are not in memory) are cropped with the heights; without them, the mean."""
    import dataclasses

    import tifffile
    from recon_data import recon_data_from_arrays

    from impress_gui.core.formats.recon_files import LAYER_FILES
    from impress_gui.validation.run import uncertainty_contexts

    spec = GridSpec(0.0, 0.0, 0.1, (40, 60))
    green = np.full(spec.shape, 1.0, np.float32)
    red = np.full(spec.shape, 1.8, np.float32)
    fused = green.copy()
    fused[:, 40:] = red[:, 40:]  # x >= 4 mm: the fusion kept red; before, green
    code = np.full(spec.shape, 4, np.uint8)
    for name, arr in (("green", green), ("red", red)):
        tifffile.imwrite(tmp_path / LAYER_FILES[name], arr)
    rec = dataclasses.replace(recon_data_from_arrays(spec, fused, contribution=code),
                              folder=tmp_path)
    h, sspec = V.crop(fused, spec, (2.0, 5.5), (1.0, 3.0))
    ctx = uncertainty_contexts(rec, None, None)(h, sspec, None)
    assert ctx.per_laser is not None
    assert all(m.shape == h.shape for m in ctx.per_laser.values())
    assert ctx.lasers_at(5.0, 2.0) == [("red", 1.0)]
    assert ctx.lasers_at(3.0, 2.0) == [("green", 1.0)]
    # a reconstruction without the per-laser layers: None, no error, the lasers' mean
    bare = uncertainty_contexts(recon_data_from_arrays(spec, fused, contribution=code),
                                None, None)(h, sspec, None)
    assert bare.per_laser is None
    assert bare.lasers_at(5.0, 2.0) == [("green", 0.5), ("red", 0.5)]
