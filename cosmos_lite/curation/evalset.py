"""The splitters' evaluation set: synthetic gradual transitions between real shots, with exact annotations.

Each synthetic video chains four shots (Sintel shots and slow pans over `skimage.data` photos): shot,
gradual transition, shot, hard cut, shot, gradual transition, shot. One video per kind (dissolve, fade
through black, wipe) and length (8, 16, 30 frames), built from a seed, so the set is the same on every
machine and nothing is committed but this code. The `dev` and `test` splits use disjoint shots and
photos: tune on `dev`, report `test`. The annotated Sintel clip (hard cuts) is the set's third part;
`split.evaluate` scores all of them.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import ConfigError
from ..video import read_frames

KINDS = ("dissolve", "fade", "wipe")
LENGTHS = (8, 16, 30)
SIZE = (144, 256)  # (H, W) of the synthetic videos: Sintel's 16:9, big enough for every splitter's analysis size
FPS = 24.0
# Shots of sintel_trailer_30s.mp4 without a cut, fade or flash inside: [start, end) frame spans.
SINTEL_SHOTS = {"dev": [(0, 70), (83, 144), (524, 573), (653, 706)],
                "test": [(258, 286), (287, 308), (574, 610), (611, 624)]}
PHOTOS = {"dev": ("astronaut", "coffee"), "test": ("chelsea", "rocket")}


@dataclass
class Sample:
    """One video of the set: its frames (T, H, W, 3) uint8 RGB, and the annotation `split.evaluate` reads."""

    name: str
    frames: np.ndarray
    fps: float
    annotation: dict


class Shot:
    """Endless frames of one shot: played forwards, then backwards, and so on (no jump, so no cut inside)."""

    def __init__(self, frames: np.ndarray, start: int = 0):
        self.frames, self.i = frames, start

    def take(self, n: int) -> np.ndarray:
        period = max(1, 2 * len(self.frames) - 2)
        idx = [(k if k < len(self.frames) else period - k) for k in ((self.i + j) % period for j in range(n))]
        self.i += n
        return self.frames[idx].astype(np.float32)


def pan(image: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """`n` frames of a slow camera pan (0.5-1 px/frame at SIZE, random direction) over a photo."""
    h, w = SIZE
    scale = 1.25 * max(h / image.shape[0], w / image.shape[1])
    size = (round(image.shape[1] * scale), round(image.shape[0] * scale))
    big = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    speed, angle = rng.uniform(0.5, 1.0), rng.uniform(0, 2 * np.pi)
    room = np.array([big.shape[0] - h, big.shape[1] - w], np.float32)
    step = np.array([np.sin(angle), np.cos(angle)], np.float32) * speed
    start = np.clip(room / 2 - step * n / 2, 0, room)
    out = []
    for k in range(n):
        y, x = np.clip(start + step * k, 0, room)
        m = np.float32([[1, 0, -x], [0, 1, -y]])  # sub-pixel crop
        out.append(cv2.warpAffine(big, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT))
    return np.stack(out)


def transition(kind: str, a: np.ndarray, b: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The L frames of a `kind` transition from frames `a` to frames `b` (both (L, H, W, 3) float).

    Frame j mixes with weight (j + 1) / (L + 1), so every frame is strictly between the shots: a dissolve
    blends them, a fade through black darkens `a` to black over the first half and lightens `b` over the
    second, a wipe reveals `b` behind an edge sweeping across (from a random side).
    """
    n = len(a)
    w = ((np.arange(n) + 1) / (n + 1)).astype(np.float32)[:, None, None, None]
    if kind == "dissolve":
        return (1 - w) * a + w * b
    if kind == "fade":
        return np.where(w < 0.5, a * (1 - 2 * w), b * (2 * w - 1))
    if kind == "wipe":
        h, width = a.shape[1:3]
        axis = int(rng.integers(2))
        ramp = (np.arange(h) + 0.5) / h if axis == 0 else (np.arange(width) + 0.5) / width
        if rng.integers(2):
            ramp = 1 - ramp
        mask = (ramp[:, None] if axis == 0 else ramp[None, :]) < w[..., 0]  # (L, H, W)
        return np.where(mask[..., None], b, a)
    raise ConfigError(f"transition kind {kind!r}: choose one of {', '.join(KINDS)}")


def shots(sintel: str | os.PathLike, split: str, seed: int) -> list[np.ndarray]:
    """The split's source shots at SIZE: its Sintel shots, then a pan over each of its photos."""
    if split not in SINTEL_SHOTS:
        raise ConfigError(f"evaluation split {split!r}: choose dev (for tuning) or test")
    try:
        from skimage import data
    except ImportError:
        raise ConfigError("the evaluation set pans over skimage.data photos: pip install scikit-image") from None
    rng = np.random.default_rng((seed, list(SINTEL_SHOTS).index(split)))
    video = read_frames(sintel, end=max(e for _, e in SINTEL_SHOTS[split]), size=SIZE)
    out = [video[s:e] for s, e in SINTEL_SHOTS[split]]
    return out + [pan(getattr(data, name)()[..., :3], 96, rng) for name in PHOTOS[split]]


def synthetic_set(sintel: str | os.PathLike, split: str = "test", seed: int = 0) -> list[Sample]:
    """One video per transition kind and length: shot, transition, shot, hard cut, shot, transition, shot.

    `sintel` is sintel_trailer_30s.mp4 (the source of the split's shots); the seed and the split pick the
    shots' order and starts, the holds and the wipes' sides. Annotations give the exact
    first and last mixed frame of each transition (`gradual_tolerance_frames` 0) and each cut's frame.
    """
    pool = shots(sintel, split, seed)
    rng = np.random.default_rng((seed, list(SINTEL_SHOTS).index(split)))
    samples = []
    for kind in KINDS:
        for length in LENGTHS:
            order = rng.permutation(len(pool))[:4]
            seq = [Shot(pool[k], int(rng.integers(len(pool[k])))) for k in order]
            parts, cuts, gradual, n = [], [], [], 0
            for k, shot in enumerate(seq):
                hold = int(rng.integers(20, 41))
                parts.append(shot.take(hold))
                n += hold
                if k == 1:
                    cuts.append(n)
                elif k in (0, 2):
                    parts.append(transition(kind, shot.take(length), seq[k + 1].take(length), rng))
                    gradual.append([n, n + length - 1])
                    n += length
            frames = np.clip(np.concatenate(parts) + 0.5, 0, 255).astype(np.uint8)
            annotation = {"frames": n, "hard_cuts": cuts, "gradual_transitions": gradual, "tolerance_frames": 2,
                          "gradual_tolerance_frames": 0, "kind": kind}
            samples.append(Sample(f"{split}-{kind}-{length}", frames, FPS, annotation))
    return samples
