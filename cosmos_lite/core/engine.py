"""The one training engine (nanoGPT's train.py in spirit): every task (tokenizer, world model, frame classifier,
semantic guard) hands it a model, a dataset and `batch -> loss`; the engine owns the loop.

The task interface (duck-typed; see `Task`):

    model: nn.Module       trained; its parameters with requires_grad are optimised (AdamW, decay on matrices only)
                           and an EMA copy of all of them is kept; DDP wraps it, so `loss` must call `net(...)`
    data: Dataset          items of any kind; the engine draws the global batch and hands each process its share
    loss(net, items, batch) -> Tensor    the scalar loss of this process's `items`; `net` is the (DDP/compiled)
                           model to call; `batch` (a `Batch`) gives the step, the global batch size, this process's
                           rows of it and `batch.generator()`, seeded by (seed, step) alone, for random draws that
                           must be the same for any number of processes (draw for all `batch.size` rows, keep
                           `[batch.rows]`)
    save(ema, out)         optional: write the loadable checkpoint from the EMA model (rank 0, at each save)
    validate(ema, step, out) -> dict   optional: held-out metrics, appended to out/val.jsonl after each save
    param_groups() -> list[dict]       optional: AdamW groups instead of the default; a group's `lr_scale`
                           multiplies the scheduled learning rate

The loop: DDP under torchrun (gloo on CPU, nccl on GPU, LOCAL_RANK picks the GPU), the global batch
`trainer.batch_size` split over the processes (DistributedSampler, set_epoch each epoch), linear warmup then a cosine
decay over whichever of `trainer.steps` / `trainer.max_minutes` ends first (the processes agree on the wall clock
by all-reduce, so all stop at the same step), gradient clipping, EMA with a warm-up decay, logging to out/log.jsonl.
Every `trainer.ckpt_every` steps and at the end it writes out/train_state.safetensors: weights, EMA, AdamW moments,
step, minutes and the run config in one file, atomically, so a run killed at any moment resumes exactly (the global
RNG is reseeded from (seed, step, rank) every step, so no RNG state needs saving). Rerunning the same command
resumes; a run folder trained with a different config is refused (exit 2) unless trainer.resume=false.
"""

from __future__ import annotations

import copy
import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import torch
import torch.distributed as dist
from safetensors import safe_open
from safetensors.torch import save_file
from torch import Tensor, nn
from torch.utils.data import Dataset, DistributedSampler

from ..config import bad, register, setting
from ..errors import ConfigError
from ..files import atomic_path
from ..log import get_logger

log = get_logger("core.engine")
STATE = "train_state.safetensors"
# Keys that may change when a run is resumed: the budget (to extend a run), logging, hardware.
RESUMABLE = {"out", "trainer.steps", "trainer.epochs", "trainer.max_minutes", "trainer.log_every",
             "trainer.ckpt_every", "trainer.val_every", "trainer.resume", "trainer.compile", "trainer.threads",
             "trainer.device"}


@dataclass
class TrainerConfig:
    """Optimisation, schedule, checkpointing and hardware: the same keys for every task (`trainer.*`)."""

    steps: int = setting(1000, low=1)
    epochs: int = setting(0, low=0)  # > 0: train this many passes over the data instead of `steps`
    max_minutes: float = setting(0.0, low=0)  # wall-clock budget (0: none); the schedule follows whichever ends first
    batch_size: int = setting(16, low=1)  # global, over all processes
    lr: float = setting(3e-4, above=0)
    min_lr: float = setting(3e-5, low=0)
    warmup: int = setting(100, low=0)
    weight_decay: float = setting(0.01, low=0)  # on weight matrices only
    betas: list[float] = field(default_factory=lambda: [0.9, 0.99])
    grad_clip: float = setting(1.0, low=0)  # max gradient norm (0: no clipping)
    ema_decay: float = setting(0.999, low=0, high=1)  # 0: the EMA is the weights themselves
    log_every: int = setting(10, low=0)
    ckpt_every: int = setting(200, low=0)
    val_every: int = setting(0, low=0)  # validate at every this many steps (0: only at the end)
    resume: bool = True  # false: start over in an existing run folder
    compile: bool = False
    bf16: bool = False  # bf16 autocast
    threads: int = setting(0, low=0)  # torch CPU threads (0: torch's default)
    device: str = "auto"


