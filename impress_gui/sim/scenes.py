"""Procedural scenes for the simulator: a heightfield (mm, up = towards the camera, 0 = the
undisturbed ground) and a matching albedo texture on a regular grid in the rail frame.

Grid convention: cell ``[i, j]`` is centred at ``x = x0_mm + j * pixel_mm``,
``y = y0_mm + i * pixel_mm``; arrays are row-major ``(row = y, col = x)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from impress_gui.core.calibration.target import TargetModel

PRESETS = ("shoe", "tire", "blocks", "flat", "spheres", "letter")
DEFAULT_LENGTH_MM = {"shoe": 480.0, "tire": 1750.0, "blocks": 480.0, "flat": 260.0, "spheres": 300.0,
                     "letter": 240.0}
#: where the impression region starts along the scan (the L target lies before it)
FEATURES_START_Y_MM = 110.0
SCENE_HALF_WIDTH_MM = 185.0


@dataclass
class Scene:
    x0_mm: float
    y0_mm: float
    pixel_mm: float
    height_mm: np.ndarray  # (H, W) float32
    albedo: np.ndarray  # (H, W, 3) uint8 RGB
    features: list[dict] = field(default_factory=list)

    @property
    def shape(self) -> tuple[int, int]:
        return self.height_mm.shape

    def xs(self) -> np.ndarray:
        return self.x0_mm + self.pixel_mm * np.arange(self.shape[1])

    def ys(self) -> np.ndarray:
        return self.y0_mm + self.pixel_mm * np.arange(self.shape[0])


def _value_noise(rng: np.random.Generator, shape, cell_px: float, octaves: int = 4) -> np.ndarray:
    """Smooth multi-octave noise in [-1, 1] (cubic upsampling of random grids)."""
    import cv2

    h, w = shape
    out = np.zeros(shape, np.float32)
    amp, total = 1.0, 0.0
    cell = cell_px
    for _ in range(octaves):
        gh, gw = max(2, int(h / cell) + 3), max(2, int(w / cell) + 3)
        grid = rng.uniform(-1, 1, (gh, gw)).astype(np.float32)
        up = cv2.resize(grid, (int((gw - 1) * cell) + 1, int((gh - 1) * cell) + 1),
                        interpolation=cv2.INTER_CUBIC)
        out += amp * up[:h, :w]
        total += amp
        amp *= 0.5
        cell = max(cell / 2.0, 1.5)
    return out / total


def soil_albedo(rng: np.random.Generator, shape, pixel_mm: float, kind: str = "soil",
                soil: dict | None = None) -> np.ndarray:
    """Soil/sand texture with reddish and greenish patches, RGB uint8.

    ``soil`` (the random rigs) overrides the colour and texture: ``base`` (RGB albedo 0..1),
    ``mottle`` and ``grain`` (relative amplitudes of the coarse and fine texture)."""
    base = {"soil": (0.42, 0.33, 0.24), "sand": (0.62, 0.55, 0.42), "stone": (0.72, 0.70, 0.66)}[kind]
    n1 = _value_noise(rng, shape, 12.0 / pixel_mm, 5)
    grain = _value_noise(rng, shape, 0.6 / pixel_mm, 2)
    patches_r = np.clip(_value_noise(rng, shape, 40.0 / pixel_mm, 2) * 2.2 - 0.6, 0, 1)
    patches_g = np.clip(_value_noise(rng, shape, 45.0 / pixel_mm, 2) * 2.2 - 0.6, 0, 1)
    if soil is None:
        lum = 1.0 + 0.25 * n1 + 0.12 * grain
    else:
        base = tuple(soil["base"])
        lum = 1.0 + float(soil["mottle"]) * n1 + float(soil["grain"]) * grain
    # reddish clay and greenish moss patches: clearly coloured, never as bright as a laser
    # (each channel a contiguous plane, its terms in a fixed order: a scene is tens of
    # millions of cells)
    terms = ((np.add, 0.22, patches_r), (np.subtract, 0.10, patches_g)), (
        (np.subtract, 0.08, patches_r), (np.add, 0.16, patches_g)), (
        (np.subtract, 0.08, patches_r), (np.subtract, 0.04, patches_g))
    rgb = np.empty((*shape, 3), np.uint8)
    plane = np.empty(shape, np.float32)
    for c in range(3):
        np.multiply(lum, np.float32(base[c]), out=plane)
        for op, k, patches in terms[c]:
            op(plane, np.float32(k) * patches, out=plane)
        plane *= np.float32(255.0)
        np.clip(plane, 0, 255, out=plane)
        rgb[..., c] = plane
    return rgb


def _grid(length_mm: float, pixel_mm: float):
    x0 = -SCENE_HALF_WIDTH_MM
    y0 = -90.0
    w = int(round(2 * SCENE_HALF_WIDTH_MM / pixel_mm)) + 1
    h = int(round((length_mm + 180.0) / pixel_mm)) + 1
    xs = (x0 + pixel_mm * np.arange(w)).astype(np.float32)
    ys = (y0 + pixel_mm * np.arange(h)).astype(np.float32)
    return x0, y0, xs, ys


def _rect(X, Y, cx, cy, w, h):
    return (np.abs(X - cx) <= w / 2) & (np.abs(Y - cy) <= h / 2)


def _smooth(height: np.ndarray, sigma_mm: float, pixel_mm: float) -> np.ndarray:
    import cv2

    s = sigma_mm / pixel_mm
    if s < 0.3:
        return height
    return cv2.GaussianBlur(height, (0, 0), s)


def _shoe(X, Y, rng, length_mm, features):
    L = 290.0
    v0 = FEATURES_START_Y_MM + 20.0
    ang = np.radians(4.0)
    u = (X - 0.0) * np.cos(ang) + (Y - v0 - L / 2) * np.sin(ang)
    v = -(X - 0.0) * np.sin(ang) + (Y - v0 - L / 2) * np.cos(ang) + L / 2
    fore = (u / 52.0) ** 2 + ((v - 205.0) / 85.0) ** 2 <= 1
    heel = (u / 41.0) ** 2 + ((v - 52.0) / 52.0) ** 2 <= 1
    waist = (np.abs(u) <= 33.0) & (v > 50) & (v < 200)
    sole = fore | heel | waist
    # the sole presses 3-5 mm, deeper at heel and ball
    base = 3.0 + 1.2 * np.exp(-((v - 52) / 40) ** 2) + 1.0 * np.exp(-((v - 215) / 45) ** 2)
    h = np.zeros_like(X)
    h = np.where(sole, -base, h)
    # tread lugs (shoe rubber pushes deeper): 12 x 8 mm blocks with 4 mm grooves in the forefoot
    lug = (np.mod(u + 200.0, 16.0) < 12.0) & (np.mod(v, 12.0) < 8.0) & fore & ~heel
    h = np.where(lug, h - 4.0, h)
    # heel bars, 6 mm wide, 4 mm apart
    bars = (np.mod(v, 10.0) < 6.0) & heel & ((u / 36.0) ** 2 + ((v - 52.0) / 46.0) ** 2 <= 1)
    h = np.where(bars, h - 3.5, h)
    # logo in the waist: a ring with a bar (shallower relief)
    r = np.hypot(u, v - 135.0)
    logo = ((r > 11) & (r < 15)) | (_rect(u, v, 0.0, 135.0, 18.0, 3.0))
    h = np.where(logo & sole, h - 2.0, h)
    features.append({"kind": "shoe", "length_mm": L, "heel_y_mm": v0})
    # randomly acquired characteristics: small cuts in the sole (0.5-2 mm), soil fills them
    for k in range(6):
        cu = rng.uniform(-35, 35)
        cv_ = rng.uniform(170, 260) if k % 2 == 0 else rng.uniform(20, 85)
        size = rng.uniform(0.5, 2.0)
        mark = ((u - cu) ** 2 + (v - cv_) ** 2 <= (size / 2) ** 2) | (
            _rect(u, v, cu + 3 * size, cv_, 0.5, 2.5 * size)
        )
        h = np.where(mark & sole, h + 1.0, h)
        xw = cu * np.cos(ang) - (cv_ - L / 2) * np.sin(ang)
        yw = cu * np.sin(ang) + (cv_ - L / 2) * np.cos(ang) + v0 + L / 2
        features.append({"kind": "nick", "x_mm": float(xw), "y_mm": float(yw),
                         "size_mm": float(size)})
    # a clean 2-10 mm depth range
    return np.clip(h, -10.0, 0.0)


#: the shoe's own frame: the rail frame of today's (unposed) shoe scene; a pose turns the whole
#: sole (relief, nicks, cut) by ``rotate_deg`` about the vertical through SHOE_CENTRE_MM
#: (counter-clockwise seen from the camera in the rail frame X right, Y down the image: i.e.
#: from +X towards +Y) and then shifts it by ``(shift_x_mm, shift_y_mm)``
SHOE_CENTRE_MM = (0.0, FEATURES_START_Y_MM + 20.0 + 145.0)
SHOE_REACH_MM = 200.0  # half the rows' span computed around a posed sole's centre


@dataclass(frozen=True)
class ShoePose:
    """Where the shoe lies: rail = C + shift + Rz(rotate) (shoe - C), ``C`` = SHOE_CENTRE_MM."""

    rotate_deg: float = 0.0
    shift_x_mm: float = 0.0
    shift_y_mm: float = 0.0

    @classmethod
    def of(cls, doc) -> ShoePose:
        if doc is None:
            return cls()
        if isinstance(doc, ShoePose):
            return doc
        return cls(float(doc.get("rotate_deg", 0.0)), float(doc.get("shift_x_mm", 0.0)),
                   float(doc.get("shift_y_mm", 0.0)))

    def is_identity(self) -> bool:
        return self.rotate_deg == 0.0 and self.shift_x_mm == 0.0 and self.shift_y_mm == 0.0

    def _cs(self) -> tuple[float, float]:
        a = np.radians(self.rotate_deg)
        return float(np.cos(a)), float(np.sin(a))

    def to_shoe(self, X, Y):
        """Rail-frame (X, Y) -> the shoe's own frame (float64 arrays)."""
        c, s = self._cs()
        cx, cy = SHOE_CENTRE_MM
        dx = np.asarray(X, np.float64) - cx - self.shift_x_mm
        dy = np.asarray(Y, np.float64) - cy - self.shift_y_mm
        return cx + c * dx + s * dy, cy - s * dx + c * dy

    def to_rail(self, x, y):
        """The shoe's own frame -> the rail frame."""
        c, s = self._cs()
        cx, cy = SHOE_CENTRE_MM
        dx, dy = np.asarray(x, np.float64) - cx, np.asarray(y, np.float64) - cy
        return cx + self.shift_x_mm + c * dx - s * dy, cy + self.shift_y_mm + s * dx + c * dy

    def matrix(self) -> list[list[float]]:
        """The 3 x 3 homogeneous matrix taking shoe-frame (x, y, 1) to rail (X, Y, 1)."""
        c, s = self._cs()
        cx, cy = SHOE_CENTRE_MM
        return [[c, -s, cx + self.shift_x_mm - c * cx + s * cy],
                [s, c, cy + self.shift_y_mm - s * cx - c * cy], [0.0, 0.0, 1.0]]

    def to_json(self) -> dict:
        return {"rotate_deg": self.rotate_deg, "shift_x_mm": self.shift_x_mm,
                "shift_y_mm": self.shift_y_mm}


