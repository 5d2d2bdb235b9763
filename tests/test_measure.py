"""The measuring core against exact synthetic surfaces and against the simulator's truth for the
slotted block A of the `blocks` preset (640x360, 0.1 mm grid).

Tolerances on the simulated scan (what 640x360 allows; one camera pixel is 0.38 mm at the
block's top), on the widest slot (6.35 mm wide, 6.35 mm deep), at three places along it:
- its depth as a step height between two bands (10 mm averaging width): 0.1 mm;
- the position of its left wall, whose foot the camera sees: 0.1 mm;
- its width at half depth: 0.3 mm. The camera looks down from x = 0, so the slot's right wall
  hides the floor beside it, and the reconstruction loses the last 0.2-0.3 mm of the block's
  top at that occluded edge: 0.1 mm is not achievable there at 640x360. (The narrower slots
  also have holes in their floors, so they are not used.)
- block top 32 mm and plate 12 mm above the ground (2 mm readout radius): 0.25 mm, and the
  block 20 mm above the plate after levelling: 0.25 mm - what the reconstruction itself
  achieves (its residual roll is about 0.2 mm per 100 mm across the scan).
"""

from __future__ import annotations

import csv
import io
import math

import numpy as np
import pytest
from measure_scans import blocks_recon, blocks_scan, rail_y, truth

from impress_gui.core.base.errors import FormatError, InputError
from impress_gui.core.measure import readings as M
from impress_gui.core.reconstruction.grid import GridSpec

STEP = 6.35
TOP = 32.0  # 12 mm plate + 20 mm block


# ----- exact synthetic surfaces ----------------------------------------------------------------
def ramp(spec: GridSpec, a: float, b: float, c: float) -> np.ndarray:
    return (a * spec.xs()[None, :] + b * spec.ys()[:, None] + c).astype(np.float32)


SPEC = GridSpec(-10.0, 5.0, 0.1, (300, 400))  # x -10..29.9, y 5..34.9


def test_readout_averages_over_a_radius_and_reports_missing_data():
    h = ramp(SPEC, 0.0, 0.0, 3.0)
    h[100:120, 100:120] = np.nan
    r = M.readout(h, SPEC, 5.0, 20.0, radius_mm=1.0)
    assert r.height_mm == pytest.approx(3.0) and r.n_valid == r.n_cells
    assert r.n_cells == pytest.approx(math.pi * 100, rel=0.05)
    hole = M.readout(h, SPEC, 1.0, 16.0, radius_mm=0.5)  # cell [110, 110]
    assert math.isnan(hole.height_mm) and not hole.has_data and hole.n_cells > 0
    partly = M.readout(h, SPEC, 0.0, 15.0, radius_mm=1.0)
    assert 0 < partly.n_valid < partly.n_cells and partly.height_mm == pytest.approx(3.0)
    outside = M.readout(h, SPEC, -50.0, 0.0, radius_mm=1.0)
    assert outside.n_cells == 0 and math.isnan(outside.height_mm)
    single = M.readout(ramp(SPEC, 1.0, 0.0, 0.0), SPEC, 2.04, 10.0)
    assert single.n_cells == 1 and single.height_mm == pytest.approx(2.0, abs=1e-5)


def test_ruler_distances():
    h = ramp(SPEC, 0.0, 0.0, 0.0)
    h[:, 200:] = 4.0  # x >= 10 mm
    r = M.ruler(h, SPEC, (0.0, 10.0), (30.0 - 0.1 * 0 - 0.1, 10.0))
    assert r.xy_mm == pytest.approx(29.9)
    r = M.ruler(h, SPEC, (0.0, 10.0), (3.0, 14.0))
    assert (r.xy_mm, r.dz_mm, r.d3_mm) == pytest.approx((5.0, 0.0, 5.0))
    r = M.ruler(h, SPEC, (5.0, 10.0), (15.0, 10.0), radius_mm=0.5)
    assert r.dz_mm == pytest.approx(4.0) and r.d3_mm == pytest.approx(math.hypot(10, 4))


def test_profile_is_exact_on_a_plane_and_averages_across_its_width():
    h = ramp(SPEC, 0.2, -0.1, 1.0)
    p = M.line_profile(h, SPEC, (0.0, 10.0), (12.0, 26.0), width_mm=2.0)
    assert p.length_mm == pytest.approx(20.0) and p.distance_mm[-1] == pytest.approx(20.0)
    assert np.diff(p.distance_mm).max() <= SPEC.pixel_mm + 1e-9
    assert p.n_lines >= 21 and (p.n_valid == p.n_lines).all()
    expected = 0.2 * p.x_mm - 0.1 * p.y_mm + 1.0  # a plane: the width average is exact too
    np.testing.assert_allclose(p.height_mm, expected, atol=1e-5)
    with pytest.raises(ValueError):
        p.height_mm[0] = 0  # an immutable record


