"""Physics scenarios on pymunk: each samples its parameters from an id or ood range, builds a space and a caption.

World units: the frame is 64 units tall (a 64x64 frame has 1 unit per pixel), x to the right, y down, gravity
+y. Every parameter has an in-distribution range and out-of-distribution intervals outside it (as in PhyWorld),
so a model trained on `id` episodes can be tested on velocities, sizes and angles it never saw.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pymunk

from ..config import number
from ..errors import ConfigError
from .render import AGENT_COLOR, COLORS, Body, Scene, box_corners

WORLD_H = 64.0
GROUND_Y = 60.0  # top of the ground slab
STATE_FIELDS = ["x", "y", "vx", "vy", "angle", "angular_velocity"]  # angle: radians, clockwise on screen
STATE_DIM = len(STATE_FIELDS)
WALL = 2.0  # wall thickness
APPROACH = (1.0, 6.0)  # the pusher's agent stops this far (world units) from touching an object before pushing it
PUSH_SPEED = (0.3, 1.0)  # a push runs at this share of the path's speed, drawn per push: gentle pushes and hard ones
AGENT_MASS, AGENT_FORCE = 1000.0, 5.0e6  # the pusher: a disc or box has mass 50-150 (its area), the agent 1000


@dataclass(frozen=True)
class Param:
    """A parameter's in-distribution range and its out-of-distribution intervals (outside that range)."""

    id: tuple[float, float]
    ood: tuple[tuple[float, float], ...]
    integer: bool = False

    def sample(self, rng: np.random.Generator, split: str) -> float:
        if split == "id":
            lo, hi = self.id
        else:
            widths = np.array([b - a + self.integer for a, b in self.ood], np.float64)
            lo, hi = self.ood[rng.choice(len(self.ood), p=widths / widths.sum())]
        if self.integer:
            return int(rng.integers(int(lo), int(hi) + 1))
        return float(rng.uniform(lo, hi))


GRAVITY = Param((180.0, 220.0), ((130.0, 160.0), (240.0, 280.0)))
RADIUS = Param((3.0, 5.0), ((2.0, 2.5), (5.5, 7.0)))

SPECS: dict[str, dict[str, Param]] = {
    "bounce": {
        "radius": RADIUS,
        "height": Param((20.0, 36.0), ((12.0, 16.0), (40.0, 44.0))),  # drop height of the ball's bottom
        "vx": Param((-12.0, 12.0), ((-24.0, -16.0), (16.0, 24.0))),
        "restitution": Param((0.5, 0.8), ((0.25, 0.4), (0.85, 0.95))),
        "gravity": GRAVITY,
    },
    "projectile": {
        "radius": RADIUS,
        "speed": Param((60.0, 95.0), ((40.0, 52.0), (100.0, 115.0))),
        "angle": Param((35.0, 60.0), ((20.0, 30.0), (65.0, 72.0))),  # degrees above horizontal
        "restitution": Param((0.3, 0.6), ((0.1, 0.2), (0.7, 0.85))),
        "gravity": GRAVITY,
    },
    "collision": {
        "radius1": RADIUS,
        "radius2": RADIUS,
        "v1": Param((25.0, 45.0), ((15.0, 20.0), (50.0, 65.0))),  # speed of the left ball, to the right
        "v2": Param((0.0, 25.0), ((30.0, 40.0),)),  # speed of the right ball, to the left
        "restitution": Param((0.6, 1.0), ((0.0, 0.4),)),
    },
    "uniform": {
        "extent": Param((3.0, 5.0), ((2.0, 2.5), (5.5, 7.0))),  # radius, or half the box side
        "speed": Param((10.0, 25.0), ((3.0, 6.0), (30.0, 40.0))),
        "direction": Param((0.0, 360.0), ((0.0, 360.0),)),  # degrees, counter-clockwise on screen
        "box": Param((0, 1), ((0, 1),), integer=True),
    },
    "ramp": {
        "slope": Param((20.0, 35.0), ((12.0, 16.0), (40.0, 45.0))),  # degrees
        "friction": Param((0.05, 0.3), ((0.35, 0.5),)),
        "extent": Param((3.0, 5.0), ((2.0, 2.5), (5.5, 6.5))),  # half the block's width
        "gravity": GRAVITY,
    },
    "pendulum": {
        "length": Param((18.0, 32.0), ((10.0, 14.0), (36.0, 42.0))),
        "angle": Param((10.0, 30.0), ((35.0, 55.0),)),  # initial angle from vertical, degrees
        "radius": RADIUS,
        "gravity": GRAVITY,
    },
    "pusher": {
        "objects": Param((1, 2), ((3, 3),), integer=True),
        "extent": Param((4.0, 6.0), ((2.5, 3.5), (6.5, 8.0))),  # half the box side or the disc radius
        "agent_speed": Param((25.0, 45.0), ((50.0, 65.0),)),  # mean speed of the generated agent path
        "damping": Param((0.2, 0.5), ((0.05, 0.1), (0.6, 0.8))),  # velocity fraction left after 1 s
    },
}


