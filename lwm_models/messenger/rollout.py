"""Batched episodes of the behaviour policies: the trajectories the benchmark is made of."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import ShapeError
from .constants import DEFAULT_MAX_STEPS, NUM_CHANNELS
from .engine import BatchedMessenger
from .policies import behaviour_actions
from .spec import GameSpec


@dataclass
class Rollouts:
    """N episodes padded to max_steps + 1 observations.

    Index i of the step axis is observation i; `actions[:, i]` is the action that led to it (0 at
    i = 0, a dummy), `rewards[:, i]` and `dones[:, i]` what that step gave. `lengths` counts the
    observations of each episode (2..max_steps + 1); entries past it are zero.
    """

    observations: np.ndarray  # [N, T + 1, 4, 3] uint8, compact (id, row, col) per channel
    actions: np.ndarray  # [N, T + 1] uint8
    rewards: np.ndarray  # [N, T + 1] float32
    dones: np.ndarray  # [N, T + 1] bool
    lengths: np.ndarray  # [N] int64
    starts: np.ndarray  # [N] start index of each episode

    @property
    def returns(self) -> np.ndarray:
        return self.rewards.sum(1)


def rollout(
    specs: Sequence[GameSpec],
    seeds: Sequence[int] | np.ndarray,
    policies: Sequence[int] | np.ndarray,
    starts: Sequence[int] | np.ndarray | None = None,
    max_steps: int = DEFAULT_MAX_STEPS,
) -> Rollouts:
    """Play one episode per game, each with its behaviour policy (indices into POLICIES)."""
    n = len(specs)
    policies = np.asarray(policies, dtype=np.int64)
    if policies.shape != (n,):
        raise ShapeError(f"need one policy per game: {n} specs, policies of shape {policies.shape}")
    engine = BatchedMessenger(max_steps=max_steps)
    engine.reset(specs, seeds, starts)
    steps = max_steps + 1
    obs = np.zeros((n, steps, NUM_CHANNELS, 3), dtype=np.uint8)
    actions = np.zeros((n, steps), dtype=np.uint8)
    rewards = np.zeros((n, steps), dtype=np.float32)
    dones = np.zeros((n, steps), dtype=bool)
    obs[:, 0] = engine.compact_observation()
    lengths = np.ones(n, dtype=np.int64)
    for t in range(1, steps):
        if engine.done.all():
            break
        avatar, entities, present = engine.role_cells()
        act = behaviour_actions(policies, avatar, entities, present, engine.has_message, engine.keys, t)
        r, term, trunc, running = engine.step(act)
        obs[running, t] = engine.compact_observation()[running]
        actions[running, t] = act[running]
        rewards[:, t] = r
        dones[:, t] = term | trunc
        lengths += running
    return Rollouts(obs, actions, rewards, dones, lengths, engine.starts.copy())
