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
from omegaconf import DictConfig, OmegaConf
from torch.utils.data import TensorDataset

from ..config import number, register, setting, to_dataclass
from ..core.engine import Batch, TrainerConfig, train
from ..errors import ConfigError, InputError
from ..files import write_text
from ..video import iter_frames
from .classifier import FrameClassifier

MEDIA = {".mp4", ".mkv", ".mov", ".webm", ".avi", ".png", ".jpg", ".jpeg", ".bmp", ".webp"}


@dataclass
class DataConfig:
    """Where the labelled frames are and how many to take from each file."""

    root: str | None = None  # one sub-folder of images/videos per class
    safe: list[str] = field(default_factory=lambda: ["safe"])  # classes the guard allows
    size: int = setting(64, low=8)  # frames are resized to size x size
    frames_per_file: int = setting(16, low=1)  # evenly spaced frames taken from each video
    val_every: int = setting(5, low=0)  # every val_every-th file of a class is held out (0: none)


register("data", "frames", DataConfig)


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


class FrameClassifierTask:
    """The engine's task: class-balanced cross-entropy of the classifier on (randomly flipped) training frames."""

    def __init__(self, cfg: DictConfig, device: torch.device):
        self.dcfg, self.device = to_dataclass(DataConfig, cfg.data, "data"), device
        classes, self.splits = load_dataset(self.dcfg)
        x, y = self.splits["train"]
        self.model = FrameClassifier(classes, self.dcfg.safe, self.dcfg.size,
                                     number("model.width", cfg.model.width, low=1))
        self.data = TensorDataset(self.model.prepare(x), torch.from_numpy(y))
        weight = len(y) / (len(classes) * np.bincount(y, minlength=len(classes)).clip(min=1))  # balance the classes
        self.criterion = torch.nn.CrossEntropyLoss(weight=torch.tensor(weight, dtype=torch.float32)).to(device)

    def loss(self, net: torch.nn.Module, items: list, batch: Batch) -> torch.Tensor:
        x = torch.stack([it[0] for it in items]).to(self.device)
        x = torch.where(torch.rand(len(x), 1, 1, 1, device=self.device) < 0.5, x, x.flip(-1))  # horizontal flips
        return self.criterion(net(x), torch.stack([it[1] for it in items]).to(self.device))

    def save(self, ema: FrameClassifier, out: Path) -> None:
        ema.save(out)


def main(cfg: DictConfig, args: list[str]) -> int:
    """Train, report held-out accuracy and write the checkpoint to `out`."""
    trainer = to_dataclass(TrainerConfig, cfg.trainer, "trainer")
    t0 = time.perf_counter()
    task, model = train(lambda device: FrameClassifierTask(cfg, device), trainer, cfg.out, int(cfg.seed),
                        OmegaConf.to_container(cfg, resolve=True))
    splits, model = task.splits, model.cpu()
    x, y = splits["train"]
    summary = {"classes": model.classes, "safe": model.safe, "train_frames": len(y),
               "train_accuracy": accuracy(model, x, y), "seconds": round(time.perf_counter() - t0, 1)}
    if "val" in splits:
        summary |= {"val_frames": len(splits["val"][1]), "val_accuracy": accuracy(model, *splits["val"])}
    write_text(Path(cfg.out) / "summary.json", json.dumps(summary, indent=1))
    print(json.dumps(summary))
    return 0
