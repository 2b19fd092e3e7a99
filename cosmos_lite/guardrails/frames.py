"""Post-guards on video frames: NudeNet's nudity classes and an optional user-trained frame classifier.

Both look at every `every`-th frame (and the last), compare each class with its own threshold and reject the
video at the first flagged frame, naming its index, the class and the score.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .core import Verdict
from .detection import check_frames, get_nudenet


def sampled(n: int, every: int) -> list[int]:
    """Indices of every `every`-th frame of `n`, the last frame included."""
    if every < 1:
        raise ValueError(f"every must be >= 1 (1: check all frames), not {every}")
    return sorted({*range(0, n, every), n - 1})


@dataclass
class NudityConfig:
    """Which frames NudeNet looks at and the score at which each class rejects the video."""

    enabled: bool = True
    every: int = 2  # check every N-th frame (1: all)
    resolution: int = 320  # detector input size (multiple of 32)
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
        unknown = set(self.cfg.thresholds) - set(self.detector.labels)
        if unknown:
            raise ValueError(f"unknown NudeNet class(es) {sorted(unknown)} in guardrails.nudity.thresholds; "
                             f"classes: {', '.join(self.detector.labels)}")

    def check(self, frames: np.ndarray) -> Verdict:
        frames = check_frames(frames)
        idx = sampled(len(frames), self.cfg.every)
        for i, det in zip(idx, self.detector(frames[idx])):
            for label, score in zip(det.labels, det.scores):
                limit = self.cfg.thresholds.get(label)
                if limit is not None and score >= limit:
                    return Verdict(False, self.name, f"frame {i}: {label} (score {score:.2f} >= {limit:.2f})")
        return Verdict(True, self.name, f"{len(idx)} frames checked, nothing above its threshold")


@dataclass
class FrameClassifierConfig:
    """A checkpoint from `cosmos-lite train experiment=frame_classifier`; per-class thresholds (default 0.5)."""

    enabled: bool = False
    checkpoint: str | None = None
    every: int = 2
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
        unknown = set(cfg.thresholds) - set(self.model.classes)
        if unknown:
            raise ValueError(f"unknown class(es) {sorted(unknown)} in guardrails.frame_classifier.thresholds; "
                             f"the checkpoint has {', '.join(self.model.classes)}")

    def check(self, frames: np.ndarray) -> Verdict:
        frames = check_frames(frames)
        idx = sampled(len(frames), self.cfg.every)
        probs = self.model.predict(frames[idx])
        for i, p in zip(idx, probs):
            for c, name in enumerate(self.model.classes):
                limit = self.cfg.thresholds.get(name, 0.5)
                if name not in self.model.safe and p[c] >= limit:
                    return Verdict(False, self.name, f"frame {i}: {name} (probability {p[c]:.2f} >= {limit:.2f})")
        return Verdict(True, self.name, f"{len(idx)} frames checked, no unsafe class above its threshold")
