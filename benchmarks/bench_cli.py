"""The whole ``impress process`` command as a user runs it, against decoding the video (issue 19).

Each round runs, one after another (never side by side):

1. a warm decode-only pass in this process (PyAV already imported, the file in the page cache);
2. a decode-only run in a fresh process: ``python -c`` that imports PyAV, opens the video and
   decodes every frame with 8 frame threads, as the command's decoder does (``--decode-threads``:
   another count, or ``auto``, the fastest of PyAV's default and 2, 4, 8 frame threads, two warm
   passes each; PyAV's default, slice threading, keeps one core busy on these one-slice frames
   and is printed once per scan for reference), so that it pays the interpreter's start-up as
   the command does;
3. the command in a fresh process: ``python -c`` that calls ``impress_gui.cli.main(["process",
   VIDEO, "--calibration", C, "-o", OUT])``, which is what the ``impress`` script does, with
   timestamps taken at the boundaries of the command's stages (see below). OUT is a new folder
   in a temporary directory, removed after the round.

The ratio command / decode-only is taken within a round (this machine's speed drifts by 5-10 %
over minutes) and the median round is printed with the range of all rounds.

How the stages are measured: the command's own figures come from its ``run.json`` (timings:
``seconds_setup``, ``seconds_frame_loop``, ``seconds_finish``, ``seconds_total``, frames/s;
``wall_seconds``). Everything else is measured around it, from timestamps on the system-wide
monotonic clock (``time.monotonic()``, the same clock in the parent and the child): the parent
notes when it starts the child and when the child has exited (``os.wait4``, which also gives
the child's own peak RSS and CPU time); the child notes when the interpreter runs its first line
and, through a post-import hook that wraps three functions when their modules are first loaded
(nothing is imported earlier than the command would import it), when
``pipeline.process_files`` starts and returns, when ``reconstruct()`` starts and returns, and
when ``write_reconstruction()`` starts and returns; it also times the loading of the compiled
kernels (the import of ``impress_gui.core.reconstruction.kernels``, wherever it happens), records every
progress call the command makes (for the longest stretch without progress), and samples its
resident memory every 50 ms (``/proc/self/status``; VmHWM is also read at each boundary, exact)
and reads its processor clock (every thread) at each boundary: processor seconds per stage
depend much less on other work sharing the machine than wall seconds do.
A wrapped function that no longer exists is skipped and its boundary estimated from run.json
(the stage is then marked "~").

Stages: interpreter (start of the process to its first line), imports (the CLI and the command
module, argument parsing, until ``process_files`` starts), open (output folder check,
calibration read, video opened and hashed; until ``reconstruct()``), setup / frame loop /
finish (run.json), metadata (from ``reconstruct()`` returning to writing), writing (every
output file encoded, written, fsynced and swapped into place), after (the summary printed,
until ``main()`` returns), exit (interpreter tear-down until the parent sees the process end).

Scans are simulated with ``impress simulate`` and calibrated with ``impress calibrate ...
--picks picks.json`` once, cached under ``--cache`` (default benchmarks/.cache; one folder per
scan and resolution, reused with a note when the simulator's code has changed since,
``--resimulate`` renders them again): ``shoe`` (the shoe preset, 48 cm), ``wide`` (the same at
the simulator's largest standoff, 400 mm instead of 300: the only way it offers to widen the
field, by 1.33x; the image's width does not, the focal length scales with it), and ``tire``
(the whole rail, 1750 mm; several minutes per round at 1080p).

Usage: .venv/bin/python benchmarks/bench_cli.py [--scans shoe,wide,tire] [--rounds 3]
       [--resolution 1920x1080] [--cache DIR] [--decode-threads N] [--tmp DIR] [--warmup 1]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: the product's command (the venv's script, else the package's __main__)
IMPRESS = ([str(Path(sys.executable).parent / "impress")]
           if (Path(sys.executable).parent / "impress").exists()
           else [sys.executable, "-m", "impress_gui"])
MARK = "BENCH_CLI "

#: scan name -> arguments of ``impress simulate`` (the resolution is added)
SCANS = {
    "shoe": ["--preset", "shoe"],
    "wide": ["--preset", "shoe", "--standoff-mm", "400"],
    "tire": ["--preset", "tire", "--length-mm", "1750"],
}
#: decoder threads tried for the decode-only reference (0 = PyAV's default, slice threading)
DECODE_THREADS = (0, 2, 4, 8)

# ---------------------------------------------------------------------------------------------
# the fresh processes

DECODE_CODE = r"""
import json, sys, time
t_python = time.monotonic()
import av
t_imported = time.monotonic()
threads = int(sys.argv[2])
with av.open(sys.argv[1]) as c:
    st = c.streams.video[0]
    if threads:
        st.codec_context.thread_type = "AUTO"
        st.codec_context.thread_count = threads
    t_opened = time.monotonic()
    n = 0
    for _ in c.decode(st):
        n += 1
    t_decoded = time.monotonic()
