"""The sentence reader: a description's movement, role and subject, read by a tuned text encoder.

A person's words state a fact in any order and often by denying the others ("it is not the goal,
you carry it there"), which a bag of word vectors cannot tell from the fact itself. The reader
keeps the frozen all-MiniLM-L6-v2 (`frozen_text.py`) and adds low-rank adapters to the query and
value projections of each of its attention layers, with one linear head per fact over the mean
token vector, trained on descriptions of known truth (`scripts/fit_reading.py`). The third fact,
the subject, says whether a text is about an entity of the game at all, about some other thing
("the dragon chases you"), or about nothing (gibberish, small talk): a keyword-free guess at the
entity means little when the text is about a dragon. A fact a text does not state (stray text's
movement and role) is trained towards even odds, so text that says nothing is read as saying
nothing. The adapters and heads are about 76k numbers a fold, so they ship beside a checkpoint in
half precision (`reading_sentence.safetensors`, 300 kB).

Cross-fitting: the text is split in `folds` parts and each fold's adapters are trained on the
others, so every fitting description has a reading by adapters that never saw it; the reading's
stacking weights (`manual_reading.py`) are fitted on those, so they weigh the reader as it reads
new text. At run time a description is read by every fold and their probabilities averaged.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from ..errors import LwmError

FACTS = ("movement", "role", "subject")
SUBJECTS = ("entity", "other", "nothing")  # an entity of the game; a thing of no Messenger game; nothing
SENTENCE_FILE = "reading_sentence.safetensors"  # beside a checkpoint's reading.json


@dataclass(frozen=True)
class SentenceReaderConfig:
    rank: int = 8  # of each adapter's update B @ A
    alpha: float = 16.0  # the update is scaled by alpha / rank
    folds: int = 2  # adapter sets, each trained on the text the others hold out
    max_tokens: int = 96  # tokens read of a description, so a long one is read whole
    steps: int = 800  # training steps per fold
    batch: int = 32
    lr: float = 1e-3
    weight_decay: float = 1e-2
    warmup: int = 50  # steps of linear warm-up before the cosine decay


class _Adapted(nn.Module):
    """A frozen linear layer plus one low-rank update per fold. `fold` selects one update; None
    applies update k to the k-th of `folds` equal chunks of the batch, so all folds read at once."""

    def __init__(self, linear: nn.Linear, folds: int, rank: int, alpha: float):
        super().__init__()
        self.linear = linear
        self.a = nn.Parameter(torch.randn(folds, rank, linear.in_features) / math.sqrt(linear.in_features))
        self.b = nn.Parameter(torch.zeros(folds, linear.out_features, rank))  # a zero update at the start
        self.scale = alpha / rank
        self.fold: int | None = None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.linear(x)
        if self.fold is not None:
            return y + self.scale * (x @ self.a[self.fold].T) @ self.b[self.fold].T
        k = self.a.shape[0]
        xs = x.reshape(k, -1, *x.shape[1:])  # [K, N, T, in]
        delta = torch.einsum("knti,kri->kntr", xs, self.a)
        delta = torch.einsum("kntr,kor->knto", delta, self.b)
        return y + self.scale * delta.reshape(y.shape)


class SentenceReader(nn.Module):
    """Texts -> per fact, [N, 3] log-probabilities of its values (MOVEMENTS, ROLES, SUBJECTS order)."""

    def __init__(self, cfg: SentenceReaderConfig = SentenceReaderConfig(), model_path: str | None = None):
        super().__init__()
        from transformers import AutoModel, AutoTokenizer

        from .frozen_text import default_model_path

        path = model_path or default_model_path()
        self.cfg = cfg
        self.tokenizer = AutoTokenizer.from_pretrained(path)
        self.encoder = AutoModel.from_pretrained(path).eval()
        for p in self.encoder.parameters():
            p.requires_grad_(False)
        self.adapted: list[_Adapted] = []
        for layer in self.encoder.encoder.layer:
            attention = layer.attention.self
            attention.query = _Adapted(attention.query, cfg.folds, cfg.rank, cfg.alpha)
            attention.value = _Adapted(attention.value, cfg.folds, cfg.rank, cfg.alpha)
            self.adapted += [attention.query, attention.value]
        hidden = self.encoder.config.hidden_size
        self.head_weight = nn.Parameter(torch.zeros(cfg.folds, len(FACTS), 3, hidden))
        self.head_bias = nn.Parameter(torch.zeros(cfg.folds, len(FACTS), 3))
        self._memory: dict[str, np.ndarray] = {}

    def trainable(self) -> list[nn.Parameter]:
        return [p for p in self.parameters() if p.requires_grad]

    def logits(self, texts: Sequence[str], fold: int | None = None) -> torch.Tensor:
        """[K, N, facts, 3]: every fold's logits (K = folds), or one fold's (K = 1)."""
        for layer in self.adapted:
            layer.fold = fold
        k = 1 if fold is not None else self.cfg.folds
        enc = self.tokenizer(list(texts), padding=True, truncation=True, max_length=self.cfg.max_tokens,
                             return_tensors="pt")  # fmt: skip
        enc = {name: t.repeat(k, 1) for name, t in enc.items()}
        hidden = self.encoder(**enc).last_hidden_state
        mask = enc["attention_mask"][..., None].to(hidden.dtype)
        pooled = ((hidden * mask).sum(1) / mask.sum(1).clamp(min=1)).view(k, len(texts), -1)  # [K, N, H]
        w = self.head_weight if fold is None else self.head_weight[fold : fold + 1]
        b = self.head_bias if fold is None else self.head_bias[fold : fold + 1]
        return torch.einsum("knh,kfvh->knfv", pooled, w) + b[:, None]

    @torch.no_grad()
    def log_probs(self, texts: Sequence[str], fold: int | None = None, chunk: int = 1) -> dict[str, np.ndarray]:
        """Per fact, [N, 3]: the folds' probabilities averaged (or one fold's), as logarithms.
        Readings are remembered by text, so a manual read again costs nothing. `chunk` texts are
        read together; one at a time (the default), a text's reading does not depend on which
        texts it was read beside, not even in the last bit of its padding's arithmetic."""
        self.eval()
        texts = list(texts)
        todo = [t for t in dict.fromkeys(texts) if fold is not None or t not in self._memory]
        found: dict[str, np.ndarray] = {}
        for i in range(0, len(todo), chunk):
            part = todo[i : i + chunk]
            probs = self.logits(part, fold).softmax(-1).mean(0)  # [N, facts, 3]
            for text, p in zip(part, probs.log().double().numpy(), strict=True):
                found[text] = p
        if fold is None:
            self._memory.update(found)
            found = self._memory
        rows = np.stack([found[t] for t in texts]) if texts else np.zeros((0, len(FACTS), 3))
        return {name: rows[:, j] for j, name in enumerate(FACTS)}

    def save(self, path: str | Path) -> None:
        from safetensors.torch import save_file

        tensors = {name: p.detach().half().contiguous() for name, p in self.named_parameters() if p.requires_grad}
        save_file(tensors, str(path), metadata={"config": json.dumps(asdict(self.cfg))})

    @classmethod
    def load(cls, path: str | Path) -> SentenceReader:
        from safetensors import safe_open

        try:
            with safe_open(str(path), "pt") as f:
                meta = f.metadata() or {}
                tensors = {k: f.get_tensor(k).float() for k in f.keys()}  # noqa: SIM118 - safe_open has no iterator
            reader = cls(SentenceReaderConfig(**json.loads(meta["config"])))
            missing = reader.load_state_dict(tensors, strict=False).missing_keys
            if any(name in missing for name, p in reader.named_parameters() if p.requires_grad):
                raise KeyError(f"missing {missing}")
        except (OSError, KeyError, ValueError, TypeError, RuntimeError) as exc:
            raise LwmError(f"cannot read the sentence reader {path}: {exc}") from None
        return reader.eval()


