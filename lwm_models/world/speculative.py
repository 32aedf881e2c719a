"""Speculative imagination: one decoder call drafts and checks a whole step, and every token is still
sampled exactly as the reference path samples it.

A step of imagination samples 14 tokens (12 observation tokens, reward, done), and the reference
path (imagine.DecoderBatch) makes one decoder call per token. Most of a Messenger step repeats the last
observation: ids stay, immobile entities stay, and the avatar moves as its action says. So each step
starts from a draft of its block (the last observation, the avatar moved by the action, no reward,
not done; `draft_block`) and feeds the draft in one call. The hidden state after a token predicts
the next one, so that call yields the distribution of every token *given that the draft before it
is right*. Tokens are then sampled in order with the row's own uniform numbers, as the reference
path does; while a sampled token equals the draft, the next distribution is already there. At the
first token that differs, the row's later distributions are void: the row keeps what it accepted,
and its next call feeds the sampled token and, as the rest of its draft, the tokens this call
sampled at the later positions (from a prefix with one wrong token, with the same uniform numbers).
Those are usually what the next call samples again (one entity's move seldom changes what the
model says of the others), so a step costs one call plus one per call that met a wrong token, not
one per token that differs from the last observation (a fixed-point iteration on fixed random
numbers; docs/speed.md has the calls per step).

Every row has its own cache length (flat_decoder.RowCache), so a row that accepted more does not
wait for one that accepted less: each call feeds each unfinished row from its own place, and a row
that has sampled its whole block leaves the call. The step takes as many calls as its slowest
row, but each call carries only the rows still sampling.

Exactness: each token is drawn from the model's distribution given the true tokens before it, with
the same uniform number, so the tokens are those of the reference path up to floating-point
rounding (a call over several tokens runs matmuls of other shapes, and the output heads run
stacked per slot, `_SlotHeads`). That rounding moved
probabilities by at most 4.8e-6 over 8 NewAll games at 1, 16 and 64 rows (docs/speed.md); a token
can differ only if its uniform number falls within that distance of a boundary of the cumulative
distribution.
"""

from __future__ import annotations

import torch
from torch import nn

from ..messenger.constants import ACTION_DELTAS, GRID, NUM_ACTIONS
from .base import WorldModel
from .constraints import StepRules
from .flat_decoder import FlatDecoder, RowCache, _Step, per_weights, scripted
from .imagine import DecoderBatch, allowed_at_or_before
from .lanes import Lanes, lanes
from .tokens import BLOCK, COL_OFFSET, FIRST_REWARD_LABEL, OBS_TOKENS, OBS_VOCAB, ROW_OFFSET

STEP_TOKENS = OBS_TOKENS + 2  # tokens sampled per step: 12 observation tokens, reward, done
FED = BLOCK  # stream entries fed per step: the pending done, the action, and tokens 0..12
_DELTAS = torch.tensor(ACTION_DELTAS + ((0, 0),), dtype=torch.long)  # the dummy action stays
MIN_GROUP = 4  # rows per group at least when a step's rows are cut into groups (`_groups`)
DRIFT = 0  # steps a row may run ahead of the slowest in its group (`_Speculator.run_steps`; docs/speed.md)


def draft_block(
    last_obs: torch.Tensor, actions: torch.Tensor, last_done: torch.Tensor, last_reward: torch.Tensor
) -> torch.Tensor:
    """A guess of each row's next block [rows, 14]: the last observation tokens [rows, 12] with the
    avatar moved by its action [rows] (a move off the board undone); no reward and not done, or,
    after a done (a trajectory imagined past its end), the last reward and done again. A better
    guess only saves calls; a wrong one costs nothing in exactness."""
    return _draft(last_obs, actions, last_done, last_reward, _DELTAS, *_DRAFT_CONSTANTS)


_DRAFT_CONSTANTS = (NUM_ACTIONS, GRID, ROW_OFFSET, COL_OFFSET, FIRST_REWARD_LABEL)