def test_profile_bilinear_between_cells_and_nan_aware():
    h = np.zeros(SPEC.shape, np.float32)
    h[:, 150:] = 1.0  # a step between x = 4.9 and x = 5.0
    p = M.line_profile(h, SPEC, (4.9, 20.0), (5.0, 20.0), step_mm=0.025)
    np.testing.assert_allclose(p.height_mm, [0, 0.25, 0.5, 0.75, 1.0], atol=1e-6)
    h[:, 200:] = np.nan  # x >= 10: no data
    p = M.line_profile(h, SPEC, (9.8, 20.0), (10.2, 20.0), step_mm=0.025)
    d = p.distance_mm
    assert np.isfinite(p.height_mm[d <= 0.15]).all()  # at least half the support has data
    assert np.isnan(p.height_mm[d >= 0.26]).all()
    assert (p.height_mm[np.isfinite(p.height_mm)] == 1.0).all()  # no blending with "no data"
    wide = M.line_profile(h, SPEC, (12.0, 20.0), (20.0, 20.0), width_mm=1.0)
    assert np.isnan(wide.height_mm).all() and (wide.n_valid == 0).all()


def test_step_height_and_width_on_a_synthetic_slot():
    rng = np.random.default_rng(3)
    h = np.full(SPEC.shape, 10.0, np.float32) + rng.normal(0, 0.02, SPEC.shape).astype(np.float32)
    xs = SPEC.xs()
    slot = (xs >= 5.0) & (xs < 9.0)  # cells 5.0 .. 8.9: walls at 4.95 and 8.95
    h[:, slot] -= 3.0
    p = M.line_profile(h, SPEC, (0.0, 20.0), (14.0, 20.0), width_mm=1.0)
    s = M.step_height(p, (1.0, 4.0), (6.0, 8.0))
    assert s.difference_mm == pytest.approx(-3.0, abs=0.01)
    assert s.a.sd_mm == pytest.approx(0.02 / math.sqrt(11), rel=0.5) and s.a.n == 31
    assert s.sd_mm == pytest.approx(math.hypot(s.a.sd_mm, s.b.sd_mm))
    w = M.width_at_level(p, 8.5, around_mm=7.0)
    assert w.left_mm == pytest.approx(4.95, abs=0.01) and w.width_mm == pytest.approx(4.0, abs=0.02)
    h[:, (xs >= 8.6) & (xs < 9.4)] = np.nan  # the wall foot hidden: the top's end is the edge
    p = M.line_profile(h, SPEC, (0.0, 20.0), (14.0, 20.0))
    w = M.width_at_level(p, 8.5, around_mm=7.0)
    assert w.right_mm == pytest.approx(9.4, abs=0.01)


def test_levelling_three_points_and_region():
    h = ramp(SPEC, 0.05, -0.02, 3.0)
    h[50:60, 50:60] += 2.0  # a bump outside the fitted region
    pts = [(x, y, float(0.05 * x - 0.02 * y + 3.0)) for x, y in ((0, 10), (20, 10), (5, 30))]
    pl = M.plane_from_points(pts)
    assert (pl.a, pl.b, pl.c) == pytest.approx((0.05, -0.02, 3.0))
    lev = M.levelled(h, SPEC, pl)
    assert np.nanmax(np.abs(lev[100:, 100:])) < 1e-4 and lev[55, 55] == pytest.approx(2.0, abs=1e-4)
    fit = M.plane_from_region(h, SPEC, (10.0, 29.0), (15.0, 34.0))
    assert (fit.a, fit.b, fit.c) == pytest.approx((0.05, -0.02, 3.0), abs=1e-5)
    assert fit.rms_mm < 1e-4 and fit.n == 191 * 191
    assert fit.tilt_deg == pytest.approx(math.degrees(math.atan(math.hypot(0.05, 0.02))))
    with pytest.raises(InputError):
        M.plane_from_points([(0, 0, 1), (1, 1, 2), (2, 2, 3)])
    with pytest.raises(InputError):
        M.plane_from_points([(0, 0, 1), (1, 0, np.nan), (0, 1, 3)])
    with pytest.raises(InputError):
        M.plane_from_region(h, SPEC, (100, 200), (100, 200))
    assert M.levelled(h, SPEC, None) is h


