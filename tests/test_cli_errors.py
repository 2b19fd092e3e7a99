"""Every subcommand against a table of bad values: exit code, one line naming the key or file, no traceback, and
nothing left behind in the working folder. Free-text prompts reach the guardrails and the model as typed."""

from __future__ import annotations

import io
import json
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from cosmos_lite import cli
from cosmos_lite.log import get_logger, setup_logging


def run_cli(*argv: str) -> tuple[int, str, str]:
    """`cosmos-lite ARGV` in this process: (exit code, stdout, stderr with the log lines)."""
    out, err = io.StringIO(), io.StringIO()
    setup_logging()
    with redirect_stdout(out), redirect_stderr(err):
        code = cli.main(list(argv))
    return code, out.getvalue(), err.getvalue()


def test_log_lines_follow_stderr_after_a_redirect_is_closed():
    setup_logging()
    log = get_logger("test")
    first, second = io.StringIO(), io.StringIO()
    with redirect_stderr(first):
        log.warning("first line")
    first.close()  # as a test's capture is, after its test
    with redirect_stderr(second):
        log.warning("second line")
    assert "second line" in second.getvalue()


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, tiny_wfm) -> dict[str, Path]:
    """Small inputs outside the working folder: episodes, a raw-video folder, a tokenizer, a world model, files."""
    from cosmos_lite.sim import simulate, write_episode
    from cosmos_lite.tokenizers import build_tokenizer

    root = tmp_path_factory.mktemp("inputs")
    for seed in range(3):
        write_episode(simulate("bounce", seed, frames=9, size=32), root / "sim", f"bounce_{seed}")
    raw = root / "raw"
    raw.mkdir()
    (raw / "ep.mp4").write_bytes((root / "sim" / "bounce_0.mp4").read_bytes())
    (root / "empty.csv").write_text("")
    (root / "words.csv").write_text("a,b\nc,d\n")
    return {"sim": root / "sim", "raw": raw, "video": root / "sim" / "bounce_0.mp4",
            "tok": build_tokenizer("cv4x8x8", "tiny").save(root / "tok"), "wfm": tiny_wfm,
            "empty": root / "empty.csv", "words": root / "words.csv"}


# (subcommand and its good arguments, the bad one, exit code, what the message must name)
GEN = ["generate", "checkpoint={wfm}", "prompt=a ball falls", "output=out"]
TOK = ["tokenize", "checkpoint={tok}", "input={video}"]
GUARD = ["guard", "video={video}", "prompt=a ball"]
TRAIN = ["train", "experiment=tokenizer_tiny", "data.roots=[{sim}]", "data.num_frames=9", "out=out"]
CASES = [
    (GEN, "steps=abc", 2, "steps=abc"),
    (GEN, "steps=0", 2, "steps=0"),
    (GEN, "sampler=foo", 2, "sampler=foo"),
    (GEN, "num_frames=0", 2, "num_frames=0"),
    (GEN, "+num_frame=9", 2, "num_frames"),
    (GEN, "name=../../escape", 2, "name=../../escape"),
    (GEN, "prompt=", 2, "prompt"),
    (GEN, "actions={empty}", 4, "empty.csv"),
    (GEN, "actions={words}", 4, "words.csv"),
    (GEN, "output=/proc/x", 2, "output=/proc/x"),
    (GEN, "output=afile", 2, "output=afile"),
    (GEN, "output=afile/sub", 2, "output=afile/sub"),
    (GEN, "device=tpu", 2, "device=tpu"),
    (["sim", "out=out"], "sim.episodes=abc", 2, "sim.episodes=abc"),
    (["sim", "out=out", "sim.scenario=bounce"], "+sim.params.radius=abc", 2, "sim.params.radius=abc"),
    (["sim", "out=out", "sim.scenario=bounce"], "+sim.params.radius=-3", 2, "sim.params.radius=-3"),
    (["sim", "out=out"], "workers=0", 2, "workers=0"),
    (["sim", "out=out"], "out=/proc/x", 2, "out=/proc/x"),
    (["curate", "input={raw}", "output=out"], "transcode.size=abc", 2, "transcode.size=abc"),
    (["curate", "input={raw}", "output=out"], "output={raw}", 2, "output="),
    (["curate", "input={raw}", "output=out"], "output={raw}/sub", 2, "output="),
    (["curate", "input={raw}", "output=out"], "split.method=foo", 2, "split.method=foo"),
    (TRAIN, "trainer.batch_size=0", 2, "trainer.batch_size=0"),
    (TRAIN, "trainer.batch_size=99", 2, "trainer.batch_size=99"),
    (TRAIN, "out=/proc/x", 2, "out=/proc/x"),
    (TOK, "size=0", 2, "size=0"),
    (TOK, "size=-64", 2, "size=-64"),
    (TOK, "size=7", 2, "size=7"),
    (TOK, "window=0", 2, "window=0"),
    (TOK, "output=recon.txt", 2, "output=recon.txt"),
    (TOK, "output=/proc/recon.mp4", 2, "output=/proc/recon.mp4"),
    (TOK, "checkpoint={wfm}", 4, "tokenizer"),
    (GUARD, "chunk=abc", 2, "chunk=abc"),
    (GUARD, "chunk=0", 2, "chunk=0"),
    (GUARD, "prompt=", 2, "prompt"),
    (GUARD, "guardrails.nudity.every=0", 2, "guardrails.nudity.every=0"),
    (GUARD, "blur_out=b.txt", 2, "blur_out=b.txt"),
    (GUARD, "blur_out=/proc/b.mp4", 2, "blur_out=/proc/b.mp4"),
    (["probe"], "input=[{video},nope.mp4]", 4, "nope.mp4"),
    (["eval", "physics", "checkpoint={wfm}", "out=out"], "episodes=0", 2, "episodes=0"),
    (["eval", "physics", "checkpoint={wfm}", "out=out"], "scenarios=juggle", 2, "juggle"),
    (["eval", "physics", "checkpoint={wfm}", "out=out"], "sampler=foo", 2, "sampler=foo"),
]


