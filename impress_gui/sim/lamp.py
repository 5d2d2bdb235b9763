"""A video of a plain surface under a flickering mains lamp, as a camera with the simulated
rig's rolling shutter films it: the input of ``impress calibrate-camera
--readout-from-flicker`` (:mod:`impress_gui.core.calibration.readout`), with the readout known.

Each image row is exposed for ``exposure_s`` starting one line time after the row above; the
lamp's light over a flicker period is ``1 + depth cos`` (``wave="sine"``: a fluorescent tube)
or a pulse train (``"pwm"``: an LED driver, full light for a fifth of the period, a tenth of it
otherwise), integrated over each row's exposure; the surface is a slightly textured light card,
shaded by the lens' vignetting, with sensor noise and 8-bit rounding.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np


def lamp_frames(w: int, h: int, readout_ms: float, flicker_hz: float = 100.0, n: int = 20,
                fps: float = 30.0, exposure_s: float = 1 / 2000, depth: float = 0.3,
                seed: int = 0, wave: str = "sine", vignetting: float = 0.0) -> list[np.ndarray]:
    """RGB frames (``uint8``) of the lamp-lit card through a rolling shutter of
    ``readout_ms`` (0: a global shutter); ``vignetting``: the picture darker towards its top
    and bottom by this share."""
    if wave not in ("sine", "pwm"):
        raise ValueError(f"wave {wave!r}")
    rng = np.random.default_rng(seed)
    line_s = readout_ms / 1000.0 / (h - 1)
    albedo = 0.9 + 0.1 * rng.random((h, w))
    shade = np.linspace(0.75, 1.05, h)[:, None] * np.linspace(0.9, 1.1, w)[None]
    om = 2 * math.pi * flicker_hz
    vig = 1 - vignetting * np.linspace(-1, 1, h) ** 2
    out = []
    for k in range(n):
        t0 = k / fps + np.arange(h) * line_s  # each row's exposure start
        if wave == "sine":
            # the mean of 1 + depth cos(om t) over [t0, t0 + exposure]
            light = 1 + depth * (np.sin(om * (t0 + exposure_s)) - np.sin(om * t0)) / (
                om * exposure_s)
        else:  # the mean of the pulse train over the exposure, by sub-steps
            ts = t0[:, None] + np.linspace(0, exposure_s, 16)[None]
            light = np.where((flicker_hz * ts) % 1.0 < 0.2, 1.0, 0.1).mean(axis=1)
        img = 170 * (light * vig)[:, None] * albedo * shade + rng.normal(0, 2.0, (h, w))
        grey = np.clip(np.rint(img), 0, 255).astype(np.uint8)
        out.append(np.dstack([grey, grey, (grey * 0.95).astype(np.uint8)]))
    return out


def write_lamp_video(path: Path, width: int, height: int, fps: float, readout_ms: float,
                     flicker_hz: float = 100.0, n: int = 30, seed: int = 0) -> Path:
    """Write :func:`lamp_frames` as H.264 (``path``: .mp4, .mov or .mts; atomic)."""
    from impress_gui.sim.video_out import VideoSink

    sink = VideoSink(Path(path), width, height, fps)
    try:
        for f in lamp_frames(width, height, readout_ms, flicker_hz, n, fps, seed=seed,
                             vignetting=0.2):
            sink.write(f)
        sink.close()
    except BaseException:
        sink.abort()
        raise
    return Path(path)
