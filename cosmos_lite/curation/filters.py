"""Clip filters with one interface: score every clip, then drop it or only record the score.

Each filter is a config dataclass (mirrored by `configs/curate.yaml` under `filters.NAME`) with
`action` = drop | score | off, a `score(clip)` and a `passes(score)` rule. Near-duplicates are
judged across the whole job (`dedup`), from the perceptual hash each clip records.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar

import cv2
import numpy as np
from omegaconf import DictConfig

from ..config import to_dataclass
from ..errors import ConfigError
from ..video import frame_size
from .split import is_blank, luma, resize

ACTIONS = ("drop", "score", "off")


@dataclass
class Clip:
    """One candidate clip: its span in the source, and its frames at output and analysis size."""

    source: str
    start: int  # first frame (inclusive), at the processing frame rate
    end: int  # last frame + 1
    fps: float
    source_size: tuple[int, int]  # (H, W) of the source video, upright
    frames: list[np.ndarray] = field(default_factory=list)  # output size, RGB or yuv420p (video.to_rgb)
    small: list[np.ndarray] = field(default_factory=list)  # analysis size (36x64), RGB uint8

    @property
    def seconds(self) -> float:
        return (self.end - self.start) / self.fps


class Filter(ABC):
    """Scores a clip; `passes(score)` says whether a clip with that score is kept."""

    name: ClassVar[str]
    action: str

    @abstractmethod
    def score(self, clip: Clip) -> float: ...

    @abstractmethod
    def passes(self, score: float) -> bool: ...


@dataclass
class DurationFilter(Filter):
    """Clip length in seconds; too-short clips carry too little motion to learn from."""

    name: ClassVar[str] = "duration"
    action: str = "drop"
    min_seconds: float = 1.0

    def score(self, clip: Clip) -> float:
        return clip.seconds

    def passes(self, score: float) -> bool:
        return score >= self.min_seconds


@dataclass
class ResolutionFilter(Filter):
    """Short side of the source in pixels."""

    name: ClassVar[str] = "resolution"
    action: str = "drop"
    min_short_side: int = 64

    def score(self, clip: Clip) -> float:
        return float(min(clip.source_size))

    def passes(self, score: float) -> bool:
        return score >= self.min_short_side


@dataclass
class MotionFilter(Filter):
    """Moving share: the percentage of the picture whose brightness changes over a quarter second, clip mean.

    A pixel (of the 36x64 analysis frame) moves when its luma changes by more than `level` (of 255)
    between frames a quarter second apart: sensor and coding noise, averaged away at 36x64, stay under
    it, while a talking head in a locked-off shot or a slow pan moves several percent of the picture.
    A frozen or blank clip scores 0, so the default `min_percent` drops those and keeps real shots.
    """

    name: ClassVar[str] = "motion"
    action: str = "drop"
    min_percent: float = 1.0
    level: float = 4.0

    def score(self, clip: Clip) -> float:
        if len(clip.small) < 2:
            return 0.0
        gap = min(len(clip.small) - 1, max(1, round(clip.fps / 4)))
        y = luma(np.stack(clip.small))
        return 100.0 * float((np.abs(y[gap:] - y[:-gap]) > self.level).mean())

    def passes(self, score: float) -> bool:
        return score >= self.min_percent


@dataclass
class SharpnessFilter(Filter):
    """99.9th percentile of |Laplacian| of luma at (at most) 144 lines, median over `samples` frames: drops blur.

    The sharpest edges present, not the Laplacian's variance, so sparse but crisp renders pass.
    """

    name: ClassVar[str] = "sharpness"
    action: str = "drop"
    min: float = 30.0
    samples: int = 4

    def score(self, clip: Clip) -> float:
        idx = np.linspace(0, len(clip.frames) - 1, min(self.samples, len(clip.frames))).round().astype(int)
        values = []
        for i in idx:
            h, w = frame_size(clip.frames[i])
            lines = min(144, h)
            y = luma(resize(clip.frames[i], (lines, max(1, round(lines * w / h)))))
            values.append(np.percentile(np.abs(cv2.Laplacian(y, cv2.CV_32F)), 99.9))
        return float(np.median(values))

    def passes(self, score: float) -> bool:
        return score >= self.min


@dataclass
class BlankFilter(Filter):
    """Fraction of frames that are blank (`split.is_blank`: black, or without contrast outside letterbox bars)."""

    name: ClassVar[str] = "blank"
    action: str = "drop"
    max_fraction: float = 0.5

    def score(self, clip: Clip) -> float:
        return float(np.mean([is_blank(small) for small in clip.small]))

    def passes(self, score: float) -> bool:
        return score <= self.max_fraction


@dataclass
class DuplicateFilter(Filter):
    """Hamming distance (of 64 bits) from a clip's perceptual hash to the nearest earlier kept clip in the job.

    The per-clip part is `phash`; the decision needs the whole job, so `dedup` applies it at the end.
    """

    name: ClassVar[str] = "duplicate"
    action: str = "drop"
    max_distance: int = 6

    def score(self, clip: Clip) -> float:
        raise TypeError("duplicate is decided across the job: use phash(clip) per clip and dedup(metas)")

    def passes(self, score: float) -> bool:
        return score > self.max_distance


FILTERS: dict[str, type[Filter]] = {
    f.name: f for f in (DurationFilter, ResolutionFilter, MotionFilter, SharpnessFilter, BlankFilter, DuplicateFilter)
}


def build_filters(node: DictConfig | dict) -> list[Filter]:
    """Filters from the `filters` config node (name -> parameters); `action: off` leaves one out."""
    out = []
    for name, params in (node or {}).items():
        if name not in FILTERS:
            raise ConfigError(f"unknown filter filters.{name}; choose from {', '.join(FILTERS)}")
        f = to_dataclass(FILTERS[name], params, f"filters.{name}")
        if f.action not in ACTIONS:
            raise ConfigError(f"filters.{name}.action={f.action!r}; choose one of {', '.join(ACTIONS)}")
        if f.action != "off":
            out.append(f)
    return out


def phash(clip: Clip) -> str:
    """64-bit perceptual hash (DCT of the 32x32 luma mean of up to 8 frames) as 16 hex digits."""
    idx = np.linspace(0, len(clip.small) - 1, min(8, len(clip.small))).round().astype(int)
    y = np.mean([cv2.resize(luma(clip.small[i]), (32, 32), interpolation=cv2.INTER_AREA) for i in idx], axis=0)
    low = cv2.dct(y.astype(np.float32))[:8, :8].flatten()
    bits = low > np.median(low[1:])
    return f"{int(''.join('1' if b else '0' for b in bits), 2):016x}"


def hamming(a: str, b: str) -> int:
    return (int(a, 16) ^ int(b, 16)).bit_count()


def dedup(metas: list[dict], f: DuplicateFilter) -> list[dict]:
    """Score `duplicate` on every kept clip, in the given (deterministic) order; returns the metas it changed.

    A clip within `max_distance` bits of an earlier kept clip is a duplicate. Clips already dropped
    stay dropped, so rerunning over the same metas changes nothing.
    """
    seen: list[str] = []
    changed = []
    for m in metas:
        if not m["kept"] or "phash" not in m:
            continue
        score = float(min((hamming(m["phash"], h) for h in seen), default=64))
        ok = f.passes(score)
        if m["scores"].get(f.name) != score:
            m["scores"][f.name] = score
            m["passed"][f.name] = ok
            if not ok and f.action == "drop":
                m["kept"] = False
                m["dropped_by"].append(f.name)
            changed.append(m)
        if m["kept"]:
            seen.append(m["phash"])
    return changed
