"""``impress compare``: the whole comparison of two (or more) surfaces, written as one folder.

:func:`compare` registers B onto A and computes the difference over A's relief window;
:func:`write_comparison` does the command's job: inputs and output checked before any work,
every file made in memory and written atomically into a hidden folder that replaces ``OUT``
at the end (:class:`~impress_gui.core.base.outdir.OutputFolder`). The folder holds

- ``difference.tif`` - float32 ``A - B`` in mm on A's window (NaN outside the overlap): by
  default the signed distance along A's surface normal, or the vertical difference
  (``CompareParams.metric``; :mod:`.difference`);
- ``a.tif``, ``b_on_a.tif`` - A's window and B resampled onto it (float32 mm);
- ``difference.png`` - the difference with a diverging colour scale (blue: B higher, red: A
  higher) and the threshold's outlines; ``histogram.png``;
- ``mean.tif``, ``std.tif``, ``count.tif`` (``--mean``) - the mean track of all the inputs;
- ``compare.json`` - the record: every input's SHA-256 (and the chain behind it: a
  reconstruction's video and calibration), every parameter, the registration (4 x 4 matrix,
  mirror and inversion, pairs, residual RMS, overlap), the difference's figures and regions,
  every other file's SHA-256;
- ``report.html`` - the same for people, the figures embedded.

Nothing carries a date or a time: the same inputs give the same bytes.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from impress_gui import __version__
from impress_gui.core.base import codes
from impress_gui.core.base.errors import InputError
from impress_gui.core.base.progress import CancelToken, ProgressCallback, report, sub_progress
from impress_gui.core.compare.difference import (
    DEFAULT_METRIC,
    METRIC_TEXT,
    DiffStats,
    Region,
    check_metric,
    difference,
    outline,
    resample,
    statistics,
)
from impress_gui.core.compare.mean import MeanTrack, mean_track
from impress_gui.core.compare.register import Registration, RegistrationParams, register
from impress_gui.core.compare.surfaces import DEFAULT_PLY_PIXEL_MM, Surface, load_surface

COMPARE_FORMAT = "impress.compare"
COMPARE_VERSION = 1
KIND = "comparison"
RECORD_FILE = "compare.json"
FILES = ("difference.tif", "a.tif", "b_on_a.tif", "difference.png", "histogram.png",
         "mean.tif", "std.tif", "count.tif", RECORD_FILE, "report.html", "report.pdf")
DEFAULT_THRESHOLD_MM = 0.25
MAX_FIGURE_PX = 1600
METRIC_SHORT = {"normal": "along A's normal", "vertical": "vertical"}
SCALE_LABEL = {"normal": "A-B normal mm", "vertical": "A-B mm"}
FRAME = ("right-handed, in mm: the export frame of input A (x = rail X, y = -rail Y, z up); "
         "B is moved onto A by matrix_b_to_a")


@dataclass(frozen=True)
class CompareParams:
    registration: RegistrationParams = field(default_factory=RegistrationParams)
    threshold_mm: float = DEFAULT_THRESHOLD_MM
    min_region_mm2: float = 0.1
    outline_walls: bool = False  # outline A's steep walls too (difference.steep_walls)
    histogram_half_range_mm: float = 1.0
    ply_pixel_mm: float = DEFAULT_PLY_PIXEL_MM
    mean: bool = False
    metric: str = DEFAULT_METRIC  # difference.METRICS: along A's normal, or vertical

    def check(self) -> None:
        self.registration.check()
        check_metric(self.metric)
        for name, lo, hi in (("threshold_mm", 0.0, 100.0), ("min_region_mm2", 0.0, 1e6),
                             ("histogram_half_range_mm", 0.0, 100.0),
                             ("ply_pixel_mm", 0.0, 10.0)):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and lo < v <= hi):
                raise InputError(f"{name.replace('_', '-')} must be above {lo:g} and at most "
                                 f"{hi:g} (got {v})", code=codes.E_COMPARE_OPTION)

    def to_json(self) -> dict:
        return {"registration": self.registration.to_json(), "threshold_mm": self.threshold_mm,
                "min_region_mm2": self.min_region_mm2, "outline_walls": self.outline_walls,
                "histogram_half_range_mm": self.histogram_half_range_mm,
                "ply_pixel_mm": self.ply_pixel_mm, "mean": self.mean, "metric": self.metric}


@dataclass(frozen=True)
class Comparison:
    a: Surface  # A's window (the region compared)
    b_on_a: np.ndarray
    diff: np.ndarray
    registration: Registration
    stats: DiffStats
    regions: list[Region]
    outline: np.ndarray
    metric: str = DEFAULT_METRIC  # how diff was measured (difference.METRICS)


def derive(a: Surface, b_on_a: np.ndarray, registration: Registration,
           params: CompareParams) -> Comparison:
    """The difference of A's window and B resampled onto it by ``params.metric``, its figures
    and the regions beyond ``params.threshold_mm``."""
    params.check()
    diff = difference(a, b_on_a, params.metric)
    stats = statistics(diff, a, params.histogram_half_range_mm)
    if stats.cells < 100:
        raise InputError(f"after registration A and B share {stats.cells} cells: no difference map",
                 code=codes.E_COMPARE_NO_OVERLAP)
    regions, edge = outline(diff, a, params.threshold_mm, params.min_region_mm2,
                            walls=params.outline_walls)
    return Comparison(a, b_on_a, diff, registration, stats, regions, edge, params.metric)


def compare(a: Surface, b: Surface, params: CompareParams = CompareParams(),
            progress: ProgressCallback | None = None,
            cancel: CancelToken | None = None) -> Comparison:
    """Register ``b`` onto ``a``; the difference over A's relief window."""
    params.check()
    reg = register(a, b, params.registration, sub_progress(progress, 0.0, 0.6), cancel)
    win = a.crop(reg.window())
    b_on = resample(win, b, reg.matrix, progress=sub_progress(progress, 0.6, 0.9),
                    cancel=cancel)
    cmp = derive(win, b_on, reg, params)
    report(progress, 1.0, "compared")
    return cmp


