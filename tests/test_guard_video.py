"""Post-guards and face blur on real frames: NudeNet per-class thresholds, the user-trained frame classifier,
face pixelation on skimage's astronaut (a hand-boxed face) held over a frame the detector misses."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from skimage import data

from cosmos_lite import cli
from cosmos_lite.errors import GuardrailBlocked
from cosmos_lite.guardrails import Guardrails, blur_faces
from cosmos_lite.guardrails.faces import FaceBlur, FaceBlurConfig
from cosmos_lite.guardrails.frames import NudityConfig, NudityGuard, sampled
from cosmos_lite.video import read_frames, write_video

FACE = (180, 75, 275, 185)  # astronaut(): x0, y0, x1, y1 of the face (forehead to chin), boxed by hand


def high_frequency_energy(frame: np.ndarray) -> float:
    """Energy of the luma minus its Gaussian blur (sigma 2): the detail that identifies a face."""
    y = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY).astype(np.float32)
    return float(((y - cv2.GaussianBlur(y, (0, 0), 2)) ** 2).sum())


def motion_blur(frame: np.ndarray, length: int = 35) -> np.ndarray:
    kernel = np.zeros((length, length), np.float32)
    kernel[length // 2] = 1 / length
    return cv2.filter2D(frame, -1, kernel)


@pytest.fixture(scope="module")
def astronaut() -> np.ndarray:
    return data.astronaut()


@pytest.fixture(scope="module")
def sintel_clip(sintel_10s) -> np.ndarray:
    return read_frames(sintel_10s, start=48, end=56, size=(128, 256))


def test_face_blur_removes_face_detail_and_leaves_the_rest(astronaut):
    out = blur_faces(astronaut[None])[0]
    x0, y0, x1, y1 = FACE
    before = high_frequency_energy(astronaut[y0:y1, x0:x1])
    after = high_frequency_energy(out[y0:y1, x0:x1])
    assert after <= 0.2 * before, f"face detail only dropped by {1 - after / before:.0%}"
    w, h = x1 - x0, y1 - y0
    outside = np.ones(astronaut.shape[:2], bool)
    outside[max(0, y0 - h // 2) : y1 + h // 2, max(0, x0 - w // 2) : x1 + w // 2] = False
    assert np.array_equal(out[outside], astronaut[outside])  # nothing away from the face changed
    assert out.shape == astronaut.shape and out.dtype == np.uint8


def test_face_missed_in_one_frame_stays_blurred(astronaut):
    frames = np.stack([astronaut, astronaut, motion_blur(astronaut), astronaut, astronaut])
    x0, y0, x1, y1 = FACE
    blur = FaceBlur()
    found = [len(b) for b in FaceBlur(FaceBlurConfig(hold=0)).boxes(frames)]
    assert found == [1, 1, 0, 1, 1]  # the detector misses the motion-blurred face
    out = blur(frames)
    changed = np.any(out[2, y0:y1, x0:x1] != frames[2, y0:y1, x0:x1], -1).mean()
    assert changed > 0.95  # held from the neighbouring frames
    no_hold = FaceBlur(FaceBlurConfig(hold=0))(frames)
    assert np.array_equal(no_hold[2], frames[2])


def test_streamed_video_gives_the_whole_video_result(astronaut):
    small = cv2.resize(astronaut, (256, 256))
    frames = np.stack([small, small, motion_blur(small), small, np.zeros_like(small), small, small])
    blur = FaceBlur()
    assert np.array_equal(np.stack(list(blur.stream(iter(frames), chunk=2))), blur(frames))
    g = Guardrails.from_config({"nudity": {"every": 1, "thresholds": {"FACE_FEMALE": 0.5}}})
    verdict = g.check_video_stream(iter(np.concatenate([np.zeros_like(frames[:5]), frames])), chunk=2)
    assert not verdict.allowed and verdict.reason.startswith("frame 5: FACE_FEMALE")  # counted from the start
    assert not g.check_video_stream(iter([]), chunk=2).allowed


def test_sampled_frames_include_the_last():
    assert sampled(10, 4) == [0, 4, 8, 9] and sampled(1, 3) == [0] and sampled(5, 1) == [0, 1, 2, 3, 4]


def test_nudity_guard_per_class_thresholds_name_frame_and_class(astronaut, sintel_clip):
    assert NudityGuard().check(sintel_clip).allowed  # a clean clip passes the default thresholds
    video = np.stack([cv2.resize(f, (256, 256)) for f in [np.zeros_like(astronaut), astronaut, astronaut]])
    guard = NudityGuard(NudityConfig(every=1, thresholds={"FACE_FEMALE": 0.5}))  # a class made to reject
    verdict = guard.check(video)
    assert not verdict.allowed and verdict.reason.startswith("frame 1: FACE_FEMALE")
    assert NudityGuard(NudityConfig(every=1, thresholds={"FACE_FEMALE": 0.99})).check(video).allowed
    with pytest.raises(ValueError, match="FACE_FEMAL"):
        NudityGuard(NudityConfig(thresholds={"FACE_FEMAL": 0.5}))


def test_guardrails_video_fail_closed(sintel_clip):
    g = Guardrails.from_config(None)
    verdict = g.check_video(sintel_clip.astype(np.float32))  # wrong dtype: the guard raises, so it blocks
    assert not verdict.allowed and "uint8" in verdict.reason
    with pytest.raises(GuardrailBlocked, match="face blur failed"):
        g.postprocess(sintel_clip[..., :2])
    open_ = Guardrails.from_config({"fail_closed": False})
    assert open_.check_video(sintel_clip.astype(np.float32)).allowed
    assert Guardrails.from_config({"enabled": False}).postprocess(sintel_clip) is sintel_clip


def test_frame_classifier_trains_and_guards(tmp_path, sintel_10s, moving_square, capsys):
    root = tmp_path / "frames"
    sintel = read_frames(sintel_10s, end=96, size=(64, 64))
    square = np.stack([cv2.resize(f, (64, 64), interpolation=cv2.INTER_NEAREST) for f in moving_square])
    for i in range(4):
        write_video(root / "safe" / f"sintel{i}.mp4", sintel[i * 24 : (i + 1) * 24], fps=24)
        write_video(root / "square" / f"square{i}.mp4", np.roll(square, 8 * i, axis=2), fps=24)
    out = tmp_path / "clf"
    code = cli.main(["train", "experiment=frame_classifier", f"data.root={root}", f"out={out}", "data.size=32",
                     "data.frames_per_file=12", "data.val_every=4", "trainer.epochs=8", "model.width=16"])
    assert code == 0 and (out / "model.safetensors").is_file()
    summary = json.loads(capsys.readouterr().out)
    assert summary["val_frames"] == 24 and summary["val_accuracy"] >= 0.9  # held-out files
    g = Guardrails.from_config({"nudity": {"enabled": False}, "face_blur": {"enabled": False},
                                "frame_classifier": {"enabled": True, "checkpoint": str(out), "every": 1}})
    assert g.check_video(sintel[:8]).allowed
    mixed = np.concatenate([sintel[:3], square[:3]])
    verdict = g.check_video(mixed)
    assert not verdict.allowed and verdict.guard == "frame_classifier" and verdict.reason.startswith("frame 3: square")
