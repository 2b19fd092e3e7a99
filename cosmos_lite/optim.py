"""Optimiser pieces the trainers share: AdamW on torch's fused kernel, and the EMA update of the weights."""

from __future__ import annotations

from collections.abc import Iterable

import torch


def adamw(params: Iterable, device: torch.device, **kwargs) -> torch.optim.AdamW:
    """AdamW, fused where torch has the kernel (CPU, CUDA): one pass over all tensors instead of a dozen small ops
    per tensor (the nano tokenizer's optimiser step on 2 cores: 4.9 -> 0.9 ms of a ~65 ms training step)."""
    return torch.optim.AdamW(params, fused=device.type in ("cpu", "cuda"), **kwargs)


@torch.no_grad()
def ema_update(ema: list[torch.Tensor], params: list[torch.Tensor], decay: float, step: int) -> None:
    """One EMA step after optimiser step `step` (0-based), all tensors in one foreach call. The decay warms up as
    min(decay, (1 + step) / (10 + step)): with a constant 0.999 a 1,500-step run's EMA would still hold 22% of the
    initial weights (0.999^1500)."""
    torch._foreach_lerp_(ema, params, 1 - min(decay, (1 + step) / (10 + step)))
