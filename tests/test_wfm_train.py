"""World-model training: a short run gives a loadable checkpoint; kill-and-resume continues the loss curve;
2-process torchrun (gloo) matches 1 process with the same global batch; LoRA post-training from a parent."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from safetensors.torch import load_file

from cosmos_lite.config import load_config
from cosmos_lite.models import WorldModelPipeline
from cosmos_lite.models.train import main as train_main
from cosmos_lite.sim import simulate, write_episode
from cosmos_lite.tokenizers import build_tokenizer

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def clips(tmp_path_factory) -> tuple[Path, Path]:
    """Six short 32x32 simulator episodes (pusher and bounce, with actions and captions) and a (randomly
    initialised) tiny tokenizer folder."""
    root = tmp_path_factory.mktemp("wfm_data")
    for i in range(6):
        write_episode(simulate(("pusher", "bounce")[i % 2], seed=i, frames=13, size=32), root, f"ep{i}")
    torch.manual_seed(0)
    tok = build_tokenizer("cv4x8x8", "tiny").save(root.parent / "tok")
    return root, tok


def overrides(clips, out: Path, **kw) -> list[str]:
    root, tok = clips
    args = {"data.roots": f"[{root}]", "tokenizer.path": str(tok), "out": str(out), "trainer.steps": 6,
            "trainer.ckpt_every": 2, "trainer.batch_size": 4, **kw}
    return ["experiment=wfm_tiny"] + [f"{k}={v}" for k, v in args.items()]


def losses(out: Path) -> dict[int, float]:
    return {r["step"]: r["loss"] for r in map(json.loads, (out / "log.jsonl").read_text().splitlines())}


def run_cli(args: list[str], nproc: int = 1) -> subprocess.Popen:
    env = {**os.environ, "COSMOS_LITE_QUIET": "1", "OMP_NUM_THREADS": "1"}
    launcher = [sys.executable, "-m", "cosmos_lite.cli"] if nproc == 1 else [
        str(Path(sys.executable).parent / "torchrun"), "--standalone", f"--nproc_per_node={nproc}", "-m",
        "cosmos_lite.cli"]
    return subprocess.Popen([*launcher, "train", *args], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


def test_train_writes_a_loadable_checkpoint_and_lora_post_training(clips, tmp_path):
    out = tmp_path / "run"
    assert train_main(load_config("train", overrides(clips, out)), []) == 0
    curve = losses(out)
    assert sorted(curve) == list(range(6)) and all(np.isfinite(list(curve.values())))
    pipe = WorldModelPipeline.from_pretrained(out)
    frames = pipe(video=np.zeros((1, 32, 32, 3), np.uint8), num_frames=9, steps=2).frames
    assert frames.shape == (9, 32, 32, 3)
    # specialist: LoRA adapters on the parent, merged into a plain DiT on export
    spec = tmp_path / "spec"
    assert train_main(load_config("train", overrides(clips, spec, **{
        "trainer.init_from": str(out), "trainer.lora_rank": 4, "tokenizer.path": "null"})), []) == 0
    parent, child = load_file(out / "model.safetensors"), load_file(spec / "model.safetensors")
    assert parent.keys() == child.keys()
    assert not torch.equal(parent["blocks.0.attn.qkv.weight"], child["blocks.0.attn.qkv.weight"])
    assert torch.equal(parent["x_embed.weight"], child["x_embed.weight"])  # outside the adapters: frozen
    assert torch.equal(load_file(out / "latent_stats.safetensors")["std"],
                       load_file(spec / "latent_stats.safetensors")["std"])


def test_wall_clock_budget_ends_training_with_a_checkpoint(clips, tmp_path):
    out = tmp_path / "budget"
    assert train_main(load_config("train", overrides(clips, out, **{
        "trainer.steps": 1000, "trainer.max_minutes": 1e-6})), []) == 0
    state = json.loads((out / "train_state.json").read_text())
    assert state["step"] == 1 and state["minutes"] > 1e-6  # stopped by time after one step, long before 1000
    assert sorted(losses(out)) == [0]
    WorldModelPipeline.from_pretrained(out)


def test_kill_and_resume_continues_the_loss_curve(clips, tmp_path):
    ref = tmp_path / "ref"
    assert train_main(load_config("train", overrides(clips, ref, **{"trainer.steps": 8})), []) == 0
    out = tmp_path / "killed"
    proc = run_cli(overrides(clips, out, **{"trainer.steps": 8}))
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        state = out / "train_state.json"
        if state.is_file() and json.loads(state.read_text())["step"] >= 2:
            break
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    killed_at = json.loads((out / "train_state.json").read_text())["step"]
    assert 2 <= killed_at < 8, "the run finished before it could be killed"
    resumed = run_cli(overrides(clips, out, **{"trainer.steps": 8}))
    assert resumed.wait(timeout=300) == 0, resumed.stdout.read()
    a, b = losses(ref), losses(out)
    assert sorted(b) == list(range(8))
    np.testing.assert_allclose([b[s] for s in range(8)], [a[s] for s in range(8)], rtol=1e-5, atol=1e-6)


@pytest.mark.slow
def test_torchrun_two_processes_equal_one_process(clips, tmp_path):
    one, two = tmp_path / "one", tmp_path / "two"
    procs = [run_cli(overrides(clips, one, **{"trainer.steps": 4})),
             run_cli(overrides(clips, two, **{"trainer.steps": 4}), nproc=2)]
    for p in procs:
        assert p.wait(timeout=300) == 0, p.stdout.read()
    a, b = load_file(one / "train_state.safetensors"), load_file(two / "train_state.safetensors")
    assert a.keys() == b.keys()
    for k in a:
        torch.testing.assert_close(b[k], a[k], rtol=1e-4, atol=1e-5, msg=k)
    assert not torch.equal(a["model.net.final.linear.weight"], torch.zeros_like(a["model.net.final.linear.weight"]))
