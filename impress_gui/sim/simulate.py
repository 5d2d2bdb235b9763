"""``impress simulate``: render a scan and write its exact ground truth beside it."""

from __future__ import annotations

import dataclasses
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from impress_gui import __version__
from impress_gui.core.base import codes
from impress_gui.core.base.errors import InputError
from impress_gui.core.base.fileio import atomic_write_bytes, sha256_path, write_json
from impress_gui.core.base.outdir import OutputFolder
from impress_gui.core.base.progress import CancelToken, ProgressCallback, report
from impress_gui.core.calibration.geometry import Plane, rail_shift
from impress_gui.core.calibration.picks import Picks
from impress_gui.core.calibration.target import CORNER_NAMES, TargetModel, default_target
from impress_gui.core.formats.images import png_bytes, tiff_bytes
from impress_gui.sim.rig import Motion, Rig, default_rig
from impress_gui.sim.scenes import DEFAULT_LENGTH_MM, PRESETS, build_scene

TRUTH_FORMAT = "impress.sim-truth"
SPEED_NAMES = {"slow": 1.3138, "medium": 5.2552, "fast": 13.138}


@dataclass(frozen=True)
class SimConfig:
    preset: str = "shoe"
    length_mm: float | None = None
    speed_mm_s: float = 13.138
    fps: float = 30.0
    width: int = 1920
    height: int = 1080
    roll_deg: float = 1.2
    tilt_deg: float = -1.8
    standoff_mm: float = 300.0
    seed: int = 1
    video_format: str = "mp4"  # mp4 | mov | mts | frames
    bitrate_mbit: float | None = None
    speckle: float = 0.3
    noise_dn: float = 2.0
    grid_mm: float = 0.1
    ramp_s: float = 0.4
    click_noise_px: float = 0.0
    target_yaw_deg: float = 3.0
    blocks: dict = field(default_factory=dict)  # rotate90, lift_b_mm, tilt_deg, order
    #: shoe preset: ``pose`` (rotate_deg, shift_x_mm, shift_y_mm; sim.scenes.ShoePose) and
    #: ``cut`` (sim.scenes.ShoeCut fields) - empty: today's shoe, bit for bit
    shoe: dict = field(default_factory=dict)
    #: a rig drawn from this seed (sim.random_rig); the fields above then come from the draw
    #: (:meth:`random`), the rig, lens, lasers, target and soil from :func:`random_rig`
    random_rig: int | None = None
    #: a rolling shutter's readout: the time (ms) from the exposure of the first image row to
    #: that of the last (0: a global shutter). Row ``v`` of frame ``k`` shows the scene at
    #: ``k / fps + v * readout_ms / 1000 / (height - 1)``: a CMOS camcorder's rows are read one
    #: after another while the carriage moves on
    readout_ms: float = 0.0
    #: the stripe's light follows the soil's texture row by row (``RenderOptions``), as on a
    #: real surface; off by default (the renders and figures before 2026-12-06)
    stripe_follows_soil: bool = False

    @property
    def line_time_s(self) -> float:
        """The time from one image row's exposure to the next, s (0: a global shutter)."""
        return self.readout_ms / 1000.0 / max(self.height - 1, 1)

    @classmethod
    def random(cls, rig_seed: int, width: int = 1920, height: int = 1080,
               video_format: str = "mp4", grid_mm: float = 0.1,
               click_noise_px: float = 0.0, readout_ms: float = 0.0,
               stripe_follows_soil: bool = False) -> SimConfig:
        """The configuration of random rig ``rig_seed`` (``impress simulate --random-rig``);
        ``readout_ms``: a rolling shutter's readout (not drawn: the rig's other draws stay
        those of the seed); ``stripe_follows_soil``: likewise not drawn."""
        from impress_gui.sim.random_rig import draw_random_rig

        p = draw_random_rig(int(rig_seed), width, height).params
        return cls(preset=p["preset"], length_mm=round(p["length_mm"], 3),
                   speed_mm_s=p["speed_mm_s"], fps=p["fps"], width=width, height=height,
                   roll_deg=p["roll_deg"], tilt_deg=p["tilt_deg"],
                   standoff_mm=p["standoff_mm"], seed=int(rig_seed),
                   video_format=video_format,
                   bitrate_mbit=p["bitrate_mbit_1080p"] * width * height / (1920 * 1080),
                   speckle=p["speckle"], noise_dn=p["noise_dn"], grid_mm=grid_mm,
                   ramp_s=p["ramp_s"], click_noise_px=click_noise_px,
                   target_yaw_deg=p["target_yaw_deg"], random_rig=int(rig_seed),
                   readout_ms=float(readout_ms), stripe_follows_soil=bool(stripe_follows_soil))

    def to_json(self) -> dict:
        """The fields (``random_rig`` only when set: a preset's truth stays as it was)."""
        d = dataclasses.asdict(self)
        if d["random_rig"] is None:
            del d["random_rig"]
        if not d["shoe"]:
            del d["shoe"]
        if not d["readout_ms"]:
            del d["readout_ms"]  # a global shutter: the truth as before rolling shutters
        if not d["stripe_follows_soil"]:
            del d["stripe_follows_soil"]  # the truth as before the option
        return d

    def validate(self) -> None:
        def bad(msg: str) -> None:
            raise InputError(msg, code=codes.E_SIM_OPTION)

        if self.preset not in PRESETS:
            bad(f"unknown preset {self.preset!r}; choose one of {', '.join(PRESETS)}")
        if self.length_mm is not None and not 60.0 <= self.length_mm <= 1770.0:
            bad("--length-mm must be between 60 and 1770 mm (the rail is 1.77 m)")
        if not 0.05 <= self.speed_mm_s <= 100.0:
            bad("--speed must be between 0.05 and 100 mm/s")
        if not 1.0 <= self.fps <= 240.0:
            bad("--fps must be between 1 and 240")
        if not (64 <= self.width <= 4096 and 36 <= self.height <= 2304):
            bad("--resolution must be between 64x36 and 4096x2304")
        if self.width % 2 or self.height % 2:
            bad("--resolution needs even width and height (4:2:0 video)")
        if self.random_rig is not None:
            if not 0 <= self.random_rig < 2**32:
                bad("--random-rig must be between 0 and 4294967295")
            if self.blocks:
                bad("placement options (--rotate90, ...) do not go with --random-rig")
            mine = SimConfig.random(self.random_rig, self.width, self.height,
                                    self.video_format, self.grid_mm, self.click_noise_px,
                                    self.readout_ms, self.stripe_follows_soil)
            if mine != self:
                bad("a random rig's configuration comes from its seed: use "
                    "SimConfig.random(seed, ...)")
        elif abs(self.roll_deg) > 10 or abs(self.tilt_deg) > 10:
            bad("--roll and --tilt must be within 10 degrees")
        if not 200.0 <= self.standoff_mm <= 400.0:
            bad("--standoff-mm must be between 200 and 400 mm")
        if self.video_format not in ("mp4", "mov", "mts", "frames"):
            bad("--format must be mp4, mov, mts or frames")
        if not 0 <= self.speckle <= 1 or not 0 <= self.noise_dn <= 50:
            bad("--speckle must be in [0, 1] and --noise in [0, 50] DN")
        if not 0.02 <= self.grid_mm <= 1.0:
            bad("--grid-mm must be between 0.02 and 1 mm")
        if not (math.isfinite(self.readout_ms) and 0 <= self.readout_ms <= 1000.0 / self.fps):
            bad("--readout-ms must be between 0 (a global shutter) and one frame interval "
                f"({1000.0 / self.fps:.4g} ms at {self.fps:g} frames/s)")
        if not 0 <= self.click_noise_px <= 20:
            bad("--click-noise-px must be between 0 and 20")
        if self.bitrate_mbit is not None and not 0.001 <= self.bitrate_mbit <= 500:
            bad("--bitrate-mbit must be between 0.001 and 500 Mbit/s")
        if not 0 <= self.seed < 2**32:
            bad("--seed must be between 0 and 4294967295")
        if self.shoe:
            self._validate_shoe(bad)
        if self.blocks and self.preset != "blocks":
            bad("placement options (--rotate90, --lift-b-mm, --tilt-plates, --order) need "
                "--preset blocks")

    def _validate_shoe(self, bad) -> None:
        import math

        from impress_gui.sim.scenes import ShoeCut, ShoePose

        if self.preset != "shoe" or self.random_rig is not None:
            bad("shoe options (--shoe-rotate, --shoe-shift-mm, --cut) need --preset shoe "
                "(and no --random-rig)")
        if set(self.shoe) - {"pose", "cut", "sole_seed"}:
            bad(f"unknown shoe options {sorted(set(self.shoe) - {'pose', 'cut', 'sole_seed'})}")
        sole_seed = self.shoe.get("sole_seed")
        if sole_seed is not None and (isinstance(sole_seed, bool) or not isinstance(sole_seed, int)
                                      or not 0 <= sole_seed < 2**32):
            bad("--sole-seed must be a whole number between 0 and 4294967295")
        try:
            pose = ShoePose.of(self.shoe.get("pose"))
            cut = None if self.shoe.get("cut") is None else ShoeCut.of(self.shoe["cut"])
        except (TypeError, ValueError, AttributeError):
            bad("the shoe's pose or cut has a missing or wrong field")
            return
        values = [pose.rotate_deg, pose.shift_x_mm, pose.shift_y_mm]
        if cut is not None:
            values += list(cut.to_json().values())
        if not all(math.isfinite(v) for v in values):
            bad("the shoe's pose and cut take finite numbers")
        if not -180.0 <= pose.rotate_deg <= 180.0:
            bad("--shoe-rotate must be between -180 and 180 degrees")
        if abs(pose.shift_x_mm) > 60.0 or abs(pose.shift_y_mm) > 60.0:
            bad("--shoe-shift-mm must be within 60 mm in x and y")
        if cut is not None and not (0 < cut.length_mm <= 50 and 0 < cut.width_mm <= 10
                                    and 0 < cut.depth_mm <= 5):
            bad("the cut must be 0-50 mm long, 0-10 mm wide and 0-5 mm deep")

    @property
    def scan_length_mm(self) -> float:
        return float(self.length_mm or DEFAULT_LENGTH_MM[self.preset])


