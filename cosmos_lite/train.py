"""Train a model: `experiment=NAME` picks an experiment config, whose `task` names the task the training engine
(cosmos_lite.core.engine) runs. Every experiment shares `trainer.*` (core.engine.TrainerConfig: steps, max_minutes,
batch_size, lr, min_lr, warmup, ema_decay, ckpt_every, val_every, ...); `data.*` and the task's own nodes come from
the task's structured configs, so an experiment's YAML holds only what differs from their defaults.

Examples: `cosmos-lite train experiment=tokenizer_nano`, `cosmos-lite train experiment=wfm_nano
posttrain.init_from=runs/wfm_generalist`. Sweeps, one run folder per job (OUT/0, OUT/1):
`cosmos-lite train -m experiment=wfm_nano ... trainer.lr=1e-3,3e-4 out=runs/sweep`.
"""

from __future__ import annotations

from collections.abc import Callable

from omegaconf import DictConfig

from .errors import ConfigError
from .guardrails import train as frame_classifier  # importing a task registers its structured configs
from .models import train as wfm
from .tokenizers import train as tokenizer

TASKS: dict[str, Callable[[DictConfig, list[str]], int]] = {
    "tokenizer": tokenizer.main,
    "wfm": wfm.main,
    "frame_classifier": frame_classifier.main,
}


def main(cfg: DictConfig, args: list[str]) -> int | None:
    task = cfg.get("task")
    if task not in TASKS:
        raise ConfigError(f"experiment sets task={task!r}; expected one of {', '.join(TASKS)}")
    return TASKS[task](cfg, args)
