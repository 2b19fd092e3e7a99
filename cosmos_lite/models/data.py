"""Training data for the world model: the VideoWindows of episodes and curated clips, encoded once by the frozen
tokenizer, kept with their per-frame actions and captions. An item is one prediction: frame t of window w from
the frames before it."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch.utils.data import Dataset

from ..config import setting
from ..core.dataset import VideoWindows
from ..core.frames import to_frames
from ..errors import ConfigError
from ..log import progress
from ..tokenizers import Tokenizer


@dataclass
class DataConfig:
    """Where clips are and how they are cut: windows of `num_frames` every `stride` frames, every video resampled
    to `fps` (so episodes and curated clips share one time scale)."""

    roots: list[str] = field(default_factory=list)
    val_roots: list[str] = field(default_factory=list)
    num_frames: int = setting(33, low=1)
    stride: int = setting(16, low=1)
    fps: float = setting(16.0, above=0)
    height: int = setting(64, low=8)
    width: int = setting(64, low=8)
    val_clips: int = setting(4, low=1)  # windows of val_roots generated and scored at each validation


class LatentClips(Dataset):
    """VideoWindows of every folder in `roots`, tokenised once into `latents (N, T, C, h, w)` with `actions
    (N, T, A)`, `has_actions (N,)` and `captions`; item i is the pair (window i // T, frame i % T)."""

    def __init__(self, roots: list[str], tokenizer: Tokenizer, cfg: DataConfig, batch_size: int = 8):
        if not roots:
            raise ConfigError("data.roots is empty: set data.roots=[DIR,...] (folders from `cosmos-lite sim`)")
        if tokenizer.temporal_compression != 1:
            raise ConfigError(f"the world model predicts one latent frame per pixel frame; tokenizer "
                              f"{tokenizer.cfg.variant} compresses time {tokenizer.temporal_compression}x "
                              "(train one with experiment=tokenizer_sim)")
        self.cfg = cfg
        self.videos = VideoWindows(roots, cfg.num_frames, size=(cfg.height, cfg.width), stride=cfg.stride,
                                   fps=cfg.fps)
        latents, actions, has_actions, self.captions = [], [], [], []
        device = next(tokenizer.parameters()).device
        for s in progress(range(0, len(self.videos), batch_size), desc="tokenising windows"):
            batch = [self.videos[i] for i in range(s, min(s + batch_size, len(self.videos)))]
            with torch.no_grad():
                z = tokenizer.encode(torch.stack([b["video"] for b in batch]).to(device)).float().cpu()
            latents.append(z.transpose(1, 2))
            actions += [b["actions"] for b in batch]
            has_actions += [bool(b["has_masks"]) for b in batch]
            self.captions += [b["caption"] for b in batch]
        self.latents = torch.cat(latents)
        self.actions = torch.stack(actions)
        self.has_actions = torch.tensor(has_actions)

    def window(self, w: int) -> dict:
        """Window w in pixels: video uint8 `(T, H, W, 3)`, masks `(T, H, W)`, actions, caption, ..."""
        item = self.videos[w]
        return {**item, "video": to_frames(item["video"]), "masks": item["masks"].numpy()}

    def __len__(self) -> int:
        return self.latents.shape[0] * self.latents.shape[1]

    def __getitem__(self, i: int) -> tuple[int, int]:
        return divmod(i, self.latents.shape[1])

    def action_scale(self) -> torch.Tensor:
        """Per-dimension std of the training actions (1 where there are none), so the network sees unit scale."""
        if not self.has_actions.any():
            return torch.ones(self.actions.shape[-1])
        std = self.actions[self.has_actions].flatten(0, 1).std(0)
        return torch.where(std > 1e-6, std, torch.ones_like(std))
