"""Causal video tokenizer in the Cosmos style: Haar wavelet patchify, factorised causal residual blocks, hybrid
down/upsampling, a mid-block with spatial and causal temporal attention, continuous (CV) or FSQ (DV) latents.

Reads top-down like DiT's models.py: small blocks, then the encoder/decoder, then the tokenizer, then the variants
and size presets. Causality: time is padded on the left only, norms are per frame and temporal attention is masked,
so latent frame j depends only on input frames up to the end of its group; the first frame is its own group.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

import torch
import torch.nn as nn
import torch.nn.functional as F
from omegaconf import OmegaConf
from safetensors.torch import load_file

from ..config import register, to_dataclass
from ..core.checkpoint import save_tensors
from ..errors import ConfigError, InputError
from ..files import write_text


def frames(x: torch.Tensor) -> torch.Tensor:
    """(B, C, T, H, W) -> (B*T, C, H, W): spatial ops run as 2D ops on a batch of frames (far faster on CPU)."""
    b, c, t, h, w = x.shape
    return x.transpose(1, 2).reshape(b * t, c, h, w)


def unframes(f: torch.Tensor, b: int) -> torch.Tensor:
    """(B*T, C, H, W) -> (B, C, T, H, W), a view."""
    bt, c, h, w = f.shape
    return f.view(b, bt // b, c, h, w).transpose(1, 2)


def norm(c: int) -> nn.GroupNorm:
    """Group norm applied per frame (never across time, which would break causality)."""
    return nn.GroupNorm(math.gcd(c, 8), c, eps=1e-6)


#################################################################################
#                                 Blocks                                        #
#################################################################################


class HaarPatcher(nn.Module):
    """Haar wavelet patchify by `pt` in time and `ps` in space (pt <= ps, powers of 2); the first frame is replicated
    pt times so it forms its own temporal group. Orthonormal, so `inverse` reconstructs exactly.
    (B,3,1+k*pt,H,W) -> (B,3*pt*ps^2,1+k,H/ps,W/ps)."""

    def __init__(self, pt: int, ps: int):
        super().__init__()
        self.pt, self.levels_t, self.levels = pt, int(math.log2(pt)), int(math.log2(ps))

    @staticmethod
    def _butterfly(x: torch.Tensor, dims: tuple[int, ...]) -> torch.Tensor:
        s = 0.5**0.5
        for d in dims:
            a, b = x.narrow(d, 0, 1), x.narrow(d, 1, 1)
            x = torch.cat([(a + b) * s, (a - b) * s], d)
        return x

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = torch.cat([x[:, :, :1].expand(-1, -1, self.pt - 1, -1, -1), x], 2)
        for level in range(self.levels):
            b, c, t, h, w = x.shape
            nt = 2 if level < self.levels_t else 1
            x = self._butterfly(x.reshape(b, c, t // nt, nt, h // 2, 2, w // 2, 2), (3, 5, 7) if nt == 2 else (5, 7))
            x = x.permute(0, 1, 3, 5, 7, 2, 4, 6).reshape(b, c * 4 * nt, t // nt, h // 2, w // 2)
        return x

    def inverse(self, y: torch.Tensor) -> torch.Tensor:
        for level in reversed(range(self.levels)):
            b, cn, t, h, w = y.shape
            nt = 2 if level < self.levels_t else 1
            y = y.reshape(b, cn // (4 * nt), nt, 2, 2, t, h, w)
            y = self._butterfly(y, (2, 3, 4) if nt == 2 else (3, 4))
            y = y.permute(0, 1, 5, 2, 6, 3, 7, 4).reshape(b, cn // (4 * nt), t * nt, h * 2, w * 2)
        return y[:, :, self.pt - 1 :]


class TemporalConv(nn.Conv3d):
    """Causal (k,1,1) convolution over time: padded on the left with the first frame, optionally strided."""

    def __init__(self, cin: int, cout: int, k: int = 3, stride: int = 1):
        super().__init__(cin, cout, (k, 1, 1), stride=(stride, 1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        k = self.kernel_size[0]
        return super().forward(torch.cat([x[:, :, :1].expand(-1, -1, k - 1, -1, -1), x], 2))


class ResBlock(nn.Module):
    """Factorised causal residual block: twice (norm, SiLU, 3x3 spatial conv, causal 3x1x1 temporal conv)."""

    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.norm1, self.conv1s, self.conv1t = norm(cin), nn.Conv2d(cin, cout, 3, padding=1), TemporalConv(cout, cout)
        self.norm2, self.conv2s, self.conv2t = norm(cout), nn.Conv2d(cout, cout, 3, padding=1), TemporalConv(cout, cout)
        self.skip = nn.Conv2d(cin, cout, 1) if cin != cout else nn.Identity()
        nn.init.zeros_(self.conv2t.weight)  # each block starts as the identity (plus skip)
        nn.init.zeros_(self.conv2t.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, f = x.shape[0], frames(x)
        h = self.conv1t(unframes(self.conv1s(F.silu(self.norm1(f))), b))
        h = self.conv2t(unframes(self.conv2s(F.silu(self.norm2(frames(h)))), b))
        return unframes(self.skip(f), b) + h


class Downsample(nn.Module):
    """Hybrid 2x downsampling (strided conv + average pool) in space and/or causally in time."""

    def __init__(self, c: int, spatial: bool, temporal: bool):
        super().__init__()
        self.conv_s = nn.Conv2d(c, c, 3, stride=2) if spatial else None
        self.conv_t = TemporalConv(c, c, 3, stride=2) if temporal else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.conv_s is not None:
            f = frames(x)
            x = unframes(self.conv_s(F.pad(f, (0, 1, 0, 1))) + F.avg_pool2d(f, 2), x.shape[0])
        if self.conv_t is not None:  # T = 1 + 2m -> 1 + m; frame 0 stays its own group
            x = torch.cat([x[:, :, :1], x], 2)
            x = self.conv_t(x) + (x[:, :, 0::2] + x[:, :, 1::2]) / 2
        return x


class Upsample(nn.Module):
    """Hybrid 2x upsampling (repeat + conv, with the repeated input as residual) in space and/or causally in time."""

    def __init__(self, c: int, spatial: bool, temporal: bool):
        super().__init__()
        self.conv_s = nn.Conv2d(c, c, 3, padding=1) if spatial else None
        self.conv_t = TemporalConv(c, c, 3) if temporal else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.conv_t is not None:  # T = 1 + m -> 1 + 2m
            x = x.repeat_interleave(2, dim=2)[:, :, 1:]
            x = x + self.conv_t(x)
        if self.conv_s is not None:
            f = F.interpolate(frames(x), scale_factor=2.0, mode="nearest")
            x = unframes(f + self.conv_s(f), x.shape[0])
        return x


class AttnBlock(nn.Module):
    """Self-attention over the pixels of each frame, then causal self-attention over time at each pixel."""

    def __init__(self, c: int, head_dim: int):
        super().__init__()
        self.heads = max(1, c // head_dim)
        self.norm_s, self.qkv_s, self.proj_s = norm(c), nn.Conv2d(c, 3 * c, 1), nn.Conv2d(c, c, 1)
        self.norm_t, self.qkv_t, self.proj_t = norm(c), nn.Linear(c, 3 * c), nn.Linear(c, c)
        for proj in (self.proj_s, self.proj_t):  # zero-init: the block starts as the identity
            nn.init.zeros_(proj.weight)
            nn.init.zeros_(proj.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, c, t, h, w = x.shape
        n, d = self.heads, c // self.heads
        f = frames(x)
        # Tokens channels-last (last-dim stride 1), which torch's fused CPU attention kernel needs: strided q/k/v fall
        # back to the math path, which materialises the (h*w)^2 scores (80% of the time at 480x854, 8x slower).
        qkv = self.qkv_s(self.norm_s(f)).flatten(2).transpose(1, 2).contiguous()
        q, k, v = qkv.view(b * t, h * w, 3, n, d).permute(2, 0, 3, 1, 4)
        o = F.scaled_dot_product_attention(q, k, v)
        f = f + self.proj_s(o.transpose(1, 2).reshape(b * t, h, w, c).permute(0, 3, 1, 2))
        seq = self.norm_t(f).view(b, t, c, h * w).permute(0, 3, 1, 2).reshape(b * h * w, t, c)
        q, k, v = self.qkv_t(seq).view(b * h * w, t, 3, n, d).permute(2, 0, 3, 1, 4)
        o = F.scaled_dot_product_attention(q, k, v, is_causal=True).transpose(1, 2).reshape(b * h * w, t, c)
        f = f + self.proj_t(o).view(b, h * w, t, c).permute(0, 2, 3, 1).reshape(b * t, c, h, w)
        return unframes(f, b)


class FSQ(nn.Module):
    """Finite scalar quantisation (Mentzer et al. 2023): bound each channel with tanh, round with a straight-through
    gradient; codes lie in [-1, 1] and map one-to-one to integer indices in [0, prod(levels))."""

    def __init__(self, levels: list[int]):
        super().__init__()
        lv = torch.tensor(levels, dtype=torch.long)
        self.register_buffer("levels", lv, persistent=False)
        self.register_buffer("basis", torch.cumprod(torch.cat([lv.new_ones(1), lv[:-1]]), 0), persistent=False)
        self.codebook_size = int(lv.prod())

    def _shape(self, t: torch.Tensor) -> torch.Tensor:
        return t.view(1, -1, 1, 1, 1).to(torch.float32)

    def forward(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """z (B,len(levels),T,H,W) -> (codes of the same shape, indices (B,T,H,W))."""
        lv = self._shape(self.levels)
        half_l = (lv - 1) * (1 + 1e-3) / 2
        offset = (1 - lv % 2) * 0.5
        bounded = torch.tanh(z + torch.atanh(offset / half_l)) * half_l - offset
        rounded = bounded + (bounded.round() - bounded).detach()
        codes = rounded / (lv // 2)
        return codes, self.codes_to_indices(codes.detach())

    def snap(self, codes: torch.Tensor) -> torch.Tensor:
        """Values near codes `(B, len(levels), ...)` -> the nearest codes: each channel's digit (as in
        codes_to_indices) rounded and kept within its levels."""
        lv = self.levels.view(1, -1, *[1] * (codes.dim() - 2)).to(codes.dtype)
        half = lv // 2
        return (torch.minimum((codes * half + half).round().clamp(min=0), lv - 1) - half) / half

    def codes_to_indices(self, codes: torch.Tensor) -> torch.Tensor:
        half = self._shape(self.levels // 2)
        return ((codes * half + half).round().long() * self.basis.view(1, -1, 1, 1, 1)).sum(1)

    def indices_to_codes(self, indices: torch.Tensor) -> torch.Tensor:
        digits = (indices.unsqueeze(1) // self.basis.view(1, -1, 1, 1, 1)) % self.levels.view(1, -1, 1, 1, 1)
        half = self._shape(self.levels // 2)
        return (digits - half) / half


#################################################################################
#                              Encoder / decoder                                #
#################################################################################


class Encoder(nn.Module):
    """Patchified video -> z: conv in, residual levels with hybrid downsampling, attention mid-block, conv out."""

    def __init__(self, cfg: TokenizerConfig):
        super().__init__()
        chans, sd, td = cfg.level_channels(), cfg.spatial_downs(), cfg.temporal_downs()
        self.conv_in = nn.Conv2d(cfg.patch_channels(), chans[0], 3, padding=1)
        self.levels = nn.ModuleList()
        cin = chans[0]
        for i, c in enumerate(chans):
            blocks: list[nn.Module] = []
            for _ in range(cfg.num_res_blocks):
                blocks.append(ResBlock(cin, c))
                cin = c
            if i < len(chans) - 1:
                blocks.append(Downsample(c, spatial=i < sd, temporal=i < td))
            self.levels.append(nn.Sequential(*blocks))
        self.mid = mid_block(cin, cfg)
        self.norm_out, self.conv_out = norm(cin), nn.Conv2d(cin, cfg.z_channels, 3, padding=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b = x.shape[0]
        x = unframes(self.conv_in(frames(x)), b)
        for level in self.levels:
            x = level(x)
        x = self.mid(x)
        return unframes(self.conv_out(F.silu(self.norm_out(frames(x)))), b)


class Decoder(nn.Module):
    """z -> patchified video, mirroring the encoder with one more residual block per level (as in LDM/Cosmos)."""

    def __init__(self, cfg: TokenizerConfig):
        super().__init__()
        chans, sd, td = cfg.level_channels(), cfg.spatial_downs(), cfg.temporal_downs()
        cin = chans[-1]
        self.conv_in = nn.Conv2d(cfg.z_channels, cin, 3, padding=1)
        self.mid = mid_block(cin, cfg)
        self.levels = nn.ModuleList()
        for i in reversed(range(len(chans))):
            blocks: list[nn.Module] = []
            for _ in range(cfg.num_res_blocks + 1):
                blocks.append(ResBlock(cin, chans[i]))
                cin = chans[i]
            if i > 0:
                blocks.append(Upsample(cin, spatial=i - 1 < sd, temporal=i - 1 < td))
            self.levels.append(nn.Sequential(*blocks))
        self.norm_out, self.conv_out = norm(cin), nn.Conv2d(cin, cfg.patch_channels(), 3, padding=1)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        b = z.shape[0]
        x = self.mid(unframes(self.conv_in(frames(z)), b))
        for level in self.levels:
            x = level(x)
        return unframes(self.conv_out(F.silu(self.norm_out(frames(x)))), b)


def mid_block(c: int, cfg: TokenizerConfig) -> nn.Sequential:
    attn = [AttnBlock(c, cfg.head_dim)] if cfg.attention else []
    return nn.Sequential(ResBlock(c, c), *attn, ResBlock(c, c))


#################################################################################
#                                  Tokenizer                                    #
#################################################################################


class Tokenizer(nn.Module):
    """encode (B,3,T,H,W) in [-1,1], T = 1 + k*ct -> z (B,C,1+k,H/cs,W/cs); decode z -> video. DV variants quantise
    z with FSQ (C = len(levels)) and can also return the integer token indices."""

    def __init__(self, cfg: TokenizerConfig):
        super().__init__()
        self.cfg = cfg = cfg.resolved()
        self.patcher = HaarPatcher(cfg.temporal_patch(), cfg.patch_size)
        self.encoder, self.decoder = Encoder(cfg), Decoder(cfg)
        self.quant_conv = nn.Conv3d(cfg.z_channels, self.latent_channels, 1)
        self.post_quant_conv = nn.Conv3d(self.latent_channels, cfg.z_channels, 1)
        self.fsq = FSQ(cfg.levels) if cfg.discrete else None

    @property
    def latent_channels(self) -> int:
        return self.cfg.latent_channels

    @property
    def temporal_compression(self) -> int:
        return self.cfg.temporal_compression

    @property
    def spatial_compression(self) -> int:
        return self.cfg.spatial_compression

    def check_input(self, x: torch.Tensor) -> None:
        """Raise InputError unless x is (B, 3, 1 + k*ct, H, W) with H, W multiples of cs."""
        ct, cs = self.temporal_compression, self.spatial_compression
        if x.ndim != 5 or x.shape[1] != 3 or (x.shape[2] - 1) % ct or x.shape[3] % cs or x.shape[4] % cs:
            raise InputError(
                f"tokenizer {self.cfg.variant} takes (B, 3, 1 + k*{ct}, H, W) with H, W multiples of {cs}; got "
                f"{tuple(x.shape)}. Pad or trim the clip (cosmos_lite.tokenizers.inference.pad_video does this)."
            )

    def encode(self, x: torch.Tensor, return_indices: bool = False):
        """Video (B,3,T,H,W) in [-1,1] -> latent z; for DV, `return_indices=True` gives (z, indices (B,T',H',W'))."""
        self.check_input(x)
        z = self.quant_conv(self.encoder(self.patcher(x)))
        if self.fsq is None:
            if return_indices:
                raise ConfigError(f"{self.cfg.variant} is continuous; only dv* variants have token indices")
            return z
        codes, indices = self.fsq(z)
        return (codes, indices) if return_indices else codes

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """Latent z (or FSQ codes) -> video (B,3,1+(T'-1)*ct,H'*cs,W'*cs), roughly in [-1,1] (not clamped)."""
        return self.patcher.inverse(self.decoder(self.post_quant_conv(z)))

    def decode_indices(self, indices: torch.Tensor) -> torch.Tensor:
        """FSQ token indices (B,T',H',W') -> video (DV variants only)."""
        if self.fsq is None:
            raise ConfigError(f"{self.cfg.variant} is continuous; only dv* variants decode token indices")
        return self.decode(self.fsq.indices_to_codes(indices))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.decode(self.encode(x))

    def save(self, directory: str | Path, extra: dict | None = None) -> Path:
        """Write model.safetensors and config.yaml (`tokenizer:` the resolved config, plus any `extra` sections such
        as the training run's config) into `directory`, each through a temp file then rename."""
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        save_tensors(d / "model.safetensors", self.state_dict())
        config = OmegaConf.create({"tokenizer": OmegaConf.structured(self.cfg), **(extra or {})})
        write_text(d / "config.yaml", OmegaConf.to_yaml(config, resolve=True))
        return d


#################################################################################
#                          Variants, size presets, I/O                          #
#################################################################################

# name -> (discrete, temporal compression, spatial compression). The Cosmos factors are for real video; cv1x4x4,
# dv1x4x4 and cv2x4x4 fit 64x64 simulator scenes, where a 6-10 px object must span several latent cells and its
# 2-3 px of motion per frame must not be folded into one latent frame.
VARIANTS = {
    "cv1x4x4": (False, 1, 4),
    "cv2x4x4": (False, 2, 4),
    "cv4x8x8": (False, 4, 8),
    "cv8x8x8": (False, 8, 8),
    "cv8x16x16": (False, 8, 16),
    "dv1x4x4": (True, 1, 4),
    "dv4x8x8": (True, 4, 8),
    "dv8x8x8": (True, 8, 8),
    "dv8x16x16": (True, 8, 16),
}

# tiny: tests (seconds); nano: trains on 2 CPU cores and runs >= 21 frames/s at 256x256; super: GPU (Cosmos scale).
# The decoder ends in a conv from the first level's channels to the 3*p^3 Haar coefficients of each patch, so at each
# spatial frequency its output lies in a subspace of that many dimensions. With nano's old first level of 32, the best
# such subspaces (PCA of simulator patches) bound held-out PSNR at 32.1 dB, the target; 64 lifts it to 34.7.
SIZES = {
    "tiny": dict(channels=8, channels_mult=[1, 2, 2], num_res_blocks=1, attention=True),
    "nano": dict(channels=32, channels_mult=[2, 2, 2], num_res_blocks=1, attention=True),
    "super": dict(channels=128, channels_mult=[2, 4, 4], num_res_blocks=2, attention=True),
}


@dataclass
class TokenizerConfig:
    """Variant and size preset; null architecture fields take the preset's value (`resolved()` fills them)."""

    variant: str = "cv4x8x8"
    size: str = "tiny"
    channels: int | None = None
    channels_mult: list[int] | None = None
    num_res_blocks: int | None = None
    attention: bool | None = None
    patch_size: int = 4
    z_channels: int = 16
    head_dim: int = 32
    levels: list[int] = field(default_factory=lambda: [8, 8, 8, 5, 5, 5])

    def resolved(self) -> TokenizerConfig:
        if self.variant not in VARIANTS:
            raise ConfigError(f"unknown tokenizer variant {self.variant!r}; choose one of {', '.join(VARIANTS)}")
        if self.size not in SIZES:
            raise ConfigError(f"unknown tokenizer size {self.size!r}; choose one of {', '.join(SIZES)}")
        preset = {k: v for k, v in SIZES[self.size].items() if getattr(self, k) is None}
        cfg = dataclasses.replace(self, **preset)
        cfg.channels_mult = list(cfg.channels_mult)
        if cfg.temporal_downs() < 0 or cfg.spatial_downs() < 0:
            raise ConfigError(f"patch_size={cfg.patch_size} exceeds the compression of {cfg.variant}")
        if len(cfg.channels_mult) < max(cfg.temporal_downs(), cfg.spatial_downs()) + 1:
            raise ConfigError(f"channels_mult {cfg.channels_mult} needs one entry per level of {cfg.variant}")
        return cfg

    @property
    def discrete(self) -> bool:
        return VARIANTS[self.variant][0]

    @property
    def latent_channels(self) -> int:
        return len(self.levels) if self.discrete else self.z_channels

    @property
    def temporal_compression(self) -> int:
        return VARIANTS[self.variant][1]

    @property
    def spatial_compression(self) -> int:
        return VARIANTS[self.variant][2]

    def temporal_patch(self) -> int:
        """Haar patch size in time: the spatial patch, or less where the variant compresses time less."""
        return min(self.patch_size, self.temporal_compression)

    def patch_channels(self) -> int:
        return 3 * self.temporal_patch() * self.patch_size**2

    def temporal_downs(self) -> int:
        return int(math.log2(self.temporal_compression // self.temporal_patch())) if self.patch_size else -1

    def spatial_downs(self) -> int:
        return int(math.log2(self.spatial_compression // self.patch_size)) if self.patch_size else -1

    def level_channels(self) -> list[int]:
        n = max(self.temporal_downs(), self.spatial_downs()) + 1
        return [self.channels * m for m in self.channels_mult[:n]]


register("tokenizer", "base", TokenizerConfig)


def build_tokenizer(variant: str = "cv4x8x8", size: str = "tiny", **overrides) -> Tokenizer:
    """A freshly initialised tokenizer, e.g. `build_tokenizer("dv8x16x16", "nano")`."""
    return Tokenizer(TokenizerConfig(variant=variant, size=size, **overrides))


def tokenizer_config(directory: str | Path) -> TokenizerConfig:
    """The config of a checkpoint directory written by `Tokenizer.save` (its config.yaml), without the weights."""
    d = Path(directory)
    weights, config = d / "model.safetensors", d / "config.yaml"
    for path in (weights, config):
        if not path.is_file():
            raise InputError(f"{path} is missing: pass a tokenizer checkpoint directory written by Tokenizer.save")
    node = OmegaConf.load(config)
    if "model" in node and (d / "tokenizer" / "config.yaml").is_file():
        raise InputError(f"{d} is a world-model checkpoint; its tokenizer is in {d / 'tokenizer'}: pass that folder")
    if "tokenizer" not in node:
        raise InputError(f"{config} has no `tokenizer:` section; it is not a tokenizer checkpoint")
    return to_dataclass(TokenizerConfig, node.tokenizer, where=f"{config}: tokenizer")


def load_tokenizer(directory: str | Path, device: str | torch.device = "cpu") -> Tokenizer:
    """Load a checkpoint directory (model.safetensors + config.yaml) written by `Tokenizer.save`, in eval mode."""
    model = Tokenizer(tokenizer_config(directory))
    model.load_state_dict(load_file(Path(directory) / "model.safetensors", device=str(device)))
    return model.to(device).eval()
