"""What the next latent frame is conditioned on: the latent frames before it (any number up to the model's
context, noise-augmented per frame), text tokens and the actions that lead into it, plus the dropout that
teaches the model to go without text and actions (for guidance)."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import torch
from torch import Tensor


@dataclass
class Condition:
    """Conditioning of one next-frame prediction for a batch; context frames are oldest first, right-aligned (the
    last one is the frame just before the prediction), absent ones zero with `present` False."""

    context: Tensor  # (B, K, C, H, W) normalised latent frames
    present: Tensor  # (B, K) bool
    context_sigma: Tensor  # (B, K) noise-augmentation level of each context frame
    context_noise: Tensor  # (B, K, C, H, W) standard normal, fixed for a whole sampling run
    text: Tensor  # (B, L, text_dim)
    text_mask: Tensor  # (B, L) bool; all False = no text
    actions: Tensor  # (B, K, A): the action after each context frame (the last leads into the prediction)
    has_actions: Tensor  # (B,) bool

    def noisy_context(self) -> Tensor:
        """The context frames as the network sees them: noise-augmented, absent ones zero."""
        s = self.context_sigma[..., None, None, None]
        return (self.context + s * self.context_noise) * self.present[..., None, None, None]

    def without_text(self) -> Condition:
        return replace(self, text_mask=torch.zeros_like(self.text_mask))

    def without_actions(self) -> Condition:
        return replace(self, has_actions=torch.zeros_like(self.has_actions))

    def to(self, device: torch.device | str) -> Condition:
        return Condition(**{f.name: getattr(self, f.name).to(device) for f in fields(self)})

    @staticmethod
    def cat(conds: list[Condition]) -> Condition:
        """Stack conditions along the batch (to run several guidance branches in one forward pass)."""
        return Condition(**{f.name: torch.cat([getattr(c, f.name) for c in conds]) for f in fields(Condition)})


def context_window(frames: Tensor, actions: Tensor, t: Tensor, k: int) -> tuple[Tensor, Tensor, Tensor]:
    """The k latent frames before frame t of each clip and the actions after them: `frames (B, T, C, H, W)`,
    `actions (B, T, A)`, `t (B,)` -> context `(B, k, C, H, W)`, present `(B, k)`, actions `(B, k, A)`; frames before
    the clip's start are zero and absent."""
    idx = t[:, None] - k + torch.arange(k, device=t.device)[None]  # (B, k): t-k .. t-1
    present = idx >= 0
    rows = torch.arange(len(t), device=t.device)[:, None]
    context = frames[rows, idx.clamp(min=0)] * present[..., None, None, None]
    return context, present, actions[rows, idx.clamp(min=0)] * present[..., None]


def make_condition(context: Tensor, present: Tensor, actions: Tensor | None = None,
                   has_actions: Tensor | None = None, text: Tensor | None = None, text_mask: Tensor | None = None,
                   context_sigma: float | Tensor = 0.0, generator: torch.Generator | None = None,
                   text_dim: int = 384, action_dim: int = 2, context_noise: Tensor | None = None) -> Condition:
    """A Condition from its parts; absent text or actions become their 'dropped' form; `context_noise`: standard
    normal, the shape of `context` (None: drawn from `generator`)."""
    b, k = present.shape
    dev = context.device
    if text is None:
        text, text_mask = torch.zeros(b, 1, text_dim, device=dev), torch.zeros(b, 1, dtype=torch.bool, device=dev)
    elif text_mask is None:
        text_mask = torch.ones(text.shape[:2], dtype=torch.bool, device=dev)
    if actions is None:
        actions, has_actions = torch.zeros(b, k, action_dim, device=dev), torch.zeros(b, dtype=torch.bool, device=dev)
    elif has_actions is None:
        has_actions = torch.ones(b, dtype=torch.bool, device=dev)
    sigma = torch.as_tensor(context_sigma, dtype=torch.float32, device=dev).expand(b, k)
    if context_noise is None:
        context_noise = torch.randn(context.shape, generator=generator, device=dev)
    return Condition(context=context, present=present, context_sigma=sigma, context_noise=context_noise,
                     text=text.float(), text_mask=text_mask, actions=actions.float(), has_actions=has_actions)
