"""How the agent's policy learns: behaviour cloning of the expert on the training games (the
warm start), online imitation inside a world model (§4), and evaluation in the real game.

Online imitation: the learner acts in imagination (sampling), the expert (go_to_goal reading the
true manual, i.e. the simulated human) labels every imagined state, and the loss is
-log pi(expert action). Only imagined states are used: the agent never acts in the unseen game
before evaluation.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from ..data.dataset import TrajectoryDataset
from ..messenger.constants import STARTS
from ..messenger.engine import BatchedMessenger
from ..messenger.spec import GameSpec
from ..world.base import ManualBatch, WorldModel
from ..world.imagine import imagine
from .expert import expert_actions, role_ids
from .policy import HISTORY, EmmaPolicy, act, stack_history


def _history_at(obs: np.ndarray, offsets: np.ndarray, t: np.ndarray) -> np.ndarray:
    """[B, 3, 4, 3]: observations t-2..t of each sampled episode (clamped at its start)."""
    idx = offsets[:, None] + np.maximum(t[:, None] + np.arange(-HISTORY + 1, 1)[None, :], 0)
    return obs[idx]


def pretrain(
    policy: EmmaPolicy,
    data: TrajectoryDataset,
    features: torch.Tensor,
    lengths: torch.Tensor,
    steps: int = 2000,
    batch: int = 128,
    lr: float = 1e-3,
    seed: int = 0,
    progress=None,
) -> list[float]:
    """Behaviour cloning on states of the training episodes, labelled by the expert.

    features/lengths: the frozen encodings of data.texts ([num_texts, T, F], [num_texts]).
    """
    rng = np.random.default_rng(seed)
    opt = torch.optim.Adam(policy.parameters(), lr=lr)
    obs = np.asarray(data.observations)
    offsets = np.asarray(data.episode_offsets)
    ep_len = np.diff(offsets)
    ids_by_game = np.stack([role_ids(g) for g in data.games])
    losses = []
    policy.train()
    for step in range(steps):
        e = rng.integers(len(ep_len), size=batch)
        t = (rng.random(batch) * (ep_len[e] - 1)).astype(np.int64)  # states that have a next action
        hist = _history_at(obs, offsets[e], t)
        labels = np.empty(batch, dtype=np.int64)
        games = np.asarray(data.episode_games)[e]
        seeds = np.asarray(data.episode_seeds)[e]
        for k in range(batch):  # the expert is vectorised over games with the same step index
            labels[k] = expert_actions(hist[k : k + 1, -1], ids_by_game[games[k]], int(t[k]) + 1, seeds[k])[0]
        manual = manual_from_text_ids(np.asarray(data.manuals)[e], features, lengths)
        logits = policy(torch.from_numpy(hist), policy.id_values(manual))
        loss = F.cross_entropy(logits, torch.from_numpy(labels))
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
        if progress:
            progress(step, loss.item())
    policy.eval()
    return losses


def fit_labels(
    policy: EmmaPolicy, manual: ManualBatch, history: np.ndarray, labels: np.ndarray, updates: int, lr: float
) -> None:
    """Full-batch supervised steps on (3-observation history, expert action) pairs of one manual."""
    h = torch.from_numpy(np.ascontiguousarray(history))
    y = torch.as_tensor(np.asarray(labels, dtype=np.int64))
    opt = torch.optim.Adam(policy.parameters(), lr=lr)
    policy.train()
    for _ in range(updates):
        loss = F.cross_entropy(policy(h, policy.id_values(manual).expand(len(h), -1, -1)), y)
        opt.zero_grad()
        loss.backward()
        opt.step()
    policy.eval()


def manual_from_text_ids(text_ids: np.ndarray, features: torch.Tensor, lengths: torch.Tensor) -> ManualBatch:
    idx = torch.from_numpy(np.asarray(text_ids, dtype=np.int64))
    f = features[idx].float()
    mask = torch.arange(f.shape[2])[None, None, :] < lengths[idx][..., None]
    return ManualBatch(f, mask)


@dataclass
class RealEvaluation:
    returns: np.ndarray  # [episodes]
    wins: int
    deaths: int

    @property
    def mean(self) -> float:
        return float(self.returns.mean())

    def interval(self) -> tuple[float, float]:
        """95% normal interval of the mean return."""
        half = 1.96 * float(self.returns.std(ddof=1)) / np.sqrt(len(self.returns)) if len(self.returns) > 1 else 0.0
        return self.mean - half, self.mean + half


def evaluate_real(
    policy: EmmaPolicy, game: GameSpec, manual: ManualBatch, episodes: int = 48, seed: int = 0, max_steps: int = 32
) -> RealEvaluation:
    """Argmax actions in the real game: episode i starts at STARTS[i % 24] (48 = each start twice)."""
    engine = BatchedMessenger(max_steps=max_steps)
    engine.reset([game] * episodes, seed * 100_000 + np.arange(episodes), np.arange(episodes) % len(STARTS))
    id_values = policy.id_values(manual).detach().expand(episodes, -1, -1)
    history = [engine.compact_observation()]
    total = np.zeros(episodes, dtype=np.float64)
    while not engine.done.all():
        obs = np.stack(history[-HISTORY:], axis=1)
        actions = act(policy, stack_history(obs), id_values, sample=False)
        rewards, _, _, _ = engine.step(actions.astype(np.int64))
        total += rewards
        history.append(engine.compact_observation())
    return RealEvaluation(total, int(engine.won.sum()), int((~engine.alive).sum()))


def expert_labeller(game: GameSpec, seed: int = 0) -> Callable[[np.ndarray, int], np.ndarray]:
    """The simulated human: go_to_goal reading the game's true manual labels observations."""
    ids = role_ids(game)
    return lambda obs, t: expert_actions(obs, ids, t, seed)