# ----- figures -------------------------------------------------------------------------------
_DIVERGING = np.array([[5, 48, 97], [33, 102, 172], [67, 147, 195], [146, 197, 222],
                       [209, 229, 240], [247, 247, 247], [253, 219, 199], [244, 165, 130],
                       [214, 96, 77], [178, 24, 43], [103, 0, 31]], np.float64)


def diverging_lut() -> np.ndarray:
    """256 RGB entries: dark blue (negative) - white (0) - dark red (positive)."""
    t = np.linspace(0, len(_DIVERGING) - 1, 256)
    k = np.minimum(t.astype(int), len(_DIVERGING) - 2)
    f = (t - k)[:, None]
    return np.rint(_DIVERGING[k] * (1 - f) + _DIVERGING[k + 1] * f).astype(np.uint8)


def _nice_up(v: float) -> float:
    if not math.isfinite(v) or v <= 0:
        return 1.0
    p = 10 ** math.floor(math.log10(v))
    for m in (1, 2, 2.5, 5, 10):
        if m * p >= v - 1e-12:
            return m * p
    return 10 * p


def colour_range(stats: DiffStats, threshold_mm: float) -> float:
    """The colour scale's half range (mm): a round number at least twice the threshold and the
    99th percentile of |A - B|."""
    return _nice_up(max(2 * threshold_mm, stats.p99_abs_mm if math.isfinite(stats.p99_abs_mm)
                        else 0.0))


def _display(arr: np.ndarray, surface: Surface) -> tuple[np.ndarray, int]:
    """Rows as seen from above (largest y first) and every ``step``-th cell for the figure."""
    a = arr if surface.y_step_mm < 0 else arr[::-1]
    step = max(1, math.ceil(max(a.shape) / MAX_FIGURE_PX))
    return a[::step, ::step], step


