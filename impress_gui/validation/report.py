"""The validation table (text) and report (one self-contained HTML file with inline PNG
figures) from a validation record (:mod:`impress_gui.validation.run`). Qt-free."""

from __future__ import annotations

import base64
import functools
import html
import json
import math
from pathlib import Path

import numpy as np
from markupsafe import Markup

from impress_gui.core.base.fileio import atomic_write_bytes
from impress_gui.core.formats.images import png_bytes
from impress_gui.core.formats.recon_files import HEIGHTMAP_FILE, METADATA_FILE, X3P_FILE
from impress_gui.validation import protocol as V

REPORT_FILE = "validation_report.html"
TABLE_FILE = "validation_table.txt"


def _f(v, nd: int = 3) -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.{nd}f}"


def table_rows(record: dict) -> list[dict]:
    """Rows of the thesis-layout table: ours and, where the thesis has the row, its figures."""
    rows = []
    for group, s in record.get("summary", {}).items():
        thesis = V.THESIS_TABLE.get(group)
        rows.append(
            {"group": group, "xy": s["xy"], "z": s["z"], "thesis": list(thesis) if thesis else None}
        )
    return rows


def format_table(record: dict) -> str:
    """The table in the thesis' layout with its figures beside ours, then the acceptance
    verdict and the plane and sphere quantities."""
    w = max([len(r["group"]) for r in table_rows(record)] + [20])
    head = (
        f"{'':{w}}  {'--------------- this software ---------------':45}  "
        f"{'----- thesis table 4.1 -----':28}\n"
        f"{'Absolute errors (mm)':{w}}  {'xy ME':>7}{'xy SD':>7}{'z ME':>7}{'z SD':>7}"
        f"{'n xy/z':>9}{'fail':>6}   {'xy ME':>6}{'xy SD':>6}{'z ME':>6}{'z SD':>6}\n"
    )
    lines = [head.rstrip("\n")]
    for r in table_rows(record):
        xy, z, th = r["xy"], r["z"], r["thesis"]
        fails = xy["failed"] + z["failed"]
        thesis = "".join(f"{v:6.2f}" for v in th) if th else ""
        if r["group"] == "Overall" and th:
            thesis += f"  ({V.THESIS_READINGS} readings)"
        if r["group"] == "Overall":
            lines.append("-" * (w + 84))
        lines.append(
            f"{r['group']:{w}}  {_f(xy['mean_abs_mm']):>7}{_f(xy['sd_mm']):>7}"
            f"{_f(z['mean_abs_mm']):>7}{_f(z['sd_mm']):>7}"
            f"{xy['n']:>5}/{z['n']:<3}{fails:>6}   {thesis}"
        )
    acc = record.get("acceptance", {})
    if acc:
        lines.append("")
        lines.append(
            f"Acceptance (5x better than the thesis): xy mean {_f(acc.get('xy_mean_mm'))} mm "
            f"<= {V.BAR_XY_MM} mm: {'PASS' if acc.get('xy_ok') else 'FAIL'}; z mean "
            f"{_f(acc.get('z_mean_mm'))} mm <= {V.BAR_Z_MM} mm: "
            f"{'PASS' if acc.get('z_ok') else 'FAIL'}"
            + ("" if acc.get("all_placements") else "  (not all six placements were run)")
        )
    cov = record.get("uncertainty_coverage") or {}
    if cov:
        parts = [
            f"{k.replace('_', ' ')} {c['covered']}/{c['n']} ({100 * c['share']:.1f} %)"
            for k, c in cov.items() if c.get("share") is not None
        ]
        if parts:
            lines.append(
                "Stated uncertainty (U, about 95 %) covers the true error: " + ", ".join(parts)
                + " (about 95 % expected)"
            )
        no_u = (cov.get("all") or {}).get("no_U")
        if no_u:
            lines.append(
                f"No uncertainty stated for {no_u} reading(s): the calibration is unstable "
                "(its Monte Carlo failed in most trials); they are not counted above"
            )
    if "flat" in record:
        f = record["flat"]
        lines.append(
            f"Plane (VDI/VDE 2634-2 flatness): F = {_f(f['flatness_mm'])} mm (0.3 % trimmed; "
            f"untrimmed range {_f(f['range_mm'])} mm), RMS {_f(f['rms_mm'])} mm, height offset "
            f"{_f(f['offset_mm'])} mm, tilt {_f(f['tilt_deg'], 4)} deg, over "
            f"{f['x_mm'][1] - f['x_mm'][0]:.0f} x {f['y_mm'][1] - f['y_mm'][0]:.0f} mm "
            f"({f['n']} cells)"
        )
    if "spheres" in record:
        s = record["spheres"]
        d, sp = s["diameter"], s["spacing"]
        lines.append(
            f"Spheres (VDI/VDE 2634-2): {d['n']} spheres, diameter error (PS) mean "
            f"{_f(d['mean_abs_mm'])} max {_f(d['max_abs_mm'])} mm; form (PF) max "
            f"{_f(s['form_max_mm'])} mm; centre-distance error (SD) over {sp['n']} pairs mean "
            f"{_f(sp['mean_abs_mm'])} max {_f(sp['max_abs_mm'])} mm"
        )
    return "\n".join(lines) + "\n"


