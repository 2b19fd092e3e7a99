"""`cosmos-lite guard`: JSON verdicts and exit codes 0 allowed, 3 blocked, 2 bad arguments, 4 unreadable input."""

from __future__ import annotations

import json

import numpy as np
from skimage import data

from cosmos_lite import cli
from cosmos_lite.video import read_frames, write_video

FAST = ["guardrails.semantic.enabled=false"]  # the blocklist alone decides these prompts


def run(capsys, *args: str) -> tuple[int, dict | None]:
    code = cli.main(["guard", *args])
    out = capsys.readouterr().out
    return code, json.loads(out) if out.strip() else None


def test_prompt_exit_codes(capsys):
    code, verdict = run(capsys, "prompt=a robot arm stacks three cubes", *FAST)
    assert code == 0 and verdict["allowed"]
    code, verdict = run(capsys, "prompt=a video of a m.a.s.s.a.c.r.e", *FAST)
    assert code == 3 and not verdict["allowed"]
    assert verdict["verdicts"][0]["guard"] == "blocklist" and "massacre" in verdict["verdicts"][0]["reason"]
    code, verdict = run(capsys, "prompt=", *FAST)  # a bad argument, not a blocked prompt
    assert code == 2 and verdict is None


def test_an_everyday_prompt_passes_every_guard(capsys):
    code, verdict = run(capsys, "prompt=hello")  # issue 22: the semantic guard once blocked greetings
    assert code == 0 and verdict["allowed"] and {v["guard"] for v in verdict["verdicts"]} == {"blocklist", "semantic"}


def test_bad_arguments_exit_2(capsys):
    assert run(capsys)[0] == 2
    assert run(capsys, "check")[0] == 2
    assert run(capsys, "prompt=x", "guardrails.blocklist.nope=1")[0] == 2


def test_video_exit_codes_and_blurred_output(tmp_path, sintel_10s, capsys):
    face = np.repeat(data.astronaut()[None, ::2, ::2], 4, axis=0)  # 256x256, a face in every frame
    video = write_video(tmp_path / "face.mp4", face, fps=8)
    blurred = tmp_path / "blurred.mp4"
    code, verdict = run(capsys, f"video={video}", f"blur_out={blurred}")
    assert code == 0 and verdict["allowed"] and blurred.is_file()
    assert np.abs(read_frames(blurred).astype(int) - read_frames(video)).mean() > 1  # the face was pixelated
    code, verdict = run(capsys, f"video={video}", "+guardrails.nudity.thresholds.FACE_FEMALE=0.5")
    assert code == 3 and "FACE_FEMALE" in verdict["verdicts"][0]["reason"]
    assert run(capsys, f"video={tmp_path / 'missing.mp4'}")[0] == 4
    (tmp_path / "junk.mp4").write_bytes(b"not a video")
    assert run(capsys, f"video={tmp_path / 'junk.mp4'}")[0] == 4
