"""Curation: splitters against annotated cuts, filters, the job's output contract, bad inputs, resume."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from cosmos_lite.cli import main as cli_main
from cosmos_lite.config import load_config
from cosmos_lite.curation import CurateConfig, curate, detect, evaluate
from cosmos_lite.curation.filters import Clip, build_filters, dedup, phash
from cosmos_lite.curation.split import (
    ANALYSIS_SIZE,
    CUT,
    KEEP,
    SKIP,
    Detection,
    FastSplitter,
    build_splitter,
    detect_frames,
    spans_of,
)
from cosmos_lite.errors import ConfigError
from cosmos_lite.video import probe, write_video

ROOT = Path(__file__).resolve().parent.parent
SMALL = ["transcode.size=96"]  # fast encodes in tests


def _cfg(input_dir, output_dir, *overrides) -> CurateConfig:
    return CurateConfig.from_node(load_config("curate", [f"input={input_dir}", f"output={output_dir}", *overrides]))


def _metas(out: Path) -> dict[str, dict]:
    return {p.stem: json.loads(p.read_text()) for p in sorted((out / "metas").glob("*.json"))}


def _check_spans(spans, ann) -> None:
    """No clip holds a hard cut or a frame of a gradual transition (its annotated ends may be 3 frames off)."""
    for s, e in spans:
        assert not [c for c in ann["hard_cuts"] if s < c < e], (s, e)
        assert not [g for g in ann["gradual_transitions"] if s <= g[1] - 3 and e > g[0] + 3], (s, e)


@pytest.mark.parametrize("method", ["fast", "adaptive"])
def test_splitter_on_sintel_meets_f1_and_never_spans_a_cut(sintel_30s, sintel_cuts, method):
    det = detect(sintel_30s, build_splitter(method))
    r = evaluate(det, sintel_cuts)
    assert r["f1"] >= (0.93 if method == "fast" else 0.9), r
    assert r["clips_with_cut"] == []
    if method == "fast":  # PySceneDetect's detectors see hard cuts only
        assert r["clips_in_transition"] == [] and r["gradual_recall"] == 1.0, r
    assert len(det.labels) == len(det.blank) == sintel_cuts["frames"]
    assert det.blank[[100 - 24, 200, 230, 380, 472, 627]].all()  # fades through white and black are blank


@pytest.mark.slow
def test_transnetv2_finds_every_hard_cut(sintel_30s, sintel_cuts):
    r = evaluate(detect(sintel_30s, build_splitter("transnetv2")), sintel_cuts)
    assert r["recall"] == 1.0 and r["clips_with_cut"] == []  # its clips may hold fading frames (160-171 here)


def test_fast_splitter_labels_synthetic_cut_and_ignores_steady_motion(moving_square):
    frames = np.concatenate([moving_square, 255 - moving_square])  # cut at 24
    s = FastSplitter()
    s.reset(24.0)
    labels = [lab for f in frames for lab in s.push(f)] + s.flush()
    assert len(labels) == 48
    assert [i for i, lab in enumerate(labels) if lab == CUT] == [24]


def test_segmenter_spans_and_boundaries():
    labels = np.array([KEEP] * 5 + [CUT] + [KEEP] * 4 + [SKIP] * 2 + [CUT] + [KEEP] * 7)
    blank = np.zeros(len(labels), bool)
    blank[15:17] = True
    assert spans_of(labels, blank, max_frames=100) == [(0, 5), (5, 10), (12, 15), (17, 20)]
    assert spans_of(labels, blank, max_frames=3) == [(0, 3), (3, 5), (5, 8), (8, 10), (12, 15), (17, 20)]
    det = Detection(labels, blank, [], 24.0)
    assert det.boundaries == [5, 10, 12, 15, 17]
    ann = {"hard_cuts": [5, 17], "gradual_transitions": [[10, 11]], "tolerance_frames": 2}
    assert det.excluded_runs == [(10, 11), (15, 16)]
    r = evaluate(det, ann)
    assert (r["precision"], r["recall"]) == (1.0, 1.0)  # 10, 12 and 15 are ends of excluded runs, scored as such:
    assert (r["gradual_precision"], r["gradual_recall"]) == (1.0, 1.0)  # (10, 11) is found, (15, 16) ends at a cut
    det.labels[2] = CUT
    assert evaluate(det, ann)["precision"] == 2 / 3  # a cut label where there is none is a false alarm
    r = evaluate(det, {"hard_cuts": [5, 17], "gradual_transitions": []})
    assert (r["runs_fp"], r["runs_tp"]) == (1, 0)  # (10, 11) is a false alarm; (15, 16) ends at a cut: neither


def _two_real_shots(sintel_30s, kind: str, length: int, level: float | None = None):
    """Sintel shots 258-286 (dark, still) and 524-573 (bright, moving) joined by a `kind` transition of `length`
    frames, at analysis size; its annotation. `level`: both shots dimmed to that mean luma (a night scene), the
    transition's frames by the mix of both gains."""
    from cosmos_lite.curation.evalset import Shot, transition
    from cosmos_lite.curation.split import luma
    from cosmos_lite.video import read_frames

    video = read_frames(sintel_30s, start=258, end=573, size=ANALYSIS_SIZE)
    a, b = Shot(video[:28]), Shot(video[524 - 258 :])
    rng = np.random.default_rng(0)
    first, mixed, last = a.take(40), transition(kind, a.take(length), b.take(length), rng), b.take(40)
    if level is not None:
        ga, gb = level / luma(first).mean(), level / luma(last).mean()
        w = ((np.arange(length) + 1) / (length + 1))[:, None, None, None]
        first, mixed, last = first * ga, mixed * ((1 - w) * ga + w * gb), last * gb
    frames = np.concatenate([first, mixed, last])
    ann = {"hard_cuts": [], "gradual_transitions": [[40, 40 + length - 1]], "tolerance_frames": 2,
           "gradual_tolerance_frames": 0}
    return np.clip(frames + 0.5, 0, 255).astype(np.uint8), ann


