"""The measurement uncertainty of every reading (Qt-free), in the terms of the GUM (JCGM 100).

A reading's :class:`Budget` lists its components - each an input quantity with its standard
uncertainty ``u(x_i)``, its sensitivity coefficient ``c_i`` and its contribution
``u_i = |c_i| u(x_i)`` in mm - combines them by root-sum-square into the combined standard
uncertainty ``u_c`` (the components are taken as uncorrelated; correlations *within* the
calibration component are kept, see below) and states the expanded uncertainty
``U = k u_c`` at a coverage probability of about 95 % (95.45 %, the coverage of ``k = 2`` for a
normal distribution): ``k = 2`` where the normal components dominate; where a rectangular one
does (a wall hidden in a gap of the map, the rail speed), ``k`` is taken from the distribution of
the sum of the components, down to 1.66 for a rectangular one alone (EA-4/02 M: 2022, 5.6 and
Annex E; GUM G.2.3): ``k = 2`` there would state an interval wider than the component's whole
range (:func:`coverage_factor`).

Components (docs/uncertainty.md says the same for a quality manager):

- **calibration** (type A, Monte Carlo): the spread of the reading over the Monte Carlo trials
  of the scene calibration (:mod:`impress_gui.core.calibration.uncertainty`): each trial moves
  every cell the reading uses; the reading is recomputed per trial, so both ends of a ruler or
  both bands of a step move together and their common part cancels. Sensitivity 1 (the
  component is already in mm). Absent (and said so) when no calibration is known. A trial
  moves a cell as the laser that made it (both lasers' weighted mean where they agreed; where they
  disagreed, the laser whose value the fusion kept, when the per-laser maps are given:
  ``per_laser``, which the viewer and ``impress validate`` take from the reconstruction with
  :func:`per_laser_maps`). A depth below three points is recomputed per trial with the points'
  moved positions too (the plane read at a point shifted against its supports); a width at a level
  is found again per trial on the moved profile (:func:`_trial_crossings`), at a level that moves
  with the bands it was taken from when it came from bands on the same profile (``level_bands``:
  only the wall's change relative to them counts), never a height error divided by a slope.
- **rail speed** (type B, rectangular): the travel along the scan scales with the rail speed.
  The half-width is the difference between the speed implied by the target and the one entered
  (a floor of 0.1 % for the motor's own regulation); sensitivity: the reading's change per
  relative speed change (lengths along the scan; heights through the reference plane's slope).
- **surface noise** (type A): the standard error of the cells or profile samples averaged,
  from their scatter about a local plane (a line, for a band), with the sample count reduced to
  an *effective* count by their spatial autocorrelation (neighbouring cells of a heightmap
  interpolated from one stripe are not independent): ``n_eff = n / prod(1 + 2 sum rho_k)``.
- **grid resolution** (type B, rectangular): a height read at one cell is read up to half a
  cell ``a`` from the point marked, so ``u = a / (2 sqrt 3)`` per coordinate, times the
  local slope. A ruler's length between two marked points has none (the coordinates marked
  are not snapped to cells), nor has a width (its crossings are interpolated along a profile;
  the scanner's own sampling, never taken finer than a cell, is its **lateral sampling**
  component: where a wall lies between two samples).
- **method** (type B, normal): bias and precision of the method from an ``impress validate``
  report of the rig, when one is given (:class:`UncertaintyContext` ``validation``; the viewer
  takes it from the record the examiner chose, impress_gui.validation.method). Without one,
  the product's own figure (:data:`METHOD_STRIPE_PX`): what the calibration's Monte Carlo and
  the surface noise leave out - the calibration's own bias with exact picks, the stripe
  detector's bias on the scene's surfaces - as a stripe position error in pixels, times the
  height one pixel of stripe shift means for the laser that made the cells
  (``UncertaintyContext.per_px``).
"""

from __future__ import annotations

import functools
import json
import math
import os
import threading
import weakref
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from impress_gui.core.measure.surface import Plane
from impress_gui.core.reconstruction.grid import GridSpec

if TYPE_CHECKING:
    from impress_gui.core.calibration.uncertainty import CalibrationEnsemble

K = 2.0
#: the coverage probability of the expanded uncertainty: what k = 2 gives a normal distribution
COVERAGE_P = 0.9545
#: the largest ring (mm) over which the scatter of nearby means is taken for a difference
#: (60 mm was measured on the random-rig benchmark, 2026-11-29: a ruler's dz 94.0 -> 91.5 %
#: within U - the wider ring's disks fall on other relief and are left out; docs/uncertainty.md)
RING_MAX_MM = 15.0
SPEED_FLOOR_REL = 0.001  # the servo's own speed regulation, as a relative half-width
#: The method's own error where no validation record of the rig is given (type B, normal), as
#: a stripe position error in pixels: "absolute" for a height read at a point (a fused cell:
#: the lasers' errors taken as fully correlated, their weighted heights per pixel added),
#: "difference" for a difference between heights (each laser's own bias moves every height it
#: made alike and cancels; the lasers' biases independent: a difference whose points are all
#: one laser's, or fused alike, carries none). Established with the uncertainty benchmark on
#: random rigs 0-23 and checked on rigs 24-47, which it never saw (benchmarks/
#: bench_uncertainty.py; docs/uncertainty.md "The method's own component"): each laser's bias
#: per video, RMS 0.031 px. The absolute figure was 0.035 px while it also stood for the
#: detector's local errors beyond the surface noise; since the surface noise takes those from
#: the two lasers' disagreement at the reading's scale (agreement_noise), it is the bias alone.
#: Where the disagreement is not available (a folder without the per-laser maps, too few
#: tiles both lasers saw) a height keeps the former 0.035 px ("absolute, alone").
METHOD_STRIPE_PX = {"absolute": 0.03, "difference": 0.03, "absolute, alone": 0.035}
#: How the estimates of a mean's surface noise are combined (:func:`combine_noise`). Each is
#: blind to part of it - the cells' standard error to errors correlated over more than the
#: disk; the scatter of nearby means (8 of them, 6 degrees of freedom) adds the relief a plane
#: through them leaves; the lasers' disagreement, from hundreds of tiles, is the whole map's
#: random error at the disk's scale - so a rule that averages them understates (on random
#: rigs 0-23, 2026-12-05: ``median`` put steps at 89 %, ``rms`` dz at 90 % within U).
#: ``"agreement"`` (the default since 2026-12-05): for a point's own height the larger of the
#: standard error and the disagreement where the disagreement is known, else the largest; for
#: the ends of a difference (dz, depth; their ring as wide as the points' distance) the larger
#: of the standard error and the disagreement, with the ring's scatter in place of the
#: disagreement where it exceeds it beyond its own sampling spread (:func:`ring_exceeds`, since
#: 2026-12-05, night; before, the largest of the three. The larger of two estimates of one
#: noise is biased up, the ring's having only 6 degrees of freedom: on the same 65
#: calibrations depths 97.4 -> 95.9 % within U, dz 96.4 -> 95.4 %; docs/uncertainty.md "The
#: ring at the ends of a difference");
#: ``"largest"``: the largest estimate always (before: heights 98.3 % within U on
#: rigs 0-23, 97.9 % on rigs 90-117; the disagreement in place of the ring for differences
#: too put dz at 91.8 % on rigs 90-117: the ring at the ends' distance sees what the
#: disagreement at the disk's scale does not).
#: The others are for the uncertainty benchmark (``bench_uncertainty.py --noise-rules``).
NOISE_RULES = ("agreement", "largest", "median", "rms")
NOISE_RULE = "agreement"
#: How far into a gap of the map a wall hidden there may lie (:func:`hidden_reach`):
#: ``"geometric"`` (the default since 2026-12-05) as far as a wall steeper than the ray grazing
#: its top can reach at the level, with the top's last sample's own sideways error beside it
#: (*method, top beside a gap*); ``"whole"`` (before) anywhere in the gap. On 65 calibrations of
#: random rigs 0-47 and 90-117 (0.5 px clicks) widths at a level were covered 98.6 -> 96.6 %,
#: between bands 98.8 -> 95.8 % (docs/uncertainty.md, "A hidden wall's reach from the grazing
#: ray"). The other is for ``bench_uncertainty.py --gap-rules``.
GAP_RULES = ("geometric", "whole")
GAP_RULE = "geometric"
#: the one-sided level at which a ring's scatter counts as exceeding the lasers' disagreement
#: (:func:`ring_exceeds`)
RING_TEST_P = 0.95
LASER_NAMES = ("green", "red")


@dataclass(frozen=True)
class Component:
    """One line of a budget. ``u_x`` is the input quantity's standard uncertainty in ``unit``;
    ``sensitivity`` is ``c_i`` (mm per ``unit``); ``u_mm`` = ``|c_i| u_x``."""

    name: str
    quantity: str
    evaluation: str  # "A" or "B" (GUM 4.2 / 4.3)
    distribution: str
    u_x: float
    unit: str
    sensitivity: float
    u_mm: float
    note: str = ""
    #: a rectangular component that sums independent rectangular ones (two walls each in a
    #: gap): their half-widths in mm (``u_mm`` is their root-sum-square over sqrt 3, with the
    #: offset below in quadrature); empty: one rectangle of half-width ``sqrt(3) u_mm``
    half_widths_mm: tuple[float, ...] = ()
    #: a one-sided component (an error of known sign the reading does not correct: a wall
    #: hidden in a gap lies on the gap's side of the crossing): the mean of the error it adds
    #: to the reading (reading minus truth, signed), mm; its rectangles are about that mean,
    #: and ``u_mm`` is the RMS about 0 (the rectangles' root-sum-square over sqrt 3 and the
    #: offset, in quadrature). A budget holds at most one (:func:`coverage_factor`)
    offset_mm: float = 0.0

    def rectangles_mm(self) -> tuple[float, ...]:
        """The half-widths (mm) of the rectangular distributions this component sums; () for
        a normal (or Monte Carlo) one."""
        if self.distribution != "rectangular" or not math.isfinite(self.u_mm):
            return ()
        if self.offset_mm and not self.half_widths_mm:
            return ()  # an offset alone: u_mm is the offset, not a rectangle
        return self.half_widths_mm or (math.sqrt(3.0) * abs(self.u_mm),)

    def to_json(self) -> dict:
        return {"name": self.name, "quantity": self.quantity, "type": self.evaluation,
                "distribution": self.distribution, "u_x": _r(self.u_x), "unit": self.unit,
                "c": _r(self.sensitivity), "u_mm": _r(self.u_mm), "note": self.note,
                **({"half_widths_mm": [_r(a) for a in self.half_widths_mm]}
                   if self.half_widths_mm else {}),
                **({"offset_mm": _r(self.offset_mm)} if self.offset_mm else {})}


def _r(v, nd: int = 6):
    v = float(v)
    return round(v, nd) if math.isfinite(v) else None


@dataclass(frozen=True)
class Budget:
    """The uncertainty budget of one reading ``reading`` (e.g. "step height B - A")."""

    reading: str
    value_mm: float
    components: tuple[Component, ...]
    k: float = K
    notes: tuple[str, ...] = ()
    #: why no uncertainty is stated ("" : it is): a component that cannot be evaluated and
    #: cannot be left out (the calibration's, when its Monte Carlo fails in most trials)
    incomplete: str = ""

    @property
    def u_c_mm(self) -> float:
        if self.incomplete:
            return math.nan
        us = [c.u_mm for c in self.components if math.isfinite(c.u_mm)]
        return float(math.sqrt(sum(u * u for u in us))) if us else math.nan

    @property
    def U_mm(self) -> float:  # noqa: N802 - the GUM's symbol
        return self.k * self.u_c_mm

    def short(self) -> str:
        """``± 0.123 mm (k=2)`` (``k=1.93`` where a rectangular component shapes the sum)."""
        return (f"± - (k={self.k:g})" if not math.isfinite(self.U_mm)
                else f"± {self.U_mm:.3f} mm (k={self.k:g})")

    def to_json(self) -> dict:
        return {"reading": self.reading, "value_mm": _r(self.value_mm), "u_c_mm": _r(self.u_c_mm),
                "U_mm": _r(self.U_mm), "k": self.k,
                "components": [c.to_json() for c in self.components], "notes": list(self.notes),
                **({"incomplete": self.incomplete} if self.incomplete else {})}

    def text(self) -> str:
        """A plain-text table of the budget (for a tooltip or a details view)."""
        lines = [f"{self.reading}: {self.value_mm:.3f} mm; "
                 + (f"no uncertainty stated: {self.incomplete}" if self.incomplete else
                    f"u_c {self.u_c_mm:.4f} mm; U = {self.k:g} u_c = {self.U_mm:.3f} mm"),
                 "component | input u(x) | c | u_i (mm) | type, distribution"]
        for c in self.components:
            lines.append(f"{c.name} | {_g(c.u_x)} {c.unit} | {_g(c.sensitivity)} | "
                         f"{_g4(c.u_mm)} | {c.evaluation}, {c.distribution}"
                         + (f", one-sided (mean error {c.offset_mm:+.3f} mm)"
                            if c.offset_mm else "")
                         + (f" - {c.note}" if c.note else ""))
        lines += list(self.notes)
        return "\n".join(lines)


def _g(v: float) -> str:
    return "-" if not math.isfinite(v) else f"{v:.4g}"