@dataclass(frozen=True)
class ShoeCut:
    """A cut in the outsole (a randomly acquired characteristic): a groove ``depth_mm`` deep,
    ``length_mm`` long and ``width_mm`` wide centred at ``(x_mm, y_mm)`` of the shoe's own
    frame, its length along ``angle_deg`` (from +x towards +y). Soil fills the groove: the
    impression gets a flat-topped ridge ``depth_mm`` high (towards the camera), added after
    the sole's smoothing so its top is exactly ``depth_mm`` above the sole."""

    x_mm: float = 15.0
    y_mm: float = 230.0
    angle_deg: float = 30.0
    length_mm: float = 3.0
    width_mm: float = 0.6
    depth_mm: float = 0.5

    @classmethod
    def of(cls, doc) -> ShoeCut:
        if isinstance(doc, ShoeCut):
            return doc
        if doc is True:
            return cls()
        return cls(**{k: float(v) for k, v in dict(doc).items()})

    def to_json(self) -> dict:
        return {"x_mm": self.x_mm, "y_mm": self.y_mm, "angle_deg": self.angle_deg,
                "length_mm": self.length_mm, "width_mm": self.width_mm,
                "depth_mm": self.depth_mm}


def _place_features(features: list[dict], pose: ShoePose) -> None:
    """The shoe's recorded feature positions moved by the pose (into the rail frame)."""
    for f in features:
        if f.get("kind") == "nick":
            x, y = pose.to_rail(f["x_mm"], f["y_mm"])
            f["x_mm"], f["y_mm"] = float(x), float(y)
        elif f.get("kind") == "shoe":
            f["pose"] = {**pose.to_json(), "centre_mm": list(SHOE_CENTRE_MM),
                         "matrix_shoe_to_rail": pose.matrix()}