def _draft(
    last_obs: torch.Tensor,
    actions: torch.Tensor,
    last_done: torch.Tensor,
    last_reward: torch.Tensor,
    deltas: torch.Tensor,
    num_actions: int,
    grid: int,
    row_offset: int,
    col_offset: int,
    no_reward: int,
) -> torch.Tensor:
    """`draft_block`, with the game's constants as arguments: TorchScript reads no module constants,
    and the scripted multi-step run (`_Speculator.run_steps`) drafts with it too."""
    block = torch.empty(last_obs.shape[0], 14, dtype=torch.long)
    block[:, :12] = last_obs
    delta = deltas[actions.long().clamp(0, num_actions)]
    avatar = 9  # the avatar channel's first token (id, row, column) in an observation
    here = last_obs[:, avatar] > 0
    row = (last_obs[:, avatar + 1] - row_offset + delta[:, 0]).clamp(0, grid - 1) + row_offset
    col = (last_obs[:, avatar + 2] - col_offset + delta[:, 1]).clamp(0, grid - 1) + col_offset
    block[:, avatar + 1] = torch.where(here, row, last_obs[:, avatar + 1])
    block[:, avatar + 2] = torch.where(here, col, last_obs[:, avatar + 2])
    ended = last_done == 1
    block[:, 12] = torch.where(ended, last_reward, torch.full_like(last_reward, no_reward))  # label 2: reward 0
    block[:, 13] = last_done
    return block


class FlatDecoderBatch(DecoderBatch):
    """`DecoderBatch` on the flat decoder, drafting `lookahead` tokens per call (-1: by the rows in the
    call and its place in the step, `_lookahead`; 0: one token per call as the reference path, on the
    flat decoder only)."""

    def __init__(self, model: WorldModel, first_blocks: int = 0, lookahead: int = -1) -> None:
        super().__init__(model, use_cache=True, first_blocks=first_blocks)
        self.decoder = FlatDecoder.for_model(model)
        self.speculator = per_weights(model, "speculator", _Speculator.scripted)
        self.cache: RowCache = self.decoder.new_cache(0)
        self.lookahead = lookahead
        self.last_reward = torch.zeros(0, dtype=torch.long)  # each row's last reward label (for drafts)
        self.calls = 0  # decoder calls made by steps (for benchmarks)

    def _first_block(self, tokens: torch.Tensor, cond) -> RowCache:
        """The joining rows' cache holding their first block (kept per start as in `DecoderBatch`)."""
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
        """As `DecoderBatch.step`: every row takes its action; returns the sampled blocks [rows, 14] and
        each token's probability (numpy)."""
        if not bool(self.constrained.any()):
            blocks, probs, _ = self.run_steps(actions[:, None], stop_on_done=False)
            return blocks[:, 0], probs[:, 0]
        # Under the game's rules, which are Python: what they allow is computed before each call.
        b = len(self)
        state = self._start(actions, self.uniforms[torch.arange(b), self.t])
        _, _, _, block, probs, *_ = state
        self.t = self.t + 1
        rules = StepRules(self.last_obs, actions, self.t >= self.limit)
        rows, calls = torch.arange(b), 0
        while len(rows):
            allowed = self._allowed(rules, block, rows)
            rows = self.speculator(*state, rows, *self._conditioning(), *self._lookahead(len(rows)), allowed)
            calls += 1
        self.calls += calls
        self._ended(block)
        return block.numpy(), probs.numpy()

    @torch.inference_mode()
    def run_steps(self, actions: torch.Tensor, stop_on_done: bool) -> tuple:
        """Every row takes all its actions [rows, S] (none constrained), in scripted calls, one
        chain per group of rows (lanes.py; `_Speculator.run_steps`), until the last action or, with
        `stop_on_done`, a done; returns the blocks [rows, S, 14], their tokens' probabilities and the
        steps each row took [rows] (numpy). What `step` samples, a step at a time, for the same rows
        (tests/test_fast_imagination.py)."""
        if bool(self.constrained.any()):
            raise ValueError("run_steps samples without the game's rules; step constrained rows one at a time")
        b, steps = actions.shape
        everyone = torch.arange(b)
        later = self.uniforms[everyone[:, None], self.t[:, None] + torch.arange(steps)]  # [rows, S, 14]
        # The graph drafts every step, the first too, from the block before it: here each row's last.
        last = torch.cat([self.last_obs, self.last_reward[:, None], self.pending[:, None]], 1)
        stream, probs = torch.empty(b, FED, dtype=torch.long), torch.zeros(b, STEP_TOKENS)
        fed, known = torch.zeros(b, dtype=torch.long), torch.zeros(b, dtype=torch.long)
        state = (stream, fed, known, last, probs, self.cache.lengths, torch.empty(b, STEP_TOKENS), self.temperature)
        taken = torch.zeros(b, dtype=torch.long)
        blocks = torch.zeros(b, steps, STEP_TOKENS, dtype=torch.long)
        block_probs = torch.zeros(b, steps, STEP_TOKENS)
        out = (actions.long(), later, taken, blocks, block_probs, stop_on_done, DRIFT)
        available = lanes()
        groups = _groups(b, available)
        if len(groups) == 1:
            threads = torch.get_num_threads()
            self.calls += self.speculator.run_steps(
                everyone, *state, *self._conditioning(), self.lookahead, threads, *out
            )
        else:
            work = [
                (self.speculator.run_steps, (rows, *state, *self._conditioning(), self.lookahead, 1, *out))
                for rows in groups
            ]
            self.calls += max(available.run(work))
        self.t = self.t + taken
        _, _, _, block, *_ = state
        self._ended(block)  # each row's last sampled block (no draft follows a row's last step)
        return blocks.numpy(), block_probs.numpy(), taken.numpy()

    def _start(self, actions: torch.Tensor, uniforms: torch.Tensor) -> tuple:
        """The state of a step every row starts with its action [rows] and uniform numbers [rows, 14]:
        the block (sampled tokens where known, the draft after), their probabilities, the step's
        stream (pending done, action, tokens 0..12) of which `fed` are in each row's cache, and the
        tokens of the block sampled so far (`known`)."""
        b = len(self)
        block = draft_block(self.last_obs, actions, self.pending, self.last_reward)
        stream = torch.cat([self.pending[:, None], actions[:, None], block[:, : FED - 2]], 1)
        fed, known = torch.zeros(b, dtype=torch.long), torch.zeros(b, dtype=torch.long)
        probs = torch.zeros(b, STEP_TOKENS)
        return stream, fed, known, block, probs, self.cache.lengths, uniforms, self.temperature

    def _conditioning(self) -> tuple:
        return self.cond.id_table, self.cache.k, self.cache.v

    def _ended(self, block: torch.Tensor) -> None:
        """Each row's last sampled block [rows, 14]: what its next step is drafted from."""
        self.pending = block[:, -1].clone()
        self.last_reward = block[:, OBS_TOKENS].clone()
        self.last_obs = block[:, :OBS_TOKENS].clone()

    def admit(self, cond, first, max_steps, temperature, gen, constrained=False) -> None:
        super().admit(cond, first, max_steps, temperature, gen, constrained)
        grown = len(self) - len(self.last_reward)
        self.last_reward = torch.cat([self.last_reward, torch.full((grown,), FIRST_REWARD_LABEL)])

    def keep(self, idx: torch.Tensor) -> None:
        super().keep(idx)
        self.last_reward = self.last_reward[idx]

    def _lookahead(self, rows: int) -> tuple[int, int]:
        if self.lookahead < 0:
            return _lookahead(rows, torch.get_num_threads())
        return self.lookahead, self.lookahead

    def _allowed(self, rules: StepRules, block: torch.Tensor, rows: torch.Tensor) -> torch.Tensor:
        """What the rules allow at each of the 14 slots of rows `rows` [A, 14, 37] (reward and done
        in their first columns), given that the tokens before each slot are `block`'s; unconstrained
        rows allow everything."""
        out = torch.zeros(len(rows), STEP_TOKENS, OBS_VOCAB, dtype=torch.bool)
        sampled = [block[:, i] for i in range(STEP_TOKENS)]
        for k in range(STEP_TOKENS):
            mask = rules.allowed(k, sampled[:k])[rows]
            out[:, k, : mask.shape[1]] = mask
        out |= ~self.constrained[rows][:, None, None]
        return out


