"""Do the stated uncertainties cover the true errors? (issue 22)

For each random rig (the cached simulator scans of bench_random_rigs.py at 640x360) and each of
``--draws`` click-noise draws: the scene is calibrated from the simulator's exact corner picks
plus normal noise of ``--noise-px`` (as a person's clicks), reconstructed with the default
settings, and random readings of every kind are taken on the map with their budgets
(impress_gui.core.measure.uncertainty, the calibration's Monte Carlo with ``--trials`` trials).
Each reading's true value comes from the simulator's truth:

- heights (point, step B - A, depth below a plane through three points, dz): the same
  readings on the true height of the PHYSICAL point each reconstructed cell shows (its camera
  ray at its time through the TRUE calibration: the simulator's rotation, laser planes and
  target pose, core.calibration.uncertainty.map_points; Rig.physical_truth). Not the truth at
  the same map coordinates (sim.truth.truth_for_reconstruction): the map's frame is the
  calibration's own, turned against the true one by its tilt error, which at 0.5 px of click
  noise puts the scene up to ~10 mm away along the scan (random rig 0, draw 1: 7.3 mm); an
  examiner picks points by what the map shows, so a reading's measurand is the physical
  points shown, and the same-cell truth charged the frame's shift to readings wherever it
  carried a point across an edge (a depth error of 3.1 mm on flat blocks). The depth's plane
  is taken through the supports' true positions, at the point's true position;
- lengths (ruler xy and 3D, width at a level): the reading's end points taken to where they
  truly are by the true calibration (map_points). "width" is at a level fixed from outside the
  profile (the truth's mid-height: a calibration's absolute height error moves its crossings);
  "width (bands)" is measured as ``impress validate`` measures one, at half the step between a
  band on the feature and one beside it on the same profile (the level moves with the surface;
  its true value: the same bands on the true profile; only where the band inside truly lies on
  the feature and the one beside it off it - since 3 December 2026: before, two bands on the
  ground either side of a wall hidden in a gap gave a level at the ground's own height and
  errors of 30 mm, a measurand that does not exist). A width's true crossings are taken on
  the truth with the map's gaps filled within GAP_TRUTH_MM of data (since 3 December 2026,
  later; physical_truth): a wall hidden in a gap of the map lies somewhere in the gap, and the
  truth read only at the map's cells put its crossing exactly at the map's.

Coverage = the share of readings whose true error lies within their expanded uncertainty
U (k = 2); the target is 93-97 % per reading kind. Readings on or near a height edge (a jump of
more than 1 mm within 0.5 mm in the truth) are left out: there the measurand itself is not
defined to better than a cell. A cell the two lasers disagreed on is taken as the laser the
fusion kept (the per-laser maps are given to the budgets too).

Coverage is printed with a 90 % interval from a bootstrap over the calibrations (every reading
of a scan shares its calibration's error, so the calibrations, not the readings, are the
sample: with 48 calibrations a kind's interval spans several points) and a verdict against
the band: inside, over or under, and whether the interval lies within, beyond or across it.

The budgets are the product's: no validation record, so the method's own component is the
product's figure (impress_gui.core.measure.uncertainty.METHOD_STRIPE_PX), whose two values
were found on seeds 0-23 and checked on seeds 24-47 (docs/uncertainty.md "The method's own
component"); ``--stripe-model`` chooses the calibration Monte Carlo's stripe model. Each
reading saved with ``--json`` carries its budget's parts and ``per_px``, the height per pixel
of stripe shift of the lasers at its (first) point; a width its ``walls``: per wall the gap
between the samples with data that bracket its crossing, the level's fraction of the drop
between them, one scanner sample along the profile and how far the true crossing lies into
the gap from the measured one (``--gap-rules`` chooses how far a wall hidden in a gap may
lie: impress_gui.core.measure.uncertainty.GAP_RULES).

Usage: .venv/bin/python benchmarks/bench_uncertainty.py [--seeds 0,1,2,3] [--draws 2]
       [--first-draw 0] [--noise-px 0.5] [--trials 30] [--per-kind 25] [--json out.json]
       [--stripe-model measured] [--noise-rules largest,median,rms,agreement]
       [--gap-rules whole,geometric]
       .venv/bin/python benchmarks/bench_uncertainty.py --from-json a.json b.json
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import replace
from pathlib import Path

import common
import numpy as np

from impress_gui.sim.truth import true_cal_params as true_params

KINDS = ("height", "ruler xy", "ruler 3D", "ruler dz", "step height", "width", "width (bands)",
         "depth")


#: cells without data this near a cell with data get a truth too (mm): a wall hidden in a gap
#: of the map (an occluded foot, a shadow) lies somewhere in the gap, and a width's true
#: crossing is where the true surface crosses the level there, not at the gap's edge
GAP_TRUTH_MM = 2.5


def physical_truth(scan_dir: Path, cal, rec, nominal=None, true=None) -> np.ndarray:
    """The true height of the physical point each reconstructed cell shows: the cell's
    camera ray at its time through the TRUE calibration (map_points), the simulator's height
    map read there (for a cell both lasers made, the mean over the two lasers' points; for
    one where they disagreed, the laser the fusion kept). Not the truth at the same map
    coordinates: the map's frame is the calibration's, turned against the true one by its
    tilt and roll errors (0.5 px of click noise: up to ~9 mm along y at the scene), and a
    point the examiner picks on the map is the physical point shown there. ``rec``: the
    reconstruction (its fused map, contribution codes and per-laser maps); ``nominal`` and
    ``true``: the calibration's and the true CalParams (made from ``cal`` when not given).

    Cells without data within :data:`GAP_TRUTH_MM` of data (since 3 December 2026, later)
    get the true surface too, read where the nearest cell with data truly is, moved by the
    map's local step to the gap cell (an affine fit of the cells' true positions). Before, the truth had the map's gaps, so a
    wall hidden in a gap had its true crossing at the gap's edge, exactly where the map's is
    (level_crossings puts it at the higher side's last sample): widths' errors there were 0
    by construction (most band widths' walls on random rigs 0-23)."""
    import tifffile
    from scipy import ndimage

    from impress_gui.core.calibration.uncertainty import CalParams, map_points
    from impress_gui.sim.truth import _turn_ideal_to_rail

    nominal = CalParams.of_calibration(cal) if nominal is None else nominal
    true = true_params(scan_dir, cal) if true is None else true
    truth = json.loads((scan_dir / "truth.json").read_text())
    turn = _turn_ideal_to_rail(truth, cal.rotation)  # the true params' frame -> rail
    hm = truth["heightmap"]
    tmap = tifffile.imread(scan_dir / hm["file"])
    s1 = truth["travel_mm"][truth["calibration_frames"]["t1"]]
    ref = true.ref[0]

    def surface(x, y, h, name):
        """Where laser ``name``'s points (x, y, h) truly are (rail frame x, y) and the true
        surface height there."""
        tx, ty, th = (v[0] for v in map_points(nominal, true, x, y, h, name))
        z = ref[0] + ref[1] * tx + ref[2] * ty - th
        p = np.column_stack([tx, ty, z]) @ turn.T
        return p[:, 0], p[:, 1], read(p[:, 0], p[:, 1])

    def read(px, py):
        ci = np.rint((py + s1 - hm["y0_mm"]) / hm["pixel_mm"]).astype(int)
        cj = np.rint((px - hm["x0_mm"]) / hm["pixel_mm"]).astype(int)
        inside = (ci >= 0) & (ci < tmap.shape[0]) & (cj >= 0) & (cj < tmap.shape[1])
        v = np.full(len(px), np.nan)
        v[inside] = tmap[ci[inside], cj[inside]]
        return v

    measured = np.isfinite(rec.height_mm)
    ii, jj = np.nonzero(measured)
    x, y = rec.spec.xs()[jj], rec.spec.ys()[ii]
    h = rec.height_mm[ii, jj].astype(float)
    code = np.asarray(rec.contribution)[ii, jj]
    both = float(rec.stats.get("fusion_weights", {}).get("green", 0.5))  # the fusion's weight
    wg = np.where(code == 1, 1.0, np.where(code == 2, 0.0, both))
    four = code == 4
    if four.any():
        g, r = (np.asarray(rec.per_laser_mm[n])[ii[four], jj[four]] for n in ("green", "red"))
        wg[four] = np.where(np.abs(g - h[four]) <= np.abs(r - h[four]), 1.0, 0.0)
    out_v = np.zeros(len(x))
    pos = np.zeros((len(x), 2))  # where each cell's point truly is (rail frame, weighted)
    for name, w in (("green", wg), ("red", 1.0 - wg)):
        for a in range(0, len(x), 500_000):
            sl = slice(a, a + 500_000)
            sel = np.flatnonzero(w[sl] > 0) + a
            if not sel.size:
                continue
            px, py, v = surface(x[sel], y[sel], h[sel], name)
            out_v[sel] += w[sel] * v
            pos[sel, 0] += w[sel] * px
            pos[sel, 1] += w[sel] * py
    out = np.full(rec.spec.shape, np.nan, np.float32)
    out[ii, jj] = out_v
    # the gaps near data: the nearest cell with data's true position, moved by the map's
    # local step to the gap cell (the map's frame against the true one: an affine fit over
    # the cells with data), the true surface read there. (Not a point of the gap cell's own
    # ray: no laser point exists there, and one at a wrong height maps to another frame.)
    dist, (ni, nj) = ndimage.distance_transform_edt(~measured, return_indices=True)
    gi, gj = np.nonzero(~measured & (dist * rec.spec.pixel_mm <= GAP_TRUTH_MM))
    if gi.size and len(x) >= 3:
        k = np.linspace(0, len(x) - 1, min(len(x), 200_000)).astype(int)
        design = np.column_stack([x[k], y[k], np.ones(len(k))])
        coef, *_ = np.linalg.lstsq(design, pos[k], rcond=None)  # (3, 2): [x, y, 1] -> p
        index = np.full(rec.spec.shape, -1, np.int64)
        index[ii, jj] = np.arange(len(x))
        m = index[ni[gi, gj], nj[gi, gj]]
        gx, gy = rec.spec.xs()[gj], rec.spec.ys()[gi]
        step = np.column_stack([gx - x[m], gy - y[m]]) @ coef[:2]
        out[gi, gj] = read(pos[m, 0] + step[:, 0], pos[m, 1] + step[:, 1])
    return out


class Rig:
    """One calibrated, reconstructed draw and what the readings need."""

    def __init__(self, seed: int, draw: int, noise_px: float, trials: int,
                 speed_error_rel: float = 0.0, stripe_model: str | None = None) -> None:
        from impress_gui.core.calibration.target import TargetModel
        from impress_gui.core.calibration.uncertainty import CalParams
        from impress_gui.core.formats.video import open_video
        from impress_gui.core.measure.uncertainty import UncertaintyContext
        from impress_gui.core.reconstruction.reconstruct import (
            ProcessParams,
            reconstruct,
        )
        from impress_gui.sim.truth import truth_for_reconstruction

        d = common.CACHE / f"random-{seed}-640x360-{common.SIM_KEY}"
        if not (d / "truth.json").exists():
            raise FileNotFoundError(f"{d}: not cached (this benchmark renders nothing: "
                                    f"bench_random_rigs.py --seeds {seed}, renders it)")
        self.dir = d
        truth = json.loads((d / "truth.json").read_text())
        t0 = time.perf_counter()
        # the speed entered: the rail's true speed off by the servo's regulation (a uniform
        # draw within +-speed_error_rel), as the budget's rail-speed component claims
        eps = float(np.random.default_rng(7919 * seed + draw).uniform(-1.0, 1.0)) * speed_error_rel
        self.entered_speed = truth["speed_mm_s"] * (1.0 + eps)
        self.cal = cal = common.calibrate(d, noise_px=noise_px, seed=1000 * seed + draw + 1,
                                          speed_mm_s=self.entered_speed)
        with open_video(d / truth["video"]) as v:
            rec = reconstruct(v, cal, ProcessParams(**PROCESS))
        self.t_rec = time.perf_counter() - t0
        self.spec = rec.spec
        self.h = rec.height_mm
        self.same_cell_truth = truth_for_reconstruction(d, rec.spec, rec.height_mm,
                                                        cal.reference_depth)
        t0 = time.perf_counter()
        self.ctx = UncertaintyContext.for_calibration(
            self.h, rec.spec, cal, TargetModel.load(d / "target.json"), rec.contribution,
            trials=trials, per_laser=rec.per_laser_mm,
            fusion_weights=rec.stats.get("fusion_weights"), stripe_model=stripe_model)
        self.per_px = self.ctx.per_px or {"green": math.nan, "red": math.nan}
        self.t_mc = time.perf_counter() - t0
        self.nominal = CalParams.of_calibration(cal)
        true = true_params(d, cal)  # the true travel over the entered one: the speed's error
        self.true = replace(true, speed_scale=np.array([truth["speed_mm_s"] / self.entered_speed]))
        self.contrib = rec.contribution
        # the truth with the map's gaps filled near data (widths' true crossings), and as
        # the map shows it (every other reading: the same cells as the measured reading)
        self.truth_filled = self.physical_truth(rec)
        self.truth = np.where(np.isfinite(self.h), self.truth_filled, np.float32(np.nan))
        self.edge = common.edge_mask(self.truth, 5, 1.0)
        self.ok = np.isfinite(self.h) & np.isfinite(self.truth) & ~self.edge
        self.cells = np.argwhere(self.ok)

    def physical_truth(self, rec) -> np.ndarray:
        """:func:`physical_truth` of this draw's map."""
        return physical_truth(self.dir, self.cal, rec, self.nominal, self.true)

    def to_true(self, x, y, h):
        """Map points to where they truly are (true ideal frame)."""
        from impress_gui.core.calibration.uncertainty import map_points

        x, y, h = (np.atleast_1d(np.asarray(v, float)) for v in (x, y, h))
        out = np.zeros((3, len(x)))
        for n in range(len(x)):
            acc = np.zeros(3)
            for laser, w in self.ctx.lasers_at(x[n], y[n]):
                tx, ty, th = map_points(self.nominal, self.true, x[n:n + 1], y[n:n + 1],
                                        h[n:n + 1], laser)
                acc += w * np.array([tx[0, 0], ty[0, 0], th[0, 0]])
            out[:, n] = acc
        return out

    def random_point(self, rng):
        i, j = self.cells[rng.integers(len(self.cells))]
        return float(self.spec.x0_mm + j * self.spec.pixel_mm), float(
            self.spec.y0_mm + i * self.spec.pixel_mm)

    def clean_disk(self, x, y, r) -> bool:
        from impress_gui.core.measure.readings import readout

        e = readout(self.edge.astype(np.float32), self.spec, x, y, r + 0.5)
        return e.has_data and e.height_mm == 0.0


def readings(rig: Rig, rng, per_kind: int) -> list[dict]:
    from impress_gui.core.measure import readings as M
    from impress_gui.core.measure import uncertainty as U

    out: list[dict] = []
    ctx, spec = rig.ctx, rig.spec
    radius = 0.5

    def add(kind, budget, err, x, y, walls=None):
        if math.isfinite(err) and budget.incomplete:  # no U stated: counted, not covered
            out.append({"kind": kind, "err": float(err), "U": None, "u_c": None,
                        "incomplete": budget.incomplete, "x": x, "y": y,
                        "value": budget.value_mm})
        elif math.isfinite(err) and math.isfinite(budget.U_mm):
            _, _, _, gx, gy = U.patch_noise(rig.truth, spec, x, y, 1.0)
            out.append({"kind": kind, "err": float(err), "U": budget.U_mm, "u_c": budget.u_c_mm,
                        "parts": {c.name: c.u_mm for c in budget.components},
                        "x": x, "y": y, "slope": float(math.hypot(gx, gy)),
                        "value": budget.value_mm,
                        # the mm per stripe pixel of the lasers that made the point
                        "per_px": _finite(sum(w * rig.per_px[la] for la, w in ctx.lasers_at(x, y)))})
            if walls is not None:
                out[-1]["walls"] = walls

    tries = 0
    counts = dict.fromkeys([k for k in KINDS if k != "width (bands)"], 0)
    while tries < 25 * per_kind and min(counts.values()) < per_kind:
        tries += 1
        x, y = rig.random_point(rng)
        if not rig.clean_disk(x, y, radius):
            continue
        # height at a point
        if counts["height"] < per_kind:
            r = M.readout(rig.h, spec, x, y, radius)
            t = M.readout(rig.truth, spec, x, y, radius)
            if r.has_data and t.has_data:
                add("height", U.height_budget(ctx, r), r.height_mm - t.height_mm, x, y)
                counts["height"] += 1
        # ruler: a second point 10-60 mm away
        ang = rng.uniform(0, 2 * math.pi)
        dist = rng.uniform(10, 60)
        x2, y2 = x + dist * math.cos(ang), y + dist * math.sin(ang)
        if min(counts["ruler xy"], counts["ruler 3D"], counts["ruler dz"]) < per_kind and \
                rig.clean_disk(x2, y2, radius):
            r = M.ruler(rig.h, spec, (x, y), (x2, y2), radius)
            t = M.ruler(rig.truth, spec, (x, y), (x2, y2), radius)
            if np.isfinite([r.dz_mm, t.dz_mm]).all():
                b = U.ruler_budgets(ctx, r)
                p = rig.to_true([x, x2], [y, y2], [r.start.height_mm, r.end.height_mm])
                xy_true = math.hypot(p[0, 1] - p[0, 0], p[1, 1] - p[1, 0])
                dz_true = t.dz_mm
                for key, kind, err in (("xy", "ruler xy", r.xy_mm - xy_true),
                                       ("3d", "ruler 3D", r.d3_mm - math.hypot(xy_true, dz_true)),
                                       ("dz", "ruler dz", r.dz_mm - dz_true)):
                    if counts[kind] < per_kind:
                        add(kind, b[key], err, x, y)
                        counts[kind] += 1
        # a profile 24 mm long from the point, 1 mm wide: a step between bands and a width
        x3, y3 = x + 24 * math.cos(ang), y + 24 * math.sin(ang)
        if counts["step height"] < per_kind or counts["width"] < per_kind:
            prof = M.line_profile(rig.h, spec, (x, y), (x3, y3), 1.0)
            tprof = M.line_profile(rig.truth, spec, (x, y), (x3, y3), 1.0)
            ba, bb = (1.0, 5.0), (17.0, 21.0)
            ea = M.line_profile(rig.edge.astype(np.float32), spec, (x, y), (x3, y3), 2.0)
            clean = lambda band, ea=ea: np.nanmax(  # noqa: E731
                np.where((ea.distance_mm >= band[0] - 0.5) & (ea.distance_mm <= band[1] + 0.5),
                         ea.height_mm, 0.0)) == 0.0
            if counts["step height"] < per_kind and clean(ba) and clean(bb):
                s = M.step_height(prof, ba, bb)
                ts = M.step_height(tprof, ba, bb)
                if s.a.n >= 20 and s.b.n >= 20 and math.isfinite(ts.difference_mm):
                    add("step height", U.step_budget(ctx, prof, s, ba, bb),
                        s.difference_mm - ts.difference_mm, x, y)
                    counts["step height"] += 1
            if counts["width"] < per_kind:
                th = tprof.height_mm
                if np.isfinite(th).mean() > 0.9 and np.nanmax(th) - np.nanmin(th) > 1.5:
                    level = float((np.nanmax(th) + np.nanmin(th)) / 2)
                    tc = M.level_crossings(tprof, level)
                    if len(tc) == 2 and tc[1] - tc[0] > 1.0:
                        around = float((tc[0] + tc[1]) / 2)
                        w = M.width_at_level(prof, level, around)
                        # where the true surface crosses the level, gaps of the map included
                        tc = _true_crossings(rig, (x, y), (x3, y3), level, tc)
                        if math.isfinite(w.width_mm) and tc is not None:
                            ux, uy = (x3 - x) / 24, (y3 - y) / 24
                            pts = rig.to_true(x + tc * ux, y + tc * uy, [level, level])
                            w_true = math.hypot(pts[0, 1] - pts[0, 0], pts[1, 1] - pts[1, 0])
                            add("width", U.width_budget(ctx, prof, w), w.width_mm - w_true,
                                x + around * ux, y + around * uy,
                                _walls(U, ctx, prof, w, [level, level], tc))
                            counts["width"] += 1
        # depth below a plane through three points 8-15 mm around
        if counts["depth"] < per_kind:
            sup = []
            for k in range(3):
                a = ang + 2 * math.pi * k / 3 + rng.uniform(-0.3, 0.3)
                rr = rng.uniform(8, 15)
                sx, sy = x + rr * math.cos(a), y + rr * math.sin(a)
                if not rig.clean_disk(sx, sy, radius):
                    break
                sup.append((sx, sy))
            if len(sup) == 3:
                rs = [M.readout(rig.h, spec, sx, sy, radius) for sx, sy in sup]
                ts = [M.readout(rig.truth, spec, sx, sy, radius) for sx, sy in sup]
                r = M.readout(rig.h, spec, x, y, radius)
                t = M.readout(rig.truth, spec, x, y, radius)
                if all(v.has_data for v in (*rs, *ts, r, t)):
                    b = U.depth_budget(ctx, r, rs)
                    # the true depth: the plane through the physical points, at the physical
                    # point (their true positions; the map's are the calibration's)
                    q = rig.to_true([v.x_mm for v in (*rs, r)], [v.y_mm for v in (*rs, r)],
                                    [v.height_mm for v in (*rs, r)])
                    tp = M.plane_from_points([(q[0, k], q[1, k], v.height_mm)
                                              for k, v in enumerate(ts)])
                    add("depth", b, b.value_mm - float(tp.at(q[0, 3], q[1, 3]) - t.height_mm),
                        x, y)
                    counts["depth"] += 1
    # widths between bands: random profiles across one whole feature are rare on these scenes
    # (most are flat or cross one edge), so a pass of their own, each profile (60 mm) started
    # before a random wall and run across it, the feature between its first two crossings (its
    # own random stream: the readings above are as without it)
    wrng = np.random.default_rng(int(rng.integers(2**32)))
    edges = np.argwhere(rig.edge & np.isfinite(rig.truth))
    n = 0
    for _ in range(40 * per_kind if edges.size else 0):
        if n >= per_kind:
            break
        # across a wall: from 2-10 mm before a random edge cell, along the truth's gradient
        i, j = edges[wrng.integers(len(edges))]
        ex, ey = spec.x0_mm + j * spec.pixel_mm, spec.y0_mm + i * spec.pixel_mm
        _, _, _, gx, gy = U.patch_noise(rig.truth, spec, ex, ey, 1.0)
        if not (math.isfinite(gx) and math.hypot(gx, gy) > 0):
            continue
        ang = math.atan2(gy, gx) + (math.pi if wrng.random() < 0.5 else 0.0)
        back = wrng.uniform(2.0, 10.0)
        x, y = ex - back * math.cos(ang), ey - back * math.sin(ang)
        x3, y3 = x + 60 * math.cos(ang), y + 60 * math.sin(ang)
        tprof = M.line_profile(rig.truth, spec, (x, y), (x3, y3), 1.0)
        th = tprof.height_mm
        if np.isfinite(th).mean() <= 0.5 or np.nanmax(th) - np.nanmin(th) <= 1.5:
            continue
        prof = M.line_profile(rig.h, spec, (x, y), (x3, y3), 1.0)
        wb = _band_width(M, U, rig, ctx, prof, tprof, (x, y), (x3, y3))
        if wb is not None:
            add("width (bands)", *wb[:4], walls=wb[4])
            n += 1
    return out


def _finite(v) -> float | None:
    """``v`` as a float for the JSON, None where it is not finite (JSON has no NaN)."""
    v = float(v)
    return v if math.isfinite(v) else None


def _band_width(M, U, rig: Rig, ctx, prof, tprof, p0, p1):
    """A width the way ``impress validate`` measures one: at half the step between a band on
    the feature and one beside it, both on the measured profile (the level moves with the
    surface); the truth's width at half the step between the same bands of the true profile,
    its crossings taken to where they truly are. ``(budget, error, x, y, walls)`` (walls:
    :func:`_walls`) or None where the
    true profile has no feature (between its first two crossings of its mid-height) with bands
    on and beside it that hold no height edge and have data on both profiles."""
    th = tprof.height_mm
    mid_h = float((np.nanmax(th) + np.nanmin(th)) / 2)
    tc = M.level_crossings(tprof, mid_h)[:2]
    if len(tc) != 2 or tc[1] - tc[0] <= 2.0:
        return None
    mid = float((tc[0] + tc[1]) / 2)
    half = min(2.0, (tc[1] - tc[0]) / 2 - 1.0)
    if half < 0.3:
        return None
    length = prof.length_mm
    inside = (mid - half, mid + half)
    edge = M.line_profile(rig.edge.astype(np.float32), rig.spec, p0, p1, 1.0)

    def usable(b) -> bool:
        sel = (prof.distance_mm >= b[0]) & (prof.distance_mm <= b[1])
        return (b[1] - b[0] >= 1.0 and np.nanmax(edge.height_mm[sel]) == 0
                and np.isfinite(prof.height_mm[sel]).mean() >= 0.9
                and np.isfinite(th[sel]).mean() >= 0.9)

    # beside the feature: 1-5 mm before its first crossing, else after its second
    beside = [b for b in ((max(0.0, tc[0] - 5.0), tc[0] - 1.0),
                          (tc[1] + 1.0, min(length, tc[1] + 5.0))) if usable(b)]
    if not (usable(inside) and beside):
        return None
    bands = (inside, beside[0])
    # the band "inside" must lie on the feature and the one beside it off it (their true means
    # on either side of the mid-height that found the feature): where a wall hidden by a gap
    # wider than a crossing may span (level_crossings' max_gap) pairs the walls of two features,
    # both bands can lie on the ground, and a level at the ground's own height has no crossing
    # to measure (errors of 30 mm on random rig 42)
    if (M.band_stats(tprof, inside).mean_mm - mid_h) * (
            M.band_stats(tprof, beside[0]).mean_mm - mid_h) >= 0:
        return None
    tlevel = float(np.mean([M.band_stats(tprof, b).mean_mm for b in bands]))
    level = float(np.mean([M.band_stats(prof, b).mean_mm for b in bands]))
    tcs = M.level_crossings(tprof, tlevel)
    left, right = tcs[tcs <= mid], tcs[tcs > mid]
    w = M.width_at_level(prof, level, mid)
    if not (left.size and right.size and math.isfinite(w.width_mm)):
        return None
    # the true surface's crossings nearest those (gaps of the map included)
    ends = _true_crossings(rig, p0, p1, tlevel, np.array([left.max(), right.min()]))
    if ends is None:
        return None
    (x0, y0), (x1, y1) = p0, p1
    ux, uy = (x1 - x0) / length, (y1 - y0) / length
    pts = rig.to_true(x0 + ends * ux, y0 + ends * uy, [tlevel, tlevel])
    w_true = math.hypot(pts[0, 1] - pts[0, 0], pts[1, 1] - pts[1, 0])
    b = U.width_budget(ctx, prof, w, level_bands=(bands, bands))
    return (b, w.width_mm - w_true, x0 + mid * ux, y0 + mid * uy,
            _walls(U, ctx, prof, w, [level, level], ends))


def _walls(U, ctx, prof, w, levels, true_mm) -> list[dict]:
    """Per wall of a width (left, right): the samples with data that bracket its crossing
    (their gap, the level's fraction of the drop between them), one scanner sample along the
    profile, and how far the true crossing lies from the measured one towards the lower
    sample (mm; positive: into the gap), for the wall-in-a-gap term's rule (--gap-rules)."""
    L = prof.length_mm or 1.0
    (x0, y0), (x1, y1) = prof.start, prof.end
    s_mm, _ = U._profile_sampling(ctx, (x1 - x0) / L, (y1 - y0) / L)
    ds = [w.left_mm, w.right_mm]
    out = []
    for dd, t, (gap, _, frac, lower) in zip(ds, true_mm, U.crossing_samples(prof, ds, levels)):
        out.append({"gap": _finite(gap), "fraction": _finite(frac), "sample": _finite(s_mm),
                    "step": float(prof.distance_mm[1] - prof.distance_mm[0]),
                    "into_gap": _finite((t - dd) * lower) if lower else None})
    return out


def _true_crossings(rig: Rig, p0, p1, level: float, near: np.ndarray):
    """The true surface's crossings of ``level`` along the profile p0-p1 (the truth with the
    map's gaps filled), the one nearest each of ``near`` (within GAP_TRUTH_MM); None where
    one has none."""
    from impress_gui.core.measure import readings as M

    c = M.level_crossings(M.line_profile(rig.truth_filled, rig.spec, p0, p1, 1.0), level)
    out = []
    for d in near:
        if not c.size or np.min(np.abs(c - d)) > GAP_TRUTH_MM:
            return None
        out.append(float(c[np.argmin(np.abs(c - d))]))
    return np.array(out)


BAND = (93.0, 97.0)  # issue 22: the share within U (k = 2), neither over- nor under-stated


def coverage_interval(rr: list[dict], n_boot: int = 4000, level: float = 0.90
                      ) -> tuple[float, float, int]:
    """A ``level`` interval of the coverage, by a bootstrap over the calibrations (each
    rig and draw one cluster): every reading of a scan shares its calibration's error (a
    ruler's length error is nearly its calibration's scale error times the length), so
    the readings are not independent and the calibrations are the sample. (low, high, the
    number of calibrations)."""
    keys = sorted({(r.get("seed", 0), r.get("draw", 0)) for r in rr})
    index = {k: i for i, k in enumerate(keys)}
    inside = np.zeros(len(keys))
    count = np.zeros(len(keys))
    for r in rr:
        i = index[(r.get("seed", 0), r.get("draw", 0))]
        count[i] += 1
        inside[i] += abs(r["err"]) <= r["U"]
    rng = np.random.default_rng(2022)
    pick = rng.integers(len(keys), size=(n_boot, len(keys)))
    cov = 100 * inside[pick].sum(axis=1) / count[pick].sum(axis=1)
    tail = 100 * (1 - level) / 2
    low, high = np.percentile(cov, [tail, 100 - tail])
    return float(low), float(high), len(keys)


def verdict(cov: float, low: float, high: float) -> str:
    """Whether the coverage is inside issue 22's band, and whether the sample can tell."""
    if BAND[0] <= cov <= BAND[1]:
        where = "inside"
    else:
        where = "over" if cov > BAND[1] else "under"
    if high < BAND[0] or low > BAND[1]:
        return f"{where} (the interval lies {'below' if high < BAND[0] else 'above'} the band)"
    if BAND[0] <= low and high <= BAND[1]:
        return f"{where} (the interval lies inside the band)"
    return f"{where} (the interval reaches {'into' if where != 'inside' else 'beyond'} the band)"


def table(rows: list[dict]) -> str:
    rules = sorted({r.get("noise_rule", "") for r in rows})
    if len(rules) > 1:  # one table per way of combining the surface noise's estimates
        return "\n\n".join(f"surface noise: {rule or 'untagged (before 2026-12-05: largest)'}\n"
                            + table([r for r in rows if r.get("noise_rule", "") == rule])
                            for rule in rules)
    rules = sorted({r.get("gap_rule", "") for r in rows})
    if len(rules) > 1:  # one table per reach of a wall hidden in a gap
        return "\n\n".join(f"wall in a gap: {rule or 'untagged (before 2026-12-05: whole)'}\n"
                            + table([r for r in rows if r.get("gap_rule", "") == rule])
                            for rule in rules)
    lines = [f"{'reading':<13} {'n':>4} {'cal':>4} {'within U':>9} {'90% interval':>13} "
             f"{'median U':>9} {'median |e|':>10} {'rms e/u_c':>9}  largest components "
             "(median u_i, mm)"]
    verdicts = []
    stated = [r for r in rows if r.get("U") is not None]
    if len(stated) < len(rows):  # readings made with an unstable calibration: no U stated
        cals = {(r.get("seed"), r.get("draw")) for r in rows if r.get("U") is None}
        lines.insert(0, f"(readings with no U stated, the calibration unstable: "
                        f"{len(rows) - len(stated)} of {len(rows)}, from {len(cals)} "
                        "calibration(s); left out of the coverage below)")
    rows = stated
    for kind in KINDS:
        rr = [r for r in rows if r["kind"] == kind]
        if not rr:
            lines.append(f"{kind:<13} {0:>4} {'-':>9}")
            continue
        e = np.array([r["err"] for r in rr])
        u = np.array([r["U"] for r in rr])
        uc = np.array([r["u_c"] for r in rr])
        cov = 100 * float(np.mean(np.abs(e) <= u))
        low, high, ncal = coverage_interval(rr)
        names = sorted({n for r in rr for n in r["parts"]})
        med = {n: float(np.nanmedian([r["parts"].get(n, np.nan) for r in rr])) for n in names}
        parts = ", ".join(f"{n} {v:.3f}" for n, v in sorted(med.items(), key=lambda kv: -kv[1]))
        lines.append(f"{kind:<13} {len(rr):>4} {ncal:>4} {cov:>8.1f}% "
                     f"{f'{low:.1f}-{high:.1f}':>13} {np.median(u):>9.3f} "
                     f"{np.median(np.abs(e)):>10.3f} {np.sqrt(np.mean((e / uc) ** 2)):>9.2f}  "
                     f"{parts}")
        verdicts.append(f"  {kind:<13} {verdict(cov, low, high)}")
    lines.append(f"coverage against issue 22's {BAND[0]:g}-{BAND[1]:g} % (the interval: 90 %, a "
                 "bootstrap over the calibrations, whose errors a scan's readings share):")
    return "\n".join(lines + verdicts)


#: processing parameters other than the defaults (``--no-unlit-soil``)
PROCESS: dict = {}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0,1,2,3")
    ap.add_argument("--draws", type=int, default=2)
    ap.add_argument("--no-unlit-soil", action="store_true",
                    help="reconstruct without ProcessParams.unlit_soil (on by default)")
    ap.add_argument("--first-draw", type=int, default=0,
                    help="the first draw's number (draws first .. first + draws - 1; other "
                         "numbers give other click noise, e.g. to check on new calibrations)")
    ap.add_argument("--noise-px", type=float, default=0.5)
    ap.add_argument("--trials", type=int, default=30)
    ap.add_argument("--per-kind", type=int, default=25)
    ap.add_argument("--speed-error-pct", type=float, default=0.1,
                    help="half-width (%%) of the uniform error of the speed entered against "
                         "the rail's true speed (the servo's regulation; 0: exact)")
    ap.add_argument("--stripe-model", default=None,
                    help="the calibration Monte Carlo's stripe model (impress_gui.core."
                         "calibration.uncertainty.STRIPE_MODELS; default: the product's)")
    ap.add_argument("--noise-rules", default=None,
                    help="comma-separated ways of combining the surface noise's estimates "
                         "(impress_gui.core.measure.uncertainty.NOISE_RULES; default: the "
                         "product's): the same readings are taken with each, one table each")
    ap.add_argument("--gap-rules", default=None,
                    help="comma-separated reaches of a wall hidden in a gap of the map "
                         "(impress_gui.core.measure.uncertainty.GAP_RULES; default: the "
                         "product's): the same readings are taken with each, one table each")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--from-json", type=Path, nargs="+", default=None, metavar="JSON",
                    help="print the table of readings saved with --json (several files: "
                         "their readings together) and measure nothing")
    args = ap.parse_args()
    if args.no_unlit_soil:
        PROCESS["unlit_soil"] = False
    if args.from_json:
        rows = [r for f in args.from_json for r in json.loads(f.read_text())]
        print(table(rows))
        return
    seeds = [int(s) for s in args.seeds.split(",") if s]
    from impress_gui.core.measure import uncertainty as U

    noise_rules = list(dict.fromkeys(r for r in (args.noise_rules or "").split(",") if r)) or [""]
    for rule in noise_rules:
        if rule and rule not in U.NOISE_RULES:
            ap.error(f"--noise-rules: {rule!r} is not one of {', '.join(U.NOISE_RULES)}")
    gap_rules = list(dict.fromkeys(r for r in (args.gap_rules or "").split(",") if r)) or [""]
    for rule in gap_rules:
        if rule and rule not in U.GAP_RULES:
            ap.error(f"--gap-rules: {rule!r} is not one of {', '.join(U.GAP_RULES)}")
    rules = [(n, g) for n in noise_rules for g in gap_rules]
    print(f"random rigs {seeds} at 640x360, {args.draws} draws of click noise "
          f"{args.noise_px} px each, {args.trials} Monte Carlo trials per calibration, "
          f"speed entered within +-{args.speed_error_pct:g} % of the true")
    rows: list[dict] = []
    for seed in seeds:
        for draw in range(args.first_draw, args.first_draw + args.draws):
            try:
                rig = Rig(seed, draw, args.noise_px, args.trials, args.speed_error_pct / 100,
                          args.stripe_model)
            except Exception as exc:  # noqa: BLE001 - a rig the product refuses is a result
                print(f"  seed {seed} draw {draw}: not measured ({type(exc).__name__}: {exc})")
                continue
            got = []
            for noise_rule, gap_rule in rules:
                defaults = U.NOISE_RULE, U.GAP_RULE
                U.NOISE_RULE = noise_rule or defaults[0]
                U.GAP_RULE = gap_rule or defaults[1]
                try:
                    these = readings(rig, np.random.default_rng(100 * seed + draw),
                                     args.per_kind)
                    for r in these:
                        r.update(seed=seed, draw=draw,
                                 per_px_lasers={k: _finite(v) for k, v in rig.per_px.items()},
                                 noise_rule=U.NOISE_RULE, gap_rule=U.GAP_RULE)
                finally:
                    U.NOISE_RULE, U.GAP_RULE = defaults
                got += these
            rows += got
            e = rig.ctx.ensemble
            print(f"  seed {seed} draw {draw}: {len(got) // len(rules)} readings"
                  + (f" x {len(rules)} rules" if len(rules) > 1 else "") + "; calibrate+reconstruct "
                  f"{rig.t_rec:.0f} s, Monte Carlo {rig.t_mc:.0f} s; click sigma "
                  f"{e.click_sigma_px if e else float('nan'):.2f} px; "
                  + (f"UNSTABLE calibration, no U stated: {rig.ctx.unstable}"
                     if rig.ctx.unstable else
                     f"{'; '.join(rig.ctx.notes) or 'calibration component in'}"), flush=True)
            if args.json:
                args.json.write_text(json.dumps(rows, indent=0))
    print(table(rows))


if __name__ == "__main__":
    main()
