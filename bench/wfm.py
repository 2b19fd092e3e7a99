"""World-model benchmark: train the nano DiT on simulator episodes (bounce, collision, pusher), then on held-out
episodes generate 16 frames from 1 and from 9 given frames and print PSNR, SSIM and mean object IoU next to the
copy-last-frame baseline measured in the same run; the pusher's IoU with true vs shuffled actions; a specialist
post-trained from the generalist vs the generalist and a from-scratch model (same small budget) on a new
scenario; seconds per generated clip at 10 and 35 sampler steps. The ceiling (seconds, `--sections ceiling`): the
IoU a perfect generative model would score, from re-simulations that agree with everything the model is shown.

    python bench/wfm.py                       # the full budget (about 60 min of 2 free CPU cores)
    python bench/wfm.py --steps 300 --quick   # a smoke run
Rerunning with the same --out resumes or skips every finished stage (episodes, tokenizer, each training run).
Targets (issue 6): PSNR >= baseline + 3 dB; mean object IoU >= 0.6; pusher IoU true - shuffled >= 0.15.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
import torch

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("COSMOS_LITE_QUIET", "0")

from cosmos_lite.config import load_config  # noqa: E402
from cosmos_lite.eval.ceiling import ceiling  # noqa: E402
from cosmos_lite.eval.metrics import nanmean, object_iou_per_frame, palette_object_iou  # noqa: E402
from cosmos_lite.log import setup_logging  # noqa: E402
from cosmos_lite.models import WorldModelPipeline  # noqa: E402
from cosmos_lite.sim import read_episode, simulate, write_episode  # noqa: E402
from cosmos_lite.train import main as train  # noqa: E402

MIX = ("bounce", "collision", "pusher")
NEW = "pendulum"  # the specialist's scenario, unseen by the generalist
GENERATED = 16


def make_episodes(out: Path, scenarios: tuple[str, ...], n: int, seed0: int) -> Path:
    """n episodes per scenario (64x64, 33 frames, 16 fps) into `out`; existing ones are kept."""
    out.mkdir(parents=True, exist_ok=True)
    for s, name in enumerate(scenarios):
        for i in range(n):
            stem = f"{name}_{seed0 + i:05d}"
            if not (out / f"{stem}.json").is_file():
                write_episode(simulate(name, seed=seed0 + 100_000 * s + i), out, stem)
    return out


def run(overrides: list[str]) -> None:
    code = train(load_config("train", overrides), [])
    if code:
        raise SystemExit(f"training failed ({code}): {' '.join(overrides)}")


def object_iou(frames: np.ndarray, masks: np.ndarray, meta: dict, ids: list[int]) -> float:
    """Mean object IoU of colour-segmented `frames` with an episode's true `masks` (its palette and scenery)."""
    return palette_object_iou(frames, masks, meta["palette"], [meta["scenery_color"]], ids)


def moved_object(ep, k: int) -> int:
    """The non-agent object that moves most over the generated span (the one the agent pushes)."""
    ids = [i + 1 for i, name in enumerate(ep.meta["objects"]) if name != "agent"]
    disp = [np.hypot(*(ep.states[k + GENERATED - 1, i - 1, :2] - ep.states[k - 1, i - 1, :2])) for i in ids]
    return ids[int(np.argmax(disp))]


def print_ceiling(held: list, proposals: int) -> dict:
    """The ceiling per scenario and overall for 1 and 9 given frames, beside copy-last-frame on the true masks."""
    rng = np.random.default_rng(0)
    print(f"\nceiling: a perfect generative model's mean object IoU (re-simulations consistent with the given frames, "
          f"caption and actions; {proposals} draws per episode), and copy-last-frame, both on true masks")
    results = {}
    for k in (1, 9):
        rows = {}
        for ep in held:
            iou, n = ceiling(ep, k, proposals, rng)
            copy = np.repeat(ep.masks[k - 1 : k], GENERATED, axis=0)
            base = float(nanmean(object_iou_per_frame(copy, ep.masks[k : k + GENERATED])))
            rows.setdefault(ep.meta["scenario"], []).append((iou, base, n))
        for name, r in rows.items():
            v = np.array(r)
            results[f"given_{k}_{name}"] = {"ceiling": float(np.nanmean(v[:, 0])), "copy": float(v[:, 1].mean())}
            print(f"  {k} given, {name:<10} ceiling {np.nanmean(v[:, 0]):.3f} (copy-last {v[:, 1].mean():.3f}; "
                  f"{int(v[:, 2].sum())} draws kept)")
        allv = np.concatenate([np.array(r) for r in rows.values()])
        results[f"given_{k}"] = {"ceiling": float(np.nanmean(allv[:, 0])), "copy": float(allv[:, 1].mean())}
        print(f"  {k} given, all        ceiling {np.nanmean(allv[:, 0]):.3f} (copy-last {allv[:, 1].mean():.3f}); "
              "target for the world model: 0.6")
    return results


