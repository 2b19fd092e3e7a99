"""Physics-alignment benchmark end to end on the tiny world model: results.json, the verdict (score, intervals),
tables, plots, players and videos, HTML in headless Chromium, compare as a CI gate, the perfect-model ceiling, and
errors."""

from __future__ import annotations

import copy
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch
from PIL import Image

from cosmos_lite.cli import main
from cosmos_lite.core.metrics import nanmean, object_iou_per_frame, psnr_per_frame
from cosmos_lite.eval.ceiling import VISIBLE, PerfectModel, ceiling
from cosmos_lite.eval.physics import CopyLastFrame, EvalConfig, heldout_episodes
from cosmos_lite.eval.report import GIVEN_COLOUR, PREDICTED_COLOUR, strip_path, table_cells, write_report
from cosmos_lite.sim import SPECS, simulate
from cosmos_lite.video import probe

ARGS = ["episodes=2", "steps=1", "given=[1,5]", "horizon=4", "scenarios=[pusher]", "conditions=[text+actions,none]"]
MODELS = ["world model (text+actions)", "world model (none)", "copy last frame", "tokenizer reconstruction",
          "perfect model"]
SCORED = ("iou", "spatial_iou", "spatiotemporal_iou", "weighted_spatial_iou")
CHROMIUM = Path("/usr/bin/chromium")


