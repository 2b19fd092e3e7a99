"""Face blur post-processor: NudeNet's face classes find faces in every frame, boxes are grown by a margin and
held for a few frames before and after each detection (so a face missed for a frame stays hidden), then pixelated.

NudeNet was chosen by measurement among detectors whose weights ship in a pip wheel (bench/guardrails.py):
OpenCV 5 wheels dropped the Haar cascades and facenet-pytorch pins an old torch.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from ..config import setting
from .detection import FACE_CLASSES, check_frames, get_nudenet


@dataclass
class FaceBlurConfig:
    """Detection threshold, temporal smoothing and pixelation strength of face blur."""

    enabled: bool = True
    threshold: float = setting(0.15, low=0, high=1)  # minimum FACE_* score (low: a blurred non-face costs little)
    resolution: int = setting(320, low=32)  # detector input size (multiple of 32)
    hold: int = setting(2, low=0)  # a box also covers this many frames before and after the frame it was found in
    margin: float = setting(0.15, low=0)  # grow each box by this share of its width and height on every side
    cells: int = setting(6, low=1)  # pixelation: a face keeps about cells x cells average colours


def pixelate(frame: np.ndarray, box: np.ndarray, cells: int) -> None:
    """Replace the box `(x0, y0, x1, y1)` of `frame` in place by its cells x cells average colours, upsampled
    bilinearly: identity is gone and no block edges are left as high-frequency detail."""
    import cv2

    x0, y0, x1, y1 = box
    region = frame[y0:y1, x0:x1]
    h, w = region.shape[:2]
    if h < 2 or w < 2:
        return
    small = cv2.resize(region, (max(1, round(w * cells / max(h, w))), max(1, round(h * cells / max(h, w)))),
                       interpolation=cv2.INTER_AREA)
    frame[y0:y1, x0:x1] = cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


class FaceBlur:
    """Pixelates every face in a video; same shape and dtype out."""

    name = "face_blur"

    def __init__(self, cfg: FaceBlurConfig | None = None):
        self.cfg = cfg or FaceBlurConfig()

    def boxes(self, frames: np.ndarray) -> list[np.ndarray]:
        """Integer face boxes `(N, 4)` to blur in each frame: detections grown by the margin, held over time."""
        c = self.cfg
        _, h, w, _ = frames.shape
        found = [d.of(FACE_CLASSES, c.threshold) for d in get_nudenet(c.resolution)(frames)]
        grown = []
        for b in found:
            pad = np.concatenate([b[:, 2:] - b[:, :2]] * 2, 1) * c.margin * np.array([-1, -1, 1, 1])
            grown.append(b + pad)
        held = [np.concatenate(grown[max(0, t - c.hold) : t + c.hold + 1]) for t in range(len(frames))]
        limit = np.array([w, h, w, h])
        return [np.clip(np.round(b), 0, limit).astype(int) for b in held]

    def __call__(self, frames: np.ndarray) -> np.ndarray:
        frames = check_frames(frames)
        out = frames.copy()
        for frame, boxes in zip(out, self.boxes(frames)):
            for box in boxes:
                pixelate(frame, box, self.cfg.cells)
        return out

    def stream(self, frames: Iterable[np.ndarray], chunk: int = 64) -> Iterator[np.ndarray]:
        """Blur a stream chunk by chunk; each chunk sees `hold` frames on both sides, so the output equals
        blurring the whole video at once (the detector's cache keeps the overlap from running twice)."""
        hold = self.cfg.hold
        chunk = max(chunk, hold, 1)
        buf: list[np.ndarray] = []
        done = 0  # leading frames of buf already emitted (context only)
        for frame in frames:
            buf.append(frame)
            if len(buf) - done >= chunk + hold:
                yield from self(np.stack(buf))[done : len(buf) - hold]
                buf, done = buf[len(buf) - 2 * hold :], hold
        if len(buf) > done:
            yield from self(np.stack(buf))[done:]
