"""Running the validation protocol (Qt-free): simulator scans or a real scan's spec -> record.

:func:`run_simulated` renders (or reuses) a simulator scan per item - the six placements of
the ``blocks`` preset, ``flat`` and ``spheres`` -, calibrates it from its corner picks,
reconstructs it with the product's pipeline and measures it (:mod:`impress_gui.validation.protocol`).
:func:`run_real` measures reconstructions of physical artefacts from a spec file. Both return
a record (format :data:`RECORD_FORMAT`) that :mod:`impress_gui.validation.report` turns
into the table and the report.

Folder layout under ``out_dir``::

    scans/<item>/        simulator output (video, truth, picks, intrinsics), reused while the
                         scan's settings are unchanged (``fresh``: render again)
    runs/<item>/         calibration.json and reconstruction/ of this run
    validation.json      the record; validation-spec.json the readings as a real-scan spec
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import platform
import shutil
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

from impress_gui import __version__
from impress_gui.core.base import codes
from impress_gui.core.base.errors import InputError
from impress_gui.core.base.fileio import sha256_file, write_json
from impress_gui.core.base.progress import CancelToken, ProgressCallback, report, sub_progress
from impress_gui.core.formats.provenance import calibration_inputs, input_record
from impress_gui.core.formats.recon_files import (
    HEIGHTMAP_FILE,
    METADATA_FILE,
    RECON_FILES,
    RUN_FILE,
)
from impress_gui.validation import protocol as V
from impress_gui.validation import spec as S
from impress_gui.validation import vdi as VDI

if TYPE_CHECKING:  # imported where used: the simulator and the pipeline are heavy
    from impress_gui.core.measure.readings import ReconData
    from impress_gui.core.reconstruction.reconstruct import ProcessParams
    from impress_gui.sim.simulate import SimConfig

RECORD_FORMAT = "impress.validation"
EXTRAS = ("flat", "spheres")


class _SimCommon(TypedDict):
    """The :class:`~impress_gui.sim.simulate.SimConfig` settings every item of a run shares."""

    width: int
    height: int
    speed_mm_s: float
    seed: int
    click_noise_px: float


@dataclass(frozen=True)
class RunConfig:
    """Settings of a simulated validation run. Use :meth:`quick` or :meth:`full`."""

    mode: str = "quick"
    width: int = 640
    height: int = 360
    speed_mm_s: float = 39.414
    blocks_length_mm: float = 440.0
    flat_length_mm: float = 160.0
    spheres_length_mm: float = 220.0
    placements: tuple[str, ...] = tuple(p.key for p in V.PLACEMENTS)
    extras: tuple[str, ...] = EXTRAS
    click_noise_px: float = 0.0
    seed: int = 1
    workers: int = 2
    reuse_scans: bool = True
    #: keep every file of each reconstruction; by default only what the record and the report
    #: need stays (the fused heightmap, metadata.json, run.json): a quick run wrote about 2 GB
    keep_reconstructions: bool = False
    #: the rail raised for "B lifted by 40 mm": at the default 300 mm the two laser planes cross
    #: 67 mm above the ground and the stair on the lifted plate reaches 77 mm
    lifted_standoff_mm: float = 380.0
    #: the calibration Monte Carlo's trials behind each reading's stated uncertainty (the
    #: product's default, 60, states a reading's SD to about 7 % of itself; fewer: faster, the
    #: stated U itself less certain); the same as core.calibration.uncertainty.DEFAULT_TRIALS
    #: (not imported here: this module loads without the calibration's; a test checks it)
    uncertainty_trials: int = 60

    @classmethod
    def quick(cls, **kw: Any) -> RunConfig:
        """640x360 at three times the fast rail speed: minutes, not hours; xy accuracy is
        limited by the 0.38 mm camera pixel on the targets."""
        return cls(**kw)

    @classmethod
    def full(cls, **kw: Any) -> RunConfig:
        base: dict[str, Any] = dict(
            mode="full",
            width=1920,
            height=1080,
            speed_mm_s=13.138,
            blocks_length_mm=480.0,
            flat_length_mm=260.0,
            spheres_length_mm=300.0,
        )
        return cls(**(base | kw))

    def validate(self) -> None:
        unknown = set(self.placements) - set(V.PLACEMENT_BY_KEY)
        if unknown:
            raise InputError(
                f"unknown placements {sorted(unknown)}; choose from "
                f"{', '.join(V.PLACEMENT_BY_KEY)}",
                code=codes.E_VAL_OPTION,
            )
        if set(self.extras) - set(EXTRAS):
            raise InputError(
                f"unknown extras {sorted(set(self.extras) - set(EXTRAS))}", code=codes.E_VAL_OPTION
            )
        if not self.placements and not self.extras:
            raise InputError("nothing to validate", code=codes.E_VAL_OPTION)
        if not 4 <= self.uncertainty_trials <= 1000:
            raise InputError(f"uncertainty trials {self.uncertainty_trials}: give 4 to 1000",
                             code=codes.E_VAL_OPTION)
        for sc in self.sim_configs().values():
            sc.validate()

    def to_json(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["placements"], d["extras"] = list(self.placements), list(self.extras)
        return d

    def sim_configs(self) -> dict[str, SimConfig]:
        """``{item: SimConfig}`` in table order: placements, then the extras."""
        from impress_gui.sim.simulate import SimConfig

        common = _SimCommon(
            width=self.width,
            height=self.height,
            speed_mm_s=self.speed_mm_s,
            seed=self.seed,
            click_noise_px=self.click_noise_px,
        )
        out: dict[str, SimConfig] = {}
        for key in self.placements:
            p = V.PLACEMENT_BY_KEY[key]
            sc = SimConfig(
                preset="blocks",
                length_mm=self.blocks_length_mm,
                blocks=p.blocks_options(),
                **common,
            )
            if p.lift_b_mm:
                sc = dataclasses.replace(sc, standoff_mm=self.lifted_standoff_mm)
            out[key] = sc
        if "flat" in self.extras:
            out["flat"] = SimConfig(preset="flat", length_mm=self.flat_length_mm, **common)
        if "spheres" in self.extras:
            out["spheres"] = SimConfig(preset="spheres", length_mm=self.spheres_length_mm, **common)
        return out


def simulator_sha256() -> str:
    """Hash of the simulator's code (recorded with each scan it renders)."""
    import impress_gui.sim as sim_pkg

    h = hashlib.sha256()
    import impress_gui.core.calibration as calibration_pkg

    core = Path(calibration_pkg.__file__).parent
    files = sorted(Path(sim_pkg.__file__).parent.glob("*.py"))
    files += [core / n for n in ("target.py", "geometry.py", "picks.py")]
    for f in files:
        h.update(f.read_bytes())
    return h.hexdigest()


