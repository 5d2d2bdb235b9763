"""The two lasers' agreement across the map (reconstruction.agreement): a laser plane turned in
the calibration shows as the lasers' difference changing across the map, without any truth."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from impress_gui.core.calibration.geometry import Plane
from impress_gui.core.reconstruction.agreement import (
    DIVERGE_MM,
    agreement_warnings,
    laser_agreement,
)
from impress_gui.core.reconstruction.grid import GridSpec

SPEC = GridSpec(x0_mm=-100.0, y0_mm=-20.0, pixel_mm=0.1, shape=(600, 2000))


def _surface(rng) -> np.ndarray:
    """A ground with a dug letter 3 mm deep and noisy heights (0.02 mm)."""
    h = np.zeros(SPEC.shape, np.float32)
    h[200:400, 500:900] = -3.0
    return h + rng.normal(0, 0.02, SPEC.shape).astype(np.float32)


def test_a_twist_and_a_scale_of_one_laser_are_read_from_the_difference():
    rng = np.random.default_rng(3)
    true = _surface(rng)
    x = SPEC.x0_mm + SPEC.pixel_mm * np.arange(SPEC.shape[1])
    green = true + 0.004 + 0.03 * (x[None, :] / 100.0)  # 0.03 mm per 100 mm across
    red = true * (1 + 0.01) + rng.normal(0, 0.02, SPEC.shape)  # heights 1 % too deep
    red[50:60, :] += 5.0  # an edge only one laser saw: left out as an outlier
    green[:, :300] = np.nan  # one laser alone at one side: not in the difference
    a = laser_agreement(green, red.astype(np.float32), SPEC)
    assert a is not None
    assert a["x_mm_per_100mm"] == pytest.approx(0.03, abs=0.001)
    assert a["y_mm_per_100mm"] == pytest.approx(0.0, abs=0.002)
    assert a["height_pct"] == pytest.approx(-1.0, abs=0.05)
    assert a["x_span_mm"] == pytest.approx(169.6, abs=0.5)  # x from -70 to +99.9 mm
    assert a["across_mm"] == pytest.approx(0.03 * 1.696, abs=0.002)
    assert a["rms_mm"] == pytest.approx(0.02, rel=0.1)  # red's own noise (the surface cancels)
    w = agreement_warnings(a)
    assert len(w) == 1 and w[0].startswith("W-LASERS-DIVERGE: the green and red heights differ "
                                           "by 0.051 mm more at one side")
    # red scaled more: the height's warning too; red alone: no figures
    a2 = laser_agreement(green, (true * 1.03).astype(np.float32), SPEC)
    assert a2["with_height_mm"] > DIVERGE_MM
    assert [x.split(":")[0] for x in agreement_warnings(a2)] == ["W-LASERS-DIVERGE"] * 2
    assert laser_agreement(np.full(SPEC.shape, np.nan, np.float32), red, SPEC) is None
    assert agreement_warnings(None) == []


def test_lasers_that_agree_are_not_warned_of():
    rng = np.random.default_rng(4)
    true = _surface(rng)
    red = true + rng.normal(0, 0.03, SPEC.shape).astype(np.float32)
    a = laser_agreement(true, red, SPEC)
    assert a["across_mm"] < 0.005 and a["with_height_mm"] < 0.005
    assert agreement_warnings(a) == []


def test_the_written_metadata_carries_the_figures_and_the_warning_follows_them(flat_recon):
    # the flat preset at 640x360: its green plane is turned (-0.108 mm per 100 mm across the
    # map against the simulator's truth, measured 2026-12-07), which this check shows
    meta = json.loads((flat_recon / "metadata.json").read_text())
    a = meta["stats"]["laser_agreement"]
    assert a["cells"] > 1000 and a["x_span_mm"] > 100
    warned = [w for w in meta["warnings"] if w.startswith("W-LASERS-DIVERGE")]
    expected = int(a["across_mm"] > DIVERGE_MM) + int(a["with_height_mm"] > DIVERGE_MM)
    assert len(warned) == expected


def _twisted(plane: Plane, deg: float) -> Plane:
    """``plane`` turned by ``deg`` about the axis in it across its stripe on the ground (the
    stripe runs along the ideal frame's x), through its point straight ahead of the camera."""
    n = plane.normal
    stripe = np.cross(n, [0.0, 0.0, 1.0])
    axis = np.cross(n, stripe)
    axis /= np.linalg.norm(axis)
    t = np.radians(deg)
    turned = (n * np.cos(t) + np.cross(axis, n) * np.sin(t)
              + axis * (axis @ n) * (1 - np.cos(t)))
    p0 = np.array([0.0, 0.0, plane.offset_mm / n[2]])
    return Plane(turned, float(turned @ p0))


def test_a_turned_red_plane_is_seen_as_the_truth_sees_it(flat_scan, flat_calibration):
    from impress_gui.core.calibration.scene import SceneCalibration
    from impress_gui.core.formats.video import open_video
    from impress_gui.core.reconstruction.reconstruct import ProcessParams, reconstruct
    from impress_gui.sim.truth import true_laser_plane, truth_for_reconstruction

    cal = SceneCalibration.load(flat_calibration)
    truth = json.loads((flat_scan / "truth.json").read_text())
    # the simulator's own planes: the lasers agree; then the red one turned by 0.08 deg
    true = {n: replace(f, plane=true_laser_plane(truth, n, cal.rotation).oriented_like(f.plane))
            for n, f in cal.planes.items()}
    red = true["red"]
    for turn in (0.0, 0.08):
        c = replace(cal, planes={**true, "red": replace(red, plane=_twisted(red.plane, turn))})
        with open_video(flat_scan / "scan.mp4") as v:
            rec = reconstruct(v, c, ProcessParams())
        a = rec.stats["laser_agreement"]
        # each laser's height error against x, from the simulator's truth
        slopes = {}
        for name, h in rec.per_laser_mm.items():
            t = truth_for_reconstruction(flat_scan, rec.spec, h, c.reference_depth, c.rotation)
            ok = np.isfinite(h) & np.isfinite(t) & (np.abs(h - t) < 1.0)
            x = rec.spec.x0_mm + rec.spec.pixel_mm * np.nonzero(ok)[1]
            slopes[name] = 100 * np.polyfit(x, (h - t)[ok].astype(float), 1)[0]
        assert a["x_mm_per_100mm"] == pytest.approx(slopes["green"] - slopes["red"], abs=0.005)
        warned = any(w.startswith("W-LASERS-DIVERGE") for w in rec.warnings)
        if turn:
            assert abs(slopes["red"]) > 0.03 and warned  # the turn is there, and seen
        else:
            assert abs(a["x_mm_per_100mm"]) < 0.01 and not warned, a


def test_a_long_map_is_sampled_more_sparsely_and_reads_the_same(monkeypatch):
    import impress_gui.core.reconstruction.agreement as ag

    rng = np.random.default_rng(5)
    true = _surface(rng)
    x = SPEC.x0_mm + SPEC.pixel_mm * np.arange(SPEC.shape[1])
    green = true + 0.02 * (x[None, :] / 100.0)
    full = laser_agreement(green, true, SPEC)
    monkeypatch.setattr(ag, "MAX_SAMPLES", 10_000)  # 1.2 M cells: every 11th row and column
    sparse = laser_agreement(green, true, SPEC)
    assert sparse["cells"] < 0.2 * full["cells"]
    assert sparse["x_mm_per_100mm"] == pytest.approx(0.02, abs=0.001)
    assert full["x_mm_per_100mm"] == pytest.approx(0.02, abs=0.0005)
