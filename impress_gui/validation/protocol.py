"""Method validation (Qt-free): the thesis' accuracy protocol as a product feature.

The thesis (chapter 4, table 4.1) scanned two plates with wooden targets - A: a slotted target,
B: a stepped target - in six placements, measured four dimensions per target in the 3D model
(widths in xy, heights in z) and tabulated the absolute errors against caliper values: xy mean
0.60 mm (SD 0.39), z mean 0.94 mm (SD 0.51) over 208 readings. This module holds the protocol:

- :class:`Reading` - one measurement to make (a profile line, bands, the known value), and
  :func:`measure_reading`, which makes it with the product's own measuring functions
  (:mod:`impress_gui.core.measure.readings`): a profile across the target averaged over a width, after
  levelling on the plate around the target; widths are :func:`measure.width_at_level` at half
  the step between two reference bands (or the distance between two such edges), heights are
  :func:`measure.step_height` between two bands;
- :func:`blocks_readings` - the readings of a simulated ``blocks`` scan, placed from its truth;
- :func:`stats`, :func:`summarise` and the thesis' table 4.1 (:data:`THESIS_TABLE`).

The flatness and sphere quantities of VDI/VDE 2634 part 2 are in
:mod:`impress_gui.validation.vdi`, the real-scan file format (the user's known dimensions
and measuring positions) in :mod:`impress_gui.validation.spec`, running it all on
simulator scans or real ones in :mod:`impress_gui.validation.run`, the table and the report
in :mod:`impress_gui.validation.report`.
Coordinates are the reconstruction's rail frame in mm (what the viewer shows); the simulator's
truth ("world") y is the rail y plus the travel at calibration frame t1.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any, TypedDict, TypeVar

import numpy as np

from impress_gui.core.base import codes
from impress_gui.core.base.errors import InputError
from impress_gui.core.measure import readings as M
from impress_gui.core.reconstruction.grid import GridSpec

if TYPE_CHECKING:
    from impress_gui.core.measure.uncertainty import UncertaintyContext

SPEC_FORMAT = "impress.validation-spec"
KINDS = ("width", "edge_distance", "step")
AXIS_OF_KIND = {"width": "xy", "edge_distance": "xy", "step": "z"}

#: the thesis' table 4.1: placement -> (xy mean, xy SD, z mean, z SD) of absolute errors, mm
THESIS_TABLE: dict[str, tuple[float, float, float, float]] = {
    "Order AB": (0.54, 0.34, 1.45, 0.47),
    "Order AB, each rotated 90 degrees": (0.74, 0.36, 1.55, 0.34),
    "Order AB, B lifted by 40 mm": (0.57, 0.48, 0.78, 0.31),
    "Order AB, each tilted by 5.035 degrees": (0.56, 0.36, 0.78, 0.32),
    "Order BA": (0.63, 0.36, 0.52, 0.23),
    "Order BA, each rotated 90 degrees": (0.60, 0.40, 0.67, 0.31),
    "Overall": (0.60, 0.39, 0.94, 0.51),
}
THESIS_READINGS = 208
#: the issue's acceptance bar: five times better than the thesis' overall means
BAR_XY_MM = 0.12
BAR_Z_MM = 0.19


@dataclass(frozen=True)
class Placement:
    """One of the thesis' six placements of plates A and B (the ``blocks`` preset options)."""

    key: str
    title: str
    order: str = "AB"
    rotate90: bool = False
    lift_b_mm: float = 0.0
    tilt_deg: float = 0.0

    def blocks_options(self) -> dict[str, str | bool | float]:
        return {
            "order": self.order,
            "rotate90": self.rotate90,
            "lift_b_mm": self.lift_b_mm,
            "tilt_deg": self.tilt_deg,
        }


#: in the order of the thesis' table 4.1 (its text says "tilted by 5 degrees", its table 5.035)
PLACEMENTS = (
    Placement("AB", "Order AB"),
    Placement("AB-rot90", "Order AB, each rotated 90 degrees", rotate90=True),
    Placement("AB-lift40", "Order AB, B lifted by 40 mm", lift_b_mm=40.0),
    Placement("AB-tilt5", "Order AB, each tilted by 5.035 degrees", tilt_deg=5.035),
    Placement("BA", "Order BA", order="BA"),
    Placement("BA-rot90", "Order BA, each rotated 90 degrees", order="BA", rotate90=True),
)
PLACEMENT_BY_KEY = {p.key: p for p in PLACEMENTS}


