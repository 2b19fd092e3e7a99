"""EDM denoiser (Karras et al. 2022) for the next latent frame: preconditioning, log-normal noise levels and loss
weighting around a network that knows nothing about noise. It denoises the whole next frame (DIAMOND, GameNGen), so
each frame is predicted afresh from its context and sampling errors do not add up along a rollout (denoising the
residual from the last frame instead, errors accumulated into speckle within 16 frames); context frames are fed
noise-augmented, each with its own noise level (Diffusion Forcing), so the model learns to trust its own imperfect
past."""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .conditioning import Condition


@dataclass
class EDMConfig:
    """Noise distribution, preconditioning constants and loss weighting (latents are normalised to unit std)."""

    sigma_data: float = 1.0  # latents are normalised to unit std
    # Log-normal training sigma, log(sigma) ~ N(p_mean, p_std), centred on the level one sampler step starts from
    # (sigma_max): at 1500 steps, 1-step rollout object IoU from 1 / 9 given frames 0.036 / 0.046 with DIAMOND's
    # (-0.4, 1.2), 0.084 / 0.093 with (1.0, 1.2), 0.155 / 0.145 with (2.0, 0.8), 0.167 / 0.149 with (2.3, 0.4); the
    # spread of (2.0, 0.8) still trains the low levels that more sampler steps visit.
    p_mean: float = 2.0
    p_std: float = 0.8
    sigma_min: float = 0.002
    sigma_max: float = 10.0
    context_sigma_max: float = 0.3  # training: each context frame augmented with sigma ~ U(0, max)
    context_sigma: float = 0.02  # sampling: fixed augmentation of the context frames
    moving_weight: float = 10.0  # extra loss weight on latent cells that change (objects are 1-2% of pixels)
    moving_threshold: float = 0.3  # a cell changes when its largest channel difference from the last exceeds this
    # Sampler steps per generated frame unless a caller asks for others. One Euler step (the denoiser's estimate from
    # pure noise) kept objects best: the bench's model, rollout object IoU from 1 given frame 0.077 / 0.075 / 0.061 at
    # 1 / 2 / 3 steps, from 9 given 0.110 vs 0.088 at 3 (docs/wfm_diagnosis_2026-11-26.txt).
    steps: int = 1


class Denoiser(nn.Module):
    """D(y; sigma, cond) = c_skip y + c_out F(c_in y; c_noise, cond) for the next latent frame y."""

    def __init__(self, net: nn.Module, cfg: EDMConfig):
        super().__init__()
        self.net = net
        self.cfg = cfg

    def precondition(self, sigma: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        sd = self.cfg.sigma_data
        c_skip = sd**2 / (sigma**2 + sd**2)
        c_out = sigma * sd / (sigma**2 + sd**2).sqrt()
        c_in = 1 / (sigma**2 + sd**2).sqrt()
        c_noise = sigma.clamp(min=1e-20).log() / 4
        return c_skip, c_out, c_in, c_noise

    def forward(self, y: Tensor, sigma: Tensor, cond: Condition) -> Tensor:
        """Denoised next frame from `y (B, C, H, W)` at noise level `sigma (B,)`."""
        c_skip, c_out, c_in, c_noise = self.precondition(sigma)
        s = cond.context_sigma
        context = cond.noisy_context() / (s**2 + 1).sqrt()[..., None, None, None]  # unit variance in, like c_in
        noise_levels = torch.cat([c_noise[:, None], s.clamp(min=1e-3).log() / 4], dim=1)
        out = self.net(c_in[:, None, None, None] * y, context, cond.present, noise_levels, cond.actions,
                       cond.has_actions, cond.text, cond.text_mask)
        return c_skip[:, None, None, None] * y + c_out[:, None, None, None] * out.to(y.dtype)

    def sample_sigma(self, n: int, generator: torch.Generator | None = None) -> Tensor:
        """Training noise levels, log-normal."""
        return (torch.randn(n, generator=generator) * self.cfg.p_std + self.cfg.p_mean).exp()

    def loss(self, target: Tensor, cond: Condition, sigma: Tensor, noise: Tensor) -> Tensor:
        """EDM-weighted MSE per sample `(B,)` of the denoised next frame against `target`; latent cells that change
        between the last context frame and the next (and their neighbours) weigh more."""
        sd = self.cfg.sigma_data
        denoised = self(target + sigma[:, None, None, None] * noise, sigma, cond)
        moved = target - cond.context[:, -1] * cond.present[:, -1, None, None, None]
        changed = (moved.abs().amax(1, keepdim=True) > self.cfg.moving_threshold).float()
        weight = 1 + self.cfg.moving_weight * F.max_pool2d(changed, 3, stride=1, padding=1)
        lam = (sigma**2 + sd**2) / (sigma * sd) ** 2
        return lam * ((denoised - target).pow(2) * weight).mean(dim=(1, 2, 3))
