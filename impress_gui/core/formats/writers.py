"""Writing a reconstruction: one folder per scan, replaced atomically.

All files are first written into a hidden sibling folder, which is renamed into place only
when everything is complete, so an interrupted or failed run never leaves a half-written
result that looks whole. Every file except ``run.json`` (timings, date) and the X3P's creation
date is byte-identical for identical inputs.
"""

from __future__ import annotations

import hashlib
import io
import os
import zipfile
from collections.abc import Callable, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, cast

import numpy as np
import plyfile

from impress_gui import __version__
from impress_gui.core.base.fileio import dumps_json, sha256_file
from impress_gui.core.formats.images import bgr_png_bytes, png_bytes, tiff_bytes
from impress_gui.core.formats.recon_files import (
    COLOUR_PNG,
    CONTRIBUTION_PNG,
    GREY8_PNG,
    LAYER_FILES,
    METADATA_FILE,
    PLY_FILE,
    RECON_FILES,
    RECON_FORMAT,
    RECON_VERSION,
    RUN_FILE,
    TEXTURE_FILE,
    X3P_FILE,
)

HEIGHT_CONVENTION = (
    "height in mm, up = towards the camera, relative to the calibration target's base plane "
    "(the ground the target stands on); NaN = no data"
)
GREY_OFFSET = 128  # thesis 8-bit convention: one grey level = 0.1 mm, 128 = reference height
CONTRIB_CODES = {0: "no data", 1: "green only", 2: "red only", 3: "both (mean)",
                 4: "both disagree (nearer the local consensus)"}


def grey8(height: np.ndarray, step_mm: float = 0.1) -> np.ndarray:
    """The seed's 8-bit heightmap: one grey level per 0.1 mm, 128 = reference, 0 = no data."""
    out = np.empty(height.shape, np.uint8)
    for rows in _row_blocks(height.shape[0]):
        g = np.rint(np.nan_to_num(height[rows], nan=-1e9) / step_mm) + GREY_OFFSET
        out[rows] = np.clip(g, 0, 255)
    return out


#: rows per block of the images made from a grid: a block's temporaries stay in the cache
ROW_BLOCK = 256


def _row_blocks(n: int):
    for a in range(0, n, ROW_BLOCK):
        yield slice(a, min(n, a + ROW_BLOCK))


def color_range(height: np.ndarray) -> tuple[float, float]:
    v = height[np.isfinite(height)]
    if v.size == 0:
        return (-1.0, 1.0)
    lo, hi = np.percentile(v, [0.5, 99.5])
    if hi - lo < 0.1:
        lo, hi = lo - 0.05, hi + 0.05
    return float(lo), float(hi)


def pseudo_colour(height: np.ndarray, vrange=None, bar: bool = True) -> np.ndarray:
    """Turbo-coloured heightmap (RGB) with a labelled colour bar in mm on the right."""
    return pseudo_colour_bgr(height, vrange, bar)[..., ::-1]


