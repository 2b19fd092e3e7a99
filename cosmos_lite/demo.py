"""The whole toolkit end to end on a small embedded default: simulate physics episodes, curate them together with
the Sintel clip, train the nano tokenizer and the nano world model on the episodes, generate guarded videos (one
allowed prompt with actions, one the pre-guard blocks) and write the physics-alignment report.

Example: `cosmos-lite demo out=demo_out` (what `make demo` runs). Each stage runs the same subcommand a user would;
finished stages are cached in out/.stages/ so a rerun is quick (force=true reruns everything); an interrupted
training stage resumes where it stopped.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from omegaconf import DictConfig, OmegaConf

from .errors import ConfigError
from .files import write_text
from .log import get_logger

log = get_logger("demo")
SINTEL = "sintel_trailer_10s.mp4"
HELD_OUT_SEED = 10_000  # held-out generation episodes are seeded far from the training seeds


def sintel_clip(data: str | None) -> Path | None:
    """The Sintel test clip: data=DIR, else $COSMOS_LITE_DATA, else ../shared/data beside the repository."""
    root = Path(__file__).resolve().parent.parent
    folder = Path(data or os.environ.get("COSMOS_LITE_DATA") or root.parent / "shared" / "data")
    path = folder / SINTEL
    return path if path.is_file() else None


class Stages:
    """Runs named stages in order, once: a stage whose recorded arguments match is skipped on the next run, unless a
    stage before it ran again (its output changed). A stage that starts over first clears its output folder; one
    that was interrupted with the same arguments keeps it (training resumes from its checkpoint)."""

    def __init__(self, out: Path, force: bool):
        self.dir, self.force, self.timings, self.ran = out / ".stages", force, {}, False
        self.dir.mkdir(parents=True, exist_ok=True)

    def _record(self, marker: Path, record: dict) -> None:
        write_text(marker, json.dumps(record, indent=1, default=str))

    def run(self, name: str, key: dict, fn: Callable[[], dict | None], output: Path | None = None) -> dict:
        marker = self.dir / f"{name}.json"
        done = json.loads(marker.read_text()) if marker.is_file() else None
        same = done is not None and done["key"] == key and not (self.force or self.ran)
        if same and done.get("status", "done") == "done":
            log.info("[%s] cached (%.0f s when it ran)", name, done["seconds"])
            self.timings[name] = 0.0
            return done["result"]
        if output is not None and not same:
            shutil.rmtree(output, ignore_errors=True)
        log.info("[%s] %s", name, "resuming" if same else "running")
        self._record(marker, {"key": key, "status": "running"})
        self.ran = True
        t0 = time.perf_counter()
        result = fn() or {}
        seconds = time.perf_counter() - t0
        self.timings[name] = seconds
        self._record(marker, {"key": key, "status": "done", "seconds": seconds, "result": result})
        log.info("[%s] done in %.0f s", name, seconds)
        return result


def cli(*args: str) -> None:
    """Run a subcommand in-process, exactly as `cosmos-lite ARGS` would (errors propagate with their exit code)."""
    from .cli import run

    code = run(list(args))
    if code:
        raise ConfigError(f"`cosmos-lite {' '.join(args)}` exited with {code}")


def generate_examples(cfg: DictConfig, out: Path) -> list[dict]:
    """One allowed generation (a held-out pusher episode's first frame, actions and caption) and one prompt that the
    pre-guard blocks, through the guarded pipeline as `cosmos-lite generate` runs it."""
    from PIL import Image

    from .guardrails import Guardrails
    from .models import WorldModelPipeline
    from .models.cli import generate_one
    from .sim import simulate

    gen = out / "generate"
    gen.mkdir(parents=True, exist_ok=True)
    pipe = WorldModelPipeline.from_pretrained(out / "wfm", guardrails=Guardrails.from_config())
    window = int(pipe.cfg.data.num_frames)
    episode = {"scenario": "pusher", "seed": HELD_OUT_SEED, "frames": window, "size": pipe.size}
    ep = simulate(**episode)
    Image.fromarray(ep.frames[0]).save(gen / "pusher_first_frame.png")
    np.save(gen / "pusher_actions.npy", ep.actions)
    base = {"input_frames": 1, "num_frames": window, "sampler": "euler",
            "guidance": 1.0, "action_guidance": 1.0, "seed": int(cfg.seed)}
    allowed = {**base, "prompt": cfg.generate.prompt or ep.meta["caption"], "name": "allowed_pusher",
               "input": str(gen / "pusher_first_frame.png"), "actions": str(gen / "pusher_actions.npy")}
    blocked = {**base, "prompt": cfg.generate.blocked_prompt, "input": None, "actions": None, "name": "blocked"}
    records, config = [], OmegaConf.to_container(cfg, resolve=True)
    for title, req, truth in (("allowed: held-out pusher, first frame + actions", allowed, episode),
                              ("blocked by the pre-guard", blocked, None)):
        rec = generate_one(pipe, req, gen, config=config)
        last = rec["verdicts"][-1] if rec["verdicts"] else {"allowed": True, "guard": "", "reason": ""}
        records.append({"title": title, "prompt": req["prompt"], "allowed": rec["status"] == "ok",
                        "guard": last["guard"], "reason": last["reason"], "video": rec["video"], "gif": None,
                        "name": req["name"], "fps": ep.meta["fps"], "truth": truth})
        log.info("generate %s: %s (%s)", req["name"], rec["status"], last["reason"] or last["guard"])
    return records


def add_generations(results: dict, records: list[dict], report: Path) -> dict:
    """Show the guarded generations in the report: the allowed one beside its simulator ground truth."""
    from .eval.report import write_report, write_side_by_side
    from .sim import simulate
    from .video import read_frames

    shown = []
    for rec in records:
        video, rec = rec["video"], {**rec, "video": None, "gif": None}
        if video and rec["truth"]:
            truth = simulate(**rec["truth"]).frames
            rec["video"], rec["gif"] = write_side_by_side(report, f"generation_{rec['name']}", truth,
                                                          read_frames(video), rec["fps"])
        shown.append(rec)
    results["generations"] = shown
    write_report(results, report)
    return results


def main(cfg: DictConfig, args: list[str]) -> int:
    out = Path(cfg.out)
    stages = Stages(out, bool(cfg.force))
    t0 = time.perf_counter()
    scenarios = list(cfg.sim.scenarios)
    episodes = out / "episodes"
    stages.run("simulate", {"scenarios": scenarios, "episodes": cfg.sim.episodes, "seed": cfg.seed}, lambda: cli(
        "sim", f"out={episodes}", f"sim.scenario=[{','.join(scenarios)}]", f"sim.episodes={cfg.sim.episodes}",
        f"seed={cfg.seed}"), output=episodes)

    raw, curated = out / "raw", out / "curated"
    sintel = sintel_clip(cfg.data)
    if sintel is None:
        log.warning("%s not found (set data=DIR or COSMOS_LITE_DATA): curating the simulator episodes only", SINTEL)

    def curate() -> dict:
        for d in (raw, curated):  # a fresh job: curation refuses to resume into output made with other settings
            shutil.rmtree(d, ignore_errors=True)
        raw.mkdir(parents=True)
        for src in [*sorted(episodes.glob("*.mp4")), *([sintel] if sintel else [])]:
            (raw / src.name).symlink_to(src.resolve())
        cli("curate", f"input={raw}", f"output={curated}", f"transcode.size={cfg.curate.size}")
        return json.loads((curated / "summary.json").read_text())

    summary = stages.run("curate", {"size": cfg.curate.size, "sintel": str(sintel), "episodes": cfg.sim.episodes},
                         curate)
    tok = out / "tokenizer"
    # The world model's tokenizer learns from the episodes as simulated, like the world model: on the curated clips
    # (H.264 at crf 23, chroma at half resolution) its reconstruction object IoU was 0.53 against 0.66 (same steps).
    stages.run("tokenizer", {"experiment": cfg.tokenizer.experiment, "minutes": cfg.tokenizer.minutes,
                             "data": "episodes"}, lambda: cli(
        "train", f"experiment={cfg.tokenizer.experiment}", f"data.roots=[{episodes}]", f"out={tok}",
        f"trainer.max_minutes={cfg.tokenizer.minutes}", f"seed={cfg.seed}"), output=tok)
    wfm = out / "wfm"
    stages.run("wfm", {"experiment": cfg.wfm.experiment, "minutes": cfg.wfm.minutes}, lambda: cli(
        "train", f"experiment={cfg.wfm.experiment}", f"data.roots=[{episodes}]", f"tokenizer.path={tok}",
        f"out={wfm}", f"trainer.max_minutes={cfg.wfm.minutes}", f"seed={cfg.seed}"), output=wfm)
    generations = stages.run("generate", OmegaConf.to_container(cfg.generate),
                             lambda: {"records": generate_examples(cfg, out)}, output=out / "generate")

    report = out / "report"

    def evaluate() -> dict:
        from .config import load_config
        from .eval.physics import run_physics_eval

        ecfg = load_config("eval", [f"checkpoint={wfm}", f"out={report}", f"episodes={cfg.eval.episodes}",
                                    f"scenarios=[{','.join(scenarios)}]",
                                    f"conditions=[{','.join(cfg.eval.conditions)}]"])
        results = run_physics_eval(ecfg)
        return add_generations(results, generations["records"], report)

    results = stages.run("eval", OmegaConf.to_container(cfg.eval), evaluate, output=report)
    print_summary(results, summary, stages.timings, time.perf_counter() - t0, report / "report.html")
    return 0


def headline(results: dict) -> list[str]:
    """The main table as text, and per number of given frames whether the world model beats copy-last-frame."""
    rows = results["table"]
    lines = [f"{'model':<34}{'given':>6}{'PSNR':>8}{'SSIM':>8}{'IoU':>8}"]
    for r in rows:
        lines.append(f"{r['model']:<34}{r['given']:>6}" + "".join(
            f"{r[m]:>8.3f}" if r[m] is not None else f"{'-':>8}" for m in ("psnr", "ssim", "iou")))
    for k in dict.fromkeys(r["given"] for r in rows):
        base = next(r for r in rows if r["given"] == k and r["model"] == "copy last frame")
        for r in (r for r in rows if r["given"] == k and r["model"].startswith("world model")):
            wins = [m for m in ("psnr", "ssim", "iou") if None not in (r[m], base[m]) and r[m] > base[m]]
            lines.append(f"{r['model']}, {k} given, beats copy-last-frame on: {', '.join(wins) or 'nothing'}")
    return lines


def print_summary(results: dict, curated: dict, timings: dict, seconds: float, html: Path) -> None:
    """The closing summary: what each stage made and took, the headline numbers, where the report is."""
    lines = ["", f"cosmos-lite demo finished in {seconds / 60:.1f} min"]
    lines += [f"  {name:<10} {t / 60:5.1f} min" if t else f"  {name:<10} cached" for name, t in timings.items()]
    lines.append(f"  curated clips: {curated.get('clips_kept')} kept, {curated.get('clips_dropped')} dropped")
    lines += ["  " + ln for ln in headline(results)]
    for g in results.get("generations", []):
        lines.append(f"  generate [{'allowed' if g['allowed'] else 'BLOCKED'}] {g['prompt']!r}"
                     + ("" if g["allowed"] else f" ({g['guard']}: {g['reason']})"))
    lines.append(f"  report: {html.resolve()}")
    print("\n".join(lines))
