"""`cosmos-lite generate` driven as a user would (subprocess) on a tiny checkpoint: every conditioning mix, batch
mode with a bad line, a blocked prompt, a bad checkpoint, a corrupt input video, guardrails switched off."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cosmos_lite.video import probe, read_frames, write_video

ROOT = Path(__file__).resolve().parent.parent


def generate(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "cosmos_lite.cli", "generate", "steps=2", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, tiny_wfm) -> Path:
    """A 32x32 image, a 12-frame video and an actions file beside a batch file with every conditioning mix."""
    d = tmp_path_factory.mktemp("gen_inputs")
    frames = np.zeros((12, 32, 32, 3), np.uint8)
    for i in range(12):
        frames[i, 10:20, i : i + 10] = (230, 40, 40)
    write_video(d / "clip.mp4", frames, fps=16)
    from PIL import Image

    Image.fromarray(frames[0]).save(d / "first.png")
    np.save(d / "push.npy", np.random.default_rng(0).normal(size=(40, 2)).astype(np.float32))
    requests = [
        {"prompt": "a red ball rolls to the right", "name": "text2world"},
        {"prompt": "a red ball rolls to the right", "input": "first.png", "name": "image2world"},
        {"input": "clip.mp4", "input_frames": 5, "name": "video2world"},
        {"prompt": "a pusher shoves the red block", "input": "first.png", "actions": "push.npy", "name": "actions"},
        {"prompt": "a red ball keeps rolling", "input": "clip.mp4", "actions": "push.npy", "num_frames": 21,
         "name": "long_rollout"},
        {"prompt": "a red ball", "input": "missing.mp4", "name": "bad_input"},
        {"prompt": "a red ball", "colour": "red"},
    ]
    (d / "batch.jsonl").write_text("\n".join(json.dumps(r) for r in requests) + "\n")
    return d


def test_batch_runs_every_conditioning_mix_and_survives_bad_lines(tiny_wfm, inputs, tmp_path):
    r = generate(f"checkpoint={tiny_wfm}", f"batch={inputs / 'batch.jsonl'}", f"output={tmp_path}")
    assert r.returncode == 4, r.stderr  # the worst line: an unreadable input
    lines = [json.loads(line) for line in r.stdout.splitlines()]
    assert [ln["status"] for ln in lines] == ["ok"] * 5 + ["failed"] * 2
    assert "missing.mp4" in lines[5]["error"] and "colour" in lines[6]["error"]
    expected = {"text2world": 9, "image2world": 9, "video2world": 9, "actions": 9, "long_rollout": 21}
    for name, n in expected.items():
        info = probe(tmp_path / f"{name}.mp4")
        assert (info.num_frames, info.height, info.width) == (n, 32, 32)
        side = json.loads((tmp_path / f"{name}.json").read_text())
        assert side["status"] == "ok" and side["frames"] == n and side["config"]["checkpoint"] == str(tiny_wfm)
        assert [v["guard"] for v in side["verdicts"] if v["allowed"]] and "generate" in side["timings_s"]
    given = read_frames(tmp_path / "video2world.mp4", end=5).astype(int)
    assert np.abs(given - read_frames(inputs / "clip.mp4", end=5)).mean() < 3  # given frames kept (through H.264)
    assert not list(tmp_path.glob("*.tmp*"))


def test_blocked_prompt_exits_3_and_writes_no_video(tiny_wfm, tmp_path):
    r = generate(f"checkpoint={tiny_wfm}", "prompt=a robot stabs a man to death with a knife", f"output={tmp_path}",
                 "name=blocked")
    assert r.returncode == 3, r.stderr
    verdict = json.loads(r.stdout)
    assert verdict["status"] == "blocked" and not verdict["verdicts"][-1]["allowed"]
    assert not list(tmp_path.glob("*.mp4")) and json.loads((tmp_path / "blocked.json").read_text())["video"] is None


def test_bad_checkpoint_and_corrupt_input_exit_with_clear_messages(tiny_wfm, tmp_path):
    r = generate(f"checkpoint={tmp_path / 'nowhere'}", "prompt=a ball falls", f"output={tmp_path / 'out'}")
    assert r.returncode == 4 and "nowhere" in r.stderr and "checkpoint" in r.stderr
    corrupt = tmp_path / "corrupt.mp4"
    corrupt.write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 8)
    r = generate(f"checkpoint={tiny_wfm}", "prompt=a ball falls", f"input={corrupt}", f"output={tmp_path / 'out'}")
    assert r.returncode == 4 and "corrupt.mp4" in r.stderr
    r = generate(f"checkpoint={tiny_wfm}", "prompt=  ", f"output={tmp_path / 'out'}")
    assert r.returncode == 2 and "empty" in r.stderr
    assert not list((tmp_path / "out").glob("*.mp4"))


def test_guardrails_off_needs_the_explicit_switch_and_warns(tiny_wfm, tmp_path):
    r = generate(f"checkpoint={tiny_wfm}", "prompt=a ball falls", "guardrails.enabled=false", f"output={tmp_path}",
                 "name=unguarded", "num_frames=5")
    assert r.returncode == 0, r.stderr
    assert "guardrails are OFF" in r.stderr
    assert json.loads((tmp_path / "unguarded.json").read_text())["verdicts"] == []
