"""Policy evaluation in the world model: the goal task's success check, the colour read-out against the simulator's
state, scripted policies, closed loops in a real (tiny) world model, MPC, `cosmos-lite eval policy` and its errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cosmos_lite.cli import main
from cosmos_lite.eval.policies import policy_family, read_positions
from cosmos_lite.eval.policy import (
    LOST_COST,
    MPCConfig,
    candidates,
    closed_loop,
    goal_episodes,
    model_foresight,
    model_world,
    mpc,
    plan_cost,
    proposals,
    simulator_foresight,
    simulator_world,
)
from cosmos_lite.sim import read_episode, simulate
from cosmos_lite.sim.goal import AGENT, DISC, make_goal_task

POLICIES = {p.name: p for p in policy_family()}
SMALL = ["steps=1", "policy.tasks=1", "policy.frames=9", "policy.mpc.tasks=1", "policy.mpc.candidates=2",
         "policy.mpc.horizon=4", "policy.mpc.execute=4", "policy.videos=1"]


def test_goal_task_is_deterministic_undrawn_and_scored_from_the_simulators_state():
    task = make_goal_task(3, seed=5)
    assert task == make_goal_task(3, seed=5) and task != make_goal_task(4, seed=5)
    first = task.simulate(np.zeros((0, 2)))
    assert first.meta["shapes"][DISC - 1]["kind"] == "circle"
    # The goal is not drawn: the task's frames are the pusher scenario's own, the first one as in any rollout.
    np.testing.assert_array_equal(first.frames, simulate("pusher", task.seed, frames=2, objects=1).frames[:1])
    np.testing.assert_array_equal(first.frames, task.simulate(np.ones((5, 2))).frames[:1])
    start = task.distance(first.states[0, DISC - 1, :2])
    assert 12 <= start <= 24  # GOAL_DISTANCE world units at 64 px
    still = task.outcome(task.simulate(np.zeros((8, 2))))
    assert still == {"distance": pytest.approx(start), "success": False}
    # Success is the disc's centre ending within the goal radius.
    assert task.succeeded(task.goal_radius) and not task.succeeded(task.goal_radius + 1e-6)


def test_a_good_scripted_policy_reaches_goals_and_standing_still_never_does():
    careful, still = POLICIES["careful"], POLICIES["still"]
    outcomes = []
    for i in range(4):
        task = make_goal_task(i, seed=0)
        _, actions, _ = closed_loop(task, careful, simulator_world(task), 4, seed=i)
        outcomes.append(task.outcome(task.simulate(actions)))
        _, actions, _ = closed_loop(task, still, simulator_world(task), 4, seed=i)
        assert not task.outcome(task.simulate(actions))["success"]
    assert any(o["success"] for o in outcomes)


def test_goal_pushing_training_episodes_push_discs_and_are_reproducible(tmp_path):
    goal_episodes(tmp_path / "a", 6, seed=2)
    goal_episodes(tmp_path / "b", 6, seed=2)
    eps = [read_episode(p) for p in sorted((tmp_path / "a").glob("*.json"))]
    assert len(eps) == 6 and all(ep.frames.shape == (33, 64, 64, 3) for ep in eps)
    travel = [float(np.hypot(*(ep.states[-1, DISC - 1, :2] - ep.states[0, DISC - 1, :2]))) for ep in eps]
    assert sum(t > 2.0 for t in travel) >= 3  # the behaviour pushes the disc in most episodes
    again = [read_episode(p) for p in sorted((tmp_path / "b").glob("*.json"))]
    for ep, twin in zip(eps, again):  # deterministic in (seed, index)
        np.testing.assert_array_equal(ep.states, twin.states)


def test_read_out_centroids_are_within_a_pixel_of_the_simulators_state():
    """On every frame where the agent and the disc are apart and the disc is not pressed into a wall, the read-out is
    exact up to rasterisation, far below a pixel."""
    errors, shown = [], []
    for size in (64, 128):
        for i, name in enumerate(["greedy", "greedy-fast", "random-fast", "careful"]):
            task = make_goal_task(i, seed=0, size=size)
            frames, actions, _ = closed_loop(task, POLICIES[name], simulator_world(task), 4, seed=i)
            ep = task.simulate(actions)
            np.testing.assert_array_equal(frames, ep.frames)
            true = ep.states[:, [AGENT - 1, DISC - 1], :2]
            apart = np.hypot(*(true[:, 0] - true[:, 1]).T) >= task.disc_radius + task.agent_radius - size / 64
            margin = 2.0 * size / 64 + task.disc_radius
            inside = np.all((true[:, 1] >= margin) & (true[:, 1] <= size - margin), axis=1)
            pos = read_positions(ep.frames, ep.meta)
            errors.append(np.hypot(*(pos - true).transpose(2, 0, 1))[apart & inside])
            shown.append((apart & inside).mean())
    err = np.concatenate(errors)
    assert np.mean(shown) > 0.9 and not np.isnan(err).any()
    assert err.max() < 1.0, err.max()
    assert err.mean() < 0.2


def test_tiny_closed_loop_in_a_real_world_model(tiny_wfm):
    from cosmos_lite.models import WorldModelPipeline

    pipe = WorldModelPipeline.from_pretrained(tiny_wfm)
    task = make_goal_task(0, seed=0, frames=9, size=pipe.size)
    first = task.simulate(np.zeros((0, 2))).frames
    stream = pipe.stream(first, steps=1)
    nxt = np.concatenate([stream.extend(np.ones((3, 2)), 3, seed=0), stream.extend(np.ones((5, 2)), 2, seed=1)])
    assert nxt.shape == (5, 32, 32, 3) and nxt.dtype == np.uint8 and len(stream) == 6
    whole = pipe(video=first, actions=np.ones((5, 2)), num_frames=6, steps=1).frames[1:]
    assert np.abs(whole[:3].astype(int) - nxt[:3]).max() <= 1  # the same first chunk, decoded from fewer frames
    world = model_world(pipe, steps=1, sampler="euler")
    frames, actions, score = closed_loop(task, POLICIES["greedy"], world, 4, seed=1)
    assert frames.shape == (9, 32, 32, 3) and actions.shape == (8, 2)
    np.testing.assert_array_equal(frames[0], first[0])  # the given frame, then the model's
    assert not np.array_equal(frames[1:], task.simulate(actions).frames[1:])
    again = closed_loop(task, POLICIES["greedy"], world, 4, seed=1)
    np.testing.assert_array_equal(frames, again[0])  # deterministic given the seed
    assert set(score) == {"distance", "success", "found"}
    # MPC planned in the world model acts in the true simulator: its frames are the simulator's.
    m = MPCConfig(candidates=2, horizon=4, execute=4, samples=2)
    planned, outcome = mpc(task, model_foresight(pipe, 1, "euler", m.samples), m, seed=0)
    assert planned.shape == (9, 32, 32, 3) and set(outcome) == {"distance", "success"}


def test_foresight_batches_candidates_under_common_noise(tiny_wfm):
    """The planner's batched look-ahead: (samples, candidates) final frames; under one seed equal action sequences
    get equal frames and a candidate's frame does not depend on the others in the batch; seeds differ."""
    from cosmos_lite.models import WorldModelPipeline

    pipe = WorldModelPipeline.from_pretrained(tiny_wfm)
    task = make_goal_task(1, seed=0, frames=12, size=pipe.size)
    given = task.simulate(np.full((4, 2), 20.0)).frames
    rng = np.random.default_rng(0)
    cands = rng.normal(0.0, 40.0, (3, 4 + 6, 2))
    cands[2] = cands[0]
    out = pipe.foresee(given, cands, 6, seeds=[3, 4], steps=2)
    assert out.shape == (2, 3, 32, 32, 3) and out.dtype == np.uint8
    np.testing.assert_array_equal(out[:, 0], out[:, 2])
    alone = pipe.foresee(given, cands[1:2], 6, seeds=[4], steps=2)
    assert np.abs(alone[0, 0].astype(int) - out[1, 1]).max() <= 1
    assert not np.array_equal(out[0], out[1])
    looked = model_foresight(pipe, 2, "euler", 2)(given, cands, 6, 0)
    assert looked.shape == (2, 3, 32, 32, 3)
    sim = simulator_foresight(task)(given, cands, 6, 0)
    np.testing.assert_array_equal(sim[0, 1], task.simulate(cands[1]).frames[-1])


