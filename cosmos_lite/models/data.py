"""Training data for the world model: fixed-length windows of clips (simulator episodes or curated clips),
encoded once by the frozen tokenizer, with their per-frame actions and captions."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import Dataset

from ..errors import ConfigError, InputError
from ..log import progress
from ..tokenizers import Tokenizer
from ..video import probe, read_frames


@dataclass
class DataConfig:
    """Where clips are and how they are cut: windows of `num_frames` (1 + ct*k) every `stride` frames."""

    roots: list[str] = field(default_factory=list)
    val_roots: list[str] = field(default_factory=list)
    num_frames: int = 25
    stride: int = 4
    fps: float = 16.0
    height: int = 64
    width: int = 64
    action_dim: int = 2


def find_clips(roots: list[str]) -> list[Path]:
    """All .mp4 files under the given folders, sorted (so every process sees the same order)."""
    clips = []
    for root in roots:
        r = Path(root)
        if not r.is_dir():
            raise ConfigError(f"data root {r} is not a folder; write episodes with `cosmos-lite sim out={r}` "
                              "or clips with `cosmos-lite curate`")
        clips += sorted(r.rglob("*.mp4"))
    return clips


def clip_meta(path: Path) -> dict:
    """A clip's metadata: NAME.json beside a simulator episode, or metas/NAME.json for a curated clip."""
    for meta in (path.with_suffix(".json"), path.parent.parent / "metas" / f"{path.stem}.json"):
        if meta.is_file():
            return json.loads(meta.read_text())
    return {}


def clip_actions(path: Path, action_dim: int) -> np.ndarray | None:
    """Per-frame actions `(T, A)` from NAME.npz beside the clip, if it has them."""
    npz = path.with_suffix(".npz")
    if not npz.is_file():
        return None
    with np.load(npz) as f:
        if "actions" not in f:
            return None
        actions = f["actions"].astype(np.float32)
    if actions.ndim != 2 or actions.shape[1] != action_dim:
        raise InputError(f"{npz}: actions have shape {actions.shape}; the model expects (T, {action_dim}) "
                         f"(set data.action_dim)")
    return actions


class LatentWindows(Dataset):
    """Windows of every clip under `roots`, tokenised once; items are dicts of latents `(C, T', h, w)`,
    actions `(num_frames, A)`, has_actions, caption, fps, and where the window came from."""

    def __init__(self, roots: list[str], tokenizer: Tokenizer, cfg: DataConfig, batch_size: int = 8):
        self.cfg = cfg
        ct = tokenizer.temporal_compression
        if (cfg.num_frames - 1) % ct:
            raise ConfigError(f"data.num_frames={cfg.num_frames} must be 1 + {ct}*k for this tokenizer")
        self.items: list[dict] = []
        for path in find_clips(roots):
            n = probe(path).num_frames
            actions, meta = clip_actions(path, cfg.action_dim), clip_meta(path)
            for start in range(0, n - cfg.num_frames + 1, cfg.stride):
                acts = np.zeros((cfg.num_frames, cfg.action_dim), np.float32)
                if actions is not None:
                    chunk = actions[start : start + cfg.num_frames]
                    acts[: len(chunk)] = chunk
                self.items.append(dict(path=str(path), start=start, actions=torch.from_numpy(acts),
                                       has_actions=actions is not None, caption=str(meta.get("caption", "")),
                                       fps=float(meta.get("fps", cfg.fps))))
        if not self.items:
            raise InputError(f"no clip of at least {cfg.num_frames} frames under {', '.join(roots)}")
        self.latents = self._encode(tokenizer, batch_size)

    def window(self, i: int) -> np.ndarray:
        """The pixel frames of window i, uint8 `(T, H, W, 3)`."""
        it = self.items[i]
        return read_frames(it["path"], it["start"], it["start"] + self.cfg.num_frames,
                           size=(self.cfg.height, self.cfg.width))

    @torch.no_grad()
    def _encode(self, tokenizer: Tokenizer, batch_size: int) -> torch.Tensor:
        device = next(tokenizer.parameters()).device
        out = []
        for s in progress(range(0, len(self.items), batch_size), desc="tokenising windows"):
            frames = np.stack([self.window(i) for i in range(s, min(s + batch_size, len(self.items)))])
            x = torch.from_numpy(frames).permute(0, 4, 1, 2, 3).float().div(127.5).sub(1).to(device)
            out.append(tokenizer.encode(x).float().cpu())
        return torch.cat(out)

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, i: int) -> dict:
        it = self.items[i]
        return dict(latents=self.latents[i], actions=it["actions"], has_actions=it["has_actions"],
                    caption=it["caption"], fps=it["fps"], index=i)
