"""`Guardrails`: the configured pre-guards, post-guards and face blur, built from `configs/guardrails/`.

Models load on first use and are kept, so a `Guardrails` made once serves every generation; a guard whose
model fails to load blocks (fail closed) like one that fails while checking.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import GuardrailBlocked, InputError
from .core import Verdict, each_verdict, log, run_guards, run_postprocessors


class LazyGuard:
    """A guard built by `factory` on its first check, then reused; a failure to build is a failure to check."""

    def __init__(self, name: str, factory: Callable[[], Any]):
        self.name, self.factory, self.guard = name, factory, None

    def get(self) -> Any:
        """The guard, built now if this is the first use."""
        if self.guard is None:
            self.guard = self.factory()
        return self.guard

    def check(self, x: Any, **kw: Any) -> Verdict:
        return self.get().check(x, **kw)


@dataclass
class GuardrailsConfig:
    """Mirror of configs/guardrails/default.yaml: switches, then one node per guard (see each guard's config)."""

    enabled: bool = True
    fail_closed: bool = True
    blocklist: dict = field(default_factory=dict)
    semantic: dict = field(default_factory=dict)
    nudity: dict = field(default_factory=dict)
    frame_classifier: dict = field(default_factory=dict)
    face_blur: dict = field(default_factory=dict)


class Guardrails:
    """Pre-guard prompts, post-guard videos and blur faces, as configured; `from_config(None)` gives the defaults."""

    def __init__(self, cfg: GuardrailsConfig | None = None):
        from ..config import to_dataclass
        from .blocklist import BlocklistConfig, BlocklistGuard
        from .faces import FaceBlur, FaceBlurConfig
        from .frames import FrameClassifierConfig, FrameClassifierGuard, NudityConfig, NudityGuard
        from .semantic import SemanticConfig, SemanticGuard

        self.cfg = cfg = cfg or GuardrailsConfig()
        blocklist = to_dataclass(BlocklistConfig, cfg.blocklist, "guardrails.blocklist")
        semantic = to_dataclass(SemanticConfig, cfg.semantic, "guardrails.semantic")
        nudity = to_dataclass(NudityConfig, cfg.nudity, "guardrails.nudity")
        classifier = to_dataclass(FrameClassifierConfig, cfg.frame_classifier, "guardrails.frame_classifier")
        face_blur = to_dataclass(FaceBlurConfig, cfg.face_blur, "guardrails.face_blur")
        meaning = LazyGuard("semantic", lambda: SemanticGuard(semantic))
        confirm = (lambda text: meaning.get().confirm(text)) if semantic.enabled else None  # noqa: E731
        self.prompt_guards = [g for on, g in [
            (blocklist.enabled, LazyGuard("blocklist", lambda: BlocklistGuard(blocklist, confirm))),
            (semantic.enabled, meaning),
        ] if on]
        self.video_guards = [g for on, g in [
            (nudity.enabled, LazyGuard("nudity", lambda: NudityGuard(nudity))),
            (classifier.enabled, LazyGuard("frame_classifier", lambda: FrameClassifierGuard(classifier))),
        ] if on]
        self.postprocessors = [FaceBlur(face_blur)] if face_blur.enabled else []

    @classmethod
    def from_config(cls, node: Any = None) -> Guardrails:
        """From a `guardrails` config node (DictConfig or dict); None: configs/guardrails/default.yaml."""
        from omegaconf import OmegaConf

        from ..config import CONFIG_DIR, to_dataclass

        if node is None:
            node = OmegaConf.load(CONFIG_DIR / "guardrails" / "default.yaml")
        return cls(to_dataclass(GuardrailsConfig, node, "guardrails"))

    def check_prompt(self, text: str) -> Verdict:
        """Blocklist then semantic check, stopping at the first block; an empty prompt is blocked (nothing to check
        is not a pass)."""
        return self._unchecked_prompt(text) or run_guards(self.prompt_guards, text, self.cfg.fail_closed)

    def prompt_verdicts(self, text: str) -> list[Verdict]:
        """Every pre-guard's verdict on the prompt, also after one has blocked (what `cosmos-lite guard` prints);
        the prompt is allowed when all of them allow it."""
        decided = self._unchecked_prompt(text)
        return [decided] if decided else list(each_verdict(self.prompt_guards, text, self.cfg.fail_closed))

    def _unchecked_prompt(self, text: str) -> Verdict | None:
        """The verdict when the guards need not run: guardrails disabled, or an empty prompt."""
        if not self.cfg.enabled:
            return Verdict(True, "guardrails", "guardrails disabled (guardrails.enabled=false)")
        if not isinstance(text, str) or not text.strip():
            return Verdict(False, "prompt", "empty prompt: give a text prompt, or generate without one")
        return None

    def check_video(self, frames: np.ndarray, start: int = 0) -> Verdict:
        """Nudity and (if enabled) the user's frame classifier on sampled frames of uint8 `(T, H, W, 3)`; `start`:
        the index of the first frame in a longer video (for the reason)."""
        if not self.cfg.enabled:
            return Verdict(True, "guardrails", "guardrails disabled (guardrails.enabled=false)")
        return run_guards(self.video_guards, frames, self.cfg.fail_closed, start=start)

    def check_video_stream(self, frames: Iterable[np.ndarray], chunk: int = 64) -> Verdict:
        """`check_video` over a stream of frames, `chunk` at a time, so a long video never sits in memory."""
        start = 0
        for part in chunked(frames, chunk):
            verdict = self.check_video(part, start)
            if not verdict.allowed:
                return verdict
            start += len(part)
        if not start:
            return Verdict(False, "video", "no frames to check")
        return Verdict(True, "+".join(g.name for g in self.video_guards) or "none", f"{start} frames checked")

    def postprocess(self, frames: np.ndarray) -> np.ndarray:
        """Face blur on a video that passed; if it fails, raise GuardrailBlocked (fail closed) or return as is."""
        if not self.cfg.enabled:
            return frames
        try:
            return run_postprocessors(self.postprocessors, frames)
        except Exception as e:  # noqa: BLE001 - an unblurred video must not leave when fail_closed
            if self.cfg.fail_closed:
                raise GuardrailBlocked(f"face blur failed ({type(e).__name__}: {e}); video withheld") from e
            log.warning("face blur failed (%s: %s); video returned unblurred because fail_closed=false",
                        type(e).__name__, e)
            return frames

    def postprocess_stream(self, frames: Iterable[np.ndarray], chunk: int = 64) -> Iterator[np.ndarray]:
        """`postprocess` over a stream of frames, `chunk` at a time. A failure always raises GuardrailBlocked:
        half a video cannot be handed back unblurred (write it with video.write_video, which is atomic)."""
        if not self.cfg.enabled:
            yield from frames
            return
        for step in self.postprocessors:
            frames = step.stream(frames, chunk)
        try:
            yield from frames
        except InputError:  # the stream itself failed (e.g. a truncated file): not a guardrail decision
            raise
        except Exception as e:  # noqa: BLE001 - see above
            raise GuardrailBlocked(f"face blur failed ({type(e).__name__}: {e}); video withheld") from e


def chunked(frames: Iterable[np.ndarray], size: int) -> Iterator[np.ndarray]:
    """Stacks of up to `size` consecutive frames from a stream."""
    it = iter(frames)
    while part := list(itertools.islice(it, size)):
        yield np.stack(part)
