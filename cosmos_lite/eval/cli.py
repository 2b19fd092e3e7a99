"""`cosmos-lite eval physics checkpoint=DIR out=DIR [episodes=N steps=N ...]`: the physics-alignment benchmark,
written to out/ as results.json, report.md and report.html.
`cosmos-lite eval compare A B [fail_on=iou|fail_on=[iou,score]]`: every metric of two runs (results.json or their
folders) side by side with B - A and its 95% interval; warns about every setting in which they differ; exits 1 if a
world model got worse beyond the interval on a metric named in fail_on (a CI gate for training changes).
`cosmos-lite eval policy checkpoint=DIR out=DIR [policy.tasks=N policy.runner=ray ...]`: scripted policies run
closed-loop in the simulator and in the world model (Spearman rank correlation of their scores) and model-predictive
control planned in each, written to out/ as policy.json, policy.md and policy.html.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from omegaconf import DictConfig, ListConfig

from ..errors import ConfigError, InputError
from ..log import get_logger
from .compare import compare, differing_settings, format_table
from .physics import run_physics_eval

USAGE = ("use `cosmos-lite eval physics checkpoint=DIR out=DIR`, `cosmos-lite eval policy checkpoint=DIR out=DIR` "
         "or `cosmos-lite eval compare A.json B.json`")
log = get_logger("eval")


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
    if not isinstance(results, dict) or not {"table", "records", "scores", "kinds"} <= set(results):
        raise InputError(f"{p}: no per-episode results (an older or foreign file); rerun `cosmos-lite eval physics`")
    return results


def run_compare(cfg: DictConfig, path_a: str, path_b: str) -> int:
    """Print the comparison; 1 if a metric in cfg.fail_on regressed, else 0."""
    fail_on = cfg.fail_on
    fail_on = list(fail_on) if isinstance(fail_on, ListConfig | list) else [str(fail_on)] if fail_on else []
    a, b = read_results(path_a), read_results(path_b)
    rows, regressions = compare(a, b, fail_on)
    settings = differing_settings(a, b)
    if settings:
        log.warning("the runs differ in settings, so differences may come from them and not the model: %s",
                    "; ".join(settings))
    print(f"A: {a['checkpoint']}\nB: {b['checkpoint']}\n{format_table(rows, a, b)}")
    for r in regressions:
        print(f"REGRESSION {r}", file=sys.stderr)
    if fail_on and not regressions:
        print(f"no regression beyond the 95% interval on {', '.join(fail_on)}")
    return 1 if regressions else 0


def main(cfg: DictConfig, args: list[str]) -> int:
    if not args:
        raise ConfigError(f"missing command: {USAGE}")
    if args[0] == "compare":
        if len(args) != 3:
            raise ConfigError(f"compare takes two results files: {USAGE}")
        return run_compare(cfg, args[1], args[2])
    if args == ["policy"]:
        from .policy import run_policy_eval

        results = run_policy_eval(cfg)
        print(json.dumps({"out": str(cfg.out), "spearman": results["spearman"], "mpc": results["mpc"],
                          "gap_closed": results["gap_closed"]}, indent=1))
        return 0
    if args != ["physics"]:
        raise ConfigError(f"unknown argument(s) {' '.join(args)}: {USAGE}")
    results = run_physics_eval(cfg)
    print("\n".join([v["text"] for v in results["verdicts"]] + [f"report: {Path(cfg.out) / 'report.html'}"]))
    return 0