def _add_cut(h: np.ndarray, Xs, Ys, cut: ShoeCut, pose: ShoePose, features: list) -> np.ndarray:
    """``h`` (rows of the scene) with the cut's ridge; ``Xs, Ys`` the cells in the shoe's frame."""
    a = np.radians(cut.angle_deg)
    du, dv = np.asarray(Xs, np.float64) - cut.x_mm, np.asarray(Ys, np.float64) - cut.y_mm
    along = du * np.cos(a) + dv * np.sin(a)
    across = -du * np.sin(a) + dv * np.cos(a)
    mark = (np.abs(along) <= cut.length_mm / 2) & (np.abs(across) <= cut.width_mm / 2)
    ends = [pose.to_rail(cut.x_mm + sgn * cut.length_mm / 2 * np.cos(a),
                         cut.y_mm + sgn * cut.length_mm / 2 * np.sin(a)) for sgn in (-1, 1)]
    cx, cy = pose.to_rail(cut.x_mm, cut.y_mm)
    features.append({"kind": "cut", **cut.to_json(), "frame": "shoe (before the pose)",
                     "centre_rail_mm": [float(cx), float(cy)],
                     "ends_rail_mm": [[float(e[0]), float(e[1])] for e in ends],
                     "angle_rail_deg": cut.angle_deg + pose.rotate_deg,
                     "cells": int(mark.sum()),
                     "note": "a groove in the outsole; in the impression a ridge depth_mm "
                             "high (towards the camera), flat-topped"})
    return np.where(mark, h + np.float32(cut.depth_mm), h).astype(np.float32)


