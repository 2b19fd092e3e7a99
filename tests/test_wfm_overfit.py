"""The world model can represent an episode: a small model overfit on one pusher episode regenerates its motion from
the first frame, the caption and the true actions. If the path (tokenizer, next-frame DiT, sampler, decoder) cannot
do this, nothing else matters."""

from __future__ import annotations

import pytest

from cosmos_lite.cli import run
from cosmos_lite.core.frames import to_frames, to_tensor
from cosmos_lite.core.metrics import palette_object_iou
from cosmos_lite.models import WorldModelPipeline
from cosmos_lite.sim import simulate, write_episode


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_overfit_one_episode_regenerates_its_motion(tmp_path):
    ep = simulate("pusher", seed=3)
    sim, tok, wfm = tmp_path / "sim", tmp_path / "tok", tmp_path / "wfm"
    write_episode(ep, sim, "pusher_00003")
    assert run(["train", "experiment=tokenizer_sim", f"data.roots=[{sim}]", f"data.val_roots=[{sim}]", f"out={tok}",
                "trainer.max_minutes=0", "trainer.steps=1200", "trainer.val_every=0"]) == 0
    assert run(["train", "experiment=wfm_nano", f"data.roots=[{sim}]", f"tokenizer.path={tok}",
                f"out={wfm}", "trainer.steps=800", "trainer.warmup=50", "trainer.ema_decay=0.99",
                "cond.p_drop_text=0", "cond.p_drop_actions=0"]) == 0
    pipe = WorldModelPipeline.from_pretrained(wfm)
    gen = pipe(prompt=ep.meta["caption"], video=ep.frames[:1], actions=ep.actions, num_frames=len(ep.frames),
               seed=0).frames
    m = ep.meta
    iou = palette_object_iou(gen[1:], ep.masks[1:], m["palette"], [m["scenery_color"]])
    recon = to_frames(pipe.decode(pipe.encode(to_tensor(ep.frames))))
    recon_iou = palette_object_iou(recon[1:], ep.masks[1:], m["palette"], [m["scenery_color"]])
    assert iou >= 0.8, f"object IoU {iou:.3f} of the regenerated episode (tokenizer alone: {recon_iou:.3f})"
