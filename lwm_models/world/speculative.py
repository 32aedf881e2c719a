"""Speculative imagination: one decoder call drafts and checks a whole step, and every token is still
sampled exactly as the reference path samples it.

A step of imagination samples 14 tokens (12 observation tokens, reward, done), and the reference
path (imagine.Rows) makes one decoder call per token. Most of a Messenger step repeats the last
observation: ids stay, immobile entities stay, and the avatar moves as its action says. So each step
starts from a draft of its block (the last observation, the avatar moved by the action, no reward,
not done; `draft_block`) and feeds the draft in one call. The hidden state after a token predicts
the next one, so that call yields the distribution of every token *given that the draft before it
is right*. Tokens are then sampled in order with the row's own uniform numbers, as the reference
path does; while a sampled token equals the draft, the next distribution is already there. At the
first token that differs, the row's later positions are void: the row keeps what it accepted, and
its next call feeds the sampled token and the rest of the draft. A step costs 1 + (tokens that
differ from the draft) calls instead of 14.

Every row has its own cache length (flat_decoder.RowCache), so a row that accepted more does not
wait for one that accepted less: each call feeds each unfinished row from its own place, and a row
that has sampled its whole block leaves the call. The step takes as many calls as its slowest
row, but each call carries only the rows still sampling.

Exactness: each token is drawn from the model's distribution given the true tokens before it, with
the same uniform number, so the tokens are those of the reference path up to floating-point
rounding (a call over several tokens runs matmuls of other shapes). That rounding moved
probabilities by at most ~1e-6 in tests/test_fast_imagination.py; a token can differ only if its
uniform number falls within that distance of a boundary of the cumulative distribution.
"""

from __future__ import annotations

import torch

from ..messenger.constants import ACTION_DELTAS, GRID, NUM_ACTIONS
from .base import WorldModel
from .constraints import StepRules
from .flat_decoder import FlatDecoder, RowCache
from .imagine import Rows
from .tokens import BLOCK, COL_OFFSET, FIRST_REWARD_LABEL, OBS_TOKENS, ROW_OFFSET

STEP_TOKENS = OBS_TOKENS + 2  # tokens sampled per step: 12 observation tokens, reward, done
FED = BLOCK  # stream entries fed per step: the pending done, the action, and tokens 0..12
_DELTAS = torch.tensor(ACTION_DELTAS + ((0, 0),), dtype=torch.long)  # the dummy action stays
_AVATAR = 3 * 3  # the avatar channel's first token (id, row, column) in an observation


