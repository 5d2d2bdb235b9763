"""The ``impress`` console command.

Subcommands are registered by name with the module that implements them; a module is
imported only when its subcommand runs (or its ``--help`` is asked for), so ``impress --help``
never loads Qt, open3d or the video stack. Each command module provides
``add_arguments(parser)`` and ``run(args) -> int``.
"""

from __future__ import annotations

import sys

try:  # Ctrl-C this early (the console script importing this module) is an interruption too
    import argparse
    import importlib
    import signal

    from impress_gui import __version__
    from impress_gui.core.base import codes
except KeyboardInterrupt:
    sys.stderr.write("impress: interrupted\n")
    raise SystemExit(130) from None

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
    "batch": ("impress_gui.commands.batch", "process the scans of a manifest, locally or on Dask"),
    "motor": ("impress_gui.commands.motor", "drive the Cool Muscle rail motor (or its emulator)"),
    "demo": ("impress_gui.commands.demo", "make (or reuse) the cached sample scan and process it"),
    "validate": ("impress_gui.commands.validate", "accuracy validation (thesis table 4.1) and report"),
    "cast": ("impress_gui.commands.cast", "a watertight mesh (STL/PLY/OBJ) of an impression to print"),
    "compare": ("impress_gui.commands.compare", "register two impressions, their difference map and report"),
}


def _load(name: str):
    module_name, _ = COMMANDS[name]
    return importlib.import_module(module_name)


USAGE = codes.E_USAGE  # a wrong command line (argparse's exit status 2)
IO = codes.E_IO  # an unforeseen failure to read or write a file
MEMORY = codes.E_MEMORY
INTERNAL = codes.E_INTERNAL


def finite_float(text: str) -> float:
    """argparse type: a finite decimal number (no nan, inf or overflow)."""
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def _finite_floats(parser: argparse.ArgumentParser) -> None:
    """Every ``type=float`` option of ``parser`` and its subparsers takes finite numbers only."""
    for action in parser._actions:
        if action.type is float:
            action.type = finite_float
        if isinstance(action, argparse._SubParsersAction):
            for sp in action.choices.values():
                _finite_floats(sp)


class _Parser(argparse.ArgumentParser):
    """Usage errors carry the code ``E-USAGE`` (exit status 2, as argparse's own)."""

    def error(self, message: str):
        self.print_usage(sys.stderr)
        self.exit(2, f"{self.prog}: error [{USAGE}]: {message}\n")


def build_parser(selected: str | None = None) -> argparse.ArgumentParser:
    parser = _Parser(
        prog="impress",
        description="IMPREsS workstation: 3D scanning of forensic footwear and tire-track "
        "impressions. Without a subcommand, opens the workstation window.",
    )
    parser.add_argument("--version", action="version", version=f"impress {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, (_, help_text) in COMMANDS.items():
        sp = sub.add_parser(name, help=help_text, description=help_text)
        if name == selected:
            _load(name).add_arguments(sp)
            _finite_floats(sp)
    return parser


def _unknown_command(word: str) -> int:
    import difflib

    close = difflib.get_close_matches(word, list(COMMANDS), n=1, cutoff=0.5)
    hint = f" Did you mean 'impress {close[0]}'?" if close else ""
    print(f"impress: error [{USAGE}]: '{word}' is not a command.{hint} "
          f"The commands are: {', '.join(COMMANDS)} (impress --help).", file=sys.stderr)
    return 2


def _looks_like_command(word: str) -> bool:
    """A first argument that is neither an option nor an existing path: a (mistyped) command
    (``impress PROJECT`` opens the window on a project folder or file)."""
    import os

    return not word.startswith("-") and not os.path.exists(word) and "/" not in word \
        and "." not in word


#: set when Ctrl-C (SIGINT) arrives while the command starts (see :func:`_watch_interrupts`)
_interrupted = False


class Terminated(KeyboardInterrupt):
    """A terminate signal (SIGTERM, or SIGHUP: the terminal closed) ended the command: raised
    in the main thread as Ctrl-C's KeyboardInterrupt is, so that everything an interruption
    cleans up - the output folder being written, a batch's workers - is cleaned up as well."""

    def __init__(self, signum: int) -> None:
        self.signum = int(signum)
        self.name = signal.Signals(self.signum).name
        super().__init__(self.name)


#: after a terminate signal, the longest the command may take to clean up (s): the clean-up
#: waits for the files being written to finish (a few seconds); past this it is stuck (a lock
#: the signal's exception left held, a worker that never returns) and the process removes its
#: half-written files itself and exits (:func:`_force_exit_after`)
TERMINATE_GRACE_S = 60.0

_watchdog_started = False


def _force_exit_after(grace_s: float, signum: int) -> None:
    """In its own thread: if the process is still running ``grace_s`` after a terminate
    signal, remove every half-written file and folder it has open and exit with 128 + the
    signal's number, without Python's clean-up (which is what hangs)."""
    import os
    import time

    from impress_gui.core.base import workfiles

    time.sleep(grace_s)
    workfiles.remove_all()
    name = signal.Signals(signum).name
    try:
        sys.stderr.write(f"impress: stopped by {name}; the clean-up did not finish within "
                         f"{grace_s:.0f} s, so the half-written output was removed and the "
                         "command ended\n")
        sys.stderr.flush()
    finally:
        os._exit(128 + signum)


def _on_terminate(signum, frame) -> None:
    """Raise :class:`Terminated` in the main thread (the clean-up of Ctrl-C follows), and make
    sure the command ends even when that clean-up cannot: a watchdog thread forces the exit
    :data:`TERMINATE_GRACE_S` later. An exception raised at an arbitrary moment can land inside
    a lock's acquisition and leave it held (a full-suite run once waited 120 s for a command
    that never exited): nothing may hang."""
    import threading

    global _watchdog_started
    if not _watchdog_started:
        _watchdog_started = True
        threading.Thread(target=_force_exit_after, args=(TERMINATE_GRACE_S, signum),
                         name="impress-terminate-watchdog", daemon=True).start()
    raise Terminated(signum)


#: the terminate signals a command ends on as on Ctrl-C (the window and the motor command
#: install their own handlers while they run)
TERMINATE_SIGNALS = tuple(getattr(signal, n) for n in ("SIGTERM", "SIGHUP") if hasattr(signal, n))


def _interrupted_line(who: str, exc: KeyboardInterrupt) -> tuple[str, int]:
    """The line printed and the exit status of an interruption: 130 for Ctrl-C, 128 + the
    signal's number for a terminate signal. What the interruption's own clean-up left of the
    half-written files this process noted (one that landed between a work folder's making and
    the clean-up's taking charge of it) is removed first."""
    from impress_gui.core.base import workfiles

    workfiles.remove_all()
    if isinstance(exc, Terminated):
        return (f"{who}: stopped by {exc.name}; nothing half-written was kept",
                128 + exc.signum)
    return f"{who}: interrupted", 130


def _on_sigint(signum, frame) -> None:
    global _interrupted
    _interrupted = True
    signal.default_int_handler(signum, frame)  # KeyboardInterrupt, as Python's own


def _watch_interrupts() -> dict:
    """Note a Ctrl-C that arrives while modules are still being imported: an import it
    interrupts can surface as an ImportError (numpy's, say) rather than a KeyboardInterrupt,
    which must be reported as an interruption, not as an internal error. Only where Python's
    own handler is in place (a command may install its own later). A terminate signal ends
    the command as Ctrl-C does (:class:`Terminated`): returns the handlers it replaced, for
    :func:`main` to put back."""
    import threading

    global _interrupted
    _interrupted = False
    if threading.current_thread() is not threading.main_thread():
        return {}
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _on_sigint)
    replaced = {}
    for number in TERMINATE_SIGNALS:
        # not where the signal is ignored (``nohup`` ignores SIGHUP) or someone else's
        if signal.getsignal(number) is signal.SIG_DFL:
            replaced[number] = signal.signal(number, _on_terminate)
    return replaced


