"""Next-frame latent diffusion transformer (DiT) for world models, read top-down like facebookresearch/DiT
`models.py`: embedders, attention, the block, the final layer, then the model (size presets: configs/model/wfm_*.yaml).

The network predicts one latent frame from the K latent frames before it (DIAMOND's frame stacking): a token is a
p x p patch of [the noisy next frame, the K context frames, K planes marking which context frames exist]. One
conditioning vector per sample (the noise level of the next frame and of each context frame, Diffusion-Forcing style,
plus the actions that lead into the next frame) modulates every block (adaLN-Zero); text enters by
cross-attention. The network knows nothing about noise schedules (see denoiser.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn


@dataclass
class DiTConfig:
    """Network hyper-parameters; the defaults are the nano size (CPU training within an hour), the other sizes are
    configs/model/wfm_{tiny,super}.yaml. A checkpoint's config.yaml stores every field."""

    latent_channels: int = 16
    context: int = 8  # latent frames the next one is predicted from (8 vs 4 in a 1500-step A/B: object IoU from 9
    # given frames 0.179 vs 0.145, objects found over a 49-frame rollout 56% vs 49%)
    patch: int = 2
    stem: int = 64  # > 0: channels of two 3x3 convolutions over the stacked frames before patchifying (0: linear)
    dim: int = 128
    depth: int = 4
    heads: int = 4
    mlp_ratio: float = 4.0
    text_dim: int = 384
    action_dim: int = 2
    # Each action also a cross-attention token beside the text, so every latent cell can look up the actions itself
    # rather than read them only from the one adaLN vector. The 42-minute bench on one tokenizer and one set of
    # episodes: object IoU from 1 / 9 given frames 0.424 / 0.410 -> 0.442 / 0.429, objects found over 49 frames 80.5%
    # -> 83.6%, pushed-object gap +0.055 / +0.057 -> +0.060 / +0.058, in 7% fewer steps.
    action_tokens: bool = True


#################################################################################
#               Embedding layers for noise levels, actions and positions          #
#################################################################################


def timestep_embedding(t: Tensor, dim: int, max_period: float = 10000.0) -> Tensor:
    """Sinusoidal embedding of scalars `t (...)` -> `(..., dim)`."""
    half = dim // 2
    freqs = torch.exp(-math.log(max_period) * torch.arange(half, dtype=torch.float32, device=t.device) / half)
    args = t[..., None].float() * freqs
    return torch.cat([torch.cos(args), torch.sin(args)], dim=-1)