# ----- what to measure ----------------------------------------------------------------------
@dataclass(frozen=True)
class Edge:
    """An edge on a profile: where the profile crosses the level halfway between the means of
    two bands (distance ranges in mm along the profile), the crossing nearest ``near_mm`` -
    none (a failed reading) when that is farther than ``max_offset_mm``: a missing wall must
    not be replaced by the next one."""

    band_low_mm: tuple[float, float]
    band_high_mm: tuple[float, float]
    near_mm: float
    max_offset_mm: float | None = None


@dataclass(frozen=True)
class LevelRegion:
    """Levelling reference: a least-squares plane through the cells with data in the rectangle
    ``x_mm`` x ``y_mm`` minus the ``exclude`` rectangles (each ``(x_range, y_range)``)."""

    x_mm: tuple[float, float]
    y_mm: tuple[float, float]
    exclude: tuple[tuple[tuple[float, float], tuple[float, float]], ...] = ()


@dataclass(frozen=True)
class Reading:
    """One measurement to make on a reconstruction (rail-frame mm).

    ``kind``:
    - ``"width"``: the feature containing ``around_mm`` where the profile crosses the level
      halfway between ``band_a_mm`` (e.g. a slot's top) and ``band_b_mm`` (its floor);
    - ``"edge_distance"``: the distance between two :class:`Edge` s (a tread between risers);
    - ``"step"``: ``|mean(band B) - mean(band A)|`` (a depth or a height).
    Bands and ``around_mm`` are distances along the profile from ``start_mm`` to ``end_mm``,
    which is averaged across ``profile_width_mm``; with a ``level`` region the heights are
    first levelled on that plane."""

    id: str
    group: str  # the placement or scan this reading belongs to
    target: str
    kind: str
    nominal_mm: float
    start_mm: tuple[float, float]
    end_mm: tuple[float, float]
    profile_width_mm: float = 2.0
    band_a_mm: tuple[float, float] | None = None
    band_b_mm: tuple[float, float] | None = None
    around_mm: float | None = None
    edges: tuple[Edge, ...] = ()
    level: LevelRegion | None = None
    label: str = ""

    @property
    def axis(self) -> str:
        return AXIS_OF_KIND[self.kind]


@dataclass(frozen=True)
class Result:
    reading: Reading
    measured_mm: float
    error_mm: float  # measured - nominal (NaN when the measurement failed)
    note: str = ""
    #: the reading's stated uncertainty (expanded at about 95 %, and combined standard), NaN
    #: when no budget was computed (issue 22)
    U_mm: float = math.nan  # noqa: N815 - the GUM's symbol
    u_c_mm: float = math.nan
    #: why the budget states no uncertainty ("": it states one, or none was computed)
    no_u: str = ""
    #: the coverage factor of ``U_mm`` (2, or less where a rectangular component shapes it)
    k: float = math.nan

    @property
    def covered(self) -> bool | None:
        """Whether the true error lies within the stated U (None: no error or no U)."""
        if not (math.isfinite(self.error_mm) and math.isfinite(self.U_mm)):
            return None
        return abs(self.error_mm) <= self.U_mm

    def to_json(self) -> dict[str, Any]:
        r = self.reading
        return {
            "id": r.id,
            "group": r.group,
            "target": r.target,
            "label": r.label,
            "kind": r.kind,
            "axis": r.axis,
            "nominal_mm": r.nominal_mm,
            "measured_mm": _num(self.measured_mm),
            "error_mm": _num(self.error_mm),
            "u_c_mm": _num(self.u_c_mm),
            "U_k2_mm": _num(self.U_mm),
            "k": _num(self.k),
            "covered": self.covered,
            **({"no_U": self.no_u} if self.no_u else {}),
            "note": self.note,
            "start_mm": list(r.start_mm),
            "end_mm": list(r.end_mm),
        }


def _num(v: float) -> float | None:
    return round(float(v), 5) if math.isfinite(v) else None