def random_rig(cfg: SimConfig):
    """The drawn rig of a random-rig configuration (``None`` for the presets' rig)."""
    if cfg.random_rig is None:
        return None
    from impress_gui.sim.random_rig import draw_random_rig

    return draw_random_rig(cfg.random_rig, cfg.width, cfg.height)


def make_rig(cfg: SimConfig) -> Rig:
    rr = random_rig(cfg)
    if rr is not None:
        return rr.rig
    return default_rig(cfg.width, cfg.height, cfg.roll_deg, cfg.tilt_deg, cfg.standoff_mm)


def make_motion(cfg: SimConfig) -> Motion:
    return Motion(cfg.speed_mm_s, cfg.fps, cfg.scan_length_mm, cfg.ramp_s)


def make_target(cfg: SimConfig) -> TargetModel:
    rr = random_rig(cfg)
    return default_target() if rr is None else rr.target


TARGET_POSE = (-40.0, 70.0)  # object origin of the L target in the rail frame (mm)


def target_pose(cfg: SimConfig) -> tuple[float, float, float]:
    rr = random_rig(cfg)
    if rr is not None:
        return rr.target_pose
    return (TARGET_POSE[0], TARGET_POSE[1], cfg.target_yaw_deg)


def target_to_rail(obj_pts: np.ndarray, pose, standoff_mm: float) -> np.ndarray:
    """Object-frame points (x across, y along, z up) to the rail frame (X', Y', Z' = depth).

    The placement is a proper rotation: ``(X', Y') = T + Rz(yaw) (x, -y)``, ``Z' = standoff - z``.
    """
    tx, ty, yaw = pose
    c, s = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
    obj = np.asarray(obj_pts, float)
    x, y = obj[..., 0], -obj[..., 1]
    return np.stack([tx + c * x - s * y, ty + s * x + c * y, standoff_mm - obj[..., 2]], axis=-1)