@pytest.fixture(scope="module")
def run(tiny_wfm, tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("eval") / "report"
    assert main(["eval", "physics", f"checkpoint={tiny_wfm}", f"out={out}", *ARGS]) == 0
    return out, json.loads((out / "results.json").read_text())


def _markdown_tables(text: str) -> list[list[list[str]]]:
    """Every table of a markdown file as rows of cells (header and rule dropped)."""
    tables, current = [], None
    for line in text.splitlines():
        if line.startswith("|"):
            if current is None:
                current = []
                tables.append(current)
            current.append([c.strip() for c in line.strip("|").split("|")])
        else:
            current = None
    return [t[2:] for t in tables]


def _episode_means(results: dict, model: str, given: int, metric: str, **where) -> list[float]:
    return [r["mean"][metric] for r in results["records"] if r["model"] == model and r["given"] == given
            and all(r[k] == v for k, v in where.items()) and r["mean"][metric] is not None]


def _md(cell: tuple[str, str, bool]) -> str:
    text, ci, best = cell
    return (f"**{text}**" if best else text) + (f" [{ci}]" if ci else "")


def test_run_scores_every_model_condition_split_and_given_count(run):
    out, results = run
    assert results["models"] == MODELS
    assert results["kinds"] == dict(zip(MODELS, ["world model", "world model", "baseline", "reference", "ceiling"]))
    assert [(r["model"], r["given"]) for r in results["table"]] == [(m, k) for k in (1, 5) for m in MODELS]
    assert {r["split"] for r in results["by_split"]} == {"id", "ood"}
    assert {r["scenario"] for r in results["by_scenario"]} == {"pusher"}
    assert len(results["records"]) == 4 * 2 * len(MODELS)  # episodes x given x models
    for r in results["records"]:
        assert set(r["per_frame"]) == set(results["metrics"]) and all(len(v) == 4 for v in r["per_frame"].values())
    assert results["config"]["horizon"] == 4 and results["config"]["seed"] == 0
    assert set(results["seeds"]["episodes"]) == {e["name"] for e in results["episodes"]}
    # The copy baseline, recomputed from the recorded seeds, gives the recorded numbers.
    ep_info = results["episodes"][1]
    ep = simulate("pusher", ep_info["seed"], split=ep_info["split"], frames=9, size=(32, 32))
    rec = next(r for r in results["records"] if r["model"] == "copy last frame" and r["given"] == 5
               and r["episode"] == ep_info["name"])
    expected = psnr_per_frame(np.repeat(ep.frames[4:5], 4, axis=0), ep.frames[5:9])
    np.testing.assert_allclose(rec["per_frame"]["psnr"], expected)
    assert ep.meta["caption"] == ep_info["caption"]
    assert rec["per_frame"]["spatiotemporal_iou"] == [0.0] * 4  # nothing moves in a held frame; the pusher does
    perfect = next(r for r in results["records"] if r["model"] == "perfect model" and r["given"] == 5
                   and r["episode"] == ep_info["name"])
    assert perfect["mean"]["iou"] > rec["mean"]["iou"]


def test_headline_score_is_normalised_between_copy_and_perfect_model(run):
    out, results = run
    html, md = (out / "report.html").read_text(), (out / "report.md").read_text()
    assert {(s["model"], s["given"]) for s in results["scores"]} == {(m, k) for m in MODELS for k in (1, 5)}
    for s in results["scores"]:
        k = s["given"]
        mean = {m: {x: np.mean(_episode_means(results, m, k, x)) for x in SCORED}
                for m in (s["model"], "copy last frame", "perfect model")}
        assert s["metrics"] and set(s["metrics"]) <= set(SCORED)
        assert all(mean["perfect model"][x] > mean["copy last frame"][x] for x in s["metrics"])
        expected = np.mean([100 * (mean[s["model"]][x] - mean["copy last frame"][x])
                            / (mean["perfect model"][x] - mean["copy last frame"][x]) for x in s["metrics"]])
        assert s["score"] == pytest.approx(expected)
        assert s["ci"][0] <= s["score"] + 1e-9 and s["score"] <= s["ci"][1] + 1e-9
        if s["model"] == "copy last frame" or s["model"] == "perfect model":
            assert s["score"] == pytest.approx(0 if s["model"] == "copy last frame" else 100)
            continue
        # The headline table shows the score and its interval; the verdict sentence says it in words.
        cell = f"<td>{s['score']:.1f}<span class='ci'>{s['ci'][0]:.1f} to {s['ci'][1]:.1f}</span></td>"
        assert f"<td>{s['model']}</td><td>{k} given</td>{cell}" in html
        if s["model"].startswith("world model"):
            sentence = next(v["text"] for v in results["verdicts"] if v["model"] == s["model"] and v["given"] == k)
            assert sentence.startswith(f"{s['model']}, {k} given: physics-alignment score "
                                       f"{s['score']:.1f} (95% CI ")
            assert "Against copy-last-frame" in sentence and "object IoU (" in sentence
            verdict = next(v for v in results["verdicts"] if v["model"] == s["model"] and v["given"] == k)
            assert f"<li><strong>{verdict['head']}</strong> {verdict['details']}</li>" in html
            assert f"- {sentence}" in md
    assert "<td>copy last frame</td><td>1 given</td><td>0<span class='ci'>by definition</span></td>" in html
    assert html.index("id='verdict'") < html.index("id='how-to-read'") < html.index("<h2>All held-out episodes")
    assert all(f"<dt>{term}</dt>" in html for term in ("k given", "Conditions", "copy last frame", "perfect model",
                                                         "Score", "spatial IoU", "weighted spatial IoU",
                                                         "velocity error (px/frame)", "Intervals"))
    assert f"<td>{results['checkpoint']}</td>" in html and "Training" in html and "steps not recorded" in html


def test_every_metric_has_an_interval_and_the_best_is_marked(run):
    out, results = run
    spread = 0
    for key in ("table", "by_scenario", "by_split"):
        for row in results[key]:
            where = {k: row[k] for k in ("scenario", "split") if k in row}
            for m in results["metrics"]:
                values = _episode_means(results, row["model"], row["given"], m, **where)
                lo, hi = row["ci"][m]
                if not values:
                    assert row[m] is None and lo is None
                    continue
                assert min(values) - 1e-9 <= lo <= row[m] + 1e-9 and row[m] - 1e-9 <= hi <= max(values) + 1e-9
                spread += hi > lo
    assert spread > 0  # the episodes differ, so some interval is not a point
    for row in results["horizon"]:
        assert all(len(row["ci"][m][0]) == len(row["ci"][m][1]) == 4 for m in results["metrics"])
    tables = _markdown_tables((out / "report.md").read_text())
    cells = table_cells(results, results["table"], score=True)
    assert tables[1] == [[_md(c) for c in row] for row in cells]
    html = (out / "report.html").read_text()
    for k in (1, 5):  # the best object IoU among world models and copy-last-frame is marked, and only it
        rows = [(i, r) for i, r in enumerate(results["table"]) if r["given"] == k
                and results["kinds"][r["model"]] in ("world model", "baseline")]
        top = max(r["iou"] for _, r in rows)
        col = 3 + list(results["metrics"]).index("iou")
        for i, r in rows:
            assert cells[i][col][2] == (r["iou"] == top)
        i_best = next(i for i, r in rows if r["iou"] == top)
        assert f"<td class='best'>{cells[i_best][col][0]}<span class='ci'>{cells[i_best][col][1]}</span>" in html
    ref = MODELS.index("perfect model")
    assert not any(best for _, _, best in cells[ref])  # references are never marked
    copy_row = next(r for r in results["table"] if r["model"] == "copy last frame" and r["given"] == 1)
    assert copy_row["psnr"] == pytest.approx(np.mean(_episode_means(results, "copy last frame", 1, "psnr")))


def test_plots_players_and_given_frames(run):
    out, results = run
    assert set(results["plots"]) == set(results["metrics"])
    for path in results["plots"].values():
        with Image.open(out / path) as im:
            assert im.format == "PNG" and im.size[0] >= 1000  # two panels, shown at 100% in the HTML
    html = (out / "report.html").read_text()
    assert len(results["videos"]) == 4 and html.count("<figure class='player'") == 4  # 1 per split x 2 given counts
    for v in results["videos"]:
        n = v["given"] + 4
        info = probe(out / v["mp4"])
        assert info.num_frames == n
        assert (info.width, info.height) == (6 * (3 * 32 + 8), 6 * 36)  # 3 panels, separators, frame; upscaled
        with Image.open(out / v["gif"]) as gif:
            assert (gif.format, gif.size, gif.n_frames) == ("GIF", (3 * 32 + 8, 36), n)
        with Image.open(out / strip_path(v["mp4"])) as strip:  # the player's frames, stacked, lossless
            assert strip.text["frames"] == str(n) and strip.size == (3 * 32 + 8, 36 * n)
            frames = np.asarray(strip.convert("RGB")).reshape(n, 36, 3 * 32 + 8, 3)
        for i, f in enumerate(frames):  # given frames framed in orange, predicted ones in white
            colour = GIVEN_COLOUR if i < v["given"] else PREDICTED_COLOUR
            assert (f[[0, 1, -2, -1]] == colour).all() and (f[:, [0, 1, -2, -1]] == colour).all()
        assert (f"data-frames='{n}' data-given='{v['given']}' data-fps='16'" in html
                and f"<a href=\"{v['mp4']}\">mp4</a>" in html)
    assert "<button type='button'>▶ play</button>" in html and "type='range'" in html and "class='counter'" in html
    assert "<img class=\"video\"" not in html and "image/gif" not in html  # players replace the GIF loops
    assert not list(out.rglob("*.tmp*"))


def _chromium() -> str:
    if not CHROMIUM.is_file():
        pytest.skip(f"{CHROMIUM} not found (Debian: apt-get install chromium); the browser checks need it")
    return str(CHROMIUM)


def _chromium_run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([_chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                           "--allow-file-access-from-files", *args], capture_output=True, text=True, timeout=120)


def test_html_in_headless_chromium_images_decode_and_the_player_steps(run, tmp_path):
    out, results = run
    # A harness page loads the report in a frame, lists images that failed to decode and drives the first player
    # of 5 given frames: it opens on the first predicted frame; the slider steps back to a given one; play toggles.
    harness = tmp_path / "harness.html"
    harness.write_text(
        f"<html><body><iframe id='r' src='{(out / 'report.html').as_uri()}'></iframe><script>"
        "window.onload = () => { const d = document.getElementById('r').contentDocument;"
        "const imgs = [...d.images]; const bad = imgs.filter(i => !i.complete || i.naturalWidth === 0);"
        "const p = d.querySelector(\"figure.player[data-given='5']\"); const c = p.querySelector('.counter');"
        "const first = c.textContent; const s = p.querySelector('input'); s.value = 0;"
        "s.dispatchEvent(new Event('input')); const given = c.textContent + '|' + c.className;"
        "p.querySelector('button').click(); const playing = p.querySelector('button').textContent;"
        "p.querySelector('button').click();"
        "document.body.setAttribute('data-result', [`images=${imgs.length}`, `broken=${bad.length}`,"
        "`tables=${d.querySelectorAll('table').length}`, first, given, playing].join(';')); };"
        "</script></body></html>")
    proc = _chromium_run("--enable-logging=stderr", "--v=0", "--dump-dom", harness.as_uri())
    assert proc.returncode == 0, proc.stderr[-2000:]
    console = [line for line in proc.stderr.splitlines() if "CONSOLE" in line or "Uncaught" in line]
    assert not console, console
    assert 'data-result="images=' in proc.stdout, proc.stdout[-500:]
    images, broken, tables, first, given, playing = proc.stdout.split('data-result="')[1].split('"')[0].split(";")
    assert (images, broken, tables) == (f"images={len(results['metrics']) + 4}", "broken=0", "tables=5")
    assert first == "frame 6 / 9 · predicted"
    assert given == "frame 1 / 9 · given|counter given"
    assert playing == "❚❚ pause"


def test_chromium_screenshot_of_the_report_top(run, tmp_path):
    out, _ = run
    png = tmp_path / "top.png"
    proc = _chromium_run("--window-size=1280,900", f"--screenshot={png}", (out / "report.html").as_uri())
    assert proc.returncode == 0 and png.is_file(), proc.stderr[-2000:]
    with Image.open(png) as im:
        assert im.size == (1280, 900)
        pixels = np.asarray(im.convert("RGB")).reshape(-1, 3)
    assert (pixels.max(1) < 80).mean() > 0.005  # text was drawn (dark pixels)
    assert (np.all(pixels == [230, 244, 230], axis=1)).any() or len(np.unique(pixels, axis=0)) > 20


def test_guarded_generations_section(run, tmp_path):
    out, results = run
    shutil.copytree(out, tmp_path / "demo")
    extra = copy.deepcopy(results)
    video = results["videos"][0]
    extra["generations"] = [
        {"title": "ball", "prompt": "a red ball <bounces>", "allowed": True, "guard": "all", "reason": "ok",
         "video": video["mp4"], "gif": video["gif"]},
        {"title": "unsafe", "prompt": "something bad", "allowed": False, "guard": "blocklist",
         "reason": "blocked word", "video": None, "gif": None},
    ]
    html = write_report(extra, tmp_path / "demo").read_text()
    assert "Guarded generations" in html and "a red ball &lt;bounces&gt;" in html
    assert html.count("class='blocked'") == 1 and html.count("class='ok'") == 1
    assert html.count("<figure class='player'") == len(results["videos"]) + 1
    md = (tmp_path / "demo" / "report.md").read_text()
    assert "| unsafe | something bad | blocked | blocklist | blocked word | – |" in md
    assert json.loads((tmp_path / "demo" / "results.json").read_text())["generations"][1]["allowed"] is False


def test_compare_gates_a_regression_beyond_its_interval(run, tmp_path, capsys, caplog):
    out, results = run
    a = str(out / "results.json")
    capsys.readouterr()
    assert main(["eval", "compare", a, a, "fail_on=iou"]) == 0  # a run against itself
    text = capsys.readouterr().out
    assert "no regression beyond the 95% interval on iou" in text
    assert re.search(r"world model \(text\+actions\)\s+1 given\s+object IoU\s", text)
    lowered = copy.deepcopy(results)
    for r in lowered["records"]:
        if r["model"].startswith("world model"):
            r["mean"]["iou"] -= 0.2
            r["per_frame"]["iou"] = [v - 0.2 for v in r["per_frame"]["iou"]]
    lowered["config"]["steps"] = 2
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "results.json").write_text(json.dumps(lowered))
    with caplog.at_level("WARNING"):
        assert main(["eval", "compare", a, str(tmp_path / "b"), "fail_on=iou"]) == 1
    assert "steps: 1 vs 2" in caplog.text
    captured = capsys.readouterr()
    assert "REGRESSION world model (text+actions), 1 given: object IoU" in captured.err
    assert "REGRESSION world model (none), 5 given: object IoU" in captured.err
    rows = [re.split(r"\s{2,}", line) for line in captured.out.splitlines()]
    row = next(r for r in rows if r[:3] == ["world model (none)", "1 given", "object IoU"])
    assert row[5] == "-0.200" and row[6] == "-0.200 to -0.200" and row[7] == "worse"
    assert main(["eval", "compare", a, str(tmp_path / "b"), "fail_on=[psnr,ssim]"]) == 0  # untouched metrics
    assert main(["eval", "compare", a, str(tmp_path / "b"), "fail_on=score"]) == 1  # IoU is part of the score
    assert main(["eval", "compare", a, str(tmp_path / "b")]) == 0  # no gate: a report only
    assert main(["eval", "compare", a, a, "fail_on=fps"]) == 2
    assert "fail_on: unknown metric(s) fps" in capsys.readouterr().err
    assert main(["eval", "compare", a, str(tmp_path / "missing.json")]) == 4