def sincos_2d(dim: int, h: int, w: int, device: torch.device) -> Tensor:
    """Fixed 2D sine-cosine positions of an h x w token grid (row-major) -> `(h*w, dim)`."""
    gy, gx = torch.meshgrid(torch.arange(h, dtype=torch.float32, device=device),
                            torch.arange(w, dtype=torch.float32, device=device), indexing="ij")
    return torch.cat([timestep_embedding(gy.flatten(), dim // 2), timestep_embedding(gx.flatten(), dim // 2)], -1)


class NoiseEmbedder(nn.Module):
    """Noise levels of the next frame and of each context frame `(B, 1+K)` -> one conditioning vector."""

    def __init__(self, frames: int, dim: int, freq_dim: int = 128):
        super().__init__()
        self.freq_dim = freq_dim
        self.mlp = nn.Sequential(nn.Linear(frames * freq_dim, dim), nn.SiLU(), nn.Linear(dim, dim))

    def forward(self, c_noise: Tensor) -> Tensor:
        return self.mlp(timestep_embedding(c_noise, self.freq_dim).flatten(1))


class ActionEmbedder(nn.Module):
    """The K actions up to the next frame `(B, K, A)` -> a vector; samples without actions (none recorded, or
    dropped for guidance) get a learned null vector."""

    def __init__(self, in_dim: int, dim: int):
        super().__init__()
        self.mlp = nn.Sequential(nn.Linear(in_dim, dim), nn.SiLU(), nn.Linear(dim, dim))
        self.null = nn.Parameter(torch.zeros(dim))

    def forward(self, actions: Tensor, has_actions: Tensor) -> Tensor:
        return torch.where(has_actions[:, None], self.mlp(actions.flatten(1)), self.null)


class PatchEmbed(nn.Module):
    """Stacked latent frames `(B, Cin, H, W)` -> tokens `(B, H/p * W/p, dim)`: a linear map of each p x p patch, or
    with `stem` channels first two 3x3 convolutions at latent resolution, so every token starts from its cells'
    neighbourhood in each frame (where an object was, where it is now) rather than from its own cells alone."""

    def __init__(self, cin: int, dim: int, patch: int, stem: int):
        super().__init__()
        layers: list[nn.Module] = []
        if stem:
            layers = [nn.Conv2d(cin, stem, 3, padding=1), nn.SiLU(), nn.Conv2d(stem, stem, 3, padding=1), nn.SiLU()]
            cin = stem
        self.net = nn.Sequential(*layers, nn.Conv2d(cin, dim, patch, stride=patch))

    def forward(self, x: Tensor) -> Tensor:
        return self.net(x).flatten(2).transpose(1, 2)


def modulate(x: Tensor, shift: Tensor, scale: Tensor) -> Tensor:
    return x * (1 + scale[:, None]) + shift[:, None]


#################################################################################
#                                 Core DiT Model                                #
#################################################################################


class Attention(nn.Module):
    """Multi-head attention with QK RMSNorm on torch SDPA: self-attention, or cross-attention to `ctx` (masked)."""

    def __init__(self, dim: int, heads: int):
        super().__init__()
        self.heads = heads
        self.q = nn.Linear(dim, dim)
        self.kv = nn.Linear(dim, 2 * dim)
        self.q_norm, self.k_norm = nn.RMSNorm(dim // heads), nn.RMSNorm(dim // heads)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: Tensor, ctx: Tensor | None = None, ctx_mask: Tensor | None = None) -> Tensor:
        ctx = x if ctx is None else ctx
        q = self.q_norm(self.q(x).unflatten(-1, (self.heads, -1)).transpose(1, 2))
        k, v = self.kv(ctx).unflatten(-1, (2, self.heads, -1)).permute(2, 0, 3, 1, 4)
        mask = None if ctx_mask is None else ctx_mask[:, None, None, :]
        out = F.scaled_dot_product_attention(q, self.k_norm(k), v, attn_mask=mask)
        return self.proj(out.transpose(1, 2).flatten(2))


class DiTBlock(nn.Module):
    """Self-attention over the frame's tokens, cross-attention to text, MLP; each with adaLN shift/scale/gate."""

    def __init__(self, dim: int, heads: int, mlp_ratio: float):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)
        self.attn = Attention(dim, heads)
        self.norm2 = nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)
        self.cross = Attention(dim, heads)
        self.norm3 = nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)
        hidden = int(dim * mlp_ratio)
        self.mlp = nn.Sequential(nn.Linear(dim, hidden), nn.GELU(approximate="tanh"), nn.Linear(hidden, dim))
        self.adaLN_modulation = nn.Sequential(nn.SiLU(), nn.Linear(dim, 9 * dim))

    def forward(self, x: Tensor, c: Tensor, text: Tensor, text_mask: Tensor) -> Tensor:
        sh1, sc1, g1, sh2, sc2, g2, sh3, sc3, g3 = self.adaLN_modulation(c).chunk(9, dim=-1)
        x = x + g1[:, None] * self.attn(modulate(self.norm1(x), sh1, sc1))
        x = x + g2[:, None] * self.cross(modulate(self.norm2(x), sh2, sc2), text, text_mask)
        return x + g3[:, None] * self.mlp(modulate(self.norm3(x), sh3, sc3))


class FinalLayer(nn.Module):
    """adaLN then a linear map from each token back to its p x p latent patch."""

    def __init__(self, dim: int, patch: int, out_channels: int):
        super().__init__()
        self.norm = nn.LayerNorm(dim, elementwise_affine=False, eps=1e-6)
        self.linear = nn.Linear(dim, patch * patch * out_channels)
        self.adaLN_modulation = nn.Sequential(nn.SiLU(), nn.Linear(dim, 2 * dim))

    def forward(self, x: Tensor, c: Tensor) -> Tensor:
        shift, scale = self.adaLN_modulation(c).chunk(2, dim=-1)
        return self.linear(modulate(self.norm(x), shift, scale))


class DiT(nn.Module):
    """Next-latent-frame DiT: linear patchify of the stacked frames, fixed 2D sine-cosine positions, one adaLN
    conditioning vector per sample (noise levels + actions), text cross-attention."""

    def __init__(self, cfg: DiTConfig):
        super().__init__()
        self.cfg = cfg
        c, k, p, d = cfg.latent_channels, cfg.context, cfg.patch, cfg.dim
        self.x_embed = PatchEmbed((k + 1) * c + k, d, p, cfg.stem)
        self.noise_embed = NoiseEmbedder(1 + k, d)
        self.action_embed = ActionEmbedder(k * cfg.action_dim, d)
        self.text_proj = nn.Sequential(nn.Linear(cfg.text_dim, d), nn.GELU(approximate="tanh"), nn.Linear(d, d))
        self.text_null = nn.Parameter(torch.zeros(1, 1, d))  # always attendable, so dropped text is well-defined
        if cfg.action_tokens:
            self.action_proj = nn.Sequential(nn.Linear(cfg.action_dim, d), nn.SiLU(), nn.Linear(d, d))
            self.action_pos = nn.Parameter(torch.zeros(1, k, d))  # which context frame each action follows
        self.blocks = nn.ModuleList(DiTBlock(d, cfg.heads, cfg.mlp_ratio) for _ in range(cfg.depth))
        self.final = FinalLayer(d, p, c)
        self.initialize_weights()

    def initialize_weights(self) -> None:
        def _basic_init(m: nn.Module) -> None:
            if isinstance(m, nn.Linear | nn.Conv2d):
                nn.init.xavier_uniform_(m.weight)
                if m.bias is not None:
                    nn.init.zeros_(m.bias)

        self.apply(_basic_init)
        nn.init.normal_(self.text_null, std=0.02)
        if self.cfg.action_tokens:
            nn.init.normal_(self.action_pos, std=0.02)
        # Zero-out adaLN modulation and the output layer, so every block starts as the identity and the model's
        # initial output is 0 (DiT's adaLN-Zero).
        for m in [self.final.adaLN_modulation[-1], self.final.linear] + [b.adaLN_modulation[-1] for b in self.blocks]:
            nn.init.zeros_(m.weight)
            nn.init.zeros_(m.bias)

    def unpatchify(self, x: Tensor, h: int, w: int) -> Tensor:
        """`(B, H/p * W/p, C*p*p)` -> `(B, C, H, W)`."""
        b = x.shape[0]
        p, c = self.cfg.patch, self.cfg.latent_channels
        return x.reshape(b, h // p, w // p, c, p, p).permute(0, 3, 1, 4, 2, 5).reshape(b, c, h, w)

    def forward(self, x: Tensor, context: Tensor, present: Tensor, c_noise: Tensor, actions: Tensor,
                has_actions: Tensor, text: Tensor, text_mask: Tensor) -> Tensor:
        """x `(B, C, H, W)` the preconditioned noisy next frame, context `(B, K, C, H, W)` with present `(B, K)`,
        c_noise `(B, 1+K)`, actions `(B, K, A)` with has_actions `(B,)`, text `(B, L, text_dim)` with mask `(B, L)`
        -> `(B, C, H, W)`."""
        b, _, h, w = x.shape
        p = self.cfg.patch
        if h % p or w % p:
            raise ValueError(f"latent size {h}x{w} is not divisible by the patch size {p}")
        planes = present[:, :, None, None].to(x.dtype).expand(-1, -1, h, w)
        tokens = self.x_embed(torch.cat([x, context.flatten(1, 2), planes], dim=1))
        tokens = tokens + sincos_2d(self.cfg.dim, h // p, w // p, x.device)
        cond = self.noise_embed(c_noise) + self.action_embed(actions, has_actions)
        ctx = torch.cat([self.text_null.expand(b, -1, -1), self.text_proj(text)], dim=1)
        ctx_mask = torch.cat([torch.ones_like(text_mask[:, :1]), text_mask], dim=1)
        if self.cfg.action_tokens:
            ctx = torch.cat([ctx, self.action_proj(actions) + self.action_pos], dim=1)
            ctx_mask = torch.cat([ctx_mask, present & has_actions[:, None]], dim=1)
        for block in self.blocks:
            tokens = block(tokens, cond, ctx, ctx_mask)
        return self.unpatchify(self.final(tokens, cond), h, w)


def build_dit(**overrides) -> DiT:
    """A DiT with DiTConfig's defaults (the nano size) and optional field overrides; the size presets are
    configs/model/wfm_{tiny,nano,super}.yaml."""
    return DiT(DiTConfig(**overrides))