def target_world_corners(target: TargetModel, pose, standoff_mm: float) -> np.ndarray:
    """Target corners A-F in the rail frame (X', Y', Z' = depth), ``(6, 3)``."""
    return target_to_rail(target.corner_array(), pose, standoff_mm)


def project_rail(rig: Rig, pts_rail: np.ndarray, travel_mm) -> np.ndarray:
    """Image points of rail points with the optical centre at ``travel_mm`` (one travel, or
    one per point)."""
    return rig.intrinsics.project((np.asarray(pts_rail, float) - rail_shift(travel_mm))
                                  @ rig.rotation)


def project_rail_rolling(rig: Rig, motion: Motion, pts_rail: np.ndarray, k: int,
                         line_time_s: float) -> np.ndarray:
    """Where rail points appear in frame ``k`` under a rolling shutter: each at the travel of
    the row it appears on (solved by iteration: a row's time moves the point by well under a
    pixel, so it converges in a few steps). A global shutter (``line_time_s`` 0): the
    frame's travel."""
    t = k / motion.fps
    uv = project_rail(rig, pts_rail, float(motion.travel_mm(t)))
    if line_time_s <= 0:
        return uv
    for _ in range(20):
        before = uv
        uv = project_rail(rig, pts_rail, motion.travel_mm(t + uv[:, 1] * line_time_s))
        if np.max(np.abs(uv - before)) < 1e-9:
            break
    return uv


