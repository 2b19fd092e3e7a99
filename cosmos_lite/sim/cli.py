"""Simulate physics episodes into a folder: NAME.mp4 + NAME.npz + NAME.json each, and index.json.

Example: `cosmos-lite sim out=data/sim sim.scenario=mix sim.episodes=64 seed=0 workers=2`. Episode i uses the
seed derived from (seed, i), so the output is the same for any worker count; a rerun skips finished episodes.
`cosmos-lite sim ranges` prints every scenario's parameters with their id and ood ranges (world units: the frame is
64 units tall); fix or narrow one with `+sim.params.NAME=VALUE` or `+sim.params.NAME=[lo,hi]`.

Main keys: sim.scenario = bounce | projectile | collision | uniform | ramp | pendulum | pusher | mix (all) or a
list [a,b]; sim.split = id | ood; sim.size (int or [H,W]); sim.frames; sim.fps; sim.substeps;
sim.background = plain | textured; workers (processes).
"""

from __future__ import annotations

import json
import multiprocessing as mp
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from ..config import bad, number, setting, to_dataclass
from ..errors import ConfigError
from ..files import write_text
from ..log import get_logger, progress
from .episode import read_meta, simulate, write_episode
from .scenarios import SCENARIOS, SPECS

log = get_logger("sim")


@dataclass
class SimConfig:
    """Mirrors configs/sim/default.yaml."""

    scenario: str | list[str] = "mix"
    episodes: int = setting(8, low=1)
    split: str = setting("id", choices=("id", "ood"))
    size: int | list[int] = 64
    frames: int = setting(33, low=1)
    fps: float = setting(16.0, above=0)
    substeps: int = setting(16, low=1)
    background: str = setting("plain", choices=("plain", "textured"))
    params: dict = field(default_factory=dict)

    def scenarios(self) -> list[str]:
        names = list(SCENARIOS) if self.scenario == "mix" else [self.scenario] if isinstance(self.scenario, str) \
            else list(self.scenario)
        bad = [s for s in names if s not in SCENARIOS]
        if bad or not names:
            raise ConfigError(f"sim.scenario: unknown {bad or names}; choose from {', '.join(SCENARIOS)} or mix")
        return names


def episode_seed(seed: int, index: int) -> int:
    """The seed of episode `index` in a run seeded `seed`, independent of how episodes are spread over workers."""
    return int(np.random.SeedSequence([seed, index]).generate_state(1)[0])


def _done(path: Path, seed: int, kwargs: dict) -> dict | None:
    """The meta of a finished episode written with these settings, else None (it is simulated again)."""
    if not (path.with_suffix(".json").is_file() and path.with_suffix(".mp4").is_file()):
        return None
    meta = read_meta(path)
    size = kwargs["size"]
    wanted = {**kwargs, "seed": seed, "size": [size, size] if isinstance(size, int) else list(size)}
    same = all(meta.get(k) == v for k, v in wanted.items() if k in meta and k != "params")
    same &= all(meta["params"].get(k) == v for k, v in wanted.items() if k in SPECS[meta["scenario"]])
    return meta if same and meta.get("seed") == seed else None


def _one(job: tuple[str, str, int, dict]) -> dict:
    out, name, seed, kwargs = job
    meta = _done(Path(out) / name, seed, kwargs)
    if meta is None:
        ep = simulate(seed=seed, **kwargs)
        write_episode(ep, out, name)
        meta = ep.meta
    return {"name": name, **{k: meta[k] for k in ("scenario", "split", "seed", "caption")}}


def run(sim: SimConfig, out: str | Path, seed: int = 0, workers: int = 1) -> list[dict]:
    """Simulate `sim.episodes` episodes into `out` (in parallel over `workers` processes); returns the index."""
    names = sim.scenarios()
    size = sim.size if isinstance(sim.size, int) else tuple(sim.size)
    jobs = []
    for i in range(sim.episodes):
        scenario = names[i % len(names)]
        kwargs = dict(scenario=scenario, split=sim.split, frames=sim.frames, fps=sim.fps, size=size,
                      substeps=sim.substeps, background=sim.background, **sim.params)
        jobs.append((str(out), f"{scenario}_{i:06d}", episode_seed(seed, i), kwargs))
    if jobs:
        simulate(seed=0, **{**jobs[0][3], "frames": 1})  # fail fast on bad settings, before any process starts
    try:
        Path(out).mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ConfigError(f"out={out}: cannot create the folder ({e.strerror}); pass a writable out=DIR") from None
    if workers > 1:
        with mp.get_context("spawn").Pool(workers) as pool:
            index = list(progress(pool.imap(_one, jobs), desc="sim", total=len(jobs)))
    else:
        index = [_one(j) for j in progress(jobs, desc="sim", total=len(jobs))]
    manifest = {"seed": seed, "sim": asdict(sim), "episodes": index}
    write_text(Path(out) / "index.json", json.dumps(manifest, indent=1))
    return index


def main(cfg: DictConfig, args: list[str]) -> int:
    if args == ["ranges"]:
        print(json.dumps({s: {k: asdict(p) for k, p in spec.items()} for s, spec in SPECS.items()}, indent=1))
        return 0
    if args:
        raise ConfigError(f"unknown argument(s) {' '.join(args)}; the only one is `ranges`")
    if not cfg.out:
        raise ConfigError("no output folder: pass out=DIR")
    workers, seed = number("workers", cfg.workers, low=1), number("seed", cfg.seed, low=0)
    sim = to_dataclass(SimConfig, cfg.sim, "sim")
    sizes = [sim.size] if isinstance(sim.size, int) else sim.size
    if len(sizes) not in (1, 2) or min(sizes) < 8:
        raise bad("sim.size", sim.size, "an integer >= 8 or [H, W] of integers >= 8")
    index = run(sim, cfg.out, seed, workers)
    log.info("wrote %d episodes to %s", len(index), cfg.out)
    print(json.dumps({"out": str(cfg.out), "episodes": len(index)}))
    return 0
