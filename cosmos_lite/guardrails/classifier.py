"""A small CNN frame classifier that users train on their own labelled frames (`cosmos-lite train
experiment=frame_classifier`) and the post-guard runs on sampled frames. Checkpoint: a folder with
model.safetensors and config.yaml (classes, which of them are safe, input size).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from omegaconf import OmegaConf
from safetensors.torch import load_file
from torch import nn

from ..core.checkpoint import save_tensors
from ..core.frames import to_tensor
from ..errors import InputError
from ..files import write_text


def block(cin: int, cout: int) -> nn.Sequential:
    """Conv 3x3 stride 2, group norm, GELU: halves the resolution."""
    return nn.Sequential(nn.Conv2d(cin, cout, 3, 2, 1), nn.GroupNorm(8, cout), nn.GELU())


class FrameClassifier(nn.Module):
    """Four stride-2 conv blocks, global average pooling and a linear head over `classes`."""

    def __init__(self, classes: list[str], safe: list[str], size: int = 64, width: int = 32):
        super().__init__()
        self.classes, self.safe, self.size, self.width = list(classes), list(safe), size, width
        self.features = nn.Sequential(block(3, width), block(width, width), block(width, 2 * width),
                                      block(2 * width, 2 * width))
        self.head = nn.Linear(2 * width, len(classes))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Logits `(B, classes)` for frames `(B, 3, size, size)` in [-1, 1]."""
        return self.head(self.features(x).mean((2, 3)))

    def prepare(self, frames: np.ndarray) -> torch.Tensor:
        """uint8 `(T, H, W, 3)` frames to the model's input (resized, [-1, 1])."""
        x = to_tensor(frames)[0].transpose(0, 1)  # (T, 3, H, W): one image per frame
        return nn.functional.interpolate(x, size=(self.size, self.size), mode="area")

    @torch.no_grad()
    def predict(self, frames: np.ndarray, batch: int = 64) -> np.ndarray:
        """Class probabilities `(T, classes)` for uint8 `(T, H, W, 3)` frames."""
        self.eval()
        return torch.cat([self(self.prepare(frames[i : i + batch])).softmax(-1)
                          for i in range(0, len(frames), batch)]).numpy()

    def save(self, directory: str | Path) -> Path:
        """Write model.safetensors and config.yaml atomically."""
        d = Path(directory)
        d.mkdir(parents=True, exist_ok=True)
        save_tensors(d / "model.safetensors", self.state_dict())
        meta = {"classes": self.classes, "safe": self.safe, "size": self.size, "width": self.width}
        write_text(d / "config.yaml", OmegaConf.to_yaml(OmegaConf.create({"frame_classifier": meta})))
        return d


def load_classifier(directory: str | Path) -> FrameClassifier:
    """Load a checkpoint folder written by `FrameClassifier.save`, in eval mode."""
    d = Path(directory)
    weights, config = d / "model.safetensors", d / "config.yaml"
    if not weights.is_file() or not config.is_file():
        raise InputError(f"{d}: not a frame-classifier checkpoint (needs model.safetensors and config.yaml); "
                         "train one with `cosmos-lite train experiment=frame_classifier data.root=DIR out=DIR`")
    meta = OmegaConf.load(config).frame_classifier
    model = FrameClassifier(list(meta.classes), list(meta.safe), int(meta.size), int(meta.width))
    model.load_state_dict(load_file(weights))
    return model.eval()
