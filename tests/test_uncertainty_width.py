"""The calibration term of a width / edge distance (issue 22): a crossing is found again per
Monte Carlo trial on the moved profile. Where its level comes from bands on the same profile
(``impress validate``'s edges and widths) the level moves with them, so a calibration's common
height error does not move the crossing - even where the crossing lies between two nearly level
samples (which the former dh / slope term turned into millimetres) - while a noisier
calibration still gives a larger U."""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest

from impress_gui.core.measure import readings as M
from impress_gui.core.measure import uncertainty as U
from impress_gui.core.reconstruction.grid import GridSpec
from impress_gui.validation import protocol as V

S = 300  # trials of the stub ensemble
SPEC = GridSpec(0.0, 0.0, 0.1, (300, 500))
Y = 15.0
START, END = (5.0, Y), (45.0, Y)
# profile distances (x - 5) of the bands: the left edge's low band (x 12-17) and high band
# (x 23-28, the top), the right edge's top band (x 23-28) and low band (x 33-38)
LEFT_LOW, TOP, RIGHT_LOW = (7.0, 12.0), (18.0, 23.0), (28.0, 33.0)


def _row(x: np.ndarray) -> np.ndarray:
    """A block 2 mm high from x = 20 to 31 whose left wall has a nearly level part
    (slope 0.08 from x = 20.5 to 21.5) right at half its height, where the level is crossed;
    the right wall is steep."""
    h = np.zeros_like(x)
    h = np.where((x >= 20.0) & (x < 20.5), 1.91 * (x - 20.0), h)
    h = np.where((x >= 20.5) & (x < 21.5), 0.955 + 0.08 * (x - 20.5), h)
    h = np.where((x >= 21.5) & (x < 22.0), 1.035 + 1.93 * (x - 21.5), h)
    h = np.where((x >= 22.0) & (x < 30.0), 2.0, h)
    h = np.where((x >= 30.0) & (x < 31.0), 2.0 * (31.0 - x), h)
    return h


HEIGHT = np.repeat(_row(SPEC.xs())[None, :], SPEC.shape[0], axis=0).astype(np.float32)


class _Trials:
    """A stub calibration whose trial t moves a cell at ``(x, y, h)`` by
    ``dh = a_t + b_t h + c_t (x - 25)`` (a common height error, a height scale and a tilt along
    the profile) and ``dx = f_t (x - 25)`` (a scale across the map); ``scale`` multiplies all
    four spreads (a noisier calibration)."""

    def __init__(self, scale: float = 1.0, common_mm: float = 1.0, seed: int = 7):
        rng = np.random.default_rng(seed)
        self.a = rng.normal(0.0, common_mm * scale, S)
        self.b = rng.normal(0.0, 0.01 * scale, S)
        self.c = rng.normal(0.0, 0.005 * scale, S)
        self.f = rng.normal(0.0, 0.002 * scale, S)

    def __call__(self, x, y, h):
        x, h = (np.atleast_1d(np.asarray(v, float)) for v in (x, h))
        dh = self.a[:, None] + self.b[:, None] * h[None] + self.c[:, None] * (x[None] - 25.0)
        dx = self.f[:, None] * (x[None] - 25.0)
        return dx, np.zeros_like(dx), dh


class _StubContext(U.UncertaintyContext):
    trials: _Trials | None = None

    def calibration_deltas(self, x, y, h):
        assert self.trials is not None
        return self.trials(x, y, h)


def _ctx(trials: _Trials) -> _StubContext:
    ens = SimpleNamespace(n_trials=S, click_sigma_px=0.5, sigma_source="stub", summary={})
    # both lasers' maps the same: every wall seen by both (no one-laser wall component: the
    # calibration's share is what these tests look at)
    ctx = _StubContext(HEIGHT, SPEC, ensemble=ens, per_laser={"green": HEIGHT, "red": HEIGHT})
    ctx.trials = trials
    return ctx


EDGES = (V.Edge(LEFT_LOW, TOP, 16.0), V.Edge(RIGHT_LOW, TOP, 25.5))


def _edge_pair(prof):
    e0, e1 = (V._edge(prof, e) for e in EDGES)
    return SimpleNamespace(left_mm=min(e0, e1), right_mm=max(e0, e1), level_mm=1.0,
                           width_mm=abs(e1 - e0))


def _cal_u(b: U.Budget) -> float:
    return next(c.u_mm for c in b.components if c.name == "calibration")


def _brute_force_sd(trials: _Trials) -> float:
    """The edge distance re-measured per trial with the protocol's own edge finding on the
    moved profile (heights moved, the crossings then moved across the map)."""
    prof = M.line_profile(HEIGHT, SPEC, START, END, 0.0)
    dx, _, dh = trials(prof.x_mm, prof.y_mm, prof.height_mm)
    out = []
    for t in range(S):
        moved = dataclasses.replace(prof, height_mm=prof.height_mm + dh[t])
        e = [V._edge(moved, edge) for edge in EDGES]
        x = [d + np.interp(d, prof.distance_mm, dx[t]) for d in e]
        out.append(abs(x[1] - x[0]))
    return float(np.std(out, ddof=1))


