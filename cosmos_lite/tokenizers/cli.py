"""Encode and decode a video with a trained tokenizer; print PSNR/SSIM against the input, the compression ratio,
frames/s and (DV) codebook perplexity.

Example: `cosmos-lite tokenize checkpoint=runs/tokenizer_nano input=clip.mp4 output=recon.mp4 size=256`.
Long videos run through overlapping causal windows (window/overlap latent frames), so memory stays bounded; the clip
is edge-padded to the latent grid and the reconstruction cropped back to the input's frames and size.
"""

from __future__ import annotations

import json

from omegaconf import DictConfig

from ..config import as_list, bad, number
from ..errors import ConfigError
from ..video import probe, read_frames, write_video
from .inference import reconstruct
from .models import load_tokenizer
from .train import codebook_usage

MIN_SIZE = 16  # frames smaller than this are below the metrics' (SSIM) window


def main(cfg: DictConfig, args: list[str]) -> int:
    if not cfg.checkpoint:
        raise ConfigError("pass checkpoint=DIR: a tokenizer checkpoint (e.g. from `cosmos-lite train experiment=...`)")
    src = cfg.input or (args[0] if args else None)
    if not src or len(args) > (0 if cfg.input else 1):
        raise ConfigError("pass input=VIDEO: the one video to tokenize")
    sizes = [number("size", v, low=MIN_SIZE) for v in as_list(cfg.size)]
    if len(sizes) > 2:
        raise bad("size", cfg.size, f"an integer >= {MIN_SIZE} or [H, W] (null: the video's size)")
    size = None if not sizes else sizes[0] if len(sizes) == 1 else tuple(sizes)
    max_frames = None if cfg.max_frames is None else number("max_frames", cfg.max_frames, low=1)
    window = number("window", cfg.window, low=1)
    overlap = number("overlap", cfg.overlap, low=0, high=window - 1)
    crf = number("crf", cfg.crf, low=0, high=51)
    tok = load_tokenizer(cfg.checkpoint)
    info = probe(src)
    frames = read_frames(src, end=max_frames, size=size)
    recon, metrics = reconstruct(tok, frames, window, overlap)
    if "indices" in metrics:  # DV: how much of the codebook the clip uses
        metrics.update(codebook_usage(metrics.pop("indices").flatten(), tok.fsq.codebook_size))
    t, h, w = frames.shape[:3]
    result = {"input": str(src), "checkpoint": str(cfg.checkpoint), "variant": tok.cfg.variant, "frames": t,
              "size": [h, w], **metrics}
    if cfg.output:
        write_video(cfg.output, recon, info.fps, crf=crf)
        result["output"] = str(cfg.output)
    print(json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in result.items()}))
    return 0
