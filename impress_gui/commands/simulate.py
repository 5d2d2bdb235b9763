"""``impress simulate``: render a scan video with exact ground truth."""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path

from impress_gui.core.base import codes


def _speed(text: str) -> float:
    from impress_gui.sim.simulate import SPEED_NAMES

    if text in SPEED_NAMES:
        return SPEED_NAMES[text]
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a speed: give mm/s or one of slow, medium, fast") from None
    if not (math.isfinite(value) and 0.01 <= value <= 1000.0):
        raise argparse.ArgumentTypeError(
            f"{text!r} is not a possible rail speed (0.01 to 1000 mm/s)")
    return value


def _resolution(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not WIDTHxHEIGHT, e.g. 640x360") from None
    return w, h


def _floats(text: str, n: int) -> tuple[float, ...]:
    import math

    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not {n} numbers separated by commas") \
            from None
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"{text!r} is not {n} finite numbers")
    return values


def _pair(text: str) -> tuple[float, ...]:
    return _floats(text, 2)


def _triple(text: str) -> tuple[float, ...]:
    return _floats(text, 3)


def _shoe_options(args: argparse.Namespace) -> dict:
    shoe: dict = {}
    if args.shoe_rotate is not None or args.shoe_shift_mm is not None:
        sx, sy = args.shoe_shift_mm or (0.0, 0.0)
        shoe["pose"] = {"rotate_deg": float(args.shoe_rotate or 0.0), "shift_x_mm": sx,
                        "shift_y_mm": sy}
    if args.cut_at is not None:
        x, y, a = args.cut_at
        shoe["cut"] = {"x_mm": x, "y_mm": y, "angle_deg": a}
    elif args.cut:
        shoe["cut"] = {}
    if args.sole_seed is not None:
        shoe["sole_seed"] = args.sole_seed
    return shoe


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("out", type=Path, help="output folder (created; existing files are replaced)")
    p.add_argument("--preset", default="shoe",
                   choices=["shoe", "tire", "blocks", "flat", "spheres", "letter"],
                   help="scene: shoe impression, tire track, the thesis' accuracy blocks, a flat "
                   "plane, spheres or a raised letter F (chiral: shows a mirrored export) (default: shoe)")
    p.add_argument("--length-mm", type=float, default=None,
                   help="travel of the camera along the rail in mm (default per preset: shoe "
                   "480, tire 1750, blocks 480, flat 260, spheres 300)")
    p.add_argument("--speed", type=_speed, default=13.138,
                   help="rail speed in mm/s or slow (1.3138), medium (5.2552), fast (13.138; "
                   "default)")
    p.add_argument("--fps", type=float, default=30.0, help="frame rate (default 30)")
    p.add_argument("--resolution", type=_resolution, default=(1920, 1080),
                   help="WIDTHxHEIGHT (default 1920x1080, the camcorder's; 640x360 renders "
                   "about 7x faster for quick trials)")
    p.add_argument("--roll", type=float, default=1.2,
                   help="camera roll misalignment, degrees (default 1.2)")
    p.add_argument("--tilt", type=float, default=-1.8,
                   help="camera tilt misalignment, degrees (default -1.8)")
    p.add_argument("--standoff-mm", type=float, default=300.0,
                   help="height of the camera above the ground (default 300)")
    p.add_argument("--seed", type=int, default=1,
                   help="random seed 0..2^32-1 (default 1; same seed, same frames)")
    p.add_argument("--format", dest="video_format", default="mp4",
                   choices=["mp4", "mov", "mts", "frames"],
                   help="H.264 in MP4/MOV, AVCHD-like MPEG-TS (.mts), or a PNG frame folder "
                   "(default mp4)")
    p.add_argument("--bitrate-mbit", type=float, default=None,
                   help="H.264 bitrate (default 22 Mbit/s scaled by frame area)")
    p.add_argument("--speckle", type=float, default=0.3,
                   help="laser speckle contrast 0..1 (default 0.3)")
    p.add_argument("--noise", type=float, default=2.0,
                   help="sensor noise, grey levels (SD; default 2)")
    p.add_argument("--grid-mm", type=float, default=0.1,
                   help="scene grid (truth) spacing in mm (default 0.1)")
    p.add_argument("--click-noise-px", type=float, default=0.0,
                   help="add Gaussian noise of this SD to the written corner picks")
    p.add_argument("--readout-ms", type=float, default=0.0, metavar="MS",
                   help="a rolling shutter: the time from the first image row's exposure to "
                   "the last's, ms (0, the default: a global shutter; a CMOS camcorder reads "
                   "its rows over most of a frame interval, e.g. 20-30 ms at 30 frames/s); "
                   "recorded in truth.json")
    p.add_argument("--stripe-follows-soil", action="store_true",
                   help="draw each pixel of a laser stripe with the albedo of the soil it "
                   "sees, as a real surface reflects it (default: each column's stripe scaled "
                   "by the albedo at its centre, as renders before 6 December 2026); recorded "
                   "in truth.json")
    p.add_argument("--lamp-video", type=float, default=None, metavar="HZ",
                   help="also film a plain card under a lamp flickering at HZ (100 on 50 Hz "
                   "mains, 120 on 60 Hz) with this camera: lamp.mp4, the input of impress "
                   "calibrate-camera --readout-from-flicker (bands only with --readout-ms)")
    p.add_argument("--target-yaw", type=float, default=3.0,
                   help="rotation of the L target on the ground, degrees (default 3)")
    g = p.add_argument_group("blocks preset placements (thesis section 4.2)")
    g.add_argument("--order", choices=["AB", "BA"], default=None, help="plate order along the scan")
    g.add_argument("--rotate90", action="store_true", help="plates rotated 90 degrees")
    g.add_argument("--lift-b-mm", type=float, default=None, help="lift plate B (thesis: 40 mm)")
    g.add_argument("--tilt-plates", type=float, default=None, help="tilt both plates (thesis: 5)")
    g = p.add_argument_group("shoe preset: the shoe's pose and a cut (comparison tests)")
    g.add_argument("--shoe-rotate", type=float, default=None, metavar="DEG",
                   help="turn the shoe about the vertical through its centre, degrees (+ turns "
                   "rail X towards rail Y)")
    g.add_argument("--shoe-shift-mm", type=_pair, default=None, metavar="X,Y",
                   help="shift the shoe by X,Y mm in the rail frame (after the turn)")
    g.add_argument("--cut", action="store_true",
                   help="give the sole a cut: a groove 0.5 mm deep, 3 mm long, 0.6 mm wide "
                   "(soil fills it: a ridge in the impression), in the shoe's own frame")
    g.add_argument("--cut-at", type=_triple, default=None, metavar="X,Y,ANGLE",
                   help="the cut's centre (mm, the shoe's own frame) and direction (deg); "
                   "implies --cut (default 15,230,30)")
    g.add_argument("--sole-seed", type=int, default=None, metavar="SEED",
                   help="draw the sole's random nicks from SEED (default: from --seed), so that "
                   "scans with different --seed show the same shoe")
    p.add_argument("--random-rig", type=int, default=None, metavar="SEED",
                   help="draw the rig, lens, lasers, L target (written as target.json), "
                   "scene, soil, motion, noise and bitrate from SEED over the documented "
                   "family (docs/accuracy.md, Random rigs), every drawn value recorded in "
                   "truth.json's random_rig section; only --resolution, --format, --grid-mm, "
                   "--click-noise-px, --readout-ms, --stripe-follows-soil and --workers still apply")
    p.add_argument("--workers", type=int, default=None,
                   help="render processes (default: 1 for short clips, else up to 2)")