def test_oracle_planning_beats_random_actions():
    m = MPCConfig(candidates=8)
    tasks = [make_goal_task(i, seed=3, frames=33) for i in range(3)]
    oracle = [mpc(t, simulator_foresight(t), m, seed=i)[1]["distance"] for i, t in enumerate(tasks)]
    random = [mpc(t, None, m, seed=i)[1]["distance"] for i, t in enumerate(tasks)]
    assert np.mean(oracle) < np.mean(random)


def test_proposed_candidates_push_the_disc_towards_the_goal_more_than_random_waypoints():
    """The planner's goal-shaped proposals, played open loop in the simulator from a task's start, leave the disc
    nearer the goal than the random waypoint candidates do."""
    rng = np.random.default_rng(0)
    m = MPCConfig()
    shaped, waypoints = [], []
    for i in range(4):
        task = make_goal_task(i, seed=3, frames=33)
        agent, disc = task.simulate(np.zeros((0, 2))).states[0, [AGENT - 1, DISC - 1], :2]
        args = (rng, 8, 32, m.segment)
        for out, cands in ((shaped, proposals(*args, task, agent, disc)),
                           (waypoints, candidates(*args, task.fps, m.speed, agent, disc, m.spread))):
            out += [task.outcome(task.simulate(task.limit(c)))["distance"] for c in cands]
    assert np.mean(shaped) < 0.8 * np.mean(waypoints)


