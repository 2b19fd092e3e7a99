"""Checkpoints describe themselves: a world-model checkpoint loads the same whatever the size presets in code become."""

from __future__ import annotations

import numpy as np
from omegaconf import OmegaConf

from cosmos_lite.models import WorldModelPipeline, dit
from cosmos_lite.tokenizers import models as tokenizer_models


def test_checkpoint_loads_identically_after_the_presets_change(tiny_wfm, monkeypatch):
    def generate() -> np.ndarray:
        pipe = WorldModelPipeline.from_pretrained(tiny_wfm)
        return pipe(prompt="a red ball bounces", video=np.full((1, 32, 32, 3), 90, np.uint8), num_frames=9,
                    steps=2, seed=3).frames

    before = generate()
    saved = OmegaConf.load(tiny_wfm / "config.yaml").model
    assert saved.dim == dit.PRESETS["tiny"]["dim"] and saved.depth == dit.PRESETS["tiny"]["depth"]  # no 0 = preset
    monkeypatch.setitem(dit.PRESETS, "tiny", dict(dim=64, depth=3, heads=4, adaln_lora_rank=4))
    monkeypatch.setitem(tokenizer_models.SIZES, "tiny", dict(channels=16, channels_mult=[1, 1, 1], num_res_blocks=2,
                                                            attention=False))
    np.testing.assert_array_equal(generate(), before)