def _stripe_on_faces(rig: Rig, laser_name: str, target: TargetModel, pose, travel: float,
                     margin_mm: float = 6.0) -> bool:
    """Does the laser's stripe cross every top face of the target well inside its ends?"""
    laser = rig.laser(laser_name)
    n, d = laser.plane.normal, laser.plane.offset_mm
    for face in target.top_faces():
        v = face.vertices_mm
        ys = np.linspace(v[:, 1].min(), v[:, 1].max(), 400)
        line = np.column_stack([np.full_like(ys, v[:, 0].mean()), ys, np.full_like(ys, v[0, 2])])
        P = target_to_rail(line, pose, rig.standoff_mm)
        val = n[0] * P[:, 0] + n[1] * (P[:, 1] - travel) + n[2] * P[:, 2] - d
        cross = np.flatnonzero(np.diff(np.sign(val)) != 0)
        if cross.size != 1:
            return False
        yc = ys[cross[0]]
        if yc - v[:, 1].min() < margin_mm or v[:, 1].max() - yc < margin_mm:
            return False
    return True


def calibration_frames(cfg: SimConfig, rig: Rig, motion: Motion, target: TargetModel) -> tuple[int, int]:
    """``(t1, t2)``: a frame with the green stripe on both target tops and one with the red
    stripe there, both at constant speed with all six corners well inside the image, as far
    apart as that allows (green's first and red's last where green leads; green's last and
    red's first where red leads, t2 before t1)."""
    return _calibration_frames(rig, motion, target, target_pose(cfg), cfg.width, cfg.height)


def _calibration_frames(rig: Rig, motion: Motion, target: TargetModel, pose, w: int,
                        h: int) -> tuple[int, int]:
    corners = target_world_corners(target, pose, rig.standoff_mm)
    margin = 0.03 * w
    ok_green, ok_red = [], []
    times = motion.times_s()
    for k, t in enumerate(times):
        if not motion.constant_speed(t):
            continue
        s = float(motion.travel_mm(t))
        uv = project_rail(rig, corners, s)
        if not (np.all(uv[:, 0] > margin) and np.all(uv[:, 0] < w - margin)
                and np.all(uv[:, 1] > margin) and np.all(uv[:, 1] < h - margin)):
            continue
        if _stripe_on_faces(rig, "green", target, pose, s):
            ok_green.append(k)
        if _stripe_on_faces(rig, "red", target, pose, s):
            ok_red.append(k)
    if not ok_green or not ok_red:
        raise InputError("the calibration target never shows both stripes with all corners in "
                         "view; use a longer scan or a smaller tilt", code=codes.E_SIM_OPTION)
    # the two frames as far apart as the stripes allow, as a careful user (and "Find t1 and
    # t2") chooses them: the green laser's first frame and the red's last where green leads,
    # the green's last and the red's first where red leads (a rig built the other way round;
    # t2 then comes first). Until 2026-12-04 the first pair was taken on every rig: where red
    # leads it is the closest pair (random rig 88: frames 114 and 115), and the corners that
    # barely moved between them were refused (E-PICKS) or fixed the motion direction poorly
    lead_green, lead_red = (ok_green[0], ok_red[-1]), (ok_green[-1], ok_red[0])
    if abs(lead_red[1] - lead_red[0]) > abs(lead_green[1] - lead_green[0]):
        return lead_red
    return lead_green