def _same_config(truth: dict[str, Any], sim_cfg: SimConfig) -> bool:
    a = json.dumps(truth.get("config"), sort_keys=True)
    # as the simulator writes it into truth.json (SimConfig.to_json: unset options left out)
    return a == json.dumps(json.loads(json.dumps(sim_cfg.to_json())), sort_keys=True)


def produce_scan(
    sim_cfg: SimConfig,
    folder: Path,
    workers: int = 2,
    reuse: bool = True,
    progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
) -> bool:
    """Render ``sim_cfg`` into ``folder`` unless a complete scan of the same settings is there
    (its truth.json, written last, records them) with its video unchanged. A scan rendered by
    an older simulator is reused too (the video and its truth stay consistent); the record
    says which simulator made it. Returns True when it rendered."""
    from impress_gui.sim.simulate import simulate

    truth_path = folder / "truth.json"
    if reuse and truth_path.is_file():
        try:
            truth = json.loads(truth_path.read_text())
            ok = _same_config(truth, sim_cfg) and truth.get("video_sha256") == sha256_file(
                folder / truth["video"]
            )
        except (OSError, ValueError, KeyError, TypeError):
            ok = False
        if ok:
            report(progress, 1.0, "reusing the rendered scan")
            return False
    if folder.exists():
        shutil.rmtree(folder)
    code = simulator_sha256()
    simulate(sim_cfg, folder, workers=workers, progress=progress, cancel=cancel)
    (folder / "simulator.txt").write_text(code + "\n")
    return True