# ----- figures -------------------------------------------------------------------------------
def _png_data_uri(rgb: np.ndarray) -> str:
    return "data:image/png;base64," + base64.b64encode(png_bytes(rgb)).decode("ascii")


def _text(img, s, org, scale=0.45, colour=(0, 0, 0), thick=1):
    import cv2

    cv2.putText(img, s, org, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, thick, cv2.LINE_AA)


def bar_chart(record: dict) -> np.ndarray:
    """Mean absolute error (bar) +- SD (whisker) per placement, xy and z, ours beside the
    thesis', on one linear scale in mm."""
    import cv2

    rows = table_rows(record)
    w_row, left, top, h_plot = 150, 60, 40, 300
    width = max(520, left + w_row * len(rows) + 20)
    img = np.full((top + h_plot + 90, width, 3), 255, np.uint8)
    vmax = 2.2
    for r in rows:
        for m_i, s_i in ((0, 1), (2, 3)):
            if r["thesis"]:
                vmax = max(vmax, r["thesis"][m_i] + r["thesis"][s_i])

    def y_of(v):
        return int(top + h_plot - h_plot * min(v, vmax) / vmax)

    for k in range(0, int(vmax * 2) + 1):
        v = k / 2
        y = y_of(v)
        cv2.line(img, (left, y), (width - 10, y), (225, 225, 225), 1)
        _text(img, f"{v:.1f}", (8, y + 4))
    _text(img, "mean |error| (mm), whisker = SD; dashed: the acceptance bars", (left, 22))
    for bar, colour in ((V.BAR_XY_MM, (31, 119, 180)), (V.BAR_Z_MM, (214, 39, 40))):
        y = y_of(bar)
        for x in range(left, width - 10, 12):
            cv2.line(img, (x, y), (min(x + 6, width - 10), y), colour, 1)
    colours = {
        ("xy", "ours"): (31, 119, 180),
        ("z", "ours"): (214, 39, 40),
        ("xy", "thesis"): (158, 202, 225),
        ("z", "thesis"): (252, 174, 145),
    }
    for i, r in enumerate(rows):
        x0 = left + i * w_row + 10
        bars = [
            ("xy", "ours", r["xy"]["mean_abs_mm"], r["xy"]["sd_mm"]),
            ("xy", "thesis", *(r["thesis"][0:2] if r["thesis"] else (None, None))),
            ("z", "ours", r["z"]["mean_abs_mm"], r["z"]["sd_mm"]),
            ("z", "thesis", *(r["thesis"][2:4] if r["thesis"] else (None, None))),
        ]
        for j, (ax, who, mean, sd) in enumerate(bars):
            if mean is None:
                continue
            xa = x0 + j * 30
            cv2.rectangle(img, (xa, y_of(mean)), (xa + 24, y_of(0)), colours[(ax, who)], -1)
            if sd:
                xc = xa + 12
                cv2.line(img, (xc, y_of(mean)), (xc, y_of(mean + sd)), (60, 60, 60), 1)
                cv2.line(img, (xc - 5, y_of(mean + sd)), (xc + 5, y_of(mean + sd)), (60, 60, 60), 1)
        label = r["group"].replace("Order ", "").replace("each ", "").replace(" degrees", "")
        for k, part in enumerate(_wrap(label, 20)):
            _text(img, part, (x0, top + h_plot + 18 + 15 * k), 0.38)
    lx = left
    for (ax, who), c in colours.items():
        cv2.rectangle(img, (lx, top + h_plot + 66), (lx + 14, top + h_plot + 80), c, -1)
        _text(img, f"{ax} {who}", (lx + 18, top + h_plot + 78), 0.4)
        lx += 110
    return img