def _text(img, s, org, scale=0.45, colour=(0, 0, 0)) -> None:
    import cv2

    cv2.putText(img, s, org, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


def difference_png(cmp: Comparison, half_range_mm: float, title: str,
                   scale_label: str = "A-B mm") -> bytes:
    from impress_gui.core.formats.images import png_bytes

    d, step = _display(cmp.diff, cmp.a)
    edge, _ = _display(cmp.outline, cmp.a)
    lut = diverging_lut()
    t = (np.nan_to_num(d, nan=0.0) + half_range_mm) * (255.0 / (2 * half_range_mm))
    rgb = lut[np.clip(np.rint(t), 0, 255).astype(np.uint8)]
    rgb[~np.isfinite(d)] = (40, 40, 40)
    rgb[edge] = (0, 160, 0)
    h, w = rgb.shape[:2]
    bar_w, pad, top = 110, 10, 34
    img = np.full((h + top + pad, w + bar_w + 2 * pad, 3), 255, np.uint8)
    img[top : top + h, pad : pad + w] = rgb
    _text(img, title[:120], (pad, 22))
    bx = w + 2 * pad
    ramp = lut[np.linspace(255, 0, h).astype(int)]
    img[top : top + h, bx : bx + 20] = ramp[:, None, :]
    for v in (-half_range_mm, -half_range_mm / 2, 0.0, half_range_mm / 2, half_range_mm):
        y = top + int(round((half_range_mm - v) / (2 * half_range_mm) * (h - 1)))
        img[y, bx + 20 : bx + 26] = 0
        _text(img, f"{v:+.3g}", (bx + 28, min(top + h, max(top + 10, y + 4))), 0.4)
    _text(img, scale_label, (bx, top + h + 8 if h > 60 else top + h), 0.4)
    return png_bytes(img)


def histogram_png(stats: DiffStats, threshold_mm: float, what: str = "A - B") -> bytes:
    from impress_gui.core.formats.images import png_bytes

    counts = np.asarray(stats.histogram_counts, np.float64)
    edges = np.asarray(stats.histogram_edges_mm, np.float64)
    w, h, left, bottom, top = 800, 360, 60, 40, 30
    img = np.full((h, w, 3), 255, np.uint8)
    pw, ph = w - left - 20, h - bottom - top
    peak = counts.max() if counts.size and counts.max() > 0 else 1.0
    n = len(counts)
    lo, hi = edges[0], edges[-1]
    for k, c in enumerate(counts):
        x0 = left + int(k * pw / n)
        x1 = max(x0 + 1, left + int((k + 1) * pw / n))
        y = top + ph - int(round(ph * math.sqrt(c / peak)))
        img[y : top + ph, x0:x1] = (70, 110, 170)
    img[top + ph, left : left + pw] = 0
    img[top : top + ph, left] = 0
    for v in np.linspace(lo, hi, 5):
        x = left + int(round((v - lo) / (hi - lo) * pw))
        img[top + ph : top + ph + 5, x] = 0
        _text(img, f"{v:+.2f}", (x - 18, top + ph + 18), 0.4)
    for v in (-threshold_mm, threshold_mm):
        if lo < v < hi:
            x = left + int(round((v - lo) / (hi - lo) * pw))
            img[top:top + ph:3, x] = (0, 160, 0)
    _text(img, f"{what} (mm); bar height: square root of the cell count; green: the threshold",
          (left, 20), 0.42)
    return png_bytes(img)


def map_png(height: np.ndarray, surface: Surface, vrange: tuple[float, float]) -> bytes:
    from impress_gui.core.formats.images import png_bytes

    d, _ = _display(height, surface)
    lo, hi = vrange
    t = (np.nan_to_num(d, nan=lo) - lo) / (hi - lo if hi > lo else 1.0)
    g = np.clip(np.rint(40 + 215 * t), 0, 255).astype(np.uint8)
    rgb = np.repeat(g[..., None], 3, axis=2)
    rgb[~np.isfinite(d)] = (0, 0, 0)
    return png_bytes(rgb)


# ----- the record ----------------------------------------------------------------------------
def _input_doc(s: Surface) -> dict:
    src = dict(s.source)
    return {k: v for k, v in src.items() if v is not None}


def record_document(cmp: Comparison, b: Surface, params: CompareParams, colour_mm: float,
                    mean: MeanTrack | None, more: Sequence[tuple[Surface, Registration]]
                    ) -> dict:
    doc = {
        "format": COMPARE_FORMAT,
        "version": COMPARE_VERSION,
        "software": f"IMPREsS workstation {__version__}",
        "inputs": {"a": _input_doc(cmp.a), "b": _input_doc(b),
                   **{f"input_{k + 3}": _input_doc(s) for k, (s, _) in enumerate(more)}},
        "parameters": params.to_json(),
        "frame": {"units": "mm", "handedness": "right", "description": FRAME},
        "registration": cmp.registration.to_json(),
        "grid": cmp.a.grid_json(),
        "difference": {**cmp.stats.to_json(), "metric": params.metric,
                       "definition": METRIC_TEXT[params.metric],
                       "sign": "A - B (positive: A higher)",
                       "colour_half_range_mm": colour_mm},
        "regions": {"threshold_mm": params.threshold_mm,
                    "steep_walls": "outlined" if params.outline_walls else (
                        "left out: cells of A where one cell of lateral misplacement changes "
                        "the height by more than the threshold"),
                    "count": len(cmp.regions),
                    "items": [r.to_json() for r in cmp.regions]},
    }
    if more:
        doc["more_registrations"] = [{"input": f"input_{k + 3}", **r.to_json()}
                                     for k, (_, r) in enumerate(more)]
    if mean is not None:
        doc["mean_track"] = mean.summary()
    return doc


REPORT = """\
{% macro table(items) %}<table>{% for k, v in items %}<tr><th>{{ k }}</th><td>{{ v }}</td></tr>\
{% endfor %}</table>{% endmacro %}
<!DOCTYPE html>
<html><head><meta charset='utf-8'><title>IMPREsS comparison</title>
<style>body{font-family:sans-serif;margin:2em;color:#111}table{border-collapse:collapse;\
margin:0.5em 0 1.5em}th,td{border:1px solid #bbb;padding:3px 8px;text-align:left;\
font-size:90%;vertical-align:top}th{background:#eee}img{max-width:100%;border:1px solid #ccc}\
code{font-size:85%}</style></head><body>
<h1>IMPREsS comparison report</h1>
<p>IMPREsS workstation {{ version }}. Frame: {{ frame }}.</p>
<h2>Inputs and the chain behind them (SHA-256)</h2>
{% for name, src in inputs %}
<h3>{{ name }}: {{ src.get('kind', '') }}</h3>
{{ table(src_rows(src)) }}
{% endfor %}
<h2>Registration (B onto A)</h2>
{{ table(registration) }}
<h2>Difference A - B over the overlap</h2>
<p>{{ metric }}.</p>
{{ table(difference) }}
<h2>Regions beyond {{ threshold }} mm (largest first{% if regions|length == 20 %}, the first 20
{% endif %})</h2>
{% if regions %}
<table><tr><th>#</th><th>area mm2</th><th>deepest mm</th><th>depth p90 mm</th>\
<th>length mm</th><th>width mm</th><th>centroid x, y mm</th></tr>
{% for r in regions %}<tr><td>{{ loop.index }}</td><td>{{ '%.3f'|format(r.area_mm2) }}</td>\
<td>{{ '%+.3f'|format(r.deepest_mm) }}</td><td>{{ '%.3f'|format(r.depth_p90_mm) }}</td>\
<td>{{ '%.2f'|format(r.length_mm) }}</td><td>{{ '%.2f'|format(r.width_mm) }}</td>\
<td>{{ '%.2f, %.2f'|format(r.centroid_mm[0], r.centroid_mm[1]) }}</td></tr>
{% endfor %}</table>
{% else %}<p>None.</p>{% endif %}
{% if mean %}<h2>Mean track</h2>{{ table(mean) }}{% endif %}
<h2>Files of this comparison (SHA-256)</h2>
{{ table(files) }}
<h2>Figures</h2>
{% for caption, data in images %}
<figure><img alt='{{ caption }}' src='data:image/png;base64,{{ data }}'>\
<figcaption>{{ caption }}</figcaption></figure>
{% endfor %}
</body></html>
"""


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, (list, tuple)):
        return ", ".join(_fmt(x) for x in v)
    if isinstance(v, dict):
        return "; ".join(f"{k}: {_fmt(x)}" for k, x in v.items())
    return "-" if v is None else str(v)


