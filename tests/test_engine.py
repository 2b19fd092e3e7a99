"""The training engine, through its two heaviest tasks (tokenizer, world model): kill-and-resume continues the loss
curve exactly; 2-process torchrun (gloo) equals 1 process with the same global batch; a run folder trained with a
different config is refused; a crashed run leaves no checkpoint; the wall-clock budget ends a run with a checkpoint;
a world-model run folder is a loadable checkpoint and LoRA post-training starts from it."""

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

from cosmos_lite.cli import main as cli_main
from cosmos_lite.config import load_config
from cosmos_lite.core.engine import Batch, TrainerConfig, lr_at, read_state_meta
from cosmos_lite.models import WorldModelPipeline
from cosmos_lite.models.train import WorldModelTask
from cosmos_lite.sim import simulate, write_episode
from cosmos_lite.tokenizers import build_tokenizer
from cosmos_lite.train import main as train_main

ROOT = Path(__file__).resolve().parent.parent
STEPS = {"tokenizer": 30, "wfm": 8}  # enough steps that a run can be killed part-way


@pytest.fixture(scope="module")
def clips(tmp_path_factory) -> tuple[Path, Path]:
    """Six short 32x32 simulator episodes (pusher and bounce, with actions and captions) and a (randomly
    initialised) tiny tokenizer folder for the world model."""
    root = tmp_path_factory.mktemp("engine_data")
    for i in range(6):
        write_episode(simulate(("pusher", "bounce")[i % 2], seed=i, frames=13, size=32), root, f"ep{i}")
    torch.manual_seed(0)
    tok = build_tokenizer("cv1x4x4", "tiny").save(root.parent / "tok")
    return root, tok


def overrides(task: str, clips, out: Path, **kw) -> list[str]:
    root, tok = clips
    args = {"data.roots": f"[{root}]", "out": str(out), "trainer.steps": STEPS[task], "trainer.ckpt_every": 2,
            "trainer.batch_size": 4}
    if task == "tokenizer":
        args |= {"data.num_frames": 9, "data.val_every": 3, "data.val_clips": 2, "trainer.val_every": 0}
    else:
        args |= {"tokenizer.path": str(tok)}
    return [f"experiment={task}_tiny"] + [f"{k}={v}" for k, v in {**args, **kw}.items()]


def losses(out: Path) -> dict[int, float]:
    return {r["step"]: r["loss"] for r in map(json.loads, (out / "log.jsonl").read_text().splitlines())}


