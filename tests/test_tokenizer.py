"""Causal video tokenizer: shapes, causality, FSQ round trip, save/load, errors (tiny configs, seconds)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from cosmos_lite.cli import main as cli_main
from cosmos_lite.core.frames import to_tensor
from cosmos_lite.errors import ConfigError, InputError
from cosmos_lite.tokenizers import VARIANTS, build_tokenizer, load_tokenizer
from cosmos_lite.tokenizers.inference import (
    _windows,
    bicubic_baseline,
    decode_long,
    encode_long,
    pad_video,
    reconstruct,
)
from cosmos_lite.tokenizers.train import codebook_usage, reconstruction_loss


@pytest.fixture(autouse=True)
def _seed():
    torch.manual_seed(0)


def video(t: int, h: int = 32, w: int = 32, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(1, 3, t, h, w, generator=g) * 2 - 1


@pytest.mark.parametrize("variant", list(VARIANTS))
def test_shapes_every_variant(variant):
    tok = build_tokenizer(variant, "tiny").eval()
    ct, cs = tok.temporal_compression, tok.spatial_compression
    x = torch.cat([video(1 + 2 * ct, 32, 48), video(1 + 2 * ct, 32, 48, seed=1)])
    with torch.no_grad():
        z = tok.encode(x)
        assert z.shape == (2, tok.latent_channels, 3, 32 // cs, 48 // cs)
        assert tok.decode(z).shape == x.shape
        image = tok.encode(x[:, :, :1])  # an image is a 1-frame video
        assert image.shape == (2, tok.latent_channels, 1, 32 // cs, 48 // cs)
        torch.testing.assert_close(image[:, :, 0], z[:, :, 0], rtol=1e-4, atol=1e-5)
    assert tok.latent_channels == (6 if variant.startswith("dv") else 16)


@pytest.mark.parametrize("variant", ["cv4x8x8", "dv8x16x16", "cv1x4x4", "cv2x4x4"])
def test_causal_encode_and_decode(variant):
    tok = build_tokenizer(variant, "tiny").eval()
    ct = tok.temporal_compression
    x = video(1 + 3 * ct)
    with torch.no_grad():
        z = tok.encode(x)
        for t in (1, ct + 1, 2 * ct):  # frame t belongs to latent group (t - 1) // ct + 1
            x2 = x.clone()
            x2[:, :, t] = -x2[:, :, t]
            z2 = tok.encode(x2)
            g = (t - 1) // ct + 1
            assert torch.equal(z2[:, :, :g], z[:, :, :g]), f"latents before group {g} changed"
            pre, pre2 = (tok.quant_conv(tok.encoder(tok.patcher(v))) for v in (x, x2))  # before FSQ rounding
            assert not torch.equal(pre2[:, :, g], pre[:, :, g])
        z2 = z.clone()
        z2[:, :, 2] += 1.0  # changing latent frame 2 leaves the frames decoded from latents 0..1 unchanged
        y, y2 = tok.decode(z), tok.decode(z2)
        assert torch.equal(y[:, :, : 1 + ct], y2[:, :, : 1 + ct])
        assert not torch.equal(y[:, :, 1 + ct :], y2[:, :, 1 + ct :])


@pytest.mark.parametrize(("variant", "pt"), [("cv4x8x8", 4), ("cv2x4x4", 2), ("cv1x4x4", 1)])
def test_haar_patcher_inverts_exactly(variant, pt):
    p = build_tokenizer(variant, "tiny").patcher  # 4x4 spatial patches, pt frames in time
    x = video(9, 16, 24)
    y = p(x)
    assert y.shape == (1, 3 * pt * 16, 1 + 8 // pt, 4, 6)
    torch.testing.assert_close(p.inverse(y), x, rtol=0, atol=1e-5)
    torch.testing.assert_close(y.square().sum(), torch.cat([x[:, :, :1]] * (pt - 1) + [x], 2).square().sum())


def test_fsq_indices_codes_round_trip():
    tok = build_tokenizer("dv4x8x8", "tiny").eval()
    fsq = tok.fsq
    assert fsq.codebook_size == 8 * 8 * 8 * 5 * 5 * 5
    idx = torch.arange(fsq.codebook_size).view(1, 1, 40, 1600)
    codes = fsq.indices_to_codes(idx)
    assert codes.shape == (1, 6, 1, 40, 1600) and codes.abs().max() <= 1
    assert torch.equal(fsq.codes_to_indices(codes), idx)
    with torch.no_grad():
        z, indices = tok.encode(video(9), return_indices=True)
        assert torch.equal(fsq.indices_to_codes(indices), z)
        assert torch.equal(tok.decode_indices(indices), tok.decode(z))
    assert indices.dtype == torch.long and indices.min() >= 0 and indices.max() < fsq.codebook_size


def test_fsq_snap_rounds_to_the_nearest_code_and_clamps_to_the_grid():
    fsq = build_tokenizer("dv1x4x4", "tiny", levels=[7, 8, 5]).fsq
    codes = fsq.indices_to_codes(torch.arange(fsq.codebook_size).view(1, 1, 1, 280))
    off = torch.rand(codes.shape, generator=torch.Generator().manual_seed(0)) * 0.2 - 0.1  # under half a step (1/8)
    assert torch.equal(fsq.snap(codes + off * 0.5 / 0.4), codes)
    assert fsq.snap(codes * 3).amax(dim=(0, 2, 3, 4)).tolist() == [1.0, 0.75, 1.0]  # even levels: one less above 0
    assert fsq.snap(-codes * 3).amin(dim=(0, 2, 3, 4)).tolist() == [-1.0, -1.0, -1.0]


def test_fsq_passes_gradients_straight_through():
    fsq = build_tokenizer("dv4x8x8", "tiny").fsq
    z = torch.randn(2, 6, 1, 3, 3, requires_grad=True)
    codes, _ = fsq(z)
    codes.sum().backward()
    assert z.grad is not None and z.grad.abs().sum() > 0


@pytest.mark.parametrize("variant", ["cv8x8x8", "dv4x8x8"])
def test_save_load_bit_exact(tmp_path, variant):
    tok = build_tokenizer(variant, "tiny").eval()
    with torch.no_grad():  # perturb the zero-initialised layers so the check covers every weight
        for p in tok.parameters():
            p.add_(torch.randn_like(p) * 0.01)
    tok.save(tmp_path / "ckpt")
    assert sorted(f.name for f in (tmp_path / "ckpt").iterdir()) == ["config.yaml", "model.safetensors"]
    loaded = load_tokenizer(tmp_path / "ckpt")
    assert loaded.cfg == tok.cfg
    x = video(1 + 2 * tok.temporal_compression)
    with torch.no_grad():
        assert torch.equal(loaded.decode(loaded.encode(x)), tok.decode(tok.encode(x)))


def test_bad_inputs_and_configs(tmp_path):
    tok = build_tokenizer("cv4x8x8", "tiny")
    with pytest.raises(InputError, match=r"1 \+ k\*4"):
        tok.encode(video(8))
    with pytest.raises(InputError, match="multiples of 8"):
        tok.encode(video(5, 30, 32))
    with pytest.raises(ConfigError, match="unknown tokenizer variant"):
        build_tokenizer("cv2x2x2")
    with pytest.raises(ConfigError, match="unknown tokenizer size"):
        build_tokenizer("cv4x8x8", "huge")
    with pytest.raises(ConfigError, match="continuous"):
        tok.encode(video(5), return_indices=True)
    with pytest.raises(InputError, match="model.safetensors is missing"):
        load_tokenizer(tmp_path)


def test_long_video_windows_match_single_window_and_cover_every_frame():
    tok = build_tokenizer("cv4x8x8", "tiny").eval()
    x = video(1 + 4 * 5)  # 6 latent frames: fits one window of 8
    with torch.no_grad():
        assert torch.equal(encode_long(tok, x, window=8, overlap=3), tok.encode(x))
        long = video(1 + 4 * 20)  # 21 latent frames: several overlapping windows
        z = encode_long(tok, long, window=6, overlap=2)
        assert z.shape == (1, 16, 21, 4, 4)
        torch.testing.assert_close(z[:, :, :6], tok.encode(long[:, :, :21]))  # the first window is exact
        assert decode_long(tok, z, window=6, overlap=2).shape == long.shape
        u8 = ((long + 1) * 127.5).round().to(torch.uint8)  # uint8 input is converted window by window
        torch.testing.assert_close(encode_long(tok, u8, 6, 2), encode_long(tok, u8.float() / 127.5 - 1, 6, 2))
    spans = _windows(21, 6, 2)
    kept = [i for s, e, keep in spans for i in range(s + keep, e)]
    assert kept == list(range(21))  # every latent frame is produced exactly once
    assert all(keep >= 3 for s, e, keep in spans[1:])  # ... after an image latent plus `overlap` of context


def test_pad_video_reaches_the_latent_grid():
    x = video(10, 30, 20)
    p = pad_video(x, 4, 8)
    assert p.shape == (1, 3, 13, 32, 24)
    assert torch.equal(p[:, :, :10, :30, :20], x) and torch.equal(p[:, :, 12, 31, 23], x[:, :, 9, 29, 19])


def test_bicubic_baseline_uses_no_more_values_than_allowed_and_reconstructs():
    x = video(17, 64, 64)
    smooth = torch.nn.functional.avg_pool3d(x, (1, 9, 9), 1, (0, 4, 4))
    rec, how = bicubic_baseline(smooth, values=16 * 5 * 8 * 8, ct=4)
    assert rec.shape == smooth.shape and "every" in how
    assert (rec - smooth).square().mean() < smooth.var()  # better than predicting the mean


def test_a_few_training_steps_lower_the_loss(moving_square):
    tok = build_tokenizer("dv4x8x8", "tiny")
    x = to_tensor(moving_square[:17])
    opt = torch.optim.AdamW(tok.parameters(), lr=3e-3)
    losses = []
    for _ in range(12):
        loss = reconstruction_loss(tok(x), x, grad_weight=1.0, temporal_weight=0.5)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.8 * losses[0], losses


def test_codebook_usage_perplexity():
    uniform = codebook_usage(torch.arange(100).repeat(3), 1000)
    assert uniform["perplexity"] == pytest.approx(100) and uniform["used"] == pytest.approx(0.1)
    assert codebook_usage(torch.zeros(50, dtype=torch.long), 1000)["perplexity"] == pytest.approx(1)


def test_reconstruct_crops_back_and_scores_with_the_metrics(moving_square):
    from cosmos_lite.core.metrics import psnr, ssim

    tok = build_tokenizer("dv4x8x8", "tiny").eval()
    frames = moving_square[:22, :60]  # neither 1 + 4k frames nor a multiple of 8 high: padded, then cropped back
    recon, m = reconstruct(tok, frames, window=3, overlap=1)
    assert recon.shape == frames.shape and recon.dtype == np.uint8
    assert m["psnr"] == pytest.approx(psnr(recon, frames)) and m["ssim"] == pytest.approx(ssim(recon, frames))
    assert m["latent"] == [6, 7, 8, 8] and m["indices"].shape == (1, 7, 8, 8)
    assert m["compression"] == pytest.approx(22 * 60 * 64 * 3 * 8 / (7 * 8 * 8 * math.log2(8**3 * 5**3)))


@pytest.fixture()
def episodes(tmp_path):
    from cosmos_lite.sim.cli import SimConfig, run

    run(SimConfig(episodes=6, frames=17, size=32), tmp_path / "episodes")
    return tmp_path / "episodes"


def test_train_cli_writes_a_checkpoint_logs_held_out_metrics_and_resumes(tmp_path, episodes):
    out = tmp_path / "run"
    args = ["train", "experiment=tokenizer_tiny", f"data.roots=[{episodes}]", f"out={out}", "data.val_every=3",
            "trainer.val_every=3", "trainer.ckpt_every=3"]
    assert cli_main([*args, "trainer.steps=6"]) == 0
    records = [json.loads(line) for line in (out / "val.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records] == [3, 6] and all(math.isfinite(r["psnr"]) for r in records)
    assert (out / "train_state.safetensors").is_file()
    first = load_tokenizer(out)
    assert cli_main([*args, "trainer.steps=9"]) == 0  # resumes at step 6, not from scratch
    assert [json.loads(line)["step"] for line in (out / "val.jsonl").read_text().splitlines()] == [3, 6, 9]
    later = load_tokenizer(out).state_dict()
    assert any(not torch.equal(v, later[k]) for k, v in first.state_dict().items())
    assert cli_main(["train", "experiment=tokenizer_tiny", f"out={out}"]) == 2  # no data.roots


def test_tokenize_cli_prints_metrics_and_writes_the_reconstruction(tmp_path, sintel_10s, capsys):
    from cosmos_lite.video import probe

    ckpt = build_tokenizer("dv4x8x8", "tiny").save(tmp_path / "ckpt")
    out = tmp_path / "recon.mp4"
    args = ["tokenize", f"checkpoint={ckpt}", "size=32", "max_frames=20", "window=3", "overlap=1"]
    assert cli_main([*args, f"input={sintel_10s}", f"output={out}"]) == 0
    r = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert r["frames"] == 20 and r["size"] == [32, 32] and r["latent"] == [6, 6, 4, 4]
    assert math.isfinite(r["psnr"]) and 0 < r["ssim"] < 1 and r["perplexity"] >= 1 and r["compression"] > 1
    assert probe(out).num_frames == 20 and probe(out).size == (32, 32)
    assert cli_main([*args, f"input={tmp_path / 'missing.mp4'}"]) == 4
    assert cli_main([*args, f"input={sintel_10s}", f"output={tmp_path / 'recon.avi'}"]) == 2
    assert cli_main(["tokenize", f"checkpoint={tmp_path}", f"input={sintel_10s}"]) == 4


def test_reconstruction_loss_terms():
    x = torch.zeros(1, 3, 5, 8, 8)
    y = x.clone()
    y[..., 0, 0] = 1.0  # one wrong pixel per frame and channel
    n = y.numel()
    assert reconstruction_loss(y, x, 0.0, 0.0, "l2").item() == pytest.approx(3 * 5 / n)
    assert reconstruction_loss(y * 2, x, 0.0, 0.0, "l2").item() == pytest.approx(4 * 3 * 5 / n)
    assert reconstruction_loss(y * 2, x, 0.0, 0.0, "l1").item() == pytest.approx(2 * 3 * 5 / n)
    assert reconstruction_loss(y, x, 1.0, 0.0).item() > reconstruction_loss(y, x, 0.0, 0.0).item()
    with pytest.raises(ConfigError, match="loss.pixel"):
        reconstruction_loss(y, x, 0.0, 0.0, "l3")


def test_moving_weight_counts_errors_on_moving_pixels_more():
    x = -torch.ones(1, 3, 5, 8, 8)
    x[:, :, 2, 4, 4] = 1.0  # an object passes pixel (4, 4) in frame 2: the only moving pixel
    on_object, on_background = x.clone(), x.clone()
    on_object[:, :, 2, 4, 4] -= 0.5
    on_background[:, :, 2, 0, 0] += 0.5  # the same error on a static pixel
    for y in (on_object, on_background):  # without the weight both cost the same
        assert reconstruction_loss(y, x, 0.0, 0.0, "l2").item() == pytest.approx(3 * 0.25 / x.numel())
    weighted = [reconstruction_loss(y, x, 0.0, 0.0, "l2", moving_weight=3.0).item() for y in (on_object, on_background)]
    assert weighted[0] == pytest.approx(4 * weighted[1])


def test_object_weight_counts_errors_on_still_objects_more():
    x = -torch.ones(1, 3, 5, 8, 8)
    x[:, :, :, 4, 4] = 1.0  # an object that rests at pixel (4, 4) in every frame: not moving, but not background
    on_object, on_background = x.clone(), x.clone()
    on_object[:, :, 2, 4, 4] -= 0.5
    on_background[:, :, 2, 0, 0] += 0.5
    errors = (on_object, on_background)
    moving_only = [reconstruction_loss(y, x, 0.0, 0.0, "l2", moving_weight=3.0).item() for y in errors]
    assert moving_only[0] == pytest.approx(moving_only[1])  # the moving weight sees a still object as background
    weighted = [reconstruction_loss(y, x, 0.0, 0.0, "l2", object_weight=3.0).item() for y in errors]
    assert weighted[0] == pytest.approx(4 * weighted[1])
