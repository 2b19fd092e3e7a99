"""Captions from templates: what the scenario is, its parameters in words, and what happened (from the states)."""

from __future__ import annotations

import math
import re

import numpy as np

from .render import Scene

NUMBERS = ["no", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine"]
TIMES = {1: "once", 2: "twice"}
DIRECTIONS = ["to the right", "up and to the right", "upward", "up and to the left", "to the left",
              "down and to the left", "downward", "down and to the right"]


def direction(dx: float, dy: float) -> str:
    """Screen direction in words of a displacement (y down)."""
    return DIRECTIONS[int(round(math.degrees(math.atan2(-dy, dx)) / 45.0)) % 8]


def bounces(vy: np.ndarray, threshold: float = 5.0) -> str:
    """"bounces twice" etc.: counts frames where a falling body (vy > 0) starts rising."""
    n = int(((vy[:-1] > threshold) & (vy[1:] < -threshold)).sum())
    return "does not bounce" if n == 0 else "bounces " + TIMES.get(n, f"{NUMBERS[n] if n < len(NUMBERS) else n} times")


def _pick(rng: np.random.Generator, templates: list[str], **words) -> str:
    text = templates[rng.integers(len(templates))].format(**words)
    return re.sub(r"\ba (?=[aeiou])", "an ", re.sub(" +", " ", text)).strip()


def caption(scenario: str, p: dict, scene: Scene, states: np.ndarray, rng: np.random.Generator) -> str:
    """A one-sentence description, e.g. "a red ball is thrown to the right and bounces twice"."""
    c = [b.color for b in scene.bodies]
    x, y, vx, vy = (states[..., k] for k in range(4))
    if scenario == "bounce":
        height = "a low height" if p["height"] < 24 else "high up" if p["height"] > 32 else "mid-air"
        drift = "" if abs(p["vx"]) < 4 else f", drifting {'right' if p['vx'] > 0 else 'left'},"
        return _pick(rng, ["a {c} ball falls from {h}{d} and {n}", "a {c} ball is dropped from {h}{d} and {n}"],
                     c=c[0], h=height, d=drift, n=bounces(vy[:, 0]))
    if scenario == "projectile":
        steep = "a steep" if p["angle"] > 50 else "a shallow" if p["angle"] < 40 else "a medium"
        side = "right" if vx[0, 0] > 0 else "left"
        return _pick(rng, ["a {c} ball is thrown to the {s} at {a} angle and {n}",
                           "a {c} ball flies to the {s} in an arc, launched at {a} angle, and {n}"],
                     c=c[0], s=side, a=steep, n=bounces(vy[:, 0]))
    if scenario == "collision":
        how = "elastically" if p["restitution"] >= 0.9 else "and nearly stick" if p["restitution"] <= 0.4 else ""
        ratio = p["radius2"] / p["radius1"]
        size = "larger " if ratio > 1.2 else "smaller " if ratio < 1 / 1.2 else ""
        other = "resting" if p["v2"] < 2 else "oncoming"
        return _pick(rng, ["a {c1} ball hits a {o} {s}{c2} ball head-on {h}", "a {c1} ball and a {o} {s}{c2} ball "
                           "collide head-on {h}"], c1=c[0], c2=c[1], o=other, s=size, h=how)
    if scenario == "uniform":
        pace = "slowly" if p["speed"] < 14 else "quickly" if p["speed"] > 21 else "steadily"
        kind = "box" if p["box"] else "ball"
        return _pick(rng, ["a {c} {k} moves {p} {d}", "a {c} {k} glides {p} {d} at constant speed"],
                     c=c[0], k=kind, p=pace, d=direction(vx[0, 0], vy[0, 0]))
    if scenario == "ramp":
        steep = "steep" if p["slope"] > 30 else "gentle" if p["slope"] < 24 else ""
        moved = math.hypot(x[-1, 0] - x[0, 0], y[-1, 0] - y[0, 0]) > 1.0
        if not moved:
            return _pick(rng, ["a {c} block rests on a {s} ramp without sliding"], c=c[0], s=steep)
        side = "right" if x[-1, 0] > x[0, 0] else "left"
        return _pick(rng, ["a {c} block slides down a {s} ramp to the {d}", "a {c} block slides {d} down a {s} ramp"],
                     c=c[0], s=steep, d=side)
    if scenario == "pendulum":
        length = "long" if p["length"] > 27 else "short" if p["length"] < 22 else ""
        side = "left" if x[0, 0] < scene.rods[0][0][0] else "right"
        swing = "wide" if p["angle"] > 25 else "gentle"
        return _pick(rng, ["a {c} pendulum bob on a {l} string swings from the {s}",
                           "a {l} pendulum with a {c} bob makes {w} swings, released from the {s}"],
                     c=c[0], l=length, s=side, w=swing)
    if scenario == "pusher":
        pushed = [(b, direction(x[-1, i] - x[0, i], y[-1, i] - y[0, i])) for i, b in enumerate(scene.bodies)
                  if i and math.hypot(x[-1, i] - x[0, i], y[-1, i] - y[0, i]) > 3.0]
        if not pushed:
            n = len(scene.bodies) - 1
            return f"a white agent moves around {NUMBERS[n]} object{'s' * (n > 1)} without pushing any"
        parts = [f"the {b.color} {b.name} {d}" for b, d in pushed]
        return "a white agent pushes " + (", ".join(parts[:-1]) + " and " if len(parts) > 1 else "") + parts[-1]
    raise ValueError(f"no captions for scenario {scenario!r}")