def test_perfect_model_is_a_consistent_resimulation():
    assert set(VISIBLE) == set(SPECS) and all(set(v) <= set(SPECS[s]) for s, v in VISIBLE.items())
    ep = simulate("bounce", 7, frames=25)
    iou, kept = ceiling(ep, 1, 40, np.random.default_rng(0))
    copy_iou = nanmean(object_iou_per_frame(np.repeat(ep.masks[:1], 16, axis=0), ep.masks[1:17]))
    assert kept > 0 and iou > copy_iou
    model = PerfectModel(horizon=16, proposals=40, seed=0)
    pred = model.predict(ep, 9, True, True)
    assert pred.shape == (16, 64, 64, 3) and np.array_equal(pred, model.predict(ep, 9, True, True))
    copy_psnr = psnr_per_frame(np.repeat(ep.frames[8:9], 16, axis=0), ep.frames[9:25]).mean()
    assert psnr_per_frame(pred, ep.frames[9:25]).mean() > copy_psnr


def test_training_details_come_from_the_checkpoint(tiny_wfm, tmp_path):
    from omegaconf import OmegaConf
    from safetensors.torch import save_file

    from cosmos_lite.eval.physics import training_details

    ckpt = shutil.copytree(tiny_wfm, tmp_path / "trained")
    cfg = OmegaConf.create({"trainer": {"steps": 200, "max_minutes": 5}, "data": {"roots": ["runs/sim"]},
                            "model": {"dim": 32, "depth": 2}})
    assert training_details(str(ckpt), cfg)["steps"] is None  # no train state: not recorded
    meta = {"step": "120", "minutes": "3.46", "config": "{}"}
    save_file({"x": torch.zeros(1)}, ckpt / "train_state.safetensors", metadata=meta)
    t = training_details(str(ckpt), cfg)
    assert (t["steps"], t["planned_steps"], t["minutes"], t["max_minutes"], t["data"], t["model"]) == (
        120, 200, 3.5, 5, ["runs/sim"], "dim 32, depth 2")