def test_a_foreseen_frame_that_lost_the_disc_costs_more_than_leaving_it_where_it_was_seen():
    task = make_goal_task(0, seed=3, frames=9)
    ep = task.simulate(np.zeros((0, 2)))
    seen = ep.states[0, :, :2].astype(np.float64)
    frame = ep.frames[0]
    lost = frame.copy()
    y, x = np.mgrid[: frame.shape[0], : frame.shape[1]] + 0.5
    disc = np.hypot(x - seen[DISC - 1, 0], y - seen[DISC - 1, 1]) <= task.disc_radius + 1.5
    lost[disc] = ep.meta["scenery_color"]  # the disc painted over with the floor
    assert np.isnan(read_positions(lost[None], ep.meta)[0, DISC - 1, 0])
    kept = plan_cost(task, frame, ep.meta, seen)
    assert kept >= task.distance(seen[DISC - 1])
    assert plan_cost(task, lost, ep.meta, seen) == pytest.approx(task.distance(seen[DISC - 1]) + LOST_COST)


@pytest.fixture(scope="module")
def policy_run(tiny_wfm, tmp_path_factory):
    out = tmp_path_factory.mktemp("policy") / "report"
    assert main(["eval", "policy", f"checkpoint={tiny_wfm}", f"out={out}", *SMALL]) == 0
    return out, json.loads((out / "policy.json").read_text())


def test_eval_policy_writes_spearman_per_policy_scores_mpc_and_a_report(policy_run):
    out, results = policy_run
    assert results["spearman"] is None or -1.0 <= results["spearman"] <= 1.0
    assert [p["name"] for p in results["policies"]] == list(POLICIES)
    for p in results["policies"]:
        for world in ("simulator", "world model"):
            assert p[world]["distance"] >= 0 and 0 <= p[world]["success"] <= 1
    assert set(results["mpc"]) == {"world model", "simulator", "random"}
    assert len(results["records"]) == 2 * len(POLICIES) + 3
    # The simulator's scores are reproducible from the recorded task seeds.
    rec = next(r for r in results["records"] if r["name"] == "greedy" and r["world"] == "simulator")
    task = make_goal_task(0, seed=0, frames=9, size=(32, 32))
    assert results["tasks"][0]["seed"] == task.seed
    _, actions, _ = closed_loop(task, POLICIES["greedy"], simulator_world(task), 4, seed=rec["seed"])
    assert task.outcome(task.simulate(actions))["distance"] == pytest.approx(rec["distance"])
    md = (out / "policy.md").read_text()
    assert "Spearman" in md and "| careful |" in md
    for f in ("policy.html", "plots/policy_scores.png", "plots/mpc.png", "videos/policy_careful_task0.mp4",
              "videos/policy_mpc_task0.gif"):
        assert (out / f).is_file(), f


@pytest.mark.parametrize(("args", "code", "words"), [
    (["policy.tasks=0"], 2, "policy.tasks=0"),
    (["policy.policies=[still,teleport]"], 2, "teleport"),
    (["policy.runner=spark"], 2, "policy.runner"),
    (["policy.mpc.depth=3"], 2, "policy.mpc.depth"),
])
def test_bad_policy_config_exits_2_naming_the_key(tiny_wfm, tmp_path, capsys, args, code, words):
    assert main(["eval", "policy", f"checkpoint={tiny_wfm}", f"out={tmp_path / 'o'}", *SMALL, *args]) == code
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_missing_or_unreadable_checkpoint_exits_cleanly(tmp_path, capsys):
    assert main(["eval", "policy", f"out={tmp_path / 'o'}"]) == 2
    (tmp_path / "bad").mkdir()
    assert main(["eval", "policy", f"checkpoint={tmp_path / 'bad'}", f"out={tmp_path / 'o'}"]) == 4
    assert "model.safetensors" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_ray_runner_gives_the_local_results(tiny_wfm, policy_run, tmp_path):
    import ray

    _, local = policy_run
    out = tmp_path / "ray"
    try:
        assert main(["eval", "policy", f"checkpoint={tiny_wfm}", f"out={out}", *SMALL, "policy.runner=ray",
                     "policy.workers=2"]) == 0
    finally:
        ray.shutdown()
    remote = json.loads((out / "policy.json").read_text())
    drop = ("seconds",)
    assert [{k: v for k, v in r.items() if k not in drop} for r in remote["records"]] == \
        [{k: v for k, v in r.items() if k not in drop} for r in local["records"]]
