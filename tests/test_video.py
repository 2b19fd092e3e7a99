"""Video I/O: round trips, frame counts, seeking, resampling, rotation and clear errors."""

from __future__ import annotations

import subprocess

import imageio_ffmpeg
import numpy as np
import pytest

from cosmos_lite.errors import InputError
from cosmos_lite.video import VideoError, frame_size, iter_frames, probe, read_frames, to_rgb, write_video

FFMPEG = imageio_ffmpeg.get_ffmpeg_exe()


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float(10 * np.log10(255.0**2 / mse))


def test_probe_and_frame_counts(sintel_10s, sintel_30s):
    info = probe(sintel_30s)
    assert (info.num_frames, info.fps, info.size, info.codec) == (720, 24.0, (480, 854), "h264")
    assert info.duration == pytest.approx(30.0, abs=0.1)
    assert probe(sintel_10s).num_frames == 240
    assert sum(1 for _ in iter_frames(sintel_30s, size=(48, 86))) == 720
    assert read_frames(sintel_10s, size=(48, 86)).shape == (240, 48, 86, 3)


def test_roundtrip_psnr_at_default_crf(sintel_10s, tmp_path):
    frames = read_frames(sintel_10s, 0, 48)
    out = write_video(tmp_path / "rt.mp4", frames, fps=24)
    back = read_frames(out)
    assert back.shape == frames.shape
    assert psnr(back, frames) > 35
    assert not [p for p in tmp_path.iterdir() if "tmp" in p.name]


def test_seek_and_resample_match_full_decode(sintel_10s):
    full = read_frames(sintel_10s, 0, 60)
    np.testing.assert_array_equal(read_frames(sintel_10s, 37, 45), full[37:45])
    half = read_frames(sintel_10s, 0, 30, fps=12)
    np.testing.assert_array_equal(half, full[::2])
    double = read_frames(sintel_10s, 0, 20, fps=48)
    np.testing.assert_array_equal(double[::2], full[:10])


def test_variable_frame_rate_resamples_to_constant(tmp_path, moving_square):
    src = tmp_path / "cfr.mp4"
    write_video(src, moving_square, fps=24, crf=0)
    vfr = tmp_path / "vfr.mkv"
    # Drop frames 2, 5, 8, ... and keep timestamps: a genuinely variable frame rate file.
    subprocess.run(
        [FFMPEG, "-loglevel", "error", "-i", str(src), "-vf", "select='lt(mod(n\\,3)\\,2)'", "-fps_mode", "vfr",
         "-c:v", "libx264", "-crf", "0", str(vfr)], check=True)
    out = read_frames(vfr, fps=24)
    assert 22 <= len(out) <= 24  # back on the 24 fps grid, gaps filled by the nearest frame
    for k in range(len(out)):
        if k % 3 != 2:  # kept frames land in their own slot
            assert psnr(out[k], moving_square[k]) > 40


def test_rotation_metadata_matches_ffmpeg_autorotate(tmp_path, moving_square):
    src = write_video(tmp_path / "a.mp4", moving_square[:, :, :48], fps=24, crf=0)
    rot = tmp_path / "rot.mp4"
    subprocess.run([FFMPEG, "-loglevel", "error", "-display_rotation", "90", "-i", str(src), "-c", "copy",
                    str(rot)], check=True)
    ours = read_frames(rot)
    raw = subprocess.run([FFMPEG, "-loglevel", "error", "-i", str(rot), "-f", "rawvideo", "-pix_fmt", "rgb24",
                          "-"], check=True, capture_output=True).stdout
    ref = np.frombuffer(raw, np.uint8).reshape(ours.shape)
    assert probe(rot).size == (48, 64) and ours.shape[1:3] == (48, 64)
    assert np.abs(ours.astype(int) - ref).max() <= 2


def test_yuv420p_frames_pass_through_and_match_rgb(tmp_path, sintel_10s, moving_square):
    rgb = read_frames(sintel_10s, 0, 6, size=(48, 86))
    yuv = list(iter_frames(sintel_10s, 0, 6, size=(48, 86), format="yuv420p"))
    assert yuv[0].shape == (72, 86) and frame_size(yuv[0]) == (48, 86)
    assert psnr(np.stack([to_rgb(f) for f in yuv]), rgb) > 40  # chroma resized at half size: a level or two apart
    assert to_rgb(yuv[0], 2).shape == (24, 42, 3)  # a preview: cut to even
    back = read_frames(write_video(tmp_path / "y.mp4", yuv, fps=24, crf=0))
    assert psnr(back, rgb) > 40
    src = write_video(tmp_path / "a.mp4", moving_square[:, :, :48], fps=24, crf=0)
    rot = tmp_path / "rot.mp4"
    subprocess.run([FFMPEG, "-loglevel", "error", "-display_rotation", "90", "-i", str(src), "-c", "copy",
                    str(rot)], check=True)
    upright = np.stack([to_rgb(f) for f in iter_frames(rot, format="yuv420p")])
    assert upright.shape[1:3] == (48, 64) and psnr(upright, read_frames(rot)) > 40


