"""What every world-model family shares: its config, token embeddings, the causal decoder, the
output heads and the training loss. A family declares what it reads of a manual (`reads_text`,
`needs_parse`, `read_manual`) and decides how the manual conditions the decoder (`condition`):

- an `id_table` [B, 17, H] whose row i is added to the embedding of every entity-channel id token
  equal to i (EMMA-LWM, OracleParse, GPTHard; Observational has none), and/or
- a `memory` [B, M, H] of description tokens that every block cross-attends to (Standard).

Because the additions depend only on the token's value, the table is computed once per manual and
gathered at each id token, in training and in imagination alike.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..messenger.constants import NUM_IDS, Triple
from .description_encoder import TextConfig
from .frozen_text import FrozenTextEncoder
from .gpt import Block, DecoderConfig, KVCache, head, init_weights
from .manual import ManualBatch, ManualError, text_manual
from .tokens import (
    ACTION_VOCAB,
    BLOCK,
    DONE_VOCAB,
    FIRST_REWARD_LABEL,
    ID_SLOTS,
    MAX_BLOCKS,
    OBS_VOCAB,
    REWARD_VOCAB,
    SLOT_DONE,
    SLOT_KIND,
    SLOT_OBS,
    SLOT_REWARD,
)

# One embedding matrix holds the four slot kinds' tables in disjoint row ranges, which is the same
# as four separate tables and embeds a whole sequence with one lookup.
_SLOT_OFFSET = np.array([0, ACTION_VOCAB, ACTION_VOCAB + OBS_VOCAB, ACTION_VOCAB + OBS_VOCAB + REWARD_VOCAB])
_EMBED_ROWS = ACTION_VOCAB + OBS_VOCAB + REWARD_VOCAB + DONE_VOCAB
MAX_LEN = MAX_BLOCKS * BLOCK
# Which of n new tokens starting at block offset o are entity id tokens: looked up at every
# imagination step, so precomputed for the short calls.
_ID_COLUMNS = {
    (o, n): torch.as_tensor(np.flatnonzero(np.isin((o + np.arange(n)) % BLOCK, ID_SLOTS)))
    for o in range(BLOCK)
    for n in range(1, BLOCK + 1)
}


@dataclass
class WorldModelConfig:
    """The sizes of a world model, whatever its kind.

    decoder: the causal decoder over the token sequence (shared by every kind).
    text: the trainable description encoder (used by the kinds that read text).
    """

    decoder: DecoderConfig = field(default_factory=DecoderConfig)
    text: TextConfig = field(default_factory=TextConfig)


@dataclass
class Conditioning:
    id_table: torch.Tensor | None = None  # [B, 17, H]
    memory: torch.Tensor | None = None  # [B, M, H]
    memory_mask: torch.Tensor | None = None  # [B, M] True at real tokens
    # Several readings of each manual (a hedged EMMA-LWM's `condition_on`): row r of id_table is a
    # reading of manual `reading_owner[r]` with prior log-probability `reading_log_prior[r]`, rows of
    # one manual together and likeliest first. `rows_for` gives each trajectory one of them.
    reading_owner: torch.Tensor | None = None  # [R]
    reading_log_prior: torch.Tensor | None = None  # [R]

    def index(self, idx: torch.Tensor) -> Conditioning:
        return Conditioning(*(None if t is None else t[idx] for t in (self.id_table, self.memory, self.memory_mask)))

    def rows_for(self, n: int) -> Conditioning:
        """n rows, one reading each, drawn from the readings' prior without a random stream: n
        trajectories of one manual spread over its readings in proportion (stratified: trajectory i
        takes the reading at prior quantile (i + 0.5) / n, so a lone trajectory imagines the likeliest
        reading); one manual per trajectory takes the quantile 0.5 + 0.618 i (mod 1), a low-discrepancy
        sequence, so that a batch of episodes samples each one's prior."""
        if self.reading_owner is None:
            return self
        owner = self.reading_owner
        manuals = int(owner.max()) + 1
        if manuals not in (1, n):
            raise ValueError(f"manual batch must be 1 or {n}, got {manuals}")
        steps = torch.arange(n, dtype=torch.float64)
        quantiles = (steps + 0.5) / n if manuals == 1 else torch.remainder(0.5 + 0.6180339887498949 * steps, 1.0)
        first = torch.searchsorted(owner, torch.arange(manuals))  # a manual's rows are together
        cdfs = [torch.cumsum(torch.softmax(self.reading_log_prior[owner == m].double(), 0), 0) for m in range(manuals)]
        picked = []
        for i in range(n):
            m = 0 if manuals == 1 else i
            k = min(int(torch.searchsorted(cdfs[m], quantiles[i : i + 1])), len(cdfs[m]) - 1)
            picked.append(int(first[m]) + k)
        return self.index(torch.tensor(picked, dtype=torch.long))

    @staticmethod
    def cat(parts: Sequence[Conditioning]) -> Conditioning:
        """The conditionings of several batches as one (memories padded to the longest)."""
        id_table = None if parts[0].id_table is None else torch.cat([p.id_table for p in parts])
        if parts[0].memory is None:
            return Conditioning(id_table)
        m = max(p.memory.shape[1] for p in parts)
        memory = torch.cat([F.pad(p.memory, (0, 0, 0, m - p.memory.shape[1])) for p in parts])
        mask = torch.cat([F.pad(p.memory_mask, (0, m - p.memory_mask.shape[1]), value=False) for p in parts])
        return Conditioning(id_table, memory, mask)


