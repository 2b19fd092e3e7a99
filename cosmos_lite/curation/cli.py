"""Curate a folder of raw videos into training clips: split into shots, filter, transcode to H.264.

Example: `cosmos-lite curate input=raw/ output=curated/ transcode.size=256`; on Ray with
`runner=ray workers=4` (local Ray) or `ray.address=auto` (a running cluster). Writes
clips/<id>.mp4, metas/<id>.json, markers/ and summary.json; a rerun resumes. Exit 4 if every
input failed (bad inputs are listed in summary.json while the rest complete).
"""

from __future__ import annotations

from omegaconf import DictConfig

from ..errors import InputError
from .pipeline import CurateConfig, curate


def main(cfg: DictConfig, args: list[str]) -> int:
    conf = CurateConfig.from_node(cfg)
    if args and not conf.input:
        conf.input = args[0]
    s = curate(conf)
    print(
        f"curate: {s['inputs_done']}/{s['inputs']} inputs done, {s['inputs_failed']} failed; "
        f"{s['clips_kept']} clips kept ({s['kept_seconds']:.1f} s), {s['clips_dropped']} dropped "
        f"{s['dropped_by'] or ''}; {s['wall_seconds']:.1f} s wall, {s['frames_per_second'] or 0:.0f} frames/s "
        f"-> {conf.output}/summary.json"
    )
    for f in s["failures"]:
        print(f"  failed: {f['reason']}")
    if s["inputs_failed"] == s["inputs"]:
        raise InputError(f"all {s['inputs']} inputs under {conf.input} failed; see {conf.output}/summary.json")
    return 0
