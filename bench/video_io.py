"""Decode and encode throughput of cosmos_lite.video against the plain ffmpeg binary (imageio-ffmpeg).

Decode: every frame of the 30 s Sintel clip to RGB24 (ours: iter_frames; ffmpeg: rawvideo to a pipe).
Encode: the same RGB frames to H.264 with the same settings (libx264, CRF 18, preset veryfast, yuv420p).
Prints frames/s and the ratio of wall times (ours / ffmpeg; target for decode <= 1.3).

    .venv/bin/python bench/video_io.py [--video PATH] [--repeats 3] [--encode-frames 240]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

import imageio_ffmpeg
import numpy as np

from cosmos_lite.video import iter_frames, probe, read_frames, write_video

FFMPEG = imageio_ffmpeg.get_ffmpeg_exe()
DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "data" / "sintel_trailer_30s.mp4"


def timed(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def ours_decode(path: Path) -> int:
    return sum(1 for _ in iter_frames(path))


def ffmpeg_decode(path: Path, frame_bytes: int) -> int:
    proc = subprocess.Popen([FFMPEG, "-loglevel", "error", "-i", str(path), "-f", "rawvideo", "-pix_fmt", "rgb24", "-"],
                            stdout=subprocess.PIPE)
    n = 0
    while proc.stdout.read(frame_bytes):
        n += 1
    proc.wait()
    return n


def ffmpeg_encode(frames: np.ndarray, fps: float, out: Path) -> None:
    t, h, w, _ = frames.shape
    cmd = [FFMPEG, "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}", "-r", str(fps),
           "-i", "-", "-c:v", "libx264", "-crf", "18", "-preset", "veryfast", "-pix_fmt", "yuv420p", str(out)]
    subprocess.run(cmd, input=frames.tobytes(), check=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--video", type=Path, default=DEFAULT)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--encode-frames", type=int, default=240)
    a = ap.parse_args()
    info = probe(a.video)
    frame_bytes = info.height * info.width * 3
    assert ours_decode(a.video) == ffmpeg_decode(a.video, frame_bytes) == info.num_frames
    t_ours = timed(lambda: ours_decode(a.video), a.repeats)
    t_ff = timed(lambda: ffmpeg_decode(a.video, frame_bytes), a.repeats)
    n = info.num_frames
    print(f"decode {a.video.name} ({n} frames {info.width}x{info.height}), median of {a.repeats}")
    print(f"  cosmos_lite.video : {n / t_ours:7.1f} frames/s  ({t_ours:.2f} s)")
    print(f"  ffmpeg            : {n / t_ff:7.1f} frames/s  ({t_ff:.2f} s)")
    print(f"  ratio ours/ffmpeg wall time: {t_ours / t_ff:.2f}x  (target <= 1.3)")

    frames = read_frames(a.video, 0, a.encode_frames)
    with tempfile.TemporaryDirectory() as tmp:
        e_ours = timed(lambda: write_video(Path(tmp) / "ours.mp4", frames, info.fps, crf=18, preset="veryfast"), 1)
        e_ff = timed(lambda: ffmpeg_encode(frames, info.fps, Path(tmp) / "ff.mp4"), 1)
    m = len(frames)
    print(f"encode {m} frames, libx264 crf 18 veryfast yuv420p")
    print(f"  cosmos_lite.video : {m / e_ours:7.1f} frames/s  ({e_ours:.2f} s)")
    print(f"  ffmpeg            : {m / e_ff:7.1f} frames/s  ({e_ff:.2f} s)")
    print(f"  ratio ours/ffmpeg wall time: {e_ours / e_ff:.2f}x")


if __name__ == "__main__":
    main()
