"""World-model benchmark, tokenizer training included (about 60 min of 2 free CPU cores by default).

Trains the scene tokenizer (dv1x4x4) and the next-frame world model on simulator episodes (bounce, collision,
pusher; a share of the pushers goal-directed pushes by randomized greedy policies, `--goal-pushes`), then on
held-out episodes generates 16 frames from 1 and from 9 given frames and prints, next to copy-last-frame measured in
the same run: mean object IoU (colour segmentation against the true masks) per scenario, object centroid error (px)
and PhyWorld-style velocity error (px/frame), PSNR and SSIM; the pusher's IoU of the pushed object with the true vs
shuffled actions (on 96 more held-out pusher episodes); a 49-frame rollout (beyond the 33-frame training clips)
scored by how often each given object is found in its colour; a learning curve (object IoU of snapshots taken at
wall-clock minutes of training); training throughput (samples/s, achieved GFLOP/s beside this machine's matmul peak
measured in the same run). The ceiling (seconds, `--sections ceiling`): the IoU a perfect generative model would
score, from re-simulations that agree with everything the model is shown.

    python bench/wfm.py                                # the full budget
    python bench/wfm.py --tok-minutes 1 --minutes 2 --quick   # a smoke run
    python bench/wfm.py --checkpoint runs/wfm --sections model  # score a trained world model (no training)
Rerunning with the same --out resumes or skips every finished stage (episodes, tokenizer, training).
Targets (issue 19): IoU >= copy-last + 0.10 from 1 and 9 given frames and above copy-last in each scenario;
centroid error below copy-last's; pusher IoU true - shuffled >= 0.10; objects found in >= 90% of rollout frames.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import threading
import time
from pathlib import Path

import numpy as np
import torch

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("COSMOS_LITE_QUIET", "0")

from cosmos_lite.config import load_config  # noqa: E402
from cosmos_lite.core.engine import read_state_meta  # noqa: E402
from cosmos_lite.core.frames import to_frames, to_tensor  # noqa: E402
from cosmos_lite.core.metrics import (  # noqa: E402
    nanmean,
    object_iou_per_frame,
    palette_object_iou,
    psnr,
    segment_by_palette,
    ssim,
    trajectory_errors,
)
from cosmos_lite.eval.ceiling import ceiling  # noqa: E402
from cosmos_lite.eval.policy import goal_episodes  # noqa: E402
from cosmos_lite.log import setup_logging  # noqa: E402
from cosmos_lite.models import WorldModelPipeline  # noqa: E402
from cosmos_lite.sim import read_episode, simulate, write_episode  # noqa: E402
from cosmos_lite.train import main as train  # noqa: E402

MIX = ("bounce", "collision", "pusher")
GENERATED = 16
ROLLOUT = 49  # frames of the long rollout, beyond the 33-frame training clips
GOAL_DATA_SEED = 2  # goal-task family of the goal-pushing training episodes (the policy bench: 0, its validation: 1)
CURVE = (5, 10, 20, 40, 60)  # wall-clock minutes of world-model training at which snapshots are scored


def make_episodes(out: Path, counts: dict[str, int], seed0: int) -> Path:
    """counts[scenario] episodes of each scenario (64x64, 33 frames, 16 fps) into `out`; existing ones are kept."""
    out.mkdir(parents=True, exist_ok=True)
    for s, (name, n) in enumerate(counts.items()):
        for i in range(n):
            stem = f"{name}_{seed0 + i:05d}"
            if not (out / f"{stem}.json").is_file():
                write_episode(simulate(name, seed=seed0 + 100_000 * s + i), out, stem)
    return out


def run(overrides: list[str]) -> None:
    code = train(load_config("train", overrides), [])
    if code:
        raise SystemExit(f"training failed ({code}): {' '.join(overrides)}")


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


def segment(frames: np.ndarray, meta: dict) -> np.ndarray:
    """Object-id masks of rendered or generated frames by the episode's palette (its scenery counts as background)."""
    return segment_by_palette(frames, meta["palette"], background=[meta["scenery_color"]])


