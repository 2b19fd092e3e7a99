"""Simulator: determinism, physics against closed form, actions, masks vs pixels, captions, splits, I/O, CLI."""

from __future__ import annotations

import inspect
import json
import math
import multiprocessing as mp
import subprocess
import sys

import numpy as np
import pytest

from cosmos_lite.cli import main
from cosmos_lite.errors import ConfigError, InputError
from cosmos_lite.sim import SCENARIOS, SPECS, read_episode, simulate, write_episode
from cosmos_lite.sim.render import SCENERY_COLOR, box_corners, fill_discs, fill_polygons
from cosmos_lite.sim.scenarios import APPROACH, GROUND_Y, pusher_actions


def _digest(scenario: str, seed: int) -> tuple[bytes, bytes, bytes]:
    ep = simulate(scenario, seed)
    return ep.frames.tobytes(), ep.masks.tobytes(), ep.states.tobytes()


def test_same_seed_identical_across_processes_different_seeds_differ():
    jobs = [("pusher", 7), ("bounce", 7), ("ramp", 3)]
    with mp.get_context("spawn").Pool(2) as pool:
        remote = pool.starmap(_digest, jobs)
    assert remote == [_digest(*j) for j in jobs]
    for scenario in SCENARIOS:
        a, b = simulate(scenario, 1), simulate(scenario, 2)
        assert not np.array_equal(a.frames, b.frames) and not np.array_equal(a.states, b.states)


@pytest.mark.parametrize("size", [64, 128])
def test_free_fall_matches_half_g_t_squared(size):
    ep = simulate("bounce", 0, size=size, vx=0.0, height=36.0, radius=4.0, gravity=200.0)
    scale, fps = ep.meta["scale"], ep.meta["fps"]
    y, vy = ep.states[:, 0, 1], ep.states[:, 0, 3]
    before = np.arange(np.argmax(np.diff(vy) < 0) + 1)  # frames before the first contact slows the ball
    assert len(before) > 8 and y[before[-1]] + 4.0 * scale > (GROUND_Y - 8) * scale  # falls to the ground
    t = before[1:] / fps
    expected = 0.5 * 200.0 * scale * t**2
    np.testing.assert_allclose(y[before[1:]] - y[0], expected, rtol=0.01)
    np.testing.assert_allclose(ep.states[before[1:], 0, 3], 200.0 * scale * t, rtol=0.01)  # vy = g t


def test_projectile_follows_the_parabola_until_it_lands():
    ep = simulate("projectile", 3, speed=80.0, angle=50.0, gravity=200.0)
    x, y, vx, vy = (ep.states[:, 0, k].astype(np.float64) for k in range(4))
    free = np.arange(np.argmax(np.abs(np.diff(vy) - 200.0 / 16) > 1e-3) + 1)  # until the first contact
    assert len(free) > 8
    t = free / ep.meta["fps"]
    np.testing.assert_allclose(x[free], x[0] + vx[0] * t, rtol=0.01)
    np.testing.assert_allclose(y[free] - y[0], vy[0] * t + 100.0 * t**2, atol=0.01 * np.abs(y[free] - y[0]).max())


@pytest.mark.parametrize("slope,friction", [(30.0, 0.1), (25.0, 0.3)])
def test_ramp_block_accelerates_as_g_sin_minus_mu_cos(slope, friction):
    ep = simulate("ramp", 0, slope=slope, friction=friction, gravity=200.0)
    x, y = ep.states[:, 0, 0], ep.states[:, 0, 1]
    on_slope = np.nonzero(np.abs(np.degrees(np.abs(ep.states[:, 0, 4])) - slope) < 1)[0][-1]
    k = np.arange(4, min(on_slope, 12))  # after settling onto the slope, before reaching its foot
    t = k / ep.meta["fps"]
    a = 200.0 * (math.sin(math.radians(slope)) - friction * math.cos(math.radians(slope)))
    np.testing.assert_allclose(np.hypot(x[k] - x[0], y[k] - y[0]), 0.5 * a * t**2, rtol=0.03)
    rest = simulate("ramp", 0, slope=20.0, friction=0.45)  # friction above tan(slope): it stays
    assert np.abs(rest.states[:, 0, :2] - rest.states[0, 0, :2]).max() < 0.5 and "rests" in rest.meta["caption"]


