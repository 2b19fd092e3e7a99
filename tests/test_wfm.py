"""World model: conditioning shapes, fixed given frames, guidance, seeding, LoRA, pipeline round trip."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from cosmos_lite.core.lora import add_lora, merge_lora
from cosmos_lite.errors import InputError
from cosmos_lite.models import (
    Denoiser,
    EDMConfig,
    WorldModelPipeline,
    build_dit,
    group_actions,
    make_condition,
    sample,
)
from cosmos_lite.models.samplers import guided
from cosmos_lite.models.train import dit_lora_targets

SHAPE = (2, 16, 3, 4, 4)  # (B, C, T', h, w): 9 frames of 32x32 through a 4x8x8 tokenizer


@pytest.fixture(scope="module")
def denoiser(randomise) -> Denoiser:
    torch.manual_seed(0)
    return randomise(Denoiser(build_dit("tiny"), EDMConfig())).eval()


def condition(num_given: int, text: bool, actions: bool, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    z = torch.randn(SHAPE, generator=g)
    return z, make_condition(
        SHAPE, latents=z, num_given=num_given, text=torch.randn(2, 5, 384, generator=g) if text else None,
        actions=torch.randn(2, 9, 2, generator=g) if actions else None, cond_sigma=0.05, generator=g,
    )


@pytest.mark.parametrize("num_given", [0, 1, 2])
@pytest.mark.parametrize("text", [False, True])
@pytest.mark.parametrize("actions", [False, True])
def test_shapes_and_given_frames_for_every_conditioning_mix(denoiser, num_given, text, actions):
    z, cond = condition(num_given, text, actions)
    x = torch.randn(SHAPE)
    out = denoiser(x, torch.full((2,), 3.0), cond)
    assert out.shape == SHAPE and torch.isfinite(out).all()
    assert torch.equal(out[:, :, :num_given], z[:, :, :num_given])
    video = sample(denoiser, cond, steps=3, guidance=2.0, action_guidance=1.5, churn=1.0)
    assert video.shape == SHAPE and torch.isfinite(video).all()
    assert torch.equal(video[:, :, :num_given], z[:, :, :num_given])  # kept at their true values, exactly
    if num_given < SHAPE[2]:
        assert not torch.equal(video[:, :, num_given:], z[:, :, num_given:])


def test_conditions_change_the_prediction(denoiser):
    _, cond = condition(1, True, True)
    x, s = torch.randn(SHAPE), torch.full((2,), 2.0)
    full = denoiser(x, s, cond)
    assert not torch.allclose(full, denoiser(x, s, cond.without_text()))
    assert not torch.allclose(full, denoiser(x, s, cond.without_actions()))
    # per-frame actions: changing only the actions into the last latent frame changes that frame most
    moved = cond.actions.clone()
    moved[:, -1] += 1.0
    diff = (denoiser(x, s, replace(cond, actions=moved)) - full).abs().mean(dim=(0, 1, 3, 4))
    assert diff[-1] > 0 and diff[0] == 0  # frame 0 is given: it comes back as is


def test_guidance_one_equals_conditional_prediction(denoiser):
    _, cond = condition(1, True, True)
    x, s = torch.randn(SHAPE), torch.full((2,), 1.5)
    conditional = denoiser(x, s, cond)
    assert torch.equal(guided(denoiser, cond, 1.0, 1.0)(x, s), conditional)
    uncond = denoiser(x, s, cond.without_text().without_actions())
    text_only = denoiser(x, s, cond.without_actions())
    expected = uncond + 3.0 * (text_only - uncond) + 2.0 * (conditional - text_only)
    got = guided(denoiser, cond, 3.0, 2.0)(x, s)
    torch.testing.assert_close(got, expected, rtol=1e-4, atol=1e-5)
    assert not torch.allclose(got, conditional)


def test_same_seed_same_video(denoiser):
    _, cond = condition(1, True, True)
    a = sample(denoiser, cond, steps=4, sampler="euler", churn=2.0, guidance=2.0, seed=3)
    b = sample(denoiser, cond, steps=4, sampler="euler", churn=2.0, guidance=2.0, seed=3)
    c = sample(denoiser, cond, steps=4, sampler="euler", churn=2.0, guidance=2.0, seed=4)
    assert torch.equal(a, b) and not torch.equal(a, c)


def test_group_actions_puts_each_frames_actions_in_its_latent_frame():
    actions = torch.arange(9 * 2, dtype=torch.float32).reshape(1, 9, 2)
    grouped = group_actions(actions, 3, 4)
    assert grouped.shape == (1, 3, 8)
    assert torch.equal(grouped[0, 0], torch.zeros(8))  # the first frame is caused by no action
    assert torch.equal(grouped[0, 1], actions[0, 0:4].flatten())
    assert torch.equal(grouped[0, 2], actions[0, 4:8].flatten())


def test_lora_starts_at_base_and_merges_exactly(randomise):
    torch.manual_seed(0)
    net = randomise(build_dit("tiny"))
    _, cond = condition(1, True, True)
    args = (torch.randn(2, 17, 3, 4, 4), torch.randn(2, 3), cond.text, cond.text_mask, cond.actions,
            cond.has_actions, cond.fps)
    base = net(*args)
    add_lora(net, 4, None, dit_lora_targets)
    torch.testing.assert_close(net(*args), base)
    trainable = [n for n, p in net.named_parameters() if p.requires_grad]
    assert trainable and all(".lora_" in n for n in trainable)
    with torch.no_grad():
        for n, p in net.named_parameters():
            if "lora_b" in n:
                p.normal_(0, 0.1)
    adapted = net(*args)
    assert not torch.allclose(adapted, base)
    torch.testing.assert_close(merge_lora(net)(*args), adapted, rtol=1e-4, atol=1e-5)
    assert not any(".lora_" in n for n, _ in net.named_parameters())


@pytest.fixture(scope="module")
def pipe(tiny_wfm) -> WorldModelPipeline:
    return WorldModelPipeline.from_pretrained(tiny_wfm)


def test_pipeline_round_trip_given_frames_and_long_rollout(pipe, moving_square):
    video = moving_square[:5, :32, :32]
    actions = np.random.default_rng(0).normal(size=(40, 2)).astype(np.float32)
    out = pipe(prompt="a white square slides right", video=video, actions=actions, num_frames=21, steps=2,
               guidance=2.0, action_guidance=2.0, seed=1)
    assert out.frames.shape == (21, 32, 32, 3) and out.frames.dtype == np.uint8
    assert np.array_equal(out.frames[:5], video)  # given frames come back unchanged
    again = pipe(prompt="a white square slides right", video=video, actions=actions, num_frames=21, steps=2,
                 guidance=2.0, action_guidance=2.0, seed=1)
    assert np.array_equal(out.frames, again.frames)
    text2world = pipe(prompt=None, video=None, actions=None, num_frames=9, steps=2)
    assert text2world.frames.shape == (9, 32, 32, 3)


def test_pipeline_rejects_bad_inputs(pipe, tmp_path):
    with pytest.raises(InputError, match="64x64"):
        pipe(video=np.zeros((1, 64, 64, 3), np.uint8), steps=1)
    with pytest.raises(InputError, match="actions"):
        pipe(video=np.zeros((1, 32, 32, 3), np.uint8), actions=np.zeros((3, 2)), num_frames=9, steps=1)
    with pytest.raises(InputError, match="model.safetensors"):
        WorldModelPipeline.from_pretrained(tmp_path)
