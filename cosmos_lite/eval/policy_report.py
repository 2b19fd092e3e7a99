"""The report of `eval policy` in `out/`: policy.json, policy.md and a self-contained policy.html (plots and GIFs
embedded), a scatter of policy scores in the world model against the simulator, MPC success rates, and side-by-side
videos (simulator | world model | difference) with the goal drawn in."""

from __future__ import annotations

import html
import json
from pathlib import Path

import numpy as np

from ..files import write_text
from ..sim.goal import GoalTask
from .report import DISPLAY_HEIGHT, _data_uri, _html_table, write_side_by_side

GOAL_RING = np.array([255, 255, 255], np.float64)  # drawn half-transparent into report videos only


def draw_goal(frames: np.ndarray, task: GoalTask) -> np.ndarray:
    """Frames with the task's goal circle drawn as a thin ring (for viewing; policies never see it)."""
    h, w = frames.shape[1:3]
    y, x = np.mgrid[0:h, 0:w] + 0.5
    ring = np.abs(np.hypot(x - task.goal[0], y - task.goal[1]) - task.goal_radius) < 0.5
    out = frames.astype(np.float64)
    out[:, ring] = 0.5 * out[:, ring] + 0.5 * GOAL_RING
    return out.round().astype(np.uint8)


def _savefig(fig, path: Path) -> None:
    tmp = path.with_name(f".{path.stem}.tmp.png")
    fig.savefig(tmp)
    tmp.replace(path)