def run_cli(args: list[str], nproc: int = 1) -> subprocess.Popen:
    env = {**os.environ, "COSMOS_LITE_QUIET": "1", "OMP_NUM_THREADS": "1"}
    launcher = [sys.executable, "-m", "cosmos_lite.cli"] if nproc == 1 else [
        str(Path(sys.executable).parent / "torchrun"), "--standalone", f"--nproc_per_node={nproc}", "-m",
        "cosmos_lite.cli"]
    return subprocess.Popen([*launcher, "train", *args], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


def test_lr_schedule_warms_up_then_decays():
    cfg = TrainerConfig(lr=1e-3, min_lr=1e-5, warmup=10)
    assert lr_at(0, 0.0, cfg) == pytest.approx(1e-4)
    assert lr_at(10, 0.0, cfg) == pytest.approx(1e-3)
    assert lr_at(500, 0.5, cfg) == pytest.approx((1e-3 + 1e-5) / 2)
    assert lr_at(1000, 1.0, cfg) == pytest.approx(1e-5)


@pytest.mark.parametrize("task", ["tokenizer", "wfm"])
def test_kill_and_resume_continues_the_loss_curve(task, clips, tmp_path):
    ref = tmp_path / "ref"
    assert train_main(load_config("train", overrides(task, clips, ref)), []) == 0
    out = tmp_path / "killed"
    proc = run_cli(overrides(task, clips, out))
    deadline = time.time() + 120
    while time.time() < deadline and proc.poll() is None:
        state = read_state_meta(out)
        if state is not None and state["step"] >= 2:
            break
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    killed_at = read_state_meta(out)["step"]
    assert 2 <= killed_at < STEPS[task], "the run finished before it could be killed"
    resumed = run_cli(overrides(task, clips, out))
    assert resumed.wait(timeout=300) == 0, resumed.stdout.read()
    a, b = losses(ref), losses(out)
    steps = list(range(STEPS[task]))
    assert sorted(b) == steps
    np.testing.assert_allclose([b[s] for s in steps], [a[s] for s in steps], rtol=1e-5, atol=1e-6)


def test_resume_refuses_a_different_config_and_a_crash_leaves_no_checkpoint(clips, tmp_path, monkeypatch, capsys):
    out = tmp_path / "run"
    assert cli_main(["train", *overrides("tokenizer", clips, out, **{"trainer.steps": 2})]) == 0
    assert cli_main(["train", *overrides("tokenizer", clips, out, **{"trainer.steps": 4})]) == 0  # extend: fine
    assert read_state_meta(out)["step"] == 4
    code = cli_main(["train", *overrides("tokenizer", clips, out, **{"trainer.lr": 0.1, "loss.grad_weight": 0})])
    err = capsys.readouterr().err
    assert code == 2 and "loss.grad_weight" in err and "trainer.lr" in err and "trainer.resume=false" in err
    assert cli_main(["train", *overrides("tokenizer", clips, out, **{"trainer.lr": 0.1, "trainer.resume": "false",
                                                                     "trainer.steps": 2})]) == 0
    assert read_state_meta(out)["step"] == 2 and sorted(losses(out)) == [0, 1]

    from cosmos_lite.tokenizers.train import TokenizerTask

    def crash(self, net, items, batch):
        raise RuntimeError("killed")

    monkeypatch.setattr(TokenizerTask, "loss", crash)
    crashed = tmp_path / "crashed"
    with pytest.raises(RuntimeError, match="killed"):
        train_main(load_config("train", overrides("tokenizer", clips, crashed)), [])
    assert crashed.is_dir() and not (crashed / "model.safetensors").exists() and read_state_meta(crashed) is None


def test_world_model_run_is_a_checkpoint_and_lora_post_training_from_it(clips, tmp_path):
    out = tmp_path / "run"
    assert train_main(load_config("train", overrides("wfm", clips, out, **{"trainer.steps": 6})), []) == 0
    curve = losses(out)
    assert sorted(curve) == list(range(6)) and all(np.isfinite(list(curve.values())))
    pipe = WorldModelPipeline.from_pretrained(out)
    frames = pipe(video=np.zeros((1, 32, 32, 3), np.uint8), num_frames=9, steps=2).frames
    assert frames.shape == (9, 32, 32, 3)
    # specialist: LoRA adapters on the parent, merged into a plain DiT on export
    spec = tmp_path / "spec"
    assert train_main(load_config("train", overrides("wfm", clips, spec, **{
        "trainer.steps": 6, "posttrain.init_from": str(out), "posttrain.lora_rank": 4, "tokenizer.path": "null"})),
        []) == 0
    parent, child = load_file(out / "model.safetensors"), load_file(spec / "model.safetensors")
    assert parent.keys() == child.keys()
    assert not torch.equal(parent["blocks.0.attn.q.weight"], child["blocks.0.attn.q.weight"])
    assert torch.equal(parent["x_embed.net.0.weight"], child["x_embed.net.0.weight"])  # outside the adapters: frozen
    assert torch.equal(load_file(out / "latent_stats.safetensors")["std"],
                       load_file(spec / "latent_stats.safetensors")["std"])


def test_world_model_over_a_discrete_tokenizer_generates_frames_on_its_code_grid(clips, tmp_path):
    torch.manual_seed(0)
    tok = build_tokenizer("dv1x4x4", "tiny", levels=[7, 7, 5]).save(tmp_path / "dv_tok")
    out = tmp_path / "run"
    assert train_main(load_config("train", overrides("wfm", clips, out, **{
        "trainer.steps": 2, "tokenizer.path": str(tok)})), []) == 0
    pipe = WorldModelPipeline.from_pretrained(out)
    assert pipe.denoiser.net.cfg.latent_channels == 3  # the network's channels follow the tokenizer's
    latents = torch.zeros(1, 3, 3, 8, 8)
    z = pipe.next_latent(latents, None, 1, None, None, steps=2, generator=torch.Generator().manual_seed(0))
    codes = z * pipe.stats["std"][:, None, None] + pipe.stats["mean"][:, None, None]
    steps = codes * torch.tensor([3.0, 3.0, 2.0])[:, None, None]  # level // 2 per channel
    torch.testing.assert_close(steps, steps.round(), atol=1e-4, rtol=0)


def test_own_context_replaces_the_last_context_frame_with_the_models_sample(clips, tmp_path):
    torch.manual_seed(0)
    tok = build_tokenizer("dv1x4x4", "tiny", levels=[7, 7, 5]).save(tmp_path / "dv_tok")

    def loss(p_own: float, items: list[tuple[int, int]]) -> float:
        torch.manual_seed(0)  # the same initial weights for both tasks
        task = WorldModelTask(load_config("train", overrides("wfm", clips, tmp_path / "run", **{
            "tokenizer.path": str(tok), "model.latent_channels": 3, "cond.p_own_context": p_own})), torch.device("cpu"))
        return float(task.loss(task.model, items, Batch(step=0, size=len(items), rows=slice(None), seed=0)))

    first = [(0, 1), (1, 1)]  # frame 1's context is the given frame 0 alone: always the true one
    assert loss(1.0, first) == loss(0.0, first)
    later = [(0, 4), (1, 3)]
    assert loss(1.0, later) != loss(0.0, later)


def test_wall_clock_budget_ends_training_with_a_checkpoint(clips, tmp_path):
    out = tmp_path / "budget"
    assert train_main(load_config("train", overrides("wfm", clips, out, **{
        "trainer.steps": 1000, "trainer.max_minutes": 1e-6})), []) == 0
    state = read_state_meta(out)
    assert state["step"] == 1 and state["minutes"] > 1e-6  # stopped by time after one step, long before 1000
    assert sorted(losses(out)) == [0]
    WorldModelPipeline.from_pretrained(out)


@pytest.mark.slow
@pytest.mark.parametrize("task", ["tokenizer", "wfm"])
def test_torchrun_two_processes_equal_one_process(task, clips, tmp_path):
    one, two = tmp_path / "one", tmp_path / "two"
    procs = [run_cli(overrides(task, clips, one, **{"trainer.steps": 4})),
             run_cli(overrides(task, clips, two, **{"trainer.steps": 4}), nproc=2)]
    for p in procs:
        assert p.wait(timeout=300) == 0, p.stdout.read()
    np.testing.assert_allclose(list(losses(two).values()), list(losses(one).values()), rtol=1e-5)
    a, b = load_file(one / "train_state.safetensors"), load_file(two / "train_state.safetensors")
    assert a.keys() == b.keys()
    # Every weight, EMA and Adam moment equal, but for round-off: a bias right before a normalisation has a
    # gradient of pure round-off, which Adam scales up to a full step of either sign (a few such tensors in the
    # tokenizer). A wrong split of the batch would move nearly every element.
    same = sum(int(torch.isclose(b[k], a[k], rtol=1e-4, atol=1e-5).sum()) for k in a)
    assert same >= 0.999 * sum(v.numel() for v in a.values())
    moved = [k for k in a if k.startswith("model.") and not torch.equal(a[k], a[k.replace("model.", "ema.", 1)])]
    assert moved  # the weights trained (the EMA lags them)


def test_trainer_keys_are_typed_and_checked_by_the_structured_config(capsys):
    assert cli_main(["train", "experiment=tokenizer_tiny", "trainer.max_step=5"]) == 2
    assert "trainer.max_step" in capsys.readouterr().err
    assert cli_main(["train", "experiment=wfm_tiny", "trainer.lr=fast"]) == 2
    assert "trainer.lr" in capsys.readouterr().err
    cfg = load_config("train", ["experiment=wfm_tiny"])  # defaults come from the dataclass, the YAML holds the rest
    assert cfg.trainer.weight_decay == TrainerConfig().weight_decay and cfg.trainer.steps == 20
