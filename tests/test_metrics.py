"""Metrics against the reference libraries (scikit-image, pytorch-msssim) and hand-made masks."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from cosmos_lite.core.metrics import (
    MAX_PSNR,
    centroids,
    mask_iou,
    mask_iou_per_frame,
    motion_iou_per_frame,
    motion_masks,
    object_iou,
    object_iou_per_frame,
    psnr,
    psnr_per_frame,
    segment_by_palette,
    spatial_iou_so_far,
    ssim,
    ssim_per_frame,
    to_uint8,
    trajectory_errors,
    weighted_spatial_iou_so_far,
)
from cosmos_lite.sim import read_episode, simulate, write_episode
from cosmos_lite.video import read_frames

skimage_metrics = pytest.importorskip("skimage.metrics")
pytorch_msssim = pytest.importorskip("pytorch_msssim")


def _noisy(frames: np.ndarray, amount: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.clip(frames.astype(np.int16) + rng.integers(-amount, amount + 1, frames.shape), 0, 255).astype(np.uint8)


def _reference(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-frame PSNR and SSIM from scikit-image, SSIM from pytorch-msssim."""
    sk_ssim = [skimage_metrics.structural_similarity(x, y, gaussian_weights=True, sigma=1.5,
                                                     use_sample_covariance=False, data_range=255, channel_axis=-1)
               for x, y in zip(a, b)]
    sk_psnr = [skimage_metrics.peak_signal_noise_ratio(x, y, data_range=255) for x, y in zip(a, b)]
    t = lambda v: torch.from_numpy(v).permute(0, 3, 1, 2).double()  # noqa: E731
    ms = pytorch_msssim.ssim(t(a), t(b), data_range=255, size_average=False).numpy()
    return np.array(sk_psnr), np.array(sk_ssim), ms