# ----- rendering workers ---------------------------------------------------------------
_WORKER: dict = {}


def _make_renderer(cfg: SimConfig, scene=None):
    """(renderer, scene) of ``cfg``; ``scene``, when given, is the one this configuration
    builds (the rendering workers get it from the parent instead of building it again)."""
    from impress_gui.sim.render import Renderer, RenderOptions

    rig, motion, target = make_rig(cfg), make_motion(cfg), make_target(cfg)
    rr = random_rig(cfg)
    if rr is None:
        if scene is None:
            scene = build_scene(cfg.preset, cfg.scan_length_mm, cfg.grid_mm, cfg.seed, target,
                                target_pose(cfg), **cfg.blocks, **cfg.shoe)
        opts = RenderOptions(noise_sigma_dn=cfg.noise_dn, speckle_contrast=cfg.speckle,
                             seed=cfg.seed, stripe_sigma_px=max(1.2, 1.6 * cfg.width / 1920.0),
                             laser_peak=3.5, line_time_s=cfg.line_time_s,
                             stripe_follows_soil=cfg.stripe_follows_soil)
    else:
        from impress_gui.sim.random_rig import soil_of

        p = rr.params
        if scene is None:
            scene = build_scene(cfg.preset, cfg.scan_length_mm, cfg.grid_mm, cfg.seed, target,
                                target_pose(cfg), soil=soil_of(p))
        opts = RenderOptions(noise_sigma_dn=cfg.noise_dn, speckle_contrast=cfg.speckle,
                             seed=cfg.seed, laser_peak=p["laser_peak"], ambient=p["ambient"],
                             stripe_sigma_px=max(0.9, p["stripe_sigma_px_1080p"]
                                                 * cfg.width / 1920.0),
                             line_time_s=cfg.line_time_s,
                             stripe_follows_soil=cfg.stripe_follows_soil)
    return Renderer(scene, rig, motion, opts), scene


def _worker_init(cfg_json: str, scene, quiet: bool = False) -> None:
    import signal

    if quiet:  # started by the console command: no library warning lines
        from impress_gui.core.base.quiet import quiet_libraries

        quiet_libraries()

    # Ctrl-C is the parent's to handle (it stops handing out frames); a worker interrupted
    # while it builds its renderer printed a traceback
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    cfg = SimConfig(**json.loads(cfg_json))
    _WORKER["renderer"] = _make_renderer(cfg, scene)[0]


def _worker_render(k: int) -> np.ndarray:
    return _WORKER["renderer"].render(k)[0]


def render_frames(cfg: SimConfig, frames, workers: int = 1, scene=None):
    """Yield rendered RGB frames in order; with ``workers > 1`` render in spawned processes.
    ``scene``: the scene ``cfg`` builds, when the caller has it (built once, not per process:
    a shoe scene takes seconds to build and a fraction of a second to send)."""
    if workers <= 1:
        renderer, _ = _make_renderer(cfg, scene)
        for k in frames:
            yield renderer.render(k)[0]
        return
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    from impress_gui.core.base.quiet import child_initializer

    cfg_json = json.dumps(dataclasses.asdict(cfg))
    if scene is None:
        scene = _make_renderer(cfg)[1]
    with ProcessPoolExecutor(workers, mp_context=mp.get_context("spawn"),
                             initializer=_worker_init,
                             initargs=(cfg_json, scene, child_initializer() is not None)) as pool:
        pending = []
        it = iter(frames)
        for k in it:
            pending.append(pool.submit(_worker_render, k))
            if len(pending) >= 4 * workers:
                yield pending.pop(0).result()
        for fut in pending:
            yield fut.result()


