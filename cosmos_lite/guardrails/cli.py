"""Check a prompt and/or a video against the guardrails and print every guard's verdict as JSON (a blocked one names
the category of harm); exit 0 allowed, 3 blocked.

Examples: `cosmos-lite guard prompt="a robot stacks cubes"`, `cosmos-lite guard video=out.mp4 blur_out=blurred.mp4`,
`cosmos-lite guard prompt="..." guardrails.semantic.enabled=false`. `cosmos-lite guard fit-semantic` refits the
semantic head on the shipped red-team set (reproducible: same data, same head).
"""

from __future__ import annotations

import json
from collections.abc import Mapping

from omegaconf import DictConfig

from ..config import bad, number
from ..errors import ConfigError, GuardrailBlocked
from .core import Verdict
from .runner import Guardrails


def fit_semantic(cfg: DictConfig) -> int:
    """Fit the semantic head (train split; only its logistic head with semantic_adapters=HEAD_FILE), choose its
    threshold (val split; the confirm threshold is confirm_threshold) and write it."""
    from .semantic import HEAD, fit_head, save_head

    if not isinstance(cfg.max_fpr, Mapping):
        raise bad("max_fpr", cfg.max_fpr, "a share per benign category, e.g. max_fpr.everyday=0.01")
    max_fpr = {str(k): number(f"max_fpr.{k}", v, float, above=0, high=1) for k, v in cfg.max_fpr.items()}
    confirm = number("confirm_threshold", cfg.confirm_threshold, float, low=0, high=1)
    head = fit_head(max_fpr, confirm, encoder=cfg.guardrails.semantic.encoder, adapters_from=cfg.semantic_adapters)
    path = save_head(head, cfg.semantic_out or HEAD)
    print(json.dumps({"head": str(path), "threshold": head["threshold"], "confirm_threshold": head["confirm_threshold"],
                      "val": head["val"]}))
    return 0


def main(cfg: DictConfig, args: list[str]) -> int:
    if args == ["fit-semantic"]:
        return fit_semantic(cfg)
    if args:
        raise ConfigError(f"unknown argument(s) {' '.join(args)}; use prompt=\"...\", video=FILE or fit-semantic")
    if cfg.prompt is None and cfg.video is None:
        raise ConfigError('nothing to check: pass prompt="..." and/or video=FILE')
    if cfg.prompt is not None and not str(cfg.prompt).strip():
        raise bad("prompt", cfg.prompt, 'some text to check, not an empty one: prompt="..."')
    chunk = number("chunk", cfg.chunk, low=1)
    if cfg.blur_out and cfg.video is None:
        raise ConfigError(f"blur_out={cfg.blur_out} needs video=FILE: the video whose faces are blurred")
    guards = Guardrails.from_config(cfg.guardrails)
    verdicts = []
    if cfg.prompt is not None:
        verdicts += guards.prompt_verdicts(str(cfg.prompt))
    if cfg.video is not None and all(v.allowed for v in verdicts):
        from ..video import iter_frames, probe

        fps = probe(cfg.video).fps
        verdicts.append(guards.check_video_stream(iter_frames(cfg.video), chunk))
    allowed = all(v.allowed for v in verdicts)
    if allowed and cfg.video is not None and cfg.blur_out:
        from ..video import write_video

        try:
            write_video(cfg.blur_out, guards.postprocess_stream(iter_frames(cfg.video), chunk), fps)
        except GuardrailBlocked as e:
            verdicts.append(Verdict(False, "face_blur", str(e)))
            allowed = False
    print(json.dumps({"allowed": allowed, "verdicts": [v._asdict() for v in verdicts]}, indent=1))
    return 0 if allowed else GuardrailBlocked.exit_code
