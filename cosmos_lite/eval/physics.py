"""Physics-alignment benchmark: held-out simulator episodes (in- and out-of-distribution) are continued from 1 and
from 9 given frames, with and without text and actions, and scored against the simulator's frames and masks.

Every predictor has one small interface (`name`, `conditioned`, `predict(episode, num_given, use_text,
use_actions) -> frames`): the world model, the copy-last-frame baseline and the tokenizer's reconstruction of the
ground truth (the ceiling a latent model can reach).
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
import torch
import yaml
from omegaconf import DictConfig
from omegaconf.errors import OmegaConfBaseException
from safetensors import SafetensorError

from ..config import to_dataclass
from ..errors import ConfigError, InputError
from ..log import get_logger, progress
from ..sim import SCENARIOS, Episode, simulate
from ..tokenizers import Tokenizer
from ..tokenizers.inference import pad_video, to_frames, to_tensor
from .metrics import (
    nanmean,
    object_iou_per_frame,
    psnr_per_frame,
    segment_by_palette,
    ssim_per_frame,
    trajectory_errors,
)

log = get_logger("eval")

# name -> (use text, use actions) for the world model's conditioning variants.
CONDITIONS = {"text+actions": (True, True), "text": (True, False), "actions": (False, True), "none": (False, False)}
# metric -> (label, higher is better); each is scored per predicted frame.
METRICS = {
    "psnr": ("PSNR (dB)", True),
    "ssim": ("SSIM", True),
    "iou": ("object IoU", True),
    "position": ("centroid error (px)", False),
    "velocity": ("velocity error (px/frame)", False),
}
HELDOUT_TAG = 8  # mixed into every held-out episode seed, so none equals a `cosmos-lite sim` training seed


@dataclass
class EvalConfig:
    """Mirrors configs/eval.yaml."""

    checkpoint: str | None = None
    out: str = "outputs/eval"
    scenarios: list[str] = field(default_factory=lambda: ["bounce", "collision", "pusher"])
    splits: list[str] = field(default_factory=lambda: ["id", "ood"])
    episodes: int = 4
    given: list[int] = field(default_factory=lambda: [1, 9])
    horizon: int = 16
    conditions: list[str] = field(default_factory=lambda: list(CONDITIONS))
    steps: int = 10
    sampler: str = "heun"
    seed: int = 0
    videos: int = 1
    device: str = "cpu"
    policy: dict = field(default_factory=dict)  # settings of `eval policy` (cosmos_lite.eval.policy), unused here

    def check(self) -> EvalConfig:
        bad = [s for s in self.scenarios if s not in SCENARIOS]
        if bad or not self.scenarios:
            raise ConfigError(f"scenarios: unknown {bad or self.scenarios}; choose from {', '.join(SCENARIOS)}")
        if not self.splits or set(self.splits) - {"id", "ood"}:
            raise ConfigError(f"splits={self.splits}: use a list of id and/or ood")
        bad = [c for c in self.conditions if c not in CONDITIONS]
        if bad:
            raise ConfigError(f"conditions: unknown {bad}; choose from {', '.join(CONDITIONS)}")
        if self.episodes < 1 or self.horizon < 1 or self.steps < 1 or not self.given or min(self.given) < 1:
            raise ConfigError(f"need episodes, horizon, steps >= 1 and given frames >= 1; got episodes="
                              f"{self.episodes} horizon={self.horizon} steps={self.steps} given={self.given}")
        return self


class Predictor(Protocol):
    """Continues an episode: `predict` returns the `horizon` frames after the first `num_given`, uint8 (T, H, W, 3).
    `conditioned`: whether text and actions matter (else it is run once per number of given frames)."""

    name: str
    conditioned: bool

    def predict(self, ep: Episode, num_given: int, use_text: bool, use_actions: bool) -> np.ndarray: ...


class WorldModel:
    """The diffusion world model: given frames, optionally the episode's caption and actions, same seed for all."""

    name, conditioned = "world model", True

    def __init__(self, pipe, horizon: int, steps: int, sampler: str, seed: int):
        self.pipe, self.horizon, self.steps, self.sampler, self.seed = pipe, horizon, steps, sampler, seed

    def predict(self, ep: Episode, num_given: int, use_text: bool, use_actions: bool) -> np.ndarray:
        out = self.pipe(prompt=ep.meta["caption"] if use_text else None, video=ep.frames[:num_given],
                        actions=ep.actions if use_actions else None, num_frames=num_given + self.horizon,
                        steps=self.steps, sampler=self.sampler, seed=self.seed)
        return out.frames[num_given:]