register("trainer", "base", TrainerConfig)


@dataclass
class Batch:
    """Where a process's items sit in the global batch of one step."""

    step: int
    size: int  # the global batch size
    rows: slice  # this process's rows of the global batch
    seed: int

    def generator(self) -> torch.Generator:
        """A generator seeded by (seed, step) alone: draws from it are the same in every process."""
        return torch.Generator().manual_seed(self.seed * 1_000_003 + self.step)


class Task(Protocol):
    model: nn.Module
    data: Dataset

    def loss(self, net: nn.Module, items: list, batch: Batch) -> Tensor: ...


def setup(cfg: TrainerConfig) -> tuple[int, int, torch.device]:
    """Rank, world size and device; joins the process group when launched by torchrun."""
    world, rank = int(os.environ.get("WORLD_SIZE", "1")), int(os.environ.get("RANK", "0"))
    cuda = torch.cuda.is_available() and cfg.device in ("auto", "cuda")
    if world > 1 and not dist.is_initialized():
        dist.init_process_group(backend="nccl" if cuda else "gloo")
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    if cuda:
        local = int(os.environ.get("LOCAL_RANK", "0"))
        torch.cuda.set_device(local)
        return rank, world, torch.device("cuda", local)
    return rank, world, torch.device("cpu" if cfg.device == "auto" else cfg.device)


def lr_at(step: int, progress: float, cfg: TrainerConfig) -> float:
    """Linear warmup over `cfg.warmup` steps, then cosine from lr to min_lr as `progress` goes 0 -> 1."""
    if step < cfg.warmup:
        return cfg.lr * (step + 1) / cfg.warmup
    return cfg.min_lr + 0.5 * (cfg.lr - cfg.min_lr) * (1 + math.cos(math.pi * min(progress, 1.0)))


@torch.no_grad()
def ema_update(ema: list[Tensor], params: list[Tensor], decay: float, step: int) -> None:
    """One EMA step after optimiser step `step` (0-based), all tensors in one foreach call. The decay warms up as
    min(decay, (1 + step) / (10 + step)): with a constant 0.999 a 1,500-step run's EMA would still hold 22% of the
    initial weights (0.999^1500)."""
    torch._foreach_lerp_(ema, params, 1 - min(decay, (1 + step) / (10 + step)))


def default_groups(model: nn.Module, weight_decay: float) -> list[dict]:
    """AdamW groups: weight decay on matrices and kernels, none on biases, norms and embeddings' vectors."""
    params = [p for p in model.parameters() if p.requires_grad]
    return [{"params": [p for p in params if p.ndim >= 2], "weight_decay": weight_decay},
            {"params": [p for p in params if p.ndim < 2], "weight_decay": 0.0}]


