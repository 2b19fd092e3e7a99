"""LoRA adapters for post-training any model (the world model's DiT, the semantic guard's text encoder): low-rank
updates beside frozen linear layers, merged back for export."""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor, nn


class LoRALinear(nn.Module):
    """y = base(x) + (alpha / rank) * B A x, with B zero-initialised so training starts from the base model."""

    def __init__(self, base: nn.Linear, rank: int, alpha: float):
        super().__init__()
        self.base = base.requires_grad_(False)
        self.lora_a = nn.Parameter(torch.empty(rank, base.in_features))
        self.lora_b = nn.Parameter(torch.zeros(base.out_features, rank))
        nn.init.kaiming_uniform_(self.lora_a, a=5**0.5)
        self.scale = alpha / rank

    def forward(self, x: Tensor) -> Tensor:
        return self.base(x) + (x @ self.lora_a.t() @ self.lora_b.t()) * self.scale

    def merged(self) -> nn.Linear:
        """A plain Linear equal to this layer."""
        out = nn.Linear(self.base.in_features, self.base.out_features, bias=self.base.bias is not None)
        with torch.no_grad():
            out.weight.copy_(self.base.weight + self.scale * self.lora_b @ self.lora_a)
            if self.base.bias is not None:
                out.bias.copy_(self.base.bias)
        return out


def _swap(model: nn.Module, make) -> None:
    for name, module in list(model.named_modules()):
        for child_name, child in list(module.named_children()):
            full = f"{name}.{child_name}" if name else child_name
            new = make(full, child)
            if new is not None:
                setattr(module, child_name, new)


def add_lora(model: nn.Module, rank: int, alpha: float | None, targets: Callable[[str], bool]) -> nn.Module:
    """Freeze `model` and add adapters to the linear layers whose names `targets` accepts; only adapters train."""
    model.requires_grad_(False)
    alpha = float(alpha or rank)

    def make(name: str, child: nn.Module):
        if isinstance(child, nn.Linear) and targets(name):
            return LoRALinear(child, rank, alpha)
        return None

    _swap(model, make)
    return model


def merge_lora(model: nn.Module) -> nn.Module:
    """Fold every adapter into its base layer (in place), leaving the plain architecture."""
    _swap(model, lambda name, child: child.merged() if isinstance(child, LoRALinear) else None)
    return model