# ----- measuring ----------------------------------------------------------------------------
def crop(
    height: np.ndarray, spec: GridSpec, x_range: Sequence[float], y_range: Sequence[float]
) -> tuple[np.ndarray, GridSpec]:
    """A view of ``height`` covering the ranges (mm) and the view's own grid."""
    p = spec.pixel_mm
    j0 = max(0, math.floor((min(x_range) - spec.x0_mm) / p))
    j1 = min(spec.shape[1], math.ceil((max(x_range) - spec.x0_mm) / p) + 1)
    i0 = max(0, math.floor((min(y_range) - spec.y0_mm) / p))
    i1 = min(spec.shape[0], math.ceil((max(y_range) - spec.y0_mm) / p) + 1)
    if i1 <= i0 or j1 <= j0:
        raise InputError("the measurement lies outside the reconstruction", code=codes.E_VAL_OUTSIDE)
    sub = GridSpec(spec.x0_mm + j0 * p, spec.y0_mm + i0 * p, p, (i1 - i0, j1 - j0))
    return height[i0:i1, j0:j1], sub


def levelled_crop(
    height: np.ndarray, spec: GridSpec, region: LevelRegion
) -> tuple[np.ndarray, GridSpec, M.Plane]:
    """The region's heights levelled on its plane: ``(heights, grid, plane)``."""
    sub, sspec = crop(height, spec, region.x_mm, region.y_mm)
    mask = np.ones(sub.shape, bool)
    xs, ys = sspec.xs(), sspec.ys()
    for bx, by in region.exclude:
        mask[np.ix_((ys >= min(by)) & (ys <= max(by)), (xs >= min(bx)) & (xs <= max(bx)))] = False
    plane = M.plane_from_region(sub, sspec, region.x_mm, region.y_mm, mask)
    return M.levelled(sub, sspec, plane), sspec, plane


#: levelled crops (heights, grid, levelling plane) kept between readings sharing a region
LevelCache = dict[tuple[str, LevelRegion], tuple[np.ndarray, GridSpec, M.Plane]]
#: makes the uncertainty context of a reading from the (cropped, maybe levelled) heights it is
#: measured on, their grid and the levelling plane (None: not levelled)
ContextFactory = Callable[[np.ndarray, GridSpec, "M.Plane | None"], "UncertaintyContext"]

_T = TypeVar("_T")


def _required(value: _T | None, what: str, r: Reading) -> _T:
    """``value``, or an :class:`InputError` (a failed reading) when the reading lacks it."""
    if value is None:
        raise InputError(f"a {r.kind} reading needs {what}", code=codes.E_VAL_SPEC)
    return value


def _edge(profile: M.Profile, e: Edge) -> float:
    lo = M.band_stats(profile, e.band_low_mm)
    hi = M.band_stats(profile, e.band_high_mm)
    level = 0.5 * (lo.mean_mm + hi.mean_mm)
    if not math.isfinite(level):
        return math.nan
    c = M.level_crossings(profile, level)
    if not c.size:
        return math.nan
    best = float(c[np.argmin(np.abs(c - e.near_mm))])
    if e.max_offset_mm is not None and abs(best - e.near_mm) > e.max_offset_mm:
        return math.nan
    return best