def test_elastic_collision_conserves_momentum():
    ep = simulate("collision", 4, restitution=1.0, radius1=3.0, radius2=5.0, v1=40.0, v2=10.0)
    m = np.array([3.0, 5.0]) ** 2  # equal density discs: mass ~ r^2
    vx = ep.states[:, :, 2].astype(np.float64)
    p = vx @ m
    assert vx[-1, 0] < 0 < vx[0, 0]  # the light ball really bounced back
    np.testing.assert_allclose(p, p[0], rtol=0.01)
    ke = (vx**2) @ m
    np.testing.assert_allclose(ke[-1], ke[0], rtol=0.01)
    assert "elastically" in ep.meta["caption"]


def test_pendulum_small_angle_period():
    length, g = 30.0, 200.0
    ep = simulate("pendulum", 2, angle=4.0, length=length, gravity=g, frames=1 + 8 * 16, fps=16.0)
    x = ep.states[:, 0, 0].astype(np.float64)
    x = x - x.mean()
    k = np.nonzero((x[:-1] < 0) & (x[1:] >= 0))[0]
    crossings = (k + x[k] / (x[k] - x[k + 1])) / ep.meta["fps"]  # upward zero crossings, interpolated
    assert len(crossings) >= 3
    period = np.diff(crossings).mean()
    assert period == pytest.approx(2 * math.pi * math.sqrt(length / g), rel=0.02)


def test_pusher_actions_change_outcome():
    still = simulate("pusher", 11, objects=1, actions=np.zeros((33, 2)))
    np.testing.assert_allclose(still.states[-1, 1, :2], still.states[0, 1, :2], atol=1e-4)
    agent, obj = still.states[0, 0, :2], still.states[0, 1, :2]
    d = obj - agent
    push = np.tile(d / np.linalg.norm(d) * (np.linalg.norm(d) + 15.0) / 1.5, (32, 1))  # reach it within 1.5 s
    pushed = simulate("pusher", 11, objects=1, actions=push)
    np.testing.assert_array_equal(pushed.states[0], still.states[0])  # same seed: same initial scene
    assert np.linalg.norm(pushed.states[-1, 1, :2] - still.states[-1, 1, :2]) > 3.0
    assert np.allclose(pushed.actions[:32], push) and not pushed.actions[-1].any()
    free = simulate("pusher", 11, objects=1)  # generated actions: smooth and non-zero
    assert np.abs(free.actions).max() > 5 and np.abs(np.diff(free.actions[:-1], axis=0)).max() < 40
    with pytest.raises(ConfigError):
        simulate("bounce", 0, actions=np.zeros((33, 2)))


def test_pusher_path_stops_clear_of_each_object_then_pushes_through_it():
    """The generated agent path shows the world model an agent that comes close without touching (the disc must not
    move yet), then pushes from that side: before passing through each goal it stops APPROACH clear of touching."""
    start, goals, reach, fps = np.array([10.0, 50.0]), [np.array([30.0, 30.0]), np.array([45.0, 20.0])], 12.0, 16.0
    for seed in range(5):
        a = pusher_actions(np.random.default_rng(seed), start, goals, 96, fps, 30.0, 64.0, 3.5, reach)
        path = start + np.concatenate([[[0.0, 0.0]], np.cumsum(a[:-1], axis=0) / fps])
        speed = np.hypot(*a.T)
        for g in goals:
            d = np.hypot(*(path - g).T)
            through = int(np.argmax(d < 2.5))  # frames ~2 units apart at the push's top speed
            assert d[through] < 2.5
            stop = [t for t in range(1, through) if speed[t] <= speed[t - 1] and speed[t] <= speed[t + 1]
                    and reach + APPROACH[0] - 0.5 < d[t] < reach + APPROACH[1] + 0.5]
            assert stop, (seed, g)


def test_pusher_agent_has_bounded_force_and_follows_its_actions():
    """An object the agent presses against a wall stays there: nothing moves much faster than the agent (a kinematic
    agent with unbounded force had the solver shoot squeezed objects out at 20-50 px a frame); away from contacts the
    agent moves as its actions say."""
    fastest, lag = [], []
    for seed in range(40):
        ep = simulate("pusher", seed)
        step = np.hypot(*np.diff(ep.states[:, :, :2], axis=0).transpose(2, 0, 1))  # px per frame, (T-1, n)
        fastest.append(step[:, 1:].max() / max(step[:, 0].max(), 1e-6))
        lag.append(np.median(np.abs(step[:, 0] - np.hypot(*ep.actions[:-1].T) / ep.meta["fps"])))
    assert max(fastest) < 2.5, max(fastest)
    assert np.median(lag) < 0.12, np.median(lag)  # 0.11: the agent starts each push from a stop beside the object

    # pushed into the right wall and held there: the agent stops at the object, the object at the wall
    ep = simulate("pusher", 11, objects=1, actions=np.tile([200.0 / 1.5, 0.0], (32, 1)))
    assert np.hypot(*np.diff(ep.states[:, :, :2], axis=0).transpose(2, 0, 1)).max() < 200.0 / 1.5 / 16 * 2.5
    assert ep.states[-1, 0, 0] < 64 and abs(ep.states[-1, 0, 1] - ep.states[0, 0, 1]) < 8.0


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_masks_agree_with_pixels(scenario):
    ep = simulate(scenario, 5)
    pal = np.array([ep.meta["palette"][i] for i in range(len(ep.meta["palette"]))], np.uint8)
    assert ep.masks.max() == len(ep.meta["objects"]) and (np.bincount(ep.masks.ravel()) > 0).all()
    recoloured = pal[ep.masks]
    on = ep.masks > 0
    np.testing.assert_array_equal(ep.frames[on], recoloured[on])
    bg = ep.frames[~on]
    assert ((bg == pal[0]).all(-1) | (bg == SCENERY_COLOR).all(-1)).all()
    colours = pal.astype(int)
    assert all(np.abs(a - b).sum() > 60 for i, a in enumerate(colours) for b in colours[i + 1:])  # flat, distinct