def test_heldout_episodes_are_deterministic_and_split():
    c = EvalConfig(scenarios=["bounce", "collision"], episodes=2, given=[1, 3], horizon=2)
    eps = heldout_episodes(c, (32, 32), 16.0)
    again = heldout_episodes(c, (32, 32), 16.0)
    assert [e.meta["name"] for e in eps] == [f"{s}_{p}_{i:03d}" for s in ("bounce", "collision")
                                             for p in ("id", "ood") for i in range(2)]
    assert all(np.array_equal(a.frames, b.frames) for a, b in zip(eps, again))
    assert len({e.meta["seed"] for e in eps}) == len(eps)
    assert all(e.frames.shape == (5, 32, 32, 3) for e in eps)
    r = eps[2].meta["params"]["radius"]  # bounce, ood: outside the in-distribution radius range
    assert not 3.0 <= r <= 5.0
    held = CopyLastFrame(2).predict(eps[0], 3, True, True)
    assert held.shape == (2, 32, 32, 3) and np.array_equal(held[1], eps[0].frames[2])


def test_bad_checkpoint_and_arguments(tiny_wfm, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["eval", "physics", f"checkpoint={tmp_path / 'nope'}", f"out={out}"]) == 4
    err = capsys.readouterr().err
    assert str(tmp_path / "nope") in err and "cosmos-lite train" in err
    corrupt = shutil.copytree(tiny_wfm, tmp_path / "corrupt")
    (corrupt / "model.safetensors").write_bytes(b"not a safetensors file")
    assert main(["eval", "physics", f"checkpoint={corrupt}", f"out={out}"]) == 4
    err = capsys.readouterr().err
    assert f"{corrupt}: unreadable world-model checkpoint" in err and "cosmos-lite train" in err
    assert not out.exists()
    assert main(["eval", "physics", f"out={out}"]) == 2
    assert main(["eval", "physics", "checkpoint=x", "scenarios=[juggling]"]) == 2
    assert main(["eval"]) == 2 and main(["eval", "fizz"]) == 2
    assert main(["eval", "physics", "nonsense_key=1"]) == 2