def draft_block(last_obs: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
    """A guess of each row's next block [rows, 14]: the last observation tokens [rows, 12] with the
    avatar moved by its action [rows] (a move off the board undone), reward 0, not done. A better
    guess only saves calls; a wrong one costs nothing in exactness."""
    block = torch.empty(len(last_obs), STEP_TOKENS, dtype=torch.long)
    block[:, :OBS_TOKENS] = last_obs
    delta = _DELTAS[actions.long().clamp(0, NUM_ACTIONS)]
    here = last_obs[:, _AVATAR] > 0
    row = (last_obs[:, _AVATAR + 1] - ROW_OFFSET + delta[:, 0]).clamp(0, GRID - 1) + ROW_OFFSET
    col = (last_obs[:, _AVATAR + 2] - COL_OFFSET + delta[:, 1]).clamp(0, GRID - 1) + COL_OFFSET
    block[:, _AVATAR + 1] = torch.where(here, row, last_obs[:, _AVATAR + 1])
    block[:, _AVATAR + 2] = torch.where(here, col, last_obs[:, _AVATAR + 2])
    block[:, OBS_TOKENS] = FIRST_REWARD_LABEL  # the label of reward 0
    block[:, OBS_TOKENS + 1] = 0
    return block


class FastRows(Rows):
    """`Rows` on the flat decoder, drafting `lookahead` tokens per call (13: the whole block,
    speculative; 0: one token per call as the reference path, on the flat decoder only)."""

    def __init__(self, model: WorldModel, first_blocks: int = 0, lookahead: int = FED - 2) -> None:
        super().__init__(model, use_cache=True, first_blocks=first_blocks)
        self.decoder = FlatDecoder.for_model(model)
        self.cache: RowCache = self.decoder.new_cache(0)
        self.lookahead = lookahead
        self.calls = 0  # decoder calls made by steps (for benchmarks)

    def _first_block(self, tokens: torch.Tensor, cond) -> RowCache:
        """The joining rows' cache holding their first block (kept per start as in `Rows`)."""
        n, width = tokens.shape
        joining = self.decoder.new_cache(n)
        key = self._start_key(tokens, cond) if self.max_first_blocks else None
        if key is None:
            self.decoder(tokens, joining, cond.id_table)
            joining.lengths[:] = width
            return joining
        if key not in self.first_blocks:
            one = self.decoder.new_cache(1)
            self.decoder(tokens[:1], one, None if cond.id_table is None else cond.id_table[:1])
            self.first_blocks[key] = (one.k[:, :, :, :width].clone(), one.v[:, :, :, :width].clone())
            if len(self.first_blocks) > self.max_first_blocks:
                self.first_blocks.popitem(last=False)
        self.first_blocks.move_to_end(key)
        k, v = self.first_blocks[key]
        joining.k[:, :, :, :width] = k
        joining.v[:, :, :, :width] = v
        joining.lengths[:] = width
        return joining

    @torch.inference_mode()
    def step(self, actions: torch.Tensor) -> tuple:
        """As `Rows.step`: every row takes its action; returns the sampled blocks [rows, 14] and
        each token's probability (numpy)."""
        b = len(self)
        everyone = torch.arange(b)
        uniforms = self.uniforms[everyone, self.t]  # [rows, 14]
        self.t = self.t + 1
        rules = StepRules(self.last_obs, actions, self.t >= self.limit) if bool(self.constrained.any()) else None
        block = draft_block(self.last_obs, actions)  # sampled tokens where known, the draft after
        probs = torch.zeros(b, STEP_TOKENS)
        # The step's stream: pending done, action, tokens 0..12; fed[i] of it are in row i's cache.
        stream = torch.cat([self.pending[:, None], actions[:, None], block[:, : FED - 2]], 1)
        fed = torch.zeros(b, dtype=torch.long)
        known = torch.zeros(b, dtype=torch.long)  # tokens of the block sampled so far
        rows = everyone
        while len(rows):
            c = fed[rows]
            # Row i feeds the stream from c: one token (two at the start) plus the draft ahead.
            count = torch.minimum(FED - c, torch.where(c == 0, 2, 1) + self.lookahead)
            n = int(count.max())
            ahead = torch.arange(n)
            at = (c[:, None] + ahead).clamp_(max=FED - 1)
            tokens = stream[rows[:, None], at].masked_fill_(ahead >= count[:, None], 0)  # padding: 0
            table = None if self.cond.id_table is None else self.cond.id_table[rows]
            h = self.decoder(tokens, self.cache, table, None if len(rows) == b else rows)
            self.calls += 1
            # Token m is predicted by the hidden state of stream entry m + 1.
            first = int(known[rows].min())
            m = torch.arange(first, STEP_TOKENS)
            q = (m[None, :] + 1 - c[:, None]).clamp(0, n - 1)
            grid = h.gather(1, q[:, :, None].expand(-1, -1, h.shape[-1]))  # [A, 14 - first, H]
            tok, p = self._sample_all(grid, first, rows, uniforms[rows], block, rules)
            # Each row's first token that differs from the draft (or its last predicted one) ends
            # what this call decided for it.
            last = c + count - 2
            stop = (m[None, :] >= known[rows, None]) & ((tok != block[rows, first:]) | (m[None, :] >= last[:, None]))
            end = first + stop.int().argmax(1)  # the first True
            take = (m[None, :] >= known[rows, None]) & (m[None, :] <= end[:, None])
            block[rows, first:] = torch.where(take, tok, block[rows, first:])
            probs[rows, first:] = torch.where(take, p, probs[rows, first:])
            stream[rows, 2:] = block[rows, : FED - 2]
            now = torch.clamp(end + 2, max=FED)  # entries valid: up to the one holding token `end`
            self.cache.lengths[rows] += now - c
            fed[rows] = now
            known[rows] = end + 1
            rows = rows[end + 1 < STEP_TOKENS]
        self.pending = block[:, -1]
        self.last_obs = block[:, :OBS_TOKENS].clone()
        return block.numpy(), probs.numpy()

    def _sample_all(
        self,
        grid: torch.Tensor,
        first: int,
        rows: torch.Tensor,
        uniforms: torch.Tensor,
        block: torch.Tensor,
        rules: StepRules | None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Tokens first..13 of rows `rows` sampled from the hidden states [A, 14 - first, H] that
        predict them, as `Rows._sample` samples each (inverse CDF with the row's uniform number,
        restricted to the allowed tokens if constrained), each as if the tokens before it are
        `block`'s; with the model's unrestricted probability of each."""
        temperature = self.temperature[rows][:, None]
        parts = []
        obs = max(0, OBS_TOKENS - first)
        if obs:
            parts.append((self.model.obs_head, grid[:, :obs], first))
        for k, head_ in ((OBS_TOKENS, self.model.reward_head), (OBS_TOKENS + 1, self.model.done_head)):
            if k >= first:
                parts.append((head_, grid[:, k - first : k - first + 1], k))
        tokens, probs = [], []
        for head_, hs, k0 in parts:
            logits = head_(hs).float() / temperature[:, :, None]  # [A, slots, vocab]
            p_all = torch.softmax(logits, dim=-1)
            draw = p_all
            allowed = None
            if rules is not None:
                allowed = torch.stack(
                    [rules.allowed(k, [block[:, i] for i in range(k)])[rows] for k in range(k0, k0 + hs.shape[1])], 1
                ) | ~self.constrained[rows][:, None, None]
                draw = torch.softmax(logits.masked_fill(~allowed, -torch.inf), dim=-1)
            u = uniforms[:, k0 : k0 + hs.shape[1]]
            token = (draw.cumsum(-1) < u[:, :, None]).sum(-1).clamp_(max=draw.shape[-1] - 1)
            if allowed is not None:
                token = _allowed_at_or_before(allowed, token)
            tokens.append(token)
            probs.append(p_all.gather(2, token[:, :, None]).squeeze(2))
        return torch.cat(tokens, 1), torch.cat(probs, 1)


def _allowed_at_or_before(allowed: torch.Tensor, token: torch.Tensor) -> torch.Tensor:
    """imagine._allowed_at_or_before over [..., vocab] masks: each token if allowed, else the
    nearest allowed token below it, else the first allowed."""
    vocab = torch.arange(allowed.shape[-1])
    below = allowed & (vocab <= token[..., None])
    last_below = torch.where(below, vocab, -1).amax(-1)
    return torch.where(last_below >= 0, last_below, allowed.float().argmax(-1))

__all__ = ["FastRows", "draft_block"]
