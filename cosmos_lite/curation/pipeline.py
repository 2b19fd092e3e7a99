"""The curation job: one decode pass per video feeds the splitter, the filters and the encoder.

Output (DESIGN.md): `clips/<id>.mp4` for kept clips, `metas/<id>.json` for every clip (kept or
dropped, with scores and reasons), `markers/<key>.json` per finished input (done or failed),
`summary.json`, and `settings.json` (what decides the clips). Ids are uuid5 of source and span,
every file is written to a temp name and renamed, and a rerun skips inputs with a marker and
reuses clips already encoded, so a killed job resumed gives the same output as one that was
never interrupted; a rerun with other settings is refused rather than mixing clips of both.
"""

from __future__ import annotations

import json
import os
import queue
import tarfile
import threading
import time
import uuid
from collections import Counter, deque
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path

from omegaconf import DictConfig

from ..config import bad, setting, to_dataclass
from ..errors import ConfigError, CosmosError, InputError
from ..files import atomic_path, remove_temp_files, write_text
from ..log import debugging, get_logger, progress
from ..video import frame_size, iter_frames, probe, write_video
from .filters import Clip, DuplicateFilter, build_filters, dedup, phash
from .runners import Stage, run_local, run_ray
from .split import ANALYSIS_SIZE, SPLITTERS, Segmenter, build_splitter, is_blank, resize

log = get_logger("curation")
ID_NAMESPACE = uuid.UUID("5a1e3c0d-7c1f-4b8e-9d2a-c0505e11e000")
VIDEO_EXTENSIONS = [".mp4", ".mov", ".mkv", ".avi", ".webm", ".m4v", ".mpg", ".mpeg", ".ts"]
X264_PRESETS = ["ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower", "veryslow",
                "placebo"]


@dataclass
class SplitConfig:
    # fast (ours: hard cuts, and dissolves, fades, wipes kept out of clips) | transnetv2 | content | adaptive | stride
    method: str = setting("fast", choices=tuple(SPLITTERS))
    max_seconds: float = setting(10.0, above=0)  # longer shots are cut into pieces of this length
    fast: dict = field(default_factory=dict)  # parameters of each method
    transnetv2: dict = field(default_factory=dict)
    content: dict = field(default_factory=dict)
    adaptive: dict = field(default_factory=dict)
    stride: dict = field(default_factory=dict)


@dataclass
class TranscodeConfig:
    size: int | None = setting(None, low=2)  # short side in pixels (aspect kept, even, never upscaled); None: source
    fps: float | None = setting(None, above=0)  # None: source rate
    crf: int = setting(23, low=0, high=51)
    preset: str = setting("veryfast", choices=X264_PRESETS)


@dataclass
class RayConfig:
    address: str | None = None  # None: start a local Ray; "auto": join the running cluster
    num_cpus: float = 1  # per worker; workers limit their threads to it
    max_retries: int = 2  # retries of a task whose worker died (the worker is restarted); then the input fails
    pin_cpus: bool = True  # pin local workers to distinct cores so each really uses num_cpus


@dataclass
class CurateConfig:
    input: str | None = None
    output: str | None = None
    runner: str = setting("local", choices=("local", "ray"))  # local | ray (implied by workers > 1 or ray.address)
    workers: int = setting(1, low=1)
    encoders: int | None = setting(None, low=1)  # clips encoded at once per video; None: the cores this process may use
    extensions: list[str] = field(default_factory=lambda: list(VIDEO_EXTENSIONS))
    split: SplitConfig = field(default_factory=SplitConfig)
    transcode: TranscodeConfig = field(default_factory=TranscodeConfig)
    filters: dict = field(default_factory=dict)
    ray: RayConfig = field(default_factory=RayConfig)
    clips_per_shard: int = setting(0, low=0)  # > 0: also write webdataset-style shards/shard-NNNNNN.tar of kept clips

    @classmethod
    def from_node(cls, node: DictConfig | dict) -> CurateConfig:
        """Build from the composed `curate` config, checking every key."""
        cfg = to_dataclass(cls, node)  # nested nodes too (split, transcode, ray)
        if cfg.ray.address or cfg.workers > 1:
            cfg.runner = "ray"
        build_filters(cfg.filters)
        return cfg


