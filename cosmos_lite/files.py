"""Atomic file writes, the one scheme every writer uses: write a hidden temp file beside the target, then rename it
over the target, so a reader (or a rerun after a kill) never sees a partial file. Temp names are `.NAME.HEX.tmpSUFFIX`:
hidden, unique per writer, and ending in the target's suffix so writers that infer the format from it still work."""

from __future__ import annotations

import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

TEMP_GLOB = ".*.tmp*"  # what a killed writer can leave behind (see remove_temp_files)


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temp path to write; on success it is renamed over `path`, on error it is removed."""
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{uuid.uuid4().hex[:8]}.tmp{path.suffix}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_text(path: str | os.PathLike, text: str) -> Path:
    """Write `text` (UTF-8) to `path` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def remove_temp_files(folder: str | os.PathLike) -> int:
    """Remove the temp files killed writers left in `folder`; returns how many."""
    found = [p for p in Path(folder).glob(TEMP_GLOB) if p.is_file()]
    for p in found:
        p.unlink(missing_ok=True)
    return len(found)
