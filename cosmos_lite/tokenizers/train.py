"""Train a causal video tokenizer: `cosmos-lite train experiment=tokenizer_nano data.roots=[DIR] out=DIR`.

A loop you can read in one sitting (nanoGPT style): L2 (or L1) + spatial-gradient (+ optional temporal-difference) loss,
AdamW with warmup and a cosine decay over whichever of trainer.max_steps / trainer.max_minutes ends first, EMA
weights that are evaluated on held-out clips (PSNR/SSIM) and saved as the checkpoint (model.safetensors +
config.yaml); rerunning with the same out= resumes from train_state.safetensors. Under torchrun it trains with DDP.
"""

from __future__ import annotations

import copy
import json
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf
from safetensors.torch import load_file, save_file

from ..config import bad, setting, to_dataclass
from ..errors import ConfigError, InputError
from ..eval.metrics import moving
from ..log import get_logger
from ..optim import adamw, ema_update
from ..sim.dataset import spread
from .models import Tokenizer, TokenizerConfig

log = get_logger("tokenizers.train")


@dataclass
class DataConfig:
    """Clips come from simulator episodes or curated clips (`cosmos_lite.sim.dataset.VideoWindows`)."""

    roots: list[str] = field(default_factory=list)
    val_roots: list[str] = field(default_factory=list)  # held-out episodes; empty: hold out every val_every-th video
    val_every: int = setting(10, low=0)
    num_frames: int = setting(17, low=1)
    stride: int = setting(4, low=1)  # training windows start every `stride` frames (held-out windows do not overlap)
    size: int | None = setting(None, low=8)  # resize on load (None: native size)
    crop: int = setting(64, low=0)  # random square crop for training (0: whole frame)
    val_clips: int = setting(16, low=1)


@dataclass
class OptimConfig:
    lr: float = setting(1e-3, above=0)
    min_lr: float = setting(2e-5, low=0)
    weight_decay: float = 0.01
    betas: list[float] = field(default_factory=lambda: [0.9, 0.99])
    warmup: int = 100
    grad_clip: float = 1.0


@dataclass
class TrainerConfig:
    max_steps: int = setting(2000, low=1)
    max_minutes: float = setting(0.0, low=0)  # wall-clock budget (0: none); the cosine follows whichever ends first
    batch_size: int = setting(4, low=1)
    ema: float = setting(0.999, low=0, high=1)
    pixel_loss: str = setting("l2", choices=("l2", "l1"))  # l1 let the encoder collapse to a constant latent on sim
    grad_weight: float = 0.1  # L1 on spatial finite differences (sharp edges)
    temporal_weight: float = 0.0  # L1 on frame-to-frame differences (temporal consistency)
    moving_weight: float = 0.0  # extra pixel-loss weight on moving pixels (eval.metrics.moving)
    log_every: int = setting(25, low=1)
    eval_every: int = setting(250, low=1)
    resume: bool = True
    compile: bool = False
    threads: int = 0  # torch CPU threads (0: torch's default)
    device: str = "auto"


def reconstruction_loss(y: torch.Tensor, x: torch.Tensor, grad_weight: float, temporal_weight: float,
                        pixel: str = "l2", moving_weight: float = 0.0) -> torch.Tensor:
    """L2 (or L1) on pixels, plus L1 on spatial gradients and on temporal differences (no pretrained-network losses).
    L2 on pixels: with L1 the encoder's latents became nearly input-independent early in training on sim episodes
    (sign gradients from the flat background swamp the few object pixels). `moving_weight`: moving pixels (off the
    clip's temporal median, eval.metrics.moving) weigh 1 + moving_weight times as much, normalised to the mean
    weight; small moving objects are a few percent of the pixels, and without it they come back dimmed and blurred."""
    if pixel not in ("l1", "l2"):
        raise ConfigError(f"trainer.pixel_loss={pixel!r}: choose l2 or l1")
    d = y - x
    e = d.square() if pixel == "l2" else d.abs()
    if moving_weight:
        w = 1 + moving_weight * moving((x.transpose(1, 2) + 1) / 2).unsqueeze(1).to(e.dtype)
        loss = (e * w).mean() / w.mean()
    else:
        loss = e.mean()
    if grad_weight:
        loss = loss + grad_weight * (d.diff(dim=-1).abs().mean() + d.diff(dim=-2).abs().mean())
    if temporal_weight and d.shape[2] > 1:
        loss = loss + temporal_weight * d.diff(dim=2).abs().mean()
    return loss


def lr_at(progress: float, step: int, opt: OptimConfig) -> float:
    """Linear warmup over `opt.warmup` steps, then cosine from lr to min_lr as progress goes 0 -> 1."""
    if step < opt.warmup:
        return opt.lr * (step + 1) / opt.warmup
    return opt.min_lr + 0.5 * (opt.lr - opt.min_lr) * (1 + math.cos(math.pi * min(progress, 1.0)))


def make_datasets(cfg: DataConfig, ct: int):
    """(train, held-out) windows; without val_roots, every val_every-th video (not window) is held out."""
    from ..sim.dataset import VideoWindows

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
    from ..eval.metrics import psnr, ssim

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


def save_state(path: Path, model: torch.nn.Module, opt: torch.optim.Optimizer, step: int, elapsed: float) -> None:
    """Raw weights + AdamW state as safetensors (no pickle), via a temp file."""
    tensors = {f"model.{k}": v.contiguous() for k, v in model.state_dict().items()}
    sd = opt.state_dict()
    for i, st in sd["state"].items():
        tensors.update({f"optim.{i}.{k}": torch.as_tensor(v).contiguous() for k, v in st.items()})
    meta = {"step": str(step), "elapsed": str(elapsed), "param_groups": json.dumps(sd["param_groups"])}
    save_file(tensors, path.with_suffix(".tmp"), metadata=meta)
    path.with_suffix(".tmp").replace(path)