def _pairs(sintel: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(1)
    random = rng.integers(0, 256, (3, 40, 56, 3), dtype=np.uint8)
    long = rng.integers(0, 256, (50, 64, 64, 3), dtype=np.uint8)  # three chunks of work, the last one shorter
    return [(random, _noisy(random, 60)), (random, rng.integers(0, 256, random.shape, dtype=np.uint8)),
            (long, _noisy(long, 40)),
            (sintel, _noisy(sintel, 12)), (sintel[:-1], sintel[1:])]


@pytest.fixture(scope="module")
def sintel(sintel_10s) -> np.ndarray:
    return read_frames(sintel_10s, start=40, end=44, size=(136, 240))


def test_psnr_and_ssim_match_scikit_image_and_pytorch_msssim(sintel):
    for a, b in _pairs(sintel):
        ref_psnr, ref_ssim, ms_ssim = _reference(a, b)
        np.testing.assert_allclose(psnr_per_frame(a, b), ref_psnr, atol=1e-4)
        np.testing.assert_allclose(ssim_per_frame(a, b), ref_ssim, atol=1e-4)
        np.testing.assert_allclose(ssim_per_frame(a, b), ms_ssim, atol=1e-4)
        assert psnr(a, b) == pytest.approx(ref_psnr.mean(), abs=1e-4)
        assert ssim(a, b) == pytest.approx(ref_ssim.mean(), abs=1e-4)


def test_model_tensors_batches_and_uint8_give_the_same_scores(sintel):
    a, b = sintel, _noisy(sintel, 30)
    ta = torch.from_numpy(a).permute(3, 0, 1, 2).float() / 127.5 - 1  # (3, T, H, W) in [-1, 1]
    tb = torch.from_numpy(b).permute(3, 0, 1, 2).float() / 127.5 - 1
    np.testing.assert_allclose(ssim_per_frame(ta, tb), ssim_per_frame(a, b), atol=1e-5)
    np.testing.assert_allclose(psnr_per_frame(ta, tb), psnr_per_frame(a, b), atol=1e-3)
    batched = ssim_per_frame(np.stack([a, b]), np.stack([b, b]))
    assert batched.shape == (2, len(a))
    np.testing.assert_allclose(batched[0], ssim_per_frame(a, b), atol=1e-6)
    np.testing.assert_allclose(batched[1], 1.0, atol=1e-6)
    assert np.array_equal(to_uint8(ta), a)
    assert psnr(a, a) == MAX_PSNR


def test_metrics_reject_mismatched_or_malformed_frames(sintel):
    with pytest.raises(ValueError, match="differ in shape"):
        psnr(sintel, sintel[:, :-1])
    with pytest.raises(ValueError, match="uint8 frames must be"):
        ssim(sintel[..., :2], sintel[..., :2])
    with pytest.raises(ValueError, match="at least 11x11"):
        ssim(sintel[:, :8, :8], sintel[:, :8, :8])
    with pytest.raises(TypeError, match="dtype"):
        psnr(sintel.astype(np.int32), sintel.astype(np.int32))


def test_iou_is_one_for_identical_masks_and_exact_for_hand_made_overlaps():
    a = np.zeros((2, 10, 10), np.uint8)
    b = np.zeros_like(a)
    a[:, 2:6, 2:6] = 1  # 16 pixels
    b[0, 3:7, 2:6] = 1  # shifted by one row: 12 shared, union 20
    b[1, 6:8, 6:8] = 1  # disjoint
    assert mask_iou(a, a) == 1.0 and mask_iou(np.zeros_like(a), np.zeros_like(a)) == 1.0
    np.testing.assert_array_equal(mask_iou_per_frame(a, b), [12 / 20, 0.0])
    assert mask_iou(a, b) == pytest.approx(12 / (20 + 16 + 4))
    a[:, 0, 0], b[:, 0, 0] = 2, 2  # a second object, present and equal in both
    per_frame = object_iou_per_frame(a, b, ids=[1, 2, 3])
    np.testing.assert_array_equal(per_frame[:, 0], [12 / 20, 0.0])
    np.testing.assert_array_equal(per_frame[:, 1], [1.0, 1.0])
    assert np.isnan(per_frame[:, 2]).all()  # object 3 is nowhere: no score rather than a perfect one
    assert object_iou(a, b) == {1: pytest.approx(12 / 40), 2: 1.0}


@pytest.mark.parametrize("scenario", ["bounce", "collision", "pusher", "pendulum", "ramp"])
def test_segment_by_palette_recovers_the_simulators_masks(scenario, tmp_path):
    ep = simulate(scenario, 4, frames=12, background="textured")
    palette, scenery = ep.meta["palette"], [ep.meta["scenery_color"]]
    ids = list(range(1, len(ep.meta["objects"]) + 1))
    direct = segment_by_palette(ep.frames, palette, background=scenery)
    assert np.array_equal(direct, ep.masks)  # hard-edged flat colours: exact on the rendered frames
    write_episode(ep, tmp_path, "ep")
    back = read_episode(tmp_path / "ep")  # after the mp4 round trip
    seg = segment_by_palette(back.frames, back.meta["palette"], background=scenery)
    assert min(object_iou(seg, ep.masks, ids).values()) >= 0.99


def test_centroid_trajectory_and_velocity_errors():
    masks = np.zeros((3, 20, 20), np.uint8)
    for t in range(3):
        masks[t, 4:8, 2 + 3 * t : 6 + 3 * t] = 1  # a 4x4 square moving 3 px/frame to the right
    np.testing.assert_allclose(centroids(masks, [1])[:, 0], [[4.0, 6.0], [7.0, 6.0], [10.0, 6.0]])
    shifted = np.roll(masks, 2, axis=1)  # 2 px lower, same motion
    err = trajectory_errors(shifted, masks)
    np.testing.assert_allclose(err["position"], 2.0)
    np.testing.assert_allclose(err["velocity"], 0.0)
    np.testing.assert_allclose(err["found"], 1.0)
    still = np.repeat(masks[:1], 3, axis=0)  # a prediction that never moves
    err = trajectory_errors(still, masks)
    np.testing.assert_allclose(err["position"], [0.0, 3.0, 6.0])
    np.testing.assert_allclose(err["velocity"], 3.0)
    lost = masks.copy()
    lost[2] = 0
    err = trajectory_errors(lost, masks)
    assert np.isnan(err["position"][2]) and err["found"][2] == 0.0


def test_motion_masks_find_the_moving_square(moving_square):
    moving = motion_masks(moving_square)
    truth = np.zeros(moving.shape, bool)
    for i in range(len(moving_square)):
        truth[i, 24:40, 2 + 2 * i : 18 + 2 * i] = True
    assert mask_iou(moving, truth) > 0.95
    np.testing.assert_allclose(motion_iou_per_frame(moving_square, moving_square), 1.0)
    frozen = np.repeat(moving_square[:1], len(moving_square), axis=0)
    assert motion_iou_per_frame(frozen, moving_square).mean() < 0.1


def test_physics_iq_spatial_and_weighted_spatial_iou_by_hand():
    target = np.zeros((3, 4, 4), bool)
    target[0, 0, 0] = target[1, 0, 0] = target[1, 0, 1] = target[2, 0, 1] = True  # pixel a twice, b twice
    pred = np.zeros_like(target)
    pred[0, 0, 0] = pred[2, 0, 2] = True  # a once, c once
    # where (moved at any time, over frames 0..t): {a} vs {a}; {a} vs {a, b}; {a, c} vs {a, b}
    np.testing.assert_allclose(spatial_iou_so_far(pred, target), [1.0, 1 / 2, 1 / 3])
    # how much (frames moved per pixel): min/max summed: t=0: 1/1; t=1: a 1 vs 2, b 0 vs 1 -> 1/3;
    # t=2: a 1 vs 2, b 0 vs 2, c 1 vs 0 -> 1/5
    np.testing.assert_allclose(weighted_spatial_iou_so_far(pred, target), [1.0, 1 / 3, 1 / 5])
    still = np.zeros_like(target)
    np.testing.assert_allclose(spatial_iou_so_far(still, still), 1.0)  # nothing moved in either: nothing missed
    np.testing.assert_allclose(weighted_spatial_iou_so_far(still, target), 0.0)