def test_textured_background_and_mp4_roundtrip_masks_by_colour(tmp_path):
    ep = simulate("pusher", 3, background="textured", objects=2)
    path = write_episode(ep, tmp_path, "ep")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ep.json", "ep.mp4", "ep.npz"]  # no temp files left
    back = read_episode(path)
    assert back.meta == json.loads(json.dumps(ep.meta)) | {"palette": ep.meta["palette"]}
    np.testing.assert_array_equal(back.masks, ep.masks)
    np.testing.assert_array_equal(back.states, ep.states)
    # Recover object masks from decoded colours by the nearest palette entry (background/scenery -> 0).
    pal = np.array([ep.meta["palette"][i] for i in range(1, len(ep.meta["palette"]))], float)
    dist = np.linalg.norm(back.frames[..., None, :].astype(float) - pal, axis=-1)
    guess = np.where(dist.min(-1) < 60, dist.argmin(-1) + 1, 0)
    assert (guess == ep.masks).mean() > 0.99
    assert read_episode(tmp_path / "ep").frames.shape == ep.frames.shape
    with pytest.raises(InputError, match="missing.npz|missing.json"):
        read_episode(tmp_path / "missing")


def test_odd_and_non_square_sizes_and_lengths(tmp_path):
    for frames in (1, 17, 1 + 8 * 4):
        ep = simulate("uniform", 0, frames=frames, size=(48, 80))
        assert ep.frames.shape == (frames, 48, 80, 3) and ep.masks.shape == (frames, 48, 80)
        assert ep.actions.shape == (frames, 2) and ep.states.shape == (frames, 1, 6)
    ep = simulate("bounce", 1, size=(33, 47))
    assert read_episode(write_episode(ep, tmp_path, "odd")).frames.shape == (33, 33, 47, 3)


def test_captions_from_templates_describe_the_episode():
    for scenario in SCENARIOS:
        ep = simulate(scenario, 9)
        cap = ep.meta["caption"]
        assert cap and "{" not in cap and "  " not in cap
        first = ep.meta["shapes"][1 if scenario == "pusher" else 0]["color"]
        assert first in cap or "without" in cap
    thrown = simulate("projectile", 0, angle=60.0, restitution=0.1)
    side = "right" if thrown.states[0, 0, 2] > 0 else "left"
    assert f"thrown to the {side}" in thrown.meta["caption"] or f"to the {side} in an arc" in thrown.meta["caption"]
    assert "steep" in thrown.meta["caption"]
    assert simulate("bounce", 0, frames=5).meta["caption"].endswith("does not bounce")  # still falling
    bouncy = simulate("bounce", 0, restitution=0.8, height=36.0, vx=0.0, frames=1 + 4 * 12)
    y = bouncy.states[:, 0, 1] + bouncy.meta["shapes"][0]["size"][0]  # the ball's bottom
    lows = [t for t in range(1, len(y) - 1) if y[t - 1] <= y[t] > y[t + 1] and y[t] > GROUND_Y - 8]
    words = {2: "twice", 3: "three times", 4: "four times", 5: "five times", 6: "six times"}
    assert len(lows) >= 2 and bouncy.meta["caption"].endswith("bounces " + words[len(lows)])