def test_hillshade():
    flat = np.zeros((50, 60), np.float32)
    np.testing.assert_allclose(
        M.hillshade(flat, 0.1, 315, 30), math.sin(math.radians(30)), atol=1e-6
    )
    tilted = ramp(GridSpec(0, 0, 0.1, (50, 60)), 0.0, 1.0, 0.0)  # rises towards +y (north)
    north = M.hillshade(tilted, 0.1, 0, 45)  # light from the north: the slope faces away
    south = M.hillshade(tilted, 0.1, 180, 45)
    assert (south > north).all()
    tilted[10:12, 10:12] = np.nan
    hs = M.hillshade(tilted, 0.1, 180, 45, chunk_rows=7)
    assert np.isnan(hs[10:12, 10:12]).all() and np.isfinite(hs).sum() == hs.size - 4
    np.testing.assert_allclose(hs[np.isfinite(hs)], south[np.isfinite(hs)], atol=1e-6)


def test_csv_round_trip_and_measurements_table():
    h = ramp(SPEC, 0.1, 0.0, 0.0)
    h[:, 100:110] = np.nan
    p = M.line_profile(h, SPEC, (-5.0, 20.0), (5.0, 20.0), width_mm=0.5)
    s = M.step_height(p, (0, 2), (8, 10))
    text = M.profile_csv(p, s)
    assert text.startswith("# IMPREsS profile") and "# step B - A:" in text
    d, z = M.read_profile_csv(text)
    np.testing.assert_allclose(d, p.distance_mm, atol=1e-4)
    np.testing.assert_allclose(z, p.height_mm, atol=1e-4)
    assert np.isnan(z).sum() == np.isnan(p.height_mm).sum() > 0
    r = M.ruler(h, SPEC, (0, 10), (3, 14))
    m1 = M.new_measurement(
        "ruler",
        [(0, 10), (3, 14)],
        M.ruler_values(r) | M.step_values(s),
        label='slot, "deep"',
        params={"width_mm": 0.5},
    )
    m2 = M.new_measurement("annotation", [(1, 2)], {"height_mm": float("nan")}, label="nick")
    assert m2["values"]["height_mm"] is None  # JSON-able
    rows = M.measurements_csv([m1, m2]).splitlines()
    assert rows[0].startswith("number,id,kind,label,note,x1_mm,y1_mm,x2_mm,y2_mm,xy_mm")
    assert rows[1].split(",")[:3] == ["1", m1["id"], "ruler"] and '"slot, ""deep"""' in rows[1]
    assert len(rows) == 3
    with pytest.raises(InputError):
        M.new_measurement("volume", [], {})
    # text a spreadsheet would run as a formula is written as text; numbers stay numbers
    m3 = M.new_measurement("annotation", [(-1.5, 2)], {"height_mm": -0.25},
                           label='=HYPERLINK("http://x","y")', note="@SUM(A1)")
    (row,) = list(csv.DictReader(io.StringIO(M.measurements_csv([m3]))))
    assert row["label"] == '\'=HYPERLINK("http://x","y")' and row["note"] == "'@SUM(A1)"
    assert float(row["x1_mm"]) == -1.5 and float(row["height_mm"]) == -0.25
    # a text value or layer read from a project file is text too
    m4 = M.new_measurement("annotation", [(0, 0)], {"height_mm": -0.5, "=cmd": "=1+1"},
                           params={"layer": "@x"})
    (row,) = list(csv.DictReader(io.StringIO(M.measurements_csv([m4]))))
    assert row["'=cmd"] == "'=1+1" and row["layer"] == "'@x" and row["height_mm"] == "-0.5000"


def test_damaged_reconstruction_folders(tmp_path):
    with pytest.raises(FormatError):
        M.load_reconstruction(tmp_path)
    (tmp_path / "metadata.json").write_text("{not json")
    with pytest.raises(FormatError):
        M.load_reconstruction(tmp_path)
    (tmp_path / "metadata.json").write_text('{"format": "impress.reconstruction", "version": 9}')
    with pytest.raises(FormatError, match="version"):
        M.load_reconstruction(tmp_path)
    (tmp_path / "metadata.json").write_text(
        '{"format": "impress.reconstruction", "version": 1, "grid": {"x0_mm": 0, "y0_mm": 0, '
        '"pixel_mm": 0.1, "shape": [4, 5]}}'
    )
    with pytest.raises(FormatError, match="missing"):
        M.load_reconstruction(tmp_path)
    import tifffile

    tifffile.imwrite(tmp_path / "heightmap.tif", np.zeros((5, 4), np.float32))
    with pytest.raises(FormatError, match="shape"):
        M.load_reconstruction(tmp_path)
    tifffile.imwrite(tmp_path / "heightmap.tif", np.zeros((4, 5), np.float32))
    data = M.load_reconstruction(tmp_path)
    assert data.spec.shape == (4, 5) and set(data.layers) == {"fused"} and data.texture_rgb is None


