"""Encode and decode a video with a trained tokenizer; print PSNR/SSIM against the input, the compression ratio,
frames/s and (DV) codebook perplexity.

Example: `cosmos-lite tokenize checkpoint=runs/tokenizer_nano input=clip.mp4 output=recon.mp4 size=256`.
Long videos run through overlapping causal windows (window/overlap latent frames), so memory stays bounded; the clip
is edge-padded to the latent grid and the reconstruction cropped back to the input's frames and size.
"""

from __future__ import annotations

import json
from pathlib import Path

from omegaconf import DictConfig, ListConfig

from ..errors import ConfigError
from ..video import probe, read_frames, write_video
from .inference import reconstruct
from .models import load_tokenizer
from .train import codebook_usage


def main(cfg: DictConfig, args: list[str]) -> int:
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
    recon, metrics = reconstruct(tok, frames, cfg.window, cfg.overlap)
    if "indices" in metrics:  # DV: how much of the codebook the clip uses
        metrics.update(codebook_usage(metrics.pop("indices").flatten(), tok.fsq.codebook_size))
    t, h, w = frames.shape[:3]
    result = {"input": str(src), "checkpoint": str(cfg.checkpoint), "variant": tok.cfg.variant, "frames": t,
              "size": [h, w], **metrics}
    if cfg.output:
        write_video(cfg.output, recon, info.fps, crf=cfg.crf)
        result["output"] = str(cfg.output)
    print(json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in result.items()}))
    return 0
