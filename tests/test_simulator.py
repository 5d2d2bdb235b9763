"""The simulator checked against geometry, not against itself.

Predictions here come from the rig's laser planes, the intrinsics, the target model and its
written placement, with plain plane/ray algebra; the renderer's ray caster and stripe drawing are
only ever looked at through the pixels they produce.
"""

from __future__ import annotations

import json
import subprocess
import sys
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from impress_gui.core.calibration.geometry import Intrinsics
from impress_gui.core.calibration.picks import Picks
from impress_gui.core.calibration.target import CORNER_NAMES, TargetModel, default_target
from impress_gui.sim.render import Renderer, RenderOptions
from impress_gui.sim.scenes import build_scene
from impress_gui.sim.simulate import (
    SimConfig,
    make_motion,
    make_rig,
    render_frames,
    target_pose,
    target_to_rail,
)

W, H = 640, 360
GREEN, RED = 1, 0  # dominant channel of each laser (RGB)

# tolerances (pixels unless stated)
STRIPE_TOL_CLEAN_PX = 0.06  # noise-free, unsaturated stripe: every column (seen: 0.036)
STRIPE_BIAS_PX = 0.05  # default noise, speckle and saturated core: median signed error (0.009)
STRIPE_TOL_MEDIAN_PX = 0.2  # ... median absolute error (seen: 0.09-0.12)
STRIPE_TOL_P95_PX = 0.5  # ... 95th percentile (seen: 0.25-0.29)
# target edges and corners: the scene grid ends a top face at its last cell centre inside the
# face, on average half a cell (0.05 mm, 0.12-0.14 px here) inside the model's edge
EDGE_TOL_PX = 0.25  # median offset of an edge found in the image from its projection
CORNER_TOL_PX = 0.3  # corner from two fitted edges vs the projected corner
DEPTH_TOL_MM = 0.05  # what a pixel next to an occluding edge sees


@pytest.fixture(scope="module")
def world():
    """The `flat` preset with the L target, 120 mm of travel, at 640x360."""
    cfg = SimConfig(preset="flat", length_mm=120.0, width=W, height=H, seed=3)
    rig, motion, target = make_rig(cfg), make_motion(cfg), default_target()
    scene = build_scene(cfg.preset, cfg.scan_length_mm, cfg.grid_mm, cfg.seed, target,
                        target_pose(cfg))
    travel = motion.travel_mm(motion.times_s())
    return SimpleNamespace(cfg=cfg, rig=rig, motion=motion, target=target, scene=scene,
                           travel=travel)


def renderer(world, **options) -> Renderer:
    return Renderer(world.scene, world.rig, world.motion, RenderOptions(**options))


def frame_at(world, travel_mm: float) -> tuple[int, float]:
    k = int(np.argmin(np.abs(world.travel - travel_mm)))
    return k, float(world.travel[k])


def to_pixels(rig, pts_ideal: np.ndarray) -> np.ndarray:
    """Camera-fixed ideal-frame points (mm) -> distorted pixels: x = R^T X, then the lens."""
    return rig.intrinsics.project(np.asarray(pts_ideal, float) @ rig.rotation)


def pixel_rays_ideal(rig, uv: np.ndarray) -> np.ndarray:
    """Ideal-frame directions (Z = 1) of the rays through distorted pixels ``(N, 2)``."""
    d = rig.intrinsics.rays(uv) @ rig.rotation.T
    return d / d[:, 2:3]


def laser_ground_line(rig, laser, s_mm: float, n: int = 40000):
    """Rail-frame points of the laser plane on the ground (depth = standoff) in frame travel
    ``s_mm``, and their pixels; the plane is fixed to the camera, the ground to the rail."""
    nrm, d = laser.plane.normal, laser.plane.offset_mm
    z = rig.standoff_mm
    direction = np.cross(nrm, [0.0, 0.0, 1.0])
    direction /= np.linalg.norm(direction)
    p0 = np.array([0.0, (d - nrm[2] * z) / nrm[1], z])  # X = 0 on the line
    t = np.linspace(-260.0, 260.0, n)
    pts = p0 + t[:, None] * direction
    uv = to_pixels(rig, pts)
    return pts + [0.0, s_mm, 0.0], uv


