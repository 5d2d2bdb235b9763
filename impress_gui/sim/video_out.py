"""Writers for rendered scans: H.264 (MP4 or an AVCHD-like MPEG-TS .mts) through PyAV, or PNG frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np

CONTAINERS = {"mp4": "mp4", "mov": "mov", "mts": "mpegts"}


#: x264's instruction sets on a processor with AVX-512, that one left out (x264's own names)
X264_WITHOUT_AVX512 = "SSE2,SSSE3,SSE4.2,AVX,AVX2,FMA3,BMI2,LZCNT"
#: OpenCV's number for AVX-512F in ``cv2.checkHardwareSupport`` (``CPU_AVX_512F`` in its
#: cvdef.h; the headless wheel does not name the constants)
_CV_CPU_AVX_512F = 13


def x264_params() -> str:
    """The encoder's parameters: two frame threads and, on a processor with AVX-512, x264's
    AVX-512 code left out. With it the same frames encoded twice in one process gave different
    bytes (and different decoded frames) one time in two to three - 6 outputs of 16 runs on a
    320x180 render, single-threaded too - so ``impress simulate`` did not make the same video
    twice; the AVX2 code gave one output in 16 runs with two threads and in 24 with one. Every
    processor with AVX-512 has the sets listed (naming one it lacks would crash x264), and
    elsewhere x264 chooses as always."""
    import cv2

    params = "threads=2:sliced-threads=0"
    if cv2.checkHardwareSupport(_CV_CPU_AVX_512F):
        params += f":asm={X264_WITHOUT_AVX512}"
    return params


class VideoSink:
    """Encodes RGB frames with libx264, 4:2:0, at a camcorder-like bitrate.

    ``bitrate_mbit`` defaults to 22 Mbit/s scaled by the frame area relative to 1920x1080.
    Writes to a temporary name and renames on :meth:`close` so an interrupted run leaves no
    video that looks complete.
    """

    def __init__(self, path: Path, width: int, height: int, fps: float,
                 bitrate_mbit: float | None = None) -> None:
        import av

        self.path = Path(path)
        self.tmp = self.path.with_name(f".{self.path.name}.partial")
        ext = self.path.suffix.lower().lstrip(".")
        if ext not in CONTAINERS:
            raise ValueError(f"unsupported video container .{ext}")
        if bitrate_mbit is None:
            bitrate_mbit = 22.0 * (width * height) / (1920 * 1080)
        self._container = av.open(str(self.tmp), "w", format=CONTAINERS[ext])
        from fractions import Fraction

        stream = self._container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
        stream.width, stream.height = width, height
        stream.pix_fmt = "yuv420p"
        stream.bit_rate = int(bitrate_mbit * 1e6)
        stream.gop_size = 15
        stream.options = {"preset": "veryfast", "x264-params": x264_params()}
        self._stream = stream
        self._av = av

    def write(self, rgb: np.ndarray) -> None:
        frame = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
        for packet in self._stream.encode(frame):
            self._container.mux(packet)

    def close(self) -> None:
        for packet in self._stream.encode():
            self._container.mux(packet)
        self._container.close()
        self.tmp.replace(self.path)

    def abort(self) -> None:
        try:
            self._container.close()
        except Exception:  # noqa: BLE001 - best effort on the error path
            pass
        self.tmp.unlink(missing_ok=True)


class FrameFolderSink:
    """Writes ``frame_000000.png`` ... into a folder (lossless)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.tmp = self.path.with_name(f".{self.path.name}.partial")
        self.tmp.mkdir(parents=True, exist_ok=True)
        self.count = 0

    def write(self, rgb: np.ndarray) -> None:
        from impress_gui.core.formats.images import png_bytes

        (self.tmp / f"frame_{self.count:06d}.png").write_bytes(png_bytes(rgb))
        self.count += 1

    def close(self) -> None:
        if self.path.exists():
            import shutil

            shutil.rmtree(self.path)
        self.tmp.replace(self.path)

    def abort(self) -> None:
        import shutil

        shutil.rmtree(self.tmp, ignore_errors=True)