@pytest.mark.parametrize(("kind", "length", "level"),
                         [("dissolve", 16, None), ("fade", 16, None), ("dissolve", 30, None), ("wipe", 8, None),
                          ("wipe", 16, 15.0)])  # the last: a wipe between two night shots (mean luma 15)
def test_fast_splitter_keeps_every_transition_frame_out_of_clips(sintel_30s, kind, length, level):
    frames, ann = _two_real_shots(sintel_30s, kind, length, level)
    det = detect_frames(frames, 24.0, build_splitter("fast"))
    r = evaluate(det, ann)
    assert r["clips_in_transition"] == [] and r["gradual_found"] == 1 and r["runs_fp"] == 0, det.excluded_runs
    first, last = ann["gradual_transitions"][0]
    assert det.spans[0][1] <= first and det.spans[-1][0] > last and len(det.spans) == 2, det.spans  # both shots stay


def test_fast_splitter_widens_each_transition_by_its_margin_never_across_a_cut():
    rng = np.random.default_rng(0)
    a, b, c = (rng.integers(lo, hi, (*ANALYSIS_SIZE, 3)).astype(np.float32)
               for lo, hi in ((0, 120), (100, 256), (0, 256)))
    w = ((np.arange(16) + 1) / 17)[:, None, None, None]
    dissolve = np.concatenate([np.repeat(a[None], 40, 0), (1 - w) * a + w * b, np.repeat(b[None], 6, 0)])  # 40-55

    def run(frames, margin):
        s = FastSplitter(margin=margin)
        s.reset(24.0)
        labels = np.array([lab for f in frames.astype(np.uint8) for lab in s.push(f)] + s.flush())
        skipped = np.flatnonzero(labels == SKIP)
        assert len(skipped) == skipped[-1] - skipped[0] + 1  # one run
        return skipped[0], skipped[-1], list(np.flatnonzero(labels == CUT))

    then_b = np.concatenate([dissolve, np.repeat(b[None], 34, 0)])
    first, last, _ = run(then_b, 0.0)
    assert first <= 40 and last >= 55
    m = int(np.ceil(0.1 * (last - first + 1)))
    assert run(then_b, 0.1) == (first - m, last + m, [])
    then_cut = np.concatenate([dissolve, np.repeat(c[None], 30, 0)])  # a cut to c at 62
    assert run(then_cut, 0.3)[1:] == (61, [62])  # 7 more frames would cross it