def score(frames: np.ndarray, ep, k: int) -> dict:
    """Metrics of `frames` (the GENERATED frames after k given ones) against the episode's truth."""
    truth, masks = ep.frames[k : k + GENERATED], ep.masks[k : k + GENERATED]
    ids = list(range(1, len(ep.meta["objects"]) + 1))
    pred = segment(frames, ep.meta)
    traj = trajectory_errors(np.concatenate([ep.masks[k - 1 : k], pred]), ep.masks[k - 1 : k + GENERATED], ids)
    return {"iou": float(nanmean(object_iou_per_frame(pred, masks, ids))), "psnr": psnr(frames, truth),
            "ssim": ssim(frames, truth), "centroid_px": float(nanmean(traj["position"][1:])),
            "velocity_px": float(nanmean(traj["velocity"]))}


def evaluate(pipe: WorldModelPipeline, episodes: list, k: int, steps: int, actions: list | None = None) -> list[dict]:
    """Per episode: the world model's and copy-last-frame's metrics over GENERATED frames after k given ones."""
    rows = []
    for j, ep in enumerate(episodes):
        acts = ep.actions if actions is None else actions[j]
        gen = pipe(prompt=ep.meta["caption"], video=ep.frames[:k], actions=acts, num_frames=k + GENERATED,
                   steps=steps, seed=j).frames[k:]
        row = {"scenario": ep.meta["scenario"], "model": score(gen, ep, k),
               "copy": score(np.repeat(ep.frames[k - 1 : k], GENERATED, axis=0), ep, k)}
        if ep.meta["scenario"] == "pusher":
            pushed = moved_object(ep, k)
            row["pushed_iou"] = float(nanmean(object_iou_per_frame(segment(gen, ep.meta),
                                                                   ep.masks[k : k + GENERATED], [pushed])))
        rows.append(row)
    return rows


def mean(rows: list[dict], who: str, key: str, scenario: str | None = None) -> float:
    return float(np.nanmean([r[who][key] for r in rows if scenario in (None, r["scenario"])]))


def print_table(rows: list[dict], k: int) -> dict:
    """Per scenario and overall: the world model beside copy-last on every metric."""
    keys = ("iou", "centroid_px", "velocity_px", "psnr", "ssim")
    print(f"\n{k} given frame(s), {GENERATED} generated; world model / copy-last frame")
    print(f"  {'scenario':<10}" + "".join(f"{key:>22}" for key in keys))
    out = {}
    for sc in (*MIX, None):
        res = {key: {"model": mean(rows, "model", key, sc), "copy": mean(rows, "copy", key, sc)} for key in keys}
        out[sc or "all"] = res
        print(f"  {sc or 'all':<10}" + "".join(f"{res[key]['model']:>12.3f} /{res[key]['copy']:>7.3f}"
                                              for key in keys))
    gain = out["all"]["iou"]["model"] - out["all"]["iou"]["copy"]
    print(f"  object IoU gain over copy-last: {gain:+.3f} (target >= +0.10); above copy-last in "
          f"{sum(out[sc]['iou']['model'] > out[sc]['iou']['copy'] for sc in MIX)} of {len(MIX)} scenarios")
    return out


@torch.no_grad()
def one_step_iou(pipe: WorldModelPipeline, held: list, k: int, steps: int) -> tuple[float, float]:
    """Object IoU of GENERATED frames after k given ones, each predicted from the true frames before it
    (teacher-forced: no error fed back), beside copying the true previous frame; the gap to a rollout's IoU is what
    feeding back its own errors costs, the gap to copy-previous what the one-step prediction itself loses."""
    model, copy = [], []
    for j, ep in enumerate(held):
        latents = pipe.encode(to_tensor(ep.frames))
        actions = torch.from_numpy(ep.actions).float()[None].to(pipe.device) / pipe.stats["action_scale"]
        text, text_mask = pipe.text_tokens(ep.meta["caption"])
        g = torch.Generator(pipe.device).manual_seed(j)
        pred = latents.clone()
        for t in range(k, k + GENERATED):
            pred[:, t] = pipe.next_latent(latents, actions, t, text, text_mask, steps, generator=g)
        frames = to_frames(pipe.decode(pred))[k : k + GENERATED]
        model.append(score(frames, ep, k)["iou"])
        copy.append(score(ep.frames[k - 1 : k - 1 + GENERATED], ep, k)["iou"])
    return float(np.mean(model)), float(np.mean(copy))