def _src_rows(src: dict) -> list[tuple[str, str]]:
    rows = [("path", src.get("path", "-"))]
    for name, sha in (src.get("files") or {}).items():
        rows.append((f"{name} sha256", sha))
    for key in ("video_sha256", "calibration_sha256", "gridded_pixel_mm"):
        if src.get(key) is not None:
            rows.append((key.replace("_", " "), _fmt(src[key])))
    return rows


def _sentence(s: str) -> str:
    return s[:1].upper() + s[1:]


def report_html(doc: dict, files: dict, images: Sequence[tuple[str, bytes]]) -> str:
    import base64

    import jinja2

    env = jinja2.Environment(autoescape=True, trim_blocks=True, lstrip_blocks=True,
                             undefined=jinja2.StrictUndefined)
    reg = doc["registration"]
    matrix = " / ".join(" ".join(f"{v:+.9f}" for v in row) for row in reg["matrix_b_to_a"])
    registration = [
        ("method (coarse)", reg["coarse"]["method"]),
        ("refinement", "open3d point-to-plane ICP, Tukey kernel; stages: " + "; ".join(
            f"{s['max_distance_mm']:g} mm (fitness {s['fitness']:.3f})" for s in reg["icp"])),
        ("mirror (x -> -x)", "yes" if reg["mirror"] else "no"),
        ("height inversion (z -> -z)", "yes" if reg["invert"] else "no"),
        ("turn about z (deg)", f"{reg['rotation_about_z_deg']:.4f}"),
        ("matrix B -> A (rows)", matrix),
        ("residual RMS (mm)", f"{reg['residual_rms_mm']:.4f} over {reg['residual_inliers']} "
                              f"of {reg['residual_points']} points within "
                              f"{doc['parameters']['registration']['max_distance_mm']:g} mm"),
        ("overlap", f"{reg['overlap']:.3f} (share of B's points with a partner within "
                    f"{doc['parameters']['registration']['overlap_tolerance_mm']:g} mm)"),
        ("point pairs", _fmt(doc["parameters"]["registration"]["pairs"])),
    ]
    d = doc["difference"]
    difference_rows = [("metric", d.get("metric", "vertical"))] + [
        (k.replace("_", " "), _fmt(d[k])) for k in
        ("overlap_cells", "overlap_share_of_a", "mean_mm", "median_mm", "rms_mm", "p95_abs_mm",
         "p99_abs_mm", "max_abs_mm", "colour_half_range_mm")]
    mean = None
    if "mean_track" in doc:
        mean = [(k.replace("_", " "), _fmt(v)) for k, v in doc["mean_track"].items()]
    tpl = env.from_string(REPORT)
    tpl.globals["src_rows"] = _src_rows
    return tpl.render(
        version=__version__, frame=doc["frame"]["description"],
        inputs=list(doc["inputs"].items()), registration=registration,
        difference=difference_rows,
        metric=_sentence(str(d.get("definition", METRIC_TEXT["vertical"]))),
        threshold=doc["regions"]["threshold_mm"],
        regions=doc["regions"]["items"][:20], mean=mean,
        files=sorted(files.items()),
        images=[(c, base64.b64encode(p).decode("ascii")) for c, p in images])


