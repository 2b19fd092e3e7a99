"""Latent diffusion transformer (DiT) for world models, read top-down like facebookresearch/DiT `models.py`:
embedders, attention, the block, the final layer, the model, then named size presets.

The network knows nothing about noise schedules (see denoiser.py): it maps a preconditioned latent video
plus a given-frame mask channel, a per-latent-frame noise embedding, text tokens and per-frame actions to
an output of the latent's shape.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn


@dataclass
class DiTConfig:
    """Network hyper-parameters; `size` picks a preset in PRESETS, explicit fields override it."""

    size: str = "nano"
    latent_channels: int = 16
    patch: int = 2  # spatial patch; the temporal patch is 1 (one latent frame per token row)
    dim: int = 0  # 0: from the preset
    depth: int = 0
    heads: int = 0
    adaln_lora_rank: int = 0
    mlp_ratio: float = 4.0
    text_dim: int = 384
    action_dim: int = 2
    temporal_compression: int = 4  # pixel frames per latent frame (actions are grouped by it)
    rope_theta: float = 10000.0
    rope_fps: float = 16.0  # temporal RoPE positions count pixel-frame time at this frame rate

    def resolved(self) -> DiTConfig:
        """This config with the preset's values filled in where a field is 0."""
        if self.size not in PRESETS:
            raise ValueError(f"unknown DiT size {self.size!r}; choose one of {', '.join(PRESETS)}")
        preset = PRESETS[self.size]
        vals = {k: getattr(self, k) or preset[k] for k in preset}
        return DiTConfig(**{**self.__dict__, **vals})


#################################################################################
#               Embedding layers for noise levels, actions and positions          #
#################################################################################


def timestep_embedding(t: Tensor, dim: int, max_period: float = 10000.0) -> Tensor:
    """Sinusoidal embedding of scalar noise levels `t (...)` -> `(..., dim)`."""
    half = dim // 2
    freqs = torch.exp(-math.log(max_period) * torch.arange(half, dtype=torch.float32, device=t.device) / half)
    args = t[..., None].float() * freqs
    return torch.cat([torch.cos(args), torch.sin(args)], dim=-1)


class TimestepEmbedder(nn.Module):
    """Per-latent-frame noise level -> conditioning vector (given frames carry their own, lower, level)."""

    def __init__(self, dim: int, freq_dim: int = 256):
        super().__init__()
        self.freq_dim = freq_dim
        self.mlp = nn.Sequential(nn.Linear(freq_dim, dim), nn.SiLU(), nn.Linear(dim, dim))

    def forward(self, c_noise: Tensor) -> Tensor:
        return self.mlp(timestep_embedding(c_noise, self.freq_dim))


class ActionEmbedder(nn.Module):
    """The actions that lead into each latent frame (grouped, `(B, T, ct*A)`) -> a vector added to that
    frame's conditioning; samples without actions (dropped for guidance) get a learned null vector."""

    def __init__(self, in_dim: int, dim: int):
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(in_dim, dim), nn.SiLU(), nn.Linear(dim, dim))
        self.null = nn.Parameter(torch.zeros(dim))

    def forward(self, actions: Tensor, has_actions: Tensor) -> Tensor:
        return torch.where(has_actions[:, None, None], self.mlp(actions), self.null)


