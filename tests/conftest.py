"""Shared fixtures: quiet logs, the Sintel test media in ../shared/data, a small synthetic video."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("COSMOS_LITE_QUIET", "1")
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("RAY_AUTH_MODE", "disabled")

ROOT = Path(__file__).resolve().parent.parent
DATA = Path(os.environ.get("COSMOS_LITE_DATA", ROOT.parent / "shared" / "data"))


def _media(name: str) -> Path:
    path = DATA / name
    if not path.is_file():
        pytest.skip(f"test media {path} is missing (set COSMOS_LITE_DATA to the folder that holds it)")
    return path


@pytest.fixture(scope="session")
def sintel_10s() -> Path:
    return _media("sintel_trailer_10s.mp4")


@pytest.fixture(scope="session")
def sintel_30s() -> Path:
    return _media("sintel_trailer_30s.mp4")


@pytest.fixture(scope="session")
def sintel_cuts() -> dict:
    return json.loads(_media("sintel_trailer_30s.cuts.json").read_text())


@pytest.fixture()
def moving_square() -> np.ndarray:
    """A 24-frame 64x64 video of a white square moving right on a dark gradient."""
    t, h, w = 24, 64, 64
    frames = np.zeros((t, h, w, 3), np.uint8)
    frames[..., 2] = np.linspace(20, 80, w, dtype=np.uint8)[None, None, :]
    for i in range(t):
        frames[i, 24:40, 2 + 2 * i : 18 + 2 * i] = 255
    return frames


def randomised(module, seed: int = 0):
    """Random weights everywhere (the zero-initialised gates would make every condition irrelevant)."""
    import torch

    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in module.parameters():
            p.copy_(torch.randn(p.shape, generator=g) * 0.1)
    return module


@pytest.fixture(scope="session")
def randomise():
    """`randomise(module, seed=0)`: fill every weight with small random values."""
    return randomised


@pytest.fixture(scope="session")
def tiny_wfm(tmp_path_factory) -> Path:
    """A tiny world-model checkpoint folder (random weights, 9 frames of 32x32, text and 2-D actions): fast to
    load and sample, for tests of everything that consumes a checkpoint."""
    import torch
    from omegaconf import OmegaConf

    from cosmos_lite.models import WorldModelPipeline
    from cosmos_lite.models.pipeline import build_denoiser
    from cosmos_lite.tokenizers import build_tokenizer

    torch.manual_seed(0)
    cfg = OmegaConf.create({
        "model": {"dim": 32, "depth": 2, "heads": 2}, "edm": {}, "text": {"path": None, "max_length": 16},
        "data": {"num_frames": 9, "fps": 16.0, "height": 32, "width": 32},
    })
    made = WorldModelPipeline(randomised(build_denoiser(cfg)), build_tokenizer("cv1x4x4", "tiny"), cfg,
                              {"mean": torch.zeros(16), "std": torch.ones(16), "action_scale": torch.ones(2)})
    return made.save_pretrained(tmp_path_factory.mktemp("wfm") / "tiny_wfm")
