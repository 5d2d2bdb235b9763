"""``impress calibrate-camera``: camera intrinsics from a checkerboard video or image folder.

Example::

    impress calibrate-camera board.MTS --board 9x6 --square-mm 25 -o intrinsics.json
    impress calibrate-camera board.MTS --readout-from-flicker lamp.MTS --flicker-hz 100
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from impress_gui.core.base import codes


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("input", type=Path,
                   help="checkerboard video (.mp4, .mov, .mts, ...) or a folder of images")
    p.add_argument("--board", default="9x6",
                   help="inner corners COLSxROWS, as OpenCV counts them: a board of 10 x 7 "
                   "squares is 9x6 (default 9x6)")
    p.add_argument("--square-mm", type=float, default=25.0,
                   help="side of one square in mm, measured on the print (default 25)")
    p.add_argument("-o", "--output", type=Path, default=Path("intrinsics.json"),
                   help="intrinsics file to write (default intrinsics.json)")
    p.add_argument("--max-frames", type=int, default=80,
                   help="frames of a video examined, evenly spread (default 80)")
    p.add_argument("--min-boards", type=int, default=8,
                   help="fewest distinct board views accepted (default 8)")
    p.add_argument("--k3", action="store_true",
                   help="also fit the third radial coefficient k3 (default: k3 = 0)")
    p.add_argument("--fps", type=float, default=None,
                   help="frame rate of an image folder (only used in messages)")
    p.add_argument("--readout-ms", type=float, default=None, metavar="MS",
                   help="record the camera's rolling-shutter readout, the time from the first "
                   "image row's exposure to the last (ms; from the camera's data sheet or "
                   "measured; 0: a global shutter); the scene calibration and the "
                   "reconstruction place each row where the camera was when it was exposed. "
                   "Not given: the scene calibration estimates it from the corner picks")
    p.add_argument("--readout-from-flicker", type=Path, default=None, metavar="VIDEO",
                   help="measure the readout from a video, in the scans' recording mode, of a "
                   "plain light surface lit only by a mains lamp (short exposure): the "
                   "rolling shutter draws the lamp's flicker as bands whose spacing gives it "
                   "(needs --flicker-hz; docs/camera-calibration.md)")
    p.add_argument("--flicker-hz", type=float, default=None, metavar="HZ",
                   help="the lamp's flicker: twice the mains frequency, 100 on 50 Hz mains, "
                   "120 on 60 Hz")
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def run(args: argparse.Namespace) -> int:
    import math

    from impress_gui.commands._progress import progress_printer
    from impress_gui.core.base.errors import InputError
    from impress_gui.core.calibration.geometry import MAX_READOUT_MS
    from impress_gui.core.calibration.intrinsics import parse_board, run_camera_calibration
    from impress_gui.core.formats.video import open_video

    if args.readout_ms is not None and not (math.isfinite(args.readout_ms)
                                            and 0.0 <= args.readout_ms <= MAX_READOUT_MS):
        raise InputError(f"--readout-ms must be between 0 (a global shutter) and "
                         f"{MAX_READOUT_MS:g} ms", code=codes.E_VALUE)
    if args.readout_from_flicker is not None and args.readout_ms is not None:
        raise InputError("give the readout (--readout-ms) or a video to measure it from "
                         "(--readout-from-flicker), not both", code=codes.E_VALUE)
    if (args.readout_from_flicker is None) != (args.flicker_hz is None):
        raise InputError("--readout-from-flicker and --flicker-hz go together: the video of "
                         "the flickering lamp and its flicker (100 Hz on 50 Hz mains, 120 Hz "
                         "on 60 Hz)", code=codes.E_VALUE)
    if (args.readout_from_flicker is not None
            and args.readout_from_flicker.resolve() == args.input.resolve()):
        raise InputError("the lamp video (--readout-from-flicker) is the checkerboard video: "
                         "film the flickering lamp apart", code=codes.E_VALUE)
    board = parse_board(args.board)
    if args.max_frames < 3:
        raise InputError("--max-frames must be at least 3", code=codes.E_BOARD)
    if args.output.suffix.lower() != ".json":
        raise InputError(f"--output {args.output}: the intrinsics file must end in .json",
                         code=codes.E_OUTPUT)
    from impress_gui.core.base.outdir import check_output_file

    flicker_inputs = () if args.readout_from_flicker is None else (args.readout_from_flicker,)
    check_output_file(args.output, inputs=(args.input, *flicker_inputs),
                      formats=("impress.intrinsics",))
    progress = progress_printer(2, quiet=args.quiet)
    flicker = None
    t0 = time.perf_counter()
    with open_video(args.input, args.fps) as video:
        if args.readout_from_flicker is not None:  # the cheaper refusals before the board's
            from impress_gui.core.calibration.readout import measure_readout_file

            flicker, flicker_source = measure_readout_file(
                args.readout_from_flicker, args.flicker_hz, size=tuple(video.size))
        res = run_camera_calibration(video, board, args.square_mm, progress,
                                     min_boards=args.min_boards, max_frames=args.max_frames,
                                     fix_k3=not args.k3)
    intr = res.intrinsics
    if flicker is not None:
        import dataclasses

        intr = dataclasses.replace(intr, readout_ms=round(flicker.readout_ms, 3),
                                   source=f"{intr.source}; {flicker_source}")
    elif args.readout_ms is not None:
        import dataclasses

        intr = dataclasses.replace(intr, readout_ms=args.readout_ms)
    intr.save(args.output)
    w, h = intr.image_size
    k1, k2, p1, p2, k3 = intr.dist_coeffs[:5]
    print(f"camera intrinsics from {res.boards_found} board views in {res.frames_examined} "
          f"frames ({time.perf_counter() - t0:.1f} s), image {w}x{h}")
    print(f"  focal length     fx = {intr.fx:.2f} px, fy = {intr.fy:.2f} px")
    print(f"  principal point  cx = {intr.cx:.2f} px, cy = {intr.cy:.2f} px")
    print(f"  distortion       k1 = {k1:.5f}, k2 = {k2:.5f}, p1 = {p1:.6f}, p2 = {p2:.6f}, "
          f"k3 = {k3:.5f}")
    print(f"  RMS reprojection error {intr.rms_px:.3f} px over {len(res.views)} views "
          f"(worst view {max(res.view_rms_px):.3f} px)")
    if res.rejected_frames:
        print(f"  dropped as outliers: frames {', '.join(map(str, res.rejected_frames))}")
    print(f"  frames used: {', '.join(map(str, intr.frames_used))}")
    print(f"  rolling shutter  readout {intr.readout_ms:g} ms" if intr.readout_ms else
          "  shutter          global (--readout-ms 0)" if intr.readout_ms == 0 else
          "  shutter          not given (--readout-ms): the scene calibration estimates a "
          "rolling shutter's readout from the picks")
    if flicker is not None:
        print(f"  measured from {args.readout_from_flicker.name}: {flicker.summary()}")
    print(f"wrote {args.output}")
    return 0
