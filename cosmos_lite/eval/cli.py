"""`cosmos-lite eval physics checkpoint=DIR out=DIR [episodes=N steps=N ...]`: the physics-alignment benchmark,
written to out/ as results.json, report.md and report.html.
`cosmos-lite eval compare A/results.json B/results.json`: the main tables of two runs side by side, for regressions.
`cosmos-lite eval policy checkpoint=DIR out=DIR [policy.tasks=N policy.runner=ray ...]`: scripted policies run
closed-loop in the simulator and in the world model (Spearman rank correlation of their scores) and model-predictive
control planned in each, written to out/ as policy.json, policy.md and policy.html.
"""

from __future__ import annotations

import json
from pathlib import Path

from omegaconf import DictConfig

from ..errors import ConfigError, InputError
from .physics import run_physics_eval
from .report import compare

USAGE = ("use `cosmos-lite eval physics checkpoint=DIR out=DIR`, `cosmos-lite eval policy checkpoint=DIR out=DIR` "
         "or `cosmos-lite eval compare A.json B.json`")


def read_results(path: str) -> dict:
    """A results.json of an earlier run (InputError naming the file otherwise)."""
    p = Path(path)
    if p.is_dir():
        p = p / "results.json"
    try:
        results = json.loads(p.read_text())
    except FileNotFoundError:
        raise InputError(f"{p}: no such results file; pass the results.json of `cosmos-lite eval physics`") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(f"{p}: not valid JSON ({e}); rerun `cosmos-lite eval physics` to rewrite it") from None
    if not isinstance(results, dict) or "table" not in results:
        raise InputError(f"{p}: no results table; pass the results.json of `cosmos-lite eval physics`")
    return results


def main(cfg: DictConfig, args: list[str]) -> int:
    if not args:
        raise ConfigError(f"missing command: {USAGE}")
    if args[0] == "compare":
        if len(args) != 3:
            raise ConfigError(f"compare takes two results files: {USAGE}")
        print(compare(read_results(args[1]), read_results(args[2])))
        return 0
    if args == ["policy"]:
        from .policy import run_policy_eval

        results = run_policy_eval(cfg)
        print(json.dumps({"out": str(cfg.out), "spearman": results["spearman"], "mpc": results["mpc"],
                          "gap_closed": results["gap_closed"]}, indent=1))
        return 0
    if args != ["physics"]:
        raise ConfigError(f"unknown argument(s) {' '.join(args)}: {USAGE}")
    results = run_physics_eval(cfg)
    print(json.dumps({"out": str(cfg.out), "table": results["table"]}, indent=1))
    return 0
