"""Physics-alignment benchmark end to end on the tiny world model: results.json, tables, plots, videos, HTML in
headless Chromium, compare, and errors."""

from __future__ import annotations

import copy
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from cosmos_lite.cli import main
from cosmos_lite.core.metrics import psnr_per_frame
from cosmos_lite.eval.physics import CopyLastFrame, EvalConfig, heldout_episodes
from cosmos_lite.eval.report import table_cells, write_report
from cosmos_lite.sim import simulate
from cosmos_lite.video import probe

ARGS = ["episodes=1", "steps=1", "given=[1,5]", "horizon=4", "scenarios=[pusher]", "conditions=[text+actions,none]"]
MODELS = ["world model (text+actions)", "world model (none)", "copy last frame", "tokenizer reconstruction"]


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


def test_run_scores_every_model_condition_split_and_given_count(run):
    out, results = run
    assert results["models"] == MODELS
    assert [(r["model"], r["given"]) for r in results["table"]] == [(m, k) for k in (1, 5) for m in MODELS]
    assert {r["split"] for r in results["by_split"]} == {"id", "ood"}
    assert {r["scenario"] for r in results["by_scenario"]} == {"pusher"}
    assert len(results["records"]) == 2 * 2 * len(MODELS)  # episodes x given x models
    for r in results["records"]:
        assert all(len(v) == 4 for v in r["per_frame"].values())  # horizon
    for row in results["horizon"]:
        assert len(row["psnr"]) == 4
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


def test_report_tables_match_results_json(run):
    out, results = run
    tables = _markdown_tables((out / "report.md").read_text())
    assert tables[0] == table_cells(results, results["table"])
    assert tables[1] == table_cells(results, sorted(results["by_scenario"], key=lambda r: r["scenario"]), "scenario")
    assert tables[2] == table_cells(results, sorted(results["by_split"], key=lambda r: r["split"]), "split")
    row = tables[0][MODELS.index("copy last frame")]  # copy last frame, 1 given
    copy_row = next(r for r in results["table"] if r["model"] == "copy last frame" and r["given"] == 1)
    assert float(row[2]) == pytest.approx(copy_row["psnr"], abs=0.005)
    assert copy_row["psnr"] == pytest.approx(np.mean(
        [r["mean"]["psnr"] for r in results["records"] if r["model"] == "copy last frame" and r["given"] == 1]))
    html = (out / "report.html").read_text()
    assert all(f"<td>{c}</td>" in html for c in tables[0][0])


def test_plots_and_side_by_side_videos(run):
    out, results = run
    assert set(results["plots"]) == set(results["metrics"])
    for path in results["plots"].values():
        assert (out / path).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(results["videos"]) == 4  # 1 per split x 2 given counts
    for v in results["videos"]:
        info = probe(out / v["mp4"])
        assert info.num_frames == v["given"] + 4
        assert (info.width, info.height) == (4 * (3 * 32 + 4), 4 * 32)  # 3 panels + separators, upscaled to 128
        with Image.open(out / v["gif"]) as gif:  # native size, shown upscaled by the HTML
            assert (gif.format, gif.size, gif.n_frames) == ("GIF", (3 * 32 + 4, 32), v["given"] + 4)
    assert not list(out.rglob("*.tmp*"))


def test_html_opens_in_headless_chromium_without_errors(run, tmp_path):
    out, _ = run
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        pytest.skip("chromium not installed (Debian: apt-get install chromium); the HTML check needs it")
    # A harness page loads the report in a frame and lists images that failed to decode.
    harness = tmp_path / "harness.html"
    harness.write_text(
        f"<html><body><iframe id='r' src='{(out / 'report.html').as_uri()}'></iframe><script>"
        "window.onload = () => { const d = document.getElementById('r').contentDocument;"
        "const imgs = [...d.images]; const bad = imgs.filter(i => !i.complete || i.naturalWidth === 0);"
        "document.body.setAttribute('data-result', `images=${imgs.length} broken=${bad.length} "
        "tables=${d.querySelectorAll('table').length}`); };</script></body></html>")
    proc = subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--allow-file-access-from-files",
                           "--enable-logging=stderr", "--v=0", "--dump-dom", harness.as_uri()],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    console = [line for line in proc.stderr.splitlines() if "CONSOLE" in line or "Uncaught" in line]
    assert not console, console
    assert 'data-result="images=' in proc.stdout, proc.stdout[-500:]
    result = proc.stdout.split('data-result="')[1].split('"')[0]
    counts = dict(kv.split("=") for kv in result.split())
    assert int(counts["images"]) == 5 + 4 and counts["broken"] == "0" and counts["tables"] == "3"


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
    md = (tmp_path / "demo" / "report.md").read_text()
    assert "| unsafe | something bad | blocked | blocklist | blocked word | – |" in md
    assert json.loads((tmp_path / "demo" / "results.json").read_text())["generations"][1]["allowed"] is False


def test_compare_prints_differences(run, tmp_path, capsys):
    out, results = run
    changed = copy.deepcopy(results)
    changed["table"][0]["psnr"] += 1.5
    changed["table"] = changed["table"][:-1]
    (tmp_path / "b.json").write_text(json.dumps(changed))
    capsys.readouterr()
    assert main(["eval", "compare", str(out / "results.json"), str(tmp_path / "b.json")]) == 0
    lines = capsys.readouterr().out.splitlines()
    first = lines[1].split("\t")
    assert first[:2] == [MODELS[0], "1-frame"] and first[2].endswith("/ +1.50")
    assert lines[-1].endswith("only in A")
    assert main(["eval", "compare", str(out / "results.json"), str(tmp_path / "missing.json")]) == 4


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