def test_the_level_from_the_bands_moves_with_them_between_nearly_level_samples():
    prof = M.line_profile(HEIGHT, SPEC, START, END, 0.0)
    pair = _edge_pair(prof)
    assert pair.left_mm + 5.0 == pytest.approx(21.0625, abs=0.01)  # on the nearly level part
    assert pair.right_mm + 5.0 == pytest.approx(30.5, abs=0.01)
    # the samples that bracket the left crossing are nearly level (0.008 mm apart over 0.1 mm)
    i = int(np.searchsorted(prof.distance_mm, pair.left_mm))
    slope = (prof.height_mm[i] - prof.height_mm[i - 1]) / 0.1
    assert slope == pytest.approx(0.08, abs=0.01)
    trials = _Trials()
    ctx = _ctx(trials)
    bands = [(LEFT_LOW, TOP), (TOP, RIGHT_LOW)]
    b = U.width_budget(ctx, prof, pair, level_bands=bands)
    u = _cal_u(b)
    # a common height error of 1 mm (SD) over a slope of 0.08 would move the crossing by
    # 12 mm; relative to the bands it moves by the tilt over the 1 mm between the crossing
    # and the bands' mean position, 0.005 mm / 0.08, and the lateral scale adds 0.002 x 9.4 mm
    assert u < 0.15
    assert b.U_mm < 1.0
    assert u == pytest.approx(_brute_force_sd(trials), rel=0.05)
    # the same crossings at a level fixed on the map: the common error moves them (and none
    # is millimetres farther than the moved profile really puts it)
    fixed = SimpleNamespace(**{**vars(pair), "level_mm": U._bands_level(prof, (LEFT_LOW, TOP))})
    u_fixed = _cal_u(U.width_budget(ctx, prof, fixed))
    assert u_fixed > 3 * u
    assert u_fixed < 5.0


def test_a_noisier_calibration_gives_a_larger_width_uncertainty():
    prof = M.line_profile(HEIGHT, SPEC, START, END, 0.0)
    pair = _edge_pair(prof)
    bands = [(LEFT_LOW, TOP), (TOP, RIGHT_LOW)]
    us = [_cal_u(U.width_budget(_ctx(_Trials(scale)), prof, pair, level_bands=bands))
          for scale in (0.5, 1.0, 2.0)]
    assert us[0] < us[1] < us[2]
    assert us[2] == pytest.approx(4 * us[0], rel=0.1)  # small moves: linear in the spread
    # the expanded uncertainty grows with it
    big = [U.width_budget(_ctx(_Trials(s)), prof, pair, level_bands=bands).U_mm
           for s in (1.0, 4.0)]
    assert big[1] > big[0]


def test_the_edge_distance_reading_gives_each_edge_its_own_bands():
    """``impress validate``'s edge distance: each crossing's level moves with that edge's
    bands, in the order of the crossings along the profile (edges listed right to left)."""
    base = dict(group="g", target="t", nominal_mm=9.4375, start_mm=START, end_mm=END,
                profile_width_mm=0.0)
    trials = _Trials()
    contexts = []

    def context(h, spec, plane):
        c = _StubContext(h, spec, ensemble=SimpleNamespace(
            n_trials=S, click_sigma_px=0.5, sigma_source="stub", summary={}),
            per_laser={"green": h, "red": h})  # both lasers saw every wall
        c.trials = trials
        contexts.append(c)
        return c

    for edges in (EDGES, EDGES[::-1]):
        r = V.Reading(id="e", kind="edge_distance", edges=edges, **base)
        res = V.measure_reading(HEIGHT, SPEC, r, context=context)
        assert res.measured_mm == pytest.approx(9.4375, abs=0.02)
        assert math.isfinite(res.U_mm) and res.U_mm < 1.0
    # a width between the same walls at half the step between the top and the floor beside it
    w = V.Reading(id="w", kind="width", band_a_mm=TOP, band_b_mm=RIGHT_LOW, around_mm=20.0,
                  **base)
    res = V.measure_reading(HEIGHT, SPEC, w, context=context)
    assert res.measured_mm == pytest.approx(9.4375, abs=0.02)
    assert res.U_mm < 1.0


def test_a_trial_without_a_crossing_is_said_not_hidden():
    """A level fixed on the map that a trial lifts the whole wall past: that trial has no
    crossing there; it is left out of the spread and counted in the component's note."""
    prof = M.line_profile(HEIGHT, SPEC, START, END, 0.0)
    pair = _edge_pair(prof)
    fixed = SimpleNamespace(**{**vars(pair), "level_mm": 1.0})
    b = U.width_budget(_ctx(_Trials(common_mm=1.5)), prof, fixed)
    cal = next(c for c in b.components if c.name == "calibration")
    assert math.isfinite(cal.u_mm)
    assert "did not cross the level" in cal.note
