"""Logging and progress bars: one place, quiet when COSMOS_LITE_QUIET=1 (tests set it)."""

from __future__ import annotations

import logging
import os
import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

from tqdm.auto import tqdm

T = TypeVar("T")


def quiet() -> bool:
    return os.environ.get("COSMOS_LITE_QUIET", "") not in ("", "0")


def debugging() -> bool:
    """COSMOS_LITE_DEBUG=1: show the traceback of a failure beside its one-line message."""
    return os.environ.get("COSMOS_LITE_DEBUG", "") not in ("", "0")


class StderrHandler(logging.StreamHandler):
    """A handler on whatever sys.stderr is when a record is written, not the stream it was when logging was set up
    (a caller that redirects stderr for a while, such as a test's capture, may close that one)."""

    @property
    def stream(self):
        return sys.stderr

    @stream.setter
    def stream(self, _):
        pass


def setup_logging(level: str = "INFO") -> None:
    """Configure the root `cosmos_lite` logger once: `HH:MM:SS name: message` on stderr."""
    root = logging.getLogger("cosmos_lite")
    if not root.handlers:
        handler = StderrHandler()
        handler.setFormatter(logging.Formatter("%(asctime)s %(name)s: %(message)s", "%H:%M:%S"))
        root.addHandler(handler)
    root.setLevel("WARNING" if quiet() else level)


def get_logger(name: str) -> logging.Logger:
    return logging.getLogger(name if name.startswith("cosmos_lite") else f"cosmos_lite.{name}")


def progress(iterable: Iterable[T], desc: str = "", total: int | None = None, **kw) -> Iterator[T]:
    """A tqdm progress bar on stderr, hidden when quiet or when stderr is not a terminal."""
    disable = True if quiet() else None
    return iter(tqdm(iterable, desc=desc, total=total, disable=disable, leave=False, **kw))