@pytest.mark.parametrize(("base", "arg", "code", "named"), CASES, ids=[f"{c[0][0]}-{c[1]}" for c in CASES])
def test_bad_value(base, arg, code, named, inputs, tmp_path, monkeypatch):
    work = tmp_path / "work"
    work.mkdir()
    (work / "afile").write_text("a file where a folder is expected")
    monkeypatch.chdir(work)
    before = sorted(work.rglob("*"))
    argv = [a.format(**inputs) for a in [*base, arg]]
    got, out, err = run_cli(*argv)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert got == code, err
    assert len(lines) == 1 and lines[0].startswith("cosmos-lite: error: "), err
    assert "Traceback" not in err
    assert named.format(**inputs) in lines[0]
    assert sorted(work.rglob("*")) == before, "a failed command left files or folders behind"


PROMPTS = [
    "a ball, then a cube", "it's a ball", 'a "red" ball', "a ball [big] (very) {x} #1 = 2", "a ball = a sphere",
    "une balle tombée à côté", "a ball 🙂 falls 🚀", "一个红球落下", "كرة حمراء تسقط", "cost ${oops} and \\${x}",
    "prompt=inside", "",
]


@pytest.mark.parametrize("text", PROMPTS[:-1])
def test_free_text_reaches_the_config_verbatim(text):
    rest, texts = cli.split_free_text([f"prompt={text}", "chunk=3"])
    cfg = cli.load_config("guard", rest)
    cli.set_free_text(cfg, texts, "guard")
    assert cfg.prompt == text and OmegaConf.to_container(cfg, resolve=True)["prompt"] == text
    assert cfg.chunk == 3


LONG = "a ball falls. " * 7300  # 100 KB: the blocklist alone takes ~30 s on it (2 loaded cores)


@pytest.mark.parametrize("text", [*PROMPTS[:-1], pytest.param(LONG, marks=pytest.mark.slow)])
def test_guard_answers_any_prompt(text):
    code, out, err = run_cli("guard", f"prompt={text}")
    assert code in (0, 3), err
    assert json.loads(out)["allowed"] == (code == 0)


@pytest.mark.parametrize("long", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_generate_and_batch_take_prompts_as_typed(inputs, tmp_path, long):
    texts = [*PROMPTS[:-2], *([LONG] if long else [])]
    code, out, err = run_cli("generate", f"checkpoint={inputs['wfm']}", f"prompt={texts[0]}", "steps=1",
                             f"output={tmp_path / 'one'}", "name=one")
    assert code in (0, 3), err
    assert json.loads((tmp_path / "one" / "one.json").read_text())["request"]["prompt"] == texts[0]
    batch = tmp_path / "requests.jsonl"
    lines = [{"prompt": t, "steps": 1, "name": f"p{i}"} for i, t in enumerate(texts)]
    lines += [{"prompt": "a ball", "steps": "abc"}, {"prompt": "a ball", "sampler": "foo"},
              {"prompt": "a ball", "num_frames": "abc"}, {"prompt": "a ball", "name": "../../escape"}]
    batch.write_text("\n".join(json.dumps(x, ensure_ascii=False) for x in lines) + "\n")
    code, out, err = run_cli("generate", f"checkpoint={inputs['wfm']}", f"batch={batch}", f"output={tmp_path / 'b'}")
    records = [json.loads(ln) for ln in out.splitlines()]
    blocked = any(r["status"] == "blocked" for r in records)
    assert code == (3 if blocked else 2)  # the worst of the lines: bad ones (2), blocked ones (3); the others ran
    assert all(r["status"] in ("ok", "blocked") for r in records[: len(texts)])  # answered on their content
    for i, text in enumerate(texts):
        assert json.loads((tmp_path / "b" / f"p{i}.json").read_text())["request"]["prompt"] == text
    failed = records[len(texts):]
    assert [r["status"] for r in failed] == ["failed"] * 4
    for r, key in zip(failed, ["steps=abc", "sampler=foo", "num_frames=abc", "name=../../escape"]):
        assert key in r["error"]
    assert not (tmp_path / "escape.json").exists() and not (tmp_path.parent / "escape.json").exists()


def test_sweep_gives_each_job_its_folder(inputs, tmp_path):
    out = tmp_path / "sweep"
    code, stdout, err = run_cli("sim", "-m", f"out={out}", "sim.scenario=bounce", "sim.frames=5", "sim.episodes=1",
                                "seed=0,1")
    assert code == 0, err
    summary = json.loads(stdout.splitlines()[-1])["multirun"]
    assert [(j["job"], j["overrides"], j["out"]) for j in summary] == [
        (0, [f"out={out}", "sim.scenario=bounce", "sim.frames=5", "sim.episodes=1", "seed=0"], str(out / "0")),
        (1, [f"out={out}", "sim.scenario=bounce", "sim.frames=5", "sim.episodes=1", "seed=1"], str(out / "1"))]
    assert [json.loads((out / str(j) / "index.json").read_text())["seed"] for j in (0, 1)] == [0, 1]
    assert json.loads((out / "multirun.json").read_text())["jobs"] == summary


def test_debug_shows_the_traceback(monkeypatch):
    monkeypatch.setenv("COSMOS_LITE_DEBUG", "1")
    code, _, err = run_cli("guard", "chunk=0", "prompt=a ball")
    assert code == 2 and "Traceback" in err and err.strip().splitlines()[-1].startswith("cosmos-lite: error:")

