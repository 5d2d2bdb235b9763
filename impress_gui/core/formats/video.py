"""Video input: H.264 in MP4/MOV and camcorder AVCHD (.MTS/.M2TS) through PyAV, or a folder of
frames. Frame counts and times come from the demuxed packets (every packet of the video stream
is indexed when the file is opened), never from container metadata alone.

Files are opened read-only; nothing here ever writes to an evidence file.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterator
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from impress_gui.core.base import codes
from impress_gui.core.base.errors import VideoError
from impress_gui.core.base.fileio import FRAME_SUFFIXES, open_regular


def _open_regular(path: Path, what: str, max_bytes: int) -> int:
    """A read-only descriptor of the regular file ``path`` (VideoError codes otherwise)."""
    from impress_gui.core.base.errors import FormatError

    try:
        return open_regular(path, what, max_bytes)
    except FormatError as exc:
        code = codes.E_VIDEO_EMPTY if exc.code == codes.E_FILE_EMPTY else exc.code
        raise VideoError(str(exc), code=code) from None

VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".mts", ".m2ts", ".ts", ".avi", ".mkv")
IMAGE_SUFFIXES = FRAME_SUFFIXES
#: packets demuxed after a seek while looking for a keyframe's own packet (a seek can land on
#: an earlier keyframe in some containers)
KEY_SEEK_PACKETS = 300


@dataclass
class Planes:
    """A frame as BT.601 limited-range YCbCr planes, the way H.264 stores it: luma ``y`` at
    full resolution, chroma ``cb``/``cr`` at ``chroma_step`` (2 for 4:2:0 video, 1 for frames
    converted from RGB). What :meth:`VideoSource.iter_planes` yields."""

    y: np.ndarray  # (H, W) uint8
    cb: np.ndarray
    cr: np.ndarray
    chroma_step: int = 2

    #: image rows converted together by :meth:`from_rgb` (every step is per pixel: the same
    #: bytes as in one go, without a dozen float frames at once - 0.1 GB at 1080p)
    ROWS_BLOCK = 128

    @classmethod
    def from_rgb(cls, rgb: np.ndarray) -> Planes:
        rgb = np.asarray(rgb)
        q = [np.empty(rgb.shape[:2], np.uint8) for _ in range(3)]
        for a in range(0, rgb.shape[0], cls.ROWS_BLOCK):
            f = rgb[a : a + cls.ROWS_BLOCK].astype(np.float32)
            r, g, b = f[..., 0], f[..., 1], f[..., 2]
            y = 16 + (65.481 * r + 128.553 * g + 24.966 * b) / 255
            cb = 128 + (-37.797 * r - 74.203 * g + 112.0 * b) / 255
            cr = 128 + (112.0 * r - 93.786 * g - 18.214 * b) / 255
            for out, v in zip(q, (y, cb, cr)):
                out[a : a + cls.ROWS_BLOCK] = np.clip(np.rint(v), 0, 255)
        return cls(q[0], q[1], q[2], 1)

    @classmethod
    def from_av(cls, frame) -> Planes:
        """Zero-copy views of a decoded PyAV frame's planes (converted to yuv420p first if it
        is in another format); the views keep the frame's buffers alive."""
        if frame.format.name not in ("yuv420p", "yuvj420p"):
            frame = frame.reformat(format="yuv420p")
        w, h = frame.width, frame.height
        views = []
        for i, (pw, ph) in enumerate(((w, h), ((w + 1) // 2, (h + 1) // 2),
                                      ((w + 1) // 2, (h + 1) // 2))):
            pl = frame.planes[i]
            arr = np.frombuffer(pl, np.uint8).reshape(-1, pl.line_size)
            views.append(arr[:ph, :pw])
        return cls(views[0], views[1], views[2], 2)

    def rgb(self, rows: np.ndarray, cols: np.ndarray, dtype=np.float32) -> np.ndarray:
        """RGB (``dtype``, 0..255) of the pixels at ``rows``/``cols`` (broadcast arrays);
        float64 computes as the compiled kernels' ``_rgb`` does."""
        s = self.chroma_step
        y = (self.y[rows, cols].astype(dtype) - 16) * 1.164
        cb = self.cb[rows // s, cols // s].astype(dtype) - 128
        cr = self.cr[rows // s, cols // s].astype(dtype) - 128
        rgb = np.stack([y + 1.596 * cr, y - 0.392 * cb - 0.813 * cr, y + 2.017 * cb], axis=-1)
        return np.clip(rgb, 0, 255)


class VideoSource:
    """Common interface. ``size`` is the displayed ``(width, height)`` (1088-line codings are
    cropped to 1080); frames are RGB ``uint8`` arrays ``(H, W, 3)``."""

    path: Path
    size: tuple[int, int]
    fps: float
    times_s: np.ndarray

    @property
    def frame_count(self) -> int:
        return len(self.times_s)

    def read(self, k: int) -> np.ndarray:
        raise NotImplementedError

    def iter_frames(self, start: int = 0, stop: int | None = None) -> Iterator[tuple[int, np.ndarray]]:
        """Yield ``(index, RGB frame)`` for ``start <= index < stop``, in order."""
        raise NotImplementedError

    def iter_planes(self, start: int = 0, stop: int | None = None,
                    keep_rgb: dict[int, np.ndarray | None] | None = None
                    ) -> Iterator[tuple[int, Planes]]:
        """Yield ``(index, frame as YCbCr planes)`` for ``start <= index < stop``, in order:
        what the reconstruction reads (a frame folder's RGB frames converted). ``keep_rgb``:
        the frames whose keys it holds are also stored there as :meth:`read` returns them (the
        same bytes, without seeking again)."""
        for k, rgb in self.iter_frames(start, stop):
            if keep_rgb is not None and k in keep_rgb:
                keep_rgb[k] = rgb
            yield k, Planes.from_rgb(rgb)

    def quick_frames(self, start: int, stop: int, n: int) -> list[int]:
        """About ``n`` frame indices spread over ``start..stop-1`` that are cheap to read
        (in a compressed video: keyframes, which decode without their predecessors)."""
        return sorted({int(k) for k in np.linspace(start, stop - 1, max(1, min(n, stop - start)))})

    def read_many(self, ks, threads: int = 1) -> list[np.ndarray]:
        """Frames ``ks`` (in that order); a video decodes its keyframes on ``threads``
        threads."""
        return [self.read(k) for k in ks]

    def clone(self, threads: int | None = None) -> VideoSource:
        """Another reader of the same source, for use beside this one in another thread
        (frame folders read each frame on its own, so a shallow copy will do)."""
        import copy

        return copy.copy(self)

    #: problems found when the source was opened (timestamp gaps, a cut-off file): plain text
    open_warnings: list[str]
    #: frame index -> what is wrong with it, filled in while frames are decoded (shared by clones)
    damage: dict[int, str]

    #: the recording date the container states (ISO 8601), if any
    recorded_utc: str | None = None

    def frame_damage(self, k: int) -> str | None:
        """What is known to be wrong with frame ``k`` once it has been decoded (None: nothing)."""
        return self.damage.get(int(k))

    def damage_warnings(self, limit: int = 12) -> list[str]:
        """The source's problems as warnings: those found on opening, then the damaged frames
        (runs of consecutive frames in one line)."""
        out = list(self.open_warnings)
        ks = sorted(self.damage)
        runs: list[tuple[int, int, str]] = []
        for k in ks:
            why = self.damage[k]
            if runs and runs[-1][1] == k - 1 and runs[-1][2] == why:
                runs[-1] = (runs[-1][0], k, why)
            else:
                runs.append((k, k, why))
        for a, b, why in runs[:limit]:
            frames = f"frame {a}" if a == b else f"frames {a}-{b}"
            out.append(f"W-VIDEO-DAMAGED: {frames} of {self.path.name}: {why}")
        if len(runs) > limit:
            out.append(f"W-VIDEO-DAMAGED: {len(runs) - limit} more damaged stretches "
                       f"({len(ks)} damaged frames in all)")
        return out

    def sha256(self) -> str:
        """SHA-256 of exactly what this source decodes (a file: the bytes of the open file;
        a frame folder: the hash of its manifest)."""
        raise NotImplementedError

    def check_unchanged(self) -> None:
        """Raise IntegrityError ``E-EVIDENCE-CHANGED`` if the source was written to since it
        was opened (its bytes may then differ from those hashed)."""

    def check_index(self, k: int) -> int:
        if not isinstance(k, (int, np.integer)) or not 0 <= k < self.frame_count:
            raise VideoError(f"frame {k} is outside the video (0..{self.frame_count - 1})",
                             code=codes.E_FRAME_RANGE)
        return int(k)

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


#: a scan video larger than this is refused before opening (a 1.77 m scan at 1080p is ~1 GB)
MAX_VIDEO_BYTES = 64 << 30
#: a gap between frame stamps longer than this many frame intervals is reported
GAP_FRAMES = 1.5


def _pinned_name(fd: int, path: Path) -> str:
    """A name that opens the very file behind ``fd`` even if ``path`` is replaced meanwhile
    (Linux: /proc/self/fd/N); elsewhere the path itself."""
    proc = f"/proc/self/fd/{fd}"
    return proc if os.path.exists(proc) else str(path)


def _stat_key(st: os.stat_result) -> tuple:
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)


class AVVideo(VideoSource):
    def __init__(self, path: Path, threads: int = 2) -> None:
        import av

        # (FFmpeg's own messages stay off: PyAV's default. Never install PyAV's Python log
        # callback here: a decoding thread logging while the GIL's holder frees its codec
        # waits for the GIL forever - a deadlock seen in the hostile-input tests)
        self.path = Path(path)
        self._threads = threads
        self.open_warnings = []
        self.damage = {}
        # the file is opened once; every decoder reads this open file (never the path again),
        # so the bytes hashed by sha256() are the bytes decoded
        self._fd = _open_regular(self.path, "video", MAX_VIDEO_BYTES)
        self._owner = True
        self._stat = _stat_key(os.fstat(self._fd))
        self._name = _pinned_name(self._fd, self.path)
        try:
            self._container = av.open(self._name, "r")
        except (av.error.FFmpegError, OSError, ValueError):
            self._close_fd()
            raise VideoError(f"{self.path}: not a readable video (the container is damaged, cut "
                             "short or of an unknown kind)", code=codes.E_VIDEO_OPEN) from None
        try:
            self._index()
        except BaseException:
            self.close()
            raise

    def _close_fd(self) -> None:
        if getattr(self, "_owner", False) and self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def sha256(self) -> str:
        from impress_gui.core.base.fileio import sha256_file

        return sha256_file(self._fd, 4 << 20)

    def check_unchanged(self) -> None:
        now = _stat_key(os.fstat(self._fd))
        moved = False
        try:
            moved = _stat_key(os.stat(self.path))[:2] != self._stat[:2]
        except OSError:
            moved = True
        if now != self._stat:
            from impress_gui.core.base.errors import IntegrityError

            raise IntegrityError(f"{self.path} was written to while it was being read: the "
                                 "result is not kept", code=codes.E_EVIDENCE_CHANGED)
        if moved:
            self.open_warnings.append(
                f"W-VIDEO-REPLACED: {self.path} was replaced or removed while it was read; "
                "the file that was opened and hashed was processed")

    def _index(self) -> None:
        import av

        tag = str((self._container.metadata or {}).get("creation_time") or "")
        self.recorded_utc = tag if len(tag) >= 10 and tag[:4].isdigit() else None
        streams = self._container.streams.video
        if not streams:
            raise VideoError(f"{self.path}: the file has no video stream", code=codes.E_VIDEO_OPEN)
        st = streams[0]
        if st.codec_context is None:
            raise VideoError(f"{self.path}: the video stream cannot be decoded",
                             code=codes.E_VIDEO_OPEN)
        st.codec_context.thread_type = "AUTO"
        st.codec_context.thread_count = self._threads
        self._stream = st
        self._tb = float(st.time_base) if st.time_base else 1.0 / 90000
        cc = st.codec_context
        w, h = cc.width, cc.height
        if not w or not h:
            raise VideoError(f"{self.path}: the video stream has no frame size", code=codes.E_VIDEO_OPEN)
        self._coded_h = h
        self.size = (w, 1080 if h == 1088 else h)
        pts, keys = [], []
        try:
            for pkt in self._container.demux(st):
                if pkt.pts is None or pkt.size == 0:
                    continue
                pts.append(pkt.pts)
                if pkt.is_keyframe:
                    keys.append(pkt.pts)
        except av.error.FFmpegError:
            raise VideoError(f"{self.path}: the file is damaged after {len(pts)} frames",
                             code=codes.E_VIDEO_TRUNCATED) from None
        if not pts:
            raise VideoError(f"{self.path}: the video has no frames", code=codes.E_VIDEO_EMPTY)
        if len(set(pts)) != len(pts):
            self.open_warnings.append(f"W-VIDEO-STAMPS: {self.path.name}: "
                                      f"{len(pts) - len(set(pts))} frames share a time stamp "
                                      "with another frame (only one of each is used)")
            pts = sorted(set(pts))
            keys = sorted(set(keys))
        self._pts = np.array(sorted(pts), dtype=np.int64)
        self._keys = np.array(sorted(keys), dtype=np.int64)
        t = (self._pts - self._pts[0]) * self._tb
        self.times_s = t
        rate = st.average_rate or st.guessed_rate
        if len(t) > 1:
            self.fps = float((len(t) - 1) / (t[-1] - t[0])) if t[-1] > t[0] else float(rate or 30)
        else:
            self.fps = float(rate or 30.0)
        if rate:
            # prefer the nominal rate when the stamps agree with it (it is exact, e.g. 30000/1001)
            if abs(float(rate) - self.fps) / float(rate) < 0.002:
                self.fps = float(rate)
        self._decoder: Iterator | None = None
        self._taint: int | None = None
        self._check_completeness(st)

    def _check_completeness(self, st) -> None:
        """Warnings for a stream that is shorter than its container says, a file cut off in
        the middle of a transport packet, and gaps in the frame stamps."""
        declared = int(st.frames or 0)
        n = len(self._pts)
        if declared > n:
            self.open_warnings.append(
                f"W-VIDEO-TRUNCATED: {self.path.name}: the container declares {declared} frames "
                f"but only {n} are in the file (cut short?)")
        if self.path.suffix.lower() in (".mts", ".m2ts", ".ts"):
            size = os.fstat(self._fd).st_size
            if size % 188 and size % 192:
                self.open_warnings.append(
                    f"W-VIDEO-TRUNCATED: {self.path.name}: the file ends in the middle of a "
                    "transport packet (cut short?); its last frames may be incomplete")
        tail_gap = False
        if n > 2:
            dt = np.diff(self._pts.astype(np.float64))
            step = float(np.median(dt))
            if step > 0:
                gaps = np.nonzero(dt > GAP_FRAMES * step)[0]
                # a gap among the last frames: pictures decoded before them were lost with
                # the end of the file (frames are stored out of display order)
                tail_gap = bool(gaps.size and gaps[-1] >= n - 4)
                for i in gaps[:10]:
                    missing = int(round(dt[i] / step)) - 1
                    self.open_warnings.append(
                        f"W-VIDEO-GAP: {self.path.name}: about {max(1, missing)} frame(s) "
                        f"missing between frames {i} and {i + 1} "
                        f"({dt[i] * self._tb * 1000:.0f} ms instead of "
                        f"{step * self._tb * 1000:.0f} ms)")

        tail = self._tail_damage()
        if tail_gap or tail:
            self.open_warnings.insert(0,
                f"W-VIDEO-TRUNCATED: {self.path.name}: the video's last frames are incomplete "
                f"({tail or 'frames are missing just before the end'}): the file was probably "
                "cut short")

    def _tail_damage(self) -> str | None:
        """Decode the last group of pictures (from the last keyframe) once: a file cut short
        ends in a damaged or missing picture. Returns what is wrong, or None."""
        if self._keys.size == 0:
            return None
        k = int(np.searchsorted(self._pts, self._keys[-1]))
        try:
            for _ in self._frames_from(k):
                pass
        except VideoError:
            return "the last frames cannot be decoded"
        finally:
            self._decoder = None
        bad = [i for i in range(k, len(self._pts)) if i in self.damage]
        return f"frame {bad[0]} is damaged" if bad else None

    def _note_damage(self, idx: int, frame) -> None:
        """Record frame ``idx`` as damaged when the decoder flags it, and the frames after it
        up to the next keyframe as depending on it."""
        if frame.is_corrupt:
            self.damage[idx] = "the decoder found damaged data in it"
            self._taint = idx
        elif frame.key_frame:
            self._taint = None
        elif self._taint is not None and idx > self._taint:
            self.damage.setdefault(idx, f"decoded from damaged frame {self._taint}")

    def clone(self, threads: int | None = None) -> AVVideo:
        """Another reader of the same file with its own decoder (``threads`` decoding threads),
        sharing this one's frame index: the file is not indexed again."""
        import copy

        import av

        other = copy.copy(self)
        other._owner = False  # the original keeps (and closes) the open file
        other._threads = threads or self._threads
        # this reader knows the stream already: the clone's probe decodes no picture (opening
        # otherwise decodes the first one, ~60 ms at 1080p); the decoder is opened anew, with
        # the same frames (tested)
        try:
            other._container, other._stream = other._open_for_decoding(probe_pictures=False)
        except (av.error.FFmpegError, OSError, ValueError):
            raise VideoError(f"{self.path}: the video cannot be opened again for decoding",
                             code=codes.E_VIDEO_OPEN) from None
        other._decoder = None
        return other

    def _open_for_decoding(self, probe_pictures: bool = True):
        """The file opened again for decoding on this reader's threads: (container, video
        stream). Without ``probe_pictures`` the stream probe decodes no picture (for a reader
        that knows the stream; a format whose streams appear only while probing, such as
        MPEG-PS, is probed in full all the same)."""
        import av

        container = None
        if not probe_pictures:
            # (PyAV's type stubs say list[str]; the library takes one dict per stream)
            quick: Any = [{"skip_frame": "all"}] * len(self._container.streams)
            try:
                container = av.open(self._name, "r", stream_options=quick)
            except ValueError:
                container = None
        if container is None:
            container = av.open(self._name, "r")
        st = container.streams.video[0]
        st.codec_context.thread_type = "AUTO"
        st.codec_context.thread_count = self._threads
        return container, st

    def quick_frames(self, start: int, stop: int, n: int) -> list[int]:
        keys = np.searchsorted(self._pts, self._keys)
        keys = keys[(keys >= start) & (keys < stop)]
        if len(keys) < max(2, n // 2):  # too few keyframes in the range: any frames
            return super().quick_frames(start, stop, n)
        pick = np.unique(np.rint(np.linspace(0, len(keys) - 1, min(n, len(keys)))).astype(int))
        return [int(k) for k in keys[pick]]

    def _open_decoder(self, k: int, attempt: int = 0):
        """Position the decoder before frame ``k``: at the keyframe before it, or ``attempt``
        keyframes earlier (some containers, e.g. MPEG-TS, seek imprecisely), or - as the last
        resort - by reopening the file and decoding from its start."""
        target_pts = int(self._pts[k])
        key = self._keys[self._keys <= target_pts]
        if attempt >= 3 or key.size <= attempt:
            self._reopen()
        else:
            seek_pts = int(key[-1 - attempt])
            self._container.seek(seek_pts, stream=self._stream, backward=True, any_frame=False)
        self._decoder = self._container.decode(self._stream)
        self._taint = None

    def _reopen(self) -> None:
        """Open the file again (positioned at its start)."""
        self._container.close()
        self._container, self._stream = self._open_for_decoding()

    def _indexed(self, want: int):
        """(index, frame) pairs from the positioned decoder, skipping frames before ``want``."""
        assert self._decoder is not None, "position the decoder first"
        for frame in self._decoder:
            if frame.pts is None:
                continue
            idx = int(np.searchsorted(self._pts, frame.pts))
            if idx < len(self._pts) and self._pts[idx] == frame.pts:
                self._note_damage(idx, frame)
                if idx >= want:
                    yield idx, frame

    def _frames_from(self, k: int):
        """Decoded frames (PyAV objects) from frame ``k`` on, in order.

        A seek that lands after ``k`` is retried from earlier keyframes; a decoder that runs
        dry before the last indexed frame (the tail of an MPEG-TS can be lost after a seek) is
        re-run from the start of the file; a frame that still cannot be decoded is an error."""
        import av

        want = k
        try:
            for attempt in range(4):
                self._open_decoder(want, attempt)
                late = False
                for idx, frame in self._indexed(want):
                    if idx > want:
                        if want == k and attempt < 3:
                            late = True
                            break
                        raise VideoError(f"{self.path}: frame {want} cannot be decoded",
                                         code=codes.E_VIDEO_TRUNCATED)
                    yield idx, frame
                    want = idx + 1
                if late:
                    continue
                if want >= len(self._pts) or attempt == 3:
                    break
                # ran dry early: one more pass, decoding from the start of the file
                self._open_decoder(want, 3)
                for idx, frame in self._indexed(want):
                    if idx > want:
                        break
                    yield idx, frame
                    want = idx + 1
                break
        except av.error.FFmpegError:
            raise VideoError(f"{self.path}: frame {want} cannot be decoded (damaged data)",
                             code=codes.E_VIDEO_DAMAGED) from None
        if want < len(self._pts):
            raise VideoError(f"{self.path}: the video ends at frame {want} although "
                             f"{len(self._pts)} frames were indexed (truncated?)",
                             code=codes.E_VIDEO_TRUNCATED)

    def _decode_keyframe(self, k: int):
        """Frame ``k`` decoded from its packet alone when it is a keyframe (an intra-coded
        picture decodes the same without its neighbours), else None. A frame-threaded decoder
        positioned at a keyframe would decode several more frames before returning this one;
        any surprise here (no such packet, not exactly one picture) falls back to that path."""
        packet = self._own_packet(k)
        return None if packet is None else self._decode_alone(packet)

    def _own_packet(self, k: int):
        """The packet of frame ``k`` if it is a keyframe and can be found, else None."""
        import av

        pts = int(self._pts[k])
        i = int(np.searchsorted(self._keys, pts))
        if i >= len(self._keys) or self._keys[i] != pts:
            return None
        try:
            return self._keyframe_packet(pts, i)
        except (av.error.FFmpegError, ValueError):
            return None

    def _decode_alone(self, packet):
        """The one picture of a keyframe's packet, by a decoder of its own (None if it does
        not give exactly one picture of the video's size)."""
        import av

        st = self._stream
        try:
            ctx = av.CodecContext.create(st.codec_context.name, "r")
            if st.codec_context.extradata:
                ctx.extradata = st.codec_context.extradata
            ctx.thread_count = 1
            out = list(ctx.decode(packet)) + list(ctx.decode(None))
        except (av.error.FFmpegError, ValueError):
            return None
        if len(out) != 1 or out[0].width != self.size[0] or out[0].height < self.size[1]:
            return None
        if out[0].is_corrupt:
            idx = int(np.searchsorted(self._pts, packet.pts))
            self.damage[idx] = "the decoder found damaged data in it"
        return out[0]

    def read_many(self, ks, threads: int = 1) -> list[np.ndarray]:
        """Frames ``ks``: the keyframes' packets are read here, then decoded on their own on
        ``threads`` threads (decoding releases the GIL); other frames as :meth:`read`."""
        ks = [self.check_index(k) for k in ks]
        packets = {k: self._own_packet(k) for k in ks}
        order = [k for k in ks if packets.get(k) is not None]
        decoded: dict[int, object] = {}
        # no pool for one thread: a pool made from a QThread leaves a dummy thread entry behind
        if len(order) == 1 or threads <= 1:
            decoded = {k: self._decode_alone(packets[k]) for k in order}
        elif order:
            from concurrent.futures import ThreadPoolExecutor

            with ThreadPoolExecutor(max(1, threads), thread_name_prefix="impress-keys") as pool:
                decoded = dict(zip(order, pool.map(lambda k: self._decode_alone(packets[k]),
                                                   order)))
        return [self._to_rgb(decoded[k]) if decoded.get(k) is not None else self.read(k)
                for k in ks]

    def _keyframe_packet(self, pts: int, i: int):
        """The packet of keyframe ``i`` (stamp ``pts``), demuxed by this reader's container
        (which every read positions anew): after a seek to it, or to one of the two keyframes
        before it (an MPEG-TS seek can land late), or from the file's start."""
        self._decoder = None
        for attempt in range(4):
            if attempt == 3:
                self._reopen()
            c, st = self._container, self._stream
            if attempt < 3:
                c.seek(int(self._keys[max(0, i - attempt)]), stream=st, backward=True,
                       any_frame=False)
            for n, pkt in enumerate(c.demux(st)):
                if pkt.pts == pts and pkt.size:
                    return pkt
                late = pkt.dts is not None and pkt.dts > pts
                if late or (attempt < 3 and n > KEY_SEEK_PACKETS):
                    break
        return None

    def _to_rgb(self, frame) -> np.ndarray:
        rgb = frame.to_ndarray(format="rgb24")
        return rgb[: self.size[1]]

    def read(self, k: int) -> np.ndarray:
        k = self.check_index(k)
        frame = self._decode_keyframe(k)
        if frame is not None:
            return self._to_rgb(frame)
        gen = self._frames_from(k)
        try:
            idx, frame = next(gen)
        except StopIteration:
            raise VideoError(f"{self.path}: frame {k} cannot be decoded",
                             code=codes.E_VIDEO_TRUNCATED) from None
        finally:
            gen.close()
        return self._to_rgb(frame)

    def iter_frames(self, start: int = 0, stop: int | None = None):
        with closing(self._decoded(start, stop)) as frames:
            for idx, frame in frames:
                yield idx, self._to_rgb(frame)

    def iter_planes(self, start: int = 0, stop: int | None = None,
                    keep_rgb: dict[int, np.ndarray | None] | None = None):
        """As :meth:`VideoSource.iter_planes`: the decoder's own 4:2:0 planes, not converted
        (the luma at its coded height: 1088 rows for a 1080-line coding)."""
        with closing(self._decoded(start, stop)) as frames:
            for idx, frame in frames:
                if keep_rgb is not None and idx in keep_rgb:
                    keep_rgb[idx] = self._to_rgb(frame)
                yield idx, Planes.from_av(frame)

    def _decoded(self, start: int, stop: int | None):
        """``(index, PyAV frame)`` for ``start <= index < stop``."""
        stop = self.frame_count if stop is None else min(stop, self.frame_count)
        if start >= stop:
            return
        self.check_index(start)
        gen = self._frames_from(start)
        try:
            for idx, frame in gen:
                if idx >= stop:
                    break
                yield idx, frame
        finally:
            gen.close()

    def close(self) -> None:
        container = getattr(self, "_container", None)
        if container is not None:
            container.close()
        self._close_fd()


_FRAME_NUMBER = re.compile(r"^(.*?)(\d+)$")


def frame_numbers(names: list[str]) -> list[int] | None:
    """The frame number of each file name (``frame_000123.png`` -> 123) when every name is a
    common prefix followed by digits; None otherwise (the frames are then taken in name
    order, one frame interval apart)."""
    found = [m for m in (_FRAME_NUMBER.match(Path(n).stem) for n in names) if m is not None]
    if len(found) != len(names) or len({m.group(1) for m in found}) != 1:
        return None
    return [int(m.group(2)) for m in found]


class FrameFolder(VideoSource):
    """A folder of numbered still frames (``.png``, ``.jpg``, ``.tif``, ``.bmp``). Frames
    named by a common prefix and a number are taken in the numbers' order (``frame_9`` before
    ``frame_10``) and timed by their numbers: a missing number is a missing frame, warned about
    (``W-VIDEO-GAP``) and left out of the time line, not closed up. An entry with a frame's
    name that is not a regular file (a folder, a pipe, a device) is refused."""

    def __init__(self, path: Path, fps: float = 30.0) -> None:
        import cv2

        self.path = Path(path)
        self.open_warnings = []
        self.damage = {}
        try:
            named = [p for p in self.path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES]
            odd = sorted(p.name for p in named if not p.is_file())
        except OSError:
            raise VideoError(f"{self.path}: the folder cannot be read", code=codes.E_VIDEO_OPEN) from None
        if odd:
            raise VideoError(f"{self.path}: {', '.join(odd[:3])}{' ...' if len(odd) > 3 else ''} "
                             "named as frames but not regular image files (a folder, a pipe, a "
                             "device or a broken link): the frames cannot be read as evidence",
                             code=codes.E_VIDEO_OPEN)
        files = sorted(named)
        numbers = frame_numbers([p.name for p in files])
        if numbers is not None:
            nums: list[int] = numbers
            order = sorted(range(len(files)), key=lambda i: (nums[i], files[i].name))
            files = [files[i] for i in order]
            numbers = [nums[i] for i in order]
            twice = sorted({a for a, b in zip(numbers, numbers[1:], strict=False) if a == b})
            if twice:
                raise VideoError(f"{self.path}: frame number {twice[0]} is on two files: which "
                                 "comes first is not known", code=codes.E_VIDEO_OPEN)
        self._files = files
        if not self._files:
            raise VideoError(f"{self.path}: the folder holds no frames (.png, .jpg, .tif)",
                             code=codes.E_VIDEO_EMPTY)
        self._manifest = self._stats()
        first = cv2.imread(str(self._files[0]), cv2.IMREAD_COLOR)
        if first is None:
            raise VideoError(f"{self._files[0]}: not a readable image", code=codes.E_VIDEO_OPEN)
        self.size = (first.shape[1], first.shape[0])
        self.fps = float(fps)
        if numbers is None:
            self.times_s = np.arange(len(self._files)) / self.fps
        else:
            steps = np.diff(np.array(numbers, np.int64))
            for i in np.flatnonzero(steps > 1)[:10]:
                self.open_warnings.append(
                    f"W-VIDEO-GAP: {self.path.name}: {int(steps[i]) - 1} frame(s) missing "
                    f"between {self._files[i].name} and {self._files[i + 1].name} (frames "
                    f"{i} and {i + 1}); they are timed by their numbers")
            if (steps > 1).sum() > 10:
                self.open_warnings.append(
                    f"W-VIDEO-GAP: {self.path.name}: {int((steps > 1).sum())} gaps in the frame "
                    "numbers in all")
            self.times_s = (np.array(numbers, np.float64) - numbers[0]) / self.fps

    def _stats(self) -> list[tuple]:
        out: list[tuple] = []
        for f in self._files:
            try:
                st = os.stat(f)
                out.append((f.name, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns))
            except OSError:
                out.append((f.name, None))
        return out

    def sha256(self) -> str:
        from impress_gui.core.base.fileio import sha256_path

        return sha256_path(self.path)

    def check_unchanged(self) -> None:
        if self._stats() != self._manifest:
            from impress_gui.core.base.errors import IntegrityError

            raise IntegrityError(f"{self.path}: frames were changed while they were being read: "
                                 "the result is not kept", code=codes.E_EVIDENCE_CHANGED)

    def read(self, k: int) -> np.ndarray:
        import cv2

        k = self.check_index(k)
        img = cv2.imread(str(self._files[k]), cv2.IMREAD_COLOR)
        if img is None:
            raise VideoError(f"{self._files[k]}: frame {k} is not a readable image",
                             code=codes.E_VIDEO_TRUNCATED)
        if (img.shape[1], img.shape[0]) != self.size:
            raise VideoError(f"{self._files[k]}: frame {k} has a different size",
                             code=codes.E_VIDEO_TRUNCATED)
        return np.ascontiguousarray(img[..., ::-1])

    def iter_frames(self, start: int = 0, stop: int | None = None):
        stop = self.frame_count if stop is None else min(stop, self.frame_count)
        for k in range(start, stop):
            yield k, self.read(k)


def open_video(path: str | Path, fps: float | None = None) -> VideoSource:
    """Open a video file or a frame folder; raise :class:`VideoError` with a clear reason."""
    path = Path(path)
    if not path.exists():
        raise VideoError(f"{path}: no such file or folder", code=codes.E_FILE_MISSING)
    if fps is not None and not (np.isfinite(fps) and 0.5 <= fps <= 1000):
        raise VideoError(f"a frame rate of {fps} frames/s is not possible (0.5 to 1000)",
                         code=codes.E_VALUE)
    if path.is_dir():
        return FrameFolder(path, fps or 30.0)
    src = AVVideo(path)
    if fps:
        src.fps = float(fps)
        src.times_s = np.arange(src.frame_count) / src.fps
    return src
