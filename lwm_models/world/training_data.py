"""Token batches from a Messenger-WM dataset split, for training and teacher-forced evaluation.

At load time every observation of the split becomes a 15-token block (a few seconds for the
training split) and every distinct description is encoded once by the frozen text encoder, so a
batch is only slicing and stacking.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np
import torch

from ..data.dataset import TrajectoryDataset
from ..messenger.constants import ALL_TRIPLES, IDENTITIES, MOVEMENTS, ROLES, Triple
from .base import ManualBatch
from .frozen_text import FrozenTextEncoder
from .tokens import BLOCK, DUMMY_ACTION, FIRST_REWARD_LABEL, OBS_TOKENS, obs_to_tokens, reward_label

# (identity id, movement index, role index) of each triple index: the OracleParse input.
TRIPLE_CODES = np.array(
    [(IDENTITIES[i], MOVEMENTS.index(m), ROLES.index(r)) for i, m, r in ALL_TRIPLES], dtype=np.int64
)


def dataset_blocks(ds: TrajectoryDataset) -> np.ndarray:
    """[S, 15] uint8 token blocks of every observation of the split, episode starts carrying the
    dummy action, reward label 2 and done 0."""
    blocks = np.empty((len(ds.observations), BLOCK), dtype=np.uint8)
    blocks[:, 0] = ds.actions
    blocks[:, 1 : 1 + OBS_TOKENS] = obs_to_tokens(np.asarray(ds.observations))
    blocks[:, -2] = reward_label(np.asarray(ds.rewards))
    blocks[:, -1] = ds.dones
    firsts = np.asarray(ds.episode_offsets[:-1])
    blocks[firsts, 0] = DUMMY_ACTION
    blocks[firsts, -2] = FIRST_REWARD_LABEL
    blocks[firsts, -1] = 0
    return blocks


class SplitTokens:
    """A dataset split ready for the world models.

    Args:
        root: dataset directory (from `lwm data generate`).
        split: split name.
        encoder: frozen text encoder; None skips text (Observational, OracleParse).
        router: maps a description to an identity id (GPTHard's parser); None skips routing.
    """

    def __init__(
        self,
        root: str | Path,
        split: str,
        encoder: FrozenTextEncoder | None = None,
        router: Callable[[str], int] | None = None,
    ) -> None:
        self.ds = TrajectoryDataset(root, split)
        self.split = split
        self.blocks = dataset_blocks(self.ds)
        self.offsets = np.asarray(self.ds.episode_offsets)
        self.lengths = np.diff(self.offsets)
        self.manuals = np.asarray(self.ds.manuals, dtype=np.int64)
        self.texts: list[str] = list(self.ds.texts)
        self.parses = np.asarray(self.ds.parses, dtype=np.int64)  # [E, 3] triple indices
        self.parse_codes = TRIPLE_CODES[self.parses]  # [E, 3, 3]
        self.features = self.text_lengths = None
        if encoder is not None:
            feats, lengths = encoder.encode_arrays(self.texts)
            self.features = torch.from_numpy(feats)  # [num_texts, T, F] float16
            self.text_lengths = torch.from_numpy(lengths)
        self.router = router
        self.routed = None if router is None else np.array([router(t) for t in self.texts], dtype=np.int64)
        self.mix_prob = 0.0
        self.mix_ids = np.zeros((len(ALL_TRIPLES), 0), dtype=np.int64)  # [triple, candidate] text ids
        self.mix_counts = np.zeros(len(ALL_TRIPLES), dtype=np.int64)

    def __len__(self) -> int:
        return len(self.lengths)

    def _add_texts(self, texts: list[str], encoder: FrozenTextEncoder | None) -> None:
        self.texts.extend(texts)
        if self.router is not None:
            extra = np.array([self.router(t) for t in texts], dtype=np.int64)
            self.routed = np.concatenate([self.routed, extra])
        if encoder is not None and self.features is not None:
            feats, lengths = encoder.encode_arrays(texts)
            self.features = torch.cat([self.features, torch.from_numpy(feats)])
            self.text_lengths = torch.cat([self.text_lengths, torch.from_numpy(lengths)])

    def mix_manuals(
        self, texts_by_triple: Mapping[Triple, Sequence[str]], prob: float, encoder: FrozenTextEncoder | None
    ) -> None:
        """Training manuals in other words: `sample` and `sample_parts` replace each description,
        with probability `prob`, by one of `texts_by_triple[its triple]` (uniformly). A model that
        only ever sees one style of writing learns that style, not the language (docs/language.md).
        Triples without texts keep their description; evaluation (`full_episodes`) is unchanged."""
        new = sorted({t for texts in texts_by_triple.values() for t in texts} - set(self.texts))
        self._add_texts(new, encoder)
        index = {t: i for i, t in enumerate(self.texts)}
        by_triple = [[index[t] for t in dict.fromkeys(texts_by_triple.get(triple, ()))] for triple in ALL_TRIPLES]
        self.mix_counts = np.array([len(ids) for ids in by_triple], dtype=np.int64)
        self.mix_ids = np.zeros((len(ALL_TRIPLES), max(1, int(self.mix_counts.max()))), dtype=np.int64)
        for k, ids in enumerate(by_triple):
            self.mix_ids[k, : len(ids)] = ids
        self.mix_prob = float(prob)

    def _mixed_text_ids(self, rng: np.random.Generator, episodes: np.ndarray) -> np.ndarray:
        text_ids = self.manuals[episodes].copy()  # [B, 3]
        if self.mix_prob <= 0:
            return text_ids
        triples = self.parses[episodes]
        counts = self.mix_counts[triples]
        pick = (rng.random(text_ids.shape) * np.maximum(counts, 1)).astype(np.int64)
        swap = (rng.random(text_ids.shape) < self.mix_prob) & (counts > 0)
        return np.where(swap, self.mix_ids[triples, pick], text_ids)

    def manual_batch(self, episodes: np.ndarray, text_ids: np.ndarray | None = None) -> ManualBatch:
        """The manuals of `episodes` (their own descriptions, or `text_ids` [B, 3] in their place)."""
        text_ids = self.manuals[episodes] if text_ids is None else text_ids  # [B, 3]
        features = mask = routed = None
        if self.features is not None:
            idx = torch.from_numpy(text_ids)
            features = self.features[idx].float()  # [B, 3, T, F]
            mask = torch.arange(features.shape[2])[None, None, :] < self.text_lengths[idx][..., None]
        if self.routed is not None:
            routed = torch.from_numpy(self.routed[text_ids])
        return ManualBatch(features, mask, torch.from_numpy(self.parse_codes[episodes]), routed)

    def segments(self, episodes: np.ndarray, starts: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        """Tokens [B, 15 * max_blocks] of the segments episode[start:] (padded with 0) and their
        lengths in blocks."""
        lengths = self.lengths[episodes] - starts
        width = int(lengths.max())
        out = np.zeros((len(episodes), width, BLOCK), dtype=np.int64)
        for i, (e, s, n) in enumerate(zip(episodes, starts, lengths)):
            lo = self.offsets[e] + s
            out[i, :n] = self.blocks[lo : lo + n]
        return torch.from_numpy(out.reshape(len(episodes), width * BLOCK)), torch.from_numpy(lengths)

    def _draw(self, rng: np.random.Generator, batch: int) -> tuple[np.ndarray, np.ndarray]:
        """Random episodes and a random start in each (leaving at least one block to predict)."""
        episodes = rng.integers(len(self), size=batch)
        starts = (rng.random(batch) * (self.lengths[episodes] - 1)).astype(np.int64)
        return episodes, starts

    def sample(self, rng: np.random.Generator, batch: int) -> tuple[torch.Tensor, torch.Tensor, ManualBatch]:
        """Segments that start at a random step of random episodes: the paper's training batches."""
        episodes, starts = self._draw(rng, batch)
        tokens, lengths = self.segments(episodes, starts)
        return tokens, lengths, self.manual_batch(episodes, self._mixed_text_ids(rng, episodes))

    def sample_parts(self, rng: np.random.Generator, batch: int, parts: int, own_manuals: bool = False) -> list[tuple]:
        """The segments `sample` draws (the same random numbers), sorted by length and split into
        `parts` groups, each padded only to its own longest segment. Segments run from a random
        step to the episode's end, so one batch padded to its longest is about two thirds padding
        (measured on the training split: 36% of the padded blocks are real; 75% in 4 parts).
        Each part is (tokens, lengths, manual), and with `own_manuals` also the episodes' own
        manuals (their dataset descriptions, where `manual` may hold mixed-in ones)."""
        episodes, starts = self._draw(rng, batch)
        text_ids = self._mixed_text_ids(rng, episodes)
        order = np.argsort(self.lengths[episodes] - starts, kind="stable")
        out = []
        for part in np.array_split(order, min(parts, batch)):
            tokens, lengths = self.segments(episodes[part], starts[part])
            part_ = (tokens, lengths, self.manual_batch(episodes[part], text_ids[part]))
            out.append((*part_, self.manual_batch(episodes[part])) if own_manuals else part_)
        return out

    def evaluated_episodes(self, limit: int | None = None) -> np.ndarray:
        """The episodes an evaluation limited to `limit` episodes reads: evenly spaced over the split."""
        episodes = np.arange(len(self))
        if limit is not None and limit < len(episodes):
            episodes = np.linspace(0, len(episodes) - 1, limit).round().astype(np.int64)
        return episodes

    def full_episodes(
        self, batch: int, limit: int | None = None
    ) -> Iterator[tuple[torch.Tensor, torch.Tensor, ManualBatch]]:
        """Whole episodes, for evaluation, in batches of similar length (each batch is padded to
        its longest episode); `limit` keeps an evenly spaced subset (`evaluated_episodes`)."""
        episodes = self.evaluated_episodes(limit)
        episodes = episodes[np.argsort(self.lengths[episodes], kind="stable")]
        for lo in range(0, len(episodes), batch):
            chunk = episodes[lo : lo + batch]
            tokens, lengths = self.segments(chunk, np.zeros(len(chunk), dtype=np.int64))
            yield tokens, lengths, self.manual_batch(chunk)


def redraw_manuals(data: SplitTokens, pools, encoder: FrozenTextEncoder | None, seed: int = 0) -> None:
    """Replace every episode's manual by descriptions drawn from `pools` (e.g. human-written
    files) for the same triples in the same order, then encode them."""
    rng = np.random.default_rng([seed, 0x524544])
    texts: dict[str, int] = {}
    manuals = np.zeros_like(data.manuals)
    for e, parse in enumerate(np.asarray(data.ds.parses)):
        triples = [ALL_TRIPLES[int(i)] for i in parse]
        for k, text in enumerate(pools.draw(data.split, triples, rng)):
            manuals[e, k] = texts.setdefault(text, len(texts))
    data.manuals = manuals
    data.texts = list(texts)
    if data.router is not None:
        data.routed = np.array([data.router(t) for t in data.texts], dtype=np.int64)
    if encoder is not None:
        feats, lengths = encoder.encode_arrays(data.texts)
        data.features = torch.from_numpy(feats)
        data.text_lengths = torch.from_numpy(lengths)
