"""``impress batch``: process the scans of a manifest, locally or on a Dask cluster."""

from __future__ import annotations

import argparse
from pathlib import Path

from impress_gui.core.base import codes


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("manifest", type=Path,
                   help="batch manifest (impress.batch JSON: the scans' names, videos, "
                        "calibrations and parameters; see docs/formats.md)")
    p.add_argument("-o", "--output", type=Path, required=True,
                   help="batch folder: one result folder per scan, summary.csv and summary.json "
                        "(a run into the same folder resumes: finished scans are kept)")
    p.add_argument("--jobs", type=int, default=None,
                   help="scans processed at once on this machine (default: the cores, limited "
                        "by memory at about 2.5 GB a scan)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="submit the scans to this Dask distributed scheduler "
                        "(e.g. tcp://10.0.0.5:8786) instead of the local pool")


def run(args: argparse.Namespace) -> int:
    from impress_gui.commands._progress import progress_printer
    from impress_gui.core.base.errors import InputError
    from impress_gui.session.batch import load_manifest, run_batch

    if args.jobs is not None and not 1 <= args.jobs <= 256:
        raise InputError("--jobs must be 1 to 256", code=codes.E_BATCH)
    items = load_manifest(args.manifest)

    rows = run_batch(items, args.output, jobs=args.jobs, scheduler=args.scheduler,
                     progress=progress_printer(0), manifest=args.manifest)
    width = max(len(r["name"]) for r in rows)
    print(f"batch of {len(rows)} scans in {args.output} (summary.csv, summary.json)")
    for r in rows:
        extra = f" [{r['code']}] {r['message']}" if r.get("code") else (
            f"; {r['warnings']} warning(s)" if r.get("warnings") else "")
        print(f"  {r['name']:<{width}}  {r['status']:<12} {r.get('cells_fused') or '':>10} "
              f"cells{extra}")
    failed = [r for r in rows if r["status"] == "failed"]
    return 1 if failed else 0