@dataclass
class Setup:
    """A built scenario: the pymunk space, the recorded bodies (in scene order) and the agent's actions."""

    space: pymunk.Space
    bodies: list[pymunk.Body]
    scene: Scene
    actions: np.ndarray | None = None  # (T, 2) world units/s commanded to the first body (the agent)
    driver: pymunk.Body | None = None  # the kinematic body the actions move; the agent follows it with bounded force


# Values a fixed or narrowed parameter may take at all (world units: the frame is 64 tall): outside them a scene
# is invisible or unphysical (a negative radius, restitution above 1). Unlisted parameters take any number.
PHYSICAL: dict[str, tuple[float, float]] = {
    **dict.fromkeys(("radius", "radius1", "radius2", "extent"), (0.5, 16.0)), "length": (1.0, 60.0),
    "height": (0.0, 60.0), "gravity": (0.0, 2000.0), "restitution": (0.0, 1.0), "friction": (0.0, 2.0),
    "damping": (0.0, 1.0), "objects": (1, 6), "box": (0, 1),
}


def sample_params(scenario: str, split: str, rng: np.random.Generator, overrides: dict) -> dict:
    """Draw every parameter of `scenario` from its split; an override is a fixed value or a [lo, hi] range."""
    spec = SPECS[scenario]
    unknown = sorted(set(overrides) - set(spec))
    if unknown:
        raise ConfigError(f"scenario {scenario!r} has no parameter(s) {', '.join(unknown)}; valid: {', '.join(spec)}")
    params = {}
    for name, p in spec.items():
        value = p.sample(rng, split)  # always drawn, so overriding one parameter leaves the others unchanged
        if name in overrides:
            v = overrides[name]
            lo, hi = PHYSICAL.get(name, (None, None))
            key = f"sim.params.{name}"
            if isinstance(v, list | tuple):
                lo_v, hi_v = (number(key, x, float, low=lo, high=hi) for x in v) if len(v) == 2 else (1, 0)
                if lo_v > hi_v:
                    raise ConfigError(f"{key}={list(v)} is not allowed; {key} takes a number or a range [lo, hi] "
                                      "with lo <= hi")
                value = Param((lo_v, hi_v), ()).sample(rng, "id")
            else:
                value = number(key, v, float, low=lo, high=hi)
            value = int(round(value)) if p.integer else float(value)
        params[name] = value
    return params


def _space(gravity: float = 0.0, damping: float = 1.0) -> pymunk.Space:
    space = pymunk.Space()
    space.gravity = (0.0, gravity)
    space.damping = damping
    return space


def _ball(space: pymunk.Space, x: float, y: float, r: float, elasticity: float, friction: float = 0.5) -> pymunk.Body:
    body = pymunk.Body(math.pi * r * r, pymunk.moment_for_circle(math.pi * r * r, 0, r))
    body.position = (x, y)
    shape = pymunk.Circle(body, r)
    shape.elasticity, shape.friction = elasticity, friction
    space.add(body, shape)
    return body


def _box(space: pymunk.Space, x: float, y: float, w: float, h: float, friction: float, angle: float = 0.0):
    body = pymunk.Body(w * h, pymunk.moment_for_box(w * h, (w, h)))
    body.position, body.angle = (x, y), angle
    shape = pymunk.Poly.create_box(body, (w, h))
    shape.elasticity, shape.friction = 0.0, friction
    space.add(body, shape)
    return body


def _ground(space: pymunk.Space, width: float, elasticity: float = 1.0, friction: float = 1.0) -> list[np.ndarray]:
    """A static slab below GROUND_Y and walls at both sides (so nothing leaves the frame); their polygons."""
    polys = _walls(space, [(-width, GROUND_Y + 1), (2 * width, GROUND_Y + 1)], elasticity, friction)
    polys[0][2:, 1] = WORLD_H  # draw the slab down to the bottom of the frame
    sides = [[(WALL / 2, -WORLD_H), (WALL / 2, GROUND_Y)], [(width - WALL / 2, -WORLD_H), (width - WALL / 2, GROUND_Y)]]
    return polys + _walls(space, [p for side in sides for p in side], elasticity, friction)


