"""Reports of a physics-alignment run in `out/`: results.json, report.md and a self-contained report.html (plots and
frames inline): the run's settings and training, the verdict (score per model with intervals, in a sentence), how to
read it, tables with intervals and the best value marked, metric-vs-horizon plots, and players over side-by-side
videos (truth | generated | difference; given frames framed in orange), with mp4 and GIF beside.

`results["generations"]` (optional, e.g. from the demo): a list of {"title", "prompt", "allowed", "guard", "reason",
"video", "gif"} (paths relative to out/ or None; "given": frames the generation started from, default 0), shown as a
gallery of guarded generations.
"""

from __future__ import annotations

import base64
import html
import io
import json
import os
from pathlib import Path

import numpy as np
from PIL import Image
from PIL.PngImagePlugin import PngInfo

from ..files import atomic_path, write_text
from ..video import write_video
from .stats import LEVEL, RESAMPLES, SCORE_DIGITS, SCORE_METRICS

DISPLAY_HEIGHT = 192  # pixels: side-by-side mp4s and the HTML players show frames (nearest) at least this tall
GIVEN_COLOUR, PREDICTED_COLOUR = (255, 140, 0), (255, 255, 255)  # the 2-px frame around given / predicted frames
HEADLINE_METRICS = ("iou", "spatiotemporal_iou", "velocity", "psnr")  # the raw metrics beside the score
COMPETITORS = ("world model", "baseline")  # kinds whose best value a column marks (references see the truth)


def side_by_side(truth: np.ndarray, pred: np.ndarray, given: int = 0) -> np.ndarray:
    """Frames `truth | pred | |truth - pred|` with white 2-px separators, in a 2-px frame: orange around the first
    `given` frames (the model saw them), white around the predicted ones."""
    diff = np.abs(truth.astype(np.int16) - pred.astype(np.int16)).astype(np.uint8)
    sep = np.full((*truth.shape[:2], 2, 3), 255, np.uint8)
    frames = np.pad(np.concatenate([truth, sep, pred, sep, diff], axis=2), ((0, 0), (2, 2), (2, 2), (0, 0)))
    inside = np.zeros(frames.shape[1:3], bool)
    inside[2:-2, 2:-2] = True
    for i, f in enumerate(frames):
        f[~inside] = GIVEN_COLOUR if i < given else PREDICTED_COLOUR
    return frames


def strip_path(mp4: str) -> str:
    """The lossless frame strip (all frames stacked vertically, PNG) that `write_side_by_side` writes beside an mp4."""
    return str(Path(mp4).with_suffix(".png"))


def write_side_by_side(out: Path, name: str, truth: np.ndarray, pred: np.ndarray, fps: float,
                       given: int = 0) -> tuple[str, str]:
    """videos/NAME.mp4 (upscaled to DISPLAY_HEIGHT, nearest), videos/NAME.gif (native size) and videos/NAME.png (the
    frames stacked, the HTML player's source) of `side_by_side`; returns the mp4's and the GIF's paths relative to
    `out`."""
    frames = side_by_side(truth, pred, given)
    f = _scale(frames.shape[1])
    videos = Path(out) / "videos"
    write_video(videos / f"{name}.mp4", frames.repeat(f, axis=1).repeat(f, axis=2), fps)
    write_video(videos / f"{name}.gif", frames, fps, codec="gif", pix_fmt="rgb8", preset=None)
    info = PngInfo()
    info.add_text("frames", str(len(frames)))
    info.add_text("fps", f"{fps:g}")
    buf = io.BytesIO()
    Image.fromarray(frames.reshape(-1, *frames.shape[2:])).save(buf, format="PNG", pnginfo=info, optimize=True)
    with atomic_path(videos / f"{name}.png") as tmp:
        tmp.write_bytes(buf.getvalue())
    return f"videos/{name}.mp4", f"videos/{name}.gif"