def _tif(arr: np.ndarray, pixel_mm: float, what: str, inputs: str = "") -> bytes:
    from impress_gui.core.formats.images import tiff_bytes

    return tiff_bytes(arr, pixel_mm=pixel_mm,
                      description=f"IMPREsS comparison: {what}{inputs}",
                      software=f"IMPREsS workstation {__version__}")


def _inputs_line(surfaces: Sequence[Surface]) -> str:
    """The compared inputs' files and SHA-256, for the figures' and maps' own descriptions
    (every parameter is in compare.json)."""
    parts = []
    for label, s in zip("ABCDEFGHIJKLMNOPQRSTUVWXYZ", surfaces):
        files = (s.source or {}).get("files") or {}
        parts.append(f"{label} " + ", ".join(f"{n} sha256 {h}" for n, h in sorted(files.items())))
    return "; inputs: " + "; ".join(parts) + "; parameters: compare.json"


def _json_bytes(doc: dict) -> bytes:
    from impress_gui.core.base.fileio import dumps_json

    return dumps_json(doc).encode("utf-8")


def write_comparison(inputs: Sequence[str | Path], output: str | Path,
                     params: CompareParams = CompareParams(),
                     progress: ProgressCallback | None = None,
                     cancel: CancelToken | None = None,
                     pdf: Callable[[str], bytes] | None = None) -> dict:
    """Compare ``inputs[0]`` (A) with ``inputs[1]`` (B) - and, with ``params.mean``, make the
    mean track of all of them on A's window - and write the folder ``output``. Returns the
    record. Inputs, output and parameters are checked before any work; on any error nothing is
    written. ``pdf``: renders the report's HTML as PDF bytes (the window passes Qt's
    renderer), written as ``report.pdf`` in the same atomic folder."""
    from impress_gui.core.base.outdir import OutputFolder, check_output_dir, writing

    paths = [Path(p) for p in inputs]
    if len(paths) < 2:
        raise InputError("give two inputs: A and B", code=codes.E_COMPARE_OPTION)
    if len(paths) > 2 and not params.mean:
        raise InputError("more than two inputs make a mean track: add --mean",
                         code=codes.E_COMPARE_OPTION)
    if params.registration.pairs is not None and len(paths) > 2:
        raise InputError("point pairs register B onto A: give them with two inputs only",
                         code=codes.E_COMPARE_OPTION)
    params.check()
    for p in paths:
        if not p.exists():
            raise InputError(f"{p}: no such reconstruction folder or file",
                             code=codes.E_COMPARE_INPUT)
    check_output_dir(output, KIND, paths, FILES)
    n = len(paths)
    report(progress, 0.0, f"reading {paths[0]}")
    surfaces = []
    for k, p in enumerate(paths):
        if cancel is not None:
            cancel.check()
        report(progress, 0.1 * k / n, f"reading {p}")
        surfaces.append(load_surface(p, params.ply_pixel_mm))
    a, b = surfaces[0], surfaces[1]
    cmp = compare(a, b, params, sub_progress(progress, 0.1, 0.6 if params.mean else 0.85),
                  cancel)
    more: list[tuple[Surface, Registration]] = []
    mean = None
    if params.mean:
        for k, s in enumerate(surfaces[2:]):
            part = sub_progress(progress, 0.6 + 0.2 * k / max(1, n - 2),
                                0.6 + 0.2 * (k + 1) / max(1, n - 2))
            more.append((s, register(a, s, params.registration, part, cancel)))
        mean = mean_track(cmp.a, [(b, cmp.registration.matrix)]
                          + [(s, r.matrix) for s, r in more],
                          sub_progress(progress, 0.8, 0.85), cancel)
    report(progress, 0.85, "figures and report")
    p_mm = cmp.a.pixel_mm
    what = METRIC_SHORT[params.metric]
    colour_mm = colour_range(cmp.stats, params.threshold_mm)
    src = _inputs_line(surfaces)

    def png(data: bytes, what_png: str) -> bytes:
        from impress_gui.core.formats.provenance import png_with_text

        return png_with_text(data, {"Software": f"IMPREsS workstation {__version__}",
                                    "Description": f"IMPREsS comparison: {what_png}{src}"})

    payload: dict[str, bytes] = {
        "difference.tif": _tif(cmp.diff, p_mm, f"A - B (mm), {what}, NaN outside the "
                               "overlap; grid in compare.json", src),
        "a.tif": _tif(cmp.a.height_mm.astype(np.float32), p_mm, "A (mm), its compared window",
                      src),
        "b_on_a.tif": _tif(cmp.b_on_a, p_mm, "B moved onto A and resampled on A's grid (mm)",
                           src),
        "difference.png": png(difference_png(cmp, colour_mm,
                                             f"A - B {what}, mm (+-{colour_mm:g}); green: "
                                             f"|A - B| > {params.threshold_mm:g} mm",
                                             SCALE_LABEL[params.metric]),
                              f"A - B {what} (mm)"),
        "histogram.png": png(histogram_png(cmp.stats, params.threshold_mm,
                                           f"A - B {what}"), f"histogram of A - B {what}"),
    }
    if mean is not None:
        payload["mean.tif"] = _tif(mean.mean_mm, p_mm, "mean track (mm)", src)
        payload["std.tif"] = _tif(mean.std_mm, p_mm, "standard deviation per cell (mm)", src)
        payload["count.tif"] = _tif(mean.count, p_mm, "maps with data per cell", src)
    files = {name: hashlib.sha256(data).hexdigest() for name, data in payload.items()}
    doc = record_document(cmp, b, params, colour_mm, mean, more)
    doc["files"] = dict(sorted(files.items()))
    ha = cmp.a.height_mm
    fin = ha[np.isfinite(ha)]
    vr = (float(np.percentile(fin, 1)), float(np.percentile(fin, 99))) if fin.size else (0, 1)
    images = [(f"Difference A - B {what} (mm)", payload["difference.png"]),
              (f"Histogram of A - B {what}", payload["histogram.png"]),
              ("A (grey: height)", map_png(ha, cmp.a, vr)),
              ("B moved onto A (grey: height, same scale)", map_png(cmp.b_on_a, cmp.a, vr))]
    if cancel is not None:
        cancel.check()
    payload[RECORD_FILE] = _json_bytes(doc)
    payload["report.html"] = report_html(doc, files, images).encode("utf-8")
    if pdf is not None:
        payload["report.pdf"] = pdf(payload["report.html"].decode("utf-8"))
    with OutputFolder(output, KIND, inputs=paths, allowed=FILES) as folder:
        for name in sorted(payload):
            with writing(folder.path(name)):
                folder.path(name).write_bytes(payload[name])
        folder.commit()
    report(progress, 1.0, "written")
    return doc