def test_fast_splitter_finds_a_cut_right_after_a_fast_pan(sintel_30s):
    """The pan's own differences (~30 levels a frame) raise one side of the cut: it need only double them."""
    import cv2
    from skimage import data

    from cosmos_lite.video import read_frames

    wide = cv2.resize(data.astronaut(), (3 * ANALYSIS_SIZE[1], ANALYSIS_SIZE[0]), interpolation=cv2.INTER_AREA)
    pan = np.stack([wide[:, 4 * i : 4 * i + ANALYSIS_SIZE[1]] for i in range(30)])  # 4 px a frame at 36x64
    shot = read_frames(sintel_30s, start=524, end=560, size=ANALYSIS_SIZE)
    s = FastSplitter()
    s.reset(24.0)
    labels = [lab for f in np.concatenate([pan, shot]) for lab in s.push(f)] + s.flush()
    assert [i for i, lab in enumerate(labels) if lab != KEEP] == [30]


def test_transitions_mix_the_shots_and_nothing_else():
    from cosmos_lite.curation.evalset import transition

    rng = np.random.default_rng(0)
    a, b = np.full((8, 4, 6, 3), 200.0), np.full((8, 4, 6, 3), 40.0)
    dissolve = transition("dissolve", a, b, rng)
    assert np.all(np.diff(dissolve[:, 0, 0, 0]) < 0) and 40 < dissolve.min() and dissolve.max() < 200
    fade = transition("fade", a, b, rng)[:, 0, 0, 0]
    assert fade[0] < 200 and fade[3] < fade[0] and fade[4] < 40 and fade[-1] < 40 and fade.min() > 0
    wipe = transition("wipe", a, b, rng)
    shares = (wipe == 40.0).mean(axis=(1, 2, 3))
    assert np.all(np.diff(shares) >= 0) and 0 < shares[0] and shares[-1] < 1 and set(np.unique(wipe)) == {40.0, 200.0}


def _clip(frames: np.ndarray) -> Clip:
    from cosmos_lite.curation.split import resize

    c = Clip("x.mp4", 0, len(frames), 24.0, frames.shape[1:3])
    c.frames = list(frames)
    c.small = [resize(f, ANALYSIS_SIZE) for f in frames]
    return c


def test_filters_score_motion_sharpness_blank_and_duplicates(moving_square):
    import cv2

    filters = {f.name: f for f in build_filters(load_config("curate").filters)}
    moving = _clip(np.stack([cv2.resize(f, (256, 256), interpolation=cv2.INTER_NEAREST) for f in moving_square]))
    static = _clip(np.repeat(moving.frames[0][None], 24, 0))
    blurred = _clip(np.stack([cv2.GaussianBlur(f, (0, 0), 8) for f in moving.frames]))
    black = _clip(np.zeros((24, 64, 64, 3), np.uint8))
    m = filters["motion"]
    assert m.passes(m.score(moving)) and not m.passes(m.score(static))
    s = filters["sharpness"]
    assert s.passes(s.score(moving)) and not s.passes(s.score(blurred))
    b = filters["blank"]
    assert b.passes(b.score(moving)) and not b.passes(b.score(black))
    d = filters["duration"]
    assert d.score(moving) == 1.0 and d.passes(1.0) and not d.passes(0.5)
    # near-duplicates: a re-encode-like copy (noise) is within the distance, a different clip is not
    noisy = _clip(np.clip(np.stack(moving.frames).astype(int) + 3, 0, 255).astype(np.uint8))
    metas = [
        {"id": k, "kept": True, "phash": phash(c), "scores": {}, "passed": {}, "dropped_by": []}
        for k, c in (("a", moving), ("b", noisy), ("c", black))
    ]
    changed = dedup(metas, filters["duplicate"])
    assert [m["kept"] for m in metas] == [True, False, True] and len(changed) == 3
    assert dedup(metas, filters["duplicate"]) == []  # idempotent
    with pytest.raises(ConfigError):
        build_filters({"motion": {"min": 1.0, "typo": 2}})
    with pytest.raises(ConfigError):
        build_filters({"motion": {"action": "delete"}})