def online_imitation_with(
    policy: EmmaPolicy,
    world: WorldModel,
    world_manual: ManualBatch,
    policy_manual: ManualBatch,
    labeller: Callable[[np.ndarray, int], np.ndarray],
    first_obs: np.ndarray,
    updates: int = 50,
    episodes_per_update: int = 16,
    lr: float = 3e-4,
    seed: int = 0,
    max_steps: int = 32,
) -> list[float]:
    """Online imitation learning inside the world model (see the module docstring).

    world_manual is what the world model reads (the manual the human gave), policy_manual what the
    policy reads; labeller(observations [n, 4, 3], t) gives the expert's actions.
    """
    opt = torch.optim.Adam(policy.parameters(), lr=lr)
    gen = torch.Generator().manual_seed(seed)
    losses = []
    for u in range(updates):
        with torch.no_grad():
            id_values = policy.id_values(policy_manual).expand(episodes_per_update, -1, -1)

        def learner(obs: np.ndarray, idx: np.ndarray, t: int, id_values=id_values) -> np.ndarray:
            return act(policy, stack_history(obs), id_values[: len(idx)], sample=True, generator=gen)

        im = imagine(
            world,
            world_manual,
            first_obs,
            n=episodes_per_update,
            policy=learner,
            max_steps=max_steps,
            seed=seed * 10_000 + u,
        )
        hist, labels = [], []
        for t in range(1, max_steps + 1):
            # States at step t-1 of trajectories still running then: one labeller call per step.
            alive = np.flatnonzero(im.lengths > t)
            if len(alive) == 0:
                break
            hist.append(stack_history(im.observations[alive, :t]))
            labels.append(labeller(im.observations[alive, t - 1], t))
        policy.train()
        h = torch.from_numpy(np.concatenate(hist))
        logits = policy(h, policy.id_values(policy_manual).expand(len(h), -1, -1))
        loss = F.cross_entropy(logits, torch.from_numpy(np.concatenate(labels).astype(np.int64)))
        opt.zero_grad()
        loss.backward()
        opt.step()
        policy.eval()
        losses.append(loss.item())
    return losses
