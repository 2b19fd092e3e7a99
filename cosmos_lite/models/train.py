"""Train the world model: `cosmos-lite train experiment=wfm_nano data.roots=[DIR] tokenizer.path=DIR out=RUN`.

Post-train a specialist from a generalist with `trainer.init_from=RUN out=NEW_RUN` (add `trainer.lora_rank=8`
to train LoRA adapters only). Multi-process: `torchrun --nproc_per_node=N -m cosmos_lite.cli train ...` (gloo on
CPU, nccl on GPU); the global batch and every random draw are the same for any number of processes.
The run folder is a checkpoint (`WorldModelPipeline.from_pretrained(out)`), plus train_state.* for exact
resume (rerun the same command), log.jsonl (losses), val.jsonl and samples/ (validation clips).
"""

from __future__ import annotations

import copy
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from omegaconf import DictConfig, OmegaConf
from safetensors import safe_open
from safetensors.torch import load_file
from torch import nn
from torch.nn.parallel import DistributedDataParallel as DDP
from torch.utils.data.distributed import DistributedSampler

from ..config import setting, to_dataclass
from ..errors import ConfigError, InputError
from ..log import get_logger
from ..optim import adamw, ema_update
from ..sim.dataset import spread
from ..text import get_text_encoder
from ..tokenizers import load_tokenizer
from ..video import write_video
from .conditioning import Condition, make_condition
from .data import DataConfig, LatentWindows, action_scale
from .denoiser import Denoiser
from .lora import add_lora, merge_lora
from .pipeline import WorldModelPipeline, build_denoiser, save_atomic

log = get_logger("models.train")


@dataclass
class TrainerConfig:
    """Optimisation, schedule, checkpointing and hardware switches."""

    steps: int = setting(3000, low=1)
    max_minutes: float = setting(0.0, low=0)  # wall-clock budget (0: none); the schedule follows whichever ends first
    batch_size: int = setting(16, low=1)  # global, over all processes
    lr: float = setting(3e-4, above=0)
    min_lr: float = setting(3e-5, low=0)
    warmup: int = setting(100, low=0)
    weight_decay: float = setting(0.01, low=0)
    grad_clip: float = setting(1.0, above=0)
    ema_decay: float = setting(0.999, low=0, high=1)
    log_every: int = setting(10, low=1)
    ckpt_every: int = setting(200, low=1)
    val_every: int = setting(0, low=0)  # 0: only at the end
    val_clips: int = setting(4, low=1)
    val_steps: int = setting(10, low=1)  # sampler steps for validation clips
    init_from: str | None = None  # a world-model checkpoint to post-train from
    lora_rank: int = setting(0, low=0)  # > 0: train LoRA adapters only (with init_from)
    lora_alpha: float = setting(0.0, low=0)  # 0: = lora_rank
    compile: bool = False
    bf16: bool = False  # bf16 autocast (GPU)
    threads: int = 0  # torch CPU threads (0: torch's default)
    device: str = "auto"


@dataclass
class CondConfig:
    """Conditioning mix in training: k ~ U{0..max_given} given latent frames; each condition dropped with p."""

    max_given: int = setting(3, low=0)
    p_drop_text: float = setting(0.15, low=0, high=1)
    p_drop_actions: float = setting(0.15, low=0, high=1)


class EDMLoss(nn.Module):
    """The per-sample training loss as a module, so DistributedDataParallel sees it as `forward`."""

    def __init__(self, denoiser: Denoiser):
        super().__init__()
        self.denoiser = denoiser

    def forward(self, x0: torch.Tensor, cond: Condition, sigma: torch.Tensor, noise: torch.Tensor) -> torch.Tensor:
        return self.denoiser.loss(x0, cond, sigma, noise)


def lr_at(step: int, progress: float, t: TrainerConfig) -> float:
    """Linear warmup over `t.warmup` steps, then cosine decay to min_lr as `progress` (of the budget) goes 0 -> 1."""
    if step < t.warmup:
        return t.lr * (step + 1) / t.warmup
    return t.min_lr + 0.5 * (t.lr - t.min_lr) * (1 + math.cos(math.pi * min(progress, 1.0)))


