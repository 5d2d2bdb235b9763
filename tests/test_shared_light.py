"""One laser's detector taking the other laser's stripe (issue 18: "never take one laser's
light for the other's"). Where both lasers' rows meet in a column but the two points they
give through the two planes lie apart, the laser whose run of columns lies on the other's
light over the larger share loses it (stripes.shared_light; in random rig 205 the red
detector took the green stripe on the ground in runs of 4-8 columns, frame after frame:
pieces of the red map 60 mm up)."""

import json

import numpy as np

from impress_gui.core.reconstruction import reconstruct as R
from impress_gui.core.reconstruction import stripes as S
from impress_gui.core.reconstruction.stripes import shared_light


def _stripes(n=300):
    c = np.arange(n, dtype=float)
    green = 670.0 + 0.01 * c
    red = 320.0 - 0.02 * c
    return green, red


def test_a_short_run_on_the_other_lasers_light_is_dropped_whole():
    green, red = _stripes()
    red[100:108] = green[100:108]  # red took green's light in 8 columns
    red[100] += 0.6  # within the row tolerance of green, not exactly on it
    conflict = np.zeros(300, bool)
    conflict[101:108] = True  # the check found 7 of the 8 apart (one just out of reach)
    dg, dr = shared_light(green, red, conflict, 2.0)
    assert not dg.any()
    assert np.flatnonzero(dr).tolist() == list(range(100, 108))  # the whole run, 7/8 >= 0.5


def test_only_the_conflicting_columns_of_a_longer_run_go_and_equal_shares_lose_both():
    green, red = _stripes()
    red[100:120] = green[100:120]  # a 20-column run; 6 of them found apart
    conflict = np.zeros(300, bool)
    conflict[100:106] = True
    dg, dr = shared_light(green, red, conflict, 2.0)
    assert not dg.any() and np.flatnonzero(dr).tolist() == list(range(100, 106))
    # both stripes broken to the same short piece: neither can be told from the other
    g2, r2 = np.full(300, np.nan), np.full(300, np.nan)
    g2[50:55] = r2[50:55] = 400.0
    c2 = np.zeros(300, bool)
    c2[50:55] = True
    dg, dr = shared_light(g2, r2, c2, 2.0)
    assert np.flatnonzero(dg).tolist() == np.flatnonzero(dr).tolist() == list(range(50, 55))
    # nothing apart: nothing dropped (where the two planes meet both lasers light one pixel)
    dg, dr = shared_light(green, red, np.zeros(300, bool), 2.0)
    assert not dg.any() and not dr.any()


def _red_takes_green(monkeypatch, cols):
    """Every frame, the red detector reports the green stripe's rows (and strength) in
    ``cols``, as rig 205's did."""
    made = {}
    init, call = S.StripeDetector.__init__, S.StripeDetector.__call__

    def init2(self, name, *a, **k):
        init(self, name, *a, **k)
        if k.get("ground") is not None:  # each laser's detector (not its second look's)
            made[name] = self

    def call2(self, planes):
        res = call(self, planes)
        g = made.get("green")
        if self is made.get("red") and g is not None:
            ok = np.isfinite(g.result.rows[cols])
            res.rows[cols][ok] = g.result.rows[cols][ok]
            res.strength[cols][ok] = g.result.strength[cols][ok]
        return res

    monkeypatch.setattr(S.StripeDetector, "__init__", init2)
    monkeypatch.setattr(S.StripeDetector, "__call__", call2)


def _wild_cells(scan, cal_path, params, laser="red"):
    """Cells of ``laser``'s map more than 1 mm off the truth, and the reconstruction."""
    from impress_gui.core.calibration.scene import SceneCalibration
    from impress_gui.core.formats.video import open_video
    from impress_gui.sim.truth import truth_for_reconstruction

    cal = SceneCalibration.load(cal_path)
    truth = json.loads((scan / "truth.json").read_text())
    with open_video(scan / truth["video"]) as v:
        rec = R.reconstruct(v, cal, params)
    h = rec.per_laser_mm[laser]
    t = truth_for_reconstruction(scan, rec.spec, h, cal.reference_depth, cal.rotation)
    ok = np.isfinite(h) & np.isfinite(t)
    return int((np.abs(h - t)[ok] > 1.0).sum()), rec