def read_record(path: str | Path) -> dict:
    """A comparison record (``impress.compare`` v1), checked."""
    from impress_gui.core.base.fileio import read_json

    return read_json(path, COMPARE_FORMAT, (COMPARE_VERSION,))


def load_pairs(path: str | Path) -> tuple:
    """Point pairs from a JSON file: ``{"pairs": [{"a": [x, y], "b": [x, y]}, ...]}`` (or the
    list alone), export-frame mm."""
    from impress_gui.core.base.fileio import read_regular

    p = Path(path)
    try:
        doc = json.loads(read_regular(p, "point pairs", 1 << 20).decode("utf-8"))
    except Exception:  # noqa: BLE001 - any unreadable file is the same user error
        raise InputError(f"{p}: not a readable JSON file of point pairs",
                         code=codes.E_COMPARE_PAIRS) from None
    items = doc.get("pairs") if isinstance(doc, dict) else doc
    out = []
    try:
        for it in list(items or []):
            if len(it["a"]) != 2 or len(it["b"]) != 2:
                raise ValueError
            a = (float(it["a"][0]), float(it["a"][1]))
            b = (float(it["b"][0]), float(it["b"][1]))
            if not all(math.isfinite(v) and abs(v) <= 1e6 for v in (*a, *b)):
                raise ValueError
            out.append((a, b))
    except (TypeError, KeyError, IndexError, ValueError):
        raise InputError(f"{p}: each pair must be {{\"a\": [x, y], \"b\": [x, y]}} with finite "
                         "numbers (mm, within 1 km)", code=codes.E_COMPARE_PAIRS) from None
    if len(out) < 3:
        raise InputError(f"{p}: {len(out)} point pair(s); at least 3 are needed",
                         code=codes.E_COMPARE_PAIRS)
    return tuple(out)
