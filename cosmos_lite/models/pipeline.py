"""Diffusers-style world-model pipeline: first frames + prompt + actions -> video, one latent frame at a time, each
predicted from the frames before it (the given ones, then its own), so video2world from any number of given frames,
text2world (no given frame: the first one is generated from the prompt) and long rollouts are the same loop. A
checkpoint directory is self-contained: model.safetensors, config.yaml (every component's resolved config),
latent_stats.safetensors and the tokenizer it was trained on (tokenizer/)."""

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
from .conditioning import context_window, make_condition
from .denoiser import Denoiser, EDMConfig
from .dit import DiT, DiTConfig
from .samplers import SAMPLERS, sample_next

DECODE_OVERLAP = 3  # latent frames decoded before the one wanted (the causal decoder's reach: <= 1 grey level off)
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
    """The DiT and its EDM wrapper from a run's config (`model`, `edm` nodes)."""
    return Denoiser(DiT(to_dataclass(DiTConfig, cfg.model, "model")), to_dataclass(EDMConfig, cfg.edm, "edm"))


def load_network(net: DiT, directory: Path) -> None:
    """The weights of checkpoint folder `directory` into `net`, built from its config.yaml; InputError naming the
    weight groups that differ and the fix when the two do not match."""
    weights = load_file(directory / "model.safetensors")
    try:
        net.load_state_dict(weights)
    except RuntimeError:
        want, have = ({k.split(".")[0] for k in keys} for keys in (net.state_dict(), weights))
        raise InputError(f"{directory / 'model.safetensors'} does not hold the network {directory / 'config.yaml'} "
                         f"describes (missing: {', '.join(sorted(want - have)) or '-'}; unexpected: "
                         f"{', '.join(sorted(have - want)) or '-'}); a checkpoint from an older cosmos-lite may lack "
                         "a newer model.* key: set it in config.yaml (model.action_tokens: false before action "
                         "tokens) or retrain") from None


