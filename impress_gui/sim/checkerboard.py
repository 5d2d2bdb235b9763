"""Synthetic checkerboard views with known intrinsics, to test camera calibration.

A planar board is placed at varied poses in front of a camera whose intrinsics (including lens
distortion) are known; every pixel is the average of ``supersample x supersample`` rays through
its area (the sensor integrates over the pixel, so edges are anti-aliased), then lens blur,
shading and sensor noise are added. The views are written as a PNG folder or an H.264 video
together with the true intrinsics and poses.

Board convention (OpenCV's): ``inner_cols x inner_rows`` inner corners, so the board has
``(inner_cols + 1) x (inner_rows + 1)`` squares, inside a white margin.

Run ``python -m impress_gui.sim.checkerboard OUT`` to write a sample set.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from impress_gui.core.base.fileio import write_json
from impress_gui.core.calibration.geometry import Intrinsics

BOARD_TRUTH_FORMAT = "impress.checkerboard-truth"


@dataclass(frozen=True)
class Board:
    """A printed checkerboard; lengths in mm in the board's own frame (z = 0 on the board)."""

    inner_cols: int = 9
    inner_rows: int = 6
    square_mm: float = 25.0
    margin_squares: float = 1.0

    @property
    def size_mm(self) -> tuple[float, float]:
        return ((self.inner_cols + 1) * self.square_mm, (self.inner_rows + 1) * self.square_mm)

    def corners_mm(self) -> np.ndarray:
        """Inner corners ``(N, 3)``, row by row (OpenCV's object-point order)."""
        c, r = np.meshgrid(np.arange(1, self.inner_cols + 1), np.arange(1, self.inner_rows + 1))
        pts = np.column_stack([c.ravel(), r.ravel(), np.zeros(c.size)])
        return pts * self.square_mm

    def outline_mm(self) -> np.ndarray:
        """The four corners of the sheet (margin included), ``(4, 3)``."""
        m = self.margin_squares * self.square_mm
        w, h = self.size_mm
        return np.array([[-m, -m, 0], [w + m, -m, 0], [w + m, h + m, 0], [-m, h + m, 0]], float)


@dataclass(frozen=True)
class BoardPose:
    """Board frame -> camera frame: ``X_cam = rotation @ X_board + translation_mm``."""

    rotation: np.ndarray
    translation_mm: np.ndarray

    def to_camera(self, pts: np.ndarray) -> np.ndarray:
        return np.asarray(pts, float) @ self.rotation.T + self.translation_mm