class RoPE3D(nn.Module):
    """Factorised 3D rotary positions: the head dim is split into t/h/w parts; time is in pixel frames
    scaled by `rope_fps / fps`, so clips at other frame rates get consistent temporal distances."""

    def __init__(self, head_dim: int, theta: float, temporal_compression: int, rope_fps: float):
        super().__init__()
        self.dh = self.dw = head_dim // 6 * 2
        self.dt = head_dim - self.dh - self.dw
        self.theta, self.ct, self.rope_fps = theta, temporal_compression, rope_fps

    def _freqs(self, pos: Tensor, d: int) -> Tensor:
        inv = self.theta ** (-torch.arange(0, d, 2, dtype=torch.float32, device=pos.device) / d)
        return pos[..., None] * inv

    def forward(self, t: int, h: int, w: int, fps: Tensor) -> tuple[Tensor, Tensor]:
        """cos and sin of shape `(B, 1, t*h*w, head_dim/2)` for tokens ordered (t, h, w)."""
        dev = fps.device
        tpos = torch.arange(t, device=dev, dtype=torch.float32)[None] * self.ct * (self.rope_fps / fps[:, None])
        ft = self._freqs(tpos, self.dt)[:, :, None, None].expand(-1, t, h, w, -1)
        fh = self._freqs(torch.arange(h, device=dev, dtype=torch.float32), self.dh)[None, None, :, None]
        fw = self._freqs(torch.arange(w, device=dev, dtype=torch.float32), self.dw)[None, None, None, :]
        b = fps.shape[0]
        angles = torch.cat([ft, fh.expand(b, t, h, w, -1), fw.expand(b, t, h, w, -1)], dim=-1)
        angles = angles.reshape(b, 1, t * h * w, -1)
        return angles.cos(), angles.sin()


def apply_rope(x: Tensor, cos: Tensor, sin: Tensor) -> Tensor:
    """Rotate consecutive channel pairs of `x (B, heads, N, head_dim)` by the given angles."""
    x1, x2 = x.float().unflatten(-1, (-1, 2)).unbind(-1)
    out = torch.stack([x1 * cos - x2 * sin, x1 * sin + x2 * cos], dim=-1).flatten(-2)
    return out.type_as(x)


def modulate(x: Tensor, shift: Tensor, scale: Tensor) -> Tensor:
    """adaLN on tokens grouped per latent frame: `x (B, T, HW, D)`, shift/scale `(B, T, D)`."""
    return x * (1 + scale[:, :, None]) + shift[:, :, None]


#################################################################################
#                                 Core DiT Model                                #
#################################################################################