def test_motion_filter_keeps_a_static_real_shot_and_drops_a_frozen_frame(sintel_30s, tmp_path):
    from cosmos_lite.video import read_frames

    shot = read_frames(sintel_30s, start=287, end=308, size=(144, 256))  # a locked-off shot: d < 0.5 per frame
    write_video(tmp_path / "frozen.mp4", np.repeat(shot[:1], 48, 0), fps=24)  # encoded and decoded, noise and all
    frozen = read_frames(tmp_path / "frozen.mp4")
    m = next(f for f in build_filters(load_config("curate").filters) if f.name == "motion")
    assert m.score(_clip(shot)) >= 5 * m.min_percent
    assert m.score(_clip(frozen)) < m.min_percent and m.score(_clip(np.zeros_like(frozen))) == 0


def test_curate_sintel_clips_respect_cuts_and_the_output_contract(sintel_30s, sintel_cuts, tmp_path):
    inp = tmp_path / "in"
    inp.mkdir()
    (inp / "sintel.mp4").symlink_to(sintel_30s)
    out = tmp_path / "out"
    summary = curate(_cfg(inp, out, *SMALL, "clips_per_shard=4"))
    metas = _metas(out)
    kept = [m for m in metas.values() if m["kept"]]
    # >= 3: the trailer's many fades (and the frames around them) stay out of clips
    assert summary["inputs_done"] == 1 and summary["clips_kept"] == len(kept) >= 3 and summary["cpu_seconds"] > 0
    assert summary["clips_dropped"] == len(metas) - len(kept) <= sum(summary["dropped_by"].values())  # 1+ reasons each
    _check_spans([m["span"] for m in metas.values()], sintel_cuts)
    assert {p.stem for p in (out / "clips").iterdir()} == {m["id"] for m in kept}
    for m in kept[:3]:
        info = probe(out / "clips" / f"{m['id']}.mp4")
        assert info.num_frames == m["num_frames"] and info.size == tuple(m["size"]) == (96, 170)
        assert info.codec == "h264" and info.fps == pytest.approx(24.0)
    for m in metas.values():
        assert m["kept"] == (m["dropped_by"] == []) and set(m["scores"]) >= {"motion", "sharpness", "blank"}
    shards = sorted((out / "shards").glob("*.tar"))
    assert len(shards) == -(-len(kept) // 4)
    # a rerun skips the finished input and changes nothing
    before = {p.name: p.stat().st_mtime_ns for p in (out / "clips").iterdir()}
    again = curate(_cfg(inp, out, *SMALL, "clips_per_shard=4"))
    assert again["frames_processed"] == 0 and again["clips_kept"] == summary["clips_kept"]
    assert {p.name: p.stat().st_mtime_ns for p in (out / "clips").iterdir()} == before
    # a rerun with other output settings is refused instead of mixing clips of both
    with pytest.raises(ConfigError, match="other transcode settings"):
        curate(_cfg(inp, out, "transcode.size=64", "clips_per_shard=4"))
    assert {p.name: p.stat().st_mtime_ns for p in (out / "clips").iterdir()} == before


def _bad_inputs(folder: Path, good: Path) -> None:
    folder.mkdir()
    shutil.copy(good, folder / "good.mp4")
    data = good.read_bytes()
    (folder / "zero.mp4").write_bytes(b"")
    (folder / "truncated.mp4").write_bytes(data[: len(data) // 2])
    corrupt = bytearray(data)
    corrupt[2000:200000] = np.random.default_rng(0).integers(0, 256, 198000, dtype=np.uint8).tobytes()
    (folder / "corrupt.mp4").write_bytes(bytes(corrupt))
    (folder / "notes.mp4").write_text("not a video\n")
    (folder / "readme.txt").write_text("ignored: not a video extension\n")


def test_bad_inputs_fail_with_reasons_and_leave_no_partial_files(sintel_10s, tmp_path, capsys):
    inp, out = tmp_path / "in", tmp_path / "out"
    _bad_inputs(inp, sintel_10s)
    code = cli_main(["curate", f"input={inp}", f"output={out}", *SMALL])
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["inputs"] == 5 and summary["inputs_done"] == 1 and summary["inputs_failed"] == 4
    reasons = {f["source"]: f["reason"] for f in summary["failures"]}
    assert set(reasons) == {"zero.mp4", "truncated.mp4", "corrupt.mp4", "notes.mp4"}
    assert "empty" in reasons["zero.mp4"] and "corrupt.mp4" in reasons["corrupt.mp4"]
    metas = _metas(out)
    assert metas and {m["source"] for m in metas.values()} == {"good.mp4"}
    assert {p.stem for p in (out / "clips").iterdir()} == {k for k, m in metas.items() if m["kept"]}
    leftovers = [p for p in out.rglob("*") if p.name.startswith(".")]
    assert leftovers == []
    assert "4 failed" in capsys.readouterr().out


def test_cli_errors_name_the_fix(tmp_path, capsys):
    assert cli_main(["curate", f"output={tmp_path}"]) == 2
    assert cli_main(["curate", f"input={tmp_path / 'nope'}", f"output={tmp_path}"]) == 4
    assert cli_main(["curate", f"input={tmp_path}", f"output={tmp_path}", "split.method=magic"]) == 2
    err = capsys.readouterr().err
    assert "input=DIR" in err and "no such file or folder" in err and "fast, transnetv2" in err
    (tmp_path / "a.mp4").write_bytes(b"")
    blocker = tmp_path / "file"
    blocker.write_text("")
    bad = {"transcode.preset=fastest": "veryfast, faster", "transcode.crf=60": "<= 51",
           "transcode.size=0": "integer >= 2", "workers=0": "integer >= 1", f"output={blocker / 'out'}": "is a file"}
    for override, fix in bad.items():
        assert cli_main(["curate", f"input={tmp_path}", f"output={tmp_path / 'out'}", override]) == 2, override
        assert fix in capsys.readouterr().err, override
    assert not (tmp_path / "out").exists()


def _run_cli(inp: Path, out: Path) -> subprocess.Popen:
    env = dict(os.environ, COSMOS_LITE_QUIET="1")
    args = ["curate", f"input={inp}", f"output={out}", *SMALL]
    return subprocess.Popen([sys.executable, "-m", "cosmos_lite.cli", *args], env=env, cwd=ROOT)


def test_sigkill_halfway_then_rerun_equals_an_uninterrupted_run(sintel_10s, sintel_30s, tmp_path):
    inp = tmp_path / "in"
    inp.mkdir()
    (inp / "a.mp4").symlink_to(sintel_10s)
    (inp / "b.mp4").symlink_to(sintel_30s)
    full, killed = tmp_path / "full", tmp_path / "killed"
    assert _run_cli(inp, full).wait() == 0
    n_full = len(_metas(full))
    proc = _run_cli(inp, killed)
    deadline = time.time() + 120
    while time.time() < deadline and len(list((killed / "metas").glob("*.json"))) < n_full // 2:
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert 0 < len(list((killed / "metas").glob("*.json"))) < n_full
    assert _run_cli(inp, killed).wait() == 0
    a, b = _metas(full), _metas(killed)
    assert a.keys() == b.keys()
    assert a == b
    assert sorted(p.name for p in (full / "clips").iterdir()) == sorted(p.name for p in (killed / "clips").iterdir())
    assert [p for p in killed.rglob("*") if p.name.startswith(".")] == []


@pytest.mark.slow
def test_ray_runner_matches_local(sintel_10s, tmp_path):
    inp = tmp_path / "in"
    inp.mkdir()
    for name in ("a.mp4", "b.mp4"):
        (inp / name).symlink_to(sintel_10s)
    local = curate(_cfg(inp, tmp_path / "local", *SMALL, "filters.duplicate.action=score"))
    ray = curate(_cfg(inp, tmp_path / "ray", *SMALL, "filters.duplicate.action=score", "runner=ray", "workers=2"))
    assert _metas(tmp_path / "local") == _metas(tmp_path / "ray")
    assert ray["clips_kept"] == local["clips_kept"] > 0


@pytest.mark.slow
def test_ray_runner_restarts_dead_workers_and_reports_items_that_always_kill_them(tmp_path):
    import ray

    from cosmos_lite.curation import Stage, run_ray
    from cosmos_lite.curation.pipeline import RayConfig

    class Crashes(Stage):
        """Item (flag, value): the worker dies on the first try (every try when value < 0), then doubles it."""

        def process(self, batch):
            flag, value = batch[0]
            if value < 0 or not Path(flag).exists():
                Path(flag).touch()
                os._exit(1)
            return [value * 2]

        def failed(self, item, error):
            return [("failed", item[1], type(error).__name__)]

    items = [(str(tmp_path / f"flag{i}"), i) for i in (-1, 1, 2, 3)]
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        results = list(run_ray(Crashes(), items, 2, RayConfig(max_retries=1, pin_cpus=False)))
        assert sorted(r for r in results if not isinstance(r, tuple)) == [2, 4, 6]  # a worker died 2+ times
        assert [r[:2] for r in results if isinstance(r, tuple)] == [("failed", -1)]
    finally:
        ray.shutdown()


def test_an_input_that_kills_its_worker_is_marked_failed_without_clips(sintel_10s, tmp_path):
    from cosmos_lite.curation.pipeline import VideoCurator, input_key, write_json

    out = tmp_path / "out"
    curator = VideoCurator(_cfg(tmp_path, out), out)
    write_json(out / "metas" / "c1.json", {"id": "c1", "source": "a.mp4"})
    write_json(out / "metas" / "c2.json", {"id": "c2", "source": "b.mp4"})
    (out / "clips").mkdir()
    (out / "clips" / "c1.mp4").write_bytes(b"partial")
    [marker] = curator.failed((sintel_10s, "a.mp4"), RuntimeError("worker died"))
    assert marker["status"] == "failed" and "died on every try" in marker["reason"] and marker["clips"] == []
    assert json.loads((out / "markers" / f"{input_key('a.mp4')}.json").read_text()) == marker
    assert [p.name for p in (out / "metas").iterdir()] == ["c2.json"] and not list((out / "clips").iterdir())


def test_dropped_and_kept_clips_encode_only_kept(tmp_path, moving_square):
    inp = tmp_path / "in"
    inp.mkdir()
    still = np.repeat(moving_square[:1], 48, 0)
    write_video(inp / "moving.mp4", np.concatenate([moving_square, moving_square[::-1]]), fps=24)
    write_video(inp / "still.mp4", still, fps=24)
    out = tmp_path / "out"
    s = curate(_cfg(inp, out, "filters.sharpness.action=score", "filters.resolution.min_short_side=32"))
    metas = list(_metas(out).values())
    by_source = {m["source"]: m for m in metas}
    assert by_source["moving.mp4"]["kept"] and by_source["still.mp4"]["dropped_by"] == ["motion"]
    assert s["dropped_by"] == {"motion": 1} and len(list((out / "clips").iterdir())) == 1
    # an input that changed since is curated again, and its old clips go
    old_id = by_source["moving.mp4"]["id"]
    write_video(inp / "moving.mp4", np.concatenate([moving_square, moving_square[::-1], moving_square]), fps=24)
    s = curate(_cfg(inp, out, "filters.sharpness.action=score", "filters.resolution.min_short_side=32"))
    metas = _metas(out)
    assert s["frames_processed"] == 72 and old_id not in metas and len(metas) == 2
    assert {p.stem for p in (out / "clips").iterdir()} == {k for k, m in metas.items() if m["kept"]} != {old_id}