def _rotation(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    r, _ = cv2.Rodrigues(np.asarray(axis, float).reshape(3, 1) * angle_rad)
    return r


def random_poses(intr: Intrinsics, board: Board, n: int, rng: np.random.Generator,
                 max_tilt_deg: float = 40.0, fill: tuple[float, float] = (0.35, 0.7),
                 border_px: float = 6.0) -> list[BoardPose]:
    """``n`` poses that keep the whole sheet inside the image: tilts up to ``max_tilt_deg``
    about random in-plane axes, in-plane turns up to 30 degrees, sizes filling ``fill`` of the
    image diagonal, spread over the whole image (corners included, where distortion shows)."""
    w, h = intr.image_size
    diag_norm = np.hypot(w / intr.fx, h / intr.fy)
    bw, bh = board.size_mm
    centre = np.array([bw / 2, bh / 2, 0.0])
    sheet = board.outline_mm()
    poses: list[BoardPose] = []
    tries = 0
    while len(poses) < n:
        tries += 1
        if tries > 200 * n:
            raise RuntimeError("cannot place the board inside the image; use a smaller board")
        az = rng.uniform(0, 2 * np.pi)
        tilt_axis = np.array([np.cos(az), np.sin(az), 0.0])
        tilt = np.radians(rng.uniform(5.0, max_tilt_deg))
        spin = np.radians(rng.uniform(-30.0, 30.0))
        rot = _rotation(tilt_axis, tilt) @ _rotation(np.array([0.0, 0.0, 1.0]), spin)
        depth = np.hypot(bw, bh) / (rng.uniform(*fill) * diag_norm)
        # aim the board centre at a random pixel
        u, v = rng.uniform(0.1 * w, 0.9 * w), rng.uniform(0.1 * h, 0.9 * h)
        ray = intr.rays(np.array([[u, v]]))[0]
        t = ray * depth - rot @ centre
        pose = BoardPose(rot, t)
        cam = pose.to_camera(sheet)
        if np.any(cam[:, 2] < 0.2 * depth):
            continue
        uv = intr.project(cam)
        if (uv[:, 0].min() < border_px or uv[:, 0].max() > w - 1 - border_px
                or uv[:, 1].min() < border_px or uv[:, 1].max() > h - 1 - border_px):
            continue
        poses.append(pose)
    return poses


class CheckerboardRenderer:
    """Renders a board seen through ``intr`` (sub-pixel rays from a per-pixel table of the
    undistorted ray directions, interpolated bilinearly inside each pixel)."""

    def __init__(self, intr: Intrinsics, board: Board, supersample: int = 4) -> None:
        self.intr, self.board, self.ss = intr, board, int(supersample)
        w, h = intr.image_size
        # undistorted normalized coordinates of every pixel centre, with a one-pixel rim so
        # that sub-pixel positions interpolate inside the table
        uu, vv = np.meshgrid(np.arange(-1, w + 1, dtype=float), np.arange(-1, h + 1, dtype=float))
        n = intr.undistort_points(np.column_stack([uu.ravel(), vv.ravel()]))
        self._xn = n[:, 0].reshape(h + 2, w + 2)
        self._yn = n[:, 1].reshape(h + 2, w + 2)

    def _subpixel(self, table: np.ndarray, dx: float, dy: float) -> np.ndarray:
        """``table`` (with rim) bilinearly interpolated at every pixel centre + (dx, dy)."""
        h, w = table.shape[0] - 2, table.shape[1] - 2
        i0, j0 = int(np.floor(dy)), int(np.floor(dx))
        fy, fx = dy - i0, dx - j0
        a = table[1 + i0 : 1 + i0 + h, 1 + j0 : 1 + j0 + w]
        b = table[1 + i0 : 1 + i0 + h, 2 + j0 : 2 + j0 + w]
        c = table[2 + i0 : 2 + i0 + h, 1 + j0 : 1 + j0 + w]
        d = table[2 + i0 : 2 + i0 + h, 2 + j0 : 2 + j0 + w]
        return (1 - fy) * ((1 - fx) * a + fx * b) + fy * ((1 - fx) * c + fx * d)

    def coverage(self, pose: BoardPose) -> tuple[np.ndarray, np.ndarray]:
        """Per pixel: the fraction of its area showing white squares or margin, and the
        fraction showing the sheet at all (the rest is the table). Both ``(H, W)`` float."""
        b = self.board
        # board (x, y) of a normalized ray (xn, yn, 1): the inverse of H = [r1 r2 t]
        hom = np.column_stack([pose.rotation[:, 0], pose.rotation[:, 1], pose.translation_mm])
        hinv = np.linalg.inv(hom)
        m = b.margin_squares * b.square_mm
        bw, bh = b.size_mm
        w, h = self.intr.image_size
        white = np.zeros((h, w))
        sheet = np.zeros((h, w))
        offs = (np.arange(self.ss) + 0.5) / self.ss - 0.5
        for dy in offs:
            for dx in offs:
                xn, yn = self._subpixel(self._xn, dx, dy), self._subpixel(self._yn, dx, dy)
                q = hinv[:, 0, None, None] * xn + hinv[:, 1, None, None] * yn + hinv[:, 2, None, None]
                front = q[2] > 0
                x, y = q[0] / q[2], q[1] / q[2]
                on = front & (x >= -m) & (x <= bw + m) & (y >= -m) & (y <= bh + m)
                inner = (x >= 0) & (x <= bw) & (y >= 0) & (y <= bh)
                dark = inner & ((np.floor(x / b.square_mm) + np.floor(y / b.square_mm)) % 2 == 0)
                white += on & ~dark
                sheet += on
        k = float(self.ss * self.ss)
        return white / k, sheet / k

    def render(self, pose: BoardPose, rng: np.random.Generator, noise_dn: float = 2.0,
               blur_px: float = 0.6) -> np.ndarray:
        """One view as RGB uint8 ``(H, W, 3)``: matte paper on a table, uneven light."""
        w, h = self.intr.image_size
        white, sheet = self.coverage(pose)
        table = _smooth_noise(rng, (h, w), 40.0)
        yy, xx = np.mgrid[0:h, 0:w]
        r2 = ((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / (w * w / 4 + h * h / 4)
        light = (1.0 - 0.25 * r2) * (1.0 + 0.08 * _smooth_noise(rng, (h, w), 150.0))
        paper_black, paper_white = 18.0, 215.0
        grey = light * (paper_black * (sheet - white) + paper_white * white
                        + (90.0 + 20.0 * table) * (1.0 - sheet))
        if blur_px > 0:
            grey = cv2.GaussianBlur(grey.astype(np.float32), (0, 0), blur_px)
        tint = np.array([1.0, 0.98, 0.93], np.float32)  # warm indoor light
        rgb = grey[..., None] * tint + rng.normal(0.0, noise_dn, (h, w, 3))
        return np.clip(rgb + 0.5, 0, 255).astype(np.uint8)


def _smooth_noise(rng: np.random.Generator, shape: tuple[int, int], cell_px: float) -> np.ndarray:
    """Smooth noise in about [-1, 1] with features of ``cell_px``."""
    h, w = shape
    gh, gw = max(2, int(h / cell_px) + 2), max(2, int(w / cell_px) + 2)
    grid = rng.uniform(-1, 1, (gh, gw)).astype(np.float32)
    return cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)


def write_views(out_dir: Path, intr: Intrinsics, board: Board = Board(), n_views: int = 20,
                seed: int = 0, video_format: str = "frames", hold_frames: int = 1,
                supersample: int = 4, noise_dn: float = 2.0) -> Path:
    """Render ``n_views`` views into ``out_dir`` (``frames/`` of PNGs, or ``board.<format>``
    with each view held for ``hold_frames`` frames) and write ``intrinsics_truth.json`` (the
    intrinsics file format) and ``board_truth.json`` (board, poses and the frames of each view).
    Return the path of the views."""
    from impress_gui.sim.video_out import FrameFolderSink, VideoSink

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    poses = random_poses(intr, board, n_views, rng)
    rend = CheckerboardRenderer(intr, board, supersample)
    w, h = intr.image_size
    sink: FrameFolderSink | VideoSink
    if video_format == "frames":
        path = out_dir / "frames"
        sink = FrameFolderSink(path)
    else:
        path = out_dir / f"board.{video_format}"
        sink = VideoSink(path, w, h, 30.0)
    frames = []
    try:
        for i, pose in enumerate(poses):
            frames.append(list(range(i * hold_frames, (i + 1) * hold_frames)))
            for _ in range(hold_frames):
                sink.write(rend.render(pose, np.random.default_rng([seed, i, len(frames[-1])]),
                                       noise_dn))
        sink.close()
    except BaseException:
        sink.abort()
        raise
    intr.save(out_dir / "intrinsics_truth.json")
    write_json(out_dir / "board_truth.json", {
        "format": BOARD_TRUTH_FORMAT,
        "version": 1,
        "board": {"inner_cols": board.inner_cols, "inner_rows": board.inner_rows,
                  "square_mm": board.square_mm, "margin_squares": board.margin_squares},
        "views": [{"frames": f, "rotation": p.rotation.tolist(),
                   "translation_mm": p.translation_mm.tolist()}
                  for f, p in zip(frames, poses, strict=True)],
        "convention": "X_camera = rotation @ X_board + translation_mm (OpenCV camera frame, mm)",
    })
    return path


def main(argv: list[str] | None = None) -> int:
    from impress_gui.sim.rig import default_intrinsics

    p = argparse.ArgumentParser(prog="python -m impress_gui.sim.checkerboard",
                                description="Render checkerboard views with known intrinsics "
                                "(the simulator's camera) for testing impress calibrate-camera.")
    p.add_argument("out", type=Path, help="output folder")
    p.add_argument("--views", type=int, default=20, help="number of board poses (default 20)")
    p.add_argument("--resolution", default="1920x1080", help="WIDTHxHEIGHT (default 1920x1080)")
    p.add_argument("--board", default="9x6", help="inner corners COLSxROWS (default 9x6)")
    p.add_argument("--square-mm", type=float, default=25.0, help="square size (default 25)")
    p.add_argument("--format", dest="fmt", default="frames", choices=["frames", "mp4", "mov"],
                   help="PNG folder (default) or H.264 video")
    p.add_argument("--hold-frames", type=int, default=1, help="video frames per view")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    try:
        w, h = (int(v) for v in args.resolution.lower().split("x"))
        cols, rows = (int(v) for v in args.board.lower().split("x"))
    except ValueError:
        p.error("--resolution and --board take WIDTHxHEIGHT / COLSxROWS")
    intr = default_intrinsics(w, h)
    path = write_views(args.out, intr, Board(cols, rows, args.square_mm), args.views, args.seed,
                       args.fmt, args.hold_frames)
    truth = json.loads((args.out / "intrinsics_truth.json").read_text())
    print(f"wrote {args.views} views to {path}; true intrinsics in "
          f"{args.out / 'intrinsics_truth.json'} (fx = {truth['camera_matrix'][0][0]:.2f} px)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
