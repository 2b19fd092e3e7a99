"""Optimiser pieces the trainers share: AdamW on torch's fused kernel, and the EMA update of the weights."""

from __future__ import annotations

from collections.abc import Iterable

import torch


def adamw(params: Iterable, device: torch.device, **kwargs) -> torch.optim.AdamW:
    """AdamW, fused where torch has the kernel (CPU, CUDA): one pass over all tensors instead of a dozen small ops
    per tensor (the nano tokenizer's optimiser step on 2 cores: 4.9 -> 0.9 ms of a ~65 ms training step)."""
    return torch.optim.AdamW(params, fused=device.type in ("cpu", "cuda"), **kwargs)


@torch.no_grad()
def ema_update(ema: list[torch.Tensor], params: list[torch.Tensor], weight: float) -> None:
    """Move every EMA tensor `weight` of the way towards its parameter, all tensors in one foreach call."""
    torch._foreach_lerp_(ema, params, weight)
