"""Imagination: batched, KV-cached sampling of trajectories from a world model.

Start from a real first observation and its manual, feed actions (a fixed sequence, or a policy
called on the imagined observations), and sample each next block's 12 observation tokens, reward
and done token (categorical, temperature 1 by default) until done or the time limit. A trajectory
that has ended is dropped from the batch (and from the KV cache), so the batch shrinks as
episodes finish.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import ShapeError
from ..messenger.constants import DEFAULT_MAX_STEPS, NUM_ACTIONS, NUM_CHANNELS
from .base import ManualBatch, WorldModel
from .tokens import (
    BLOCK,
    DUMMY_ACTION,
    FIRST_REWARD_LABEL,
    OBS_TOKENS,
    REWARD_VALUES,
    obs_to_tokens,
    tokens_to_obs,
)

Policy = Callable[[np.ndarray, np.ndarray, int], np.ndarray]
"""policy(observations [n, t, 4, 3] so far (compact), trajectory indices [n], step t) -> actions [n]."""


@dataclass
class Imagination:
    """N imagined trajectories, padded to max_steps + 1 observations (index 0 is the real one).

    `token_probs[:, t]` holds the probability of each of block t's 14 sampled tokens (12
    observation tokens, reward, done): the model's confidence in what it imagined.
    """

    observations: np.ndarray  # [N, T + 1, 4, 3] uint8
    actions: np.ndarray  # [N, T + 1] (0 at index 0)
    rewards: np.ndarray  # [N, T + 1] float32
    dones: np.ndarray  # [N, T + 1] bool
    lengths: np.ndarray  # [N] observations per trajectory
    token_probs: np.ndarray  # [N, T + 1, 14] float32 ([N, T + 1, 1]: the step confidence, from a service)
    manual_version: int = 0  # the simulator's manual version it read (0: a manual given directly)

    @property
    def returns(self) -> np.ndarray:
        return self.rewards.sum(1)

    def to_json(self) -> list[dict]:
        """Each trajectory as plain lists (observations include the first, real one)."""
        conf = self.confidence()
        out = []
        for i in range(len(self.lengths)):
            n = int(self.lengths[i])
            out.append(
                {
                    "observations": self.observations[i, :n].tolist(),
                    "actions": self.actions[i, 1:n].tolist(),
                    "rewards": self.rewards[i, 1:n].tolist(),
                    "dones": self.dones[i, 1:n].tolist(),
                    "confidence": conf[i, 1:n].round(4).tolist(),
                    "return": float(self.returns[i]),
                }
            )
        return out

    def confidence(self) -> np.ndarray:
        """[N, T + 1] per-step confidence: the geometric mean of the step's 14 token probabilities
        (1 at index 0 and past the end). A product would vanish for any step with many tokens."""
        p = np.where(self.token_probs > 0, self.token_probs, 1.0)
        return np.exp(np.log(p).mean(-1))


def _check_inputs(first_obs: np.ndarray, n: int) -> np.ndarray:
    first = np.asarray(first_obs)
    if first.shape == (NUM_CHANNELS, 3):
        first = np.broadcast_to(first, (n, NUM_CHANNELS, 3))
    if first.shape != (n, NUM_CHANNELS, 3):
        raise ShapeError(f"first observation must be compact (4, 3) or ({n}, 4, 3), got {first.shape}")
    return first


@dataclass
class _Sampler:
    """Feeds tokens through the model (with or without the KV cache) and samples the next one."""

    model: WorldModel
    cond: object
    cache: object
    history: torch.Tensor | None
    gens: list[torch.Generator]  # one random stream per group of trajectories
    stream: np.ndarray  # [rows]: the stream of each running trajectory
    temperature: float
    stream_rows: list[torch.Tensor] = field(init=False)  # the running rows of each stream

    def __post_init__(self) -> None:
        self._index_streams()

    def _index_streams(self) -> None:
        # Rows change only when trajectories end (keep), not at each of a step's 14 samples.
        self.stream_rows = [torch.from_numpy(np.flatnonzero(self.stream == s)) for s in range(len(self.gens))]

    def run(self, new_tokens: torch.Tensor) -> torch.Tensor:
        """Feed tokens; the last hidden state predicts the next token."""
        if self.cache is not None:
            return self.model.hidden_states(new_tokens, self.cond, self.cache)[:, -1]
        self.history = torch.cat([self.history, new_tokens], dim=1)
        return self.model.hidden_states(self.history, self.cond)[:, -1]

    def sample(self, h: torch.Tensor, position: int) -> tuple[torch.Tensor, torch.Tensor]:
        probs = torch.softmax(self.model.next_token_logits(h, position).float() / self.temperature, dim=-1)
        if len(self.gens) == 1:
            token = torch.multinomial(probs, 1, generator=self.gens[0]).squeeze(1)
        else:
            token = torch.empty(len(probs), dtype=torch.long)
            for gen, rows in zip(self.gens, self.stream_rows):
                if len(rows):
                    token[rows] = torch.multinomial(probs[rows], 1, generator=gen).squeeze(1)
        return token, probs.gather(1, token[:, None]).squeeze(1)

    def keep(self, idx: torch.Tensor) -> None:
        self.stream = self.stream[idx.numpy()]
        self._index_streams()
        self.cond = self.cond.index(idx)
        if self.cache is not None:
            self.cache.select(idx)
        else:
            self.history = self.history[idx]


class Rollout:
    """Step-wise imagination of n trajectories: the caller gives the actions of the running
    trajectories one step at a time (a policy acting inside imagination), and the KV cache stays
    here between steps. `imagine` is a loop over it; the simulator keeps one per session.

    After `step`, the new observation of trajectory i is `observations[i, t]` for each i in the
    returned indices (those that were running), with `rewards`, `dones` and `token_probs` alike.

    Sampling draws from one random stream seeded with `seed`, or, with `streams` [(count, seed),
    ...], from one stream per consecutive group of trajectories: the simulator batches concurrent
    requests that way, and each samples as if it had been imagined alone.
    """

    def __init__(
        self,
        model: WorldModel,
        manual: ManualBatch,
        first_obs: np.ndarray,
        n: int = 1,
        max_steps: int = DEFAULT_MAX_STEPS,
        temperature: float = 1.0,
        seed: int | None = None,
        use_cache: bool = True,
        stop_on_done: bool = True,
        streams: Sequence[tuple[int, int]] | None = None,
    ) -> None:
        if max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {max_steps}")
        if temperature <= 0:
            raise ValueError("temperature must be > 0")
        first = _check_inputs(first_obs, n)
        model.eval()
        with torch.inference_mode():  # faster than no_grad for the many small ops of a step
            cond = model.condition(manual)
        batch_of_manual = (
            next(t for t in (cond.id_table, cond.memory) if t is not None).shape[0]
            if (cond.id_table is not None or cond.memory is not None)
            else n
        )
        if batch_of_manual not in (1, n):
            raise ShapeError(f"manual batch must be 1 or {n}, got {batch_of_manual}")
        if batch_of_manual == 1 and n > 1:
            cond = cond.index(torch.zeros(n, dtype=torch.long))
        self.n, self.max_steps, self.stop_on_done = n, max_steps, stop_on_done
        steps = max_steps + 1
        self.observations = np.zeros((n, steps, NUM_CHANNELS, 3), dtype=np.uint8)
        self.actions = np.zeros((n, steps), dtype=np.int64)
        self.rewards = np.zeros((n, steps), dtype=np.float32)
        self.dones = np.zeros((n, steps), dtype=bool)
        self.token_probs = np.zeros((n, steps, OBS_TOKENS + 2), dtype=np.float32)
        self.lengths = np.ones(n, dtype=np.int64)
        self.observations[:, 0] = first
        self.active = np.arange(n)
        self.t = 0
        first_block = np.zeros((n, BLOCK), dtype=np.int64)
        first_block[:, 0] = DUMMY_ACTION
        first_block[:, 1 : 1 + OBS_TOKENS] = obs_to_tokens(first)
        first_block[:, -2] = FIRST_REWARD_LABEL
        if streams is None:
            streams = [(n, seed if seed is not None else int(torch.randint(2**31, ()).item()))]
        if sum(count for count, _ in streams) != n:
            raise ValueError(f"the streams' counts must add up to {n}, got {[c for c, _ in streams]}")
        gens = [torch.Generator().manual_seed(int(s)) for _, s in streams]
        stream = np.repeat(np.arange(len(streams)), [count for count, _ in streams])
        tokens = torch.from_numpy(first_block)
        cache = model.new_cache(n) if use_cache else None
        self._sampler = _Sampler(model, cond, cache, None if use_cache else tokens, gens, stream, temperature)
        if use_cache:
            with torch.inference_mode():
                model.hidden_states(tokens, cond, cache)
        self._pending: torch.Tensor | None = None  # the last block's done token, fed with the next action

    @property
    def finished(self) -> bool:
        return len(self.active) == 0 or self.t >= self.max_steps

    @torch.inference_mode()  # faster than no_grad for a step's many small ops (15% measured)
    def step(self, actions: np.ndarray) -> np.ndarray:
        """Advance every running trajectory by one action (`actions[k]` for `active[k]`); returns the
        indices that stepped."""
        if self.finished:
            raise ValueError("the imagination has ended: every trajectory is done or at the time limit")
        act = np.asarray(actions, dtype=np.int64).reshape(-1)
        if act.shape != (len(self.active),) or ((act < 0) | (act >= NUM_ACTIONS)).any():
            raise ValueError(
                f"give {len(self.active)} actions in 0..{NUM_ACTIONS - 1}, got {np.asarray(actions).tolist()}"
            )
        s, active = self._sampler, self.active
        self.t += 1
        t = self.t
        self.actions[active, t] = act
        new = torch.from_numpy(act)[:, None]
        if self._pending is not None:
            new = torch.cat([self._pending[:, None], new], dim=1)
        h = s.run(new)
        block_tokens, probs = [], []
        for k in range(OBS_TOKENS + 2):
            token, p = s.sample(h, t * BLOCK + 1 + k)
            block_tokens.append(token)
            probs.append(p)
            if k < OBS_TOKENS + 1:
                h = s.run(token[:, None])
        block = torch.stack(block_tokens, 1).numpy()
        self.observations[active, t] = tokens_to_obs(block[:, :OBS_TOKENS])
        self.rewards[active, t] = REWARD_VALUES[block[:, OBS_TOKENS]]
        done = block[:, OBS_TOKENS + 1] == 1
        self.dones[active, t] = done
        self.token_probs[active, t] = torch.stack(probs, 1).numpy()
        self.lengths[active] += 1
        self._pending = torch.from_numpy(block[:, OBS_TOKENS + 1])
        keep = ~done if self.stop_on_done else np.ones_like(done)
        if not keep.all():
            idx = torch.from_numpy(np.flatnonzero(keep))
            self.active = active[keep]
            self._pending = self._pending[idx]
            if len(self.active):
                s.keep(idx)
        return active

    def result(self) -> Imagination:
        return Imagination(self.observations, self.actions, self.rewards, self.dones, self.lengths, self.token_probs)


@torch.no_grad()
def imagine(
    model: WorldModel,
    manual: ManualBatch,
    first_obs: np.ndarray,
    n: int = 1,
    actions: np.ndarray | None = None,
    policy: Policy | None = None,
    max_steps: int = DEFAULT_MAX_STEPS,
    temperature: float = 1.0,
    seed: int | None = None,
    use_cache: bool = True,
    stop_on_done: bool = True,
    streams: Sequence[tuple[int, int]] | None = None,
) -> Imagination:
    """Imagine `n` trajectories.

    manual: the manual of every trajectory (batch 1, broadcast) or one per trajectory (batch n).
    first_obs: compact first observation (4, 3), or one per trajectory (n, 4, 3).
    actions: [n, max_steps] or [max_steps] actions to replay, or None with a `policy`.
    use_cache: False recomputes the whole prefix at every token (for the speed benchmark only).
    stop_on_done: False keeps imagining past a sampled done (benchmarks use it for full-length
        trajectories).
    streams: independent random streams per group of trajectories (see Rollout).
    """
    if (actions is None) == (policy is None):
        raise ValueError("give either an action sequence or a policy")
    if actions is not None:  # the rest (max_steps, first observations) Rollout checks
        actions = np.asarray(actions)
        if actions.ndim == 1:
            actions = np.broadcast_to(actions, (n, actions.shape[0]))
        if actions.shape[0] != n or actions.shape[1] < max_steps:
            raise ShapeError(f"actions must be [{n}, >= {max_steps}], got {actions.shape}")
        if ((actions < 0) | (actions >= NUM_ACTIONS)).any():
            raise ValueError(f"actions must be in 0..{NUM_ACTIONS - 1}")
    rollout = Rollout(model, manual, first_obs, n, max_steps, temperature, seed, use_cache, stop_on_done, streams)
    while not rollout.finished:
        active, t = rollout.active, rollout.t + 1
        if policy is not None:
            act = np.asarray(policy(rollout.observations[active, :t], active, t), dtype=np.int64)
            if act.shape != (len(active),) or ((act < 0) | (act >= NUM_ACTIONS)).any():
                raise ValueError(f"the policy must return {len(active)} actions in 0..{NUM_ACTIONS - 1}")
        else:
            act = actions[active, t - 1]
        rollout.step(act)
    return rollout.result()