def budget_progress(step: int, minutes: float, t: TrainerConfig, world: int) -> float:
    """Fraction of the budget used: steps or wall-clock minutes, whichever is further along (1 = stop). Under
    DDP the furthest process decides, so every process stops at the same step."""
    progress = max(step / t.steps, minutes / t.max_minutes if t.max_minutes else 0.0)
    if world > 1 and t.max_minutes:
        p = torch.tensor([progress])
        dist.all_reduce(p, op=dist.ReduceOp.MAX)
        progress = float(p)
    return progress


def draws(step: int, seed: int, n: int, shape: tuple[int, ...], denoiser: Denoiser, cc: CondConfig) -> dict:
    """Every random draw of one global batch, from (seed, step) alone: the same for any process count."""
    g = torch.Generator().manual_seed(seed * 1_000_003 + step)
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


def save_train_state(out: Path, step: int, minutes: float, model: nn.Module, ema: nn.Module,
                     opt: torch.optim.Optimizer) -> None:
    """Raw weights, EMA, AdamW moments, step and minutes trained in one safetensors file (no pickle), atomically, so
    a run killed at any moment resumes from a consistent state; train_state.json repeats step and minutes."""
    state = {f"model.{k}": v for k, v in model.state_dict().items()}
    state.update({f"ema.{k}": v for k, v in ema.state_dict().items()})
    for i, s in opt.state_dict()["state"].items():
        state.update({f"opt.{i}.{k}": torch.as_tensor(v) for k, v in s.items()})
    save_atomic(state, out / "train_state.safetensors", {"step": str(step), "minutes": str(minutes)})
    (out / "train_state.json.tmp").write_text(json.dumps({"step": step, "minutes": minutes}))
    (out / "train_state.json.tmp").replace(out / "train_state.json")


def load_train_state(out: Path, model: nn.Module, ema: nn.Module, opt: torch.optim.Optimizer) -> tuple[int, float]:
    """Restore what save_train_state wrote; returns the step to continue from and the minutes trained so far."""
    with safe_open(out / "train_state.safetensors", "pt") as f:  # runs saved before metadata: the JSON beside it
        meta = f.metadata() or json.loads((out / "train_state.json").read_text())
        state = {k: f.get_tensor(k) for k in f.keys()}
    model.load_state_dict({k[6:]: v for k, v in state.items() if k.startswith("model.")})
    ema.load_state_dict({k[4:]: v for k, v in state.items() if k.startswith("ema.")})
    opt_state: dict[int, dict] = {}
    for k, v in state.items():
        if k.startswith("opt."):
            _, i, name = k.split(".", 2)
            opt_state.setdefault(int(i), {})[name] = v
    opt.load_state_dict({"state": opt_state, "param_groups": opt.state_dict()["param_groups"]})
    return int(meta["step"]), float(meta["minutes"])


def setup_distributed(device_cfg: str) -> tuple[int, int, torch.device]:
    """rank, world size and device; joins the process group when launched by torchrun."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    cuda = torch.cuda.is_available() and device_cfg in ("auto", "cuda")
    if world > 1 and not dist.is_initialized():
        dist.init_process_group(backend="nccl" if cuda else "gloo")
    if cuda:
        local = int(os.environ.get("LOCAL_RANK", "0"))
        torch.cuda.set_device(local)
        return rank, world, torch.device("cuda", local)
    return rank, world, torch.device("cpu" if device_cfg == "auto" else device_cfg)


@torch.no_grad()
def validate(pipe: WorldModelPipeline, val: LatentWindows, t: TrainerConfig, step: int, out: Path) -> dict:
    """PSNR of clips generated from each validation window's first latent frames; writes one sample video."""
    from ..eval.metrics import psnr

    k = 1 + pipe.ct * (int(pipe.cfg.cond.max_given) - 1)
    scores = []
    for n, i in enumerate(spread(t.val_clips, len(val))):
        win = val.window(i)
        truth = win["video"]
        gen = pipe(prompt=win["caption"] or None, video=truth[:k],
                   actions=win["actions"].numpy() if win["has_masks"] else None, num_frames=len(truth),
                   steps=t.val_steps, seed=i).frames
        scores.append(psnr(gen[k:], truth[k:]))
        if n == 0:
            (out / "samples").mkdir(exist_ok=True)
            write_video(out / "samples" / f"step_{step:06d}.mp4", np.concatenate([truth, gen], axis=2), fps=val.cfg.fps)
    return {"step": step, "val_psnr": float(np.mean(scores)), "given_frames": k}


