"""VideoWindows: fixed-length windows from simulated episodes and curated clips, default-collatable."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from cosmos_lite.core.dataset import VideoWindows
from cosmos_lite.errors import InputError
from cosmos_lite.sim import simulate, write_episode
from cosmos_lite.video import write_video


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("mixed")
    eps = {}
    for i, (scenario, split) in enumerate([("pusher", "id"), ("bounce", "ood")]):
        eps[f"e{i}"] = simulate(scenario, i, split=split)
        write_episode(eps[f"e{i}"], root, f"e{i}")
    (root / "index.json").write_text("{}")
    clip = np.random.default_rng(0).integers(0, 255, (20, 64, 64, 3), dtype=np.uint8)
    write_video(root / "clips" / "c0.mp4", clip, 24)
    (root / "metas").mkdir()
    (root / "metas" / "c0.json").write_text(json.dumps({"caption": "a real clip", "kept": True}))
    (root / "metas" / "dropped.json").write_text(json.dumps({"kept": False, "why": "too dark"}))
    return root, eps


def test_windows_from_episodes_and_clips(folder):
    root, eps = folder
    ds = VideoWindows(root, num_frames=9, stride=8)
    assert len(ds) == 4 + 4 + 2  # 33-frame episodes: starts 0, 8, 16, 24; the 20-frame clip: 0, 8
    by_name = {(it["name"], it["start"]): it for it in ds}
    item = by_name[("e0", 8)]
    assert item["video"].shape == (3, 9, 64, 64) and item["video"].dtype == torch.float32
    assert -1.0 <= item["video"].min() and item["video"].max() <= 1.0
    ref = torch.from_numpy(eps["e0"].frames[8:17]).permute(3, 0, 1, 2).float() / 127.5 - 1
    assert (item["video"] - ref).abs().mean() < 0.01
    assert item["has_masks"] and torch.equal(item["masks"], torch.from_numpy(eps["e0"].masks[8:17]))
    np.testing.assert_allclose(item["actions"].numpy(), eps["e0"].actions[8:17])
    assert item["caption"] == eps["e0"].meta["caption"]
    clip = by_name[("c0", 8)]
    assert not clip["has_masks"] and clip["caption"] == "a real clip" and not clip["masks"].any()
    assert not clip["actions"].any()
    batch = next(iter(DataLoader(ds, batch_size=4, shuffle=True)))
    assert batch["video"].shape == (4, 3, 9, 64, 64) and batch["actions"].shape == (4, 9, 2)
    assert len(batch["caption"]) == 4 and batch["has_masks"].dtype == torch.bool


def test_resize_split_and_cache(folder):
    root, eps = folder
    ds = VideoWindows([root], num_frames=33, size=32, split="id", cache_mb=1)
    assert sorted(s.name for s in ds.sources) == ["c0", "e0"] and len(ds) == 1  # the clip is too short
    item = ds[0]
    assert item["video"].shape == (3, 33, 32, 32) and item["masks"].shape == (33, 32, 32)
    np.testing.assert_array_equal(item["masks"].numpy(), eps["e0"].masks[:, 1::2, 1::2])
    np.testing.assert_allclose(item["actions"].numpy(), eps["e0"].actions / 2, rtol=1e-6)
    assert torch.equal(ds[0]["video"], item["video"])  # served from the cache
    assert [s.name for s in VideoWindows(root, 17, split="ood").sources] == ["e1"]


def test_bad_roots(tmp_path):
    with pytest.raises(InputError, match="no such folder"):
        VideoWindows(tmp_path / "nope", 9)
    with pytest.raises(InputError, match="no episodes"):
        VideoWindows(tmp_path, 9)


def test_resample_to_a_common_fps(folder):
    root, eps = folder
    ds = VideoWindows(root, num_frames=9, stride=8, fps=32)
    assert {s.name: ds._length(s) for s in ds.sources} == {"e0": 65, "e1": 65, "c0": 26}
    item = next(it for it in (ds[i] for i in range(len(ds))) if it["name"] == "e0" and it["start"] == 8)
    idx = np.floor(np.arange(8, 17) / 2 + 0.5).astype(int)  # nearest source frame at 16 fps
    np.testing.assert_array_equal(item["masks"].numpy(), eps["e0"].masks[idx])
    ref = torch.from_numpy(eps["e0"].frames[idx]).permute(3, 0, 1, 2).float() / 127.5 - 1
    assert (item["video"] - ref).abs().mean() < 0.01 and item["fps"] == 32
    assert next(iter(DataLoader(ds, batch_size=len(ds))))["video"].shape == (len(ds), 3, 9, 64, 64)


def test_validation_windows_are_spread_over_all_videos():
    from cosmos_lite.core.dataset import spread

    assert spread(4, 10) == [0, 3, 6, 9]
    assert spread(16, 5) == [0, 1, 2, 3, 4]
    assert spread(1, 10) == [0]
    assert spread(3, 0) == []