def shoe_relief(pixel_mm: float, sole_seed: int = 1, pose=None, cut=None,
                half_width_mm: float = 125.0) -> Scene:
    """The shoe preset's relief alone (no target, a flat albedo) on the cells around the sole:
    rail X within ``half_width_mm`` of the posed centre, Y within SHOE_REACH_MM of it; the
    same heights as :func:`build_scene` gives there with ``sole_seed`` (for tests and
    benchmarks that need the truth of several poses quickly)."""
    pose = ShoePose.of(pose)
    cx = SHOE_CENTRE_MM[0] + pose.shift_x_mm
    cy = SHOE_CENTRE_MM[1] + pose.shift_y_mm
    # on the scene's own grid (cells at -SCENE_HALF_WIDTH_MM + j p, -90 + i p)
    j0 = int(np.floor((cx - half_width_mm + SCENE_HALF_WIDTH_MM) / pixel_mm))
    j1 = int(np.ceil((cx + half_width_mm + SCENE_HALF_WIDTH_MM) / pixel_mm)) + 1
    i0 = int(np.floor((cy - SHOE_REACH_MM + 90.0) / pixel_mm))
    i1 = int(np.ceil((cy + SHOE_REACH_MM + 90.0) / pixel_mm)) + 1
    xs = (-SCENE_HALF_WIDTH_MM + pixel_mm * np.arange(j0, j1)).astype(np.float32)
    ys = (-90.0 + pixel_mm * np.arange(i0, i1)).astype(np.float32)
    X, Y = np.meshgrid(xs, ys)
    features: list[dict] = []
    rng = np.random.default_rng(int(sole_seed))
    Xs, Ys = (X, Y) if pose.is_identity() else (
        v.astype(np.float32) for v in pose.to_shoe(X, Y))
    h = _smooth(_shoe(Xs, Ys, rng, 0.0, features).astype(np.float32), 0.25, pixel_mm)
    if not pose.is_identity():
        _place_features(features, pose)
    if cut is not None:
        h = _add_cut(h, Xs, Ys, ShoeCut.of(cut), pose, features)
    albedo = np.full((*h.shape, 3), 128, np.uint8)
    return Scene(float(xs[0]), float(ys[0]), pixel_mm, h.astype(np.float32), albedo, features)


