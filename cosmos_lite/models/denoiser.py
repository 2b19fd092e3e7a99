"""EDM denoiser (Karras et al. 2022): preconditioning, log-normal noise levels and loss weighting around a
network that knows nothing about noise. Given (condition) frames get their own low noise level per frame,
are fed noise-augmented, and come back at their true values."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor, nn

from .conditioning import Condition


@dataclass
class EDMConfig:
    """Noise distribution and preconditioning constants (latents are normalised to unit std)."""

    sigma_data: float = 1.0
    p_mean: float = 0.0  # log-normal training sigma: log(sigma) ~ N(p_mean, p_std)
    p_std: float = 1.2
    sigma_min: float = 0.002
    sigma_max: float = 80.0
    cond_sigma_max: float = 0.3  # training: given frames augmented with sigma ~ U(0, cond_sigma_max)
    cond_sigma: float = 0.05  # sampling: fixed augmentation of the given frames


class Denoiser(nn.Module):
    """D(x; sigma, cond) = c_skip x + c_out F(c_in x; c_noise, cond), per latent frame."""

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

    def forward(self, x: Tensor, sigma: Tensor, cond: Condition) -> Tensor:
        """Denoised estimate of `x (B, C, T, H, W)` at noise level `sigma (B,)`."""
        given = cond.given[:, None, :, None, None]
        frame_sigma = torch.where(cond.given, cond.cond_sigma[:, None], sigma[:, None])  # (B, T)
        x = torch.where(given, cond.latents + cond.cond_sigma[:, None, None, None, None] * cond.aug_noise, x)
        c_skip, c_out, c_in, c_noise = self.precondition(frame_sigma)
        per_frame = (slice(None), None, slice(None), None, None)
        net_in = torch.cat([c_in[per_frame] * x, given.expand(-1, 1, -1, *x.shape[3:]).to(x.dtype)], dim=1)
        out = self.net(net_in, c_noise, cond.text, cond.text_mask, cond.actions, cond.has_actions, cond.fps)
        denoised = c_skip[per_frame] * x + c_out[per_frame] * out.to(x.dtype)
        return torch.where(given, cond.latents, denoised)

    def sample_sigma(self, n: int, generator: torch.Generator | None = None) -> Tensor:
        """Training noise levels, log-normal."""
        return (torch.randn(n, generator=generator) * self.cfg.p_std + self.cfg.p_mean).exp()

    def loss(self, x0: Tensor, cond: Condition, sigma: Tensor, noise: Tensor) -> Tensor:
        """EDM-weighted MSE per sample `(B,)`, averaged over the frames to generate (given frames excluded)."""
        sd = self.cfg.sigma_data
        denoised = self(x0 + sigma[:, None, None, None, None] * noise, sigma, cond)
        weight = (sigma**2 + sd**2) / (sigma * sd) ** 2
        free = (~cond.given).float()  # (B, T)
        err = (denoised - x0).pow(2).mean(dim=(1, 3, 4))  # (B, T)
        return weight * (err * free).sum(1) / free.sum(1).clamp(min=1)
