"""From per-episode scores to the verdict: means with bootstrap 95% intervals over episodes, the physics-alignment
score (copy-last-frame 0, perfect model 100, as Physics-IQ normalises by physical variance) and a sentence per world
model saying which baseline it beats, on what, by how much.

Every interval resamples episodes with replacement (RESAMPLES times, percentile interval). Comparisons of two models
on the same episodes resample the episodes jointly (paired), so a shared hard episode does not widen the difference.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..core.metrics import nanmean

RESAMPLES = 2000
LEVEL = 95  # percent
# The physics-alignment score averages these metrics' normalised values (Physics-IQ's three motion IoUs and object
# IoU); centroid and velocity errors are undefined where an object is not found, so they stay beside it.
SCORE_METRICS = ("iou", "spatial_iou", "spatiotemporal_iou", "weighted_spatial_iou")
SCORE_DIGITS = 1
BASELINE, CEILING = "copy last frame", "perfect model"


def resamples(n: int, rng: np.random.Generator) -> np.ndarray:
    """Bootstrap indices `(RESAMPLES, n)` into n episodes."""
    return rng.integers(0, n, (RESAMPLES, n))


def interval(samples: np.ndarray) -> list[float | None]:
    """The central LEVEL% percentile interval of bootstrap samples along axis 0 ([None, None] if all are NaN)."""
    s = np.asarray(samples, np.float64)
    if np.isnan(s).all():
        return [None, None]
    with np.errstate(invalid="ignore"):
        lo, hi = np.nanpercentile(s, [(100 - LEVEL) / 2, (100 + LEVEL) / 2], axis=0)
    return [json_float(lo), json_float(hi)]


def mean_and_interval(values: np.ndarray, idx: np.ndarray) -> tuple[float | None, list[float | None]]:
    """The mean over episodes (NaN ignored) and its bootstrap interval; `values` `(n,)` or `(n, T)` (then per t)."""
    v = np.asarray(values, np.float64)
    mean = nanmean(v, 0)
    boot = nanmean(v[idx], 1)
    if v.ndim == 1:
        return json_float(mean), interval(boot)
    lo_hi = [interval(boot[:, t]) for t in range(v.shape[1])]
    return [json_float(m) for m in mean], [list(x) for x in zip(*lo_hi)]


def json_float(v) -> float | None:
    """A JSON-safe float: NaN becomes None."""
    v = float(v)
    return None if np.isnan(v) or np.isinf(v) else v


def episode_values(records: list[dict], model: str, given: int, metric: str, episodes: Sequence[str]) -> np.ndarray:
    """A model's per-episode value of a metric for one number of given frames, in the order of `episodes`."""
    by_name = {r["episode"]: r["mean"][metric] for r in records if r["model"] == model and r["given"] == given}
    return np.array([np.nan if by_name.get(e) is None else by_name[e] for e in episodes], np.float64)


def summary_rows(records: list[dict], keys: tuple[str, ...], metrics: Sequence[str], rng: np.random.Generator
                 ) -> list[dict]:
    """Mean over episodes of each metric with its interval (`row["ci"][metric]`), grouped by `keys` in first-seen
    order."""
    groups: dict[tuple, list[dict]] = {}
    for r in records:
        groups.setdefault(tuple(r[k] for k in keys), []).append(r)
    rows = []
    for key, rs in groups.items():
        idx = resamples(len(rs), rng)
        row, ci = dict(zip(keys, key), episodes=len(rs)), {}
        for m in metrics:
            row[m], ci[m] = mean_and_interval(np.array([np.nan if r["mean"][m] is None else r["mean"][m]
                                                        for r in rs]), idx)
        rows.append({**row, "ci": ci})
    return rows


def horizon_rows(records: list[dict], metrics: Sequence[str], rng: np.random.Generator) -> list[dict]:
    """Per model and number of given frames: each metric's mean over episodes at each predicted frame, and its
    interval (`row["ci"][metric] = [lows, highs]`)."""
    groups: dict[tuple, list[dict]] = {}
    for r in records:
        groups.setdefault((r["model"], r["given"]), []).append(r)
    rows = []
    for (model, given), rs in groups.items():
        idx = resamples(len(rs), rng)
        row, ci = {"model": model, "given": given}, {}
        for m in metrics:
            v = np.array([[np.nan if x is None else x for x in r["per_frame"][m]] for r in rs], np.float64)
            row[m], ci[m] = mean_and_interval(v, idx)
        rows.append({**row, "ci": ci})
    return rows


def score_samples(model: dict[str, np.ndarray], baseline: dict[str, np.ndarray], ceiling: dict[str, np.ndarray],
                  idx: np.ndarray, metrics: Sequence[str]) -> np.ndarray:
    """The physics-alignment score for each row of episode indices `idx` `(B, n)`: per metric
    100 (model - baseline) / (ceiling - baseline) of the means over those episodes, averaged over `metrics`."""
    parts = []
    for m in metrics:
        mm, bb, cc = (nanmean(v[m][idx], 1) for v in (model, baseline, ceiling))
        with np.errstate(divide="ignore", invalid="ignore"):
            parts.append(100 * (mm - bb) / (cc - bb))
    return np.mean(parts, 0) if parts else np.full(len(idx), np.nan)


def _better(diff: np.ndarray, higher_is_better: bool) -> np.ndarray:
    return diff if higher_is_better else -diff


