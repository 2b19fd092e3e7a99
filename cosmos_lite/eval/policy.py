"""The world model as a neural simulator: rank policies in it and plan with it, checked against the true simulator.

`cosmos-lite eval policy checkpoint=DIR out=DIR` runs every scripted policy closed-loop on goal-reaching pusher
tasks twice, in the simulator and in the world model (the model's frames feed the policy's next action), and
reports each policy's score in both and their Spearman rank correlation: a world model that can stand in for the
simulator ranks policies as the simulator does. It then runs model-predictive control, planned in the world model,
in the simulator (the oracle) and not at all (random actions), each acting in the true simulator.
The rollouts are independent jobs: in this process (runner=local) or on Ray actors (runner=ray).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from scipy.stats import spearmanr

from ..config import setting, to_dataclass
from ..curation.pipeline import RayConfig
from ..curation.runners import Stage, limit_threads, run_local, run_ray
from ..errors import ConfigError
from ..log import get_logger, progress
from ..models.samplers import SAMPLERS
from ..sim import write_episode
from ..sim.goal import AGENT, DISC, GoalTask, make_goal_task
from .policies import Observation, Scripted, behaviour_policy, policy_family, read_positions

log = get_logger("eval.policy")

WORLDS = ("simulator", "world model")
PLANNERS = ("world model", "simulator", "random")  # MPC planned in the world model, in the simulator (oracle), not
APPROACH_WEIGHT = 0.2  # MPC cost per pixel between agent and disc (beyond touching), beside the disc-goal distance
# MPC cost, in pixels, of a predicted final frame in which the disc is not found, on top of its last seen distance: a
# rollout that loses the disc says nothing about it. Validation tasks (goal seed 1, 32 tasks, docs/policy_diagnosis_
# 2026-11-28.txt): world-model planner success 0.03 -> 0.12, final distance 23.6 -> 16.6 px against no penalty.
LOST_COST = 10.0
GOAL_DATA_TAG = 31  # mixed into the behaviour seeds of `goal_episodes`

# A world continues a rollout: (frames so far (T, H, W, 3), actions (T - 1 + n, 2), n, seed) -> the next n frames.
World = Callable[[np.ndarray, np.ndarray, int, int], np.ndarray]
# A foresight looks ahead for a planner: (frames so far (T, H, W, 3), candidate actions (K, T - 1 + n, 2), n, seed)
# -> the frame n frames on under each candidate, per sample (S, K, H, W, 3).
Foresight = Callable[[np.ndarray, np.ndarray, int, int], np.ndarray]


@dataclass
class MPCConfig:
    """Model-predictive control by random shooting: candidates head for random waypoints around the disc, or are
    goal-shaped proposals of behaviour policies (`proposals`)."""

    tasks: int = setting(4, low=0)  # tasks each planner runs (0: no planning)
    candidates: int = setting(16, low=1)  # action sequences scored per plan (the previous best, shifted, is one)
    horizon: int = setting(16, low=1)  # frames each candidate is rolled out before its final frame is scored
    execute: int = setting(4, low=1)  # frames of the best candidate executed in the simulator before planning again
    segment: int = setting(8, low=1)  # frames per constant-velocity segment of a candidate
    speed: float = setting(45.0, above=0)  # top speed of candidate actions, world units/s
    spread: float = setting(6.0, low=0)  # std of the candidates' waypoints around the disc, world units
    proposals: float = setting(0.5, low=0, high=1)  # share of candidates proposed by behaviour policies (`proposals`)
    samples: int = setting(3, low=1)  # world-model rollouts of each candidate (own noise each), their costs averaged


@dataclass
class PolicyEvalConfig:
    """The `policy` node of configs/eval.yaml, plus the shared top-level keys."""

    checkpoint: str | None = None
    out: str = "outputs/eval"
    seed: int = setting(0, low=0)
    device: str = setting("cpu", choices=("cpu", "cuda"))
    steps: int | None = setting(None, low=1)  # sampler steps per generated frame (null: the checkpoint's edm.steps)
    sampler: str = setting("euler", choices=SAMPLERS)
    tasks: int = setting(4, low=1)  # goal tasks each policy runs in both worlds
    frames: int = setting(49, low=2)  # frames per rollout, the given first one included
    chunk: int = setting(4, low=1)  # frames per policy decision (the action is held) and per world-model call
    policies: list[str] | None = None  # names from policy_family(); None: all
    mpc: MPCConfig = field(default_factory=MPCConfig)
    runner: str = setting("local", choices=("local", "ray"))
    workers: int = setting(1, low=1)
    ray: RayConfig = field(default_factory=RayConfig)
    videos: int = setting(3, low=0)  # side-by-side videos (simulator | world model) on task 0, of the last policies

    def check(self) -> PolicyEvalConfig:
        self.mpc = to_dataclass(MPCConfig, self.mpc, "policy.mpc")
        self.ray = to_dataclass(RayConfig, self.ray, "policy.ray")
        names = [p.name for p in policy_family()]
        self.policies = names if self.policies is None else list(self.policies)
        bad = [p for p in self.policies if p not in names]
        if bad or not self.policies:
            raise ConfigError(f"policy.policies: unknown {bad}; choose from {names}")
        return self


def simulator_world(task: GoalTask) -> World:
    """The true simulator as a world: the task's episode under the actions (deterministic, so the frames so far are
    reproduced, not read)."""
    return lambda frames, actions, n, seed: task.simulate(actions).frames[len(frames):]


def model_world(pipe, steps: int, sampler: str) -> World:
    """The world model as a world: one `pipe.stream` per rollout, continued while it is given its own frames so far
    (other frames, such as a new rollout's first, start a new stream from them)."""
    stream, last = None, None

    def world(frames: np.ndarray, actions: np.ndarray, n: int, seed: int) -> np.ndarray:
        nonlocal stream, last
        if stream is None or len(stream) != len(frames) or not np.array_equal(frames[-1], last):
            stream = pipe.stream(frames, steps, sampler)
        new = stream.extend(actions, n, seed)
        last = new[-1]
        return new

    return world


def simulator_foresight(task: GoalTask) -> Foresight:
    """The true simulator looking ahead: each candidate's episode, one sample (it is deterministic)."""
    return lambda frames, actions, n, seed: np.stack([task.simulate(a).frames[-1] for a in actions])[None]


def model_foresight(pipe, steps: int, sampler: str, samples: int) -> Foresight:
    """The world model looking ahead: all candidates in one batched rollout (`foresee`), `samples` times."""
    return lambda frames, actions, n, seed: pipe.foresee(frames, actions, n, [_seed(seed, s) for s in range(samples)],
                                                         steps, sampler)


def _seed(*parts: int) -> int:
    return int(np.random.SeedSequence([int(p) for p in parts]).generate_state(1)[0])


def _readout(frames: np.ndarray, meta: dict, last: np.ndarray) -> np.ndarray:
    """Agent and disc centroids (2, 2) in the last frame; an object not found keeps its `last` position."""
    now = read_positions(frames[-1:], meta)[0]
    return np.where(np.isnan(now), last, now)


def closed_loop(task: GoalTask, policy: Scripted, world: World, chunk: int,
                seed: int) -> tuple[np.ndarray, np.ndarray, dict]:
    """Run `policy` in `world` from the task's first frame: every `chunk` frames it reads the latest frame and picks
    the velocity held for the next chunk. Returns the frames (task.frames, H, W, 3), the actions and the score read
    out of the frames."""
    first = task.simulate(np.zeros((0, 2)))
    frames, actions, seen = first.frames, np.zeros((0, 2)), first.states[0, :, :2].astype(np.float64)
    rng = np.random.default_rng(seed)
    while len(frames) < task.frames:
        seen = _readout(frames, first.meta, seen)
        n = min(chunk, task.frames - len(frames))
        a = policy.act(Observation(seen[AGENT - 1], seen[DISC - 1], task), rng)
        actions = task.limit(np.concatenate([actions, np.repeat(a[None], n, 0)]))
        frames = np.concatenate([frames, world(frames, actions, n, _seed(seed, len(frames)))])
    return frames, actions, _score(task, frames, first.meta, seen)


def _score(task: GoalTask, frames: np.ndarray, meta: dict, seen: np.ndarray) -> dict:
    """Final disc distance and success read out of the last frame (the last seen position if the disc is gone)."""
    now = read_positions(frames[-1:], meta)[0, DISC - 1]
    found = not np.isnan(now[0])
    d = task.distance(now if found else seen[DISC - 1])
    return {"distance": d, "success": task.succeeded(d), "found": found}


def goal_episodes(out: Path, n: int, seed: int, frames: int = 33, size: int = 64, fps: float = 16.0) -> Path:
    """`n` goal-pushing episodes for world-model training into `out` (existing ones are kept): on goal task i of the
    family `seed` (keep it apart from the families policies are evaluated on), a `behaviour_policy` acts closed-loop
    in the simulator, deciding every 2-6 frames. Scripted policies push steadily and slowly where the pusher
    scenario's random paths push in one stroke; a world model that ranks them must have seen such pushes."""
    out.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        stem = f"goalpush_{seed:03d}_{i:05d}"
        if (out / f"{stem}.json").is_file():
            continue
        task = make_goal_task(i, seed, frames=frames, size=size, fps=fps)
        rng = np.random.default_rng(_seed(seed, GOAL_DATA_TAG, i))
        _, actions, _ = closed_loop(task, behaviour_policy(rng), simulator_world(task), int(rng.integers(2, 7)),
                                    _seed(seed, i))
        write_episode(task.simulate(actions), out, stem)
    return out


def candidates(rng: np.random.Generator, k: int, frames: int, segment: int, fps: float, speed: float,
               agent: np.ndarray, disc: np.ndarray, spread: float) -> np.ndarray:
    """`k` random action sequences (k, frames, 2): per segment of `segment` frames, the agent heads for a waypoint
    drawn around the disc (Gaussian, std `spread` pixels) at up to `speed` pixels/s (the agent follows its actions
    closely, so its path is known up to what it pushes)."""
    dt = segment / fps
    out = np.zeros((k, -(-frames // segment) * segment, 2))
    pos = np.repeat(np.asarray(agent, np.float64)[None], k, 0)
    for j in range(out.shape[1] // segment):
        step = disc + rng.normal(0.0, spread, (k, 2)) - pos
        dist = np.hypot(step[:, 0], step[:, 1])[:, None]
        v = step / np.maximum(dist, 1e-9) * np.minimum(speed, dist / dt)
        out[:, j * segment : (j + 1) * segment] = v[:, None]
        pos = pos + v * dt
    return out[:, :frames]


def proposals(rng: np.random.Generator, k: int, frames: int, segment: int, task: GoalTask, agent: np.ndarray,
              disc: np.ndarray) -> np.ndarray:
    """`k` goal-shaped action sequences (k, frames, 2): each a `behaviour_policy` (the greedy pushers of random speed,
    noise and care that the world model's goal-pushing episodes were collected with) acting every `segment` frames on
    an imagined state, in which the agent moves as told and shoves the disc ahead of it on contact."""
    out = np.zeros((k, frames, 2))
    reach, dt = task.disc_radius + task.agent_radius, 1.0 / task.fps
    for i in range(k):
        policy, a, d = behaviour_policy(rng), np.array(agent, np.float64), np.array(disc, np.float64)
        for t in range(frames):
            if t % segment == 0:
                v = policy.act(Observation(a, d, task), rng)
            out[i, t] = v
            a = a + v * dt
            gap = d - a
            dist = float(np.hypot(*gap))
            if dist < reach:  # contact: the disc is pushed clear of the agent
                d = a + gap / max(dist, 1e-9) * reach
    return out


def plan_cost(task: GoalTask, final: np.ndarray, meta: dict, seen: np.ndarray) -> float:
    """Cost of a predicted final frame: the disc's distance to the goal plus a little for an agent far from it; a
    frame that lost the disc costs its last `seen` distance plus LOST_COST."""
    now = read_positions(final[None], meta)[0]
    if np.isnan(now[DISC - 1, 0]):
        return task.distance(seen[DISC - 1]) + LOST_COST
    agent, disc = np.where(np.isnan(now), seen, now)  # an agent not found keeps its last seen position
    gap = float(np.hypot(*(agent - disc))) - task.disc_radius - task.agent_radius
    return task.distance(disc) + APPROACH_WEIGHT * max(gap, 0.0)


def mpc(task: GoalTask, planner: Foresight | None, m: MPCConfig, seed: int) -> tuple[np.ndarray, dict]:
    """Model-predictive control acting in the true simulator: every `m.execute` frames, sample candidates, look
    `m.horizon` frames ahead under each with `planner` from the frames so far, and execute the first frames of the
    one whose final frame costs least (averaged over the planner's samples). `planner` None executes the first
    candidate, a random waypoint path, unscored. Returns the frames and the simulator's score."""
    first = task.simulate(np.zeros((0, 2)))
    ep, actions, best = first, np.zeros((0, 2)), None
    seen = first.states[0, :, :2].astype(np.float64)
    rng = np.random.default_rng(seed)
    scale = task.size[0] / 64.0
    shaped = min(int(round(m.proposals * m.candidates)), m.candidates - 1)  # the first stays random
    while len(actions) < task.frames - 1:
        h = min(m.horizon, task.frames - 1 - len(actions))
        seen = _readout(ep.frames, first.meta, seen)
        cands = np.concatenate([
            candidates(rng, m.candidates - shaped, h, m.segment, task.fps, m.speed * scale, seen[AGENT - 1],
                       seen[DISC - 1], m.spread * scale),
            proposals(rng, shaped, h, m.segment, task, seen[AGENT - 1], seen[DISC - 1])])
        if planner is not None and best is not None and len(best) > 0:  # warm start: the rest of the last plan
            cands[0] = np.concatenate([best, np.repeat(best[-1:], h, 0)])[:h]
        cands = np.stack([task.limit(np.concatenate([actions, c]))[len(actions):] for c in cands])
        if planner is not None:
            finals = planner(ep.frames, np.concatenate([np.repeat(actions[None], len(cands), 0), cands], 1), h,
                             _seed(seed, len(actions)))  # one seed for all: every candidate sees the same noise
            costs = [np.mean([plan_cost(task, f, first.meta, seen) for f in per_sample])
                     for per_sample in finals.swapaxes(0, 1)]
            choice = cands[int(np.argmin(costs))]
        else:
            choice = cands[0]
        n = min(m.execute, h)
        actions = np.concatenate([actions, choice[:n]])
        best = choice[n:]
        ep = task.simulate(actions)
    return ep.frames, task.outcome(ep)


class RolloutStage(Stage):
    """Runs rollout jobs (dicts: kind policy|mpc, name, world or planner, task index) on one world model."""

    def __init__(self, c: PolicyEvalConfig, size: tuple[int, int], fps: float, pipe=None):
        self.c, self.size, self.fps, self.pipe = c, size, fps, pipe
        self.resources = {"num_cpus": c.ray.num_cpus, "num_gpus": 1 if c.device.startswith("cuda") else 0}

    def setup(self) -> None:
        if self.pipe is None:  # a Ray worker: its own threads and its own copy of the model
            limit_threads(self.c.ray.num_cpus)
            torch.set_num_threads(max(1, int(self.c.ray.num_cpus)))
            from .physics import load_pipeline

            self.pipe = load_pipeline(self.c.checkpoint, self.c.device)

    def process(self, batch: list[dict]) -> list[dict]:
        return [self.run(job) for job in batch]

    def run(self, job: dict) -> dict:
        c, t0 = self.c, time.time()
        task = make_goal_task(job["task"], c.seed, frames=c.frames, size=self.size, fps=self.fps)
        if job["kind"] == "policy":
            policy = next(p for p in policy_family() if p.name == job["name"])
            world = (model_world(self.pipe, c.steps, c.sampler) if job["world"] == "world model"
                     else simulator_world(task))
            seed = _seed(c.seed, job["index"], task.index)  # the same in both worlds
            frames, actions, score = closed_loop(task, policy, world, c.chunk, seed)
            if job["world"] == "simulator":  # the simulator's own state, not the read-out, scores a true rollout
                score = {**task.outcome(task.simulate(actions)), "found": score["found"]}
        else:
            planner = {"world model": model_foresight(self.pipe, c.steps, c.sampler, c.mpc.samples),
                       "simulator": simulator_foresight(task), "random": None}[job["world"]]
            seed = _seed(c.seed, 7, task.index)  # the same candidates for every planner
            frames, score = mpc(task, planner, c.mpc, seed)
        return {**job, **score, "seed": seed, "seconds": round(time.time() - t0, 2),
                "frames": frames if job["keep"] else None}


def policy_config(cfg: DictConfig | dict) -> PolicyEvalConfig:
    """The checked config of `eval policy`: the `policy` node of configs/eval.yaml and the shared top-level keys."""
    node = OmegaConf.to_container(cfg, resolve=True) if isinstance(cfg, DictConfig) else dict(cfg)
    shared = {k: node[k] for k in ("checkpoint", "out", "seed", "device", "steps", "sampler") if k in node}
    return to_dataclass(PolicyEvalConfig, {**shared, **(node.get("policy") or {})}, "policy").check()


def rollout_jobs(c: PolicyEvalConfig) -> list[dict]:
    """Every rollout, the costliest (planning in the world model) first, so parallel workers finish together."""
    family = [p.name for p in policy_family()]
    jobs = [{"kind": "mpc", "name": f"MPC ({planner})", "world": planner, "index": -1, "task": t, "keep": t == 0}
            for planner in PLANNERS for t in range(c.mpc.tasks)]
    for world in reversed(WORLDS):
        jobs += [{"kind": "policy", "name": name, "world": world, "index": family.index(name), "task": t,
                  "keep": t == 0 and i >= len(c.policies) - c.videos}
                 for i, name in enumerate(c.policies) for t in range(c.tasks)]
    return jobs


def _mean(records: list[dict], key: str) -> float | None:
    return float(np.mean([r[key] for r in records])) if records else None


def summarise(records: list[dict], c: PolicyEvalConfig) -> dict:
    """Per-policy scores in both worlds, their Spearman rank correlation (of the mean final distance), and the MPC
    success rates with the share of the random-to-oracle gap the world-model planner closes."""
    def pick(kind: str, name: str, world: str) -> list[dict]:
        return [r for r in records if r["kind"] == kind and r["name"] == name and r["world"] == world]

    policies = [{"name": name, **{world: {k: _mean(pick("policy", name, world), k) for k in ("distance", "success",
                                                                                              "found")}
                                  for world in WORLDS}} for name in c.policies]
    sim, model = ([p[w]["distance"] for p in policies] for w in WORLDS)
    varied = len(policies) > 1 and np.ptp(sim) > 0 and np.ptp(model) > 0  # else the correlation is undefined
    rho = float(spearmanr(sim, model).statistic) if varied else float("nan")
    planners = {p: {k: _mean(pick("mpc", f"MPC ({p})", p), k) for k in ("distance", "success")} for p in PLANNERS}
    gap = {}
    if c.mpc.tasks:
        for key, sign in (("success", 1.0), ("distance", -1.0)):
            wm, oracle, rand = (sign * planners[p][key] for p in PLANNERS)
            gap[key] = (wm - rand) / (oracle - rand) if oracle > rand else None
    return {"spearman": None if np.isnan(rho) else rho, "policies": policies, "mpc": planners, "gap_closed": gap}


def run_policy_eval(cfg: DictConfig | dict) -> dict:
    """Run `eval policy` (configs/eval.yaml: shared keys and the `policy` node), write out/policy.json, policy.md,
    policy.html, plots and side-by-side videos; returns the results."""
    from .physics import load_pipeline
    from .policy_report import write_policy_report

    c = policy_config(cfg)
    pipe = load_pipeline(c.checkpoint, c.device)
    size, fps = pipe.size, float(pipe.cfg.data.fps)
    t0 = time.time()
    jobs = rollout_jobs(c)
    if c.runner == "ray":
        results = run_ray(RolloutStage(c, size, fps), jobs, c.workers, c.ray)
    else:
        results = run_local(RolloutStage(c, size, fps, pipe), jobs)
    records = list(progress(results, desc="policy rollouts", total=len(jobs)))
    order = {(j["kind"], j["name"], j["world"], j["task"]): i for i, j in enumerate(jobs)}
    records.sort(key=lambda r: order[r["kind"], r["name"], r["world"], r["task"]])  # Ray yields in completion order
    tasks = [make_goal_task(t, c.seed, frames=c.frames, size=size, fps=fps) for t in range(max(c.tasks, c.mpc.tasks))]
    results = {
        "checkpoint": str(Path(c.checkpoint).resolve()),
        "config": asdict(c),
        "tasks": [{**asdict(t), "start_distance": t.distance(t.simulate(np.zeros((0, 2))).states[0, DISC - 1, :2])}
                  for t in tasks],
        **summarise(records, c),
        "records": [{k: v for k, v in r.items() if k != "frames"} for r in records],
        "seconds": round(time.time() - t0, 1),
    }
    write_policy_report(results, records, tasks, Path(c.out), fps)
    log.info("eval policy: %d rollouts in %.0f s, Spearman %s -> %s", len(records), results["seconds"],
             results["spearman"], Path(c.out) / "policy.html")
    return results
