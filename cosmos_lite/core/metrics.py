"""Video metrics, the one home of all of them: PSNR, SSIM (Gaussian window, Wang et al. 2004), mask IoU,
palette segmentation, centroid trajectory and velocity errors (as PhyWorld), motion-mask IoU (as Physics-IQ).

Frames may be uint8 `(T, H, W, 3)` / `(B, T, H, W, 3)` arrays or tensors, or model tensors float `(3, T, H, W)` /
`(B, 3, T, H, W)` in [-1, 1]. Both map to float `(B, T, 3, H, W)` in [0, 1] (data range 255 resp. 2 becomes 1),
so a uint8 video can be scored against a decoded tensor directly. Per-frame metrics return `(T,)` or `(B, T)`.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor

SSIM_SIGMA, SSIM_TRUNCATE, SSIM_K1, SSIM_K2 = 1.5, 3.5, 0.01, 0.03  # skimage's gaussian_weights=True window
MAX_PSNR = 100.0  # dB for identical frames (MSE floored at 1e-10 of the squared data range)
CHUNK_VALUES = 1 << 18  # values (frames x 3 x H x W) per chunk of work: one 256x256 frame; a few MiB per map

ArrayLike = np.ndarray | Tensor


def _frames(x: ArrayLike) -> tuple[Tensor, bool]:
    """Frames in any accepted form -> a view `(B, T, 3, H, W)` in their own dtype and range (uint8 0-255 or float
    in [-1, 1]), and whether the input had a batch axis. No conversion yet: `_unit` converts slices of it."""
    t = x if isinstance(x, Tensor) else torch.from_numpy(np.ascontiguousarray(x))
    if t.dtype == torch.uint8:
        if t.ndim not in (4, 5) or t.shape[-1] != 3:
            raise ValueError(f"uint8 frames must be (T, H, W, 3) or (B, T, H, W, 3), got {tuple(t.shape)}")
        batched = t.ndim == 5
        return (t if batched else t[None]).permute(0, 1, 4, 2, 3), batched
    if t.is_floating_point():
        if t.ndim not in (4, 5) or t.shape[-4] != 3:
            raise ValueError(f"float video tensors must be (3, T, H, W) or (B, 3, T, H, W) in [-1, 1], "
                             f"got {tuple(t.shape)}")
        batched = t.ndim == 5
        return (t if batched else t[None]).transpose(1, 2), batched
    raise TypeError(f"frames must be uint8 (T, H, W, 3) or float (3, T, H, W) in [-1, 1], got dtype {t.dtype}")


def _unit(v: Tensor) -> Tensor:
    """A slice of `_frames`' view as float32 in [0, 1] (a new tensor)."""
    return v.float().div_(255) if v.dtype == torch.uint8 else v.float().add(1).div_(2)


def to_unit(x: ArrayLike) -> tuple[Tensor, bool]:
    """Frames in any accepted form -> (float `(B, T, 3, H, W)` in [0, 1], whether the input had a batch axis)."""
    v, batched = _frames(x)
    return _unit(v), batched


def to_uint8(x: ArrayLike) -> np.ndarray:
    """Frames in any accepted form -> uint8 numpy `(T, H, W, 3)` (or `(B, T, H, W, 3)` if batched)."""
    if x.dtype in (np.uint8, torch.uint8) and x.ndim in (4, 5) and x.shape[-1] == 3:
        return x.cpu().numpy() if isinstance(x, Tensor) else np.asarray(x)
    u, batched = to_unit(x)
    out = (u.clamp(0, 1) * 255).round().to(torch.uint8).permute(0, 1, 3, 4, 2).cpu().numpy()
    return out if batched else out[0]