def _calibrate_and_process(
    scan: Path,
    run_dir: Path,
    params: ProcessParams,
    progress: ProgressCallback | None,
    cancel: CancelToken | None,
) -> dict[str, Any]:
    from impress_gui.core.calibration.geometry import Intrinsics
    from impress_gui.core.calibration.picks import Picks
    from impress_gui.core.calibration.scene import calibrate_scene
    from impress_gui.core.calibration.target import TargetModel
    from impress_gui.core.formats.video import open_video
    from impress_gui.core.reconstruction.pipeline import process_files

    truth = json.loads((scan / "truth.json").read_text())
    video = scan / truth["video"]
    inputs = {
        n: input_record(scan / f, sha256_file(scan / f))
        for n, f in (
            ("video", truth["video"]),
            ("intrinsics", "intrinsics.json"),
            ("picks", "picks.json"),
            ("target", "target.json"),
            ("truth", "truth.json"),
        )
    }
    run_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with open_video(video) as v:
        cal = calibrate_scene(
            v,
            Intrinsics.load(scan / "intrinsics.json"),
            TargetModel.load(scan / "target.json"),
            Picks.load(scan / "picks.json"),
            truth["speed_mm_s"],
            progress=sub_progress(progress, 0.0, 0.2),
            cancel=cancel,
            inputs=calibration_inputs(inputs["video"], inputs["intrinsics"], picks=inputs["picks"]),
        )
    cal_path = run_dir / "calibration.json"
    cal.save(cal_path)
    t_cal = time.perf_counter() - t0
    meta = process_files(
        video,
        cal_path,
        run_dir / "reconstruction",
        params,
        progress=sub_progress(progress, 0.2, 1.0),
        cancel=cancel,
    )
    inputs["calibration"] = input_record(cal_path, sha256_file(cal_path))
    return {
        "inputs": inputs,
        "parameters": params.to_json(),
        "reconstruction": {
            "path": str(run_dir / "reconstruction"),
            "files": meta["files"],
            "warnings": meta["warnings"],
        },
        "calibration": {
            "roll_deg": cal.roll_deg,
            "tilt_deg": cal.tilt_deg,
            "reprojection_rms_px": cal.reprojection_rms_px,
            "implied_speed_mm_s": cal.implied_speed_mm_s,
            "warnings": list(cal.warnings),
        },
        "seconds": {"calibration": round(t_cal, 1), "processing": meta["run"]["wall_seconds"]},
    }


def _flat_region(
    rec: ReconData, truth: dict[str, Any]
) -> tuple[tuple[float, float], tuple[float, float]]:
    """Ground beyond the L target (world y > 90 mm), x within +-60 mm, limited to the rows
    the scan covered (95 % of the cells have data)."""
    import numpy as np

    s1 = truth["travel_mm"][truth["calibration_frames"]["t1"]]
    xr = (-60.0, 60.0)
    sub, sspec = V.crop(rec.height_mm, rec.spec, xr, (90.0 - s1, truth["length_mm"] + 60 - s1))
    rows = np.flatnonzero(np.isfinite(sub).mean(1) >= 0.95)
    if rows.size < 50:
        raise InputError(
            "the flat scan covers too little ground beyond the target", code=codes.E_VAL_COVERAGE
        )
    ys = sspec.ys()
    return xr, (float(ys[rows[0]]), float(ys[rows[-1]]))


def uncertainty_contexts(
    rec: ReconData, calibration: Path | None, target: Path | None, trials: int | None = None
) -> V.ContextFactory:
    """The uncertainty context of each validation reading, as the viewer would make it for the
    same cells: the reconstruction's calibration (its Monte Carlo computed once, cached), the
    target it was fitted with, the lasers' contribution codes and the per-laser height maps
    (where the lasers disagreed, the kept laser's calibration moves the cell; taken from
    ``rec`` or its folder, None when absent) cropped like the heights, and the weights the
    fusion gave agreeing lasers. ``trials``: the Monte Carlo's (None: its default)."""
    from impress_gui.core.calibration.scene import SceneCalibration
    from impress_gui.core.calibration.target import TargetModel
    from impress_gui.core.measure.uncertainty import (
        UncertaintyContext,
        fusion_weights_of,
        per_laser_maps,
    )

    cal = SceneCalibration.load(calibration) if calibration is not None else None
    model = TargetModel.load(target) if target is not None else None
    contribution = rec.layers.get("contribution")
    per_laser = per_laser_maps(rec) if contribution is not None else None
    weights = fusion_weights_of(rec.metadata)
    p = rec.spec.pixel_mm

    def make(h, sspec, plane):
        i0 = int(round((sspec.y0_mm - rec.spec.y0_mm) / p))
        j0 = int(round((sspec.x0_mm - rec.spec.x0_mm) / p))
        window = (slice(i0, i0 + sspec.shape[0]), slice(j0, j0 + sspec.shape[1]))
        c = None if contribution is None else contribution[window]
        lasers = None if per_laser is None else {n: m[window] for n, m in per_laser.items()}
        return UncertaintyContext.for_calibration(h, sspec, cal, model, c, level_plane=plane,
                                                  trials=trials, per_laser=lasers,
                                                  fusion_weights=weights)

    return make


