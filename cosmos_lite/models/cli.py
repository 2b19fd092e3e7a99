"""Generate guarded videos with a trained world model: text2world, video2world, action-conditioned, long rollouts.

Example: `cosmos-lite generate checkpoint=runs/wfm_nano prompt="a red ball falls and bounces" input=first.png
actions=push.npy num_frames=33 output=outputs/gen`. Writes OUTPUT/NAME.mp4 and a JSON sidecar OUTPUT/NAME.json
(prompt, seed, resolved config, guard verdicts, timings). A prompt or video that a guardrail blocks writes no video,
prints the verdict as JSON and exits 3. `batch=requests.jsonl` runs one request per line (keys: prompt, input,
input_frames, actions, num_frames, steps, sampler, guidance, action_guidance, seed, name; relative paths are relative
to the JSONL file); a failed or blocked line is reported and the rest continue.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from ..config import bad, choice, number, setting, to_dataclass
from ..errors import ConfigError, CosmosError, GuardrailBlocked, InputError
from ..files import write_text
from ..log import get_logger, progress
from ..video import read_frames, write_video
from .pipeline import WorldModelPipeline
from .samplers import SAMPLERS

log = get_logger("generate")
PATH_KEYS = ("input", "actions")


@dataclass
class Request:
    """One generation request: the CLI's keys (configs/generate.yaml) or one line of a batch JSONL file."""

    prompt: str | None = None
    input: str | None = None
    input_frames: int = setting(9, low=1)
    actions: str | None = None
    num_frames: int | None = setting(None, low=1)
    steps: int | None = setting(None, low=1)  # sampler steps per generated frame (null: the checkpoint's edm.steps)
    sampler: str = setting("euler", choices=SAMPLERS)  # euler | heun
    guidance: float = setting(1.0, low=0)
    action_guidance: float = setting(1.0, low=0)
    seed: int = setting(0, low=0)
    name: str | None = None

    def check(self, where: str = "") -> Request:
        """Checks beyond types and ranges: some condition to generate from, a name that stays in the output folder."""
        key = f"{where}prompt"
        if self.prompt is not None and not self.prompt.strip():
            raise bad(key, self.prompt, 'some text, not an empty one: prompt="...", or leave it out and pass input=')
        if not self.prompt and not self.input:
            raise ConfigError(f"{where}nothing to condition on: pass prompt=\"...\" and/or input=IMAGE_OR_VIDEO")
        if self.name is not None and (not self.name.strip() or self.name != Path(self.name).name
                                      or self.name.startswith(".") or "\\" in self.name):
            raise bad(f"{where}name", self.name, "a plain file name (no folders, not starting with '.'); "
                      "videos are written inside output=")
        return self


REQUEST_KEYS = tuple(f.name for f in dataclasses.fields(Request))


