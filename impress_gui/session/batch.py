"""Many scans in one run: ``impress batch MANIFEST -o BATCH``.

A manifest (``impress.batch`` JSON) lists the scans: each a name, a video, a calibration and
optionally processing parameters. Every scan is processed by
:func:`~impress_gui.core.reconstruction.pipeline.process_files` (the same call as ``impress process``) into
``BATCH/<name>/``; ``BATCH/summary.csv`` and ``BATCH/summary.json`` list the outcome of each.

- **Locally** the scans run in a pool of processes sized to the machine (cores, and memory at
  about :data:`GB_PER_JOB` per reconstruction), or ``jobs`` of them.
- **On a cluster** (``scheduler`` = a Dask distributed scheduler's address, or a
  :class:`distributed.Client`): the same per-scan job is submitted to it. The machines must see
  the videos and the batch folder at the same paths (a shared drive).
- **Resumption**: a scan whose folder already holds a complete result made from the same
  inputs (same SHA-256) with the same parameters is not processed again ("done earlier"); a run
  interrupted part way goes on where it stopped.

The batch folder is an output folder of the product (``kind`` ``batch``): it is refused when it
holds anything else, and every scan's folder follows the rules of ``impress process``.
"""

from __future__ import annotations

import csv
import io
import json
import os
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from impress_gui.core.base import codes
from impress_gui.core.base.errors import FormatError, ImpressError, InputError
from impress_gui.core.base.fileio import dumps_json, read_json

BATCH_FORMAT = "impress.batch"
GB_PER_JOB = 2.5
SUMMARY_FILES = ("summary.csv", "summary.json")
#: processing parameters a manifest may set (the others keep their defaults)
PARAM_KEYS = ("method", "frame_start", "frame_stop", "grid_mm", "min_peak", "subpixel", "texture",
              "unlit_soil", "reconcile_lasers", "fps")


@dataclass(frozen=True)
class BatchItem:
    name: str
    video: Path
    calibration: Path
    params: dict = field(default_factory=dict)


#: the type each manifest parameter must have (bool is not a number here)
PARAM_TYPES = {"method": (str,), "frame_start": (int, type(None)), "frame_stop": (int, type(None)),
               "grid_mm": (int, float), "min_peak": (int, float), "subpixel": (str,),
               "texture": (bool,), "unlit_soil": (bool,), "reconcile_lasers": (bool,),
               "fps": (int, float, type(None))}


def _control(text: str) -> bool:
    return any(ord(ch) < 32 or ord(ch) == 127 for ch in text)


def _path_field(s: dict, key: str, where: str) -> str:
    v = s[key]
    if not isinstance(v, str) or not v.strip() or _control(v):
        raise FormatError(f"{where}: {key!r} must be a file path (text without control "
                          "characters)", code=codes.E_BATCH)
    return v


#: names Windows keeps for devices (with any extension, in any case): a folder named so cannot
#: be made or opened there, and a batch folder is copied between machines
WINDOWS_DEVICE_NAMES = frozenset(
    ["CON", "PRN", "AUX", "NUL"] + [f"{p}{i}" for p in ("COM", "LPT") for i in range(1, 10)])
#: characters Windows does not allow in a file name
WINDOWS_FORBIDDEN = set('<>:"|?*')


def _safe_name(name: str, where: str) -> str:
    if (not name or name.startswith(".") or "/" in name or "\\" in name or name in SUMMARY_FILES
            or len(name) > 120 or name != name.strip() or _control(name)
            or name.endswith(".") or WINDOWS_FORBIDDEN & set(name)
            or name.split(".")[0].upper() in WINDOWS_DEVICE_NAMES):
        raise FormatError(f"{where}: the scan name {name!r} cannot be a folder name (it must "
                          "be 1-120 characters without '/', '\\', control characters or any of "
                          "< > : \" | ? *, not start or end with a dot or begin or end with a "
                          "space, not be a name Windows keeps for a device (CON, NUL, COM1, "
                          f"...), and not be {' or '.join(SUMMARY_FILES)})", code=codes.E_BATCH)
    return name