def load_state(path: Path, model: torch.nn.Module, opt: torch.optim.Optimizer) -> tuple[int, float]:
    from safetensors import safe_open

    with safe_open(path, "pt") as f:
        meta = f.metadata()
    tensors = load_file(path)
    model.load_state_dict({k[6:]: v for k, v in tensors.items() if k.startswith("model.")})
    state: dict[int, dict] = {}
    for k, v in tensors.items():
        if k.startswith("optim."):
            _, i, name = k.split(".", 2)
            state.setdefault(int(i), {})[name] = v
    opt.load_state_dict({"state": state, "param_groups": json.loads(meta["param_groups"])})
    return int(meta["step"]), float(meta["elapsed"])


def main(cfg: DictConfig, args: list[str]) -> int:
    tcfg = to_dataclass(TokenizerConfig, cfg.tokenizer, "tokenizer")
    data = to_dataclass(DataConfig, cfg.data, "data")
    opt_cfg = to_dataclass(OptimConfig, cfg.optim, "optim")
    tr = to_dataclass(TrainerConfig, cfg.trainer, "trainer")
    out = Path(cfg.out)
    ddp = "RANK" in os.environ
    if ddp:  # torchrun: one process per device, gradients all-reduced
        torch.distributed.init_process_group("nccl" if torch.cuda.is_available() else "gloo")
    rank, world = (torch.distributed.get_rank(), torch.distributed.get_world_size()) if ddp else (0, 1)
    device = torch.device(
        (f"cuda:{rank % torch.cuda.device_count()}" if torch.cuda.is_available() else "cpu")
        if tr.device == "auto"
        else tr.device
    )
    if tr.threads:
        torch.set_num_threads(tr.threads)
    torch.manual_seed(cfg.seed + rank)

    model = Tokenizer(tcfg).to(device)
    ema = copy.deepcopy(model).requires_grad_(False)
    params, ema_params = list(model.parameters()), list(ema.parameters())
    opt = adamw(params, device, lr=opt_cfg.lr, betas=tuple(opt_cfg.betas), weight_decay=opt_cfg.weight_decay)
    step, elapsed = 0, 0.0
    state_path = out / "train_state.safetensors"
    if tr.resume and state_path.is_file():
        step, elapsed = load_state(state_path, model, opt)
        ema.load_state_dict(load_file(out / "model.safetensors"))
        log.info("resumed %s at step %d (%.1f min)", out, step, elapsed / 60)
    train_set, val_set = make_datasets(data, model.temporal_compression)
    g = torch.Generator().manual_seed(cfg.seed * 1000 + step)
    val = [val_set[i]["video"][None].to(device) for i in spread(data.val_clips, len(val_set))]
    cs = model.spatial_compression
    val = [v[..., : v.shape[-2] // cs * cs, : v.shape[-1] // cs * cs] for v in val]
    sampler = torch.utils.data.DistributedSampler(train_set, seed=cfg.seed + step) if ddp else None
    loader = torch.utils.data.DataLoader(train_set, batch_size=tr.batch_size, sampler=sampler,
                                         shuffle=sampler is None, generator=g, drop_last=True, num_workers=0)
    if len(loader) == 0:  # drop_last: no full batch, so the loop would never step
        raise bad("trainer.batch_size", tr.batch_size, f"at most the {len(train_set)} training windows")
    net = torch.nn.parallel.DistributedDataParallel(model) if ddp else model
    net = torch.compile(net) if tr.compile else net
    log.info("tokenizer %s/%s: %.2fM params, %d train / %d held-out clips, out=%s", tcfg.variant, tcfg.size,
             sum(p.numel() for p in model.parameters()) / 1e6, len(train_set), len(val), out)

    run_cfg = OmegaConf.to_container(cfg, resolve=True)
    run_cfg.pop("tokenizer")
    metrics_log = out / "metrics.jsonl"
    t0 = time.time() - elapsed
    done = step >= tr.max_steps
    while not done:
        for batch in loader:
            x = random_crop(batch["video"].to(device), data.crop, cs, g)
            progress = max(step / tr.max_steps, (time.time() - t0) / 60 / tr.max_minutes if tr.max_minutes else 0)
            lr = lr_at(progress, step, opt_cfg)
            for group in opt.param_groups:
                group["lr"] = lr
            model.train()
            loss = reconstruction_loss(net(x), x, tr.grad_weight, tr.temporal_weight, tr.pixel_loss, tr.moving_weight)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(params, opt_cfg.grad_clip)
            opt.step()
            ema_update(ema_params, params, tr.ema, step)
            step += 1
            done = step >= tr.max_steps or progress >= 1
            if rank == 0 and (step % tr.log_every == 0 or step == 1):
                log.info("step %d loss %.4f lr %.2e (%.1f min)", step, loss.item(), lr, (time.time() - t0) / 60)
            if rank == 0 and (step % tr.eval_every == 0 or done):
                record = {"step": step, "loss": loss.item(), "minutes": (time.time() - t0) / 60, **evaluate(ema, val)}
                log.info("held-out: %s", " ".join(f"{k} {v:.4g}" for k, v in record.items()))
                ema.save(out, extra=run_cfg)
                save_state(state_path, model, opt, step, time.time() - t0)
                with metrics_log.open("a") as f:
                    f.write(json.dumps(record) + "\n")
            if done:
                break
    if ddp:
        torch.distributed.destroy_process_group()
    return 0
