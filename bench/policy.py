"""The world model as a simulator, on a trained checkpoint: does it rank policies as the simulator does, and does
planning in it help? Prints the Spearman rank correlation of 12 scripted policies' scores (mean final disc-goal
distance) in the world model and in the simulator (target >= 0.8), and the success rate of model-predictive control
planned in the world model, in the true simulator (the oracle) and not at all (random actions), all measured in the
same run (target: the world-model planner closes >= half of the success gap from random to the oracle).

Budget: at most 30 minutes on 2 cores (two Ray workers, one core each) for a world model that takes about a second
per call; the run prints its own duration and the per-call time, so scale --tasks to a slower model.

    .venv/bin/python bench/policy.py [--checkpoint runs/bench_wfm/world_model] [--tasks 24] [--mpc-tasks 32]

24 tasks per policy: the simulator itself ranks the 12 policies alike on two disjoint task sets with Spearman 0.88 on
average at 24 tasks each, 0.84 at 16 and only 0.77 at 8 (48 validation tasks, 300 random splits), so at 8 tasks the
target would measure the draw of tasks as much as the world model (docs/policy_diagnosis_2026-11-27.txt). 32 tasks
per planner: one task is 0.03 of a success rate (at 16 it was 0.06, and the world-model planner's share of the gap
moved by 0.14 with a single disc); the batched look-ahead (`WorldModelPipeline.foresee`) makes them affordable.

Without --checkpoint it uses the world model that bench/wfm.py writes (runs/bench_wfm/world_model), and skips
(exit 0) if there is none yet.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

from cosmos_lite.config import load_config
from cosmos_lite.errors import CosmosError
from cosmos_lite.eval.policy import run_policy_eval

DEFAULT_CHECKPOINT = "runs/bench_wfm/world_model"  # written by bench/wfm.py


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", help=f"a trained world-model folder (default: {DEFAULT_CHECKPOINT})")
    ap.add_argument("--out", default="runs/bench_policy")
    ap.add_argument("--tasks", type=int, default=24, help="goal tasks per policy and world")
    ap.add_argument("--mpc-tasks", type=int, default=32, help="goal tasks per planner")
    ap.add_argument("--candidates", type=int, default=16, help="MPC candidates per plan")
    ap.add_argument("--steps", type=int, help="sampler steps per generated frame (default: the checkpoint's)")
    ap.add_argument("--workers", type=int, default=2, help="Ray workers (1: in this process)")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    if a.checkpoint is None:
        if not (Path(DEFAULT_CHECKPOINT) / "model.safetensors").is_file():
            print(f"skipped: no trained world model at {DEFAULT_CHECKPOINT}; run bench/wfm.py first or pass "
                  "--checkpoint DIR")
            return
        a.checkpoint = DEFAULT_CHECKPOINT
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    steps = "null" if a.steps is None else a.steps  # null: the checkpoint's edm.steps; 0 is refused by the config
    overrides = [f"checkpoint={a.checkpoint}", f"out={a.out}", f"steps={steps}", f"seed={a.seed}",
                 f"policy.tasks={a.tasks}", f"policy.mpc.tasks={a.mpc_tasks}", f"policy.mpc.candidates={a.candidates}",
                 f"policy.runner={'ray' if a.workers > 1 else 'local'}", f"policy.workers={a.workers}"]
    t0 = time.time()
    try:
        r = run_policy_eval(load_config("eval", overrides))
    except CosmosError as e:
        print(f"bench/policy.py: error: {e}", file=sys.stderr)
        sys.exit(e.exit_code)
    minutes = (time.time() - t0) / 60
    model = [x for x in r["records"] if x["world"] == "world model"]
    calls = sum(-(-(r["config"]["frames"] - 1) // r["config"]["chunk"]) for x in model if x["kind"] == "policy")
    policy_seconds = sum(x["seconds"] for x in model if x["kind"] == "policy")
    print(f"policies: {len(r['policies'])} x {a.tasks} tasks; world-model rollouts {policy_seconds / 60:.1f} "
          f"worker-minutes, {policy_seconds / max(calls, 1):.2f} s per world-model call")
    print(f"{'policy':<24}{'sim distance':>14}{'WM distance':>13}{'sim success':>13}{'WM success':>12}")
    for p in r["policies"]:
        s, w = p["simulator"], p["world model"]
        print(f"{p['name']:<24}{s['distance']:>14.2f}{w['distance']:>13.2f}{s['success']:>13.2f}{w['success']:>12.2f}")
    rho = r["spearman"]
    print(f"Spearman rank correlation, world model vs simulator: {'undefined' if rho is None else f'{rho:.3f}'} "
          f"(target >= 0.8: {'met' if rho is not None and rho >= 0.8 else 'not met'})")
    if a.mpc_tasks:
        labels = {"world model": "planned in the world model", "simulator": "planned in the simulator (oracle)",
                  "random": "random actions (no planning)"}
        for name, v in r["mpc"].items():
            print(f"MPC {labels[name]:<34} success {v['success']:.2f}  final distance {v['distance']:.2f} px")
        gap, dist = r["gap_closed"].get("success"), r["gap_closed"].get("distance")
        print(f"world-model planner closes {'–' if gap is None else f'{gap:.2f}'} of the success gap from random "
              f"to the oracle (target >= 0.5: {'met' if gap is not None and gap >= 0.5 else 'not met'}); of the "
              f"distance gap {'–' if dist is None else f'{dist:.2f}'}")
    print(f"total {minutes:.1f} min (budget 30 on 2 cores); report {a.out}/policy.html")
    print(json.dumps({"spearman": rho, "mpc": r["mpc"], "gap_closed": r["gap_closed"], "minutes": round(minutes, 1)}))


if __name__ == "__main__":
    main()