def test_the_red_detector_taking_the_green_stripe_leaves_no_wild_points(
        flat_scan, flat_calibration, monkeypatch):
    """The flat scan with the red detector fed green's stripe in 8 columns of every frame:
    those columns are dropped from red's rows and the red map has no point more than 1 mm
    off the truth; with the check off (monkeypatched) the same input gives such points, so
    the check is what removes them. Green's map is untouched."""
    # the island steps and the rows' height range off, so that only this check can remove
    # the points (the scan's own red map then has points more than 1 mm off by the target's
    # edges: counted first)
    monkeypatch.setattr(R, "BEYOND_RANGE_PX", 1e9)
    # and the lasers not reconciled: the maps as the detectors made them (the wild points
    # with the check off would move the lasers' fitted difference, and green's map with it)
    params = R.ProcessParams(texture=False, floating_max_cells=0, island_max_cells=0,
                             frame_start=60, frame_stop=140, reconcile_lasers=False)
    before, _ = _wild_cells(flat_scan, flat_calibration, params)
    _red_takes_green(monkeypatch, slice(300, 308))
    wild, rec = _wild_cells(flat_scan, flat_calibration, params)
    dropped = rec.stats["stripe_columns_other_laser_dropped"]
    n = rec.stats["frames_processed"]
    assert dropped["green"] == 0 and dropped["red"] >= 8 * 0.8 * n
    monkeypatch.setattr(R, "SHARED_ROW_PX", -1.0)  # the check off
    wild_off, rec_off = _wild_cells(flat_scan, flat_calibration, params)
    print(f"red cells over 1 mm off: scan alone {before}, fed green's light {wild}, "
          f"the same with the check off {wild_off}; columns dropped {dropped} in {n} frames")
    assert wild <= before + 10
    assert rec_off.stats["stripe_columns_other_laser_dropped"]["red"] == 0
    assert wild_off > before + 500
    assert np.array_equal(rec.per_laser_mm["green"], rec_off.per_laser_mm["green"],
                          equal_nan=True)


def _green_reads_beyond(monkeypatch, cal_path, size, cols, below_px, cut_px=40):
    """Every frame, the green detector reports a row ``below_px`` rows past its column's own
    end of band in ``cols`` (inside the band the detector searches, which is as high as its
    largest column's), as rig 208's did where it took the red stripe. The flat scan's bands
    are nearly equal in every column, so the columns' own ends are brought ``cut_px`` rows
    in (as a rolled camera's slanted stripe has them), the band searched left as it was."""
    from impress_gui.core.calibration.scene import SceneCalibration

    cal = SceneCalibration.load(cal_path)
    limits = R.column_band_limits(cal, size, R.ProcessParams().height_range_mm)
    start, stop = limits["green"]
    height = int((stop - start).max())
    short = stop.copy()
    short[cols] -= cut_px
    row = (short - 1 + below_px).astype(float)
    usable = np.zeros(size[0], bool)
    usable[cols] = True
    usable &= row < start + height - 1  # the detector can report it
    limits_of = R.column_band_limits

    def limits2(*a, **k):
        out = limits_of(*a, **k)
        a0, b0 = out["green"]
        b1 = b0.copy()
        b1[cols] -= cut_px
        out["green"] = (a0, b1)
        return out

    init, call = S.StripeDetector.__init__, S.StripeDetector.__call__
    made = {}

    def init2(self, name, *a, **k):
        init(self, name, *a, **k)
        if k.get("ground") is not None:  # each laser's detector (not its second look's)
            made[name] = self

    def call2(self, planes):
        res = call(self, planes)
        if self is made.get("green"):
            res.rows[usable] = row[usable]
            res.strength[usable] = 200.0
        return res

    monkeypatch.setattr(R, "column_band_limits", limits2)
    monkeypatch.setattr(S.StripeDetector, "__init__", init2)
    monkeypatch.setattr(S.StripeDetector, "__call__", call2)
    return int(usable.sum())


def test_a_stripe_read_beyond_the_height_range_is_dropped(flat_scan, flat_calibration,
                                                          monkeypatch):
    """The flat scan with the green detector fed a row 10 px past its column's end of band
    in 40 columns of every frame (a surface below the height range, which no column's band
    was made for): those rows are dropped, and the green map has no more points over 1 mm
    off than the scan alone; with the check off (monkeypatched) they are in the map."""
    import cv2

    truth = json.loads((flat_scan / "truth.json").read_text())
    cap = cv2.VideoCapture(str(flat_scan / truth["video"]))
    size = (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
    cap.release()
    params = R.ProcessParams(texture=False, floating_max_cells=0, island_max_cells=0,
                             frame_start=60, frame_stop=140)

    def green_wild():
        return _wild_cells(flat_scan, flat_calibration, params, "green")

    before, _ = green_wild()
    n = _green_reads_beyond(monkeypatch, flat_calibration, size, slice(200, 240), 10)
    assert n >= 20
    wild, rec = green_wild()
    beyond = rec.stats["stripe_columns_beyond_height_range"]
    assert beyond["green"] >= n * rec.stats["frames_processed"]
    monkeypatch.setattr(R, "BEYOND_RANGE_PX", 1e9)  # the check off
    wild_off, rec_off = green_wild()
    print(f"green cells over 1 mm off: scan alone {before}, fed rows past the band {wild}, "
          f"the same with the check off {wild_off}; {n} columns a frame")
    assert rec_off.stats["stripe_columns_beyond_height_range"]["green"] == 0
    assert wild <= before + 10
    assert wild_off > before + 500