def main(cfg: DictConfig, args: list[str]) -> int:
    t = to_dataclass(TrainerConfig, cfg.trainer, "trainer")
    cc = to_dataclass(CondConfig, cfg.cond, "cond")
    dc = to_dataclass(DataConfig, cfg.data, "data")
    rank, world, device = setup_distributed(t.device)
    if t.threads:
        torch.set_num_threads(t.threads)
    if t.batch_size % world:
        raise ConfigError(f"trainer.batch_size={t.batch_size} must be divisible by the {world} processes")
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    parent = Path(t.init_from) if t.init_from else None
    if parent is not None:  # a specialist keeps the generalist's network, tokenizer and latent statistics
        if not (parent / "config.yaml").is_file():
            raise InputError(f"trainer.init_from={parent} has no config.yaml: pass a world-model checkpoint folder")
        OmegaConf.set_struct(cfg, False)
        cfg.model = OmegaConf.load(parent / "config.yaml").model
        OmegaConf.set_struct(cfg, True)
    tok_dir = parent / "tokenizer" if parent is not None else cfg.tokenizer.path
    if not tok_dir:
        raise ConfigError("set tokenizer.path=DIR (a trained tokenizer, `cosmos-lite train experiment=tokenizer_nano`)")
    tokenizer = load_tokenizer(tok_dir, device)
    ct = tokenizer.temporal_compression

    data = LatentWindows(dc.roots, tokenizer, dc)
    stats_src = parent if parent is not None else out if (out / "latent_stats.safetensors").is_file() else None
    if stats_src is not None:
        stats = load_file(stats_src / "latent_stats.safetensors")
    else:
        z = data.latents.transpose(0, 1).flatten(1)
        stats = {"mean": z.mean(1), "std": z.std(1).clamp(min=1e-4), "action_scale": action_scale(data)}
    mean, std = stats["mean"][:, None, None, None], stats["std"][:, None, None, None]
    text_encoder = get_text_encoder(cfg.text.path, int(cfg.text.max_length))

    torch.manual_seed(cfg.seed)
    denoiser = build_denoiser(cfg)
    if parent is not None:
        denoiser.net.load_state_dict(load_file(parent / "model.safetensors"))
    if t.lora_rank > 0:
        add_lora(denoiser.net, t.lora_rank, t.lora_alpha or None)
    denoiser.to(device)
    ema = copy.deepcopy(denoiser).requires_grad_(False).eval()
    params = [p for p in denoiser.parameters() if p.requires_grad]
    decay = [p for p in params if p.ndim >= 2]
    no_decay = [p for p in params if p.ndim < 2]
    opt = adamw([{"params": decay, "weight_decay": t.weight_decay}, {"params": no_decay, "weight_decay": 0.0}],
                device, lr=t.lr, betas=(0.9, 0.99))
    ema_params, all_params = list(ema.parameters()), list(denoiser.parameters())
    start, minutes = 0, 0.0
    if (out / "train_state.safetensors").is_file():
        start, minutes = load_train_state(out, denoiser, ema, opt)
        log.info("resumed %s at step %d (%.1f min)", out, start, minutes)
    loss_fn: nn.Module = EDMLoss(denoiser)
    if t.compile:
        loss_fn = torch.compile(loss_fn)
    if world > 1:
        loss_fn = DDP(loss_fn, device_ids=[device.index] if device.type == "cuda" else None)
    if rank == 0:
        log.info("world model %s: %.2fM params (%.2fM trainable), %d windows, %d process(es)",
                 denoiser.net.cfg.size, sum(p.numel() for p in denoiser.parameters()) / 1e6,
                 sum(p.numel() for p in params) / 1e6, len(data), world)
        save_checkpoint(out, cfg, ema, tokenizer, stats)
        log_path = out / "log.jsonl"  # drop lines past the resumed step, so the curve continues from it
        lines = log_path.read_text().splitlines() if log_path.is_file() else []
        log_path.write_text("".join(ln + "\n" for ln in lines if json.loads(ln)["step"] < start))
    val = LatentWindows(dc.val_roots, tokenizer, dc) if dc.val_roots and rank == 0 else None

    local = t.batch_size // world
    sampler = DistributedSampler(data, num_replicas=world, rank=rank, shuffle=True, seed=cfg.seed, drop_last=True)
    per_epoch = len(data) // t.batch_size
    if per_epoch == 0:
        raise ConfigError(f"trainer.batch_size={t.batch_size} exceeds the {len(data)} training windows")
    shape = tuple(data.latents.shape[1:])
    autocast = torch.autocast(device.type, dtype=torch.bfloat16, enabled=t.bf16 and device.type == "cuda")
    t0 = time.time() - 60 * minutes
    step, progress = start, budget_progress(start, minutes, t, world)
    while progress < 1:
        epoch, b = divmod(step, per_epoch)
        sampler.set_epoch(epoch)
        idx = list(sampler)[b * local : (b + 1) * local]
        items = [data[i] for i in idx]
        d = {k: v[rank::world] for k, v in draws(step, cfg.seed, t.batch_size, shape, denoiser, cc).items()}
        x0 = (torch.stack([it["latents"] for it in items]) - mean) / std
        cond = to_device(batch_condition(items, d, text_encoder, x0, ct, stats), device)
        lr = lr_at(step, progress, t)
        for group in opt.param_groups:
            group["lr"] = lr
        with autocast:
            loss = loss_fn(x0.to(device), cond, d["sigma"].to(device), d["noise"].to(device)).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        grad_norm = torch.nn.utils.clip_grad_norm_(params, t.grad_clip)
        opt.step()
        ema_update(ema_params, all_params, t.ema_decay, step)
        if world > 1:
            dist.all_reduce(loss.detach(), op=dist.ReduceOp.AVG)
        if rank == 0:
            with open(out / "log.jsonl", "a") as f:
                f.write(json.dumps({"step": step, "loss": loss.item(), "lr": lr, "grad_norm": grad_norm.item()}) + "\n")
        step += 1
        progress = budget_progress(step, (time.time() - t0) / 60, t, world)
        if rank == 0:
            if step % t.log_every == 0:
                log.info("step %d/%d loss %.4f lr %.2e (%.1f min)", step, t.steps, loss.item(), lr,
                         (time.time() - t0) / 60)
            if step % t.ckpt_every == 0 or progress >= 1:
                save_checkpoint(out, cfg, ema, tokenizer, stats)
                save_train_state(out, step, (time.time() - t0) / 60, denoiser, ema, opt)
            if val is not None and ((t.val_every and step % t.val_every == 0) or progress >= 1):
                pipe = WorldModelPipeline.from_pretrained(out, device)
                result = validate(pipe, val, t, step, out)
                log.info("validation at step %d: PSNR %.2f dB", step, result["val_psnr"])
                with open(out / "val.jsonl", "a") as f:
                    f.write(json.dumps(result) + "\n")
    if world > 1:
        dist.barrier()
    return 0


def save_checkpoint(out: Path, cfg: DictConfig, ema: Denoiser, tokenizer, stats: dict) -> None:
    """The loadable checkpoint: EMA weights (adapters merged into a plain DiT), config, tokenizer, stats."""
    net = merge_lora(copy.deepcopy(ema.net)).cpu()
    pipe = WorldModelPipeline(Denoiser(net, ema.cfg), tokenizer, cfg, stats)
    pipe.save_pretrained(out)
