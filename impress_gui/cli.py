"""The ``impress`` console command.

Subcommands are registered by name with the module that implements them; a module is
imported only when its subcommand runs (or its ``--help`` is asked for), so ``impress --help``
never loads Qt, open3d or the video stack. Each command module provides
``add_arguments(parser)`` and ``run(args) -> int``.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from impress_gui import __version__

#: name -> (module implementing it, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "gui": ("impress_gui.commands.gui", "open the workstation window (the default)"),
    "simulate": ("impress_gui.commands.simulate", "render a scan video with exact ground truth"),
    "calibrate-camera": (
        "impress_gui.commands.calibrate_camera",
        "camera intrinsics from checkerboard views",
    ),
    "calibrate": ("impress_gui.commands.calibrate", "scene calibration from the L-target picks"),
    "process": ("impress_gui.commands.process", "reconstruct heightmap, texture and point cloud"),
    "motor": ("impress_gui.commands.motor", "drive the Cool Muscle rail motor (or its emulator)"),
    "demo": ("impress_gui.commands.demo", "make (or reuse) the cached sample scan and process it"),
    "validate": ("impress_gui.commands.validate", "accuracy validation (thesis table 4.1) and report"),
}


def _load(name: str):
    module_name, _ = COMMANDS[name]
    return importlib.import_module(module_name)


def build_parser(selected: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="impress",
        description="IMPREsS workstation: 3D scanning of forensic footwear and tire-track "
        "impressions. Without a subcommand, opens the workstation window.",
    )
    parser.add_argument("--version", action="version", version=f"impress {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (_, help_text) in COMMANDS.items():
        sp = sub.add_parser(name, help=help_text, description=help_text)
        if name == selected:
            _load(name).add_arguments(sp)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in COMMANDS:
        command = argv[0]
    elif argv and argv[0] in ("-h", "--help", "--version"):
        build_parser().parse_args(argv)  # prints and exits
        return 0
    else:
        # no subcommand: the GUI, with everything given as its arguments (`impress PROJECT`)
        command, argv = "gui", ["gui", *argv]
    args = build_parser(command).parse_args(argv)
    from impress_gui.core.errors import ImpressError

    try:
        return int(_load(command).run(args) or 0)
    except ImpressError as exc:
        print(f"impress {command}: error [{exc.code}]: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"impress {command}: interrupted", file=sys.stderr)
        return 130
