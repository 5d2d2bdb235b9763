"""``impress compare``: register two impressions (or an impression and an outsole), their signed
difference map, histogram, outlined regions, an optional mean track, a JSON record and an HTML
report, written into one folder."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    from impress_gui.core.compare.difference import DEFAULT_METRIC, METRICS
    from impress_gui.core.compare.record import DEFAULT_THRESHOLD_MM
    from impress_gui.core.compare.register import RegistrationParams
    from impress_gui.core.compare.surfaces import DEFAULT_PLY_PIXEL_MM

    d = RegistrationParams()
    p.add_argument("inputs", type=Path, nargs="+", metavar="INPUT",
                   help="A, then B (and more with --mean): reconstruction folders (impress "
                   "process), .x3p or .ply exports")
    p.add_argument("-o", "--output", type=Path, required=True,
                   help="output folder (made; a previous comparison there is replaced "
                   "atomically)")
    p.add_argument("--pairs", type=Path, default=None,
                   help="JSON file of at least 3 point pairs {\"pairs\": [{\"a\": [x, y], "
                   "\"b\": [x, y]}, ...]} (mm, each input's export frame) for the coarse "
                   "registration (default: automatic)")
    p.add_argument("--mirror", action="store_true",
                   help="mirror B (x -> -x) before registering: an impression against an "
                   "outsole")
    p.add_argument("--invert", action="store_true",
                   help="invert B's heights (z -> -z) before registering: an impression against "
                   "an outsole")
    p.add_argument("--threshold-mm", type=float, default=DEFAULT_THRESHOLD_MM,
                   help=f"outline the regions where |A - B| exceeds this (default "
                   f"{DEFAULT_THRESHOLD_MM:g})")
    p.add_argument("--metric", choices=METRICS, default=DEFAULT_METRIC,
                   help="the difference: 'normal' is the signed distance along A's surface "
                   "normal, as inspection software's deviation maps measure it (a tread wall's "
                   "small lateral misplacement no longer reads as a large difference); "
                   "'vertical' is the height difference A - B along z (default "
                   f"{DEFAULT_METRIC})")
    p.add_argument("--outline-walls", action="store_true",
                   help="outline differences on A's steep walls too (left out by default: one "
                   "cell of lateral misplacement there exceeds the threshold)")
    p.add_argument("--max-distance-mm", type=float, default=d.max_distance_mm,
                   help=f"the final ICP's correspondence distance: farther points are outliers "
                   f"(default {d.max_distance_mm:g})")
    p.add_argument("--sample-mm", type=float, default=d.sample_mm,
                   help=f"spacing of A's points in the ICP (B's: twice it) (default "
                   f"{d.sample_mm:g})")
    p.add_argument("--relief-mm", type=float, default=d.relief_mm,
                   help=f"cells this far from the ground plane are the relief registered "
                   f"(default {d.relief_mm:g})")
    p.add_argument("--ply-grid-mm", type=float, default=DEFAULT_PLY_PIXEL_MM,
                   help=f"grid a PLY point cloud is binned onto (default "
                   f"{DEFAULT_PLY_PIXEL_MM:g})")
    p.add_argument("--mean", action="store_true",
                   help="also the mean track of all the inputs on A's grid (mean.tif, std.tif, "
                   "count.tif)")


def run(args: argparse.Namespace) -> int:
    from impress_gui.commands._progress import progress_printer
    from impress_gui.core.compare.record import CompareParams, load_pairs, write_comparison
    from impress_gui.core.compare.register import RegistrationParams

    pairs = load_pairs(args.pairs) if args.pairs is not None else None
    reg = RegistrationParams(mirror=args.mirror, invert=args.invert, pairs=pairs,
                             relief_mm=args.relief_mm, sample_mm=args.sample_mm,
                             max_distance_mm=args.max_distance_mm)
    params = CompareParams(registration=reg, threshold_mm=args.threshold_mm,
                           outline_walls=args.outline_walls,
                           ply_pixel_mm=args.ply_grid_mm, mean=args.mean,
                           metric=args.metric)
    doc = write_comparison(args.inputs, args.output, params, progress_printer())
    r, d = doc["registration"], doc["difference"]
    print(f"comparison written to {args.output}")
    print(f"  registration: turn {r['rotation_about_z_deg']:.3f} deg, residual RMS "
          f"{r['residual_rms_mm']:.4f} mm, overlap {r['overlap']:.3f}"
          f"{' (B mirrored)' if r['mirror'] else ''}{' (B inverted)' if r['invert'] else ''}")
    what = "along A's normal" if d["metric"] == "normal" else "vertical"
    print(f"  difference A - B ({what}) over {d['overlap_cells']} cells: median "
          f"{d['median_mm']:+.4f} "
          f"mm, 95th percentile of |A - B| {d['p95_abs_mm']:.4f} mm")
    print(f"  {doc['regions']['count']} region(s) beyond {doc['regions']['threshold_mm']:g} mm")
    for k, reg_ in enumerate(doc["regions"]["items"][:5], 1):
        print(f"    {k}. {reg_['area_mm2']:.2f} mm2, deepest {reg_['deepest_mm']:+.3f} mm, "
              f"length {reg_['length_mm']:.2f} mm at ({reg_['centroid_mm'][0]:.1f}, "
              f"{reg_['centroid_mm'][1]:.1f})")
    if "mean_track" in doc:
        m = doc["mean_track"]
        print(f"  mean track of {m['maps']} maps: median standard deviation "
              f"{m['std_median_mm']} mm")
    print(f"  record: {Path(args.output) / 'compare.json'}, report: "
          f"{Path(args.output) / 'report.html'}")
    return 0
