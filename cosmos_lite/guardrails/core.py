"""The one guard interface and the runner that chains guards, stops at the first block and fails closed.

Like PySceneDetect's detectors, every guard is small and alike: a `name` and `check(x) -> Verdict`.
Post-processors (face blur) have `name` and `__call__(frames) -> frames` instead.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any, NamedTuple, Protocol

import numpy as np

from ..log import get_logger

log = get_logger("guardrails")


class Verdict(NamedTuple):
    """A guard's decision: allowed or not, which guard decided, and why (names the term, frame or class)."""

    allowed: bool
    guard: str
    reason: str


class Guard(Protocol):
    """A prompt guard (`check(str)`) or a video guard (`check(frames uint8 (T,H,W,3), start=0)`, where `start` is
    the index of the first frame in the whole video, for the reason)."""

    name: str

    def check(self, x: Any, **kw: Any) -> Verdict: ...


class Postprocessor(Protocol):
    """Transforms a video that passed the guards (e.g. pixelates faces); same shape and dtype out. `stream` does
    the same to a stream of frames, chunk by chunk, with the result a whole-video call would give."""

    name: str

    def __call__(self, frames: np.ndarray) -> np.ndarray: ...

    def stream(self, frames: Iterable[np.ndarray], chunk: int) -> Iterator[np.ndarray]: ...


def run_guards(guards: Sequence[Guard], x: Any, fail_closed: bool = True, **kw: Any) -> Verdict:
    """Run `guards` in order on `x` (`kw` passed on); the first block wins. A guard that raises blocks unless
    fail_closed=False."""
    for guard in guards:
        try:
            verdict = guard.check(x, **kw)
        except Exception as e:  # noqa: BLE001 - any failure of a guard is a decision, not a crash
            if fail_closed:
                return Verdict(False, guard.name, f"guard failed ({type(e).__name__}: {e}); blocked (fail closed)")
            log.warning("guard %s failed (%s: %s); skipped because fail_closed=false", guard.name, type(e).__name__, e)
            continue
        if not verdict.allowed:
            return verdict
    return Verdict(True, "+".join(g.name for g in guards) or "none", "passed")


def run_postprocessors(steps: Sequence[Postprocessor | Callable], frames: np.ndarray) -> np.ndarray:
    """Apply post-processors in order; they must keep the video's shape and dtype."""
    for step in steps:
        out = step(frames)
        if out.shape != frames.shape or out.dtype != frames.dtype:
            raise ValueError(f"post-processor {getattr(step, 'name', step)} changed the video's shape or dtype")
        frames = out
    return frames
