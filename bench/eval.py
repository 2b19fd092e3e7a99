"""Metric throughput: frames/s of PSNR + SSIM + object IoU at 256x256 (cosmos_lite.core.metrics, batched) next to
scikit-image measured in the same run (structural_similarity and peak_signal_noise_ratio frame by frame, plus the
same nearest-colour segmentation and per-object IoU written plainly in numpy, frame by frame).
Target: ours >= 5x the baseline's frames/s.

Frames: a 256x256 pusher episode as truth and the same episode one frame later as the prediction.
Both wall-clock and CPU-time rates are printed: on a shared machine the CPU-time ratio is the steadier one.

    .venv/bin/python bench/eval.py [--frames 32] [--size 256] [--repeats 3] [--threads 1]
"""

from __future__ import annotations

import argparse
import resource
import statistics
import time

import numpy as np
import torch
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from cosmos_lite.core.metrics import object_iou_per_frame, psnr_per_frame, segment_by_palette, ssim_per_frame
from cosmos_lite.sim import simulate


def numpy_object_iou(frame: np.ndarray, mask: np.ndarray, palette: dict, scenery: list, ids: list[int],
                     tol: float = 60.0) -> list[float]:
    """Baseline: nearest palette colour within tol, then IoU per object, one frame, plain numpy."""
    cols = np.array([palette[k] for k in palette] + scenery, np.int32)
    lut = np.array([int(k) for k in palette] + [0] * len(scenery), np.uint8)
    d = ((frame[:, :, None, :].astype(np.int32) - cols) ** 2).sum(-1)
    seg = np.where(d.min(-1) <= tol * tol, lut[d.argmin(-1)], 0)
    return [np.logical_and(seg == k, mask == k).sum() / max(np.logical_or(seg == k, mask == k).sum(), 1) for k in ids]


def cpu_seconds() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def rate(fn, frames: int, repeats: int) -> tuple[float, float]:
    """Median frames per wall second and per CPU second of `fn` over `repeats` calls (after one warm-up)."""
    fn()
    walls, cpus = [], []
    for _ in range(repeats):
        t, c = time.perf_counter(), cpu_seconds()
        fn()
        walls.append(time.perf_counter() - t)
        cpus.append(cpu_seconds() - c)
    return frames / statistics.median(walls), frames / statistics.median(cpus)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=32)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1, help="torch threads for ours (scikit-image uses one)")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    ep = simulate("pusher", 0, frames=a.frames + 1, size=a.size, objects=2)
    truth, pred, masks = ep.frames[:-1], ep.frames[1:], ep.masks[:-1]
    palette, scenery = ep.meta["palette"], [ep.meta["scenery_color"]]
    ids = list(range(1, len(ep.meta["objects"]) + 1))

    def ours_psnr_ssim():
        return psnr_per_frame(pred, truth), ssim_per_frame(pred, truth)

    def ours():
        return ours_psnr_ssim(), object_iou_per_frame(segment_by_palette(pred, palette, background=scenery), masks,
                                                      ids)

    def skimage_psnr_ssim():
        return [(peak_signal_noise_ratio(t, p, data_range=255),
                 structural_similarity(t, p, gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
                                       data_range=255, channel_axis=-1)) for t, p in zip(truth, pred)]

    def skimage_all():
        return skimage_psnr_ssim(), [numpy_object_iou(p, m, palette, scenery, ids) for p, m in zip(pred, masks)]

    (ref, ref_iou), ((p, s), iou) = skimage_all(), ours()
    ref = np.array(ref)
    print(f"agreement: max |PSNR diff| {np.abs(ref[:, 0] - p).max():.2e} dB, max |SSIM diff| "
          f"{np.abs(ref[:, 1] - s).max():.2e}, max |IoU diff| {np.abs(np.array(ref_iou) - iou).max():.2e}")
    print(f"{a.frames} frames {a.size}x{a.size}, {a.repeats} repeats, torch threads {a.threads}")
    print(f"{'what':<22} {'ours f/s':>9} {'skimage f/s':>12} {'ratio':>6}   {'(per CPU s: ours':>17} "
          f"{'skimage':>8} {'ratio)':>7}")
    for name, fo, fs in (("PSNR+SSIM", ours_psnr_ssim, skimage_psnr_ssim), ("PSNR+SSIM+IoU", ours, skimage_all)):
        (ow, oc), (sw, sc) = rate(fo, a.frames, a.repeats), rate(fs, a.frames, a.repeats)
        print(f"{name:<22} {ow:9.1f} {sw:12.1f} {ow / sw:5.1f}x   {oc:17.1f} {sc:8.1f} {oc / sc:6.1f}x")
    print("target: PSNR+SSIM+IoU ratio >= 5x (wall clock)")


if __name__ == "__main__":
    main()
