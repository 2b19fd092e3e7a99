"""Tokenizer benchmark (issue 5): train the nano CV4x8x8 and DV4x8x8 on simulator episodes, then print, on held-out
episodes and on the Sintel 10 s clip (64x64, 256x256, native), PSNR, SSIM, compression ratio and encode/decode
frames/s next to the bicubic baseline measured in the same run (on episodes also object IoU of the colour-segmented
reconstructions; DV: codebook perplexity too), and the held-out PSNR
that the decoder's output width bounds; then frames/s and peak memory of nano vs a Cosmos-Tokenizer-sized CV4x8x8
(about 90M parameters) at 64x64 and 256x256.

    python bench/tokenizer.py                            # train both (--minutes each, 30 by default), then report
    python bench/tokenizer.py --cv DIR --dv DIR          # report on trained checkpoints, no training
    python bench/tokenizer.py --out runs/bench/tok_quick --episodes 28 --minutes 1 --no-native   # a smoke run
Rerunning with the same --out skips the finished stages (episodes, each training run), so it re-prints quickly.
Targets: held-out sim PSNR >= 32 dB and >= baseline + 3 dB; Sintel above the baseline; nano >= 21 frames/s at
256x256 (>= 10x the Cosmos-sized model).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import numpy as np
import torch

os.environ.setdefault("COSMOS_LITE_QUIET", "0")

from cosmos_lite.config import load_config  # noqa: E402
from cosmos_lite.core.engine import read_state_meta  # noqa: E402
from cosmos_lite.core.frames import to_frames, to_tensor  # noqa: E402
from cosmos_lite.core.metrics import palette_object_iou, psnr_per_frame, ssim_per_frame  # noqa: E402
from cosmos_lite.log import setup_logging  # noqa: E402
from cosmos_lite.sim import read_episode  # noqa: E402
from cosmos_lite.sim.cli import SimConfig  # noqa: E402
from cosmos_lite.sim.cli import run as simulate_into  # noqa: E402
from cosmos_lite.tokenizers import Tokenizer, build_tokenizer, load_tokenizer  # noqa: E402
from cosmos_lite.tokenizers.inference import bicubic_baseline, reconstruct  # noqa: E402
from cosmos_lite.tokenizers.train import codebook_usage  # noqa: E402
from cosmos_lite.train import main as train  # noqa: E402
from cosmos_lite.video import read_frames  # noqa: E402

SINTEL = Path(os.environ.get("COSMOS_LITE_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
SEGMENT = 33  # frames per baseline segment (1 + 8*4: whole latent groups for 4x and 8x temporal compression)
COSMOS_SIZED = dict(size="super", channels=144)  # Cosmos' layout (mult 2,4,4; 2 res blocks) widened to ~90M params
COSMOS_FPS = {64: 28.0, 256: 2.1}  # the figures for Cosmos-Tokenizer CV4x8x8 on this 2-core machine


def make_episodes(out: Path, n: int, seed: int) -> Path:
    """n episodes of every scenario in turn (64x64, 33 frames); episodes already there are kept."""
    simulate_into(SimConfig(scenario="mix", episodes=n), out, seed=seed)
    return out


def finished(run: Path, minutes: float) -> bool:
    """Whether `run` holds a checkpoint saved at the end of its time budget."""
    state = read_state_meta(run)
    return (run / "model.safetensors").is_file() and state is not None and state["minutes"] >= minutes * 0.999


def train_run(variant: str, run: Path, train_dir: Path, held_dir: Path, minutes: float, threads: int) -> Path:
    """Train (or resume) the nano `variant` for `minutes` of wall clock, unless already finished."""
    if not finished(run, minutes):
        cfg = load_config("train", [
            "experiment=tokenizer_nano", f"tokenizer.variant={variant}", f"data.roots=[{train_dir}]",
            f"data.val_roots=[{held_dir}]", f"out={run}", f"trainer.max_minutes={minutes}",
            f"trainer.threads={threads}",
        ])
        if train(cfg, []):
            raise SystemExit(f"training {variant} into {run} failed")
    return run


def latent_values(tok: Tokenizer, t: int, h: int, w: int) -> int:
    """Numbers in the latent of a (t, h, w) clip (after padding to the latent grid)."""
    ct, cs = tok.temporal_compression, tok.spatial_compression
    return tok.latent_channels * (1 + math.ceil((t - 1) / ct)) * math.ceil(h / cs) * math.ceil(w / cs)


def baseline(tok: Tokenizer, frames: np.ndarray) -> tuple[np.ndarray, str]:
    """Bicubic baseline per SEGMENT frames, each with as many values as the tokenizer's latent of that segment."""
    out, how = [], ""
    for k in range(0, len(frames), SEGMENT):
        seg = frames[k : k + SEGMENT]
        rec, how = bicubic_baseline(to_tensor(seg), latent_values(tok, *seg.shape[:3]), tok.temporal_compression)
        out.append(to_frames(rec))
    return np.concatenate(out), how


