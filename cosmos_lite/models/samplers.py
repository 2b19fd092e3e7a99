"""Samplers as plain functions over a denoiser: Karras noise schedule, Euler and Heun (EDM Algorithm 2, optional
stochastic churn), and classifier-free guidance with separate text and action scales. A world model samples one
latent frame at a time with a few steps (DIAMOND: 3; GameNGen: 4 matched 64)."""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import Tensor

from .conditioning import Condition
from .denoiser import Denoiser

DenoiseFn = Callable[[Tensor, Tensor], Tensor]  # (x, sigma (B,)) -> denoised x


def karras_sigmas(steps: int, sigma_min: float = 0.002, sigma_max: float = 80.0, rho: float = 7.0) -> Tensor:
    """`steps` noise levels from sigma_max down to sigma_min (Karras et al. eq. 5), then a final 0."""
    ramp = torch.linspace(0, 1, steps, dtype=torch.float64)
    inv = sigma_max ** (1 / rho) + ramp * (sigma_min ** (1 / rho) - sigma_max ** (1 / rho))
    return torch.cat([inv**rho, torch.zeros(1, dtype=torch.float64)])


def guided(denoiser: Denoiser, cond: Condition, guidance: float = 1.0, action_guidance: float = 1.0) -> DenoiseFn:
    """Compositional classifier-free guidance, with both scales 1 equal to the conditional prediction:
    D = D(-,-) + g_text (D(text,-) - D(-,-)) + g_act (D(text,act) - D(text,-)).

    Branches with a zero weight are skipped; the rest run as one batch.
    """
    branches = [(1 - guidance, cond.without_text().without_actions()), (guidance - action_guidance,
                cond.without_actions()), (action_guidance, cond)]
    branches = [(w, c) for w, c in branches if w != 0]
    batched = Condition.cat([c for _, c in branches]) if len(branches) > 1 else branches[0][1]
    n = len(branches)

    def denoise(x: Tensor, sigma: Tensor) -> Tensor:
        out = denoiser(x.repeat(n, 1, 1, 1), sigma.repeat(n), batched).chunk(n)
        return sum(w * o for (w, _), o in zip(branches, out))

    return denoise


def _churn(x: Tensor, sigma: float, churn: float, steps: int,
           generator: torch.Generator | None) -> tuple[Tensor, float]:
    """EDM's stochastic step: raise the noise level by a factor gamma, adding fresh noise."""
    gamma = min(churn / steps, math.sqrt(2) - 1) if churn > 0 else 0.0
    sigma_hat = sigma * (1 + gamma)
    if gamma > 0:
        noise = torch.randn(x.shape, generator=generator, device=x.device, dtype=x.dtype)
        x = x + math.sqrt(sigma_hat**2 - sigma**2) * noise
    return x, sigma_hat


def integrate(denoise: DenoiseFn, x: Tensor, sigmas: Tensor, second_order: bool, churn: float = 0.0,
              generator: torch.Generator | None = None) -> Tensor:
    """EDM Algorithm 2 from noise level sigmas[0]: Euler steps, plus (Heun) a second-order correction except into
    sigma = 0."""
    steps = len(sigmas) - 1
    for i in range(steps):
        s, s_next = float(sigmas[i]), float(sigmas[i + 1])
        x, s_hat = _churn(x, s, churn, steps, generator)
        d = (x - denoise(x, x.new_full((x.shape[0],), s_hat))) / s_hat
        x_next = x + (s_next - s_hat) * d
        if second_order and s_next > 0:
            d2 = (x_next - denoise(x_next, x.new_full((x.shape[0],), s_next))) / s_next
            x_next = x + (s_next - s_hat) * (d + d2) / 2
        x = x_next
    return x


SAMPLERS = {"euler": False, "heun": True}  # name -> second order


@torch.no_grad()
def sample_next(denoiser: Denoiser, cond: Condition, steps: int | None = None, sampler: str = "euler",
                guidance: float = 1.0, action_guidance: float = 1.0, churn: float = 0.0,
                generator: torch.Generator | None = None, noise: Tensor | None = None) -> Tensor:
    """The next normalised latent frame `(B, C, H, W)` after `cond`'s context, in `steps` sampler steps (None: the
    denoiser's `edm.steps`), from standard normal `noise` (None: drawn from `generator`)."""
    if sampler not in SAMPLERS:
        raise ValueError(f"unknown sampler {sampler!r}; choose one of {', '.join(SAMPLERS)}")
    cfg = denoiser.cfg
    sigmas = karras_sigmas(cfg.steps if steps is None else steps, cfg.sigma_min, cfg.sigma_max)
    shape = cond.context.shape[:1] + cond.context.shape[2:]
    if noise is None:
        noise = torch.randn(shape, generator=generator, device=cond.context.device)
    x = noise * float(sigmas[0])
    return integrate(guided(denoiser, cond, guidance, action_guidance), x, sigmas, SAMPLERS[sampler], churn, generator)
