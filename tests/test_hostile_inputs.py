"""A table of hostile and damaged inputs, across every reader and command.

Each case runs the real ``impress`` command line (in this process, through
:func:`impress_gui.cli.main`, so an escaping exception fails the test) inside a sandbox folder
holding a copy of the evidence, and asserts:

- the outcome: an error with its code (exit status 2), or a success that carries its warning;
- nothing outside the output the case names was created, changed or removed (every file of
  the sandbox is hashed before and after), so the evidence is never lost;
- no traceback on the console, no Python type or errno text in the message;
- nothing hangs: ``pytest-timeout`` fails a case that runs 120 s (the cases take well under a
  second; the bound is generous, as any bound on their time would otherwise fail on a busy
  machine: a hang never ends).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from conftest import calibrate_scan

from impress_gui import cli

FRAMES = ["--frames", "40:100", "--no-texture"]
LEAKS = ("Traceback", "<class", "Errno", "errno", "NoneType", "KeyError", "ValueError",
         "TypeError", "AttributeError")


@dataclass
class Case:
    name: str
    argv: list[str]  # {ev} = the evidence folder, {box} = the sandbox
    expect: str  # "E-..." error code (exit 2) or "W-..." warning on a success (exit 0)
    setup: object = None  # callable(box: Path) run before the command
    output: str | None = None  # the output the case names (relative to the box): may change
    extra: dict = field(default_factory=dict)


# ----- building damaged inputs ------------------------------------------------------------------
def _write(rel: str, data: bytes | str):
    def setup(box: Path) -> None:
        p = box / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(data.encode() if isinstance(data, str) else data)
    return setup


def _json_edit(src: str, rel: str, edit):
    """A copy of the evidence's JSON file ``src`` edited by ``edit(doc)`` (may return text)."""
    def setup(box: Path) -> None:
        doc = json.loads((box / "ev" / src).read_text())
        out = edit(doc)
        text = out if isinstance(out, str) else json.dumps(doc)
        (box / rel).write_text(text)
    return setup


def _fifo(rel: str):
    def setup(box: Path) -> None:
        os.mkfifo(box / rel)
    return setup


def _symlink(rel: str, target: str):
    def setup(box: Path) -> None:
        (box / rel).symlink_to(box / target)
    return setup


def _mkdir(rel: str, files: dict | None = None):
    def setup(box: Path) -> None:
        (box / rel).mkdir(parents=True, exist_ok=True)
        for name, data in (files or {}).items():
            (box / rel / name).write_bytes(data)
    return setup


def _cut(src: str, rel: str, fraction: float, more: int = 0):
    def setup(box: Path) -> None:
        data = (box / "ev" / src).read_bytes()
        (box / rel).write_bytes(data[: int(len(data) * fraction) + more])
    return setup