def _measure_item(
    item: str,
    rec: ReconData,
    truth: dict[str, Any],
    group: str,
    context: V.ContextFactory | None = None,
) -> dict[str, Any]:
    if item in V.PLACEMENT_BY_KEY:
        readings = V.blocks_readings(truth, group)
        return {
            "results": V.measure_all(rec.height_mm, rec.spec, readings, context),
            "readings": readings,
        }
    if item == "flat":
        xr, yr = _flat_region(rec, truth)
        return {"flat": VDI.flatness(rec.height_mm, rec.spec, xr, yr).to_json()}
    s1 = truth["travel_mm"][truth["calibration_frames"]["t1"]]
    spheres: list[tuple[float, float, float, float]] = []
    for f in truth["features"]:
        if f.get("kind") != "sphere":
            continue
        x, y, r = f["x_mm"], f["y_mm"] - s1, f["radius_mm"]
        pts = VDI.sphere_points(rec.height_mm, rec.spec, x, y, r)
        if len(pts) >= 0.5 * math.pi * (0.85 * r / rec.spec.pixel_mm) ** 2:  # covered
            spheres.append((x, y, f["z_mm"], r))
    if len(spheres) < 2:
        raise InputError("fewer than two spheres were scanned", code=codes.E_VAL_COVERAGE)
    return {"spheres": VDI.sphere_errors(rec.height_mm, rec.spec, spheres)}


def _header(kind: str) -> dict[str, Any]:
    return {
        "format": RECORD_FORMAT,
        "version": 1,
        "kind": kind,
        "software": f"impress {__version__}",
        "date_utc": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "host": platform.node(),
        "python": platform.python_version(),
        "thesis": {
            "table": {k: list(v) for k, v in V.THESIS_TABLE.items()},
            "readings": V.THESIS_READINGS,
        },
        "bar": {"xy_mm": V.BAR_XY_MM, "z_mm": V.BAR_Z_MM},
    }


def _finish(record: dict[str, Any], results: list[V.Result], groups: list[str]) -> dict[str, Any]:
    summary = V.summarise(results, groups)
    record["readings"] = [r.to_json() for r in results]
    # issue 22: do the stated uncertainties (U, about 95 %) cover the true errors?
    record["uncertainty_coverage"] = V.coverage(results)
    record["summary"] = {g: {ax: s.to_json() for ax, s in v.items()} for g, v in summary.items()}
    ov = summary["Overall"]
    record["acceptance"] = {
        "xy_mean_mm": V._num(ov["xy"].mean_mm),
        "z_mean_mm": V._num(ov["z"].mean_mm),
        "xy_ok": bool(ov["xy"].n and ov["xy"].mean_mm <= V.BAR_XY_MM and not ov["xy"].failed),
        "z_ok": bool(ov["z"].n and ov["z"].mean_mm <= V.BAR_Z_MM and not ov["z"].failed),
        "all_placements": [p.title for p in V.PLACEMENTS] == groups,
    }
    return record


def prepare_output(out_dir: str | os.PathLike[str], inputs=()) -> Path:
    """The validation folder: new, empty, or one an earlier validation made (it holds the
    reused scans); anything else is refused before any work (``E-OUTPUT-*``). Marked as the
    product's own."""
    from impress_gui.core.base.outdir import (
        MARK_FILE,
        check_output_dir,
        mark_bytes,
        read_mark,
        writing,
    )

    folder = Path(out_dir)
    record = folder / "validation.json"
    try:  # a validation folder of an earlier version (no mark): its record says what it is
        if (folder.is_dir() and not folder.is_symlink() and read_mark(folder) is None
                and record.is_file() and not record.is_symlink()
                and json.loads(record.read_text()).get("format") == RECORD_FORMAT):
            (folder / MARK_FILE).write_bytes(mark_bytes("validation"))
    except (OSError, ValueError, AttributeError):
        pass
    out = check_output_dir(out_dir, "validation", inputs)
    with writing(out):
        out.mkdir(parents=True, exist_ok=True)
        if not (out / MARK_FILE).exists():
            (out / MARK_FILE).write_bytes(mark_bytes("validation"))
    return out