def load_actions(path: str | os.PathLike) -> np.ndarray:
    """Per-frame actions `(T, A)` float32 from .npy, .npz (key `actions`), .json (list of lists) or .csv/.txt."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"actions file {p} not found: pass actions=FILE with a (T, A) array (.npy/.npz/.json/.csv)")
    try:
        if p.suffix == ".npy":
            a = np.load(p, allow_pickle=False)
        elif p.suffix == ".npz":
            with np.load(p, allow_pickle=False) as z:
                a = z["actions"]
        elif p.suffix == ".json":
            a = np.asarray(json.loads(p.read_text()), dtype=np.float32)
        else:
            with warnings.catch_warnings():  # an empty file: reported below, with its name
                warnings.simplefilter("ignore", UserWarning)
                a = np.loadtxt(p, delimiter="," if p.suffix == ".csv" else None, ndmin=2)
    except (ValueError, KeyError, OSError) as e:
        raise InputError(f"{p}: cannot read actions ({e}); write a (T, A) float array (.npy/.npz key "
                         "'actions'/.json/.csv)") from e
    a = np.asarray(a, dtype=np.float32)
    if a.ndim != 2 or a.size == 0 or not np.isfinite(a).all():
        raise InputError(f"{p}: actions must be a finite (T, A) array; got shape {a.shape}")
    return a


def default_name(req: dict) -> str:
    """A readable, deterministic file stem: the prompt's first words (or the input's name) and the seed."""
    stem = req.get("prompt") or (Path(req["input"]).stem if req.get("input") else "sample")
    slug = "-".join(re.findall(r"[a-z0-9]+", stem.lower()))[:40].strip("-") or "sample"
    return f"{slug}-s{req['seed']}"


def write_json(path: Path, record: dict) -> None:
    """Atomic JSON write."""
    write_text(path, json.dumps(record, indent=2, default=str) + "\n")


def generate_one(pipe: WorldModelPipeline, req: dict, out: Path, crf: int = 18, config: dict | None = None) -> dict:
    """Run one request (checked as a Request); write NAME.mp4 (unless blocked) and NAME.json (with `config`, the
    resolved CLI config); return the sidecar record."""
    r = to_dataclass(Request, req).check()
    name = r.name or default_name(req)
    t0 = time.perf_counter()
    video = read_frames(r.input, end=r.input_frames, size=pipe.size) if r.input else None
    actions = load_actions(r.actions) if r.actions else None
    t1 = time.perf_counter()
    result = pipe(prompt=r.prompt, video=video, actions=actions, num_frames=r.num_frames, steps=r.steps,
                  sampler=r.sampler, guidance=r.guidance, action_guidance=r.action_guidance, seed=r.seed)
    t2 = time.perf_counter()
    fps = float(pipe.cfg.data.fps)
    record = {
        "name": name, "status": "blocked" if result.blocked else "ok", "request": req,
        "verdicts": [dict(v._asdict()) for v in result.verdicts], "video": None,
        "given_frames": 0 if video is None else len(video),
        "timings_s": {"read_inputs": round(t1 - t0, 3), "generate": round(t2 - t1, 3)}, "config": config,
    }
    out.mkdir(parents=True, exist_ok=True)
    if not result.blocked:
        path = out / f"{name}.mp4"
        write_video(path, result.frames, fps, crf=crf)
        record.update(video=str(path), frames=len(result.frames), fps=fps, size=list(result.frames.shape[1:3]))
        record["timings_s"]["write"] = round(time.perf_counter() - t2, 3)
    write_json(out / f"{name}.json", record)
    return record


def read_batch(path: str | os.PathLike, defaults: dict) -> list[dict | CosmosError]:
    """One request per JSONL line (defaults filled in, paths made relative to the file, every value checked); a bad
    line becomes the error it raises, so the other lines still run."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"batch file {p} not found: pass batch=FILE.jsonl with one JSON request per line")
    requests: list[dict | CosmosError] = []
    for i, line in enumerate(p.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            item = json.loads(line)
            if not isinstance(item, dict):
                raise ValueError("not a JSON object")
        except ValueError as e:
            requests.append(ConfigError(f"{p}:{i}: not a JSON object ({e})"))
            continue
        for k in PATH_KEYS:
            if isinstance(item.get(k), str) and item[k] and not Path(item[k]).is_absolute():
                item[k] = str(p.parent / item[k])
        req = {**defaults, **item}
        try:
            to_dataclass(Request, req).check()
        except ConfigError as e:
            requests.append(ConfigError(f"{p}:{i}: {e}"))
            continue
        req["name"] = item.get("name") or f"{i:03d}-{default_name(req)}"
        requests.append(req)
    if not requests:
        raise InputError(f"batch file {p} has no requests: write one JSON object per line")
    return requests


def load_pipeline(cfg: DictConfig) -> WorldModelPipeline:
    """The checkpoint's pipeline, wrapped in the configured guardrails (on unless guardrails.enabled=false)."""
    from ..guardrails import Guardrails

    if not cfg.checkpoint:
        raise ConfigError("pass checkpoint=DIR: a world-model folder from `cosmos-lite train experiment=wfm_nano`")
    guards = None
    if cfg.guardrails.enabled:
        guards = Guardrails.from_config(cfg.guardrails)
    else:
        log.warning("guardrails are OFF (guardrails.enabled=false): prompts and videos are not checked")
    device = choice("device", cfg.device, ("cpu", "cuda", "auto"))
    if device == "auto":
        import torch

        device = "cuda" if torch.cuda.is_available() else "cpu"
    return WorldModelPipeline.from_pretrained(cfg.checkpoint, device, guardrails=guards)


def main(cfg: DictConfig, args: list[str]) -> int:
    if not cfg.output:
        raise ConfigError("pass output=DIR: where NAME.mp4 and NAME.json are written")
    config = OmegaConf.to_container(cfg, resolve=True)
    defaults = {k: config[k] for k in REQUEST_KEYS}
    crf = number("crf", cfg.crf, low=0, high=51)
    if args:
        raise ConfigError(f"unknown argument(s) {' '.join(args)}; pass key=value settings (see --help)")
    if cfg.batch:
        requests: list[dict | CosmosError] = read_batch(cfg.batch, defaults)
    else:  # every value and input file checked before the model loads
        request = to_dataclass(Request, defaults).check()
        if request.actions:
            load_actions(request.actions)
        if request.input and not Path(request.input).is_file():
            raise InputError(f"input={request.input}: no such file; pass an image or video file")
        requests = [defaults]
    pipe = load_pipeline(cfg)
    out = Path(cfg.output)
    code = 0
    for req in progress(requests, desc="generate", unit="video"):
        try:
            if isinstance(req, CosmosError):
                raise req
            record = generate_one(pipe, req, out, crf, config)
        except CosmosError as e:
            if not cfg.batch:
                raise
            log.error("%s", e)
            print(json.dumps({"status": "failed", "error": str(e)}))
            code = max(code, e.exit_code)
            continue
        print(json.dumps({k: record[k] for k in ("name", "status", "video", "verdicts")}))
        if record["status"] == "blocked":
            code = max(code, GuardrailBlocked.exit_code)
    return code