def _corrupt_packet(src: str, rel: str, which: float | str, pattern: bytes = b"\xff" * 200):
    """200 bytes overwritten inside the coded picture of the frame at ``which`` (a fraction of
    the file's packets, by position; or "t1": the picks' first calibration frame): what a bad
    sector or a broken copy does."""
    def setup(box: Path) -> None:
        import av

        with av.open(str(box / "ev" / src)) as c:
            st = c.streams.video[0]
            pk = sorted((p.pos, p.size, p.pts) for p in c.demux(st)
                        if p.size and p.pos is not None)
        if which == "t1":
            t1 = json.loads((box / "ev" / "picks.json").read_text())["t1"]
            pts = sorted(p[2] for p in pk)[t1]
            pos, size = next((p[0], p[1]) for p in pk if p[2] == pts)
        else:
            pos, size = pk[int(len(pk) * which)][:2]
        data = bytearray((box / "ev" / src).read_bytes())
        off = pos + min(40, size // 3)
        data[off: off + len(pattern)] = pattern
        (box / rel).write_bytes(bytes(data))
    return setup


def _sparse(rel: str, size: int):
    def setup(box: Path) -> None:
        with open(box / rel, "wb") as fh:
            fh.truncate(size)
    return setup


def _chain(*steps):
    def setup(box: Path) -> None:
        for s in steps:
            s(box)
    return setup


def _cal_set(key, value):
    def edit(doc):
        doc[key] = value
    return edit


PROC = ["process", "{ev}/scan.mp4", "--calibration", "{ev}/calibration.json"]
CALIB = ["calibrate", "{ev}/scan.mp4", "--intrinsics", "{ev}/intrinsics.json", "--picks",
         "{ev}/picks.json", "--speed", "fast"]


def _proc(video="{ev}/scan.mp4", cal="{ev}/calibration.json", out="{box}/out", *more):
    return ["process", video, "--calibration", cal, "-o", out, *FRAMES, *more]


def _calib(video="{ev}/scan.mp4", intr="{ev}/intrinsics.json", picks="{ev}/picks.json",
           out="{box}/cal.json", *more):
    return ["calibrate", video, "--intrinsics", intr, "--picks", picks, "--speed", "fast",
            "--plane-frames", "3", "-o", out, *more]


CASES: list[Case] = [
    # --- item 1: the output folder never destroys anything --------------------------------------
    Case("process -o the evidence folder", _proc(out="{ev}"), "E-OUTPUT-HOLDS-INPUT"),
    Case("process -o the sandbox (holds the evidence folder)", _proc(out="{box}"),
         "E-OUTPUT-HOLDS-INPUT"),
    Case("process -o .", _proc(out="."), "E-OUTPUT-UNSAFE"),
    Case("process -o ..", _proc(out=".."), "E-OUTPUT-UNSAFE"),
    Case("process -o /", _proc(out="/"), "E-OUTPUT-UNSAFE"),
    Case("process -o an existing file", _proc(out="{ev}/notes.txt"), "E-OUTPUT-NOT-FOLDER",
         _write("ev/notes.txt", "examiner's notes")),
    Case("process -o the video itself", _proc(out="{ev}/scan.mp4"), "E-OUTPUT-HOLDS-INPUT"),
    Case("process -o the calibration file", _proc(out="{ev}/calibration.json"),
         "E-OUTPUT-HOLDS-INPUT"),
    Case("process -o a link to a folder", _proc(out="{box}/link"), "E-OUTPUT-LINK",
         _chain(_mkdir("elsewhere"), _symlink("link", "elsewhere"))),
    Case("process -o a dangling link", _proc(out="{box}/dangling"), "E-OUTPUT-LINK",
         _symlink("dangling", "nowhere")),
    Case("process -o a foreign non-empty folder", _proc(out="{box}/photos"),
         "E-OUTPUT-NOT-EMPTY", _mkdir("photos", {"IMG_0001.JPG": b"\xff\xd8 photo"})),
    Case("process -o a folder with a hidden file", _proc(out="{box}/h"), "E-OUTPUT-NOT-EMPTY",
         _mkdir("h", {".keep": b""})),
    Case("process -o a forged mark with a foreign file", _proc(out="{box}/forged"),
         "E-OUTPUT-NOT-EMPTY",
         _mkdir("forged", {".impress-output.json": json.dumps(
             {"format": "impress.output-folder", "kind": "reconstruction"}).encode(),
             "evidence.mp4": b"precious"})),
    Case("process -o a simulation's folder", _proc(out="{box}/sim"), "E-OUTPUT-NOT-EMPTY",
         _mkdir("sim", {".impress-output.json": json.dumps(
             {"format": "impress.output-folder", "kind": "simulation"}).encode(),
             "truth.json": b"{}"})),
    Case("process -o a folder holding a frame-folder input",
         _proc(video="{box}/frames", out="{box}"), "E-OUTPUT-HOLDS-INPUT"),
    Case("process -o inside a frame-folder input",
         _proc(video="{box}/frames", out="{box}/frames/out"), "E-OUTPUT-HOLDS-INPUT",
         _mkdir("frames", {"f0001.png": b"x"})),
    Case("process -o under a file", _proc(out="{ev}/notes.txt/out"), "E-OUTPUT-NOT-FOLDER",
         _write("ev/notes.txt", "notes")),
    Case("process -o where nothing can be written", _proc(out="/proc/impress-out"), "E-WRITE"),
    Case("process -o an empty string", _proc(out=""), "E-OUTPUT-UNSAFE"),
    Case("calibrate -o a folder", _calib(out="{box}/dir"), "E-OUTPUT-NOT-FILE", _mkdir("dir")),
    Case("calibrate -o the video", _calib(out="{ev}/scan.mp4"), "E-OUTPUT-HOLDS-INPUT"),
    Case("calibrate -o the picks", _calib(out="{ev}/picks.json"), "E-OUTPUT-HOLDS-INPUT"),
    Case("calibrate -o a foreign file", _calib(out="{box}/report.docx"), "E-OUTPUT-EXISTS",
         _write("report.docx", "case report")),
    Case("calibrate -o another kind of JSON", _calib(out="{box}/other.json"), "E-OUTPUT-EXISTS",
         _write("other.json", json.dumps({"format": "impress.picks", "version": 1}))),
    Case("calibrate -o a link", _calib(out="{box}/l.json"), "E-OUTPUT-LINK",
         _chain(_write("t.json", "{}"), _symlink("l.json", "t.json"))),
    Case("calibrate -o the current folder", _calib(out="."), "E-OUTPUT-UNSAFE"),
    Case("calibrate-camera -o a folder",
         ["calibrate-camera", "{ev}/scan.mp4", "-o", "{box}/d.json"], "E-OUTPUT-NOT-FILE",
         _mkdir("d.json")),
    Case("calibrate-camera -o the input", ["calibrate-camera", "{box}/cb.json", "-o",
                                           "{box}/cb.json"], "E-OUTPUT-HOLDS-INPUT",
         _write("cb.json", "{}")),
    Case("simulate into a foreign folder", ["simulate", "{box}/photos", "--preset", "flat"],
         "E-OUTPUT-NOT-EMPTY", _mkdir("photos", {"a.jpg": b"photo"})),
    Case("simulate into the evidence folder", ["simulate", "{ev}", "--preset", "flat"],
         "E-OUTPUT-NOT-EMPTY"),
    Case("simulate into a file", ["simulate", "{ev}/scan.mp4", "--preset", "flat"],
         "E-OUTPUT-NOT-FOLDER"),
    Case("simulate into a link", ["simulate", "{box}/sl", "--preset", "flat"], "E-OUTPUT-LINK",
         _chain(_mkdir("st"), _symlink("sl", "st"))),
    Case("simulate into .", ["simulate", ".", "--preset", "flat"], "E-OUTPUT-UNSAFE"),
    Case("validate into the evidence folder", ["validate", "--quick", "--out", "{ev}"],
         "E-OUTPUT-NOT-EMPTY"),
    Case("validate into a link", ["validate", "--quick", "--out", "{box}/vl"],
         "E-OUTPUT-LINK", _chain(_mkdir("vt"), _symlink("vl", "vt"))),
    # --- options out of range (a hostile-input audit: a billion plane frames hung; 0 and -3
    # were taken as 1; --workers 0 and 100000 were taken) -----------------------------------
    Case("calibrate --plane-frames 0", _calib("{ev}/scan.mp4", "{ev}/intrinsics.json",
                                              "{ev}/picks.json", "{box}/cal.json",
                                              "--plane-frames", "0"), "E-VALUE"),
    Case("calibrate --plane-frames 1e9", _calib("{ev}/scan.mp4", "{ev}/intrinsics.json",
                                                "{ev}/picks.json", "{box}/cal.json",
                                                "--plane-frames", "1000000000"), "E-VALUE"),
    Case("simulate --workers 0", ["simulate", "{box}/sw", "--preset", "flat", "--workers", "0"],
         "E-SIM-OPTION"),
    Case("simulate --workers 100000", ["simulate", "{box}/sw", "--preset", "flat", "--workers",
                                       "100000"], "E-SIM-OPTION"),
    Case("validate --workers 0", ["validate", "--quick", "--out", "{box}/vw", "--workers", "0"],
         "E-VAL-OPTION"),
    # --- item 3: damaged video -----------------------------------------------------------------
    Case("video: missing", _proc(video="{box}/none.mp4"), "E-FILE-MISSING"),
    Case("video: empty", _proc(video="{box}/e.mp4"), "E-VIDEO-EMPTY", _write("e.mp4", b"")),
    Case("video: text", _proc(video="{box}/t.mp4"), "E-VIDEO-OPEN", _write("t.mp4", "hello")),
    Case("video: random bytes", _proc(video="{box}/r.mp4"), "E-VIDEO-OPEN",
         _write("r.mp4", bytes(range(256)) * 4000)),
    Case("video: a JSON file", _proc(video="{ev}/picks.json"), "E-VIDEO-OPEN"),
    Case("video: a FIFO", _proc(video="{box}/fifo.mp4"), "E-NOT-A-FILE", _fifo("fifo.mp4")),
    Case("video: /dev/zero", _proc(video="/dev/zero"), "E-NOT-A-FILE"),
    Case("video: /dev/null", _proc(video="/dev/null"), "E-NOT-A-FILE"),
    Case("video: a sparse 70 GB file", _proc(video="{box}/huge.mp4"), "E-TOO-LARGE",
         _sparse("huge.mp4", 70 << 30)),
    Case("video: an empty folder", _proc(video="{box}/nof"), "E-VIDEO-EMPTY", _mkdir("nof")),
    Case("video: a frame folder of broken images", _proc(video="{box}/bad"), "E-VIDEO-OPEN",
         _mkdir("bad", {"f0.png": b"not a png", "f1.png": b"nor this"})),
    Case("video: MP4 cut at 30 %", _proc(video="{box}/c30.mp4"), "E-VIDEO-OPEN",
         _cut("scan.mp4", "c30.mp4", 0.30)),
    Case("video: MP4 cut at 95 %", _proc(video="{box}/c95.mp4"), "E-VIDEO-OPEN",
         _cut("scan.mp4", "c95.mp4", 0.95)),
    Case("video: MP4 cut to its first 2 kB", _proc(video="{box}/c0.mp4"), "E-VIDEO-OPEN",
         _cut("scan.mp4", "c0.mp4", 0.001)),
    Case("video: MP4 with 200 damaged bytes (0xff)", _proc(video="{box}/d1.mp4"),
         "W-VIDEO-DAMAGED", _corrupt_packet("scan.mp4", "d1.mp4", 0.35)),
    Case("video: MP4 with 200 damaged bytes (zeros)", _proc(video="{box}/d2.mp4"),
         "W-VIDEO-DAMAGED", _corrupt_packet("scan.mp4", "d2.mp4", 0.25, b"\0" * 200)),
    Case("video: MP4 with 200 damaged bytes (ramp)", _proc(video="{box}/d3.mp4"),
         "W-VIDEO-DAMAGED", _corrupt_packet("scan.mp4", "d3.mp4", 0.35, bytes(range(200)))),
    Case("video: MTS cut at 30 %", _proc(video="{box}/c30.mts", cal="{ev}/mts_cal.json"),
         "W-VIDEO-TRUNCATED", _cut("scan.mts", "c30.mts", 0.30)),
    Case("video: MTS cut at 60 %", _proc(video="{box}/c60.mts", cal="{ev}/mts_cal.json"),
         "W-VIDEO-TRUNCATED", _cut("scan.mts", "c60.mts", 0.60)),
    Case("video: MTS cut at 95 % and 100 bytes",
         _proc(video="{box}/c95.mts", cal="{ev}/mts_cal.json"), "W-VIDEO-TRUNCATED",
         _cut("scan.mts", "c95.mts", 0.95, 100)),
    Case("video: MTS cut at 77 %", _proc(video="{box}/c77.mts", cal="{ev}/mts_cal.json"),
         "W-VIDEO-TRUNCATED", _cut("scan.mts", "c77.mts", 0.77)),
    Case("calibrate on a damaged calibration frame", _calib(video="{box}/dc.mp4"),
         "E-VIDEO-DAMAGED", _corrupt_packet("scan.mp4", "dc.mp4", "t1")),
    Case("calibrate on an MTS cut before t1", _calib(video="{box}/m.mts", out="{box}/m.json"),
         "E-FRAME-RANGE", _cut("scan.mts", "m.mts", 0.05)),
    # --- item 8: calibration files --------------------------------------------------------------
    Case("calibration: missing", _proc(cal="{box}/none.json"), "E-FILE-MISSING"),
    Case("calibration: a folder", _proc(cal="{box}/cd"), "E-NOT-A-FILE", _mkdir("cd")),
    Case("calibration: a FIFO", _proc(cal="{box}/cf"), "E-NOT-A-FILE", _fifo("cf")),
    Case("calibration: /dev/zero", _proc(cal="/dev/zero"), "E-NOT-A-FILE"),
    Case("calibration: empty", _proc(cal="{box}/ce.json"), "E-FILE-EMPTY",
         _write("ce.json", b"")),
    Case("calibration: 60 MB", _proc(cal="{box}/cbig.json"), "E-TOO-LARGE",
         _sparse("cbig.json", 60 << 20)),
    Case("calibration: not UTF-8", _proc(cal="{box}/c8.json"), "E-JSON",
         _write("c8.json", b"\xff\xfe{\x00")),
    Case("calibration: not JSON", _proc(cal="{box}/cj.json"), "E-JSON",
         _write("cj.json", "{speed: fast")),
    Case("calibration: a JSON list", _proc(cal="{box}/cl.json"), "E-FORMAT",
         _write("cl.json", "[1, 2, 3]")),
    Case("calibration: nested 100000 deep", _proc(cal="{box}/cn.json"), "E-JSON",
         _write("cn.json", "[" * 100000 + "]" * 100000)),
    Case("calibration: NaN", _proc(cal="{box}/cnan.json"), "E-JSON",
         _json_edit("calibration.json", "cnan.json",
                    lambda d: json.dumps(d).replace('"fps": 30.0', '"fps": NaN'))),
    Case("calibration: wrong format", _proc(cal="{ev}/picks.json"), "E-WRONG-FORMAT"),
    Case("calibration: version 99", _proc(cal="{box}/cv.json"), "E-VERSION",
         _json_edit("calibration.json", "cv.json", _cal_set("version", 99))),
    # the audit of 4 December 2026: a range past the video's end was cut to it silently
    Case("frames: a range past the video's end",
         ["process", "{ev}/scan.mp4", "--calibration", "{ev}/calibration.json", "-o",
          "{box}/out", "--frames", "180:99999999999", "--no-texture"], "W-FRAME-RANGE"),
    # the audit of 4 December 2026: a calibration made from picks with t1 and t2 swapped put
    # the red plane through the camera's centre; processing ran with the red laser silently
    # lost (calibrate now refuses such a plane, and processing with one is refused)
    Case("calibration: red plane through the camera", _proc(cal="{box}/crp.json"), "E-CALIB",
         _json_edit("calibration.json", "crp.json", lambda d: d["laser_planes"]["red"].update(
             normal=[-0.03464613435775545, -0.9917588055364139, 0.12334551882841141],
             offset_mm=-0.007575268009347271))),
    Case("calibration: speed 1e-300", _proc(cal="{box}/cs.json"), "E-VALUE",
         _json_edit("calibration.json", "cs.json", _cal_set("speed_mm_s", 1e-300))),
    Case("calibration: speed 1e9", _proc(cal="{box}/cs9.json"), "E-VALUE",
         _json_edit("calibration.json", "cs9.json", _cal_set("speed_mm_s", 1e9))),
    Case("calibration: negative speed", _proc(cal="{box}/csn.json"), "E-VALUE",
         _json_edit("calibration.json", "csn.json", _cal_set("speed_mm_s", -13.1))),
    # a hostile-input audit: an all-zero rotation went on to numpy warnings and E-NO-STRIPE
    Case("calibration: a rotation of zeros", _proc(cal="{box}/crz.json"), "E-VALUE",
         _json_edit("calibration.json", "crz.json",
                    _cal_set("rotation_camera_to_ideal", [[0.0] * 3] * 3))),
    Case("calibration: a scaled rotation", _proc(cal="{box}/crs.json"), "E-VALUE",
         _json_edit("calibration.json", "crs.json",
                    _cal_set("rotation_camera_to_ideal", [[2.0, 0, 0], [0, 2.0, 0],
                                                          [0, 0, 2.0]]))),
    Case("calibration: fps 1e12", _proc(cal="{box}/cfps.json"), "E-VALUE",
         _json_edit("calibration.json", "cfps.json", _cal_set("fps", 1e12))),
    Case("calibration: fps 0", _proc(cal="{box}/cf0.json"), "E-VALUE",
         _json_edit("calibration.json", "cf0.json", _cal_set("fps", 0))),
    Case("calibration: t1 1e12", _proc(cal="{box}/ct1.json"), "E-VALUE",
         _json_edit("calibration.json", "ct1.json", _cal_set("t1", 10**12))),
    Case("calibration: t2 negative", _proc(cal="{box}/ct2.json"), "E-VALUE",
         _json_edit("calibration.json", "ct2.json", _cal_set("t2", -5))),
    Case("calibration: t_ref 1e300", _proc(cal="{box}/ctr.json"), "E-VALUE",
         _json_edit("calibration.json", "ctr.json", _cal_set("t_ref_s", 1e300))),
    Case("calibration: speed as text", _proc(cal="{box}/cst.json"), "E-FORMAT",
         _json_edit("calibration.json", "cst.json", _cal_set("speed_mm_s", "fast"))),
    Case("calibration: speed true", _proc(cal="{box}/csb.json"), "E-FORMAT",
         _json_edit("calibration.json", "csb.json", _cal_set("speed_mm_s", True))),
    Case("calibration: no red plane", _proc(cal="{box}/cr.json"), "E-FORMAT",
         _json_edit("calibration.json", "cr.json",
                    lambda d: d["laser_planes"].pop("red"))),
    Case("calibration: planes as a list", _proc(cal="{box}/cpl.json"), "E-FORMAT",
         _json_edit("calibration.json", "cpl.json", _cal_set("laser_planes", [1, 2]))),
    Case("calibration: rotation of the wrong shape", _proc(cal="{box}/crot.json"), "E-FORMAT",
         _json_edit("calibration.json", "crot.json",
                    _cal_set("rotation_camera_to_ideal", [[1, 0], [0, 1]]))),
    Case("calibration: a huge number", _proc(cal="{box}/chuge.json"), "E-FORMAT",
         _json_edit("calibration.json", "chuge.json",
                    _cal_set("motion_direction_camera", [1e300, 0, 0]))),
    Case("calibration: intrinsics missing", _proc(cal="{box}/cin.json"), "E-FORMAT",
         _json_edit("calibration.json", "cin.json", lambda d: d.pop("intrinsics"))),
    Case("calibration: of another image size", _proc(cal="{box}/csz.json"), "E-SIZE-MISMATCH",
         _json_edit("calibration.json", "csz.json",
                    lambda d: d["intrinsics"].__setitem__("image_size", [1920, 1080]))),
    Case("calibration: a link to the video", _proc(cal="{box}/cvl.json"), "E-JSON",
         _symlink("cvl.json", "ev/scan.mp4")),
    # --- calibrate's other inputs ----------------------------------------------------------------
    Case("intrinsics: missing", _calib(intr="{box}/no.json"), "E-FILE-MISSING"),
    Case("intrinsics: a folder", _calib(intr="{box}/idir"), "E-NOT-A-FILE", _mkdir("idir")),
    Case("intrinsics: garbage", _calib(intr="{box}/ig.json"), "E-JSON",
         _write("ig.json", "\x00\x01garbage")),
    Case("intrinsics: a calibration instead", _calib(intr="{ev}/calibration.json"),
         "E-WRONG-FORMAT"),
    # a second audit: 1e-300 px focal lengths ended in E-INTERNAL (an SVD that did not
    # converge); a matrix whose last row is zeros was accepted and saved in the calibration
    Case("intrinsics: focal lengths of 1e-300 px", _calib(intr="{box}/if.json"), "E-FORMAT",
         _json_edit("intrinsics.json", "if.json",
                    lambda d: [d["camera_matrix"][0].__setitem__(0, 1e-300),
                               d["camera_matrix"][1].__setitem__(1, 1e-300)])),
    Case("intrinsics: a last row of zeros", _calib(intr="{box}/iz.json"), "E-FORMAT",
         _json_edit("intrinsics.json", "iz.json",
                    lambda d: d["camera_matrix"].__setitem__(2, [0, 0, 0]))),
    Case("picks: a FIFO", _calib(picks="{box}/pf"), "E-NOT-A-FILE", _fifo("pf")),
    Case("picks: corners missing", _calib(picks="{box}/pm.json"), "E-PICKS-INCOMPLETE",
         _json_edit("picks.json", "pm.json",
                    lambda d: d["corners"]["t1"].pop("A") if "corners" in d else
                    d["corners_t1"].pop("A"))),
    # a second audit: a number for the video's hash was accepted and the check against the
    # video silently off
    Case("picks: the video's hash a number", _calib(picks="{box}/ph.json"), "E-FORMAT",
         _json_edit("picks.json", "ph.json", _cal_set("video_sha256", 12))),
    Case("picks: t1 outside the video", _calib(picks="{box}/pt.json"), "E-FRAME-RANGE",
         _json_edit("picks.json", "pt.json", _cal_set("t1", 99999))),
    Case("picks: t1 = t2", _calib(picks="{box}/pe.json"), "E-PICKS",
         _json_edit("picks.json", "pe.json", lambda d: d.__setitem__("t2", d["t1"]))),
    Case("target: garbage", _calib() + ["--target", "{box}/tg.json"], "E-JSON",
         _write("tg.json", "not json")),
    Case("target: a folder", _calib() + ["--target", "{box}/td"], "E-NOT-A-FILE",
         _mkdir("td")),
    # --- numbers on the command line ---------------------------------------------------------------
    Case("process --fps nan", _proc() + ["--fps", "nan"], "E-USAGE"),
    Case("process --fps inf", _proc() + ["--fps", "inf"], "E-USAGE"),
    Case("process --fps 1e12", _proc() + ["--fps", "1e12"], "E-VALUE"),
    Case("process --fps -30", _proc() + ["--fps", "-30"], "E-VALUE"),
    Case("process --grid-mm nan", _proc() + ["--grid-mm", "nan"], "E-USAGE"),
    Case("process --grid-mm 0", _proc() + ["--grid-mm", "0"], "E-PARAM"),
    Case("process --grid-mm 1e-9", _proc() + ["--grid-mm", "1e-9"], "E-PARAM"),
    Case("process --min-peak -1e308", _proc() + ["--min-peak=-1e308"], "E-PARAM"),
    Case("process --frames 100:40", _proc() + ["--frames", "100:40"], "E-PARAM"),
    Case("process --frames abc", _proc() + ["--frames", "abc"], "E-USAGE"),
    Case("process --roi green=9:1", _proc() + ["--roi", "green=9:1"], "E-PARAM"),
    Case("calibrate --speed nan", _calib() + ["--speed", "nan"], "E-USAGE"),
    Case("calibrate --speed 1e9", _calib() + ["--speed", "1e9"], "E-USAGE"),
    Case("calibrate --speed 0", _calib() + ["--speed", "0"], "E-USAGE"),
    Case("calibrate --fps inf", _calib() + ["--fps", "inf"], "E-USAGE"),
    Case("simulate --fps nan", ["simulate", "{box}/s", "--fps", "nan"], "E-USAGE"),
    Case("simulate --length-mm -5", ["simulate", "{box}/s", "--length-mm", "-5"],
         "E-SIM-OPTION"),
    # --- the command line itself --------------------------------------------------------------------
    Case("a mistyped command", ["proces", "x"], "E-USAGE"),
    Case("an unknown command with --help", ["contrast", "--help"], "E-USAGE"),
    Case("process without arguments", ["process"], "E-USAGE"),
    Case("process with an unknown option", _proc() + ["--turbo"], "E-USAGE"),
]


@pytest.fixture(scope="module")
def evidence(flat_scan, flat_calibration, tmp_path_factory) -> Path:
    """The evidence every case starts from: the flat scan (MP4, and the same as an MTS), its
    intrinsics, picks and calibrations (one of each video)."""
    ev = tmp_path_factory.mktemp("evidence")
    for name in ("scan.mp4", "intrinsics.json", "picks.json", "target.json"):
        shutil.copy2(flat_scan / name, ev / name)
    shutil.copy2(flat_calibration, ev / "calibration.json")
    _mpegts_copy(flat_scan / "scan.mp4", ev / "scan.mts")
    calibrate_scan(flat_scan, ev / "mts_cal.json", video=ev / "scan.mts")
    return ev


def _mpegts_copy(mp4: Path, mts: Path) -> None:
    """The MP4's H.264 stream, packet for packet, in an MPEG-TS container: the simulator's
    ``video_format="mts"`` writes the same encoder's stream into the same container (the
    same start time, the same 241 packets within a byte of each other's size), without
    rendering the scan a second time."""
    import av

    with av.open(str(mp4)) as src, av.open(str(mts), "w", format="mpegts") as dst:
        stream = src.streams.video[0]
        out = dst.add_stream_from_template(stream)
        for packet in src.demux(stream):
            if packet.dts is not None:  # not the demuxer's final empty packet
                packet.stream = out
                dst.mux(packet)


def _snapshot(root: Path, skip: Path | None) -> dict[str, str]:
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        d = Path(dirpath)
        if skip is not None and (d == skip or skip in d.parents):
            dirnames[:] = []
            continue
        for name in dirnames + filenames:
            p = d / name
            if skip is not None and p == skip:
                continue
            rel = str(p.relative_to(root))
            if p.is_symlink():
                out[rel] = "link:" + os.readlink(p)
            elif p.is_file():
                out[rel] = hashlib.sha256(p.read_bytes()).hexdigest() if p.stat().st_size < (
                    1 << 30) else f"size:{p.stat().st_size}"
            elif p.is_dir():
                out[rel] = "dir"
            else:
                out[rel] = "special"
    return out


def test_the_table_is_large_enough():
    assert len(CASES) >= 100
    assert len({c.name for c in CASES}) == len(CASES)


@pytest.mark.timeout(120, func_only=True)
@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_hostile_input(case: Case, evidence, tmp_path, capsys, monkeypatch):
    box = tmp_path / "box"
    ev = box / "ev"
    shutil.copytree(evidence, ev)
    if case.setup is not None:
        case.setup(box)
    argv = [a.replace("{ev}", str(ev)).replace("{box}", str(box)) for a in case.argv]
    # the named output (after -o, or simulate's folder) may appear; nothing else may change
    named = None
    for flag in ("-o", "--output", "--out"):
        if flag in argv:
            named = Path(argv[argv.index(flag) + 1])
    if argv[0] == "simulate":
        named = Path(argv[1])
    if named is not None and not named.is_absolute():
        named = box / named
    skip = named if (named is not None and box in named.parents
                     and not named.exists()) else None
    monkeypatch.chdir(tmp_path)
    before = _snapshot(box, skip)
    try:
        code = cli.main(argv)
    except SystemExit as exc:  # argparse
        code = exc.code
    out, err = capsys.readouterr()
    text = out + err
    for leak in LEAKS:
        assert leak not in text, f"{case.name}: {leak!r} in {text!r}"
    after = _snapshot(box, skip)
    assert after == before, f"{case.name}: files outside the output changed"
    if case.expect.startswith("E-"):
        assert code == 2, f"{case.name}: exit {code}; {text}"
        assert f"[{case.expect}]" in text, f"{case.name}: {text}"
    else:
        assert code == 0, f"{case.name}: exit {code}; {text}"
        assert case.expect in text, f"{case.name}: {text}"
        meta = json.loads((named / "metadata.json").read_text())
        assert any(w.startswith(case.expect) for w in meta["warnings"]), meta["warnings"]


@pytest.mark.timeout(60, func_only=True)
@pytest.mark.parametrize("member", ["metadata.json", "heightmap.tif", "texture.png", "folder"])
def test_a_reconstruction_folder_with_a_fifo_never_hangs(member, tmp_path):
    """The reconstruction reader (viewer, cast, validation) refuses a pipe or a folder where
    a file belongs, instead of waiting on it forever."""
    from impress_gui.core.base.errors import ImpressError
    from impress_gui.core.measure.readings import load_reconstruction

    rec = tmp_path / "recon"
    rec.mkdir()
    meta = {"format": "impress.reconstruction", "version": 1,
            "grid": {"x0_mm": 0.0, "y0_mm": 0.0, "pixel_mm": 0.1, "shape": [4, 5]}}
    import numpy as np
    import tifffile

    if member == "folder":
        target = tmp_path / "afile"
        target.write_text("x")
        with pytest.raises(ImpressError) as err:
            load_reconstruction(target)
        assert err.value.code == "E-NOT-A-FILE"
        return
    (rec / "metadata.json").write_text(json.dumps(meta))
    tifffile.imwrite(rec / "heightmap.tif", np.zeros((4, 5), np.float32))
    (rec / member).unlink(missing_ok=True)
    os.mkfifo(rec / member)
    with pytest.raises(ImpressError) as err:
        load_reconstruction(rec)
    assert err.value.code == "E-NOT-A-FILE"