@dataclass
class LossOutput:
    loss: torch.Tensor  # total = obs + reward + done (means over their valid tokens)
    obs: torch.Tensor
    reward: torch.Tensor
    done: torch.Tensor
    sums: dict[str, torch.Tensor]  # summed cross-entropy per kind, for exact dataset averages
    counts: dict[str, torch.Tensor]


def _targets_layout(length: int) -> dict[int, np.ndarray]:
    """Positions (into a sequence of `length` tokens) whose *next* token each head predicts; the
    first block is context only."""
    nxt = np.arange(BLOCK, length)
    kind = SLOT_KIND[nxt % BLOCK]
    return {k: nxt[kind == k] - 1 for k in (SLOT_OBS, SLOT_REWARD, SLOT_DONE)}


def event_steps(tokens: torch.Tensor) -> torch.Tensor:
    """Which blocks of token sequences [B, L] are steps where something happens [B, L / 15]: a
    reward other than 0, or the end. A contact's outcome follows from the role the manual gives the
    entity, and such steps are about one in fifteen, so the mean loss weighs them little."""
    blocks = tokens.view(len(tokens), -1, BLOCK)
    return (blocks[:, :, BLOCK - 2] != FIRST_REWARD_LABEL) | (blocks[:, :, BLOCK - 1] == 1)