def rollout_found(pipe: WorldModelPipeline, held: list, steps: int) -> dict:
    """Generate ROLLOUT frames from each held-out episode's first frame (its caption and true actions, re-simulated
    to ROLLOUT frames): the fraction of frames in which each object the simulator shows is found in its colour."""
    found, shown = 0, 0
    per = {}
    for j, ep in enumerate(held):
        truth = simulate(ep.meta["scenario"], ep.meta["seed"], frames=ROLLOUT)
        gen = pipe(prompt=truth.meta["caption"], video=truth.frames[:1], actions=truth.actions, num_frames=ROLLOUT,
                   steps=steps, seed=j).frames[1:]
        pred, true = segment(gen, truth.meta), truth.masks[1:]
        ids = range(1, len(truth.meta["objects"]) + 1)
        vis = np.array([[(true[t] == i).any() for i in ids] for t in range(len(true))])
        hit = np.array([[(pred[t] == i).sum() >= 3 for i in ids] for t in range(len(pred))])
        found, shown = found + (hit & vis).sum(), shown + vis.sum()
        f = per.setdefault(truth.meta["scenario"], [0, 0])
        f[0], f[1] = f[0] + (hit & vis).sum(), f[1] + vis.sum()
    result = {"all": found / max(shown, 1), **{sc: a / max(b, 1) for sc, (a, b) in per.items()}}
    print(f"\n{ROLLOUT}-frame rollout from 1 given frame: objects found in their colour in "
          f"{100 * result['all']:.1f}% of the frames that show them (target >= 90%): "
          + ", ".join(f"{sc} {100 * result[sc]:.1f}%" for sc in per))
    return result


class Snapshots(threading.Thread):
    """Copies the run's checkpoint aside the first time its train state passes each of `minutes` (the learning
    curve of one run, under its own schedule)."""

    def __init__(self, run: Path, dest: Path, minutes: tuple[int, ...]):
        super().__init__(daemon=True)
        self.run_dir, self.dest, self.todo = run, dest, [m for m in minutes if not (dest / f"{m:02d}min").is_dir()]
        self.done = threading.Event()

    def run(self) -> None:
        while self.todo and not self.done.wait(5):
            meta = read_state_meta(self.run_dir)
            while meta and self.todo and meta["minutes"] >= self.todo[0]:
                m = self.todo.pop(0)
                tmp = self.dest / f".{m:02d}min.tmp"
                shutil.rmtree(tmp, ignore_errors=True)
                shutil.copytree(self.run_dir, tmp, ignore=shutil.ignore_patterns("train_state*", "*.jsonl", "samples"))
                (tmp / "minutes.json").write_text(json.dumps({"minutes": meta["minutes"], "step": meta["step"]}))
                tmp.rename(self.dest / f"{m:02d}min")


def matmul_peak(device: torch.device, dtype: torch.dtype, threads: int, repeats: int = 10) -> float:
    """The device's matmul GFLOP/s in `dtype` (the training's: bf16 under autocast), the best of `repeats`; on the
    CPU with `threads` threads."""
    torch.set_num_threads(threads)
    n = 8192 if device.type == "cuda" else 2048
    a, b = torch.randn(n, n, device=device, dtype=dtype), torch.randn(n, n, device=device, dtype=dtype)
    best = float("inf")
    for _ in range(repeats + 1):  # the first warms up
        t = time.perf_counter()
        a @ b
        if device.type == "cuda":
            torch.cuda.synchronize()
        best = min(best, time.perf_counter() - t)
    return 2 * n**3 / best / 1e9


