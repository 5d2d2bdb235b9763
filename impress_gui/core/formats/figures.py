"""Figures and the case report of the viewer (no Qt here: numpy, OpenCV and text only).

- :func:`colourise` - heights to RGB through a 256-entry colour table (NaN = no data, black);
- :func:`figure` - a map as seen from above (as ``texture.png``: row 0 at the top) with title,
  axes in mm, measurement overlay, scale bar, the rail's direction and a colour bar in mm;
- :func:`profile_figure` - a depth profile (distance along the ruler vs height, in mm) with
  title, case lines, ticked and labelled axes and the reference bands;
- :func:`report_html` - one self-contained HTML file (images embedded) with the case data,
  every measurement, the calibration's quality figures, the software version and input hashes.
"""

from __future__ import annotations

import base64
import functools
import math
from collections.abc import Mapping, Sequence

import numpy as np

from impress_gui import __version__
from impress_gui.core.formats import images
from impress_gui.core.formats.provenance import png_provenance_text, png_with_text
from impress_gui.core.reconstruction.grid import GridSpec

NO_DATA_RGB = (0, 0, 0)
MAX_FIGURE_PX = 6000


def colourise(height: np.ndarray, lut: np.ndarray, vrange: tuple[float, float]) -> np.ndarray:
    lo, hi = vrange
    span = hi - lo if hi > lo else 1.0
    t = (np.nan_to_num(height, nan=lo) - lo) * (255.0 / span)
    idx = np.clip(t, 0, 255).astype(np.uint8)
    rgb = np.asarray(lut, np.uint8)[:, :3][idx]
    rgb[~np.isfinite(height)] = NO_DATA_RGB
    return rgb


def nice_length(target_mm: float) -> float:
    """1, 2 or 5 times a power of ten, at most ``target_mm``."""
    if target_mm <= 0:
        return 1.0
    p = 10 ** math.floor(math.log10(target_mm))
    for m in (5, 2, 1):
        if m * p <= target_mm:
            return m * p
    return p


def _text(img, s, org, scale, colour=(0, 0, 0), thick=1) -> None:
    import cv2

    cv2.putText(img, s, org, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, thick, cv2.LINE_AA)


def _ticks(lo_mm: float, hi_mm: float, n: int = 6) -> list[float]:
    """Round tick values (1, 2 or 5 times a power of ten apart) inside ``[lo_mm, hi_mm]``."""
    step = nice_length((hi_mm - lo_mm) / max(1, n))
    if step <= 0:
        return []
    first = math.ceil(lo_mm / step - 1e-9)
    last = math.floor(hi_mm / step + 1e-9)
    return [round(k * step, 9) for k in range(first, last + 1)]


def _tick_text(v: float) -> str:
    return f"{v:g}" if abs(v) >= 1e-9 else "0"


