"""Reports of a physics-alignment run in `out/`: results.json, report.md and a self-contained report.html (plots and
GIFs embedded), metric-vs-horizon plots (PNG) and side-by-side videos (truth | generated | difference, mp4 + GIF).

`results["generations"]` (optional, e.g. from the demo): a list of {"title", "prompt", "allowed", "guard", "reason",
"video", "gif"} (paths relative to out/ or None), shown as a gallery of guarded generations.
"""

from __future__ import annotations

import base64
import html
import json
import os
from pathlib import Path

import numpy as np

from ..files import atomic_path, write_text
from ..video import write_video

DISPLAY_HEIGHT = 128  # pixels: side-by-side mp4s are upscaled (nearest) to at least this; HTML shows GIFs this tall
MAIN_METRICS = ("psnr", "ssim", "iou", "position", "velocity")
DIGITS = {"psnr": 2, "ssim": 3, "iou": 3, "position": 2, "velocity": 2}


def side_by_side(truth: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """Frames `truth | pred | |truth - pred|` with white 2-px separators."""
    diff = np.abs(truth.astype(np.int16) - pred.astype(np.int16)).astype(np.uint8)
    sep = np.full((*truth.shape[:2], 2, 3), 255, np.uint8)
    return np.concatenate([truth, sep, pred, sep, diff], axis=2)


def write_side_by_side(out: Path, name: str, truth: np.ndarray, pred: np.ndarray, fps: float) -> tuple[str, str]:
    """videos/NAME.mp4 (upscaled to DISPLAY_HEIGHT, nearest) and videos/NAME.gif (native size, small) of
    `side_by_side`; returns their paths relative to `out`."""
    frames = side_by_side(truth, pred)
    f = max(1, -(-DISPLAY_HEIGHT // truth.shape[1]))
    write_video(Path(out) / "videos" / f"{name}.mp4", frames.repeat(f, axis=1).repeat(f, axis=2), fps)
    write_video(Path(out) / "videos" / f"{name}.gif", frames, fps, codec="gif", pix_fmt="rgb8", preset=None)
    return f"videos/{name}.mp4", f"videos/{name}.gif"


def plot_horizon(results: dict, out: Path) -> dict[str, str]:
    """One PNG per metric: its mean against the predicted frame index, a line per model and given frames."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    (Path(out) / "plots").mkdir(parents=True, exist_ok=True)
    colours = {m: f"C{i}" for i, m in enumerate(results["models"])}
    given = sorted({r["given"] for r in results["horizon"]})
    styles = {k: ("-", "--", ":", "-.")[i % 4] for i, k in enumerate(given)}
    paths = {}
    for metric, info in results["metrics"].items():
        fig, ax = plt.subplots(figsize=(9, 4), dpi=100)
        for row in results["horizon"]:
            y = np.array([np.nan if v is None else v for v in row[metric]])
            ax.plot(np.arange(1, len(y) + 1), y, styles[row["given"]], color=colours[row["model"]],
                    label=f"{row['model']}, {row['given']} given")
        ax.set(xlabel="predicted frame", ylabel=info["label"], title=f"{info['label']} vs prediction horizon")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
        fig.tight_layout()
        path = Path(out) / "plots" / f"{metric}.png"
        with atomic_path(path) as tmp:
            fig.savefig(tmp)
        plt.close(fig)
        paths[metric] = f"plots/{metric}.png"
    return paths


def _fmt(v: float | None, metric: str) -> str:
    return "–" if v is None else f"{v:.{DIGITS[metric]}f}"


def _header(results: dict, group: str | None) -> list[str]:
    arrows = {m: "↑" if info["higher_is_better"] else "↓" for m, info in results["metrics"].items()}
    return (["Model", "Condition"] + ([group.capitalize()] if group else []) + [
        f"{results['metrics'][m]['label']} {arrows[m]}" for m in MAIN_METRICS] + ["Episodes"])


def table_cells(results: dict, rows: list[dict], group: str | None = None) -> list[list[str]]:
    """The rows of a results table as text cells (the same in report.md and report.html)."""
    return [[r["model"], f"{r['given']}-frame"] + ([r[group]] if group else []) +
            [_fmt(r[m], m) for m in MAIN_METRICS] + [str(r["episodes"])] for r in rows]


def _sections(results: dict) -> list[tuple[str, list[str], list[list[str]]]]:
    """(title, header, cells) of every table: main, per scenario, per split."""
    by = lambda key: sorted(results[f"by_{key}"], key=lambda r: r[key])  # noqa: E731 (stable: model order kept)
    return [
        ("Physics alignment (held-out episodes, all scenarios and splits)", _header(results, None),
         table_cells(results, results["table"])),
        ("Per scenario", _header(results, "scenario"), table_cells(results, by("scenario"), "scenario")),
        ("In- vs out-of-distribution", _header(results, "split"), table_cells(results, by("split"), "split")),
    ]


def _summary(results: dict) -> str:
    c = results["config"]
    return (f"Checkpoint {results['checkpoint']}; scenarios {', '.join(c['scenarios'])}; splits "
            f"{', '.join(c['splits'])}; {c['episodes']} episode(s) per scenario and split; {c['horizon']} predicted "
            f"frames after {' or '.join(map(str, c['given']))} given; {c['steps']} {c['sampler']} steps; seed "
            f"{c['seed']}; {results['seconds']} s.")


def to_markdown(results: dict) -> str:
    """report.md: the summary, every table, plot and video links, guarded generations if any."""
    lines = ["# Physics-alignment report", "", _summary(results), ""]
    for title, header, cells in _sections(results):
        lines += [f"## {title}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(row) + " |" for row in cells] + [""]
    lines += ["## Metrics vs prediction horizon", ""]
    lines += [f"![{m}]({p})" for m, p in results.get("plots", {}).items()] + ["", "## Side-by-side videos", "",
                                                                               "truth | generated | difference", ""]
    lines += [f"- {v['title']}: [mp4]({v['mp4']}) [gif]({v['gif']})" for v in results["videos"]]
    if results.get("generations"):
        lines += ["", "## Guarded generations", "", "| Title | Prompt | Verdict | Guard | Reason | Video |",
                  "|---|---|---|---|---|---|"]
        for g in results["generations"]:
            video = " ".join(f"[{k}]({g[k]})" for k in ("video", "gif") if g.get(k))
            lines.append(f"| {g['title']} | {g['prompt']} | {'allowed' if g['allowed'] else 'blocked'} | "
                         f"{g['guard']} | {g['reason']} | {video or '–'} |")
    return "\n".join(lines) + "\n"


def _data_uri(path: Path, mime: str) -> str:
    return f"data:{mime};base64,{base64.b64encode(path.read_bytes()).decode()}"


def _html_table(header: list[str], cells: list[list[str]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in cells)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _media(out: Path, gif: str | None, mp4: str | None, alt: str) -> str:
    parts = [f'<img class="video" src="{_data_uri(out / gif, "image/gif")}" alt="{html.escape(alt)}">'] if gif else []
    if mp4:
        parts.append(f'<a href="{html.escape(mp4)}">mp4</a>')
    return " ".join(parts) or "–"


def to_html(results: dict, out: Path) -> str:
    """report.html: the same content as report.md, self-contained (plots and GIFs embedded as base64)."""
    out = Path(out)
    body = ["<h1>Physics-alignment report</h1>", f"<p>{html.escape(_summary(results))}</p>"]
    for title, header, cells in _sections(results):
        body += [f"<h2>{html.escape(title)}</h2>", _html_table(header, cells)]
    body.append("<h2>Metrics vs prediction horizon</h2>")
    body += [f'<img class="plot" src="{_data_uri(out / p, "image/png")}" alt="{m} vs horizon">'
             for m, p in results.get("plots", {}).items()]
    body.append("<h2>Side-by-side videos</h2><p>truth | generated | difference</p><div class='gallery'>")
    body += [f"<figure>{_media(out, v['gif'], v['mp4'], v['title'])}<figcaption>{html.escape(v['title'])}"
             "</figcaption></figure>" for v in results["videos"]]
    body.append("</div>")
    if results.get("generations"):
        rows = "".join(
            f"<tr><td>{html.escape(g['title'])}</td><td>{html.escape(g['prompt'])}</td>"
            f"<td class='{'ok' if g['allowed'] else 'blocked'}'>{'allowed' if g['allowed'] else 'blocked'}</td>"
            f"<td>{html.escape(g['guard'])}</td><td>{html.escape(g['reason'])}</td>"
            f"<td>{_media(out, g.get('gif'), g.get('video'), g['title'])}</td></tr>" for g in results["generations"])
        body += ["<h2>Guarded generations</h2>", "<table><thead><tr><th>Title</th><th>Prompt</th><th>Verdict</th>"
                 f"<th>Guard</th><th>Reason</th><th>Video</th></tr></thead><tbody>{rows}</tbody></table>"]
    style = ("body{font-family:sans-serif;margin:2em;max-width:75em}table{border-collapse:collapse;margin:1em 0}"
             "td,th{border:1px solid #ccc;padding:.3em .6em;text-align:right}td:first-child,th:first-child"
             "{text-align:left}.plot{max-width:48%}.gallery{display:flex;flex-wrap:wrap;gap:1em}"
             f"figure{{margin:0}}.ok{{color:#070}}.blocked{{color:#b00}}.video{{height:{DISPLAY_HEIGHT}px;"
             "image-rendering:pixelated}")
    return ("<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'><title>Physics-alignment report</title>"
            f"<style>{style}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")


def write_report(results: dict, out: str | os.PathLike) -> Path:
    """Write plots/, results.json, report.md and report.html into `out` (each file atomically); returns the HTML."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    results["plots"] = plot_horizon(results, out)
    write_text(out / "results.json", json.dumps(results, indent=1, allow_nan=False))
    write_text(out / "report.md", to_markdown(results))
    write_text(out / "report.html", to_html(results, out))
    return out / "report.html"


def compare(a: dict, b: dict) -> str:
    """The main tables of two results side by side: each metric in A, in B and B - A, per model and given frames."""
    rows_b = {(r["model"], r["given"]): r for r in b["table"]}
    header = ["Model", "Condition"] + [f"{m} A / B / B-A" for m in MAIN_METRICS]
    lines = ["\t".join(header)]
    for r in a["table"]:
        other = rows_b.get((r["model"], r["given"]))
        if other is None:
            lines.append(f"{r['model']}\t{r['given']}-frame\tonly in A")
            continue
        cells = []
        for m in MAIN_METRICS:
            x, y = r[m], other[m]
            delta = "–" if x is None or y is None else f"{y - x:+.{DIGITS[m]}f}"
            cells.append(f"{_fmt(x, m)} / {_fmt(y, m)} / {delta}")
        lines.append("\t".join([r["model"], f"{r['given']}-frame", *cells]))
    keys_a = {(r["model"], r["given"]) for r in a["table"]}
    lines += [f"{m}\t{k}-frame\tonly in B" for m, k in rows_b if (m, k) not in keys_a]
    return "\n".join(lines)