class SelfAttention(nn.Module):
    """Full spatio-temporal self-attention with QK RMSNorm and 3D RoPE, on torch SDPA."""

    def __init__(self, dim: int, heads: int):
        super().__init__()
        self.heads = heads
        self.qkv = nn.Linear(dim, 3 * dim)
        self.q_norm = nn.RMSNorm(dim // heads)
        self.k_norm = nn.RMSNorm(dim // heads)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: Tensor, rope: tuple[Tensor, Tensor]) -> Tensor:
        q, k, v = self.qkv(x).unflatten(-1, (3, self.heads, -1)).permute(2, 0, 3, 1, 4)
        q, k = apply_rope(self.q_norm(q), *rope), apply_rope(self.k_norm(k), *rope)
        return self.proj(F.scaled_dot_product_attention(q, k, v).transpose(1, 2).flatten(2))


class CrossAttention(nn.Module):
    """Attention from video tokens to text tokens (QK RMSNorm); the mask hides padding and dropped text."""

    def __init__(self, dim: int, heads: int):
        super().__init__()
        self.heads = heads
        self.q = nn.Linear(dim, dim)
        self.kv = nn.Linear(dim, 2 * dim)
        self.q_norm = nn.RMSNorm(dim // heads)
        self.k_norm = nn.RMSNorm(dim // heads)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: Tensor, ctx: Tensor, ctx_mask: Tensor) -> Tensor:
        q = self.q_norm(self.q(x).unflatten(-1, (self.heads, -1)).transpose(1, 2))
        k, v = self.kv(ctx).unflatten(-1, (2, self.heads, -1)).permute(2, 0, 3, 1, 4)
        out = F.scaled_dot_product_attention(q, self.k_norm(k), v, attn_mask=ctx_mask[:, None, None, :])
        return self.proj(out.transpose(1, 2).flatten(2))


class DiTBlock(nn.Module):
    """Self-attention, cross-attention to text, MLP; each sub-layer with adaLN shift/scale/gate.

    Modulation is Cosmos' adaLN-LoRA: a projection shared by all blocks (computed once in the model) plus a
    low-rank per-block projection of the same conditioning vector.
    """

    def __init__(self, dim: int, heads: int, mlp_ratio: float, lora_rank: int):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)
        self.attn = SelfAttention(dim, heads)
        self.norm2 = nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)
        self.cross = CrossAttention(dim, heads)
        self.norm3 = nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)
        hidden = int(dim * mlp_ratio)
        self.mlp = nn.Sequential(nn.Linear(dim, hidden), nn.GELU(approximate="tanh"), nn.Linear(hidden, dim))
        self.adaLN_lora = nn.Sequential(nn.SiLU(), nn.Linear(dim, lora_rank, bias=False),
                                        nn.Linear(lora_rank, 9 * dim, bias=False))

    def forward(self, x: Tensor, c: Tensor, shared_mod: Tensor, rope: tuple[Tensor, Tensor],
                ctx: Tensor, ctx_mask: Tensor) -> Tensor:
        b, t, hw, d = x.shape
        (sh1, sc1, g1, sh2, sc2, g2, sh3, sc3, g3) = (shared_mod + self.adaLN_lora(c)).chunk(9, dim=-1)
        flat = (b, t * hw, d)
        x = x + g1[:, :, None] * self.attn(modulate(self.norm1(x), sh1, sc1).reshape(flat), rope).view_as(x)
        x = x + g2[:, :, None] * self.cross(modulate(self.norm2(x), sh2, sc2).reshape(flat), ctx, ctx_mask).view_as(x)
        return x + g3[:, :, None] * self.mlp(modulate(self.norm3(x), sh3, sc3))


class FinalLayer(nn.Module):
    """adaLN then a linear map from each token back to its 2x2 latent patch."""

    def __init__(self, dim: int, patch: int, out_channels: int):
        super().__init__()
        self.norm = nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)
        self.linear = nn.Linear(dim, patch * patch * out_channels)
        self.adaLN_modulation = nn.Sequential(nn.SiLU(), nn.Linear(dim, 2 * dim))

    def forward(self, x: Tensor, c: Tensor) -> Tensor:
        shift, scale = self.adaLN_modulation(c).chunk(2, dim=-1)
        return self.linear(modulate(self.norm(x), shift, scale))