def flops_per_step(pipe: WorldModelPipeline, batch: int, p_own: float) -> float:
    """FLOPs of one training step of the run's world model at `batch` samples: forward and backward, plus the
    forward that samples the model's own context frame for the `p_own` share of the batch."""
    from torch.utils.flop_counter import FlopCounterMode

    from cosmos_lite.models import make_condition

    net, dev = pipe.denoiser.net.cfg, pipe.device
    h = pipe.size[0] // pipe.tokenizer.spatial_compression

    def inputs(n: int) -> tuple:
        context = torch.randn(n, net.context, net.latent_channels, h, h, device=dev)
        cond = make_condition(context, torch.ones(n, net.context, dtype=torch.bool, device=dev),
                              torch.randn(n, net.context, 2, device=dev),
                              text=torch.randn(n, 16, net.text_dim, device=dev))
        return torch.randn(n, net.latent_channels, h, h, device=dev), cond, torch.ones(n, device=dev)

    target, cond, sigma = inputs(batch)
    with FlopCounterMode(display=False) as counter:
        pipe.denoiser.loss(target, cond, sigma, torch.randn_like(target)).mean().backward()
        own = round(batch * p_own)
        if own:
            y, c, s = inputs(own)
            with torch.no_grad():
                pipe.denoiser(y, s, c)
    return float(counter.get_total_flops())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/bench_wfm")
    ap.add_argument("--checkpoint", help="score this trained world-model folder instead of training one (the "
                    "tokenizer and the training are skipped; --out still holds the episodes and results)")
    ap.add_argument("--tokenizer", help="a trained tokenizer folder (default: train one here)")
    ap.add_argument("--tok-minutes", type=float, default=10.0)
    ap.add_argument("--episodes", type=int, default=448, help="training episodes per scenario")
    ap.add_argument("--goal-pushes", type=int, default=160, help="of the pusher training episodes, this many are "
                    "goal-directed pushes by randomized greedy policies acting closed-loop (the rest random paths)")
    ap.add_argument("--heldout", type=int, default=6, help="held-out episodes per scenario")
    ap.add_argument("--pushers", type=int, default=96, help="more held-out pusher episodes for the action line")
    ap.add_argument("--minutes", type=float, default=42.0, help="world-model wall-clock training budget")
    ap.add_argument("--size", default="nano", choices=["tiny", "nano", "super"], help="world-model size preset")
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--sampler-steps", type=int, help="per generated frame (default: the checkpoint's edm.steps)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--device", default="auto", help="training device: auto (CUDA when present), cpu, cuda")
    ap.add_argument("--quick", action="store_true", help="tiny models and few episodes: checks the plumbing")
    ap.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE",
                    help="overrides of the world-model run, after the bench's own (e.g. trainer.lr=3e-4 "
                         "trainer.bf16=true trainer.ckpt_every=1000 for the super preset on a GPU)")
    ap.add_argument("--sections", nargs="+", default=["ceiling", "model"], choices=["ceiling", "model"],
                    help="ceiling: a perfect model's IoU (seconds); model: train and score the world model")
    ap.add_argument("--proposals", type=int, default=300, help="ceiling: re-simulations drawn per episode")
    a = ap.parse_args()
    if not 0 <= a.goal_pushes <= a.episodes:
        ap.error(f"--goal-pushes {a.goal_pushes}: give 0 to --episodes ({a.episodes}), the pusher episodes it replaces")
    torch.set_num_threads(a.threads)
    setup_logging()
    out = Path(a.out)
    t0 = time.time()
    sim = out / "sim"
    held_dir = make_episodes(sim / "heldout", dict.fromkeys(MIX, 2 if a.quick else a.heldout), 50_000)
    push_dir = make_episodes(sim / "heldout_pusher", {"pusher": 2 if a.quick else a.pushers}, 60_000)
    print(f"held-out episodes ready ({time.time() - t0:.0f} s)")
    held = [read_episode(p) for p in sorted(held_dir.glob("*.json"))]
    pushers = [read_episode(p) for p in sorted(push_dir.glob("*.json"))]
    saved = out / "results.json"
    results: dict = json.loads(saved.read_text()) if saved.is_file() else {}  # sections run apart add up
    if "ceiling" in a.sections:
        results["ceiling"] = print_ceiling(held, a.proposals)
    if "model" in a.sections:
        results.update(train_and_score(a, out, t0, held, pushers))
    saved.write_text(json.dumps(results, indent=1))
    print(f"\nwrote {saved} (total {time.time() - t0:.0f} s)")


