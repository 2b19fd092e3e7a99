"""`cosmos-lite demo` end to end on a shrunken default (seconds of training): every stage runs, the report shows the
guarded generations (one allowed, one blocked) and a rerun finds every stage cached."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
STAGES = ("simulate", "curate", "tokenizer", "wfm", "generate", "eval")


def demo(out: Path) -> subprocess.CompletedProcess:
    args = [f"out={out}", "sim.scenarios=[pusher]", "sim.episodes=6", "tokenizer.minutes=0.05", "wfm.minutes=0.05",
            "eval.episodes=1"]
    return subprocess.run([sys.executable, "-m", "cosmos_lite.cli", "demo", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=600, env={**os.environ, "COSMOS_LITE_QUIET": "0"})


def test_demo_runs_every_stage_then_caches_them(tmp_path, sintel_10s):
    out = tmp_path / "demo"
    r = demo(out)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "report: " in r.stdout and (out / "report" / "report.html").is_file()
    results = json.loads((out / "report" / "results.json").read_text())
    gens = {g["title"].split(":")[0]: g for g in results["generations"]}
    assert not gens["blocked by the pre-guard"]["allowed"] and gens["blocked by the pre-guard"]["video"] is None
    assert not list((out / "generate").glob("blocked*.mp4"))
    sidecar = json.loads((out / "generate" / "allowed_pusher.json").read_text())
    assert sidecar["status"] == "ok" and sidecar["config"]["wfm"]["minutes"] == 0.05
    assert {r["model"].split(" (")[0] for r in results["table"]} == {"world model", "copy last frame", "perfect model",
                                                                      "tokenizer reconstruction"}
    sources = {json.loads(m.read_text())["source"] for m in (out / "curated" / "metas").glob("*.json")}
    assert any("sintel" in s for s in sources) and any("pusher" in s for s in sources)
    again = demo(out)
    assert again.returncode == 0, again.stderr[-3000:]
    assert all(f"[{s}] cached" in again.stderr for s in STAGES)


def test_a_changed_stage_starts_over_and_reruns_the_stages_after_it(tmp_path):
    from cosmos_lite.demo import Stages

    calls = []

    def stage(name: str, output: Path):
        def fn():
            calls.append(name)
            kept = sorted(p.name for p in output.glob("*")) if output.exists() else []
            output.mkdir(parents=True, exist_ok=True)
            (output / f"{name}.txt").write_text(name)
            return {"kept": kept}
        return fn

    def pipeline(minutes: float, force: bool = False) -> dict:
        stages = Stages(tmp_path, force)
        a = stages.run("a", {"n": 1}, stage("a", tmp_path / "a"), output=tmp_path / "a")
        b = stages.run("b", {"minutes": minutes}, stage("b", tmp_path / "b"), output=tmp_path / "b")
        c = stages.run("c", {}, stage("c", tmp_path / "c"), output=tmp_path / "c")
        return {"a": a, "b": b, "c": c}

    pipeline(1)
    assert calls == ["a", "b", "c"]
    pipeline(1)
    assert calls == ["a", "b", "c"]  # all cached
    out = pipeline(2)  # b's key changed: b starts over from an empty folder, c reruns although its key did not change
    assert calls == ["a", "b", "c", "b", "c"] and out["b"]["kept"] == [] and out["c"]["kept"] == []
    (tmp_path / ".stages" / "b.json").write_text(json.dumps({"key": {"minutes": 3}, "status": "running"}))
    (tmp_path / "b" / "checkpoint").write_text("")
    out = pipeline(3)  # b was interrupted with the same key: its output is kept, so training resumes
    assert calls[-2:] == ["b", "c"] and "checkpoint" in out["b"]["kept"]
    pipeline(3, force=True)
    assert calls[-3:] == ["a", "b", "c"]
