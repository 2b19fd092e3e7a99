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
            "eval.episodes=1", "eval.steps=1", "generate.steps=1"]
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
    assert {r["model"].split(" (")[0] for r in results["table"]} == {"world model", "copy last frame",
                                                                      "tokenizer reconstruction"}
    sources = {json.loads(m.read_text())["source"] for m in (out / "curated" / "metas").glob("*.json")}
    assert any("sintel" in s for s in sources) and any("pusher" in s for s in sources)
    again = demo(out)
    assert again.returncode == 0, again.stderr[-3000:]
    assert all(f"[{s}] cached" in again.stderr for s in STAGES)
