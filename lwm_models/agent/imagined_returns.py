"""Learning from the world model's imagined returns alone: no expert, no labels, no controller.

Policy optimisation in imagination with group baselines (clipped surrogate as in PPO, baselines as
in GRPO). Each round the agent's policy plays `group` imagined episodes from each of the game's
first boards, sampling its actions. A state's advantage is how much the imagined return after it
(discounted by `gamma`) beats the mean over the episodes from the same board still running at the
same step: the group shares the board, so what differs is what the policy did. The policy then
takes `epochs` passes over the round's states in minibatches, each pass moving the probability of
the taken actions towards the advantage, clipped to a ratio of 1 +- `clip` of the probability the
round was played with, so a round can be reused without the policy running away from it. An
entropy bonus keeps it exploring.

Only the world model's imagined observations, rewards and terminations decide what is learnt, so
nothing here knows the game's roles or a way to play it: the world model, having read the manual,
is the only source of what is good. The rules it imagines under (decoding constraints) say only
what no game can do, not which entity is which.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from ..world.base import ManualBatch, WorldModel
from ..world.imagine import imagine
from .learning import imagined_states, sampling_policy
from .policy import EmmaPolicy


@dataclass
class ImaginedReturns:
    """How the agent learns from imagined returns."""

    rounds: int = 24  # imagine, then learn: how many times
    group: int = 8  # imagined episodes a round from each first board (the game has 24)
    epochs: int = 4  # passes over a round's states
    minibatch: int = 512  # states a gradient step
    lr: float = 1e-3  # Adam
    clip: float = 0.2  # how far a round's passes may move an action's probability ratio
    gamma: float = 0.95  # discount of the imagined return after a state
    entropy: float = 0.01  # weight of the policy's entropy in the loss
    # Under the game's rules (decoding constraints) the policy has fewer of the world model's
    # impossible futures to exploit; the rules say nothing of which entity is which.
    constrained: bool = True


def returns_after(rewards: np.ndarray, lengths: np.ndarray, gamma: float) -> np.ndarray:
    """[N, T + 1]: at s, the discounted imagined return of the steps after observation s
    (rewards[:, t] is earned on the step into observation t; nothing after a trajectory's end)."""
    earned = np.where(np.arange(rewards.shape[1])[None, :] < lengths[:, None], rewards, 0.0)
    after = np.zeros_like(earned, dtype=np.float64)
    acc = np.zeros(len(earned))
    for t in range(earned.shape[1] - 1, 0, -1):
        acc = earned[:, t] + gamma * acc
        after[:, t - 1] = acc
    return after


def group_advantages(returns: np.ndarray, steps: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Each state's return minus the mean return of its group's states at its step (all states at
    that step when it is alone in its group there), over the spread of these gains."""
    baseline = np.empty_like(returns, dtype=np.float64)
    for s in np.unique(steps):
        at = np.flatnonzero(steps == s)
        ids, inverse, counts = np.unique(groups[at], return_inverse=True, return_counts=True)
        sums = np.bincount(inverse, weights=returns[at], minlength=len(ids))
        baseline[at] = np.where(counts[inverse] > 1, sums[inverse] / counts[inverse], returns[at].mean())
    gain = returns - baseline
    return gain / (gain.std() + 1e-6)


def learn_from_imagined_returns(
    policy: EmmaPolicy,
    world: WorldModel,
    world_manual: ManualBatch,
    policy_manual: ManualBatch,
    starts: np.ndarray,
    cfg: ImaginedReturns,
    seed: int = 0,
) -> list[dict]:
    """Improve `policy` in place; one entry a round: the mean imagined return of its episodes."""
    starts = np.asarray(starts, dtype=np.uint8).reshape(-1, 4, 3)
    first = np.repeat(starts, cfg.group, axis=0)
    board = np.repeat(np.arange(len(starts)), cfg.group)
    opt = torch.optim.Adam(policy.parameters(), lr=cfg.lr)
    rng = np.random.default_rng(seed)
    log = []
    for r in range(cfg.rounds):
        round_seed = seed * 1_000 + r
        im = imagine(
            world, world_manual, first, n=len(first), seed=round_seed, constrained=cfg.constrained,
            policy=sampling_policy(policy, policy_manual, len(first), torch.Generator().manual_seed(round_seed)),
        )  # fmt: skip
        hist, _, steps, traj = imagined_states(im, im.actions.shape[1] - 1)
        gain = group_advantages(returns_after(im.rewards, im.lengths, cfg.gamma)[traj, steps], steps, board[traj])
        h = torch.from_numpy(np.ascontiguousarray(hist))
        taken = torch.from_numpy(im.actions[traj, steps + 1].astype(np.int64))[:, None]
        weight = torch.from_numpy(gain).float()
        with torch.no_grad():
            played = F.log_softmax(policy(h, policy.id_values(policy_manual).expand(len(h), -1, -1)), -1)
            played = played.gather(1, taken)[:, 0]
        policy.train()
        for _ in range(cfg.epochs):
            order = torch.from_numpy(rng.permutation(len(h)))
            for b in order.split(cfg.minibatch):
                logp = F.log_softmax(policy(h[b], policy.id_values(policy_manual).expand(len(b), -1, -1)), -1)
                ratio = (logp.gather(1, taken[b])[:, 0] - played[b]).exp()
                surrogate = torch.minimum(ratio * weight[b], ratio.clamp(1 - cfg.clip, 1 + cfg.clip) * weight[b])
                entropy = -(logp.exp() * logp).sum(-1).mean()
                loss = -surrogate.mean() - cfg.entropy * entropy
                opt.zero_grad()
                loss.backward()
                opt.step()
        policy.eval()
        log.append({"round": r + 1, "imagined_return": float(im.returns.mean()), "states": len(h)})
    return log


__all__ = ["ImaginedReturns", "group_advantages", "learn_from_imagined_returns", "returns_after"]
