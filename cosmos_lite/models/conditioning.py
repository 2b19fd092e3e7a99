"""What a world-model sample is conditioned on: given first latent frames (video2world), text tokens and
per-frame actions, plus the dropout that teaches the model to go without each (for guidance)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import Tensor


@dataclass
class Condition:
    """Conditioning for a batch of latent videos `(B, C, T, H, W)`.

    `given (B, T)` marks latent frames whose values are known (`latents` there); they are fed to the network
    noise-augmented with the fixed `aug_noise * cond_sigma`, and the denoiser returns them unchanged.
    """

    latents: Tensor  # (B, C, T, H, W); only the given frames matter
    given: Tensor  # (B, T) bool
    cond_sigma: Tensor  # (B,) noise-augmentation level of the given frames
    aug_noise: Tensor  # (B, C, T, H, W) standard normal, fixed for a whole sampling run
    text: Tensor  # (B, L, text_dim)
    text_mask: Tensor  # (B, L) bool; all False = no text
    actions: Tensor  # (B, T, ct*A) grouped per latent frame
    has_actions: Tensor  # (B,) bool
    fps: Tensor  # (B,)

    def keep_given(self, x: Tensor) -> Tensor:
        """`x` with the given frames set to their true values."""
        return torch.where(self.given[:, None, :, None, None], self.latents, x)

    def without_text(self) -> Condition:
        return replace(self, text_mask=torch.zeros_like(self.text_mask))

    def without_actions(self) -> Condition:
        return replace(self, has_actions=torch.zeros_like(self.has_actions))

    def slice(self, idx: slice | Tensor) -> Condition:
        return Condition(**{k: getattr(self, k)[idx] for k in self.__dataclass_fields__})

    @staticmethod
    def cat(conds: list[Condition]) -> Condition:
        """Stack conditions along the batch (to run several guidance branches in one forward pass)."""
        return Condition(**{k: torch.cat([getattr(c, k) for c in conds]) for k in Condition.__dataclass_fields__})


def group_actions(actions: Tensor, num_latent_frames: int, ct: int) -> Tensor:
    """Per-pixel-frame actions `(B, T, A)` -> `(B, num_latent_frames, ct*A)`: latent frame i >= 1 gets the
    actions at pixel frames ct*(i-1) .. ct*i - 1 (the ones that lead into its frames); frame 0 (the first
    pixel frame alone) is caused by none. Missing trailing actions are zero."""
    b, t, a = actions.shape
    need = ct * (num_latent_frames - 1)
    padded = actions.new_zeros(b, max(need, 0), a)
    padded[:, : min(t, need)] = actions[:, :need]
    grouped = padded.reshape(b, num_latent_frames - 1, ct * a)
    return torch.cat([actions.new_zeros(b, 1, ct * a), grouped], dim=1)


def make_condition(
    shape: tuple[int, ...],
    latents: Tensor | None = None,
    num_given: int | Tensor = 0,
    text: Tensor | None = None,
    text_mask: Tensor | None = None,
    actions: Tensor | None = None,
    has_actions: Tensor | None = None,
    fps: float | Tensor = 16.0,
    cond_sigma: float | Tensor = 0.0,
    text_dim: int = 384,
    action_dim: int = 2,
    ct: int = 4,
    generator: torch.Generator | None = None,
    device: torch.device | str | None = None,
) -> Condition:
    """Build a Condition for latent `shape (B, C, T, H, W)`; absent parts become their 'dropped' form.

    `latents` holds the given frames first (`num_given` latent frames, int or per-sample `(B,)`); `actions`
    are per pixel frame `(B, T_pix, A)`.
    """
    b, c, t, h, w = shape
    dev = torch.device(device) if device is not None else latents.device if latents is not None else torch.device("cpu")
    full = torch.zeros(shape, device=dev)
    if latents is not None:
        full[:, :, : latents.shape[2]] = latents[:, :, :t]
    k = torch.as_tensor(num_given, device=dev).expand(b)
    given = torch.arange(t, device=dev)[None] < k[:, None]
    if text is None:
        text, text_mask = torch.zeros(b, 1, text_dim, device=dev), torch.zeros(b, 1, dtype=torch.bool, device=dev)
    elif text_mask is None:
        text_mask = torch.ones(text.shape[:2], dtype=torch.bool, device=dev)
    if actions is None:
        grouped, has = torch.zeros(b, t, ct * action_dim, device=dev), torch.zeros(b, dtype=torch.bool, device=dev)
    else:
        grouped = group_actions(actions.float(), t, ct)
        has = torch.ones(b, dtype=torch.bool, device=dev) if has_actions is None else has_actions
    noise = torch.randn(shape, generator=generator, device=dev)
    return Condition(
        latents=full, given=given, cond_sigma=torch.as_tensor(cond_sigma, dtype=torch.float32, device=dev).expand(b),
        aug_noise=noise, text=text.float(), text_mask=text_mask, actions=grouped, has_actions=has,
        fps=torch.as_tensor(fps, dtype=torch.float32, device=dev).expand(b),
    )