def score(tok: Tokenizer, clips: list[np.ndarray], window: int = 8, episodes: list | None = None) -> dict:
    """Tokenizer and baseline PSNR/SSIM over all frames of `clips`, compression, frames/s, DV codebook usage; with
    the clips' `episodes`, also the mean object IoU of the colour-segmented reconstructions (objects kept in their
    colour and place, what a world model over the latents can at best score)."""
    ps, ss, bps, bss, ious, bious, indices, enc_s, dec_s, how = [], [], [], [], [], [], [], 0.0, 0.0, ""
    for j, frames in enumerate(clips):
        rec, m = reconstruct(tok, frames, window=window)
        ps.append(m["psnr"] * len(frames))
        ss.append(m["ssim"] * len(frames))
        enc_s += len(frames) / m["encode_fps"]
        dec_s += len(frames) / m["decode_fps"]
        if "indices" in m:
            indices.append(m["indices"].flatten())
        base, how = baseline(tok, frames)
        bps.append(sum(psnr_per_frame(base[i : i + 32], frames[i : i + 32]).sum() for i in range(0, len(base), 32)))
        bss.append(sum(ssim_per_frame(base[i : i + 32], frames[i : i + 32]).sum() for i in range(0, len(base), 32)))
        if episodes:
            meta, masks = episodes[j].meta, episodes[j].masks
            ious.append(palette_object_iou(rec, masks, meta["palette"], [meta["scenery_color"]]))
            bious.append(palette_object_iou(base, masks, meta["palette"], [meta["scenery_color"]]))
    n = sum(len(c) for c in clips)
    out = {"psnr": sum(ps) / n, "ssim": sum(ss) / n, "base_psnr": float(sum(bps)) / n, "base_ssim": float(sum(bss)) / n,
           "compression": m["compression"], "encode_fps": n / enc_s, "decode_fps": n / dec_s, "baseline": how,
           "frames": n}
    if ious:
        out.update(iou=float(np.mean(ious)), base_iou=float(np.mean(bious)))
    if indices:
        out.update(codebook_usage(torch.cat(indices), tok.fsq.codebook_size))
    return out


