"""Continuous batching of one-shot imaginations: requests join a running batch between steps and
leave it at their own last step, as inference servers batch token generation.

A one-shot request replays known action sequences, so its trajectories need nothing from outside
between steps, and any number of requests can share each step of the model (a step of 16 rows
costs about 1.6x a step of one, measured). Requests need not match: each row keeps its own
conditioning (manual), temperature, time limit, decoding constraints, random stream and place in
the KV cache. A batch
that waited for its longest trajectory before taking new requests (this module's predecessor) ran
most steps for a few long trajectories while new requests queued.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from .base import Conditioning, WorldModel
from .decoding import make_decoder_batch
from .imagine import Imagination, Trajectories, decode_blocks

MAX_ROWS = 256  # trajectories running at once: bounds the memory and the time of one step
FIRST_BLOCKS = 64  # start states whose first block a batch keeps (DecoderBatch._first_block): 16 KB each


@dataclass
class OneShot:
    """A one-shot request in a batch: n trajectories, each replaying its actions from its start.

    cond: the model's conditioning on the request's manual, one row per trajectory.
    first: [n, 4, 3] start observations; actions: [n, max_steps] actions to replay.
    info: the owner's (what to answer, and to whom); the batch does not read it.
    """

    cond: Conditioning
    first: np.ndarray
    actions: np.ndarray
    max_steps: int
    temperature: float = 1.0
    seed: int = 0
    constrained: bool = False  # sampled under the game's rules (world/constraints.py)
    info: dict[str, Any] = field(default_factory=dict)
    t: int = 0  # steps taken
    peak: int = 1  # the most requests that shared a step with this one (itself included)

    def __post_init__(self) -> None:
        self.trajectories = Trajectories(self.first, self.max_steps)
        self.running = np.arange(len(self.first))  # trajectories not ended, in row order

    @property
    def size(self) -> int:
        return len(self.first)

    def result(self) -> Imagination:
        return self.trajectories.result()


class ContinuousBatch:
    """The running one-shot requests and their rows: `admit` between steps, `step` returns those that ended."""

    def __init__(self, model: WorldModel, max_rows: int = MAX_ROWS, decoding: str | None = None) -> None:
        """decoding: the path that decodes the rows (world/decoding.py; None: the default)."""
        self.rows = make_decoder_batch(model, decoding, first_blocks=FIRST_BLOCKS)
        self.max_rows = max_rows
        self.shots: list[OneShot] = []  # in row order: each one's rows are contiguous
        self.steps = 0  # steps taken, and trajectory-steps imagined: for status and benchmarks
        self.row_steps = 0
        self.widest = 0  # the most trajectories in one step

    def __len__(self) -> int:
        return len(self.shots)

    def fits(self, size: int) -> bool:
        """Whether a one-shot request of `size` trajectories may join now (a big one may join an empty batch)."""
        return not self.shots or len(self.rows) + size <= self.max_rows

    def admit(self, shot: OneShot) -> None:
        gen = torch.Generator().manual_seed(shot.seed)
        self.rows.admit(shot.cond, shot.first, shot.max_steps, shot.temperature, gen, shot.constrained)
        self.shots.append(shot)

    def step(self) -> list[OneShot]:
        """One step of every running trajectory; returns the one-shot requests whose last trajectory ended."""
        actions = np.concatenate([shot.actions[shot.running, shot.t] for shot in self.shots])
        block, probs = self.rows.step(torch.from_numpy(actions))
        self.steps += 1
        self.row_steps += len(actions)
        self.widest = max(self.widest, len(actions))
        # Decoded for every row at once: per request, numpy's per-call cost would dominate.
        observations, rewards, dones = decode_blocks(block)
        keep, ended, lo = [], [], 0
        for shot in self.shots:
            k = len(shot.running)
            shot.t += 1
            shot.peak = max(shot.peak, len(self.shots))
            rows = slice(lo, lo + k)
            done = dones[rows].copy()
            shot.trajectories.put(
                shot.running, shot.t, actions[rows], observations[rows], rewards[rows], done, probs[rows]
            )
            if shot.t >= shot.max_steps:
                done[:] = True
            keep.append(lo + np.flatnonzero(~done))
            shot.running = shot.running[~done]
            if not len(shot.running):
                ended.append(shot)
            lo += k
        keep = np.concatenate(keep)
        if len(keep) < lo:
            self.rows.keep(torch.from_numpy(keep))
            self.shots = [shot for shot in self.shots if len(shot.running)]
        return ended


def run_alone(model: WorldModel, shot: OneShot) -> Imagination:
    """A one-shot request imagined in a batch of its own (the answer it gets in any batch)."""
    batch = ContinuousBatch(model)
    batch.admit(shot)
    while batch:
        batch.step()
    return shot.result()


__all__ = ["ContinuousBatch", "MAX_ROWS", "OneShot", "run_alone"]