def measure_reading(
    height: np.ndarray,
    spec: GridSpec,
    r: Reading,
    cache: LevelCache | None = None,
    context: ContextFactory | None = None,
) -> Result:
    """Make one reading on a heightmap (float32 mm, NaN = no data) with its grid. ``cache``
    keeps levelled regions between readings that share one. With ``context``, the reading's
    uncertainty budget (:mod:`impress_gui.core.measure.uncertainty`) is computed as the viewer
    computes it, and the result carries its U (about 95 %) and k."""
    plane: M.Plane | None = None
    try:
        if r.level is not None:
            key = ("level", r.level)
            if cache is not None and key in cache:
                h, sspec, plane = cache[key]
            else:
                h, sspec, plane = levelled_crop(height, spec, r.level)
                if cache is not None:
                    cache[key] = (h, sspec, plane)
        else:
            pad = r.profile_width_mm + 1.0
            xs, ys = (r.start_mm[0], r.end_mm[0]), (r.start_mm[1], r.end_mm[1])
            h, sspec = crop(
                height, spec, (min(xs) - pad, max(xs) + pad), (min(ys) - pad, max(ys) + pad)
            )
        prof = M.line_profile(h, sspec, r.start_mm, r.end_mm, r.profile_width_mm)
        budget_of: Callable[[UncertaintyContext], Any]
        if r.kind == "step":
            band_a = _required(r.band_a_mm, "band_a_mm", r)
            band_b = _required(r.band_b_mm, "band_b_mm", r)
            s = M.step_height(prof, band_a, band_b)
            value, note = abs(s.difference_mm), f"bands n={s.a.n}/{s.b.n}"

            def budget_of(ctx):
                from impress_gui.core.measure import uncertainty as U

                return U.step_budget(ctx, prof, s, band_a, band_b)
        elif r.kind == "width":
            bands = (_required(r.band_a_mm, "band_a_mm", r),
                     _required(r.band_b_mm, "band_b_mm", r))
            a, b = (M.band_stats(prof, band) for band in bands)
            level = 0.5 * (a.mean_mm + b.mean_mm)
            w = M.width_at_level(prof, level, _required(r.around_mm, "around_mm", r))
            value = w.width_mm
            note = f"at level {level:.3f} mm"

            def budget_of(ctx):
                from impress_gui.core.measure import uncertainty as U

                # the level is half the step between the bands: it moves with them
                return U.width_budget(ctx, prof, w, level_bands=(bands, bands))
        elif r.kind == "edge_distance":
            e0, e1 = (_edge(prof, e) for e in r.edges)
            value, note = abs(e1 - e0), ""
            levels = [
                0.5 * (M.band_stats(prof, e.band_low_mm).mean_mm
                       + M.band_stats(prof, e.band_high_mm).mean_mm)
                for e in r.edges
            ]
            # two edges found as level crossings, like a width's two walls, each at its own
            # level halfway between its two bands (which the budget moves with the surface)
            pair = SimpleNamespace(left_mm=min(e0, e1), right_mm=max(e0, e1),
                                   level_mm=float(np.mean(levels)), width_mm=value)
            edge_bands = [(e.band_low_mm, e.band_high_mm) for e in r.edges]
            if e0 > e1:
                edge_bands.reverse()  # in the order of the crossings along the profile

            def budget_of(ctx):
                from impress_gui.core.measure import uncertainty as U

                return U.width_budget(ctx, prof, pair, level_bands=edge_bands)
        else:
            raise InputError(f"unknown measurement kind {r.kind!r}", code=codes.E_VAL_SPEC)
    except InputError as exc:
        return Result(r, math.nan, math.nan, f"failed: {exc}")
    if not math.isfinite(value):
        return Result(r, math.nan, math.nan, "failed: no data at the measuring position")
    big_u = u_c = k = math.nan
    no_u = ""
    if context is not None:
        budget = budget_of(context(h, sspec, plane))
        big_u, u_c, no_u = float(budget.U_mm), float(budget.u_c_mm), budget.incomplete
        k = float(budget.k)
    return Result(r, float(value), float(value - r.nominal_mm), note, big_u, u_c, no_u, k)


def measure_all(
    height: np.ndarray,
    spec: GridSpec,
    readings: Sequence[Reading],
    context: ContextFactory | None = None,
) -> list[Result]:
    cache: LevelCache = {}
    return [measure_reading(height, spec, r, cache, context) for r in readings]


def coverage(results: Sequence[Result]) -> dict[str, dict[str, Any]]:
    """Per reading kind (and ``"all"``): how many readings have both a true error and a stated
    U (about 95 %), and the share whose error lies within it (the target is about 95 %)."""
    out: dict[str, dict[str, Any]] = {}
    for kind in [*KINDS, "all"]:
        rs = [r for r in results if kind == "all" or r.reading.kind == kind]
        known = [f for f in (r.covered for r in rs) if f is not None]
        # readings measured whose budget states no U (an unstable calibration): counted apart
        no_u = sum(1 for r in rs if r.no_u and math.isfinite(r.error_mm))
        if not known and not no_u:
            continue
        n_in = int(sum(known))
        out[kind] = {"n": len(known), "covered": n_in,
                     "share": round(n_in / len(known), 4) if known else None}
        if no_u:
            out[kind]["no_U"] = no_u
    return out


# ----- the simulator's blocks: readings from the truth features ------------------------------
STATIONS_MM = (-10.0, 0.0, 10.0)  # profile lines across each target (targets are 44 mm long)
PROFILE_WIDTH_MM = 2.0
BAND_MARGIN_MM = 1.0  # bands on tops keep this far from walls and edges
FLOOR_MARGIN_MM = 0.3  # slot floors: laser shadows can leave data only near the walls (rotated)
EDGE_SEARCH_MM = 1.5  # an edge is looked for within this distance of where it should be


