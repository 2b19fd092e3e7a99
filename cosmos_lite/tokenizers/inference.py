"""Tokenizer inference on real clips: padding to the latent grid, long videos by overlapping causal windows,
and the bicubic down/up-sampling baseline the tokenizer is scored against."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator

import numpy as np
import torch
import torch.nn.functional as F

from ..core.frames import to_frames
from .models import Tokenizer

METRIC_CHUNK = 32  # frames scored at a time


def pad_video(x: torch.Tensor, ct: int, cs: int) -> torch.Tensor:
    """Pad (B,3,T,H,W) on the right/bottom/end by edge replication to T = 1 + k*ct and H, W multiples of cs."""
    t, h, w = x.shape[2:]
    pt, ph, pw = (-(t - 1)) % ct, (-h) % cs, (-w) % cs
    if pt:
        x = torch.cat([x, x[:, :, -1:].expand(-1, -1, pt, -1, -1)], 2)
    if ph or pw:
        x = F.pad(x.flatten(1, 2), (0, pw, 0, ph), mode="replicate").unflatten(1, (3, -1))
    return x


def _windows(n: int, window: int, overlap: int) -> list[tuple[int, int, int]]:
    """Latent windows (start, end, keep_from): each window after the first restarts at a group boundary (its latent 0
    is an image latent) and warms up on `overlap` latents whose outputs are dropped, so kept latents see context."""
    if window < overlap + 2:
        raise ValueError(f"window ({window}) must exceed overlap ({overlap}) + 1 latent frames")
    spans, done = [], 0
    while done < n:
        s = 0 if done == 0 else max(0, min(done - overlap - 1, n - window))
        e = min(n, s + window)
        spans.append((s, e, done - s))
        done = e
    return spans


@torch.no_grad()
def encode_long(tok: Tokenizer, x: torch.Tensor, window: int = 8, overlap: int = 3, return_indices: bool = False):
    """Encode a video of any length by overlapping causal windows of `window` latent frames (no seams: every kept
    latent has at least `overlap` latent frames of history); same output as `tok.encode` when it fits one window.
    x: float in [-1, 1] or uint8 (converted window by window, so long clips stay small in memory)."""
    ct, n = tok.temporal_compression, 1 + (x.shape[2] - 1) // tok.temporal_compression
    zs, idx = [], []
    for s, e, keep in _windows(n, window, overlap):
        chunk = x[:, :, s * ct : (e - 1) * ct + 1]
        chunk = chunk.float() / 127.5 - 1 if chunk.dtype == torch.uint8 else chunk
        out = tok.encode(chunk, return_indices=return_indices)
        z, i = out if return_indices else (out, None)
        zs.append(z[:, :, keep:])
        if i is not None:
            idx.append(i[:, keep:])
    z = torch.cat(zs, 2)
    return (z, torch.cat(idx, 1)) if return_indices else z


@torch.no_grad()
def iter_decode(tok: Tokenizer, z: torch.Tensor, window: int = 8, overlap: int = 3) -> Iterator[torch.Tensor]:
    """Decode latents of any length by overlapping causal windows (the mirror of `encode_long`), yielding
    consecutive chunks of frames (B,3,t,H,W)."""
    ct = tok.temporal_compression
    for s, e, keep in _windows(z.shape[2], window, overlap):
        y = tok.decode(z[:, :, s:e])
        yield y if keep == 0 else y[:, :, 1 + (keep - 1) * ct :]


def decode_long(tok: Tokenizer, z: torch.Tensor, window: int = 8, overlap: int = 3) -> torch.Tensor:
    """All of `iter_decode` as one video tensor."""
    return torch.cat(list(iter_decode(tok, z, window, overlap)), 2)


def compression_ratio(tok: Tokenizer, shape: tuple[int, int, int], latent_shape: tuple[int, ...]) -> float:
    """Input size over latent size: 8-bit RGB values over latent values (CV, float) or over token bits (DV)."""
    t, h, w = shape
    if tok.fsq is not None:
        return t * h * w * 3 * 8 / (math.prod(latent_shape[2:]) * math.log2(tok.fsq.codebook_size))
    return t * h * w * 3 / math.prod(latent_shape[1:])


def reconstruct(tok: Tokenizer, frames: np.ndarray, window: int = 8, overlap: int = 3) -> tuple[np.ndarray, dict]:
    """Encode + decode uint8 frames (T,H,W,3) by overlapping windows (edge-padded to the latent grid, cropped back);
    returns (reconstruction, {psnr, ssim, latent, compression, encode_fps, decode_fps, indices (DV only)})."""
    from ..core.metrics import psnr_per_frame, ssim_per_frame

    t, h, w = frames.shape[:3]
    x = pad_video(torch.from_numpy(frames).permute(3, 0, 1, 2)[None], tok.temporal_compression, tok.spatial_compression)
    t0 = time.perf_counter()
    out = encode_long(tok, x, window, overlap, return_indices=tok.fsq is not None)
    z, indices = out if tok.fsq is not None else (out, None)
    t1 = time.perf_counter()
    recon = np.concatenate([to_frames(y[..., :h, :w]) for y in iter_decode(tok, z, window, overlap)])[:t]
    t2 = time.perf_counter()
    spans = [slice(k, k + METRIC_CHUNK) for k in range(0, t, METRIC_CHUNK)]  # bounded memory on long videos
    psnrs = np.concatenate([psnr_per_frame(recon[s], frames[s]) for s in spans])
    ssims = np.concatenate([ssim_per_frame(recon[s], frames[s]) for s in spans])
    result = {
        "psnr": float(psnrs.mean()),
        "ssim": float(ssims.mean()),
        "latent": list(z.shape[1:]),
        "compression": compression_ratio(tok, (t, h, w), tuple(z.shape)),
        "encode_fps": t / (t1 - t0),
        "decode_fps": t / (t2 - t1),
    }
    if indices is not None:
        result["indices"] = indices
    return recon, result


def bicubic_baseline(x: torch.Tensor, values: int, ct: int) -> tuple[torch.Tensor, str]:
    """The best of bicubic spatial downsampling plus temporal subsampling (by 1, 2 or ct) to at least `values`
    numbers, then bicubic/linear upsampling back; returns (reconstruction, description)."""
    b, c, t, h, w = x.shape
    best = None
    for ft in sorted({1, 2, ct}):
        if (t - 1) % ft:
            continue
        keys = x[:, :, ::ft]
        s = math.sqrt(values / (c * keys.shape[2] * h * w))
        hh, ww = min(h, math.ceil(h * s)), min(w, math.ceil(w * s))
        small = F.interpolate(frames2d(keys), size=(hh, ww), mode="bicubic", antialias=True, align_corners=False)
        up = F.interpolate(small, size=(h, w), mode="bicubic", align_corners=False)
        up = up.view(b, -1, c, h, w).transpose(1, 2)
        rec = F.interpolate(up.flatten(3), size=(t, h * w), mode="bilinear", align_corners=True).view(b, c, t, h, w)
        rec = rec.clamp(-1, 1)
        err = (rec - x).square().mean().item()
        if best is None or err < best[0]:
            best = (err, rec, f"{hh}x{ww} every {ft} frame(s)")
    return best[1], best[2]


def frames2d(x: torch.Tensor) -> torch.Tensor:
    """(B,C,T,H,W) -> (B*T,C,H,W)."""
    return x.transpose(1, 2).flatten(0, 1)