def _tire(X, Y, rng, length_mm, features):
    y_a, y_b = FEATURES_START_Y_MM, length_mm + 60.0
    inside = (np.abs(X) <= 92.5) & (Y >= y_a) & (Y <= y_b)
    h = np.where(inside, -5.0, 0.0)
    # ribs along the track separated by 4 circumferential grooves, lateral chevron sipes
    grooves = np.zeros_like(inside)
    for gx in (-55.0, -18.0, 18.0, 55.0):
        grooves |= np.abs(X - gx) <= 5.0
    chevron = np.mod(Y + 0.35 * np.abs(X), 28.0) < 6.0
    tread = inside & ~grooves & ~(chevron & (np.abs(X) > 60.0))
    h = np.where(tread, h - 8.5, h)  # tread blocks press 8.5 mm deeper than the grooves
    # wear bars in the grooves every 250 mm: 1.6 mm high, 10 mm long
    wear = inside & grooves & (np.mod(Y - y_a, 250.0) < 10.0)
    h = np.where(wear, h - 1.6, h)
    features.append({"kind": "tire", "width_mm": 185.0, "tread_depth_mm": 8.5})
    return h


STEP_MM = 6.35
SLOT_WIDTHS_MM = (6.35, 4.76, 3.18, 2.38, 1.59, 0.83)