def simulate(cfg: SimConfig, out_dir: Path, workers: int = 1,
             progress: ProgressCallback | None = None, cancel: CancelToken | None = None) -> dict:
    """Render the scan into ``out_dir`` and write the ground truth; return a summary dict."""
    cfg.validate()
    cancel = cancel or CancelToken()
    final_dir = Path(out_dir)
    _adopt_legacy(final_dir)
    _check_frames_folder(final_dir)
    # everything is written into a hidden sibling folder that replaces the old one at the end:
    # an interrupted run leaves the previous simulation whole; a folder that is not a previous
    # simulation is refused before any work (E-OUTPUT-*)
    with OutputFolder(final_dir, "simulation", allowed=SIM_FILES) as folder:
        res = _simulate_into(cfg, folder.begin(), workers, progress, cancel)
        folder.commit()
    res["video"] = str(final_dir / Path(res["video"]).name)
    res["out_dir"] = str(final_dir)
    return res


#: every name a simulation folder may hold
SIM_FILES = ("scan.mp4", "scan.mov", "scan.mts", "frames", "intrinsics.json", "target.json",
             "picks.json", "truth_height.tif", "truth_texture.png", "truth.json",
             "simulator.txt")


#: the only names a simulation's frame folder holds
SIM_FRAME = re.compile(r"frame_\d{6}\.png")


def _frames_only(frames: Path) -> bool:
    """Whether ``frames`` holds nothing but the simulator's frame files (regular, no links)."""
    return all(SIM_FRAME.fullmatch(p.name) and p.is_file() and not p.is_symlink()
               for p in frames.iterdir())


def _check_frames_folder(folder: Path) -> None:
    """A simulation folder about to be replaced must not hold anything the simulator did not
    write below its top level either (its ``frames`` folder holds frame files only)."""
    from impress_gui.core.base.outdir import OutputError

    frames = folder / "frames"
    try:
        ok = frames.is_symlink() is False and (not frames.is_dir() or _frames_only(frames))
    except OSError:
        ok = False
    if not ok:
        raise OutputError(f"{frames} holds files a simulation did not write: nothing is "
                          "replaced; move them or name another folder",
                          code=codes.E_OUTPUT_NOT_EMPTY)


def _adopt_legacy(folder: Path) -> None:
    """A simulation written before folders were marked gets the mark, so that it can be
    replaced like a marked one: nothing but simulator files, no links, a truth.json of the
    simulator's format whose video hash is the video's (a folder of a lab's own files that
    happen to have these names is not one)."""
    from impress_gui.core.base.fileio import sha256_path
    from impress_gui.core.base.outdir import MARK_FILE, mark_bytes, read_mark

    try:
        if (folder.is_symlink() or not folder.is_dir() or read_mark(folder) is not None
                or not (folder / "truth.json").is_file()):
            return
        names = [p for p in folder.iterdir()]
        if not all(p.name in SIM_FILES and not p.is_symlink() for p in names):
            return
        truth = json.loads((folder / "truth.json").read_text(encoding="utf-8"))
        video = folder / str(truth.get("video", ""))
        if (truth.get("format") != "impress.sim-truth" or video.parent != folder
                or video.name not in SIM_FILES or not video.exists()
                or (video.is_dir() and not _frames_only(video))
                or sha256_path(video) != truth.get("video_sha256")):
            return
        (folder / MARK_FILE).write_bytes(mark_bytes("simulation"))
    except (OSError, ValueError, AttributeError):
        return


