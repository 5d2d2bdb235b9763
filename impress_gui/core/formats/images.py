"""Image files as bytes: the one PNG encoder and the one TIFF writer of every image the
product writes (the reconstruction's files, figures, reports, the simulator's truth). Callers
write the bytes where they belong (atomically, into a checked output folder, inline).

The encoders are imported with this module, not on first use: a first import inside a writer
thread holds the interpreter for about 0.1 s, which froze the window at the end of a run."""

from __future__ import annotations

import io

import cv2
import numpy as np
import tifffile


def png_bytes(img: np.ndarray) -> bytes:
    """PNG of an RGB ``(H, W, 3)`` or grey ``(H, W)`` image, 8 or 16 bits per sample
    (OpenCV's encoder with its default settings)."""
    return bgr_png_bytes(img[..., ::-1] if img.ndim == 3 else img)


def bgr_png_bytes(img: np.ndarray) -> bytes:
    """:func:`png_bytes` of an image in OpenCV's channel order (B, G, R): no reordered copy."""
    ok, enc = cv2.imencode(".png", np.ascontiguousarray(img))
    if not ok:
        raise OSError("PNG encoding failed")
    return enc.tobytes()


def tiff_bytes(arr: np.ndarray, *, pixel_mm: float | None = None,
               description: str | None = None, software: str | None = None,
               level: int | None = None, shape_metadata: bool = False,
               predictor: bool = False) -> bytes:
    """zlib-compressed (Adobe deflate) TIFF of ``arr``.

    ``pixel_mm``: the resolution tags give the cell size (pixels per cm); ``description``: the
    ImageDescription (ASCII; other characters become backslash escapes); ``software``: the
    Software tag (tifffile's own name when None); ``level``: the zlib level (zlib's default
    when None); ``shape_metadata``: tifffile's JSON description of the array's shape instead
    of no description (as the simulator's truth heightmap has always been written);
    ``predictor``: the TIFF predictor for the array's kind (floating point, 3, for floats;
    horizontal differencing, 2, for integers), which libtiff, Pillow, GDAL and tifffile read.

    The deflate encoder is imagecodecs' (libdeflate): 3.6x faster than Python's zlib at the
    same level, the same standard TIFF."""
    extra: dict = {}
    if pixel_mm is not None:
        ppcm = 10.0 / pixel_mm
        extra = {"resolution": (ppcm, ppcm), "resolutionunit": "CENTIMETER"}
    if description:
        extra["description"] = description.encode("ascii", "backslashreplace").decode("ascii")
    if level is not None:
        extra["compressionargs"] = {"level": level}
    if predictor:
        extra["predictor"] = True
    if not shape_metadata:
        extra["metadata"] = None
    buf = io.BytesIO()
    tifffile.imwrite(buf, arr, compression="zlib", software=software, **extra)
    return buf.getvalue()