def patch_fields(clips: list[np.ndarray], p: int) -> np.ndarray:
    """Each clip's frames after the first, as fields of (p, p, p, 3) blocks: (groups, 3*p^3, H/p, W/p) in [-1, 1]."""
    out = []
    for frames in clips:
        f = frames[1 : 1 + (len(frames) - 1) // p * p].astype(np.float32) / 127.5 - 1
        t, h, w, c = f.shape
        f = f[:, : h // p * p, : w // p * p].reshape(t // p, p, h // p, p, w // p, p, c)
        out.append(f.transpose(0, 1, 3, 5, 6, 2, 4).reshape(t // p, p**3 * c, h // p, w // p))
    return np.concatenate(out)


def output_bound(train: list[np.ndarray], held: list[np.ndarray], p: int, dims: list[int]) -> dict[int, float]:
    """Held-out PSNR bound of a decoder whose last layer is a conv from k channels onto each patch's 3*p^3 (Haar,
    orthonormal) coefficients: at each spatial frequency its output spans at most k dimensions, and the best k
    (PCA of `train` at that frequency) leave the held-out residual counted here."""
    a, b = np.fft.fft2(patch_fields(train, p)), np.fft.fft2(patch_fields(held, p))
    residual = dict.fromkeys(dims, 0.0)
    for i, j in np.ndindex(*a.shape[2:]):
        fa, fb = a[:, :, i, j], b[:, :, i, j]
        basis = np.linalg.eigh(fa.T @ fa.conj())[1]
        for k in dims:
            u = basis[:, -k:]
            residual[k] += float(np.square(np.abs(fb - fb @ u.conj() @ u.T)).sum())
    values = b.size * b.shape[2] * b.shape[3]  # numpy's FFT is unnormalised: energies scale by H*W
    return {k: float(10 * np.log10(4 * values / r)) for k, r in residual.items()}


def print_scores(title: str, rows: dict[str, dict]) -> None:
    iou = all("iou" in r for r in rows.values())
    print(f"\n{title}")
    print(f"{'model':<9} {'PSNR':>6} {'base':>6} {'gain':>6} {'SSIM':>6} {'base':>6} "
          + (f"{'IoU':>6} {'base':>6} " if iou else "")
          + f"{'compr.':>7} {'enc f/s':>8} {'dec f/s':>8} {'perplex.':>9}  baseline")
    for name, r in rows.items():
        perp = f"{r['perplexity']:9.0f}" if "perplexity" in r else f"{'-':>9}"
        print(f"{name:<9} {r['psnr']:6.2f} {r['base_psnr']:6.2f} {r['psnr'] - r['base_psnr']:+6.2f} {r['ssim']:6.3f} "
              f"{r['base_ssim']:6.3f} " + (f"{r['iou']:6.3f} {r['base_iou']:6.3f} " if iou else "")
              + f"{r['compression']:7.1f} {r['encode_fps']:8.1f} {r['decode_fps']:8.1f} {perp}  {r['baseline']}")


def _status_mb(field: str) -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    return float("nan")


def speed_probe(kw: dict, res: int, repeats: int, threads: int) -> dict:
    """In a fresh process: encode+decode frames/s of 17 frames at res x res (float32, no_grad, batch 1; median of
    `repeats` after a warm-up, or one cold run if repeats is 1), and peak resident memory (whole process, and above
    the loaded model)."""
    torch.set_num_threads(threads)
    tok = build_tokenizer("cv4x8x8", **kw).eval()
    x = torch.rand(1, 3, 17, res, res, generator=torch.Generator().manual_seed(0)) * 2 - 1
    loaded = _status_mb("VmRSS")
    with torch.no_grad():
        if repeats > 1:
            tok.decode(tok.encode(x))  # warm-up
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            tok.decode(tok.encode(x))
            times.append(time.perf_counter() - t)
    peak = _status_mb("VmHWM")
    return {"params_m": sum(p.numel() for p in tok.parameters()) / 1e6, "fps": 17 / float(np.median(times)),
            "peak_mb": peak, "over_model_mb": peak - loaded}


def speed(kw: dict, res: int, repeats: int, threads: int) -> dict:
    with ProcessPoolExecutor(1, mp_context=get_context("spawn")) as pool:
        return pool.submit(speed_probe, kw, res, repeats, threads).result()


def quality(a: argparse.Namespace, out: Path) -> dict:
    """Train (unless given or finished) and score both variants on held-out episodes and Sintel."""
    t0 = time.time()
    train_dir = make_episodes(out / "sim" / "train", a.episodes, seed=0)
    held_dir = make_episodes(out / "sim" / "heldout", a.heldout, seed=1)
    print(f"episodes ready ({time.time() - t0:.0f} s)")
    runs = {v: Path(given) if given else train_run(v, out / v, train_dir, held_dir, a.minutes, a.threads)
            for v, given in (("cv4x8x8", a.cv), ("dv4x8x8", a.dv))}
    toks = {v: load_tokenizer(r) for v, r in runs.items()}
    for v, r in runs.items():
        last = read_state_meta(r) or {}
        print(f"{v}: {r} ({last.get('step', '?')} steps in {last.get('minutes', float('nan')):.1f} min)")
    results: dict = {"runs": {v: str(r) for v, r in runs.items()}}

    held_eps = [read_episode(p) for p in sorted(held_dir.glob("*.mp4"))]
    held = [ep.frames for ep in held_eps]
    rows = {v: score(tok, held, window=16, episodes=held_eps) for v, tok in toks.items()}
    print_scores(f"held-out simulator episodes ({len(held)} x {len(held[0])} frames, 64x64)", rows)
    results["heldout"] = rows
    widths = sorted({tok.cfg.level_channels()[0] for tok in toks.values()} | {32})
    p = next(iter(toks.values())).cfg.patch_size
    bound = output_bound([read_episode(q).frames for q in sorted(train_dir.glob("*.mp4"))[::4]], held, p, widths)
    print(f"decoder output bound (PSNR, best k-dim subspace per spatial frequency of {p}x{p}x{p} blocks): "
          + ", ".join(f"{k} dims {v:.2f} dB" for k, v in bound.items())
          + f"; these models' first level: {', '.join(str(tok.cfg.level_channels()[0]) for tok in toks.values())}")
    results["output_bound"] = bound

    sizes = [64, 256] + ([None] if not a.no_native else [])
    for size in sizes:
        frames = read_frames(a.sintel, size=size)
        name = f"{frames.shape[1]}x{frames.shape[2]}"
        rows = {v: score(tok, [frames]) for v, tok in toks.items()}
        print_scores(f"Sintel 10 s ({len(frames)} frames, {name}; windows of 8 latent frames, overlap 3)", rows)
        results[f"sintel_{name}"] = rows

    return results


def speed_table(threads: int) -> dict:
    """Frames/s and peak memory of nano vs the Cosmos-sized CV4x8x8 at 64x64 and 256x256, printed as a table."""
    print(f"\nspeed: encode+decode 17 frames, float32, no_grad, batch 1, {threads} thread(s), fresh process each; "
          "nano: median of 3 after a warm-up, Cosmos-sized: one run (seconds to minutes each)")
    print(f"{'model':<22} {'params':>7} {'res':>4} {'frames/s':>9} {'peak MB':>8} {'+model MB':>9} {'nano x':>7} "
          f"{'Cosmos f/s (issue)':>18}")
    models = {"nano cv4x8x8": {"size": "nano"}, "Cosmos-sized cv4x8x8": COSMOS_SIZED}
    speeds: dict = {}
    for res in (64, 256):
        for name, kw in models.items():
            speeds[f"{name} {res}"] = s = speed(kw, res, 3 if kw is not COSMOS_SIZED else 1, threads)
            ratio = speeds[f"nano cv4x8x8 {res}"]["fps"] / s["fps"]
            print(f"{name:<22} {s['params_m']:6.1f}M {res:>4} {s['fps']:9.2f} {s['peak_mb']:8.0f} "
                  f"{s['over_model_mb']:9.0f} {ratio:7.1f} {COSMOS_FPS[res]:18.1f}")
    nano256 = speeds["nano cv4x8x8 256"]["fps"]
    print(f"target nano >= 21 frames/s at 256x256: {nano256:.1f} ({'met' if nano256 >= 21 else 'NOT met'}); "
          f"vs the issue's Cosmos figure 2.1: {nano256 / COSMOS_FPS[256]:.1f}x")
    return speeds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/bench/tokenizer")
    ap.add_argument("--minutes", type=float, default=30.0, help="training budget per variant (wall clock)")
    ap.add_argument("--episodes", type=int, default=200, help="training episodes (all scenarios in turn)")
    ap.add_argument("--heldout", type=int, default=28, help="held-out episodes (another seed)")
    ap.add_argument("--cv", help="a trained nano CV4x8x8 checkpoint to report on (default: train one under --out)")
    ap.add_argument("--dv", help="a trained nano DV4x8x8 checkpoint to report on (default: train one under --out)")
    ap.add_argument("--sintel", default=str(SINTEL / "sintel_trailer_10s.mp4"))
    ap.add_argument("--no-native", action="store_true", help="skip Sintel at its native 480x854")
    ap.add_argument("--sections", nargs="+", default=["quality", "speed"], choices=["quality", "speed"],
                    help="quality: train + score on held-out episodes and Sintel; speed: frames/s and memory only")
    ap.add_argument("--threads", type=int, default=1,
                    help="torch threads for training and timing; 2 only on an idle machine (with other jobs on the "
                         "2 cores, 2 threads measured 10x slower than 1)")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    setup_logging()
    out, t0 = Path(a.out), time.time()
    saved = out / "results.json"
    results: dict = json.loads(saved.read_text()) if saved.is_file() else {}  # sections run apart add up
    if "quality" in a.sections:
        results.update(quality(a, out))
    if "speed" in a.sections:
        results["speed"] = speed_table(a.threads)
    out.mkdir(parents=True, exist_ok=True)
    saved.write_text(json.dumps(results, indent=1))
    print(f"\nwrote {saved} (total {time.time() - t0:.0f} s)")


if __name__ == "__main__":
    main()
