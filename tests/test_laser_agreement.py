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
    # reconciled by default, recorded as a parameter and with what was done
    assert meta["parameters"]["reconcile_lasers"] is True
    done = meta["stats"]["lasers_reconciled"]
    assert 0 < done["green_share"] < 1 and done["largest_mm"] > 0


def test_no_reconcile_lasers_keeps_each_lasers_map_as_its_plane_makes_it(
        flat_scan, flat_calibration, tmp_path, capsys):
    """``impress process --no-reconcile-lasers``: recorded, nothing shared; the per-laser maps
    differ from the default run's by the fitted difference's share, the fused heights where
    both lasers measured do not."""
    import tifffile

    from impress_gui.cli import main

    out = {}
    for name, more in (("default", []), ("off", ["--no-reconcile-lasers"])):
        out[name] = tmp_path / name
        code = main(["process", str(flat_scan / "scan.mp4"), "--calibration",
                     str(flat_calibration), "-o", str(out[name]), "--no-texture", *more])
        assert code == 0, capsys.readouterr().err
    meta = {k: json.loads((d / "metadata.json").read_text()) for k, d in out.items()}
    assert meta["off"]["parameters"]["reconcile_lasers"] is False
    assert meta["off"]["stats"]["lasers_reconciled"] is None
    done = meta["default"]["stats"]["lasers_reconciled"]
    assert done is not None
    assert meta["off"]["stats"]["laser_agreement"] == meta["default"]["stats"]["laser_agreement"]
    moved = max(float(np.nanmax(np.abs(tifffile.imread(out["default"] / f)
                                       - tifffile.imread(out["off"] / f))))
                for f in ("height_green.tif", "height_red.tif"))
    assert 0.9 * done["largest_mm"] < moved < done["largest_mm"] + 1e-4
    fused = {k: tifffile.imread(d / "heightmap.tif") for k, d in out.items()}
    both = ((tifffile.imread(out["off"] / "contribution.tif") == 3)
            & (tifffile.imread(out["default"] / "contribution.tif") == 3))
    assert both.sum() > 10_000
    assert np.abs(fused["default"] - fused["off"])[both].max() < 1e-4


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
    from impress_gui.core.reconstruction.reconstruct import (
        ProcessParams,
        fusion_weight,
        reconstruct,
    )
    from impress_gui.sim.truth import true_laser_plane, truth_for_reconstruction

    cal = SceneCalibration.load(flat_calibration)
    truth = json.loads((flat_scan / "truth.json").read_text())
    # the simulator's own planes: the lasers agree; then the red one turned by 0.08 deg
    true = {n: replace(f, plane=true_laser_plane(truth, n, cal.rotation).oriented_like(f.plane))
            for n, f in cal.planes.items()}
    red = true["red"]
    size: list = []

    def run(c, reconcile: bool):
        with open_video(flat_scan / "scan.mp4") as v:
            rec = reconstruct(v, c, ProcessParams(reconcile_lasers=reconcile))
            size.append(v.size)
        # each laser's height error against x, from the simulator's truth
        slopes = {}
        for name, h in rec.per_laser_mm.items():
            t = truth_for_reconstruction(flat_scan, rec.spec, h, c.reference_depth, c.rotation)
            ok = np.isfinite(h) & np.isfinite(t) & (np.abs(h - t) < 1.0)
            x = rec.spec.x0_mm + rec.spec.pixel_mm * np.nonzero(ok)[1]
            slopes[name] = 100 * np.polyfit(x, (h - t)[ok].astype(float), 1)[0]
        return rec, slopes

    for turn in (0.0, 0.08):
        c = replace(cal, planes={**true, "red": replace(red, plane=_twisted(red.plane, turn))})
        rec, slopes = run(c, False)  # the maps as the planes make them
        a = rec.stats["laser_agreement"]
        assert rec.stats["lasers_reconciled"] is None
        assert a["x_mm_per_100mm"] == pytest.approx(slopes["green"] - slopes["red"], abs=0.005)
        warned = any(w.startswith("W-LASERS-DIVERGE") for w in rec.warnings)
        if turn:
            assert abs(slopes["red"]) > 0.03 and warned  # the turn is there, and seen
        else:
            assert abs(a["x_mm_per_100mm"]) < 0.01 and not warned, a
    # reconciled (the default): both lasers read the pair's weighted twist, the same figures
    # found and warned of
    rec2, slopes2 = run(c, True)
    w = fusion_weight(c, size[-1])
    assert rec2.stats["lasers_reconciled"]["green_share"] == pytest.approx(1 - w, abs=1e-4)
    assert rec2.stats["laser_agreement"] == rec.stats["laser_agreement"]
    assert rec2.warnings == rec.warnings
    pair = w * slopes["green"] + (1 - w) * slopes["red"]
    for name in ("green", "red"):
        assert slopes2[name] == pytest.approx(pair, abs=0.005), (name, slopes, slopes2)
    assert abs(slopes2["red"]) < abs(slopes["red"]) - 0.01
    # where both lasers measured, the fused map is the same
    both = (rec.contribution == 3) & (rec2.contribution == 3)
    assert both.sum() > 100_000
    assert np.abs(rec2.height_mm - rec.height_mm)[both].max() < 1e-4


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


