"""Diffusion world model: next-latent-frame DiT, EDM denoiser, samplers, conditioning, training and the pipeline."""

from .conditioning import Condition, context_window, make_condition
from .denoiser import Denoiser, EDMConfig
from .dit import DiT, DiTConfig, build_dit
from .pipeline import WorldModelOutput, WorldModelPipeline
from .samplers import karras_sigmas, sample_next

__all__ = [
    "Condition", "DiT", "DiTConfig", "Denoiser", "EDMConfig", "WorldModelOutput", "WorldModelPipeline", "build_dit",
    "context_window", "karras_sigmas", "make_condition", "sample_next",
]