def _quiet_libraries() -> None:
    """No library's own warning lines on the console, in this process and the processes it
    starts (:mod:`impress_gui.core.base.quiet`); ``IMPRESS_DEBUG=1`` keeps them."""
    from impress_gui.core.base.quiet import quiet_libraries

    quiet_libraries()


def main(argv: list[str] | None = None) -> int:
    """The console command: every outcome is an exit status and, on failure, one coded line;
    a Ctrl-C at any moment (even while the command's modules load) exits with 130, a terminate
    signal (SIGTERM, SIGHUP) with 128 + its number, each after the same clean-up."""
    replaced: dict = {}
    try:
        replaced = _watch_interrupts()
        _quiet_libraries()
        return _main(argv)
    except KeyboardInterrupt as exc:
        line, status = _interrupted_line("impress", exc)
        print(line, file=sys.stderr)
        return status
    except Exception:  # noqa: BLE001 - while the command's modules load: no traceback either
        return _unexpected("impress")
    finally:
        for number, old in replaced.items():
            signal.signal(number, old)


def _main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in COMMANDS:
        command = argv[0]
    elif argv and argv[0] in ("-h", "--help", "--version"):
        build_parser().parse_args(argv)  # prints and exits
        return 0
    elif argv and _looks_like_command(argv[0]):
        return _unknown_command(argv[0])
    else:
        # no subcommand: the GUI, with everything given as its arguments (`impress PROJECT`)
        command, argv = "gui", ["gui", *argv]
    args = build_parser(command).parse_args(argv)
    return run_command(command, args)


def run_command(command: str, args: argparse.Namespace) -> int:
    """Run one subcommand; every failure is one coded line on stderr, never a traceback
    (``IMPRESS_DEBUG=1`` prints the traceback of an unexpected error as well)."""

    from impress_gui.core.base.errors import ImpressError

    try:
        return int(_load(command).run(args) or 0)
    except ImpressError as exc:
        print(f"impress {command}: error [{exc.code}]: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        line, status = _interrupted_line(f"impress {command}", exc)
        print(line, file=sys.stderr)
        return status
    except MemoryError:
        print(f"impress {command}: error [{MEMORY}]: not enough memory for this input",
              file=sys.stderr)
        return 2
    except OSError as exc:
        from impress_gui.core.base.outdir import reason

        where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
        print(f"impress {command}: error [{IO}]: a file could not be read or written{where}: "
              f"{reason(exc)}", file=sys.stderr)
        return 2
    except Exception:  # noqa: BLE001 - the last line of defence: no traceback for users
        return _unexpected(f"impress {command}")


def _unexpected(who: str) -> int:
    """An exception nobody foresaw (in an ``except`` block): one coded line, exit 3; or, if
    Ctrl-C broke off an import meanwhile, the interruption it is (exit 130)."""
    import os

    if _interrupted:
        print(f"{who}: interrupted", file=sys.stderr)
        return 130
    if os.environ.get("IMPRESS_DEBUG"):
        import traceback

        traceback.print_exc()
    print(f"{who}: error [{INTERNAL}]: an internal error stopped the command; "
          "no output was completed. Please report it with the command "
          "line; IMPRESS_DEBUG=1 shows the details.", file=sys.stderr)
    return 3
