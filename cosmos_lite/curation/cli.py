"""Curate a folder of raw videos into training clips: split into shots, filter, transcode to H.264.

Example: `cosmos-lite curate input=raw/ output=curated/ transcode.size=256`; on Ray with
`workers=4` (local Ray) or `ray.address=auto` (a running cluster). Writes clips/<id>.mp4,
metas/<id>.json (scores, why kept or dropped), markers/, settings.json and summary.json; a rerun
resumes (with the same settings). Bad inputs are listed in summary.json while the rest complete;
exit 4 only if every input failed.

Main keys: split.method = fast (default, ours: hard cuts, and dissolves, fades and wipes, whose frames
never enter a clip) | transnetv2 | content | adaptive (PySceneDetect) | stride; split.max_seconds;
transcode.size (short side), .fps, .crf, .preset; filters.NAME.action = drop | score | off for NAME in
duration, resolution, motion, sharpness, blank, duplicate; filters.motion.min_percent (the share of the
picture, in %, that changes over a quarter second; frozen or blank clips score 0); clips_per_shard > 0
for webdataset tar shards.
"""

from __future__ import annotations

from omegaconf import DictConfig

from ..errors import ConfigError, InputError
from .pipeline import CurateConfig, curate


def main(cfg: DictConfig, args: list[str]) -> int:
    if args:
        raise ConfigError(f"unexpected argument(s) {' '.join(args)}; pass input=DIR output=DIR")
    conf = CurateConfig.from_node(cfg)
    s = curate(conf)
    dropped = ", ".join(f"{k} {v}" for k, v in s["dropped_by"].items())
    print(
        f"curate: {s['inputs_done']}/{s['inputs']} inputs done, {s['inputs_failed']} failed; "
        f"{s['clips_kept']} clips kept ({s['kept_seconds']:.1f} s), {s['clips_dropped']} dropped"
        f"{f' ({dropped})' if dropped else ''}; {s['wall_seconds']:.1f} s wall, "
        f"{s['frames_per_second'] or 0:.0f} frames/s -> {conf.output}/summary.json"
    )
    for f in s["failures"]:
        print(f"  failed: {f['reason']}")
    if s["inputs_failed"] == s["inputs"]:
        raise InputError(f"all {s['inputs']} inputs under {conf.input} failed; see {conf.output}/summary.json")
    return 0