#: what a validation keeps of each reconstruction unless asked for everything: the fused
#: heightmap the readings are measured on (a real-scan spec made from the run measures it
#: again) and the two records that name every file with its SHA-256
KEPT_FILES = (HEIGHTMAP_FILE, METADATA_FILE, RUN_FILE)


def prune_reconstruction(folder: Path) -> list[str]:
    """Delete the files of a validation's own reconstruction that its record and report do
    not need (the point cloud, the per-laser maps, the pictures, the X3P); their SHA-256 stay
    in metadata.json. Returns the names deleted."""
    gone = []
    for name in RECON_FILES:
        f = folder / name
        if name not in KEPT_FILES and f.is_file() and not f.is_symlink():
            f.unlink()
            gone.append(name)
    return gone


def disk_usage_bytes(folder: Path) -> int:
    return sum(f.stat().st_size for f in Path(folder).rglob("*") if f.is_file() and not f.is_symlink())


def _only_marks(folder: Path) -> bool:
    """Whether ``folder`` holds nothing but the product's mark and empty folders."""
    from impress_gui.core.base.outdir import MARK_FILE

    for p in folder.iterdir():
        if p.is_symlink() or (p.is_file() and p.name != MARK_FILE):
            return False
        if p.is_dir() and not _only_marks(p):
            return False
    return True


def _cleared_on_failure(run):
    """``run`` (``run_simulated`` or ``run_real``): a validation folder it made anew and that
    holds nothing of value when the run fails or is interrupted (only its mark and empty
    folders: no scan was kept) is removed again, so no half-made output stays behind. A folder
    that existed, or holds rendered scans to reuse, is left."""
    import functools
    import shutil

    @functools.wraps(run)
    def wrapper(first, out_dir, *args, **kw):
        folder = Path(out_dir)
        existed = folder.exists() or folder.is_symlink()
        try:
            return run(first, out_dir, *args, **kw)
        except BaseException:
            try:
                if not existed and folder.is_dir() and not folder.is_symlink() \
                        and _only_marks(folder):
                    shutil.rmtree(folder)
            except OSError:
                pass
            raise

    return wrapper