def _blocks(X, Y, rng, length_mm, features, rotate90=False, lift_b_mm=0.0, tilt_deg=0.0,
            order="AB"):
    h = np.zeros(X.shape, np.float32)
    centres = {"A": FEATURES_START_Y_MM + 80.0, "B": FEATURES_START_Y_MM + 240.0}
    if order == "BA":
        centres = {"A": centres["B"], "B": centres["A"]}
    plate_h = 12.0
    X_all, Y_all = X, Y
    for name, cy in centres.items():
        lift = lift_b_mm if name == "B" else 0.0
        # the plate's rows only (it reaches 80 mm from its centre either way round): the same
        # cell values as over the whole scene, without tens of millions of cells per step
        rows = np.flatnonzero(np.abs(Y_all[:, 0] - cy) <= 81.0)
        X, Y = X_all[rows], Y_all[rows]
        # local coordinates: a along the features, b across; rotate90 swaps them
        a, b = (Y - cy, X) if rotate90 else (X, Y - cy)
        plate = (np.abs(a) <= 80.0) & (np.abs(b) <= 60.0)
        local = np.where(plate, plate_h, 0.0)
        if name == "A":
            # slotted target: 20 mm high block with slots 6.35 deep, walls 6.35 apart
            top = 20.0
            width = sum(SLOT_WIDTHS_MM) + STEP_MM * (len(SLOT_WIDTHS_MM) + 1)
            a0 = -width / 2
            block = (np.abs(b) <= 22.0) & (a >= a0) & (a <= a0 + width)
            local = np.where(block, plate_h + top, local)
            pos = a0 + STEP_MM
            for w in SLOT_WIDTHS_MM:
                slot = block & (a >= pos) & (a < pos + w)
                local = np.where(slot, plate_h + top - STEP_MM, local)
                features.append({"kind": "slot", "plate": name, "width_mm": w,
                                 "depth_mm": STEP_MM, "centre_a_mm": pos + w / 2,
                                 "plate_centre_y_mm": cy, "rotated90": rotate90})
                pos += w + STEP_MM
        else:
            # stepped target: four steps 6.35 wide and 6.35 high
            a0 = -2 * STEP_MM
            for k in range(4):
                step = (np.abs(b) <= 22.0) & (a >= a0 + k * STEP_MM)
                local = np.where(plate & step & (a <= a0 + 4 * STEP_MM), plate_h + (k + 1) * STEP_MM,
                                 local)
            features.append({"kind": "steps", "plate": name, "step_width_mm": STEP_MM,
                             "step_height_mm": STEP_MM, "n_steps": 4, "start_a_mm": a0,
                             "plate_centre_y_mm": cy, "rotated90": rotate90})
        if tilt_deg:
            # tilt about the plate's own x axis (a shear: xy widths and vertical steps keep size)
            local = np.where(plate, local + np.tan(np.radians(tilt_deg)) * (Y - cy), local)
        local = np.where(plate, local + lift, local)
        h[rows] = np.where(plate, local, h[rows])
    features.append({"kind": "blocks", "order": order, "rotated90": rotate90,
                     "lift_b_mm": lift_b_mm, "tilt_deg": tilt_deg, "plate_height_mm": plate_h})
    return h


def _spheres(X, Y, rng, length_mm, features, radius=12.7, spacing=50.0):
    h = np.zeros_like(X)
    ys = np.arange(FEATURES_START_Y_MM + 40.0, length_mm + 40.0, spacing)
    for cy in ys:
        for cx in (-spacing, 0.0, spacing):
            rho2 = (X - cx) ** 2 + (Y - cy) ** 2
            cap = np.sqrt(np.clip(radius**2 - rho2, 0, None))
            h = np.maximum(h, np.where(rho2 < radius**2, cap, 0.0))
            features.append({"kind": "sphere", "x_mm": float(cx), "y_mm": float(cy),
                             "z_mm": 0.0, "radius_mm": radius})
    return h


def _letter_f(X, Y, features, height=6.0, cy=None):
    """A raised letter F, as read from above with the camera's view (x to the right, the
    image's first rows at the top): a chiral relief, its mirror image is another shape. The
    letter's top is towards the start of the scan (smaller rail Y)."""
    cy = FEATURES_START_Y_MM + 60.0 if cy is None else cy
    top = cy - 40.0  # rail Y of the letter's top edge
    stem = _rect(X, Y, -20.0, cy, 12.0, 80.0)
    bar_top = _rect(X, Y, 2.0, top + 6.0, 56.0, 12.0)
    bar_mid = _rect(X, Y, -4.0, cy + 2.0, 44.0, 10.0)
    f = stem | bar_top | bar_mid
    features.append({"kind": "letter", "letter": "F", "height_mm": height, "centre_y_mm": cy,
                     "reads": "upright with x to the right and rail Y downwards (as the "
                              "camera sees it)"})
    return np.where(f, height, 0.0)