def figure(
    spec: GridSpec,
    *,
    height: np.ndarray | None = None,
    lut: np.ndarray | None = None,
    vrange: tuple[float, float] | None = None,
    rgb: np.ndarray | None = None,
    title: str = "",
    measurements: Sequence[Mapping] = (),
    max_px: int = MAX_FIGURE_PX,
    unit_label: str = "height (mm)",
    legend: Sequence[tuple[Sequence[int], str]] = (),
    legend_title: str = "",
) -> np.ndarray:
    """An RGB figure of the whole map with axes in mm, scale bar, the rail's direction and,
    for heights, a colour bar (for an RGB map, ``legend``: ``(colour, meaning)`` pairs under
    ``legend_title``). The title spans the whole figure, wrapped over lines when long.

    The map is drawn as the camera sees the ground from above, as ``texture.png`` is stored
    and as the viewer shows it: grid row 0 at the top, y (the carriage's motion, +Y)
    increasing downwards, x to the right. The axes' labels are the rail-frame coordinates of
    the cells' edges; an arrow marks the rail's direction of motion."""
    import cv2

    if rgb is None:
        if height is None or lut is None or vrange is None:
            raise ValueError("give either rgb, or height with lut and vrange")
        rgb = colourise(height, lut, vrange)
    img = np.ascontiguousarray(rgb)  # row 0 (smallest y) at the top, as texture.png
    h, w = img.shape[:2]
    f = max(1.0, max(h, w) / max_px)
    if f > 1.0:
        img = cv2.resize(
            img, (max(1, int(w / f)), max(1, int(h / f))), interpolation=cv2.INTER_AREA
        )
    else:
        img = img.copy()
    h, w = img.shape[:2]
    mm_per_px = spec.pixel_mm * f
    scale = max(0.45, min(w, h) / 900)
    thick = max(1, int(round(scale * 1.6)))
    left_mm, top_mm = spec.x0_mm - spec.pixel_mm / 2, spec.y0_mm - spec.pixel_mm / 2

    def to_px(x_mm: float, y_mm: float) -> tuple[int, int]:
        j = (x_mm - left_mm) / mm_per_px
        i = (y_mm - top_mm) / mm_per_px
        return int(round(j)), int(round(i))

    for k, m in enumerate(measurements, 1):
        pts = [to_px(p[0], p[1]) for p in m.get("points_mm", [])]
        if not pts:
            continue
        for a, b in zip(pts, pts[1:]):
            cv2.line(img, a, b, (255, 255, 255), thick + 2, cv2.LINE_AA)
            cv2.line(img, a, b, (255, 60, 220), thick, cv2.LINE_AA)
        cv2.circle(img, pts[0], 3 * thick + 2, (255, 60, 220), -1, cv2.LINE_AA)
        _text(
            img,
            str(k),
            (pts[0][0] + 4 * thick, pts[0][1] - 4 * thick),
            scale,
            (255, 255, 255),
            thick + 1,
        )
    # axes in mm: y ticks on a left panel, x ticks on a row under the map
    font = cv2.FONT_HERSHEY_SIMPLEX
    tick_scale = scale * 0.8
    tick_len = max(4, int(8 * scale))
    text_h = cv2.getTextSize("0", font, tick_scale, thick)[0][1]
    widest = max(
        cv2.getTextSize(_tick_text(v), font, tick_scale, thick)[0][0]
        for v in (left_mm, left_mm + w * mm_per_px)
    )
    y_ticks = _ticks(top_mm, top_mm + h * mm_per_px, max(2, min(8, h // (5 * text_h))))
    x_ticks = _ticks(left_mm, left_mm + w * mm_per_px, max(2, min(8, w // (2 * widest + 8))))
    text_w = max(
        [cv2.getTextSize(_tick_text(v), font, tick_scale, thick)[0][0] for v in y_ticks] + [1]
    )
    # the y axis' title, written along the axis (read from the bottom up, as usual)
    y_title = "y (mm), down: rail motion"
    (tw_y, th_y), base_y = cv2.getTextSize(y_title, font, tick_scale, thick)
    title_img = np.full((th_y + base_y + 4, tw_y + 4, 3), 255, np.uint8)
    _text(title_img, y_title, (2, th_y + 2), tick_scale, thick=thick)
    title_img = np.rot90(title_img)  # counter-clockwise: bottom-up
    tw = title_img.shape[1] + int(6 * scale)
    left = np.full((h, tw + text_w + tick_len + int(12 * scale), 3), 255, np.uint8)
    lw = left.shape[1]
    if title_img.shape[0] <= h:
        r0 = (h - title_img.shape[0]) // 2
        left[r0 : r0 + title_img.shape[0], 2 : 2 + title_img.shape[1]] = title_img
    for v in y_ticks:
        i = int(round((v - top_mm) / mm_per_px))
        left[max(0, i - thick // 2) : i + thick // 2 + 1, lw - tick_len :] = 0
        tw = cv2.getTextSize(_tick_text(v), font, tick_scale, thick)[0][0]
        y_text = min(h - 2, max(text_h + 2, i + text_h // 2))
        _text(left, _tick_text(v), (lw - tick_len - 4 - tw, y_text), tick_scale, thick=thick)
    axis_row = np.full((text_h * 3 + tick_len + int(20 * scale), lw + w, 3), 255, np.uint8)
    for v in x_ticks:
        j = lw + int(round((v - left_mm) / mm_per_px))
        axis_row[:tick_len, max(lw, j - thick // 2) : j + thick // 2 + 1] = 0
        tw = cv2.getTextSize(_tick_text(v), font, tick_scale, thick)[0][0]
        x_text = min(lw + w - tw - 2, max(lw, j - tw // 2))
        _text(axis_row, _tick_text(v), (x_text, tick_len + text_h + 4), tick_scale, thick=thick)
    tw_x = cv2.getTextSize("x (mm)", font, tick_scale, thick)[0][0]
    _text(
        axis_row,
        "x (mm)",
        (lw + max(0, (w - tw_x) // 2), tick_len + 2 * text_h + int(14 * scale)),
        tick_scale,
        thick=thick,
    )
    middle = np.concatenate([left, img], axis=1)
    w_all = middle.shape[1]
    # bottom strip: scale bar and the rail's direction; right: colour bar or legend
    strip = int(60 * scale) + 10
    bar_mm = nice_length(0.25 * w * mm_per_px)
    bar_px = max(1, int(round(bar_mm / mm_per_px)))
    bar_text = f"{bar_mm:g} mm"
    rail_text = "rail motion (+y)"
    bar_end = lw + int(25 * scale) + bar_px + cv2.getTextSize(bar_text, font, scale, thick)[0][0]
    rail_w = int(22 * scale) + cv2.getTextSize(rail_text, font, scale * 0.8, thick)[0][0]
    one_line = bar_end + int(30 * scale) + rail_w <= w_all
    bottom = np.full((strip if one_line else 2 * strip, w_all, 3), 255, np.uint8)
    x0, y0 = lw + int(15 * scale), strip // 2
    cv2.rectangle(
        bottom, (x0, y0 - int(5 * scale)), (x0 + bar_px, y0 + int(5 * scale)), (0, 0, 0), -1
    )
    _text(
        bottom, bar_text, (x0 + bar_px + int(10 * scale), y0 + int(8 * scale)), scale, thick=thick
    )
    ax, ay = (bar_end + int(30 * scale), 0) if one_line else (x0, strip)
    cv2.arrowedLine(
        bottom,
        (ax, ay + int(6 * scale)),
        (ax, ay + strip - int(6 * scale)),
        (0, 0, 0),
        thick + 1,
        cv2.LINE_AA,
        tipLength=0.3,
    )
    _text(
        bottom,
        rail_text,
        (ax + int(12 * scale), ay + y0 + int(8 * scale)),
        scale * 0.8,
        thick=thick,
    )
    body = np.concatenate([middle, axis_row, bottom], axis=0)
    below = axis_row.shape[0] + bottom.shape[0]
    # the colour bar's label (or the legend's heading) has a row of its own above the map,
    # under the title: it never meets the title nor the bar
    head_h = text_h * 3 + int(24 * scale)
    body = np.concatenate([np.full((head_h, w_all, 3), 255, np.uint8), body], axis=0)
    if height is not None and lut is not None and vrange is not None:
        body = np.concatenate(
            [
                body,
                _colour_bar(body.shape[0], head_h, below, lut, vrange, scale, thick, unit_label),
            ],
            axis=1,
        )
    elif legend:
        body = np.concatenate(
            [body, _legend(body.shape[0], head_h, legend, legend_title, scale, thick)], axis=1
        )
    return np.concatenate([_title_rows(title, body.shape[1], scale, thick), body], axis=0)


def _wrap(text: str, width_px: int, scale: float, thick: int) -> list[str]:
    """``text`` in lines at most ``width_px`` wide (broken at spaces; a longer word alone)."""
    import cv2

    lines: list[str] = []
    for word in text.split():
        trial = f"{lines[-1]} {word}" if lines else word
        if (
            lines
            and cv2.getTextSize(trial, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)[0][0] <= width_px
        ):
            lines[-1] = trial
        else:
            lines.append(word)
    return lines or [""]


def _title_rows(title: str, width: int, scale: float, thick: int) -> np.ndarray:
    """The title over the whole figure's width, wrapped so that it is never cut off."""
    import cv2

    margin = int(10 * scale) + 2
    t_scale = scale * 1.1
    lines = _wrap(title[:400], width - 2 * margin, t_scale, thick)
    (_tw, th), base = cv2.getTextSize("Ag", cv2.FONT_HERSHEY_SIMPLEX, t_scale, thick)
    line_h = th + base + int(10 * scale)
    rows = np.full((line_h * len(lines) + int(16 * scale) + 4, width, 3), 255, np.uint8)
    for k, line in enumerate(lines):
        _text(rows, line, (margin, int(12 * scale) + th + k * line_h), t_scale, thick=thick)
    return rows


def _colour_bar(
    total_h: int, top: int, below: int, lut, vrange, scale: float, thick: int, unit_label: str
) -> np.ndarray:
    """The colour bar beside the map: ``top`` rows above it (where its label is written, clear
    of the bar), ``below`` rows under it."""
    import cv2

    font = cv2.FONT_HERSHEY_SIMPLEX
    bw = int(30 * scale) + 6
    lo, hi = vrange
    labels = [f"{lo + i / 5 * (hi - lo):.2f}" for i in range(6)]
    tick_w = max(cv2.getTextSize(t, font, scale * 0.9, thick)[0][0] for t in labels)
    label_w = cv2.getTextSize(unit_label, font, scale * 0.8, thick)[0][0]
    width = max(bw + int(12 * scale) + tick_w, label_w + 6) + int(14 * scale)
    panel = np.full((total_h, width, 3), 255, np.uint8)
    a, b = top, total_h - below - 5
    n = max(2, b - a)
    idx = np.linspace(255, 0, n).astype(np.uint8)
    panel[a : a + n, 6 : 6 + bw - 6] = np.asarray(lut, np.uint8)[:, :3][idx][:, None, :]
    for i, text in enumerate(labels):
        y = int(round(a + (1 - i / 5) * (n - 1)))
        panel[max(0, y - thick // 2) : y + thick // 2 + 1, bw : bw + int(8 * scale)] = 0
        _text(panel, text, (bw + int(12 * scale), y + int(6 * scale)), scale * 0.9, thick=thick)
    # above the top tick's label, with a gap
    tick_h = cv2.getTextSize("0", font, scale * 0.9, thick)[0][1]
    _text(panel, unit_label, (4, top - tick_h - int(10 * scale)), scale * 0.8, thick=thick)
    return panel


def _legend(
    total_h: int,
    top: int,
    entries: Sequence[tuple[Sequence[int], str]],
    heading: str,
    scale: float,
    thick: int,
) -> np.ndarray:
    """A legend beside the map: one colour swatch and its meaning a line, from the map's top."""
    import cv2

    font = cv2.FONT_HERSHEY_SIMPLEX
    sw = int(26 * scale) + 4
    th = cv2.getTextSize("Ag", font, scale * 0.8, thick)[0][1]
    widest = max(
        [cv2.getTextSize(t, font, scale * 0.8, thick)[0][0] for _c, t in entries]
        + [cv2.getTextSize(heading, font, scale * 0.8, thick)[0][0] - sw]
    )
    panel = np.full((total_h, sw + widest + int(30 * scale) + 8, 3), 255, np.uint8)
    _text(panel, heading, (6, top - int(12 * scale)), scale * 0.8, thick=thick)
    y = top
    for colour, text in entries:
        c = tuple(int(v) for v in colour[:3])
        cv2.rectangle(panel, (6, y), (6 + sw, y + sw), c, -1)
        cv2.rectangle(panel, (6, y), (6 + sw, y + sw), (90, 90, 90), 1)
        _text(panel, text, (6 + sw + int(10 * scale), y + (sw + th) // 2), scale * 0.8, thick=thick)
        y += sw + int(12 * scale)
    return panel


#: the reference bands' colours (RGB), as the viewer draws them
BAND_RGB = {"A": (60, 140, 255), "B": (255, 150, 30)}


def profile_figure(
    distance_mm: np.ndarray,
    height_mm: np.ndarray,
    *,
    title: str = "",
    lines: Sequence[str] = (),
    bands: Mapping[str, tuple[float, float]] | None = None,
    band_means: Mapping[str, float] | None = None,
    size: tuple[int, int] = (2000, 1000),
) -> np.ndarray:
    """An RGB figure of a depth profile: height (mm) against the distance along the ruler (mm),
    with ``title`` and the text ``lines`` (case, evidence, source...) above it, both axes
    ticked and labelled with their units, a light grid, and the reference ``bands`` (A, B:
    distances along the ruler) shaded with their means (``band_means``) when placed."""
    import cv2

    font = cv2.FONT_HERSHEY_SIMPLEX
    width, height = int(size[0]), int(size[1])
    scale = max(0.5, width / 2000)
    thick = max(1, int(round(scale * 1.6)))
    d = np.asarray(distance_mm, np.float64)
    z = np.asarray(height_mm, np.float64)
    ok = np.isfinite(d) & np.isfinite(z)
    head = [(title, scale * 1.1)] + [(t, scale * 0.75) for t in lines]
    wrapped = [(ln, sc) for t, sc in head for ln in _wrap(t, width - 40, sc, thick)]
    heights = [cv2.getTextSize("Ag", font, sc, thick) for _t, sc in wrapped]
    top = int(20 * scale) + sum(th + base + int(12 * scale) for (_w, th), base in heights)
    tick_scale = scale * 0.8
    th_tick = cv2.getTextSize("0", font, tick_scale, thick)[0][1]
    # the plot's ranges: the data's, padded; the distance from 0 to the ruler's end
    x_lo, x_hi = 0.0, float(d[ok].max()) if ok.any() else 1.0
    if ok.any():
        z_lo, z_hi = float(z[ok].min()), float(z[ok].max())
    else:
        z_lo, z_hi = -1.0, 1.0
    for m in (band_means or {}).values():
        if math.isfinite(m):
            z_lo, z_hi = min(z_lo, m), max(z_hi, m)
    pad = max(0.05 * (z_hi - z_lo), 0.05)
    z_lo, z_hi = z_lo - pad, z_hi + pad
    x_hi = x_hi if x_hi > x_lo else x_lo + 1.0
    y_ticks = _ticks(z_lo, z_hi, 6)
    x_ticks = _ticks(x_lo, x_hi, 10)
    y_w = max(
        [cv2.getTextSize(_tick_text(v), font, tick_scale, thick)[0][0] for v in y_ticks] + [1]
    )
    left = int(40 * scale) + th_tick + y_w + int(24 * scale)
    right = int(40 * scale)
    bottom = th_tick * 3 + int(50 * scale)
    plot_top = top + th_tick + int(24 * scale)  # the bands' labels above the frame
    img = np.full((height, width, 3), 255, np.uint8)
    pw, ph = width - left - right, height - plot_top - bottom
    if pw < 20 or ph < 20:
        raise ValueError("the profile figure is too small")

    def px(x: float, y: float) -> tuple[int, int]:
        return (
            int(round(left + (x - x_lo) / (x_hi - x_lo) * pw)),
            int(round(plot_top + (z_hi - y) / (z_hi - z_lo) * ph)),
        )

    y = int(16 * scale)
    for (t, sc), ((_w, th), base) in zip(wrapped, heights):
        y += th
        _text(img, t, (20, y), sc, thick=thick)
        y += base + int(12 * scale)
    for name, band in (bands or {}).items():
        colour = BAND_RGB.get(name, (150, 150, 150))
        lo, hi = sorted(band)
        (x0, _), (x1, _) = px(max(lo, x_lo), 0), px(min(hi, x_hi), 0)
        roi = img[plot_top : plot_top + ph, x0 : x1 + 1]
        roi[:] = (0.8 * roi + 0.2 * np.array(colour)).astype(np.uint8)
        for xb in (x0, x1):
            cv2.line(img, (xb, plot_top), (xb, plot_top + ph), colour, thick)
        mean = (band_means or {}).get(name)
        label = name if mean is None or not math.isfinite(mean) else f"{name}: {mean:.3f} mm"
        if mean is not None and math.isfinite(mean):
            ym = px(0, mean)[1]
            cv2.line(img, (x0, ym), (x1, ym), colour, thick + 1, cv2.LINE_AA)
        _text(img, label, (x0, plot_top - int(10 * scale)), tick_scale, colour, thick)
    grid = (225, 225, 225)
    for v in x_ticks:
        xp = px(v, 0)[0]
        cv2.line(img, (xp, plot_top), (xp, plot_top + ph), grid, 1)
        cv2.line(img, (xp, plot_top + ph), (xp, plot_top + ph + int(8 * scale)), (0, 0, 0), thick)
        tw = cv2.getTextSize(_tick_text(v), font, tick_scale, thick)[0][0]
        _text(
            img,
            _tick_text(v),
            (xp - tw // 2, plot_top + ph + int(14 * scale) + th_tick),
            tick_scale,
            thick=thick,
        )
    for v in y_ticks:
        yp = px(0, v)[1]
        cv2.line(img, (left, yp), (left + pw, yp), grid, 1)
        cv2.line(img, (left - int(8 * scale), yp), (left, yp), (0, 0, 0), thick)
        tw = cv2.getTextSize(_tick_text(v), font, tick_scale, thick)[0][0]
        _text(
            img,
            _tick_text(v),
            (left - int(14 * scale) - tw, yp + th_tick // 2),
            tick_scale,
            thick=thick,
        )
    # the curve, broken where there is no data
    pts = np.array([px(a, b) for a, b in zip(d, np.nan_to_num(z))], np.int32).reshape(-1, 2)
    run: list[int] = []
    for k in range(len(d) + 1):
        if k < len(d) and ok[k]:
            run.append(k)
            continue
        if len(run) >= 2:
            cv2.polylines(img, [pts[run]], False, (0, 0, 0), thick, cv2.LINE_AA)
        elif len(run) == 1:
            cv2.circle(img, tuple(int(v) for v in pts[run[0]]), thick, (0, 0, 0), -1)
        run = []
    cv2.rectangle(img, (left, plot_top), (left + pw, plot_top + ph), (0, 0, 0), thick)
    x_title = "distance along the ruler (mm)"
    tw = cv2.getTextSize(x_title, font, tick_scale, thick)[0][0]
    _text(img, x_title, (left + (pw - tw) // 2, height - int(16 * scale)), tick_scale, thick=thick)
    y_title = "height (mm)"
    (tw, th), base = cv2.getTextSize(y_title, font, tick_scale, thick)
    lab = np.full((th + base + 4, tw + 4, 3), 255, np.uint8)
    _text(lab, y_title, (2, th + 2), tick_scale, thick=thick)
    lab = np.rot90(lab)
    r0 = plot_top + max(0, (ph - lab.shape[0]) // 2)
    if r0 + lab.shape[0] <= height:
        img[r0 : r0 + lab.shape[0], int(12 * scale) : int(12 * scale) + lab.shape[1]] = lab
    return img


def png_bytes(rgb: np.ndarray, provenance: Mapping | None = None) -> bytes:
    """PNG of an RGB image (:func:`images.png_bytes`); with ``provenance`` (an export's
    provenance dictionary) its Software, Source and 'IMPREsS provenance' (JSON) tEXt chunks
    follow the header."""
    data = images.png_bytes(rgb)
    if provenance is None:
        return data
    return png_with_text(data, png_provenance_text(provenance))


# ----- the report ----------------------------------------------------------------------------
# One self-contained HTML document; every value is escaped by Jinja2 (autoescape on).
REPORT_TEMPLATE = """\
{% macro row(key, value) %}<tr><th>{{ key }}</th><td>{{ value|v }}</td></tr>{% endmacro %}
{% macro rows(items) %}
{% for key, value in items %}
{{ row(key, value) }}
{% endfor %}
{% endmacro %}
<!DOCTYPE html>
<html><head><meta charset='utf-8'>
<title>IMPREsS report {{ case.get('case_id', '') }}</title>
<style>body{font-family:sans-serif;margin:2em;color:#111}table{border-collapse:collapse;\
margin:0.5em 0 1.5em}th,td{border:1px solid #bbb;padding:3px 8px;text-align:left;\
font-size:90%}th{background:#eee}img{max-width:100%;border:1px solid #ccc}\
h2{border-bottom:2px solid #333;margin-top:1.6em}table.inner{margin:0}</style></head><body>
<h1>IMPREsS impression scan report</h1>
<p>Generated {{ created_utc }} by IMPREsS workstation {{ version }}.</p>
<h2>Case</h2><table>
{% for key in ('case_id', 'evidence_id', 'examiner', 'notes', 'project') %}
{{ row(key|replace('_', ' '), case.get(key, '')) }}
{% endfor %}
{% if signature %}
</table><h2>Case record signature (Ed25519)</h2><table>
{% for key in ('key_fingerprint', 'public_key', 'user', 'head_signature', 'log_head') %}
{{ row(key|replace('_', ' '), 'not signed' if signature.get(key) is none \
else signature.get(key)) }}
{% endfor %}
{% endif %}
</table><h2>Inputs (SHA-256)</h2><table>
{% for name, info in inputs.items() %}
{{ row(name, info.get('path', '') ~ '  sha256 ' ~ info.get('sha256', '-')) }}
{% endfor %}
</table><h2>Reconstruction</h2><table>
{{ rows(reconstruction.items()) }}</table>
{% if calibration %}
<h2>Calibration quality</h2><table>
{{ rows(calibration.items()) }}</table>
{% endif %}
{% if levelling %}
<h2>Levelling</h2><table>
{{ rows(levelling.items()) }}</table>
{% endif %}
<h2>Measurements</h2>
{% if measurements %}
<table><tr>{% for h in head %}<th>{{ h }}</th>{% endfor %}</tr>
{% for cells in measurements %}
<tr>{% for c in cells %}<td>{{ c }}</td>{% endfor %}</tr>
{% endfor %}
</table>
{% else %}
<p>No measurements.</p>
{% endif %}
<h2>Figures</h2>
{% for caption, data in images %}
<figure><img alt='{{ caption }}' src='data:image/png;base64,{{ data }}'>\
<figcaption>{{ caption }}</figcaption></figure>
{% endfor %}
</body></html>"""


def _v(value):
    """A value as the report shows it: '-' for none, floats to 4 decimals, a list as its items
    separated by commas, a mapping (the processing parameters, a region) as a small table of
    its own - never as Python's text of a dict."""
    from markupsafe import Markup, escape

    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.4f}" if math.isfinite(value) else "-"
    if isinstance(value, Mapping):
        if not value:
            return "-"
        rows = "".join(
            f"<tr><th>{escape(str(k).replace('_', ' '))}</th><td>{escape(_v(v))}</td></tr>"
            for k, v in value.items()
        )
        return Markup(f"<table class='inner'>{rows}</table>")
    if isinstance(value, (list, tuple)):
        return ", ".join(str(_v(x)) for x in value) if value else "-"
    return str(value)


@functools.lru_cache(maxsize=1)
def _report_template():
    import jinja2

    env = jinja2.Environment(
        autoescape=True,
        trim_blocks=True,
        lstrip_blocks=True,
        undefined=jinja2.StrictUndefined,
    )
    env.filters["v"] = _v
    return env.from_string(REPORT_TEMPLATE)


def report_html(
    *,
    case: Mapping,
    reconstruction: Mapping,
    calibration: Mapping | None,
    measurements: Sequence[Mapping],
    images: Sequence[tuple[str, bytes]],
    inputs: Mapping,
    created_utc: str,
    levelling: Mapping | None = None,
) -> str:
    """The case report as one HTML document (PNG images embedded as data URLs), rendered from
    :data:`REPORT_TEMPLATE` with every value escaped."""
    # one row per measurement, its values as a small table of their own: a column per value
    # (a ruler has five, each reading its uncertainties too) squeezes an A4 page's table until
    # its words break letter by letter
    rows = []
    for n, m in enumerate(measurements, 1):
        pts = "; ".join(f"({p[0]:.2f}, {p[1]:.2f})" for p in m.get("points_mm", []))
        cells = [str(n), m.get("kind", ""), m.get("label", ""), m.get("note", ""), pts,
                 _v(dict(m.get("values", {})))]
        rows.append([c if hasattr(c, "__html__") else str(c) for c in cells])
    return _report_template().render(
        case=case,
        signature=case.get("signature"),
        inputs=inputs,
        reconstruction=reconstruction,
        calibration=calibration,
        levelling=levelling,
        head=["#", "kind", "label", "note", "points (mm)", "values"],
        measurements=rows,
        images=[(caption, base64.b64encode(png).decode("ascii")) for caption, png in images],
        created_utc=created_utc,
        version=__version__,
    )