def _wrap(s: str, n: int) -> list[str]:
    out, cur = [], ""
    for word in s.split():
        if cur and len(cur) + 1 + len(word) > n:
            out.append(cur)
            cur = word
        else:
            cur = f"{cur} {word}".strip()
    return [*out, cur] if cur else out


def scan_figure(folder: Path, readings: list[dict], max_px: int = 560) -> np.ndarray | None:
    """The reconstruction around the readings, pseudo-coloured, with each profile line drawn
    (green: within the bar, red: above it or failed)."""
    import cv2

    from impress_gui.core.formats.writers import pseudo_colour
    from impress_gui.core.measure.readings import load_reconstruction

    try:
        rec = load_reconstruction(folder, layers=("fused",))
    except Exception:  # noqa: BLE001 - a figure is optional: the report says it is missing
        return None
    pts = np.array([p for r in readings for p in (r["start_mm"], r["end_mm"])], float)
    if not len(pts):
        return None
    lo, hi = pts.min(0) - 25.0, pts.max(0) + 25.0
    sub, sspec = V.crop(rec.height_mm, rec.spec, (lo[0], hi[0]), (lo[1], hi[1]))
    scale = min(1.0, max_px / max(sub.shape))
    img = pseudo_colour(np.asarray(sub), bar=False)
    img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)

    def px(p):
        return (
            int(round((p[0] - sspec.x0_mm) / sspec.pixel_mm * scale)),
            int(round((p[1] - sspec.y0_mm) / sspec.pixel_mm * scale)),
        )

    def ok(r) -> bool:
        bar = V.BAR_XY_MM if r["axis"] == "xy" else V.BAR_Z_MM
        return r["error_mm"] is not None and abs(r["error_mm"]) <= bar

    for r in sorted(readings, key=ok, reverse=True):  # the ones above the bar drawn last
        colour = (0, 160, 0) if ok(r) else (220, 0, 0)
        cv2.line(img, px(r["start_mm"]), px(r["end_mm"]), colour, 1)
    return img


