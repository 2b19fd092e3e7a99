"""The one place that probes, decodes and encodes video, on PyAV.

Frames are numpy uint8 arrays `(T, H, W, 3)`, RGB. Where frames are only re-encoded (curation),
`iter_frames(format="yuv420p")` yields the decoder's planes instead, `(H * 3 // 2, W)` (Y, then U,
then V, as PyAV and OpenCV lay out I420), and `write_video` takes them back without any colour
conversion; `to_rgb` turns either kind into RGB. Colours are BT.601 limited range both ways, what
ffmpeg assumes for untagged video. Decoding streams: `iter_frames` holds one
frame at a time (plus the decoder's small queue), so a long video never sits in memory whole.
Frames come out upright (rotation metadata applied). Every failure to read is a `VideoError`
that names the file.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np

from .errors import InputError
from .files import atomic_path


class VideoError(InputError):
    """Corrupt, truncated, empty, missing or non-video input; the message names the file."""


@dataclass(frozen=True)
class VideoInfo:
    """What `probe` reads from the container, without decoding more than one frame."""

    path: str
    fps: float
    num_frames: int
    height: int  # upright, after rotation metadata
    width: int
    codec: str
    duration: float  # seconds
    rotation: int  # degrees counter-clockwise that decoding applies

    @property
    def size(self) -> tuple[int, int]:
        return self.height, self.width


def _fail(path: str | os.PathLike, what: str) -> VideoError:
    return VideoError(f"{path}: {what}. Check that it is a complete video file (re-encode or re-copy it).")


def _open(path: str | os.PathLike) -> av.container.InputContainer:
    p = Path(path)
    if not p.is_file():
        raise VideoError(f"{path}: no such file. Check the path.")
    if p.stat().st_size == 0:
        raise _fail(path, "file is empty (0 bytes)")
    try:
        container = av.open(str(p), "r")
    except (av.FFmpegError, UnicodeDecodeError, ValueError) as e:
        raise _fail(path, f"not a readable video ({e})") from None
    if not container.streams.video:
        container.close()
        raise _fail(path, "contains no video stream")
    return container


def _count_packets(container: av.container.InputContainer, stream) -> int:
    """Frame count by demuxing (no decoding), for containers that do not store it."""
    n = sum(1 for pkt in container.demux(stream) if pkt.size)
    container.seek(0)
    return n


def _upright(frame: np.ndarray, rotation: int) -> np.ndarray:
    k = (rotation // 90) % 4
    if not k:
        return frame
    if frame.ndim == 3:
        return np.ascontiguousarray(np.rot90(frame, k))
    y, uv = _planes(frame)
    y, uv = np.rot90(y, k), np.rot90(uv, k, axes=(1, 2))
    return np.concatenate([y.ravel(), uv.ravel()]).reshape(-1, y.shape[1])


def _planes(frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Views of a yuv420p frame `(H * 3 // 2, W)`: Y `(H, W)` and U, V stacked `(2, H // 2, W // 2)`."""
    h, w = frame.shape[0] * 2 // 3, frame.shape[1]
    return frame[:h], frame[h:].reshape(2, h // 2, w // 2)


def _yuv420p_array(frame: av.VideoFrame) -> np.ndarray:
    """A yuv420p av frame as one `(H * 3 // 2, W)` array, its planes copied row block by row block (PyAV's
    `to_ndarray` stacks them through a temporary, about twice the work)."""
    out = np.empty((frame.height * 3 // 2, frame.width), np.uint8)
    y, uv = _planes(out)
    for plane, dst in zip(frame.planes, (y, uv[0], uv[1])):
        ph, pw = dst.shape
        dst[:] = np.frombuffer(plane, np.uint8, count=plane.line_size * ph).reshape(ph, plane.line_size)[:, :pw]
    return out


def frame_size(frame: np.ndarray) -> tuple[int, int]:
    """(H, W) of an RGB `(H, W, 3)` or yuv420p `(H * 3 // 2, W)` frame."""
    return (frame.shape[0], frame.shape[1]) if frame.ndim == 3 else (frame.shape[0] * 2 // 3, frame.shape[1])


def to_rgb(frame: np.ndarray, step: int = 1) -> np.ndarray:
    """RGB `(h, w, 3)` of an RGB or yuv420p frame, keeping every `step`-th pixel (a cheap preview for analysis).

    yuv420p goes through OpenCV's BT.601 limited-range conversion (same as swscale's to 1 level); with step > 1
    only the kept pixels are converted, so a 36x64 preview of a 480p frame costs almost nothing.
    """
    if frame.ndim == 3:
        return np.ascontiguousarray(frame[::step, ::step]) if step > 1 else frame
    if step > 1:
        y, uv = _planes(frame)
        y, uv = y[::step, ::step], uv[:, ::step, ::step]
        h, w = min(y.shape[0] // 2, uv.shape[1]), min(y.shape[1] // 2, uv.shape[2])
        frame = np.concatenate([y[: 2 * h, : 2 * w].ravel(), uv[:, :h, :w].ravel()]).reshape(3 * h, 2 * w)
    return cv2.cvtColor(frame, cv2.COLOR_YUV2RGB_I420)


def probe(path: str | os.PathLike) -> VideoInfo:
    """Frame rate, frame count, upright size, codec, duration and rotation of a video file."""
    with _open(path) as container:
        stream = container.streams.video[0]
        rate = stream.average_rate or stream.guessed_rate or stream.base_rate
        if not rate:
            raise _fail(path, "has no frame rate")
        fps = float(rate)
        n = stream.frames or _count_packets(container, stream)
        if stream.duration is not None and stream.time_base is not None:
            duration = float(stream.duration * stream.time_base)
        elif container.duration is not None:
            duration = container.duration / av.time_base
        else:
            duration = n / fps
        try:
            first = next(container.decode(stream))
        except (StopIteration, av.FFmpegError) as e:
            raise _fail(path, f"has no decodable frame ({e})") from None
        rotation = int(round(getattr(first, "rotation", 0) or 0))
        h, w = stream.codec_context.height, stream.codec_context.width
        if (rotation // 90) % 2:
            h, w = w, h
        return VideoInfo(str(path), fps, n, h, w, stream.codec_context.name, duration, rotation)


def _to_hw(size) -> tuple[int, int] | None:
    if size is None:
        return None
    if isinstance(size, int):
        return size, size
    h, w = size
    return int(h), int(w)


def _decode(path, container, stream) -> Iterator[tuple[float, np.ndarray]]:
    """Yield (time in seconds, av frame), turning FFmpeg errors into VideoError."""
    try:
        for frame in container.decode(stream):
            yield frame.time, frame
    except av.FFmpegError as e:
        raise _fail(path, f"decoding failed ({e})") from None


def iter_frames(
    path: str | os.PathLike,
    start: int = 0,
    end: int | None = None,
    size: int | tuple[int, int] | None = None,
    fps: float | None = None,
    format: str = "rgb24",
) -> Iterator[np.ndarray]:
    """Stream upright RGB frames `(H, W, 3)` uint8 with indices in `[start, end)`.

    size: `(H, W)` (or an int for square) to resize to, after rotation. fps: resample to this
    constant rate by nearest timestamp (handles variable frame rate); indices then count
    resampled frames. Without fps, indices count frames at the stream's average rate.
    format="yuv420p": the decoder's planes `(H * 3 // 2, W)` instead of RGB (even sizes only), for
    frames that are only re-encoded: no colour conversion either way.
    """
    if format not in ("rgb24", "yuv420p"):
        raise ValueError(f"format must be 'rgb24' or 'yuv420p', not {format!r}")
    hw = _to_hw(size)
    with _open(path) as container:
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        src_rate = float(stream.average_rate or stream.guessed_rate or 25)
        rate = float(fps) if fps else src_rate
        t0 = float(stream.start_time * stream.time_base) if stream.start_time is not None else 0.0
        expected = stream.frames
        if start > 0:
            # Seek to the keyframe before `start`; frames before it are decoded and skipped.
            container.seek(int((t0 + start / rate) / stream.time_base), stream=stream, backward=True)

        def convert(frame) -> np.ndarray:
            rot = int(round(getattr(frame, "rotation", 0) or 0))
            h, w = (frame.height, frame.width) if hw is None else (hw[1], hw[0]) if (rot // 90) % 2 else hw
            if format == "yuv420p" and (h % 2 or w % 2):
                raise ValueError(f"{path}: yuv420p frames need an even size, not {h}x{w}; pass an even size=")
            if hw is not None:
                frame = frame.reformat(width=w, height=h, format=format, interpolation="AREA")
            if format == "yuv420p" and frame.format.name == "yuv420p":
                return _upright(_yuv420p_array(frame), rot)
            return _upright(frame.to_ndarray(format=format), rot)

        def fill(frame, until: float) -> Iterator[np.ndarray]:
            """Emit `frame` for every resampled slot before time `until`."""
            nonlocal k
            img = None
            while k / rate < until and (end is None or k < end):
                img = convert(frame) if img is None else img
                yield img
                k += 1

        k = start  # next output index (fps resampling)
        decoded_last = -1  # source index of the last decoded frame
        prev = None  # (time, frame) of the previous source frame (fps resampling)
        for t, frame in _decode(path, container, stream):
            t = (t if t is not None else (decoded_last + 1) / src_rate + t0) - t0
            decoded_last = int(round(t * src_rate))
            if fps is None:
                if decoded_last < start:
                    continue
                if end is not None and decoded_last >= end:
                    return
                yield convert(frame)
                continue
            if prev is not None:
                # Slot k takes the source frame nearest to its time k / fps.
                yield from fill(prev[1], (prev[0] + t) / 2)
                if end is not None and k >= end:
                    return
            prev = (t, frame)
        if prev is not None:
            yield from fill(prev[1], prev[0] + 1 / src_rate - 1e-9)
        if end is None and expected and decoded_last >= 0 and decoded_last + 1 < expected:
            raise _fail(path, f"is truncated: {decoded_last + 1} of {expected} frames could be decoded")
        if decoded_last < 0 and start == 0:
            raise _fail(path, "has no decodable frame")


def read_frames(
    path: str | os.PathLike,
    start: int = 0,
    end: int | None = None,
    size: int | tuple[int, int] | None = None,
    fps: float | None = None,
) -> np.ndarray:
    """All frames in `[start, end)` as one `(T, H, W, 3)` uint8 array (see `iter_frames`)."""
    frames = list(iter_frames(path, start, end, size, fps))
    if not frames:
        raise VideoError(f"{path}: no frames in [{start}, {end}). Check the frame range.")
    return np.stack(frames)


def _even(frame: np.ndarray, even: str) -> np.ndarray:
    h, w = frame.shape[:2]
    if not (h % 2 or w % 2) or frame.ndim == 2:  # yuv420p frames are even by construction
        return frame
    if even == "crop":
        return frame[: h - h % 2, : w - w % 2]
    return np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")


def _to_av_frame(frame: np.ndarray, pix_fmt: str) -> av.VideoFrame:
    """An even-sized RGB frame as an av frame; yuv420p by OpenCV (~3x cheaper than swscale, same BT.601 colours)."""
    if frame.ndim == 2:  # the encoder reads the array in place (it stays referenced by the frame)
        return av.VideoFrame.from_numpy_buffer(np.ascontiguousarray(frame), format="yuv420p")
    if pix_fmt == "yuv420p":
        return av.VideoFrame.from_numpy_buffer(cv2.cvtColor(frame, cv2.COLOR_RGB2YUV_I420), format="yuv420p")
    return av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")


def write_video(
    path: str | os.PathLike,
    frames: Iterable[np.ndarray] | np.ndarray,
    fps: float,
    codec: str = "libx264",
    crf: int = 18,
    preset: str | None = "veryfast",
    pix_fmt: str = "yuv420p",
    even: str = "pad",
    threads: int = 0,
) -> Path:
    """Encode RGB uint8 frames to `path` atomically (temp file in the same folder, then rename).

    frames may be an array `(T, H, W, 3)` or any iterable of `(H, W, 3)` frames (streamed), or of
    yuv420p frames `(H * 3 // 2, W)` from `iter_frames(format="yuv420p")` (encoded without conversion).
    Odd sizes are padded (`even="pad"`, edge pixels repeated) or cropped (`even="crop"`) to even,
    as yuv420p requires. threads: encoder threads (0: the codec's own choice, from the usable cores).
    yuv420p arrays are handed to the encoder in place, not copied: a generator must yield a new array per frame,
    not refill one (codecs with a frame delay may read it later). Returns the path written.
    """
    path = Path(path)
    if even not in ("pad", "crop"):
        raise ValueError(f"even must be 'pad' or 'crop', not {even!r}")
    path.parent.mkdir(parents=True, exist_ok=True)
    n = 0
    with atomic_path(path) as tmp:
        with av.open(str(tmp), "w") as container:
            stream = None
            for frame in frames:
                rgb = frame.ndim == 3 and frame.shape[2] == 3
                yuv = frame.ndim == 2 and frame.shape[0] % 3 == 0 and frame.shape[1] % 2 == 0
                if frame.dtype != np.uint8 or not (rgb or yuv):
                    raise ValueError(f"{path}: frames must be uint8 RGB (H, W, 3) or yuv420p (H * 3 // 2, W) with even "
                                     f"H and W, got {frame.dtype} {frame.shape}")
                frame = _even(frame, even)
                if stream is None:
                    stream = container.add_stream(codec, rate=Fraction(fps).limit_denominator(1001))
                    stream.height, stream.width = frame_size(frame)
                    stream.pix_fmt = pix_fmt
                    stream.thread_type = "AUTO"
                    stream.codec_context.thread_count = threads
                    options = {"crf": str(crf)}
                    if preset is not None:
                        options["preset"] = str(preset)
                    if codec == "libvpx-vp9":
                        options["b"] = "0"
                    stream.options = options
                container.mux(stream.encode(_to_av_frame(frame, pix_fmt)))
                n += 1
            if stream is None:
                raise ValueError(f"{path}: no frames to write")
            container.mux(stream.encode(None))
    return path