def build_scene(preset: str, length_mm: float, pixel_mm: float, seed: int,
                target: TargetModel | None, target_pose: tuple[float, float, float],
                soil: dict | None = None, **options) -> Scene:
    """Make the heightfield and albedo for ``preset`` over a scan of ``length_mm``.

    ``target_pose`` = (x_mm, y_mm, yaw_deg) of the target's object origin in the rail frame.
    """
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}")
    rng = np.random.default_rng(seed)
    x0, y0, xs, ys = _grid(length_mm, pixel_mm)
    X, Y = np.meshgrid(xs, ys)
    features: list[dict] = []
    kind = "soil"
    if preset == "shoe":
        pose = ShoePose.of(options.pop("pose", None))
        cut = options.pop("cut", None)
        sole_seed = options.pop("sole_seed", None)
        # the sole's random nicks from their own seed when given (two scans of one shoe with
        # different render seeds), else from the scene's generator as always
        sole_rng = rng if sole_seed is None else np.random.default_rng(int(sole_seed))
        if options:
            raise ValueError(f"unknown shoe options {sorted(options)}")
        if pose.is_identity():
            # the sole spans about 300 mm from FEATURES_START_Y_MM: compute its relief there only
            rows = (ys >= FEATURES_START_Y_MM) & (ys <= FEATURES_START_Y_MM + 340.0)
            Xs, Ys = X[rows], Y[rows]
        else:
            cy = SHOE_CENTRE_MM[1] + pose.shift_y_mm
            rows = (ys >= cy - SHOE_REACH_MM) & (ys <= cy + SHOE_REACH_MM)
            Xs, Ys = (v.astype(np.float32) for v in pose.to_shoe(X[rows], Y[rows]))
        h = np.zeros(X.shape, np.float32)
        h[rows] = _smooth(_shoe(Xs, Ys, sole_rng, length_mm, features).astype(np.float32),
                          0.25, pixel_mm)
        if not pose.is_identity():
            _place_features(features, pose)
        if cut is not None:
            h[rows] = _add_cut(h[rows], Xs, Ys, ShoeCut.of(cut), pose, features)
    elif preset == "tire":
        h = _smooth(_tire(X, Y, rng, length_mm, features).astype(np.float32), 0.3, pixel_mm)
        kind = "sand"
    elif preset == "blocks":
        h = _blocks(X, Y, rng, length_mm, features, **options)
        kind = "stone"
    elif preset == "spheres":
        h = _spheres(X, Y, rng, length_mm, features)
        kind = "stone"
    elif preset == "letter":
        h = _smooth(_letter_f(X, Y, features).astype(np.float32), 0.3, pixel_mm)
    else:
        h = np.zeros_like(X)
        features.append({"kind": "plane", "height_mm": 0.0})
    del X
    h = np.asarray(h, dtype=np.float32)
    albedo = soil_albedo(rng, h.shape, pixel_mm, kind, soil)
    if target is not None:
        tx, ty, yaw = target_pose
        c, s = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
        # only the cells around the target (its footprint's bounding box)
        corners = target.corner_array()
        reach = float(np.max(np.abs(corners[:, :2]))) * 1.5 + 2.0
        j0 = max(0, int((tx - reach - x0) / pixel_mm))
        j1 = min(len(xs), int((tx + reach - x0) / pixel_mm) + 1)
        i0 = max(0, int((ty - reach - y0) / pixel_mm))
        i1 = min(len(ys), int((ty + reach - y0) / pixel_mm) + 1)
        Xg, Yg = np.meshgrid(xs[j0:j1], ys[i0:i1])
        # object coordinates of every cell: the inverse of rail = T + Rz(yaw) (x, -y) (object z
        # is up while the rail frame's Z' is depth, so the object's y axis points backwards)
        ox = c * (Xg - tx) + s * (Yg - ty)
        oy = s * (Xg - tx) - c * (Yg - ty)
        th = target.heightfield(ox, oy, grow_mm=0.5 * pixel_mm)
        on = np.isfinite(th)
        sub = h[i0:i1, j0:j1]
        sub[on] = th[on]
        # painted wood: light grey with a matte finish
        alb = albedo[i0:i1, j0:j1]
        alb[on] = (np.array([178, 170, 160]) * (1 + 0.03 * rng.standard_normal((on.sum(), 1))))\
            .clip(0, 255).astype(np.uint8)
    return Scene(x0, y0, pixel_mm, h, albedo, features)