def _pair(a: ArrayLike, b: ArrayLike) -> tuple[Iterator[tuple[Tensor, Tensor]], tuple[int, int], bool]:
    """Two videos of one shape -> (chunks of both as float `(n, 3, H, W)` in [0, 1], (B, T), whether batched).

    Frames are converted a chunk of about CHUNK_VALUES values at a time: the elementwise work of a metric then runs
    on data that stays in the CPU cache instead of streaming whole float videos through memory."""
    x, batched = _frames(a)
    y, _ = _frames(b)
    if x.shape != y.shape:
        raise ValueError(f"videos differ in shape: {tuple(x.shape)} vs {tuple(y.shape)} (as (B, T, 3, H, W))")
    bt = x.shape[:2]
    x, y = x.flatten(0, 1), y.flatten(0, 1)
    n = max(1, CHUNK_VALUES // x[0].numel())
    return ((_unit(x[i : i + n]), _unit(y[i : i + n]).to(x.device)) for i in range(0, len(x), n)), bt, batched


def _out(v: Tensor, batched: bool) -> np.ndarray:
    v = v.double().cpu().numpy()
    return v if batched else v[0]


@torch.no_grad()
def psnr_per_frame(a: ArrayLike, b: ArrayLike) -> np.ndarray:
    """PSNR in dB of each frame, `(T,)` or `(B, T)`; identical frames score MAX_PSNR."""
    chunks, bt, batched = _pair(a, b)
    mse = torch.cat([(x - y).square_().mean(dim=(1, 2, 3), dtype=torch.float64) for x, y in chunks]).view(bt)
    return _out(10 * torch.log10(1 / mse.clamp_min(10 ** (-MAX_PSNR / 10))), batched)


def psnr(a: ArrayLike, b: ArrayLike) -> float:
    """Mean over frames (and batch) of the per-frame PSNR in dB."""
    return float(psnr_per_frame(a, b).mean())


def gaussian_window(sigma: float = SSIM_SIGMA, truncate: float = SSIM_TRUNCATE) -> Tensor:
    """The normalised 1-D Gaussian of scipy.ndimage (radius int(truncate * sigma + 0.5)): 11 taps for sigma 1.5."""
    r = int(truncate * sigma + 0.5)
    g = torch.exp(-torch.arange(-r, r + 1, dtype=torch.float64) ** 2 / (2 * sigma**2))
    return g / g.sum()


def _blur(x: Tensor, g: Tensor) -> Tensor:
    """Separable 'valid' Gaussian filter of each channel of (N, C, H, W): the border skimage crops is never computed.
    Depthwise (grouped) convolutions: several times faster on CPU than one single-channel conv per map."""
    c = x.shape[1]
    x = F.conv2d(x, g.view(1, 1, 1, -1).expand(c, 1, 1, -1), groups=c)
    return F.conv2d(x, g.view(1, 1, -1, 1).expand(c, 1, -1, 1), groups=c)


@torch.no_grad()
def ssim_per_frame(a: ArrayLike, b: ArrayLike) -> np.ndarray:
    """Gaussian-window SSIM of each frame, averaged over pixels and channels, `(T,)` or `(B, T)`.

    Equals skimage `structural_similarity(gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
    data_range=..., channel_axis=-1)` and pytorch-msssim `ssim(size_average=False)`.
    """
    chunks, bt, batched = _pair(a, b)
    c1, c2 = SSIM_K1**2, SSIM_K2**2
    # Four blurred maps instead of five: of the sum s = x + y - 1 (centred, so E[s^2] - E[s]^2 loses less to float32
    # rounding) and the difference d = x - y, with P = (E[s] + 1)^2, Q = E[d]^2, vs = Var s, vd = Var d:
    # SSIM = (P - Q + 2 c1) (vs - vd + 2 c2) / ((P + Q + 2 c1) (vs + vd + 2 c2)).
    # s, d, s*s, d*d of a chunk as the channels of one channels-last image (h, w, 4 * frames * c): oneDNN's depthwise
    # convolution vectorises over channels, and each map stays a run of frames * c contiguous floats per pixel.
    scores, buf, g = [], None, None
    for xs, ys in chunks:
        n, c, h, w = xs.shape
        if g is None:
            g = gaussian_window().to(xs)
            if min(h, w) < len(g):
                raise ValueError(f"SSIM needs frames of at least {len(g)}x{len(g)} pixels, got {h}x{w}")
            buf = torch.empty(1, 4 * n * c, h, w, device=xs.device).to(memory_format=torch.channels_last)
        k = n * c
        z = buf[:, : 4 * k]
        s, d, ss, dd = (m.view(n, c, h, w) for m in z[0].split(k))
        torch.add(xs, ys, out=s).sub_(1)
        torch.sub(xs, ys, out=d)
        torch.mul(s, s, out=ss), torch.mul(d, d, out=dd)
        ms, md, vs, vd = _blur(z, g)[0].contiguous().split(k)  # planar: the elementwise work below vectorises
        vs.addcmul_(ms, ms, value=-1)  # in place from here
        vd.addcmul_(md, md, value=-1)
        p = ms.add_(1).square_()
        q = md.square_()
        num = (p - q).add_(2 * c1).mul_((vs - vd).add_(2 * c2))
        den = p.add_(q).add_(2 * c1).mul_(vs.add_(vd).add_(2 * c2))
        scores.append(num.div_(den).mean(dim=(1, 2), dtype=torch.float64))
    return _out(torch.cat(scores).view(*bt, -1).mean(-1), batched)


def ssim(a: ArrayLike, b: ArrayLike) -> float:
    """Mean over frames (and batch) of the per-frame SSIM."""
    return float(ssim_per_frame(a, b).mean())


def _masks(m: ArrayLike) -> np.ndarray:
    return m.cpu().numpy() if isinstance(m, Tensor) else np.asarray(m)


def _binary_iou(p: np.ndarray, t: np.ndarray, axes: tuple[int, ...]) -> np.ndarray:
    """IoU of boolean arrays reduced over `axes`; 1 where both are empty (nothing to miss)."""
    inter = np.logical_and(p, t).sum(axes)
    union = np.logical_or(p, t).sum(axes)
    return np.where(union > 0, inter / np.maximum(union, 1), 1.0)


def mask_iou_per_frame(pred: ArrayLike, target: ArrayLike) -> np.ndarray:
    """Foreground IoU (nonzero = in) of each frame of `(T, H, W)` masks -> `(T,)` (1 where both are empty)."""
    p, t = _masks(pred), _masks(target)
    if p.shape != t.shape or p.ndim < 2:
        raise ValueError(f"masks must be (..., H, W) of one shape, got {p.shape} vs {t.shape}")
    return _binary_iou(p != 0, t != 0, (-2, -1)).astype(np.float64)


def mask_iou(pred: ArrayLike, target: ArrayLike) -> float:
    """Foreground IoU (nonzero = in) over all pixels of two masks of one shape (1 if both are empty)."""
    p, t = _masks(pred), _masks(target)
    if p.shape != t.shape:
        raise ValueError(f"masks must have one shape, got {p.shape} vs {t.shape}")
    return float(_binary_iou(p != 0, t != 0, tuple(range(p.ndim))))


def object_ids(target: ArrayLike) -> list[int]:
    """The nonzero object ids present in an id mask."""
    return [int(i) for i in np.unique(_masks(target)) if i != 0]


def object_iou_per_frame(pred: ArrayLike, target: ArrayLike, ids: Sequence[int] | None = None) -> np.ndarray:
    """Per-object IoU of id masks `(T, H, W)` in each frame -> `(T, n_objects)`; NaN where the object is in neither.

    ids: the objects to score (default: those in `target`). One pass: a per-frame joint histogram of (pred, target).
    """
    p, t = _masks(pred), _masks(target)
    if p.shape != t.shape or p.ndim != 3:
        raise ValueError(f"id masks must be (T, H, W) of one shape, got {p.shape} vs {t.shape}")
    ids = object_ids(t) if ids is None else list(ids)
    k = int(max(p.max(initial=0), t.max(initial=0), *ids, 0)) + 1
    frame = np.arange(len(t), dtype=np.int64)[:, None, None] * (k * k)
    joint = np.bincount((frame + p.astype(np.int64) * k + t).ravel(), minlength=len(t) * k * k).reshape(-1, k, k)
    idx = np.array(ids, np.int64)
    inter = joint[:, idx, idx]
    union = joint[:, idx, :].sum(2) + joint[:, :, idx].sum(1) - inter
    return np.where(union > 0, inter / np.maximum(union, 1), np.nan)


def object_iou(pred: ArrayLike, target: ArrayLike, ids: Sequence[int] | None = None) -> dict[int, float]:
    """Per-object IoU of id masks over the whole video (all frames' pixels together): {id: IoU}."""
    p, t = _masks(pred), _masks(target)
    if p.shape != t.shape:
        raise ValueError(f"id masks must have one shape, got {p.shape} vs {t.shape}")
    ids = object_ids(t) if ids is None else list(ids)
    return {k: float(_binary_iou(p == k, t == k, tuple(range(p.ndim)))) for k in ids}


def segment_by_palette(
    frames: ArrayLike,
    palette: Mapping[int, Sequence[int]],
    tol: float = 60.0,
    background: Sequence[Sequence[int]] = (),
) -> np.ndarray:
    """Object-id masks `(T, H, W)` uint8 of rendered or generated frames by nearest palette colour.

    palette: {id: (r, g, b)} (id 0 = background); background: more colours that count as 0 (e.g. scenery).
    A pixel takes the id of the nearest colour if it is within `tol` (Euclidean, 0-255 units), else 0.
    """
    u = to_uint8(frames)
    ids = torch.tensor([int(k) for k in palette] + [0] * len(background), dtype=torch.uint8)
    cols = torch.tensor([list(palette[k]) for k in palette] + [list(c) for c in background], dtype=torch.float32)
    norms = (cols * cols).sum(1, keepdim=True)
    pixels = torch.from_numpy(u).view(-1, 3)
    seg = torch.empty(len(pixels), dtype=torch.uint8)
    step = CHUNK_VALUES // 8  # pixels per chunk: planar float copies of a chunk stay in the cache
    for i in range(0, len(pixels), step):
        f = pixels[i : i + step].T.float()  # planar (3, n): the reductions below run over rows
        # |f - c|^2 = |f|^2 - 2 c.f + |c|^2: a (K, 3) x (3, n) matmul, exact in float32 for 8-bit integers (< 2^24).
        best, nearest = torch.mm(cols, f).mul_(-2).add_(norms).min(0)
        inside = best.add_(f.square_().sum(0)) <= tol * tol
        seg[i : i + step] = ids[nearest].mul_(inside)
    return seg.numpy().reshape(u.shape[:-1])


def palette_object_iou(frames: ArrayLike, masks: ArrayLike, palette: Mapping[int, Sequence[int]],
                       background: Sequence[Sequence[int]] = (), ids: Sequence[int] | None = None) -> float:
    """Mean over frames and objects of the IoU between the palette segmentation of rendered or generated `frames`
    and the true id `masks` `(T, H, W)`: how much of each object comes back in its own colour and place."""
    return float(nanmean(object_iou_per_frame(segment_by_palette(frames, palette, background=background), masks, ids)))


def centroids(masks: ArrayLike, ids: Sequence[int]) -> np.ndarray:
    """Centroids (x, y) in pixels (pixel centres at +0.5) of each object per frame -> `(T, n, 2)`, NaN if absent."""
    m = _masks(masks)
    ys, xs = np.arange(m.shape[1]) + 0.5, np.arange(m.shape[2]) + 0.5
    out = np.full((len(m), len(ids), 2), np.nan)
    for j, k in enumerate(ids):
        mk = m == k
        area = mk.sum((1, 2))
        ok = area > 0
        out[ok, j, 0] = (mk.sum(1) * xs).sum(1)[ok] / area[ok]
        out[ok, j, 1] = (mk.sum(2) * ys).sum(1)[ok] / area[ok]
    return out


def trajectory_errors(pred: ArrayLike, target: ArrayLike, ids: Sequence[int] | None = None) -> dict[str, np.ndarray]:
    """Centroid position error (pixels) and velocity error (pixels/frame) per frame, as PhyWorld measures.

    From id masks `(T, H, W)`: returns `position (T,)`, `velocity (T-1,)` (mean over objects, NaN where no object is
    found in both) and `found (T,)`, the fraction of target objects present in `pred`.
    """
    t = _masks(target)
    ids = object_ids(t) if ids is None else list(ids)
    cp, ct = centroids(pred, ids), centroids(t, ids)
    pos = np.linalg.norm(cp - ct, axis=-1)  # (T, n)
    vel = np.linalg.norm(np.diff(cp, axis=0) - np.diff(ct, axis=0), axis=-1)
    present = ~np.isnan(ct[..., 0])
    found = (~np.isnan(cp[..., 0]) & present).sum(1) / np.maximum(present.sum(1), 1)
    return {"position": nanmean(pos, 1), "velocity": nanmean(vel, 1), "found": found.astype(np.float64)}


def nanmean(a: ArrayLike, axis: int | None = None) -> np.ndarray:
    """Mean ignoring NaN, NaN (without a warning) where all are NaN."""
    a = np.asarray(a, np.float64)
    n = (~np.isnan(a)).sum(axis)
    return np.where(n > 0, np.nansum(a, axis) / np.maximum(n, 1), np.nan)


def moving(x: Tensor, threshold: float = 0.1, background: Tensor | None = None) -> Tensor:
    """Moving pixels of videos `(..., T, 3, H, W)` in [0, 1] -> bool `(..., T, H, W)`: the largest channel difference
    from a static background (default: the per-pixel temporal median) exceeds threshold."""
    bg = x.median(-4, keepdim=True).values if background is None else background
    return (x - bg).abs().amax(-3) > threshold


def motion_masks(frames: ArrayLike, threshold: float = 0.1, background: ArrayLike | None = None) -> np.ndarray:
    """Moving pixels `(T, H, W)` bool: the largest channel difference from a static background exceeds threshold.

    The background model is the per-pixel temporal median of the clip (an object that rests most of the time is
    background), or a given `(H, W, 3)` uint8 image; threshold is a fraction of the data range.
    """
    x, batched = to_unit(frames)
    if batched:
        raise ValueError(f"motion_masks takes one video, got a batch of {len(x)}")
    bg = None if background is None else to_unit(np.asarray(background)[None])[0][0, 0]
    return moving(x[0], threshold, bg).cpu().numpy()


def motion_iou_per_frame(pred: ArrayLike, target: ArrayLike, threshold: float = 0.1) -> np.ndarray:
    """IoU of the motion masks of a generated and a true video per frame `(T,)` (Physics-IQ's spatiotemporal IoU)."""
    return mask_iou_per_frame(motion_masks(pred, threshold), motion_masks(target, threshold))


def spatial_iou_so_far(pred_moving: ArrayLike, target_moving: ArrayLike) -> np.ndarray:
    """Physics-IQ's spatial IoU ('where'): IoU of the pixels that moved at any time, of bool motion masks `(T, H, W)`,
    over frames 0..t for each t -> `(T,)` (the last is the clip's; 1 where neither moved)."""
    p, t = np.logical_or.accumulate(_masks(pred_moving), 0), np.logical_or.accumulate(_masks(target_moving), 0)
    return _binary_iou(p, t, (-2, -1)).astype(np.float64)


def weighted_spatial_iou_so_far(pred_moving: ArrayLike, target_moving: ArrayLike) -> np.ndarray:
    """Physics-IQ's weighted spatial IoU ('where and how much'): sum_x min(a, b) / sum_x max(a, b) of the per-pixel
    counts of moving frames of bool motion masks `(T, H, W)`, over frames 0..t for each t -> `(T,)` (1 where neither
    moved)."""
    a, b = np.cumsum(_masks(pred_moving), 0), np.cumsum(_masks(target_moving), 0)
    num, den = np.minimum(a, b).sum((-2, -1)), np.maximum(a, b).sum((-2, -1))
    return np.where(den > 0, num / np.maximum(den, 1), 1.0)