def test_native_yuv420p_frames_equal_pyav_planes(tmp_path):
    """Our plane copy (rows padded to the line size dropped) gives PyAV's own yuv420p array, byte for byte."""
    import av

    frames = np.random.default_rng(0).integers(0, 255, (6, 46, 70, 3), dtype=np.uint8)
    path = write_video(tmp_path / "w70.mp4", frames, fps=24, crf=0)
    with av.open(str(path)) as c:
        theirs = [f.to_ndarray(format="yuv420p") for f in c.decode(video=0)]
    assert theirs[0].shape == (69, 70)
    ours = list(iter_frames(path, format="yuv420p"))
    assert len(ours) == len(theirs) and all(np.array_equal(a, b) for a, b in zip(ours, theirs))


def test_odd_sizes_are_padded_or_cropped(tmp_path):
    frames = np.random.default_rng(0).integers(0, 255, (5, 33, 47, 3), dtype=np.uint8)
    assert read_frames(write_video(tmp_path / "p.mp4", frames, 10)).shape == (5, 34, 48, 3)
    assert read_frames(write_video(tmp_path / "c.mp4", frames, 10, even="crop")).shape == (5, 32, 46, 3)


def test_streaming_writer_accepts_a_generator(tmp_path, moving_square):
    out = write_video(tmp_path / "g.mkv", (f for f in moving_square), fps=24, codec="libx264", crf=10)
    assert probe(out).num_frames == len(moving_square)


@pytest.mark.parametrize("kind", ["truncated", "zero", "text", "missing", "truncated_faststart"])
def test_bad_input_raises_video_error_naming_the_file(kind, tmp_path, sintel_10s):
    bad = tmp_path / f"{kind}.mp4"
    data = sintel_10s.read_bytes()
    if kind == "truncated":
        bad.write_bytes(data[: len(data) // 3])
    elif kind == "zero":
        bad.write_bytes(b"")
    elif kind == "text":
        bad.write_text("this is not a video\n" * 50)
    elif kind == "truncated_faststart":
        fs = tmp_path / "fs.mp4"
        subprocess.run([FFMPEG, "-loglevel", "error", "-i", str(sintel_10s), "-t", "2", "-c", "copy",
                        "-movflags", "+faststart", str(fs)], check=True)
        bad.write_bytes(fs.read_bytes()[: fs.stat().st_size // 2])
    with pytest.raises(VideoError) as err:
        read_frames(bad)
    assert str(bad) in str(err.value)
    assert isinstance(err.value, InputError)


def test_failed_write_leaves_no_partial_file(tmp_path):
    def frames():
        yield np.zeros((16, 16, 3), np.uint8)
        raise RuntimeError("source died")

    with pytest.raises(RuntimeError):
        write_video(tmp_path / "x.mp4", frames(), fps=10)
    assert list(tmp_path.iterdir()) == []


def test_colours_match_the_ffmpeg_binary_both_ways(tmp_path):
    """Saturated colour blocks survive write_video -> ffmpeg decode and ffmpeg encode -> read_frames.

    Both sides must use the BT.601 limited-range matrix ffmpeg assumes for untagged video: with BT.709 on one
    side, pure red comes back with G off by ~24 levels.
    """
    colours = [(255, 0, 0), (0, 255, 0), (0, 0, 255), (0, 255, 255), (255, 0, 255), (255, 255, 0), (255, 255, 255),
               (0, 0, 0), (128, 128, 128), (224, 172, 140)]
    frame = np.concatenate([np.full((32, 32, 3), c, np.uint8) for c in colours], axis=1)
    frames = np.repeat(frame[None], 4, axis=0)
    ours = write_video(tmp_path / "ours.mp4", frames, fps=10, crf=0)
    raw = subprocess.run([FFMPEG, "-loglevel", "error", "-i", str(ours), "-f", "rawvideo", "-pix_fmt", "rgb24", "-"],
                         check=True, capture_output=True).stdout
    by_ffmpeg = np.frombuffer(raw, np.uint8).reshape(frames.shape)
    theirs = tmp_path / "theirs.mp4"
    subprocess.run([FFMPEG, "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", "320x32", "-r", "10",
                    "-i", "-", "-c:v", "libx264", "-crf", "0", "-pix_fmt", "yuv420p", str(theirs)],
                   input=frames.tobytes(), check=True)
    by_us = read_frames(theirs)
    for decoded in (by_ffmpeg, by_us):
        err = np.abs(decoded.astype(int) - frames).reshape(4, 32, 10, 32, 3)[:, 4:28, :, 4:28]  # block interiors
        assert err.max() <= 3, err.max()