def test_id_and_ood_splits_sample_disjoint_ranges():
    for scenario, spec in SPECS.items():
        for seed in range(6):
            for split in ("id", "ood"):
                params = simulate(scenario, seed, split=split, frames=1).meta["params"]
                for name, p in spec.items():
                    lo, hi, v = *p.id, params[name]
                    if split == "id":
                        assert lo <= v <= hi, (scenario, name, v)
                    elif p.ood != (p.id,):  # e.g. direction: the same range in both splits
                        assert not lo < v < hi and any(a <= v <= b for a, b in p.ood), (scenario, name, v)


def test_param_overrides_and_errors():
    keywords = set(inspect.signature(simulate).parameters)
    assert not [name for spec in SPECS.values() for name in spec if name in keywords]  # no shadowed parameter
    ep = simulate("bounce", 0, radius=[6.0, 6.5], restitution=0.7)
    assert 6.0 <= ep.meta["params"]["radius"] <= 6.5 and ep.meta["params"]["restitution"] == 0.7
    with pytest.raises(ConfigError, match="radius"):
        simulate("bounce", 0, radus=3)
    with pytest.raises(ConfigError, match="unknown scenario"):
        simulate("juggle", 0)
    with pytest.raises(ConfigError):
        simulate("bounce", 0, split="test")


def cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cosmos_lite.cli", "sim", *args], capture_output=True, text=True)


def test_cli_parallel_output_matches_serial(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    r = cli(f"out={a}", "sim.episodes=4", "seed=3", "workers=2", "sim.frames=9")
    assert r.returncode == 0, r.stderr
    assert cli(f"out={b}", "sim.episodes=4", "seed=3", "sim.frames=9").returncode == 0
    index = json.loads((a / "index.json").read_text())
    assert [e["name"] for e in index["episodes"]] == ["bounce_000000", "projectile_000001", "collision_000002",
                                                      "uniform_000003"]
    for e in index["episodes"]:
        for ext in (".mp4", ".npz", ".json"):
            assert (a / (e["name"] + ext)).read_bytes() == (b / (e["name"] + ext)).read_bytes()
    assert json.loads((b / "index.json").read_text()) == index
    before = {p.name: p.stat().st_mtime_ns for p in a.iterdir()}
    assert cli(f"out={a}", "sim.episodes=5", "seed=3", "sim.frames=9").returncode == 0  # resumes: adds one
    after = {p.name: p.stat().st_mtime_ns for p in a.iterdir()}
    assert {k for k in after if before.get(k) != after[k]} == {"index.json", "ramp_000004.mp4", "ramp_000004.npz",
                                                               "ramp_000004.json"}


def test_cli_lists_parameter_ranges(capsys):
    assert main(["sim", "ranges"]) == 0
    ranges = json.loads(capsys.readouterr().out)
    assert set(ranges) == set(SCENARIOS) and ranges["pendulum"]["length"]["id"] == list(SPECS["pendulum"]["length"].id)


def test_cli_bad_arguments_exit_2(tmp_path, capsys):
    assert main(["sim", "sim.episodes=1"]) == 2  # no out=
    assert main(["sim", f"out={tmp_path}", "sim.scenario=juggle"]) == 2
    assert main(["sim", f"out={tmp_path}", "sim.scenario=bounce", "+sim.params.spin=1"]) == 2
    assert main(["sim", f"out={tmp_path}", "sim.episodes=0"]) == 2
    err = capsys.readouterr().err
    assert "out=DIR" in err and "juggle" in err and "spin" in err and "sim.episodes=0 is not allowed" in err
    assert not list(tmp_path.iterdir())
    (tmp_path / "file").write_text("")
    assert main(["sim", f"out={tmp_path / 'file' / 'out'}", "sim.episodes=1"]) == 2
    assert "is a file, not a folder" in capsys.readouterr().err


def test_rasteriser_areas_match_geometry():
    labels = np.zeros((2, 100, 100), np.uint8)
    corners = box_corners(np.array([50.0, 30.0]), np.array([50.0, 40.0]), np.array([0.3, 1.0]), 40.0, 20.0)
    fill_polygons(labels, corners[:, ::-1], 1)  # either winding
    np.testing.assert_allclose((labels == 1).sum((1, 2)), 800, rtol=0.01)
    labels[:] = 0
    fill_discs(labels, np.array([[50.0, 50.0], [-5.0, 50.0]]), 10.0, 2)  # the second one half off-frame
    segment = 100 * math.acos(0.5) - 5 * math.sqrt(75)
    np.testing.assert_allclose((labels == 2).sum((1, 2)), [math.pi * 100, segment], rtol=0.03)
    ep = simulate("uniform", 1, size=256, box=1)
    side = ep.meta["shapes"][0]["size"][0]
    np.testing.assert_allclose((ep.masks[8:25] == 1).sum((1, 2)), side * side, rtol=0.03)  # fully in view
