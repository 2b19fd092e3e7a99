"""Train a model: `experiment=NAME` picks an experiment config, whose `task` names the trainer.

Examples: `cosmos-lite train experiment=tokenizer_nano`, `cosmos-lite train experiment=wfm_nano
posttrain.init_from=runs/wfm_generalist`. Sweeps, one run folder per job (OUT/0, OUT/1):
`cosmos-lite train -m experiment=wfm_nano ... trainer.lr=1e-3,3e-4 out=runs/sweep`.
"""

from __future__ import annotations

import importlib

from omegaconf import DictConfig

from .errors import ConfigError

TRAINERS = {
    "tokenizer": "cosmos_lite.tokenizers.train",
    "wfm": "cosmos_lite.models.train",
    "frame_classifier": "cosmos_lite.guardrails.train",
}


def main(cfg: DictConfig, args: list[str]) -> int | None:
    task = cfg.get("task")
    if task not in TRAINERS:
        raise ConfigError(f"experiment sets task={task!r}; expected one of {', '.join(TRAINERS)}")
    return importlib.import_module(TRAINERS[task]).main(cfg, args)