def train_models(a: argparse.Namespace, out: Path, t0: float) -> Path:
    """Simulate the training episodes, train the tokenizer (unless given) and the world model (snapshots for the
    learning curve); the world model's folder."""
    n, goal = (4, 1) if a.quick else (a.episodes, a.goal_pushes)
    train_dir = make_episodes(out / "sim" / "train", {**dict.fromkeys(MIX, n), "pusher": n - goal}, 0)
    goal_episodes(train_dir, goal, GOAL_DATA_SEED)
    print(f"training episodes ready ({time.time() - t0:.0f} s)")
    tok = Path(a.tokenizer) if a.tokenizer else out / "tokenizer"
    if not a.tokenizer:
        run(["experiment=tokenizer_sim", f"data.roots=[{train_dir}]", f"out={tok}",
             f"trainer.max_minutes={a.tok_minutes}", f"trainer.threads={a.threads}", f"trainer.device={a.device}"]
            + (["tokenizer.size=tiny"] if a.quick else []))
    print(f"tokenizer ready ({time.time() - t0:.0f} s)")

    gen_dir = out / "world_model"
    snaps = Snapshots(gen_dir, out / "curve", tuple(m for m in CURVE if m < a.minutes))
    snaps.start()
    overrides = dict(o.split("=", 1) for o in [
        "experiment=wfm_nano", f"model=wfm_{'tiny' if a.quick else a.size}", f"data.roots=[{train_dir}]",
        f"tokenizer.path={tok}", f"out={gen_dir}", "trainer.steps=1000000", f"trainer.max_minutes={a.minutes}",
        f"trainer.batch_size={a.batch}", "trainer.ckpt_every=50", "trainer.log_every=100",
        "trainer.compile=true",  # torch.compile: +18% train steps/s on this CPU (docs/wfm_diagnosis_2026-11-26.txt)
        f"trainer.threads={a.threads}", f"trainer.device={a.device}", *a.set])
    run([f"{k}={v}" for k, v in overrides.items()])
    snaps.done.set()
    snaps.join()
    return gen_dir


