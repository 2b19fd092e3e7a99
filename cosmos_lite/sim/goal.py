"""A goal-reaching task on the pusher scenario: push the disc into a goal region within a number of frames.

The task is a pusher episode with one object, a disc, and a goal circle that is not drawn (frames stay those the
world model was trained on); the agent is driven by the actions a policy chooses. Success and the continuous score
(the disc's final distance to the goal centre, in pixels) come from the simulator's state. Deterministic in
(index, seed, frames, size, fps).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .episode import Episode, simulate
from .scenarios import WALL, WORLD_H

AGENT, DISC = 1, 2  # palette / mask ids in a one-object pusher episode (0 is the background)
GOAL_TAG = 25  # mixed into every task seed, so no task shares a seed with a `cosmos-lite sim` episode
GOAL_RADIUS = 5.0  # world units: the disc's centre must end this close to the goal's
GOAL_DISTANCE = (12.0, 24.0)  # world units from the disc's start to the goal


@dataclass(frozen=True)
class GoalTask:
    """One task: the pusher seed, the goal (pixels of the rendered frame), and the rollout length and format."""

    index: int
    seed: int  # of the pusher episode the task runs in
    frames: int  # frames of a rollout, the first (given) one included
    fps: float
    size: tuple[int, int]
    goal: tuple[float, float]  # x, y in pixels
    goal_radius: float  # pixels
    disc_radius: float  # pixels
    agent_radius: float  # pixels
    agent_start: tuple[float, float]  # x, y in pixels

    def limit(self, actions: np.ndarray) -> np.ndarray:
        """`actions` (t, 2) with each step cut short where it would take the agent beyond the box's inner walls
        (its workspace), so the recorded actions are the ones the agent can carry out; actions inside it are returned
        unchanged."""
        a = np.array(actions, np.float64).reshape(-1, 2)
        scale = self.size[0] / WORLD_H
        lo = (WALL + 0.5) * scale + self.agent_radius
        hi = np.array([self.size[1], self.size[0]]) - lo
        pos = np.array(self.agent_start)
        for t in range(len(a)):
            nxt = np.clip(pos + a[t] / self.fps, lo, hi)
            a[t] = (nxt - pos) * self.fps
            pos = nxt
        return a

    def simulate(self, actions: np.ndarray) -> Episode:
        """The episode that `actions` (t, 2) (agent velocities, pixels/s, one per frame step; pass them through
        `limit` first) drive: t + 1 frames.

        At least two frames are simulated: the scenario draws its background after a random agent path that it only
        draws for two frames or more, so a lone first frame would differ in colour from the rollout it starts."""
        a = np.asarray(actions, np.float64).reshape(-1, 2)
        n = len(a) + 1
        ep = simulate("pusher", self.seed, frames=max(n, 2), fps=self.fps, size=self.size, objects=1,
                      actions=np.concatenate([a, np.zeros((2 - n, 2))]) if n < 2 else a)
        return replace(ep, frames=ep.frames[:n], masks=ep.masks[:n], states=ep.states[:n], actions=ep.actions[:n],
                       meta={**ep.meta, "frames": n})

    def distance(self, disc: np.ndarray) -> float:
        """The disc centre's distance (pixels) to the goal centre."""
        return float(np.hypot(*(np.asarray(disc, np.float64) - self.goal)))

    def succeeded(self, distance: float) -> bool:
        return bool(distance <= self.goal_radius)

    def outcome(self, episode: Episode) -> dict:
        """Score of a simulated rollout from the simulator's state: final `distance` (pixels) and `success`."""
        d = self.distance(episode.states[-1, DISC - 1, :2])
        return {"distance": d, "success": self.succeeded(d)}


def _place_goal(rng: np.random.Generator, first: Episode) -> np.ndarray | None:
    """A goal centre (world units) GOAL_DISTANCE from the disc, inside the box, with room behind the disc for the
    agent to push it there; None if 100 draws found none."""
    scale = first.meta["scale"]
    disc = first.states[0, DISC - 1, :2] / scale
    rd, ra = (first.meta["shapes"][k - 1]["size"][0] / scale for k in (DISC, AGENT))
    width = first.meta["size"][1] / scale
    for _ in range(100):
        angle, dist = rng.uniform(0, 2 * np.pi), rng.uniform(*GOAL_DISTANCE)
        u = np.array([np.cos(angle), np.sin(angle)])
        goal, behind = disc + u * dist, disc - u * (rd + ra + 1.0)
        lo_g, lo_a = WALL + rd + 2.0, WALL + ra + 1.0
        if (np.all(goal >= lo_g) and np.all(goal <= [width - lo_g, WORLD_H - lo_g])
                and np.all(behind >= lo_a) and np.all(behind <= [width - lo_a, WORLD_H - lo_a])):
            return goal
    return None


def make_goal_task(index: int, seed: int = 0, *, frames: int = 49, size: int | tuple[int, int] = 64,
                   fps: float = 16.0) -> GoalTask:
    """Task number `index` of the family `seed`: the first pusher seed drawn whose object is a disc with a reachable
    goal (about half of the seeds draw a box)."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, GOAL_TAG, index]))
    while True:
        pusher_seed = int(rng.integers(2**31))
        first = simulate("pusher", pusher_seed, frames=2, fps=fps, size=size, objects=1)
        if first.meta["shapes"][DISC - 1]["kind"] != "circle":
            continue
        goal = _place_goal(rng, first)
        if goal is not None:
            break
    scale, shapes = first.meta["scale"], first.meta["shapes"]
    gx, gy = (float(v) * scale for v in goal)
    ax, ay = (float(v) for v in first.states[0, AGENT - 1, :2])
    return GoalTask(index, pusher_seed, frames, float(fps), tuple(first.meta["size"]), (gx, gy), GOAL_RADIUS * scale,
                    shapes[DISC - 1]["size"][0], shapes[AGENT - 1]["size"][0], (ax, ay))