def _pair(rng):
    """The dug surface seen by two lasers with turned planes: green reads 0.03 mm per 100 mm
    of x high and 0.5 % deep, red 0.01 mm low; green alone at the map's first 150 rows, red
    alone at its last 150 (the scan's ends), both in between."""
    true = _surface(rng)
    x = SPEC.x0_mm + SPEC.pixel_mm * np.arange(SPEC.shape[1])
    green = (true * 1.005 + 0.03 * (x[None, :] / 100.0)).astype(np.float32)
    red = (true - 0.01 + rng.normal(0, 0.02, SPEC.shape)).astype(np.float32)
    green[450:] = np.nan
    red[:150] = np.nan
    return true, green, red


@pytest.mark.parametrize("w", [0.5, 0.2])
def test_reconciled_lasers_keep_the_fused_heights_and_share_the_difference(w):
    from impress_gui.core.reconstruction.agreement import reconcile
    from impress_gui.core.reconstruction.grid import fuse

    rng = np.random.default_rng(6)
    true, green, red = _pair(rng)
    err_g, err_r = green - true, red - true
    fused0, _d, contrib0 = fuse(green, red, 0.3, weight_green=w)
    a = laser_agreement(green, red, SPEC)
    per = {"green": green.copy(), "red": red.copy()}
    done = reconcile(per, SPEC, a, w, block_rows=64)  # blocks smaller than the map
    assert done == {"green_share": pytest.approx(1 - w, abs=1e-5),
                    "largest_mm": pytest.approx(done["largest_mm"])}
    assert 0.01 < done["largest_mm"] < 0.1
    fused1, _d, contrib1 = fuse(per["green"], per["red"], 0.3, weight_green=w)
    both = contrib0 == 3
    # where both lasers measured, the fused heights are unchanged (to float32's rounding)
    assert np.abs(fused1 - fused0)[both].max() < 2e-5
    assert (contrib1[both] == 3).all()
    # each laser now reads what the pair's weighted mean read: green alone at the start and
    # red alone at the end carry the same systematic error as the fused heights between
    expected = w * err_g + (1 - w) * err_r  # red's noise included: compare means by column
    for name, rows in (("green", slice(0, 150)), ("red", slice(450, 600))):
        e_after = (per[name] - true)[rows]
        e_before = {"green": err_g, "red": err_r}[name][rows]
        # the pair's error on the ground, per column (rows without the dug letter)
        def by_5mm(m):  # column means over 5 mm wide strips (red's noise averaged)
            return np.nanmean(m.reshape(m.shape[0], -1, 50), axis=(0, 2))
        want = by_5mm(expected[150:200])
        got = by_5mm(e_after)
        before = by_5mm(e_before)
        assert np.abs(got - want).max() < 0.003, name
        assert np.abs(got - want).mean() < 0.25 * np.abs(before - want).mean(), name
    # NaN stays NaN
    assert np.isnan(per["green"][450:]).all() and np.isnan(per["red"][:150]).all()
    # the height scale is not shared (the target's faces fix it): green's letter stays
    # 0.5 % deeper than red's
    def depth(m):
        return float(np.nanmean(m[220:380, 520:880]) - np.nanmean(m[155:195, 520:880]))
    assert depth(per["green"]) == pytest.approx(depth(green), abs=1e-4)
    assert depth(per["green"]) - depth(per["red"]) == pytest.approx(-0.015, abs=0.003)


def test_lasers_too_far_apart_are_not_reconciled():
    import impress_gui.core.reconstruction.agreement as ag

    rng = np.random.default_rng(7)
    true, green, red = _pair(rng)
    green = green + 2.1  # 2.1 mm apart: a fit taken by something else than a plane's turn
    a = laser_agreement(green, red, SPEC)
    before = green.copy()
    per = {"green": green, "red": red}
    assert ag.reconcile(per, SPEC, a, 0.5) is None
    assert np.array_equal(per["green"], before, equal_nan=True)
    assert ag.reconcile(per, SPEC, None, 0.5) is None
    assert ag.reconcile(per, SPEC, laser_agreement(green - 2.1, red, SPEC), 0.5) is not None