def load_manifest(path: str | os.PathLike) -> list[BatchItem]:
    """Read a batch manifest; paths in it are relative to the manifest's folder."""
    path = Path(path)
    doc = read_json(path, BATCH_FORMAT)
    scans = doc.get("scans")
    if not isinstance(scans, list) or not scans:
        raise FormatError(f"{path}: 'scans' must be a non-empty list", code=codes.E_BATCH)
    base = path.parent
    items: list[BatchItem] = []
    seen: set[str] = set()
    for i, s in enumerate(scans):
        where = f"{path}: scan {i + 1}"
        if not isinstance(s, dict):
            raise FormatError(f"{where} must be an object", code=codes.E_BATCH)
        try:
            video_text = _path_field(s, "video", where)
            name = _safe_name(str(s.get("name") or Path(video_text).stem), where)
            video = base / video_text
            cal = base / _path_field(s, "calibration", where)
        except KeyError as exc:
            raise FormatError(f"{where}: the field {exc.args[0]!r} is missing",
                              code=codes.E_BATCH) from None
        # names that differ only in case are one folder on a case-insensitive disk (Windows,
        # macOS, an exFAT archive drive): the second scan would write into the first's
        if name.casefold() in seen:
            raise FormatError(f"{where}: the name {name!r} is used twice (names are compared "
                              "ignoring case: they are folder names)", code=codes.E_BATCH)
        seen.add(name.casefold())
        params = s.get("parameters") or {}
        if not isinstance(params, dict) or set(params) - set(PARAM_KEYS):
            raise FormatError(f"{where}: parameters may only set {', '.join(PARAM_KEYS)}",
                              code=codes.E_BATCH)
        for key, value in params.items():
            types = PARAM_TYPES[key]
            if not isinstance(value, types) or (isinstance(value, bool) and bool not in types):
                names = " or ".join("null" if t is type(None) else t.__name__ for t in types)
                raise FormatError(f"{where}: the parameter {key!r} must be {names}, not "
                                  f"{value!r}", code=codes.E_BATCH)
        items.append(BatchItem(name, video, cal, dict(params)))
    return items


def _params(item: BatchItem):
    from impress_gui.core.reconstruction.reconstruct import ProcessParams

    p = {k: v for k, v in item.params.items() if k != "fps"}
    try:
        params = ProcessParams(**p)
        params.validate()
    except TypeError:
        raise InputError(f"scan {item.name}: unusable parameters", code=codes.E_BATCH) from None
    return params


def process_one(item: BatchItem, out_dir: str) -> dict[str, Any]:
    """One scan (run in a worker process or on a cluster): its summary row. Never raises for
    a scan's own failure: the row says what went wrong (its code and message)."""
    from impress_gui.core.reconstruction.pipeline import process_files

    out = Path(out_dir) / item.name
    t0 = time.perf_counter()
    row: dict[str, Any] = {"name": item.name, "video": str(item.video),
                           "calibration": str(item.calibration), "folder": str(out)}
    try:
        params = _params(item)
        done = _done_earlier(item, out, params)
        if done is not None:
            return row | done | {"status": "done earlier"}
        meta = process_files(item.video, item.calibration, out, params, fps=item.params.get("fps"))
        row |= _row_from_metadata(meta) | {"status": "processed"}
    except ImpressError as exc:
        row |= {"status": "failed", "code": exc.code, "message": str(exc)}
    except MemoryError:
        row |= {"status": "failed", "code": codes.E_MEMORY, "message": "not enough memory"}
    except OSError as exc:
        from impress_gui.core.base.outdir import reason

        row |= {"status": "failed", "code": codes.E_IO, "message": reason(exc)}
    row["seconds"] = round(time.perf_counter() - t0, 3)
    return row


def _row_from_metadata(meta: dict) -> dict[str, Any]:
    from impress_gui.core.formats.provenance import recorded_sha256

    st = meta.get("stats") or {}
    return {"video_sha256": recorded_sha256(meta.get("inputs"), "video"),
            "calibration_sha256": recorded_sha256(meta.get("inputs"), "calibration"),
            "frames": f"{meta['frames']['start']}..{meta['frames']['stop'] - 1}",
            "cells_fused": st.get("cells_fused"), "warnings": len(meta.get("warnings") or []),
            "code": "", "message": "; ".join(meta.get("warnings") or [])}


