"""Train the post-guard's frame classifier on your own labelled frames:
`cosmos-lite train experiment=frame_classifier data.root=DIR data.safe=[safe] out=runs/frame_classifier`.

DIR has one folder per class holding images or videos (`DIR/safe/*.mp4`, `DIR/weapon/*.png`, ...). Frames are
sampled from each file, a held-out share of the files measures accuracy, and the checkpoint (model.safetensors +
config.yaml) is what `guardrails.frame_classifier.checkpoint=DIR` loads.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig

from ..config import setting, to_dataclass
from ..errors import ConfigError, InputError
from ..log import get_logger
from ..video import iter_frames
from .classifier import FrameClassifier

log = get_logger("guardrails.train")
MEDIA = {".mp4", ".mkv", ".mov", ".webm", ".avi", ".png", ".jpg", ".jpeg", ".bmp", ".webp"}


@dataclass
class DataConfig:
    """Where the labelled frames are and how many to take from each file."""

    root: str | None = None  # one sub-folder of images/videos per class
    safe: list[str] = field(default_factory=lambda: ["safe"])  # classes the guard allows
    size: int = setting(64, low=8)  # frames are resized to size x size
    frames_per_file: int = setting(16, low=1)  # evenly spaced frames taken from each video
    val_every: int = setting(5, low=0)  # every val_every-th file of a class is held out (0: none)


@dataclass
class TrainerConfig:
    epochs: int = setting(20, low=1)
    batch_size: int = setting(32, low=1)
    lr: float = setting(3e-3, above=0)
    weight_decay: float = setting(1e-4, low=0)
    width: int = setting(32, low=1)
    threads: int = setting(0, low=0)  # torch threads (0: torch's default)


def load_frames(path: Path, size: int, count: int) -> np.ndarray:
    """Up to `count` evenly spaced frames of an image or video, resized to size x size."""
    frames = np.stack(list(iter_frames(path, size=size)))
    return frames[np.unique(np.linspace(0, len(frames) - 1, count).round().astype(int))]


def load_dataset(cfg: DataConfig) -> tuple[list[str], dict[str, tuple[np.ndarray, np.ndarray]]]:
    """Class names and the train/val splits as (frames uint8 (N, S, S, 3), labels (N,))."""
    root = Path(cfg.root or "")
    if not cfg.root or not root.is_dir():
        raise ConfigError(f"data.root={cfg.root!r} is not a folder; pass data.root=DIR with one sub-folder of "
                          "images or videos per class")
    classes = sorted(d.name for d in root.iterdir() if d.is_dir())
    if len(classes) < 2 or not set(cfg.safe) <= set(classes):
        raise ConfigError(f"{root}: needs at least two class folders including the safe one(s) {cfg.safe}; "
                          f"found {classes}")
    splits: dict[str, tuple[list, list]] = {"train": ([], []), "val": ([], [])}
    for label, name in enumerate(classes):
        files = sorted(f for f in (root / name).rglob("*") if f.suffix.lower() in MEDIA)
        if not files:
            raise InputError(f"{root / name}: no images or videos ({', '.join(sorted(MEDIA))})")
        for i, f in enumerate(files):
            split = "val" if cfg.val_every and i % cfg.val_every == cfg.val_every - 1 else "train"
            frames = load_frames(f, cfg.size, cfg.frames_per_file)
            splits[split][0].append(frames)
            splits[split][1].append(np.full(len(frames), label))
    return classes, {k: (np.concatenate(x), np.concatenate(y)) for k, (x, y) in splits.items() if x}


def accuracy(model: FrameClassifier, frames: np.ndarray, labels: np.ndarray) -> float:
    return float((model.predict(frames).argmax(1) == labels).mean())


def main(cfg: DictConfig, args: list[str]) -> int:
    """Train, report held-out accuracy and write the checkpoint to `out`."""
    data = to_dataclass(DataConfig, cfg.data, "data")
    tr = to_dataclass(TrainerConfig, cfg.trainer, "trainer")
    if tr.threads:
        torch.set_num_threads(tr.threads)
    torch.manual_seed(int(cfg.get("seed", 0)))
    classes, splits = load_dataset(data)
    x, y = splits["train"]
    model = FrameClassifier(classes, data.safe, data.size, tr.width)
    inputs, targets = model.prepare(x), torch.from_numpy(y)
    weight = len(y) / (len(classes) * np.bincount(y, minlength=len(classes)).clip(min=1))  # balance the classes
    loss_fn = torch.nn.CrossEntropyLoss(weight=torch.tensor(weight, dtype=torch.float32))
    opt = torch.optim.AdamW(model.parameters(), lr=tr.lr, weight_decay=tr.weight_decay)
    steps = tr.epochs * -(-len(y) // tr.batch_size)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, tr.lr, total_steps=steps)
    t0 = time.perf_counter()
    for epoch in range(tr.epochs):
        model.train()
        total = 0.0
        for idx in torch.randperm(len(y)).split(tr.batch_size):
            xb = inputs[idx]
            xb = torch.where(torch.rand(len(idx), 1, 1, 1) < 0.5, xb, xb.flip(-1))  # horizontal flips
            loss = loss_fn(model(xb), targets[idx])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            total += loss.item() * len(idx)
        log.info("epoch %d/%d loss %.4f", epoch + 1, tr.epochs, total / len(y))
    summary = {"classes": classes, "safe": data.safe, "train_frames": len(y), "train_accuracy": accuracy(model, x, y),
               "seconds": round(time.perf_counter() - t0, 1)}
    if "val" in splits:
        summary |= {"val_frames": len(splits["val"][1]), "val_accuracy": accuracy(model, *splits["val"])}
    out = model.save(cfg.out)
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(summary))
    return 0
