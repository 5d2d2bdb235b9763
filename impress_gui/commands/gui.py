"""``impress gui [PROJECT_OR_VIDEO]`` (and plain ``impress``): open the workstation window."""

from __future__ import annotations

import argparse
from pathlib import Path

from impress_gui.core.base import codes


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not WIDTHxHEIGHT, e.g. 1920x1080") from None
    if not (320 <= w <= 10000 and 240 <= h <= 10000):
        raise argparse.ArgumentTypeError(f"{text!r} is not a sensible window size")
    return w, h


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "path",
        nargs="?",
        type=Path,
        default=None,
        help="a project folder (or its project.json), or a scan video to start a new project with",
    )
    p.add_argument(
        "--screenshot",
        type=Path,
        default=None,
        metavar="PNG",
        help="save a picture of the window once it has opened the path (a .png file; "
        "an existing file is replaced only if it is a PNG picture, and never inside the "
        "opened path)",
    )
    p.add_argument(
        "--quit-after",
        type=float,
        nargs="?",
        const=1.0,
        default=None,
        metavar="SECONDS",
        help="close the window this many seconds after start-up (default 1; after "
        "the screenshot). With QT_QPA_PLATFORM=offscreen no display is needed.",
    )
    p.add_argument(
        "--size",
        type=_size,
        default=None,
        metavar="WxH",
        help="window size (default: as the window was last closed; the first time "
        "1920x1080, or the whole free area of a smaller screen)",
    )
    p.add_argument(
        "--settings",
        type=Path,
        default=None,
        help="settings file (INI) instead of the user's configuration",
    )
    p.add_argument("--no-motor", action="store_true", help="no motor panel")
    p.add_argument("--tab", choices=["calibration", "processing", "viewer"], default=None,
                   help="the tab to show first")
    p.add_argument(
        "--check",
        action="store_true",
        help="open PATH, wait until it has loaded (with the reconstruction shown in the "
        "viewer when the project has one), take the --screenshot if asked, and close: exit "
        "status 0 if everything opened, 1 with the reasons on stderr if anything failed or "
        "an error message was shown (for smoke tests; with QT_QPA_PLATFORM=offscreen no "
        "display is needed; without --settings it runs on a copy of the user's settings, "
        "which it leaves as they were)",
    )
    p.add_argument(
        "--check-timeout",
        type=float,
        default=120.0,
        metavar="SECONDS",
        help="with --check: fail if loading takes longer than this (default 120)",
    )


PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def check_screenshot(shot: Path, opened: Path | None) -> Path:
    """Where ``--screenshot`` may write (before the window opens): a ``.png`` name, not the
    opened path nor inside it, not a link or folder; an existing file is replaced only when it
    is a PNG picture (an earlier screenshot), never a video, a document or a result."""
    from impress_gui.core.base.errors import InputError
    from impress_gui.core.base.outdir import check_output_file

    if shot.suffix.lower() != ".png":
        raise InputError(f"--screenshot {shot}: name a .png file for the picture",
                         code=codes.E_USAGE)
    inputs = () if opened is None else (opened,)
    real = check_output_file(shot, inputs=inputs, formats=None)
    if real.is_file():
        try:
            with open(real, "rb") as fh:
                head = fh.read(len(PNG_MAGIC))
        except OSError:
            head = b""
        if head != PNG_MAGIC:
            return check_output_file(shot, inputs=inputs, formats=())  # raises E-OUTPUT-EXISTS
    return real


def run(args: argparse.Namespace) -> int:
    from impress_gui.ui.app import run_gui

    path = getattr(args, "path", None)
    if path is not None and not path.exists():
        from impress_gui.core.base.errors import InputError

        raise InputError(f"{path}: no such project folder or video", code=codes.E_FILE_MISSING)
    if args.screenshot is not None:
        check_screenshot(args.screenshot, path)
    extra = {}
    if getattr(args, "check", False):
        extra = {"check": True, "check_timeout_s": args.check_timeout}
    return run_gui(
        path,
        screenshot=args.screenshot,
        quit_after_s=args.quit_after,
        size=args.size,
        settings_path=args.settings,
        with_motor=not args.no_motor,
        tab=args.tab,
        **extra,
    )
