"""Policies for the goal-reaching pusher task, and the state read-out they see the world through.

A policy never reads the simulator's state: it sees object centroids read out of frames by colour (the palette
segmentation of `metrics`), so it runs on generated frames exactly as on simulated ones. The scripted family spans
poor to good: standing still, random, straight lines that ignore the task's geometry, and a greedy pusher (get
behind the disc, then push it to the goal) at several speeds and noise levels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.metrics import centroids, segment_by_palette
from ..sim.goal import AGENT, DISC, GoalTask

CAREFUL_GAIN = 0.9  # 1/s: a careful push moves the disc at most this times its distance to the goal per second


def read_positions(frames: np.ndarray, meta: dict, ids: tuple[int, ...] = (AGENT, DISC)) -> np.ndarray:
    """Centroids (x, y) in pixels of the objects `ids` in uint8 frames (T, H, W, 3) -> (T, len(ids), 2), NaN where
    an object's colour is absent. `meta`: the episode's meta (palette and scenery colour)."""
    seg = segment_by_palette(frames, meta["palette"], background=[meta["scenery_color"]])
    return centroids(seg, list(ids))


@dataclass(frozen=True)
class Observation:
    """What a policy sees: the agent's and the disc's centroids read from the latest frame, and the task."""

    agent: np.ndarray  # (2,) pixels
    disc: np.ndarray  # (2,) pixels
    task: GoalTask

    @property
    def scale(self) -> float:
        """Pixels per world unit (policy speeds are in world units per second)."""
        return self.task.size[0] / 64.0


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.hypot(*v))
    return v / n if n > 1e-9 else np.zeros(2)


@dataclass(frozen=True)
class Scripted:
    """A scripted policy: `kind` still | random | to_goal (the agent walks to the goal, ignoring the disc) | at_disc
    (charges through the disc) | greedy (behind the disc, then push it to the goal); `speed` in world units/s;
    `noise`: std (radians) of a random turn of every action; `careful`: slow the push down near the goal, so the
    disc, which glides on after a push, stops there."""

    name: str
    kind: str
    speed: float = 40.0
    noise: float = 0.0
    careful: bool = False

    def act(self, obs: Observation, rng: np.random.Generator) -> np.ndarray:
        """The agent's velocity (pixels/s) for the next frames."""
        if self.kind == "still":
            return np.zeros(2)
        speed = self.speed * obs.scale
        if self.kind == "random":
            angle = rng.uniform(0, 2 * np.pi)
            return speed * np.array([np.cos(angle), np.sin(angle)])
        goal = np.asarray(obs.task.goal)
        pushing = False
        if self.kind == "greedy":
            direction, pushing = self._greedy(obs, goal)
        else:
            direction = goal - obs.agent if self.kind == "to_goal" else obs.disc - obs.agent
        if self.kind == "to_goal":
            speed = min(speed, float(np.hypot(*direction)) * 4)  # arrive and stay
        if pushing and self.careful:
            speed = min(speed, CAREFUL_GAIN * obs.task.distance(obs.disc))
        direction = _unit(direction)
        if self.noise:
            turn = rng.normal(0.0, self.noise)
            c, s = np.cos(turn), np.sin(turn)
            direction = np.array([c * direction[0] - s * direction[1], s * direction[0] + c * direction[1]])
        return speed * direction

    @staticmethod
    def _greedy(obs: Observation, goal: np.ndarray) -> tuple[np.ndarray, bool]:
        """The direction to move: around the disc to the point behind it (seen from the goal), then through it; and
        whether it pushes."""
        task, agent, disc = obs.task, obs.agent, obs.disc
        if task.distance(disc) <= 0.4 * task.goal_radius:
            return np.zeros(2), False
        u = _unit(goal - disc)
        reach = task.disc_radius + task.agent_radius
        rel = agent - disc
        along, lateral = float(rel @ u), float(rel[0] * u[1] - rel[1] * u[0])
        if along < -0.7 * reach and abs(lateral) < 0.4 * reach:  # behind and in line: push
            return _unit(disc - agent) + u, True
        if along < -0.3 * reach:  # behind but off the line: to the push point
            return disc - u * (reach + 1.0) - agent, False
        side = np.array([u[1], -u[0]]) * (1.0 if lateral >= 0 else -1.0)  # the agent's side of the line
        return disc + side * (reach + 2.0) - u * reach - agent, False  # go around, clear of the disc


def behaviour_policy(rng: np.random.Generator) -> Scripted:
    """A greedy pusher of random speed (15-60 world units/s), noise (none in a third, else up to 1 radian) and care:
    the behaviour that collects goal-pushing episodes for world-model training, around the family's good policies."""
    noise = 0.0 if rng.random() < 1 / 3 else float(rng.uniform(0.0, 1.0))
    return Scripted("behaviour", "greedy", speed=float(rng.uniform(15.0, 60.0)), noise=noise,
                    careful=bool(rng.random() < 0.5))


def policy_family() -> list[Scripted]:
    """The scripted policies `eval policy` ranks, roughly from poor to good."""
    return [
        Scripted("still", "still"),
        Scripted("random-slow", "random", speed=25.0),
        Scripted("random-fast", "random", speed=50.0),
        Scripted("walk-to-goal", "to_goal", speed=40.0),
        Scripted("charge-disc", "at_disc", speed=40.0),
        Scripted("careful-very-noisy", "greedy", speed=40.0, noise=1.5, careful=True),
        Scripted("careful-noisy", "greedy", speed=40.0, noise=0.8, careful=True),
        Scripted("careful-slightly-noisy", "greedy", speed=40.0, noise=0.3, careful=True),
        Scripted("greedy-slow", "greedy", speed=20.0),
        Scripted("greedy-fast", "greedy", speed=60.0),
        Scripted("greedy", "greedy", speed=40.0),
        Scripted("careful", "greedy", speed=40.0, careful=True),
    ]