@_cleared_on_failure
def run_simulated(
    cfg: RunConfig,
    out_dir: str | os.PathLike[str],
    progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
    scans_dir: str | os.PathLike[str] | None = None,
) -> dict[str, Any]:
    """The protocol on simulator scans; writes ``validation.json`` (and the spec of its
    readings) into ``out_dir`` and returns the record. Rendered scans are kept in
    ``scans_dir`` (default ``out_dir/scans``) and reused while unchanged. A folder made anew
    is removed again when the run fails or is interrupted before any scan was kept."""
    from impress_gui.core.measure.readings import load_reconstruction
    from impress_gui.core.reconstruction.reconstruct import ProcessParams

    cfg.validate()
    cancel = cancel or CancelToken()
    out = prepare_output(out_dir)
    items = cfg.sim_configs()
    record = _header("simulator") | {"config": cfg.to_json(), "scans": []}
    results: list[V.Result] = []
    groups: list[str] = []
    spec_scans: list[tuple[str, str, list[V.Reading]]] = []
    for i, (item, sim_cfg) in enumerate(items.items()):
        part = sub_progress(progress, i / len(items), (i + 1) / len(items))
        title = V.PLACEMENT_BY_KEY[item].title if item in V.PLACEMENT_BY_KEY else item
        cancel.check()
        t0 = time.perf_counter()
        scan = Path(scans_dir or out / "scans") / item
        rendered = produce_scan(
            sim_cfg,
            scan,
            cfg.workers,
            cfg.reuse_scans,
            _labelled(sub_progress(part, 0.0, 0.7), title),
            cancel,
        )
        t_render = time.perf_counter() - t0
        lift = sim_cfg.blocks.get("lift_b_mm", 0.0) if sim_cfg.blocks else 0.0
        # a lifted plate: its top (77 mm) is the tallest surface; the default range reaches
        # past the laser planes' crossing, where the two stripes' bands overlap
        hr = (-20.0, 40.0 + lift) if lift else (-40.0, 60.0)
        params = ProcessParams(texture=False, height_range_mm=hr)
        info = _calibrate_and_process(
            scan,
            out / "runs" / item,
            params,
            _labelled(sub_progress(part, 0.7, 0.97), title),
            cancel,
        )
        report(part, 0.98, f"{title}: measuring")
        truth = json.loads((scan / "truth.json").read_text())
        rec = load_reconstruction(
            out / "runs" / item / "reconstruction",
            layers=("fused", "contribution", "green", "red"),
        )
        context = uncertainty_contexts(
            rec, out / "runs" / item / "calibration.json", scan / "target.json",
            cfg.uncertainty_trials,
        )
        measured = _measure_item(item, rec, truth, title, context)
        del rec
        if not cfg.keep_reconstructions:
            info["reconstruction"]["pruned"] = prune_reconstruction(out / "runs" / item / "reconstruction")
        if "results" in measured:
            results.extend(measured["results"])
            groups.append(title)
            spec_scans.append((title, f"runs/{item}/reconstruction", measured["readings"]))
        else:
            record.update({k: v for k, v in measured.items()})
        info["seconds"]["render"] = round(t_render, 1) if rendered else 0.0
        record["scans"].append(
            {
                "item": item,
                "title": title,
                "sim_config": dataclasses.asdict(sim_cfg),
                "rendered_now": rendered,
                "simulator_sha256": _read_text(scan / "simulator.txt") or "unknown",
            }
            | info
        )
        report(part, 1.0, f"{title}: done")
    _finish(record, results, groups)
    if spec_scans:
        write_json(
            out / "validation-spec.json",
            S.spec_to_json("simulator readings (template)", spec_scans),
        )
    write_json(out / "validation.json", record)
    return record


@_cleared_on_failure
def run_real(
    spec_path: str | os.PathLike[str],
    out_dir: str | os.PathLike[str],
    progress: ProgressCallback | None = None,
    cancel: CancelToken | None = None,
) -> dict[str, Any]:
    """The protocol on reconstructions of physical artefacts: known dimensions and measuring
    positions from a spec file (:data:`validate.SPEC_FORMAT`)."""
    from impress_gui.core.measure.readings import load_reconstruction, verified_heightmap_sha256

    cancel = cancel or CancelToken()
    name, scans = S.load_spec(spec_path)
    # the reconstructions the spec names are inputs too: the output never goes into one
    out = prepare_output(out_dir, inputs=(spec_path, *(s.reconstruction for s in scans)))
    record = _header("real") | {
        "name": name,
        "scans": [],
        "spec": input_record(spec_path, sha256_file(spec_path)),
    }
    results: list[V.Result] = []
    groups: list[str] = []
    for i, s in enumerate(scans):
        cancel.check()
        report(progress, i / len(scans), f"{s.name}: measuring")
        rec = load_reconstruction(s.reconstruction, layers=("fused",))
        # the map measured must be the one its metadata records (as cast and compare check)
        verified_heightmap_sha256(s.reconstruction, rec.metadata, codes.E_VALIDATE_HASH)
        res = V.measure_all(rec.height_mm, rec.spec, s.readings)
        results.extend(res)
        groups.append(s.name)
        meta = dict(rec.metadata)
        record["scans"].append(
            {
                "item": s.name,
                "title": s.name,
                "reconstruction": {"path": str(s.reconstruction), "files": meta.get("files", {})},
                "inputs": meta.get("inputs", {}),
                "parameters": meta.get("parameters", {}),
                "software": meta.get("software"),
            }
        )
    report(progress, 1.0, "done")
    _finish(record, results, groups)
    write_json(out / "validation.json", record)
    return record


def _read_text(path: Path) -> str | None:
    try:
        return path.read_text().strip()
    except OSError:
        return None


def _labelled(progress: ProgressCallback | None, title: str) -> ProgressCallback | None:
    if progress is None:
        return None
    return lambda f, msg: progress(f, f"{title}: {msg}")