def rows_at_columns(uv: np.ndarray, cols: np.ndarray) -> np.ndarray:
    order = np.argsort(uv[:, 0])
    return np.interp(cols, uv[order, 0], uv[order, 1], left=np.nan, right=np.nan)


def rail_polygons(world) -> list[tuple[np.ndarray, float]]:
    """Top faces of the placed target: rail-frame (x, y) polygons and their depth (mm)."""
    out = []
    for face in world.target.top_faces():
        v = target_to_rail(face.vertices_mm, target_pose(world.cfg), world.rig.standoff_mm)
        out.append((v[:, :2].astype(np.float32), float(v[0, 2])))
    return out


def inside(poly: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Signed distance (mm) of points ``(..., 2)`` into a convex polygon, positive inside
    (exact inside, a lower bound of the distance outside)."""
    p = np.asarray(poly, float)
    area2 = np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1])
    e = np.roll(p, -1, axis=0) - p
    n = np.stack([-e[:, 1], e[:, 0]], axis=1) / np.linalg.norm(e, axis=1)[:, None]
    n *= np.sign(area2)  # inward normals
    xy = np.asarray(xy, float)[..., None, :]
    return np.min(np.sum((xy - p) * n, axis=-1), axis=-1)


def blocked(world, a, b, n: int = 800) -> np.ndarray:
    """For segments ``a -> b`` (rail frame; ``b`` is ``(N, 3)``), does the segment pass through
    the target (vertical-walled prisms under its top faces)? The last 0.5 mm before ``b`` is
    not tested (``b`` lies on a surface)."""
    a = np.broadcast_to(np.asarray(a, float), np.shape(b))
    b = np.asarray(b, float)
    length = np.linalg.norm(b - a, axis=1)
    t = np.linspace(0.0, 1.0, n)[None, :] * (1.0 - 0.5 / length)[:, None]
    p = a[:, None, :] + t[..., None] * (b - a)[:, None, :]  # (N, n, 3)
    hit = np.zeros(len(b), bool)
    for poly, depth in rail_polygons(world):
        hit |= np.any((p[..., 2] >= depth) & (inside(poly, p[..., :2]) > 0), axis=1)
    return hit


def stripe_centres(signal: np.ndarray, rows: np.ndarray, floor: float, half: int = 7) -> np.ndarray:
    """Per-column centre of mass of ``signal`` above ``floor`` times its maximum, in a window
    around the expected row (NaN where the column has no stripe)."""
    out = np.full(signal.shape[1], np.nan)
    for u in np.flatnonzero(np.isfinite(rows)):
        r0 = int(round(rows[u]))
        lo, hi = max(0, r0 - half), min(signal.shape[0], r0 + half + 1)
        col = signal[lo:hi, u].astype(float)
        if col.max() < 10:
            continue
        w = np.clip(col - floor * col.max(), 0, None)
        out[u] = lo + float(np.sum(w * np.arange(col.size)) / np.sum(w))
    return out


# ----- (a) stripes on the ground plane ---------------------------------------------------------
@pytest.fixture(scope="module")
def stripe_frame(world):
    """A frame whose stripes both fall on open ground behind the target."""
    k, s = frame_at(world, 118.0)
    dark = renderer(world, noise_sigma_dn=0.0, speckle_contrast=0.0, laser_peak=0.0)
    background = dark.render(k)[0].astype(np.int16)
    return SimpleNamespace(k=k, s=s, background=background)


@pytest.mark.parametrize("name, ch", [("green", GREEN), ("red", RED)])
def test_clean_stripe_centre_is_plane_ground_intersection(world, stripe_frame, name, ch):
    laser = world.rig.laser(name)
    pts, uv = laser_ground_line(world.rig, laser, stripe_frame.s)
    cols = np.arange(W)
    expected = rows_at_columns(uv, cols)
    # the stripe must be on open ground: neither shadowed nor hidden by the target
    src = laser.source_mm + [0.0, stripe_frame.s, 0.0]
    assert not blocked(world, src, pts[::100]).any()
    assert not blocked(world, [0.0, stripe_frame.s, 0.0], pts[::100]).any()
    # unsaturated, noise-free stripe minus the same frame without lasers
    clean = renderer(world, noise_sigma_dn=0.0, speckle_contrast=0.0, laser_peak=0.25)
    img = clean.render(stripe_frame.k)[0].astype(np.int16)
    signal = np.clip(img[..., ch] - stripe_frame.background[..., ch], 0, None)
    found = stripe_centres(signal, expected, floor=0.0)
    ok = np.isfinite(found) & np.isfinite(expected)
    assert ok.sum() > 0.95 * W, f"stripe found in {ok.sum()} of {W} columns"
    err = np.abs(found[ok] - expected[ok])
    assert err.max() < STRIPE_TOL_CLEAN_PX, f"max error {err.max():.3f} px"


@pytest.mark.parametrize("name, ch", [("green", GREEN), ("red", RED)])
def test_realistic_stripe_centre_has_no_bias(world, stripe_frame, name, ch):
    """Default speckle, sensor noise and a saturated core: no bias, sub-pixel scatter."""
    _, uv = laser_ground_line(world.rig, world.rig.laser(name), stripe_frame.s)
    expected = rows_at_columns(uv, np.arange(W))
    real = renderer(world, seed=5)
    img = real.render(stripe_frame.k)[0].astype(np.int16)
    signal = np.clip(img[..., ch] - stripe_frame.background[..., ch], 0, None)
    found = stripe_centres(signal, expected, floor=0.5)
    ok = np.isfinite(found) & np.isfinite(expected)
    assert ok.sum() > 0.95 * W
    err = found[ok] - expected[ok]
    assert abs(np.median(err)) < STRIPE_BIAS_PX, f"bias {np.median(err):.3f} px"
    assert np.median(np.abs(err)) < STRIPE_TOL_MEDIAN_PX, f"median {np.median(np.abs(err)):.3f}"
    assert np.percentile(np.abs(err), 95) < STRIPE_TOL_P95_PX


def test_a_stripe_that_follows_the_soil_leans_to_its_brighter_side(world, stripe_frame):
    """``RenderOptions.stripe_follows_soil``: each pixel of a stripe reflects the laser with the
    albedo of the surface point it sees, as a real surface does. On ground whose albedo steps
    from dark to bright along each laser's line, the stripe's centre of mass moves towards the
    bright side; drawn as before (one albedo per column, at the exact centre) it stays on the
    line. Away from the stripes the two frames are the same."""
    from dataclasses import replace

    sc = world.scene
    ys = sc.y0_mm + sc.pixel_mm * np.arange(sc.albedo.shape[0])
    xs = sc.x0_mm + sc.pixel_mm * np.arange(sc.albedo.shape[1])
    lines = {name: laser_ground_line(world.rig, world.rig.laser(name), stripe_frame.s)
             for name in ("green", "red")}
    # the albedo steps along each laser's ground line (each cell takes the nearer line's side)
    dist = {}
    for name, (pts, _) in lines.items():
        d = pts[-1, :2] - pts[0, :2]
        d /= np.linalg.norm(d)
        dist[name] = d[0] * (ys[:, None] - pts[0, 1]) - d[1] * (xs[None, :] - pts[0, 0])
    near_green = np.abs(dist["green"]) < np.abs(dist["red"])
    side = np.where(near_green, dist["green"], dist["red"]) > 0
    alb = np.where(side[..., None], 200, 60).astype(np.uint8)
    scene = replace(sc, albedo=np.ascontiguousarray(np.broadcast_to(alb, sc.albedo.shape)))
    opts = dict(noise_sigma_dn=0.0, speckle_contrast=0.0, laser_peak=0.25)
    frames = {}
    for key, extra in (("bg", dict(laser_peak=0.0)), ("off", {}),
                       ("on", dict(stripe_follows_soil=True))):
        r = Renderer(scene, world.rig, world.motion, RenderOptions(**{**opts, **extra}))
        frames[key] = r.render(stripe_frame.k)[0].astype(np.int16)
    far = np.ones(H, bool)  # image rows away from both stripes
    for (name, ch), (_, uv) in zip((("green", GREEN), ("red", RED)), lines.values(),
                                   strict=True):
        expected = rows_at_columns(uv, np.arange(W))
        far[max(0, int(np.nanmin(expected)) - 12):int(np.nanmax(expected)) + 13] = False
        bg = frames["bg"][..., ch]
        cols = np.flatnonzero(np.isfinite(expected) & (expected > 8) & (expected < H - 9))
        rows = np.round(expected[cols]).astype(int)
        bright_below = np.sign(bg[rows + 4, cols] - bg[rows - 4, cols])  # + : towards more rows
        assert np.mean(bright_below != 0) > 0.9
        shift = {}
        for key in ("off", "on"):
            sig = np.clip(frames[key][..., ch] - bg, 0, None)
            found = stripe_centres(sig, expected, floor=0.1)
            shift[key] = (found - expected)[cols] * bright_below
        ok = np.isfinite(shift["off"]) & np.isfinite(shift["on"]) & (bright_below != 0)
        assert ok.sum() > 0.8 * W
        assert abs(np.median(shift["off"][ok])) < 0.05, name  # on the line (seen: -0.01)
        assert np.median(shift["on"][ok]) > 0.15, name  # towards the bright side (seen: 0.45)
    # the soil away from both stripes is untouched
    assert far.sum() > H / 3
    np.testing.assert_array_equal(frames["on"][far], frames["off"][far])


def test_the_stripe_option_reaches_the_renderer_and_the_truth(monkeypatch):
    """``impress simulate --stripe-follows-soil``, with a random rig or a preset: the config
    the renderer is built from has it, and ``truth.json``'s config records it (left out when
    off: a render's truth stays as before the option)."""
    from impress_gui.cli import build_parser
    from impress_gui.commands import simulate as cmd
    from impress_gui.sim.simulate import _make_renderer

    seen = []
    monkeypatch.setattr(cmd, "_run", lambda args, cfg: seen.append(cfg) or 0)
    for extra in (["--random-rig", "13"], ["--preset", "flat"]):
        for flag in ([], ["--stripe-follows-soil"]):
            args = build_parser("simulate").parse_args(
                ["simulate", "out", "--resolution", "320x180", "--grid-mm", "0.5", *extra,
                 *flag])
            assert cmd.run(args) == 0
            cfg = seen[-1]
            cfg.validate()  # a random rig's config is checked against its seed
            assert cfg.stripe_follows_soil is bool(flag)
            assert cfg.to_json().get("stripe_follows_soil", False) is bool(flag)
            if cfg.random_rig is not None:
                assert _make_renderer(cfg)[0].opt.stripe_follows_soil is bool(flag)


# ----- (b) target corners -------------------------------------------------------------------------
def edge_points(gray, world, s, corner, other, centre):
    """Sub-pixel image points of the target edge ``corner -> other`` (object frame, mm) where
    it runs from 8 % to 60 % of its length from ``corner``: on profiles across the projected
    edge, the crossing of the level halfway between the paint (inside) and the soil (outside).
    Return the points found and their signed offsets from the projected edge (px, + outward)."""
    pose, z = target_pose(world.cfg), world.rig.standoff_mm
    a, b, c = (target_to_rail(np.asarray(v, float), pose, z) for v in (corner, other, centre))
    t = np.linspace(0.08, 0.6, 60)
    uv = to_pixels(world.rig, a + t[:, None] * (b - a) - [0.0, s, 0.0])
    tangent = np.gradient(uv, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.column_stack([tangent[:, 1], -tangent[:, 0]])
    inward = to_pixels(world.rig, c - [0.0, s, 0.0]) - uv
    normal *= -np.sign(np.sum(normal * inward, axis=1, keepdims=True))  # outward
    offs = np.arange(-5.0, 5.0001, 0.05)
    mx = (uv[:, 0, None] + offs * normal[:, 0, None]).astype(np.float32)
    my = (uv[:, 1, None] + offs * normal[:, 1, None]).astype(np.float32)
    prof = cv2.remap(gray, mx, my, cv2.INTER_LINEAR)
    paint = np.median(prof[:, (offs >= -4) & (offs <= -2)], axis=1)
    soil = np.median(prof[:, (offs >= 2) & (offs <= 4)], axis=1)
    below = prof < 0.5 * (paint + soil)[:, None]
    j = np.argmax(below & (offs > -2), axis=1)  # first sample past the half level
    f = (prof[np.arange(len(j)), j - 1] - 0.5 * (paint + soil)) / (
        prof[np.arange(len(j)), j - 1] - prof[np.arange(len(j)), j])
    d = offs[j - 1] + f * (offs[1] - offs[0])
    return uv + d[:, None] * normal, d


def _line(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = points.mean(axis=0)
    return c, np.linalg.svd(points - c)[2][0]


def _intersect(l1, l2) -> np.ndarray:
    (c1, d1), (c2, d2) = l1, l2
    t = np.linalg.solve(np.column_stack([d1, -d2]), c2 - c1)
    return c1 + t[0] * d1


def test_target_corners_render_where_they_project(world):
    """In a frame with the target in mid-view no end or side face is visible, so the outer
    corners of both top faces are corners of light paint against soil. Each corner is found
    from the image alone (sub-pixel points on its two edges, a line through each, their
    intersection) and compared with the projection of the target model's corner as placed."""
    k, s = frame_at(world, 35.0)
    corners = target_to_rail(world.target.corner_array(), target_pose(world.cfg),
                             world.rig.standoff_mm)
    expected = to_pixels(world.rig, corners - [0.0, s, 0.0])
    img = renderer(world, laser_peak=0.0, seed=2).render(k)[0]
    gray = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY).astype(np.float32)
    faces = {f.name: f.vertices_mm for f in world.target.top_faces()}
    for name in "ABDE":  # C and F join the riser: paint on paint
        corner = world.target.corners_mm[name]
        verts = next(v for v in faces.values() if np.any(np.all(np.isclose(v, corner), axis=1)))
        i = int(np.flatnonzero(np.all(np.isclose(verts, corner), axis=1))[0])
        lines, offsets = [], []
        for other in (verts[i - 1], verts[(i + 1) % len(verts)]):
            pts, d = edge_points(gray, world, s, corner, other, verts.mean(axis=0))
            lines.append(_line(pts))
            offsets.append(float(np.median(d)))
        found = _intersect(*lines)
        err = float(np.linalg.norm(found - expected[CORNER_NAMES.index(name)]))
        assert max(map(abs, offsets)) < EDGE_TOL_PX, f"{name}: edge offsets {offsets} px"
        assert err < CORNER_TOL_PX, f"corner {name} is {err:.3f} px from its projection"


# ----- (c) occlusion and shadows ------------------------------------------------------------------
def _edge_pixels(world, s: float, a: np.ndarray, b: np.ndarray, depth: float):
    """Pixels just inside/outside the image of the 3D edge a -> b (rail frame, at ``depth``):
    for image rows along the edge, the nearest pixel centres on each side at 0.45-1.5 px."""
    t = np.linspace(0.05, 0.95, 4000)
    edge_uv = to_pixels(world.rig, a + t[:, None] * (b - a) - [0.0, s, 0.0])
    rows = np.arange(int(np.ceil(edge_uv[:, 1].min())) + 1, int(edge_uv[:, 1].max()), 3)
    order = np.argsort(edge_uv[:, 1])
    u_edge = np.interp(rows, edge_uv[order, 1], edge_uv[order, 0])
    pix = []
    for v, ue in zip(rows, u_edge, strict=True):
        for u in range(int(np.floor(ue)) - 1, int(np.ceil(ue)) + 2):
            if 0.45 <= abs(u - ue) <= 1.5:
                pix.append((u, v))
    return np.array(pix, float)


def test_occluding_edge_hides_what_geometry_says(world):
    """Pixels whose rays pass just inside the high top's outer edge see the top (depth 260 mm
    and its light paint); just outside they pass above the edge and see the soil beyond."""
    k, s = frame_at(world, 35.0)
    polys = rail_polygons(world)
    high, depth = min(polys, key=lambda p: p[1])  # the shallowest top face
    corners = target_to_rail(world.target.corner_array(), target_pose(world.cfg),
                             world.rig.standoff_mm)
    d, e = corners[CORNER_NAMES.index("D")], corners[CORNER_NAMES.index("E")]
    pix = _edge_pixels(world, s, d, e, depth)
    rays = pixel_rays_ideal(world.rig, pix)
    on_top = inside(high, rays[:, :2] * depth + [0.0, s]) > 0
    assert 10 < on_top.sum() < len(pix) - 10
    ground = world.rig.standoff_mm
    for poly, _ in polys:  # passing above the edge, a ray meets the ground off the target
        assert np.all(inside(poly, rays[~on_top, :2] * ground + [0.0, s]) < 0)
    rend = renderer(world, noise_sigma_dn=0.0, laser_peak=0.0)
    _, _, z = rend.camera_surface(k)
    img = rend.render(k)[0].astype(int)
    u, v = pix[:, 0].astype(int), pix[:, 1].astype(int)
    want = np.where(on_top, depth, ground)
    bad = np.abs(z[v, u] - want) > DEPTH_TOL_MM
    assert not bad.any(), f"{bad.sum()} of {len(pix)} pixels see the wrong surface"
    rgb = img[v, u]
    paint = (rgb.mean(axis=1) > 130) & (np.ptp(rgb, axis=1) < 30)
    assert np.array_equal(paint, on_top)


def _stripe_presence(world, name: str, ch: int, s_target: float):
    """Per column: is the laser's ground stripe lit and in view (geometry), is it in the image?"""
    k, s = frame_at(world, s_target)
    laser = world.rig.laser(name)
    pts, uv = laser_ground_line(world.rig, laser, s, n=4000)
    keep = (uv[:, 0] > 2) & (uv[:, 0] < W - 3) & (uv[:, 1] > 8) & (uv[:, 1] < H - 9)
    pts, uv = pts[keep], uv[keep]
    src = laser.source_mm + [0.0, s, 0.0]
    cam = np.array([0.0, s, 0.0])
    lit = ~blocked(world, src, pts) & ~blocked(world, cam, pts)
    on = renderer(world, noise_sigma_dn=0.0, speckle_contrast=0.0).render(k)[0].astype(int)
    off = renderer(world, noise_sigma_dn=0.0, laser_peak=0.0).render(k)[0].astype(int)
    u = np.round(uv[:, 0]).astype(int)
    v = np.round(uv[:, 1]).astype(int)
    band = np.stack([on[v + dv, u, ch] - off[v + dv, u, ch] for dv in range(-3, 4)])
    seen = band.max(axis=0) > 25
    # compare away from the predicted transitions (2 px)
    change = np.flatnonzero(np.diff(lit.astype(int)))
    far = np.ones(len(u), bool)
    for c in change:
        far &= np.abs(uv[:, 0] - uv[c, 0]) > 2.0
    return lit, seen, far


def test_green_stripe_has_the_shadow_gap_geometry_predicts(world):
    """The green laser shines forward (+Y): behind the target's far end its ground stripe is in
    the target's shadow over the target's width."""
    lit, seen, far = _stripe_presence(world, "green", GREEN, 42.0)
    assert (~lit).sum() > 50, "the chosen frame should put the stripe in the shadow"
    assert np.array_equal(seen[far], lit[far])


def test_red_stripe_on_the_same_ground_has_no_gap(world):
    """The red laser shines backward (-Y): on the same strip of ground behind the target it is
    not shadowed, so its stripe is unbroken."""
    lit, seen, far = _stripe_presence(world, "red", RED, 118.0)
    assert lit.all()
    assert seen.all()


# ----- (d) determinism ----------------------------------------------------------------------------
def test_same_seed_same_bytes_other_seed_other_frame(world):
    k = frame_at(world, 60.0)[0]
    a = renderer(world, seed=11).render(k)[0]
    b = renderer(world, seed=11).render(k)[0]  # a fresh renderer: nothing cached
    c = renderer(world, seed=12).render(k)[0]
    assert a.dtype == np.uint8 and a.shape == (H, W, 3)
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != c.tobytes()
    assert np.abs(a.astype(int) - c.astype(int)).mean() > 0.5  # noise differs, not one pixel


def test_the_same_frames_encode_to_the_same_bytes(world, tmp_path):
    """Twenty rendered frames (320x180) encoded six times give one file. With x264's AVX-512
    code (on a processor that has it) the same frames gave 2-6 different files in 6-16 runs
    (sim.video_out.x264_params); on a processor without AVX-512 this holds either way."""
    import hashlib

    from impress_gui.sim.video_out import VideoSink

    r = renderer(world, seed=5)
    frames = [cv2.resize(r.render(k)[0], (320, 180), interpolation=cv2.INTER_AREA)
              for k in range(0, 100, 5)]
    digests = set()
    for i in range(6):
        sink = VideoSink(tmp_path / f"v{i}.mp4", 320, 180, 30.0)
        for f in frames:
            sink.write(f)
        sink.close()
        digests.add(hashlib.sha256((tmp_path / f"v{i}.mp4").read_bytes()).hexdigest())
    assert len(digests) == 1


# ----- (e) the command line end to end ------------------------------------------------------------
def _impress(*args: str, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "impress_gui", *args], capture_output=True,
                          text=True, cwd=cwd, timeout=240)


@pytest.mark.parametrize("fmt", ["frames", "mp4"])
def test_cli_writes_truth_that_loads_and_agrees(tmp_path, fmt):
    # a 0.5 mm scene grid (the default 0.1 mm is rendered by the tests above and by every
    # shared scan): nothing checked here depends on it, and the command takes half the time
    out = tmp_path / "scan"
    # the frame folder is rendered by two processes (the scene built once and handed to them);
    # its middle frame is compared below with one rendered here in this process
    workers = ["--workers", "2"] if fmt == "frames" else []
    res = _impress("simulate", str(out), "--preset", "flat", "--length-mm", "80",
                   "--resolution", "320x180", "--format", fmt, "--seed", "4", "--grid-mm", "0.5",
                   *workers)
    assert res.returncode == 0, res.stderr
    for name in ("intrinsics.json", "target.json", "picks.json", "truth.json",
                 "truth_height.tif", "truth_texture.png"):
        assert (out / name).is_file(), name
    truth = json.loads((out / "truth.json").read_text())
    assert truth["format"] == "impress.sim-truth" and truth["version"] == 1
    intr = Intrinsics.load(out / "intrinsics.json")
    target = TargetModel.load(out / "target.json")
    picks = Picks.load(out / "picks.json")
    assert intr.image_size == (320, 180) and target.name
    # the picks are the projections of the written 3D corners in the written frames
    rot = np.array(truth["rotation_camera_to_ideal"])
    corners = np.array([truth["target"]["corners_rail_mm"][c] for c in CORNER_NAMES])
    for key, k in (("t1", picks.t1), ("t2", picks.t2)):
        rel = corners - [0.0, truth["travel_mm"][k], 0.0]
        cam = rel @ rot  # ideal -> camera: x = R^T X
        xn, yn = cam[:, 0] / cam[:, 2], cam[:, 1] / cam[:, 2]
        u, v = intr.distort_normalized(xn, yn)
        assert np.allclose(picks.array(key), np.column_stack([u, v]), atol=1e-6)
        assert np.all((u > 0) & (u < 320) & (v > 0) & (v < 180))
    assert picks.t1 != picks.t2
    n = truth["frame_count"]
    assert len(truth["frame_times_s"]) == n == len(truth["travel_mm"])
    if fmt == "frames":
        files = sorted((out / "frames").glob("frame_*.png"))
        assert len(files) == n
        # a frame written by the command equals the same frame rendered here, byte for byte
        cfg = SimConfig(preset="flat", length_mm=80.0, width=320, height=180, seed=4,
                        video_format="frames", grid_mm=0.5)
        k = n // 2
        mine = next(render_frames(cfg, [k]))
        theirs = cv2.imread(str(files[k]), cv2.IMREAD_COLOR)[..., ::-1]
        assert mine.tobytes() == theirs.tobytes()
    else:
        from impress_gui.core.formats.video import open_video

        with open_video(out / "scan.mp4") as video:
            assert video.frame_count == n and video.size == (320, 180)
            assert abs(video.fps - 30.0) < 1e-6
        assert picks.video == "scan.mp4" and picks.video_sha256 == truth["video_sha256"]


# ----- (f) bad options ----------------------------------------------------------------------------
@pytest.mark.parametrize("args, option", [
    (["--resolution", "641x361"], "--resolution"),
    (["--resolution", "640by360"], "--resolution"),
    (["--speed", "-3"], "--speed"),
    (["--preset", "nope"], "--preset"),
    (["--length-mm", "5000"], "--length-mm"),
    (["--format", "avi"], "--format"),
    (["--standoff-mm", "50"], "--standoff-mm"),
    (["--seed", "-1"], "--seed"),
])
def test_bad_option_is_a_clear_error(tmp_path, capsys, args, option):
    from impress_gui.cli import main

    try:
        code = main(["simulate", str(tmp_path / "out"), *args])
    except SystemExit as exc:  # argparse rejects it while parsing
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2
    assert option in err, err
    assert "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_output_folder_is_replaced_whole_or_not_at_all(tmp_path):
    """A re-simulation that is interrupted leaves the previous simulation whole; a folder that
    holds something else is refused; a frame folder's truth carries its manifest hash."""
    from impress_gui.core.base.errors import Cancelled
    from impress_gui.core.base.fileio import sha256_path
    from impress_gui.core.base.progress import CancelToken
    from impress_gui.sim.simulate import SimConfig, simulate

    # a coarse scene (0.5 mm grid): what is checked is the folder, not the frames
    small = dict(preset="flat", length_mm=60.0, width=160, height=90, speed_mm_s=40.0,
                 grid_mm=0.5)
    out = tmp_path / "scan"
    simulate(SimConfig(video_format="frames", **small), out)
    truth = json.loads((out / "truth.json").read_text())
    assert truth["video_sha256"] == sha256_path(out / "frames") is not None
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    cancel = CancelToken()

    def stop_half_way(frac, _msg):
        if frac > 0.5:
            cancel.cancel()

    with pytest.raises(Cancelled):
        simulate(SimConfig(video_format="mp4", seed=9, **small), out, progress=stop_half_way,
                 cancel=cancel)
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before
    assert [p.name for p in tmp_path.iterdir()] == ["scan"]  # no partial folder left behind
    other = tmp_path / "notes"
    other.mkdir()
    (other / "case.txt").write_text("evidence notes")
    from impress_gui.core.base.outdir import OutputError

    with pytest.raises(OutputError, match="not made by a previous simulation") as err:
        simulate(SimConfig(**small), other)
    assert err.value.code == "E-OUTPUT-NOT-EMPTY"
    assert (other / "case.txt").read_text() == "evidence notes"
