"""The README's command examples run as written, in order, on tiny data (each gets only the overrides in TINY that
shrink its work); the few that need minutes or a cluster are skipped with the reason."""

from __future__ import annotations

import json
import re
import shlex
import shutil
from pathlib import Path

import numpy as np
from test_cli_errors import run_cli

from cosmos_lite.sim import simulate, write_episode

README = Path(__file__).resolve().parent.parent / "README.md"

# Appended to a command starting with the key: fewer episodes, steps and frames; nothing else changes.
TINY = {
    "sim out=": ["sim.episodes=3"],
    "train experiment=tokenizer_sim": ["trainer.steps=2", "trainer.max_minutes=0", "trainer.val_every=2",
                                       "trainer.batch_size=1", "data.val_clips=1", "data.val_every=2"],
    "train experiment=wfm_nano": ["trainer.steps=1", "trainer.batch_size=1", "trainer.ckpt_every=1"],
    "train -m experiment=wfm_nano": ["trainer.steps=1", "trainer.batch_size=1", "trainer.ckpt_every=1"],
    "generate": ["steps=1"],
    "eval physics": ["episodes=1", "steps=1", "horizon=2", "given=[1]", "conditions=[none]", "splits=[id]",
                     "scenarios=[bounce]", "videos=0"],
    "eval policy": ["steps=1", "policy.tasks=1", "policy.frames=9", "policy.policies=[still,careful]",
                    "policy.mpc.tasks=1", "policy.mpc.candidates=2", "policy.mpc.horizon=4", "policy.mpc.execute=4",
                    "policy.videos=1"],
}
SKIP = {
    "make ": "runs the whole demo or suite (minutes)",
    "torchrun": "several processes; the `...` stands for the keys of the line above",
    "runner=ray": "starts a Ray cluster (minutes on 2 cores)",
    "fit-semantic": "refits the semantic head (about 3 minutes)",
    "posttrain.init_from": "the `...` stands for the keys of the training line above",
    "SUBCOMMAND": "a placeholder",
}


def readme_commands() -> list[tuple[str, int]]:
    """(command line, expected exit code) of every line of the README's bash blocks, continuations joined."""
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", README.read_text(), re.S):
        for line in block.replace("\\\n", " ").splitlines():
            if line.strip():
                expected = re.search(r"#\s*exit (\d)", line)
                commands.append((line, int(expected.group(1)) if expected else 0))
    return commands


def make_inputs(work: Path) -> None:
    """What the README's examples read besides what earlier examples write: raw videos, a clip, a first frame,
    actions, a batch file, a generated clip to guard."""
    from PIL import Image

    ep = simulate("pusher", 7)
    write_episode(ep, work / "raw", "pusher")
    write_episode(simulate("bounce", 8), work / "raw", "bounce")
    shutil.copy(work / "raw" / "pusher.mp4", work / "clip.mp4")
    Image.fromarray(ep.frames[0]).save(work / "first.png")
    np.save(work / "push.npy", np.zeros((48, 2), np.float32))
    (work / "requests.jsonl").write_text(json.dumps({"prompt": "a red ball falls", "seed": 1}) + "\n")
    (work / "outputs" / "gen").mkdir(parents=True)
    shutil.copy(work / "clip.mp4", work / "outputs" / "gen" / "clip.mp4")


def test_readme_examples_run_as_written(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    make_inputs(tmp_path)
    ran, skipped = [], []
    for line, expected in readme_commands():
        argv = shlex.split(line, comments=True)
        if not argv:  # a comment
            continue
        reason = next((why for key, why in SKIP.items() if key in line), None)
        if reason or argv[0] != "cosmos-lite":
            skipped.append((line, reason or "not a cosmos-lite command"))
            continue
        args = argv[1:]
        text = " ".join(args)
        args += next((extra for key, extra in TINY.items() if text.startswith(key)), [])
        if args[:2] == ["eval", "compare"] and not Path("outputs/eval_old").exists():
            shutil.copytree("outputs/eval", "outputs/eval_old")  # the earlier results to compare with
        code, out, err = run_cli(*args)
        assert code == expected, f"{line}\nexit {code}\n{err[-2000:]}"
        assert "Traceback" not in err, line
        ran.append(line)
    assert len(ran) >= 17, ran
    assert all(reason for _, reason in skipped)