class CopyLastFrame:
    """The last given frame, held: a model must beat it to show it predicts motion."""

    name, conditioned = "copy last frame", False

    def __init__(self, horizon: int):
        self.horizon = horizon

    def predict(self, ep: Episode, num_given: int, use_text: bool, use_actions: bool) -> np.ndarray:
        return np.repeat(ep.frames[num_given - 1 : num_given], self.horizon, axis=0)


class TokenizerReconstruction:
    """The tokenizer's encode-decode of the true frames: the ceiling of a model that generates in its latent space."""

    name, conditioned = "tokenizer reconstruction", False

    def __init__(self, tokenizer: Tokenizer, horizon: int):
        self.tokenizer, self.horizon = tokenizer, horizon

    @torch.no_grad()
    def predict(self, ep: Episode, num_given: int, use_text: bool, use_actions: bool) -> np.ndarray:
        tok, n = self.tokenizer, num_given + self.horizon
        device = next(tok.parameters()).device
        x = pad_video(to_tensor(ep.frames[:n]), tok.temporal_compression, tok.spatial_compression).to(device)
        h, w = ep.frames.shape[1:3]
        return to_frames(tok.decode(tok.encode(x)).cpu())[num_given:n, :h, :w]


def heldout_episodes(c: EvalConfig, size: tuple[int, int], fps: float) -> list[Episode]:
    """`episodes` new simulator episodes per scenario and split, at the model's size and frame rate."""
    frames = max(c.given) + c.horizon
    eps = []
    for s, scenario in enumerate(c.scenarios):
        for split in c.splits:
            for i in range(c.episodes):
                seed = int(np.random.SeedSequence([c.seed, HELDOUT_TAG, s, split == "ood", i]).generate_state(1)[0])
                ep = simulate(scenario, seed, split=split, frames=frames, fps=fps, size=size)
                ep.meta["name"] = f"{scenario}_{split}_{i:03d}"
                eps.append(ep)
    return eps


def score(pred: np.ndarray, ep: Episode, num_given: int) -> dict[str, np.ndarray]:
    """Per predicted frame: PSNR, SSIM, mean object IoU of the colour-segmented prediction with the simulator's masks,
    centroid and velocity errors (the velocity into the first predicted frame starts from the last given one)."""
    n = len(pred)
    truth, masks = ep.frames[num_given : num_given + n], ep.masks[num_given - 1 : num_given + n]
    ids = list(range(1, len(ep.meta["objects"]) + 1))
    seg = segment_by_palette(np.concatenate([ep.frames[num_given - 1 : num_given], pred]), ep.meta["palette"],
                             background=[ep.meta["scenery_color"]])
    traj = trajectory_errors(seg, masks, ids)
    return {
        "psnr": psnr_per_frame(pred, truth),
        "ssim": ssim_per_frame(pred, truth),
        "iou": nanmean(object_iou_per_frame(seg[1:], masks[1:], ids), 1),
        "position": traj["position"][1:],
        "velocity": traj["velocity"],
    }


def load_pipeline(checkpoint: str | None, device: str):
    """The world-model pipeline of a checkpoint folder (InputError naming the path and the fix if it is not one)."""
    from ..models import WorldModelPipeline

    if not checkpoint:
        raise ConfigError("checkpoint= is required: a world-model folder from `cosmos-lite train experiment=wfm_nano`")
    try:
        return WorldModelPipeline.from_pretrained(checkpoint, device=device)
    except (SafetensorError, yaml.YAMLError, OmegaConfBaseException, RuntimeError, OSError, KeyError, ValueError) as e:
        why = str(e).splitlines()[0] if str(e) else ""
        raise InputError(f"{checkpoint}: unreadable world-model checkpoint ({type(e).__name__}: {why}); rewrite "
                         "it with `cosmos-lite train experiment=wfm_nano` (or WorldModelPipeline.save_pretrained)"
                         ) from None


def _runs(predictors: list[Predictor], conditions: list[str], model_cond: dict[str, bool]):
    """(label, predictor, use_text, use_actions) for each model row; conditions the model lacks are left out."""
    for p in predictors:
        if not p.conditioned:
            yield p.name, p, False, False
            continue
        for cond in conditions:
            text, actions = CONDITIONS[cond]
            if (text and not model_cond["text"]) or (actions and not model_cond["actions"]):
                log.warning("%s: checkpoint has no %s input; skipping condition %s", p.name,
                            "text" if text and not model_cond["text"] else "action", cond)
                continue
            yield f"{p.name} ({cond})", p, text, actions