def output_size(size: tuple[int, int], short_side: int | None) -> tuple[int, int]:
    """Even (H, W) with the given short side, keeping aspect ratio; never larger than the source."""
    h, w = size
    if short_side and short_side < min(h, w):
        s = short_side / min(h, w)
        h, w = round(h * s), round(w * s)
    return max(2, h - h % 2), max(2, w - w % 2)


def clip_id(source: str, start: int, end: int, fps: float) -> str:
    """Deterministic clip id: uuid5 of the source (relative path) and the span at the processing rate."""
    return str(uuid.uuid5(ID_NAMESPACE, f"{source}:{start}:{end}@{fps:g}"))


def input_key(source: str) -> str:
    return str(uuid.uuid5(ID_NAMESPACE, source))


def output_settings(cfg: CurateConfig) -> dict:
    """The settings that decide which clips an input yields and how they are encoded (not where it runs)."""
    split = {"method": cfg.split.method, "max_seconds": cfg.split.max_seconds,
             "params": getattr(cfg.split, cfg.split.method) or {}}
    return json.loads(json.dumps({"split": split, "transcode": asdict(cfg.transcode), "filters": cfg.filters}))


def check_settings(out: Path, settings: dict) -> None:
    """Record the job's output settings in `out/settings.json`; refuse to resume a job made with other ones.

    A rerun reuses finished inputs and already-encoded clips, so mixing settings would mix clips of both.
    """
    path = out / "settings.json"
    if path.is_file():
        old = json.loads(path.read_text())
        if old != settings:
            diff = sorted(k for k in settings if old.get(k) != settings[k])
            raise ConfigError(
                f"output={out} holds clips curated with other {', '.join(diff)} settings (see {path}); "
                "rerun with those settings, or choose a new output=DIR (or delete the old one)"
            )
    else:
        write_json(path, settings)


def write_json(path: Path, data: dict) -> None:
    """Write JSON atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text(path, json.dumps(data, indent=1, sort_keys=True))


def list_inputs(root: Path, extensions: list[str]) -> list[tuple[Path, str]]:
    """(path, source name relative to the input) of every video-named file under `root`, sorted."""
    if root.is_file():
        return [(root, root.name)]
    if not root.is_dir():
        raise InputError(f"input={root}: no such file or folder. Pass input=DIR (or a video file).")
    exts = {e.lower() for e in extensions}
    files = sorted(p for p in root.rglob("*") if p.suffix.lower() in exts and not p.name.startswith("."))
    return [(p, p.relative_to(root).as_posix()) for p in files if p.is_file()]


def _fingerprint(path: Path) -> dict:
    st = path.stat()
    return {"size": st.st_size, "mtime_ns": st.st_mtime_ns}


def usable_cores() -> int:
    """Cores this process may run on (a pinned Ray worker: its own ones)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