def run(args: argparse.Namespace) -> int:
    from impress_gui.core.base.errors import InputError
    from impress_gui.sim.simulate import SimConfig

    blocks = {}
    if args.order:
        blocks["order"] = args.order
    if args.rotate90:
        blocks["rotate90"] = True
    if args.lift_b_mm is not None:
        blocks["lift_b_mm"] = args.lift_b_mm
    if args.tilt_plates is not None:
        blocks["tilt_deg"] = args.tilt_plates
    if args.random_rig is not None:
        if not 0 <= args.random_rig < 2**32:
            raise InputError("--random-rig must be between 0 and 4294967295",
                             code=codes.E_SIM_OPTION)
        if blocks or _shoe_options(args):
            raise InputError("placement options (--rotate90, --shoe-rotate, --cut, --sole-seed, "
                             "...) do not "
                             "go with --random-rig", code=codes.E_SIM_OPTION)
        w, h = args.resolution
        if not (64 <= w <= 4096 and 36 <= h <= 2304) or w % 2 or h % 2:
            raise InputError("--resolution must be between 64x36 and 4096x2304, even width "
                             "and height", code=codes.E_SIM_OPTION)
        cfg = SimConfig.random(args.random_rig, w, h, args.video_format, args.grid_mm,
                               args.click_noise_px, args.readout_ms,
                               args.stripe_follows_soil)
    else:
        cfg = _preset_config(args, blocks)
    return _run(args, cfg)