def _done_earlier(item: BatchItem, out: Path, params) -> dict[str, Any] | None:
    """The row of a complete earlier result of exactly this job in ``out``, else None."""
    from impress_gui.core.base.fileio import sha256_file
    from impress_gui.core.base.outdir import read_mark
    from impress_gui.core.formats.provenance import recorded_sha256

    meta_path = out / "metadata.json"
    if not meta_path.is_file() or read_mark(out) is None:
        return None
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
        ins = meta["inputs"]
        given = (meta.get("frame_rate") or {}).get("given_fps")
        same = (meta.get("parameters") == params.to_json()
                and given == item.params.get("fps")
                and recorded_sha256(ins, "calibration") == sha256_file(item.calibration)
                and recorded_sha256(ins, "video") == _video_sha(item.video))
        files_ok = same and _files_intact(out, meta.get("files") or {})
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    return _row_from_metadata(meta) if same and files_ok else None


def _files_intact(out: Path, digests: dict) -> bool:
    """Every file the metadata lists has the SHA-256 it records, and the folder holds nothing
    else (a result changed or added to after it was written is not a finished result)."""
    from impress_gui.core.base.fileio import sha256_file
    from impress_gui.core.formats.recon_files import METADATA_FILE, RUN_FILE

    if not digests:
        return False
    present = {p.name for p in out.iterdir()}
    if present != set(digests) | {METADATA_FILE, RUN_FILE}:
        return False
    return all(sha256_file(out / name) == digest for name, digest in digests.items())


def _video_sha(path: Path) -> str:
    from impress_gui.core.base.fileio import sha256_path

    return sha256_path(path)


