"""Guardrails around every generation: pre-guards on the prompt (obfuscation-aware blocklist, adapted MiniLM semantic
head), post-guards on the video (NudeNet, an optional user-trained frame classifier) and face blur.

`Guardrails.from_config(node)` is what the pipeline uses; the functions below run the default configuration.
Nothing heavy is imported until a guard first runs.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from .core import Verdict, run_guards
from .runner import Guardrails

__all__ = ["Guardrails", "Verdict", "blur_faces", "check_prompt", "check_video", "default_guardrails", "run_guards"]


@lru_cache(maxsize=1)
def default_guardrails() -> Guardrails:
    """The guardrails of configs/guardrails/default.yaml, built once per process."""
    return Guardrails.from_config(None)


def check_prompt(text: str) -> Verdict:
    """Pre-guard a prompt with the default guardrails."""
    return default_guardrails().check_prompt(text)


def check_video(frames: np.ndarray) -> Verdict:
    """Post-guard uint8 `(T, H, W, 3)` RGB frames with the default guardrails."""
    return default_guardrails().check_video(frames)


def blur_faces(frames: np.ndarray) -> np.ndarray:
    """Pixelate the faces in uint8 `(T, H, W, 3)` RGB frames (default face-blur settings)."""
    from .faces import FaceBlur

    return FaceBlur()(frames)
