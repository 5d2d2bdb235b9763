"""``impress calibrate``: scene calibration from the L-target corner picks."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    from impress_gui.commands.simulate import _speed

    p.add_argument("video", type=Path, help="scan video (or frame folder)")
    p.add_argument("--intrinsics", type=Path, required=True, help="intrinsics JSON")
    p.add_argument("--picks", type=Path, required=True, help="corner picks JSON")
    p.add_argument("--target", type=Path, default=None,
                   help="target model JSON (default: the IMPREsS L target v1)")
    p.add_argument("--speed", type=_speed, required=True,
                   help="rail speed in mm/s (or slow, medium, fast)")
    p.add_argument("--fps", type=float, default=None, help="frame rate (default: from the video)")
    # scene.DEFAULT_PLANE_FRAMES (not imported here: the parser is built on every start)
    p.add_argument("--plane-frames", type=int, default=45,
                   help="frames used per laser plane around t1/t2 (1 = the seed's single "
                        "frame; at most 300)")
    p.add_argument("--planes", choices=("stripe-fit", "three-point"), default="stripe-fit",
                   help="laser planes: fitted to each stripe on the target's faces (default), "
                        "or the seed's fallback through three stripe points per laser picked "
                        "on target edges (the picks' stripe_points)")
    p.add_argument("-o", "--output", type=Path, required=True, help="calibration JSON to write")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from impress_gui.core.base.fileio import sha256_file
    from impress_gui.core.base.outdir import check_output_file, writing
    from impress_gui.core.calibration.geometry import Intrinsics
    from impress_gui.core.calibration.picks import Picks
    from impress_gui.core.calibration.scene import calibrate_scene
    from impress_gui.core.calibration.target import CORNER_NAMES, TargetModel, default_target
    from impress_gui.core.formats.provenance import calibration_inputs, input_record
    from impress_gui.core.formats.video import open_video

    check_output_file(args.output, inputs=(args.video, args.intrinsics, args.picks, args.target),
                      formats=("impress.calibration",))
    intr = Intrinsics.load(args.intrinsics)
    picks = Picks.load(args.picks)
    target = TargetModel.load(args.target) if args.target else default_target()
    intrinsics = input_record(args.intrinsics, sha256_file(args.intrinsics))
    picks_record = input_record(args.picks, sha256_file(args.picks))
    target_record = {"name": target.name} | (
        input_record(args.target, sha256_file(args.target)) if args.target else {"builtin": True})
    notes = []
    with open_video(args.video, fps=args.fps) as video:
        # the hash of the open file that is decoded (a frame folder: of its manifest)
        video_sha256 = video.sha256()
        inputs = calibration_inputs(input_record(args.video, video_sha256), intrinsics,
                                    picks=picks_record, target=target_record, video_last=True)
        if picks.video_sha256 and picks.video_sha256 != video_sha256:
            notes.append("W-PICKS-OTHER-VIDEO: the picks were made on a different video "
                         "(SHA-256 differs)")
        cal = calibrate_scene(video, intr, target, picks, args.speed, args.fps,
                              plane_frames=args.plane_frames, inputs=inputs,
                              plane_method=args.planes)
        video.check_unchanged()
    if notes:
        import dataclasses

        cal = dataclasses.replace(cal, warnings=tuple(notes) + tuple(cal.warnings))
    with writing(args.output):
        cal.save(args.output)
    vp = cal.vanishing_point_px
    print(f"calibration written to {args.output}")
    print(f"  roll {cal.roll_deg:+.4f} deg, tilt {cal.tilt_deg:+.4f} deg, turn about the motion "
          f"axis {cal.cross_tilt_deg:+.4f} deg (the map levelled across the scan); vanishing point "
          + (f"({vp[0]:.1f}, {vp[1]:.1f}) px" if vp[2] else "at infinity"))
    print(f"  reprojection RMS of the 12 picks: {cal.reprojection_rms_px:.3f} px")
    print("  corner residuals (mm): " + ", ".join(
        f"{c} {r:.3f}" for c, r in zip(CORNER_NAMES, cal.corner_residuals_mm)))
    print(f"  speed entered {cal.speed_mm_s:.4f} mm/s, implied by the target "
          f"{cal.implied_speed_mm_s:.4f} mm/s")
    for name, f in cal.planes.items():
        n = f.plane.normal
        if f.method == "three-point":
            how = (f"three points (L, M, N) in frame {f.frames[0]}, rays missing their edges "
                   f"by {f.rms_mm:.4f} mm RMS")
        else:
            how = f"RMS {f.rms_mm:.4f} mm over {f.n_points} points in {len(f.frames)} frames"
        print(f"  {name} plane: normal ({n[0]:+.5f}, {n[1]:+.5f}, {n[2]:+.5f}), offset "
              f"{f.plane.offset_mm:.3f} mm, {how}")
    for w in cal.warnings:
        print(f"  WARNING: {w}")
    return 0 if np.all(np.isfinite(cal.corner_residuals_mm)) else 1