def _preset_config(args: argparse.Namespace, blocks: dict):
    from impress_gui.sim.simulate import SimConfig

    return SimConfig(preset=args.preset, length_mm=args.length_mm, speed_mm_s=args.speed,
                    fps=args.fps, width=args.resolution[0], height=args.resolution[1],
                    roll_deg=args.roll, tilt_deg=args.tilt, standoff_mm=args.standoff_mm,
                    seed=args.seed, video_format=args.video_format,
                    bitrate_mbit=args.bitrate_mbit, speckle=args.speckle, noise_dn=args.noise,
                    grid_mm=args.grid_mm, click_noise_px=args.click_noise_px,
                    target_yaw_deg=args.target_yaw, blocks=blocks, shoe=_shoe_options(args),
                    readout_ms=args.readout_ms, stripe_follows_soil=args.stripe_follows_soil)


#: the most render processes ``--workers`` starts (each holds the scene; more than the
#: machine's cores only slows it)
MAX_WORKERS = 64


def _run(args: argparse.Namespace, cfg) -> int:
    from impress_gui.commands._progress import progress_printer
    from impress_gui.core.base.errors import InputError
    from impress_gui.sim.simulate import make_motion, simulate

    cfg.validate()
    if args.lamp_video is not None and not (math.isfinite(args.lamp_video)
                                            and 20.0 <= args.lamp_video <= 1000.0):
        raise InputError("--lamp-video: give the lamp's flicker in Hz (100 or 120)",
                         code=codes.E_SIM_OPTION)
    n = make_motion(cfg).frame_count
    workers = (args.workers if args.workers is not None
               else (1 if n < 300 else min(2, os.cpu_count() or 1)))
    if not 1 <= workers <= MAX_WORKERS:
        raise InputError(f"--workers {workers}: give 1 to {MAX_WORKERS} render processes",
                         code=codes.E_SIM_OPTION)
    progress = progress_printer()

    t0 = time.perf_counter()
    res = simulate(cfg, args.out, workers=workers, progress=progress)
    dt = time.perf_counter() - t0
    what = cfg.preset if cfg.random_rig is None else f"random rig {cfg.random_rig} ({cfg.preset})"
    print(f"simulated {what}: {res['frames']} frames of {cfg.width}x{cfg.height} in "
          f"{dt:.1f} s ({res['frames'] / dt:.1f} frames/s)")
    print(f"  video:       {res['video']}")
    print(f"  calibration frames: t1 = {res['t1']} (green on target), t2 = {res['t2']} (red)")
    for name in ("intrinsics.json", "target.json", "picks.json", "truth.json",
                 "truth_height.tif", "truth_texture.png"):
        print(f"  {name:<18s} {Path(args.out) / name}")
    if args.lamp_video is not None:
        from impress_gui.sim.lamp import write_lamp_video

        lamp = write_lamp_video(Path(args.out) / "lamp.mp4", cfg.width, cfg.height, cfg.fps,
                                cfg.readout_ms, args.lamp_video, seed=cfg.seed)
        print(f"  {'lamp.mp4':<18s} {lamp} (a card under a {args.lamp_video:g} Hz flicker)")
    return 0