# ----- the simulated blocks scan ----------------------------------------------------------------
@pytest.fixture(scope="module")
def scan(request, tmp_path_factory):
    return blocks_scan(request.config, tmp_path_factory)


@pytest.fixture(scope="module")
def recon(request, tmp_path_factory):
    return M.load_reconstruction(blocks_recon(request.config, tmp_path_factory))


@pytest.fixture(scope="module")
def slots(scan):
    return [f for f in truth(scan)["features"] if f["kind"] == "slot"]


def across_block_a(scan, recon, dy_mm: float, width_mm: float) -> M.Profile:
    y = rail_y(scan, 190.0) + dy_mm  # block A's centre line, profile along x
    return M.line_profile(recon.height_mm, recon.spec, (-40.0, y), (40.0, y), width_mm)


def test_loaded_reconstruction(recon):
    assert recon.spec.pixel_mm == pytest.approx(0.1)
    assert set(recon.layers) == {"fused", "green", "red", "difference", "contribution"}
    assert recon.texture_rgb is not None and recon.texture_rgb.shape == (*recon.spec.shape, 3)
    assert not recon.height_mm.flags.writeable


@pytest.mark.parametrize("dy", [-8.0, 0.0, 8.0])
def test_slot_depth_as_step_height_within_0_1_mm(scan, recon, slots, dy):
    f = slots[0]  # the widest slot
    p = across_block_a(scan, recon, dy, width_mm=10.0)
    left = f["centre_a_mm"] - f["width_mm"] / 2 + 40.0
    s = M.step_height(p, (left - 4.5, left - 1.0), (left + 0.6, left + f["width_mm"] - 0.6))
    assert -s.difference_mm == pytest.approx(f["depth_mm"], abs=0.1)
    assert s.a.sd_mm < 0.1 and s.b.sd_mm < 0.1 and s.a.n > 30 and s.b.n > 30


def test_block_and_plate_heights(scan, recon):
    """Absolute heights carry the reconstruction's residual errors, hence 0.25 mm."""
    y = rail_y(scan, 190.0)
    top = M.readout(recon.height_mm, recon.spec, 28.5, y + 10.0, radius_mm=2.0)
    plate = M.readout(recon.height_mm, recon.spec, -60.0, y + 10.0, radius_mm=2.0)
    assert top.height_mm == pytest.approx(TOP, abs=0.25) and top.n_valid > 1000
    assert plate.height_mm == pytest.approx(12.0, abs=0.25)
    r = M.ruler(recon.height_mm, recon.spec, (-60.0, y + 10.0), (28.5, y + 10.0), 2.0)
    assert r.dz_mm == pytest.approx(20.0, abs=0.25) and r.xy_mm == pytest.approx(88.5)


@pytest.mark.parametrize("dy", [-8.0, 0.0, 8.0])
def test_slot_wall_and_width(scan, recon, slots, dy):
    f = slots[0]
    p = across_block_a(scan, recon, dy, width_mm=2.0)
    level = TOP - STEP / 2
    wall = f["centre_a_mm"] - f["width_mm"] / 2
    assert np.abs(M.level_crossings(p, level) - 40.0 - wall).min() < 0.1
    w = M.width_at_level(p, level, f["centre_a_mm"] + 40.0)
    assert w.left_mm - 40.0 == pytest.approx(wall, abs=0.1)
    assert w.width_mm == pytest.approx(f["width_mm"], abs=0.3)


def test_levelling_on_the_plate(scan, recon):
    """A region fit on the plate beside the block: nearly no tilt, and the block's top stands
    20 mm above the plate (0.25 mm)."""
    y = rail_y(scan, 190.0)
    plane = M.plane_from_region(recon.height_mm, recon.spec, (-75.0, 75.0), (y - 55, y - 25))
    assert plane.tilt_deg < 0.3 and plane.rms_mm < 0.15 and plane.n > 300_000
    lev = M.levelled(recon.height_mm, recon.spec, plane)
    for x in (-28.5, 28.5):
        top = M.readout(lev, recon.spec, x, y + 10.0, radius_mm=2.0)
        assert top.height_mm == pytest.approx(20.0, abs=0.25)
