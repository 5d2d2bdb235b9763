"""``impress process``: reconstruct heightmaps, texture and point cloud from a scan video."""

from __future__ import annotations

import argparse
from pathlib import Path


def _frames(text: str) -> tuple[int | None, int | None]:
    try:
        a, b = text.split(":")
        return (int(a) if a else None, int(b) if b else None)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not START:STOP (e.g. 30:900)") from None


def _roi(text: str) -> tuple[str, int, int]:
    try:
        name, rng = text.split("=")
        a, b = rng.split(":")
        return name, int(a), int(b)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not LASER=FIRST:STOP rows") from None


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("video", type=Path, help="scan video (MP4/MOV/MTS/M2TS) or frame folder")
    p.add_argument("--calibration", type=Path, required=True, help="scene calibration JSON")
    p.add_argument("-o", "--output", type=Path, required=True,
                   help="output folder (replaced atomically when the run completes)")
    p.add_argument("--method", choices=["combined", "hue", "lut"], default="combined",
                   help="stripe detection method (default combined)")
    p.add_argument("--frames", type=_frames, default=(None, None),
                   help="frame range START:STOP (default: skip 0.5 s at each end)")
    p.add_argument("--grid-mm", type=float, default=0.1, help="grid resolution (default 0.1)")
    p.add_argument("--roi", type=_roi, action="append", default=[],
                   help="region of interest rows, e.g. green=600:800 (default automatic)")
    p.add_argument("--min-peak", type=float, default=25.0,
                   help="minimum stripe peak above background, grey levels of luma (light of "
                   "the laser's colour counts down to 0.2 of it)")
    p.add_argument("--weak-run-ratio", type=float, default=0.5,
                   help="drop short stripe pieces weaker than this share of the frame's stripe, "
                   "unless they continue a longer piece across gaps of a few columns (0 keeps "
                   "every piece; default 0.5)")
    p.add_argument("--subpixel", choices=("half-max", "window"), default="window",
                   help="the stripe centre's sub-pixel estimate: 'window' (default: the centre "
                   "of mass above half maximum refined in a window, far less locked to the "
                   "pixel grid) or 'half-max' (that first centre; see docs/accuracy.md)")
    p.add_argument("--island-cells", type=int, default=50,
                   help="drop islands of at most this many cells of a laser's map, cut off from "
                   "their surroundings by steps over --island-step-mm or by cells without data "
                   "(a false stripe's heights floating off the surface; 0 keeps them; default 50)")
    p.add_argument("--island-step-mm", type=float, default=0.5,
                   help="the step that separates an island from its surroundings (default 0.5)")
    p.add_argument("--floating-cells", type=int, default=400,
                   help="drop pieces of at most this many cells of a laser's map (joined as "
                   "islands are) around which, within 2 mm, at most 15 %% of the cells hold data "
                   "of either laser (a detector's guess in a laser's shadow; 0 keeps them; "
                   "default 400)")
    p.add_argument("--unlit-soil", action=argparse.BooleanOptionalAction, default=True,
                   help="subtract the soil under each stripe, as earlier frames saw it unlit, "
                   "before its centre is estimated: dim stripes on grainy soil (on by "
                   "default; --no-unlit-soil leaves the stripe's profile as the frame shows "
                   "it; see docs/accuracy.md, 'Dim stripes on grainy soil')")
    p.add_argument("--reconcile-lasers", action=argparse.BooleanOptionalAction, default=True,
                   help="share the part of the two lasers' difference that runs across the "
                   "map between their maps, so that the scan's ends one laser saw alone read "
                   "what the pair reads (on by default; --no-reconcile-lasers keeps each "
                   "laser's map as its calibrated plane makes it; see docs/measuring-guide.md)")
    p.add_argument("--no-texture", action="store_true", help="skip the texture")
    p.add_argument("--fps", type=float, default=None, help="override the frame rate")


def run(args: argparse.Namespace) -> int:
    from impress_gui.commands._progress import progress_printer
    from impress_gui.core.reconstruction.reconstruct import ProcessParams

    rois = {name: (a, b) for name, a, b in args.roi}
    params = ProcessParams(method=args.method, frame_start=args.frames[0],
                           frame_stop=args.frames[1], grid_mm=args.grid_mm, rois=rois,
                           min_peak=args.min_peak, weak_run_ratio=args.weak_run_ratio,
                           texture=not args.no_texture, subpixel=args.subpixel,
                           island_max_cells=args.island_cells,
                           island_step_mm=args.island_step_mm,
                           floating_max_cells=args.floating_cells,
                           unlit_soil=args.unlit_soil,
                           reconcile_lasers=args.reconcile_lasers)
    progress = progress_printer()

    from impress_gui.core.reconstruction.pipeline import process_files

    meta = process_files(args.video, args.calibration, args.output, params, args.fps, progress)
    st = meta["stats"]
    print(f"reconstruction written to {args.output}")
    print(f"  frames {meta['frames']['start']}..{meta['frames']['stop'] - 1}, grid "
          f"{meta['grid']['shape'][1]} x {meta['grid']['shape'][0]} cells of "
          f"{meta['grid']['pixel_mm']} mm; {meta['run']['timings']['frames_per_second']} frames/s")
    print(f"  cells with data: fused {st['cells_fused']}, green {st['cells_green']}, "
          f"red {st['cells_red']}")
    isl = st.get("island_cells_dropped") or {}
    if any(isl.values()):
        print("  small islands dropped (cells): " + ", ".join(f"{k} {v}" for k, v in isl.items()))
    sh = st.get("stripe_columns_other_laser_dropped") or {}
    if any(sh.values()):
        print("  stripe columns on the other laser's light dropped: "
              + ", ".join(f"{k} {v}" for k, v in sh.items()))
    fl = st.get("floating_cells_dropped") or {}
    if any(fl.values()):
        print("  floating pieces dropped (cells): "
              + ", ".join(f"{k} {v}" for k, v in fl.items()))
    ov = st.get("overreach_cells_dropped") or {}
    if any(ov.values()):
        print("  cells reaching past an edge dropped: "
              + ", ".join(f"{k} {v}" for k, v in ov.items()))
    for w in meta["warnings"]:
        print(f"  WARNING: {w}")
    return 0
