"""Diffusers-style world-model pipeline: first frames + prompt + actions -> video, windowed autoregressively
for clips longer than the training window. A checkpoint directory is self-contained: model.safetensors,
config.yaml, latent_stats.safetensors and the tokenizer it was trained on (tokenizer/)."""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from safetensors.torch import load_file
from torch import Tensor

from ..config import to_dataclass
from ..core.checkpoint import save_tensors
from ..core.frames import to_frames, to_tensor
from ..errors import ConfigError, InputError
from ..files import write_text
from ..text import get_text_encoder
from ..tokenizers import Tokenizer, load_tokenizer
from .conditioning import make_condition
from .denoiser import Denoiser, EDMConfig
from .dit import DiT, DiTConfig
from .samplers import sample

FILES = ("model.safetensors", "config.yaml", "latent_stats.safetensors", "tokenizer/model.safetensors")


@dataclass
class WorldModelOutput:
    """Generated video `frames (T, H, W, 3)` uint8, the given frames included; None when a guardrail blocked.
    `verdicts`: the guardrail verdicts in the order they ran (empty without guardrails)."""

    frames: np.ndarray | None
    verdicts: list = field(default_factory=list)

    @property
    def blocked(self) -> bool:
        return any(not v.allowed for v in self.verdicts)


def build_denoiser(cfg: DictConfig) -> Denoiser:
    """The DiT and its EDM wrapper from a training config (`model`, `edm` nodes)."""
    return Denoiser(DiT(to_dataclass(DiTConfig, cfg.model, "model")), to_dataclass(EDMConfig, cfg.edm, "edm"))