# ----- the report ----------------------------------------------------------------------------
# One self-contained HTML document (figures inline); every value is escaped (autoescape on).
REPORT_TEMPLATE = """\
{% macro cell(v, nd=3) %}<td>{{ v|f(nd) }}</td>{% endmacro %}
{% macro verdict(ok) %}{% if ok %}<span class='pass'>PASS</span>{% else %}<span class='fail'>FAIL</span>{% endif %}{% endmacro %}
<!DOCTYPE html><html><head><meta charset='utf-8'><title>{{ title }}</title><style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:3px 7px;
text-align:right;font-size:13px}th{background:#eee}td.l,th.l{text-align:left}
.pass{color:#080;font-weight:bold}.fail{color:#b00;font-weight:bold}code{font-size:12px}
img{border:1px solid #ccc;margin:4px}</style></head><body><h1>{{ title }}</h1>
<table>{% for key, value in about %}<tr><th class='l'>{{ key }}</th><td class='l'>{{ value }}</td></tr>{% endfor %}</table>
{% if record.get("config") %}
<h2>Parameters</h2><pre>{{ record["config"]|dumps(indent=1) }}</pre>
{% endif %}
<h2>Absolute errors in the thesis' layout (table 4.1)</h2><table><tr><th class='l' rowspan=2>Placement</th><th colspan=6>this software</th><th colspan=4>thesis (208 readings)</th></tr><tr><th>xy ME</th><th>xy SD</th><th>z ME</th><th>z SD</th><th>n xy/z</th><th>failed</th><th>xy ME</th><th>xy SD</th><th>z ME</th><th>z SD</th></tr>
{% for r in rows %}
{% set xy, z = r["xy"], r["z"] %}
<tr><td class='l'>{{ r["group"] }}</td>{{ cell(xy["mean_abs_mm"]) }}{{ cell(xy["sd_mm"]) }}{{ cell(z["mean_abs_mm"]) }}{{ cell(z["sd_mm"]) }}<td>{{ xy["n"] }}/{{ z["n"] }}</td><td>{{ xy["failed"] + z["failed"] }}</td>{% if r["thesis"] %}{% for v in r["thesis"] %}{{ cell(v, 2) }}{% endfor %}{% else %}<td colspan=4></td>{% endif %}</tr>
{% endfor %}
</table>
{% if acc %}
<p>Acceptance (five times better than the thesis' overall means): xy mean {{ acc.get("xy_mean_mm")|f }} mm &le; {{ bar_xy_mm }} mm {{ verdict(acc.get("xy_ok")) }}; z mean {{ acc.get("z_mean_mm")|f }} mm &le; {{ bar_z_mm }} mm {{ verdict(acc.get("z_ok")) }}.{% if not acc.get("all_placements") %} <b>Not all six placements were run.</b>{% endif %}</p>
{% endif %}
<p>Protocol: per target four dimensions (widths in xy, heights in z) measured with the product's profile tools (a 2 mm wide profile across the target at three stations, after levelling on the plate around it) and compared with the known dimensions. Slotted target A: widths and depths of its two widest slots; stepped target B: widths of treads 2 and 3, rise of the first step and of the whole stair. The thesis' own four measurements are in its missing figure 4.6b/c.</p>
{% if chart %}
<img alt='errors per placement' src='{{ chart }}'>
{% endif %}
<pre>{{ table }}</pre>
{% if "flat" in record or "spheres" in record %}
<h2>VDI/VDE 2634-2 style quantities</h2>
{% if "flat" in record %}
<pre>{{ record["flat"]|dumps(indent=1) }}</pre>
{% endif %}
{% if "spheres" in record %}
<table><tr><th>#</th><th>nominal centre (mm)</th><th>diameter</th><th>error</th><th>form</th><th>n</th></tr>
{% for row in record["spheres"]["spheres"] %}
{% if "error" in row %}
<tr><td>{{ loop.index0 }}</td><td class='l' colspan=5>{{ row["error"] }}</td></tr>
{% else %}
<tr><td>{{ loop.index0 }}</td><td>{{ row["nominal_centre_mm"]|join_fixed(1) }}</td>{{ cell(row["diameter_mm"]) }}{{ cell(row["diameter_error_mm"]) }}{{ cell(row["form_mm"]) }}<td>{{ row["n"] }}</td></tr>
{% endif %}
{% endfor %}
</table>
{% endif %}
{% endif %}
<h2>Inputs and outputs (SHA-256)</h2><table><tr><th class='l'>scan</th><th class='l'>file</th><th class='l'>SHA-256</th></tr>
{% for scan, name, sha in files %}
<tr><td class='l'>{{ scan }}</td><td class='l'>{{ name }}</td><td class='l'><code>{{ sha }}</code></td></tr>
{% endfor %}
</table>
{% if record.get("spec") %}
<p>Spec file {{ record["spec"]["path"] }}, SHA-256 <code>{{ record["spec"]["sha256"] }}</code></p>
{% endif %}
{% if scan_figures is not none %}
<h2>Where the readings were taken</h2>
{% for scan, uri in scan_figures %}
<figure style='display:inline-block'><img alt='{{ scan }}' src='{{ uri }}'><figcaption>{{ scan }}</figcaption></figure>
{% endfor %}
{% endif %}
<h2>Every reading</h2><table><tr><th class='l'>reading</th><th>axis</th><th>nominal</th><th>measured</th><th>error</th><th class='l'>note</th></tr>
{% for r in record.get("readings", []) %}
<tr><td class='l'>{{ r["id"] }}</td><td>{{ r["axis"] }}</td>{{ cell(r["nominal_mm"]) }}{{ cell(r["measured_mm"]) }}{{ cell(r["error_mm"]) }}<td class='l'>{{ r["note"] }}</td></tr>
{% endfor %}
</table>
{% if parameters %}
<h3>Processing parameters: {{ parameters[0] }}</h3><pre>{{ parameters[1]|dumps }}</pre>
{% endif %}
</body></html>
"""


