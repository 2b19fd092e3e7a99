"""Print what `cosmos_lite.video.probe` reads from each video as one JSON line.

Example: `cosmos-lite probe input=clip.mp4` (or `input=[a.mp4,b.mp4]`); exit 4 if the file is not a readable video.
"""

from __future__ import annotations

import dataclasses
import json

from omegaconf import DictConfig

from .config import as_list
from .errors import ConfigError
from .video import probe


def main(cfg: DictConfig, args: list[str]) -> int:
    paths = list(args) + [str(p) for p in as_list(cfg.input)]
    if not paths:
        raise ConfigError("no input: pass input=VIDEO (or the paths as arguments)")
    for path in paths:
        print(json.dumps(dataclasses.asdict(probe(path))))
    return 0
