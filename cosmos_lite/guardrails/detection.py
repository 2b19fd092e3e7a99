"""NudeNet's detector (a YOLOv8 ONNX model that ships inside the `nudenet` wheel), run batched on RGB frames.

One detector serves both the nudity post-guard (its EXPOSED classes) and face blur (FACE_FEMALE, FACE_MALE).
Pre- and post-processing are vectorised here instead of NudeNet's one-image, per-row Python loop.
"""

from __future__ import annotations

import hashlib
import os
from collections import OrderedDict
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..errors import InputError

FACE_CLASSES = ("FACE_FEMALE", "FACE_MALE")


@dataclass
class Detections:
    """Boxes `(N, 4)` as x0, y0, x1, y1 in pixels of the frame, their scores `(N,)` and class names."""

    boxes: np.ndarray
    scores: np.ndarray
    labels: list[str]

    def of(self, classes: tuple[str, ...] | set[str], min_score: float = 0.0) -> np.ndarray:
        """Boxes of the given classes with at least `min_score`."""
        keep = [i for i, c in enumerate(self.labels) if c in classes and self.scores[i] >= min_score]
        return self.boxes[keep]


def check_frames(frames: np.ndarray) -> np.ndarray:
    """The video contract of the guardrails: uint8 `(T, H, W, 3)` RGB with at least one frame."""
    frames = np.asarray(frames)
    if frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] != 3 or not len(frames):
        raise InputError(f"guardrails take uint8 RGB frames (T, H, W, 3) with T >= 1; got {frames.dtype} "
                         f"{frames.shape}. Convert with np.asarray(frames, np.uint8).")
    return frames


class NudeNet:
    """Detect NudeNet's 18 classes (exposed/covered body parts, faces) in frames at `resolution` (multiple of 32)."""

    def __init__(self, resolution: int = 320, min_score: float = 0.1, nms_iou: float = 0.45, batch: int = 8,
                 keep: int = 512):
        if resolution % 32:
            raise ValueError(f"NudeNet resolution must be a multiple of 32, not {resolution}")
        import nudenet.nudenet as nn
        import onnxruntime as ort

        path = os.path.join(os.path.dirname(nn.__file__), "320n.onnx")
        self.session = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
        self.input = self.session.get_inputs()[0].name
        self.labels: list[str] = list(vars(nn)["__labels"])  # the model's class order, kept by nudenet
        self.resolution, self.min_score, self.nms_iou, self.batch = resolution, min_score, nms_iou, batch
        self.recent: OrderedDict[bytes, Detections] = OrderedDict()  # frame digest -> detections
        self.keep = keep

    def _blob(self, frames: np.ndarray) -> np.ndarray:
        """Letterbox (pad right/bottom to square, as NudeNet was trained) and resize to the input size."""
        import cv2

        t, h, w, _ = frames.shape
        side = max(h, w)
        square = np.zeros((t, side, side, 3), np.uint8)
        square[:, :h, :w] = frames
        r = self.resolution
        small = square if side == r else np.stack([cv2.resize(f, (r, r), interpolation=cv2.INTER_LINEAR)
                                                   for f in square])
        return np.ascontiguousarray(small.transpose(0, 3, 1, 2), dtype=np.float32) / 255.0

    def _decode(self, out: np.ndarray, side: int, h: int, w: int) -> Detections:
        """One frame's raw output `(4 + classes, anchors)` to boxes after score filtering and NMS."""
        import cv2

        scores_all = out[4:].T
        cls = scores_all.argmax(1)
        score = scores_all[np.arange(len(cls)), cls]
        keep = score >= self.min_score
        cx, cy, bw, bh = out[:4, keep] * (side / self.resolution)
        x0, y0 = np.clip(cx - bw / 2, 0, w), np.clip(cy - bh / 2, 0, h)
        x1, y1 = np.clip(cx + bw / 2, 0, w), np.clip(cy + bh / 2, 0, h)
        score, cls = score[keep], cls[keep]
        xywh = np.stack([x0, y0, x1 - x0, y1 - y0], 1)
        idx = np.asarray(cv2.dnn.NMSBoxes(xywh.tolist(), score.tolist(), self.min_score, self.nms_iou),
                         dtype=int).reshape(-1)
        boxes = np.stack([x0, y0, x1, y1], 1)[idx].astype(np.float32)
        return Detections(boxes, score[idx].astype(np.float32), [self.labels[c] for c in cls[idx]])

    def __call__(self, frames: np.ndarray) -> list[Detections]:
        """Detections for each frame of uint8 `(T, H, W, 3)` RGB frames, in batches. The last frames' results are
        kept by content, so face blur does not run the model again on frames the post-guard just checked."""
        frames = check_frames(frames)
        _, h, w, _ = frames.shape
        keys = [hashlib.blake2b(f.tobytes(), digest_size=16, key=str(f.shape).encode()).digest() for f in frames]
        first: dict[bytes, int] = {}
        for i, k in enumerate(keys):
            if k not in self.recent:
                first.setdefault(k, i)  # a repeated frame runs once
        todo = list(first.values())
        for i in range(0, len(todo), self.batch):
            chunk = todo[i : i + self.batch]
            out = self.session.run(None, {self.input: self._blob(frames[chunk])})[0]
            for j, o in zip(chunk, out):
                self.recent[keys[j]] = self._decode(o, max(h, w), h, w)
        result = [self.recent[k] for k in keys]
        while len(self.recent) > self.keep:
            self.recent.popitem(last=False)
        return result


@lru_cache(maxsize=4)
def get_nudenet(resolution: int = 320) -> NudeNet:
    """One shared detector per resolution in a process (the guard and face blur load the model once)."""
    return NudeNet(resolution)