def _random_truth(rr) -> dict:
    """The ``random_rig`` section of truth.json: the seed and every drawn parameter."""
    rig = rr.rig
    doc = rr.to_json()
    doc.update({
        "rotation_camera_to_rail": rig.rotation.tolist(),
        "cross_tilt_note": "the rail frame is the ideal frame (camera turned by roll_deg and "
                           "tilt_deg) turned by cross_tilt_deg about the motion axis Y",
        "intrinsics": rig.intrinsics.to_json(),
        "target_file": "target.json",
        "target_pose": {"x_mm": rr.target_pose[0], "y_mm": rr.target_pose[1],
                        "yaw_deg": rr.target_pose[2]},
        "lasers_rgb_response": {la.name: list(la.rgb_response) for la in rig.lasers},
    })
    return doc


def _shoe_truth(cfg: SimConfig) -> dict:
    """The ``shoe`` section of truth.json: the pose (and its matrix) and the cut, if any."""
    from impress_gui.sim.scenes import SHOE_CENTRE_MM, ShoeCut, ShoePose

    pose = ShoePose.of(cfg.shoe.get("pose"))
    doc: dict = {"pose": {**pose.to_json(), "centre_mm": list(SHOE_CENTRE_MM),
                          "matrix_shoe_to_rail": pose.matrix(),
                          "convention": "rail (X, Y) = centre + shift + Rz(rotate_deg) "
                                        "((x, y) - centre), (x, y) in the shoe's own frame "
                                        "(the rail frame of the unposed shoe scene); rotate_deg "
                                        "turns +X towards +Y"}}
    if cfg.shoe.get("cut") is not None:
        doc["cut"] = ShoeCut.of(cfg.shoe["cut"]).to_json()
    doc["sole_seed"] = cfg.shoe.get("sole_seed")
    doc["sole_seed_note"] = ("the sole's random nicks drawn from sole_seed" if
                             cfg.shoe.get("sole_seed") is not None else
                             "the sole's random nicks drawn from the scene's seed")
    return doc