class ClipEncoder:
    """Encodes kept clips on `workers` background threads, so libx264 overlaps with decoding the next clip and with
    other clips: each clip's encoder drains its frame-thread pipeline at the end, which leaves cores idle when short
    clips are encoded one at a time (on Sintel 30 s, 10 clips: 2.5 s one at a time, 2.0 s two at once).

    While the video is still being decoded, each encoder runs libx264 on `cores // workers` threads (one, with one
    encoder per core): the clips already keep the cores busy, and a single-threaded x264 spends ~7% less CPU per
    frame than a frame-threaded one. Clips submitted after `last_clips()` (nothing left to decode) get all cores.

    At most one clip waits in the queue (memory: workers + 2 clips at most, the one being built
    included). The meta is written after its clip, so an existing meta means a finished clip.
    """

    def __init__(self, transcode: TranscodeConfig, workers: int = 1):
        self.tc = transcode
        self.encoder_threads = max(1, usable_cores() // max(1, workers))
        self.jobs: queue.Queue = queue.Queue(maxsize=1)
        self.error: BaseException | None = None
        self.threads = [threading.Thread(target=self._loop, name=f"clip-encoder-{k}", daemon=True)
                        for k in range(max(1, workers))]
        for t in self.threads:
            t.start()

    def _loop(self) -> None:
        while (job := self.jobs.get()) is not None:
            mp4, clip, meta_path, meta, threads = job
            if self.error is not None:
                continue
            try:
                if not mp4.is_file():  # an interrupted run may already have encoded it
                    write_video(mp4, clip.frames, clip.fps, codec="libx264", crf=self.tc.crf, preset=self.tc.preset,
                                threads=threads)
                write_json(meta_path, meta)
            except BaseException as e:  # noqa: BLE001 - handed to the submitting thread
                self.error = e

    def submit(self, mp4: Path, clip: Clip, meta_path: Path, meta: dict) -> None:
        self._raise()
        self.jobs.put((mp4, clip, meta_path, meta, self.encoder_threads))

    def last_clips(self) -> None:
        """Nothing is left to decode: clips submitted from now on are encoded on all cores (libx264's own count)."""
        self.encoder_threads = 0

    def close(self, check: bool = True) -> None:
        """Wait for the queued clips; re-raise an encoding error when `check`."""
        for _ in self.threads:
            self.jobs.put(None)
        for t in self.threads:
            t.join()
        if check:
            self._raise()

    def _raise(self) -> None:
        if self.error is not None:
            raise self.error


class VideoCurator(Stage):
    """The per-video stage: items are (path, source name); each returns its marker (done or failed)."""

    def __init__(self, cfg: CurateConfig, out: Path):
        self.cfg, self.out = cfg, out
        self.filters = build_filters(cfg.filters)
        self.clip_filters = [f for f in self.filters if not isinstance(f, DuplicateFilter)]
        self.hash = any(isinstance(f, DuplicateFilter) for f in self.filters)
        self.splitter = None
        params = getattr(cfg.split, cfg.split.method, None) or {}
        gpu = cfg.split.method == "transnetv2" and str(params.get("device", "cpu")).startswith("cuda")
        self.resources = {"num_cpus": cfg.ray.num_cpus, "num_gpus": 1 if gpu else 0}

    def setup(self) -> None:
        s = self.cfg.split
        self.splitter = build_splitter(s.method, **(getattr(s, s.method, None) or {}))

    def process(self, batch: list[tuple[Path, str]]) -> list[dict]:
        return [self(path, source) for path, source in batch]

    def marker(self, source: str) -> dict | None:
        """The marker of a finished (done or failed) input, else None."""
        path = self.out / "markers" / f"{input_key(source)}.json"
        return json.loads(path.read_text()) if path.is_file() else None

    def done(self, path: Path, source: str) -> bool:
        """True when `source` has a marker written for the file as it is now (so a rerun skips it)."""
        m = self.marker(source)
        return m is not None and m.get("fingerprint") == _fingerprint(path)

    def _remove(self, clip_ids: list[str]) -> None:
        for cid in clip_ids:
            (self.out / "clips" / f"{cid}.mp4").unlink(missing_ok=True)
            (self.out / "metas" / f"{cid}.json").unlink(missing_ok=True)

    def __call__(self, path: Path, source: str) -> dict:
        """Split, filter and encode one video; always returns its marker (status done or failed)."""
        if self.splitter is None:
            self.setup()
        t0, cpu0 = time.perf_counter(), time.process_time()
        stale = self.marker(source)  # the input changed since it was curated: its old clips go
        if stale is not None:
            self._remove(stale["clips"])
        written: list[str] = []
        marker = {"source": source, "fingerprint": _fingerprint(path)}
        try:
            frames = self._run(path, source, written)
            marker.update(status="done", clips=written, frames=frames)
        except CosmosError as e:
            reason = str(e)
        except Exception as e:  # noqa: BLE001 - one bad input must not stop the job; the reason is kept
            if debugging():
                log.exception("%s: unexpected failure", source)
            reason = f"{path}: {type(e).__name__}: {e}"
        else:
            reason = None
        if reason is not None:
            self._remove(written)  # no partial output for a failed input
            marker.update(status="failed", reason=reason, clips=[], frames=0)
        marker["seconds"] = round(time.perf_counter() - t0, 3)
        marker["cpu_seconds"] = round(time.process_time() - cpu0, 3)  # this process, all threads
        write_json(self.out / "markers" / f"{input_key(source)}.json", marker)
        return marker

    def failed(self, item: tuple[Path, str], error: Exception) -> list[dict]:
        """The Ray worker died on every try of this input: remove the clips it wrote and mark it failed."""
        path, source = item
        metas = (json.loads(p.read_text()) for p in (self.out / "metas").glob("*.json"))
        self._remove([m["id"] for m in metas if m["source"] == source])
        reason = f"{path}: the worker died on every try ({type(error).__name__}); check the file and its size"
        marker = {"source": source, "fingerprint": _fingerprint(path), "status": "failed", "reason": reason,
                  "clips": [], "frames": 0, "seconds": 0.0, "cpu_seconds": 0.0}
        write_json(self.out / "markers" / f"{input_key(source)}.json", marker)
        return [marker]

    def _run(self, path: Path, source: str, written: list[str]) -> int:
        info = probe(path)
        tc = self.cfg.transcode
        fps = float(tc.fps or info.fps)
        hw = output_size(info.size, tc.size)
        splitter = self.splitter
        splitter.reset(fps)
        seg = Segmenter(round(self.cfg.split.max_seconds * fps))
        pending: deque = deque()  # (index, frame, small, blank) waiting for their label
        clip: Clip | None = None
        encoder = ClipEncoder(tc, self.cfg.encoders or usable_cores())

        def route(label: int) -> None:
            nonlocal clip
            i, frame, small, blank = pending.popleft()
            closed, joins = seg.step(i, label, blank)
            if closed:
                self._finish(clip, written, encoder)
                clip = None
            if joins:
                if clip is None:
                    clip = Clip(source, i, i, fps, info.size)
                clip.frames.append(frame)
                clip.small.append(small)
                clip.end = i + 1

        n = 0
        try:
            # yuv420p: the frames are only re-encoded (and previewed small), so they skip RGB both ways.
            for frame in iter_frames(path, size=None if hw == info.size else hw, fps=tc.fps, format="yuv420p"):
                small = resize(frame, ANALYSIS_SIZE)
                pending.append((n, frame, small, is_blank(small)))
                n += 1
                for label in splitter.push(small if splitter.size == ANALYSIS_SIZE else resize(frame, splitter.size)):
                    route(label)
            encoder.last_clips()
            for label in splitter.flush():
                route(label)
            if clip is not None:
                self._finish(clip, written, encoder)
        except BaseException:
            encoder.close(check=False)
            raise
        encoder.close()
        if n == 0:
            raise InputError(f"{path}: no frames could be decoded. Check that it is a complete video file.")
        return n

    def _finish(self, clip: Clip, written: list[str], encoder: ClipEncoder) -> None:
        """Score a closed clip; queue it for encoding (then its meta) if kept, else write its meta now."""
        cid = clip_id(clip.source, clip.start, clip.end, clip.fps)
        scores = {f.name: round(f.score(clip), 4) for f in self.clip_filters}
        passed = {f.name: f.passes(scores[f.name]) for f in self.clip_filters}
        dropped_by = [f.name for f in self.clip_filters if f.action == "drop" and not passed[f.name]]
        h, w = frame_size(clip.frames[0])
        meta = {
            "id": cid,
            "source": clip.source,
            "span": [clip.start, clip.end],
            "time": [round(clip.start / clip.fps, 4), round(clip.end / clip.fps, 4)],
            "fps": clip.fps,
            "num_frames": clip.end - clip.start,
            "size": [h, w],
            "source_size": list(clip.source_size),
            "splitter": self.cfg.split.method,
            "scores": scores,
            "passed": passed,
            "kept": not dropped_by,
            "dropped_by": dropped_by,
        }
        if self.hash:
            meta["phash"] = phash(clip)
        written.append(cid)
        meta_path = self.out / "metas" / f"{cid}.json"
        if meta["kept"]:
            encoder.submit(self.out / "clips" / f"{cid}.mp4", clip, meta_path, meta)
        else:
            write_json(meta_path, meta)


def clean_temp(out: Path) -> None:
    """Remove temp files a killed run left behind."""
    for sub in ("clips", "metas", "markers", "shards"):
        remove_temp_files(out / sub)


def finalize(cfg: CurateConfig, out: Path, inputs: list[tuple[Path, str]], wall: float, frames: int) -> dict:
    """Job-level steps over all finished inputs: near-duplicate filter, shards, `summary.json`."""
    markers = []
    for _, source in inputs:
        p = out / "markers" / f"{input_key(source)}.json"
        if p.is_file():
            markers.append(json.loads(p.read_text()))
    metas = [json.loads((out / "metas" / f"{cid}.json").read_text()) for m in markers for cid in m["clips"]]
    metas.sort(key=lambda m: (m["source"], m["span"][0]))
    dup = next((f for f in build_filters(cfg.filters) if isinstance(f, DuplicateFilter)), None)
    if dup is not None:
        for m in dedup(metas, dup):
            if not m["kept"]:
                (out / "clips" / f"{m['id']}.mp4").unlink(missing_ok=True)
            write_json(out / "metas" / f"{m['id']}.json", m)
    kept = [m for m in metas if m["kept"]]
    if cfg.clips_per_shard > 0:
        write_shards(out, kept, cfg.clips_per_shard)
    failed = [{"source": m["source"], "reason": m["reason"]} for m in markers if m["status"] == "failed"]
    summary = {
        "inputs": len(inputs),
        "inputs_done": sum(m["status"] == "done" for m in markers),
        "inputs_failed": len(failed),
        "failures": failed,
        "clips_kept": len(kept),
        "clips_dropped": len(metas) - len(kept),
        "dropped_by": dict(sorted(Counter(r for m in metas for r in m["dropped_by"]).items())),
        "kept_seconds": round(sum(m["num_frames"] / m["fps"] for m in kept), 3),
        "wall_seconds": round(wall, 3),
        "cpu_seconds": round(sum(m.get("cpu_seconds", 0.0) for m in markers), 3),  # all inputs, in the workers
        "frames_processed": frames,
        "frames_per_second": round(frames / wall, 2) if wall > 0 else None,
        "config": asdict(cfg),
    }
    write_json(out / "summary.json", summary)
    return summary


def write_shards(out: Path, kept: list[dict], per_shard: int) -> None:
    """Webdataset-style tar shards: `<id>.mp4` + `<id>.json` per kept clip, in id order."""
    kept = sorted(kept, key=lambda m: m["id"])
    shard_dir = out / "shards"
    shard_dir.mkdir(parents=True, exist_ok=True)
    names = set()
    for k in range(0, len(kept), per_shard):
        name = shard_dir / f"shard-{k // per_shard:06d}.tar"
        with atomic_path(name) as tmp, tarfile.open(tmp, "w") as tar:
            for m in kept[k : k + per_shard]:
                tar.add(out / "clips" / f"{m['id']}.mp4", arcname=f"{m['id']}.mp4")
                tar.add(out / "metas" / f"{m['id']}.json", arcname=f"{m['id']}.json")
        names.add(name.name)
    for stale in shard_dir.glob("shard-*.tar"):
        if stale.name not in names:
            stale.unlink()


def curate(cfg: CurateConfig) -> dict:
    """Run a whole curation job (local or Ray, as configured); returns the summary."""
    if not cfg.input or not cfg.output:
        raise ConfigError("curate needs input=DIR (videos) and output=DIR (clips, metas, summary.json)")
    out = Path(cfg.output)
    if out.resolve() == Path(cfg.input).resolve() or Path(cfg.input).resolve() in out.resolve().parents:
        raise bad("output", cfg.output, f"a folder outside input={cfg.input} (clips written there would be inputs)")
    inputs = list_inputs(Path(cfg.input), cfg.extensions)
    if not inputs:
        raise InputError(f"input={cfg.input}: no files ending in {', '.join(cfg.extensions)}. Check the folder.")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ConfigError(f"output={out}: cannot create it ({e.strerror}); pass a writable output=DIR") from None
    check_settings(out, output_settings(cfg))
    clean_temp(out)
    t0 = time.perf_counter()
    curator = VideoCurator(cfg, out)
    todo = [(p, s) for p, s in inputs if not curator.done(p, s)]
    if len(todo) < len(inputs):
        log.info("resuming: %d of %d inputs already finished", len(inputs) - len(todo), len(inputs))
    results: Iterator[dict] = (
        run_ray(curator, todo, cfg.workers, cfg.ray) if cfg.runner == "ray" else run_local(curator, todo)
    )
    frames = 0
    for marker in progress(results, desc="curate", total=len(todo), unit="video"):  # failures: in the summary
        frames += marker["frames"]
    return finalize(cfg, out, inputs, time.perf_counter() - t0, frames)