def target_blocks(length: int) -> dict[str, torch.Tensor]:
    """The block of each target token of `WorldModel.predictions` on sequences of `length` tokens."""
    layout = _targets_layout(length)
    kinds = {"obs": SLOT_OBS, "reward": SLOT_REWARD, "done": SLOT_DONE}
    return {name: torch.as_tensor((layout[kind] + 1) // BLOCK) for name, kind in kinds.items()}


class WorldModel(nn.Module):
    """Base class: subclasses set `kind` (and `reads_text`, `needs_parse` if they do) and implement
    `condition(manual)`."""

    kind: ClassVar[str] = "base"
    reads_text: ClassVar[bool] = False  # conditions on the frozen text encoder's description vectors
    needs_parse: ClassVar[bool] = False  # conditions on the true parse, which a person's manual lacks
    # description -> identity id, for a kind that routes descriptions to entities (GPTHard)
    route: ClassVar[Callable[[str], int] | None] = None

    def __init__(self, config: WorldModelConfig, decoder: DecoderConfig | None = None) -> None:
        """`decoder` replaces config.decoder where a kind needs a variant of it (Standard)."""
        super().__init__()
        self.config = config
        decoder = decoder or config.decoder
        self.decoder_config = decoder
        h = decoder.hidden
        self.tok_emb = nn.Embedding(_EMBED_ROWS, h)
        self.pos_emb = nn.Embedding(MAX_LEN, h)
        self.drop = nn.Dropout(decoder.dropout)
        self.blocks = nn.ModuleList(Block(decoder) for _ in range(decoder.layers))
        self.ln_f = nn.LayerNorm(h)
        self.obs_head = head(h, OBS_VOCAB)
        self.reward_head = head(h, REWARD_VOCAB)
        self.done_head = head(h, DONE_VOCAB)
        self.register_buffer("_slot_offset", torch.as_tensor(_SLOT_OFFSET[SLOT_KIND]), persistent=False)

    def _init(self) -> None:
        self.apply(init_weights)

    # ------------------------------------------------------------------ the manual
    def frozen_text_encoder(self) -> FrozenTextEncoder | None:
        """The frozen encoder this model's manuals go through (keeping its `max_tokens`), or None
        if it reads no text."""
        return FrozenTextEncoder(max_tokens=self.config.text.max_tokens) if self.reads_text else None

    def read_manual(
        self, descriptions: Sequence[str], encoder: FrozenTextEncoder | None, parse: Sequence[Triple] | None = None
    ) -> ManualBatch:
        """A batch-of-one ManualBatch of a manual, in the form this model reads (the true `parse`,
        (identity, movement, role) per description, only where a kind needs it). The encoder keeps
        as many tokens per description as this model was trained with."""
        if self.reads_text and encoder is None:
            raise ManualError(f"a {self.kind} model reads text: it needs a text encoder")
        if not self.reads_text:
            return text_manual(descriptions, None)
        return text_manual(descriptions, encoder.keeping(self.config.text.max_tokens))

    def condition(self, manual: ManualBatch) -> Conditioning:
        raise NotImplementedError

    def on_board(self, manual: ManualBatch, board: torch.Tensor) -> ManualBatch:
        """The manual as this model reads it on a board (`board` [B, K]: the identity ids of each
        manual's entities, 0 for none). Most models read a manual the same on any board; a hedged
        one may ground its words' entities on it (world/hedged_reading.py, `ground_words`)."""
        return manual

    @torch.inference_mode()
    def condition_on(self, manual: ManualBatch) -> Conditioning:
        """`condition` for imagination (no autograd; once per manual, not per step)."""
        self.eval()
        return self.condition(manual)

    def obs_embedding(self, ids: torch.Tensor) -> torch.Tensor:
        """Embedding of observation tokens (used by EMMA to query the manual with id tokens)."""
        return self.tok_emb(ids + ACTION_VOCAB)

    # ------------------------------------------------------------------ decoder
    def embed(self, tokens: torch.Tensor, positions: torch.Tensor, cond: Conditioning) -> torch.Tensor:
        """Token + position embeddings of tokens [B, n] at absolute `positions` ([n], or [B, n] for
        sequences of different lengths; those are at the same place within a block)."""
        n = tokens.shape[1]
        x = self.tok_emb(tokens + self._slot_offset[positions % BLOCK])
        if cond.id_table is not None:
            first = int(positions.reshape(-1, n)[0, 0])
            cols = (
                _ID_COLUMNS[(first % BLOCK, n)]
                if n <= BLOCK
                else torch.as_tensor(np.flatnonzero(np.isin(np.arange(first, first + n) % BLOCK, ID_SLOTS)))
            )
            if len(cols):
                ids = tokens[:, cols].clamp(0, NUM_IDS - 1)
                add = torch.gather(cond.id_table, 1, ids.unsqueeze(-1).expand(-1, -1, x.shape[-1]))
                x[:, cols] = x[:, cols] + add * (ids > 0).unsqueeze(-1).to(add.dtype)
        return self.drop(x + self.pos_emb(positions))

    def hidden_states(self, tokens: torch.Tensor, cond: Conditioning, cache: KVCache | None = None) -> torch.Tensor:
        """Final hidden states [B, n, H] of tokens [B, n]: the whole sequence from position 0, or,
        with a cache, n more tokens of each cached sequence."""
        n = tokens.shape[1]
        positions = torch.arange(n, device=tokens.device) if cache is None else cache.begin(n)
        x = self.embed(tokens, positions, cond)
        memory_kv = self._memory_kv(cond, cache)
        for i, block in enumerate(self.blocks):
            x = block(x, cache, i, memory_kv[i] if memory_kv else None, cond.memory_mask)
        if cache is not None:
            cache.advance(n)
        return self.ln_f(x)

    def _memory_kv(self, cond: Conditioning, cache: KVCache | None):
        if cond.memory is None:
            return None
        if cache is not None and cache.memory_kv is not None:
            return cache.memory_kv
        kv = [block.cross.memory_kv(cond.memory) for block in self.blocks]
        if cache is not None:
            cache.memory_kv = kv
        return kv

    def new_cache(self, batch: int, max_len: int = MAX_LEN) -> KVCache:
        p = next(self.parameters())
        cfg = self.decoder_config
        return KVCache(cfg.layers, batch, cfg.num_kv_heads, cfg.hidden // cfg.heads, max_len, p.dtype, p.device)

    def next_token_logits(self, h: torch.Tensor, next_position: int) -> torch.Tensor:
        """Logits for the token at absolute `next_position`, from the hidden state before it."""
        kind = SLOT_KIND[next_position % BLOCK]
        if kind == SLOT_OBS:
            return self.obs_head(h)
        if kind == SLOT_REWARD:
            return self.reward_head(h)
        if kind == SLOT_DONE:
            return self.done_head(h)
        raise ValueError(f"position {next_position} holds an action: the model does not predict it")

    # ------------------------------------------------------------------ training
    def predictions(
        self, tokens: torch.Tensor, lengths: torch.Tensor, manual: ManualBatch
    ) -> dict[str, tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        """Teacher-forced predictions of each kind of token ("obs", "reward", "done"): the logits
        [B, P, V] (float32), the true next tokens [B, P] and which of them are real [B, P] (the first
        block is context only; padding past `lengths` blocks is not)."""
        return self.predictions_given(tokens, lengths, self.condition(manual))

    def predictions_given(
        self, tokens: torch.Tensor, lengths: torch.Tensor, cond: Conditioning
    ) -> dict[str, tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        """`predictions` under a conditioning already computed (one row per sequence)."""
        n = tokens.shape[1]
        if n % BLOCK or n > MAX_LEN:
            raise ValueError(f"sequence length {n} must be a multiple of {BLOCK} and at most {MAX_LEN}")
        h = self.hidden_states(tokens, cond)
        layout = _targets_layout(n)
        valid_tokens = lengths.to(tokens.device)[:, None] * BLOCK  # target positions < this are real
        out = {}
        for name, kind, head_ in (
            ("obs", SLOT_OBS, self.obs_head),
            ("reward", SLOT_REWARD, self.reward_head),
            ("done", SLOT_DONE, self.done_head),
        ):
            pos = torch.as_tensor(layout[kind], device=tokens.device)
            out[name] = (head_(h[:, pos]).float(), tokens[:, pos + 1], (pos + 1)[None, :] < valid_tokens)
        return out

    def forward(self, tokens: torch.Tensor, lengths: torch.Tensor, manual: ManualBatch) -> LossOutput:
        """Teacher-forced losses on a batch of token sequences.

        tokens: [B, L] blocks of 15 tokens, right-padded; lengths: [B] valid blocks per sequence.
        Returns the mean cross-entropy of observation, reward and done tokens (first block is
        context only, padding masked) and their total.
        """
        return losses(self.predictions(tokens, lengths, manual))


def losses(predictions: dict[str, tuple[torch.Tensor, torch.Tensor, torch.Tensor]]) -> LossOutput:
    """The cross-entropy of `WorldModel.predictions`: means over the real targets of each kind, and
    their total."""
    sums, counts, means = {}, {}, {}
    for name, (logits, target, mask) in predictions.items():
        ce = F.cross_entropy(logits.transpose(1, 2), target, reduction="none")
        sums[name] = (ce * mask).sum()
        counts[name] = mask.sum()
        means[name] = sums[name] / counts[name].clamp(min=1)
    total = means["obs"] + means["reward"] + means["done"]
    return LossOutput(total, means["obs"], means["reward"], means["done"], sums, counts)
