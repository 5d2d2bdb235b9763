"""The robustness benchmark's verdicts (issue 18) name the rigs a failing point fails on."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import bench_robustness
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    return bench_robustness


def _rig(seed: int, **over) -> dict:
    row = {"seed": seed, "rep_px": 0.001, "roll_err": 0.0, "tilt_err": 0.001,
           "bias_g": 0.001, "bias_r": -0.002, "slope_g": 0.01, "slope_r": -0.01,
           "mae_f": 0.02, "mae_g": 0.02, "mae_r": 0.03, "wild": 0.0, "fill": 99.8,
           "edge_mm": 0.002, "noise_mae": 0.03}
    row.update(over)
    return row


def _by_text(verdicts) -> dict[str, tuple[bool, str]]:
    return {text: (ok, msg) for text, ok, msg in verdicts}


def test_a_failing_point_lists_the_rigs_outside_it_and_only_those(bench):
    rows = [_rig(3), _rig(7, bias_r=-0.0136, slope_g=0.07), _rig(11, bias_g=0.0107),
            _rig(12, fill=98.5, edge_mm=0.3), _rig(20, mae_r=0.063)]
    got = _by_text(bench.verdicts(rows, draws=0, with_fill=True))
    ok, msg = got["each laser's height bias <= 0.01 mm"]
    assert not ok and msg.endswith("rigs outside: 7, 11")
    ok, msg = got["height-scale error <= 0.05 %"]
    assert not ok and msg.endswith("rigs outside: 7")
    ok, msg = got["fill >= 99 % of what either laser sees (on the modelled scene)"]
    assert not ok and msg.endswith("rigs outside: 12")
    ok, msg = got["feature-edge error <= 0.05 mm"]
    assert not ok and msg.endswith("rigs outside: 12")
    ok, msg = got["per-laser MAE worst <= 0.05 mm"]
    assert not ok and msg.endswith("rigs outside: 20")
    # the points every rig meets name none
    for text in ("tilt within 0.01 deg", "fused MAE worst <= 0.04 mm",
                 "wild points <= 0.01 % on every rig"):
        ok, msg = got[text]
        assert ok and "outside" not in msg, (text, msg)


def test_a_rig_without_a_figure_is_not_counted_outside(bench):
    rows = [_rig(1, edge_mm=float("nan")), _rig(2, edge_mm=0.07)]
    ok, msg = _by_text(bench.verdicts(rows, draws=0, with_fill=False))[
        "feature-edge error <= 0.05 mm"]
    assert not ok and msg.endswith("rigs outside: 2")


def test_rigs_without_any_edge_crossing_do_not_fail_the_edge_point(bench):
    rows = [_rig(4, edge_mm=float("nan")), _rig(5, edge_mm=float("nan"))]
    ok, msg = _by_text(bench.verdicts(rows, draws=0, with_fill=False))[
        "feature-edge error <= 0.05 mm"]
    assert ok and msg == "no edge crossed on these rigs"


def test_an_edge_left_in_a_gap_is_placed_at_the_gap_middle(bench):
    """The crossings across the scan in a gap (not an acceptance point): a wall between cells
    7 and 8 (truth) with cell 8 left empty reads half a cell off, with cells 7 and 8 empty
    exact; no gap, a gap of three cells or one at the window's end are not counted there,
    and the plain crossing leaves every gap out."""
    import numpy as np

    t = np.array([5.0] * 8 + [0.0] * 8)

    def with_nan(cells):
        h = t.copy()
        h[cells] = np.nan
        return h

    assert bench._crossings(t, with_nan([8])) == []
    assert bench._crossings(t, with_nan([8]), 2, t) == [0.5]
    assert bench._crossings(t, with_nan([7, 8]), 2, t) == [0.0]
    assert bench._crossings(t, with_nan([6, 7, 8]), 2, t) == []
    assert bench._crossings(t, with_nan([4]), 2, t) == []  # the window's first cell
    assert bench._crossings(t, t, 2, t) == [] and bench._crossings(t, t) == [0.0]
    # the truth looked up without the map's holes fills the truth's own NaN
    assert bench._crossings(np.where(np.isnan(with_nan([8])), np.nan, t), with_nan([8]), 2,
                            t) == [0.5]
    # a map holding the higher level one cell too far: one cell off (the plain crossing)
    late = t.copy()
    late[8] = 5.0
    assert bench._crossings(t, late) == [1.0]
    grid_t = np.tile(t[:, None], (1, 8))
    got = bench.edge_errors_mm(np.tile(with_nan([8])[:, None], (1, 8)), grid_t, 0.1, grid_t)
    assert got["edge_gap_n_y"] == 2 and abs(got["edge_gap_y_mm"] - 0.05) < 1e-12
    assert got["edge_n_y"] == 0


def test_ground_twist_reads_the_slope_of_the_ground_error_across_the_map(bench):
    # a map 200 mm wide whose bare ground (truth 0) reads 0.02 mm per 100 mm high to the
    # right, a constant 0.005 mm low besides; a block (truth 5 mm) with a wild error and a
    # wild ground cell must not count
    x0, px = -100.0, 0.5
    x = x0 + px * np.arange(401)
    truth = np.zeros((40, 401), np.float32)
    truth[10:20, 100:150] = 5.0
    height = (truth + 0.0002 * x[None, :] - 0.005).astype(np.float32)
    height[10:20, 100:150] += 0.7  # off on the block: not ground
    height[3, 7] = 3.0  # a wild point on the ground
    height[30:, :] = np.nan  # no data
    assert bench.ground_twist(height, truth, x0, px) == pytest.approx(0.02, abs=1e-5)
    # the other way round, and none with too little ground or x
    assert bench.ground_twist(-height, truth, x0, px) == pytest.approx(-0.02, abs=1e-5)
    assert np.isnan(bench.ground_twist(height[:, :10], truth[:, :10], x0, px))
    narrow = np.full_like(height, np.nan)
    narrow[:, 200:210] = height[:, 200:210]
    assert np.isnan(bench.ground_twist(narrow, truth, x0, px))


def test_the_true_planes_split_the_failures_into_the_planes_and_the_detector(bench):
    rows = [_rig(250, bias_r=-0.0109, slope_r=0.0666, tp_bias_r=-0.0026, tp_slope_r=0.0308),
            _rig(61, slope_g=-0.0581, tp_slope_g=-0.0675, tp_bias_g=0.0009),
            _rig(5, bias_g=0.002, tp_bias_g=0.02)]  # inside as calibrated: not listed
    bias, scale = bench.planes_explain(rows)
    assert "within it with the true planes: 250 red (-0.0109 -> -0.0026); " in bias
    assert bias.endswith("still outside with them: none")
    assert "within it with the true planes: 250 red (+0.0666 -> +0.0308); " in scale
    assert scale.endswith("still outside with them: 61 green (-0.0581 -> -0.0675)")
    # a rig without the true-plane figures is still outside
    _, scale = bench.planes_explain([_rig(9, slope_r=0.09)])
    assert scale.endswith("still outside with them: 9 red (+0.0900 -> +nan)")


def test_seeds_a_count_a_list_and_ranges(bench):
    # a bare number is a count (the tables' commands); a trailing comma makes it one rig
    assert bench.parse_seeds("3") == [0, 1, 2]
    assert bench.parse_seeds("254,") == [254]
    assert bench.parse_seeds("3,7,11") == [3, 7, 11]
    assert bench.parse_seeds("200-202,212") == [200, 201, 202, 212]
    assert bench.parse_seeds("60-61") == [60, 61]
