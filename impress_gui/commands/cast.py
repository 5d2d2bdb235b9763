"""``impress cast``: a watertight mesh of an impression (binary STL, PLY or OBJ) for a 3D
printer, as recorded (a negative) or turned into the outsole's positive, with a JSON sidecar."""

from __future__ import annotations

import argparse
from pathlib import Path


def _crop(text: str) -> tuple[float, float, float, float]:
    import math

    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not X0,Y0,X1,Y1 in mm") from None
    if len(values) != 4 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"{text!r} is not four finite numbers X0,Y0,X1,Y1")
    return values[0], values[1], values[2], values[3]


def add_arguments(p: argparse.ArgumentParser) -> None:
    from impress_gui.core.measure.cast import (
        DECIMATE_METHODS,
        DEFAULT_BASE_MM,
        DEFAULT_DECIMATE,
        DEFAULT_MAX_TRIANGLES,
        DEFAULT_TOLERANCE_MM,
    )

    p.add_argument("reconstruction", type=Path, help="reconstruction folder (impress process)")
    p.add_argument("-o", "--output", type=Path, required=True,
                   help="the mesh file: .stl (binary), .ply or .obj; a sidecar OUTPUT.json "
                   "records the inputs and parameters")
    p.add_argument("--positive", action="store_true",
                   help="the outsole's positive: the cast poured into the impression, turned "
                   "over (rotated 180 deg about y: x -> -x, z -> -z); default the impression "
                   "as recorded")
    p.add_argument("--base-mm", type=float, default=DEFAULT_BASE_MM,
                   help=f"base thickness below the lowest point, mm (default {DEFAULT_BASE_MM:g})")
    p.add_argument("--crop", type=_crop, default=None, metavar="X0,Y0,X1,Y1",
                   help="region in the export frame, mm (default: the cells with data)")
    p.add_argument("--tolerance-mm", type=float, default=DEFAULT_TOLERANCE_MM,
                   help=f"with --decimate adaptive: the largest vertical distance allowed "
                   f"between the mesh's surface and any cell of the heightmap, mm (default "
                   f"{DEFAULT_TOLERANCE_MM:g}; 0 keeps every cell that is not on a plane with "
                   f"its neighbours)")
    p.add_argument("--max-triangles", type=int, default=DEFAULT_MAX_TRIANGLES,
                   help=f"triangle cap (the file's size: 50 bytes a triangle in STL); with "
                   f"--decimate adaptive a cap reached before the tolerance is said so in the "
                   f"output and the record (default {DEFAULT_MAX_TRIANGLES})")
    p.add_argument("--decimate", choices=DECIMATE_METHODS, default=DEFAULT_DECIMATE,
                   help="how the mesh is made smaller than the grid: 'adaptive' places "
                   "vertices on the cells where the relief needs them until every cell lies "
                   "within --tolerance-mm of the surface (flat ground gets large triangles, "
                   "walls and edges small ones); 'sample' keeps every k-th cell under the cap "
                   "(walls smeared over k cells); 'quadric' simplifies the full-resolution mesh "
                   "with open3d's quadric error decimation to the cap (slower, more memory); "
                   f"the record gives the surface's deviation from the heightmap either way "
                   f"(default {DEFAULT_DECIMATE})")


def run(args: argparse.Namespace) -> int:
    from impress_gui.commands._progress import progress_printer
    from impress_gui.core.measure.cast import CastParams, write_cast

    params = CastParams(positive=args.positive, base_mm=args.base_mm, crop_mm=args.crop,
                        max_triangles=args.max_triangles, decimate=args.decimate,
                        tolerance_mm=args.tolerance_mm)
    progress = progress_printer()

    doc = write_cast(args.reconstruction, args.output, params, progress)
    for line in summary_lines(doc, args.output):
        print(line)
    return 0


def summary_lines(doc: dict, output: Path | str) -> list[str]:
    """What ``impress cast`` prints about the cast it wrote (``doc``: its sidecar's record).
    The record's optional parts may be absent (no cell measured; every vertical ray missed:
    no vertical figures and no ``tolerance_mm``, docs/formats.md): said so, never a KeyError
    after the files were written."""
    from impress_gui.core.measure.cast import SURFACE_TOLERANCE_MM

    m, holes = doc["mesh"], doc.get("holes") or {}
    box = m["bounding_box"]
    size = [hi - lo for lo, hi in zip(box["min_mm"], box["max_mm"], strict=True)]
    dec = m.get("decimation") or {}
    where = (f"adaptive, {dec.get('surface_vertices')} surface vertices on the "
             f"{dec.get('cells')} cells" if dec.get("method") == "adaptive" else
             f"every {m['step_cells']} cell(s) ({m['vertex_spacing_mm']:g} mm)")
    lines = [f"cast written to {output} ({doc['parameters']['mode']}, {m['format']})",
             f"  {m['triangles']} triangles, {m['vertices']} vertices, {where}; size "
             f"{size[0]:.1f} x {size[1]:.1f} x {size[2]:.1f} mm; volume "
             f"{m['volume_mm3'] / 1000:.1f} cm3"]
    dev, chk = doc.get("surface_deviation") or {}, doc.get("checks") or {}
    for w in doc.get("warnings") or ():
        lines.append(f"  WARNING {w}")
    if dec.get("method") == "adaptive":
        lines.append(f"  every cell within {dec.get('max_vertical_error_mm', 0):.4f} mm of the "
                     f"surface, vertically (tolerance {dec.get('tolerance_mm', 0):g} mm)")
    elif dec.get("method") == "quadric":
        lines.append(f"  quadric decimation of {dec.get('input_triangles')} triangles (every "
                     f"{dec.get('input_step_cells')} cell(s))")
    elif dec.get("note"):
        lines.append(f"  NOTE: {dec['note']}")
    tol = dev.get("tolerance_mm", SURFACE_TOLERANCE_MM)  # the normal uses the same tolerance
    cells, missed = dev.get("cells", 0), dev.get("missed", 0)
    if "max_mm" in dev:
        lines.append(f"  surface vs heightmap: max {dev['max_mm']:.4f} mm, RMS "
                     f"{dev['rms_mm']:.4f} mm, {100 * dev['within_tolerance_fraction']:.2f} % of "
                     f"{cells - missed} cells within {tol:g} mm (vertical)"
                     + (f"; {missed} ray(s) missed the mesh" if missed else ""))
    elif cells:
        lines.append(f"  surface vs heightmap (vertical): all {missed} ray(s) missed the mesh; "
                     "no vertical figures")
    else:
        lines.append("  surface vs heightmap: no cell with data was measured")
    if "normal" in dev:
        n = dev["normal"]
        lines.append(f"  surface vs heightmap along the normal (closest point): max "
                     f"{n['max_mm']:.4f} mm, RMS {n['rms_mm']:.4f} mm, "
                     f"{100 * n['within_tolerance_fraction']:.2f} % of {cells} cells within "
                     f"{tol:g} mm")
    si = chk.get("self_intersection") or {}
    lines.append("  checks (open3d and numpy): edge- and vertex-manifold, orientable, closed, "
                 "outward" + ("; no self-intersection" if si.get("tested") else
                              "; self-intersection not tested (large mesh)"))
    if holes.get("filled_cells"):
        lines.append(f"  NOTE: {holes['filled_cells']} cells without data were filled "
                     f"({holes.get('filled_vertices', 0)} mesh vertices lie on filled cells)")
    lines.append(f"  record: {output}.json")
    return lines
