"""World model: next-frame conditioning, context windows, guidance, seeding, LoRA, pipeline round trip."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from cosmos_lite.core.lora import add_lora, merge_lora
from cosmos_lite.errors import ConfigError, InputError
from cosmos_lite.models import (
    Denoiser,
    EDMConfig,
    WorldModelPipeline,
    build_dit,
    context_window,
    make_condition,
    sample_next,
)
from cosmos_lite.models.samplers import guided
from cosmos_lite.models.train import dit_lora_targets

B, K, C, H = 2, 4, 16, 4  # batch, context frames, latent channels, latent size (32x32 frames, 8x8 spatial)
TINY = dict(dim=32, depth=2, heads=2, context=K)


@pytest.fixture(scope="module")
def denoiser(randomise) -> Denoiser:
    torch.manual_seed(0)
    return randomise(Denoiser(build_dit(**TINY), EDMConfig())).eval()


def condition(present: int, text: bool, actions: bool, seed: int = 0):
    """A condition whose last `present` of K context frames exist."""
    g = torch.Generator().manual_seed(seed)
    have = torch.arange(K)[None].expand(B, K) >= K - present
    context = torch.randn(B, K, C, H, H, generator=g) * have[..., None, None, None]
    return make_condition(context, have, torch.randn(B, K, 2, generator=g) if actions else None,
                          text=torch.randn(B, 5, 384, generator=g) if text else None, context_sigma=0.05, generator=g)


@pytest.mark.parametrize("present", [0, 1, 4])
@pytest.mark.parametrize("text", [False, True])
@pytest.mark.parametrize("actions", [False, True])
def test_shapes_for_every_conditioning_mix(denoiser, present, text, actions):
    cond = condition(present, text, actions)
    y = torch.randn(B, C, H, H)
    out = denoiser(y, torch.full((B,), 3.0), cond)
    assert out.shape == (B, C, H, H) and torch.isfinite(out).all()
    nxt = sample_next(denoiser, cond, steps=3, guidance=2.0, action_guidance=1.5, churn=1.0)
    assert nxt.shape == (B, C, H, H) and torch.isfinite(nxt).all()


def test_context_window_right_aligns_and_marks_frames_before_the_start():
    frames = torch.arange(2 * 6, dtype=torch.float32).reshape(2, 6, 1, 1, 1).expand(2, 6, C, H, H)
    actions = torch.arange(2 * 6 * 2, dtype=torch.float32).reshape(2, 6, 2)
    context, present, acts = context_window(frames, actions, torch.tensor([2, 5]), K)
    assert present.tolist() == [[False, False, True, True], [True, True, True, True]]
    assert context[0, :, 0, 0, 0].tolist() == [0, 0, 0, 1] and context[1, :, 0, 0, 0].tolist() == [7, 8, 9, 10]
    assert torch.equal(acts[0, 2:], actions[0, 0:2]) and torch.equal(acts[0, :2], torch.zeros(2, 2))
    assert torch.equal(acts[1], actions[1, 1:5])  # the action after each context frame; the last leads into t


def test_conditions_change_the_prediction(denoiser):
    cond = condition(4, True, True)
    y, s = torch.randn(B, C, H, H), torch.full((B,), 2.0)
    full = denoiser(y, s, cond)
    assert not torch.allclose(full, denoiser(y, s, cond.without_text()))
    assert not torch.allclose(full, denoiser(y, s, cond.without_actions()))
    moved = cond.actions.clone()
    moved[:, -1] += 1.0  # only the action that leads into the predicted frame
    assert not torch.allclose(full, denoiser(y, s, replace(cond, actions=moved)))
    older = cond.context.clone()
    older[:, 0] += 1.0  # the oldest context frame matters too
    assert not torch.allclose(full, denoiser(y, s, replace(cond, context=older)))


def test_action_tokens_carry_the_actions_by_cross_attention(randomise):
    torch.manual_seed(0)
    den = randomise(Denoiser(build_dit(**TINY), EDMConfig())).eval()
    for p in den.net.action_embed.parameters():  # silence the adaLN route: only the tokens carry the actions
        torch.nn.init.zeros_(p)
    cond = condition(4, True, True)
    y, s = torch.randn(B, C, H, H), torch.full((B,), 2.0)
    assert not torch.allclose(den(y, s, cond), den(y, s, replace(cond, actions=cond.actions + 1.0)))
    dropped = cond.without_actions()  # dropped actions are masked out of the cross-attention
    torch.testing.assert_close(den(y, s, dropped), den(y, s, replace(dropped, actions=dropped.actions + 1.0)))


def test_guidance_one_equals_conditional_prediction(denoiser):
    cond = condition(2, True, True)
    y, s = torch.randn(B, C, H, H), torch.full((B,), 1.5)
    conditional = denoiser(y, s, cond)
    assert torch.equal(guided(denoiser, cond, 1.0, 1.0)(y, s), conditional)
    uncond = denoiser(y, s, cond.without_text().without_actions())
    text_only = denoiser(y, s, cond.without_actions())
    expected = uncond + 3.0 * (text_only - uncond) + 2.0 * (conditional - text_only)
    got = guided(denoiser, cond, 3.0, 2.0)(y, s)
    torch.testing.assert_close(got, expected, rtol=1e-4, atol=1e-5)
    assert not torch.allclose(got, conditional)


def test_same_seed_same_frame(denoiser):
    cond = condition(2, True, True)

    def draw(seed: int) -> torch.Tensor:
        return sample_next(denoiser, cond, steps=4, churn=2.0, guidance=2.0,
                           generator=torch.Generator().manual_seed(seed))

    assert torch.equal(draw(3), draw(3)) and not torch.equal(draw(3), draw(4))


def test_lora_starts_at_base_and_merges_exactly(randomise):
    torch.manual_seed(0)
    net = randomise(build_dit(**TINY))
    cond = condition(2, True, True)
    args = (torch.randn(B, C, H, H), cond.context, cond.present, torch.randn(B, 1 + K), cond.actions,
            cond.has_actions, cond.text, cond.text_mask)
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
    text2world = pipe(prompt="a red ball", video=None, actions=None, num_frames=9, steps=2)
    assert text2world.frames.shape == (9, 32, 32, 3)


def test_sampler_steps_default_to_the_checkpoints_edm_steps(pipe, moving_square):
    video = moving_square[:2, :32, :32]
    one, two = (pipe(video=video, num_frames=4, steps=s, seed=3).frames for s in (1, 2))
    assert not np.array_equal(one, two)  # the step count matters, so the default below is visible
    assert pipe.denoiser.cfg.steps == 1
    assert np.array_equal(pipe(video=video, num_frames=4, seed=3).frames, one)
    pipe.denoiser.cfg.steps = 2
    try:
        assert np.array_equal(pipe(video=video, num_frames=4, seed=3).frames, two)
    finally:
        pipe.denoiser.cfg.steps = 1


def test_pipeline_rejects_bad_inputs(pipe, tmp_path):
    with pytest.raises(InputError, match="64x64"):
        pipe(video=np.zeros((1, 64, 64, 3), np.uint8), steps=1)
    with pytest.raises(InputError, match="actions"):
        pipe(video=np.zeros((1, 32, 32, 3), np.uint8), actions=np.zeros((3, 2)), num_frames=9, steps=1)
    with pytest.raises(ConfigError, match="steps"):
        pipe(video=np.zeros((1, 32, 32, 3), np.uint8), steps=0)
    with pytest.raises(ConfigError, match="sampler"):
        pipe(video=np.zeros((1, 32, 32, 3), np.uint8), sampler="foo")
    with pytest.raises(InputError, match="model.safetensors"):
        WorldModelPipeline.from_pretrained(tmp_path)
    old = pipe.save_pretrained(tmp_path / "old")  # a checkpoint whose config predates a model key
    cfg = OmegaConf.load(old / "config.yaml")
    cfg.model.action_tokens = not cfg.model.action_tokens
    OmegaConf.save(cfg, old / "config.yaml")
    with pytest.raises(InputError, match=r"does not hold .*unexpected: action_pos, action_proj.*model\.action_tokens"):
        WorldModelPipeline.from_pretrained(old)
