"""The simulated rig: camera on the rail, its misalignment, the two laser planes, and the motion."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from impress_gui.core.calibration.geometry import Intrinsics, Plane, ideal_rotation

SPEED_PRESETS_MM_S = (1.3138, 5.2552, 13.138)


def rot_y(angle_rad: float) -> np.ndarray:
    """Rotation about the Y (motion) axis: X towards Z for a positive angle."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


@dataclass(frozen=True)
class Laser:
    """A line laser fixed to the camera bracket.

    ``source_mm`` and ``plane`` are in the camera-fixed ideal frame (mm); ``rgb_response`` is how
    the camera's channels respond to its light (relative, the dominant channel is 1).
    """

    name: str
    source_mm: np.ndarray
    plane: Plane
    rgb_response: tuple[float, float, float]
    fan_dir_mm: np.ndarray  # unit vector in the plane pointing from the source to the ground

    @classmethod
    def aimed(cls, name: str, source_mm, aim_y_mm: float, standoff_mm: float, yaw_deg: float,
              rgb_response) -> Laser:
        """A laser at ``source_mm`` whose fan hits the ground (depth ``standoff_mm``) along the
        line ``Y = aim_y_mm``, the fan rotated by ``yaw_deg`` about the vertical."""
        s = np.asarray(source_mm, float)
        down = np.array([0.0, aim_y_mm - s[1], standoff_mm - s[2]])
        down /= np.linalg.norm(down)
        yaw = np.radians(yaw_deg)
        across = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        across -= down * (across @ down)
        across /= np.linalg.norm(across)
        n = np.cross(across, down)
        return cls(name, s, Plane(n, float(n @ s)), tuple(rgb_response), down)


@dataclass(frozen=True)
class Rig:
    intrinsics: Intrinsics
    roll_deg: float
    tilt_deg: float
    standoff_mm: float
    lasers: tuple[Laser, ...]
    #: rotation of the camera about the rail's motion axis (Y), degrees: the one rotation the
    #: motion does not reveal; the ground is then seen tilted across the image
    cross_tilt_deg: float = 0.0

    @property
    def ideal_rotation(self) -> np.ndarray:
        """Camera frame -> the calibration's ideal frame (roll and tilt only)."""
        return ideal_rotation(np.radians(self.roll_deg), np.radians(self.tilt_deg))

    @property
    def rotation(self) -> np.ndarray:
        """Camera frame -> rail frame (the ground is ``Z' = standoff``): the ideal frame turned
        by ``cross_tilt_deg`` about the motion axis (the ideal frame itself when that is 0)."""
        if not self.cross_tilt_deg:
            return self.ideal_rotation
        return rot_y(np.radians(self.cross_tilt_deg)) @ self.ideal_rotation

    def laser(self, name: str) -> Laser:
        return next(la for la in self.lasers if la.name == name)


def default_intrinsics(width: int, height: int) -> Intrinsics:
    """A camcorder at its widest zoom (f = 2110 px at 1920x1080), scaled to ``width``."""
    s = width / 1920.0
    k = np.array([[2110.0 * s, 0.0, width / 2 + 6.5 * s],
                  [0.0, 2110.0 * s, height / 2 - 4.25 * s],
                  [0.0, 0.0, 1.0]])
    return Intrinsics(k, np.array([-0.12, 0.06, 0.0004, -0.0003, 0.0]), (width, height),
                      source="simulator")


def default_rig(width: int = 1920, height: int = 1080, roll_deg: float = 1.2,
                tilt_deg: float = -1.8, standoff_mm: float = 300.0,
                laser_offset_mm: float = 130.0, stripe_offset_mm: float = 38.0) -> Rig:
    """Green laser behind the camera lighting the leading (lower) half of the image, red
    laser ahead lighting the trailing (upper) half: they cross and fill each other's shadows."""
    green = Laser.aimed("green", (8.0, -laser_offset_mm, 5.0), stripe_offset_mm, standoff_mm, 1.5,
                        (0.25, 1.0, 0.22))
    red = Laser.aimed("red", (-6.0, laser_offset_mm, 4.0), -stripe_offset_mm, standoff_mm, -2.0,
                      (1.0, 0.2, 0.16))
    return Rig(default_intrinsics(width, height), roll_deg, tilt_deg, standoff_mm, (green, red))


@dataclass(frozen=True)
class Motion:
    """Constant speed with a constant-acceleration ramp of ``ramp_s`` at each end."""

    speed_mm_s: float
    fps: float
    length_mm: float
    ramp_s: float = 0.4

    @property
    def duration_s(self) -> float:
        return self.length_mm / self.speed_mm_s + self.ramp_s

    @property
    def frame_count(self) -> int:
        return int(np.floor(self.duration_s * self.fps)) + 1

    def times_s(self) -> np.ndarray:
        return np.arange(self.frame_count) / self.fps

    def travel_mm(self, t_s: np.ndarray | float) -> np.ndarray:
        t = np.clip(np.asarray(t_s, float), 0.0, self.duration_s)
        v, ta, T = self.speed_mm_s, self.ramp_s, self.duration_s
        if ta <= 0:
            return v * t
        a = v / ta
        up = 0.5 * a * t**2
        cruise = 0.5 * v * ta + v * (t - ta)
        tail = self.length_mm - 0.5 * a * (T - t) ** 2
        return np.where(t < ta, up, np.where(t > T - ta, tail, cruise))

    def constant_speed(self, t_s: float) -> bool:
        return self.ramp_s <= t_s <= self.duration_s - self.ramp_s