def _g4(v: float) -> str:
    return "-" if not math.isfinite(v) else f"{v:.4f}"


def coverage_factor(components: Sequence[Component], p: float = COVERAGE_P) -> float:
    """The coverage factor ``k`` of an expanded uncertainty at coverage probability ``p``
    (default :data:`COVERAGE_P`, that of k = 2 for a normal distribution) for the sum of
    ``components``: the normal ones (normal, Monte Carlo) pooled into one normal, each
    rectangular one a uniform distribution (:meth:`Component.rectangles_mm`), the density of
    their sum computed by convolution on a grid of 1/2000 of its range (JCGM 101's propagation
    of distributions, done exactly instead of by sampling: the same budget always gives the
    same k) and k the half-width of the central interval holding ``p`` over ``u_c``, rounded up
    to 0.01 and at most 2 (2 for a normal sum; 1.66 for one rectangle alone).

    A one-sided component (:attr:`Component.offset_mm`) shifts the sum by its offset: the
    interval is still the one about 0 (the reading) holding ``p``, and ``u_c`` holds its RMS
    about 0. A budget holds at most one: two would need their offsets' correlation in
    ``u_c`` (taken in quadrature, two offsets of one sign would understate it)."""
    us = [c.u_mm for c in components if math.isfinite(c.u_mm)]
    uc = math.sqrt(sum(u * u for u in us)) if us else 0.0
    if not uc > 0:
        return K
    rect = [a for c in components for a in c.rectangles_mm() if a > 0]
    offsets = [c.offset_mm for c in components
               if c.offset_mm and math.isfinite(c.u_mm) and math.isfinite(c.offset_mm)]
    if len(offsets) > 1:
        raise ValueError("a budget holds at most one one-sided component")
    off = abs(offsets[0]) if offsets else 0.0
    var_n = max(uc * uc - sum(a * a / 3.0 for a in rect) - off * off, 0.0)
    rect = [a for a in rect if a > 0.01 * uc]  # a rectangle this narrow adds no shape
    if not rect and not off > 0.01 * uc:
        return K
    sn = math.sqrt(var_n)
    h = (sum(rect) + 6.0 * sn) / 2000.0
    if off > 0.01 * uc:
        h = h if h > 0 else off / 2000.0
        dens = _sum_density(rect, sn, h)
        # the sum shifted by the offsets: the smallest half-width about 0 holding p
        x = np.abs((np.arange(dens.size) - dens.size // 2) * h + off)
        order = np.argsort(x, kind="stable")
        cum = np.cumsum(dens[order]) / dens.sum()
        i = min(int(np.searchsorted(cum, p)), cum.size - 1)
        t = float(x[order][i]) + 0.5 * h  # where the cell holding the p-quantile ends
        return min(K, math.ceil(100.0 * t / uc - 1e-9) / 100.0)
    dens = _sum_density(rect, sn, h)
    c = dens.size // 2
    # the mass within +-t for t = 0, h, 2h, ... (each grid point stands for a cell of width h)
    mass = dens[c] + 2.0 * np.cumsum(dens[c + 1:])
    i = int(np.searchsorted(mass, p))
    t = (i + 0.5) * h  # where the cell holding the p-quantile ends, halfway on average
    return min(K, math.ceil(100.0 * t / uc - 1e-9) / 100.0)


def _sum_density(rect: Sequence[float], sn: float, h: float) -> np.ndarray:
    """The density, on a grid of step ``h`` centred on 0, of the sum of uniform distributions
    of half-widths ``rect`` and a normal of SD ``sn`` (:func:`coverage_factor`)."""
    dens = np.ones(1)
    for a in rect:
        m = max(int(round(a / h)), 1)
        dens = np.convolve(dens, np.full(2 * m + 1, 1.0 / (2 * m + 1)))
    if sn > 0.5 * h:
        m = int(math.ceil(6.0 * sn / h))
        g = np.exp(-0.5 * (np.arange(-m, m + 1) * h / sn) ** 2)
        dens = np.convolve(dens, g / g.sum())
    return dens


def budget_from_json(doc: Mapping) -> Budget:
    comps = tuple(Component(c.get("name", ""), c.get("quantity", ""), c.get("type", ""),
                            c.get("distribution", ""), _f(c.get("u_x")), c.get("unit", ""),
                            _f(c.get("c")), _f(c.get("u_mm")), c.get("note", ""),
                            tuple(_f(a) for a in c.get("half_widths_mm") or ()),
                            _f(c.get("offset_mm", 0.0)))
                  for c in doc.get("components", []))
    return Budget(doc.get("reading", ""), _f(doc.get("value_mm")), comps,
                  float(doc.get("k", K)), tuple(doc.get("notes", [])),
                  str(doc.get("incomplete") or ""))


def _f(v) -> float:
    return math.nan if v is None else float(v)


# ----- what the budgets need ----------------------------------------------------------------------
@dataclass
class UncertaintyContext:
    """What a reading's budget is computed from: the heights measured on (``height``, the
    layer shown, levelled or not), the grid, the lasers' contribution codes (1 green, 2 red,
    3/4 both; None: both assumed), the calibration's Monte Carlo (None: no calibration
    component, said so), the entered and the target-implied rail speed, and a validation
    report's ``{"bias_mm", "sd_mm", "source"}`` (None: not used)."""

    height: np.ndarray
    spec: GridSpec
    contribution: np.ndarray | None = None
    ensemble: CalibrationEnsemble | None = None
    speed_mm_s: float | None = None
    implied_speed_mm_s: float | None = None
    validation: Mapping | None = None
    level_plane: Plane | None = None  # the levelling plane the heights are relative to
    level_support: Sequence | None = None  # (x, y) points the plane was fitted to
    notes: list = field(default_factory=list)
    laser: str | None = None  # the heights are one laser's ("green", "red"), not fused
    #: the scanner's lateral sampling (mm) across the scan (one camera column) and along it
    #: (one frame's travel); None: unknown
    sampling_mm: tuple[float, float] | None = None
    #: the per-laser height maps ({"green": ..., "red": ...}, same grid as ``height``): with
    #: them a cell where the lasers disagreed (code 4) is moved as the laser whose value the
    #: fusion kept, not as their mean (the two lasers' calibration errors differ)
    per_laser: Mapping | None = None
    #: the lasers' weights in the mean where they agreed (code 3): the reconstruction's
    #: recorded ``stats.fusion_weights`` (:func:`fusion_weights_of`); None: 0.5 each, as
    #: results made before the weights were recorded were fused
    fusion_weights: Mapping | None = None
    #: per laser, the height (mm) one pixel of stripe shift means (reconstruct.
    #: height_per_pixel of the calibration): the method's own component's sensitivity where no
    #: validation record is given; None: that component is left out
    per_px: Mapping | None = None
    #: why the calibration's Monte Carlo failed in most trials ("" : it did not): budgets then
    #: state no uncertainty (:attr:`Budget.incomplete`)
    unstable: str = ""

    @classmethod
    def for_calibration(cls, height, spec, cal=None, target=None, contribution=None,
                        level_plane=None, validation=None, trials: int | None = None,
                        per_laser=None, fusion_weights=None, stripe_model: str | None = None
                        ) -> UncertaintyContext:
        """A context with the calibration's Monte Carlo (computed once per calibration and
        cached; a target model that does not fit or a failing solve leave the component out,
        with a note). ``stripe_model``: the Monte Carlo's (None: its default)."""
        notes = []
        ens = None
        unstable = ""
        if cal is not None and target is not None:
            from impress_gui.core.calibration import uncertainty as CU

            try:
                ens = CU.calibration_ensemble(
                    cal, target, n=CU.DEFAULT_TRIALS if trials is None else int(trials),
                    stripe_model=stripe_model or CU.DEFAULT_STRIPE_MODEL)
            except CU.UnstableCalibration as exc:  # no U can be stated with this calibration
                unstable = str(exc)
            except Exception as exc:  # noqa: BLE001 - any failure leaves the component out
                notes.append(f"calibration component not evaluated: {exc}")
        elif cal is None:
            notes.append("no scene calibration known: the calibration component is missing")
        else:
            notes.append("no target model known: the calibration component is missing")
        per_px = None if cal is None else method_sensitivity(cal, notes)
        return cls(height, spec, contribution, ens,
                   None if cal is None else float(cal.speed_mm_s),
                   None if cal is None else float(cal.implied_speed_mm_s),
                   validation=validation, level_plane=level_plane, notes=notes,
                   sampling_mm=None if cal is None else lateral_sampling(cal),
                   per_laser=per_laser, fusion_weights=fusion_weights, per_px=per_px,
                   unstable=unstable)

    # ----- helpers ---------------------------------------------------------------------------
    def lasers_at(self, x, y) -> list[tuple[str, float]]:
        """The lasers (and their weights) of the cell at ``(x, y)``."""
        if self.laser in LASER_NAMES:
            return [(self.laser, 1.0)]
        fw = self.fusion_weights or {"green": 0.5, "red": 0.5}
        both = [("green", float(fw["green"])), ("red", float(fw["red"]))]
        if self.contribution is None:
            return both
        i, j = _cell(self.spec, x, y)
        if not (0 <= i < self.spec.shape[0] and 0 <= j < self.spec.shape[1]):
            return both
        c = int(self.contribution[i, j])
        if c == 4 and self.per_laser is not None:
            f = float(np.asarray(self.raw_height(x, y, float(self.height[i, j]))))
            kept = _kept_laser(f, self.per_laser, i, j)
            if kept is not None:
                return [(kept, 1.0)]
        return {1: [("green", 1.0)], 2: [("red", 1.0)]}.get(c, both)

    def calibration_deltas(self, x, y, h) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """Per Monte Carlo trial, how the cells ``(x, y)`` with heights ``h`` (the measured,
        unlevelled heights) move: ``(dx, dy, dh)`` each ``(S, N)``; weighted over the lasers
        that made each cell."""
        ens = self.ensemble
        if ens is None:
            return None
        x, y, h = (np.atleast_1d(np.asarray(v, float)) for v in (x, y, h))
        h = np.where(np.isfinite(h), h, 0.0)
        s = ens.n_trials
        out = [np.zeros((s, len(x))) for _ in range(3)]
        weights = [dict(self.lasers_at(xi, yi)) for xi, yi in zip(x, y)]
        for laser in LASER_NAMES:  # the cells of one laser in one call
            idx = np.array([n for n, wd in enumerate(weights) if laser in wd], int)
            if not idx.size:
                continue
            w = np.array([weights[n][laser] for n in idx])
            d = ens.deltas(x[idx], y[idx], h[idx], laser)
            for o, v in zip(out, d):
                o[:, idx] += w[None] * v
        return out[0], out[1], out[2]

    def raw_height(self, x, y, h):
        """The unlevelled height of a levelled reading (the calibration moves raw heights)."""
        if self.level_plane is None:
            return h
        return np.asarray(h, float) + self.level_plane.at(x, y)

    def speed_half_width_rel(self) -> float | None:
        if self.speed_mm_s is None or not self.speed_mm_s:
            return None
        rel = abs((self.implied_speed_mm_s or self.speed_mm_s) / self.speed_mm_s - 1.0)
        return max(rel, SPEED_FLOOR_REL)


def method_sensitivity(cal, notes: list | None = None) -> dict[str, float] | None:
    """Per laser, the height (mm) one pixel of stripe shift means with the calibration ``cal``
    (reconstruct.height_per_pixel at its picture size): the sensitivity of the method's own
    component (:data:`METHOD_STRIPE_PX`). None (and a note) when it cannot be found."""
    from impress_gui.core.reconstruction.reconstruct import height_per_pixel

    try:
        return {k: float(v) for k, v in
                height_per_pixel(cal, tuple(cal.intrinsics.image_size)).items()}
    except Exception as exc:  # noqa: BLE001 - the component is then left out, said so
        if notes is not None:
            notes.append(f"the method's own component not evaluated: {exc}")
        return None


def fusion_weights_of(metadata: Mapping | None) -> dict[str, float] | None:
    """The lasers' weights where they agreed, as the reconstruction recorded them
    (``metadata.json``'s ``stats.fusion_weights``); None when it did not (0.5 each then)."""
    try:
        w = (metadata or {}).get("stats", {}).get("fusion_weights")
        g, r = float(w["green"]), float(w["red"])
    except (AttributeError, KeyError, TypeError, ValueError):
        return None
    if not (0.0 <= g <= 1.0 and 0.0 <= r <= 1.0 and abs(g + r - 1.0) < 1e-3):
        return None
    return {"green": g, "red": r}


def _kept_laser(f: float, per_laser: Mapping, i: int, j: int) -> str | None:
    """Which laser's value the fusion kept at a cell where the lasers disagreed (the fused
    (unlevelled) height ``f`` is one of the two): the one nearer; None if unknown."""
    d = {n: abs(float(per_laser[n][i, j]) - f) for n in LASER_NAMES if n in per_laser}
    d = {n: v for n, v in d.items() if math.isfinite(v)}
    if not math.isfinite(f) or not d:
        return None
    return min(d, key=lambda n: d[n])


def per_laser_maps(data) -> dict[str, np.ndarray] | None:
    """The per-laser height maps of a reconstruction
    (:class:`~impress_gui.core.measure.readings.ReconData`) for
    :attr:`UncertaintyContext.per_laser`: its "green" and "red" layers when they are in memory,
    else read from its folder's TIFF layers (only those two files). None when either is absent,
    unreadable or not on the reconstruction's grid: the budget then moves a cell where the
    lasers disagreed as their mean, as without the maps (no error)."""
    layers = data.layers
    out: dict[str, np.ndarray] = {n: layers[n] for n in LASER_NAMES if n in layers}
    missing = [n for n in LASER_NAMES if n not in out]
    if missing and data.folder is None:
        return None
    for n in missing:
        arr = _read_layer(data.folder, n, tuple(data.spec.shape))
        if arr is None:
            return None
        out[n] = arr
    return out


def _read_layer(folder, name: str, shape: tuple[int, int]) -> np.ndarray | None:
    """One float32 height layer of a reconstruction folder; None if absent, damaged or not of
    ``shape``."""
    import tifffile

    from impress_gui.core.base.fileio import open_regular
    from impress_gui.core.formats.recon_files import LAYER_FILES

    path = Path(folder) / LAYER_FILES[name]
    try:
        if not path.is_file():
            return None
        os.close(open_regular(path, "heightmap", 8 << 30))  # a regular file, not a FIFO
        arr = tifffile.imread(path, maxworkers=1)
    except Exception:  # noqa: BLE001 - an unreadable layer is as good as an absent one
        return None
    if arr.shape != shape:
        return None
    arr = np.asarray(arr, np.float32)
    arr.setflags(write=False)
    return arr


def lateral_sampling(cal) -> tuple[float, float]:
    """The scanner's lateral sampling at the reference plane: one camera column across the
    scan (depth / focal length) and one frame's travel along it (speed / frame rate)."""
    z = float(cal.reference_depth(np.array(0.0), np.array(0.0)))
    k = cal.intrinsics.camera_matrix
    return abs(z) / float(k[0, 0]), float(cal.speed_mm_s) / float(cal.fps)


def _cell(spec: GridSpec, x: float, y: float) -> tuple[int, int]:
    return (int(round((y - spec.y0_mm) / spec.pixel_mm)),
            int(round((x - spec.x0_mm) / spec.pixel_mm)))


# ----- statistics of the averaged cells -------------------------------------------------------
def _acf_factor(r: np.ndarray, axis: int) -> float:
    """``1 + 2 sum rho_k`` of residuals ``r`` (2-D, NaN for missing) along ``axis``, summed
    while the autocorrelation stays positive (lags up to a quarter of the length)."""
    r = np.moveaxis(np.asarray(r, float), axis, -1)
    var = np.nanmean(r**2)
    if not np.isfinite(var) or var <= 0 or r.shape[-1] < 3:
        return 1.0
    total = 0.0
    for lag in range(1, max(2, r.shape[-1] // 2)):
        prod = r[..., lag:] * r[..., :-lag]
        if not np.isfinite(prod).any():
            break
        rho = float(np.nanmean(prod) / var)
        if not math.isfinite(rho) or rho <= 0.05:
            break
        total += rho
    return 1.0 + 2.0 * total


def patch_noise(height: np.ndarray, spec: GridSpec, x: float, y: float, radius_mm: float,
                min_radius_mm: float = 0.5) -> tuple[float, float, int, float, float]:
    """The cells within ``max(radius, min_radius)`` of ``(x, y)``: per-cell noise (robust SD of
    the residuals about a least-squares plane), effective count, cells, and the plane's slope
    ``(dh/dx, dh/dy)``. ``(nan, nan, 0, nan, nan)`` with fewer than 4 cells with data."""
    p = spec.pixel_mm
    r = max(radius_mm, min_radius_mm) / p
    fi, fj = (y - spec.y0_mm) / p, (x - spec.x0_mm) / p
    i0, i1 = max(0, math.ceil(fi - r)), min(spec.shape[0] - 1, math.floor(fi + r))
    j0, j1 = max(0, math.ceil(fj - r)), min(spec.shape[1] - 1, math.floor(fj + r))
    if i0 > i1 or j0 > j1:
        return math.nan, math.nan, 0, math.nan, math.nan
    sub = np.asarray(height[i0:i1 + 1, j0:j1 + 1], float)
    ii, jj = np.mgrid[i0:i1 + 1, j0:j1 + 1]
    disk = (ii - fi) ** 2 + (jj - fj) ** 2 <= r * r
    ok = disk & np.isfinite(sub)
    if ok.sum() < 4:
        return math.nan, math.nan, int(ok.sum()), math.nan, math.nan
    a = np.column_stack([jj[ok] * p, ii[ok] * p, np.ones(ok.sum())])
    coef, *_ = np.linalg.lstsq(a, sub[ok], rcond=None)
    res = np.full(sub.shape, np.nan)
    res[ok] = sub[ok] - a @ coef
    mad = float(np.median(np.abs(res[ok])))
    sigma = max(1.4826 * mad, float(np.sqrt(np.mean(res[ok] ** 2))) * 0.5)
    factor = _acf_factor(res, 0) * _acf_factor(res, 1)
    n = int(ok.sum())
    return sigma, max(1.0, n / factor), n, float(coef[0]), float(coef[1])


#: a neighbouring reading more than this many robust SDs (and 0.05 mm) off the fit through the
#: others is other relief (a wall, another slot), not this reading's noise
RELIEF_SIGMAS = 3.0
#: and so is one more than this far (mm) from the reading itself (half the neighbours can lie
#: on other relief, e.g. across slots, where no fit separates them)
RELIEF_MM = 0.3


def _consistent_scatter(design: np.ndarray, values: np.ndarray, min_keep: int
                        ) -> tuple[float, int]:
    """The residual SD of ``values`` about a least-squares fit (columns of ``design``), the
    reading itself (row 0) always kept, neighbours that are other relief dropped one at a
    time (the worst first while it lies more than RELIEF_SIGMAS robust SDs, and 0.05 mm, off
    the fit of the rest), and any more than RELIEF_MM from the reading itself.
    ``(SD, readings used)``; NaN when fewer than ``min_keep`` remain
    consistent: the neighbourhood is too structured to say anything about the noise, and the
    cells' own standard error stands alone."""
    keep = np.abs(values - values[0]) <= RELIEF_MM
    if keep.sum() < min_keep:
        return math.nan, int(keep.sum())
    p = design.shape[1]
    while True:
        coef, *_ = np.linalg.lstsq(design[keep], values[keep], rcond=None)
        res = values - design @ coef
        dof = int(keep.sum()) - p
        if dof < 1:
            return math.nan, int(keep.sum())
        robust = 1.4826 * float(np.median(np.abs(res[keep])))
        worst = int(np.argmax(np.where(keep, np.abs(res), -1.0)))
        if worst != 0 and abs(res[worst]) > max(RELIEF_SIGMAS * robust, 0.05):
            keep[worst] = False
            if keep.sum() < min_keep:
                return math.nan, int(keep.sum())
            continue
        return float(np.sqrt(np.sum(res[keep] ** 2) / dof)), int(keep.sum())


def disk_repeatability(height: np.ndarray, spec: GridSpec, x: float, y: float,
                       radius_mm: float, ring_mm: float | None = None) -> tuple[float, int]:
    """The scatter of a disk mean at this scale: the means of the disk at ``(x, y)`` and of 8
    disks of the same radius on a ring around it (3 radii + 0.5 mm away, radius at least
    0.5 mm) about a plane through them; ``(SD, disks used)``. It sees errors correlated over
    more than the disk (one stripe's offset, a frame's) that the cells' own scatter cannot.
    Neighbours on other relief (a wall, another slot) are left out
    (:func:`_consistent_scatter`); with fewer than 6 consistent disks the result is NaN."""
    from impress_gui.core.measure.readings import readout

    r = max(radius_mm, 0.5)

    def mean_at(dx: float, dy: float) -> float | None:
        rd = readout(height, spec, x + dx, y + dy, r)
        return rd.height_mm if rd.n_valid >= max(3, rd.n_cells // 2) else None

    return _ring_scatter(mean_at, max(3 * r + 0.5, ring_mm or 0.0))


def _ring_scatter(mean_at, ring_mm: float) -> tuple[float, int]:
    """The scatter of a local mean: ``mean_at(dx, dy)`` (None where too few cells have data)
    here and at 8 places on a ring of ``ring_mm`` around, about a plane through them
    (:func:`_consistent_scatter`); ``(SD, means used)``, NaN with fewer than 6 consistent
    ones or none here."""
    vals = []
    for dx, dy in [(0.0, 0.0)] + [(ring_mm * math.cos(t), ring_mm * math.sin(t))
                                  for t in np.linspace(0, 2 * math.pi, 8, endpoint=False)]:
        m = mean_at(dx, dy)
        if m is not None:
            vals.append((dx, dy, m))
    if len(vals) < 6 or vals[0][:2] != (0.0, 0.0):
        return math.nan, len(vals)
    v = np.array(vals)
    return _consistent_scatter(np.column_stack([v[:, 0], v[:, 1], np.ones(len(v))]), v[:, 2], 6)


def series_noise(values: np.ndarray) -> tuple[float, float, int]:
    """Profile samples of a band: SD of the residuals about a line, effective count, count."""
    v = np.asarray(values, float)
    t = np.arange(len(v), dtype=float)
    ok = np.isfinite(v)
    n = int(ok.sum())
    if n < 3:
        return (math.nan, math.nan, n)
    coef = np.polyfit(t[ok], v[ok], 1)
    res = np.where(ok, v - np.polyval(coef, t), np.nan)
    sigma = float(np.sqrt(np.nansum(res**2) / max(1, n - 2)))
    factor = _acf_factor(res[None, :], 1)
    return sigma, max(1.0, n / factor), n


# ----- components -------------------------------------------------------------------------------
def _cal_component(samples: np.ndarray | None, what: str, ctx: UncertaintyContext) -> list:
    if samples is None:
        return []
    e = ctx.ensemble
    if e is None:
        return []
    u = float(np.std(samples, ddof=1))
    return [Component("calibration", what, "A", f"Monte Carlo, {e.n_trials} trials", u, "mm",
                      1.0, u, f"click noise {e.click_sigma_px:.2f} px ({e.sigma_source}); "
                      f"plane fit RMS green {_plane_rms(e, 'green')}, red {_plane_rms(e, 'red')}")]


def _plane_rms(e, laser: str) -> str:
    v = e.summary.get(f"{laser}_plane_rms_mm")
    return "-" if v is None else f"{v:.3f} mm"


def _speed_component(ctx: UncertaintyContext, sens_mm: float) -> list:
    hw = ctx.speed_half_width_rel()
    if hw is None:
        return []
    u = hw / math.sqrt(3.0)
    src = (f"entered {ctx.speed_mm_s:.4f} mm/s, implied by the target "
           f"{(ctx.implied_speed_mm_s or ctx.speed_mm_s):.4f} mm/s")
    return [Component("rail speed", "relative speed error", "B", "rectangular", u, "(relative)",
                      sens_mm, abs(sens_mm) * u, src)]


def _grid_component(ctx: UncertaintyContext, sens_mm_per_mm: float, n_coords: float,
                    what: str) -> Component:
    u = ctx.spec.pixel_mm / (2.0 * math.sqrt(3.0))
    c = abs(sens_mm_per_mm) * math.sqrt(n_coords)
    return Component("grid resolution", what, "B", "rectangular", u, "mm", c, c * u,
                     f"cell {ctx.spec.pixel_mm:g} mm, half-width {ctx.spec.pixel_mm / 2:g} mm")


#: the two lasers' disagreement is taken over tiles at least this much of whose cells both
#: lasers saw, and only when at least AGREEMENT_MIN_TILES such tiles exist
AGREEMENT_MIN_COVER = 0.9
AGREEMENT_MIN_TILES = 50
#: at most this many tiles enter the robust SD (a regular subsample beyond it)
AGREEMENT_MAX_TILES = 200_000
#: per green map (by id, dropped when the map is freed): (red map, tile side, ratio of the
#: heights per pixel) -> the figure in mm, with a weak reference that confirms the red map is
#: the one it was computed from
_AGREEMENT_CACHE: dict[int, dict] = {}
_AGREEMENT_LOCK = threading.Lock()


def laser_agreement_px(green: np.ndarray, red: np.ndarray, spec: GridSpec, radius_mm: float,
                       per_px: Mapping) -> tuple[float, int] | None:
    """The stripe's random error (pixels) at the scale of a mean over a disk of
    ``radius_mm``, from the two lasers' disagreement: the map is cut into square tiles of
    the disk's area, each tile's mean of ``green - red`` over the cells both lasers saw
    (tiles at least AGREEMENT_MIN_COVER covered), a least-squares fit of those means to
    ``a + b x + c y + e h`` removed (the calibration's errors, which the Monte Carlo carries,
    make the lasers disagree linearly across the map and with height; ``h`` the lasers'
    heights combined as ``(p_red^2 g + p_green^2 r) / (p_green^2 + p_red^2)``, whose noise is
    uncorrelated with their difference when each laser's error is a stripe error times its
    height per pixel), and the robust SD (1.4826 x the median absolute deviation) of what
    remains, divided by ``sqrt(p_green^2 + p_red^2)`` (the lasers' heights per pixel of stripe
    shift: the same stripe error in pixels moves the two lasers' heights in proportion).

    The two lasers see each point of the surface independently - other frames, other camera
    pixels, other light - so their disagreement at a scale is the reconstruction's own random
    error at that scale, correlations over a frame's stripe included, which no scatter inside
    one small disk sees (random rig 34, white stripes on near-white soil at 640x360: for 0.5 mm
    disks, 0.89 mm tiles, the true errors of the fused map's tile means scatter 0.25 mm (robust
    SD), this figure predicts 0.23 mm; the disk's own standard error said about 0.08 mm).
    ``(pixels, tiles)``; None where either laser's map or height per pixel is missing, the maps
    are not of the grid ``spec``, or too few tiles both lasers saw."""
    pg, pr = (float(per_px.get(k, math.nan)) for k in LASER_NAMES)
    if not (math.isfinite(pg) and math.isfinite(pr) and pg > 0 and pr > 0):
        return None
    got = _agreement_mm(green, red, spec, radius_mm, pg / pr)
    if got is None:
        return None
    return got[0] / math.hypot(pg, pr), got[1]


def _agreement_mm(green, red, spec: GridSpec, radius_mm: float, ratio: float
                  ) -> tuple[float, int] | None:
    """:func:`laser_agreement_px` before the division (mm): cached per pair of maps, tile
    side and ratio of the heights per pixel (which sets the height term)."""
    g = np.asarray(green)
    r = np.asarray(red)
    if g.shape != r.shape or g.shape != tuple(spec.shape):
        return None
    k = max(1, int(round(math.sqrt(math.pi) * max(radius_mm, 0.0) / spec.pixel_mm)))
    ny, nx = g.shape[0] // k, g.shape[1] // k
    if ny * nx < AGREEMENT_MIN_TILES:
        return None
    key = (id(r), k, round(ratio, 9))
    with _AGREEMENT_LOCK:
        cache = _AGREEMENT_CACHE.get(id(g))
        if cache is None:
            cache = _AGREEMENT_CACHE[id(g)] = {}
            weakref.finalize(g, _AGREEMENT_CACHE.pop, id(g), None)
        hit = cache.get(key)
    if hit is not None and hit[0]() is r:
        return hit[1]
    # every st-th tile along each axis: a regular subsample of at most ~4 x AGREEMENT_MAX_TILES
    st = max(1, math.ceil(math.sqrt(ny * nx / (4 * AGREEMENT_MAX_TILES))))

    def tiles(a: np.ndarray) -> np.ndarray:
        return a[:ny * k, :nx * k].reshape(ny, k, nx, k)[::st, :, ::st, :]

    tg, tr = tiles(g), tiles(r)
    ok = np.isfinite(tg) & np.isfinite(tr)
    cnt = ok.sum(axis=(1, 3))
    sg = np.where(ok, tg, 0.0).sum(axis=(1, 3), dtype=np.float64)
    sr = np.where(ok, tr, 0.0).sum(axis=(1, 3), dtype=np.float64)
    del ok
    dsum = sg - sr
    # the height term: the lasers combined so that its noise is independent of the difference
    wg = 1.0 / (1.0 + ratio * ratio)  # p_red^2 / (p_green^2 + p_red^2)
    hsum = wg * sg + (1.0 - wg) * sr
    good = cnt >= AGREEMENT_MIN_COVER * k * k
    ii, jj = np.nonzero(good)
    n = int(ii.size)
    out: tuple[float, int] | None = None
    if n >= AGREEMENT_MIN_TILES:
        if n > AGREEMENT_MAX_TILES:  # a regular subsample, deterministic
            keep = np.linspace(0, n - 1, AGREEMENT_MAX_TILES).astype(np.int64)
            ii, jj = ii[keep], jj[keep]
        c = cnt[ii, jj]
        m = dsum[ii, jj] / c
        h = hsum[ii, jj] / c
        xs = spec.x0_mm + (jj * st + 0.5) * k * spec.pixel_mm
        ys = spec.y0_mm + (ii * st + 0.5) * k * spec.pixel_mm
        a = np.column_stack([np.ones(m.size), xs - xs.mean(), ys - ys.mean(), h - h.mean()])
        coef, *_ = np.linalg.lstsq(a, m, rcond=None)
        res = m - a @ coef
        out = (1.4826 * float(np.median(np.abs(res - np.median(res)))), int(m.size))
    with _AGREEMENT_LOCK:
        cache[key] = (weakref.ref(r), out)
    return out


def agreement_noise(ctx: UncertaintyContext, x: float, y: float, radius_mm: float
                    ) -> tuple[float, str] | None:
    """The reconstruction's random error of a mean over a disk at ``(x, y)``, from the two
    lasers' disagreement at that scale (:func:`laser_agreement_px`): its pixels times the
    height per pixel of the lasers that made the cells there, weighted as the fusion weighed
    them, in quadrature (the lasers' random errors are independent). None without both
    lasers' maps and heights per pixel."""
    pl = ctx.per_laser
    if pl is None or ctx.per_px is None or "green" not in pl or "red" not in pl:
        return None
    got = laser_agreement_px(pl["green"], pl["red"], ctx.spec, radius_mm, ctx.per_px)
    if got is None:
        return None
    s_px, tiles = got
    u = s_px * math.sqrt(sum((w * float(ctx.per_px.get(la, math.nan))) ** 2
                             for la, w in ctx.lasers_at(x, y)))
    if not math.isfinite(u):
        return None
    return u, (f"the two lasers' disagreement at this scale ({tiles} tiles of the disk's "
               f"area): {s_px:.3f} px of stripe, {u:.4f} mm here")


def point_noise(ctx: UncertaintyContext, readout, ring_mm: float | None = None
                ) -> tuple[float, str]:
    """The surface noise of one point reading and how it was found
    (:func:`_point_noise`)."""
    u, how, _ = _point_noise(ctx, readout, ring_mm)
    return u, how


def _point_noise(ctx: UncertaintyContext, readout, ring_mm: float | None = None
                 ) -> tuple[float, str, bool | None]:
    """The surface noise of one point reading (mean over its radius): the larger of the
    standard error of its cells (effective count) and, with both lasers' maps, the
    reconstruction's random error at the disk's scale from their disagreement
    (:func:`agreement_noise`); without the disagreement, the larger of the standard error and
    the scatter of such means nearby (:func:`disk_repeatability`, which adds any relief the
    plane through them leaves). With ``ring_mm`` (an end of a ruler's dz, a point of a depth:
    the ring as wide as the points' distance, where it sees errors correlated over that
    distance) the ring's scatter counts where it exceeds the disagreement beyond its own
    sampling spread (:func:`ring_exceeds`), and without the disagreement the larger of the
    standard error and the ring. :func:`combine_noise` with :data:`NOISE_RULE`; its standard
    uncertainty, how it was found, and whether the ring's scatter was taken (None where the
    ring was not tested: a point's own height, or no disagreement)."""
    x, y = readout.x_mm, readout.y_mm
    sigma, n_eff, n, _, _ = patch_noise(ctx.height, ctx.spec, x, y, readout.radius_mm)
    if readout.n_valid > 1 and readout.radius_mm > 0:
        _, n_eff, n, _, _ = patch_noise(ctx.height, ctx.spec, x, y, readout.radius_mm, 0.0)
    else:
        n_eff, n = 1.0, 1
    se = sigma / math.sqrt(max(n_eff, 1.0)) if math.isfinite(sigma) else math.nan
    rep, k = disk_repeatability(ctx.height, ctx.spec, x, y, readout.radius_mm, ring_mm)
    ag = agreement_noise(ctx, x, y, readout.radius_mm)
    u, which = _choose_noise({"standard error": se, "ring": rep,
                              "agreement": ag[0] if ag is not None else math.nan},
                             difference=ring_mm is not None, ring_dof=k - 3)
    rule = _effective_rule(NOISE_RULE, ring_mm is not None, ag is not None)
    says = _RULE_SAYS[rule]
    tested = rule == "ring test" and ag is not None
    if tested and ag is not None:
        if math.isfinite(rep) and k > 3:
            lim = _ring_limit(k - 3, RING_TEST_P)
            says += (f": ring {rep:.4f} mm against the limit {lim:.2f} x {ag[0]:.4f} = "
                     f"{lim * ag[0]:.4f} mm ({k - 3} degrees of freedom), "
                     + ("the ring taken" if which == "ring" else
                        "exceeded, the standard error larger" if ring_exceeds(rep, ag[0], k - 3)
                        else "not exceeded"))
        else:
            says += ": no ring (too few consistent neighbouring means)"
    how = (f"cells: SD {sigma:.4f} mm, n {n}, effective n {n_eff:.1f}, standard error "
           f"{se:.4f} mm; {k} neighbouring means scatter {rep:.4f} mm; "
           + (ag[1] + "; " if ag is not None else "") + says)
    return u, how, (which == "ring") if tested else None


_RULE_SAYS = {
    "agreement": "the larger of the standard error and the lasers' disagreement taken (the "
                 "nearby means left out: at a point's own scale they add relief)",
    "ring test": "the larger of the standard error and the lasers' disagreement taken; the "
                 "nearby means' scatter in place of the disagreement where it exceeds it by "
                 "more than chance alone would 19 times in 20 (noise correlated over the "
                 "points' distance that the disagreement at the disk's scale does not see)",
    "largest": "the largest taken",
    "median": "the median taken",
    "rms": "their root mean square taken",
}


def _effective_rule(rule: str, difference: bool, has_agreement: bool) -> str:
    """The rule :func:`combine_noise` applies: ``agreement`` falls back to ``largest`` where
    the lasers' disagreement is not known, and is the ``ring test`` for the ends of a
    difference."""
    if rule == "agreement":
        if not has_agreement:
            return "largest"
        if difference:
            return "ring test"
    return rule


@functools.lru_cache(maxsize=64)
def _ring_limit(dof: int, p: float) -> float:
    from scipy.stats import chi2

    return math.sqrt(float(chi2.ppf(p, dof)) / dof)


def ring_exceeds(ring: float, agreement: float, dof: int, p: float = RING_TEST_P) -> bool:
    """Whether the scatter of nearby means (``ring``, an SD with ``dof`` degrees of freedom:
    the means used less the plane's 3) exceeds the lasers' disagreement (``agreement``, from
    at least 50 tiles, usually thousands: taken as exact, an approximation) beyond the ring's
    own sampling spread: a one-sided
    chi-square test at ``p``, ``ring^2 / agreement^2 > chi2_p(dof) / dof`` (with 6 degrees of
    freedom at 95 %, a ring more than 1.45 times the disagreement). Two estimates of one
    noise, the larger of them taken, state it too high; the ring counts only where it sees
    more than the disagreement can (errors both lasers share, correlated over the points'
    distance)."""
    if not (math.isfinite(ring) and math.isfinite(agreement)) or dof < 1:
        return math.isfinite(ring) and not math.isfinite(agreement)
    if agreement <= 0:
        return ring > 0
    return ring > agreement * _ring_limit(int(dof), float(p))


def combine_noise(estimates: Mapping[str, float], rule: str | None = None,
                  difference: bool = False, ring_dof: int = 6) -> float:
    """One standard uncertainty from the estimates of a mean's surface noise (NaN: not
    available) by ``rule`` (default :data:`NOISE_RULE`): ``largest``; ``median``; ``rms``
    (root mean square); ``agreement``: for a point's own height (not ``difference``) the
    larger of the standard error and the lasers' disagreement where that is known, else the
    largest; for the ends of a ``difference`` (a ruler's dz, a depth: their ring as wide as
    the distance between the points, where it sees errors correlated over that distance,
    which the disagreement at the disk's scale does not) the larger of the standard error
    and the disagreement, or the ring's scatter where it exceeds the disagreement beyond its
    sampling spread (:func:`ring_exceeds`, ``ring_dof`` its degrees of freedom). NaN when
    none is known."""
    return _choose_noise(estimates, rule, difference, ring_dof)[0]


def _choose_noise(estimates: Mapping[str, float], rule: str | None = None,
                  difference: bool = False, ring_dof: int = 6) -> tuple[float, str | None]:
    """:func:`combine_noise` and which estimate it took (None where the rule combines
    several, or none is known): the value and what a budget says of it come from one
    decision."""
    rule = rule or NOISE_RULE
    if rule not in NOISE_RULES:
        raise ValueError(f"unknown noise rule {rule!r} (one of {', '.join(NOISE_RULES)})")
    v = {k: float(x) for k, x in estimates.items() if x is not None and math.isfinite(x)}
    if not v:
        return math.nan, None
    rule = _effective_rule(rule, difference, "agreement" in v)
    vals = np.array(list(v.values()))
    if rule == "median":
        return float(np.median(vals)), None
    if rule == "rms":
        return float(np.sqrt(np.mean(vals * vals))), None
    if rule == "agreement":
        v = {k: v[k] for k in ("agreement", "standard error") if k in v}
    elif rule == "ring test":
        if not ring_exceeds(v.get("ring", math.nan), v["agreement"], ring_dof):
            v = {k: v[k] for k in ("agreement", "standard error") if k in v}
        else:
            v = {k: v[k] for k in ("ring", "standard error") if k in v}
    which = max(v, key=lambda k: v[k])  # the largest; the first of equal ones
    return v[which], which


def _noise_component(sigma: float, n_eff: float, n: int, what: str) -> Component:
    if not math.isfinite(sigma):
        return Component("surface noise", what, "A", "normal", math.nan, "mm", 1.0, math.nan,
                         "too few cells with data to estimate it")
    u = sigma / math.sqrt(max(n_eff, 1.0))
    return Component("surface noise", what, "A", "normal", sigma, "mm",
                     1.0 / math.sqrt(max(n_eff, 1.0)), u,
                     f"SD {sigma:.4f} mm about a local fit, n {n}, effective n {n_eff:.1f}")


def _laser_shares(ctx: UncertaintyContext, terms) -> dict[str, float]:
    """Per laser, its net share ``c_l = sum_k coef_k w_kl`` in a reading that combines the
    heights of the points ``terms`` (``(x, y, coef)``: e.g. +1 at a ruler's end, -1 at its
    start), ``w_kl`` the weight of laser ``l`` in the point's height."""
    out = dict.fromkeys(LASER_NAMES, 0.0)
    for x, y, coef in terms:
        for la, w in ctx.lasers_at(x, y):
            out[la] += float(coef) * w
    return out


def _method_component(ctx: UncertaintyContext, scale: float = 1.0, terms=None,
                      kind: str = "absolute", radius_mm: float = 0.5) -> list:
    """The method's own component: the validation record's when one is given, else the
    product's figure (:data:`METHOD_STRIPE_PX`) for the reading that combines the heights of
    the points ``terms`` (``(x, y, coef)``). "absolute": a height at a point (``coef`` 1), the
    stripe error times the height per pixel of its lasers. "difference": a difference of
    heights; each laser's own bias moves every height it made alike and cancels between points
    of the same laser: the error of ``sum_k coef_k h_k`` is ``sum_l c_l b_l`` with ``c_l``
    each laser's net share (:func:`_laser_shares`) and ``b_l`` its bias (the stripe error
    times its height per pixel), independent between the lasers."""
    v = ctx.validation
    if not v:
        sigma = METHOD_STRIPE_PX[kind]
        if not ctx.per_px or not terms or sigma <= 0:
            return []
        alone = ""
        if kind == "absolute" and agreement_noise(ctx, terms[0][0], terms[0][1],
                                                  radius_mm) is None:
            # the surface noise has no disagreement figure to carry the detector's local
            # errors: the figure that stood for them too
            sigma = METHOD_STRIPE_PX["absolute, alone"]
            alone = ("the lasers' disagreement not available to the surface noise, so the "
                     "figure that includes the detector's local errors; ")
        c = {la: v for la, v in _laser_shares(ctx, terms).items() if abs(v) > 1e-9}
        px = {la: float(ctx.per_px.get(la, math.nan)) for la in LASER_NAMES}
        known = [v for v in px.values() if math.isfinite(v)]
        if not known:
            return []
        # a laser whose height per pixel is not known (its stripe mostly outside the picture)
        # is taken as the larger known one
        px = {la: v if math.isfinite(v) else max(known) for la, v in px.items()}
        if kind == "absolute":
            s = abs(sum(c[la] * px[la] for la in c))
        else:
            s = math.sqrt(sum((c[la] * px[la]) ** 2 for la in c))
        shares = ", ".join(f"{la} {c[la]:+.2f} x {px[la]:.3f}" for la in c)
        what = {"absolute": "a height", "difference": "a height difference"}[kind]
        how = ("each laser's own bias cancels between points it made both of; "
               if kind == "difference" else "")
        return [Component("method (product)", f"the method's own error in {what}", "B", "normal",
                          sigma, "px", s * scale, sigma * s * scale,
                          f"stripe position error {sigma:g} px (the product's validation on "
                          f"random rigs; no impress validate report of the rig given); {alone}{how}"
                          f"lasers' shares x mm of height per pixel of stripe shift: "
                          f"{shares or 'none'}")]
    bias, sd = float(v.get("bias_mm", 0.0) or 0.0), float(v.get("sd_mm", 0.0) or 0.0)
    u = math.hypot(bias, sd) * scale
    return [Component("method (validation)", "bias and precision of the method", "B", "normal",
                      math.hypot(bias, sd), "mm", scale, u,
                      f"bias {bias:+.3f} mm, SD {sd:.3f} mm from {v.get('source', 'a validation')}")]


def _budget(ctx: UncertaintyContext, reading: str, value: float, comps: Sequence) -> Budget:
    """A reading's budget with the context's notes; with a calibration whose Monte Carlo
    failed (``ctx.unstable``) the calibration's line is there without a figure and no
    uncertainty is stated (a U without its calibration component would be understated)."""
    comps = list(comps)
    if ctx.unstable and not any(c.name == "calibration" for c in comps):
        comps.insert(0, Component("calibration", "the calibration's Monte Carlo", "A",
                                  "Monte Carlo", math.nan, "mm", 1.0, math.nan, ctx.unstable))
    # no k from a budget that states no U (its calibration's line has no figure)
    return Budget(reading, value, tuple(comps), k=K if ctx.unstable else coverage_factor(comps),
                  notes=_notes(ctx, comps),
                  incomplete=ctx.unstable and f"the calibration is unstable ({ctx.unstable}): "
                  "its uncertainty cannot be evaluated - mark the corners again")


def _notes(ctx: UncertaintyContext, comps: Sequence = ()) -> tuple[str, ...]:
    """The context's notes and what the budget ``comps`` says of the method."""
    out = list(ctx.notes)
    if not ctx.validation:
        out.append("method: the product's own figure (no impress validate report of the rig "
                   "given)" if any(c.name == "method (product)" for c in comps) else
                   "method bias from an impress validate report: not included")
    return tuple(out)


# ----- budgets per reading ------------------------------------------------------------------------
def height_budget(ctx: UncertaintyContext, readout, reading: str = "height") -> Budget:
    """The height of a :class:`~impress_gui.core.measure.readings.Readout` (the mean of the
    cells within its radius; on a levelled map, the depth from the levelling plane)."""
    x, y, h = readout.x_mm, readout.y_mm, readout.height_mm
    _, _, _, gx, gy = patch_noise(ctx.height, ctx.spec, x, y, readout.radius_mm)
    comps: list = []
    d = ctx.calibration_deltas([x], [y], ctx.raw_height([x], [y], [h]))
    if d is not None:
        dh = d[2][:, 0]
        if ctx.level_plane is not None:
            dh = dh - _plane_deltas(ctx, x, y)
        comps += _cal_component(dh, "height of the point", ctx)
    ref_slope = _ref_slope_y(ctx)
    comps += _speed_component(ctx, _y_travel(ctx, y) * ref_slope)
    u_n, how = point_noise(ctx, readout)
    comps.append(Component("surface noise", "mean of the cells", "A", "normal", u_n, "mm", 1.0,
                           u_n, how))
    slope = math.hypot(gx, gy) if math.isfinite(gx) else 0.0
    if readout.radius_mm < ctx.spec.pixel_mm / 2:
        comps.append(_grid_component(ctx, slope, 1.0, "position of the cell read"))
    comps += _method_component(ctx, 1.0, [(x, y, 1.0)], "absolute", readout.radius_mm)
    return _budget(ctx, reading, h, comps)


def _y_travel(ctx: UncertaintyContext, y: float) -> float:
    return float(y)


def _ref_slope_y(ctx: UncertaintyContext) -> float:
    e = ctx.ensemble
    if e is None:
        return 0.0
    return float(e.nominal.ref[0, 2])


def _plane_deltas(ctx: UncertaintyContext, x: float, y: float) -> np.ndarray:
    """How the levelling plane at ``(x, y)`` moves per trial: the plane through its support
    points (``ctx.level_support``) as the trials move them; without support points the plane
    is taken not to move (the calibration component is then that of the unlevelled height)."""
    pl, ens = ctx.level_plane, ctx.ensemble
    if ens is None:
        return np.zeros(0)
    d = None
    if ctx.level_support and pl is not None:
        pts = np.asarray(ctx.level_support, float)[:, :2]
        d = ctx.calibration_deltas(pts[:, 0], pts[:, 1], pl.at(pts[:, 0], pts[:, 1]))
    if d is None:
        return np.zeros(ens.n_trials)
    dh = d[2]
    a = np.column_stack([pts[:, 0], pts[:, 1], np.ones(len(pts))])
    coef = np.linalg.lstsq(a, dh.T, rcond=None)[0]  # (3, S)
    return coef[0] * x + coef[1] * y + coef[2]


def depth_budget(ctx: UncertaintyContext, readout, support: Sequence) -> Budget:
    """The depth of a point below a plane through three support readouts (heights on the
    unlevelled map): ``plane(P) - h(P)`` with the plane through ``support``'s means."""
    from impress_gui.core.measure.surface import plane_from_points

    pts = np.array([[s.x_mm, s.y_mm, s.height_mm] for s in support], float)
    plane = plane_from_points(pts.tolist())
    x, y, h = readout.x_mm, readout.y_mm, readout.height_mm
    depth = float(plane.at(x, y) - h)
    m = np.column_stack([pts[:, 0], pts[:, 1], np.ones(3)])
    w = np.linalg.solve(m.T, np.array([x, y, 1.0]))  # plane(P) = w . heights of the support
    comps: list = []
    xs, ys = np.append(pts[:, 0], x), np.append(pts[:, 1], y)
    d = ctx.calibration_deltas(xs, ys, np.append(pts[:, 2], h))
    if d is not None:
        # per trial the four points move in height and across the map: the plane through the
        # moved support points, evaluated at the moved point (a tilted plane read at a point
        # shifted against its supports changes by the plane's slope times the shift)
        comps += _cal_component(_trial_depths(xs, ys, np.append(pts[:, 2], h), d) - depth,
                                "depth below the plane", ctx)
    ring = min(RING_MAX_MM, float(np.median(np.hypot(pts[:, 0] - x, pts[:, 1] - y))))
    got = [_point_noise(ctx, r, ring) for r in (*support, readout)]
    us = np.array([u for u, _, _ in got])
    u = float(math.sqrt(np.nansum((np.append(w, 1.0) * us) ** 2)))
    comps.append(Component("surface noise", "means at the point and the three plane points", "A",
                           "normal", u, "mm", 1.0, u,
                           "each mean's surface noise (the larger of its cells' standard "
                           "error and the lasers' disagreement, the scatter of such means on a "
                           "ring as wide as the points' distance where it exceeds the "
                           "disagreement beyond its sampling spread), weighted by its share of "
                           "the plane at "
                           "the point (" + ", ".join(f"{v:+.2f}" for v in w) + ")"
                           + _ring_taken([t for _, _, t in got])))
    # depth = plane(P) - h(P), plane(P) = w . the supports' heights
    comps += _method_component(ctx, 1.0, [*zip(xs, ys, [*w, -1.0])], "difference")
    return _budget(ctx, "depth below a plane", depth, comps)


def _ring_taken(taken: Sequence[bool | None]) -> str:
    """What the ring test decided at the points (:func:`_point_noise`'s third value; "" where
    no point was tested)."""
    if all(t is None for t in taken):
        return ""
    return f"; the ring's scatter taken at {sum(bool(t) for t in taken)} of {len(taken)} points"


def _trial_depths(xs, ys, hs, d) -> np.ndarray:
    """The depth of point 3 below the plane through points 0-2, per Monte Carlo trial, the
    points moved by the trial's ``(dx, dy, dh)`` (each ``(S, 4)``)."""
    dx, dy, dh = d
    X, Y, H = xs[None] + dx, ys[None] + dy, hs[None] + dh
    m = np.stack([X[:, :3], Y[:, :3], np.ones_like(X[:, :3])], axis=1)  # (S, 3 rows, 3 pts)
    rhs = np.stack([X[:, 3], Y[:, 3], np.ones(len(X))], axis=1)[..., None]
    w = np.linalg.solve(m, rhs)[..., 0]  # plane(P) = w . heights of the support
    return np.einsum("sk,sk->s", w, H[:, :3]) - H[:, 3]


def ruler_budgets(ctx: UncertaintyContext, r) -> dict[str, Budget]:
    """Budgets of a :class:`~impress_gui.core.measure.readings.RulerResult`: ``xy``, ``3d``
    and ``dz`` (the latter two need data at both ends)."""
    a, b = r.start, r.end
    pts_x, pts_y = [a.x_mm, b.x_mm], [a.y_mm, b.y_mm]
    hs = np.array([a.height_mm, b.height_mm], float)
    d = ctx.calibration_deltas(pts_x, pts_y, ctx.raw_height(pts_x, pts_y, hs))
    ux, uy = (b.x_mm - a.x_mm), (b.y_mm - a.y_mm)
    xy = r.xy_mm
    out: dict[str, Budget] = {}
    # xy
    comps: list = []
    if d is not None:
        dx, dy = d[0], d[1]
        xs = np.hypot(ux + dx[:, 1] - dx[:, 0], uy + dy[:, 1] - dy[:, 0])
        comps += _cal_component(xs - xy, "length in the xy plane", ctx)
    comps += _speed_component(ctx, (uy * uy / xy) if xy > 0 else 0.0)
    # no grid term: the ends are the coordinates marked (not snapped to cells), so the length
    # between them is not quantised; where the examiner puts them is not the reading's
    out["xy"] = _budget(ctx, "ruler xy", xy, comps)
    # dz and 3D
    if np.isfinite(hs).all():
        noise, hows = [], []
        for p in (a, b):
            _, _, _, gx, gy = patch_noise(ctx.height, ctx.spec, p.x_mm, p.y_mm, p.radius_mm)
            u_p, _, taken = _point_noise(ctx, p, min(xy, RING_MAX_MM))
            noise.append((u_p, math.hypot(gx, gy) if math.isfinite(gx) else 0.0))
            hows.append(taken)
        u_noise = math.sqrt(sum(u * u for u, _ in noise if math.isfinite(u)))
        slope = math.sqrt(sum(g * g for _, g in noise))
        dz = r.dz_mm
        for key, val in (("dz", dz), ("3d", r.d3_mm)):
            comps = []
            if d is not None:
                dx, dy, dh = d
                dzs = dz + dh[:, 1] - dh[:, 0]
                if key == "dz":
                    comps += _cal_component(dzs - dz, "height difference", ctx)
                else:
                    xys = np.hypot(ux + dx[:, 1] - dx[:, 0], uy + dy[:, 1] - dy[:, 0])
                    comps += _cal_component(np.hypot(xys, dzs) - val, "3D length", ctx)
            c_noise = 1.0 if key == "dz" else (abs(dz) / val if val > 0 else 0.0)
            comps.append(Component("surface noise", "heights of the two ends", "A", "normal",
                                   u_noise, "mm", c_noise, c_noise * u_noise,
                                   "the two ends' means (each the larger of its cells' "
                                   "standard error and the lasers' disagreement, the "
                                   "scatter of such means on a ring as wide as the ruler, "
                                   "up to 15 mm, where it exceeds the disagreement beyond "
                                   "its sampling spread), in quadrature" + _ring_taken(hows)))
            # the heights are read at the cell nearest each end (radius 0) or over a disk
            # about it: the position's resolution moves a height by the slope there
            c_grid = slope if key == "dz" else c_noise * slope
            comps.append(_grid_component(ctx, c_grid, 1.0, "heights read at the ends' cells"))
            comps += _speed_component(ctx, (uy * uy / val) if (key == "3d" and val > 0) else 0.0)
            comps += _method_component(ctx, c_noise, [(a.x_mm, a.y_mm, -1.0),
                                                      (b.x_mm, b.y_mm, 1.0)], "difference")
            out[key] = _budget(ctx, "ruler dz" if key == "dz" else "ruler 3D", val, comps)
    return out


def _band_points(profile, band: Sequence[float], n: int = 5):
    lo, hi = sorted(map(float, band))
    d = np.linspace(lo, hi, n)
    length = profile.length_mm or 1.0
    (x0, y0), (x1, y1) = profile.start, profile.end
    t = d / length
    return x0 + t * (x1 - x0), y0 + t * (y1 - y0)


def _band_values(profile, band: Sequence[float]) -> np.ndarray:
    lo, hi = sorted(map(float, band))
    sel = (profile.distance_mm >= lo) & (profile.distance_mm <= hi)
    return np.asarray(profile.height_mm[sel], float)


def step_budget(ctx: UncertaintyContext, profile, step, band_a, band_b) -> Budget:
    """The step B - A between two bands of a profile (their means)."""
    comps: list = []
    xa, ya = _band_points(profile, band_a)
    xb, yb = _band_points(profile, band_b)
    xs, ys = np.concatenate([xa, xb]), np.concatenate([ya, yb])
    hs = np.concatenate([np.full(len(xa), step.a.mean_mm), np.full(len(xb), step.b.mean_mm)])
    d = ctx.calibration_deltas(xs, ys, ctx.raw_height(xs, ys, hs))
    if d is not None:
        dh = d[2]
        k = len(xa)
        comps += _cal_component(dh[:, k:].mean(1) - dh[:, :k].mean(1), "step between the bands",
                                ctx)
    comps += _speed_component(ctx, _ref_slope_y(ctx) * float(np.mean(yb) - np.mean(ya)))
    sa = series_noise(_band_values(profile, band_a))
    sb = series_noise(_band_values(profile, band_b))
    ua = sa[0] / math.sqrt(sa[1]) if math.isfinite(sa[0]) else math.nan
    ub = sb[0] / math.sqrt(sb[1]) if math.isfinite(sb[0]) else math.nan
    u_se = math.hypot(ua, ub)
    # each band's mean also as the scatter of the same band's mean on a ring around it, as
    # wide as the distance between the bands (errors correlated over more than a band - a
    # frame's offset shared along a stripe - that neither the band's own samples nor
    # profiles beside it see when the profile runs along the scan)
    sep = abs(0.5 * (band_b[0] + band_b[1]) - 0.5 * (band_a[0] + band_a[1]))
    ring = min(max(sep, 1.0), RING_MAX_MM)
    ra, ka = _band_repeatability(ctx, profile, band_a, ring)
    rb, kb = _band_repeatability(ctx, profile, band_b, ring)
    u_ring = math.hypot(float(np.nanmax([ua, ra])), float(np.nanmax([ub, rb])))
    rep, k = _step_repeatability(ctx, profile, band_a, band_b)
    u = combine_noise({"standard error": u_se, "ring": u_ring, "parallel": rep},
                      difference=True)
    comps.append(Component("surface noise", "means of the two bands", "A", "normal", u, "mm", 1.0,
                           u, f"band A: SD {sa[0]:.4f} mm, n {sa[2]}, effective n {sa[1]:.1f}; "
                           f"band B: SD {sb[0]:.4f} mm, n {sb[2]}, effective n {sb[1]:.1f}; "
                           f"standard error {u_se:.4f} mm; each band's mean on a ring of "
                           f"{ring:.1f} mm scatters {ra:.4f} ({ka}) and {rb:.4f} ({kb}) mm, "
                           f"together {u_ring:.4f} mm; the same step on {k} parallel profiles "
                           f"scatters {rep:.4f} mm; "
                           + _RULE_SAYS[_effective_rule(NOISE_RULE, True, False)]))
    comps += _method_component(
        ctx, 1.0, [*((px_, py_, -1.0 / len(xa)) for px_, py_ in zip(xa, ya)),
                   *((px_, py_, 1.0 / len(xb)) for px_, py_ in zip(xb, yb))], "difference")
    return _budget(ctx, "step height B - A", step.difference_mm, comps)


def _band_repeatability(ctx: UncertaintyContext, profile, band, ring_mm: float
                        ) -> tuple[float, int]:
    """The scatter of a band's mean (the band of ``profile`` between the distances ``band``)
    at this scale: the same band moved to 8 places on a ring of ``ring_mm`` around it, about a
    plane through them, as :func:`disk_repeatability` does for a disk; ``(SD, bands used)``,
    NaN with fewer than 6 consistent ones."""
    from impress_gui.core.measure.readings import line_profile

    L = profile.length_mm
    if L <= 0:
        return math.nan, 0
    (x0, y0), (x1, y1) = profile.start, profile.end
    ux, uy = (x1 - x0) / L, (y1 - y0) / L
    a = (x0 + band[0] * ux, y0 + band[0] * uy)
    b = (x0 + band[1] * ux, y0 + band[1] * uy)

    def mean_at(dx: float, dy: float) -> float | None:
        p = line_profile(ctx.height, ctx.spec, (a[0] + dx, a[1] + dy), (b[0] + dx, b[1] + dy),
                         profile.width_mm)
        hv = np.asarray(p.height_mm, float)
        return float(np.nanmean(hv)) if hv.size and np.isfinite(hv).mean() >= 0.5 else None

    return _ring_scatter(mean_at, ring_mm)


def _step_repeatability(ctx: UncertaintyContext, profile, band_a, band_b) -> tuple[float, int]:
    """The scatter of the step on parallel profiles beside this one (offsets of one profile
    width plus 0.5 mm, three on each side) about a line across them: ``(SD, profiles)``;
    profiles over other relief are left out (:func:`_consistent_scatter`), NaN with fewer than
    5 consistent ones."""
    from impress_gui.core.measure.readings import line_profile, step_height

    L = profile.length_mm
    if L <= 0:
        return math.nan, 0
    (x0, y0), (x1, y1) = profile.start, profile.end
    nx, ny = -(y1 - y0) / L, (x1 - x0) / L
    gap = profile.width_mm + 0.5
    offs, steps = [], []
    for k in range(-3, 4):
        o = k * gap
        p = line_profile(ctx.height, ctx.spec, (x0 + o * nx, y0 + o * ny),
                         (x1 + o * nx, y1 + o * ny), profile.width_mm)
        s = step_height(p, band_a, band_b)
        if math.isfinite(s.difference_mm):
            offs.append(o)
            steps.append(s.difference_mm)
    if len(steps) < 5 or 0.0 not in offs:
        return math.nan, len(steps)
    order = np.argsort(np.abs(np.array(offs)), kind="stable")  # this profile first
    o = np.array(offs)[order]
    a = np.column_stack([o, np.ones(len(o))])
    return _consistent_scatter(a, np.array(steps)[order], 5)


def _bracketing_samples(d_all: np.ndarray, h_all: np.ndarray, at_mm: float,
                        level: float) -> tuple[int, int] | None:
    """The two consecutive samples with data between which the profile crosses ``level`` at
    ``at_mm``: of the pairs whose heights straddle the level, the one whose crossing, found
    as :func:`~impress_gui.core.measure.readings.level_crossings` finds it (linear between
    neighbours, the higher side's sample across a gap, which may be the later one), is
    nearest ``at_mm`` - not merely the samples either side of ``at_mm``. Without a level or
    such a pair, the samples with data either side of it. None at the profile's ends."""
    ok = np.flatnonzero(np.isfinite(h_all))
    if ok.size < 2:
        return None
    if math.isfinite(level):
        i0, i1 = ok[:-1], ok[1:]
        s0, s1 = h_all[i0] - level, h_all[i1] - level
        k = np.flatnonzero((s0 < 0) != (s1 < 0))
        if k.size:
            a, b = i0[k], i1[k]
            t = s0[k] / (s0[k] - s1[k])
            pos = np.where(b - a == 1, d_all[a] + t * (d_all[b] - d_all[a]),
                           np.where(s0[k] > s1[k], d_all[a], d_all[b]))
            j = int(np.argmin(np.abs(pos - at_mm)))
            return int(a[j]), int(b[j])
    before, after = ok[d_all[ok] <= at_mm], ok[d_all[ok] > at_mm]
    if not before.size or not after.size:
        return None
    return int(before[-1]), int(after[0])


def _level_fraction(d_all: np.ndarray, h_all: np.ndarray, at_mm: float, level: float,
                    reach_mm: float = 2.0) -> float:
    """Where ``level`` lies between the low and the high side of the wall crossed at
    ``at_mm`` (the profile's lowest and highest heights within ``reach_mm``), 0..1; 0.5 when
    not known. A wall seen as a jump between two samples is crossed by the line joining them
    at this fraction of the way, so the wall's true position lies up to ``max(f, 1 - f)``
    samples from the crossing found."""
    near = np.isfinite(h_all) & (np.abs(d_all - at_mm) <= reach_mm)
    if not near.any() or not math.isfinite(level):
        return 0.5
    lo, hi = float(np.min(h_all[near])), float(np.max(h_all[near]))
    if hi - lo <= 0:
        return 0.5
    return float(np.clip((level - lo) / (hi - lo), 0.0, 1.0))


def crossing_samples(profile, ds: Sequence[float] | np.ndarray, levels: Sequence[float]
                     ) -> list[tuple[float, float, float, int]]:
    """Per crossing of ``levels`` at ``ds`` (mm along ``profile``): the two samples with data
    that bracket it (:func:`_bracketing_samples`) as ``(gap, slope, fraction, lower)``: their
    distance (mm), the profile's slope between them (height per mm, signed), how far down the
    drop between them the level lies (:func:`_hidden_fraction`) and which way the lower one
    lies along the profile (+1 after, -1 before); NaNs (and 0) where there is no such pair."""
    d_all = np.asarray(profile.distance_mm, float)
    h_all = np.asarray(profile.height_mm, float)
    out = []
    for dd, lv in zip(ds, levels):
        pair = _bracketing_samples(d_all, h_all, dd, lv)
        if pair is None:
            out.append((math.nan, math.nan, math.nan, 0))
            continue
        i0, i1 = pair
        gap = float(d_all[i1] - d_all[i0])
        out.append((gap, float(h_all[i1] - h_all[i0]) / max(gap, 1e-9),
                    _hidden_fraction(float(h_all[i0]), float(h_all[i1]), lv),
                    1 if h_all[i1] < h_all[i0] else -1))
    return out


def _hidden_fraction(h0: float, h1: float, level: float) -> float:
    """How far below the higher of two samples ``level`` lies, as a fraction of the drop
    between them (0: at the higher one's height, 1: at the lower's), 0..1; 1 when not known."""
    hi, lo = max(h0, h1), min(h0, h1)
    if not (math.isfinite(level) and hi - lo > 0):
        return 1.0
    return float(np.clip((hi - level) / (hi - lo), 0.0, 1.0))


def hidden_reach(gap_mm: float, fraction: float, sample_mm: float,
                 rule: str | None = None) -> float:
    """How far from the higher side's sample a wall hidden in a gap of ``gap_mm`` can cross a
    level ``fraction`` of the way down the drop across the gap (:func:`_hidden_fraction`), with
    the scanner sampling the profile every ``sample_mm``.

    ``"whole"`` (before 2026-12-05): anywhere in the gap. ``"geometric"`` (:data:`GAP_RULE`):
    a stretch is hidden from a laser (or the camera) behind a top edge: the ray grazing the
    edge comes down across the stretch to the first sample beyond it, so a wall hidden there is
    steeper than that ray, and falls to the level ``fraction`` of the drop below the top within
    ``fraction`` of the stretch; the top's edge itself lies up to a sample beyond the last sample
    on it. So the reach is ``fraction * gap + (1 - fraction) * sample``, never more than the
    gap (a straight wall smeared by the map or dropped as a small island spans the gap, and
    crosses it at the same fraction). A model: on the random-rig benchmark 1-4 % of hidden
    walls lay beyond it (docs/uncertainty.md)."""
    rule = rule or GAP_RULE
    if rule not in GAP_RULES:
        raise ValueError(f"unknown gap rule {rule!r} (one of {', '.join(GAP_RULES)})")
    if rule == "whole" or not (math.isfinite(fraction) and math.isfinite(sample_mm)):
        return float(gap_mm)
    return float(min(gap_mm, fraction * gap_mm + (1.0 - fraction) * sample_mm))


def _profile_sampling(ctx: UncertaintyContext, ux: float, uy: float) -> tuple[float, str]:
    """One sample of the scanner along a profile of direction (``ux``, ``uy``) in mm, and
    what it is: a camera column across the scan and a frame's travel along it, never less than
    a cell of the grid the profile is read from (no separate grid term: the crossings are
    interpolated, not cells)."""
    cell = ctx.spec.pixel_mm
    if ctx.sampling_mm is not None:
        s_mm = max(math.hypot(ux * ctx.sampling_mm[0], uy * ctx.sampling_mm[1]), cell)
        return s_mm, (f"one sample along the profile {s_mm:.3f} mm (a camera column "
                      f"{ctx.sampling_mm[0]:.3f} mm across the scan, a frame's travel "
                      f"{ctx.sampling_mm[1]:.3f} mm along it, at least a cell {cell:g} mm)")
    return cell, f"one sample along the profile: a cell {cell:g} mm (the scanner's sampling not known)"


def _height_noise_beside(profile, at_mm: float) -> float:
    """The profile's height noise beside a wall crossed at ``at_mm``: the scatter about a line
    of the samples 0.5-2 mm before and after it (RMS of the two sides that have data), not of
    the samples on the wall, whose curve is shape, not noise (a line through a wall's S leaves
    residuals of tenths of a millimetre). 0 when neither side has data."""
    sides = []
    for band in ((at_mm - 2.0, at_mm - 0.5), (at_mm + 0.5, at_mm + 2.0)):
        sg, _, n = series_noise(_band_values(profile, band))
        if math.isfinite(sg) and n >= 5:
            sides.append(sg)
    return float(np.sqrt(np.mean(np.square(sides)))) if sides else 0.0


def width_budget(ctx: UncertaintyContext, profile, width,
                 level_bands: Sequence[Sequence[Sequence[float]]] | None = None) -> Budget:
    """The width of a feature at a level (two crossings of a profile), or the distance between
    two edges found as level crossings.

    ``level_bands`` says where the level comes from. None: a height given from outside the
    profile (typed in, or the truth's), fixed under a calibration change, so a trial's absolute
    height change moves the crossings. Otherwise one entry per crossing (left, right), each the
    bands (distance ranges on this profile) whose means' mean is that crossing's level (e.g.
    half the step between a band below and one above, as ``impress validate`` finds its
    edges): a trial moves the level with those bands, so only the surface's change at the
    crossing relative to them moves it."""
    comps: list = []
    L = profile.length_mm or 1.0
    (x0, y0), (x1, y1) = profile.start, profile.end
    ux, uy = (x1 - x0) / L, (y1 - y0) / L
    ds = np.array([width.left_mm, width.right_mm])
    d_all = np.asarray(profile.distance_mm, float)
    h_all = np.asarray(profile.height_mm, float)
    if level_bands is not None:
        levels = [_bands_level(profile, bands) for bands in level_bands]
    else:
        levels = [float(width.level_mm)] * 2
    # each crossing lies between the two samples with data that bracket it: their spacing and
    # the wall's signed slope there (height per mm along the profile)
    walls = crossing_samples(profile, ds, levels)
    gaps = [w[0] for w in walls]
    slopes = [w[1] for w in walls]
    hidden_f = [w[2] for w in walls]
    if ctx.ensemble is not None and np.isfinite(ds).all() and np.isfinite(levels).all():
        trial = _trial_crossings(ctx, profile, ds, levels, level_bands)
        if trial is not None:
            px, py, lost = trial
            w = np.hypot(px[:, 1] - px[:, 0], py[:, 1] - py[:, 0])
            what = ("distance between the crossings, found again per trial on the moved "
                    "profile " + ("at the level of its moved bands" if level_bands is not None
                                  else "at the fixed level") + " and moved across the map")
            found = w[np.isfinite(w)]
            if found.size >= 2:
                cal = _cal_component(found - width.width_mm, what, ctx)
                if lost:  # the reading would fail there: said, not hidden
                    c = cal[0]
                    cal = [Component(c.name, c.quantity, c.evaluation, c.distribution, c.u_x,
                                     c.unit, c.sensitivity, c.u_mm,
                                     c.note + f"; in {lost} of {len(w)} trials the moved "
                                     "profile did not cross the level there (left out)")]
                comps += cal
            else:
                comps.append(Component("calibration", what, "A", "Monte Carlo", math.nan, "mm",
                                       1.0, math.nan, f"in {lost} of {len(w)} trials the moved "
                                       "profile did not cross the level there: not evaluated"))
    comps += _speed_component(ctx, width.width_mm * uy * uy)
    # each crossing: the height noise over the wall's slope moves it, but never beyond the two
    # samples with data that bracket it (the crossing is found between them); where both
    # lasers crossed the level there, their disagreement, if larger (the reconstruction's own
    # error at the wall: a smeared or misplaced wall moves one laser's crossing from the
    # other's, which noise beside the wall does not show)
    us = []
    seen: list[set] = [set(), set()]
    dis = _crossing_disagreement(ctx, profile, ds, levels, level_bands, seen)
    for dd, gap, g, dl in zip(ds, gaps, slopes, dis):
        if not math.isfinite(gap):
            us.append(math.nan)
            continue
        sg = _height_noise_beside(profile, dd)
        shift = sg / abs(g) if g != 0 else math.inf
        us.append(max(min(shift, gap / math.sqrt(3.0)), dl if math.isfinite(dl) else 0.0))
    u = math.hypot(*us)
    said = ", ".join(f"{v:.3f}" if math.isfinite(v) else "-" for v in dis)
    comps.append(Component("surface noise", "positions of the crossings", "A", "normal", u, "mm",
                           1.0, u, "height noise beside each crossing (0.5-2 mm either side, "
                           "off the wall) over the wall's slope, at most the spacing of the "
                           "samples that bracket it (rectangular); or, if larger, the two "
                           "lasers' disagreement on where the wall crosses the level (RMS "
                           "over three parallel lines 0.5 mm apart, over the square root of 2: "
                           f"{said} mm per wall; '-' where one laser did not cross there)"))
    if level_bands is None:  # a fixed level: the method's height error moves the crossings
        comps += _method_width(ctx, ux, uy, x0, y0, ds, gaps, slopes)
    # a wall hidden in a gap of the map (an occluded foot, a shadow: the samples with data
    # that bracket the crossing more than a profile step apart) lies between them; the
    # crossing is put at the higher side's last sample (level_crossings), and the true one
    # lies from there up to hidden_reach into the gap (GAP_RULE), taken as uniform: RMS
    # reach / sqrt(3) about it; with the geometric reach, the top's last sample's own
    # sideways error beside it. That is the whole of its placement error: no one-laser wall
    # error and no lateral-sampling term for it (the gap holds them)
    step = float(d_all[1] - d_all[0]) if d_all.size > 1 else ctx.spec.pixel_mm
    in_gap = [math.isfinite(g) and g > 1.5 * step for g in gaps]
    comps += _one_laser_walls(ctx, dis, [math.nan if hid else g for g, hid in zip(gaps, in_gap)],
                              seen, "fixed" if level_bands is None else "bands")
    s_mm, what = _profile_sampling(ctx, ux, uy)
    fr = [_level_fraction(d_all, h_all, dd, lv) for dd, lv in zip(ds, levels)]
    # the full half-width whatever the wall's slope on the map: a steep wall the reconstruction
    # smeared over several samples (a column lost at a slot's edge, occlusion filled) looks on
    # the map like a wall sloping over them, and is placed no better (a systematic widening,
    # such as impress validate's quick-mode slots, is a method bias this term does not carry)
    if any(in_gap):
        reach = [hidden_reach(g, f, s_mm) if hid else 0.0
                 for g, f, hid in zip(gaps, hidden_f, in_gap)]
        geometric = GAP_RULE == "geometric"
        # a hidden wall lies on the gap's side of its crossing, towards the lower side: the
        # truth minus the reading moves along the profile by 0 to the reach, forward where
        # the wall falls (slope < 0); the width is right minus left, so the walls' shifts add
        # (a block, a groove: both walls widen or both narrow it) or cancel (two steps the
        # same way). One-sided: rectangles of half the reach about their mean, the mean
        # summed with its sign; a wall whose slope is not known is taken either side
        signs = [(1.0 if g < 0 else -1.0) * (1.0 if k == 1 else -1.0)
                 if hid and geometric and math.isfinite(g) and g != 0 else 0.0
                 for k, (g, hid) in enumerate(zip(slopes, in_gap))]
        halves = [r / 2.0 if sg else r for r, sg in zip(reach, signs)]
        # the mean error the walls add to the reading (reading minus truth: the signs are the
        # truth's side), rounded so that two equal reaches cancel to 0 exactly
        err_mean = round(-sum(sg * r / 2.0 for r, sg in zip(reach, signs)), 9)
        off = abs(err_mean)
        ug = [a / math.sqrt(3.0) for a in halves]
        u_gap = math.sqrt(sum(v * v for v in ug) + off * off)
        said = "; ".join(f"{side}: " + (
            f"{g:.2f} mm apart" + (f", the wall within {r:.2f} mm of the higher side's sample "
                                   f"(the level at {f:.2f} of the drop)" if geometric else "")
            if hid else "adjacent")
            for side, g, r, f, hid in zip(("left", "right"), gaps, reach, hidden_f, in_gap))
        comps.append(Component(
            "wall in a gap", "where a wall hidden in missing data lies", "B", "rectangular",
            u_gap, "mm", 1.0, u_gap,
            f"the samples with data either side of each crossing ({said}): the crossing is put "
            "at the higher side's sample, and a wall hidden in the gap lies between it and "
            + ("the reach stated (a wall hidden from a laser or the camera is steeper than "
               "the ray that grazes its top, so it crosses the level within f of the hidden "
               "stretch, f the level's fraction of the drop, plus up to a sample for the top "
               "edge's own place; on the gap's side only, so one-sided: each wall's place "
               "uniform from 0 to its reach, and the reading "
               + (f"is {'short' if err_mean < 0 else 'long'} by {off:.3f} mm on average"
                  if off else "is right on average")
               + " (" + ("the two walls' shifts adding" if signs[0] * signs[1] > 0
                         else "the two walls' shifts cancelling" if signs[0] * signs[1] < 0
                         else "one wall's")
               + "); u the RMS about the reading)"
               if geometric else "the other sample (RMS about the crossing: gap / sqrt(3))")
            + "; no one-laser wall error or lateral sampling for such a wall",
            tuple(math.sqrt(3.0) * v for v in ug if v > 0), err_mean))
        if geometric:
            # the reach holds the wall on the gap's side only; the higher side's last sample
            # is itself placed by the stripe's centre next to the image of the top's edge,
            # which a detector puts up to cells past it (docs/accuracy.md): a sideways error
            # of the crossing either way, as a wall placed by one laser between bands
            n_hid = sum(in_gap)
            u_top = ONE_LASER_WALL_MM["bands"] * math.sqrt(n_hid)
            comps.append(Component(
                "method, top beside a gap", "where the top's last sample beside a gap lies",
                "B", "normal", u_top, "mm", 1.0, u_top,
                f"{ONE_LASER_WALL_MM['bands']:g} mm per wall hidden in a gap ({n_hid}), as a "
                "wall one laser placed between bands (the stripe's centre beside the image of "
                "an edge), the walls independent"))
    u_w = [0.0 if hid else s_mm * max(f, 1.0 - f) / math.sqrt(3.0)
           for f, hid in zip(fr, in_gap)]
    u1 = math.hypot(*u_w)
    comps.append(Component("lateral sampling", "where each wall lies between two samples",
                           "B", "rectangular", u1, "mm", 1.0, u1,
                           f"{what}; a steep wall between two samples is crossed by the line "
                           "between them at the level's fraction f of the step, the wall itself "
                           "anywhere between them: half-width max(f, 1 - f) samples per wall "
                           f"(f {fr[0]:.2f}, {fr[1]:.2f})",
                           tuple(math.sqrt(3.0) * v for v in u_w if v > 0)))
    return _budget(ctx, "width at level", width.width_mm, comps)


#: the per-laser crossings are looked for this far from the fused map's (mm)
DISAGREEMENT_REACH_MM = 2.0


def _crossing_disagreement(ctx: UncertaintyContext, profile, ds: np.ndarray,
                           levels: Sequence[float], level_bands,
                           seen: list[set] | None = None) -> list[float]:
    """Per crossing at distance ``ds[k]``: each laser's own map read along the profile and two
    lines beside it (0.5 mm either side, parallel), each crossing the level (``levels``, fixed
    heights, when ``level_bands`` is None; else each laser's level from the same bands on its
    own profile)
    nearest the fused crossing, within :data:`DISAGREEMENT_REACH_MM`; the RMS of the green
    minus red crossings over the lines where both found one, over sqrt(2) (the standard
    deviation of one laser's crossing, were their errors independent and alike). NaN where
    no line has both, or without both lasers' maps. ``seen`` (two sets, filled in): the
    lasers whose maps crossed each wall's level on any of the lines."""
    from impress_gui.core.measure.readings import level_crossings, line_profile

    out = [math.nan, math.nan]
    pl = ctx.per_laser
    if pl is None or "green" not in pl or "red" not in pl or not np.isfinite(ds).all():
        return out
    (x0, y0), (x1, y1) = profile.start, profile.end
    L = profile.length_mm
    d = np.asarray(profile.distance_mm, float)
    if L <= 0 or d.size < 2:
        return out
    step = float(d[1] - d[0])
    nx, ny = -(y1 - y0) / L, (x1 - x0) / L
    diffs: list[list[float]] = [[], []]
    if seen is None:
        seen = [set(), set()]
    for off in (-0.5, 0.0, 0.5):
        a, b = (x0 + off * nx, y0 + off * ny), (x1 + off * nx, y1 + off * ny)
        found = {}
        for name in LASER_NAMES:
            p = line_profile(pl[name], ctx.spec, a, b, profile.width_mm, step)
            lv = (list(levels) if level_bands is None
                  else [_bands_level(p, bands) for bands in level_bands])
            cs = []
            for k in range(2):
                c = level_crossings(p, lv[k]) if math.isfinite(lv[k]) else np.zeros(0)
                near = c[np.abs(c - ds[k]) <= DISAGREEMENT_REACH_MM] if c.size else c
                cs.append(float(near[np.argmin(np.abs(near - ds[k]))]) if near.size
                          else math.nan)
            found[name] = cs
        for k in range(2):
            g, r = found["green"][k], found["red"][k]
            if math.isfinite(g) and math.isfinite(r):
                diffs[k].append(g - r)
            seen[k].update(n for n in LASER_NAMES if math.isfinite(found[n][k]))
    for k in range(2):
        if diffs[k]:
            out[k] = float(np.sqrt(np.mean(np.square(diffs[k]))) / math.sqrt(2.0))
    return out


#: the standard uncertainty (mm) of where one laser alone places a wall's crossing, by where
#: the level comes from: "fixed" (typed in, or the truth's), "bands" (the mean of bands on the
#: same profile, whose height bias the crossing shares). A wall only one laser saw (the other
#: occluded or shadowed there) has no second laser to show its error; validation, not the
#: scan, gives it: on the training rigs of the coverage benchmark (random rigs 0-22, draw 0,
#: 640x360, 0.5 px clicks), the RMS of the true crossing errors of such walls (not in a gap):
#: 0.44 mm at a fixed level (42 walls on 12 rigs; median 0.07, 95 % within 0.94 mm), 0.11 mm
#: at a level from bands (89 walls on 10 rigs; 95 % within 0.26 mm). (The first figure, 0.36
#: mm for both, was the RMS over sqrt 2 of the two lasers' disagreement where both crossed a
#: fixed level: a different population.)
ONE_LASER_WALL_MM = {"fixed": 0.44, "bands": 0.11}


def _one_laser_walls(ctx: UncertaintyContext, dis: Sequence[float], gaps,
                     seen: Sequence[set] = (set(), set()), level: str = "fixed") -> list:
    """A width (at a fixed level or between bands: ``level`` "fixed" or "bands"): the
    method's wall-placement error, :data:`ONE_LASER_WALL_MM` ``[level]``,
    for each wall without the two lasers' disagreement there (``dis`` NaN: the lasers' maps
    not both crossing the level within :data:`DISAGREEMENT_REACH_MM` of the fused crossing -
    the other laser occluded, one laser's map shown, the per-laser maps not given); two such
    walls taken as independent. ``seen``: the lasers whose maps crossed each wall (named in
    the note)."""
    walls = [k for k in range(2) if math.isfinite(gaps[k]) and not math.isfinite(dis[k])]
    if not walls:
        return []
    if ctx.laser in LASER_NAMES:
        why = f"the heights are the {ctx.laser} laser's alone"
    elif ctx.per_laser is None or not {"green", "red"} <= set(ctx.per_laser):
        why = "the lasers' own maps not given: not known whether both saw the walls"
    else:
        by = ", ".join(f"{('left', 'right')[k]} " + (" and ".join(sorted(seen[k])) or "neither")
                       for k in walls)
        why = ("the two lasers' maps do not both cross the level within "
               f"{DISAGREEMENT_REACH_MM:g} mm of it (one laser occluded there; crossed by: "
               f"{by})")
    per_wall = ONE_LASER_WALL_MM[level]
    u = per_wall * math.sqrt(len(walls))
    which = " and ".join(("left", "right")[k] for k in walls)
    return [Component("method, walls one laser saw", "positions of the crossings", "B", "normal",
                      u, "mm", 1.0, u,
                      f"{which} wall{'s' if len(walls) > 1 else ''}: {why}; "
                      f"{per_wall:g} mm per wall (the walls independent): one laser's "
                      "crossing error " + ("at a fixed level" if level == "fixed" else
                                           "at a level from bands on the same profile")
                      + ", measured on the training rigs (RMS of such walls' true errors)")]


def _method_width(ctx: UncertaintyContext, ux, uy, x0, y0, ds, gaps, slopes) -> list:
    """A width at a level fixed from outside the profile: the method's height error at each
    crossing (:func:`_method_component`, "absolute": the validation record's when one is
    given, else the product's figure) over the wall's slope there, at most the spacing of the
    samples that bracket it; the two added (one bias moves both walls)."""
    shifts = []
    name = note = ""
    for dd, gap, g in zip(ds, gaps, slopes):
        if not (math.isfinite(gap) and math.isfinite(g)):
            return []
        c = _method_component(ctx, 1.0, [(x0 + dd * ux, y0 + dd * uy, 1.0)], "absolute")
        if not c:
            return []
        dh, name, note = c[0].u_mm, c[0].name, c[0].note
        if not math.isfinite(dh):
            return []
        shifts.append(min(dh / abs(g) if g != 0 else math.inf, gap / math.sqrt(3.0)))
    u = float(sum(shifts))
    return [Component(name, "the method's height error at the crossings", "B", "normal", u, "mm",
                      1.0, u, "the height error at each crossing over the wall's slope there, at "
                      "most the spacing of the samples that bracket it; the two walls' shifts "
                      f"added ({shifts[0]:.4f} + {shifts[1]:.4f} mm); the height error: {note}")]


def _band_mask(profile, band: Sequence[float]) -> np.ndarray:
    lo, hi = sorted(map(float, band))
    d = np.asarray(profile.distance_mm, float)
    return (d >= lo) & (d <= hi) & np.isfinite(np.asarray(profile.height_mm, float))


def _bands_level(profile, bands: Sequence[Sequence[float]]) -> float:
    """The mean of the bands' means (as :func:`~impress_gui.core.measure.readings.band_stats`
    takes them); NaN when a band has no data."""
    h = np.asarray(profile.height_mm, float)
    means = [float(h[m].mean()) if (m := _band_mask(profile, b)).any() else math.nan
             for b in bands]
    return float(np.mean(means)) if means else math.nan


#: the largest gap of missing data a crossing is looked for across (as ``level_crossings``)
CROSSING_MAX_GAP_MM = 2.0


def _trial_crossings(ctx: UncertaintyContext, profile, ds: np.ndarray, levels: Sequence[float],
                     level_bands) -> tuple[np.ndarray, np.ndarray, int] | None:
    """Where each Monte Carlo trial puts the crossings found at distances ``ds`` (at heights
    ``levels``): every sample of the profile with data is moved by the trial (its height and
    its place on the map), the level with the bands it comes from (``level_bands``; None: the
    level stays), and the crossing is found again on the moved profile as
    :func:`~impress_gui.core.measure.readings.level_crossings` finds it (linear between
    neighbouring samples, the higher side's sample across a gap), the one nearest the original.
    No division by the slope: between nearly level samples the crossing moves only as far as
    the moved profile really moves it. Returns the crossings' map positions ``(px, py)`` each
    ``(S, 2)`` (NaN in a trial where the moved profile does not cross the level) and how many
    trials lost a crossing; None without calibration trials."""
    d_all = np.asarray(profile.distance_mm, float)
    h_all = np.asarray(profile.height_mm, float)
    ok = np.flatnonzero(np.isfinite(h_all))
    if ok.size < 2:
        return None
    xs, ys = np.asarray(profile.x_mm, float)[ok], np.asarray(profile.y_mm, float)[ok]
    hs, dd = h_all[ok], d_all[ok]
    delta = ctx.calibration_deltas(xs, ys, ctx.raw_height(xs, ys, hs))
    if delta is None:
        return None
    dx, dy, dh = delta
    H = hs[None] + dh  # (S, N): the moved profile
    s = H.shape[0]
    i0, i1 = np.arange(ok.size - 1), np.arange(1, ok.size)
    near = d_all[ok[1:]] - d_all[ok[:-1]] <= CROSSING_MAX_GAP_MM + 1e-9
    adjacent = ok[1:] - ok[:-1] == 1
    px, py = np.full((s, 2), np.nan), np.full((s, 2), np.nan)
    for k in range(2):
        lev = np.full(s, float(levels[k]))
        if level_bands is not None:
            masks = [_band_mask(profile, b)[ok] for b in level_bands[k]]
            lev = lev + np.mean([dh[:, m].mean(1) for m in masks], axis=0)
        s0, s1 = H[:, i0] - lev[:, None], H[:, i1] - lev[:, None]
        cross = ((s0 < 0) != (s1 < 0)) & near[None]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(adjacent[None], s0 / (s0 - s1), np.where(s0 > s1, 0.0, 1.0))
        t = np.where(cross, t, np.nan)
        pos = dd[i0][None] + t * (dd[i1] - dd[i0])[None]
        far = np.where(cross, np.abs(pos - ds[k]), np.inf)
        j = np.argmin(far, axis=1)
        rows = np.arange(s)
        found = np.isfinite(far[rows, j])
        tj = t[rows, j]
        a, b = i0[j], i1[j]
        along = pos[rows, j]
        mx = (1 - tj) * dx[rows, a] + tj * dx[rows, b]
        my = (1 - tj) * dy[rows, a] + tj * dy[rows, b]
        px[:, k] = np.where(found, _at(profile, along, 0) + mx, np.nan)
        py[:, k] = np.where(found, _at(profile, along, 1) + my, np.nan)
    lost = int((~np.isfinite(px).all(1)).sum())
    return px, py, lost


def _at(profile, along: np.ndarray, axis: int) -> np.ndarray:
    """The map coordinate (``axis`` 0: x, 1: y) of distances ``along`` the profile."""
    L = profile.length_mm or 1.0
    p0, p1 = profile.start[axis], profile.end[axis]
    return p0 + np.asarray(along, float) * (p1 - p0) / L


def k_text(budgets, spaced: bool = False) -> str:
    """The coverage factors of ``budgets`` (Budgets or numbers) for a label: ``k=2``, ``k=1.93``
    or, when they differ, ``k=1.93-2`` (``k = 2`` with ``spaced``)."""
    ks = sorted({float(b.k if isinstance(b, Budget) else b) for b in budgets})
    eq = " = " if spaced else "="
    if not ks:
        return f"k{eq}{K:g}"
    return f"k{eq}{ks[0]:g}" if len(ks) == 1 else f"k{eq}{ks[0]:g}-{ks[-1]:g}"


def with_uncertainty(values: dict, budgets: Mapping[str, Budget]) -> dict:
    """``values`` with ``U_k2_<name>_mm``, ``u_c_<name>_mm`` and ``k_<name>`` for each budget
    (name ``""``: ``u_c_mm``, ``U_k2_mm``, ``k``). ``U_k2`` is the expanded uncertainty at the
    coverage probability of k = 2 for a normal distribution (about 95 %; the name from the
    first version, when k was always 2); ``k`` is its coverage factor (:func:`coverage_factor`)."""
    out = dict(values)
    for name, b in budgets.items():
        sfx = f"_{name}" if name else ""
        out[f"u_c{sfx}_mm"] = b.u_c_mm
        out[f"U_k2{sfx}_mm"] = b.U_mm
        out[f"k{sfx}"] = b.k
    return out


def budgets_json(budgets: Mapping[str, Budget]) -> dict:
    return {name: b.to_json() for name, b in budgets.items()}


def budgets_text(budgets_doc: Mapping) -> str:
    """The details of a measurement record's ``uncertainty`` (JSON) as text."""
    return "\n\n".join(budget_from_json(b).text() for b in budgets_doc.values())


def budget_csv_cell(budgets_doc: Mapping | None) -> str:
    return "" if not budgets_doc else json.dumps(budgets_doc, separators=(",", ":"),
                                                 sort_keys=True)