def train_and_score(a: argparse.Namespace, out: Path, t0: float, held: list, pushers: list) -> dict:
    """Train (or take --checkpoint's world model), then score it and the learning curve's snapshots."""
    results: dict = {}
    gen_dir = Path(a.checkpoint) if a.checkpoint else train_models(a, out, t0)
    meta = read_state_meta(gen_dir)
    if meta is None:
        raise SystemExit(f"{gen_dir}: no training state (train_state.safetensors); pass a world-model run folder "
                         "from `cosmos-lite train` or this bench")
    print(f"world model trained: {meta['step']} steps in {meta['minutes']:.1f} min ({time.time() - t0:.0f} s)")

    device = torch.device("cuda" if a.device in ("auto", "cuda") and torch.cuda.is_available() else "cpu")
    pipe = WorldModelPipeline.from_pretrained(gen_dir, device)
    s = a.sampler_steps or pipe.denoiser.cfg.steps
    recon = [palette_object_iou(to_frames(pipe.decode(pipe.encode(to_tensor(ep.frames)))), ep.masks,
                                ep.meta["palette"], [ep.meta["scenery_color"]]) for ep in held]
    results["tokenizer_iou"] = float(np.mean(recon))
    print(f"\ntokenizer reconstruction object IoU on the held-out episodes: {results['tokenizer_iou']:.3f} "
          "(bounds any model over its latents)")
    print(f"held-out {', '.join(MIX)} ({len(held)} episodes), {s} Euler steps per generated frame")
    for k in (1, 9):
        rows = evaluate(pipe, held, k, s)
        results[f"given_{k}"] = print_table(rows, k)
        one, prev = one_step_iou(pipe, held, k, s)
        results[f"given_{k}"]["one_step"] = {"model": one, "copy_previous": prev}
        print(f"  one step at a time from the true frames (teacher-forced): object IoU {one:.3f}; copy the true "
              f"previous frame {prev:.3f}")

    shuffled = [pushers[(j + 1) % len(pushers)].actions for j in range(len(pushers))]
    print(f"\npusher, pushed object IoU with the true actions and with shuffled ones (the next episode's) on "
          f"{len(pushers)} more held-out pusher episodes (target: difference >= +0.10)")
    for k in (1, 9):
        true_iou = float(np.mean([r["pushed_iou"] for r in evaluate(pipe, pushers, k, s)]))
        shuf_iou = float(np.mean([r["pushed_iou"] for r in evaluate(pipe, pushers, k, s, actions=shuffled)]))
        results[f"pusher_given_{k}"] = {"true_actions_iou": true_iou, "shuffled_actions_iou": shuf_iou}
        print(f"  {k} given: true actions {true_iou:.3f}, shuffled {shuf_iou:.3f}, difference "
              f"{true_iou - shuf_iou:+.3f}")

    results["rollout_found"] = rollout_found(pipe, held, s)

    if a.checkpoint:  # trained elsewhere: neither its learning curve nor its throughput is measured here
        return results

    print("\nlearning curve: object IoU of snapshots of the run (1 / 9 given frames)")
    curve = {}
    for snap in sorted((out / "curve").glob("*min")) + [gen_dir]:
        snap_meta = json.loads((snap / "minutes.json").read_text()) if snap != gen_dir else meta
        p = WorldModelPipeline.from_pretrained(snap, device)
        ious = [mean(evaluate(p, held, k, s), "model", "iou") for k in (1, 9)]
        curve[f"{snap_meta['minutes']:.1f}"] = {"step": snap_meta["step"], "iou_1": ious[0], "iou_9": ious[1]}
        print(f"  {snap_meta['minutes']:5.1f} min ({snap_meta['step']:>6} steps): {ious[0]:.3f} / {ious[1]:.3f}")
    results["curve"] = curve

    steps_per_s = meta["step"] / (60 * meta["minutes"])
    flops = flops_per_step(pipe, a.batch, meta["config"]["cond"]["p_own_context"])
    bf16 = bool(meta["config"]["trainer"]["bf16"])
    peak = matmul_peak(device, torch.bfloat16 if bf16 else torch.float32, a.threads)
    results["throughput"] = {"samples_per_s": steps_per_s * a.batch, "gflops": flops * steps_per_s / 1e9,
                             "matmul_peak_gflops": peak}
    print(f"\ntraining throughput: {steps_per_s * a.batch:.1f} samples/s ({steps_per_s:.2f} steps/s at batch "
          f"{a.batch}), {flops / 1e9:.1f} GFLOP per step -> {flops * steps_per_s / 1e9:.1f} GFLOP/s achieved; "
          f"this machine's {'bf16' if bf16 else 'fp32'} matmul peak on {device.type}"
          f"{f' with {a.threads} threads' if device.type == 'cpu' else ''}: {peak:.1f} GFLOP/s "
          f"({100 * flops * steps_per_s / 1e9 / peak:.0f}%)")
    return results


if __name__ == "__main__":
    main()