def _escaped(value) -> Markup:
    """A value as the standard library's :func:`html.escape` writes it (``&quot;``,
    ``&#x27;``: the entities of the reports written before the template)."""
    return value if isinstance(value, Markup) else Markup(html.escape(str(value)))


@functools.cache
def _template():
    import jinja2

    env = jinja2.Environment(autoescape=True, finalize=_escaped, trim_blocks=True,
                             lstrip_blocks=True, keep_trailing_newline=True,
                             undefined=jinja2.StrictUndefined)
    env.filters["f"] = _f
    env.filters["dumps"] = json.dumps
    env.filters["join_fixed"] = lambda values, nd: ", ".join(f"{v:.{nd}f}" for v in values)
    return env.from_string(REPORT_TEMPLATE)


def _file_rows(scans: list[dict]) -> list[tuple[str, str, object]]:
    """(scan, file, SHA-256) of every scan's inputs, main outputs and simulator code."""
    out = []
    for s in scans:
        files = {
            f"input {k}": v.get("sha256")
            for k, v in s.get("inputs", {}).items()
            if isinstance(v, dict)
        }
        files |= {
            f"output {k}": v
            for k, v in s.get("reconstruction", {}).get("files", {}).items()
            if k in (HEIGHTMAP_FILE, METADATA_FILE, X3P_FILE)
        }
        if s.get("simulator_sha256"):
            files["simulator code (at rendering)"] = s["simulator_sha256"]
        out += [(s["title"], k, v) for k, v in files.items()]
    return out


def _scan_figures(record: dict) -> list[tuple[str, str]]:
    """(scan, PNG data URI) of where each scan's readings were taken."""
    out = []
    for s in record.get("scans", []):
        rs = [r for r in record.get("readings", []) if r["group"] == s["title"]]
        path = s.get("reconstruction", {}).get("path")
        img = scan_figure(Path(path), rs) if rs and path else None
        if img is not None:
            out.append((s["title"], _png_data_uri(img)))
    return out


def report_html(record: dict, figures: bool = True) -> str:
    title = (
        "IMPREsS method validation - simulator"
        if record.get("kind") == "simulator"
        else f"IMPREsS method validation - {record.get('name', 'real scans')}"
    )
    about = [("Software", record.get("software")), ("Date (UTC)", record.get("date_utc")),
             ("Host", record.get("host")), ("Python", record.get("python")),
             ("Kind", record.get("kind"))]
    chart = _png_data_uri(bar_chart(record)) if figures and record.get("summary") else None
    parameters = next(((s["title"], s["parameters"]) for s in record.get("scans", [])
                       if s.get("parameters")), None)
    return _template().render(
        record=record, title=title, about=about, rows=table_rows(record),
        acc=record.get("acceptance", {}), bar_xy_mm=V.BAR_XY_MM, bar_z_mm=V.BAR_Z_MM,
        chart=chart, table=format_table(record), files=_file_rows(record.get("scans", [])),
        scan_figures=_scan_figures(record) if figures else None, parameters=parameters)


def write_report(record: dict, out_dir: str | Path, figures: bool = True) -> dict[str, Path]:
    """Write the table (text) and the HTML report into ``out_dir`` atomically."""
    out = Path(out_dir)
    paths = {"table": out / TABLE_FILE, "report": out / REPORT_FILE}
    atomic_write_bytes(paths["table"], format_table(record).encode("utf-8"))
    atomic_write_bytes(paths["report"], report_html(record, figures).encode("utf-8"))
    return paths