class _PlateFrame:
    """Plate-local (a along the target's features, b across) to rail (x, y) coordinates."""

    def __init__(self, centre_y_world: float, rotated: bool, s1: float) -> None:
        self.cy, self.rot, self.s1 = float(centre_y_world), bool(rotated), float(s1)

    def xy(self, a: float, b: float) -> tuple[float, float]:
        x, y = (b, self.cy + a) if self.rot else (a, self.cy + b)
        return (round(float(x), 4), round(float(y - self.s1), 4))

    def box(
        self, a_range: Sequence[float], b_range: Sequence[float]
    ) -> tuple[tuple[float, float], tuple[float, float]]:
        p = [self.xy(a, b) for a in a_range for b in b_range]
        xs, ys = [q[0] for q in p], [q[1] for q in p]
        return (min(xs), max(xs)), (min(ys), max(ys))

    def level_region(self, a_lo: float, a_hi: float) -> LevelRegion:
        """The plate on both sides of a target spanning ``a_lo..a_hi``, the target excluded."""
        outer = self.box((a_lo - 30.0, a_hi + 30.0), (-20.0, 20.0))
        inner = self.box((a_lo - 8.0, a_hi + 8.0), (-30.0, 30.0))
        return LevelRegion(outer[0], outer[1], (inner,))


class _Placed(TypedDict):
    """The keyword arguments the readings along one profile line share."""

    group: str
    target: str
    start_mm: tuple[float, float]
    end_mm: tuple[float, float]
    profile_width_mm: float
    level: LevelRegion


class _PlacedBands(_Placed):
    band_a_mm: tuple[float, float]
    band_b_mm: tuple[float, float]


