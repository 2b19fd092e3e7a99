"""Training data for the world model: the simulator's VideoWindows (episodes and curated clips) encoded once
by the frozen tokenizer, kept with their per-frame actions and captions."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch.utils.data import Dataset

from ..config import setting
from ..errors import ConfigError
from ..log import progress
from ..sim.dataset import VideoWindows
from ..tokenizers import Tokenizer
from .pipeline import tensor_to_frames


@dataclass
class DataConfig:
    """Where clips are and how they are cut: windows of `num_frames` (1 + ct*k) every `stride` frames, every video
    resampled to `fps` (so episodes and curated clips share one time scale)."""

    roots: list[str] = field(default_factory=list)
    val_roots: list[str] = field(default_factory=list)
    num_frames: int = setting(25, low=1)
    stride: int = setting(4, low=1)
    fps: float = setting(16.0, above=0)
    height: int = setting(64, low=8)
    width: int = setting(64, low=8)


class LatentWindows(Dataset):
    """VideoWindows of every folder in `roots`, tokenised once; items are dicts of latents `(C, T', h, w)`,
    actions `(num_frames, A)`, has_actions, caption, fps and index."""

    def __init__(self, roots: list[str], tokenizer: Tokenizer, cfg: DataConfig, batch_size: int = 8):
        if not roots:
            raise ConfigError("data.roots is empty: set data.roots=[DIR,...] (folders from `cosmos-lite sim`)")
        ct = tokenizer.temporal_compression
        if (cfg.num_frames - 1) % ct:
            raise ConfigError(f"data.num_frames={cfg.num_frames} must be 1 + {ct}*k for this tokenizer")
        self.cfg = cfg
        self.videos = VideoWindows(roots, cfg.num_frames, size=(cfg.height, cfg.width), stride=cfg.stride,
                                   fps=cfg.fps)
        self.items: list[dict] = []
        latents = []
        device = next(tokenizer.parameters()).device
        for s in progress(range(0, len(self.videos), batch_size), desc="tokenising windows"):
            batch = [self.videos[i] for i in range(s, min(s + batch_size, len(self.videos)))]
            with torch.no_grad():
                latents.append(tokenizer.encode(torch.stack([b["video"] for b in batch]).to(device)).float().cpu())
            self.items += [dict(actions=b["actions"], has_actions=bool(b["has_masks"]), caption=b["caption"],
                                name=b["name"], start=b["start"]) for b in batch]
        self.latents = torch.cat(latents)

    def window(self, i: int) -> dict:
        """Window i in pixels: video uint8 `(T, H, W, 3)`, masks `(T, H, W)` and the rest of its item."""
        item = self.videos[i]
        return {**item, "video": tensor_to_frames(item["video"]), "masks": item["masks"].numpy()}

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, i: int) -> dict:
        return dict(latents=self.latents[i], fps=self.cfg.fps, index=i, **self.items[i])


def action_scale(data: LatentWindows) -> torch.Tensor:
    """Per-dimension std of the training actions (1 where there are none), so the network sees unit scale."""
    acts = [it["actions"] for it in data.items if it["has_actions"]]
    if not acts:
        return torch.ones(data.items[0]["actions"].shape[-1])
    std = torch.cat(acts).std(0)
    return torch.where(std > 1e-6, std, torch.ones_like(std))