def alignment_scores(results: dict, rng: np.random.Generator) -> list[dict]:
    """The physics-alignment score of every model row that has a baseline and a ceiling for its number of given
    frames: {model, given, score, ci, metrics (those that separate the ceiling from the baseline), per_metric}.

    A metric enters only if the perfect model beats copy-last-frame on it beyond the interval: on the others the
    normalisation would divide by noise."""
    records, info = results["records"], results["metrics"]
    episodes = [e["name"] for e in results["episodes"]]
    idx = resamples(len(episodes), rng)
    full = np.arange(len(episodes))[None]
    out = []
    for k in dict.fromkeys(r["given"] for r in results["table"]):
        models = [r["model"] for r in results["table"] if r["given"] == k]
        if BASELINE not in models or CEILING not in models:
            continue
        values = {m: {x: episode_values(records, m, k, x, episodes) for x in SCORE_METRICS} for m in models}
        base, ceil = values[BASELINE], values[CEILING]
        used = [x for x in SCORE_METRICS if (interval(_better(
            nanmean(ceil[x][idx], 1) - nanmean(base[x][idx], 1), info[x]["higher_is_better"]))[0] or 0) > 0]
        for m in models:
            per_metric = {x: json_float(score_samples(values[m], base, ceil, full, [x])[0]) for x in used}
            out.append({"model": m, "given": k, "metrics": used, "per_metric": per_metric,
                        "score": json_float(score_samples(values[m], base, ceil, full, used)[0]) if used else None,
                        "ci": interval(score_samples(values[m], base, ceil, idx, used)) if used else [None, None]})
    return out


def differences(records: list[dict], model: str, other: str, given: int, metrics: dict, episodes: Sequence[str],
                idx: np.ndarray) -> dict[str, dict]:
    """Paired differences `model - other` of each metric over the same episodes: {metric: {diff, ci, verdict}},
    verdict "better" / "worse" when the interval excludes 0, else "same"."""
    out = {}
    for m, info in metrics.items():
        d = episode_values(records, model, given, m, episodes) - episode_values(records, other, given, m, episodes)
        diff, ci = mean_and_interval(d, idx)
        out[m] = {"diff": diff, "ci": ci, "verdict": judge(ci, info["higher_is_better"])}
    return out


def judge(ci: list[float | None], higher_is_better: bool) -> str:
    """'better' / 'worse' if a difference's interval excludes 0 (in the metric's good / bad direction), else 'same'."""
    lo, hi = ci
    if lo is None or hi is None:
        return "same"
    if lo > 0 or hi < 0:
        return "better" if (lo > 0) == higher_is_better else "worse"
    return "same"


def _signed(v: float | None, digits: int) -> str:
    return "–" if v is None else f"{v:+.{digits}f}"


def _plain(v: float | None, digits: int) -> str:
    return "–" if v is None else f"{v:.{digits}f}"


def score_phrase(score: float | None, ci: list[float | None]) -> str:
    """The score's interval in words."""
    lo, hi = ci
    if score is None or lo is None or hi is None:
        return "no score (no metric separates the perfect model from copy-last-frame on these episodes)"
    if hi < 0:
        return "worse than copying the last frame"
    if lo <= 0:
        return "not distinguishable from copying the last frame"
    if hi < 100:
        return f"better than copying the last frame, {score:.0f}% of the way to a perfect model"
    if lo <= 100:
        return "as good as a perfect model within the interval"
    return "above the perfect model's sample (more episodes will tell)"


def verdict_sentence(model: str, given: int, score: dict | None, diffs: dict[str, dict], metrics: dict
                     ) -> tuple[str, str]:
    """('<model>, k given: score S (95% CI lo to hi), <words>.', 'Against copy-last-frame it is better on ...; worse
    on ...; no clear difference on ...') with every difference and its interval."""
    head = f"{model}, {given} given"
    if score is not None:
        s, (lo, hi) = score["score"], score["ci"]
        head += (f": physics-alignment score {_plain(s, SCORE_DIGITS)} ({LEVEL}% CI {_plain(lo, SCORE_DIGITS)} to "
                 f"{_plain(hi, SCORE_DIGITS)}; copy-last-frame 0, perfect model 100), {score_phrase(s, score['ci'])}")
    parts = {"better": [], "worse": [], "same": []}
    for m, d in diffs.items():
        info = metrics[m]
        unit = f" {info['unit']}" if info.get("unit") else ""
        lo, hi = d["ci"]
        parts[d["verdict"]].append(f"{info['label']} ({_signed(d['diff'], info['digits'])}{unit}, "
                                   f"{_signed(lo, info['digits'])} to {_signed(hi, info['digits'])})")
    said = [f"{word} on {', '.join(parts[v])}" for v, word in
            (("better", "better"), ("worse", "worse"), ("same", "no clear difference")) if parts[v]]
    return f"{head}.", f"Against copy-last-frame (difference, {LEVEL}% CI) it is " + "; ".join(said) + "."


def verdicts(results: dict, rng: np.random.Generator) -> list[dict]:
    """The verdict on each world-model row: its score in words (`head`), its paired differences with copy-last-frame
    (`details`) and both as one `text`."""
    episodes = [e["name"] for e in results["episodes"]]
    idx = resamples(len(episodes), rng)
    scores = {(s["model"], s["given"]): s for s in results["scores"]}
    out = []
    for row in results["table"]:
        if results["kinds"].get(row["model"]) != "world model":
            continue
        k = row["given"]
        diffs = differences(results["records"], row["model"], BASELINE, k, results["metrics"], episodes, idx)
        head, details = verdict_sentence(row["model"], k, scores.get((row["model"], k)), diffs, results["metrics"])
        out.append({"model": row["model"], "given": k, "differences": diffs, "head": head, "details": details,
                    "text": f"{head} {details}"})
    return out
