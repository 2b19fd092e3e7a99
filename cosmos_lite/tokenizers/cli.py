"""Encode and decode a video with a trained tokenizer; print PSNR/SSIM against the input and the compression ratio.

Example: `cosmos-lite tokenize checkpoint=runs/tokenizer_nano input=clip.mp4 output=recon.mp4 size=256`.
Long videos run through overlapping causal windows (window/overlap latent frames), so memory stays bounded; the clip
is edge-padded to the latent grid and the reconstruction cropped back to the input's frames and size.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, ListConfig

from ..errors import ConfigError, InputError
from ..video import probe, read_frames, write_video
from .inference import encode_long, iter_decode, pad_video, to_frames
from .models import load_tokenizer


def compression_ratio(tok, shape: tuple[int, int, int], latent_shape: tuple[int, ...]) -> float:
    """Input size over latent size: 8-bit RGB values over latent values (CV, float) or over token bits (DV)."""
    t, h, w = shape
    if tok.fsq is not None:
        return t * h * w * 3 * 8 / (math.prod(latent_shape[2:]) * math.log2(tok.fsq.codebook_size))
    return t * h * w * 3 / math.prod(latent_shape[1:])


def main(cfg: DictConfig, args: list[str]) -> int:
    from ..eval.metrics import ssim

    if not cfg.checkpoint:
        raise ConfigError("pass checkpoint=DIR: a tokenizer checkpoint (e.g. from `cosmos-lite train experiment=...`)")
    src = cfg.input or (args[0] if args else None)
    if not src:
        raise ConfigError("pass input=VIDEO: the video to tokenize")
    if cfg.output and Path(cfg.output).suffix.lower() != ".mp4":
        raise ConfigError(f"output={cfg.output} must end in .mp4")
    tok = load_tokenizer(cfg.checkpoint)
    size = tuple(cfg.size) if isinstance(cfg.size, ListConfig) else cfg.size
    info = probe(src)
    frames = read_frames(src, end=cfg.max_frames, size=size)
    t, h, w = frames.shape[:3]
    x = pad_video(torch.from_numpy(frames).permute(3, 0, 1, 2)[None], tok.temporal_compression, tok.spatial_compression)

    t0 = time.perf_counter()
    z = encode_long(tok, x, cfg.window, cfg.overlap)
    t1 = time.perf_counter()
    sq, ssims, recon, k = 0.0, [], [], 0
    for chunk in iter_decode(tok, z, cfg.window, cfg.overlap):
        rec = to_frames(chunk[..., :h, :w])[: max(0, t - k)]
        ref = frames[k : k + len(rec)]
        sq += float(((rec.astype(np.float64) - ref) ** 2).sum())
        ssims.append(float(ssim(_unit(rec), _unit(ref))) * len(rec))
        recon.append(rec)
        k += len(rec)
    t2 = time.perf_counter()
    if k != t:
        raise InputError(f"{src}: decoded {k} of {t} frames; the checkpoint and clip do not match")
    mse = sq / frames.size
    result = {
        "input": str(src),
        "checkpoint": str(cfg.checkpoint),
        "variant": tok.cfg.variant,
        "frames": t,
        "size": [h, w],
        "latent": list(z.shape[1:]),
        "psnr": 10 * math.log10(255**2 / mse) if mse > 0 else float("inf"),
        "ssim": sum(ssims) / t,
        "compression": compression_ratio(tok, (t, h, w), tuple(z.shape)),
        "encode_fps": t / (t1 - t0),
        "decode_fps": t / (t2 - t1),
    }
    if cfg.output:
        write_video(cfg.output, np.concatenate(recon), info.fps, crf=cfg.crf)
        result["output"] = str(cfg.output)
    print(json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in result.items()}))
    return 0


def _unit(frames: np.ndarray) -> torch.Tensor:
    """uint8 (T,H,W,3) -> float (T,3,H,W) in [0, 1] for the metrics."""
    return torch.from_numpy(frames).permute(0, 3, 1, 2).float() / 255