class DiT(nn.Module):
    """Latent video DiT: linear 1x2x2 patchify, per-frame adaLN-LoRA conditioning (noise level + actions),
    text cross-attention, 3D RoPE; input has one extra channel marking the given (condition) frames."""

    def __init__(self, cfg: DiTConfig):
        super().__init__()
        cfg = cfg.resolved()
        self.cfg = cfg
        d, p, c = cfg.dim, cfg.patch, cfg.latent_channels
        self.x_embed = nn.Linear((c + 1) * p * p, d)
        self.t_embed = TimestepEmbedder(d)
        self.a_embed = ActionEmbedder(cfg.temporal_compression * cfg.action_dim, d)
        self.shared_mod = nn.Sequential(nn.SiLU(), nn.Linear(d, 9 * d))
        self.text_proj = nn.Sequential(nn.Linear(cfg.text_dim, d), nn.GELU(approximate="tanh"), nn.Linear(d, d))
        self.text_null = nn.Parameter(torch.zeros(1, 1, d))  # always attendable, so dropped text is well-defined
        self.rope = RoPE3D(d // cfg.heads, cfg.rope_theta, cfg.temporal_compression, cfg.rope_fps)
        self.blocks = nn.ModuleList(
            DiTBlock(d, cfg.heads, cfg.mlp_ratio, cfg.adaln_lora_rank) for _ in range(cfg.depth)
        )
        self.final = FinalLayer(d, p, c)
        self.initialize_weights()

    def initialize_weights(self) -> None:
        def _basic_init(m: nn.Module) -> None:
            if isinstance(m, nn.Linear):
                nn.init.xavier_uniform_(m.weight)
                if m.bias is not None:
                    nn.init.zeros_(m.bias)

        self.apply(_basic_init)
        nn.init.normal_(self.t_embed.mlp[0].weight, std=0.02)
        nn.init.normal_(self.t_embed.mlp[2].weight, std=0.02)
        nn.init.normal_(self.text_null, std=0.02)
        # Zero-out adaLN modulation (shared, per-block LoRA up-projection, final) and the output layer, so
        # every block starts as the identity and the model's initial output is 0 (DiT's adaLN-Zero).
        for m in (self.shared_mod[-1], self.final.adaLN_modulation[-1], self.final.linear):
            nn.init.zeros_(m.weight)
            nn.init.zeros_(m.bias)
        for block in self.blocks:
            nn.init.zeros_(block.adaLN_lora[-1].weight)

    def patchify(self, x: Tensor) -> Tensor:
        """`(B, C, T, H, W)` -> `(B, T, H/p * W/p, C*p*p)`."""
        b, c, t, h, w = x.shape
        p = self.cfg.patch
        x = x.reshape(b, c, t, h // p, p, w // p, p).permute(0, 2, 3, 5, 1, 4, 6)
        return x.reshape(b, t, (h // p) * (w // p), c * p * p)

    def unpatchify(self, x: Tensor, h: int, w: int) -> Tensor:
        """`(B, T, H/p * W/p, C*p*p)` -> `(B, C, T, H, W)`."""
        b, t = x.shape[:2]
        p, c = self.cfg.patch, self.cfg.latent_channels
        x = x.reshape(b, t, h // p, w // p, c, p, p).permute(0, 4, 1, 2, 5, 3, 6)
        return x.reshape(b, c, t, h, w)

    def forward(self, x: Tensor, c_noise: Tensor, text: Tensor, text_mask: Tensor, actions: Tensor,
                has_actions: Tensor, fps: Tensor) -> Tensor:
        """x `(B, C+1, T, H, W)`, c_noise `(B, T)`, text `(B, L, text_dim)` with mask `(B, L)`, actions
        `(B, T, ct*A)` with has_actions `(B,)`, fps `(B,)` -> `(B, C, T, H, W)`."""
        b, _, t, h, w = x.shape
        p = self.cfg.patch
        if h % p or w % p:
            raise ValueError(f"latent size {h}x{w} is not divisible by the patch size {p}")
        tokens = self.x_embed(self.patchify(x))
        cond = self.t_embed(c_noise) + self.a_embed(actions, has_actions)  # (B, T, D): one vector per latent frame
        shared_mod = self.shared_mod(cond)
        ctx = torch.cat([self.text_null.expand(b, -1, -1), self.text_proj(text)], dim=1)
        ctx_mask = torch.cat([torch.ones_like(text_mask[:, :1]), text_mask], dim=1)
        rope = self.rope(t, h // p, w // p, fps)
        for block in self.blocks:
            tokens = block(tokens, cond, shared_mod, rope, ctx, ctx_mask)
        return self.unpatchify(self.final(tokens, cond), h, w)


#################################################################################
#                                   DiT Configs                                 #
#################################################################################

PRESETS: dict[str, dict[str, int]] = {
    "tiny": dict(dim=32, depth=2, heads=2, adaln_lora_rank=8),  # tests: seconds
    "nano": dict(dim=192, depth=6, heads=6, adaln_lora_rank=48),  # CPU training within an hour
    "super": dict(dim=1024, depth=24, heads=16, adaln_lora_rank=256),  # GPU
}


def build_dit(size: str = "nano", **overrides) -> DiT:
    """A DiT from a named preset (`tiny`, `nano`, `super`) with optional field overrides."""
    return DiT(DiTConfig(size=size, **overrides))
