"""Checkpoints describe themselves: a world-model checkpoint stores every component's resolved config, so it loads the
same whatever the size presets and defaults become."""

from __future__ import annotations

import dataclasses

import numpy as np
from omegaconf import OmegaConf

from cosmos_lite.models import DiTConfig, EDMConfig, WorldModelPipeline
from cosmos_lite.tokenizers import models as tokenizer_models


def test_checkpoint_loads_identically_after_the_presets_change(tiny_wfm, monkeypatch):
    def generate() -> np.ndarray:
        pipe = WorldModelPipeline.from_pretrained(tiny_wfm)
        return pipe(prompt="a red ball bounces", video=np.full((1, 32, 32, 3), 90, np.uint8), num_frames=9,
                    steps=2, seed=3).frames

    before = generate()
    saved = OmegaConf.load(tiny_wfm / "config.yaml")
    assert set(saved.model) == {f.name for f in dataclasses.fields(DiTConfig)}  # every field, no "see the preset"
    assert set(saved.edm) == {f.name for f in dataclasses.fields(EDMConfig)}
    monkeypatch.setitem(tokenizer_models.SIZES, "tiny", dict(channels=16, channels_mult=[1, 1, 1], num_res_blocks=2,
                                                            attention=False))
    np.testing.assert_array_equal(generate(), before)