def plot_policy_scores(results: dict, out: Path) -> dict[str, str]:
    """plots/policy_scores.png (each policy's mean final distance, world model vs simulator) and plots/mpc.png
    (success rate and final distance of each planner)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    (out / "plots").mkdir(parents=True, exist_ok=True)
    fig, ax = plt.subplots(figsize=(6.5, 5), dpi=100)
    sim = [p["simulator"]["distance"] for p in results["policies"]]
    model = [p["world model"]["distance"] for p in results["policies"]]
    ax.scatter(sim, model)
    for p, x, y in zip(results["policies"], sim, model):
        ax.annotate(p["name"], (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
    top = max(sim + model + [1.0]) * 1.05
    ax.plot([0, top], [0, top], ":", color="grey")
    rho = results["spearman"]
    ax.set(xlabel="final distance in the simulator (px)", ylabel="final distance in the world model (px)",
           title=f"Policies: world model vs simulator (Spearman {'–' if rho is None else f'{rho:.2f}'})")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    _savefig(fig, out / "plots" / "policy_scores.png")
    plt.close(fig)
    paths = {"policy_scores": "plots/policy_scores.png"}
    if results["config"]["mpc"]["tasks"]:
        fig, axes = plt.subplots(1, 2, figsize=(8, 3.5), dpi=100)
        names = list(results["mpc"])
        for ax, key, label in zip(axes, ("success", "distance"), ("success rate", "final distance (px)")):
            ax.bar(names, [results["mpc"][n][key] for n in names], color=["C0", "C2", "C7"])
            ax.set(title=f"MPC: {label}", ylabel=label)
        fig.tight_layout()
        _savefig(fig, out / "plots" / "mpc.png")
        plt.close(fig)
        paths["mpc"] = "plots/mpc.png"
    return paths


def write_policy_videos(records: list[dict], tasks: list[GoalTask], out: Path, fps: float) -> list[dict]:
    """Side-by-side videos of the kept rollouts: a policy in the simulator | in the world model, and MPC planned in
    the simulator (oracle) | in the world model."""
    kept = {(r["name"], r["world"], r["task"]): r["frames"] for r in records if r["frames"] is not None}
    pairs = [(name, task, "simulator", "world model") for name, w, task in kept if w == "world model"
             and not name.startswith("MPC")]
    if ("MPC (simulator)", "simulator", 0) in kept and ("MPC (world model)", "world model", 0) in kept:
        pairs.append(("MPC", 0, "simulator", "world model"))
    videos = []
    for name, t, left, right in pairs:
        a = kept[(f"MPC ({left})", left, t) if name == "MPC" else (name, left, t)]
        b = kept[(f"MPC ({right})", right, t) if name == "MPC" else (name, right, t)]
        if a is None or b is None:
            continue
        slug = "policy_" + "".join(ch if ch.isalnum() else "_" for ch in name.lower()) + f"_task{t}"
        mp4, gif = write_side_by_side(out, slug, draw_goal(a, tasks[t]), draw_goal(b, tasks[t]), fps)
        title = (f"MPC on task {t}: planned in the simulator | in the world model" if name == "MPC"
                 else f"{name} on task {t}: simulator | world model")
        videos.append({"title": title, "mp4": mp4, "gif": gif})
    return videos


def _fmt(v: float | None, digits: int = 2) -> str:
    return "–" if v is None else f"{v:.{digits}f}"


def tables(results: dict) -> list[tuple[str, list[str], list[list[str]]]]:
    """(title, header, cells) of the policy table and the MPC table (the same in policy.md and policy.html)."""
    pol = [[p["name"], _fmt(p["simulator"]["distance"]), _fmt(p["simulator"]["success"]),
            _fmt(p["world model"]["distance"]), _fmt(p["world model"]["success"]), _fmt(p["world model"]["found"])]
           for p in results["policies"]]
    out = [("Policies: simulator vs world model", ["Policy", "Sim distance (px) ↓", "Sim success ↑",
                                                   "WM distance (px) ↓", "WM success ↑", "WM disc found ↑"], pol)]
    if results["config"]["mpc"]["tasks"]:
        out.append(("Planning (MPC), executed in the simulator", ["Planner", "Success ↑", "Final distance (px) ↓"],
                    [[name, _fmt(v["success"]), _fmt(v["distance"])] for name, v in results["mpc"].items()]))
    return out


def summary(results: dict) -> str:
    c, rho, gap = results["config"], results["spearman"], results["gap_closed"]
    text = (f"Checkpoint {results['checkpoint']}; {len(results['policies'])} policies x {c['tasks']} goal task(s), "
            f"{c['frames']} frames per rollout, a decision and a world-model call every {c['chunk']} frames; "
            f"{c['steps']} {c['sampler']} steps; seed {c['seed']}; {results['seconds']} s. "
            f"Spearman rank correlation of the policies' mean final distance, world model vs simulator: "
            f"{_fmt(rho)} (target >= 0.8).")
    if c["mpc"]["tasks"]:
        text += (f" MPC ({c['mpc']['tasks']} task(s), {c['mpc']['candidates']} candidates): the world-model planner "
                 f"closes {_fmt(gap.get('success'))} of the success gap from random to the oracle "
                 f"({_fmt(gap.get('distance'))} of the distance gap; target >= 0.5).")
    return text


def to_markdown(results: dict) -> str:
    lines = ["## The world model as a simulator: policy evaluation and planning", "", summary(results), ""]
    for title, header, cells in tables(results):
        lines += [f"### {title}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(row) + " |" for row in cells] + [""]
    lines += [f"![{k}]({p})" for k, p in results["plots"].items()] + ["", "### Side-by-side videos", ""]
    lines += [f"- {v['title']}: [mp4]({v['mp4']}) [gif]({v['gif']})" for v in results["videos"]]
    return "\n".join(lines) + "\n"


def to_html(results: dict, out: Path) -> str:
    body = ["<h1>The world model as a simulator</h1>", f"<p>{html.escape(summary(results))}</p>"]
    for title, header, cells in tables(results):
        plain = [[(x, "", False) for x in row] for row in cells]  # report.py's cells: (text, interval, best)
        body += [f"<h2>{html.escape(title)}</h2>", _html_table(header, plain)]
    body += [f'<img class="plot" src="{_data_uri(out / p, "image/png")}" alt="{k}">'
             for k, p in results["plots"].items()]
    body.append("<h2>Side-by-side videos</h2><div class='gallery'>")
    body += [f"<figure><img class='video' src='{_data_uri(out / v['gif'], 'image/gif')}' "
             f"alt='{html.escape(v['title'])}'> <a href='{html.escape(v['mp4'])}'>mp4</a>"
             f"<figcaption>{html.escape(v['title'])}</figcaption></figure>" for v in results["videos"]]
    body.append("</div>")
    style = ("body{font-family:sans-serif;margin:2em;max-width:75em}table{border-collapse:collapse;margin:1em 0}"
             "td,th{border:1px solid #ccc;padding:.3em .6em;text-align:right}td:first-child,th:first-child"
             "{text-align:left}.plot{max-width:48%}.gallery{display:flex;flex-wrap:wrap;gap:1em}figure{margin:0}"
             f".video{{height:{DISPLAY_HEIGHT}px;image-rendering:pixelated}}")
    return ("<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'><title>Policy evaluation</title>"
            f"<style>{style}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")


def write_policy_report(results: dict, records: list[dict], tasks: list[GoalTask], out: Path, fps: float) -> Path:
    """Write plots/, videos/, policy.json, policy.md and policy.html into `out` (files atomically); returns the
    HTML's path."""
    out.mkdir(parents=True, exist_ok=True)
    results["plots"] = plot_policy_scores(results, out)
    results["videos"] = write_policy_videos(records, tasks, out, fps)
    write_text(out / "policy.json", json.dumps(results, indent=1, allow_nan=False))
    write_text(out / "policy.md", to_markdown(results))
    write_text(out / "policy.html", to_html(results, out))
    return out / "policy.html"
