"""Budget components found by the coverage benchmark (issue 22): a depth below a tilted plane
moves with the calibration's lateral displacement of the point against its supports, and a cell
where the two lasers disagreed moves as the laser the fusion kept."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from impress_gui.core.measure import readings as M
from impress_gui.core.measure import uncertainty as U
from impress_gui.core.reconstruction.grid import GridSpec

S = 400  # trials of the stub ensemble


class _StubContext(U.UncertaintyContext):
    """A context whose calibration trials move every cell by given deltas: ``shift(x, y, h)``
    returns ``(dx, dy, dh)`` each ``(S, N)``."""

    shift = None

    def calibration_deltas(self, x, y, h):
        x, y, h = (np.atleast_1d(np.asarray(v, float)) for v in (x, y, h))
        return self.shift(x, y, h)


def _ctx(slope: float, lateral_sd: float) -> tuple[_StubContext, GridSpec, np.ndarray]:
    spec = GridSpec(0.0, 0.0, 0.1, (500, 500))
    h = (slope * spec.xs()[None, :] + 0.0 * spec.ys()[:, None]).astype(np.float32)
    h = np.repeat(h, spec.shape[0], axis=0)
    ens = SimpleNamespace(n_trials=S, click_sigma_px=0.5, sigma_source="stub", summary={})
    ctx = _StubContext(h, spec, ensemble=ens)
    rng = np.random.default_rng(3)
    shift_of_point = rng.normal(0.0, lateral_sd, S)  # the point moves against its supports

    def shift(x, y, hh):
        dx = np.zeros((S, len(x)))
        if len(x) == 4:
            dx[:, 3] = shift_of_point
        return dx, np.zeros_like(dx), np.zeros_like(dx)

    ctx.shift = shift
    return ctx, spec, h


def _depth_cal_u(slope: float, lateral_sd: float) -> float:
    ctx, spec, h = _ctx(slope, lateral_sd)
    sup = [M.readout(h, spec, x, y, 0.5) for x, y in ((10.0, 10.0), (40.0, 12.0), (25.0, 40.0))]
    p = M.readout(h, spec, 25.0, 20.0, 0.5)
    b = U.depth_budget(ctx, p, sup)
    assert b.value_mm == pytest.approx(0.0, abs=1e-3)  # the point lies on the plane
    return next(c.u_mm for c in b.components if c.name == "calibration")


def test_depth_below_a_tilted_plane_grows_with_its_slope_and_the_lateral_shift():
    # the supports stay, the point moves across the map by N(0, sd): the plane read at the
    # moved point changes by slope x shift
    flat = _depth_cal_u(0.0, 0.2)
    assert flat == pytest.approx(0.0, abs=1e-9)
    u1 = _depth_cal_u(0.3, 0.2)
    u2 = _depth_cal_u(0.6, 0.2)
    u3 = _depth_cal_u(0.6, 0.4)
    assert u1 == pytest.approx(0.3 * 0.2, rel=0.15)
    assert u2 == pytest.approx(2 * u1, rel=1e-6)
    assert u3 == pytest.approx(2 * u2, rel=1e-6)


def test_trial_depths_reproduce_the_depth_without_noise():
    xs, ys = np.array([0.0, 10.0, 0.0, 3.0]), np.array([0.0, 0.0, 10.0, 3.0])
    hs = 0.5 * xs + 0.2 * ys - np.array([0, 0, 0, 1.0])  # the point 1 mm below the plane
    z = np.zeros((5, 4))
    assert np.allclose(U._trial_depths(xs, ys, hs, (z, z, z)), 1.0)
    # a common move of all four (the whole map shifted) changes nothing
    dx = np.full((5, 4), 0.7)
    assert np.allclose(U._trial_depths(xs, ys, hs, (dx, -dx, z)), 1.0)


def test_a_cell_where_the_lasers_disagreed_moves_as_the_laser_the_fusion_kept():
    spec = GridSpec(0.0, 0.0, 0.1, (20, 20))
    green = np.full(spec.shape, 1.0, np.float32)
    red = np.full(spec.shape, 1.8, np.float32)
    fused = green.copy()
    fused[:, 10:] = red[:, 10:]
    code = np.full(spec.shape, 4, np.uint8)
    ctx = U.UncertaintyContext(fused, spec, code)
    assert ctx.lasers_at(0.5, 0.5) == [("green", 0.5), ("red", 0.5)]  # unknown: the mean
    ctx.per_laser = {"green": green, "red": red}
    assert ctx.lasers_at(0.5, 0.5) == [("green", 1.0)]
    assert ctx.lasers_at(1.5, 0.5) == [("red", 1.0)]
    code[:] = 3
    assert ctx.lasers_at(1.5, 0.5) == [("green", 0.5), ("red", 0.5)]
    assert math.isfinite(float(fused[0, 0]))


def _ridge_width_cal_u(g: float, sd: float) -> tuple[float, float]:
    """A ridge along y with walls of slope ``g`` (top 4 mm): the width at 2 mm and its
    calibration u when each trial raises the whole surface by N(0, sd)."""
    spec = GridSpec(0.0, 0.0, 0.1, (300, 500))
    x = spec.xs()
    row = np.clip(g * (12.0 - np.abs(x - 25.0)), 0.0, 4.0)
    h = np.repeat(row[None, :], spec.shape[0], axis=0).astype(np.float32)
    ens = SimpleNamespace(n_trials=S, click_sigma_px=0.5, sigma_source="stub", summary={})
    ctx = _StubContext(h, spec, ensemble=ens)
    lift = np.random.default_rng(5).normal(0.0, sd, S)

    def shift(xx, yy, hh):
        z = np.zeros((S, len(xx)))
        return z, z.copy(), z + lift[:, None]

    ctx.shift = shift
    prof = M.line_profile(h, spec, (5.0, 15.0), (45.0, 15.0), 0.0)
    w = M.width_at_level(prof, 2.0, 20.0)
    b = U.width_budget(ctx, prof, w)
    return w.width_mm, next(c.u_mm for c in b.components if c.name == "calibration")


def test_width_at_a_level_moves_with_the_height_error_over_the_walls_slope():
    # the level is a height on the map: raising the surface by dh moves each crossing of a
    # wall of slope g by dh / g, so the width by 2 dh / g on a ridge
    w, u = _ridge_width_cal_u(1.0, 0.1)
    assert w == pytest.approx(2 * (12.0 - 2.0), abs=0.05)
    assert u == pytest.approx(2 * 0.1 / 1.0, rel=0.15)
    _, u_half = _ridge_width_cal_u(0.5, 0.1)
    assert u_half == pytest.approx(2 * u, rel=0.02)  # half the slope, twice the shift
    _, u_steep = _ridge_width_cal_u(4.0, 0.1)
    assert u_steep < u / 3
