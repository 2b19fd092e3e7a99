"""Frames <-> tensors, the one conversion between the two contracts (DESIGN.md): frames are uint8 `(T, H, W, 3)`
RGB; model tensors are float `(B, 3, T, H, W)` in [-1, 1]."""

from __future__ import annotations

import numpy as np
import torch


def to_tensor(frames: np.ndarray) -> torch.Tensor:
    """uint8 frames `(T, H, W, 3)` -> float `(1, 3, T, H, W)` in [-1, 1]."""
    return torch.from_numpy(np.ascontiguousarray(frames)).permute(3, 0, 1, 2)[None].float() / 127.5 - 1


def to_frames(x: torch.Tensor) -> np.ndarray:
    """float `(1, 3, T, H, W)` or `(3, T, H, W)` in [-1, 1] -> uint8 frames `(T, H, W, 3)`, clamped and rounded."""
    x = x[0] if x.ndim == 5 else x
    return ((x.clamp(-1, 1) + 1) * 127.5).round().to(torch.uint8).permute(1, 2, 3, 0).cpu().numpy()
