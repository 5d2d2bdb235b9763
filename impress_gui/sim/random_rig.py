"""Random rigs: a rig, target, scene and camera drawn from a seed, over a wide but physically
plausible family of mountings (``impress simulate --random-rig SEED``).

Every range is in :data:`RANGES` (1080p pixel units; lengths in mm, angles in degrees) and is
documented in docs/accuracy.md ("Random rigs"). A draw whose calibration target never shows
both stripes with all six corners in view, whose stripes leave the picture, or whose lasers
triangulate at too flat an angle is refused and drawn again (attempts ``0..MAX_ATTEMPTS-1``
with their own random streams); when no attempt works the seed is refused with
``E-SIM-RANDOM-RIG``. The drawing is pure (no rendering): the same seed and image size give the
same rig on every machine.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from impress_gui.core.base import codes
from impress_gui.core.base.errors import InputError
from impress_gui.core.calibration.geometry import Intrinsics
from impress_gui.core.calibration.target import TargetModel, make_l_target
from impress_gui.sim.rig import Laser, Motion, Rig

#: the family: ``(low, high)`` uniform ranges, or a tuple of choices (``"choice"`` entries)
RANGES: dict[str, tuple] = {
    # camera
    "standoff_mm": (220.0, 380.0),
    "focal_px_1080p": (1500.0, 2600.0),
    "pixel_aspect": (0.998, 1.002),  # fy / fx
    "principal_dx_px_1080p": (-40.0, 40.0),
    "principal_dy_px_1080p": (-30.0, 30.0),
    "k1": (-0.25, 0.10),
    "k2": (-0.10, 0.20),
    "p1": (-0.002, 0.002),
    "p2": (-0.002, 0.002),
    # mounting: roll about the optical axis within 12 deg of 0 or of 180 (the motion runs down
    # or up the image), tilt about the image's x axis, and rotation about the motion axis
    "roll_offset_deg": (-12.0, 12.0),
    "roll_flipped": ("choice", False, True),
    "tilt_deg": (-5.0, 5.0),
    "cross_tilt_deg": (-5.0, 5.0),
    # lasers (each independently); the stripe lands on the ground at Y = +-fraction of the
    # ground's half view (the two on opposite sides of the image centre)
    "green_leads": ("choice", False, True),
    "stripe_fraction": (0.25, 0.55),
    "incidence_deg": (15.0, 40.0),  # fan's angle from the vertical at the ground line
    "from_behind": ("choice", False, True),  # light travels along +Y (source behind the stripe)
    "source_x_mm": (-40.0, 40.0),
    "source_z_mm": (-30.0, 20.0),  # depth of the source relative to the camera (- = above)
    "fan_yaw_deg": (-4.0, 4.0),
    "green_crosstalk_r": (0.08, 0.40),
    "green_crosstalk_b": (0.05, 0.35),
    "red_crosstalk_g": (0.03, 0.30),
    "red_crosstalk_b": (0.03, 0.25),
    "laser_power": (0.6, 1.0),  # relative, per laser
    "laser_peak": (0.8, 6.0),  # full scales: < 1 dim and unsaturated, > 2 blooming
    "stripe_sigma_px_1080p": (0.6, 1.8),  # Gaussian sigma: FWHM 1.4-4.2 px
    "ambient": (0.25, 0.70),
    # target (an L of other dimensions) and its placement
    "target_low_h_mm": (5.0, 15.0),
    "target_step_mm": (10.0, 25.0),  # high top minus low top
    "target_low_w_mm": (25.0, 50.0),
    "target_high_w_mm": (25.0, 50.0),
    "target_length_mm": (40.0, 90.0),
    "target_centre_x_mm": (-25.0, 25.0),
    "target_front_y_mm": (60.0, 100.0),
    "target_yaw_deg": (-15.0, 15.0),
    # scene, soil, motion, sensor and video
    "preset": ("choice", "shoe", "tire", "blocks", "letter", "spheres", "flat"),
    "soil_brightness": (0.12, 0.85),  # dark soil to white plaster
    "soil_chroma": (0.0, 0.35),
    "soil_tint": (-0.3, 0.3),
    "soil_mottle": (0.05, 0.35),
    "soil_grain": (0.03, 0.20),
    "length_mm": (170.0, 260.0),
    "speed_mm_s": (10.0, 30.0),
    "fps": ("choice", 25.0, 29.97, 30.0, 50.0, 59.94),
    "ramp_s": (0.15, 0.45),
    "noise_dn": (0.5, 5.0),
    "speckle": (0.1, 0.6),
    "bitrate_mbit_1080p": (8.0, 24.0),
}
MAX_ATTEMPTS = 40
#: least angle between a laser's plane and the camera's ray to its stripe (degrees)
MIN_TRIANGULATION_DEG = 12.0


def _u(rng: np.random.Generator, name: str) -> float:
    lo, hi = RANGES[name]
    return float(rng.uniform(lo, hi))


def _c(rng: np.random.Generator, name: str):
    choices = RANGES[name][1:]
    return choices[int(rng.integers(len(choices)))]


@dataclass(frozen=True)
class RandomRig:
    """One drawn rig (every parameter in ``params``) and the objects built from it."""

    seed: int
    attempt: int
    params: dict
    rig: Rig
    target: TargetModel
    target_pose: tuple[float, float, float]
    motion: Motion

    def to_json(self) -> dict:
        return {"seed": self.seed, "attempt": self.attempt, "ranges": "impress_gui.sim."
                "random_rig.RANGES (docs/accuracy.md, Random rigs)", **self.params}


def _draw_params(rng: np.random.Generator) -> dict:
    p: dict = {}
    for name in ("standoff_mm", "focal_px_1080p", "pixel_aspect", "principal_dx_px_1080p",
                 "principal_dy_px_1080p", "k1", "k2", "p1", "p2", "roll_offset_deg"):
        p[name] = _u(rng, name)
    p["roll_flipped"] = bool(_c(rng, "roll_flipped"))
    roll = p["roll_offset_deg"] + (180.0 if p["roll_flipped"] else 0.0)
    p["roll_deg"] = float((roll + 180.0) % 360.0 - 180.0)
    p["tilt_deg"] = _u(rng, "tilt_deg")
    p["cross_tilt_deg"] = _u(rng, "cross_tilt_deg")
    p["green_leads"] = bool(_c(rng, "green_leads"))
    for laser in ("green", "red"):
        q: dict = {n: _u(rng, n) for n in ("stripe_fraction", "incidence_deg", "source_x_mm",
                                             "source_z_mm", "fan_yaw_deg", "laser_power")}
        q["from_behind"] = bool(_c(rng, "from_behind"))
        if laser == "green":
            q["crosstalk"] = [_u(rng, "green_crosstalk_r"), 1.0, _u(rng, "green_crosstalk_b")]
        else:
            q["crosstalk"] = [1.0, _u(rng, "red_crosstalk_g"), _u(rng, "red_crosstalk_b")]
        p[laser] = q
    for name in ("laser_peak", "stripe_sigma_px_1080p", "ambient", "target_low_h_mm",
                 "target_step_mm", "target_low_w_mm", "target_high_w_mm", "target_length_mm",
                 "target_centre_x_mm", "target_front_y_mm", "target_yaw_deg"):
        p[name] = _u(rng, name)
    p["preset"] = str(_c(rng, "preset"))
    for name in ("soil_brightness", "soil_chroma", "soil_tint", "soil_mottle", "soil_grain",
                 "length_mm", "speed_mm_s"):
        p[name] = _u(rng, name)
    p["fps"] = float(_c(rng, "fps"))
    for name in ("ramp_s", "noise_dn", "speckle", "bitrate_mbit_1080p"):
        p[name] = _u(rng, name)
    return p


def soil_of(p: dict) -> dict:
    b, c, t = p["soil_brightness"], p["soil_chroma"], p["soil_tint"]
    base = np.clip(b * np.array([1.0 + c, 1.0 + c * t, 1.0 - c]), 0.02, 0.95)
    return {"base": base.tolist(), "mottle": p["soil_mottle"], "grain": p["soil_grain"]}


def _build(p: dict, width: int, height: int) -> tuple[Rig, TargetModel, tuple, Motion]:
    s = width / 1920.0
    f = p["focal_px_1080p"] * s
    k = np.array([[f, 0.0, width / 2 + p["principal_dx_px_1080p"] * s],
                  [0.0, f * p["pixel_aspect"], height / 2 + p["principal_dy_px_1080p"] * s],
                  [0.0, 0.0, 1.0]])
    intr = Intrinsics(k, np.array([p["k1"], p["k2"], p["p1"], p["p2"], 0.0]), (width, height),
                      source="simulator (random rig)")
    z0 = p["standoff_mm"]
    # the ground's half view along Y at the image centre (1080p: 540 px of 1920 x 1080)
    half_view = 540.0 / p["focal_px_1080p"] * z0
    lasers = []
    for name in ("green", "red"):
        q = p[name]
        leads = p["green_leads"] == (name == "green")
        aim = (1.0 if leads else -1.0) * q["stripe_fraction"] * half_view
        direction = 1.0 if q["from_behind"] else -1.0
        sz = q["source_z_mm"]
        sy = aim - direction * (z0 - sz) * np.tan(np.radians(q["incidence_deg"]))
        resp = tuple(float(v) * q["laser_power"] for v in q["crosstalk"])
        lasers.append(Laser.aimed(name, (q["source_x_mm"], sy, sz), aim, z0, q["fan_yaw_deg"],
                                  resp))
    rig = Rig(intr, p["roll_deg"], p["tilt_deg"], z0, tuple(lasers), p["cross_tilt_deg"])
    lw, hw = p["target_low_w_mm"], p["target_high_w_mm"]
    lh = p["target_low_h_mm"]
    target = make_l_target(lh, lh + p["target_step_mm"], lw, hw, p["target_length_mm"])
    target = TargetModel("random L target", target.corners_mm, target.faces,
                         target.description)
    pose = (p["target_centre_x_mm"] - (lw + hw) / 2, p["target_front_y_mm"], p["target_yaw_deg"])
    motion = Motion(p["speed_mm_s"], p["fps"], p["length_mm"], p["ramp_s"])
    return rig, target, pose, motion


def _problems(rig: Rig, target: TargetModel, pose, motion: Motion, width: int,
              height: int) -> list[str]:
    """Why a drawn rig is unusable (empty when it is fine)."""
    from impress_gui.sim.simulate import _calibration_frames

    out = []
    z0 = rig.standoff_mm
    rows = {}
    for laser in rig.lasers:
        d = laser.fan_dir_mm
        hit = laser.source_mm + d * (z0 - laser.source_mm[2]) / d[2]
        ray = hit / np.linalg.norm(hit)
        tri = float(np.degrees(np.arcsin(min(1.0, abs(ray @ laser.plane.normal)))))
        if tri < MIN_TRIANGULATION_DEG:
            out.append(f"{laser.name} triangulates at {tri:.1f} deg")
        # the stripe across the picture at the ground and 60 mm above it: inside the image
        vs = []
        for h_mm in (0.0, 40.0, 60.0, -15.0):
            z = z0 - h_mm
            xs = np.linspace(-0.3, 0.3, 9) * z * width / rig.intrinsics.fx
            n, off = laser.plane.normal, laser.plane.offset_mm
            ys = (off - n[0] * xs - n[2] * z) / n[1]
            uv = rig.intrinsics.project(np.column_stack([xs, ys, np.full_like(xs, z)])
                                        @ rig.rotation)
            vs.append(uv[:, 1])
            if h_mm == 0.0 and not np.all((uv[:, 1] > 0.08 * height)
                                          & (uv[:, 1] < 0.92 * height)):
                out.append(f"the {laser.name} stripe on the ground leaves the picture")
        rows[laser.name] = np.concatenate(vs)
    g, r = rows["green"], rows["red"]
    if abs(np.median(g) - np.median(r)) < 0.2 * height:
        out.append("the stripes lie too close together in the picture")
    if not out:
        try:
            _calibration_frames(rig, motion, target, pose, width, height)
        except InputError:
            out.append("the target never shows both stripes with all corners in view")
    return out


@lru_cache(maxsize=32)
def draw_random_rig(seed: int, width: int = 1920, height: int = 1080) -> RandomRig:
    """The rig of ``seed`` at ``width x height`` (the geometry is drawn in 1080p units and
    scaled, so a 16:9 size changes nothing but the pixel scale)."""
    if not 0 <= int(seed) < 2**32:
        raise InputError("--random-rig must be between 0 and 4294967295", code=codes.E_SIM_OPTION)
    why: list[str] = []
    for attempt in range(MAX_ATTEMPTS):
        rng = np.random.default_rng([int(seed), attempt, 18])
        p = _draw_params(rng)
        rig, target, pose, motion = _build(p, width, height)
        why = _problems(rig, target, pose, motion, width, height)
        if not why:
            return RandomRig(int(seed), attempt, p, rig, target, pose, motion)
    raise InputError(f"random rig {seed}: no usable rig in {MAX_ATTEMPTS} draws (last: "
                     f"{'; '.join(why)})", code=codes.E_SIM_RANDOM_RIG)