def _walls(space: pymunk.Space, points: list, elasticity: float, friction: float) -> list[np.ndarray]:
    """Static segments between consecutive point pairs, WALL thick; returns their rectangles, clipped to view."""
    polys = []
    for a, b in zip(points[::2], points[1::2]):
        seg = pymunk.Segment(space.static_body, a, b, WALL / 2)
        seg.elasticity, seg.friction = elasticity, friction
        space.add(seg)
        (x0, y0), (x1, y1) = np.minimum(a, b) - WALL / 2, np.maximum(a, b) + WALL / 2
        x0, y0 = max(x0, 0.0), max(y0, 0.0)
        polys.append(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], np.float64))
    return polys


def _colors(rng: np.random.Generator, n: int) -> list[tuple[str, tuple[int, int, int]]]:
    names = rng.choice(list(COLORS), size=n, replace=False)
    return [(str(c), COLORS[c]) for c in names]


def build_bounce(p: dict, rng: np.random.Generator, width: float, frames: int, fps: float) -> Setup:
    space = _space(p["gravity"])
    r = p["radius"]
    x = rng.uniform(0.3, 0.7) * width
    ball = _ball(space, x, GROUND_Y - p["height"] - r, r, p["restitution"])
    ball.velocity = (p["vx"], 0.0)
    (color, rgb), = _colors(rng, 1)
    return Setup(space, [ball], Scene([Body("ball", "circle", (r,), color, rgb)], _ground(space, width)))


def build_projectile(p: dict, rng: np.random.Generator, width: float, frames: int, fps: float) -> Setup:
    space = _space(p["gravity"])
    r, a = p["radius"], math.radians(p["angle"])
    direction = 1.0 if rng.random() < 0.5 else -1.0
    x = WALL + r + 1 if direction > 0 else width - WALL - r - 1
    ball = _ball(space, x, GROUND_Y - r - rng.uniform(0.0, 8.0), r, p["restitution"])
    ball.velocity = (direction * p["speed"] * math.cos(a), -p["speed"] * math.sin(a))
    (color, rgb), = _colors(rng, 1)
    return Setup(space, [ball], Scene([Body("ball", "circle", (r,), color, rgb)], _ground(space, width)))


def build_collision(p: dict, rng: np.random.Generator, width: float, frames: int, fps: float) -> Setup:
    space = _space()
    r1, r2 = p["radius1"], p["radius2"]
    y = WORLD_H / 2 + rng.uniform(-8.0, 8.0)
    a = _ball(space, rng.uniform(r1 + 2, 0.3 * width), y, r1, p["restitution"], friction=0.0)
    b = _ball(space, rng.uniform(0.7 * width, width - r2 - 2), y, r2, p["restitution"], friction=0.0)
    a.velocity, b.velocity = (p["v1"], 0.0), (-p["v2"], 0.0)
    (c1, rgb1), (c2, rgb2) = _colors(rng, 2)
    bodies = [Body("left ball", "circle", (r1,), c1, rgb1), Body("right ball", "circle", (r2,), c2, rgb2)]
    return Setup(space, [a, b], Scene(bodies))


def build_uniform(p: dict, rng: np.random.Generator, width: float, frames: int, fps: float) -> Setup:
    space = _space()
    s, d = p["extent"], math.radians(p["direction"])
    v = np.array([math.cos(d), -math.sin(d)]) * p["speed"]  # counter-clockwise on screen (y down)
    centre = np.array([width / 2, WORLD_H / 2]) + rng.uniform(-6.0, 6.0, 2)
    start = centre - v * (frames - 1) / fps / 2  # mid-episode at the centre, so it stays in view
    if p["box"]:
        body = _box(space, *start, 2 * s, 2 * s, friction=0.0, angle=rng.uniform(0, math.pi / 2))
        shape = Body("box", "box", (2 * s, 2 * s), *_colors(rng, 1)[0])
    else:
        body = _ball(space, *start, s, 1.0)
        shape = Body("ball", "circle", (s,), *_colors(rng, 1)[0])
    body.velocity = tuple(v)
    return Setup(space, [body], Scene([shape]))