def default_jobs() -> int:
    cores = os.cpu_count() or 1
    try:
        import psutil

        mem_gb = psutil.virtual_memory().available / 2**30
    except ImportError:
        mem_gb = cores * GB_PER_JOB
    return max(1, min(cores, int(mem_gb // GB_PER_JOB)))


def run_batch(items: list[BatchItem], out_dir: str | os.PathLike, jobs: int | None = None,
              scheduler: Any = None, progress: Callable[[float, str], None] | None = None,
              manifest: str | os.PathLike | None = None) -> list[dict[str, Any]]:
    """Process ``items`` into ``out_dir``; return the summary rows (manifest order) after
    writing ``summary.csv`` and ``summary.json``."""
    from impress_gui.core.base.fileio import sha256_file
    from impress_gui.core.base.outdir import MARK_FILE, check_output_dir, mark_bytes, writing

    names = [i.name for i in items]
    inputs = [p for i in items for p in (i.video, i.calibration)]
    manifest_record = None
    if manifest is not None:
        inputs.append(Path(manifest))
        # the manifest as the batch starts (not as it may be when the batch ends)
        manifest_record = {"path": str(manifest), "sha256": sha256_file(manifest)}
    # the batch folder: new, empty or an earlier batch's (its scans' folders and summaries)
    allowed = {*names, *SUMMARY_FILES}
    out = check_output_dir(out_dir, "batch", inputs, allowed=None)
    from impress_gui.core.base.outdir import read_mark

    if out.exists() and read_mark(out) is not None:
        foreign = sorted(p.name for p in out.iterdir() if p.name not in allowed | {MARK_FILE}
                         and not p.name.startswith("."))
        if foreign:
            from impress_gui.core.base.outdir import OutputError

            raise OutputError(f"{out} holds {', '.join(foreign[:5])}, which this batch does not "
                              "write: nothing is changed; name another folder",
                              code=codes.E_OUTPUT_NOT_EMPTY)
    with writing(out):
        out.mkdir(parents=True, exist_ok=True)
        if not (out / MARK_FILE).exists():
            (out / MARK_FILE).write_bytes(mark_bytes("batch"))
    rows: dict[str, dict[str, Any]] = {}
    n = len(items)

    def done(row: dict[str, Any]) -> None:
        rows[row["name"]] = row
        if progress is not None:
            progress(len(rows) / n, f"{row['name']}: {row['status']}"
                     + (f" [{row['code']}]" if row.get("code") else ""))

    try:
        if scheduler is not None:
            _run_dask(items, str(out), scheduler, done)
        else:
            _run_local(items, str(out), jobs or default_jobs(), done)
    except KeyboardInterrupt:
        # what finished is kept and summarised; the rest is marked, and a run again with
        # the same manifest resumes there
        write_summary([rows.get(i.name) or _finished_unreported(i, out) or _not_run(i)
                       for i in items], out, manifest_record)
        raise
    ordered = [rows[name] for name in names]
    write_summary(ordered, out, manifest_record)
    return ordered


def _finished_unreported(item: BatchItem, out: Path) -> dict[str, Any] | None:
    """The row of a scan whose worker finished its result folder but was interrupted before
    it reported back (Ctrl-C between the two): the complete result of exactly this job, read
    back as :func:`_done_earlier` reads one; None when there is none."""
    folder = out / item.name
    if not (folder / "metadata.json").is_file():
        return None
    try:
        done = _done_earlier(item, folder, _params(item))
    except (ImpressError, OSError, ValueError):
        return None
    if done is None:
        return None
    return {"name": item.name, "video": str(item.video), "calibration": str(item.calibration),
            "folder": str(folder)} | done | {"status": "processed"}


def _not_run(item: BatchItem) -> dict[str, Any]:
    return {"name": item.name, "status": "not run (interrupted)", "video": str(item.video),
            "calibration": str(item.calibration),
            "message": "the batch was interrupted before this scan was done: run it again"}


def _run_local(items: list[BatchItem], out: str, jobs: int, done) -> None:
    if jobs <= 1 or len(items) == 1:
        for item in items:
            done(process_one(item, out))
        return
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed

    # "spawn": a clean interpreter per worker (no inherited threads or Qt state)
    from impress_gui.core.base.quiet import child_initializer

    pool = ProcessPoolExecutor(max_workers=jobs, mp_context=mp.get_context("spawn"),
                               initializer=child_initializer())
    try:
        futures = [pool.submit(process_one, item, out) for item in items]
        for fut in as_completed(futures):
            done(fut.result())
    except BaseException:
        # interrupted (Ctrl-C): no further scan is started, and the scans in progress are
        # stopped (their outputs are written atomically: nothing half-made is left as a result)
        procs = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in procs:
            proc.terminate()
        for proc in procs:
            proc.join(10)
        raise
    pool.shutdown()


def _run_dask(items: list[BatchItem], out: str, scheduler: Any, done) -> None:
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise InputError("--scheduler needs the dask distributed package "
                         "(pip install 'dask[distributed]')", code=codes.E_BATCH) from None
    own = not isinstance(scheduler, Client)
    try:
        client = Client(scheduler, timeout=30) if own else scheduler
    except (OSError, TimeoutError, ValueError):
        raise InputError(f"no Dask scheduler answers at {scheduler}",
                         code=codes.E_BATCH_SCHEDULER) from None
    try:
        futures = [client.submit(process_one, item, out, pure=False, key=f"impress-{item.name}")
                   for item in items]
        for fut in as_completed(futures):
            done(fut.result())
    finally:
        if own:
            client.close()


SUMMARY_COLUMNS = ("name", "status", "code", "frames", "cells_fused", "warnings", "seconds",
                   "video", "video_sha256", "calibration", "calibration_sha256", "folder",
                   "message")


def write_summary(rows: Iterable[dict[str, Any]], out: Path,
                  manifest: dict[str, str] | None = None) -> None:
    """``summary.csv`` and ``summary.json`` in the batch folder ``out``: each scan's folder
    named relative to it (the summaries do not depend on where the batch folder is), and in
    the JSON ``manifest`` (its path and SHA-256 as the batch started). Only ``seconds``
    differs between two runs."""
    from impress_gui.core.base.fileio import atomic_write_bytes
    from impress_gui.core.formats.provenance import csv_text

    def relative(row: dict[str, Any]) -> dict[str, Any]:
        folder = row.get("folder")
        if folder:
            try:
                row = row | {"folder": Path(folder).relative_to(out).as_posix()}
            except ValueError:
                pass
        return row

    rows = [relative(r) for r in rows]
    buf = io.StringIO()
    w = csv.DictWriter(buf, SUMMARY_COLUMNS, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:  # text cells made safe for spreadsheets (summary.json keeps them exact)
        w.writerow({k: csv_text(v) if isinstance(v := r.get(k, ""), str) else v
                    for k in SUMMARY_COLUMNS})
    atomic_write_bytes(out / "summary.csv", buf.getvalue().encode("utf-8"))
    doc = {"format": "impress.batch-summary", "version": 1,
           "scans": [{k: r.get(k) for k in SUMMARY_COLUMNS} for r in rows]}
    if manifest is not None:
        doc["manifest"] = dict(manifest)
    atomic_write_bytes(out / "summary.json", dumps_json(doc).encode("utf-8"))
