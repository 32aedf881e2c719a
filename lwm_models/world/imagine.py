"""Imagination: batched, KV-cached sampling of trajectories from a world model.

Start from a real first observation and its manual, feed actions (a fixed sequence, or a policy
called on the imagined observations), and sample each next block's 12 observation tokens, reward
and done token (categorical, temperature 1 by default) until done or the time limit. A trajectory
that has ended is dropped from the batch (and from the KV cache), so the batch shrinks as
episodes finish. `DecoderBatch` is that batch; trajectories can also join it between steps, which the
world-model server's continuous batching of requests uses (world/continuous.py).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from ..errors import ShapeError
from ..messenger.constants import DEFAULT_MAX_STEPS, NUM_ACTIONS, NUM_CHANNELS
from .base import Conditioning, ManualBatch, WorldModel
from .constraints import StepRules
from .gpt import KVCache
from .tokens import (
    BLOCK,
    OBS_TOKENS,
    REWARD_VALUES,
    first_block_tokens,
    tokens_to_obs,
)

Policy = Callable[[np.ndarray, np.ndarray, int], np.ndarray]
"""policy(observations [n, t, 4, 3] so far (compact), trajectory indices [n], step t) -> actions [n]."""


@dataclass
class Imagination:
    """N imagined trajectories, padded to max_steps + 1 observations (index 0 is the real one).

    `token_probs[:, t]` holds the probability of each of block t's 14 sampled tokens (12
    observation tokens, reward, done): the model's confidence in what it imagined. Imagined
    elsewhere (`/lwm/imagine` answers a step's confidence, not its tokens'), each of a step's 14
    holds that step's confidence, so `confidence()` is the same on both sides.
    """

    observations: np.ndarray  # [N, T + 1, 4, 3] uint8
    actions: np.ndarray  # [N, T + 1] (0 at index 0)
    rewards: np.ndarray  # [N, T + 1] float32
    dones: np.ndarray  # [N, T + 1] bool
    lengths: np.ndarray  # [N] observations per trajectory
    token_probs: np.ndarray  # [N, T + 1, 14] float32
    manual_version: int = 0  # the world-model server's manual version it read (0: a manual given directly)

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


class DecoderBatch:
    """The running trajectories of a batch and the model state they carry between steps: their
    conditioning, KV cache, last done token, temperature and random numbers. Trajectories join
    (`admit`) and leave (`keep`) between steps, so the batch can be continuous: a one-shot request
    joins while others are half-way, each at its own place in the cache.

    A step feeds every row its pending done token and its action, then samples the block's 14
    tokens. Each row's uniform numbers for all its steps are drawn when it joins, from the random
    generator it joined with, and a token is drawn by inverting the row's cumulative distribution:
    what a row samples does not depend on which other rows share its steps.
    """

    def __init__(self, model: WorldModel, use_cache: bool = True, first_blocks: int = 0) -> None:
        """first_blocks: how many first blocks' keys and values to keep for rows that join later
        with the same start observation and conditioning (0: none; see `_first_block`)."""
        model.eval()
        self.model = model
        self.cache = model.new_cache(0) if use_cache else None
        self.first_blocks: OrderedDict[tuple, tuple[torch.Tensor, torch.Tensor]] = OrderedDict()
        self.max_first_blocks = first_blocks if use_cache else 0
        self.history: torch.Tensor | None = None  # without a cache: every row's tokens so far
        self.cond: Conditioning | None = None
        self.pending = torch.zeros(0, dtype=torch.long)  # each row's last done token
        self.temperature = torch.zeros(0)
        self.uniforms = torch.zeros(0, 0, BLOCK - 1)  # [rows, steps, 14]: each row's random numbers
        self.t = torch.zeros(0, dtype=torch.long)  # steps each row has taken
        self.last_obs = torch.zeros(0, OBS_TOKENS, dtype=torch.long)  # each row's last observation tokens
        self.constrained = torch.zeros(0, dtype=torch.bool)  # rows sampled under the game's rules
        self.limit = torch.zeros(0, dtype=torch.long)  # each row's time limit (max steps)

    def __len__(self) -> int:
        return len(self.pending)

    @torch.inference_mode()
    def admit(
        self,
        cond: Conditioning,
        first: np.ndarray,
        max_steps: int,
        temperature: float,
        gen: torch.Generator,
        constrained: bool = False,
    ) -> None:
        """New rows: n trajectories of up to max_steps from first observations [n, 4, 3] under
        `cond` (batch n), their random numbers drawn from `gen`, sampled under the game's rules if
        `constrained` (world/constraints.py). The first block is fed now except its done token,
        which is fed with the first action as every later block's is."""
        n = len(first)
        tokens = torch.from_numpy(first_block_tokens(first))
        if self.cache is not None:
            self.cache.extend(self._first_block(tokens, cond))
        elif len(self):
            raise ValueError("without a KV cache every trajectory must start together")
        else:
            self.history = tokens
        self.cond = cond if self.cond is None else Conditioning.cat([self.cond, cond])
        self.pending = torch.cat([self.pending, torch.zeros(n, dtype=torch.long)])  # the first done is 0
        self.temperature = torch.cat([self.temperature, torch.full((n,), float(temperature))])
        uniforms = torch.rand(n, max_steps, BLOCK - 1, generator=gen)
        steps = max(max_steps, self.uniforms.shape[1])
        self.uniforms = torch.cat([_pad_steps(self.uniforms, steps), _pad_steps(uniforms, steps)])
        self.t = torch.cat([self.t, torch.zeros(n, dtype=torch.long)])
        self.last_obs = torch.cat([self.last_obs, tokens[:, 1 : 1 + OBS_TOKENS]])
        self.constrained = torch.cat([self.constrained, torch.full((n,), constrained)])
        self.limit = torch.cat([self.limit, torch.full((n,), max_steps, dtype=torch.long)])

    @torch.inference_mode()
    def step(self, actions: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        """Every row takes its action [rows]; returns the sampled blocks [rows, 14] (12 observation
        tokens, reward, done) and each token's probability."""
        uniforms = self.uniforms[torch.arange(len(self)), self.t]  # [rows, 14]
        self.t = self.t + 1
        h = self._run(torch.stack([self.pending, actions], 1))
        rules = StepRules(self.last_obs, actions, self.t >= self.limit) if bool(self.constrained.any()) else None
        tokens, probs = [], []
        for k in range(OBS_TOKENS + 2):
            allowed = None if rules is None else rules.allowed(k, tokens) | ~self.constrained[:, None]
            token, p = self._sample(h, 1 + k, uniforms[:, k], allowed)
            tokens.append(token)
            probs.append(p)
            if k < OBS_TOKENS + 1:
                h = self._run(token[:, None])
        self.pending = tokens[-1]
        self.last_obs = torch.stack(tokens[:OBS_TOKENS], 1)
        return torch.stack(tokens, 1).numpy(), torch.stack(probs, 1).numpy()

    def _first_block(self, tokens: torch.Tensor, cond: Conditioning) -> KVCache:
        """A cache of the joining rows holding their first block. Rows that all start alike (one
        request's trajectories from one state under one manual) are computed once, and kept: a
        planner imagines again and again from the state under review, and a server's next calls
        often start where its last ones did. The first block is 13 tokens, a decoder call that
        cost 0.7 ms of the ~0.8 ms of admitting a call (measured)."""
        n = len(tokens)
        joining = self.model.new_cache(n)
        key = self._start_key(tokens, cond) if self.max_first_blocks else None
        if key is None:
            self.model.hidden_states(tokens, cond, joining)
            return joining
        if key not in self.first_blocks:
            one = self.model.new_cache(1)
            self.model.hidden_states(tokens[:1], cond.index(torch.zeros(1, dtype=torch.long)), one)
            self.first_blocks[key] = (one.k[:, :, :, : one.end].clone(), one.v[:, :, :, : one.end].clone())
            if len(self.first_blocks) > self.max_first_blocks:
                self.first_blocks.popitem(last=False)
        self.first_blocks.move_to_end(key)
        k, v = self.first_blocks[key]
        width = k.shape[3]
        joining.k[:, :, :, :width] = k
        joining.v[:, :, :, :width] = v
        joining.lengths = torch.full((n,), width, dtype=torch.long)
        joining.end = width
        return joining

    @staticmethod
    def _start_key(tokens: torch.Tensor, cond: Conditioning) -> tuple | None:
        """What the first block's keys and values depend on, when every row has the same; else None."""
        parts = [tokens]
        for t in (cond.id_table, cond.memory, cond.memory_mask):
            if t is not None:
                parts.append(t)
        if any(len(p) > 1 and not bool((p == p[:1]).all()) for p in parts):
            return None
        return tuple(p[0].numpy().tobytes() for p in parts)

    def keep(self, idx: torch.Tensor) -> None:
        """Keep only the rows at `idx` (the others' trajectories have ended)."""
        self.pending = self.pending[idx]
        self.temperature = self.temperature[idx]
        self.uniforms = self.uniforms[idx]
        self.t = self.t[idx]
        self.last_obs = self.last_obs[idx]
        self.constrained = self.constrained[idx]
        self.limit = self.limit[idx]
        self.cond = self.cond.index(idx)
        if self.cache is not None:
            self.cache.select(idx)
        else:
            self.history = self.history[idx]

    def _run(self, new_tokens: torch.Tensor) -> torch.Tensor:
        """Feed tokens; the last hidden state predicts the next token."""
        if self.cache is not None:
            return self.model.hidden_states(new_tokens, self.cond, self.cache)[:, -1]
        self.history = torch.cat([self.history, new_tokens], dim=1)
        return self.model.hidden_states(self.history, self.cond)[:, -1]

    def _sample(
        self, h: torch.Tensor, slot: int, u: torch.Tensor, allowed: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """A token per row, from the model's distribution restricted to `allowed` if given; with
        the model's own (unrestricted) probability of it, which is what confidence reports."""
        logits = self.model.next_token_logits(h, slot).float() / self.temperature[:, None]
        probs = torch.softmax(logits, dim=-1)
        draw = probs if allowed is None else torch.softmax(logits.masked_fill(~allowed, -torch.inf), dim=-1)
        # The first token whose cumulative probability reaches u (clamped: rounding can leave
        # the last cumulative value a little under 1), then the last allowed one at or before it
        # (rounding again: a disallowed token of probability 0 must never be drawn).
        token = (draw.cumsum(-1) < u[:, None]).sum(-1).clamp_(max=draw.shape[-1] - 1)
        if allowed is not None:
            token = allowed_at_or_before(allowed, token)
        return token, probs.gather(1, token[:, None]).squeeze(1)


def allowed_at_or_before(allowed: torch.Tensor, token: torch.Tensor) -> torch.Tensor:
    """Each token [...] if its mask [..., vocab] allows it, else the nearest allowed token below it,
    else the first allowed (scripted by the speculative path too)."""
    vocab = torch.arange(allowed.shape[-1])
    below = allowed & (vocab <= token[..., None])
    last_below = torch.where(below, vocab, -1).amax(-1)
    return torch.where(last_below >= 0, last_below, allowed.float().argmax(-1))


def _pad_steps(uniforms: torch.Tensor, steps: int) -> torch.Tensor:
    return torch.nn.functional.pad(uniforms, (0, 0, 0, steps - uniforms.shape[1]))


def decode_blocks(block: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sampled blocks [k, 14] as a step's observations [k, 4, 3], rewards [k] and dones [k]."""
    return tokens_to_obs(block[:, :OBS_TOKENS]), REWARD_VALUES[block[:, OBS_TOKENS]], block[:, OBS_TOKENS + 1] == 1


class Trajectories:
    """What has been imagined of n trajectories so far: step t of trajectory i at [i, t]. Filled
    from sampled token blocks here (`write`), or from decoded steps (`put`, `put_trajectory`: what
    `/lwm/imagine` answers)."""

    def __init__(self, first: np.ndarray, max_steps: int) -> None:
        n, steps = len(first), max_steps + 1
        self.observations = np.zeros((n, steps, NUM_CHANNELS, 3), dtype=np.uint8)
        self.actions = np.zeros((n, steps), dtype=np.int64)
        self.rewards = np.zeros((n, steps), dtype=np.float32)
        self.dones = np.zeros((n, steps), dtype=bool)
        self.token_probs = np.zeros((n, steps, OBS_TOKENS + 2), dtype=np.float32)
        self.lengths = np.ones(n, dtype=np.int64)
        self.observations[:, 0] = first

    def write(self, which: np.ndarray, t: int, actions: np.ndarray, block: np.ndarray, probs: np.ndarray) -> np.ndarray:
        """Step t of trajectories `which` (their actions, sampled blocks and token probabilities);
        returns which of them sampled done."""
        observations, rewards, done = decode_blocks(block)
        self.put(which, t, actions, observations, rewards, done, probs)
        return done

    def put(self, which, t: int, actions, observations, rewards, dones, probs) -> None:
        """Step t of trajectories `which`, decoded: probs [k, 14] per token, or [k] or [k, 1] a
        step's confidence (given to each of its tokens)."""
        self.actions[which, t] = actions
        self.observations[which, t] = observations
        self.rewards[which, t] = rewards
        self.dones[which, t] = dones
        probs = np.asarray(probs, dtype=np.float32)
        self.token_probs[which, t] = probs if probs.ndim == 2 and probs.shape[1] > 1 else probs.reshape(-1, 1)
        self.lengths[which] = t + 1

    def put_trajectory(self, i: int, observations, actions, rewards, dones, confidence) -> None:
        """Trajectory i whole (observations include the first; the rest one per step)."""
        n = len(observations)
        self.observations[i, :n] = observations
        self.actions[i, 1:n] = actions
        self.rewards[i, 1:n] = rewards
        self.dones[i, 1:n] = dones
        self.token_probs[i, 1:n] = np.asarray(confidence, dtype=np.float32).reshape(-1, 1)
        self.lengths[i] = n

    def result(self, manual_version: int = 0) -> Imagination:
        return Imagination(
            self.observations, self.actions, self.rewards, self.dones, self.lengths, self.token_probs, manual_version
        )


def board_of(observations: np.ndarray | torch.Tensor) -> torch.Tensor:
    """[N, 3]: the identity ids of the entities (0: an empty channel) of compact observations
    [N, 4, 3] (channels 0-2 the entities, 3 the avatar; each channel's first value its id)."""
    return torch.from_numpy(np.array(np.asarray(observations)[:, : NUM_CHANNELS - 1, 0], dtype=np.int64))


def condition_rows(cond: Conditioning, n: int) -> Conditioning:
    """A conditioning on a manual (batch 1, broadcast; or one per trajectory) for n rows; of a
    manual read several ways, one reading per row (`Conditioning.rows_for`)."""
    if cond.reading_owner is not None:
        try:
            return cond.rows_for(n)
        except ValueError as e:
            raise ShapeError(str(e)) from None
    given = next((t.shape[0] for t in (cond.id_table, cond.memory) if t is not None), n)
    if given not in (1, n):
        raise ShapeError(f"manual batch must be 1 or {n}, got {given}")
    return cond.index(torch.zeros(n, dtype=torch.long)) if given == 1 and n > 1 else cond


class StepwiseImagination:
    """Step-wise imagination of n trajectories: the caller gives the actions of the running
    trajectories one step at a time (a policy acting inside imagination), and the KV cache stays
    here between steps. `imagine` is a loop over it; the world-model server keeps one per session.

    After `step`, the new observation of trajectory i is `observations[i, t]` for each i in the
    returned indices (those that were running), with `rewards`, `dones` and `token_probs` alike.
    Sampling draws from one random stream seeded with `seed`.
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
        constrained: bool = False,
        decoding: str | None = None,
    ) -> None:
        if max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {max_steps}")
        if temperature <= 0:
            raise ValueError("temperature must be > 0")
        first = _check_inputs(first_obs, n)
        self.n, self.max_steps, self.stop_on_done, self.constrained = n, max_steps, stop_on_done, constrained
        self._trajectories = so_far = Trajectories(first, max_steps)
        # Its arrays, written in place at each step (see the class docstring).
        self.observations, self.actions, self.rewards = so_far.observations, so_far.actions, so_far.rewards
        self.dones, self.token_probs, self.lengths = so_far.dones, so_far.token_probs, so_far.lengths
        self.active = np.arange(n)
        self.t = 0
        seed = seed if seed is not None else int(torch.randint(2**31, ()).item())
        from .decoding import make_decoder_batch  # decoding's paths build on DecoderBatch, defined here

        self._rows = make_decoder_batch(model, decoding, use_cache)
        cond = condition_rows(model.condition_on(model.on_board(manual, board_of(first))), n)
        self._rows.admit(cond, first, max_steps, temperature, torch.Generator().manual_seed(seed), constrained)

    @property
    def finished(self) -> bool:
        return len(self.active) == 0 or self.t >= self.max_steps

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
        active = self.active
        self.t += 1
        block, probs = self._rows.step(torch.from_numpy(act))
        done = self._trajectories.write(active, self.t, act, block, probs)
        if self.stop_on_done and done.any():
            keep = np.flatnonzero(~done)
            self.active = active[keep]
            if len(self.active):
                self._rows.keep(torch.from_numpy(keep))
        return active

    def run(self, actions: np.ndarray) -> None:
        """Every running trajectory takes all its remaining actions [running, steps left], to the end.
        The fast paths, unconstrained, take every step in their scripted graph, each lane's group of
        rows on its own, with no Python step and no wait for the other lanes between steps
        (`FlatDecoderBatch.run_steps`): the tokens of `step` at a time, in less time."""
        act = np.asarray(actions, dtype=np.int64)
        left = self.max_steps - self.t
        if act.shape != (len(self.active), left) or ((act < 0) | (act >= NUM_ACTIONS)).any():
            raise ValueError(f"give [{len(self.active)}, {left}] actions in 0..{NUM_ACTIONS - 1}")
        if self.finished:
            return
        active, start = self.active, self.t
        run_steps = getattr(self._rows, "run_steps", None)
        if run_steps is None or self.constrained:
            while not self.finished:  # `active` is sorted, and those still running are a subset of it
                self.step(act[np.searchsorted(active, self.active), self.t - start])
            return
        blocks, probs, taken = run_steps(torch.from_numpy(act), self.stop_on_done)
        for s in range(int(taken.max(initial=0))):
            which = np.flatnonzero(taken > s)
            self._trajectories.write(active[which], start + s + 1, act[which, s], blocks[which, s], probs[which, s])
        ended = blocks[np.arange(len(active)), np.maximum(taken - 1, 0), -1] == 1
        self.t, self.active = self.max_steps, active[~ended] if self.stop_on_done else active

    def result(self) -> Imagination:
        return self._trajectories.result()


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
    constrained: bool = False,
    decoding: str | None = None,
) -> Imagination:
    """Imagine `n` trajectories.

    manual: the manual of every trajectory (batch 1, broadcast) or one per trajectory (batch n).
    first_obs: compact first observation (4, 3), or one per trajectory (n, 4, 3).
    actions: [n, max_steps] or [max_steps] actions to replay, or None with a `policy`.
    use_cache: False recomputes the whole prefix at every token (for the speed benchmark only).
    stop_on_done: False keeps imagining past a sampled done (benchmarks use it for full-length
        trajectories).
    constrained: sample under the game's rules (world/constraints.py), for plans shown to people.
    decoding: "speculative", "flat" or "reference" (world/decoding.py); None: the default, the
        fastest path that samples the reference path's tokens.
    """
    if (actions is None) == (policy is None):
        raise ValueError("give either an action sequence or a policy")
    if actions is not None:  # the rest (max_steps, first observations) StepwiseImagination checks
        actions = np.asarray(actions)
        if actions.ndim == 1:
            actions = np.broadcast_to(actions, (n, actions.shape[0]))
        if actions.shape[0] != n or actions.shape[1] < max_steps:
            raise ShapeError(f"actions must be [{n}, >= {max_steps}], got {actions.shape}")
        if ((actions < 0) | (actions >= NUM_ACTIONS)).any():
            raise ValueError(f"actions must be in 0..{NUM_ACTIONS - 1}")
    rollout = StepwiseImagination(
        model, manual, first_obs, n, max_steps, temperature, seed, use_cache, stop_on_done, constrained, decoding
    )
    if actions is not None:
        rollout.run(actions[:, :max_steps])
    while not rollout.finished:  # a policy acts on what has been imagined, a step at a time
        active, t = rollout.active, rollout.t + 1
        act = np.asarray(policy(rollout.observations[active, :t], active, t), dtype=np.int64)
        if act.shape != (len(active),) or ((act < 0) | (act >= NUM_ACTIONS)).any():
            raise ValueError(f"the policy must return {len(active)} actions in 0..{NUM_ACTIONS - 1}")
        rollout.step(act)
    return rollout.result()