def snap(z: Tensor, tokenizer: Tokenizer, stats: dict[str, Tensor]) -> Tensor:
    """Normalised latent frames `(B, C, h, w)` onto the tokenizer's code grid (discrete tokenizers; continuous ones
    unchanged), so a rollout's frames stay codes the decoder knows and small errors do not carry forward; `stats`:
    the latents' per-channel mean and std."""
    if tokenizer.fsq is None:
        return z
    mean, std = (stats[k][:, None, None].to(z) for k in ("mean", "std"))
    return (tokenizer.fsq.snap(z * std + mean) - mean) / std


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
        self.size = (int(cfg.data.height), int(cfg.data.width))
        if tokenizer.temporal_compression != 1:
            raise ConfigError(f"the world model predicts one latent frame per pixel frame; tokenizer "
                              f"{tokenizer.cfg.variant} compresses time {tokenizer.temporal_compression}x "
                              "(train one with experiment=tokenizer_sim)")

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
        load_network(denoiser.net, d)
        pipe = cls(denoiser, load_tokenizer(d / "tokenizer"), cfg, load_file(d / "latent_stats.safetensors"),
                   guardrails)
        return pipe.to(device)

    def to(self, device: str | torch.device) -> WorldModelPipeline:
        self.denoiser.to(device)
        self.tokenizer.to(device)
        self.stats = {k: v.to(device) for k, v in self.stats.items()}
        return self

    def save_pretrained(self, directory: str | os.PathLike) -> Path:
        """Write the self-contained checkpoint directory, the weights last (a folder with model.safetensors is
        complete); config.yaml holds the network's and the denoiser's fully resolved configs, so the checkpoint loads
        the same whatever the defaults in code become."""
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        self.tokenizer.save(d / "tokenizer")
        save_tensors(d / "latent_stats.safetensors", self.stats)
        cfg = OmegaConf.to_container(self.cfg, resolve=True)
        cfg |= {"model": dataclasses.asdict(self.denoiser.net.cfg), "edm": dataclasses.asdict(self.denoiser.cfg)}
        write_text(d / "config.yaml", OmegaConf.to_yaml(cfg))
        save_tensors(d / "model.safetensors", self.denoiser.net.state_dict())
        return d

    @torch.no_grad()
    def encode(self, video: Tensor) -> Tensor:
        """Video `(B, 3, T, H, W)` in [-1, 1] -> normalised latent frames `(B, T, C, h, w)`."""
        z = self.tokenizer.encode(video.to(self.device))
        return ((z - self._stat("mean")) / self._stat("std")).transpose(1, 2)

    @torch.no_grad()
    def decode(self, z: Tensor) -> Tensor:
        """Normalised latent frames `(B, T, C, h, w)` -> video `(B, 3, T, H, W)`."""
        return self.tokenizer.decode(z.transpose(1, 2) * self._stat("std") + self._stat("mean"))

    def decode_last(self, z: Tensor, count: int) -> Tensor:
        """The last `count` of the normalised latent frames `z (B, T, C, h, w)` -> video `(B, 3, count, H, W)`,
        decoded after up to DECODE_OVERLAP latent frames before them (the causal decoder's reach), not all T."""
        first = max(0, z.shape[1] - count - DECODE_OVERLAP)
        return self.decode(z[:, first:])[:, :, z.shape[1] - count - first :]

    def _stat(self, name: str) -> Tensor:
        return self.stats[name][:, None, None, None]

    def text_tokens(self, prompt: str | None) -> tuple[Tensor | None, Tensor | None]:
        if not prompt:
            return None, None
        enc = get_text_encoder(self.cfg.text.path, int(self.cfg.text.max_length))
        emb, mask = enc.tokens([prompt])
        return emb.to(self.device), mask.to(self.device)

    def _check(self, video: np.ndarray | None, actions: np.ndarray | None, num_frames: int, steps: int | None,
               sampler: str) -> None:
        if num_frames < 1:
            raise ConfigError(f"num_frames={num_frames}: ask for at least 1 frame")
        if steps is not None and steps < 1:
            raise ConfigError(f"steps={steps}: the sampler needs at least 1 step")
        if sampler not in SAMPLERS:
            raise ConfigError(f"sampler={sampler!r}: choose one of {', '.join(SAMPLERS)}")
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
            if not np.isfinite(actions).all():
                raise InputError("actions hold NaN or infinite values")

    @torch.no_grad()
    def __call__(
        self, prompt: str | None = None, video: np.ndarray | None = None, actions: np.ndarray | None = None,
        num_frames: int | None = None, steps: int | None = None, guidance: float = 1.0, action_guidance: float = 1.0,
        seed: int = 0, sampler: str = "euler", churn: float = 0.0,
    ) -> WorldModelOutput:
        """Generate `num_frames` frames (default: the training clip length), the given `video` frames first.
        `actions[t]` is the action between frames t and t+1 (e.g. the pusher's agent velocity); `steps`: sampler steps
        per frame (None: the checkpoint's `edm.steps`)."""
        num_frames = num_frames or int(self.cfg.data.num_frames)
        video = None if video is None else np.asarray(video)
        actions = None if actions is None else np.asarray(actions, dtype=np.float32)
        self._check(video, actions, num_frames, steps, sampler)
        verdicts = []
        if self.guardrails is not None and prompt is not None:
            verdicts.append(self.guardrails.check_prompt(prompt))
            if not verdicts[-1].allowed:
                return WorldModelOutput(None, verdicts)
        frames = self.rollout(prompt, video, actions, num_frames, steps, guidance, action_guidance, seed, sampler,
                              churn)
        if self.guardrails is not None:
            verdicts.append(self.guardrails.check_video(frames))
            if not verdicts[-1].allowed:
                return WorldModelOutput(None, verdicts)
            frames = self.guardrails.postprocess(frames)
        return WorldModelOutput(frames, verdicts)

    def next_latent(self, latents: Tensor, actions: Tensor | None, t: int, text: Tensor | None,
                    text_mask: Tensor | None, steps: int | None = None, sampler: str = "euler", guidance: float = 1.0,
                    action_guidance: float = 1.0, churn: float = 0.0, generator: torch.Generator | None = None,
                    noise: tuple[Tensor, Tensor] | None = None) -> Tensor:
        """Latent frame t `(B, C, h, w)` sampled from the `context` normalised latent frames before it in `latents
        (B, T, C, h, w)`, with the scaled `actions (B, T, A)` after them (None: no actions) and the prompt's tokens;
        `noise`: the context's and the sample's standard normal noise, (B, context, C, h, w) and (B, C, h, w)
        (None: drawn from `generator`)."""
        net = self.denoiser.net.cfg
        acts = torch.zeros(*latents.shape[:2], net.action_dim, device=self.device) if actions is None else actions
        context, present, context_actions = context_window(latents, acts, torch.full((len(latents),), t,
                                                                                      device=self.device), net.context)
        cond = make_condition(context, present, None if actions is None else context_actions, text=text,
                              text_mask=text_mask, context_sigma=self.denoiser.cfg.context_sigma,
                              generator=generator, text_dim=net.text_dim, action_dim=net.action_dim,
                              context_noise=None if noise is None else noise[0])
        z = sample_next(self.denoiser, cond, steps, sampler, guidance, action_guidance, churn, generator,
                        None if noise is None else noise[1])
        return snap(z, self.tokenizer, self.stats)

    def action_tensor(self, actions: np.ndarray, total: int) -> Tensor:
        """Actions `(K, >= total - 1, A)` between the frames of a `total`-frame rollout -> `(K, total, A)` scaled
        as in training (the last frame has none)."""
        acts = torch.zeros(len(actions), total, self.denoiser.net.cfg.action_dim, device=self.device)
        acts[:, : total - 1] = torch.from_numpy(np.asarray(actions[:, : total - 1], np.float32)).to(self.device)
        return acts / self.stats["action_scale"]

    def stream(self, video: np.ndarray, steps: int | None = None, sampler: str = "euler") -> RolloutStream:
        """A rollout from `video (T, H, W, 3)` continued chunk by chunk (`RolloutStream.extend`), for closed loops
        whose next actions depend on the frames so far."""
        video = np.asarray(video)
        self._check(video, None, len(video), steps, sampler)
        return RolloutStream(self, self.encode(to_tensor(video)), steps, sampler)

    @torch.no_grad()
    def foresee(self, video: np.ndarray, actions: np.ndarray, n: int, seeds: list[int], steps: int | None = None,
                sampler: str = "euler") -> np.ndarray:
        """For planners that score many futures: the frame `n` frames after `video (T, H, W, 3)` under each of K
        action sequences `actions (K, T - 1 + n, A)`, once per seed -> uint8 `(len(seeds), K, H, W, 3)`. One batched
        rollout, unguarded and without a prompt: the given frames are encoded once, and only the last frame is
        decoded (`decode_last`, as `decode_long`'s windows). Under one seed every sequence sees the same noise
        (common random numbers), so their futures differ by the actions alone."""
        video, actions = np.asarray(video), np.asarray(actions, dtype=np.float32)
        if actions.ndim != 3 or not len(actions):
            raise InputError(f"actions must be (K, T, A) with K >= 1; got {actions.shape}")
        total = len(video) + n
        self._check(video, actions[0], total, steps, sampler)
        k, b, net = len(actions), len(seeds) * len(actions), self.denoiser.net.cfg
        given = self.encode(to_tensor(video))
        latents = torch.cat([given.expand(b, -1, -1, -1, -1), given.new_zeros(b, n, *given.shape[2:])], 1)
        acts = self.action_tensor(actions, total).repeat(len(seeds), 1, 1)
        generators = [torch.Generator(device=self.device).manual_seed(int(s)) for s in seeds]

        def shared(*shape: int) -> Tensor:  # one draw per seed, the same for its K sequences
            return torch.cat([torch.randn(1, *shape, generator=g, device=self.device).expand(k, *shape)
                              for g in generators])

        for t in range(len(video), total):
            noise = (shared(net.context, *given.shape[2:]), shared(*given.shape[2:]))
            latents[:, t] = self.next_latent(latents, acts, t, None, None, steps, sampler, noise=noise)
        last = self.decode_last(latents, 1)[:, :, 0]  # (b, 3, H, W)
        return to_frames(last.transpose(0, 1)).reshape(len(seeds), k, *self.size, 3)  # batch as time

    def rollout(self, prompt, video, actions, num_frames, steps, guidance, action_guidance, seed, sampler,
                churn) -> np.ndarray:
        """The unguarded generation: each new latent frame sampled from the last `context` ones."""
        net = self.denoiser.net.cfg
        given = 0 if video is None else min(len(video), num_frames)
        h, w = self.size
        cs = self.tokenizer.spatial_compression
        latents = torch.zeros(1, num_frames, net.latent_channels, h // cs, w // cs, device=self.device)
        if given:
            latents[:, :given] = self.encode(to_tensor(video[:given]))
        acts = None if actions is None else self.action_tensor(actions[None], num_frames)
        text, text_mask = self.text_tokens(prompt)
        generator = torch.Generator(device=self.device).manual_seed(seed)
        for t in range(given, num_frames):
            latents[:, t] = self.next_latent(latents, acts, t, text, text_mask, steps, sampler, guidance,
                                             action_guidance, churn, generator)
        frames = to_frames(self.decode(latents))
        if given:
            frames[:given] = video[:given]
        return frames


class RolloutStream:
    """A rollout continued chunk by chunk (`WorldModelPipeline.stream`), unguarded and without a prompt. It keeps
    the latent frames as the model made them: a fresh `pipe()` per chunk would decode every frame so far and encode
    it again (O(T^2) work, and each round trip changes the codes the next frames are predicted from)."""

    def __init__(self, pipe: WorldModelPipeline, latents: Tensor, steps: int | None, sampler: str):
        self.pipe, self.latents, self.steps, self.sampler = pipe, latents, steps, sampler

    def __len__(self) -> int:
        return self.latents.shape[1]

    @torch.no_grad()
    def extend(self, actions: np.ndarray, n: int, seed: int) -> np.ndarray:
        """The next `n` frames under `actions (len(self) - 1 + n, A)` (those so far and the next n) -> uint8
        `(n, H, W, 3)` (`decode_last`: not the frames so far)."""
        pipe, start = self.pipe, len(self)
        total = start + n
        actions = np.asarray(actions, dtype=np.float32)
        pipe._check(None, actions, total, self.steps, self.sampler)
        acts = pipe.action_tensor(actions[None], total)
        latents = torch.cat([self.latents, self.latents.new_zeros(1, n, *self.latents.shape[2:])], 1)
        generator = torch.Generator(device=pipe.device).manual_seed(seed)
        for t in range(start, total):
            latents[:, t] = pipe.next_latent(latents, acts, t, None, None, self.steps, self.sampler,
                                             generator=generator)
        self.latents = latents
        return to_frames(pipe.decode_last(latents, n))