def build_ramp(p: dict, rng: np.random.Generator, width: float, frames: int, fps: float) -> Setup:
    space = _space(p["gravity"])
    theta = math.radians(p["slope"])
    run = 0.6 * width
    rise = min(run * math.tan(theta), 0.75 * GROUND_Y)
    run = rise / math.tan(theta)
    x0 = rng.uniform(WALL, width - run - WALL)
    top, bottom = np.array([x0, GROUND_Y - rise]), np.array([x0 + run, GROUND_Y])
    if rng.random() < 0.5:  # mirror: slope down to the left
        top[0], bottom[0] = width - top[0], width - bottom[0]
    slope = pymunk.Segment(space.static_body, tuple(top), tuple(bottom), 0.0)
    slope.friction = 1.0  # pymunk multiplies the two frictions: the block's friction is the coefficient
    space.add(slope)
    w, h = 2 * p["extent"], 1.4 * p["extent"]
    along = (bottom - top) / np.hypot(*(bottom - top))
    normal = np.array([along[1], -along[0]]) * (1.0 if along[0] > 0 else -1.0)  # the upward side
    centre = top + along * (w / 2 + 2.0) + normal * (h / 2 + 0.05)
    angle = math.atan2(along[1], along[0])
    if abs(angle) > math.pi / 2:
        angle -= math.copysign(math.pi, angle)
    block = _box(space, *centre, w, h, friction=p["friction"], angle=angle)
    (color, rgb), = _colors(rng, 1)
    triangle = np.array([top, bottom, [top[0], GROUND_Y]], np.float64)
    scenery = _ground(space, width, elasticity=0.0) + [triangle]
    return Setup(space, [block], Scene([Body("block", "box", (w, h), color, rgb)], scenery))


def build_pendulum(p: dict, rng: np.random.Generator, width: float, frames: int, fps: float) -> Setup:
    space = _space(p["gravity"])
    length, a, r = p["length"], math.radians(p["angle"]), p["radius"]
    pivot = (width / 2 + rng.uniform(-6.0, 6.0), 6.0)
    side = 1.0 if rng.random() < 0.5 else -1.0
    bob = pymunk.Body(math.pi * r * r, math.inf)  # no rotational inertia: a simple (point-mass) pendulum
    bob.position = (pivot[0] + side * length * math.sin(a), pivot[1] + length * math.cos(a))
    space.add(bob, pymunk.Circle(bob, r), pymunk.PinJoint(space.static_body, bob, pivot, (0, 0)))
    (color, rgb), = _colors(rng, 1)
    hub = box_corners(pivot[0], pivot[1], 0.0, 3.0, 3.0)
    return Setup(space, [bob], Scene([Body("bob", "circle", (r,), color, rgb)], [hub], [(pivot, 0, 0.8)]))


def pusher_actions(rng: np.random.Generator, start: np.ndarray, goals: list[np.ndarray], frames: int, fps: float,
                   speed: float, width: float, radius: float, reach: float) -> np.ndarray:
    """A smooth random agent path as per-frame velocities (T, 2): for each goal, first to a stop beside it on a
    random side (APPROACH world units beyond `reach`, the farthest distance at which the agent touches it), then
    through it from there (overshooting it) at a PUSH_SPEED share of `speed`, so objects are pushed from every side,
    gently and hard, and the agent also comes close without touching."""
    if frames < 2:
        return np.zeros((frames, 2))
    pts, speeds = [start], []
    for g in goals:
        angle = rng.uniform(0.0, 2 * np.pi)
        side = np.array([np.cos(angle), np.sin(angle)])  # from the goal to the stop; the push runs the other way
        pts += [g + side * (reach + rng.uniform(*APPROACH)), g - side * rng.uniform(6.0, 12.0)]
        speeds += [speed, speed * rng.uniform(*PUSH_SPEED)]
    speeds.append(speed)
    lo, hi = WALL + radius + 1, [width - WALL - radius - 1, WORLD_H - WALL - radius - 1]
    pts.append(rng.uniform(lo, hi))
    pts = [np.clip(q, lo, hi) for q in pts]
    lengths = np.array([np.hypot(*(b - a)) for a, b in zip(pts[:-1], pts[1:])])
    duration = (frames - 1) / fps
    times = np.concatenate([[0.0], np.cumsum(np.maximum(lengths / np.array(speeds), 0.3))])
    times *= duration / times[-1] if times[-1] > duration else 1.0
    t = np.arange(frames) / fps
    k = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(lengths) - 1)
    u = np.clip((t - times[k]) / (times[k + 1] - times[k]), 0.0, 1.0)
    ease = (1 - np.cos(np.pi * u)) / 2  # zero velocity at every waypoint: smooth turns
    path = np.array(pts)[k] + (np.array(pts)[k + 1] - np.array(pts)[k]) * ease[:, None]
    actions = np.zeros((frames, 2))
    actions[:-1] = np.diff(path, axis=0) * fps
    return actions