class WorldModelPipeline:
    """`pipe(prompt=, video=, actions=, num_frames=, steps=, guidance=, action_guidance=, seed=)`, wrapped in
    guardrails when given: the pre-guard checks the prompt before any compute, the post-guard the generated video
    (face blur applied to what passes)."""

    def __init__(self, denoiser: Denoiser, tokenizer: Tokenizer, cfg: DictConfig, stats: dict[str, Tensor],
                 guardrails=None):
        """`stats`: per-channel latent `mean` and `std`, per-dimension `action_scale` of the training data;
        `guardrails`: a `cosmos_lite.guardrails.Guardrails` or None (no checks)."""
        self.denoiser, self.tokenizer, self.cfg = denoiser.eval(), tokenizer.eval(), cfg
        self.guardrails = guardrails
        self.stats = {k: v.float() for k, v in stats.items()}
        self.ct = tokenizer.temporal_compression
        self.window = int(cfg.data.num_frames)  # pixel frames per generated window (1 + ct * k)
        self.context = 1 + self.ct * (int(cfg.cond.max_given) - 1)  # pixel frames carried into the next window
        self.size = (int(cfg.data.height), int(cfg.data.width))

    @property
    def device(self) -> torch.device:
        return next(self.denoiser.parameters()).device

    @classmethod
    def from_pretrained(cls, directory: str | os.PathLike, device: str | torch.device = "cpu",
                        guardrails=None) -> WorldModelPipeline:
        """Load a checkpoint directory written by `save_pretrained` (training writes one). `guardrails`: a
        `Guardrails` to wrap every generation in (`Guardrails.from_config()` for the defaults), or None."""
        d = Path(directory)
        for name in FILES:
            if not (d / name).is_file():
                raise InputError(f"{d / name} is missing: pass a world-model checkpoint directory written by "
                                 "`cosmos-lite train experiment=wfm_nano` (or WorldModelPipeline.save_pretrained)")
        cfg = OmegaConf.load(d / "config.yaml")
        denoiser = build_denoiser(cfg)
        denoiser.net.load_state_dict(load_file(d / "model.safetensors"))
        pipe = cls(denoiser, load_tokenizer(d / "tokenizer"), cfg, load_file(d / "latent_stats.safetensors"),
                   guardrails)
        return pipe.to(device)

    def to(self, device: str | torch.device) -> WorldModelPipeline:
        self.denoiser.to(device)
        self.tokenizer.to(device)
        self.stats = {k: v.to(device) for k, v in self.stats.items()}
        return self

    def save_pretrained(self, directory: str | os.PathLike) -> Path:
        """Write the self-contained checkpoint directory (file by file, atomically); config.yaml holds the network's
        and the denoiser's fully resolved configs, so the checkpoint loads the same whatever the presets become."""
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        self.tokenizer.save(d / "tokenizer")
        save_tensors(d / "latent_stats.safetensors", self.stats)
        save_tensors(d / "model.safetensors", self.denoiser.net.state_dict())
        cfg = OmegaConf.to_container(self.cfg, resolve=True)  # each component's resolved config: no preset look-ups
        cfg |= {"model": dataclasses.asdict(self.denoiser.net.cfg), "edm": dataclasses.asdict(self.denoiser.cfg)}
        write_text(d / "config.yaml", OmegaConf.to_yaml(cfg))
        return d

    @torch.no_grad()
    def encode(self, video: Tensor) -> Tensor:
        """Video `(B, 3, T, H, W)` in [-1, 1] -> normalised latents."""
        z = self.tokenizer.encode(video.to(self.device))
        return (z - self._stat("mean")) / self._stat("std")

    @torch.no_grad()
    def decode(self, z: Tensor) -> Tensor:
        return self.tokenizer.decode(z * self._stat("std") + self._stat("mean"))

    def _stat(self, name: str) -> Tensor:
        return self.stats[name][:, None, None, None]

    def text_tokens(self, prompt: str | None) -> tuple[Tensor | None, Tensor | None]:
        if not prompt:
            return None, None
        enc = get_text_encoder(self.cfg.text.path, int(self.cfg.text.max_length))
        emb, mask = enc.tokens([prompt])
        return emb.to(self.device), mask.to(self.device)

    def _check(self, video: np.ndarray | None, actions: np.ndarray | None, num_frames: int) -> None:
        if num_frames < 1:
            raise ConfigError(f"num_frames={num_frames}: ask for at least 1 frame")
        if video is not None:
            if video.dtype != np.uint8 or video.ndim != 4 or video.shape[-1] != 3 or len(video) == 0:
                raise InputError(f"video must be uint8 (k, H, W, 3) with k >= 1; got {video.dtype} {video.shape}")
            if video.shape[1:3] != self.size:
                raise InputError(f"video frames are {video.shape[1]}x{video.shape[2]}; this model generates "
                                 f"{self.size[0]}x{self.size[1]}: resize them (e.g. video.read_frames(size=...))")
        if actions is not None:
            a = self.denoiser.net.cfg.action_dim
            if actions.ndim != 2 or actions.shape[1] != a or len(actions) < num_frames - 1:
                raise InputError(f"actions must be (T, {a}) with T >= num_frames - 1 = {num_frames - 1}; "
                                 f"got {actions.shape}")

    @torch.no_grad()
    def __call__(
        self, prompt: str | None = None, video: np.ndarray | None = None, actions: np.ndarray | None = None,
        num_frames: int | None = None, steps: int = 35, guidance: float = 1.0, action_guidance: float = 1.0,
        seed: int = 0, sampler: str = "heun", churn: float = 0.0, fps: float | None = None,
    ) -> WorldModelOutput:
        """Generate `num_frames` frames (default: one training window), the given `video` frames first."""
        num_frames = num_frames or self.window
        video = None if video is None else np.asarray(video)
        actions = None if actions is None else np.asarray(actions, dtype=np.float32)
        self._check(video, actions, num_frames)
        verdicts = []
        if self.guardrails is not None and prompt is not None:
            verdicts.append(self.guardrails.check_prompt(prompt))
            if not verdicts[-1].allowed:
                return WorldModelOutput(None, verdicts)
        frames = self._generate(prompt, video, actions, num_frames, steps, guidance, action_guidance, seed, sampler,
                                churn, fps)
        if self.guardrails is not None:
            verdicts.append(self.guardrails.check_video(frames))
            if not verdicts[-1].allowed:
                return WorldModelOutput(None, verdicts)
            frames = self.guardrails.postprocess(frames)
        return WorldModelOutput(frames, verdicts)

    def _generate(self, prompt, video, actions, num_frames, steps, guidance, action_guidance, seed, sampler, churn,
                  fps) -> np.ndarray:
        """The unguarded generation: one training window per pass, autoregressively."""
        text, text_mask = self.text_tokens(prompt)
        fps = float(fps or self.cfg.data.fps)
        frames = list(video) if video is not None else []
        h, w = self.size
        cs = self.tokenizer.spatial_compression
        shape = (1, self.tokenizer.latent_channels, 1 + (self.window - 1) // self.ct, h // cs, w // cs)
        net_cfg, window_index = self.denoiser.net.cfg, 0
        while len(frames) < num_frames:  # one window per pass, conditioned on the last frames so far
            n_ctx = 0 if not frames else 1 + self.ct * ((min(len(frames), self.context) - 1) // self.ct)
            start = len(frames) - n_ctx
            ctx = self.encode(to_tensor(np.stack(frames[start:]))) if n_ctx else None
            acts = None
            if actions is not None:
                acts = torch.zeros(1, self.window, actions.shape[1])
                chunk = torch.from_numpy(actions[start : start + self.window])
                acts[0, : len(chunk)] = chunk
                acts = acts.to(self.device) / self.stats["action_scale"]
            cond = make_condition(
                shape, latents=ctx, num_given=0 if ctx is None else ctx.shape[2], text=text, text_mask=text_mask,
                actions=acts, fps=fps, cond_sigma=self.denoiser.cfg.cond_sigma, text_dim=net_cfg.text_dim,
                action_dim=net_cfg.action_dim, ct=self.ct, device=self.device,
                generator=torch.Generator(device=self.device).manual_seed(seed + 7919 * (window_index + 1)),
            )
            z = sample(self.denoiser, cond, steps=steps, sampler=sampler, guidance=guidance,
                       action_guidance=action_guidance, churn=churn, seed=seed + window_index)
            window_index += 1
            frames += list(to_frames(self.decode(z))[n_ctx:])
        return np.stack(frames[:num_frames])
