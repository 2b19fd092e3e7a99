"""The one guard interface and the runners that chain guards (stopping at the first block, or hearing every guard)
and fail closed.

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
    """A guard's decision: allowed or not, which guard decided, why (names the term, frame or class) and, for a
    blocked prompt, the category of harm (violence, sexual, minors, self-harm, hate, weapons, drugs) where known."""

    allowed: bool
    guard: str
    reason: str
    category: str | None = None


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


def each_verdict(guards: Sequence[Guard], x: Any, fail_closed: bool = True, **kw: Any) -> Iterator[Verdict]:
    """Each guard's verdict on `x`, in order (`kw` passed on). A guard that raises blocks unless fail_closed=False,
    in which case it is skipped."""
    for guard in guards:
        try:
            verdict = guard.check(x, **kw)
        except Exception as e:  # noqa: BLE001 - any failure of a guard is a decision, not a crash
            if not fail_closed:
                log.warning("guard %s failed (%s: %s); skipped because fail_closed=false", guard.name,
                            type(e).__name__, e)
                continue
            verdict = Verdict(False, guard.name, f"guard failed ({type(e).__name__}: {e}); blocked (fail closed)")
        yield verdict


def run_guards(guards: Sequence[Guard], x: Any, fail_closed: bool = True, **kw: Any) -> Verdict:
    """Run `guards` in order on `x` (`kw` passed on); the first block wins and the rest do not run."""
    for verdict in each_verdict(guards, x, fail_closed, **kw):
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