def _simulate_into(cfg: SimConfig, out_dir: Path, workers: int,
                   progress: ProgressCallback | None, cancel: CancelToken) -> dict:
    rig, motion, target = make_rig(cfg), make_motion(cfg), make_target(cfg)
    t1, t2 = calibration_frames(cfg, rig, motion, target)
    report(progress, 0.0, "building the scene")
    renderer, scene = _make_renderer(cfg)
    n = motion.frame_count
    from impress_gui.sim.video_out import FrameFolderSink, VideoSink

    sink: FrameFolderSink | VideoSink
    if cfg.video_format == "frames":
        video_path = out_dir / "frames"
        sink = FrameFolderSink(video_path)
    else:
        video_path = out_dir / f"scan.{cfg.video_format}"
        sink = VideoSink(video_path, cfg.width, cfg.height, cfg.fps, cfg.bitrate_mbit)
    try:
        if workers > 1:
            del renderer
            frames = render_frames(cfg, range(n), workers, scene)
        else:
            frames = (renderer.render(k)[0] for k in range(n))
        for k, rgb in enumerate(frames):
            cancel.check()
            sink.write(rgb)
            report(progress, 0.05 + 0.9 * (k + 1) / n, f"rendered frame {k + 1}/{n}")
        sink.close()
    except BaseException:
        sink.abort()
        raise

    # ----- ground truth -------------------------------------------------------------------
    # the camera as a lab knows it: its lens, and its rolling shutter's readout (if any)
    intr = dataclasses.replace(rig.intrinsics, readout_ms=cfg.readout_ms or None)
    intr.save(out_dir / "intrinsics.json")
    target.save(out_dir / "target.json")
    times = motion.times_s()
    travel = motion.travel_mm(times)
    corners_rail = target_world_corners(target, target_pose(cfg), cfg.standoff_mm)
    rng = np.random.default_rng([cfg.seed, 7])
    picks_doc = {}
    for key, k in (("t1", t1), ("t2", t2)):
        uv = project_rail_rolling(rig, motion, corners_rail, k, cfg.line_time_s)
        if cfg.click_noise_px > 0:
            uv = uv + rng.normal(0, cfg.click_noise_px, uv.shape)
        picks_doc[key] = (k, {c: uv[i].tolist() for i, c in enumerate(CORNER_NAMES)})
    video_sha = sha256_path(video_path)  # frames: the hash of the folder's manifest
    picks = Picks(video=video_path.name, video_sha256=video_sha,
                  t1=picks_doc["t1"][0], t2=picks_doc["t2"][0],
                  corners_t1={c: tuple(v) for c, v in picks_doc["t1"][1].items()},
                  corners_t2={c: tuple(v) for c, v in picks_doc["t2"][1].items()},
                  note=f"simulator picks (click noise {cfg.click_noise_px} px)")
    picks.save(out_dir / "picks.json")
    atomic_write_bytes(out_dir / "truth_height.tif",
                       tiff_bytes(scene.height_mm.astype(np.float32), shape_metadata=True))
    atomic_write_bytes(out_dir / "truth_texture.png", png_bytes(scene.albedo))
    truth = {
        "format": TRUTH_FORMAT,
        "version": 1,
        "software": f"impress {__version__}",
        "config": cfg.to_json(),
        "video": video_path.name,
        "video_sha256": video_sha,
        "image_size": [cfg.width, cfg.height],
        "fps": cfg.fps,
        "frame_count": n,
        "speed_mm_s": cfg.speed_mm_s,
        "ramp_s": cfg.ramp_s,
        "length_mm": cfg.scan_length_mm,
        "standoff_mm": cfg.standoff_mm,
        "roll_deg": cfg.roll_deg,
        "tilt_deg": cfg.tilt_deg,
        "rotation_camera_to_ideal": rig.ideal_rotation.tolist(),
        "lasers": {la.name: {"plane": la.plane.to_json(), "source_mm": la.source_mm.tolist()}
                   for la in rig.lasers},
        "target": {"x_mm": target_pose(cfg)[0], "y_mm": target_pose(cfg)[1],
                   "yaw_deg": target_pose(cfg)[2],
                   "corners_rail_mm": {c: corners_rail[i].tolist()
                                       for i, c in enumerate(CORNER_NAMES)}},
        "calibration_frames": {"t1": t1, "t2": t2},
        **({"rolling_shutter": {
            "readout_ms": cfg.readout_ms, "line_time_s": cfg.line_time_s,
            "convention": "row v (pixel row coordinate, 0 = the first row's centre) of frame "
                          "k shows the scene at frame_times_s[k] + v * line_time_s; "
                          "travel_mm and the picks' frames are the frames' own times"}}
           if cfg.readout_ms else {}),
        "frame_times_s": times.tolist(),
        "travel_mm": travel.tolist(),
        "heightmap": {"file": "truth_height.tif", "texture": "truth_texture.png",
                      "x0_mm": scene.x0_mm, "y0_mm": scene.y0_mm, "pixel_mm": scene.pixel_mm,
                      "shape": list(scene.shape),
                      "convention": "height in mm, up = towards the camera, 0 = undisturbed "
                                    "ground at depth standoff_mm; cell [i, j] centred at "
                                    "(x0 + j*pixel, y0 + i*pixel) in the rail frame whose "
                                    "origin is the optical centre at frame 0"},
        "features": scene.features,
    }
    if cfg.shoe:
        truth["shoe"] = _shoe_truth(cfg)
    rr = random_rig(cfg)
    if rr is not None:
        truth["random_rig"] = _random_truth(rr)
        # the calibration's ideal frame is the camera turned by roll and tilt only: the planes
        # it estimates are the rail-frame planes turned back by the rotation about the motion
        turn = rig.rotation @ rig.ideal_rotation.T  # ideal -> rail
        for la in rig.lasers:
            truth["lasers"][la.name] = {
                "plane": Plane(turn.T @ la.plane.normal, la.plane.offset_mm).to_json(),
                "source_mm": (turn.T @ la.source_mm).tolist(),
                "plane_rail": la.plane.to_json(), "source_rail_mm": la.source_mm.tolist()}
    write_json(out_dir / "truth.json", truth)
    return {"video": str(video_path), "frames": n, "t1": t1, "t2": t2, "out_dir": str(out_dir)}