def blocks_readings(
    truth: Mapping[str, Any], group: str, stations_mm: Sequence[float] = STATIONS_MM
) -> list[Reading]:
    """The four thesis measurements per target at each station across the target, placed from
    the truth features of a simulated ``blocks`` scan.

    Slotted target A: xy = widths of the two widest slots, z = their depths.
    Stepped target B: xy = widths of treads 2 and 3 (riser to riser), z = the first step's
    rise above the plate and the whole stair's rise."""
    try:
        s1 = float(truth["travel_mm"][truth["calibration_frames"]["t1"]])
        feats = list(truth.get("features", []))
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise InputError(f"not a simulator truth ({exc})", code=codes.E_VAL_TRUTH) from None
    slots = sorted((f for f in feats if f.get("kind") == "slot"), key=lambda f: f["centre_a_mm"])
    steps = [f for f in feats if f.get("kind") == "steps"]
    if not slots or not steps:
        raise InputError(
            "the truth has no slotted and stepped targets (not a blocks scan)", code=codes.E_VAL_TRUTH
        )
    m = BAND_MARGIN_MM
    out: list[Reading] = []
    # ----- slotted target: walls between the slots are as wide as the widest slot
    fr = _PlateFrame(slots[0]["plate_centre_y_mm"], slots[0]["rotated90"], s1)
    land = max(f["width_mm"] for f in slots)
    region = fr.level_region(
        slots[0]["centre_a_mm"] - slots[0]["width_mm"] / 2 - land,
        slots[-1]["centre_a_mm"] + slots[-1]["width_mm"] / 2 + land,
    )
    for k, f in enumerate(sorted(slots, key=lambda f: -f["width_mm"])[:2], 1):
        w, depth = float(f["width_mm"]), float(f["depth_mm"])
        a_l = f["centre_a_mm"] - w / 2
        start, end = a_l - land - 2.0, a_l + w + land + 2.0
        off = a_l - start  # the near wall's distance along the profile
        top = (off - land + m, off - m)
        top2 = (off + w + m, off + w + land - m)
        fm = min(FLOOR_MARGIN_MM, w / 4)
        floor = (off + fm, off + w - fm)
        walls = (Edge(floor, top, off, EDGE_SEARCH_MM), Edge(floor, top2, off + w, EDGE_SEARCH_MM))
        for b in stations_mm:
            common_a = _PlacedBands(
                group=group,
                target="A",
                start_mm=fr.xy(start, b),
                end_mm=fr.xy(end, b),
                profile_width_mm=PROFILE_WIDTH_MM,
                level=region,
                band_a_mm=top,
                band_b_mm=floor,
            )
            out.append(
                Reading(
                    f"{group}/A/slot{k}-width/b{b:+.0f}",
                    kind="edge_distance",
                    nominal_mm=w,
                    edges=walls,
                    label=f"A: slot {k} width",
                    **common_a,
                )
            )
            out.append(
                Reading(
                    f"{group}/A/slot{k}-depth/b{b:+.0f}",
                    kind="step",
                    nominal_mm=depth,
                    label=f"A: slot {k} depth",
                    **common_a,
                )
            )
    # ----- stepped target
    st = steps[0]
    fr = _PlateFrame(st["plate_centre_y_mm"], st["rotated90"], s1)
    sw, sh, n = float(st["step_width_mm"]), float(st["step_height_mm"]), int(st["n_steps"])
    a0 = float(st["start_a_mm"])
    region = fr.level_region(a0, a0 + n * sw)
    start, end = a0 - 8.0, a0 + n * sw - 0.5
    riser = [8.0 + k * sw for k in range(n)]  # riser k + 1 along the profile
    plate_band = (riser[0] - 6.0, riser[0] - m)

    def tread(k: int) -> tuple[float, float]:  # tread k (1-based)
        return (riser[k - 1] + m, riser[k - 1] + sw - m)

    for b in stations_mm:
        common = _Placed(
            group=group,
            target="B",
            start_mm=fr.xy(start, b),
            end_mm=fr.xy(end, b),
            profile_width_mm=PROFILE_WIDTH_MM,
            level=region,
        )
        for k in (2, 3):
            edges = (
                Edge(tread(k - 1), tread(k), riser[k - 1], EDGE_SEARCH_MM),
                Edge(tread(k), tread(k + 1), riser[k], EDGE_SEARCH_MM),
            )
            out.append(
                Reading(
                    f"{group}/B/tread{k}-width/b{b:+.0f}",
                    kind="edge_distance",
                    nominal_mm=sw,
                    edges=edges,
                    label=f"B: tread {k} width",
                    **common,
                )
            )
        out.append(
            Reading(
                f"{group}/B/step1-rise/b{b:+.0f}",
                kind="step",
                nominal_mm=sh,
                band_a_mm=plate_band,
                band_b_mm=tread(1),
                label="B: first step rise",
                **common,
            )
        )
        out.append(
            Reading(
                f"{group}/B/stair-rise/b{b:+.0f}",
                kind="step",
                nominal_mm=n * sh,
                band_a_mm=plate_band,
                band_b_mm=tread(n),
                label=f"B: rise of {n} steps",
                **common,
            )
        )
    return out


# ----- statistics ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Stats:
    """Absolute errors of a set of readings: count, mean, sample SD, maximum; ``failed``
    readings (no data at the position) are counted apart, never as zero."""

    n: int
    mean_mm: float
    sd_mm: float
    max_mm: float
    failed: int = 0

    def to_json(self) -> dict[str, Any]:
        return {
            "n": self.n,
            "mean_abs_mm": _num(self.mean_mm),
            "sd_mm": _num(self.sd_mm),
            "max_abs_mm": _num(self.max_mm),
            "failed": self.failed,
        }


def stats(errors: Sequence[float]) -> Stats:
    e = np.abs(np.asarray(list(errors), np.float64))
    ok = e[np.isfinite(e)]
    failed = int(e.size - ok.size)
    if not ok.size:
        return Stats(0, math.nan, math.nan, math.nan, failed)
    sd = float(ok.std(ddof=1)) if ok.size > 1 else 0.0
    return Stats(int(ok.size), float(ok.mean()), sd, float(ok.max()), failed)


def summarise(
    results: Sequence[Result], groups: Sequence[str] | None = None
) -> dict[str, dict[str, Stats]]:
    """``{group: {"xy": Stats, "z": Stats}}`` in ``groups`` order, then ``"Overall"``."""
    order = (
        list(groups)
        if groups is not None
        else list(dict.fromkeys(r.reading.group for r in results))
    )
    out: dict[str, dict[str, Stats]] = {}
    for g in [*order, "Overall"]:
        sel = [r for r in results if g == "Overall" or r.reading.group == g]
        out[g] = {
            ax: stats([r.error_mm for r in sel if r.reading.axis == ax]) for ax in ("xy", "z")
        }
    return out
