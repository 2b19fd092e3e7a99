"""Physics-alignment benchmark: held-out simulator episodes (in- and out-of-distribution) are continued from 1 and
from 9 given frames, with and without text and actions, and scored against the simulator's frames and masks.

Every predictor has one small interface (`name`, `conditioned`, `kind`, `predict(episode, num_given, use_text,
use_actions) -> frames`): the world model, the copy-last-frame baseline (the score's 0), the tokenizer's
reconstruction of the ground truth (the best a latent model can look) and the perfect model (re-simulation, the
score's 100). `stats` turns the per-episode scores into intervals, scores and verdicts; `report` writes them.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
import torch
import yaml
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException
from safetensors import SafetensorError

from ..config import setting, to_dataclass
from ..core.engine import read_state_meta
from ..core.frames import to_frames, to_tensor
from ..core.metrics import (
    mask_iou_per_frame,
    motion_masks,
    nanmean,
    object_iou_per_frame,
    psnr_per_frame,
    segment_by_palette,
    spatial_iou_so_far,
    ssim_per_frame,
    trajectory_errors,
    weighted_spatial_iou_so_far,
)
from ..errors import ConfigError, InputError
from ..log import get_logger, progress
from ..models.samplers import SAMPLERS
from ..sim import SCENARIOS, Episode, simulate
from ..tokenizers import Tokenizer
from ..tokenizers.inference import pad_video
from .ceiling import PerfectModel
from .stats import alignment_scores, horizon_rows, json_float, summary_rows, verdicts

log = get_logger("eval")

# name -> (use text, use actions) for the world model's conditioning variants.
CONDITIONS = {"text+actions": (True, True), "text": (True, False), "actions": (False, True), "none": (False, False)}
# Every metric is scored per predicted frame; "clip" metrics at frame t cover predicted frames 1..t (an episode's value
# is the last), the others are means over frames. `about` is the report's definition.
METRICS = {
    "psnr": {"label": "PSNR", "unit": "dB", "higher_is_better": True, "per": "frame", "digits": 2,
             "about": "peak signal-to-noise ratio of the predicted frames against the simulator's (appearance)"},
    "ssim": {"label": "SSIM", "unit": "", "higher_is_better": True, "per": "frame", "digits": 3,
             "about": "structural similarity, Gaussian window (appearance)"},
    "iou": {"label": "object IoU", "unit": "", "higher_is_better": True, "per": "frame", "digits": 3,
            "about": "each object's pixels found by colour in the prediction against the simulator's object mask, "
                     "IoU averaged over objects"},
    "spatial_iou": {"label": "spatial IoU", "unit": "", "higher_is_better": True, "per": "clip", "digits": 3,
                    "about": "Physics-IQ's 'where': IoU of the pixels that moved at any time (motion: a pixel "
                             "differs from the clip's per-pixel temporal median by over 10%)"},
    "spatiotemporal_iou": {"label": "spatiotemporal IoU", "unit": "", "higher_is_better": True, "per": "frame",
                           "digits": 3, "about": "Physics-IQ's 'where and when': IoU of the moving pixels of each "
                                                 "frame, averaged over frames"},
    "weighted_spatial_iou": {"label": "weighted spatial IoU", "unit": "", "higher_is_better": True, "per": "clip",
                             "digits": 3, "about": "Physics-IQ's 'where and how much': per pixel the number of "
                                                   "frames it moved, sum of minima over sum of maxima"},
    "position": {"label": "centroid error", "unit": "px", "higher_is_better": False, "per": "frame", "digits": 2,
                 "about": "distance between each object's centroid in the prediction and in the simulator, "
                          "averaged over the objects found (PhyWorld)"},
    "velocity": {"label": "velocity error", "unit": "px/frame", "higher_is_better": False, "per": "frame",
                 "digits": 2, "about": "per-object velocity error: distance between the predicted and the true "
                                       "centroid displacement per frame, averaged over objects found (PhyWorld)"},
}
HELDOUT_TAG = 8  # mixed into every held-out episode seed, so none equals a `cosmos-lite sim` training seed


@dataclass
class EvalConfig:
    """Mirrors configs/eval.yaml."""

    checkpoint: str | None = None
    out: str = "outputs/eval"
    scenarios: list[str] = field(default_factory=lambda: ["bounce", "collision", "pusher"])
    splits: list[str] = field(default_factory=lambda: ["id", "ood"])
    episodes: int = setting(4, low=1)
    given: list[int] = field(default_factory=lambda: [1, 9])
    horizon: int = setting(16, low=1)
    conditions: list[str] = field(default_factory=lambda: list(CONDITIONS))
    steps: int | None = setting(None, low=1)  # null: the checkpoint's edm.steps
    sampler: str = setting("euler", choices=SAMPLERS)
    seed: int = setting(0, low=0)
    videos: int = setting(1, low=0)
    device: str = setting("cpu", choices=("cpu", "cuda"))
    ceiling_draws: int = setting(300, low=1)  # re-simulations tried per episode for the perfect model's sample
    fail_on: list[str] = field(default_factory=list)  # compare: metrics (or score) whose regression fails the run
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
        if self.episodes < 1 or self.horizon < 1 or not self.given or min(self.given) < 1 or self.ceiling_draws < 1:
            raise ConfigError(f"need episodes, horizon, ceiling_draws >= 1 and given frames >= 1; got episodes="
                              f"{self.episodes} horizon={self.horizon} ceiling_draws={self.ceiling_draws} "
                              f"given={self.given}")
        return self


class Predictor(Protocol):
    """Continues an episode: `predict` returns the `horizon` frames after the first `num_given`, uint8 (T, H, W, 3),
    or None if it has none. `conditioned`: whether text and actions matter (else it is run once per number of given
    frames). `kind`: world model, baseline (the score's 0), reference (sees the true future) or ceiling (the 100)."""

    name: str
    conditioned: bool
    kind: str

    def predict(self, ep: Episode, num_given: int, use_text: bool, use_actions: bool) -> np.ndarray | None: ...


class WorldModel:
    """The diffusion world model: given frames, optionally the episode's caption and actions, same seed for all."""

    name, conditioned, kind = "world model", True, "world model"

    def __init__(self, pipe, horizon: int, steps: int, sampler: str, seed: int):
        self.pipe, self.horizon, self.steps, self.sampler, self.seed = pipe, horizon, steps, sampler, seed

    def predict(self, ep: Episode, num_given: int, use_text: bool, use_actions: bool) -> np.ndarray:
        out = self.pipe(prompt=ep.meta["caption"] if use_text else None, video=ep.frames[:num_given],
                        actions=ep.actions if use_actions else None, num_frames=num_given + self.horizon,
                        steps=self.steps, sampler=self.sampler, seed=self.seed)
        return out.frames[num_given:]


class CopyLastFrame:
    """The last given frame, held: a model must beat it to show it predicts motion."""

    name, conditioned, kind = "copy last frame", False, "baseline"

    def __init__(self, horizon: int):
        self.horizon = horizon

    def predict(self, ep: Episode, num_given: int, use_text: bool, use_actions: bool) -> np.ndarray:
        return np.repeat(ep.frames[num_given - 1 : num_given], self.horizon, axis=0)


class TokenizerReconstruction:
    """The tokenizer's encode-decode of the true frames: the ceiling of a model that generates in its latent space."""

    name, conditioned, kind = "tokenizer reconstruction", False, "reference"

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


def score(pred: np.ndarray | None, ep: Episode, num_given: int, horizon: int) -> dict[str, np.ndarray]:
    """Every metric of METRICS per predicted frame (NaN throughout if `pred` is None). Object IoU and the centroid
    errors come from the colour-segmented prediction against the simulator's masks (the velocity into the first
    predicted frame starts from the last given one); the motion IoUs from motion masks of the given frames followed by
    the prediction, against those of the true clip."""
    if pred is None:
        return {m: np.full(horizon, np.nan) for m in METRICS}
    n = len(pred)
    truth, masks = ep.frames[num_given : num_given + n], ep.masks[num_given - 1 : num_given + n]
    ids = list(range(1, len(ep.meta["objects"]) + 1))
    seg = segment_by_palette(np.concatenate([ep.frames[num_given - 1 : num_given], pred]), ep.meta["palette"],
                             background=[ep.meta["scenery_color"]])
    traj = trajectory_errors(seg, masks, ids)
    moved = motion_masks(np.concatenate([ep.frames[:num_given], pred]))[num_given:]
    true_moved = motion_masks(ep.frames[: num_given + n])[num_given:]
    return {
        "psnr": psnr_per_frame(pred, truth),
        "ssim": ssim_per_frame(pred, truth),
        "iou": nanmean(object_iou_per_frame(seg[1:], masks[1:], ids), 1),
        "spatial_iou": spatial_iou_so_far(moved, true_moved),
        "spatiotemporal_iou": mask_iou_per_frame(moved, true_moved),
        "weighted_spatial_iou": weighted_spatial_iou_so_far(moved, true_moved),
        "position": traj["position"][1:],
        "velocity": traj["velocity"],
    }


def episode_value(metric: str, per_frame: np.ndarray) -> float:
    """An episode's value of a metric: the last frame's for clip metrics (they accumulate), else the mean."""
    return float(per_frame[-1]) if METRICS[metric]["per"] == "clip" else float(nanmean(per_frame))


def training_details(checkpoint: str, cfg: DictConfig) -> dict:
    """What the checkpoint was trained on and for how long, from its config and the step and minutes in its train
    state's metadata (None where a detail is not recorded)."""
    state = read_state_meta(checkpoint) or {}
    pick = lambda key: OmegaConf.select(cfg, key, default=None)  # noqa: E731
    roots = pick("data.roots")
    return {
        "steps": None if state.get("step") is None else int(state["step"]), "planned_steps": pick("trainer.steps"),
        "minutes": None if state.get("minutes") is None else round(float(state["minutes"]), 1),
        "max_minutes": pick("trainer.max_minutes"),
        "data": None if roots is None else [str(r) for r in roots],
        "model": None if pick("model.dim") is None else f"dim {pick('model.dim')}, depth {pick('model.depth')}",
        "frames": pick("data.num_frames"), "size": [pick("data.height"), pick("data.width")],
        "tokenizer": pick("tokenizer.path"), "init_from": pick("posttrain.init_from"),
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


def run_physics_eval(cfg: DictConfig | dict) -> dict:
    """Run the benchmark of configs/eval.yaml (`cfg`), write out/results.json, report.md, report.html, plots and
    side-by-side videos; returns the results."""
    from .report import write_report, write_side_by_side

    c = to_dataclass(EvalConfig, cfg).check()
    pipe = load_pipeline(c.checkpoint, c.device)
    net = pipe.denoiser.net.cfg
    model_cond = {"text": net.text_dim > 0, "actions": net.action_dim > 0}
    out = Path(c.out)
    t0 = time.time()
    episodes = heldout_episodes(c, pipe.size, float(pipe.cfg.data.fps))
    predictors: list[Predictor] = [WorldModel(pipe, c.horizon, c.steps, c.sampler, c.seed), CopyLastFrame(c.horizon),
                                   TokenizerReconstruction(pipe.tokenizer, c.horizon),
                                   PerfectModel(c.horizon, c.ceiling_draws, c.seed)]
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
                if pred is None:
                    log.warning("%s: no consistent re-simulation of %s in %d draws (%d given); its metrics are "
                                "left out", label, ep.meta["name"], c.ceiling_draws, k)
                per_frame = score(pred, ep, k, c.horizon)
                records.append({
                    "model": label, "given": k, "episode": ep.meta["name"], "scenario": ep.meta["scenario"],
                    "split": ep.meta["split"],
                    "mean": {m: json_float(episode_value(m, v)) for m, v in per_frame.items()},
                    "per_frame": {m: [json_float(x) for x in v] for m, v in per_frame.items()},
                })
                if show and label == runs[0][0]:
                    name = f"{ep.meta['name']}_given{k}"
                    mp4, gif = write_side_by_side(out, name, ep.frames[: k + c.horizon],
                                                  np.concatenate([ep.frames[:k], pred]), ep.meta["fps"], given=k)
                    videos.append({"title": f"{ep.meta['scenario']} ({ep.meta['split']}), {k} given, {label}",
                                   "episode": ep.meta["name"], "model": label, "given": k, "mp4": mp4, "gif": gif})
    rng = np.random.default_rng(c.seed)
    results = {
        "checkpoint": str(Path(c.checkpoint).resolve()),
        "training": training_details(c.checkpoint, pipe.cfg),
        "config": asdict(c),
        "seeds": {"episodes": {ep.meta["name"]: ep.meta["seed"] for ep in episodes}, "sampler": c.seed},
        "episodes": [{k: ep.meta[k] for k in ("name", "scenario", "split", "seed", "caption", "params")}
                     for ep in episodes],
        "metrics": METRICS,
        "models": [label for label, *_ in runs],
        "kinds": {label: p.kind for label, p, *_ in runs},
        "table": summary_rows(records, ("model", "given"), METRICS, rng),
        "by_scenario": summary_rows(records, ("model", "given", "scenario"), METRICS, rng),
        "by_split": summary_rows(records, ("model", "given", "split"), METRICS, rng),
        "horizon": horizon_rows(records, METRICS, rng),
        "records": records,
        "videos": videos,
    }
    results["scores"] = alignment_scores(results, rng)
    results["verdicts"] = verdicts(results, rng)
    results["seconds"] = round(time.time() - t0, 1)
    write_report(results, out)
    log.info("eval: %d episodes, %d predictions in %.0f s -> %s", len(episodes), len(records), results["seconds"],
             out / "report.html")
    return results
