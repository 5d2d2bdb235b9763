"""``impress validate``: the thesis' accuracy protocol (table 4.1) on simulator scans, or on
reconstructions of physical artefacts described by a spec file; prints the table and writes a
self-contained HTML report."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

#: the most render processes ``--workers`` starts
MAX_WORKERS = 64


def _resolution(text: str) -> tuple[int, int]:
    from impress_gui.commands.simulate import _resolution as parse

    return parse(text)


def _keys(text: str) -> tuple[str, ...]:
    return tuple(k.strip() for k in text.split(",") if k.strip())


def add_arguments(p: argparse.ArgumentParser) -> None:
    from impress_gui.validation.protocol import PLACEMENTS

    p.add_argument(
        "--quick",
        action="store_true",
        help="quick mode: 640x360 at three times the fast rail speed (minutes); "
        "the default is the full mode, 1920x1080 at the fast speed (about half an hour on two cores)",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=Path("impress-validation"),
        help="folder for scans, reconstructions, the record and the report "
        "(default ./impress-validation; rendered scans are reused between runs)",
    )
    p.add_argument(
        "--resolution",
        type=_resolution,
        default=None,
        help="camera WIDTHxHEIGHT of the simulated scans (overrides the mode's)",
    )
    p.add_argument(
        "--speed",
        type=float,
        default=None,
        help="rail speed in mm/s of the simulated scans (overrides the mode's)",
    )
    p.add_argument(
        "--placements",
        type=_keys,
        default=None,
        help="comma-separated subset of " + ",".join(p.key for p in PLACEMENTS),
    )
    p.add_argument(
        "--extras",
        type=_keys,
        default=None,
        help="comma-separated subset of flat,spheres; 'none' for neither",
    )
    p.add_argument(
        "--click-noise-px",
        type=float,
        default=0.0,
        help="noise added to the simulated corner clicks (pixels, default 0)",
    )
    p.add_argument(
        "--uncertainty-trials",
        type=int,
        default=None,
        help="trials of the calibration's Monte Carlo behind each reading's uncertainty "
        "(4 to 1000; default: the product's, 60)",
    )
    p.add_argument("--workers", type=int, default=2,
                   help=f"render processes (default 2; 1 to {MAX_WORKERS})")
    p.add_argument("--fresh", action="store_true", help="render every scan again")
    p.add_argument(
        "--spec",
        type=Path,
        default=None,
        help="validate real scans instead: a JSON file (format "
        "impress.validation-spec) with known dimensions and measuring positions",
    )
    p.add_argument("--no-figures", action="store_true", help="leave the figures out of the report")
    p.add_argument(
        "--keep-reconstructions",
        action="store_true",
        help="keep every file of each reconstruction (point clouds, per-laser maps, pictures: "
        "about 2 GB in quick mode); by default only the fused heightmap and the records stay",
    )


def run(args: argparse.Namespace) -> int:
    from impress_gui.commands._progress import progress_printer
    from impress_gui.validation.report import format_table, write_report
    from impress_gui.validation.run import RunConfig, run_real, run_simulated

    progress = progress_printer(5)
    if not 1 <= args.workers <= MAX_WORKERS:
        from impress_gui.core.base import codes
        from impress_gui.core.base.errors import InputError

        raise InputError(f"--workers {args.workers}: give 1 to {MAX_WORKERS} render processes",
                         code=codes.E_VAL_OPTION)

    if args.spec is not None:
        record = run_real(args.spec, args.out, progress)
    else:
        kw: dict = {
            "workers": args.workers,
            "reuse_scans": not args.fresh,
            "click_noise_px": args.click_noise_px,
            "keep_reconstructions": args.keep_reconstructions,
        }
        if args.uncertainty_trials is not None:
            kw["uncertainty_trials"] = args.uncertainty_trials
        if args.resolution:
            kw["width"], kw["height"] = args.resolution
        if args.speed:
            kw["speed_mm_s"] = args.speed
        if args.placements is not None:
            kw["placements"] = args.placements
        if args.extras is not None:
            kw["extras"] = () if args.extras == ("none",) else args.extras
        cfg = RunConfig.quick(**kw) if args.quick else RunConfig.full(**kw)
        print(
            f"impress validate: {cfg.mode} mode, {cfg.width}x{cfg.height}, "
            f"{cfg.speed_mm_s} mm/s, into {args.out}",
            file=sys.stderr,
        )
        record = run_simulated(cfg, args.out, progress)
    paths = write_report(record, args.out, figures=not args.no_figures)
    print(format_table(record), end="")
    print(f"report: {paths['report']}")
    print(f"record: {Path(args.out) / 'validation.json'}")
    if args.spec is None:
        from impress_gui.validation.run import disk_usage_bytes

        scans = Path(args.out) / "scans"
        total, kept = disk_usage_bytes(Path(args.out)), disk_usage_bytes(scans)
        print(f"disk: {total / 1e6:.0f} MB in {args.out}, of which {kept / 1e6:.0f} MB are the "
              f"rendered scans (reused by the next run; delete {scans} to free them)")
    acc = record.get("acceptance", {})
    if not record.get("readings"):
        return 0
    return 0 if acc.get("xy_ok") and acc.get("z_ok") else 1
