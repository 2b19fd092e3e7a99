"""Fixed-length training windows from folders of simulated episodes and curated clips, as a torch Dataset.

A folder may hold episodes (NAME.mp4 + NAME.npz + NAME.json, as `cosmos-lite sim` writes them) and/or curated
clips (clips/<id>.mp4 + metas/<id>.json, as `cosmos-lite curate` writes them). Clips have no masks or actions
(zeros, has_masks False) and count as split "id".
"""

from __future__ import annotations

import json
import os
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from ..errors import InputError
from ..log import get_logger
from ..sim.episode import read_arrays, read_meta
from ..video import probe, read_frames
from .frames import to_tensor

log = get_logger("core.dataset")


@dataclass(frozen=True)
class Source:
    """One video the windows are cut from."""

    name: str
    video: Path
    episode: bool  # True: NAME.npz holds masks and actions
    caption: str
    num_frames: int  # at its own rate
    fps: float
    split: str
    size: tuple[int, int]  # (H, W) as stored


def _episodes(root: Path) -> list[Source]:
    out = []
    for meta_path in sorted(root.glob("*.json")):
        stem = meta_path.with_suffix("")
        if not (stem.with_suffix(".mp4").is_file() and stem.with_suffix(".npz").is_file()):
            continue  # index.json, summary.json, or an unfinished episode
        meta = read_meta(stem)
        out.append(Source(stem.name, stem.with_suffix(".mp4"), True, meta.get("caption", ""), int(meta["frames"]),
                          float(meta["fps"]), meta.get("split", "id"), tuple(meta["size"])))
    return out


def _clips(root: Path) -> list[Source]:
    out = []
    for meta_path in sorted((root / "metas").glob("*.json")):
        clip = root / "clips" / f"{meta_path.stem}.mp4"
        if not clip.is_file():
            continue  # a dropped clip keeps its meta (why it was dropped) but has no video
        try:
            meta = json.loads(meta_path.read_text())
        except json.JSONDecodeError as e:
            raise InputError(f"{meta_path}: not valid JSON ({e}); re-run `cosmos-lite curate`") from None
        info = probe(clip)
        out.append(Source(meta_path.stem, clip, False, meta.get("caption", ""), info.num_frames, info.fps,
                          meta.get("split", "id"), info.size))
    return out


def spread(n: int, total: int) -> list[int]:
    """`n` indices spread evenly over `range(total)` (all of them when total <= n): validation windows drawn from
    every held-out video, not only the first few in file order (one scenario, for sorted episode names)."""
    if total <= n:
        return list(range(total))
    return [round(i * (total - 1) / max(1, n - 1)) for i in range(n)]


class VideoWindows(Dataset):
    """Windows of `num_frames` frames every `stride` frames (default: non-overlapping) from episodes and clips.

    Items: video float32 (3, T, H, W) in [-1, 1], actions float32 (T, 2) (pixels/s at the served size), caption,
    masks uint8 (T, H, W), has_masks, name, start, fps. size: (H, W) or int to resize to; fps: resample every
    video to this rate (nearest frame), else each plays at its own; split: keep only "id"/"ood".
    Whole videos up to `cache_mb` in total stay decoded in memory (small episodes are decoded once).
    """

    def __init__(
        self,
        roots: str | os.PathLike | list[str | os.PathLike],
        num_frames: int,
        size: int | tuple[int, int] | None = None,
        stride: int | None = None,
        split: str | None = None,
        cache_mb: float = 1024.0,
        fps: float | None = None,
    ):
        roots = [roots] if isinstance(roots, str | os.PathLike) else list(roots)
        self.num_frames, self.stride = int(num_frames), int(stride or num_frames)
        self.size = (size, size) if isinstance(size, int) else tuple(size) if size is not None else None
        self.fps = float(fps) if fps else None
        sources = []
        for root in map(Path, roots):
            if not root.is_dir():
                raise InputError(f"{root}: no such folder; pass folders written by `cosmos-lite sim` or `curate`")
            found = _episodes(root) + _clips(root)
            if not found:
                raise InputError(f"{root}: no episodes (NAME.mp4/.npz/.json) or clips (clips/, metas/) found")
            sources += found
        self.sources = [s for s in sources if split is None or s.split == split]
        short = [s.name for s in self.sources if self._length(s) < self.num_frames]
        if short:
            log.warning("skipping %d videos shorter than %d frames (e.g. %s)", len(short), self.num_frames, short[0])
        self.windows = [(i, start) for i, s in enumerate(self.sources)
                        for start in range(0, self._length(s) - self.num_frames + 1, self.stride)]
        if not self.windows:
            raise InputError(f"{', '.join(map(str, roots))}: no window of {num_frames} frames (split={split})")
        self.cache_bytes = int(cache_mb * 2**20)
        self._cache: OrderedDict[int, np.ndarray] = OrderedDict()

    def _length(self, src: Source) -> int:
        """Frames served from `src`: its own count, or the slots at self.fps before its last frame's time."""
        return src.num_frames if self.fps is None else int((src.num_frames - 1) * self.fps / src.fps) + 1

    def _source_index(self, src: Source, start: int) -> np.ndarray:
        """Indices of the source frames that served frames start.. come from (nearest in time)."""
        k = np.arange(start, start + self.num_frames)
        return k if self.fps is None else np.minimum(np.floor(k * src.fps / self.fps + 0.5).astype(int),
                                                     src.num_frames - 1)

    def __len__(self) -> int:
        return len(self.windows)

    def _frames(self, i: int, start: int) -> np.ndarray:
        src, end = self.sources[i], start + self.num_frames
        if i in self._cache:
            self._cache.move_to_end(i)
            return self._cache[i][start:end]
        h, w = self.size or probe(src.video).size
        if src.num_frames * h * w * 3 > self.cache_bytes:
            return read_frames(src.video, start, end, self.size, self.fps)
        video = read_frames(src.video, size=self.size, fps=self.fps)
        self._cache[i] = video
        while sum(v.nbytes for v in self._cache.values()) > self.cache_bytes:
            self._cache.popitem(last=False)
        return video[start:end]

    def __getitem__(self, index: int) -> dict:
        i, start = self.windows[index]
        src = self.sources[i]
        frames = self._frames(i, start)
        t, h, w = frames.shape[:3]
        masks = np.zeros((t, h, w), np.uint8)
        actions = np.zeros((t, 2), np.float32)
        if src.episode:
            arrays = read_arrays(src.video)
            idx = self._source_index(src, start)
            m = arrays["masks"][idx]
            rows = ((np.arange(h) + 0.5) * m.shape[1] / h).astype(int)  # nearest-neighbour resize
            cols = ((np.arange(w) + 0.5) * m.shape[2] / w).astype(int)
            masks = np.ascontiguousarray(m[:, rows][:, :, cols])
            actions = arrays["actions"][idx] * np.array([w / m.shape[2], h / m.shape[1]], np.float32)
        return {
            "video": to_tensor(frames)[0],
            "actions": torch.from_numpy(np.ascontiguousarray(actions, np.float32)),
            "caption": src.caption,
            "masks": torch.from_numpy(masks),
            "has_masks": src.episode,
            "name": src.name,
            "start": start,
            "fps": self.fps or src.fps,
        }
