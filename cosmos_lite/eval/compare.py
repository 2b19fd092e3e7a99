"""`eval compare A B`: every metric and the physics-alignment score of two runs side by side, B - A with a bootstrap
interval over episodes (paired when both ran the same episodes), a warning naming every setting in which the runs
differ, and the regressions of the metrics chosen with `fail_on` (B worse than A beyond the interval), so a training
change can be gated in CI.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..core.metrics import nanmean
from ..errors import ConfigError
from .stats import BASELINE, CEILING, LEVEL, SCORE_METRICS, episode_values, interval, judge, resamples, score_samples

NOT_SETTINGS = ("out", "checkpoint", "fail_on")  # config keys that may differ without changing what is measured


def differing_settings(a: dict, b: dict) -> list[str]:
    """'key: A vs B' for every evaluation setting in which two runs differ, and whether their episodes do."""
    ca, cb = a["config"], b["config"]
    diff = [f"{k}: {ca.get(k)} vs {cb.get(k)}" for k in dict.fromkeys([*ca, *cb])
            if k not in NOT_SETTINGS and ca.get(k) != cb.get(k)]
    if a["seeds"]["episodes"] != b["seeds"]["episodes"]:
        diff.append("episodes: different held-out episodes (intervals are unpaired)")
    return diff


def _episode_samples(a: dict, b: dict, rng: np.random.Generator) -> tuple[list[str], list[str], np.ndarray,
                                                                             np.ndarray]:
    """Episode names of A and B and the bootstrap indices into each: the same indices when the runs share their
    episodes (paired), independent ones otherwise."""
    ea, eb = [e["name"] for e in a["episodes"]], [e["name"] for e in b["episodes"]]
    ia = resamples(len(ea), rng)
    paired = a["seeds"]["episodes"] == b["seeds"]["episodes"]
    return ea, eb, ia, (ia if paired else resamples(len(eb), rng))


def _metric_samples(results: dict, model: str, given: int, metric: str, episodes: list[str], idx: np.ndarray
                    ) -> tuple[float, np.ndarray]:
    """A model's mean of a metric (or its score) over the episodes, and its value in each bootstrap resample."""
    if metric == "score":
        values = {m: {x: episode_values(results["records"], m, given, x, episodes) for x in SCORE_METRICS}
                  for m in (model, BASELINE, CEILING)}
        used = next((s["metrics"] for s in results["scores"] if s["model"] == model and s["given"] == given), [])
        full = np.arange(len(episodes))[None]
        args = values[model], values[BASELINE], values[CEILING]
        return float(score_samples(*args, full, used)[0]), score_samples(*args, idx, used)
    v = episode_values(results["records"], model, given, metric, episodes)
    return float(nanmean(v)), nanmean(v[idx], 1)


def compare(a: dict, b: dict, fail_on: Sequence[str] = (), seed: int = 0) -> tuple[list[dict], list[str]]:
    """Rows {model, given, metric, a, b, diff, ci, verdict} for every model, condition and metric (and the score) of
    both runs, and the regressions: world-model rows of a metric in `fail_on` that got worse beyond the interval."""
    metrics = {**a["metrics"], "score": {"label": "physics-alignment score", "higher_is_better": True, "digits": 1,
                                         "unit": ""}}
    unknown = sorted(set(fail_on) - set(metrics))
    if unknown:
        raise ConfigError(f"fail_on: unknown metric(s) {', '.join(unknown)}; choose from {', '.join(metrics)}")
    rng = np.random.default_rng(seed)
    ea, eb, ia, ib = _episode_samples(a, b, rng)
    keys_b = {(r["model"], r["given"]) for r in b["table"]}
    scored = {(s["model"], s["given"]) for s in a.get("scores", []) if s["score"] is not None} & {
        (s["model"], s["given"]) for s in b.get("scores", []) if s["score"] is not None}
    rows, regressions = [], []
    for r in a["table"]:
        key = (r["model"], r["given"])
        if key not in keys_b:
            continue
        for m, info in metrics.items():
            if m == "score" and key not in scored:
                continue
            va, sa = _metric_samples(a, *key, m, ea, ia)
            vb, sb = _metric_samples(b, *key, m, eb, ib)
            ci = interval(sb - sa)
            row = {"model": key[0], "given": key[1], "metric": m, "a": va, "b": vb, "diff": vb - va, "ci": ci,
                   "verdict": judge(ci, info["higher_is_better"])}
            rows.append(row)
            if m in fail_on and row["verdict"] == "worse" and b["kinds"].get(key[0]) == "world model":
                regressions.append(f"{key[0]}, {key[1]} given: {info['label']} {_f(va, info)} -> {_f(vb, info)} "
                                   f"({_f(row['diff'], info, True)}, {LEVEL}% CI {_f(ci[0], info, True)} to "
                                   f"{_f(ci[1], info, True)})")
    return rows, regressions


def _f(v: float | None, info: dict, signed: bool = False) -> str:
    if v is None or np.isnan(v):
        return "–"
    return f"{v:+.{info['digits']}f}" if signed else f"{v:.{info['digits']}f}"


def format_table(rows: list[dict], a: dict, b: dict) -> str:
    """The rows as an aligned text table: model, condition, metric, A, B, B - A and its interval, verdict."""
    metrics = {**a["metrics"], "score": {"label": "physics-alignment score", "digits": 1}}
    cells = [["model", "condition", "metric", "A", "B", "B - A", f"{LEVEL}% CI", "B vs A"]]
    for r in rows:
        info = metrics[r["metric"]]
        cells.append([r["model"], f"{r['given']} given", info["label"], _f(r["a"], info), _f(r["b"], info),
                      _f(r["diff"], info, True), f"{_f(r['ci'][0], info, True)} to {_f(r['ci'][1], info, True)}",
                      r["verdict"]])
    only = lambda x, y: [f"{m} ({k} given)" for m, k in dict.fromkeys(  # noqa: E731
        (r["model"], r["given"]) for r in x["table"]) if (m, k) not in {(s["model"], s["given"]) for s in y["table"]}]
    width = [max(len(row[i]) for row in cells) for i in range(len(cells[0]))]
    lines = ["  ".join(c.ljust(w) if i < 3 else c.rjust(w) for i, (c, w) in enumerate(zip(row, width)))
             for row in cells]
    lines += [f"only in A: {x}" for x in only(a, b)] + [f"only in B: {x}" for x in only(b, a)]
    return "\n".join(lines)