def _groups(rows: int, available: Lanes | None) -> list[torch.Tensor]:
    """The groups of consecutive rows a step runs at once, one per lane of `available`, each of
    MIN_GROUP rows at least (fewer rows are one group: a call over 2 rows costs about what a call
    over 4 does)."""
    count = 1 if available is None else min(available.count, rows // MIN_GROUP)
    if count <= 1:
        return [torch.arange(rows)]
    return [torch.arange(rows * i // count, rows * (i + 1) // count) for i in range(count)]


def _lookahead(rows: int, threads: int) -> tuple[int, int]:
    """Draft tokens a call feeds per row when `rows` rows take part on `threads` intra-op threads:
    (where a row starts its step, where it goes on). A call over one row costs about the same for 1
    token or 15 (dispatch, not arithmetic), so a lone row feeds its whole draft; over many rows
    every rejected token is arithmetic. A step's first draft (the last observation) is wrong
    somewhere in most rows, so a step's first call feeds a few tokens; a later call's draft is what
    the call before it sampled, mostly right, so up to 16 rows a thread feed the rest of the block.
    Above that a call is arithmetic-bound and feeding 3 throughout was fastest, on 2 threads or on a
    lane's one (benchmarks/imagination.py, docs/speed.md)."""
    if rows <= 4:
        return 13, 13  # the whole draft (FED - 2; TorchScript reads no module constants)
    if rows > 16 * threads:
        return 3, 3
    return 5, 13


class _Speculator(nn.Module):
    """A decoder call with what comes before and after it (`_feed`, `_decide`), and the calls of
    one or more steps of known actions (`run_steps`), as one scripted graph: the per-call
    bookkeeping is ~60 small ops, which cost more than the decoder call itself when dispatched
    from Python."""

    def __init__(self, model: WorldModel) -> None:
        super().__init__()
        self.decoder = _Step(model)
        self.heads = _SlotHeads(model.obs_head, model.reward_head, model.done_head)
        self.deltas = _DELTAS.clone()
        self.num_actions, self.grid, self.row_offset, self.col_offset, self.no_reward = _DRAFT_CONSTANTS

    @staticmethod
    def scripted(model: WorldModel) -> torch.jit.ScriptModule:
        with torch.no_grad():
            return scripted(_Speculator(model).eval())

    def forward(
        self,
        stream: torch.Tensor,
        fed: torch.Tensor,
        known: torch.Tensor,
        block: torch.Tensor,
        probs: torch.Tensor,
        lengths: torch.Tensor,
        uniforms: torch.Tensor,
        temperature: torch.Tensor,
        rows: torch.Tensor,
        id_table: torch.Tensor | None,
        k_cache: torch.Tensor,
        v_cache: torch.Tensor,
        first: int,
        later: int,
        allowed: torch.Tensor | None,
    ) -> torch.Tensor:
        """One call for rows `rows`, feeding `first` draft tokens where a row starts its step and
        `later` where it goes on; updates the step's state in place and returns the rows still
        sampling."""
        tokens, count = _feed(stream, fed, rows, first, later)
        table = None if id_table is None else id_table.index_select(0, rows)
        # A lone row is never padded: its call skips the packing's bookkeeping.
        h = self.decoder(tokens, rows, lengths, table, k_cache, v_cache, count if rows.shape[0] > 1 else None)
        return _decide(
            h, rows, count, fed, known, block, probs, stream, lengths, uniforms, temperature, self.heads, allowed
        )

    @torch.jit.export
    def run_steps(
        self,
        rows: torch.Tensor,
        stream: torch.Tensor,
        fed: torch.Tensor,
        known: torch.Tensor,
        block: torch.Tensor,
        probs: torch.Tensor,
        lengths: torch.Tensor,
        uniforms: torch.Tensor,
        temperature: torch.Tensor,
        id_table: torch.Tensor | None,
        k_cache: torch.Tensor,
        v_cache: torch.Tensor,
        lookahead: int,
        threads: int,
        actions: torch.Tensor,
        later_uniforms: torch.Tensor,
        taken: torch.Tensor,
        blocks: torch.Tensor,
        block_probs: torch.Tensor,
        stop_on_done: bool,
        drift: int,
    ) -> int:
        """Steps, unconstrained, until each of the rows `rows` has taken every action of `actions`
        [rows, S] (or sampled done, with `stop_on_done`); returns the calls it took. The state
        (`stream` to `temperature`, as `FlatDecoderBatch._start` makes it) is filled here: `block`
        holds each row's last sampled block, from which its first step is drafted. A row that has
        sampled its block writes it to `blocks` [rows, S, 14] (and its probabilities to
        `block_probs`) and starts its next step in a later call, drafted from that block, with its
        uniform numbers from `later_uniforms` [rows, S, 14], once no row still running is more
        than `drift` steps behind it. `taken` [rows]: the steps each row has sampled. `lookahead`
        < 0: by the rows in each call (`_lookahead`) on `threads` intra-op threads (a lane has
        one). Groups of rows may run at once on other threads (lanes.py): each writes only its own
        rows of the state and the cache."""
        steps = actions.shape[1]
        calls = 0
        self._begin(rows, taken, actions, block, stream, fed, known, uniforms, later_uniforms)
        waiting = rows[:0]  # rows that have sampled a block and wait to start the next (`drift`)
        while rows.shape[0] > 0:
            first, later = _lookahead(rows.shape[0], threads) if lookahead < 0 else (lookahead, lookahead)
            called = rows
            rows = self.forward(
                stream,
                fed,
                known,
                block,
                probs,
                lengths,
                uniforms,
                temperature,
                rows,
                id_table,
                k_cache,
                v_cache,
                first,
                later,
                None,
            )
            calls += 1
            done = called[known.index_select(0, called) >= 14]
            if done.shape[0] == 0:
                continue
            # The rows that sampled their block: record it; those that go on wait until no row
            # still running is more than `drift` steps behind them.
            s = taken.index_select(0, done)
            last = block.index_select(0, done)
            blocks[done, s] = last
            block_probs[done, s] = probs.index_select(0, done)
            taken.index_copy_(0, done, s + 1)
            going = s + 1 < steps
            if stop_on_done:
                going = going & (last[:, 13] != 1)
            waiting = torch.cat([waiting, done[going]])
            if waiting.shape[0] == 0:
                continue
            slowest = taken.index_select(0, torch.cat([rows, waiting])).min()
            ready = taken.index_select(0, waiting) <= slowest + drift
            on, waiting = waiting[ready], waiting[~ready]
            if on.shape[0] == 0:
                continue
            self._begin(on, taken, actions, block, stream, fed, known, uniforms, later_uniforms)
            rows = torch.cat([rows, on]).sort()[0]  # ascending, as the decoder reads its rows
        return calls

    def _begin(
        self,
        on: torch.Tensor,
        taken: torch.Tensor,
        actions: torch.Tensor,
        block: torch.Tensor,
        stream: torch.Tensor,
        fed: torch.Tensor,
        known: torch.Tensor,
        uniforms: torch.Tensor,
        later_uniforms: torch.Tensor,
    ) -> None:
        """Rows `on` start their next step (`taken` of them sampled so far), drafted from the block
        each last sampled (in `block`)."""
        s, last = taken.index_select(0, on), block.index_select(0, on)
        act = actions[on, s]
        draft = self._draft(last, act)
        block[on] = draft
        stream[on] = torch.cat([last[:, 13:], act[:, None], draft[:, :13]], 1)
        fed.index_fill_(0, on, 0)
        known.index_fill_(0, on, 0)
        uniforms[on] = later_uniforms[on, s]

    def _draft(self, last: torch.Tensor, act: torch.Tensor) -> torch.Tensor:
        """`draft_block` from each row's last block [rows, 14] and its action."""
        return _draft(
            last[:, :12],
            act,
            last[:, 13],
            last[:, 12],
            self.deltas,
            self.num_actions,
            self.grid,
            self.row_offset,
            self.col_offset,
            self.no_reward,
        )


def _feed(
    stream: torch.Tensor, fed: torch.Tensor, rows: torch.Tensor, first: int, later: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """The tokens [A, n] rows `rows` feed next: each row's stream from what it has fed, two tokens
    and `first` of the draft at a step's start, else one token and up to `later` of the draft,
    right-padded with 0 (a token of every vocabulary); and how many of them are real [A]."""
    c = fed.index_select(0, rows)
    count = torch.minimum(15 - c, torch.where(c == 0, 2 + first, 1 + later))
    n = int(count.max())
    ahead = torch.arange(n)
    at = (c[:, None] + ahead[None, :]).clamp(max=14)
    tokens = stream.index_select(0, rows).gather(1, at).masked_fill(ahead[None, :] >= count[:, None], 0)
    return tokens, count


class _SlotHeads(nn.Module):
    """The three output heads (observation tokens, reward, done) as one head per slot of the
    block: slot k's weights stacked at k, the reward's and done's logits padded to the observation
    vocabulary with -inf (probability 0). A call samples any range of slots with two batched
    matmuls instead of a pair per head and their bookkeeping."""

    def __init__(self, obs_head: nn.Sequential, reward_head: nn.Sequential, done_head: nn.Sequential) -> None:
        super().__init__()
        heads = [obs_head] * OBS_TOKENS + [reward_head, done_head]
        hidden = obs_head[0].in_features
        self.w1 = torch.stack([h[0].weight.detach().t() for h in heads])  # [14, H, H]: x @ w1
        self.b1 = torch.stack([h[0].bias.detach()[None, :] for h in heads])  # [14, 1, H]
        self.w2 = torch.zeros(STEP_TOKENS, hidden, OBS_VOCAB)
        self.b2 = torch.full((STEP_TOKENS, 1, OBS_VOCAB), float("-inf"))
        for k, h in enumerate(heads):
            vocab = h[2].out_features
            self.w2[k, :, :vocab] = h[2].weight.detach().t()
            self.b2[k, 0, :vocab] = h[2].bias.detach()
        self.last = torch.tensor([h[2].out_features - 1 for h in heads])  # each slot's last token

    def forward(
        self,
        hs: torch.Tensor,
        first: int,
        temperature: torch.Tensor,
        u: torch.Tensor,
        allowed: torch.Tensor | None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Tokens [A, k] of slots first..first+k-1 from the hidden states [A, k, H] that predict
        them, as `DecoderBatch._sample` draws each: the first token whose cumulative probability
        reaches the row's uniform number (under the allowed ones if constrained), and the model's
        unrestricted probability of it."""
        k = hs.shape[1]
        w1, b1 = self.w1[first : first + k], self.b1[first : first + k]
        w2, b2 = self.w2[first : first + k], self.b2[first : first + k]
        hidden = torch.relu(torch.baddbmm(b1, hs.transpose(0, 1), w1))
        logits = torch.baddbmm(b2, hidden, w2).transpose(0, 1) / temperature[:, None, None]
        p_all = torch.softmax(logits, dim=-1)
        draw = p_all
        if allowed is not None:
            draw = torch.softmax(logits.masked_fill(~allowed, float("-inf")), dim=-1)
        # Clamped to the slot's vocabulary: rounding can leave the last cumulative value under 1.
        token = torch.minimum((draw.cumsum(-1) < u[:, :, None]).sum(-1), self.last[first : first + k])
        if allowed is not None:
            token = allowed_at_or_before(allowed, token)
        return token, p_all.gather(2, token[:, :, None]).squeeze(2)


def _decide(
    h: torch.Tensor,
    rows: torch.Tensor,
    count: torch.Tensor,
    fed: torch.Tensor,
    known: torch.Tensor,
    block: torch.Tensor,
    probs: torch.Tensor,
    stream: torch.Tensor,
    lengths: torch.Tensor,
    uniforms: torch.Tensor,
    temperature: torch.Tensor,
    heads: _SlotHeads,
    allowed: torch.Tensor | None,
) -> torch.Tensor:
    """After a call of rows `rows` (hidden states h [A, n, H] of the `count` tokens each fed):
    sample their tokens in order while they agree with the draft, write what is decided into the
    step's state (block, probs, stream, fed, known, the cache lengths), and return the rows still
    sampling."""
    c = fed.index_select(0, rows)
    k = known.index_select(0, rows)
    hidden = h.shape[2]
    # Token m is predicted by the hidden state of stream entry m + 1, fed at index m + 1 - c.
    first = int(k.min())
    last = c + count - 2  # the last token each row's call predicts
    top = int(last.max())
    m = torch.arange(first, top + 1)
    q = (m[None, :] + 1 - c[:, None]).clamp(0, h.shape[1] - 1)
    grid = h.gather(1, q[:, :, None].expand(-1, -1, hidden))
    u = uniforms.index_select(0, rows)[:, first : top + 1]
    mask = None if allowed is None else allowed[:, first : top + 1]
    tok, p = heads.forward(grid, first, temperature.index_select(0, rows), u, mask)
    # Each row's first token that differs from the draft (or its last predicted one) ends what
    # this call decided for it.
    mine = block.index_select(0, rows)[:, first : top + 1]
    pending = m[None, :] >= k[:, None]
    stop = pending & ((tok != mine) | (m[None, :] >= last[:, None]))
    end = first + stop.int().argmax(1)  # argmax returns the first True
    take = pending & (m[None, :] <= end[:, None])
    # What this call sampled past the accepted tokens is the row's next draft (the module docstring).
    guess = pending & (m[None, :] <= last[:, None])
    block[rows, first : top + 1] = torch.where(guess, tok, mine)
    probs[rows, first : top + 1] = torch.where(take, p, probs.index_select(0, rows)[:, first : top + 1])
    stream[rows, 2:] = block.index_select(0, rows)[:, :13]
    now = torch.clamp(end + 2, max=15)  # stream entries valid: up to the one holding token `end`
    lengths.index_add_(0, rows, now - c)
    fed.index_copy_(0, rows, now)
    known.index_copy_(0, rows, end + 1)
    return rows[end + 1 < 14]


__all__ = ["FlatDecoderBatch", "draft_block"]