def build_pusher(p: dict, rng: np.random.Generator, width: float, frames: int, fps: float) -> Setup:
    space = _space(damping=p["damping"])
    lo, hi = WALL / 2, (width - WALL / 2, WORLD_H - WALL / 2)  # a closed box around the frame
    corners = [(lo, lo), (hi[0], lo), (hi[0], hi[1]), (lo, hi[1])]
    walls = _walls(space, [p for k in range(4) for p in (corners[k], corners[(k + 1) % 4])], 0.3, 0.5)
    ra = 3.5
    # The agent is a heavy body that tracks the commanded velocity with a bounded force (pymunk's control-body
    # pattern), not a kinematic one: a kinematic agent has unbounded force, and an object it pressed against a
    # wall was shot out at 20-50 px a frame (a quarter of the episodes) by the solver's overlap correction.
    agent = pymunk.Body(AGENT_MASS, float("inf"))
    agent_shape = pymunk.Circle(agent, ra)
    agent_shape.friction, agent_shape.elasticity = 0.5, 0.0
    driver = pymunk.Body(body_type=pymunk.Body.KINEMATIC)
    grip = pymunk.PivotJoint(driver, agent, (0, 0), (0, 0))
    grip.max_bias, grip.max_force = 0.0, AGENT_FORCE  # velocity tracking only, bounded force
    space.add(agent, agent_shape, driver, grip)
    s = p["extent"]
    placed: list[np.ndarray] = []
    bodies, shapes = [agent], [Body("agent", "circle", (ra,), *AGENT_COLOR)]
    colors = _colors(rng, p["objects"])
    for i in range(p["objects"] + 1):
        margin = WALL + (ra + 1 if i == 0 else 1.5 * s + 2)
        for _ in range(100):  # rejection-sample a free spot
            q = rng.uniform(margin, [width - margin, WORLD_H - margin])
            if all(np.hypot(*(q - o)) > 1.5 * s + ra + 6 for o in placed):
                break
        placed.append(q)
        if i == 0:
            agent.position = driver.position = tuple(q)
            continue
        if rng.random() < 0.5:
            body = _box(space, *q, 2 * s, 2 * s, friction=0.5, angle=rng.uniform(0, math.pi / 2))
            shapes.append(Body("box", "box", (2 * s, 2 * s), *colors[i - 1]))
        else:
            body = _ball(space, *q, s, 0.3)
            shapes.append(Body("disc", "circle", (s,), *colors[i - 1]))
        bodies.append(body)
    order = rng.permutation(p["objects"]) + 1
    reach = ra + s * math.sqrt(2)  # the farthest the agent's centre can be from an object's and touch it (a box corner)
    actions = pusher_actions(rng, placed[0], [placed[i] for i in order], frames, fps, p["agent_speed"], width, ra,
                             reach)
    return Setup(space, bodies, Scene(shapes, walls), actions, driver)


BUILDERS: dict[str, Callable[..., Setup]] = {
    "bounce": build_bounce,
    "projectile": build_projectile,
    "collision": build_collision,
    "uniform": build_uniform,
    "ramp": build_ramp,
    "pendulum": build_pendulum,
    "pusher": build_pusher,
}
SCENARIOS = tuple(BUILDERS)


def step(setup: Setup, frames: int, fps: float, substeps: int) -> np.ndarray:
    """Run the space for `frames` frames of `substeps` steps; returns world-unit states (T, n, STATE_DIM).

    Velocities start half a step ahead (leapfrog): with pymunk's position-then-velocity update, positions
    under constant acceleration then match the closed form exactly at every step; recorded velocities are
    shifted back to the frame time.
    """
    dt = 1.0 / (fps * substeps)
    half = np.array(setup.space.gravity) * dt / 2
    dynamic = [b.body_type == pymunk.Body.DYNAMIC for b in setup.bodies]
    states = np.empty((frames, len(setup.bodies), STATE_DIM), np.float64)

    def record(t: int, shift: np.ndarray) -> None:
        for i, b in enumerate(setup.bodies):
            v = np.array(b.velocity) - (shift if dynamic[i] else 0.0)
            states[t, i] = (*b.position, *v, b.angle, b.angular_velocity)

    record(0, 0.0 * half)
    for i, b in enumerate(setup.bodies):
        if dynamic[i]:
            b.velocity = tuple(np.array(b.velocity) + half)
    for t in range(1, frames):
        if setup.actions is not None:
            setup.driver.velocity = tuple(setup.actions[t - 1])
        for _ in range(substeps):
            setup.space.step(dt)
        record(t, half)
    return states