def evaluate(pipe: WorldModelPipeline, episodes: list, k: int, steps: int, actions: list | None = None) -> dict:
    """Generate GENERATED frames after k given ones for each episode; metrics vs truth and the copy baseline."""
    from cosmos_lite.eval.metrics import psnr, ssim

    rows = []
    for j, ep in enumerate(episodes):
        acts = ep.actions if actions is None else actions[j]
        gen = pipe(prompt=ep.meta["caption"], video=ep.frames[:k], actions=acts, num_frames=k + GENERATED,
                   steps=steps, seed=j).frames[k:]
        truth, masks = ep.frames[k : k + GENERATED], ep.masks[k : k + GENERATED]
        copy = np.repeat(ep.frames[k - 1 : k], GENERATED, axis=0)
        ids = list(range(1, len(ep.meta["objects"]) + 1))
        row = {"scenario": ep.meta["scenario"], "psnr": psnr(gen, truth), "ssim": ssim(gen, truth),
               "iou": object_iou(gen, masks, ep.meta, ids), "base_psnr": psnr(copy, truth),
               "base_ssim": ssim(copy, truth), "base_iou": object_iou(copy, masks, ep.meta, ids)}
        if ep.meta["scenario"] == "pusher":
            row["pushed_iou"] = object_iou(gen, masks, ep.meta, [moved_object(ep, k)])
        rows.append(row)
    return {key: float(np.mean([r[key] for r in rows if key in r])) for key in rows[0] | rows[-1]
            if key != "scenario"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/bench_wfm")
    ap.add_argument("--tokenizer", help="a trained tokenizer folder (default: train one here)")
    ap.add_argument("--tok-minutes", type=float, default=12.0)
    ap.add_argument("--episodes", type=int, default=64, help="training episodes per scenario")
    ap.add_argument("--heldout", type=int, default=6, help="held-out episodes per scenario")
    ap.add_argument("--steps", type=int, default=2500, help="generalist training steps")
    ap.add_argument("--minutes", type=float, default=35.0, help="generalist wall-clock budget (0: steps only)")
    ap.add_argument("--post-steps", type=int, default=300, help="specialist / scratch training steps")
    ap.add_argument("--post-episodes", type=int, default=16)
    ap.add_argument("--lora-rank", type=int, default=0, help="> 0: post-train LoRA adapters only")
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--sampler-steps", type=int, default=20)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="tiny model and few episodes: checks the plumbing")
    ap.add_argument("--sections", nargs="+", default=["ceiling", "model"], choices=["ceiling", "model"],
                    help="ceiling: a perfect model's IoU (seconds); model: train and score the world models")
    ap.add_argument("--proposals", type=int, default=300, help="ceiling: re-simulations drawn per episode")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    setup_logging()
    out = Path(a.out)
    t0 = time.time()
    sim = out / "sim"
    train_dir = make_episodes(sim / "train", MIX, a.episodes, 0)
    held_dir = make_episodes(sim / "heldout", MIX, a.heldout, 50_000)
    new_train = make_episodes(sim / "new_train", (NEW,), a.post_episodes, 0)
    new_held = make_episodes(sim / "new_heldout", (NEW,), a.heldout, 50_000)
    print(f"episodes ready ({time.time() - t0:.0f} s)")
    held = [read_episode(p) for p in sorted(held_dir.glob("*.json"))]
    saved = out / "results.json"
    results: dict = json.loads(saved.read_text()) if saved.is_file() else {}  # sections run apart add up
    if "ceiling" in a.sections:
        results["ceiling"] = print_ceiling(held, a.proposals)
    if "model" in a.sections:
        results.update(train_and_score(a, out, t0, train_dir, held, new_train, new_held))
    saved.write_text(json.dumps(results, indent=1))
    print(f"\nwrote {saved} (total {time.time() - t0:.0f} s)")


def train_and_score(a: argparse.Namespace, out: Path, t0: float, train_dir: Path, held: list, new_train: Path,
                    new_held: Path) -> dict:
    """Train the tokenizer (unless given), the generalist, the specialist and scratch runs, then score them."""
    tok = Path(a.tokenizer) if a.tokenizer else out / "tokenizer"
    if not a.tokenizer:
        run(["experiment=tokenizer_nano", f"data.roots=[{train_dir},{new_train}]", f"out={tok}",
             f"trainer.max_minutes={a.tok_minutes}"] + (["tokenizer.size=tiny"] if a.quick else []))
    print(f"tokenizer ready ({time.time() - t0:.0f} s)")

    common = [f"tokenizer.path={tok}", f"trainer.batch_size={a.batch}", "trainer.log_every=50"] + (
        ["model.size=tiny"] if a.quick else [])
    gen_dir, spec_dir, scratch_dir = out / "generalist", out / "specialist", out / "scratch"
    run(["experiment=wfm_nano", f"data.roots=[{train_dir}]", f"out={gen_dir}", f"trainer.steps={a.steps}",
         f"trainer.max_minutes={a.minutes}", f"trainer.ckpt_every={max(50, a.steps // 10)}"] + common)
    t_gen = time.time() - t0
    post = [f"data.roots=[{new_train}]", f"trainer.steps={a.post_steps}", f"trainer.warmup={a.post_steps // 10}",
            f"trainer.ckpt_every={max(50, a.post_steps // 4)}", "trainer.ema_decay=0.99"]
    run(["experiment=wfm_nano", f"out={spec_dir}", f"trainer.init_from={gen_dir}",
         f"trainer.lora_rank={a.lora_rank}"] + post + common)
    run(["experiment=wfm_nano", f"out={scratch_dir}"] + post + common)
    print(f"training done ({time.time() - t0:.0f} s; generalist {t_gen:.0f} s)")

    generalist = WorldModelPipeline.from_pretrained(gen_dir)
    s = a.sampler_steps
    print(f"\nheld-out {', '.join(MIX)} ({len(held)} episodes), {GENERATED} generated frames, {s} Heun steps")
    print(f"{'given':>5} {'PSNR':>7} {'base':>7} {'gain':>6} {'SSIM':>6} {'base':>6} {'IoU':>6} {'base':>6}")
    results = {}
    for k in (1, 9):
        r = evaluate(generalist, held, k, s)
        results[f"given_{k}"] = r
        print(f"{k:>5} {r['psnr']:7.2f} {r['base_psnr']:7.2f} {r['psnr'] - r['base_psnr']:+6.2f} {r['ssim']:6.3f} "
              f"{r['base_ssim']:6.3f} {r['iou']:6.3f} {r['base_iou']:6.3f}")

    pushers = [ep for ep in held if ep.meta["scenario"] == "pusher"]
    shuffled = [pushers[(j + 1) % len(pushers)].actions for j in range(len(pushers))]
    true_iou = evaluate(generalist, pushers, 9, s)["pushed_iou"]
    shuf_iou = evaluate(generalist, pushers, 9, s, actions=shuffled)["pushed_iou"]
    results["pusher"] = {"true_actions_iou": true_iou, "shuffled_actions_iou": shuf_iou}
    print(f"\npusher, pushed object IoU (9 given): true actions {true_iou:.3f}, shuffled {shuf_iou:.3f}, "
          f"difference {true_iou - shuf_iou:+.3f} (target >= 0.15)")

    new_eps = [read_episode(p) for p in sorted(new_held.glob("*.json"))]
    print(f"\nnew scenario {NEW} ({len(new_eps)} held-out episodes, 9 given), post-training budget {a.post_steps} "
          f"steps{' (LoRA)' if a.lora_rank else ''}")
    for name, d in (("generalist", gen_dir), ("specialist", spec_dir), ("scratch", scratch_dir)):
        r = evaluate(WorldModelPipeline.from_pretrained(d), new_eps, 9, s)
        results[f"{NEW}_{name}"] = r
        print(f"  {name:<11} PSNR {r['psnr']:6.2f} (copy {r['base_psnr']:6.2f})  SSIM {r['ssim']:.3f}  "
              f"IoU {r['iou']:.3f}")

    ep = held[0]
    for steps in (10, 35):
        generalist(prompt=ep.meta["caption"], video=ep.frames[:9], actions=ep.actions, num_frames=9 + GENERATED,
                   steps=2)  # warm-up (loads the text encoder)
        t = time.time()
        generalist(prompt=ep.meta["caption"], video=ep.frames[:9], actions=ep.actions, num_frames=9 + GENERATED,
                   steps=steps)
        results[f"seconds_per_clip_{steps}_steps"] = time.time() - t
        print(f"seconds per generated clip ({GENERATED} frames, {steps} Heun steps): {time.time() - t:.2f}")
    return results


if __name__ == "__main__":
    main()
