"""Train a causal video tokenizer: `cosmos-lite train experiment=tokenizer_nano data.roots=[DIR] out=DIR`.

The task for the training engine (cosmos_lite.core.engine): L2 (or L1) + spatial-gradient (+ optional temporal-
difference) loss on random crops of training windows; the EMA weights are scored on held-out clips (PSNR/SSIM,
out/val.jsonl) and saved as the checkpoint (model.safetensors + config.yaml). Rerun the same command to resume;
`torchrun --nproc_per_node=N -m cosmos_lite.cli train ...` trains with DDP (same global batch for any N).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf

from ..config import bad, register, setting, to_dataclass
from ..core.dataset import spread
from ..core.engine import Batch, TrainerConfig, train
from ..core.metrics import moving
from ..errors import ConfigError, InputError
from .models import Tokenizer, TokenizerConfig


@dataclass
class DataConfig:
    """Clips come from simulator episodes or curated clips (`cosmos_lite.core.dataset.VideoWindows`)."""

    roots: list[str] = field(default_factory=list)
    val_roots: list[str] = field(default_factory=list)  # held-out episodes; empty: hold out every val_every-th video
    val_every: int = setting(10, low=0)
    num_frames: int = setting(17, low=1)
    stride: int = setting(4, low=1)  # training windows start every `stride` frames (held-out windows do not overlap)
    size: int | None = setting(None, low=8)  # resize on load (None: native size)
    crop: int = setting(64, low=0)  # random square crop for training (0: whole frame)
    val_clips: int = setting(16, low=1)  # held-out clips scored at each validation


@dataclass
class LossConfig:
    """The reconstruction loss (see reconstruction_loss)."""

    pixel: str = setting("l2", choices=("l2", "l1"))  # l1 let the encoder collapse to a constant latent on sim episodes
    grad_weight: float = setting(0.1, low=0)  # L1 on spatial finite differences (sharp edges)
    temporal_weight: float = setting(0.0, low=0)  # L1 on frame-to-frame differences (temporal consistency)
    moving_weight: float = setting(1.0, low=0)  # extra pixel-loss weight on moving pixels (core.metrics.moving)
    object_weight: float = setting(0.0, low=0)  # extra pixel-loss weight on pixels off the frame's median colour


register("data", "tokenizer", DataConfig)
register("loss", "reconstruction", LossConfig)


def reconstruction_loss(y: torch.Tensor, x: torch.Tensor, grad_weight: float, temporal_weight: float,
                        pixel: str = "l2", moving_weight: float = 0.0, object_weight: float = 0.0) -> torch.Tensor:
    """L2 (or L1) on pixels, plus L1 on spatial gradients and on temporal differences (no pretrained-network losses).
    L2 on pixels: with L1 the encoder's latents became nearly input-independent early in training on sim episodes
    (sign gradients from the flat background swamp the few object pixels). `moving_weight`: moving pixels (off the
    clip's temporal median, core.metrics.moving) weigh 1 + moving_weight times as much, normalised to each clip's
    mean weight (so the loss of a batch does not depend on how it is split over processes); small moving objects
    are a few percent of the pixels, and without it they come back dimmed and blurred. `object_weight` does the same
    for pixels off each frame's median colour: on a flat background these are the objects, the ones at rest too,
    which the temporal median counts as background."""
    if pixel not in ("l1", "l2"):
        raise ConfigError(f"loss.pixel={pixel!r}: choose l2 or l1")
    d = y - x
    e = d.square() if pixel == "l2" else d.abs()
    if moving_weight or object_weight:
        u = (x.transpose(1, 2) + 1) / 2
        w = torch.ones(u.shape[:2] + u.shape[3:], dtype=e.dtype, device=e.device)
        if moving_weight:
            w = w + moving_weight * moving(u)
        if object_weight:
            w = w + object_weight * moving(u, background=u.flatten(-2).median(-1).values[..., None, None])
        w = w.unsqueeze(1)
        loss = ((e * w).flatten(1).mean(1) / w.flatten(1).mean(1)).mean()
    else:
        loss = e.mean()
    if grad_weight:
        loss = loss + grad_weight * (d.diff(dim=-1).abs().mean() + d.diff(dim=-2).abs().mean())
    if temporal_weight and d.shape[2] > 1:
        loss = loss + temporal_weight * d.diff(dim=2).abs().mean()
    return loss


def make_datasets(cfg: DataConfig, ct: int):
    """(train, held-out) windows; without val_roots, every val_every-th video (not window) is held out."""
    from ..core.dataset import VideoWindows

    if not cfg.roots:
        raise ConfigError("no training data: pass data.roots=[DIR] (simulator episodes or curated clips)")
    if (cfg.num_frames - 1) % ct:
        raise ConfigError(f"data.num_frames={cfg.num_frames} must be 1 + k*{ct} for this tokenizer")
    train = VideoWindows(list(cfg.roots), cfg.num_frames, size=cfg.size, stride=cfg.stride)
    sizes = sorted({s.size for s in train.sources})
    if cfg.size is None and len(sizes) > 1:  # a batch stacks windows of one size
        raise bad("data.size", None, f"a size such as data.size=64: the videos under data.roots differ in size "
                  f"({', '.join(f'{h}x{w}' for h, w in sizes[:4])})")
    if cfg.val_roots:
        return train, VideoWindows(list(cfg.val_roots), cfg.num_frames, size=cfg.size)
    every = max(2, cfg.val_every)
    held = [k for k, (i, start) in enumerate(train.windows) if i % every == 0 and start % cfg.num_frames == 0]
    kept = [k for k, (i, _) in enumerate(train.windows) if i % every]
    if not held or not kept:
        raise InputError(f"{cfg.roots}: too few videos ({len(train.sources)}) to hold out every {every}th")
    return torch.utils.data.Subset(train, kept), torch.utils.data.Subset(train, held)


def random_crop(x: torch.Tensor, crop: int, cs: int, g: torch.Generator) -> torch.Tensor:
    """Random square crop (B,3,T,H,W) -> (B,3,T,c,c), c a multiple of the spatial compression."""
    h, w = x.shape[-2:]
    c = min(crop or max(h, w), h, w) // cs * cs
    i = int(torch.randint(0, h - c + 1, (1,), generator=g))
    j = int(torch.randint(0, w - c + 1, (1,), generator=g))
    return x[..., i : i + c, j : j + c]


@torch.no_grad()
def evaluate(model: Tokenizer, clips: list[torch.Tensor]) -> dict[str, float]:
    """Mean PSNR/SSIM (dB, [0,1]) and, for DV, codebook perplexity of the model's reconstructions of `clips`."""
    from ..core.metrics import psnr, ssim

    model.eval()
    ps, ss, indices = [], [], []
    for x in clips:
        if model.fsq is not None:
            z, idx = model.encode(x, return_indices=True)
            indices.append(idx.flatten())
        else:
            z = model.encode(x)
        y = model.decode(z).clamp(-1, 1)
        ps.append(psnr(y, x))
        ss.append(ssim(y, x))
    out = {"psnr": sum(ps) / len(ps), "ssim": sum(ss) / len(ss)}
    if indices:
        out.update(codebook_usage(torch.cat(indices), model.fsq.codebook_size))
    return out


def codebook_usage(indices: torch.Tensor, size: int) -> dict[str, float]:
    """Perplexity exp(H) of the token histogram and the fraction of codes used (FSQ has no dead-code collapse)."""
    counts = torch.bincount(indices, minlength=size).double()
    p = counts[counts > 0] / counts.sum()
    return {"perplexity": float(torch.exp(-(p * p.log()).sum())), "used": float((counts > 0).double().mean())}


class TokenizerTask:
    """The engine's task: the tokenizer, training windows and the reconstruction loss of a random crop."""

    def __init__(self, cfg: DictConfig, device: torch.device):
        self.tcfg = to_dataclass(TokenizerConfig, cfg.tokenizer, "tokenizer")
        self.dcfg = to_dataclass(DataConfig, cfg.data, "data")
        self.lcfg = to_dataclass(LossConfig, cfg.loss, "loss")
        self.device = device
        self.model = Tokenizer(self.tcfg)
        self.data, val_set = make_datasets(self.dcfg, self.model.temporal_compression)
        cs = self.cs = self.model.spatial_compression
        val = [val_set[i]["video"][None].to(device) for i in spread(self.dcfg.val_clips, len(val_set))]
        self.val = [v[..., : v.shape[-2] // cs * cs, : v.shape[-1] // cs * cs] for v in val]
        self.run_config = OmegaConf.to_container(cfg, resolve=True)
        self.run_config.pop("tokenizer")

    def loss(self, net: torch.nn.Module, items: list[dict], batch: Batch) -> torch.Tensor:
        x = torch.stack([it["video"] for it in items]).to(self.device)
        x = random_crop(x, self.dcfg.crop, self.cs, batch.generator())
        c = self.lcfg
        return reconstruction_loss(net(x), x, c.grad_weight, c.temporal_weight, c.pixel, c.moving_weight,
                                   c.object_weight)

    def save(self, ema: Tokenizer, out: Path) -> None:
        ema.save(out, extra=self.run_config)

    def validate(self, ema: Tokenizer, step: int, out: Path) -> dict[str, float]:
        return evaluate(ema, self.val)


def main(cfg: DictConfig, args: list[str]) -> int:
    trainer = to_dataclass(TrainerConfig, cfg.trainer, "trainer")
    train(lambda device: TokenizerTask(cfg, device), trainer, cfg.out, int(cfg.seed),
          OmegaConf.to_container(cfg, resolve=True))
    return 0
