"""Diffusion world model: latent DiT, EDM denoiser, samplers, conditioning, training and the pipeline."""

from .conditioning import Condition, group_actions, make_condition
from .denoiser import Denoiser, EDMConfig
from .dit import PRESETS, DiT, DiTConfig, build_dit
from .pipeline import WorldModelOutput, WorldModelPipeline
from .samplers import karras_sigmas, sample, sample_euler, sample_heun

__all__ = [
    "PRESETS", "Condition", "DiT", "DiTConfig", "Denoiser", "EDMConfig", "WorldModelOutput", "WorldModelPipeline",
    "build_dit", "group_actions", "karras_sigmas", "make_condition", "sample", "sample_euler", "sample_heun",
]