print("BENCH_CLI " + json.dumps({"python": t_python, "imported": t_imported, "opened": t_opened,
                                 "decoded": t_decoded, "frames": n}), flush=True)
"""

COMMAND_CODE = r"""
import json, sys, threading, time
T, MEM, CPU, SAMPLES, EVENTS = {}, {}, {}, [], []

def _status():
    out = {}
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(("VmRSS:", "VmHWM:")):
                k, v = line.split(":")
                out[k] = int(v.split()[0])
    return out

def mark(name):
    T[name] = time.monotonic()
    CPU[name] = time.process_time()
    MEM[name] = _status()

mark("python")

def _sample():
    while True:
        SAMPLES.append((time.monotonic(), _status().get("VmRSS", 0)))
        time.sleep(0.05)

threading.Thread(target=_sample, daemon=True, name="bench-rss").start()

def _wrap(fn, label, track_progress):
    import functools
    import inspect

    sig = inspect.signature(fn)

    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        if track_progress:
            bound = sig.bind(*args, **kwargs)
            user = bound.arguments.get("progress")
            if user is not None:
                def progress(frac, msg):
                    EVENTS.append((time.monotonic(), float(frac), str(msg)[:80]))
                    user(frac, msg)
                bound.arguments["progress"] = progress
            args, kwargs = bound.args, bound.kwargs
        mark(label + "_start")
        try:
            return fn(*args, **kwargs)
        finally:
            mark(label + "_end")
    return wrapped

PATCH = {"impress_gui.core.reconstruction.pipeline": [("process_files", "process_files", True)],
         "impress_gui.core.reconstruction.reconstruct": [("reconstruct", "reconstruct", False)],
         "impress_gui.core.formats.writers": [("write_reconstruction", "write", False)]}
TIMED = {"impress_gui.core.reconstruction.kernels": "kernels"}

import importlib.abc
import importlib.machinery

