"""The coverage statistics of benchmarks/bench_uncertainty.py (issue 22): the interval is a
bootstrap over the calibrations, since every reading of a scan shares its calibration's error."""

from __future__ import annotations

from conftest import load_benchmark

bench = load_benchmark("bench_uncertainty")


def _rows(n_cal: int, outside: int, per_cal: int = 25, clustered: bool = True) -> list[dict]:
    """Readings of ``n_cal`` calibrations whose first ``outside`` lie wholly outside U (as a
    ruler's length error is its calibration's scale error: all or none of a scan's readings)."""
    rows = []
    for c in range(n_cal):
        for k in range(per_cal):
            seed = c if clustered else c * per_cal + k
            rows.append({"kind": "ruler xy", "err": 3.0 if c < outside else 0.5, "U": 1.0,
                         "u_c": 0.5, "parts": {"calibration": 0.5}, "seed": seed, "draw": 0})
    return rows


def test_the_interval_is_as_wide_as_the_number_of_calibrations_allows():
    rows = _rows(48, 2)  # 95.8 %: 46 of 48 calibrations inside
    low, high, n = bench.coverage_interval(rows)
    assert n == 48
    assert low <= 91.7 and high == 100.0  # 2 of 48 out: a bootstrap spans 0-4 of them
    # the same share as independent readings (each its own calibration): far narrower
    ilow, ihigh, n_ind = bench.coverage_interval(_rows(48, 2, clustered=False))
    assert n_ind == 48 * 25
    assert (high - low) > 5 * (ihigh - ilow)
    assert bench.verdict(95.8, low, high) == "inside (the interval reaches beyond the band)"


def test_the_verdict_says_whether_the_sample_can_tell():
    low, high, _ = bench.coverage_interval(_rows(400, 0))
    assert (low, high) == (100.0, 100.0)
    assert bench.verdict(100.0, low, high) == "over (the interval lies above the band)"
    low, high, _ = bench.coverage_interval(_rows(200, 40))  # 80 %
    assert high < 93.0
    assert bench.verdict(80.0, low, high) == "under (the interval lies below the band)"
    assert bench.verdict(98.0, 95.0, 99.5) == "over (the interval reaches into the band)"
    assert bench.verdict(95.0, 94.0, 96.0) == "inside (the interval lies inside the band)"
    text = bench.table(_rows(48, 2))
    assert "95.8%" in text and "ruler xy" in text and "interval" in text


def test_readings_without_a_stated_u_are_counted_apart():
    """Readings made with an unstable calibration have no U: the table says how many, from how
    many calibrations, and leaves them out of the coverage (not counted as covered)."""
    rows = _rows(10, 0)  # all inside
    rows += [{"kind": "ruler xy", "err": 5.0, "U": None, "u_c": None, "seed": 99, "draw": 1,
              "incomplete": "the calibration is unstable"} for _ in range(7)]
    text = bench.table(rows)
    assert "readings with no U stated, the calibration unstable: 7 of 257, from 1 " \
        "calibration(s)" in text
    line = next(x for x in text.splitlines() if x.startswith("ruler xy"))
    assert " 250 " in line and "100.0%" in line
    assert "no U stated" not in bench.table(_rows(10, 0))