def _mean_rows(records: list[dict], keys: tuple[str, ...]) -> list[dict]:
    """Mean over episodes of each metric's per-episode mean, grouped by `keys` (first-seen order)."""
    groups: dict[tuple, list[dict]] = {}
    for r in records:
        groups.setdefault(tuple(r[k] for k in keys), []).append(r)
    rows = []
    for key, rs in groups.items():
        row = dict(zip(keys, key), episodes=len(rs))
        row.update({m: _num(nanmean([r["mean"][m] for r in rs])) for m in METRICS})
        rows.append(row)
    return rows


def _horizon_rows(records: list[dict]) -> list[dict]:
    """Mean over episodes at each predicted frame, per model and number of given frames."""
    groups: dict[tuple, list[dict]] = {}
    for r in records:
        groups.setdefault((r["model"], r["given"]), []).append(r)
    return [{"model": m, "given": k, **{name: [_num(v) for v in nanmean(
        np.array([[np.nan if v is None else v for v in r["per_frame"][name]] for r in rs]), 0)] for name in METRICS}}
        for (m, k), rs in groups.items()]


def _num(v) -> float | None:
    """A JSON-safe float: NaN (no object to score) becomes None."""
    v = float(v)
    return None if np.isnan(v) else v


def run_physics_eval(cfg: DictConfig | dict) -> dict:
    """Run the benchmark of configs/eval.yaml (`cfg`), write out/results.json, report.md, report.html, plots and
    side-by-side videos; returns the results."""
    from .report import write_report, write_side_by_side

    c = to_dataclass(EvalConfig, cfg, "eval").check()
    pipe = load_pipeline(c.checkpoint, c.device)
    net = pipe.denoiser.net.cfg
    model_cond = {"text": net.text_dim > 0, "actions": net.action_dim > 0}
    out = Path(c.out)
    t0 = time.time()
    episodes = heldout_episodes(c, pipe.size, float(pipe.cfg.data.fps))
    predictors: list[Predictor] = [WorldModel(pipe, c.horizon, c.steps, c.sampler, c.seed), CopyLastFrame(c.horizon),
                                   TokenizerReconstruction(pipe.tokenizer, c.horizon)]
    runs = list(_runs(predictors, c.conditions, model_cond))
    shown = {(ep.meta["scenario"], ep.meta["split"]): [] for ep in episodes}
    records, videos = [], []
    for ep in progress(episodes, desc="eval episodes"):
        show = len(shown[ep.meta["scenario"], ep.meta["split"]]) < c.videos
        if show:
            shown[ep.meta["scenario"], ep.meta["split"]].append(ep.meta["name"])
        for k in c.given:
            for label, predictor, text, actions in runs:
                pred = predictor.predict(ep, k, text, actions)
                per_frame = score(pred, ep, k)
                records.append({
                    "model": label, "given": k, "episode": ep.meta["name"], "scenario": ep.meta["scenario"],
                    "split": ep.meta["split"],
                    "mean": {m: _num(nanmean(v)) for m, v in per_frame.items()},
                    "per_frame": {m: [_num(x) for x in v] for m, v in per_frame.items()},
                })
                if show and label == runs[0][0]:
                    name = f"{ep.meta['name']}_given{k}"
                    mp4, gif = write_side_by_side(out, name, ep.frames[: k + c.horizon],
                                                  np.concatenate([ep.frames[:k], pred]), ep.meta["fps"])
                    videos.append({"title": f"{ep.meta['scenario']} ({ep.meta['split']}), {k} given, {label}",
                                   "episode": ep.meta["name"], "model": label, "given": k, "mp4": mp4, "gif": gif})
    results = {
        "checkpoint": str(Path(c.checkpoint).resolve()),
        "config": asdict(c),
        "seeds": {"episodes": {ep.meta["name"]: ep.meta["seed"] for ep in episodes}, "sampler": c.seed},
        "episodes": [{k: ep.meta[k] for k in ("name", "scenario", "split", "seed", "caption", "params")}
                     for ep in episodes],
        "metrics": {m: {"label": label, "higher_is_better": hib} for m, (label, hib) in METRICS.items()},
        "models": list(dict.fromkeys(r["model"] for r in records)),
        "table": _mean_rows(records, ("model", "given")),
        "by_scenario": _mean_rows(records, ("model", "given", "scenario")),
        "by_split": _mean_rows(records, ("model", "given", "split")),
        "horizon": _horizon_rows(records),
        "records": records,
        "videos": videos,
        "seconds": round(time.time() - t0, 1),
    }
    write_report(results, out)
    log.info("eval: %d episodes, %d predictions in %.0f s -> %s", len(episodes), len(records), results["seconds"],
             out / "report.html")
    return results