def _schedule(step: int, cfg: SentenceReaderConfig) -> float:
    """The learning rate's factor: a linear warm-up, then a cosine decay to 0 at the last step."""
    return min(1.0, (step + 1) / cfg.warmup) * 0.5 * (1 + math.cos(math.pi * min(step, cfg.steps) / cfg.steps))


def fit_sentence_reader(
    texts: Sequence[str],
    truth: dict[str, np.ndarray],
    known: dict[str, np.ndarray],
    weights: np.ndarray,
    folds: np.ndarray,
    cfg: SentenceReaderConfig = SentenceReaderConfig(),
    seed: int = 0,
    progress: Callable[[str], None] = print,
) -> tuple[SentenceReader, dict[str, np.ndarray]]:
    """Train every fold's adapters on the descriptions outside it and read the descriptions inside
    it with them. `truth[fact]` [N] value indices, `known[fact]` [N] whether the fact is stated (an
    unstated one is trained towards even odds), `weights` [N] each description's sampling weight,
    `folds` [N] in 0..folds-1.
    Returns the reader and, per fact, the held-out log-probabilities [N, 3]."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    reader = SentenceReader(cfg)
    texts = list(texts)
    held_out = {name: np.zeros((len(texts), 3)) for name in FACTS}
    for k in range(cfg.folds):
        outside = np.flatnonzero(folds != k)
        p = weights[outside] / weights[outside].sum()
        opt = torch.optim.AdamW(reader.trainable(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        decay = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: _schedule(s, cfg))
        reader.train()
        for step in range(cfg.steps):
            idx = rng.choice(outside, size=cfg.batch, p=p)
            logits = reader.logits([texts[i] for i in idx], fold=k)[0]  # [B, facts, 3]
            loss = torch.zeros(())
            for j, name in enumerate(FACTS):
                if name not in truth:  # a fact the caller gives no truth for is not trained
                    continue
                stated = torch.as_tensor(known[name][idx])
                target = F.one_hot(torch.as_tensor(truth[name][idx]), 3).float()
                target[~stated] = 1 / 3
                loss = loss + F.cross_entropy(logits[:, j], target)
            opt.zero_grad()
            loss.backward()
            opt.step()
            decay.step()
            if (step + 1) % 100 == 0:
                done = f"step {step + 1}/{cfg.steps}"
                progress(f"sentence reader fold {k + 1}/{cfg.folds}: {done}, loss {loss.item():.3f}")
        inside = np.flatnonzero(folds == k)
        read = reader.log_probs([texts[i] for i in inside], fold=k, chunk=64)
        for name in FACTS:
            held_out[name][inside] = read[name]
    return reader.eval(), held_out


__all__ = ["FACTS", "SENTENCE_FILE", "SUBJECTS", "SentenceReader", "SentenceReaderConfig", "fit_sentence_reader"]