def flat_config(node: dict, prefix: str = "") -> dict[str, Any]:
    """{"a": {"b": 1}} -> {"a.b": 1}."""
    out = {}
    for k, v in node.items():
        if isinstance(v, dict):
            out.update(flat_config(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def read_state_meta(out: str | os.PathLike) -> dict[str, Any] | None:
    """The step, minutes and config of a run folder's train state, or None when it has none."""
    path = Path(out) / STATE
    if not path.is_file():
        return None
    with safe_open(path, "pt") as f:
        meta = f.metadata()
    return {"step": int(meta["step"]), "minutes": float(meta["minutes"]), "config": json.loads(meta["config"])}


def save_state(out: Path, step: int, minutes: float, config: dict, model: nn.Module, ema: nn.Module,
               opt: torch.optim.Optimizer) -> None:
    """Weights, EMA, AdamW moments, step, minutes and the run config in one safetensors file, atomically."""
    state = {f"model.{k}": v for k, v in model.state_dict().items()}
    state.update({f"ema.{k}": v for k, v in ema.state_dict().items()})
    for i, s in opt.state_dict()["state"].items():
        state.update({f"opt.{i}.{k}": torch.as_tensor(v) for k, v in s.items()})
    meta = {"step": str(step), "minutes": str(minutes), "config": json.dumps(config)}
    with atomic_path(out / STATE) as tmp:
        save_file({k: v.detach().contiguous().cpu() for k, v in state.items()}, tmp, metadata=meta)


def load_state(out: Path, model: nn.Module, ema: nn.Module, opt: torch.optim.Optimizer) -> tuple[int, float]:
    """Restore what save_state wrote; returns the step to continue from and the minutes trained so far."""
    device = next(model.parameters()).device
    with safe_open(out / STATE, "pt", device=str(device)) as f:
        meta = f.metadata()
        state = {k: f.get_tensor(k) for k in f.keys()}
    model.load_state_dict({k[6:]: v for k, v in state.items() if k.startswith("model.")})
    ema.load_state_dict({k[4:]: v for k, v in state.items() if k.startswith("ema.")})
    opt_state: dict[int, dict] = {}
    for k, v in state.items():
        if k.startswith("opt."):
            _, i, name = k.split(".", 2)
            opt_state.setdefault(int(i), {})[name] = v.cpu() if name == "step" else v
    opt.load_state_dict({"state": opt_state, "param_groups": opt.state_dict()["param_groups"]})
    return int(meta["step"]), float(meta["minutes"])


def check_resumable(out: Path, config: dict) -> None:
    """Refuse to resume a run folder trained with a different config (other than RESUMABLE keys)."""
    old, new = flat_config(read_state_meta(out)["config"]), flat_config(config)
    differ = sorted(k for k in old.keys() | new.keys() if k not in RESUMABLE and old.get(k) != new.get(k))
    if differ:
        changes = ", ".join(f"{k}: {old.get(k)!r} -> {new.get(k)!r}" for k in differ[:5])
        raise ConfigError(f"out={out} holds a run trained with a different config ({changes}); pass a new out= "
                          "or trainer.resume=false to start over")


def all_ranks_max(x: float, world: int) -> float:
    """The largest `x` over all processes (so they agree on, e.g., the wall clock)."""
    if world == 1:
        return x
    t = torch.tensor([x], dtype=torch.float64)
    dist.all_reduce(t, op=dist.ReduceOp.MAX)
    return float(t)


def keep_lines(path: Path, before: int) -> None:
    """Keep the JSONL records of steps before `before` (a resumed run rewrites the rest)."""
    if not path.is_file():
        return
    lines = path.read_text().splitlines()
    path.write_text("".join(ln + "\n" for ln in lines if json.loads(ln)["step"] < before))


def append_jsonl(path: Path, record: dict) -> None:
    with open(path, "a") as f:
        f.write(json.dumps(record) + "\n")


def train(make_task: Callable[[torch.device], Task], cfg: TrainerConfig, out: str | os.PathLike, seed: int,
          config: dict) -> tuple[Task, nn.Module]:
    """Train the task `make_task(device)` builds (after seeding: a task builds its model first, before anything
    else draws random numbers); returns the task and its EMA model. `config`: the run's resolved config (stored with
    the train state, checked on resume)."""
    rank, world, device = setup(cfg)
    if cfg.batch_size % world:
        raise ConfigError(f"trainer.batch_size={cfg.batch_size} must be divisible by the {world} processes")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    resume = cfg.resume and (out / STATE).is_file()
    if resume:
        check_resumable(out, config)
    torch.manual_seed(seed)
    task = make_task(device)
    model = task.model.to(device)
    ema = copy.deepcopy(model).requires_grad_(False).eval()
    groups = task.param_groups() if hasattr(task, "param_groups") else default_groups(model, cfg.weight_decay)
    opt = torch.optim.AdamW(groups, lr=cfg.lr, betas=tuple(cfg.betas), fused=device.type in ("cpu", "cuda"))
    params = [p for g in opt.param_groups for p in g["params"]]
    ema_params, all_params = list(ema.parameters()), list(model.parameters())
    ema_buffers, buffers = list(ema.buffers()), list(model.buffers())  # e.g. norm statistics: copied, not averaged
    step, minutes = load_state(out, model, ema, opt) if resume else (0, 0.0)
    if resume:
        log.info("resumed %s at step %d (%.1f min)", out, step, minutes)

    net = torch.compile(model) if cfg.compile else model
    if world > 1:
        net = nn.parallel.DistributedDataParallel(net, device_ids=[device.index] if device.type == "cuda" else None)
    local = cfg.batch_size // world
    sampler = DistributedSampler(task.data, num_replicas=world, rank=rank, shuffle=True, seed=seed, drop_last=True)
    per_epoch = len(task.data) // cfg.batch_size
    if per_epoch == 0:
        raise bad("trainer.batch_size", cfg.batch_size, f"at most the {len(task.data)} training items")
    steps = cfg.epochs * per_epoch if cfg.epochs else cfg.steps
    autocast = torch.autocast(device.type, dtype=torch.bfloat16, enabled=cfg.bf16)
    if rank == 0:
        log.info("%s: %.2fM params (%.2fM trained), %d items, global batch %d over %d process(es), out=%s",
                 type(task).__name__, sum(p.numel() for p in all_params) / 1e6,
                 sum(p.numel() for p in params) / 1e6, len(task.data), cfg.batch_size, world, out)
        keep_lines(out / "log.jsonl", step if resume else 0)  # the curve continues from the resumed step
        keep_lines(out / "val.jsonl", step + 1 if resume else 0)

    def budget(step: int) -> float:
        """Fraction of the budget used (1 = stop): steps or minutes, whichever is further, agreed by all ranks."""
        used = (time.time() - t0) / 60
        return all_ranks_max(max(step / steps, used / cfg.max_minutes if cfg.max_minutes else 0.0), world)

    t0 = time.time() - 60 * minutes
    order: list[int] = []
    progress = budget(step)
    while progress < 1:
        epoch, b = divmod(step, per_epoch)
        if b == 0 or not order:
            sampler.set_epoch(epoch)
            order = list(sampler)
        items = [task.data[i] for i in order[b * local : (b + 1) * local]]
        torch.manual_seed(seed * 1_000_003 + step * 1009 + rank)  # dropout, flips: exact on resume
        lr = lr_at(step, progress, cfg)
        for group in opt.param_groups:
            group["lr"] = lr * group.get("lr_scale", 1.0)
        model.train()
        with autocast:
            loss = task.loss(net, items, Batch(step, cfg.batch_size, slice(rank, None, world), seed))
        opt.zero_grad(set_to_none=True)
        loss.backward()
        grad_norm = torch.nn.utils.clip_grad_norm_(params, cfg.grad_clip or math.inf)
        opt.step()
        ema_update(ema_params, all_params, cfg.ema_decay, step)
        if buffers:
            torch._foreach_copy_(ema_buffers, buffers)
        loss = loss.detach()
        if world > 1:
            dist.all_reduce(loss)
            loss /= world
        if rank == 0:
            record = {"step": step, "loss": loss.item(), "lr": lr, "grad_norm": grad_norm.item()}
            append_jsonl(out / "log.jsonl", record)
        step += 1
        progress = budget(step)
        if rank == 0 and (step == 1 or (cfg.log_every and step % cfg.log_every == 0)):
            log.info("step %d/%d loss %.4f lr %.2e (%.1f min)", step, steps, loss.item(), lr, (time.time() - t0) / 60)
        if rank == 0 and ((cfg.ckpt_every and step % cfg.ckpt_every == 0) or progress >= 1):
            if hasattr(task, "save"):
                task.save(ema, out)
            save_state(out, step, (time.time() - t0) / 60, config, model, ema, opt)
        if rank == 0 and hasattr(task, "validate") and ((cfg.val_every and step % cfg.val_every == 0) or progress >= 1):
            record = {"step": step, **task.validate(ema, step, out)}
            log.info("validation: %s", " ".join(f"{k} {v:.4g}" for k, v in record.items() if isinstance(v, float)))
            append_jsonl(out / "val.jsonl", record)
    if world > 1:
        dist.barrier()
    return task, ema