def _scale(height: int) -> int:
    return max(1, -(-DISPLAY_HEIGHT // height))


# ---- plots ------------------------------------------------------------------------------------------------------

def plot_horizon(results: dict, out: Path) -> dict[str, str]:
    """One PNG per metric: its mean (line) and 95% interval (band) against the predicted frame, a panel per number
    of given frames, a colour per model; fonts readable at 100% zoom."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    (Path(out) / "plots").mkdir(parents=True, exist_ok=True)
    colours = {m: f"C{i}" for i, m in enumerate(results["models"])}
    given = sorted({r["given"] for r in results["horizon"]})
    paths = {}
    style = {"font.size": 12, "axes.titlesize": 13, "axes.labelsize": 12, "legend.fontsize": 11,
             "xtick.labelsize": 11, "ytick.labelsize": 11}
    for metric, info in results["metrics"].items():
        with matplotlib.rc_context(style):
            fig, axes = plt.subplots(1, len(given), figsize=(5.2 * len(given), 4.2), dpi=100, sharey=True,
                                     squeeze=False)
            for ax, k in zip(axes[0], given):
                for row in (r for r in results["horizon"] if r["given"] == k):
                    y = _array(row[metric])
                    lo, hi = (_array(v) for v in row["ci"][metric])
                    x = np.arange(1, len(y) + 1)
                    ax.plot(x, y, "-o", ms=3, color=colours[row["model"]], label=row["model"])
                    ax.fill_between(x, lo, hi, color=colours[row["model"]], alpha=0.15, lw=0)
                ax.set(title=f"{k} given", xlabel="predicted frames so far" if info["per"] == "clip"
                       else "predicted frame")
                ax.grid(alpha=0.3)
                ax.xaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
            axes[0][0].set_ylabel(_label(info) + (" ↑" if info["higher_is_better"] else " ↓"))
            handles, labels = axes[0][0].get_legend_handles_labels()
            fig.legend(handles, labels, loc="lower center", ncol=min(3, len(labels)), frameon=False)
            fig.suptitle(f"{_label(info)} vs prediction horizon (mean, band: {LEVEL}% interval over episodes)")
            fig.tight_layout(rect=(0, 0.06 * -(-len(labels) // 3) + 0.02, 1, 1))
            path = Path(out) / "plots" / f"{metric}.png"
            with atomic_path(path) as tmp:
                fig.savefig(tmp)
            plt.close(fig)
        paths[metric] = f"plots/{metric}.png"
    return paths


def _array(values: list) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], np.float64)


def _label(info: dict) -> str:
    return f"{info['label']} ({info['unit']})" if info["unit"] else info["label"]


# ---- tables -----------------------------------------------------------------------------------------------------

def _fmt(v: float | None, digits: int) -> str:
    return "–" if v is None else f"{v:.{digits}f}"


def _ci(ci: list, digits: int) -> str:
    return "" if ci[0] is None else f"{ci[0]:.{digits}f} to {ci[1]:.{digits}f}"


def _score_text(score: dict) -> tuple[str, str]:
    return _fmt(score["score"], SCORE_DIGITS), _ci(score["ci"], SCORE_DIGITS)


def _header(results: dict, group: str | None, score: bool) -> list[str]:
    arrows = {m: "↑" if info["higher_is_better"] else "↓" for m, info in results["metrics"].items()}
    return (["Model", "Condition"] + ([group.capitalize()] if group else []) + (["Score ↑"] if score else [])
            + [f"{_label(info)} {arrows[m]}" for m, info in results["metrics"].items()] + ["Episodes"])


def _best(results: dict, rows: list[dict], group: str | None) -> set[tuple[int, str]]:
    """(row index, metric) of the best value of each metric among world models and baselines of one condition."""
    best = set()
    blocks: dict[tuple, list[int]] = {}
    for i, r in enumerate(rows):
        if results["kinds"].get(r["model"]) in COMPETITORS:
            blocks.setdefault((r["given"], r[group] if group else None), []).append(i)
    for members in blocks.values():
        for m, info in results["metrics"].items():
            values = [(rows[i][m], i) for i in members if rows[i][m] is not None]
            if values:
                top = (max if info["higher_is_better"] else min)(v for v, _ in values)
                best |= {(i, m) for v, i in values if v == top}
    return best


def table_cells(results: dict, rows: list[dict], group: str | None = None, score: bool = False
                ) -> list[list[tuple[str, str, bool]]]:
    """The rows of a results table as cells (text, interval text, best in its column and condition), the same in
    report.md and report.html."""
    best = _best(results, rows, group)
    scores = {(s["model"], s["given"]): s for s in results.get("scores", [])}
    cells = []
    for i, r in enumerate(rows):
        row = [(r["model"], "", False), (f"{r['given']} given", "", False)] + ([(r[group], "", False)] if group else [])
        if score:
            s = scores.get((r["model"], r["given"]))
            row.append(("–", "", False) if s is None else (*_score_text(s), False))
        row += [(_fmt(r[m], info["digits"]), _ci(r["ci"][m], info["digits"]), (i, m) in best)
                for m, info in results["metrics"].items()]
        cells.append(row + [(str(r["episodes"]), "", False)])
    return cells


def _sections(results: dict) -> list[tuple[str, list[str], list]]:
    """(title, header, cells) of every table: main, per scenario, per split."""
    by = lambda key: sorted(results[f"by_{key}"], key=lambda r: r[key])  # noqa: E731 (stable: model order kept)
    return [
        ("All held-out episodes", _header(results, None, True), table_cells(results, results["table"], score=True)),
        ("Per scenario", _header(results, "scenario", False), table_cells(results, by("scenario"), "scenario")),
        ("In- vs out-of-distribution", _header(results, "split", False), table_cells(results, by("split"), "split")),
    ]


def headline_cells(results: dict) -> list[list[tuple[str, str, bool]]]:
    """The verdict table's cells: every scored model, its score (copy-last-frame and the perfect model are 0 and 100
    by definition) and the raw metrics beside it."""
    table, metrics = {(r["model"], r["given"]): r for r in results["table"]}, results["metrics"]
    anchors = {"baseline": "0", "ceiling": "100"}
    cells = []
    for s in results.get("scores", []):
        r, kind = table[s["model"], s["given"]], results["kinds"].get(s["model"])
        score = (anchors[kind], "by definition") if kind in anchors else _score_text(s)
        cells.append([(s["model"], "", False), (f"{s['given']} given", "", False), (*score, False)] + [
            (_fmt(r[m], metrics[m]["digits"]), _ci(r["ci"][m], metrics[m]["digits"]), False)
            for m in HEADLINE_METRICS])
    return cells


# ---- text -------------------------------------------------------------------------------------------------------

def settings(results: dict) -> list[tuple[str, str]]:
    """(what, details) lines for the top of the report: checkpoint, training, evaluation settings."""
    c, t = results["config"], results.get("training", {})
    of = lambda done, planned, unit: (f"{unit} not recorded" if done is None else  # noqa: E731
                                      f"{done}" + (f" of {planned}" if planned else "") + f" {unit}")
    training = ", ".join(x for x in (
        of(t.get("steps"), t.get("planned_steps"), "steps"),
        of(t.get("minutes"), t.get("max_minutes"), "minutes"),
        f"model {t['model']}" if t.get("model") else "",
        f"{t['frames']} frames of {t['size'][0]}x{t['size'][1]}" if t.get("frames") and t.get("size") else "",
        f"data {', '.join(t['data'])}" if t.get("data") else "data not recorded",
        f"tokenizer {t['tokenizer']}" if t.get("tokenizer") else "",
        f"post-trained from {t['init_from']}" if t.get("init_from") else "") if x)
    evaluation = (f"scenarios {', '.join(c['scenarios'])}; splits {', '.join(c['splits'])}; {c['episodes']} "
                  f"episode(s) per scenario and split ({len(results['episodes'])} in all); {c['horizon']} predicted "
                  f"frames after {' or '.join(map(str, c['given']))} given; conditions {', '.join(c['conditions'])}; "
                  f"{c['steps']} {c['sampler']} sampler steps; seed {c['seed']}; perfect model: up to "
                  f"{c['ceiling_draws']} re-simulations per episode; intervals: {RESAMPLES} bootstrap resamples of "
                  f"episodes; device {c['device']}; {results['seconds']} s")
    return [("Checkpoint", results["checkpoint"]), ("Training", training), ("Evaluation", evaluation)]


def how_to_read(results: dict) -> list[tuple[str, str]]:
    """(term, definition) pairs: conditions, models, score, metrics, intervals, marks, player."""
    score_metrics = ", ".join(results["metrics"][m]["label"] for m in SCORE_METRICS)
    terms = [
        ("k given", "the model sees the first k true frames of a held-out episode and predicts the next "
                    f"{results['config']['horizon']}; every metric is over the predicted frames only."),
        ("Conditions", "what the world model gets besides the given frames: text+actions (the episode's caption "
                       "and the agent's true actions), text, actions, or none."),
        ("copy last frame", "the baseline: holds the last given frame. A model must beat it to show it predicts "
                            "motion. Score 0."),
        ("perfect model", "the ceiling: a re-simulation with the parameters the model cannot see (restitution, "
                          "gravity, ...) drawn again and kept only if it agrees with the given frames, caption and "
                          "actions: what a perfect generative model would produce. Score 100."),
        ("tokenizer reconstruction", "a reference, not a competitor: the tokenizer's encode-decode of the true "
                                     "future, the best a model generating in that latent space can look."),
        ("Score", f"physics-alignment score: per metric 100 x (model - copy) / (perfect - copy), averaged over "
                  f"{score_metrics} (those where the perfect model beats copy-last-frame beyond the interval). "
                  "0 = no better than holding the last frame, 100 = as good as a perfect model."),
    ]
    terms += [(_label(info), info["about"] + ".") for info in results["metrics"].values()]
    terms += [
        ("Intervals", f"{LEVEL}% bootstrap intervals: episodes resampled with replacement {RESAMPLES} times; "
                      "differences between two models resample the same episodes for both (paired). With few "
                      "episodes they are wide: read overlapping intervals as 'no clear difference'."),
        ("Bold", "the best value of a column among world models and copy-last-frame with the same given frames."),
        ("Player", "truth | generated | difference, the given frames framed in orange, the predicted ones in white; "
                   "it opens on the first predicted frame. Play/pause, or drag the slider to step."),
    ]
    return terms


def to_markdown(results: dict) -> str:
    """report.md: the same content as report.html, with links to plots and videos."""
    lines = ["# Physics-alignment report", ""]
    lines += [f"- **{k}**: {v}" for k, v in settings(results)] + ["", "## Verdict", ""]
    metrics = results["metrics"]
    lines += [f"- {v['text']}" for v in results.get("verdicts", [])] + [""]
    lines += ["| Model | Condition | Score (95% CI) | " + " | ".join(_label(metrics[m]) for m in HEADLINE_METRICS)
              + " |", "|" + "---|" * (3 + len(HEADLINE_METRICS))]
    lines += ["| " + " | ".join(_md_cell(c) for c in row) + " |" for row in headline_cells(results)]
    lines += ["", "## How to read this", ""] + [f"- **{k}**: {v}" for k, v in how_to_read(results)] + [""]
    for title, header, cells in _sections(results):
        lines += [f"## {title}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(_md_cell(c) for c in row) + " |" for row in cells] + [""]
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


def _md_cell(cell: tuple[str, str, bool]) -> str:
    text, ci, best = cell
    return (f"**{text}**" if best else text) + (f" [{ci}]" if ci else "")


# ---- HTML -------------------------------------------------------------------------------------------------------

def _data_uri(path: Path, mime: str) -> str:
    return f"data:{mime};base64,{base64.b64encode(path.read_bytes()).decode()}"


def _html_cell(cell: tuple[str, str, bool]) -> str:
    text, ci, best = cell
    inner = html.escape(text) + (f"<span class='ci'>{html.escape(ci)}</span>" if ci else "")
    return f"<td class='best'>{inner}</td>" if best else f"<td>{inner}</td>"


def _html_table(header: list[str], cells: list[list[tuple[str, str, bool]]], cls: str = "") -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(_html_cell(c) for c in row) + "</tr>" for row in cells)
    return f"<table class='{cls}'><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def player(out: Path, mp4: str, gif: str | None, given: int, title: str) -> str:
    """A player over the frame strip beside `mp4`: play/pause, a frame slider and a counter that says whether the
    frame was given or predicted; links to the mp4 (and GIF)."""
    with Image.open(out / strip_path(mp4)) as strip:
        (width, total_height), frames, fps = strip.size, int(strip.text["frames"]), float(strip.text["fps"])
    height = total_height // frames
    s = _scale(height)
    w, h = width * s, height * s
    links = f'<a href="{html.escape(mp4)}">mp4</a>' + (f' <a href="{html.escape(gif)}">gif</a>' if gif else "")
    return (f"<figure class='player' data-frames='{frames}' data-given='{given}' data-fps='{fps:g}' "
            f"data-height='{h}'><div class='screen' style='width:{w}px;height:{h}px'>"
            f"<img src='{_data_uri(out / strip_path(mp4), 'image/png')}' style='width:{w}px' "
            f"alt='{html.escape(title)}'></div><div class='panels' style='width:{w}px'><span>truth</span>"
            "<span>generated</span><span>difference</span></div><div class='controls'><button type='button'>"
            f"▶ play</button><input type='range' min='0' max='{frames - 1}' value='{min(given, frames - 1)}' "
            f"aria-label='frame'><span class='counter'></span> {links}</div>"
            f"<figcaption>{html.escape(title)}</figcaption></figure>")


PLAYER_JS = """
document.querySelectorAll('.player').forEach(p => {
  const img = p.querySelector('img'), slider = p.querySelector('input'), button = p.querySelector('button');
  const counter = p.querySelector('.counter'), n = +p.dataset.frames, given = +p.dataset.given;
  let timer = null;
  const show = i => {
    slider.value = i;
    img.style.transform = `translateY(${-i * p.dataset.height}px)`;
    const kind = i < given ? 'given' : 'predicted';
    counter.textContent = `frame ${i + 1} / ${n} · ${kind}`;
    counter.className = 'counter ' + kind;
  };
  const stop = () => { clearInterval(timer); timer = null; button.textContent = '▶ play'; };
  button.onclick = () => {
    if (timer) return stop();
    timer = setInterval(() => show((+slider.value + 1) % n), 1000 / +p.dataset.fps);
    button.textContent = '❚❚ pause';
  };
  slider.oninput = () => { stop(); show(+slider.value); };
  show(+slider.value);
});
"""

STYLE = ("body{font-family:sans-serif;margin:2em;max-width:80em;line-height:1.4}table{border-collapse:collapse;"
         "margin:1em 0}td,th{border:1px solid #ccc;padding:.3em .6em;text-align:right;vertical-align:top}"
         "td:first-child,th:first-child{text-align:left}.ci{display:block;font-size:.8em;color:#666}"
         ".best{font-weight:bold;background:#e6f4e6}.headline td:nth-child(3){font-size:1.4em;font-weight:bold}"
         ".settings th{text-align:left;background:#f6f6f6}.settings td{text-align:left}"
         ".verdicts li{margin:.4em 0}dl{display:grid;grid-template-columns:max-content auto;gap:.3em 1em}"
         "dt{font-weight:bold}dd{margin:0}.plot{max-width:100%;display:block;margin:1em 0}"
         ".gallery{display:flex;flex-wrap:wrap;gap:1.5em}figure{margin:0}.screen{overflow:hidden}"
         ".screen img{image-rendering:pixelated;display:block}.panels{display:flex;justify-content:space-around;"
         "font-size:.9em;color:#444}.controls{display:flex;align-items:center;gap:.6em;margin:.3em 0}"
         ".controls input{flex:1}.counter{font-variant-numeric:tabular-nums;min-width:12em}"
         f".counter.given{{color:rgb{GIVEN_COLOUR};font-weight:bold}}.ok{{color:#070}}.blocked{{color:#b00}}")


def to_html(results: dict, out: Path) -> str:
    """report.html: the same content as report.md, self-contained (plots and frame strips inline as base64)."""
    out = Path(out)
    metrics = results["metrics"]
    body = ["<h1>Physics-alignment report</h1>", "<table class='settings'>" + "".join(
        f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in settings(results)) + "</table>",
            "<h2 id='verdict'>Verdict</h2>"]
    body.append("<ul class='verdicts'>" + "".join(f"<li><strong>{html.escape(v['head'])}</strong> "
                                                  f"{html.escape(v['details'])}</li>"
                                                  for v in results.get("verdicts", [])) + "</ul>")
    head = ["Model", "Condition", f"Physics-alignment score ({LEVEL}% CI)"] + [
        _label(metrics[m]) + (" ↑" if metrics[m]["higher_is_better"] else " ↓") for m in HEADLINE_METRICS]
    body.append(_html_table(head, headline_cells(results), "headline"))
    body.append("<h2 id='how-to-read'>How to read this</h2><dl>" + "".join(
        f"<dt>{html.escape(k)}</dt><dd>{html.escape(v)}</dd>" for k, v in how_to_read(results)) + "</dl>")
    for title, header, cells in _sections(results):
        body += [f"<h2>{html.escape(title)}</h2>", _html_table(header, cells)]
    body.append("<h2 id='horizon'>Metrics vs prediction horizon</h2>")
    body += [f'<img class="plot" src="{_data_uri(out / p, "image/png")}" alt="{m} vs horizon">'
             for m, p in results.get("plots", {}).items()]
    body.append("<h2 id='videos'>Side-by-side videos</h2><div class='gallery'>")
    body += [player(out, v["mp4"], v["gif"], v["given"], v["title"]) for v in results["videos"]]
    body.append("</div>")
    if results.get("generations"):
        rows_html = "".join(
            f"<tr><td>{html.escape(g['title'])}</td><td>{html.escape(g['prompt'])}</td>"
            f"<td class='{'ok' if g['allowed'] else 'blocked'}'>{'allowed' if g['allowed'] else 'blocked'}</td>"
            f"<td>{html.escape(g['guard'])}</td><td>{html.escape(g['reason'])}</td><td>"
            + (player(out, g["video"], g.get("gif"), g.get("given", 0), g["title"])
               if g.get("video") else "–") + "</td></tr>" for g in results["generations"])
        body += ["<h2>Guarded generations</h2>", "<table><thead><tr><th>Title</th><th>Prompt</th><th>Verdict</th>"
                 f"<th>Guard</th><th>Reason</th><th>Video</th></tr></thead><tbody>{rows_html}</tbody></table>"]
    return ("<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'><title>Physics-alignment report</title>"
            f"<style>{STYLE}</style></head><body>\n" + "\n".join(body) + f"\n<script>{PLAYER_JS}</script>\n"
            "</body></html>\n")


def write_report(results: dict, out: str | os.PathLike) -> Path:
    """Write plots/, results.json, report.md and report.html into `out` (each file atomically); returns the HTML."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    results["plots"] = plot_horizon(results, out)
    write_text(out / "results.json", json.dumps(results, indent=1, allow_nan=False))
    write_text(out / "report.md", to_markdown(results))
    write_text(out / "report.html", to_html(results, out))
    return out / "report.html"
