"""Curation throughput and splitter accuracy, each against a baseline measured in the same run.

1. `cosmos-lite curate` vs PySceneDetect's `detect-content split-video` (one ffmpeg per scene),
   same input, size, CRF and preset, both as fresh processes (target: ours >= 2x faster).
2. Our in-process job vs its lower bound: one decode of the input (RGB, streamed) plus one
   encode of exactly the frames we keep (target: <= 1.3x).
3. 1 vs 2 Ray workers (1 CPU each) on 8 videos, Ray already started (target: >= 1.7x).
4. Each splitter scored by `split.evaluate`: hard-cut F1 (+-2 frames) on the annotated Sintel clip and on the
   synthetic set (`curation.evalset`: dissolves, fades and wipes of 8, 16 and 30 frames between real shots),
   gradual-transition F1 on the synthetic set (per kind too), frames/s, clips holding a cut or transition frame
   (targets for fast: Sintel cut F1 >= 0.93, gradual F1 >= 0.9, no such clip, >= 2,000 frames/s).

[1] and [2] run their sides interleaved and also print CPU seconds (this process and its children) and
their ratio: on a machine shared with other jobs wall time swings, CPU time much less ([3] prints the CPU
seconds the Ray workers report).

    .venv/bin/python bench/curate.py [--video PATH] [--repeats 3] [--ray-videos 8] [--parts pipeline,ray,splitters]
                                     [--split test|dev] [--seed 0]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import imageio_ffmpeg
import torch

from cosmos_lite.config import load_config
from cosmos_lite.curation import CurateConfig, build_splitter, combine, curate, detect, detect_frames, evaluate
from cosmos_lite.curation.evalset import synthetic_set
from cosmos_lite.curation.pipeline import output_size
from cosmos_lite.curation.split import ANALYSIS_SIZE, is_blank, resize
from cosmos_lite.video import iter_frames, probe, read_frames, write_video

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("COSMOS_LITE_DATA", ROOT.parent / "shared" / "data"))
BIN = Path(sys.executable).parent
CRF, PRESET = 23, "veryfast"


def timed(fns: list, repeats: int) -> list[tuple[float, float]]:
    """Median wall and CPU seconds (this process and its children) of each function, calls interleaved.

    Interleaving (a, b, a, b, ...) lets a change in the load of a shared machine hit every side alike; CPU time
    barely moves with that load, so its ratios stay meaningful when wall time does not.
    """
    def cpu() -> float:
        return sum(r.ru_utime + r.ru_stime for r in map(resource.getrusage, (resource.RUSAGE_SELF,
                                                                              resource.RUSAGE_CHILDREN)))

    walls, cpus = [[] for _ in fns], [[] for _ in fns]
    for _ in range(repeats):
        for k, fn in enumerate(fns):
            t, c = time.perf_counter(), cpu()
            fn()
            walls[k].append(time.perf_counter() - t)
            cpus[k].append(cpu() - c)
    return [(statistics.median(w), statistics.median(c)) for w, c in zip(walls, cpus)]


def run_ours_cli(inp: Path, out: Path) -> None:
    shutil.rmtree(out, ignore_errors=True)
    cmd = [str(BIN / "cosmos-lite"), "curate", f"input={inp}", f"output={out}", f"transcode.crf={CRF}"]
    subprocess.run([*cmd, f"transcode.preset={PRESET}"], check=True, capture_output=True)


def run_scenedetect(video: Path, out: Path, path_env: str) -> None:
    shutil.rmtree(out, ignore_errors=True)
    cmd = [str(BIN / "scenedetect"), "-q", "-i", str(video), "-o", str(out), "detect-content"]
    cmd += ["split-video", "-p", PRESET, "-crf", str(CRF)]
    subprocess.run(cmd, check=True, capture_output=True, env=dict(os.environ, PATH=path_env))


def job_config(inp: Path, out: Path, *extra: str) -> CurateConfig:
    overrides = [f"input={inp}", f"output={out}", f"transcode.crf={CRF}", f"transcode.preset={PRESET}", *extra]
    return CurateConfig.from_node(load_config("curate", overrides))


def decode_once(video: Path) -> None:
    """Lower bound, part 1: one streamed RGB decode of the input."""
    for _ in iter_frames(video):
        pass


def encode_spans(frames, spans: list[tuple[int, int]], fps: float, tmp: Path) -> None:
    """Lower bound, part 2: encode exactly the kept spans (frames already in memory)."""
    for k, (s, e) in enumerate(spans):
        write_video(tmp / f"lb{k}.mp4", frames[s:e], fps, crf=CRF, preset=PRESET)


def bench_pipeline(video: Path, repeats: int, tmp: Path) -> None:
    inp = tmp / "in"
    inp.mkdir()
    (inp / video.name).symlink_to(video)
    fake_bin = tmp / "bin"  # split-video runs `ffmpeg`: the one imageio-ffmpeg ships
    fake_bin.mkdir()
    (fake_bin / "ffmpeg").symlink_to(imageio_ffmpeg.get_ffmpeg_exe())
    path_env = f"{fake_bin}{os.pathsep}{os.environ.get('PATH', '')}"

    (base, base_cpu), (ours_cli, ours_cli_cpu) = timed(
        [lambda: run_scenedetect(video, tmp / "sd", path_env), lambda: run_ours_cli(inp, tmp / "cli")], repeats)
    n_sd = len(list((tmp / "sd").glob("*.mp4")))
    print(f"[1] scenedetect detect-content split-video: {base:.2f} s wall, {base_cpu:.2f} s CPU ({n_sd} clips)")
    print(f"    cosmos-lite curate (process):            {ours_cli:.2f} s wall, {ours_cli_cpu:.2f} s CPU")
    print(f"    speedup: {base / ours_cli:.2f}x wall, {base_cpu / ours_cli_cpu:.2f}x CPU (target >= 2)")

    def job():
        shutil.rmtree(tmp / "job", ignore_errors=True)
        curate(job_config(inp, tmp / "job"))

    job()  # the kept spans, for the lower bound
    metas = [json.loads(p.read_text()) for p in (tmp / "job" / "metas").glob("*.json")]
    spans = sorted(tuple(m["span"]) for m in metas if m["kept"])
    fps = probe(video).fps
    frames = read_frames(video)
    (ours, ours_cpu), (decode, decode_cpu), (encode, encode_cpu) = timed(
        [job, lambda: decode_once(video), lambda: encode_spans(frames, spans, fps, tmp)], repeats)
    kept = sum(e - s for s, e in spans)
    lb, lb_cpu = decode + encode, decode_cpu + encode_cpu
    print(f"[2] lower bound: decode {decode:.2f} s + encode of {kept} kept frames {encode:.2f} s = {lb:.2f} s wall, "
          f"{lb_cpu:.2f} s CPU")
    print(f"    curate() in process: {ours:.2f} s wall, {ours_cpu:.2f} s CPU; ratio {ours / lb:.2f}x wall, "
          f"{ours_cpu / lb_cpu:.2f}x CPU (target <= 1.3)")


def bench_ray(video: Path, n: int, repeats: int, tmp: Path) -> None:
    import ray

    inp = tmp / "ray_in"
    inp.mkdir()
    for k in range(n):
        (inp / f"v{k}.mp4").symlink_to(video)
    os.environ.setdefault("RAY_AUTH_MODE", "disabled")
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        times, cpus, clips = {1: [], 2: []}, {1: [], 2: []}, {}
        for _ in range(repeats):  # interleaved, as in timed()
            for w in (1, 2):
                shutil.rmtree(tmp / f"ray{w}", ignore_errors=True)
                cfg = job_config(inp, tmp / f"ray{w}", "runner=ray", f"workers={w}", "filters.duplicate.action=score")
                t = time.perf_counter()
                s = curate(cfg)
                times[w].append(time.perf_counter() - t)
                cpus[w].append(s["cpu_seconds"])
                clips[w] = s["clips_kept"]
        med = {w: statistics.median(v) for w, v in times.items()}
        for w in (1, 2):
            print(f"[3] Ray, {w} worker(s), {n} videos: {med[w]:.2f} s wall (median of {repeats}: "
                  f"{', '.join(f'{t:.2f}' for t in times[w])}; {clips[w]} clips); "
                  f"{statistics.median(cpus[w]):.1f} CPU-s in the workers")
        print(f"    speedup 2 vs 1 workers: {med[1] / med[2]:.2f}x (target >= 1.7)")
    finally:
        ray.shutdown()


def bench_splitters(video: Path, cuts: Path, split: str, seed: int) -> None:
    ann = json.loads(cuts.read_text())
    frames = read_frames(video, size=(160, 284))  # the largest size a splitter reads
    synthetic = synthetic_set(video, split, seed)
    kinds = sorted({s.annotation["kind"] for s in synthetic})
    n_gradual = sum(len(s.annotation["gradual_transitions"]) for s in synthetic)
    n_cuts = sum(len(s.annotation["hard_cuts"]) for s in synthetic)
    print(f"[4] splitters: hard cuts on the annotated Sintel clip, gradual transitions on the synthetic {split} split "
          f"(seed {seed}: {n_gradual} dissolves, fades and wipes of 8-30 frames between real shots, {n_cuts} cuts)")
    print(f"    {'method':<10} {'Sintel cut F1':>13} {'synth cut F1':>12} {'gradual F1 (P/R)':>18} "
          f"{' '.join(f'{k:>8}' for k in kinds)} {'frames/s':>9} {'bad clips':>9} {'kept':>5}")
    fast_sintel = None
    for method in ("fast", "content", "adaptive", "transnetv2", "stride"):
        splitter = build_splitter(method)
        small = [resize(f, splitter.size) for f in frames]
        splitter.reset(probe(video).fps)
        t = time.perf_counter()
        n = sum(len(splitter.push(f)) for f in small) + len(splitter.flush())
        fps = n / (time.perf_counter() - t)
        sintel = evaluate(detect(video, splitter), ann)
        fast_sintel = fast_sintel or sintel
        per_video = [evaluate(detect_frames(s.frames, s.fps, splitter), s.annotation) for s in synthetic]
        synth = combine(per_video)
        by_kind = " ".join(
            f"{combine([r for r, s in zip(per_video, synthetic) if s.annotation['kind'] == k])['gradual_f1']:8.3f}"
            for k in kinds)
        both = combine([sintel, synth])
        bad = len(both["clips_with_cut"]) + len(both["clips_in_transition"])
        print(f"    {method:<10} {sintel['f1']:13.3f} {synth['f1']:12.3f} {synth['gradual_f1']:8.3f} "
              f"({synth['gradual_precision']:.2f}/{synth['gradual_recall']:.2f}) {by_kind} {fps:9.0f} {bad:9d} "
              f"{both['kept']:5.2f}")
    print("    bad clips: clips (Sintel and synthetic) holding a hard cut or a transition frame; "
          "kept: share of frames in clips")
    print(f"    fast on Sintel's gradual transitions: F1 {fast_sintel['gradual_f1']:.3f} "
          "(annotated +-3 frames, and some of its fades are not annotated: not a target)")
    t = time.perf_counter()
    for f in frames:
        is_blank(resize(f, ANALYSIS_SIZE))
    print(f"    blank-frame check (all splitters): {len(frames) / (time.perf_counter() - t):.0f} frames/s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--video", type=Path, default=DATA / "sintel_trailer_30s.mp4")
    ap.add_argument("--cuts", type=Path, default=DATA / "sintel_trailer_30s.cuts.json")
    ap.add_argument("--ray-video", type=Path, default=DATA / "sintel_trailer_10s.mp4")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--ray-videos", type=int, default=8)
    ap.add_argument("--parts", default="pipeline,ray,splitters", help="which of pipeline ([1], [2]), ray, splitters")
    ap.add_argument("--split", default="test", choices=("dev", "test"), help="synthetic split for [4] (tune on dev)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the synthetic split")
    args = ap.parse_args()
    os.environ.setdefault("COSMOS_LITE_QUIET", "1")
    torch.set_num_threads(2)
    info = probe(args.video)
    print(
        f"input {args.video.name}: {info.num_frames} frames {info.width}x{info.height} @ {info.fps:g}; "
        f"output {output_size(info.size, None)[::-1]} libx264 CRF {CRF} {PRESET}; medians of {args.repeats}"
    )
    parts = set(args.parts.split(","))
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        if "pipeline" in parts:
            bench_pipeline(args.video, args.repeats, tmp)
        if "ray" in parts:
            bench_ray(args.ray_video, args.ray_videos, args.repeats, tmp)
    if "splitters" in parts:
        bench_splitters(args.video, args.cuts, args.split, args.seed)


if __name__ == "__main__":
    main()