class _Hook(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name not in PATCH and name not in TIMED:
            return None
        spec = importlib.machinery.PathFinder.find_spec(name, path, target)
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        real = spec.loader.exec_module

        def exec_module(module):
            if name in TIMED:
                mark(TIMED[name] + "_start")
            real(module)
            if name in TIMED:
                mark(TIMED[name] + "_end")
            for attr, label, track in PATCH.get(name, ()):
                fn = getattr(module, attr, None)
                if callable(fn):
                    setattr(module, attr, _wrap(fn, label, track))

        spec.loader.exec_module = exec_module
        return spec

sys.meta_path.insert(0, _Hook())
import impress_gui.cli
mark("cli_imported")
rc = impress_gui.cli.main(sys.argv[1:])
mark("main_end")
print("BENCH_CLI " + json.dumps({"t": T, "mem": MEM, "cpu": CPU, "samples": list(SAMPLES),
                                 "events": EVENTS, "rc": rc}), flush=True)
sys.exit(rc)
"""


def run_child(code: str, args: list[str], log: Path) -> dict:
    """Run ``python -c code args`` as a fresh process; return its JSON line with the parent's
    start and exit times and the child's own rusage (peak RSS, CPU)."""
    with open(log, "w") as err, tempfile.TemporaryFile("w+") as out:
        t_spawn = time.monotonic()
        p = subprocess.Popen([sys.executable, "-c", code, *args], stdout=out, stderr=err,
                             stdin=subprocess.DEVNULL, cwd=ROOT)
        _, status, ru = os.wait4(p.pid, 0)
        t_exit = time.monotonic()
        p.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        text = out.read()
    if p.returncode != 0:
        raise RuntimeError(f"child failed ({p.returncode}); stderr in {log}:\n"
                           + log.read_text()[-2000:])
    line = [x for x in text.splitlines() if x.startswith(MARK)][-1]
    doc = json.loads(line[len(MARK):])
    doc.update(spawn=t_spawn, exit=t_exit, maxrss_mb=ru.ru_maxrss / 1024,
               cpu_s=ru.ru_utime + ru.ru_stime)
    return doc


def decode_warm(video: Path, threads: int) -> tuple[float, int]:
    """Decode every frame in this process; (seconds, frames)."""
    import av

    with av.open(str(video)) as c:
        st = c.streams.video[0]
        if threads:
            st.codec_context.thread_type = "AUTO"
            st.codec_context.thread_count = threads
        t0 = time.monotonic()
        n = sum(1 for _ in c.decode(st))
        return time.monotonic() - t0, n


# ---------------------------------------------------------------------------------------------
# parsing the command's own figures and putting the stages together


def read_run(folder: Path) -> dict:
    """The command's own timings from ``run.json`` and the grid from ``metadata.json`` of an
    output folder: seconds of setup, frame loop, finish and reconstruct() in all, the wall
    seconds the command states (video opened to writing), frames/s of the loop, the share of
    the grid finished during the loop; the field (grid) width and length in mm, its cells, and
    the frames processed. Missing keys come back as None (older or newer formats)."""
    folder = Path(folder)
    run = json.loads((folder / "run.json").read_text())
    t = run.get("timings") or {}
    out = {"setup": t.get("seconds_setup"), "frame_loop": t.get("seconds_frame_loop"),
           "finish": t.get("seconds_finish"), "reconstruct": t.get("seconds_total"),
           "wall": run.get("wall_seconds"), "fps": t.get("frames_per_second"),
           "rows_in_loop": t.get("rows_finished_in_loop"),
           "other_seconds": {k[len("seconds_"):]: v for k, v in t.items()
                             if k.startswith("seconds_") and k not in (
                                 "seconds_setup", "seconds_frame_loop", "seconds_finish",
                                 "seconds_total")}}
    meta_path = folder / "metadata.json"
    meta = json.loads(meta_path.read_text()) if meta_path.exists() else {}
    grid = meta.get("grid") or {}
    shape, pixel = grid.get("shape"), grid.get("pixel_mm")
    out["cells"] = shape[0] * shape[1] if shape else None
    out["width_mm"] = shape[1] * pixel if shape and pixel else None
    out["length_mm"] = shape[0] * pixel if shape and pixel else None
    frames = meta.get("frames") or {}
    out["frames"] = (frames["stop"] - frames["start"]) if "stop" in frames else None
    return out


#: stage names in order; their seconds add up to the whole command
STAGES = ("interpreter", "imports", "open", "setup", "frame_loop", "finish", "reconstruct_other",
          "metadata", "writing", "after", "exit")
LABELS = {"interpreter": "interpreter start-up", "imports": "imports, CLI parsing",
          "open": "open (output check, calibration, video opened + hashed)",
          "setup": "setup (run.json)", "frame_loop": "frame loop (run.json)",
          "finish": "finish (run.json)", "reconstruct_other": "reconstruct() outside its timings",
          "metadata": "metadata (to writing)", "writing": "writing every output",
          "after": "summary printed", "exit": "process exit (tear-down)", "total": "whole command"}


def stages(child: dict, run: dict) -> tuple[dict, set]:
    """Seconds per stage (:data:`STAGES`, plus ``total``) from the child's timestamps and the
    command's run.json (:func:`read_run`); and the set of stages whose boundary had to be
    estimated from run.json because a wrapped function was missing."""
    t = dict(child["t"])
    estimated: set = set()
    pf0 = t.get("process_files_start", t["cli_imported"])
    pf1 = t.get("process_files_end", t["main_end"])
    if "reconstruct_start" not in t or "reconstruct_end" not in t:
        # run.json's wall seconds run from opening the video to just before writing
        r1 = t.get("write_start", pf0 + (run["wall"] or 0.0))
        t["reconstruct_end"] = r1
        t["reconstruct_start"] = r1 - (run["reconstruct"] or 0.0)
        estimated |= {"open", "metadata", "reconstruct_other"}
    if "write_start" not in t or "write_end" not in t:
        t["write_start"], t["write_end"] = t["reconstruct_end"], pf1
        estimated |= {"metadata", "writing"}
    r0, r1, w0, w1 = (t["reconstruct_start"], t["reconstruct_end"], t["write_start"],
                      t["write_end"])
    inner = sum(run[k] or 0.0 for k in ("setup", "frame_loop", "finish"))
    s = {"interpreter": t["python"] - child["spawn"], "imports": pf0 - t["python"],
         "open": r0 - pf0, "setup": run["setup"] or 0.0, "frame_loop": run["frame_loop"] or 0.0,
         "finish": run["finish"] or 0.0, "reconstruct_other": (r1 - r0) - inner,
         "metadata": w0 - r1, "writing": w1 - w0, "after": t["main_end"] - w1,
         "exit": child["exit"] - t["main_end"], "total": child["exit"] - child["spawn"]}
    return s, estimated


def stage_windows(child: dict, s: dict) -> dict:
    """Absolute (start, end) of the stages whose memory is reported."""
    t = child["t"]
    a = child["spawn"]
    pf0 = a + s["interpreter"] + s["imports"]
    r0 = pf0 + s["open"]
    loop0 = r0 + s["setup"]
    loop1 = loop0 + s["frame_loop"]
    r1 = r0 + s["setup"] + s["frame_loop"] + s["finish"] + s["reconstruct_other"]
    w0 = r1 + s["metadata"]
    w1 = w0 + s["writing"]
    return {"start-up": (a, pf0), "open": (pf0, r0), "setup": (r0, loop0),
            "frame loop": (loop0, loop1), "finish": (loop1, r1), "writing": (w0, w1),
            "after writing": (w1, t["main_end"])}


def cpu_stages(child: dict) -> dict:
    """Processor seconds (every thread of the command) per coarse stage, from the process's CPU
    clock read at the boundaries and its rusage at exit; stages whose boundaries are missing
    are left out."""
    c, total = child.get("cpu") or {}, child["cpu_s"]
    keys = [("start-up", None, "process_files_start"),
            ("open", "process_files_start", "reconstruct_start"),
            ("reconstruct()", "reconstruct_start", "reconstruct_end"),
            ("metadata", "reconstruct_end", "write_start"),
            ("writing", "write_start", "write_end"), ("after", "write_end", "main_end")]
    out = {}
    for name, a, b in keys:
        if b in c and (a is None or a in c):
            out[name] = c[b] - (c[a] if a else 0.0)
    if "main_end" in c:
        out["exit"] = total - c["main_end"]
    out["total"] = total
    return out


def peak_mb(child: dict, a: float, b: float) -> float:
    """Peak resident memory in [a, b]: the RSS samples (every 50 ms) and the readings at the
    stage boundaries inside it; exact (VmHWM) when b is a boundary and the high-water mark rose
    since a (a boundary too, or the process's start)."""
    marks = [(child["t"][k], m) for k, m in child["mem"].items() if k in child["t"]]
    vals = [rss for t, rss in child["samples"] if a <= t <= b]
    vals += [m.get("VmRSS", 0) for tm, m in marks if a - 1e-6 <= tm <= b + 1e-6]
    at_a = [m.get("VmHWM", 0) for tm, m in marks if abs(tm - a) < 1e-6]
    at_b = [m.get("VmHWM", 0) for tm, m in marks if abs(tm - b) < 1e-6]
    if at_b and ((at_a and at_b[0] > at_a[0]) or a <= child["spawn"]):
        vals.append(at_b[0])
    return max(vals, default=0) / 1024


def longest_silence(child: dict) -> tuple[float, str]:
    """The longest time without a progress call, from the first one to the process's end, and
    the last message before it."""
    ev = child["events"]
    if not ev:
        return float("nan"), "no progress calls"
    times = [e[0] for e in ev] + [child["exit"]]
    gaps = [(times[i + 1] - times[i], ev[i][2]) for i in range(len(ev))]
    return max(gaps)


# ---------------------------------------------------------------------------------------------
# scans


def sim_key() -> str:
    sys.path.insert(0, str(Path(__file__).parent))
    from common import SIM_KEY

    return SIM_KEY


def prepare(name: str, resolution: str, cache: Path, resimulate: bool = False
            ) -> tuple[Path, Path]:
    """(video, calibration) of a simulated scan, simulated and calibrated once. The folder
    records the simulator's source key; a scan made by other simulator code is reused (for
    timing, the scene's details hardly matter, and a 1080p scan takes minutes to render) with
    a note, unless ``resimulate``."""
    d = cache / f"{name}-{resolution}"
    made = d / "bench_cli.json"
    key = sim_key()
    if made.exists() and not resimulate:
        was = json.loads(made.read_text()).get("simulator_key")
        if was != key:
            print(f"[{d.name}: made by simulator code {was}, now {key}; reused "
                  "(--resimulate to render it again)]", flush=True)
    else:
        print(f"[simulating {name} at {resolution} into {d}]", flush=True)
        shutil.rmtree(d, ignore_errors=True)
        t0 = time.monotonic()
        subprocess.run([*IMPRESS, "simulate", *SCANS[name], "--resolution", resolution, str(d)],
                       check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
        print(f"[simulated in {time.monotonic() - t0:.0f} s]", flush=True)
        made.write_text(json.dumps({"simulator_key": key, "simulate": SCANS[name]}))
    truth = json.loads((d / "truth.json").read_text())
    video = d / truth["video"]
    cal = d / "calibration.json"
    if not cal.exists():
        print(f"[calibrating {name}]", flush=True)
        subprocess.run([*IMPRESS, "calibrate", str(video), "--intrinsics",
                        str(d / "intrinsics.json"), "--picks", str(d / "picks.json"),
                        "--target", str(d / "target.json"), "--speed",
                        str(truth["speed_mm_s"]), "-o", str(cal)], check=True, cwd=ROOT,
                       stdout=subprocess.DEVNULL)
    return video, cal


# ---------------------------------------------------------------------------------------------
# one scan


def med(values, fmt: str = "{:.2f}") -> str:
    vals = [v for v in values if v == v]
    if not vals:
        return "-"
    m = statistics.median(vals)
    if len(vals) == 1:
        return fmt.format(m)
    return f"{fmt.format(m)} ({fmt.format(min(vals))}-{fmt.format(max(vals))})"


def folder_mb(folder: Path) -> float:
    return sum(p.stat().st_size for p in Path(folder).rglob("*") if p.is_file()) / 2**20


def bench_scan(name: str, args, tmp_root: Path) -> dict:
    video, cal = prepare(name, args.resolution, args.cache, args.resimulate)
    size_mb = video.stat().st_size / 2**20
    print(f"\n== {name} ({args.resolution}): {video} ({size_mb:.0f} MB)", flush=True)
    if args.decode_threads == "auto":
        # two interleaved passes per choice, the faster kept: one pass is at the mercy of
        # whatever else the machine does at that moment
        trial: dict = {}
        for _ in range(2):
            for n in DECODE_THREADS:
                sec, frames = decode_warm(video, n)
                trial[n] = min(trial.get(n, (sec, frames)), (sec, frames))
        print("warm decode-only, every frame (" + str(frames) + " frames): " + ", ".join(
            f"{'default' if n == 0 else f'{n} threads'} {sec:.2f} s ({frames / sec:.0f} "
            f"frames/s)" for n, (sec, _) in trial.items()), flush=True)
        threads = min(trial, key=lambda n: trial[n][0])
    else:
        threads = int(args.decode_threads)
        # PyAV's default (slice threading) does nothing for these one-slice frames: one core
        default_s, frames = decode_warm(video, 0)
        print(f"warm decode-only with PyAV's default threads (slice threading): {default_s:.2f} s "
              f"({frames / default_s:.0f} frames/s, {frames} frames)", flush=True)
    tdesc = "PyAV's default threads" if threads == 0 else f"{threads} frame threads"
    print(f"decode-only reference: {tdesc}", flush=True)
    cmd_args = ["process", str(video), "--calibration", str(cal), *args.process_args.split()]
    rounds = []
    for k in range(args.warmup + args.rounds):
        warm = k < args.warmup
        tmp = Path(tempfile.mkdtemp(prefix="bench_cli-", dir=tmp_root))
        try:
            wsec, _ = decode_warm(video, threads)
            dec = run_child(DECODE_CODE, [str(video), str(threads)], tmp / "decode.log")
            out = tmp / "out"  # a new folder: the command refuses folders that are not its own
            cmd = run_child(COMMAND_CODE, [*cmd_args, "-o", str(out)], tmp / "command.log")
            run = read_run(out)
            out_mb = folder_mb(out)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        s, estimated = stages(cmd, run)
        r = {"s": s, "estimated": estimated, "run": run, "out_mb": out_mb,
             "dec_total": dec["exit"] - dec["spawn"], "dec_loop": dec["decoded"] - dec["opened"],
             "dec_start": dec["opened"] - dec["spawn"], "dec_exit": dec["exit"] - dec["decoded"],
             "dec_frames": dec["frames"], "dec_rss": dec["maxrss_mb"], "dec_cpu": dec["cpu_s"],
             "warm": wsec, "cmd_rss": cmd["maxrss_mb"], "cmd_cpu": cmd["cpu_s"],
             "kernels": (cmd["t"].get("kernels_end", float("nan"))
                         - cmd["t"].get("kernels_start", float("nan"))),
             "silence": longest_silence(cmd), "cpu": cpu_stages(cmd),
             "peaks": {st: peak_mb(cmd, a, b) for st, (a, b) in stage_windows(cmd, s).items()}}
        r["ratio"] = s["total"] / r["dec_total"]
        w0 = stage_windows(cmd, s)["writing"][0]
        r["writing_events"] = [(t - w0, msg) for t, _, msg in cmd["events"] if t >= w0]
        line = (f"decode-only {r['dec_total']:.2f} s fresh (loop {r['dec_loop']:.2f} s; warm "
                f"{wsec:.2f} s) | command {s['total']:.2f} s = {r['ratio']:.2f}x: " + ", ".join(
                    f"{st} {s[st]:.2f}" for st in STAGES if abs(s[st]) >= 0.005)
                + f" | peak RSS {cmd['maxrss_mb']:.0f} MB (decode {dec['maxrss_mb']:.0f} MB)"
                f" | load average {os.getloadavg()[0]:.1f}")
        if warm:
            print(f"warm-up (not counted; fills numba's cache and the page cache): {line}",
                  flush=True)
            continue
        print(f"round {len(rounds) + 1}: {line}", flush=True)
        rounds.append(r)
    summarise(name, rounds, tdesc)
    return {"name": name, "rounds": rounds}


def summarise(name: str, rounds: list[dict], tdesc: str) -> None:
    n = len(rounds)
    run0 = rounds[0]["run"]
    dec = [r["dec_total"] for r in rounds]
    tot = [r["s"]["total"] for r in rounds]
    print(f"\n{name}: {n} rounds, medians (range); ratio = stage / decode-only in a fresh process "
          f"({tdesc}) of the same round")
    print("| stage | seconds | / decode-only | share of the command | peak RSS, MB |")
    print("|---|---|---|---|---|")
    print(f"| decode-only, fresh process (every frame: {rounds[0]['dec_frames']}) | {med(dec)} | "
          f"1 | | {med([r['dec_rss'] for r in rounds], '{:.0f}')} |")
    print(f"| - of which start-up (interpreter, PyAV, open) | "
          f"{med([r['dec_start'] for r in rounds])} | | | |")
    print(f"| - of which decoding | {med([r['dec_loop'] for r in rounds])} | | | |")
    print(f"| decode-only, warm (in a running process) | {med([r['warm'] for r in rounds])} | "
          f"{med([r['warm'] / r['dec_total'] for r in rounds])} | | |")
    peaks_for = {"interpreter": None, "imports": "start-up", "open": "open", "setup": "setup",
                 "frame_loop": "frame loop", "finish": "finish", "writing": "writing",
                 "after": "after writing"}
    for st in STAGES:
        vals = [r["s"][st] for r in rounds]
        if max(abs(v) for v in vals) < 0.005:
            continue
        mark = "~" if any(st in r["estimated"] for r in rounds) else ""
        p = peaks_for.get(st)
        peak = med([r["peaks"][p] for r in rounds], "{:.0f}") if p else ""
        if st == "imports":
            peak += " (start-up)"
        print(f"| {mark}{LABELS[st]} | {med(vals)} | "
              f"{med([r['s'][st] / r['dec_total'] for r in rounds])} | "
              f"{100 * statistics.median(v / t for v, t in zip(vals, tot)):.0f} % | {peak} |")
    print(f"| **{LABELS['total']}** | **{med(tot)}** | **{med([r['ratio'] for r in rounds])}** | "
          f"100 % | {med([r['cmd_rss'] for r in rounds], '{:.0f}')} (ru_maxrss) |")
    cpu = [r["cmd_cpu"] / r["dec_cpu"] for r in rounds]
    before = [r["s"]["interpreter"] + r["s"]["imports"] + r["s"]["open"] for r in rounds]
    after = [r["s"]["metadata"] + r["s"]["writing"] + r["s"]["after"] + r["s"]["exit"]
             for r in rounds]
    print(f"\nbefore reconstruct() {med(before)} s, after it {med(after)} s; "
          f"reconstruct() {med([r['run']['reconstruct'] for r in rounds])} s (run.json; its "
          f"wall_seconds {med([r['run']['wall'] for r in rounds])} s include opening the video)")
    print(f"CPU: command {med([r['cmd_cpu'] for r in rounds], '{:.1f}')} s, decode-only "
          f"{med([r['dec_cpu'] for r in rounds], '{:.1f}')} s, ratio {med(cpu)}; command by "
          "stage (all threads): " + ", ".join(
              f"{k} {med([r['cpu'].get(k, float('nan')) for r in rounds])} s"
              for k in rounds[0]["cpu"] if k != "total"))
    print(f"frame loop: {med([r['run']['fps'] for r in rounds], '{:.0f}')} frames/s over "
          f"{run0['frames']} frames, field {run0['width_mm']:.0f} mm wide x "
          f"{run0['length_mm']:.0f} mm long ({run0['cells'] / 1e6:.1f} M cells; 32 B/cell during "
          f"a run = {run0['cells'] * 32 / 2**20:.0f} MB of grids); decoding alone "
          f"{med([r['dec_frames'] / r['dec_loop'] for r in rounds], '{:.0f}')} frames/s fresh, "
          f"{med([r['dec_frames'] / r['warm'] for r in rounds], '{:.0f}')} warm; frame loop / "
          f"warm decode-only {med([r['s']['frame_loop'] / r['warm'] for r in rounds])}; "
          f"{100 * (run0['rows_in_loop'] or 0):.0f} % of the grid finished during the loop")
    print(f"kernels loaded in {med([r['kernels'] for r in rounds])} s (inside the stages "
          f"above); outputs {med([r['out_mb'] for r in rounds], '{:.0f}')} MB; longest time "
          f"without progress {med([r['silence'][0] for r in rounds])} s (after "
          f"\"{rounds[len(rounds) // 2]['silence'][1]}\")", flush=True)
    mid = sorted(rounds, key=lambda r: r["s"]["total"])[len(rounds) // 2]
    if mid["writing_events"]:
        print("progress while writing (median round; seconds after writing began): " + ", ".join(
            f"{dt:.1f} {msg}" for dt, msg in mid["writing_events"]), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scans", default="shoe", help="comma list of " + ", ".join(SCANS))
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--process-args", default="",
                    help="more options for the timed command, one string (e.g. "
                    "'--no-unlit-soil' to time it without the unlit soil's subtraction)")
    ap.add_argument("--warmup", type=int, default=1,
                    help="untimed command runs first (numba's cache, the page cache)")
    ap.add_argument("--resolution", default="1920x1080", help="WIDTHxHEIGHT of the scans")
    ap.add_argument("--cache", type=Path, default=Path(__file__).parent / ".cache")
    ap.add_argument("--resimulate", action="store_true",
                    help="render the scans again (default: reuse the cached ones)")
    ap.add_argument("--decode-threads", default="8",
                    help="frame threads of the decode-only runs (default 8, as the command's "
                         "decoder; 0 = PyAV's default, slice threading, one core for these "
                         "videos; auto = the fastest of " + ", ".join(map(str, DECODE_THREADS))
                         + ", two warm passes each)")
    ap.add_argument("--tmp", type=Path, default=Path(tempfile.gettempdir()),
                    help="where the output folders are written (removed after each round)")
    args = ap.parse_args()
    args.cache = args.cache.resolve()
    args.cache.mkdir(parents=True, exist_ok=True)
    print(f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, {platform.node()}, "
          f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}; python "
          f"{platform.python_version()}; outputs under {args.tmp}; cache {args.cache}")
    for name in args.scans.split(","):
        if name not in SCANS:
            raise SystemExit(f"unknown scan {name!r} (one of {', '.join(SCANS)})")
        bench_scan(name, args, args.tmp)
    print(f"\nload average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