def pseudo_colour_bgr(height: np.ndarray, vrange=None, bar: bool = True) -> np.ndarray:
    """:func:`pseudo_colour` in OpenCV's channel order (B, G, R), made a block of rows at a
    time (no full-size temporaries)."""
    import cv2

    lo, hi = vrange or color_range(height)
    h, w = height.shape
    bw = max(60, h // 12)
    out = np.empty((h, w + (bw * 3 if bar else 0), 3), np.uint8)
    for rows in _row_blocks(h):
        hh = height[rows]
        t = np.clip((np.nan_to_num(hh, nan=lo) - lo) / (hi - lo), 0, 1)
        block = cv2.applyColorMap((t * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
        block[~np.isfinite(hh)] = 0
        out[rows, :w] = block
    if not bar:
        return out
    panel = out[:, w:]
    panel[:] = 255
    ramp = np.linspace(1, 0, h)[:, None]
    col = cv2.applyColorMap((ramp * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    panel[:, 4:bw] = col
    panel = np.ascontiguousarray(panel)
    scale = max(0.4, h / 1400)
    for i in range(6):
        f = i / 5
        y = int(round((1 - f) * (h - 1)))
        cv2.line(panel, (bw, y), (bw + 8, y), (0, 0, 0), max(1, int(scale * 2)))
        cv2.putText(panel, f"{lo + f * (hi - lo):.2f}", (bw + 12, min(h - 4, max(int(20 * scale), y + 8))),
                    cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), max(1, int(scale * 2)))
    cv2.putText(panel, "mm", (bw + 12, h // 2), cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0),
                max(1, int(scale * 2)))
    out[:, w:] = panel
    return out


EXPORT_FRAME = (
    "right-handed, in mm: x = across the rail (the image's columns, to the right), y = against "
    "the carriage's motion (y = -rail Y, so the image's first row has the largest y), z = height "
    "up, towards the camera; seen from above (+z) with y up the surface looks as the camera and "
    "texture.png show it: a left shoe stays a left shoe"
)


def export_xy(spec, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Grid cells ``(rows, cols)`` -> the right-handed export frame's (x, y) in mm (see
    :data:`EXPORT_FRAME`): x = rail X, y = -rail Y."""
    x = spec.x0_mm + cols * spec.pixel_mm
    y = -(spec.y0_mm + rows * spec.pixel_mm)
    return x, y


def ply_bytes(spec, height: np.ndarray, texture: np.ndarray | None, step: int = 1,
              comments: Sequence[str] = ()) -> bytes:
    """Binary little-endian PLY (written by plyfile): float32 x, y, z (mm, the right-handed
    :data:`EXPORT_FRAME`) and uchar RGB. Each of ``comments`` (provenance lines) becomes one
    header ``comment`` line (one line; ASCII, other characters as backslash escapes)."""
    hh = height[::step, ::step]
    ok = np.isfinite(hh)
    ii, jj = np.nonzero(ok)
    n = len(ii)
    pts = np.empty(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                             ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    pts["x"], pts["y"] = export_xy(spec, ii * step, jj * step)
    pts["z"] = hh[ok]
    if texture is not None:
        tex = texture[::step, ::step][ok]
        pts["red"], pts["green"], pts["blue"] = tex[:, 0], tex[:, 1], tex[:, 2]
    else:
        pts["red"] = pts["green"] = pts["blue"] = 200
    lines = [f"IMPREsS workstation {__version__}; units mm", f"frame: {EXPORT_FRAME}",
             f"sampling: every {step} cell(s) of the {spec.pixel_mm:g} mm grid each way",
             *(_one_line(c) for c in comments)]
    # plyfile refuses non-ASCII and newlines in comments: escape them as before
    ply = plyfile.PlyData([plyfile.PlyElement.describe(pts, "vertex")], byte_order="<",
                          comments=[_ascii(c) for c in lines])
    buf = io.BytesIO()
    ply.write(buf)
    return buf.getvalue()


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _ascii(text: str) -> str:
    return text.encode("ascii", "backslashreplace").decode("ascii")


X3P_ROWS_PER_CHUNK = 256


def _x3p_chunks(height: np.ndarray):
    """The X3P's point data in pieces of rows: float64 metres, x fastest, the grid's rows
    last first (no full-size copy of the grid is ever made)."""
    ny = height.shape[0]
    for stop in range(ny, 0, -X3P_ROWS_PER_CHUNK):
        start = max(0, stop - X3P_ROWS_PER_CHUNK)
        yield (height[start:stop][::-1].astype("<f8") * 1e-3).tobytes()


def x3p_bytes(spec, height: np.ndarray, created: str, comment: str = "",
              calibrated: str | None = None,
              done: Callable[[float], None] | None = None) -> bytes:
    """The X3P of :func:`write_x3p` as bytes."""
    buf = io.BytesIO()
    write_x3p(buf, spec, height, created, comment, calibrated, done)
    return buf.getvalue()


def write_x3p(target, spec, height: np.ndarray, created: str, comment: str = "",
              calibrated: str | None = None,
              done: Callable[[float], None] | None = None) -> None:
    """ISO 25178-72 (XML 3D surface profile) container: an areal surface, x/y incremental
    axes in metres, z as float64 metres with NaN for invalid points, in the right-handed
    :data:`EXPORT_FRAME` (the grid's rows are stored last first, so that y increases with the
    point index). ``comment`` (provenance included) goes into Record2/Comment, XML-escaped.
    ``created`` and ``calibrated`` are ISO 8601 dates; for reproducible files pass dates that
    come from the inputs (the calibration's date), not the time of writing. ``done`` is
    called with the share of the work done (0..1) after each piece of rows."""
    from xml.sax.saxutils import escape

    ny, nx = height.shape
    n_chunks = -(-ny // X3P_ROWS_PER_CHUNK)
    md5 = hashlib.md5()
    for k, chunk in enumerate(_x3p_chunks(height), 1):
        md5.update(chunk)
        if done is not None:  # the checksum's pass: a tenth of the work
            done(0.1 * k / n_chunks)
    md5_data = md5.hexdigest()
    y_offset_mm = -(spec.y0_mm + (ny - 1) * spec.pixel_mm)
    comment = f"frame: {EXPORT_FRAME}; {comment}" if comment else f"frame: {EXPORT_FRAME}"
    calibrated = calibrated or created
    xml = f"""<?xml version="1.0" encoding="UTF-8"?>
<p:ISO5436_2 xmlns:p="http://www.opengps.eu/2008/ISO5436_2" xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" xsi:schemaLocation="http://www.opengps.eu/2008/ISO5436_2 http://www.opengps.eu/2008/ISO5436_2/ISO5436_2_XML.xsd">
  <Record1>
    <Revision>ISO5436 - 2000</Revision>
    <FeatureType>SUR</FeatureType>
    <Axes>
      <CX><AxisType>I</AxisType><DataType>D</DataType><Increment>{spec.pixel_mm * 1e-3:.12g}</Increment><Offset>{spec.x0_mm * 1e-3:.12g}</Offset></CX>
      <CY><AxisType>I</AxisType><DataType>D</DataType><Increment>{spec.pixel_mm * 1e-3:.12g}</Increment><Offset>{y_offset_mm * 1e-3:.12g}</Offset></CY>
      <CZ><AxisType>A</AxisType><DataType>D</DataType></CZ>
    </Axes>
  </Record1>
  <Record2>
    <Date>{created}</Date>
    <Creator>IMPREsS workstation</Creator>
    <Instrument>
      <Manufacturer>IMPREsS</Manufacturer>
      <Model>laser line scanner (camcorder, green and red line lasers)</Model>
      <Serial>not available</Serial>
      <Version>{__version__}</Version>
    </Instrument>
    <CalibrationDate>{calibrated}</CalibrationDate>
    <ProbingSystem><Type>NonContacting</Type><Identification>laser triangulation</Identification></ProbingSystem>
    <Comment>{escape(comment)}</Comment>
  </Record2>
  <Record3>
    <MatrixDimension><SizeX>{nx}</SizeX><SizeY>{ny}</SizeY><SizeZ>1</SizeZ></MatrixDimension>
    <DataLink><PointDataLink>bindata/data.bin</PointDataLink><MD5ChecksumPointData>{md5_data}</MD5ChecksumPointData></DataLink>
  </Record3>
  <Record4><ChecksumFile>md5checksum.hex</ChecksumFile></Record4>
</p:ISO5436_2>
"""
    xml_b = xml.encode("utf-8")
    nbytes = nx * ny * 8

    def member(name: str):
        info = zipfile.ZipInfo(name, date_time=(2000, 1, 1, 0, 0, 0))
        info.compress_type = zipfile.ZIP_DEFLATED
        cast(Any, info)._compresslevel = ZLIB_LEVEL  # zipfile's own field (3.10-3.13)
        return info

    with zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.writestr(member("main.xml"), xml_b, compresslevel=ZLIB_LEVEL)
        zf.writestr(member("md5checksum.hex"),
                    f"{hashlib.md5(xml_b).hexdigest()} *main.xml\n".encode(),
                    compresslevel=ZLIB_LEVEL)
        # the point data streamed in pieces of rows
        with zf.open(member("bindata/data.bin"), "w", force_zip64=nbytes > 2**31 - 1) as fh:
            for k, chunk in enumerate(_x3p_chunks(height), 1):
                fh.write(chunk)
                if done is not None:
                    done(0.1 + 0.9 * k / n_chunks)


def _write_file(path: Path, write) -> None:
    with open(path, "wb") as fh:
        write(fh)


#: the X3P's date where the inputs state none (a date is required there): the start of the
#: Unix epoch, which no scan has, and ``metadata.json`` says so (``dates.source``)
UNKNOWN_DATE = "1970-01-01T00:00:00Z"


def input_dates(video, calibration_path) -> dict[str, str]:
    """The X3P's dates, taken from the inputs' contents so that identical inputs give
    identical files (a copy of the evidence too, whatever its file times): ``measured`` = the
    recording date the video's container states, else :data:`UNKNOWN_DATE`; ``calibrated`` =
    the same when the calibration was made on this video (the rig calibrates itself from each
    scan), else :data:`UNKNOWN_DATE`; ``source`` says which. (Until 4 December 2026 the files'
    modification times stood in: a copied video gave another X3P.)"""
    measured = None
    if getattr(video, "recorded_utc", None):
        measured = str(video.recorded_utc)[:19].replace(" ", "T") + "Z"
    said = ("the recording date the video's container states" if measured else
            f"not stated by the video's container: {UNKNOWN_DATE} stands for unknown")
    measured = measured or UNKNOWN_DATE
    calibrated, cal_said = measured, "the calibration was made on this video: its date"
    try:
        import json

        doc = json.loads(Path(calibration_path).read_bytes())
        made_on = ((doc.get("inputs") or {}).get("video") or {}).get("sha256")
        if made_on != video.sha256():
            calibrated = UNKNOWN_DATE
            cal_said = (f"the calibration was made on another video: {UNKNOWN_DATE} stands "
                        "for unknown")
    except (OSError, ValueError, AttributeError):
        pass
    return {"measured": measured, "calibrated": calibrated,
            "source": f"measured: {said}; calibrated: {cal_said}"}


CONTRIB_RGB = np.array([[0, 0, 0], [40, 200, 40], [220, 40, 40], [230, 230, 230], [240, 160, 0]],
                       np.uint8)


def contribution_png(contrib: np.ndarray) -> np.ndarray:
    """The contribution codes (any shape) as RGB (:data:`CONTRIB_RGB`)."""
    return CONTRIB_RGB[np.clip(contrib, 0, 4)]


def contribution_bgr(contrib: np.ndarray) -> np.ndarray:
    """:func:`contribution_png` of a 2-D map in OpenCV's channel order (B, G, R): one
    table lookup per channel, codes above 4 shown as 4."""
    import cv2

    lut = np.zeros((256, 1, 3), np.uint8)
    lut[:, 0] = CONTRIB_RGB[4, ::-1]
    lut[:5, 0] = CONTRIB_RGB[:, ::-1]
    c = contrib if contrib.dtype == np.uint8 else np.clip(contrib, 0, 4).astype(np.uint8)
    return cv2.LUT(cv2.merge([c, c, c]), lut)


#: threads encoding and writing the outputs side by side
WRITE_THREADS = 4
#: the slowest files first, so that they overlap the rest
WRITE_ORDER = {X3P_FILE: 0, LAYER_FILES["fused"]: 1, PLY_FILE: 2, TEXTURE_FILE: 3}
#: zlib level of the TIFFs and the X3P: level 1 is 2x faster than the default 6 for files
#: 0.5 % (TIFF) and 9 % (X3P) larger (measured on a shoe scan's heightmap); with the floating
#: point predictor level 6 is 1 % smaller than level 1 and takes 1.6x its time
ZLIB_LEVEL = 1
#: the longest wait between two progress reports while the outputs are written
PROGRESS_SECONDS = 0.5
#: each file's cost relative to the others (processor seconds per grid cell, measured on a
#: shoe scan: the X3P's Python zlib is the slowest), for the writing's progress fraction
WRITE_COST = {X3P_FILE: 2.6, LAYER_FILES["fused"]: 0.6, LAYER_FILES["green"]: 0.6,
              LAYER_FILES["red"]: 0.6, LAYER_FILES["difference"]: 0.6,
              LAYER_FILES["contribution"]: 0.1, CONTRIBUTION_PNG: 0.25, GREY8_PNG: 0.25,
              COLOUR_PNG: 1.0, PLY_FILE: 0.3, TEXTURE_FILE: 0.6}


class _Shares:
    """How much of each output is done (0..1), set from the writer threads."""

    def __init__(self) -> None:
        self._done: dict[str, float] = {}

    def set(self, name: str, fraction: float) -> None:
        self._done[name] = fraction  # one float per name: atomic under the GIL

    def fraction(self, names) -> float:
        total = sum(WRITE_COST.get(n, 0.5) for n in names)
        done = sum(WRITE_COST.get(n, 0.5) * self._done.get(n, 0.0) for n in names)
        return done / total if total else 1.0


def write_reconstruction(rec, out_dir, metadata: dict, run_info: dict,
                         ply_step: int = 2, dates: dict | None = None,
                         progress=None) -> dict[str, str]:
    """Write every output into ``out_dir`` (a path, or an
    :class:`~impress_gui.core.base.outdir.OutputFolder` already checked) atomically; return
    {file: sha256}. ``dates`` (``measured``, ``calibrated``: see :func:`input_dates`) go into
    the X3P; without them the run's date is used (the file then differs between runs).

    The point cloud takes every ``ply_step``-th cell in each direction (default 2: 0.2 mm
    spacing on the default grid, a quarter of the cells; 1 keeps every cell)."""
    from impress_gui.core.base.outdir import OutputFolder, writing

    folder = out_dir if isinstance(out_dir, OutputFolder) else OutputFolder(
        out_dir, "reconstruction", allowed=RECON_FILES)
    run_date = run_info.get("date_utc") or datetime.now(timezone.utc).strftime(
        "%Y-%m-%dT%H:%M:%SZ")
    dates = dates or {"measured": run_date, "calibrated": run_date}
    inputs = metadata.get("inputs") or {}
    source = [f"source {k} sha256: {(inputs.get(k) or {}).get('sha256') or '-'}"
              for k in ("video", "calibration")]
    def desc(what: str) -> str:
        return (f"IMPREsS workstation {__version__}: {what}; cell {rec.spec.pixel_mm} mm, "
                f"x0 {rec.spec.x0_mm} mm, y0 {rec.spec.y0_mm} mm (rail frame, row 0 first); "
                + "; ".join(source) + "; parameters: metadata.json")

    def png_text(png: bytes, what: str) -> bytes:
        """The PNG view with its provenance as text chunks (the pixels untouched)."""
        from impress_gui.core.formats.provenance import png_with_text

        return png_with_text(png, {"Software": f"IMPREsS workstation {__version__}",
                                   "Description": desc(what)})

    h32 = np.asarray(rec.height_mm, np.float32)  # no copy of float32 maps
    # each file is made, written and hashed by a task of its own: the encoders (deflate, PNG)
    # release the GIL, so the files are made side by side
    def tiff(arr: np.ndarray, what: str, predictor: bool = True) -> bytes:
        return tiff_bytes(arr, pixel_mm=rec.spec.pixel_mm, description=desc(what),
                          level=ZLIB_LEVEL, predictor=predictor)

    makers: dict[str, Callable[[], bytes]] = {
        LAYER_FILES["fused"]: lambda: tiff(h32, "fused height, mm, NaN = no data"),
        LAYER_FILES["green"]: lambda: tiff(np.asarray(rec.per_laser_mm["green"], np.float32),
                                           "green laser height, mm"),
        LAYER_FILES["red"]: lambda: tiff(np.asarray(rec.per_laser_mm["red"], np.float32),
                                         "red laser height, mm"),
        LAYER_FILES["difference"]: lambda: tiff(np.asarray(rec.difference_mm, np.float32),
                                                "green - red height, mm"),
        LAYER_FILES["contribution"]: lambda: tiff(np.asarray(rec.contribution, np.uint8),
                                                  "contribution codes (metadata.json)",
                                                  predictor=False),
        CONTRIBUTION_PNG: lambda: png_text(bgr_png_bytes(contribution_bgr(rec.contribution)),
                                           "contribution codes as colours (metadata.json)"),
        GREY8_PNG: lambda: png_text(png_bytes(grey8(rec.height_mm)),
                                    "height, 8-bit grey levels (scale: metadata.json)"),
        COLOUR_PNG: lambda: png_text(bgr_png_bytes(pseudo_colour_bgr(rec.height_mm)),
                                     "height in pseudo-colour (scale: metadata.json)"),
        PLY_FILE: lambda: ply_bytes(rec.spec, rec.height_mm, rec.texture_rgb, ply_step, source),
    }
    shares = _Shares()
    # written straight into their files (no copy of the whole file in memory)
    streamed: dict[str, Callable[[Path], None]] = {
        X3P_FILE: lambda path: _write_file(path, lambda fh: write_x3p(
            fh, rec.spec, rec.height_mm, dates["measured"],
            "IMPREsS reconstruction; " + "; ".join(source)
            + "; parameters, grid and height convention: metadata.json",
            calibrated=dates["calibrated"], done=lambda f: shares.set(X3P_FILE, f))),
    }
    if rec.texture_rgb is not None:
        makers[TEXTURE_FILE] = lambda: png_text(png_bytes(rec.texture_rgb),
                                                "colour texture on the height grid")
    from concurrent.futures import FIRST_COMPLETED, ThreadPoolExecutor, wait

    from impress_gui.core.base.outdir import MARK_FILE, mark_bytes
    from impress_gui.core.base.progress import report

    def make(name: str) -> str:
        if name in streamed:
            streamed[name](folder.path(name))
            return sha256_file(folder.path(name))
        payload = makers[name]()
        folder.path(name).write_bytes(payload)
        return hashlib.sha256(payload).hexdigest()

    made: dict[str, str] = {}
    names = [*makers, *streamed]
    order = sorted(names, key=lambda n: WRITE_ORDER.get(n, 9))
    try:
        with writing(folder.final):
            folder.begin()
            workers = max(1, min(WRITE_THREADS, os.cpu_count() or 1))
            with ThreadPoolExecutor(workers, thread_name_prefix="impress-write") as pool:
                futures = {pool.submit(make, n): n for n in order}
                pending = set(futures)
                last = ""
                while pending:
                    # progress at least every PROGRESS_SECONDS: the finished files' shares
                    # and the streamed file's pieces, weighted by their measured costs
                    finished, pending = wait(pending, timeout=PROGRESS_SECONDS,
                                             return_when=FIRST_COMPLETED)
                    for fut in finished:
                        made[futures[fut]] = fut.result()
                        shares.set(futures[fut], 1.0)
                        last = f"written {futures[fut]}"
                    msg = last or "writing the outputs"
                    report(progress, shares.fraction(names) * len(names) / (len(names) + 1),
                           f"{msg} ({len(made)} of {len(names)} files)")
            digests = {MARK_FILE: hashlib.sha256(mark_bytes("reconstruction")).hexdigest()}
            digests.update((n, made[n]) for n in RECON_FILES if n in made)
            meta = dict(metadata)
            meta["files"] = digests
            folder.path(METADATA_FILE).write_text(dumps_json(meta))
            folder.path(RUN_FILE).write_text(dumps_json(run_info))
        report(progress, 1.0, "outputs written")
        folder.commit()
    except BaseException:
        folder.abort()
        raise
    return digests


def build_metadata(rec, cal, params, inputs: dict) -> dict:
    return {
        "format": RECON_FORMAT,
        "version": RECON_VERSION,
        "software": f"impress {__version__}",
        "inputs": inputs,
        "parameters": params.to_json(),
        "frames": {"start": rec.frames[0], "stop": rec.frames[1]},
        "regions_of_interest": {k: list(v) for k, v in rec.rois.items()},
        "grid": rec.spec.to_json() | {
            "convention": "cell [i, j] centred at rail (x0 + j*pixel, y0 + i*pixel) mm; rail "
                          "frame origin = optical centre at calibration frame t1; +Y = motion; "
                          "row 0 is the first row of every image file (as the camera sees it)"},
        "export_frame": {"files": [PLY_FILE, X3P_FILE], "frame": EXPORT_FRAME,
                         "x_mm": "x0 + j*pixel", "y_mm": "-(y0 + i*pixel)", "z_mm": "height"},
        "height": HEIGHT_CONVENTION,
        "grey8": {"file": GREY8_PNG, "mm_per_level": 0.1, "reference_level":
                  GREY_OFFSET, "no_data_level": 0},
        "contribution_codes": {str(k): v for k, v in CONTRIB_CODES.items()},
        "calibration": {"roll_deg": cal.roll_deg, "tilt_deg": cal.tilt_deg,
                        "speed_mm_s": cal.speed_mm_s,
                        "implied_speed_mm_s": cal.implied_speed_mm_s},
        "stats": rec.result_stats(),
        "warnings": list(rec.warnings),
    }

