"""Post-guards on video frames: NudeNet's nudity classes and an optional user-trained frame classifier.

Both look at every `every`-th frame (and the last), compare each class with its own threshold and reject the
video at the first flagged frame, naming its index, the class and the score.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..config import setting
from .core import Verdict
from .detection import check_frames, get_nudenet


def sampled(n: int, every: int) -> list[int]:
    """Indices of every `every`-th frame of `n`, the last frame included."""
    if every < 1:
        raise ValueError(f"every must be >= 1 (1: check all frames), not {every}")
    return sorted({*range(0, n, every), n - 1})


def check_classes(thresholds: dict[str, float], classes: list[str], key: str) -> None:
    """Thresholds must name classes the model has (a typo would silently never block)."""
    unknown = set(thresholds) - set(classes)
    if unknown:
        raise ValueError(f"unknown class(es) {sorted(unknown)} in {key}; classes: {', '.join(classes)}")


def first_flagged(name: str, idx: list[int], scores, limits: dict[str, float], start: int = 0) -> Verdict:
    """Reject at the first sampled frame with a class scoring at least its limit; `scores` gives each frame's
    (class, score) pairs; frame indices are reported from `start`."""
    for i, frame in zip(idx, scores):
        for label, score in frame:
            limit = limits.get(label)
            if limit is not None and score >= limit:
                return Verdict(False, name, f"frame {start + i}: {label} (score {score:.2f} >= {limit:.2f})")
    return Verdict(True, name, f"{len(idx)} frames checked, no class at or above its threshold")


@dataclass
class NudityConfig:
    """Which frames NudeNet looks at and the score at which each class rejects the video."""

    enabled: bool = True
    every: int = setting(2, low=1)  # check every N-th frame (1: all)
    resolution: int = setting(320, low=32)  # detector input size (multiple of 32)
    thresholds: dict[str, float] = field(default_factory=lambda: {
        "FEMALE_BREAST_EXPOSED": 0.45, "FEMALE_GENITALIA_EXPOSED": 0.4, "MALE_GENITALIA_EXPOSED": 0.4,
        "ANUS_EXPOSED": 0.4, "BUTTOCKS_EXPOSED": 0.5,
    })


class NudityGuard:
    """Rejects a video when NudeNet finds a thresholded class in a sampled frame."""

    name = "nudity"

    def __init__(self, cfg: NudityConfig | None = None):
        self.cfg = cfg or NudityConfig()
        self.detector = get_nudenet(self.cfg.resolution)
        check_classes(self.cfg.thresholds, self.detector.labels, "guardrails.nudity.thresholds")

    def check(self, frames: np.ndarray, start: int = 0) -> Verdict:
        frames = check_frames(frames)
        idx = sampled(len(frames), self.cfg.every)
        scores = [zip(d.labels, d.scores) for d in self.detector(frames[idx])]
        return first_flagged(self.name, idx, scores, self.cfg.thresholds, start)


@dataclass
class FrameClassifierConfig:
    """A checkpoint from `cosmos-lite train experiment=frame_classifier`; per-class thresholds (default 0.5)."""

    enabled: bool = False
    checkpoint: str | None = None
    every: int = setting(2, low=1)
    thresholds: dict[str, float] = field(default_factory=dict)


class FrameClassifierGuard:
    """Rejects a video when the user's classifier gives an unsafe class at least its threshold in a sampled frame."""

    name = "frame_classifier"

    def __init__(self, cfg: FrameClassifierConfig):
        from .classifier import load_classifier

        if not cfg.checkpoint:
            raise ValueError("guardrails.frame_classifier.checkpoint is not set; train one with "
                             "`cosmos-lite train experiment=frame_classifier data.root=DIR` or disable the guard")
        self.cfg = cfg
        self.model = load_classifier(cfg.checkpoint)
        check_classes(cfg.thresholds, self.model.classes, "guardrails.frame_classifier.thresholds")
        self.limits = {c: cfg.thresholds.get(c, 0.5) for c in self.model.classes if c not in self.model.safe}

    def check(self, frames: np.ndarray, start: int = 0) -> Verdict:
        frames = check_frames(frames)
        idx = sampled(len(frames), self.cfg.every)
        scores = [zip(self.model.classes, p) for p in self.model.predict(frames[idx])]
        return first_flagged(self.name, idx, scores, self.limits, start)
